"""Shared test helpers (plain functions, importable from any test module)."""
from functools import lru_cache

import numpy as np
import shapely

from conftest import BUBENEC, HELSINKI


@lru_cache(maxsize=1)
def _helsinki_lines():
    import pyogrio

    return pyogrio.read_dataframe(HELSINKI, layer="lines")


def helsinki_roads(crs=32635):
    """Drivable Helsinki roads in UTM 35N with a vertical layer column ``z``."""
    from urban_synthesis.plugin import roads

    df = _helsinki_lines()
    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(crs).reset_index(drop=True)
    tags = [roads.parse_other_tags(t) for t in df.other_tags]
    df["z"] = [roads.vertical_layer(t.get("layer"), t.get("bridge"), t.get("tunnel")) for t in tags]
    return df


def bubenec(layer, crs=32633):
    import pyogrio

    return pyogrio.read_dataframe(BUBENEC, layer=layer).to_crs(crs)


def assert_planar(lines, z_layer=None, tol=1e-6):
    """No two edges of the same vertical layer meet except at shared end points."""
    lines = np.asarray(lines, dtype=object)
    z = np.zeros(len(lines), dtype=int) if z_layer is None else np.asarray(z_layer)
    tree = shapely.STRtree(lines)
    a, b = tree.query(lines, predicate="intersects")
    sel = (a < b) & (z[a] == z[b])
    a, b = a[sel], b[sel]
    ends = shapely.union_all([shapely.boundary(lines[a]), shapely.boundary(lines[b])], axis=0) \
        if len(a) else []
    inter = shapely.intersection(lines[a], lines[b])
    # the intersection of two edges must be a subset of their end points
    bad = ~shapely.covers(shapely.buffer(ends, tol), inter) if len(a) else np.zeros(0, bool)
    assert not bad.any(), f"{int(bad.sum())} pairs of edges cross or overlap away from a node"


def layer_features(layer):
    """A QGIS layer's features as (rows: list of dicts with NULL as None, shapely geometries)."""
    from qgis.PyQt.QtCore import QVariant

    feats = list(layer.getFeatures())
    names = [f.name() for f in layer.fields()]
    rows = [{k: None if isinstance(v, QVariant) and v.isNull() else v
             for k, v in zip(names, f.attributes())} for f in feats]
    geoms = shapely.from_wkb([bytes(f.geometry().asWkb()) if f.hasGeometry() else None
                              for f in feats]) if feats else np.empty(0, dtype=object)
    return rows, geoms


def layer_rows(layer):
    """A QGIS layer's attribute rows (dicts, NULL as None)."""
    return layer_features(layer)[0]


def clipped_metrics(lines, area):
    """Layout metrics of the part of a network inside ``area`` (the same cut for an
    original, a synthesis and a baseline)."""
    from urban_synthesis.plugin import metrics

    with np.errstate(invalid="ignore", divide="ignore"):  # empty intersections outside
        parts = shapely.get_parts(shapely.intersection(np.asarray(lines, object), area))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)]
    return metrics.compute_layout_metrics(roads=parts)
