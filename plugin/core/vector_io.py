"""GeoPackage layers <-> (pandas table, shapely geometries) through GDAL's own bindings.

The example databases are GeoPackages that QGIS opens directly. They are written and read
with ``osgeo.ogr``, the GDAL that every QGIS ships with and links against, not with the
pyogrio/geopandas wheels: those bundle a second GDAL, which crashes a QGIS process
(docs/ARCHITECTURE.md, "Native libraries") and which a QGIS user would have to install.
"""
from __future__ import annotations

import os
from typing import Optional, Tuple

import numpy as np
import pandas as pd
import shapely

from .progress import InputError

__all__ = ["write_layer", "read_layer"]

_GEOMETRY_TYPES = {"Point": 1, "LineString": 2, "Polygon": 3, "MultiPoint": 4,
                   "MultiLineString": 5, "MultiPolygon": 6}
_SHAPELY_TYPES = {"Point": 0, "LineString": 1, "Polygon": 3}


def _ogr():
    # imported here: the engine's other modules stay importable without GDAL bindings
    from osgeo import ogr, osr

    ogr.UseExceptions()
    osr.UseExceptions()
    return ogr, osr


def _field_type(ogr, series: pd.Series):
    """The OGR field type (and subtype) that stores a column without loss."""
    kind = series.dtype.kind
    if str(series.dtype) == "boolean" or kind == "b":
        return ogr.OFTInteger, ogr.OFSTBoolean
    if kind in "iu" or str(series.dtype).startswith(("Int", "UInt")):
        return ogr.OFTInteger64, ogr.OFSTNone
    if kind == "f":
        return ogr.OFTReal, ogr.OFSTNone
    return ogr.OFTString, ogr.OFSTNone


def _python_value(value):
    if value is None or value is pd.NA or (isinstance(value, float) and np.isnan(value)):
        return None
    if isinstance(value, (np.bool_, bool)):
        return int(bool(value))
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def write_layer(path: str, layer: str, table: pd.DataFrame, geometry, crs: str,
                geometry_type: str) -> None:
    """Add a layer to a GeoPackage (created if missing).

    Parameters
    ----------
    path : GeoPackage file
    layer : layer name
    table : one row per geometry; numbers, booleans (nullable) and text columns
    geometry : shapely geometries; single parts are promoted when ``geometry_type`` is Multi
    crs : authority id (``EPSG:32635``) or WKT; empty for none
    geometry_type : 'Polygon', 'MultiPolygon', 'LineString', ...
    """
    ogr, osr = _ogr()
    geometry = np.asarray(geometry, dtype=object)
    table = table.reset_index(drop=True)
    if len(table) != len(geometry):
        raise ValueError("one table row per geometry is needed")
    if geometry_type.startswith("Multi") and len(geometry):
        # shapely's own type id of the single part (OGR's are not shapely's: Polygon is 3
        # in both, LineString 2 in OGR and 1 in shapely)
        single = shapely.get_type_id(geometry) == _SHAPELY_TYPES[geometry_type[5:]]
        promote = {"MultiPolygon": shapely.multipolygons, "MultiLineString":
                   shapely.multilinestrings, "MultiPoint": shapely.multipoints}[geometry_type]
        geometry = geometry.copy()
        geometry[single] = [promote([g]) for g in geometry[single]]
    driver = ogr.GetDriverByName("GPKG")
    ds = ogr.Open(path, 1) if os.path.exists(path) else driver.CreateDataSource(path)
    srs = None
    if crs:
        srs = osr.SpatialReference()
        srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
        srs.SetFromUserInput(crs)
    lyr = ds.CreateLayer(layer, srs, _GEOMETRY_TYPES[geometry_type], ["SPATIAL_INDEX=YES"])
    for name in table.columns:
        ftype, subtype = _field_type(ogr, table[name])
        definition = ogr.FieldDefn(str(name), ftype)
        definition.SetSubType(subtype)
        lyr.CreateField(definition)
    wkb = shapely.to_wkb(geometry)
    names = [str(c) for c in table.columns]
    columns = [table[c].astype(object).to_numpy() for c in table.columns]
    defn = lyr.GetLayerDefn()
    lyr.StartTransaction()
    for i in range(len(table)):
        feature = ogr.Feature(defn)
        for j, name in enumerate(names):
            value = _python_value(columns[j][i])
            if value is None:
                feature.SetFieldNull(j)
            else:
                feature.SetField(name, value)
        if geometry[i] is not None:
            feature.SetGeometry(ogr.CreateGeometryFromWkb(wkb[i]))
        lyr.CreateFeature(feature)
    lyr.CommitTransaction()
    ds = None  # noqa: F841 - closes and flushes the file


def read_layer(path, layer: str) -> Tuple[pd.DataFrame, Optional[np.ndarray]]:
    """A GeoPackage layer as (attribute table, shapely geometries or None)."""
    ogr, _ = _ogr()
    try:
        ds = ogr.Open(str(path), 0)
        lyr = ds.GetLayerByName(layer) if ds is not None else None
    except RuntimeError as exc:
        raise InputError(f"{path}: layer '{layer}' cannot be read ({exc})") from exc
    if lyr is None:
        raise InputError(f"{path}: layer '{layer}' cannot be read (no such layer)")
    defn = lyr.GetLayerDefn()
    fields = [defn.GetFieldDefn(i) for i in range(defn.GetFieldCount())]
    rows, wkbs = [], []
    for feature in lyr:
        rows.append([None if feature.IsFieldNull(i) else feature.GetField(i)
                     for i in range(len(fields))])
        geom = feature.GetGeometryRef()
        wkbs.append(None if geom is None else bytes(geom.ExportToIsoWkb()))
    table = pd.DataFrame(rows, columns=[f.GetName() for f in fields])
    for i, f in enumerate(fields):
        name = f.GetName()
        col = table[name]
        # as pyogrio reads them: integers with nulls become floats with NaN
        if f.GetSubType() == ogr.OFSTBoolean:
            table[name] = col.astype("boolean") if col.isna().any() else col.astype(bool)
        elif f.GetType() in (ogr.OFTInteger, ogr.OFTInteger64):
            table[name] = col.astype(np.float64) if col.isna().any() else col.astype(np.int64)
        elif f.GetType() == ogr.OFTReal:
            table[name] = table[name].astype(np.float64)
    geoms = None
    if lyr.GetGeomType() != ogr.wkbNone:
        geoms = shapely.from_wkb(np.array(wkbs, dtype=object))
    return table, geoms
