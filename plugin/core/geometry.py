"""Small geometry and array helpers that several stages use (one home for each).

- :func:`minimum_rectangles`, :func:`minimum_rectangle_corners`: minimum-area bounding
  rectangles by vectorised rotating calipers (block shape metrics, parcel cuts, the OBB
  axis of the Voronoi parcels, template frames, grid directions of road growth);
- :func:`largest_polygons`: the largest polygon part of each (repaired) geometry;
- :func:`without_areas`: geometries less the areas to keep clear that reach them;
- :func:`too_thin`: land nowhere :data:`MIN_BUILDABLE_WIDTH` wide (no lot, no building);
- :func:`substrings`: stretches of lines between arc lengths; :func:`end_sections`:
  the cross-sections at their ends;
- :func:`unit`: unit vectors; :func:`group_starts` / :func:`group_ends`: runs of equal keys;
- :func:`ring_turns`: the signed turn at each vertex of a closed ring;
- :func:`first_hits`: how far each of many rays goes before it meets a set of lines;
- :func:`rounded_bends`: a polygon's shallow bends drawn as arcs (shapely smooths nothing);
  :func:`rounded_band_bends`: a street band's, never narrowing it.

shapely's ``oriented_envelope`` loops over geometries in Python on GEOS 3.11 and gives no
side lengths or directions; ``shapely.ops.substring`` works on one line at a time: these
are the vectorised forms the engine needs in its hot loops.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import shapely

__all__ = ["group_starts", "group_ends", "unit", "substrings", "end_sections", "pinned_ends",
           "polygon_parts", "largest_polygons", "minimum_rectangles", "minimum_rectangle_corners",
           "longest_edge_directions", "ring_turns", "rounded_bends", "rounded_band_bends",
           "two_point_segments", "first_hits", "without_areas", "MIN_BUILDABLE_WIDTH",
           "MIN_BUILDABLE_AREA", "too_thin", "counter_clockwise", "one_areal"]

#: Land (a block less its street surfaces) nowhere this wide (m) is no building land: no
#: parcel is made on it and no footprint stands on it. A strip left between two wide streets
#: (a block 17 m across between two 16 m primaries keeps 1.3 m) or the island of a roundabout
#: is street furniture, not a plot. It is the default minimum lot width of the parcels
#: (``parcels.DEFAULT_MIN_WIDTH``, which 'subdivideparcels' lets the analyst change).
MIN_BUILDABLE_WIDTH = 8.0
#: A piece of land smaller than this (m²) is no building land either: it gets no parcel
#: (``parcels.DEFAULT_MIN_AREA``, the minimum parcel area) and no footprint. This takes the
#: island of a roundabout that no tag names (a 25 m ring in a 16 m road keeps a 9 m disc,
#: 64 m², wide enough by :data:`MIN_BUILDABLE_WIDTH`).
MIN_BUILDABLE_AREA = 150.0


# --------------------------------------------------------------------------- arrays

def two_point_segments(lines: Sequence) -> np.ndarray:
    """The straight segments of lines or polygon outlines (multi-part or not), one two-point
    line each (empty geometries, points and zero-length segments left out).

    >>> [g.wkt for g in two_point_segments([shapely.LineString([(0, 0), (1, 0), (1, 2)])])]
    ['LINESTRING (0 0, 1 0)', 'LINESTRING (1 0, 1 2)']
    >>> len(two_point_segments([shapely.MultiLineString([[(0, 0), (1, 0)], [(5, 0), (5, 1)]]),
    ...                         shapely.box(0, 0, 4, 4).difference(shapely.box(1, 1, 2, 2))]))
    10
    """
    geoms = np.asarray(lines, dtype=object)
    geoms = geoms[~shapely.is_empty(geoms)] if len(geoms) else geoms
    if not len(geoms):
        return np.zeros(0, dtype=object)
    # single parts first: the boundary of a multi-line is its end points, not its lines
    parts = shapely.get_parts(shapely.get_parts(geoms))
    parts = shapely.get_parts(np.where(shapely.get_type_id(parts) == 3,
                                       shapely.boundary(parts), parts))
    parts = parts[np.isin(shapely.get_type_id(parts), (1, 2))]
    xy, idx = shapely.get_coordinates(parts, return_index=True)
    same = idx[1:] == idx[:-1]
    a, b = xy[:-1][same], xy[1:][same]
    keep = np.hypot(*(b - a).T) > 1e-9
    return shapely.linestrings(np.stack([a[keep], b[keep]], axis=1))


#: Ray-segment pairs solved at once by :func:`first_hits` (memory: about 50 bytes each).
_HIT_CHUNK = 500_000


def first_hits(origins: np.ndarray, directions: np.ndarray, lines, reach: float,
               start: float = 0.0) -> np.ndarray:
    """Distance from each origin along its unit direction to the first point of ``lines``
    between ``start`` and ``reach`` (NaN where the ray meets none).

    The rays against every segment of the lines, solved in numpy: shapely intersects one
    ray with the lines at a time, each an overlay of the whole outline (a region's
    streamline scoring casts thousands). A ray along a segment meets it where it meets the
    segments on either side.

    Examples
    --------
    >>> import numpy as np, shapely
    >>> square = shapely.box(0, 0, 10, 10).boundary
    >>> first_hits(np.array([[2.0, 5.0], [2.0, 5.0]]), np.array([[1.0, 0.0], [0.0, -1.0]]),
    ...            [square], reach=20.0).tolist()
    [8.0, 5.0]
    >>> first_hits(np.array([[2.0, 5.0]]), np.array([[1.0, 0.0]]), [square], reach=3.0).tolist()
    [nan]
    """
    origins = np.asarray(origins, dtype=float).reshape(-1, 2)
    directions = np.asarray(directions, dtype=float).reshape(-1, 2)
    segs = two_point_segments(lines)
    out = np.full(len(origins), np.nan)
    if not len(segs) or not len(origins):
        return out
    xy = shapely.get_coordinates(segs).reshape(-1, 2, 2)
    a, e = xy[:, 0], xy[:, 1] - xy[:, 0]
    step = max(1, _HIT_CHUNK // len(a))
    for lo in range(0, len(origins), step):
        o, d = origins[lo:lo + step, None, :], directions[lo:lo + step, None, :]
        ao = a[None] - o
        denom = d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / denom
            u = (ao[..., 0] * d[..., 1] - ao[..., 1] * d[..., 0]) / denom
        hit = (denom != 0) & (t >= start) & (t <= reach) & (u >= 0.0) & (u <= 1.0)
        t = np.where(hit, t, np.inf).min(axis=1)
        out[lo:lo + step] = np.where(np.isfinite(t), t, np.nan)
    return out


def group_starts(keys: np.ndarray) -> np.ndarray:
    """True where a run of equal values in ``keys`` begins.

    >>> group_starts(np.array([1, 1, 2, 3, 3])).tolist()
    [True, False, True, True, False]
    """
    out = np.ones(len(keys), dtype=bool)
    np.not_equal(keys[1:], keys[:-1], out=out[1:])
    return out


def group_ends(keys: np.ndarray) -> np.ndarray:
    """True where a run of equal values in ``keys`` ends.

    >>> group_ends(np.array([1, 1, 2, 3, 3])).tolist()
    [False, True, True, False, True]
    """
    out = np.ones(len(keys), dtype=bool)
    np.not_equal(keys[1:], keys[:-1], out=out[:-1])
    return out


def unit(v: np.ndarray) -> np.ndarray:
    """Vectors (last axis) scaled to length 1; zero vectors stay zero.

    >>> unit(np.array([3.0, 4.0])).tolist(), unit(np.array([[0.0, 2.0], [0.0, 0.0]])).tolist()
    ([0.6, 0.8], [[0.0, 1.0], [0.0, 0.0]])
    """
    v = np.asarray(v, dtype=np.float64)
    n = np.hypot(v[..., 0], v[..., 1])
    return v / np.where(n > 0, n, 1.0)[..., None]


# --------------------------------------------------------------------------- lines

def substrings(lines: Sequence, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The stretch of each line from arc length ``a`` to ``b`` (a < b), with the interior
    vertices, vectorised over all lines (one line may be repeated for many stretches).

    >>> line = shapely.LineString([(0, 0), (10, 0), (10, 10)])
    >>> [g.wkt for g in substrings([line, line], np.array([5.0, 0.0]), np.array([15.0, 2.0]))]
    ['LINESTRING (5 0, 10 0, 10 5)', 'LINESTRING (0 0, 2 0)']
    """
    lines = np.asarray(lines, dtype=object)
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    seg = np.r_[0.0, np.hypot(*np.diff(coords, axis=0).T)]
    first = np.r_[True, idx[1:] != idx[:-1]]
    seg[first] = 0.0
    cum = np.cumsum(seg)
    cum -= cum[np.flatnonzero(first)][idx]
    inner = (cum > a[idx] + 1e-9) & (cum < b[idx] - 1e-9)
    pa = shapely.get_coordinates(shapely.line_interpolate_point(lines, a))
    pb = shapely.get_coordinates(shapely.line_interpolate_point(lines, b))
    n = len(lines)
    all_xy = np.vstack([pa, coords[inner], pb])
    all_line = np.r_[np.arange(n), idx[inner], np.arange(n)]
    all_pos = np.r_[a, cum[inner], b]
    order = np.lexsort((all_pos, all_line))
    return shapely.linestrings(all_xy[order], indices=all_line[order])


def end_sections(lines: Sequence, half: np.ndarray):
    """Left and right points (n, 2, 2) of each line's cross-section at its start ([:, 0])
    and end ([:, 1]), ``half`` to either side of its end vertex, perpendicular to the end
    segment, as a flat-capped buffer cuts it. Whoever needs an end's edge takes these:
    the same arithmetic on the same vertices, so two polygons that share an end share
    its edge to the last bit (the end seen from the other side: its left is ``right``).

    >>> left, right = end_sections([shapely.LineString([(0, 0), (2, 0), (2, 2)])], np.r_[1.0])
    >>> left.tolist(), right.tolist()
    ([[[0.0, 1.0], [1.0, 2.0]]], [[[0.0, -1.0], [3.0, 2.0]]])
    """
    xy, idx = shapely.get_coordinates(lines, return_index=True)
    first = np.searchsorted(idx, np.arange(len(lines)))
    last = np.r_[first[1:], len(xy)] - 1
    p = np.stack([xy[first], xy[last]], axis=1)
    d = unit(np.stack([xy[first + 1] - xy[first], xy[last] - xy[last - 1]], axis=1))
    off = np.asarray(half, dtype=np.float64)[:, None, None] * np.stack([-d[..., 1], d[..., 0]], -1)
    return p + off, p - off


# --------------------------------------------------------------------------- polygons

def pinned_ends(lines: Sequence, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The lines with their first and last vertex set exactly to ``start`` and ``end``
    ((n, 2) or one (2,) point): a line meets its node at one shared point only if its end is
    the node's coordinate to the last bit (round-off of a transform, a rounding to the
    millimetre or a merged node leave it a hair off).

    >>> pinned_ends([shapely.LineString([(0, 0), (1, 1), (2, 0)])], [[0, 0.001]], [[2, 0]])[0]
    <LINESTRING (0 0.001, 1 1, 2 0)>
    """
    coords, index = shapely.get_coordinates(lines, return_index=True)
    first = np.r_[True, index[1:] != index[:-1]]
    last = np.r_[index[1:] != index[:-1], True]
    coords[first] = start
    coords[last] = end
    return shapely.linestrings(coords, indices=index)


def counter_clockwise(geoms: Sequence) -> np.ndarray:
    """Polygons with their outer rings counter-clockwise and their holes clockwise, the
    way GEOS builds them (the same coordinates where they already run so; anything but a
    polygon or multipolygon as it is). A shapefile stores outer rings clockwise: a block
    read from one gave other lots and footprints than the same block from memory, laid
    out from the way its outline runs.

    >>> square = shapely.Polygon([(0, 0), (0, 1), (1, 1), (1, 0)])   # clockwise
    >>> shapely.is_ccw(counter_clockwise([square])[0].exterior)
    True
    """
    from shapely.geometry.polygon import orient

    # one by one: shapely 2.0 has no vectorised orient (2.1: orient_polygons); blocks are
    # thousands at most
    def one(geom):
        if geom is None:
            return geom
        if geom.geom_type == "Polygon":
            return orient(geom, 1.0)
        if geom.geom_type == "MultiPolygon":
            return shapely.MultiPolygon([orient(p, 1.0) for p in geom.geoms])
        return geom

    return np.array([one(g) for g in np.asarray(geoms, dtype=object).ravel()], dtype=object)


def filled(polygons: Sequence) -> np.ndarray:
    """Each polygon or multipolygon with its holes filled (its parts' outer rings).

    >>> ring = shapely.box(0, 0, 10, 10).difference(shapely.box(4, 4, 6, 6))
    >>> float(shapely.area(filled([ring])[0]))
    100.0
    """
    polys = np.asarray(polygons, dtype=object).ravel()
    parts, owner = shapely.get_parts(polys, return_index=True)
    shells = shapely.polygons(shapely.get_exterior_ring(parts))
    out = np.array([shapely.Polygon()] * len(polys), dtype=object)
    count = np.bincount(owner, minlength=len(polys))
    alone = count[owner] == 1
    out[owner[alone]] = shells[alone]
    for i in np.flatnonzero(count > 1):   # a part may lie in another's hole: a union
        out[i] = shapely.union_all(shells[owner == i])
    return out


def one_areal(parts: Sequence) -> shapely.Geometry:
    """Polygon parts as one geometry: the polygon itself, a MultiPolygon of several, an
    empty Polygon of none.

    >>> one_areal([]).wkt, one_areal([shapely.box(0, 0, 1, 1)]).geom_type
    ('POLYGON EMPTY', 'Polygon')
    """
    parts = np.asarray(parts, dtype=object).ravel()
    return parts[0] if len(parts) == 1 else \
        shapely.multipolygons(parts) if len(parts) else shapely.Polygon()


def polygon_parts(geoms: Sequence):
    """The Polygon parts of any geometries and the index of the geometry each came from.

    Overlays and ``make_valid`` of touching polygons return collections that hold
    collections: they are flattened once more; lines and points are left out.

    >>> inner = shapely.GeometryCollection([shapely.box(0, 0, 1, 1),
    ...                                     shapely.LineString([(2, 0), (3, 0)])])
    >>> nested = shapely.GeometryCollection([inner, shapely.box(5, 5, 6, 6)])
    >>> parts, owner = polygon_parts([shapely.Point(9, 9), nested])
    >>> len(parts), owner.tolist()
    (2, [1, 1])
    """
    parts, owner = shapely.get_parts(np.asarray(geoms, dtype=object).ravel(),
                                     return_index=True)
    nested = shapely.get_type_id(parts) == 7
    if nested.any():
        inner, j = shapely.get_parts(parts[nested], return_index=True)
        parts = np.concatenate([parts[~nested], inner])
        owner = np.concatenate([owner[~nested], owner[nested][j]])
    poly = shapely.get_type_id(parts) == 3
    return parts[poly], owner[poly]


def without_areas(geoms: Sequence, areas: Sequence) -> np.ndarray:
    """Each geometry less the union of the ``areas`` it meets (e.g. blocks less the street
    surfaces and junctions that reach into them), in 2D.

    >>> block = shapely.box(0, 0, 10, 10)
    >>> street = shapely.box(4, -1, 6, 11)
    >>> [round(g.area, 6) for g in without_areas([block, shapely.box(20, 0, 21, 1)], [street])]
    [80.0, 1.0]
    """
    geoms = np.asarray(geoms, dtype=object).ravel()
    areas = shapely.force_2d(np.asarray(areas, dtype=object).ravel())
    areas = areas[~(shapely.is_missing(areas) | shapely.is_empty(areas))]
    out = geoms.copy()
    if len(areas) == 0 or len(geoms) == 0:
        return out
    areas = shapely.make_valid(areas)
    g_idx, a_idx = shapely.STRtree(areas).query(geoms, predicate="intersects")
    if len(g_idx):
        starts = np.flatnonzero(group_starts(g_idx))
        ends = np.append(starts[1:], len(g_idx))
        for s, e in zip(starts, ends):  # one union per geometry: the areas it meets only
            i = g_idx[s]
            out[i] = shapely.difference(shapely.force_2d(geoms[i]),
                                        shapely.union_all(areas[a_idx[s:e]]))
    return out


def too_thin(polygons: Sequence, width: float = MIN_BUILDABLE_WIDTH) -> np.ndarray:
    """Per polygon: True where no disc ``width`` across fits in it anywhere (its inward
    offset by ``width / 2`` is empty), i.e. it is narrower than ``width`` everywhere.

    The one rule of what land is too thin to build on (:data:`MIN_BUILDABLE_WIDTH`): a
    strip, a sliver or a small island is; a block with one wide part is not, however thin
    its other arms. Empty geometries are too thin; with ``width`` 0 nothing is.

    >>> strip, plot = shapely.box(0, 0, 120, 1.3), shapely.box(0, 0, 20, 9)
    >>> too_thin([strip, plot, shapely.Polygon()]).tolist()
    [True, False, True]
    >>> too_thin([plot], 10.0).tolist()
    [True]
    """
    polygons = np.asarray(polygons, dtype=object).ravel()
    empty = shapely.is_missing(polygons) | shapely.is_empty(polygons)
    if width <= 0:
        return empty
    out = empty.copy()
    core = shapely.buffer(polygons[~empty], -width / 2.0, quad_segs=2, join_style="mitre")
    out[~empty] = shapely.is_empty(core) | (shapely.area(core) <= 0)
    return out


def largest_polygons(geoms: Sequence) -> np.ndarray:
    """Valid single polygons: the largest polygon part of each geometry after
    ``make_valid`` (None where there is none).

    >>> bow = shapely.from_wkt("POLYGON ((0 0, 4 4, 4 0, 0 4, 0 0))")  # a bow tie
    >>> [round(g.area, 6) for g in largest_polygons([bow])]
    [4.0]
    >>> largest_polygons([shapely.LineString([(0, 0), (1, 1)])]).tolist()
    [None]
    """
    geoms = shapely.make_valid(np.asarray(geoms, dtype=object))
    parts, idx = polygon_parts(geoms)
    out = np.full(len(geoms), None, dtype=object)
    if len(parts):
        area = shapely.area(parts)
        order = np.lexsort((-area, idx))
        first = order[group_starts(idx[order])]
        out[idx[first]] = parts[first]
    return out


def _calipers(polygons: np.ndarray):
    """Per polygon with an areal convex hull, the best hull edge of the rotating calipers.

    Returns (ok, u, s_lo, s_hi, t_lo, t_hi): ``ok`` marks the polygons with an areal hull;
    for those, the unit direction ``u`` of the edge the rectangle stands on and the
    rectangle's extent along ``u`` (s) and along its left normal (t).
    """
    hulls = shapely.convex_hull(polygons)
    ok = shapely.get_type_id(hulls) == 3  # degenerate hulls (points, lines) have no area
    empty = np.zeros(0)
    if not ok.any():
        return ok, np.zeros((0, 2)), empty, empty, empty, empty
    rings = shapely.get_exterior_ring(hulls[ok])
    # the search below needs counter-clockwise rings (GEOS returns clockwise hulls)
    rings = np.where(shapely.is_ccw(rings), rings, shapely.reverse(rings))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    # vertex i starts edge i; the ring repeats its first vertex at its end
    e0 = np.flatnonzero(idx[1:] == idx[:-1])
    v = coords[e0]
    hull = idx[e0]
    d = coords[e0 + 1] - v
    alpha = np.arctan2(d[:, 1], d[:, 0])
    start = group_starts(hull)
    first_of = np.flatnonzero(start)            # first edge of each hull
    n_edges = np.diff(np.append(first_of, len(hull)))
    # edge angles relative to the first edge of their hull: increasing in [0, 2 pi)
    rel = np.mod(alpha - alpha[first_of][hull], 2 * np.pi)
    rel[start] = 0.0
    key = hull * 8.0 + rel

    def support(turn):
        """Index of the vertex extreme in direction (edge angle + turn - pi/2)."""
        target = hull * 8.0 + np.mod(rel + turn, 2 * np.pi)
        i = np.searchsorted(key, target, side="left")
        end = first_of[hull] + n_edges[hull]
        return np.where(i >= end, first_of[hull], i)

    u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)[:, None]
    hi_along, lo_along, far = support(np.pi / 2), support(1.5 * np.pi), support(np.pi)
    along = np.einsum("ij,ij->i", v[hi_along] - v[lo_along], u)
    w = v[far] - v
    across = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    order = np.lexsort((along * across, hull))
    best = order[group_starts(hull[order])]
    ub = u[best]
    normal = np.column_stack([-ub[:, 1], ub[:, 0]])
    s_lo = np.einsum("ij,ij->i", v[lo_along[best]], ub)
    t_lo = np.einsum("ij,ij->i", v[best], normal)
    return ok, ub, s_lo, s_lo + along[best], t_lo, t_lo + across[best]


def minimum_rectangles(polygons: Sequence):
    """Minimum-area bounding rectangles of polygons, vectorised rotating calipers.

    The minimum-area rectangle has a side on an edge of the convex hull (Freeman &
    Shapira 1975). For every hull edge the three other sides touch the hull at its support
    vertices in the edge's directions; on a convex polygon walked counter-clockwise, the
    edge angles increase through one turn, so each support vertex is found by a binary
    search over the hull's edge angles (all edges of all polygons at once).

    Parameters
    ----------
    polygons : array of Polygon

    Returns
    -------
    length, width : float arrays
        Longer and shorter side of the rectangle (m); 0 for degenerate polygons.
    angle : float array
        Direction of the longer side in degrees, in [0, 180) counter-clockwise from east.

    References
    ----------
    Freeman, H. and Shapira, R. (1975) Determining the minimum-area encasing rectangle for
    an arbitrary closed curve. Communications of the ACM 18(7).

    Examples
    --------
    >>> rect = shapely.affinity.rotate(shapely.box(0, 0, 40, 10), 30, origin=(0, 0))
    >>> [round(float(v[0]), 6) for v in minimum_rectangles([rect])]
    [40.0, 10.0, 30.0]
    """
    polygons = np.asarray(polygons, dtype=object)
    n = len(polygons)
    length, width, angle = np.zeros(n), np.zeros(n), np.zeros(n)
    if n == 0:
        return length, width, angle
    ok, u, s_lo, s_hi, t_lo, t_hi = _calipers(polygons)
    if not ok.any():
        return length, width, angle
    a, b = s_hi - s_lo, t_hi - t_lo
    dir_long = np.where((a >= b)[:, None], u, np.column_stack([-u[:, 1], u[:, 0]]))
    length[ok] = np.maximum(a, b)
    width[ok] = np.minimum(a, b)
    angle[ok] = np.degrees(np.arctan2(dir_long[:, 1], dir_long[:, 0])) % 180.0
    return length, width, angle


def minimum_rectangle_corners(polygons: Sequence) -> np.ndarray:
    """Corners (n, 4, 2) of the minimum-area bounding rectangles (counter-clockwise), by
    the calipers of :func:`minimum_rectangles`. A polygon whose hull has no area (all
    points on a line) gets the rectangle of zero width along that line; an empty one NaN.

    >>> c = minimum_rectangle_corners([shapely.box(0, 0, 4, 2)])[0]
    >>> sorted(map(tuple, np.round(c, 9) + 0.0))
    [(0.0, 0.0), (0.0, 2.0), (4.0, 0.0), (4.0, 2.0)]
    """
    polygons = np.asarray(polygons, dtype=object)
    out = np.full((len(polygons), 4, 2), np.nan)
    if len(polygons) == 0:
        return out
    ok, u, s_lo, s_hi, t_lo, t_hi = _calipers(polygons)
    if ok.any():
        nrm = np.column_stack([-u[:, 1], u[:, 0]])
        corner = [(s_lo, t_lo), (s_hi, t_lo), (s_hi, t_hi), (s_lo, t_hi)]
        out[ok] = np.stack([s[:, None] * u + t[:, None] * nrm for s, t in corner], axis=1)
    for i in np.flatnonzero(~ok):
        xy = shapely.get_coordinates(polygons[i])
        if len(xy) == 0:
            continue
        # a segment or a point: its two extreme points along the line, as a flat rectangle
        d = xy - xy[0]
        direction = unit(d[int(np.argmax(np.hypot(d[:, 0], d[:, 1])))])
        s = d @ direction
        lo, hi = xy[int(np.argmin(s))], xy[int(np.argmax(s))]
        out[i] = [lo, hi, hi, lo]
    return out


def longest_edge_directions(rings: Sequence) -> np.ndarray:
    """Direction (radians, from the edge's first vertex to its second) of each ring's or
    line's longest edge; the first of equally long edges. 0 for one without an edge.

    >>> box = shapely.box(0, 0, 4, 2)   # drawn from (4, 0) counter-clockwise
    >>> longest_edge_directions([box.exterior]).round(6).tolist()
    [3.141593]
    """
    rings = np.asarray(rings, dtype=object)
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    step, owner = np.diff(coords, axis=0)[same], idx[1:][same]
    order = np.lexsort((-np.hypot(step[:, 0], step[:, 1]), owner))
    longest = order[group_starts(owner[order])]
    out = np.zeros(len(rings))
    out[owner[longest]] = np.arctan2(step[longest, 1], step[longest, 0])
    return out


# --------------------------------------------------------------------------- curves

def ring_turns(xy: np.ndarray) -> np.ndarray:
    """Turn (degrees, positive to the left, in [-180, 180]) at every vertex of a closed ring
    given without its closing vertex.

    >>> ring_turns(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])).tolist()
    [90.0, 90.0, 90.0, 90.0]
    """
    xy = np.asarray(xy, dtype=float)
    into = xy - np.roll(xy, 1, axis=0)
    out_of = np.roll(xy, -1, axis=0) - xy
    return np.degrees(np.arctan2(into[:, 0] * out_of[:, 1] - into[:, 1] * out_of[:, 0],
                                 (into * out_of).sum(1)))


def _rounded_ring(xy: np.ndarray, max_turn: float, reach, step: float):
    """Coordinates of a closed ring with its bends rounded (see :func:`rounded_bends`), or
    None when it has no bend to round. ``reach`` is metres, or a function of the signed
    turns (degrees, left positive) giving each bend's reach (0: the bend stays)."""
    xy = np.asarray(xy, dtype=float)[:-1]
    if len(xy) < 3:
        return None
    into = xy - np.roll(xy, 1, axis=0)
    out_of = np.roll(xy, -1, axis=0) - xy
    len_in, len_out = np.hypot(*into.T), np.hypot(*out_of.T)
    signed = ring_turns(xy)
    turn = np.abs(signed)
    reaches = reach(signed) if callable(reach) else np.full(len(xy), float(reach))
    bend = (turn > step) & (turn <= max_turn) & (len_in > 0) & (len_out > 0) & (reaches > 0)
    if not bend.any():
        return None
    pieces = []
    for k in range(len(xy)):
        if not bend[k]:
            pieces.append(xy[k:k + 1])
            continue
        # the arc starts and ends at most 0.4 of an edge away: neighbouring arcs never meet
        t = min(reaches[k], 0.4 * len_in[k], 0.4 * len_out[k])
        start = xy[k] - t * into[k] / len_in[k]
        end = xy[k] + t * out_of[k] / len_out[k]
        s = np.linspace(0.0, 1.0, max(2, math.ceil(turn[k] / step)) + 1)[:, None]
        pieces.append((1 - s) ** 2 * start + 2 * s * (1 - s) * xy[k] + s ** 2 * end)
    ring = np.vstack(pieces)
    return np.vstack([ring, ring[:1]])


def rounded_bends(polygon, max_turn: float, reach: float, step: float = 5.0):
    """The polygon with each vertex whose outline turns by more than ``step`` and at most
    ``max_turn`` degrees (a bend of a curved side, not a corner) replaced by a quadratic
    Bézier arc from ``reach`` metres before it to ``reach`` metres after it (at most 0.4 of
    either edge), sampled in ceil(turn / step) even steps of its parameter, so that a
    vertex of the arc turns by about ``step`` degrees (a 20-degree bend in 5-degree steps:
    2.5, 5.0, 5.1, 5.0, 2.5). Sharper corners, and flatter bends, stay as they are; the
    outline moves by
    about ``reach * sin(turn / 2) / 2`` at a bend (the arc's polyline a little more). A
    result that would not be valid (the arcs of two bends of a narrow neck crossing) is
    not returned: the polygon comes back as it was. Written here because shapely smooths
    no curve.

    Examples
    --------
    >>> sixteen_gon = shapely.Point(0, 0).buffer(50, quad_segs=4)  # bends of 22.5°
    >>> round_ = rounded_bends(sixteen_gon, max_turn=35.0, reach=7.5)
    >>> len(shapely.get_coordinates(sixteen_gon)), len(shapely.get_coordinates(round_))
    (17, 97)
    >>> round(shapely.hausdorff_distance(sixteen_gon, round_), 2)  # 7.5 sin(11.25°) / 2 = 0.73
    0.76
    >>> rounded_bends(shapely.box(0, 0, 40, 20), max_turn=35.0, reach=7.5).equals(
    ...     shapely.box(0, 0, 40, 20))
    True
    """
    # near-repeated vertices (a buffer's seams) would give their bends no direction
    polygon = shapely.remove_repeated_points(polygon, 0.01)
    rounded = [_rounded_ring(shapely.get_coordinates(r), max_turn, reach, step)
               for r in _rings(polygon)]
    if all(r is None for r in rounded):
        return polygon
    return _with_rings(polygon, rounded)


def _rings(polygon) -> list:
    """The exterior ring and the holes of a polygon."""
    return [shapely.get_exterior_ring(polygon)] + [
        shapely.get_interior_ring(polygon, i)
        for i in range(shapely.get_num_interior_rings(polygon))]


def _with_rings(polygon, new: list):
    """The polygon with the rings that ``new`` gives coordinates for (None: as it was)
    replaced; the polygon as it was when the result is not valid."""
    xy = [shapely.get_coordinates(r) if n is None else n for r, n in zip(_rings(polygon), new)]
    # holes as rings: their vertex counts differ, so they make no (k, n, 2) coordinate array
    out = shapely.polygons(xy[0], holes=[shapely.linearrings(h) for h in xy[1:]] or None)
    return out if shapely.is_valid(out) else polygon


def rounded_band_bends(band, half_width: float, max_turn: float, step: float = 5.0):
    """A street band (lines buffered by ``half_width``, square caps, mitre joins) with its
    shallow bends (turning by more than ``step`` and at most ``max_turn`` degrees) rounded
    without narrowing it: where its outline is reflex (the inner side of a bend of the
    lines, where the land beside the band has a corner pointing into the street) by the arc
    of :func:`rounded_bends` reaching ``half_width`` along each side (the band grows);
    where it is convex (a mitre's tip) by an arc reaching half way to where the circle of
    ``half_width`` round the bend touches the sides (``half_width * tan(turn / 2) / 2``
    from the tip), which cuts the tip off but keeps outside that circle, its chords
    included. The land beside the band then has no corner at a bend that Yang's Table 1
    counts (its arcs turn by about ``step`` at a vertex) and never reaches into the
    street's half width.

    >>> bent = shapely.LineString([(0, 0), (50, 0), (100, 15)])   # a bend of 16.7°
    >>> band = shapely.buffer(bent, 7.5, cap_style="square", join_style="mitre")
    >>> rounded = rounded_band_bends(band, 7.5, 35.0)
    >>> round(float(shapely.distance(bent, rounded.exterior)), 6)   # the half width kept
    7.5
    >>> sorted(set(np.abs(ring_turns(shapely.get_coordinates(rounded.exterior)[:-1])).round(1)))
    [0.0, 2.1, 4.2, 90.0]
    >>> round(rounded.area - band.area, 2)   # the inner side's arc adds, the tip's cuts
    3.01
    """
    def reach(turns):
        # oriented: the band on the left of its outline; a right turn is reflex
        tip = 0.5 * half_width * np.tan(np.radians(np.abs(turns)) / 2)
        return np.where(turns < 0, half_width, tip)

    out = []
    for part in shapely.get_parts(band):
        part = shapely.geometry.polygon.orient(part, 1.0)
        out.append(_with_rings(part, [
            _rounded_ring(shapely.get_coordinates(shapely.remove_repeated_points(r, 0.01)),
                          max_turn, reach, step) for r in _rings(part)]))
    return shapely.union_all(out) if len(out) != 1 else out[0]
