"""Street and parcel layouts by hierarchical domain splitting (Yang et al. 2013).

Pipeline of :func:`split_domain` (one layout) and :func:`split_variations` (k layouts):

1. **Constraints** (sec. 3): the region minus the key areas (parks, school, lake: kept
   as parcels of their own land use) is cut by the key roads into sub-regions. A key road
   ending inside the region is continued straight to the next street (a dangle leaves a
   slit no template fills). Region outlines count as streets (a development bounded by
   roads) unless ``outline_streets`` is off: then they are "no street" edges (Fig. 4 edge
   labels); where the outline runs beside a key road just outside the region, the key road
   is the street (:func:`_outline_onto_key_roads`). An outline street bends as a curve,
   not a kink, where the outline bends by less than a corner (``templates.CORNER_TURN``,
   35°: a boundary polygon's arcs, such as a buffer's 22.5° steps; :func:`rounded_bends`).
   Where the outline runs beside a key road a street width to a street plus the shallowest
   row of parcels from it, it is no street: no row would fit between the two streets, so
   the land up to the outline fronts on the key road (:func:`_outline_beside_key_roads`).
   Key roads of a motorway class take no junction and give no frontage (the outline
   street and key roads' continuations end short of them).
2. **Hierarchical splitting with backtracking** (sec. 3-5, :class:`_Search`): a region is
   replaced by a template when one matches: row templates are warped onto it
   (:func:`templates.warp_rows`, registration / regression) and their **warp energy**
   (registration residual per corner / parcel width, plus the turn of region corners the
   template cannot take; a corner on a long street side, up to 50°, is taken by a parcel
   joint and costs only its residual) is under ``energy_threshold``; edge labels must
   agree (a double strip needs a street on both long sides); drawn by probability
   x exp(-energy / 0.1).
   Otherwise the region is split along a streamline of its cross field (:mod:`cross_field`
   with a divergence term, :mod:`streamlines`: Delaunay seeds, RK2, the four quality
   terms; the width fit prefers the templates with less street, ``WIDTH_FIT_PREFERENCE``),
   drawn by quality; a split whose children could hold no template, that leaves land too
   thin for a row of parcels where the region had none (``THIN_LAND``), or whose street
   would run along a key road (in its corridor, :func:`invariants.doubles_a_street`; key
   roads just outside the region too), is rejected,
   and when a child can be neither matched nor split the split is undone and another
   streamline drawn (``MAX_TRIES`` per region, ``MAX_BACKTRACKS`` per layout; template
   ``max_count`` limits are kept during the search). A region that fails everything
   gets rule-based parcels (``fallback_parcels``: recursive splits, each the squarest by
   Yang's p_area and p_angle of its two pieces among the cuts across the long axis, the
   short axis, the longest and the second-longest side, by default, or the
   straight-skeleton parcels the paper names, Vanegas et al. 2012)
   or, when small, a park.
3. **Global optimisation of the road mesh** (sec. 6, :mod:`mesh_optimisation`): strip
   fitting, fairness and closeness on the noded street mesh, junctions sliding along the
   fixed roads, until converged; kept when it lowers the summed warp distortion of the
   row templates (what the paper optimises for), then the templates are warped again.
   Then the **"no street" joints** (Fig. 4 edge labels, :func:`no_street_joints`, on by
   ``back_to_back``): a split street between two row-template blocks that both keep their
   template and street access without it is dropped (parcel strips back to back along
   their rear lot lines, rows end to end), up to a block as long as the longest row; so
   is one between rows or a park and a park left in a small region, which keeps a street;
   a street whose blocks on one side were joined before is dropped whole when all its
   blocks allow it (one piece alone would leave the rest of it a dead end).
4. Parcels: lots without frontage and crumbs join their neighbours; a lot still without
   frontage is an inner green (the paper's template with a private park). The optional
   :func:`repair_lots` (off by default; not in the paper) cuts misshapen lots to the
   rectangle on their street and makes the wedges pocket parks. :func:`table1` gives the
   paper's Table 1 through :mod:`metrics`, counting every designed parcel, parks too.
5. Streets: :func:`road_network` nodes every line at its junctions (snap-rounded) and
   drops dangling pieces under 1 m (overshoot stubs).

Nothing here imports QGIS. Geometry is metric; each variation draws from
``numpy.random.default_rng([seed, variation])``.

References
----------
Yang, Y.-L., Wang, J., Vouga, E., Wonka, P. (2013). Urban pattern: layout design by
    hierarchical domain splitting. ACM TOG 32(6) (SIGGRAPH Asia), sec. 3-7, Table 1-2.
Vanegas, C. A. et al. (2012). Procedural generation of parcels in urban modeling. CGF 31(2).
"""
from __future__ import annotations

import functools
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely
from scipy.cluster.hierarchy import DisjointSet

from ..core.geometry import (minimum_rectangles, rounded_band_bends, rounded_bends,
                             substrings, unit)
from ..core.progress import InputError, Progress, ensure
from ..measure import metrics as _metrics
from ..network import invariants as _invariants
from ..network.controlled_access import ended_short
from ..network.links import meets_only_at_ends
from ..network.street_graph import (JUNCTION_TOLERANCE, collapse_short_pieces,
                                   snap_ends_onto_lines, weld_ends)
from ..parcels import subdivision as _parcels
from . import templates as _templates
from .cross_field import cross_field
from .mesh_optimisation import NODING_GRID, faces_of, noded, optimise_roads
from .streamlines import score_streamlines, seed_points, trace_streamlines, width_fit

__all__ = ["SplitSettings", "Layout", "ROAD_FIELDS", "PARCEL_FIELDS", "METRIC_FIELDS",
           "split_domain", "split_variations", "table1", "unused_drawn_templates", "prepare_domain", "no_street_joints"]

#: Output attributes (name, type) of the roads, parcels and metrics tables.
ROAD_FIELDS = [("road_id", "int"), ("level", "int"), ("kind", "str"), ("variation", "int"),
               ("length_m", "float")]
PARCEL_FIELDS = [("parcel_id", "int"), ("variation", "int"), ("land_use", "str"),
                 ("template", "str"), ("area_m2", "float"), ("frontage_m", "float"),
                 ("has_street_access", "bool"), ("p_angle", "float"), ("p_area", "float"),
                 ("undesirable", "bool")]
METRIC_FIELDS = [("variation", "int"), ("l_s", "float"), ("l_r", "float"), ("l_p", "float"),
                 ("l_o", "float"), ("b_n", "float"), ("b_max", "float"), ("b_avg", "float"),
                 ("b_min", "float"), ("s_l", "float"), ("s_i", "float"), ("s_d", "float"),
                 ("p_n", "float"), ("p_count", "int"), ("p_angle", "float"),
                 ("p_area", "float"), ("undesirable", "int"), ("undesirable_pct", "float"),
                 ("p_count_residential", "int"), ("p_angle_residential", "float"),
                 ("p_area_residential", "float"), ("no_access", "int"), ("time_split_s", "float"),
                 ("time_backtrack_s", "float"), ("time_optimise_s", "float")]

#: Streamline candidates drawn per region before it counts as not splittable.
MAX_DRAWS = 20
#: Searches at most, when templates have a minimum count (Yang's k2), until every minimum
#: is met.
MIN_COUNT_ATTEMPTS = 8
#: Alternative splits tried per region when a child cannot be filled (backtracking) ...
MAX_TRIES = 3
#: ... and the most abandoned attempts in one layout.
MAX_BACKTRACKS = 60

#: Parcel outlines are simplified with this tolerance (m).
_OUTPUT_GRID = 0.01
#: (m) a line this close to a region's outline runs along it (a few output grid cells)
_ON_OUTLINE = 0.05
#: Rule-based parcels: a recursive cut moves by up to this many parcel widths to leave from
#: a corner of the lot's outline (the row templates' alignment: no parcel straddles a bend
#: of its street side; on the fidelity benchmark's Schaan and Vaduz p_angle 3.22 and 3.28
#: -> 3.05 and 3.10 degrees at 0.35).
CUT_TO_CORNER = 0.35
#: A split is rejected when it leaves more than this many parcel lengths squared of land in
#: bands too thin for a row of parcels that were not thin before.
THIN_LAND = 2.0
#: The width fit of a split weights each template by its probability (relative to the
#: likeliest) to this power: a width a double strip fills scores well above one that a
#: parcel strip fills (0.13 against 1 with the shipped library, 0.6 at the power 1), whose
#: share of street land is 1.7 times as large (15 m of every 45 across, against 15 of 75).
#: On the fidelity benchmark's Ruggell, Gamprin and Mauren (seeds 1-3, means) the streets
#: took 29.3 / 30.4 / 28.7 % of the land at 4 against 31.3 / 31.3 / 31.0 % at 1.
WIDTH_FIT_PREFERENCE = 4.0
#: The leaf marker of a region given rule-based parcels (no template, no split).
RULE_BASED = "rule_based"
#: The subdivision methods that may give a region its rule-based parcels.
FALLBACK_PARCELS = ("recursive", "skeleton")
#: Road levels: 0 key road, 1 region outline, 2 split street, 3 template street (cul-de-sac).
LEVEL_KEY, LEVEL_OUTLINE, LEVEL_SPLIT, LEVEL_TEMPLATE = 0, 1, 2, 3


@dataclass(frozen=True)
class SplitSettings:
    """Parameters of the splitting (the paper's Table 1 runs: 30 m x 18 m parcels, 15 m
    streets).

    Attributes
    ----------
    parcel_length, parcel_width, street_width : float (m)
    energy_threshold : float
        A template is used when its energy is below this.
    optimise : bool
        Run the global road-mesh optimisation (sec. 6).
    max_regions : int
        Safety bound on the number of regions split.
    choice_temperature : float
        Streamlines are drawn with probability exp((qual - best) / T): small T = nearly
        always the best (the paper's comparison runs), larger T = more variety.
    repair_lots : bool
        Run the optional lot repair (:func:`repair_lots`, not in the paper); off by default.
    outline_streets : bool
        The region's outline is a street (a development bounded by roads, the paper's
        boundary condition). False labels it "no street" (Yang Fig. 4 edge labels): no
        street land is reserved along it and parcels back onto it (a town's edge against
        fields or forest).
    back_to_back : bool
        "No street" joints (:func:`no_street_joints`, Yang Fig. 4 edge labels): a split
        street along which every block keeps its template and its street access without
        it (two parcel strips back to back along their rear lot lines, or row templates
        end to end) is dropped and becomes a "no street" edge, up to a block perimeter of
        the longest row template. False keeps every split street.
    fallback_parcels : str
        The rule-based parcels of a region no template fits and no streamline splits
        (Yang sec. 3: "a rule-based assignment that either uses the parceling algorithm
        based on the straight skeleton [Vanegas et al. 2012] or places a park"), by the
        name of a :mod:`parcels.subdivision` method: ``"recursive"`` (the default: cuts
        across an axis of each lot's bounding rectangle or across one of its two longest
        sides, whichever leaves the squarest pieces, every piece with street frontage) or ``"skeleton"`` (the paper's). Recursive is the default because its
        lots are squarer where the fallback is needed, odd leftover regions: on the
        domain-split benchmark's towns p_angle falls by 0.2-0.9 deg and p_area by up to
        0.012 against skeleton lots (README).
    settle_joints : bool
        Each joint between two lots with frontage moved to where the two are squarest
        (:func:`settle_joints`; not in the paper, a discrete regression of the warp's
        joints by Table 1's measures): lower p_area, no higher p_angle, the same streets
        and lot count, at 1.2-1.5 times the split's CPU (on by default; README,
        splitdomain).
    """

    parcel_length: float = 30.0
    parcel_width: float = 18.0
    street_width: float = 15.0
    energy_threshold: float = 0.1
    optimise: bool = True
    max_regions: int = 2000
    choice_temperature: float = 0.3
    repair_lots: bool = False
    outline_streets: bool = True
    back_to_back: bool = True
    fallback_parcels: str = "recursive"
    settle_joints: bool = True

    def validate(self) -> "SplitSettings":
        if self.fallback_parcels not in FALLBACK_PARCELS:
            raise InputError(f"the rule-based parcels must be one of {', '.join(FALLBACK_PARCELS)} "
                             f"(got {self.fallback_parcels!r})")
        for name in ("parcel_length", "parcel_width", "street_width"):
            v = getattr(self, name)
            if v is None or not math.isfinite(v) or v <= 0:
                raise InputError(f"{name.replace('_', ' ')} must be a positive number (got {v})")
        if self.parcel_width > 10 * self.parcel_length or self.parcel_length > 20 * self.parcel_width:
            raise InputError("parcel length and width are absurd together "
                             f"({self.parcel_length:g} m x {self.parcel_width:g} m)")
        if self.street_width > 5 * self.parcel_length:
            raise InputError(f"the street width ({self.street_width:g} m) is absurd for parcels "
                             f"{self.parcel_length:g} m deep")
        return self


@dataclass
class Layout:
    """One layout.

    Attributes
    ----------
    roads : ndarray of LineString; road_level, road_kind : arrays
    blocks : ndarray of Polygon (centre-line blocks, one per template); block_template : names
    parcels : ndarray of Polygon; table : DataFrame (PARCEL_FIELDS)
    stats : dict (counts and the times of splitting, backtracking and optimisation)
    street_blocks : ndarray of Polygon or None
        The blocks between streets where they differ from ``blocks`` (blocks joined by
        "no street" edges, :func:`no_street_joints`): what the block metrics count.
    """

    roads: np.ndarray
    road_level: np.ndarray
    road_kind: np.ndarray
    blocks: np.ndarray
    block_template: np.ndarray
    parcels: np.ndarray
    table: pd.DataFrame
    domain: shapely.Geometry
    stats: dict = field(default_factory=dict)
    street_blocks: Optional[np.ndarray] = None


# --------------------------------------------------------------------------- input

def _polygonal(geoms, what: str) -> shapely.Geometry:
    geoms = np.asarray([g for g in np.asarray(geoms, dtype=object).ravel()
                        if g is not None and not shapely.is_empty(g)], dtype=object)
    if len(geoms) == 0:
        raise InputError(f"the {what} has no geometry")
    if not (shapely.get_dimensions(geoms) == 2).all():
        raise InputError(f"the {what} must be polygons")
    geoms = shapely.make_valid(geoms)
    parts = _parcels._polygon_parts(geoms)
    if len(parts) == 0:
        raise InputError(f"the {what} has no area")
    return shapely.union_all(parts)


#: OSM classes of limited-access roads: no street joins them at grade and no parcel
#: fronts on them (the hierarchy rule of the layout's key roads).
LIMITED_ACCESS = frozenset({"motorway", "motorway_link"})


def key_area_parcels(key_areas, key_area_use, domain):
    """The key areas inside ``domain`` as parcels, each with the land use of its feature.

    Key areas of one use are merged (two overlapping parks are one park); where areas of
    different uses overlap, the use that comes first in the layer keeps the overlap, so
    that the parcels never overlap. A missing use is 'park'. The uses follow the features,
    not the parts of their union: a part's use was once taken by position, and any key area
    outside the region, split in two or overlapping another made every use 'park' (or
    swapped two uses).

    Returns (polygons, uses).

    >>> import shapely
    >>> polys, uses = key_area_parcels(
    ...     [shapely.box(60, 0, 80, 20), shapely.box(0, 0, 20, 20), shapely.box(10, 0, 30, 20)],
    ...     ["lake", "school", None], shapely.box(0, 0, 100, 100))
    >>> [(u, shapely.area(p)) for u, p in zip(uses, polys)]
    [('lake', 400.0), ('school', 400.0), ('park', 200.0)]
    """
    areas = np.asarray(key_areas, dtype=object).ravel()
    raw = (np.asarray(key_area_use, dtype=object).ravel() if key_area_use is not None
           else np.full(len(areas), None, dtype=object))
    if len(raw) != len(areas):
        raise InputError(f"{len(raw)} land uses for {len(areas)} key areas")
    _polygonal(areas, "key areas layer")  # some geometry, all of it polygons
    uses = np.array(["park" if u is None or (isinstance(u, float) and math.isnan(u))
                     or not str(u).strip() else str(u) for u in raw], dtype=object)
    ok = np.array([g is not None and not shapely.is_empty(g) for g in areas], dtype=bool)
    polys, poly_uses, taken = [], [], shapely.Polygon()
    for use in dict.fromkeys(uses[ok]):
        area = shapely.union_all(_parcels._polygon_parts(
            shapely.make_valid(areas[ok & (uses == use)])))
        with np.errstate(invalid="ignore"):
            own = shapely.difference(shapely.intersection(area, domain), taken)
        parts = _parcels._polygon_parts([own], 1.0)
        polys += list(parts)
        poly_uses += [use] * len(parts)
        taken = shapely.union(taken, area)
    return np.asarray(polys, dtype=object), np.asarray(poly_uses, dtype=object)


def prepare_domain(region, key_roads=None, key_areas=None, street_width: float = 15.0,
                   key_road_classes=None, max_extension: float = 400.0,
                   outline_streets: bool = True, beside_reach: float = 0.0,
                   key_area_use=None):
    """Work regions, the fixed street lines and the key-area polygons with their uses.

    A key road that ends inside the region (a dangling street of a real network) is
    continued straight ahead to the next street or the region outline when that is at
    most ``max_extension`` metres away: a dangle would otherwise leave a slit in its face
    that no template fits (the continuity rule of Yang sec. 5, applied to the given roads).
    Key roads of a :data:`LIMITED_ACCESS` class stay as they are and are returned in
    ``no_access`` (a line geometry, or None): no new street may end on them and no parcel
    counts them as frontage. Where the outline runs beside a key road (not a motorway), a
    street width to ``beside_reach`` metres from it, for
    :data:`invariants.MIN_DUPLICATE_LENGTH` or more, no row of parcels would fit between
    the two streets: the outline is no street there (the key road is; the land up to the
    outline fronts on it), and the outline street's ends there are joined to the key road
    (:func:`_outline_beside_key_roads`).

    Returns (faces, fixed_lines, fixed_kinds, key_polys, key_uses, domain, no_access)
    (``key_polys`` and their uses: :func:`key_area_parcels`).
    """
    domain = _polygonal(region, "region")
    key_polys = key_uses = np.empty(0, dtype=object)
    work = domain
    if outline_streets:
        # the street along the outline is laid as a curve where the outline only bends (a
        # polygon's arc): copied kink by kink, every lot along it would have a corner of
        # 145-170° at each kink. It moves by at most 0.08 street widths (1.1 m for 15 m),
        # well inside its own half-width.
        work = shapely.union_all([rounded_bends(p, _templates.CORNER_TURN, street_width / 2)
                                  for p in shapely.get_parts(domain)])
    if key_areas is not None and len(key_areas):
        keys = _polygonal(key_areas, "key areas layer")
        with np.errstate(invalid="ignore"):
            keys = shapely.intersection(keys, domain)
        key_polys, key_uses = key_area_parcels(key_areas, key_area_use, domain)
        work = shapely.difference(work, keys)
    outline = shapely.get_parts(shapely.line_merge(shapely.boundary(work)))
    lines = list(outline)
    kinds = ["outline" if outline_streets else "edge"] * len(lines)
    no_access = None
    if key_roads is not None and len(key_roads):
        raw = np.asarray(key_roads, dtype=object).ravel()
        cls = (np.asarray([str(c) if c is not None else "" for c in key_road_classes],
                          dtype=object) if key_road_classes is not None
               else np.full(len(raw), "", dtype=object))
        if len(cls) != len(raw):
            raise InputError(f"{len(cls)} road classes for {len(raw)} key roads")
        ok = np.array([g is not None and not shapely.is_empty(g) for g in raw], dtype=bool)
        roads, cls = raw[ok], cls[ok]
        if len(roads) and not (shapely.get_dimensions(roads) == 1).all():
            raise InputError("the key roads must be lines")
        limited = np.isin(cls, list(LIMITED_ACCESS))
        merged_all = []
        for sel, kind in ((~limited, "key"), (limited, "limited")):
            if not sel.any():
                continue
            with np.errstate(invalid="ignore"):
                inside = shapely.get_parts(shapely.intersection(shapely.union_all(roads[sel]),
                                                                work))
            inside = inside[(shapely.get_type_id(inside) == 1) & (shapely.length(inside) > 0.5)]
            merged = shapely.get_parts(shapely.line_merge(shapely.union_all(inside))) \
                if len(inside) else np.empty(0, dtype=object)
            merged_all.append((merged, kind))
        barrier = shapely.union_all(np.concatenate([outline] + [m for m, _ in merged_all]))
        for merged, kind in merged_all:
            if kind == "key":
                merged = _extend_dangles(merged, barrier, max_extension)
            else:
                no_access = shapely.union_all(merged) if len(merged) else None
            lines += list(merged)
            kinds += [kind] * len(merged)
        keys_ = np.asarray([g for g, k in zip(lines, kinds) if k == "key"], dtype=object)
        if outline_streets and beside_reach > 0 and len(keys_):
            lines, kinds = _outline_beside_key_roads(lines, kinds, keys_, beside_reach,
                                                     street_width)
    faces = _faces(lines, work)
    if len(faces) == 0:
        raise InputError("the region is empty once the key areas are removed" if len(key_polys)
                         else "the region encloses no area to lay out")
    return (faces, np.asarray(lines, dtype=object), np.asarray(kinds), key_polys, key_uses,
            domain, no_access)


def _outline_beside_key_roads(lines, kinds, keys, reach: float, nearest: float,
                              step: float = 5.0, max_angle: float = 30.0):
    """The fixed lines with each stretch of outline street that runs beside a key road
    (``nearest`` to ``reach`` m from it and within ``max_angle`` degrees of its direction,
    sampled every ``step`` m, for at least :data:`invariants.MIN_DUPLICATE_LENGTH`) made a
    "no street" edge, and a link street from each of the stretch's ends to the key road
    (when it crosses no line). Nearer than ``nearest`` (a street width) the two streets
    leave no land between them and the outline stays a street (the key road takes its
    place in the result, :func:`_outline_onto_key_roads`). Returns (lines, kinds)."""
    key_union = shapely.union_all(keys)
    tree = shapely.STRtree(keys)
    cos_max = math.cos(math.radians(max_angle))
    out_lines, out_kinds, links = [], [], []
    for line, kind in zip(lines, kinds):
        if kind != "outline" or line.length < _invariants.MIN_DUPLICATE_LENGTH:
            out_lines.append(line)
            out_kinds.append(kind)
            continue
        at = np.linspace(0.0, line.length, max(int(line.length // step), 1) + 1)
        pts = shapely.line_interpolate_point(line, at)
        to_key = shapely.shortest_line(pts, key_union)
        dist = shapely.length(to_key)
        near = shapely.get_point(to_key, 1)
        key = keys[tree.nearest(near)]
        key_dir = _direction_at(key, shapely.line_locate_point(key, near))
        beside = (dist >= nearest) & (dist < reach) & \
            (np.abs((key_dir * _direction_at(line, at)).sum(1)) > cos_max)
        # runs of samples beside a key road, long enough to be more than a crossing
        edges = np.flatnonzero(np.diff(np.r_[0, beside.astype(np.int8), 0]))
        runs = [(at[a], at[b - 1]) for a, b in zip(edges[::2], edges[1::2])
                if at[b - 1] - at[a] >= _invariants.MIN_DUPLICATE_LENGTH]
        if not runs:
            out_lines.append(line)
            out_kinds.append(kind)
            continue
        # where the outline goes on to meet the key road within ``reach`` (a corner of the
        # region where the key road leaves it), the stretch runs on to that crossing: no
        # link is needed there, and none would run along the outline
        with np.errstate(invalid="ignore"):
            meet = shapely.get_parts(shapely.intersection(line, key_union))
        meet = np.sort(shapely.line_locate_point(line, meet[shapely.get_type_id(meet) == 0]))
        lo, hi = np.array(runs).T
        before = np.searchsorted(meet, lo, side="right") - 1
        after = np.searchsorted(meet, hi, side="left")
        lo_meets = (before >= 0) & (lo - meet[np.maximum(before, 0)] <= reach) \
            if len(meet) else np.zeros(len(lo), dtype=bool)
        hi_meets = (after < len(meet)) & (meet[np.minimum(after, len(meet) - 1)] - hi <= reach) \
            if len(meet) else np.zeros(len(hi), dtype=bool)
        if len(meet):
            lo = np.where(lo_meets, meet[np.maximum(before, 0)], lo)
            hi = np.where(hi_meets, meet[np.minimum(after, len(meet) - 1)], hi)
        # two stretches run on over the same short gap are one (only possible where
        # ``reach`` exceeds MIN_DUPLICATE_LENGTH: large streets or parcels)
        spans: list = []
        for a, b, ma, mb in sorted(zip(lo, hi, lo_meets, hi_meets)):
            if spans and a < spans[-1][1]:
                if b > spans[-1][1]:
                    spans[-1][1], spans[-1][3] = b, mb
            else:
                spans.append([a, b, ma, mb])
        lo, hi, lo_meets, hi_meets = (np.asarray(v) for v in zip(*spans))
        stretches = substrings([line] * len(lo), lo, hi)
        rest = _line_without(line, stretches)
        out_lines += list(rest) + list(stretches)
        out_kinds += [kind] * len(rest) + ["edge"] * len(stretches)
        rest_union = shapely.union_all(rest) if len(rest) else None
        # an end at a crossing, at the line's own end or at another stretch stays as it is
        for ends, meets in ((shapely.get_point(stretches, 0), lo_meets),
                            (shapely.get_point(stretches, -1), hi_meets)):
            links += [shapely.shortest_line(e, key_union) for e, m in zip(ends, meets)
                      if not m and rest_union is not None
                      and shapely.distance(e, rest_union) < 1e-6]
    for link in links:
        if 1e-6 < link.length <= reach + step and meets_only_at_ends(link, out_lines):
            out_lines.append(link)
            out_kinds.append("outline")
    return out_lines, out_kinds


def _direction_at(lines, at) -> np.ndarray:
    """Unit directions (n, 2) of lines at distances ``at`` along them, over 2 m (clamped to
    the line: a negative distance would count from its far end)."""
    ahead = shapely.line_interpolate_point(lines, np.minimum(at + 1.0, shapely.length(lines)))
    behind = shapely.line_interpolate_point(lines, np.maximum(at - 1.0, 0.0))
    return unit(shapely.get_coordinates(ahead) - shapely.get_coordinates(behind))


def _extend_dangles(lines: np.ndarray, barrier, max_extension: float) -> np.ndarray:
    """Lines whose free ends (touching no other line nor the outline) are continued
    straight ahead to the first line they meet within ``max_extension``."""
    if len(lines) == 0:
        return lines
    out = []
    for k, g in enumerate(lines):
        xy = shapely.get_coordinates(g)
        others = shapely.union_all(np.concatenate([lines[:k], lines[k + 1:]])) \
            if len(lines) > 1 else shapely.GeometryCollection()
        rest = shapely.union_all([others, barrier])
        stop = shapely.union_all([others, _outline_of(barrier, g)])
        for end, prev in ((0, 1), (-1, -2)):
            p = xy[end]
            touching = shapely.distance(stop, shapely.Point(p)) < 0.5
            if touching:
                continue
            d = p - xy[prev]
            d = d / max(float(np.hypot(*d)), 1e-12)
            ray = shapely.LineString([p + 0.01 * d, p + max_extension * d])
            with np.errstate(invalid="ignore"):
                hit = shapely.intersection(ray, rest)
            if hit.is_empty:
                continue
            dist = shapely.distance(shapely.Point(p), hit)
            q = p + (dist + 1e-6) * d
            xy = np.vstack([q[None], xy]) if end == 0 else np.vstack([xy, q[None]])
        out.append(shapely.LineString(xy))
    return np.asarray(out, dtype=object)


def _key_lines(key_roads) -> np.ndarray:
    """The key roads as given, missing and empty geometries left out."""
    keys = np.asarray(key_roads, dtype=object).ravel()
    return keys[~(shapely.is_missing(keys) | shapely.is_empty(keys))]


def _outline_onto_key_roads(roads, level, kind, key_roads):
    """The region's outline where it runs beside a key road (in its corridor for longer than
    the invariants allow, :func:`invariants.corridor_of`: a key road just outside the region)
    is no street of the result: the key road is the street there. The outline's cut ends and
    the streets that ended on the dropped stretch are carried straight onto the key road (at
    most twice the corridor's half-width, crossing no street), so that none is left dangling.
    Returns (roads, level, kind, stretches dropped)."""
    keys = _key_lines(key_roads)
    if not len(keys):
        return roads, level, kind, 0
    corridor = _invariants.corridor_of(keys)
    out_roads, out_level, out_kind, dropped, ends = [], [], [], [], []
    for line, lv, kd in zip(roads, level, kind):
        along = np.empty(0, dtype=object)
        if kd == "outline" and corridor.intersects(line):
            with np.errstate(invalid="ignore"):
                along = shapely.get_parts(shapely.line_merge(
                    shapely.intersection(line, corridor)))
            along = along[(shapely.get_dimensions(along) == 1) &
                          (shapely.length(along) > _invariants.MIN_DUPLICATE_LENGTH)]
        pieces = _line_without(line, along) if len(along) else [line]
        out_roads += pieces
        out_level += [lv] * len(pieces)
        out_kind += [kd] * len(pieces)
        dropped += list(along)
        for stretch in along:   # the outline's cut ends (a ring has no ends of its own)
            for end in (shapely.get_point(stretch, 0), shapely.get_point(stretch, -1)):
                if line.is_ring or shapely.distance(end, shapely.boundary(line)) > 1e-6:
                    ends.append(end)
    if not dropped:
        return roads, level, kind, 0
    gone = shapely.union_all(dropped)
    for line, kd in zip(list(out_roads), out_kind):  # streets that ended on a dropped stretch
        if kd != "outline":
            ends += [e for e in (shapely.get_point(line, 0), shapely.get_point(line, -1))
                     if shapely.distance(e, gone) < 1e-6]
    key_lines = shapely.union_all(keys)
    reach = 2 * _invariants.CORRIDOR_HALF_WIDTH
    for end in ends:
        link = shapely.shortest_line(end, key_lines)
        if link is None or not 1e-6 < link.length <= reach:
            continue
        if meets_only_at_ends(link, out_roads):
            out_roads.append(link)
            out_level.append(LEVEL_OUTLINE)
            out_kind.append("outline")
    return out_roads, out_level, out_kind, len(dropped)


def _line_without(line, stretches):
    """The pieces of ``line`` outside ``stretches`` (sub-lines of it), cut by distance along
    it, so that the pieces end exactly where the stretches began (a ring's stretch may run
    over its first point)."""
    total = line.length
    start = shapely.line_locate_point(line, shapely.get_point(stretches, 0))
    end = shapely.line_locate_point(line, shapely.get_point(stretches, -1))
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    wraps = np.abs((hi - lo) - shapely.length(stretches)) > \
        1e-3 * shapely.length(stretches) + 1e-6
    spans = []
    for i in range(len(stretches)):
        spans += [(hi[i], total), (0.0, lo[i])] if wraps[i] else [(lo[i], hi[i])]
    starts, stops, at = [], [], 0.0
    for a0, a1 in sorted(spans):
        if a0 - at > 1e-6:
            starts.append(at)
            stops.append(a0)
        at = max(at, a1)
    if total - at > 1e-6:
        starts.append(at)
        stops.append(total)
    return list(substrings([line] * len(starts), np.array(starts), np.array(stops))) \
        if starts else []


def _cut_continuations(roads, level, kind, key_roads, tolerance: float = 0.01):
    """Key roads that :func:`prepare_domain` continued past their free ends, cut where the
    given road ends: the given part stays the road the user gave, the continuation is a
    street of its own that ends on it. As one line, the continuation made the whole road a
    new street doubling the given one, crossing it wherever rounding put it on the other
    side (Helsinki: 11 crossings without a junction and 4 duplicates in one layout).

    Returns (roads, level, kind) arrays, the continued lines in two or three pieces.
    """
    given = shapely.union_all(np.asarray(key_roads, dtype=object).ravel())
    shapely.prepare(given)
    out, out_level, out_kind = [], [], []
    for g, lv, k in zip(roads, level, kind):
        xy = shapely.get_coordinates(g)
        cuts = []
        if k == "key" and len(xy) >= 3:
            on = shapely.dwithin(given, shapely.points(xy), tolerance)
            # the given part may end any number of vertices from the line's end (a
            # continuation noded at a junction on its way has more than one)
            if on.any() and not on[0]:
                cuts.append(int(np.argmax(on)))
            if on.any() and not on[-1]:
                cuts.append(len(xy) - 1 - int(np.argmax(on[::-1])))
            cuts = sorted(set(c for c in cuts if 0 < c < len(xy) - 1))
        bounds = [0] + cuts + [len(xy) - 1]
        for i0, i1 in zip(bounds[:-1], bounds[1:]):
            if i1 > i0:
                out.append(shapely.LineString(xy[i0:i1 + 1]))
                out_level.append(lv)
                out_kind.append(k)
    return np.asarray(out, dtype=object), np.asarray(out_level), np.asarray(out_kind, dtype=object)


def _ended_short_of_limited_access(roads, level, kind, key_roads, tolerance: float = 0.01):
    """Streets that end on a motorway key road away from its junctions with the other key
    roads end short of it, outside its corridor (the invariants' width), as side streets
    end at a motorway's fence; one with both ends on it goes. The split streets already
    keep off motorways; the region's outline street still ended on one where the outline
    crosses it (a motorway across the region: four junctions on it), and so did a key road's
    continuation (:func:`_cut_continuations`) that met one. The rule's geometry is
    :func:`network.controlled_access.ended_short`'s.

    Returns (roads, level, kind, number of streets ended short or removed)."""
    limited = kind == "limited"
    if not limited.any():
        return roads, level, kind, 0
    motorways = shapely.union_all(roads[limited])
    # a key road's continuation is a new street: it does not lie on the roads given
    given = shapely.buffer(shapely.union_all(np.asarray(key_roads, dtype=object).ravel()),
                           tolerance)
    continued = (kind == "key") & ~shapely.within(roads, given)
    others = roads[(kind == "key") & ~continued]
    # the motorways' own junctions: where another key road ends on them (a motorway's end
    # at the region's edge is none)
    junctions = shapely.multipoints(np.r_[shapely.get_point(others, 0),
                                          shapely.get_point(others, -1)])
    corridor = shapely.buffer(motorways, _invariants.CORRIDOR_HALF_WIDTH)
    keep = np.ones(len(roads), dtype=bool)
    roads = roads.copy()
    n = 0
    for i in np.flatnonzero(~np.isin(kind, ("key", "limited")) | continued):
        ends = shapely.get_point(roads[i], [0, -1])
        on = shapely.dwithin(ends, motorways, tolerance) & \
            ~shapely.dwithin(ends, junctions, tolerance)
        if not on.any():
            continue
        n += 1
        short = None if on.all() else ended_short(roads[i], ends[1 if on[0] else 0], corridor)
        if short is None:
            keep[i] = False
        else:
            roads[i] = short
    return roads[keep], level[keep], kind[keep], n


def _outline_of(barrier, line):
    """The barrier less the line itself (its own vertices touch it)."""
    with np.errstate(invalid="ignore"):
        return shapely.difference(barrier, shapely.buffer(line, 0.01))


def _faces(lines, work) -> np.ndarray:
    faces = faces_of(lines)
    if len(faces) == 0:
        return faces
    inside = shapely.within(shapely.point_on_surface(faces), work)
    return _parcels._polygon_parts(faces[inside], 1.0)


# --------------------------------------------------------------------------- splitting

def _shallowest_rows(lib, length: float) -> float:
    """Depth (m) of the shallowest row template of ``lib`` at its smallest depth scale,
    parcels ``length`` deep (inf without a row template): thinner land holds no row."""
    return min([t.rows * length * t.depth_scale[0] for t in lib if t.kind == "rows"],
               default=math.inf)


class _Splitter:
    def __init__(self, lib, settings: SplitSettings, rng):
        self.lib = lib
        self.s = settings
        self.rng = rng
        L, S = settings.parcel_length, settings.street_width
        self.fitted = [t for t in lib if t.kind in ("rows", "drawn")]
        self.use_boost({})
        # a sub-region thinner than this holds no template: its split is rejected
        self.min_depth = S + min(_shallowest_rows(lib, L), 2.6 * L)
        self.n_split = 0
        self.n_rejected = 0
        self.n_no_access = 0
        self.no_access = None      # motorways: no junction
        self.key_corridor = None   # the key roads' corridors: no split street runs along one
        self.no_street = None      # no-street edges: no street land
        self.no_frontage = None    # both: no parcel fronts on them

    def use_boost(self, boost: Dict[str, float]):
        """The width fit of the splits (:func:`streamlines.width_fit`) with the templates'
        probabilities to the power :data:`WIDTH_FIT_PREFERENCE`, times ``boost`` (name ->
        factor: the templates still short of their minimum count)."""
        L, S = self.s.parcel_length, self.s.street_width
        widths = [t.gross_depth(L, S) for t in self.fitted]
        top = max(t.probability for t in self.fitted) or 1.0
        self.opt = width_fit(widths, 6 * max(widths + [L + S]), 0.12 * L, weights=[
            max(t.probability / top, 0.05) ** WIDTH_FIT_PREFERENCE * boost.get(t.name, 1.0)
            for t in self.fitted])

    def energies(self, region) -> Dict[str, float]:
        """Warp energy of every template on a region (Yang sec. 4.1): row templates are
        warped onto the region shrunk by half a street and scored by their registration
        residual, drawn templates (the built-in spike and loop among them) warped as drawn
        and scored the same way (:func:`templates.warp_drawn`); the area template by
        :func:`templates.fit_energy`."""
        s = self.s
        shape = _templates.region_shape(region)
        out = {t.name: _templates.fit_energy(region, t, s.parcel_length, s.parcel_width,
                                             s.street_width, shape)
               for t in self.lib if t.kind not in ("rows", "drawn")}
        block = None   # the net block and its no-access zone, made once for all templates
        for t in self.lib:
            if t.kind not in ("rows", "drawn"):
                continue
            if block is None:
                block = self.net_block_of(region, self.no_street, self.no_frontage)
            if t.kind == "rows":
                out[t.name] = self.row_energy(region, t, self.no_street, self.no_frontage,
                                              block)
            else:
                parts = block[0]
                warp = _templates.warp_drawn(parts[0], t, cut=False,
                                             entrance_ok=self.entrance_ok) \
                    if len(parts) == 1 else None
                out[t.name] = math.inf if warp is None else warp.energy
        return out

    def entrance_ok(self, points) -> bool:
        """Whether a drawn template's own streets, leaving its block at ``points`` (the
        block's edge, half a street inside the region), join a street there: no "no
        street" edge and no motorway within a street width (Yang's edge labels)."""
        return self.no_frontage is None or not shapely.dwithin(
            self.no_frontage, shapely.points(np.asarray(points).reshape(-1, 2)),
            self.s.street_width).any()

    def net_block_of(self, region, no_street, no_frontage):
        """(parts of the region's net block, the zone where its sides give no access or
        None): what every template's energy on the region starts from."""
        s = self.s
        parts = _parcels._polygon_parts([net_block(region, s.street_width, no_street)], 1.0)
        near = None if no_frontage is None else shapely.buffer(
            _near(no_frontage, region, s.street_width), s.street_width / 2 + 1.0)
        return parts, near

    def row_energy(self, region, t, no_street, no_frontage, block=None) -> float:
        """Warp energy of the row template ``t`` on a region whose sides along
        ``no_street`` are "no street" edges and along ``no_frontage`` give no access
        (inf when it does not fit or its edge labels do not agree); ``block``: the
        region's :meth:`net_block_of` with the same lines, when made already."""
        parts, near = block if block is not None else \
            self.net_block_of(region, no_street, no_frontage)
        if len(parts) != 1:
            return math.inf
        return _rows_energy(parts[0], t, self.s, near)

    def pick_template(self, energies, exclude=(), boost=None):
        """A template for a region, drawn by probability x exp(-energy / 0.1) among those
        under the threshold (``boost``: name -> factor on the probability)."""
        by_name = {t.name: t for t in self.lib}
        ok = [(n, e) for n, e in energies.items()
              if e < self.s.energy_threshold and n not in exclude and by_name[n].kind != "park"]
        if not ok:
            return None
        boost = boost or {}
        p = np.array([by_name[n].probability * boost.get(n, 1.0) * math.exp(-e / 0.1)
                      for n, e in ok])
        if p.sum() <= 0:
            return None
        return ok[int(self.rng.choice(len(ok), p=p / p.sum()))][0]

    def candidates(self, region, ends):
        """Streamline splits of a region, drawn by quality without replacement: yields
        (line, children) for every drawn candidate whose children could hold a template
        (at most ``MAX_DRAWS`` draws). Lines ending on a limited-access road are skipped:
        no side street joins a motorway at grade."""
        L = self.s.parcel_length
        area = shapely.area(region)
        h = max(L / 5.0, math.sqrt(area) / 35.0)
        field_ = cross_field(region, h)
        d_eps = 0.3 * L
        seeds = seed_points(region, d_eps, self.rng)
        cands = trace_streamlines(field_, region, seeds, max(h, L / 4.0), d_eps, self.rng)
        if len(cands.lines) == 0:
            return
        keep = shapely.length(cands.lines) >= L
        if self.no_access is not None:
            ends_xy = np.array([shapely.get_coordinates(g)[[0, -1]] for g in cands.lines])
            if len(ends_xy):
                near = shapely.dwithin(self.no_access, shapely.points(ends_xy.reshape(-1, 2)),
                                       0.5).reshape(-1, 2).any(1)
                self.n_no_access += int((keep & near).sum())
                keep &= ~near
        if not keep.any():
            return
        cands.lines, cands.seeds, cands.orientation = (cands.lines[keep], cands.seeds[keep],
                                                       cands.orientation[keep])
        qual, _ = score_streamlines(cands, field_, region, self.opt, ends, step=h)
        alive = np.ones(len(qual), dtype=bool)
        thin_before = functools.lru_cache(maxsize=1)(lambda: self._thin_land(region)[2])
        for _ in range(MAX_DRAWS):
            if not alive.any():
                return
            q = np.where(alive, qual, -np.inf)
            p = np.exp((q - q.max()) / max(self.s.choice_temperature, 1e-6))
            i = int(self.rng.choice(len(q), p=p / p.sum()))
            alive[i] = False
            got = self._children(region, cands.lines[i], thin_before)
            if got is not None:
                self.n_split += 1
                yield got
            else:
                self.n_rejected += 1

    def _thin_land(self, polygons):
        """(eroded, opened, thin) of ``polygons`` by half a street and 0.3 parcel depths:
        the thin land, what the morphological opening takes away, is too thin for a row of
        parcels with its street."""
        r = self.s.street_width / 2 + 0.3 * self.s.parcel_length
        inner = shapely.buffer(polygons, -r, join_style="mitre")
        opened = shapely.buffer(inner, r, join_style="mitre")
        return inner, opened, shapely.difference(polygons, opened)

    def _children(self, region, line, thin_before=None):
        """(street, children) of a split along ``line``, or None when a child could hold
        no template. The street is the streamline clipped by the region, so that its ends
        lie exactly on the region's outline (no overshoot, no gap). ``thin_before``: a
        callable giving the region's own thin land (cached by :meth:`candidates`, which
        tries up to MAX_DRAWS splits of one region)."""
        coords = shapely.get_coordinates(line)
        ext = shapely.LineString(np.vstack([coords[0] + 0.5 * unit(coords[0] - coords[1]),
                                            coords,
                                            coords[-1] + 0.5 * unit(coords[-1] - coords[-2])]))
        with np.errstate(invalid="ignore"):
            inside = shapely.get_parts(shapely.intersection(ext, region))
        inside = inside[shapely.get_type_id(inside) == 1]
        if len(inside) != 1:
            return None
        faces = _faces([shapely.boundary(region), ext], region)
        if len(faces) < 2:
            return None
        # the street is taken from the same noded arrangement as the faces (snap-rounded
        # to NODING_GRID): the children's outlines and the street then share their
        # vertices exactly, and a later street ending on this one meets it at a node of
        # the noding instead of a few 1e-5 m beside it (a false dead end, and blocks that
        # the road mesh would not separate)
        pieces = noded([shapely.boundary(region), ext])
        mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
        on_outline = shapely.dwithin(shapely.boundary(region), mid, 10 * NODING_GRID)
        in_region = shapely.within(mid, region)
        street = shapely.line_merge(shapely.union_all(pieces[in_region & ~on_outline]))
        if street.geom_type != "LineString":
            return None
        _, short, _ = minimum_rectangles(faces)
        if (short < self.min_depth).any():
            return None
        inner, opened, thin = self._thin_land(faces)
        if shapely.is_empty(inner).any():
            return None
        # morphological opening: a child that is thick somewhere but a thin band elsewhere
        # (a streamline running close to the boundary) leaves a sliver no template fills
        if (shapely.area(opened) < 0.85 * shapely.area(faces)).any():
            return None
        # ... nor one that makes bands of land too thin for a row where the region had none,
        # however large its children (a street down the middle of a narrow arm of the region
        # leaves a sliver on each side of it, a small part of each child)
        most_thin = THIN_LAND * self.s.parcel_length ** 2
        thin_now = shapely.union_all(thin)
        if shapely.area(thin_now) > most_thin:
            before = thin_before() if thin_before is not None else self._thin_land(region)[2]
            if shapely.area(shapely.difference(thin_now, before)) > most_thin:
                return None
        if self.key_corridor is not None and \
                _invariants.doubles_a_street(np.array([street]), self.key_corridor).any():
            return None  # it would run along a key road (the invariants' corridor rule)
        return street, faces


class _Search:
    """Hierarchical splitting with backtracking (Yang sec. 3).

    A region is replaced by a template when one matches (energy under the threshold,
    drawn by probability x exp(-energy / 0.1), templates at their ``max_count`` left out);
    otherwise it is split along a streamline drawn by quality and its children are filled
    the same way, depth first. When a child can be neither matched nor split (it would
    fall back to rule-based parcels or a park), the split is undone and another streamline
    drawn (``MAX_TRIES`` per region, ``MAX_BACKTRACKS`` per layout); the attempt with the
    least fallback area is kept. Template counts are restored on every undo.
    """

    def __init__(self, splitter, by_name, s, work_area, progress, boost=None):
        self.sp = splitter
        self.boost = boost
        self.by_name = by_name
        self.s = s
        self.work_area = work_area
        self.progress = progress
        self.counts = Counter()
        self.n_regions = 0
        self.n_backtracks = 0
        self.time_abandoned = 0.0
        self.done_area = 0.0

    def _full(self):
        return {n for n, t in self.by_name.items()
                if t.max_count is not None and self.counts[n] >= t.max_count}

    def fill(self, region, ends, depth):
        """(leaves, street lines, fallback area) of a region."""
        s = self.s
        L, W = s.parcel_length, s.parcel_width
        self.progress.check()
        self.n_regions += 1
        if self.n_regions > s.max_regions or shapely.area(region) < 0.5 * L * W:
            name = RULE_BASED if shapely.area(region) >= 0.5 * L * W else "park"
            return [[region, name, {}]], [], float(shapely.area(region))
        energies = self.sp.energies(region)
        name = self.sp.pick_template(energies, exclude=self._full(), boost=self.boost)
        if name is not None:
            self.counts[name] += 1
            self._report(region)
            return [[region, name, energies]], [], 0.0
        best = None
        tries = 0
        for street, children in self.sp.candidates(region, ends):
            self.progress.check()
            t0 = time.perf_counter()
            inner0 = self.time_abandoned
            saved = self.counts.copy()
            leaves, lines, bad = [], [street], 0.0
            sub_ends = np.vstack([ends, _end_dirs([street])])
            for child in children:
                got = self.fill(child, sub_ends, depth + 1)
                leaves += got[0]
                lines += got[1]
                bad += got[2]
                sub_ends = np.vstack([sub_ends, _end_dirs(got[1])])
            # the time of this attempt less what its own sub-searches already counted as
            # abandoned (so nested backtracking is not counted twice)
            own = time.perf_counter() - t0 - (self.time_abandoned - inner0)
            if best is None or bad < best[2]:
                if best is not None:
                    self.time_abandoned += best[4]
                best = (leaves, lines, bad, self.counts.copy(), own)
            else:
                self.time_abandoned += own
            tries += 1
            if bad <= 0 or tries >= MAX_TRIES or self.n_backtracks >= MAX_BACKTRACKS:
                break
            self.n_backtracks += 1  # a child failed: undo this split, draw another
            self.counts = saved
        if best is None:
            fb = _fallback(region, energies, self.by_name, s)
            self.counts[fb] += 1
            self._report(region)
            return [[region, fb, energies]], [], (0.0 if fb in self.by_name and
                                                  self.by_name[fb].kind == "rows"
                                                  else float(shapely.area(region)))
        self.counts = best[3]
        return best[0], best[1], best[2]

    def _report(self, region):
        self.done_area += float(shapely.area(region))
        if self.work_area:
            self.progress.step(min(0.6, 0.6 * self.done_area / self.work_area))


def road_network(roads, level, kind, stub: float = 1.0):
    """The streets of a layout as a planar network: every line noded at its crossings and
    T-junctions (snap-rounded, :data:`mesh_optimisation.NODING_GRID`), each piece keeping
    the level and kind of the line it came from. Pieces shorter than ``stub`` metres are
    dropped where they dangle (overshoots of a junction computed in floating point) and
    collapsed into one junction where they lie between two (:func:`street_graph.
    collapse_short_pieces`: one junction computed twice, or two streets meeting a road
    from its two sides a fraction of a metre apart: 0.5-5 mm pieces of split streets and
    0.5-0.8 m pieces of key roads on Mauren; dropped, they left that gap in the road). The
    key roads (``level`` :data:`LEVEL_KEY`) stay on their lines: another street's short
    piece collapses onto its end on one, and stays between two; a key road's short piece
    stays, the streets at one of its ends move to the other, and it is merged back into
    the road (:func:`_merge_through`). Line ends under ``stub`` / 2 apart are then one
    point (:func:`street_graph.weld_ends`; the key roads' ends stay).

    Returns (pieces, level, kind, number of stubs dropped).

    >>> key = shapely.LineString([(0, 0), (100, 0)])
    >>> a = shapely.LineString([(50, 0), (50, 80)])
    >>> b = shapely.LineString([(50.4, 0), (50.4, -80)])
    >>> pieces, *_ = road_network([key, a, b], [0, 1, 1], ["road"] * 3)
    >>> sorted(round(float(x), 3) for x in shapely.length(pieces))   # the key road as it was
    [50.0, 50.0, 80.0, 80.001]
    >>> ends = shapely.get_coordinates(shapely.boundary(pieces))
    >>> xy, count = np.unique(ends, axis=0, return_counts=True)
    >>> xy[count == 4].round(6).tolist()   # one crossing
    [[50.0, 0.0]]
    """
    roads = np.asarray(roads, dtype=object)
    level = np.asarray(level)
    kind = np.asarray(kind, dtype=object)
    if len(roads) == 0:
        return roads, level, kind, 0
    pieces, _ = collapse_short_pieces(noded(roads), JUNCTION_TOLERANCE)   # round-off first
    mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    pi, ri = shapely.STRtree(roads).query_nearest(mid, all_matches=True)
    # the lowest level (most important road) wins where two lines share a piece
    order = np.lexsort((level[ri], pi))
    pi, ri = pi[order], ri[order]
    first = np.r_[True, pi[1:] != pi[:-1]]
    src = np.empty(len(pieces), dtype=np.int64)
    src[pi[first]] = ri[first]
    xy0 = shapely.get_coordinates(shapely.get_point(pieces, 0))
    xy1 = shapely.get_coordinates(shapely.get_point(pieces, -1))
    ends = np.round(np.vstack([xy0, xy1]) / NODING_GRID).astype(np.int64)
    _, inv, count = np.unique(ends, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    deg = count[inv]
    dangling = (deg[:len(pieces)] == 1) | (deg[len(pieces):] == 1)
    stubs = dangling & (shapely.length(pieces) < stub)
    keep = ~stubs
    level, kind = level[src][keep], kind[src][keep]
    # the key roads stay on their lines: a street's piece between two collapses onto them
    pieces, kept = collapse_short_pieces(pieces[keep], stub, anchored=level == LEVEL_KEY)
    level, kind = level[kept], kind[kept]
    # line ends a fraction of a metre apart, one point (four streets whose crossing was
    # computed twice met as two bends 9 cm apart on Triesenberg)
    pieces = weld_ends(pieces, level != LEVEL_KEY, stub / 2)
    pieces, level, kind = _merge_through(pieces, level, kind, stub)
    # a street's piece welded onto a key road's (a split street along the road for a metre,
    # Mauren): one street there, the most important
    same = shapely.to_wkb(shapely.normalize(shapely.set_precision(pieces, NODING_GRID)))
    order = np.argsort(level, kind="stable")
    _, first = np.unique(same[order], return_index=True)
    keep = np.sort(order[first])
    return pieces[keep], level[keep], kind[keep], int(stubs.sum())


def _merge_through(pieces, level, kind, shorter: float):
    """Pieces shorter than ``shorter`` m merged into the piece of the same level and kind
    that goes on from one of their ends where nothing else meets it (a key road's piece
    between two streets that became one crossing)."""
    short = np.flatnonzero(shapely.length(pieces) < shorter)
    if not len(short):
        return pieces, level, kind
    pieces = pieces.copy()
    ends = np.vstack([shapely.get_coordinates(shapely.get_point(pieces, 0)),
                      shapely.get_coordinates(shapely.get_point(pieces, -1))])
    n = len(pieces)
    at = {}
    for k, xy in enumerate(map(tuple, ends)):
        at.setdefault(xy, []).append(k % n)
    gone = np.zeros(n, bool)
    for i in short:
        for xy, far in ((tuple(ends[i]), tuple(ends[i + n])), (tuple(ends[i + n]), tuple(ends[i]))):
            if len(at.get(xy, ())) != 2 or xy == far:
                continue
            j = at[xy][0] if at[xy][1] == i else at[xy][1]
            if j == i or level[j] != level[i] or kind[j] != kind[i]:
                continue
            merged = shapely.line_merge(shapely.multilinestrings([pieces[j], pieces[i]]))
            if shapely.get_type_id(merged) != 1:
                continue
            pieces[j] = merged
            gone[i] = True
            del at[xy]   # now inside the merged piece
            at[far] = [j if k == i else k for k in at[far]]
            break
    return pieces[~gone], level[~gone], kind[~gone]


def net_block(region, street_width: float, no_street=None):
    """The land of a centre-line region left for parcels: the region less half a street
    along every side that is a street. Sides on ``no_street`` lines (a region outline
    labelled "no street") keep their land; the street bands end square there.
    """
    edge = shapely.boundary(region)
    if no_street is not None:
        with np.errstate(invalid="ignore"):
            edge = shapely.difference(edge, shapely.buffer(_near(no_street, region, 1.0), 0.01))
    if shapely.is_empty(edge):
        return region
    # square ends: where a street side meets a "no street" edge at an obtuse corner, a
    # flat end would leave a tooth of the block reaching the street's centre line
    with np.errstate(invalid="ignore"):
        return shapely.difference(region, street_band(edge, street_width, "square"))


def street_band(lines, street_width: float, cap_style: str):
    """The land within half a street of the street centre ``lines`` (mitre joins), its
    shallow bends rounded (:func:`rounded_band_bends`, up to :data:`templates.CORNER_TURN`):
    a given road's kinks (a real road is digitised as a polyline) and the bends of the
    split streets would otherwise give every lot along them a corner of 145-170° at each,
    which Table 1's p_angle counts (on Helsinki, 83 such corners along the given roads
    carried 22 % of its sum); the band is never narrower than half a street."""
    band = shapely.buffer(lines, street_width / 2, cap_style=cap_style, join_style="mitre")
    return rounded_band_bends(band, street_width / 2, _templates.CORNER_TURN)


def access_frontage(lots, region, street_width: float, no_access=None) -> np.ndarray:
    """Length (m) of each lot's outline along a street of its centre-line region that
    gives access: every side but the ``no_access`` lines (no-street edges, motorways)."""
    lots = np.asarray(lots, dtype=object)
    if len(lots) == 0:
        return np.zeros(0)
    edge = _access_edge(region, no_access)
    if shapely.is_empty(edge):
        return np.zeros(len(lots))
    band = shapely.buffer(street_band(edge, street_width, "flat"), 0.05, join_style="mitre")
    with np.errstate(invalid="ignore"):
        inside = shapely.intersection(shapely.boundary(lots), band)
    # a side leaving the street crosses the 5 cm band: to the decimetre, the rest is frontage
    return np.round(np.maximum(shapely.length(inside) - 0.2, 0.0), 2)


def _warp_distortion(regions, leaves, by_name, s: SplitSettings) -> float:
    """Sum of the warp energies of the row templates of ``leaves`` on ``regions``."""
    total = 0.0
    for reg, leaf in zip(regions, leaves):
        t = by_name.get(leaf[1])
        if t is None or t.kind != "rows":
            continue
        parts = _parcels._polygon_parts([shapely.buffer(reg, -s.street_width / 2,
                                                        join_style="mitre")], 1.0)
        warp = _templates.warp_rows(parts[0], t, s.parcel_length, s.parcel_width, None,
                                    cut=False) if len(parts) == 1 else None
        total += warp.energy if warp is not None else 1.0
    return total


def _rows_energy(part, t, s: SplitSettings, near=None) -> float:
    """Warp energy of the row template ``t`` on a net block ``part`` (inf when it does not
    fit). Edge labels (Yang Fig. 4): a double strip needs a street on both long sides, a
    strip on one; a side mostly inside ``near`` (where a side gives no access: along a
    no-street edge or a motorway; None: everywhere access) is no street."""
    warp = _templates.warp_rows(part, t, s.parcel_length, s.parcel_width, None, cut=False)
    if warp is None:
        return math.inf
    if near is not None and \
            sum(_street_share(side, near) > 0.5 for side in warp.long_sides) < t.rows:
        return math.inf
    return warp.energy


def _street_share(side, near) -> float:
    """Share of a block side (of the net block) that lies along an access street: outside
    ``near``, the area where a side gives no access."""
    line = shapely.LineString(side)
    if line.length <= 0:
        return 0.0
    with np.errstate(invalid="ignore"):
        return 1.0 - shapely.length(shapely.intersection(line, near)) / line.length


def _union(*geoms):
    """Union of the geometries that are not None (None when all are)."""
    geoms = [g for g in geoms if g is not None]
    return shapely.union_all(geoms) if geoms else None


def no_street_joints(leaves, split_lines, roads, splitter, by_name, s: SplitSettings):
    """Pieces of split streets that become "no street" edges (``SplitSettings.back_to_back``).

    Yang et al. 2013 label template edges "street", "no street" or unconstrained (sec. 4.1,
    Fig. 4): parcel rows need a street only on their front; their rear lot lines and the
    ends of a row may meet other parcels. The split streets are noded with the fixed roads;
    the pieces between the same two blocks are dropped together, and kept as a "no street"
    edge between them, when

    * both blocks along it are row templates (parcel strip or double strip) or parks,
    * each row template still fits its block without the street, labels included
      (:meth:`_Splitter.row_energy`: its lots take the street's half of the land; a
      parcel strip needs a street on its other long side, a double strip on both: two
      parcel strips end up back to back along their rear lot lines, row templates end to
      end, a parcel strip backs onto a park), with an energy under the threshold or no
      higher than before,
    * a park keeps a street along at least a parcel width of its outline (a park the
      layout left in a small region stays public; a park no street reaches would be a
      private one, which only a drawn template makes),
    * no street is left ending there (no dead end is made), and
    * the blocks it joins have a centre-line perimeter of at most that of the longest row
      template: 2 (max_columns x parcel width + 2 parcel lengths + street width), 1,230 m
      with the paper's parcels (sec. 7: a block too long "will take too long to walk (or
      drive) around"; Table 1, "Our": b_max 955-1,454 m).

    Pairs of blocks are tried longest joint first. Then the streets that those joints ran
    through: where the blocks on one side of a street were joined, the "no street" edge
    meets it at a node of two pieces, each between another pair of blocks, and either
    piece dropped alone would leave the other ending there (refused above, though no
    block needs either). The pieces along such a street, up to nodes where it meets
    other streets, are dropped together under the same rules (every block along it keeps
    its template and access, the joined block within the limit): no dead end is made.
    Returns (split street pieces kept, "no street" lines, street block number per leaf:
    leaves joined by a "no street" edge share one).
    """
    regions = np.array([leaf[0] for leaf in leaves], dtype=object)
    names = [leaf[1] for leaf in leaves]
    rows = [t for t in by_name.values() if t.kind == "rows"]

    def is_rows(k):
        return names[k] in by_name and by_name[names[k]].kind == "rows"

    def is_park(k):
        return names[k] == "park" or (names[k] in by_name and by_name[names[k]].kind == "park")
    if len(split_lines) == 0 or len(regions) < 2 or not rows:
        return list(split_lines), [], np.arange(len(regions))
    limit = 2 * (max(t.max_columns for t in rows) * s.parcel_width + 2 * s.parcel_length
                 + s.street_width)
    roads = list(roads)
    pieces = noded(roads + list(split_lines))
    pieces = pieces[shapely.length(pieces) > 0]
    mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    is_split = ~shapely.dwithin(shapely.union_all(np.asarray(roads, dtype=object)), mid,
                                10 * NODING_GRID) if roads else np.ones(len(pieces), bool)
    xy = np.vstack([shapely.get_coordinates(shapely.get_point(pieces, 0)),
                    shapely.get_coordinates(shapely.get_point(pieces, -1))])
    _, node = np.unique(np.round(xy / NODING_GRID).astype(np.int64), axis=0,
                        return_inverse=True)
    node = node.ravel().reshape(2, -1).T              # (piece, end) -> node id
    degree = np.bincount(node.ravel())
    leaf_tree = shapely.STRtree(regions)
    joined = DisjointSet(range(len(regions)))
    # the street block number of each set of joined leaves, at its root: a joined block keeps
    # the number of its lower leaf's block (the street blocks are listed in number order)
    number = np.arange(len(regions))
    no_street, no_frontage = splitter.no_street, splitter.no_frontage
    energy = {}
    removed = np.zeros(len(pieces), dtype=bool)
    # the pieces between the same two row-template blocks: one candidate
    between: Dict[tuple, list] = {}
    for i in np.flatnonzero(is_split):
        near = leaf_tree.query(pieces[i], predicate="dwithin", distance=0.05)
        with np.errstate(invalid="ignore"):
            shared = shapely.length(shapely.intersection(
                shapely.boundary(regions[near]),
                shapely.buffer(pieces[i], 0.05, cap_style="flat")))
        adj = near[shared > 0.5 * shapely.length(pieces[i])]
        if len(adj) == 2 and all(is_rows(a) or is_park(a) for a in adj):
            between.setdefault(tuple(sorted(int(a) for a in adj)), []).append(int(i))
    order = sorted(between, key=lambda k: -shapely.length(pieces[between[k]]).sum())
    group_of = {i: pair for pair, ids in between.items() for i in ids}
    at_node: Dict[int, list] = {}
    for i, (n0, n1) in enumerate(node):
        at_node.setdefault(int(n0), []).append(i)
        at_node.setdefault(int(n1), []).append(i)

    def degree_without(ids) -> np.ndarray:
        """Node degrees with the pieces ``ids`` dropped."""
        left = degree.copy()
        np.subtract.at(left, node[ids].ravel(), 1)
        return left

    def join(pairs) -> bool:
        """Drop the pieces between the pairs of blocks ``pairs`` together when the rules
        allow it (see above); whether they were dropped."""
        nonlocal degree, no_street, no_frontage
        ids = np.concatenate([between[p] for p in pairs])
        adj = sorted({a for p in pairs for a in p})
        left = degree_without(ids)
        if (left[node[ids].ravel()] == 1).any():
            return False  # a street would end there: no dead end is made
        line = shapely.line_merge(shapely.union_all(pieces[ids]))
        members = sorted(set().union(*(joined.subset(a) for a in adj)))
        if shapely.length(shapely.boundary(shapely.union_all(regions[members]))) > limit:
            return False
        trial_ns, trial_nf = _union(no_street, line), _union(no_frontage, line)
        after = {}
        for a in adj:
            if is_park(a):
                if not _reached_by_street(regions[a], trial_ns, trial_nf, s.parcel_width):
                    return False
                continue
            t = by_name[names[a]]
            if a not in energy:
                energy[a] = splitter.row_energy(regions[a], t, no_street, no_frontage)
            after[a] = splitter.row_energy(regions[a], t, trial_ns, trial_nf)
            if not (after[a] < s.energy_threshold or after[a] <= energy[a]):
                return False
        removed[ids] = True
        degree = left
        no_street, no_frontage = trial_ns, trial_nf
        energy.update(after)
        block_number = number[joined[pairs[0][0]]]
        for p in pairs:
            joined.merge(*p)
        number[joined[pairs[0][0]]] = block_number
        return True

    def street_through(pair):
        """The pairs of blocks along the street that the pieces of ``pair`` belong to: the
        pair itself and, while dropping them would leave a street ending at a node, the
        pair of the piece that would end there (a street whose blocks on one side changed
        at a joint dropped before runs on through that node); None when a piece that
        would end there is no candidate (a fixed road, or a street along another block)."""
        pairs = [pair]
        while True:
            ids = np.concatenate([between[p] for p in pairs])
            left = degree_without(ids)
            ends = [n for n in np.unique(node[ids].ravel()) if left[n] == 1]
            if not ends:
                return pairs
            taken = set(ids.tolist())
            for n in ends:
                rest = [j for j in at_node[int(n)] if not removed[j] and j not in taken]
                if len(rest) != 1 or rest[0] not in group_of:
                    return None
                if group_of[rest[0]] not in pairs:  # (two ends may lead to one pair)
                    pairs.append(group_of[rest[0]])

    for pair in order:
        join([pair])
    # a street run through by joints dropped before it: its pieces between different pairs
    # of blocks, each of which alone would leave the rest of the street ending there
    # (refused above), are dropped together when every block along it allows it; a street
    # dropped so can leave others running through a node of two pieces: until none is left
    changed = True
    while changed:
        changed = False
        for pair in order:
            if removed[between[pair][0]]:
                continue
            pairs = street_through(pair)
            if pairs is not None and len(pairs) > 1 and join(pairs):
                changed = True
    block = number[[joined[k] for k in range(len(regions))]]
    return list(pieces[is_split & ~removed]), list(pieces[removed]), block


def _reached_by_street(region, no_street, no_frontage, length: float) -> bool:
    """Whether at least ``length`` (m) of the region's outline is a street that gives
    access: not on a "no street" edge, not along a motorway."""
    return shapely.length(_access_edge(region, no_street, no_frontage)) >= length


def _access_edge(region, *no_access):
    """The region's outline less the lines that give no access (no-street edges,
    motorways); one that lies within :data:`_ON_OUTLINE` of the outline runs along it."""
    edge = shapely.boundary(region)
    with np.errstate(invalid="ignore"):
        for lines in no_access:
            if lines is not None:
                edge = shapely.difference(
                    edge, shapely.buffer(_near(lines, region, 1.0), _ON_OUTLINE))
    return edge


def _near(lines, region, margin: float):
    """The parts of ``lines`` whose bounds come within ``margin`` (m) of the region's: the
    no-street edges are one geometry for the whole town, and buffering all of it for each
    region was about a fifth of the split's time; without the parts far away the buffer
    near it is the same but for the last digits of its overlay."""
    parts = shapely.get_parts(lines)
    x0, y0, x1, y1 = shapely.bounds(region)
    b = shapely.bounds(parts)
    close = (b[:, 0] <= x1 + margin) & (b[:, 2] >= x0 - margin) & \
        (b[:, 1] <= y1 + margin) & (b[:, 3] >= y0 - margin)
    if close.all():
        return lines
    return shapely.geometrycollections(parts[close])


def _end_dirs(lines) -> np.ndarray:
    """Street ends (x, y, outward unit direction) of lines."""
    out = []
    for g in lines:
        xy = shapely.get_coordinates(g)
        if len(xy) < 2:
            continue
        for p, q in ((xy[0], xy[1]), (xy[-1], xy[-2])):
            out.append(np.r_[p, unit(p - q)])
    return np.asarray(out) if out else np.zeros((0, 4))


# --------------------------------------------------------------------------- main API

def split_domain(region, key_roads=None, key_areas=None, key_area_use=None,
                 templates: Optional[Sequence] = None, key_road_classes=None,
                 settings: Optional[SplitSettings] = None, seed: int = 0, variation: int = 1,
                 progress: Optional[Progress] = None) -> Layout:
    """One street and parcel layout of a region (see module doc).

    Parameters
    ----------
    region : polygons (metric CRS), holes allowed
    key_roads : lines, optional
        Main roads the layout keeps (they split the region).
    key_areas : polygons, optional
        Parks, schools, lakes: excluded from the splitting, kept as parcels.
    key_area_use : labels per key area, optional (default 'park')
    key_road_classes : OSM highway class per key road, optional
        Key roads of a :data:`LIMITED_ACCESS` class (motorways) take no junction and give
        no frontage.
    templates : list of :class:`templates.Template`, optional (default: the shipped library)
    settings : SplitSettings
    seed, variation : int
        The layout draws from ``default_rng([seed, variation])``.
    progress : Progress, optional

    Returns
    -------
    Layout

    Examples
    --------
    >>> import shapely
    >>> lay = split_domain([shapely.box(0, 0, 300, 200)], seed=1)
    >>> bool(lay.table.has_street_access[lay.table.land_use == "residential"].all())
    True
    """
    progress = ensure(progress)
    s = (settings or SplitSettings()).validate()
    if seed is None or int(seed) != seed or seed < 0:
        raise InputError(f"the seed must be a whole number >= 0 (got {seed})")
    # the layout is planar: the inputs' heights (Z) are dropped (a cadastre exported in 3D)
    region, key_roads, key_areas = (
        None if g is None else shapely.force_2d(np.asarray(g, dtype=object).ravel())
        for g in (region, key_roads, key_areas))
    lib = list(templates) if templates is not None else _templates.load_library()
    if not any(t.kind in ("rows", "spike", "loop", "drawn") for t in lib):
        raise InputError("the templates hold no parcel template")
    # the built-in spike and loop are drawn templates at this layout's parcel size
    lib = [_templates.built_in_drawn(t, s.parcel_length, s.parcel_width, s.street_width)
           for t in lib]
    rng = np.random.default_rng([int(seed), int(variation)])
    # no row of parcels fits between the outline street and a key road nearer than this
    rows_depth = _shallowest_rows(lib, s.parcel_length)
    if not math.isfinite(rows_depth):
        rows_depth = s.parcel_length
    faces, fixed, fixed_kinds, key_polys, key_uses, domain, no_access = prepare_domain(
        region, key_roads, key_areas, s.street_width, key_road_classes,
        outline_streets=s.outline_streets, beside_reach=s.street_width + rows_depth,
        key_area_use=key_area_use)
    work_area = float(shapely.area(domain))
    L, W, S = s.parcel_length, s.parcel_width, s.street_width
    splitter = _Splitter(lib, s, rng)
    by_name = {t.name: t for t in lib}

    # ---- hierarchical splitting with backtracking
    t0 = time.perf_counter()
    splitter.no_access = no_access
    # the key roads as fixed (their dangles continued) and as given, also just outside the
    # region (where its outline is no street)
    keys = fixed[np.isin(fixed_kinds, ("key", "limited"))]
    if key_roads is not None and len(key_roads):
        raw = _key_lines(key_roads)
        near = shapely.buffer(domain, 2 * _invariants.CORRIDOR_HALF_WIDTH)
        with np.errstate(invalid="ignore"):
            raw = shapely.intersection(raw[shapely.intersects(raw, near)], near)
        keys = np.concatenate([keys, raw[~shapely.is_empty(raw)]])
    splitter.key_corridor = _invariants.corridor_of(keys) if len(keys) else None
    edges = fixed[fixed_kinds == "edge"]
    splitter.no_street = shapely.union_all(edges) if len(edges) else None
    blocked = [g for g in (no_access, splitter.no_street) if g is not None]
    splitter.no_frontage = shapely.union_all(blocked) if blocked else None
    # templates with a minimum count (Yang's k2): the randomized search is repeated until
    # every minimum is met, each time with the probability of the templates still short
    # doubled (at most MIN_COUNT_ATTEMPTS times; the attempt short of the fewest
    # templates, then with the least fallback area, is kept)
    attempts = MIN_COUNT_ATTEMPTS if any(t.min_count for t in lib) else 1
    best, boost = None, Counter()
    for attempt in range(1, attempts + 1):
        # each search reports up to 0.6 of its share: the searches' shares follow each other
        start = 0.6 * (attempt - 1) / attempts
        factors = {n: 2.0 ** k for n, k in boost.items()}
        splitter.use_boost(factors)
        search = _Search(splitter, by_name, s, work_area,
                         progress.sub(start, start + 1.0 / attempts), boost=factors)
        leaves: List[list] = []  # [region, template name or RULE_BASED / 'park', energies]
        split_lines: List[shapely.LineString] = []
        fallback = 0.0
        ends = _end_dirs(fixed[fixed_kinds == "key"])
        for face in faces:
            got_leaves, got_lines, bad = search.fill(face, ends, 0)
            leaves += got_leaves
            split_lines += got_lines
            fallback += bad
            ends = np.vstack([ends, _end_dirs(got_lines)])
        short = sum(max(0, t.min_count - search.counts[t.name]) for t in lib)
        boost.update(t.name for t in lib if search.counts[t.name] < t.min_count)
        if best is None or (short, fallback) < best[0]:
            best = ((short, fallback), search, leaves, split_lines, attempt)
        if short == 0:
            break
    (n_short, _), search, leaves, split_lines, _ = best
    if split_lines:
        # a split street ends on its parent's outline only up to round-off (the outline is
        # a face of a snap-rounded arrangement, 1e-6 .. 3e-5 m off the line it came from):
        # its end becomes a vertex of the line it meets, so that every later noding
        # (global optimisation, road network) sees the junction (no false dead end, and
        # the blocks of the road mesh are the leaves)
        snapped = snap_ends_onto_lines(list(fixed) + split_lines,
                                       np.r_[np.zeros(len(fixed), bool),
                                             np.ones(len(split_lines), bool)])
        fixed = np.asarray(list(snapped[:len(fixed)]), dtype=object)
        split_lines = list(snapped[len(fixed):])
    n_done = search.n_regions
    n_backtracked = search.n_backtracks
    t_back = search.time_abandoned
    t_split = time.perf_counter() - t0 - t_back
    progress.step(0.6)

    # ---- global optimisation of the road mesh
    t0 = time.perf_counter()
    opt_stats = {"iterations": 0, "shape_before": 0.0, "shape_after": 0.0, "reverted": False}
    if s.optimise and split_lines:
        leaf_regions = np.array([leaf[0] for leaf in leaves], dtype=object)
        tree = shapely.STRtree(leaf_regions)
        leaf_width = np.array([by_name[leaf[1]].gross_depth(L, S) if leaf[1] in by_name and
                               by_name[leaf[1]].kind == "rows" else np.nan for leaf in leaves])

        def face_width(face):
            hit = tree.query(shapely.point_on_surface(face), predicate="within")
            return float(leaf_width[hit[0]]) if len(hit) else float("nan")

        # vertices every third of a parcel: a curved street bends by a few degrees per
        # vertex, not by the 10-20° that a parcel corner rule would count as a corner
        new_lines, opt_stats = optimise_roads(split_lines, fixed, face_width,
                                              spacing=min(L, W) / 3.0)
        if opt_stats["iterations"]:
            new_faces = _faces(list(fixed) + list(new_lines), shapely.difference(
                domain, shapely.union_all(key_polys)) if len(key_polys) else domain)
            # every new block inherits the template of the old block it overlaps most
            fi, li = tree.query(new_faces, predicate="intersects")
            with np.errstate(invalid="ignore"):
                share = shapely.area(shapely.intersection(new_faces[fi], leaf_regions[li]))
            owner = np.full(len(new_faces), -1)
            best = np.zeros(len(new_faces))
            for f, leaf, a in zip(fi, li, share):
                if a > best[f]:
                    owner[f], best[f] = leaf, a
            # a leaf may be two faces of the arrangement (a key road ending inside it, a
            # street of a neighbour closing that slit): its faces are put together again
            if (owner >= 0).all() and sorted(set(owner.tolist())) == list(range(len(leaves))):
                # the optimisation is kept when it lowers what it is for: the distortion of
                # the template warps (Yang sec. 6), summed over the row-template blocks
                moved = [shapely.union_all(new_faces[owner == o]) for o in range(len(leaves))]
                moved = [m if m.geom_type == "Polygon" else leaves[o][0]
                         for o, m in enumerate(moved)]
                before = _warp_distortion([leaf[0] for leaf in leaves], leaves, by_name, s)
                after = _warp_distortion(moved, leaves, by_name, s)
                opt_stats["warp_energy_before"], opt_stats["warp_energy_after"] = before, after
                opt_stats["kept"] = bool(after < before)
                if after < before:
                    for o, face in enumerate(moved):
                        leaves[o][0] = face
                    split_lines = list(new_lines)
            else:
                opt_stats["reverted"] = True
                opt_stats["relabel_failed"] = True
    t_opt = time.perf_counter() - t0
    # ---- "no street" joints: rows back to back or end to end where no street is needed
    n_joints = 0
    street_blocks = None
    if s.back_to_back and split_lines:
        split_lines, joints, block_of = no_street_joints(
            leaves, split_lines, fixed[fixed_kinds != "edge"], splitter, by_name, s)
        if joints:
            # the blocks of the street network: leaves joined by a "no street" edge are one
            street_blocks = np.array([shapely.union_all([leaf[0] for leaf, b in
                                                         zip(leaves, block_of) if b == k])
                                      for k in np.unique(block_of)], dtype=object)
            n_joints = len(joints)
            fixed = np.asarray(list(fixed) + joints, dtype=object)
            fixed_kinds = np.asarray(list(fixed_kinds) + ["edge"] * n_joints)
            splitter.no_street = _union(splitter.no_street, *joints)
            splitter.no_frontage = _union(splitter.no_frontage, *joints)
    progress.step(0.7)

    # ---- templates warped onto the blocks: parcels
    lots_all, use_all, tmpl_all, front_all = [], [], [], []
    template_roads = []
    key_road_zone = None
    key_lines = fixed[fixed_kinds == "key"]
    if len(key_lines):
        key_road_zone = shapely.buffer(shapely.union_all(key_lines), S / 2, cap_style="flat")
    lot_settings = _parcels.SubdivisionSettings(
        max_area=1.6 * L * W, min_area=0.3 * L * W, min_width=0.4 * W, lot_width=W,
        irregularity=0.0, options={"pin_cuts_to_corners": CUT_TO_CORNER * W,
                                    "cut_across_longest_side": True})
    n_inner = n_pocket = n_settled = 0
    for k, (reg, name, _) in enumerate(leaves):
        progress.step(0.7 + 0.25 * k / max(len(leaves), 1))
        shrunk = net_block(reg, S, splitter.no_street)
        if key_road_zone is not None:
            shrunk = shapely.difference(shrunk, key_road_zone)
        for part in _parcels._polygon_parts([shrunk], 1.0):
            lots, kind, own_street, green = _lots_for(part, reg, name, by_name, s,
                                                      lot_settings, rng, template_roads,
                                                      splitter.entrance_ok,
                                                      splitter.no_frontage)
            if kind == "park" or (green is not None and green.all()):
                lots_all.append(lots)
                use_all += ["park"] * len(lots)
                tmpl_all += [name] * len(lots)
                front_all.append(np.full(len(lots), np.nan))
                continue
            if green is not None and green.any():
                # a drawn template's parks (a private park) stay parks, as drawn
                lots_all.append(lots[green])
                use_all += ["park"] * int(green.sum())
                tmpl_all += [kind] * int(green.sum())
                front_all.append(np.full(int(green.sum()), np.nan))
                lots = lots[~green]
            def frontage(lots_, reg=reg, own=own_street):
                """Frontage on the region's streets and on the template's own streets (the
                edge of their warped surface)."""
                front_ = access_frontage(lots_, reg, S, splitter.no_frontage)
                if own is not None:
                    band = shapely.buffer(own, 0.05, join_style="mitre")
                    with np.errstate(invalid="ignore"):
                        inner_ = shapely.length(shapely.intersection(
                            shapely.boundary(lots_), band))
                    front_ = front_ + np.round(np.maximum(inner_ - 0.2, 0.0), 2)
                return front_

            front = frontage(lots)
            # lots without frontage and crumbs join their neighbour (parcelling: every lot
            # needs street access and a useful size); with the optional repair, small
            # misshapen end lots too (the triangle left where a strip meets a slanted street)
            area = shapely.area(lots)
            bad = (front < _parcels.MIN_FRONTAGE) | (area < 0.25 * L * W)
            if s.repair_lots:
                bad |= _parcels.lot_quality(lots)[2] & (area < 0.6 * L * W)
            if bad.any() and len(lots) > 1:
                lots = _parcels._polygon_parts(_parcels.merge_into_neighbours(lots, bad)[0])
                front = frontage(lots)
            if s.settle_joints and len(lots) > 1:
                # each joint where its two lots are squarest (a discrete regression)
                lots, front, moved = settle_joints(lots, front, frontage,
                                                   lot_settings.min_area, lot_settings.min_width)
                n_settled += moved
            remnant = np.zeros(len(lots), dtype=bool)
            if s.repair_lots:
                lots, front, remnant = repair_lots(lots, front, part, L, W)
            # a lot still without frontage (all its neighbours were merged away) is kept as
            # a green inside the block, as the paper's template with a private park
            cut_off = front < _parcels.MIN_FRONTAGE
            inner = cut_off | remnant
            n_inner += int(cut_off.sum())
            n_pocket += int((remnant & ~cut_off).sum())
            lots_all.append(lots)
            use_all += ["park" if i else "residential" for i in inner]
            tmpl_all += [kind] * len(lots)
            front_all.append(front)
    # key areas are parcels of their own use
    if len(key_polys):
        lots_all.append(key_polys)
        use_all += list(key_uses)
        tmpl_all += ["key_area"] * len(key_polys)
        front_all.append(np.full(len(key_polys), np.nan))
    geoms = np.concatenate(lots_all) if lots_all else np.empty(0, dtype=object)
    front = np.concatenate(front_all) if front_all else np.zeros(0)
    # drop vertices within a centimetre of their neighbours' line: the sub-centimetre
    # spikes and slivers of the overlays would make a parcel invalid once reprojected
    geoms = shapely.simplify(geoms, _OUTPUT_GRID, preserve_topology=True)
    keep = ~shapely.is_empty(geoms) & shapely.is_valid(geoms)
    geoms, front = geoms[keep], front[keep]
    use_all = [u for u, k in zip(use_all, keep) if k]
    tmpl_all = [t for t, k in zip(tmpl_all, keep) if k]
    p_angle, p_area, bad = _parcels.lot_quality(geoms)
    use = np.asarray(use_all, dtype=object)
    residential = use == "residential"
    table = pd.DataFrame({
        "parcel_id": np.arange(1, len(geoms) + 1), "variation": int(variation),
        "land_use": use, "template": np.asarray(tmpl_all, dtype=object),
        "area_m2": shapely.area(geoms), "frontage_m": front,
        "has_street_access": np.where(residential, np.nan_to_num(front) >= _parcels.MIN_FRONTAGE,
                                      False),
        # Yang's shape flag on every parcel (a green wedge is flagged too: honest styling)
        "p_angle": p_angle, "p_area": p_area, "undesirable": bad})

    # roads
    is_road = fixed_kinds != "edge"  # a no-street edge is no road
    roads = list(fixed[is_road]) + list(split_lines) + [g for g, _ in template_roads]
    level = [LEVEL_KEY if k in ("key", "limited") else LEVEL_OUTLINE
             for k in fixed_kinds[is_road]] + \
        [LEVEL_SPLIT] * len(split_lines) + [LEVEL_TEMPLATE] * len(template_roads)
    kind = [str(k) for k in fixed_kinds[is_road]] + ["split"] * len(split_lines) + \
        [k for _, k in template_roads]
    n_beside = 0
    if key_roads is not None and len(key_roads):
        roads, level, kind, n_beside = _outline_onto_key_roads(roads, level, kind, key_roads)
    roads, level, kind, n_stubs = road_network(roads, level, kind)
    if key_roads is not None and len(key_roads):
        # after the noding, which merges lines through their shared ends again
        roads, level, kind = _cut_continuations(roads, level, kind, key_roads)
    roads, level, kind, n_short = _ended_short_of_limited_access(
        np.asarray(roads, dtype=object), np.asarray(level), np.asarray(kind, dtype=object),
        [] if key_roads is None else key_roads)
    stats = {
        "n_regions": n_done, "n_splits": splitter.n_split, "n_rejected_splits": splitter.n_rejected,
        "n_backtracked": n_backtracked, "n_blocks": len(leaves),
        "search_attempts": attempt, "min_count_short": int(n_short),
        "n_no_access_rejected": splitter.n_no_access, "n_stubs_dropped": n_stubs,
        "n_outline_beside_key_roads": n_beside, "n_ended_short_of_motorways": n_short,
        "templates": dict(Counter(leaf[1] for leaf in leaves)),
        "n_parcels": int(residential.sum()),
        "n_no_access": int((residential & ~table.has_street_access.to_numpy(bool)).sum()),
        "n_inner_parks": n_inner, "n_pocket_parks": n_pocket, "n_no_street_joints": n_joints,
        "n_joints_settled": n_settled,
        "time_split_s": t_split, "time_backtrack_s": t_back, "time_optimise_s": t_opt,
        "optimisation": opt_stats,
    }
    progress.step(1.0)
    return Layout(np.asarray(roads, dtype=object), np.asarray(level), np.asarray(kind, dtype=object),
                  np.array([leaf[0] for leaf in leaves], dtype=object),
                  np.array([leaf[1] for leaf in leaves], dtype=object), geoms, table, domain, stats,
                  street_blocks)


def _front_rectangle(lot, street, L: float, W: float):
    """The largest rectangle of a lot standing on one of its (four longest) street edges,
    depth 0.4-1.2 L, width >= 0.6 W, or None."""
    xy = shapely.get_coordinates(shapely.geometry.polygon.orient(lot).exterior)
    seg = np.diff(xy, axis=0)
    length = np.hypot(*seg.T)
    mids = shapely.points(xy[:-1] + seg / 2)
    on_street = shapely.dwithin(mids, shapely.boundary(street), 0.05) & (length > 0.3 * W)
    best, best_area = None, 0.0
    for k in np.argsort(-np.where(on_street, length, -1))[:4]:
        if not on_street[k]:
            break
        u = seg[k] / length[k]
        nrm = np.array([-u[1], u[0]])  # counter-clockwise ring: the lot lies to the left
        local = np.c_[(xy - xy[k]) @ u, (xy - xy[k]) @ nrm]
        lot_l = shapely.Polygon(local)
        lo, hi = local[:, 0].min() - 1, local[:, 0].max() + 1
        mid = 0.5 * length[k]
        for d in np.linspace(0.4 * L, 1.2 * L, 9):
            if d > local[:, 1].max():
                break
            x0, x1 = 0.0, length[k]  # the base: the street edge itself
            with np.errstate(invalid="ignore"):
                cut = shapely.get_parts(shapely.intersection(
                    lot_l, shapely.LineString([(lo, d), (hi, d)])))
            cut = [c for c in cut if c.geom_type == "LineString"]
            span = [shapely.get_coordinates(c)[:, 0] for c in cut]
            span = [(c.min(), c.max()) for c in span if c.min() <= mid <= c.max()]
            if not span:
                continue
            x0, x1 = max(x0, span[0][0]), min(x1, span[0][1])
            if x1 - x0 >= 0.6 * W and (x1 - x0) * d > best_area:
                best, best_area = (xy[k], u, nrm, (x0, 0.0, x1, d)), (x1 - x0) * d
    if best is None:
        return None
    origin, u, nrm, box = best
    corners = shapely.get_coordinates(shapely.box(*box))
    rect = shapely.Polygon(origin + corners[:, :1] * u + corners[:, 1:] * nrm)
    rect = shapely.intersection(rect, lot)  # exact shared outline, no slivers outside
    # the sides must not cross the lot's outline (a non-convex lot between base and top)
    ok = rect.geom_type == "Polygon" and rect.area > 0.99 * best_area
    return rect if ok else None


def repair_lots(lots, front, street, L: float, W: float):
    """The optional lot repair (``SplitSettings.repair_lots``; off by default).

    Not in Yang et al. 2013: a cosmetic post-process of the undesirable lots (Fig. 12
    test). A misshapen lot of at least 0.6 template parcels keeps the largest rectangle
    standing on its street edge (:func:`_front_rectangle`) and its wedges become pocket
    parks; an undesirable lot smaller than a template parcel becomes a pocket park. The
    parks are counted by :func:`table1` (p_angle and p_area over every designed parcel),
    so the repair cannot hide a bad lot, only turn it into a park.

    Returns (lots, frontage, park flag per lot).
    """
    area = shapely.area(lots)
    bad = _parcels.lot_quality(lots)[2]
    remnant = bad & (area < 1.0 * L * W)
    fixable = bad & (area >= 0.6 * L * W) & (front >= _parcels.MIN_FRONTAGE)
    if fixable.any():
        return _rectify(lots, front, remnant, fixable, street, L, W)
    return lots, front, remnant


def _rectify(lots, front, remnant, which, street, L: float, W: float):
    """Undesirable lots (triangles and wedges where streets meet at acute angles or a strip
    ends on a slanted street) keep the rectangle standing on their street edge when it is
    at least 0.45 of a template parcel; the rest becomes green unless it is itself a good
    parcel with frontage."""
    out, out_green = [], []
    for i, lot in enumerate(lots):
        rect = _front_rectangle(lot, street, L, W) if which[i] else None
        if rect is None or rect.area < 0.45 * L * W:
            out.append(lot)
            out_green.append(remnant[i])
            continue
        # the wedges are shrunk by 2 cm: that drops the zero-width float-noise slivers
        # along the rectangle's sides and parts them where they only touch at the
        # rectangle's corners (a pinched ring turns invalid once reprojected)
        rest = shapely.buffer(shapely.difference(lot, rect), -0.02, join_style="mitre")
        rest = _parcels._polygon_parts([rest], 1.0)
        rest = rest[~shapely.is_empty(shapely.buffer(rest, -0.25, join_style="mitre"))]
        ok = np.zeros(len(rest), dtype=bool)
        if len(rest):
            good = ~_parcels.lot_quality(rest)[2] & (shapely.area(rest) >= 0.5 * L * W)
            ok = good & (_parcels.street_frontage(rest, street) >= _parcels.MIN_FRONTAGE)
        out += [rect] + list(rest)
        out_green += [False] + list(~ok)
    out = np.asarray(out, dtype=object)
    return out, _parcels.street_frontage(out, street), np.asarray(out_green, dtype=bool)


def _fallback(region, energies, by_name, s: SplitSettings) -> str:
    """Rule-based assignment of a region no template matches and no streamline splits:
    the nearest row template when its energy is within twice the threshold (the warp
    absorbs the distortion), else a park when it holds fewer than six parcels, else
    rule-based parcels (``fallback_parcels``)."""
    rows = [(e, n) for n, e in energies.items() if by_name[n].kind == "rows" and np.isfinite(e)]
    if rows and min(rows)[0] < 2 * s.energy_threshold:
        return min(rows)[1]
    if shapely.area(region) < 6 * s.parcel_length * s.parcel_width:
        return "park"
    return RULE_BASED


def _onto_outline(line, part, reg, street: float):
    """``line`` with each end on the block part's edge carried straight on to the region's
    outline (the centre line of the street around the block), at most a street width."""
    xy = shapely.get_coordinates(line)
    edge, outline = shapely.boundary(part), shapely.boundary(reg)
    for end in (0, -1):
        if len(xy) < 2 or shapely.distance(shapely.Point(xy[end]), edge) > 1.0:
            continue
        foot = _templates.end_ray_hit(xy, end, outline, 2 * street)
        if foot is not None:
            xy = np.vstack([foot, xy]) if end == 0 else np.vstack([xy, foot])
    return shapely.LineString(xy)


def _lots_for(part, reg, name, by_name, s: SplitSettings, lot_settings, rng, template_roads,
              entrance_ok=None, no_frontage=None):
    """Lots of one shrunk block part: (lots, template name, the surface of the template's
    own streets or None, park mask of the lots or None)."""
    L, W, S = s.parcel_length, s.parcel_width, s.street_width
    if name == "park" or shapely.area(part) < 0.5 * L * W:
        return np.array([part], dtype=object), "park", None, None
    t = by_name.get(name)
    if t is not None and t.kind == "rows":
        warped = _templates.warp_rows(part, t, L, W, rng)
        if warped is not None and len(warped.lots):
            return warped.lots, t.name, None, None
    if t is not None and t.kind == "drawn":
        warped = _templates.warp_drawn(part, t, entrance_ok=entrance_ok)
        if warped is not None and len(warped.lots):
            # the template's own streets run on from the block's edge to the street around
            # it (the region's outline, half a street width away)
            roads = [_onto_outline(r, part, reg, S) for r in warped.roads]
            kind = "loop" if any(r.is_ring for r in roads) else "cul_de_sac"
            template_roads += [(r, kind) for r in roads]
            lots, green = warped.lots, warped.green
            if warped.area is not None and warped.area.any():
                rows = [x for x in by_name.values() if x.kind == "rows"]
                lots, green = _fill_areas(lots, warped.area, green, part, warped.surface,
                                          rows, s, lot_settings, rng, no_frontage)
            return lots, t.name, warped.surface, green
    lots = _rule_based_lots(part, s, lot_settings, rng)
    return (lots if len(lots) else np.array([part], dtype=object)), s.fallback_parcels, \
        None, None


def _corner_deviations(lots):
    """Per lot: the sum of |corner angle - 90 deg| over its corners (Table 1's corners) and
    their number."""
    angles, owner = _metrics.corner_angles(lots)
    n = len(lots)
    return (np.bincount(owner, np.abs(angles - 90.0), minlength=n),
            np.bincount(owner, minlength=n))


#: Joints re-placed between two lots (:func:`settle_joints`): the shortest boundary two lots
#: share to count as neighbours along a joint (m; a touch at a corner is none).
JOINT_MIN_SHARED = 2.0
#: Where a joint may go: at these fractions of the pair's extent across the cut...
JOINT_POSITIONS = tuple(np.round(np.arange(0.25, 0.751, 0.05), 2))
#: ... parallel to the joint, turned off it by these angles (degrees), across the pair's
#: longest side and across its bounding rectangle's long axis.
JOINT_TURNS = (-10.0, -5.0, 5.0, 10.0)
#: A pair whose summed p_area excess ((p_area - 1) of both) is below this cannot gain
#: more than this and is not tried.
JOINT_MIN_EXCESS = 0.005


def settle_joints(lots, front, frontage, min_area: float = 0.0, min_width: float = 0.0,
                  max_rounds: int = 10):
    """Each joint between two lots of a block moved to where the two lots are squarest.

    Yang's warp (sec. 4.2) registers every parcel to its ideal shape and regresses the
    vertices two parcels share; where a row ends at a slanted side or a corner, the warp
    leaves an odd end piece (a wedge, a trapezoid of p_area 1.1-2) beside a squarer lot.
    Here the two lots' union is cut again by one straight joint: parallel to their shared
    joint or turned off it (:data:`JOINT_TURNS`), across the union's longest side or
    across its bounding rectangle, at :data:`JOINT_POSITIONS` of its extent. A new joint is
    taken where it lowers the pair's summed p_area (minimum rectangle / area, Yang sec. 7:
    the lots' mean, their number unchanged), does not raise their mean corner deviation
    (the corners it removes and adds against the lots' mean at the round's start), and
    leaves each piece between the pair's smaller and larger area (no lot smaller or
    larger than the two were), at least ``min_area`` and ``min_width`` wide, with street frontage
    (``frontage``: a function of lots). The best gains first, each lot once a round; later
    rounds try the pairs a new joint touched. No lot is merged, dropped or changes use.
    Not in the paper: a discrete regression of the joints by Table 1's measures.

    Returns the lots (as many as given), their frontage and how many joints moved.
    """
    lots = np.asarray(lots, dtype=object)
    front = np.asarray(front, dtype=float)
    changed = np.ones(len(lots), dtype=bool)
    moved = 0
    for _ in range(max_rounds):
        n = len(lots)
        if n < 2 or not changed.any():
            break
        area = shapely.area(lots)
        _, ratio, _ = _parcels.lot_quality(lots)
        usable = np.isfinite(ratio) & (np.nan_to_num(front) >= _parcels.MIN_FRONTAGE)
        dev, count = _corner_deviations(lots)
        mean_dev = dev.sum() / max(count.sum(), 1)
        i, j = shapely.STRtree(lots).query(lots, predicate="dwithin",
                                            distance=_parcels._SHARE_EPS)
        keep = (i < j) & usable[i] & usable[j] & (changed[i] | changed[j]) & \
            (ratio[i] + ratio[j] - 2.0 >= JOINT_MIN_EXCESS)
        i, j = i[keep], j[keep]
        if len(i):
            keep = _parcels._shared_length(lots[i], lots[j]) >= JOINT_MIN_SHARED
            i, j = i[keep], j[keep]
        if not len(i):
            break
        union = np.array([_parcels._clean_union([lots[a], lots[b]]) for a, b in zip(i, j)],
                         dtype=object)
        single = shapely.get_type_id(union) == 3
        i, j, union = i[single], j[single], union[single]
        k = len(i)
        if not k:
            break
        # the shared joint's direction: its two farthest points
        joint = shapely.intersection(shapely.boundary(lots[i]), shapely.boundary(lots[j]))
        xy, owner = shapely.get_coordinates(joint, return_index=True)
        across = np.zeros(k)
        for c in np.unique(owner):
            pts = xy[owner == c]
            d = pts[np.argmax(((pts - pts[0]) ** 2).sum(1))] - pts[0]
            across[c] = math.atan2(d[1], d[0]) + math.pi / 2
        longest, _ = _parcels._side_directions(union)
        _, _, axis = minimum_rectangles(union)
        directions = [across] + [across + math.radians(d) for d in JOINT_TURNS] + \
            [longest, np.radians(axis)]
        lo = np.minimum(area[i], area[j])
        hi = np.maximum(area[i], area[j])
        # every cut of every pair at once: candidate m is pair m % k
        n_cuts = len(directions) * len(JOINT_POSITIONS)
        angle = np.concatenate([d for d in directions for _ in JOINT_POSITIONS])
        t = np.repeat(np.tile(np.asarray(JOINT_POSITIONS, dtype=float), len(directions)), k)
        pair = np.tile(np.arange(k), n_cuts)
        m = len(pair)
        # only the cuts whose sides' areas may pass are cut (areas with the crumbs'
        # and round-off's slack; the test on the parts below decides)
        below, above = _parcels.cut_areas(union[pair], angle, t, np.zeros(m))
        slack = 1e-6 * (lo + hi)[pair] + 10 * _parcels._CRUMB
        sized = np.flatnonzero(
            (np.minimum(below, above) >= np.maximum(min_area, lo[pair]) - slack) &
            (np.maximum(below, above) <= hi[pair] + slack))
        if not len(sized):
            break
        parts, owner, beyond = _parcels._cut(union[pair[sized]], angle[sized], t[sized],
                                             np.zeros(len(sized)))
        owner = sized[owner]
        p_len, p_wid, _ = minimum_rectangles(parts)
        p_area = shapely.area(parts)
        p_ratio = p_len * p_wid / np.maximum(p_area, 1e-9)
        p_dev, p_count = _corner_deviations(parts)
        of = pair[owner]
        fine = (p_area >= np.maximum(min_area, lo[of] * (1 - 1e-9))) & \
            (p_area <= hi[of] * (1 + 1e-9)) & (p_wid >= min_width)
        ok = (np.bincount(owner, minlength=m) == 2) & \
            (np.bincount(owner, beyond, minlength=m) == 1) & \
            (np.bincount(owner, ~fine, minlength=m) == 0)
        gain = (ratio[i] + ratio[j])[pair] - np.bincount(owner, p_ratio, minlength=m)
        d_dev = np.bincount(owner, p_dev, minlength=m) - (dev[i] + dev[j])[pair]
        d_count = np.bincount(owner, p_count, minlength=m) - (count[i] + count[j])[pair]
        ok &= (gain > 1e-6) & (d_dev <= mean_dev * d_count + 1e-9)
        cand = np.flatnonzero(ok)
        if not len(cand):
            break
        cand_pair, cand_gain = pair[cand], gain[cand]
        mine = ok[owner]    # each candidate's two pieces, in candidate order
        pieces = parts[mine][np.argsort(owner[mine], kind="stable")].reshape(-1, 2)
        # frontage once for every candidate piece (one street band)
        f = np.asarray(frontage(pieces.ravel()), dtype=float).reshape(-1, 2)
        on_street = np.flatnonzero((f >= _parcels.MIN_FRONTAGE).all(axis=1))
        # each pair's best candidate that keeps both pieces on a street, the pairs by gain
        by_pair = on_street[np.lexsort((-cand_gain[on_street], cand_pair[on_street]))]
        best = by_pair[np.unique(cand_pair[by_pair], return_index=True)[1]]
        best = best[np.argsort(-cand_gain[best], kind="stable")]
        taken = np.zeros(n, dtype=bool)
        out, out_front = [], []
        for o in best:
            a, b = i[cand_pair[o]], j[cand_pair[o]]
            if taken[a] or taken[b]:
                continue
            taken[a] = taken[b] = True
            out += list(pieces[o])
            out_front += list(f[o])
        if not out:
            break
        moved += len(out) // 2
        lots = np.concatenate([np.asarray(out, dtype=object), lots[~taken]])
        front = np.r_[np.asarray(out_front, dtype=float), front[~taken]]
        changed = np.r_[np.ones(len(out), dtype=bool), np.zeros(int((~taken).sum()), bool)]
    return lots, front, moved


def _rule_based_lots(part, s: SplitSettings, lot_settings, rng) -> np.ndarray:
    """Lots of a region no template fits, by the subdivision method ``fallback_parcels``."""
    method = _parcels.METHODS[s.fallback_parcels]
    return _parcels._polygon_parts(method.subdivide(part, lot_settings, rng))


def _fill_areas(lots, area, green, part, surface, rows, s: SplitSettings, lot_settings, rng,
                no_frontage=None):
    """The area faces (label A) of a warped drawn template as regions of the next level
    (Yang Fig. 4, "regions labeled A ... can be replaced by level-two templates"): each is
    filled by the row template of least warp energy whose street sides agree (its rows'
    fronts on the street around the block or on the template's own street; within twice
    the selection threshold, as the fallback of the search), else given rule-based
    parcels (``fallback_parcels``). ``no_frontage``: the region's no-street edges and
    motorways, which give no frontage. Returns the lots and their park mask."""
    L, W, S = s.parcel_length, s.parcel_width, s.street_width
    streets = shapely.boundary(part) if surface is None else \
        shapely.union(shapely.boundary(part), shapely.boundary(surface))
    out, out_green = [], []
    for lot, is_area, is_green in zip(lots, area, green):
        if not is_area:
            out.append(lot)
            out_green.append(is_green)
            continue
        # where its parcels would front on no street: its own sides that are no street,
        # and the region's no-street edges and motorways (centre lines half a street off)
        near = shapely.buffer(shapely.difference(shapely.boundary(lot),
                                                 shapely.buffer(streets, 0.05)), 1.0)
        if no_frontage is not None:
            near = shapely.union(near, shapely.buffer(no_frontage, S / 2 + 1.0))
        energy, best = min(((_rows_energy(lot, t, s, near), i) for i, t in enumerate(rows)),
                           default=(math.inf, None))
        filled = _templates.warp_rows(lot, rows[best], L, W, rng) \
            if energy < 2 * s.energy_threshold else None
        pieces = filled.lots if filled is not None and len(filled.lots) else \
            _rule_based_lots(lot, s, lot_settings, rng)
        if not len(pieces):
            pieces = [lot]
        out += list(pieces)
        out_green += [False] * len(pieces)
    return np.asarray(out, dtype=object), np.asarray(out_green, dtype=bool)


def split_variations(region, variations: int = 1, seed: int = 0, progress=None,
                     **kwargs) -> List[Layout]:
    """``variations`` layouts of one region (variation v draws from ``[seed, v]``)."""
    progress = ensure(progress)
    if variations is None or int(variations) != variations or not 1 <= variations <= 100:
        raise InputError(f"the number of variations must be 1..100 (got {variations})")
    out = []
    for v in range(1, int(variations) + 1):
        out.append(split_domain(region, seed=seed, variation=v,
                                progress=progress.sub((v - 1) / variations, v / variations),
                                **kwargs))
    return out


def variation_summary(variation: int, stats: dict, table1: dict) -> str:
    """One line of the log on a variation: its splits, blocks, parcels and their quality
    (``table1``: :func:`table1`), and the steps' counts and times (``stats``:
    ``Layout.stats``)."""
    st, m, opt = stats, table1, stats["optimisation"]
    return (f"Variation {variation}: {st['n_splits']} streamline splits "
            f"({st['n_rejected_splits']} candidates rejected), {st['n_blocks']} blocks "
            f"(templates {st['templates']}), {st['n_parcels']} parcels, "
            f"{st['n_backtracked']} splits undone by backtracking; p_angle "
            f"{m['p_angle']:.2f}°, p_area {m['p_area']:.3f}, {m['undesirable']} "
            f"undesirable; {st['n_joints_settled']} joints settled; {st['n_no_access']} "
            f"parcels without street access ({st['n_inner_parks']} lots cut off from the "
            f"street kept as inner greens, {st['n_pocket_parks']} pocket parks from the "
            f"optional repair); {st['n_ended_short_of_motorways']} streets ended short of a "
            f"motorway; road mesh optimisation: {opt.get('iterations', 0)} iterations, "
            f"{'kept' if opt.get('kept') else 'not kept'} (it is kept when it lowers the "
            f"warp distortion); times split {st['time_split_s']:.1f} s, optimise "
            f"{st['time_optimise_s']:.1f} s.")


def unused_drawn_templates(templates: Sequence, layouts: Sequence[Layout]) -> List[str]:
    """A warning for each template warped as drawn (kind 'drawn', a user's drawing) that no
    layout used, naming it and its drawn size (its minimum rectangle, m).

    A drawn template takes a region within its ``width_scale`` of its length and its
    ``depth_scale`` of its depth and is not scaled to the parcel size: one drawn far larger
    or smaller than the layout's blocks fits no region, and the layout used the other
    templates or rule-based parcels without a word.
    """
    used = set()
    for lay in layouts:
        used |= set(lay.stats.get("templates", {}))
    out = []
    for t in templates:
        if t.kind == "drawn" and t.name not in used:
            length, depth, _ = minimum_rectangles([_templates.drawn_outline(t)])
            out.append(
                f"Drawn template '{t.name}' ({length[0]:,.0f} x {depth[0]:,.0f} m) was used in "
                f"no variation: a template warped as drawn takes only a block "
                f"{t.width_scale[0]:g}-{t.width_scale[1]:g} x its length and "
                f"{t.depth_scale[0]:g}-{t.depth_scale[1]:g} x its depth (the parcel sizes do "
                "not scale it), chosen by its warp energy: draw it at the size of the blocks "
                "it should fill.")
    return out


def table1(layout: Layout) -> Dict[str, float]:
    """The paper's Table 1 metrics of a layout (land use %, blocks, streets, parcels).

    Land use is over the whole region; block metrics over the centre-line blocks between
    streets (template blocks joined by a "no street" edge are one block); street
    densities over the noded road graph. The parcel metrics (p_n, p_angle, p_area,
    undesirable) count **every parcel the layout designed**, residential lots and parks
    alike (inner greens, pocket parks of the optional repair, park templates): a
    misshapen lot turned into a park still counts. Only the user's key areas (given, not
    designed) are left out. ``p_angle_residential`` / ``p_area_residential`` are the same
    over the residential lots alone.

    p_angle is the mean over all parcel corners of |angle - 90°| (Yang sec. 7); a vertex
    whose two edges turn by less than 10° (an angle above
    :data:`metrics.STRAIGHT_ANGLE` = 170°) is not a corner but a bend of a straight or
    curved side, and is left out (a lot along a curved street would otherwise count
    every vertex of its curve as a 0-10° "corner" and look better than it is, or, with
    the 170-180° deviation measured from 90°, far worse).
    """
    blocks = layout.street_blocks if layout.street_blocks is not None else layout.blocks

    def given(geoms):
        return geoms if geoms is not None and len(geoms) else None

    # a region too small for a lot has no parcels (and may have no street): its figures
    # are NaN, not an error about an empty layer
    res = _metrics.compute_layout_metrics(
        roads=given(layout.roads), parcels=given(layout.parcels), blocks=given(blocks),
        area=layout.domain,
        landuse=layout.table.land_use.to_numpy() if len(layout.parcels) else None)

    def scalar(kind, name):
        try:
            return res.scalar(kind, name)
        except KeyError:
            return float("nan")

    use = layout.table.land_use.to_numpy()
    resid = use == "residential"
    designed = (layout.table.template.to_numpy() != "key_area")
    pm = _metrics.parcel_metrics(layout.parcels[designed], area=layout.domain) \
        if designed.any() else None
    pr = _metrics.parcel_metrics(layout.parcels[resid], area=layout.domain) \
        if resid.any() else None
    st = layout.stats
    nan = float("nan")
    return {
        "l_s": scalar("parcels", "l_s"), "l_r": scalar("parcels", "l_r"),
        "l_p": scalar("parcels", "l_p"), "l_o": scalar("parcels", "l_o"),
        "b_n": scalar("blocks", "blocks_per_km2"), "b_max": scalar("blocks", "b_max"),
        "b_avg": scalar("blocks", "b_avg"), "b_min": scalar("blocks", "b_min"),
        "s_l": scalar("roads", "street_length_km_per_km2"),
        "s_i": scalar("roads", "intersections_per_km2"),
        "s_d": scalar("roads", "dead_ends_per_km2"),
        "p_n": pm.scalar("parcels", "p_n_per_km2") if pm else 0.0,
        "p_count": int(designed.sum()),
        "p_angle": pm.scalar("parcels", "p_angle") if pm else nan,
        "p_area": pm.scalar("parcels", "p_area") if pm else nan,
        "undesirable": int(pm.scalar("parcels", "undesirable_count")) if pm else 0,
        "undesirable_pct": pm.scalar("parcels", "undesirable_share") if pm else 0.0,
        "p_count_residential": int(resid.sum()),
        "p_angle_residential": pr.scalar("parcels", "p_angle") if pr else nan,
        "p_area_residential": pr.scalar("parcels", "p_area") if pr else nan,
        "no_access": st.get("n_no_access", 0),
        "time_split_s": st.get("time_split_s", 0.0),
        "time_backtrack_s": st.get("time_backtrack_s", 0.0),
        "time_optimise_s": st.get("time_optimise_s", 0.0),
    }
