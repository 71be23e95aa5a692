"""Steering the dead-end share of a synthesised network towards the example's.

The fidelity issue asks every road synthesis to keep the dead-end share (dead ends among the
nodes of degree != 2, :func:`invariants.dead_end_share`) within ±30 % of the example's. A
method that adds streets one by one cannot aim at that number while it builds, so it ends
with one more pass: while the share, counted as it will be measured, is above the
example's, close dead ends; while it is below, open new ones. This module is the one home of
that rule; each method says what closing and opening are for its streets (the random walk:
one more step from a stub, or a new street from an unreached dead-end point onto the nearest
street; the fragment synthesis: a short link from a dead end onto the nearest street, or
the stem of a T cut short into a cul-de-sac). For a network of lines (the fragment
synthesis', StreetGAN's) those two are here too: :func:`steer_dead_ends`, and
:func:`steer_into_band` for once more where a later step moved the share out of the band.

References
----------
docs/ARCHITECTURE.md, "Quality measures"; issue 15 (the dead-end share within ±30 % of the
example's). Not in the papers: their syntheses leave the share where the streets put it.
"""
from __future__ import annotations

from typing import Callable, Iterable, List, Tuple

import numpy as np
import shapely
from scipy.cluster.hierarchy import DisjointSet
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely.ops import substring

from .blocks import planar_faces
from .invariants import (CORRIDOR_HALF_WIDTH, DEAD_END_TOLERANCE, SNAP_TOLERANCE,
                         corridor_around, counted_nodes, dead_end_share, doubles_a_street)
from .links import meets_only_at_ends
from .street_graph import add_streets, clean_network, renode_attributed, synthesised

__all__ = ["steer_share", "steer_dead_ends", "steer_into_band", "steer_attributed", "MIN_DANGLE",
           "CLOSE_REACH"]

#: New dead-end edges shorter than this (m) are pruned (stubs of clipped warps: tuned on the
#: fidelity benchmark's tuning towns, where 5 m left a dead-end share 30 % over the example's).
MIN_DANGLE = 25.0
#: A dead end closes onto a street at most this far (m) when the network has too many.
CLOSE_REACH = 2 * MIN_DANGLE


def steer_share(share_now: Callable[[], float], target: float,
                close: Callable[[object], bool], close_candidates: Callable[[], Iterable],
                open_: Callable[[object], bool], open_candidates: Callable[[], Iterable],
                tolerance: float = 0.0) -> Tuple[int, int]:
    """Close dead ends while the share is above ``target``, then open while it is below
    (beyond ``tolerance``, relative: 0 steers to the target itself).

    Parameters
    ----------
    share_now : () -> float, the share as it will be measured, after the changes so far
    target : float, the example's share
    close : candidate -> bool, close one dead end (True when it did)
    close_candidates : () -> iterable, the dead ends to try, in order (called once, before
        the first is closed, even when none needs closing: a method that draws the order
        from its random generator draws it at the same point of its sequence every time)
    open_ : candidate -> bool, open one dead end (True when it did)
    open_candidates : () -> iterable, where to try, in order (called once, after closing)
    tolerance : float, relative: closing stops at ``target * (1 + tolerance)``, opening at
        ``target * (1 - tolerance)`` (a method that changes its streets as little as the
        rule allows steers into the band, with a margin, rather than onto its middle)

    Returns
    -------
    (n_closed, n_opened)

    Examples
    --------
    >>> state = {"dead": 1, "nodes": 10}
    >>> def share():
    ...     return state["dead"] / state["nodes"]
    >>> def open_one(_):
    ...     state["dead"] += 1
    ...     return True
    >>> steer_share(share, 0.3, lambda c: False, lambda: [], open_one, lambda: range(5))
    (0, 2)
    """
    high, low = target * (1 + tolerance), target * (1 - tolerance)
    n_closed = 0
    for c in close_candidates():
        if share_now() <= high:
            break
        n_closed += bool(close(c))
    n_opened = 0
    for c in open_candidates():
        if share_now() >= low:
            break
        n_opened += bool(open_(c))
    return n_closed, n_opened


def steer_attributed(geometry, level, attrs, share: float, area, rng, min_dangle: float,
                     max_block: float = np.inf):
    """:func:`_steer_dead_ends` for a network whose lines carry levels and provenance
    attributes (the fragment synthesis'), again from the measured network (up to three
    rounds) where its count drifted from the measure's; returns the network, its levels and
    attributes, (closed, opened) and the measured share."""
    n_closed = n_opened = 0
    now = np.nan
    for _ in range(3):
        geometry, level, attrs, (closed, opened) = _steer_dead_ends(
            geometry, level, attrs, share, area, rng, min_dangle, max_block)
        n_closed, n_opened = n_closed + closed, n_opened + opened
        now = dead_end_share(geometry, area)
        if not (closed or opened) or not np.isfinite(now) or \
                abs(now - share) <= share * DEAD_END_TOLERANCE / 2 + 1e-9:
            break
    return geometry, level, attrs, (n_closed, n_opened), now


def steer_dead_ends(lines, is_new, share: float, area, rng: np.random.Generator,
                    min_dangle: float = MIN_DANGLE, max_block: float = np.inf):
    """The fragment synthesis' dead-end steering (:func:`_steer_dead_ends`, in rounds from
    the measured network) for any network: ``is_new`` marks the lines it may change; the
    others are given and kept as they are. Returns (lines, is_new, (closed, opened)): the
    network re-noded, chains of new lines through degree-2 nodes merged."""
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    n = len(lines)
    attrs = {"source_fragment": np.where(is_new, "new", "arterial").astype(object),
             "database": np.full(n, "", dtype=object),
             "fragment_id": np.full(n, -1, dtype=np.int64),
             # given lines keep their own features: no two merge through a degree-2 node
             "query": np.where(is_new, -1, -2 - np.arange(n)).astype(np.int64)}
    geometry, _, attrs, counts, _ = steer_attributed(lines, is_new.astype(np.int64), attrs,
                                                     share, area, rng, min_dangle, max_block)
    return geometry, attrs["source_fragment"] != "arterial", counts


def steer_into_band(lines, is_new, share: float, area, rng: np.random.Generator):
    """Where the dead-end share (as the invariants measure it) is outside their band around
    ``share`` (a step after :func:`steer_dead_ends` moved it: StreetGAN's crossings; or a
    small network, where one dead end is a tenth of the share): :func:`steer_dead_ends` once
    more with ``rng``'s draw, its result kept only where it brings the share nearer.
    Returns (lines, is_new, (closed, opened)); (0, 0) where the network is kept."""
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    before = abs(dead_end_share(lines, area) - share)
    if before <= DEAD_END_TOLERANCE * share:
        return lines, is_new, (0, 0)
    again, again_new, counts = steer_dead_ends(lines, is_new, share, area, rng)
    if sum(counts) and abs(dead_end_share(again, area) - share) < before:
        return again, again_new, counts
    return lines, is_new, (0, 0)


def _steer_dead_ends(geometry, level, attrs, share: float, area, rng, min_dangle: float,
                     max_block: float = np.inf):
    """Steer the dead-end share of the network to ``share`` (:func:`steer_share`).

    Counted on the graph :func:`invariants.dead_end_share` builds (nodes of degree != 2
    inside ``area``, away from its boundary, the arterials' nodes too); the changes are
    made to the network's own lines. Too many dead ends: a synthesised dead end is closed by
    the shortest straight street onto another line, at most ``CLOSE_REACH`` m, crossing
    nothing and doubling nothing (shortest gaps first); where no such street is left, a
    synthesised dead-end street is removed (the shortest first) where its other end stays a
    junction. Too few: first a cul-de-sac is added
    (no block is lost: the district model's blocks fell from -19 % to -33 % of the example's
    when T's were cut first): from the middle of a synthesised street, square to it, into
    the larger block beside it, as long as the block's mean width (at least ``min_dangle``
    m), clear of every other street's corridor; then the stem of a synthesised T (the edge
    that leaves the through street at the largest angle) is cut short into a cul-de-sac,
    half its length but at least ``min_dangle`` m kept, whose end is clear of every other
    street's corridor, where the stem is no bridge of the network, its other end stays a
    junction and the two blocks it parted make one no larger than ``max_block`` (the fill's
    threshold: a town of few large blocks would lose them); last, T's whose blocks merge
    larger (streets and T's in random order, as the random walk's unreached points). The
    share is steered into the invariants' band with half of it as margin (``share`` ±15 %),
    not onto ``share``: the streets are the example's, the steering a repair that changes
    as few as the rule allows. Fill, procedural and statistical splits cut
    faces from outline to outline, and the example's dead-end streets outside closed faces
    are in no fragment, so the share otherwise lands wherever the chosen fragments put it
    (0.02 for Helsinki from Bubeneč, whose share is 0.07).

    Returns the network and the counts (closed, opened).
    """
    n = len(geometry)
    if n < 2 or not np.isfinite(share):
        return geometry, level, attrs, (0, 0)
    # the measured graph: nodes closer than SNAP_TOLERANCE are one, look-alikes one street
    g = clean_network(geometry, snap_tolerance=SNAP_TOLERANCE, min_dangle_length=0.0,
                             merge_degree2=False, duplicate_tolerance=SNAP_TOLERANCE)
    u, v, src = np.asarray(g.u), np.asarray(g.v), np.asarray(g.source)
    nodes = np.asarray(g.nodes)
    m = g.n_edges
    deg = np.bincount(np.r_[u, v], minlength=len(nodes))
    inc_node, inc_edge = np.r_[u, v], np.r_[np.arange(m), np.arange(m)]
    lines = np.array(geometry, dtype=object)      # the network's own lines, changed in place
    # an edge stands for its line where it is the whole of it (ends moved by the snapping)
    whole = np.abs(shapely.length(lines[src]) - shapely.length(g.geometry)) < 2 * SNAP_TOLERANCE
    new = synthesised(level, attrs["source_fragment"])[src]
    shapely.prepare(area)

    def counted(xy) -> np.ndarray:
        return counted_nodes(xy, area)

    inside = counted(nodes)
    state = {"dead": int((inside & (deg == 1)).sum()),
             "nodes": int((inside & (deg != 2) & (deg > 0)).sum())}
    joins = np.ones(m, bool)       # edges joining their two nodes (a cut stem does not)
    kept = np.ones(len(lines), bool)   # lines not removed (a dead-end street pruned)
    links: List = []               # closing streets
    stubs: List = []               # new cul-de-sacs

    def share_now() -> float:
        return state["dead"] / state["nodes"] if state["nodes"] else 0.0

    def current():
        added = links + stubs
        return np.concatenate([lines[kept], np.asarray(added, dtype=object)]) if added \
            else lines[kept]

    def touch(j: int, d: int):
        """Degree of node j changes by d: the counts follow."""
        old, now = deg[j], deg[j] + d
        deg[j] = now
        if inside[j]:
            state["dead"] += int(now == 1) - int(old == 1)
            state["nodes"] += int(now not in (0, 2)) - int(old not in (0, 2))

    def end_near(line, xy) -> np.ndarray:
        ends = shapely.get_coordinates(shapely.boundary(line))
        return ends[int(np.argmin(np.hypot(*(ends - xy).T)))] if len(ends) else xy

    # ---- closing: a dead end onto the nearest other line
    def close_candidates():
        tree = shapely.STRtree(lines)
        cand = []
        for k in np.flatnonzero(inside & (deg == 1)):
            e = int(inc_edge[np.flatnonzero(inc_node == k)[0]])
            if not new[e] or not whole[e]:
                continue
            p = shapely.Point(end_near(lines[src[e]], nodes[k]))
            near = tree.query(p, predicate="dwithin", distance=CLOSE_REACH)
            near = near[near != src[e]]
            if len(near):
                d = shapely.distance(lines[near], p)
                cand.append((float(d.min()), int(k), e, int(near[int(np.argmin(d))])))
        # last, dead ends no closing street reaches: their street is pruned (the shortest
        # first) where its other end stays a junction (StreetGAN on Bubenec had 2 dead ends
        # among 8 nodes, none in reach of another street)
        ends = np.flatnonzero(inside & (deg == 1))
        stems = [int(inc_edge[np.flatnonzero(inc_node == k)[0]]) for k in ends]
        prune = sorted((float(g.geometry[e].length), int(k), e, -1) for k, e in zip(ends, stems))
        return sorted(cand) + [(np.inf, k, e, j) for _, k, e, j in prune]

    def close(c) -> bool:
        _, k, e, j = c
        if deg[k] != 1:
            return False
        if j < 0:
            return prune(k, e)
        p = shapely.Point(end_near(lines[src[e]], nodes[k]))
        link = shapely.shortest_line(p, lines[j])
        if link.length <= 1e-6:
            return False
        others = current()
        if not meets_only_at_ends(link, others):
            return False   # it would cross a street
        near = others[shapely.dwithin(others, link, CORRIDOR_HALF_WIDTH)]
        if doubles_a_street(np.array([link]), corridor_around(None, near)).any():
            return False
        links.append(link)
        touch(k, 1)
        q = np.asarray(link.coords[-1])
        at = np.flatnonzero(np.hypot(*(nodes - q).T) <= SNAP_TOLERANCE)
        if len(at):
            touch(int(at[0]), 1)
        elif counted(q)[0]:
            state["nodes"] += 1     # a new T on the line
        return True

    def prune(k: int, e: int) -> bool:
        o = int(v[e] if u[e] == k else u[e])
        if not new[e] or not whole[e] or not joins[e] or o == k or deg[o] < 3:
            return False
        kept[src[e]] = False
        joins[e] = False
        touch(k, -1)
        touch(o, -1)
        return True

    # ---- opening: the stem of a T cut short into a cul-de-sac
    def leaving(e: int, k: int) -> np.ndarray:
        """Unit direction of edge e leaving node k (up to 10 m along it)."""
        line = g.geometry[e]
        t_ = min(10.0, line.length / 2)
        q = shapely.get_coordinates(line.interpolate(t_ if u[e] == k else line.length - t_))[0]
        d = q - nodes[k]
        return d / max(np.hypot(*d), 1e-12)

    # the blocks, to know what a cut merges: sets of faces, each block's area at its root
    faces, f_area, f_perimeter = planar_faces(lines)
    blocks = DisjointSet(range(len(faces)))
    block_area = f_area.copy()
    f_tree = shapely.STRtree(faces)

    def sides(line):
        """The faces left and right of a line's middle (-1: none)."""
        mid = line.interpolate(0.5, normalized=True)
        a_, b_ = shapely.get_coordinates(line.interpolate(
            np.clip(np.array([0.5 * line.length - 0.5, 0.5 * line.length + 0.5]), 0,
                    line.length)))
        d = (b_ - a_) / max(np.hypot(*(b_ - a_)), 1e-12)
        nrm = np.array([-d[1], d[0]])
        c = shapely.get_coordinates(mid)[0]
        out = []
        for q in (c + 0.5 * nrm, c - 0.5 * nrm):
            hit = f_tree.query(shapely.Point(q), predicate="within")
            out.append(int(hit[0]) if len(hit) else -1)
        return out, c, nrm

    def open_candidates():
        ts = np.flatnonzero(inside & (deg == 3))
        es = np.flatnonzero(new & whole & (shapely.length(g.geometry) >= 2 * min_dangle))
        ts = ts[rng.permutation(len(ts))]
        return [("stub", int(x), None) for x in es[rng.permutation(len(es))]] + \
            [("cut", int(x), max_block) for x in ts] + \
            [("cut", int(x), np.inf) for x in ts]

    def stub(e: int) -> bool:
        line = lines[src[e]]
        if line.length < 2 * min_dangle:
            return False
        (fl, fr), c, nrm = sides(line)
        cand = [(block_area[blocks[f]], f, s) for f, s in ((fl, 1.0), (fr, -1.0)) if f >= 0]
        if not cand:
            return False
        _, f, sgn = max(cand)
        width = 2 * f_area[f] / max(f_perimeter[f], 1e-9)
        others = current()
        for length in (max(width, min_dangle), max(width / 2, min_dangle)):
            street = shapely.LineString([c, c + sgn * length * nrm])
            end = shapely.get_point(street, -1)
            if not shapely.contains(faces[f], street.interpolate(length - 1e-3)):
                continue
            hit = others[shapely.intersects(others, street)]
            if len(hit) > 1 or shapely.dwithin(others, end, CORRIDOR_HALF_WIDTH).any():
                continue
            near = others[shapely.dwithin(others, street, CORRIDOR_HALF_WIDTH)]
            tail = substring(street, CORRIDOR_HALF_WIDTH, length)
            if doubles_a_street(np.array([tail]), corridor_around(None, near)).any():
                continue
            stubs.append(street)
            if counted(c)[0]:
                state["nodes"] += 1                      # the T
            if counted(shapely.get_coordinates(end))[0]:
                state["dead"] += 1
                state["nodes"] += 1
            return True
        return False

    def is_bridge(e: int) -> bool:
        keep = joins.copy()
        keep[e] = False
        k = len(nodes)
        adj = coo_matrix((np.ones(keep.sum()), (u[keep], v[keep])), shape=(k, k))
        _, label = connected_components(adj, directed=False)
        return label[u[e]] != label[v[e]]

    def open_(cand) -> bool:
        kind, x, limit = cand
        return cut(x, limit) if kind == "cut" else stub(x)

    def cut(t_, limit) -> bool:
        if deg[t_] != 3:
            return False
        es = np.unique(inc_edge[inc_node == t_])
        es = es[joins[es]]
        if len(es) != 3:
            return False
        dirs = np.array([leaving(int(e), t_) for e in es])
        # the through pair is the most opposite pair; the stem is the edge left out of it
        stem = int(es[int(np.argmin([dirs[1] @ dirs[2], dirs[0] @ dirs[2],
                                     dirs[0] @ dirs[1]]))])
        o = int(v[stem] if u[stem] == t_ else u[stem])
        if not new[stem] or not whole[stem] or o == t_ or deg[o] < 3:
            return False
        line = lines[src[stem]]
        length = line.length
        keep_len = max(min_dangle, length / 2)
        if length - keep_len < CORRIDOR_HALF_WIDTH:
            return False
        at_t = shapely.get_coordinates(shapely.get_point(line, 0))[0]
        from_t = np.hypot(*(at_t - nodes[t_])) <= np.hypot(*(
            shapely.get_coordinates(shapely.get_point(line, -1))[0] - nodes[t_]))
        rest = substring(line, length - keep_len, length) if from_t else \
            substring(line, 0, keep_len)
        end = shapely.get_point(rest, 0 if from_t else -1)
        others = current()
        others = others[np.arange(len(others)) != src[stem]]
        if shapely.dwithin(others, end, CORRIDOR_HALF_WIDTH).any() or is_bridge(stem):
            return False
        (fl, fr), _, _ = sides(g.geometry[stem])
        if fl < 0 or fr < 0:
            return False
        fl, fr = blocks[fl], blocks[fr]
        if fl != fr:
            merged_area = block_area[fl] + block_area[fr]
            if merged_area > limit:
                return False
            blocks.merge(fl, fr)
            block_area[blocks[fl]] = merged_area
        lines[src[stem]] = rest
        joins[stem] = False
        touch(t_, -1)
        if counted(shapely.get_coordinates(end))[0]:
            state["dead"] += 1
            state["nodes"] += 1
        return True

    # into the invariants' band with half of it as margin: the streets are the example's,
    # the steering a repair that changes as few as the rule allows
    n_closed, n_opened = steer_share(share_now, share, close, close_candidates, open_,
                                     open_candidates, tolerance=DEAD_END_TOLERANCE / 2)
    if not n_closed and not n_opened:
        return geometry, level, attrs, (0, 0)
    lines, level, attrs = lines[kept], level[kept], {k: a[kept] for k, a in attrs.items()}
    groups = [(np.asarray(a, dtype=object), (name, "", -1, len(a), -1))
              for a, name in ((links, "close"), (stubs, "cul-de-sac")) if a]
    if groups:
        return (*add_streets(lines, level, attrs, [a for a, _ in groups],
                              [b for _, b in groups], int(level.max()) + 1, 0.0),
                (n_closed, n_opened))
    merged, s = renode_attributed(lines, level, attrs, -1, 0.0)
    return merged, level[s], {k: a[s] for k, a in attrs.items()}, (n_closed, n_opened)
