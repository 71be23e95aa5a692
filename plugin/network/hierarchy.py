"""Street hierarchy: continuous streets, stream-order levels and attributed intersections.

- Continuous streets ("strokes"): at every intersection the incident edges are paired by the
  straightest continuation (deflection under a threshold, same name and class preferred),
  and paired edges form one street. This is the street notion of Aliaga et al. 2008
  (sec. 3.1.1: only two streets pass through an intersection point) and of the thesis's
  stream ordering, which labels whole streets.
- Levels (Hartmann thesis ch. 4.1.2; Aliaga et al. 2008 sec. 5): level 0 = arterials, from
  OSM classes where present, else the longest / straightest streets; every street that
  meets a street of level k and has no level yet gets level k + 1 (Gravelius / Horton
  stream order, Holton 1994). The street graph is not a tree, so the propagation is a
  multi-source breadth-first search on the street adjacency graph: a loop simply reaches
  a street from two sides and the first (lowest) label wins.
- Attributed intersection points (Aliaga et al. 2008 sec. 3.1.1 and 5): for each node the
  two most important streets through it with their levels h_a, h_b, average tortuosity
  t_a, t_b, and the mean / variance of the distance between consecutive intersections and
  of the angle between consecutive segments; plus the mean area of the blocks (or parcels)
  around it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import pandas as pd
import shapely
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from ..core.progress import InputError, Progress, ensure
from .street_graph import ARTERIAL_CLASSES, RoadGraph, class_rank

__all__ = ["METHODS", "Streets", "build_streets", "assign_levels", "intersection_attributes",
           "road_hierarchy", "Hierarchy"]

METHODS = ("osm", "topological", "both")
_PROBE = 10.0  # metres along an edge used for its direction at a node


@dataclass
class Streets:
    """Continuous streets of a :class:`RoadGraph`.

    street_id : per edge, the street it belongs to (0..n-1)
    length, straightness, rank : per street; straightness = end-to-end distance / length
    turn_street, turn_angle : one sample per pairing of two edges at a node (degrees)
    """

    street_id: np.ndarray
    length: np.ndarray
    straightness: np.ndarray
    rank: np.ndarray
    road_class: np.ndarray
    turn_street: np.ndarray
    turn_angle: np.ndarray

    @property
    def n(self) -> int:
        return len(self.length)


def _incidences(graph: RoadGraph):
    """Per edge end: node, edge, local direction away from the node and chord direction."""
    geoms, lengths = graph.geometry, graph.length
    m = graph.n_edges
    d = np.minimum(_PROBE, lengths / 2.0)
    start = graph.nodes[graph.u]
    end = graph.nodes[graph.v]
    near_start = shapely.get_coordinates(shapely.line_interpolate_point(geoms, d))
    near_end = shapely.get_coordinates(shapely.line_interpolate_point(geoms, lengths - d))
    local = np.vstack([near_start - start, near_end - end])
    chord = np.vstack([end - start, start - end])
    node = np.concatenate([graph.u, graph.v])
    edge = np.concatenate([np.arange(m), np.arange(m)])
    ang = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
    chord_ang = np.degrees(np.arctan2(chord[:, 1], chord[:, 0]))
    return node, edge, ang, chord_ang


def _deflection(a, b):
    """Deflection (degrees) of continuing through a node from direction a to b.

    a and b point away from the node; going straight through means b = a + 180.
    """
    diff = np.abs((a - b + 180.0) % 360.0 - 180.0)  # angle between the two outgoing vectors
    return 180.0 - diff


def build_streets(graph: RoadGraph, max_deflection: float = 45.0,
                  name_penalty: float = 30.0, rank_penalty: float = 8.0,
                  separate_classes: Optional[Sequence[str]] = None,
                  progress: Optional[Progress] = None) -> Streets:
    """Group edges into continuous streets by greedy best-continuation pairing at nodes.

    Parameters
    ----------
    graph : RoadGraph
    max_deflection : float
        Largest deflection (degrees) at which two edges still continue one street.
    name_penalty, rank_penalty : float
        Added to the deflection when the names differ / per class rank step, so that a named
        street continues under its name where possible.
    """
    progress = ensure(progress)
    m = graph.n_edges
    node, edge, ang, chord_ang = _incidences(graph)
    names = graph.name
    ranks = graph.class_rank
    sep = set(separate_classes or ())
    in_sep = np.array([c in sep for c in graph.road_class], dtype=bool)
    order = np.argsort(node, kind="stable")
    node_s, edge_s, ang_s, chord_s = node[order], edge[order], ang[order], chord_ang[order]
    bounds = np.flatnonzero(np.r_[True, node_s[1:] != node_s[:-1], True])
    pairs_a, pairs_b, turns = [], [], []
    n_groups = len(bounds) - 1
    for k in range(n_groups):
        s, e = bounds[k], bounds[k + 1]
        deg = e - s
        if deg < 2:
            continue
        if k % 2000 == 0:
            progress.step(k / n_groups)
        es, angs, chords = edge_s[s:e], ang_s[s:e], chord_s[s:e]
        if deg == 2:
            cand = [(0, 1)]
        else:
            cand = [(i, j) for i in range(deg) for j in range(i + 1, deg)]
        costs = []
        for i, j in cand:
            ei, ej = es[i], es[j]
            if ei == ej or in_sep[ei] != in_sep[ej]:  # self-loop ends; arterial class ends
                continue
            defl = _deflection(angs[i], angs[j])
            if defl > max_deflection:
                continue
            cost = defl
            if names[ei] and names[ej] and names[ei] != names[ej]:
                cost += name_penalty
            cost += rank_penalty * abs(int(ranks[ei]) - int(ranks[ej]))
            costs.append((cost, i, j))
        costs.sort()
        used = set()
        for _, i, j in costs:
            if i in used or j in used:
                continue
            used.update((i, j))
            pairs_a.append(es[i])
            pairs_b.append(es[j])
            turns.append(_deflection(chords[i], chords[j]))
    pa, pb = np.asarray(pairs_a, dtype=np.int64), np.asarray(pairs_b, dtype=np.int64)
    adj = coo_matrix((np.ones(len(pa)), (pa, pb)), shape=(m, m))
    n_streets, street_id = connected_components(adj, directed=False)
    lengths = graph.length
    street_len = np.bincount(street_id, lengths, minlength=n_streets)
    # dominant class: the class of the longest edge of the street
    o = np.lexsort((-lengths, street_id))
    first = o[np.r_[True, street_id[o][1:] != street_id[o][:-1]]]
    dom_class = np.empty(n_streets, dtype=object)
    dom_class[street_id[first]] = graph.road_class[first]
    dom_rank = np.array([class_rank(c) for c in dom_class], dtype=np.int64)
    straight = _street_straightness(graph, street_id, n_streets, street_len)
    turn_street = street_id[pa] if len(pa) else np.zeros(0, dtype=np.int64)
    progress.step(1.0)
    return Streets(street_id, street_len, straight, dom_rank, dom_class, turn_street,
                   np.asarray(turns, dtype=float))


def _street_straightness(graph, street_id, n_streets, street_len):
    """End-to-end distance / length of each street (0 for closed streets)."""
    n_nodes = len(graph.nodes)
    keys = np.concatenate([street_id * n_nodes + graph.u, street_id * n_nodes + graph.v])
    uniq, counts = np.unique(keys, return_counts=True)
    ends = uniq[counts % 2 == 1]
    s_of_end = ends // n_nodes
    node_of_end = ends % n_nodes
    straight = np.zeros(n_streets)
    o = np.argsort(s_of_end, kind="stable")
    s_sorted, n_sorted = s_of_end[o], node_of_end[o]
    starts = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    cnt = np.diff(np.r_[starts, len(s_sorted)])
    ok = cnt == 2  # a simple path has exactly two ends
    sa = starts[ok]
    d = np.linalg.norm(graph.nodes[n_sorted[sa]] - graph.nodes[n_sorted[sa + 1]], axis=1)
    sid = s_sorted[sa]
    straight[sid] = np.where(street_len[sid] > 0, d / np.maximum(street_len[sid], 1e-9), 0.0)
    return np.clip(straight, 0.0, 1.0)


def _street_adjacency(graph: RoadGraph, street_id: np.ndarray, n_streets: int) -> csr_matrix:
    """Streets that share a node (incidence matrix times its transpose)."""
    n_nodes = len(graph.nodes)
    rows = np.concatenate([street_id, street_id])
    cols = np.concatenate([graph.u, graph.v])
    inc = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_streets, n_nodes))
    inc.data[:] = 1.0
    adj = (inc @ inc.T).tocsr()
    adj.setdiag(0)
    adj.eliminate_zeros()
    adj.data[:] = 1.0
    return adj


def assign_levels(graph: RoadGraph, streets: Streets, method: str = "both",
                  arterial_classes: Sequence[str] = ARTERIAL_CLASSES,
                  arterial_share: float = 0.1, progress: Optional[Progress] = None):
    """Stream-order street levels (0 = arterial) with loops handled.

    Parameters
    ----------
    method : 'osm' | 'topological' | 'both'
        osm: arterials are streets whose (dominant) class is in ``arterial_classes``;
        topological: the longest / straightest streets (length x straightness) making up
        ``arterial_share`` of the total street length; both: OSM classes where a connected
        part of the network has them, the topological choice elsewhere.
    arterial_share : float
        Share of the street length taken as arterials by the topological choice.

    Returns
    -------
    level : int array per street
    seed_method : str array per street ('osm', 'topological', 'component' or '')

    References
    ----------
    Hartmann thesis ch. 4.1.2 (stream order after Holton 1994, adapted to loops);
    Aliaga et al. 2008 sec. 5 ("a small percentage of the longest and widest streets").
    """
    progress = ensure(progress)
    if method not in METHODS:
        raise InputError(f"unknown hierarchy method {method!r} (use one of {', '.join(METHODS)})")
    if not 0.0 < arterial_share <= 1.0:
        raise InputError(f"the arterial share must be in (0, 1], got {arterial_share}")
    n = streets.n
    adj = _street_adjacency(graph, streets.street_id, n)
    n_comp, comp = connected_components(adj, directed=False)
    art = set(arterial_classes)
    is_osm_art = np.array([c is not None and c in art for c in streets.road_class], dtype=bool)
    score = streets.length * np.maximum(streets.straightness, 0.05)

    def topological_seeds(mask):
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return idx
        o = idx[np.argsort(-score[idx], kind="stable")]
        cum = np.cumsum(streets.length[o])
        k = int(np.searchsorted(cum, arterial_share * cum[-1])) + 1
        return o[:k]

    seed_kind = np.full(n, "", dtype=object)
    if method == "osm":
        seeds = np.flatnonzero(is_osm_art)
        seed_kind[seeds] = "osm"
    elif method == "topological":
        seeds = topological_seeds(np.ones(n, dtype=bool))
        seed_kind[seeds] = "topological"
    else:
        comp_has_art = np.bincount(comp, is_osm_art.astype(float), minlength=n_comp) > 0
        osm_seeds = np.flatnonzero(is_osm_art)
        topo_seeds = topological_seeds(~comp_has_art[comp])
        seed_kind[osm_seeds] = "osm"
        seed_kind[topo_seeds] = "topological"
        seeds = np.concatenate([osm_seeds, topo_seeds])
    if len(seeds) == 0 and method == "osm":
        progress.info("No street has an arterial OSM class: arterials chosen topologically "
                      "(longest / straightest streets).")
        seeds = topological_seeds(np.ones(n, dtype=bool))
        seed_kind[seeds] = "topological"
    progress.step(0.3)
    level = np.full(n, -1, dtype=np.int64)
    if len(seeds):
        dist = dijkstra(adj, directed=False, indices=seeds, unweighted=True, min_only=True)
        reached = np.isfinite(dist)
        level[reached] = dist[reached].astype(np.int64)
    # parts of the network that no arterial reaches: their best street starts at level 1
    missing = level < 0
    if missing.any():
        comps = np.unique(comp[missing])
        extra = []
        for c in comps:
            members = np.flatnonzero(comp == c)
            extra.append(members[np.argmax(score[members])])
        extra = np.asarray(extra)
        seed_kind[extra] = "component"
        dist = dijkstra(adj, directed=False, indices=extra, unweighted=True, min_only=True)
        fill = missing & np.isfinite(dist)
        level[fill] = dist[fill].astype(np.int64) + 1
        progress.info(f"{len(extra)} part{'s' if len(extra) > 1 else ''} of the network "
                      f"{'are' if len(extra) > 1 else 'is'} not connected to an arterial; "
                      f"{'their' if len(extra) > 1 else 'its'} longest street starts at "
                      "level 1.")
    progress.step(1.0)
    return level, seed_kind


def intersection_attributes(graph: RoadGraph, streets: Streets, street_level: np.ndarray,
                            parcels: Optional[np.ndarray] = None, parcel_radius: float = 100.0,
                            min_block_area: float = 50.0) -> pd.DataFrame:
    """Aliaga et al. 2008 attributes of every node (intersections and street ends).

    Returns a DataFrame with one row per node: node_id, x, y, degree, street_a, street_b,
    level_a, level_b, tortuosity_a/b, dist_mean_a/b, dist_var_a/b, angle_mean_a/b,
    angle_var_a/b (degrees), block_area (mean area of the faces around the node) and
    parcel_area (mean area of parcels within ``parcel_radius``, when parcels are given).
    Street a is the more important of the two (lower level, then longer).
    """
    n_nodes = len(graph.nodes)
    sid = streets.street_id
    ns = streets.n
    lengths = graph.length
    chord = np.linalg.norm(graph.nodes[graph.v] - graph.nodes[graph.u], axis=1)
    # per-street statistics (Aliaga sec. 3.1.1 (ii) and (iv))
    valid = chord > 1e-6
    # node coordinates are rounded to the millimetre: clip the ratio at its definition's 1
    tort = np.where(valid, np.maximum(lengths / np.maximum(chord, 1e-9), 1.0), np.nan)
    cnt = np.bincount(sid[valid], minlength=ns).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        tort_mean = np.bincount(sid[valid], tort[valid], minlength=ns) / cnt
        d_mean = np.bincount(sid[valid], chord[valid], minlength=ns) / cnt
        d_var = np.bincount(sid[valid], chord[valid] ** 2, minlength=ns) / cnt - d_mean ** 2
        tc = np.bincount(streets.turn_street, minlength=ns).astype(float)
        a_mean = np.bincount(streets.turn_street, streets.turn_angle, minlength=ns) / tc
        a_var = np.bincount(streets.turn_street, streets.turn_angle ** 2, minlength=ns) / tc - a_mean ** 2
    d_var = np.maximum(d_var, 0.0)
    a_var = np.maximum(a_var, 0.0)

    # the two most important streets through each node
    node = np.concatenate([graph.u, graph.v])
    st = np.concatenate([sid, sid])
    key = np.unique(node * ns + st)
    node_k, st_k = key // ns, key % ns
    order = np.lexsort((-streets.length[st_k], street_level[st_k], node_k))
    node_k, st_k = node_k[order], st_k[order]
    first = np.r_[True, node_k[1:] != node_k[:-1]]
    rank_in_node = np.arange(len(node_k)) - np.maximum.accumulate(np.where(first, np.arange(len(node_k)), 0))
    street_a = np.full(n_nodes, -1, dtype=np.int64)
    street_b = np.full(n_nodes, -1, dtype=np.int64)
    street_a[node_k[rank_in_node == 0]] = st_k[rank_in_node == 0]
    street_b[node_k[rank_in_node == 1]] = st_k[rank_in_node == 1]

    def per_node(values, s):
        out = np.full(n_nodes, np.nan)
        ok = s >= 0
        out[ok] = values[s[ok]]
        return out

    df = pd.DataFrame({
        "node_id": np.arange(n_nodes),
        "x": graph.nodes[:, 0], "y": graph.nodes[:, 1],
        "degree": graph.degree,
        "street_a": street_a, "street_b": np.where(street_b >= 0, street_b, None),
        "level_a": per_node(street_level.astype(float), street_a),
        "level_b": per_node(street_level.astype(float), street_b),
        "tortuosity_a": per_node(tort_mean, street_a), "tortuosity_b": per_node(tort_mean, street_b),
        "dist_mean_a": per_node(d_mean, street_a), "dist_var_a": per_node(d_var, street_a),
        "dist_mean_b": per_node(d_mean, street_b), "dist_var_b": per_node(d_var, street_b),
        "angle_mean_a": per_node(a_mean, street_a), "angle_var_a": per_node(a_var, street_a),
        "angle_mean_b": per_node(a_mean, street_b), "angle_var_b": per_node(a_var, street_b),
    })
    points = shapely.points(graph.nodes)
    # mean area of the faces (blocks) around each node (Aliaga's a(v_i) without parcels)
    faces = shapely.get_parts(shapely.polygonize(graph.geometry))
    faces = faces[shapely.area(faces) >= min_block_area]
    df["block_area"] = _mean_area_near(points, faces, None)
    if parcels is not None and len(parcels):
        df["parcel_area"] = _mean_area_near(points, np.asarray(parcels, dtype=object), parcel_radius)
    return df


def _mean_area_near(points, polygons, radius):
    out = np.full(len(points), np.nan)
    if len(polygons) == 0:
        return out
    tree = shapely.STRtree(polygons)
    if radius is None:
        pi, gi = tree.query(points, predicate="intersects")
    else:
        pi, gi = tree.query(points, predicate="dwithin", distance=radius)
    if len(pi) == 0:
        return out
    areas = shapely.area(polygons)
    cnt = np.bincount(pi, minlength=len(points))
    tot = np.bincount(pi, areas[gi], minlength=len(points))
    ok = cnt > 0
    out[ok] = tot[ok] / cnt[ok]
    return out


@dataclass
class Hierarchy:
    graph: RoadGraph
    streets: Streets
    street_level: np.ndarray
    seed_kind: np.ndarray

    @property
    def edge_level(self) -> np.ndarray:
        return self.street_level[self.streets.street_id]

    def roads_table(self) -> pd.DataFrame:
        g = self.graph
        chord = np.linalg.norm(g.nodes[g.v] - g.nodes[g.u], axis=1)
        length = g.length
        return pd.DataFrame({
            "edge_id": np.arange(g.n_edges),
            "level": self.edge_level,
            "road_class": g.road_class,
            "length_m": length,
            "street_id": self.streets.street_id,
            "name": g.name,
            "osm_layer": g.z_layer,
            "node_from": g.u,
            "node_to": g.v,
            "tortuosity": np.where(chord > 1e-6, np.maximum(length / np.maximum(chord, 1e-9), 1.0),
                                   np.nan),
            "arterial_source": self.seed_kind[self.streets.street_id],
        })


def road_hierarchy(graph: RoadGraph, method: str = "both",
                   arterial_classes: Sequence[str] = ARTERIAL_CLASSES,
                   arterial_share: float = 0.1, max_deflection: float = 45.0,
                   progress: Optional[Progress] = None) -> Hierarchy:
    """Streets and stream-order levels of a clean road graph (see module docstring)."""
    progress = ensure(progress)
    separate = arterial_classes if method in ("osm", "both") else None
    streets = build_streets(graph, max_deflection=max_deflection, separate_classes=separate,
                            progress=progress.sub(0.0, 0.6))
    level, seed_kind = assign_levels(graph, streets, method, arterial_classes, arterial_share,
                                     progress=progress.sub(0.6, 1.0))
    return Hierarchy(graph, streets, level, seed_kind)
