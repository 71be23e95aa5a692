"""Global optimisation of the road mesh (Yang et al. 2013, sec. 6).

The streets made by splitting are moved to minimise

    f(V) = w_s f_shape + w_f f_fair + w_c f_close          (w = 1, 0.8, 0.2)

* f_shape (regularity, eq. 4-5): every block is fitted by a *strip*, its two long sides
  an offset pair at the block's preferred width (the gross depth of its template); a road
  vertex on one long side prefers the point at that width from the opposite side; with
  several incident blocks the preferred positions are averaged with equal weights;
* f_fair (eq. 6): squared second differences along each road;
* f_close (eq. 7): squared distance to the original vertices.

Each iteration re-fits the strips to the current blocks and solves the quadratic energy as
one sparse linear system (scipy; the paper uses CHOLMOD), 10 iterations. Vertices on the
region boundary and on key roads are fixed (the paper lets boundary junctions slide; here
they stay, a simplification); T-junctions between new streets move with their host
street. An iteration that would change the block structure (a street crossing another)
is undone and the optimisation stops.

Nothing here imports QGIS.

References
----------
Yang et al. (2013), sec. 6, eq. (3)-(7), Fig. 8-10.
"""
from __future__ import annotations

from typing import Callable, Sequence, Tuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import shapely
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .templates import region_frame

__all__ = ["WEIGHTS", "ITERATIONS", "optimise_roads", "faces_of"]

#: (w_shape, w_fair, w_close) of eq. (3).
WEIGHTS = (1.0, 0.8, 0.2)
#: Fixed number of iterations (the paper: 10).
ITERATIONS = 10

_ON = 0.05  # m: a vertex this close to a block side lies on it


def faces_of(lines: Sequence) -> np.ndarray:
    """Faces of the arrangement of lines (noded), as polygons."""
    noded = shapely.union_all(np.asarray(lines, dtype=object))
    return shapely.get_parts(shapely.polygonize(shapely.get_parts(noded)))


def _build_vertices(free: Sequence, fixed_union, spacing: float):
    """Shared vertex array and the index sequence of every free road.

    An end of a road on another free road (a T-junction) becomes a vertex of that road, so
    that the junction moves with its host.
    """
    free = list(free)
    params = [list(np.linspace(0, 1, max(2, int(np.ceil(g.length / spacing)) + 1)))
              for g in free]
    extra = [[] for _ in free]
    for a, line in enumerate(free):
        xy = shapely.get_coordinates(line)
        for end in (xy[0], xy[-1]):
            pt = shapely.Point(end)
            if shapely.distance(fixed_union, pt) < 1e-3:
                continue
            for b, host in enumerate(free):
                if b != a and host.distance(pt) < 1e-3:
                    extra[b].append((host.project(pt, normalized=True), end))
                    break
    seqs = []
    for g, ts, ex in zip(free, params, extra):
        pts = shapely.get_coordinates(shapely.line_interpolate_point(g, ts, normalized=True))
        t_all = list(ts) + [t for t, _ in ex]
        p_all = list(pts) + [e for _, e in ex]
        order = np.argsort(t_all, kind="stable")
        xy = np.asarray([p_all[i] for i in order])
        t_sorted = np.asarray(t_all)[order]
        inserted = np.r_[np.zeros(len(ts), bool), np.ones(len(ex), bool)][order]
        # drop resampled points (not junctions, not the ends) next to an inserted junction
        keep = np.ones(len(xy), dtype=bool)
        for t, _ in ex:
            close = (np.abs(t_sorted - t) * g.length < 0.25 * spacing) & ~inserted
            close[[0, -1]] = False
            keep &= ~close
        seqs.append(xy[keep])
    # vertices closer than a millimetre are one vertex (junctions of several streets)
    allpts = np.concatenate(seqs)
    pairs = cKDTree(allpts).query_pairs(1e-3, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                          shape=(len(allpts), len(allpts)))
    _, label = connected_components(graph, directed=False)
    _, first, label = np.unique(label, return_index=True, return_inverse=True)
    verts = allpts[first]
    index_seqs = []
    offset = 0
    for xy in seqs:
        idx = label[offset:offset + len(xy)]
        offset += len(xy)
        keep = np.r_[True, idx[1:] != idx[:-1]]
        index_seqs.append(idx[keep])
    verts = np.asarray(verts, dtype=float)
    fixed = shapely.distance(fixed_union, shapely.points(verts)) < 1e-3
    return verts, index_seqs, fixed


def optimise_roads(free: Sequence, fixed_lines: Sequence,
                   face_width: Callable[[shapely.Geometry], float], spacing: float,
                   weights: Tuple[float, float, float] = WEIGHTS,
                   iterations: int = ITERATIONS):
    """Optimise the free streets (see module doc).

    Parameters
    ----------
    free : LineStrings
        Streets that may move (made by splitting).
    fixed_lines : LineStrings
        Region boundary and key roads.
    face_width : callable(block polygon) -> float
        Preferred centre-line width of a block (nan: no strip target).
    spacing : float
        Vertex spacing of the resampled streets (m).

    Returns
    -------
    lines : list of LineString
    stats : dict
        ``iterations`` done, ``energy`` before / after (shape term, m²), ``reverted``.
    """
    free = list(free)
    if not free:
        return free, {"iterations": 0, "shape_before": 0.0, "shape_after": 0.0, "reverted": False}
    fixed_union = shapely.union_all(np.asarray(fixed_lines, dtype=object))
    verts, seqs, fixed = _build_vertices(free, fixed_union, spacing)
    v0 = verts.copy()
    n = len(verts)
    ws, wf, wc = weights
    # fairness operator D: one row per interior vertex of every road
    rows, cols, vals = [], [], []
    r = 0
    for seq in seqs:
        for k in range(1, len(seq) - 1):
            rows += [r, r, r]
            cols += [seq[k - 1], seq[k], seq[k + 1]]
            vals += [1.0, -2.0, 1.0]
            r += 1
    dmat = sp.csr_matrix((vals, (rows, cols)), shape=(max(r, 1), n))
    fair = (dmat.T @ dmat).tocsr()
    free_idx = np.flatnonzero(~fixed)
    fix_idx = np.flatnonzero(fixed)

    def lines_of(v):
        return [shapely.LineString(v[s]) for s in seqs]

    base_faces = faces_of(list(fixed_lines) + lines_of(verts))
    n_faces = len(base_faces)
    shape_before = None
    done, reverted = 0, False
    faces = base_faces
    for _ in range(iterations):
        target, has, err = _strip_targets(verts, faces, face_width)
        if shape_before is None:
            shape_before = err
        a = ws * sp.diags(has.astype(float)) + wf * fair + wc * sp.identity(n)
        a = a.tocsr()
        new = verts.copy()
        if len(free_idx):
            aff = a[free_idx][:, free_idx].tocsc()
            afc = a[free_idx][:, fix_idx]
            solve = spla.factorized(aff)
            for dim in (0, 1):
                b = ws * has * target[:, dim] + wc * v0[:, dim]
                rhs = b[free_idx] - afc @ verts[fix_idx, dim]
                new[free_idx, dim] = solve(rhs)
        # a step that changes the block structure is halved (up to 4 times), else undone
        for _half in range(5):
            cand = lines_of(new)
            if all(shapely.is_simple(g) for g in cand):
                new_faces = faces_of(list(fixed_lines) + cand)
                if len(new_faces) == n_faces:
                    break
            new = 0.5 * (new + verts)
        else:
            reverted = True
            break
        verts = new
        faces = new_faces
        done += 1
    _, _, shape_after = _strip_targets(verts, faces, face_width)
    return lines_of(verts), {"iterations": done, "shape_before": float(shape_before or 0.0),
                             "shape_after": float(shape_after), "reverted": reverted}


def _strip_targets(verts: np.ndarray, faces: np.ndarray, face_width):
    """Preferred position of every vertex from the strips fitted to its blocks."""
    n = len(verts)
    acc = np.zeros((n, 2))
    cnt = np.zeros(n)
    pts = shapely.points(verts)
    bounds = shapely.bounds(faces)
    for face, (x0, y0, x1, y1) in zip(faces, bounds):
        # only the vertices in the face's bounding box can lie on its sides
        cand = np.flatnonzero((verts[:, 0] >= x0 - 1) & (verts[:, 0] <= x1 + 1) &
                              (verts[:, 1] >= y0 - 1) & (verts[:, 1] <= y1 + 1))
        if len(cand) == 0:
            continue
        width = face_width(face)
        if not np.isfinite(width) or width <= 0:
            continue
        frame = region_frame(face)
        if frame is None:
            continue
        c1, c2 = shapely.LineString(frame[0]), shapely.LineString(frame[1])
        for side, other in ((c1, c2), (c2, c1)):
            on = cand[shapely.distance(side, pts[cand]) < _ON]
            if len(on) == 0:
                continue
            p = verts[on]
            q = shapely.get_coordinates(shapely.line_interpolate_point(
                other, shapely.line_locate_point(other, shapely.points(p))))
            d = p - q
            dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            acc[on] += q + d / dist[:, None] * width
            cnt[on] += 1
    has = cnt > 0
    target = verts.copy()
    target[has] = acc[has] / cnt[has, None]
    err = float(((verts - target) ** 2).sum())
    return target, has, err
