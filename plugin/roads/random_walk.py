"""Street generation by random walks through attributed intersection points.

Aliaga, Vanegas and Benes (2008), sec. 3.1.1: the streets of each hierarchy level h_0,
h_1, ... are random walks through the intersection points. A step from a base point v_i
goes to a target point v_j drawn with the transition probability

    p(v_i, v_j) = exp(-(d - mu_d)^2 / (2 sigma_d^2) - (alpha - mu_alpha)^2 / (2 sigma_alpha^2))

(a bivariate Gaussian on the step's length d and its turn alpha from the street's last
segment, with the statistics of the base point's street); steps under a threshold are
ignored. p is zero for a point that no street of the walk's level passes (wrong level),
for a saturated point (its example's number of connections, at most 4), for a step that
would cross or touch an existing segment (a grid of cells over the segments, which grows
with the walk, and an exact test of the segments in the step's cells) or pass over another
point (no new intersections), and for a step closer than a minimum angle to a street
already at either end. A walk ends where every p is zero; new walks start from free street
slots until none can start.

The paper's REPEAT ("until no new street segments are added") is completed so that the
result is one network (:func:`connect_points`):

- streets that stopped short of the connections their point had in the example close with
  one more step to the nearest free point, until the dead-end share is the example's; where
  it is below (the example's street ends that no walk reached), such an end gets its
  street, one step onto the nearest street (a T);
- every connected piece that reaches neither the given roads nor (without given roads) the
  largest piece is joined to the nearest other piece by a clear step to one of its points,
  or, where no point is in reach, by a step onto the nearest visible street, which is split
  there (a new T junction: a crossing becomes a junction, never a bare crossing); a piece
  that no step joins (built land far from the rest, an arm of the target) is linked by the
  shortest clear street inside the target once the streets are drawn, bent along the
  target where it turns, and dropped (rejected) only where no such street reaches it, so
  no floating piece is left (a part of the target apart that no given road reaches keeps
  its own network: its longest piece anchors).

Each segment then becomes a polyline (fig. 5c). With the example's streets at hand
(:mod:`street_shapes`), the shape is that of an example segment of the same level and a
similar chord length and tortuosity, scaled onto the new chord and mirrored at random, so
that the new streets bend like the example's: the same tortuosity and turn distribution.
Without them (an example given as points only), a parabola of the points' tortuosity
attribute. Shapes that would cross another street are redrawn, then straightened, so the
result stays planar.

Given roads (expand, sec. 4.2): the nodes of existing roads join the point set; the dead
ends of the existing network at the target ("seam ends") continue their streets into the
new points first, and seam ends still open at the end connect to the nearest free point of
any level, else, while more of them stay open than the example's dead-end share, end on the
nearest street (a T, :func:`_close_seam_ends`). Along the given roads inside the target,
junction slots are placed at the spacing of the example's level-0 streets (its
intersections along its arterials): a new street may end there (a T) or cross there (a
4-way junction), never anywhere else on a given road. The given roads play the example's
level 0: new points of level 0 become the next level.

Blocks are the faces of the result, and the block graph (the dual, sec. 3.1.2) is kept
for parcels (:func:`blocks_and_dual`).

Nothing here imports QGIS.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1, 4.2, figs. 3-5 and 8-12.
"""
from __future__ import annotations

import functools
import heapq
import itertools
import math
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy.cluster.hierarchy import DisjointSet
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..core.geometry import pinned_ends
from ..core.progress import InputError, Progress, ensure
from ..network.controlled_access import end_short_of_controlled_access
from ..network.crossings import streets_across, t_stem
from ..network.dead_ends import steer_share
from ..network.invariants import (DEAD_END_TOLERANCE, MIN_DUPLICATE_LENGTH, connected_pieces,
                                  corridor_of, counted_nodes)
from ..network.invariants import dead_end_share as measured_dead_end_share
from ..network.links import allowed_area, join_pieces, link_floating_pieces
from ..network.street_graph import ends_as_vertices, node_lines, snap_ends_onto_lines
from ..network.undershoots import clear_undershoots
from . import intersection_quadtree as iq
from .street_shapes import (StreetShapes, blend_shapes, draw_geometry, example_from_roads,
                            street_shapes)

__all__ = ["WalkSettings", "Synthesis", "StreetShapes", "street_shapes", "example_from_roads",
           "connect_points", "synthesize", "given_with_junctions", "points_used",
           "blocks_and_dual", "block_table", "dead_end_share_of", "crossing_share_of",
           "ROAD_FIELDS", "POINT_FIELDS", "BLOCK_FIELDS"]

ROAD_FIELDS = [("edge_id", "int"), ("level", "int"), ("length_m", "float"),
               ("tortuosity", "float"), ("origin", "str"), ("node_from", "int"),
               ("node_to", "int")]
POINT_FIELDS = [("node_id", "int"), ("degree", "int"), ("example", "int"), ("source_id", "int"),
                ("level_a", "int"), ("level_b", "int"), ("tortuosity_a", "float"),
                ("tortuosity_b", "float"), ("dist_mean_a", "float"), ("dist_var_a", "float"),
                ("dist_mean_b", "float"), ("dist_var_b", "float"), ("angle_mean_a", "float"),
                ("angle_var_a", "float"), ("angle_mean_b", "float"), ("angle_var_b", "float"),
                ("parcel_area", "float"), ("connections", "int"), ("generated", "int")]

BLOCK_FIELDS = [("block_id", "int"), ("area_m2", "float"), ("neighbours", "int"),
                ("parcel_area", "float")]

_TOUCH = 0.5     # m: a step closer than this to another segment touches it
_ON_POINT = 0.01  # m: a line end this close to a point ends there (points are on a mm grid)
#: example == -1: a node of the given roads; -2: a junction slot placed on a given road
EXISTING, ROAD_SLOT = -1, -2
#: Existing roads' nodes closer than this (m) are one junction when the walk cleans them;
#: the new streets' ends on them are moved back onto the roads as given by up to as much.
ROAD_SNAP_TOLERANCE = 1.0


@dataclass(frozen=True)
class WalkSettings:
    """Parameters of the walk (defaults follow the paper where it gives them).

    threshold : transition probabilities under this are ignored (the "user-defined
        threshold"; the Gaussian's peak is 1)
    reach_sd : candidates lie within mu_d + reach_sd * sigma_d of the base point
    min_angle : degrees; no two streets leave a point closer in direction than this
    clearance : a step may not pass closer than clearance x its length (at least
        ``min_clearance`` m) to another point: streets cross only at intersection points
    max_capacity : connections of a point (the paper's 4)
    max_sagitta : the bend of a parabolic segment (examples without street shapes) is at
        most this share of its chord
    seam_distance : m; dead ends of existing roads this close to the target are seam ends
        (None: a quarter of the example's median street distance)
    close_ends : after the walks, points whose street stopped short of the connections they
        had in the example make one more step to the nearest free point, or a T onto the
        nearest street of their level, until the share of dead ends is the example's (not
        in the paper: its walks leave such stubs); where that leaves the share above the
        invariants' band less half its width, stubs end on streets of any level
    join_pieces : join every piece of the network to the given roads (or to the largest
        piece): by a step, else by the shortest street inside the target; drop what
        neither reaches (the paper's REPEAT, completed)
    match_crossings : after the walks, T junctions that were crossings in the example, then
        T junctions on the given roads, become crossings (the T's own street goes on
        straight across, one step onto the network) until the share of 4-way junctions is
        the example's (not in the paper: its walks keep about half the example's
        crossings, as a crossing street is rarely walked both ways); where the network is
        still under the invariants' band less half its width (a grid's crossings: the
        walk's T's on given roads' own nodes, or with no point in reach across), T's own
        streets go on straight across to the street they meet
        (:func:`network.crossings.streets_across`, as StreetGAN's) up to that margin
    road_slots : place junction slots along the given roads at the spacing of the
        example's level-0 streets (else new streets meet given roads only at their nodes)
    join_reach : joins look this many of the point's mean street distances far
    shape_retries : a street shape that crosses another street is redrawn this often before
        the segment is straightened
    min_face : the steps made after the walks (closing a stub, a crossing street's step,
        a T onto a street) close no ring of streets shorter than ``min_face`` x sqrt(a(v)),
        a(v) the mean block area around the point in the example: a square of a seventh
        of those blocks at 1.5. Without it a third of the walk's blocks were smaller than
        the example's 10th percentile, mostly behind a crossing street's one step (not in
        the paper, whose walks make no such steps); a stub that closes no other way may
        still close a shorter ring (the dead-end share comes first); 0: off
    """

    threshold: float = 0.05
    reach_sd: float = 2.5
    min_angle: float = 25.0
    clearance: float = 0.08
    min_clearance: float = 2.0
    max_capacity: int = 4
    max_sagitta: float = 0.25
    seam_distance: Optional[float] = None
    close_ends: bool = True
    join_pieces: bool = True
    match_crossings: bool = True
    road_slots: bool = True
    join_reach: float = 3.0
    shape_retries: int = 3
    min_face: float = 1.5

    def validate(self) -> "WalkSettings":
        checks = (("threshold", 0.0, 1.0), ("reach_sd", 0.1, 10.0), ("min_angle", 0.0, 89.0),
                  ("clearance", 0.0, 0.5), ("min_clearance", 0.0, 1000.0),
                  ("max_sagitta", 0.0, 0.5), ("join_reach", 0.5, 20.0),
                  ("min_face", 0.0, 10.0))
        for name, lo, hi in checks:
            v = getattr(self, name)
            if v is None or not math.isfinite(v) or not lo <= v <= hi:
                raise InputError(f"{name} must be in [{lo:g}, {hi:g}] (got {v})")
        if not 1 <= self.max_capacity <= 8:
            raise InputError("max_capacity must be in 1..8")
        if not 0 <= self.shape_retries <= 20:
            raise InputError("shape_retries must be in 0..20")
        if self.seam_distance is not None and not (self.seam_distance >= 0):
            raise InputError("the seam distance must not be negative")
        return self

    def reach(self, dist_mean, dist_sd):
        """How far a step looks from a point's street slot: its mean street distance and
        ``reach_sd`` deviations (scalars or arrays)."""
        return dist_mean + self.reach_sd * dist_sd


def _example_node_degrees(points: iq.PointSet) -> np.ndarray:
    """Degrees of the example points that are nodes of the example network (degree != 2).

    Street ends on the convex hull of the example's points are left out: an example that is
    an extract has its streets cut at the extract's edge, and those ends are no dead ends
    (Bubeneč: all 11 of its street ends; counted, its dead-end share was 0.44 instead of
    0.07)."""
    from ..network.invariants import EDGE_DISTANCE

    own = points.example >= 0
    deg, xy = points.degree[own], points.xy[own]
    counted = deg != 2
    hull = shapely.convex_hull(shapely.multipoints(xy)) if len(xy) >= 3 else None
    if hull is not None and hull.area > 0:
        counted &= ~((deg == 1) & shapely.dwithin(shapely.boundary(hull), shapely.points(xy),
                                                  EDGE_DISTANCE))
    return deg[counted]


def dead_end_share_of(points: iq.PointSet) -> float:
    """Share of dead ends (degree 1) among the example's nodes (its intersections and street
    ends, :func:`_example_node_degrees`)."""
    deg = _example_node_degrees(points)
    return float((deg == 1).mean()) if len(deg) else 0.0


def crossing_share_of(points: iq.PointSet) -> float:
    """Share of crossings (degree 4 or more) among the example's nodes."""
    deg = _example_node_degrees(points)
    return float((deg >= 4).mean()) if len(deg) else 0.0


def _reserve(rows: np.ndarray, size: int) -> np.ndarray:
    """``rows`` with room for at least ``size`` rows (doubled when full), its rows kept:
    appending one row at a time costs O(1) amortised, not a copy of all."""
    if len(rows) >= size:
        return rows
    out = np.zeros((max(size, 2 * len(rows)),) + rows.shape[1:], dtype=rows.dtype)
    out[:len(rows)] = rows
    return out


# Written by hand: a walk step tests a handful of nearby segments, ~10^5 steps per 10,000
# points, where a GEOS call per pair costs several times the arithmetic; GEOS decides the
# cases the floats cannot tell.
def _point_gap(px, py, ax, ay, bx, by):
    """Distance from the point p to the segment ab (floats)."""
    ux, uy = bx - ax, by - ay
    ll = ux * ux + uy * uy
    t = ((px - ax) * ux + (py - ay) * uy) / ll if ll > 0 else 0.0
    t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
    dx, dy = px - ax - t * ux, py - ay - t * uy
    return math.sqrt(dx * dx + dy * dy)


def _segments_within(ax, ay, bx, by, cx, cy, dx, dy, distance):
    """Whether the segments ab and cd come within ``distance`` of each other (floats), or
    None where the float arithmetic cannot tell (the gap within a micrometre of the
    distance, or an end almost on the other's line): GEOS decides those."""
    o1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    o2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
    o3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
    o4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
    if ((o1 < 0 < o2) or (o2 < 0 < o1)) and ((o3 < 0 < o4) or (o4 < 0 < o3)):
        return True  # they cross
    gap = min(_point_gap(ax, ay, cx, cy, dx, dy), _point_gap(bx, by, cx, cy, dx, dy),
              _point_gap(cx, cy, ax, ay, bx, by), _point_gap(dx, dy, ax, ay, bx, by))
    if abs(gap - distance) <= 1e-6:
        return None
    if gap <= distance:
        return True
    scale = 1e-9 * (abs(bx - ax) + abs(by - ay) + abs(dx - cx) + abs(dy - cy)) ** 2
    if min(abs(o1), abs(o2), abs(o3), abs(o4)) <= scale:
        return None
    return False


class _SegmentGrid:
    """Segment ids in square cells (a dict of cell -> list of ids), each segment listed in
    every cell its bounding box touches: the segments whose bounding boxes meet a box are
    among those listed in the cells the box touches. A segment is added or removed in
    O(cells), so the index follows the walk (an STRtree would have to be rebuilt)."""

    def __init__(self, cell: float):
        self.cell = float(cell)
        self.cells = {}

    def _keys(self, xmin, ymin, xmax, ymax):
        c = self.cell
        return [(ix, iy) for ix in range(math.floor(xmin / c), math.floor(xmax / c) + 1)
                for iy in range(math.floor(ymin / c), math.floor(ymax / c) + 1)]

    def add(self, i: int, box):
        cells = self.cells
        for key in self._keys(*box):
            cells.setdefault(key, []).append(i)

    def remove(self, i: int, box):
        for key in self._keys(*box):
            self.cells[key].remove(i)

    def near(self, xmin, ymin, xmax, ymax) -> set:
        """Ids listed in the cells the box touches."""
        get = self.cells.get
        found = set()
        for key in self._keys(xmin, ymin, xmax, ymax):
            ids = get(key)
            if ids:
                found.update(ids)
        return found


class _Walker:
    """State of the street generation: slot counts, capacities, segments, edges.

    Per point and per segment state lives in arrays with spare rows (:func:`_reserve`);
    the public arrays (``p``, ``xy``, ``cap``, ``cnt``, ``deg`` ...) are views of their
    first rows, renewed when points are added."""

    def __init__(self, pts: iq.PointSet, settings: WalkSettings, rng, cap, cnt, slot_dir,
                 dirs, seg0):
        self.s = settings
        self.rng = rng
        self.kd = cKDTree(pts.xy)
        self._pts_rows = pts  # the point attributes, with spare rows once points are added
        self._point_rows = {
            "cap": np.asarray(cap), "cnt": np.asarray(cnt), "slot_dir": np.asarray(slot_dir),
            "deg": np.zeros(len(pts), dtype=np.int64),
            "used": np.zeros((len(pts), 2), dtype=bool),  # slots with a segment of theirs
            "_mark": np.zeros(len(pts), dtype=bool)}  # scratch mask of a point's neighbours
        self._show_points(len(pts))
        self.adj = [set() for _ in range(len(pts))]
        self.dirs = dirs
        # edges: (a, slot_a, b, slot_b, level, origin) tuples, and their end points, segment
        # and liveness as arrays (a piece's edges are found at once when it is dropped)
        self.edges: List[tuple] = []
        self._edge_ends = np.zeros((2 * len(pts) + 16, 2), dtype=np.int64)
        self._edge_seg = np.zeros(len(self._edge_ends), dtype=np.int64)
        self._edge_alive = np.zeros(len(self._edge_ends), dtype=bool)
        # segments: coordinates (an array, and tuples for the tests of one step), owners
        # and geometries (made when an exact test needs them) of all, the live ones in a
        # grid of cells about a street gap wide; a split segment is dead (its two halves
        # are added as new ones)
        seg0 = np.asarray(seg0, dtype=float).reshape(-1, 4)
        size = len(seg0) + 4 * len(pts) + 16
        self._coords = np.zeros((size, 4))
        self._ends: List[tuple] = []
        self._geoms = np.empty(size, dtype=object)
        self._seg_edge = np.full(size, -1, dtype=np.int64)  # -1: given road
        self._seg_start = np.full(size, -1, dtype=np.int64)  # the edge's a
        self._seg_level = np.full(size, -1, dtype=np.int64)  # the edge's level
        gaps = pts.dist_mean[:, 0][np.isfinite(pts.dist_mean[:, 0])]
        self._grid = _SegmentGrid(max(float(np.median(gaps)) if len(gaps) else 100.0, 10.0))
        self.n_seg = 0
        for p0x, p0y, p1x, p1y in seg0:
            self._add_segment((p0x, p0y), (p1x, p1y))
        self.cos_min = math.cos(math.radians(settings.min_angle))
        self.area = None  # the target: junctions made on streets stay inside it
        self.corridor = None  # the given roads' corridors (prepared): no step runs along one
        self._neighbourhoods(pts)
        # a(v) where the example gave none: the median of the others
        finite = pts.area[np.isfinite(pts.area)]
        self._area_fill = float(np.median(finite)) if len(finite) else 1e4
        self.n_small_faces_refused = 0
        self.check_rings = True  # off for a stub that closes no other way

    def _neighbourhoods(self, pts: iq.PointSet):
        """For every point and street slot, the other points within the slot's reach
        (ascending), their offsets, distances and directions, and the distance terms of the
        step's weights: computed for all at once (the points stay where they are), where a
        step would compute them for each."""
        reach = self.s.reach(pts.dist_mean, pts.dist_sd)
        rows = np.flatnonzero((np.isfinite(reach) & (pts.level >= 0)).ravel())  # 2 v + slot
        owner = rows // 2
        balls = self.kd.query_ball_point(pts.xy[owner], reach.ravel()[rows],
                                         return_sorted=True)
        count = np.fromiter(map(len, balls), dtype=np.int64, count=len(balls))
        nb = np.fromiter(itertools.chain.from_iterable(balls), dtype=np.int64,
                         count=int(count.sum()))
        row_of = np.repeat(np.arange(len(rows)), count)
        keep = nb != owner[row_of]
        nb, row_of = nb[keep], row_of[keep]
        start = np.full(2 * len(pts), -1, dtype=np.int64)  # -1: not computed
        start[rows] = np.searchsorted(row_of, np.arange(len(rows)))
        stop = np.full(2 * len(pts), -1, dtype=np.int64)
        stop[rows] = np.searchsorted(row_of, np.arange(len(rows)), side="right")
        self._nb_start, self._nb_stop = start.tolist(), stop.tolist()
        mu = pts.dist_mean.ravel()[rows][row_of]
        sd = pts.dist_sd.ravel()[rows][row_of]
        vec = pts.xy[nb] - pts.xy[owner[row_of]]
        d = np.sqrt((vec * vec).sum(axis=1))
        unit = vec / np.maximum(d, 1e-9)[:, None]
        self._nb = (nb, vec, d, unit, -0.5 * ((d - mu) / sd) ** 2, -0.5 * (d / mu) ** 2)

    def _neighbourhood(self, v, slot):
        """(points, offsets, distances, unit vectors, log transition weight of the distance,
        log weight of a relaxed step's distance) of the points within reach of v's slot."""
        r = 2 * v + slot
        if r < len(self._nb_stop) and self._nb_start[r] >= 0:
            lo, hi = self._nb_start[r], self._nb_stop[r]
            return tuple(a[lo:hi] for a in self._nb)
        mu, sd = self.p.dist_mean[v, slot], self.p.dist_sd[v, slot]
        reach = self.s.reach(mu, sd)
        nb = np.asarray(self.kd.query_ball_point(self.xy[v], reach, return_sorted=False),
                        dtype=np.int64)
        nb = np.sort(nb[nb != v])
        vec = self.xy[nb] - self.xy[v]
        d = np.sqrt((vec * vec).sum(axis=1))
        unit = vec / np.maximum(d, 1e-9)[:, None]
        return nb, vec, d, unit, -0.5 * ((d - mu) / sd) ** 2, -0.5 * (d / mu) ** 2

    def _show_points(self, n: int):
        """Point views onto the first ``n`` rows of the point arrays."""
        rows = self._pts_rows
        self.p = iq.PointSet(**{k: getattr(rows, k)[:n] for k in iq.PointSet.__dataclass_fields__})
        self.xy = self.p.xy
        for name, a in self._point_rows.items():
            setattr(self, name, a[:n])

    @property
    def edge_alive(self) -> np.ndarray:
        return self._edge_alive[:len(self.edges)]

    # -- segment index ---------------------------------------------------------------

    def _add_segment(self, p, q, edge=-1):
        i = self.n_seg
        if i == len(self._coords):
            self._coords, self._geoms, self._seg_edge, self._seg_start, self._seg_level = (
                _reserve(a, i + 1) for a in (self._coords, self._geoms, self._seg_edge,
                                             self._seg_start, self._seg_level))
        ends = (float(p[0]), float(p[1]), float(q[0]), float(q[1]))
        self._coords[i] = ends
        self._ends.append(ends)
        self._seg_edge[i] = edge
        if edge >= 0:
            self._edge_seg[edge] = i
            self._seg_start[i] = self.edges[edge][0]
            self._seg_level[i] = self.edges[edge][4]
        else:
            self._seg_start[i] = self._seg_level[i] = -1
        self._grid.add(i, self._box(i))
        self.n_seg += 1

    def _box(self, i):
        x0, y0, x1, y1 = self._ends[i]
        return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)

    def _kill_segment(self, i):
        """A segment split or dropped: out of the grid, so no test meets it any more."""
        self._grid.remove(i, self._box(i))

    def _geometries(self, ids):
        """The segments' LineStrings (made on first use)."""
        ids = np.asarray(ids, dtype=np.int64)
        g = self._geoms[ids]
        new = ids[[x is None for x in g]]
        if len(new):
            self._geoms[new] = shapely.linestrings(self._coords[new].reshape(-1, 2, 2))
            g = self._geoms[ids]
        return g

    def _near_point(self, xy, distance):
        """Indices of the live segments within ``distance`` of the point ``xy``
        (ascending)."""
        x, y = float(xy[0]), float(xy[1])
        pad = distance + 1e-3  # the box of everything within distance, and a hair more
        ids = np.array(sorted(self._grid.near(x - pad, y - pad, x + pad, y + pad)),
                       dtype=np.int64)
        if not len(ids):
            return ids
        c = self._coords[ids]
        a, u = c[:, :2], c[:, 2:] - c[:, :2]
        ll = (u * u).sum(axis=1)
        t = np.clip(((xy - a) * u).sum(axis=1) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
        off = xy - a - t[:, None] * u
        gap = np.sqrt((off * off).sum(axis=1))
        near = gap <= distance
        # GEOS decides where the floats cannot tell (the gap within a micrometre)
        unsure = np.flatnonzero(np.abs(gap - distance) <= 1e-6)
        if len(unsure):
            near[unsure] = shapely.dwithin(self._geometries(ids[unsure]), shapely.Point(xy),
                                           distance)
        return ids[near]

    def _clear_of(self, p, q, q_is_end=True, skip=-1):
        """Whether the step p -> q keeps _TOUCH clear of every live segment but ``skip``,
        except for those sharing its end p (or q, where ``q_is_end``): they meet it there,
        and the angles there are checked apart. Segments are ruled out by their ends and
        boxes first, then tested in floats (:func:`_segments_within`); GEOS decides where
        the floats cannot (the same answers as GEOS for all, at a fraction of the cost of
        its calls for a few segments)."""
        px, py, qx, qy = float(p[0]), float(p[1]), float(q[0]), float(q[1])
        pad = _TOUCH + 1e-3
        xmin, ymin = min(px, qx) - pad, min(py, qy) - pad
        xmax, ymax = max(px, qx) + pad, max(py, qy) + pad
        ends = self._ends
        close = []
        for i in self._grid.near(xmin, ymin, xmax, ymax):
            x0, y0, x1, y1 = ends[i]
            if (i == skip or abs(x0 - px) + abs(y0 - py) < 1e-6
                    or abs(x1 - px) + abs(y1 - py) < 1e-6
                    or (q_is_end and (abs(x0 - qx) + abs(y0 - qy) < 1e-6
                                      or abs(x1 - qx) + abs(y1 - qy) < 1e-6))):
                continue
            if max(x0, x1) < xmin or min(x0, x1) > xmax or max(y0, y1) < ymin \
                    or min(y0, y1) > ymax:
                continue  # its box is farther than _TOUCH
            near = _segments_within(px, py, qx, qy, x0, y0, x1, y1, _TOUCH)
            if near:
                return False
            if near is None:
                close.append(i)
        step = None
        if close:
            step = shapely.LineString([p, q])
            if shapely.dwithin(self._geometries(close), step, _TOUCH).any():
                return False
        if self.corridor is None:
            return True
        # nor along a given road, in its corridor longer than the invariants allow
        step = shapely.LineString([p, q]) if step is None else step
        if not self.corridor.intersects(step):
            return True
        return shapely.intersection(step, self.corridor).length <= MIN_DUPLICATE_LENGTH

    def _inside(self, p, q) -> bool:
        """Whether the step p -> q stays in the target (within a metre): between two
        points of a concave target a straight step can cross land outside it (on the
        fidelity benchmark's towns 0.3-7 km of streets per town did, single steps up to
        1.7 km across the fields between a town's parts)."""
        return self.area is None or bool(shapely.covers(self.area, shapely.linestrings(
            [p, q])))

    def _clear(self, v, j, q=None):
        """Whether the step v -> j (or to the location q) stays in the target and keeps
        clear of every segment except at a shared end."""
        q = self.xy[j] if q is None else q
        return self._clear_of(self.xy[v], q) and self._inside(self.xy[v], q)

    # -- growing the point set (junctions made on a street by a join) ----------------------

    def _add_point(self, xy, like: int, level, through_dirs, on_given: bool):
        """A new point at ``xy`` with the attributes of point ``like``; street a (``level``)
        passes through it along ``through_dirs`` (two unit vectors), street b is free for
        one connection (a T junction). Returns its index."""
        k = len(self.p)
        rows = self._pts_rows
        if k == len(rows):
            rows = iq.PointSet(**{f: _reserve(getattr(rows, f), k + 1)
                                  for f in iq.PointSet.__dataclass_fields__})
            self._pts_rows = rows
            self._point_rows = {name: _reserve(a, k + 1) for name, a in self._point_rows.items()}
        for f in iq.PointSet.__dataclass_fields__:
            a = getattr(rows, f)
            a[k] = a[like]
        rows.xy[k] = np.asarray(xy, dtype=float).reshape(2)
        rows.level[k] = level
        rows.example[k] = ROAD_SLOT if on_given else max(int(rows.example[like]), 0)
        rows.generated[k] = True
        rows.source[k] = -1  # made by a join, not from the example
        rows.degree[k] = 3
        for name, value in (("cap", 3), ("cnt", (2, 1)), ("slot_dir", 0.0), ("deg", 2),
                            ("used", (True, False)), ("_mark", False)):
            self._point_rows[name][k] = value
        self._show_points(k + 1)
        self.adj.append(set())
        self.dirs.append([np.asarray(d, dtype=float) for d in through_dirs])
        return k

    def _new_edge(self, a, sa, b, sb, h, origin):
        """Record the edge a -> b and add its segment."""
        e = len(self.edges)
        if e == len(self._edge_ends):
            self._edge_ends, self._edge_seg, self._edge_alive = (
                _reserve(x, e + 1) for x in (self._edge_ends, self._edge_seg, self._edge_alive))
        self.edges.append((a, sa, b, sb, h, origin))
        self._edge_ends[e] = (a, b)
        self._edge_alive[e] = True
        self._add_segment(self.xy[a], self.xy[b], e)

    def split_segment(self, seg: int, xy, like: int) -> int:
        """Split a live segment at ``xy`` (a point on it): a new junction point, the two
        halves as segments (and edges, for a walk edge). Returns the new point's index."""
        c = self._coords[seg]
        p, q = c[:2].copy(), c[2:].copy()
        d = (q - p) / max(np.linalg.norm(q - p), 1e-9)
        e = int(self._seg_edge[seg])
        level = self.edges[e][4] if e >= 0 else int(self.p.level[like, 0])
        k = self._add_point(xy, like, level, [d, -d], on_given=e < 0)
        self._kill_segment(seg)
        if e >= 0:
            a, sa, b, sb, h, origin = self.edges[e]
            self.edge_alive[e] = False
            self.adj[a].discard(b)
            self.adj[b].discard(a)
            for u, w, su, sw in ((a, k, sa, 0), (k, b, 0, sb)):
                self._new_edge(u, su, w, sw, h, origin)
                self.adj[u].add(w)
                self.adj[w].add(u)
        else:
            self._add_segment(p, self.xy[k], -1)
            self._add_segment(self.xy[k], q, -1)
        return k

    # -- one step --------------------------------------------------------------------

    def _angles_ok(self, v, j, unit):
        """Streets leave v and j at least min_angle apart from the streets already there."""
        if self.dirs[v] and (np.asarray(self.dirs[v]) @ unit).max() >= self.cos_min:
            return False
        return not (self.dirs[j] and (np.asarray(self.dirs[j]) @ -unit).max() >= self.cos_min)

    def _face_limit(self, v) -> float:
        """The shortest ring of streets a step from v may close (m; 0: any)."""
        if not self.s.min_face or not self.check_rings:
            return 0.0
        a = self.p.area[v]
        if not math.isfinite(a):
            a = self._area_fill
        return self.s.min_face * math.sqrt(a)

    def _graph_distances(self, v, limit) -> dict:
        """Network distances from v along the walk's edges, under ``limit`` m (Dijkstra
        on the walker's own adjacency, which changes at every step: a graph library would
        be rebuilt each time for a search of a few dozen nodes)."""
        xy = self.xy
        best = {v: 0.0}
        heap = [(0.0, v)]
        while heap:
            d, u = heapq.heappop(heap)
            if d > best.get(u, math.inf):
                continue
            ux, uy = xy[u]
            for x in self.adj[u]:
                nd = d + math.hypot(xy[x, 0] - ux, xy[x, 1] - uy)
                if nd < limit and nd < best.get(x, math.inf):
                    best[x] = nd
                    heapq.heappush(heap, (nd, x))
        return best

    def _closes_small_face(self, v, j, dist) -> bool:
        """Whether a step v -> j of ``dist`` m closes a ring of streets shorter than
        :meth:`_face_limit` (``WalkSettings.min_face``)."""
        if self.deg[j] == 0 or self.deg[v] == 0 or not self.check_rings:
            return False
        limit = self._face_limit(v) - dist
        if limit > 0 and j in self._graph_distances(v, limit):
            self.n_small_faces_refused += 1
            return True
        return False

    def _feasible(self, v, j, unit, dist, vec, nb, rel=None, at=None):
        """The constraints of a step v -> j that need its neighbourhood (fig. 5a iv);
        ``rel``: the offsets of ``nb`` from v, and ``at``: j's place in ``nb``, where
        known."""
        ux, uy = unit.tolist()
        for dx, dy in self.dirs[j]:  # a street at j within min_angle of the step
            if dx * -ux + dy * -uy >= self.cos_min:
                return False
        # no step passes over another point: streets cross only at intersection points
        if rel is None:
            rel = self.xy[nb] - self.xy[v]
        u = np.minimum(np.maximum(rel @ unit / max(dist, 1e-9), 0.0), 1.0)
        off = rel - u[:, None] * vec
        near = np.sqrt(np.add.reduce(off * off, axis=1)) < max(self.s.clearance * dist,
                                                               self.s.min_clearance)
        near[nb == j if at is None else at] = False  # j is the step's end
        if np.count_nonzero(near):
            return False
        return self._clear(v, j)

    def step(self, v, slot, h, prev_dir, relaxed=False):
        """The next point of a walk from v (street slot ``slot``, level h), or None."""
        p = self.p
        nb, vec, d, unit, logp, log_relaxed = self._neighbourhood(v, slot)
        if len(nb) == 0:
            return None
        lv = p.level[nb]
        # seam joins connect two hierarchies ranked apart: there any level may join; other
        # steps keep to their street's level (sec. 3.1.1)
        slot_ok = ((lv >= 0) if relaxed == "seam" else (lv == h)) & (self.cnt[nb] < 2)
        # there a point may get more connections than its example had (up to 4)
        cap = np.where(p.example[nb] >= 0, self.s.max_capacity, self.cap[nb]) \
            if relaxed else self.cap[nb]
        free = (self.deg[nb] < cap) & (slot_ok[:, 0] | slot_ok[:, 1])
        if relaxed == "across":  # a crossing street goes on onto the network, no new stub
            free &= self.deg[nb] > 0
        if self.adj[v]:
            linked = set(self.adj[v])
            if relaxed:
                # a closing step makes no triangle (a face of three streets: a sliver
                # block the example's streets would not close)
                for u in self.adj[v]:
                    linked |= self.adj[u]
            linked = list(linked)
            self._mark[linked] = True
            free &= ~self._mark[nb]
            self._mark[linked] = False
        # the weights of all neighbours, zero for those that may not be joined
        if prev_dir is not None and not relaxed:
            alpha = np.degrees(np.arccos(np.clip(unit @ prev_dir, -1.0, 1.0)))
            logp = logp - 0.5 * ((alpha - p.angle_mean[v, slot]) / p.angle_sd[v, slot]) ** 2
        w_angle = 0.0
        if relaxed in ("close", "across") and prev_dir is not None:
            # a stub (or a T's street) goes on about straight (its street's turn
            # statistics, twice as wide)
            alpha = np.degrees(np.arccos(np.clip(unit @ prev_dir, -1.0, 1.0)))
            w_angle = -0.5 * ((alpha - p.angle_mean[v, slot]) / (2 * p.angle_sd[v, slot])) ** 2
        elif relaxed == "cross" and self.dirs[v]:
            # a crossing street leaves across the street through v (the example's 90 degrees
            # give or take 30)
            through = np.asarray(self.dirs[v])
            across = np.abs(unit @ through.T).max(axis=1)
            alpha = np.degrees(np.arcsin(np.clip(across, 0.0, 1.0)))
            w_angle = -0.5 * (alpha / 30.0) ** 2
        prob = np.exp(logp)
        good = free & (prob >= self.s.threshold)
        # streets leave a point at least min_angle apart (at v and at the target)
        if self.dirs[v]:
            good &= (unit @ np.asarray(self.dirs[v]).T).max(axis=1) < self.cos_min
        w = np.where(good, prob if not relaxed else np.exp(log_relaxed + w_angle), 0.0)
        # draw by the transition probabilities; the costlier constraints are checked on the
        # drawn point only, and a point that fails them gets p = 0 and the draw is repeated
        # (the same distribution as checking all first)
        while True:
            cum = w.cumsum()
            total = cum[-1]
            if total <= 0:
                return None
            k = int(cum.searchsorted(self.rng.random() * total, side="right"))
            if k == len(w):  # the draw rounded up to the total: the last weighted point
                k = int(np.flatnonzero(w)[-1])
            if self._feasible(v, nb[k], unit[k], d[k], vec[k], nb, rel=vec, at=k) and not (
                    relaxed and self._closes_small_face(v, nb[k], d[k])):
                break
            w[k] = 0.0
        j = nb[k]
        s_ok = slot_ok[k]
        c = self.cnt[j]
        # a fresh slot continues the street; a half-used one joins another street's end
        if s_ok[0] and s_ok[1]:
            ns = 0 if c[0] <= c[1] else 1
        else:
            ns = 0 if s_ok[0] else 1
        return j, ns

    def add_edge(self, a, sa, b, sb, h, origin):
        d = self.xy[b] - self.xy[a]
        d = d / max(math.sqrt(d[0] * d[0] + d[1] * d[1]), 1e-9)
        if self.cnt[a, sa] == 0:
            self.slot_dir[a, sa] = -d
        if self.cnt[b, sb] == 0:
            self.slot_dir[b, sb] = d
        self.cnt[a, sa] = min(self.cnt[a, sa] + 1, 2)
        self.cnt[b, sb] = min(self.cnt[b, sb] + 1, 2)
        self.used[a, sa] = self.used[b, sb] = True
        self.deg[a] += 1
        self.deg[b] += 1
        self.adj[a].add(b)
        self.adj[b].add(a)
        self.dirs[a].append(d)
        self.dirs[b].append(-d)
        self._new_edge(a, sa, b, sb, h, origin)

    def extend(self, cur, cs, h, relaxed=False, origin="walk"):
        added = 0
        while self.deg[cur] < self.cap[cur] and self.cnt[cur, cs] < 2:
            prev = self.slot_dir[cur, cs] if self.cnt[cur, cs] == 1 and self.used[cur, cs] \
                else None
            r = self.step(cur, cs, h, prev, relaxed)
            if r is None:
                break
            nxt, ns = r
            joined = self.cnt[nxt, ns] == 1
            self.add_edge(cur, cs, nxt, ns, h, origin)
            added += 1
            if joined or relaxed:
                break
            cur, cs = nxt, ns
        return added

    def walk(self, start, slot, h):
        """A street through ``start``: grown forward, then from the start the other way."""
        n = self.extend(start, slot, h)
        if n and self.cnt[start, slot] == 1:
            n += self.extend(start, slot, h)
        return n

    # -- the REPEAT: one network --------------------------------------------------------

    def live_edges(self) -> np.ndarray:
        return self._edge_ends[:len(self.edges)][self.edge_alive]

    def pieces(self, anchors: np.ndarray):
        """Component label per point (edges of the walk; all ``anchors`` in one component),
        and the label of the network the others must join (the anchors', else the
        largest piece's)."""
        n = len(self.p)
        e = self.live_edges()
        rows = [e[:, 0]]
        cols = [e[:, 1]]
        if len(anchors) > 1:
            rows.append(anchors[:-1])
            cols.append(anchors[1:])
        r, c = np.concatenate(rows), np.concatenate(cols)
        adj = coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
        _, label = connected_components(adj, directed=False)
        if len(anchors):
            main = label[anchors[0]]
        else:
            on = self.deg > 0
            main = np.bincount(label[on]).argmax() if on.any() else -1
        return label, main

    def _free_slot(self, v, saturated=False):
        """The street slot of v that can take one more connection (the emptier one);
        ``saturated``: the emptier of its slots even when both are full."""
        c = self.cnt[v]
        ok = (self.p.level[v] >= 0) & ((c < 2) | saturated)
        if not ok.any():
            return None
        return int(np.flatnonzero(ok)[np.argmin(c[ok])])

    def _join_by_point(self, members, root, tree, pool, reach, saturated=False):
        """The shortest clear step from a point of ``members`` to a connected point of
        another piece (``root(points)`` gives each point's piece; ``tree`` indexes the
        candidate points ``pool``; ``saturated``: through full street slots too). Returns
        the joined point, or -1."""
        cap = self.s.max_capacity
        ok = members[self.deg[members] < cap]
        if not len(ok) or tree is None:
            return -1
        k = min(12, len(pool))
        dist, idx = tree.query(self.xy[ok], k=k, distance_upper_bound=reach)
        dist, idx = dist.reshape(len(ok), k), idx.reshape(len(ok), k)
        own = root(ok[:1])[0]
        for flat in np.argsort(dist, axis=None):
            i, j = np.unravel_index(flat, dist.shape)
            if not np.isfinite(dist[i, j]):
                break
            v, u = ok[i], pool[idx[i, j]]
            if self.deg[u] == 0 or self.deg[u] >= cap or root(np.array([u]))[0] == own:
                continue
            if self.area is not None and self.p.example[u] < 0 and \
                    not shapely.contains_xy(self.area, *self.xy[u]):
                continue  # a node of the given roads outside the target takes no street
            vec = self.xy[u] - self.xy[v]
            d = float(np.linalg.norm(vec))
            if d < 1e-6:
                continue
            unit = vec / d
            sv, su = self._free_slot(v, saturated), self._free_slot(u, saturated)
            if sv is None or su is None or not self._angles_ok(v, u, unit):
                continue
            nb = np.asarray(self.kd.query_ball_point(self.xy[v], d + 1.0), dtype=np.int64)
            nb = nb[(nb != v) & (nb < len(self.p))]
            if not self._feasible(v, u, unit, d, vec, nb):
                continue
            self.add_edge(v, sv, u, su, int(self.p.level[v, sv]), "join")
            return int(u)
        return -1

    def _join_by_split(self, members, root, reach, origin="join", level=None,
                       saturated=False):
        """A clear step from a point of ``members`` onto the nearest street of another piece
        (or a given road), split there: a new T junction. ``root(points)`` gives each
        point's piece; None: any street not at the point (closing a dead end), of ``level``
        where given. Returns (the new junction, the street's end point (-1 for a given
        road)), or None."""
        cap = self.s.max_capacity
        best = None
        for v in members[self.deg[members] < cap]:
            sv = self._free_slot(v, saturated)
            if sv is None:
                continue
            pv = self.xy[v]
            hit = self._near_point(pv, reach)
            if not len(hit):
                continue
            seg = self._coords[hit]
            e = self._seg_edge[hit]
            if root is None:  # any street that does not end at v
                ends = seg.reshape(-1, 2, 2)
                keep = ~(np.abs(ends - pv).sum(axis=2) < 1e-6).any(axis=1)
                if level is not None:  # of that level (or a given road)
                    keep &= (e < 0) | (self._seg_level[hit] == level)
            else:  # another piece's street, or a given road (never v's piece)
                end_pt = self._seg_start[hit]
                keep = end_pt < 0
                if (end_pt >= 0).any():
                    keep[end_pt >= 0] = root(end_pt[end_pt >= 0]) != root(np.array([v]))[0]
            if not keep.any():
                continue
            seg, hit = seg[keep], hit[keep]
            p0, p1 = seg[:, :2], seg[:, 2:]
            dvec = p1 - p0
            ll = np.maximum((dvec ** 2).sum(axis=1), 1e-12)
            t = np.clip(((pv - p0) * dvec).sum(axis=1) / ll, 0.0, 1.0)
            # stay off the segment's ends by a quarter street gap (a point there joins)
            margin = np.minimum(0.25 * self.p.dist_mean[v, sv], 0.4 * np.sqrt(ll)) / np.sqrt(ll)
            t = np.clip(t, margin, 1.0 - margin)
            q = p0 + t[:, None] * dvec
            d = np.linalg.norm(q - pv, axis=1)
            # closing a dead end or a crossing street: no ring shorter than min_face (a
            # join reaches another piece, never v's own)
            ring_limit = self._face_limit(v) if root is None and self.deg[v] > 0 else 0.0
            near_v = self._graph_distances(v, ring_limit) if ring_limit > 0 else {}
            for i in np.argsort(d, kind="stable"):  # ties: the older segment
                if best is not None and d[i] >= best[0]:
                    break
                if d[i] < 1.0:
                    continue
                unit = (q[i] - pv) / d[i]
                along = dvec[i] / np.sqrt(ll[i])
                # the new street meets the split street at least min_angle from it
                if abs(unit @ along) >= self.cos_min:
                    continue
                if self.dirs[v] and (np.asarray(self.dirs[v]) @ unit).max() >= self.cos_min:
                    continue
                if self.area is not None and not shapely.contains_xy(self.area, *q[i]):
                    continue
                if near_v and self._seg_edge[hit[i]] >= 0:
                    ea, _, eb = self.edges[int(self._seg_edge[hit[i]])][:3]
                    ring = min(near_v.get(ea, math.inf) + np.linalg.norm(self.xy[ea] - q[i]),
                               near_v.get(eb, math.inf) + np.linalg.norm(self.xy[eb] - q[i]))
                    if ring + d[i] < ring_limit:
                        self.n_small_faces_refused += 1
                        continue
                if not self._clear_except(v, q[i], hit[i]):
                    continue
                best = (d[i], v, sv, hit[i], q[i])
                break
        if best is None:
            return None
        _, v, sv, seg, q = best
        e = int(self._seg_edge[seg])
        end = self._edge_end(e) if e >= 0 else -1
        k = self.split_segment(seg, q, end if end >= 0 else v)
        self.add_edge(v, sv, k, 1, int(self.p.level[v, sv]), origin)
        return k, end

    def _edge_end(self, e):
        return self.edges[e][0]

    def _clear_except(self, v, q, seg):
        """Whether the step v -> q keeps clear of every live segment but ``seg`` (which it
        ends on) and those sharing v."""
        return self._clear_of(self.xy[v], q, q_is_end=False, skip=seg) and \
            self._inside(self.xy[v], q)

    def join_pieces(self, anchors):
        """Join every piece to the anchors' network (or the largest piece) by a step; what
        no step joins is left as it is (:func:`synthesize` links it by a street through the
        target, or drops it). Returns counts. The pieces are found once and merged (a
        disjoint set of their labels) as joins are made."""
        joined = split = apart = through_full_slots = 0
        label, main = self.pieces(anchors)
        if main < 0:
            return {"n_joins": 0, "n_join_splits": 0, "n_pieces_apart": 0,
                    "n_joins_saturated": 0}
        merged = DisjointSet(range(label.max() + 1))

        def root(points):
            return np.array([merged[x] for x in label[points]])

        on = self.deg > 0
        labs, sizes = np.unique(label[on], return_counts=True)
        order = labs[np.lexsort((labs, sizes))]
        cap = self.s.max_capacity
        pool = np.flatnonzero(on & (self.deg < cap))
        tree = cKDTree(self.xy[pool]) if len(pool) else None
        by_label = {}
        idx = np.flatnonzero(on)
        srt = idx[np.argsort(label[idx], kind="stable")]
        bounds = np.searchsorted(label[srt], labs)
        for i, lab in enumerate(labs):
            end = bounds[i + 1] if i + 1 < len(labs) else len(srt)
            by_label[lab] = srt[bounds[i]:end]
        for lab in order:
            if merged.connected(lab, main):
                continue
            members = by_label[lab]
            members = members[self.deg[members] > 0]
            if not len(members):
                continue
            reach = self.s.join_reach * float(np.median(self.p.dist_mean[members, 0]))
            # a piece whose points near the rest have used their street slots joins through
            # a full slot rather than being dropped (a third of a town was, on Vaduz), and
            # then by a step up to twice as long
            for saturated, far in ((False, 1.0), (True, 1.0), (True, 2.0)):
                u = self._join_by_point(members, root, tree, pool, far * reach, saturated)
                if u >= 0:
                    merged.merge(lab, label[u])
                    joined += 1
                    break
                r = self._join_by_split(members, root, far * reach, saturated=saturated)
                if r is not None:
                    k, end = r
                    other = label[end] if end >= 0 else main
                    label = np.r_[label, other]
                    merged.merge(lab, other)
                    split += 1
                    break
            else:
                apart += 1  # no step reaches (an arm of the target, built land far away)
                continue
            through_full_slots += saturated
        return {"n_joins": joined, "n_join_splits": split, "n_pieces_apart": apart,
                "n_joins_saturated": through_full_slots}


def _close_seam_ends(w: "_Walker", points: iq.PointSet, seam, is_new, share: float, area,
                     rng) -> int:
    """Seam ends that no step reached (a given street cut where the target begins: the
    street goes on into it) end on the nearest street instead (a T, as a stub is closed),
    in random order, while more of them stay open than the example ends its streets
    (``share``, its dead-end share; not in the paper, whose walks leave them open: 5 of the
    15 streets a 300 m hole in Helsinki cuts stayed open, 0.33 against the example's 0.21).
    Only a street that arrives from outside the target goes on into it: a given road that
    leaves the target there (an arterial at a town's edge) ends where it was cut. Returns
    the number of seam ends closed."""
    seams = np.flatnonzero(seam)
    if not len(seams):
        return 0
    # a street that goes on into the target: 5 m on from its end, along it, is inside
    ahead = points.xy[seams] + 5.0 * w.slot_dir[seams, 0]
    seams = seams[shapely.contains_xy(area, ahead[:, 0], ahead[:, 1])]
    # the reach of a typical new point's step (WalkSettings.reach)
    reach = float(np.nanmedian(w.s.reach(points.dist_mean[is_new, 0],
                                         points.dist_sd[is_new, 0]))) \
        if is_new.any() else math.nan

    def too_many_open() -> bool:
        return (w.cnt[seams, 0] == 1).sum() > share * len(seams)

    if not (np.isfinite(reach) and too_many_open()):
        return 0
    closed = 0
    for v in rng.permutation(seams[w.cnt[seams, 0] == 1]):
        if not too_many_open():
            break
        closed += w._join_by_split(np.array([v]), None, reach, "seam") is not None
    return closed


def connect_points(points: iq.PointSet, rng: np.random.Generator,
                   settings: Optional[WalkSettings] = None, existing=None,
                   dead_end_share: Optional[float] = None, area=None,
                   progress: Optional[Progress] = None,
                   crossing_share: Optional[float] = None):
    """Connect attributed points by random walks, level by level (fig. 3), into one network.

    Parameters
    ----------
    points : PointSet (new points first; given-road nodes and junction slots have
        ``example`` < 0)
    existing : dict, optional, from :func:`_existing_state`: capacities, slot counts and
        directions of the existing points and the existing segments (crossing constraints).
    dead_end_share : float, optional
        Close stubs until the dead-end share of the new points is at most this (default:
        the example's, :func:`dead_end_share_of`).
    crossing_share : float, optional
        Make T junctions crossings until the share of 4-way junctions is at least this
        (default: the example's, :func:`crossing_share_of`; ``settings.match_crossings``).

    Returns
    -------
    edges : (m, 6) object array rows (a, slot_a, b, slot_b, level, origin) of the live edges
    walker : the final state (points, which may have grown by junctions made on streets;
        degrees, slot counts, counts of joins in ``walker.stats``)
    """
    progress = ensure(progress)
    s = (settings or WalkSettings()).validate()
    n = len(points)
    cap = np.minimum(points.degree, s.max_capacity).astype(np.int64)
    # connections each street slot may take: street a (the more important) passes through
    # while the point has 2 connections for it; street b gets what is left (one at a
    # T-junction: it ends there). A slot that starts half used is a street end: a walk
    # arriving there stops, and no walk starts from it.
    slot_max = np.column_stack([np.minimum(cap, 2), np.clip(cap - 2, 0, 2)])
    cnt = np.where(points.level >= 0, 2 - slot_max, 2).astype(np.int64)
    slot_dir = np.zeros((n, 2, 2))
    dirs = [[] for _ in range(n)]
    seg0 = np.zeros((0, 4))
    seam = np.zeros(n, dtype=bool)
    if existing is not None:
        ex = existing["index"]
        cap[ex] = existing["cap"]
        cnt[ex] = existing["cnt"]
        slot_dir[ex] = existing["slot_dir"]
        for i, dl in zip(ex, existing["dirs"]):
            dirs[i] = list(dl)
        seg0 = existing["segments"]
        seam[ex[existing["seam"]]] = True
    w = _Walker(points, s, rng, cap, cnt, slot_dir, dirs, seg0)
    if area is not None:
        w.area = allowed_area(area)
    if len(seg0):
        w.corridor = corridor_of(shapely.linestrings(seg0.reshape(-1, 2, 2)))
    if existing is not None:
        w.deg[existing["index"]] = existing["degree"]
    levels = np.unique(points.level[points.level >= 0])
    for k, h in enumerate(levels):
        has = (points.level == h)
        # seam ends first (they continue existing streets), then fresh points at random
        seam_starts = np.flatnonzero(seam & has.any(axis=1))
        fresh = rng.permutation(np.flatnonzero(~seam & has.any(axis=1)))
        for i, v in enumerate(np.concatenate([seam_starts, fresh])):
            if i % 200 == 0:
                progress.step(0.8 * (k + i / max(len(fresh), 1)) / (len(levels) + 1))
            for slot in (0, 1):
                if points.level[v, slot] != h or w.deg[v] >= w.cap[v]:
                    continue
                # a fresh slot, a street end (set aside at a T-junction: the street starts
                # there) or an existing road's dead end at the seam
                end = w.cnt[v, slot] == 1 and (seam[v] or not w.used[v, slot])
                if w.cnt[v, slot] == 0 or end:
                    w.walk(v, slot, h)
    progress.step(0.7)
    # seam ends still open: the nearest free point of any level (connect to the old network)
    for v in np.flatnonzero(seam):
        for slot in (0, 1):
            if points.level[v, slot] >= 0 and w.cnt[v, slot] == 1 and w.deg[v] < w.cap[v]:
                w.extend(v, slot, points.level[v, slot], relaxed="seam", origin="seam")
    is_new = points.example >= 0
    # the dead-end share the stubs are steered to (below), and the seam ends held to
    target = dead_end_share_of(points) if dead_end_share is None else float(dead_end_share)
    n_seam_closed = _close_seam_ends(w, points, seam, is_new, target, area, rng) \
        if s.close_ends and area is not None else 0
    n_crossed = 0
    if s.close_ends:
        # points a street passes whose crossing street never came (degree 2 where the
        # example had 3 or 4): the crossing street leaves with one step to a free point, so
        # that the point is the junction it was
        # (and 3 where it had 4: the crossing street went on only one way)
        through = rng.permutation(np.flatnonzero((w.deg[:n] >= 2) & (w.deg[:n] < w.cap[:n])
                                                 & is_new))
        for v in through:
            for slot in (1, 0):
                h = points.level[v, slot]
                if h < 0 or w.deg[v] >= w.cap[v] or w.cnt[v, slot] >= 2:
                    continue
                added = w.extend(v, slot, h, relaxed="cross", origin="cross")
                if not added:  # no free point in reach: a T onto the nearest street
                    reach = s.reach(points.dist_mean[v, slot], points.dist_sd[v, slot])
                    added = int(w._join_by_split(np.array([v]), None, reach, "cross",
                                                 level=h) is not None)
                n_crossed += added
    progress.step(0.8)
    w.stats = {"n_seam_ends_closed": int(n_seam_closed), "n_crossings_made": int(n_crossed),
               "n_joins": 0, "n_join_splits": 0, "n_pieces_apart": 0,
               "n_joins_saturated": 0}
    if s.join_pieces:
        anchors = np.flatnonzero(points.example < 0) if existing is not None else \
            np.zeros(0, dtype=np.int64)
        w.stats.update(w.join_pieces(anchors))
    progress.step(0.9)
    inside = np.ones(0, dtype=bool)

    def node_degrees() -> np.ndarray:
        """Degrees of the nodes (degree != 2) as the network will be measured
        (:func:`invariants.dead_end_share`): every point the walker holds, the junctions its
        joins made and the given roads' nodes included, inside the target and away from its
        boundary (a street cut there has no dead end)."""
        nonlocal inside
        m = len(w.p)
        if len(inside) < m:  # the points added since (junctions made by joins)
            more = counted_nodes(w.xy[len(inside):m], area) if area is not None else \
                np.ones(m - len(inside), dtype=bool)
            inside = np.concatenate([inside, more])
        deg = w.deg[:m]
        return deg[(deg > 0) & (deg != 2) & inside]

    def crossings_now() -> float:
        deg = node_degrees()
        return float((deg >= 4).mean()) if len(deg) else 0.0

    def across(v, split: bool) -> bool:
        """A T junction becomes a crossing: its own street goes on straight across the
        street it meets, one step to a connected free point, else (``split``) a T onto the
        nearest street of its level."""
        d = np.asarray(w.dirs[v])
        if w.deg[v] != 3 or len(d) != 3:
            return False
        stem = t_stem(d)
        if stem is None:
            return False
        slot = 1 if w.p.level[v, 1] >= 0 else 0
        h = int(w.p.level[v, slot])
        before = (w.cap[v], w.cnt[v, slot], w.used[v, slot], w.slot_dir[v, slot].copy())
        w.cap[v], w.cnt[v, slot], w.used[v, slot] = max(w.cap[v], 4), 1, True
        w.slot_dir[v, slot] = -d[stem]  # as if the street arrived along its stem
        added = w.extend(v, slot, h, relaxed="across", origin="across")
        if not added and split:
            reach = s.reach(w.p.dist_mean[v, slot], w.p.dist_sd[v, slot])
            added = int(w._join_by_split(np.array([v]), None, reach, "across",
                                         level=h) is not None)
        if not added:
            w.cap[v], w.cnt[v, slot], w.used[v, slot], w.slot_dir[v, slot] = before
        return bool(added)

    def t_junctions():
        # the example's crossings whose crossing street went on only one way, then the
        # junction slots of the given roads (a given road crossed, not only met); other T
        # junctions stay T's (the walk made them so)
        m = len(w.p)
        t = (w.deg[:m] == 3) & ((w.p.example >= 0) | (w.p.example == ROAD_SLOT))
        t[:len(inside)] &= inside
        was = t & (np.minimum(w.p.degree, s.max_capacity) >= 4)
        slot = t & ~was & (w.p.example == ROAD_SLOT)
        return np.concatenate([rng.permutation(np.flatnonzero(was)),
                               rng.permutation(np.flatnonzero(slot))])

    n_across = 0
    if s.match_crossings:
        node_degrees()  # which points count (inside), before the candidates are listed
        target_x = crossing_share_of(points) if crossing_share is None else \
            float(crossing_share)
        # steps onto free points first (they make no new T), then T's onto streets
        for split in (False, True):
            n_across += steer_share(crossings_now, target_x, lambda v: False, lambda: (),
                                    lambda v: across(v, split), t_junctions)[1]
    w.stats["n_crossings_matched"] = int(n_across)
    w.stats["crossing_share"] = crossings_now()
    # closing stubs last: it only adds connections, so the network stays one piece

    def share_now() -> float:
        deg = node_degrees()
        return float((deg == 1).mean()) if len(deg) else 0.0

    def close(v, any_level=False) -> bool:
        """Streets that stopped short of what their point had in the example (deg 1 < cap):
        one more step to the nearest free point of any level, turn angle ignored, else a T
        onto the nearest street of its level; closing a ring shorter than ``min_face`` only
        where it closes no other way (the dead-end share is an invariant, the ring rule a
        preference: in a blend towards Bubenec's small blocks the stubs kept open moved
        the share to twice the example's). ``any_level``: a T onto a street of any level
        (the stub's street ends there, as at a join)."""
        if w.deg[v] != 1:
            return False
        was_end = w.cap[v] == 1
        if was_end:  # the street may go on from here: one more connection on slot a
            w.cap[v], w.cnt[v, 0] = 2, 1
            slot = 0
        else:
            slot = int(np.argmax(w.cnt[v] == 1))
        if w.cnt[v, slot] != 1:
            return False
        reach = s.reach(points.dist_mean[v, slot], points.dist_sd[v, slot])
        h = points.level[v, slot]
        for rings in (True, False):  # a short ring rather than a stub that stays
            w.check_rings = rings
            added = 0 if any_level else \
                w.extend(v, slot, h, relaxed="close", origin="close")
            if not added:  # no free point in reach: a T onto the nearest street
                added = int(w._join_by_split(np.array([v]), None, reach, "close",
                                             level=None if any_level else h) is not None)
            if added:
                break
        w.check_rings = True
        if not added and was_end:
            w.cap[v], w.cnt[v, 0] = 1, 2
        return bool(added)

    def stubs():
        # first the stubs, then (if the share is still above the example's) points that
        # were dead ends in the example too: copies near the edges of an example clipped to
        # a study area, whose clip ends are no dead ends of the town
        return np.concatenate([
            rng.permutation(np.flatnonzero((w.deg[:n] == 1) & (w.cap[:n] > 1) & is_new)),
            rng.permutation(np.flatnonzero((w.deg[:n] == 1) & (w.cap[:n] == 1) & is_new))])

    # the other way: a dead-end point of the example is only ever a walk's last step, so
    # many stay unreached and the share falls below the example's; unreached dead-end
    # points then get their street, one clear step onto the nearest street (a T)
    def open_(v) -> bool:
        reach = s.reach(points.dist_mean[v, 0], points.dist_sd[v, 0])
        return w._join_by_split(np.array([v]), None, reach, "dead_end") is not None

    def unreached():
        return rng.permutation(np.flatnonzero((w.deg[:n] == 0) & (w.cap[:n] == 1) & is_new))

    # the share is steered to the example's (network.dead_ends: one home for the rule)
    n_closed, n_opened = steer_share(share_now, target, close, stubs, open_, unreached) \
        if s.close_ends else (0, 0)
    # still above the invariants' band (with a margin): stubs with no street of their own
    # level in reach end on one of any level (Bubenec's stubs blended into a square of
    # Helsinki kept up to twice its dead ends); within the band, the level rule is kept
    margin = 0.5 * DEAD_END_TOLERANCE
    if s.close_ends and share_now() > target * (1 + margin):
        n_closed += steer_share(share_now, target, functools.partial(close, any_level=True),
                                stubs, lambda v: False, lambda: (), tolerance=margin)[0]
    w.stats["n_closed"] = int(n_closed)
    w.stats["n_dead_ends_opened"] = int(n_opened)
    w.stats["dead_end_share"] = share_now()
    w.stats["n_small_faces_refused"] = int(w.n_small_faces_refused)
    progress.step(1.0)
    alive = np.asarray(w.edge_alive, dtype=bool)
    edges = np.array(w.edges, dtype=object).reshape(-1, 6)[alive]
    return edges, w


# --------------------------------------------------------------------------- synthesis

@dataclass
class Synthesis:
    """Result of :func:`synthesize`.

    geometry, table : the new road segments (:data:`ROAD_FIELDS`)
    points, point_table : the attributed points used (:data:`POINT_FIELDS`); given-road
        nodes have example == -1, junction slots on given roads -2
    stats : counts (points, edges, dead ends, seam ends connected, joins ...)
    quadtrees : the quadtree of each example
    existing_lines : the given roads as used (noded, cleaned), or None
    """

    geometry: np.ndarray
    table: pd.DataFrame
    points: iq.PointSet
    point_table: pd.DataFrame
    stats: dict = field(default_factory=dict)
    quadtrees: list = field(default_factory=list)
    existing_lines: Optional[np.ndarray] = None


def _road_slot_points(graph, example: iq.PointSet, area, rng, min_gap_share=0.4):
    """Junction slots along the given roads inside the target (see the module docstring).

    Gaps along each given street are drawn from the example's distances between
    intersections along its level-0 streets (N(mu_d, sigma_d) of a random level-0 point,
    at least ``min_gap_share`` mu_d); each slot takes street b's statistics, degree and
    level from a random example point on a level-0 street that has a crossing street.

    Returns (xy (k, 2), donor index into ``example`` (k,), edge index (k,), distance along
    the edge (k,)).
    """
    lv0 = int(example.level[:, 0][example.level[:, 0] >= 0].min()) \
        if (example.level[:, 0] >= 0).any() else 0
    on_art = np.flatnonzero((example.level[:, 0] == lv0) & (example.level[:, 1] >= 0)
                            & (example.degree >= 3))
    on_lv0 = np.flatnonzero(example.level[:, 0] == lv0)
    empty = (np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if not len(on_art) or not len(on_lv0):
        return empty
    xy, donor, edge, dist = [], [], [], []
    shapely.prepare(area)
    node_xy = graph.nodes
    for e in range(graph.n_edges):
        g = graph.geometry[e]
        if not shapely.intersects(area, g):
            continue
        length = g.length
        t = 0.0
        k = int(on_lv0[rng.integers(len(on_lv0))])
        mu, sd = example.dist_mean[k, 0], example.dist_sd[k, 0]
        t = rng.uniform(0.0, mu)
        while t < length:
            xy_t = np.asarray(shapely.line_interpolate_point(g, t).coords[0])
            near_node = min(np.linalg.norm(node_xy[graph.u[e]] - xy_t),
                            np.linalg.norm(node_xy[graph.v[e]] - xy_t))
            if near_node >= min_gap_share * mu and shapely.contains_xy(area, *xy_t):
                xy.append(xy_t)
                donor.append(int(on_art[rng.integers(len(on_art))]))
                edge.append(e)
                dist.append(t)
            k = int(on_lv0[rng.integers(len(on_lv0))])
            mu, sd = example.dist_mean[k, 0], example.dist_sd[k, 0]
            t += max(rng.normal(mu, sd), min_gap_share * mu)
    if not xy:
        return empty
    return np.array(xy), np.array(donor), np.array(edge), np.array(dist)


def seam_distance(example: iq.PointSet, settings: Optional[WalkSettings] = None) -> float:
    """How close (m) to the target an existing road's dead end must be to be a seam end
    (the walks continue it): ``settings.seam_distance``, else a quarter of the example's
    median street distance."""
    if settings is not None and settings.seam_distance is not None:
        return float(settings.seam_distance)
    return 0.25 * float(np.median(example.dist_mean[:, 0]))


def _existing_state(lines, area, offset: int, seam_distance: float, example=None, rng=None,
                    slots: bool = True):
    """Existing roads as points (their nodes and junction slots) and constraints (their
    segments)."""
    from ..network import hierarchy
    from ..network import street_graph as roads

    lines = np.asarray(lines, dtype=object)
    graph = roads.clean_network(lines, snap_tolerance=ROAD_SNAP_TOLERANCE, merge_degree2=True)
    # nodes back onto the input's own line ends (cleaning rounds them to the millimetre),
    # so that new streets end exactly where the existing roads do
    raw = shapely.get_coordinates(shapely.boundary(shapely.get_parts(lines)))
    if len(raw):
        dist, near = cKDTree(raw).query(graph.nodes, distance_upper_bound=0.01)
        hit = np.isfinite(dist)
        graph.nodes = graph.nodes.copy()
        graph.nodes[hit] = raw[near[hit]]
    h = hierarchy.road_hierarchy(graph)
    table = hierarchy.intersection_attributes(graph, h.streets, h.street_level)
    pts = iq.points_from_table(graph.nodes, table, example=EXISTING)
    node = pts.source  # node ids kept
    deg = graph.degree[node]
    n = len(pts)
    near = shapely.distance(area, shapely.points(pts.xy)) <= seam_distance
    seam = (deg == 1) & near
    cap = np.where(seam, 2, deg)
    cnt = np.full((n, 2), 2, dtype=np.int64)
    cnt[seam, 0] = 1
    # the direction a seam end's street arrives with, from its last 10 m
    slot_dir = np.zeros((n, 2, 2))
    dirs = [[] for _ in range(n)]
    pos = {int(nd): i for i, nd in enumerate(node)}
    for e in range(graph.n_edges):
        g = graph.geometry[e]
        length = g.length
        for end, nd in ((0, graph.u[e]), (1, graph.v[e])):
            i = pos.get(int(nd))
            if i is None:
                continue
            probe = min(10.0, length / 2.0)
            other = shapely.line_interpolate_point(g, probe if end == 0 else length - probe)
            v = np.asarray(other.coords[0]) - pts.xy[i]
            v = v / max(np.linalg.norm(v), 1e-9)
            dirs[i].append(v)
            if seam[i]:
                slot_dir[i, 0] = -v
    # the lines' end vertices exactly on their (millimetre-rounded) nodes, so that new
    # streets meet them at one shared point
    graph.geometry = pinned_ends(graph.geometry, graph.nodes[graph.u], graph.nodes[graph.v])
    coords, idx = shapely.get_coordinates(graph.geometry, return_index=True)
    first = np.r_[True, idx[1:] != idx[:-1]]
    # junction slots along the given roads: split the segments there
    s_xy, s_donor, s_edge, s_dist = (np.zeros((0, 2)), np.zeros(0, np.int64),
                                     np.zeros(0, np.int64), np.zeros(0))
    if slots and example is not None:
        s_xy, s_donor, s_edge, s_dist = _road_slot_points(graph, example, area, rng)
    if len(s_xy):
        # distance of each vertex along its line (cumulative, exact for loops too)
        step = np.r_[0.0, np.linalg.norm(np.diff(coords, axis=0), axis=1)]
        step[first] = 0.0
        cum = np.cumsum(step)
        vdist = cum - cum[first][np.cumsum(first) - 1]
        key = np.r_[idx, s_edge]
        along = np.r_[vdist, s_dist]
        allxy = np.vstack([coords, s_xy])
        # vertices in order along each line; a slot sits between its neighbours
        order = np.lexsort((np.r_[np.arange(len(idx)), np.full(len(s_edge), -1)], along, key))
        seg_xy, seg_idx = allxy[order], key[order]
    else:
        seg_xy, seg_idx = coords, idx
    same = seg_idx[1:] == seg_idx[:-1]
    segs = np.hstack([seg_xy[:-1][same], seg_xy[1:][same]])
    segs = segs[np.abs(segs[:, :2] - segs[:, 2:]).sum(axis=1) > 1e-9]
    state = {"cap": cap, "cnt": cnt, "slot_dir": slot_dir, "dirs": dirs, "seam": seam,
             "degree": deg}
    if len(s_xy):
        sp = example.take(s_donor)
        sp.xy = s_xy
        sp.example = np.full(len(s_xy), ROAD_SLOT, dtype=np.int64)
        sp.generated = np.ones(len(s_xy), dtype=bool)
        road_level = h.edge_level[s_edge]
        sp.level = np.column_stack([road_level, np.maximum(sp.level[:, 1], road_level + 1)])
        k = len(s_xy)
        s_cap = np.clip(sp.degree, 3, 4)
        s_cnt = np.column_stack([np.full(k, 2), 2 - (s_cap - 2)])
        s_dirs = []
        for e, t in zip(s_edge, s_dist):
            g = graph.geometry[e]
            a_ = np.asarray(shapely.line_interpolate_point(g, max(t - 5.0, 0.0)).coords[0])
            b_ = np.asarray(shapely.line_interpolate_point(g, min(t + 5.0, g.length)).coords[0])
            d = (b_ - a_) / max(np.linalg.norm(b_ - a_), 1e-9)
            s_dirs.append([d, -d])
        pts = iq.PointSet.concat([pts, sp])
        state = {"cap": np.r_[cap, s_cap], "cnt": np.vstack([cnt, s_cnt]),
                 "slot_dir": np.concatenate([slot_dir, np.zeros((k, 2, 2))]),
                 "dirs": dirs + s_dirs, "seam": np.r_[seam, np.zeros(k, dtype=bool)],
                 "degree": np.r_[deg, np.full(k, 2)]}
    state["index"] = np.arange(len(pts)) + offset
    state["segments"] = segs
    state["n_slots"] = len(s_xy)
    return pts, state, graph


def _points_at_ends(lines, pts) -> np.ndarray:
    """The point each line leaves from and ends at, (n, 2); -1 where it ends on a street
    between points (a T)."""
    ends = np.column_stack([shapely.get_coordinates(shapely.get_point(lines, 0)),
                            shapely.get_coordinates(shapely.get_point(lines, -1))])
    gap, near = cKDTree(pts.xy).query(ends.reshape(-1, 2))
    return np.where(gap <= _ON_POINT, near, -1).reshape(-1, 2)


def _link_pieces_apart(lines, given, area):
    """Links for the pieces no walk step joined (:meth:`_Walker.join_pieces`: they lie
    further than a step from the rest, in an arm of the target or on built land far from
    the given roads, as Schaan's hamlets do): the shortest clear street from each to the
    given roads (without given roads, the largest piece) or to a piece linked before,
    inside the target and bent along it where the target turns
    (:func:`network.links.link_floating_pieces`, as growroads links its pieces). A piece
    that no such street reaches is dropped (a part of the target apart with no given road
    anchors its own longest piece): the paper's REPEAT
    with its rejection last. Returns (links, keep: per line of ``lines``)."""
    network = np.concatenate([lines, given])
    anchored = np.r_[np.zeros(len(lines), bool), np.ones(len(given), bool)]
    links, keep = link_floating_pieces(network, anchored, drop_unlinked=True,
                                       pieces=connected_pieces(network), inside=area,
                                       bent=area is not None)
    return links, keep[:len(lines)]


def synthesize(example: iq.PointSet, target, existing_lines=None,
               example_b: Optional[iq.PointSet] = None, blend=0.0, seed: int = 0,
               settings: Optional[WalkSettings] = None, in_place: Optional[bool] = None,
               progress: Optional[Progress] = None, shapes: Optional[StreetShapes] = None,
               shapes_b: Optional[StreetShapes] = None,
               dead_end_share: Optional[float] = None, given_class=None) -> Synthesis:
    """Join / expand / blend (sec. 4.2): place example points in ``target`` and connect them.

    Parameters
    ----------
    example, example_b : PointSet (example_b only for a blend)
    target : polygon(s) in the examples' metric CRS
    existing_lines : array of LineString, optional: roads to expand from and connect to
    blend : weight of example B, a number in [0, 1] or a function of (n, 2) locations
    seed : int >= 0; the same seed gives the same network
    in_place : see :func:`intersection_quadtree.place_points`
    shapes, shapes_b : StreetShapes of the examples (:func:`street_shapes`), optional: the
        new segments bend like them; without, parabolas of the points' tortuosity
    dead_end_share : the example's share of dead ends, optional; default the share among
        the example's points (:func:`dead_end_share_of`), which counts the ends of an
        example clipped to a study area as dead ends too: pass the share measured inside
        the example's area (``invariants.dead_end_share(lines, area)``) when it is known
    given_class : OSM class per line of ``existing_lines``, optional: a new street that
        would end on a motorway or trunk away from its junctions ends short of it
        (:mod:`network.controlled_access`)

    Raises
    ------
    InputError: bad target, no point falls into the target, bad blend, bad settings.
    """
    progress = ensure(progress)
    settings = (settings or WalkSettings()).validate()
    if seed is None or int(seed) != seed or seed < 0:
        raise InputError(f"the seed must be a whole number >= 0 (got {seed})")
    rng = np.random.default_rng(int(seed))
    area = iq._as_target(target)
    qt_a = iq.build_quadtree(example)
    quadtrees = [qt_a]
    pts = iq.place_points(example, qt_a, area, rng, in_place)
    if example_b is not None:
        qt_b = iq.build_quadtree(example_b)
        quadtrees.append(qt_b)
        pts_b = iq.place_points(example_b, qt_b, area, rng, None)
        pts_b.example = np.ones(len(pts_b), dtype=np.int64)
        pts.example = np.zeros(len(pts), dtype=np.int64)
        pts = iq.blend_points(pts, pts_b, blend, rng)
        if shapes is not None and shapes_b is not None:
            beta = float(np.mean(blend(pts.xy))) if callable(blend) else float(blend)
            shapes = blend_shapes(shapes, shapes_b, beta, rng)
        elif shapes_b is not None or shapes is not None:
            shapes = None  # one example without shapes: parabolas for both
    progress.step(0.1)
    # the dead-end share to close stubs down to and the crossing share to make up to: the
    # example's (a blend: the mix)
    target_share = dead_end_share_of(example) if dead_end_share is None else \
        float(dead_end_share)
    crossing_share = crossing_share_of(example)
    if example_b is not None:
        beta = float(np.mean(blend(pts.xy))) if callable(blend) else float(blend)
        if dead_end_share is None:
            target_share = (1 - beta) * target_share + beta * dead_end_share_of(example_b)
        crossing_share = (1 - beta) * crossing_share + beta * crossing_share_of(example_b)
    n_new = len(pts)
    existing = None
    ex_lines = None
    if given_class is not None and (existing_lines is None or
                                    len(given_class) != len(existing_lines)):
        raise InputError(f"{len(given_class)} road classes for "
                         f"{0 if existing_lines is None else len(existing_lines)} existing roads")
    if existing_lines is not None and len(existing_lines):
        seam_d = seam_distance(example, settings)
        # new points too close to an existing road would make slivers
        ex_lines = np.asarray(existing_lines, dtype=object)
        d = shapely.distance(shapely.union_all(ex_lines), shapely.points(pts.xy))
        pts = pts.take(np.flatnonzero(d >= 0.3 * pts.dist_mean[:, 0]))
        # the given roads are the example's arterials (level 0): new streets rank below
        low = int(example.level[example.level >= 0].min())
        pts.level = np.where(pts.level == low, low + 1, pts.level)
        n_new = len(pts)
        ex_pts, existing, graph = _existing_state(ex_lines, area, n_new, seam_d, example, rng,
                                                  settings.road_slots)
        ex_lines = graph.geometry
        pts = iq.PointSet.concat([pts, ex_pts])
    if n_new == 0:
        raise InputError("no example point is left in the target")
    edges, w = connect_points(pts, rng, settings, existing, dead_end_share=target_share,
                              area=area, progress=progress.sub(0.1, 0.85),
                              crossing_share=crossing_share)
    pts = w.p
    if len(edges) == 0:
        raise InputError("no street could be made: the points are too far apart for their "
                         "street statistics")
    a, sa = edges[:, 0].astype(np.int64), edges[:, 1].astype(np.int64)
    b, sb = edges[:, 2].astype(np.int64), edges[:, 3].astype(np.int64)
    level = edges[:, 4].astype(np.int64)
    origin = edges[:, 5].astype(object)
    tort = 0.5 * (pts.tortuosity[a, sa] + pts.tortuosity[b, sb])
    lines, straight, n_redrawn = draw_geometry(
        pts.xy, a, b, level, tort, shapes, settings, rng,
        ex_lines if ex_lines is not None else np.empty(0, dtype=object), area)
    if ex_lines is not None:
        # onto the roads as given, not the cleaned copy the walk ran on (a millimetre off)
        from ..network.street_graph import move_ends_onto_lines

        lines = move_ends_onto_lines(lines, shapely.get_parts(existing_lines),
                                     ROAD_SNAP_TOLERANCE)
    given_roads = shapely.get_parts(existing_lines) if ex_lines is not None else \
        np.empty(0, dtype=object)
    links = np.empty(0, dtype=object)
    n_dropped = 0
    if settings.join_pieces and w.stats["n_pieces_apart"]:
        links, keep = _link_pieces_apart(lines, given_roads, area)
        n_dropped = int((~keep).sum())
        lines, straight = lines[keep], straight[keep]
        a, sa, b, sb, level, origin = a[keep], sa[keep], b[keep], sb[keep], level[keep], \
            origin[keep]
    bridge = np.empty(0, dtype=object)
    if existing is not None:
        # the walks join their pieces to the given roads, not given roads that lie apart
        # inside the target to each other: the shortest clear street inside it does, as for
        # the other methods (network.links.join_pieces). It leaves from a point (a street
        # end or a road node) or from a street (a T, no point there: -1)
        bridge = join_pieces(np.concatenate([lines, links, given_roads]), inside=area)
    joins = np.concatenate([links, bridge])
    join_node = _points_at_ends(joins, pts)
    progress.step(0.95)
    length = shapely.length(lines)
    chord = shapely.length(straight)
    used = np.zeros(len(pts), dtype=bool)
    used[a] = used[b] = True
    table = pd.DataFrame({
        "edge_id": np.arange(1, len(lines) + 1), "level": level, "length_m": length,
        "tortuosity": length / np.maximum(chord, 1e-9), "origin": origin,
        "node_from": a, "node_to": b})
    ptab = pts.table()
    ptab.insert(0, "node_id", np.arange(len(pts)))
    deg = np.bincount(np.r_[a, b], minlength=len(pts))
    if existing is not None:  # connections of given-road points include their own roads
        ex = existing["index"]
        deg[ex] += existing["degree"]
        made = np.arange(n_new + len(ex), len(pts))  # junctions made by joins
        deg[made[pts.example[made] == ROAD_SLOT]] += 2
    np.add.at(deg, join_node[join_node >= 0], 1)
    ptab["connections"] = deg
    ptab["generated"] = pts.generated.astype(np.int64)
    is_new = pts.example >= 0
    dead = is_new & (deg == 1)
    stats = {
        "n_points": int(n_new), "n_points_generated": int(pts.generated[:n_new].sum()),
        "n_points_connected": int(used[:n_new].sum()),
        "n_edges": len(lines), "n_dead_ends": int(dead.sum()),
        # as the invariants measure it (the given roads' nodes too, away from the edge)
        "dead_end_share": w.stats["dead_end_share"],
        "example_dead_end_share": float(target_share),
        "n_straight": int((shapely.get_num_coordinates(lines) == 2).sum()),
        "n_redrawn": int(n_redrawn),
        "example_mean_tortuosity": float(shapes.mean_tortuosity()) if shapes is not None
        else float(np.mean(example.tortuosity[:, 0])),
        "n_levels": int(len(np.unique(level))),
        "quadtree_leaves": [len(q.leaves) for q in quadtrees],
        "n_closed": w.stats["n_closed"], "n_crossings_made": w.stats["n_crossings_made"],
        "n_crossings_matched": w.stats["n_crossings_matched"],
        # measured before the dead ends are steered (a stub closed may add a crossing)
        "crossing_share": w.stats["crossing_share"],
        "example_crossing_share": float(crossing_share),
        "n_dead_ends_opened": w.stats["n_dead_ends_opened"],
        "n_joins": w.stats["n_joins"],
        "n_join_splits": w.stats["n_join_splits"],
        "n_pieces_apart": w.stats["n_pieces_apart"], "n_pieces_linked": len(links),
        "n_dropped_edges": n_dropped,
        "n_joins_saturated": w.stats["n_joins_saturated"],
        "n_small_faces_refused": w.stats["n_small_faces_refused"],
    }
    if existing is not None:
        seam_idx = existing["index"][existing["seam"]]
        stats["n_seam_ends"] = int(len(seam_idx))
        stats["n_seam_ends_connected"] = int((w.deg[seam_idx] >= 2).sum())
        # every seam join after the walks: relaxed steps and the T's of _close_seam_ends
        stats["n_seam_joins_relaxed"] = int((origin == "seam").sum())
        stats["n_seam_ends_closed"] = w.stats["n_seam_ends_closed"]
        slot_idx = np.flatnonzero(pts.example == ROAD_SLOT)
        stats["n_road_junctions"] = int(used[slot_idx].sum())
        stats["n_given_joined"] = len(bridge)
    if len(joins):
        # a join's end on a street (a T, node -1) is a vertex of it, as for the streets
        # across (a zero-tolerance network analysis joins lines only at vertices)
        lines = snap_ends_onto_lines(np.concatenate([lines, joins]),
                                     np.r_[np.zeros(len(lines), bool), np.ones(len(joins), bool)])
        joined = lines[len(table):]
        table = pd.concat([table, pd.DataFrame({
            "edge_id": np.arange(len(table) + 1, len(lines) + 1),
            "level": int(level.min()), "length_m": shapely.length(joined),
            "tortuosity": shapely.length(joined) / np.maximum(shapely.distance(
                shapely.get_point(joined, 0), shapely.get_point(joined, -1)), 1e-9),
            "origin": np.r_[np.full(len(links), "piece_link", object),
                            np.full(len(bridge), "given_join", object)],
            "node_from": join_node[:, 0], "node_to": join_node[:, 1]})], ignore_index=True)
        stats["n_edges"] = len(lines)
    if settings.match_crossings and settings.max_capacity >= 4:
        # the saturation rule kept: only a point that had four streets in the example, or a
        # junction on a given road, takes a fourth
        may_cross = (pts.degree >= 4) | (pts.example < 0)
        lines, table = _streets_across(lines, table, ptab, pts, may_cross, existing_lines,
                                       area, crossing_share, rng, stats)
    if given_class is not None and ex_lines is not None:
        lines, table, ptab = _off_controlled_access(lines, table, ptab, pts, given_roads,
                                                    existing_lines, given_class, area, stats)
    lines, table, ptab = _clear_undershoots(lines, table, ptab, pts, given_roads, stats)
    if len(links) or n_dropped or stats.get("n_streets_across") or \
            stats.get("n_controlled_access_ended_short") or stats["n_undershoot_streets_dropped"]:
        # the share as the invariants measure it, as returned: counted once, after every
        # step that moved it (a whole network's cleaning, about 1 s at 10,000 points)
        stats["dead_end_share"] = measured_dead_end_share(np.concatenate([lines, given_roads]),
                                                          area)
    # of every street returned: the given-road joins and the streets across are straight,
    # a piece's link bends only along the target
    stats["mean_tortuosity"] = float(table.tortuosity.mean())
    # pieces left apart: a part of the target that no street inside it reaches keeps its
    # own (its longest piece anchors it, :func:`_link_pieces_apart`); 0 for one network
    label = connected_pieces(np.concatenate([lines, given_roads]))
    stats["n_pieces_left_apart"] = len(set(label[:len(lines)]) - set(label[len(lines):])) \
        if len(given_roads) else max(len(np.unique(label)) - 1, 0)
    progress.step(1.0)
    return Synthesis(lines, table, pts, ptab, stats, quadtrees, ex_lines)


def _off_controlled_access(lines, table, ptab, pts, roads, existing_lines, given_class, area,
                           stats):
    """New streets that end on a motorway or trunk away from its junctions (a junction slot
    on it, a T onto the nearest street) end short of it, out of its corridor; a piece cut
    off is joined again (:func:`network.controlled_access.end_short_of_controlled_access`;
    origin 'piece_link'). ``roads``: the single parts of ``existing_lines``. The table and
    the points' connections follow."""
    n = len(lines)
    network = np.concatenate([lines, roads])
    out, source, ca = end_short_of_controlled_access(
        network, np.r_[np.ones(n, bool), np.zeros(len(roads), bool)], existing_lines,
        given_class, area)
    stats["n_controlled_access_ended_short"] = ca["n_ended_short"] + ca["n_removed"]
    stats["n_controlled_access_dropped"] = ca["n_dropped"]
    stats["n_dropped_edges"] += ca["n_dropped"]
    if not (ca["n_ended_short"] or ca["n_removed"]):
        return lines, table, ptab
    new = (source < n)
    return _followed(lines, table, ptab, pts, source[new & (source >= 0)],
                     out[new & (source >= 0)], out[source < 0], stats)


def _clear_undershoots(lines, table, ptab, pts, roads, stats):
    """New streets that end within 2 m of another street, not on it, cut back until they
    keep 8 m from every street, or dropped (:func:`network.undershoots.clear_undershoots`,
    as the other methods; the walk's steps keep only 0.5 m from other segments). The table
    and the points' connections follow."""
    n = len(lines)
    out, keep = clear_undershoots(np.concatenate([lines, roads]),
                                  np.r_[np.ones(n, bool), np.zeros(len(roads), bool)])
    kept = np.flatnonzero(keep[:n])
    out = out[:len(kept)]
    changed = int(n - len(kept) + (~shapely.equals_exact(out, lines[kept], 0.0)).sum())
    stats["n_undershoots_cleared"] = changed
    # a street cut back stays a dead end: the share moves only where one went
    stats["n_undershoot_streets_dropped"] = n - len(kept)
    if not changed:
        return lines, table, ptab
    return _followed(lines, table, ptab, pts, kept, out, np.empty(0, dtype=object), stats)


def _followed(lines, table, ptab, pts, kept, out, joins, stats):
    """The table and the points' connections after the streets ``kept`` (indices into
    ``lines``) became ``out`` (cut back, or as they were) and the others went, with
    ``joins`` added (origin 'piece_link'). A street cut back no longer reaches the node at
    its cut end (-1 there, one connection less). The dead-end share is measured again by
    the caller."""
    n = len(lines)
    connections = ptab["connections"].to_numpy().copy()
    rows = table.iloc[kept].reset_index(drop=True)
    node = rows[["node_from", "node_to"]].to_numpy().copy()
    gone = np.setdiff1d(np.arange(n), kept)
    ends = table[["node_from", "node_to"]].to_numpy()[gone].ravel()
    np.add.at(connections, ends[ends >= 0], -1)
    for k in np.flatnonzero(~shapely.equals_exact(out, lines[kept], 0.0)):
        for j, at in enumerate((0, -1)):
            v = node[k, j]
            if v >= 0 and shapely.distance(shapely.get_point(out[k], at),
                                           shapely.points(pts.xy[v])) > _ON_POINT:
                connections[v] -= 1
                node[k, j] = -1
    rows[["node_from", "node_to"]] = node
    rows["length_m"] = shapely.length(out)
    chord = shapely.distance(shapely.get_point(out, 0), shapely.get_point(out, -1))
    rows["tortuosity"] = rows["length_m"] / np.maximum(chord, 1e-9)
    if len(joins):
        join_node = _points_at_ends(joins, pts)
        np.add.at(connections, join_node[join_node >= 0], 1)
        rows = pd.concat([rows, pd.DataFrame({
            "level": int(table.level.min()), "length_m": shapely.length(joins),
            "tortuosity": 1.0, "origin": "piece_link", "node_from": join_node[:, 0],
            "node_to": join_node[:, 1]})], ignore_index=True)
        out = np.concatenate([out, joins])
    rows["edge_id"] = np.arange(1, len(rows) + 1)
    ptab = ptab.copy()
    ptab["connections"] = connections
    stats["n_edges"] = len(out)
    stats["n_dead_ends"] = int(((connections == 1) & (pts.example >= 0)).sum())
    return out, rows[table.columns], ptab


def _streets_across(lines, table, ptab, pts, may_cross, existing_lines, area, share: float,
                    rng, stats):
    """Where the walks left the network's share of 4-way junctions (given roads included,
    as the invariants count it) under the band of ``share`` less half its width, T's own
    streets go on across (:func:`network.crossings.streets_across`) up to that margin, at
    the points ``may_cross`` only; each a new edge of its stem's level, origin
    "across_street", from its junction's point to a T on the street it meets (node -1: that
    line is not split, as a given-road join's), or, with no street in reach, to the
    target's edge."""
    given = shapely.get_parts(np.asarray(existing_lines, dtype=object)) \
        if existing_lines is not None and len(existing_lines) else np.empty(0, dtype=object)
    network = np.concatenate([lines, given])
    is_new = np.r_[np.ones(len(lines), bool), np.zeros(len(given), bool)]
    floor = share * (1 - 0.5 * DEAD_END_TOLERANCE)
    added, stems = streets_across(network, is_new, floor, area, rng,
                                  given=given if len(given) else None, at=pts.xy[may_cross])
    stats["n_streets_across"] = len(added)
    if not len(added):
        return lines, table
    gap, near = cKDTree(pts.xy).query(shapely.get_coordinates(shapely.get_point(added, 0)))
    start = np.where(gap <= _ON_POINT, near, -1)
    connections = ptab["connections"].to_numpy().copy()
    np.add.at(connections, start[start >= 0], 1)
    ptab["connections"] = connections
    # the street met keeps its feature, with the T's end as its vertex (a zero-tolerance
    # network analysis joins lines only at vertices)
    lines = snap_ends_onto_lines(np.concatenate([lines, added]),
                                 np.r_[np.zeros(len(lines), bool), np.ones(len(added), bool)])
    table = pd.concat([table, pd.DataFrame({
        "edge_id": np.arange(len(table) + 1, len(lines) + 1),
        "level": table.level.to_numpy()[stems], "length_m": shapely.length(added),
        "tortuosity": 1.0, "origin": "across_street", "node_from": start,
        "node_to": -1})], ignore_index=True)
    stats["n_edges"] = len(lines)
    return lines, table   # each new T counts as a node: the caller counts the share again


def points_used(result: Synthesis, target) -> Tuple[np.ndarray, pd.DataFrame]:
    """The points of a synthesis for its intersections output: the example points and
    junction slots placed in the target, and of the given roads' nodes those in the target
    or where a new street ends. The other nodes of the given roads are left out: a
    country's roads given for a 1.3 km² target put 1,582 of its 1,879 points far outside.

    Returns (geometry: array of Point, table: rows of ``result.point_table``).
    """
    xy = result.points.xy
    keep = result.points.example != EXISTING
    ends = np.r_[result.table.node_from, result.table.node_to].astype(np.int64)
    keep[ends[(ends >= 0) & (ends < len(xy))]] = True
    area = iq._as_target(target)
    keep |= shapely.intersects_xy(shapely.buffer(area, ROAD_SNAP_TOLERANCE), xy[:, 0], xy[:, 1])
    return shapely.points(xy[keep]), result.point_table[keep].reset_index(drop=True)


def given_with_junctions(existing_lines, lines) -> Tuple[np.ndarray, pd.DataFrame]:
    """The given roads with every new street's end on them as a vertex: (lines, their table
    in :data:`ROAD_FIELDS`, origin 'given', level 0, no points (-1), and ``source``: the
    index of the input feature each came from; a multi-part feature gives one line per part).

    The new streets end exactly on the given roads (:func:`synthesize` moves their ends
    onto the roads as given) but mostly between two of their vertices; a tool that builds
    its graph from vertices (QGIS's network analysis) joins lines only at vertices, so
    without these the new network would touch the given roads and not be connected to
    them. The roads stay whole, their geometry otherwise as given.

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> street = shapely.LineString([(40, 50), (40, 0)])
    >>> out, table = given_with_junctions([road], [street])
    >>> out[0].wkt, table.source.tolist(), table.origin.tolist()
    ('LINESTRING (0 0, 40 0, 100 0)', [0], ['given'])
    """
    given, source = shapely.get_parts(np.asarray(existing_lines, dtype=object),
                                      return_index=True)
    # only the given roads take vertices (a given road's end on a new street is a seam,
    # a point of the walk already)
    given = ends_as_vertices(given, lines)
    length = shapely.length(given)
    chord = shapely.distance(shapely.get_point(given, 0), shapely.get_point(given, -1))
    return given, pd.DataFrame({
        "edge_id": np.arange(1, len(given) + 1), "level": 0, "length_m": length,
        # a ring (a roundabout) has no chord: no tortuosity (NULL)
        "tortuosity": np.where(chord > 0, length / np.maximum(chord, 1e-9), np.nan),
        "origin": "given", "node_from": -1, "node_to": -1, "source": source})


def blocks_and_dual(lines, extra_lines=None, min_area: float = 50.0):
    """Blocks (faces of the streets) and the block graph B, the dual of S (sec. 3.1.2).

    Returns (blocks: array of Polygon, dual: (k, 2) int array of adjacent block pairs,
    two blocks being adjacent when they share a street edge).
    """
    allg = np.asarray(lines, dtype=object)
    if extra_lines is not None and len(extra_lines):
        allg = np.concatenate([allg, np.asarray(extra_lines, dtype=object)])
    faces = shapely.get_parts(shapely.polygonize(node_lines(allg)))
    faces = faces[shapely.area(faces) >= min_area]
    if len(faces) < 2:
        return faces, np.zeros((0, 2), dtype=np.int64)
    tree = shapely.STRtree(faces)
    i, j = tree.query(faces, predicate="intersects")
    sel = i < j
    i, j = i[sel], j[sel]
    shared = shapely.length(shapely.intersection(shapely.boundary(faces[i]),
                                                 shapely.boundary(faces[j])))
    keep = shared > 1e-6
    return faces, np.column_stack([i[keep], j[keep]])


def block_table(result: Synthesis, min_area: float = 50.0, target=None):
    """The blocks made by a synthesis (faces with a new street on their outline), with
    their number of neighbours in the block graph and Aliaga's a(v): the mean parcel (else
    block) area stored in the points on their outline, which sizes their parcels.

    ``target``: the target polygon(s), optional: a face that the given roads close outside
    it is cut to it (each part of at least ``min_area`` a block): the land outside is the
    given roads' own, not the new streets' (a face of a country's roads 98 % outside a
    1.3 km² target made a 1.3 km² block).

    Returns (geometry: array of Polygon, table: DataFrame with :data:`BLOCK_FIELDS`).
    """
    faces, dual = blocks_and_dual(result.geometry, result.existing_lines, min_area)
    if len(faces):
        hit = shapely.STRtree(faces).query(result.geometry, predicate="intersects")[1]
        keep = np.zeros(len(faces), dtype=bool)
        keep[hit] = True
    else:
        keep = np.zeros(0, dtype=bool)
    neighbours = np.bincount(dual.ravel(), minlength=len(faces)) if len(dual) else \
        np.zeros(len(faces), dtype=np.int64)
    faces, neighbours = faces[keep], neighbours[keep]
    if target is not None and len(faces):
        area = iq._as_target(target)
        out = ~shapely.covers(area, faces)
        with np.errstate(invalid="ignore"):
            cut = faces.copy()
            cut[out] = shapely.intersection(faces[out], area)
        parts, index = shapely.get_parts(cut, return_index=True)
        big = (shapely.get_type_id(parts) == 3) & (shapely.area(parts) >= min_area)
        faces, neighbours = parts[big], neighbours[index[big]]
    area_attr = np.full(len(faces), np.nan)
    if len(faces):
        pts = shapely.points(result.points.xy)
        fi, pi = shapely.STRtree(pts).query(shapely.boundary(faces), predicate="dwithin",
                                             distance=0.01)
        vals = result.points.area[pi]
        ok = np.isfinite(vals)
        cnt = np.bincount(fi[ok], minlength=len(faces))
        tot = np.bincount(fi[ok], vals[ok], minlength=len(faces))
        area_attr = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
        # a block with no value on its outline (its corners are dead ends or junctions made
        # by joins): the mean of the 4 nearest points that have one
        miss = ~np.isfinite(area_attr)
        has = np.flatnonzero(np.isfinite(result.points.area))
        if miss.any() and len(has):
            k = min(4, len(has))
            _, near = cKDTree(result.points.xy[has]).query(
                shapely.get_coordinates(shapely.point_on_surface(faces[miss])), k=k)
            area_attr[miss] = result.points.area[has[np.asarray(near).reshape(-1, k)]].mean(
                axis=1)
    table = pd.DataFrame({"block_id": np.arange(1, len(faces) + 1), "area_m2": shapely.area(faces),
                          "neighbours": neighbours, "parcel_area": area_attr})
    return faces, table
