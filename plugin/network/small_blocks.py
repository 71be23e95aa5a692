"""Blocks smaller than the example's: merged by removing a synthesised street between two of
them, so that the block sizes follow the example's.

A generator that draws its streets as a texture (StreetGAN) makes cells of its own size,
not the example's blocks: on the fidelity benchmark's towns its median block is a quarter
of the real one. :func:`merge_small_blocks` removes, smallest block first, the synthesised
street between a block under ``min_area`` (the example's 10th-percentile block area) and
its smallest neighbouring block, until no more than ``share`` of the blocks (the example's
10 %) are under it (counting the blocks a synthesised street bounds: a strip between the
given roads alone is not the method's to merge); run with the example's median block area
and half the blocks, it holds the median too. A small block with no removable street to
another block (a cell at the network's edge) is opened onto the land around it: its
shortest removable street with no block behind it goes. Only a street whose two ends stay
junctions (degree >= 3 before) is removed, so no dead end is made, and a street on a
block's outline is never a bridge, so the network stays in one piece. Given streets are
never removed. Not in the papers: a rule of ours that holds a method to the example's
block-size distribution.

Nothing here imports QGIS.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import shapely

from scipy.cluster.hierarchy import DisjointSet

from .street_graph import collapse_short_pieces, node_lines, snap_ends_onto_lines

__all__ = ["merge_small_blocks", "fewer_crossings"]

#: Line ends closer than this (m) are one node.
_NODE_GRID = 1e-3


def merge_small_blocks(lines: Sequence, is_new: Sequence, min_area: float, area=None,
                       share: float = 0.1, per_round: Optional[int] = None
                       ) -> Tuple[np.ndarray, np.ndarray, int]:
    """Remove synthesised streets between small blocks (see the module doc).

    Parameters
    ----------
    lines : LineStrings of the network (given and synthesised)
    is_new : bool per line, the synthesised ones (only these may be removed)
    min_area : m², the example's 10th-percentile block area (<= 0 or NaN: nothing done)
    area : polygon, optional: only blocks inside it count
    share : the share of blocks that may stay under ``min_area`` (of the blocks with a
        synthesised street on their outline)
    per_round : streets removed between two polygonisations of the network (default: half
        the small blocks over the share, no two at one block; 1: one street at a time,
        the rule before, whose cost grew with the square of the target)

    Returns
    -------
    (lines noded, is_new per noded line, number of streets removed)
    """
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    if not len(lines) or not np.isfinite(min_area) or min_area <= 0:
        return lines, is_new, 0
    net = _Network(lines, is_new, area)

    def plan(faces, fa, on_p, on_f, chain, removable):
        # the blocks a synthesised street bounds: those of the given roads alone (a dual
        # carriageway's strip) are not the method's to merge
        made = np.zeros(len(faces), dtype=bool)
        made[on_f[net.new[on_p]]] = True
        small = np.flatnonzero((fa < min_area) & made)
        if len(small) <= share * made.sum():
            return None
        chain_length = np.bincount(chain, weights=shapely.length(net.pieces) * net.alive,
                                   minlength=len(net.pieces))

        def candidates():
            # smallest block first, with the street to its smallest neighbour; a block with
            # no removable street to another block opens onto the land around it through
            # its shortest removable street with no block behind it
            for f in small[np.argsort(fa[small], kind="stable")]:
                best = outer = None
                for p in on_p[(on_f == f) & removable[chain[on_p]]]:
                    other = on_f[(on_p == p) & (on_f != f)]
                    if len(other):
                        if best is None or fa[other].min() < best[0]:
                            best = (float(fa[other].min()), int(chain[p]),
                                    int(other[np.argmin(fa[other])]))
                    elif outer is None or chain_length[chain[p]] < outer[0]:
                        outer = (float(chain_length[chain[p]]), int(chain[p]))
                if best is not None:
                    yield best[1], {int(f), best[2]}
                elif outer is not None:
                    yield outer[1], {int(f)}

        return per_round or max(1, int(len(small) - share * made.sum()) // 2), candidates()

    removed = _remove_in_rounds(net, plan, lambda ends: True)
    return (*net.lines(), removed)


def fewer_crossings(lines: Sequence, is_new: Sequence, share: float, area,
                    share_of, per_round: Optional[int] = None
                    ) -> Tuple[np.ndarray, np.ndarray, int]:
    """While the share of 4-way junctions is above ``share``, remove the synthesised street
    at a 4-way junction whose two blocks together are the smallest: the crossing becomes a
    T and the two blocks one (a street whose ends both stay junctions, between two faces:
    no dead end, no floating piece). Where no such street is left and the share is still
    above, the shortest synthesised dead-end street at a crossing goes
    (:func:`_stubs_at_crossings`).

    The streets go in rounds: each takes, smallest merged blocks first, up to half the
    crossings still to remove (counted on the network's own nodes; ``per_round`` fixes the
    number), no two of them at the same block, each checked against the degrees the earlier
    ones left; the share is measured after each round. One street per round (``per_round``
    1, the rule before) measures the whole network once per street
    (``tests/benchmarks/bench_crossings.py``).

    ``share_of(lines) -> float``: the share as it will be measured
    (:func:`invariants.crossing_share` in the target). Returns (lines noded, is_new,
    streets removed).
    """
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    if not len(lines) or not np.isfinite(share):
        return lines, is_new, 0
    net = _Network(lines, is_new, area)
    inside = np.ones(len(net.node_xy), dtype=bool) if area is None else \
        shapely.contains_xy(area, *net.node_xy.T)

    measured = [np.inf]   # the share as last measured (the fallback below starts from it)

    def plan(faces, fa, on_p, on_f, chain, removable):
        measured[0] = share_of(net.pieces[net.alive])
        if measured[0] <= share:
            return None
        counted = inside & (net.degree > 0) & (net.degree != 2)
        n4 = int((counted & (net.degree >= 4)).sum())
        # per chain the least area its pieces would merge; ties: the lower piece
        merged = np.bincount(on_p, weights=fa[on_f], minlength=len(net.pieces))
        by_chain = {}
        for p in np.unique(on_p[removable[chain[on_p]]]):
            root = int(chain[p])
            if root not in by_chain or merged[p] < by_chain[root][0]:
                by_chain[root] = (float(merged[p]), int(p))

        def candidates():
            for _, _, root in sorted((v[0], v[1], r) for r, v in by_chain.items()):
                yield root, set(on_f[np.isin(on_p, np.flatnonzero(net.alive & (chain == root)))])

        return per_round or max(1, int(n4 - share * counted.sum()) // 2), candidates()

    # one end a crossing, under the degrees left so far
    removed = _remove_in_rounds(net, plan,
                                lambda ends: (inside[ends] & (net.degree[ends] >= 4)).any())
    if not np.isfinite(measured[0]):   # no face at all: the rounds measured nothing
        measured[0] = share_of(net.pieces[net.alive])
    if measured[0] > share:
        removed += _stubs_at_crossings(net, inside, share, share_of, measured[0])
    return (*net.lines(), removed)


def _stubs_at_crossings(net, inside, share: float, share_of, now: float) -> int:
    """Where no street between two junctions is left to go at a crossing and the share is
    still above ``share``: the shortest synthesised dead-end street that ends at a counted
    crossing goes, one at a time (the crossing becomes a T, a dead end less, nothing is cut
    off). On a small target a crossing is a large part of the share (Ruggell, 1.5 km²:
    a fifth of the ±30 % band), and a generator's star of stubs can hold it there. ``now``:
    the share as measured last."""
    removed = 0
    while now > share:
        chain, _ = _chains(net.node, net.degree, net.alive, net.new)
        length = np.bincount(chain, weights=shapely.length(net.pieces) * net.alive,
                             minlength=len(net.pieces))
        best = None
        for root, ends in net.chain_ends_all(chain).items():
            if not net.new[root] or len(ends) != 2:
                continue
            deg = net.degree[ends]
            stub = deg.min() == 1 and deg.max() >= 4 and inside[ends[np.argmax(deg)]]
            if stub and (best is None or length[root] < length[best]):
                best = root
        if best is None:
            break
        net.remove(chain, best)
        removed += 1
        now = share_of(net.pieces[net.alive])
    return removed


def _remove_in_rounds(net, plan, end_rule) -> int:
    """Streets removed in rounds, one polygonisation per round (the one home of both rules'
    loop). ``plan(faces, face_area, *net.sides(faces))`` gives None to stop, else
    (how many streets this round at most, candidates in order as (chain root, the blocks it
    touches)); a candidate is taken when none of its blocks was touched this round and both
    its ends are still junctions under the degrees the streets taken before it left, and
    ``end_rule(ends)`` holds. Returns the number of streets removed."""
    removed = 0
    while True:
        faces, fa = net.faces()
        if not len(faces):
            break
        on_p, on_f, chain, removable = net.sides(faces)
        todo = plan(faces, fa, on_p, on_f, chain, removable)
        if todo is None:
            break
        batch, candidates = todo
        ends = net.chain_ends_all(chain)
        touched, taken = set(), 0
        for root, blocks in candidates:
            if taken >= batch:
                break
            if blocks & touched:
                continue
            e = ends.get(root, ())
            if not _between_junctions(e, net.degree) or not end_rule(e):
                continue
            touched |= blocks
            net.remove(chain, root)
            taken += 1
        if not taken:
            break
        removed += taken
    return removed


class _Network:
    """A network noded into pieces, with node ids, degrees and which pieces are synthesised
    (a piece is given where it lies on a given line); streets are removed piece by piece
    and the rest joined again into lines between junctions."""

    def __init__(self, lines, is_new, area):
        # an end on another line only up to round-off is made its vertex first: noding alone
        # left such a T unsplit, and the street it held on to looked removable (a floating
        # piece on Vaduz)
        pieces = node_lines(snap_ends_onto_lines(lines))
        # round-off between two ends that noding set apart (5e-11 m on a given road) is
        # no street: a loop there would count twice in its node's degree
        self.pieces = collapse_short_pieces(pieces, _NODE_GRID)[0]
        self.mids = shapely.line_interpolate_point(self.pieces, 0.5, normalized=True)
        given = lines[~is_new]
        self.new = np.ones(len(self.pieces), dtype=bool)
        if len(given):
            hit = shapely.STRtree(given).query(self.mids, predicate="dwithin",
                                               distance=_NODE_GRID)[0]
            self.new[hit] = False
        ends = np.stack([shapely.get_coordinates(shapely.get_point(self.pieces, 0)),
                         shapely.get_coordinates(shapely.get_point(self.pieces, -1))], axis=1)
        keys = np.round(ends.reshape(-1, 2) / _NODE_GRID).astype(np.int64)
        _, first, node = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        self.node = node.reshape(-1, 2)
        self.node_xy = ends.reshape(-1, 2)[first]
        self.degree = np.bincount(self.node.ravel(), minlength=int(self.node.max()) + 1)
        self.alive = np.ones(len(self.pieces), dtype=bool)
        self.area = area
        if area is not None:
            shapely.prepare(area)

    def faces(self):
        faces = shapely.get_parts(shapely.polygonize(self.pieces[self.alive]))
        if self.area is not None and len(faces):
            faces = faces[shapely.within(shapely.point_on_surface(faces), self.area)]
        return faces, shapely.area(faces)

    def sides(self, faces):
        """(piece, face) pairs of live pieces on the faces' outlines, each piece's chain and
        which chains may be removed."""
        chain, removable = _chains(self.node, self.degree, self.alive, self.new)
        on_p, on_f = shapely.STRtree(shapely.get_exterior_ring(faces)).query(
            self.mids, predicate="dwithin", distance=_NODE_GRID)
        keep = self.alive[on_p]
        return on_p[keep], on_f[keep], chain, removable

    def chain_ends_all(self, chain) -> dict:
        """Chain root -> the array of its end nodes (degree != 2), for the live pieces."""
        live = np.flatnonzero(self.alive)
        roots = np.repeat(chain[live], 2)
        v = self.node[live].ravel()
        end = self.degree[v] != 2
        out: dict = {}
        for r, x in zip(roots[end].tolist(), v[end].tolist()):
            out.setdefault(r, []).append(x)
        return {r: np.asarray(x, dtype=np.int64) for r, x in out.items()}

    def remove(self, chain, root):
        gone = self.alive & (chain == root)
        self.alive[gone] = False
        np.subtract.at(self.degree, self.node[gone].ravel(), 1)   # its inner nodes drop to 0

    def lines(self):
        """The live pieces of a street between two junctions joined into one line again."""
        chain, _ = _chains(self.node, self.degree, self.alive, self.new)
        out, out_new = [], []
        for root, members in _members(chain[self.alive], np.flatnonzero(self.alive)).items():
            merged = shapely.line_merge(shapely.union_all(self.pieces[members])) \
                if len(members) > 1 else self.pieces[members[0]]
            parts = shapely.get_parts(merged)
            out += list(parts)
            out_new += [bool(self.new[members[0]])] * len(parts)
        return np.asarray(out, dtype=object), np.asarray(out_new, dtype=bool)


def _chains(node: np.ndarray, degree: np.ndarray, alive: np.ndarray, new: np.ndarray):
    """Streets as the analyst sees them: live synthesised pieces joined through nodes of
    degree 2 into chains between junctions. Returns the chain of every piece (its root)
    and, per root, whether the chain may be removed (synthesised, two distinct ends that
    are junctions of degree >= 3)."""
    n = len(node)
    groups = DisjointSet(range(n))
    live_new = np.flatnonzero(alive & new)
    at = {}
    for p in live_new:
        for v in node[p]:
            if degree[v] == 2:
                if v in at:
                    groups.merge(at[v], int(p))
                else:
                    at[v] = int(p)
    chain = np.array([groups[i] for i in range(n)], dtype=np.int64)
    removable = np.zeros(n, dtype=bool)
    for root, members in _members(chain[live_new], live_new).items():
        removable[root] = _between_junctions(
            [v for p in members for v in node[p] if degree[v] != 2], degree)
    return chain, removable


def _between_junctions(ends, degree: np.ndarray) -> bool:
    """Whether a street with these end nodes (degree != 2) runs between two distinct
    junctions (degree >= 3): removed, it leaves no dead end."""
    return len(ends) == 2 and ends[0] != ends[1] and \
        min(degree[ends[0]], degree[ends[1]]) >= 3


def _members(roots: np.ndarray, pieces: np.ndarray) -> dict:
    out: dict = {}
    for r, p in zip(roots.tolist(), pieces.tolist()):
        out.setdefault(r, []).append(p)
    return out
