"""Fidelity of a synthesised street network to a real one, and the naive baselines it must beat.

The yardstick of the fidelity benchmark (``tests/benchmarks/bench_fidelity.py``): a method
is given a town's arterials and boundary and an example of other towns; its streets are
measured with :func:`plugin.measure.metrics.compute_layout_metrics` inside the boundary and
compared, statistic by statistic, with the town's real drivable streets. DESIGN.md
("Quality measures"): "Judge a synthesis where it was not tuned, against naive baselines in
the same target: a grid at the example's median segment length, random chords and random
Delaunay edges with the example's street length per km². A method that does not beat them
is not yet a method."

- :data:`STATISTICS`: sixteen numbers of a network: intersections and dead ends per km²,
  km of street per km², the shares of degree 1, 3 and 4 among the nodes of degree != 2
  (degree-2 nodes dissolved), segment length p10 / median / p90, orientation entropy
  (Boeing 2019), blocks per km², block area p10 / median / p90, and the medians of block
  compactness and aspect ratio (Hartmann thesis ch. 4.2).
- :func:`relative_errors`: |candidate - real| / |real| per statistic; a statistic the
  candidate cannot produce (no block) counts as error 1.
- baselines: :func:`grid_baseline`, :func:`chord_baseline`, :func:`delaunay_baseline`.
- :func:`score`: median relative error and wins against each baseline.

References
----------
Yang et al. 2013, sec. 7 (street metrics s_l, s_i, s_d); Boeing 2019 (orientation entropy);
Hartmann thesis ch. 4.2 (block area, compactness, aspect ratio as distributions).
"""
from __future__ import annotations

from typing import Dict, Mapping, Optional, Sequence

import numpy as np
import shapely
from scipy.spatial import Delaunay

from ..core.progress import InputError
from ..network import blocks as _blocks
from ..network import invariants as _invariants
from . import metrics as _metrics

__all__ = [
    "STATISTICS", "EDGE_DISTANCE", "clip_to_area", "fidelity_statistics", "land_in_blocks",
    "statistics_of_extract", "relative_errors",
    "grid_baseline", "chord_baseline", "delaunay_baseline", "score",
]

#: The statistics, in table order: (key, label).
STATISTICS = (
    ("intersections_per_km2", "Intersections / km²"),
    ("dead_ends_per_km2", "Dead ends / km²"),
    ("street_length_km_per_km2", "Street km / km²"),
    ("degree1_share", "Degree-1 share"),
    ("degree3_share", "Degree-3 share"),
    ("degree4_share", "Degree-4 share"),
    ("segment_length_p10", "Segment length p10 (m)"),
    ("segment_length_p50", "Segment length median (m)"),
    ("segment_length_p90", "Segment length p90 (m)"),
    ("orientation_entropy", "Orientation entropy (nats)"),
    ("blocks_per_km2", "Blocks / km²"),
    ("block_area_p10", "Block area p10 (m²)"),
    ("block_area_p50", "Block area median (m²)"),
    ("block_area_p90", "Block area p90 (m²)"),
    ("block_compactness_p50", "Block compactness median"),
    ("block_aspect_p50", "Block aspect ratio median"),
)
#: Nodes this close (m) to the boundary are where the network was cut, not dead ends.
EDGE_DISTANCE = 1.0


def clip_to_area(lines: Sequence, area, edge_distance: float = EDGE_DISTANCE) -> np.ndarray:
    """The parts of ``lines`` inside ``area``: single lines longer than a centimetre. A
    street within ``edge_distance`` of the area counts as inside it, as the invariants
    count a synthesised street inside its target (:func:`metrics.clip_lines`: a street
    along the edge whole, each street across it ending on it).

    A street along the edge that rounds a reflex corner 0.5 m outside counts whole (m);
    clipped within a millimetre, only its two ends' 10 cm were left:

    >>> area = shapely.Polygon([(0, 0), (100, 0), (100, 50), (50, 50), (50, 100), (0, 100)])
    >>> along = shapely.LineString([(100, 50), (50.5, 50.5), (50, 100)])
    >>> [round(float(shapely.length(clip_to_area([along], area, d)).sum()), 1)
    ...  for d in (1.0, 1e-3)]
    [99.0, 0.2]
    """
    lines = np.asarray(lines, dtype=object).ravel()
    if not len(lines):
        return np.empty(0, dtype=object)
    parts = _metrics.clip_lines(lines, area, tolerance=edge_distance)
    return parts[shapely.length(parts) > 0.01]


def fidelity_statistics(lines: Sequence, area, min_block_area: float = _blocks.MIN_BLOCK_AREA,
                        min_block_width: float = _blocks.MIN_BLOCK_WIDTH,
                        edge_distance: float = EDGE_DISTANCE) -> Dict[str, float]:
    """The :data:`STATISTICS` of a street network inside ``area``.

    Lines are clipped to the area and measured with
    :func:`metrics.compute_layout_metrics` (densities per km² of the area; nodes within
    ``edge_distance`` of its boundary are clip ends and do not count; faces under
    ``min_block_area`` m² or thinner than ``min_block_width`` m are slivers, not blocks).
    Statistics of an empty distribution (no block) are NaN.
    """
    parts = clip_to_area(lines, area, edge_distance)
    if not len(parts):
        raise InputError("no street lies inside the area")
    m = _metrics.compute_layout_metrics(roads=parts, area=area, min_block_area=min_block_area,
                                        min_block_width=min_block_width,
                                        edge_distance=edge_distance)
    out = {k: m.scalar("roads", k) for k in ("intersections_per_km2", "dead_ends_per_km2",
                                             "street_length_km_per_km2", "degree3_share",
                                             "degree4_share", "orientation_entropy")}
    out["degree1_share"] = m.scalar("roads", "dead_end_share")
    seg = m.distribution("roads", "segment_length")
    for q in (10, 50, 90):
        out[f"segment_length_p{q}"] = float(np.percentile(seg, q)) if len(seg) else np.nan
    has_blocks = m.has("blocks", "area")
    out["blocks_per_km2"] = m.scalar("blocks", "blocks_per_km2") if has_blocks else 0.0
    area_d = m.distribution("blocks", "area") if has_blocks else np.zeros(0)
    for q in (10, 50, 90):
        out[f"block_area_p{q}"] = float(np.percentile(area_d, q)) if len(area_d) else np.nan
    for key, name in (("block_compactness_p50", "compactness"),
                      ("block_aspect_p50", "aspect_ratio")):
        d = m.distribution("blocks", name) if has_blocks else np.zeros(0)
        out[key] = float(np.median(d)) if len(d) else np.nan
    return {k: float(out[k]) for k, _ in STATISTICS}


def land_in_blocks(lines: Sequence, area, min_block_area: float = _blocks.MIN_BLOCK_AREA,
                   min_block_width: float = _blocks.MIN_BLOCK_WIDTH) -> float:
    """The share of ``area`` inside the blocks of the streets (the faces
    :func:`fidelity_statistics` counts as blocks, :func:`metrics.block_faces` of the lines
    clipped to the area; ``layoutmetrics``' ``land_share`` / 100). Not one of the
    :data:`STATISTICS`, and scored by none: it tells how much of a target a network leaves
    open, which the block statistics (of the closed blocks only) do not; the fidelity
    benchmark reports it beside them.

    A 300 m square area with streets closing its western two thirds into blocks:

    >>> grid = ([shapely.LineString([(x, 0), (x, 300)]) for x in (0, 100, 200)]
    ...         + [shapely.LineString([(0, y), (200, y)]) for y in (0, 150, 300)])
    >>> round(land_in_blocks(grid, shapely.box(0, 0, 300, 300)), 3)
    0.667
    """
    faces = closed_blocks(lines, area, min_block_area, min_block_width)
    if not len(faces):
        return 0.0
    return _metrics.block_metrics(faces, area).scalar("blocks", "land_share") / 100.0


def edge_ends(lines: Sequence, area, given: Sequence = (),
              edge_distance: float = EDGE_DISTANCE) -> float:
    """Streets cut at the edge of ``area``, per km²: the network's ends (nodes of degree 1)
    within ``edge_distance`` of its boundary, those of the ``given`` roads not counted (a
    town's arterials leave it). :func:`fidelity_statistics` counts them as no dead ends (a
    network clipped to an area ends there), so the dead-end statistics do not see them;
    scored by none, reported beside them: a town's envelope hugs its streets, so few of its
    own reach its edge.

    A 200 m square crossed by a given road, with a street from it to the northern edge and
    a cul-de-sac (a dead end, not at the edge):

    >>> square = shapely.box(0, 0, 200, 200)
    >>> given = [shapely.LineString([(0, 100), (200, 100)])]
    >>> streets = [shapely.LineString([(100, 100), (100, 200)]),
    ...            shapely.LineString([(50, 100), (50, 150)])]
    >>> edge_ends(given + streets, square, given)
    25.0
    """
    parts = clip_to_area(lines, area, edge_distance)
    if not len(parts):
        return 0.0
    # the graph fidelity_statistics counts the dead ends on
    g = _metrics.road_graph(parts)
    nodes = np.asarray(g.nodes)
    # every node of the clipped network lies in the area: those not counted are at its edge
    cut = (g.degree == 1) & ~_invariants.counted_nodes(nodes, area, edge_distance)
    given = np.asarray(given, dtype=object).ravel()
    if len(given) and cut.any():
        # a given road's own end (merged nodes move by up to half the snap tolerance)
        cut[cut] = ~shapely.dwithin(shapely.union_all(given), shapely.points(nodes[cut]),
                                    _invariants.SNAP_TOLERANCE)
    return float(cut.sum() / (shapely.area(area) / 1e6))


def closed_blocks(lines: Sequence, area, min_block_area: float = _blocks.MIN_BLOCK_AREA,
                  min_block_width: float = _blocks.MIN_BLOCK_WIDTH) -> np.ndarray:
    """The blocks :func:`fidelity_statistics` counts: the faces of the streets clipped to
    ``area`` (:func:`metrics.block_faces`, traffic islands under ``min_block_area`` or
    thinner than ``min_block_width`` left out)."""
    parts = clip_to_area(lines, area)
    if not len(parts):
        return np.empty(0, dtype=object)
    return np.asarray(_metrics.block_faces(parts, min_block_area, min_block_width),
                      dtype=object)


def statistics_of_extract(lines: Sequence) -> Dict[str, float]:
    """The :data:`STATISTICS` of an example known only by its lines, measured inside their
    convex hull (:func:`invariants.extract_hull`: an extract's streets are cut at its edge,
    which the hull follows): what a generator is steered to
    (:func:`roads.streetgan.example_steering`). All NaN when the lines span no area.

    A 300 m square cut into nine 100 m blocks, one of them halved:

    >>> grid = ([shapely.LineString([(x, 0), (x, 300)]) for x in range(0, 301, 100)]
    ...         + [shapely.LineString([(0, y), (300, y)]) for y in range(0, 301, 100)])
    >>> halved = grid + [shapely.LineString([(0, 50), (100, 50)])]
    >>> s = statistics_of_extract(halved)
    >>> round(s["block_area_p10"]), round(s["block_area_p50"]), s["blocks_per_km2"] > 0
    (5000, 10000, True)
    """
    lines = np.asarray(lines, dtype=object)
    hull = _invariants.extract_hull(lines) if len(lines) else None
    if hull is None or hull.area <= 0:
        return {k: np.nan for k, _ in STATISTICS}
    return fidelity_statistics(lines, hull)


def relative_errors(candidate: Mapping[str, float], real: Mapping[str, float]) -> Dict[str, float]:
    """|candidate - real| / |real| per statistic.

    A statistic the candidate lacks (NaN: no block at all) counts as error 1; where the
    real value is 0, the error is 0 for 0 and 1 otherwise.
    """
    out = {}
    for key, _ in STATISTICS:
        c, r = float(candidate[key]), float(real[key])
        if not np.isfinite(r):
            out[key] = np.nan
        elif not np.isfinite(c):
            out[key] = 1.0
        elif r == 0:
            out[key] = 0.0 if c == 0 else 1.0
        else:
            out[key] = abs(c - r) / abs(r)
    return out


# --------------------------------------------------------------------------- baselines

def _area(area) -> shapely.Geometry:
    geoms = shapely.get_parts(np.asarray(area, dtype=object).ravel())
    geom = shapely.union_all(geoms) if len(geoms) else None
    if geom is None or geom.is_empty or geom.area <= 0:
        raise InputError("the target area has no area")
    return geom


def _head(line, length: float):
    """The first ``length`` metres of a line."""
    from shapely.ops import substring

    return substring(line, 0.0, max(float(length), 0.0))


def _given_length(given, area) -> float:
    return float(shapely.length(clip_to_area(given, area)).sum()) if given is not None else 0.0


def grid_baseline(area, spacing: float, angle: Optional[float] = None) -> np.ndarray:
    """A grid of streets ``spacing`` m apart over the area, clipped to it.

    Aligned with the area's minimum rotated rectangle unless ``angle`` (degrees from the x
    axis) is given; the grid's origin is the rectangle's centre.
    """
    geom = _area(area)
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError("the grid spacing must be a positive number of metres")
    long, short, ang = _blocks.minimum_rectangles([geom])
    a = np.radians(float(ang[0]) if angle is None else float(angle))
    u = np.array([np.cos(a), np.sin(a)])
    w = np.array([-u[1], u[0]])
    c = np.asarray(shapely.oriented_envelope(geom).centroid.coords[0])
    half = 0.5 * float(np.hypot(long[0], short[0])) + spacing
    offs = np.arange(-np.ceil(half / spacing), np.ceil(half / spacing) + 1) * spacing
    ends = []
    for axis, other in ((u, w), (w, u)):
        p = c + offs[:, None] * other
        ends.append(np.stack([p - half * axis, p + half * axis], axis=1))
    return clip_to_area(shapely.linestrings(np.concatenate(ends)), geom)


def chord_baseline(area, km_per_km2: float, rng: np.random.Generator,
                   given: Optional[Sequence] = None) -> np.ndarray:
    """Random chords of the area until the network (given roads included) has ``km_per_km2``.

    A chord is the piece, through a uniform random point of the area, of a line of uniform
    random direction, clipped to the area.
    """
    geom = _area(area)
    need = km_per_km2 * geom.area / 1e3 - _given_length(given, geom)
    out, total = [], 0.0
    x0, y0, x1, y1 = geom.bounds
    reach = float(np.hypot(x1 - x0, y1 - y0))
    done = need <= 0
    while not done:
        n = 64
        pts = shapely.points(rng.uniform([x0, y0], [x1, y1], (n, 2)))
        inside = shapely.contains(geom, pts)
        pts = pts[inside]
        if not len(pts):
            continue
        xy = shapely.get_coordinates(pts)
        t = rng.uniform(0, np.pi, len(xy))
        d = np.column_stack([np.cos(t), np.sin(t)]) * reach
        lines = shapely.linestrings(np.stack([xy - d, xy + d], axis=1))
        with np.errstate(invalid="ignore"):
            parts, owner = shapely.get_parts(shapely.intersection(lines, geom), return_index=True)
        # keep the piece through the drawn point
        through = shapely.dwithin(parts, pts[owner], 1e-6)
        for piece in parts[through]:
            if total + piece.length >= need:    # the last chord is cut to the density
                out.append(_head(piece, need - total))
                done = True
                break
            out.append(piece)
            total += piece.length
    return np.asarray(out, dtype=object)


def delaunay_baseline(area, km_per_km2: float, spacing: float, rng: np.random.Generator,
                      given: Optional[Sequence] = None) -> np.ndarray:
    """Random edges of a Delaunay triangulation of random points, up to ``km_per_km2``.

    Points are uniform in the area, about one per ``spacing``² (so that edges are about
    the example's segment length); edges are drawn in random order, clipped to the area,
    until the network (given roads included) reaches the density.
    """
    geom = _area(area)
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError("the point spacing must be a positive number of metres")
    need = km_per_km2 * geom.area / 1e3 - _given_length(given, geom)
    n = max(int(1.2 * geom.area / spacing ** 2), 4)
    x0, y0, x1, y1 = geom.bounds
    xy = np.zeros((0, 2))
    while len(xy) < n:
        cand = rng.uniform([x0, y0], [x1, y1], (2 * n, 2))
        xy = np.vstack([xy, cand[shapely.contains_xy(geom, cand[:, 0], cand[:, 1])]])
    xy = xy[:n]
    tri = Delaunay(xy)
    s = tri.simplices
    e = np.sort(np.vstack([s[:, [0, 1]], s[:, [1, 2]], s[:, [0, 2]]]), axis=1)
    e = np.unique(e, axis=0)
    e = e[rng.permutation(len(e))]
    edges = clip_to_area(shapely.linestrings(np.stack([xy[e[:, 0]], xy[e[:, 1]]], axis=1)), geom)
    if need <= 0:
        return edges[:0]
    cum = np.cumsum(shapely.length(edges))
    k = int(np.searchsorted(cum, need))
    if k >= len(edges):
        return edges
    out = edges[:k + 1].copy()
    out[k] = _head(out[k], need - (cum[k - 1] if k else 0.0))   # the last one cut to the density
    return out


# --------------------------------------------------------------------------- scoring

def score(candidate_runs: Sequence[Mapping[str, float]], real: Mapping[str, float],
          baseline_runs: Optional[Mapping[str, Sequence[Mapping[str, float]]]] = None) -> dict:
    """Relative errors of a method (mean over its runs), their median, wins on baselines.

    Parameters
    ----------
    candidate_runs : statistics of each run (seed) of the method
    real : statistics of the real network
    baseline_runs : {baseline name: statistics of each of its runs}

    Returns
    -------
    dict with ``errors`` {statistic: mean relative error}, ``median_error``, and
    ``wins`` {baseline: number of statistics where the method's error is smaller}.
    """
    def mean_errors(runs):
        errs = [relative_errors(r, real) for r in runs]
        return {k: float(np.nanmean([e[k] for e in errs])) if errs else np.nan
                for k, _ in STATISTICS}

    errors = mean_errors(candidate_runs)
    out = {"errors": errors, "median_error": float(np.nanmedian(list(errors.values())))}
    out["wins"] = {}
    for name, runs in (baseline_runs or {}).items():
        b = mean_errors(runs)
        out["wins"][name] = int(sum(errors[k] < b[k] for k, _ in STATISTICS
                                    if np.isfinite(errors[k]) and np.isfinite(b[k])))
    return out
