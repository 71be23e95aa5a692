"""Joining the pieces of a street network into one: no floating pieces.

The fidelity issue asks every road synthesis for one network connected to the given roads.
A method that fills faces closed only by a target's outline (fragments), or grows in a part
of a target that no given road reaches (growroads), leaves pieces that touch nothing; each
gets the shortest straight street that joins it to the network that is anchored (reaches
the given roads) and crosses no other street. This module is the one home of that rule.

Nothing here imports QGIS.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Tuple

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from . import street_graph as _roads

__all__ = ["link_floating_pieces", "meets_only_at_ends"]

#: Nodes of a piece tried as a link's start, nearest to the anchored network first.
NODES_TRIED = 32


def meets_only_at_ends(link, lines) -> bool:
    """Whether ``link`` touches ``lines`` only at its two ends (within a micrometre): a new
    street that crosses or runs along none of them.

    >>> road = shapely.LineString([(0, 0), (10, 0)])
    >>> meets_only_at_ends(shapely.LineString([(5, 0), (5, 5)]), [road])
    True
    >>> meets_only_at_ends(shapely.LineString([(5, -5), (5, 5)]), [road])
    False
    """
    lines = np.asarray(lines, dtype=object)
    hit = lines[shapely.intersects(lines, link)]
    return bool(shapely.covers(shapely.buffer(shapely.boundary(link), 1e-6),
                               shapely.intersection(hit, link)).all())


def link_floating_pieces(lines, anchored, accept: Optional[Callable] = None,
                         drop_unlinked: bool = True, ends_on=None,
                         max_length: Optional[Callable[[float], float]] = None
                         ) -> Tuple[np.ndarray, np.ndarray]:
    """Links that join every piece of a noded network to its anchored pieces.

    Each piece (connected component) with no anchored line gets the shortest straight street
    from one of its nodes to the anchored network that touches no other street on its way;
    pieces are linked nearest first, so a linked piece anchors the next. Without any
    anchored line the longest piece anchors. A piece that no such street reaches cannot be
    joined: it is left out, or kept as it is with ``drop_unlinked`` False.

    Parameters
    ----------
    lines : array of LineString, noded (lines meet only at their ends), metric CRS
    anchored : bool array, one per line: lines of the network the others must reach
    accept : (LineString) -> bool, optional: a method's own rule for a road it may build
        (growroads: no steeper than its slope limit, through no obstacle)
    drop_unlinked : bool, leave out the lines of pieces that cannot be joined
    ends_on : bool array, optional, one per line: the anchored lines a link may end on
        (default all; a motorway is anchored but takes no new junction)
    max_length : (m of street in the piece) -> m, optional: the longest link a piece of that
        much street may take (StreetGAN: a larger piece is worth a longer street to it)

    Returns
    -------
    (links, keep): the link lines (they end on a node of their piece and on an anchored line,
    which is not split), and per line whether it is kept (False: its piece could not be
    joined).

    >>> a = shapely.LineString([(0, 0), (100, 0)]); b = shapely.LineString([(40, 30), (60, 30)])
    >>> links, keep = link_floating_pieces([a, b], [True, False])
    >>> [round(x.length, 6) for x in links], keep.tolist()
    ([30.0], [True, True])

    A motorway 30 m away takes no junction (``ends_on``): the link goes to the road 50 m away.

    >>> road = shapely.LineString([(0, 80), (100, 80)])
    >>> links, keep = link_floating_pieces([a, road, b], [True, True, False],
    ...                                    ends_on=[False, True, True])
    >>> [round(x.length, 6) for x in links], keep.tolist()
    ([50.0], [True, True, True])
    """
    geometry = np.asarray(lines, dtype=object)
    anchored_line = np.asarray(anchored, dtype=bool)
    n = len(geometry)
    keep = np.ones(n, bool)
    if n < 2:
        return np.empty(0, dtype=object), keep
    g = _roads.graph_from_lines(geometry, np.full(n, None, object), np.full(n, None, object),
                                np.zeros(n, int), np.arange(n), snap_tolerance=0.0)
    m = len(g.nodes)
    adj = coo_matrix((np.ones(g.n_edges), (g.u, g.v)), shape=(m, m))
    n_comp, label = connected_components(adj, directed=False)
    if n_comp == 1:
        return np.empty(0, dtype=object), keep
    edge_comp = label[g.u]
    src = np.asarray(g.source)
    anchored = np.zeros(n_comp, bool)
    anchored[edge_comp[anchored_line[src]]] = True
    # metres of street per piece: the longest anchors when nothing is anchored
    piece_m = np.bincount(edge_comp, weights=shapely.length(g.geometry), minlength=n_comp)
    if not anchored.any():
        anchored[np.argmax(piece_m)] = True
    links = []
    edges = np.asarray(g.geometry, dtype=object)
    edge_tree = shapely.STRtree(edges)

    def clear(link) -> bool:  # the streets near it from a tree, not all of them per link
        near = edges[edge_tree.query(link, predicate="intersects")]
        return meets_only_at_ends(link, np.concatenate([near, np.asarray(links, dtype=object)]))

    takes_link = np.ones(len(edges), bool) if ends_on is None else \
        np.asarray(ends_on, dtype=bool)[src]
    while not anchored.all():
        # the anchored network as a tree of its edges (its union, rebuilt per link, cost
        # seconds on a 36 km² StreetGAN network): the nearest edge is the nearest point
        target = edges[anchored[edge_comp] & takes_link]
        if not len(target):
            break
        tree = shapely.STRtree(target)
        best = None
        for comp in np.flatnonzero(~anchored):
            nodes = np.unique(np.r_[g.u[edge_comp == comp], g.v[edge_comp == comp]])
            pts = shapely.points(g.nodes[nodes])
            (_, near), d = tree.query_nearest(pts, return_distance=True, all_matches=False)
            longest = math.inf if max_length is None else max_length(float(piece_m[comp]))
            for k in np.argsort(d, kind="stable")[:NODES_TRIED]:
                if (best is not None and d[k] >= best[0]) or d[k] > longest:
                    break
                link = shapely.shortest_line(pts[k], target[near[k]])
                if link.length <= 1e-6:
                    continue
                # it may touch only the piece at its start and the anchored line at its end
                if clear(link) and (accept is None or accept(link)):
                    best = (float(d[k]), comp, link)
                    break
        if best is None:
            break  # no piece can be linked without crossing a street
        _, comp, link = best
        links.append(link)
        anchored[comp] = True
    if drop_unlinked:
        keep[src[~anchored[edge_comp]]] = False
    return np.asarray(links, dtype=object), keep
