"""Guided re-synthesis of footprint layouts along block boundaries (thesis ch. 5.2).

A block's footprints are discrete elements grouped by the boundary segment (street) they
front: an element within a directed Hausdorff distance of tau = 25 m of a segment belongs to
its group; an element of two or more groups is *fixed* (a corner building, placed at most
once), of one group *repeatable*; each group also has a virtual *empty space* element
(1 m wide, the group's mean depth). A boundary edit or an example-to-target fit gives a map
phi (mean value coordinates); the warped elements phi(P) are the guidance map, and
phi(T(P)) with T an anisotropic scaling by 1.5 along the segment is the modified guidance
that lets neighbouring guides overlap. Per group, the sequence of undeformed elements on
1 m steps that minimises

    L(f_1..f_N) = sum_k O(f_k) + sum_k delta(f_k, f_k+1)                    (eq. 5.1)

with O(f) = A(P_i) - A(P_i at m  ∩  P''_i) and delta = alpha (two empty spaces),
1 - alpha (the same element twice) or 0, alpha = 0.05, is found exactly by dynamic
programming over positions (eq. 5.2; the thesis pops a priority queue over the same
graph, both give the optimum of eq. 5.3). Groups go in descending number of elements;
a later group may not put an element into the convex hull of the earlier groups' sequences.

**Continuous rows** (terraced houses, closed perimeter rows): where a group's example
elements form one row whose neighbours touch or stand less than ``ROW_GAP`` = 1 m apart
(measured on the undeformed example, so the warp cannot open or close a gap) and whose
guidance reaches both ends of the free frontage (within ``SPAN_TOL``), the new row must
fill that frontage *exactly*: no gap, no overhang. The frontage [a, b] is the stretch of
the row's front line inside the buildable area and outside the earlier groups' hulls.
The sequence is then the optimum of the same energy (overlap data term on 1 m steps,
repetition cost 1 - alpha) under the equality constraint sum of widths = round(b - a)
on the 1 m grid, solved by the resource-constrained shortest-path engine
(:func:`sequences.solve`); the corner (fixed) elements at the row's ends are pinned there
(``first`` / ``last`` and the data term), other fixed elements get a 0/1 resource each
(at most once). There is no empty-space element. The footprints are then laid side by
side at their true widths, ``GAP`` apart, from ``a``; the residual of the grid rounding
(the true widths and ``b - a`` are not whole metres) is absorbed by stretching or
shrinking the *last repeatable* element of the row along the street, by less than 1 m
(when the rounding errors of many elements add up to 1 m or more, the residual is shared
equally by all repeatable elements instead). When no sequence meets the length exactly
the group falls back to the unconstrained DP.

References
----------
Hartmann, S., Weinmann, M., Wessel, R., Klein, R. (2015), "Layout retargeting" (the
re-targeting paper), sections 3-4; Hartmann, thesis ch. 5.2.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from ..core import coordinates
from ..core.geometry import longest_edge_directions, ring_turns
from ..retrieval.warp import warp_geometries
from .sequences import Constraint, InfeasibleError, solve

__all__ = ["TAU", "ALPHA", "STEP", "GUIDE_SCALE", "EMPTY_WIDTH", "Segment",
           "boundary_segments", "assign_groups", "sequence_dp", "retarget_layout",
           "Placement"]

#: Hausdorff distance of an element to a boundary segment for grouping (paper: 25 m).
TAU = 25.0
#: Repetition cost weight (paper: alpha = 0.05).
ALPHA = 0.05
#: Position step along a segment (paper: 1 m).
STEP = 1.0
#: Anisotropic scaling of the modified guidance map along the segment (paper: 1.5).
GUIDE_SCALE = 1.5
#: Width of the virtual empty-space element (paper: 1.0 m).
EMPTY_WIDTH = 1.0
#: A turn sharper than this (degrees) splits the block boundary into segments.
CORNER_ANGLE = 30.0
#: Footprints within this angle (degrees, modulo 90) of the segment are squared to it.
SQUARE_ANGLE = 20.0
#: Footprint outlines are densified to this (m) before the warp bends them.
WARP_SEGMENT = 10.0
#: Gap kept between consecutive elements (m): touching walls become 1 cm apart.
GAP = 0.01
#: How far (m) a placed footprint may reach out of the buildable area (it is cut there).
OUT_TOL = 0.5
#: The exact frontage is kept this far (m) inside its ends (floating-point safety).
EDGE = 1e-6
#: Example neighbours closer than this (m) belong to one continuous row (terraced houses).
ROW_GAP = 1.0
#: A continuous row spans its street when its guidance reaches within this (m) of both
#: ends of the free frontage.
SPAN_TOL = 3.0
#: Consecutive guides of a row may overlap along the street by at most this share of the
#: narrower one (the warp bulges guides); more is a building behind another (a backyard).
ROW_OVERLAP = 0.5
#: Fixed elements inside a row beyond this many keep the unconstrained DP (each costs a
#: resource dimension of the intermediate graph).
ROW_MAX_FIXED = 4


@dataclass
class Segment:
    """A boundary segment S_j: its polyline and the chord frame used for positions."""

    line: shapely.LineString
    a: np.ndarray        # chord start
    u: np.ndarray        # unit direction along the chord
    n: np.ndarray        # unit inward normal
    length: float


@dataclass
class Placement:
    """One placed element: the source element index and its polygon."""

    element: int
    polygon: shapely.Geometry
    group: int
    kind: str            # 'fixed', 'repeatable' or 'interior'
    row: bool = False    # part of a continuous row filled to its exact frontage


def boundary_segments(block, corner_angle: float = CORNER_ANGLE,
                      simplify: float = 1.0) -> List[Segment]:
    """Split a block's exterior at its corners into street segments.

    The ring is simplified by ``simplify`` metres, oriented counter-clockwise (the interior
    on the left) and cut at vertices that turn by more than ``corner_angle``; a ring
    without corners (a round block) is cut into four arcs.
    """
    poly = orient(shapely.get_geometry(block, 0) if block.geom_type == "MultiPolygon"
                  else block, 1.0)
    ring = shapely.simplify(poly.exterior, simplify)
    xy = shapely.get_coordinates(ring)[:-1]
    if len(xy) < 3:
        xy = shapely.get_coordinates(poly.exterior)[:-1]
    turn = np.abs(ring_turns(xy))
    corners = np.flatnonzero(turn > corner_angle)
    if len(corners) < 2:
        corners = np.round(np.linspace(0, len(xy), 5)[:-1]).astype(int) % len(xy)
        corners = np.unique(corners)
    segs = []
    for i, c0 in enumerate(corners):
        c1 = corners[(i + 1) % len(corners)]
        idx = np.arange(c0, c1 + 1) if c1 > c0 else np.r_[np.arange(c0, len(xy)),
                                                           np.arange(0, c1 + 1)]
        pts = xy[idx]
        chord = pts[-1] - pts[0]
        length = float(np.hypot(*chord))
        if length < 1e-6:
            continue
        u = chord / length
        segs.append(Segment(shapely.LineString(pts), pts[0].copy(), u,
                            np.array([-u[1], u[0]]), length))
    return segs


def assign_groups(elements: Sequence, segments: Sequence[Segment],
                  tau: float = TAU) -> np.ndarray:
    """Boolean (n_elements, n_segments): element P_i belongs to group G_j.

    The distance is the directed Hausdorff distance from the element outline to the
    segment (the farthest vertex of P_i from S_j): P_i fronts S_j when all of it lies
    within ``tau`` of the street.
    """
    elements = np.asarray(elements, dtype=object)
    if len(elements) == 0 or len(segments) == 0:
        return np.zeros((len(elements), len(segments)), dtype=bool)
    coords, idx = shapely.get_coordinates(elements, return_index=True)
    lines = np.array([s.line for s in segments], dtype=object)
    dist = shapely.distance(shapely.points(coords)[:, None], lines[None, :])
    starts = np.r_[0, np.flatnonzero(np.diff(idx)) + 1]
    far = np.maximum.reduceat(dist, starts, axis=0)
    out = np.zeros((len(elements), len(segments)), dtype=bool)
    out[idx[starts]] = far <= tau
    return out


def sequence_dp(cost: np.ndarray, width: np.ndarray, fixed_bit: np.ndarray,
                alpha: float = ALPHA) -> Tuple[float, List[Tuple[int, int]]]:
    """Optimal element sequence along one segment (eqs. 5.1-5.3), exact.

    Parameters
    ----------
    cost : (K, M) data term O of element k starting at slot m (inf = forbidden); the last
        row is the empty-space element
    width : (K,) int slots each element occupies (>= 1)
    fixed_bit : (K,) int, a distinct power of two for fixed elements (placed at most
        once), 0 otherwise
    alpha : float, the repetition weight: delta = alpha for two consecutive empty spaces,
        1 - alpha for the same element twice, 0 otherwise

    Returns
    -------
    (total cost, [(element, start slot), ...]) of the cheapest sequence that starts at slot
    0 and reaches slot M (the last element may overhang); (inf, []) when none exists.
    """
    cost = np.asarray(cost, dtype=np.float64)
    k_n, m_n = cost.shape
    # plain Python lists: the state space per position is tiny (elements x fixed masks),
    # where numpy's per-call overhead would dominate
    o = cost.tolist()
    w = [int(x) for x in np.asarray(width)]
    bit = [int(x) for x in np.asarray(fixed_bit)]
    n_masks = max(bit) * 2 if any(bit) else 1
    same = [1.0 - alpha] * (k_n - 1) + [alpha]
    inf = float("inf")
    start = k_n
    size = k_n * n_masks
    # state (p, last, mask) at index last * n_masks + mask: a sequence covering [0, p)
    c = [[inf] * size for _ in range(m_n + 1)]
    par = [[None] * size for _ in range(m_n + 1)]   # (start slot of last, previous last, mask)
    for p in range(m_n):
        row = c[p]
        for s in range(n_masks):
            if p == 0:
                m1, a1, m2, a2 = (0.0, start, inf, -1) if s == 0 else (inf, -1, inf, -1)
            else:
                m1 = m2 = inf
                a1 = a2 = -1
                for k in range(k_n):
                    v = row[k * n_masks + s]
                    if v < m1:
                        m2, a2, m1, a1 = m1, a1, v, k
                    elif v < m2:
                        m2, a2 = v, k
            if m1 == inf:
                continue
            for k in range(k_n):
                b = bit[k]
                if s & b:
                    continue
                if a1 == k:
                    best, arg = m2, a2
                    rep = m1 + same[k]
                    if rep < best:
                        best, arg = rep, k
                else:
                    best, arg = m1, a1
                val = best + o[k][p]
                if val == inf:
                    continue
                p2 = p + w[k]
                if p2 > m_n:
                    p2 = m_n
                idx = k * n_masks + (s | b)
                if val < c[p2][idx]:
                    c[p2][idx] = val
                    par[p2][idx] = (p, arg, s)
    final = c[m_n]
    best_i = min(range(size), key=final.__getitem__)
    total = final[best_i]
    if total == inf:
        return inf, []
    seq = []
    p, k, s = m_n, best_i // n_masks, best_i % n_masks
    while True:
        q, last, s_prev = par[p][k * n_masks + s]
        seq.append((k, q))
        if last == start:
            break
        p, k, s = q, last, s_prev
    return float(total), seq[::-1]


def _valid(geoms: np.ndarray) -> np.ndarray:
    """Valid polygons: invalid ones repaired, keeping their polygonal part."""
    geoms = np.asarray(geoms, dtype=object)
    bad = ~shapely.is_valid(geoms)
    if bad.any():
        fixed = shapely.make_valid(geoms[bad])
        # the polygonal part of a repaired geometry (a fold also leaves lines)
        parts = [shapely.union_all([p for p in shapely.get_parts(g) if p.geom_type in
                                    ("Polygon", "MultiPolygon")]) for g in fixed]
        geoms = geoms.copy()
        geoms[bad] = parts
    return geoms


def _translate(geom, offsets: np.ndarray) -> np.ndarray:
    """Copies of one geometry moved by each of ``offsets`` (m, 2), vectorised."""
    return coordinates.translate(np.full(len(offsets), geom, dtype=object), offsets)


def _local(coords: np.ndarray, seg: Segment) -> np.ndarray:
    rel = coords - seg.a
    return np.column_stack([rel @ seg.u, rel @ seg.n])


def _bounds_local(geoms: np.ndarray, seg: Segment) -> np.ndarray:
    """(n, 4) u_min, u_max, v_min, v_max of each geometry in the segment frame."""
    coords, idx = shapely.get_coordinates(geoms, return_index=True)
    loc = _local(coords, seg)
    n = len(geoms)
    out = np.full((n, 4), np.nan)
    if len(idx) == 0:
        return out
    starts = np.r_[0, np.flatnonzero(np.diff(idx)) + 1]
    out[idx[starts], 0] = np.minimum.reduceat(loc[:, 0], starts)
    out[idx[starts], 1] = np.maximum.reduceat(loc[:, 0], starts)
    out[idx[starts], 2] = np.minimum.reduceat(loc[:, 1], starts)
    out[idx[starts], 3] = np.maximum.reduceat(loc[:, 1], starts)
    return out


def _scale_along(geoms: np.ndarray, u: np.ndarray, factor: float) -> np.ndarray:
    """Anisotropic scaling of each geometry about its centroid along direction ``u``."""
    cen = shapely.get_coordinates(shapely.centroid(geoms))

    def fn(xy, i):
        along = ((xy - cen[i]) * u).sum(1)
        return xy + (factor - 1.0) * along[:, None] * u[None, :]
    return coordinates.transform(geoms, fn)


def _overlap_term(el: np.ndarray, base_off: np.ndarray, seg: Segment, slots: np.ndarray,
                  areas: np.ndarray, width_m: np.ndarray, g2: np.ndarray, g2b: np.ndarray,
                  buildable, blocked, out_tol: float = OUT_TOL):
    """Data term O of eq. 5.1 for each element starting at each slot (m along the chord).

    O = A(P) - A(P at the slot ∩ its modified guide); inf where a corner of the footprint
    leaves the buildable area by more than ``out_tol`` (it would only be cut there) or where
    it meets ``blocked``. Returns (cost (k, slots), candidate polygons per element).
    """
    k_n, m_n = len(el), len(slots)
    cost = np.empty((k_n, m_n))
    shapes = []
    allowed = shapely.buffer(buildable, out_tol, quad_segs=2)
    shapely.prepare(allowed)
    for k in range(k_n):
        offs = base_off[k] + slots[:, None] * seg.u
        cand = _translate(el[k], offs)
        shapes.append(cand)
        xy, idx = shapely.get_coordinates(cand, return_index=True)
        inside = shapely.contains_xy(allowed, xy[:, 0], xy[:, 1])
        out_slot = np.bincount(idx, weights=~inside, minlength=m_n) > 0
        row = np.full(m_n, areas[k])
        lo, hi = g2b[k, 0], g2b[k, 1]
        if np.isfinite(lo):
            near = (slots + width_m[k] > lo) & (slots < hi)
            if near.any():
                row[near] = areas[k] - shapely.area(shapely.intersection(cand[near], g2[k]))
        row[out_slot] = np.inf
        if blocked is not None:
            row[shapely.intersects(cand, blocked)] = np.inf
        cost[k] = row
    return cost, shapes


def _intervals(geom, seg: Segment) -> List[Tuple[float, float]]:
    """Chord-coordinate intervals [u0, u1] of the line pieces of ``geom``."""
    parts = shapely.get_parts(geom)
    out = []
    for part in parts[(shapely.get_type_id(parts) == 1) & ~shapely.is_empty(parts)]:
        u = (shapely.get_coordinates(part) - seg.a) @ seg.u
        out.append((float(u.min()), float(u.max())))
    return out


def _subtract(free: List[Tuple[float, float]], cut: List[Tuple[float, float]],
              gap: float) -> List[Tuple[float, float]]:
    """Intervals ``free`` less ``cut`` (each widened by ``gap``: a new wall never touches)."""
    for c0, c1 in cut:
        nxt = []
        for a, b in free:
            if c1 + gap <= a or c0 - gap >= b:
                nxt.append((a, b))
                continue
            if c0 - gap > a:
                nxt.append((a, c0 - gap))
            if c1 + gap < b:
                nxt.append((c1 + gap, b))
        free = nxt
    return free


def _row_frontage(seg: Segment, el_rest: np.ndarray, gb: np.ndarray, fixed: np.ndarray,
                  v_front: float, buildable, blocked):
    """(order, a, b) when the group is a continuous row spanning its street, else None.

    Continuous: ordered along the street by their guides, neighbouring example elements
    are less than ``ROW_GAP`` apart (in the example, where the warp cannot change it) and
    their guides do not stand behind one another. ``[a, b]``: the piece of the row's front
    line (depth ``v_front``) inside the buildable area and outside the earlier groups'
    hulls that the guides cover most; the row spans it when its guides reach both ends
    within ``SPAN_TOL``.
    """
    k_n = len(el_rest)
    if k_n < 2 or not np.isfinite(gb[:, :2]).all():
        return None
    order = np.argsort(0.5 * (gb[:, 0] + gb[:, 1]), kind="stable")
    if (fixed[order[1:-1]].sum() > ROW_MAX_FIXED or
            (gb[order[:-1], 1] - gb[order[1:], 0] >
             ROW_OVERLAP * np.minimum(np.diff(gb[order[:-1], :2], axis=1)[:, 0],
                                      np.diff(gb[order[1:], :2], axis=1)[:, 0])).any() or
            not (shapely.distance(el_rest[order[:-1]], el_rest[order[1:]]) < ROW_GAP).all()):
        return None
    line = shapely.LineString([seg.a - seg.length * seg.u + v_front * seg.n,
                               seg.a + 2.0 * seg.length * seg.u + v_front * seg.n])
    free = _intervals(shapely.intersection(line, buildable), seg)
    if blocked is not None and free:
        free = _subtract(free, _intervals(shapely.intersection(line, blocked), seg), GAP)
    if not free:
        return None
    g_lo, g_hi = gb[order[0], 0], gb[order[-1], 1]
    a, b = max(free, key=lambda ab: min(ab[1], g_hi) - max(ab[0], g_lo))
    if min(b, g_hi) - max(a, g_lo) <= 0 or g_lo > a + SPAN_TOL or g_hi < b - SPAN_TOL:
        return None
    # a micrometre inside: the walls summed along the row must not round out of the area
    return order, a + EDGE, b - EDGE


def _scale_from(poly, seg: Segment, start: float, factor: float):
    """Scale ``poly`` along the chord by ``factor``, keeping its wall at ``start``."""
    def fn(xy, _):
        along = ((xy - seg.a) * seg.u).sum(1) - start
        return xy + (factor - 1.0) * along[:, None] * seg.u[None, :]
    return coordinates.transform([poly], fn)[0]


def _fill_row(seg: Segment, members: np.ndarray, order: np.ndarray, a: float, b: float,
              el: np.ndarray, width_m: np.ndarray, base_off: np.ndarray, areas: np.ndarray,
              fixed: np.ndarray, g2: np.ndarray, g2b: np.ndarray, buildable, blocked,
              step: float, alpha: float):
    """A continuous row filling the frontage [a, b] exactly; None when no sequence can.

    The optimum of eq. 5.1 over the sequences whose grid widths sum to exactly
    round((b - a) / step), by :func:`sequences.solve`; see the module docstring for the
    corner pinning and the sub-metre residual.
    """
    k_n = len(members)
    m_n = int(round((b - a) / step))
    d = np.maximum(1, np.round(width_m / step)).astype(np.int64)
    if m_n < d.min():
        return None
    slots = a + np.arange(m_n + 1) * step
    # the grid start of an element is up to about a metre off its final place: test the
    # street and the earlier hulls with that much slack (legalise is the hard guarantee)
    shrunk = None
    if blocked is not None:
        shrunk = shapely.buffer(blocked, -step, quad_segs=2)
        shrunk = None if shrunk.is_empty else shrunk
    cost, _ = _overlap_term(el, base_off, seg, slots, areas, width_m, g2, g2b, buildable,
                            shrunk, OUT_TOL + step)
    np.maximum(cost, 0.0, out=cost)     # an overlay may round the overlap above the area
    first, last = ~fixed, ~fixed
    pinned = []
    head, tail = order[0], order[-1]
    # a corner building at an end of the row stays there: only that start is allowed (its
    # cost there is a constant of every feasible sequence, so it is set to 0)
    if fixed[head]:
        first = np.arange(k_n) == head
        cost[head] = np.inf
        cost[head, 0] = 0.0
        pinned.append(head)
    if fixed[tail]:
        at = m_n - d[tail]
        if at < 0:
            return None
        last = np.arange(k_n) == tail
        cost[tail] = np.inf
        cost[tail, at] = 0.0
        pinned.append(tail)
    transition = np.zeros((k_n, k_n))
    transition[np.diag_indices(k_n)] = np.where(fixed, np.inf, 1.0 - alpha)
    # any other fixed element at most once: a 0/1 resource of its own (the graph method)
    loose = [k for k in np.flatnonzero(fixed) if k not in pinned]
    res = np.zeros((k_n, 1 + len(loose)))
    res[:, 0] = d * step
    constraints = [Constraint.equal(0, m_n * step)]
    for j, k in enumerate(loose, start=1):
        res[k, j] = 1.0
        constraints.append(Constraint(j, 0.0, 1.0))
    try:
        best = solve(res, transition, constraints, resolution=np.r_[step, np.ones(len(loose))],
                     position_cost=cost, first=first, last=last)[0]
    except InfeasibleError:
        return None
    seq = np.asarray(best.sequence, dtype=np.int64)
    w = width_m[seq].astype(np.float64)
    # true widths side by side, GAP apart; the grid rounding residual goes to the last
    # repeatable element (< 1 m), or is shared by all repeatable ones when it is larger
    eps = (b - a) - (w.sum() + GAP * (len(seq) - 1))
    rep = np.flatnonzero(~fixed[seq])
    adj = np.zeros(len(seq))
    if len(rep) == 0:
        adj[:] = eps / len(seq)
    elif abs(eps) < step:
        adj[rep[-1]] = eps
    else:
        adj[rep] = eps / len(rep)
    w2 = w + adj
    if (w2 < 0.5 * w).any():
        return None
    starts = a + np.r_[0.0, np.cumsum(w2 + GAP)[:-1]]
    out = []
    for i, k in enumerate(seq):
        poly = _translate(el[k], (base_off[k] + starts[i] * seg.u)[None, :])[0]
        if adj[i] != 0.0:
            poly = _scale_from(poly, seg, starts[i], w2[i] / w[i])
        out.append((int(members[k]), poly))
    return out


def _synthesize_group(seg: Segment, members: np.ndarray, kinds: np.ndarray,
                      rest: np.ndarray, guides: np.ndarray, scaled_guides: np.ndarray,
                      buildable, blocked, inset: float, step: float, alpha: float):
    """Place one group's sequence; returns ([(element, polygon)] in order, is_row)."""
    m_n = int(round(seg.length / step))
    if m_n < 1 or len(members) == 0:
        return [], False
    # square each footprint to its street when it nearly is (it keeps its shape)
    theta = np.arctan2(seg.u[1], seg.u[0])
    el = rest[members]
    cen = shapely.get_coordinates(shapely.centroid(el))
    longest = longest_edge_directions(shapely.get_exterior_ring(el))
    diff = (theta - longest + np.pi / 4) % (np.pi / 2) - np.pi / 4
    diff = np.where(np.abs(diff) <= np.radians(SQUARE_ANGLE), diff, 0.0)
    el = coordinates.rotate(el, diff, cen)
    eb = _bounds_local(el, seg)
    gb = _bounds_local(guides[members], seg)
    width_m = eb[:, 1] - eb[:, 0]
    d = np.maximum(1, np.round(width_m / step)).astype(np.int64)
    v0 = np.maximum(gb[:, 2], inset + GAP)
    areas = shapely.area(el)
    # modified guidance, clipped to where buildings may stand
    g2 = shapely.intersection(scaled_guides[members], buildable)
    if blocked is not None:
        g2 = shapely.difference(g2, blocked)
    g2b = _bounds_local(g2, seg)
    k_n = len(members)
    base_off = (-eb[:, 0])[:, None] * seg.u + (v0 - eb[:, 2])[:, None] * seg.n
    is_fixed = kinds[members] == "fixed"
    # a continuous row (terraced houses) fills its frontage exactly; members whose guide
    # lies mostly in an earlier group's hull (a warp pulled the house next to a corner
    # within tau of this street too) belong to that group's row, not to this one
    sub = np.arange(k_n)
    if k_n >= 2 and blocked is not None:
        gm = guides[members]
        sub = np.flatnonzero(shapely.area(shapely.intersection(gm, blocked))
                             <= 0.5 * shapely.area(gm))
    if len(sub) >= 2:
        found = _row_frontage(seg, rest[members[sub]], gb[sub], is_fixed[sub],
                              float(np.median(v0[sub])) + 0.5, buildable, blocked)
        if found is not None:
            row = _fill_row(seg, members[sub], *found, el[sub], width_m[sub], base_off[sub],
                            areas[sub], is_fixed[sub], g2[sub], g2b[sub], buildable, blocked,
                            step, alpha)
            if row is not None:
                return row, True
    slots = np.arange(m_n) * step
    cost = np.empty((k_n + 1, m_n))
    cost[:k_n], shapes = _overlap_term(el, base_off, seg, slots, areas, width_m, g2, g2b,
                                       buildable, blocked)
    # empty space: the guidance area it would leave empty
    depth = float(np.mean(eb[:, 3] - eb[:, 2]))
    v_e = float(np.median(v0))
    union = shapely.union_all(shapely.intersection(guides[members], buildable))
    if union.is_empty:
        cost[k_n] = 0.0
    else:
        ub = _bounds_local(np.array([union], dtype=object), seg)[0]
        row = np.zeros(m_n)
        near = (slots + EMPTY_WIDTH > ub[0]) & (slots < ub[1])
        if near.any():
            corners = seg.a + slots[near, None] * seg.u + v_e * seg.n
            boxes = shapely.polygons(np.stack([
                corners, corners + EMPTY_WIDTH * seg.u,
                corners + EMPTY_WIDTH * seg.u + depth * seg.n, corners + depth * seg.n],
                axis=1))
            row[near] = shapely.area(shapely.intersection(boxes, union))
        cost[k_n] = row
    width = np.r_[d, max(1, int(round(EMPTY_WIDTH / step)))]
    fixed = np.flatnonzero(is_fixed)[:12]
    # the paper's energy lets a sequence omit any element for free; a corner building
    # left out of a shrunk street must cost its area, else tight streets lose their corners
    cost[fixed] -= areas[fixed, None]
    bits = np.zeros(k_n + 1, dtype=np.int64)
    bits[fixed] = 1 << np.arange(len(fixed))
    _, seq = sequence_dp(cost, width, bits, alpha)
    out = []
    end = -np.inf
    for k, q in seq:
        if k == k_n:
            continue
        # the rounded width may be shorter than the wall: push on by the remainder so that
        # consecutive buildings never overlap
        start_u = max(q * step, end + GAP)
        poly = shapes[k][q] if start_u == q * step else \
            _translate(el[k], (base_off[k] + start_u * seg.u)[None, :])[0]
        end = start_u + width_m[k]
        out.append((int(members[k]), poly))
    return out, False


def retarget_layout(elements: Sequence, source: np.ndarray, target: np.ndarray,
                    target_block, buildable, inset: float = 0.0, tau: float = TAU,
                    alpha: float = ALPHA, step: float = STEP,
                    guide_scale: float = GUIDE_SCALE,
                    keep_interior: bool = True) -> List[Placement]:
    """Re-synthesise a layout of ``elements`` in a target block (paper sections 3-4).

    Parameters
    ----------
    elements : array of Polygon, the undeformed footprints in the source frame (for an
        example block: already rigidly aligned with the target)
    source, target : (n, 2) corresponding boundary points of the source and target domain:
        the map phi is the mean value coordinate warp between them
    target_block : Polygon, the target domain D_d
    buildable : Polygon, where footprints may stand (the block less the street offset)
    inset : float, the distance of ``buildable`` from the block boundary (street half
        width + setback): elements never start closer to the street
    tau, alpha, step, guide_scale : the paper's parameters (25 m, 0.05, 1 m, 1.5)
    keep_interior : bool, place elements of no group (courtyard buildings; ignored by the
        paper) rigidly at their guidance position

    Returns
    -------
    list of Placement (not yet legalised: the caller trims what still overlaps).
    """
    elements = np.asarray(elements, dtype=object)
    if len(elements) == 0:
        return []
    # a warp near a concave corner can fold an outline: repair, keep the largest piece
    guides = _valid(warp_geometries(elements, source, target, max_segment=WARP_SEGMENT))
    segs = boundary_segments(target_block)
    member = assign_groups(guides, segs, tau)
    # element types come from the initial domain (a stretched corner building stays one);
    # the groups they join are the target's streets their guides front
    n_src = member.sum(1)
    src_poly = shapely.Polygon(np.asarray(source, dtype=np.float64))
    if src_poly.is_valid and src_poly.area > 0:
        n_src = assign_groups(elements, boundary_segments(src_poly), tau).sum(1)
    kinds = np.where(n_src >= 2, "fixed", "repeatable")
    kinds = np.where(member.any(1), kinds, "interior")
    order = sorted(range(len(segs)), key=lambda j: (-int(member[:, j].sum()), -segs[j].length))
    placed: List[Placement] = []
    blocked = None
    used_fixed = np.zeros(len(elements), dtype=bool)
    for j in order:
        members = np.flatnonzero(member[:, j] & ~used_fixed)
        if len(members) == 0:
            continue
        seg = segs[j]
        # modified guidance chi(T) = phi(T(P)) of this group's elements only
        scaled = np.empty(len(elements), dtype=object)
        scaled[members] = _valid(warp_geometries(
            _scale_along(elements[members], seg.u, guide_scale), source, target,
            max_segment=WARP_SEGMENT))
        # GEOS reports round-off on touching guides and lots as 'invalid value' warnings
        # (printed to the user's console); the overlays' results are sound
        with np.errstate(invalid="ignore"):
            seq, is_row = _synthesize_group(seg, members, kinds, elements, guides, scaled,
                                            buildable, blocked, inset, step, alpha)
        if not seq:
            continue
        for i, poly in seq:
            placed.append(Placement(i, poly, j, str(kinds[i]), is_row))
            if kinds[i] == "fixed":
                used_fixed[i] = True
        hull = shapely.convex_hull(shapely.union_all([p for _, p in seq]))
        blocked = hull if blocked is None else shapely.union(blocked, hull)
    if keep_interior:
        inner = np.flatnonzero(kinds == "interior")
        if len(inner):
            shift = shapely.get_coordinates(shapely.centroid(guides[inner])) - \
                shapely.get_coordinates(shapely.centroid(elements[inner]))
            for i, off in zip(inner, shift):
                poly = _translate(elements[i], off[None, :])[0]
                if blocked is None or not shapely.intersects(poly, blocked):
                    placed.append(Placement(int(i), poly, -1, "interior"))
    return placed
