"""The only module that converts between QGIS objects and engine data.

Data flows one way: QGIS layer -> :func:`read_source` (features reprojected into a local
metric CRS, geometries as shapely arrays, attributes as a pandas DataFrame) -> engine ->
:func:`write_sink` (back to the input CRS). Engine errors (:class:`InputError`) become
:class:`QgsProcessingException` with the layer's name; the engine's :class:`Canceled` becomes
:class:`ProcessingCanceled`, a QgsProcessingException of its own type, so that callers tell a
cancel from a failure by type, never by searching the message.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsCoordinateTransform,
    QgsCsException,
    QgsDistanceArea,
    QgsFeature,
    QgsFeatureRequest,
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsGeometry,
    QgsPointXY,
    QgsProcessingException,
    QgsProcessingFeatureSource,
    QgsProcessingParameterDefinition,
    QgsProcessingFeatureSourceDefinition,
    QgsProcessingFeedback,
    QgsProject,
    QgsRectangle,
    QgsUnitTypes,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QVariant

from ..core import coordinates
from ..core import crs as crs_rule
from . import dependencies, outputs, styles
from ..core.progress import Canceled, InputError, MissingPackage, Progress
from ..core.text import counted

_GEOM_NAMES = {QgsWkbTypes.GeometryType.PointGeometry: "points", QgsWkbTypes.GeometryType.LineGeometry: "lines",
               QgsWkbTypes.GeometryType.PolygonGeometry: "polygons"}
_KIND_TO_GEOMTYPE = {"points": QgsWkbTypes.GeometryType.PointGeometry, "lines": QgsWkbTypes.GeometryType.LineGeometry,
                     "polygons": QgsWkbTypes.GeometryType.PolygonGeometry}


def geometry_kind(alg, parameters, name: str, context) -> Optional[str]:
    """'points', 'lines' or 'polygons': what a source parameter's layer holds (None when it
    is not given or holds mixed types), known before it is read."""
    source = alg.parameterAsSource(parameters, name, context)
    gtype = None if source is None else QgsWkbTypes.geometryType(source.wkbType())
    return next((kind for kind, g in _KIND_TO_GEOMTYPE.items() if g == gtype), None)


def unknown_parameters(alg, parameters) -> List[str]:
    """A warning for each name in ``parameters`` that is none of the algorithm's (or the
    model's) parameters or outputs, with the nearest names: QGIS ignores them silently, so
    a typo on the command line (SNAP_TOLERENCE) ran with the default, and another tool's
    parameter (EXAMPLE_ROADS given to synthesizeroadsgan) did nothing."""
    import difflib

    names = [d.name() for d in alg.parameterDefinitions()] + \
        [d.name() for d in alg.outputDefinitions()]
    warnings = []
    for name in parameters:
        if not isinstance(name, str) or name in names:
            continue
        near = difflib.get_close_matches(name.upper(), names, n=2, cutoff=0.6)
        hint = f" Did you mean {' or '.join(near)}?" if near else ""
        warnings.append(f"{name} is not a parameter of {alg.name()}: ignored.{hint}")
    return warnings


class ProcessingCanceled(QgsProcessingException):
    """The user canceled the run (a QgsProcessingException, so QGIS ends the run with its
    message; a type of its own, so the plugin's code and tests tell it from a failure)."""

    def __init__(self, message: str = "Canceled by the user."):
        super().__init__(message)


def stop_if_canceled(feedback) -> None:
    """Raise :class:`ProcessingCanceled` when the user asked to stop."""
    if feedback is not None and feedback.isCanceled():
        raise ProcessingCanceled()


# --------------------------------------------------------------------------- CRS

def working_crs(crs: QgsCoordinateReferenceSystem, extent_in_crs: QgsRectangle,
                context) -> QgsCoordinateReferenceSystem:
    """The metric CRS the engine works in, by the plugin's rule (:func:`core.crs.working_crs`:
    a projected CRS in metres as it is, unless its scale at the data is more than 1 % off
    true (Web Mercator, World Mercator ...); else the UTM zone of the data's centre)."""
    def scale_error() -> float:
        """How far 100 CRS metres east and north of the data's centre are from 100 m on the
        CRS's ellipsoid (QGIS's own measure); 0 where it cannot tell."""
        da = QgsDistanceArea()
        da.setSourceCrs(crs, context.transformContext())
        da.setEllipsoid(crs.ellipsoidAcronym() or "WGS84")
        if not da.willUseEllipsoid():
            return 0.0
        c, step, errors = extent_in_crs.center(), 100.0, []
        for dx, dy in ((step, 0.0), (0.0, step)):
            try:
                true = da.measureLine(QgsPointXY(c.x() - dx / 2, c.y() - dy / 2),
                                      QgsPointXY(c.x() + dx / 2, c.y() + dy / 2))
            except QgsCsException:
                return 0.0
            if math.isfinite(true) and true > 0:
                errors.append(abs(step / true - 1.0))
        return max(errors, default=0.0)

    def centre_lonlat():
        centre = extent_in_crs.center()
        wgs84 = QgsCoordinateReferenceSystem("EPSG:4326")
        if crs.isValid() and crs != wgs84:
            try:
                tr = QgsCoordinateTransform(crs, wgs84, context.transformContext())
                centre = tr.transform(centre)
            except Exception as exc:  # noqa: BLE001 - QgsCsException: a CRS PROJ cannot use
                raise QgsProcessingException(
                    f"The data's CRS ({crs_label(crs)}) cannot be transformed to longitude and "
                    "latitude to choose a metric working CRS: assign a known CRS to the layer "
                    "(Layer Properties > Source).") from exc
        return centre.x(), centre.y()

    projected_in_metres = (crs.isValid() and not crs.isGeographic()
                           and crs.mapUnits() == QgsUnitTypes.DistanceUnit.DistanceMeters)
    try:
        code = crs_rule.working_crs(crs.authid(), projected_in_metres, centre_lonlat,
                                    scale_error)
    except InputError as exc:
        raise QgsProcessingException(f"Cannot find a metric CRS for the data: {exc}.") from exc
    return crs if code is None else QgsCoordinateReferenceSystem(code)


def crs_label(crs: QgsCoordinateReferenceSystem) -> str:
    """A CRS for messages: 'EPSG:3857 (WGS 84 / Pseudo-Mercator)', or what it is without one."""
    if not crs.isValid():
        return "no CRS"
    name = crs.description() if crs.description() not in ("", "unknown") else \
        crs.toProj() or "an unnamed CRS"
    return f"{crs.authid()} ({name})" if crs.authid() else f"'{name}'"


def working_crs_note(label: str, src: QgsCoordinateReferenceSystem,
                     work: QgsCoordinateReferenceSystem, chosen: bool = True) -> str:
    """The log line saying which CRS a layer is worked in: every length, area and
    distance in metres is measured there."""
    if src == work:
        return f"{label}: worked in its own CRS, {crs_label(work)}."
    why = "not in metres" if src.isGeographic() or \
        src.mapUnits() != QgsUnitTypes.DistanceUnit.DistanceMeters else \
        "more than 1 % off true scale here"
    return (f"{label} is in {crs_label(src)} ({why}): worked in {crs_label(work)}."
            if chosen else
            f"{label} is in {crs_label(src)}: projected to the working CRS, {crs_label(work)}.")


def usable_crs(crs: QgsCoordinateReferenceSystem) -> bool:
    """Whether a CRS says what the coordinates are: valid, and not one of GeoPackage's
    placeholders for 'no CRS' (srs_id 0 'Undefined geographic SRS', -1 'Undefined Cartesian
    SRS'), which QGIS reads as valid CRSs without an authority id."""
    if not crs.isValid():
        return False
    if crs.authid():
        return True
    return bool(crs.toProj()) and not crs.description().lower().startswith("undefined")


def extent_parameter(alg, parameters, name: str, context, label: str):
    """An extent parameter and its CRS: its own (``'xmin,xmax,ymin,ymax [EPSG:3067]'``, a
    layer's), else the project's. An extent with neither is refused, as a layer without a
    CRS is (:func:`read_source`): its numbers were taken as metres of no CRS and the output
    was written with an undefined one."""
    rect = alg.parameterAsExtent(parameters, name, context)
    crs = alg.parameterAsExtentCrs(parameters, name, context)
    if not usable_crs(crs):
        raise QgsProcessingException(
            f"The {label} has no coordinate reference system (CRS), so its units are "
            "unknown: give it with its CRS, as 'xmin,xmax,ymin,ymax [EPSG:code]' (the "
            "dialog's extent does that), or run in a project with a CRS.")
    return rect, crs


def point_parameter(alg, parameters, name: str, context, work_crs, default_crs, label: str,
                    feedback=None, near=None, near_label: str = "the layer"):
    """A point parameter in the working CRS: from its own CRS (``'x,y [EPSG:4326]'``),
    else the project's, else ``default_crs`` (the layer it belongs to; said in the log).
    A point without a CRS was taken in the working CRS, which the user never sees: the
    boundary's own coordinates put the centre hundreds of kilometres away. ``near``:
    bounds (working CRS) the point may lie at most their diagonal away from, else it is
    refused (a wrong CRS)."""
    point = alg.parameterAsPoint(parameters, name, context)
    crs = alg.parameterAsPointCrs(parameters, name, context)
    if not usable_crs(crs):
        crs = default_crs
        if feedback is not None:
            feedback.pushInfo(f"{label} has no CRS: read in {crs_label(crs)}, the CRS of "
                              "its layer (give 'x,y [EPSG:code]' for another).")
    if crs != work_crs:
        try:
            point = QgsCoordinateTransform(crs, work_crs, context.transformContext()
                                           ).transform(point)
        except QgsCsException as exc:
            raise QgsProcessingException(
                f"{label} ({point.x():g}, {point.y():g}) cannot be transformed from "
                f"{crs_label(crs)} to {crs_label(work_crs)}: check its CRS.") from exc
    if near is not None:
        far = shapely.distance(shapely.box(*near), shapely.Point(point.x(), point.y()))
        if not far <= math.hypot(near[2] - near[0], near[3] - near[1]):
            raise QgsProcessingException(
                f"{label}, read in {crs_label(crs)}, lies {far:,.0f} m from {near_label}: "
                "check its coordinates and CRS ('x,y [EPSG:code]').")
    return point.x(), point.y()


@dataclass
class Frame:
    """Features of one layer in the working CRS."""

    geometry: np.ndarray          # shapely geometries
    attributes: pd.DataFrame      # one row per geometry, original field names
    fids: np.ndarray              # feature ids in the source
    source_crs: QgsCoordinateReferenceSystem
    crs: QgsCoordinateReferenceSystem  # the working CRS
    name: str
    #: {field name in the layer: the name it is read as} for the fields a shapefile cut
    #: short (:func:`read_source`): carry them under their full names (:func:`carried_fields`)
    renamed: Dict[str, str] = dataclass_field(default_factory=dict)

    def __len__(self):
        return len(self.geometry)


def _vector_layer(alg, parameters, name, context):
    """The vector layer a source parameter names, also one given with "Selected features
    only" (a QgsProcessingFeatureSourceDefinition, which parameterAsVectorLayer does not
    resolve on 3.22); None for sources that are no layer."""
    try:
        layer = alg.parameterAsVectorLayer(parameters, name, context)
    except Exception:  # noqa: BLE001 - sources that are not layers (e.g. feature iterators)
        layer = None
    value = parameters.get(name) if isinstance(parameters, dict) else None
    if layer is None and isinstance(value, QgsProcessingFeatureSourceDefinition):
        try:
            layer = alg.parameterAsVectorLayer(
                {name: value.source.staticValue()}, name, context)
        except Exception:  # noqa: BLE001 - an expression-based source: no layer
            layer = None
    return layer


def layer_name(alg, parameters, name, context) -> str:
    """A name for messages: the layer's name, else the parameter's description.

    A layer given with "Selected features only" (a QgsProcessingFeatureSourceDefinition,
    which parameterAsVectorLayer does not resolve on 3.22) is named too, and said to be
    its selection: "layer 'Region' is empty" named no layer of the user's, and the layer
    was not empty, its selection was.
    """
    layer = _vector_layer(alg, parameters, name, context)
    value = parameters.get(name) if isinstance(parameters, dict) else None
    definition = value if isinstance(value, QgsProcessingFeatureSourceDefinition) else None
    selected = " (selected features)" if definition is not None and \
        definition.selectedFeaturesOnly else ""
    if layer is not None and layer.name():
        # 'Helsinki' is both the lines and the multipolygons of one .osm.pbf: say which
        sub = layer.source().split("|layername=")
        if len(sub) > 1 and sub[1].split("|")[0] and sub[1].split("|")[0] != layer.name():
            return f"'{layer.name()} ({sub[1].split('|')[0]})'{selected}"
        return f"'{layer.name()}'{selected}"
    definition = alg.parameterDefinition(name)
    return f"'{definition.description()}'" if definition is not None else f"'{name}'"


def field_aliases(alg, parameters, name, context, source) -> Dict[str, str]:
    """{alias: field name} of a source: the layer's own aliases, else those of the sidecar
    style of a file layer (Processing opens a file without its default style, and the
    plugin's shapefile outputs keep the full names GDAL cut there:
    ``styles.save_style_with_layer``)."""
    aliases = {f.alias(): f.name() for f in source.fields() if f.alias()}
    if aliases:
        return aliases
    # the layer of a selection too: Processing loads its outputs without their sidecar
    # style, so a selection in one had no full names to be read by
    layer = _vector_layer(alg, parameters, name, context)
    if layer is None or layer.providerType() != "ogr":
        return {}
    qml = Path(layer.source().split("|")[0]).with_suffix(".qml")
    if not qml.is_file():
        return {}
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(qml).getroot()
    except (ElementTree.ParseError, OSError):
        return {}
    return {a.get("name"): a.get("field") for a in root.iter("alias")
            if a.get("name") and a.get("field")}


def _cut_by_gdal(full: str, short: str) -> bool:
    """Whether ``short`` is a name GDAL gives the field ``full`` in a shapefile: its ten
    first characters, or fewer numbered ('tortuosity_b' -> 'tortuosi_1'). Only such an
    alias names a field read in full where every field is read: a user's alias ('Height
    (m)') is no field name of the plugin's."""
    cut = styles.DBF_NAME_LENGTH
    if len(full) <= cut or len(short) > cut or not full.isidentifier():
        return False
    if short == full[:cut]:
        return True
    stem, _, number = short.rpartition("_")
    return number.isdigit() and bool(stem) and full.startswith(stem)


def read_source(alg, parameters, name: str, context, feedback,
                kind: Optional[str] = None, required_fields: Sequence[str] = (),
                target_crs: Optional[QgsCoordinateReferenceSystem] = None,
                repair: bool = True, optional: bool = False,
                progress_range: tuple = (0.0, 5.0),
                expression: Optional[str] = None,
                fields: Optional[Sequence[str]] = None,
                read_twice: bool = False, parts: bool = False) -> Optional[Frame]:
    """Read a feature source parameter into a :class:`Frame` in a metric working CRS.

    Raises a QgsProcessingException naming the layer for: a missing layer, the wrong geometry
    type, missing fields, no features with geometry. ``fields`` limits the attributes read
    to those named (the ones that exist): reading every attribute of a wide OSM layer costs
    more than the algorithms themselves. Null geometries are skipped; invalid ones stop the
    run or are skipped as Processing's invalid features filtering says
    (:func:`invalid_geometry_rule`), and with "do not filter" they are repaired
    (``make_valid``), with a count in the log. An ``optional`` input that is not given, or
    holds no feature with a geometry (a model step that made nothing), gives None (the
    latter with a warning naming the layer and the parameter). Lines and polygons drawn twice (the same
    geometry, in either direction) are read once, with a count in the log, unless
    ``read_twice`` (a library of shapes, where two entries may share one outline). With
    ``parts`` each part of a multi-part feature is read as a feature of its own (its
    attributes and fid repeated, with a count in the log) before the validity check: the
    parts of a collected layer (blocks gathered by 'Collect geometries') touch along the
    streets between them, and the repair of the whole would merge them across the streets.
    The source is never modified.
    """
    source = alg.parameterAsSource(parameters, name, context)
    label = layer_name(alg, parameters, name, context)
    if source is None:
        if optional:
            return None
        raise QgsProcessingException(f"Layer {label} could not be loaded.")
    mixed = False  # a layer of collections or of mixed types: its parts of ``kind`` are read
    if kind is not None:
        gtype = QgsWkbTypes.geometryType(source.wkbType())
        mixed = gtype == QgsWkbTypes.GeometryType.UnknownGeometry
        if gtype != _KIND_TO_GEOMTYPE[kind] and not mixed:
            got = _GEOM_NAMES.get(gtype, "no geometry")
            raise QgsProcessingException(
                f"Layer {label} has {got}; {kind} are needed.")
    all_names = [f.name() for f in source.fields()]
    field_names = all_names if fields is None else \
        [f for f in dict.fromkeys(fields) if f and f in all_names]
    # a field asked for by its full name that a shapefile (dBase: 10 characters) holds cut
    # short: read under its full name, which the plugin's own outputs give it as its alias
    # (styles.save_style_with_layer: 'tortuosity_b' from 'tortuosi_1'), else when the cut
    # is the full name's ten first characters and no other name cuts to them
    # ('building_type' from 'building_t')
    cut = styles.DBF_NAME_LENGTH
    wanted = [f for f in dict.fromkeys([*(fields or ()), *required_fields]) if f]
    by_alias = {alias: field for alias, field in field_aliases(alg, parameters, name, context,
                                                               source).items()
                if alias != field and alias not in all_names and field in all_names}
    if fields is None:
        # every field read: those a shapefile cut short under their full names (a tool
        # that carries the input's fields, or looks one up by its full name, gets it)
        aliased = {field: alias for alias, field in by_alias.items()
                   if _cut_by_gdal(alias, field)}
    else:
        aliased = {by_alias[f]: f for f in wanted if f not in all_names and f in by_alias}
    field_names += [name for name in aliased if name not in field_names]
    wanted = [f for f in wanted if f not in aliased.values()]
    shorts = pd.Series([f[:cut] for f in wanted]).value_counts()
    # two names cut to the same ten characters cannot be told apart: neither is guessed
    cut_short = {f[:cut]: f for f in wanted
                 if len(f) > cut and f not in all_names and f[:cut] in all_names
                 and f[:cut] not in wanted and shorts[f[:cut]] == 1}
    alike = [f for f in wanted if len(f) > cut and f not in all_names and f[:cut] in all_names
             and shorts[f[:cut]] > 1]
    field_names += [short for short in cut_short if short not in field_names]
    field_idx = [all_names.index(f) for f in field_names]
    missing = [f for f in required_fields if f not in all_names and f not in aliased.values()
               and f not in cut_short.values()]
    if missing:
        raise QgsProcessingException(
            f"Layer {label} has no field {', '.join(repr(m) for m in missing)} "
            f"(fields: {', '.join(all_names) or 'none'}).")
    src_crs = source.sourceCrs()
    if not usable_crs(src_crs):
        # metres, feet and degrees differ by 10^5: a guess would give silently wrong sizes
        raise QgsProcessingException(
            f"Layer {label} has no coordinate reference system (CRS), so its units are "
            "unknown. Assign its CRS (Layer Properties > Source, or Processing 'Assign "
            "projection') and run again.")
    chosen = target_crs is None  # this layer decides the working CRS (else it follows one)
    if target_crs is None:
        extent = source.sourceExtent()
        if extent.isNull() or extent.isEmpty() and extent.width() == 0 and extent.height() == 0:
            extent = None
        if extent is None:
            # streaming providers (the OSM driver) may not know their extent: read first
            target_crs = None
        else:
            target_crs = working_crs(src_crs, extent, context)
    request = QgsFeatureRequest()
    if expression:
        # filtering in the provider saves converting features the caller drops anyway
        request.setFilterExpression(expression)
    if fields is not None:
        request.setSubsetOfAttributes(field_idx)
    wkbs: List[bytes] = []
    rows: List[list] = []
    fids: List[int] = []
    n_null = 0
    total = source.featureCount()
    p0, p1 = progress_range
    step = (p1 - p0) / total if total and total > 0 else 0
    # the context's check is applied below, on every feature at once (a message that names
    # the layer and the feature; "do not filter" repairs instead)
    features = source.getFeatures(request, QgsProcessingFeatureSource.Flag.FlagSkipGeometryValidityChecks)
    try:
        for i, feature in enumerate(features):
            if i % 256 == 0:
                stop_if_canceled(feedback)
            geom = feature.geometry()
            if geom is None or geom.isNull() or geom.isEmpty():
                n_null += 1
                continue
            wkbs.append(bytes(geom.asWkb()))
            rows.append(feature.attributes() if fields is None else
                        [feature.attribute(i) for i in field_idx])
            fids.append(feature.id())
            if step and feedback is not None and i % 1000 == 0:
                feedback.setProgress(p0 + i * step)
    finally:
        # hand the provider's connection back now, not when the iterator is collected: the
        # OSM driver serves a file's layers from one dataset and a second reader of the same
        # .pbf waited on it once (tests/test_model_chain.py)
        features.close()
    value = parameters.get(name) if isinstance(parameters, dict) else None
    if isinstance(value, QgsProcessingFeatureSourceDefinition) and value.selectedFeaturesOnly \
            and fids != sorted(fids):
        # a memory layer serves its selection in the order of a hash set, which Qt seeds
        # anew in each process: one SEED gave other parcels from one run to the next, and
        # others than the whole layer's. A selection is read in the layer's order.
        order = np.argsort(np.asarray(fids), kind="stable")
        wkbs, rows, fids = ([r[i] for i in order] for r in (wkbs, rows, fids))
    definition = alg.parameterDefinition(name)
    declared_optional = definition is None or bool(
        definition.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional)
    if not wkbs and optional and declared_optional:
        # an optional input that holds nothing (a chained step of a model that made
        # nothing, an empty selection) is one not given: the run goes on without it (a
        # helper shared with tools that need the layer reads it optional=True too: there
        # an empty one is refused by its name, as any needed layer is)
        if feedback is not None:
            what = f"{definition.description()} ({name})" if definition is not None else name
            feedback.pushWarning(
                f"Layer {label} is empty"
                + (f" ({n_null} null geometries skipped)" if n_null else "")
                + f": the run goes on without {what}, as if it were not given.")
        return None
    if not wkbs:
        raise QgsProcessingException(
            f"Layer {label} is empty: it has no features with a geometry"
            + (f" ({n_null} null geometries skipped)." if n_null else "."))
    geoms = shapely.from_wkb(np.array(wkbs, dtype=object), on_invalid="ignore")
    if kind in ("polygons", "lines") and not mixed:
        # a layer typed as polygons may still hold points (GeoJSON): read as a mixed one
        read = ~shapely.is_missing(geoms)
        mixed = bool((shapely.get_dimensions(geoms[read])
                      != (2 if kind == "polygons" else 1)).any())
    if mixed:
        geoms, rows, fids = _parts_of_kind(geoms, rows, fids, kind, label, feedback)
    if parts:
        geoms, owner = _split_parts(geoms, label, feedback)
        # the attributes, ids and source geometries (for the repair by QGIS) of each part
        rows, fids, wkbs = ([r[i] for i in owner] for r in (rows, fids, wkbs))
    if kind in ("polygons", "lines"):
        geoms, rows, fids = _apply_invalid_rule(
            invalid_geometry_rule(parameters, name, context), geoms, rows, fids, label, feedback)
    unreadable = np.flatnonzero(shapely.is_missing(geoms))
    if len(unreadable):
        # GEOS refuses some OSM geometries outright (rings of < 4 points): let QGIS repair them
        for i in unreadable:
            g = QgsGeometry()
            g.fromWkb(wkbs[i])
            fixed = g.makeValid()
            if fixed is not None and not fixed.isEmpty():
                geoms[i] = shapely.from_wkb(bytes(fixed.asWkb()), on_invalid="ignore")
                if kind is not None:
                    # a ring of two points comes back a line: no polygon to keep
                    geoms[i] = _keep_dimension(geoms[i], kind)
                    if geoms[i] is not None and geoms[i].is_empty:
                        geoms[i] = None
        bad = shapely.is_missing(geoms)
        if feedback is not None:
            # how many QGIS made readable, and how many are left out ('11 repaired, 11
            # skipped' said of 11 that none could be read)
            n_bad = int(bad.sum())
            feedback.pushInfo(
                f"{label}: {counted(len(unreadable), 'unreadable geometry')}"
                + (f": {len(unreadable) - n_bad} repaired by QGIS, {n_bad} skipped." if n_bad
                   else " repaired by QGIS."))
        if bad.any():
            geoms, rows, fids = _kept(~bad, geoms, rows, fids)
            if len(geoms) == 0:
                raise QgsProcessingException(f"Layer {label} has no readable geometry.")
    if target_crs is None:
        b = shapely.total_bounds(geoms)
        target_crs = working_crs(src_crs, QgsRectangle(*b), context)
    if feedback is not None:
        feedback.pushInfo(working_crs_note(label, src_crs, target_crs, chosen))
    if target_crs != src_crs:
        geoms = _transform(geoms, src_crs, target_crs, context, label)
    if n_null and feedback is not None:
        feedback.pushInfo(f"{label}: {counted(n_null, 'feature')} with a null or empty "
                          "geometry skipped.")
    if repair and kind in ("polygons", "lines"):
        invalid = ~shapely.is_valid(geoms)
        if invalid.any():
            fixed = shapely.make_valid(geoms[invalid])
            fixed = np.array([_keep_dimension(g, kind) for g in fixed], dtype=object)
            geoms[invalid] = fixed
            if feedback is not None:
                feedback.pushInfo(f"{label}: {counted(invalid.sum(), 'invalid geometry')} "
                                  "repaired.")
        empty = shapely.is_empty(geoms) | shapely.is_missing(geoms)
        if empty.any():
            geoms, rows, fids = _kept(~empty, geoms, rows, fids)
            if feedback is not None:
                feedback.pushInfo(f"{label}: " + counted(
                    empty.sum(), "geometry could not be repaired and was skipped.",
                    "geometries could not be repaired and were skipped."))
            if len(geoms) == 0:
                raise QgsProcessingException(f"Layer {label} has no valid geometry.")
    if kind in ("polygons", "lines") and len(geoms) > 1 and not read_twice:
        # a feature drawn twice (a layer merged with itself, an import run twice) would
        # count twice: a street twice, a block cut along a doubled line, two buildings
        twice = pd.Series(shapely.to_wkb(shapely.normalize(geoms), output_dimension=2)
                          ).duplicated().to_numpy()
        if twice.any():
            geoms, rows, fids = _kept(~twice, geoms, rows, fids)
            if feedback is not None:
                feedback.pushInfo(f"{label}: {counted(twice.sum(), 'feature')} with the same "
                                  "geometry as an earlier one skipped.")
    attrs = pd.DataFrame([[_py(v) for v in r] for r in rows], columns=field_names)
    if alike and feedback is not None:
        feedback.pushInfo(f"{label}: " + ", ".join(f"'{f}'" for f in alike) + " are cut to "
                          "the same 10 characters in a shapefile and cannot be told apart: "
                          "they are not read (a GeoPackage keeps whole field names).")
    for renamed, why in ((aliased, "the full names the layer keeps as aliases"),
                         (cut_short, "field names cut to 10 characters, as a shapefile "
                                     "keeps them")):
        if renamed:
            attrs = attrs.rename(columns=renamed)
            if feedback is not None:
                feedback.pushInfo(f"{label}: " + ", ".join(f"'{full}' read from '{short}'"
                                                           for short, full in renamed.items())
                                  + f" ({why}).")
    return Frame(geoms, attrs, np.asarray(fids), src_crs, target_crs, label,
                 {**aliased, **cut_short})


def example_in_place(frame: Frame, target_geoms, work_crs, context, feedback=None) -> Frame:
    """An example layer read in its own working CRS, moved into the target's working CRS
    when their extents overlap (the same town: it is used in place, e.g. neighbour
    heights, a random walk that stays where it is); an example elsewhere keeps its own.
    Projected into a target's UTM zone, an example 16 degrees of longitude away had its
    lengths 1 % and areas 2 % off; one on another continent was torn apart."""
    if frame.crs == work_crs:
        return frame
    box = shapely.box(*shapely.total_bounds(reproject(
        np.asarray(target_geoms, dtype=object), work_crs, frame.crs, context)))
    if shapely.intersects(box, shapely.box(*shapely.total_bounds(frame.geometry))):
        frame.geometry = reproject(frame.geometry, frame.crs, work_crs, context, frame.name)
        frame.crs = work_crs
        if feedback is not None:
            feedback.pushInfo(f"{frame.name} overlaps the target: used in the target's "
                              f"working CRS, {crs_label(work_crs)}.")
    return frame


def invalid_geometry_rule(parameters, name: str, context) -> int:
    """What to do with an input's invalid geometries: the input's own setting (the
    dialog's per-input "Invalid feature filtering") or Processing's (Settings > Options >
    Processing > General). A QgsFeatureRequest.InvalidGeometryCheck value."""
    from qgis.core import QgsProcessingFeatureSourceDefinition

    value = parameters.get(name)
    if isinstance(value, QgsProcessingFeatureSourceDefinition) and \
            value.flags & QgsProcessingFeatureSourceDefinition.Flag.FlagOverrideDefaultGeometryCheck:
        return int(value.geometryCheck)
    return int(context.invalidGeometryCheck())


def _apply_invalid_rule(rule: int, geoms, rows, fids, label: str, feedback):
    """Stop on or skip invalid geometries as the rule says; "do not filter" leaves them to
    the repair of :func:`read_source` (``make_valid``, counted in the log)."""
    if rule == QgsFeatureRequest.InvalidGeometryCheck.GeometryNoCheck:
        return geoms, rows, fids
    invalid = shapely.is_missing(geoms) | ~shapely.is_valid(geoms)
    if not invalid.any():
        return geoms, rows, fids
    if rule == QgsFeatureRequest.InvalidGeometryCheck.GeometryAbortOnInvalid:
        first = int(np.flatnonzero(invalid)[0])
        reason = "unreadable" if shapely.is_missing(geoms[first]) else \
            shapely.is_valid_reason(geoms[first])
        raise QgsProcessingException(
            f"Layer {label}: feature {fids[first]} has an invalid geometry ({reason}; "
            f"{int(invalid.sum())} in all). Repair them (Processing 'Fix geometries'), or set "
            "Settings > Options > Processing > General > Invalid features filtering (or this "
            "input's own setting in the dialog) to 'Do not filter', and Urban Synthesis "
            "repairs them, or to 'Skip' to leave them out.")
    keep = ~invalid
    if feedback is not None:
        feedback.pushInfo(f"{label}: {counted(invalid.sum(), 'feature')} with an invalid geometry "
                          "skipped (Processing's invalid features filtering).")
    if not keep.any():
        raise QgsProcessingException(f"Layer {label} has no valid geometry.")
    return _kept(keep, geoms, rows, fids)


def valid_after_transform(polygons: np.ndarray, multi: bool = True) -> np.ndarray:
    """Polygons written back to the input CRS, each one the transform left invalid made valid
    again (its polygon parts kept; for a single-part output the largest): a junction's
    micro-sliver of a micrometre, valid in metres, crossed its own ring once its
    coordinates were rounded to degrees (4 of 2,165 junctions of a district in EPSG:4326)."""
    polygons = np.asarray(polygons, dtype=object)
    bad = ~(shapely.is_valid(polygons) | shapely.is_missing(polygons))
    if not bad.any():
        return polygons
    out = polygons.copy()
    fixed = [_keep_dimension(g, "polygons") for g in shapely.make_valid(polygons[bad])]
    if not multi:
        fixed = [max(shapely.get_parts(g), key=shapely.area) if shapely.get_num_geometries(g) > 1
                 else g for g in fixed]
    out[np.flatnonzero(bad)] = fixed
    return out


def _keep_dimension(geom, kind):
    """make_valid, or a layer of collections, may give a collection: keep only the parts
    of the wanted dimension."""
    if geom is None:
        return None
    dim = {"points": 0, "lines": 1, "polygons": 2}[kind]
    parts = [p for p in shapely.get_parts(geom) if shapely.get_dimensions(p) == dim]
    if not parts:
        return shapely.from_wkt("GEOMETRYCOLLECTION EMPTY")
    if dim == 2:
        return shapely.union_all(parts) if len(parts) > 1 else parts[0]
    if dim == 0:
        return shapely.multipoints(parts) if len(parts) > 1 else parts[0]
    return shapely.multilinestrings(parts) if len(parts) > 1 else parts[0]


def _kept(keep, geoms, rows, fids):
    """The features of a reading where ``keep`` is True: geometries, attribute rows, ids."""
    keep = np.asarray(keep, dtype=bool)
    return (geoms[keep], [r for r, k in zip(rows, keep) if k],
            [f for f, k in zip(fids, keep) if k])


def _split_parts(geoms, label: str, feedback):
    """Each part of a multi-part feature as a geometry of its own (see :func:`read_source`),
    and the index of the feature each comes from; a geometry GEOS cannot read stays whole,
    for the repair by QGIS."""
    geoms = np.asarray(geoms, dtype=object)
    # collections (get_num_geometries: 0 for what GEOS cannot read, which stays whole)
    n_parts = shapely.get_num_geometries(geoms)
    multi = (shapely.get_type_id(geoms) >= 4) & (n_parts > 0)
    n_parts = np.where(multi, n_parts, 1)
    if not (n_parts > 1).any():
        return geoms, np.arange(len(geoms))
    owner = np.repeat(np.arange(len(geoms)), n_parts)
    out = np.empty(len(owner), dtype=object)
    out[~multi[owner]] = geoms[~multi]
    out[multi[owner]] = shapely.get_parts(geoms[multi])   # in feature order
    if feedback is not None:
        split = n_parts > 1
        feedback.pushInfo(f"{label}: {counted(int(split.sum()), 'multi-part feature')} read "
                          f"as {int(n_parts[split].sum())} parts of their own.")
    return out, owner


def _parts_of_kind(geoms, rows, fids, kind: str, label: str, feedback):
    """The features of a layer of collections or mixed types, each reduced to its parts of
    ``kind``; features without any are skipped (counted in the log), and a layer with none
    is refused by name."""
    kept = np.array([_keep_dimension(g, kind) for g in geoms], dtype=object)
    has = ~(shapely.is_missing(kept) | shapely.is_empty(kept))
    if not has.any():
        raise QgsProcessingException(
            f"Layer {label} has no {kind}: its geometries are collections or of mixed "
            f"types without any {kind[:-1]}; {kind} are needed.")
    if not has.all() and feedback is not None:
        feedback.pushInfo(f"{label}: {counted((~has).sum(), 'feature')} without {kind} skipped (the "
                          "layer holds collections or mixed geometry types).")
    return _kept(has, kept, rows, fids)


def _py(value):
    """QVariant nulls -> None; other values unchanged (the hot path of reading attributes)."""
    if isinstance(value, QVariant):
        return None if value.isNull() else value.value()
    return value


def crs_text(crs: QgsCoordinateReferenceSystem) -> str:
    """A CRS as text for PROJ/GDAL and for databases: the authority id, else the WKT."""
    return crs.authid() or crs.toWkt(QgsCoordinateReferenceSystem.WktVariant.WKT_PREFERRED)


def _transform(geoms: np.ndarray, src, dst, context, label: str = "The data") -> np.ndarray:
    """Reproject shapely geometries, vectorised over all coordinates; z values (when the
    geometries have them) are carried along unchanged.

    Uses Debian's pyproj (built on the same PROJ as QGIS; docs/ARCHITECTURE.md, "Native
    libraries") when available, else QGIS's own transform point by point.
    """
    if shapely.get_num_coordinates(geoms).sum() == 0:
        return geoms
    has_z = bool(shapely.has_z(geoms).any())
    try:
        from pyproj import Transformer

        try:
            tr = Transformer.from_crs(crs_text(src), crs_text(dst), always_xy=True)
        except Exception as exc:  # noqa: BLE001 - pyproj's CRSError / ProjError
            raise QgsProcessingException(
                f"{label}: its CRS ({crs_label(src)}) cannot be transformed to "
                f"{crs_label(dst)}: {exc}") from exc

        def project(coords, _):
            return np.column_stack([*tr.transform(coords[:, 0], coords[:, 1]), coords[:, 2:]])
    except ImportError:  # pragma: no cover - QGIS without pyproj
        ctx = context.transformContext() if context else QgsProject.instance().transformContext()
        qtr = QgsCoordinateTransform(src, dst, ctx)

        def project(coords, _):
            xy = np.array([[p.x(), p.y()] for p in
                           (qtr.transform(QgsPointXY(x, y)) for x, y in coords[:, :2])])
            return np.column_stack([xy, coords[:, 2:]])
    out = coordinates.transform(geoms if has_z else shapely.force_2d(geoms), project,
                                include_z=has_z)
    if not np.isfinite(shapely.get_coordinates(out)).all():
        raise QgsProcessingException(
            f"{label}: some coordinates cannot be transformed from {crs_label(src)} to "
            f"{crs_label(dst)} (outside the area where the CRS is defined?).")
    return out


def reproject(geoms: np.ndarray, src, dst, context, label: str = "The data") -> np.ndarray:
    """Geometries from CRS ``src`` to ``dst`` (z values kept); unchanged when either CRS is
    missing (geometry-less tables) or both are the same."""
    if src == dst or not src.isValid() or not dst.isValid():
        return geoms
    return _transform(np.asarray(geoms, dtype=object), src, dst, context, label)


# --------------------------------------------------------------------------- sinks

_QVARIANT = {"int": QVariant.Type.LongLong, "float": QVariant.Type.Double, "str": QVariant.Type.String,
             "bool": QVariant.Type.Bool}


_INT_TYPES = (QVariant.Type.Int, QVariant.Type.LongLong, QVariant.Type.UInt, QVariant.Type.ULongLong)


def field_kind(field: QgsField) -> str:
    """A QGIS field's type in the terms of :func:`make_fields`: int, float, bool or str."""
    if field.type() in _INT_TYPES:
        return "int"
    if field.type() == QVariant.Type.Double:
        return "float"
    return "bool" if field.type() == QVariant.Type.Bool else "str"


def carried_fields(fields: QgsFields, reserved=(), renamed: Optional[Dict[str, str]] = None
                   ) -> List[tuple]:
    """(name, type) of a layer's own fields to carry to an output, leaving out ``reserved``
    names (the computed ones win; compared case-insensitively, as GeoPackage and shapefiles
    do) and 'fid' (the GeoPackage key). ``renamed`` (:attr:`Frame.renamed`): the full names
    of fields a shapefile cut short, which they are carried (and reserved) under: a cut
    'building_t' beside a new 'building_type' would be a second, stale copy of it."""
    reserved = {r.lower() for r in reserved} | {"fid"}
    renamed = renamed or {}
    named = [(renamed.get(f.name(), f.name()), field_kind(f)) for f in fields]
    return [(name, kind) for name, kind in named if name.lower() not in reserved]


#: Width of the integer fields of a shapefile output. QGIS's writer gives a 64-bit integer
#: field without a length 20 digits, and GDAL reads a shapefile number of 19 digits or more
#: back as Real: 18 digits (any id, OSM's included) read back as Integer64.
SHAPEFILE_INT_WIDTH = 18


#: Width of the text fields of a shapefile output: dBase's most (QGIS asks for 255, and
#: GDAL warned 'Field road_class of width 255 truncated to 254' for every text field).
SHAPEFILE_TEXT_WIDTH = 254


def make_fields(spec: Sequence[tuple], names: Optional[Sequence[str]] = None,
                int_width: int = 0, text_width: int = 0) -> QgsFields:
    """``spec`` is a sequence of (name, type) with type in int / float / str / bool;
    ``names`` (optional) the names to write them as; ``int_width`` / ``text_width`` the
    length of the int / text fields (0: the format's default)."""
    fields = QgsFields()
    width = {"int": int_width, "str": text_width}
    for i, (name, typ) in enumerate(spec):
        fields.append(QgsField(name if names is None else names[i], _QVARIANT[typ],
                               len=width.get(typ, 0)))
    return fields


def write_sink(alg, parameters, name: str, context, geoms: np.ndarray, table: pd.DataFrame,
               spec: Sequence[tuple], wkb_type, out_crs: QgsCoordinateReferenceSystem,
               work_crs: QgsCoordinateReferenceSystem, feedback=None) -> Optional[str]:
    """Write engine results to a feature sink parameter, back in ``out_crs``.

    ``spec`` lists the output fields (name, type); ``table`` holds their values per row.
    Geometries with z values are written as such (``wkb_type`` gets its Z variant) and keep
    their z through the reprojection. Returns the destination id (None when the output was
    not requested).

    The fields follow the destination's format (:mod:`outputs`): an attribute named like
    its geometry column (``geom`` in a GeoPackage) is written as ``geom_1``; a shapefile
    gets integer fields GDAL reads back as integers, and the log lists the field names
    GDAL cut to 10 characters.
    """
    destination = outputs.sink_destination(parameters, name, context)
    names, renamed = outputs.field_names_for(destination, [n for n, _ in spec])
    shapefile = outputs.is_shapefile(destination)
    fields = make_fields(spec, names, *((SHAPEFILE_INT_WIDTH, SHAPEFILE_TEXT_WIDTH)
                                        if shapefile else (0, 0)))
    geoms = np.asarray(geoms, dtype=object)
    has_z = bool(len(geoms)) and bool(shapely.has_z(geoms).any())
    if has_z:
        wkb_type = QgsWkbTypes.addZ(wkb_type)
    # a shapefile's text in UTF-8 unless the run chose an encoding: 'System' or none (what
    # Processing and qgis_process pass) is the machine's code page: no 'č' on a Western
    # Windows
    encoding = context.defaultEncoding()
    if shapefile and encoding.lower() in ("", "system"):
        context.setDefaultEncoding("UTF-8")
    try:
        sink, dest_id = alg.parameterAsSink(parameters, name, context, fields, wkb_type,
                                            out_crs)
    finally:
        context.setDefaultEncoding(encoding)
    if sink is None:
        return None
    if len(geoms):
        geoms = reproject(geoms, work_crs, out_crs, context, f"Output {name}")
        if QgsWkbTypes.geometryType(wkb_type) == QgsWkbTypes.GeometryType.PolygonGeometry \
                and work_crs != out_crs:
            geoms = valid_after_transform(geoms, QgsWkbTypes.isMultiType(wkb_type))
    wkbs = shapely.to_wkb(geoms, output_dimension=3 if has_z else 2) if len(geoms) else []
    n = len(geoms)
    columns = [_column_values(table[f] if f in table else None, typ, n) for f, typ in spec]
    if shapefile:  # dBase holds 254 bytes of text: cut here, and said (GDAL cut silently)
        n_cut = 0
        for k, (_, typ) in enumerate(spec):
            if typ == "str":
                columns[k], cut = _cut_text(columns[k], SHAPEFILE_TEXT_WIDTH)
                n_cut += cut
        if n_cut and feedback is not None:
            feedback.pushWarning(
                f"Output {name} is a shapefile, whose text values hold at most "
                f"{SHAPEFILE_TEXT_WIDTH} bytes: {counted(n_cut, 'value')} cut to it. Write a "
                "GeoPackage to keep them whole.")
    rows = list(zip(*columns)) if columns else [()] * n
    features = []
    multi = QgsWkbTypes.isMultiType(wkb_type)
    for i, wkb in enumerate(wkbs):
        if i % 1000 == 0:
            stop_if_canceled(feedback)
        f = QgsFeature(fields)
        g = QgsGeometry()
        g.fromWkb(wkb)
        if multi and not g.isMultipart():
            g.convertToMultiType()
        f.setGeometry(g)
        f.setAttributes(list(rows[i]))
        features.append(f)
    if not sink.addFeatures(features, QgsFeatureSink.Flag.FastInsert):
        raise QgsProcessingException(f"Could not write the output {name}: {sink.lastError()}")
    del sink                             # closes the file: its fields can be read back
    if feedback is not None and renamed:
        feedback.pushWarning(f"Output {name}: {renamed}")
    if shapefile and wkb_type == QgsWkbTypes.Type.NoGeometry and feedback is not None:
        dbf = Path(str(destination).split("|")[0]).with_suffix(".dbf").name
        feedback.pushWarning(
            f"Output {name} has no geometry: GDAL writes a shapefile of a table as its .dbf "
            f"alone ({dbf}), not the .shp named. Write a CSV or a GeoPackage instead.")
    if shapefile:
        cut = outputs.shapefile_renames(dest_id, names)
        # the shipped style names each field as GDAL wrote it (styles.style_for_fields)
        styles.record_written_field_names(
            dest_id, {spec[names.index(a)][0]: b for a, b in cut})
        if cut and feedback is not None:
            feedback.pushWarning(
                f"Output {name} is a shapefile, whose field names have at most 10 "
                f"characters: {counted(len(cut), 'field')} renamed by GDAL: "
                + ", ".join(f"{a} -> {b}" for a, b in cut)
                + ". Write a GeoPackage to keep the full names.")
    return dest_id


def _cut_text(values: list, width: int) -> tuple:
    """Text values cut to ``width`` bytes of UTF-8 (whole characters), and how many were."""
    out, n_cut = list(values), 0
    for i, v in enumerate(out):
        if v is not None and len(v) * 4 > width and len(v.encode("utf-8")) > width:
            out[i] = v.encode("utf-8")[:width].decode("utf-8", "ignore")
            n_cut += 1
    return out, n_cut


def _column_values(column, typ: str, n: int) -> list:
    """A column as a list of plain Python values of the field type, None for missing.

    Vectorised per column (pandas / numpy), not per value: writing is a hot path.
    """
    if column is None:
        return [None] * n
    series = pd.Series(np.asarray(column, dtype=object))
    missing = series.isna().to_numpy()
    if typ in ("int", "float", "bool"):
        numbers = pd.to_numeric(series.where(~missing), errors="coerce").to_numpy(dtype=float)
        missing |= ~np.isfinite(numbers)
        numbers = np.where(missing, 0.0, numbers)
        if typ == "int":
            values = numbers.astype(np.int64).tolist()
        elif typ == "bool":
            values = (numbers != 0).tolist()
        else:
            values = numbers.tolist()
    else:
        values = [v if isinstance(v, str) else str(v) for v in series.tolist()]
    if missing.any():
        for i in np.flatnonzero(missing):
            values[i] = None
    return values


# --------------------------------------------------------------------------- engine calls

def progress_for(feedback: Optional[QgsProcessingFeedback], start: float = 0.0,
                 end: float = 100.0) -> Progress:
    if feedback is None:
        return Progress(start=start, end=end)
    return Progress(feedback.setProgress, feedback.isCanceled, feedback.pushInfo, start, end)


def run_engine(label: str, fn, *args, **kwargs):
    """Call an engine function: its :class:`InputError` becomes a QgsProcessingException
    naming ``label``, its :class:`Canceled` a :class:`ProcessingCanceled`, a package it
    lacks the plugin's advice to install it (:func:`missing_package_error`)."""
    try:
        return fn(*args, **kwargs)
    except Canceled as exc:
        raise ProcessingCanceled(str(exc) or "Canceled by the user.") from exc
    except MissingPackage as exc:
        raise missing_package_error(exc) from exc
    except InputError as exc:
        raise QgsProcessingException(f"{label}: {exc}") from exc


def missing_package_error(exc: MissingPackage) -> QgsProcessingException:
    """What a method says when a package it imports where it needs it (OpenCV, onnxruntime)
    is missing: the installer, as a tool whose packages are missing says (a QGIS whose
    Python has shapely and pandas lists these tools as available)."""
    return QgsProcessingException(dependencies.missing_message([exc.distribution]))


def field_values(frame: Frame, field: Optional[str], default=None) -> np.ndarray:
    if field and field in frame.attributes:
        return frame.attributes[field].to_numpy(dtype=object)
    return np.full(len(frame), default, dtype=object)


# --------------------------------------------------------------------------- OSM attributes

def subset(frame: Frame, keep) -> Frame:
    keep = np.asarray(keep, dtype=bool)
    return Frame(frame.geometry[keep], frame.attributes[keep].reset_index(drop=True),
                 frame.fids[keep], frame.source_crs, frame.crs, frame.name, frame.renamed)


def osm_tag_column(frame: Frame, key: str) -> Optional[np.ndarray]:
    """Values of an attribute that may be a field or a key inside OSM's ``other_tags``.

    Returns None when neither holds it.
    """
    from ..network.street_graph import parse_other_tags

    if key in frame.attributes:
        return frame.attributes[key].to_numpy(dtype=object)
    if "other_tags" in frame.attributes:
        values = np.array([parse_other_tags(t).get(key) for t in frame.attributes["other_tags"]],
                          dtype=object)
        if any(v is not None for v in values):
            return values
    return None


#: Fields a line's own width is read from, in this order: a tool's ``width_m`` (growroads,
#: extractroadhierarchy), OSM's ``width`` (a field or in ``other_tags``).
WIDTH_FIELDS = ("width_m", "width")


def road_width_column(frame: Frame, width_field: Optional[str] = None) -> Optional[np.ndarray]:
    """Each line's own width as given (``width_field``, else the first of
    :data:`WIDTH_FIELDS` the layer holds), unparsed; None when none is there."""
    for name in ([width_field] if width_field else WIDTH_FIELDS):
        values = osm_tag_column(frame, name)
        if values is not None:
            return values
    return None


#: The fields :func:`road_classes` reads: ask read_source for them.
ROAD_CLASS_FIELDS = ("highway", "other_tags", "road_class")


def road_classes(frame: Frame, class_field: Optional[str] = None):
    """The road class of each line and the field it was read from: ``class_field`` (a field,
    or a key of OSM's ``other_tags``; default ``highway``), else, for the default, the
    ``road_class`` field that 'Extract road hierarchy' and the synthesis tools write (their
    level-0 roads are the arterials a synthesis is usually given). (None, None) when the
    layer holds neither. Read the frame with :data:`ROAD_CLASS_FIELDS`.
    """
    values = osm_tag_column(frame, class_field or "highway")
    if values is not None:
        return values, class_field or "highway"
    if class_field in (None, "", "highway") and "road_class" in frame.attributes:
        return frame.attributes["road_class"].to_numpy(dtype=object), "road_class"
    return None, None


#: Fields that hold a line's vertical layer: OSM's (``layer``, ``bridge``, ``tunnel``, or in
#: ``other_tags``) and the one extractroadhierarchy writes (``osm_layer``), so that a chain
#: of tools keeps a bridge off the street it passes over. Read a frame with these to use
#: :func:`osm_vertical_layers`.
VERTICAL_LAYER_FIELDS = ("layer", "bridge", "tunnel", "other_tags", "osm_layer")


def osm_vertical_layers(frame: Frame) -> np.ndarray:
    """OSM vertical layer per feature from layer / bridge / tunnel fields or other_tags, else
    from the ``osm_layer`` field of extractroadhierarchy's output (:data:`VERTICAL_LAYER_FIELDS`)."""
    from ..network.street_graph import parse_other_tags, vertical_layer

    keys = ("layer", "bridge", "tunnel")
    n = len(frame)
    cols = {k: frame.attributes[k].to_numpy(dtype=object) for k in keys if k in frame.attributes}
    if "layer" not in cols and "osm_layer" in frame.attributes:
        cols["layer"] = frame.attributes["osm_layer"].to_numpy(dtype=object)
    tags = frame.attributes["other_tags"].to_numpy(dtype=object) \
        if "other_tags" in frame.attributes else np.full(n, None, dtype=object)
    out = np.zeros(n, dtype=np.int64)
    for i in range(n):
        values = {k: c[i] for k, c in cols.items()}
        text = tags[i]
        # parse other_tags once per feature, and only when it can hold one of the keys
        if text and len(values) < 3 and any(k in text for k in keys):
            parsed = parse_other_tags(text)
            for k in keys:
                values.setdefault(k, parsed.get(k))
        if values:
            out[i] = vertical_layer(values.get("layer"), values.get("bridge"), values.get("tunnel"))
    return out


# --------------------------------------------------------------------------- styles

style_output = styles.style_output  # the algorithms' one call (qgis_glue/styles.py)


# --------------------------------------------------------------------------- rasters

#: Values that mark gaps in many DEMs (ESRI, SRTM, float32's lowest) and read as heights
#: when the file does not declare them as no data.
UNDECLARED_NODATA = (-9999.0, -32767.0, -32768.0, float(np.finfo(np.float32).min))


def height_unit(source: str):
    """(metres per unit, unit name) of the heights in band 1 of a raster file: the band's
    declared unit type, else the unit of a vertical CRS in the file's CRS (a compound CRS
    such as NAD83 / New York + NAVD88 height (ftUS)), else metres (the name is then '');
    the factor is None for a unit that is not a known length
    (:func:`core.crs.metres_per_unit`)."""
    from osgeo import gdal

    try:
        ds = gdal.OpenEx(source, gdal.OF_RASTER | gdal.OF_READONLY)
    except RuntimeError:  # exceptions enabled by someone else; the warp reports it
        ds = None
    if ds is None or ds.RasterCount < 1:
        return 1.0, ""
    name = (ds.GetRasterBand(1).GetUnitType() or "").strip()
    if not name:
        srs = ds.GetSpatialRef()
        if srs is not None and (srs.IsCompound() or srs.IsVertical()):
            name = (srs.GetAttrValue("VERT_CS|UNIT") or "").strip() or \
                ("metre" if srs.GetTargetLinearUnits("VERT_CS") == 1.0 else "")
    ds = None
    return crs_rule.metres_per_unit(name), name


def read_raster(layer, work_crs: QgsCoordinateReferenceSystem, bounds, cell_size: float,
                feedback=None, what: str = "DEM", heights: bool = True):
    """Warp a raster layer into the working CRS over ``bounds`` (+ a margin) with GDAL.

    The engine works on a numpy grid with a geotransform (a :class:`DemGrid`); GDAL (the
    same library QGIS uses) reprojects and resamples the raster bilinearly into an
    in-memory dataset first. ``what`` names the raster in messages (DEM, density ...).
    ``heights``: the values are heights, returned in metres whatever unit the raster
    declares (:func:`height_unit`; feet would make every slope 3.28 times too steep);
    False for other values (density, obstacles), read as they are.
    """
    from osgeo import gdal

    from ..retrieval.shape_context import DemGrid

    if not layer.crs().isValid():
        raise QgsProcessingException(
            f"{what} '{layer.name()}' has no coordinate reference system (CRS). Assign its "
            "CRS (Layer Properties > Source, or GDAL 'Assign projection') and run again.")
    source = layer.source().split("|")[0]
    margin = 4 * cell_size
    x0, y0, x1, y1 = bounds
    options = gdal.WarpOptions(
        format="MEM", dstSRS=crs_text(work_crs), srcSRS=crs_text(layer.crs()) or None,
        outputBounds=(x0 - margin, y0 - margin, x1 + margin, y1 + margin),
        xRes=cell_size, yRes=cell_size, resampleAlg="bilinear", dstNodata=float("nan"),
        outputType=gdal.GDT_Float32, multithread=False)
    # no gdal.UseExceptions(): it would switch the bindings' error mode for all of QGIS
    try:
        ds = gdal.Warp("", source, options=options)
    except RuntimeError as exc:  # exceptions already enabled by someone else
        raise QgsProcessingException(
            f"{what} '{layer.name()}' cannot be read or reprojected: {exc}") from exc
    if ds is None:
        raise QgsProcessingException(f"{what} '{layer.name()}' cannot be read or reprojected: "
                                     f"{gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
    band = ds.GetRasterBand(1)
    grid = band.ReadAsArray().astype(np.float64)
    nodata = band.GetNoDataValue()
    if feedback is not None:
        if layer.bandCount() > 1:
            feedback.pushWarning(f"{what} '{layer.name()}' has {layer.bandCount()} bands: band 1 "
                                 "is read as the heights.")
        # a common 'no data' code the file does not declare reads as a height
        codes = [v for v in UNDECLARED_NODATA if (grid == v).any()]
        if codes:
            feedback.pushWarning(
                f"{what} '{layer.name()}' has cells of {codes[0]:g} that are not declared as "
                "'no data': they are read as heights. Set the raster's no-data value (Layer "
                "Properties > Transparency, or GDAL 'Translate' with -a_nodata) if they are "
                "gaps.")
    if heights:
        factor, unit = height_unit(source)
        if factor is None:
            if feedback is not None:
                feedback.pushWarning(f"{what} '{layer.name()}' declares its heights in "
                                     f"'{unit}', not a known length unit: they are read as "
                                     "metres.")
        elif factor != 1.0:
            # nodata cells are NaN already (dstNodata); the no-data code is no height
            grid = np.where(np.isfinite(grid), grid * factor, grid)
            if feedback is not None:
                feedback.pushInfo(f"{what} '{layer.name()}': heights in {unit} "
                                  f"({factor:.10g} m), converted to metres.")
    dem = DemGrid(grid, ds.GetGeoTransform(), nodata)
    valid = np.isfinite(dem.array)
    if not valid.any():
        raise QgsProcessingException(
            f"{what} '{layer.name()}' has no value over the input's extent: check that they "
            "overlap.")
    if feedback is not None and not valid.all():
        # a warning: every tool that reads a DEM treats cells without a value as a guess
        # (flat, filled or left out), which the analyst should know of
        feedback.pushWarning(f"{what} '{layer.name()}': {100 * (1 - valid.mean()):.0f} % of the "
                             "input's extent has no value (holes, or beyond its edge).")
    return dem


def raster_cell_size(layer, work_crs, bounds, context, max_cells: int = 2048,
                     min_cell: float = 1.0, feedback=None) -> float:
    """Cell size (m) for a raster in the working CRS: its own resolution, at least
    ``min_cell`` m, and coarse enough that the input's extent spans at most ``max_cells``
    cells (said in the log, with ``feedback``, when that coarsens the raster)."""
    ext = layer.extent()
    px, py = layer.rasterUnitsPerPixelX(), layer.rasterUnitsPerPixelY()
    native = max(px, py)
    try:  # the resolution in metres: one pixel's two sides, transformed, as one square's
        # (the bounding box of the pixel's diagonal made a 5 m pixel in degrees 8 m cells)
        tr = QgsCoordinateTransform(layer.crs(), work_crs, context.transformContext())
        c = ext.center()
        corner = tr.transform(QgsPointXY(c.x(), c.y()))
        side_x = corner.distance(tr.transform(QgsPointXY(c.x() + px, c.y())))
        side_y = corner.distance(tr.transform(QgsPointXY(c.x(), c.y() + py)))
        native_m = math.sqrt(side_x * side_y)
    except Exception:  # noqa: BLE001 - an unknown CRS: trust the number as metres
        native_m = native
    span = max(bounds[2] - bounds[0], bounds[3] - bounds[1])
    cell = max(native_m if math.isfinite(native_m) and native_m > 0 else 1.0, min_cell)
    if feedback is not None and span / max_cells > cell:
        feedback.pushInfo(f"Raster {layer.name()}: its {cell:.1f} m cells are read as "
                          f"{span / max_cells:.1f} m cells, so that the {span / 1000:,.1f} km "
                          f"extent spans at most {max_cells:,} cells.")
    return max(cell, span / max_cells)


def read_image(layer, work_crs: QgsCoordinateReferenceSystem, bounds, cell_size: float,
               what: str = "Image"):
    """All bands of an image layer warped into the working CRS over ``bounds`` with GDAL
    (bilinear, its own data type), as an engine GeoImage whose ``valid`` mask is GDAL's
    alpha (no data, outside the source, or the source's own alpha)."""
    from osgeo import gdal

    from ..imagery.aerial_image import GeoImage

    if not layer.crs().isValid():
        raise QgsProcessingException(
            f"{what} '{layer.name()}' has no coordinate reference system (CRS). Assign its "
            "CRS (Layer Properties > Source, or GDAL 'Assign projection') and run again.")
    source = layer.source().split("|")[0]
    x0, y0, x1, y1 = bounds
    options = gdal.WarpOptions(
        format="MEM", dstSRS=crs_text(work_crs), srcSRS=crs_text(layer.crs()) or None,
        outputBounds=(x0, y0, x1, y1), xRes=cell_size, yRes=cell_size,
        resampleAlg="bilinear", dstAlpha=True, multithread=False)
    try:
        ds = gdal.Warp("", source, options=options)
    except RuntimeError as exc:
        raise QgsProcessingException(f"{what} '{layer.name()}' cannot be read or reprojected: "
                                     f"{exc}") from exc
    if ds is None:
        raise QgsProcessingException(f"{what} '{layer.name()}' cannot be read or reprojected: "
                                     f"{gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
    data = ds.ReadAsArray()
    data = data[None] if data.ndim == 2 else data
    valid = data[-1] > 0
    if not valid.any():
        raise QgsProcessingException(
            f"{what} '{layer.name()}' has no value over the example's extent: check that "
            "they overlap.")
    return GeoImage(np.moveaxis(data[:-1], 0, -1), ds.GetGeoTransform(), valid)


def write_image(path: str, image, alpha: np.ndarray, work_crs: QgsCoordinateReferenceSystem,
                target_crs: QgsCoordinateReferenceSystem) -> None:
    """An engine GeoImage as a tiled, compressed GeoTIFF in ``target_crs`` (warped there
    with GDAL when it is not the working CRS) with an alpha band and averaged overviews
    (halving until under 128 pixels, at least one level)."""
    from osgeo import gdal, gdal_array

    rows, cols, bands = image.array.shape
    gdal_type = gdal_array.NumericTypeCodeToGDALTypeCode(image.array.dtype)
    if gdal_type is None:
        raise QgsProcessingException(f"Images of type {image.array.dtype} cannot be written.")
    top = 255 if image.array.dtype == np.uint8 else \
        np.iinfo(image.array.dtype).max if np.issubdtype(image.array.dtype, np.integer) else 1
    mem = gdal.GetDriverByName("MEM").Create("", cols, rows, bands + 1, gdal_type)
    mem.SetGeoTransform(tuple(image.geotransform))
    mem.SetProjection(work_crs.toWkt())
    for b in range(bands):
        mem.GetRasterBand(b + 1).WriteArray(image.array[:, :, b])
    mem.GetRasterBand(bands + 1).WriteArray(np.where(alpha > 0, top, 0).astype(image.array.dtype))
    mem.GetRasterBand(bands + 1).SetColorInterpretation(gdal.GCI_AlphaBand)
    if bands >= 3:
        for b, ci in enumerate((gdal.GCI_RedBand, gdal.GCI_GreenBand, gdal.GCI_BlueBand)):
            mem.GetRasterBand(b + 1).SetColorInterpretation(ci)
    if target_crs.isValid() and target_crs != work_crs:
        mem = gdal.Warp("", mem, options=gdal.WarpOptions(
            format="MEM", dstSRS=crs_text(target_crs), srcAlpha=True, dstAlpha=True,
            resampleAlg="bilinear", multithread=False))
    creation = ["TILED=YES", "COMPRESS=DEFLATE", "ALPHA=YES", "BIGTIFF=IF_SAFER"]
    if bands >= 3:
        creation.append("PHOTOMETRIC=RGB")
    out = gdal.Translate(str(path), mem, options=gdal.TranslateOptions(
        format="GTiff", creationOptions=creation))
    if out is None:
        raise QgsProcessingException(f"The image cannot be written to {path}: "
                                     f"{gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
    levels, size = [2], max(out.RasterXSize, out.RasterYSize)
    while size / (2 * levels[-1]) >= 128:
        levels.append(2 * levels[-1])
    out.BuildOverviews("AVERAGE", levels)
    out.FlushCache()
    out = None


def write_geotiff(path: str, dem, crs_wkt: str, what: str = "The raster") -> None:
    """Write a DemGrid as a single-band float32 GeoTIFF (NaN = no data) with GDAL; ``what``
    names it in messages ('The generator image', 'The relief')."""
    from osgeo import gdal

    rows, cols = dem.array.shape
    driver = gdal.GetDriverByName("GTiff")
    ds = driver.Create(str(path), cols, rows, 1, gdal.GDT_Float32, options=["COMPRESS=DEFLATE"])
    if ds is None:
        raise QgsProcessingException(f"{what} cannot be written to {path}: "
                                     f"{gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
    ds.SetGeoTransform(tuple(dem.geotransform))
    ds.SetProjection(crs_wkt)
    band = ds.GetRasterBand(1)
    band.SetNoDataValue(float("nan"))
    band.WriteArray(np.asarray(dem.array, dtype=np.float32))
    band.FlushCache()
    ds = None
