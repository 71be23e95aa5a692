"""Real towns for the fidelity benchmark and its tests: boundaries, drivable streets, levels.

Liechtenstein (``/work/shared/data/liechtenstein-2013-08-03.osm.pbf`` or
``$URBANSYNTH_LI_PBF``): the admin_level=8 multipolygons are the eleven municipalities
(the place=* points inside each name its villages); a municipality is a town when at least
``MIN_STREET_KM`` of drivable streets lie in its settlement envelope. Helsinki and Bubeneč
come from the example data. Data is read with pyogrio (plain Python, no QGIS).

A town's **boundary** is its settlement envelope: the drivable streets inside the
municipality buffered by 120 m and shrunk by 100 m (a morphological closing that fills gaps
between streets up to ~240 m and leaves a 20 m margin), holes filled (fields enclosed by
the town's roads belong to it), cut to the municipality, parts under 0.2 km² dropped. It
says where the town is, not where its minor streets are. Its **given roads** are its level-0
roads (:mod:`plugin.network.hierarchy`, OSM primary / secondary where present, computed on
the whole country's network) clipped to the boundary.

Helsinki and Bubeneč are extracts: their streets stop where the extract was cut, and those
cut ends are no dead ends. Their envelope is therefore also cut to the convex hull of the
streets (the extract's coverage as far as the data tells), which puts the cut ends on the
boundary, where the statistics do not count them (before, all 11 of Bubeneč's dead ends and
35 of Helsinki's 47 were cut ends 17.7 m inside the envelope: dead-end shares 0.44 and 0.28
instead of 0.07 and 0.18).

© OpenStreetMap contributors, ODbL.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List

import numpy as np
import shapely

from conftest import BUBENEC, HELSINKI
from urban_synthesis.plugin.measure import metrics
from urban_synthesis.plugin.network import hierarchy
from urban_synthesis.plugin.network import street_graph as sg

LI_PBF = Path(os.environ.get("URBANSYNTH_LI_PBF",
                             "/work/shared/data/liechtenstein-2013-08-03.osm.pbf"))
#: Settlement envelope (metrics.settled_area, closed by 120 m / 100 m): smallest part kept (m²).
ENVELOPE_MIN_PART = 2e5
#: A municipality is a town when this much drivable street (km) lies in its envelope.
MIN_STREET_KM = 15.0


@dataclass
class Town:
    """One town: its boundary, its real drivable streets (with levels and classes) inside."""

    name: str
    region: str
    area: shapely.Geometry              # settlement envelope (metric CRS)
    lines: np.ndarray                   # real drivable streets clipped to the area
    level: np.ndarray                   # hierarchy level per line
    road_class: np.ndarray
    villages: List[str] = field(default_factory=list)

    @property
    def given(self) -> np.ndarray:
        return self.lines[self.level == 0]

    @property
    def given_class(self) -> np.ndarray:
        return self.road_class[self.level == 0]

    @property
    def km2(self) -> float:
        return self.area.area / 1e6


def _drivable_graph(df):
    tags = [sg.parse_other_tags(t) for t in df.other_tags] if "other_tags" in df else []
    z = [sg.vertical_layer(t.get("layer"), t.get("bridge"), t.get("tunnel")) for t in tags] \
        if tags else None
    g = sg.clean_network(df.geometry.values, df.highway.values,
                         df.name.values if "name" in df else None, z)
    return g, hierarchy.road_hierarchy(g).edge_level


def envelope(streets: np.ndarray, within=None) -> shapely.Geometry:
    """Settlement envelope of a street network (see the module docstring)."""
    return metrics.settled_area(streets, within, ENVELOPE_MIN_PART)


def _coverage(streets: np.ndarray) -> shapely.Geometry:
    """What an extract covers, as far as its streets tell: their convex hull (the streets
    that were cut when the extract was made end on it)."""
    return shapely.convex_hull(shapely.multilinestrings(list(streets)))


def _town(name, region, area, g, level, villages=()):
    with np.errstate(invalid="ignore"):
        cut = shapely.intersection(g.geometry, area)
    parts, idx = shapely.get_parts(cut, return_index=True)
    keep = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)
    return Town(name, region, area, parts[keep], np.asarray(level)[idx[keep]],
                np.asarray(g.road_class, dtype=object)[idx[keep]], list(villages))


def liechtenstein_towns() -> List[Town]:
    import pyogrio

    crs = 32632
    lines = pyogrio.read_dataframe(LI_PBF, layer="lines",
                                   columns=["highway", "name", "other_tags"]).to_crs(crs)
    lines = lines[lines.highway.isin(sg.DRIVABLE_CLASSES)].reset_index(drop=True)
    munis = pyogrio.read_dataframe(LI_PBF, layer="multipolygons", columns=["name", "admin_level"],
                                   where="admin_level='8'").to_crs(crs)
    places = pyogrio.read_dataframe(LI_PBF, layer="points", columns=["name", "place"])
    places = places[places.place.isin(["town", "village", "suburb", "hamlet"])].to_crs(crs)
    g, level = _drivable_graph(lines)
    towns = []
    for _, m in munis.sort_values("name").iterrows():
        inside = g.geometry[shapely.intersects(m.geometry, g.geometry)]
        if not len(inside):
            continue
        env = envelope(inside, m.geometry)
        if env.is_empty:
            continue
        villages = sorted(set(places.name[shapely.within(places.geometry.values, m.geometry)]))
        t = _town(m["name"], "Liechtenstein", env, g, level, villages)
        if shapely.length(t.lines).sum() / 1000 >= MIN_STREET_KM:
            towns.append(t)
    return towns


def helsinki_town() -> Town:
    import pyogrio

    df = pyogrio.read_dataframe(HELSINKI, layer="lines").to_crs(32635)
    df = df[df.highway.isin(sg.DRIVABLE_CLASSES)].reset_index(drop=True)
    g, level = _drivable_graph(df)
    return _town("Helsinki", "Helsinki", envelope(g.geometry, _coverage(g.geometry)), g, level)


def bubenec_town() -> Town:
    import pyogrio

    df = pyogrio.read_dataframe(BUBENEC, layer="streets").to_crs(32633)
    df["highway"] = "residential"   # the momepy streets carry no class: all drivable
    g, level = _drivable_graph(df)
    return _town("Bubenec", "Prague", envelope(g.geometry, _coverage(g.geometry)), g, level)
