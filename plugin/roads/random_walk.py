"""Street generation by random walks through attributed intersection points.

Aliaga, Vanegas and Benes (2008), sec. 3.1.1: the streets of each hierarchy level h_0,
h_1, ... are random walks through the intersection points. A step from a base point v_i
goes to a target point v_j drawn with the transition probability

    p(v_i, v_j) = exp(-(d - mu_d)^2 / (2 sigma_d^2) - (alpha - mu_alpha)^2 / (2 sigma_alpha^2))

(a bivariate Gaussian on the step's length d and its turn alpha from the street's last
segment, with the statistics of the base point's street); steps under a threshold are
ignored. p is zero for a point that no street of the walk's level passes (wrong level),
for a saturated point (its example's number of connections, at most 4), for a step that
would cross or touch an existing segment (an STRtree over the segments, rebuilt in batches,
plus a vectorised test against the latest segments) or pass over another point (no new
intersections), and for a step closer than a minimum angle to a street already at either
end. A walk ends where every p is zero; new walks start from free street slots until none
can start. Each segment then becomes a polyline bent to the tortuosity of its end points'
streets (fig. 5c); bends that would cross another street are straightened, so the result
is planar.

Expand (sec. 4.2): the nodes of existing roads join the point set; the dead ends of the
existing network at the target ("seam ends") continue their streets into the new points
first, and seam ends still open at the end connect to the nearest free point of any level.
Blocks are the faces of the result, and the block graph (the dual, sec. 3.1.2) is kept for
parcels (:func:`blocks_and_dual`).

Nothing here imports QGIS.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1, 4.2, figs. 3-5 and 8-12.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree

from ..core.progress import InputError, Progress, ensure
from . import intersection_quadtree as iq

__all__ = ["WalkSettings", "Synthesis", "connect_points", "synthesize", "blocks_and_dual",
           "block_table", "ROAD_FIELDS", "POINT_FIELDS", "BLOCK_FIELDS"]

ROAD_FIELDS = [("edge_id", "int"), ("level", "int"), ("length_m", "float"),
               ("tortuosity", "float"), ("origin", "str"), ("node_from", "int"),
               ("node_to", "int")]
POINT_FIELDS = [("node_id", "int"), ("degree", "int"), ("example", "int"), ("source_id", "int"),
                ("level_a", "int"), ("level_b", "int"), ("tortuosity_a", "float"),
                ("tortuosity_b", "float"), ("dist_mean_a", "float"), ("dist_var_a", "float"),
                ("dist_mean_b", "float"), ("dist_var_b", "float"), ("angle_mean_a", "float"),
                ("angle_var_a", "float"), ("angle_mean_b", "float"), ("angle_var_b", "float"),
                ("parcel_area", "float"), ("connections", "int")]

BLOCK_FIELDS = [("block_id", "int"), ("area_m2", "float"), ("neighbours", "int"),
                ("parcel_area", "float")]

_BATCH = 64      # segments checked one by one before the STRtree is rebuilt
_TOUCH = 0.5     # m: a step closer than this to another segment touches it


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
    max_sagitta : the bend of a tortuous segment is at most this share of its chord
    seam_distance : m; dead ends of existing roads this close to the target are seam ends
        (None: a quarter of the example's median street distance)
    close_ends : after the walks, a point whose street stopped short of the connections
        it had in its example (one connection of at least two) makes one more step to the
        nearest free point of its level, without the turn-angle term (not in the paper:
        its walks leave such stubs)
    """

    threshold: float = 0.05
    reach_sd: float = 2.5
    min_angle: float = 25.0
    clearance: float = 0.08
    min_clearance: float = 2.0
    max_capacity: int = 4
    max_sagitta: float = 0.12
    seam_distance: Optional[float] = None
    close_ends: bool = True

    def validate(self) -> "WalkSettings":
        checks = (("threshold", 0.0, 1.0), ("reach_sd", 0.1, 10.0), ("min_angle", 0.0, 89.0),
                  ("clearance", 0.0, 0.5), ("min_clearance", 0.0, 1000.0),
                  ("max_sagitta", 0.0, 0.5))
        for name, lo, hi in checks:
            v = getattr(self, name)
            if v is None or not math.isfinite(v) or not lo <= v <= hi:
                raise InputError(f"{name} must be in [{lo:g}, {hi:g}] (got {v})")
        if not 1 <= self.max_capacity <= 8:
            raise InputError("max_capacity must be in 1..8")
        if self.seam_distance is not None and not (self.seam_distance >= 0):
            raise InputError("the seam distance must not be negative")
        return self


class _Walker:
    """State of the street generation: slot counts, capacities, segments, edges."""

    def __init__(self, pts: iq.PointSet, settings: WalkSettings, rng, cap, cnt, slot_dir,
                 dirs, seg0):
        self.p = pts
        self.s = settings
        self.rng = rng
        self.xy = pts.xy
        self.kd = cKDTree(pts.xy)
        self.cap = cap
        self.cnt = cnt
        self.slot_dir = slot_dir
        self.deg = np.zeros(len(pts), dtype=np.int64)
        self.used = np.zeros((len(pts), 2), dtype=bool)  # slots with a segment of theirs
        self.adj = [set() for _ in range(len(pts))]
        self.dirs = dirs
        self.edges: List[tuple] = []
        self._mark = np.zeros(len(pts), dtype=bool)  # scratch mask of a point's neighbours
        # segments: coordinates of all, an STRtree over the first n_tree, and the newest
        # (at most _BATCH) as a small geometry array tested directly
        seg0 = np.asarray(seg0, dtype=float).reshape(-1, 4)
        self._coords = np.zeros((len(seg0) + 4 * len(pts) + 16, 4))
        self._coords[:len(seg0)] = seg0
        self.n_seg = len(seg0)
        self._recent = np.empty(_BATCH, dtype=object)
        self.n_tree = 0
        self.tree = None
        self._rebuild()
        self.cos_min = math.cos(math.radians(settings.min_angle))

    # -- segment index ---------------------------------------------------------------

    def _rebuild(self):
        self.n_tree = self.n_seg
        if self.n_tree:
            s = self._coords[:self.n_tree]
            self.tree = shapely.STRtree(shapely.linestrings(s.reshape(-1, 2, 2)))

    def _add_segment(self, p, q):
        if self.n_seg == len(self._coords):
            self._coords = np.vstack([self._coords, np.zeros_like(self._coords)])
        self._coords[self.n_seg] = (p[0], p[1], q[0], q[1])
        self._recent[self.n_seg - self.n_tree] = shapely.LineString([p, q])
        self.n_seg += 1
        if self.n_seg - self.n_tree >= _BATCH:
            self._rebuild()

    def _clear(self, v, j):
        """Whether the step v -> j keeps clear of every segment except at a shared end."""
        line = shapely.LineString([self.xy[v], self.xy[j]])
        hits = []
        if self.tree is not None and self.n_tree:
            hits.append(self.tree.query(line, predicate="dwithin", distance=_TOUCH))
        n_recent = self.n_seg - self.n_tree
        if n_recent:
            near = shapely.dwithin(self._recent[:n_recent], line, _TOUCH)
            hits.append(np.flatnonzero(near) + self.n_tree)
        if not hits:
            return True
        hit = np.concatenate(hits)
        if len(hit) == 0:
            return True
        ends = self._coords[hit].reshape(-1, 2, 2)
        p, q = self.xy[v], self.xy[j]
        # a segment that shares an end with the step meets it there (angles are checked apart)
        shared = ((np.abs(ends - p).sum(axis=2) < 1e-6)
                  | (np.abs(ends - q).sum(axis=2) < 1e-6)).any(axis=1)
        return bool(shared.all())

    # -- one step --------------------------------------------------------------------

    def _feasible(self, v, j, unit, dist, vec, nb):
        """The constraints of a step v -> j that need its neighbourhood (fig. 5a iv)."""
        if self.dirs[j] and (np.asarray(self.dirs[j]) @ -unit).max() >= self.cos_min:
            return False
        # no step passes over another point: streets cross only at intersection points
        others = nb[nb != j]
        if len(others):
            rel = self.xy[others] - self.xy[v]
            u = np.clip(rel @ unit / max(dist, 1e-9), 0.0, 1.0)
            near = np.linalg.norm(rel - u[:, None] * vec[None, :], axis=1)
            if (near < max(self.s.clearance * dist, self.s.min_clearance)).any():
                return False
        return self._clear(v, j)

    def step(self, v, slot, h, prev_dir, relaxed=False):
        """The next point of a walk from v (street slot ``slot``, level h), or None."""
        p = self.p
        mu, sd = p.dist_mean[v, slot], p.dist_sd[v, slot]
        reach = mu + self.s.reach_sd * sd
        nb = np.asarray(self.kd.query_ball_point(self.xy[v], reach), dtype=np.int64)
        nb = nb[nb != v]
        if len(nb) == 0:
            return None
        lv, cnt = p.level[nb], self.cnt[nb]
        # seam joins connect two hierarchies ranked apart: there any level may join
        slot_ok = (lv >= 0) & (cnt < 2) if relaxed == "seam" else (lv == h) & (cnt < 2)
        # a seam join may give a point more connections than its example had (up to 4)
        cap = np.where(self.p.example[nb] >= 0, self.s.max_capacity, self.cap[nb]) \
            if relaxed == "seam" else self.cap[nb]
        free = (self.deg[nb] < cap) & slot_ok.any(axis=1)
        if self.adj[v]:
            linked = list(self.adj[v])
            self._mark[linked] = True
            free &= ~self._mark[nb]
            self._mark[linked] = False
        if not free.any():
            return None
        cand, cslots = nb[free], slot_ok[free]
        vec = self.xy[cand] - self.xy[v]
        d = np.linalg.norm(vec, axis=1)
        unit = vec / np.maximum(d, 1e-9)[:, None]
        logp = -0.5 * ((d - mu) / sd) ** 2
        if prev_dir is not None and not relaxed:
            alpha = np.degrees(np.arccos(np.clip(unit @ prev_dir, -1.0, 1.0)))
            logp -= 0.5 * ((alpha - p.angle_mean[v, slot]) / p.angle_sd[v, slot]) ** 2
        prob = np.exp(logp)
        good = prob >= self.s.threshold
        # streets leave a point at least min_angle apart (at v and at the target)
        if self.dirs[v]:
            dv = np.asarray(self.dirs[v])
            good &= (unit @ dv.T).max(axis=1) < self.cos_min
        if not good.any():
            return None
        w = prob if not relaxed else np.exp(-0.5 * (d / mu) ** 2)
        w = np.where(good, w, 0.0)
        # draw by the transition probabilities; the costlier constraints are checked on the
        # drawn point only, and a point that fails them gets p = 0 and the draw is repeated
        # (the same distribution as checking all first)
        while True:
            total = w.sum()
            if total <= 0:
                return None
            k = int(np.searchsorted(np.cumsum(w), self.rng.random() * total, side="right"))
            k = min(k, len(w) - 1)
            if self._feasible(v, cand[k], unit[k], d[k], vec[k], nb):
                break
            w[k] = 0.0
        j = cand[k]
        s_ok = cslots[k]
        c = self.cnt[j]
        # a fresh slot continues the street; a half-used one joins another street's end
        if s_ok[0] and s_ok[1]:
            ns = 0 if c[0] <= c[1] else 1
        else:
            ns = 0 if s_ok[0] else 1
        return j, ns

    def add_edge(self, a, sa, b, sb, h, origin):
        d = self.xy[b] - self.xy[a]
        d = d / max(np.linalg.norm(d), 1e-9)
        if self.cnt[a, sa] == 0:
            self.slot_dir[a, sa] = -d
        if self.cnt[b, sb] == 0:
            self.slot_dir[b, sb] = d
        self.cnt[a, sa] += 1
        self.cnt[b, sb] += 1
        self.used[a, sa] = self.used[b, sb] = True
        self.deg[a] += 1
        self.deg[b] += 1
        self.adj[a].add(b)
        self.adj[b].add(a)
        self.dirs[a].append(d)
        self.dirs[b].append(-d)
        self.edges.append((a, sa, b, sb, h, origin))
        self._add_segment(self.xy[a], self.xy[b])

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


def connect_points(points: iq.PointSet, rng: np.random.Generator,
                   settings: Optional[WalkSettings] = None, existing=None,
                   progress: Optional[Progress] = None):
    """Connect attributed points by random walks, level by level (fig. 3).

    Parameters
    ----------
    points : PointSet (new points first; existing-road nodes have ``example`` == -1)
    existing : dict, optional, from :func:`_existing_state`: capacities, slot counts and
        directions of the existing nodes and the existing segments (crossing constraints).

    Returns
    -------
    edges : (m, 6) object array rows (a, slot_a, b, slot_b, level, origin)
    walker : the final state (degrees, slot counts)
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
                progress.step((k + i / max(len(fresh), 1)) / (len(levels) + 1))
            for slot in (0, 1):
                if points.level[v, slot] != h or w.deg[v] >= w.cap[v]:
                    continue
                # a fresh slot, a street end (set aside at a T-junction: the street starts
                # there) or an existing road's dead end at the seam
                end = w.cnt[v, slot] == 1 and (seam[v] or not w.used[v, slot])
                if w.cnt[v, slot] == 0 or end:
                    w.walk(v, slot, h)
    # seam ends still open: the nearest free point of any level (connect to the old network)
    for v in np.flatnonzero(seam):
        for slot in (0, 1):
            if points.level[v, slot] >= 0 and w.cnt[v, slot] == 1 and w.deg[v] < w.cap[v]:
                w.extend(v, slot, points.level[v, slot], relaxed="seam", origin="seam")
    if s.close_ends:
        # streets that stopped short of what their point had in the example (deg 1 < cap):
        # one more step to the nearest free point of the same level, turn angle ignored
        for v in np.flatnonzero((w.deg == 1) & (w.cap > 1) & (points.example >= 0)):
            slot = int(np.argmax(w.cnt[v] == 1))
            if w.cnt[v, slot] == 1:
                w.extend(v, slot, points.level[v, slot], relaxed="close", origin="close")
    progress.step(1.0)
    edges = np.array(w.edges, dtype=object).reshape(-1, 6)
    return edges, w


# --------------------------------------------------------------------------- geometry

def _bend(a, b, tortuosity, max_sagitta, sign, n=9):
    """A parabolic arc from a to b whose length / chord is about ``tortuosity`` (fig. 5c)."""
    chord = b - a
    length = float(np.linalg.norm(chord))
    t = np.linspace(0.0, 1.0, n)
    sag = length * min(math.sqrt(max(3.0 * (tortuosity - 1.0) / 8.0, 0.0)), max_sagitta)
    if sag < 0.5 or length == 0:
        return shapely.LineString([a, b])
    normal = np.array([-chord[1], chord[0]]) / length
    pts = a + t[:, None] * chord + (sign * sag * 4.0 * t * (1.0 - t))[:, None] * normal
    return shapely.LineString(pts)


def _straighten_crossings(lines, straight, others):
    """Replace bent lines that meet another line anywhere but at shared end points by their
    chords (the chords are planar by construction)."""
    lines = lines.copy()
    others = np.asarray(others, dtype=object)
    for _ in range(5):
        bent = np.flatnonzero(shapely.get_num_coordinates(lines) > 2)
        if len(bent) == 0:
            return lines
        allg = np.concatenate([lines, others]) if len(others) else lines
        tree = shapely.STRtree(allg)
        a, b = tree.query(lines[bent], predicate="intersects")
        a = bent[a]
        sel = a != b
        a, b = a[sel], b[sel]
        if len(a) == 0:
            return lines
        # only boundary meets boundary: interiors and interior-boundary contacts are empty
        ok = shapely.relate_pattern(lines[a], allg[b], "FF*F*****")
        if ok.all():
            return lines
        other = b[~ok]
        fix = np.unique(np.concatenate([a[~ok], other[other < len(lines)]]))
        lines[fix] = straight[fix]
    return lines


# --------------------------------------------------------------------------- synthesis

@dataclass
class Synthesis:
    """Result of :func:`synthesize`.

    geometry, table : the new road segments (:data:`ROAD_FIELDS`)
    points, point_table : the attributed points used (:data:`POINT_FIELDS`); existing-road
        nodes have example == -1
    stats : counts (points, edges, dead ends, seam ends connected ...)
    quadtrees : the quadtree of each example
    """

    geometry: np.ndarray
    table: pd.DataFrame
    points: iq.PointSet
    point_table: pd.DataFrame
    stats: dict = field(default_factory=dict)
    quadtrees: list = field(default_factory=list)
    existing_lines: Optional[np.ndarray] = None


def _existing_state(lines, area, offset: int, seam_distance: float):
    """Existing roads as points (their nodes) and constraints (their segments)."""
    from ..network import hierarchy
    from ..network import street_graph as roads

    lines = np.asarray(lines, dtype=object)
    graph = roads.clean_network(lines, merge_degree2=True)
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
    pts = iq.points_from_table(graph.nodes, table, example=-1)
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
    coords, idx = shapely.get_coordinates(graph.geometry, return_index=True)
    first = np.r_[True, idx[1:] != idx[:-1]]
    last = np.r_[idx[1:] != idx[:-1], True]
    coords[first] = graph.nodes[graph.u]
    coords[last] = graph.nodes[graph.v]
    graph.geometry = shapely.linestrings(coords, indices=idx)
    same = idx[1:] == idx[:-1]
    segs = np.hstack([coords[:-1][same], coords[1:][same]])
    return pts, {"index": np.arange(n) + offset, "cap": cap, "cnt": cnt, "slot_dir": slot_dir,
                 "dirs": dirs, "segments": segs, "seam": seam, "degree": deg}, graph


def synthesize(example: iq.PointSet, target, existing_lines=None,
               example_b: Optional[iq.PointSet] = None, blend=0.0, seed: int = 0,
               settings: Optional[WalkSettings] = None, in_place: Optional[bool] = None,
               progress: Optional[Progress] = None) -> Synthesis:
    """Join / expand / blend (sec. 4.2): place example points in ``target`` and connect them.

    Parameters
    ----------
    example, example_b : PointSet (example_b only for a blend)
    target : polygon(s) in the examples' metric CRS
    existing_lines : array of LineString, optional: roads to expand from and connect to
    blend : weight of example B, a number in [0, 1] or a function of (n, 2) locations
    seed : int >= 0; the same seed gives the same network
    in_place : see :func:`intersection_quadtree.place_points`

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
    progress.step(0.1)
    n_new = len(pts)
    existing = None
    ex_lines = None
    if existing_lines is not None and len(existing_lines):
        seam_d = settings.seam_distance if settings.seam_distance is not None else \
            0.25 * float(np.median(example.dist_mean[:, 0]))
        # new points too close to an existing road would make slivers
        ex_lines = np.asarray(existing_lines, dtype=object)
        d = shapely.distance(shapely.union_all(ex_lines), shapely.points(pts.xy))
        pts = pts.take(np.flatnonzero(d >= 0.3 * pts.dist_mean[:, 0]))
        n_new = len(pts)
        ex_pts, existing, graph = _existing_state(ex_lines, area, n_new, seam_d)
        ex_lines = graph.geometry
        pts = iq.PointSet.concat([pts, ex_pts])
    if n_new == 0:
        raise InputError("no example point is left in the target")
    edges, w = connect_points(pts, rng, settings, existing, progress=progress.sub(0.1, 0.85))
    if len(edges) == 0:
        raise InputError("no street could be made: the points are too far apart for their "
                         "street statistics")
    a, sa = edges[:, 0].astype(np.int64), edges[:, 1].astype(np.int64)
    b, sb = edges[:, 2].astype(np.int64), edges[:, 3].astype(np.int64)
    level = edges[:, 4].astype(np.int64)
    origin = edges[:, 5].astype(object)
    tort = 0.5 * (pts.tortuosity[a, sa] + pts.tortuosity[b, sb])
    sign = rng.choice([-1.0, 1.0], size=len(a))
    straight = shapely.linestrings(np.stack([pts.xy[a], pts.xy[b]], axis=1))
    bent = np.array([_bend(pts.xy[i], pts.xy[j], t, settings.max_sagitta, sg)
                     for i, j, t, sg in zip(a, b, tort, sign)], dtype=object)
    lines = _straighten_crossings(bent, straight, ex_lines if ex_lines is not None
                                  else np.empty(0, dtype=object))
    progress.step(0.95)
    length = shapely.length(lines)
    chord = shapely.length(straight)
    # node ids of the output: new points keep their index; points without a street go
    used = np.zeros(len(pts), dtype=bool)
    used[a] = used[b] = True
    table = pd.DataFrame({
        "edge_id": np.arange(1, len(lines) + 1), "level": level, "length_m": length,
        "tortuosity": length / np.maximum(chord, 1e-9), "origin": origin,
        "node_from": a, "node_to": b})
    ptab = pts.table()
    ptab.insert(0, "node_id", np.arange(len(pts)))
    ptab["connections"] = w.deg
    is_new = pts.example >= 0
    dead = is_new & (w.deg == 1)
    stats = {
        "n_points": int(n_new), "n_points_connected": int((used & is_new).sum()),
        "n_edges": len(lines), "n_dead_ends": int(dead.sum()),
        "dead_end_share": float(dead.sum() / max((used & is_new).sum(), 1)),
        "n_straightened": int((shapely.length(lines) <= chord + 1e-9).sum()),
        "n_levels": int(len(np.unique(level))),
        "quadtree_leaves": [len(q.leaves) for q in quadtrees],
    }
    if existing is not None:
        seam_idx = existing["index"][existing["seam"]]
        stats["n_seam_ends"] = int(len(seam_idx))
        stats["n_seam_ends_connected"] = int((w.deg[seam_idx] >= 2).sum())
        stats["n_seam_joins_relaxed"] = int((origin == "seam").sum())
    progress.step(1.0)
    return Synthesis(lines, table, pts, ptab, stats, quadtrees, ex_lines)


def blocks_and_dual(lines, extra_lines=None, min_area: float = 50.0):
    """Blocks (faces of the streets) and the block graph B, the dual of S (sec. 3.1.2).

    Returns (blocks: array of Polygon, dual: (k, 2) int array of adjacent block pairs,
    two blocks being adjacent when they share a street edge).
    """
    allg = np.asarray(lines, dtype=object)
    if extra_lines is not None and len(extra_lines):
        allg = np.concatenate([allg, np.asarray(extra_lines, dtype=object)])
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.node(
        shapely.multilinestrings(allg)))))
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


def block_table(result: Synthesis, min_area: float = 50.0):
    """The blocks made by a synthesis (faces with a new street on their outline), with
    their number of neighbours in the block graph and Aliaga's a(v): the mean parcel (else
    block) area stored in the points on their outline, which sizes their parcels.

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
    table = pd.DataFrame({"block_id": np.arange(1, len(faces) + 1), "area_m2": shapely.area(faces),
                          "neighbours": neighbours, "parcel_area": area_attr})
    return faces, table
