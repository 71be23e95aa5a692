"""Hierarchical road fragments: minimal cycles per street level with their interior streets.

Hartmann's thesis (ch. 4.1.2, "Data structures") decomposes a levelled street network
into fragments: a fragment F_l of level l has

- a boundary, a minimal cycle of the subgraph of streets with level <= l. The minimal
  cycles of a planar embedded graph are its bounded faces, so they are computed with the
  blocks module's face tracing (the same faces as ``shapely.polygonize``; dead ends and
  bridges between loops bound no face), without the sliver faces of dual carriageways;
- interior streets: only the streets of level exactly l + 1 inside it (deeper levels are
  ignored for this fragment: they belong to the fragments of level l + 1);
- the terrain relief under it, when a DEM is given;
- a fragment whose interior streets do not split it (only dead ends, or none) is a
  **city block** (``is_block``): no face of the level <= l + 1 subgraph other than itself
  lies inside it.

Fragments are made for the levels 0 .. L - 1 of a network with levels 0 .. L (level L
streets have no deeper level to hold). Everything is vectorised over faces and streets
(STRtree queries, shapely 2 array functions, numpy reductions).

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 4.1.2
(fragments F_l, boundaries as minimal cycles of the level <= l subgraph, interior streets
of level l + 1, relief, fragments with only dead-end streets stored as city blocks).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core.progress import InputError, Progress, ensure
from ..retrieval.shape_context import DemGrid
from .blocks import MIN_BLOCK_AREA, MIN_BLOCK_WIDTH, block_faces, shape_metrics
from .street_graph import degree2_chains, merge_chains

__all__ = ["RELIEF_CELL_SIZE", "MAX_PATCH_CELLS", "FRAGMENT_FIELDS", "Fragments",
           "extract_fragments", "interior_streets", "relief_patches", "street_chains"]

#: Cell size (m) of the relief patch stored per fragment.
RELIEF_CELL_SIZE = 5.0
#: A relief patch larger than this many cells is stored at a coarser cell size.
MAX_PATCH_CELLS = 250_000

#: Per-fragment attributes of :attr:`Fragments.table` with their types.
FRAGMENT_FIELDS = [
    ("fragment_id", "int"), ("level", "int"), ("area_m2", "float"), ("perimeter_m", "float"),
    ("compactness", "float"), ("aspect_ratio", "float"), ("n_interior", "int"),
    ("interior_length_m", "float"), ("is_block", "bool"), ("relief_m", "float"),
    ("mean_slope", "float"), ("elevation_m", "float"),
]


@dataclass
class Fragments:
    """Result of :func:`extract_fragments`.

    Attributes
    ----------
    geometry : ndarray of Polygon
        Fragment boundaries (faces), ordered by level, then by position.
    table : DataFrame
        One row per fragment with the columns of :data:`FRAGMENT_FIELDS`; ``fragment_id``
        runs 1..n. Relief columns are NaN without a DEM.
    street_geometry : ndarray of LineString
        Interior streets (level l + 1 pieces clipped to their fragment).
    street_fragment : int array
        Index into ``geometry`` of each interior street's fragment.
    street_level : int array
        Level of each interior street (the fragment's level + 1).
    street_source : int array
        Index of the input line each interior street was cut from.
    patches : list of float32 arrays or None
        Relief patch per fragment (rows north to south), NaN where the DEM has no data.
    patch_transform : (n, 6) float array or None
        GDAL geotransform ``(x_min, cell, 0, y_max, 0, -cell)`` of each patch.
    counts : dict
        ``per_level`` {level: number of fragments}, ``blocks_per_level``,
        ``n_unassigned_streets`` (level l + 1 streets outside every level l fragment),
        ``n_faces_dropped`` (slivers), ``max_level``.
    """

    geometry: np.ndarray
    table: pd.DataFrame
    street_geometry: np.ndarray
    street_fragment: np.ndarray
    street_level: np.ndarray
    street_source: np.ndarray
    patches: Optional[List[np.ndarray]] = None
    patch_transform: Optional[np.ndarray] = None
    counts: Dict = field(default_factory=dict)

    def __len__(self):
        return len(self.geometry)


def interior_streets(faces: Sequence, lines: Sequence, min_length: float = 0.01):
    """Clip lines to the faces that contain them (vectorised).

    A street of level l + 1 lies inside one level-l face in a planar network; a merged
    street feature may also run through several faces, so each line is intersected with
    every face it meets and the line parts are kept (a line that only touches a face's
    boundary gives a point and is dropped).

    Parameters
    ----------
    faces : array of Polygon (non-overlapping)
    lines : array of LineString / MultiLineString
    min_length : float
        Pieces shorter than this (m) are dropped.

    Returns
    -------
    pieces : ndarray of LineString
    face : int array, the face of each piece
    source : int array, the line each piece comes from
    """
    faces = np.asarray(faces, dtype=object)
    lines = np.asarray(lines, dtype=object)
    empty = np.empty(0, dtype=object), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if len(faces) == 0 or len(lines) == 0:
        return empty
    tree = shapely.STRtree(faces)
    li, fi = tree.query(lines, predicate="intersects")
    if len(li) == 0:
        return empty
    # the common case needs no overlay: the line lies inside the face
    inside = shapely.contains_properly(faces[fi], lines[li])
    clipped = lines[li].copy()
    cross = ~inside
    if cross.any():
        clipped[cross] = shapely.intersection(lines[li[cross]], faces[fi[cross]])
    parts, idx = shapely.get_parts(clipped, return_index=True)
    if len(parts) == 0:
        return empty
    keep = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) >= min_length)
    parts, idx = parts[keep], idx[keep]
    if len(parts) == 0:
        return empty
    # parts of one line in one face that touch (an overlay may cut at vertices): rejoin
    uniq, inv = np.unique(idx, return_inverse=True)
    merged = shapely.line_merge(shapely.multilinestrings(parts, indices=inv))
    out, oidx = shapely.get_parts(merged, return_index=True)
    pair = uniq[oidx]
    return out, fi[pair], li[pair]


def street_chains(pieces: np.ndarray, face: np.ndarray, source: np.ndarray, faces: Sequence,
                  network: Sequence):
    """Interior streets joined where two pieces of one face meet at a point that no other
    line of the ``network`` (any level) touches, away from the face's outline, so that a
    fragment holds the same streets however its lines were split (a bridge apart from its
    approach, OSM ways cut at arbitrary points).

    A chain keeps the source of its longest piece; a chain that closes on itself, or whose
    pieces do not join into one line, keeps its pieces.

    >>> import shapely
    >>> square = shapely.box(0, 0, 100, 100)
    >>> halves = np.array([shapely.LineString([(0, 50), (50, 50)]),
    ...                    shapely.LineString([(50, 50), (100, 50)])])
    >>> side = shapely.LineString([(50, 50), (50, 100)])
    >>> chains, _, _ = street_chains(halves, np.zeros(2, int), np.arange(2), [square], halves)
    >>> [round(c.length) for c in chains]
    [100]
    >>> chains, _, _ = street_chains(halves, np.zeros(2, int), np.arange(2), [square],
    ...                              np.r_[halves, side])
    >>> [round(c.length) for c in chains]
    [50, 50]
    """
    if len(pieces) < 2:
        return pieces, face, source
    faces = np.asarray(faces, dtype=object)
    m = len(pieces)
    ends = shapely.get_coordinates(np.r_[shapely.get_point(pieces, 0),
                                         shapely.get_point(pieces, -1)])
    xy, node = np.unique(np.round(ends, 3), axis=0, return_inverse=True)  # nodes: mm
    node = node.reshape(-1)
    # a point where more than two lines of the network meet (or cross) is a junction
    at, _ = shapely.STRtree(np.asarray(network, dtype=object)).query(
        shapely.points(xy), predicate="dwithin", distance=1e-3)
    junction = np.bincount(at, minlength=len(xy)) != 2
    # an end on the face's outline meets the enclosing streets: never joined
    outline = shapely.boundary(faces[np.r_[face, face]])
    apart = junction[node] | shapely.dwithin(shapely.points(ends), outline, 1e-3)
    node = np.where(apart, len(xy) + np.arange(2 * m), node)
    comp = degree2_chains(node[:m], node[m:], len(xy) + 2 * m, face)
    if comp is None:
        return pieces, face, source
    chains, rows = merge_chains(pieces, comp, longest=True)
    return chains, face[rows], source[rows]


def relief_patches(polygons: Sequence, dem: DemGrid, cell_size: float = RELIEF_CELL_SIZE,
                   max_cells: int = MAX_PATCH_CELLS):
    """Relief statistics and a relief patch for every polygon, vectorised over all cells.

    Each polygon's bounding box is covered by cells of ``cell_size`` (coarser for huge
    polygons, so a patch holds at most ``max_cells``); the DEM is sampled bilinearly at
    every cell centre of every polygon in one call, cells inside the polygon give the
    statistics (one numpy reduction per statistic over all polygons).

    Parameters
    ----------
    polygons : array of Polygon
    dem : DemGrid
    cell_size : float (m)

    Returns
    -------
    relief : float array, max - min elevation inside, NaN off the DEM (the thesis's "relative elevation
        change" used by the retrieval prefilter)
    mean_slope : float array, mean slope magnitude (rise / run) inside
    elevation : float array, mean elevation inside
    patches : list of (rows, cols) float32 arrays
    transforms : (n, 6) float array of GDAL geotransforms

    References
    ----------
    Hartmann, thesis ch. 4.1.2: a fragment has "the terrain relief under its area"; the
    pre-filter clusters fragments by "relative elevation change".
    """
    if not cell_size > 0:
        raise InputError("the relief cell size must be positive")
    polygons = np.asarray(polygons, dtype=object)
    k = len(polygons)
    if k == 0:
        return (np.zeros(0), np.zeros(0), np.zeros(0), [], np.zeros((0, 6)))
    b = shapely.bounds(polygons)
    w = np.maximum(b[:, 2] - b[:, 0], 1e-9)
    h = np.maximum(b[:, 3] - b[:, 1], 1e-9)
    cs = np.maximum(cell_size, np.sqrt(w * h / max_cells))
    cols = np.maximum(np.ceil(w / cs).astype(np.int64), 1)
    rows = np.maximum(np.ceil(h / cs).astype(np.int64), 1)
    n_cells = rows * cols
    owner = np.repeat(np.arange(k), n_cells)
    local = np.arange(n_cells.sum()) - np.repeat(np.cumsum(n_cells) - n_cells, n_cells)
    r, c = local // cols[owner], local % cols[owner]
    x = b[owner, 0] + (c + 0.5) * cs[owner]
    y = b[owner, 3] - (r + 0.5) * cs[owner]
    z = dem(np.column_stack([x, y]))
    slope = DemGrid(dem.slope(), dem.geotransform)(np.column_stack([x, y]))
    shapely.prepare(polygons)
    inside = shapely.contains_xy(polygons[owner], x, y) & np.isfinite(z)
    starts = np.r_[0, np.cumsum(n_cells)[:-1]]
    zmax = np.maximum.reduceat(np.where(inside, z, -np.inf), starts)
    zmin = np.minimum.reduceat(np.where(inside, z, np.inf), starts)
    n_in = np.add.reduceat(inside.astype(np.int64), starts)
    zsum = np.add.reduceat(np.where(inside, z, 0.0), starts)
    ssum = np.add.reduceat(np.where(inside & np.isfinite(slope), slope, 0.0), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        relief = np.where(n_in > 0, zmax - zmin, 0.0)
        mean_slope = np.where(n_in > 0, ssum / n_in, np.nan)
        elevation = np.where(n_in > 0, zsum / n_in, np.nan)
    # polygons too thin to hold a cell centre: their representative point
    thin = n_in == 0
    if thin.any():
        pts = shapely.get_coordinates(shapely.point_on_surface(polygons[thin]))
        elevation[thin] = dem(pts)
        mean_slope[thin] = DemGrid(dem.slope(), dem.geotransform)(pts)
        # one off the DEM has no relief: unknown (NaN, as its slope and elevation), not flat
        relief[thin & ~np.isfinite(elevation)] = np.nan
    patches = [p.reshape(rr, cc).astype(np.float32)
               for p, rr, cc in zip(np.split(z, np.cumsum(n_cells)[:-1]), rows, cols)]
    transforms = np.column_stack([b[:, 0], cs, np.zeros(k), b[:, 3], np.zeros(k), -cs])
    return relief, mean_slope, elevation, patches, transforms


def extract_fragments(lines: Sequence, levels: Sequence, min_area: float = MIN_BLOCK_AREA,
                      min_width: float = MIN_BLOCK_WIDTH, dem: Optional[DemGrid] = None,
                      cell_size: float = RELIEF_CELL_SIZE,
                      progress: Optional[Progress] = None) -> Fragments:
    """Fragments of every level of a levelled street network.

    For each level l = 0 .. L - 1 (L the deepest level present): the bounded faces of the
    subgraph of streets with level <= l, without slivers, with the level l + 1 streets
    inside each; ``is_block`` when those streets do not split the face (dead ends only).

    Parameters
    ----------
    lines : array of LineString / MultiLineString
        Streets in a metric CRS (e.g. the output of the road hierarchy). They are noded
        together per level, so merged street features work as well as graph edges.
    levels : int array
        Street level per line, 0 = arterial. Negative or missing levels are not allowed
        (filter them out first). Only their order counts: the k-th smallest value present
        is level k of the fragments (``counts["level_values"]`` lists the values).
    min_area, min_width : float
        Faces smaller than ``min_area`` (m²) or with a mean width ``2 area / perimeter``
        under ``min_width`` (m) are slivers of dual carriageways and junctions, dropped as
        in the blocks module.
    dem : DemGrid, optional
        Terrain in the same CRS: adds ``relief_m``, ``mean_slope``, ``elevation_m`` and a
        relief patch per fragment.
    cell_size : float
        Cell size of the relief patches (m).

    Returns
    -------
    Fragments

    Raises
    ------
    InputError
        No lines, fewer than two levels, or no closed fragment at any level.

    References
    ----------
    Hartmann, thesis ch. 4.1.2 ("For each l, fragments are the minimal cycles of the
    subgraph with level <= l"; "interior streets: only the segments of level exactly l+1";
    "a fragment whose interior has only dead-end streets is stored as a city block").

    Examples
    --------
    >>> import shapely
    >>> ring = [shapely.LineString([(0, 0), (200, 0), (200, 200), (0, 200), (0, 0)])]
    >>> cross = [shapely.LineString([(100, 0), (100, 200)])]
    >>> f = extract_fragments(ring + cross, [0, 1])
    >>> f.table[["level", "n_interior", "is_block"]].values.tolist()
    [[0, 1, False]]
    """
    progress = ensure(progress)
    lines = np.asarray(lines, dtype=object)
    levels = np.asarray(levels)
    if len(lines) != len(levels):
        raise InputError("one level per line is needed")
    if len(lines) == 0:
        raise InputError("no road lines")
    if not np.issubdtype(levels.dtype, np.number):
        try:
            levels = levels.astype(np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError("street levels must be whole numbers") from exc
    if not np.isfinite(levels.astype(np.float64)).all() or (levels < 0).any():
        raise InputError("street levels must be whole numbers >= 0 (0 = arterial)")
    if (levels != np.round(levels)).any():
        raise InputError("street levels must be whole numbers")
    levels = levels.astype(np.int64)
    ok = ~(shapely.is_missing(lines) | shapely.is_empty(lines))
    lines, levels = lines[ok], levels[ok]
    # only the order of the levels counts: 1, 2, 3 or 3, 5, 7 or 10, 20, 30 are the levels
    # 0, 1, 2 of the database (a level between them that no street has made every fragment
    # of the level above it a block, and levels of 2^40 looped for hours)
    level_values, levels = np.unique(levels, return_inverse=True)
    levels = levels.reshape(-1).astype(np.int64)
    max_level = len(level_values) - 1
    if max_level < 1:
        raise InputError("all streets have one level"
                         + (f" ({int(level_values[0])})" if len(level_values) else "")
                         + ": fragments need at least two street levels (a level l fragment "
                         "holds the streets of level l + 1)")

    # faces of every level <= l subgraph, l = 0 .. L (level L faces only decide is_block)
    faces_by_level: List[np.ndarray] = []
    dropped = 0
    for level in range(max_level + 1):
        try:
            faces, counts = block_faces(lines[levels <= level], min_area, min_width)
            dropped += counts["n_small"] + counts["n_thin"] if level < max_level else 0
        except InputError:
            faces = np.empty(0, dtype=object)
        faces_by_level.append(faces)
        progress.step(0.5 * (level + 1) / (max_level + 1))

    geoms, lvl, n_int, int_len, is_block = [], [], [], [], []
    s_geom, s_frag, s_level, s_src, assigned = [], [], [], [], [np.zeros(0, np.int64)]
    offset = 0
    for level in range(max_level):
        faces = faces_by_level[level]
        k = len(faces)
        if k == 0:
            continue
        sel = np.flatnonzero(levels == level + 1)
        pieces, face, source = interior_streets(faces, lines[sel])
        assigned.append(sel[source])
        pieces, face, source = street_chains(pieces, face, source, faces, lines)
        n_pieces = np.bincount(face, minlength=k)
        length = np.bincount(face, weights=shapely.length(pieces), minlength=k) \
            if len(pieces) else np.zeros(k)
        # a face the level l + 1 streets do not split holds at most one level l + 1 face
        # (itself, or none when the split-off parts are all slivers)
        deeper = faces_by_level[level + 1]
        n_sub = np.zeros(k, dtype=np.int64)
        if len(deeper):
            pts = shapely.point_on_surface(deeper)
            d_idx, f_idx = shapely.STRtree(faces).query(pts, predicate="within")
            n_sub = np.bincount(f_idx, minlength=k)
        geoms.append(faces)
        lvl.append(np.full(k, level))
        n_int.append(n_pieces)
        int_len.append(length)
        is_block.append(n_sub <= 1)
        s_geom.append(pieces)
        s_frag.append(face + offset)
        s_level.append(np.full(len(pieces), level + 1))
        s_src.append(np.flatnonzero(ok)[sel[source]] if len(source) else np.zeros(0, np.int64))
        offset += k
        progress.step(0.5 + 0.3 * (level + 1) / max_level)

    if offset == 0:
        raise InputError("no closed fragment at any level: the streets of level <= l form no "
                         f"closed face of at least {min_area:g} m² and {min_width:g} m mean "
                         f"width for any l < {max_level}")
    geometry = np.concatenate(geoms)
    metrics = shape_metrics(geometry)
    table = pd.DataFrame({
        "fragment_id": np.arange(1, offset + 1),
        "level": np.concatenate(lvl),
        "area_m2": metrics["area_m2"].to_numpy(),
        "perimeter_m": metrics["perimeter_m"].to_numpy(),
        "compactness": metrics["compactness"].to_numpy(),
        "aspect_ratio": metrics["aspect_ratio"].to_numpy(),
        "n_interior": np.concatenate(n_int),
        "interior_length_m": np.concatenate(int_len),
        "is_block": np.concatenate(is_block),
        "relief_m": np.nan, "mean_slope": np.nan, "elevation_m": np.nan,
    })
    patches = transforms = None
    if dem is not None:
        relief, slope, elev, patches, transforms = relief_patches(geometry, dem, cell_size)
        table["relief_m"] = relief
        table["mean_slope"] = slope
        table["elevation_m"] = elev
    progress.step(1.0)
    per_level = table.groupby("level").size()
    blocks = table.groupby("level")["is_block"].sum()
    counts = {
        "per_level": {int(k): int(v) for k, v in per_level.items()},
        "blocks_per_level": {int(k): int(v) for k, v in blocks.items()},
        "n_unassigned_streets": int((levels >= 1).sum()) - len(np.unique(np.concatenate(assigned))),
        "n_faces_dropped": int(dropped),
        "max_level": max_level,
        # the level values given, in order: database level k is level_values[k]
        "level_values": [int(v) for v in level_values],
    }
    return Fragments(geometry, table, np.concatenate(s_geom).astype(object),
                     np.concatenate(s_frag).astype(np.int64),
                     np.concatenate(s_level).astype(np.int64),
                     np.concatenate(s_src).astype(np.int64), patches, transforms, counts)
