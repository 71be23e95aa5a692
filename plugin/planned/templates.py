"""Hierarchical parcel templates and their warping (Yang et al. 2013, sec. 4).

A template is a small designed layout that a region can be replaced by. The shipped
library (:func:`default_library`, written to ``resources/templates/library.json`` by
:func:`write_library`) holds the four patterns of the paper's Fig. 2 and an area template:

=============  =====  ===============================================================
name           label  pattern
=============  =====  ===============================================================
parcel_strip   L      one row of parcels (R) between two streets
double_strip   D      two rows of parcels (R) back to back, each facing its street
spike          S      a cul-de-sac street into the block, parcels (R) around it
loop           O      a loop street inside a deep block, joined to the block's longest
                      street at its middle, parcels on both sides of the loop
park           A      an area template kept as a park (the fallback of the paper)
(drawn)        T      a user's template that is no strip (more rows, parks among the
                      parcels, any outline), warped as drawn (:func:`warp_drawn`)
=============  =====  ===============================================================

Labels R (parcel), S (spike) and A (area) are the paper's (Fig. 4); L and D name the two
level-two row templates, which the paper draws but does not label in its text.

Template-based splitting (:func:`fit_energy`, :func:`warp_rows`):

* **Selection** (sec. 4.1, "the warping energy that is necessary to deform the template
  region to the region"): a row template is warped onto the region (below) and scored by
  its registration residual, the root mean square distance between the warped parcel
  corners and each parcel's best registration in its allowed deformation class, divided
  by the parcel width, plus the turn (radians) of the region's corners that the
  template's four corners cannot take (:func:`region_frame`; a corner inside a long street
  side turning by at most :data:`LONG_SIDE_BEND` is a regular boundary vertex of the
  repeating row, taken by a pinned parcel joint, and costs only its residual). A
  template whose depth
  range or row length (``max_columns``) the region exceeds does not match. A drawn
  template is scored by the same residual for parcels of any shape (:func:`warp_drawn`),
  and so are the built-in spike and loop, which are drawn templates built at the
  layout's parcel and street size (:func:`built_in_drawn`); the area template keeps the
  fixed price of :func:`fit_energy`.
  Templates with energy under a threshold are drawn with probability template
  probability x exp(-energy / 0.1).
* **Hierarchical warping** of the row templates: level one chooses the number of parcels
  per row (Fig. 5) from the length of the region's street sides; level two warps the grid
  of parcel corners by the paper's alternating optimisation: *registration* of each
  parcel to its template rectangle by a similarity followed by a non-uniform scaling in
  its principal directions with bounded factors (the constrained affine class), then
  *regression*: every shared corner moves to the mean of its registered copies and corners
  on the street sides are projected back onto them (alignment constraints), the four
  corners stay on the region's corners and a corner nearest a bend of a street side
  (> 8°) is pinned to the bend, so no parcel straddles one; 30 iterations. A drawn
  template's parcel mesh starts from its mean value warp and is regressed the same way
  (:func:`warp_drawn`).
  The arc-length initialisation is the paper's; the final cut lines split the exact
  (curved) block outline, so the parcels tile the block.

Nothing here imports QGIS.

References
----------
Yang et al. (2013), sec. 4 (templates, warping algorithm, hierarchical matching), Fig. 2,
Fig. 4, Fig. 5.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import shapely
import shapely.affinity
import shapely.ops
from scipy.spatial import Delaunay, cKDTree

from ..core.paths import RESOURCES
from ..core.geometry import minimum_rectangles, ring_turns
from ..core.progress import InputError
from ..parcels import subdivision as _parcels
from ..retrieval.warp import warp_points

__all__ = ["Template", "LIBRARY_PATH", "LIBRARY_SUBSETS", "default_library", "write_library",
           "load_library", "templates_from_drawn", "fit_energy", "region_shape", "region_frame",
           "warp_rows", "warp_drawn", "drawn_outline", "end_ray_hit", "built_in_drawn",
           "spike_geometry", "loop_geometry", "WarpResult", "WARP_ITERATIONS", "KINDS"]

LIBRARY_PATH = RESOURCES / "templates" / "library.json"
#: Iterations of registration / regression (the paper: about 30 per match).
WARP_ITERATIONS = 30
#: Template kinds: parcel rows, spike (cul-de-sac), loop, area (park), drawn (as drawn).
KINDS = ("rows", "spike", "loop", "park", "drawn")
#: The labels of a drawn template's features (Yang's): a feature without one is a parcel.
DRAWN_LABELS = {"R": "parcel", "P": "park", "A": "area", "S": "street"}
#: Named subsets of the shipped library (the toolbox's TEMPLATES enum, in this order).
LIBRARY_SUBSETS = {
    "all": ("parcel_strip", "double_strip", "spike", "loop", "park"),
    "strips": ("parcel_strip", "double_strip", "park"),
    "double_strips": ("double_strip", "park"),
}


@dataclass(frozen=True)
class Template:
    """One template of the library.

    Attributes
    ----------
    name : str
    label : str
        Region label (see the module table).
    kind : str
        'rows' (parcel rows facing the streets), 'spike' or 'loop' (the built-in ones,
        drawn at the layout's size by :func:`built_in_drawn`), 'park' or 'drawn'.
    rows : int
        Parcel rows across the block (rows templates).
    probability : float
        User-defined probability (how common the pattern is).
    width_scale, depth_scale : (float, float)
        Allowed scaling of a parcel's width (along the street) and depth.
    depth_range : (float, float)
        Spikes and loops: the block depth in parcel lengths the pattern was made for
        (informative: they are matched by their warp energy as drawn).
    max_count : int or None
        At most this many per layout (met by backtracking).
    min_count : int
        At least this many per layout (Yang's k2; met by repeating the randomized search,
        :data:`domain_split.MIN_COUNT_ATTEMPTS` times at most).
    max_columns : int
        Most parcels in one row: the repeating element's limit, i.e. the longest block
        (30 x 18 m = 540 m with the paper's parcels: a double-strip block of 1,230 m
        perimeter, inside the range of Yang's longest blocks, b_max 955-1,454 m in
        Table 1's "Our" rows).
    land_use : str
    parcels : list of polygons (unit coordinates: x in parcel widths, y in parcel lengths)
        The drawn layout, for display and user templates; a 'drawn' template's parcels are
        in metres, centred on its outline, its long axis along x (warped as drawn).
    parcel_labels : tuple of str
        A 'drawn' template's label per parcel: R (parcel), P (park), A (an area of the
        next level, filled by level-two templates: Yang Fig. 4), S (its own street,
        drawn as a surface).
    streets : tuple of coordinate lists
        A 'drawn' template's own streets: the centre lines of its S surfaces (template
        frame), running onto its outline where they leave it.
    parcel_groups : tuple of int
        A 'drawn' template's drawn parcel of every stored piece: a parcel drawn with a hole
        (a ring street, a lot round a courtyard) is stored as pieces without holes and
        warped back into one (empty: every piece is a parcel of its own).
    """

    name: str
    label: str
    kind: str
    rows: int = 1
    probability: float = 1.0
    width_scale: Tuple[float, float] = (0.75, 1.35)
    depth_scale: Tuple[float, float] = (0.8, 1.25)
    depth_range: Tuple[float, float] = (0.0, 0.0)
    max_count: Optional[int] = None
    min_count: int = 0
    max_columns: int = 30
    land_use: str = "residential"
    parcels: tuple = field(default=(), compare=False)
    parcel_labels: tuple = field(default=(), compare=False)
    streets: tuple = field(default=(), compare=False)
    parcel_groups: tuple = field(default=(), compare=False)

    def gross_depth(self, length: float, street: float) -> float:
        """Ideal centre-line width of a block of this template (m)."""
        if self.kind == "rows":
            return self.rows * length + street
        if self.kind == "drawn":
            return float(minimum_rectangles([drawn_outline(self)])[1][0]) + street
        return 0.0


def _rect(x0, y0, x1, y1):
    return [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]


def default_library() -> List[Template]:
    """The shipped templates (see the module table)."""
    return [
        Template("parcel_strip", "L", "rows", rows=1, probability=0.6, depth_scale=(0.8, 1.45),
                 parcels=tuple(_rect(i, 0, i + 1, 1) for i in range(4))),
        # two parcel strips back to back: rows as deep as the strip's (Fig. 4 "no street"
        # rear edges; a deeper face would otherwise need a street and a third row)
        Template("double_strip", "D", "rows", rows=2, probability=1.0, depth_scale=(0.7, 1.45),
                 parcels=tuple(_rect(i, j, i + 1, j + 1) for i in range(4) for j in range(2))),
        Template("spike", "S", "spike", probability=0.4, depth_range=(2.6, 4.6), max_count=4,
                 parcels=tuple([_rect(0, 0, 1, 1), _rect(2, 0, 3, 1), _rect(0, 1, 1, 2),
                                _rect(2, 1, 3, 2), _rect(0.5, 2, 2.5, 3)])),
        Template("loop", "O", "loop", probability=0.3, depth_range=(4.6, 7.0), max_count=3,
                 parcels=tuple([_rect(i, 0, i + 1, 1) for i in range(5)]
                               + [_rect(i, 5, i + 1, 6) for i in range(5)]
                               + [_rect(1.5, 2, 3.5, 4)])),
        Template("park", "A", "park", probability=0.05, land_use="park",
                 parcels=(_rect(0, 0, 2, 2),)),
    ]


def write_library(path: Path = LIBRARY_PATH) -> Path:
    """Write the shipped library as JSON (resources/templates/library.json)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": "urbansynth-templates/1",
           "reference": "Yang et al. 2013, Urban Pattern, sec. 4, Fig. 2 and Fig. 4",
           "units": "x in parcel widths, y in parcel lengths",
           "templates": [asdict(t) for t in default_library()]}
    path.write_text(json.dumps(doc, indent=1))
    return path


def load_library(path=LIBRARY_PATH, subset: Optional[str] = None) -> List[Template]:
    """Templates from a library JSON file, optionally one of :data:`LIBRARY_SUBSETS`.

    Raises
    ------
    InputError
        Unreadable file, wrong format or unknown subset.
    """
    try:
        doc = json.loads(Path(path).read_text())
        items = doc["templates"]
        out = [Template(**{**t, "width_scale": tuple(t.get("width_scale", (0.75, 1.35))),
                           "depth_scale": tuple(t.get("depth_scale", (0.8, 1.25))),
                           "depth_range": tuple(t.get("depth_range", (0.0, 0.0))),
                           "parcels": tuple(t.get("parcels", ())),
                           "parcel_labels": tuple(t.get("parcel_labels", ())),
                           "streets": tuple(t.get("streets", ())),
                           "parcel_groups": tuple(t.get("parcel_groups", ()))}) for t in items]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"the template library {path} cannot be read ({exc})") from exc
    for t in out:
        if t.kind not in KINDS or t.rows < 1 or t.probability < 0 or \
                not 0 <= t.min_count <= (t.max_count if t.max_count is not None else
                                         math.inf):
            raise InputError(f"template {t.name!r} in {path} is not a valid template")
    if subset is not None:
        if subset not in LIBRARY_SUBSETS:
            raise InputError(f"unknown template subset {subset!r}")
        out = [t for t in out if t.name in LIBRARY_SUBSETS[subset]]
    if not out:
        raise InputError(f"the template library {path} holds no template")
    return out


def templates_from_drawn(geoms: Sequence, names: Sequence, labels: Sequence,
                         settings: Optional[dict] = None) -> List[Template]:
    """Templates drawn as polygons (e.g. in QGIS), one feature per parcel or area.

    Each template is the group of features sharing a ``names`` value; ``labels`` are the
    paper's: R (residential parcel), P (park), A (area: in a template with parcels, a
    region of the next level that the layout fills with parcel rows, Yang Fig. 4), S the
    template's own street drawn as a surface (alone, without parcels: a marker of the
    built-in spike). Row templates are recognised from the geometry: the parcels' centres
    are clustered across the template's long axis into rows (1 or 2 make a strip or a
    double strip, which repeat along any street length). A group of only park or area
    polygons is an area template (a park). Any other group -- three rows or more, parks or
    areas among the parcels (the paper's template with a private park), its own streets
    drawn as a surface (S: a cul-de-sac of any shape with its turning head, a loop street
    as a ring with its connector), any outline -- is a **drawn** template, kept as drawn
    and warped onto a region corner to corner (:func:`warp_drawn`).

    ``settings`` (optional): per feature, ``probability``, ``min_count`` and ``max_count``
    (Yang's user probability and k1 / k2 counts): a template takes the first value given
    among its features (None or NaN: the default).

    A feature without a label (None or empty) is a parcel (R); a label is one of the four
    letters, in either case. Any other label (a word such as 'parcel', which was read by its
    first letter as a park, or a code) and a feature without a template name are refused.

    Raises
    ------
    InputError
        A feature without a template name, a label that is none of R, P, A, S, no group
        with parcels, a drawn group whose parcels do not form one polygon, a
        drawn street that does not reach the template's outline, or a setting that is no
        number, negative, or a minimum count above the maximum.
    """
    def given(v):
        return v is not None and not (isinstance(v, float) and math.isnan(v)) \
            and str(v).strip() != ""

    geoms = np.asarray(geoms, dtype=object)
    unnamed = sum(not given(n) for n in names)
    if unnamed:
        raise InputError(f"{unnamed} of {len(names)} features have no template name (field "
                         "'template'): each feature names the template it belongs to")
    names = np.asarray([str(n) for n in names], dtype=object)
    raw = [str(v).strip() if given(v) else "R" for v in labels]
    for name, lab in zip(names, raw):
        if lab.upper() not in DRAWN_LABELS:
            raise InputError(
                f"template {name!r}: label {lab!r} is none of "
                + ", ".join(f"{k} ({v})" for k, v in DRAWN_LABELS.items()))
    labels = np.asarray([lab.upper() for lab in raw])
    out = []
    for name in dict.fromkeys(names):
        sel = names == name
        g, lab = geoms[sel], labels[sel]
        parcels_ = tuple(shapely.get_coordinates(shapely.get_exterior_ring(p)).tolist()
                         for p in g if p is not None)
        if set(lab) <= {"P", "A"}:
            out.append(Template(name, "A", "park", land_use="park", parcels=parcels_))
            continue
        if "S" in lab and "R" not in lab:   # a spike marker: the built-in cul-de-sac
            out.append(Template(name, "S", "spike", depth_range=(2.6, 4.6), parcels=parcels_))
            continue
        res = g[lab == "R"]
        # a parcel is deeper than wide: its long axis runs across the street, and rows
        # are the clusters of parcel centres along that axis
        depth, _, angle = minimum_rectangles(res)
        a = np.radians(float(np.median(angle)))
        across = shapely.get_coordinates(shapely.centroid(res)) @ np.array([np.cos(a), np.sin(a)])
        gap = max(0.5 * float(np.median(depth)), 1e-6)
        rows = 1 + int((np.diff(np.sort(across)) > gap).sum())
        if rows <= 2 and set(lab) == {"R"}:
            out.append(Template(name, "L" if rows == 1 else "D", "rows", rows=rows,
                                parcels=parcels_))
        else:
            out.append(_drawn_template(name, g, lab))
        if settings:
            out[-1] = _with_settings(out[-1], {k: np.asarray(v, dtype=object)[sel]
                                               for k, v in settings.items()})
    if not any(t.kind != "park" for t in out):
        raise InputError("the template layer has no parcel template (label R or S)")
    return out


def _with_settings(template: Template, values: dict) -> Template:
    """``template`` with the first probability / min_count / max_count given among its
    features' ``values`` (see :func:`templates_from_drawn`)."""
    changes = {}
    for key in ("probability", "min_count", "max_count"):
        given = [v for v in values.get(key, ()) if v is not None and v == v and v != ""]
        if not given:
            continue
        try:
            v = float(given[0])
        except (TypeError, ValueError):
            raise InputError(f"template {template.name!r}: {key} {given[0]!r} is no number")
        if not (v >= 0 and math.isfinite(v)) or (key != "probability" and v != int(v)):
            raise InputError(f"template {template.name!r}: {key} must be a "
                             f"{'number' if key == 'probability' else 'whole number'} "
                             f">= 0 (got {given[0]})")
        changes[key] = v if key == "probability" else int(v)
    t = replace(template, **changes)
    if t.max_count is not None and t.min_count > t.max_count:
        raise InputError(f"template {t.name!r}: min_count {t.min_count} is above max_count "
                         f"{t.max_count}")
    return t


def _without_holes(poly) -> list:
    """``poly`` cut by a line across its first hole, again until no piece has a hole."""
    if not poly.interiors:
        return [poly]
    x = shapely.point_on_surface(shapely.Polygon(poly.interiors[0])).x
    _, y0, _, y1 = poly.bounds
    halves = shapely.get_parts(shapely.ops.split(poly, shapely.LineString([(x, y0 - 1),
                                                                         (x, y1 + 1)])))
    return [piece for half in halves for piece in _without_holes(half)]


def _drawn_template(name: str, geoms: np.ndarray, labels: np.ndarray) -> Template:
    """A drawn template: its parcels in metres about the outline's centre, the outline's
    long axis along x (the frame :func:`warp_drawn` scales in)."""
    geoms, part_of = shapely.get_parts(shapely.make_valid(np.asarray(geoms, dtype=object)),
                                       return_index=True)
    keep = shapely.get_type_id(geoms) == 3
    geoms, labels = geoms[keep], np.asarray(labels)[part_of[keep]]
    # a parcel is kept as its outer ring: a part with holes (the surface of a loop
    # street) is cut across them into pieces without, warped back into one
    pieces = [(piece, lab, k) for k, (g, lab) in enumerate(zip(geoms, labels))
              for piece in _without_holes(g)]
    geoms = np.array([p for p, _, _ in pieces], dtype=object)
    labels = np.array([lab for _, lab, _ in pieces])
    groups = tuple(k for _, _, k in pieces)
    outline = shapely.union_all(geoms)
    if shapely.get_type_id(outline) != 3:
        raise InputError(f"template {name!r}: its parcels and areas must join into one "
                         "polygon without gaps, to be warped as drawn")
    _, _, angle = minimum_rectangles([outline])
    centre = shapely.centroid(outline)
    frame = shapely.affinity.rotate(shapely.affinity.translate(
        shapely.GeometryCollection(list(geoms)), -centre.x, -centre.y),
        -float(angle[0]), origin=(0.0, 0.0))
    parcels_ = tuple(np.round(shapely.get_coordinates(shapely.get_exterior_ring(p)), 6).tolist()
                     for p in shapely.get_parts(frame))
    labs = tuple(v if v in ("P", "A", "S") else "R" for v in labels)
    streets = []
    surface = shapely.union_all([p for p, v in zip(shapely.get_parts(frame), labs) if v == "S"])
    if not surface.is_empty:
        from ..roads.raster_graph import polygon_centre_lines

        edge = shapely.boundary(shapely.union_all(shapely.get_parts(frame)))
        width = 2 * shapely.area(surface) / max(shapely.length(surface), 1e-9)
        for line in polygon_centre_lines(surface):
            xy = shapely.get_coordinates(line)
            # an end near the outline is where the street leaves the template: it runs on
            # onto the outline (the centre line stops half a width short of it)
            for end in (0, -1):
                if shapely.distance(shapely.Point(xy[end]), edge) <= width:
                    hit = end_ray_hit(xy, end, edge, 2 * width)
                    if hit is not None:
                        xy[end] = hit
            streets.append(np.round(xy, 6).tolist())
        ends = shapely.points(np.array([xy_[k] for xy_ in streets for k in (0, -1)])) \
            if streets else np.empty(0, dtype=object)
        if not len(ends) or not shapely.dwithin(ends, edge, 1e-3).any():
            raise InputError(f"template {name!r}: its street (label S) must be drawn as a "
                             "surface that reaches the template's outline, where it joins "
                             "the street around the region")
    return Template(name, "T", "drawn", parcels=parcels_, parcel_labels=labs,
                    streets=tuple(streets), parcel_groups=groups)


def drawn_outline(template: Template):
    """The outline of a drawn template (the union of its parcels, template frame)."""
    return _drawn_frame(template).outline


def _drawn_parcels(template: Template) -> np.ndarray:
    return np.array([shapely.Polygon(p) for p in template.parcels], dtype=object)


@dataclass(frozen=True)
class _DrawnSide:
    """What :func:`warp_drawn` needs of a drawn template as drawn or mirrored (``flip``)."""

    flip: np.ndarray
    parcels: np.ndarray       # the parcels, mirrored with the template
    outline: shapely.Geometry
    ring: np.ndarray          # the outline's corners (:func:`region_corners`)
    corners: np.ndarray
    label: np.ndarray         # +1 convex, -1 concave corner
    sides: list               # the outline between corners
    verts: np.ndarray         # every parcel's ring, at most DRAWN_SAMPLE_SPACING apart
    face: np.ndarray          # the parcel of each of verts
    centred: np.ndarray       # verts less their parcel's mean
    ends: np.ndarray          # where each parcel's verts end (np.split)
    root_area: np.ndarray     # sqrt of each parcel's area


@dataclass(frozen=True)
class _DrawnFrame:
    """A drawn template's outline, size, labels, street entrances and both sides."""

    outline: shapely.Geometry
    long: float
    short: float
    parcels: np.ndarray
    labels: np.ndarray
    entrances: np.ndarray
    sides: tuple


#: Drawn templates prepared for :func:`warp_drawn`, by their drawing (a layout evaluates
#: every drawn template on every region: the union of its parcels alone cost 5 % of a
#: town's split), the oldest of more than _MAX_FRAMES dropped.
_FRAMES: Dict[tuple, _DrawnFrame] = {}
_MAX_FRAMES = 64


def _drawn_frame(template: Template) -> _DrawnFrame:
    """The template-only part of :func:`warp_drawn`, computed once per drawing (keyed by
    its parcels, labels and streets, so a template redrawn in place is prepared anew)."""
    key = (tuple(np.asarray(p, dtype=float).tobytes() for p in template.parcels),
           tuple(template.parcel_labels),
           tuple(np.asarray(xy, dtype=float).tobytes() for xy in template.streets))
    frame = _FRAMES.get(key)
    if frame is None:
        frame = _prepare_drawn(template)
        if len(_FRAMES) >= _MAX_FRAMES:
            _FRAMES.pop(next(iter(_FRAMES)))
        _FRAMES[key] = frame
    return frame


def _prepare_drawn(template: Template) -> _DrawnFrame:
    parcels_ = _drawn_parcels(template)
    outline = shapely.union_all(parcels_, grid_size=1e-6)
    (t_long,), (t_short,), _ = minimum_rectangles([outline]) \
        if shapely.get_type_id(outline) == 3 else ((np.nan,), (np.nan,), None)
    labels = np.asarray(template.parcel_labels or ("R",) * len(parcels_), dtype=object)
    # where the template's own streets leave its outline (they join the street around)
    t_edge = shapely.boundary(outline)
    street_ends = np.array([xy[k] for xy in template.streets for k in (0, -1)]
                           ).reshape(-1, 2)
    entrances = street_ends[shapely.dwithin(shapely.points(street_ends), t_edge, 1e-3)] \
        if len(street_ends) else street_ends
    sides = []
    for flip in ((np.array([1.0, 1.0]), np.array([-1.0, 1.0]))   # as drawn, mirrored
                 if shapely.get_type_id(outline) == 3 else ()):
        parcels_m = shapely.transform(parcels_, lambda xy: xy * flip)
        t_outline = shapely.union_all(parcels_m, grid_size=1e-6)
        t_ring, t_idx, t_turn = region_corners(t_outline)
        dense = shapely.segmentize(parcels_m, DRAWN_SAMPLE_SPACING)
        rings = [shapely.get_coordinates(shapely.get_exterior_ring(p))[:-1] for p in dense]
        sides.append(_DrawnSide(
            flip, parcels_m, t_outline, t_ring, t_idx, np.sign(t_turn[t_idx]),
            _sides(t_ring, t_idx), np.concatenate(rings),
            np.repeat(np.arange(len(rings)), [len(r) for r in rings]),
            np.concatenate([r - r.mean(axis=0) for r in rings]),
            np.cumsum([len(r) for r in rings])[:-1],
            np.sqrt(np.maximum(shapely.area(dense), 1e-9))))
    for a in [parcels_, labels, entrances] + [v for side in sides for v in vars(side).values()
                                              if isinstance(v, np.ndarray)]:
        a.setflags(write=False)   # shared by every call: read only
    return _DrawnFrame(outline, float(t_long), float(t_short), parcels_, labels, entrances,
                       tuple(sides))


# --------------------------------------------------------------------------- selection

def region_shape(region):
    """(long side, short side of the minimum rectangle, shape distortion) of a region:
    the template-independent part of :func:`fit_energy`, computed once per region."""
    long_side, short_side, _ = minimum_rectangles([region])
    p_angle, p_area, _ = _parcels.lot_quality([region])
    shape = (float(np.nan_to_num(p_area[0], nan=10.0)) - 1.0) + \
        0.5 * float(np.nan_to_num(p_angle[0], nan=45.0)) / 45.0
    return float(long_side[0]), float(short_side[0]), shape


def fit_energy(region, template: Template, length: float, width: float,
               street: float, shape_of=None) -> float:
    """Energy of matching ``template`` to a region bounded by street centre lines.

    ``shape_of`` is :func:`region_shape` of the region when already known. Returns
    ``inf`` when the template cannot fit (wrong depth or too short).
    """
    long_side, short_side, shape = shape_of if shape_of is not None else region_shape(region)
    if shapely.area(region) <= 0 or short_side <= street:
        return math.inf
    net_depth = short_side - street
    net_long = long_side - street
    if template.kind == "rows":
        scale = net_depth / (template.rows * length)
        lo, hi = template.depth_scale
        if not lo <= scale <= hi or net_long < template.width_scale[0] * width:
            return math.inf
        return abs(math.log(scale)) + shape
    # an area template fits anything, at a price: it is the fallback; drawn templates (the
    # built-in spike and loop among them, :func:`built_in_drawn`) are scored by their warp
    # energy (:func:`warp_drawn`)
    return 0.9 if template.kind == "park" else math.inf


#: A vertex of a region whose outline turns by more than this (degrees) is a corner
#: (Yang sec. 4.1, "we first detect the convex and concave corners of R").
CORNER_TURN = 35.0
#: A region corner inside a long side of a row template, turning by at most this
#: (degrees), is taken by a joint between two parcels of the row (see :func:`region_frame`).
LONG_SIDE_BEND = 50.0


def region_corners(poly, min_turn: float = CORNER_TURN):
    """Corners of a polygon's outer ring: (ring (n, 2) counter-clockwise without the
    closing vertex, corner vertex indices, signed turn at every vertex in degrees).

    The turn is measured on the ring simplified by 0.5 m (a streamline's small wiggles
    are not corners) and each corner is put back on the nearest vertex of the exact ring.
    Positive turns are convex corners, negative ones concave (Yang sec. 4.1).
    """
    poly = shapely.geometry.polygon.orient(poly)
    ring = np.asarray(poly.exterior.coords)[:-1]
    coarse = shapely.geometry.polygon.orient(shapely.simplify(poly, 0.5))
    if coarse.geom_type != "Polygon" or coarse.is_empty:
        coarse = poly
    c = np.asarray(coarse.exterior.coords)[:-1]
    turn = ring_turns(c)
    near = cKDTree(ring).query(c)[1]
    full = np.zeros(len(ring))
    full[near] = turn
    idx = np.flatnonzero(np.abs(full) > min_turn)
    return ring, idx, full


def _side_ids(a: int, b: int, n: int) -> np.ndarray:
    """Vertex indices of a ring of ``n`` vertices from corner a to corner b, both included
    (round the closing vertex where b comes before a)."""
    return np.arange(a, b + 1) if b > a else np.r_[np.arange(a, n), np.arange(0, b + 1)]


def region_frame(poly, with_penalty: bool = False):
    """Four corners of a quad-like polygon and its sides (Yang sec. 4.1 initialisation).

    The region's corners (:func:`region_corners`) are matched to the four corners of a
    strip template: with more than four, the four sharpest convex ones are kept and the
    others become regular boundary vertices (their turn is the ``penalty``, in radians);
    with fewer, the sharpest remaining vertices fill in. Returns (c1, c2, e0, e1) as
    coordinate arrays: the two long (street) sides running the same way and the two end
    sides from c1's start to c2's start and from c1's end to c2's end; or None when the
    polygon has no four distinct vertices. ``with_penalty`` adds the penalty.
    """
    poly = shapely.simplify(shapely.geometry.polygon.orient(poly), 0.05)
    if poly.geom_type != "Polygon" or len(poly.exterior.coords) < 5:
        return None
    ring, idx, turn = region_corners(poly)
    order = np.argsort(-turn)                       # convex first, sharpest first
    corner_idx = sorted(int(i) for i in order[:4])
    dropped = [int(i) for i in idx if i not in corner_idx]
    if len(set(corner_idx)) < 4:
        return None
    n = len(ring)
    sides, side_ids = [], []
    for a, b in zip(corner_idx, corner_idx[1:] + corner_idx[:1]):
        ids = _side_ids(a, b, n)
        sides.append(ring[ids % n])
        side_ids.append(set((ids % n).tolist()))
    lengths = [np.hypot(*np.diff(s, axis=0).T).sum() for s in sides]
    k = 0 if lengths[0] + lengths[2] >= lengths[1] + lengths[3] else 1
    # a dropped corner inside a long (street) side is a regular boundary vertex of the
    # repeating parcel row: a joint between two parcels is pinned to it (warp_rows) and
    # its cost is the parcels' registration residual; up to LONG_SIDE_BEND. Any other
    # dropped corner is one the template cannot take: its turn is the penalty.
    along = side_ids[k] | side_ids[(k + 2) % 4]
    penalty = float(sum(np.radians(abs(turn[i])) for i in dropped
                        if not (i in along and abs(turn[i]) <= LONG_SIDE_BEND)))
    c1 = sides[k]
    c2 = sides[(k + 2) % 4][::-1]
    e0 = sides[(k + 3) % 4][::-1]  # from c1's start to c2's start
    e1 = sides[(k + 1) % 4]        # from c1's end to c2's end
    return (c1, c2, e0, e1, penalty) if with_penalty else (c1, c2, e0, e1)


@dataclass
class WarpResult:
    """Parcels of one warped row template and its warp energy.

    Attributes
    ----------
    lots : ndarray of Polygon
    residual : float
        Root mean square registration distance (m) of the parcel corners: the distance
        between each warped corner and its parcel's best registration within the allowed
        deformation class (Yang eq. 1, summed over the parcels, per corner).
    columns : int
        Parcels per row.
    energy : float
        ``residual / width`` plus the turn (radians) of the region corners that the
        template's four corners could not take: the selection energy (sec. 4.1).
    depth_scale : float
        Block depth / template depth.
    long_sides : (ndarray, ndarray)
        The two street sides the rows run along (for the edge labels).
    green : ndarray of bool, optional
        A drawn template's park lots.
    roads : tuple of LineString
        A drawn template's own streets, warped (their surfaces are no lot).
    surface : Polygon or None
        A drawn template's own street surface, warped: what its lots front on there.
    area : ndarray of bool, optional
        A drawn template's area faces (label A): regions of the next level, which the
        layout fills with level-two templates (Yang Fig. 4).
    """

    lots: np.ndarray
    residual: float
    columns: int
    energy: float = 0.0
    depth_scale: float = 1.0
    long_sides: tuple = ()
    green: Optional[np.ndarray] = None
    roads: tuple = ()
    surface: Optional[shapely.Geometry] = None
    area: Optional[np.ndarray] = None


def _project(line, pts: np.ndarray) -> np.ndarray:
    s = shapely.line_locate_point(line, shapely.points(pts))
    return shapely.get_coordinates(shapely.line_interpolate_point(line, s))


def _along(line, t: np.ndarray) -> np.ndarray:
    return shapely.get_coordinates(shapely.line_interpolate_point(line, t, normalized=True))


def _register(grid, quad_r, quad_j, tmpl, wlo, whi, dlo, dhi):
    """Registration (Yang sec. 4.1): every parcel quad of the grid registered to the
    template rectangle by a rotation (Kabsch) and a scaling along the template's axes
    bounded to the allowed ranges (the constrained affine class of a rectangle).
    Returns the registered corners (nq, 4, 2)."""
    q = grid[quad_r, quad_j]                       # (nq, 4, 2)
    cq = q.mean(axis=1, keepdims=True)
    qc = q - cq
    h = np.einsum("ki,nkj->nij", tmpl, qc)
    ang = np.arctan2(h[:, 0, 1] - h[:, 1, 0], h[:, 0, 0] + h[:, 1, 1])
    cos, sin = np.cos(ang), np.sin(ang)
    rot = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], 1)  # (nq,2,2)
    local = np.einsum("nji,nkj->nki", rot, qc)     # R^T q
    sx = np.clip((local[:, :, 0] * tmpl[:, 0]).sum(1) / (tmpl[:, 0] ** 2).sum(), wlo, whi)
    sy = np.clip((local[:, :, 1] * tmpl[:, 1]).sum(1) / (tmpl[:, 1] ** 2).sum(), dlo, dhi)
    return np.einsum("nij,nkj->nki", rot, tmpl[None] * np.stack([sx, sy], -1)[:, None]) + cq


def warp_rows(block, template: Template, length: float, width: float,
              rng: Optional[np.random.Generator], iterations: int = WARP_ITERATIONS,
              cut: bool = True) -> Optional[WarpResult]:
    """Warp a row template (strip or double strip) onto a shrunk block (see module doc).

    Parameters
    ----------
    block : Polygon
        The block shrunk by half the street width (its whole outline is street).
    template : Template (kind 'rows')
    length, width : float
        Template parcel depth and width (m).
    rng : numpy Generator or None
        Draws the number of parcels per row (level one) among the near-best counts; None
        takes the best count (the energy evaluation of the selection).
    cut : bool
        Cut the block into the lots (False: only the energy, for the selection).

    Returns
    -------
    WarpResult, or None when the block has no four corners, its depth is outside the
    template's depth range or its rows would need more than ``max_columns`` parcels.
    """
    frame = region_frame(block, with_penalty=True)
    if frame is None:
        return None
    *sides, penalty = frame
    c1, c2, e0, e1 = (shapely.LineString(s) for s in sides)
    rows = template.rows
    # depth of the block across the rows: mean distance between the two street sides
    probe = _along(c1, np.linspace(0.1, 0.9, 9))
    depth = float(np.mean(shapely.distance(c2, shapely.points(probe))))
    depth_scale = depth / (rows * length)
    dlo, dhi = template.depth_scale
    if not dlo <= depth_scale <= dhi:
        return None
    # level one: parcels per row, drawn among the counts whose width distortion is small
    mean_len = 0.5 * (c1.length + c2.length)
    base = max(1, int(round(mean_len / width)))
    if base > template.max_columns:
        return None
    counts = np.array([c for c in (base - 1, base, base + 1) if c >= 1])
    dev = np.log(mean_len / (counts * width))
    lo, hi = template.width_scale
    w = np.exp(-0.5 * (dev / 0.08) ** 2) * ((mean_len / counts >= lo * width) &
                                              (mean_len / counts <= hi * width) | (counts == base))
    m = int(counts[np.argmax(w)]) if rng is None else int(rng.choice(counts, p=w / w.sum()))
    t = np.linspace(0.0, 1.0, m + 1)
    top, bottom = _along(c1, t), _along(c2, t)
    grid = np.stack([top + (bottom - top) * r / rows for r in range(rows + 1)])  # (rows+1, m+1, 2)
    tmpl = np.array([[0, 0], [width, 0], [width, length], [0, length]], dtype=float)
    tmpl -= tmpl.mean(axis=0)
    r_idx, j_idx = np.meshgrid(np.arange(rows), np.arange(m), indexing="ij")
    r_idx, j_idx = r_idx.ravel(), j_idx.ravel()
    quad_r = np.stack([r_idx, r_idx, r_idx + 1, r_idx + 1], axis=1)
    quad_j = np.stack([j_idx, j_idx + 1, j_idx + 1, j_idx], axis=1)
    wlo, whi = template.width_scale
    # alignment (sec. 4.1): where a street side bends by more than BEND_TURN, the nearest
    # parcel corner on it is pinned to the bend, so that no parcel straddles a bend (its
    # street side would have a corner of 170-135° there)
    pins = []
    for r, side in ((0, sides[0]), (rows, sides[1][::-1])):
        for xy in _bends(side):
            j = int(np.argmin(np.hypot(*(grid[r] - xy).T)))
            if 0 < j < m and np.hypot(*(grid[r, j] - xy)) < 0.5 * mean_len / m:
                pins.append((r, j, xy))
    for _ in range(iterations):
        reg = _register(grid, quad_r, quad_j, tmpl, wlo, whi, dlo, dhi)
        # regression: shared corners to the mean of their registered copies
        acc = np.zeros_like(grid)
        cnt = np.zeros(grid.shape[:2])
        np.add.at(acc, (quad_r, quad_j), reg)
        np.add.at(cnt, (quad_r, quad_j), 1.0)
        new = acc / cnt[..., None]
        # alignment constraints: street sides stay on the street sides, corners fixed
        new[0] = _project(c1, new[0])
        new[rows] = _project(c2, new[rows])
        new[1:rows, 0] = _project(e0, new[1:rows, 0]) if rows > 1 else new[1:rows, 0]
        new[1:rows, m] = _project(e1, new[1:rows, m]) if rows > 1 else new[1:rows, m]
        new[0, 0], new[0, m] = top[0], top[-1]
        new[rows, 0], new[rows, m] = bottom[0], bottom[-1]
        for r, j, xy in pins:
            new[r, j] = xy
        grid = new
    reg = _register(grid, quad_r, quad_j, tmpl, wlo, whi, dlo, dhi)
    residual = float(np.sqrt(np.mean(((reg - grid[quad_r, quad_j]) ** 2).sum(-1))))
    energy = residual / width + penalty
    lots = np.empty(0, dtype=object)
    if cut:
        cuts = [_extend(grid[:, j], 2.0) for j in range(1, m)]
        cuts += [_extend(grid[r, :], 2.0) for r in range(1, rows)]
        lots = _cut(block, cuts)
    return WarpResult(lots, residual, m, energy, depth_scale, (sides[0], sides[1]))


#: A street side that turns by more than this (degrees) at a vertex bends there.
BEND_TURN = 8.0


def _bends(xy: np.ndarray) -> np.ndarray:
    """Interior vertices of a polyline where it turns by more than :data:`BEND_TURN`."""
    xy = np.asarray(xy, dtype=float)
    if len(xy) < 3:
        return np.zeros((0, 2))
    a = xy[1:-1] - xy[:-2]
    b = xy[2:] - xy[1:-1]
    turn = np.degrees(np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(1))))
    return xy[1:-1][turn > BEND_TURN]


def _extend(xy: np.ndarray, ext: float, ends=(True, True)) -> shapely.LineString:
    """The polyline extended straight on by ``ext`` at its first and/or last end."""
    xy = np.asarray(xy, dtype=float)
    d0 = xy[0] - xy[1]
    d1 = xy[-1] - xy[-2]
    d0 /= max(np.hypot(*d0), 1e-12)
    d1 /= max(np.hypot(*d1), 1e-12)
    return shapely.LineString(np.vstack([xy[0] + ext * d0] * bool(ends[0]) + [xy]
                                        + [xy[-1] + ext * d1] * bool(ends[1])))


def end_ray_hit(xy: np.ndarray, end: int, target, reach: float) -> Optional[np.ndarray]:
    """Where the polyline ``xy`` carried straight on from its end (0 or -1) by up to
    ``reach`` first meets ``target`` (a line geometry), or None."""
    prev = 1 if end == 0 else -2
    d = xy[end] - xy[prev]
    d = d / max(float(np.hypot(*d)), 1e-9)
    hit = shapely.get_coordinates(shapely.intersection(
        shapely.LineString([xy[end], xy[end] + reach * d]), target))
    return hit[np.argmin(np.hypot(*(hit - xy[end]).T))] if len(hit) else None


def _cut(block, cuts) -> np.ndarray:
    """Faces of the block cut by the lines (the block's exact outline is kept)."""
    if not cuts:
        return _parcels._polygon_parts([block])
    with np.errstate(invalid="ignore", divide="ignore"):
        # the cut lines cross the outline (they are extended beyond it), so that noding
        # splits the outline at proper crossings; their outer ends are dangles
        noded = shapely.union_all(np.concatenate([[shapely.boundary(block)],
                                                  np.asarray(cuts, dtype=object)]))
        faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(noded)))
    if len(faces) == 0:
        return _parcels._polygon_parts([block])
    inside = shapely.within(shapely.point_on_surface(faces), block)
    return _parcels._polygon_parts(faces[inside])


#: A vertex where a drawn face's outline turns by more than this (degrees) is a node of
#: the regressed mesh (:class:`_DrawnMesh`); the points of a curve between nodes follow.
MESH_NODE_TURN = 20.0

#: Samples of a drawn template's outline and the region's (m apart, at most) that define
#: the warp: the outlines correspond corner to corner, and by arc length in between.
DRAWN_SAMPLE_SPACING = 2.0


def _sides(ring: np.ndarray, corners: np.ndarray) -> List[shapely.LineString]:
    """The outline between consecutive corners, as lines (counter-clockwise)."""
    return [shapely.LineString(ring[_side_ids(a, b, len(ring)) % len(ring)])
            for a, b in zip(corners, np.roll(corners, -1))]


def _register_faces(t: np.ndarray, w: np.ndarray, face: np.ndarray, n: int,
                    wlo, whi, dlo, dhi) -> np.ndarray:
    """The registration of :func:`_register` for faces of any shape at once: each face's
    drawn vertices ``t`` (its frame, centred on the face) turned (Kabsch) and scaled along
    the frame's axes within the allowed ranges onto its warped vertices ``w`` (the same
    rows); ``face`` says which of the ``n`` faces a row belongs to. Returns the registered
    vertices. Sums by face (no BLAS: the same digits under every processor kernel)."""
    def by_face(v):
        return np.bincount(face, v, n)

    count = np.bincount(face, minlength=n)
    cw = np.stack([by_face(w[:, 0]), by_face(w[:, 1])], 1) / np.maximum(count, 1)[:, None]
    w = w - cw[face]
    ang = np.arctan2(by_face(t[:, 0] * w[:, 1]) - by_face(t[:, 1] * w[:, 0]),
                     by_face(t[:, 0] * w[:, 0]) + by_face(t[:, 1] * w[:, 1]))
    c, s = np.cos(ang)[face], np.sin(ang)[face]
    lx, ly = w[:, 0] * c + w[:, 1] * s, -w[:, 0] * s + w[:, 1] * c     # R^T w
    sx = np.clip(by_face(lx * t[:, 0]) / np.maximum(by_face(t[:, 0] ** 2), 1e-12), wlo, whi)
    sy = np.clip(by_face(ly * t[:, 1]) / np.maximum(by_face(t[:, 1] ** 2), 1e-12), dlo, dhi)
    tx, ty = t[:, 0] * sx[face], t[:, 1] * sy[face]
    return np.stack([c * tx - s * ty, s * tx + c * ty], 1) + cw[face]


class _DrawnMesh:
    """The regression of a drawn template's parcel mesh (Yang sec. 4.1, as
    :func:`warp_rows` does for rows): the noded vertices of the parcel boundaries start at
    their mean value warp; each face (parcel, park, street surface) is registered to its
    drawn shape (:func:`_register_faces`) and every node of the mesh (a vertex
    where a face's outline turns by more than :data:`MESH_NODE_TURN`: lot corners,
    junctions) moves to the mean of its registered copies; the other vertices (the points
    of a drawn curve, a cul-de-sac's turning circle) follow their nodes' displacement,
    interpolated linearly, so that a curve moves as a whole and cannot fold; vertices of
    the outline slide along the block side they were warped onto and the matched corners
    stay; :data:`WARP_ITERATIONS` rounds. Points that are no vertex (street centre lines,
    inner points) are carried the same way (:meth:`carry`)."""

    def __init__(self, pieces, edge, t_sides, b_sides, src, dst, wlo, whi, dlo, dhi):
        self.src, self.dst = src, dst
        # the drawn coordinates, a T's node of both lines once
        verts = np.unique(np.round(shapely.get_coordinates(pieces), 6), axis=0)
        nv = len(verts)
        self.tree = cKDTree(verts)
        self.start = warp_points(verts, src, dst)
        faces = shapely.get_parts(shapely.polygonize(pieces))
        rings = [shapely.get_coordinates(shapely.get_exterior_ring(f))[:-1] for f in faces]
        idx = np.concatenate([self.tree.query(r)[1] for r in rings])
        face = np.repeat(np.arange(len(rings)), [len(r) for r in rings])
        tmpl = np.concatenate(rings)
        n = len(rings)
        count = np.bincount(face, minlength=n)
        centre = np.stack([np.bincount(face, tmpl[:, k], n) for k in (0, 1)], 1) / count[:, None]
        t = tmpl - centre[face]
        on_side = np.full(nv, -1)
        pts = shapely.points(verts)
        on_edge = shapely.dwithin(pts, edge, 1e-6)
        if on_edge.any():
            d = np.stack([shapely.distance(pts[on_edge], side) for side in t_sides], 1)
            on_side[on_edge] = np.argmin(d, axis=1)
        corners = np.unique(self.tree.query(np.array(
            [shapely.get_coordinates(side)[0] for side in t_sides]))[1])
        node = np.zeros(nv, dtype=bool)
        node[corners] = True
        node[idx[np.abs(np.concatenate([ring_turns(r) for r in rings])) > MESH_NODE_TURN]] = True
        follow = _linear_weights(self.start[node], self.start[~node])
        pos = self.start.copy()
        for _ in range(WARP_ITERATIONS):
            reg = _register_faces(t, pos[idx], face, n, wlo, whi, dlo, dhi)
            acc = np.stack([np.bincount(idx, reg[:, k], nv) for k in (0, 1)], 1)
            cnt = np.bincount(idx, minlength=nv)
            new = np.where(cnt[:, None] > 0, acc / np.maximum(cnt, 1)[:, None], pos)
            new[~node] = self.start[~node] + _interpolate(follow, new[node] - self.start[node])
            for k, side in enumerate(b_sides):
                sel = on_side == k
                if sel.any():
                    new[sel] = _project(side, new[sel])
            new[corners] = self.start[corners]
            pos = new
        self.regressed, self.pos = pos, pos
        self._on_side, self._b_sides = on_side, b_sides
        self._edge, self._t_sides = edge, t_sides
        #: faces of the drawn mesh (the lots a clean cut gives, its own slivers left out)
        self.n_faces = int((shapely.area(faces) > 1e-3).sum())

    def damp(self, share: float) -> None:
        """Take only ``share`` of the regression's displacement (outline vertices kept on
        their sides)."""
        pos = self.start + share * (self.regressed - self.start)
        for k, side in enumerate(self._b_sides):
            sel = self._on_side == k
            if sel.any() and 0.0 < share < 1.0:
                pos[sel] = _project(side, pos[sel])
        self.pos = pos

    def vertices_at(self, xy: np.ndarray) -> np.ndarray:
        """The regressed positions of mesh vertices given in the template's frame (other
        points are carried)."""
        d, i = self.tree.query(xy)
        out = self.pos[i]
        far = d > 1e-5
        if far.any():
            out[far] = self.carry(xy[far])
        return out

    def carry(self, xy: np.ndarray) -> np.ndarray:
        """Points of the template's frame warped: the mean value warp plus the vertices'
        displacement by the regression, interpolated linearly (nearest outside them); a
        point on the template's outline (where its own street enters) stays on its side of
        the block, as the outline's vertices do."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        moved = warp_points(xy, self.src, self.dst)
        out = moved + _interpolate(_linear_weights(self.start, moved), self.pos - self.start)
        pts = shapely.points(xy)
        on_edge = shapely.dwithin(pts, self._edge, 1e-3)
        if on_edge.any():
            side = np.argmin(np.stack([shapely.distance(pts[on_edge], t)
                                       for t in self._t_sides], 1), axis=1)
            rows = np.flatnonzero(on_edge)
            for k in np.unique(side):
                out[rows[side == k]] = _project(self._b_sides[k], out[rows[side == k]])
        return out


def _linear_weights(at: np.ndarray, query: np.ndarray):
    """Indices into ``at`` (n, 3) and weights (n, 3) that interpolate values given at the
    points ``at`` linearly over their Delaunay triangles at the points ``query``; outside
    them, the nearest point's value."""
    query = np.asarray(query, dtype=float).reshape(-1, 2)
    tri = Delaunay(at)
    simplex = tri.find_simplex(query)
    inside = simplex >= 0
    tr = tri.transform[np.maximum(simplex, 0)]
    b = np.einsum("nij,nj->ni", tr[:, :2], query - tr[:, 2])
    weights = np.c_[b, 1.0 - b.sum(axis=1)]
    index = tri.simplices[np.maximum(simplex, 0)]
    if not inside.all():
        index[~inside] = cKDTree(at).query(query[~inside])[1][:, None]
        weights[~inside] = 1.0 / 3.0
    return index, weights


def _interpolate(weights, values: np.ndarray) -> np.ndarray:
    """Values (m, 2) at the points of :func:`_linear_weights` interpolated (no BLAS)."""
    index, w = weights
    return np.einsum("nk,nkj->nj", w, values[index])


def warp_drawn(block, template: Template, cut: bool = True,
               entrance_ok=None) -> Optional[WarpResult]:
    """A drawn template warped onto a block as drawn (Yang sec. 4.1, for any template).

    The template's outline corners (:func:`region_corners`) are matched to the block's in
    cyclic order -- every rotation of the correspondence and the mirrored template tried --
    and both outlines are sampled at the same arc-length fractions between matched corners
    (at most :data:`DRAWN_SAMPLE_SPACING` m apart); the parcels are mapped by mean value
    coordinates on those samples (Floater 2003, :mod:`retrieval.warp`). The warp energy is
    the root mean square distance of each warped parcel's vertices from its registration
    to the drawn parcel (turned and scaled along its axes within the template's width and
    depth scales), divided by the square root of the drawn parcel's area: the residual of
    the row templates for any parcel shape. The correspondence of least energy is kept.
    Its parcel mesh is then regressed as the rows' grid is (:class:`_DrawnMesh`: each
    face registered to its drawn shape, shared vertices to the mean of their registered
    copies, outline vertices sliding along their block side, corners fixed): the mean
    value warp spreads a block's skew over every lot, the regression gives it back to the
    lots along the outline (a spike on a block skewed by 12°: its lots' mean corner
    deviation 12° -> 4°); where the regressed cut leaves other faces than the drawn ones
    (a fold), the displacement is halved until it does not. The lots are the block cut
    along the regressed inner parcel boundaries, straight between their drawn vertices as
    drawn (its exact outline kept, so the lots tile it); a lot takes the label of the
    drawn parcel whose inner point it holds (P: a park, ``green``; A: an area of the next
    level, ``area``; S: the template's own street, no lot: its centre lines, warped and
    moved with the mesh, are ``roads``).

    A block with more corners than the template (turning by more than
    :data:`CORNER_TURN`) gives the template's corners to its sharpest ones, and the turn
    (radians) of the others is added to the energy, as for the row templates
    (:func:`region_frame`); with fewer, its sharpest other vertices take the rest. Corners
    are labelled convex or concave (Yang sec. 4.1): a correspondence that puts a convex
    corner of the template on a concave corner of the block, or the other way round, is
    not taken (a vertex that only fills in for a missing corner takes either). Returns None
    when the block has fewer vertices than the template has corners or its size is outside
    the template's scales (its minimum rectangle against the outline's, width_scale along
    the long side and depth_scale across), or when ``entrance_ok`` (points -> bool) refuses
    every correspondence: it says whether the warped points where the template's own
    streets leave its outline may join the street around the block (edge labels: not a
    "no street" edge, not a motorway).
    """
    if block is None or shapely.get_type_id(block) != 3 or not template.parcels:
        return None
    frame = _drawn_frame(template)
    if shapely.get_type_id(frame.outline) != 3:
        return None
    (b_long,), (b_short,), _ = minimum_rectangles([block])
    sx, sy = b_long / max(frame.long, 1e-9), b_short / max(frame.short, 1e-9)
    (wlo, whi), (dlo, dhi) = template.width_scale, template.depth_scale
    if not (wlo <= sx <= whi and dlo <= sy <= dhi):
        return None
    b_ring, b_idx, b_turn = region_corners(block)
    parcels_, labels, entrances = frame.parcels, frame.labels, frame.entrances
    best = None
    for side in frame.sides:   # as drawn, mirrored
        flip, parcels_m, t_outline, t_sides = side.flip, side.parcels, side.outline, side.sides
        t_label, verts, face, centred = side.label, side.verts, side.face, side.centred
        ends, root_area = side.ends, side.root_area
        k = len(side.corners)
        if k < 3 or k > len(b_ring):
            continue
        # the block's k sharpest vertices take the template's corners (more corners: the
        # others are bends the warp absorbs, their turn the penalty; fewer: the sharpest
        # other vertices fill in), as the row templates' frame does with four
        keep = np.sort(np.argsort(-np.abs(b_turn), kind="stable")[:k])
        penalty = float(np.radians(np.abs(b_turn[np.setdiff1d(b_idx, keep)])).sum())
        # corner labels (the template's: +1 convex, -1 concave), 0 a block vertex filling
        # in (either); every parcel registered to its drawn shape at once (below)
        b_label = np.where(np.abs(b_turn[keep]) > CORNER_TURN, np.sign(b_turn[keep]), 0.0)
        for shift in range(k):
            on = np.roll(b_label, -shift)
            if ((on != 0) & (on != t_label)).any():
                continue   # a convex corner on a concave one, or the other way round
            b_sides = _sides(b_ring, np.roll(keep, -shift))
            src, dst = [], []
            for ts, bs in zip(t_sides, b_sides):
                m = max(2, int(math.ceil(max(ts.length, bs.length) / DRAWN_SAMPLE_SPACING)))
                f = np.arange(m) / m
                src.append(_along(ts, f))
                dst.append(_along(bs, f))
            src, dst = np.concatenate(src), np.concatenate(dst)
            moved = warp_points(verts, src, dst)
            reg = _register_faces(centred, moved, face, len(root_area), wlo, whi, dlo, dhi)
            sq = np.split(((reg - moved) ** 2).sum(axis=1), ends)
            rms = np.sqrt([float(v.mean()) for v in sq])
            energy = float(np.mean(rms / root_area)) + penalty
            if entrance_ok is not None and len(entrances) and \
                    not entrance_ok(warp_points(entrances * flip, src, dst)):
                continue   # its street would enter from no street (edge labels)
            if best is None or energy < best[0]:
                best = (energy, flip, src, dst, parcels_m, t_outline, t_sides, b_sides)
    if best is None:
        return None
    energy, flip, src, dst, parcels_m, t_outline, t_sides, b_sides = best
    if not cut:
        return WarpResult(np.empty(0, dtype=object), energy, len(parcels_), energy, sy)
    edge = shapely.boundary(t_outline)
    pieces = shapely.get_parts(shapely.node(shapely.union_all(shapely.boundary(parcels_m))))
    mesh = _DrawnMesh(pieces, edge, t_sides, b_sides, src, dst, wlo, whi, dlo, dhi)
    # the inner parcel boundaries, noded in the template's frame (a T is a vertex of both
    # lines, so the warped lines meet exactly), warped, and extended across the outline
    mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    inner = pieces[~shapely.dwithin(mid, edge, 1e-6)]
    inner = shapely.get_parts(shapely.line_merge(shapely.union_all(inner)))
    # where the regression would fold the mesh (a narrow neck of a drawn street surface
    # between two lots pulled apart: the cut leaves a sliver), its displacement is halved
    # until the cut gives the drawn faces again; none of it, the mean value warp as before
    for share in (1.0, 0.5, 0.25, 0.0):
        mesh.damp(share)
        cuts = []
        for line in inner:
            xy = shapely.get_coordinates(line)
            on_edge = shapely.dwithin(shapely.points(xy[[0, -1]]), edge, 1e-6)
            cuts.append(_extend(mesh.vertices_at(xy), 3 * DRAWN_SAMPLE_SPACING, on_edge))
        lots = _cut(block, cuts)
        if len(lots) == mesh.n_faces:
            break
    # the template's own streets, warped (mirrored with the template)
    roads = []
    for xy in template.streets:
        line = shapely.segmentize(shapely.LineString(np.asarray(xy, dtype=float) * flip),
                                  DRAWN_SAMPLE_SPACING)
        roads.append(shapely.LineString(mesh.carry(shapely.get_coordinates(line))))
    # each lot takes the label of the drawn parcel whose inner point it holds
    inside = shapely.points(mesh.carry(shapely.get_coordinates(
        shapely.point_on_surface(parcels_m))))
    li, pi = shapely.STRtree(lots).query(inside, predicate="within")[::-1]
    if len(template.parcel_groups) == len(parcels_) and \
            len(set(template.parcel_groups)) < len(parcels_):
        lots, li, pi = _rejoin_pieces(lots, li, pi, np.asarray(template.parcel_groups))
    green, area, street = (np.zeros(len(lots), dtype=bool) for _ in range(3))
    green[li] = labels[pi] == "P"
    area[li] = labels[pi] == "A"
    street[li] = labels[pi] == "S"
    return WarpResult(lots[~street], energy, len(parcels_), energy, sy, green=green[~street],
                      roads=tuple(roads),
                      surface=shapely.union_all(lots[street]) if street.any() else None,
                      area=area[~street])


def _rejoin_pieces(lots, li, pi, groups):
    """The lots of the pieces of one drawn parcel (``groups``: its index per template
    piece; ``li``/``pi``: lot and piece of each label) joined into one lot again. Returns
    the lots and the (lot, piece) label pairs, one per lot."""
    owner = np.full(len(lots), -1)
    owner[li] = groups[pi]
    piece_of = dict(zip(li.tolist(), pi.tolist()))
    out, out_li, out_pi = [], [], []
    done = set()
    for k in range(len(lots)):
        g = owner[k]
        if g >= 0 and g in done:
            continue
        members = [k] if g < 0 else np.flatnonzero(owner == g).tolist()
        out.append(lots[k] if len(members) == 1 else shapely.union_all(lots[members]))
        if k in piece_of:
            out_li.append(len(out) - 1)
            out_pi.append(piece_of[k])
        done.add(g)
    return np.asarray(out, dtype=object), np.asarray(out_li, dtype=np.int64), \
        np.asarray(out_pi, dtype=np.int64)


def spike_geometry(length: float, width: float, street: float, lots_per_side: int = 4):
    """The built-in spike (Yang Fig. 2, "spikes"), drawn in metres as a block of lots at
    the layout's parcel size: a straight cul-de-sac of the street width from the middle of
    one side, ``lots_per_side`` lots (``width`` along it, ``length`` deep) on each side
    facing it, and two lots across its end, each fronting half of it. Returns (polygons,
    labels: R per lot, S the street surface)."""
    L, W, S = float(length), float(width), float(street)
    across, run = 2 * L + S, lots_per_side * W
    polys = [shapely.box(x0, k * W, x0 + L, (k + 1) * W)
             for k in range(lots_per_side) for x0 in (0.0, L + S)]
    polys += [shapely.box(0, run, across / 2, run + L), shapely.box(across / 2, run, across, run + L)]
    return polys + [shapely.box(L, 0, L + S, run)], ["R"] * len(polys) + ["S"]


def loop_geometry(length: float, width: float, street: float, inner_columns: int = 4):
    """The built-in loop (Yang Fig. 2/4), drawn in metres at the layout's parcel size: a
    ring street of the street width one lot deep inside the block, joined to the middle of
    one side by a connector; a band of lots (``length`` deep, about ``width`` wide) round
    the block between its streets and the ring, and two rows of ``inner_columns`` lots
    back to back inside the ring. Returns (polygons, labels: R per lot, S the street
    surface)."""
    L, W, S = float(length), float(width), float(street)
    across, deep = 2 * L + 2 * S + inner_columns * W, 4 * L + 2 * S

    def row(x0, y0, x1, y1, along_x=True):
        n = max(1, int(round(((x1 - x0) if along_x else (y1 - y0)) / W)))
        cuts = np.linspace(x0, x1, n + 1) if along_x else np.linspace(y0, y1, n + 1)
        return [shapely.box(a, y0, b, y1) if along_x else shapely.box(x0, a, x1, b)
                for a, b in zip(cuts[:-1], cuts[1:])]

    mid = across / 2
    polys = row(0, 0, mid - S / 2, L) + row(mid + S / 2, 0, across, L) + \
        row(0, deep - L, across, deep) + row(0, L, L, deep - L, along_x=False) + \
        row(across - L, L, across, deep - L, along_x=False)
    core = (L + S, L + S, across - L - S, deep - L - S)
    half = (core[1] + core[3]) / 2
    polys += row(core[0], core[1], core[2], half) + row(core[0], half, core[2], core[3])
    ring = shapely.difference(shapely.box(L, L, across - L, deep - L), shapely.box(*core))
    surface = shapely.union(ring, shapely.box(mid - S / 2, 0, mid + S / 2, L))
    return polys + [surface], ["R"] * len(polys) + ["S"]


@lru_cache(maxsize=16)
def _built_in(kind: str, length: float, width: float, street: float) -> Template:
    polys, labels = (spike_geometry if kind == "spike" else loop_geometry)(length, width,
                                                                          street)
    return _drawn_template(kind, np.asarray(polys, dtype=object), np.asarray(labels))


def built_in_drawn(template: Template, length: float, width: float,
                   street: float) -> Template:
    """The built-in spike or loop as a drawn template at the layout's parcel ``length`` x
    ``width`` and ``street`` width (:func:`spike_geometry`, :func:`loop_geometry`), so that
    it is warped as drawn and selected by its warp energy like any drawn template (Yang
    sec. 4.1); it keeps the library entry's name, label, probability, scales and count
    limit. Any other template is returned as it is."""
    if template.kind not in ("spike", "loop"):
        return template
    drawn = _built_in(template.kind, float(length), float(width), float(street))
    return replace(drawn, name=template.name, label=template.label,
                   probability=template.probability, width_scale=template.width_scale,
                   depth_scale=template.depth_scale, max_count=template.max_count,
                   min_count=template.min_count,
                   land_use=template.land_use)
