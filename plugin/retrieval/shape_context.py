"""Scale-aware, rotation-invariant shape context with a terrain term, cyclic DTW, rigid alignment.

The retrieval machinery of Hartmann's thesis, used for road fragments (ch. 4.1.2,
"Retrieval") and for city blocks and footprints (ch. 5.1):

- boundaries are described by ``n = 100`` uniform arc-length samples of the exterior ring
  (ch. 5.1 gives 100 samples, 8 angular x 5 radial bins);
- each sample gets a log-polar histogram of where the other samples lie (Belongie, Malik
  and Puzicha 2000), **rotation invariant** because angles are measured from the local
  tangent, and **scale aware** because the radial bin edges are absolute distances in
  metres (the thesis does *not* normalise by the mean distance, so a block twice as large
  is a worse match). The text's tangent alignment is used, not the centre-of-gravity
  alignment of the caption of the thesis's Fig. 4.5. The edges are
  ``scale * logspace(1/8 .. 2)`` where ``scale`` is one number per database (the median
  mean inter-sample distance of its shapes), stored with the database so that queries use
  the same bins;
- the per-point shape cost C^S is Belongie's chi-square distance, the elevation cost C^E
  compares the slopes from each sample to its bin centres (thesis eq. 4.3), combined as
  ``gamma * C^S + (1 - gamma) * C^E`` (eq. 4.2; the thesis gives no gamma);
- the correspondence is the least-cost cyclic dynamic-time-warping path (Sakoe and Chiba
  1978). The thesis does not say how the cyclic start is found; we try start offsets,
  vectorised over offsets and candidates;
- a least-squares rigid transform (Kabsch / Procrustes without scale, ch. 5.1) aligns the
  matched shape with the query from the correspondences.

Everything works on arrays of many shapes at once (numpy broadcasting, shapely 2
vectorised functions); the only Python loops run over the rows of the DTW table and
over the backtracked path of one match.

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 4.1.2
(fragment retrieval, slope term, eqs. 4.1-4.3) and ch. 5.1 (block retrieval, 100 samples,
8 x 5 bins, Procrustes alignment).
Belongie, S., Malik, J., Puzicha, J. Shape context: a new descriptor for shape matching
and object recognition. NIPS 2000.
Sakoe, H., Chiba, S. Dynamic programming algorithm optimization for spoken word
recognition. IEEE TASSP 1978.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence, Tuple

import numpy as np
import shapely

from ..core import coordinates
from ..core.coordinates import apply_affine
from ..core.progress import InputError

__all__ = [
    "N_SAMPLES", "N_ANGULAR", "N_RADIAL", "INNER", "OUTER",
    "DTWResult", "DemGrid",
    "exterior_rings", "sample_boundaries", "tangent_angles", "default_scale", "radial_edges",
    "shape_contexts", "normalised_histograms", "bin_centres", "slope_descriptors",
    "chi2_cost", "elevation_cost", "combined_cost",
    "DTW_WINDOW", "cyclic_dtw_costs", "cyclic_dtw", "dtw_path",
    "rigid_align", "apply_rigid", "transform_geometries",
]

#: Boundary samples per shape (thesis ch. 5.1).
N_SAMPLES = 100
#: Angular bins of the log-polar histogram (thesis ch. 5.1).
N_ANGULAR = 8
#: Radial bins of the log-polar histogram (thesis ch. 5.1).
N_RADIAL = 5
#: Inner and outer radial edge as multiples of the database scale (Belongie's 1/8 .. 2).
INNER = 0.125
OUTER = 2.0


# --------------------------------------------------------------------------- sampling

def exterior_rings(polygons: Sequence) -> np.ndarray:
    """Counter-clockwise exterior rings of polygons (the largest part of a multipolygon).

    Parameters
    ----------
    polygons : array of Polygon / MultiPolygon

    Returns
    -------
    ndarray of LinearRing, oriented counter-clockwise so that every boundary is walked with
    its interior on the left (the cyclic DTW compares sequences of the same orientation).
    """
    geoms = np.asarray(polygons, dtype=object).copy()
    if len(geoms) == 0:
        return geoms
    if shapely.is_empty(geoms).any() or shapely.is_missing(geoms).any():
        raise InputError("empty polygon: it has no boundary to sample")
    multi = np.flatnonzero(shapely.get_type_id(geoms) != 3)
    if len(multi):
        parts, idx = shapely.get_parts(geoms[multi], return_index=True)
        if len(parts) == 0 or (shapely.get_type_id(parts) != 3).any():
            raise InputError("only polygons have a boundary to sample")
        area = shapely.area(parts)
        order = np.lexsort((-area, idx))  # per source geometry, the largest part first
        first = order[np.r_[True, idx[order][1:] != idx[order][:-1]]]
        geoms[multi[idx[first]]] = parts[first]
    rings = shapely.get_exterior_ring(geoms)
    ccw = shapely.is_ccw(rings)
    if not ccw.all():
        rings = np.where(ccw, rings, shapely.reverse(rings))
    return rings


def sample_boundaries(polygons: Sequence, n: int = N_SAMPLES) -> np.ndarray:
    """Uniform arc-length samples of the exterior boundary of many polygons at once.

    The walk is counter-clockwise and starts, deterministically, at the ring vertex farthest
    from the polygon's centroid (the first one in ring order when several are within a
    relative 1e-7): that vertex does not depend on where the digitiser started the ring,
    nor on a rotation or translation, so a moved copy of a shape gets the same samples.

    Parameters
    ----------
    polygons : array of Polygon / MultiPolygon (metric CRS)
    n : int
        Samples per boundary (thesis ch. 5.1: 100).

    Returns
    -------
    samples : (k, n, 2) float64 array

    References
    ----------
    Hartmann, thesis ch. 4.1.2 ("uniform points on the fragment boundary") and ch. 5.1
    ("100 evenly spaced boundary samples").

    Examples
    --------
    >>> s = sample_boundaries([shapely.box(0, 0, 10, 10)], n=4)
    >>> s.shape
    (1, 4, 2)
    """
    if n < 3:
        raise InputError("at least 3 boundary samples are needed")
    polygons = np.asarray(polygons, dtype=object)
    k = len(polygons)
    if k == 0:
        return np.zeros((0, n, 2))
    rings = exterior_rings(polygons)
    length = shapely.length(rings)
    if (length <= 0).any():
        raise InputError("a polygon has a boundary of zero length")
    centroid = shapely.get_coordinates(shapely.centroid(shapely.polygons(rings)))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    d = np.hypot(coords[:, 0] - centroid[idx, 0], coords[:, 1] - centroid[idx, 1])
    starts = np.r_[0, np.flatnonzero(np.diff(idx)) + 1]
    dmax = np.maximum.reduceat(d, starts)
    # first vertex (ring order) within a relative tolerance of the maximum: robust to the
    # round-off of a rotated copy, where two equally far corners must not swap
    near = np.flatnonzero(d >= dmax[idx] * (1.0 - 1e-7))
    _, first = np.unique(idx[near], return_index=True)
    start_pt = shapely.points(coords[near[first]])
    s0 = shapely.line_locate_point(rings, start_pt)
    pos = (s0[:, None] + length[:, None] * (np.arange(n) / n)[None, :]) % length[:, None]
    pts = shapely.line_interpolate_point(np.repeat(rings, n), pos.ravel())
    return shapely.get_coordinates(pts).reshape(k, n, 2)


def tangent_angles(samples: np.ndarray) -> np.ndarray:
    """Direction of the boundary at each sample (radians), from its two cyclic neighbours.

    A central difference of the samples is smoother than the direction of the ring segment
    under the sample, and it rotates exactly with the shape.

    Parameters
    ----------
    samples : (..., n, 2) array

    Returns
    -------
    (..., n) array of angles in (-pi, pi]
    """
    samples = np.asarray(samples, dtype=np.float64)
    d = np.roll(samples, -1, axis=-2) - np.roll(samples, 1, axis=-2)
    return np.arctan2(d[..., 1], d[..., 0])


def default_scale(samples: np.ndarray) -> float:
    """The database scale: median over shapes of the mean distance between samples.

    Belongie normalises every shape by its own mean distance, which would make the
    descriptor scale invariant; the thesis wants scale-aware histograms, so we use one
    absolute scale for a whole database (stored with it) and keep the bins in metres.

    Parameters
    ----------
    samples : (k, n, 2) array

    Returns
    -------
    float, metres
    """
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 3 or len(samples) == 0:
        raise InputError("no shapes to derive a shape-context scale from")
    if len(samples) > 512:
        # a median is stable on a deterministic, evenly spread subset; all pairs of 100
        # samples for thousands of shapes cost seconds
        samples = samples[np.linspace(0, len(samples) - 1, 512).round().astype(int)]
    n = samples.shape[1]
    means = np.empty(len(samples))
    for a in range(0, len(samples), 256):  # chunks bound the (chunk, n, n) memory
        s = samples[a:a + 256]
        d = np.linalg.norm(s[:, :, None, :] - s[:, None, :, :], axis=-1)
        means[a:a + 256] = d.sum(axis=(1, 2)) / (n * (n - 1))
    scale = float(np.median(means))
    if not np.isfinite(scale) or scale <= 0:
        raise InputError("the shapes are degenerate: no shape-context scale")
    return scale


def radial_edges(scale: float, n_radial: int = N_RADIAL, inner: float = INNER,
                 outer: float = OUTER) -> np.ndarray:
    """Absolute log-spaced radial bin edges in metres: ``scale * logspace(inner, outer)``.

    Parameters
    ----------
    scale : float
        The database scale in metres (:func:`default_scale`).
    n_radial : int
        Number of radial bins (thesis ch. 5.1: 5).
    inner, outer : float
        First and last edge as multiples of ``scale`` (Belongie: 1/8 and 2).

    Returns
    -------
    (n_radial + 1,) array. Distances below the second edge fall in the first bin and
    distances beyond the last-but-one in the last bin (clipped), so every histogram counts
    all n - 1 other samples and the chi-square cost stays in [0, 1].
    """
    if not (scale > 0 and np.isfinite(scale)):
        raise InputError(f"shape-context scale must be a positive number of metres, got {scale}")
    if not 0 < inner < outer:
        raise InputError("radial bins need 0 < inner < outer")
    return scale * np.logspace(np.log10(inner), np.log10(outer), n_radial + 1)


# --------------------------------------------------------------------------- histograms

def shape_contexts(samples: np.ndarray, edges: np.ndarray, n_angular: int = N_ANGULAR,
                   chunk: int = 64) -> np.ndarray:
    """Log-polar shape-context histograms of every sample of every shape.

    For sample i, every other sample j is binned by the distance |p_j - p_i| (absolute
    ``edges``, in metres) and by the angle of p_j - p_i measured from the tangent at p_i,
    which makes the histogram rotation invariant. Angular bin a is *centred* on
    ``a * 2 pi / n_angular`` from the tangent: samples on the same straight edge lie at
    exactly 0 or pi, and a bin border there would let round-off flip them between bins.
    Bins are ordered radial-major: ``r * n_angular + a``.

    Parameters
    ----------
    samples : (k, n, 2) or (n, 2) array of boundary samples
    edges : radial bin edges in metres (:func:`radial_edges`)
    n_angular : int
        Angular bins (thesis ch. 5.1: 8).
    chunk : int
        Shapes per vectorised block (bounds memory to a few chunk * n * n arrays).

    Returns
    -------
    (k, n, n_radial * n_angular) uint8 counts (or (n, B) for one shape); each row sums to
    n - 1. Divide by n - 1 (:func:`normalised_histograms`) before comparing.

    References
    ----------
    Belongie, Malik, Puzicha 2000; Hartmann, thesis ch. 4.1.2 (rotation invariance by the
    local tangent, no normalisation by the mean distance).
    """
    samples = np.asarray(samples, dtype=np.float64)
    single = samples.ndim == 2
    if single:
        samples = samples[None]
    k, n, _ = samples.shape
    if n > 256:
        raise InputError("at most 256 samples per boundary (histogram counts are 8-bit)")
    if n_angular < 1:
        raise InputError("at least one angular bin is needed")
    edges = np.asarray(edges, dtype=np.float64)
    n_radial = len(edges) - 1
    n_bins = n_radial * n_angular
    out = np.zeros((k, n, n_bins), dtype=np.uint8)
    inner_sq = (edges[1:-1] ** 2).astype(np.float32)
    diag = np.arange(n)
    for a in range(0, k, chunk):
        s = samples[a:a + chunk]
        m = len(s)
        # relative coordinates in float32 (metres around the shape: ample precision) keep
        # the (m, n, n) temporaries small; x and y apart avoid strided access
        centre = s.mean(axis=1, keepdims=True)
        x = (s[..., 0] - centre[..., 0]).astype(np.float32)
        y = (s[..., 1] - centre[..., 1]).astype(np.float32)
        phi = tangent_angles(s)
        if n_angular == 8:
            phi = phi - np.pi / 8  # octant borders at multiples of 45 degrees (fast path)
        else:
            phi = phi - np.pi / n_angular
        cos = np.cos(phi).astype(np.float32)[:, :, None]
        sin = np.sin(phi).astype(np.float32)[:, :, None]
        dx = x[:, None, :] - x[:, :, None]                         # p_j - p_i
        dy = y[:, None, :] - y[:, :, None]
        u = dx * cos + dy * sin                                    # tangent frame of p_i
        w = dy * cos - dx * sin
        r2 = dx * dx
        r2 += dy * dy
        del dx, dy
        rbin = np.zeros(r2.shape, dtype=np.int32)
        for e in inner_sq:
            rbin += r2 >= e
        if n_angular == 8:
            # octant from signs and |w| >= |u|: three comparisons instead of an arctan2
            un, wn = u < 0, w < 0
            steep = np.abs(w) >= np.abs(u)
            odd = un ^ wn                                          # quadrants 1 and 3
            abin = (wn.astype(np.int32) * 4 + odd.astype(np.int32) * 2
                    + (steep ^ odd).astype(np.int32))
        else:
            ang = np.mod(np.arctan2(w, u), 2 * np.pi)
            abin = np.minimum((ang * (n_angular / (2 * np.pi))).astype(np.int32), n_angular - 1)
        flat = rbin
        flat *= n_angular
        flat += abin
        flat += (np.arange(m * n, dtype=np.int32) * n_bins).reshape(m, n, 1)
        flat[:, diag, diag] = m * n * n_bins                       # self pairs: a dummy slot
        counts = np.bincount(flat.ravel(), minlength=m * n * n_bins + 1)[:-1]
        out[a:a + m] = counts.reshape(m, n, n_bins)
    return out[0] if single else out


def normalised_histograms(counts: np.ndarray) -> np.ndarray:
    """Histogram counts -> fractions of the other samples (float32, rows sum to 1)."""
    counts = np.asarray(counts)
    total = counts.sum(axis=-1, keepdims=True, dtype=np.float32)
    return (counts / np.maximum(total, 1)).astype(np.float32)


def bin_centres(samples: np.ndarray, edges: np.ndarray,
                n_angular: int = N_ANGULAR) -> Tuple[np.ndarray, np.ndarray]:
    """World coordinates of the log-polar bin centres around every sample.

    The centre of radial bin r is at the geometric mean of its edges, the centre of angular
    bin a at ``a * 2 pi / n_angular`` from the local tangent; bins are ordered like
    :func:`shape_contexts`.

    Returns
    -------
    (..., n, n_radial * n_angular, 2) array, and the centre radius of each bin
    ``(n_radial * n_angular,)`` as a second value.
    """
    samples = np.asarray(samples, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.float64)
    n_radial = len(edges) - 1
    rad = np.sqrt(edges[:-1] * edges[1:])
    ang = np.arange(n_angular) * (2 * np.pi / n_angular)
    rr = np.repeat(rad, n_angular)                   # (B,) radial-major
    aa = np.tile(ang, n_radial)
    phi = tangent_angles(samples)[..., None] + aa    # (..., n, B)
    centres = samples[..., None, :] + np.stack([rr * np.cos(phi), rr * np.sin(phi)], axis=-1)
    return centres, rr


def slope_descriptors(samples: np.ndarray, elevation: Callable[[np.ndarray], np.ndarray],
                      edges: np.ndarray, n_angular: int = N_ANGULAR,
                      max_slope: float = 1.0) -> np.ndarray:
    """Slope descriptor SL(i) of every sample: slopes to the shape-context bin centres.

    ``sl_it = (E(bin centre t) - E(p_i)) / l_t`` with l_t the distance from p_i to the
    centre (thesis Fig. 4.5). Slopes are clipped to +-``max_slope`` (the thesis assumes
    urban slopes <= 1, which keeps C^E in [0, 1]); where the DEM has no value the slope is 0.

    Parameters
    ----------
    samples : (k, n, 2) or (n, 2) array
    elevation : callable
        ``elevation(xy)`` with xy of shape (..., 2) returns heights of shape (...);
        e.g. a :class:`DemGrid`. NaN means no data.
    edges : radial bin edges (:func:`radial_edges`)

    Returns
    -------
    (k, n, v) float32 array, v = n_radial * n_angular (or (n, v) for one shape).

    References
    ----------
    Hartmann, thesis ch. 4.1.2, eq. 4.3 and Fig. 4.5.
    """
    samples = np.asarray(samples, dtype=np.float64)
    centres, rr = bin_centres(samples, edges, n_angular)
    e_bins = np.asarray(elevation(centres), dtype=np.float64)
    e_pts = np.asarray(elevation(samples), dtype=np.float64)
    sl = (e_bins - e_pts[..., None]) / rr
    sl = np.where(np.isfinite(sl), sl, 0.0)
    return np.clip(sl, -max_slope, max_slope).astype(np.float32)


#: Cells of the holes :meth:`DemGrid.filled` fills smoothly in one sparse solve (6 s for
#: 360,000 cells on this 2-core machine); larger holes take the nearest cell's height.
MAX_HOLE_CELLS = 400_000


@dataclass
class DemGrid:
    """A north-up elevation grid with a GDAL geotransform, sampled bilinearly.

    Parameters
    ----------
    array : (rows, cols) float array of heights (metres); NaN where there is no data
    geotransform : GDAL-style (x0, dx, 0, y0, 0, dy) with dy < 0 for a north-up grid
    nodata : optional value replaced by NaN

    Points outside the grid take the height of the nearest edge cell, so a fragment that
    pokes out of a clipped DEM gets flat slopes there rather than garbage.
    """

    array: np.ndarray
    geotransform: Tuple[float, float, float, float, float, float]
    nodata: Optional[float] = None

    def __post_init__(self):
        a = np.asarray(self.array, dtype=np.float64)
        if a.ndim != 2 or a.size == 0:
            raise InputError("the DEM must be a non-empty 2-D grid")
        if self.nodata is not None and np.isfinite(self.nodata):
            a = np.where(a == self.nodata, np.nan, a)
        gt = tuple(float(v) for v in self.geotransform)
        if gt[2] != 0 or gt[4] != 0 or gt[1] == 0 or gt[5] == 0:
            raise InputError("the DEM must be a north-up grid without rotation")
        self.array = a
        self.geotransform = gt

    @property
    def cell_size(self) -> float:
        return abs(self.geotransform[1])

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        x0, dx, _, y0, _, dy = self.geotransform
        rows, cols = self.array.shape
        # continuous cell coordinates of cell centres
        c = np.clip((xy[..., 0] - x0) / dx - 0.5, 0, cols - 1)
        r = np.clip((xy[..., 1] - y0) / dy - 0.5, 0, rows - 1)
        c0 = np.minimum(np.floor(c).astype(np.int64), max(cols - 2, 0))
        r0 = np.minimum(np.floor(r).astype(np.int64), max(rows - 2, 0))
        c1 = np.minimum(c0 + 1, cols - 1)
        r1 = np.minimum(r0 + 1, rows - 1)
        fc, fr = c - c0, r - r0
        a = self.array
        top = a[r0, c0] * (1 - fc) + a[r0, c1] * fc
        bottom = a[r1, c0] * (1 - fc) + a[r1, c1] * fc
        return top * (1 - fr) + bottom * fr

    def filled(self) -> Tuple["DemGrid", np.ndarray]:
        """The grid with every cell without a value given one, and the distance (m) to the
        nearest cell with its own value (0 where it has one).

        A hole (cells without a value enclosed by cells with one) is filled smoothly: the
        harmonic surface through its rim (Laplace's equation, as GDAL's FillNodata
        smooths), so no step appears where a street crosses it; beyond the DEM's edge the
        nearest edge cell's height goes on (flat).

        >>> a = np.array([[1.0, 2.0, 3.0], [1.0, np.nan, 3.0], [1.0, 2.0, 3.0]])
        >>> g, d = DemGrid(a, (0, 10, 0, 30, 0, -10)).filled()
        >>> float(g.array[1, 1]), float(d[1, 1])
        (2.0, 10.0)
        >>> b = np.array([[1.0, np.nan, np.nan], [4.0, 5.0, np.nan]])
        >>> DemGrid(b, (0, 10, 0, 20, 0, -10)).filled()[0].array.tolist()
        [[1.0, 1.0, 5.0], [4.0, 5.0, 5.0]]
        """
        from scipy.ndimage import distance_transform_edt, label
        from scipy.sparse import coo_matrix
        from scipy.sparse.linalg import spsolve

        a = self.array
        missing = ~np.isfinite(a)
        if not missing.any() or missing.all():
            return self, np.zeros(a.shape)
        dist, (ri, ci) = distance_transform_edt(
            missing, sampling=(abs(self.geotransform[5]), abs(self.geotransform[1])),
            return_indices=True)
        out = a[ri, ci]
        # holes: the missing regions that do not reach the grid's border
        regions, _ = label(missing)
        border = np.unique(np.r_[regions[0], regions[-1], regions[:, 0], regions[:, -1]])
        hole = missing & ~np.isin(regions, border)
        n = int(hole.sum())
        if 0 < n <= MAX_HOLE_CELLS:
            index = np.full(a.shape, -1, dtype=np.int64)
            index[hole] = np.arange(n)
            r, c = np.nonzero(hole)
            rows, cols, vals = [np.arange(n)], [np.arange(n)], [np.full(n, 4.0)]
            rhs = np.zeros(n)
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                # a hole touches no border: every neighbour is inside the grid
                rr, cc = r + dr, c + dc
                unknown = hole[rr, cc]
                rows.append(np.arange(n)[unknown])
                cols.append(index[rr[unknown], cc[unknown]])
                vals.append(np.full(int(unknown.sum()), -1.0))
                rhs[~unknown] += a[rr[~unknown], cc[~unknown]]
            lap = coo_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))), shape=(n, n))
            out[hole] = spsolve(lap.tocsr(), rhs)
        return DemGrid(out, self.geotransform), dist

    def slope(self) -> np.ndarray:
        """Slope magnitude (rise over run) of every cell, by central differences."""
        gy, gx = np.gradient(self.array, abs(self.geotransform[5]), abs(self.geotransform[1]))
        return np.hypot(gx, gy)


# --------------------------------------------------------------------------- costs

def chi2_cost(h1: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """Belongie's chi-square cost between every pair of histograms.

    ``C_ij = 1/2 sum_k (h1_ik - h2_jk)^2 / (h1_ik + h2_jk)`` (0/0 = 0).

    Computed as ``1/2 (sum_k h1_ik + sum_k h2_jk) - 2 sum_k h1_ik h2_jk / (h1_ik + h2_jk)``,
    which is the same sum rewritten so that a bin empty on either side adds nothing: only
    bins occupied on both sides are visited (boundary histograms fill about a third of
    their 40 bins), with ``a b / (a + b) = 1 / (1/a + 1/b)`` two (..., n, m) passes per bin
    instead of an (..., n, m, B) temporary.

    Parameters
    ----------
    h1 : (..., n, B) normalised histograms (:func:`normalised_histograms`)
    h2 : (..., m, B), broadcastable with h1 over the leading dimensions

    Returns
    -------
    (..., n, m) float32 costs in [0, 1] for normalised histograms.
    """
    a = np.asarray(h1, dtype=np.float32)
    b = np.asarray(h2, dtype=np.float32)
    lead = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    n, m = a.shape[-2], b.shape[-2]
    total = 0.5 * (a.sum(-1)[..., :, None] + b.sum(-1)[..., None, :])
    used = np.flatnonzero(a.reshape(-1, a.shape[-1]).any(0) & b.reshape(-1, b.shape[-1]).any(0))
    acc = np.zeros(lead + (n, m), dtype=np.float32)
    # a b / (a + b) = 1 / (1/a + 1/b), with 1/0 = inf giving 0: two passes per bin
    with np.errstate(divide="ignore"):
        ia = np.float32(1) / a
        ib = np.float32(1) / b
    tmp = np.empty_like(acc)
    for k in used:
        np.add(ia[..., :, k, None], ib[..., None, :, k], out=tmp)
        np.reciprocal(tmp, out=tmp)
        acc += tmp
    out = total - 2 * acc
    return np.maximum(out, 0, out=out).astype(np.float32, copy=False)


def elevation_cost(sl1: np.ndarray, sl2: np.ndarray) -> np.ndarray:
    """Thesis eq. 4.3: ``C^E_ij = ||SL(i) - SL(j)|| / (2 sqrt(v))`` for every pair.

    Parameters
    ----------
    sl1 : (..., n, v) slope descriptors; sl2 : (..., m, v)

    Returns
    -------
    (..., n, m) float32 costs in [0, 1] for slopes within +-1.
    """
    a = np.asarray(sl1, dtype=np.float32)
    b = np.asarray(sl2, dtype=np.float32)
    v = a.shape[-1]
    # |a|^2 + |b|^2 - 2 a.b: one matrix product instead of an (n, m, v) difference
    sq = (a * a).sum(-1)[..., :, None] + (b * b).sum(-1)[..., None, :] \
        - 2 * np.matmul(a, np.swapaxes(b, -1, -2))
    return (np.sqrt(np.maximum(sq, 0)) / (2 * np.sqrt(v))).astype(np.float32)


def combined_cost(h1: np.ndarray, h2: np.ndarray, sl1: Optional[np.ndarray] = None,
                  sl2: Optional[np.ndarray] = None, gamma: float = 0.5) -> np.ndarray:
    """Thesis eq. 4.2 per point pair: ``gamma * C^S + (1 - gamma) * C^E``.

    Without slope descriptors on both sides the cost is C^S alone (the thesis drops the
    terrain term for blocks, ch. 5.1).
    """
    cs = chi2_cost(h1, h2)
    if sl1 is None or sl2 is None or gamma >= 1:
        return cs
    if not 0 <= gamma <= 1:
        raise InputError(f"gamma must lie in [0, 1], got {gamma}")
    return gamma * cs + (1 - gamma) * elevation_cost(sl1, sl2)


# --------------------------------------------------------------------------- DTW

def _diag_index(n: int, m: int) -> np.ndarray:
    """Column of row i on the straight path from (0, 0) to (n - 1, m - 1)."""
    if n == 1:
        return np.zeros(1, dtype=np.int64)
    return np.floor(np.arange(n) * (m - 1) / (n - 1) + 0.5).astype(np.int64)


def _dtw_rows(cost: np.ndarray, offsets: np.ndarray, window: Optional[int]) -> np.ndarray:
    """DTW total cost with both ends fixed, for each start offset (vectorised).

    ``cost`` (..., n, m), ``offsets`` (..., s) int: the column sequence of B is rolled to
    start at the offset. Returns (..., s) costs of the best monotone path from (0, 0) to
    (n - 1, m - 1) of each rolled matrix, within ``window`` columns of the straight
    diagonal (Sakoe and Chiba's adjustment window; None: no window).

    The row update D[i, j] = c_j + min(D[i-1, j], D[i-1, j-1], D[i, j-1]) is unrolled to
    D[i, j] = S_j + cummin_k<=j (t_k - S_k) with S the running sum of the row's costs and
    t_k = c_k + min(D[i-1, k], D[i-1, k-1]): one numpy pass per row instead of a scalar
    loop over columns, for all offsets and candidates at once. Each row only holds the
    2 window + 1 columns around the diagonal, which is what makes a query fast.
    """
    n, m = cost.shape[-2:]
    lead = cost.shape[:-2]
    if window is None or 2 * int(window) + 1 >= m:
        width = m                                                     # the whole row
        start = np.zeros(n, dtype=np.int64)
    else:
        width = 2 * int(window) + 1
        start = _diag_index(n, m) - int(window)                       # first column per row
    if np.diff(start).max(initial=0) > 2:
        raise InputError("cyclic DTW needs n >= m / 2 samples")
    j = start[:, None] + np.arange(width)[None, :]                    # (n, W) columns
    valid = (j >= 0) & (j < m)
    # Layout (row, window column, batch) with batch = every (candidate, offset) pair
    # contiguous last: the running sums and minima along the window are then numpy passes
    # over whole batch vectors instead of many short rows.
    n_lead = int(np.prod(lead, dtype=np.int64))
    offs = np.asarray(offsets).reshape(n_lead, -1)                    # (L, s)
    n_off = offs.shape[1]
    batch = n_lead * n_off
    # one np.take from the column-doubled cost: column offset + j of the doubled row is
    # column (offset + j) mod m of the original
    doubled = np.asarray(cost, dtype=np.float64).reshape(n_lead, n, m)
    flat_cost = np.concatenate([doubled, doubled], axis=-1).reshape(-1)
    lead_base = (np.repeat(np.arange(n_lead), n_off) * (n * 2 * m) + offs.reshape(-1))  # (B,)
    row_base = np.arange(n)[:, None] * (2 * m) + np.clip(j, 0, m - 1)                  # (n, W)
    band = np.take(flat_cost, row_base[:, :, None] + lead_base[None, None, :])       # (n, W, B)
    # what does not depend on the previous row, for all rows at once: the running sums S
    # and c_k - S_k. Columns outside the matrix hold some finite cost; they get t = +inf
    # below, and S only enters through differences between valid columns.
    run = np.empty_like(band)
    run[:, 0] = band[:, 0]
    for k in range(1, width):  # faster than np.cumsum along a short middle axis
        np.add(run[:, k - 1], band[:, k], out=run[:, k])
    excl = band - run
    outside = np.where(valid, 0.0, np.inf)
    edge_rows = np.flatnonzero(~valid.all(axis=1))
    excl[edge_rows] += outside[edge_rows][:, :, None]
    # previous row with an inf column on top (diagonal move into the window's first
    # column) and two below (the window moves right by up to two columns per row)
    buf = np.full((width + 3, batch), np.inf)
    first = -start[0]                                                 # window index of column 0
    buf[1:width + 1] = run[0] - (run[0, first - 1:first] if first > 0 else 0.0) \
        + outside[0][:, None]
    for i in range(1, n):
        shift = int(start[i] - start[i - 1])
        t = np.minimum(buf[1 + shift:1 + shift + width], buf[shift:shift + width])
        t += excl[i]
        np.minimum.accumulate(t, axis=0, out=t)
        t += run[i]
        buf[1:width + 1] = t
    return buf[1 + (m - 1) - start[-1]].reshape(lead + (n_off,))


#: Default Sakoe-Chiba window (samples either side of the diagonal) for retrieval.
DTW_WINDOW = 12


def cyclic_dtw_costs(cost: np.ndarray, n_offsets: Optional[int] = 3,
                     window: Optional[int] = DTW_WINDOW) -> Tuple[np.ndarray, np.ndarray]:
    """Best cyclic DTW cost and start offset for one or many cost matrices at once.

    The sequence B is cut at a start offset s (B_s, B_s+1, ..., B_s-1) and aligned with
    A by DTW with both ends fixed (A_0 <-> B_s and A_n-1 <-> B_s-1); the cheapest offset
    wins. With ``n_offsets=None`` and ``window=None`` every offset and every path is tried
    (exact, O(n m^2)). For retrieval two standard restrictions make it fast:

    - ``n_offsets``: the offsets are ranked by the cost of a near-diagonal path (each row's
      cheapest column within 3 of the straight diagonal: one O(n m) pass) and only the
      ``n_offsets`` best and their two neighbours get a DTW;
    - ``window``: Sakoe and Chiba's adjustment window, paths stay within this many samples
      of the diagonal (12 of 100 samples lets an eighth of the boundary stretch).

    The result is always the exact cost of a real cyclic path, so never below the optimum,
    and equal to it whenever the best offset and path lie in the searched set, as they do
    for uniform samples of similar shapes, the matches retrieval cares about (see tests).

    Parameters
    ----------
    cost : (..., n, m) point-pair costs (:func:`combined_cost`)
    n_offsets : int or None
    window : int or None

    Returns
    -------
    costs : (...) best total path cost (sum of the point costs along the path)
    offsets : (...) int, the start offset s of that path

    References
    ----------
    Hartmann, thesis ch. 4.1.2 ("Matching": cyclic correspondence by DTW); Sakoe and
    Chiba 1978 (the adjustment window).
    """
    cost = np.asarray(cost, dtype=np.float64)
    n, m = cost.shape[-2:]
    lead = cost.shape[:-2]
    if n_offsets is not None and n_offsets < 1:
        raise InputError("at least one DTW start offset must be tried")
    if n_offsets is None or 3 * n_offsets >= m:
        offsets = np.broadcast_to(np.arange(m), lead + (m,))
    else:
        # each row's cheapest column within 3 of a column: 7 shifted views of a padded copy
        pad = np.concatenate([cost[..., -3:], cost, cost[..., :3]], axis=-1)
        near = pad[..., 0:m].copy()
        for delta in range(1, 7):
            np.minimum(near, pad[..., delta:delta + m], out=near)
        if n == m:
            # diagonal s of the column-doubled matrix, for every s, as a strided view
            near2 = np.concatenate([near, near], axis=-1)
            st = near2.strides
            diags = np.lib.stride_tricks.as_strided(
                near2, shape=near2.shape[:-2] + (m, n),
                strides=st[:-2] + (st[-1], st[-2] + st[-1]), writeable=False)
            ranking = diags.sum(-1)                                    # (..., s)
        else:
            di = _diag_index(n, m)
            cols = (np.arange(m)[:, None] + di[None, :]) % m            # (s, n)
            ranking = near[..., np.arange(n)[None, :], cols].sum(-1)   # (..., s)
        best = np.argpartition(ranking, n_offsets - 1, axis=-1)[..., :n_offsets]
        offsets = np.concatenate([best - 1, best, best + 1], axis=-1) % m
    offsets = np.ascontiguousarray(offsets)
    totals = _dtw_rows(cost, offsets, window)
    k = np.argmin(totals, axis=-1)
    best_cost = np.take_along_axis(totals, k[..., None], axis=-1)[..., 0]
    best_off = np.take_along_axis(offsets, k[..., None], axis=-1)[..., 0]
    return best_cost, best_off


def dtw_path(cost: np.ndarray, offset: int = 0) -> Tuple[float, np.ndarray]:
    """DTW with fixed ends on the column-rolled matrix and its backtracked path.

    Returns
    -------
    total : float
    path : (p, 2) int array of (i, j) pairs, j indexing the *original* columns, from
        (0, offset) to (n - 1, offset - 1 mod m).
    """
    cost = np.asarray(cost, dtype=np.float64)
    n, m = cost.shape
    c = np.roll(cost, -int(offset), axis=1)
    d = np.empty((n, m))
    d[0] = np.cumsum(c[0])
    s = np.cumsum(c, axis=1)
    diag = np.empty(m)
    diag[0] = np.inf
    for i in range(1, n):
        prev = d[i - 1]
        diag[1:] = prev[:-1]
        t = np.minimum(prev, diag)
        t += c[i] - s[i]
        np.minimum.accumulate(t, out=t)
        d[i] = t + s[i]
    # backtrack on plain floats: a scalar loop of at most n + m steps
    rows = d.tolist()
    i, j = n - 1, m - 1
    path = [(i, j)]
    while i > 0 or j > 0:
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            a, b, e = rows[i - 1][j - 1], rows[i - 1][j], rows[i][j - 1]
            if a <= b and a <= e:
                i, j = i - 1, j - 1
            elif b <= e:
                i -= 1
            else:
                j -= 1
        path.append((i, j))
    path = np.array(path[::-1], dtype=np.int64)
    path[:, 1] = (path[:, 1] + int(offset)) % m
    return float(d[-1, -1]), path


@dataclass
class DTWResult:
    """A cyclic DTW match of sequence A (rows) against sequence B (columns).

    Attributes
    ----------
    cost : float, total cost along the path
    offset : int, the sample of B matched with A's first sample
    path : (p, 2) int array of corresponding (i, j) sample indices
    sigma : (n,) int array, for every sample i of A one matched sample of B (the first on
        the path), the correspondence sigma(i) of the thesis's eq. 4.1
    """

    cost: float
    offset: int
    path: np.ndarray
    sigma: np.ndarray


def cyclic_dtw(cost: np.ndarray, n_offsets: Optional[int] = None,
               window: Optional[int] = None) -> DTWResult:
    """Cyclic DTW between two sequences: best start offset, cost and correspondence.

    Parameters
    ----------
    cost : (n, m) point-pair cost matrix
    n_offsets, window : None tries every offset and path (exact); see
        :func:`cyclic_dtw_costs`. The returned path is the best unrestricted path for the
        chosen offset.

    Returns
    -------
    DTWResult

    Examples
    --------
    >>> c = 1.0 - np.roll(np.eye(4), 1, axis=1)   # zero cost where j = i + 1 (mod 4)
    >>> r = cyclic_dtw(c)
    >>> r.offset, float(r.cost), r.sigma.tolist()
    (1, 0.0, [1, 2, 3, 0])
    """
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2 or min(cost.shape) == 0:
        raise InputError("cyclic DTW needs a non-empty 2-D cost matrix")
    _, off = cyclic_dtw_costs(cost, n_offsets, window)
    total2, path = dtw_path(cost, int(off))
    first = np.r_[True, path[1:, 0] != path[:-1, 0]]
    return DTWResult(float(total2), int(off), path, path[first, 1])


# --------------------------------------------------------------------------- alignment

def rigid_align(src: np.ndarray, dst: np.ndarray,
                weights: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray, float]:
    """Least-squares rigid transform (rotation + translation, no scale, no reflection).

    ``(R, t) = argmin sum_i w_i ||R src_i + t - dst_i||^2`` by the Kabsch / Procrustes SVD.

    Parameters
    ----------
    src, dst : (p, 2) corresponding points
    weights : (p,) optional non-negative weights

    Returns
    -------
    R : (2, 2) rotation matrix (det +1)
    t : (2,) translation
    rms : root mean square residual (metres)

    References
    ----------
    Hartmann, thesis ch. 5.1 ("Alignment"); Kabsch 1976.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 2 or len(src) == 0:
        raise InputError("rigid alignment needs two equal (p, 2) arrays of points")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    # the 2D Kabsch solution in closed form (the SVD's rotation is atan2 of the weighted
    # cross and dot sums): element-wise sums, no BLAS or LAPACK call, so the same bits on
    # every processor kernel
    ms = (w[:, None] * src).sum(axis=0)
    md = (w[:, None] * dst).sum(axis=0)
    a, b = src - ms, dst - md
    cross = float((w * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])).sum())
    dot = float((w * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])).sum())
    theta = np.arctan2(cross, dot)
    c, s = np.cos(theta), np.sin(theta)
    r = np.array([[c, -s], [s, c]])
    t = md - np.array([c * ms[0] - s * ms[1], s * ms[0] + c * ms[1]])
    res = apply_rigid(src, r, t) - dst
    rms = float(np.sqrt((w * (res * res).sum(1)).sum()))
    return r, t, rms


def apply_rigid(xy: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``R x + t`` for points of shape (..., 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    flat = apply_affine(xy.reshape(-1, 2), rotation, translation)
    return flat.reshape(xy.shape)


def transform_geometries(geoms: Sequence, rotation: np.ndarray,
                         translation: np.ndarray) -> np.ndarray:
    """Apply a rigid transform to an array of shapely geometries (vectorised)."""
    geoms = np.asarray(geoms, dtype=object)
    return coordinates.rigid(geoms, rotation, translation)
