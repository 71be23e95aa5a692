"""Street surfaces and junction polygons, flat or draped on terrain (Scharl 2010, ch. 5).

Scharl, *Artist-controlled urban modeling* (2010), ch. 5.1 after Zimmermann [Zim07]: the
centre line of every street is offset by half its width on both sides (the *street
outlines*); the outlines of two neighbouring streets of a junction meet at a *corner
point*; the corner points and the junction's *centre point* bound the junction, which
therefore connects any number of streets. Each street end is cut at a line perpendicular
to the street (Fig. 5.4) through the farther of its two corner points, so junction and
street meet at a straight *connecting line*. Junction centres closer than a threshold, or
whose geometries would overlap along the street between them, are merged (sec. 5.1).

Ch. 5.2 (3D): each junction is moved into the tangent plane of the terrain at its centre
(here: the least-squares plane through DEM samples around the centre, applied to the
vertices vertically, so the 2D footprint is unchanged and the junction stays planar);
between the connecting lines the street is subdivided regularly and follows the terrain,
blending from the junction planes at its ends. Longitudinal and lateral slopes are
reported per feature against Scharl's limits (12 % / 8 %).

Guarantees (checked by the tests): every polygon is valid, no two polygons of one vertical
layer overlap (overlaps left by curved or acute streets are cut away, junctions first),
and together they cover the centre lines buffered by half their width.

Everything is vectorised with shapely 2 / numpy over incidences, vertices and samples; the
only Python loops are over the rare polygons that need an overlap cut.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
import pandas as pd
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..core import coordinates
from ..core.geometry import end_sections, pinned_ends, substrings, unit
from ..core.progress import InputError, Progress, ensure
from ..retrieval.shape_context import DemGrid
from .street_graph import RoadGraph, clean_network

__all__ = [
    "CLASS_WIDTHS", "LEVEL_WIDTHS", "DEFAULT_WIDTH", "SURFACE_FIELDS", "JUNCTION_FIELDS",
    "parse_width", "road_widths", "Tessellation", "tessellate_network", "tessellate_lines",
    "reference_area", "merge_junctions",
]

#: Default carriageway width (m) per OSM ``highway`` class (links: 7 m), used when a line
#: has no width of its own. Typical urban cross-sections; the user's width field wins.
CLASS_WIDTHS = {
    "motorway": 25.0, "trunk": 20.0, "primary": 16.0, "secondary": 13.0, "tertiary": 11.0,
    "unclassified": 7.0, "residential": 8.0, "living_street": 6.0, "road": 7.0,
    "service": 5.0, "pedestrian": 6.0, "busway": 7.0, "track": 3.5, "cycleway": 3.0,
    "footway": 2.5, "path": 2.0, "steps": 2.0, "major": 12.0, "minor": 8.0,
}
LINK_WIDTH = 7.0
#: Default width (m) per hierarchy ``level`` (0 = arterial) when there is no class either.
LEVEL_WIDTHS = {0: 16.0, 1: 11.0, 2: 8.0}
DEEP_LEVEL_WIDTH = 6.0
DEFAULT_WIDTH = 8.0

SURFACE_FIELDS = [("segment_id", "int"), ("edge_id", "int"), ("from_junction", "int"),
                  ("to_junction", "int"), ("road_class", "str"), ("z_layer", "int"),
                  ("width_m", "float"), ("length_m", "float"), ("area_m2", "float"),
                  ("slope_long_pct", "float"), ("slope_lat_pct", "float"),
                  ("too_steep_long", "bool"), ("too_steep_lat", "bool")]
JUNCTION_FIELDS = [("junction_id", "int"), ("degree", "int"), ("merged_nodes", "int"),
                   ("z_layer", "int"), ("area_m2", "float"), ("z_centre", "float"),
                   ("slope_pct", "float"), ("slope_long_pct", "float"),
                   ("slope_lat_pct", "float"), ("too_steep_long", "bool"),
                   ("too_steep_lat", "bool")]

_NUMBER = re.compile(r"^\s*([0-9]+(?:[.,][0-9]+)?)\s*(m|metres|meters)?\s*$")
_ARC = 6          # points on the round fill of a corner wider than 180 degrees
_QUAD_SEGS = 8    # buffer resolution (shapely's default): the reference uses the same


# --------------------------------------------------------------------------- widths

def parse_width(value) -> float:
    """A width in metres from a number or an OSM ``width`` tag ('7', '7.5 m', '6,5'); NaN
    for anything else (feet, ranges, lists, nonsense)."""
    if value is None:
        return np.nan
    if isinstance(value, (int, float, np.integer, np.floating)):
        w = float(value)
    else:
        text = str(value).split(";")[0]
        m = _NUMBER.match(text)
        if not m:
            return np.nan
        w = float(m.group(1).replace(",", "."))
    return w if np.isfinite(w) and 0.5 <= w <= 200.0 else np.nan


def road_widths(width=None, road_class=None, level=None, n: Optional[int] = None,
                default_width: float = DEFAULT_WIDTH, oneway=None):
    """Width (m) per line: its own width when valid, else the class table, else the level
    table, else ``default_width``. A table width is halved (at least 3.5 m) for a one-way
    line (OSM ``oneway`` yes / true / 1 / -1): OSM maps each carriageway of a dual
    carriageway as its own one-way way.

    Returns (widths, source) with source per line in {'field', 'class', 'level', 'default'}.
    """
    if n is None:
        n = len(next(a for a in (width, road_class, level) if a is not None))
    out = np.full(n, np.nan)
    src = np.full(n, "default", dtype=object)
    if width is not None:
        out = np.array([parse_width(v) for v in width], dtype=float)
        src[np.isfinite(out)] = "field"
    if road_class is not None:
        cls = np.array([CLASS_WIDTHS.get(str(c), LINK_WIDTH if str(c).endswith("_link") else np.nan)
                        if c not in (None, "") else np.nan for c in road_class], dtype=float)
        take = ~np.isfinite(out) & np.isfinite(cls)
        out[take], src[take] = cls[take], "class"
    if level is not None:
        lv = pd.to_numeric(pd.Series(np.asarray(level, dtype=object)), errors="coerce").to_numpy()
        by_level = np.array([LEVEL_WIDTHS.get(int(x), DEEP_LEVEL_WIDTH) if np.isfinite(x) and x >= 0
                             else np.nan for x in lv], dtype=float)
        take = ~np.isfinite(out) & np.isfinite(by_level)
        out[take], src[take] = by_level[take], "level"
    take = ~np.isfinite(out)
    out[take] = default_width
    if oneway is not None:
        one = np.array([str(o).strip().lower() in ("yes", "true", "1", "-1") for o in oneway])
        half = one & (src != "field") & (src != "default")
        out[half] = np.maximum(out[half] / 2.0, 3.5)
    return out, src


# --------------------------------------------------------------------------- result

@dataclass
class Tessellation:
    """Street surfaces and junctions of one network.

    surfaces, junctions : arrays of (Multi)Polygons, with Z when a DEM was given
    surface_table, junction_table : attributes per polygon (:data:`SURFACE_FIELDS`,
        :data:`JUNCTION_FIELDS`)
    graph : the street graph after junction merging; widths : its edge widths
    stats : counts and timings for the log
    """

    surfaces: np.ndarray
    surface_table: pd.DataFrame
    junctions: np.ndarray
    junction_table: pd.DataFrame
    graph: RoadGraph
    widths: np.ndarray
    stats: dict = field(default_factory=dict)
    #: centre line, edge index and width of every surface (kept rows), for the mesh
    centres: Optional[np.ndarray] = None
    surface_edge: Optional[np.ndarray] = None
    #: graph node of every junction (kept rows)
    junction_node: Optional[np.ndarray] = None
    #: with a DEM: z of points on surface k (terrain blended into the junction planes),
    #: z of points in the plane of junction node n, and the terrain itself
    surface_z: Optional[Callable] = None
    junction_z: Optional[Callable] = None
    terrain_z: Optional[Callable] = None


# --------------------------------------------------------------------------- merging

def merge_junctions(graph: RoadGraph, widths: np.ndarray, pairs: np.ndarray):
    """Merge node pairs (k, 2) into their centroid (Scharl 5.1: 'the two center points are
    merged'). Edges between merged nodes shorter than the merged cluster's span plus their
    width vanish into the junction; the ends of the other edges move onto the new centre.

    Returns (graph, widths, new node index of every old node, -1 for nodes that vanished).
    """
    n = len(graph.nodes)
    if len(pairs) == 0:
        return graph, widths, np.arange(n)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    counts = np.bincount(label)
    centre = np.column_stack([np.bincount(label, graph.nodes[:, 0]) / counts,
                              np.bincount(label, graph.nodes[:, 1]) / counts])
    u, v = label[graph.u], label[graph.v]
    # span of each cluster: the farthest member from its centre
    span = np.zeros(len(counts))
    np.maximum.at(span, label, np.hypot(*(graph.nodes - centre[label]).T))
    length = graph.length
    absorbed = (u == v) & (graph.u != graph.v) & (length <= 2 * span[u] + widths)
    keep = ~absorbed
    lines = pinned_ends(graph.geometry[keep], centre[u[keep]], centre[v[keep]])
    used, inv = np.unique(np.concatenate([u[keep], v[keep]]), return_inverse=True)
    m = int(keep.sum())
    g = RoadGraph(lines, inv[:m], inv[m:], graph.road_class[keep], graph.name[keep],
                  graph.z_layer[keep], centre[used], graph.source[keep])
    new_of_label = np.full(len(counts), -1)
    new_of_label[used] = np.arange(len(used))
    return g, widths[keep], new_of_label[label]


# --------------------------------------------------------------------------- geometry

def _incidences(graph: RoadGraph, widths: np.ndarray):
    """Both ends of every edge as incidences (node, edge, end), sorted CCW around the node.

    The head direction is taken towards the point one width (at most half the edge) along
    the line, which is steadier on OSM's short first segments than the first vertex.
    """
    m = graph.n_edges
    length = graph.length
    lines = graph.geometry
    h = np.minimum(np.maximum(widths, 1.0), 0.5 * length)
    start = shapely.get_coordinates(shapely.get_point(lines, 0))
    end = shapely.get_coordinates(shapely.get_point(lines, -1))
    a = shapely.get_coordinates(shapely.line_interpolate_point(lines, h))
    b = shapely.get_coordinates(shapely.line_interpolate_point(lines, length - h))
    node = np.concatenate([graph.u, graph.v])
    edge = np.concatenate([np.arange(m), np.arange(m)])
    at_end = np.r_[np.zeros(m, bool), np.ones(m, bool)]
    direction = unit(np.vstack([a - start, b - end]))
    angle = np.arctan2(direction[:, 1], direction[:, 0])
    order = np.lexsort((angle, node))
    return (node[order], edge[order], at_end[order], direction[order], angle[order],
            widths[edge[order]] / 2.0, length[edge[order]])


def _groups(node: np.ndarray):
    """For incidences sorted by node: the next (CCW) incidence in the same node, cyclically."""
    k = len(node)
    start = np.r_[True, node[1:] != node[:-1]]
    gid = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    size = np.diff(np.r_[first, k])
    pos = np.arange(k) - first[gid]
    nxt = first[gid] + (pos + 1) % size[gid]
    return nxt, size[gid], gid, first


def _junction_heads(graph, widths, node_xy, max_head):
    """Scharl's street heads: corner points with the next street (CCW) and cut distances.

    Returns a dict of per-incidence arrays, sorted CCW around each node; ``t`` / ``s`` are
    the corner's distances along this street's left and the next street's right outline.
    """
    node, edge, at_end, d, ang, half, length = _incidences(graph, widths)
    nxt, deg, _, _ = _groups(node)
    p = node_xy[node]
    nrm = np.column_stack([-d[:, 1], d[:, 0]])            # left normal
    dj, nj, hj = d[nxt], nrm[nxt], half[nxt]
    gap = np.mod(ang[nxt] - ang, 2 * np.pi)
    gap = np.where((nxt == np.arange(len(node))), 2 * np.pi, gap)
    # left outline of i: p + half_i n_i + t d_i ; right outline of j: p - half_j n_j + s d_j
    rhs = -hj[:, None] * nj - half[:, None] * nrm
    det = -(d[:, 0] * dj[:, 1] - d[:, 1] * dj[:, 0])       # det [d_i, -d_j]
    ok = (np.abs(det) > 1e-9) & (gap < np.pi - 1e-6)
    sdet = np.where(ok, det, 1.0)
    t = (rhs[:, 0] * -dj[:, 1] - rhs[:, 1] * -dj[:, 0]) / sdet
    s = (d[:, 0] * rhs[:, 1] - d[:, 1] * rhs[:, 0]) / sdet
    ok &= (t >= 0) & (s >= 0)
    t, s = np.where(ok, t, 0.0), np.where(ok, s, 0.0)
    # cut distance of each head: the farther of its two corners, within limits
    cap = np.minimum(0.5 * length, max_head)
    back = np.empty_like(s)
    back[nxt] = s                                          # s is the right corner of nxt
    cut = np.minimum(np.maximum(t, back), cap)
    corner = p + half[:, None] * nrm + t[:, None] * d
    corner_ok = ok & (t <= cut + 1e-9) & (s <= cut[nxt] + 1e-9)
    return dict(node=node, edge=edge, at_end=at_end, d=d, nrm=nrm, half=half, gap=gap,
                cut=cut, corner=corner, corner_ok=corner_ok, nxt=nxt, deg=deg, p=p,
                length=length, t=t, s=s)


def _cut_points(lines, at_end, cut, length):
    """Point and unit direction (away from the junction) at ``cut`` metres along each head."""
    pos = np.where(at_end, length - cut, cut)
    eps = np.minimum(0.01, 0.25 * length)
    here = shapely.get_coordinates(shapely.line_interpolate_point(lines, pos))
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(
        lines, np.where(at_end, pos - eps, pos + eps)))
    return here, unit(ahead - here)


def _junction_rings(h, right, left):
    """One ring per node of degree >= 2: per head (CCW) its right and left cut point, then
    the corner point with the next head, or a round fill where they diverge (> 180 deg)."""
    half = h["half"]
    nxt = h["nxt"]
    # corner slots (_ARC + 2 points each): corner point, chord, or round fill
    slots = np.repeat(left[:, None, :], _ARC + 2, axis=1)
    good = h["corner_ok"]
    slots[good] = h["corner"][good][:, None, :]
    # a corner that set (or nearly set) a cut distance is that cut's end point: the ring then
    # runs straight from this street's cut to the next one's. The corner itself comes from
    # the straight head direction, which on a curved street is centimetres off the cut
    # points measured on the street, and would twist the ring
    tol = 0.1 * np.minimum(half, half[nxt])
    at_cut = good & ((h["t"] >= h["cut"] - tol) | (h["s"] >= h["cut"][nxt] - tol))
    slots[at_cut] = left[at_cut][:, None, :]
    wide = h["gap"] >= np.pi - 1e-6
    if wide.any():
        p, nrm = h["p"][wide], h["nrm"][wide]
        a0 = np.arctan2(nrm[:, 1], nrm[:, 0])
        span = h["gap"][wide] - np.pi
        r0, r1 = half[wide], half[nxt][wide]
        f = np.linspace(0.0, 1.0, _ARC + 2)[None, :]
        ang = a0[:, None] + span[:, None] * f
        r = r0[:, None] + (r1 - r0)[:, None] * f
        slots[wide] = p[:, None, :] + r[..., None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    ring = np.concatenate([right[:, None, :], left[:, None, :], slots], axis=1)
    coords = ring.reshape(-1, 2)
    owner = np.repeat(h["node"], ring.shape[1])
    return coords, owner


def _pinned_caps(surfaces, caps, tol):
    """``surfaces`` with their vertex nearest each of their cap points ``caps`` (n, 4, 2:
    :func:`end_sections`) set to it where it is within ``tol`` (per surface) of it: GEOS
    offsets a flat cap's vertices its own way, a cut snaps them to the micrometre."""
    xy, idx = shapely.get_coordinates(surfaces, return_index=True)
    if not len(xy):
        return surfaces
    span = 4.0 * (np.abs(xy).max() + np.abs(caps).max() + 1.0)
    tree = cKDTree(np.column_stack([xy, idx * span]))   # one surface's vertices only
    own = np.repeat(np.arange(len(surfaces)), 4)
    pts = caps.reshape(-1, 2)
    dist, j = tree.query(np.column_stack([pts, own * span]), k=2)
    ok = dist[:, 0] < tol[own]
    twin = ok & (xy[j[:, 1]] == xy[j[:, 0]]).all(1)
    xy[j[ok, 0]] = pts[ok]
    xy[j[twin, 1]] = pts[twin]
    return shapely.set_coordinates(surfaces.copy(), xy)


def _cut_overlaps(polys, layer, fixed=None, fixed_layer=None, incident=None, priority=None,
                  tol=1e-6):
    """Remove from ``polys`` what overlaps ``fixed`` polygons (or, when ``fixed`` is None,
    what overlaps polygons of ``polys`` with a higher priority), within one vertical layer
    (and across layers for a surface and the junctions at its own ends, via ``incident``).
    Returns (polys, number cut)."""
    polys = polys.copy()
    other = polys if fixed is None else fixed
    other_layer = layer if fixed is None else fixed_layer
    none = np.zeros(0, dtype=np.int64)
    if len(polys) == 0 or len(other) == 0:
        return polys, none
    # most neighbours only share a connecting line: a copy of the cutters shrunk by a tenth
    # of a millimetre no longer touches them, so a fast prepared 'intersects' finds the
    # pairs whose interiors overlap (a full relate / touches would cost 30x more)
    shrunk = shapely.buffer(other, -1e-4, join_style="mitre")
    tree = shapely.STRtree(shrunk)
    i, j = tree.query(polys, predicate="intersects")
    same = layer[i] == other_layer[j]
    if incident is not None:
        same |= incident(i, j)
    if fixed is None:
        sel = same & (priority[j] < priority[i])
    else:
        sel = same
    i, j = i[sel], j[sel]
    if len(i) == 0:
        return polys, none
    area = shapely.area(shapely.intersection(polys[i], other[j]))
    big = area > tol
    i, j = i[big], j[big]
    if len(i) == 0:
        return polys, none
    original = other.copy()
    order = np.argsort(i, kind="stable")
    i, j = i[order], j[order]
    starts = np.r_[0, np.flatnonzero(np.diff(i)) + 1]
    ends = np.r_[starts[1:], len(i)]
    single = (ends - starts) == 1
    # one cutter (the usual case): one vectorised difference
    t1, c1 = i[starts[single]], j[starts[single]]
    with np.errstate(divide="ignore", invalid="ignore"):  # GEOS's empty results
        polys[t1] = shapely.difference(polys[t1], original[c1])
    for s, e in zip(starts[~single], ends[~single]):
        polys[i[s]] = shapely.difference(polys[i[s]], shapely.union_all(original[j[s:e]]))
    changed = i[starts]
    odd = ~np.isin(shapely.get_type_id(polys[changed]), (3, 6))
    for k in changed[odd]:
        polys[k] = _polygonal(polys[k])
    # snap what was cut to a micrometre grid: differences leave vertices nanometres apart,
    # which a reprojection to the input CRS can turn into self-intersections; GEOS keeps
    # the result valid
    polys[changed] = shapely.set_precision(polys[changed], 1e-6)
    return polys, changed


def _polygonal(g):
    """Keep the polygons of a geometry (a difference may leave lines or points behind)."""
    if g is None or g.is_empty:
        return shapely.Polygon()
    if shapely.get_type_id(g) in (3, 6):
        return g
    parts = [p for p in shapely.get_parts(g) if shapely.get_type_id(p) in (3, 6)]
    return shapely.union_all(parts) if parts else shapely.Polygon()


# --------------------------------------------------------------------------- terrain

def _fit_planes(dem, centres, radius, n=5):
    """Least-squares plane z = z0 + g . (xy - c) through DEM samples on an n x n grid of
    half-size ``radius`` around each centre (Scharl's tangent plane of the terrain)."""
    f = np.linspace(-1.0, 1.0, n)
    ox, oy = np.meshgrid(f, f)
    off = np.column_stack([ox.ravel(), oy.ravel()])            # symmetric: normal eqs decouple
    pts = centres[:, None, :] + radius[:, None, None] * off[None, :, :]
    z = dem(pts)
    zc = dem(centres)
    fill = np.where(np.isfinite(z), z, zc[:, None])
    fill = np.where(np.isfinite(fill), fill, 0.0)
    dx = radius[:, None] * off[None, :, 0]
    dy = radius[:, None] * off[None, :, 1]
    gx = (fill * dx).sum(1) / np.maximum((dx * dx).sum(1), 1e-12)
    gy = (fill * dy).sum(1) / np.maximum((dy * dy).sum(1), 1e-12)
    z0 = fill.mean(1)                                          # plane's height at the centre
    return z0, np.column_stack([gx, gy])


def _dem_z(dem, xy):
    z = dem(xy)
    return np.where(np.isfinite(z), z, np.nanmean(z) if np.isfinite(z).any() else 0.0)


# --------------------------------------------------------------------------- main API

def _snap_ends(graph: RoadGraph) -> RoadGraph:
    """Put every line's end exactly on its node: the cleaner's node ids are rounded to the
    millimetre, and half a millimetre between a street's end and its junction centre is
    enough to twist corner points against cut points."""
    lines = pinned_ends(graph.geometry, graph.nodes[graph.u], graph.nodes[graph.v])
    return RoadGraph(lines, graph.u, graph.v, graph.road_class, graph.name, graph.z_layer,
                     graph.nodes, graph.source)


def _head_cap(graph, widths, max_head):
    """Longest street head per node: ``max_head``, else 3 x its widest street."""
    if max_head is not None:
        return np.full(len(graph.nodes), float(max_head))
    wmax = np.zeros(len(graph.nodes))
    np.maximum.at(wmax, np.concatenate([graph.u, graph.v]), np.r_[widths, widths])
    return 3.0 * wmax


def tessellate_network(graph: RoadGraph, widths: Sequence[float],
                       merge_distance: float = 3.0, dem=None,
                       max_longitudinal_slope: float = 0.12, max_lateral_slope: float = 0.08,
                       max_head: Optional[float] = None, sample_spacing: Optional[float] = None,
                       merge_heads: bool = False, progress: Optional[Progress] = None) -> Tessellation:
    """Street-segment and junction polygons of a planar street graph.

    Parameters
    ----------
    graph : RoadGraph
        Noded street graph (:func:`plugin.network.street_graph.clean_network`), metric CRS.
    widths : array of float
        Full street width (m) per edge.
    merge_distance : float
        Junction centres (degree >= 3) closer than this are merged into one (Scharl 5.1).
    merge_heads : bool
        Also merge the two centres of an edge whose street heads meet along it (Scharl's
        rule for overlapping junction geometry). Off by default: heads are then capped at
        half the edge, the two junctions share a connecting line and the streets keep their
        true positions (merging moves them onto the merged centre).
    dem : DemGrid or None
        Terrain: junctions go into the tangent plane at their centre, streets are draped
        between them; slopes are measured.
    max_longitudinal_slope, max_lateral_slope : float
        Limits (rise over run, Scharl: 0.12 and 0.08) for the ``too_steep_*`` flags.
    max_head : float or None
        Longest street head (cut distance from the centre); default 3 x the widest street at
        the junction, so acute junctions stay compact.
    sample_spacing : float or None
        Spacing (m) of the terrain samples along streets; default the DEM's cell (>= 2 m).

    Returns
    -------
    Tessellation

    References
    ----------
    Scharl 2010, ch. 5.1 (planar streets, street heads, merging) and 5.2 (tangent planes).
    """
    progress = ensure(progress)
    widths = np.asarray(widths, dtype=float)
    if graph.n_edges == 0:
        raise InputError("the street graph has no edges")
    if len(widths) != graph.n_edges or not np.isfinite(widths).all() or (widths <= 0).any():
        raise InputError("every street needs a positive, finite width")
    if merge_distance < 0:
        raise InputError("the merge distance must not be negative")
    n_nodes_in = len(graph.nodes)
    graph = _snap_ends(graph)

    # 1. merge close junction centres, then centres whose heads meet along the edge between
    #    them (repeated: a merge can bring new neighbours together)
    merged = np.ones(n_nodes_in, dtype=np.int64)
    for it in range(4):
        deg = graph.degree
        pairs = np.empty((0, 2), dtype=np.int64)
        junction = np.flatnonzero(deg >= 3)
        if merge_distance > 0 and len(junction) > 1:
            close = cKDTree(graph.nodes[junction]).query_pairs(merge_distance, output_type="ndarray")
            if len(close):
                pairs = junction[close]
        if merge_heads:
            h = _junction_heads(graph, widths, graph.nodes, np.inf)
            cut = np.minimum(h["cut"], _head_cap(graph, widths, max_head)[h["node"]])
            # a head reaching half the edge (where it is capped) meets the other one
            full = np.zeros(graph.n_edges, dtype=bool)
            np.logical_or.at(full, h["edge"],
                             (h["deg"] >= 3) & (cut >= 0.5 * h["length"] - 1e-9))
            full &= (deg[graph.u] >= 3) & (deg[graph.v] >= 3) & (graph.u != graph.v)
            if full.any():
                pairs = np.vstack([pairs, np.column_stack([graph.u[full], graph.v[full]])])
        if len(pairs) == 0:
            break
        graph, widths, new_of_old = merge_junctions(graph, widths, pairs)
        ok = new_of_old >= 0
        merged = np.bincount(new_of_old[ok], weights=merged[ok],
                             minlength=len(graph.nodes)).astype(np.int64)
        if graph.n_edges == 0:
            raise InputError("nothing is left after merging junctions: the streets are "
                             "shorter than their widths")
    progress.step(0.15)

    # 2. street heads and junction rings
    deg = graph.degree
    cap = _head_cap(graph, widths, max_head)
    node_inc = np.concatenate([graph.u, graph.v])
    h = _junction_heads(graph, widths, graph.nodes, np.inf)
    h["cut"] = np.minimum(h["cut"], cap[h["node"]])
    h["corner_ok"] &= (np.abs(h["corner"] - h["p"]).max(1) <= 2 * cap[h["node"]])
    # a corner beyond either cut is replaced by the chord between the two cut points
    t_corner = ((h["corner"] - h["p"]) * h["d"]).sum(1)
    s_corner = ((h["corner"] - h["p"]) * h["d"][h["nxt"]]).sum(1)
    h["corner_ok"] &= (t_corner <= h["cut"] + 1e-6) & (s_corner <= h["cut"][h["nxt"]] + 1e-6)
    is_junction_inc = h["deg"] >= 2
    h["cut"] = np.where(is_junction_inc, h["cut"], 0.0)
    lines_inc = graph.geometry[h["edge"]]
    cut_xy, cut_dir = _cut_points(lines_inc, h["at_end"], h["cut"], h["length"])
    nrm_cut = h["half"][:, None] * np.column_stack([-cut_dir[:, 1], cut_dir[:, 0]])
    right, left = cut_xy - nrm_cut, cut_xy + nrm_cut
    # the street centre lines between the cuts; where a street has one, its ends' edges
    # are the junctions' connecting lines, to the last bit (computed apart, the two
    # differed by round-off and the paved area had cracks a nanometre wide)
    cut_start = np.zeros(graph.n_edges)
    cut_end = np.zeros(graph.n_edges)
    cut_start[h["edge"][~h["at_end"]]] = h["cut"][~h["at_end"]]
    cut_end[h["edge"][h["at_end"]]] = h["cut"][h["at_end"]]
    length = graph.length
    a, b = cut_start, length - cut_end
    has_surface = (b - a) > 1e-3
    centre = substrings(graph.geometry[has_surface], a[has_surface], b[has_surface])
    surf_edge = np.flatnonzero(has_surface)
    cap_left, cap_right = end_sections(centre, widths[surf_edge] / 2.0)
    row = np.cumsum(has_surface) - 1
    on = has_surface[h["edge"]]
    r, e = row[h["edge"][on]], h["at_end"][on].astype(np.int64)
    # seen from the junction, a street's end runs backwards: its left is the right
    right[on] = np.where(e[:, None] == 1, cap_left[r, e], cap_right[r, e])
    left[on] = np.where(e[:, None] == 1, cap_right[r, e], cap_left[r, e])
    sel = is_junction_inc
    hj = {k: (v[sel] if isinstance(v, np.ndarray) and len(v) == len(sel) else v)
          for k, v in h.items()}
    # ``nxt`` indexes all incidences: re-index within the junction subset
    remap = np.full(len(sel), -1)
    remap[np.flatnonzero(sel)] = np.arange(int(sel.sum()))
    hj["nxt"] = remap[h["nxt"][sel]]
    coords, owner = _junction_rings(hj, right[sel], left[sel])
    progress.step(0.3)

    junction_nodes = np.unique(owner)
    if len(coords):
        # close each ring: repeat its first point
        start = np.r_[True, owner[1:] != owner[:-1]]
        firsts = np.flatnonzero(start)
        ins = np.r_[firsts[1:], len(coords)]
        coords_c = np.insert(coords, ins, coords[firsts], axis=0)
        owner_c = np.insert(owner, ins, owner[firsts])
        rings = shapely.linearrings(coords_c, indices=np.searchsorted(junction_nodes, owner_c))
        jpolys = shapely.polygons(rings)
        # cut points that coincide with a corner differ by float noise: merge them
        jpolys = shapely.remove_repeated_points(jpolys, 1e-6)
        # a ring still twisted by centimetres on a curved street: buffer(0) drops the tiny
        # reversed lobe (15x faster than make_valid, which is the fallback)
        bad = np.flatnonzero(~shapely.is_valid(jpolys))
        if len(bad):
            raw = jpolys[bad]
            fixed = shapely.buffer(raw, 0.0)
            still = ~shapely.is_valid(fixed) | shapely.is_empty(fixed) | \
                (shapely.area(fixed) < 0.98 * np.abs(shapely.area(raw)))
            fixed[still] = [_polygonal(g) for g in shapely.make_valid(raw[still])]
            jpolys[bad] = fixed
    else:
        jpolys = np.empty(0, dtype=object)
    progress.step(0.4)

    # 3. street surfaces between the connecting lines
    caps = np.concatenate([cap_left, cap_right], axis=1)
    surfaces = shapely.buffer(centre, widths[surf_edge] / 2.0, quad_segs=_QUAD_SEGS,
                              cap_style="flat", join_style="round")
    # GEOS simplifies the line by 1 % of the half width
    surfaces = _pinned_caps(surfaces, caps, 0.005 * widths[surf_edge])
    progress.step(0.55)

    # 4. overlaps: junctions keep their shape; later junctions and all surfaces give way
    node_layer = np.zeros(len(graph.nodes), dtype=np.int64)
    # a junction belongs to the lowest |layer| among its streets (bridges end on the ground)
    zl_inc = np.r_[graph.z_layer, graph.z_layer]
    order = np.argsort(-np.abs(zl_inc), kind="stable")
    node_layer[node_inc[order]] = zl_inc[order]
    j_layer = node_layer[junction_nodes]
    jpolys, n_jcut = _cut_overlaps(jpolys, j_layer, priority=np.arange(len(jpolys)))
    s_layer = graph.z_layer[surf_edge]
    su, sv = graph.u[surf_edge], graph.v[surf_edge]

    def incident(i, j):
        node = junction_nodes[j]
        return (su[i] == node) | (sv[i] == node)

    surfaces, n_scut = _cut_overlaps(surfaces, s_layer, fixed=jpolys, fixed_layer=j_layer,
                                     incident=incident)
    rank = graph.class_rank[surf_edge]
    priority = np.lexsort((surf_edge, -widths[surf_edge], rank))
    prio = np.empty(len(priority), dtype=np.int64)
    prio[priority] = np.arange(len(priority))
    surfaces, n_sscut = _cut_overlaps(surfaces, s_layer, priority=prio)
    surfaces = _pinned_caps(surfaces, caps, np.full(len(surfaces), 1e-6))
    keep_s = ~shapely.is_empty(surfaces) & (shapely.area(surfaces) > 1e-6)
    progress.step(0.7)

    # 5. attributes, terrain
    s_table = pd.DataFrame({
        "edge_id": surf_edge + 1, "from_junction": su + 1, "to_junction": sv + 1,
        "road_class": graph.road_class[surf_edge], "z_layer": s_layer,
        "width_m": widths[surf_edge], "length_m": shapely.length(centre),
        "area_m2": shapely.area(surfaces)})
    j_deg = deg[junction_nodes]
    j_table = pd.DataFrame({
        "junction_id": junction_nodes + 1, "degree": j_deg,
        "merged_nodes": merged[junction_nodes], "z_layer": j_layer,
        "area_m2": shapely.area(jpolys)})
    for col in ("slope_long_pct", "slope_lat_pct", "z_centre"):
        s_table[col] = np.nan
        j_table[col] = np.nan
    j_table["slope_pct"] = np.nan
    dem_gaps = {}
    if dem is not None and not np.isfinite(dem.array).all():
        # a hole in the DEM, or its edge inside the network: holes are filled smoothly from
        # their rim, the land beyond the edge keeps the edge's height (bilinear sampling
        # would give NaN, which no geometry can hold), and the log says how many and how far
        xy, k = shapely.get_coordinates(shapely.segmentize(graph.geometry, dem.cell_size),
                                        return_index=True)
        off = ~np.isfinite(dem(xy))
        dem, distance = dem.filled()
        if off.any():
            reach = DemGrid(distance, dem.geotransform)(xy[off])   # sampled as the DEM is
            dem_gaps = {"dem_gap_edges": int(len(np.unique(k[off]))),
                        "dem_gap_max_m": float(reach.max())}
    if dem is not None:
        surfaces, jpolys, heights = _drape(dem, graph, widths, h, junction_nodes, jpolys,
                                           surfaces, centre, surf_edge, s_table, j_table,
                                           sample_spacing, progress.sub(0.7, 0.98))
        s_table["too_steep_long"] = s_table["slope_long_pct"] > 100 * max_longitudinal_slope
        s_table["too_steep_lat"] = s_table["slope_lat_pct"] > 100 * max_lateral_slope
        j_table["too_steep_long"] = j_table["slope_long_pct"] > 100 * max_longitudinal_slope
        j_table["too_steep_lat"] = j_table["slope_lat_pct"] > 100 * max_lateral_slope
    else:
        heights = None
        for t in (s_table, j_table):
            t["too_steep_long"] = None
            t["too_steep_lat"] = None
    s_table = s_table.drop(columns=["z_centre"])
    keep_j = ~shapely.is_empty(jpolys) & (shapely.area(jpolys) > 1e-6)
    surfaces, s_table = surfaces[keep_s], s_table[keep_s].reset_index(drop=True)
    jpolys, j_table = jpolys[keep_j], j_table[keep_j].reset_index(drop=True)
    s_table.insert(0, "segment_id", np.arange(1, len(s_table) + 1))
    stats = {"edges": graph.n_edges, "nodes_in": n_nodes_in, "nodes": len(graph.nodes),
             "merged_away": n_nodes_in - len(graph.nodes), "surfaces": len(surfaces),
             "junctions": len(jpolys), "edges_without_surface": int((~has_surface).sum()),
             "cut_junctions": len(n_jcut),
             "cut_surfaces": len(np.union1d(n_scut, n_sscut)),
             "max_degree": int(j_deg.max()) if len(j_deg) else 0, **dem_gaps}
    progress.step(1.0)
    out = Tessellation(surfaces, s_table, jpolys, j_table, graph, widths, stats,
                       centres=centre[keep_s], surface_edge=surf_edge[keep_s],
                       junction_node=junction_nodes[keep_j])
    if dem is not None:
        kept = np.flatnonzero(keep_s)
        height, plane, terrain = heights
        out.surface_z = lambda k, xy: height(kept[k], xy)
        out.junction_z = plane
        out.terrain_z = terrain
    return out


def _drape(dem, graph, widths, h, junction_nodes, jpolys, surfaces, centre, surf_edge,
           s_table, j_table, sample_spacing, progress):
    """Give junctions their tangent plane and drape surfaces between them (Scharl 5.2)."""
    nodes = graph.nodes
    n_nodes = len(nodes)
    cell = dem.cell_size
    spacing = max(cell, 2.0) if sample_spacing is None else float(sample_spacing)
    # plane per node: fitted over the junction's reach (its longest head), >= 1.5 cells
    reach = np.zeros(n_nodes)
    np.maximum.at(reach, h["node"], h["cut"] + h["half"])
    radius = np.maximum(reach, 1.5 * cell)
    z0, grad = _fit_planes(dem, nodes, radius)
    has_plane = np.zeros(n_nodes, dtype=bool)
    has_plane[junction_nodes] = True

    def plane(node_idx, xy):
        return z0[node_idx] + ((xy - nodes[node_idx]) * grad[node_idx]).sum(-1)

    # junctions: every vertex on its plane
    if len(jpolys):
        jpolys = coordinates.transform(
            shapely.force_3d(jpolys, 0.0),
            lambda c, i: np.column_stack([c[:, :2], plane(junction_nodes[i], c[:, :2])]),
            include_z=True)
        g = grad[junction_nodes]
        j_table["z_centre"] = z0[junction_nodes]
        j_table["slope_pct"] = 100 * np.hypot(g[:, 0], g[:, 1])
        # per incident street: the plane's grade along it and across it
        inc = np.isin(h["node"], junction_nodes)
        along = np.abs((grad[h["node"]] * h["d"]).sum(1))
        across = np.abs((grad[h["node"]] * h["nrm"]).sum(1))
        lon = np.zeros(n_nodes)
        lat = np.zeros(n_nodes)
        np.maximum.at(lon, h["node"][inc], along[inc])
        np.maximum.at(lat, h["node"][inc], across[inc])
        j_table["slope_long_pct"] = 100 * lon[junction_nodes]
        j_table["slope_lat_pct"] = 100 * lat[junction_nodes]
    progress.step(0.3)

    # surfaces: terrain, blended into the end planes over a transition
    u, v = graph.u[surf_edge], graph.v[surf_edge]
    plane_u, plane_v = has_plane[u], has_plane[v]
    seg_len = shapely.length(centre)
    trans = np.minimum(0.5 * seg_len, np.maximum(2.0 * widths[surf_edge], 3.0 * cell))

    def height(k, xy):
        """Height of points ``xy`` on street surface k: terrain, blended into the junction
        planes within ``trans`` of either end, the distance from an end measured along the
        centre line (a street that bends back past its own end, a hairpin, is not taken
        for its end there: measured along the end's direction it was, and stepped)."""
        zt = _dem_z(dem, xy)
        su = shapely.line_locate_point(centre[k], shapely.points(xy))
        sv = seg_len[k] - su
        wu = np.where(plane_u[k], np.clip(1.0 - su / trans[k], 0.0, 1.0), 0.0)
        wv = np.where(plane_v[k], np.clip(1.0 - sv / trans[k], 0.0, 1.0), 0.0)
        return zt + wu * (plane(u[k], xy) - zt) + wv * (plane(v[k], xy) - zt)

    dense = shapely.segmentize(surfaces, spacing)
    surfaces = coordinates.transform(
        shapely.force_3d(dense, 0.0),
        lambda c, i: np.column_stack([c[:, :2], height(i, c[:, :2])]), include_z=True)
    progress.step(0.7)

    # slopes along the centre line (between samples at most ``spacing`` apart) and across
    # the street (between its two edges, perpendicular to the centre line)
    xy, k = shapely.get_coordinates(shapely.segmentize(centre, spacing), return_index=True)
    z = height(k, xy)
    step = np.diff(xy, axis=0)
    ds = np.hypot(step[:, 0], step[:, 1])
    same = (k[1:] == k[:-1]) & (ds > 1e-9)
    grade = np.abs(np.diff(z))[same] / ds[same]
    lon = np.zeros(len(centre))
    np.maximum.at(lon, k[1:][same], grade)
    # direction at each sample: of the segment that starts there, the last one at the end
    dvec = np.zeros_like(xy)
    seg_dir = unit(step)
    dvec[:-1][k[1:] == k[:-1]] = seg_dir[k[1:] == k[:-1]]
    last = np.r_[k[1:] != k[:-1], True]
    dvec[last] = dvec[np.maximum(np.flatnonzero(last) - 1, 0)]
    nrm = np.column_stack([-dvec[:, 1], dvec[:, 0]])
    half = (widths[surf_edge] / 2.0)[k][:, None]
    zl = height(k, xy + half * nrm)
    zr = height(k, xy - half * nrm)
    lat_g = np.abs(zl - zr) / (2 * half[:, 0])
    lat = np.zeros(len(centre))
    np.maximum.at(lat, k, lat_g)
    s_table["slope_long_pct"] = 100 * lon
    s_table["slope_lat_pct"] = 100 * lat
    progress.step(1.0)
    return surfaces, jpolys, (height, plane, lambda xy: _dem_z(dem, xy))


def tessellate_lines(lines: Sequence, widths: Sequence[float], road_class=None, z_layer=None,
                     snap_tolerance: float = 1.0, min_dangle_length: float = 0.0,
                     progress: Optional[Progress] = None, **kwargs) -> Tessellation:
    """Clean raw centre lines (:func:`plugin.network.street_graph.clean_network`) and tessellate them.

    ``widths`` are per input line; an edge takes the width of the input line it came from.
    Other keyword arguments go to :func:`tessellate_network`.
    """
    progress = ensure(progress)
    widths = np.asarray(widths, dtype=float)
    graph = clean_network(lines, road_class=road_class, z_layer=z_layer,
                          snap_tolerance=snap_tolerance, min_dangle_length=min_dangle_length,
                          progress=progress.sub(0.0, 0.3))
    return tessellate_network(graph, widths[graph.source], progress=progress.sub(0.3, 1.0),
                              **kwargs)


def reference_area(graph: RoadGraph, widths: np.ndarray, layer: Optional[int] = None):
    """The area the tessellation must cover: the centre lines buffered by half their width,
    round at junctions and flat at dead ends (a round cap is a flat cap plus a disc at the
    end). Returns the union (one layer, or all)."""
    sel = np.ones(graph.n_edges, bool) if layer is None else graph.z_layer == layer
    deg = graph.degree
    flat = shapely.buffer(graph.geometry[sel], widths[sel] / 2.0, quad_segs=_QUAD_SEGS,
                          cap_style="flat")
    ends = np.r_[graph.u[sel], graph.v[sel]]
    w = np.r_[widths[sel], widths[sel]]
    at_junction = deg[ends] >= 2
    discs = shapely.buffer(shapely.points(graph.nodes[ends[at_junction]]),
                           w[at_junction] / 2.0, quad_segs=_QUAD_SEGS)
    return shapely.union_all(np.concatenate([flat, discs]))
