"""Global optimisation of the road mesh (Yang et al. 2013, sec. 6).

The streets made by splitting are moved to minimise

    f(V) = w_s f_shape + w_f f_fair + w_c f_close          (w = 1, 0.8, 0.2)

* f_shape (regularity, eq. 4-5): every block is fitted by a *strip*, its two long sides
  an offset pair at the block's preferred width (the gross depth of its template); a road
  vertex on one long side prefers the point at that width from the opposite side; with
  several incident blocks the preferred positions are averaged with equal weights;
* f_fair (eq. 6): squared second differences along each road;
* f_close (eq. 7): squared distance to the original vertices.

The mesh is the noded arrangement of all streets: every free piece between junctions is
resampled every ``spacing`` metres and junctions are shared vertices. Each iteration
re-fits the strips to the current blocks and solves the quadratic energy as one sparse
linear system (scipy's sparse LU; the paper uses CHOLMOD), until no vertex moves more than
``TOLERANCE`` or the energy has not reached a new low for ``STALL`` iterations
(converged), or ``ITERATIONS`` have run (the paper: a fixed 10); the lowest-energy mesh
is returned (re-fitting the strips is not an exact projection, so the energy of the
alternation is not monotone: a near-square block may flip its strip). Vertices on
the region outline and on key roads are fixed, except the junctions of new streets with
them, which slide along the fixed road (projected onto it after each solve), as in the
paper. A step that would change the block structure (a street crossing another) is
halved up to four times, else undone and the optimisation stops (``reverted``).

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

__all__ = ["WEIGHTS", "ITERATIONS", "NODING_GRID", "optimise_roads", "noded", "faces_of"]

#: (w_shape, w_fair, w_close) of eq. (3).
WEIGHTS = (1.0, 0.8, 0.2)
#: Most iterations (the paper runs a fixed 10; here the loop also stops once converged).
ITERATIONS = 30
#: Converged when no vertex moves more than this (m) in an iteration, or when the energy
#: has not gone below its lowest value for ``STALL`` iterations (the strip fit then only
#: flips between near-equal fits); the lowest-energy mesh is returned.
TOLERANCE = 0.01
STALL = 3
#: Times the vertices around a step's sliver faces may be frozen before the loop stops.
MAX_FREEZE = 5

_ON = 0.05  # m: a vertex this close to a block side lies on it


#: Snap-rounding grid (m) of every noding of street lines: a street that ends on another
#: (a T-junction computed by GEOS lies on its host only to rounding) is noded with it.
NODING_GRID = 1e-5


def noded(lines: Sequence) -> np.ndarray:
    """The lines noded at every crossing and T-junction (snap-rounded to
    :data:`NODING_GRID`), as single LineStrings."""
    return shapely.get_parts(shapely.union_all(np.asarray(lines, dtype=object),
                                               grid_size=NODING_GRID))


def faces_of(lines: Sequence) -> np.ndarray:
    """Faces of the arrangement of lines (noded), as polygons."""
    return shapely.get_parts(shapely.polygonize(noded(lines)))


def _build_mesh(free: Sequence, fixed_lines: Sequence, spacing: float):
    """The road mesh M = (V, E) of Yang sec. 6 from the noded arrangement of all lines.

    Every free street piece between two junctions of the arrangement is resampled every
    ``spacing`` metres; junctions are shared vertices by construction (coordinates
    snap-rounded to :data:`NODING_GRID`). Returns (vertices (n, 2), index sequence of each
    free piece, fixed flag per vertex, host fixed line index per sliding vertex or -1).
    A free vertex is fixed when it lies on a fixed line, except a junction (a free piece
    ends there) which slides along that line (Yang: "road intersections can slide on the
    boundary").
    """
    fixed_lines = list(fixed_lines)
    pieces = noded(fixed_lines + list(free))
    fixed_union = shapely.union_all(np.asarray(fixed_lines, dtype=object))
    mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    is_free = shapely.distance(fixed_union, mid) > 1e-4
    seqs_xy = []
    for g in pieces[is_free]:
        n = max(1, int(np.ceil(g.length / spacing)))
        xy = shapely.get_coordinates(shapely.line_interpolate_point(
            g, np.linspace(0.0, 1.0, n + 1), normalized=True))
        ends = shapely.get_coordinates(g)[[0, -1]]
        xy[0], xy[-1] = ends[0], ends[-1]
        seqs_xy.append(xy)
    if not seqs_xy:
        return np.zeros((0, 2)), [], np.zeros(0, bool), np.zeros(0, int)
    allpts = np.concatenate(seqs_xy)
    # snap rounding may put the two sides of one junction a grid step apart: points within
    # a millimetre are one vertex
    pairs = cKDTree(allpts).query_pairs(1e-3, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                          shape=(len(allpts), len(allpts)))
    _, comp = connected_components(graph, directed=False)
    _, first, label = np.unique(comp, return_index=True, return_inverse=True)
    verts = allpts[first].astype(float)
    seqs, offset = [], 0
    for xy in seqs_xy:
        seqs.append(label[offset:offset + len(xy)])
        offset += len(xy)
    pts = shapely.points(verts)
    on_fixed = shapely.distance(fixed_union, pts) < 1e-4
    ends = np.zeros(len(verts), dtype=bool)
    for sq in seqs:
        ends[sq[[0, -1]]] = True
    host = np.full(len(verts), -1)
    slide = on_fixed & ends
    if slide.any():
        fl = np.asarray(fixed_lines, dtype=object)
        d = shapely.distance(fl[None, :], pts[slide][:, None])
        host[slide] = np.argmin(d, axis=1)
    fixed = on_fixed & ~slide
    return verts, seqs, fixed, host


def optimise_roads(free: Sequence, fixed_lines: Sequence,
                   face_width: Callable[[shapely.Geometry], float], spacing: float,
                   weights: Tuple[float, float, float] = WEIGHTS,
                   iterations: int = ITERATIONS, tolerance: float = TOLERANCE):
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
    iterations : int
        Most iterations; the loop stops earlier once no vertex moves more than
        ``tolerance`` metres (converged).

    Returns
    -------
    lines : list of LineString
        The free street pieces between junctions, moved.
    stats : dict
        ``iterations`` done, ``converged``, ``energy`` per iteration (eq. 3, m²; entry
        0 before the first step), ``best_iteration`` (the mesh returned: the lowest
        energy), ``frozen_events``,
        ``shape_before`` / ``shape_after`` (f_shape, m²), ``reverted`` (a step was undone
        because it would have changed the block structure).
    """
    free = list(free)
    verts, seqs, fixed, host = _build_mesh(free, fixed_lines, spacing) if free else \
        (np.zeros((0, 2)), [], np.zeros(0, bool), np.zeros(0, int))
    if not seqs:
        return free, {"iterations": 0, "converged": True, "energy": [], "shape_before": 0.0,
                      "shape_after": 0.0, "reverted": False}
    fixed_arr = np.asarray(list(fixed_lines), dtype=object)
    v0 = verts.copy()
    n = len(verts)
    ws, wf, wc = weights
    # fairness operator D: one row per interior vertex of every road piece
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
    fixed = fixed.copy()
    sliding = np.flatnonzero(host >= 0)

    def lines_of(v):
        return [shapely.LineString(v[sq]) for sq in seqs]

    def energy(v, target, has):
        fr = dmat @ v
        return float(ws * (has * ((v - target) ** 2).sum(1)).sum() + wf * (fr ** 2).sum()
                     + wc * ((v - v0) ** 2).sum())

    def slide(v):
        """Junctions on a fixed road back onto it (projected)."""
        if len(sliding):
            hosts = fixed_arr[host[sliding]]
            v[sliding] = shapely.get_coordinates(shapely.line_interpolate_point(
                hosts, shapely.line_locate_point(hosts, shapely.points(v[sliding]))))
        return v

    # the junctions are put exactly onto their fixed road first: noding is then the same
    # before and after every step
    verts = slide(verts)
    v0 = verts.copy()
    faces = faces_of(list(fixed_lines) + lines_of(verts))
    n_faces = len(faces)
    shape_before = None
    history = []
    done, reverted, converged = 0, False, False
    frozen = 0
    it = 0
    while it < iterations:
        target, has, err = _strip_targets(verts, faces, face_width)
        if shape_before is None:
            shape_before = err
        if not history:
            history.append(energy(verts, target, has))
            best = (history[0], verts.copy(), faces, 0)
        a = (ws * sp.diags(has.astype(float)) + wf * fair + wc * sp.identity(n)).tocsr()
        free_idx = np.flatnonzero(~fixed)
        fix_idx = np.flatnonzero(fixed)
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
        full = new.copy()
        for _half in range(5):
            new = slide(new)  # junctions on a fixed road slide along it
            cand = lines_of(new)
            if all(shapely.is_simple(g) for g in cand):
                new_faces = faces_of(list(fixed_lines) + cand)
                if len(new_faces) == n_faces:
                    break
            new = 0.5 * (new + verts)
        else:
            # the full step made sliver faces (a street poking across another near a
            # junction): the free vertices around them stay where they are, and the
            # iteration is solved again; after MAX_FREEZE such events the loop stops
            grown = _sliver_vertices(full, seqs, fixed_lines, fixed | (host >= 0))
            if len(grown) == 0 or frozen >= MAX_FREEZE:
                reverted = True
                break
            fixed[grown] = True
            frozen += 1
            continue
        step = float(np.abs(new - verts).max()) if len(new) else 0.0
        verts = new
        faces = new_faces
        done += 1
        it += 1
        target, has, _ = _strip_targets(verts, faces, face_width)
        history.append(energy(verts, target, has))
        if history[-1] < best[0]:
            best = (history[-1], verts.copy(), faces, done)
        if step < tolerance or done - best[3] >= STALL:
            converged = True
            break
    if best[3] != done:  # the lowest-energy mesh seen
        _, verts, faces, _ = best
    target, has, shape_after = _strip_targets(verts, faces, face_width)
    return lines_of(verts), {"iterations": done, "converged": converged, "energy": history,
                             "shape_before": float(shape_before or 0.0),
                             "shape_after": float(shape_after), "reverted": reverted,
                             "frozen_events": frozen, "best_iteration": int(best[3])}


def _sliver_vertices(verts, seqs, fixed_lines, not_free) -> np.ndarray:
    """Free vertices within a metre of the sliver faces (under 1 m²) that a step made."""
    faces = faces_of(list(fixed_lines) + [shapely.LineString(verts[sq]) for sq in seqs])
    slivers = faces[shapely.area(faces) < 1.0]
    if len(slivers) == 0:
        return np.zeros(0, dtype=int)
    near = shapely.dwithin(shapely.union_all(slivers), shapely.points(verts), 1.0)
    return np.flatnonzero(near & ~not_free)


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
            # Yang sec. 6: the target strip is the middle line of the pair offset by half
            # the preferred width to either side
            acc[on] += 0.5 * (p + q) + 0.5 * d / dist[:, None] * width
            cnt[on] += 1
    has = cnt > 0
    target = verts.copy()
    target[has] = acc[has] / cnt[has, None]
    err = float(((verts - target) ** 2).sum())
    return target, has, err
