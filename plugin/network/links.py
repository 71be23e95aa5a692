"""Joining the pieces of a street network into one: no floating pieces.

The fidelity issue asks every road synthesis for one network connected to the given roads.
A method that fills faces closed only by a target's outline (fragments), or grows in a part
of a target that no given road reaches (growroads), leaves pieces that touch nothing; each
gets the shortest straight street that joins it to the network that is anchored (reaches
the given roads) and crosses no other street; where a target's outline is given and no
straight street inside it is left, a method may ask for a street bent along the target's
arm (:class:`PathsInside`, growroads). This module is the one home of that rule.

Nothing here imports QGIS.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable, Optional, Tuple

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from shapely.geometry.polygon import orient
from shapely.ops import substring

from . import street_graph as _roads
from .invariants import CORRIDOR_HALF_WIDTH, EDGE_DISTANCE, connected_pieces

__all__ = ["link_floating_pieces", "join_pieces", "meets_only_at_ends", "allowed_area",
           "path_inside", "PathsInside"]

#: Nodes of a piece tried as a link's start, nearest to the anchored network first.
NODES_TRIED = 32

#: m: how far a new street may leave the target (one along its outline): the invariants'
#: own tolerance for a street leaving it (``check_network(target=...)``).
OUTSIDE_TOLERANCE = EDGE_DISTANCE
#: m: a bent link (:func:`path_inside`) turns this far inside the target's outline.
PATH_MARGIN = 5.0
#: Most corners a bent link's visibility graph holds (their legs are checked pairwise).
MAX_PATH_CORNERS = 800


def allowed_area(target):
    """Where a new street may run: the target grown by :data:`OUTSIDE_TOLERANCE`, prepared
    (the one construction of that rule for the links, the walk's joins and its bends).

    >>> area = allowed_area(shapely.box(0, 0, 10, 10))
    >>> shapely.covers(area, shapely.LineString([(0, -0.5), (10, -0.5)]))
    True
    """
    area = shapely.buffer(target, OUTSIDE_TOLERANCE)
    shapely.prepare(area)
    return area


def path_inside(area, starts: np.ndarray, ends: np.ndarray, within=None):
    """The shortest polyline inside ``area`` from one of the points ``starts`` (k, 2) to one
    of ``ends`` (m, 2) (:class:`PathsInside`); None when no path exists (the two lie in
    parts of the area apart).

    Around the inner corner of an L:

    >>> ell = shapely.Polygon([(0, 0), (100, 0), (100, 100), (80, 100), (80, 20), (0, 20)])
    >>> path = path_inside(ell, np.array([[5.0, 10.0]]), np.array([[90.0, 95.0]]))
    >>> len(path.coords), round(path.length), shapely.covers(allowed_area(ell), path)
    (3, 156, True)
    """
    return PathsInside(area, within).shortest(starts, ends)


class PathsInside:
    """Shortest paths inside a polygon(s): a visibility graph over the reflex corners of the
    area shrunk by :data:`PATH_MARGIN` (simplified by a tenth of it, or more where it keeps
    over :data:`MAX_PATH_CORNERS`; a shortest path bends only at reflex corners), searched
    with Dijkstra. The legs between corners are found once; each query adds only its own
    points' legs. ``within``: where a leg may run (default :func:`allowed_area`). No
    library does this for a polygon (shapely has no shortest path inside one), hence by
    hand."""

    def __init__(self, area, within=None):
        self.within = allowed_area(area) if within is None else within
        shapely.prepare(self.within)
        self._outline = shapely.boundary(self.within)
        shapely.prepare(self._outline)
        shrunk = shapely.buffer(area, -PATH_MARGIN)
        tolerance = PATH_MARGIN / 10
        # a finely digitised boundary is simplified further, so that the legs between its
        # corners stay countable (a leg is checked inside, so no path can leave the area)
        while len(corners := _reflex_corners(shapely.simplify(shrunk, tolerance))) > \
                MAX_PATH_CORNERS:
            tolerance *= 2
        self.corners = corners
        i, j = np.triu_indices(len(self.corners), 1)
        ok = self._visible(self.corners[i], self.corners[j])
        self._legs = (i[ok], j[ok])

    def _visible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether each leg a -> b lies inside: it starts inside and crosses no outline (the
        same as ``covers``, for a leg not ending exactly on the outline, and eight times
        faster on a town's envelope: Triesenberg's 168,000 legs between corners 0.36 s
        against 2.8 s)."""
        if not len(a):
            return np.zeros(0, bool)
        legs = shapely.linestrings(np.stack([a, b], axis=1))
        return shapely.contains_xy(self.within, a[:, 0], a[:, 1]) & \
            ~shapely.intersects(self._outline, legs)

    def shortest(self, starts: np.ndarray, ends: np.ndarray):
        """The shortest path from one of ``starts`` to one of ``ends``, or None."""
        starts, ends = np.atleast_2d(starts), np.atleast_2d(ends)
        k, m, c = len(starts), len(ends), len(self.corners)
        pts = np.concatenate([starts, ends, self.corners])
        # legs: corner to corner (found once), and from each query point to everything
        q_i, q_j = np.meshgrid(np.arange(k + m), np.arange(k + m + c), indexing="ij")
        keep = q_j > q_i
        q_i, q_j = q_i[keep], q_j[keep]
        ok = self._visible(pts[q_i], pts[q_j])
        i = np.r_[q_i[ok], self._legs[0] + k + m]
        j = np.r_[q_j[ok], self._legs[1] + k + m]
        w = np.hypot(*(pts[i] - pts[j]).T) + 1e-9
        n = k + m + c
        graph = coo_matrix((np.r_[w, w], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
        dist, pred, source = dijkstra(graph, indices=np.arange(k), min_only=True,
                                      return_predecessors=True)
        end_ids = np.arange(k, k + m)
        best = int(end_ids[np.argmin(dist[end_ids])])
        if not np.isfinite(dist[best]):
            return None
        chain = [best]
        while chain[-1] != source[best]:
            chain.append(int(pred[chain[-1]]))
        return shapely.LineString(pts[chain[::-1]])


def _reflex_corners(area) -> np.ndarray:
    """The corners of a polygon(s) where its inside turns more than half round (a shortest
    path inside bends only there): (k, 2)."""
    out = [np.empty((0, 2))]
    for part in shapely.get_parts(area):
        # exterior counter-clockwise, holes clockwise: the inside lies left of every ring
        part = orient(part, 1.0)
        for ring in [part.exterior, *part.interiors]:
            c = shapely.get_coordinates(ring)[:-1]
            if len(c) < 3:
                continue
            a, b = c - np.roll(c, 1, axis=0), np.roll(c, -1, axis=0) - c
            out.append(c[a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] < 0])   # a right turn
    return np.concatenate(out)


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
                         max_length: Optional[Callable[[float], float]] = None,
                         pieces=None, both_ways: bool = False, inside=None,
                         bent: bool = False) -> Tuple[np.ndarray, np.ndarray]:
    """Links that join every piece of a noded network to its anchored pieces.

    Each piece (connected component) with no anchored line gets the shortest straight street
    from one of its nodes to the anchored network that touches no other street on its way;
    pieces are linked nearest first, so a linked piece anchors the next. Without any
    anchored line the longest piece anchors; with ``inside`` in parts apart and
    ``drop_unlinked``, so does the longest piece of each part that holds no anchored line
    (no link reaches a part apart: its streets were all left out). A piece that no such
    street reaches cannot be joined: it is left out, or kept as it is with ``drop_unlinked``
    False.

    Parameters
    ----------
    lines : array of LineString, noded (lines meet only at their ends), metric CRS
    anchored : bool array, one per line: lines of the network the others must reach
    accept : (LineString) -> bool, optional: a method's own rule for a road it may build
        (growroads: no steeper than its slope limit, through no obstacle)
    drop_unlinked : bool, leave out the lines of pieces that cannot be joined
    ends_on : bool array, optional, one per line: the lines a link may end on (default all;
        a motorway is anchored but takes no new junction)
    max_length : (m of street in the piece) -> m, optional: the longest link a piece of that
        much street may take (StreetGAN: a larger piece is worth a longer street to it)
    pieces : int array, optional, one per line: the piece of each line (default: lines meet
        at their end points)
    both_ways : bool, a link may also start on the anchored network and end on the piece
        (a lane apart is joined by the street whose end is nearest to it)
    inside : Polygon(s), optional, the target: a link stays in it (within
        :data:`OUTSIDE_TOLERANCE`; between two arms of a concave target a straight link
        would cross land outside it)
    bent : bool, with ``inside``: where no straight link is left, a piece in an arm of the
        target is joined by the shortest polyline inside it (:func:`path_inside`, from the
        piece's nodes nearest to the anchored network to that network's nodes nearest to
        the piece), clear of the other streets as a straight link is

    Returns
    -------
    (links, keep): the link lines (they end on a node of their piece and on an anchored line,
    or with ``both_ways`` on a node of the anchored network and a line of the piece; the line
    is not split), and per line whether it is kept (False: its piece could not be joined).

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

    Two parts of a target apart, nothing anchored: each keeps its own network.

    >>> far = shapely.LineString([(500, 0), (560, 0)]); near = shapely.LineString([(500, 30), (560, 30)])
    >>> parts = shapely.union_all([shapely.box(-5, -5, 105, 40), shapely.box(495, -5, 565, 40)])
    >>> links, keep = link_floating_pieces([a, b, far, near], [False] * 4, inside=parts)
    >>> [round(x.length, 6) for x in links], keep.tolist()
    ([30.0, 30.0], [True, True, True, True])
    """
    geometry = np.asarray(lines, dtype=object)
    anchored_line = np.asarray(anchored, dtype=bool)
    n = len(geometry)
    keep = np.ones(n, bool)
    if n < 2:
        return np.empty(0, dtype=object), keep
    g = _roads.graph_from_lines(geometry, np.full(n, None, object), np.full(n, None, object),
                                np.zeros(n, int), np.arange(n), snap_tolerance=0.0)
    src = np.asarray(g.source)
    if pieces is None:
        m = len(g.nodes)
        adj = coo_matrix((np.ones(g.n_edges), (g.u, g.v)), shape=(m, m))
        n_comp, label = connected_components(adj, directed=False)
        edge_comp = label[g.u]
    else:
        _, label = np.unique(np.asarray(pieces)[src], return_inverse=True)
        n_comp, edge_comp = int(label.max()) + 1 if len(label) else 0, label.ravel()
    if n_comp <= 1:
        return np.empty(0, dtype=object), keep
    # links start at the junctions as the lines have them (the nodes are rounded)
    g = replace(g, nodes=_roads.junction_points(g.nodes, g.geometry))
    anchored = np.zeros(n_comp, bool)
    anchored[edge_comp[anchored_line[src]]] = True
    # metres of street per piece: the longest anchors when nothing is anchored
    piece_m = np.bincount(edge_comp, weights=shapely.length(g.geometry), minlength=n_comp)
    edges = np.asarray(g.geometry, dtype=object)
    within = None
    if inside is not None:
        within = allowed_area(inside)
    if drop_unlinked and within is not None:
        # a part of the target apart that holds no anchored line anchors its own longest
        # piece: no link reaches it, and its streets were all dropped (one network per part)
        parts = shapely.get_parts(within)
        if len(parts) > 1:
            part_tree = shapely.STRtree(parts)
            on_edge, on_part = part_tree.query(edges, predicate="intersects")
            for k in range(len(parts)):
                own = np.unique(edge_comp[on_edge[on_part == k]])
                if len(own) and not anchored[own].any():
                    anchored[own[np.argmax(piece_m[own])]] = True
    if not anchored.any():
        anchored[np.argmax(piece_m)] = True
    links = []
    edge_tree = shapely.STRtree(edges)

    def clear(link) -> bool:  # the streets near it from a tree, not all of them per link
        near = edges[edge_tree.query(link, predicate="intersects")]
        return meets_only_at_ends(link, np.concatenate([near, np.asarray(links, dtype=object)]))

    takes_link = np.ones(len(edges), bool) if ends_on is None else \
        np.asarray(ends_on, dtype=bool)[src]

    def nearest_clear(starts, ends, ends_tree, longest, bound):
        """The shortest clear link from one of the points ``starts`` to the lines ``ends``
        (in ``ends_tree``), shorter than ``bound`` and ``longest``: (length, link) or None."""
        (_, near), d = ends_tree.query_nearest(starts, return_distance=True, all_matches=False)
        for k in np.argsort(d, kind="stable")[:NODES_TRIED]:
            if d[k] >= bound or d[k] > longest:
                break
            link = shapely.shortest_line(starts[k], ends[near[k]])
            if link.length <= 1e-6:
                continue
            # it may touch only the piece at its start and the line it ends on
            if clear(link) and (within is None or shapely.covers(within, link)) and \
                    (accept is None or accept(link)):
                return float(d[k]), link
        return None

    paths = None   # the target's visibility graph, built at the first bent link
    while not anchored.all():
        # the anchored network as its edges (its union, rebuilt per link, cost seconds on a
        # 36 km² StreetGAN network): the nearest edge is the nearest point
        target = edges[anchored[edge_comp] & takes_link]
        if not len(target):
            break
        target_tree = shapely.STRtree(target)
        if both_ways:
            at = anchored[edge_comp] & takes_link
            anchor_points = shapely.points(g.nodes[np.unique(np.r_[g.u[at], g.v[at]])])
        best = None
        for comp in np.flatnonzero(~anchored):
            # a link starts or ends only on lines that take one (not on a motorway)
            own = (edge_comp == comp) & takes_link
            if not own.any():
                continue
            pts = shapely.points(g.nodes[np.unique(np.r_[g.u[own], g.v[own]])])
            longest = math.inf if max_length is None else max_length(float(piece_m[comp]))
            tries = [(pts, target, target_tree)]
            if both_ways:
                tries.append((anchor_points, edges[own], shapely.STRtree(edges[own])))
            for starts, ends, ends_tree in tries:
                found = nearest_clear(starts, ends, ends_tree, longest,
                                      math.inf if best is None else best[0])
                if found is not None:
                    best = (found[0], comp, found[1])
        if best is None and bent and inside is not None:
            paths = paths or PathsInside(inside, within)
            best = _nearest_bent(paths, g, edge_comp, anchored, takes_link, clear, accept)
        if best is None:
            break  # no piece can be linked without crossing a street
        _, comp, link = best
        links.append(link)
        anchored[comp] = True
    if drop_unlinked:
        keep[src[~anchored[edge_comp]]] = False
    return np.asarray(links, dtype=object), keep


def _nearest_bent(paths, g, edge_comp, anchored, takes_link, clear, accept):
    """The shortest clear bent link (:func:`path_inside`) from a piece not anchored to the
    anchored network, between the :data:`NODES_TRIED` nodes of each nearest to the other:
    (length, piece, link) or None."""
    at = anchored[edge_comp] & takes_link
    anchor_xy = g.nodes[np.unique(np.r_[g.u[at], g.v[at]])]
    if not len(anchor_xy):
        return None
    anchor_tree = shapely.STRtree(shapely.points(anchor_xy))
    best = None
    for comp in np.flatnonzero(~anchored):
        own = (edge_comp == comp) & takes_link
        if not own.any():
            continue
        xy = g.nodes[np.unique(np.r_[g.u[own], g.v[own]])]
        _, d = anchor_tree.query_nearest(shapely.points(xy), return_distance=True,
                                         all_matches=False)
        starts = xy[np.argsort(d, kind="stable")[:NODES_TRIED]]
        own_tree = shapely.STRtree(shapely.points(starts))
        _, d = own_tree.query_nearest(shapely.points(anchor_xy), return_distance=True,
                                      all_matches=False)
        ends = anchor_xy[np.argsort(d, kind="stable")[:NODES_TRIED]]
        path = paths.shortest(starts, ends)
        link = None if path is None else _first_reach(path, g.geometry[edge_comp == comp],
                                                      g.geometry[at])
        if link is None or (best is not None and link.length >= best[0]):
            continue
        if clear(link) and (accept is None or accept(link)):
            best = (float(link.length), int(comp), link)
    return best


def _first_reach(path, own, anchored):
    """The stretch of a bent path from its last contact with its own piece (``own``) to
    where it first comes within a street's corridor of the anchored network (``anchored``)
    after it, then square onto that street (a path that followed the street's side there
    would double it); None where it reaches none.

    A path that starts in the street's corridor goes square onto it from its start:

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> own = np.array([shapely.LineString([(40, 5), (60, 5)])])
    >>> path = shapely.LineString([(50, 5), (50, 60), (90, 60)])
    >>> _first_reach(path, own, np.array([road])).wkt
    'LINESTRING (50 5, 50 0)'
    """
    touch = shapely.get_coordinates(shapely.intersection(own[shapely.intersects(own, path)],
                                                        path))
    s0 = float(shapely.line_locate_point(path, shapely.points(touch)).max()) if len(touch) \
        else 0.0
    steps = np.arange(s0, path.length, 1.0)
    near, d = shapely.STRtree(anchored).query_nearest(
        shapely.line_interpolate_point(path, steps), return_distance=True, all_matches=False)
    reached = np.flatnonzero(d <= CORRIDOR_HALF_WIDTH)
    if not len(reached):
        return None
    k = int(reached[0])
    # the path up to there (only its start where that is already in the corridor)
    head = shapely.get_coordinates(substring(path, s0, float(steps[k]))) if k else \
        shapely.get_coordinates(shapely.line_interpolate_point(path, s0))
    to_street = shapely.shortest_line(shapely.Point(head[-1]), anchored[near[1][k]])
    coords = np.concatenate([head[:-1], shapely.get_coordinates(to_street)])
    coords = coords[np.r_[True, np.hypot(*np.diff(coords, axis=0).T) > 1e-9]]
    return shapely.LineString(coords) if len(coords) > 1 else None


def join_pieces(lines, ends_on=None, max_length: Optional[Callable[[float], float]] = None,
                inside=None) -> np.ndarray:
    """Links that join the pieces of a noded network into one, keeping every piece.

    For a network whose pieces all reach given roads, and given roads that are themselves
    apart inside the target (a village's roads cut off by the boundary, a lane the level-0
    roads do not reach): the real streets join them, so the synthesised ones should. The
    piece with the most street anchors; the others are linked to it nearest first, as
    :func:`link_floating_pieces` links floating pieces but from either side (the street
    whose end is nearest to a lane joins it), and stay as they are when no clear street
    reaches them. Pieces are counted as :func:`invariants.check_network` counts components
    (a bridge over a road does not join it). ``ends_on``, ``max_length`` and ``inside`` as
    for :func:`link_floating_pieces`: with ``inside`` parts of a target apart stay apart.

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> street = shapely.LineString([(50, 0), (50, 40)])
    >>> lane = shapely.LineString([(0, 70), (100, 70)])
    >>> [x.wkt for x in join_pieces([road, street, lane])]
    ['LINESTRING (50 40, 50 70)']

    The lane in a part of the target apart from the road's: no street joins them.

    >>> parts = shapely.union_all([shapely.box(-9, -9, 109, 50), shapely.box(-9, 60, 109, 80)])
    >>> len(join_pieces([road, street, lane], inside=parts))
    0
    """
    lines = np.asarray(lines, dtype=object)
    if len(lines) < 2:
        return np.empty(0, dtype=object)
    links, _ = link_floating_pieces(lines, np.zeros(len(lines), bool), drop_unlinked=False,
                                    ends_on=ends_on, max_length=max_length,
                                    pieces=connected_pieces(lines), both_ways=True,
                                    inside=inside)
    return links
