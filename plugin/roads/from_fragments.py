"""Hierarchical example-based road synthesis by recursive fragment insertion (thesis ch. 4.1.3).

Hartmann's Function 2: the sketched arterials are street level 0; for l = 0, 1, ... the
query fragments are the minimal cycles (bounded faces) of the streets of level <= l; for
each query a fragment of the same level is retrieved from an example database (prefilter by
area, aspect ratio and relief change to c = 10 candidates, then scale-aware,
rotation-invariant shape context plus the slope term C^E with cyclic DTW), rigidly aligned
from the DTW correspondences, and its interior streets (level l + 1) are warped into the
query with mean value coordinates defined on the match's boundary samples and evaluated
with the corresponding query samples; its relief is warped the same way and merged into
the height field with a Poisson solve. The loop stops when no database holds fragments of
the next level (or ``max_level`` is reached).

Choices the thesis leaves open, made here:

- **Which match**: a random choice among the ``n_best`` lowest-cost candidates (seeded
  ``numpy.random.Generator``). The candidates are tried in that random order; a candidate
  whose warp is not acceptable (below) is skipped, and when none is acceptable the query
  gets a **procedural split** (one street along the midline across the long axis of its
  minimum rotated rectangle) if both halves are blocks, else it stays a block.
- **Acceptable warp**: every warped street node that is not on the fragment boundary (dead
  ends, junctions) lies inside the query, at most 20 % of the warped street length is lost
  to clipping, and the inserted streets cut the query into no more sliver faces (under the
  block area / width thresholds of :mod:`blocks`) than the example fragment had. Very
  concave targets fail these tests instead of producing streets outside the query.
- **Insertion**: street ends that lay on the example's boundary are snapped onto the query
  boundary (onto an existing node when one is within ``snap_distance``); streets are
  clipped to the query; the level is then re-noded as one planar network (the boundary
  edges split where new streets meet them), new dead ends shorter than ``min_dangle`` m
  are pruned and chains through degree-2 nodes of one source are merged. No new street
  runs along a street in its corridor (the invariants' rule,
  :func:`network.invariants.doubles_a_street`), whether the street bounds the query or lies
  inside it (an arterial ending in the face).
- **Dead-end share** (issue 15, not in the thesis): last, the share is steered to the
  example's (:mod:`network.dead_ends`, as the random walk does).
- **Levels of a database**: a database's hierarchy starts at its own lowest fragment level
  (an example whose arterials close no face, like Bubenec, starts at level 1): query level
  l uses database level ``min_level + l``.
- **Several databases**: with style polygons each query uses the database of the style
  polygon holding its representative point (the first database elsewhere); without them
  the candidates of all databases compete by cost.
- **Terrain**: the query's slope descriptors are taken from the current height field, which
  already holds the relief merged at the previous levels.

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 4.1.3
(Function 2, fragment retrieval with eqs. 4.1-4.3, fragment insertion by generalised
barycentric coordinates, Poisson merge of the relief) and ch. 4.1.4 (reproduction of Bonn,
style mixing, terrain-dependent choice).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core.progress import InputError, Progress, ensure
from ..core.text import counted
from ..network import street_graph as _roads
from ..network.controlled_access import end_short_of_controlled_access
from ..network.dead_ends import MIN_DANGLE, steer_attributed
from ..network.links import join_pieces, link_floating_pieces
from ..network.invariants import SNAP_TOLERANCE, corridor_around, doubles_a_street
from ..network.street_graph import add_streets, close_short_gaps, synthesised
from ..network.undershoots import clear_undershoots
from ..network.blocks import (
    MIN_BLOCK_AREA,
    MIN_BLOCK_WIDTH,
    block_faces,
    planar_faces,
    shape_metrics,
)
from ..retrieval import shape_context as sc
from ..retrieval.database import N_CANDIDATES, FragmentDatabase
from ..retrieval.shape_context import DemGrid
from ..retrieval.warp import poisson_blend, warp_geometries, warp_points

__all__ = [
    "MAX_N_BEST", "MAX_LEVELS", "EDGE_FIELDS", "Retrieval", "SynthesisResult",
    "retrieve", "synthesize", "procedural_split", "grid_streets", "example_blocks",
    "close_sketch", "statistical_split", "example_dead_end_share",
]

#: Upper bound of N_BEST: beyond it the "random choice among the best" is just random.
MAX_N_BEST = 50
#: Safety bound on the number of synthesised levels.
MAX_LEVELS = 12
#: Output attributes per edge.
EDGE_FIELDS = [("level", "int"), ("source_fragment", "str"), ("database", "str"),
               ("fragment_id", "int"), ("length_m", "float")]
#: Share of the warped street length that may be clipped away before a warp is rejected.
MAX_CLIPPED_SHARE = 0.2
#: Largest linear scale factor between a query and an inserted fragment (area ratio 4).
MAX_SCALE = 2.0
#: Street ends closer than this (m) to the example fragment's boundary end on it.
_ON_BOUNDARY = 0.5
#: Rounds of the fill stage: each fills the faces the previous round left too large.
MAX_FILL_ROUNDS = 16
#: Candidates tried per face and way (at scale, scaled) in the fill stage.
FILL_TRIES = 6
#: Quantile of the example's block areas above which a face must not stay empty.
FILL_QUANTILE = 90.0


@dataclass
class Retrieval:
    """Candidates of a batch of queries against one database level.

    Attributes
    ----------
    rows : (F, c) int array of database rows (-1 where fewer candidates exist)
    costs : (F, c) float array of cyclic DTW costs (inf for missing candidates)
    offsets : (F, c) int array of DTW start offsets
    cost_matrices : (F, c, n, n) float32 point-pair costs (for the correspondences)
    samples : (F, n, 2) query boundary samples
    """

    rows: np.ndarray
    costs: np.ndarray
    offsets: np.ndarray
    cost_matrices: np.ndarray
    samples: np.ndarray

    def ranked(self, f: int, n_best: int) -> np.ndarray:
        """Indices (into the candidate axis) of query f's ``n_best`` cheapest candidates."""
        order = np.argsort(self.costs[f], kind="stable")
        order = order[np.isfinite(self.costs[f][order])]
        return order[:n_best]


@dataclass
class SynthesisResult:
    """Result of :func:`synthesize`.

    Attributes
    ----------
    geometry : ndarray of LineString, the planar street network (metric CRS)
    table : DataFrame, per edge the columns of :data:`EDGE_FIELDS`: ``level`` (0 =
        arterial), ``source_fragment`` ('arterial', 'procedural' or '<database>:<id>'),
        ``database`` (its name, empty for arterials and procedural streets),
        ``fragment_id`` (-1 when none), ``length_m``
    dem : DemGrid or None, the height field with the inserted relief merged
    queries : DataFrame, one row per query fragment: level, database, fragment_id, cost,
        outcome ('fragment', 'block', 'procedural', 'unsplit', 'no_candidate'), area_m2,
        n_rejected (candidates whose warp was not acceptable)
    area : Polygon / MultiPolygon, the union of the arterials' faces (the synthesis area)
    stats : dict, counts and timings per level
    """

    geometry: np.ndarray
    table: pd.DataFrame
    dem: Optional[DemGrid]
    queries: pd.DataFrame
    area: object
    stats: Dict = field(default_factory=dict)


# --------------------------------------------------------------------------- retrieval

def _db_levels(db: FragmentDatabase) -> np.ndarray:
    return np.unique(db.levels)


def _query_relief(faces: np.ndarray, dem: Optional[DemGrid]) -> Optional[np.ndarray]:
    if dem is None:
        return None
    from ..network.fragments import relief_patches

    return relief_patches(faces, dem, cell_size=max(dem.cell_size, 1.0))[0]


def retrieve(db: FragmentDatabase, faces: Sequence, level: Optional[int],
             dem: Optional[DemGrid] = None, gamma: float = 0.5, c: int = N_CANDIDATES,
             relief: Optional[np.ndarray] = None, chunk: int = 8,
             rows: Optional[np.ndarray] = None) -> Retrieval:
    """Retrieve candidates for many query faces of one level at once (vectorised).

    The batch version of :meth:`FragmentDatabase.query`: the prefilter (standardised log
    area, aspect ratio and relief change, nearest ``c``) is one (faces x fragments)
    distance matrix; shape contexts and slope descriptors of all queries are computed in
    one call; the point-pair costs and the cyclic DTW of all (query, candidate) pairs are
    evaluated in blocks of ``chunk`` queries.

    Parameters
    ----------
    db : FragmentDatabase
    faces : array of Polygon (the database's metric units)
    level : int, the *database* level to retrieve from (exact; no fallback)
    rows : int array, optional, the database rows to retrieve from instead of a level (the
        fill stage retrieves among the fragments of every level that hold streets)
    dem : DemGrid, optional, terrain of the queries (adds the slope term when the database
        has slope descriptors and ``gamma < 1``)
    gamma : float, weight of the shape term in eq. 4.2
    c : int, prefilter size (thesis: 10)
    relief : per face relief change (m) for the prefilter, optional

    Returns
    -------
    Retrieval

    References
    ----------
    Hartmann, thesis ch. 4.1.3, "Fragment Retrieval" (eqs. 4.1-4.3, c = 10).
    """
    faces = np.asarray(faces, dtype=object)
    desc = db.descriptors
    n = desc.samples.shape[1]
    k = len(faces)
    rows_all = np.flatnonzero(db.levels == level) if rows is None else np.asarray(rows)
    samples = sc.sample_boundaries(faces, n) if k else np.zeros((0, n, 2))
    c_eff = int(min(c, len(rows_all)))
    if k == 0 or c_eff == 0:
        return Retrieval(np.full((k, 0), -1), np.zeros((k, 0)), np.zeros((k, 0), np.int64),
                         np.zeros((k, 0, n, n), np.float32), samples)
    # prefilter: the database's features standardised over its fragments of this level
    feats = db._features(rows_all)
    m = shape_metrics(faces)
    q = [np.log(np.maximum(m["area_m2"].to_numpy(), 1e-9)), m["aspect_ratio"].to_numpy()]
    if feats.shape[1] == 3:
        q.append(np.full(k, np.nan) if relief is None else np.asarray(relief, np.float64))
    q = np.column_stack(q)
    mu, sd = np.nanmean(feats, axis=0), np.nanstd(feats, axis=0)
    sd = np.where(sd > 1e-12, sd, 1.0)
    z, zq = (feats - mu) / sd, (q - mu) / sd
    d = np.nansum((zq[:, None, :] - z[None, :, :]) ** 2, axis=2)          # (k, R)
    keep = np.argsort(d, axis=1, kind="stable")[:, :c_eff]
    rows = rows_all[keep]                                                # (k, c)
    edges = desc.edges
    qh = sc.normalised_histograms(sc.shape_contexts(samples, edges, desc.n_angular))
    qsl = None
    if dem is not None and desc.slopes is not None and gamma < 1:
        qsl = sc.slope_descriptors(samples, dem, edges, desc.n_angular)
    hist = db.histograms
    costs = np.empty((k, c_eff))
    offsets = np.empty((k, c_eff), dtype=np.int64)
    mats = np.empty((k, c_eff, n, n), dtype=np.float32)
    for a in range(0, k, chunk):
        b = min(a + chunk, k)
        cm = sc.combined_cost(qh[a:b, None], hist[rows[a:b]],
                              None if qsl is None else qsl[a:b, None],
                              None if qsl is None else desc.slopes[rows[a:b]], gamma)
        mats[a:b] = cm
        costs[a:b], offsets[a:b] = sc.cyclic_dtw_costs(cm)
    return Retrieval(rows, costs, offsets, mats, samples)


# --------------------------------------------------------------------------- geometry helpers

def _line_ends(lines: np.ndarray):
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    first = np.r_[True, idx[1:] != idx[:-1]]
    last = np.r_[idx[1:] != idx[:-1], True]
    return coords, idx, np.flatnonzero(first), np.flatnonzero(last)


def _is_sliver(area: np.ndarray, perimeter: np.ndarray, min_area: float = MIN_BLOCK_AREA,
               min_width: float = MIN_BLOCK_WIDTH) -> np.ndarray:
    """The blocks module's sliver rule (:func:`block_faces`) on measured faces."""
    return (area < min_area) | (2 * area < min_width * perimeter)


def _sliver_count(faces: np.ndarray, area: np.ndarray, perimeter: np.ndarray,
                  min_area: float, min_width: float) -> int:
    return int(_is_sliver(area, perimeter, min_area, min_width).sum())


def _sub_faces(polygon, streets: np.ndarray):
    """Faces of a polygon's outline cut by streets (street ends made vertices of the outline:
    an end clipped onto it lies on it only up to round-off). The outline is every ring: a
    street from the exterior to a hole ends on the outline too; the holes are no faces."""
    rings = shapely.get_parts(shapely.boundary(polygon))
    streets = np.asarray(streets, dtype=object)
    if len(streets):
        ends = np.concatenate([shapely.get_coordinates(shapely.get_point(streets, 0)),
                               shapely.get_coordinates(shapely.get_point(streets, -1))])
        rings = shapely.snap(rings, shapely.multipoints(ends), 1e-6)
    faces, area, perimeter = planar_faces(np.concatenate([rings, streets]))
    if len(rings) > 1 and len(faces):
        inside = shapely.contains(polygon, shapely.point_on_surface(faces))
        faces, area, perimeter = faces[inside], area[inside], perimeter[inside]
    return faces, area, perimeter


def _touching(face, tree: shapely.STRtree, lines: np.ndarray) -> np.ndarray:
    """The network lines that touch a face: those of its outline, and those inside it that
    its outline does not show (an arterial ending in the face, a dual carriageway whose
    sliver is no face, a dead end of an earlier level)."""
    return lines[tree.query(face, predicate="intersects")]


def procedural_split(face, min_area: float = MIN_BLOCK_AREA,
                     min_width: float = MIN_BLOCK_WIDTH, avoid=None) -> np.ndarray:
    """One street across a face: the midline across the long axis of its minimum rectangle.

    The line through the centre of the minimum rotated rectangle, perpendicular to its long
    side, clipped to the face (a concave face may give several pieces, each from boundary
    to boundary). Returns no street when a resulting face would be a sliver; a piece that
    would run along a street (in its corridor, :func:`network.invariants.doubles_a_street`)
    is left out.

    Parameters
    ----------
    face : Polygon
    min_area, min_width : float, the block thresholds of :mod:`blocks`
    avoid : array of LineString, optional, network lines touching the face besides its
        outline, whose corridors the street keeps out of (:func:`_touching`)

    Returns
    -------
    ndarray of LineString (possibly empty)
    """
    m = shape_metrics([face]).iloc[0]
    if not np.isfinite(m.mbr_length_m) or m.mbr_length_m <= 0:
        return np.empty(0, dtype=object)
    rect = shapely.oriented_envelope(face)
    centre = np.asarray(rect.centroid.coords[0])
    a = np.radians(m.mbr_angle_deg)
    across = np.array([-np.sin(a), np.cos(a)])        # perpendicular to the long side
    half = m.mbr_length_m + m.mbr_width_m
    line = shapely.LineString([centre - half * across, centre + half * across])
    parts = shapely.get_parts(shapely.intersection(line, face))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 1e-6)]
    if len(parts):
        parts = parts[~doubles_a_street(parts, corridor_around(face, avoid))]
    if len(parts) == 0:
        return parts
    _, area, perimeter = _sub_faces(face, parts)
    if len(area) < 2 or _sliver_count(None, area, perimeter, min_area, min_width):
        return np.empty(0, dtype=object)
    return parts


def grid_streets(faces: Sequence, spacing: float) -> np.ndarray:
    """A plain grid of streets inside each face, aligned with its minimum rectangle.

    The procedural baseline of the evaluation: parallel streets ``spacing`` m apart in the
    two directions of each face's minimum rotated rectangle, centred on it and clipped to
    the face.

    Parameters
    ----------
    faces : array of Polygon
    spacing : float, metres between parallel streets

    Returns
    -------
    ndarray of LineString
    """
    if not spacing > 0:
        raise InputError("the grid spacing must be positive")
    faces = np.asarray(faces, dtype=object)
    if len(faces) == 0:
        return np.empty(0, dtype=object)
    m = shape_metrics(faces)
    out = []
    for face, (_, row) in zip(faces, m.iterrows()):
        c = np.asarray(shapely.oriented_envelope(face).centroid.coords[0])
        a = np.radians(row.mbr_angle_deg)
        u = np.array([np.cos(a), np.sin(a)])
        w = np.array([-u[1], u[0]])
        half_l, half_w = row.mbr_length_m / 2, row.mbr_width_m / 2
        lines = []
        for axis, other, half_a, half_o in ((u, w, half_l, half_w), (w, u, half_w, half_l)):
            n_lines = int(np.floor(2 * half_a / spacing))
            offs = (np.arange(1, n_lines + 1) - (n_lines + 1) / 2) * spacing
            for o in offs:
                p = c + o * axis
                lines.append([p - (half_o + 1) * other, p + (half_o + 1) * other])
        if not lines:
            continue
        with np.errstate(invalid="ignore"):  # lines that miss a concave face
            cut = shapely.intersection(shapely.linestrings(np.asarray(lines)), face)
        parts = shapely.get_parts(cut)
        out.append(parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 1e-6)])
    return np.concatenate(out) if out else np.empty(0, dtype=object)


def example_blocks(databases: Sequence[FragmentDatabase]) -> pd.DataFrame:
    """The example's city blocks as the databases know them: area and rectangle sides.

    A block is a fragment that no street of the next level splits (``is_block``); the same
    face is a fragment of every deeper level, so faces are counted once (same area and
    perimeter). The deepest level's streets split their fragments into blocks that are no
    fragment of any level (there is no level below to hold them): those are the faces of
    each such fragment's outline and streets, slivers dropped as in :func:`block_faces`
    (a database of three levels knew one block of a street network with seven before).
    The sides are those of the minimum rotated rectangle, recovered from compactness
    (area / rectangle area) and aspect ratio (short / long side).
    """
    frames = []
    for db in databases:
        t = db.table
        if "is_block" not in t:
            continue
        is_block = t["is_block"].to_numpy().astype(bool)
        b = t[is_block][["area_m2", "perimeter_m", "compactness", "aspect_ratio"]]
        deepest = np.flatnonzero(~is_block & (t["level"].to_numpy() == t["level"].max()))
        faces = [_sub_faces(db.geometry[row], _street_lines(db, row))[0] for row in deepest]
        if faces:
            faces = np.concatenate(faces)
            keep = ~_is_sliver(shapely.area(faces), shapely.length(faces))
            b = pd.concat([b, shape_metrics(faces[keep])[list(b.columns)]], ignore_index=True)
        frames.append(b.round({"area_m2": 1, "perimeter_m": 1}).drop_duplicates(
            ["area_m2", "perimeter_m"]))
    if not frames:
        return pd.DataFrame(columns=["area_m2", "long_m", "short_m"])
    b = pd.concat(frames, ignore_index=True)
    rect = b["area_m2"] / b["compactness"].clip(lower=1e-6)
    long = np.sqrt(rect / b["aspect_ratio"].clip(lower=1e-6))
    return pd.DataFrame({"area_m2": b["area_m2"].to_numpy(), "long_m": long.to_numpy(),
                         "short_m": (long * b["aspect_ratio"]).to_numpy()})


def _street_lines(db: FragmentDatabase, row: int) -> np.ndarray:
    """A fragment's streets as single lines."""
    streets = db.streets_of(int(db.ids[row]))
    streets = shapely.get_parts(streets) if len(streets) else np.empty(0, dtype=object)
    return streets[shapely.get_type_id(streets) == 1] if len(streets) else streets


def close_sketch(arterials: Sequence, boundary) -> tuple:
    """The sketch closed by the target boundary: arterials clipped to it, plus its rings.

    An open sketch (arterials that close few faces) leaves most of a town unfilled; the
    boundary's rings close every face. Returns (lines, is_boundary).
    """
    arterials = np.asarray(arterials, dtype=object).ravel()
    area = shapely.union_all(shapely.get_parts(np.asarray(boundary, dtype=object).ravel()))
    if area is None or area.is_empty or shapely.area(area) <= 0:
        raise InputError("the target boundary has no area")
    area = shapely.make_valid(area)
    with np.errstate(invalid="ignore"):
        inside = shapely.get_parts(shapely.intersection(arterials, area)) if len(arterials) \
            else np.empty(0, dtype=object)
    inside = shapely.get_parts(inside)
    inside = inside[(shapely.get_type_id(inside) == 1) & (shapely.length(inside) > 1e-6)]
    rings = shapely.get_parts(shapely.boundary(shapely.get_parts(area)))
    rings = shapely.get_parts(rings)
    rings = rings[shapely.length(rings) > 0]
    # the cut ends lie on the outline only up to round-off: make them vertices of it, so
    # that noding joins the two
    if len(inside):
        ends = shapely.multipoints(np.concatenate([
            shapely.get_coordinates(shapely.get_point(inside, 0)),
            shapely.get_coordinates(shapely.get_point(inside, -1))]))
        rings = shapely.snap(rings, ends, 1e-6)
    lines = np.concatenate([inside, rings]).astype(object)
    return lines, np.r_[np.zeros(len(inside), bool), np.ones(len(rings), bool)]


def statistical_split(face, sides: np.ndarray, rng: np.random.Generator,
                      min_area: float = MIN_BLOCK_AREA, min_width: float = MIN_BLOCK_WIDTH,
                      tries: int = 8, avoid=None) -> np.ndarray:
    """One street across a face, cutting off a block-sized piece (the fill's fallback).

    The street runs across the long axis of the face's minimum rotated rectangle, at a
    distance from one end drawn from the example's block sides (``sides``: the sides of
    the rectangles of its blocks), so that recursion leaves blocks of the example's
    dimensions; a face shorter than twice the drawn side is cut near its middle. Only the
    piece of the cut through the chosen point is kept (in a concave face a straight line
    meets the outline many times), or the whole cut where that piece does not split the
    face (a face with a hole). A cut that would leave a sliver is tried elsewhere
    (``tries`` positions: from the drawn side at both ends, then uniformly along the
    axis), and so is one that runs along a street (in the corridor of the face's outline or
    of ``avoid``, the network lines touching it: :func:`network.invariants.doubles_a_street`);
    no street when every cut fails.
    """
    m = shape_metrics([face]).iloc[0]
    length = float(m.mbr_length_m)
    if not np.isfinite(length) or length <= 0 or not len(sides):
        return np.empty(0, dtype=object)
    rect = shapely.oriented_envelope(face)
    centre = np.asarray(rect.centroid.coords[0])
    a = np.radians(m.mbr_angle_deg)
    along = np.array([np.cos(a), np.sin(a)])
    across = np.array([-along[1], along[0]])
    d = float(rng.choice(sides))
    if length < 2 * d:
        d = length * float(rng.uniform(0.4, 0.6))
    sign = float(rng.choice([-1.0, 1.0]))
    half = length + float(m.mbr_width_m)
    positions = [sign * (d - length / 2), -sign * (d - length / 2)] + \
        list(rng.uniform(-0.4, 0.4, max(tries - 2, 0)) * length)
    # slivers the outline makes on its own (a spur of the boundary) are not the cut's
    _, area0, perimeter0 = _sub_faces(face, np.empty(0, dtype=object))
    base = _sliver_count(None, area0, perimeter0, min_area, min_width)
    corridor = corridor_around(face, avoid)
    for t in positions:
        p = centre + t * along
        line = shapely.LineString([p - half * across, p + half * across])
        parts = shapely.get_parts(shapely.intersection(line, face))
        parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 1e-6)]
        if not len(parts):
            continue
        # the piece through the cut's centre (the longest where the centre is outside); where
        # that one does not split the face (a face with a hole: it runs from the outline to
        # the hole), every piece of the cut
        dist = shapely.distance(parts, shapely.Point(p))
        one = parts[[int(np.argmin(dist)) if dist.min() < 1e-6 else
                     int(np.argmax(shapely.length(parts)))]]
        for cut in (one, parts) if len(parts) > 1 else (one,):
            if doubles_a_street(cut, corridor).any():
                continue
            _, area, perimeter = _sub_faces(face, cut)
            if len(area) >= 2 and \
                    _sliver_count(None, area, perimeter, min_area, min_width) <= base:
                return cut
    return np.empty(0, dtype=object)


# --------------------------------------------------------------------------- insertion

class _Inserter:
    """Warps the interior streets of one candidate into one query face."""

    def __init__(self, min_area: float, min_width: float, snap_distance: float):
        self.min_area = min_area
        self.min_width = min_width
        self.snap_distance = snap_distance
        self._example_slivers: Dict = {}
        self._example_ends: Dict = {}

    def example(self, db: FragmentDatabase, row: int):
        """Streets of a fragment, which of their ends lie on its boundary, its sliver count."""
        key = (id(db), row)
        if key not in self._example_ends:
            streets = _street_lines(db, row)
            if len(streets):
                coords, _, first, last = _line_ends(streets)
                ring = shapely.get_exterior_ring(db.geometry[row])
                d0 = shapely.distance(ring, shapely.points(coords[first]))
                d1 = shapely.distance(ring, shapely.points(coords[last]))
                on = (d0 < _ON_BOUNDARY, d1 < _ON_BOUNDARY)
                _, area, perimeter = _sub_faces(db.geometry[row], streets)
                slivers = _sliver_count(None, area, perimeter, self.min_area, self.min_width)
            else:
                on, slivers = (np.zeros(0, bool), np.zeros(0, bool)), 0
            self._example_ends[key] = (streets, on)
            self._example_slivers[key] = slivers
        return self._example_ends[key][0], self._example_ends[key][1], \
            self._example_slivers[key]

    def insert(self, face, q_samples: np.ndarray, ex_samples: np.ndarray, path: np.ndarray,
               streets: np.ndarray, on_boundary, example_slivers: int, avoid=None):
        """Warp, snap and clip; returns (pieces, None) or (None, reason). ``avoid``: the
        network lines touching the face (:func:`_touching`), whose corridors, like the
        outline's, no street may run along."""
        src = ex_samples[path[:, 1]]
        dst = q_samples[path[:, 0]]
        r, t, _ = sc.rigid_align(src, dst)
        src_aligned = sc.apply_rigid(src, r, t)
        aligned = sc.transform_geometries(streets, r, t)
        seg = max(2.0, np.sqrt(face.area) / 25.0)
        warped = warp_geometries(aligned, src_aligned, dst, max_segment=seg)
        coords, idx, first, last = _line_ends(warped)
        if not np.isfinite(coords).all():
            return None, "warp"
        on0, on1 = on_boundary
        interior_ends = np.concatenate([coords[first][~on0], coords[last][~on1]])
        if len(interior_ends):
            pts = shapely.points(interior_ends)
            if (shapely.distance(face, pts) > 0.5).any() or \
                    not shapely.contains_xy(face, *interior_ends.T).all():
                return None, "outside"
        # boundary ends onto the query boundary, onto an existing corner when one is near
        ring = shapely.get_exterior_ring(face)
        corners = shapely.get_coordinates(ring)[:-1]
        for ends, on in ((first, on0), (last, on1)):
            sel = ends[on]
            if not len(sel):
                continue
            p = coords[sel]
            d = np.hypot(*(p[:, None, :] - corners[None, :, :]).transpose(2, 0, 1))
            near = d.min(axis=1) <= self.snap_distance
            snapped = np.empty_like(p)
            snapped[near] = corners[d[near].argmin(axis=1)]
            far = ~near
            if far.any():
                pos = shapely.line_locate_point(ring, shapely.points(p[far]))
                snapped[far] = shapely.get_coordinates(shapely.line_interpolate_point(ring, pos))
            coords[sel] = snapped
        warped = shapely.linestrings(coords, indices=idx)
        warped = warped[shapely.length(warped) > 1e-6]
        total = float(shapely.length(warped).sum())
        pieces = shapely.get_parts(shapely.intersection(warped, face))
        pieces = pieces[(shapely.get_type_id(pieces) == 1) & (shapely.length(pieces) > 1e-3)]
        if len(pieces):
            # nothing that runs along the query boundary (it is a street already)
            along = shapely.within(pieces, shapely.buffer(shapely.boundary(face), 1e-3))
            pieces = pieces[~along]
        if len(pieces):
            # nothing that doubles a street of the query boundary, or one inside the query
            # that the boundary does not show, in its corridor
            pieces = pieces[~doubles_a_street(pieces, corridor_around(face, avoid))]
        kept = float(shapely.length(pieces).sum()) if len(pieces) else 0.0
        if total > 0 and kept < (1 - MAX_CLIPPED_SHARE) * total:
            return None, "clipped"
        if not len(pieces):
            return None, "empty"
        _, area, perimeter = _sub_faces(face, pieces)
        if _sliver_count(None, area, perimeter, self.min_area, self.min_width) > example_slivers:
            return None, "slivers"
        return pieces, None


# --------------------------------------------------------------------------- network

def _faces_in(lines, min_area: float, min_width: float, target=None) -> np.ndarray:
    """Block faces of the lines that lie in the target (a hole of the boundary is a face of
    its outline too, but outside the target)."""
    try:
        faces, _ = block_faces(lines, min_area, min_width)
    except InputError:
        return np.empty(0, dtype=object)
    if target is not None and len(faces):
        faces = faces[shapely.contains(target, shapely.point_on_surface(faces))]
    return faces


def _empty(faces: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Which faces hold no street (a dead end inside a face makes it not empty)."""
    inner = np.zeros(len(faces), bool)
    if len(faces) and len(lines):
        # half a metre inside the outline: the streets that bound the face do not count
        hit = shapely.STRtree(lines).query(shapely.buffer(faces, -0.5), predicate="intersects")[0]
        inner[hit] = True
    return ~inner


def _face_key(face) -> tuple:
    c = face.centroid
    return (round(c.x, 1), round(c.y, 1), round(face.area))


def _fill_stage(geometry, level, attrs, databases, names, inserter, rng, max_block,
                blocks_ex, n_best, c, gamma, max_scale, min_area, min_width, min_dangle,
                query_rows, query_id, progress, target=None, style_polygons=None,
                style_database=None):
    """Fill every face larger than ``max_block`` (see :func:`synthesize`, Notes)."""
    counts = dict(rounds=0, fill_fragment=0, fill_scaled=0, fill_statistics=0, left_empty=0)
    sides = np.concatenate([blocks_ex["long_m"].to_numpy(), blocks_ex["short_m"].to_numpy()])
    sides = sides[np.isfinite(sides) & (sides > 0)]
    # the fragments whose streets split them (not blocks), per database: a fill that left
    # only dead ends would leave the face as large as it was
    with_streets = []
    for db in databases:
        t = db.table
        ok = t["n_interior"].to_numpy() > 0 if "n_interior" in t else np.ones(len(t), bool)
        if "is_block" in t:
            ok &= ~t["is_block"].to_numpy().astype(bool)
        with_streets.append(np.flatnonzero(ok))
    exhausted = set()   # faces nothing could split
    tried = set()       # faces a fragment was put into (the next try is a statistical split)
    next_level = int(level.max()) + 1 if len(level) else 1
    for rnd in range(MAX_FILL_ROUNDS):
        faces = _faces_in(geometry, min_area, min_width, target)
        # filled down to the example's block sizes: a face with dead ends inside is not
        # empty, but still larger than the example's blocks
        faces = faces[shapely.area(faces) > max_block] if len(faces) else faces
        big = list({_face_key(f): f for f in faces if _face_key(f) not in exhausted}.values())
        if not big:
            break
        counts["rounds"] += 1
        big = np.asarray(big, dtype=object)
        options: List[list] = [[] for _ in range(len(big))]
        # style polygons choose the database here as in the levels
        style = _style_index(big, style_polygons, style_database, len(databases))
        for i, db in enumerate(databases):
            sel = np.arange(len(big)) if style_polygons is None else np.flatnonzero(style == i)
            if not len(with_streets[i]) or not len(sel):
                continue
            ret = retrieve(db, big[sel], None, None, gamma, max(c, 2 * FILL_TRIES),
                           rows=with_streets[i])
            for jj, j in enumerate(sel):
                for k in ret.ranked(jj, ret.rows.shape[1]):
                    row = int(ret.rows[jj, k])
                    ratio = big[j].area / max(float(db.table["area_m2"].iat[row]), 1e-9)
                    options[j].append((float(ret.costs[jj, k]), i, ret, jj, int(k), ratio))
        new_geoms, new_attrs = [], []
        tree = shapely.STRtree(geometry)
        for j, face in enumerate(big):
            avoid = _touching(face, tree, geometry)
            progress.step((rnd + j / len(big)) / MAX_FILL_ROUNDS)
            opts = sorted(options[j], key=lambda o: o[0])
            # the fill never shrinks a fragment into a face: its blocks would come out smaller
            # than the example's (shrunk by up to MAX_SCALE, a grid's 80 m blocks became 40 m
            # ones in faces a little over the p90 block area); a fragment smaller than the
            # face is stretched, at most MAX_SCALE times, then scaled up at any scale
            at_scale = [o for o in opts if 1 <= o[5] <= max_scale ** 2]
            scaled = [o for o in opts if o[5] > max_scale ** 2]
            row = dict(query=query_id, level=next_level, database="", fragment_id=-1,
                       cost=np.nan, outcome="left_empty", area_m2=float(face.area), n_rejected=0)
            pieces = None
            key = _face_key(face)
            ways = (("fill_fragment", at_scale), ("fill_scaled", scaled)) \
                if key not in tried else ()
            for outcome, pool in ways:
                head = pool[:n_best]
                tries = [head[int(p)] for p in rng.permutation(len(head))] + \
                    pool[n_best:FILL_TRIES]
                for cost, i, ret, jj, k, _ in tries:
                    db = databases[i]
                    db_row = int(ret.rows[jj, k])
                    _, dtw = sc.dtw_path(ret.cost_matrices[jj, k], int(ret.offsets[jj, k]))
                    streets, on, ex_slivers = inserter.example(db, db_row)
                    if not len(streets):
                        continue
                    got, _ = inserter.insert(face, ret.samples[jj],
                                             db.descriptors.samples[db_row], dtw, streets, on,
                                             ex_slivers, avoid)
                    if got is None:
                        row["n_rejected"] += 1
                        continue
                    pieces = got
                    row.update(outcome=outcome, database=names[i],
                               fragment_id=int(db.ids[db_row]), cost=cost)
                    new_attrs.append((f"{names[i]}:{int(db.ids[db_row])}", names[i],
                                      int(db.ids[db_row]), len(pieces), query_id))
                    break
                if pieces is not None:
                    break
            if pieces is None:
                split = statistical_split(face, sides, rng, min_area, min_width,
                                          avoid=avoid)
                if len(split):
                    pieces = split
                    row.update(outcome="fill_statistics")
                    new_attrs.append(("statistics", "", -1, len(split), query_id))
                else:
                    exhausted.add(key)
            if pieces is not None:
                new_geoms.append(pieces)
                tried.add(key)
            counts[row["outcome"]] += 1
            query_rows.append(row)
            query_id += 1
        if new_geoms:
            geometry, level, attrs = add_streets(geometry, level, attrs, new_geoms, new_attrs,
                                                 next_level, min_dangle)
            next_level += 1
    return geometry, level, attrs, counts, query_id


def _left_empty(geometry, max_block: float, min_area: float, min_width: float,
                target=None) -> int:
    """What the fill rule is about: faces over ``max_block`` with no street inside."""
    faces = _faces_in(geometry, min_area, min_width, target)
    big = faces[shapely.area(faces) > max_block] if len(faces) else faces
    return int(_empty(big, geometry).sum()) if len(big) else 0


def _link_level(level, max_level: Optional[int] = None) -> int:
    """The level of a link that joins pieces apart: a level below the deepest street, but
    not below ``max_level``."""
    lvl = int(level.max()) + 1 if len(level) else 1
    return max(min(lvl, int(max_level)), 1) if max_level is not None else lvl


def _off_controlled_access(geometry, level, attrs, arterials, arterial_class, inside,
                           max_level: Optional[int] = None):
    """Streets that end on a motorway or trunk of the arterials away from its junctions end
    short of it; a piece cut off is linked again ('link', at :func:`_link_level`;
    :func:`network.controlled_access.end_short_of_controlled_access`). Returns the network
    and the rule's counts."""
    is_new = synthesised(level, attrs["source_fragment"])
    geometry, source, ca = end_short_of_controlled_access(geometry, is_new, arterials,
                                                          arterial_class, inside)
    link = {"source_fragment": "link", "database": "", "fragment_id": -1, "query": -1}
    level = np.r_[level, _link_level(level, max_level)][source]
    attrs = {k: np.r_[v, np.array([link[k]], dtype=v.dtype)][source] for k, v in attrs.items()}
    return geometry, level, attrs, ca


def _link_floating(geometry, level, attrs, inside, max_level: Optional[int] = None):
    """Link the pieces of the network that do not reach an arterial to the network that does
    (:func:`links.link_floating_pieces`: streets of faces closed only by the boundary, whose
    outline is no street), bent along the target where no straight link stays inside it
    (the streets of a hamlet at the end of a narrow arm of the target: Schaan's were dropped
    with up to 3.2 km of streets, leaving a face of three times the example's p90 block
    empty); a piece that cannot be linked is dropped. Then arterials apart inside the
    target, with the streets on each, are joined into one network (:func:`links.join_pieces`;
    parts of a target apart stay apart). Every link stays ``inside``, at
    :func:`_link_level`. Returns the network, the number of links and the number of streets
    dropped."""
    links, keep = link_floating_pieces(geometry, attrs["source_fragment"] == "arterial",
                                       inside=inside, bent=True)
    if not keep.all():
        geometry, level = geometry[keep], level[keep]
        attrs = {k: v[keep] for k, v in attrs.items()}

    def with_links(geometry, level, attrs, links):
        if not len(links):
            return geometry, level, attrs
        return add_streets(geometry, level, attrs, [links], [("link", "", -1, len(links), -1)],
                           _link_level(level, max_level), 0.0)

    geometry, level, attrs = with_links(geometry, level, attrs, links)
    joins = join_pieces(geometry, inside=inside)
    geometry, level, attrs = with_links(geometry, level, attrs, joins)
    return geometry, level, attrs, len(links) + len(joins), int((~keep).sum())


def example_dead_end_share(databases: Sequence[FragmentDatabase]) -> float:
    """The example's dead-end share recorded in the databases' metadata (``dead_end_share``,
    their mean), NaN when none records it.

    The fragments cannot tell it: a dead-end street outside every closed face is in no
    fragment (Bubeneč's three fragments hold none of its dead ends).
    """
    values = [float(db.metadata["dead_end_share"]) for db in databases
              if "dead_end_share" in (getattr(db, "metadata", None) or {})]
    return float(np.mean(values)) if values else float("nan")


# --------------------------------------------------------------------------- relief

def _relief_for_face(face, dem: DemGrid, db: FragmentDatabase, row: int, path: np.ndarray,
                     q_samples: np.ndarray):
    """Cells of ``dem`` inside the face and the warped example relief there (or None)."""
    if db.relief is None:
        return None
    patch = db.relief.get(int(db.ids[row]))
    if patch is None:
        return None
    heights, gt = patch
    x0, dx, _, y0, _, dy = dem.geotransform
    rows, cols = dem.array.shape
    b = face.bounds
    c0 = max(int(np.floor((b[0] - x0) / dx)), 0)
    c1 = min(int(np.ceil((b[2] - x0) / dx)), cols)
    r0 = max(int(np.floor((b[3] - y0) / dy)), 0)
    r1 = min(int(np.ceil((b[1] - y0) / dy)), rows)
    if c1 <= c0 or r1 <= r0:
        return None
    cc, rr = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
    x = x0 + dx * (cc.ravel() + 0.5)
    y = y0 + dy * (rr.ravel() + 0.5)
    inside = shapely.contains_xy(face, x, y)
    if not inside.any():
        return None
    cells = np.column_stack([x[inside], y[inside]])
    ex = db.descriptors.samples[row][path[:, 1]]
    src = warp_points(cells, q_samples[path[:, 0]], ex)
    values = DemGrid(np.asarray(heights, dtype=np.float64), gt)(src)
    flat = rr.ravel()[inside] * cols + cc.ravel()[inside]
    return flat, values


# --------------------------------------------------------------------------- main

def _style_index(faces: np.ndarray, style_polygons, style_database, n_db: int) -> np.ndarray:
    """Database index per face: the style polygon holding the face's representative point."""
    out = np.zeros(len(faces), dtype=np.int64)
    if style_polygons is None or len(faces) == 0:
        return out
    polys = np.asarray(style_polygons, dtype=object)
    pts = shapely.point_on_surface(faces)
    f_idx, p_idx = shapely.STRtree(polys).query(pts, predicate="within")
    # the first style polygon (lowest index) wins where several overlap
    order = np.lexsort((p_idx, f_idx))
    f_idx, p_idx = f_idx[order], p_idx[order]
    first = np.r_[True, f_idx[1:] != f_idx[:-1]]
    out[f_idx[first]] = np.asarray(style_database)[p_idx[first]]
    return out


def synthesize(arterials: Sequence, databases: Sequence[FragmentDatabase],
               dem: Optional[DemGrid] = None, style_polygons: Optional[Sequence] = None,
               style_database: Optional[Sequence[int]] = None, n_best: int = 3,
               seed: Optional[int] = None, max_level: Optional[int] = None,
               gamma: float = 0.5, names: Optional[Sequence[str]] = None,
               min_area: float = MIN_BLOCK_AREA, min_width: float = MIN_BLOCK_WIDTH,
               snap_tolerance: float = 1.0, snap_distance: float = 3.0,
               min_dangle: float = MIN_DANGLE, c: int = N_CANDIDATES,
               max_scale: float = MAX_SCALE,
               boundary=None, fill: bool = True, fill_quantile: float = FILL_QUANTILE,
               dead_end_share: Optional[float] = None,
               progress: Optional[Progress] = None,
               arterial_class: Optional[Sequence] = None) -> SynthesisResult:
    """Synthesise a street network inside sketched arterials from fragment databases.

    Parameters
    ----------
    arterials : array of LineString / MultiLineString, metric CRS (the sketch, level 0)
    databases : list of FragmentDatabase (:func:`database.load_fragment_database`); their
        geometries may be in any metric CRS (fragments are aligned and warped, never placed
        at their own coordinates)
    dem : DemGrid, optional, the desired terrain in the arterials' CRS: adds the slope term
        to the retrieval and returns the height field with the fragments' relief merged
    style_polygons : array of Polygon, optional; ``style_database`` gives per polygon the
        index (0-based) of the database to use inside it
    n_best : int, random choice among this many best matches (1 = always the best)
    seed : int, optional, seed of the random generator (same seed, same network)
    max_level : int, optional, deepest street level to synthesise (default: as deep as
        the databases go); with it the fill and the dead-end steering are off (a network of
        those levels only: a face over the example's p90 may stay empty), and the links
        that join pieces apart take that level, none deeper
    gamma : float in [0, 1], weight of the shape term against the slope term (eq. 4.2)
    names : database names for the output (default: the file names without extension)
    min_area, min_width : float, faces under these (m², m) are slivers, not queries
    snap_tolerance : float, node snapping of the arterials (m, :func:`roads.clean_network`)
    snap_distance : float, a warped street end snaps onto a query corner this close (m)
    min_dangle : float, new dead-end edges shorter than this (m) are removed
    max_scale : float, a fragment is inserted only when the query's linear size (square
        root of the area) is within this factor of the fragment's
    c : int, prefilter size (thesis: 10)
    boundary : Polygon(s), optional, the target: the arterials are clipped to it and its
        outline closes the faces they leave open (:func:`close_sketch`); the outline is no
        street of the result, so streets that reach it end there
    fill : bool, fill the faces down to the example's block sizes (see below); a
        ``max_level`` that stops the recursion early turns the fill off
    fill_quantile : float, quantile (%) of the example's block areas above which no face
        stays empty (the issue's rule: 90)
    dead_end_share : float in [0, 1], optional, the example's dead-end share
        (:func:`invariants.dead_end_share` on the example inside its area) to steer the
        result's to; default the one the databases record (:func:`example_dead_end_share`),
        no steering when none does
    progress : Progress, optional (per query fragment; raises Canceled)
    arterial_class : OSM class per line of ``arterials``, optional: a new street that ends
        on a motorway or trunk away from its junctions (a fragment's street warped onto its
        face's outline) ends short of it (:mod:`network.controlled_access`)

    Returns
    -------
    SynthesisResult

    Notes
    -----
    The fill stage (not in the thesis, whose Function 2 stops when the databases have no
    deeper level and leaves a face empty when its best match is a block): a face may stay
    empty (no street inside), and is split down to the example's block sizes, only when it
    is no larger than the example's p90 block area
    (:func:`example_blocks`; ``fill_quantile`` chooses another quantile). Larger faces
    are filled, round after round, (1) with a
    fragment of any level that holds streets, no larger than the face (a fragment shrunk
    into it would leave blocks smaller than the example's) and within ``max_scale`` of it;
    else (2) with the best-matching smaller such fragment at whatever scale, which splits
    the face along the fragment's streets (its pieces are filled in the next rounds);
    else (3) by a
    statistics-driven split (:func:`statistical_split`, a street cutting off a piece of the
    example's block dimensions). ``queries.outcome`` says which way each face went
    ('fill_fragment', 'fill_scaled', 'fill_statistics', 'left_empty'). At the end, pieces
    of the network not connected to the arterials (streets of faces closed only by the
    boundary) are linked to them by the shortest street that crosses nothing ('link'),
    bent along the target where no straight one stays inside it (``stats['n_dropped']``:
    the streets of pieces no link reaches). Last, the dead-end share, counted as
    :func:`invariants.check_network` counts it, is steered to the example's
    (:mod:`network.dead_ends`: dead ends closed onto the nearest street while it is above
    ('close'), cul-de-sacs added into blocks ('cul-de-sac') and stems of T's cut short while
    it is below; ``stats['dead_ends']``). ``stats['fill']['left_empty']`` counts the faces
    over the threshold left empty in the network returned (the boundary closing them).

    Raises
    ------
    InputError
        No database, absurd parameters, arterials that enclose no face.

    References
    ----------
    Hartmann, thesis ch. 4.1.3 (Function 2).
    """
    progress = ensure(progress)
    databases = list(databases)
    if not databases:
        raise InputError("at least one fragment database is needed")
    if not (1 <= int(n_best) <= MAX_N_BEST) or int(n_best) != n_best:
        raise InputError(f"N_BEST must be a whole number from 1 to {MAX_N_BEST}, got {n_best}")
    n_best = int(n_best)
    if not 0 <= gamma <= 1:
        raise InputError(f"gamma must lie in [0, 1], got {gamma}")
    if not max_scale >= 1:
        raise InputError(f"the maximum scale factor must be at least 1, got {max_scale}")
    if dead_end_share is not None and not 0 <= dead_end_share <= 1:
        raise InputError(f"the dead-end share must lie in [0, 1], got {dead_end_share}")
    if max_level is not None and (int(max_level) != max_level or max_level < 0):
        raise InputError(f"the maximum level must be a whole number >= 0, got {max_level}")
    if arterial_class is not None and len(arterial_class) != len(arterials):
        raise InputError(f"{len(arterial_class)} road classes for {len(arterials)} arterials")
    if style_polygons is not None:
        style_database = np.asarray(style_database, dtype=np.int64)
        if len(style_database) != len(style_polygons):
            raise InputError("one database index per style polygon is needed")
        bad = (style_database < 0) | (style_database >= len(databases))
        if bad.any():
            raise InputError(f"style polygons name database {int(style_database[bad][0]) + 1}, "
                             f"but only {len(databases)} database(s) are given")
    names = [Path(d.path).stem for d in databases] if names is None else list(names)
    rng = np.random.default_rng(seed)
    t_start = time.perf_counter()

    if boundary is not None:
        sketch, is_ring = close_sketch(arterials, boundary)
    else:
        sketch, is_ring = np.asarray(arterials, dtype=object), None
    graph = _roads.clean_network(sketch, snap_tolerance=snap_tolerance,
                                 min_dangle_length=0.0)
    geometry = np.asarray(graph.geometry, dtype=object)
    level = np.zeros(len(geometry), dtype=np.int64)
    attrs = {"source_fragment": np.where(is_ring[graph.source], "boundary", "arterial")
             .astype(object) if is_ring is not None else
             np.full(len(geometry), "arterial", dtype=object),
             "database": np.full(len(geometry), "", dtype=object),
             "fragment_id": np.full(len(geometry), -1, dtype=np.int64),
             "query": np.full(len(geometry), -1, dtype=np.int64)}
    target = None
    if boundary is not None:
        target = shapely.make_valid(shapely.union_all(shapely.get_parts(
            np.asarray(boundary, dtype=object).ravel())))
        shapely.prepare(target)
    faces0 = _faces_in(geometry, min_area, min_width, target)
    if len(faces0) == 0:
        raise InputError("the arterials enclose no face: draw closed loops of streets "
                         f"(each at least {min_area:g} m² and {min_width:g} m wide) to "
                         "fill with fragments")
    area = shapely.union_all(faces0)
    blocks_ex = example_blocks(databases)
    if not 0 <= fill_quantile <= 100:
        raise InputError(f"the fill quantile must lie in [0, 100], got {fill_quantile}")
    max_block = float(np.percentile(blocks_ex["area_m2"], fill_quantile)) \
        if fill and len(blocks_ex) else np.inf
    base_level = [int(_db_levels(d).min()) if len(d) else 0 for d in databases]
    levels_of = [set(int(x) for x in _db_levels(d)) for d in databases]
    inserter = _Inserter(min_area, min_width, snap_distance)
    heights = None if dem is None else np.array(dem.array, dtype=np.float64)
    query_rows: List[dict] = []
    stats: Dict = {"levels": {}}
    query_id = 0
    deepest = MAX_LEVELS if max_level is None else min(int(max_level), MAX_LEVELS)

    for lvl in range(deepest):
        usable = [lvl + base_level[i] in levels_of[i] for i in range(len(databases))]
        if not any(usable):
            break
        t_level = time.perf_counter()
        if lvl == 0:
            faces = faces0
        else:
            faces = _faces_in(geometry[level <= lvl], min_area, min_width, target)
        if len(faces) == 0:
            break
        cur_dem = None if dem is None else DemGrid(heights, dem.geotransform)
        relief = _query_relief(faces, cur_dem)
        style = _style_index(faces, style_polygons, style_database, len(databases))
        # candidates per face: (cost, db index, Retrieval, face index in it, candidate k)
        options: List[list] = [[] for _ in range(len(faces))]
        pooled = style_polygons is None and len(databases) > 1
        for i, db in enumerate(databases):
            if not usable[i]:
                continue
            sel = np.arange(len(faces)) if pooled else np.flatnonzero(style == i)
            if not len(sel):
                continue
            ret = retrieve(db, faces[sel], lvl + base_level[i], cur_dem, gamma, c,
                           None if relief is None else relief[sel])
            for j, f in enumerate(sel):
                for k in ret.ranked(j, n_best):
                    options[f].append((float(ret.costs[j, k]), i, ret, j, int(k)))
        new_geoms, new_attrs = [], []
        relief_cells, relief_values, relief_labels = [], [], []
        counts = dict(queries=len(faces), fragment=0, block=0, procedural=0, unsplit=0,
                      too_small=0, no_candidate=0, rejected=0)
        n_faces = len(faces)
        tree = shapely.STRtree(geometry)
        for f, face in enumerate(faces):
            avoid = _touching(face, tree, geometry)
            progress.step((lvl + f / n_faces) / max(deepest, 1) * 0.6)
            opts = sorted(options[f], key=lambda o: o[0])[:n_best]
            row = dict(query=query_id, level=lvl, database="", fragment_id=-1, cost=np.nan,
                       outcome="no_candidate", area_m2=float(face.area), n_rejected=0)
            chosen = None
            pieces = None
            too_small = 0
            for o in (opts[int(p)] for p in rng.permutation(len(opts))):
                cost, i, ret, j, k = o
                db = databases[i]
                db_row = int(ret.rows[j, k])
                ratio = face.area / max(float(db.table["area_m2"].iat[db_row]), 1e-9)
                if not 1 / max_scale ** 2 <= ratio <= max_scale ** 2:
                    row["n_rejected"] += 1
                    too_small += ratio < 1
                    continue
                _, dtw = sc.dtw_path(ret.cost_matrices[j, k], int(ret.offsets[j, k]))
                streets, on, ex_slivers = inserter.example(db, db_row)
                if len(streets) == 0:
                    if face.area > max_block:   # too large to stay empty: the fill's job
                        row["n_rejected"] += 1
                        continue
                    chosen = (o, dtw)
                    row.update(outcome="block")
                    break
                pieces, reason = inserter.insert(face, ret.samples[j],
                                                 db.descriptors.samples[db_row], dtw,
                                                 streets, on, ex_slivers, avoid)
                if pieces is not None:
                    chosen = (o, dtw)
                    row.update(outcome="fragment")
                    break
                row["n_rejected"] += 1
            if chosen is not None:
                (cost, i, ret, j, k), dtw = chosen
                db = databases[i]
                db_row = int(ret.rows[j, k])
                row.update(database=names[i], fragment_id=int(db.ids[db_row]), cost=cost)
                if pieces is not None and row["outcome"] == "fragment":
                    new_geoms.append(pieces)
                    new_attrs.append((f"{names[i]}:{int(db.ids[db_row])}", names[i],
                                      int(db.ids[db_row]), len(pieces), query_id))
                if heights is not None:
                    got = _relief_for_face(face, cur_dem, db, db_row, dtw, ret.samples[j])
                    if got is not None:
                        relief_cells.append(got[0])
                        relief_values.append(got[1])
                        relief_labels.append(np.full(len(got[0]), query_id))
            elif opts and too_small == len(opts):
                row.update(outcome="too_small")
            elif opts:
                split = procedural_split(face, min_area, min_width, avoid)
                if len(split):
                    row.update(outcome="procedural")
                    new_geoms.append(split)
                    new_attrs.append(("procedural", "", -1, len(split), query_id))
                else:
                    row.update(outcome="unsplit")
            counts[row["outcome"]] += 1
            counts["rejected"] += row["n_rejected"]
            query_rows.append(row)
            query_id += 1
        if relief_cells:
            cells = np.concatenate(relief_cells)
            guidance = np.full(heights.size, np.nan)
            guidance[cells] = np.concatenate(relief_values)
            mask = np.zeros(heights.size, dtype=bool)
            mask[cells] = True
            labels = np.zeros(heights.size, dtype=np.int64)
            labels[cells] = np.concatenate(relief_labels)
            base = np.where(np.isfinite(heights), heights, np.nanmean(heights))
            heights = poisson_blend(base, guidance.reshape(heights.shape),
                                    mask.reshape(heights.shape), labels.reshape(heights.shape))
        if new_geoms:
            geometry, level, attrs = add_streets(geometry, level, attrs, new_geoms,
                                                 new_attrs, lvl + 1, min_dangle)
        counts["seconds"] = time.perf_counter() - t_level
        stats["levels"][lvl] = counts
        # every query has one outcome: the rest are too small, or neither a fragment nor a
        # split fits them
        rest = counts["queries"] - counts["fragment"] - counts["block"] - counts["procedural"]
        progress.info(f"Level {lvl}: {counts['queries']} query fragments, "
                      f"{counts['fragment']} filled from examples, {counts['block']} kept as "
                      f"blocks, {counts['procedural']} split procedurally"
                      + (f", {rest} left as they are (too small, or no fragment or split "
                         "fits)" if rest else "")
                      + (f" ({counted(counts['rejected'], 'warp')} rejected)"
                         if counts["rejected"] else "")
                      + ".")
    if fill and max_level is None and np.isfinite(max_block):
        t_fill = time.perf_counter()
        geometry, level, attrs, fill_counts, query_id = _fill_stage(
            geometry, level, attrs, databases, names, inserter, rng, max_block, blocks_ex,
            n_best, c, gamma, max_scale, min_area, min_width, min_dangle, query_rows, query_id,
            progress.sub(0.6, 0.95), target, style_polygons, style_database)
        fill_counts["seconds"] = time.perf_counter() - t_fill
        fill_counts["max_block_m2"] = max_block
        stats["fill"] = fill_counts
        progress.info(f"Fill: faces over the example's p{fill_quantile:g} block area "
                      f"({max_block:,.0f} m²): {fill_counts['fill_fragment']} filled with "
                      f"fragments at scale, {fill_counts['fill_scaled']} split along a scaled "
                      f"fragment's streets, {fill_counts['fill_statistics']} split from the "
                      "example's block dimensions.")
    outline = np.empty(0, dtype=object)
    if is_ring is not None:
        on_ring = attrs["source_fragment"] == "boundary"
        outline = geometry[on_ring]
        geometry, level = geometry[~on_ring], level[~on_ring]
        attrs = {k: v[~on_ring] for k, v in attrs.items()}
    geometry, level, attrs, n_links, n_dropped = _link_floating(
        geometry, level, attrs, target if target is not None else area, max_level)
    stats["links"] = n_links
    stats["n_dropped"] = n_dropped
    if n_links or n_dropped:
        progress.info(f"{n_links} street(s) added to link pieces of the network that "
                      "touched only the boundary to the arterials, or arterials that lay "
                      f"apart to each other; {n_dropped} street(s) of pieces no link reaches "
                      "dropped.")
    if fill and max_level is None:
        share = example_dead_end_share(databases) if dead_end_share is None else \
            float(dead_end_share)
        counted_in = target if target is not None else area
        geometry, level, attrs, (n_closed, n_opened), now = steer_attributed(
            geometry, level, attrs, share, counted_in, rng, min_dangle, max_block)
        stats["dead_ends"] = dict(example_share=share, share=now, closed=n_closed,
                                  opened=n_opened)
        progress.info(f"Dead-end share {now:.2f} (example {share:.2f}): {n_closed} dead "
                      f"end(s) closed, {n_opened} T stem(s) cut into cul-de-sacs.")
    if arterial_class is not None:
        geometry, level, attrs, ca = _off_controlled_access(
            geometry, level, attrs, arterials, arterial_class,
            target if target is not None else area, max_level)
        stats["controlled_access_ended_short"] = ca["n_ended_short"] + ca["n_removed"]
        stats["n_dropped"] += ca["n_dropped"]
        if stats["controlled_access_ended_short"]:
            progress.info(f"{stats['controlled_access_ended_short']} street(s) that ended on a "
                          f"motorway or trunk away from its junctions end short of it; "
                          f"{ca['n_dropped']} street(s) that only such a road reached "
                          "dropped.")
    # what the invariants read within their tolerance, exactly: no street ending a few
    # decimetres from a junction, no street of a few decimetres between two
    new = synthesised(level, attrs["source_fragment"])
    geometry, keep = close_short_gaps(geometry, new, SNAP_TOLERANCE)
    level, attrs = level[keep], {k: v[keep] for k, v in attrs.items()}
    # nor a metre or two short of one (a warped street's end, a stub by a junction)
    geometry, keep = clear_undershoots(geometry, new[keep])
    level, attrs = level[keep], {k: v[keep] for k, v in attrs.items()}
    keep = shapely.length(geometry) > 1e-6
    geometry = geometry[keep]
    if "fill" in stats:  # counted on the network returned, the outline closing its faces
        stats["fill"]["left_empty"] = _left_empty(np.concatenate([geometry, outline]),
                                                  max_block, min_area, min_width, target)
        progress.info(f"Faces over the example's p{fill_quantile:g} block area left empty: "
                      f"{stats['fill']['left_empty']}.")
    table = pd.DataFrame({"level": level[keep],
                          "source_fragment": attrs["source_fragment"][keep],
                          "database": attrs["database"][keep],
                          "fragment_id": attrs["fragment_id"][keep],
                          "length_m": shapely.length(geometry)})
    out_dem = None if dem is None else DemGrid(heights, dem.geotransform)
    stats["seconds"] = time.perf_counter() - t_start
    stats["n_queries"] = len(query_rows)
    stats["area_km2"] = float(area.area) / 1e6
    stats["max_block_m2"] = max_block
    progress.step(1.0)
    queries = pd.DataFrame(query_rows, columns=["query", "level", "database", "fragment_id",
                                                "cost", "outcome", "area_m2", "n_rejected"])
    return SynthesisResult(geometry, table.reset_index(drop=True), out_dem, queries, area, stats)
