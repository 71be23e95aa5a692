"""Blocks smaller than the example's: merged by removing a synthesised street between two of
them, so that the block sizes follow the example's.

A generator that draws its streets as a texture (StreetGAN) makes cells of its own size,
not the example's blocks: on the fidelity benchmark's towns its median block is a quarter
of the real one. :func:`merge_small_blocks` removes, smallest block first, the synthesised
street between a block under ``min_area`` (the example's 10th-percentile block area) and
its smallest neighbouring block, until no more than ``share`` of the blocks (the example's
10 %) are under it. Only a street whose two ends stay junctions (degree >= 3 before) is
removed, so no dead end is made, and a street between two faces is never a bridge, so the
network stays in one piece. Given streets are never removed. Not in the papers: a rule of
ours that holds a method to the example's block-size distribution.

Nothing here imports QGIS.
"""
from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np
import shapely

from scipy.cluster.hierarchy import DisjointSet

from .street_graph import node_lines

__all__ = ["merge_small_blocks"]

#: Line ends closer than this (m) are one node.
_NODE_GRID = 1e-3


def merge_small_blocks(lines: Sequence, is_new: Sequence, min_area: float, area=None,
                       share: float = 0.1) -> Tuple[np.ndarray, np.ndarray, int]:
    """Remove synthesised streets between small blocks (see the module doc).

    Parameters
    ----------
    lines : LineStrings of the network (given and synthesised)
    is_new : bool per line, the synthesised ones (only these may be removed)
    min_area : m², the example's 10th-percentile block area (<= 0 or NaN: nothing done)
    area : polygon, optional: only blocks inside it count
    share : the share of blocks that may stay under ``min_area``

    Returns
    -------
    (lines noded, is_new per noded line, number of streets removed)
    """
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    if not len(lines) or not np.isfinite(min_area) or min_area <= 0:
        return lines, is_new, 0
    pieces = node_lines(lines)
    pieces = pieces[shapely.length(pieces) > 0]
    mids = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    # a piece is given where it lies on a given line
    given = lines[~is_new]
    new = np.ones(len(pieces), dtype=bool)
    if len(given):
        hit = shapely.STRtree(given).query(mids, predicate="dwithin", distance=_NODE_GRID)[0]
        new[hit] = False
    ends = np.stack([shapely.get_coordinates(shapely.get_point(pieces, 0)),
                     shapely.get_coordinates(shapely.get_point(pieces, -1))], axis=1)
    keys = np.round(ends.reshape(-1, 2) / _NODE_GRID).astype(np.int64)
    _, node = np.unique(keys, axis=0, return_inverse=True)
    node = node.reshape(-1, 2)
    degree = np.bincount(node.ravel(), minlength=int(node.max()) + 1)
    alive = np.ones(len(pieces), dtype=bool)
    if area is not None:
        shapely.prepare(area)
    removed = 0
    while True:
        faces = shapely.get_parts(shapely.polygonize(pieces[alive]))
        if area is not None and len(faces):
            faces = faces[shapely.within(shapely.point_on_surface(faces), area)]
        if not len(faces):
            break
        fa = shapely.area(faces)
        small = np.flatnonzero(fa < min_area)
        if len(small) <= share * len(faces):
            break
        chain, removable = _chains(node, degree, alive, new)
        on_p, on_f = shapely.STRtree(shapely.get_exterior_ring(faces)).query(
            mids, predicate="dwithin", distance=_NODE_GRID)
        keep = alive[on_p]
        on_p, on_f = on_p[keep], on_f[keep]
        best = None
        for f in small[np.argsort(fa[small], kind="stable")]:
            for p in on_p[(on_f == f) & removable[chain[on_p]]]:
                other = on_f[(on_p == p) & (on_f != f)]
                if len(other) and (best is None or fa[other].min() < best[0]):
                    best = (float(fa[other].min()), int(chain[p]))
            if best is not None:
                break
        if best is None:
            break
        gone = alive & (chain == best[1])
        alive[gone] = False
        np.subtract.at(degree, node[gone].ravel(), 1)   # its inner nodes drop to 0
        removed += 1
    # the pieces of a street left between two junctions are one line again
    chain, _ = _chains(node, degree, alive, new)
    out, out_new = [], []
    for root, members in _members(chain[alive], np.flatnonzero(alive)).items():
        merged = shapely.line_merge(shapely.union_all(pieces[members])) \
            if len(members) > 1 else pieces[members[0]]
        parts = shapely.get_parts(merged)
        out += list(parts)
        out_new += [bool(new[members[0]])] * len(parts)
    return np.asarray(out, dtype=object), np.asarray(out_new, dtype=bool), removed


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
        ends = [v for p in members for v in node[p] if degree[v] != 2]
        removable[root] = len(ends) == 2 and ends[0] != ends[1] and \
            min(degree[ends[0]], degree[ends[1]]) >= 3
    return chain, removable


def _members(roots: np.ndarray, pieces: np.ndarray) -> dict:
    out: dict = {}
    for r, p in zip(roots.tolist(), pieces.tolist()):
        out.setdefault(r, []).append(p)
    return out
