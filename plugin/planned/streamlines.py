"""Streamline candidates of a cross field and their quality (Yang et al. 2013, sec. 5).

Streamline-based splitting cuts a region along one streamline of its cross field:

1. **Seeds** (:func:`seed_points`): Yang et al. seed at the inner vertices of a constrained
   Delaunay triangulation; here the inner vertices of a Delaunay mesh of the region made
   by Delaunay refinement (circumcentres inserted until no triangle is wider than
   ``d_eps``, 0.3 x parcel length in the paper).
2. **Tracing** (:func:`trace_streamlines`): from each seed, both orientations of the cross,
   both ways, with 2nd-order Runge-Kutta (midpoint), all seeds at once (numpy), until the streamline
   leaves the region; streamlines that run into a singularity (|u| small) or cross
   themselves are dropped, as in the paper. Seeds within ``d_eps`` of an accepted
   streamline of the same orientation are deactivated (greedy, random order).
3. **Quality** (:func:`score_streamlines`): the paper's four components, each normalised
   to [0, 1] over the candidates with weight one:

   - DIV: ``length^-p * sum |div f| ds`` with p = 0.9 (for a unit field the divergence is
     the derivative of its angle across the streamline);
   - DB: mean over the streamline of opt(distance to the boundary), opt(y) telling how well
     y is a sum of template widths (exhaustive sums up to a threshold); the distance is
     taken along the streamline's normal on both sides (geometric mean of the two opt
     values), so that the strips fit on either side of the new street;
   - DS: distance to the nearest singularity (a streamline near a singularity is
     preferred: it removes singularities from the sub-regions);
   - CT: continuity with existing street ends (4 m, 20 degrees): 1, 0.5 or 0.

Nothing here imports QGIS.

References
----------
Yang et al. (2013), sec. 5 "Streamline Candidate Generation", "Quality Score", eq. (2).
Alliez, P. et al. (2003). Anisotropic polygonal remeshing. ACM TOG 22(3) (RK streamlines).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import Delaunay, cKDTree

from ..core.geometry import first_hits
from .cross_field import SINGULAR_NORM, CrossField

__all__ = ["DIVERGENCE_P", "CONTINUITY_DIST", "CONTINUITY_ANGLE", "Candidates",
           "QUALITY_WEIGHTS", "seed_points", "trace_streamlines", "width_fit", "score_streamlines"]

#: Exponent of the length normalisation of the divergence score (eq. 2).
DIVERGENCE_P = 0.9
#: Continuity thresholds: distance (m) and angle (degrees) to an existing street end.
CONTINUITY_DIST = 4.0
CONTINUITY_ANGLE = 20.0
#: Weights lambda_1..4 of the normalised DIV, DB, DS and CT scores. The paper sets all to
#: one and lets the user change them; here DB counts twice: the regions must be filled by
#: strips of the template widths (see the README's notes on the Table 1 runs).
QUALITY_WEIGHTS = (1.0, 2.0, 1.0, 1.0)


@dataclass
class Candidates:
    """Streamline candidates of one region.

    Attributes
    ----------
    lines : ndarray of LineString
        Each clipped to the region, ending on its boundary.
    seeds : ndarray (n, 2)
    orientation : ndarray of int (0 or 1: which line of the cross)
    """

    lines: np.ndarray
    seeds: np.ndarray
    orientation: np.ndarray


def seed_points(region, d_eps: float, rng: np.random.Generator, max_seeds: int = 400):
    """Seed points: the inner vertices of a Delaunay mesh of ``region`` (Yang sec. 5).

    Yang et al. seed at the inner vertices of a constrained Delaunay triangulation of the
    region. shapely 2.0 offers no constrained or quality triangulation, so the mesh is made
    by Delaunay refinement (Chew / Ruppert style, with scipy's Delaunay): the outline is
    sampled every ``spacing`` metres, then the circumcentres of the triangles inside the
    region whose circumradius exceeds ``spacing`` are inserted, round after round, until
    none is left; the inserted points are the seeds. ``spacing`` is ``d_eps`` (0.3 x the
    parcel length in the paper), coarsened so that at most ``max_seeds`` seeds are made.
    ``rng`` is not used (the mesh is deterministic); it is kept for the signature.
    """
    area = shapely.area(region)
    spacing = max(d_eps, np.sqrt(2.0 * area / max_seeds))
    boundary = shapely.boundary(region)
    dense = shapely.segmentize(boundary, spacing)
    pts = np.unique(shapely.get_coordinates(dense), axis=0)
    inner = np.zeros((0, 2))
    shapely.prepare(region)
    for _ in range(30):
        allp = np.vstack([pts, inner])
        if len(allp) < 3:
            break
        tri = Delaunay(allp)
        a, b, c = (allp[tri.simplices[:, k]] for k in range(3))
        d = 2 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1])
                 + c[:, 0] * (a[:, 1] - b[:, 1]))
        ok = np.abs(d) > 1e-12
        a2, b2, c2 = (a ** 2).sum(1), (b ** 2).sum(1), (c ** 2).sum(1)
        ux = (a2 * (b[:, 1] - c[:, 1]) + b2 * (c[:, 1] - a[:, 1]) + c2 * (a[:, 1] - b[:, 1]))
        uy = (a2 * (c[:, 0] - b[:, 0]) + b2 * (a[:, 0] - c[:, 0]) + c2 * (b[:, 0] - a[:, 0]))
        cc = np.column_stack([ux, uy]) / np.where(ok, d, 1.0)[:, None]
        radius = np.hypot(*(cc - a).T)
        centroid = (a + b + c) / 3.0
        big = ok & (radius > spacing) & shapely.contains_xy(region, centroid[:, 0], centroid[:, 1])
        cand = cc[big]
        cand = cand[shapely.contains_xy(region, cand[:, 0], cand[:, 1])]
        # keep new points off the outline and apart from each other
        cand = cand[shapely.distance(boundary, shapely.points(cand)) > 0.5 * spacing]
        if len(cand) == 0:
            break
        existing = cKDTree(allp)
        d_old, _ = existing.query(cand)
        chosen = np.zeros((0, 2))
        for q, dq in zip(cand, d_old):
            if dq < 0.5 * spacing:
                continue
            if len(chosen) and np.hypot(*(chosen - q).T).min() < 0.5 * spacing:
                continue
            chosen = np.vstack([chosen, q])
        if len(chosen) == 0:
            break
        inner = np.vstack([inner, chosen])
        if len(inner) >= max_seeds:
            break
    if len(inner) == 0:
        inner = shapely.get_coordinates(shapely.point_on_surface(region))
    return inner[:max_seeds]


def _rk2(field: CrossField, p: np.ndarray, d: np.ndarray, step: float):
    """One 2nd-order Runge-Kutta (midpoint) step along the cross direction nearest ``d``
    (the field is smooth at the step sizes used, a quarter of a parcel length or less)."""
    k1, n1 = field.direction(p, d)
    k2, n2 = field.direction(p + 0.5 * step * k1, k1)
    return p + step * k2, k2, np.minimum(n1, n2)


def trace_streamlines(field: CrossField, region, seeds: np.ndarray, step: float,
                      d_eps: float, rng: np.random.Generator) -> Candidates:
    """Streamlines through ``seeds`` in both orientations of the cross (see module doc)."""
    n = len(seeds)
    theta, _ = field.angle(seeds)
    base = np.concatenate([theta, theta + np.pi / 2])
    starts = np.concatenate([seeds, seeds])
    # four traces per seed: orientation o in {0, 1} x way in {+1, -1}
    p = np.concatenate([starts, starts])
    ang = np.concatenate([base, base + np.pi])
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    xmin, ymin, xmax, ymax = shapely.bounds(region)
    max_steps = int(2.5 * (xmax - xmin + ymax - ymin) / step) + 2
    alive = np.ones(len(p), dtype=bool)
    singular = np.zeros(len(p), dtype=bool)
    paths = [p.copy()]
    shapely.prepare(region)
    for _ in range(max_steps):
        if not alive.any():
            break
        q, v, norm = _rk2(field, p[alive], d[alive], step)
        ids = np.flatnonzero(alive)
        p = p.copy()
        p[ids] = q
        d[ids] = v
        paths.append(p.copy())
        weak = norm < SINGULAR_NORM
        out = ~field.surely_inside(q)
        if out.any():  # the exact test only near the boundary
            out[out] = ~shapely.contains_xy(region, q[out, 0], q[out, 1])
        singular[ids[weak & ~out]] = True
        alive[ids[weak | out]] = False
    paths = np.stack(paths, axis=1)  # (4n, steps, 2); dead traces repeat their last point
    # the last step left the region: move each end onto the boundary by bisection
    last = np.array([_last_inside(path) for path in paths])
    inside_pt = paths[np.arange(len(paths)), last]
    outside_pt = paths[np.arange(len(paths)), np.minimum(last + 1, paths.shape[1] - 1)]
    lo, hi = inside_pt.copy(), outside_pt.copy()
    for _ in range(16):  # a step of at most ~40 m / 2**16: sub-millimetre
        mid = 0.5 * (lo + hi)
        inn = shapely.contains_xy(region, mid[:, 0], mid[:, 1])
        lo[inn] = mid[inn]
        hi[~inn] = mid[~inn]
    m = 2 * n
    lines, keep = [], []
    for k in range(m):
        if singular[k] or singular[k + m] or alive[k] or alive[k + m]:
            continue
        fwd = _dedupe(np.vstack([paths[k, :last[k] + 1], hi[k][None]]))
        bwd = _dedupe(np.vstack([paths[k + m, :last[k + m] + 1], hi[k + m][None]]))
        xy = np.concatenate([bwd[::-1], fwd[1:]])
        if len(xy) < 3:
            continue
        lines.append(xy)
        keep.append(k)
    if not lines:
        return Candidates(np.empty(0, dtype=object), np.zeros((0, 2)), np.zeros(0, int))
    geoms = np.array([shapely.LineString(xy) for xy in lines], dtype=object)
    keep = np.asarray(keep)
    ok = shapely.is_simple(geoms) & (shapely.length(geoms) > 0)
    out_lines, out_k = geoms[ok], keep[ok]
    if not len(out_lines):
        return Candidates(np.empty(0, dtype=object), np.zeros((0, 2)), np.zeros(0, int))
    # greedy deactivation: seeds within d_eps of an accepted streamline of the same
    # orientation make no further candidate
    order = rng.permutation(len(out_lines))
    seed_xy = starts[out_k]
    orient = out_k // n
    active = np.ones(len(out_lines), dtype=bool)
    accepted = []
    for i in order:
        if not active[i]:
            continue
        accepted.append(i)
        same = orient == orient[i]
        close = shapely.dwithin(out_lines[i], shapely.points(seed_xy), d_eps)
        active &= ~(same & close)
    accepted = np.asarray(accepted)
    return Candidates(out_lines[accepted], seed_xy[accepted], orient[accepted])


def _last_inside(path: np.ndarray) -> int:
    """Index of the last distinct point of a trace before it stopped (the point outside)."""
    moved = np.flatnonzero(np.hypot(*(path[1:] - path[:-1]).T) > 0)
    return int(moved[-1]) if len(moved) else 0


def _dedupe(xy: np.ndarray) -> np.ndarray:
    keep = np.ones(len(xy), dtype=bool)
    keep[1:] = np.hypot(*(xy[1:] - xy[:-1]).T) > 1e-9
    return xy[keep]


def width_fit(widths, max_total: float, sigma: float, weights=None):
    """opt(y): how well a distance y is a sum of template widths (Yang 2013, DB score).

    All sums of the widths up to ``max_total`` are enumerated (exhaustive search up to a
    threshold); opt(y) = max over the sums s of w_s exp(-(y - s)^2 / 2 sigma^2), w_s the
    largest product of the template ``weights`` (their user probabilities, default 1)
    over the ways of making s, so that a distance filled by the preferred templates
    (double strips: less street per parcel) scores higher; beyond the threshold any
    distance can be explained later and opt = 0.5.

    Examples
    --------
    >>> f = width_fit([45.0, 75.0], 300.0, 5.0)
    >>> [round(float(v), 2) for v in f(np.array([45.0, 90.0, 60.0, 1000.0]))]
    [1.0, 1.0, 0.01, 0.5]
    >>> g = width_fit([45.0, 75.0], 300.0, 5.0, weights=[0.6, 1.0])
    >>> [round(float(v), 2) for v in g(np.array([45.0, 75.0, 150.0]))]
    [0.6, 1.0, 1.0]
    """
    if weights is None:
        weights = [1.0] * len(widths)
    pairs = [(float(w), float(p)) for w, p in zip(widths, weights) if w > 0 and p > 0]
    best = {0.0: 1.0}
    frontier = {0.0}
    while frontier:
        nxt = set()
        for s in frontier:
            for w, p in pairs:
                t = round(s + w, 6)
                if t <= max_total + 1e-9 and best[s] * p > best.get(t, 0.0):
                    best[t] = best[s] * p
                    nxt.add(t)
        frontier = nxt
    best.pop(0.0)
    sums = np.array(sorted(best))
    wts = np.array([best[s] for s in sums])

    def opt(y):
        y = np.asarray(y, dtype=float)
        if len(sums) == 0:
            return np.full(y.shape, 0.5)
        fit = np.max(wts * np.exp(-0.5 * ((y[..., None] - sums) / sigma) ** 2), axis=-1)
        return np.where(y > max_total, 0.5, fit)

    return opt


def _resample(lines: np.ndarray, step: float):
    """Points every ``step`` m along each line and the owner index."""
    length = shapely.length(lines)
    counts = np.maximum(np.ceil(length / step).astype(int), 1) + 1
    owner = np.repeat(np.arange(len(lines)), counts)
    frac = np.concatenate([np.linspace(0, 1, c) for c in counts])
    pts = shapely.line_interpolate_point(lines[owner], frac, normalized=True)
    return shapely.get_coordinates(pts), owner, frac


def score_streamlines(cands: Candidates, field: CrossField, region, opt, ends=None,
                      step: float = 4.0, weights=QUALITY_WEIGHTS):
    """Quality of each candidate (higher is better) and its four raw components.

    Parameters
    ----------
    cands : Candidates
    field : CrossField
    region : Polygon
    opt : callable
        :func:`width_fit` of the template widths.
    ends : ndarray (k, 4), optional
        Existing street ends: x, y and the unit direction pointing out of the street.
    step : float
        Sampling step along the streamlines (m).

    Returns
    -------
    qual : ndarray
        Sum of the normalised components (weights one): (1 - DIV) + DB + (1 - DS) + (1 - CT).
    parts : dict of ndarrays
        Raw ``div``, ``db``, ``ds``, ``ct``.
    """
    lines = cands.lines
    n = len(lines)
    if n == 0:
        return np.zeros(0), {}
    xy, owner, _ = _resample(lines, step)
    length = shapely.length(lines)
    # divergence of the unit field along the line = derivative of its angle across it
    tangent = np.zeros_like(xy)
    tangent[1:] = xy[1:] - xy[:-1]
    first = np.r_[True, owner[1:] != owner[:-1]]
    tangent[first] = (xy[np.flatnonzero(first) + 1] - xy[first]) if len(xy) > 1 else 1.0
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-12)[:, None]
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    eps = field.h
    da, _ = field.direction(xy + eps * normal, tangent)
    db_, _ = field.direction(xy - eps * normal, tangent)
    dphi = np.arctan2(da[:, 0] * db_[:, 1] - da[:, 1] * db_[:, 0],
                      (da * db_).sum(axis=1)) / (2 * eps)
    div = np.bincount(owner, np.abs(dphi) * step, minlength=n) / \
        np.maximum(length, 1e-9) ** DIVERGENCE_P
    # distance to the boundary explained by template widths, on both sides: the
    # boundary is found along the streamline's normal (a ray each way), so that the
    # strips between the streamline and the boundary fit on the left and on the right
    boundary = shapely.boundary(region)
    reach = float(np.hypot(*(np.subtract(*np.reshape(shapely.bounds(region), (2, 2)))))) + 1.0
    both = np.concatenate([xy, xy])   # a ray each way, cast against the outline at once
    d = first_hits(both, np.concatenate([normal, -normal]), [boundary], reach, start=0.01)
    missed = ~np.isfinite(d)
    if missed.any():
        d[missed] = shapely.distance(boundary, shapely.points(both[missed]))
    side = np.split(d, 2)
    pointwise = np.sqrt(opt(side[0]) * opt(side[1]))
    count = np.bincount(owner, minlength=n)
    dbs = np.bincount(owner, pointwise, minlength=n) / np.maximum(count, 1)
    # distance to singularities (smaller preferred)
    if len(field.singularities):
        ds = shapely.distance(lines[:, None], shapely.points(field.singularities)[None, :]).min(1)
    else:
        ds = np.zeros(n)
    # continuity with existing street ends
    ct = np.ones(n)
    if ends is not None and len(ends):
        cont = np.zeros(n)
        for which in (0, -1):
            coords = [shapely.get_coordinates(g) for g in lines]
            p = np.array([c[which] for c in coords])
            q = np.array([c[1] if which == 0 else c[-2] for c in coords])
            out_dir = p - q  # pointing out of the candidate at this end
            out_dir /= np.maximum(np.hypot(out_dir[:, 0], out_dir[:, 1]), 1e-12)[:, None]
            d = np.hypot(p[:, None, 0] - ends[None, :, 0], p[:, None, 1] - ends[None, :, 1])
            # continuing a street: the candidate's outward direction is opposite to the
            # existing street's outward direction
            cosang = -(out_dir[:, None, 0] * ends[None, :, 2] + out_dir[:, None, 1] * ends[None, :, 3])
            ok = (d <= CONTINUITY_DIST) & (cosang >= np.cos(np.radians(CONTINUITY_ANGLE)))
            cont += ok.any(axis=1)
        ct = 1.0 - 0.5 * np.minimum(cont, 2)
    l1, l2, l3, l4 = weights
    qual = l1 * (1 - _norm(div)) + l2 * _norm(dbs) + l3 * (1 - _norm(ds)) + l4 * (1 - ct)
    return qual, {"div": div, "db": dbs, "ds": ds, "ct": ct}


def _norm(v: np.ndarray) -> np.ndarray:
    lo, hi = np.min(v), np.max(v)
    return np.zeros_like(v) if hi - lo < 1e-12 else (v - lo) / (hi - lo)

