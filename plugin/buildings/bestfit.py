"""Best-fitting library buildings on parcels (Scharl 2010, ch. 6).

Scharl assigns pre-modelled buildings to parcels: "the building with the largest
footprint that meets all the criteria" (ch. 6.2). Each library building has *street
access sides* (a door: must face a street) and *inaccessible* (blind) sides (a plain
wall: must not face a street); "a side faces a street if it is nearly parallel (± 30°)
and a ray cast perpendicular from its center directly hits a street". Per parcel the
library, sorted by footprint area from largest to smallest, is enumerated:

- buildings larger than the parcel, or with more access sides than the parcel has street
  sides, are skipped (constraints 1 and 2);
- the footprint is centred on the parcel and its largest access side aligned with the
  parcel's longest street side (step 2); if that fails, the other alignments of an
  access side with a street side are tried (step 3, "rotate until ...");
- it is moved as close as possible to the street, keeping ``min_setback`` from the
  parcel's street sides (step 4): the translations that keep every vertex of the rotated
  footprint inside the parcel minus the setback zone are the intersection of that region
  shifted by each vertex (a Minkowski difference), and the one furthest towards the
  street, nearest to the centre of the street side, is taken;
- a road centreline that runs through the parcel or beside it (a dead-end street the
  parcel covers, a road along a side that does not count as a street side) is a street
  side too for the setback: the translations that bring the footprint's convex hull
  within ``min_setback`` of it (the Minkowski sum of each road segment with the mirrored
  hull, buffered by the setback) are removed, so no building crosses a road centreline
  or comes closer to it than the setback; a parcel left without room for any building
  that way stays empty and is counted (``crossed_by_road``);
- the footprint must lie inside the parcel (step 5) and satisfy the side constraints;
  the first building that passes is placed (step 6), else the parcel stays empty.

On terrain (a DEM given), Scharl ch. 6.2: "If the parcel is located on a slope, the
building is moved down so that every vertex is on the ground or beneath. If the slope of
the gradient of the parcel exceeds a user defined threshold ``maxParcelSlope``, the
parcel is discarded and no building is assigned." The parcel's slope is the gradient of
the least-squares plane through DEM samples over the parcel (a 2 m grid, at least 25
points); the building's base is the lowest terrain height under its footprint's vertices
(``base_z``), so no corner floats; ``sunk_m`` is how far its highest corner's ground lies
above the base (the depth the building is sunk into the slope there).

Library sides are edge indices of the footprint's exterior ring as stored (edge ``i``
runs from vertex ``i`` to vertex ``i + 1``). The placement is
``translate(rotate(footprint, rotation, origin=centroid), offset_x, offset_y)``.

Nothing here imports QGIS; geometry is in a metric CRS.

References
----------
Scharl, A. (2010). Artist-controlled urban modeling (thesis), ch. 6 "A Constraint Based
    System to Populate Cities with Buildings", Fig. 6.3.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
import shapely.ops

from ..core import coordinates
from ..core.progress import InputError, Progress, ensure

__all__ = ["LibraryBuilding", "BestFit", "PLACEMENT_FIELDS", "SIDE_FIELDS", "MAX_ANGLE",
           "DEFAULT_MAX_PARCEL_SLOPE", "parcel_slopes", "parse_sides",
           "library_from_table", "library_fields", "default_library", "side_normals",
           "fit_buildings"]

#: Scharl's maximum deviation from parallel for a side to face a street (degrees).
MAX_ANGLE = 30.0
#: Default reach (m) of the perpendicular ray from a side to a street centreline: the
#: setback plus half a street.
DEFAULT_REACH = 20.0
DEFAULT_SETBACK = 1.0
#: Output fields of a placement.
PLACEMENT_FIELDS = [("parcel_id", "int"), ("source_id", "int"), ("rotation", "float"),
                    ("offset_x", "float"), ("offset_y", "float"), ("area_m2", "float"),
                    ("parcel_share", "float"), ("base_z", "float"),
                    ("parcel_slope_pct", "float"), ("sunk_m", "float")]
#: A library building's side lists (comma-separated edge indices): text in any output.
SIDE_FIELDS = ("street_access_sides", "blind_sides")
#: Default steepest parcel (rise over run) that still gets a building, with a DEM.
DEFAULT_MAX_PARCEL_SLOPE = 0.25


@dataclass
class LibraryBuilding:
    """One library footprint (metric units, any position) with its side constraints."""

    footprint: shapely.Polygon
    access: Tuple[int, ...] = ()
    blind: Tuple[int, ...] = ()
    source_id: int = 0
    attributes: Dict = field(default_factory=dict)

    @property
    def area(self) -> float:
        return float(self.footprint.area)

    @property
    def n_edges(self) -> int:
        return len(self.footprint.exterior.coords) - 1


@dataclass
class BestFit:
    """Result of :func:`fit_buildings`: placed footprints, a table and statistics."""

    geometry: np.ndarray
    table: pd.DataFrame
    stats: Dict[str, float]


def parse_sides(value, n_edges: int, what: str) -> Tuple[int, ...]:
    """'0, 2' -> (0, 2); empty -> (); indices outside 0..n_edges-1 raise InputError."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ()
    if isinstance(value, (int, np.integer)):
        items = [str(int(value))]
    else:
        items = [t for t in str(value).replace(";", ",").replace(" ", ",").split(",") if t]
    out = []
    for t in items:
        try:
            i = int(float(t))
        except ValueError:
            raise InputError(f"{what}: '{value}' is not a list of edge indices") from None
        if not 0 <= i < n_edges:
            raise InputError(f"{what}: edge {i} does not exist (the footprint has edges "
                             f"0..{n_edges - 1})")
        out.append(i)
    return tuple(sorted(set(out)))


def library_from_table(geoms, access, blind, source_ids=None,
                       attributes: Optional[pd.DataFrame] = None) -> List[LibraryBuilding]:
    """Library buildings from footprints and their side lists (comma-separated edges)."""
    geoms = np.asarray(geoms, dtype=object)
    out = []
    for i, g in enumerate(geoms):
        sid = int(source_ids[i]) if source_ids is not None else i + 1
        what = f"library building {sid}"
        if shapely.get_type_id(g) == 6:
            parts = shapely.get_parts(g)
            if len(parts) != 1:
                raise InputError(f"{what} has {len(parts)} parts; one polygon is needed")
            g = parts[0]
        if shapely.get_type_id(g) != 3 or g.is_empty or not g.is_valid:
            raise InputError(f"{what} is not a valid polygon")
        g = shapely.Polygon(g.exterior)  # courtyards do not matter for the fit
        n = len(g.exterior.coords) - 1
        a = parse_sides(access[i], n, f"{what}, street access sides")
        b = parse_sides(blind[i], n, f"{what}, blind sides")
        if set(a) & set(b):
            raise InputError(f"{what}: edges {sorted(set(a) & set(b))} are both street access "
                             "and blind sides")
        attrs = {} if attributes is None else attributes.iloc[i].to_dict()
        # the sides as read ('0' from an integer field, '0;2'): one spelling in the output
        attrs.update(zip(SIDE_FIELDS, (",".join(map(str, a)), ",".join(map(str, b)))))
        out.append(LibraryBuilding(g, a, b, sid, attrs))
    if not out:
        raise InputError("the building library is empty")
    return out


def library_fields(library: Sequence[LibraryBuilding]) -> List[Tuple[str, str]]:
    """(name, type) of the library's own attributes as output fields, after
    :data:`PLACEMENT_FIELDS` (whose names, and 'fid', they cannot take). Each type holds
    over the whole library, not only over the buildings one run places, so the output's
    fields do not change with what fitted (and are there when nothing fitted); the side
    lists are text.

    >>> library_fields(default_library())[:3]
    [('name', 'str'), ('height_m', 'float'), ('levels', 'int')]
    >>> dict(library_fields(default_library()))["street_access_sides"]
    'str'
    """
    reserved = {name.lower() for name, _ in PLACEMENT_FIELDS} | {"fid"}
    names = dict.fromkeys(k for b in library for k in b.attributes)
    out = []
    for name in names:
        if str(name).lower() in reserved:
            continue
        values = [b.attributes.get(name) for b in library]
        values = [v for v in values if v is not None and not pd.isna(v)]
        out.append((name, "str" if name in SIDE_FIELDS else _value_kind(values)))
    return out


def _value_kind(values) -> str:
    """int / float / bool / str: the one field type that holds every value."""
    if not values:
        return "str"
    if all(isinstance(v, (bool, np.bool_)) for v in values):
        return "bool"
    if all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
           for v in values):
        return "int"
    if all(isinstance(v, (int, float, np.integer, np.floating))
           and not isinstance(v, (bool, np.bool_)) for v in values):
        return "float"
    return "str"


def _rect(w, d):
    return shapely.Polygon([(0, 0), (w, 0), (w, d), (0, d)])


def _l_shape(w, d, wing_w, wing_d):
    return shapely.Polygon([(0, 0), (w, 0), (w, d), (w - wing_w, d), (w - wing_w, wing_d),
                            (0, wing_d)])


#: The default library: (name, footprint, access edges, blind edges, height, levels, type,
#: roof). Edge 0 is the front (y = 0, facing -y) of every footprint; row and terraced
#: houses have blind party walls on their sides (edges 1 and 3), corner buildings two
#: fronts.
_DEFAULT = [
    ("detached house", _rect(10, 9), (0,), (), 7.0, 2, "residential", "gabled"),
    ("small house", _rect(8, 7), (0,), (), 5.5, 1, "residential", "gabled"),
    ("villa", _l_shape(16, 14, 7, 8), (0,), (), 8.0, 2, "residential", "hipped"),
    ("terraced house", _rect(7, 11), (0,), (1, 3), 9.0, 3, "residential", "gabled"),
    ("town house", _rect(12, 13), (0,), (1, 3), 15.0, 5, "residential", "gabled"),
    ("apartment block", _rect(30, 13), (0,), (), 18.0, 6, "residential", "flat"),
    ("large apartment block", _rect(48, 14), (0,), (), 24.0, 8, "residential", "flat"),
    ("corner block", _l_shape(26, 26, 13, 13), (0, 5), (), 21.0, 7, "residential", "flat"),
    ("office", _rect(36, 20), (0,), (), 27.0, 7, "commercial", "flat"),
    ("shop", _rect(14, 12), (0,), (), 4.5, 1, "commercial", "flat"),
    ("workshop", _rect(22, 16), (0,), (2,), 7.0, 1, "industrial", "gabled"),
    ("school", _l_shape(44, 34, 14, 14), (0,), (), 12.0, 3, "public", "hipped"),
]


def default_library() -> List[LibraryBuilding]:
    """Twelve simple buildings (houses, row houses, apartment and corner blocks, office,
    shop, workshop, school) with their access and blind sides; see :data:`_DEFAULT`."""
    out = []
    for i, (name, g, a, b, h, lv, t, r) in enumerate(_DEFAULT):
        out.append(LibraryBuilding(shapely.geometry.polygon.orient(g), a, b, i + 1, {
            "name": name, "height_m": h, "levels": lv, "building_type": t,
            "roof_shape": r, "street_access_sides": ",".join(map(str, a)),
            "blind_sides": ",".join(map(str, b))}))
    return out


# --------------------------------------------------------------------------- sides

def side_normals(ring_coords: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints, unit directions and unit outward normals of a closed ring's edges."""
    c = np.asarray(ring_coords, dtype=float)[:, :2]
    a, b = c[:-1], c[1:]
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(length, 1e-12)[:, None]
    # shoelace sign: counter-clockwise rings have the outside on the right of each edge
    ccw = np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]) > 0
    n = np.column_stack([u[:, 1], -u[:, 0]]) if ccw else np.column_stack([-u[:, 1], u[:, 0]])
    return (a + b) / 2.0, u, n


class _Streets:
    """Road centrelines with an STRtree for the perpendicular ray test."""

    def __init__(self, roads):
        self.lines = np.asarray(roads, dtype=object)
        self.tree = shapely.STRtree(self.lines)

    def near(self, parcel, clear: float) -> np.ndarray:
        """The road centrelines within ``clear`` of the parcel (through it, along its
        sides), clipped to a little more than that around it: single lines."""
        idx = self.tree.query(parcel, predicate="dwithin", distance=clear + 1e-3)
        if len(idx) == 0:
            return np.empty(0, dtype=object)
        parts = shapely.get_parts(shapely.intersection(
            self.lines[idx], shapely.buffer(parcel, clear + 0.1)))
        parts = shapely.get_parts(parts)  # lines and points of a geometry collection
        return parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0)]

    def faces(self, mids: np.ndarray, dirs: np.ndarray, normals: np.ndarray, reach: float,
              max_angle: float = MAX_ANGLE) -> np.ndarray:
        """Does each side face a street: the ray of length ``reach`` from its midpoint along
        its outward normal hits a road, and the road there is within ``max_angle`` of
        parallel to the side."""
        n = len(mids)
        out = np.zeros(n, dtype=bool)
        if n == 0 or len(self.lines) == 0:
            return out
        # from a millimetre inside the side: a road drawn on the side itself (a parcel or
        # block cut along the centre line) is hit at once; one outside would miss it
        start = mids - normals * 1e-3
        rays = shapely.linestrings(np.stack([start, mids + normals * reach], axis=1))
        ri, li = self.tree.query(rays, predicate="intersects")
        if len(ri) == 0:
            return out
        hits = shapely.intersection(rays[ri], self.lines[li])
        # the nearest hit of each ray decides: "directly hits a street"
        dist = shapely.distance(shapely.points(start[ri]), hits)
        order = np.lexsort((dist, ri))
        first = order[np.r_[True, ri[order][1:] != ri[order][:-1]]]
        r, line = ri[first], self.lines[li[first]]
        # the tangent of the road near the hit: two points 1 m apart along it
        hit_pt = shapely.points(start[r] + normals[r] * dist[first][:, None])
        at = shapely.line_locate_point(line, hit_pt)
        p0 = shapely.get_coordinates(shapely.line_interpolate_point(line, np.maximum(at - 1.0, 0)))
        p1 = shapely.get_coordinates(shapely.line_interpolate_point(
            line, np.minimum(at + 1.0, shapely.length(line))))
        t = p1 - p0
        t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
        cos = np.abs(np.sum(t * dirs[r], axis=1))
        out[r] = cos >= math.cos(math.radians(max_angle)) - 1e-9
        return out


# --------------------------------------------------------------------------- fitting

def _angle(v) -> float:
    return math.degrees(math.atan2(v[1], v[0]))


#: Segments of the buffers' round caps: a circumscribed polygon keeps the full distance.
_QUAD_SEGS = 8


def _buffer_at_least(geoms, distance: float, margin: float = 0.0):
    """Round buffers that keep ``distance`` everywhere (plus ``margin``): the polygon of a
    round buffer lies inside its circle, so the radius is widened to circumscribe it."""
    return shapely.buffer(geoms, distance / math.cos(math.pi / (4 * _QUAD_SEGS)) + margin,
                          quad_segs=_QUAD_SEGS)


def _road_blocked(lines, verts: np.ndarray, clear: float):
    """The reference-point positions at which a footprint whose convex hull has the
    vertices ``verts`` (relative to the reference point) comes within ``clear`` of one of
    the ``lines``: per segment ``ab`` the convex hull of ``a - verts`` and ``b - verts``
    (the Minkowski sum of the segment and the mirrored hull), buffered by ``clear``."""
    xy, which = shapely.get_coordinates(lines, return_index=True)
    same = which[1:] == which[:-1]
    a, b = xy[:-1][same], xy[1:][same]
    pts = np.concatenate([a[:, None, :] - verts[None], b[:, None, :] - verts[None]], axis=1)
    sums = shapely.convex_hull(shapely.multipoints(pts))
    return shapely.union_all(_buffer_at_least(sums, clear, 1e-6))


def _placements(allowed, street_sides, building: LibraryBuilding,
                rotations: Sequence[Tuple[float, int]], roads=None, clear: float = 0.0):
    """Yield (rotation, placed footprint, offset) for each candidate rotation (step 4);
    with ``roads`` (lines), none within ``clear`` of one."""
    centroid = building.footprint.centroid
    hull = np.asarray(building.footprint.convex_hull.exterior.coords)[:-1]
    for rot, side in rotations:
        origin = np.array([centroid.x, centroid.y])
        rotated_hull = coordinates.rotate([shapely.MultiPoint(hull)], np.radians(rot), origin)[0]
        verts = shapely.get_coordinates(rotated_hull) - origin
        # reference-point positions keeping every hull vertex inside the allowed region
        shifted = coordinates.translate(np.full(len(verts), allowed, dtype=object), -verts)
        with np.errstate(invalid="ignore"):  # empty pieces are expected here
            region = shapely.intersection_all(shifted)
        if region.is_empty:
            continue
        if roads is not None and len(roads):
            # off the roads through or beside the parcel: edges too, not only vertices
            region = region.difference(_road_blocked(roads, verts, clear))
            if region.is_empty:
                continue
        mid, _, normal = street_sides[side]
        # furthest towards the street, then nearest to the middle of the street side
        ring = shapely.get_coordinates(region)
        front = ring[np.argmax(ring @ normal)]
        tangent = np.array([normal[1], -normal[0]])
        span = 2.0 * (region.length + 1.0)
        band = region.intersection(shapely.Polygon(
            [front + normal + tangent * span, front + normal - tangent * span,
             front - normal * 0.05 - tangent * span, front - normal * 0.05 + tangent * span]))
        target = band if not band.is_empty else region
        p = shapely.ops.nearest_points(target, shapely.Point(mid))[0]
        offset = (p.x - centroid.x, p.y - centroid.y)
        placed = coordinates.translate(
            coordinates.rotate([building.footprint], np.radians(rot), origin), offset)[0]
        yield rot, placed, offset


def _rotations(building: LibraryBuilding, street_sides, parcel_lengths) -> List[Tuple[float, int]]:
    """Rotations aligning an access side's normal with a street side's normal, the largest
    access side with the longest street side first (Scharl step 2, then step 3)."""
    mids, dirs, normals = side_normals(np.asarray(building.footprint.exterior.coords))
    lengths = np.hypot(*(np.diff(np.asarray(building.footprint.exterior.coords)[:, :2],
                                 axis=0).T))
    fronts = list(building.access) or [i for i in np.argsort(-lengths)
                                       if i not in building.blind][:2]
    fronts = sorted(fronts, key=lambda i: -lengths[i])
    order = np.argsort(-parcel_lengths)
    out = []
    for i in fronts:
        for j in order:
            rot = _angle(street_sides[j][2]) - _angle(normals[i])
            if not any(abs((rot - r + 180) % 360 - 180) < 1e-6 and s == j for r, s in out):
                out.append((rot, int(j)))
    return out


def _best(allowed, parcel, sides, side_len, lib, lib_areas, streets, reach, max_angle,
          roads=None, clear: float = 0.0):
    """(building, rotation, footprint, offset) of the largest library building that fits
    the parcel (steps 1-6), clear of ``roads`` by ``clear``; None when none does."""
    area = parcel.area
    for b_i in np.flatnonzero(lib_areas <= area):
        b = lib[b_i]
        if len(b.access) > len(sides):  # constraint 2: not enough street sides
            continue
        for rot, g, off in _placements(allowed, sides, b, _rotations(b, sides, side_len),
                                       roads, clear):
            if not parcel.buffer(1e-6).contains(g):  # step 5
                continue
            if roads is not None and len(roads) and (
                    shapely.intersects(g, roads).any()
                    or shapely.distance(g, roads).min() < clear - 1e-6):
                continue  # the hull's clearance holds; a guard against rounding
            m, d, n = side_normals(np.asarray(g.exterior.coords))
            ok = streets.faces(m, d, n, reach, max_angle)
            if all(ok[list(b.access)]) and not any(ok[list(b.blind)]):
                return b, rot, g, off
    return None


def parcel_slopes(parcels, dem, spacing: float = 2.0) -> np.ndarray:
    """Slope (rise over run) of the least-squares plane through the DEM over each parcel.

    Samples lie on a grid of ``spacing`` metres (refined to at least 25 points inside
    small parcels); NaN where the DEM has no value over the parcel.
    """
    out = np.full(len(parcels), np.nan)
    for i, p in enumerate(parcels):
        if p is None or p.is_empty:
            continue
        x0, y0, x1, y1 = p.bounds
        step = min(spacing, max(x1 - x0, y1 - y0) / 5.0) or spacing
        xs, ys = np.meshgrid(np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step))
        pts = np.column_stack([xs.ravel(), ys.ravel()])
        pts = pts[shapely.contains_xy(p, pts[:, 0], pts[:, 1])]
        if len(pts) < 3:
            pts = shapely.get_coordinates(p.exterior)[:-1]
        z = dem(pts)
        ok = np.isfinite(z)
        if ok.sum() < 3:
            continue
        a = np.column_stack([pts[ok] - pts[ok].mean(0), np.ones(ok.sum())])
        coef, *_ = np.linalg.lstsq(a, z[ok], rcond=None)
        out[i] = float(np.hypot(coef[0], coef[1]))
    return out


def fit_buildings(parcels, roads, library: Sequence[LibraryBuilding],
                  parcel_ids: Optional[Sequence[int]] = None,
                  min_setback: float = DEFAULT_SETBACK, reach: float = DEFAULT_REACH,
                  max_angle: float = MAX_ANGLE, dem=None,
                  max_parcel_slope: float = DEFAULT_MAX_PARCEL_SLOPE,
                  progress: Optional[Progress] = None) -> BestFit:
    """Place the largest fitting library building on each parcel (Scharl ch. 6.2).

    Parameters
    ----------
    parcels : array of polygons (metric CRS)
    roads : array of lines: street centrelines
    library : LibraryBuilding sequence
    parcel_ids : int sequence, optional (default 1..n)
    min_setback : float
        Minimum distance (m) between the building and the parcel's street sides, and
        between the building and any road centreline through or beside the parcel (no
        building crosses a road centreline, even with no setback).
    reach : float
        Length (m) of the perpendicular ray of the facing test: a side faces a street when
        a road centreline lies within this distance in front of it.
    max_angle : float
        Maximum deviation (degrees) from parallel of a facing side (Scharl: 30).
    dem : callable (n, 2) -> (n,) heights, optional
        Terrain (a :class:`retrieval.shape_context.DemGrid`) in the parcels' CRS.
    max_parcel_slope : float
        With a DEM, parcels steeper than this (rise over run) get no building (Scharl's
        ``maxParcelSlope``).

    Returns
    -------
    BestFit
        ``geometry`` placed footprints (with a DEM: Polygon Z at ``base_z``); ``table``
        with :data:`PLACEMENT_FIELDS` and the library building's attributes; ``stats``
        with ``n_parcels``, ``n_placed``, ``empty_share``, ``no_street`` (parcels with no
        street side), ``too_steep`` (parcels over the slope limit), ``no_terrain`` (parcels,
        or the corners of the building chosen for them, where the DEM has no value: left
        empty, not guessed), ``crossed_by_road`` (parcels left empty because a road
        centreline runs through them, or along them: a building would fit without it, none
        fits clear of it), ``no_fit`` (the other empty parcels: facing a street, but no
        library building fits inside with the setback and the side rules).
    """
    progress = ensure(progress)
    parcels = np.asarray(parcels, dtype=object)
    if len(parcels) == 0:
        raise InputError("no parcels")
    if not len(library):
        raise InputError("the building library is empty")
    if roads is None or len(roads) == 0:
        raise InputError("no roads: the street sides of the parcels are unknown")
    for name, v, lo, hi in (("minimum setback", min_setback, 0, 1000), ("reach", reach, 0.1, 1000),
                            ("maximum angle", max_angle, 0, 90),
                            ("maximum parcel slope", max_parcel_slope, 0, 100)):
        if not (lo <= v <= hi):
            raise InputError(f"the {name} {v} is outside {lo}..{hi}")
    streets = _Streets(roads)
    ids = np.arange(1, len(parcels) + 1) if parcel_ids is None else np.asarray(parcel_ids)
    lib = sorted(library, key=lambda b: -b.area)
    lib_areas = np.array([b.area for b in lib])
    geoms, rows = [], []
    no_street = 0
    slopes = parcel_slopes(parcels, dem) if dem is not None else np.full(len(parcels), np.nan)
    too_steep = no_terrain = crossed_by_road = 0
    for pi, parcel in enumerate(parcels):
        if pi % 20 == 0:
            progress.step(pi / len(parcels))
        parts = shapely.get_parts(parcel)
        parcel = parts[np.argmax(shapely.area(parts))] if len(parts) else parcel
        if parcel.is_empty or shapely.get_type_id(parcel) != 3:
            continue
        if dem is not None and np.isnan(slopes[pi]):
            no_terrain += 1  # the DEM has no value over the parcel: its slope is unknown
            continue
        if dem is not None and not (slopes[pi] <= max_parcel_slope):
            too_steep += 1  # Scharl: a parcel over maxParcelSlope is discarded
            continue
        # sides of the parcel: simplified so that collinear pieces count as one side
        simple = shapely.geometry.polygon.orient(parcel.simplify(0.3), 1.0)
        ring = np.asarray(simple.exterior.coords)
        mids, dirs, normals = side_normals(ring)
        lengths = np.hypot(*(np.diff(ring[:, :2], axis=0).T))
        facing = streets.faces(mids, dirs, normals, reach, max_angle) & (lengths > 1.0)
        if not facing.any():
            no_street += 1
            continue
        sides = [(mids[j], dirs[j], normals[j]) for j in np.flatnonzero(facing)]
        side_len = lengths[facing]
        zone = shapely.union_all(shapely.buffer(shapely.linestrings(
            np.stack([ring[:-1][facing], ring[1:][facing]], axis=1)), min_setback,
            cap_style="flat")) if min_setback > 0 else None
        allowed_streets = parcel.difference(zone) if zone is not None else parcel
        # roads through the parcel or beside it count as street sides for the setback
        clear = max(min_setback, 1e-3)
        near = streets.near(parcel, clear)
        allowed = allowed_streets
        if len(near):
            allowed = allowed.difference(shapely.union_all(_buffer_at_least(near, clear)))
        if allowed_streets.is_empty:
            continue
        area = parcel.area
        fit = (parcel, sides, side_len, lib, lib_areas, streets, reach, max_angle)
        placed = None if allowed.is_empty else _best(allowed, *fit, near, clear)
        if placed is None:
            # a road through the parcel (or along it) that leaves no room is counted apart
            # when a building would have fitted without it
            if len(near) and _best(allowed_streets, *fit) is not None:
                crossed_by_road += 1
            continue
        b, rot, g, off = placed
        base = sunk = np.nan
        if dem is not None:
            # Scharl: moved down so that every vertex is on the ground or beneath
            ground = dem(shapely.get_coordinates(g.exterior)[:-1])
            if not np.isfinite(ground).all():
                no_terrain += 1  # a corner off the DEM: how deep to sink it is unknown
                continue
            base, sunk = float(ground.min()), float(ground.max() - ground.min())
            g = shapely.force_3d(g, base)
        geoms.append(g)
        rows.append({**b.attributes, "parcel_id": int(ids[pi]), "source_id": b.source_id,
                     "rotation": float((rot + 180.0) % 360.0 - 180.0), "offset_x": off[0],
                     "offset_y": off[1], "area_m2": float(g.area),
                     "parcel_share": float(g.area / area), "base_z": base,
                     "parcel_slope_pct": 100.0 * slopes[pi], "sunk_m": sunk})
    progress.step(1.0)
    n = len(parcels)
    stats = {"n_parcels": n, "n_placed": len(rows), "empty_share": 1.0 - len(rows) / n,
             "no_street": no_street, "too_steep": too_steep, "no_terrain": no_terrain,
             "crossed_by_road": crossed_by_road,
             "no_fit": n - len(rows) - no_street - too_steep - no_terrain - crossed_by_road}
    return BestFit(np.array(geoms, dtype=object), pd.DataFrame(rows), stats)
