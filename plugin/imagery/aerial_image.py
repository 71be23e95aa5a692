"""Aerial-image synthesis per parcel (Aliaga, Vanegas and Benes 2008, sec. 3.2).

For each new parcel l_N the example parcel l_O whose oriented bounding box (OBB) is most
similar in area and aspect ratio, and that faces the street with the same side, is found;
its image fragment is warped onto l_N through an s x n grid: s scanlines perpendicular to
the main axis of each parcel's OBB, uniformly spaced, and n uniformly spaced samples
between the two points p_a, p_b where a scanline meets the parcel's contour; the grids of
l_O and l_N correspond one to one, and the quadrilaterals between them are texture-mapped
(fig. 7). The warp is C0 and does not fold when both contours project monotonically onto
their main axes (the paper's condition).

How the paper's steps are done here:

- **Street side** (:func:`parcel_frames`). Each parcel gets a right-handed frame (a, b) on
  its OBB: a along the main (long) axis, the street at b = -width/2 when the side nearest
  the street is a long side, at a = -length/2 when it is a short side. The side nearest the
  street is the OBB side whose midpoint lies closest to the streets (road lines or
  surfaces), or, without roads, to the outline of all the parcels together (the block
  outlines). Mapping frame to frame puts the example's street side on the new street side,
  with a rotation (never a mirror image: shadows keep their sense of rotation).
- **Similarity** (:func:`match_parcels`). The paper's "most similar in area and aspect
  ratio" is the L1 distance between (log OBB area, log OBB aspect ratio), found with a k-d
  tree among example parcels with the same street side (long or short). That distance is
  twice the larger of the stretches along the two OBB axes, so a match is good when no
  axis is stretched by more than ``max_stretch`` (default 2); parcels without a good match
  stay transparent and are counted. Our addition against the repetition the paper names as
  a limitation: among the ``candidates`` nearest matches within ``near_best`` of the best,
  one is drawn with the seed.
- **Warp** (:func:`scanline_extents`, :func:`scanline_grid`). The s scanlines sit at the
  centres of s equal slices of the OBB length; p_a, p_b are the extreme intersections of a
  scanline with the outer ring (holes are ignored). Each output pixel of l_N finds its
  place in l_N's grid (the scanline coordinate from a; the position between p_a and p_b,
  interpolated linearly between the two nearest scanlines, from b) and takes the same
  place in l_O's grid: the bilinear quadrilateral mesh evaluated per pixel. Because the n
  samples are uniformly spaced, the mesh is linear along each scanline and the map is the
  same for any n (n matters only for the explicit grid); beyond the first and last
  scanline the nearest one's p_a, p_b are used. The whole output is then resampled from
  the example image in one ``cv2.remap`` (bilinear), by row bands.
- **Roads** (not detailed in the paper: "rendered together with the rest of the layout").
  The new road surface (centrelines buffered by half the road width) is painted from the
  example's road pixels: a road pixel at distance t along its road and offset d across it
  takes the example pixel at t (modulo the length) along an example road drawn with the
  seed (weighted by length) and offset d scaled by the width ratio, so markings and kerbs
  follow the new road. Parcels are painted over roads.

Everything is in metres in a metric CRS; the example and the new layout may each be in
their own. Rasters are :class:`GeoImage` (numpy array + GDAL geotransform, north up).

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.2, fig. 3 (generateNewImagery) and fig. 7.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence, Tuple

import cv2
import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree

from ..core.progress import InputError, Progress, ensure
from ..network import blocks as _blocks

__all__ = ["GeoImage", "ImageSettings", "ParcelFrames", "ImageSynthesis", "parcel_frames",
           "match_parcels", "scanline_extents", "scanline_grid", "synthesize_image",
           "PARCEL_IMAGE_FIELDS"]

#: Per new parcel: the example parcel its pixels come from (-1: none good enough), the
#: largest stretch of an OBB axis, and which side faces the street.
PARCEL_IMAGE_FIELDS = [("parcel", "int"), ("example_parcel", "int"), ("stretch", "float"),
                       ("street_side", "str")]

_FAR = -1.0e6     # a map coordinate far outside any image: remap gives transparent
_BAND_ROWS = 2048  # output rows per cv2.remap call (its maps must stay under 32767 px)
_MAX_SOURCE = 32000  # cv2.remap's fixed-point maps address at most this many pixels


@dataclass
class GeoImage:
    """A north-up raster: ``array`` (rows, cols, bands), a GDAL geotransform
    (x0, dx, 0, y0, 0, -dy) and where it has data (``valid``, all by default)."""

    array: np.ndarray
    geotransform: Tuple[float, float, float, float, float, float]
    valid: Optional[np.ndarray] = None

    def __post_init__(self):
        a = np.asarray(self.array)
        if a.ndim == 2:
            a = a[:, :, None]
        self.array = a
        gt = tuple(float(v) for v in self.geotransform)
        if len(gt) != 6 or gt[2] != 0 or gt[4] != 0 or not (gt[1] > 0 and gt[5] < 0):
            raise InputError("the image must be north up (a geotransform without rotation)")
        self.geotransform = gt
        if self.valid is None:
            self.valid = np.ones(a.shape[:2], dtype=bool)

    @property
    def shape(self) -> Tuple[int, int]:
        return self.array.shape[0], self.array.shape[1]

    @property
    def bounds(self) -> Tuple[float, float, float, float]:
        x0, dx, _, y0, _, dy = self.geotransform
        rows, cols = self.shape
        return x0, y0 + rows * dy, x0 + cols * dx, y0

    def pixel_of(self, xy: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """(column, row) of points, pixel centres at whole numbers (cv2's convention)."""
        x0, dx, _, y0, _, dy = self.geotransform
        return (xy[..., 0] - x0) / dx - 0.5, (xy[..., 1] - y0) / dy - 0.5


@dataclass(frozen=True)
class ImageSettings:
    """Parameters of the image synthesis (see the module doc).

    Attributes
    ----------
    pixel_size : float
        Output pixel size (m).
    scanlines : int
        The paper's s, scanlines per parcel.
    samples : int
        The paper's n, samples per scanline of the explicit grid (:func:`scanline_grid`).
    max_stretch : float
        A match is good when neither OBB axis is stretched (or shrunk) by more than this.
    candidates, near_best : int, float
        Draw among this many nearest matches within ``near_best`` (log units) of the best.
    road_width, example_road_width : float
        Full width (m) of the new roads and of the example's (default: the same).
    max_pixels : int
        Refuse outputs larger than this (memory: about 12 bytes per pixel while warping).
    """

    pixel_size: float = 0.5
    scanlines: int = 32
    samples: int = 8
    max_stretch: float = 2.0
    candidates: int = 3
    near_best: float = 0.1
    road_width: float = 12.0
    example_road_width: Optional[float] = None
    max_pixels: int = 200_000_000

    def validate(self) -> "ImageSettings":
        if not (math.isfinite(self.pixel_size) and self.pixel_size > 0):
            raise InputError(f"the pixel size must be positive (got {self.pixel_size:g})")
        if int(self.scanlines) < 2 or int(self.samples) < 2:
            raise InputError("a parcel needs at least 2 scanlines and 2 samples per scanline")
        if not self.max_stretch >= 1:
            raise InputError(f"the largest stretch must be at least 1 (got {self.max_stretch:g})")
        if int(self.candidates) < 1 or not self.near_best >= 0:
            raise InputError("candidates must be at least 1 and near_best not negative")
        for name in ("road_width", "example_road_width"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise InputError(f"{name} must not be negative (got {value:g})")
        return self


@dataclass
class ParcelFrames:
    """Each parcel's OBB frame: centre, unit axes a (main axis) and b (right-handed), the
    OBB length (along a) and width (along b), and whether the street is on a long side
    (at b = -width / 2) or a short side (at a = -length / 2)."""

    centre: np.ndarray
    axis_a: np.ndarray
    axis_b: np.ndarray
    length: np.ndarray
    width: np.ndarray
    front_on_long_side: np.ndarray

    def __len__(self):
        return len(self.length)

    def local(self, xy: np.ndarray, index: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """(a, b) of points ``xy`` in the frames of parcels ``index``."""
        d = xy - self.centre[index]
        return (np.einsum("ij,ij->i", d, self.axis_a[index]),
                np.einsum("ij,ij->i", d, self.axis_b[index]))

    def world(self, a: np.ndarray, b: np.ndarray, index: np.ndarray) -> np.ndarray:
        return self.centre[index] + a[:, None] * self.axis_a[index] + \
            b[:, None] * self.axis_b[index]


@dataclass
class ImageSynthesis:
    """Result of :func:`synthesize_image`: the image (bands of the example, ``alpha`` 255
    where painted), a table per new parcel (:data:`PARCEL_IMAGE_FIELDS`) and counts."""

    image: GeoImage
    alpha: np.ndarray
    table: pd.DataFrame
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- geometry

def _largest_polygons(geoms, what: str) -> np.ndarray:
    """Each geometry as its largest polygon part; InputError when there is none."""
    geoms = np.asarray(geoms, dtype=object).ravel()
    if len(geoms) == 0:
        raise InputError(f"no {what}")
    present = ~(shapely.is_missing(geoms) | shapely.is_empty(geoms))
    if not present.all():
        raise InputError(f"{int((~present).sum())} {what} have no geometry")
    if not (shapely.get_dimensions(geoms) == 2).all():
        raise InputError(f"{what} must be polygons")
    out = geoms.copy()
    multi = shapely.get_type_id(geoms) != 3
    for i in np.flatnonzero(multi):
        parts = shapely.get_parts(geoms[i])
        parts = parts[shapely.get_type_id(parts) == 3]
        out[i] = parts[np.argmax(shapely.area(parts))] if len(parts) else shapely.Polygon()
    if not (shapely.area(out) > 0).all():
        raise InputError(f"{int((shapely.area(out) <= 0).sum())} {what} have no area")
    return out


def parcel_frames(parcels, streets=None) -> ParcelFrames:
    """OBB frames of parcels with the street side, see the module doc.

    Parameters
    ----------
    parcels : array of Polygon
    streets : array of geometries, optional
        Road centrelines or surfaces; default: the outline of the union of the parcels.

    Returns
    -------
    ParcelFrames

    Examples
    --------
    >>> import shapely
    >>> f = parcel_frames([shapely.box(0, 0, 10, 30)], [shapely.LineString([(-5, 0), (-5, 30)])])
    >>> f.length.round(6).tolist(), f.width.round(6).tolist(), f.front_on_long_side.tolist()
    ([30.0], [10.0], [True])
    >>> (f.axis_b.round(6) + 0.0).tolist()  # b: away from the street (x = -5), inwards
    [[1.0, 0.0]]
    """
    parcels = np.asarray(parcels, dtype=object)
    n = len(parcels)
    length, width, angle = _blocks.minimum_rectangles(parcels)
    t = np.radians(angle)
    u = np.column_stack([np.cos(t), np.sin(t)])
    v = np.column_stack([-u[:, 1], u[:, 0]])
    centre = _rectangle_centres(parcels, u, v)
    # the four sides' outward normals and midpoints: +-v on the long sides, +-u on the short
    normals = np.stack([-v, v, -u, u], axis=1)
    half = np.stack([width, width, length, length], axis=1) / 2.0
    mids = centre[:, None, :] + normals * half[:, :, None]
    if streets is None:
        streets = shapely.boundary(shapely.union_all(parcels))
    streets = shapely.get_parts(np.asarray(streets, dtype=object).ravel())
    streets = streets[~shapely.is_empty(streets)]
    if len(streets):
        _, dist = shapely.STRtree(streets).query_nearest(
            shapely.points(mids.reshape(-1, 2)), return_distance=True, all_matches=False)
        dist = dist.reshape(n, 4)
    else:
        dist = np.zeros((n, 4))
    front = np.argmin(dist, axis=1)
    on_long = front < 2
    nrm = normals[np.arange(n), front]
    a_long = np.column_stack([-nrm[:, 1], nrm[:, 0]])   # b = -n, a = (b_y, -b_x)
    b_short = np.column_stack([nrm[:, 1], -nrm[:, 0]])  # a = -n, b = (-a_y, a_x)
    axis_a = np.where(on_long[:, None], a_long, -nrm)
    axis_b = np.where(on_long[:, None], -nrm, b_short)
    return ParcelFrames(centre, axis_a, axis_b, length, width, on_long)


def _rectangle_centres(parcels, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Centres of the rectangles with axes u, v around each parcel (its extent along each)."""
    coords, idx = shapely.get_coordinates(parcels, return_index=True)
    n = len(parcels)
    centre = np.zeros((n, 2))
    for axis in (u, v):
        t = np.einsum("ij,ij->i", coords, axis[idx])
        lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
        np.minimum.at(lo, idx, t)
        np.maximum.at(hi, idx, t)
        centre += ((lo + hi) / 2.0)[:, None] * axis
    return centre


def scanline_extents(parcels, frames: ParcelFrames, scanlines: int) -> Tuple[np.ndarray,
                                                                               np.ndarray]:
    """b of the points p_a (lowest) and p_b (highest) where each of the s scanlines meets
    the parcel's outer ring; scanline k at a = -length/2 + (k + 1/2) length / s.

    Returns
    -------
    lo, hi : (P, s) float arrays
    """
    parcels = np.asarray(parcels, dtype=object)
    n, s = len(parcels), int(scanlines)
    coords, idx = shapely.get_coordinates(shapely.get_exterior_ring(parcels), return_index=True)
    a, b = frames.local(coords, idx)
    edge = np.flatnonzero(idx[1:] == idx[:-1])
    p = idx[edge]
    a1, a2, b1, b2 = a[edge], a[edge + 1], b[edge], b[edge + 1]
    k = np.arange(s)
    ak = (-0.5 + (k[None, :] + 0.5) / s) * frames.length[p][:, None]
    lo_a, hi_a = np.minimum(a1, a2)[:, None], np.maximum(a1, a2)[:, None]
    crosses = (lo_a <= ak) & (ak <= hi_a) & (hi_a > lo_a)
    with np.errstate(invalid="ignore", divide="ignore"):
        bk = b1[:, None] + (ak - a1[:, None]) * ((b2 - b1) / (a2 - a1))[:, None]
    rows, cols = np.nonzero(crosses)
    lo = np.full((n, s), np.inf)
    hi = np.full((n, s), -np.inf)
    np.minimum.at(lo, (p[rows], cols), bk[rows, cols])
    np.maximum.at(hi, (p[rows], cols), bk[rows, cols])
    missing = ~np.isfinite(lo)
    if missing.any():  # numerically missed (a vertex exactly on a scanline): centre
        lo[missing] = hi[missing] = 0.0
    return lo, hi


def scanline_grid(parcels, frames: ParcelFrames, scanlines: int, samples: int) -> np.ndarray:
    """The paper's s x n grid of each parcel (fig. 7): (P, s, n, 2) points in world
    coordinates, n uniformly spaced samples between p_a and p_b on each of s scanlines.

    Examples
    --------
    >>> import shapely
    >>> box = shapely.box(0, 0, 40, 10)
    >>> grid = scanline_grid([box], parcel_frames([box]), 4, 3)
    >>> grid.shape, sorted(set(grid[0, :, 0, 0].round(6)))
    ((1, 4, 3, 2), [5.0, 15.0, 25.0, 35.0])
    """
    s, m = int(scanlines), int(samples)
    lo, hi = scanline_extents(parcels, frames, s)
    n = len(lo)
    ak = (-0.5 + (np.arange(s) + 0.5) / s)[None, :] * frames.length[:, None]
    t = np.linspace(0.0, 1.0, m)
    bk = lo[:, :, None] + t[None, None, :] * (hi - lo)[:, :, None]
    a = np.broadcast_to(ak[:, :, None], bk.shape)
    index = np.broadcast_to(np.arange(n)[:, None, None], bk.shape)
    return frames.world(a.ravel(), bk.ravel(), index.ravel()).reshape(n, s, m, 2)


# --------------------------------------------------------------------------- matching

def match_parcels(frames: ParcelFrames, example: ParcelFrames, settings: ImageSettings,
                  rng: np.random.Generator, eligible: Optional[np.ndarray] = None):
    """The example parcel for each new parcel (sec. 3.2: OBB most similar in area and
    aspect ratio, the same side facing the street); see the module doc.

    Returns
    -------
    index : int array
        Example parcel per new parcel; -1 when none has the same street side within
        ``max_stretch``.
    stretch : float array
        The larger factor by which an OBB axis is stretched or shrunk (inf: no candidate).
    """
    n = len(frames)
    index = np.full(n, -1, dtype=np.int64)
    stretch = np.full(n, np.inf)
    ok_example = np.ones(len(example), dtype=bool) if eligible is None else np.asarray(eligible)

    def features(f):
        return np.column_stack([np.log(f.length * f.width), np.log(f.length / f.width)])

    fx, fe = features(frames), features(example)
    limit = 2.0 * math.log(settings.max_stretch) + 1e-9
    for side in (True, False):
        mine = np.flatnonzero(frames.front_on_long_side == side)
        pool = np.flatnonzero((example.front_on_long_side == side) & ok_example)
        if len(mine) == 0 or len(pool) == 0:
            continue
        k = min(int(settings.candidates), len(pool))
        dist, nearest = cKDTree(fe[pool]).query(fx[mine], k=k, p=1)
        dist, nearest = dist.reshape(len(mine), k), nearest.reshape(len(mine), k)
        near = dist <= dist[:, :1] + settings.near_best
        # one draw per parcel among its near-best candidates (fixed count: reproducible)
        pick = np.floor(rng.random(len(mine)) * near.sum(axis=1)).astype(np.int64)
        d = dist[np.arange(len(mine)), pick]
        chosen = pool[nearest[np.arange(len(mine)), pick]]
        good = d <= limit
        index[mine[good]] = chosen[good]
        ls = np.abs(np.log(frames.length[mine] / example.length[chosen]))
        ws = np.abs(np.log(frames.width[mine] / example.width[chosen]))
        stretch[mine] = np.exp(np.maximum(ls, ws))
    return index, stretch


# --------------------------------------------------------------------------- rendering

@dataclass
class _Grid:
    x0: float
    y0: float
    size: float
    rows: int
    cols: int

    def pixel_of(self, xy):
        return (xy[..., 0] - self.x0) / self.size - 0.5, (self.y0 - xy[..., 1]) / self.size - 0.5

    def centres(self, rr, cc):
        return np.column_stack([self.x0 + (cc + 0.5) * self.size, self.y0 - (rr + 0.5) * self.size])


def _grid_on(bounds, pixel_size: float) -> _Grid:
    """The grid of whole multiples of ``pixel_size`` that covers ``bounds``."""
    x0, y0, x1, y1 = bounds
    x0, y0 = math.floor(x0 / pixel_size) * pixel_size, math.floor(y0 / pixel_size) * pixel_size
    x1, y1 = math.ceil(x1 / pixel_size) * pixel_size, math.ceil(y1 / pixel_size) * pixel_size
    cols, rows = max(1, int(round((x1 - x0) / pixel_size))), max(1, int(round((y1 - y0) / pixel_size)))
    return _Grid(x0, y1, pixel_size, rows, cols)


def _too_large(geoms, margin: float, settings: ImageSettings) -> bool:
    """Whether the image :func:`_output_grid` would make of ``geoms`` (arrays of
    geometries), their bounds grown by ``margin`` / 2 on every side, has more than
    ``settings.max_pixels`` pixels."""
    x0, y0, x1, y1 = shapely.total_bounds(np.concatenate(
        [np.asarray(g, dtype=object).ravel() for g in geoms]))
    h = margin / 2
    grid = _grid_on((x0 - h, y0 - h, x1 + h, y1 + h), settings.pixel_size)
    return grid.rows * grid.cols > settings.max_pixels


def _output_grid(geoms, pixel_size: float, max_pixels: int) -> _Grid:
    grid = _grid_on(shapely.total_bounds(geoms), pixel_size)
    if grid.rows * grid.cols > max_pixels:
        raise InputError(f"the image would have {grid.rows} x {grid.cols} pixels (more than "
                         f"{max_pixels:,}): use a larger pixel size")
    return grid


def _label_polygons(grid: _Grid, polygons: Sequence) -> np.ndarray:
    """An int32 raster: pixel = 1 + index of the last polygon covering it (0: none).

    cv2.fillPoly at 1/256 pixel precision: a pixel whose centre lies in a polygon or on its
    outline is labelled (outlines are shared by neighbours: the later one wins).
    """
    label = np.zeros((grid.rows, grid.cols), dtype=np.int32)
    polygons = np.asarray(polygons, dtype=object)
    rings, owner = shapely.get_rings(polygons, return_index=True)
    if len(rings) == 0:
        return label
    coords, ring = shapely.get_coordinates(rings, return_index=True)
    col, row = grid.pixel_of(coords)
    fixed = np.round(np.column_stack([col, row]) * 256).astype(np.int32)
    # rings repeat their first vertex: drop it, then split per ring and group per polygon
    last = np.r_[ring[1:] != ring[:-1], True]
    fixed, ring = fixed[~last], ring[~last]
    cuts = np.flatnonzero(np.diff(ring)) + 1
    pieces = np.split(fixed, cuts)
    starts = np.r_[0, np.flatnonzero(np.diff(owner)) + 1, len(owner)]
    for k in range(len(starts) - 1):
        cv2.fillPoly(label, pieces[starts[k]:starts[k + 1]], int(owner[starts[k]] + 1),
                     lineType=cv2.LINE_8, shift=8)
    return label


def _pixel_coefficients(example: GeoImage, frames: ParcelFrames):
    """Per example parcel: source (column, row) = c0 + ca * a + cb * b of frame point (a, b)."""
    x0, dx, _, y0, _, dy = example.geotransform
    col0 = (frames.centre[:, 0] - x0) / dx - 0.5
    row0 = (frames.centre[:, 1] - y0) / dy - 0.5
    return (col0, frames.axis_a[:, 0] / dx, frames.axis_b[:, 0] / dx,
            row0, frames.axis_a[:, 1] / dy, frames.axis_b[:, 1] / dy)


def _parcel_sources(grid, label, frames, lo, hi, example, ex_frames, ex_lo, ex_hi, match):
    """Output pixels of matched parcels and the example pixels (column, row) they take.

    Per pixel only 1-D gathers of per-parcel numbers (this is the hot loop: a few million
    pixels per thousand parcels at 0.5 m).
    """
    rr, cc = np.nonzero(label)
    p = label[rr, cc] - 1
    keep = match[p] >= 0
    rr, cc, p = rr[keep], cc[keep], p[keep]
    e = match[p]
    s = lo.shape[1]
    dx = grid.x0 + (cc + 0.5) * grid.size - frames.centre[p, 0]
    dy = grid.y0 - (rr + 0.5) * grid.size - frames.centre[p, 1]
    a = dx * frames.axis_a[p, 0] + dy * frames.axis_a[p, 1]
    b = dx * frames.axis_b[p, 0] + dy * frames.axis_b[p, 1]
    del dx, dy
    u = (a / frames.length[p] + 0.5) * s - 0.5  # scanline coordinate in [-0.5, s - 0.5]
    k0 = np.clip(np.floor(u).astype(np.int64), 0, s - 2)
    f = np.clip(u - k0, 0.0, 1.0)
    g = 1.0 - f
    at_p, at_e = p * s + k0, e * s + k0
    lo_n = lo.ravel()[at_p] * g + lo.ravel()[at_p + 1] * f
    span = hi.ravel()[at_p] * g + hi.ravel()[at_p + 1] * f - lo_n
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(span > 1e-9, (b - lo_n) / span, 0.5)
    del lo_n, span, b
    lo_e = ex_lo.ravel()[at_e] * g + ex_lo.ravel()[at_e + 1] * f
    b_e = lo_e + t * (ex_hi.ravel()[at_e] * g + ex_hi.ravel()[at_e + 1] * f - lo_e)
    a_e = (u + 0.5) / s * ex_frames.length[e] - 0.5 * ex_frames.length[e]
    col0, col_a, col_b, row0, row_a, row_b = _pixel_coefficients(example, ex_frames)
    col = col0[e] + col_a[e] * a_e + col_b[e] * b_e
    row = row0[e] + row_a[e] * a_e + row_b[e] * b_e
    return rr, cc, col, row


def _segments(lines):
    """Straight segments of lines: start, unit direction, length, distance along the line
    at the start, line index."""
    coords, idx = shapely.get_coordinates(lines, return_index=True)
    seg = np.flatnonzero(idx[1:] == idx[:-1])
    p0, p1 = coords[seg], coords[seg + 1]
    d = p1 - p0
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 1e-9
    seg, p0, d, length = seg[keep], p0[keep], d[keep], length[keep]
    line = idx[seg]
    direction = d / length[:, None]
    cum = np.zeros(len(seg))
    if len(seg):
        total = np.cumsum(length)
        start_of_line = np.r_[True, line[1:] != line[:-1]]
        offset = np.maximum.accumulate(np.where(start_of_line, np.r_[0.0, total[:-1]], 0.0))
        cum = np.r_[0.0, total[:-1]] - offset
    return p0, direction, length, cum, line


def _road_sources(grid, example, roads, example_roads, width, ex_width, rng, exclude):
    """Output road pixels and the example pixels (column, row) they take (module doc,
    Roads)."""
    p0, u, seg_len, cum, line = _segments(roads)
    q0, w, q_len, q_cum, q_line = _segments(example_roads)
    if len(p0) == 0 or len(q0) == 0 or width <= 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0)
    h = width / 2.0
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    quads = [shapely.Polygon([a - h * d - h * m, a + (ln + h) * d - h * m,
                              a + (ln + h) * d + h * m, a - h * d + h * m])
             for a, d, m, ln in zip(p0, u, nrm, seg_len)]
    label = _label_polygons(grid, quads)
    label[exclude] = 0
    rr, cc = np.nonzero(label)
    k = label[rr, cc] - 1
    rx = grid.x0 + (cc + 0.5) * grid.size - p0[k, 0]
    ry = grid.y0 - (rr + 0.5) * grid.size - p0[k, 1]
    ux, uy = u[k, 0], u[k, 1]
    t = cum[k] + rx * ux + ry * uy
    off = ry * ux - rx * uy  # along the normal (-uy, ux)
    inside = np.abs(off) <= h + 1e-9
    rr, cc, k, t, off = rr[inside], cc[inside], k[inside], t[inside], off[inside]
    # one example road per new road, drawn with the seed, weighted by length
    n_ex = int(q_line.max()) + 1
    ex_total = np.bincount(q_line, q_len, minlength=n_ex)
    n_new = int(line.max()) + 1
    chosen = rng.choice(n_ex, size=n_new, p=ex_total / ex_total.sum())
    e = chosen[line[k]]
    te = np.mod(t, ex_total[e])
    # the example segment holding te: segments are sorted by (line, cum)
    step = q_cum.max() + q_len.max() + 1.0
    j = np.searchsorted(q_line * step + q_cum, e * step + te, side="right") - 1
    j = np.clip(j, 0, len(q0) - 1)
    along = te - q_cum[j]
    across = off * (ex_width / width)
    x = q0[j, 0] + along * w[j, 0] - across * w[j, 1]
    y = q0[j, 1] + along * w[j, 1] + across * w[j, 0]
    col, row = example.pixel_of(np.column_stack([x, y]))
    return rr, cc, col, row


def _remap(example: GeoImage, map_x: np.ndarray, map_y: np.ndarray, progress: Progress):
    """The example resampled at (map_x, map_y) (bilinear), and where that has data."""
    rows, cols = map_x.shape
    src = example.array
    if src.dtype not in (np.uint8, np.uint16, np.int16, np.float32, np.float64):
        src = src.astype(np.float64)  # what cv2.remap cannot read; cast back below
    out = np.zeros((rows, cols, src.shape[2]), dtype=example.array.dtype)
    alpha = np.zeros((rows, cols), dtype=np.uint8)
    valid = example.valid.astype(np.uint8) * 255
    for r0 in range(0, rows, _BAND_ROWS):
        progress.step(r0 / rows)
        sl = slice(r0, min(rows, r0 + _BAND_ROWS))
        mx, my = map_x[sl], map_y[sl]
        for c0 in range(0, src.shape[2], 4):
            part = np.ascontiguousarray(src[:, :, c0:c0 + 4])
            res = cv2.remap(part, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=0)
            out[sl, :, c0:c0 + 4] = res.reshape(res.shape[0], res.shape[1], -1)
        alpha[sl] = cv2.remap(valid, mx, my, cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, alpha


def synthesize_image(example: GeoImage, example_parcels, parcels, roads=None,
                     example_roads=None, settings: Optional[ImageSettings] = None,
                     seed: int = 0, progress: Optional[Progress] = None) -> ImageSynthesis:
    """An aerial-view image of new parcels and roads from an example image (sec. 3.2).

    Parameters
    ----------
    example : GeoImage
        The example's aerial image, in the example's metric CRS.
    example_parcels : array of Polygon
        The example's parcels (or blocks), same CRS; those not wholly on the image are not
        used.
    parcels : array of Polygon
        The new parcels (their own metric CRS); multipolygons are reduced to their largest
        part.
    roads, example_roads : arrays of LineString, optional
        Centrelines of the new and of the example roads; new roads are painted when both
        are given. Without ``roads`` the street side of a new parcel is found from the
        outline of the new parcels (likewise for the example).
    settings : ImageSettings, optional
    seed : int
        The same seed gives the same image.
    progress : Progress, optional
        Cancellation raises :class:`progress.Canceled`.

    Returns
    -------
    ImageSynthesis
        ``image`` covers the new parcels and roads on the ``pixel_size`` grid (aligned to
        whole multiples of it), with the example's bands and dtype; ``alpha`` is 0 off the
        layout and on parcels without a good match. Where the roads reach so far beyond the
        parcels that the image would be too large (``max_pixels``) and the parcels' alone
        would not, it covers the parcels and the roads within a road width of their bounding
        box; ``stats['n_roads_beyond']`` counts the roads left out.

    Raises
    ------
    InputError
        Empty or non-polygon parcels, an image larger than cv2 can address, absurd settings,
        no example parcel on the image.
    """
    progress = ensure(progress)
    settings = (settings or ImageSettings()).validate()
    if example.array.size == 0:
        raise InputError("the example image is empty")
    if max(example.shape) > _MAX_SOURCE:
        raise InputError(f"the example image has {example.shape[0]} x {example.shape[1]} "
                         f"pixels; at most {_MAX_SOURCE} per side can be warped (read it at "
                         "a coarser resolution)")
    rng = np.random.default_rng(int(seed))
    parcels = _largest_polygons(parcels, "new parcels")
    ex_parcels = _largest_polygons(example_parcels, "example parcels")
    x0, y0, x1, y1 = example.bounds
    on_image = shapely.within(ex_parcels, shapely.box(x0, y0, x1, y1))
    if not on_image.any():
        raise InputError("no example parcel lies on the example image: check that they "
                         "overlap")
    roads = None if roads is None else _lines(roads)
    example_roads = None if example_roads is None else _lines(example_roads)
    if example_roads is not None:
        example_roads = _lines(shapely.intersection(example_roads, shapely.box(
            x0, y0, x1, y1).buffer(-(settings.example_road_width or settings.road_width) / 2)))
    progress.step(0.02)
    frames = parcel_frames(parcels, roads)
    ex_frames = parcel_frames(ex_parcels, example_roads)
    match, stretch = match_parcels(frames, ex_frames, settings, rng, eligible=on_image)
    progress.step(0.1)

    s = int(settings.scanlines)
    lo, hi = scanline_extents(parcels, frames, s)
    ex_lo, ex_hi = scanline_extents(ex_parcels, ex_frames, s)
    extent = list(parcels)
    width = settings.road_width
    n_roads_beyond = 0
    if roads is not None and len(roads):
        if _too_large(extent + [roads], width, settings) and \
                not _too_large(extent, width, settings):
            # a region's (a country's) road layer with a town's parcels: the image of every
            # road was refused as too large; it covers the parcels and the roads within a
            # road width of them (the street sides above used every road)
            x0, y0, x1, y1 = shapely.total_bounds(parcels)
            reach = shapely.box(x0 - width, y0 - width, x1 + width, y1 + width)
            n_roads_beyond = int((~shapely.intersects(roads, reach)).sum())
            roads = _lines(shapely.intersection(roads, reach))
        if len(roads):
            extent.append(shapely.buffer(shapely.multilinestrings(roads), width / 2,
                                         cap_style="flat"))
    grid = _output_grid(np.array(extent, dtype=object), settings.pixel_size, settings.max_pixels)
    progress.step(0.15)

    label = _label_polygons(grid, parcels)
    progress.step(0.3)
    map_x = np.full((grid.rows, grid.cols), _FAR, dtype=np.float32)
    map_y = np.full((grid.rows, grid.cols), _FAR, dtype=np.float32)
    n_road = 0
    painted_roads = roads is not None and example_roads is not None and len(roads) \
        and len(example_roads) > 0
    if painted_roads:
        rr, cc, col, row = _road_sources(grid, example, roads, example_roads, width,
                                         settings.example_road_width or width, rng, label > 0)
        map_x[rr, cc], map_y[rr, cc] = col, row
        n_road = len(rr)
    progress.step(0.45)
    rr, cc, col, row = _parcel_sources(grid, label, frames, lo, hi, example, ex_frames,
                                       ex_lo, ex_hi, match)
    map_x[rr, cc], map_y[rr, cc] = col, row
    progress.step(0.6)
    out, alpha = _remap(example, map_x, map_y, progress.sub(0.6, 0.98))

    image = GeoImage(out, (grid.x0, grid.size, 0.0, grid.y0, 0.0, -grid.size), alpha > 0)
    table = pd.DataFrame({
        "parcel": np.arange(len(parcels), dtype=np.int64), "example_parcel": match,
        "stretch": np.where(np.isfinite(stretch), stretch, np.nan),
        "street_side": np.where(frames.front_on_long_side, "long", "short").astype(object)})
    matched = match >= 0
    stats = {
        "n_parcels": len(parcels), "n_matched": int(matched.sum()),
        "n_unmatched": int((~matched).sum()),
        "n_example_parcels": len(ex_parcels), "n_example_on_image": int(on_image.sum()),
        "n_example_used": int(len(np.unique(match[matched]))),
        "median_stretch": float(np.median(stretch[matched])) if matched.any() else float("nan"),
        "roads_painted": bool(painted_roads), "n_road_pixels": int(n_road),
        "n_roads_beyond": n_roads_beyond,
        "rows": grid.rows, "cols": grid.cols,
    }
    progress.step(1.0)
    return ImageSynthesis(image, alpha, table, stats)


def _lines(geoms) -> np.ndarray:
    """The non-empty LineString parts of any geometries."""
    parts = shapely.get_parts(np.asarray(geoms, dtype=object).ravel())
    parts = parts[shapely.get_type_id(parts) == 1]
    return parts[shapely.length(parts) > 0]
