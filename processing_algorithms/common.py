"""Shared plumbing of the urbansynth algorithms: identity, icon, parameter help, and the
rules every algorithm follows once: numbers checked against the range they were declared
with, seeds, field types by the declaration, roads -> blocks, the example databases."""
import functools
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsProcessingUtils,
)
from qgis.PyQt.QtCore import QCoreApplication
from qgis.PyQt.QtGui import QIcon

from ..plugin.buildings import attributes as building_attributes
from ..plugin.core.ids import whole_ids
from ..plugin.core.progress import Canceled, InputError, MissingPackage
from ..plugin.core.seeds import MAX_SEED
from ..plugin.core.text import counted
from ..plugin.network import blocks as block_rules
from ..plugin.network import street_graph
from ..plugin.qgis_glue import outputs, qgis_io
from ..plugin.qgis_glue import toolbox
from ..plugin.qgis_glue.toolbox import GROUPS

ICON = Path(__file__).resolve().parent.parent / "resources" / "icons" / "urbansynth.svg"


#: QGIS's "no bound" of a Number parameter is +-DBL_MAX.
_UNBOUNDED = 1e300


def _range_text(lo: float, hi: float) -> str:
    if lo <= -_UNBOUNDED and hi >= _UNBOUNDED:
        return "any finite number"
    if lo <= -_UNBOUNDED:
        return f"at most {hi:g}"
    if hi >= _UNBOUNDED:
        return f"at least {lo:g}"
    return f"from {lo:g} to {hi:g}"


def number_error(definition, value):
    """Why ``value`` is not acceptable for a Number parameter (None when it is): the check
    derived from the declaration (its minimum, maximum and data type), so that a range is
    typed once. QGIS itself checks ranges only in the dialog, and says no more than
    'Incorrect parameter value' on the command line."""
    label = f"{definition.description()} ({definition.name()})"
    integer = definition.dataType() == QgsProcessingParameterNumber.Type.Integer
    lo, hi = definition.minimum(), definition.maximum()
    if value is None or not math.isfinite(value):
        return f"{label} must be a finite number, not {value}."
    if integer and value != round(value):
        return f"{label} must be a whole number, not {value:g}."
    if value < lo or value > hi:
        return f"{label} = {value:g} is out of range: allowed {_range_text(lo, hi)}."
    return None


def clear_error(alg, exc: BaseException, feedback) -> BaseException:
    """The exception a run ends with: a QgsProcessingException whose message a GIS analyst
    understands. A cancel is a :class:`qgis_io.ProcessingCanceled` whatever raised it (an
    engine loop, or a library interrupted half-way); an engine error that escaped
    ``run_engine`` names the tool; anything unexpected says so in one sentence, never as
    a traceback."""
    if feedback is not None and feedback.isCanceled() and \
            not isinstance(exc, qgis_io.ProcessingCanceled):
        return qgis_io.ProcessingCanceled()
    if isinstance(exc, QgsProcessingException):
        return exc
    if isinstance(exc, Canceled):
        return qgis_io.ProcessingCanceled()
    if isinstance(exc, MissingPackage):
        return qgis_io.missing_package_error(exc)
    if isinstance(exc, InputError):
        return QgsProcessingException(f"{alg.displayName()}: {exc}")
    if isinstance(exc, MemoryError):
        return QgsProcessingException(
            f"{alg.displayName()} ran out of memory: run it on a smaller area or split the "
            "input.")
    if isinstance(exc, Exception):
        return QgsProcessingException(
            f"{alg.displayName()} failed on this input ({type(exc).__name__}: {exc}). This is "
            "a defect of Urban Synthesis: please report it with the input layers.")
    return exc


def at_qgis_boundary(error: BaseException) -> BaseException:
    """The exception as QGIS wants it: exactly a QgsProcessingException. QGIS reports one
    with its message only, and any other type -- a subclass such as ProcessingCanceled
    included -- with the whole Python traceback (its sip handler compares type names)."""
    if isinstance(error, QgsProcessingException) and type(error) is not QgsProcessingException:
        return QgsProcessingException(str(error))
    return error


def _guarded(run):
    """``processAlgorithm`` with the rules of every run: the declarations checked (models do
    not call checkParameterValues), an output that is an input refused before anything is
    written, every file output staged and moved into place only when the run succeeded
    (:mod:`qgis_glue.outputs`), a cancel typed, an unexpected error a clear message."""
    @functools.wraps(run)
    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802 (QGIS API)
        message = self.declaration_error(parameters, context)
        if message:
            raise QgsProcessingException(message)
        for warning in qgis_io.unknown_parameters(self, parameters):
            feedback.pushWarning(warning)
        staging = outputs.OutputStaging(self, parameters, context, feedback)
        staged = staging.prepare()
        try:
            results = run(self, staged, context, feedback)
            qgis_io.stop_if_canceled(feedback)   # a cancel at the very end writes nothing
            return staging.commit(results)
        except BaseException as exc:
            staging.discard()
            error = at_qgis_boundary(clear_error(self, exc, feedback))
            if error is exc:
                raise
            raise error from exc

    processAlgorithm.guarded = True
    return processAlgorithm


class AlgorithmBase(QgsProcessingAlgorithm):
    """Base for every urbansynth algorithm: group, icon, instance creation and ``add``, and
    the rules of every run (:func:`_guarded` wraps each subclass's ``processAlgorithm``).

    Subclasses set ``GROUP_ID`` (a key of :data:`GROUPS`).
    """

    GROUP_ID = "analysis"

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        run = cls.__dict__.get("processAlgorithm")
        if run is not None and not getattr(run, "guarded", False):
            cls.processAlgorithm = _guarded(run)

    def group(self):
        return self.tr(GROUPS[self.GROUP_ID])

    def groupId(self):  # noqa: N802
        return self.GROUP_ID

    def createInstance(self):  # noqa: N802 (QGIS API)
        return type(self)()

    def icon(self):
        return QIcon(str(ICON))

    def helpUrl(self):  # noqa: N802
        return toolbox.help_url(self.name())

    def tags(self):
        return [self.tr(tag) for tag in toolbox.TAGS.get(self.name(), ())]

    @staticmethod
    def tr(text: str) -> str:
        """The text in the user's language where a translation is installed."""
        return QCoreApplication.translate("UrbanSynthesis", text)

    @staticmethod
    def given(parameters, name: str) -> bool:
        """Whether an optional parameter was given a value."""
        value = parameters.get(name)
        return value is not None and value != ""

    def input_error(self, parameters, context):
        """A message when the inputs do not go together (checked before the run, in the
        dialog and on the command line), else None. Overridden by algorithms that need it."""
        return None

    def checkParameterValues(self, parameters, context):  # noqa: N802 (QGIS API)
        # numbers and field types first: QGIS's own message names neither range nor type
        message = self.declaration_error(parameters, context) or \
            outputs.destination_error(self, parameters, context)
        if message:
            return False, message
        ok, message = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, message
        message = self.input_error(parameters, context)
        return (False, message) if message else (True, "")

    # ----------------------------------------------------------------- declared once

    def declaration_error(self, parameters, context):
        """The first value that breaks its parameter's declaration (a mandatory parameter
        not given, a number out of its range or not whole, a field of the wrong type), else
        None."""
        for definition in self.parameterDefinitions():
            name = definition.name()
            if not self.given(parameters, name):
                if not (definition.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional) \
                        and not definition.isDestination() and definition.defaultValue() is None:
                    return f"{definition.description()} ({name}) is needed."
                continue
            if isinstance(definition, QgsProcessingParameterNumber):
                message = self._number_message(parameters, definition, context)
            elif isinstance(definition, QgsProcessingParameterField):
                message = self._field_message(parameters, definition, context)
            else:
                message = None
            if message:
                return message
        return None

    def _number_message(self, parameters, definition, context):
        raw = parameters.get(definition.name())
        if isinstance(raw, str):
            try:
                float(raw)
            except ValueError:
                return (f"{definition.description()} ({definition.name()}) must be a number, "
                        f"not '{raw}'.")
        return number_error(definition, self.parameterAsDouble(parameters, definition.name(),
                                                               context))

    def _field_message(self, parameters, definition, context):
        """A Numeric or String field parameter naming a field of another type."""
        wanted = definition.dataType()
        if wanted not in (QgsProcessingParameterField.DataType.Numeric,
                          QgsProcessingParameterField.DataType.String):
            return None
        parent = definition.parentLayerParameterName()
        try:
            source = self.parameterAsSource(parameters, parent, context) if parent else None
        except Exception:  # noqa: BLE001 - an unreadable parent is reported by its own check
            source = None
        if source is None:
            return None
        fields = source.fields()
        for name in self.parameterAsFields(parameters, definition.name(), context):
            index = fields.lookupField(name)
            if index < 0:
                continue  # a missing field is reported where the layer is read
            field = fields.at(index)
            numeric = field.isNumeric()
            if wanted == QgsProcessingParameterField.DataType.Numeric and not numeric:
                return (f"{definition.description()} ({definition.name()}): field '{name}' of "
                        f"{qgis_io.layer_name(self, parameters, parent, context)} holds "
                        f"{field.typeName() or 'text'} values; a numeric field is needed.")
        return None

    def number(self, parameters, name, context):
        """A Number parameter's value checked against its declaration (range, whole number
        for Integer parameters): an int for Integer parameters, else a float; None for an
        optional parameter without default that was not given."""
        definition = self.parameterDefinition(name)
        if not self.given(parameters, name) and definition.defaultValue() is None:
            if definition.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional:
                return None
        message = self._number_message(parameters, definition, context) \
            if self.given(parameters, name) else None
        value = self.parameterAsDouble(parameters, name, context)
        message = message or number_error(definition, value)
        if message:
            raise QgsProcessingException(message)
        if definition.dataType() == QgsProcessingParameterNumber.Type.Integer:
            return int(round(value))
        return float(value)

    def bound_work(self, what: str, amount: float, limit: float, unit: str, advice: str):
        """Refuse a run larger than ``limit`` (in ``unit``) before it starts: ``what`` says
        what is measured ('Region 'x' at 30 x 18 m parcels'), ``advice`` what to do."""
        if amount > limit:
            raise QgsProcessingException(
                f"{what} makes about {amount:,.0f} {unit}, more than the {limit:,.0f} one run "
                f"makes: {advice}.")

    def add_seed(self, help_text: str, name: str = "SEED", advanced: bool = False):
        """The random seed parameter: a whole number 0 .. 2^31 - 1, default 1."""
        self.add(QgsProcessingParameterNumber(
            name, "Random seed", QgsProcessingParameterNumber.Type.Integer, defaultValue=1,
            minValue=0, maxValue=MAX_SEED), help_text, advanced=advanced)

    def seed(self, parameters, context, name: str = "SEED") -> int:
        """The seed, a whole number in range (1.5 or 2^31 are refused, never rounded)."""
        return self.number(parameters, name, context)

    # ----------------------------------------------------------------- areas kept clear

    KEEP_CLEAR = "KEEP_CLEAR"

    def add_keep_clear(self, what: str, more: str = ""):
        """The optional polygon layer of areas ``what`` (parcels, footprints) never cover;
        ``more``: what else the tool does with them."""
        self.add(QgsProcessingParameterFeatureSource(
            self.KEEP_CLEAR, "Areas to keep clear (street surfaces)",
            [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            f"Polygons no {what} may cover, e.g. the street surfaces and junctions of "
            "'Tessellate streets (surfaces and junctions)' merged into one layer: their widths "
            "follow each street's class, and dead-end streets inside a block are kept clear "
            "too. Applied on top of the street width." + (" " + more if more else ""))

    def optional_polygons(self, parameters, name, context, feedback, frame, blocks, what):
        """An optional polygon layer (KEEP_CLEAR, BUILDINGS) in ``frame``'s working CRS, or
        None: None too when it is empty (a chained step that made nothing), and a warning
        when none of it reaches the ``blocks``."""
        source = self.parameterAsSource(parameters, name, context)
        if source is not None and source.featureCount() == 0:
            feedback.pushInfo(f"Layer {qgis_io.layer_name(self, parameters, name, context)} "
                              f"is empty: no {what}.")
            return None
        layer = qgis_io.read_source(self, parameters, name, context, feedback,
                                    kind="polygons", target_crs=frame.crs, optional=True,
                                    fields=[])
        if layer is None:
            return None
        blocks = np.asarray(blocks, dtype=object)
        reach = np.unique(shapely.STRtree(blocks).query(layer.geometry,
                                                        predicate="intersects")[0]) \
            if len(blocks) else np.zeros(0)
        if len(reach) == 0:
            feedback.pushWarning((f"The polygon of {layer.name} reaches no block"
                                  if len(layer) == 1 else f"None of the {len(layer)} polygons "
                                  f"of {layer.name} reaches a block") + f": no {what}.")
            return None
        feedback.pushInfo(f"{len(reach)} of the {counted(len(layer), 'polygon')} of {layer.name} "
                          f"{'reaches' if len(reach) == 1 else 'reach'} the blocks: {what}.")
        return layer.geometry

    def keep_clear_areas(self, parameters, context, feedback, frame, blocks):
        """The KEEP_CLEAR polygons in ``frame``'s working CRS, or None."""
        return self.optional_polygons(parameters, self.KEEP_CLEAR, context, feedback, frame,
                                      blocks, "areas kept clear")

    @staticmethod
    def only_buildings(frame, feedback):
        """The polygons of ``frame`` with a 'building' value (not 'no') when the layer has
        that field -- an OSM multipolygons layer holds land use, parks, water and boundaries
        too -- the others skipped with a count in the log; every polygon of a layer without
        the field. One rule for every tool that reads buildings."""
        if frame is None or "building" not in frame.attributes:
            return frame
        value = frame.attributes["building"].to_numpy(dtype=object)
        keep = np.array([v is not None and not (isinstance(v, float) and math.isnan(v))
                         and str(v).strip() not in ("", "no") for v in value], dtype=bool)
        if not keep.any():
            raise QgsProcessingException(f"Layer {frame.name} has a 'building' field but no "
                                         "polygon with a value in it: no building to read.")
        if not keep.all():
            feedback.pushInfo(f"{frame.name}: {counted((~keep).sum(), 'polygon')} without a "
                              f"'building' value skipped (of {len(frame)}: land use, water ... "
                              "of an OSM layer are no buildings).")
            frame = qgis_io.subset(frame, keep)
        return frame

    @staticmethod
    def building_attributes_of(frame, **kwargs):
        """Height, levels, type and roof of each building of ``frame`` from its 'building'
        field, its OSM tags ('other_tags' and the tag fields) and ``kwargs`` (height,
        levels, storey_height: :func:`buildings.attributes.building_attributes`)."""
        a = frame.attributes
        return qgis_io.run_engine(
            frame.name, building_attributes.building_attributes, len(frame),
            building=qgis_io.field_values(frame, "building"),
            other_tags=qgis_io.field_values(frame, "other_tags"),
            tags={k: a[k].to_numpy(dtype=object) for k in building_attributes.TAG_FIELDS
                  if k in a}, **kwargs)

    # ----------------------------------------------------------------- roads and blocks

    def drivable_roads(self, parameters, name, context, feedback, class_field=None,
                       classes=None, fields=(), required_fields=()):
        """A road line layer (OSM lines filtered to drivable classes; a layer without
        classes keeps every line) and its road classes (None without classes)."""
        frame = qgis_io.read_source(
            self, parameters, name, context, feedback, kind="lines",
            fields=[class_field or "highway", "other_tags", "road_class", "junction", *fields],
            required_fields=required_fields)
        classes = set(street_graph.DRIVABLE_CLASSES) if classes is None else classes
        return drivable_lines(frame, class_field, classes, feedback)

    def blocks_from_roads(self, frame, road_class, feedback, progress=(5.0, 30.0),
                          boundary_name=None, **kwargs):
        """The street graph and city blocks of a road frame (:func:`blocks.blocks_from_roads`,
        the rule of 'Extract city blocks'), with the counts in the log; the islands of
        OSM's ``junction=roundabout`` rings are no blocks. ``kwargs``: buildings, parcels,
        min_area, min_width, boundary (named ``boundary_name`` in the log)."""
        junction = qgis_io.osm_tag_column(frame, "junction")
        roundabout = None if junction is None else np.array(
            [str(v).strip().lower() == "roundabout" for v in junction], dtype=bool)
        graph, result = qgis_io.run_engine(
            frame.name, block_rules.blocks_from_roads, frame.geometry, road_class,
            progress=qgis_io.progress_for(feedback, *progress), roundabout=roundabout,
            **kwargs)
        st = result.stats
        closed = "" if boundary_name is None else f" and the boundary {boundary_name}"
        feedback.pushInfo(
            f"Street graph: {graph.n_edges} edges, {len(graph.nodes)} nodes; "
            f"{st['n_blocks']} blocks from {st['n_faces']} closed faces of {frame.name}"
            f"{closed} ({st['n_small']} too small, {st['n_thin']} too thin and "
            f"{counted(st['n_roundabout'], 'roundabout island')} dropped).")
        if boundary_name is not None:
            feedback.pushInfo(
                f"{counted(st['n_on_boundary'], 'block lies', 'blocks lie')} on the boundary "
                f"{boundary_name} (its edges are no street); "
                f"{counted(st['n_outside'], 'face lies', 'faces lie')} outside it and "
                f"{counted(st['n_without_street'], 'face', 'faces')} inside it no road "
                "reaches: no blocks.")
        return graph, result

    @staticmethod
    def require_roads_reach(roads, area, area_label: str, reach: float = 1.0):
        """Refuse given roads (a Frame) none of which reaches the target ``area`` (within
        ``reach`` m): the new streets would join none of them, and the run would end
        empty, or filled far from the roads, without saying why."""
        if roads is None or not len(roads.geometry):
            return
        target = shapely.union_all(np.asarray(area, dtype=object))
        lines = shapely.union_all(roads.geometry)
        if shapely.dwithin(target, lines, reach):
            return
        raise QgsProcessingException(
            f"Layer {roads.name} lies entirely outside {area_label} (its nearest road is "
            f"{shapely.distance(target, lines):,.0f} m away"
            + (f", more than {reach:,.0f} m" if reach > 1.0 else "") + "): no given road "
            "reaches the target, so none could join its new streets. Check that both layers "
            "cover the same place.")

    def roads_and_arterials(self, parameters, name, context, feedback, crs):
        """Road lines of an optional layer (drivable classes when it has OSM classes) and
        the arterials among them (level 0, else OSM motorway .. secondary); (None, None)
        when the layer is not given."""
        frame = qgis_io.read_source(self, parameters, name, context, feedback, kind="lines",
                                    target_crs=crs, optional=True,
                                    fields=["highway", "other_tags", "level"])
        if frame is None:
            return None, None
        keep, arterial = street_graph.drivable_and_arterial(
            qgis_io.osm_tag_column(frame, "highway"),
            frame.attributes["level"] if "level" in frame.attributes else None, len(frame))
        return frame.geometry[keep], frame.geometry[arterial]

    def block_ids(self, frame, feedback, field="block_id", what="block"):
        """A block (or parcel, ``what``) layer's own ids (:func:`core.ids.whole_ids`), or
        None with a note when they are not a unique whole number per feature (they are
        then numbered 1..n); the parts of a multi-part feature read apart keep its id."""
        if field not in frame.attributes:
            return None
        # the parts of one feature (read_source's ``parts``) follow each other and share its id
        first = ~pd.Series(np.asarray(frame.fids)).duplicated().to_numpy()
        ids = whole_ids(frame.attributes[field].to_numpy()[first])
        if ids is not None:
            ids = ids[np.cumsum(first) - 1]
        if ids is None:
            feedback.pushInfo(f"{frame.name}: {field} is not a unique whole number per "
                              f"{what}; {what}s are numbered 1..n in layer order instead.")
        return ids

    def blocks_or_roads_error(self, parameters, done: str, to_do: str):
        """The message when not exactly one of BLOCKS and ROADS is given (``done``: what
        happens to blocks, e.g. 'filled'; ``to_do``: e.g. 'fill')."""
        blocks_given, roads_given = self.given(parameters, "BLOCKS"), self.given(parameters, "ROADS")
        if blocks_given and roads_given:
            return (f"Give either Blocks or Roads, not both: blocks are {done} as they are, "
                    "roads are first turned into blocks.")
        if not blocks_given and not roads_given:
            return f"Give the Blocks to {to_do}, or Roads to extract the blocks from."
        return None

    def database_paths(self, parameters, context, first: str, second: str, what: str):
        """The files of one or two example databases (parameters ``first`` and optional
        ``second``) and their names: the file stems, numbered when both are the same."""
        paths = [self.parameterAsFile(parameters, first, context)]
        extra = self.parameterAsFile(parameters, second, context)
        if extra:
            paths.append(extra)
        if not paths[0]:
            raise QgsProcessingException(f"A {what} database is needed ({first}).")
        names = [self._database_name(p) for p in paths]
        if len(names) == 2 and names[0] == names[1]:
            names = [f"{n}_{k + 1}" for k, n in enumerate(names)]
        return paths, names

    @staticmethod
    def database_name(layer_label: str) -> str:
        """A database's name from the layer it is built from, as a file stem: 'Helsinki'
        for the lines of 'Helsinki.osm.pbf' (recorded in its metadata: a database that a
        model step writes to a temporary file is named after the step's output, 'OUTPUT')."""
        return re.sub(r"\W+", "_", str(layer_label).split(" (")[0]).strip("_") or "example"

    @staticmethod
    def _database_name(path: str) -> str:
        """The file's stem, or for a model step's temporary database (in Processing's
        temporary folder) the name recorded in it (:meth:`database_name`)."""
        stem = Path(path).stem
        try:
            temporary = Path(QgsProcessingUtils.tempFolder()).resolve() in \
                Path(path).resolve().parents
        except OSError:
            return stem
        if temporary:
            from ..plugin.retrieval import database

            try:
                return database.read_metadata(path).get("name") or stem
            except Exception:  # noqa: BLE001 - loading the database says what is wrong
                return stem
        return stem

    def style_databases(self, parameters, context, feedback, target_crs, n_databases: int):
        """The STYLE polygons and the 0-based database each one chooses (its STYLE_FIELD
        holds 1..n_databases), or None without style polygons."""
        field = self.parameterAsString(parameters, "STYLE_FIELD", context) or "database"
        style = qgis_io.read_source(self, parameters, "STYLE", context, feedback,
                                    kind="polygons", target_crs=target_crs, optional=True,
                                    fields=[field], read_twice=True)
        if style is None:
            return None
        if field not in style.attributes:
            raise QgsProcessingException(f"Layer {style.name} has no field '{field}' with the "
                                         "database number (1 or 2) per polygon.")
        values = pd.to_numeric(style.attributes[field], errors="coerce").to_numpy(
            dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(values) | (values != np.round(values)) | (values < 1) | \
            (values > n_databases)
        if bad.any():
            raise QgsProcessingException(
                f"Layer {style.name}: field '{field}' must hold a database number from 1 to "
                f"{n_databases} in every polygon ({int(bad.sum())} do not).")
        return style.geometry, values.astype(np.int64) - 1

    def add(self, parameter, help_text: str, advanced: bool = False):
        """Add a parameter with its help text (shown in the dialog and in qgis_process help)."""
        parameter.setHelp(help_text)
        if advanced:
            parameter.setFlags(parameter.flags() | QgsProcessingParameterDefinition.Flag.FlagAdvanced)
        if parameter.isDestination():
            self.addParameter(parameter, createOutput=True)
        else:
            self.addParameter(parameter)


def fill_quantile_parameter(name: str = "FILL_QUANTILE") -> QgsProcessingParameterNumber:
    """Fragment synthesis' fill quantile (one definition for the fragment tool, the road
    method chooser and the district model): % of the example's block areas, 50 .. 100,
    default :data:`plugin.roads.from_fragments.FILL_QUANTILE`."""
    from ..plugin.roads.from_fragments import FILL_QUANTILE

    return QgsProcessingParameterNumber(
        name, "Largest empty face (quantile of the example's block areas, %)",
        QgsProcessingParameterNumber.Type.Double, defaultValue=FILL_QUANTILE, minValue=50.0,
        maxValue=100.0)


def parse_class_list(text):
    """'primary, secondary' -> {'primary', 'secondary'}; empty -> empty set (keep all)."""
    if not text:
        return set()
    return {c.strip() for c in str(text).split(",") if c.strip()}


def drivable_lines(frame, class_field, classes, feedback):
    """Keep the lines of a drivable class.

    Returns (frame, road_class), road_class being None when the layer has no classes (no
    such field, not in OSM ``other_tags`` either, or all empty): then every line is kept.
    An explicitly chosen class field that does not exist is an error.
    """
    road_class, read_from = qgis_io.road_classes(frame, class_field)
    if read_from == "road_class" and classes:
        # the classes of 'Extract road hierarchy' (and the synthesis tools) kept as road_class;
        # the synthesis tools' own classes (major, minor, local ...) are streets too
        classes = set(classes) | set(street_graph.SYNTHESISED_CLASSES)
    if road_class is not None and all(c is None or c == "" for c in road_class):
        road_class = None
    if road_class is None:
        if class_field and class_field != "highway":
            raise QgsProcessingException(f"Layer {frame.name} has no field '{class_field}' "
                                         "with road classes.")
        feedback.pushInfo(f"{frame.name} has no road classes: every line is used.")
        return frame, None
    if not classes:
        return frame, road_class
    keep = np.array([c in classes for c in road_class], dtype=bool)
    n_keep = int(keep.sum())
    feedback.pushInfo(f"{n_keep} of {len(frame)} lines have a drivable class.")
    if n_keep == 0:
        raise QgsProcessingException(
            f"Layer {frame.name}: no line has one of the drivable classes "
            f"({', '.join(sorted(classes))}) in field '{class_field or 'highway'}'.")
    return qgis_io.subset(frame, keep), road_class[keep]
