"""Attributed intersection points and their adaptive quadtree (Aliaga et al. 2008, sec. 4).

An example layout is abstracted into street intersection points, each with the attributes
of sec. 3.1.1 (the levels of the two streets through it, their tortuosity and the mean /
variance of the distance and of the turn angle between consecutive intersections along
them). This module

- turns the attribute table of :func:`hierarchy.intersection_attributes` (the
  OUTPUT_INTERSECTIONS of ``extractroadhierarchy``) or a road layer into a
  :class:`PointSet` (:func:`points_from_table`, :func:`points_from_roads`);
- organises a point set in the adaptive quadtree of sec. 4.1 (:func:`build_quadtree`): the
  oriented bounding box of the points is split recursively until a leaf holds roughly
  uniformly distributed points (a chi-square test on its four quadrants), or reaches a
  minimum area or point count; each leaf stores its point density and the relative
  probability of each hierarchy level;
- places copies of an example's points into a target polygon of any shape (join /
  expand, sec. 4.2, :func:`place_points`) and fills what the copies leave empty with new
  points drawn from the leaves' model (:func:`generate_points`: each patch of the area
  takes a built-up leaf, points at its density, levels from its level probabilities,
  street statistics from its points of that level; sec. 4.1 "parametrically producing
  attributed intersection points");
- blends two examples with a constant or spatially varying weight (:func:`blend_points`):
  a smooth random field gives a share beta of the area to B's point layout and the rest
  to A's, and every point's street statistics (distances, angles, their variances,
  tortuosity, parcel area) are interpolated by beta between its own and the other
  example's there (sec. 4.2: a constant blend "interpolates" between the styles).

Nothing here imports QGIS.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1.1, 4.1, 4.2, 5.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import List, Optional, Sequence, Union

import numpy as np
import pandas as pd
import shapely
from scipy import stats
from scipy.spatial import cKDTree

from ..core.coordinates import apply_affine
from ..core.geometry import minimum_rectangle_corners
from ..core.progress import InputError

__all__ = ["REQUIRED_FIELDS", "PointSet", "points_from_table", "points_from_roads",
           "Leaf", "QuadTree", "build_quadtree", "place_points", "generate_points",
           "blend_points", "BLENDED_ATTRIBUTES", "copy_patches", "built_up_leaves",
           "example_density", "interpolate_attributes"]

#: Attribute columns a point layer must have (street a; street b is optional per point).
REQUIRED_FIELDS = ("level_a", "dist_mean_a")
#: Every field :func:`points_from_table` reads (``extractroadhierarchy``'s intersections).
TABLE_FIELDS = ("level_a", "level_b", "degree", "tortuosity_a", "tortuosity_b", "dist_mean_a",
                "dist_var_a", "dist_mean_b", "dist_var_b", "angle_mean_a", "angle_var_a",
                "angle_mean_b", "angle_var_b", "parcel_area", "block_area")
_SLOT_COLUMNS = ("level", "tortuosity", "dist_mean", "dist_var", "angle_mean", "angle_var")
#: Floors of the transition Gaussian's spreads: a street with two equal gaps has variance 0.
MIN_DIST_SD_SHARE = 0.15   # of the mean distance
MIN_DIST_SD = 3.0          # m
MIN_ANGLE_SD = 8.0         # degrees


@dataclass
class PointSet:
    """Attributed intersection points (two street slots a, b per point).

    xy : (n, 2) metric coordinates
    level : (n, 2) int, hierarchy level of street a / b (-1: no such street)
    tortuosity, dist_mean, dist_sd, angle_mean, angle_sd : (n, 2) float per slot
    degree : (n,) int, connections of the point in its example (the walk's capacity, <= 4)
    area : (n,) float, mean parcel (else block) area around the point (m², NaN unknown)
    source : (n,) int, index of the point in its example (for provenance / evidence); for
        a generated point, the example point it took its attributes from
    example : (n,) int, which example the point comes from (0 = A, 1 = B, -1 = existing)
    generated : (n,) bool, drawn from the quadtree model (:func:`generate_points`) rather
        than copied from the example
    """

    xy: np.ndarray
    level: np.ndarray
    tortuosity: np.ndarray
    dist_mean: np.ndarray
    dist_sd: np.ndarray
    angle_mean: np.ndarray
    angle_sd: np.ndarray
    degree: np.ndarray
    area: np.ndarray
    source: np.ndarray
    example: np.ndarray
    generated: Optional[np.ndarray] = None

    def __post_init__(self):
        if self.generated is None:
            self.generated = np.zeros(len(self.xy), dtype=bool)

    def __len__(self) -> int:
        return len(self.xy)

    def take(self, idx) -> "PointSet":
        idx = np.asarray(idx)
        if idx.dtype != bool:
            idx = idx.astype(np.int64)
        return PointSet(**{k: getattr(self, k)[idx] for k in self.__dataclass_fields__})

    def moved(self, offset) -> "PointSet":
        return replace(self, xy=self.xy + np.asarray(offset, dtype=float))

    @staticmethod
    def concat(sets: Sequence["PointSet"]) -> "PointSet":
        keys = PointSet.__dataclass_fields__
        return PointSet(**{k: np.concatenate([getattr(s, k) for s in sets]) for k in keys})

    def table(self) -> pd.DataFrame:
        """Attributes in the column names of :func:`hierarchy.intersection_attributes`."""
        out = {"degree": self.degree, "example": self.example, "source_id": self.source}
        for j, s in enumerate("ab"):
            lv = self.level[:, j].astype(float)
            out[f"level_{s}"] = np.where(lv >= 0, lv, np.nan)
            out[f"tortuosity_{s}"] = self.tortuosity[:, j]
            out[f"dist_mean_{s}"] = self.dist_mean[:, j]
            out[f"dist_var_{s}"] = self.dist_sd[:, j] ** 2
            out[f"angle_mean_{s}"] = self.angle_mean[:, j]
            out[f"angle_var_{s}"] = self.angle_sd[:, j] ** 2
        out["parcel_area"] = self.area
        return pd.DataFrame(out)


def _column(df: pd.DataFrame, name: str) -> np.ndarray:
    if name not in df:
        return np.full(len(df), np.nan)
    return pd.to_numeric(df[name], errors="coerce").to_numpy(dtype=float)


def _fill(values: np.ndarray, level: np.ndarray, default: float) -> np.ndarray:
    """NaN slot statistics -> the median of the points with the same level, else overall."""
    out = values.copy()
    for lv in np.unique(level[level >= 0]):
        sel = level == lv
        good = sel & np.isfinite(values)
        out[sel & ~np.isfinite(values)] = np.median(values[good]) if good.any() else np.nan
    rest = ~np.isfinite(out)
    fin = np.isfinite(values)
    out[rest] = np.median(values[fin]) if fin.any() else default
    return out


def points_from_table(xy, table: pd.DataFrame, example: int = 0) -> PointSet:
    """A :class:`PointSet` from intersection attributes (``extractroadhierarchy`` fields).

    Parameters
    ----------
    xy : (n, 2) coordinates in a metric CRS
    table : DataFrame with at least :data:`REQUIRED_FIELDS`; the other columns of
        :func:`hierarchy.intersection_attributes` (level_b, tortuosity_a/b, dist_var_a/b,
        angle_mean_a/b, angle_var_a/b, degree, parcel_area, block_area) are used when present.

    Raises
    ------
    InputError
        Missing fields, no point with a level, negative distances.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    missing = [f for f in REQUIRED_FIELDS if f not in table]
    if missing:
        raise InputError(f"the intersection points have no field {', '.join(missing)} "
                         "(use the intersections of 'Extract road hierarchy', or give roads)")
    if len(table) != len(xy):
        raise InputError(f"{len(table)} attribute rows for {len(xy)} points")
    level = np.column_stack([_column(table, "level_a"), _column(table, "level_b")])
    ok = np.isfinite(level) & (level >= 0)
    level = np.where(ok, np.round(np.where(ok, level, 0)), -1).astype(np.int64)
    keep = (level[:, 0] >= 0) & np.isfinite(xy).all(axis=1)
    if not keep.any():
        raise InputError("no intersection point has a street level (level_a)")
    cols = {}
    for name, default in (("tortuosity", 1.0), ("dist_mean", np.nan), ("dist_var", np.nan),
                          ("angle_mean", 10.0), ("angle_var", 100.0)):
        cols[name] = np.column_stack([_column(table, f"{name}_a"), _column(table, f"{name}_b")])
    dm = cols["dist_mean"]
    if (dm[np.isfinite(dm)] < 0).any():
        raise InputError("negative distances in dist_mean_a / dist_mean_b")
    if not np.isfinite(dm[keep, 0]).any():
        raise InputError("no intersection point has a mean street distance (dist_mean_a)")
    # one order whatever order the rows came in (a layer's, a selection's, a shapefile's):
    # the walks draw points by position, so the same points in another order gave another
    # network; x then y is the order of a cleaned graph's nodes, which stay as they were
    rows = np.flatnonzero(keep)
    rows = rows[np.lexsort((level[rows, 1], level[rows, 0], xy[rows, 1], xy[rows, 0]))]
    xy, level = xy[rows], level[rows]
    cols = {k: v[rows] for k, v in cols.items()}
    filled = {}
    flat_level = level.ravel()
    for name, default in (("tortuosity", 1.0), ("dist_mean", 100.0), ("dist_var", np.nan),
                          ("angle_mean", 10.0), ("angle_var", 100.0)):
        v = cols[name].ravel().copy()
        v[flat_level < 0] = np.nan
        filled[name] = _fill(v, flat_level, default).reshape(-1, 2)
    dist_mean = np.maximum(filled["dist_mean"], 1.0)
    dist_var = np.where(np.isfinite(filled["dist_var"]), filled["dist_var"],
                        (0.3 * dist_mean) ** 2)
    dist_sd = np.maximum.reduce([np.sqrt(np.maximum(dist_var, 0.0)),
                                 MIN_DIST_SD_SHARE * dist_mean,
                                 np.full_like(dist_mean, MIN_DIST_SD)])
    angle_sd = np.maximum(np.sqrt(np.maximum(filled["angle_var"], 0.0)), MIN_ANGLE_SD)
    tort = np.clip(filled["tortuosity"], 1.0, 3.0)
    degree = _column(table, "degree")[rows]
    degree = np.where(np.isfinite(degree), np.clip(degree, 1, 4), 4).astype(np.int64)
    area = _column(table, "parcel_area")[rows]
    block_area = _column(table, "block_area")[rows]
    area = np.where(np.isfinite(area), area, block_area)
    n = len(xy)
    return PointSet(xy, level, tort, dist_mean, dist_sd, filled["angle_mean"], angle_sd,
                    degree, area, rows, np.full(n, example, dtype=np.int64))


def points_from_roads(lines, road_class=None, parcels=None, example: int = 0,
                      progress=None):
    """Clean a road layer, rank its streets and attribute its intersections.

    Returns
    -------
    (PointSet, RoadGraph, Hierarchy): the points are the graph's nodes (``source`` = node id).
    """
    from ..network import hierarchy
    from ..network import street_graph as roads

    graph = roads.clean_network(lines, road_class, progress=progress)
    h = hierarchy.road_hierarchy(graph)
    table = hierarchy.intersection_attributes(graph, h.streets, h.street_level, parcels=parcels)
    return points_from_table(graph.nodes, table, example), graph, h


# --------------------------------------------------------------------------- quadtree

@dataclass
class Leaf:
    """A quadtree leaf: a rectangle of the example's OBB frame with roughly uniform points.

    polygon : the leaf rectangle in world coordinates
    index : indices of its points in the point set
    density : points per m²
    level_prob : relative probability of each hierarchy level (over both street slots)
    """

    polygon: shapely.Geometry
    index: np.ndarray
    density: float
    level_prob: np.ndarray


@dataclass
class QuadTree:
    leaves: List[Leaf]
    angle: float                 # OBB orientation (radians)
    leaf_of_point: np.ndarray    # leaf index of every point
    n_levels: int = 0
    depth: int = 0
    tree: Optional[shapely.STRtree] = field(default=None, repr=False)

    def leaf_at(self, xy) -> np.ndarray:
        """Leaf index containing each location (-1 outside every leaf)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        out = np.full(len(xy), -1, dtype=np.int64)
        if self.tree is None:
            self.tree = shapely.STRtree([leaf.polygon for leaf in self.leaves])
        pi, li = self.tree.query(shapely.points(xy), predicate="intersects")
        out[pi] = li
        return out

    def density_at(self, xy) -> np.ndarray:
        leaf = self.leaf_at(xy)
        d = np.array([lf.density for lf in self.leaves] + [0.0])
        return d[leaf]


def _rotation(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def build_quadtree(points: PointSet, min_points: int = 8, min_area: float = 2500.0,
                   alpha: float = 0.05, max_depth: int = 12) -> QuadTree:
    """Adaptive quadtree of sec. 4.1 over the OBB of the points.

    A node is split into four while it has at least ``min_points`` points, is at least
    ``4 * min_area`` m², and its points are not uniformly spread: the counts in its four
    quadrants fail a chi-square test of equal counts at level ``alpha``.
    """
    xy = points.xy
    n = len(xy)
    if n == 0:
        raise InputError("no intersection points")
    hull = shapely.multipoints(xy)
    c = minimum_rectangle_corners([hull])[0]
    e = c[1] - c[0]
    angle = float(np.arctan2(e[1], e[0])) if np.isfinite(e).all() and e.any() else 0.0
    rot = _rotation(-angle)
    local = apply_affine(xy, rot, (0.0, 0.0))
    lo, hi = local.min(axis=0) - 1e-6, local.max(axis=0) + 1e-6
    hi = np.maximum(hi, lo + 1.0)
    levels = points.level[points.level >= 0]
    n_levels = int(levels.max()) + 1 if len(levels) else 1
    crit = stats.chi2.ppf(1.0 - alpha, 3)
    leaves: List[Leaf] = []
    leaf_of = np.full(n, -1, dtype=np.int64)
    back = _rotation(angle)
    max_seen = 0

    def add_leaf(idx, b0, b1):
        corners = np.array([[b0[0], b0[1]], [b1[0], b0[1]], [b1[0], b1[1]], [b0[0], b1[1]]])
        poly = shapely.Polygon(apply_affine(corners, back, (0.0, 0.0)))
        area = float(np.prod(b1 - b0))
        lv = points.level[idx].ravel()
        lv = lv[lv >= 0]
        prob = np.bincount(lv, minlength=n_levels).astype(float)
        prob = prob / prob.sum() if prob.sum() else prob
        leaf_of[idx] = len(leaves)
        leaves.append(Leaf(poly, idx, len(idx) / area, prob))

    stack = [(np.arange(n), lo, hi, 0)]
    while stack:
        idx, b0, b1, depth = stack.pop()
        max_seen = max(max_seen, depth)
        size = b1 - b0
        mid = (b0 + b1) / 2.0
        q = (local[idx, 0] >= mid[0]).astype(int) + 2 * (local[idx, 1] >= mid[1]).astype(int)
        counts = np.bincount(q, minlength=4)
        expected = len(idx) / 4.0
        uniform = expected == 0 or ((counts - expected) ** 2 / expected).sum() <= crit
        if (len(idx) < min_points or np.prod(size) < 4 * min_area or uniform
                or depth >= max_depth):
            add_leaf(idx, b0, b1)
            continue
        for k in range(4):
            c0 = np.array([b0[0] if k % 2 == 0 else mid[0], b0[1] if k < 2 else mid[1]])
            c1 = np.array([mid[0] if k % 2 == 0 else b1[0], mid[1] if k < 2 else b1[1]])
            stack.append((idx[q == k], c0, c1, depth + 1))
    return QuadTree(leaves, angle, leaf_of, n_levels, max_seen)


# --------------------------------------------------------------------------- placement

def _as_target(target) -> shapely.Geometry:
    geoms = np.asarray(target, dtype=object).ravel() if not isinstance(
        target, shapely.Geometry) else np.array([target], dtype=object)
    geoms = geoms[~(shapely.is_missing(geoms) | shapely.is_empty(geoms))]
    if len(geoms) == 0:
        raise InputError("the target has no polygon")
    if not (shapely.get_dimensions(geoms) == 2).all():
        raise InputError("the target must be polygons")
    area = shapely.union_all(shapely.make_valid(geoms))
    if area.area <= 0:
        raise InputError("the target polygons have no area")
    return area


def place_points(points: PointSet, quadtree: QuadTree, target, rng: np.random.Generator,
                 in_place: Optional[bool] = None, n_offsets: int = 6,
                 fill: Optional[bool] = None, patches: bool = True) -> PointSet:
    """Copies of the example's points that cover ``target`` (join / expand, sec. 4.2), and
    points drawn from the quadtree model where the copies leave the target empty.

    The example is tiled over the target by translation (its bounding box repeated); the
    quadtree leaves are the atomic units: a leaf copy is used when it overlaps the target,
    and its points inside the target are kept. Sparse leaves (under a quarter of the median
    leaf density: parks, water, the clipped margin of an extract) are skipped when the target
    is larger than the example, so that the tiling repeats built-up parts.

    in_place : bool, optional
        True: the example's own coordinates (a copy-and-reconnect, fig. 8); False: the
        translation that puts the most example points into the target, among
        ``n_offsets``² shifts of the tiling (ties: the most central); None: in place unless
        a shift puts over 25 % more points into the target (a target beside or inside a
        hole of the example gets shifted copies).
    fill : bool, optional
        Fill the parts of the target farther than :data:`FILL_GAP` x the example's median
        street distance from every copied point with points of :func:`generate_points`
        (a target of another shape than the example, or an example with parks, water or
        empty margins). Default: fill unless ``in_place`` is True (the copy-and-reconnect
        of fig. 8 keeps exactly the example's points).
    patches : bool
        Fill first with patches of the example's built-up layout (:func:`copy_patches`),
        then with the quadtree model where gaps remain; False: the model only.
    """
    area = _as_target(target)
    if fill is None:
        fill = in_place is not True
    xy = points.xy
    x0, y0 = xy.min(axis=0)
    x1, y1 = xy.max(axis=0)
    # the period of the tiling: the example's extent plus one typical street gap
    gap = float(np.median(points.dist_mean[:, 0]))
    w, h = max(x1 - x0, 1.0) + gap, max(y1 - y0, 1.0) + gap
    example_hull = shapely.convex_hull(shapely.multipoints(xy))
    tx0, ty0, tx1, ty1 = area.bounds
    shapely.prepare(area)
    leaf_density = np.array([lf.density for lf in quadtree.leaves])
    dense = leaf_density[quadtree.leaf_of_point] >= 0.25 * np.median(leaf_density)
    big = area.area > shapely.area(example_hull)
    usable = dense if (big and not in_place) else np.ones(len(xy), dtype=bool)

    def tiled(offset, single=False):
        # integer tile shifts that can reach the target from this offset
        i0 = int(np.floor((tx0 - (x1 + offset[0])) / w))
        i1 = int(np.ceil((tx1 - (x0 + offset[0])) / w))
        j0 = int(np.floor((ty0 - (y1 + offset[1])) / h))
        j1 = int(np.ceil((ty1 - (y0 + offset[1])) / h))
        if single:  # in place: the example itself, no repeats
            i0 = i1 = j0 = j1 = 0
        sets = []
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                shift = np.array([offset[0] + i * w, offset[1] + j * h])
                moved = xy + shift
                inside = usable & shapely.contains_xy(area, moved[:, 0], moved[:, 1])
                if inside.any():
                    sets.append((np.flatnonzero(inside), shift))
        return sets

    best, best_key = [], (0, 0.0)
    if in_place is not False:
        best = tiled(np.zeros(2), single=True)
        best_key = (sum(len(s[0]) for s in best), 0.0)
    if not in_place:
        in_place_count = best_key[0]
        centre = np.array([(tx0 + tx1 - x0 - x1) / 2.0, (ty0 + ty1 - y0 - y1) / 2.0])
        shifted, shifted_key = None, None
        for fx in np.linspace(-0.5, 0.5, n_offsets, endpoint=False):
            for fy in np.linspace(-0.5, 0.5, n_offsets, endpoint=False):
                offset = centre + np.array([fx * w, fy * h])
                sets = tiled(offset)
                key = (sum(len(s[0]) for s in sets), -abs(fx) - abs(fy))
                if shifted_key is None or key > shifted_key:
                    shifted, shifted_key = sets, key
        # automatic: in place unless a shift brings clearly more points into the target
        if in_place is False or shifted_key[0] > 1.25 * in_place_count:
            best = shifted
    if not best and not fill:
        if in_place and not shapely.intersects(example_hull, area):
            # at its own coordinates the example lies elsewhere: not a target too small
            raise InputError("the example lies outside the target, and placement 'in place' "
                             "keeps its points where they are: place it automatically or "
                             "shifted to copy it into the target")
        raise InputError("no example point falls into the target: the target is smaller than "
                         "the example's street spacing")
    placed = PointSet.concat([points.take(idx).moved(shift) for idx, shift in best]) \
        if best else points.take(np.zeros(0, dtype=np.int64))
    # only copies of different tiles can stack at a seam
    placed = _thin(placed, 0.3) if len(best) > 1 else placed
    if not fill:
        return placed
    reach = FILL_GAP * gap
    parts = [placed]

    cache = {}

    def uncovered(xy):
        """Locations farther than ``reach`` from every point placed so far."""
        n = sum(len(p) for p in parts)
        if not n:
            return np.ones(len(xy), dtype=bool)
        if cache.get("n") != n:
            cache["n"], cache["tree"] = n, cKDTree(np.concatenate([p.xy for p in parts]))
        return cache["tree"].query(xy, distance_upper_bound=reach)[0] > reach

    if patches:
        # patches of the example's built-up point layout first (streets stay aligned) ...
        parts.append(copy_patches(points, quadtree, area, rng, accept=uncovered))
    # ... then the quadtree model where they leave gaps
    parts.append(generate_points(points, quadtree, area, rng, accept=uncovered))
    out = PointSet.concat(parts)
    out = _thin(out, 0.3)
    # copies of built-up windows are denser than the example as a whole (its edges and
    # gaps count too): keep the example's density per area near its streets
    want = example_density(points) * area.area
    if len(out) > want > 0:
        out = out.take(np.sort(rng.permutation(len(out))[:int(round(want))]))
    if not len(out):
        raise InputError("no example point falls into the target: the target is smaller than "
                         "the example's street spacing")
    return out


def example_density(points: PointSet) -> float:
    """Points per m² of the example's street area: the union of discs of one median street
    distance around its points (the built area an outline of the example would hold)."""
    if not len(points):
        return 0.0
    gap = float(np.median(points.dist_mean[:, 0]))
    step = gap / 4.0
    lo, hi = points.xy.min(axis=0) - gap, points.xy.max(axis=0) + gap
    n_cells = np.prod(np.ceil((hi - lo) / step))
    if n_cells > 4e6:  # a huge example: a coarser raster
        step = float(np.sqrt(np.prod(hi - lo) / 4e6))
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step) + step / 2,
                         np.arange(lo[1], hi[1], step) + step / 2)
    near = cKDTree(points.xy).query(np.column_stack([gx.ravel(), gy.ravel()]),
                                    distance_upper_bound=gap)[0] <= gap
    area = near.sum() * step * step  # a raster of the union of the discs
    return len(points) / area if area > 0 else 0.0


#: Parts of the target farther than this x the example's median street distance from every
#: copied point are filled by :func:`generate_points`.
FILL_GAP = 0.75


def _cells(region, side: float, rng) -> np.ndarray:
    """Square cells of ``side`` m at a random offset that meet ``region``."""
    x0, y0, x1, y1 = region.bounds
    off = rng.uniform(0.0, side, 2)
    cx = np.arange(np.floor((x0 - off[0]) / side), np.ceil((x1 - off[0]) / side)) * side \
        + off[0]
    cy = np.arange(np.floor((y0 - off[1]) / side), np.ceil((y1 - off[1]) / side)) * side \
        + off[1]
    if not len(cx) or not len(cy):
        return np.empty(0, dtype=object)
    gx, gy = np.meshgrid(cx, cy)
    cells = shapely.box(gx, gy, gx + side, gy + side).ravel()
    return cells[shapely.intersects(cells, region)]


def copy_patches(points: PointSet, quadtree: QuadTree, region, rng: np.random.Generator,
                 side: Optional[float] = None, tries: int = 6,
                 accept: Optional[callable] = None) -> PointSet:
    """Copies of square windows of the example's built-up layout that tile ``region``.

    The paste of sec. 4.2 ("copies of their attributed intersection points placed next to
    each other") for a region of any shape: the region is cut into squares of ``side`` m
    (default 5 median street distances); each square takes the points of a window of the
    same size centred on a uniform random location of the built-up leaves
    (:func:`built_up_leaves`), translated; a window with fewer points than half the
    leaves' mean density predicts is redrawn up to ``tries`` times (it fell on a park or
    the edge of the example). ``accept(xy) -> bool`` keeps only some locations (the holes
    left by earlier copies); a square where it keeps under a third of the area is skipped.
    """
    region = _as_target(region)
    use = built_up_leaves(quadtree)
    if not len(use):
        return points.take([])
    area = np.array([quadtree.leaves[k].polygon.area for k in use])
    dens = float(sum(len(quadtree.leaves[k].index) for k in use) / area.sum())
    gap = float(np.median(points.dist_mean[:, 0]))
    side = side or 5.0 * gap
    tree = cKDTree(points.xy)
    shapely.prepare(region)
    idx_all, shift_all = [], []
    probe = (np.stack(np.meshgrid(np.linspace(-0.4, 0.4, 5), np.linspace(-0.4, 0.4, 5)),
                      axis=-1).reshape(-1, 2)) * side
    for cell in _cells(region, side, rng):
        b = cell.bounds
        c = np.array([(b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0])
        if accept is not None:
            pr = c + probe
            ok = shapely.contains_xy(region, pr[:, 0], pr[:, 1])
            if not ok.any() or accept(pr[ok]).sum() < len(pr) / 3.0:
                continue

        def part_contains(m):
            inside = (m[:, 0] >= b[0]) & (m[:, 0] < b[2]) & (m[:, 1] >= b[1]) & (m[:, 1] < b[3])
            inside &= shapely.contains_xy(region, m[:, 0], m[:, 1])
            if accept is not None and inside.any():
                inside[inside] = accept(m[inside])
            return inside

        best = None
        for _ in range(tries):
            # a uniform location of the built-up area (not a point: that would favour the
            # densest leaves)
            leaf = quadtree.leaves[int(use[rng.choice(len(use), p=area / area.sum())])]
            lb = leaf.polygon
            ring = shapely.get_coordinates(lb)[:4]
            u, v = rng.random(2)
            centre = ring[0] + u * (ring[1] - ring[0]) + v * (ring[3] - ring[0])
            idx = np.asarray(tree.query_ball_point(centre, side / 2.0, p=np.inf), dtype=np.int64)
            moved = points.xy[idx] + (c - centre)
            inside = part_contains(moved)
            if best is None or inside.sum() > best[0].sum():
                best = (inside, idx, c - centre)
            if len(idx) >= 0.5 * dens * side * side:
                break
        inside, idx, shift = best
        if inside.any():
            idx_all.append(idx[inside])
            shift_all.append(np.repeat(shift[None, :], inside.sum(), axis=0))
    if not idx_all:
        return points.take([])
    out = points.take(np.concatenate(idx_all))
    out.xy = out.xy + np.concatenate(shift_all)
    return out


#: Leaves with at least this share of the median leaf density model built-up area.
BUILT_UP_SHARE = 0.1


def built_up_leaves(quadtree: QuadTree, min_share: Optional[float] = None) -> np.ndarray:
    """Indices of the leaves that model built-up area: at least 3 points and at least
    ``min_share`` of the median density of such leaves (parks, water and the empty margins
    of an extract are sparse leaves)."""
    min_share = BUILT_UP_SHARE if min_share is None else min_share
    n = np.array([len(lf.index) for lf in quadtree.leaves])
    dens = np.array([lf.density for lf in quadtree.leaves])
    ok = n >= 3
    if not ok.any():
        ok = n >= 1
    if not ok.any():
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(ok & (dens >= min_share * np.median(dens[ok])))


def generate_points(points: PointSet, quadtree: QuadTree, region, rng: np.random.Generator,
                    patch: Optional[float] = None, leaves: Optional[np.ndarray] = None,
                    level_prob: Optional[callable] = None,
                    accept: Optional[callable] = None) -> PointSet:
    """New attributed points in ``region`` drawn from the example's quadtree leaves.

    Sec. 4.1: each leaf is "a set of points of approximately uniform spatial distribution"
    that stores "the relative probability of each hierarchy level", which "enables
    parametrically producing attributed intersection points". Here the region is cut into
    square patches of about one leaf's size; each patch takes one built-up leaf
    (:func:`built_up_leaves`, drawn with probability proportional to its points) and gets

    - points at the leaf's density, one uniform point per cell of a lattice of spacing
      ``1 / sqrt(density)`` (stratified sampling: the density of the leaf exactly, evenly
      spread as intersections are, never two on one spot);
    - a hierarchy level per point drawn from the leaf's level probabilities (or
      ``level_prob(leaf_index, xy) -> (n, n_levels)`` probabilities, for a blend);
    - the street statistics of a random point of the leaf whose streets have that level
      (so that the two streets' attributes stay a consistent pair).

    Parameters
    ----------
    points, quadtree : the example and its quadtree (:func:`build_quadtree`)
    region : Polygon / MultiPolygon to fill
    rng : numpy Generator
    patch : side (m) of the patches; default the median side of the built-up leaves,
        within 3 .. 12 median street distances
    leaves : leaf indices to draw from (default :func:`built_up_leaves`)
    accept : function (n, 2) locations -> bool, optional: only these locations get points
        (the holes left by copies)

    Returns
    -------
    PointSet with ``generated`` True (``source`` = the example point that gave the
    attributes).

    References
    ----------
    Aliaga, Vanegas, Benes 2008, sec. 4.1 (adaptive quadtree, uniform leaves, level
    probabilities) and 4.2 (expand: points placed next to an existing layout).
    """
    region = _as_target(region)
    use = built_up_leaves(quadtree) if leaves is None else np.asarray(leaves, dtype=np.int64)
    empty = points.take(np.zeros(0, dtype=np.int64))
    if len(use) == 0:
        return empty
    count = np.array([len(quadtree.leaves[k].index) for k in use], dtype=float)
    weight = count / count.sum()
    gap = float(np.median(points.dist_mean[:, 0]))
    if patch is None:
        sides = [np.sqrt(quadtree.leaves[k].polygon.area) for k in use]
        patch = float(np.clip(np.median(sides), 3.0 * gap, 12.0 * gap))
    shapely.prepare(region)
    cells = _cells(region, patch, rng)
    xy_all, donor_all = [], []
    for cell in cells:
        k = int(use[rng.choice(len(use), p=weight)])
        leaf = quadtree.leaves[k]
        step = 1.0 / np.sqrt(max(leaf.density, 1e-12))
        b = cell.bounds
        gx = np.arange(b[0], b[2], step)
        gy = np.arange(b[1], b[3], step)
        if not len(gx) or not len(gy):
            continue
        lx, ly = np.meshgrid(gx, gy)
        xy = np.column_stack([lx.ravel(), ly.ravel()]) + rng.uniform(0.0, step, (lx.size, 2))
        inside = (xy[:, 0] < b[2]) & (xy[:, 1] < b[3])
        inside[inside] = shapely.contains_xy(region, xy[inside, 0], xy[inside, 1])
        if accept is not None and inside.any():
            inside[inside] = accept(xy[inside])
        xy = xy[inside]
        if not len(xy):
            continue
        prob = np.asarray(leaf.level_prob, dtype=float)
        if level_prob is not None:
            prob = np.asarray(level_prob(k, xy), dtype=float)
        prob = np.broadcast_to(prob, (len(xy), len(prob))) if prob.ndim == 1 else prob
        lv_of = points.level[leaf.index]
        # levels this leaf's points can give; a draw of another level is redrawn among them
        avail = np.array([(lv_of == lv).any() for lv in range(prob.shape[1])])
        prob = np.where(avail[None, :], prob, 0.0)
        total = prob.sum(axis=1, keepdims=True)
        prob = np.where(total > 0, prob / np.maximum(total, 1e-300), avail / avail.sum())
        levels = (rng.random(len(xy))[:, None] > np.cumsum(prob, axis=1)).sum(axis=1)
        levels = np.minimum(levels, prob.shape[1] - 1)
        donor = np.empty(len(xy), dtype=np.int64)
        for lv in np.unique(levels):
            pool = leaf.index[(lv_of == lv).any(axis=1)]
            sel = levels == lv
            donor[sel] = pool[rng.integers(0, len(pool), sel.sum())]
        xy_all.append(xy)
        donor_all.append(donor)
    if not xy_all:
        return empty
    out = points.take(np.concatenate(donor_all))
    out.xy = np.concatenate(xy_all)
    out.generated = np.ones(len(out), dtype=bool)
    return out


def _thin(points: PointSet, share: float, order=None) -> PointSet:
    """Drop points closer than ``share`` x their mean street distance to a kept point
    (tile seams and blends must not stack two intersections on one spot)."""
    if len(points) < 2:
        return points
    r = share * points.dist_mean[:, 0]
    tree = cKDTree(points.xy)
    pairs = tree.query_pairs(float(r.max()), output_type="ndarray")
    if len(pairs) == 0:
        return points
    d = np.linalg.norm(points.xy[pairs[:, 0]] - points.xy[pairs[:, 1]], axis=1)
    close = d < np.minimum(r[pairs[:, 0]], r[pairs[:, 1]])
    pairs = pairs[close]
    if len(pairs) == 0:
        return points
    rank = np.arange(len(points))
    if order is not None:
        rank[np.argsort(order)] = np.arange(len(points))
    drop = np.zeros(len(points), dtype=bool)
    # greedy: process pairs by the better-ranked member; drop the other unless already gone
    first = np.where(rank[pairs[:, 0]] < rank[pairs[:, 1]], pairs[:, 0], pairs[:, 1])
    second = np.where(first == pairs[:, 0], pairs[:, 1], pairs[:, 0])
    for a, b in sorted(zip(first, second), key=lambda p: rank[p[0]]):
        if not drop[a]:
            drop[b] = True
    return points.take(np.flatnonzero(~drop))


def _smooth_uniform(xy, scale, rng, n_waves: int = 48) -> np.ndarray:
    """A smooth random field with uniform marginals on [0, 1] (random Fourier features of a
    Gaussian field with correlation length ``scale``, mapped through the normal CDF)."""
    k = rng.normal(0.0, 1.0 / scale, (n_waves, 2))
    phase = rng.uniform(0.0, 2.0 * np.pi, n_waves)
    # written out: a BLAS product rounds differently under different processor kernels
    proj = xy[:, :1] * k[:, 0] + xy[:, 1:2] * k[:, 1]
    field = np.sqrt(2.0 / n_waves) * np.cos(proj + phase).sum(axis=1)
    return stats.norm.cdf(field)


#: Point attributes a blend interpolates (sec. 3.1.1 (ii)-(iv)): street distances and turn
#: angles (means and variances), tortuosity and parcel area.
BLENDED_ATTRIBUTES = ("dist_mean", "dist_var", "angle_mean", "angle_var", "tortuosity",
                      "parcel_area")


def _nearest_same_level(own: PointSet, other: PointSet) -> np.ndarray:
    """Index into ``other`` of the nearest point whose street a has the level of each point
    of ``own`` (the nearest point of any level where ``other`` has none of that level)."""
    out = cKDTree(other.xy).query(own.xy)[1]
    for lv in np.unique(own.level[:, 0]):
        pool = np.flatnonzero(other.level[:, 0] == lv)
        sel = own.level[:, 0] == lv
        if len(pool) and sel.any():
            out[sel] = pool[cKDTree(other.xy[pool]).query(own.xy[sel])[1]]
    return out


def interpolate_attributes(own: PointSet, other: PointSet, weight) -> PointSet:
    """``own``'s points with their :data:`BLENDED_ATTRIBUTES` moved towards those of the
    nearest point of ``other`` with the same street level: (1 - w) own + w other, variances
    interpolated as variances; street b takes the other point's street b where it has one,
    else its street a. Levels, degrees and positions stay ``own``'s.

    weight : float or (n,) array in [0, 1], the share of ``other``'s style at each point.
    """
    if not len(own) or not len(other):
        return own
    w = np.broadcast_to(np.asarray(weight, dtype=float), (len(own),))[:, None]
    j = _nearest_same_level(own, other)
    src = other.take(j)
    slot_b_ok = src.level[:, 1] >= 0
    out = own.take(np.arange(len(own)))

    def other_slots(values):
        v = values.copy()
        v[:, 1] = np.where(slot_b_ok, values[:, 1], values[:, 0])
        return v

    out.dist_mean = (1 - w) * own.dist_mean + w * other_slots(src.dist_mean)
    out.dist_sd = np.sqrt((1 - w) * own.dist_sd ** 2 + w * other_slots(src.dist_sd) ** 2)
    out.angle_mean = (1 - w) * own.angle_mean + w * other_slots(src.angle_mean)
    out.angle_sd = np.sqrt((1 - w) * own.angle_sd ** 2 + w * other_slots(src.angle_sd) ** 2)
    out.tortuosity = (1 - w) * own.tortuosity + w * other_slots(src.tortuosity)
    w1 = w[:, 0]
    both = np.isfinite(own.area) & np.isfinite(src.area)
    out.area = np.where(both, (1 - w1) * np.where(both, own.area, 0.0)
                        + w1 * np.where(both, src.area, 0.0),
                        np.where(np.isfinite(own.area), own.area, src.area))
    return out


def blend_by_polygons(polygons, weights, default: float):
    """The weight of example B at any location (a function for :func:`blend_points`): the
    weight of the polygon it lies in (a target layer's field, one value per polygon), else
    ``default``; a weight that is no number is ``default`` too.

    >>> w = blend_by_polygons([shapely.box(0, 0, 10, 10)], ["0.8"], 0.25)
    >>> w(np.array([[5.0, 5.0], [50.0, 5.0]])).tolist()
    [0.8, 0.25]
    """
    values = pd.to_numeric(pd.Series(list(weights), dtype=object), errors="coerce")
    values = values.fillna(default).to_numpy(dtype=float)
    if (values < 0).any() or (values > 1).any():
        raise InputError("blend weights must be between 0 and 1")
    tree = shapely.STRtree(np.asarray(polygons, dtype=object))

    def weight(xy):
        out = np.full(len(xy), float(default))
        at, poly = tree.query(shapely.points(xy), predicate="intersects")
        out[at] = values[poly]
        return out

    return weight


def blend_points(a: PointSet, b: PointSet, beta: Union[float, np.ndarray, callable],
                 rng: np.random.Generator, patch: float = 5.0) -> PointSet:
    """Blend two point sets placed over the same target (sec. 4.2, figs. 10-12).

    beta : weight of B in [0, 1]: a number, or a function of (n, 2) locations -> weights
        (a spatially varying blend, e.g. north-south as in fig. 10).
    patch : correlation length of the mixing field, in mean street distances.

    Positions: a smooth random field u(x), uniform on [0, 1], decides at every location
    whose point layout is used: A's points where u >= beta(x), B's where u < beta(x), so a
    share beta of the area takes B's layout (point density and level mix move linearly with
    beta) while each patch keeps a consistent layout of intersections (mixing the points
    one by one would break the streets of both). Attributes: every kept point's street
    statistics are interpolated by the blend weight between its own and those of the
    nearest point of the other example with the same level
    (:func:`interpolate_attributes`): an A point takes (1 - beta) of its own and beta of B's,
    a B point beta of its own and (1 - beta) of A's, so that streets everywhere get
    distances, angles, their variances, tortuosity and parcel sizes between the two
    examples ("interpolate between the styles", sec. 4.2). Points closer than 0.3 x the mean
    street distance to a kept point (at patch seams) are thinned.
    """
    def weights(xy):
        if callable(beta):
            w = np.asarray(beta(xy), dtype=float)
        else:
            w = np.broadcast_to(np.asarray(beta, dtype=float), (len(xy),)).copy()
        if not np.isfinite(w).all() or (w < 0).any() or (w > 1).any():
            raise InputError("blend weights must be between 0 and 1")
        return w

    scale = patch * float(np.median(np.concatenate([a.dist_mean[:, 0], b.dist_mean[:, 0]])))
    both = np.vstack([a.xy, b.xy])
    u = _smooth_uniform(both, scale, rng)
    w = weights(both)
    keep_a = np.flatnonzero(u[:len(a)] >= w[:len(a)])
    keep_b = np.flatnonzero(u[len(a):] < w[len(a):])
    part_a = interpolate_attributes(a.take(keep_a), b, w[:len(a)][keep_a])
    part_b = interpolate_attributes(b.take(keep_b), a, 1.0 - w[len(a):][keep_b])
    mixed = PointSet.concat([part_a, part_b])
    if len(mixed) == 0:
        raise InputError("the blend keeps no point")
    # random priority at the seams, so that thinning favours neither example
    return _thin(mixed, 0.3, order=rng.random(len(mixed)))
