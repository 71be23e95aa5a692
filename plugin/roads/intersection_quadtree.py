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
- places copies of an example's points into a target polygon of any shape, leaf by leaf
  (join / expand, sec. 4.2, :func:`place_points`), and blends two examples with a constant
  or spatially varying weight (:func:`blend_points`): a smooth random field gives a share
  beta of the area to B's points and the rest to A's, so that the expected point density,
  level mix and street statistics at every location are the beta-weighted combination of
  the two examples' leaves there, while each patch keeps its example's street pattern.

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

from ..core.geometry import minimum_rectangle_corners
from ..core.progress import InputError

__all__ = ["REQUIRED_FIELDS", "PointSet", "points_from_table", "points_from_roads",
           "Leaf", "QuadTree", "build_quadtree", "place_points", "blend_points"]

#: Attribute columns a point layer must have (street a; street b is optional per point).
REQUIRED_FIELDS = ("level_a", "dist_mean_a")
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
    source : (n,) int, index of the point in its example (for provenance / evidence)
    example : (n,) int, which example the point comes from (0 = A, 1 = B, -1 = existing)
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

    def __len__(self) -> int:
        return len(self.xy)

    def take(self, idx) -> "PointSet":
        idx = np.asarray(idx)
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
    xy, level = xy[keep], level[keep]
    cols = {k: v[keep] for k, v in cols.items()}
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
    degree = _column(table, "degree")[keep]
    degree = np.where(np.isfinite(degree), np.clip(degree, 1, 4), 4).astype(np.int64)
    area = _column(table, "parcel_area")[keep]
    block_area = _column(table, "block_area")[keep]
    area = np.where(np.isfinite(area), area, block_area)
    n = len(xy)
    return PointSet(xy, level, tort, dist_mean, dist_sd, filled["angle_mean"], angle_sd,
                    degree, area, np.flatnonzero(keep), np.full(n, example, dtype=np.int64))


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
    local = xy @ rot.T
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
        poly = shapely.Polygon(corners @ back.T)
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
                 in_place: Optional[bool] = None, n_offsets: int = 6) -> PointSet:
    """Copies of the example's points that cover ``target`` (join / expand, sec. 4.2).

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
    """
    area = _as_target(target)
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
    if not best:
        raise InputError("no example point falls into the target: the target is smaller than "
                         "the example's street spacing")
    placed = PointSet.concat([points.take(idx).moved(shift) for idx, shift in best])
    # only copies of different tiles can stack at a seam
    return _thin(placed, 0.3) if len(best) > 1 else placed


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
    field = np.sqrt(2.0 / n_waves) * np.cos(xy @ k.T + phase).sum(axis=1)
    return stats.norm.cdf(field)


def blend_points(a: PointSet, b: PointSet, beta: Union[float, np.ndarray, callable],
                 rng: np.random.Generator, patch: float = 5.0) -> PointSet:
    """Blend two point sets placed over the same target (sec. 4.2, figs. 10-12).

    beta : weight of B in [0, 1]: a number, or a function of (n, 2) locations -> weights
        (a spatially varying blend, e.g. north-south as in fig. 10).
    patch : correlation length of the mixing field, in mean street distances.

    A smooth random field u(x), uniform on [0, 1], decides at every location which example
    speaks: A's points where u >= beta(x), B's where u < beta(x). A share beta of the area
    takes B's points, so the expected point density, level mix and street statistics at
    every location are the beta-weighted combination of both examples' quadtree leaves
    there, while each patch keeps the consistent street pattern of its example (mixing the
    points one by one would break the streets of both). Points closer than 0.3 x the mean
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
    keep_a = u[:len(a)] >= w[:len(a)]
    keep_b = u[len(a):] < w[len(a):]
    mixed = PointSet.concat([a.take(np.flatnonzero(keep_a)), b.take(np.flatnonzero(keep_b))])
    if len(mixed) == 0:
        raise InputError("the blend keeps no point")
    # random priority at the seams, so that thinning favours neither example
    return _thin(mixed, 0.3, order=rng.random(len(mixed)))
