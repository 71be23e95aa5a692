"""Road network cleaning: a raw line layer -> a planar, noded street graph.

Preprocessing of Hartmann's thesis (ch. 4.1.2, "the streets of a given example city are
inserted into a graph G = (V, E)") and of Aliaga et al. 2008 (sec. 5, intersection points
are "all the pair-wise intersection points between street centerlines, and all street
centerline endpoints"). Real OSM is dirty, so this module:

- nodes the lines at real crossings, separately per vertical layer so that bridges and
  tunnels do not connect to what they pass over; ways of different layers connect only
  where they share an OSM node (an endpoint of one on a vertex of the other);
- snaps nodes closer than a tolerance together, in groups no wider than it, and drops the
  zero-length edges this makes; an edge that its moved end now makes cross another is
  noded there again;
- drops exact and near-duplicate edges (same end nodes, Hausdorff distance under the tolerance);
- prunes dangling slivers (dead-end edges shorter than a minimum length);
- merges chains through degree-2 nodes (OSM splits ways at arbitrary points), within one
  vertical layer (a bridge stays apart from its approach: its layer is its own).

Everything is vectorised with shapely 2 / numpy; the only Python loops are over groups of
duplicates, which are rare.
"""
from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..core.geometry import pinned_ends
from ..core.progress import InputError, Progress, ensure

__all__ = [
    "DRIVABLE_CLASSES", "SYNTHESISED_CLASSES", "ARTERIAL_CLASSES", "CLASS_RANK", "RoadGraph",
    "drivable_and_arterial", "parse_other_tags", "vertical_layer", "class_rank",
    "clean_network", "measured_graph", "collapse_short_pieces", "graph_from_lines",
    "node_lines", "renode", "snap_ends_onto_lines", "ends_as_vertices", "split_at_ends",
    "weld_ends", "close_short_gaps", "move_ends_onto_lines", "junction_points", "synthesised",
    "renode_attributed", "add_streets", "degree2_chains", "merge_chains", "snap_clusters",
    "JUNCTION_TOLERANCE",
]

#: OSM highway classes kept by default: what cars drive on and what forms city blocks.
DRIVABLE_CLASSES = (
    "motorway", "motorway_link", "trunk", "trunk_link", "primary", "primary_link",
    "secondary", "secondary_link", "tertiary", "tertiary_link", "unclassified",
    "residential", "living_street", "road",
)
#: The road classes this plugin's own road synthesis writes (growroads: major, minor;
#: StreetGAN: given, arterial, local): drivable streets too when a synthesis is measured.
SYNTHESISED_CLASSES = ("major", "minor", "given", "arterial", "local")
#: OSM classes taken as arterials (hierarchy level 0) by the OSM-class method.
ARTERIAL_CLASSES = (
    "motorway", "motorway_link", "trunk", "trunk_link", "primary", "primary_link",
    "secondary", "secondary_link",
)
_RANKED = ("motorway", "trunk", "primary", "secondary", "tertiary", "unclassified",
           "residential", "living_street", "road", "service", "pedestrian", "track")
#: Importance rank of a class (0 = most important); links rank with their class.
CLASS_RANK = {c: i for i, c in enumerate(_RANKED)}
UNKNOWN_RANK = len(_RANKED)

#: Points closer than this (m) are one point: a street end this close to a line meets it
#: (a junction), in the network cleaning and in the invariant checks alike.
JUNCTION_TOLERANCE = 1e-3

_TAG_RE = re.compile(r'"((?:[^"\\]|\\.)*)"=>"((?:[^"\\]|\\.)*)"')
_YES = {"yes", "true", "1", "viaduct", "covered", "building_passage", "culvert", "boardwalk"}


def drivable_and_arterial(road_class: Optional[Sequence] = None,
                          level: Optional[Sequence] = None, n: Optional[int] = None):
    """Which roads count, and which of them are arterials: the rule of the tools that take
    roads around buildings (attributes, best fit, the command line).

    A layer with OSM classes keeps its drivable lines (one without any keeps every line);
    arterials are level 0 when there is a level, else the arterial OSM classes.

    Returns
    -------
    (keep, arterial) : bool arrays over all lines (arterial only where kept)

    Examples
    --------
    >>> keep, art = drivable_and_arterial(["primary", "footway", "residential"])
    >>> keep.tolist(), art.tolist()
    ([True, False, True], [True, False, False])
    >>> drivable_and_arterial(level=[0, 1, None])[1].tolist()
    [True, False, False]
    """
    n = len(road_class if road_class is not None else level) if n is None else n
    keep = np.ones(n, dtype=bool)
    if road_class is not None:
        drivable = np.array([c in DRIVABLE_CLASSES for c in road_class], dtype=bool)
        if drivable.any():
            keep = drivable
    if level is not None:
        numbers = pd.to_numeric(pd.Series(np.asarray(level, dtype=object)), errors="coerce")
        arterial = (numbers == 0).to_numpy()
    elif road_class is not None:
        arterial = np.array([c in ARTERIAL_CLASSES for c in road_class], dtype=bool)
    else:
        arterial = np.zeros(n, dtype=bool)
    return keep, arterial & keep


def parse_other_tags(text: Optional[str]) -> dict:
    """Parse the hstore-like ``other_tags`` field of GDAL's OSM driver into a dict."""
    if not text:
        return {}
    return {k.replace('\\"', '"'): v.replace('\\"', '"') for k, v in _TAG_RE.findall(str(text))}


def vertical_layer(layer=None, bridge=None, tunnel=None) -> int:
    """OSM vertical layer of a way: ``layer`` when given, else +1 for bridges, -1 for tunnels."""
    if layer not in (None, ""):
        try:
            return int(round(float(str(layer).split(";")[0])))
        except ValueError:
            pass
    if bridge is not None and str(bridge).lower() in _YES:
        return 1
    if tunnel is not None and str(tunnel).lower() in _YES:
        return -1
    return 0


def class_rank(road_class: Optional[str]) -> int:
    if not road_class:
        return UNKNOWN_RANK
    base = str(road_class).replace("_link", "")
    return CLASS_RANK.get(base, UNKNOWN_RANK)


@dataclass
class RoadGraph:
    """A planar street graph: edges are linestrings between nodes.

    Attributes
    ----------
    geometry : ndarray of LineString, one per edge (metric CRS)
    u, v : int arrays, node ids of the first / last vertex of each edge
    road_class : object array of class names (None when unknown)
    name : object array of street names (None when unknown)
    z_layer : int array, the OSM vertical layer of the edge
    nodes : (n, 2) float array of node coordinates
    source : int array, index of the input line that contributed the longest part of the edge
    """

    geometry: np.ndarray
    u: np.ndarray
    v: np.ndarray
    road_class: np.ndarray
    name: np.ndarray
    z_layer: np.ndarray
    nodes: np.ndarray
    source: np.ndarray

    @property
    def n_edges(self) -> int:
        return len(self.geometry)

    @property
    def length(self) -> np.ndarray:
        return shapely.length(self.geometry)

    @property
    def degree(self) -> np.ndarray:
        return np.bincount(np.concatenate([self.u, self.v]), minlength=len(self.nodes))

    @property
    def class_rank(self) -> np.ndarray:
        return np.array([class_rank(c) for c in self.road_class], dtype=np.int64)


# --------------------------------------------------------------------------- helpers

def _node_ids(points: np.ndarray, decimals: int = 3):
    """Integer ids for coordinates equal to the millimetre.

    Coordinates are packed into one complex number each: a 1-D unique is several times
    faster than ``np.unique(axis=0)`` on rows.
    """
    keys = np.round(points, decimals)
    packed = keys[:, 0] + 1j * keys[:, 1]
    uniq, inv = np.unique(packed, return_inverse=True)
    return np.column_stack([uniq.real, uniq.imag]), inv.reshape(-1)


def _endpoints(geoms: np.ndarray):
    return shapely.get_coordinates(shapely.get_point(geoms, 0)), \
        shapely.get_coordinates(shapely.get_point(geoms, -1))


def _attach_attributes(pieces: np.ndarray, originals: np.ndarray, original_index: np.ndarray,
                       priority: np.ndarray):
    """For each noded piece, the index (into ``original_index``) of the input line it came from.

    Noding dissolves overlapping lines into one piece: of several parents, the one with the
    lowest ``priority`` (the most important road class) gives the piece its attributes.

    A piece's midpoint lies on its parent line; a millimetre ``dwithin`` query finds it
    several times faster than a nearest-neighbour search, which only handles the rest.
    """
    tree = shapely.STRtree(originals)
    mids = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    piece_idx, orig_idx = tree.query(mids, predicate="dwithin", distance=1e-3)
    out = np.full(len(pieces), -1, dtype=np.int64)
    order = np.lexsort((priority[orig_idx], piece_idx))
    p_sorted, o_sorted = piece_idx[order], orig_idx[order]
    best = np.r_[True, p_sorted[1:] != p_sorted[:-1]]  # first = best parent of each piece
    out[p_sorted[best]] = o_sorted[best]
    missing = np.flatnonzero(out < 0)
    if len(missing):
        p_idx, o_idx = tree.query_nearest(mids[missing], return_distance=False)
        out[missing[p_idx]] = o_idx
    return original_index[out]


def _split_at_vertices(geoms: np.ndarray, split_mask_fn):
    """Split linestrings at interior vertices selected by ``split_mask_fn(coords)``."""
    coords, line_idx = shapely.get_coordinates(geoms, return_index=True)
    first = np.r_[True, line_idx[1:] != line_idx[:-1]]
    last = np.r_[line_idx[1:] != line_idx[:-1], True]
    interior = ~(first | last)
    split = interior & split_mask_fn(coords)
    if not split.any():
        return geoms, np.arange(len(geoms))
    # duplicate each split vertex: it ends one piece and starts the next
    reps = np.where(split, 2, 1)
    new_coords = np.repeat(coords, reps, axis=0)
    new_line = np.repeat(line_idx, reps)
    starts_new_piece = np.repeat(first, reps)
    # the second copy of a split vertex starts a new piece
    dup_second = np.zeros(len(new_coords), dtype=bool)
    pos = np.cumsum(reps) - 1  # index of last copy of each vertex
    dup_second[pos[split]] = True
    piece_id = np.cumsum(starts_new_piece | dup_second) - 1
    pieces = shapely.linestrings(new_coords, indices=piece_id)
    parent = new_line[np.r_[0, np.flatnonzero(np.diff(piece_id)) + 1]]
    return pieces, parent


# --------------------------------------------------------------------------- main API

def node_lines(lines: Sequence) -> np.ndarray:
    """The lines split at every crossing and shared point, overlaps dissolved: the parts of
    ``shapely.node``.

    Nearly coincident lines can defeat GEOS's floating-point noding ("noding failed to
    converge"); they are then noded by snap-rounding on the :data:`JUNCTION_TOLERANCE` grid
    (a unary union at that grid size), which always converges. Noding them set to that
    precision (``shapely.set_precision``) instead still failed on most such sets (GEOS 3.11).

    >>> a = shapely.LineString([(0, 0), (10, 0)]); b = shapely.LineString([(5, -5), (5, 5)])
    >>> len(node_lines([a, b]))
    4
    """
    lines = shapely.multilinestrings(lines)
    try:
        return shapely.get_parts(shapely.node(lines))
    except shapely.errors.GEOSException:
        return shapely.get_parts(shapely.union_all(lines, grid_size=JUNCTION_TOLERANCE))


def renode(lines: Sequence, new: Sequence, priority: Sequence, min_length: float = 0.0):
    """A network with new lines added, noded again: the new lines' ends that nearly meet
    another end made one point (:func:`weld_ends`) and vertices of the lines they end on
    (:func:`snap_ends_onto_lines`), everything noded (:func:`node_lines`),
    pieces shorter than ``min_length`` m collapsed (:func:`collapse_short_pieces`: the
    pieces at both their ends meet, no gap is left), zero-length ones dropped. Returns
    (pieces, parent): the index of the line each piece came from (the lowest ``priority``
    where lines overlap), for carrying attributes over.

    Two new streets that end on a street at the same point up to round-off (3.5e-10 m
    apart, made by two interpolations) become two of its vertices, and noding cuts a piece
    that short between them; dropped, it left the two pairs of ends apart, a junction that a
    zero-tolerance network analysis reads as two:

    >>> road = shapely.LineString([(0, 0), (10, 0)])
    >>> north = shapely.LineString([(5, 5), (5, 0)])
    >>> south = shapely.LineString([(5 + 3e-10, -5), (5 + 3e-10, 0)])
    >>> pieces, parent = renode([road, north, south], [False, True, True], [0, 1, 1], 1e-6)
    >>> len(pieces), len(np.unique(shapely.get_coordinates(shapely.boundary(pieces)), axis=0))
    (4, 5)
    """
    lines = snap_ends_onto_lines(weld_ends(lines, new), new)
    pieces = node_lines(lines)
    if min_length > 0:
        pieces, _ = collapse_short_pieces(pieces, min_length)
    pieces = pieces[shapely.length(pieces) > 0]
    parent = _attach_attributes(pieces, lines, np.arange(len(lines)),
                                np.asarray(priority, dtype=np.int64))
    return pieces, parent


def collapse_short_pieces(pieces: Sequence, tolerance: float,
                          anchored: Optional[Sequence] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Noded pieces shorter than ``tolerance`` m dropped, the other pieces' ends at a dropped
    piece's last point moved to its first (along chains of them): round-off between two
    ends that noding set apart leaves no zero-length street and no gap. Returns (the kept
    pieces, which pieces were kept: for carrying their attributes over).

    ``anchored`` (a mask, optional): pieces that neither move nor vanish (given roads). A
    short piece that is not one of them collapses onto its end on one (between two, it is
    kept: collapsed, it would bend a road off its line); a short anchored piece is kept and
    the other pieces at its last point move to its first (two streets meeting a road from
    its two sides a fraction of a metre apart become one crossing, the road as it was).

    >>> a, b = shapely.LineString([(0, 0), (5, 0)]), shapely.LineString([(5, 0), (5, 1e-10)])
    >>> c = shapely.LineString([(5, 1e-10), (9, 0)])
    >>> kept, keep = collapse_short_pieces([a, b, c], 1e-6)
    >>> [p.wkt for p in kept], keep.tolist()
    (['LINESTRING (0 0, 5 0)', 'LINESTRING (5 0, 9 0)'], [True, False, True])

    A street's 0.5 m piece whose last point is on an anchored road collapses onto that point:

    >>> west, east = shapely.LineString([(0, 0), (5, 0)]), shapely.LineString([(5, 0), (9, 0)])
    >>> stub = shapely.LineString([(5, 0.5), (5, 0)])
    >>> street = shapely.LineString([(5, 9), (5, 0.5)])
    >>> kept, _ = collapse_short_pieces([west, east, stub, street], 1.0, [True, True, False, False])
    >>> [p.wkt for p in kept]
    ['LINESTRING (0 0, 5 0)', 'LINESTRING (5 0, 9 0)', 'LINESTRING (5 9, 5 0)']

    Two streets meeting that road 0.4 m apart, its piece between them anchored: one crossing.

    >>> mid = shapely.LineString([(5, 0), (5.4, 0)])
    >>> east = shapely.LineString([(5.4, 0), (9, 0)])
    >>> north = shapely.LineString([(5, 9), (5, 0)])
    >>> south = shapely.LineString([(5.4, -9), (5.4, 0)])
    >>> kept, keep = collapse_short_pieces([west, mid, east, north, south], 1.0, [1, 1, 1, 0, 0])
    >>> [p.wkt for p in kept[3:]], keep.all()
    (['LINESTRING (5 9, 5 0)', 'LINESTRING (5.4 -9, 5 0)'], True)
    """
    pieces = np.asarray(pieces, dtype=object)
    short = shapely.length(pieces) < tolerance
    fixed_piece = np.zeros(len(pieces), bool) if anchored is None else \
        np.asarray(anchored, dtype=bool)
    if not short.any():
        return pieces, ~short
    first = shapely.get_coordinates(shapely.get_point(pieces, 0))
    last = shapely.get_coordinates(shapely.get_point(pieces, -1))
    onto_all, onto_free = {}, {}   # last point -> first point: for every piece / free ones
    if fixed_piece.any():
        n_fixed = Counter(map(tuple, np.r_[first[fixed_piece], last[fixed_piece]]))
        free_at = {tuple(xy) for xy in np.r_[first[~fixed_piece], last[~fixed_piece]]}
        for i in np.flatnonzero(short):
            p, q = tuple(first[i]), tuple(last[i])
            if p == q:
                continue
            if fixed_piece[i]:
                # kept, the road as it was; the free pieces leave the end where it goes on
                # through one other anchored piece (a point of the road, then), for the
                # other end: never leaving it dangling
                if n_fixed[q] == 2 and q in free_at:
                    onto_free[q] = p
                elif n_fixed[p] == 2 and p in free_at:
                    onto_free[p] = q
                short[i] = False
            elif p in n_fixed and q in n_fixed:
                short[i] = False
            elif q in n_fixed:
                onto_all[p] = q
            else:
                onto_all[q] = p
    else:
        onto_all = {tuple(q): tuple(p) for p, q in zip(first[short], last[short])
                    if tuple(p) != tuple(q)}

    def target(xy, onto):
        seen = set()
        while xy in onto and xy not in seen:
            seen.add(xy)
            xy = onto[xy]
        return xy

    kept_idx = np.flatnonzero(~short)
    kept = pieces[kept_idx].copy()
    for j, i in enumerate(kept_idx):
        ends = (tuple(first[i]), tuple(last[i]))
        maps = (onto_all,) if fixed_piece[i] else (onto_all, onto_free)
        if not any(e in m for e in ends for m in maps):
            continue
        xyz = shapely.get_coordinates(kept[j], include_z=shapely.has_z(kept[j]))
        for k in (0, -1):
            xy = tuple(xyz[k, :2])
            for m in maps:
                xy = target(xy, m)
            xyz[k, :2] = xy
        kept[j] = shapely.set_coordinates(kept[j], xyz)
    return kept, ~short


def move_ends_onto_lines(lines: Sequence, onto: Sequence, tolerance: float) -> np.ndarray:
    """Move every line end within ``tolerance`` of a line of ``onto`` to its nearest point on
    that line (the lines of ``onto`` are not changed).

    A street ended on a cleaned copy of the given roads (coordinates rounded to the
    millimetre, near nodes merged) lies up to the cleaning's tolerance beside the roads the
    user gave: a millimetre beside is a crossing or a dead end there. Ends that share a
    point move together (they are projected the same way).

    >>> road = shapely.LineString([(0, 0), (10, 0)])
    >>> moved = move_ends_onto_lines([shapely.LineString([(5, 5), (5, -0.002)])], [road], 0.01)
    >>> moved[0].coords[-1]
    (5.0, 0.0)
    """
    lines = np.asarray(lines, dtype=object).copy()
    onto = np.asarray(onto, dtype=object)
    if not len(lines) or not len(onto):
        return lines
    coords = shapely.get_coordinates(lines)
    count = shapely.get_num_coordinates(lines)
    last = np.cumsum(count) - 1
    end_at = np.r_[last - count + 1, last]
    ends = shapely.points(coords[end_at])
    e_i, o_i = shapely.STRtree(onto).query_nearest(ends, max_distance=tolerance,
                                                   all_matches=False)
    if not len(e_i):
        return lines
    target = onto[o_i]
    moved = shapely.line_interpolate_point(target, shapely.line_locate_point(target, ends[e_i]))
    coords[end_at[e_i]] = shapely.get_coordinates(moved)
    owner = np.repeat(np.arange(len(lines)), count)
    return shapely.linestrings(coords, indices=owner)


def junction_points(nodes: np.ndarray, lines: Sequence) -> np.ndarray:
    """Each node at the nearest end point of ``lines``: the junction as the lines have it.

    A graph's nodes are rounded to the millimetre (:func:`graph_from_lines`' node key) or
    merged within a snap tolerance; a street drawn from one starts up to that far beside the
    street it should meet (0.3-0.6 mm on the syntheses' links and crossing streets until
    2026-12-06): a gap and a dangle to any GIS network tool. New streets start here instead.

    >>> line = shapely.LineString([(0.0004, 0.0004), (10.0004, 0.0004)])
    >>> junction_points(np.array([[0.0, 0.0], [10.0, 0.0]]), [line]).tolist()
    [[0.0004, 0.0004], [10.0004, 0.0004]]
    """
    lines = np.asarray(lines, dtype=object)
    nodes = np.asarray(nodes, dtype=float).reshape(-1, 2)
    if not len(lines) or not len(nodes):
        return nodes.copy()
    ends = shapely.get_coordinates(np.concatenate([shapely.get_point(lines, 0),
                                                   shapely.get_point(lines, -1)]))
    _, nearest = shapely.STRtree(shapely.points(ends)).query_nearest(
        shapely.points(nodes), all_matches=False)
    return ends[nearest]


def weld_ends(geometry: Sequence, new: Optional[Sequence] = None,
              tolerance: float = JUNCTION_TOLERANCE) -> np.ndarray:
    """Line ends that lie within ``tolerance`` of each other made one point: each group's
    ends of the ``new`` lines (a mask, default all) moved onto one of them, an end of a line
    that is not new where the group has one (those stay as they are).

    Two pieces of one warped street that should meet end to end came out 9.3e-10 m apart
    (Eschen's fragments, seed 1): :func:`snap_ends_onto_lines` takes an end that close to a
    vertex for one on it, and noding leaves two dead ends facing each other, which a
    zero-tolerance network analysis reads as a gap.

    >>> a = shapely.LineString([(0, 0), (5, 0)])
    >>> b = shapely.LineString([(5, 9e-10), (9, 0)])
    >>> [g.wkt for g in weld_ends([a, b], [False, True])]
    ['LINESTRING (0 0, 5 0)', 'LINESTRING (5 0, 9 0)']
    """
    geometry = np.asarray(geometry, dtype=object).copy()
    n = len(geometry)
    new = np.ones(n, dtype=bool) if new is None else np.asarray(new, dtype=bool)
    if n < 2 or not new.any():
        return geometry
    ends = shapely.get_coordinates(np.concatenate([shapely.get_point(geometry, 0),
                                                   shapely.get_point(geometry, -1)]))
    pairs = cKDTree(ends).query_pairs(tolerance, output_type="ndarray")
    pairs = pairs[(ends[pairs[:, 0]] != ends[pairs[:, 1]]).any(axis=1)] if len(pairs) else pairs
    if not len(pairs):
        return geometry
    _, group = connected_components(coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(2 * n, 2 * n)),
        directed=False)
    movable = np.r_[new, new]
    touched = np.zeros(2 * n, bool)
    touched[pairs.ravel()] = True
    # per group, the point its ends go to: a fixed end's (the lowest index), else the first
    anchor = {}
    for k in np.flatnonzero(touched):
        g = group[k]
        if g not in anchor or (not movable[k] and movable[anchor[g]]):
            anchor[g] = k
    for line in np.unique(np.flatnonzero(touched & movable) % n):
        xyz = shapely.get_coordinates(geometry[line], include_z=shapely.has_z(geometry[line]))
        for k, row in ((line, 0), (line + n, -1)):
            if touched[k] and anchor[group[k]] != k:
                xyz[row, :2] = ends[anchor[group[k]]]
        geometry[line] = shapely.set_coordinates(geometry[line], xyz)
    return geometry


def close_short_gaps(geometry: Sequence, new: Sequence, tolerance: float
                     ) -> Tuple[np.ndarray, np.ndarray]:
    """The network as a tool without topology tolerance reads it, made what a tolerance of
    ``tolerance`` m reads (the network invariants' and the statistics' 0.5 m): ends of the
    ``new`` lines within it of another end made one point (:func:`weld_ends`), then new lines
    it made a point or a loop shorter than twice the tolerance (a street of a few
    decimetres between two junctions), new dead-end lines shorter than it (a stub beside
    a junction) and new lines it made a double of another between the same two points
    (within the tolerance) left out. Returns (the lines, which are kept).

    Synthesised networks kept such places where two steps met within the tolerance: on the
    fidelity benchmark's towns a street ending 7-39 cm from a junction or from another
    street's end, a street of 27 cm between two junctions (StreetGAN, fragments; 0-3 per
    run), a dead end or a degree-5 junction to QGIS's network analysis.

    >>> road = shapely.LineString([(0, 0), (10, 0)])
    >>> gap = shapely.LineString([(10.2, 0), (20, 0)])       # 20 cm short of the road's end
    >>> stub = shapely.LineString([(10, 0), (10, 0.1)])      # 10 cm dead end at a junction
    >>> lines, keep = close_short_gaps([road, gap, stub], [False, True, True], 0.5)
    >>> [g.wkt for g in lines], keep.tolist()
    (['LINESTRING (0 0, 10 0)', 'LINESTRING (10 0, 20 0)'], [True, True, False])
    >>> beside = shapely.LineString([(0, 0), (9.7, 0.05)])  # welded onto the road's end
    >>> close_short_gaps([road, beside], [False, True], 0.5)[1].tolist()
    [True, False]
    """
    geometry = weld_ends(geometry, new, tolerance)
    new = np.asarray(new, dtype=bool)
    first = shapely.get_coordinates(shapely.get_point(geometry, 0))
    last = shapely.get_coordinates(shapely.get_point(geometry, -1))
    length = shapely.length(geometry)
    collapsed = new & (first == last).all(axis=1) & (length < 2 * tolerance)
    ends = np.concatenate([first, last])
    _, inverse, count = np.unique(ends, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    n = len(geometry)
    dead = (count[inverse[:n]] == 1) | (count[inverse[n:]] == 1)
    keep = ~(collapsed | (new & dead & (length < tolerance)))
    # a new line that now joins the same two points as another, along it (a short street
    # beside a given road whose end was welded onto the road's): the other one stays
    pair = np.sort(np.column_stack([inverse[:n], inverse[n:]]), axis=1)
    order = np.lexsort((new, pair[:, 1], pair[:, 0]))   # per pair, lines not new first
    for a, b in zip(order[:-1], order[1:]):
        if keep[a] and keep[b] and new[b] and (pair[a] == pair[b]).all() and \
                shapely.hausdorff_distance(geometry[a], geometry[b]) < tolerance:
            keep[b] = False
    return geometry[keep], keep


def snap_ends_onto_lines(geometry: Sequence, new: Optional[Sequence] = None,
                         tolerance: float = JUNCTION_TOLERANCE) -> np.ndarray:
    """Make every line end that lies on another line (up to ``tolerance``) a vertex of it.

    An end point put onto a line by interpolation lies on it only up to round-off
    (1e-9 m .. 1e-4 m), and a street may pass a junction at a micrometre; noding would leave
    the end dangling next to the edge (a dead end and a lost junction), or the street
    crossing the junction without meeting it. GEOS snapping inserts the points as vertices,
    so that both lines share them exactly. With ``new`` (a mask), only pairs with a new
    line take part (the rest is already noded).

    >>> a = shapely.LineString([(0, 0), (10, 0)]); b = shapely.LineString([(5, 5), (5, 1e-5)])
    >>> len(shapely.get_parts(shapely.node(shapely.multilinestrings([a, b]))))
    2
    >>> snapped = snap_ends_onto_lines([a, b])
    >>> len(shapely.get_parts(shapely.node(shapely.multilinestrings(snapped))))
    3
    """
    geometry = np.asarray(geometry, dtype=object).copy()
    n = len(geometry)
    new = np.ones(n, dtype=bool) if new is None else np.asarray(new, dtype=bool)
    if n < 2 or not new.any():
        return geometry
    ends = np.concatenate([shapely.get_point(geometry, 0), shapely.get_point(geometry, -1)])
    owner = np.r_[np.arange(n), np.arange(n)]
    e_i, l_i = shapely.STRtree(geometry).query(ends, predicate="dwithin", distance=tolerance)
    keep = (owner[e_i] != l_i) & (new[owner[e_i]] | new[l_i])
    e_i, l_i = e_i[keep], l_i[keep]
    if not len(e_i):
        return geometry
    # an end already on a vertex of the line needs nothing
    on_vertex = shapely.dwithin(ends[e_i], shapely.extract_unique_points(geometry[l_i]), 1e-9)
    e_i, l_i = e_i[~on_vertex], l_i[~on_vertex]
    if not len(e_i):
        return geometry
    order = np.argsort(l_i, kind="stable")
    e_i, l_i = e_i[order], l_i[order]
    lines, first = np.unique(l_i, return_index=True)
    group = np.repeat(np.arange(len(lines)), np.diff(np.r_[first, len(l_i)]))
    pts = shapely.multipoints(shapely.get_coordinates(ends[e_i]), indices=group)
    geometry[lines] = shapely.snap(geometry[lines], pts, tolerance)
    return geometry


def ends_as_vertices(lines: Sequence, new_lines: Sequence,
                     tolerance: float = JUNCTION_TOLERANCE) -> np.ndarray:
    """``lines`` with every end of ``new_lines`` that lies on one (within ``tolerance``) as
    a vertex of it (:func:`snap_ends_onto_lines`); the new lines are not changed. A tool
    that builds its graph from vertices (QGIS's network analysis) joins lines only there.

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> ends_as_vertices([road], [shapely.LineString([(40, 50), (40, 0)])])[0].wkt
    'LINESTRING (0 0, 40 0, 100 0)'
    """
    lines = np.asarray(lines, dtype=object)
    new_lines = np.asarray(new_lines, dtype=object)
    if not len(lines) or not len(new_lines):
        return lines.copy()
    both = snap_ends_onto_lines(np.concatenate([lines, new_lines]),
                                np.r_[np.zeros(len(lines), bool), np.ones(len(new_lines), bool)],
                                tolerance)
    return both[:len(lines)]


def split_at_ends(lines: Sequence, new_lines: Sequence,
                  tolerance: float = JUNCTION_TOLERANCE) -> np.ndarray:
    """``lines`` cut where an end of ``new_lines`` lies on one (:func:`ends_as_vertices`),
    each piece ending at that end exactly. ``lines`` are not noded with each other (a
    bridge over a road stays one). Returns the pieces, in the order of ``lines``.

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> [g.wkt for g in split_at_ends([road], [shapely.LineString([(40, 50), (40, 1e-7)])])]
    ['LINESTRING (0 0, 40 0.0000001)', 'LINESTRING (40 0.0000001, 100 0)']
    """
    lines = ends_as_vertices(lines, new_lines, tolerance)
    new_lines = np.asarray(new_lines, dtype=object)
    if not len(lines) or not len(new_lines):
        return lines
    ends = np.unique(shapely.get_coordinates(shapely.boundary(new_lines)), axis=0)
    tree = cKDTree(ends)
    pieces = []
    for g in lines:
        xy = shapely.get_coordinates(g)
        # a vertex within 1e-9 m of an end was taken for it (snap_ends_onto_lines): the
        # end's own coordinates there
        gap, near = tree.query(xy[1:-1], distance_upper_bound=1e-9)
        cut = np.flatnonzero(np.isfinite(gap)) + 1
        if not len(cut):
            pieces.append(g)
            continue
        xy[cut] = ends[near[cut - 1]]
        bounds = np.r_[0, cut, len(xy) - 1]
        pieces.extend(shapely.LineString(xy[a:b + 1]) for a, b in zip(bounds[:-1], bounds[1:]))
    return np.asarray(pieces, dtype=object)


def clean_network(geometries: Sequence, road_class: Optional[Sequence] = None,
                  name: Optional[Sequence] = None, z_layer: Optional[Sequence] = None,
                  snap_tolerance: float = 1.0, min_dangle_length: float = 5.0,
                  merge_degree2: bool = True, duplicate_tolerance: Optional[float] = None,
                  progress: Optional[Progress] = None) -> RoadGraph:
    """Turn raw road lines into a clean planar :class:`RoadGraph`.

    Parameters
    ----------
    geometries : array of LineString / MultiLineString in a metric CRS
    road_class, name, z_layer : per-line attributes (optional)
    snap_tolerance : float
        Nodes closer than this (metres) are merged, in groups no wider than it
        (:func:`snap_clusters`: a row of nodes each this close to the next is not chained
        into one, so no end moves farther than it); an edge that merging makes cross another
        is noded at the crossing. Duplicates are edges with the same end nodes whose
        Hausdorff distance is under it. Above 0, a line end within
        :data:`JUNCTION_TOLERANCE` of another line also joins it (a junction, not a dead
        end beside the line); 0 is the plain noding of the lines as they are.
    min_dangle_length : float
        Dead-end edges shorter than this are removed (dangling slivers of OSM digitising).
    merge_degree2 : bool
        Merge chains through nodes of degree 2 into one edge (of one vertical layer).
    duplicate_tolerance : float, optional
        Edges between the same nodes within this Hausdorff distance (m) are one street;
        default ``max(snap_tolerance, 0.5)``. 0 drops only exact duplicates (a plain count).

    Returns
    -------
    RoadGraph

    References
    ----------
    Hartmann, thesis ch. 4.1.2; Aliaga, Vanegas, Benes 2008, sec. 5.
    """
    progress = ensure(progress)
    if snap_tolerance < 0 or min_dangle_length < 0:
        raise InputError("tolerances must not be negative")
    geoms = np.asarray(geometries, dtype=object)
    n_in = len(geoms)
    if n_in == 0:
        raise InputError("no line features")
    road_class = np.asarray(road_class if road_class is not None else [None] * n_in, dtype=object)
    name = np.asarray(name if name is not None else [None] * n_in, dtype=object)
    zl = np.asarray(z_layer if z_layer is not None else np.zeros(n_in), dtype=np.int64)

    # 1. single-part, non-empty, 2D lines
    parts, part_src = shapely.get_parts(geoms, return_index=True)
    parts = shapely.force_2d(parts)
    keep = (shapely.get_type_id(parts) == 1) & ~shapely.is_empty(parts)
    parts, part_src = parts[keep], part_src[keep]
    keep = shapely.length(parts) > 0
    parts, part_src = parts[keep], part_src[keep]
    if len(parts) == 0:
        raise InputError("no line geometries with a length")
    progress.step(0.05)

    # 2. node at real crossings, per vertical layer
    rank = np.array([class_rank(c) for c in road_class], dtype=np.int64)
    pieces_all, src_all = [], []
    layers = np.unique(zl[part_src])
    for k, layer in enumerate(layers):
        sel = np.flatnonzero(zl[part_src] == layer)
        # an end within a millimetre of another line is a junction, as for the invariants
        # (snapping off, 0: the plain noding count)
        layer_parts = snap_ends_onto_lines(parts[sel], tolerance=min(
            JUNCTION_TOLERANCE, snap_tolerance)) if snap_tolerance > 0 else parts[sel]
        noded = node_lines(layer_parts)
        noded = noded[shapely.length(noded) > 0]
        pieces_all.append(noded)
        src_all.append(_attach_attributes(noded, parts[sel], part_src[sel], rank[part_src[sel]]))
        progress.step(0.05 + 0.3 * (k + 1) / len(layers))
    pieces = np.concatenate(pieces_all)
    src = np.concatenate(src_all)

    # 3. connect layers where they share an OSM node: split at interior vertices that are
    #    endpoints of other pieces (within one layer noding already did this)
    if len(layers) > 1:
        a, b = _endpoints(pieces)
        ends = np.vstack([a, b])

        def at_endpoint(coords):
            _, ids = _node_ids(np.vstack([ends, coords]))
            return np.isin(ids[len(ends):], ids[:len(ends)])

        pieces, parent = _split_at_vertices(pieces, at_endpoint)
        src = src[parent]
    progress.step(0.4)

    graph = graph_from_lines(pieces, road_class[src], name[src], zl[src], src,
                             snap_tolerance=snap_tolerance)
    progress.step(0.55)
    graph = _drop_duplicates(graph, max(snap_tolerance, 0.5) if duplicate_tolerance is None
                             else duplicate_tolerance)
    progress.step(0.65)
    if min_dangle_length > 0:
        graph = _prune_dangles(graph, min_dangle_length)
    progress.step(0.75)
    if merge_degree2:
        graph = merge_degree2_chains(graph)
    progress.step(1.0)
    if graph.n_edges == 0:
        raise InputError("no road edges are left after cleaning")
    return graph


def measured_graph(lines: Sequence, snap_tolerance: float, z_layer: Optional[Sequence] = None,
                   progress: Optional[Progress] = None) -> RoadGraph:
    """The street graph the statistics and shares count (``layoutmetrics``, the invariants'
    degrees, the crossing steering): noded, nodes closer than ``snap_tolerance`` merged,
    chains through degree-2 nodes dissolved, doubled edges dropped; no dangle pruned (a
    network's own dead ends are part of what is measured)."""
    return clean_network(lines, z_layer=z_layer, snap_tolerance=snap_tolerance,
                         min_dangle_length=0.0, merge_degree2=True,
                         duplicate_tolerance=snap_tolerance, progress=progress)


def snap_clusters(points: np.ndarray, tolerance: float) -> Optional[np.ndarray]:
    """Groups of points to merge into one node: a label per point (0, 1, ...), points of one
    label no farther than ``tolerance`` apart, so that none moves farther than it onto the
    group's centroid; None when no two points are that close.

    Points closer than ``tolerance`` are grouped (connected components of their pairs);
    a group of more than two points is split by complete-linkage clustering cut at
    ``tolerance`` (scipy.cluster.hierarchy). Chained, the pairs merged every node of a dense
    street network within reach: at 50 m, Helsinki's points 838 m apart and a node moved by
    481 m. Two points closer than ``tolerance`` can still stay apart, each with a closer one.

    Four dead ends in a row, 8 m apart, at 10 m: two nodes, not one 24 m wide.

    >>> snap_clusters(np.array([[0.0, 0], [8, 0], [16, 0], [24, 0]]), 10.0).tolist()
    [0, 0, 1, 1]
    """
    pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
    if not len(pairs):
        return None
    n = len(points)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_label, label = connected_components(adj, directed=False)
    counts = np.bincount(label)
    # complete linkage caps a group's width at the cut (single linkage chains); a pair needs none
    wide = np.flatnonzero(counts > 2)
    if len(wide):
        order = np.argsort(label, kind="stable")
        start = np.r_[0, np.cumsum(counts)]
        for c in wide:
            members = order[start[c]:start[c + 1]]
            sub = fcluster(linkage(points[members], "complete"), t=tolerance,
                           criterion="distance")
            # the first group keeps the component's label, the others are numbered on
            label[members] = np.where(sub == 1, c, n_label + sub - 2)
            n_label += sub.max() - 1
    return label


def graph_from_lines(lines: np.ndarray, road_class, name, z_layer, source,
                     snap_tolerance: float = 0.0, min_loop: Optional[float] = None) -> RoadGraph:
    """Build a :class:`RoadGraph` from already noded lines, snapping close end nodes together.

    Snapping moves every end of a merged node onto the cluster's centroid, and the edge's
    last segment swings with it: across an edge that passed between the merged nodes, or
    across itself. Such edges are noded again (:func:`_renode_crossed`), so that the graph
    stays planar: every crossing of two edges of one vertical layer is a node.

    Two dead ends 5 m apart on either side of a road, merged at 10 m: the road is crossed,
    and the crossing is a node of degree 4 (the two halves of the street merge later, in
    :func:`clean_network`, through the degree-2 node left where they meet):

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> north = shapely.LineString([(50, 50), (50, 2)])
    >>> south = shapely.LineString([(50, -50), (50, -3)])
    >>> g = graph_from_lines([road, north, south], [None] * 3, [None] * 3, [0] * 3, [0, 1, 2], 10.0)
    >>> g.n_edges, sorted(g.degree.tolist())
    (5, [1, 1, 1, 1, 2, 4])
    """
    lines = np.asarray(lines, dtype=object)
    road_class = np.asarray(road_class, dtype=object)
    name = np.asarray(name, dtype=object)
    z_layer, source = np.asarray(z_layer), np.asarray(source)
    m = len(lines)
    a, b = _endpoints(lines)
    ends = np.vstack([a, b])
    nodes, inv = _node_ids(ends)
    moved = np.zeros(m, dtype=bool)
    if snap_tolerance > 0 and len(nodes) > 1:
        label = snap_clusters(nodes, snap_tolerance)
        if label is not None:
            counts = np.bincount(label)
            centroid = np.column_stack([np.bincount(label, nodes[:, 0]) / counts,
                                        np.bincount(label, nodes[:, 1]) / counts])
            merged = counts[label[inv]] > 1
            moved = merged[:m] | merged[m:]
            inv = label[inv]
            nodes = centroid
            # move the line ends onto the merged node
            lines = pinned_ends(lines, nodes[inv[:m]], nodes[inv[m:]])
    u, v = inv[:m].astype(np.int64), inv[m:].astype(np.int64)
    # zero-length loops left by snapping (``min_loop``: those of the snapping before a
    # re-noding, which leaves some of its own)
    min_loop = max(snap_tolerance, 1e-9) * 2 if min_loop is None else min_loop
    keep = ~((u == v) & (shapely.length(lines) <= min_loop))
    if moved[keep].any():
        renoded = _renode_crossed(lines[keep], z_layer[keep], road_class[keep], moved[keep])
        if renoded is not None:
            lines, parent = renoded
            parent = np.flatnonzero(keep)[parent]
            return graph_from_lines(lines, road_class[parent], name[parent], z_layer[parent],
                                    source[parent], min_loop=min_loop)
    g = RoadGraph(lines[keep], u[keep], v[keep], road_class[keep], name[keep], z_layer[keep],
                  nodes, source[keep])
    return _compact_nodes(g)


def _renode_crossed(lines: np.ndarray, z_layer: np.ndarray, road_class: np.ndarray,
                    moved: np.ndarray) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """The lines noded again where a ``moved`` one (an end snapped) now touches a line of
    its vertical layer (or itself) elsewhere than at an end both share, per layer
    (:func:`renode`, the moved lines as the new ones); None when none does. Returns
    (lines, parent): each line's index in ``lines``, in their order.
    """
    moved_idx = np.flatnonzero(moved)
    i, j = shapely.STRtree(lines).query(lines[moved_idx], predicate="intersects")
    i = moved_idx[i]
    sel = (i != j) & (z_layer[i] == z_layer[j])
    i, j = i[sel], j[sel]
    a, b = _endpoints(lines)
    ends = shapely.multipoints(np.stack([a, b], axis=1))
    touch = shapely.intersection(lines[i], lines[j])
    stray = ~(shapely.covers(ends[i], touch) & shapely.covers(ends[j], touch))
    crossed = np.zeros(len(lines), dtype=bool)
    crossed[i[stray]] = crossed[j[stray]] = True
    crossed |= moved & ~shapely.is_simple(lines)
    if not crossed.any():
        return None
    rank = np.array([class_rank(c) for c in road_class], dtype=np.int64)
    out, parent = [lines[~crossed]], [np.flatnonzero(~crossed)]
    for layer in np.unique(z_layer[crossed]):
        sel = np.flatnonzero(crossed & (z_layer == layer))
        pieces, src = renode(lines[sel], moved[sel], rank[sel])
        out.append(pieces)
        parent.append(sel[src])
    lines, parent = np.concatenate(out), np.concatenate(parent)
    order = np.argsort(parent, kind="stable")
    return lines[order], parent[order]


def _compact_nodes(g: RoadGraph) -> RoadGraph:
    used = np.unique(np.concatenate([g.u, g.v]))
    remap = np.full(len(g.nodes), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return RoadGraph(g.geometry, remap[g.u], remap[g.v], g.road_class, g.name, g.z_layer,
                     g.nodes[used], g.source)


def _subset(g: RoadGraph, keep: np.ndarray) -> RoadGraph:
    return _compact_nodes(RoadGraph(g.geometry[keep], g.u[keep], g.v[keep], g.road_class[keep],
                                    g.name[keep], g.z_layer[keep], g.nodes, g.source[keep]))


def _drop_duplicates(g: RoadGraph, tolerance: float) -> RoadGraph:
    """Drop edges that repeat another between the same nodes (keeps the more important class)."""
    lo, hi = np.minimum(g.u, g.v), np.maximum(g.u, g.v)
    key = lo * (len(g.nodes) + 1) + hi
    order = np.lexsort((g.class_rank, key))
    sk = key[order]
    dup_groups = np.flatnonzero(np.r_[False, sk[1:] == sk[:-1]])
    if len(dup_groups) == 0:
        return g
    drop = np.zeros(g.n_edges, dtype=bool)
    tol = tolerance
    starts = np.unique(np.searchsorted(sk, sk[dup_groups]))
    for s in starts:
        e = s
        while e + 1 < len(sk) and sk[e + 1] == sk[s]:
            e += 1
        members = order[s:e + 1]
        kept = []
        for i in members:  # members are sorted by class rank: keep the first of each look-alike
            if any(shapely.hausdorff_distance(g.geometry[i], g.geometry[j]) <= tol for j in kept):
                drop[i] = True
            else:
                kept.append(i)
    return _subset(g, ~drop)


def _prune_dangles(g: RoadGraph, min_length: float) -> RoadGraph:
    """Remove dead-end edges shorter than ``min_length`` (one pass, then once more for chains)."""
    for _ in range(2):
        deg = g.degree
        dangling = ((deg[g.u] == 1) ^ (deg[g.v] == 1)) & (g.length < min_length)
        if not dangling.any():
            break
        g = _subset(g, ~dangling)
    return g


def degree2_chains(u: np.ndarray, v: np.ndarray, n_nodes: int,
                   key: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
    """The chains of edges through nodes of degree 2: a component label per edge (the two
    edges at every such node joined; with ``key``, one per edge, only edges of one key), or
    None when no two edges join.

    >>> degree2_chains(np.array([0, 1, 2]), np.array([1, 2, 3]), 4).tolist()
    [0, 0, 0]
    >>> degree2_chains(np.array([0, 1, 2]), np.array([1, 2, 3]), 4, np.array(["a", "a", "b"])).tolist()
    [0, 0, 1]
    """
    m = len(u)
    inc_node = np.r_[u, v]
    inc_edge = np.r_[np.arange(m), np.arange(m)]
    sel = np.bincount(inc_node, minlength=n_nodes)[inc_node] == 2
    order = np.argsort(inc_node[sel], kind="stable")
    pairs = inc_edge[sel][order].reshape(-1, 2)
    ok = pairs[:, 0] != pairs[:, 1]  # a self-loop on a degree-2 node is a ring: no join
    if key is not None:
        ok &= key[pairs[:, 0]] == key[pairs[:, 1]]
    if not ok.any():
        return None
    adj = coo_matrix((np.ones(ok.sum()), (pairs[ok, 0], pairs[ok, 1])), shape=(m, m))
    n_comp, comp = connected_components(adj, directed=False)
    return comp if n_comp < m else None


def merge_degree2_chains(g: RoadGraph) -> RoadGraph:
    """Merge edges through nodes of degree 2 (OSM splits ways at arbitrary points).

    Attributes of a merged edge come from its longest part. Only edges of one vertical layer
    merge: a bridge joined to its approach would take the longer part's layer, and the
    crossing it spans would read as one without a junction.
    """
    deg = g.degree
    comp = degree2_chains(g.u, g.v, len(g.nodes), g.z_layer)
    if comp is None:
        return g
    lengths = g.length
    by_comp = np.argsort(comp, kind="stable")
    # line_merge joins ends that are equal: the ends at one node (one to the millimetre) may
    # differ below it, and a chain that failed to merge kept only its first piece (the
    # others vanished, their node a false dead end). Every end goes onto one of its node's
    # own end points, not the node's millimetre-rounded coordinate: ends that were equal
    # stay exactly where they were (the plain noding count is unchanged)
    at = np.empty_like(g.nodes)
    at[g.v] = shapely.get_coordinates(shapely.get_point(g.geometry, -1))
    at[g.u] = shapely.get_coordinates(shapely.get_point(g.geometry, 0))
    exact = pinned_ends(g.geometry, at[g.u], at[g.v])
    merged = shapely.line_merge(shapely.multilinestrings(exact[by_comp], indices=comp[by_comp]))
    # representative (longest) member of each component carries the attributes
    order = np.lexsort((-lengths, comp))
    rep = order[np.r_[True, comp[order][1:] != comp[order][:-1]]]
    # a merge can only fail to give one line for a chain of pieces that do not touch
    single = shapely.get_type_id(merged) == 1
    if not single.all():
        merged = np.where(single, merged, shapely.get_geometry(merged, 0))
    merged = _loops_start_at_their_node(merged, g, comp, deg)
    # a loop under a millimetre, pinned onto its node, is a point: no street
    kept = ~(shapely.is_missing(merged) | shapely.is_empty(merged))
    merged, rep = merged[kept], rep[kept]
    return graph_from_lines(merged, g.road_class[rep], g.name[rep], g.z_layer[rep], g.source[rep])


def _loops_start_at_their_node(merged: np.ndarray, g: RoadGraph, comp: np.ndarray,
                               deg: np.ndarray) -> np.ndarray:
    """Rotate merged rings so that they start at the junction they hang from.

    A loop hanging off a junction P (edges P-a, a-b, b-P) merges into one closed line, and
    ``line_merge`` may start it at a or b: P would lose its loop and become a dead end. Such
    loops are rare (a few per city), so they are fixed one by one.
    """
    closed = np.flatnonzero(shapely.is_closed(merged) & (shapely.get_num_points(merged) > 3))
    if not len(closed):
        return merged
    merged = merged.copy()
    ends = np.concatenate([g.u, g.v])
    owner = np.concatenate([comp, comp])
    for c in closed:
        anchor = np.unique(ends[(owner == c) & (deg[ends] != 2)])
        if not len(anchor):
            continue  # an isolated ring: any start will do
        xy = shapely.get_coordinates(merged[c])[:-1]
        at = np.flatnonzero(np.hypot(*(xy - g.nodes[anchor[0]]).T) < 1e-3)  # nodes: mm
        if len(at) and at[0] != 0:
            ring = np.roll(xy, -at[0], axis=0)
            merged[c] = shapely.linestrings(np.vstack([ring, ring[:1]]))
    return merged


def synthesised(level: np.ndarray, source_fragment: np.ndarray) -> np.ndarray:
    """Which lines of an attributed network (the fragment synthesis') the synthesis made:
    above level 0, and neither a given arterial nor the boundary ring that closed the sketch.

    >>> synthesised(np.array([0, 1, 1, 2]), np.array(["arterial", "f:3", "boundary", "link"],
    ...                                               dtype=object)).tolist()
    [False, True, False, True]
    """
    return (np.asarray(level) > 0) & \
        ~np.isin(np.asarray(source_fragment, dtype=object), ("arterial", "boundary"))


def renode_attributed(geometry: np.ndarray, level: np.ndarray, attrs: Dict[str, np.ndarray],
                      new_level: int, min_dangle: float):
    """One planar network from existing edges and new streets, attributes carried over.

    ``attrs`` are a synthesised street's provenance (the fragment synthesis' edge fields:
    ``source_fragment``, ``database``, ``fragment_id``, ``query``), one array each per line.

    Nodes everything (:func:`network.street_graph.node_lines`), gives each piece the
    attributes of its parent line (the lowest level wins where lines overlap), prunes new dead
    ends shorter than ``min_dangle`` and merges chains through degree-2 nodes whose two edges
    share level and source.
    """
    pieces, parent = renode(geometry, level == new_level, level, min_length=1e-6)
    g = graph_from_lines(pieces, np.full(len(pieces), None, object),
                                np.full(len(pieces), None, object), np.zeros(len(pieces), int),
                                parent, snap_tolerance=0.0)
    geom, u, v, src = g.geometry, g.u, g.v, g.source
    lvl = level[src]
    for _ in range(3):  # prune short new dead ends (chains of them in a few rounds)
        deg = np.bincount(np.r_[u, v], minlength=len(g.nodes))
        short = (lvl == new_level) & ((deg[u] == 1) | (deg[v] == 1)) & \
            (shapely.length(geom) < min_dangle)
        if not short.any():
            break
        keep = ~short
        geom, u, v, src, lvl = geom[keep], u[keep], v[keep], src[keep], lvl[keep]
    # merge degree-2 chains of one source
    key = np.array([f"{lvl[i]}|{attrs['source_fragment'][s]}|{attrs['query'][s]}"
                    for i, s in enumerate(src)], dtype=object)
    comp = degree2_chains(u, v, len(g.nodes), key)
    if comp is not None:
        geom, rows = merge_chains(geom, comp)
        src = src[rows]
    return geom, src


def merge_chains(lines: np.ndarray, comp: np.ndarray, longest: bool = False):
    """Lines joined chain by chain (``comp``: a chain label 0..k-1 per line, as
    :func:`degree2_chains` gives them): (the joined lines, the row of ``lines`` whose
    attributes each keeps: its chain's first line, or its longest with ``longest``). A chain
    that does not join into one line (a ring, pieces that do not touch) keeps its lines.

    >>> parts = np.array([shapely.LineString([(0, 0), (1, 0)]),
    ...                   shapely.LineString([(1, 0), (3, 0)]),
    ...                   shapely.LineString([(5, 5), (6, 5)])])
    >>> lines, rows = merge_chains(parts, np.array([0, 0, 1]), longest=True)
    >>> [round(g.length) for g in lines], rows.tolist()
    ([3, 1], [1, 2])
    """
    lines = np.asarray(lines, dtype=object)
    by = np.argsort(comp, kind="stable")
    merged = shapely.line_merge(shapely.multilinestrings(lines[by], indices=comp[by]))
    single = shapely.get_type_id(merged) == 1
    order = np.lexsort((-shapely.length(lines), comp)) if longest else by
    rep = order[np.r_[True, comp[order][1:] != comp[order][:-1]]]
    apart = np.isin(comp, np.flatnonzero(~single))
    return (np.concatenate([merged[single], lines[apart]]),
            np.concatenate([rep[single], np.flatnonzero(apart)]))


def add_streets(geometry, level, attrs, new_geoms, new_attrs, new_level: int,
                min_dangle: float):
    """Add new streets (one array per face, attributes per face: source, database, fragment
    id, count, query) and re-node the network (:func:`renode_attributed`)."""
    sizes = [a[3] for a in new_attrs]
    add = np.concatenate(new_geoms)
    geometry_all = np.concatenate([geometry, add])
    level_all = np.concatenate([level, np.full(len(add), new_level)])
    attrs_all = {
        "source_fragment": np.concatenate([attrs["source_fragment"], np.repeat(
            np.array([a[0] for a in new_attrs], dtype=object), sizes)]),
        "database": np.concatenate([attrs["database"], np.repeat(
            np.array([a[1] for a in new_attrs], dtype=object), sizes)]),
        "fragment_id": np.concatenate([attrs["fragment_id"], np.repeat(
            np.array([a[2] for a in new_attrs], dtype=np.int64), sizes)]),
        "query": np.concatenate([attrs["query"], np.repeat(
            np.array([a[4] for a in new_attrs], dtype=np.int64), sizes)]),
    }
    geometry, src = renode_attributed(geometry_all, level_all, attrs_all, new_level,
                                      min_dangle)
    return geometry, level_all[src], {k: v[src] for k, v in attrs_all.items()}
