"""Parcels: city blocks shrunk by their streets and subdivided into building lots.

Scharl's thesis (2010, ch. 4.2.6 "Building Parcel Generation") makes parcels in two steps:

1. **Shrinking.** A block found as a face of the street graph has the street centrelines
   as its outline; parcels must stop at the street's edge, so each boundary edge is
   offset inwards by the half-width of the street it lies on (Scharl modifies the
   straight skeleton of Aichholzer et al. so that every edge has its own offset). Here
   (:func:`shrink_blocks`) a constant half-width is a negative buffer with mitred joins
   (the constant-offset straight skeleton), and per-street half-widths are the block
   minus the union of the street centrelines buffered by their own half-widths (round
   caps, mitred joins), the streets near each block found with an STRtree: at convex block
   corners this is exactly the weighted offset; at reflex corners the corner is rounded
   with the street's half-width (where the weighted straight skeleton would mitre it); a
   dead-end street inside a block cuts its notch out of the block.
2. **Subdivision** of each shrunk block by a METHOD (a registry, :data:`METHODS`, that
   later methods join with :func:`register_method`):

   - ``recursive`` (Scharl 4.2.6 after Weber et al. 2009; CityEngine's "Recursive"): a
     lot larger than ``max_area`` is cut by a line perpendicular to its long axis near the
     middle, recursively; :func:`split_recursive`.
   - ``skeleton`` (Vanegas et al. 2012; CityEngine's "Skeleton"): strips along each street
     side, cut across every ``lot_width``, so that every lot has street frontage;
     :func:`split_skeleton`.

Every lot gets its frontage, street access and Yang et al.'s (2013) parcel quality
(p_angle, p_area, undesirable) (:func:`lot_quality`, the measures of
:func:`metrics.parcel_metrics`).

Nothing here imports QGIS. Geometry is in a metric CRS (metres); each block is subdivided
with its own random generator derived from the seed and where the block lies
(:func:`seeds.place_key`), so one block's lots do not depend on the other blocks, nor on
its position in the layer.

References
----------
Scharl, A. (2010). Artist-controlled urban modeling (thesis), ch. 4.2.6.
Weber, B., Müller, P., Wonka, P., Gross, M. (2009). Interactive geometric simulation of
    4D cities. Computer Graphics Forum 28(2) (recursive lot subdivision).
Vanegas, C. A., Kelly, T., Weber, B., Halatsch, J., Aliaga, D. G., Müller, P. (2012).
    Procedural generation of parcels in urban modeling. Computer Graphics Forum 31(2)
    (OBB and straight-skeleton subdivision, alpha- and beta-strips).
Yang, Y.-L., Wang, J., Vouga, E., Wonka, P. (2013). Urban pattern: layout design by
    hierarchical domain splitting. ACM TOG 32(6), sec. 7 and Table 1 (parcel metrics).
Aichholzer, O., Aurenhammer, F., Alberts, D., Gärtner, B. (1995). A novel type of
    skeleton for polygons. J. Universal Computer Science 1(12).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree
from shapely.geometry.polygon import orient

from ..core.geometry import (MIN_BUILDABLE_AREA, MIN_BUILDABLE_WIDTH, counter_clockwise,
                             filled, group_starts, longest_edge_directions,
                             minimum_rectangles, one_areal, polygon_parts, too_thin,
                             without_areas)
from ..core.progress import InputError, Progress, ensure
from ..core.seeds import place_key
from ..core.text import counted
from ..measure import metrics as _metrics

__all__ = [
    "PARCEL_FIELDS", "DEFAULT_STREET_WIDTH", "DEFAULT_MAX_AREA", "DEFAULT_MIN_AREA",
    "DEFAULT_MIN_WIDTH", "DEFAULT_LOT_WIDTH", "DEFAULT_IRREGULARITY", "MIN_FRONTAGE",
    "SubdivisionSettings", "Method", "METHODS", "register_method", "method_names",
    "Subdivision", "shrink_blocks", "street_frontage", "lot_quality", "street_sides",
    "edge_faces", "merge_into_neighbours", "unfit_lots", "merge_unfit_lots",
    "split_recursive", "split_skeleton",
    "subdivide_blocks",
]

#: Output attributes of a lot, with their types (the columns of :attr:`Subdivision.table`).
PARCEL_FIELDS = [
    ("parcel_id", "int"), ("block_id", "int"), ("area_m2", "float"), ("frontage_m", "float"),
    ("has_street_access", "bool"), ("p_angle", "float"), ("p_area", "float"),
    ("undesirable", "bool"), ("method", "str"),
]

#: Full street width (m): blocks shrink by half of it on every side.
DEFAULT_STREET_WIDTH = 12.0
#: Lots larger than this (m²) are split (recursive) or narrowed (skeleton).
DEFAULT_MAX_AREA = 1200.0
#: No lot is made smaller than this (m²); smaller pieces merge into a neighbour, and no
#: footprint stands on a smaller piece of land (:data:`core.geometry.MIN_BUILDABLE_AREA`).
DEFAULT_MIN_AREA = MIN_BUILDABLE_AREA
#: No lot is made narrower than this (m, the short side of its minimum bounding rectangle),
#: and shrunk block land nowhere this wide gets no lot (:func:`core.geometry.too_thin`).
DEFAULT_MIN_WIDTH = MIN_BUILDABLE_WIDTH
#: Target street frontage of a skeleton lot (m); Yang 2013 aims at 18 m wide parcels.
DEFAULT_LOT_WIDTH = 18.0
#: Randomness of the cut positions (and of the recursive cut angles), 0..1.
DEFAULT_IRREGULARITY = 0.2
#: A lot has street access when at least this length (m) of its outline lies on the street:
#: a driveway; a lot touching the street at a corner point has none.
MIN_FRONTAGE = 3.0

#: Recursive: at irregularity 1 the cut moves up to this share of the lot length off the
#: middle (Scharl's ``subdividingEdgeDerivation``) ...
MAX_CUT_SHIFT = 0.25
#: ... and turns up to this many degrees off the perpendicular.
MAX_CUT_TURN = 15.0
#: Recursive with ``cut_across_longest_side``: where along the longest and the
#: second-longest side (share of the lot's extent) the cuts across them are tried. Judged by
#: the bounding rectangles' area the three did as well as five positions or a second side
#: on the fidelity benchmark's Gamprin, Mauren and Helsinki; judged by the pieces'
#: squareness (:func:`_squarest_cut`) the second side pays (below).
SIDE_CUT_POSITIONS = (0.35, 0.5, 0.65)
#: Recursive with ``cut_across_longest_side``: the pieces of a cut are judged by Yang's
#: two measures per lot, bounding rectangle / area plus the mean corner deviation from
#: 90 degrees divided by this (degrees: 9 degrees weigh as 0.1 of rectangle excess). By the
#: rectangles alone the fallback lots of the fidelity benchmark's Triesenberg, Mauren and
#: Helsinki (seed 0, the regions as cut) were squarer (p_area 1.128 / 1.093 / 1.240) but
#: their corners worse (p_angle 5.4 / 4.7 / 11.9 degrees against 5.2 / 4.2 / 8.0 before);
#: at 90 both beat the old cut (1.131 / 1.097 / 1.205 and 4.4 / 4.0 / 7.6), at 45 p_area
#: less (1.135 / 1.101 / 1.221), at 180 p_angle less (4.7 / 4.1 / 10.1).
SQUARE_ANGLE = 90.0
#: Skeleton: a boundary vertex turning more than this (degrees) starts a new street side;
CORNER_ANGLE = 30.0
#: and a side ends where its edges have turned this much in total (a curved street is
#: split into several nearly straight sides, so that cuts stay nearly perpendicular).
MAX_SIDE_TURN = 40.0
#: Skeleton corners with an interior angle in this range (degrees) give their corner
#: region to one of the two strips (Vanegas's beta-strips); sharper or flatter corners
#: keep the bisector between the strips.
CORNER_SWAP_ANGLES = (45.0, 135.0)
#: Skeleton: at irregularity 1 a cut moves up to this share of the lot width.
MAX_FRONT_SHIFT = 0.4
#: Skeleton: a cut this close to a bend of its street (share of the lot width) moves onto it.
BEND_SNAP = 0.4
#: Skeleton cuts move off a building to keep it whole by up to this share of a lot width,
#: and pass it this far (m) clear.
MAX_BUILDING_SHIFT = 0.5
BUILDING_CLEARANCE = 0.5
#: Lots merged so that a building stands on one parcel make no parcel larger than this
#: many times the maximum parcel area (unless one building's own lots are larger): rows
#: of touching buildings would otherwise merge without end (Mauren's district with the
#: Helsinki example, 2,472 footprints: at 4 x 518 of them stayed split, at 8 x 311, at
#: 16 x 43 with parcels of 1.6 ha at the 99th percentile, unlimited 1 with 6.7 ha ones).
MERGE_LIMIT = 16.0

_TOUCH = 1e-3       # m: half-width of the street zone that counts as frontage
# m: an edge this near the land outside a boundary is on it (blocks read back from a file
# or reprojected lie on the boundary up to round-off)
_OUTSIDE_OVERLAP = 0.05
_CRUMB = 1e-3       # m²: polygon parts smaller than this are numerical crumbs
# m: shrunk blocks and the skeleton's overlays are snap-rounded to this grid, so that razor
# slivers between faces (a zone edge nearly on a face edge) collapse instead of separating
# pieces that should merge
_GRID = 1e-6
_SHARE_EPS = 0.01   # m: band width used to measure shared boundary lengths
_MAX_LEVELS = 64    # recursion depth guard (2**64 lots)
_SIDE_NOISE = 0.5   # m: vertices this near a straight side do not break it


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class SubdivisionSettings:
    """Parameters shared by all subdivision methods (CityEngine's ``SubdivideShapesSettings``).

    Attributes
    ----------
    max_area : float
        Lots larger than this (m²) are split further (recursive) or made narrower
        (skeleton), as long as the pieces respect ``min_area`` and ``min_width``.
    min_area : float
        No split makes a lot smaller than this (m²); skeleton slivers below it merge into
        a neighbour; shrunk block pieces below it are not subdivided (no lot fits).
    min_width : float
        No split makes a lot narrower than this (m); shrunk block land nowhere this wide
        gets no lot (:func:`core.geometry.too_thin`).
    lot_width : float
        Target frontage of skeleton lots (m).
    irregularity : float in [0, 1]
        Randomness of cut positions (and recursive cut angles); 0 = regular.
    force_street_access : bool
        Recursive: a split that would cut a lot off the street is not made (CityEngine's
        ``forceStreetAccess``); any method: lots left without access merge into a neighbour.
    min_frontage : float
        Frontage (m) needed for street access.
    options : mapping
        Method-specific extra parameters (e.g. example parcel areas for a method that
        draws lot sizes from an example).
    """

    max_area: float = DEFAULT_MAX_AREA
    min_area: float = DEFAULT_MIN_AREA
    min_width: float = DEFAULT_MIN_WIDTH
    lot_width: float = DEFAULT_LOT_WIDTH
    irregularity: float = DEFAULT_IRREGULARITY
    force_street_access: bool = True
    min_frontage: float = MIN_FRONTAGE
    options: Mapping = field(default_factory=dict)

    def validate(self) -> "SubdivisionSettings":
        """Return self, or raise :class:`InputError` naming the absurd parameter."""
        for name in ("max_area", "min_area", "min_width", "lot_width", "irregularity",
                     "min_frontage"):
            value = getattr(self, name)
            if value is None or not math.isfinite(value):
                raise InputError(f"{name} must be a finite number")
            if value < 0:
                raise InputError(f"{name} must not be negative (got {value:g})")
        if not self.max_area > self.min_area:
            raise InputError(f"the maximum lot area ({self.max_area:g} m²) must be larger than "
                             f"the minimum lot area ({self.min_area:g} m²)")
        if not self.lot_width > 0:
            raise InputError("the lot width must be positive")
        if self.lot_width < self.min_width:
            raise InputError(f"the lot width ({self.lot_width:g} m) must not be smaller than "
                             f"the minimum lot width ({self.min_width:g} m)")
        if self.irregularity > 1:
            raise InputError(f"irregularity must be in [0, 1] (got {self.irregularity:g})")
        return self


# --------------------------------------------------------------------------- registry

@dataclass(frozen=True)
class Method:
    """A subdivision method of the registry.

    Attributes
    ----------
    name : str
        Stable id (the value of the algorithm's METHOD enum).
    label : str
        Human-readable name for the toolbox.
    subdivide : callable(block, settings, rng) -> array of Polygon
        Lots of one shrunk block part (a valid Polygon whose whole outline is street):
        they must be valid, inside the block, not overlapping, and cover it.
    street_access : bool
        Whether every lot has street frontage by construction (checked and repaired by
        :func:`subdivide_blocks` either way).
    reference : str
        The paper and section it follows.
    """

    name: str
    label: str
    subdivide: Callable[..., np.ndarray]
    street_access: bool
    reference: str = ""


#: The subdivision methods by name, in registration order (the order of the toolbox enum:
#: new methods are appended so that enum indices stay stable).
METHODS: Dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """Add a method to :data:`METHODS` (a name can be registered once)."""
    if method.name in METHODS:
        raise ValueError(f"subdivision method {method.name!r} is already registered")
    METHODS[method.name] = method
    return method


def method_names() -> Tuple[str, ...]:
    """Names of the registered methods, in registration order."""
    return tuple(METHODS)


# --------------------------------------------------------------------------- helpers

def _quiet(fn):
    """Run ``fn`` with numpy's floating-point 'invalid' and 'divide' flags ignored.

    GEOS raises them when an overlay's result is empty (its envelope is NaN), which
    shapely reports as a RuntimeWarning; an empty intersection is an expected answer here
    (a cut slab beyond a strip's end).
    """
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with np.errstate(invalid="ignore", divide="ignore"):
            return fn(*args, **kwargs)
    return wrapper


def _snap(geoms):
    """Coordinates snap-rounded to the grid, the geometries keeping a floating precision.

    (A geometry keeps the precision model of ``set_precision``, and GEOS would round every
    later overlay result with it; lots of the recursive method must stay exact.)
    """
    return shapely.set_precision(shapely.set_precision(geoms, _GRID), 0.0)


def _polygon_parts(geoms, min_area: float = _CRUMB) -> np.ndarray:
    """The Polygon parts (area > ``min_area``) of any geometries, as a flat array."""
    parts, _ = polygon_parts(geoms)
    return parts[shapely.area(parts) > min_area]


def _areal(geoms) -> np.ndarray:
    """Each geometry reduced to its polygon parts (overlays of touching polygons return
    collections with lines and points): a Polygon, a MultiPolygon or an empty Polygon."""
    geoms = np.asarray(geoms, dtype=object)
    out = np.empty(len(geoms), dtype=object)
    simple = shapely.get_type_id(geoms) == 3
    out[simple] = geoms[simple]
    for i in np.flatnonzero(~simple):
        out[i] = one_areal(_polygon_parts([geoms[i]]))
    return out


def _street_zone(block, no_street=None) -> shapely.Geometry:
    """A thin zone around the block outline: outline pieces inside it are street frontage.

    Lots come out of overlay operations whose vertices lie on the block outline only up to
    rounding; a millimetre zone measures the shared length robustly where a line overlay
    of two nearly collinear segments would return points. ``no_street``: areas whose
    outline is no street (a block's holes: a pond, a park), left out of the zone.
    """
    zone = shapely.buffer(shapely.boundary(block), _TOUCH, quad_segs=1)
    if no_street is not None and not shapely.is_empty(no_street):
        zone = shapely.difference(zone, _no_street_zone(no_street))
    shapely.prepare(zone)
    return zone


def _no_street_zone(no_street) -> shapely.Geometry:
    """Where a lot's edge is no street: on or near the areas ``no_street`` (a block's
    holes, the land outside a boundary)."""
    return shapely.buffer(no_street, _OUTSIDE_OVERLAP, quad_segs=1, join_style="mitre")


def _holes(blocks) -> np.ndarray:
    """Each block's holes as one (multi)polygon: land kept out of it (a pond, a park),
    whose edge is no street."""
    blocks = np.asarray(blocks, dtype=object)
    return shapely.difference(filled(blocks), blocks)


def outside_land(blocks, area, reach: float) -> np.ndarray:
    """Per block, the land outside ``area`` (a district's boundary) within ``reach`` m of
    it: empty for a block away from the boundary's outline. The block's edges on that
    land are no street (no street width, no frontage).

    >>> land = outside_land([shapely.box(0, 0, 50, 50)], shapely.box(0, 0, 100, 100), 10.0)
    >>> round(float(shapely.area(land[0])))  # strips west and south (2 x 500 m²), 3 round ends
    1234
    """
    blocks = np.asarray(blocks, dtype=object)
    out = np.array([shapely.Polygon()] * len(blocks), dtype=object)
    if area is None or not len(blocks):
        return out
    outline = shapely.boundary(area)
    near = shapely.dwithin(blocks, outline, reach)
    out[near] = shapely.difference(shapely.buffer(blocks[near], reach), area)
    return _areal(out)


@_quiet
def street_frontage(lots, block) -> np.ndarray:
    """Length (m) of each lot's outline that lies on its block's outline (the street).

    Parameters
    ----------
    lots : array of Polygon
    block : Polygon or MultiPolygon
        The shrunk block whose whole outline is street.

    Returns
    -------
    float array

    Examples
    --------
    >>> import shapely
    >>> block = shapely.box(0, 0, 40, 20)
    >>> street_frontage([shapely.box(0, 0, 20, 20), shapely.box(10, 5, 20, 15)], block).round(3)
    array([60.,  0.])
    """
    return _frontage(np.asarray(lots, dtype=object), _street_zone(block))


def _frontage(lots: np.ndarray, zone) -> np.ndarray:
    """:func:`street_frontage` with the block's street zone computed once."""
    if len(lots) == 0:
        return np.zeros(0)
    inside = shapely.intersection(shapely.boundary(lots), zone)
    # an edge leaving the street crosses the zone for a millimetre: to the centimetre, the
    # length inside is the frontage
    return np.round(np.maximum(shapely.length(inside) - 2 * _TOUCH, 0.0), 2)


def lot_quality(lots) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Yang et al. 2013 quality of each lot: p_angle, p_area and the undesirable flag.

    Parameters
    ----------
    lots : array of Polygon (metric CRS)

    Returns
    -------
    p_angle : float array
        Mean |corner angle - 90°| of the lot's corners (degrees; vertices flatter than
        :data:`metrics.STRAIGHT_ANGLE` are not corners); NaN for a lot without corners.
    p_area : float array
        Area of the minimum bounding rectangle / lot area (>= 1).
    undesirable : bool array
        p_angle > 15° or p_area > 1.2 (Yang 2013, Fig. 12).

    References
    ----------
    Yang et al. 2013, sec. 7 "parcel metrics", Fig. 12; the same measures as
    :func:`metrics.parcel_metrics`.

    Examples
    --------
    >>> import shapely
    >>> p_angle, p_area, bad = lot_quality([shapely.box(0, 0, 18, 30),
    ...                                     shapely.Polygon([(0, 0), (30, 0), (0, 30)])])
    >>> p_angle.round(1).tolist(), p_area.round(2).tolist(), bad.tolist()
    ([0.0, 30.0], [1.0, 2.0], [False, True])
    """
    lots = np.asarray(lots, dtype=object)
    n = len(lots)
    if n == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool)
    area = shapely.area(lots)
    length, width, _ = minimum_rectangles(lots)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_area = np.where(area > 0, length * width / area, np.nan)
        angles, owner = _metrics.corner_angles(lots)
        count = np.bincount(owner, minlength=n)
        p_angle = np.bincount(owner, np.abs(angles - 90.0), minlength=n) / count
    undesirable = (np.nan_to_num(p_angle) > _metrics.UNDESIRABLE_ANGLE) | \
                  (np.nan_to_num(p_area) > _metrics.UNDESIRABLE_AREA)
    return p_angle, p_area, undesirable


def _shared_length(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Approximate length of boundary shared by polygon pairs a[i], b[i] (m).

    The part of b inside a thin mitred buffer of a is a band along their common boundary
    whose area is the shared length times the band width (robust to the rounding that
    leaves adjacent lots a few nanometres apart or overlapping).
    """
    if len(a) == 0:
        return np.zeros(0)
    band = shapely.buffer(a, _SHARE_EPS, join_style="mitre", quad_segs=1)
    return shapely.area(shapely.intersection(band, b)) / _SHARE_EPS


def _clean_union(geoms) -> shapely.Geometry:
    """Union of adjacent polygons (snap-rounded to the grid), without crumbs or pin holes."""
    union = shapely.union_all(np.asarray(geoms, dtype=object), grid_size=_GRID)
    parts = _polygon_parts([union])
    if len(parts) == 0:
        return union
    cleaned = []
    for poly in parts:
        holes = [h for h in poly.interiors if shapely.area(shapely.Polygon(h)) > _CRUMB]
        cleaned.append(poly if len(holes) == len(poly.interiors)
                       else shapely.Polygon(poly.exterior, holes))
    return cleaned[0] if len(cleaned) == 1 else shapely.multipolygons(cleaned)


@_quiet
def merge_into_neighbours(geoms, bad, max_rounds: int = 50):
    """Merge each flagged polygon into the unflagged neighbour sharing most boundary.

    Rounds repeat so that a chain of flagged polygons reaches an unflagged one; a flagged
    polygon without any unflagged neighbour (an island) stays as it is. Merged polygons
    count as unflagged: merging only adds area and frontage.

    Parameters
    ----------
    geoms : array of Polygon
    bad : bool array

    Returns
    -------
    geoms : array of Polygon
        The merged polygons (fewer than given).
    kept : int array
        For each output polygon, the index of the input polygon it grew from.
    into : int array
        For each input polygon, the index of the output polygon it ended in.
    """
    geoms = np.asarray(geoms, dtype=object).copy()
    bad = np.asarray(bad, dtype=bool)
    n = len(geoms)
    into = np.arange(n)
    alive = np.ones(n, dtype=bool)
    for _ in range(max_rounds):
        todo = np.flatnonzero(bad & alive)
        good = np.flatnonzero(~bad & alive)
        if len(todo) == 0 or len(good) == 0:
            break
        tree = shapely.STRtree(geoms[good])
        i, j = tree.query(geoms[todo], predicate="dwithin", distance=_SHARE_EPS)
        if len(i) == 0:
            break
        i, j = todo[i], good[j]
        shared = _shared_length(geoms[i], geoms[j])
        ok = shared > 10 * _SHARE_EPS  # a touch at a corner point is no neighbourhood
        i, j, shared = i[ok], j[ok], shared[ok]
        if len(i) == 0:
            break
        order = np.lexsort((-shared, i))
        first = order[group_starts(i[order])]
        src, dst = i[first], j[first]
        for target in np.unique(dst):
            members = src[dst == target]
            geoms[target] = _clean_union(np.concatenate([[geoms[target]], geoms[members]]))
            alive[members] = False
        # the members (and what had merged into them) now belong to their targets
        moved = np.zeros(n, dtype=np.int64) - 1
        moved[src] = dst
        hop = moved[into]
        into = np.where(hop >= 0, hop, into)
    kept = np.flatnonzero(alive)
    position = np.cumsum(alive) - 1
    return geoms[alive], kept, position[into]


def unfit_lots(lots, zone, settings: SubdivisionSettings) -> np.ndarray:
    """Lots that break a hard limit of the settings: smaller than ``min_area``, narrower
    than ``min_width`` (the short side of the minimum bounding rectangle) or with less than
    ``min_frontage`` on the street (``zone``: the block's :func:`_street_zone`)."""
    lots = np.asarray(lots, dtype=object)
    _, width, _ = minimum_rectangles(lots)
    return (shapely.area(lots) < settings.min_area) | (width < settings.min_width) | \
        (_frontage(lots, zone) < settings.min_frontage)


@_quiet
def merge_unfit_lots(lots, block, settings: SubdivisionSettings,
                     max_rounds: int = 4) -> np.ndarray:
    """Merge every :func:`unfit_lots` lot into the neighbour sharing most boundary.

    A merge only adds area and frontage, but the union's minimum rectangle can still be
    narrow (two slivers side by side), so the check repeats; when no lot of the block fits
    the limits, the whole block is one lot.

    Parameters
    ----------
    lots : array of Polygon
        A subdivision of ``block``.
    block : Polygon
        The shrunk block, whose whole outline is street.
    settings : SubdivisionSettings

    Returns
    -------
    ndarray of Polygon
        The lots, covering the block as before; none unfit unless merging could not reach
        a fit neighbour (an island), which :func:`subdivide_blocks` counts.
    """
    lots = _polygon_parts(lots)
    zone = _street_zone(block)
    for _ in range(max_rounds):
        if len(lots) == 0:
            break
        bad = unfit_lots(lots, zone, settings)
        if not bad.any():
            return lots
        if bad.all():
            return _polygon_parts([block])  # no lot fits: the block is one lot
        merged = _polygon_parts(merge_into_neighbours(lots, bad)[0])
        if len(merged) == len(lots):
            # stuck: the neighbour sharing most boundary by the band measure touches the
            # lot only at a point across a hair-thin spike of a third lot (cells clipped
            # where a Voronoi edge nearly follows a cut), or the lot is a crumb whose
            # sides are all shorter than a neighbourhood: merge along real shared edges
            merged = _merge_along_shared_edges(lots, bad)
            if len(merged) == len(lots):
                break  # islands: no neighbour to merge into
        lots = merged
    return lots if len(lots) else _polygon_parts([block])


def _merge_along_shared_edges(lots: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Merge each flagged lot into the touching lot whose union with it is one polygon,
    trying them by decreasing length of exactly shared boundary (one by one: the rare
    lots :func:`merge_into_neighbours` cannot place)."""
    lots = np.asarray(lots, dtype=object).copy()
    alive = np.ones(len(lots), dtype=bool)
    tree = shapely.STRtree(lots)
    for j in np.flatnonzero(bad):
        cand = tree.query(lots[j], predicate="dwithin", distance=_SHARE_EPS)
        cand = cand[(cand != j) & alive[cand]]
        if len(cand) == 0:
            continue
        shared = shapely.length(shapely.intersection(shapely.boundary(lots[j]),
                                                     shapely.buffer(lots[cand], _TOUCH)))
        for c in cand[np.argsort(-shared, kind="stable")]:
            union = _clean_union([lots[c], lots[j]])
            if shapely.get_type_id(union) == 3:
                lots[c] = union
                alive[j] = False
                break
    return _polygon_parts(lots[alive])


# --------------------------------------------------------------------------- shrinking

@_quiet
def shrink_blocks(blocks, half_width=DEFAULT_STREET_WIDTH / 2, roads=None,
                  road_half_widths=None, min_area: float = 0.0, keep_clear=None,
                  min_width: float = 0.0, outside=None) -> np.ndarray:
    """Shrink blocks by the half-widths of the streets on their edges (Scharl 4.2.6).

    Parameters
    ----------
    blocks : array of Polygon / MultiPolygon (metric CRS)
        Blocks whose outlines are street centrelines (e.g. :func:`blocks.extract_blocks`);
        a hole (a pond, a park kept out of the block) is no street and does not move.
    half_width : float or float array (per block)
        Offset of every outer block edge (m) when ``roads`` is not given.
    roads : array of LineString, optional
        The street centrelines the blocks were made from. Each block loses the part within
        each street's half-width of that street (so edges on a wide street move further
        in, and dead-end streets inside a block cut their notch).
    road_half_widths : float or float array (per road), optional
        Half-widths of ``roads`` (m); default ``half_width`` for every road.
    min_area : float
        Pieces of a shrunk block smaller than this (m²) are dropped (a narrow neck of a
        block pinched off by the streets is no building land).
    keep_clear : array of Polygon, optional
        Areas no lot may take, e.g. the street surfaces and junctions of
        'tessellatestreets' (whose widths follow each street's class): each block also
        loses the part of them that reaches into it.
    min_width : float
        Pieces nowhere this wide (m) are dropped (:func:`core.geometry.too_thin`: a strip
        left between two wide streets, the island of a roundabout is no building land).
    outside : array of Polygon (per block), optional
        Land beyond the block's edges that are no street (:func:`outside_land`: beyond a
        district's boundary); those edges do not move when ``roads`` is not given (with
        ``roads`` only the roads' bands are taken off anyway).

    Returns
    -------
    ndarray of Polygon / MultiPolygon
        One per block, possibly empty (a block narrower than its streets).

    Notes
    -----
    A constant offset is the negative buffer with mitred joins, which is the
    constant-speed straight skeleton's offset. Per-road offsets are the block minus the
    union of the roads buffered by their own half-widths (round caps, mitred joins): at a
    convex block corner the two street bands cross at the weighted offset corner; at a
    reflex corner the round cap of the street end rounds the corner off (the weighted
    straight skeleton would mitre it; the difference is 0.21 w² per reflex corner).

    Examples
    --------
    >>> import shapely
    >>> float(shapely.area(shrink_blocks([shapely.box(0, 0, 100, 100)], 6.0)[0]))
    7744.0
    >>> corners = [(0, 0), (100, 0), (100, 100), (0, 100), (0, 0)]
    >>> square = [shapely.LineString(corners[i:i + 2]) for i in range(4)]
    >>> shrunk = shrink_blocks([shapely.box(0, 0, 100, 100)], roads=square,
    ...                        road_half_widths=[3.0, 5.0, 6.0, 8.0])
    >>> round(float(shapely.area(shrunk[0])), 6)  # (100 - 3 - 6) x (100 - 5 - 8)
    7917.0
    """
    blocks = np.asarray(blocks, dtype=object).ravel()
    n = len(blocks)
    if n == 0:
        return np.empty(0, dtype=object)
    if roads is None:
        hw = np.broadcast_to(np.asarray(half_width, dtype=float), (n,))
        if (hw < 0).any() or not np.isfinite(hw).all():
            raise InputError("street half-widths must be finite and not negative")
        # the outline moves in, a hole (a pond, a park kept out of the block) does not:
        # its edge is no street; nor does an edge on the land outside (the block grown
        # over that land before the offset has no outline there)
        grown = filled(blocks) if outside is None else shapely.union(
            filled(blocks), shapely.buffer(outside, _OUTSIDE_OVERLAP, join_style="mitre"))
        out = shapely.difference(
            shapely.buffer(grown, -hw, join_style="mitre", mitre_limit=10.0),
            _holes(blocks) if outside is None else shapely.union(_holes(blocks), outside))
    else:
        roads = np.asarray(roads, dtype=object).ravel()
        hw = np.broadcast_to(np.asarray(half_width if road_half_widths is None
                                        else road_half_widths, dtype=float), (len(roads),))
        if (hw < 0).any() or not np.isfinite(hw).all():
            raise InputError("street half-widths must be finite and not negative")
        keep = (hw > 0) & ~(shapely.is_missing(roads) | shapely.is_empty(roads))
        bands = shapely.buffer(roads[keep], hw[keep], cap_style="round", join_style="mitre",
                               mitre_limit=10.0)
        out = without_areas(blocks, bands)   # each block less its own streets' bands
    out = np.asarray(out, dtype=object)
    if keep_clear is not None:
        # polygons only before the snap: a collection snaps part by part, not as one area
        out = _areal(without_areas(out, keep_clear))
    # drop crumbs and pinched-off necks; keep polygons only (a difference can return lines)
    out = _snap(out)
    small = shapely.area(shapely.get_parts(out)) <= max(min_area, _CRUMB)
    if small.any() or not np.isin(shapely.get_type_id(out), (3, 6)).all():
        for i in range(n):
            out[i] = one_areal(_polygon_parts([out[i]], max(min_area, _CRUMB)))
    return _without_thin_land(out, min_width)[0] if min_width > 0 else out


def _without_thin_land(shrunk: np.ndarray, min_width: float, min_area: float = 0.0):
    """Shrunk blocks less their pieces nowhere ``min_width`` wide (:func:`too_thin`), and
    per block whether it lost such a piece larger than ``min_area`` (one that the area
    rule alone would have given a lot)."""
    shrunk = np.asarray(shrunk, dtype=object).copy()
    parts, owner = polygon_parts(shrunk)
    thin = too_thin(parts, min_width) if len(parts) else np.zeros(0, dtype=bool)
    lost = np.zeros(len(shrunk), dtype=bool)
    lost[owner[thin & (shapely.area(parts) > min_area)]] = True
    for i in np.unique(owner[thin]):
        shrunk[i] = one_areal(parts[(owner == i) & ~thin])
    return shrunk, lost


# --------------------------------------------------------------------------- recursive

def _projections(coords, idx, starts, direction):
    """Min and max of each polygon's coordinates projected on its own direction."""
    p = np.einsum("ij,ij->i", coords, direction[idx])
    return np.minimum.reduceat(p, starts), np.maximum.reduceat(p, starts)


def _pinned_to_corners(lots: np.ndarray, angle: np.ndarray, t: np.ndarray,
                       max_shift: float) -> np.ndarray:
    """Cut fractions ``t`` along each lot's axis moved, by at most ``max_shift`` m, onto the
    nearest corner of its outline (a vertex Yang's p_angle counts,
    :func:`metrics.corners`), so that the cut leaves from that corner: a lot then has no
    bend of its street side inside it, where it would count as a corner of 150-170 degrees
    (the row templates' alignment, sec. 4.1). Corners within 5 % of the lot's extent from
    either end are not used (a cut there would leave a sliver)."""
    t = np.array(t, dtype=float, copy=True)
    xy, _, owner = _metrics.corners(lots)
    if not len(xy):
        return t
    coords, idx = shapely.get_coordinates(lots, return_index=True)
    starts = np.flatnonzero(group_starts(idx))
    u = np.column_stack([np.cos(angle), np.sin(angle)])
    umin, umax = _projections(coords, idx, starts, u)
    extent = np.maximum(umax - umin, 1e-9)
    frac = (np.einsum("ij,ij->i", xy, u[owner]) - umin[owner]) / extent[owner]
    gap = np.abs(frac - t[owner]) * extent[owner]
    ok = (frac > 0.05) & (frac < 0.95) & (gap <= max_shift)
    for i in np.unique(owner[ok]):
        mine = np.flatnonzero(ok & (owner == i))
        t[i] = frac[mine[np.argmin(gap[mine])]]
    return t


def _side_directions(lots: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Direction (radians) of each lot's longest and second-longest outline side (the
    longest again where the outline has one side); vertices within :data:`_SIDE_NOISE` of
    a straight line are dropped first, so that a digitised straight side counts whole."""
    rings = shapely.simplify(shapely.get_exterior_ring(lots), _SIDE_NOISE)
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    step, owner = np.diff(coords, axis=0)[same], idx[1:][same]
    order = np.lexsort((-np.hypot(step[:, 0], step[:, 1]), owner))
    first = group_starts(owner[order])
    longest = longest_edge_directions(rings)
    second = longest.copy()
    nxt = np.flatnonzero(first) + 1
    nxt = nxt[nxt < len(order)]
    nxt = nxt[~first[nxt]]  # the lot's own second edge, not the next lot's first
    e = order[nxt]
    second[owner[e]] = np.arctan2(step[e, 1], step[e, 0])
    return longest, second


def _squarest_cut(lots: np.ndarray, cut, pin: float, settings: SubdivisionSettings, zone):
    """The cut ``(angle, t, turn)`` per lot among: the given one; Scharl's cuts across the
    lot's longest and its second-longest side (at :data:`SIDE_CUT_POSITIONS` of its
    extent); the cut across the other axis of its bounding rectangle (at the middle);
    all pinned to a corner as the first cut is. The acceptable one (every piece big, wide
    and on the street) whose two pieces are the squarest wins: the sum over the pieces of
    bounding rectangle / area plus mean corner deviation / :data:`SQUARE_ANGLE` (Yang's
    p_area and p_angle per lot). On a lot whose long street side is not
    along its bounding rectangle (a wedge, a parallelogram) the rectangle's cut leaves
    trapezoids where the side's leaves right angles on the street; on a bent lot the cut
    across its second side can part the two arms.

    Judged per piece, not by the pieces' rectangles summed (which weights each piece by
    its area and so overlooks a small skewed piece, a whole lot in Yang's mean), and with
    the second side and the other axis: the fallback lots of the fidelity benchmark's
    Triesenberg, Mauren and Helsinki (seed 0, the regions as cut; 466 / 255 / 64 lots
    before, 465 / 263 / 65 after) had a mean p_area of 1.148 / 1.113 / 1.250 and p_angle
    of 5.2 / 4.2 / 8.0 degrees before, 1.131 / 1.097 / 1.205 and 4.4 / 4.0 / 7.6 after.
    By the rectangles per piece without the new candidates p_area was 1.144 / 1.100 /
    1.229; the second side judged by summed rectangles gave 1.146 / 1.107 / 1.268."""
    k = len(lots)
    candidates = [cut]
    for side in _side_directions(lots):
        for position in SIDE_CUT_POSITIONS:
            t = np.full(k, position)
            if pin > 0:
                t = _pinned_to_corners(lots, side, t, pin)
            candidates.append((side, t, np.zeros(k)))
    _, _, axis = minimum_rectangles(lots)
    other = np.radians(axis) + np.pi / 2
    t = np.full(k, 0.5)
    if pin > 0:
        t = _pinned_to_corners(lots, other, t, pin)
    candidates.append((other, t, np.zeros(k)))
    squareness = np.empty((len(candidates), k))
    for c, (angle, t, turn) in enumerate(candidates):
        parts, owner, beyond = _cut(lots, angle, t, turn)
        length, width, _ = minimum_rectangles(parts)
        ok = _accept(parts, owner, beyond, k, settings, zone)
        ratio = length * width / np.maximum(shapely.area(parts), _CRUMB)
        off_square = ratio + lot_quality(parts)[0] / SQUARE_ANGLE
        squareness[c] = np.where(ok, np.bincount(owner, off_square, minlength=k), np.inf)
    squareness[1:] += 1e-6  # a tie keeps the first cut
    best, lot = np.argmin(squareness, axis=0), np.arange(k)
    angle, t, turn = (np.stack([np.broadcast_to(c[i], k) for c in candidates])[best, lot]
                      for i in range(3))
    return angle, t, turn


def _cut_line(coords, idx, starts, angle, t, turn):
    """The line :func:`_cut` cuts along, as (normal, offset): the points x with
    x . normal = offset; the part below it is the lot's part with x . normal <= offset."""
    u = np.column_stack([np.cos(angle), np.sin(angle)])
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    umin, umax = _projections(coords, idx, starts, u)
    nmin, nmax = _projections(coords, idx, starts, nrm)
    point = u * (umin + t * (umax - umin))[:, None] + nrm * (0.5 * (nmin + nmax))[:, None]
    cu = np.column_stack([np.cos(angle + turn), np.sin(angle + turn)])
    return cu, np.einsum("ij,ij->i", point, cu)


def cut_areas(lots: np.ndarray, angle: np.ndarray, t: np.ndarray,
              turn: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The areas of the two sides :func:`_cut` would cut each lot into (below, beyond the
    line), without cutting: each ring's shoelace sum over the parts of its edges below the
    line, in coordinates whose origin is on the line, where the cut's own edge, a segment
    through the origin, adds nothing. GEOS's intersection of every candidate cut costs a
    thousand times more, and a search over cuts keeps only few of them.

    >>> sq = np.array([shapely.box(0, 0, 4, 2)])
    >>> [float(a[0]) for a in cut_areas(sq, np.zeros(1), np.full(1, 0.25), np.zeros(1))]
    [2.0, 6.0]
    """
    lots = np.asarray(lots, dtype=object)
    k = len(lots)
    coords, idx = shapely.get_coordinates(lots, return_index=True)
    starts = np.flatnonzero(group_starts(idx))
    cu, at = _cut_line(coords, idx, starts, angle, t, turn)
    rings, ring_owner = shapely.get_rings(lots, return_index=True)
    xy, ring = shapely.get_coordinates(rings, return_index=True)
    owner = ring_owner[ring]
    # the origin on the line, beside the lot (few digits lost to the map's offsets)
    near = coords[starts]
    origin = near - cu * (np.einsum("ij,ij->i", near, cu) - at)[:, None]
    p = xy - origin[owner]
    side = np.einsum("ij,ij->i", p, cu[owner])
    a, b, sa, sb = p[:-1], p[1:], side[:-1], side[1:]
    edge = ring[:-1] == ring[1:]
    a, b, sa, sb, of = a[edge], b[edge], sa[edge], sb[edge], ring[:-1][edge]
    a_in, b_in = sa <= 0, sb <= 0
    # where the line crosses the edge (NaN for an edge along it, beyond: never used)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a + (b - a) * (sa / (sa - sb))[:, None]
        start = np.where(a_in[:, None], a, x)
        end = np.where(b_in[:, None], b, x)
        part = np.where(a_in | b_in, start[:, 0] * end[:, 1] - start[:, 1] * end[:, 0], 0.0)
    whole = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    n_rings = len(rings)
    ring_whole = np.bincount(of, whole, minlength=n_rings)
    # an exterior adds its area, a hole takes it away, whichever way each runs
    first = np.r_[True, ring_owner[1:] != ring_owner[:-1]]
    sign = np.where(first, 1.0, -1.0) * np.sign(ring_whole)
    below = 0.5 * np.bincount(ring_owner, sign * np.bincount(of, part, minlength=n_rings),
                              minlength=k)
    total = 0.5 * np.bincount(ring_owner, sign * ring_whole, minlength=k)
    return below, total - below


def _cut(lots: np.ndarray, angle: np.ndarray, t: np.ndarray, turn: np.ndarray):
    """Cut each lot in two by a line across its axis.

    The line crosses the axis of direction ``angle`` (radians) at the fraction ``t`` of
    the lot's extent along it, turned by ``turn`` radians off the perpendicular. Both
    halves are intersections with half-plane rectangles built from the same corner
    coordinates, so their shared edge is computed alike.

    Returns
    -------
    parts : array of Polygon
    owner : int array, index of the lot of each part
    side : bool array, True for parts beyond the line
    """
    k = len(lots)
    coords, idx = shapely.get_coordinates(lots, return_index=True)
    starts = np.flatnonzero(group_starts(idx))
    cu, at = _cut_line(coords, idx, starts, angle, t, turn)
    cn = np.column_stack([-cu[:, 1], cu[:, 0]])
    amin, amax = _projections(coords, idx, starts, cu)
    bmin, bmax = _projections(coords, idx, starts, cn)
    margin = 1.0 + (amax - amin) + (bmax - bmin)
    lo, hi = bmin - margin, bmax + margin

    def rectangles(a0, a1):
        a = np.column_stack([a0, a1, a1, a0, a0])
        b = np.column_stack([lo, lo, hi, hi, lo])
        xy = a[:, :, None] * cu[:, None, :] + b[:, :, None] * cn[:, None, :]
        return shapely.polygons(xy)

    below = shapely.intersection(lots, rectangles(amin - margin, at))
    above = shapely.intersection(lots, rectangles(at, amax + margin))
    pieces = np.concatenate([below, above])
    parts, owner = polygon_parts(pieces)
    ok = shapely.area(parts) > _CRUMB
    parts, owner = parts[ok], owner[ok]
    return parts, owner % k, owner >= k


def _accept(parts, owner, side, k, settings: SubdivisionSettings, zone) -> np.ndarray:
    """Which of ``k`` cuts are acceptable: both sides non-empty, every piece big, wide
    and (with forced street access) on the street."""
    area = shapely.area(parts)
    _, width, _ = minimum_rectangles(parts)
    good = (area >= settings.min_area) & (width >= settings.min_width)
    if settings.force_street_access and len(parts):
        good &= _frontage(parts, zone) >= settings.min_frontage
    n_bad = np.bincount(owner, ~good, minlength=k)
    has_below = np.bincount(owner, ~side, minlength=k) > 0
    has_above = np.bincount(owner, side, minlength=k) > 0
    return (n_bad == 0) & has_below & has_above


@_quiet
def split_recursive(block, settings: SubdivisionSettings,
                    rng: np.random.Generator) -> np.ndarray:
    """Recursive subdivision of one block (Scharl 4.2.6, after Weber et al. 2009).

    While a lot is larger than ``max_area`` it is cut by a line perpendicular to the long
    axis of its minimum bounding rectangle near the middle: the cut moves off the middle
    by up to ``irregularity x`` :data:`MAX_CUT_SHIFT` of the lot length (Scharl's
    ``subdividingEdgeDerivation``) and turns off the perpendicular by up to
    ``irregularity x`` :data:`MAX_CUT_TURN` degrees. A cut is not made when a piece
    would be smaller than ``min_area``, narrower than ``min_width`` or, with
    ``force_street_access``, without street frontage; then the middle perpendicular cut
    and the cut across the other axis are tried, and when none is acceptable the lot
    stays as it is (larger than ``max_area``). ``settings.options['pin_cuts_to_corners']``
    (m, optional): the first cut moves by up to that much onto a corner of the lot's
    outline (:func:`_pinned_to_corners`; the domain split's rule-based parcels).
    ``settings.options['cut_across_longest_side']`` (bool, optional): the first cut is
    the one that leaves the squarest pieces among that one, Scharl's cuts across the
    lot's longest and second-longest side and the cut across the rectangle's other axis
    (:func:`_squarest_cut`; the domain split's rule-based parcels).

    Scharl cuts perpendicular to the polygon's longest side after merging collinear
    edges; for a rectangle that is the long axis of the minimum bounding rectangle used
    here, which also stays meaningful for blocks outlined by curved streets (many short
    sides).

    Parameters
    ----------
    block : Polygon
        A shrunk block part, whose whole outline is street.
    settings : SubdivisionSettings
    rng : numpy Generator

    Returns
    -------
    ndarray of Polygon
        The lots: valid, inside the block, not overlapping, covering it.

    Notes
    -----
    All lots of one recursion level are cut at once (vectorised rectangles and overlays).

    Examples
    --------
    >>> import numpy as np, shapely
    >>> lots = split_recursive(shapely.box(0, 0, 100, 40),
    ...                        SubdivisionSettings(max_area=500, irregularity=0),
    ...                        np.random.default_rng(0))
    >>> len(lots), sorted(set(shapely.area(lots).round(6).tolist()))
    (8, [500.0])
    """
    zone = _street_zone(block)
    lots = _polygon_parts([block])
    done: List[np.ndarray] = []
    limit = settings.max_area * (1.0 + 1e-9)
    irr = settings.irregularity
    pin = float(settings.options.get("pin_cuts_to_corners", 0.0) or 0.0)
    across_side = bool(settings.options.get("cut_across_longest_side", False))
    for _ in range(_MAX_LEVELS):
        if len(lots) == 0:
            break
        big = shapely.area(lots) > limit
        done.append(lots[~big])
        lots = lots[big]
        k = len(lots)
        if k == 0:
            break
        _, _, axis = minimum_rectangles(lots)
        axis = np.radians(axis)
        # one draw per lot and level, also when a later attempt wins: deterministic order
        shift = rng.uniform(-1.0, 1.0, k)
        turn = rng.uniform(-1.0, 1.0, k)
        middle = 0.5 + irr * MAX_CUT_SHIFT * shift
        if pin > 0:
            middle = _pinned_to_corners(lots, axis, middle, pin)
        attempts = [(axis, middle, irr * np.radians(MAX_CUT_TURN) * turn)]
        if across_side:
            attempts[0] = _squarest_cut(lots, attempts[0], pin, settings, zone)
        if irr > 0 or pin > 0:  # else the first cut is the middle one already
            attempts.append((axis, np.full(k, 0.5), np.zeros(k)))
        attempts.append((axis + np.pi / 2, np.full(k, 0.5), np.zeros(k)))
        pending = np.arange(k)
        children = []
        for angle, t, rot in attempts:
            if len(pending) == 0:
                break
            parts, owner, side = _cut(lots[pending], angle[pending], t[pending], rot[pending])
            ok = _accept(parts, owner, side, len(pending), settings, zone)
            children.append(parts[ok[owner]])
            pending = pending[~ok]
        done.append(lots[pending])  # no acceptable cut: the lot stays as it is
        lots = np.concatenate(children) if children else np.empty(0, dtype=object)
    done.append(lots)
    return np.concatenate(done)


# --------------------------------------------------------------------------- skeleton

@dataclass
class _Side:
    """One street side of a block ring: nearly straight consecutive boundary edges."""

    coords: np.ndarray   # (k, 2) vertices along the side, interior on the left
    ring: int            # ring index (0 = exterior)
    end_turn: float      # turn (degrees, left positive) at the vertex where the side ends

    @property
    def line(self):
        return shapely.LineString(self.coords)

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.coords, axis=0).T).sum())


def street_sides(polygon, corner_angle: float = CORNER_ANGLE,
                 max_turn: float = MAX_SIDE_TURN) -> List[_Side]:
    """Street sides of a block: maximal runs of nearly collinear boundary edges.

    A side ends at a vertex turning more than ``corner_angle`` degrees (a corner), or
    where its edges have turned more than ``max_turn`` degrees in total (a curved street
    becomes several nearly straight sides). This merges the faces of nearly collinear
    consecutive edges, as Vanegas et al. 2012 do before building their strips.

    Parameters
    ----------
    polygon : Polygon
    corner_angle, max_turn : float (degrees)

    Returns
    -------
    list of sides, each with ``coords`` (interior on the left: exterior counter-clockwise,
    holes clockwise), ``ring`` and ``end_turn`` (the signed turn at its last vertex; the
    interior angle there is 180 - end_turn).

    Examples
    --------
    >>> import shapely
    >>> sides = street_sides(shapely.box(0, 0, 100, 40).union(shapely.box(50, 0, 150, 40)))
    >>> [round(s.length) for s in sides]
    [40, 150, 40, 150]
    """
    polygon = orient(polygon, sign=1.0)
    sides: List[_Side] = []
    rings = [polygon.exterior] + list(polygon.interiors)
    for r, ring in enumerate(rings):
        ring = shapely.remove_repeated_points(shapely.LinearRing(ring), 1e-6)
        p = shapely.get_coordinates(ring)[:-1]
        k = len(p)
        if k < 3:
            continue
        d_in = p - np.roll(p, 1, axis=0)
        d_out = np.roll(p, -1, axis=0) - p
        cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
        turn = np.degrees(np.arctan2(cross, np.einsum("ij,ij->i", d_in, d_out)))
        start = int(np.argmax(np.abs(turn)))  # the sharpest corner starts the first side
        current = [start]
        acc = 0.0
        ring_sides = []
        for j in (start + np.arange(1, k)) % k:  # inherently sequential: a walk
            current.append(j)
            if abs(turn[j]) > corner_angle or abs(acc + turn[j]) > max_turn:
                ring_sides.append(_Side(p[current], r, float(turn[j])))
                current, acc = [j], 0.0
            else:
                acc += turn[j]
        current.append(start)
        ring_sides.append(_Side(p[current], r, float(turn[start])))
        sides += ring_sides
    return sides


@_quiet
def edge_faces(polygon, sides: Sequence[_Side], spacing: Optional[float] = None,
               simplify: bool = True) -> np.ndarray:
    """The face of each street side: the part of the block closest to that side.

    The straight skeleton's faces (one per boundary edge) are not available in GEOS 3.11.
    Here each side is densified to points every ``spacing`` metres, the Voronoi cells of
    all points are united per side and clipped to the block: the face of a side is the
    region closer to it than to any other side (the Voronoi diagram of the sides, up to
    the point spacing). For a convex block this equals the straight skeleton's faces
    (the bisectors of the sides' lines); at a reflex corner the boundary between faces
    curves around the corner vertex (a parabola) where the straight skeleton has a
    straight bisector, and parts of a face that lie beyond the block's outline from their
    side are cut off (they are merged into a neighbour later).

    The cell boundaries make steps of the point spacing where three faces meet; the
    lines between faces are simplified by half the spacing, all faces alike
    (:func:`_simplify_coverage`), so that lots do not inherit sham corners from them.

    Parameters
    ----------
    polygon : Polygon
    sides : list of :func:`street_sides`
    spacing : float, optional
        Point spacing (m); default one 400th of the perimeter, within 0.25-1.5 m.
    simplify : bool
        Simplify the lines between faces (the block outline is never changed).

    Returns
    -------
    ndarray of (Multi)Polygon, one per side (possibly empty); together they cover the
    block without overlaps. Their boundaries are off the exact bisectors by up to about
    the point spacing.

    Examples
    --------
    >>> import shapely
    >>> block = shapely.box(0, 0, 100, 40)
    >>> faces = edge_faces(block, street_sides(block))
    >>> sorted(shapely.area(faces).round().tolist())  # two triangles, two trapezoids
    [400.0, 400.0, 1600.0, 1600.0]
    """
    if spacing is None:
        spacing = float(np.clip(shapely.length(polygon) / 400.0, 0.25, 1.5))
    points, label = [], []
    for k, side in enumerate(sides):
        c = shapely.get_coordinates(shapely.segmentize(side.line, spacing))[:-1]
        points.append(c)
        label.append(np.full(len(c), k))
    points = np.vstack(points)
    label = np.concatenate(label)
    x0, y0, x1, y1 = shapely.bounds(polygon)
    frame = shapely.box(x0 - (x1 - x0), y0 - (y1 - y0), x1 + (x1 - x0), y1 + (y1 - y0))
    cells = shapely.get_parts(shapely.voronoi_polygons(shapely.multipoints(points),
                                                       extend_to=frame))
    # cocircular points (a square's sides) can make a cell a collection with a zero-length
    # line: keep the polygons
    cells = shapely.get_parts(cells)
    cells = cells[shapely.get_type_id(cells) == 3]
    # GEOS returns the cells in no particular order: every point inside a Voronoi cell is
    # closest to the cell's own generator, so a k-d tree finds each cell's side
    inside = shapely.get_coordinates(shapely.point_on_surface(cells))
    cell_label = label[cKDTree(points).query(inside)[1]]
    faces = np.empty(len(sides), dtype=object)
    for k in range(len(sides)):
        mine = cells[cell_label == k]
        try:  # cells of one side share exact edges: a coverage union is exact and fast
            faces[k] = shapely.coverage_union_all(mine)
        except shapely.errors.GEOSException:  # degenerate (cocircular) cells: overlay union
            faces[k] = shapely.union_all(mine)
    faces = _areal(shapely.intersection(faces, polygon, grid_size=_GRID))
    return _simplify_coverage(polygon, faces, 0.5 * spacing) if simplify else faces


def _simplify_coverage(polygon, faces: np.ndarray, tolerance: float) -> np.ndarray:
    """Simplify the lines between the faces of a block by ``tolerance``, faces alike.

    The face outlines are noded into one line network, merged into lines between
    junctions; lines on the block outline stay as they are, the others are simplified
    (Douglas-Peucker keeps their end points, so the network stays connected), the network
    is polygonised again and each new polygon goes back to the face that holds its
    representative point. If the simplified faces do not cover the block exactly (lines
    crossing after simplification), the faces are returned unchanged.
    """
    present = ~shapely.is_empty(faces)
    if present.sum() < 2:
        return faces
    lines = shapely.get_parts(shapely.line_merge(shapely.union_all(
        shapely.boundary(faces[present]))))
    outline = shapely.buffer(shapely.boundary(polygon), 1e-6, quad_segs=1)
    inner = ~shapely.covered_by(lines, outline)
    lines[inner] = shapely.simplify(lines[inner], tolerance, preserve_topology=False)
    pieces = shapely.get_parts(shapely.polygonize(
        shapely.get_parts(shapely.union_all(lines))))
    if len(pieces) == 0:
        return faces
    index = np.flatnonzero(present)
    hit_piece, hit_face = shapely.STRtree(faces[present]).query(
        shapely.point_on_surface(pieces), predicate="within")
    label = np.full(len(pieces), -1)
    label[hit_piece] = index[hit_face]
    total = shapely.area(pieces[label >= 0]).sum()
    if (label < 0).any() or abs(total - shapely.area(polygon)) > 1e-6 * shapely.area(polygon):
        return faces
    out = np.array([shapely.Polygon()] * len(faces), dtype=object)
    for k in np.unique(label):
        mine = pieces[label == k]
        try:
            out[k] = shapely.coverage_union_all(mine)
        except shapely.errors.GEOSException:
            out[k] = shapely.union_all(mine)
    return out


def _depth(face, line) -> float:
    """Largest distance (m) of a geometry's vertices from a street side."""
    coords = shapely.get_coordinates(face)
    if len(coords) == 0:
        return 0.0
    return float(shapely.distance(shapely.points(coords), line).max())


def _neighbours(sides: List[_Side]) -> Tuple[np.ndarray, np.ndarray]:
    """Index of the previous and the next side of each side on its ring."""
    ring_of = np.array([s.ring for s in sides])
    prev, nxt = np.empty(len(sides), dtype=np.int64), np.empty(len(sides), dtype=np.int64)
    for r in np.unique(ring_of):
        same = np.flatnonzero(ring_of == r)
        prev[same] = np.roll(same, 1)
        nxt[same] = np.roll(same, -1)
    return prev, nxt


def _give(faces: np.ndarray, donor: int, receiver: int, region) -> None:
    """Move the parts of ``region`` (inside the donor's face) that touch the receiver's
    face from the donor to the receiver (far pieces stay with the donor)."""
    take = _polygon_parts([shapely.intersection(faces[donor], region, grid_size=_GRID)])
    if len(take):
        take = take[shapely.distance(take, faces[receiver]) < 1e-6]
    if len(take) == 0:
        return
    take = shapely.union_all(take, grid_size=_GRID)
    faces[receiver] = _areal([shapely.union(faces[receiver], take, grid_size=_GRID)])[0]
    faces[donor] = _areal([shapely.difference(faces[donor], take, grid_size=_GRID)])[0]


def _half_plane(origin: np.ndarray, direction: np.ndarray, reach: float):
    """The rectangle of side ``reach`` beyond ``origin`` in ``direction`` (a half-plane
    as far as the block goes)."""
    d = direction / np.hypot(*direction)
    n = np.array([-d[1], d[0]])
    return shapely.Polygon([origin - n * reach, origin - n * reach + d * reach,
                            origin + n * reach + d * reach, origin + n * reach])


def _swap_corners(polygon, sides: List[_Side], faces: np.ndarray) -> np.ndarray:
    """Give the corner regions to one strip each (Vanegas et al.'s beta-strips).

    The faces of two sides meeting at a corner are separated by the corner's bisector, so
    the lots at the corner would get a 45° side. Vanegas et al. 2012 move such corner
    regions to one strip; only near-right corners (interior angle within
    :data:`CORNER_SWAP_ANGLES`) are changed:

    1. A side shorter than both its neighbours, with near-right corners at both ends (the
       short end of a rectangle), gives its whole face away: the face is cut by the line
       perpendicular to the side through the face's far end (the skeleton node), and each
       half goes to the neighbouring strip on its side. A rectangular block becomes two
       strips along its long sides whose end lots are corner lots facing two streets.
    2. At the other near-right corners the longer side (the first on a tie) takes, from
       its neighbour's face, everything within its strip's depth at the corner (the
       distance from its street of the node where the corner's bisector ends) of its
       street line extended beyond the corner. A square block becomes a pinwheel of four
       square strips.
    """
    faces = faces.copy()
    x0, y0, x1, y1 = shapely.bounds(polygon)
    reach = 2.0 * math.hypot(x1 - x0, y1 - y0)
    lo, hi = CORNER_SWAP_ANGLES
    right = np.array([lo <= 180.0 - s.end_turn <= hi for s in sides])  # corner at the end
    length = np.array([s.length for s in sides])
    prev, nxt = _neighbours(sides)
    # 1. short sides between two near-right corners
    for b in range(len(sides)):
        a, c = prev[b], nxt[b]
        if a == b or c == b or a == c or not (right[a] and right[b]):
            continue
        if not (length[b] < length[a] and length[b] < length[c]) or \
                shapely.is_empty(faces[b]):
            continue
        p = sides[b].coords
        u = p[-1] - p[0]
        u = u / np.hypot(*u)
        coords = shapely.get_coordinates(faces[b])
        dist = shapely.distance(shapely.points(coords), sides[b].line)
        far = coords[dist >= 0.95 * dist.max()]
        at = p[0] + u * float(((far - p[0]) @ u).mean())
        _give(faces, b, a, _half_plane(at, -u, reach))
        _give(faces, b, c, _half_plane(at, u, reach))
    # 2. the other near-right corners
    for a in range(len(sides)):
        b = nxt[a]
        if not right[a] or a == b:
            continue
        if shapely.is_empty(faces[a]) or shapely.is_empty(faces[b]):
            continue
        owner, other = (a, b) if length[a] >= length[b] else (b, a)
        c = sides[owner].coords
        if owner == a:  # the corner is the owner's end: extend it beyond the corner
            d = c[-1] - c[-2]
            line = np.vstack([c, c[-1] + d / np.hypot(*d) * reach])
        else:
            d = c[1] - c[0]
            line = np.vstack([c[0] - d / np.hypot(*d) * reach, c])
        # the depth of the owner's strip at this corner: how far the bisector between the
        # two faces reaches from the owner's street (the skeleton node at its end)
        shared = shapely.intersection(shapely.boundary(faces[owner]),
                                      shapely.buffer(faces[other], 1e-6, quad_segs=1))
        depth = _depth(shared, sides[owner].line)
        if depth <= 0:
            continue
        zone = shapely.buffer(shapely.LineString(line), depth * (1 + 1e-9), cap_style="flat",
                              join_style="mitre")
        _give(faces, other, owner, zone)
    return faces


def _street_sides_only(block, sides: List[_Side], faces: np.ndarray, no_street):
    """The street sides and their faces, with the faces of the sides on ``no_street`` (a
    district's boundary, a hole's edge: most of the side's length in it) shared out among
    the street sides, each part to the nearest (Vanegas et al. 2012 give strips to street
    edges only): the lots behind a boundary reach to it."""
    on = np.array([shapely.length(shapely.intersection(side.line, no_street))
                   > 0.5 * side.length for side in sides], dtype=bool)
    if not on.any():
        return sides, faces
    street = [side for side, o in zip(sides, on) if not o]
    if not street:
        return street, faces[:0]
    rest = shapely.union_all(faces[on])
    faces = faces[~on].copy()
    if not shapely.is_empty(rest):
        shared = edge_faces(rest, street)
        faces = _areal(shapely.union(faces, shared, grid_size=_GRID))
    return street, faces


def _strip_parts(sides: List[_Side], faces: np.ndarray):
    """Polygon parts of the faces, each with its side; parts that do not lie on their own
    side (beyond a reflex corner, cut off by a corner swap) merge into a neighbour."""
    parts, owner = shapely.get_parts(faces, return_index=True)
    ok = (shapely.get_type_id(parts) == 3)
    ok[ok] = shapely.area(parts[ok]) > _CRUMB
    parts, owner = parts[ok], owner[ok]
    if len(parts) == 0:
        return parts, owner
    lines = np.array([sides[k].line for k in owner], dtype=object)
    on_side = shapely.length(shapely.intersection(
        shapely.boundary(parts), shapely.buffer(lines, _TOUCH, quad_segs=1))) > 0.1
    merged, kept, _ = merge_into_neighbours(parts, ~on_side)
    return merged, owner[kept]


def _cuts_off_buildings(cuts: np.ndarray, buildings, strip, origin: np.ndarray,
                        u: np.ndarray, width: float, min_width: float, lo: float,
                        hi: float) -> np.ndarray:
    """Cut positions along a strip's street (``origin + t u``) moved off the buildings.

    A cut across the strip at ``t`` crosses a building whose part in the strip spans ``t``
    along ``u``; such a cut moves to the nearest end of a building that lies in no
    building (:data:`BUILDING_CLEARANCE` clear of a free end; on the shared wall of two
    buildings that touch, as a party wall carries a parcel line), by at most
    :data:`MAX_BUILDING_SHIFT` of a lot width and never leaving a lot narrower than
    ``min_width`` (or the strip's ends closer than that): else it stays.
    """
    inside = shapely.intersection(np.asarray(buildings, dtype=object), strip)
    inside = inside[shapely.area(inside) > 1.0]
    if len(inside) == 0:
        return cuts
    spans = np.array([[t.min(), t.max()] for t in
                      ((shapely.get_coordinates(g) - origin) @ u for g in inside)])
    wall = 0.05    # m: a cut this close to a wall runs along it

    def free(t):
        return not ((spans[:, 0] + wall < t) & (t < spans[:, 1] - wall)).any()

    ends = np.r_[spans[:, 0], spans[:, 1]]
    # at a wall no other building touches the cut keeps clear of it; on a party wall it
    # runs along the wall
    candidates = np.unique(np.r_[ends, spans[:, 0] - BUILDING_CLEARANCE,
                                 spans[:, 1] + BUILDING_CLEARANCE])
    candidates = np.array([t for t in candidates if free(t)])
    out = np.array(cuts, dtype=float)
    for j, t in enumerate(out):
        if free(t) or not len(candidates):
            continue
        prev = out[j - 1] if j > 0 else lo
        nxt = out[j + 1] if j + 1 < len(out) else hi
        for new in candidates[np.argsort(np.abs(candidates - t), kind="stable")]:
            if abs(new - t) > MAX_BUILDING_SHIFT * width:
                break
            if new - prev >= min_width and nxt - new >= min_width:
                out[j] = new
                break
    return out


def _cut_strip(strip, side: _Side, settings: SubdivisionSettings,
               rng: np.random.Generator) -> np.ndarray:
    """Cut a strip across its street into lots about ``lot_width`` wide.

    Cuts are perpendicular to the side's chord (sides are nearly straight, see
    :data:`MAX_SIDE_TURN`); their number is the strip's frontage on its side over
    ``lot_width``, raised
    so that no lot exceeds ``max_area`` but capped so that no lot is narrower than
    ``min_width``; ``irregularity`` moves each cut by up to :data:`MAX_FRONT_SHIFT` of a
    lot width (less where that would leave a lot under ``min_width``), and a cut near a bend of the street moves onto the bend (up to
    :data:`BEND_SNAP` of a lot width), so that lot fronts are straight. The first and last
    lots reach to the strip's ends (corner lots).
    """
    p0, p1 = side.coords[0], side.coords[-1]
    chord = p1 - p0
    length = float(np.hypot(*chord))
    if length <= 0:
        return _polygon_parts([strip])
    u = chord / length
    nrm = np.array([-u[1], u[0]])
    coords = shapely.get_coordinates(strip) - p0
    pu, pn = coords @ u, coords @ nrm
    # the strip's own frontage: where a neighbour took a corner region (a pinwheel), the
    # strip fronts only part of its side
    front = shapely.get_coordinates(shapely.intersection(
        shapely.boundary(strip), shapely.buffer(side.line, _TOUCH, quad_segs=1))) - p0
    lo, hi = ((front @ u).min(), (front @ u).max()) if len(front) else (pu.min(), pu.max())
    length = float(hi - lo)
    if length <= 0:
        return _polygon_parts([strip])
    count = max(1, round(length / settings.lot_width),
                math.ceil(shapely.area(strip) / settings.max_area))
    if settings.min_width > 0:
        count = max(1, min(count, int(length // settings.min_width)))
    width = length / count
    inner = lo + width * np.arange(1, count)
    # jitter, but never so much that two cuts leave a lot under the minimum width
    shift = min(settings.irregularity * MAX_FRONT_SHIFT * width,
                max(0.0, 0.5 * (width - settings.min_width)))
    inner = inner + shift * rng.uniform(-1, 1, count - 1)
    # a cut near a bend of the street moves onto the bend: the lots' fronts stay straight
    # (a 160° vertex is a corner of Yang's p_angle, and a kink in a real parcel front)
    vertices = side.coords[1:-1]
    if len(vertices) and count > 1:
        d_in = vertices - side.coords[:-2]
        d_out = side.coords[2:] - vertices
        cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
        bend = np.abs(np.degrees(np.arctan2(cross, np.einsum("ij,ij->i", d_in, d_out)))) > 3.0
        for at in (vertices[bend] - p0) @ u:
            j = int(np.argmin(np.abs(inner - at)))
            if abs(inner[j] - at) < BEND_SNAP * width:
                inner[j] = at
        inner = np.sort(inner)
    whole = settings.options.get("keep_whole") if settings.options else None
    if whole is not None and len(whole) and count > 1:
        inner = _cuts_off_buildings(inner, whole, strip, p0, u, width, settings.min_width,
                                    lo, hi)
    margin = 1.0 + (pu.max() - pu.min()) + (pn.max() - pn.min())
    cuts = np.concatenate([[min(pu.min(), 0.0) - margin], inner,
                           [max(pu.max(), length) + margin]])
    a = np.column_stack([cuts[:-1], cuts[1:], cuts[1:], cuts[:-1], cuts[:-1]])
    b = np.tile([pn.min() - margin, pn.min() - margin, pn.max() + margin,
                 pn.max() + margin, pn.min() - margin], (count, 1))
    xy = p0 + a[:, :, None] * u + b[:, :, None] * nrm
    return _polygon_parts(shapely.intersection(strip, shapely.polygons(xy), grid_size=_GRID))


@_quiet
def split_skeleton(block, settings: SubdivisionSettings,
                   rng: np.random.Generator) -> np.ndarray:
    """Skeleton subdivision of one block (Vanegas et al. 2012; CityEngine's "Skeleton").

    1. The block outline is split into street sides (:func:`street_sides`: runs of nearly
       collinear edges, the merged faces of collinear edges).
    2. Each side gets its face, the region of the block closest to it
       (:func:`edge_faces`; the straight skeleton's faces for a convex block): Vanegas's
       alpha-strips.
    3. At near-right corners the corner region goes to the longer side's strip, so that
       corner lots are rectangular and face two streets (beta-strips).
    4. Each strip is cut across its street every ``lot_width`` (jittered), so every lot
       has frontage on the strip's street.
    5. Lots smaller than ``min_area``, narrower than ``min_width`` (wedges where a strip
       ends at a skewed corner) or without ``min_frontage`` on a street merge into the
       neighbour sharing most boundary.

    Parameters
    ----------
    block : Polygon
        A shrunk block part, whose whole outline is street.
    settings : SubdivisionSettings
    rng : numpy Generator

    Returns
    -------
    ndarray of Polygon
        The lots: valid, inside the block, not overlapping, covering it, each with street
        frontage (unless the block is a single lot).

    Examples
    --------
    >>> import numpy as np, shapely
    >>> lots = split_skeleton(shapely.box(0, 0, 108, 40),
    ...                       SubdivisionSettings(irregularity=0), np.random.default_rng(0))
    >>> len(lots), round(float(shapely.area(lots).sum()), 3)
    (12, 4320.0)
    """
    block = _snap(block)  # a no-op for blocks of shrink_blocks
    if shapely.get_type_id(block) != 3:
        # snapping pinched a neck thinner than the grid: each part is a block of its own
        parts = _polygon_parts([block])
        return np.concatenate([split_skeleton(p, settings, rng) for p in parts]) \
            if len(parts) else np.empty(0, dtype=object)
    sides = street_sides(block)
    if len(sides) < 2:
        return _polygon_parts([block])
    faces = _swap_corners(block, sides, edge_faces(block, sides))
    no_street = (settings.options or {}).get("no_street")
    if no_street is not None:
        sides, faces = _street_sides_only(block, sides, faces, no_street)
        if not sides:
            return _polygon_parts([block])
    strips, side_of = _strip_parts(sides, faces)
    lots = [_cut_strip(strip, sides[k], settings, rng) for strip, k in zip(strips, side_of)]
    lots = np.concatenate(lots) if lots else np.empty(0, dtype=object)
    if len(lots) == 0:
        return _polygon_parts([block])
    return merge_unfit_lots(lots, block, settings)


# --------------------------------------------------------------------------- registry entries

register_method(Method(
    "recursive", "Recursive (split the long axis until under the maximum area)",
    split_recursive, street_access=False,
    reference="Scharl 2010, ch. 4.2.6; Weber et al. 2009; CityEngine 'Recursive'"))
register_method(Method(
    "skeleton", "Skeleton (strips along each street, every lot with frontage)",
    split_skeleton, street_access=True,
    reference="Vanegas et al. 2012; CityEngine 'Skeleton'"))


# --------------------------------------------------------------------------- main API

@dataclass
class Subdivision:
    """Result of :func:`subdivide_blocks`.

    Attributes
    ----------
    geometry : ndarray of Polygon
        The lots (metric CRS of the input).
    table : DataFrame
        One row per lot, the columns of :data:`PARCEL_FIELDS`.
    blocks : ndarray of Polygon / MultiPolygon
        The shrunk blocks, one per input block (possibly empty): the lots of a block cover it.
    stats : dict
        ``n_blocks``, ``n_empty_blocks`` (nothing left after shrinking), ``n_thin_blocks``
        (blocks with land nowhere ``min_width`` wide, which gets no lot), ``n_lots``,
        ``n_over_max_area`` (lots no acceptable cut could split), ``n_without_access``,
        ``n_merged_for_access``, ``n_under_min_width`` (lots narrower than ``min_width``:
        on a thin arm of land that is wider elsewhere), ``n_sized_by_block`` (blocks with their own
        parcel area), ``n_undesirable``.
    """

    geometry: np.ndarray
    table: pd.DataFrame
    blocks: np.ndarray
    stats: dict = field(default_factory=dict)


def _as_polygons(blocks) -> np.ndarray:
    blocks = np.asarray(blocks, dtype=object).ravel()
    present = ~(shapely.is_missing(blocks) | shapely.is_empty(blocks))
    if not present.any():
        raise InputError("no blocks to subdivide")
    dims = np.full(len(blocks), -1)
    dims[present] = shapely.get_dimensions(blocks[present])
    if not (dims[present] == 2).all():
        raise InputError("blocks must be polygons")
    out = blocks.copy()
    invalid = present & ~shapely.is_valid(np.where(present, blocks, None))
    if invalid.any():  # repair, keeping the polygon parts
        out[invalid] = [shapely.union_all(_polygon_parts([g])) for g in
                        shapely.make_valid(blocks[invalid])]
    out[~present] = shapely.Polygon()
    # one way round: a shapefile stores outer rings clockwise, GEOS and GeoPackage keep
    # them counter-clockwise, and the lots were laid out from the way the outline runs
    # (Helsinki's blocks: 762 parcels from a shapefile, 761 from memory)
    return counter_clockwise(out)


def _block_settings(settings: SubdivisionSettings, n: int, parcel_area,
                    parcel_area_sd) -> list:
    """Per block: the settings with the block's own parcel size in ``options`` (or None)."""
    if parcel_area is None:
        return [None] * n
    mean = np.asarray(parcel_area, dtype=float).ravel()
    sd = np.full(n, np.nan) if parcel_area_sd is None else \
        np.asarray(parcel_area_sd, dtype=float).ravel()
    if len(mean) != n or len(sd) != n:
        raise InputError(f"{len(mean)} parcel areas for {n} blocks")
    given = np.isfinite(mean)
    if (mean[given] <= 0).any():
        raise InputError(f"{int((mean[given] <= 0).sum())} blocks have a parcel area that "
                         "is not positive")
    if (sd[np.isfinite(sd)] < 0).any():
        raise InputError("a parcel area standard deviation is negative")
    out = []
    base = {k: v for k, v in dict(settings.options or {}).items()
            if k not in ("parcel_areas", "mean_area", "area_sd")}
    for a, s in zip(mean, sd):
        if not math.isfinite(a):
            out.append(None)
            continue
        options = dict(base, mean_area=float(a),
                       area_sd=float(s) if math.isfinite(s) else
                       settings.irregularity * 0.5 * float(a))
        out.append(replace(settings, options=options))
    return out


def merge_lots_under_buildings(lots, buildings, max_group_area: float = np.inf):
    """Lots that one building stands on (over 1 m² of it on each) merge into one, so that
    the building stands on one parcel; buildings in a row across lots merge them all, up
    to ``max_group_area``: a building whose merge would make a larger parcel than that
    (and than its own lots together) stays across its lots. Buildings are taken largest
    first. Returns (lots, number of lots merged away, per output lot whether it was
    merged). A group whose union is not one polygon (lots meeting only under a building's
    corner) stays apart.
    """
    lots = np.asarray(lots, dtype=object)
    buildings = np.asarray(buildings, dtype=object)
    none = (lots, 0, np.zeros(len(lots), dtype=bool))
    b, k = shapely.STRtree(lots).query(buildings, predicate="intersects")
    if len(b) == 0:
        return none
    on = shapely.area(shapely.intersection(buildings[b], lots[k]))
    b, k = b[on > 1.0], k[on > 1.0]
    if len(b) == 0:
        return none
    # union-find over the lots, building by building, largest first, within the size limit
    parent = np.arange(len(lots))
    area = shapely.area(lots)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for building in np.unique(b)[np.argsort(-shapely.area(buildings[np.unique(b)]),
                                            kind="stable")]:
        groups = {root(i) for i in k[b == building]}
        if len(groups) < 2:
            continue
        total = sum(area[g] for g in groups)
        own = area[k[b == building]].sum()
        if total > max(max_group_area, own) * (1 + 1e-9):   # (sums in another order)
            continue
        first, *rest = sorted(groups)
        for g in rest:
            parent[g] = first
        area[first] = total
    label = np.array([root(i) for i in range(len(lots))])
    out, merged, n_away = [], [], 0
    for group in np.unique(label):
        members = np.flatnonzero(label == group)
        union = _clean_union(lots[members]) if len(members) > 1 else lots[members[0]]
        if len(members) > 1 and shapely.get_type_id(union) == 3:
            out.append(union)
            merged.append(True)
            n_away += len(members) - 1
        else:
            out.extend(lots[members])
            merged.extend([False] * len(members))
    return np.array(out, dtype=object), n_away, np.array(merged, dtype=bool)


def _on_lots(buildings, lots):
    """Per building: its area on lots, and on the lot holding most of it."""
    buildings = np.asarray(buildings, dtype=object)
    best = np.zeros(len(buildings))
    total = np.zeros(len(buildings))
    if len(buildings) and len(lots):
        b, k = shapely.STRtree(lots).query(buildings, predicate="intersects")
        on = shapely.area(shapely.intersection(buildings[b], lots[k]))
        np.maximum.at(best, b, on)
        np.add.at(total, b, on)
    return total, best


def _on_parcels(buildings, lots, share: float = 0.95):
    """Per building: whether it stands on parcel land (half of it or more on lots, not
    outside the blocks or on land kept clear), and whether it is split there (no single
    lot holds ``share`` of its area: a parcel line runs through it)."""
    total, best = _on_lots(buildings, lots)
    area = shapely.area(buildings)
    on_land = total >= 0.5 * area
    return on_land, on_land & (best < share * area)


def on_parcel_land(buildings, lots) -> np.ndarray:
    """Per building: True where half of it or more stands on lots (:func:`_on_parcels`)."""
    return _on_parcels(buildings, lots)[0]


def split_buildings(buildings, lots, share: float = 0.95) -> np.ndarray:
    """Per building: True where it stands on parcel land and a parcel line runs through it
    (:func:`_on_parcels`)."""
    return _on_parcels(buildings, lots, share)[1]


@_quiet
def subdivide_blocks(blocks, method: str = "recursive",
                     settings: Optional[SubdivisionSettings] = None, seed: int = 0,
                     block_ids: Optional[Sequence[int]] = None,
                     street_width: float = DEFAULT_STREET_WIDTH, roads=None,
                     road_widths=None, parcel_area=None, parcel_area_sd=None,
                     keep_clear=None, keep_whole=None, boundary=None,
                     progress: Optional[Progress] = None) -> Subdivision:
    """Shrink blocks by their streets and subdivide them into lots (Scharl 4.2.6).

    Parameters
    ----------
    blocks : array of Polygon / MultiPolygon (metric CRS)
        Blocks outlined by street centrelines (e.g. :func:`blocks.extract_blocks`); each
        part of a multipolygon is subdivided on its own. A hole is land kept free (a pond,
        a park): it keeps no street width and gives no frontage.
    method : str
        A name of :data:`METHODS` ('recursive', 'skeleton').
    settings : SubdivisionSettings, optional
    seed : int >= 0
        A block uses ``numpy.random.default_rng([seed, *place_key(block)])``: the same seed
        gives the same lots, and a block's lots depend neither on the other blocks nor on
        its position among them (a selection, a layer in another order).
    block_ids : int sequence, optional
        The ``block_id`` of each block (default 1..n).
    street_width : float
        Full street width (m) of every street, or of the roads without their own width.
    roads : array of LineString, optional
        The street centrelines the blocks came from; with them the blocks are shrunk
        street by street (and dead-end streets inside blocks are cut out).
    road_widths : float array, optional
        Full width (m) of each road of ``roads``; NaN = ``street_width``.
    parcel_area, parcel_area_sd : float arrays, optional
        Per block: the mean parcel area (m²) and its standard deviation, Aliaga et al.'s
        a(v) and sigma_b of the points around the block (e.g. the ``parcel_area`` of the
        blocks of 'synthesizeroadsrandomwalk'); NaN = the settings' size. They reach the
        method as ``options['mean_area']`` / ``['area_sd']`` (used by ``voronoi-obb``; the
        other methods size lots by ``max_area`` / ``lot_width``).
    keep_clear : array of Polygon, optional
        Areas no lot may take (street surfaces, junctions): see :func:`shrink_blocks`.
    keep_whole : array of Polygon, optional
        Buildings each to stand on one lot: the skeleton's cuts move off them
        (:func:`_cuts_off_buildings`), and with any method the lots a building still stands
        on merge (:func:`merge_lots_under_buildings`).
    boundary : Polygon / MultiPolygon, optional
        The district's outline (e.g. the BOUNDARY of :func:`blocks.extract_blocks`): block
        edges on it are no street. They keep no street width, give no frontage and get
        no strip of their own (:func:`_street_sides_only`); like a hole's edges.
    progress : Progress, optional
        Stepped once per block (cancellation raises :class:`progress.Canceled`).

    Returns
    -------
    Subdivision

    Raises
    ------
    InputError
        Unknown method, no polygon blocks, absurd settings, negative widths or seed.

    References
    ----------
    Scharl 2010, ch. 4.2.6; Vanegas et al. 2012; Yang et al. 2013, sec. 7.

    Examples
    --------
    >>> import shapely
    >>> result = subdivide_blocks([shapely.box(0, 0, 112, 52)], "recursive",
    ...                           SubdivisionSettings(max_area=500, irregularity=0))
    >>> len(result.geometry), result.table.area_m2.round(3).unique().tolist()
    (8, [500.0])
    >>> bool(result.table.has_street_access.all()), result.table.method.iloc[0]
    (True, 'recursive')
    """
    progress = ensure(progress)
    if method not in METHODS:
        raise InputError(f"unknown subdivision method {method!r} "
                         f"(known: {', '.join(method_names())})")
    spec = METHODS[method]
    settings = (settings if settings is not None else SubdivisionSettings()).validate()
    if seed is None or int(seed) != seed or seed < 0:
        raise InputError(f"the seed must be a whole number >= 0 (got {seed})")
    if not (math.isfinite(street_width) and street_width >= 0):
        raise InputError(f"the street width must not be negative (got {street_width:g})")
    blocks = _as_polygons(blocks)
    n = len(blocks)
    ids = np.arange(1, n + 1) if block_ids is None else np.asarray(block_ids, dtype=np.int64)
    if len(ids) != n:
        raise InputError(f"{len(ids)} block ids for {n} blocks")
    road_hw = None
    if roads is not None and road_widths is not None:
        w = np.asarray(road_widths, dtype=float)
        w = np.where(np.isfinite(w), w, street_width)
        if (w < 0).any():
            raise InputError(f"{int((w < 0).sum())} roads have a negative street width")
        road_hw = w / 2.0
    outside = None
    if boundary is not None:
        area = shapely.union_all(np.atleast_1d(np.asarray(boundary, dtype=object)))
        widest = max([street_width, *([] if road_hw is None else 2 * road_hw)])
        outside = outside_land(blocks, area, widest + 1.0)
    # with buildings to keep whole, a piece of land under the minimum area stays if a
    # building stands on it (it gets a parcel of its own, not none)
    shrunk = shrink_blocks(blocks, street_width / 2.0, roads, road_hw,
                           min_area=settings.min_area if keep_whole is None else 0.0,
                           keep_clear=keep_clear, outside=outside)
    # land nowhere min_width wide gets no lot, whatever stands on it: a strip left between
    # two wide streets, a roundabout's island (core.geometry.too_thin, the one rule)
    shrunk, thin = _without_thin_land(shrunk, settings.min_width, settings.min_area)
    block_settings = _block_settings(settings, n, parcel_area, parcel_area_sd)
    n_sized = sum(b is not None for b in block_settings)
    whole = None
    if keep_whole is not None:
        whole = shapely.force_2d(np.asarray(keep_whole, dtype=object).ravel())
        whole = whole[~(shapely.is_missing(whole) | shapely.is_empty(whole))]
        b_idx, w_idx = shapely.STRtree(whole).query(blocks, predicate="intersects") \
            if len(whole) else (np.zeros(0, np.int64), np.zeros(0, np.int64))
        for i in np.unique(b_idx):
            own = block_settings[i] or settings
            block_settings[i] = replace(own, options=dict(own.options or {},
                                                          keep_whole=whole[w_idx[b_idx == i]]))
    progress.step(0.05)

    lots: List[np.ndarray] = []
    owner: List[np.ndarray] = []
    frontage: List[np.ndarray] = []
    n_merged = n_merged_for_buildings = n_merged_over_max = 0
    fix_access = spec.street_access or settings.force_street_access
    # land kept free (holes) and land outside the boundary: no frontage on its edge
    no_street = _holes(blocks) if outside is None else \
        shapely.union(_holes(blocks), outside)
    empty_no_street = shapely.is_empty(no_street)
    for i in np.flatnonzero(~empty_no_street):   # no skeleton strip along it either
        own = block_settings[i] or settings
        block_settings[i] = replace(own, options=dict(
            own.options or {}, no_street=_no_street_zone(no_street[i])))
    for i in range(n):
        progress.step(0.05 + 0.9 * i / n)
        rng = np.random.default_rng([int(seed), *place_key(blocks[i])])
        own = block_settings[i].options.get("keep_whole") if block_settings[i] else None
        parts = _polygon_parts([shrunk[i]])
        if keep_whole is not None:
            small = shapely.area(parts) <= max(settings.min_area, _CRUMB)
            if small.any():
                held = np.zeros(len(parts), dtype=bool)
                if own is not None and len(own):
                    p_idx, w_idx = shapely.STRtree(own).query(parts, predicate="intersects")
                    on = shapely.area(shapely.intersection(parts[p_idx], own[w_idx])) > 1.0
                    held[p_idx[on]] = True
                parts = parts[~small | held]
                shrunk[i] = one_areal(parts)
        for part in parts:
            zone = _street_zone(part, no_street[i])
            got = _polygon_parts(spec.subdivide(part, block_settings[i] or settings, rng))
            leaks = shapely.area(shapely.difference(got, part)) > _CRUMB
            if leaks.any():
                # a lot drawn over a thin notch of the land (a street surface reaching in at
                # a sliver's angle: the skeleton's strips do not follow it) is cut back to it
                got = np.concatenate([got[~leaks], _polygon_parts(
                    shapely.intersection(got[leaks], part))])
            if own is not None and len(got) > 1:
                got, n_away, merged = merge_lots_under_buildings(
                    got, own, MERGE_LIMIT * settings.max_area)
                n_merged_for_buildings += n_away
                n_merged_over_max += int((merged & (shapely.area(got) > settings.max_area
                                                    * (1 + 1e-6))).sum())
            front = _frontage(got, zone)
            no_access = front < settings.min_frontage
            if fix_access and no_access.any() and len(got) > 1:
                got = _polygon_parts(merge_into_neighbours(got, no_access)[0])
                n_merged += int(no_access.sum())
                front = _frontage(got, zone)
            lots.append(got)
            owner.append(np.full(len(got), i))
            frontage.append(front)
    progress.step(0.95)
    geometry = np.concatenate(lots) if lots else np.empty(0, dtype=object)
    owner = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
    front = np.concatenate(frontage) if frontage else np.zeros(0)
    p_angle, p_area, bad = lot_quality(geometry)
    area = shapely.area(geometry)
    _, lot_width, _ = minimum_rectangles(geometry)
    table = pd.DataFrame({
        "parcel_id": np.arange(1, len(geometry) + 1, dtype=np.int64),
        "block_id": ids[owner] if len(owner) else np.zeros(0, dtype=np.int64),
        "area_m2": area, "frontage_m": front,
        "has_street_access": front >= settings.min_frontage,
        "p_angle": p_angle, "p_area": p_area, "undesirable": bad,
        "method": np.full(len(geometry), method, dtype=object),
    })
    empty = shapely.is_empty(shrunk)
    stats = {
        "n_blocks": n, "n_empty_blocks": int(empty.sum()), "n_thin_blocks": int(thin.sum()),
        "n_lots": len(geometry),
        "n_over_max_area": int((area > settings.max_area * (1 + 1e-6)).sum()),
        "n_without_access": int((~table.has_street_access).sum()),
        "n_merged_for_access": n_merged,
        "n_under_min_width": int((lot_width < settings.min_width).sum()),
        "n_sized_by_block": n_sized,
        "n_undesirable": int(bad.sum()),
    }
    if outside is not None:
        stats["n_blocks_on_boundary"] = int((~shapely.is_empty(outside)).sum())
    if whole is not None:
        stats["n_buildings"] = len(whole)
        on_land, split = _on_parcels(whole, geometry)
        stats["n_buildings_on_lots"] = int(on_land.sum())
        stats["n_buildings_split"] = int(split.sum())
        stats["n_merged_for_buildings"] = n_merged_for_buildings
        stats["n_over_max_area_merged"] = n_merged_over_max
    progress.step(1.0)
    return Subdivision(geometry, table, shrunk, stats)


def summary(stats: Mapping, method: str) -> List[str]:
    """The log lines of a subdivision's ``stats`` (:class:`Subdivision`): what was made and
    each count of lots that are not as asked (over the maximum area, without access, ...).

    >>> summary({"n_lots": 2, "n_blocks": 1, "n_over_max_area": 0, "n_undesirable": 1},
    ...         "skeleton")[0]
    '2 parcels (skeleton) in 1 block.'
    """
    n = stats.get
    lines = [f"{counted(n('n_lots'), 'parcel')} ({method}) in "
             f"{counted(n('n_blocks'), 'block')}."]
    over = n("n_over_max_area") - n("n_over_max_area_merged", 0)
    for count, one, many, text in (
            (n("n_empty_blocks"), "block is", "blocks are", "narrower than their streets "
             "(or smaller than the minimum area after shrinking) and get no parcel."),
            (n("n_thin_blocks"), "block has", "blocks have", "land nowhere the minimum "
             "width wide after shrinking (a strip, a roundabout's island): no parcel there."),
            (over, "parcel stays", "parcels stay", "larger than the maximum area: land "
             "without frontage merged into it, or no cut left pieces big, wide, on a street."),
            (n("n_over_max_area_merged"), "parcel is", "parcels are", "larger than the "
             "maximum area because lots merged so that a building stands on one parcel."),
            (n("n_without_access"), "parcel has", "parcels have", "no street frontage."),
            (n("n_under_min_width"), "parcel is", "parcels are", "narrower than the minimum "
             "width: a thin arm of their block part."),
            (n("n_merged_for_access"), "lot", "lots", "without frontage merged into others."),
            (n("n_merged_for_buildings"), "lot", "lots", "merged into a neighbour so "
             "that a building stands on one parcel."),
            (n("n_blocks_on_boundary"), "block lies", "blocks lie", "on the boundary: its "
             "edges there are no street (no street width, no strip, no frontage).")):
        if count and count > 0:
            lines.append(f"{counted(count, one, many)} {text}")
    if n("n_buildings"):
        on_lots, split = n("n_buildings_on_lots"), n("n_buildings_split")
        lines.append(
            f"{split} of the {counted(on_lots, 'building')} on parcel land "
            f"{'is' if split == 1 else 'are'} crossed by a parcel line (no parcel holds "
            "95 % of it): on the line between two streets' strips, or in a row longer "
            f"than a merged parcel may be ({n('n_buildings') - on_lots} of the "
            f"{counted(n('n_buildings'), 'building')} "
            f"{'stands' if n('n_buildings') - on_lots == 1 else 'stand'} mostly outside "
            "the parcels).")
    lines.append(f"{counted(n('n_undesirable'), 'parcel is', 'parcels are')} undesirable "
                 "by Yang's criteria (p_angle > 15° or p_area > 1.2).")
    return lines
