"""Nothing lost, nothing half-written: how every urbansynth run (and the shipped model)
handles its output files.

- An output that is also an input (the same file, or the same layer of a GeoPackage) is
  refused before anything is written: the README promises inputs are never modified
  (the rule: ``core.destinations.overwrite_error``, shared with the command line).
- Every file output is written under a temporary name -- a hidden staging folder next to
  the destination, ``.urbansynth-run-XXXX/<the file's own name>``, so that GeoPackage
  layer names and shapefile sidecars come out right -- and moved into place only when the
  whole run succeeded. A failed or canceled run leaves the destinations as they were (an
  existing file stays untouched) and removes its staging folder. A layer written into an
  existing GeoPackage (``ogr:dbname=... table=...``) is staged in a GeoPackage of its own
  and copied into the target file on success.
- Outputs that are no files (memory layers, database connections) and QGIS's own
  temporary outputs (the Processing temporary folder) are written as they are.
- What a destination's format allows (used by ``qgis_io.write_sink``): an attribute named
  like the geometry column is renamed (``geom`` -> ``geom_1`` in a GeoPackage), and the
  field names GDAL cuts in a shapefile are read back for the log.
- A file named with dots ('my.town.v2.gpkg', '.shp', '.tif') gives its whole name before
  the extension to the GeoPackage layer and to the layer QGIS loads ('my.town.v2'; QGIS
  3.22 takes the name up to the first dot: 'my').

Used by ``processing_algorithms.common.AlgorithmBase`` (every algorithm) and by
``provider.ShippedModel`` (the district model: its outputs appear only when every step
succeeded). No engine code is involved.
"""
from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

from qgis.core import (
    QgsProcessingException,
    QgsProcessingOutputLayerDefinition,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterVectorDestination,
    QgsProcessingUtils,
    QgsProperty,
    QgsProviderRegistry,
)

from ..core.destinations import STAGING_PREFIX
from ..core.destinations import Input as _Input
from ..core.destinations import (make_folders, overwrite_error, remove_empty_folders,
                                 replaced_layers_error)
from . import styles

__all__ = ["STAGING_PREFIX", "OutputStaging", "destination_error", "sink_destination",
           "is_shapefile", "field_names_for", "shapefile_renames"]

#: The format every raster output is written in (a raster destination is named so).
RASTER_FORMAT = "GeoTIFF (*.tif *.tiff)"


_OGR_URI = re.compile(r"^ogr:dbname='(?P<path>(?:[^']|'')*)'\s+table=\"(?P<table>[^\"]+)\"")
#: An ogr: URI that names a file but no layer: QGIS 3.22 writes such an output into the
#: file's first layer (appending to it), so it is refused.
_OGR_NO_TABLE = re.compile(r"^ogr:dbname='(?P<path>(?:[^']|'')*)'")


@dataclass
class _Staged:
    name: str            # the destination parameter
    final: str           # the destination as given (path or ogr: URI)
    final_path: Path     # its file
    table: Optional[str]  # the GeoPackage layer for ogr: URIs, else None
    staging: Path        # the staging folder
    temp: str            # the destination the algorithm writes to
    temp_path: Path      # its file


def _destination(alg, definition, parameters, context) -> Optional[str]:
    """The destination of an output parameter as a path or URI, None when not requested."""
    value = parameters.get(definition.name())
    if value is None or value == "":
        return None
    if isinstance(definition, (QgsProcessingParameterFileDestination,
                               QgsProcessingParameterFolderDestination)):
        return alg.parameterAsFileOutput(parameters, definition.name(), context) or None
    return alg.parameterAsOutputLayer(parameters, definition.name(), context) or None


def _file_of(destination: str):
    """(file path, GeoPackage table or None) of a destination, None when it is no file."""
    match = _OGR_URI.match(destination)
    if match:
        return Path(match.group("path").replace("''", "'")), match.group("table")
    if re.match(r"^[a-z]+:", destination) and not re.match(r"^[A-Za-z]:[\\/]", destination):
        return None                          # memory:, postgres:, spatialite: ...
    return Path(destination.split("|")[0]), None


def _is_temporary(path: Path) -> bool:
    try:
        temp = Path(QgsProcessingUtils.tempFolder()).resolve()
        return temp == path.resolve().parent or temp in path.resolve().parents
    except OSError:
        return False


def _inputs(alg, parameters, context) -> List[_Input]:
    """The files (and GeoPackage layers) the run reads."""
    out = []
    for definition in alg.parameterDefinitions():
        name = definition.name()
        if definition.isDestination() or parameters.get(name) in (None, ""):
            continue
        kind = definition.type()
        try:
            if kind in ("source", "vector"):
                layer = alg.parameterAsVectorLayer(parameters, name, context)
            elif kind == "raster":
                layer = alg.parameterAsRasterLayer(parameters, name, context)
            elif kind == "file":
                path = alg.parameterAsFile(parameters, name, context)
                if path:
                    out.append(_Input(name, Path(path), None))
                continue
            else:
                continue
        except Exception:  # noqa: BLE001 - an unreadable input is reported where it is read
            continue
        if layer is None:
            continue
        parts = QgsProviderRegistry.instance().decodeUri(layer.providerType(), layer.source())
        if parts.get("path"):
            path = Path(parts["path"])
            layer_name = parts.get("layerName") or None
            if layer_name is None and layer.providerType() == "ogr":
                # a bare file path reads the file's first layer: that layer is the input, a
                # new layer beside it in the same GeoPackage is not
                layer_name = _first_layer(path)
            out.append(_Input(name, path, layer_name))
    return out


def _first_layer(path: Path) -> Optional[str]:
    """The name of a vector file's first layer (what QGIS reads from a bare path), None for
    a file of one unnamed layer or one OGR cannot open."""
    from osgeo import ogr

    if path.suffix.lower() != ".gpkg":
        return None        # a shapefile, a GeoJSON: the file is the layer
    ds = ogr.Open(str(path))
    if ds is None or ds.GetLayerCount() == 0:
        return None
    return ds.GetLayer(0).GetName()


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _file_type_error(definition, destination: str) -> Optional[str]:
    """The message when a file output's name does not end in its declared type's extension
    (a GeoPackage named .txt, a raster named .asc), else None: the file is written in the
    declared format whatever it is called (every raster output as a GeoTIFF:
    ``qgis_io.write_geotiff``, ``qgis_io.write_image``), and the GUI adds the extension
    where qgis_process does not."""
    if isinstance(definition, QgsProcessingParameterRasterDestination):
        written_as = RASTER_FORMAT
    elif isinstance(definition, QgsProcessingParameterFileDestination):
        written_as = definition.fileFilter()
    else:
        return None
    extensions = [e.lower() for e in re.findall(r"\*(\.[A-Za-z0-9]+)", written_as)]
    if not extensions or Path(destination).suffix.lower() in extensions:
        return None
    return (f"Output {definition.description()} ({definition.name()}) is written as "
            f"{written_as}, but {destination} does not end in "
            f"{' or '.join(extensions)}: name it so, or another program will misread it.")


def destination_error(alg, parameters, context) -> Optional[str]:
    """The message when an output would overwrite an input or another output of the run,
    names a GeoPackage but no layer in it, or a file whose extension is not its type's,
    else None (checked before anything is written: in the dialog, on the command line and
    when the run starts)."""
    inputs = _inputs(alg, parameters, context)
    written = []   # (definition, path, table) of the outputs so far
    for definition in alg.destinationParameterDefinitions():
        destination = _destination(alg, definition, parameters, context)
        if destination and not _OGR_URI.match(destination) and \
                _OGR_NO_TABLE.match(destination):
            return (f"Output {definition.description()} ({definition.name()}) names the "
                    f"file {_OGR_NO_TABLE.match(destination).group('path')} but no layer in "
                    "it (table=\"...\"): QGIS would append the output to the file's first "
                    "layer. Give a layer name, or a file of its own.")
        target = _file_of(destination) if destination else None
        if target is None:
            continue
        path, table = target
        for other, other_path, other_table in written:
            if (_same(path, other_path) or path.resolve() == other_path.resolve()) and \
                    (table is None or other_table is None or table == other_table):
                return (f"Outputs {other.description()} ({other.name()}) and "
                        f"{definition.description()} ({definition.name()}) would both be "
                        f"written to {path}: choose a file (or GeoPackage layer) of its own "
                        "for each.")
        written.append((definition, path, table))
        message = overwrite_error(f"Output {definition.description()} ({definition.name()})",
                                  path, table, inputs)
        if message:
            return message
        message = _file_type_error(definition, destination) or \
            _replaced_layers_error(definition, path, table)
        if message:
            return message
    return None


def _replaced_layers_error(definition, path: Path, table: Optional[str]) -> Optional[str]:
    """:func:`core.destinations.replaced_layers_error` for one output: a layer output
    written to a GeoPackage named without a layer makes the layer QGIS names after the file;
    a database (a file output) replaces an earlier Urban Synthesis database whole."""
    label = f"Output {definition.description()} ({definition.name()})"
    if not isinstance(definition, QgsProcessingParameterFileDestination):
        return replaced_layers_error(label, path, table, [path.stem])
    message = replaced_layers_error(label, path, table, [], as_layer_hint=False)
    if message:
        from ..core.progress import InputError
        from ..retrieval import database   # the engine's packages: only when one is there

        try:
            database.read_metadata(path)
            return None          # an earlier Urban Synthesis database: replaced whole
        except InputError:
            pass
    return message


# ------------------------------------------------------- what a destination's format allows

#: The geometry column GDAL's writer gives a new layer of these formats (its GEOMETRY_NAME
#: default): an attribute of that name cannot be written beside it.
_GEOMETRY_COLUMNS = {".gpkg": "geom", ".sqlite": "GEOMETRY", ".db": "GEOMETRY"}
_OGR_GEOMETRY_COLUMN = re.compile(
    r"^ogr:dbname='(?:[^']|'')*'\s+table=\"[^\"]+\"\s*\((?P<col>[^)]+)\)")


def sink_destination(parameters, name: str, context) -> Optional[str]:
    """The destination of a feature sink parameter as given (a path or a URI), read without
    side effects (``parameterAsSink`` adds the layer to load on completion), None when it
    is no string."""
    value = parameters.get(name)
    if isinstance(value, QgsProcessingOutputLayerDefinition):
        value = value.sink.valueAsString(context.expressionContext(), "")[0]
    return value if isinstance(value, str) and value else None


def _geometry_column(destination: Optional[str]) -> Optional[str]:
    """The geometry column of a layer written to ``destination`` (GeoPackage: 'geom'),
    None for formats without one (shapefile, memory layer)."""
    if not destination or destination == "TEMPORARY_OUTPUT":     # a memory layer
        return None
    match = _OGR_GEOMETRY_COLUMN.match(destination)
    if match:
        return match.group("col").strip()
    target = _file_of(destination)
    if target is None:
        return None
    # a file named without an extension is written in QGIS's default vector format
    suffix = target[0].suffix or f".{QgsProcessingUtils.defaultVectorExtension()}"
    return _GEOMETRY_COLUMNS.get(suffix.lower())


def is_shapefile(destination: Optional[str]) -> bool:
    """Whether ``destination`` is an ESRI shapefile (10-character field names, numbers as
    fixed-width text)."""
    target = _file_of(destination) if destination else None
    return bool(target) and target[0].suffix.lower() == ".shp"


def field_names_for(destination: Optional[str], names: List[str]):
    """(names as written, message or None): an attribute named like the destination's
    geometry column (a PostGIS export's ``geom`` written to a GeoPackage, where GDAL names
    the geometry column ``geom`` and refuses the table) is written as ``geom_1`` (the first
    free ``<name>_<n>``, as QGIS names a duplicate field); the message says so."""
    column = _geometry_column(destination)
    if column is None or column.lower() not in {n.lower() for n in names}:
        return list(names), None
    taken = {n.lower() for n in names} | {column.lower(), "fid"}
    out, renamed = [], []
    for name in names:
        if name.lower() != column.lower():
            out.append(name)
            continue
        n = 1
        while f"{name}_{n}".lower() in taken:
            n += 1
        new = f"{name}_{n}"
        taken.add(new.lower())
        out.append(new)
        renamed.append(f"'{name}' as '{new}'")
    return out, (f"field {', '.join(renamed)}: '{column}' is the name of the geometry "
                 f"column in {Path(_file_of(destination)[0]).name}.")


def shapefile_renames(path: str, names: List[str]) -> List[tuple]:
    """(declared, written) for each field GDAL renamed in the shapefile ``path`` (names of
    over 10 characters are cut, and numbered where two cuts clash: ``tortuosity_b`` ->
    ``tortuosi_1``). Read back from the file (closed first), so the names are GDAL's own."""
    from osgeo import ogr

    file = Path(str(path).split("|")[0])
    if not file.exists() and file.with_suffix(".dbf").exists():
        file = file.with_suffix(".dbf")   # a table without geometry: GDAL writes no .shp
    ds = ogr.Open(str(file))
    if ds is None or ds.GetLayerCount() == 0:
        return []
    definition = ds.GetLayer(0).GetLayerDefn()
    written = [definition.GetFieldDefn(i).GetName() for i in range(definition.GetFieldCount())]
    ds = None
    return [(a, b) for a, b in zip(names, written) if a != b]


def _dotted_geopackage_layer(definition, path: Path) -> bool:
    """Whether a vector output to the bare GeoPackage path ``path`` has a dot in its name
    (its layer is then named explicitly: :meth:`OutputStaging._stage`)."""
    return isinstance(definition, (QgsProcessingParameterFeatureSink,
                                   QgsProcessingParameterVectorDestination)) and \
        path.suffix.lower() == ".gpkg" and "." in path.stem and '"' not in path.stem


def _loaded_name_in_full(destination: str, details) -> Optional[str]:
    """The name QGIS 3.22 gives a loaded output after its file, but with the whole file
    name before the extension ('my.town.v2'); None where QGIS's own name is right: the
    output is named explicitly (forceName, or the user prefers the output's name to the
    file's), names a layer of its file, has no dot, or lies in a temporary folder (QGIS
    then uses the output's name)."""
    from qgis.core import QgsSettings
    from qgis.PyQt.QtCore import QStandardPaths

    prefer_file = QgsSettings().value("Processing/Configuration/PREFER_FILENAME_AS_LAYER_NAME",
                                      True, bool)
    if details.forceName or (details.name and not prefer_file) or "|layername=" in destination:
        return None
    target = _file_of(destination)
    if target is None or target[1] is not None:
        return None
    path = target[0]
    full = path.name.rsplit(".", 1)[0] if "." in path.name else path.name
    if not full or full == path.name.split(".")[0]:
        return None                      # no dot before the extension: QGIS names it right
    temp = [Path(p) for p in QStandardPaths.standardLocations(
        QStandardPaths.StandardLocation.TempLocation)]
    if details.name and any(_inside(path, folder) for folder in temp):
        return None
    return full


def _inside(path: Path, folder: Path) -> bool:
    try:
        path, folder = path.resolve(), folder.resolve()
    except OSError:
        return False
    return folder == path.parent or folder in path.parents


class OutputStaging:
    """The file outputs of one run, written to staging folders and moved into place by
    :meth:`commit`, or removed by :meth:`discard`."""

    def __init__(self, alg, parameters: dict, context, feedback=None):
        self.alg = alg
        self.feedback = feedback
        self.parameters = parameters
        self.context = context
        self.staged: List[_Staged] = []
        self._made_dirs: List[Path] = []

    def prepare(self) -> dict:
        """Refuse an output that is an input; return the parameters with every file
        output redirected into its staging folder."""
        message = destination_error(self.alg, self.parameters, self.context)
        if message:
            raise QgsProcessingException(message)
        staged_parameters = dict(self.parameters)
        try:
            for definition in self.alg.destinationParameterDefinitions():
                self._stage(definition, staged_parameters)
        except BaseException:
            self.discard()
            raise
        return staged_parameters

    def _stage(self, definition, staged_parameters):
        destination = _destination(self.alg, definition, self.parameters, self.context)
        target = _file_of(destination) if destination else None
        if target is None or isinstance(definition, QgsProcessingParameterFolderDestination):
            return
        path, table = target
        if _is_temporary(path):
            return
        folder = path.parent
        self._make_folder(folder, definition)
        try:
            staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=folder))
        except OSError as exc:
            raise QgsProcessingException(
                f"Output {definition.description()} ({definition.name()}) cannot be written "
                f"to the folder {folder}: {exc.strerror or exc}.") from exc
        temp_path = staging / path.name
        dotted = _dotted_geopackage_layer(definition, path)
        # QGIS 3.22 reads an ogr: URI's format from its file name after the first dot ('my.
        # town.gpkg': no driver, after the whole run): the file is written by its path, the
        # table named by the writer's layerName option (the geometry column: GeoPackage's)
        if table is not None and not dotted:
            temp = destination.replace(_OGR_URI.match(destination).group("path"),
                                       str(temp_path).replace("'", "''"), 1)
        else:
            temp = str(temp_path)
            column = _geometry_column(destination) if table is not None else None
            if column and column != "geom" and self.feedback is not None:
                self.feedback.pushWarning(
                    f"Output {definition.name()}: the geometry column is named 'geom', not "
                    f"'{column}': QGIS 3.22 cannot name it in a file whose name has a dot "
                    f"before its extension ({path.name}).")
        self.staged.append(_Staged(definition.name(), destination, path, table, staging,
                                   temp, temp_path))
        staged_parameters[definition.name()] = self._redirect(
            self.parameters[definition.name()], definition, temp,
            (table or path.stem) if dotted else None)

    def _make_folder(self, folder: Path, definition):
        try:
            self._made_dirs.extend(make_folders(folder))
        except OSError as exc:
            raise QgsProcessingException(
                f"Output {definition.description()} ({definition.name()}): the folder "
                f"{folder} cannot be created: {exc.strerror or exc}.") from exc

    @staticmethod
    def _redirect(value, definition, temp: str, layer_name: Optional[str] = None):
        """The parameter value with its destination replaced (keeping the layer name and
        options a QgsProcessingOutputLayerDefinition carries); ``layer_name``: the name of
        the GeoPackage layer to write. QGIS 3.22 names the layer of a GeoPackage given as
        a bare path after the file name up to its first dot (QFileInfo::baseName:
        'my.town.v2.gpkg' -> 'my'); the writer's ``layerName`` option names it in full."""
        if isinstance(value, QgsProcessingOutputLayerDefinition):
            copy = QgsProcessingOutputLayerDefinition(value)
            copy.sink = QgsProperty.fromValue(temp)
        elif isinstance(definition, (QgsProcessingParameterFeatureSink,
                                     QgsProcessingParameterVectorDestination,
                                     QgsProcessingParameterRasterDestination)):
            copy = QgsProcessingOutputLayerDefinition(temp)
        else:
            return temp
        if layer_name:
            copy.createOptions = dict(copy.createOptions or {}, layerName=layer_name)
        return copy

    # --------------------------------------------------------------- end of the run

    def commit(self, results: Dict) -> Dict:
        """Move every staged output into place; the results and the layers QGIS loads on
        completion then name the final destinations."""
        try:
            for item in self.staged:
                self._move(item)
        finally:
            self._remove_staging()
        renames = {item.temp: item.final for item in self.staged}
        renames.update({str(item.temp_path): str(item.final_path) for item in self.staged})
        out = {k: self._renamed(v, renames) for k, v in results.items()}
        styles.move_written_field_names(renames)
        self._rename_layers_to_load(renames)
        self._name_layers_in_full()
        self._store_styles(renames)
        return out

    def _store_styles(self, renames):
        """Every styled output keeps its style in the file (GeoPackage default style or a
        sidecar .qml), so that it opens styled in a new project; an output with no style but
        fields GDAL renamed keeps their full names as aliases (a style of aliases alone)."""
        stored = {self._renamed(k, renames): styles.STYLE_REQUESTS.pop(k)
                  for k in [k for k in styles.STYLE_REQUESTS if self._renamed(k, renames) != k]}
        for item in self.staged:
            if styles.written_field_names(str(item.final_path)):
                stored.setdefault(str(item.final_path), None)
        for final, qml in stored.items():
            warning = styles.save_style_with_layer(final, qml)
            if warning and self.feedback is not None:
                self.feedback.pushWarning(f"Output {final}: {warning}.")
            # loaded now, an output with no style of its own gets its aliases all the same
            if qml is None and self.context.willLoadLayerOnCompletion(final) and \
                    self.context.layerToLoadOnCompletionDetails(final).postProcessor() is None:
                styles.attach_style(self.context, final, None)

    def _rename_layers_to_load(self, renames):
        """The layers QGIS loads on completion keyed by their final destinations, each with
        the style the run gave it. setLayersToLoadOnCompletion deletes the old entries'
        post-processors, so the details are rebuilt and the styles attached afresh."""
        from qgis.core import QgsProcessingContext

        layers = self.context.layersToLoadOnCompletion()
        if all(self._renamed(k, renames) == k for k in layers):
            return
        # checking the destinations before the run (parameterAsOutputLayer) added an entry
        # under the destination as given; where the written layer's key differs from it (a
        # GeoPackage layer: 'file.gpkg|layername=...'), that entry would load the output a
        # second time, or fail to load (an ogr: URI)
        written = {self._renamed(k, renames) for k in layers} - set(layers)
        layers = {k: v for k, v in layers.items() if not any(
            k == item.final and k not in written and
            any(w.split("|")[0] == str(item.final_path) for w in written)
            for item in self.staged)}
        rebuilt, kept_styles = {}, {}
        # a staged layer comes after any entry QGIS already holds for its final path: its
        # details and style win
        for key, details in sorted(layers.items(),
                                   key=lambda kv: self._renamed(kv[0], renames) != kv[0]):
            final = self._renamed(key, renames)
            fresh = QgsProcessingContext.LayerDetails(
                details.name, details.project, details.outputName, details.layerTypeHint)
            fresh.forceName = details.forceName
            rebuilt[final] = fresh
            kept_styles[final] = styles.attached_style(details) or kept_styles.get(final)
        self.context.setLayersToLoadOnCompletion(rebuilt)
        for final, qml in kept_styles.items():
            if qml:
                styles.attach_style(self.context, final, qml)

    def _name_layers_in_full(self):
        """A loaded output file named with dots ('my.town.v2.tif') is named 'my.town.v2'
        in the project, not 'my': QGIS 3.22 takes a layer's name from its file name up to
        the first dot (``LayerDetails.setOutputLayerName``: QFileInfo::baseName). Where
        QGIS would name the layer after its file, the full name is given instead."""
        for key in list(self.context.layersToLoadOnCompletion()):
            details = self.context.layerToLoadOnCompletionDetails(key)
            name = _loaded_name_in_full(key, details)
            if name:
                details.name = name
                details.forceName = True

    @staticmethod
    def _renamed(value, renames):
        if not isinstance(value, str):
            return value
        if value in renames:
            return renames[value]
        for old, new in renames.items():
            if old in value:
                return value.replace(old, new)
        return value

    def _move(self, item: _Staged):
        written = sorted(p for p in item.staging.iterdir() if p.is_file())
        if not written:
            return                           # the output was not written (optional)
        if item.table is not None and item.final_path.exists():
            self._copy_layer(item)
            self._copy_style(item)
            return
        for path in written:
            os.replace(path, item.final_path.parent / path.name)

    @staticmethod
    def _copy_layer(item: _Staged):
        """A layer staged in a GeoPackage of its own, copied into the target GeoPackage
        (replacing a layer of that name)."""
        from osgeo import gdal

        options = gdal.VectorTranslateOptions(
            format="GPKG", accessMode="overwrite", layers=[item.table], layerName=item.table)
        result = gdal.VectorTranslate(str(item.final_path), str(item.temp_path),
                                      options=options)
        if result is None:
            raise QgsProcessingException(
                f"Output {item.name}: the layer '{item.table}' could not be written into "
                f"{item.final_path}: {gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
        result = None

    def _copy_style(self, item: _Staged):
        """The default style stored with the staged layer, stored with its copy too: an
        algorithm run inside this one (synthesizeroads' method) commits its own staged
        output, style included, into this run's staging GeoPackage, and _copy_layer copies
        the layer but not the GeoPackage's layer_styles table (the output, added to an
        existing GeoPackage, opened unstyled)."""
        from qgis.core import QgsVectorLayer

        staged = QgsVectorLayer(f"{item.temp_path}|layername={item.table}", "staged", "ogr")
        if not staged.isValid() or not staged.listStylesInDatabase()[0]:
            return
        qml = item.staging / f"{item.table}.qml"
        _, ok = staged.saveNamedStyle(str(qml))   # the default style it loaded
        if not ok:
            return
        warning = styles.save_style_with_layer(f"{item.final_path}|layername={item.table}",
                                               str(qml))
        if warning and self.feedback is not None:
            self.feedback.pushWarning(f"Output {item.final}: {warning}.")

    def discard(self):
        """Remove everything written (the destinations stay as they were)."""
        self._remove_staging()
        for key in [k for k in styles.STYLE_REQUESTS
                    if any(str(item.staging) in k for item in self.staged)]:
            styles.STYLE_REQUESTS.pop(key, None)
        remove_empty_folders(self._made_dirs)   # only the folders this run created

    def _remove_staging(self):
        for item in self.staged:
            shutil.rmtree(item.staging, ignore_errors=True)
