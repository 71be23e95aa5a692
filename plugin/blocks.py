"""City blocks: the faces of the planar street graph, with shape measures and contents.

Hartmann's thesis defines a city block as a minimal cycle of the planar street graph
(ch. 4.1.2: "a fragment whose interior has only dead-end streets is stored as a city
block"; ch. 5.1: "query blocks are the minimal cycles of the input street graph", a block
being D = (B, P), its boundary polygon and its footprints). The minimal cycles of a planar
embedded graph are its bounded faces, so blocks are computed here by polygonizing the
noded street edges (``shapely.polygonize``): edges that bound no face (dead-end streets and
the bridges of the graph between two loops) lie inside a block and do not split it, as in
the thesis.

Real OSM makes artefact faces (DESIGN.md, "Real example data"): dual carriageways, slip
roads and traffic islands close small or thin faces that are road surface, not blocks.
A face is dropped when its area is under ``min_area`` or its mean width ``2 * area /
perimeter`` (the width of a long strip) is under ``min_width``; the thesis does the same
for its raster artefacts (ch. 4.2, "delete the artefact blocks of area 0.5 px²").

Buildings and parcels are assigned to at most one block each: the block that holds the
largest share of their area, if that share is at least ``min_share`` (a half by default).
Features outside every closed block (the extract is clipped, so many lie beyond the
outermost street loop: only 62 % of Helsinki's buildings are inside a face closed by
drivable roads, DESIGN.md) keep no block: ``block_id`` is missing and ``in_block`` False.
They are kept, not deleted, so the caller decides what to do with them.

Shape measures follow the thesis (ch. 4.2 evaluation): compactness = block area / area of
the minimum bounding rectangle, aspect ratio = shorter / longer side of that rectangle.

Everything is vectorised with shapely 2 / numpy; the minimum-area rectangles use a numpy
rotating-calipers pass over the convex hulls (GEOS 3.11's oriented envelope costs about a
millisecond per polygon).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from .progress import InputError, Progress, ensure
from .roads import RoadGraph

__all__ = [
    "MIN_BLOCK_AREA", "MIN_BLOCK_WIDTH", "MIN_SHARE", "BLOCK_FIELDS", "BlockExtraction",
    "block_faces", "minimum_rectangles", "shape_metrics", "assign_to_blocks",
    "extract_blocks",
]

#: Faces smaller than this (m²) are traffic islands and junction artefacts, not blocks.
MIN_BLOCK_AREA = 400.0
#: Faces whose mean width 2·area/perimeter is under this (m) are slivers between
#: dual carriageways or slip roads (a 120 m x 8 m Helsinki median has 6.9 m).
MIN_BLOCK_WIDTH = 8.0
#: A building or parcel belongs to the block holding at least this share of its area.
MIN_SHARE = 0.5

#: Per-block attributes of :attr:`BlockExtraction.table` with their types.
BLOCK_FIELDS = [
    ("block_id", "int"), ("area_m2", "float"), ("perimeter_m", "float"),
    ("compactness", "float"), ("aspect_ratio", "float"), ("mbr_length_m", "float"),
    ("mbr_width_m", "float"), ("mbr_angle_deg", "float"), ("n_holes", "int"),
    ("n_dead_ends", "int"), ("n_buildings", "int"), ("building_coverage", "float"),
    ("n_parcels", "int"),
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
        Counts for the log: ``n_faces`` (all faces), ``n_small``, ``n_thin`` (dropped
        faces), ``n_blocks``, ``n_buildings_in_blocks``, ``n_parcels_in_blocks``.
    """

    geometry: np.ndarray
    table: pd.DataFrame
    buildings: Optional[pd.DataFrame] = None
    parcels: Optional[pd.DataFrame] = None
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- faces

def block_faces(lines: Sequence, min_area: float = MIN_BLOCK_AREA,
                min_width: float = MIN_BLOCK_WIDTH):
    """Bounded faces of a street network, without the sliver faces.

    Parameters
    ----------
    lines : array of LineString
        Street centrelines in a metric CRS. They are noded together first (edges of
        different vertical layers may cross without a node in the street graph, and
        snapping may move an end slightly across a neighbour), so any line set works.
    min_area : float
        Faces smaller than this (m²) are dropped.
    min_width : float
        Faces whose mean width ``2 * area / perimeter`` is under this (m) are dropped.

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
    DESIGN.md, "Real example data" (slivers of dual carriageways and service roads).

    Examples
    --------
    >>> import shapely
    >>> grid = [shapely.LineString([(0, y), (200, y)]) for y in (0, 100, 200)] + \\
    ...        [shapely.LineString([(x, 0), (x, 200)]) for x in (0, 100, 200)]
    >>> faces, counts = block_faces(grid)
    >>> len(faces), counts["n_faces"]
    (4, 4)
    """
    if min_area < 0 or min_width < 0:
        raise InputError("the minimum block area and width must not be negative")
    lines = np.asarray(lines, dtype=object)
    lines = lines[~(shapely.is_missing(lines) | shapely.is_empty(lines))]
    if len(lines) == 0:
        raise InputError("no road lines")
    noded = shapely.get_parts(shapely.node(shapely.multilinestrings(shapely.get_parts(lines))))
    faces = shapely.get_parts(shapely.polygonize(noded))
    n_faces = len(faces)
    if n_faces == 0:
        raise InputError("no closed block: the roads form no closed face")
    area = shapely.area(faces)
    perimeter = shapely.length(faces)
    small = area < min_area
    thin = ~small & (2.0 * area < min_width * perimeter)
    faces = faces[~(small | thin)]
    # polygonize returns valid faces for noded input; repair defensively all the same
    invalid = ~shapely.is_valid(faces)
    if invalid.any():
        faces[invalid] = [_largest_polygon(shapely.make_valid(f)) for f in faces[invalid]]
        faces = faces[~shapely.is_empty(faces)]
    bounds = shapely.bounds(faces)
    order = np.lexsort((np.round(bounds[:, 0], 3), np.round(bounds[:, 1], 3)))
    return faces[order], {"n_faces": n_faces, "n_small": int(small.sum()),
                          "n_thin": int(thin.sum())}


def _largest_polygon(geom):
    parts = [p for p in shapely.get_parts(geom) if shapely.get_type_id(p) == 3]
    if not parts:
        return shapely.from_wkt("POLYGON EMPTY")
    return max(parts, key=shapely.area)


# --------------------------------------------------------------------------- shape

def minimum_rectangles(polygons: Sequence):
    """Minimum-area bounding rectangles of polygons, vectorised (rotating calipers).

    The minimum-area rectangle has a side on an edge of the convex hull (Freeman &
    Shapira 1975), so every hull edge direction is tried for every polygon at once.

    Parameters
    ----------
    polygons : array of Polygon

    Returns
    -------
    length, width : float arrays
        Longer and shorter side of the rectangle (m).
    angle : float array
        Direction of the longer side in degrees, in [0, 180) counter-clockwise from east.
    """
    polygons = np.asarray(polygons, dtype=object)
    n = len(polygons)
    length, width, angle = np.zeros(n), np.zeros(n), np.zeros(n)
    if n == 0:
        return length, width, angle
    hulls = shapely.convex_hull(polygons)
    ok = shapely.get_type_id(hulls) == 3  # degenerate hulls (points, lines) have no area
    rings = shapely.get_exterior_ring(hulls[ok])
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    # consecutive vertices of one ring make an edge (the ring repeats its first vertex)
    same = idx[1:] == idx[:-1]
    e0 = np.flatnonzero(same)
    d = coords[e0 + 1] - coords[e0]
    d /= np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    edge_poly = idx[e0]
    # pair every edge with every vertex of its own hull: sum of squared hull sizes
    counts = np.bincount(idx, minlength=ok.sum())
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    n_vert = counts[edge_poly]
    pair_edge = np.repeat(np.arange(len(e0)), n_vert)
    offset = np.arange(len(pair_edge)) - np.repeat(np.cumsum(n_vert) - n_vert, n_vert)
    pair_vert = starts[edge_poly][pair_edge] + offset
    p = coords[pair_vert]
    u = d[pair_edge]
    s = p[:, 0] * u[:, 0] + p[:, 1] * u[:, 1]           # along the edge
    t = -p[:, 0] * u[:, 1] + p[:, 1] * u[:, 0]          # across the edge
    edge_starts = np.r_[0, np.cumsum(n_vert)[:-1]]
    along = np.maximum.reduceat(s, edge_starts) - np.minimum.reduceat(s, edge_starts)
    across = np.maximum.reduceat(t, edge_starts) - np.minimum.reduceat(t, edge_starts)
    area = along * across
    # the best edge per polygon: sort by (polygon, area) and take the first of each
    order = np.lexsort((area, edge_poly))
    first = order[np.r_[True, edge_poly[order][1:] != edge_poly[order][:-1]]]
    a, b = along[first], across[first]
    dir_long = np.where((a >= b)[:, None], d[first], np.column_stack([-d[first, 1], d[first, 0]]))
    length[ok] = np.maximum(a, b)
    width[ok] = np.minimum(a, b)
    angle[ok] = np.degrees(np.arctan2(dir_long[:, 1], dir_long[:, 0])) % 180.0
    return length, width, angle


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
    polygons = np.asarray(polygons, dtype=object)
    area = shapely.area(polygons)
    length, width, angle = minimum_rectangles(polygons)
    rect = length * width
    with np.errstate(divide="ignore", invalid="ignore"):
        compactness = np.where(rect > 0, np.minimum(area / rect, 1.0), np.nan)
        aspect = np.where(length > 0, width / length, np.nan)
    return pd.DataFrame({
        "area_m2": area, "perimeter_m": shapely.length(polygons), "compactness": compactness,
        "aspect_ratio": aspect, "mbr_length_m": length, "mbr_width_m": width,
        "mbr_angle_deg": angle, "n_holes": shapely.get_num_interior_rings(polygons),
    })


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
    >>> index, share = assign_to_blocks(blocks, [shapely.box(6, 2, 12, 4), shapely.box(30, 0, 31, 1)])
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
                s = np.where(area > 0, shapely.area(shapely.intersection(geoms[g], blocks[b])) / area, 0.0)
            order = np.lexsort((-s, g))
            best = order[np.r_[True, g[order][1:] != g[order][:-1]]]
            ok = s[best] >= min_share
            index[g[best[ok]]] = b[best[ok]]
            share[g[best[ok]]] = np.minimum(s[best[ok]], 1.0)
    return index, share


def _membership_table(index: np.ndarray, share: np.ndarray, block_ids: np.ndarray) -> pd.DataFrame:
    inside = index >= 0
    ids = pd.array(np.where(inside, block_ids[np.maximum(index, 0)], 0), dtype="Int64")
    ids[~inside] = pd.NA
    return pd.DataFrame({"block_id": ids, "block_share": share, "in_block": inside})


def _dead_end_points(graph: RoadGraph) -> np.ndarray:
    return shapely.points(graph.nodes[graph.degree == 1])


# --------------------------------------------------------------------------- main API

def extract_blocks(roads, buildings: Optional[Sequence] = None,
                   parcels: Optional[Sequence] = None,
                   min_area: float = MIN_BLOCK_AREA, min_width: float = MIN_BLOCK_WIDTH,
                   min_share: float = MIN_SHARE,
                   progress: Optional[Progress] = None) -> BlockExtraction:
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
    is its boundary polygon and its footprints); DESIGN.md, "Real example data".
    """
    progress = ensure(progress)
    if isinstance(roads, RoadGraph):
        lines, dead_ends = roads.geometry, _dead_end_points(roads)
    else:
        lines = np.asarray(roads, dtype=object)
        from .roads import graph_from_lines

        parts = shapely.get_parts(lines)
        noded = shapely.get_parts(shapely.node(shapely.multilinestrings(parts)))
        none = np.full(len(noded), None, dtype=object)
        dead_ends = _dead_end_points(graph_from_lines(noded, none, none, np.zeros(len(noded)),
                                                      np.arange(len(noded))))
    progress.step(0.0)
    faces, counts = block_faces(lines, min_area, min_width)
    progress.step(0.4)
    if len(faces) == 0:
        raise InputError(
            f"no closed block: all {counts['n_faces']} faces of the roads are smaller than "
            f"{min_area:g} m² or narrower than {min_width:g} m (lower the minimum block area "
            "or width)")
    table = shape_metrics(faces)
    block_ids = np.arange(1, len(faces) + 1, dtype=np.int64)
    table.insert(0, "block_id", block_ids)
    tree = shapely.STRtree(faces)
    progress.step(0.55)

    _, hit = tree.query(dead_ends, predicate="within")
    table["n_dead_ends"] = np.bincount(hit, minlength=len(faces))
    stats = dict(counts, n_blocks=len(faces))

    result = BlockExtraction(faces, table, stats=stats)
    covered = np.zeros(len(faces))
    if buildings is not None:
        b = np.asarray(buildings, dtype=object)
        index, share = assign_to_blocks(faces, b, min_share, tree)
        inside = index >= 0
        table["n_buildings"] = np.bincount(index[inside], minlength=len(faces))
        covered = np.bincount(index[inside], shapely.area(b[inside]) * share[inside],
                              minlength=len(faces))
        result.buildings = _membership_table(index, share, block_ids)
        stats["n_buildings"] = len(b)
        stats["n_buildings_in_blocks"] = int(inside.sum())
    else:
        table["n_buildings"] = 0
    progress.step(0.8)
    # overlapping footprints (dirty OSM) could count twice: a coverage is at most 1
    table["building_coverage"] = np.minimum(covered / table["area_m2"].to_numpy(), 1.0)
    if parcels is not None:
        p = np.asarray(parcels, dtype=object)
        index, share = assign_to_blocks(faces, p, min_share, tree)
        inside = index >= 0
        table["n_parcels"] = np.bincount(index[inside], minlength=len(faces))
        result.parcels = _membership_table(index, share, block_ids)
        stats["n_parcels"] = len(p)
        stats["n_parcels_in_blocks"] = int(inside.sum())
    else:
        table["n_parcels"] = 0
    result.table = table[[name for name, _ in BLOCK_FIELDS]]
    progress.step(1.0)
    return result
