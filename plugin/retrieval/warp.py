"""Warping by mean value coordinates and Poisson merging of relief patches.

Hartmann's thesis inserts a retrieved fragment into a query fragment by warping its
interior streets with generalised barycentric coordinates defined on the boundary samples
of the match and evaluated with the corresponding samples of the query (ch. 4.1.3,
"Fragment Insertion"); the fragment's relief is warped the same way and merged into the
height field by Poisson image editing so that the heights stay continuous across fragment
boundaries ("PropagateHeightDistribution").

- :func:`mean_value_coordinates`: Floater's mean value coordinates in the form of Hormann
  and Floater (2006) for arbitrary (also non-convex) simple polygons, vectorised over all
  points x all polygon vertices, with points on an edge or a vertex handled exactly;
- :func:`warp_points` / :func:`warp_geometries`: ``x -> sum_i lambda_i(x) q_i`` with
  ``lambda`` computed on polygon P and evaluated with the corresponding vertices Q;
- :func:`sample_grid_warped`: a raster patch pulled back into another polygon (backward
  mapping: every target cell centre is warped from Q to P and the patch sampled there);
- :func:`poisson_blend`: Perez et al.'s guided interpolation on a grid: inside a mask the
  heights take the gradients of a guidance patch, on the mask's border they equal the
  existing heights (Dirichlet), solved as one sparse linear system (scipy.sparse).

Nothing here imports QGIS; the road synthesis (``synthesis_fragments``) and the building
layout transfer reuse these functions.

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 4.1.3
(fragment insertion with generalised barycentric coordinates, relief merged by Poisson
image editing).
Floater, M. S. Mean value coordinates. CAGD 20(1), 2003.
Hormann, K., Floater, M. S. Mean value coordinates for arbitrary planar polygons.
ACM TOG 25(4), 2006.
Perez, P., Gangnet, M., Blake, A. Poisson image editing. ACM TOG 22(3), 2003.
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import shapely
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve

from ..core import coordinates
from ..core.progress import InputError

__all__ = ["mean_value_coordinates", "warp_points", "warp_geometries", "sample_grid_warped",
           "poisson_blend"]

#: Relative tolerance under which a point counts as lying on a polygon edge or vertex.
_ON_EDGE = 1e-10


def _polygon_array(polygon) -> np.ndarray:
    v = np.asarray(polygon, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
        raise InputError("a polygon needs at least 3 vertices given as an (n, 2) array")
    if not np.isfinite(v).all():
        raise InputError("polygon vertices must be finite numbers")
    return v


def mean_value_coordinates(points: np.ndarray, polygon: np.ndarray,
                           chunk: int = 4096) -> np.ndarray:
    """Mean value coordinates of points with respect to a closed polygon.

    ``w_i = (tan(a_{i-1} / 2) + tan(a_i / 2)) / |v_i - x|`` normalised to sum 1, with
    ``a_i`` the *signed* angle at x of the triangle (x, v_i, v_{i+1}) (Hormann and Floater
    2006), so that the coordinates are defined for any simple polygon, convex or not, and
    for points inside or outside it. ``tan(a / 2)`` is evaluated as
    ``cross / (r_i r_{i+1} + dot)``, stable for every angle except a = pi, which means the
    point lies on the edge: there (and on a vertex) the coordinates are the exact linear
    interpolation along that edge. Repeated consecutive vertices (zero-length edges, as in
    a DTW correspondence) are allowed.

    Parameters
    ----------
    points : (p, 2) array
    polygon : (n, 2) array of vertices in order; a repeated closing vertex is just a
        zero-length edge (its weight is shared with the first vertex)
    chunk : int
        Points per vectorised block (bounds memory to a few chunk x n arrays).

    Returns
    -------
    (p, n) float64 array; rows sum to 1 and reproduce the points:
    ``coords @ polygon == points`` (linear precision).

    References
    ----------
    Floater 2003; Hormann and Floater 2006, eqs. (6)-(8) and sec. 4.

    Examples
    --------
    >>> sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    >>> mean_value_coordinates(np.array([[1.0, 1.0]]), sq).round(3).tolist()
    [[0.25, 0.25, 0.25, 0.25]]
    """
    v = _polygon_array(polygon)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = len(v)
    out = np.empty((len(pts), n))
    scale = max(float(np.ptp(v, axis=0).max()), 1e-12)
    tol = _ON_EDGE * scale
    nxt = np.r_[1:n, 0]
    elen = np.hypot(*(v[nxt] - v).T)[None, :]
    # x and y apart, neighbours by a roll: the same arithmetic as on (p, n, 2) arrays with
    # fewer and smaller temporaries (1.5-3 x faster, bit for bit the same)
    vx, vy = v[None, :, 0], v[None, :, 1]
    for a in range(0, len(pts), chunk):
        x = pts[a:a + chunk]
        sx, sy = vx - x[:, :1], vy - x[:, 1:2]               # (p, n)
        r = np.hypot(sx, sy)
        sx1, sy1, r1 = (np.roll(q, -1, axis=1) for q in (sx, sy, r))
        cross = sx * sy1 - sy * sx1
        dot = sx * sx1 + sy * sy1
        denom = r * r1 + dot                                  # 0 when x lies on edge (i, i+1)
        at_vertex = r <= tol
        positive = denom > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            # tan(a_i / 2) = sin / (1 + cos); large but exact close to an edge
            t = np.where(positive, cross / np.where(positive, denom, 1.0), 0.0)
            w = (t + np.roll(t, 1, axis=1)) / np.where(at_vertex, 1.0, r)
        total = w.sum(1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = w / total
        # exact cases: on a vertex, on an edge (linear along it); a degenerate sum (a point
        # far outside a tiny polygon) falls back to the nearest vertex. On the segment:
        # between its ends (dot <= 0) at a distance |cross| / |e| ~ 0, neither end a vertex
        # the point is on (worked out for the few rows near an edge only)
        near_edge = (dot <= 0) & ((np.abs(cross) <= tol * elen) | (denom <= 0))
        special = at_vertex.any(1) | ~np.isfinite(lam).all(1) | (np.abs(total[:, 0]) < 1e-300)
        rows = np.flatnonzero(near_edge.any(1) | special)
        on_edge = near_edge[rows] & ~at_vertex[rows] & ~np.roll(at_vertex[rows], -1, axis=1)
        special[rows[on_edge.any(1)]] = True
        edge_of = dict(zip(rows.tolist(), on_edge))
        for k in np.flatnonzero(special):
            row = np.zeros(n)
            if at_vertex[k].any():
                row[np.flatnonzero(at_vertex[k])[0]] = 1.0
            elif edge_of[k].any():
                i = np.flatnonzero(edge_of[k])[0]
                j = nxt[i]
                e = v[j] - v[i]
                u = float(np.clip(np.dot(x[k] - v[i], e) / max(np.dot(e, e), 1e-300), 0, 1))
                row[i] += 1.0 - u
                row[j] += u
            else:
                row[int(np.argmin(r[k]))] = 1.0
            lam[k] = row
        out[a:a + chunk] = lam
    return out


def warp_points(points: np.ndarray, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Map points by mean value coordinates from polygon ``source`` to polygon ``target``.

    ``target`` lists the vertices corresponding one to one to those of ``source``.
    Points on the source boundary land on the target boundary; an affine map of the
    polygon is reproduced exactly inside it.
    """
    src = _polygon_array(source)
    dst = _polygon_array(target)
    if src.shape != dst.shape:
        raise InputError("source and target polygons need the same number of vertices")
    pts = np.asarray(points, dtype=np.float64)
    if pts.size == 0:
        return pts.reshape(-1, 2).copy()
    weights = mean_value_coordinates(pts.reshape(-1, 2), src)
    return blas_free_product(weights, dst).reshape(pts.shape)


def blas_free_product(a: np.ndarray, b: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """``a @ b`` for (n, k) x (k, 2) without BLAS: a BLAS product rounds differently under
    different processor kernels (OPENBLAS_CORETYPE), and a last-bit difference in a warped
    vertex can flip a later decision (a rejected fragment, a face above a threshold). Done
    as an element-wise product and a sum over k, one column of b at a time, in chunks of
    rows. The sum runs along the first axis of a (k, rows) array: numpy adds the k terms
    in order there (pairwise summation is only for the contiguous axis), as it did over the
    middle axis of the (rows, k, 2) product this replaced, bit for bit, at a fifth of the
    time (no (rows, k, 2) temporary, no strided reduction)."""
    out = np.empty((a.shape[0], b.shape[1]), dtype=np.float64)
    for i in range(0, a.shape[0], chunk):
        rows_last = np.ascontiguousarray(a[i:i + chunk].T)
        for c in range(b.shape[1]):
            out[i:i + chunk, c] = np.add.reduce(rows_last * b[:, c:c + 1], axis=0)
    return out


def warp_geometries(geoms: Sequence, source: np.ndarray, target: np.ndarray,
                    max_segment: Optional[float] = None) -> np.ndarray:
    """Warp shapely geometries vertex by vertex (:func:`warp_points`), vectorised.

    Parameters
    ----------
    geoms : array of geometries (in the source polygon's frame)
    source, target : (n, 2) corresponding polygon vertices
    max_segment : float, optional
        Densify first so that no segment is longer than this: a warp bends straight lines,
        and a long segment would otherwise stay straight between its warped ends.

    Returns
    -------
    ndarray of geometries.
    """
    geoms = np.asarray(geoms, dtype=object)
    if len(geoms) == 0:
        return geoms.copy()
    if max_segment is not None and max_segment > 0:
        geoms = shapely.segmentize(geoms, max_segment)
    src, dst = _polygon_array(source), _polygon_array(target)
    return coordinates.transform(geoms, lambda xy, _: warp_points(xy, src, dst))


def sample_grid_warped(cells_xy: np.ndarray, query: np.ndarray, example: np.ndarray,
                       sampler) -> np.ndarray:
    """Heights of an example patch at target cells, pulled back through the warp.

    Each target cell centre x (inside the query polygon) gets the mean value coordinates
    of x with respect to the ``query`` samples, evaluated with the corresponding
    ``example`` samples: the point of the example that the forward warp sends near x.
    The example relief is sampled there (``sampler(xy) -> heights``, e.g. a ``DemGrid``).

    Returns
    -------
    (p,) heights (NaN where the sampler has no data).
    """
    src = warp_points(np.asarray(cells_xy, dtype=np.float64), query, example)
    return np.asarray(sampler(src), dtype=np.float64)


def poisson_blend(base: np.ndarray, guidance: np.ndarray, mask: np.ndarray,
                  labels: Optional[np.ndarray] = None) -> np.ndarray:
    """Guided interpolation (Poisson image editing) of a height grid.

    Solves ``laplace f = laplace g`` on the masked cells, with ``f`` equal to ``base`` on
    the unmasked neighbours (Dirichlet boundary: the existing heights) and the guidance
    field the gradient of ``g``: per cell p, ``|N_p| f_p - sum_{q in N_p, masked} f_q =
    sum_{q in N_p, unmasked} base_q + sum_{q in N_p} (g_p - g_q)`` over the 4-neighbours
    inside the grid (Perez et al. 2003, eq. 7). With ``labels``, masked neighbours of a
    different label (another fragment) are treated as boundary too, so every region is
    merged into the existing heights on its own and two example patches at different
    absolute heights never pull on each other. A region with no boundary at all (the whole
    grid) keeps its mean at the base's mean.

    Parameters
    ----------
    base : (rows, cols) heights; must be finite where used as boundary
    guidance : (rows, cols) guidance heights g (only their differences matter); NaN where
        unknown: gradients touching a NaN are taken as 0
    mask : (rows, cols) bool, the cells to solve for
    labels : (rows, cols) int, optional region label per masked cell

    Returns
    -------
    (rows, cols) float64 heights: ``base`` outside the mask, the blend inside.

    References
    ----------
    Perez, Gangnet, Blake 2003 (discrete Poisson equation with Dirichlet boundary);
    Hartmann, thesis ch. 4.1.3 (relief of the inserted fragments merged this way).
    """
    base = np.asarray(base, dtype=np.float64)
    g = np.asarray(guidance, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if base.shape != g.shape or base.shape != mask.shape or base.ndim != 2:
        raise InputError("base, guidance and mask must be grids of the same shape")
    out = base.copy()
    idx = np.flatnonzero(mask.ravel())
    if len(idx) == 0:
        return out
    rows, cols = base.shape
    lab = np.zeros(base.shape, dtype=np.int64) if labels is None else np.asarray(labels)
    number = np.full(base.size, -1, dtype=np.int64)
    number[idx] = np.arange(len(idx))
    r, c = np.divmod(idx, cols)
    diag = np.zeros(len(idx))
    rhs = np.zeros(len(idx))
    ii, jj = [], []
    flat_base = base.ravel()
    flat_g = g.ravel()
    flat_lab = lab.ravel()
    flat_mask = mask.ravel()
    anchored = np.zeros(len(idx), dtype=bool)
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        p = np.flatnonzero(inside)
        q = rr[p] * cols + cc[p]
        diag[p] += 1.0
        unknown = flat_mask[q] & (flat_lab[q] == flat_lab[idx[p]])
        # guidance differences: none towards another region (its patch lies at another
        # absolute height) nor where the guidance is unknown
        v = flat_g[idx[p]] - flat_g[q]
        v[flat_mask[q] & ~unknown] = 0.0
        rhs[p] += np.where(np.isfinite(v), v, 0.0)
        # unknown neighbour: off-diagonal -1; otherwise its current height is the boundary
        ii.append(p[unknown])
        jj.append(number[q[unknown]])
        b = flat_base[q[~unknown]]
        rhs[p[~unknown]] += np.where(np.isfinite(b), b, 0.0)
        anchored[p[~unknown]] = True
    ii = np.concatenate(ii)
    jj = np.concatenate(jj)
    a = sparse.coo_matrix((np.r_[diag, -np.ones(len(ii))],
                           (np.r_[np.arange(len(idx)), ii], np.r_[np.arange(len(idx)), jj])),
                          shape=(len(idx), len(idx))).tocsr()
    # a connected region without boundary is singular (heights defined up to a constant):
    # a weak pull towards the base keeps it solvable and its mean at the base's
    n_comp, comp = connected_components(a, directed=False)
    free = ~np.bincount(comp, weights=anchored.astype(float), minlength=n_comp).astype(bool)
    if free.any():
        eps = 1e-6
        cells = free[comp]
        target = flat_base[idx[cells]]
        target = np.where(np.isfinite(target), target, np.nanmean(target) if
                          np.isfinite(target).any() else 0.0)
        a = a + sparse.diags(np.where(cells, eps, 0.0))
        rhs[cells] += eps * target
    sol = spsolve(a.tocsc(), rhs)
    out.ravel()[idx] = sol
    return out
