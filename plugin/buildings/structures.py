"""1.5D structures: buildings of parts along skeleton networks with T-junctions and a loop.

Hartmann's thesis, sec. 3.3.4 ("1.5D synthesis", Fig. 3.3-3.5) and ch. 6 (Fig. 6.6: nested
T-parts with a closed loop; Fig. 6.7: local constraints; Fig. 6.9: the k best, the part at
the T-joint varying). The skeleton is a network of centrelines (the building's wings);
a vertex with one wing is an end, with two a corner (or a straight joint, under
:data:`parts.STRAIGHT_TOLERANCE`), with three a T-junction where two wings continue
straight through and the third branches off at about 90°. At most one closed loop.

Decomposition (sec. 3.3.4). Wings are the maximal chains that pass straight through
T-junctions; the wing a T-junction's branch starts is a child of the wing passing
through it. The primary structure is the loop (cut at a corner vertex, the cut corner
cloned as first element, the closing transition paid as an end cost: Fig. 3.5), or else
the one wing no T-junction branches off from; the children are the secondary structures,
and so on (a tree of wings; a wing between two T-junctions, an H, is refused).

Merging (Fig. 3.4). The tree is unrolled into one sequence along a primary coordinate:
the parent's parts up to the T-part, then the whole child subtree, then the parent's
remaining parts. A T-part consumes its through length and its stub into the branch; its
*virtual duplicate* -- which "consumes zero resources and retains the outgoing edges of
the original" -- is contracted into the edges from the child's last (tip) parts to the
parent's next parts, which cost the T-part's outgoing transition: the choice of the
T-part depends on all three of its neighbours. As in the thesis, every substructure
(the stretch of a wing between two key vertices) gets its own subgraph -- here a copy of
the straight parts confined to the stretch by a start mask of the sequence engine -- and
a child gets one subgraph per T-part that may start it, since the T-part's length moves
the child along the primary coordinate ("we construct separate graphs for each element
that is allowed to start this current structure"). Key vertices get copies of the
parts that fit them (corners by angle, T-parts, end parts), each allowed at exactly one
start. All copies share the global resources (length, floor area, counts); a local
constraint on a wing is one more resource that only that wing's copies consume. One
exact solve of :func:`sequences.solve` over this merged graph gives the k best
buildings (one solve per corner part that may sit at the loop's cut).

Placement: centreline model. A part covering ``[a, b]`` of a wing is that stretch of the
centreline thickened by ``depth_m / 2`` to both sides with mitred joins (so a corner part
is an L and every part's footprint is its length x depth); a T-part is its through
stretch plus its stub into the branch. Floor areas are those placed footprints x levels.

Nothing here imports QGIS. Lengths in metres.

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, sec. 3.3.4
(key points, structures, 1.5D synthesis) and ch. 6 (building synthesis).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from ..core.geometry import substrings
from ..core.progress import InputError, Progress, ensure
from . import sequences
from .parts import (AREA_QUANTUM, CORNER_TOLERANCE, LENGTH_QUANTUM, STRAIGHT_TOLERANCE,
                    PartsLibrary, PartsResult, _area_bounds, _constraints, _resource_matrix)
from .sequences import Constraint, InfeasibleError

__all__ = ["TEE_TOLERANCE", "Wing", "skeleton_network", "connected_networks",
           "build_along_network"]

#: A T-junction's branch must leave its through wings at 90° within this (degrees).
TEE_TOLERANCE = 20.0
#: Vertices closer than this (m) are one skeleton vertex.
SNAP = 1e-3
#: Largest number of part copies of one merged graph (a guard on nested T-junctions).
MAX_COPIES = 20_000


@dataclass
class Wing:
    """One wing of a skeleton network (a chain through corners and T-junctions).

    ``coords`` (m, 2): its vertices, a child's first vertex being its T-junction; a closed
    wing (the loop) does not repeat its first vertex and starts at the corner where it is
    cut. ``pos``: arc length at each vertex (a closed wing has one more entry: its
    length). ``kind`` per vertex: ``tip`` (an end), ``corner``, ``pass`` (a straight joint),
    ``tee`` (a T-junction this wing passes through), ``attach`` (a child's T-junction).
    ``turn``: turning angle per vertex (degrees, left positive). ``children``: vertex ->
    child wing index. ``lines``: per vertex, the input line of the segment leaving it.
    """

    coords: np.ndarray
    closed: bool
    pos: np.ndarray
    kind: List[str]
    turn: np.ndarray
    lines: np.ndarray
    children: Dict[int, int] = field(default_factory=dict)
    parent: Optional[Tuple[int, int]] = None

    @property
    def length(self) -> float:
        return float(self.pos[-1])

    def line(self) -> shapely.LineString:
        """The centreline (a closed wing: three turns of the ring, for wrap-around)."""
        if self.closed:
            return shapely.LineString(np.vstack([self.coords] * 3 + [self.coords[:1]]))
        return shapely.LineString(self.coords)


# --------------------------------------------------------------------------- network


def _lines_of(skeleton) -> List[Tuple[np.ndarray, bool]]:
    """(coords, closed) of every line of the skeleton (2D, repeated vertices dropped)."""
    if isinstance(skeleton, (list, tuple, np.ndarray)):
        geoms = [g for g in skeleton]
    else:
        geoms = [skeleton]
    out = []
    for g in geoms:
        if g is None:
            continue
        if isinstance(g, shapely.Polygon):
            g = g.exterior
        for part in shapely.get_parts(np.array([g], dtype=object)):
            if isinstance(part, shapely.Polygon):
                part = part.exterior
            if not isinstance(part, (shapely.LineString, shapely.LinearRing)) or part.is_empty:
                raise InputError("the skeleton network must be made of lines (or a polygon "
                                 "ring)")
            xy = np.asarray(part.coords)[:, :2]
            keep = np.r_[True, np.linalg.norm(np.diff(xy, axis=0), axis=1) > SNAP]
            xy = xy[keep]
            closed = len(xy) > 3 and np.linalg.norm(xy[0] - xy[-1]) <= SNAP
            if len(xy) < 2:
                raise InputError("a skeleton line needs two distinct vertices")
            out.append((xy, closed))
    if not out:
        raise InputError("the skeleton network is empty")
    return out


def _insert_junctions(lines: List[Tuple[np.ndarray, bool]]) -> List[Tuple[np.ndarray, bool]]:
    """A wing drawn to end on another wing's side (snapped to the segment, not to a
    vertex) makes a junction there: the end point becomes a vertex of that wing."""
    ends = np.vstack([xy[[0, -1]] for xy, closed in lines if not closed] or
                     [np.zeros((0, 2))])
    out = []
    for xy, closed in lines:
        ring = xy                                 # a closed line repeats its first vertex
        line = shapely.LineString(ring)
        near = ends[shapely.distance(shapely.points(ends), line) <= SNAP] if len(ends) else ends
        if len(near):
            pos = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))]
            at = shapely.line_locate_point(line, shapely.points(near))
            new = (np.abs(at[:, None] - pos[None, :]) > SNAP).all(axis=1)
            if new.any():
                allpos = np.r_[pos, at[new]]
                allxy = np.vstack([ring, near[new]])
                order = np.argsort(allpos, kind="stable")
                ring = allxy[order]
        out.append((ring, closed))
    return out


def _angle(v: np.ndarray) -> float:
    return math.atan2(v[1], v[0])


def _turn(a_in: np.ndarray, a_out: np.ndarray) -> float:
    """Turning angle (degrees, left positive) from direction a_in to a_out."""
    t = _angle(a_out) - _angle(a_in)
    return math.degrees((t + math.pi) % (2 * math.pi) - math.pi)


def skeleton_network(skeleton, tee_tolerance: float = TEE_TOLERANCE) -> List[Wing]:
    """Decompose a skeleton network into wings, the primary one first (thesis sec. 3.3.4).

    Parameters
    ----------
    skeleton : LineString / MultiLineString / LinearRing / Polygon (its ring) or a
        sequence of them: the building's centrelines, meeting at shared vertices.
    tee_tolerance : float
        Largest deviation (degrees) of a T-junction's branch from 90°.

    Returns
    -------
    list of Wing in depth-first order (the unrolled order): the loop or the root wing
    first, each child after its parent.

    Raises
    ------
    InputError
        A vertex with four or more wings, a disconnected network, more than one loop, a
        T-junction whose wings are not two straight through and one at 90°, a wing between
        two T-junctions, or a loop without a corner to cut it at.
    """
    lines = _insert_junctions(_lines_of(skeleton))
    pts, seg_a, seg_b, seg_line = [], [], [], []
    offset = 0
    for li, (xy, closed) in enumerate(lines):
        m = len(xy) - (1 if closed else 0)
        pts.append(xy[:m])
        idx = offset + np.arange(m)
        nxt = np.r_[idx[1:], idx[:1]] if closed else idx[1:]
        seg_a.append(idx[:len(nxt)])
        seg_b.append(nxt)
        seg_line.append(np.full(len(nxt), li))
        offset += m
    P = np.vstack(pts)
    key = np.round(P / SNAP).astype(np.int64)
    _, first, node_of = np.unique(key, axis=0, return_index=True, return_inverse=True)
    node_of = node_of.ravel()
    nodes = P[first]
    a = node_of[np.concatenate(seg_a)]
    b = node_of[np.concatenate(seg_b)]
    seg_line = np.concatenate(seg_line)
    if (a == b).any():
        raise InputError("the skeleton has a zero-length segment")
    pair = np.sort(np.c_[a, b], axis=1)
    if len(np.unique(pair, axis=0)) < len(pair):
        raise InputError("the skeleton has two lines along the same segment")
    V, E = len(nodes), len(a)
    adj = sparse.coo_matrix((np.ones(2 * E), (np.r_[a, b], np.r_[b, a])), shape=(V, V))
    n_comp, _ = connected_components(adj, directed=False)
    if n_comp > 1:
        raise InputError(f"the skeleton network falls apart into {n_comp} pieces; one "
                         "building needs connected wings")
    if E - V + 1 > 1:
        raise InputError(f"the skeleton network has {E - V + 1} loops; at most one (a "
                         "courtyard ring) is supported")
    incident: List[List[int]] = [[] for _ in range(V)]
    for s in range(E):
        incident[a[s]].append(s)
        incident[b[s]].append(s)
    degree = np.array([len(x) for x in incident])
    if degree.max() > 3:
        v = int(np.argmax(degree))
        raise InputError(f"skeleton vertex ({nodes[v][0]:.1f}, {nodes[v][1]:.1f}) joins "
                         f"{degree[v]} wings; at most three (a T-junction)")

    def other(s: int, v: int) -> int:
        return int(b[s] if a[s] == v else a[s])

    def out_dir(s: int, v: int) -> np.ndarray:
        d = nodes[other(s, v)] - nodes[v]
        return d / np.linalg.norm(d)

    # at every vertex: which segment continues which (a pass, a corner, or the through
    # pair of a T-junction); the branch of a T-junction continues nothing
    through: Dict[Tuple[int, int], int] = {}
    branch_at: Dict[int, int] = {}
    for v in range(V):
        inc = incident[v]
        if len(inc) == 2:
            through[(v, inc[0])], through[(v, inc[1])] = inc[1], inc[0]
        elif len(inc) == 3:
            d = [out_dir(s, v) for s in inc]
            best, pair_ = None, None
            for i in range(3):
                for j in range(i + 1, 3):
                    dev = abs(180.0 - math.degrees(math.acos(np.clip(d[i] @ d[j], -1, 1))))
                    if best is None or dev < best:
                        best, pair_ = dev, (i, j)
            i, j = pair_
            k = 3 - i - j
            side = abs(90.0 - math.degrees(math.acos(np.clip(d[k] @ d[i], -1, 1))))
            if best > STRAIGHT_TOLERANCE or side > tee_tolerance:
                raise InputError(
                    f"skeleton vertex ({nodes[v][0]:.1f}, {nodes[v][1]:.1f}) is no T-junction: "
                    f"two wings must continue straight through (within {STRAIGHT_TOLERANCE:g}°)"
                    f" and the third leave at 90° (within {tee_tolerance:g}°)")
            through[(v, inc[i])], through[(v, inc[j])] = inc[j], inc[i]
            branch_at[v] = inc[k]
    # chains: walk both ways from every unvisited segment through the continuations
    seen = np.zeros(E, dtype=bool)
    chains = []   # (node list, segment list, closed)
    for s0 in range(E):
        if seen[s0]:
            continue
        seen[s0] = True
        fwd_nodes, fwd_segs = [int(a[s0]), int(b[s0])], [s0]
        closed = False
        while True:
            v, s = fwd_nodes[-1], fwd_segs[-1]
            nxt = through.get((v, s))
            if nxt is None:
                break
            if nxt == s0:
                closed = True
                break
            seen[nxt] = True
            fwd_segs.append(nxt)
            fwd_nodes.append(other(nxt, v))
        if not closed:
            back_nodes, back_segs = [], []
            v, s = fwd_nodes[0], s0
            while True:
                nxt = through.get((v, s))
                if nxt is None:
                    break
                seen[nxt] = True
                v = other(nxt, v)
                back_segs.append(nxt)
                back_nodes.append(v)
                s = nxt
            fwd_nodes = back_nodes[::-1] + fwd_nodes
            fwd_segs = back_segs[::-1] + fwd_segs
        else:
            fwd_nodes = fwd_nodes[:-1]
        chains.append((fwd_nodes, fwd_segs, closed))
    # orientation and the tree of wings
    attach_ends = []
    for ch_nodes, ch_segs, closed in chains:
        ends = [] if closed else [e for e in (0, -1) if degree[ch_nodes[e]] == 3]
        attach_ends.append(ends)
    loops = [i for i, c in enumerate(chains) if c[2]]
    if E - V + 1 == 1 and not loops:
        raise InputError("the skeleton's loop must pass straight through its T-junctions")
    if loops:
        root = loops[0]
        if any(len(e) != 1 for i, e in enumerate(attach_ends) if i != root):
            raise InputError("every wing off the loop must start at a T-junction and end free")
    else:
        roots = [i for i, e in enumerate(attach_ends) if not e]
        if len(roots) != 1 or any(len(e) > 1 for e in attach_ends):
            raise InputError("a wing runs between two T-junctions (an H): the wings must "
                             "form a tree, each branching off one T-junction")
        root = roots[0]
    wings: List[Wing] = []
    order: List[int] = []

    def make(ci: int) -> Wing:
        ch_nodes, ch_segs, closed = chains[ci]
        ch_nodes, ch_segs = list(ch_nodes), list(ch_segs)
        if closed:
            xy = nodes[ch_nodes]
            area = 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1)
                                      - np.roll(xy[:, 0], -1) * xy[:, 1]))
            if area < 0:      # counter-clockwise
                ch_nodes = [ch_nodes[0]] + ch_nodes[1:][::-1]
                ch_segs = ch_segs[::-1]
            m = len(ch_nodes)
            xy = nodes[ch_nodes]
            d_in = xy - np.roll(xy, 1, axis=0)
            d_out = np.roll(xy, -1, axis=0) - xy
            turns = np.array([_turn(d_in[i], d_out[i]) for i in range(m)])
            corners = [i for i in range(m) if degree[ch_nodes[i]] == 2
                       and abs(turns[i]) >= STRAIGHT_TOLERANCE]
            if not corners:
                raise InputError("the skeleton's loop needs a corner to be cut at (thesis "
                                 "Fig. 3.5)")
            c0 = min(corners, key=lambda i: (xy[i][0], xy[i][1]))
            ch_nodes = ch_nodes[c0:] + ch_nodes[:c0]
            # segment i runs from node i to node i + 1
            segs = []
            for i in range(m):
                u_, v_ = ch_nodes[i], ch_nodes[(i + 1) % m]
                segs.append(next(s for s in ch_segs if {int(a[s]), int(b[s])} == {u_, v_}))
            ch_segs = segs
        else:
            if attach_ends[ci] == [-1] or (not attach_ends[ci] and tuple(nodes[ch_nodes[-1]])
                                           < tuple(nodes[ch_nodes[0]])):
                ch_nodes, ch_segs = ch_nodes[::-1], ch_segs[::-1]
        xy = nodes[ch_nodes]
        m = len(ch_nodes)
        ring = np.vstack([xy, xy[:1]]) if closed else xy
        seg_len = np.linalg.norm(np.diff(ring, axis=0), axis=1)
        pos = np.r_[0.0, np.cumsum(seg_len)]
        kinds, turns = [], np.zeros(m)
        for i in range(m):
            v = ch_nodes[i]
            if not closed and i in (0, m - 1):
                kinds.append("attach" if degree[v] == 3 else "tip")
                continue
            d_in = xy[i] - xy[i - 1]
            d_out = xy[(i + 1) % m] - xy[i]
            turns[i] = _turn(d_in, d_out)
            if degree[v] == 3:
                kinds.append("tee")
            else:
                kinds.append("corner" if abs(turns[i]) >= STRAIGHT_TOLERANCE else "pass")
        lines_v = seg_line[np.asarray(ch_segs)]
        if not closed:
            lines_v = np.r_[lines_v, lines_v[-1:]]
        return Wing(coords=xy, closed=closed, pos=pos if closed else pos, kind=kinds,
                    turn=turns, lines=lines_v.astype(np.int64)), ch_nodes

    node_lists = {}

    def visit(ci: int, parent: Optional[Tuple[int, int]]) -> None:
        w, ch_nodes = make(ci)
        w.parent = parent
        wi = len(wings)
        wings.append(w)
        order.append(ci)
        node_lists[wi] = ch_nodes
        for vi, v in enumerate(ch_nodes):
            if w.kind[vi] != "tee":
                continue
            child = next(cj for cj, (cn, _, cl) in enumerate(chains)
                         if not cl and cj != ci and v in (cn[0], cn[-1])
                         and degree[v] == 3 and branch_at[v] in chains[cj][1])
            w.children[vi] = len(wings)
            visit(child, (wi, vi))

    visit(root, None)
    return wings


def connected_networks(lines: Sequence) -> List[np.ndarray]:
    """Group lines that touch (within :data:`SNAP`) into networks: one building each.

    Returns the line indices of every network, ordered by their smallest index.
    """
    lines = np.asarray(lines, dtype=object)
    if not len(lines):
        return []
    tree = shapely.STRtree(lines)
    i, j = tree.query(shapely.buffer(lines, SNAP), predicate="intersects")
    graph = sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(len(lines), len(lines)))
    _, label = connected_components(graph, directed=False)
    groups = [np.flatnonzero(label == k) for k in np.unique(label)]
    return sorted(groups, key=lambda g: int(g[0]))


# --------------------------------------------------------------------------- layout


@dataclass
class _Copy:
    """One part copy of the merged graph."""

    part: int            # library row
    role: str            # straight | corner | tee | end_first | end_last
    wing: int
    ctx: tuple           # the T-part choices ((wing, vertex, part), ...) of its ancestors
    x0: int              # wing-local grid position where the copy's placement starts
    line: int            # input line (local constraints); -1: none
    start: Tuple[int, int]   # allowed start levels [lo, hi] (unrolled grid steps)
    vertex: int = -1     # the key vertex (corner, tee, tip)


def _grid(w: Wing, q: float) -> np.ndarray:
    """Grid positions (steps) of the wing's vertices (+ its length for a loop)."""
    g = np.rint(w.pos / q).astype(np.int64)
    if (np.diff(g) <= 0).any():
        raise InputError(f"skeleton segments shorter than {q:g} m")
    return g


def build_along_network(skeleton, library: PartsLibrary, *, k: int = 1,
                        floor_area=None, far=None, site_area=None,
                        counts: Optional[Mapping[str, Tuple[float, float]]] = None,
                        local: Optional[Mapping[int, Mapping[str, Tuple[float, float]]]] = None,
                        corner_tolerance: float = CORNER_TOLERANCE,
                        tee_tolerance: float = TEE_TOLERANCE,
                        area_resolution: float = AREA_QUANTUM,
                        progress: Optional[Progress] = None) -> PartsResult:
    """The k best buildings of parts along a skeleton network (thesis sec. 3.3.4, ch. 6).

    Parameters
    ----------
    skeleton : lines (see :func:`skeleton_network`)
        The building's wing centrelines: ends, corners, T-junctions, at most one loop.
    library : PartsLibrary with ``straight``, ``corner``, ``tee`` and ``end_left`` /
        ``end_right`` parts as the skeleton needs them (:func:`parts.terrace_library`).
    k : int
        Number of solutions (the k best, non-decreasing cost, distinct sequences).
    floor_area, far, site_area, counts :
        Global constraints as in :func:`parts.build_along_skeleton`.
    local : {input line index: {kind or numeric field: (lo, hi)}}, optional
        Local constraints per wing (thesis Fig. 6.7): counted over the straight and end
        parts placed on that input line (corner and T-parts join wings and are not).
    corner_tolerance : float
        Largest difference (degrees) between a corner's turn and a corner part's angle
        (either sign: a centreline corner is symmetric).
    tee_tolerance : float
        See :func:`skeleton_network`.
    area_resolution : float
        Grid of the floor-area resource (m²).

    Returns
    -------
    PartsResult
        Part footprints (valid, non-overlapping within a solution) with ``wing`` (input
        line, -1 for corner and T-parts) and ``role`` in the table.

    Raises
    ------
    InputError / sequences.InfeasibleError
        A malformed network, a vertex no part fits, or no building meets the constraints.
    """
    progress = ensure(progress)
    if k < 1:
        raise InputError("k must be at least 1")
    counts = dict(counts or {})
    local = {int(key): dict(v) for key, v in (local or {}).items()}
    wings = skeleton_network(skeleton, tee_tolerance)
    n_lines = len(_lines_of(skeleton))
    for key in local:
        if not 0 <= key < n_lines:
            raise InputError(f"local constraint on line {key}: the skeleton has lines "
                             f"0..{n_lines - 1}")
    t = library.table
    kind = t["kind"].to_numpy()
    q = LENGTH_QUANTUM
    U = np.rint(t["length_m"].to_numpy(float) / q).astype(np.int64)
    branch_u = np.rint(t["branch_m"].to_numpy(float) / q).astype(np.int64) \
        if "branch_m" in t else np.zeros(len(t), np.int64)
    depth = t["depth_m"].to_numpy(float)
    half = np.rint(U / 2).astype(np.int64)           # a key part's anchor: its middle
    straights = np.flatnonzero(kind == "straight")
    corners = np.flatnonzero(kind == "corner")
    tees = np.flatnonzero(kind == "tee")
    ends_first = np.flatnonzero(kind == "end_left")
    ends_last = np.flatnonzero(kind == "end_right")
    angles = np.abs(t["angle_deg"].to_numpy(float))
    if not len(straights):
        raise InputError("the parts library has no straight parts")
    grids = [_grid(w, q) for w in wings]
    length_u = [int(g[-1]) for g in grids]

    # span of every wing's subtree along the unrolled coordinate (children after parents)
    span = [0] * len(wings)
    for wi in range(len(wings) - 1, -1, -1):
        span[wi] = length_u[wi] + sum(span[c] for c in wings[wi].children.values())

    def fitting_corners(turn: float) -> np.ndarray:
        reach = depth[corners] / 2 * math.tan(math.radians(min(abs(turn), 179.0)) / 2)
        fit = corners[(np.abs(angles[corners] - abs(turn)) <= corner_tolerance)
                      & (U[corners] * q / 2 >= reach - 1e-6)]
        if not len(fit):
            raise InfeasibleError(f"no corner part fits a skeleton vertex turning "
                                  f"{abs(turn):.0f}° (library corners: "
                                  f"{sorted(set(angles[corners]))})")
        return fit

    for w in wings:
        if any(kd == "tee" for kd in w.kind) and not len(tees):
            raise InputError("the skeleton has T-junctions but the library no T-parts")
        if any(kd == "tip" for kd in w.kind[1:]) and not len(ends_last):
            raise InputError("the skeleton has free ends but the library no end_right parts")
    if not wings[0].closed and not len(ends_first):
        raise InputError("an open skeleton needs end_left parts in the library")

    def layout(cut_part: Optional[int]) -> List[_Copy]:
        """Every part copy of one merged graph (the loop cut with ``cut_part``)."""
        copies: List[_Copy] = []

        def lay(wi: int, ctx: tuple, base: int) -> None:
            w, g = wings[wi], grids[wi]
            m = len(w.coords)
            tee_at = sorted(w.children)

            def u(x: int, after: bool = False) -> int:
                extra = sum(span[w.children[v]] for v in tee_at
                            if g[v] < x or (after and g[v] == x))
                return base + x + extra

            keys = [i for i in range(m) if w.kind[i] in ("corner", "tee", "tip", "attach")]
            if w.closed:
                keys = keys + [m]            # the cut corner again, at the loop's end
            for i in keys:
                if i == m:
                    continue
                kd = w.kind[i]
                x = int(g[i])
                if kd == "corner":
                    if w.closed and i == 0:
                        copies.append(_Copy(cut_part, "corner", wi, ctx, -int(half[cut_part]),
                                            -1, (0, 0), i))
                        continue
                    for c in fitting_corners(w.turn[i]):
                        s = u(x) - int(half[c])
                        copies.append(_Copy(int(c), "corner", wi, ctx, x - int(half[c]), -1,
                                            (s, s), i))
                elif kd == "tee":
                    child = w.children[i]
                    for j in tees:
                        s = u(x) - int(half[j])
                        copies.append(_Copy(int(j), "tee", wi, ctx, x - int(half[j]), -1,
                                            (s, s), i))
                        lay(child, ctx + ((wi, i, int(j)),), s + int(U[j]))
                elif kd == "tip" and i == 0:
                    for e in ends_first:
                        copies.append(_Copy(int(e), "end_first", wi, ctx, 0,
                                            int(w.lines[0]), (u(0), u(0)), i))
                elif kd == "tip":
                    for e in ends_last:
                        s = u(x) - int(U[e])
                        copies.append(_Copy(int(e), "end_last", wi, ctx, x - int(U[e]),
                                            int(w.lines[i - 1]), (s, s), i))
            # straights: one copy per stretch between consecutive key vertices
            bounds = sorted(set([int(g[i]) for i in keys if i < m] + ([int(g[m])] if w.closed
                                                                          else [])))
            for xa, xb in zip(bounds[:-1], bounds[1:]):
                ua, ub = u(xa, after=True), u(xb)
                mid = 0.5 * (xa + xb)
                seg = int(np.searchsorted(g, mid, side="right") - 1)
                line = int(w.lines[min(seg, len(w.lines) - 1)])
                # a straight part never touches a key vertex: only the vertex's own key
                # parts may (thesis sec. 3.3.4), so none can be skipped
                for e in straights:
                    if ub - ua - 2 >= U[e]:
                        copies.append(_Copy(int(e), "straight", wi, ctx, xa - ua, line,
                                            (ua + 1, ub - 1 - int(U[e]))))
                if len(copies) > MAX_COPIES:
                    raise InputError(f"the skeleton network needs more than {MAX_COPIES} part "
                                     "copies (deeply nested T-junctions); simplify it")

        lay(0, (), int(half[cut_part]) if cut_part is not None else 0)
        return copies

    R_lib, res, names = _resource_matrix(library, counts, area_resolution)
    # centreline placement: every part's footprint is its length x depth (a T-part's plus
    # its stub past the through wing's side), the floor area that x levels
    levels = t["levels"].to_numpy(float)
    placed = t["length_m"].to_numpy(float) * depth
    placed[tees] += np.maximum(t["branch_m"].to_numpy(float)[tees] - depth[tees] / 2, 0.0) \
        * depth[tees]
    R_lib[:, 1] = np.round(placed * levels / AREA_QUANTUM) * AREA_QUANTUM
    local_cols = []
    for key, cons in local.items():
        for name, (lo, hi) in cons.items():
            if name in ("straight", "end_left", "end_right"):
                col = (kind == name).astype(float)
            elif name in t.columns:
                col = pd.to_numeric(t[name], errors="coerce").to_numpy(float)
                if np.isnan(col).any() or (col < 0).any():
                    raise InputError(f"count field {name} must be a non-negative number per "
                                     "part")
            else:
                raise InputError(f"local constraint '{name}' on line {key}: neither straight,"
                                 f" end_left, end_right nor a field of the library")
            local_cols.append((key, name, float(lo), float(hi), col))
    area = _area_bounds(floor_area, far, site_area)
    total_u = span[0]
    cuts = [None]
    if wings[0].closed:
        cuts = list(fitting_corners(wings[0].turn[0]))
    sols, metas = [], []
    for r, cut in enumerate(cuts):
        copies = layout(cut)
        n = len(copies)
        part = np.array([c.part for c in copies], dtype=np.int64)
        role = np.array([c.role for c in copies], dtype=object)
        wing_of = np.array([c.wing for c in copies], dtype=np.int64)
        line_of = np.array([c.line for c in copies], dtype=np.int64)
        R = R_lib[part].copy()
        tee_m = role == "tee"
        R[tee_m, 0] += branch_u[part[tee_m]] * q     # through length + stub into the branch
        cols = []
        for key, name, lo, hi, col in local_cols:
            on = (line_of == key) & np.isin(role, ("straight", "end_first", "end_last"))
            cols.append(np.where(on, col[part], 0.0))
        if cols:
            R = np.column_stack([R] + cols)
        resol = np.r_[res, np.ones(len(cols))]
        cons = _constraints((total_u * q, total_u * q), area, counts)
        for i, (key, name, lo, hi, _) in enumerate(local_cols):
            cons.append(Constraint(R_lib.shape[1] + i, lo, hi))
        # where each copy may start
        mask = np.zeros((n, total_u + 1), dtype=bool)
        for i, c in enumerate(copies):
            lo_s, hi_s = max(c.start[0], 0), min(c.start[1], total_u)
            if lo_s <= hi_s:
                mask[i, lo_s:hi_s + 1] = True
        # transitions: within a (wing, context) group by the library; into a T-part from
        # its parent's group; from a T-part only into its child's group (the branch
        # cross-section); from the child's last parts back into the parent's group at the
        # T-part's own outgoing cost (its virtual duplicate, contracted)
        group = {}
        gid = np.array([group.setdefault((c.wing, c.ctx), len(group)) for c in copies])
        trans = np.full((n, n), np.inf)
        lib_T = library.transition
        base_T = lib_T[np.ix_(part, part)]
        same = gid[:, None] == gid[None, :]
        inner = same & ~tee_m[:, None]
        trans[inner] = base_T[inner]
        area_branch = t["area_branch_m2"].to_numpy(float) if "area_branch_m2" in t else \
            depth * t["height_m"].to_numpy(float)
        area_left = t["area_left_m2"].to_numpy(float)
        for ti in np.flatnonzero(tee_m):
            c = copies[ti]
            child = wings[c.wing].children[c.vertex]
            cctx = c.ctx + ((c.wing, c.vertex, c.part),)
            into = np.flatnonzero((wing_of == child) & np.array([x.ctx == cctx
                                                                 for x in copies]))
            trans[ti, into] = np.abs(area_branch[c.part] - area_left[part[into]])
            back = into[role[into] == "end_last"]
            parent = np.flatnonzero(gid == gid[ti])
            parent = parent[~tee_m[parent] | (parent != ti)]
            trans[np.ix_(back, parent)] = lib_T[c.part][part[parent]][None, :]
        # the sequence starts with the root's first end part (or the loop's cut corner)
        # and ends with its last end part (or any part of the loop)
        first = (role == "end_first") | ((role == "corner") & (wing_of == 0)
                                         & np.array([x.start == (0, 0) for x in copies]))
        last = (wing_of == 0) & (role == "end_last") if cut is None else \
            (wing_of == 0) & ~tee_m
        opts = dict(first=first, last=last, start_mask=mask)
        if cut is not None:
            opts["end_cost"] = np.where(last, lib_T[part, cut], np.inf)
        try:
            found = sequences.solve(R, trans, cons, k=k, resolution=resol,
                                    progress=progress.sub(r / len(cuts), (r + 1) / len(cuts)),
                                    **opts)
        except InfeasibleError:
            continue
        for s in found:
            sols.append(s)
            metas.append((copies, R))
    if not sols:
        raise InfeasibleError(
            f"no sequence of the {len(t)} parts fills the {total_u * q:.1f} m skeleton "
            "network" + (f" with a floor area in [{area[0]:g}, {area[1]:g}] m²" if area else "")
            + (f", counts {counts}" if counts else "")
            + (f", local constraints {local}" if local else ""))
    order = sorted(range(len(sols)), key=lambda i: (sols[i].cost, i))[:k]
    return _place(wings, grids, library, [sols[i] for i in order], [metas[i] for i in order],
                  names, R_lib, site_area)


def _arc(w: Wing, g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Wing-local grid positions -> arc length along the real centreline (piecewise linear
    between the vertices, so each stretch keeps its vertices; < 0.1 m of stretch)."""
    x = np.asarray(x, dtype=np.float64)
    if w.closed:
        L, Lg = w.pos[-1], g[-1]
        k = np.floor(x / Lg)
        return np.interp(x - k * Lg, g, w.pos) + k * L + L   # the tripled ring's middle turn
    return np.interp(x, g, w.pos)


def _band(line: shapely.LineString, a, b, width):
    """The stretches [a_i, b_i] of ``line`` thickened by width_i / 2 to both sides."""
    a = np.asarray(a, dtype=np.float64)
    pieces = substrings(np.full(len(a), line, dtype=object), a, np.asarray(b, np.float64))
    return shapely.buffer(pieces, np.asarray(width, np.float64) / 2, cap_style="flat",
                          join_style="mitre", mitre_limit=10.0)


def _place(wings, grids, library, sols, metas, names, R_lib, site_area) -> PartsResult:
    """Geometry and tables of the chosen solutions (centreline placement)."""
    t = library.table
    q = LENGTH_QUANTUM
    length = t["length_m"].to_numpy(float)
    depth = t["depth_m"].to_numpy(float)
    branch = t["branch_m"].to_numpy(float) if "branch_m" in t else np.zeros(len(t))
    lines = [w.line() for w in wings]
    geoms, rows, summaries, kept = [], [], [], []
    for rank, (s, (copies, R)) in enumerate(zip(sols, metas), start=1):
        idx = [None] * len(s.sequence)
        starts = np.rint(np.asarray(s.starts) / q).astype(np.int64)
        placed = []
        for j, (ci, st) in enumerate(zip(s.sequence, starts)):
            c = copies[ci]
            w, g = wings[c.wing], grids[c.wing]
            p = c.part
            if c.role == "straight":
                x0 = c.x0 + st
            else:
                x0 = c.x0
            a = _arc(w, g, [x0])[0]
            b = _arc(w, g, [x0 + np.rint(length[p] / q)])[0]
            poly = _band(lines[c.wing], [a], [b], [depth[p]])[0]
            if c.role == "tee":
                child = wings[w.children[c.vertex]]
                cg = grids[w.children[c.vertex]]
                stub = _arc(child, cg, [np.rint(branch[p] / q)])[0]
                if stub > depth[p] / 2 + 1e-6:
                    poly = shapely.union(poly, _band(lines[w.children[c.vertex]], [0.0],
                                                     [stub], [depth[p]])[0])
            placed.append(poly)
            idx[j] = c
        # where a part boundary falls on a slight bend the neighbours' square cuts overlap
        # in a thin wedge: every part gives up what the parts before it cover
        arr = np.asarray(placed, dtype=object)
        out = arr.copy()
        tree = shapely.STRtree(arr)
        for j in range(1, len(arr)):
            hit = tree.query(arr[j], predicate="intersects")
            hit = hit[hit < j]
            if len(hit):
                out[j] = shapely.difference(arr[j], shapely.union_all(out[hit]))
        geoms.extend(out)
        seq = np.asarray(s.sequence, dtype=np.int64)
        part = np.array([c.part for c in idx], dtype=np.int64)
        rows.append(pd.DataFrame({
            "solution": rank, "cost": s.cost, "seq_index": np.arange(len(seq)),
            "part_id": t["part_id"].to_numpy()[part], "kind": t["kind"].to_numpy()[part],
            "role": [c.role for c in idx],
            "wing": [c.line for c in idx],
            "start_m": np.asarray(s.starts), "length_m": length[part],
            "base_m": 0.0, "top_m": t["height_m"].to_numpy(float)[part],
            "height_m": t["height_m"].to_numpy(float)[part],
            "levels": t["levels"].to_numpy()[part].astype(int),
            "floor_area_m2": R_lib[part, 1]}))
        row = dict(solution=rank, cost=s.cost, n_parts=len(seq), length_m=float(s.totals[0]),
                   floor_area_m2=float(R_lib[part, 1].sum()))
        row["far"] = row["floor_area_m2"] / site_area if site_area else np.nan
        for jn, nm in enumerate(names[2:], start=2):
            row[nm] = float(R_lib[part, jn].sum())
        summaries.append(row)
        kept.append(sequences.Solution(rank=rank, cost=s.cost, sequence=tuple(part.tolist()),
                                       starts=s.starts, totals=s.totals))
    return PartsResult(np.asarray(geoms, dtype=object), pd.concat(rows, ignore_index=True),
                       pd.DataFrame(summaries), kept)
