"""Parcels from a Voronoi diagram of points along the block's OBB axis (Aliaga et al. 2008).

Sec. 3.1.2 of Aliaga, Vanegas and Benes (2008): a block b is split into n_b parcels in one
or two rows, every parcel touching the street. The main axis of the block's oriented
bounding box (OBB) approximates the central segments of its medial axis; the part of the
axis inside the block is sampled with (n_b - 1) / r_b points spaced d + epsilon, epsilon ~
N(0, sigma_b^2) (r_b rows, d from n_b and r_b, sigma_b from the spread of the example's
parcel areas). One row: the Voronoi cells of the points are strips across the block, with
street access front and back; two rows: the points are copied +-delta across the axis, so
the axis itself separates the rows and each parcel touches the street on one side. The
Voronoi cells clipped to the block are the parcels.

n_b and the parcel size come from the mean parcel area a (Aliaga's a(v) of the points
around the block): per block ``settings.options['mean_area']`` / ``['area_sd']`` (set by
:func:`subdivision.subdivide_blocks` from the blocks' ``parcel_area``), or
``settings.options['parcel_areas']`` (example parcel areas, e.g. a cadastre: their mean and
standard deviation); without them a = lot_width^2 x 1.5 (a lot 1.5 times as deep as wide)
clamped to [min_area, max_area], with a standard deviation of irregularity / 2 x a.
Rows: two when the OBB is wider than 1.5 parcel depths (depth = sqrt(1.5 a)).

Where the paper's assumptions fail on real towns (all three are ours, measured on the
Liechtenstein towns in tests/benchmarks/bench_parcels.py):

- "most blocks are nearly rectangular": a block filling less than
  :data:`MIN_RECTANGULARITY` of its OBB (an L, a long curved block between a through road
  and a river) is first cut across the middle of its OBB axis, recursively, and each piece
  gets its own rows (:func:`rectangular_pieces`);
- a block many parcels deep (farmland between through roads) would get n_b = area / a
  strips a few metres wide in its two rows: the spacing is kept at least the minimum lot
  width and at least 1 / :data:`MAX_DEPTH_RATIO` of the row depth, so such blocks get
  fewer, larger lots (:func:`row_layout`); the Gaussian spacing noise is rescaled so that
  it never makes a lot narrower than the minimum width (:func:`spacings`);
- lots still smaller than the minimum area, narrower than the minimum width or with less
  than the minimum frontage (the tapering end of a block, a piece of a concave block) are
  merged into the neighbour sharing most boundary (:func:`subdivision.merge_unfit_lots`,
  the rule the skeleton method uses too).

The method registers itself as ``voronoi-obb`` in :data:`parcels.METHODS`;
:func:`parcels.subdivide_blocks` shrinks the blocks by their streets first.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1.2 and fig. 6.
"""
from __future__ import annotations

import math
from typing import Tuple

import numpy as np
import shapely

from ..core.geometry import minimum_rectangle_corners
from ..core.progress import InputError
from . import subdivision as _parcels

__all__ = ["ASPECT", "TWO_ROWS_AT", "MAX_DEPTH_RATIO", "MIN_RECTANGULARITY", "parcel_size",
           "row_layout", "rectangular_pieces", "spacings", "split_voronoi_obb"]

#: Depth / frontage of a typical parcel when no example gives it.
ASPECT = 1.5
#: Two rows of parcels when the block's OBB is wider than this many parcel depths.
TWO_ROWS_AT = 1.5
#: No lot is made more than this many times as deep as wide (95 % of Bubeneč's cadastre
#: parcels are under 4): blocks deeper than two parcels get fewer, wider lots.
MAX_DEPTH_RATIO = 8.0
#: The paper assumes "most blocks are nearly rectangular": a block filling less than this
#: share of its OBB (an L, a U, a long curved block) is cut across the middle of its OBB
#: axis, recursively, until its pieces are, and each piece gets its own rows.
MIN_RECTANGULARITY = 0.7
#: ... unless the piece holds fewer than this many parcels.
_MIN_PIECE_PARCELS = 4
_MAX_CUTS = 64
#: The row copies sit this far (m) on either side of the axis (the paper's small delta).
_DELTA = 0.05
#: The spacing noise epsilon is clipped to this share of the spacing.
_MAX_JITTER = 0.45


def parcel_size(settings) -> tuple:
    """(mean area, standard deviation) of a parcel from the settings (see module doc)."""
    opts = dict(settings.options or {})
    areas = opts.get("parcel_areas")
    if areas is not None:
        a = np.asarray(areas, dtype=float)
        a = a[np.isfinite(a) & (a > 0)]
        if len(a) == 0:
            raise InputError("the example parcel areas hold no positive number")
        return float(a.mean()), float(a.std())
    if opts.get("mean_area") is not None:
        mean = float(opts["mean_area"])
        if not (math.isfinite(mean) and mean > 0):
            raise InputError(f"the mean parcel area must be positive (got {mean})")
        sd = float(opts.get("area_sd", settings.irregularity * 0.5 * mean))
        return mean, max(sd, 0.0)
    mean = float(np.clip(settings.lot_width ** 2 * ASPECT, settings.min_area,
                         settings.max_area))
    return mean, settings.irregularity * 0.5 * mean


def _obb(block):
    """Centre, unit main axis, its length and the width of the block's OBB."""
    c = minimum_rectangle_corners([block])[0]
    e1, e2 = c[1] - c[0], c[2] - c[1]
    l1, l2 = np.linalg.norm(e1), np.linalg.norm(e2)
    axis, length, width = (e1 / l1, l1, l2) if l1 >= l2 else (e2 / l2, l2, l1)
    return c.mean(axis=0), axis, length, width


def row_layout(block, mean: float, settings) -> Tuple[int, int, float, float]:
    """Rows, points per row, and the axis extent [t0, t1] of a block's Voronoi points.

    The paper's n_b = area / a parcels in r_b rows (1, or 2 when the OBB is wider than
    :data:`TWO_ROWS_AT` parcel depths) are spaced d = (t1 - t0) / k along the part of the
    OBB axis inside the block. Where that spacing would be narrower than the minimum lot
    width, or a row is more than :data:`MAX_DEPTH_RATIO` times deeper than the spacing
    (a block many parcels deep: farmland between a town's through roads), fewer and wider
    lots are made (larger than a); n_b is also capped by the minimum area.
    """
    area = float(block.area)
    n_b = max(1, int(round(area / mean)))
    if settings.min_area > 0:
        n_b = min(n_b, max(1, int(area // settings.min_area)))
    centre, axis, length, width = _obb(block)
    depth = math.sqrt(mean * ASPECT)
    rows = 2 if width > TWO_ROWS_AT * depth and n_b >= 2 else 1
    far = length + width
    line = shapely.LineString([centre - far * axis, centre + far * axis])
    coords = shapely.get_coordinates(shapely.intersection(line, block))
    if len(coords) < 2:  # a block the axis misses (numerically): use the OBB's extent
        t0, t1 = -length / 2.0, length / 2.0
    else:
        t = (coords - centre) @ axis
        t0, t1 = float(t.min()), float(t.max())
    narrowest = max(settings.min_width, width / rows / MAX_DEPTH_RATIO, 1e-9)
    k = max(1, min(int(round(n_b / rows)), int((t1 - t0) // narrowest)))
    return rows, k, t0, t1


def rectangular_pieces(block, mean: float) -> np.ndarray:
    """The block cut into nearly rectangular pieces (see :data:`MIN_RECTANGULARITY`).

    A piece filling less than MIN_RECTANGULARITY of its OBB and holding at least
    :data:`_MIN_PIECE_PARCELS` parcels of area ``mean`` is cut by the line through its OBB
    centre perpendicular to the OBB axis; the cut pieces are treated alike. The cuts become
    lot boundaries: a cut is perpendicular to the piece's axis, as the Voronoi edges
    between consecutive points are, so the lots along it still reach the street.
    """
    out, todo = [], [block]
    while todo:
        piece = todo.pop()
        centre, axis, length, width = _obb(piece)
        if len(out) + len(todo) >= _MAX_CUTS or piece.area < _MIN_PIECE_PARCELS * mean \
                or piece.area >= MIN_RECTANGULARITY * length * width:
            out.append(piece)
            continue
        normal = np.array([-axis[1], axis[0]])
        reach = length + width
        half = shapely.Polygon(centre + np.array([
            -reach * normal, -reach * normal + reach * axis, reach * normal + reach * axis,
            reach * normal]))
        pieces = _parcels._polygon_parts([shapely.intersection(piece, half),
                                          shapely.difference(piece, half)])
        if len(pieces) < 2:
            out.append(piece)
            continue
        todo.extend(pieces[::-1])
    return np.array(out, dtype=object)


def spacings(k: int, d: float, sigma: float, min_width: float,
             rng: np.random.Generator) -> np.ndarray:
    """The k - 1 distances d + epsilon between consecutive points, epsilon ~ N(0, sigma^2).

    Sec. 3.1.2: points "separated by a distance d + epsilon". Epsilon is clipped to
    +-:data:`_MAX_JITTER` d, and the spacings are rescaled so that they still sum to
    (k - 1) d (the points span the axis) while none is under ``min_width``: the part of
    each spacing above the minimum width is scaled by one common factor. A Voronoi cell
    between points is as wide as the mean of its two spacings, so no lot is narrower than
    the minimum width when d is not.
    """
    if k < 2:
        return np.zeros(0)
    if not (sigma > 0) or d <= min_width:
        return np.full(k - 1, d)
    eps = np.clip(rng.normal(0.0, sigma, k - 1), -_MAX_JITTER * d, _MAX_JITTER * d)
    excess = np.maximum(d + eps - min_width, 0.0)
    total = excess.sum()
    if total <= 0:
        return np.full(k - 1, d)
    return min_width + excess * ((k - 1) * (d - min_width) / total)


def _piece_lots(piece, mean: float, sd: float, settings, rng) -> np.ndarray:
    """Voronoi cells of the points on one nearly rectangular piece's OBB axis."""
    rows, k, t0, t1 = row_layout(piece, mean, settings)
    if rows == 1 and k == 1:
        return np.array([piece], dtype=object)
    centre, axis, _, _ = _obb(piece)
    d = (t1 - t0) / k
    t = t0 + d / 2 + np.concatenate([[0.0], np.cumsum(spacings(k, d, d * sd / mean,
                                                               settings.min_width, rng))])
    base = centre + t[:, None] * axis
    if rows == 2:
        normal = np.array([-axis[1], axis[0]])
        pts = np.vstack([base + _DELTA * normal, base - _DELTA * normal])
    else:
        pts = base
    cells = shapely.get_parts(shapely.voronoi_polygons(shapely.multipoints(pts),
                                                       extend_to=piece))
    return _parcels._polygon_parts(shapely.intersection(cells, piece))


def split_voronoi_obb(block, settings, rng: np.random.Generator) -> np.ndarray:
    """Parcels of one (shrunk) block: Voronoi cells of points on its OBB axis (fig. 6).

    Parameters
    ----------
    block : Polygon
        A shrunk block part, whose whole outline is street.
    settings : SubdivisionSettings
        ``options`` give the parcel size (:func:`parcel_size`); ``min_width``,
        ``min_area`` and ``min_frontage`` are hard limits.
    rng : numpy Generator
        Draws the spacing noise epsilon.

    Returns
    -------
    ndarray of Polygon
        Lots covering the block. A block that is not nearly rectangular is first cut into
        pieces that are (:func:`rectangular_pieces`); lots under the limits (pieces of a
        concave block, a tapering end) are merged into a neighbour
        (:func:`subdivision.merge_unfit_lots`).

    References
    ----------
    Aliaga, Vanegas, Benes 2008, sec. 3.1.2 and fig. 6.

    Examples
    --------
    >>> import numpy as np, shapely
    >>> from urban_synthesis.plugin.parcels.subdivision import SubdivisionSettings
    >>> lots = split_voronoi_obb(shapely.box(0, 0, 120, 30),
    ...                          SubdivisionSettings(options={"mean_area": 360, "area_sd": 0}),
    ...                          np.random.default_rng(0))
    >>> len(lots), sorted(set(np.round(shapely.area(lots), 6)))
    (10, [360.0])
    """
    mean, sd = parcel_size(settings)
    lots = [_piece_lots(piece, mean, sd, settings, rng)
            for piece in rectangular_pieces(block, mean)]
    lots = np.concatenate(lots) if lots else np.empty(0, dtype=object)
    if len(lots) <= 1:
        return np.array([block], dtype=object)
    return _parcels.merge_unfit_lots(lots, block, settings)


_parcels.register_method(_parcels.Method(
    "voronoi-obb", "Voronoi along the OBB axis (one or two rows, Aliaga et al. 2008)",
    split_voronoi_obb, street_access=True,
    reference="Aliaga, Vanegas, Benes 2008, sec. 3.1.2"))
