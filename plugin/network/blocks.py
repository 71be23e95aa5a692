"""City blocks: the faces of the planar street graph, with shape measures and contents.

Hartmann's thesis defines a city block as a minimal cycle of the planar street graph
(ch. 4.1.2: "a fragment whose interior has only dead-end streets is stored as a city
block"; ch. 5.1: "query blocks are the minimal cycles of the input street graph", a block
being D = (B, P), its boundary polygon and its footprints). The minimal cycles of a planar
embedded graph are its bounded faces, so blocks are the faces of the noded street edges,
traced on their half-edge structure (:func:`planar_faces`, the same faces as
``shapely.polygonize`` in linear time): edges that bound no face (dead-end streets and the
bridges of the graph between two loops) lie inside a block and do not split it, as in the
thesis. Every drivable edge bounds blocks whatever its vertical layer (the thesis's street
graph is planar; bridges and tunnels of city streets are short).

Real OSM makes artefact faces (docs/ARCHITECTURE.md, "Real example data"): dual carriageways, slip
roads and traffic islands close small or thin faces that are road surface, not blocks.
A face is dropped when its area is under ``min_area`` or its mean width ``2 * area /
perimeter`` (the width of a long strip) is under ``min_width``; the thesis does the same
for its raster artefacts (ch. 4.2, "delete the artefact blocks of area 0.5 px²"). The island
inside a roundabout (OSM ``junction=roundabout``, when the roads say which they are) is
road furniture too, however large: a face whose outline lies wholly on roundabout roads is
dropped (:func:`roundabout_islands`). Without the tag (a synthesised network) such an
island stays a block, and the parcel and footprint stages build on none of what is left of
it once the road surface is off: land under :data:`core.geometry.MIN_BUILDABLE_AREA` or
nowhere :data:`core.geometry.MIN_BUILDABLE_WIDTH` wide is no building land.

Buildings and parcels are assigned to at most one block each: the block that holds the
largest share of their area, if that share is at least ``min_share`` (a half by default).
Features outside every closed block (the extract is clipped, so many lie beyond the
outermost street loop: only 62 % of Helsinki's buildings are inside a face closed by
drivable roads, docs/ARCHITECTURE.md) keep no block: ``block_id`` is missing and ``in_block`` False.
They are kept, not deleted, so the caller decides what to do with them.

Shape measures follow the thesis (ch. 4.2 evaluation): compactness = block area / area of
the minimum bounding rectangle, aspect ratio = shorter / longer side of that rectangle.

Everything is vectorised with shapely 2 / numpy, with no Python loop over edges, faces or
features; the minimum-area rectangles are rotating calipers done by binary search on the
convex hulls' edge angles (GEOS 3.11's oriented envelope costs about a millisecond per
polygon).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core.geometry import group_ends, group_starts, largest_polygons, minimum_rectangles
from ..core.progress import InputError, Progress, ensure
from .street_graph import RoadGraph, node_lines

__all__ = [
    "MIN_BLOCK_AREA", "MIN_BLOCK_WIDTH", "MIN_SHARE", "BLOCK_FIELDS", "BlockExtraction",
    "planar_faces", "block_faces", "roundabout_islands", "shape_metrics", "assign_to_blocks",
    "extract_blocks", "blocks_from_roads", "with_outline",
]

#: Faces smaller than this (m²) are traffic islands and junction artefacts, not blocks.
MIN_BLOCK_AREA = 400.0
#: Faces whose mean width 2·area/perimeter is under this (m) are slivers between
#: dual carriageways or slip roads (a 120 m x 8 m Helsinki median has 6.9 m).
MIN_BLOCK_WIDTH = 8.0
#: A building or parcel belongs to the block holding at least this share of its area.
MIN_SHARE = 0.5

#: Walks enclosing less than this (m²) are the zero-area cycles of duplicate edges.
_MIN_FACE_AREA = 1e-6
#: A face outline within this (m) of a road lies on it (round-off of the traced walk).
_ON_LINE = 1e-3

#: Per-block attributes of :attr:`BlockExtraction.table` with their types.
BLOCK_FIELDS = [
    ("block_id", "int"), ("area_m2", "float"), ("perimeter_m", "float"),
    ("compactness", "float"), ("aspect_ratio", "float"), ("mbr_length_m", "float"),
    ("mbr_width_m", "float"), ("mbr_angle_deg", "float"), ("n_holes", "int"),
    ("n_dead_ends", "int"), ("n_buildings", "int"), ("building_coverage", "float"),
    ("n_parcels", "int"), ("boundary_m", "float"),
]


@dataclass
class BlockExtraction:
    """Result of :func:`extract_blocks`.

    Attributes
    ----------
    geometry : ndarray of Polygon
        The blocks (valid, pairwise non-overlapping), in the metric CRS of the input.
    table : DataFrame
        One row per block, the columns of :data:`BLOCK_FIELDS`; ``block_id`` runs 1..n.
    buildings, parcels : DataFrame or None
        One row per input building / parcel: ``block_id`` (nullable Int64, missing outside
        every block), ``block_share`` (share of the feature's area inside that block, 0
        outside), ``in_block`` (bool).
    stats : dict
        Counts for the log: ``n_faces`` (all faces), ``n_small``, ``n_thin``,
        ``n_roundabout`` (dropped faces), ``n_blocks``, ``n_buildings_in_blocks``,
        ``n_parcels_in_blocks``.
    """

    geometry: np.ndarray
    table: pd.DataFrame
    buildings: Optional[pd.DataFrame] = None
    parcels: Optional[pd.DataFrame] = None
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- array helpers

def _offsets(counts: np.ndarray) -> np.ndarray:
    """Start of each group in a concatenation of groups of the given sizes."""
    out = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=out[1:])
    return out


# --------------------------------------------------------------------------- faces

def planar_faces(lines: Sequence, node: bool = True):
    """Bounded faces of a line network, traced on its half-edge structure.

    Gives the faces of ``shapely.polygonize`` (dead-end streets and bridges between loops
    bound no face; a component enclosed by a face becomes a hole of it) in time that grows
    linearly: the faces are the cycles of the half-edge permutation
    ``next(h) = clockwise-next(twin(h))`` of a doubly connected edge list (de Berg et al.,
    *Computational Geometry*, 2008, ch. 2.2), found for all half-edges at once with numpy.

    Parameters
    ----------
    lines : array of LineString / MultiLineString, metric CRS
    node : bool
        Node the lines first (:func:`street_graph.node_lines`) so that they meet only at
        end points.
        Skip it only for lines known to be noded (e.g. one layer of a cleaned graph).

    Returns
    -------
    faces : ndarray of Polygon
        The bounded faces (valid, pairwise non-overlapping), in no particular order.
    area, perimeter : float arrays
        Their areas and perimeters (holes included), from the traced coordinates.

    Examples
    --------
    >>> import shapely
    >>> square = shapely.LineString([(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)])
    >>> dead_end = shapely.LineString([(5, 5), (10, 5)])
    >>> faces, area, _ = planar_faces([square, dead_end])
    >>> len(faces), float(area[0])
    (1, 100.0)
    """
    net = _Network(lines, node)
    return net.faces()


class _Network:
    """Noded linework as flat arrays: the half-edge structure behind :func:`planar_faces`.

    Half-edge ``h < m`` runs along edge ``h`` from its first to its last vertex, ``h + m``
    runs back; ``org`` is the node a half-edge leaves, ``angle`` its initial direction.
    """

    def __init__(self, lines: Sequence, node: bool = True):
        lines = np.asarray(lines, dtype=object)
        lines = lines[~(shapely.is_missing(lines) | shapely.is_empty(lines))]
        if not (shapely.get_type_id(lines) == 1).all():  # get_parts copies: only when needed
            lines = shapely.get_parts(lines)
        if node and len(lines):
            lines = node_lines(lines)
        coords, idx = shapely.get_coordinates(lines, return_index=True)
        counts = np.bincount(idx, minlength=len(lines))
        last = np.cumsum(counts) - 1
        first = last - counts + 1
        # drop zero-length pieces and degenerate closed ones (a closed edge needs 4 points)
        seg = np.hypot(*np.diff(coords, axis=0).T) if len(coords) else np.zeros(0)
        length = np.bincount(idx[1:], seg * (idx[1:] == idx[:-1]), minlength=len(lines))
        closed = np.all(coords[first] == coords[last], axis=1)
        keep = (length > 0) & (~closed | (counts >= 4))
        self.first, self.last = first[keep], last[keep]
        # centred coordinates keep the shoelace sums exact far from the CRS origin
        self.origin = coords.mean(axis=0) if len(coords) else np.zeros(2)
        self.coords = coords - self.origin
        m = self.m = len(self.first)
        f, l = self.first, self.last
        # node ids: noding makes the end points of touching lines bit-identical
        ends = np.concatenate([self.coords[f], self.coords[l]])
        _, org = np.unique(ends[:, 0] + 1j * ends[:, 1], return_inverse=True)
        self.org = org.reshape(-1)
        self.node_xy = ends
        d = np.concatenate([self.coords[f + 1] - self.coords[f],
                            self.coords[l - 1] - self.coords[l]])
        self.twin = np.concatenate([np.arange(m, 2 * m), np.arange(m)])
        # rotation system: around each node, the half-edge clockwise-next of each one
        order = np.lexsort((np.arctan2(d[:, 1], d[:, 0]), self.org))
        so = self.org[order]
        h = np.arange(2 * m)
        group_start = group_starts(so)
        group_end = group_ends(so)
        last_pos = np.minimum.accumulate(np.where(group_end, h, 2 * m)[::-1])[::-1]
        clockwise = np.empty(2 * m, dtype=np.int64)
        clockwise[order] = order[np.where(group_start, last_pos, h - 1)]
        self.nxt = clockwise[self.twin]  # bounded faces on the left, walked counter-clockwise

    def dead_ends(self) -> np.ndarray:
        """Points of the nodes of degree 1 (street ends)."""
        deg = np.bincount(self.org)
        first_h = np.unique(self.org, return_index=True)[1]
        return shapely.points(self.node_xy[first_h[deg == 1]] + self.origin)

    def faces(self):
        empty = np.empty(0, dtype=object), np.zeros(0), np.zeros(0)
        m = self.m
        if m == 0:
            return empty
        alive = np.arange(2 * m)
        label, seq = _cycles(self.nxt)
        # an edge with the same walk on both sides (a dead end, a bridge between two loops)
        # bounds no face: remove it from the rotation system and label the walks again
        same = label[:m] == label[m:]
        if same.any():
            removed = np.concatenate([same, same])
            nxt = self.nxt.copy()
            bad = ~removed & removed[nxt]
            while bad.any():  # skip removed half-edges around the node (few rounds)
                nxt[bad] = nxt[self.twin[nxt[bad]]]
                bad = ~removed & removed[nxt]
            alive = np.flatnonzero(~removed)
            if len(alive) == 0:
                return empty
            compact = np.cumsum(~removed) - 1
            label, seq = _cycles(compact[nxt[alive]])
            seq = alive[seq]
        return _walk_polygons(self, alive, label, seq)


def _cycles(nxt: np.ndarray):
    """Cycles of a permutation: a label per element and all elements in cycle order.

    Pointer jumping (list ranking): after t rounds every element knows the minimum over the
    next 2**t elements of its cycle, so log2(n) rounds of whole-array operations find each
    cycle's smallest element; a second jumping pass gives each element's distance to it.
    """
    k = len(nxt)
    ar = np.arange(k)
    rep, succ = ar.copy(), nxt.copy()
    for _ in range(max(int(k - 1).bit_length(), 1)):
        rep = np.minimum(rep, rep[succ])
        succ = succ[succ]
    is_rep = rep == ar
    label = (np.cumsum(is_rep) - 1)[rep]
    size = np.bincount(label)
    start = _offsets(size)
    # distance of each element to the last one of its cycle (the one before the smallest)
    is_last = nxt == rep
    succ = np.where(is_last, ar, nxt)
    dist = (~is_last).astype(np.int64)
    while True:
        succ2 = succ[succ]
        if np.array_equal(succ2, succ):
            break
        dist = dist + dist[succ]
        succ = succ2
    seq = np.empty(k, dtype=np.int64)
    seq[start[label] + size[label] - 1 - dist] = ar
    return label, seq


def _walk_polygons(net: "_Network", alive, label, seq):
    """Polygons of the counter-clockwise walks, with the clockwise walks as their holes.

    ``label`` is indexed like ``alive`` (the half-edges still in the structure), ``seq``
    lists half-edge ids grouped by walk in walking order.
    """
    m = net.m
    walk_of = np.empty(2 * m, dtype=np.int64)
    walk_of[alive] = label
    e = np.where(seq < m, seq, seq - m)
    first, last = net.first[e], net.last[e]
    n_c = last - first                             # coordinates per half-edge, end excluded
    rep_idx = np.repeat(np.arange(len(seq)), n_c)
    j = np.arange(len(rep_idx)) - np.repeat(np.cumsum(n_c) - n_c, n_c)
    cidx = np.where((seq < m)[rep_idx], first[rep_idx] + j, last[rep_idx] - j)
    xy = net.coords[cidx]
    ring = walk_of[seq][rep_idx]                   # non-decreasing
    n_ring = label.max() + 1
    ring_start = np.searchsorted(ring, np.arange(n_ring))
    k = np.arange(1, len(ring) + 1)
    wrap = group_ends(ring)
    k[wrap] = ring_start[ring[wrap]]
    x, y = xy[:, 0], xy[:, 1]
    area = 0.5 * np.bincount(ring, x * y[k] - x[k] * y, minlength=n_ring)
    perimeter = np.bincount(ring, np.hypot(x[k] - x, y[k] - y), minlength=n_ring)
    # counter-clockwise walks bound faces; the zero-area walks between duplicate edges do
    # not; each clockwise walk is the outer boundary of a connected component
    is_shell = area > _MIN_FACE_AREA
    is_hole = area < -_MIN_FACE_AREA

    def rings_of(mask):
        sel = mask[ring]
        compact = (np.cumsum(mask) - 1)[ring[sel]]
        return shapely.linearrings(xy[sel] + net.origin, indices=compact)

    faces = shapely.polygons(rings_of(is_shell)) if is_shell.any() else np.empty(0, dtype=object)
    face_area, face_perimeter = area[is_shell], perimeter[is_shell]
    holes = np.flatnonzero(is_hole)
    if len(holes) and len(faces):
        # a component inside a face is a hole of the smallest face containing it; a
        # component enclosing more than the largest face (the whole network, usually)
        # lies inside none, which saves the tree in the common case
        holes = holes[-area[holes] < face_area.max()]
    if len(holes) and len(faces):
        probe = shapely.points(xy[ring_start[holes]] + net.origin)
        h_i, f_i = shapely.STRtree(faces).query(probe, predicate="within")
        if len(h_i):
            best = np.lexsort((face_area[f_i], h_i))
            best = best[group_starts(h_i[best])]
            h_i, f_i = h_i[best], f_i[best]
            hole_mask = np.zeros(n_ring, dtype=bool)
            hole_mask[holes] = True
            hole_rings = rings_of(hole_mask)
            np.add.at(face_area, f_i, area[holes][h_i])
            np.add.at(face_perimeter, f_i, perimeter[holes][h_i])
            for face in np.unique(f_i):
                faces[face] = shapely.polygons(shapely.get_exterior_ring(faces[face]),
                                               holes=hole_rings[h_i[f_i == face]])
    # in a planar graph a walk that visits no node twice is a simple ring; a face whose
    # walk touches itself (a loop hanging into it at one node) is an invalid ring, which
    # make_valid turns into the polygon with a hole that it is
    node_key = walk_of[seq] * (net.org.max() + 1) + net.org[seq]
    node_key.sort()
    touching = np.zeros(n_ring, dtype=bool)
    touching[node_key[1:][node_key[1:] == node_key[:-1]] // (net.org.max() + 1)] = True
    suspect = np.flatnonzero(touching[is_shell])
    for i in suspect[~shapely.is_valid(faces[suspect])]:
        largest = largest_polygons([faces[i]])[0]
        faces[i] = shapely.Polygon() if largest is None else largest
        face_area[i], face_perimeter[i] = shapely.area(faces[i]), shapely.length(faces[i])
    return faces, face_area, face_perimeter


def block_faces(lines: Sequence, min_area: float = MIN_BLOCK_AREA,
                min_width: float = MIN_BLOCK_WIDTH, node: bool = True):
    """Bounded faces of a street network, without the sliver faces.

    Parameters
    ----------
    lines : array of LineString
        Street centrelines in a metric CRS.
    min_area : float
        Faces smaller than this (m²) are dropped.
    min_width : float
        Faces whose mean width ``2 * area / perimeter`` is under this (m) are dropped.
    node : bool
        Node the lines first (see :func:`planar_faces`).

    Returns
    -------
    faces : ndarray of Polygon
        The kept faces, ordered by the lower-left corner of their bounding box so that
        block ids do not depend on the order of the input lines.
    counts : dict
        ``n_faces`` (before filtering), ``n_small``, ``n_thin``.

    References
    ----------
    Hartmann, thesis ch. 4.1.2 and 5.1 (blocks are the minimal cycles of the street graph);
    docs/ARCHITECTURE.md, "Real example data" (slivers of dual carriageways and service roads).

    Examples
    --------
    >>> import shapely
    >>> grid = [shapely.LineString([(0, y), (200, y)]) for y in (0, 100, 200)] + \\
    ...        [shapely.LineString([(x, 0), (x, 200)]) for x in (0, 100, 200)]
    >>> faces, counts = block_faces(grid)
    >>> len(faces), counts["n_faces"]
    (4, 4)
    """
    return _filtered_faces(_Network(lines, node), min_area, min_width)


def _filtered_faces(net: "_Network", min_area: float, min_width: float):
    if min_area < 0 or min_width < 0:
        raise InputError("the minimum block area and width must not be negative")
    if net.m == 0:
        raise InputError("no road lines with a length")
    faces, area, perimeter = net.faces()
    n_faces = len(faces)
    if n_faces == 0:
        raise InputError("no closed block: the roads form no closed face")
    small = area < min_area
    thin = ~small & (2.0 * area < min_width * perimeter)
    faces = faces[~(small | thin)]
    bounds = shapely.bounds(faces)
    order = np.lexsort((np.round(bounds[:, 0], 3), np.round(bounds[:, 1], 3)))
    return faces[order], {"n_faces": n_faces, "n_small": int(small.sum()),
                          "n_thin": int(thin.sum())}


def roundabout_islands(faces: Sequence, lines: Sequence, roundabout: Sequence) -> np.ndarray:
    """Per face: True where its outline lies wholly on roundabout roads (the island of a
    roundabout, OSM ``junction=roundabout``): road furniture, not a block.

    Parameters
    ----------
    faces : array of Polygon
        Faces of ``lines`` (their outlines are made of the lines' coordinates).
    lines : array of LineString
    roundabout : bool per line

    Examples
    --------
    >>> import shapely
    >>> ring = shapely.Point(0, 0).buffer(12.5).exterior
    >>> island, beside = shapely.Polygon(ring), shapely.box(20, -5, 40, 5)
    >>> roundabout_islands([island, beside], [ring], [True]).tolist()
    [True, False]
    """
    faces = np.asarray(faces, dtype=object)
    out = np.zeros(len(faces), dtype=bool)
    ring_lines = np.asarray(lines, dtype=object)[np.asarray(roundabout, dtype=bool)]
    ring_lines = ring_lines[~(shapely.is_missing(ring_lines) | shapely.is_empty(ring_lines))]
    if len(faces) == 0 or len(ring_lines) == 0:
        return out
    near = np.unique(shapely.STRtree(faces).query(ring_lines, predicate="intersects")[1])
    if len(near):
        band = shapely.buffer(shapely.union_all(ring_lines), _ON_LINE, quad_segs=2)
        out[near] = shapely.covered_by(shapely.get_exterior_ring(faces[near]), band)
    return out


def _planar_lines(graph: RoadGraph) -> np.ndarray:
    """The edges of a cleaned graph, noded where edges of different vertical layers cross.

    :func:`roads.clean_network` nodes each vertical layer on its own (a bridge does not
    connect to the street below), so its edges are planar per layer. For the faces, every
    drivable edge is a block boundary whatever its layer (as in the thesis's planar street
    graph and momepy's enclosures): only the few edges off the main layer and the edges
    they touch are noded again.
    """
    lines = np.asarray(graph.geometry, dtype=object)
    layers, count = np.unique(np.asarray(graph.z_layer), return_inverse=False,
                              return_counts=True)
    if len(layers) <= 1:
        return lines
    off = np.flatnonzero(np.asarray(graph.z_layer) != layers[np.argmax(count)])
    _, touched = shapely.STRtree(lines).query(lines[off], predicate="intersects")
    involved = np.zeros(len(lines), dtype=bool)
    involved[off] = True
    involved[touched] = True
    return np.concatenate([lines[~involved], node_lines(lines[involved])])


def _area_of(boundary) -> shapely.Geometry:
    """The boundary as one polygonal geometry (its polygons united)."""
    geoms = np.atleast_1d(np.asarray(boundary, dtype=object))
    geoms = geoms[~(shapely.is_missing(geoms) | shapely.is_empty(geoms))]
    area = shapely.union_all(shapely.make_valid(geoms)) if len(geoms) else None
    if area is None or not (shapely.area(area) > 0):
        raise InputError("the boundary has no area")
    return area


def with_outline(lines: Sequence, area) -> np.ndarray:
    """Noded lines with the outline of ``area`` added: the lines that reach the outline are
    noded with it (the rest are noded already, as a cleaned graph's edges are), so that
    the outline closes the faces the lines leave open.

    >>> roads = [shapely.LineString([(50, -20), (50, 120)])]
    >>> len(with_outline(roads, shapely.box(0, 0, 100, 100)))  # 3 + 3 (ring start kept)
    6
    """
    lines = np.asarray(lines, dtype=object)
    outline = shapely.get_parts(shapely.boundary(area))
    reach = np.zeros(len(lines), dtype=bool)
    if len(lines):
        reach[np.unique(shapely.STRtree(lines).query(outline, predicate="intersects")[1])] = True
    return np.concatenate([lines[~reach], node_lines(np.concatenate([lines[reach], outline]))])


def _inside(faces: np.ndarray, area, counts: dict):
    """The faces inside ``area`` that a road reaches: the rest lie outside the district, or
    are land the outline alone closes (no street to front): no blocks. Returns them, the
    length (m) of each one's outline on the area's outline, and the counts:
    ``n_outside``, ``n_without_street`` and ``n_on_boundary`` (the blocks on the outline)."""
    shapely.prepare(area)
    inside = shapely.contains(area, shapely.point_on_surface(faces))
    n_outside = int((~inside).sum())
    faces = faces[inside]
    # a block on the outline shares a length of it, not a point; the faces' vertices there
    # are the noded outline's (a micrometre band: the roads' edges add 2 µm at a corner)
    outline = shapely.buffer(shapely.boundary(area), 1e-6, quad_segs=1)
    near = np.unique(shapely.STRtree(faces).query(outline, predicate="intersects")) \
        if len(faces) else np.zeros(0, dtype=np.int64)
    rings = shapely.boundary(faces[near])
    shared = shapely.length(shapely.intersection(rings, outline))
    on = shared > 10 * _ON_LINE
    no_street = np.zeros(len(faces), dtype=bool)
    no_street[near] = shared > shapely.length(rings) - 10 * _ON_LINE
    length = np.zeros(len(faces))
    length[near[on]] = shared[on]
    return faces[~no_street], length[~no_street], dict(
        counts, n_outside=n_outside, n_without_street=int(no_street.sum()),
        n_on_boundary=int((on & ~no_street[near]).sum()))


# --------------------------------------------------------------------------- shape

def shape_metrics(polygons: Sequence) -> pd.DataFrame:
    """Area, perimeter, compactness and aspect ratio of polygons.

    Parameters
    ----------
    polygons : array of Polygon, metric CRS

    Returns
    -------
    DataFrame
        ``area_m2``, ``perimeter_m``, ``compactness`` (area / minimum bounding rectangle
        area, 1 for a rectangle), ``aspect_ratio`` (shorter / longer side of that rectangle,
        in (0, 1]), ``mbr_length_m``, ``mbr_width_m``, ``mbr_angle_deg``, ``n_holes``.

    References
    ----------
    Hartmann, thesis ch. 4.2 (evaluation of StreetGAN): "compactness = block area / area of
    its minimum bounding box; aspect ratio = shorter / longer side of the minimum bounding box".
    """
    return pd.DataFrame(_shape_columns(np.asarray(polygons, dtype=object)))


def _shape_columns(polygons: np.ndarray, area: Optional[np.ndarray] = None) -> dict:
    area = shapely.area(polygons) if area is None else area
    length, width, angle = minimum_rectangles(polygons)
    rect = length * width
    with np.errstate(divide="ignore", invalid="ignore"):
        compactness = np.where(rect > 0, np.minimum(area / rect, 1.0), np.nan)
        aspect = np.where(length > 0, width / length, np.nan)
    return {"area_m2": area, "perimeter_m": shapely.length(polygons),
            "compactness": compactness, "aspect_ratio": aspect, "mbr_length_m": length,
            "mbr_width_m": width, "mbr_angle_deg": angle,
            "n_holes": shapely.get_num_interior_rings(polygons)}


# --------------------------------------------------------------------------- contents

def assign_to_blocks(blocks: Sequence, geometries: Sequence, min_share: float = MIN_SHARE,
                     tree: Optional[shapely.STRtree] = None):
    """Assign each polygon (building, parcel) to at most one block.

    A feature lying within a block belongs to it; a feature crossing block boundaries
    belongs to the block holding the largest share of its area, if that share is at least
    ``min_share``; otherwise (outside every closed block, or spread over several) to none.

    Parameters
    ----------
    blocks : array of Polygon
        Non-overlapping blocks.
    geometries : array of Polygon / MultiPolygon
    min_share : float in (0, 1]
    tree : STRtree over ``blocks``, optional (reused when given)

    Returns
    -------
    index : int array
        Index into ``blocks`` per feature, -1 for none.
    share : float array
        Share of the feature's area inside that block (0 for none).

    Examples
    --------
    >>> import shapely
    >>> blocks = [shapely.box(0, 0, 10, 10), shapely.box(10, 0, 20, 10)]
    >>> features = [shapely.box(6, 2, 12, 4), shapely.box(30, 0, 31, 1)]
    >>> index, share = assign_to_blocks(blocks, features)
    >>> index.tolist(), share.round(2).tolist()
    ([0, -1], [0.67, 0.0])
    """
    if not 0 < min_share <= 1:
        raise InputError("the minimum share of a feature inside its block must be in (0, 1]")
    blocks = np.asarray(blocks, dtype=object)
    geoms = np.asarray(geometries, dtype=object)
    n = len(geoms)
    index = np.full(n, -1, dtype=np.int64)
    share = np.zeros(n)
    if n == 0 or len(blocks) == 0:
        return index, share
    tree = tree if tree is not None else shapely.STRtree(blocks)
    # 1. the common case, cheap with prepared blocks: entirely within one block
    g_in, b_in = tree.query(geoms, predicate="within")
    index[g_in] = b_in
    share[g_in] = 1.0
    # 2. the rest: largest overlap among the blocks they intersect
    rest = np.flatnonzero(index < 0)
    if len(rest):
        g, b = tree.query(geoms[rest], predicate="intersects")
        if len(g):
            g = rest[g]
            area = shapely.area(geoms[g])
            with np.errstate(divide="ignore", invalid="ignore"):
                inter = shapely.area(shapely.intersection(geoms[g], blocks[b]))
                s = np.where(area > 0, inter / area, 0.0)
            order = np.lexsort((-s, g))
            best = order[group_starts(g[order])]
            ok = s[best] >= min_share
            index[g[best[ok]]] = b[best[ok]]
            share[g[best[ok]]] = np.minimum(s[best[ok]], 1.0)
    return index, share


def _membership_table(index: np.ndarray, share: np.ndarray, block_ids: np.ndarray) -> pd.DataFrame:
    inside = index >= 0
    ids = pd.array(np.where(inside, block_ids[np.maximum(index, 0)], 0), dtype="Int64")
    ids[~inside] = pd.NA
    return pd.DataFrame({"block_id": ids, "block_share": share, "in_block": inside})


# --------------------------------------------------------------------------- main API

def extract_blocks(roads, buildings: Optional[Sequence] = None,
                   parcels: Optional[Sequence] = None,
                   min_area: float = MIN_BLOCK_AREA, min_width: float = MIN_BLOCK_WIDTH,
                   min_share: float = MIN_SHARE,
                   progress: Optional[Progress] = None,
                   roundabout: Optional[Sequence[bool]] = None,
                   boundary=None) -> BlockExtraction:
    """City blocks of a street network, with their footprints and parcels.

    Parameters
    ----------
    roads : RoadGraph or array of LineString
        The cleaned street graph (:func:`roads.clean_network`; its dead-end nodes are
        counted per block) or plain centrelines in a metric CRS (dead ends then come from
        the line ends that touch no other line).
    buildings, parcels : arrays of Polygon / MultiPolygon, optional
        Footprints and cadastre parcels in the same CRS.
    min_area, min_width : float
        Sliver filter of :func:`block_faces`.
    min_share : float
        Assignment rule of :func:`assign_to_blocks`.
    progress : Progress, optional
    roundabout : bool per road (per edge of a RoadGraph), optional
        Roads that are roundabouts (OSM ``junction=roundabout``): the faces they enclose
        alone are roundabout islands, not blocks (:func:`roundabout_islands`).
    boundary : Polygon / MultiPolygon (or an array of them), optional
        The area the blocks fill (a district's outline): its outline closes the faces the
        roads leave open, and faces outside it are no blocks (:func:`with_outline`). Its
        edges are no streets: the stats count the blocks on it (``n_on_boundary``).

    Returns
    -------
    BlockExtraction
        Blocks with :data:`BLOCK_FIELDS`; per building and parcel its ``block_id``
        (missing outside every closed block: such features are kept and flagged
        ``in_block`` False, never dropped or clipped).

    Raises
    ------
    InputError
        When the roads close no face, or every face is a sliver.

    References
    ----------
    Hartmann, thesis ch. 4.1.2 (blocks keep their dead-end streets) and ch. 5.1 (a block
    is its boundary polygon and its footprints); docs/ARCHITECTURE.md, "Real example data".

    Examples
    --------
    >>> import shapely
    >>> grid = [shapely.LineString([(0, y), (200, y)]) for y in (0, 100, 200)] + \\
    ...        [shapely.LineString([(x, 0), (x, 200)]) for x in (0, 100, 200)]
    >>> result = extract_blocks(grid, buildings=[shapely.box(10, 10, 30, 30)])
    >>> result.table[["block_id", "area_m2", "n_buildings"]].values.tolist()[:2]
    [[1.0, 10000.0, 1.0], [2.0, 10000.0, 0.0]]
    >>> result.buildings.block_id.tolist()
    [1]
    """
    progress = ensure(progress)
    area = None if boundary is None else _area_of(boundary)
    if isinstance(roads, RoadGraph):
        # a cleaned graph is planar per layer: node only across layers (cheap)
        lines = _planar_lines(roads)
        net = _Network(lines if area is None else with_outline(lines, area), node=False)
        dead_ends = shapely.points(roads.nodes[roads.degree == 1])
    else:
        lines = np.asarray(roads, dtype=object)
        dead_ends = _Network(lines, node=True).dead_ends()
        net = _Network(lines if area is None else np.append(
            lines, shapely.get_parts(shapely.boundary(area))), node=True)
    progress.step(0.1)
    faces, counts = _filtered_faces(net, min_area, min_width)
    on_outline = np.zeros(len(faces))
    if area is not None:
        faces, on_outline, counts = _inside(faces, area, counts)
    counts["n_roundabout"] = 0
    if roundabout is not None:
        lines = roads.geometry if isinstance(roads, RoadGraph) else roads
        if len(roundabout) != len(lines):
            raise InputError(f"{len(roundabout)} roundabout flags for {len(lines)} roads")
        island = roundabout_islands(faces, lines, roundabout)
        faces, counts["n_roundabout"] = faces[~island], int(island.sum())
        on_outline = on_outline[~island]
    progress.step(0.4)
    if len(faces) == 0 and area is not None:
        raise InputError(
            f"no block inside the boundary: of the {counts['n_faces']} faces of the roads "
            f"and the boundary, {counts['n_outside']} lie outside it, "
            f"{counts['n_without_street']} have no road on their outline and "
            f"{counts['n_small'] + counts['n_thin'] + counts['n_roundabout']} are smaller "
            f"than {min_area:g} m², narrower than {min_width:g} m or roundabout islands "
            "(do the roads and the boundary cover the same place?)")
    if len(faces) == 0:
        raise InputError(
            f"no closed block: all {counts['n_faces']} faces of the roads are smaller than "
            f"{min_area:g} m², narrower than {min_width:g} m or roundabout islands (lower "
            "the minimum block area or width)")
    n = len(faces)
    columns = {"block_id": np.arange(1, n + 1, dtype=np.int64), "boundary_m": on_outline}
    columns.update(_shape_columns(faces))
    tree = shapely.STRtree(faces)
    progress.step(0.55)

    # dead-end streets stay inside their block (they bound no face): count their ends
    _, hit = tree.query(dead_ends, predicate="within")
    columns["n_dead_ends"] = np.bincount(hit, minlength=n)
    stats = dict(counts, n_blocks=n)
    result = BlockExtraction(faces, None, stats=stats)
    columns["n_buildings"] = np.zeros(n, dtype=np.int64)
    covered = np.zeros(n)
    if buildings is not None:
        b = np.asarray(buildings, dtype=object)
        index, share = assign_to_blocks(faces, b, min_share, tree)
        inside = index >= 0
        columns["n_buildings"] = np.bincount(index[inside], minlength=n)
        covered = np.bincount(index[inside], shapely.area(b[inside]) * share[inside], minlength=n)
        result.buildings = _membership_table(index, share, columns["block_id"])
        stats["n_buildings"] = len(b)
        stats["n_buildings_in_blocks"] = int(inside.sum())
    progress.step(0.8)
    # overlapping footprints (dirty OSM) could count twice: a coverage is at most 1
    columns["building_coverage"] = np.minimum(covered / columns["area_m2"], 1.0)
    columns["n_parcels"] = np.zeros(n, dtype=np.int64)
    if parcels is not None:
        p = np.asarray(parcels, dtype=object)
        index, share = assign_to_blocks(faces, p, min_share, tree)
        inside = index >= 0
        columns["n_parcels"] = np.bincount(index[inside], minlength=n)
        result.parcels = _membership_table(index, share, columns["block_id"])
        stats["n_parcels"] = len(p)
        stats["n_parcels_in_blocks"] = int(inside.sum())
    result.table = pd.DataFrame({name: columns[name] for name, _ in BLOCK_FIELDS})
    progress.step(1.0)
    return result


def blocks_from_roads(lines: Sequence, road_class: Optional[Sequence] = None,
                      buildings: Optional[Sequence] = None, parcels: Optional[Sequence] = None,
                      min_area: float = MIN_BLOCK_AREA, min_width: float = MIN_BLOCK_WIDTH,
                      progress: Optional[Progress] = None,
                      roundabout: Optional[Sequence[bool]] = None, boundary=None):
    """City blocks of raw road lines: the one rule of every tool that takes roads instead
    of blocks ('Extract city blocks', parcels and footprints from roads).

    The lines are cleaned into a planar street graph with one vertical layer (every
    drivable edge bounds blocks, bridges and tunnels too; degree-2 chains are not merged,
    so the faces follow the lines exactly), then :func:`extract_blocks` finds its faces.

    Parameters
    ----------
    lines : array of LineString in a metric CRS (already filtered to drivable classes)
    road_class : per-line class (optional)
    buildings, parcels, min_area, min_width, boundary : as :func:`extract_blocks`
    progress : Progress, optional
    roundabout : bool per line, optional
        Lines that are roundabouts (OSM ``junction=roundabout``): their islands are no blocks.

    Returns
    -------
    (RoadGraph, BlockExtraction)

    Examples
    --------
    >>> import shapely
    >>> grid = [shapely.LineString([(0, y), (200, y)]) for y in (0, 100, 200)] + \\
    ...        [shapely.LineString([(x, 0), (x, 200)]) for x in (0, 100, 200)]
    >>> graph, result = blocks_from_roads(grid)
    >>> graph.n_edges, result.stats["n_blocks"]
    (12, 4)
    """
    from .street_graph import clean_network

    progress = ensure(progress)
    graph = clean_network(lines, road_class, None, None, merge_degree2=False,
                          progress=progress.sub(0.0, 0.6))
    flags = None if roundabout is None else \
        np.asarray(roundabout, dtype=bool)[np.asarray(graph.source, dtype=np.int64)]
    result = extract_blocks(graph, buildings, parcels, min_area=min_area, min_width=min_width,
                            progress=progress.sub(0.6, 1.0), roundabout=flags,
                            boundary=boundary)
    return graph, result
