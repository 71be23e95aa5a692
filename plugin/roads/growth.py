"""Procedural road growth: street patterns and local constraints (Scharl 2010, ch. 4.2).

Scharl's thesis (ch. 4.2, after Parish & Müller 2001 and Weber et al. 2009) grows a street
network from seed segments with a priority queue of road *proposals*:

1. a production rule proposes an *ideal successor* of a street end: the street continues
   (appending rule) or a new street branches off (new-branch rule) (sec. 4.2.2);
2. the *global goals* of the street pattern set its length and heading: ``organic``
   (random turn of the previous heading), ``grid`` (main directions, exact 90° branches,
   regular block lengths) or ``radial`` (every segment re-oriented to a spoke out of the
   centre or a chord of the circle around it, Figs. 4.3-4.4); a density map makes major
   roads head for population (ray shooting, Fig. 4.5), seeds start where people live and
   growth thins out where nobody does (sec. 4.2.1-4.2.2);
3. the *local constraints* (sec. 4.2.3) adapt the proposal to what is already there or
   drop it: slope correction (rotate until the slope is under ``max_slope``), obstacle
   avoidance (shorten, rotate when too short), intersection (end at the first crossing and
   make a junction), snapping (end at an existing node nearby), extension-intersection
   (extend to a road just ahead), clip to mask, and removal of near-parallel duplicates
   closer than ``min_street_distance`` (``|v_a . v_b| > 0.9``, both ends close-by).

The network grows in two stages (sec. 4.2): major roads over the whole boundary, then the
quarters, the faces of the major network (sec. 4.2.4), are filled with minor roads. Scharl
closes the outskirts with a *bulged convex hull* (sec. 4.2.5) so that minor roads also
reach the city edge: when no boundary is given (growth is then bounded by the DEM's or the
density map's extent, or around the sketched roads), the convex hull of the major nodes
has each side split into four with the three new nodes pushed away from its barycentre by
a random amount (:func:`bulged_hull`), the quarters are the faces of the major roads
closed by that outline, and the outline is dropped once they are filled. With a boundary,
the boundary itself plays that role: the quarters are the faces of the major roads
together with the boundary's rings, so the outskirts (the boundary minus the major faces)
become quarters too, split where major roads reach the boundary. At the end, dead-end
roads are removed (Fig. 4.12; ``remove_dead_ends``), and pieces of the network that reach
no sketched road (or, without a sketch, the longest piece) are joined to it by the shortest
straight minor road that crosses nothing (:func:`link_pieces`; not in Scharl, whose growth
starts from one network; a boundary of several parts apart grows a piece in each). Each
quarter gets a seed street at its barycentre (sec. 4.2.1); places left farther than
``GAP_FACTOR`` segment lengths from every road get further seeds (Scharl's random fallback
seeds, scored by their distance to the roads).

Slopes are exact for the bilinear DEM surface (:func:`segment_slopes`): no sampling of a
grown segment, at any spacing, finds a grade over ``max_slope``.

Proposals never test all segments pairwise: segments are kept in a uniform grid hash
(a dict of cell -> segment ids, cell size about one minor segment), and every proposal
checks only the few segments in the cells its reach covers, with vectorised numpy.
Junctions split the segment they land on, so every junction is a vertex shared exactly by
the segments that meet there and the network is planar by construction;
:func:`roads.clean_network` nodes it once more at the end as a safety net.

References
----------
Scharl, S. (2010). Artist-controlled urban modeling (thesis), ch. 4.2.1-4.2.5.
Parish, Y., Müller, P. (2001). Procedural modeling of cities. SIGGRAPH, sec. 3.
Weber, B., Müller, P., Wonka, P., Gross, M. (2009). Interactive geometric simulation of
    4D cities. Eurographics, sec. 4.
"""
from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Tuple

import numpy as np
import pandas as pd
import shapely

from ..core.progress import InputError, Progress, ensure
from ..core.geometry import minimum_rectangles, two_point_segments
from ..network.blocks import planar_faces
from ..network.links import link_floating_pieces
from ..network.street_graph import clean_network, node_lines, renode
from ..retrieval.shape_context import DemGrid

__all__ = [
    "PATTERNS", "MAJOR", "MINOR", "ROAD_CLASSES", "MIN_ANGLE", "MAX_DEGREE", "GAP_FACTOR",
    "GrowthSettings", "GrowthResult", "grow_roads", "bulged_hull", "remove_dead_ends",
    "segment_slopes", "chord_slopes",
    "network_statistics", "mask_polygons",
]

#: Street patterns of Scharl sec. 4.2.2 ("basic" is called organic here).
PATTERNS = ("organic", "grid", "radial")
#: Hierarchy levels of the output (``level`` field): 0 major, 1 minor.
MAJOR, MINOR = 0, 1
ROAD_CLASSES = ("major", "minor")
#: Smallest angle (degrees) between two streets at a node; sharper junctions are dropped.
MIN_ANGLE = 30.0
#: Most streets per crossing (Scharl sec. 4.2.2 limits the streets per crossing).
MAX_DEGREE = 4
#: Scharl's test for near-parallel streets: |v_a . v_b| > 0.9 (sec. 4.2.3).
PARALLEL_COS = 0.9
#: A region farther than this many segment lengths from every road gets another seed.
GAP_FACTOR = 0.75

_SKETCH = 3  # pattern code of user-sketched major roads
_PATTERN_NAMES = PATTERNS + ("sketch",)
# proposal kinds
_SEED, _CONTINUE, _BRANCH = 0, 1, 2
# end kinds of a placed segment
_FREE, _NODE, _SPLIT, _CLIP = 0, 1, 2, 3
# the limit is checked less this share: rounding must not let a grade of 12.0000001 % pass
_SLOPE_MARGIN = 1e-6
# segments may poke this far (m) out of their quarter: a junction computed on a road along
# the quarter's edge lies on it only to rounding (1e-9 m at 10^7 m coordinates)
_MASK_TOLERANCE = 1e-7
_EPS = 1e-9


# --------------------------------------------------------------------------- settings

@dataclass
class GrowthSettings:
    """Parameters of :func:`grow_roads` (Scharl sec. 4.2.2-4.2.3).

    Attributes
    ----------
    major_pattern, minor_pattern : one of :data:`PATTERNS`
    major_length, minor_length : float
        Nominal segment length (m) of major and minor roads: about one block side.
    length_deviation : float
        Segment length = length x (1 ± u x deviation), u uniform in [0, 1] (Scharl's
        ``lengthDeviation``, as a share). Grid roads use a fifth of it (regular blocks).
    angle_deviation : float
        Largest random turn (degrees) of an organic street per segment and of an organic
        branch away from 90° (Scharl's ``maximumAngle``). Grid and radial streets keep
        their directions (grid: a tenth of it, at most 2°; radial: re-oriented exactly).
    branch_probability : float
        Chance that a new street branches off each side of a street end.
    snap_distance : float
        A street end this close (m) to a node snaps to it, to a road this close ahead is
        extended to it, and no street end stays this close to a road without meeting it.
    min_street_distance : float
        Near-parallel streets closer than this (m) are duplicates: the new one is dropped.
    max_segments : int
        Safety cap on the segments grown (both stages together).
    max_slope : float
        Steepest allowed grade of a grown segment as rise over run (0.12 = 12 %), checked
        on the DEM when one is given.
    max_turn : float
        Largest rotation (degrees) tried by slope correction and obstacle avoidance.
    major_width, minor_width : float
        Street width (m) written to the output (Scharl grows widths like lengths; the
        surface is built by ``tessellatestreets``).
    grow_major : bool
        Grow major roads; False keeps only the sketched major roads (artist control).
    fill_quarters : bool
        Fill the quarters with minor roads.
    remove_dead_ends : bool
        Remove dead-end roads at the end of growth (Scharl Fig. 4.12: "the final street
        network with ... dead end roads removed"): grown edges with a free end are pruned
        until every grown street ends at a junction; sketched roads are kept.
    """

    major_pattern: str = "grid"
    minor_pattern: str = "grid"
    major_length: float = 150.0
    minor_length: float = 60.0
    length_deviation: float = 0.25
    angle_deviation: float = 20.0
    branch_probability: float = 0.6
    snap_distance: float = 15.0
    min_street_distance: float = 20.0
    max_segments: int = 20000
    max_slope: float = 0.12
    max_turn: float = 45.0
    major_width: float = 14.0
    minor_width: float = 8.0
    grow_major: bool = True
    fill_quarters: bool = True
    remove_dead_ends: bool = True

    def validated(self) -> "GrowthSettings":
        """The settings, or :class:`InputError` naming the first absurd value."""
        for name in ("major_pattern", "minor_pattern"):
            if getattr(self, name) not in PATTERNS:
                raise InputError(f"{name} must be one of {', '.join(PATTERNS)}, "
                                 f"not {getattr(self, name)!r}")
        for name in ("major_length", "minor_length"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 5.0 <= v <= 10_000.0):
                raise InputError(f"{name} = {v} m is absurd: use 5 to 10,000 m")
        checks = [("length_deviation", 0.0, 0.9), ("angle_deviation", 0.0, 90.0),
                  ("branch_probability", 0.0, 1.0), ("snap_distance", 0.0, None),
                  ("min_street_distance", 0.0, None), ("max_slope", 1e-3, 10.0),
                  ("max_turn", 0.0, 90.0), ("major_width", 0.0, 200.0),
                  ("minor_width", 0.0, 200.0)]
        for name, lo, hi in checks:
            v = getattr(self, name)
            if not math.isfinite(v) or v < lo or (hi is not None and v > hi):
                top = hi if hi is not None else "inf"
                raise InputError(f"{name} = {v} is outside {lo} .. {top}")
        shortest = min(self.major_length, self.minor_length)
        if self.snap_distance >= 0.5 * shortest:
            raise InputError(f"snap_distance = {self.snap_distance} m must be under half the "
                             f"shortest segment length ({0.5 * shortest:g} m): every street "
                             "end would snap back")
        if self.min_street_distance >= shortest:
            raise InputError(f"min_street_distance = {self.min_street_distance} m must be "
                             f"under the shortest segment length ({shortest:g} m)")
        if int(self.max_segments) < 1:
            raise InputError("max_segments must be at least 1")
        return replace(self, max_segments=int(self.max_segments))


@dataclass
class GrowthResult:
    """Result of :func:`grow_roads`.

    Attributes
    ----------
    geometry : ndarray of LineString
        Planar, noded street edges (metric CRS), one per grown segment or piece of one
        between junctions; degree-2 chains are not merged, so every edge is straight.
    level : int array (0 major, 1 minor)
    pattern : object array, the pattern that grew the edge ('sketch' for sketched roads)
    width : float array (m)
    stats : dict
        ``segments`` (grown, before cleaning), ``major_segments``, ``minor_segments``,
        ``sketched_segments``, ``proposals``, ``rejected`` (per reason), ``quarters``,
        ``seeds``, ``capped`` (the max_segments cap was hit), ``seconds``.
    """

    geometry: np.ndarray
    level: np.ndarray
    pattern: np.ndarray
    width: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def road_class(self) -> np.ndarray:
        return np.array(ROAD_CLASSES, dtype=object)[self.level]

    @property
    def length(self) -> np.ndarray:
        return shapely.length(self.geometry)

    def table(self) -> pd.DataFrame:
        """Attributes per edge: level, road_class, pattern, width_m, length_m."""
        return pd.DataFrame({"level": self.level, "road_class": self.road_class,
                             "pattern": self.pattern, "width_m": self.width,
                             "length_m": self.length})


# --------------------------------------------------------------------------- helpers

def _as_grid(raster, what: str) -> Optional[DemGrid]:
    if raster is None or isinstance(raster, DemGrid):
        return raster
    try:
        array, geotransform = raster
    except (TypeError, ValueError):
        raise InputError(f"the {what} must be a DemGrid or (array, geotransform)") from None
    return DemGrid(np.asarray(array, dtype=np.float64), geotransform)


def mask_polygons(mask: np.ndarray, geotransform) -> np.ndarray:
    """Polygons covering the true cells of a raster mask (an obstacle raster).

    Runs of true cells in each row become one rectangle (numpy run-length coding), and the
    rectangles are unioned: far fewer geometries than one box per cell.

    Parameters
    ----------
    mask : (rows, cols) bool array
    geotransform : GDAL geotransform (x0, dx, 0, y0, 0, dy) of the grid (north up)

    Returns
    -------
    ndarray of Polygon (empty when no cell is set)
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return np.empty(0, dtype=object)
    x0, dx, _, y0, _, dy = geotransform
    padded = np.pad(mask, ((0, 0), (1, 1))).astype(np.int8)
    change = np.diff(padded, axis=1)
    rows_s, cols_s = np.nonzero(change == 1)   # a run starts at this column
    rows_e, cols_e = np.nonzero(change == -1)  # and ends before this one
    # np.nonzero walks row by row, so starts and ends pair up in order
    boxes = shapely.box(x0 + cols_s * dx, y0 + rows_s * dy, x0 + cols_e * dx, y0 + (rows_e + 1) * dy)
    merged = shapely.union_all(boxes)
    return shapely.get_parts(merged)


def _as_area(geoms, what: str, required: bool):
    """Union of polygons (one geometry or an array), valid; None when nothing was given."""
    if geoms is None:
        if required:
            raise InputError(f"no {what} polygon")
        return None
    arr = np.atleast_1d(np.asarray(geoms, dtype=object))
    arr = arr[~(shapely.is_missing(arr) | shapely.is_empty(arr))] if len(arr) else arr
    if len(arr):
        arr = shapely.get_parts(arr)
        arr = arr[shapely.get_dimensions(arr) == 2]
    if len(arr) == 0:
        if required:
            raise InputError(f"the {what} has no polygon with an area")
        return None
    area = shapely.union_all(shapely.make_valid(arr))
    area = shapely.union_all([p for p in shapely.get_parts(area)
                              if shapely.get_dimensions(p) == 2])
    if area.is_empty or area.area <= 0:
        if required:
            raise InputError(f"the {what} has no area")
        return None
    return area


def _max_grade(dem: DemGrid, px: float, py: float, ex: float, ey: float) -> float:
    """Steepest grade along the straight segment P -> E on the bilinear DEM surface, exactly.

    Between the lines through the cell centres the bilinear surface is a quadratic in the
    distance along a straight segment, so its slope is linear there: the steepest slope is
    at a piece's ends, found from the heights at the ends and the middle of each piece.
    Any sampling of the segment (chords of any length) finds a grade at most this.
    """
    length = math.hypot(ex - px, ey - py)
    if length <= 0:
        return 0.0
    x0, dx, _, y0, _, dy = dem.geotransform
    rows, cols = dem.array.shape
    c0, c1 = (px - x0) / dx - 0.5, (ex - x0) / dx - 0.5
    r0, r1 = (py - y0) / dy - 0.5, (ey - y0) / dy - 0.5
    cuts = [np.array([0.0, 1.0])]
    for a0, a1, n in ((c0, c1, cols), (r0, r1, rows)):
        lo, hi = max(min(a0, a1), 0.0), min(max(a0, a1), n - 1.0)
        if a1 != a0 and hi >= lo:
            k = np.arange(math.ceil(lo), math.floor(hi) + 1, dtype=np.float64)
            cuts.append((k - a0) / (a1 - a0))
    t = np.unique(np.clip(np.concatenate(cuts), 0.0, 1.0))
    mid = 0.5 * (t[1:] + t[:-1])
    tt = np.concatenate([t, mid])
    z = dem(np.column_stack([px + tt * (ex - px), py + tt * (ey - py)]))
    z0, z1, zm = z[:len(t) - 1], z[1:len(t)], z[len(t):]
    span = np.diff(t) * length
    ok = span > 1e-9 * length
    g = np.concatenate([np.abs(-3 * z0 + 4 * zm - z1)[ok] / span[ok],
                        np.abs(z0 - 4 * zm + 3 * z1)[ok] / span[ok]])
    g = g[np.isfinite(g)]
    return float(g.max()) if len(g) else 0.0


def segment_slopes(lines, dem) -> np.ndarray:
    """Steepest grade (rise over run) along each line on the bilinear DEM surface.

    Exact for the bilinear interpolation of :class:`DemGrid` (see :func:`_max_grade`): a
    grade sampled along the line at any spacing is at most this. Stretches over no-data
    cells count as flat.

    Parameters
    ----------
    lines : array of LineString, metric CRS of the DEM
    dem : DemGrid or (array, geotransform)

    Returns
    -------
    float array, one grade per line
    """
    dem = _as_grid(dem, "DEM")
    lines = np.asarray(lines, dtype=object)
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    out = np.zeros(len(lines))
    for k in np.flatnonzero(idx[1:] == idx[:-1]):
        g = _max_grade(dem, coords[k, 0], coords[k, 1], coords[k + 1, 0], coords[k + 1, 1])
        out[idx[k]] = max(out[idx[k]], g)
    return out


def chord_slopes(lines, dem, step: float) -> np.ndarray:
    """Steepest grade of each line over chords of ``step`` metres (DEM sampled every step)."""
    dem = _as_grid(dem, "DEM")
    lines = shapely.segmentize(np.asarray(lines, dtype=object), step)
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    z = dem(coords)
    same = idx[1:] == idx[:-1]
    ds = np.hypot(*np.diff(coords, axis=0).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.abs(np.diff(z)) / ds
    g = np.where(same & (ds > 0) & np.isfinite(g), g, 0.0)
    out = np.zeros(len(lines))
    np.maximum.at(out, idx[1:], g)
    return out


def _end_gap2(za: np.ndarray, zb: np.ndarray, length: float):
    """Squared distance from a new street's end (``length`` along its heading, in the
    heading frame) to each road segment za-zb (complex, same frame), the segments' squared
    lengths (a segment of length 0 gives NaN), the nearest points and their fractions along
    the segments."""
    e = zb - za
    l2 = e.real * e.real + e.imag * e.imag
    w = length - za
    u = np.clip((w.real * e.real + w.imag * e.imag) / l2, 0.0, 1.0)
    q = za + u * e
    return (q.real - length) ** 2 + q.imag * q.imag, l2, q, u


def _wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    return (a + math.pi) % (2 * math.pi) - math.pi


# --------------------------------------------------------------------------- stages

@dataclass
class _Stage:
    """One growth stage: a level, its pattern and the region it may fill."""

    level: int
    pattern: int            # index into PATTERNS
    length: float
    mask: object            # prepared polygon the segments must lie in
    mask_tol: object        # the mask grown by _MASK_TOLERANCE
    axis: float = 0.0       # grid: main direction (radians)
    min_length: float = 0.0
    reach: float = 0.0      # extension-intersection distance
    halfplanes: Optional[list] = None  # (nx, ny, c) per edge of a convex mask: n.x <= c
    count: int = 0          # segments grown in this stage


class _Grower:
    """The street graph under construction, its spatial hash and the proposal queue."""

    def __init__(self, boundary, free, obstacles, settings: GrowthSettings, rng,
                 dem: Optional[DemGrid], density: Optional[DemGrid], center):
        self.s = settings
        self.rng = rng
        self.boundary = boundary
        self.free = free                       # boundary minus obstacles
        self.obstacles = obstacles
        if obstacles is not None:
            shapely.prepare(obstacles)
        self.dem = dem
        self.density = density
        self.dmax = 1.0                        # density normalisation (set by grow_roads)
        self.center = np.asarray(center, dtype=np.float64)
        self.dev = math.radians(settings.angle_deviation)
        self.max_slope = settings.max_slope * (1.0 - _SLOPE_MARGIN)
        self.cos_min = math.cos(math.radians(MIN_ANGLE))
        self.sin_min = math.sin(math.radians(MIN_ANGLE))
        # node store
        cap = 1024
        self.xy = np.empty((cap, 2))
        self.z = np.empty(cap, dtype=np.complex128)  # the same points as complex numbers
        self.n_nodes = 0
        self.inc: list = []                    # incident segment ids per node
        # segment store
        self.su = np.empty(cap, dtype=np.int64)
        self.sv = np.empty(cap, dtype=np.int64)
        self.slevel = np.empty(cap, dtype=np.int8)
        self.spattern = np.empty(cap, dtype=np.int8)
        self.n_segs = 0
        self.n_grown = 0
        self.grown = [0, 0]                    # grown segments per level
        # uniform grid hash of segments: cell -> list of segment ids
        x0, y0, x1, y1 = boundary.bounds
        self.cell = max(min(settings.major_length, settings.minor_length),
                        2.0 * max(settings.snap_distance, settings.min_street_distance), 1.0)
        self.origin = (x0 - 2 * self.cell, y0 - 2 * self.cell)
        self.ny = int((y1 - y0) / self.cell) + 6
        self.grid: dict = {}
        self.heap: list = []
        self.counter = 0
        self.proposals = 0
        self.rejected: dict = {}
        self.seeds = 0
        self.capped = False
        self._zero = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ stores

    def add_node(self, x: float, y: float) -> int:
        n = self.n_nodes
        if n == len(self.xy):
            self.xy = np.concatenate([self.xy, np.empty_like(self.xy)])
            self.z = np.concatenate([self.z, np.empty_like(self.z)])
        self.xy[n, 0] = x
        self.xy[n, 1] = y
        self.z[n] = complex(x, y)
        self.inc.append([])
        self.n_nodes = n + 1
        return n

    def _cells(self, x0, y0, x1, y1):
        ox, oy = self.origin
        c = self.cell
        return (int((x0 - ox) // c), int((y0 - oy) // c), int((x1 - ox) // c), int((y1 - oy) // c))

    def _register(self, sid: int) -> None:
        a, b = self.xy[self.su[sid]], self.xy[self.sv[sid]]
        i0, j0, i1, j1 = self._cells(min(a[0], b[0]), min(a[1], b[1]),
                                     max(a[0], b[0]), max(a[1], b[1]))
        grid, ny = self.grid, self.ny
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                cell = grid.get(i * ny + j)
                if cell is None:
                    grid[i * ny + j] = [sid]
                else:
                    cell.append(sid)

    def add_segment(self, u: int, v: int, level: int, pattern: int) -> int:
        k = self.n_segs
        if k == len(self.su):
            for name in ("su", "sv", "slevel", "spattern"):
                arr = getattr(self, name)
                setattr(self, name, np.concatenate([arr, np.empty_like(arr)]))
        self.su[k], self.sv[k] = u, v
        self.slevel[k], self.spattern[k] = level, pattern
        self.n_segs = k + 1
        self.inc[u].append(k)
        self.inc[v].append(k)
        self._register(k)
        return k

    def split_segment(self, sid: int, node: int) -> None:
        """Split segment ``sid`` at ``node`` (a point on it): junctions are shared vertices."""
        b = int(self.sv[sid])
        self.sv[sid] = node
        self.inc[b].remove(sid)
        self.inc[node].append(sid)
        self.add_segment(node, b, int(self.slevel[sid]), int(self.spattern[sid]))

    def query(self, x0, y0, x1, y1) -> np.ndarray:
        """Ids of segments registered in the cells overlapping a box (a superset)."""
        i0, j0, i1, j1 = self._cells(x0, y0, x1, y1)
        grid, ny = self.grid, self.ny
        ids = []
        for i in range(i0, i1 + 1):
            base = i * ny
            for j in range(j0, j1 + 1):
                cell = grid.get(base + j)
                if cell is not None:
                    ids.extend(cell)
        if not ids:
            return self._zero
        return np.array(list(dict.fromkeys(ids)), dtype=np.int64)  # unique, in a fixed order

    def lines(self, sel=None) -> np.ndarray:
        n = self.n_segs
        idx = np.arange(n) if sel is None else np.asarray(sel)
        pts = np.stack([self.xy[self.su[idx]], self.xy[self.sv[idx]]], axis=1)
        return shapely.linestrings(pts) if len(idx) else np.empty(0, dtype=object)

    # ------------------------------------------------------------------ rasters

    def dens(self, x: float, y: float) -> float:
        """Normalised population density in [0, 1] (1 without a density map)."""
        if self.density is None:
            return 1.0
        v = float(self.density(np.array([x, y])))
        return min(max(v / self.dmax, 0.0), 1.0) if math.isfinite(v) else 0.0

    def slope(self, px, py, ex, ey) -> float:
        return _max_grade(self.dem, px, py, ex, ey)

    # ------------------------------------------------------------------ global goals

    def seg_length(self, st: _Stage, d: float) -> float:
        dev = self.s.length_deviation * (0.2 if st.pattern == 1 else 1.0)
        length = st.length * (1.0 + dev * self.rng.uniform(-1.0, 1.0))
        if self.density is not None:
            # dense areas get shorter blocks (Weber 2009: block size follows density)
            length *= 1.3 - 0.6 * d
        return length

    def ideal(self, st: _Stage, x: float, y: float, heading: float, turn: float,
              length: float) -> Optional[float]:
        """Heading of the ideal successor (Scharl sec. 4.2.2), None if the pattern has none."""
        pattern = st.pattern
        if pattern == 1:  # grid: main directions, exact right-angle branches
            base = heading + turn
            k = round((base - st.axis) / (0.5 * math.pi))
            jitter = min(0.1 * self.dev, math.radians(2.0))
            return st.axis + k * 0.5 * math.pi + self.rng.uniform(-jitter, jitter)
        if pattern == 0:  # organic: random turn, branches at varied angles
            h = heading + turn + self.rng.uniform(-self.dev, self.dev)
            if self.density is not None and st.level == MAJOR and turn == 0.0:
                h = self._toward_population(x, y, h, length)
            return h
        # radial: re-orient to a spoke or to a chord of the circle around the centre
        rx, ry = x - self.center[0], y - self.center[1]
        r = math.hypot(rx, ry)
        base = heading + turn
        if r < 1e-6:
            return base
        phi = math.atan2(ry, rx)
        diff = _wrap(base - phi)
        if abs(math.cos(diff)) >= math.sqrt(0.5):
            return phi if math.cos(diff) > 0 else phi + math.pi
        if length >= r:  # Scharl: the circles C1, C2 do not meet usefully: no segment
            return None
        half = math.asin(length / (2.0 * r))
        return phi + math.copysign(0.5 * math.pi + half, math.sin(diff))

    def _toward_population(self, x, y, h, length) -> float:
        """Parish & Müller's ray shooting: the heading whose rays see the most people."""
        best, best_v = h, -1.0
        for k in range(5):
            cand = h + (k - 2) * 0.5 * self.dev
            v = 0.0
            for r in (1.0, 2.0, 3.0):
                v += self.dens(x + r * length * math.cos(cand),
                               y + r * length * math.sin(cand)) / r
            if v > best_v:
                best, best_v = cand, v
        return best

    # ------------------------------------------------------------------ queue

    def push(self, priority: float, node: int, heading: float, length: float, kind: int) -> None:
        """Queue a proposal; equal priorities keep their order (a counter breaks ties)."""
        self.counter += 1
        heapq.heappush(self.heap, (priority, self.counter, node, heading, length, kind))

    def successors(self, st: _Stage, e: int, heading: float, priority: float) -> None:
        """Production rules at a free street end: continue, branch left, branch right."""
        x, y = self.xy[e]
        d = self.dens(x, y)
        grow = 1.0 if self.density is None else min(1.0, 2.0 * d)
        rng = self.rng
        if rng.random() < grow:
            length = self.seg_length(st, d)
            h = self.ideal(st, x, y, heading, 0.0, length)
            if h is not None:
                self.push(priority + 1.0, e, h, length, _CONTINUE)
        p = self.s.branch_probability * grow
        for side in (1.0, -1.0):
            if rng.random() < p:
                turn = side * 0.5 * math.pi
                length = self.seg_length(st, d)
                h = self.ideal(st, x, y, heading, turn, length)
                if h is not None:
                    # branches wait a step: streets grow before they branch (P&M 2001)
                    self.push(priority + 2.0, e, h, length, _BRANCH)

    def seed(self, st: _Stage, x: float, y: float, priority: float = 0.0) -> None:
        """A seed street at (x, y): proposals in opposite directions (Scharl sec. 4.2.1)."""
        self.seeds += 1
        n = self.add_node(x, y)
        d = self.dens(x, y)
        length = self.seg_length(st, d)
        if st.pattern == 1:
            h0 = st.axis
        elif st.pattern == 2:
            rx, ry = x - self.center[0], y - self.center[1]
            if math.hypot(rx, ry) < 0.5 * length:
                # at the centre: spokes in every direction
                k = 6
                h0 = self.rng.uniform(0, 2 * math.pi / k)
                for i in range(k):
                    self.push(priority, n, h0 + 2 * math.pi * i / k, self.seg_length(st, d),
                              _SEED)
                return
            h0 = math.atan2(ry, rx)  # a spoke through the seed
        else:
            h0 = self.rng.uniform(0, 2 * math.pi)
        self.push(priority, n, h0, length, _SEED)
        self.push(priority, n, h0 + math.pi, self.seg_length(st, d), _SEED)
        # the seed street's middle is a street node like any other: it may branch
        p = self.s.branch_probability * (1.0 if self.density is None else min(1.0, 2.0 * d))
        for side in (1.0, -1.0):
            if self.rng.random() < p:
                length = self.seg_length(st, d)
                h = self.ideal(st, x, y, h0, side * 0.5 * math.pi, length)
                if h is not None:
                    self.push(priority + 2.0, n, h, length, _BRANCH)

    def run(self, st: _Stage, progress: Progress, expected: float) -> None:
        """Grow until the queue is empty or the segment cap is reached."""
        heap = self.heap
        cap = self.s.max_segments
        while heap:
            if self.n_grown >= cap:
                self.capped = True
                heap.clear()
                return
            priority, _, node, heading, length, kind = heapq.heappop(heap)
            self.proposals += 1
            if self.proposals % 128 == 0:
                progress.step(min(st.count / max(expected, 1.0), 1.0))
            res = self.place(st, node, heading, length, kind == _SEED)
            if res is None:
                continue
            end, end_kind, h = res
            st.count += 1
            self.n_grown += 1
            self.grown[st.level] += 1
            if end_kind == _FREE:
                self.successors(st, end, h, priority)

    # ------------------------------------------------------------------ local constraints

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def headings(self, heading: float):
        yield heading
        if self.dem is None and self.obstacles is None:
            return
        step = math.radians(5.0)
        n = int(math.radians(self.s.max_turn) / step + 1e-9)
        sign = 1.0 if self.rng.random() < 0.5 else -1.0
        for k in range(1, n + 1):
            yield heading + sign * k * step
            yield heading - sign * k * step

    def place(self, st: _Stage, p: int, heading: float, length: float, is_seed: bool):
        """Apply the local constraints to one proposal; commit the segment if one is left.

        Returns (end node, end kind, heading) or None when the proposal is dropped.
        """
        if not is_seed and len(self.inc[p]) >= MAX_DEGREE:
            self._reject("degree")
            return None
        reason = "none"
        grad = None
        if self.dem is not None:
            # the terrain gradient at the start skips headings that are plainly too steep
            # (1.5 x the limit) without the exact test; the exact test decides the rest
            c = self.dem.cell_size
            x, y = self.xy[p]
            z = self.dem(np.array([[x + c, y], [x - c, y], [x, y + c], [x, y - c]]))
            grad = np.nan_to_num((z[0] - z[1]) / (2 * c)), np.nan_to_num((z[2] - z[3]) / (2 * c))
        for h in self.headings(heading):
            if grad is not None and abs(grad[0] * math.cos(h) + grad[1] * math.sin(h)) \
                    > 1.5 * self.max_slope:
                reason = "slope"
                continue
            res, reason = self._place_heading(st, p, h, length)
            if res is not None:
                return res
            if reason not in ("slope", "obstacle"):
                break  # only slope and obstacles make a street turn (Scharl sec. 4.2.3)
        self._reject(reason)
        return None

    # Geometry below works in the frame of the street being placed: complex coordinates
    # multiplied by conj(direction) put the street's start at 0 and its heading along +x,
    # so that "crosses the street" is a sign change of the imaginary part and distances to
    # it are |imag|; this keeps each proposal to a few dozen numpy calls.

    def _place_heading(self, st: _Stage, p: int, h: float, length: float):
        """Local constraints for one heading; returns (commit result or None, reason)."""
        s = self.s
        P = complex(self.z[p])
        px, py = P.real, P.imag
        dx, dy = math.cos(h), math.sin(h)
        if self.dem is not None and self.slope(px, py, px + dx * st.min_length,
                                               py + dy * st.min_length) > self.max_slope:
            return None, "slope"  # too steep from the start: turn before any other test
        rot = complex(dx, -dy)
        reach = length + st.reach
        r = max(s.snap_distance, s.min_street_distance)
        qx, qy = px + dx * reach, py + dy * reach
        cand = self.query(min(px, qx) - r, min(py, qy) - r, max(px, qx) + r, max(py, qy) + r)
        a, b = self.su[cand], self.sv[cand]
        Za, Zb = self.z[a], self.z[b]
        at_p = (a == p) | (b == p)
        ctx = (cand, a, b, Za, Zb, at_p)
        za, zb = (Za - P) * rot, (Zb - P) * rot
        frame = (za, zb)

        # intersection along the ray: the first crossing ends the street at a junction
        ya, yb = za.imag, zb.imag
        den = yb - ya
        hit = (ya * yb <= 0.0) & (den != 0.0) & ~at_p
        tc = math.inf
        if hit.any():
            u = -ya / den
            t = za.real + u * (zb.real - za.real)
            hit &= (t > 1e-6) & (t <= reach)
            if hit.any():
                i = int(np.argmin(np.where(hit, t, np.inf)))
                tc, jc, uc = float(t[i]), int(cand[i]), float(u[i])

        # candidate ends in order of preference: (kind, end, target, in heading frame); a
        # new node (split or free end) is only offered where no node is within the snap
        # distance: it would have snapped to it (Scharl: snapping "is used to prevent
        # close-by crossings of streets")
        heading = complex(dx, dy)
        options = []
        if tc <= length:
            snaps, crowded = self._near_nodes(p, complex(tc, 0.0), frame, ctx)
            options += snaps
            if not crowded:
                options.append(self._junction(jc, uc, P + tc * heading, True))
        else:
            near = False
            if len(cand):
                # distance of the street end to every road: a street end near a road meets
                # it at the nearest point (P&M 2001) and does not stop short of it
                d2, l2, q, uu = _end_gap2(za, zb, length)
                d2[at_p | ~(l2 > 0)] = np.inf
                i = int(np.argmin(d2))
                near = d2[i] < s.snap_distance ** 2
            crowded = False
            if near:  # a node can only be this close if a road is
                snaps, crowded = self._near_nodes(p, complex(length, 0.0), frame, ctx)
                options += snaps
            if tc <= reach:  # extension-intersection
                snaps, crowded_x = self._near_nodes(p, complex(tc, 0.0), frame, ctx)
                options += snaps
                if not crowded_x:
                    options.append(self._junction(jc, uc, P + tc * heading, True))
            if near:
                if not crowded:
                    world = P + complex(q[i]) * heading
                    options.append(self._junction(int(cand[i]), float(uu[i]), world, False))
            else:
                options.append((_FREE, P + length * heading, -1, True))

        reasons = []
        clipped = False
        i = 0
        while i < len(options):
            kind, E, target, on_ray = options[i]
            i += 1
            why = self._check(st, p, P, kind, E, target, frame if on_ray else None, ctx)
            if why is None:
                return self._commit(st, p, kind, E, target), None
            reasons.append(why)
            if why == "mask" and on_ray and not clipped:
                clipped = True  # clip to mask, once per heading
                t_free = self._clip(st, px, py, dx, dy, max(length, min(tc, reach)))
                if t_free is None:
                    continue
                if isinstance(t_free, str):
                    reasons.append(t_free)
                else:
                    snaps, crowded = self._near_nodes(p, complex(t_free, 0.0), frame, ctx)
                    options += snaps
                    if not crowded:
                        options.append((_CLIP, P + t_free * heading, -1, True))
        for why in ("slope", "obstacle"):
            if why in reasons:
                return None, why
        return None, reasons[-1] if reasons else "near"

    def _junction(self, j: int, u: float, E: complex, on_ray: bool):
        """A junction on segment j: its end node when the point is on one, else a split."""
        if u <= _EPS:
            n = int(self.su[j])
            return (_NODE, complex(self.z[n]), n, False)
        if u >= 1 - _EPS:
            n = int(self.sv[j])
            return (_NODE, complex(self.z[n]), n, False)
        return (_SPLIT, E, j, on_ray)

    def _near_nodes(self, p: int, Q: complex, frame, ctx):
        """Snapping: existing nodes within the snap distance of a street end, nearest first.

        Returns (options, crowded): ``crowded`` is True when any node other than p is
        that close (even one that cannot be snapped to), so no new node may go there.
        """
        cand, a, b = ctx[:3]
        if len(cand) == 0 or self.s.snap_distance <= 0:
            return [], False
        za, zb = frame
        snap2 = self.s.snap_distance ** 2
        da, db = za - Q, zb - Q
        d2 = np.concatenate([da.real ** 2 + da.imag ** 2, db.real ** 2 + db.imag ** 2])
        nodes = np.concatenate([a, b])
        sel = (d2 <= snap2) & (nodes != p)
        if not sel.any():
            return [], False
        nodes = nodes[sel]
        order = np.argsort(d2[sel], kind="stable")
        out, seen = [], {p}
        su, sv = self.su, self.sv
        for k in self.inc[p]:  # an edge p-n already exists: no duplicate edge
            seen.add(int(su[k]))
            seen.add(int(sv[k]))
        for n in nodes[order][:6].tolist():
            if n not in seen:
                seen.add(n)
                out.append((_NODE, complex(self.z[n]), n, False))
        return out, True

    def _clip(self, st: _Stage, px, py, dx, dy, length):
        """Clip to mask: the distance at which the street leaves the region it may fill.

        Returns it, None when the street leaves too soon, or 'obstacle' when it is too
        short because an obstacle is in the way (then the street tries to turn).
        """
        line = shapely.LineString([(px, py), (px + dx * length, py + dy * length)])
        inside = shapely.intersection(line, st.mask)
        t_free = 0.0
        for part in shapely.get_parts(inside):
            if shapely.get_type_id(part) != 1 or shapely.is_empty(part):
                continue
            c = shapely.get_coordinates(part)
            for k0, k1 in ((0, -1), (-1, 0)):  # the piece that starts at the street's start
                if math.hypot(c[k0, 0] - px, c[k0, 1] - py) < 1e-6:
                    t_free = max(t_free, math.hypot(c[k1, 0] - px, c[k1, 1] - py))
        if t_free >= st.min_length:
            return t_free
        if self.obstacles is not None:
            x, y = px + dx * t_free, py + dy * t_free
            if self.obstacles.distance(shapely.Point(x, y)) < 1e-6:
                return "obstacle"
        return None

    def _check(self, st: _Stage, p, P: complex, kind, E: complex, target, frame,
               ctx) -> Optional[str]:
        """Why the segment P -> E breaks a local constraint, or None if it is fine.

        ``frame`` holds the candidates in the frame of the heading when E lies on it (the
        ray test then already proved that nothing crosses P -> E).
        """
        s = self.s
        cand, a, b, Za, Zb, at_p = ctx
        V = E - P
        length = abs(V)
        if length < st.min_length:
            return "short"
        rot = V.conjugate() / length
        z, su, sv, inc = self.z, self.su, self.sv, self.inc
        # junction angles: no street meets another at less than MIN_ANGLE
        cos_min = self.cos_min
        for k in inc[p]:
            w = complex(z[sv[k] if su[k] == p else su[k]]) - P
            if (w * rot).real > cos_min * abs(w):
                return "angle"
        if kind == _NODE:
            if len(inc[target]) >= MAX_DEGREE:
                return "degree"
            for k in inc[target]:
                w = complex(z[sv[k] if su[k] == target else su[k]]) - E
                if -(w * rot).real > cos_min * abs(w):
                    return "angle"
        elif kind == _SPLIT:
            J = complex(z[sv[target]] - z[su[target]])
            if abs((J * rot).imag) < self.sin_min * abs(J):
                return "angle"
        if len(cand):
            end_node = target if kind == _NODE else -2
            at_end = (a == end_node) | (b == end_node)
            if frame is None:
                za, zb = (Za - P) * rot, (Zb - P) * rot
                # crossings anywhere but at the shared end points
                excl = at_p | at_end
                if kind == _SPLIT:
                    excl |= cand == target
                ya, yb = za.imag, zb.imag
                tol = 1e-9 * length
                touch = ((ya <= tol) & (yb >= -tol)) | ((ya >= -tol) & (yb <= tol))
                if (touch & ~excl).any():
                    den = yb - ya
                    u = np.where(np.abs(den) > 0, -ya / den, 0.0)
                    t = za.real + u * (zb.real - za.real)
                    if (touch & ~excl & (t > -tol) & (t < length + tol)).any():
                        return "crossing"
            else:
                za, zb = frame
            # near-parallel duplicates (Scharl sec. 4.2.3): |v_a . v_b| > 0.9 and close-by,
            # counting the end points of either segment that lie beside the other one;
            # numpy keeps the parallel segments that come within dmin of the new one's strip
            ya, yb = za.imag, zb.imag
            xa, xb = za.real, zb.real
            dmin = s.min_street_distance
            ex_, ey_ = xb - xa, yb - ya
            sel = ((np.abs(ex_) > PARALLEL_COS * np.sqrt(ex_ * ex_ + ey_ * ey_))
                   & (np.minimum(ya, yb) < dmin) & (np.maximum(ya, yb) > -dmin)
                   & (np.minimum(xa, xb) < length + dmin) & (np.maximum(xa, xb) > -dmin))
            if sel.any():
                idx = np.flatnonzero(sel)
                for A_, B_, ia, ib, sp, se in zip(za[idx].tolist(), zb[idx].tolist(),
                                                  a[idx].tolist(), b[idx].tolist(),
                                                  at_p[idx].tolist(), at_end[idx].tolist()):
                    e = B_ - A_
                    el = abs(e)
                    ce = e.conjugate()
                    close = 0
                    for Q, shared in ((0.0, sp), (length, se)):  # new ends beside the old
                        w = (Q - A_) * ce
                        if not shared and abs(w.imag) < dmin * el and 0 <= w.real <= el * el:
                            close += 1
                    for Zq, n in ((A_, ia), (B_, ib)):  # old ends beside the new one
                        if n != p and n != end_node and abs(Zq.imag) < dmin \
                                and 0 <= Zq.real <= length:
                            close += 1
                    if close >= 2:
                        return "duplicate"
            if kind == _SPLIT and frame is None:
                # a new node must not lie just beside another one (it would have snapped)
                snap2 = s.snap_distance ** 2
                da, db = za - length, zb - length
                if (((da.real ** 2 + da.imag ** 2) < snap2) & (a != p)).any() or \
                        (((db.real ** 2 + db.imag ** 2) < snap2) & (b != p)).any():
                    return "near"
            if kind == _CLIP:
                # a dead end must not stop just short of a road (it would have met it)
                d2 = _end_gap2(za, zb, length)[0]
                if (~at_p & (d2 < s.snap_distance ** 2)).any():
                    return "near"
        if st.halfplanes is not None:
            # a convex region holds a segment when it holds both ends: half-plane tests
            tol = _MASK_TOLERANCE
            for nx, ny, c in st.halfplanes:
                if nx * P.real + ny * P.imag > c + tol or nx * E.real + ny * E.imag > c + tol:
                    return "mask"
        elif not st.mask_tol.covers(shapely.linestrings([[P.real, P.imag], [E.real, E.imag]])):
            return "mask"
        if self.dem is not None and self.slope(P.real, P.imag, E.real, E.imag) > self.max_slope:
            return "slope"
        return None

    def _commit(self, st: _Stage, p: int, kind: int, E: complex, target: int):
        if kind == _NODE:
            end = target
        elif kind == _SPLIT:
            end = self.add_node(E.real, E.imag)
            self.split_segment(target, end)
        else:
            end = self.add_node(E.real, E.imag)
        self.add_segment(p, end, st.level, st.pattern)
        P = complex(self.z[p])
        return end, kind, math.atan2(E.imag - P.imag, E.real - P.real)

    # ------------------------------------------------------------------ seeding

    def _dist2(self, pts: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Squared distance of each point to the nearest of the segments ``ids``."""
        A, B = self.xy[self.su[ids]], self.xy[self.sv[ids]]
        e = B - A
        l2 = np.maximum((e * e).sum(axis=1), 1e-300)
        wx = pts[:, None, 0] - A[None, :, 0]
        wy = pts[:, None, 1] - A[None, :, 1]
        u = np.clip((wx * e[:, 0] + wy * e[:, 1]) / l2, 0.0, 1.0)
        return ((wx - u * e[:, 0]) ** 2 + (wy - u * e[:, 1]) ** 2).min(axis=1)

    def gap_point(self, st: _Stage, area, threshold: float, failed=()):
        """The sampled point of ``area`` farthest from every road, if farther than threshold.

        Scharl's seed search (sec. 4.2.1) tries the barycentre and then random positions;
        here the random positions are scored by their distance to the roads so that a
        region left empty (growth died out, or the first seed was blocked) gets a seed.
        """
        x0, y0, x1, y1 = area.bounds
        pts = np.column_stack([self.rng.uniform(x0, x1, 128), self.rng.uniform(y0, y1, 128)])
        pts = pts[shapely.contains_xy(area, pts[:, 0], pts[:, 1])]
        if len(pts) and self.density is not None:
            pts = pts[np.array([self.dens(x, y) for x, y in pts]) > 0.05]
        if len(pts) == 0:
            return None
        r = threshold
        ids = self.query(x0 - r, y0 - r, x1 + r, y1 + r)
        dist2 = np.full(len(pts), np.inf)
        if not len(ids):
            pass                         # no road near the region yet: every point is a gap
        elif len(ids) * len(pts) <= 250_000:
            dist2 = self._dist2(pts, ids)
        else:
            # a large region (the major stage): each point looks only at the roads within
            # the threshold around it, through the grid hash, so a reseed costs O(points)
            for k, (x, y) in enumerate(pts):
                near = self.query(x - r, y - r, x + r, y + r)
                if len(near):
                    dist2[k] = self._dist2(pts[k:k + 1], near)[0]
        for q in failed:  # places where a seed could not grow count as covered
            dist2 = np.minimum(dist2, (pts[:, 0] - q[0]) ** 2 + (pts[:, 1] - q[1]) ** 2)
        i = int(np.argmax(dist2))
        if dist2[i] <= threshold * threshold:
            return None
        return pts[i]


# --------------------------------------------------------------------------- main API

def grow_roads(boundary, *, settings: Optional[GrowthSettings] = None, major_roads=None,
               center=None, dem=None, obstacles=None, density=None,
               seed: Optional[int] = 0, progress: Optional[Progress] = None) -> GrowthResult:
    """Grow a major and a minor street network inside a boundary (Scharl 2010, ch. 4.2).

    Parameters
    ----------
    boundary : Polygon / MultiPolygon or array of them, metric CRS, optional
        The city region (Scharl's mask, sec. 4.2.3): every road lies inside it. None:
        roads grow inside the DEM's (or density map's, or the sketch's) extent and the
        outskirts are closed by the bulged convex hull of the major nodes (sec. 4.2.5).
    settings : GrowthSettings
        Patterns, lengths, angles, probabilities, distances, slope limit, cap.
    major_roads : array of LineString, optional
        Sketched major roads (Scharl ch. 7.1, artist control): clipped to the boundary and
        kept as they are (level 0, pattern 'sketch'); major growth starts from their dead
        ends and branches off them, and they bound the quarters.
    center : (x, y), optional
        Centre of the radial pattern; default the boundary's centroid (or a point inside).
    dem : DemGrid or (array, geotransform), optional
        Elevation in the same CRS; with it no grown segment is steeper than
        ``settings.max_slope`` (slope correction: the segment turns by up to
        ``settings.max_turn`` degrees, else it is dropped).
    obstacles : Polygon(s), optional
        Water, parks ...: no grown road enters them (streets are shortened, or turn).
    density : DemGrid or (array, geotransform), optional
        Population density (any unit, normalised by its maximum inside the boundary): the
        first seed goes to the densest place near the centre, major roads head for
        population, and growth, branching and block size follow density (none where it is 0).
    seed : int
        Seed of the ``numpy.random.Generator``: the same seed gives the same network.
    progress : Progress, optional

    Returns
    -------
    GrowthResult

    References
    ----------
    Scharl 2010, sec. 4.2.1 (seeds), 4.2.2 (growing strategies), 4.2.3 (local
    constraints), 4.2.4 (quarters), 4.2.5 (city boundaries); Parish & Müller 2001.

    Examples
    --------
    >>> import shapely
    >>> res = grow_roads(shapely.box(0, 0, 600, 600), seed=1)
    >>> sorted(set(res.level.tolist()))
    [0, 1]
    """
    t_start = time.perf_counter()
    progress = ensure(progress)
    s = (settings or GrowthSettings()).validated()
    rng = np.random.default_rng(seed)
    dem = _as_grid(dem, "DEM")
    dens = _as_grid(density, "density map")
    area = _as_area(boundary, "boundary", required=boundary is not None)
    hull_quarters = area is None
    if area is None:
        area = _growth_extent(dem, dens, major_roads, s)
    obst = _as_area(obstacles, "obstacles", required=False)
    free = area if obst is None else shapely.difference(area, obst)
    # land nowhere a metre wide is none: an obstacle equal to the boundary, reprojected from
    # another CRS, left a sliver of millimetres along it (growth then stopped in a numpy
    # error)
    if free.is_empty or free.area < 1e-6 * area.area or shapely.buffer(free, -0.5).is_empty:
        raise InputError("the obstacles cover the whole boundary: there is nowhere to grow roads")
    shortest = min(s.major_length, s.minor_length)
    extent, _, _ = minimum_rectangles([area])
    if extent[0] < 0.3 * shortest:
        raise InputError(f"the boundary ({extent[0]:.1f} m across) is too small for one "
                         f"segment of {0.3 * shortest:g} m (30 % of the shortest segment length)")
    if center is None:
        c = area.centroid
        center = (c.x, c.y) if area.covers(c) else area.representative_point().coords[0]
    center = np.asarray(center, dtype=np.float64).reshape(2)
    if not np.isfinite(center).all():
        raise InputError("the centre must be a finite point")

    g = _Grower(area, free, obst, s, rng, dem, dens, center)
    if dens is not None:
        g.dmax = _density_max(dens, area)
    shapely.prepare(free)
    # one error state for the whole loop: parallel segments divide by zero on purpose
    with np.errstate(divide="ignore", invalid="ignore"):
        # ---- sketched major roads (kept as they are, clipped to the boundary)
        sketched = _insert_sketch(g, major_roads, area)
        n_sketch = g.n_segs

        # ---- stage 1: major roads over the whole boundary
        axis = _grid_axes([g.lines()] if sketched else [area], lines=sketched)[0]
        major = _stage(g, MAJOR, PATTERNS.index(s.major_pattern), s.major_length, free, axis)
        if s.grow_major:
            _grow_major(g, major, sketched, progress.sub(0.0, 0.35))
        progress.step(0.35)

        # ---- stage 2: quarters (faces of the major network + outskirts), minor roads
        hull = None
        if hull_quarters and s.fill_quarters:
            hull = bulged_hull(g.xy[np.unique(np.r_[g.su[:g.n_segs], g.sv[:g.n_segs]])],
                               rng, area)
        quarters = _quarters(g, area if hull is None else hull, free, s) \
            if s.fill_quarters else []
        minor_pattern = PATTERNS.index(s.minor_pattern)
        axes = _grid_axes(quarters) if len(quarters) else []
        tols = shapely.buffer(np.asarray(quarters, dtype=object), _MASK_TOLERANCE,
                              quad_segs=2) if len(quarters) else []
        for qi, q in enumerate(quarters):
            if g.n_grown >= s.max_segments:
                g.capped = True
                break
            st = _stage(g, MINOR, minor_pattern, s.minor_length, q, axes[qi], tols[qi])
            _fill(g, st, q, progress.sub(0.35 + 0.55 * qi / len(quarters),
                                         0.35 + 0.55 * (qi + 1) / len(quarters)),
                  max_reseeds=4)
        progress.step(0.9)

    if g.n_segs == 0:
        raise InputError(f"no road could be grown: the free part of the boundary is too small, "
                         f"too steep or too fragmented for segments of {shortest:g} m")
    result = _finish(g)
    n_dead = 0
    if s.remove_dead_ends:
        result, n_dead = remove_dead_ends(result)
    result, n_links = link_pieces(result, s.minor_width, s.max_slope, dem, obst, area)
    n_apart, n_dead_left = pieces_and_dead_ends(result)
    progress.step(1.0)
    result.stats.update({
        "segments": g.n_grown, "major_segments": g.grown[MAJOR],
        "minor_segments": g.grown[MINOR], "sketched_segments": n_sketch,
        "proposals": g.proposals, "rejected": dict(sorted(g.rejected.items())),
        "quarters": len(quarters), "seeds": g.seeds, "capped": g.capped,
        "dead_ends_removed": n_dead, "links": n_links, "bulged_hull": hull is not None,
        "pieces_apart": n_apart, "dead_ends_left": n_dead_left,
        "seconds": time.perf_counter() - t_start,
    })
    progress.info(
        f"Grew {g.n_grown} segments ({g.grown[MAJOR]} major, {g.grown[MINOR]} minor) from "
        f"{g.proposals} proposals in {len(quarters)} quarters"
        + (f"; the cap of {s.max_segments} segments was reached" if g.capped else "") + ".")
    return result


def _growth_extent(dem, dens, major_roads, s: GrowthSettings):
    """Where roads may grow when no boundary is given: the DEM's extent, else the density
    map's, else the sketched major roads' envelope grown by a major segment length."""
    for grid in (dem, dens):
        if grid is not None:
            return shapely.box(*_grid_bounds(grid))
    if major_roads is not None and len(np.atleast_1d(np.asarray(major_roads, dtype=object))):
        lines = np.atleast_1d(np.asarray(major_roads, dtype=object))
        return shapely.envelope(shapely.buffer(shapely.union_all(lines), s.major_length))
    raise InputError("no boundary: give a boundary polygon, or a DEM, a density map or "
                     "sketched major roads whose extent bounds the growth")


def _grid_bounds(grid: DemGrid):
    rows, cols = grid.array.shape
    x0, dx, _, y0, _, dy = grid.geotransform
    xs, ys = (x0, x0 + cols * dx), (y0, y0 + rows * dy)
    return min(xs), min(ys), max(xs), max(ys)


def bulged_hull(points: np.ndarray, rng: np.random.Generator, clip=None,
                bulge: float = 0.25):
    """Scharl's bulged convex hull of the major nodes (sec. 4.2.5).

    "Each line segment of the convex hull is subdivided into 4 new segments, creating 3
    new nodes. Each of these nodes is displaced away from [the barycentre] C by a random
    value, forming an irregular, not necessarily convex city outline." The displacement
    is uniform in [0, ``bulge``] x the side's length; the outline is clipped to ``clip``.

    Returns a Polygon, or None when the points span no area.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(pts) < 3:
        return None
    hull = shapely.convex_hull(shapely.multipoints(pts))
    if shapely.get_type_id(hull) != 3 or hull.area <= 0:
        return None
    ring = shapely.get_coordinates(shapely.geometry.polygon.orient(hull).exterior)
    c = np.asarray(hull.centroid.coords[0])
    out = []
    for a, b in zip(ring[:-1], ring[1:]):
        out.append(a)
        length = float(np.hypot(*(b - a)))
        for f in (0.25, 0.5, 0.75):
            p = a + f * (b - a)
            away = p - c
            away /= max(float(np.hypot(*away)), 1e-12)
            out.append(p + away * rng.uniform(0.0, bulge) * length)
    poly = shapely.make_valid(shapely.Polygon(np.vstack([out, out[:1]])))
    poly = shapely.union_all([q for q in shapely.get_parts(poly) if shapely.get_type_id(q) == 3])
    if clip is not None:
        poly = shapely.intersection(poly, clip)
    parts = [q for q in shapely.get_parts(poly) if shapely.get_type_id(q) == 3]
    return max(parts, key=lambda q: q.area) if parts else None


def _end_nodes(geoms):
    """Node index of each line's two ends (ends equal to 1 µm share a node)."""
    ends = np.vstack([shapely.get_coordinates(shapely.get_point(geoms, 0)),
                      shapely.get_coordinates(shapely.get_point(geoms, -1))])
    _, node = np.unique(np.round(ends, 6), axis=0, return_inverse=True)
    node = node.ravel()
    return node[:len(geoms)], node[len(geoms):]


def pieces_and_dead_ends(result: "GrowthResult") -> Tuple[int, int]:
    """How many pieces of the network reach no sketched road (without a sketch: pieces
    besides one), and how many dead ends (nodes of degree 1) its grown roads have: what
    the log reports when linking or pruning could not do all (a part no buildable link
    reaches, a network that is all tree, as on steep terrain)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    geoms = result.geometry
    if len(geoms) == 0:
        return 0, 0
    u, v = _end_nodes(geoms)
    n = int(max(u.max(), v.max())) + 1
    # every node is an end of a line (the node index is dense): one component per piece
    n_pieces, label = connected_components(
        coo_matrix((np.ones(len(u)), (u, v)), shape=(n, n)), directed=False)
    sketched = result.pattern == "sketch"
    if sketched.any():
        apart = n_pieces - len(np.unique(label[u[sketched]]))
    else:
        apart = n_pieces - 1
    deg = np.bincount(np.r_[u, v], minlength=n)
    dead = np.unique(np.r_[u[~sketched & (deg[u] == 1)], v[~sketched & (deg[v] == 1)]])
    return int(apart), int(len(dead))


def remove_dead_ends(result: "GrowthResult"):
    """Prune grown dead-end roads (Scharl Fig. 4.12): edges with an end of degree 1 are
    removed until none is left; sketched roads stay. Nothing is pruned when that would
    remove every grown edge (a network that is all tree). Returns (result, edges removed).
    """
    geoms = result.geometry
    if len(geoms) == 0:
        return result, 0
    u, v = _end_nodes(geoms)
    keep = np.ones(len(geoms), dtype=bool)
    sketched = result.pattern == "sketch"
    while True:
        deg = np.bincount(np.r_[u[keep], v[keep]], minlength=max(u.max(), v.max()) + 1)
        dead = keep & ~sketched & ((deg[u] == 1) | (deg[v] == 1))
        if not dead.any():
            break
        keep &= ~dead
    if not (keep & ~sketched).any():
        return result, 0
    n = int((~keep).sum())
    return GrowthResult(geoms[keep], result.level[keep], result.pattern[keep],
                        result.width[keep], result.stats), n


def link_pieces(result: "GrowthResult", width: float, max_slope: float = np.inf,
                dem: Optional[DemGrid] = None, obstacles=None, inside=None):
    """Join the pieces of the network that reach no sketched road (without a sketch: the
    longest piece) by the shortest road that crosses nothing, is no steeper than
    ``max_slope`` on the DEM and enters no obstacle (:func:`links.link_floating_pieces`;
    level minor, pattern 'link', ``width``): straight where a straight road inside
    ``inside`` (the boundary) reaches the piece, else bent along the boundary's arm
    (:func:`links.path_inside`; a straight road across the bay between two arms of a
    concave boundary would leave it). Only a piece that no road inside reaches (in a part
    of the boundary apart from the rest) is joined by a straight road that leaves the
    boundary, the only road that does; a piece that no such road reaches stays as it is.
    A bent link is one road of straight legs, and the lines a link ends on are split
    there, so the edges stay noded and straight. Returns (result, links added)."""
    def buildable(link) -> bool:
        if dem is not None and segment_slopes([link], dem)[0] > max_slope:
            return False
        return obstacles is None or shapely.intersection(link, obstacles).length < 1e-6

    n_links = 0
    # inside the boundary first; then, for what is left, across it (parts apart)
    for region in ((inside, None) if inside is not None else (None,)):
        links, _ = link_floating_pieces(result.geometry, result.pattern == "sketch",
                                        accept=buildable, drop_unlinked=False, inside=region,
                                        bent=region is not None)
        if not len(links):
            continue
        n_links += len(links)
        legs = two_point_segments(links)
        lines = np.concatenate([result.geometry, legs])
        level = np.r_[result.level, np.full(len(legs), MINOR)]
        pattern = np.r_[result.pattern, np.full(len(legs), "link", dtype=object)]
        width_all = np.r_[result.width, np.full(len(legs), float(width))]
        pieces, parent = renode(lines, np.r_[np.zeros(len(result.geometry), bool),
                                             np.ones(len(legs), bool)], level, min_length=1e-9)
        result = GrowthResult(pieces, level[parent], pattern[parent].astype(object),
                              width_all[parent], result.stats)
    return result, n_links


# --------------------------------------------------------------------------- stage helpers

def _density_max(dens: DemGrid, area) -> float:
    x0, y0, x1, y1 = area.bounds
    xs, ys = np.meshgrid(np.linspace(x0, x1, 96), np.linspace(y0, y1, 96))
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    pts = pts[shapely.contains_xy(area, pts[:, 0], pts[:, 1])]
    v = dens(pts) if len(pts) else np.zeros(0)
    v = v[np.isfinite(v)]
    if len(v) == 0 or v.max() <= 0:
        raise InputError("the density map is zero or empty everywhere inside the boundary")
    return float(v.max())


def _stage(g: _Grower, level: int, pattern: int, length: float, mask, axis: float,
           mask_tol=None) -> _Stage:
    shapely.prepare(mask)
    if mask_tol is None:
        mask_tol = mask.buffer(_MASK_TOLERANCE, quad_segs=2)
    shapely.prepare(mask_tol)
    return _Stage(level, pattern, length, mask, mask_tol, axis,
                  min_length=0.3 * length,
                  reach=max(g.s.snap_distance, 0.4 * length), halfplanes=_halfplanes(mask))


def _halfplanes(mask, max_edges: int = 24) -> Optional[list]:
    """A convex polygon of few edges as half-planes n.x <= c (outward normals), else None."""
    if shapely.get_type_id(mask) != 3 or shapely.get_num_interior_rings(mask) > 0:
        return None
    area = shapely.area(mask)
    if area <= 0 or shapely.area(shapely.convex_hull(mask)) - area > 1e-9 * area:
        return None
    ring = shapely.get_exterior_ring(mask)
    if not shapely.is_ccw(ring):
        ring = shapely.reverse(ring)
    c = shapely.get_coordinates(ring)
    d = np.diff(c, axis=0)
    n = np.hypot(d[:, 0], d[:, 1])
    keep = n > 1e-9
    if keep.sum() > max_edges:
        return None
    nx, ny = d[keep, 1] / n[keep], -d[keep, 0] / n[keep]  # right of a ccw edge = outside
    return [(float(x), float(y), float(x * p[0] + y * p[1]))
            for x, y, p in zip(nx, ny, c[:-1][keep])]


def _grid_axes(geoms, lines: bool = False) -> list:
    """Main directions of grids (radians): of sketched roads, else of each area's rectangle.

    Scharl sec. 4.2.2: "the main directions are defined once for major streets and once per
    quarter for minor streets". For sketched roads the axial mean of their bearings
    (angles x 4, length-weighted) is taken; for an area the direction of its minimum-area
    rectangle.
    """
    if lines:
        out = []
        for group in geoms:
            c, idx = shapely.get_coordinates(np.asarray(group, dtype=object), return_index=True)
            same = idx[1:] == idx[:-1]
            d = np.diff(c, axis=0)[same]
            w = np.hypot(d[:, 0], d[:, 1])
            th = np.arctan2(d[:, 1], d[:, 0])
            out.append(float(np.arctan2((w * np.sin(4 * th)).sum(),
                                        (w * np.cos(4 * th)).sum()) / 4))
        return out
    _, _, angle = minimum_rectangles(np.asarray(geoms, dtype=object))
    return np.radians(angle).tolist()


def _insert_sketch(g: _Grower, major_roads, area) -> bool:
    """Put the sketched major roads into the graph: clipped, noded, split into segments."""
    if major_roads is None:
        return False
    lines = np.atleast_1d(np.asarray(major_roads, dtype=object))
    lines = lines[~(shapely.is_missing(lines) | shapely.is_empty(lines))] if len(lines) else lines
    if len(lines) == 0:
        return False
    clipped = shapely.intersection(shapely.force_2d(lines), area)
    parts = shapely.get_parts(clipped)
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0)]
    if len(parts) == 0:
        raise InputError("no sketched major road lies inside the boundary")
    noded = node_lines(parts)
    coords, idx = shapely.get_coordinates(noded, return_index=True)
    same = idx[1:] == idx[:-1]
    a, b = coords[:-1][same], coords[1:][same]
    keep = np.hypot(*(b - a).T) > 1e-6
    a, b = a[keep], b[keep]
    ids: dict = {}

    def node(pt):
        key = (round(pt[0], 6), round(pt[1], 6))
        n = ids.get(key)
        if n is None:
            n = ids[key] = g.add_node(float(pt[0]), float(pt[1]))
        return n

    L = g.s.major_length
    seen = set()
    for pa, pb in zip(a, b):
        # long straight pieces get nodes about a segment apart: places to branch from
        k = max(int(math.ceil(np.hypot(*(pb - pa)) / L - 1e-9)), 1)
        prev = node(pa)
        for i in range(1, k + 1):
            nxt = node(pa + (pb - pa) * (i / k)) if i < k else node(pb)
            key = (min(prev, nxt), max(prev, nxt))
            if prev != nxt and key not in seen:
                seen.add(key)
                g.add_segment(prev, nxt, MAJOR, _SKETCH)
            prev = nxt
    return True


def _grow_major(g: _Grower, st: _Stage, sketched: bool, progress: Progress) -> None:
    s = g.s
    expected = 2.0 * g.free.area / (s.major_length ** 2)
    if sketched:
        # the sketch's dead ends continue and its nodes branch (Scharl's production rules)
        for n in range(g.n_nodes):
            inc = g.inc[n]
            x, y = g.xy[n]
            if len(inc) == 1:
                k = inc[0]
                o = g.sv[k] if g.su[k] == n else g.su[k]
                h = math.atan2(y - g.xy[o, 1], x - g.xy[o, 0])
                g.successors(st, n, h, 0.0)
            elif len(inc) == 2:
                k0, k1 = inc
                o = g.sv[k0] if g.su[k0] == n else g.su[k0]
                h = math.atan2(y - g.xy[o, 1], x - g.xy[o, 0])
                seg_len = sum(math.hypot(*(g.xy[g.su[k]] - g.xy[g.sv[k]])) for k in inc) / 2
                p = s.branch_probability * min(1.0, seg_len / s.major_length) * \
                    (1.0 if g.density is None else min(1.0, 2.0 * g.dens(x, y)))
                for side in (1.0, -1.0):
                    if g.rng.random() < p:
                        length = g.seg_length(st, g.dens(x, y))
                        hh = g.ideal(st, x, y, h, side * 0.5 * math.pi, length)
                        if hh is not None:
                            g.push(1.0, n, hh, length, _BRANCH)
        g.run(st, progress, expected)
    else:
        x, y = _first_seed(g, st)
        g.seed(st, x, y)
        g.run(st, progress, expected)
    _reseed(g, st, g.free, progress, expected,
            max_reseeds=8 + int(g.free.area / (16.0 * st.length ** 2)))


def _first_seed(g: _Grower, st: _Stage):
    """Scharl sec. 4.2.1: the densest place, weighted towards the centre; else the centre."""
    free = g.free
    cx, cy = g.center
    if g.density is None:
        if free.covers(shapely.Point(cx, cy)):
            return cx, cy
        from shapely.ops import nearest_points

        p, _ = nearest_points(free, shapely.Point(cx, cy))
        return p.x, p.y
    x0, y0, x1, y1 = free.bounds
    xs, ys = np.meshgrid(np.linspace(x0, x1, 64), np.linspace(y0, y1, 64))
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    pts = pts[shapely.contains_xy(free, pts[:, 0], pts[:, 1])]
    if len(pts) == 0:
        rp = free.representative_point()
        return rp.x, rp.y
    d = np.array([g.dens(x, y) for x, y in pts])
    dc = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)
    v = d * (1.0 - dc / max(dc.max(), 1e-9) * 0.5)
    i = int(np.argmax(v))
    return float(pts[i, 0]), float(pts[i, 1])


def _reseed(g: _Grower, st: _Stage, area, progress: Progress, expected: float,
            max_reseeds: int) -> None:
    """Seed the gaps growth left (Scharl sec. 4.2.1's fallback seeds, scored by distance)."""
    failed = []
    for _ in range(max_reseeds):
        if g.n_grown >= g.s.max_segments:
            g.capped = True
            return
        pt = g.gap_point(st, area, GAP_FACTOR * st.length, failed)
        if pt is None:
            return
        before = st.count
        g.seed(st, float(pt[0]), float(pt[1]))
        g.run(st, progress, expected)
        if st.count == before:
            failed.append(pt)  # blocked here (too steep, obstructed): look elsewhere


def _quarters(g: _Grower, area, free, s: GrowthSettings) -> list:
    """Quarters: faces of the major network closed by the boundary (Scharl sec. 4.2.4-4.2.5).

    Scharl closes the outskirts with a bulged convex hull of the major nodes so that minor
    roads also reach the city edge; here the boundary itself is that hull: the quarters are
    the faces of the major roads together with the boundary's rings, so the outskirts
    between the outermost major roads and the boundary are split into quarters wherever a
    major road reaches the boundary. Major nodes on the boundary are inserted into its
    rings first, so that the faces close exactly there. Each quarter is intersected with
    the free area (no obstacles); slivers and tiny pieces are not filled.
    """
    major = np.flatnonzero(g.slevel[:g.n_segs] == MAJOR)
    rings = shapely.get_parts(shapely.boundary(area))
    if len(major):
        nodes = np.unique(np.concatenate([g.su[major], g.sv[major]]))
        pts = shapely.points(g.xy[nodes])
        on_edge = shapely.dwithin(shapely.boundary(area), pts, 1e-6)
        if on_edge.any():
            rings = shapely.snap(rings, shapely.multipoints(pts[on_edge]), 1e-6)
        lines = np.concatenate([g.lines(major), rings])
    else:
        lines = rings
    faces, _, _ = planar_faces(lines, node=True)
    if len(faces) == 0:
        return []
    q = shapely.intersection(faces, free)
    parts = shapely.get_parts(q)
    parts = parts[shapely.get_type_id(parts) == 3]
    min_area = 0.25 * s.minor_length ** 2
    area_ = shapely.area(parts)
    perim = shapely.length(parts)
    keep = (area_ >= min_area) & (2 * area_ > s.snap_distance * perim)
    parts = parts[keep]
    # quarters nearest to the centre first: with the cap, the city fills from its centre
    cent = shapely.get_coordinates(shapely.centroid(parts))
    order = np.lexsort((cent[:, 0], np.hypot(cent[:, 0] - g.center[0], cent[:, 1] - g.center[1])))
    return list(parts[order])


def _fill(g: _Grower, st: _Stage, quarter, progress: Progress, max_reseeds: int) -> None:
    """Fill one quarter: a seed at its barycentre (Scharl sec. 4.2.1), then the gaps."""
    expected = 2.0 * quarter.area / st.length ** 2
    c = quarter.centroid
    if not quarter.covers(c):
        c = quarter.representative_point()
    d = g.dens(c.x, c.y)
    if g.density is None or g.rng.random() < min(1.0, 2.0 * d):
        g.seed(st, c.x, c.y)
        g.run(st, progress, expected)
    _reseed(g, st, quarter, progress, expected,
            max_reseeds + int(quarter.area / (16.0 * st.length ** 2)))


def _finish(g: _Grower) -> GrowthResult:
    """The planar, noded output (:func:`roads.clean_network` as the safety net)."""
    n = g.n_segs
    lines = g.lines()
    lev = g.slevel[:n].astype(np.int64)
    pat = g.spattern[:n].astype(np.int64)
    graph = clean_network(lines, road_class=np.array(ROAD_CLASSES, dtype=object)[lev],
                          snap_tolerance=0.0, min_dangle_length=0.0, merge_degree2=False)
    src = graph.source
    level = lev[src]
    pattern = np.array(_PATTERN_NAMES, dtype=object)[pat[src]]
    width = np.where(level == MAJOR, g.s.major_width, g.s.minor_width).astype(np.float64)
    return GrowthResult(np.asarray(graph.geometry, dtype=object), level, pattern, width, {})


# --------------------------------------------------------------------------- evidence

def network_statistics(lines, area=None) -> dict:
    """Pattern evidence of a street network: orientation, junction angles, segment lengths.

    Parameters
    ----------
    lines : array of LineString (metric CRS)
    area : polygon, optional, for the densities

    Returns
    -------
    dict with ``orientation_entropy`` (nats, length-weighted, 36 bins: ln 4 = 1.386 for a
    grid, ln 36 = 3.584 for uniform bearings), ``orientation_order`` (Boeing's phi),
    ``mean_abs_angle_dev_90`` (mean |angle - 90°| over the angles between consecutive
    streets at junctions of degree 3 and 4, 180° straight-throughs of T junctions
    excluded), ``share_right_angles`` (share of those within 10° of 90°),
    ``segment_length_mean`` / ``_median`` / ``_cv`` (edges between nodes of degree != 2),
    ``edges``, ``dead_ends_per_km2``, ``intersections_per_km2``.

    References
    ----------
    Boeing 2019 (orientation entropy); Scharl 2010, Fig. 4.1 (the three patterns).
    """
    from ..measure import metrics

    r = metrics.road_metrics(lines, area=area)
    ang = r.distribution("roads", "intersection_angle")
    ang = ang[ang < 170.0]  # the straight-through of a T is not a junction angle
    seg = r.distribution("roads", "segment_length")
    dev = np.abs(ang - 90.0)
    nan = float("nan")
    return {
        "orientation_entropy": r.scalar("roads", "orientation_entropy"),
        "orientation_order": r.scalar("roads", "orientation_order"),
        "mean_abs_angle_dev_90": float(dev.mean()) if len(dev) else nan,
        "share_right_angles": float(np.mean(dev <= 10.0)) if len(dev) else nan,
        "segment_length_mean": float(seg.mean()) if len(seg) else nan,
        "segment_length_median": float(np.median(seg)) if len(seg) else nan,
        "segment_length_cv": float(seg.std() / seg.mean()) if len(seg) else nan,
        "edges": int(r.scalar("roads", "edges")),
        "dead_ends_per_km2": r.scalar("roads", "dead_ends_per_km2"),
        "intersections_per_km2": r.scalar("roads", "intersections_per_km2"),
    }
