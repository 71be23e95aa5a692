"""Boundary-aligned cross fields over a polygon (Yang et al. 2013, sec. 5).

A cross at a point is a pair of orthogonal lines; streamlines of a smooth cross field that
follows the region boundary are candidate streets that meet the boundary at right angles
or run parallel to it. Yang et al. leave the cross-field design open ("our framework is
not tied to any particular method"); here the field is the classic 4-RoSy smoothing:

* a cross of angle theta is represented by the vector u = (cos 4 theta, sin 4 theta), which
  is the same for the four directions theta + k pi / 2;
* grid nodes near the boundary are constrained (softly, by a large weight) to the
  representation of the tangent of the nearest boundary segment;
* the other nodes minimise the Dirichlet energy sum |u_i - u_j|^2 over grid edges (the
  field's smoothness) plus a **divergence term**: Yang et al. ask for fields that are
  "smooth, have low divergence, and are adapted to the boundary" so that "parallel
  streets stay a roughly constant distance apart". For the unit field v = (cos t, sin t)
  of the cross line parallel to the nearest boundary, div v = grad t . n, the derivative
  of its angle along the boundary normal n (the direction to the nearest boundary point);
  a field with div v = 0 keeps its streets parallel to the boundary at constant spacing
  (offset curves). Written on u it is |d u / d n|^2 = 16 (div v)^2 |u|^2, quadratic in u,
  so the energy stays one sparse linear system (scipy) solved once for both components:
  (L + lambda D_n^T D_n h^2 + W) u = W t, D_n the central-difference derivative along n.
  (The paper's supplement gives three field designs; this is our reading of the stated
  terms, not a copy of any of them.)
* the field's angle is atan2(u) / 4; where |u| is small the field is singular, and the
  singular cells are found by the index (the turning of 4 theta around the cell).

Nothing here imports QGIS.

References
----------
Yang, Y.-L., Wang, J., Vouga, E., Wonka, P. (2013). Urban pattern: layout design by
    hierarchical domain splitting. ACM TOG 32(6), sec. 5 and supplement (cross fields).
Palacios, J., Zhang, E. (2007). Rotational symmetry field design on surfaces. ACM TOG 26(3)
    (N-RoSy representation).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import shapely
from scipy.spatial import cKDTree

__all__ = ["CrossField", "cross_field", "boundary_segments", "DIVERGENCE_WEIGHT",
           "divergence"]

#: Weight of the boundary alignment against the smoothness of one grid edge.
BOUNDARY_WEIGHT = 100.0
#: Weight of the divergence term (see the module doc) against the Dirichlet smoothing.
DIVERGENCE_WEIGHT = 4.0
#: |u| below this (after interpolation) counts as singular: streamlines stop there.
SINGULAR_NORM = 0.05


def boundary_segments(region) -> np.ndarray:
    """All boundary segments of a (multi)polygon, including holes, as an (n, 2, 2) array."""
    rings = shapely.get_rings(shapely.get_parts(region))
    segs = []
    for ring in rings:
        xy = shapely.get_coordinates(ring)
        if len(xy) >= 2:
            segs.append(np.stack([xy[:-1], xy[1:]], axis=1))
    segs = np.concatenate(segs) if segs else np.zeros((0, 2, 2))
    return segs[np.hypot(*(segs[:, 1] - segs[:, 0]).T) > 1e-9]


@dataclass
class CrossField:
    """A cross field sampled on a regular grid of nodes.

    Attributes
    ----------
    x0, y0 : float
        Coordinates of node (0, 0).
    h : float
        Grid spacing (m).
    u : ndarray (ny, nx, 2)
        (cos 4 theta, sin 4 theta) per node (zero outside the region's neighbourhood).
    singularities : ndarray (k, 2)
        Centres of the grid cells with a non-zero index.
    """

    x0: float
    y0: float
    h: float
    u: np.ndarray
    singularities: np.ndarray
    #: (ny, nx) nodes inside the region and farther than 1.5 h from its boundary: a point
    #: whose nearest node is deep is inside for sure (tracing skips the exact test there)
    deep: Optional[np.ndarray] = None

    def surely_inside(self, xy: np.ndarray) -> np.ndarray:
        """True where a point (n, 2) is certainly inside the region (False = unknown)."""
        if self.deep is None:
            return np.zeros(len(xy), dtype=bool)
        ny, nx = self.deep.shape
        ix = np.rint((xy[:, 0] - self.x0) / self.h).astype(int)
        iy = np.rint((xy[:, 1] - self.y0) / self.h).astype(int)
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        out = np.zeros(len(xy), dtype=bool)
        out[ok] = self.deep[iy[ok], ix[ok]]
        return out

    def sample(self, xy: np.ndarray) -> np.ndarray:
        """Bilinear interpolation of u at points (n, 2) -> (n, 2)."""
        ny, nx, _ = self.u.shape
        fx = np.clip((xy[:, 0] - self.x0) / self.h, 0, nx - 1.000001)
        fy = np.clip((xy[:, 1] - self.y0) / self.h, 0, ny - 1.000001)
        ix, iy = fx.astype(int), fy.astype(int)
        tx, ty = (fx - ix)[:, None], (fy - iy)[:, None]
        # one gather of the four corners on the flat grid (this runs twice per RK step)
        k = iy * nx + ix
        c = self.u.reshape(-1, 2)[np.stack([k, k + 1, k + nx, k + nx + 1])]  # (4, n, 2)
        return ((1 - ty) * ((1 - tx) * c[0] + tx * c[1]) + ty * ((1 - tx) * c[2] + tx * c[3]))

    def angle(self, xy: np.ndarray):
        """Cross angle theta in [-pi/4, pi/4) and the field's strength |u| at points."""
        u = self.sample(np.asarray(xy, dtype=float).reshape(-1, 2))
        return np.arctan2(u[:, 1], u[:, 0]) / 4.0, np.hypot(u[:, 0], u[:, 1])

    def direction(self, xy: np.ndarray, prev: np.ndarray):
        """The unit direction of the cross closest to ``prev`` (n, 2) and the strength."""
        theta, norm = self.angle(xy)
        prev_angle = np.arctan2(prev[:, 1], prev[:, 0])
        # of the four directions theta + k pi/2, the one nearest prev
        k = np.round((prev_angle - theta) / (np.pi / 2))
        a = theta + k * np.pi / 2
        return np.stack([np.cos(a), np.sin(a)], axis=1), norm


def _normal_derivative(grid: np.ndarray, normal: np.ndarray, h: float):
    """Sparse operator D_n with (D_n u)_i = n_i . grad u at active node i (central
    differences where both neighbours are active, one-sided otherwise, none at isolated
    nodes)."""
    n = int(grid.max()) + 1 if grid.size and grid.max() >= 0 else 0
    rows, cols, vals = [], [], []
    ny, nx = grid.shape
    iy, ix = np.nonzero(grid >= 0)
    k = grid[iy, ix]
    for axis, comp in ((1, 0), (0, 1)):
        prev = np.full(len(k), -1)
        nxt = np.full(len(k), -1)
        if axis == 1:
            ok = ix > 0
            prev[ok] = grid[iy[ok], ix[ok] - 1]
            ok = ix < nx - 1
            nxt[ok] = grid[iy[ok], ix[ok] + 1]
        else:
            ok = iy > 0
            prev[ok] = grid[iy[ok] - 1, ix[ok]]
            ok = iy < ny - 1
            nxt[ok] = grid[iy[ok] + 1, ix[ok]]
        c = normal[k, comp]
        both = (prev >= 0) & (nxt >= 0)
        only_n = (prev < 0) & (nxt >= 0)
        only_p = (prev >= 0) & (nxt < 0)
        for sel, a, b, scale in ((both, nxt, prev, 0.5), (only_n, nxt, k, 1.0),
                                 (only_p, k, prev, 1.0)):
            rows += [k[sel], k[sel]]
            cols += [a[sel], b[sel]]
            vals += [c[sel] * scale / h, -c[sel] * scale / h]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))


def cross_field(region, h: float, divergence_weight: float = DIVERGENCE_WEIGHT) -> CrossField:
    """Smooth cross field aligned with the boundary of ``region`` (metric CRS).

    Parameters
    ----------
    region : Polygon or MultiPolygon
    h : float
        Grid spacing (m).
    divergence_weight : float
        Weight of the divergence term against the smoothness of one grid edge (0: the
        plain 4-RoSy smoothing).

    Returns
    -------
    CrossField

    Examples
    --------
    >>> import shapely
    >>> f = cross_field(shapely.box(0, 0, 100, 40), 4.0)
    >>> theta, norm = f.angle(np.array([[50.0, 20.0]]))
    >>> round(abs(float(theta[0])), 3), bool(norm[0] > 0.5)
    (0.0, True)
    """
    xmin, ymin, xmax, ymax = shapely.bounds(region)
    x0, y0 = xmin - 2 * h, ymin - 2 * h
    nx = int(np.ceil((xmax - x0) / h)) + 3
    ny = int(np.ceil((ymax - y0) / h)) + 3
    gx, gy = np.meshgrid(x0 + h * np.arange(nx), y0 + h * np.arange(ny))
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    shapely.prepare(region)  # a prepared polygon answers the grid's point queries fast
    inside = shapely.contains_xy(region, pts[:, 0], pts[:, 1])
    # boundary samples every h / 4 with their tangent angle; a KD-tree gives each node its
    # distance to the boundary (to h / 8) and the tangent of the nearest boundary point
    segs = boundary_segments(region)
    seg_len = np.hypot(*(segs[:, 1] - segs[:, 0]).T)
    count = np.maximum(np.ceil(seg_len / (h / 4)).astype(int), 1)
    owner = np.repeat(np.arange(len(segs)), count)
    frac = (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 0.5) / \
        np.repeat(count, count)
    samples = segs[owner, 0] + (segs[owner, 1] - segs[owner, 0]) * frac[:, None]
    d = segs[owner, 1] - segs[owner, 0]
    sample_angle = np.arctan2(d[:, 1], d[:, 0])
    dist, nearest = cKDTree(samples).query(pts, distance_upper_bound=2 * h)
    active = inside | (dist <= 1.5 * h)
    near = active & (dist <= 0.75 * h)
    near_idx = np.flatnonzero(near)
    target = np.zeros((len(pts), 2))
    ang = sample_angle[nearest[near_idx]]
    target[near_idx] = np.stack([np.cos(4 * ang), np.sin(4 * ang)], axis=1)
    # Dirichlet energy over grid edges between active nodes + weighted constraints
    idx = np.full(len(pts), -1)
    act = np.flatnonzero(active)
    idx[act] = np.arange(len(act))
    grid = idx.reshape(ny, nx)
    rows, cols = [], []
    for a, b in ((grid[:, :-1], grid[:, 1:]), (grid[:-1, :], grid[1:, :])):
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
    i, j = np.concatenate(rows), np.concatenate(cols)
    n = len(act)
    adj = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    adj = adj + adj.T
    lap = sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
    w = np.where(near[act], BOUNDARY_WEIGHT, 0.0)
    # divergence term: the derivative of u along the boundary normal n (the direction
    # to the nearest boundary point), by central differences on the grid
    _, foot = cKDTree(samples).query(pts[act])
    normal = pts[act] - samples[foot]
    length = np.hypot(normal[:, 0], normal[:, 1])
    normal = np.where(length[:, None] > 1e-9, normal / np.maximum(length, 1e-9)[:, None], 0.0)
    g_n = _normal_derivative(grid, normal, h)
    # a tiny regulariser keeps components without constraint (none in practice) solvable
    system = (lap + divergence_weight * (g_n.T @ g_n) * h * h + sp.diags(w + 1e-8)).tocsc()
    rhs = w[:, None] * target[act]
    sol = spla.splu(system).solve(rhs)
    u = np.zeros((len(pts), 2))
    u[act] = sol
    u = u.reshape(ny, nx, 2)
    # the boundary samples are h / 4 apart: a node over 1.5 h from them is over 1.25 h
    # from the boundary, and every point within h * sqrt(2) / 2 of it is inside
    deep = (inside & (dist > 1.5 * h)).reshape(ny, nx)
    return CrossField(x0, y0, h, u, _singular_cells(u, inside.reshape(ny, nx), x0, y0, h), deep)


def _singular_cells(u: np.ndarray, inside: np.ndarray, x0, y0, h) -> np.ndarray:
    """Centres of the cells around which 4 theta turns by a non-zero multiple of 2 pi."""
    phi = np.arctan2(u[..., 1], u[..., 0])
    corners = [phi[:-1, :-1], phi[:-1, 1:], phi[1:, 1:], phi[1:, :-1]]
    turn = np.zeros_like(corners[0])
    for a, b in zip(corners, corners[1:] + corners[:1]):
        turn += (b - a + np.pi) % (2 * np.pi) - np.pi
    ok = inside[:-1, :-1] & inside[:-1, 1:] & inside[1:, 1:] & inside[1:, :-1]
    iy, ix = np.nonzero(ok & (np.abs(turn) > np.pi))
    return np.stack([x0 + h * (ix + 0.5), y0 + h * (iy + 0.5)], axis=1)


def divergence(field: CrossField, region) -> float:
    """Mean |div v| (1/m) over the region's inner nodes, v the unit field of the cross line
    parallel to the nearest boundary: the quantity the divergence term keeps low."""
    ny, nx, _ = field.u.shape
    gx, gy = np.meshgrid(field.x0 + field.h * np.arange(nx), field.y0 + field.h * np.arange(ny))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    inner = shapely.buffer(region, -2 * field.h)
    if inner.is_empty:
        return 0.0
    ok = shapely.contains_xy(inner, pts[:, 0], pts[:, 1])
    p = pts[ok]
    segs = boundary_segments(region)
    mid = 0.5 * (segs[:, 0] + segs[:, 1])
    tree = cKDTree(mid)
    _, near = tree.query(p)
    d = segs[near, 1] - segs[near, 0]
    t = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    nrm = np.column_stack([-t[:, 1], t[:, 0]])
    eps = field.h
    th0, _ = field.angle(p - eps * nrm)
    th1, _ = field.angle(p + eps * nrm)
    dth = (th1 - th0 + np.pi / 4) % (np.pi / 2) - np.pi / 4
    return float(np.mean(np.abs(dth) / (2 * eps)))
