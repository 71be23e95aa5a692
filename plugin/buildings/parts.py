"""Part-based buildings: the k best sequences of building parts under constraints.

Hartmann's thesis, ch. 6: a building is a sequence of parts cut from example models along
one primary dimension -- floors stacked along the height (the skyscrapers of Fig. 6.5), or
facade parts (end, middle, corner parts) along a skeleton in plan (Fig. 6.6-6.9). Each part
carries its length along that dimension (quantised to 0.2 m), its footprint, height,
levels, floor area and any countable attribute (balconies, doors); adjacent parts pay the
cross-section disagreement ``delta(e_i, e_j) = |A_right(e_i) - A_left(e_j)|`` (eq. 6.1).
The best or k best sequences under equality / interval constraints on length, floor area
(or FAR = floor area / site area), and counts are found with :func:`sequences.solve`
(the resource-constrained k-shortest-path engine of ch. 3).

- :func:`stack_floors`: a tower of floor parts of exactly the requested height and FAR
  (the thesis's skyscraper case: 120 m, FAR 10 / 15 / 20, a database of 18 floor parts;
  :func:`skyscraper_library` is such a database, documented there).
- :func:`build_along_skeleton`: parts along a polyline skeleton (the building's street-side
  facade line, street on the ``front`` side) or a closed ring (a block's offset polygon,
  the thesis's "filling empty blocks"). Key points (sec. 3.3.4) put end parts at the two
  ends of an open skeleton and corner parts at its vertices, chosen by the vertex angle;
  a ring is cut at a corner whose part is fixed per solve, the closing transition being
  paid as an end cost. :func:`terrace_library` is the default database for this.
- :func:`library_from_table`: a parts database from a table (+ optional footprints), the
  form in which a Processing algorithm passes a BUILDING_PARTS layer.

Placement: a part covering ``[a, b]`` of the (unrolled) skeleton is that stretch of the
skeleton thickened by the part's depth to the side away from the street (a single-sided
buffer with mitred joins), so consecutive parts share their cut lines and corner parts
wrap around the vertex; a 90° corner part whose legs equal its depth is the depth x depth
square at the corner. Not implemented: T-parts at skeleton branches (1.5D skeleton
networks, thesis sec. 3.3.4) and local constraints on single skeleton edges.

Nothing here imports QGIS. Lengths in metres, areas in m².

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 6
(building synthesis with RCKSP) and ch. 3.3.4 (key points, structures).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Mapping, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely
from shapely.geometry.polygon import orient

from ..core import coordinates
from ..core.geometry import substrings
from ..core.progress import InputError, Progress, ensure
from . import sequences
from .sequences import Constraint, InfeasibleError, KeyPoint

__all__ = ["PART_KINDS", "PartsLibrary", "PartsResult", "library_from_table",
           "skyscraper_library", "terrace_library", "stack_floors", "tower_centre",
           "build_along_skeleton"]

#: Part kinds: floors stack vertically; the others follow a skeleton in plan; T-parts sit
#: at the T-junctions of a skeleton network (:mod:`structures`).
PART_KINDS = ("floor", "straight", "corner", "end_left", "end_right", "tee")
#: Length grid of the parts (thesis ch. 6: multiples of 0.2 m) and floor-area grid (1 m²).
LENGTH_QUANTUM = 0.2
AREA_QUANTUM = 1.0
#: Skeleton vertices turning less than this (degrees) need no corner part.
STRAIGHT_TOLERANCE = 15.0
#: A corner part fits a vertex whose turning angle is within this of its own (degrees).
CORNER_TOLERANCE = 15.0

_REQUIRED = ("kind", "length_m", "height_m")


@dataclass
class PartsLibrary:
    """A building-parts database.

    ``table`` columns: ``part_id``, ``kind`` (:data:`PART_KINDS`), ``length_m`` (along the
    skeleton, or a floor part's height), ``depth_m``, ``height_m``, ``levels``,
    ``footprint_m2``, ``floor_area_m2`` (footprint x levels), ``area_left_m2`` /
    ``area_right_m2`` (cross-sections at the start / end side; a floor's bottom / top),
    ``angle_deg`` (a corner's turning angle, positive towards the building side), plus any
    numeric attribute columns that count constraints may use. ``transition[i, j]`` is the
    cost of part j after part i (``inf`` forbids). ``footprints``: shapely polygons of the
    parts in their own frame (used for floors, which are stacked as they are).
    """

    table: pd.DataFrame
    transition: np.ndarray
    footprints: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.table)

    @property
    def n_transitions(self) -> int:
        return int(np.isfinite(self.transition).sum())


@dataclass
class PartsResult:
    """Placed parts of the k best buildings.

    ``geometry``: one polygon per placed part; ``table`` per part: ``solution`` (rank, 1 =
    best), ``cost``, ``seq_index``, ``part_id``, ``kind``, ``start_m`` / ``length_m`` (along
    the structure), ``base_m`` / ``top_m`` / ``height_m`` (elevations), ``levels``,
    ``floor_area_m2``; ``summary`` per solution: cost, element count, length, height, floor
    area, FAR; ``solutions``: the engine's :class:`sequences.Solution` objects.
    """

    geometry: np.ndarray
    table: pd.DataFrame
    summary: pd.DataFrame
    solutions: List[sequences.Solution]


# --------------------------------------------------------------------------- libraries


def cross_section_costs(table: pd.DataFrame) -> np.ndarray:
    """Thesis eq. 6.1: ``|A_right(i) - A_left(j)|`` for every ordered pair of parts."""
    right = table["area_right_m2"].to_numpy(dtype=np.float64)
    left = table["area_left_m2"].to_numpy(dtype=np.float64)
    return np.abs(right[:, None] - left[None, :])


def library_from_table(table: pd.DataFrame, geoms: Optional[Sequence] = None,
                       transition: Optional[np.ndarray] = None, name: str = "parts"
                       ) -> PartsLibrary:
    """A parts database from a table (one row per part) and optional footprint polygons.

    Required columns: ``kind``, ``length_m``, ``height_m``. Optional (derived when missing):
    ``part_id`` (row number), ``depth_m`` (footprint area / length, else 10 m), ``levels``
    (height / 3 m, at least 1), ``footprint_m2`` (polygon area, else length x depth),
    ``floor_area_m2`` (footprint x levels), ``area_left_m2`` / ``area_right_m2`` (depth x
    height; a floor part: its footprint), ``angle_deg`` (90 for corners). A T-part (kind
    ``tee``, thesis Fig. 6.4: three cross-sections, two length attributes) also has
    ``branch_m`` (how far it reaches into the branch, from the junction's centre; default
    ``depth_m / 2``: no stub) and ``area_branch_m2`` (its branch-side cross-section,
    default depth x height); its ``length_m`` along the through wing must be at least
    ``depth_m`` (the branch must fit). Extra numeric columns are kept for count
    constraints. Without ``transition`` every pair costs the cross-section disagreement
    (eq. 6.1); end parts can only begin (``end_left``) or end (``end_right``) a sequence and
    floors only follow floors.

    Raises :class:`InputError` naming ``name`` for missing columns, unknown kinds,
    non-positive lengths or heights.
    """
    if table is None or len(table) == 0:
        raise InputError(f"{name}: the parts library is empty")
    t = pd.DataFrame(table).reset_index(drop=True).copy()
    missing = [c for c in _REQUIRED if c not in t.columns]
    if missing:
        raise InputError(f"{name}: missing field(s) {', '.join(missing)} "
                         f"(needed: {', '.join(_REQUIRED)})")
    t["kind"] = t["kind"].astype(str).str.strip().str.lower()
    bad = sorted(set(t["kind"]) - set(PART_KINDS))
    if bad:
        raise InputError(f"{name}: unknown part kind(s) {bad}; use {', '.join(PART_KINDS)}")
    for col in ("length_m", "height_m"):
        v = pd.to_numeric(t[col], errors="coerce")
        if v.isna().any() or (v <= 0).any():
            raise InputError(f"{name}: field {col} must be a positive number for every part")
        t[col] = v.astype(float)
    fp = None
    if geoms is not None:
        fp = np.asarray(geoms, dtype=object)
        if len(fp) != len(t):
            raise InputError(f"{name}: {len(fp)} footprints for {len(t)} parts")
    if "part_id" not in t.columns:
        t["part_id"] = np.arange(len(t))
    if "footprint_m2" not in t.columns:
        if fp is not None:
            t["footprint_m2"] = shapely.area(fp)
        elif "depth_m" in t.columns:
            t["footprint_m2"] = t["length_m"] * t["depth_m"]
    if "depth_m" not in t.columns:
        t["depth_m"] = (t["footprint_m2"] / t["length_m"] if "footprint_m2" in t.columns
                        else 10.0)
    if "footprint_m2" not in t.columns:
        t["footprint_m2"] = t["length_m"] * t["depth_m"]
    floors = (t["kind"] == "floor").to_numpy()
    if "levels" not in t.columns:
        t["levels"] = np.maximum(1, np.rint(t["height_m"] / 3.0)).astype(int)
    if "floor_area_m2" not in t.columns:
        t["floor_area_m2"] = t["footprint_m2"] * t["levels"]
    # the thesis's preprocessing: lengths on the 0.2 m grid, floor areas in whole m², so
    # that the table holds exactly the values the constraints are met with
    t["length_m"] = np.round(np.round(t["length_m"] / LENGTH_QUANTUM) * LENGTH_QUANTUM, 6)
    t["floor_area_m2"] = np.round(pd.to_numeric(t["floor_area_m2"]) / AREA_QUANTUM) * AREA_QUANTUM
    if (t["length_m"] <= 0).any():
        raise InputError(f"{name}: every part must be at least {LENGTH_QUANTUM:g} m long")
    for side in ("area_left_m2", "area_right_m2"):
        if side not in t.columns:
            t[side] = np.where(floors, t["footprint_m2"], t["depth_m"] * t["height_m"])
    if "angle_deg" not in t.columns:
        t["angle_deg"] = np.where(t["kind"] == "corner", 90.0, 0.0)
    tee = (t["kind"] == "tee").to_numpy()
    if "branch_m" not in t.columns:
        t["branch_m"] = np.where(tee, t["depth_m"] / 2, 0.0)
    t["branch_m"] = pd.to_numeric(t["branch_m"], errors="coerce").fillna(0.0)
    t["branch_m"] = np.round(np.round(t["branch_m"] / LENGTH_QUANTUM) * LENGTH_QUANTUM, 6)
    if "area_branch_m2" not in t.columns:
        t["area_branch_m2"] = np.where(tee, t["depth_m"] * t["height_m"], 0.0)
    bad_tee = tee & ((t["length_m"] < t["depth_m"] - 1e-6)
                     | (t["branch_m"] < t["depth_m"] / 2 - 1e-6)).to_numpy()
    if bad_tee.any():
        raise InputError(f"{name}: T-part(s) {t.part_id[bad_tee].tolist()} must be at least "
                         "depth_m long (length_m) and reach depth_m / 2 into the branch "
                         "(branch_m)")
    # a corner turning towards the building needs legs reaching the inner mitre point
    corner = (t["kind"] == "corner").to_numpy()
    need = t["depth_m"] * np.tan(np.radians(np.clip(t["angle_deg"], 0, 179)) / 2)
    short = corner & (t["length_m"].to_numpy() / 2 < need.to_numpy() - 1e-6)
    if short.any():
        raise InputError(f"{name}: corner part(s) {t.part_id[short].tolist()} are too short "
                         "for their angle (each leg, length_m / 2, must be at least "
                         "depth_m x tan(angle / 2))")
    if transition is None:
        transition = cross_section_costs(t)
        kind = t["kind"].to_numpy()
        transition[:, kind == "end_left"] = np.inf
        transition[kind == "end_right", :] = np.inf
        transition[np.ix_(floors, ~floors)] = np.inf
        transition[np.ix_(~floors, floors)] = np.inf
    transition = np.asarray(transition, dtype=np.float64)
    if transition.shape != (len(t), len(t)):
        raise InputError(f"{name}: the transition table must be {len(t)} x {len(t)}")
    return PartsLibrary(table=t, transition=transition, footprints=fp)


def skyscraper_library() -> PartsLibrary:
    """The default floor-part database of the skyscraper case (thesis Fig. 6.5).

    18 square floor parts: sides 20, 24, 28, 32, 36, 40 m (footprints 400 ... 1,600 m²),
    each as a 1-, 3- and 5-level part of 4 m per level (4, 12, 20 m tall). Stacking rules
    (81 allowed transitions; the thesis's database: 18 elements, 80 transitions): a part
    may stand on one of the same side with at least as many levels, or on one a single
    step (4 m) wider -- the setbacks of a tower -- at the cost of the cross-section
    disagreement |A_top - A_bottom| (eq. 6.1). On a 40 m x 40 m site (1,600 m²) a 120 m
    tower has exactly 30 levels; FAR 10 / 15 / 20 ask for 16,000 / 24,000 / 32,000 m².
    """
    sides = (20.0, 24.0, 28.0, 32.0, 36.0, 40.0)
    rows, geoms = [], []
    for s in sides:
        for levels in (1, 3, 5):
            rows.append(dict(part_id=f"F{int(s)}x{levels}", kind="floor", length_m=4.0 * levels,
                             depth_m=s, height_m=4.0 * levels, levels=levels,
                             footprint_m2=s * s, side_m=s))
            geoms.append(shapely.box(-s / 2, -s / 2, s / 2, s / 2))
    t = pd.DataFrame(rows)
    t["floor_area_m2"] = t["footprint_m2"] * t["levels"]
    t["area_left_m2"] = t["footprint_m2"]
    t["area_right_m2"] = t["footprint_m2"]
    side = t["side_m"].to_numpy()
    lev = t["levels"].to_numpy()
    below, above = side[:, None], side[None, :]   # part i below, part j on top
    allowed = (((above == below) & (lev[None, :] <= lev[:, None]))
               | np.isclose(below - above, 4.0))
    trans = np.where(allowed, cross_section_costs(t), np.inf)
    return library_from_table(t, geoms, trans, name="skyscraper library")


def terrace_library(depth: float = 12.0, infill: bool = True) -> PartsLibrary:
    """The default parts database for buildings along a skeleton (street-side facade line).

    All parts are ``depth`` deep (default 12 m) with 3 m levels:

    - 27 straight parts, 3, 4 and 5 levels each: 4.0, 4.2, 4.4, 4.6, 4.8, 5.0 m (narrow
      infill houses; with them any stretch of 8 m or more on the 0.2 m grid can be filled,
      so real skeletons need no rounding) and 6, 8, 10 m; the even-metre parts have a door,
      balconies: 2 per level on parts of 8 m or more, else 1;
    - corner parts for the turning angles 30°, 60°, 90°, 120° (convex corners, the
      building on the inside of the turn; legs reaching the inner mitre point, depth x
      tan(turn / 2), up to 15° past the class: the 90° parts are the depth x depth square,
      a third 90° part with 15.6 m legs takes turns up to 105°) and -30°, -60°, -90°
      (reflex corners), 4 levels, one 90° part with 5; with :data:`CORNER_TOLERANCE` turns
      of 15-135° (convex) and 15-105° (reflex) are covered;
    - left and right end parts, 6 m, 3 and 4 levels;
    - three T-parts for skeleton networks (:func:`structures.build_along_network`):
      ``depth`` long with no stub, 4 and 5 levels, and ``depth`` + 4 m long reaching 4 m
      into the branch past the through wing, with a door.

    Transitions: the cross-section disagreement (depth x height), so that neighbours of
    equal height are free; end parts only at the ends.

    ``infill=False`` leaves out the 4.2-5.0 m parts (and the 105° and 120° corners): 23
    facade parts (+ the 3 T-parts) whose lengths are whole multiples of 2 m, so that only skeletons with such side
    lengths can be filled, but floor-area / FAR constraints stay cheap (the floor-area sums
    are few); with the infill parts a FAR interval multiplies the graph by the many
    distinct floor-area sums (use a coarse ``area_resolution`` then).
    """
    rows = []
    lengths = (4.0, 4.2, 4.4, 4.6, 4.8, 5.0, 6.0, 8.0, 10.0) if infill else (4.0, 6.0, 8.0,
                                                                              10.0)
    for length in lengths:
        for levels in (3, 4, 5):
            rows.append(dict(kind="straight", length_m=length, levels=levels,
                             doors=int(float(length).is_integer() and length % 2 == 0),
                             balconies=(2 if length >= 8 else 1) * levels))
    # (angle class, largest turn the legs must reach around, levels)
    for angle, reach, levels in ((30.0, 45.0, 4), (60.0, 75.0, 4), (90.0, 90.0, 4),
                                 (90.0, 90.0, 5), (90.0, 105.0, 4), (120.0, 135.0, 4),
                                 (-30.0, 0.0, 4), (-60.0, 0.0, 4), (-90.0, 0.0, 4)):
        if not infill and reach > 90.0:
            continue
        leg = max(6.0, math.ceil(depth * math.tan(math.radians(reach) / 2) / 0.2 - 1e-9) * 0.2)
        if angle == 90.0 and reach == 90.0 or angle == -90.0:
            leg = depth
        rows.append(dict(kind="corner", length_m=round(2 * leg, 1), levels=levels,
                         angle_deg=angle, doors=0, balconies=0))
    for kind in ("end_left", "end_right"):
        for levels in (3, 4):
            rows.append(dict(kind=kind, length_m=6.0, levels=levels, doors=0, balconies=levels))
    # T-parts for skeleton networks (centreline placement, :mod:`structures`): the plain
    # crossing (depth x depth) and a wider one with a 4 m stub into the branch and a door
    for extra, levels, doors in ((0.0, 4, 0), (0.0, 5, 0), (4.0, 4, 1)):
        rows.append(dict(kind="tee", length_m=depth + extra, branch_m=depth / 2 + extra,
                         levels=levels, doors=doors, balconies=levels))
    t = pd.DataFrame(rows)
    t["angle_deg"] = t["angle_deg"].fillna(0.0)
    t["branch_m"] = t["branch_m"].fillna(0.0)
    t["depth_m"] = depth
    t["height_m"] = 3.0 * t["levels"]
    t["part_id"] = [f"{k[0].upper()}{i}" for i, k in enumerate(t["kind"])]
    # a corner's footprint: the two legs thickened by the depth (its placed area at its angle)
    fp = []
    for kind, length, angle, branch in zip(t["kind"], t["length_m"], t["angle_deg"],
                                           t["branch_m"]):
        if kind == "corner":
            fp.append(_corner_area(length / 2, depth, angle))
        elif kind == "tee":
            fp.append(length * depth + (branch - depth / 2) * depth)
        else:
            fp.append(length * depth)
    t["footprint_m2"] = fp
    return library_from_table(t, name="terrace library")


def _corner_area(leg: float, depth: float, angle: float) -> float:
    line = _bent_line(leg, angle)
    return float(shapely.area(_thicken(line, depth)))


def _bent_line(leg: float, angle: float) -> shapely.LineString:
    """Two legs meeting at the origin, turning by ``angle`` degrees (positive: to the left)."""
    a = math.radians(angle)
    return shapely.LineString([(-leg, 0.0), (0.0, 0.0), (leg * math.cos(a), leg * math.sin(a))])


def _thicken(line, depth: float):
    """The part's footprint: the line thickened by depth to its left (the building side)."""
    return shapely.buffer(line, depth, single_sided=True, cap_style="flat",
                          join_style="mitre", mitre_limit=10.0)


# --------------------------------------------------------------------------- solving


def _resource_matrix(lib: PartsLibrary, counts: Mapping[str, Tuple[float, float]],
                     area_resolution: float = AREA_QUANTUM):
    """Resources: 0 length, 1 floor area, then one column per count constraint."""
    t = lib.table
    cols = [t["length_m"].to_numpy(float), t["floor_area_m2"].to_numpy(float)]
    names = ["length_m", "floor_area_m2"]
    for key in counts:
        if key in PART_KINDS:
            cols.append((t["kind"] == key).to_numpy(float))
        elif key in t.columns:
            v = pd.to_numeric(t[key], errors="coerce")
            if v.isna().any() or (v < 0).any():
                raise InputError(f"count field {key} must be a non-negative number per part")
            cols.append(v.to_numpy(float))
        else:
            raise InputError(f"count constraint on '{key}': neither a part kind nor a field "
                             f"of the library ({', '.join(map(str, t.columns))})")
        names.append(key)
    R = np.column_stack(cols)
    if not area_resolution > 0:
        raise InputError("the floor-area resolution must be positive")
    res = np.array([LENGTH_QUANTUM, area_resolution] + [1.0] * len(counts))
    return R, res, names


def _area_bounds(floor_area, far, site_area) -> Optional[Tuple[float, float]]:
    if far is not None:
        if site_area is None or not site_area > 0:
            raise InputError("a FAR constraint needs a positive site area")
        lo, hi = (far, far) if np.isscalar(far) else far
        if lo < 0 or hi < lo:
            raise InputError(f"FAR bounds must satisfy 0 <= lo <= hi (got {lo}, {hi})")
        bounds = (lo * site_area, hi * site_area)
        if floor_area is not None:
            flo, fhi = (floor_area, floor_area) if np.isscalar(floor_area) else floor_area
            bounds = (max(bounds[0], flo), min(bounds[1], fhi))
        return bounds
    if floor_area is not None:
        return (floor_area, floor_area) if np.isscalar(floor_area) else tuple(floor_area)
    return None


def _constraints(length_bounds, area_bounds, counts) -> List[Constraint]:
    cons = [Constraint(0, *length_bounds)]
    if area_bounds is not None:
        cons.append(Constraint(1, *area_bounds))
    for i, (lo, hi) in enumerate(counts.values()):
        cons.append(Constraint(2 + i, lo, hi))
    return cons


def _summary(sols, R, names, site_area) -> pd.DataFrame:
    rows = []
    for s in sols:
        seq = list(s.sequence)
        # the library's floor areas (whole m²), not their values on a coarser area grid
        row = dict(solution=s.rank, cost=s.cost, n_parts=len(seq),
                   length_m=float(s.totals[0]), floor_area_m2=float(R[seq, 1].sum()))
        row["far"] = row["floor_area_m2"] / site_area if site_area else np.nan
        for j, nm in enumerate(names[2:], start=2):
            row[nm] = float(R[seq, j].sum())
        rows.append(row)
    return pd.DataFrame(rows)


def stack_floors(library: PartsLibrary, height_m: float, *, far=None, site_area=None,
                 floor_area=None, counts: Optional[Mapping[str, Tuple[float, float]]] = None,
                 k: int = 1, site=None, area_resolution: float = AREA_QUANTUM,
                 progress: Optional[Progress] = None) -> PartsResult:
    """A tower of floor parts of exactly ``height_m`` (thesis Fig. 6.5).

    Parameters
    ----------
    library : PartsLibrary with ``floor`` parts (``length_m`` = the part's height).
    height_m : float
        Total height (met exactly on the 0.2 m grid).
    far : float or (lo, hi), optional
        Floor-area ratio: total floor area / ``site_area`` (exact for a float).
    site_area : float, optional
        Site (plot) area in m²; the area of ``site`` if that is given.
    floor_area : float or (lo, hi), optional
        Total floor area bounds in m² (intersected with the FAR bounds).
    counts : {kind or numeric field: (lo, hi)}, optional
        Count constraints (e.g. ``{"levels": (30, 30)}``).
    k : int
        Number of solutions (the k best, in non-decreasing cost).
    site : shapely Polygon, optional
        The plot: floors are centred on :func:`tower_centre` (default: the origin).
    area_resolution : float
        Grid of the floor-area resource (default 1 m², the thesis's); a coarser grid
        (e.g. 10 m²) makes wide FAR intervals much faster, rounding each part's area to it.

    Returns
    -------
    PartsResult
        Floor polygons (2D) with ``base_m`` / ``top_m`` per part, bottom floor first.

    Raises
    ------
    InputError / sequences.InfeasibleError
        No floor parts, or no tower meets the constraints (the message says which bounds).
    """
    counts = dict(counts or {})
    floors = np.flatnonzero((library.table["kind"] == "floor").to_numpy())
    if not len(floors):
        raise InputError("the parts library has no floor parts to stack")
    if not height_m > 0:
        raise InputError(f"the height must be positive (got {height_m})")
    if site is not None:
        site_area = float(shapely.area(site)) if site_area is None else site_area
    sub = PartsLibrary(library.table.iloc[floors].reset_index(drop=True),
                       library.transition[np.ix_(floors, floors)],
                       None if library.footprints is None else library.footprints[floors])
    R, res, names = _resource_matrix(sub, counts, area_resolution)
    area = _area_bounds(floor_area, far, site_area)
    cons = _constraints((height_m, height_m), area, counts)
    try:
        sols = sequences.solve(R, sub.transition, cons, k=k, resolution=res,
                               progress=progress)
    except InfeasibleError as err:
        raise InfeasibleError(
            f"no tower of {height_m:g} m" + (f" with a floor area in [{area[0]:g}, "
                                             f"{area[1]:g}] m²" if area else "")
            + f" can be stacked from the {len(floors)} floor parts: {err}") from None
    centre = (0.0, 0.0) if site is None else tower_centre(site)
    t = sub.table
    E = np.concatenate([s.sequence for s in sols]).astype(np.int64)
    start = np.concatenate([s.starts for s in sols])
    depth = t["depth_m"].to_numpy(float)
    geoms = []
    for e in E:
        fp = (sub.footprints[e] if sub.footprints is not None else
              shapely.box(-depth[e] / 2, -depth[e] / 2, depth[e] / 2, depth[e] / 2))
        c = shapely.centroid(fp).coords[0]
        geoms.append(coordinates.translate([fp], (centre[0] - c[0], centre[1] - c[1]))[0])
    if site is not None:
        # a floor wider than its site stood over the neighbours' land, unsaid; a corner of
        # one over a courtyard or past an L's bend (a few m²) is a cantilever, not that
        over = shapely.area(shapely.difference(np.array(geoms, dtype=object), site))
        if (over / shapely.area(np.array(geoms, dtype=object))).max() > TOWER_OVERHANG:
            raise InfeasibleError(
                f"the tower's floors do not fit on the site: {over.max():,.0f} m² of a floor "
                f"{depth[E[np.argmax(over)]]:g} m wide would stand beyond it; a wider site or "
                "narrower floor parts fit")
    return PartsResult(np.array(geoms, dtype=object), _parts_table(sols, t, E, start, start),
                       _summary(sols, R, names, site_area), sols)


#: largest share of a tower floor's area that may stand beyond its site
TOWER_OVERHANG = 0.05


def tower_centre(site) -> Tuple[float, float]:
    """Where a tower's floors are centred on its site: the centroid, or, where the centroid
    lies outside the site (a courtyard block, an L or a crescent), the point furthest inside
    it (the pole of inaccessibility).

    >>> tower_centre(shapely.box(0, 0, 40, 40))
    (20.0, 20.0)
    >>> ring = shapely.box(0, 0, 80, 60).difference(shapely.box(20, 20, 60, 40))
    >>> shapely.Point(tower_centre(ring)).within(ring)
    True
    """
    from shapely.ops import polylabel

    centroid = shapely.centroid(site)
    if shapely.covers(site, centroid):
        return centroid.coords[0]
    return polylabel(site, tolerance=0.01).coords[0]


def _skeleton_line(skeleton, front: str):
    """(coords, closed): the facade line with the street on its right, building on its left."""
    if isinstance(skeleton, shapely.Polygon):
        if skeleton.is_empty:
            raise InputError("the skeleton polygon is empty")
        # a block's offset polygon: counter-clockwise, so the inside (the building) is left
        ring = orient(skeleton, 1.0).exterior
        return np.asarray(ring.coords)[:-1], True
    if isinstance(skeleton, (shapely.LinearRing, shapely.LineString)):
        coords = np.asarray(skeleton.coords)[:, :2]
        closed = isinstance(skeleton, shapely.LinearRing) or (
            len(coords) > 3 and np.allclose(coords[0], coords[-1]))
        if closed:
            coords = coords[:-1]
    else:
        raise InputError("the skeleton must be a LineString, LinearRing or Polygon")
    if front not in ("left", "right"):
        raise InputError("front must be 'left' or 'right' (the street side of the skeleton)")
    if front == "left":
        coords = coords[::-1]
    # drop repeated vertices
    keep = np.r_[True, np.linalg.norm(np.diff(coords, axis=0), axis=1) > 1e-9]
    coords = coords[keep]
    if len(coords) < 2 or (closed and len(coords) < 3):
        raise InputError("the skeleton needs at least two distinct vertices")
    return coords, closed


def _turns(coords: np.ndarray, closed: bool) -> np.ndarray:
    """Turning angle (degrees, positive to the left) at every vertex (0 at open ends)."""
    d = np.diff(np.vstack([coords, coords[:1]]) if closed else coords, axis=0)
    a = np.arctan2(d[:, 1], d[:, 0])
    if closed:
        turn = a - np.roll(a, 1)
    else:
        turn = np.r_[0.0, a[1:] - a[:-1], 0.0]
    return np.degrees((turn + np.pi) % (2 * np.pi) - np.pi)


def build_along_skeleton(skeleton, library: PartsLibrary, *, front: str = "right", k: int = 1,
                         floor_area=None, far=None, site_area=None,
                         counts: Optional[Mapping[str, Tuple[float, float]]] = None,
                         corner_tolerance: float = CORNER_TOLERANCE,
                         area_resolution: float = AREA_QUANTUM,
                         progress: Optional[Progress] = None) -> PartsResult:
    """The k best buildings of parts along a skeleton (thesis ch. 6, Fig. 6.6-6.9).

    Parameters
    ----------
    skeleton : LineString (open: end parts at both ends), LinearRing or Polygon (closed:
        a block's offset polygon, the building fills its inside)
        The street-side facade line; parts extend ``depth_m`` away from the street.
    library : PartsLibrary with ``straight``, ``corner`` and (open skeletons) ``end_left``
        / ``end_right`` parts.
    front : 'right' or 'left'
        The street side of the skeleton's direction (ignored for a Polygon).
    k : int
        Number of solutions.
    floor_area, far, site_area :
        Total floor area bounds in m² and / or FAR bounds with the site area (as in
        :func:`stack_floors`); a float means equality.
    counts : {kind or numeric field: (lo, hi)}, optional
        E.g. ``{"doors": (2, 4), "corner": (0, 4)}``.
    corner_tolerance : float
        Largest difference (degrees) between a vertex's turn and a corner part's angle.
    area_resolution : float
        Grid of the floor-area resource (see :func:`stack_floors`).

    Returns
    -------
    PartsResult
        Part footprints (valid, non-overlapping within a solution), the total length equal
        to the skeleton's (stretched by < 0.1 m onto the 0.2 m grid).

    Raises
    ------
    InputError / sequences.InfeasibleError
        A vertex no corner part fits, missing end parts, or no sequence meets the constraints.
    """
    progress = ensure(progress)
    counts = dict(counts or {})
    t = library.table
    kind = t["kind"].to_numpy()
    coords, closed = _skeleton_line(skeleton, front)
    turns = _turns(coords, closed)
    vertex_pos = np.r_[0.0, np.cumsum(np.linalg.norm(
        np.diff(np.vstack([coords, coords[:1]]) if closed else coords, axis=0), axis=1))]
    total = float(vertex_pos[-1])
    q = LENGTH_QUANTUM
    corner_idx = np.flatnonzero(kind == "corner")
    angles = t["angle_deg"].to_numpy(float)

    legs = t["length_m"].to_numpy(float) / 2
    depths = t["depth_m"].to_numpy(float)

    def corners_for(turn: float) -> Tuple[int, ...]:
        # the angle class, and legs long enough to reach the inner mitre point at this turn
        reach = depths[corner_idx] * np.tan(np.radians(min(max(turn, 0.0), 179.0)) / 2)
        fit = corner_idx[(np.abs(angles[corner_idx] - turn) <= corner_tolerance)
                         & (legs[corner_idx] >= reach - 1e-6)]
        if not len(fit):
            raise InfeasibleError(f"no corner part fits a skeleton vertex turning {turn:.0f}° "
                                  f"(library corners: {sorted(set(angles[corner_idx]))})")
        return tuple(int(i) for i in fit)

    verts = [i for i in range(len(coords)) if abs(turns[i]) >= STRAIGHT_TOLERANCE]
    if not closed:
        verts = [i for i in verts if 0 < i < len(coords) - 1]
    R, res, names = _resource_matrix(library, counts, area_resolution)
    area = _area_bounds(floor_area, far, site_area)
    key_only = np.isin(kind, ("corner", "end_left", "end_right"))
    usable = ~np.isin(kind, ("floor", "tee"))
    trans = library.transition.copy()
    trans[~usable, :] = np.inf
    trans[:, ~usable] = np.inf
    anchor = np.where(kind == "corner", t["length_m"].to_numpy() / 2,
                      np.where(kind == "end_right", t["length_m"].to_numpy(), 0.0))
    L_u = int(round(total / q))
    runs = []   # (shift, options for sequences.solve, scale)
    if closed:
        if not verts:
            raise InputError("a closed skeleton needs at least one corner vertex to start at")
        v0 = verts[0]
        rotated = np.roll(np.arange(len(coords)), -v0)
        coords, turns = coords[rotated], turns[rotated]
        vertex_pos = np.r_[0.0, np.cumsum(np.linalg.norm(
            np.diff(np.vstack([coords, coords[:1]]), axis=0), axis=1))]
        verts = [(v - v0) % len(coords) for v in verts]
        for first in corners_for(turns[0]):
            leg_u = int(round(anchor[first] / q))
            kps = [KeyPoint(leg_u * q, (first,))]
            kps += [KeyPoint((int(round(vertex_pos[v] / q)) + leg_u) * q, corners_for(turns[v]))
                    for v in verts if v != 0]
            runs.append((-leg_u * q, dict(key_points=kps, first=[first],
                                          end_cost=trans[:, first])))
    else:
        ends_l = np.flatnonzero(kind == "end_left")
        ends_r = np.flatnonzero(kind == "end_right")
        if not len(ends_l) or not len(ends_r):
            raise InputError("an open skeleton needs end_left and end_right parts in the library")
        kps = [KeyPoint(0.0, tuple(ends_l)), KeyPoint(L_u * q, tuple(ends_r))]
        kps += [KeyPoint(int(round(vertex_pos[v] / q)) * q, corners_for(turns[v]))
                for v in verts]
        runs.append((0.0, dict(key_points=kps, first=ends_l, last=ends_r)))
    sols: List[sequences.Solution] = []
    shifts: List[float] = []
    for r, (shift, opts) in enumerate(runs):
        try:
            found = sequences.solve(R, trans, _constraints((L_u * q, L_u * q), area, counts),
                                    k=k, resolution=res, key_only=key_only, anchor=anchor,
                                    progress=progress.sub(r / len(runs), (r + 1) / len(runs)),
                                    **opts)
        except InfeasibleError:
            continue
        sols += found
        shifts += [shift] * len(found)
    if not sols:
        raise InfeasibleError(
            f"no sequence of the {len(t)} parts fills the {total:.1f} m skeleton"
            + (f" with a floor area in [{area[0]:g}, {area[1]:g}] m²" if area else "")
            + (f" and counts {counts}" if counts else "")
            + (" with a corner part at every corner vertex" if closed else
               " with end parts at the ends and corner parts at the vertices"))
    order = sorted(range(len(sols)), key=lambda i: (sols[i].cost, i))[:k]
    kept = [sequences.Solution(rank=rank, cost=sols[i].cost, sequence=sols[i].sequence,
                               starts=sols[i].starts, totals=sols[i].totals)
            for rank, i in enumerate(order, start=1)]
    # placement, vectorised over all parts of all solutions
    scale = total / (L_u * q)                       # < 0.1 m stretch onto the real length
    E = np.concatenate([s.sequence for s in kept]).astype(np.int64)
    shift = np.concatenate([np.full(len(kept[r].sequence), shifts[i])
                            for r, i in enumerate(order)])
    start = np.concatenate([s.starts for s in kept])
    length = t["length_m"].to_numpy(float)
    a = (start + shift) * scale + (total if closed else 0.0)
    b = a + length[E] * scale
    line = shapely.LineString(np.vstack([coords, coords, coords[:1]]) if closed else coords)
    pieces = substrings(np.full(len(a), line, dtype=object), a, b)
    geoms = _thicken(pieces, t["depth_m"].to_numpy(float)[E])
    # where a part boundary falls on a slight bend (no corner part there) the neighbours'
    # square cuts overlap in a thin wedge on the inner side: the later part gives it up
    sol_of = np.repeat(np.arange(len(kept)), [len(s.sequence) for s in kept])
    prev = np.arange(len(E)) - 1
    first_of = np.r_[True, sol_of[1:] != sol_of[:-1]]
    last_of = np.r_[sol_of[1:] != sol_of[:-1], True]
    prev[first_of] = np.flatnonzero(last_of) if closed else -1
    has_prev = prev >= 0
    geoms = np.asarray(geoms, dtype=object)
    trimmed = geoms.copy()
    trimmed[has_prev] = shapely.difference(geoms[has_prev], geoms[prev[has_prev]])
    geoms = trimmed
    if isinstance(skeleton, shapely.Polygon):
        _require_room(skeleton, geoms[sol_of == 0], float(t["depth_m"].to_numpy(float)[E].max()))
    table = _parts_table(kept, t, E, start, base=np.zeros(len(E)))
    return PartsResult(np.asarray(geoms, dtype=object), table,
                       _summary(kept, R, names, site_area), kept)


def _require_room(polygon, placed: np.ndarray, depth: float):
    """Refuse a polygon skeleton its parts do not fit in: where it is narrower than the
    parts' depth, they stood in its courtyard or beyond its far side (a ring 8 m wide with
    12 m parts: 800 m² of the building in the courtyard), or over the parts of the
    opposite side."""
    union = shapely.union_all(placed)
    outside = shapely.area(shapely.difference(union, polygon))
    overlap = float(shapely.area(placed).sum() - shapely.area(union))
    if outside > 1.0 or overlap > 1.0:
        raise InfeasibleError(
            f"the polygon is narrower than its parts' depth ({depth:g} m) in places: "
            + (f"{outside:,.0f} m² of them would stand outside it (in its courtyard or beyond "
               "its far side)" if outside > 1.0 else
               f"{overlap:,.0f} m² of them would overlap across it")
            + "; thinner parts fit")


def _parts_table(sols, t: pd.DataFrame, E: np.ndarray, start: np.ndarray,
                 base: np.ndarray) -> pd.DataFrame:
    """One row per placed part (see :class:`PartsResult`)."""
    n_per = [len(s.sequence) for s in sols]
    height = t["height_m"].to_numpy(float)[E]
    return pd.DataFrame({
        "solution": np.repeat([s.rank for s in sols], n_per),
        "cost": np.repeat([s.cost for s in sols], n_per),
        "seq_index": np.concatenate([np.arange(n) for n in n_per]),
        "part_id": t["part_id"].to_numpy()[E], "kind": t["kind"].to_numpy()[E],
        "start_m": start, "length_m": t["length_m"].to_numpy(float)[E],
        "base_m": base, "top_m": base + height, "height_m": height,
        "levels": t["levels"].to_numpy()[E].astype(int),
        "floor_area_m2": t["floor_area_m2"].to_numpy(float)[E]})
