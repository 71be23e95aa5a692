"""Network invariants of a synthesised street network, checked against the roads it was given.

docs/ARCHITECTURE.md ("Quality measures") asks of every road synthesis that "every crossing is a
junction, the result is connected to the given roads, no street doubles a given road";
the fidelity issue adds that motorways and trunks are crossed only at existing junctions and
that the dead-end share stays within ±30 % of the example's. This module is the one checker
all road-synthesis methods, the fidelity benchmark and ``layoutmetrics`` use.

Definitions (one home for each rule):

- **Contact**: a point where two lines meet (intersect, or come within ``tolerance`` m).
- **Junction**: a contact at an end point of either line (a street ending on another one,
  a T), or at a vertex of both lines (an OSM node shared by two ways). Noding the union of
  the lines makes every junction a graph node without moving anything.
- **Crossing without junction**: any other point contact: at least one line passes through
  the point with no vertex there (a street drawn over an arterial, an underpass that no
  layer attribute explains). A synthesised line that crosses itself counts once per line.
- **Overlap**: two lines sharing a stretch (a line-shaped intersection longer than the
  tolerance) where at least one of them is synthesised.
- **Floating piece**: a connected component (lines joined at junctions and overlaps, not at
  crossings) that holds synthesised streets but no given road; without given roads, every
  component after the first.
- **Parallel duplicate**: a piece of a synthesised street inside the corridor of a given road
  (``corridor_half_width`` m either side of its centreline) longer than
  ``min_duplicate_length`` m. A street crossing the corridor at an angle theta spends
  ``2 w / sin(theta)`` in it (< 40 m for theta > 24 degrees at w = 8 m); one running along it
  spends its whole length.
- **Controlled-access contact**: a contact of a synthesised street with a given motorway or
  trunk (or their links) farther than ``junction_radius`` m from an existing junction of
  the given roads (a point where their degree is at least 3).
- **Dead-end share**: degree-1 nodes over all nodes of degree != 2 of the noded network of
  synthesised and given roads together, chains through degree-2 nodes dissolved, counting
  nodes inside ``area`` and farther than ``edge_distance`` m from its boundary (a network
  clipped to an area ends there without being a dead end). It is a violation when an
  example share is given and the result is off by more than ``dead_end_tolerance`` of it.

The given roads are taken as they are: crossings among them are not violations (a bridge
of a real network crosses what it passes over). Pass as ``synthesised`` only what a method
added, not its copy of the given roads (a copy would double them).

Everything is vectorised with shapely 2 (``STRtree.query`` with ``dwithin``, one
intersection per candidate pair) and scipy's connected components; no loop over lines.

References
----------
docs/ARCHITECTURE.md, "Quality measures" (network invariants for any synthesised roads); Aliaga,
Vanegas, Benes 2008, sec. 5 (intersections are "all the pair-wise intersection points
between street centerlines" - so every crossing must be a node); Hartmann thesis ch. 4.1.2
(the street graph is planar).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..core.progress import InputError, Progress, ensure
from ..core.text import counted
from .street_graph import JUNCTION_TOLERANCE, measured_graph, node_lines

__all__ = [
    "JUNCTION_TOLERANCE", "CORRIDOR_HALF_WIDTH", "MIN_DUPLICATE_LENGTH", "JUNCTION_RADIUS",
    "corridor_of",
    "DEAD_END_TOLERANCE", "EDGE_DISTANCE", "SNAP_TOLERANCE", "UNDERSHOOT_DISTANCE",
    "CONTROLLED_ACCESS", "is_controlled_access", "short_ends",
    "CHECKS", "Contacts", "NetworkCheck", "line_contacts", "connected_pieces", "node_degrees",
    "dead_end_share",
    "crossing_share", "counted_nodes", "dead_end_share_of_extract", "crossing_share_of_extract",
    "extract_hull", "new_streets", "check_network", "corridor_around",
    "doubles_a_street",
]

#: Half-width (m) of the corridor of a given road in which no synthesised street may run.
CORRIDOR_HALF_WIDTH = 8.0
#: A synthesised piece inside a corridor longer than this (m) doubles the given road.
MIN_DUPLICATE_LENGTH = 40.0
#: A contact with a motorway or trunk this close (m) to an existing junction is at it.
JUNCTION_RADIUS = 1.0
#: Allowed relative deviation of the dead-end share from the example's (issue: ±30 %).
DEAD_END_TOLERANCE = 0.3
#: Nodes this close (m) to the study-area boundary are clip ends, not dead ends.
EDGE_DISTANCE = 1.0
#: Nodes closer than this (m) are one node when degrees are counted (``layoutmetrics``).
SNAP_TOLERANCE = 0.5
#: A dangling synthesised end this close (m) to another line but not on it undershoots it.
UNDERSHOOT_DISTANCE = 2.0
#: OSM classes crossed only at existing junctions.
CONTROLLED_ACCESS = ("motorway", "motorway_link", "trunk", "trunk_link")

#: The checks, in report order: (name, description, is a violation count).
CHECKS = (
    ("crossings_given", "Crossings of a given road without a junction", True),
    ("crossings_synthesised", "Crossings of synthesised streets without a junction", True),
    ("overlaps", "Synthesised streets overlapping another line", True),
    ("floating_pieces", "Floating pieces (not connected to the given roads)", True),
    ("parallel_duplicates", "Streets running inside a given road's corridor", True),
    ("controlled_access", "Motorway / trunk contacts away from existing junctions", True),
    ("outside_target", "Synthesised streets leaving the target", True),
    ("dead_end_share", "Dead-end share outside the example's ±30 %", True),
    ("components", "Connected components (synthesised and given roads)", False),
    ("undershoots", "Dangling ends just short of another line", False),
)


#: How :meth:`NetworkCheck.summary` names one and several of each violation.
_SUMMARY_NOUNS = {
    "crossings_given": ("crossing of a given road", "crossings of given roads"),
    "crossings_synthesised": ("crossing without a junction", "crossings without a junction"),
    "overlaps": ("overlap", None), "floating_pieces": ("floating piece", None),
    "parallel_duplicates": ("street along a given road", "streets along given roads"),
    "controlled_access": ("motorway / trunk contact", None),
    "outside_target": ("street leaving the target", "streets leaving the target"),
}


def is_controlled_access(road_class: Sequence) -> np.ndarray:
    """Which OSM classes are motorways or trunks (their links included): roads that take
    no new junction.

    >>> is_controlled_access(["motorway", "primary", None, "trunk_link"]).tolist()
    [True, False, False, True]
    """
    cls = np.asarray([str(c) if c is not None else "" for c in road_class], dtype=object)
    return np.isin(cls, CONTROLLED_ACCESS)


def _lines(geoms, what: str, layer=None):
    """Single-part, non-empty 2D lines of an array of (multi)lines, and the layer of each."""
    arr = np.asarray(geoms if geoms is not None else [], dtype=object).ravel()
    lay = np.zeros(len(arr), np.int64) if layer is None else \
        np.asarray(layer, dtype=np.int64).ravel()
    if len(arr) == 0:
        return np.empty(0, dtype=object), np.zeros(0, np.int64)
    ok = ~(shapely.is_missing(arr) | shapely.is_empty(arr))
    arr, lay = arr[ok], lay[ok]
    if len(arr) and not np.isin(shapely.get_type_id(arr), (1, 2, 5)).all():
        raise InputError(f"the {what} must be lines")
    parts, src = shapely.get_parts(arr, return_index=True)
    keep = shapely.get_type_id(parts) != 2
    parts, src = shapely.force_2d(parts[keep]), src[keep]
    keep = shapely.length(parts) > 0
    return parts[keep], lay[src[keep]]


@dataclass
class Contacts:
    """Where lines meet, one row per point (or stretch) of contact of two lines.

    Attributes
    ----------
    a, b : int arrays, indices of the two lines (``a < b``)
    geometry : Point, or LineString for an overlap
    junction : bool array, the contact is a junction (an end point of either line, or a
        vertex of both)
    overlap : bool array, the lines share a stretch here
    """

    a: np.ndarray
    b: np.ndarray
    geometry: np.ndarray
    junction: np.ndarray
    overlap: np.ndarray


def line_contacts(lines: Sequence, tolerance: float = JUNCTION_TOLERANCE) -> Contacts:
    """All contacts between pairs of distinct lines, classified as junctions or crossings.

    Parameters
    ----------
    lines : array of LineString (metric CRS)
    tolerance : float, lines closer than this (m) touch; a point this close to a vertex or
        an end point is at it

    Returns
    -------
    Contacts

    Examples
    --------
    >>> import shapely
    >>> plus = [shapely.LineString([(0, 5), (10, 5)]), shapely.LineString([(5, 0), (5, 10)])]
    >>> line_contacts(plus).junction.tolist()        # drawn over each other: a crossing
    [False]
    >>> tee = [shapely.LineString([(0, 5), (10, 5)]), shapely.LineString([(5, 5), (5, 10)])]
    >>> line_contacts(tee).junction.tolist()         # a street ending on another: a junction
    [True]
    """
    lines = np.asarray(lines, dtype=object)
    empty = Contacts(np.zeros(0, np.int64), np.zeros(0, np.int64), np.empty(0, dtype=object),
                     np.zeros(0, bool), np.zeros(0, bool))
    if len(lines) < 2:
        return empty
    a, b = shapely.STRtree(lines).query(lines, predicate="dwithin", distance=tolerance)
    keep = a < b
    a, b = a[keep], b[keep]
    if not len(a):
        return empty
    inter = shapely.intersection(lines[a], lines[b])
    # lines within the tolerance that do not intersect meet at their nearest points
    miss = shapely.is_empty(inter)
    if miss.any():
        inter[miss] = shapely.get_point(shapely.shortest_line(lines[a[miss]], lines[b[miss]]), 0)
    parts, pair = shapely.get_parts(inter, return_index=True)
    parts, sub = shapely.get_parts(parts, return_index=True)   # collections of multi-parts
    pair = pair[sub]
    dim = shapely.get_dimensions(parts)
    overlap = (dim == 1) & (shapely.length(parts) > tolerance)
    point = dim == 0
    # a point-like line piece (shorter than the tolerance) is a point contact at its start
    short = (dim == 1) & ~overlap
    parts = parts.copy()
    parts[short] = shapely.get_point(parts[short], 0)
    point |= short
    pa, pb = a[pair], b[pair]
    junction = np.ones(len(parts), dtype=bool)
    if point.any():
        p = parts[point]
        la, lb = lines[pa[point]], lines[pb[point]]
        with np.errstate(invalid="ignore"):
            end_a = shapely.distance(p, shapely.boundary(la)) <= tolerance
            end_b = shapely.distance(p, shapely.boundary(lb)) <= tolerance
            vtx_a = shapely.distance(p, shapely.extract_unique_points(la)) <= tolerance
            vtx_b = shapely.distance(p, shapely.extract_unique_points(lb)) <= tolerance
        junction[point] = end_a | end_b | (vtx_a & vtx_b)
    keep = point | overlap
    return Contacts(pa[keep], pb[keep], parts[keep], junction[keep], overlap[keep])


def _pieces(con: Contacts, n: int, joinable=None):
    """(count, label per line) of the connected pieces of ``n`` lines: lines are joined
    where they meet at a junction or share a stretch (``joinable``: per contact, False for
    lines on different vertical layers)."""
    joined = con.junction | con.overlap
    if joinable is not None:
        joined &= joinable
    adj = coo_matrix((np.ones(joined.sum()), (con.a[joined], con.b[joined])), shape=(n, n))
    return connected_components(adj, directed=False)


def connected_pieces(lines: Sequence, tolerance: float = JUNCTION_TOLERANCE) -> np.ndarray:
    """The connected piece of each line, as :func:`check_network` counts components: lines
    are joined where they meet at a junction or share a stretch, not where one crosses the
    other (a bridge).

    >>> import shapely
    >>> tee = [shapely.LineString([(0, 5), (10, 5)]), shapely.LineString([(5, 5), (5, 10)])]
    >>> connected_pieces(tee + [shapely.LineString([(20, 0), (20, 9)])]).tolist()
    [0, 0, 1]
    >>> plus = [shapely.LineString([(0, 5), (10, 5)]), shapely.LineString([(5, 0), (5, 10)])]
    >>> connected_pieces(plus).tolist()
    [0, 1]
    """
    lines = np.asarray(lines, dtype=object)
    return _pieces(line_contacts(lines, tolerance), len(lines))[1]


def _node_degrees(lines: np.ndarray, points: np.ndarray, tolerance: float) -> np.ndarray:
    """Degree of the network of ``lines`` at each point: 1 per line ending there, 2 per line
    passing through."""
    if not len(points) or not len(lines):
        return np.zeros(len(points), dtype=np.int64)
    p_i, l_i = shapely.STRtree(lines).query(points, predicate="dwithin", distance=tolerance)
    with np.errstate(invalid="ignore"):
        at_end = shapely.distance(points[p_i], shapely.boundary(lines[l_i])) <= tolerance
    return np.bincount(p_i, weights=np.where(at_end, 1, 2), minlength=len(points)).astype(
        np.int64)


def _self_crossings(lines: np.ndarray, tolerance: float) -> np.ndarray:
    """Points where a line crosses or touches itself (one per point and line)."""
    bad = lines[~shapely.is_simple(lines)] if len(lines) else lines
    if not len(bad):
        return np.empty(0, dtype=object)
    try:
        pieces, owner = shapely.get_parts(shapely.node(bad), return_index=True)
    except shapely.errors.GEOSException:
        # nearly coincident stretches of one line can defeat GEOS's noding: node each line
        # on its own (node_lines snap-rounds the one that fails)
        parts = [node_lines([line]) for line in bad]
        pieces = np.concatenate(parts)
        owner = np.repeat(np.arange(len(bad)), [len(p) for p in parts])
    ends = np.concatenate([shapely.get_coordinates(shapely.get_point(pieces, 0)),
                           shapely.get_coordinates(shapely.get_point(pieces, -1))])
    owner = np.r_[owner, owner]
    key = np.round(ends / max(tolerance, 1e-9))
    _, first, count = np.unique(np.column_stack([owner, key]), axis=0, return_index=True,
                                return_counts=True)
    # a crossing is where noding cut a line into pieces meeting 3 or more times
    sel = first[count >= 3]
    return shapely.points(ends[sel])


def _unique_points(points: np.ndarray, tolerance: float) -> np.ndarray:
    if not len(points):
        return points
    xy = np.round(shapely.get_coordinates(points) / max(tolerance, 1e-9))
    _, first = np.unique(xy[:, 0] + 1j * xy[:, 1], return_index=True)
    return points[np.sort(first)]


def node_degrees(lines: Sequence, area=None, edge_distance: float = EDGE_DISTANCE,
                 snap_tolerance: float = SNAP_TOLERANCE, z_layer=None) -> np.ndarray:
    """Degrees of the nodes of degree != 2 of a noded street network, as its shares count.

    Lines are noded at crossings (within their vertical layer ``z_layer`` when given: a
    bridge makes no node with the street under it), nodes closer than ``snap_tolerance``
    merged and chains through degree-2 nodes dissolved: the street graph of
    ``layoutmetrics`` (its default 0.5 m); with ``area``, only nodes inside it (or on its
    boundary, within the millimetre the nodes are rounded to) and at least ``edge_distance``
    m from its boundary count (the ends of a network clipped to the area are not dead ends).
    """
    lines, layer = _lines(lines, "roads", z_layer)
    if not len(lines):
        return np.zeros(0, dtype=np.int64)
    # lines of different vertical layers (bridges, tunnels) cross without a node
    g = measured_graph(lines, snap_tolerance, layer if layer.any() else None)
    deg = g.degree
    count = deg != 2
    if area is not None:
        count &= counted_nodes(g.nodes, area, edge_distance)
    return deg[count]


def dead_end_share(lines: Sequence, area=None, edge_distance: float = EDGE_DISTANCE,
                   snap_tolerance: float = SNAP_TOLERANCE, z_layer=None) -> float:
    """Share of dead ends among the nodes of degree != 2 of a noded street network (counted
    as :func:`node_degrees` counts them: ``layoutmetrics``' ``dead_end_share``).

    Returns
    -------
    float in [0, 1], NaN when no node counts.
    """
    deg = node_degrees(lines, area, edge_distance, snap_tolerance, z_layer)
    return float((deg == 1).mean()) if len(deg) else float("nan")


def crossing_share(lines: Sequence, area=None, edge_distance: float = EDGE_DISTANCE,
                   snap_tolerance: float = SNAP_TOLERANCE) -> float:
    """Share of 4-way (and more) junctions among the nodes of degree != 2 (counted as
    :func:`node_degrees` counts them: ``layoutmetrics``' ``degree4_share``); NaN when no
    node counts."""
    deg = node_degrees(lines, area, edge_distance, snap_tolerance)
    return float((deg >= 4).mean()) if len(deg) else float("nan")


def counted_nodes(xy: np.ndarray, area, edge_distance: float = EDGE_DISTANCE) -> np.ndarray:
    """Which nodes (n, 2) the dead-end share counts: inside ``area`` (on its boundary, within
    the millimetre nodes are rounded to, counts as inside) and at least ``edge_distance`` m
    from its boundary (the ends of a network clipped to the area are not dead ends)."""
    pts = shapely.points(np.atleast_2d(xy))
    inside = shapely.dwithin(area, pts, 1e-3)
    if edge_distance > 0:
        inside &= ~shapely.dwithin(shapely.boundary(area), pts, edge_distance)
    return inside


def dead_end_share_of_extract(lines: Sequence) -> float:
    """:func:`dead_end_share` of an example known only by its lines, measured inside their
    convex hull: an example that is an extract has its streets cut at the extract's edge,
    and those cut ends, on the hull, are no dead ends (Bubeneč: all 11 of its street ends).

    A crossing cut out of a larger network, with a cul-de-sac: its four cut ends do not count.

    >>> lines = [shapely.LineString([(0, 50), (100, 50)]), shapely.LineString([(50, 0), (50, 100)]),
    ...          shapely.LineString([(75, 50), (75, 70)])]
    >>> round(dead_end_share_of_extract(lines), 3), round(dead_end_share(lines), 3)
    (0.333, 0.714)
    """
    return _share_of_extract(dead_end_share, lines)


def crossing_share_of_extract(lines: Sequence) -> float:
    """:func:`crossing_share` of an example known only by its lines, inside their convex hull
    (as :func:`dead_end_share_of_extract`).

    >>> lines = [shapely.LineString([(0, 50), (100, 50)]), shapely.LineString([(50, 0), (50, 100)]),
    ...          shapely.LineString([(75, 50), (75, 70)])]
    >>> round(crossing_share_of_extract(lines), 3)
    0.333
    """
    return _share_of_extract(crossing_share, lines)


def _share_of_extract(share, lines) -> float:
    lines, _ = _lines(lines, "roads")
    if not len(lines):
        return float("nan")
    return share(lines, extract_hull(lines))


def short_ends(lines: Sequence, synthesised: Sequence, tolerance: float = 1e-3,
               distance: float = UNDERSHOOT_DISTANCE) -> Tuple[np.ndarray, np.ndarray]:
    """(line, end: 0 its first point, 1 its last) of each end of a ``synthesised`` line
    that lies within ``distance`` of another line but not within ``tolerance`` of one: a
    street that stops just short of another (an undershoot; one rule for the checker and
    :func:`network.undershoots.clear_undershoots`). First ends, then last ends, each in line
    order.

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> short = shapely.LineString([(50, 60), (50, 1.2)])
    >>> [a.tolist() for a in short_ends([road, short], [False, True])]
    [[1], [1]]
    """
    lines = np.asarray(lines, dtype=object)
    idx = np.flatnonzero(np.asarray(synthesised, dtype=bool))
    ends = np.concatenate([shapely.get_point(lines[idx], 0), shapely.get_point(lines[idx], -1)])
    own = np.r_[idx, idx]
    side = np.repeat([0, 1], len(idx))
    tree = shapely.STRtree(lines)
    near = []
    for reach in (tolerance, distance):
        e_i, l_i = tree.query(ends, predicate="dwithin", distance=reach)
        hit = np.zeros(len(ends), bool)
        hit[e_i[l_i != own[e_i]]] = True
        near.append(hit)
    sel = near[1] & ~near[0]
    return own[sel], side[sel]


def extract_hull(lines: Sequence):
    """The area an example known only by its lines is measured in: their convex hull (its
    streets are cut at the extract's edge, which the hull follows). Lines or multi-part
    lines (a shapefile's, GeoJSON's).

    >>> two = shapely.MultiLineString([[(0, 0), (10, 0)], [(0, 5), (10, 5)]])
    >>> extract_hull([two, shapely.LineString([(0, 0), (0, 10)])]).area
    75.0
    """
    return shapely.convex_hull(shapely.multipoints(shapely.get_coordinates(
        np.asarray(lines, dtype=object))))


def corridor_of(given: Sequence, half_width: float = CORRIDOR_HALF_WIDTH, quad_segs: int = 4):
    """The corridors of the given roads, in which no synthesised street may run (prepared)."""
    corridor = shapely.union_all(shapely.buffer(np.asarray(given, dtype=object), half_width,
                                                quad_segs=quad_segs))
    shapely.prepare(corridor)
    return corridor


def corridor_around(face, lines=None):
    """The corridors of the streets a new street in ``face`` must not run along: its outline
    (none when ``face`` is None) and ``lines`` (the network lines that touch it), prepared;
    the buffers' round ends coarser than :func:`corridor_of`'s (2 segments a quarter)."""
    lines = np.empty(0, dtype=object) if lines is None else np.asarray(lines, dtype=object)
    around = lines if face is None else np.concatenate([[shapely.boundary(face)], lines])
    return corridor_of(around, quad_segs=2)


def doubles_a_street(pieces: Sequence, corridor) -> np.ndarray:
    """Which new streets double a street in its corridor (a mask over ``pieces``).

    The rule of :func:`check_network`, applied to the streets as they will be
    measured: a stretch inside the corridor longer than ``MIN_DUPLICATE_LENGTH``, the
    stretches of all pieces joined where they meet end to end (two pieces under the limit
    that meet inside the corridor become one street when the network's degree-2 chains are
    merged). A street crossing the corridor, or crossing the face near its outline at both
    ends, is no double.
    """
    pieces = np.asarray(pieces, dtype=object)
    bad = np.zeros(len(pieces), bool)
    if not len(pieces):
        return bad
    with np.errstate(invalid="ignore"):
        inside = shapely.intersection(pieces, corridor)
    parts, owner = shapely.get_parts(inside, return_index=True)
    keep = (shapely.get_dimensions(parts) == 1) & (shapely.length(parts) > 1e-6)
    parts, owner = parts[keep], owner[keep]
    if not len(parts):
        return bad
    runs = shapely.get_parts(shapely.line_merge(shapely.union_all(parts)))
    long = runs[shapely.length(runs) > MIN_DUPLICATE_LENGTH]
    if len(long):
        r_i, p_i = shapely.STRtree(parts).query(long, predicate="intersects")
        with np.errstate(invalid="ignore"):
            shared = shapely.length(shapely.intersection(long[r_i], parts[p_i]))
        bad[owner[p_i[shared > 1e-6]]] = True
    return bad


def new_streets(lines: Sequence, given: Sequence, tolerance: float = 0.01) -> np.ndarray:
    """Which lines are not copies of the given roads (a mask).

    A method's output often holds the given roads again (re-noded arterials of level 0);
    a line that lies within ``tolerance`` m of the given roads all along is such a copy and
    must not be checked against itself.
    """
    lines = np.asarray(lines, dtype=object).ravel()
    given = np.asarray(given, dtype=object).ravel()
    if not len(lines) or not len(given):
        return np.ones(len(lines), dtype=bool)
    cover = shapely.union_all(shapely.buffer(given, tolerance, quad_segs=2))
    shapely.prepare(cover)
    return ~shapely.covers(cover, lines)


@dataclass
class NetworkCheck:
    """Result of :func:`check_network`: counts, and where each violation is.

    Attributes
    ----------
    crossings_given, crossings_synthesised : Points where a synthesised street crosses a
        given road / another synthesised street (or itself) without a junction
    overlaps : LineStrings shared by a synthesised street and another line
    duplicates : pieces of synthesised streets inside a given road's corridor
    controlled_access : Points where a synthesised street meets a motorway or trunk away
        from an existing junction
    undershoots : dangling synthesised end points just short of another line (not counted
        as violations; they leave the street a dead end)
    outside : the pieces of synthesised streets outside the target (``check_network``'s
        ``target``) by more than ``edge_distance``, each longer than that; None when no
        target was given (the check did not run: it is left out of the counts)
    n_components : connected components of synthesised and given roads together
    floating_pieces : components with synthesised streets and no given road
    dead_end_share, example_dead_end_share : float (NaN / None when unknown)
    dead_end_tolerance : relative tolerance of the dead-end share
    n_synthesised, n_given : number of single-part lines checked
    """

    crossings_given: np.ndarray
    crossings_synthesised: np.ndarray
    overlaps: np.ndarray
    duplicates: np.ndarray
    controlled_access: np.ndarray
    undershoots: np.ndarray
    n_components: int
    floating_pieces: int
    dead_end_share: float
    example_dead_end_share: Optional[float] = None
    dead_end_tolerance: float = DEAD_END_TOLERANCE
    n_synthesised: int = 0
    n_given: int = 0
    notes: List[str] = field(default_factory=list)
    outside: Optional[np.ndarray] = None

    @property
    def dead_end_ok(self) -> Optional[bool]:
        """The dead-end share is within the tolerance of the example's (None: no example)."""
        e = self.example_dead_end_share
        if e is None or not np.isfinite(e) or not np.isfinite(self.dead_end_share):
            return None
        return bool(abs(self.dead_end_share - e) <= self.dead_end_tolerance * e + 1e-12)

    def counts(self) -> Dict[str, float]:
        """Every check that ran by name, in the order of :data:`CHECKS`: a count, or the
        share for dead ends (``outside_target`` only when a target was given)."""
        c = {"crossings_given": len(self.crossings_given),
             "crossings_synthesised": len(self.crossings_synthesised),
             "overlaps": len(self.overlaps),
             "floating_pieces": self.floating_pieces,
             "parallel_duplicates": len(self.duplicates),
             "controlled_access": len(self.controlled_access),
             "outside_target": None if self.outside is None else len(self.outside),
             "dead_end_share": self.dead_end_share,
             "components": self.n_components,
             "undershoots": len(self.undershoots)}
        return {name: c[name] for name, _, _ in CHECKS if c[name] is not None}

    def violations(self) -> Dict[str, int]:
        """Violation count per check (the dead-end share gives 1 when out of tolerance)."""
        c = self.counts()
        out = {name: int(c[name]) for name, _, is_violation in CHECKS
               if is_violation and name != "dead_end_share" and name in c}
        out["dead_end_share"] = int(self.dead_end_ok is False)
        return out

    @property
    def n_violations(self) -> int:
        return int(sum(self.violations().values()))

    @property
    def ok(self) -> bool:
        return self.n_violations == 0

    def table(self) -> pd.DataFrame:
        """One row per check: check, description, value, limit, violations."""
        c, v = self.counts(), self.violations()
        rows = []
        for name, text, is_violation in CHECKS:
            if name not in c:
                continue
            limit = np.nan
            if name == "dead_end_share" and self.example_dead_end_share is not None:
                limit = self.example_dead_end_share
                text = (f"Dead-end share (example {self.example_dead_end_share:.3f} "
                        f"± {100 * self.dead_end_tolerance:.0f} %)")
            elif is_violation:
                limit = 0.0
            rows.append(dict(check=name, description=text, value=float(c[name]), limit=limit,
                             violations=v.get(name, 0) if is_violation else 0))
        return pd.DataFrame(rows)

    def summary(self) -> str:
        v = self.violations()
        bad = ["dead-end share outside the example's ±30 %" if name == "dead_end_share"
               else counted(n, *_SUMMARY_NOUNS.get(name, (name.replace("_", " "), None)))
               for name, n in v.items() if n]
        share = (f"dead-end share {self.dead_end_share:.2f}"
                 + (f" (example {self.example_dead_end_share:.2f})"
                    if self.example_dead_end_share is not None else ""))
        head = (f"{counted(self.n_synthesised, 'synthesised line')} against {self.n_given} given"
                if self.n_given else counted(self.n_synthesised, "line"))
        head += f": {counted(self.n_components, 'connected component')}, {share}"
        return head + (": no violation." if not bad else ": " + ", ".join(bad) + ".")


def check_network(synthesised: Sequence, given: Optional[Sequence] = None,
                  given_class: Optional[Sequence] = None, area=None, *,
                  given_layer: Optional[Sequence] = None,
                  synthesised_layer: Optional[Sequence] = None,
                  example_dead_end_share: Optional[float] = None,
                  tolerance: float = JUNCTION_TOLERANCE,
                  corridor_half_width: float = CORRIDOR_HALF_WIDTH,
                  min_duplicate_length: float = MIN_DUPLICATE_LENGTH,
                  junction_radius: float = JUNCTION_RADIUS,
                  dead_end_tolerance: float = DEAD_END_TOLERANCE,
                  edge_distance: float = EDGE_DISTANCE,
                  target=None,
                  progress: Optional[Progress] = None) -> NetworkCheck:
    """Check the network invariants of synthesised streets against the roads they were given.

    Parameters
    ----------
    synthesised : array of LineString / MultiLineString (metric CRS), what a method added
    given : array of lines, optional, the roads the method was given (arterials, existing
        roads); crossings among them are not checked
    given_class : OSM ``highway`` class per given line, optional (for the motorway / trunk
        check, :data:`CONTROLLED_ACCESS`)
    area : Polygon, optional, where dead ends are counted (inside it, away from its
        boundary): the target, or a study area
    given_layer : OSM vertical layer per given line, optional: given roads of another layer
        than 0 (bridges, tunnels) cross synthesised streets (layer 0) and each other
        without a junction when no end point or shared vertex joins them
    synthesised_layer : vertical layer per synthesised line, optional (default 0: a
        synthesis knows no bridges; pass the OSM layers to check a real network)
    example_dead_end_share : float, optional, the example's share (:func:`dead_end_share`)
    tolerance, corridor_half_width, min_duplicate_length, junction_radius,
    dead_end_tolerance, edge_distance : float, see the module constants
    target : Polygon(s), optional, the land the streets were synthesised for: a synthesised
        street that leaves it (by more than ``edge_distance``, for longer than that) is a
        violation (``area`` may be a study area that streets run beyond; a synthesis' target
        may not be); without it ``outside_target`` is not checked and not reported
    progress : Progress, optional

    Returns
    -------
    NetworkCheck

    Raises
    ------
    InputError
        Geometries that are not lines, a class list of the wrong length, absurd tolerances.

    Examples
    --------
    >>> import shapely
    >>> arterial = [shapely.LineString([(0, 0), (200, 0)])]
    >>> street = [shapely.LineString([(100, -50), (100, 50)])]
    >>> check_network(street, arterial).violations()["crossings_given"]
    1
    """
    progress = ensure(progress)
    for name, value in (("tolerance", tolerance), ("corridor half-width", corridor_half_width),
                        ("minimum duplicate length", min_duplicate_length),
                        ("junction radius", junction_radius),
                        ("dead-end tolerance", dead_end_tolerance),
                        ("edge distance", edge_distance)):
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"the {name} must be a non-negative number, got {value}")
    given_in = np.asarray(given if given is not None else [], dtype=object).ravel()
    cls = None
    if given_class is not None:
        cls = np.asarray(given_class, dtype=object).ravel()
        if len(cls) != len(given_in):
            raise InputError(f"{len(cls)} road classes for {len(given_in)} given roads")
    if given_layer is not None and len(np.ravel(given_layer)) != len(given_in):
        raise InputError(f"{len(np.ravel(given_layer))} vertical layers for {len(given_in)} "
                         "given roads")
    syn_in = np.asarray(synthesised if synthesised is not None else [], dtype=object).ravel()
    if synthesised_layer is not None and len(np.ravel(synthesised_layer)) != len(syn_in):
        raise InputError(f"{len(np.ravel(synthesised_layer))} vertical layers for "
                         f"{len(syn_in)} synthesised roads")
    syn, slay = _lines(syn_in, "synthesised roads", synthesised_layer)
    # given lines single-part, keeping the class of each part
    giv, glay = _lines(given_in, "given roads", given_layer)
    gcls = None
    if cls is not None:   # the class of each part: carried like the layer, by index
        _, idx = _lines(given_in, "given roads", np.arange(len(given_in)))
        gcls = cls[idx]
    n_s, n_g = len(syn), len(giv)
    lines = np.concatenate([syn, giv])
    is_given = np.r_[np.zeros(n_s, bool), np.ones(n_g, bool)]
    layer = np.r_[slay, glay]
    progress.step(0.1)

    con = line_contacts(lines, tolerance)
    progress.step(0.5)
    ga, gb = is_given[con.a], is_given[con.b]
    # lines of different vertical layers pass over each other unless a junction joins them
    apart = (layer[con.a] != layer[con.b]) & ~con.junction
    crossing = ~con.junction & ~con.overlap & ~apart
    crossings_given = con.geometry[crossing & (ga ^ gb)]
    crossings_synthesised = np.concatenate([con.geometry[crossing & ~ga & ~gb],
                                            _self_crossings(syn, tolerance)])
    overlaps = con.geometry[con.overlap & ~(ga & gb) & ~apart]

    n = len(lines)
    if n:
        n_comp, label = _pieces(con, n, ~apart)
        with_given = np.zeros(n_comp, bool)
        with_given[label[is_given]] = True
        with_syn = np.zeros(n_comp, bool)
        with_syn[label[~is_given]] = True
        floating = int((with_syn & ~with_given).sum()) if n_g else max(int(with_syn.sum()) - 1, 0)
    else:
        n_comp, floating = 0, 0
    progress.step(0.6)

    # parallel duplicates: long pieces inside the corridors of the given roads
    duplicates = np.empty(0, dtype=object)
    if n_s and n_g and corridor_half_width > 0:
        corridor = corridor_of(giv, corridor_half_width)
        hit = shapely.intersects(corridor, syn)
        if hit.any():
            with np.errstate(invalid="ignore"):
                pieces = shapely.get_parts(shapely.intersection(syn[hit], corridor))
            pieces = pieces[shapely.get_dimensions(pieces) == 1]
            duplicates = pieces[shapely.length(pieces) > min_duplicate_length]
    progress.step(0.75)

    # motorway / trunk contacts away from the given network's own junctions
    controlled = np.empty(0, dtype=object)
    if n_s and gcls is not None:
        is_ca = np.zeros(len(lines), bool)
        is_ca[n_s:] = is_controlled_access(gcls)
        sel = (ga ^ gb) & (is_ca[con.a] | is_ca[con.b])
        if sel.any():
            pts = con.geometry[sel]
            pts = np.where(shapely.get_dimensions(pts) == 0, pts, shapely.get_point(pts, 0))
            gg = ga & gb & con.junction & ~con.overlap
            cand = _unique_points(con.geometry[gg], tolerance)
            existing = cand[_node_degrees(giv, cand, tolerance) >= 3]
            if len(existing):
                near = shapely.STRtree(existing).query(pts, predicate="dwithin",
                                                       distance=junction_radius)[0]
                at = np.zeros(len(pts), bool)
                at[near] = True
            else:
                at = np.zeros(len(pts), bool)
            # a street meeting two ways of one motorway at their common end is one contact
            controlled = _unique_points(pts[~at], tolerance)
    progress.step(0.85)

    # dangling synthesised ends just short of another line (information)
    undershoots = np.empty(0, dtype=object)
    if n_s and n > 1:
        line, side = short_ends(lines, np.arange(n) < n_s, tolerance)
        undershoots = shapely.get_point(lines[line], np.where(side == 0, 0, -1))

    # pieces of synthesised streets outside the target
    outside = None if target is None else np.empty(0, dtype=object)
    if n_s and target is not None:
        within = shapely.buffer(target, max(edge_distance, tolerance))
        leaves = ~shapely.covers(within, syn)
        if leaves.any():
            with np.errstate(invalid="ignore"):
                pieces = shapely.get_parts(shapely.difference(syn[leaves], within))
            # a street along the outline may wiggle out by a little more (a rounded bend)
            outside = pieces[shapely.length(pieces) > max(edge_distance, tolerance)]

    share = dead_end_share(lines, area, edge_distance, z_layer=layer) if n else float("nan")
    progress.step(1.0)
    return NetworkCheck(crossings_given, crossings_synthesised, overlaps, duplicates, controlled,
                        undershoots, int(n_comp), floating, share,
                        None if example_dead_end_share is None else float(example_dead_end_share),
                        dead_end_tolerance, n_s, n_g, outside=outside)
