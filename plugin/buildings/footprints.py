"""Building footprints by example: block-layout transfer and guided re-synthesis.

For each target block the most similar example block of a block database is retrieved
(prefilter by area, perimeter and aspect ratio to c = 10, shape context + cyclic DTW on
100 boundary samples, :meth:`database.BlockDatabase.query`) and rigidly aligned with it
(Procrustes on the DTW correspondences). Then either

``transfer`` (thesis ch. 5.1)
    the aligned example footprints are copied: those not inside the block are deleted,
    those reaching into the street offset are relaxed rigidly (position-based dynamics
    with shape matching, :mod:`footprint_transfer`);
``resynthesis`` (thesis ch. 5.2, the re-targeting paper)
    the example footprints are the discrete elements, the mean value coordinate warp from
    the aligned example boundary onto the target boundary gives the guidance map, and a
    new layout is composed per street segment by dynamic programming
    (:mod:`footprint_resynthesis`).

Both end with :func:`legalise`, the hard guarantee of docs/ARCHITECTURE.md ("Quality
measures"): every output footprint lies inside its block and outside the road surface +
setback, and no two footprints overlap (they keep at least 1 cm apart); what still
conflicts is trimmed to the free space (kept when at least half of it remains) or dropped.

The per-block work :func:`synthesize_block` is a pure function of (block, databases,
method, seed, block index, parameters), so blocks can be distributed over workers with
identical results; :func:`synthesize_footprints` loops over blocks with progress.

References
----------
Hartmann, S., thesis ch. 5.1 (block layout transfer) and 5.2 (guided re-synthesis);
Hartmann et al. (2015), Layout retargeting.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core.geometry import (MIN_BUILDABLE_AREA, MIN_BUILDABLE_WIDTH, counter_clockwise,
                             largest_polygons, one_areal, polygon_parts, too_thin,
                             without_areas)
from ..core.progress import InputError, Progress, ensure
from ..core.seeds import place_key
from ..network.blocks import shape_metrics
from ..retrieval import shape_context as sc
from ..retrieval.database import N_CANDIDATES, BlockDatabase
from . import frontage
from .footprint_resynthesis import retarget_layout
from .footprint_transfer import classify, relax

__all__ = ["METHODS", "OUTPUT_FIELDS", "ExampleSet", "BlockLayout", "FootprintResult",
           "prepare_examples", "street_offset", "legalise", "synthesize_block",
           "synthesize_footprints"]

METHODS = ("transfer", "resynthesis")
#: Output fields (name, type) of the synthesised footprints.
OUTPUT_FIELDS = [("block_id", "int"), ("height_m", "float"), ("levels", "float"),
                 ("building_type", "str"), ("source_block", "int"), ("source_building", "int"),
                 ("database", "str"), ("method", "str"), ("placement", "str")]
#: Default street width (m): the road surface is half of it on each side of a centreline.
STREET_WIDTH = 6.0
#: A trimmed footprint is kept when at least this share of its area remains.
MIN_KEEP = 0.5
#: Footprints smaller than this (m²) after trimming are dropped.
MIN_AREA = 4.0
#: A trimmed footprint keeping this share of its area is intact (not a sliver).
INTACT = 0.9
#: Distance kept between footprints and from the street offset (m).
GAP = 0.01
#: Boundary correspondences (at most) of the re-synthesis warp.
WARP_VERTICES = 50
#: Blocks larger than this (m²) are not filled (a district-sized face is no city block).
MAX_BLOCK_AREA = 2.0e6


@dataclass
class ExampleSet:
    """A block database prepared for synthesis: footprints as clean polygons per block.

    ``frontage_angle``: per database building, its signed angle (radians) to the nearest
    street of its example block (the block outline runs along the centrelines), NaN when
    farther than :data:`frontage.REACH` (interior buildings), and ``frontage_offset`` its
    centroid's distance to that street; ``min_area``: the 10th percentile of the example
    footprint areas -- a footprint trimmed below it is a sliver.
    """

    db: BlockDatabase
    name: str
    polygons: np.ndarray                 # per database building, a Polygon (or None)
    attributes: pd.DataFrame             # height_m, levels, building_type, building_id
    rows_of_block: Dict[int, np.ndarray]  # block_id -> building rows
    usable: np.ndarray                   # database rows with enough footprints
    frontage_angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    min_area: float = 0.0
    frontage_offset: np.ndarray = field(default_factory=lambda: np.zeros(0))


def prepare_examples(db: BlockDatabase, name: str = "", min_buildings: int = 1) -> ExampleSet:
    """Index a loaded block database for :func:`synthesize_block`.

    ``min_buildings``: example blocks with fewer footprints are not retrieved (an empty
    example block in a clipped OSM extract is usually an artefact of the clip).
    """
    if len(db) == 0:
        raise InputError(f"the block database {name or db.path} holds no block")
    b = db.buildings if db.buildings is not None else pd.DataFrame()
    polys = largest_polygons(db.building_geometry) if len(b) else np.zeros(0, object)
    attrs = pd.DataFrame({
        "height_m": pd.to_numeric(b.get("height_m", pd.Series(np.nan, index=b.index)),
                                  errors="coerce").to_numpy(dtype=float),
        "levels": pd.to_numeric(b.get("levels", pd.Series(np.nan, index=b.index)),
                                errors="coerce").to_numpy(dtype=float),
        "building_type": b.get("building_type", pd.Series(None, index=b.index)).to_numpy(
            dtype=object),
        "building_id": b.get("building_id", pd.Series(np.arange(1, len(b) + 1))).to_numpy(),
    })
    ok = np.array([p is not None for p in polys], dtype=bool)
    block_of = b["block_id"].to_numpy() if len(b) else np.zeros(0, np.int64)
    rows = {int(k): np.flatnonzero((block_of == k) & ok) for k in np.unique(block_of)}
    counts = np.array([len(rows.get(int(k), ())) for k in db.ids])
    usable = np.flatnonzero(counts >= max(int(min_buildings), 0))
    if len(usable) == 0:
        raise InputError(f"the block database {name or db.path} has no block with at least "
                         f"{min_buildings} footprint(s)")
    angle = np.full(len(polys), np.nan)
    offset = np.full(len(polys), np.nan)
    if ok.any():
        segments = frontage.street_segments(db.geometry)
        rel, dist = frontage.relative_angle(polys[ok], segments)
        angle[ok] = np.where(dist <= frontage.REACH, rel, np.nan)
        _, centre_dist = frontage.nearest_street(shapely.centroid(polys[ok]), segments)
        offset[ok] = np.where(dist <= frontage.REACH, centre_dist, np.nan)
    min_area = float(np.percentile(shapely.area(polys[ok]), 10)) if ok.any() else 0.0
    return ExampleSet(db, name or str(db.path), polys, attrs, rows, usable, angle, min_area,
                      offset)


def street_offset(block, street_width: float = STREET_WIDTH, setback: float = 0.0,
                  roads: Optional[Sequence] = None, keep_clear: Optional[Sequence] = None):
    """The part of a block where footprints may stand.

    The block less the road surface (``street_width / 2`` from every road centreline on
    its boundary, and from dead-end streets inside it when ``roads`` are given) and the
    ``setback`` behind it, and less the ``keep_clear`` areas (e.g. the street surfaces and
    junctions of 'tessellatestreets', as wide as each street's class) and the ``setback``
    around them; less its parts on land that is no building land (nor gets a parcel):
    nowhere :data:`core.geometry.MIN_BUILDABLE_WIDTH` wide (:func:`core.geometry.too_thin`:
    a strip between wide streets) or smaller than :data:`core.geometry.MIN_BUILDABLE_AREA`
    (the island of a roundabout). With a setback, a part is dropped when it is nowhere
    that width less twice the setback wide, or when what the setback leaves of it is
    smaller than that area.
    """
    inset = street_width / 2.0 + setback
    if roads is not None and len(roads):
        surface = shapely.buffer(shapely.union_all(np.asarray(roads, dtype=object)), inset)
        area = shapely.difference(block, surface)
        # a block boundary that is no road centreline (clipped extract) keeps the inset too
        area = shapely.intersection(area, shapely.buffer(block, -inset)) if inset > 0 else area
    else:
        area = shapely.buffer(block, -inset) if inset > 0 else block
    if keep_clear is not None and len(keep_clear):
        clear = np.asarray(keep_clear, dtype=object)
        area = without_areas([area], shapely.buffer(clear, setback) if setback > 0 else clear)[0]
    area = shapely.make_valid(area) if not shapely.is_valid(area) else area
    parts, _ = polygon_parts([area])
    thin = too_thin(parts, max(MIN_BUILDABLE_WIDTH - 2.0 * setback, 0.0)) | \
        (shapely.area(parts) < MIN_BUILDABLE_AREA)
    if not thin.any():
        return area
    return one_areal(parts[~thin])


def legalise(polygons: Sequence, order: Sequence[int], buildable, block,
             min_area: float = MIN_AREA):
    """Hard guarantee: footprints inside ``buildable`` (and the block), none overlapping.

    Footprints are accepted in ``order``; each is clipped to the buildable area less the
    footprints accepted before it (with a 1 cm gap) and kept when one polygon of at least
    :data:`MIN_KEEP` of its area remains, and -- unless it is nearly intact (at least
    :data:`INTACT` of it) -- at least ``min_area`` m² (no slivers: the example's 10th
    percentile footprint area in :func:`synthesize_block`); footprints that need no or
    hardly any cut keep whatever size they have (a shed of the example).

    Returns
    -------
    (polygons, their indices into ``polygons``, status per kept one: 'kept' | 'trimmed')
    """
    polygons = np.asarray(polygons, dtype=object)
    out, index, status = [], [], []
    if len(polygons) == 0 or buildable is None or buildable.is_empty:
        return out, index, status
    shapely.prepare(buildable)
    shapely.prepare(block)
    grown = []       # accepted footprints grown by the gap
    clip = None
    for i in order:
        poly = polygons[i]
        if poly is None or poly.is_empty:
            continue
        a0 = poly.area
        g = poly
        near = np.zeros(0, dtype=object)
        if out:
            arr = np.array(grown, dtype=object)
            near = arr[shapely.intersects(arr, g)]
        clean = len(near) == 0 and shapely.within(g, buildable)
        if not clean:
            if clip is None:
                # 1 mm inside: an overlay's vertices can land a rounding error outside
                clip = shapely.buffer(buildable, -1e-3, quad_segs=2, join_style="mitre")
            g = shapely.intersection(g, clip)
            if len(near):
                g = shapely.difference(g, shapely.union_all(near))
            g = largest_polygons(np.array([g], dtype=object))[0]
            if g is None or g.area < max(MIN_KEEP * a0, MIN_AREA) or \
                    (g.area < min_area and g.area < INTACT * a0):
                continue
            taken = np.array(out, dtype=object)

            def legal(x):
                return (x.geom_type == "Polygon" and x.is_valid and shapely.within(x, buildable)
                        and shapely.within(x, block) and not shapely.intersects(x, taken).any())

            # without the collinear vertices of the cut, when that changes nothing else
            simple = shapely.simplify(shapely.normalize(g), 1e-3)
            if legal(simple):
                g = simple
            elif not legal(g):
                continue
        grown.append(shapely.buffer(g, GAP, quad_segs=2, join_style="mitre"))
        out.append(g)
        index.append(int(i))
        # the 1 cm gap cut off a shared wall is no trim worth reporting
        status.append("kept" if clean or a0 - g.area <= 2 * GAP * poly.length else "trimmed")
    return out, index, status


@dataclass
class BlockLayout:
    """Footprints of one block and what happened."""

    geometry: List
    table: pd.DataFrame
    stats: Dict = field(default_factory=dict)


def _empty_layout(stats: Dict) -> BlockLayout:
    return BlockLayout([], pd.DataFrame(columns=[n for n, _ in OUTPUT_FIELDS]), stats)


def _merged_layouts(layouts: Sequence[BlockLayout], seconds: float) -> BlockLayout:
    """The layouts of a block's parts as one: footprints and rows of all, counts summed,
    the example and cost those of the largest part (the first)."""
    stats = dict(layouts[0].stats)
    for key in stats:
        if key.startswith("n_"):
            stats[key] = int(sum(lay.stats[key] for lay in layouts))
    stats["seconds"] = seconds
    tables = [lay.table for lay in layouts if len(lay.table)]
    table = pd.concat(tables, ignore_index=True) if tables else layouts[0].table
    return BlockLayout([g for lay in layouts for g in lay.geometry], table, stats)


def _retrieve(block, examples: Sequence[ExampleSet], db_choice: int, n_best: int, rng):
    """The best matches (db index, Match) for a block, among one or all databases."""
    m = shape_metrics([block])
    area, aspect, per = (float(m["area_m2"][0]), float(m["aspect_ratio"][0]),
                         float(m["perimeter_m"][0]))
    which = range(len(examples)) if db_choice < 0 else [db_choice]
    found = []
    for e in which:
        ex = examples[e]
        rows = ex.db.prefilter(len(ex.db), area=area, aspect=aspect, perimeter=per)
        rows = rows[np.isin(rows, ex.usable)][:N_CANDIDATES]
        if len(rows) == 0:
            continue
        for match in ex.db.query(block, candidates=rows, n_best=n_best):
            found.append((match.cost, e, match))
    if not found:
        return None
    found.sort(key=lambda f: f[0])
    found = found[:max(1, n_best)]
    pick = int(rng.integers(len(found))) if len(found) > 1 else 0
    return found[pick][1], found[pick][2]


def synthesize_block(block, examples: Sequence[ExampleSet], method: str = "transfer",
                     seed: int = 0, block_index: int = 0, street_width: float = STREET_WIDTH,
                     setback: float = 0.0, roads: Optional[Sequence] = None,
                     db_choice: int = -1, n_best: int = 1, block_id: Optional[int] = None,
                     fill: bool = True, keep_clear: Optional[Sequence] = None) -> BlockLayout:
    """Footprints for one target block (a pure function of its arguments).

    Parameters
    ----------
    block : Polygon (metric CRS, the frame of the databases is irrelevant: retrieval is
        invariant to rotation and translation)
    examples : prepared databases (:func:`prepare_examples`)
    method : 'transfer' (ch. 5.1) or 'resynthesis' (ch. 5.2)
    seed : the random choice among the ``n_best`` matches uses
        ``default_rng([seed, *place_key(block)])`` (where the block lies, not its position
        among the blocks: a selection or another order gives each block the same footprints)
    block_index : the block's position (the default id)
    street_width, setback : the street offset (:func:`street_offset`)
    roads : optional road centrelines near the block (dead ends inside it)
    db_choice : database index to use, -1 = the best match over all
    n_best : random choice among this many best matches (1 = always the best)
    block_id : the id written to the output (default block_index + 1)
    fill : fill the street frontage the layout leaves empty (dead-end streets inside the
        block, sides of irregular blocks) with the example's street-facing footprints, up
        to the share of frontage the example block has built (:func:`frontage.fill_frontage`)
    keep_clear : optional polygons no footprint may cover (street surfaces and junctions
        near the block)

    Returns
    -------
    BlockLayout with :data:`OUTPUT_FIELDS` rows (of all its parts).
    """
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' (use one of {', '.join(METHODS)})")
    t0 = time.perf_counter()
    bid = block_index + 1 if block_id is None else block_id
    stats = dict(block_id=bid, method=method, example=None, database=None, cost=np.nan,
                 n_example=0, n_deleted=0, n_conflicted=0, n_turned=0, n_placed=0,
                 n_trimmed=0, n_dropped=0, n_filled=0, seconds=0.0)
    parts, _ = polygon_parts(shapely.make_valid(np.array([block], dtype=object)))
    if len(parts) > 1:
        # every part is land to fill (only the largest was filled, the others silently not),
        # each on its own, with the random numbers of where it lies
        parts = parts[np.argsort(-shapely.area(parts), kind="stable")]
        layouts = [synthesize_block(p, examples, method, seed, block_index, street_width,
                                    setback, roads, db_choice, n_best, bid, fill, keep_clear)
                   for p in parts]
        return _merged_layouts(layouts, time.perf_counter() - t0)
    block = parts[0] if len(parts) else None
    if block is None or block.area <= 0 or block.area > MAX_BLOCK_AREA:
        stats["seconds"] = time.perf_counter() - t0
        return _empty_layout(stats)
    buildable = street_offset(block, street_width, setback, roads, keep_clear)
    if buildable.is_empty or buildable.area < MIN_AREA:
        stats["seconds"] = time.perf_counter() - t0
        return _empty_layout(stats)
    rng = np.random.default_rng([int(seed), *place_key(block)])
    found = _retrieve(block, examples, db_choice, n_best, rng)
    if found is None:
        stats["seconds"] = time.perf_counter() - t0
        return _empty_layout(stats)
    e, match = found
    ex = examples[e]
    rows = ex.rows_of_block.get(int(match.id), np.zeros(0, np.int64))
    stats.update(example=int(match.id), database=ex.name, cost=match.cost, n_example=len(rows))
    aligned = match.transform(ex.polygons[rows]) if len(rows) else np.zeros(0, object)
    road_lines = np.asarray(roads if roads is not None else [], dtype=object)
    if len(road_lines):
        # the roads inside the block (dead ends), clipped to it; GEOS reports round-off on
        # a street along the outline as an 'invalid value' warning (printed to the user's
        # console), and its result, empty there, is sound
        with np.errstate(invalid="ignore"):
            road_lines = shapely.intersection(road_lines, shapely.buffer(block, -0.5))
        road_lines = road_lines[~shapely.is_empty(road_lines)
                                & (shapely.get_dimensions(road_lines) == 1)]
    streets = frontage.street_segments(np.r_[np.array([block], dtype=object), road_lines])
    if method == "transfer":
        # each footprint keeps the angle to its nearest street that it had in the example
        # block (a rigid fit of two blocks of different shapes turns the frontage)
        aligned, turn = frontage.align_to_frontage(aligned, ex.frontage_angle[rows], streets)
        stats["n_turned"] = int((np.abs(turn) > np.radians(1.0)).sum())
        keep, conflicted = classify(aligned, block, buildable)
        stats["n_deleted"] = int((~keep).sum())
        stats["n_conflicted"] = int(conflicted.sum())
        cand, src = aligned[keep], rows[keep]
        cand, _ = relax(cand, conflicted[keep], buildable)
        # fixed footprints first (they never move), then the relaxed ones; large first
        order = np.lexsort((-shapely.area(cand), conflicted[keep])) if len(cand) else []
        kinds = np.where(conflicted[keep], "moved", "copied")
    else:
        inset = street_width / 2.0 + setback
        samples = sc.sample_boundaries([block], ex.db.descriptors.samples.shape[1])[0]
        path = match.path
        first = np.r_[True, path[1:, 0] != path[:-1, 0]]
        pairs = path[first]
        # every other correspondence: 50 warp vertices follow a block outline closely and
        # halve the cost of the mean value coordinates
        pairs = pairs[::max(1, len(pairs) // WARP_VERTICES)]
        target = samples[pairs[:, 0]]
        source = sc.apply_rigid(ex.db.descriptors.samples[match.index][pairs[:, 1]],
                                match.rotation, match.translation)
        placements = retarget_layout(aligned, source, target, block, buildable, inset)
        cand = np.array([p.polygon for p in placements], dtype=object)
        src = rows[np.array([p.element for p in placements], dtype=np.int64)] \
            if placements else np.zeros(0, np.int64)
        # outside the exact rows (squared to their street already), each element keeps
        # its example angle to the nearest street, as in the transfer
        loose = np.array([not p.row for p in placements], dtype=bool)
        cand, turn = frontage.align_to_frontage(cand, ex.frontage_angle[src], streets,
                                                mask=loose)
        stats["n_turned"] = int((np.abs(turn) > np.radians(1.0)).sum())
        kinds = np.array([p.kind for p in placements], dtype=object)
        # placement order: the DP's groups first, interior elements last, large first
        order = np.lexsort((-shapely.area(cand), kinds == "interior")) if len(cand) else []
    geoms, idx, status = legalise(cand, order, buildable, block, min_area=ex.min_area)
    stats["n_placed"] = len(geoms)
    stats["n_trimmed"] = int(sum(s == "trimmed" for s in status))
    stats["n_dropped"] = len(cand) - len(geoms)
    idx = np.asarray(idx, dtype=np.int64)
    sources = src[idx] if len(idx) else np.zeros(0, np.int64)
    placement = [f"{kinds[i]}, trimmed" if s == "trimmed" else str(kinds[i])
                 for i, s in zip(idx, status)]
    if fill and len(rows):
        # the frontage the layout left empty (cul-de-sacs, sides of irregular blocks), up
        # to the share the example block has built
        facing = rows[np.isfinite(ex.frontage_angle[rows])]
        share = frontage.served_share([ex.db.geometry[match.index]], ex.polygons[rows])
        lines = np.r_[np.array([block.exterior], dtype=object), road_lines]
        added, k = frontage.fill_frontage(geoms, buildable, lines, ex.polygons[facing],
                                          ex.frontage_angle[facing],
                                          ex.frontage_offset[facing], share, rng)
        geoms = list(geoms) + added
        sources = np.r_[sources, facing[np.asarray(k, dtype=np.int64)]].astype(np.int64)
        placement += ["filled"] * len(added)
        stats["n_filled"] = len(added)
        stats["n_placed"] = len(geoms)
    a = ex.attributes.iloc[sources] if len(sources) else ex.attributes.iloc[[]]
    n_out = len(geoms)
    table = pd.DataFrame({
        "block_id": np.full(n_out, bid, dtype=np.int64),
        "height_m": a["height_m"].to_numpy(), "levels": a["levels"].to_numpy(),
        "building_type": a["building_type"].to_numpy(),
        "source_block": np.full(n_out, int(match.id), dtype=np.int64),
        "source_building": a["building_id"].to_numpy(),
        "database": [ex.name] * n_out, "method": [method] * n_out,
        "placement": placement,
    })
    stats["seconds"] = time.perf_counter() - t0
    return BlockLayout(list(geoms), table, stats)


@dataclass
class FootprintResult:
    """Footprints of all blocks: geometry, attribute table, per-block statistics."""

    geometry: np.ndarray
    table: pd.DataFrame
    blocks: pd.DataFrame
    seconds: float = 0.0


def synthesize_footprints(blocks: Sequence, examples: Sequence[ExampleSet],
                          method: str = "transfer", street_width: float = STREET_WIDTH,
                          setback: float = 0.0, seed: int = 0,
                          roads: Optional[Sequence] = None,
                          block_database: Optional[Sequence[int]] = None,
                          block_ids: Optional[Sequence[int]] = None, n_best: int = 1,
                          keep_clear: Optional[Sequence] = None,
                          progress: Optional[Progress] = None) -> FootprintResult:
    """Footprints for every target block (loops :func:`synthesize_block` with progress).

    Parameters
    ----------
    blocks : array of Polygon (metric CRS)
    examples : prepared databases
    method, street_width, setback, seed, n_best : see :func:`synthesize_block`
    roads : optional road centrelines (their surface, dead ends included, stays free)
    block_database : per block, the database index to use (-1 = best over all)
    block_ids : per block, the id written to the output (default 1..n)
    keep_clear : optional polygons no footprint may cover (e.g. the street surfaces and
        junctions of 'tessellatestreets')

    Returns
    -------
    FootprintResult
    """
    progress = ensure(progress)
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' (use one of {', '.join(METHODS)})")
    if not (np.isfinite(street_width) and street_width >= 0):
        raise InputError("the street width must be a non-negative number of metres")
    if not (np.isfinite(setback) and setback >= 0):
        raise InputError("the setback must be a non-negative number of metres")
    if not examples:
        raise InputError("at least one block database is needed")
    t0 = time.perf_counter()
    # one way round: a block from a shapefile (clockwise) gave other footprints
    blocks = counter_clockwise(blocks)
    n = len(blocks)
    ids = np.arange(1, n + 1) if block_ids is None else np.asarray(block_ids, dtype=np.int64)
    choice = np.full(n, -1) if block_database is None else np.asarray(block_database)
    road_arr = None if roads is None else np.asarray(roads, dtype=object)
    tree = shapely.STRtree(road_arr) if road_arr is not None and len(road_arr) else None
    # the areas near each block, made 2D and valid where they are used (street_offset)
    clear_arr = None if keep_clear is None else np.asarray(keep_clear, dtype=object)
    clear_tree = shapely.STRtree(clear_arr) if clear_arr is not None and len(clear_arr) \
        else None
    geoms, tables, stats = [], [], []
    for i in range(n):
        near = clear = None
        if tree is not None and blocks[i] is not None:
            near = road_arr[tree.query(blocks[i], predicate="intersects")]
        if clear_tree is not None and blocks[i] is not None:
            clear = clear_arr[clear_tree.query(blocks[i], predicate="intersects")]
        layout = synthesize_block(blocks[i], examples, method, seed, i, street_width, setback,
                                  near, int(choice[i]), n_best, int(ids[i]), keep_clear=clear)
        geoms.extend(layout.geometry)
        if len(layout.table):
            tables.append(layout.table)
        stats.append(layout.stats)
        progress.step((i + 1) / max(n, 1))
    table = pd.concat(tables, ignore_index=True) if tables else \
        pd.DataFrame(columns=[f for f, _ in OUTPUT_FIELDS])
    return FootprintResult(np.array(geoms, dtype=object), table, pd.DataFrame(stats),
                           time.perf_counter() - t0)
