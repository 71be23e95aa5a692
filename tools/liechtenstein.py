"""The towns of the Liechtenstein extract (``../shared/data``) for training and
leave-one-town-out checks: drivable roads in UTM 32N and a built-up outline per town.

The extract (OpenStreetMap, 2013-08-03, ODbL, (c) OpenStreetMap contributors) has the 11
municipalities as ``admin_level`` 8 multipolygons; they reach far into forest and
mountains, so a town is the built-up part of its municipality: residential and living
streets buffered by 80 m, closed by +150 m / -200 m, cut by the municipality, largest part,
holes filled, simplified at 5 m; towns under 0.4 km² are left out (all 11 stay).

Used by ``tools/streetgan/prepare.py`` (training images, held-out towns) and the tests
(``tests/helpers.py``). Runs with the plugin's venv (pyogrio, shapely).
"""
from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "build" / "plugins") not in sys.path:
    sys.path.insert(0, str(ROOT / "build" / "plugins"))

from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402

#: EPSG code of the metric CRS used for Liechtenstein (UTM 32N)
CRS = 32632


def extract_path() -> Path:
    """The shared extract: ``<worktree>/../shared/data`` or ``/work/shared/data``."""
    for base in (ROOT.parent / "shared", ROOT.parent.parent / "shared", Path("/work/shared")):
        p = base / "data" / "liechtenstein-2013-08-03.osm.pbf"
        if p.exists():
            return p
    raise FileNotFoundError("liechtenstein-2013-08-03.osm.pbf not found next to the checkout")


@lru_cache(maxsize=1)
def drivable_roads():
    """Drivable roads of the extract in UTM 32N: (lines, highway classes)."""
    import pyogrio

    df = pyogrio.read_dataframe(extract_path(), layer="lines")
    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(CRS)
    return np.asarray(df.geometry.values, dtype=object), df.highway.to_numpy(dtype=object)


@lru_cache(maxsize=1)
def towns(min_area: float = 0.4e6) -> dict:
    """{name: built-up outline Polygon (UTM 32N)} of the towns (see the module docstring)."""
    import pyogrio

    lines, cls = drivable_roads()
    res = lines[np.isin(cls, ["residential", "living_street"])]
    built = shapely.union_all(shapely.buffer(res, 80.0)).buffer(150.0).buffer(-200.0)
    mp = pyogrio.read_dataframe(extract_path(), layer="multipolygons",
                                columns=["name", "admin_level"])
    mp = mp[mp.admin_level == "8"].to_crs(CRS)
    out = {}
    for name, poly in zip(mp.name, mp.geometry):
        parts = shapely.get_parts(shapely.intersection(built, shapely.make_valid(poly)))
        parts = parts[shapely.get_type_id(parts) == 3]
        if not len(parts):
            continue
        big = shapely.Polygon(parts[np.argmax(shapely.area(parts))].exterior).simplify(5.0)
        if big.area >= min_area:
            out[name] = big
    return dict(sorted(out.items()))


def clip(lines, area, classes=None):
    """Single-part pieces of ``lines`` inside ``area`` (and their classes)."""
    lines = np.asarray(lines, dtype=object)
    with np.errstate(invalid="ignore"):
        parts, idx = shapely.get_parts(shapely.intersection(lines, area), return_index=True)
    keep = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.5)
    if classes is None:
        return parts[keep]
    return parts[keep], np.asarray(classes, dtype=object)[idx[keep]]


_CACHE = {}


def leave_one_out(name: str) -> dict:
    """A town as a leave-one-town-out case, in UTM 32N: ``area`` (its outline), ``real``
    (its drivable streets), ``given`` + ``given_class`` (its level-0 roads, from the
    hierarchy of the whole country's network), ``example`` + ``example_class`` (the streets
    of all other towns) and ``example_area`` (their outlines)."""
    from urban_synthesis.plugin.network import hierarchy

    if "graph" not in _CACHE:
        lines, cls = drivable_roads()
        graph = roads.clean_network(lines, cls)
        _CACHE["graph"] = graph
        _CACHE["level"] = hierarchy.road_hierarchy(graph).edge_level
    graph, level = _CACHE["graph"], _CACHE["level"]
    all_towns = towns()
    if name not in all_towns:
        raise KeyError(f"unknown town {name!r} (towns: {', '.join(all_towns)})")
    area = all_towns[name]
    others = shapely.union_all([a for n, a in all_towns.items() if n != name])
    given, given_class = clip(graph.geometry[level == 0], area, graph.road_class[level == 0])
    example, example_class = clip(graph.geometry, others, graph.road_class)
    return {"area": area, "real": clip(graph.geometry, area), "given": given,
            "given_class": given_class, "example": example, "example_class": example_class,
            "example_area": others}
