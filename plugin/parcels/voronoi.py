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
around the block): ``settings.options['parcel_areas']`` (example parcel areas, e.g. a
cadastre: their mean and standard deviation) or ``settings.options['mean_area']`` /
``['area_sd']``; without them a = lot_width^2 x 1.5 (a lot 1.5 times as deep as wide)
clamped to [min_area, max_area], with a standard deviation of irregularity / 2 x a.
Rows: two when the OBB is wider than 1.5 parcel depths (depth = sqrt(1.5 a)).

The method registers itself as ``voronoi-obb`` in :data:`parcels.METHODS`;
:func:`parcels.subdivide_blocks` shrinks the blocks by their streets first and merges any
piece left without street frontage (a concave block can cut a cell in two) into a neighbour.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1.2 and fig. 6.
"""
from __future__ import annotations

import math

import numpy as np
import shapely

from ..core.geometry import minimum_rectangle_corners
from ..core.progress import InputError
from . import subdivision as _parcels

__all__ = ["ASPECT", "parcel_size", "split_voronoi_obb"]

#: Depth / frontage of a typical parcel when no example gives it.
ASPECT = 1.5
#: Two rows of parcels when the block's OBB is wider than this many parcel depths.
TWO_ROWS_AT = 1.5
#: The row copies sit this far (m) on either side of the axis (the paper's small delta).
_DELTA = 0.05
#: The spacing jitter is clipped to this share of the spacing, so points keep their order.
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


def split_voronoi_obb(block, settings, rng: np.random.Generator) -> np.ndarray:
    """Parcels of one (shrunk) block: Voronoi cells of points on its OBB axis (fig. 6)."""
    mean, sd = parcel_size(settings)
    area = block.area
    n_b = max(1, int(round(area / mean)))
    if n_b == 1:
        return np.array([block], dtype=object)
    centre, axis, length, width = _obb(block)
    depth = math.sqrt(mean * ASPECT)
    rows = 2 if width > TWO_ROWS_AT * depth and n_b >= 2 else 1
    k = max(1, int(round(n_b / rows)))
    # the part of the axis inside the block (its extent over all pieces)
    far = length + width
    line = shapely.LineString([centre - far * axis, centre + far * axis])
    inside = shapely.intersection(line, block)
    coords = shapely.get_coordinates(inside)
    if len(coords) < 2:  # a block the axis misses (numerically): use the OBB's extent
        t0, t1 = -length / 2.0, length / 2.0
    else:
        t = (coords - centre) @ axis
        t0, t1 = float(t.min()), float(t.max())
    d = (t1 - t0) / k
    jitter = min(d * sd / mean, _MAX_JITTER * d) if mean > 0 else 0.0
    eps = np.clip(rng.normal(0.0, 1.0, k) * jitter, -_MAX_JITTER * d, _MAX_JITTER * d) \
        if jitter > 0 else np.zeros(k)
    t = t0 + (np.arange(k) + 0.5) * d + eps
    base = centre + t[:, None] * axis
    if rows == 2:
        normal = np.array([-axis[1], axis[0]])
        pts = np.vstack([base + _DELTA * normal, base - _DELTA * normal])
    else:
        pts = base
    if len(pts) < 2:
        return np.array([block], dtype=object)
    cells = shapely.get_parts(shapely.voronoi_polygons(shapely.multipoints(pts),
                                                       extend_to=block))
    lots = _parcels._polygon_parts(shapely.intersection(cells, block))
    # slivers of concave blocks (cells cut in two) join the neighbour they share most with
    small = shapely.area(lots) < 0.5 * settings.min_area
    if small.any() and len(lots) > 1:
        lots = _parcels._polygon_parts(_parcels.merge_into_neighbours(lots, small)[0])
    return lots


_parcels.register_method(_parcels.Method(
    "voronoi-obb", "Voronoi along the OBB axis (one or two rows, Aliaga et al. 2008)",
    split_voronoi_obb, street_access=True,
    reference="Aliaga, Vanegas, Benes 2008, sec. 3.1.2"))
