"""Layout quality and similarity metrics: roads, blocks, parcels and building footprints.

Implements the "Quality measures" of docs/ARCHITECTURE.md, which every synthesis uses to show
that its result resembles its example:

- roads: segment length, node degree, intersection angle and edge bearing distributions;
  dead ends, intersections and street length per km² (Yang et al. 2013, sec. 7, "street
  metrics" s_d, s_i, s_l); orientation entropy (Boeing 2019, as ``osmnx.bearing``);
- blocks: area, compactness, aspect ratio (Hartmann thesis ch. 4.2, Figs. 4.21-4.24) and
  boundary length; b_n per km², b_max / b_avg / b_min (Yang 2013, Table 1);
- parcels: p_n per km², p_angle, p_area, undesirable parcels, land-use shares l_s / l_r /
  l_p / l_o (Yang 2013, sec. 7 and Table 1);
- footprints: coverage, overlap with each other and with the road surface, footprints not
  inside one block, setback (docs/ARCHITECTURE.md, "Quality measures": overlaps and
  footprints outside blocks must be 0);
- two-sample comparison of a candidate layout with its example: Wasserstein distance and
  Kolmogorov-Smirnov statistic per distribution, relative difference per scalar.

Everything works on shapely 2 arrays in a metric CRS and is vectorised (numpy, STRtree);
nothing here imports QGIS.

References
----------
Yang, Y.-L., Wang, J., Vouga, E., Wonka, P. (2013). Urban pattern: layout design by
    hierarchical domain splitting. ACM TOG 32(6), sec. 7 "Quality Metrics" and Table 1.
Hartmann, S. Example-based urban modeling (thesis), ch. 4.2 (block area, compactness,
    aspect ratio compared as distributions).
Boeing, G. (2019). Urban spatial order: street network orientation, configuration, and
    entropy. Applied Network Science 4, 67 (orientation entropy, 36 bins, OSMnx).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy import stats

from ..core.geometry import minimum_rectangles
from ..core.progress import InputError, Progress, ensure
from ..core.text import counted
from ..network import blocks as _blocks
from ..network import invariants as _invariants
from ..network.street_graph import (DRIVABLE_CLASSES, SYNTHESISED_CLASSES, RoadGraph,
                                    degree2_chains, measured_graph)

__all__ = [
    "Scalar", "Distribution", "MetricsResult", "COMPARISON_COLUMNS",
    "road_graph", "road_metrics", "block_faces", "block_metrics", "parcel_metrics",
    "footprint_metrics", "compute_layout_metrics", "compare", "two_sample",
    "corner_angles", "corners", "street_bearings", "intersection_angles", "network_invariants",
    "orientation_entropy", "landuse_category", "clip_lines", "settled_area",
]

M2_PER_KM2 = 1e6
#: Yang 2013, Fig. 12: a parcel is undesirable when p_angle > 15 degrees or p_area > 1.2.
UNDESIRABLE_ANGLE = 15.0
UNDESIRABLE_AREA = 1.2
#: Vertices whose angle between the adjoining edges exceeds this are not corners.
STRAIGHT_ANGLE = 170.0
#: A footprint is inside a block when at most this share of its area lies outside it.
INSIDE_TOLERANCE = 1e-3
#: Overlaps smaller than this (m²) are numerical noise of shared edges, not overlaps.
OVERLAP_EPS = 1e-2
#: A node this close (m) to the study-area boundary is on it (the cut end of a clipped street);
#: graph nodes are rounded to the millimetre, which can put an extreme node just outside.
ON_EDGE = 1e-3

#: Columns of :func:`compare`, in order, with the type of each.
COMPARISON_COLUMNS = (
    ("kind", "str"), ("metric", "str"), ("statistic", "str"), ("unit", "str"),
    ("candidate", "float"), ("example", "float"), ("rel_diff", "float"),
    ("wasserstein", "float"), ("wasserstein_norm", "float"),
    ("ks_stat", "float"), ("ks_pvalue", "float"),
    ("n_candidate", "int"), ("n_example", "int"),
)

_KIND_ORDER = ("layout", "invariants", "roads", "blocks", "parcels", "buildings")


# --------------------------------------------------------------------------- results

@dataclass
class Scalar:
    """One number describing a layer (a density, a count, a mean)."""

    kind: str
    name: str
    value: float
    unit: str = ""
    label: str = ""


@dataclass
class Distribution:
    """Per-element values of one measure (one per edge, node, block, parcel ...)."""

    kind: str
    name: str
    values: np.ndarray
    unit: str = ""
    label: str = ""


@dataclass
class MetricsResult:
    """Scalars and distributions of one layout, plus notes on how they were obtained."""

    scalars: List[Scalar] = field(default_factory=list)
    distributions: List[Distribution] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)

    def add_scalar(self, kind, name, value, unit="", label=""):
        self.scalars.append(Scalar(kind, name, float(value), unit, label or name))

    def add_distribution(self, kind, name, values, unit="", label=""):
        v = np.asarray(values, dtype=float)
        self.distributions.append(Distribution(kind, name, v[np.isfinite(v)], unit, label or name))

    def scalar(self, kind: str, name: str) -> float:
        for s in self.scalars:
            if s.kind == kind and s.name == name:
                return s.value
        raise KeyError(f"no scalar {kind}/{name}")

    def distribution(self, kind: str, name: str) -> np.ndarray:
        for d in self.distributions:
            if d.kind == kind and d.name == name:
                return d.values
        raise KeyError(f"no distribution {kind}/{name}")

    def has(self, kind: str, name: str) -> bool:
        return any(m.kind == kind and m.name == name for m in self.scalars + self.distributions)

    def extend(self, other: "MetricsResult") -> "MetricsResult":
        self.scalars += other.scalars
        self.distributions += other.distributions
        self.notes += other.notes
        return self


# --------------------------------------------------------------------------- helpers

def _as_array(geoms, what: str, dim: int, notes: Optional[List[str]] = None,
              return_mask: bool = False):
    """Geometries as a flat object array of non-empty geometries of dimension ``dim``.

    A layer with no geometry of that dimension is an :class:`InputError`; missing, empty and
    stray geometries of another dimension (a repaired footprint that collapsed to a line)
    are dropped and counted in ``notes``. With ``return_mask``, also returns which input
    geometries were kept (to filter per-feature values alike).
    """
    if isinstance(geoms, shapely.Geometry):
        geoms = [geoms]
    arr = np.asarray(geoms, dtype=object).ravel()
    if len(arr) == 0:
        raise InputError(f"the {what} layer has no geometries")
    present = ~(shapely.is_missing(arr) | shapely.is_empty(arr))
    if not present.any():
        raise InputError(f"the {what} layer has no geometries")
    dims = np.full(len(arr), -1)
    dims[present] = shapely.get_dimensions(arr[present])
    keep = dims == dim
    if not keep.any():
        want = {1: "lines", 2: "polygons"}[dim]
        got = shapely.GeometryType(shapely.get_type_id(arr[present][0])).name.lower()
        raise InputError(f"the {what} layer must contain {want}, not {got}s")
    if not keep.all() and notes is not None:
        notes.append(f"{what}: {int((~keep).sum())} empty geometries or geometries of another "
                     "dimension ignored.")
    return (arr[keep], keep) if return_mask else arr[keep]


def _area(area, *layers) -> Tuple[Optional[shapely.Geometry], float, str]:
    """Area for densities: (polygon or None, m², description).

    ``area`` is a study polygon (or an array of polygons, united), a number of m², or None
    for the convex hull of the given layers.
    """
    if area is not None:
        if isinstance(area, (int, float, np.integer, np.floating)):
            a = float(area)
            if not a > 0:
                raise InputError("the study area must be positive")
            return None, a, "given area"
        polys = _as_array(area, "study area", 2)
        geom = polys[0] if len(polys) == 1 else shapely.union_all(polys)
        a = float(shapely.area(geom))
        if not a > 0:
            raise InputError("the study area polygon has no area")
        shapely.prepare(geom)
        return geom, a, "study area"
    coords = [shapely.get_coordinates(np.asarray(x, dtype=object)) for x in layers if x is not None]
    hull = shapely.convex_hull(shapely.multipoints(np.vstack(coords))) if coords else None
    a = float(shapely.area(hull)) if hull is not None else 0.0
    if not a > 0:
        raise InputError("the layers span no area (give a study area for the densities)")
    shapely.prepare(hull)
    return hull, a, "convex hull of the input"


#: The settled area of a street network: its streets buffered by SETTLED_OUT and shrunk by
#: SETTLED_IN (m), a closing that fills the gaps between streets up to about 240 m and
#: leaves a 20 m margin, holes filled (the fidelity benchmark's settlement envelope).
SETTLED_OUT, SETTLED_IN = 120.0, 100.0
#: An example whose streets settle less of its density area than this is mostly empty land.
SETTLED_SHARE_LOW = 0.5


def settled_area(lines, within=None, min_part: float = 0.0) -> shapely.Geometry:
    """Where a street network is: its streets closed by :data:`SETTLED_OUT` /
    :data:`SETTLED_IN`, cut to ``within`` (optional), parts under ``min_part`` m² dropped,
    holes filled (fields enclosed by a town's roads belong to it).

    >>> streets = [shapely.LineString([(0, 0), (500, 0)]), shapely.LineString([(0, 150),
    ...            (500, 150)])]
    >>> round(settled_area(streets).area / 1e3)     # 540 m x 190 m, the gap filled
    97
    """
    lines = np.asarray(lines, dtype=object)
    grown = shapely.union_all(shapely.buffer(lines, SETTLED_OUT, quad_segs=4))
    env = shapely.buffer(grown, -SETTLED_IN, quad_segs=4)
    if within is not None:
        env = shapely.intersection(env, within)
    parts = shapely.get_parts(env)
    parts = parts[shapely.area(parts) >= min_part]
    parts = shapely.polygons(shapely.get_exterior_ring(parts))
    if within is not None:
        parts = shapely.get_parts(shapely.intersection(parts, within))
        parts = parts[shapely.area(parts) >= min_part]
    return shapely.make_valid(shapely.union_all(parts))


def clip_lines(lines, area, return_index: bool = False, tolerance: float = ON_EDGE):
    """The parts of ``lines`` inside ``area``, a street along its edge whole: clipped to the
    exact polygon, a line built along the edge (a layout's outline street) lies outside it
    by round-off here and there and loses those parts (one layout's s_l moved by 2 % with a
    10 µm change of its noding). Clipped to the area grown by ``tolerance`` (default
    :data:`ON_EDGE`) instead, with each cut end moved back onto the area's edge (a street
    crossing it ends there). A larger ``tolerance`` keeps a street that runs outside the
    edge by up to that much (splitdomain's outline street rounds the outline's reflex bends
    up to 0.9 m outside it) in one piece. The parts are 2D (the lengths measured are).
    ``return_index``: also the index of the line each part came from.

    >>> area = shapely.box(0, 0, 100, 100)
    >>> along = shapely.LineString([(0, -1e-9), (100, -1e-9)])
    >>> across = shapely.LineString([(50, 50), (50, 150)])
    >>> [round(g.length, 6) for g in clip_lines([along, across], area)]
    [100.0, 50.0]
    >>> [round(g.length, 6) for g in shapely.intersection([along, across], area)]
    [0.0, 50.0]
    """
    lines = np.asarray(lines, dtype=object).ravel()
    grown = shapely.buffer(area, max(tolerance, ON_EDGE), join_style="mitre")
    with np.errstate(invalid="ignore"):
        parts, index = shapely.get_parts(shapely.intersection(lines, grown),
                                         return_index=True)
    parts, inner = shapely.get_parts(parts, return_index=True)   # a collection's members
    index = index[inner]
    single = (shapely.get_type_id(parts) == 1) & ~shapely.is_empty(parts)
    parts, index = parts[single], index[single]
    if not len(parts):
        return (parts, index) if return_index else parts
    xy = shapely.get_coordinates(parts)
    n = shapely.get_num_coordinates(parts)
    ends = np.unique(np.r_[np.cumsum(n) - n, np.cumsum(n) - 1])
    edge = shapely.boundary(area)
    pts = shapely.points(xy[ends])
    # the ends the cut made (on the grown area's edge); a line's own end within the
    # tolerance outside (a junction of a street that rounds a corner outside) stays
    out = ~shapely.intersects(area, pts) & shapely.dwithin(shapely.boundary(grown), pts, 1e-6)
    if out.any():
        xy[ends[out]] = shapely.get_coordinates(shapely.line_interpolate_point(
            edge, shapely.line_locate_point(edge, pts[out])))
    raw = parts
    parts = shapely.linestrings(xy, indices=np.repeat(np.arange(len(parts)), n))
    if tolerance > ON_EDGE and out.any():
        # a street across the edge ends where it crosses it, not where the grown area cut
        # it moved sideways onto the edge (by up to the tolerance over the tangent of its
        # angle with the edge)
        last = np.cumsum(n) - 1
        cut = set(ends[out].tolist())
        for k in np.unique(np.searchsorted(last, ends[out])):
            parts[k] = _back_to_edge(raw[k], parts[k], last[k] - n[k] + 1 in cut,
                                     last[k] in cut, edge, lines[index[k]])
    return (parts, index) if return_index else parts


def _back_to_edge(raw, moved, start_cut: bool, end_cut: bool, edge, line):
    """A part of ``line`` (``raw``: as cut from the grown area) whose cut ends are taken back
    along the line to where it crosses the area's ``edge``, the crossing nearest each such
    end; ``moved`` (its cut ends moved onto the edge) where the line does not cross it."""
    from shapely.ops import substring

    if shapely.get_type_id(line) != 1:
        return moved
    crossing = shapely.get_parts(shapely.intersection(line, edge))
    crossing = crossing[shapely.get_type_id(crossing) == 0]
    s0 = shapely.line_locate_point(line, shapely.get_point(raw, 0))
    s1 = shapely.line_locate_point(line, shapely.get_point(raw, -1))
    lo, hi = min(s0, s1), max(s0, s1)
    at = shapely.line_locate_point(line, crossing)
    at = at[(at >= lo - 1e-9) & (at <= hi + 1e-9)]
    if not len(at):
        return moved
    forward = s0 <= s1
    a = at.min() if (start_cut if forward else end_cut) else lo
    b = at.max() if (end_cut if forward else start_cut) else hi
    if b - a <= 1e-9:
        return moved
    piece = shapely.force_2d(substring(line, a, b))
    return piece if forward else shapely.reverse(piece)


def _inside(area_geom, geoms) -> np.ndarray:
    """Which elements count for a density: those whose point on surface lies in the area."""
    if area_geom is None:
        return np.ones(len(geoms), dtype=bool)
    return shapely.intersects(area_geom, shapely.point_on_surface(geoms))


def corner_angles(polygons, straight: float = STRAIGHT_ANGLE) -> Tuple[np.ndarray, np.ndarray]:
    """Corner angles of polygon outlines, in degrees, with the index of their polygon
    (:func:`corners` without the points)."""
    _, angle, owner = corners(polygons, straight)
    return angle, owner


def corners(polygons, straight: float = STRAIGHT_ANGLE
            ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners of polygon outlines: their points, their angles in degrees and the index of
    their polygon.

    The angle at a vertex is the unsigned angle between its two edges, in [0, 180]: a
    reflex corner of 270 degrees counts as 90, so that an L-shaped parcel has only right
    angles. Vertices with an angle above ``straight`` are not corners (digitising
    noise on a straight side) and are left out. Only exterior rings count; every part of a
    multipolygon counts.

    Parameters
    ----------
    polygons : array of Polygon / MultiPolygon
    straight : float
        Angles above this (degrees) are straight continuations, not corners.

    Returns
    -------
    points : (n, 2) float array
    angles : float array
    owner : int array, index into ``polygons`` of each corner
    """
    parts, owner = shapely.get_parts(np.asarray(polygons, dtype=object), return_index=True)
    # vertices within a centimetre of the previous one are digitising noise, not corners
    rings = shapely.remove_repeated_points(shapely.get_exterior_ring(parts), 0.01)
    coords, ring = shapely.get_coordinates(rings, return_index=True)
    counts = np.bincount(ring, minlength=len(rings))
    # drop each ring's closing vertex; rings of fewer than 3 distinct points have no corners
    last = np.cumsum(counts) - 1
    keep = np.ones(len(coords), dtype=bool)
    keep[last[counts > 0]] = False
    coords, ring = coords[keep], ring[keep]
    n = np.bincount(ring, minlength=len(rings))
    ok = n[ring] >= 3
    coords, ring = coords[ok], ring[ok]
    if len(coords) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
    n = np.bincount(ring, minlength=len(rings))
    start = np.r_[0, np.cumsum(n)[:-1]]
    pos = np.arange(len(coords)) - start[ring]
    prev = start[ring] + (pos - 1) % n[ring]
    nxt = start[ring] + (pos + 1) % n[ring]
    a = coords[prev] - coords
    b = coords[nxt] - coords
    cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    corner = angle <= straight
    return coords[corner], angle[corner], owner[ring[corner]]


# --------------------------------------------------------------------------- roads

def road_graph(lines, snap_tolerance: float = 0.5, z_layer=None,
               progress: Optional[Progress] = None) -> RoadGraph:
    """The street graph the road metrics are measured on.

    Lines are noded at crossings (per vertical layer ``z_layer`` when given, so bridges do
    not make intersections), nodes closer than ``snap_tolerance`` merged and chains through
    degree-2 nodes merged (OSM splits ways anywhere), but no dangle is pruned: a layout's own
    dead ends are part of what is measured.
    """
    lines, kept = _as_array(lines, "roads", 1, return_mask=True)
    if z_layer is not None:
        z_layer = np.asarray(z_layer)
        if len(z_layer) != len(kept):
            raise InputError(f"{len(z_layer)} vertical layers for {len(kept)} road lines")
        z_layer = z_layer[kept]
    return measured_graph(lines, snap_tolerance, z_layer, progress)


def street_bearings(lines, step: float = 10.0) -> Tuple[np.ndarray, np.ndarray]:
    """Compass bearings of the straight pieces of street lines, with the piece lengths.

    Lines are cut into pieces of at most ``step`` metres, so that the bearings sample the
    streets by length: a curve counts with each of its directions, and an L-shaped street
    (a grid corner, whose degree-2 node the graph merges) counts as two directions, not as
    its diagonal chord.

    Returns
    -------
    bearings : degrees clockwise from grid north, in [0, 360)
    lengths : length (m) of each piece
    """
    lines = shapely.segmentize(np.asarray(lines, dtype=object), step)
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    same = idx[1:] == idx[:-1]
    d = (coords[1:] - coords[:-1])[same]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 0
    d, length = d[keep], length[keep]
    return np.degrees(np.arctan2(d[:, 0], d[:, 1])) % 360.0, length


def orientation_entropy(bearings, weights=None, num_bins: int = 36) -> float:
    """Shannon entropy (nats) of street bearings, counted in both directions.

    Bins are centred on 0, 10, 20 ... degrees (OSMnx splits 2 x num_bins bins and merges
    neighbours), so a north-south / east-west grid falls into exactly 4 bins:
    H = ln 4 = 1.386; uniformly spread bearings give ln 36 = 3.584. With the pieces of
    :func:`street_bearings` weighted by length this is OSMnx's
    ``orientation_entropy(G, weight="length")`` on the unsimplified graph.

    References
    ----------
    Boeing 2019, eq. 1; ``osmnx.bearing.orientation_entropy``.
    """
    b = np.asarray(bearings, dtype=float)
    w = np.ones(len(b)) if weights is None else np.asarray(weights, dtype=float)
    ok = np.isfinite(b) & np.isfinite(w)
    b, w = b[ok], w[ok]
    if len(b) == 0 or w.sum() <= 0:
        return float("nan")
    both = np.concatenate([b % 360.0, (b + 180.0) % 360.0])
    width = 360.0 / num_bins
    bins = np.floor(((both + width / 2) % 360.0) / width).astype(np.int64) % num_bins
    p = np.bincount(bins, weights=np.concatenate([w, w]), minlength=num_bins)
    p = p[p > 0] / p.sum()
    return float(-(p * np.log(p)).sum())


def intersection_angles(graph: RoadGraph, bearing_length: float = 10.0) -> np.ndarray:
    """Angles (degrees) between consecutive streets around each node of degree >= 3.

    The direction of a street leaving a node is that of its first ``bearing_length``
    metres, so that curves further away do not count. Around a node of degree k the k
    angles sum to 360: a cross gives 4 x 90, a T junction 90, 90 and 180.
    """
    m = graph.n_edges
    length = graph.length
    d = np.minimum(bearing_length, length)
    near_u = shapely.get_coordinates(shapely.line_interpolate_point(graph.geometry, d))
    near_v = shapely.get_coordinates(shapely.line_interpolate_point(graph.geometry, length - d))
    node = np.concatenate([graph.u, graph.v])
    vec = np.vstack([near_u - graph.nodes[graph.u], near_v - graph.nodes[graph.v]])
    deg = graph.degree
    sel = (deg[node] >= 3) & (np.hypot(vec[:, 0], vec[:, 1]) > 0)
    if not sel.any() or m == 0:
        return np.zeros(0)
    node, vec = node[sel], vec[sel]
    az = np.degrees(np.arctan2(vec[:, 0], vec[:, 1])) % 360.0
    order = np.lexsort((az, node))
    node, az = node[order], az[order]
    same = np.r_[node[1:] == node[:-1], False]
    diff = np.r_[np.diff(az), 0.0]
    # the last street of each node closes the circle back to its first
    first = np.r_[True, node[1:] != node[:-1]]
    first_az = az[first][np.cumsum(first) - 1]
    closing = first_az + 360.0 - az
    angles = np.where(same, diff, closing)
    # a node whose streets all leave in one direction counts one 360: drop it
    return angles[angles < 360.0 - 1e-9]


def road_metrics(roads, area=None, snap_tolerance: float = 0.5, bearing_length: float = 10.0,
                 edge_distance: float = 0.0,
                 progress: Optional[Progress] = None) -> MetricsResult:
    """Street network measures of docs/ARCHITECTURE.md and Yang 2013's street metrics.

    Parameters
    ----------
    roads : array of LineString (metric CRS) or a :class:`RoadGraph`
    area : polygon(s) or float (m²), optional
        Area for the densities; default: the convex hull of the roads.
    snap_tolerance : float
        Nodes closer than this (m) are one node (see :func:`road_graph`).
    bearing_length : float
        Length (m) of the start of each street that gives its direction at a node, and of
        the pieces whose bearings sample the streets (:func:`street_bearings`).
    edge_distance : float
        Nodes closer than this (m) to the boundary of the study area do not count in the
        densities and shares: where a network was clipped to the area, its streets end on
        the boundary without being dead ends. 0 (default) counts every node inside the area
        or on its boundary (within a micrometre), as a plain count of the clipped network
        does. Needs a study polygon (or the default hull).

    Returns
    -------
    MetricsResult
        kind ``roads``; distributions ``segment_length`` (m, per edge between nodes of
        degree != 2), ``node_degree``, ``intersection_angle`` (degrees), ``street_bearing``
        (degrees, folded into [0, 180), one per piece of ``bearing_length`` m, so weighted by
        length); scalars ``edges``, ``nodes``, ``dead_ends_per_km2`` (s_d, degree 1),
        ``intersections_per_km2`` (s_i, degree >= 3), ``dead_end_share``,
        ``degree3_share``, ``degree4_share`` (degree 1, 3 and >= 4 among the counted nodes
        of degree != 2), ``street_length_km_per_km2`` (s_l),
        ``orientation_entropy`` (nats, Boeing 2019, length-weighted), ``orientation_order``
        (phi = 1 - ((H - ln 4) / (ln 36 - ln 4))^2: 1 for a grid, 0 for uniform bearings).

    References
    ----------
    Yang et al. 2013, sec. 7 (s_l, s_i, s_d); Boeing 2019 (orientation entropy and order).

    Examples
    --------
    >>> import shapely
    >>> grid = [shapely.LineString([(0, y), (200, y)]) for y in (0, 100, 200)] + \\
    ...        [shapely.LineString([(x, 0), (x, 200)]) for x in (0, 100, 200)]
    >>> r = road_metrics(grid)
    >>> round(r.scalar("roads", "orientation_entropy"), 3)
    1.386
    """
    progress = ensure(progress)
    if isinstance(roads, RoadGraph):
        graph, lines = roads, roads.geometry
    else:
        lines = _as_array(roads, "roads", 1)
        graph = road_graph(lines, snap_tolerance, progress=progress.sub(0.0, 0.7))
    area_geom, area_m2, source = _area(area, lines)
    km2 = area_m2 / M2_PER_KM2
    deg = graph.degree
    length = graph.length
    if not (np.isfinite(edge_distance) and edge_distance >= 0):
        raise InputError("the edge distance must be a non-negative number")
    # densities count the network inside the area (all of it for the default hull); nodes on
    # the boundary count unless edge_distance says they are clip ends
    node_in = np.ones(len(graph.nodes), dtype=bool)
    if area_geom is not None:
        pts = shapely.points(graph.nodes)
        node_in = shapely.dwithin(area_geom, pts, ON_EDGE)
        if edge_distance > 0:
            node_in &= ~shapely.dwithin(shapely.boundary(area_geom), pts, edge_distance)
    length_in = length.copy()
    if area_geom is not None:
        cut = np.flatnonzero(~shapely.within(graph.geometry, area_geom))
        # a street within edge_distance of the area is where the network was cut: inside
        parts, index = clip_lines(graph.geometry[cut], area_geom, return_index=True,
                                  tolerance=edge_distance)
        length_in[cut] = np.bincount(index, shapely.length(parts), minlength=len(cut))
    bearing, piece_length = street_bearings(graph.geometry, bearing_length)
    res = MetricsResult()
    # a bridge kept apart from its approach (its own vertical layer) is part of the street:
    # the joint is no node, and the segment runs on through it
    z_at = np.full((len(graph.nodes), 2), [np.inf, -np.inf])
    np.minimum.at(z_at[:, 0], np.r_[graph.u, graph.v], np.r_[graph.z_layer, graph.z_layer])
    np.maximum.at(z_at[:, 1], np.r_[graph.u, graph.v], np.r_[graph.z_layer, graph.z_layer])
    node = ~((deg == 2) & (z_at[:, 0] != z_at[:, 1]))
    chain = degree2_chains(graph.u, graph.v, len(graph.nodes))
    segment = length if chain is None else np.bincount(chain, weights=length)
    res.add_distribution("roads", "segment_length", segment, "m", "Segment length")
    res.add_distribution("roads", "node_degree", deg[node], "", "Node degree")
    res.add_distribution("roads", "intersection_angle", intersection_angles(graph, bearing_length),
                         "°", "Intersection angle")
    res.add_distribution("roads", "street_bearing", bearing % 180.0, "°", "Street bearing")
    progress.step(0.9)
    h = orientation_entropy(bearing, piece_length)
    h_grid, h_max = np.log(4.0), np.log(36.0)
    res.add_scalar("roads", "edges", len(segment), "", "Street segments")
    res.add_scalar("roads", "nodes", int(node.sum()), "", "Nodes")
    res.add_scalar("roads", "street_length_km_per_km2", length_in.sum() / 1000.0 / km2,
                   "km/km²", "Street length per km² (s_l)")
    res.add_scalar("roads", "intersections_per_km2", ((deg >= 3) & node_in).sum() / km2, "1/km²",
                   "Intersections per km² (s_i)")
    res.add_scalar("roads", "dead_ends_per_km2", ((deg == 1) & node_in).sum() / km2, "1/km²",
                   "Dead ends per km² (s_d)")
    ends = node_in & (deg != 2)
    n_ends = max(int(ends.sum()), 1)
    res.add_scalar("roads", "dead_end_share", ((deg == 1) & ends).sum() / n_ends, "",
                   "Share of dead ends (degree 1)")
    res.add_scalar("roads", "degree3_share", ((deg == 3) & ends).sum() / n_ends, "",
                   "Share of 3-way junctions")
    res.add_scalar("roads", "degree4_share", ((deg >= 4) & ends).sum() / n_ends, "",
                   "Share of 4-way (and more) junctions")
    res.add_scalar("roads", "orientation_entropy", h, "nats", "Orientation entropy")
    res.add_scalar("roads", "orientation_order", 1.0 - ((h - h_grid) / (h_max - h_grid)) ** 2, "",
                   "Orientation order φ")
    if area is None:
        res.notes.append(f"Road densities are per km² of the {source} ({km2:.3f} km²).")
    progress.step(1.0)
    return res


# --------------------------------------------------------------------------- blocks

def block_faces(roads, min_area: float = _blocks.MIN_BLOCK_AREA,
                min_width: float = _blocks.MIN_BLOCK_WIDTH,
                snap_tolerance: float = 0.5, return_counts: bool = False):
    """City blocks as the faces of the road graph, as ``extractblocks`` makes them.

    Delegates to :func:`plugin.network.blocks.block_faces` (dead ends stay inside their block;
    faces under ``min_area`` m² or thinner than ``min_width`` m are slivers between dual
    carriageways and are dropped), so that a layout is measured on the same blocks the
    toolbox extracts. ``roads`` is an array of lines or a :class:`RoadGraph`; returns an
    empty array when no street closes a face. With ``return_counts``, also the counts of
    :func:`plugin.network.blocks.block_faces` (``n_faces``, ``n_small``, ``n_thin``).
    """
    graph = roads if isinstance(roads, RoadGraph) else road_graph(roads, snap_tolerance)
    try:
        faces, counts = _blocks.block_faces(graph.geometry, min_area, min_width)
    except InputError:  # the roads close no face: no blocks, not an error here
        faces, counts = np.zeros(0, dtype=object), dict(n_faces=0, n_small=0, n_thin=0)
    return (faces, counts) if return_counts else faces


def block_metrics(blocks, area=None) -> MetricsResult:
    """Block measures: thesis ch. 4.2 distributions and Yang 2013's block metrics.

    Parameters
    ----------
    blocks : array of Polygon / MultiPolygon (metric CRS)
    area : polygon(s) or float (m²), optional; default: the convex hull of the blocks.

    Returns
    -------
    MetricsResult
        kind ``blocks``; distributions ``area`` (m²), ``compactness`` (area / area of the
        minimum rotated rectangle, 1 for a rectangle), ``aspect_ratio`` (short / long side
        of that rectangle, in (0, 1], the thesis's definition), ``boundary_length`` (m);
        scalars ``count``, ``blocks_per_km2`` (b_n), ``land_share`` (% of the area in the
        blocks b_n counts: how much of it streets close), ``b_max``, ``b_avg``, ``b_min`` (m).

    References
    ----------
    Hartmann thesis ch. 4.2 (area, compactness, aspect ratio); Yang et al. 2013, sec. 7
    (b_n, b_max, b_avg, b_min).
    """
    res = MetricsResult()
    blocks = _as_array(blocks, "blocks", 2, res.notes)
    area_geom, area_m2, _ = _area(area, blocks)
    shape = _blocks.shape_metrics(blocks)
    a = shape["area_m2"].to_numpy()
    compact = shape["compactness"].to_numpy()
    aspect = shape["aspect_ratio"].to_numpy()
    boundary = shape["perimeter_m"].to_numpy()
    res.add_distribution("blocks", "area", a, "m²", "Block area")
    res.add_distribution("blocks", "compactness", compact, "", "Block compactness")
    res.add_distribution("blocks", "aspect_ratio", aspect, "", "Block aspect ratio")
    res.add_distribution("blocks", "boundary_length", boundary, "m", "Block boundary length")
    res.add_scalar("blocks", "count", len(blocks), "", "Blocks")
    km2 = area_m2 / M2_PER_KM2
    inside = _inside(area_geom, blocks)
    res.add_scalar("blocks", "blocks_per_km2", inside.sum() / km2, "1/km²",
                   "Blocks per km² (b_n)")
    res.add_scalar("blocks", "land_share", 100.0 * a[inside].sum() / area_m2, "%",
                   "Share of the area in blocks")
    res.add_scalar("blocks", "b_max", boundary.max(), "m", "Max. block boundary (b_max)")
    res.add_scalar("blocks", "b_avg", boundary.mean(), "m", "Mean block boundary (b_avg)")
    res.add_scalar("blocks", "b_min", boundary.min(), "m", "Min. block boundary (b_min)")
    return res


# --------------------------------------------------------------------------- parcels

_RESIDENTIAL = {"r", "residential", "housing", "house", "houses", "apartments", "detached",
                "semidetached_house", "terrace", "dormitory", "bungalow"}
_PARK = {"p", "park", "parks", "green", "grass", "garden", "recreation_ground", "playground",
         "forest", "wood", "meadow", "village_green", "cemetery", "nature_reserve"}
_STREET = {"s", "street", "streets", "road", "roads", "highway"}


def landuse_category(values) -> np.ndarray:
    """Map land-use labels onto Yang's classes: 'r' residential, 'p' park, 's' street, 'o' other.

    Labels are matched case-insensitively (``residential`` / ``r``, ``park`` / ``green`` /
    ``grass`` / ``p`` ..., ``street`` / ``road`` / ``s``); anything else, including empty
    values, is 'o' (other, e.g. commercial), as in Yang 2013.
    """
    out = []
    for v in values:
        t = "" if v is None else str(v).strip().lower()
        out.append("r" if t in _RESIDENTIAL else "p" if t in _PARK else
                   "s" if t in _STREET else "o")
    return np.asarray(out, dtype=object)


def parcel_metrics(parcels, area=None, landuse=None,
                   straight: float = STRAIGHT_ANGLE) -> MetricsResult:
    """Yang 2013 parcel metrics (Table 1) and per-parcel distributions.

    Parameters
    ----------
    parcels : array of Polygon / MultiPolygon (metric CRS)
    area : polygon(s) or float (m²), optional; default: the convex hull of the parcels.
    landuse : sequence of labels per parcel, optional (see :func:`landuse_category`)
    straight : float
        Vertices with an angle above this are not corners (see :func:`corner_angles`).

    Returns
    -------
    MetricsResult
        kind ``parcels``; distributions ``area`` (m²), ``p_angle`` (per parcel, the mean of
        |corner angle - 90°|), ``p_area`` (per parcel, area of the minimum bounding
        rectangle / parcel area, >= 1); scalars ``count``, ``p_n_per_km2``, ``p_angle``
        (mean over all corners of all parcels, degrees), ``p_area`` (mean over parcels),
        ``undesirable_count`` and ``undesirable_share`` (parcels with p_angle > 15 or
        p_area > 1.2) and, with ``landuse``, ``l_s``, ``l_r``, ``l_p``, ``l_o`` in % of the
        area: l_r / l_p / l_o are the parcel areas of each class, l_s is the rest of the
        area (in a subdivision, the land between parcels is streets) plus parcels labelled
        as streets.

    References
    ----------
    Yang et al. 2013, sec. 7 "parcel metrics" and "land use metrics", Table 1, Fig. 12.

    Examples
    --------
    >>> import shapely
    >>> r = parcel_metrics([shapely.box(0, 0, 30, 18)])
    >>> r.scalar("parcels", "p_angle"), r.scalar("parcels", "p_area")
    (0.0, 1.0)
    """
    res = MetricsResult()
    parcels, kept = _as_array(parcels, "parcels", 2, res.notes, return_mask=True)
    if landuse is not None:
        landuse = np.asarray(landuse, dtype=object)
        if len(landuse) == len(kept):
            landuse = landuse[kept]
        elif len(landuse) != len(parcels):
            raise InputError(f"{len(landuse)} land-use values for {len(kept)} parcels")
    n = len(parcels)
    area_geom, area_m2, _ = _area(area, parcels)
    a = shapely.area(parcels)
    long, short, _ = minimum_rectangles(parcels)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_area = np.where(a > 0, long * short / a, np.nan)
    angles, owner = corner_angles(parcels, straight)
    dev = np.abs(angles - 90.0)
    n_corners = np.bincount(owner, minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_angle = np.bincount(owner, weights=dev, minlength=n) / n_corners
    bad = (np.nan_to_num(p_angle) > UNDESIRABLE_ANGLE) | (np.nan_to_num(p_area) > UNDESIRABLE_AREA)
    res.add_distribution("parcels", "area", a, "m²", "Parcel area")
    res.add_distribution("parcels", "p_angle", p_angle, "°", "Parcel angle deviation p_angle")
    res.add_distribution("parcels", "p_area", p_area, "", "Parcel area distortion p_area")
    res.add_scalar("parcels", "count", n, "", "Parcels")
    km2 = area_m2 / M2_PER_KM2
    res.add_scalar("parcels", "p_n_per_km2", _inside(area_geom, parcels).sum() / km2, "1/km²",
                   "Parcels per km² (p_n)")
    res.add_scalar("parcels", "p_angle", dev.mean() if len(dev) else np.nan, "°",
                   "Mean corner deviation from 90° (p_angle)")
    res.add_scalar("parcels", "p_area", np.nanmean(p_area), "",
                   "Mean MBR area / parcel area (p_area)")
    res.add_scalar("parcels", "undesirable_count", bad.sum(), "",
                   "Undesirable parcels (p_angle > 15° or p_area > 1.2)")
    res.add_scalar("parcels", "undesirable_share", 100.0 * bad.mean(), "%",
                   "Share of undesirable parcels")
    if landuse is not None:
        cat = landuse_category(landuse)
        # land inside the area only, so that the four shares add up to 100 %
        a_in = a.copy()
        if area_geom is not None:
            cut = ~shapely.within(parcels, area_geom)
            with np.errstate(invalid="ignore"):
                a_in[cut] = shapely.area(shapely.intersection(parcels[cut], area_geom))
        share = {c: 100.0 * a_in[cat == c].sum() / area_m2 for c in ("r", "p", "o", "s")}
        rest = max(0.0, 100.0 - share["r"] - share["p"] - share["o"] - share["s"])
        res.add_scalar("parcels", "l_s", share["s"] + rest, "%", "Land use: streets (l_s)")
        res.add_scalar("parcels", "l_r", share["r"], "%", "Land use: residential (l_r)")
        res.add_scalar("parcels", "l_p", share["p"], "%", "Land use: parks (l_p)")
        res.add_scalar("parcels", "l_o", share["o"], "%", "Land use: other (l_o)")
    return res


# --------------------------------------------------------------------------- footprints

def _pair_intersection_area(a: np.ndarray, b: np.ndarray, ia: np.ndarray, ib: np.ndarray):
    if len(ia) == 0:
        return np.zeros(0)
    with np.errstate(invalid="ignore"):
        return shapely.area(shapely.intersection(a[ia], b[ib]))


def footprint_metrics(footprints, blocks=None, roads=None, road_half_width: float = 3.0,
                      area=None) -> MetricsResult:
    """Building footprint measures: coverage, overlaps, footprints outside blocks, setback.

    Parameters
    ----------
    footprints : array of Polygon / MultiPolygon (metric CRS)
    blocks : array of polygons, optional
        Needed for coverage and footprints outside blocks.
    roads : array of lines, optional
        Road centrelines; the road surface is the centrelines buffered by
        ``road_half_width`` on each side (round caps, so junctions are covered).
    road_half_width : float
        Half the road width (m).
    area : polygon(s) or float (m²), optional; default: the convex hull of the footprints.

    Returns
    -------
    MetricsResult
        kind ``buildings``; distributions ``area`` (m²), ``coverage`` (per block, footprint
        area inside the block / block area; overlapping footprints count twice),
        ``setback`` (distance to the nearest road centreline minus ``road_half_width``, m;
        negative when the footprint reaches into the road surface); scalars ``count``, ``per_km2``, ``overlap_area`` (m², summed over
        pairs of footprints), ``overlapping_pairs``, ``coverage`` (total footprint area in
        blocks / total block area), ``outside_blocks`` (footprints not inside one block, up
        to 0.1 % of their area), ``road_overlap_area`` (m²), ``road_overlap_count``.
        docs/ARCHITECTURE.md: overlaps and footprints outside blocks must be 0 in a synthesis.
    """
    res = MetricsResult()
    fp = _as_array(footprints, "buildings", 2, res.notes)
    area_geom, area_m2, _ = _area(area, fp)
    fa = shapely.area(fp)
    res.add_distribution("buildings", "area", fa, "m²", "Footprint area")
    res.add_scalar("buildings", "count", len(fp), "", "Footprints")
    km2 = area_m2 / M2_PER_KM2
    res.add_scalar("buildings", "per_km2", _inside(area_geom, fp).sum() / km2, "1/km²",
                   "Footprints per km²")

    tree = shapely.STRtree(fp)
    i, j = tree.query(fp, predicate="intersects")
    upper = i < j
    ov = _pair_intersection_area(fp, fp, i[upper], j[upper])
    res.add_scalar("buildings", "overlap_area", ov.sum(), "m²", "Overlap between footprints")
    res.add_scalar("buildings", "overlapping_pairs", (ov > OVERLAP_EPS).sum(), "",
                   "Pairs of overlapping footprints")

    if blocks is not None:
        blocks = _as_array(blocks, "blocks", 2, res.notes)
        ba = shapely.area(blocks)
        fi, bi = shapely.STRtree(blocks).query(fp, predicate="intersects")
        inter = _pair_intersection_area(fp, blocks, fi, bi)
        per_block = np.bincount(bi, weights=inter, minlength=len(blocks))
        with np.errstate(divide="ignore", invalid="ignore"):
            res.add_distribution("buildings", "coverage", per_block / ba, "", "Block coverage")
        res.add_scalar("buildings", "coverage", per_block.sum() / ba.sum(), "",
                       "Coverage (footprint / block area)")
        best = np.zeros(len(fp))
        np.maximum.at(best, fi, inter)
        outside = best < fa * (1.0 - INSIDE_TOLERANCE)
        res.add_scalar("buildings", "outside_blocks", outside.sum(), "",
                       "Footprints not inside one block")

    if roads is not None:
        roads = _as_array(roads, "roads", 1, res.notes)
        surface = shapely.buffer(roads, road_half_width, quad_segs=4)
        fi, ri = shapely.STRtree(surface).query(fp, predicate="intersects")
        hit = _pair_intersection_area(fp, surface, fi, ri) > OVERLAP_EPS
        touched = np.unique(fi[hit])
        # unions on both sides: buffers overlap at every junction, footprints may overlap
        road_area = 0.0
        if len(touched):
            union = shapely.union_all(surface[np.unique(ri[hit])])
            road_area = float(shapely.area(shapely.intersection(
                shapely.union_all(fp[touched]), union)))
        res.add_scalar("buildings", "road_overlap_area", road_area, "m²",
                       "Overlap with the road surface")
        res.add_scalar("buildings", "road_overlap_count", len(touched), "",
                       "Footprints overlapping the road surface")
        _, dist = shapely.STRtree(roads).query_nearest(fp, return_distance=True, all_matches=False)
        res.add_distribution("buildings", "setback", dist - road_half_width, "m",
                             "Setback from the road edge")
    return res


# --------------------------------------------------------------------------- invariants

def network_invariants(roads, z_layer=None, given_roads=None, given_class=None,
                       given_z_layer=None, area=None, edge_distance: float = 0.0,
                       progress: Optional[Progress] = None) -> MetricsResult:
    """The network invariants of a layout's roads as scalars of kind ``invariants``.

    Runs :func:`plugin.network.invariants.check_network` on the roads that are not copies of
    ``given_roads`` (:func:`plugin.network.invariants.new_streets`), against the given
    roads; one scalar per check of :data:`plugin.network.invariants.CHECKS` that runs
    without a target (a count, or the dead-end share) plus ``violations``, the total of the
    violation counts without the dead-end share, which needs an example (:func:`compare`
    gives its relative difference).
    """
    res = MetricsResult()
    roads = np.asarray(roads, dtype=object)
    layer = None if z_layer is None else np.asarray(z_layer)
    given = None
    if given_roads is not None:
        given = _as_array(given_roads, "given roads", 1)
        new = _invariants.new_streets(roads, given)
        res.notes.append(f"Invariants: {int(new.sum())} of {len(roads)} road lines are not on "
                         f"the {len(given)} given roads and are checked against them.")
        roads = roads[new]
        layer = None if layer is None else layer[new]
    area_geom = area if isinstance(area, shapely.Geometry) else None
    check = _invariants.check_network(roads, given, given_class, area_geom,
                                      given_layer=given_z_layer, synthesised_layer=layer,
                                      edge_distance=edge_distance, progress=progress)
    counts = check.counts()
    for name, label, _ in _invariants.CHECKS:
        if name in counts:  # a layout measured in a study area has no target to leave
            res.add_scalar("invariants", name, counts[name], "", label)
    v = check.violations()
    v.pop("dead_end_share")
    res.add_scalar("invariants", "violations", sum(v.values()), "",
                   "Violations (all checks but the dead-end share)")
    res.notes.append(f"Invariants: {check.summary()}")
    return res


# --------------------------------------------------------------------------- top level

def _classed_lines(roads, z_layer, road_class, notes):
    """Leave out the lines without a road class in a layer whose other lines have one: in an
    OSM 'lines' layer they are rivers, railways, power lines and boundaries, not streets
    (Liechtenstein's country border made the study area 1,220 km² instead of 251). A layer
    without any class keeps every line (returns ``road_class`` None)."""
    none = np.array([c is None or (isinstance(c, float) and c != c) or not str(c).strip()
                     for c in road_class], dtype=bool)
    if none.all():
        return roads, z_layer, None
    if none.any():
        notes.append(f"Roads: {counted(none.sum(), 'line')} without a road class left out "
                     "(not streets: in an OpenStreetMap 'lines' layer, rivers, railways, "
                     "power lines, boundaries ...).")
        keep = ~none
        roads, road_class = roads[keep], road_class[keep]
        z_layer = None if z_layer is None else z_layer[keep]
    return roads, z_layer, road_class


def compute_layout_metrics(roads=None, blocks=None, parcels=None, buildings=None, area=None,
                           landuse=None, road_z_layer=None, road_half_width: float = 3.0,
                           snap_tolerance: float = 0.5, bearing_length: float = 10.0,
                           min_block_area: float = _blocks.MIN_BLOCK_AREA,
                           min_block_width: float = _blocks.MIN_BLOCK_WIDTH,
                           road_class=None, drivable_only: bool = False,
                           edge_distance: float = 0.0, given_roads=None, given_class=None,
                           given_z_layer=None,
                           progress: Optional[Progress] = None) -> MetricsResult:
    """All measures of one layout, from whichever layers are given.

    Parameters
    ----------
    roads : array of lines, optional
    blocks : array of polygons, optional
        When missing and roads are given, blocks are the faces of the road graph
        (:func:`block_faces`).
    parcels, buildings : arrays of polygons, optional
    area : polygon(s) or float (m²), optional
        Study area for all densities; default: the convex hull of all given layers, so that
        every density of one layout is per the same km². Densities count what lies inside
        a study polygon: street length clipped to it, nodes in it, blocks, parcels and
        footprints whose point on surface is in it (distributions keep every element).
    landuse : labels per parcel, optional (land-use shares, :func:`parcel_metrics`)
    road_z_layer : int per road line, optional
        OSM vertical layer: roads of different layers cross without an intersection.
    road_half_width : float
        Half the road width (m) for the road surface of the footprint overlap test.
    snap_tolerance, bearing_length : float
        See :func:`road_metrics`.
    min_block_area, min_block_width : float
        Road-graph faces smaller (m²) or thinner (m) than this are slivers, not blocks
        (:func:`block_faces`); the notes count them. 0 and 0 keep every face, as a plain
        ``shapely.polygonize`` of the noded roads does; the defaults (400 m², 8 m) drop the
        traffic islands and dual-carriageway strips that ``extractblocks`` drops.
    road_class : OSM ``highway`` value per road line, optional
    drivable_only : bool
        Keep only roads whose class is in :data:`street_graph.DRIVABLE_CLASSES` or is one
        this plugin's synthesis writes (:data:`street_graph.SYNTHESISED_CLASSES`) (no
        footways, paths, service roads, tracks); needs ``road_class``. Default: every line
        counts (a synthesis has no class); the notes say how many non-drivable lines count.
        Either way, lines without a class where others have one are not streets (an OSM
        layer's rivers, railways, boundaries) and are left out.
    edge_distance : float
        Nodes this close (m) to the study-area boundary are clip ends, not dead ends (see
        :func:`road_metrics`); default 0 counts them like any node.
    given_roads : array of lines, optional
        The roads the layout was given (arterials, existing roads): the network invariants
        (:func:`plugin.network.invariants.check_network`) check the layout's roads that are
        not copies of them against them. Without given roads, the layout's roads are checked
        on their own (crossings without junctions, connected components).
    given_class, given_z_layer : OSM class and vertical layer per given road, optional
    progress : Progress, optional

    Returns
    -------
    MetricsResult
        kind ``layout`` scalar ``area_km2`` plus the results of :func:`road_metrics`,
        :func:`block_metrics`, :func:`parcel_metrics` and :func:`footprint_metrics`, and with
        roads the scalars of kind ``invariants``: one per check of
        :data:`plugin.network.invariants.CHECKS` but ``outside_target`` (a study area is no
        target) plus ``violations`` (their total; the
        dead-end share is compared with an example by :func:`compare`).

    Raises
    ------
    InputError
        When no layer is given, a layer is empty or of the wrong geometry type, or a
        parameter is absurd.
    """
    progress = ensure(progress)
    if all(x is None for x in (roads, blocks, parcels, buildings)):
        raise InputError("no layer given: pass at least one of roads, blocks, parcels or "
                         "buildings")
    if not (road_half_width >= 0 and np.isfinite(road_half_width)):
        raise InputError("the road half-width must be a non-negative number")
    if landuse is not None and parcels is None:
        raise InputError("land-use values need a parcel layer")
    res = MetricsResult()
    if roads is not None:
        n_lines = len(np.asarray(roads, dtype=object).ravel()) \
            if not isinstance(roads, shapely.Geometry) else 1
        for name, values in (("vertical layers", road_z_layer), ("road classes", road_class)):
            if values is not None and len(values) != n_lines:
                raise InputError(f"{len(values)} {name} for {n_lines} road lines")
        roads, kept = _as_array(roads, "roads", 1, res.notes, return_mask=True)
        if road_z_layer is not None:
            road_z_layer = np.asarray(road_z_layer)[kept]
        if road_class is not None:
            road_class = np.asarray(road_class, dtype=object)[kept]
            roads, road_z_layer, road_class = _classed_lines(roads, road_z_layer, road_class,
                                                             res.notes)
        if road_class is not None:
            drivable = np.isin(np.asarray([str(c) for c in road_class], dtype=object),
                               DRIVABLE_CLASSES + SYNTHESISED_CLASSES)
            if drivable_only:
                if not drivable.any():
                    raise InputError("no road line has a drivable highway class")
                roads = roads[drivable]
                road_z_layer = None if road_z_layer is None else road_z_layer[drivable]
                if not drivable.all():
                    res.notes.append(f"Roads: {counted((~drivable).sum(), 'line')} of "
                                     "non-drivable classes (footways, paths, service roads "
                                     "...) left out.")
            elif not drivable.all():
                res.notes.append(f"Roads: {counted((~drivable).sum(), 'line')} of "
                                 "non-drivable classes (footways, paths, service roads ...) "
                                 "counted as streets.")
        elif drivable_only:
            raise InputError("drivable streets only needs a road class (highway) per line")
    blocks = None if blocks is None else _as_array(blocks, "blocks", 2, res.notes)
    if parcels is not None:
        parcels, kept = _as_array(parcels, "parcels", 2, res.notes, return_mask=True)
        if landuse is not None:
            landuse = np.asarray(landuse, dtype=object)
            if len(landuse) != len(kept):
                raise InputError(f"{len(landuse)} land-use values for {len(kept)} parcels")
            landuse = landuse[kept]
    buildings = None if buildings is None else _as_array(buildings, "buildings", 2, res.notes)
    area_geom, area_m2, source = _area(area, roads, blocks, parcels, buildings)
    area = area_geom if area_geom is not None else area_m2
    res.add_scalar("layout", "area_km2", area_m2 / M2_PER_KM2, "km²", "Area for densities")
    res.notes.append(f"Densities are per km² of the {source} ({area_m2 / M2_PER_KM2:.3f} km²).")
    if roads is not None and len(roads):
        # how much of that area the streets settle: a whole region's extract (a country's
        # OSM lines) counts its densities over mountains and lakes
        share = min(float(shapely.area(settled_area(roads, area_geom))) / area_m2, 1.0)
        res.add_scalar("layout", "settled_share", share, "",
                       "Share of the area the streets settle (their closing by "
                       f"{SETTLED_OUT:g} m)")
        if share < SETTLED_SHARE_LOW:
            res.notes.append(f"Only {share:.0%} of the {source} lies within reach of a "
                             "street: the densities are mostly of empty land (give a study "
                             "area, such as the town's outline).")
    progress.step(0.02)

    graph = None
    if roads is not None:
        graph = road_graph(roads, snap_tolerance, road_z_layer, progress.sub(0.02, 0.5))
        res.extend(road_metrics(graph, area, bearing_length=bearing_length,
                                edge_distance=edge_distance, progress=progress.sub(0.5, 0.55)))
        res.notes.append(f"Road graph: {len(roads)} lines -> "
                         f"{int(res.scalar('roads', 'edges'))} street segments "
                         f"between {int(res.scalar('roads', 'nodes'))} nodes"
                         + (f"; nodes within {edge_distance:g} m of the study-area boundary "
                            "are not counted" if edge_distance > 0 else "") + ".")
        res.extend(network_invariants(roads, road_z_layer, given_roads, given_class,
                                      given_z_layer, area_geom, edge_distance,
                                      progress.sub(0.55, 0.6)))
    progress.step(0.6)
    if blocks is None and graph is not None:
        faces, counts = block_faces(graph, min_block_area, min_block_width, return_counts=True)
        dropped = (f" ({counts['n_small']} faces under {min_block_area:g} m² and "
                   f"{counts['n_thin']} thinner than {min_block_width:g} m dropped as "
                   "slivers)" if counts["n_faces"] > len(faces) else "")
        if len(faces):
            blocks = faces
            res.notes.append(f"Blocks: {len(faces)} of the {counts['n_faces']} faces of the "
                             f"road graph{dropped}.")
        else:
            res.notes.append(f"Blocks: the roads close no block{dropped}, so there are no "
                             "block metrics.")
    if blocks is not None:
        res.extend(block_metrics(blocks, area))
    progress.step(0.7)
    if parcels is not None:
        res.extend(parcel_metrics(parcels, area, landuse))
    progress.step(0.8)
    if buildings is not None:
        res.extend(footprint_metrics(buildings, blocks, roads, road_half_width, area))
    progress.step(1.0)
    return res


# --------------------------------------------------------------------------- comparison

def two_sample(candidate, example) -> Dict[str, float]:
    """Distances between two samples of one measure.

    Returns
    -------
    dict with ``wasserstein`` (earth mover's distance, in the measure's unit),
    ``wasserstein_norm`` (divided by the example's standard deviation, so that 1 means
    "one example spread apart"; 0 when both are equal, NaN when the example is constant and
    the candidate differs), ``ks_stat`` and ``ks_pvalue`` (two-sided Kolmogorov-Smirnov).
    All NaN when either sample is empty.
    """
    c = np.asarray(candidate, dtype=float)
    e = np.asarray(example, dtype=float)
    c, e = c[np.isfinite(c)], e[np.isfinite(e)]
    if len(c) == 0 or len(e) == 0:
        return dict(wasserstein=np.nan, wasserstein_norm=np.nan, ks_stat=np.nan, ks_pvalue=np.nan)
    w = float(stats.wasserstein_distance(c, e))
    sd = float(np.std(e))
    if sd > 0:
        wn = w / sd
    else:
        wn = 0.0 if w == 0 else np.nan
    with warnings.catch_warnings():
        # ties make the exact p-value fail over to the asymptotic one: expected, not news
        warnings.simplefilter("ignore", RuntimeWarning)
        ks = stats.ks_2samp(c, e)
    return dict(wasserstein=w, wasserstein_norm=wn, ks_stat=float(ks.statistic),
                ks_pvalue=float(ks.pvalue))


def two_sample_axial(candidate, example, period: float = 180.0) -> Dict[str, float]:
    """:func:`two_sample` for directions on a circle of ``period`` degrees (street bearings:
    180, a street at 10° runs at 190° too), independent of where the circle is cut.

    ``wasserstein`` is the earth mover's distance on the circle, min over c of the integral
    of |F - G - c| (Rabin, Delon & Gousseau 2011), in degrees; ``wasserstein_norm`` divides
    it by the example's circular standard deviation (of the doubled angles, halved);
    ``ks_stat`` and ``ks_pvalue`` are Kuiper's V = max(F - G) + max(G - F), the KS statistic
    that does not depend on the cut, and its asymptotic p-value (Stephens 1970).
    """
    c = np.asarray(candidate, dtype=float) % period
    e = np.asarray(example, dtype=float) % period
    c, e = c[np.isfinite(c)], e[np.isfinite(e)]
    if len(c) == 0 or len(e) == 0:
        return dict(wasserstein=np.nan, wasserstein_norm=np.nan, ks_stat=np.nan, ks_pvalue=np.nan)
    cuts = np.unique(np.concatenate([c, e, [0.0, period]]))
    f = np.searchsorted(np.sort(c), cuts[:-1], side="right") / len(c)
    g = np.searchsorted(np.sort(e), cuts[:-1], side="right") / len(e)
    diff, width = f - g, np.diff(cuts)
    # the shift c minimising the weighted L1 norm is the weighted median of F - G
    order = np.argsort(diff)
    half = np.searchsorted(np.cumsum(width[order]), 0.5 * period)
    shift = diff[order][min(half, len(order) - 1)]
    w = float(np.sum(np.abs(diff - shift) * width))
    t = np.radians(e * 360.0 / period)
    r = min(float(np.hypot(np.cos(t).mean(), np.sin(t).mean())), 1.0)
    sd = float(np.degrees(np.sqrt(-2.0 * np.log(r))) * period / 360.0) if r > 0 else np.inf
    wn = w / sd if sd > 0 else (0.0 if w == 0 else np.nan)
    v = float(diff.max() - diff.min())
    n = len(c) * len(e) / (len(c) + len(e))
    lam = (np.sqrt(n) + 0.155 + 0.24 / np.sqrt(n)) * v
    j = np.arange(1, 101)
    p = float(np.clip(np.sum(2 * (4 * j**2 * lam**2 - 1) * np.exp(-2 * j**2 * lam**2)), 0, 1)) \
        if lam > 0.4 else 1.0
    return dict(wasserstein=w, wasserstein_norm=wn, ks_stat=v, ks_pvalue=p)


def _rel_diff(c: float, e: float) -> float:
    if not (np.isfinite(c) and np.isfinite(e)):
        return np.nan
    if e == 0:
        return 0.0 if c == 0 else np.nan
    return (c - e) / abs(e)


def _mean(values: np.ndarray) -> float:
    return float(values.mean()) if len(values) else np.nan


def _axial_mean(degrees: np.ndarray) -> float:
    """Mean direction of axial data (a street at 10° is the same as at 190°), in [0, 180)."""
    if not len(degrees):
        return np.nan
    t = np.radians(2.0 * np.asarray(degrees))
    return float(np.degrees(np.arctan2(np.sin(t).mean(), np.cos(t).mean())) / 2.0 % 180.0)


def _axial_difference(c: float, e: float) -> float:
    """Turn between two axial directions in degrees, signed, in [-90, 90): a difference of
    directions, not a relative one (it is reported in the rel_diff column)."""
    if not (np.isfinite(c) and np.isfinite(e)):
        return np.nan
    return float((c - e + 90.0) % 180.0 - 90.0)


def compare(candidate: MetricsResult, example: Optional[MetricsResult] = None) -> pd.DataFrame:
    """One row per measure: candidate and example values and their distance.

    Distributions give one row with ``statistic`` = 'mean' (the means of both samples and
    their relative difference) and the two-sample distances of :func:`two_sample`; street
    bearings, whose plain mean means nothing, give 'axial_mean' (the mean directions, and in
    ``rel_diff`` the turn between them in degrees) and the circular distances of
    :func:`two_sample_axial`; scalars
    give one row with ``statistic`` = 'value' and the relative difference
    (candidate - example) / |example|. Measures present on one side only keep NaN on the
    other. Without an example, the rows just list the candidate.

    Returns
    -------
    pandas.DataFrame with :data:`COMPARISON_COLUMNS`, ordered by kind (layout, roads,
    blocks, parcels, buildings), distributions before scalars.
    """
    example = example if example is not None else MetricsResult()
    rows = []
    keys: List[Tuple[str, str, str]] = []
    for side in (candidate, example):
        for d in side.distributions:
            if ("d", d.kind, d.name) not in keys:
                keys.append(("d", d.kind, d.name))
        for s in side.scalars:
            if ("s", s.kind, s.name) not in keys:
                keys.append(("s", s.kind, s.name))

    def find(side, typ, kind, name):
        items = side.distributions if typ == "d" else side.scalars
        return next((x for x in items if x.kind == kind and x.name == name), None)

    for typ, kind, name in keys:
        c, e = find(candidate, typ, kind, name), find(example, typ, kind, name)
        ref = c if c is not None else e
        row = dict(kind=kind, metric=name, unit=ref.unit)
        if typ == "d":
            cv = c.values if c is not None else np.zeros(0)
            ev = e.values if e is not None else np.zeros(0)
            axial = ref.unit == "°" and name.endswith("bearing")
            statistic, mean, distance = ("axial_mean", _axial_mean, two_sample_axial) if axial \
                else ("mean", _mean, two_sample)
            cm, em = mean(cv), mean(ev)
            rel = _axial_difference(cm, em) if axial else _rel_diff(cm, em)
            row.update(statistic=statistic, candidate=cm, example=em, rel_diff=rel,
                       n_candidate=len(cv), n_example=len(ev), **distance(cv, ev))
        else:
            cs = c.value if c is not None else np.nan
            es = e.value if e is not None else np.nan
            row.update(statistic="value", candidate=cs, example=es, rel_diff=_rel_diff(cs, es),
                       wasserstein=np.nan, wasserstein_norm=np.nan, ks_stat=np.nan,
                       ks_pvalue=np.nan, n_candidate=int(c is not None),
                       n_example=int(e is not None))
        row["_order"] = (_KIND_ORDER.index(kind) if kind in _KIND_ORDER else len(_KIND_ORDER),
                         0 if typ == "d" else 1)
        rows.append(row)
    columns = [name for name, _ in COMPARISON_COLUMNS]
    if not rows:
        return pd.DataFrame(columns=columns)
    df = pd.DataFrame(rows)
    df = df.sort_values("_order", kind="stable").drop(columns="_order").reset_index(drop=True)
    return df[columns]
