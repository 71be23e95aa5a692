"""Road rasters <-> road graphs (Hartmann thesis ch. 4.2.4, StreetGAN pre- and post-processing).

Rasterisation
    Roads are drawn as 15 px wide lines at 3 m per pixel into a binary single-channel
    image (white = road) with OpenCV ``polylines``, the thesis's training images.

Raster to graph (thesis "Road Network Post-Processing"), all on numpy / OpenCV arrays:

1. threshold the grey values (127 of 255);
2. one erosion (isolated pixels and cusps) and five dilations (gaps up to ~5 px), all with
   a 3 x 3 cross;
3. Zhang-Suen thinning (``cv2.ximgproc.thinning``) to a one-pixel skeleton;
4. a graph with one node per skeleton pixel and an edge to each skeleton pixel of its
   8-neighbourhood;
5. the artefact blocks of 0.5 px² (three mutually adjacent pixels) are removed by
   dropping their longest (diagonal, sqrt 2) edge;
6. the graph is cut into chains between nodes of degree != 2;
7. each chain is smoothed by 5 rounds of p_i <- p_(i-1)/4 + p_i/2 + p_(i+1)/4;
8. Douglas-Peucker simplification at 3 m;
9. dead-end chains of 25 m or less are removed (repeatedly, since removing one can make
   another a dead end).

The thesis left "many more dead ends" than the examples. :func:`raster_to_graph` measures a
dead end from the edge of the road it leaves to the end of the road (skeleton length plus
the road's half-width at the tip minus that at the junction, from the distance transform
of the road mask: the classic medial-axis pruning), not along the skeleton: the 25 m rule
then removes the spurs that wide generated roads and plazas sprout into the skeleton
while real side streets stay (``from_edge=False`` is the thesis's measure). Optionally
(``max_gap``) dead ends that stop short of another road are extended straight to it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence, Tuple

import numpy as np
import shapely

from ..core.geometry import pinned_ends
from ..core.progress import InputError, Progress, ensure, require

__all__ = ["rasterize_lines", "raster_to_graph", "RasterGraph", "road_mask", "skeleton", "pixel_graph",
           "chains", "smooth_chain", "merge_junction_clusters", "polygon_centre_lines",
           "CELL_SIZE", "LINE_WIDTH_PX"]

#: Thesis values: 3 m per pixel, 15 px wide roads.
CELL_SIZE = 3.0
LINE_WIDTH_PX = 15

_CROSS = None


def _cv2():
    cv2 = require("cv2", "opencv-contrib-python-headless", "OpenCV")
    if not hasattr(cv2, "ximgproc"):  # pragma: no cover
        raise InputError("OpenCV lacks the contrib module ximgproc: install "
                         "opencv-contrib-python-headless, not opencv-python")
    return cv2


def _cross():
    global _CROSS
    if _CROSS is None:
        _CROSS = _cv2().getStructuringElement(_cv2().MORPH_CROSS, (3, 3))
    return _CROSS


def polygon_centre_lines(polygon, cell_size: float = 0.25) -> np.ndarray:
    """Centre lines of a street drawn as a surface (e.g. a cul-de-sac with its turning
    head): the polygon rasterised at ``cell_size`` and read back by :func:`raster_to_graph`
    without morphology, the skeleton's spurs shorter than the polygon's mean width (from the
    edge, its corners) pruned. The lines stop about half a width short of the polygon's
    ends. Returns an array of LineStrings (empty for an empty polygon)."""
    polygon = shapely.make_valid(polygon)
    if polygon.is_empty or shapely.area(polygon) <= 0:
        return np.empty(0, dtype=object)
    x0, y0, x1, y1 = polygon.bounds
    pad = 2 * cell_size
    gt = (x0 - pad, cell_size, 0.0, y1 + pad, 0.0, -cell_size)
    image = np.zeros((int(math.ceil((y1 - y0 + 2 * pad) / cell_size)),
                      int(math.ceil((x1 - x0 + 2 * pad) / cell_size))), dtype=np.uint8)

    def pixels(ring):
        r = shapely.get_coordinates(ring)
        return np.round(np.column_stack([(r[:, 0] - gt[0]) / cell_size,
                                         (r[:, 1] - gt[3]) / gt[5]]) * 16).astype(np.int32)

    parts = [p for p in shapely.get_parts(polygon) if shapely.get_type_id(p) == 3]
    # 4 fractional bits: sub-pixel vertices; holes (a loop street's island) cut out again
    _cv2().fillPoly(image, [pixels(shapely.get_exterior_ring(p)) for p in parts], 255, shift=4)
    holes = [pixels(shapely.get_interior_ring(p, i)) for p in parts
             for i in range(shapely.get_num_interior_rings(p))]
    if holes:
        _cv2().fillPoly(image, holes, 0, shift=4)
    width = 2 * shapely.area(polygon) / max(shapely.length(polygon), 1e-9)
    return raster_to_graph(image, gt, erosions=0, dilations=0, simplify=cell_size,
                           min_dead_end=width, from_edge=True).geometry


def rasterize_lines(lines: Sequence, cell_size: float = CELL_SIZE, width_px: int = LINE_WIDTH_PX,
                    bounds: Optional[Tuple[float, float, float, float]] = None,
                    margin: float = 0.0) -> Tuple[np.ndarray, tuple]:
    """Draw road lines into a binary uint8 image (255 = road), the thesis's training image.

    Parameters
    ----------
    lines : array of LineString / MultiLineString, metric CRS
    cell_size : metres per pixel (thesis: 3)
    width_px : line width in pixels (thesis: 15)
    bounds : (xmin, ymin, xmax, ymax), default the lines' bounds grown by ``margin``

    Returns
    -------
    image : (rows, cols) uint8
    geotransform : GDAL-style (x0, cell, 0, y1, 0, -cell), north up
    """
    cv2 = _cv2()
    parts = shapely.get_parts(np.asarray(lines, dtype=object))
    parts = parts[~shapely.is_empty(parts)]
    if bounds is None:
        if len(parts) == 0:
            raise InputError("no lines to rasterise")
        x0, y0, x1, y1 = shapely.total_bounds(parts)
        x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    else:
        x0, y0, x1, y1 = bounds
    cols = max(1, int(math.ceil((x1 - x0) / cell_size)))
    rows = max(1, int(math.ceil((y1 - y0) / cell_size)))
    image = np.zeros((rows, cols), np.uint8)
    if len(parts):
        coords, index = shapely.get_coordinates(parts, return_index=True)
        # pixel coordinates with 4 fractional bits (cv2 shift) for sub-pixel accuracy
        px = np.round(np.column_stack([(coords[:, 0] - x0) / cell_size - 0.5,
                                       (y1 - coords[:, 1]) / cell_size - 0.5]) * 16).astype(np.int32)
        splits = np.flatnonzero(np.diff(index)) + 1
        # OpenCV's thick lines come out thickness + 2 px wide (odd): ask for 2 px less
        cv2.polylines(image, np.split(px, splits), False, 255, thickness=max(1, int(width_px) - 2),
                      lineType=cv2.LINE_8, shift=4)
    return image, (x0, cell_size, 0.0, y1, 0.0, -cell_size)


# --------------------------------------------------------------------------- raster -> graph

@dataclass
class RasterGraph:
    """Result of :func:`raster_to_graph`.

    Attributes
    ----------
    geometry : ndarray of LineString, planar noded street edges (map units of the geotransform)
    graph : plugin.network.street_graph.RoadGraph of the same edges (nodes, degrees)
    skeleton : (rows, cols) uint8, the thinned road pixels (255)
    stats : dict, counts per step and ``seconds`` per step
    """

    geometry: np.ndarray
    graph: object
    skeleton: np.ndarray
    stats: dict = field(default_factory=dict)


def skeleton(image: np.ndarray, threshold: float = 127.0, erosions: int = 1,
             dilations: int = 5) -> np.ndarray:
    """Threshold, 1 erosion + 5 dilations with a 3 x 3 cross, Zhang-Suen thinning (thesis)."""
    return _cv2().ximgproc.thinning(road_mask(image, threshold, erosions, dilations),
                                    thinningType=_cv2().ximgproc.THINNING_ZHANGSUEN)


def road_mask(image: np.ndarray, threshold: float = 127.0, erosions: int = 1,
              dilations: int = 5) -> np.ndarray:
    """The cleaned binary road mask (255 = road) that :func:`skeleton` thins."""
    binary = _opened(_band(image), threshold, erosions, dilations)
    # a blank border keeps the thinning and the 8-neighbourhood inside the image
    binary[[0, -1], :] = 0
    binary[:, [0, -1]] = 0
    return binary


def _band(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 2 or a.size == 0:
        raise InputError(f"the road raster must be one 2-D band, not an array of shape {a.shape}")
    return a


def _opened(a: np.ndarray, threshold: float, erosions: int, dilations: int) -> np.ndarray:
    cv2 = _cv2()
    binary = np.where(np.nan_to_num(a.astype(np.float64), nan=-np.inf) > threshold, 255, 0)
    binary = binary.astype(np.uint8)
    if erosions:
        binary = cv2.erode(binary, _cross(), iterations=int(erosions))
    if dilations:
        binary = cv2.dilate(binary, _cross(), iterations=int(dilations))
    return binary


#: Pixels per strip of :func:`mask_and_skeleton` (about 0.3 s of thinning on one core).
STRIP_PIXELS = 2_000_000
#: Rows a strip reads beyond its own on each side: thinning peels one layer per pass, so a
#: core row depends only on rows closer than the thickest road's half-width (after the
#: dilations). 128 px keeps every road up to 250 px (750 m at 3 m per pixel) exact.
STRIP_MARGIN = 128


def mask_and_skeleton(image: np.ndarray, threshold: float = 127.0, erosions: int = 1,
                      dilations: int = 5, progress: Optional[Progress] = None):
    """:func:`road_mask` and its Zhang-Suen skeleton (:func:`skeleton`), computed in strips
    of rows with a margin, so that a large raster can be canceled between strips (OpenCV's
    thinning is one uninterruptible call); the result equals the whole-image one for roads
    up to 2 x :data:`STRIP_MARGIN` pixels wide.

    >>> img = np.zeros((600, 400)); img[:, 190:210] = 255; img[290:310, :] = 255
    >>> m, s = mask_and_skeleton(img)
    >>> bool((s == skeleton(img)).all() and (m == road_mask(img)).all())
    True
    """
    progress = ensure(progress)
    a = _band(image)
    rows, cols = a.shape
    strip = max(64, STRIP_PIXELS // max(cols, 1))
    thin = _cv2().ximgproc.thinning
    mask = np.empty((rows, cols), np.uint8)
    skel = np.empty((rows, cols), np.uint8)
    for r0 in range(0, rows, strip):
        progress.step(r0 / rows)
        r1 = min(rows, r0 + strip)
        a0, a1 = max(0, r0 - STRIP_MARGIN), min(rows, r1 + STRIP_MARGIN)
        m = _opened(a[a0:a1], threshold, erosions, dilations)
        if a0 == 0:
            m[0, :] = 0
        if a1 == rows:
            m[-1, :] = 0
        m[:, [0, -1]] = 0
        s_ = thin(m, thinningType=_cv2().ximgproc.THINNING_ZHANGSUEN)
        mask[r0:r1] = m[r0 - a0:r1 - a0]
        skel[r0:r1] = s_[r0 - a0:r1 - a0]
    progress.step(1.0)
    return mask, skel


# 8-neighbourhood offsets, one per undirected pixel pair: E, SE, S, SW
_OFFSETS = ((0, 1), (1, 1), (1, 0), (1, -1))


def pixel_graph(skel: np.ndarray):
    """Pixel graph of a skeleton: nodes = skeleton pixels, edges = 8-neighbours, without the
    diagonal (longest) edge of each 0.5 px² artefact triangle (thesis, Fig. 4.14).

    Returns
    -------
    rc : (n, 2) int array of (row, col) per node
    a, b : int arrays, node indices of the edges
    n_artefacts : int, diagonal edges removed
    """
    on = np.asarray(skel) > 0
    rows, cols = on.shape
    idx = np.full(on.shape, -1, np.int64)
    rc = np.argwhere(on)
    idx[rc[:, 0], rc[:, 1]] = np.arange(len(rc))
    pad = np.zeros((rows + 2, cols + 2), bool)
    pad[1:-1, 1:-1] = on
    a_all, b_all, removed = [], [], 0
    for dr, dc in _OFFSETS:
        nb = pad[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols] & on
        if dr and dc:
            # a diagonal pair that also shares a 4-neighbour in the skeleton closes a
            # triangle of 0.5 px²: drop the diagonal (the longest edge, sqrt 2)
            corner = pad[1 + dr:1 + dr + rows, 1:1 + cols] | pad[1:1 + rows, 1 + dc:1 + dc + cols]
            removed += int((nb & corner).sum())
            nb &= ~corner
        r, c = np.nonzero(nb)
        a_all.append(idx[r, c])
        b_all.append(idx[r + dr, c + dc])
    return rc, np.concatenate(a_all), np.concatenate(b_all), removed


def chains(n: int, a: np.ndarray, b: np.ndarray, progress: Optional[Progress] = None) -> list:
    """Split a graph into chains whose end nodes have degree != 2 (and closed rings of
    degree-2 nodes, which start and end at the same node). Returns lists of node indices.

    The order is that of a walk from each end or junction in turn (by index) along each of
    its edges (by neighbour index), then the rings from their lowest node."""
    progress = ensure(progress)
    progress.step(0.0)
    nodes, offsets = _chain_nodes(n, a, b)
    progress.step(1.0)
    return [c.tolist() for c in np.split(nodes, offsets[1:-1])] if len(offsets) > 1 else []


def _chain_nodes(n: int, a: np.ndarray, b: np.ndarray):
    """The chains of :func:`chains` (same order, same direction) as one array of node
    indices and the offsets of the chains in it (n_chains + 1, the last is its length).

    Without a Python loop per node (a walk from each junction was most of the raster-to-
    graph time): the runs of degree-2 nodes are the connected components of their subgraph;
    one breadth-first search from a virtual root joined to the node where each run is
    entered puts every run's nodes in walking order (a run is a path)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    adj = csr_matrix((np.ones(2 * len(a), np.int8), (np.r_[a, b], np.r_[b, a])), shape=(n, n))
    indptr, nbrs = adj.indptr.astype(np.int64), adj.indices.astype(np.int64)
    deg = np.diff(indptr)
    row = np.repeat(np.arange(n), deg)  # the node each adjacency entry leaves
    inner = deg == 2
    in_run = inner[row] & inner[nbrs]
    _, label = connected_components(csr_matrix(
        (np.ones(int(in_run.sum()), np.int8), (row[in_run], nbrs[in_run])), shape=(n, n)),
        directed=False)

    # The walk's order: the adjacency entries that leave an end or a junction, in turn; a
    # run is walked from the first entry that reaches it, and two ends or junctions side by
    # side make a one-edge chain (once, from the lower index) ...
    from_end = ~inner[row]
    reach = np.flatnonzero(from_end & inner[nbrs])
    _, first = np.unique(label[nbrs[reach]], return_index=True)
    run_entry = reach[first]
    pair = np.flatnonzero(from_end & ~inner[nbrs] & (row < nbrs))
    # ... then the rings without a junction, by their lowest node, walked from it towards
    # its first neighbour: cutting the edge back to the lowest node makes the ring a path
    inner_nodes = np.flatnonzero(inner)
    walked = np.zeros(n, bool)
    walked[label[nbrs[run_entry]]] = True
    _, lowest = np.unique(label[inner_nodes], return_index=True)
    ring_start = np.sort(inner_nodes[lowest])
    ring_start = ring_start[~walked[label[ring_start]]]
    ring_back = nbrs[indptr[ring_start] + 1]

    # chains by walk order: key = adjacency entry, rings after all entries
    n_run, n_pair, n_ring = len(run_entry), len(pair), len(ring_start)
    key = np.r_[run_entry, pair, len(nbrs) + np.arange(n_ring)]
    rank = np.empty(len(key), np.int64)
    rank[np.argsort(key)] = np.arange(len(key))
    run_rank, pair_rank, ring_rank = np.split(rank, [n_run, n_run + n_pair])
    entry_node = np.r_[nbrs[run_entry], ring_start]  # first degree-2 node of a run or ring
    entry_rank = np.r_[run_rank, ring_rank]
    chain_of_label = np.full(n, -1, np.int64)
    chain_of_label[label[entry_node]] = entry_rank

    # run nodes in walking order: breadth-first from a root (node n) joined to each entry
    cut = np.isin(row * n + nbrs, np.r_[ring_start * n + ring_back, ring_back * n + ring_start])
    keep = in_run & ~cut
    src = np.r_[row[keep], np.full(len(entry_node), n)]
    dst = np.r_[nbrs[keep], entry_node]
    bfs = csr_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(n + 1, n + 1))
    order = breadth_first_order(bfs, n, directed=True, return_predecessors=False)[1:]
    chain = chain_of_label[label[order]]
    by_chain = np.argsort(chain, kind="stable")
    order, chain = order[by_chain], chain[by_chain]

    # chain = [start] + run + [end]: a run between ends or junctions has both, a ring only
    # ends at its first node, a one-edge chain has no run
    n_chain = len(key)
    run_size = np.bincount(chain, minlength=n_chain)
    has_head = np.ones(n_chain, bool)
    has_head[ring_rank] = False
    offsets = np.r_[0, np.cumsum(run_size + has_head + 1)]
    nodes = np.empty(offsets[-1], np.int64)
    head = np.empty(n_chain, np.int64)
    head[run_rank], head[pair_rank] = row[run_entry], row[pair]
    nodes[offsets[:-1][has_head]] = head[has_head]
    first_in_chain = np.r_[0, np.cumsum(run_size)[:-1]]
    nodes[offsets[chain] + has_head[chain] + np.arange(len(order)) - first_in_chain[chain]] = order
    tail = offsets[1:] - 1
    nodes[tail[pair_rank]] = nbrs[pair]
    nodes[tail[ring_rank]] = ring_start
    # a run leaves its last node by the neighbour it did not come from
    last, before = nodes[tail[run_rank] - 1], nodes[tail[run_rank] - 2]
    x, y = nbrs[indptr[last]], nbrs[indptr[last] + 1]
    nodes[tail[run_rank]] = np.where(x == before, y, x)
    return nodes, offsets


def smooth_chain(points: np.ndarray, iterations: int = 5) -> np.ndarray:
    """``iterations`` rounds of p_i <- p_(i-1)/4 + p_i/2 + p_(i+1)/4 on the interior points
    (thesis: 5); the end points stay where they are, so chains stay connected."""
    p = np.asarray(points, dtype=np.float64)
    return _smooth_chains(p, np.array([0, len(p)]), iterations) if len(p) >= 3 else p.copy()


def _smooth_chains(points: np.ndarray, offsets: np.ndarray, iterations: int = 5) -> np.ndarray:
    """:func:`smooth_chain` on all chains at once (``points`` of all chains one after the
    other, chain k at ``offsets[k]:offsets[k + 1]``): the same arithmetic in the same
    order, so the same floats, with the first and last point of every chain fixed."""
    p = np.asarray(points, dtype=np.float64).copy()
    fixed = np.zeros(len(p), bool)
    fixed[offsets[:-1]] = True
    fixed[offsets[1:] - 1] = True
    moves = ~fixed[1:-1, None]
    for _ in range(iterations):
        p[1:-1] = np.where(moves, 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:], p[1:-1])
    return p


def _prune_dead_ends(graph, min_length: float, allowance=None, max_rounds: int = 20):
    """Remove dead-end chains of ``min_length`` or less, merging degree-2 chains after each
    round (a removed spur can turn a junction into a bend and another chain into a spur).

    ``allowance(xy) -> lengths`` (the road's half-width at a point) measures a spur from the
    road's edge: its skeleton length + the half-width at its free end (thinning stops that
    far before the road's end) - the half-width where it leaves the network (the medial
    radius: a spur into a corner of a wide road or plaza is mostly inside the road)."""
    from ..network.street_graph import _subset, merge_degree2_chains

    removed = 0
    for _ in range(max_rounds):
        if graph.n_edges == 0:
            break
        deg = graph.degree
        dead_u, dead_v = deg[graph.u] == 1, deg[graph.v] == 1
        limit = np.full(graph.n_edges, float(min_length))
        if allowance is not None:
            # the end that is not the dead end; an isolated piece (both ends dead) gets none
            base = np.where(dead_u, graph.v, graph.u)
            tip = np.where(dead_u, graph.u, graph.v)
            extra = allowance(graph.nodes[base]) - allowance(graph.nodes[tip])
            limit += np.where(dead_u & dead_v, 0.0, extra)
        spur = (dead_u | dead_v) & (graph.length <= limit)
        if not spur.any():
            break
        removed += int(spur.sum())
        graph = _subset(graph, ~spur)
        if graph.n_edges:
            graph = merge_degree2_chains(graph)
    return graph, removed


def merge_junction_clusters(graph, distance: float):
    """Contract the short edges between junctions (both ends of degree >= 3) of a street
    graph: each cluster of junctions joined by edges of ``distance`` m or less becomes one
    node at their mean, the edges that ended there end there, the edges inside it go.

    Thinning a crossing of two wide roads seldom gives one 4-way skeleton pixel: it gives
    two 3-way nodes a few pixels apart (or a tiny loop), so the graph of a raster has almost
    no degree-4 junctions although the image shows crossings. This is the merge that
    OSMnx's ``consolidate_intersections`` makes for real networks, on the skeleton graph.

    Returns a new clean graph (``street_graph.clean_network``: moved ends that now cross a
    street are noded there, degree-2 chains merged) and the number of nodes merged away.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from ..network.street_graph import clean_network

    if graph is None or graph.n_edges == 0 or distance <= 0:
        return graph, 0
    deg = graph.degree
    short = (graph.length <= distance) & (deg[graph.u] >= 3) & (deg[graph.v] >= 3) \
        & (graph.u != graph.v)
    if not short.any():
        return graph, 0
    n = len(graph.nodes)
    adj = coo_matrix((np.ones(short.sum()), (graph.u[short], graph.v[short])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    size = np.bincount(label, minlength=n)
    centre = np.column_stack([np.bincount(label, graph.nodes[:, 0], minlength=n),
                              np.bincount(label, graph.nodes[:, 1], minlength=n)]) \
        / np.maximum(size, 1)[:, None]
    new_xy = centre[label]
    keep = label[graph.u] != label[graph.v]   # edges inside a cluster go
    keep |= (graph.u == graph.v) & (size[label[graph.u]] == 1)  # loops of single nodes stay
    geoms = graph.geometry[keep]
    u, v = graph.u[keep], graph.v[keep]
    lines = pinned_ends(geoms, new_xy[u], new_xy[v])
    lines = lines[shapely.length(lines) > 0]
    merged = int(n - len(np.unique(label[np.r_[graph.u, graph.v]]))) - \
        int(n - len(np.unique(np.r_[graph.u, graph.v])))
    if not len(lines):
        return graph, 0
    out = clean_network(lines, snap_tolerance=0.5, min_dangle_length=0.0, merge_degree2=True)
    return out, max(merged, 0)


def _join_gaps(lines: np.ndarray, max_gap: float) -> np.ndarray:
    """Extend each dead end straight ahead by up to ``max_gap`` to the first road it meets:
    the generator often stops a street a few pixels short of the next one."""
    from ..network.street_graph import graph_from_lines

    n = len(lines)
    g = graph_from_lines(lines, [None] * n, [None] * n, np.zeros(n, int), np.arange(n),
                         snap_tolerance=0.5)
    deg = g.degree
    tree = shapely.STRtree(g.geometry)
    new = []
    for e in range(g.n_edges):
        coords = shapely.get_coordinates(g.geometry[e])
        for node, end, inner in ((g.u[e], coords[0], coords[1:]), (g.v[e], coords[-1], coords[-2::-1])):
            if deg[node] != 1:
                continue
            # direction of the last ~10 m of the street
            d = np.cumsum(np.linalg.norm(np.diff(np.vstack([end, inner]), axis=0), axis=1))
            k = min(int(np.searchsorted(d, 10.0)), len(inner) - 1)
            vec = end - inner[k]
            norm = np.hypot(*vec)
            if norm == 0:
                continue
            ray = shapely.LineString([end, end + vec / norm * max_gap])
            hits = tree.query(ray, predicate="intersects")
            hits = hits[hits != e]
            if len(hits) == 0:
                continue
            pts = shapely.intersection(g.geometry[hits], ray)
            dist = shapely.distance(shapely.Point(end), pts)
            best = pts[int(np.argmin(dist))]
            target = shapely.get_coordinates(best)
            target = target[np.argmin(np.linalg.norm(target - end, axis=1))]
            if np.linalg.norm(target - end) > 1e-6:
                new.append(shapely.LineString([end, target]))
    return np.concatenate([lines, np.asarray(new, dtype=object)]) if new else lines


def raster_to_graph(image: np.ndarray, geotransform=(0.0, 1.0, 0.0, 0.0, 0.0, -1.0), *,
                    threshold: float = 127.0, erosions: int = 1, dilations: int = 5,
                    smoothing: int = 5, simplify: float = 3.0, min_dead_end: float = 25.0,
                    max_gap: float = 0.0, from_edge: bool = True,
                    merge_junctions: float = 0.0,
                    progress: Optional[Progress] = None) -> RasterGraph:
    """Extract a clean planar road graph from a road raster (thesis ch. 4.2.4).

    Parameters
    ----------
    image : (rows, cols) array, roads brighter than ``threshold`` (e.g. a generator's
        image mapped to 0 .. 255, or any road mask)
    geotransform : GDAL-style (x0, dx, 0, y0, 0, dy), north up; lengths in its units (m)
    threshold : grey value above which a pixel is road (thesis: 127)
    erosions, dilations : morphology with a 3 x 3 cross (thesis: 1 and 5)
    smoothing : rounds of (1/4, 1/2, 1/4) averaging of the chains (thesis: 5)
    simplify : Douglas-Peucker tolerance in map units (thesis: 3 m)
    min_dead_end : dead-end chains this long or shorter are removed (thesis: 25 m)
    from_edge : measure a dead end from the edge of the road it leaves, not from the
        skeleton's junction (half a road width, ~22 m for 15 px at 3 m, inside the road),
        and to the road's end, not to the skeleton's end (thinning stops half a width
        short): wide generated roads and plazas sprout skeleton spurs that are longer than
        25 m but stick out of the road by less. False: the thesis's skeleton lengths.
    max_gap : extend dead ends straight ahead by up to this to meet a road (0: off,
        the thesis's method)
    merge_junctions : junctions joined by an edge this short (map units) become one node
        (:func:`merge_junction_clusters`; 0: off, the thesis's method)
    progress : Progress, optional

    Returns
    -------
    RasterGraph (empty geometry when the raster has no road)

    References
    ----------
    Hartmann, thesis ch. 4.2.4 "Road Network Post-Processing"; Zhang & Suen 1984.
    """
    from ..network.street_graph import clean_network

    progress = ensure(progress)
    gt = tuple(float(v) for v in geotransform)
    if len(gt) != 6 or gt[2] != 0 or gt[4] != 0 or gt[1] == 0 or gt[5] == 0:
        raise InputError("the road raster must be a north-up grid without rotation")
    for name, v in (("simplify", simplify), ("min_dead_end", min_dead_end), ("max_gap", max_gap)):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be a non-negative number, not {v}")
    times, stats = {}, {}
    t = time.perf_counter()
    mask, skel = mask_and_skeleton(image, threshold, erosions, dilations,
                                   progress.sub(0.0, 0.2))
    times["skeleton"] = time.perf_counter() - t

    t = time.perf_counter()
    rc, a, b, stats["artefact_edges"] = pixel_graph(skel)
    stats["skeleton_pixels"] = len(rc)
    progress.step(0.2)
    nodes, offsets = _chain_nodes(len(rc), a, b) if len(rc) else \
        (np.empty(0, np.int64), np.zeros(1, np.int64))
    times["graph"] = time.perf_counter() - t
    progress.step(0.4)

    t = time.perf_counter()
    stats["chains"] = len(offsets) - 1
    if len(nodes):
        p = rc[nodes]
        # pixel centres -> map coordinates
        xy = np.column_stack([gt[0] + (p[:, 1] + 0.5) * gt[1], gt[3] + (p[:, 0] + 0.5) * gt[5]])
        chain_of_point = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
        geoms = shapely.linestrings(_smooth_chains(xy, offsets, smoothing),
                                    indices=chain_of_point)
    else:
        geoms = np.empty(0, dtype=object)
    if len(geoms):
        geoms = shapely.simplify(geoms, simplify, preserve_topology=False) if simplify else geoms
        geoms = geoms[shapely.length(geoms) > 0]
    times["smooth_simplify"] = time.perf_counter() - t
    progress.step(0.6)

    t = time.perf_counter()
    graph = None
    if len(geoms):
        if max_gap > 0:
            geoms = _join_gaps(geoms, max_gap)
        # node what smoothing made cross near junctions, snap, drop duplicates, merge bends
        graph = clean_network(geoms, snap_tolerance=min(1.0, abs(gt[1]) / 2),
                              min_dangle_length=0.0, merge_degree2=True,
                              progress=progress.sub(0.6, 0.9))
        # half-width of the road (distance to its edge) at a point, for the dead-end measure
        half = _cv2().distanceTransform(mask, _cv2().DIST_L2, 3) * abs(gt[1]) if from_edge else None

        def half_width(xy):
            c = np.clip(((xy[:, 0] - gt[0]) / gt[1]).astype(int), 0, mask.shape[1] - 1)
            r = np.clip(((xy[:, 1] - gt[3]) / gt[5]).astype(int), 0, mask.shape[0] - 1)
            return half[r, c]
        graph, stats["dead_ends_removed"] = _prune_dead_ends(
            graph, min_dead_end, half_width if from_edge else None)
        if merge_junctions > 0 and graph.n_edges:
            graph, stats["junctions_merged"] = merge_junction_clusters(graph, merge_junctions)
        if graph.n_edges:
            graph.geometry[:] = shapely.simplify(graph.geometry, simplify) if simplify \
                else graph.geometry
    times["clean"] = time.perf_counter() - t
    progress.step(1.0)
    out = graph.geometry if graph is not None else np.empty(0, dtype=object)
    stats["edges"] = len(out)
    stats["seconds"] = {k: round(v, 4) for k, v in times.items()}
    stats["seconds"]["total"] = round(sum(times.values()), 4)
    return RasterGraph(out, graph, skel, stats)
