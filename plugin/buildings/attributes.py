"""Building attributes normalised from OSM tags or cadastre fields.

The block database of Hartmann's thesis stores each block with its footprints and their
semantics (ch. 4.1.2: "optional semantics (... building density, building heights,
footprints)"; ch. 5.1 places 3D buildings by an architectural style map, ch. 6
synthesises buildings per footprint). Real attribute data is sparse and messy
(docs/ARCHITECTURE.md, "Real example data": 165 of Helsinki's ~490 buildings have
``building:levels``, 17 a ``height``; values such as ``"12.13 m"`` occur), so every
building gets:

- ``height_m``: from a height value (``height``, ``building:height``, or a cadastre field
  named by the user), else ``levels x storey height`` with ``height_estimated`` True,
  else missing;
- ``levels``: from ``building:levels`` (or a cadastre field), else
  ``round(height / storey height)`` with ``levels_estimated`` True, else missing;
- ``building_type``: one of :data:`BUILDING_TYPES`, from the OSM ``building`` value, else
  from ``building:use``, ``amenity``, ``shop``, ``office``, ``tourism``, ``craft``,
  ``industrial`` or ``religion``;
- the raw values (``building_tag``, ``height_tag``, ``levels_tag``, ``roof_shape``) so that
  nothing is lost by the normalisation.

Parsing is deliberately forgiving: ``"12"``, ``"12.5 m"``, ``"12,5"``, ``"40'"``,
``"40 ft"``, ``"12'6\""``, ``"~12"``, ``"12-15"`` and ``"12;15"`` all give a number (for
lists and ranges the largest value: the building is as tall as its tallest part);
anything else gives NaN, never an exception.
"""
from __future__ import annotations

import math
import re
from typing import Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from ..core.progress import InputError
from ..network.street_graph import parse_other_tags

__all__ = [
    "STOREY_HEIGHT", "BUILDING_TYPES", "TYPE_OF_BUILDING_VALUE", "ATTRIBUTE_FIELDS", "TAG_FIELDS",
    "parse_height", "parse_levels", "building_type", "building_attributes",
]

#: Default storey height (m) to estimate heights from levels and levels from heights.
STOREY_HEIGHT = 3.0
#: The normalised vocabulary of ``building_type``.
BUILDING_TYPES = ("residential", "commercial", "industrial", "public", "religious", "other",
                  "unknown")
#: Output columns of :func:`building_attributes` with their types.
ATTRIBUTE_FIELDS = [
    ("height_m", "float"), ("height_estimated", "bool"), ("levels", "float"),
    ("levels_estimated", "bool"), ("building_type", "str"), ("building_tag", "str"),
    ("height_tag", "str"), ("levels_tag", "str"), ("roof_shape", "str"),
]

_MAX_HEIGHT = 1000.0   # the tallest building is 828 m: anything above is a typo
_MAX_LEVELS = 250.0

_GROUPS = {
    "residential": (
        "residential", "apartments", "house", "detached", "semidetached_house",
        "semi-detached", "terrace", "terraced_house", "bungalow", "cabin", "dormitory",
        "farm", "houseboat", "static_caravan", "villa", "flats", "hut_residential",
        "row_house", "home", "housing",
    ),
    "commercial": (
        "commercial", "retail", "office", "supermarket", "kiosk", "hotel", "shop", "shops",
        "mall", "store", "bank", "restaurant", "motel", "hostel", "market", "offices",
    ),
    "industrial": (
        "industrial", "warehouse", "factory", "manufacture", "storage_tank", "hangar",
        "depot", "works", "workshop", "silo", "digester", "utility", "power", "plant",
    ),
    "public": (
        "public", "civic", "government", "school", "university", "college", "kindergarten",
        "hospital", "fire_station", "police", "townhall", "train_station", "transportation",
        "museum", "library", "sports_hall", "stadium", "sports_centre", "theatre", "clinic",
        "courthouse", "prison", "military", "education", "healthcare", "community_centre",
        "toilets", "post_office", "bus_station", "arts_centre", "social_facility",
        "grandstand", "gymnasium",
    ),
    "religious": (
        "religious", "church", "cathedral", "chapel", "mosque", "synagogue", "temple",
        "shrine", "monastery", "presbytery", "place_of_worship", "convent", "mausoleum",
    ),
}
#: OSM ``building`` (and ``building:use``, ``amenity`` ...) values -> building type.
TYPE_OF_BUILDING_VALUE = {v: t for t, values in _GROUPS.items() for v in values}
#: Values that say "a building" without saying which kind.
_GENERIC = {"yes", "true", "1", "building", "y", "unknown", "undefined", ""}
#: Tags consulted, in order, when the ``building`` value is generic.
_HINT_TAGS = ("building:use", "amenity", "shop", "office", "tourism", "craft", "industrial",
              "religion", "healthcare", "leisure")
#: Every tag :func:`building_attributes` reads: the columns an OSM 'multipolygons' layer (or
#: a cadastre) is read with when present.
TAG_FIELDS = ("height", "building:height", "building:levels", "levels", "roof:shape") + \
    _HINT_TAGS
_HINT_DEFAULT = {"shop": "commercial", "office": "commercial", "craft": "industrial",
                 "industrial": "industrial", "religion": "religious",
                 "healthcare": "public"}

_NUMBER = r"[-+]?\d+(?:[.,]\d+)?"
_FEET_INCHES = re.compile(
    rf"^\s*({_NUMBER})\s*(?:'|ft|feet|foot)\s*(?:({_NUMBER})\s*(?:\"|''|in|inch|inches)?)?\s*$")
_WITH_UNIT = re.compile(rf"^\s*({_NUMBER})\s*(m|meter|meters|metre|metres|cm|mm|km)?\s*$")


def _to_float(text: str) -> float:
    # a single comma between digits is a decimal comma ("12,5"), never a list in OSM
    return float(text.replace(",", "."))


def _parts(value) -> list:
    """Split a tag value into candidate numbers: lists (;) and ranges (a-b)."""
    text = str(value).strip().lower()
    for prefix in ("~", "ca.", "ca", "approx.", "approx", "about", "<", ">", "≈"):
        if text.startswith(prefix):
            text = text[len(prefix):].strip()
    parts = []
    for piece in text.split(";"):
        piece = piece.strip().rstrip("+").strip()
        # a range "12-15" (not a negative number): both ends are candidates
        m = re.match(rf"^({_NUMBER})\s*-\s*({_NUMBER})(.*)$", piece)
        if m:
            parts += [m.group(1) + m.group(3), m.group(2) + m.group(3)]
        elif piece:
            parts.append(piece)
    return parts


def _is_missing(value) -> bool:
    if value is None:
        return True
    if isinstance(value, float) and math.isnan(value):
        return True
    return isinstance(value, str) and not value.strip()


def parse_height(value) -> float:
    """A height in metres from an OSM or cadastre value; NaN when it is not one.

    Parameters
    ----------
    value : str, number or None
        ``"12"``, ``"12.5 m"``, ``"12,5"``, ``"40'"``, ``"40 ft"``, ``"12'6\""``,
        ``"~12"``, ``"12-15"`` (the largest), ``"12;15"`` (the largest), ``12.0``.

    Returns
    -------
    float
        Metres, in (0, 1000]; NaN for missing, unparsable, non-positive or absurd values.

    Examples
    --------
    >>> parse_height("12.5 m"), parse_height("40'"), parse_height("12;15"), parse_height("tall")
    (12.5, 12.192, 15.0, nan)
    """
    if _is_missing(value):
        return math.nan
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        h = float(value)
        return h if 0 < h <= _MAX_HEIGHT else math.nan
    best = math.nan
    for part in _parts(value):
        h = math.nan
        m = _FEET_INCHES.match(part)
        if m:
            inches = _to_float(m.group(2)) if m.group(2) else 0.0
            h = _to_float(m.group(1)) * 0.3048 + inches * 0.0254
        else:
            m = _WITH_UNIT.match(part)
            if m:
                scale = {"cm": 0.01, "mm": 0.001, "km": 1000.0}.get(m.group(2) or "m", 1.0)
                h = _to_float(m.group(1)) * scale
        if 0 < h <= _MAX_HEIGHT and not h <= best:
            best = round(h, 3)
    return best


def parse_levels(value) -> float:
    """A number of storeys from an OSM or cadastre value; NaN when it is not one.

    ``"5"``, ``"3.5"`` (half storeys exist in OSM), ``"5;6"`` and ``"5-6"`` (the largest),
    ``"5+"``, ``5``. Zero is kept (roofs, carports); negatives and absurd values are NaN.

    Examples
    --------
    >>> parse_levels("5"), parse_levels("2.5"), parse_levels("4;6"), parse_levels("many")
    (5.0, 2.5, 6.0, nan)
    """
    if _is_missing(value):
        return math.nan
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        n = float(value)
        return n if 0 <= n <= _MAX_LEVELS else math.nan
    best = math.nan
    for part in _parts(value):
        try:
            n = _to_float(part)
        except ValueError:
            continue
        if 0 <= n <= _MAX_LEVELS and not n <= best:
            best = n
    return best


def building_type(building=None, tags: Optional[Mapping] = None) -> str:
    """Normalise an OSM building value (and hint tags) into :data:`BUILDING_TYPES`.

    A specific ``building`` value decides (``apartments`` -> residential, ``warehouse`` ->
    industrial, ``church`` -> religious ...). A generic one (``yes``) or a missing one is
    refined by ``building:use``, ``amenity``, ``shop``, ``office``, ``tourism``, ``craft``,
    ``industrial``, ``religion`` in that order. A specific value outside the vocabulary
    (``roof``, ``shed``, ``garage``, ``ship``) is ``other``; nothing known is ``unknown``.

    Examples
    --------
    >>> building_type("apartments"), building_type("yes", {"amenity": "school"})
    ('residential', 'public')
    >>> building_type("yes"), building_type("shed"), building_type(None, {"shop": "bakery"})
    ('unknown', 'other', 'commercial')
    """
    value = "" if _is_missing(building) else str(building).strip().lower()
    if value in TYPE_OF_BUILDING_VALUE:
        return TYPE_OF_BUILDING_VALUE[value]
    tags = tags or {}
    for key in _HINT_TAGS:
        hint = tags.get(key)
        if _is_missing(hint) or str(hint).strip().lower() in ("no", "none"):
            continue
        hint = str(hint).strip().lower()
        if hint in TYPE_OF_BUILDING_VALUE:
            return TYPE_OF_BUILDING_VALUE[hint]
        if key in _HINT_DEFAULT:
            return _HINT_DEFAULT[key]
        if key == "tourism" and hint in ("hotel", "hostel", "guest_house", "motel", "apartment"):
            return "commercial"
    if value in _GENERIC or value == "no":
        return "unknown"
    return "other"


def _column(values, n: int) -> np.ndarray:
    if values is None:
        return np.full(n, None, dtype=object)
    values = np.asarray(values, dtype=object)
    if len(values) != n:
        raise InputError(f"attribute columns differ in length ({len(values)} != {n})")
    return values


def _first_present(*candidates):
    for c in candidates:
        if not _is_missing(c):
            return c
    return None


def unreadable_values(values: Sequence, parse) -> list:
    """The values given but not readable by ``parse`` (:func:`parse_height`,
    :func:`parse_levels`, a street's ``street_surfaces.parse_width``): text that is no
    number, negatives, absurd sizes. Such a value is none (NaN) to the parser's user; the
    caller says how many there were.

    >>> unreadable_values(["12", None, "tall", -3, 8.5], parse_height)
    ['tall', -3]
    """
    return [v for v in values if not _is_missing(v) and math.isnan(parse(v))]


def building_attributes(n: int, building: Optional[Sequence] = None,
                        other_tags: Optional[Sequence] = None,
                        tags: Optional[Mapping[str, Sequence]] = None,
                        height: Optional[Sequence] = None, levels: Optional[Sequence] = None,
                        storey_height: float = STOREY_HEIGHT) -> pd.DataFrame:
    """Normalised height, levels and type for ``n`` buildings.

    Parameters
    ----------
    n : int
        Number of buildings.
    building : sequence, optional
        The OSM ``building`` value per building (GDAL's ``multipolygons`` layer has it as a
        field).
    other_tags : sequence of str, optional
        GDAL's hstore-like ``other_tags`` per building: ``height``, ``building:height``,
        ``building:levels``, ``roof:shape``, ``building:use``, ``amenity`` ... are read from it.
    tags : mapping of column name -> sequence, optional
        Tag columns that are separate fields (``amenity``, ``shop``, ``office`` ... in the
        ``multipolygons`` layer, or ``height`` in a cadastre layer); they win over
        ``other_tags``.
    height, levels : sequence, optional
        Cadastre fields named by the user; they win over everything else.
    storey_height : float
        Metres per storey, for the estimates (default :data:`STOREY_HEIGHT`).

    Returns
    -------
    DataFrame
        The columns of :data:`ATTRIBUTE_FIELDS`, one row per building. ``height_m`` and
        ``levels`` are NaN when nothing is known; ``height_estimated`` is True when the
        height comes from levels, False when it was given, missing when there is none
        (likewise ``levels_estimated``).

    References
    ----------
    Hartmann, thesis ch. 4.1.2 and 5.1 (block database with footprint semantics);
    docs/ARCHITECTURE.md, "Real example data" (165 of ~490 Helsinki buildings have levels).

    Examples
    --------
    >>> df = building_attributes(2, building=["apartments", "yes"],
    ...                          other_tags=['"building:levels"=>"5"', '"height"=>"12 m"'])
    >>> df[["height_m", "height_estimated", "levels", "levels_estimated"]].values.tolist()
    [[15.0, True, 5.0, False], [12.0, False, 4.0, True]]
    """
    if not (storey_height > 0 and math.isfinite(storey_height)):
        raise InputError("the storey height must be a positive number of metres")
    building = _column(building, n)
    other = _column(other_tags, n)
    tag_cols = {k: _column(v, n) for k, v in (tags or {}).items()}
    height_in, levels_in = _column(height, n), _column(levels, n)

    height_tag = np.full(n, None, dtype=object)
    levels_tag = np.full(n, None, dtype=object)
    roof = np.full(n, None, dtype=object)
    btype = np.empty(n, dtype=object)
    building_tag = np.full(n, None, dtype=object)
    h = np.full(n, np.nan)
    lv = np.full(n, np.nan)
    # per-building work is string parsing: a loop, but over a few thousand short strings
    for i in range(n):
        t = parse_other_tags(other[i]) if not _is_missing(other[i]) else {}
        for key, col in tag_cols.items():
            if not _is_missing(col[i]):
                t[key] = col[i]
        raw_h = _first_present(height_in[i], t.get("height"), t.get("building:height"),
                               t.get("est_height"))
        raw_l = _first_present(levels_in[i], t.get("building:levels"), t.get("levels"))
        height_tag[i] = None if raw_h is None else str(raw_h)
        levels_tag[i] = None if raw_l is None else str(raw_l)
        h[i] = parse_height(raw_h)
        lv[i] = parse_levels(raw_l)
        b = building[i] if not _is_missing(building[i]) else t.get("building")
        building_tag[i] = None if _is_missing(b) else str(b)
        btype[i] = building_type(b, t)
        shape = t.get("roof:shape")
        roof[i] = None if _is_missing(shape) else str(shape)

    has_h, has_l = ~np.isnan(h), ~np.isnan(lv)
    # heights from levels only for buildings with at least one storey (levels 0: roofs)
    est_h = ~has_h & has_l & (lv > 0)
    est_l = has_h & ~has_l
    height_m = np.where(est_h, lv * storey_height, h)
    levels_out = np.where(est_l, np.maximum(np.round(h / storey_height), 1.0), lv)
    height_estimated = pd.array(np.where(has_h, False, est_h), dtype="boolean")
    height_estimated[~(has_h | est_h)] = pd.NA
    levels_estimated = pd.array(est_l, dtype="boolean")
    levels_estimated[~(has_l | est_l)] = pd.NA
    return pd.DataFrame({
        "height_m": height_m, "height_estimated": height_estimated, "levels": levels_out,
        "levels_estimated": levels_estimated, "building_type": btype,
        "building_tag": building_tag, "height_tag": height_tag, "levels_tag": levels_tag,
        "roof_shape": roof,
    })
