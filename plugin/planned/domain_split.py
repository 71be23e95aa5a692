"""Street and parcel layouts by hierarchical domain splitting (Yang et al. 2013).

Pipeline of :func:`split_domain` (one layout) and :func:`split_variations` (k layouts):

1. **Constraints** (sec. 3): the region minus the key areas (parks, school, lake: kept
   as parcels of their own land use) is cut by the key roads into sub-regions. Every
   region outline (outer ring, holes, key areas, key roads) is taken as a street centre
   line: the region is a development bounded by streets.
2. **Hierarchical splitting** (sec. 3-5): a queue of regions; each region is replaced by
   a template when one fits with energy under the threshold (:mod:`templates`,
   template-based splitting preferred); otherwise it is split along a streamline of its
   boundary-aligned cross field (:mod:`cross_field`, :mod:`streamlines`), drawn at
   random by quality. A streamline whose sub-regions could hold no template (too thin) is
   rejected and the next one drawn (backtracking of the split); a region that can be
   neither matched nor split falls back to skeleton parcels (Vanegas et al. 2012, via
   :func:`parcels.split_skeleton`) or, when too small for parcels, a park.
3. **Backtracking for template counts**: templates over their ``max_count`` are
   reassigned, at random, to the next best template of their region.
4. **Global optimisation of the road mesh** (sec. 6, :mod:`mesh_optimisation`), then the
   templates are warped again onto the optimised blocks (:func:`templates.warp_rows`).
5. Parcels get their land use, street access and Yang's quality; :func:`table1` gives the
   paper's Table 1 metrics through :mod:`metrics`. Undesirable lots (Yang's Fig. 12 test)
   are repaired where a strip meets a slanted street or streets meet at an acute angle:
   a lot of at least 0.6 of a template parcel keeps the largest rectangle standing on its
   street edge (:func:`_front_rectangle`) and its wedges become pocket parks; a misshapen
   lot smaller than a template parcel becomes a pocket park (the paper's fallback "places
   a park" for what no template fills). Splits leaving a child that is a band thinner than
   any template anywhere along it are rejected (morphological opening test).

Nothing here imports QGIS. Geometry is metric; each variation draws from
``numpy.random.default_rng([seed, variation])``.

References
----------
Yang, Y.-L., Wang, J., Vouga, E., Wonka, P. (2013). Urban pattern: layout design by
    hierarchical domain splitting. ACM TOG 32(6) (SIGGRAPH Asia), sec. 3-7, Table 1-2.
Vanegas, C. A. et al. (2012). Procedural generation of parcels in urban modeling. CGF 31(2).
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core.geometry import minimum_rectangles, unit
from ..core.progress import InputError, Progress, ensure
from ..measure import metrics as _metrics
from ..parcels import subdivision as _parcels
from . import templates as _templates
from .cross_field import cross_field
from .mesh_optimisation import optimise_roads
from .streamlines import score_streamlines, seed_points, trace_streamlines, width_fit

__all__ = ["SplitSettings", "Layout", "ROAD_FIELDS", "PARCEL_FIELDS", "METRIC_FIELDS",
           "split_domain", "split_variations", "table1", "prepare_domain"]

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
                 ("no_access", "int"), ("time_split_s", "float"),
                 ("time_backtrack_s", "float"), ("time_optimise_s", "float")]

#: Parcel outlines are simplified with this tolerance (m).
_OUTPUT_GRID = 0.01
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
    """

    parcel_length: float = 30.0
    parcel_width: float = 18.0
    street_width: float = 15.0
    energy_threshold: float = 0.45
    optimise: bool = True
    max_regions: int = 2000
    choice_temperature: float = 0.3

    def validate(self) -> "SplitSettings":
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
    blocks : ndarray of Polygon (centre-line blocks); block_template : names
    parcels : ndarray of Polygon; table : DataFrame (PARCEL_FIELDS)
    stats : dict (counts and the times of splitting, backtracking and optimisation)
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


def prepare_domain(region, key_roads=None, key_areas=None, street_width: float = 15.0):
    """Work regions, the fixed street lines and the key-area polygons.

    Returns (faces, fixed_lines, fixed_kinds, key_polys, domain).
    """
    domain = _polygonal(region, "region")
    key_polys = np.empty(0, dtype=object)
    work = domain
    if key_areas is not None and len(key_areas):
        keys = _polygonal(key_areas, "key areas layer")
        with np.errstate(invalid="ignore"):
            keys = shapely.intersection(keys, domain)
        key_polys = _parcels._polygon_parts([keys], 1.0)
        work = shapely.difference(domain, keys)
    outline = shapely.get_parts(shapely.line_merge(shapely.boundary(work)))
    lines = list(outline)
    kinds = ["outline"] * len(lines)
    if key_roads is not None and len(key_roads):
        roads = np.asarray([g for g in np.asarray(key_roads, dtype=object).ravel()
                            if g is not None and not shapely.is_empty(g)], dtype=object)
        if len(roads) and not (shapely.get_dimensions(roads) == 1).all():
            raise InputError("the key roads must be lines")
        with np.errstate(invalid="ignore"):
            inside = shapely.get_parts(shapely.intersection(shapely.union_all(roads), work))
        inside = inside[(shapely.get_type_id(inside) == 1) & (shapely.length(inside) > 0.5)]
        merged = shapely.get_parts(shapely.line_merge(shapely.union_all(inside))) \
            if len(inside) else []
        lines += list(merged)
        kinds += ["key"] * len(merged)
    faces = _faces(lines, work)
    if len(faces) == 0:
        raise InputError("the region is empty once the key areas are removed")
    return faces, np.asarray(lines, dtype=object), np.asarray(kinds), key_polys, domain


def _faces(lines, work) -> np.ndarray:
    noded = shapely.union_all(np.asarray(lines, dtype=object))
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(noded)))
    if len(faces) == 0:
        return faces
    inside = shapely.within(shapely.point_on_surface(faces), work)
    return _parcels._polygon_parts(faces[inside], 1.0)


# --------------------------------------------------------------------------- splitting

class _Splitter:
    def __init__(self, lib, settings: SplitSettings, rng):
        self.lib = lib
        self.s = settings
        self.rng = rng
        L, S = settings.parcel_length, settings.street_width
        parts = [t for t in lib if t.kind in ("rows", "spike")]
        widths = [t.gross_depth(L, S) for t in parts]
        # the templates' user probabilities weight the widths: with the shipped library a
        # double strip (one street per two rows) is preferred to two single strips
        top = max(t.probability for t in parts) or 1.0
        self.opt = width_fit(widths, 4 * max(widths + [L + S]), 0.12 * L,
                             weights=[max(t.probability / top, 0.05) for t in parts])
        # a sub-region thinner than this holds no template: its split is rejected
        self.min_depth = S + min([t.rows * L * t.depth_scale[0] for t in lib if t.kind == "rows"]
                                 + [2.6 * L])
        self.n_split = 0
        self.n_rejected = 0

    def energies(self, region) -> Dict[str, float]:
        s = self.s
        shape = _templates.region_shape(region)
        return {t.name: _templates.fit_energy(region, t, s.parcel_length, s.parcel_width,
                                              s.street_width, shape) for t in self.lib}

    def pick_template(self, energies, exclude=()):
        by_name = {t.name: t for t in self.lib}
        ok = [(n, e) for n, e in energies.items()
              if e < self.s.energy_threshold and n not in exclude and by_name[n].kind != "park"]
        if not ok:
            return None
        p = np.array([by_name[n].probability * math.exp(-e / 0.1) for n, e in ok])
        if p.sum() <= 0:
            return None
        return ok[int(self.rng.choice(len(ok), p=p / p.sum()))][0]

    def split(self, region, ends):
        """Split along a streamline: (line, children) or None."""
        L = self.s.parcel_length
        area = shapely.area(region)
        h = max(L / 5.0, math.sqrt(area) / 35.0)
        field_ = cross_field(region, h)
        d_eps = 0.3 * L
        seeds = seed_points(region, d_eps, self.rng, max_seeds=30)
        cands = trace_streamlines(field_, region, seeds, max(h, L / 4.0), d_eps, self.rng)
        if len(cands.lines) == 0:
            return None
        keep = shapely.length(cands.lines) >= L
        if not keep.any():
            return None
        cands.lines, cands.seeds, cands.orientation = (cands.lines[keep], cands.seeds[keep],
                                                       cands.orientation[keep])
        qual, _ = score_streamlines(cands, field_, region, self.opt, ends, step=h)
        alive = np.ones(len(qual), dtype=bool)
        for _ in range(20):
            if not alive.any():
                return None
            q = np.where(alive, qual, -np.inf)
            p = np.exp((q - q.max()) / max(self.s.choice_temperature, 1e-6))
            i = int(self.rng.choice(len(q), p=p / p.sum()))
            alive[i] = False
            children = self._children(region, cands.lines[i])
            if children is not None:
                self.n_split += 1
                return cands.lines[i], children
            self.n_rejected += 1
        return None

    def _children(self, region, line):
        coords = shapely.get_coordinates(line)
        ext = np.vstack([coords[0] + 0.5 * unit(coords[0] - coords[1]), coords,
                         coords[-1] + 0.5 * unit(coords[-1] - coords[-2])])
        faces = _faces([shapely.boundary(region), shapely.LineString(ext)], region)
        if len(faces) < 2:
            return None
        _, short, _ = minimum_rectangles(faces)
        if (short < self.min_depth).any():
            return None
        r = self.s.street_width / 2 + 0.3 * self.s.parcel_length
        inner = shapely.buffer(faces, -r, join_style="mitre")
        if shapely.is_empty(inner).any():
            return None
        # morphological opening: a child that is thick somewhere but a thin band elsewhere
        # (a streamline running close to the boundary) leaves a sliver no template fills
        opened = shapely.area(shapely.buffer(inner, r, join_style="mitre"))
        if (opened < 0.85 * shapely.area(faces)).any():
            return None
        return faces


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
                 templates: Optional[Sequence] = None,
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
    lib = list(templates) if templates is not None else _templates.load_library()
    if not any(t.kind in ("rows", "spike") for t in lib):
        raise InputError("the templates hold no parcel template")
    rng = np.random.default_rng([int(seed), int(variation)])
    faces, fixed, fixed_kinds, key_polys, domain = prepare_domain(
        region, key_roads, key_areas, s.street_width)
    work_area = float(shapely.area(domain))
    L, W, S = s.parcel_length, s.parcel_width, s.street_width
    splitter = _Splitter(lib, s, rng)
    by_name = {t.name: t for t in lib}

    # ---- hierarchical splitting
    t0 = time.perf_counter()
    queue = deque(faces)
    leaves: List[list] = []  # [region, template name or 'skeleton' / 'park', energies]
    split_lines: List[shapely.LineString] = []
    ends = _end_dirs(fixed[fixed_kinds == "key"])
    n_done = 0
    while queue:
        if n_done >= s.max_regions:
            leaves.extend([[r, "skeleton", {}] for r in queue])
            break
        n_done += 1
        region_ = queue.popleft()
        progress.step(min(0.6, 0.6 * (1 - shapely.area(region_) / work_area) ** 2
                          if work_area else 0.0))
        if shapely.area(region_) < 0.5 * L * W:
            leaves.append([region_, "park", {}])
            continue
        energies = splitter.energies(region_)
        name = splitter.pick_template(energies)
        if name is not None:
            leaves.append([region_, name, energies])
            continue
        got = splitter.split(region_, ends)
        if got is None:
            leaves.append([region_, _fallback(region_, energies, by_name, s), energies])
            continue
        line, children = got
        split_lines.append(line)
        ends = np.vstack([ends, _end_dirs([line])])
        queue.extend(children)
    t_split = time.perf_counter() - t0
    progress.step(0.6)

    # ---- backtracking: template counts over their maximum go to the next best template
    t0 = time.perf_counter()
    n_backtracked = 0
    by_name = {t.name: t for t in lib}
    counts = Counter(leaf[1] for leaf in leaves)
    for t in lib:
        if t.max_count is None or counts[t.name] <= t.max_count:
            continue
        idx = [i for i, leaf in enumerate(leaves) if leaf[1] == t.name]
        excess = rng.permutation(idx)[: counts[t.name] - t.max_count]
        for i in excess:
            counts[t.name] -= 1
            full = [n for n in by_name if counts[n] >= (by_name[n].max_count or 10 ** 9)]
            alt = splitter.pick_template(leaves[i][2], exclude=set(full) | {t.name})
            leaves[i][1] = alt or "skeleton"
            counts[leaves[i][1]] += 1
            n_backtracked += 1
    t_back = time.perf_counter() - t0

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

        new_lines, opt_stats = optimise_roads(split_lines, fixed, face_width, spacing=W)
        if opt_stats["iterations"]:
            new_faces = _faces(list(fixed) + list(new_lines), shapely.difference(
                domain, shapely.union_all(key_polys)) if len(key_polys) else domain)
            centre = shapely.point_on_surface(new_faces)
            # every new block inherits the template of the old block it grew from
            owner = []
            for c in centre:
                hit = tree.query(c, predicate="within")
                owner.append(int(hit[0]) if len(hit) else -1)
            if len(new_faces) == len(leaves) and sorted(owner) == list(range(len(leaves))):
                for face, o in zip(new_faces, owner):
                    leaves[o][0] = face
                split_lines = list(new_lines)
            else:
                opt_stats["reverted"] = True
    t_opt = time.perf_counter() - t0
    progress.step(0.7)

    # ---- templates warped onto the blocks: parcels
    lots_all, use_all, tmpl_all, front_all = [], [], [], []
    template_roads = []
    key_road_zone = None
    key_lines = fixed[fixed_kinds == "key"]
    if len(key_lines):
        key_road_zone = shapely.buffer(shapely.union_all(key_lines), S / 2, cap_style="flat")
    settings_sk = _parcels.SubdivisionSettings(
        max_area=1.6 * L * W, min_area=0.3 * L * W, min_width=0.4 * W, lot_width=W,
        irregularity=0.0)
    n_inner = n_pocket = 0
    for k, (reg, name, _) in enumerate(leaves):
        progress.step(0.7 + 0.25 * k / max(len(leaves), 1))
        shrunk = shapely.buffer(reg, -S / 2, join_style="mitre")
        if key_road_zone is not None:
            shrunk = shapely.difference(shrunk, key_road_zone)
        for part in _parcels._polygon_parts([shrunk], 1.0):
            lots, kind, street_area = _lots_for(part, reg, name, by_name, s, settings_sk, rng,
                                                template_roads)
            if kind == "park":
                lots_all.append(lots)
                use_all += ["park"] * len(lots)
                tmpl_all += [name] * len(lots)
                front_all.append(np.full(len(lots), np.nan))
                continue
            zone_poly = street_area
            front = _parcels.street_frontage(lots, zone_poly)
            # lots without frontage, crumbs, and small misshapen end lots (the triangle
            # left where a strip meets a slanted street) join their neighbour
            area = shapely.area(lots)
            misshapen = _parcels.lot_quality(lots)[2] & (area < 0.6 * L * W)
            bad = (front < _parcels.MIN_FRONTAGE) | (area < 0.25 * L * W) | misshapen
            if bad.any() and len(lots) > 1:
                lots = _parcels._polygon_parts(_parcels.merge_into_neighbours(lots, bad)[0])
                front = _parcels.street_frontage(lots, zone_poly)
            # a lot still without frontage (all its neighbours were merged away) is kept as
            # a green inside the block, as the paper's template with a private park; an
            # undesirable remnant no larger than a parcel (the wedge left where a strip
            # meets a slanted or curved street, a block corner) becomes a pocket park: the
            # paper's fallback "places a park" for what no template fills
            area = shapely.area(lots)
            bad = _parcels.lot_quality(lots)[2]
            remnant = bad & (area < 1.0 * L * W)
            fixable = bad & (area >= 0.6 * L * W) & (front >= _parcels.MIN_FRONTAGE)
            if fixable.any():
                lots, front, remnant = _rectify(lots, front, remnant, fixable, part, L, W)
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
        uses = np.asarray(key_area_use if key_area_use is not None else ["park"] * len(key_polys),
                          dtype=object)
        if len(uses) != len(key_polys):
            uses = np.full(len(key_polys), "park", dtype=object)
        lots_all.append(key_polys)
        use_all += [str(u) if u not in (None, "") else "park" for u in uses]
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
    roads = list(fixed) + list(split_lines) + template_roads
    level = [LEVEL_KEY if k == "key" else LEVEL_OUTLINE for k in fixed_kinds] + \
        [LEVEL_SPLIT] * len(split_lines) + [LEVEL_TEMPLATE] * len(template_roads)
    kind = [str(k) for k in fixed_kinds] + ["split"] * len(split_lines) + \
        ["cul_de_sac"] * len(template_roads)
    stats = {
        "n_regions": n_done, "n_splits": splitter.n_split, "n_rejected_splits": splitter.n_rejected,
        "n_backtracked": n_backtracked, "n_blocks": len(leaves),
        "templates": dict(Counter(leaf[1] for leaf in leaves)),
        "n_parcels": int(residential.sum()),
        "n_no_access": int((residential & ~table.has_street_access.to_numpy(bool)).sum()),
        "n_inner_parks": n_inner, "n_pocket_parks": n_pocket,
        "time_split_s": t_split, "time_backtrack_s": t_back, "time_optimise_s": t_opt,
        "optimisation": opt_stats,
    }
    progress.step(1.0)
    return Layout(np.asarray(roads, dtype=object), np.asarray(level), np.asarray(kind, dtype=object),
                  np.array([leaf[0] for leaf in leaves], dtype=object),
                  np.array([leaf[1] for leaf in leaves], dtype=object), geoms, table, domain, stats)


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
    skeleton parcels (Vanegas et al. 2012)."""
    rows = [(e, n) for n, e in energies.items() if by_name[n].kind == "rows" and np.isfinite(e)]
    if rows and min(rows)[0] < 2 * s.energy_threshold:
        return min(rows)[1]
    if shapely.area(region) < 6 * s.parcel_length * s.parcel_width:
        return "park"
    return "skeleton"


def _lots_for(part, reg, name, by_name, s: SplitSettings, settings_sk, rng, template_roads):
    """Lots of one shrunk block part: (lots, template name, street polygon for frontage)."""
    L, W, S = s.parcel_length, s.parcel_width, s.street_width
    if name == "park" or shapely.area(part) < 0.5 * L * W:
        return np.array([part], dtype=object), "park", part
    t = by_name.get(name)
    if t is not None and t.kind == "rows":
        warped = _templates.warp_rows(part, t, L, W, rng)
        if warped is not None and len(warped.lots):
            return warped.lots, t.name, part
    if t is not None and t.kind == "spike":
        got = _templates.spike_lots(reg, part, L, W, S, settings_sk, rng)
        if got is not None and len(got[0]):
            lots, road = got
            template_roads.append(road)
            return lots, t.name, shapely.union_all(lots)
    lots = _parcels._polygon_parts(_parcels.split_skeleton(part, settings_sk, rng))
    return (lots if len(lots) else np.array([part], dtype=object)), "skeleton", part


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


def table1(layout: Layout) -> Dict[str, float]:
    """The paper's Table 1 metrics of a layout (land use %, blocks, streets, parcels).

    Land use is over the whole region; block metrics over the centre-line blocks; street
    densities over the road graph; parcel metrics over the residential parcels.
    """
    res = _metrics.compute_layout_metrics(
        roads=layout.roads, blocks=layout.blocks, parcels=layout.parcels,
        area=layout.domain, landuse=layout.table.land_use.to_numpy())
    resid = layout.table.land_use.to_numpy() == "residential"
    pm = _metrics.parcel_metrics(layout.parcels[resid], area=layout.domain) if resid.any() else None
    st = layout.stats
    return {
        "l_s": res.scalar("parcels", "l_s"), "l_r": res.scalar("parcels", "l_r"),
        "l_p": res.scalar("parcels", "l_p"), "l_o": res.scalar("parcels", "l_o"),
        "b_n": res.scalar("blocks", "blocks_per_km2"), "b_max": res.scalar("blocks", "b_max"),
        "b_avg": res.scalar("blocks", "b_avg"), "b_min": res.scalar("blocks", "b_min"),
        "s_l": res.scalar("roads", "street_length_km_per_km2"),
        "s_i": res.scalar("roads", "intersections_per_km2"),
        "s_d": res.scalar("roads", "dead_ends_per_km2"),
        "p_n": pm.scalar("parcels", "p_n_per_km2") if pm else 0.0,
        "p_count": int(resid.sum()),
        "p_angle": pm.scalar("parcels", "p_angle") if pm else float("nan"),
        "p_area": pm.scalar("parcels", "p_area") if pm else float("nan"),
        "undesirable": int(pm.scalar("parcels", "undesirable_count")) if pm else 0,
        "undesirable_pct": pm.scalar("parcels", "undesirable_share") if pm else 0.0,
        "no_access": st.get("n_no_access", 0),
        "time_split_s": st.get("time_split_s", 0.0),
        "time_backtrack_s": st.get("time_backtrack_s", 0.0),
        "time_optimise_s": st.get("time_optimise_s", 0.0),
    }
