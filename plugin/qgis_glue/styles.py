"""Shipped QML styles on outputs: applied when QGIS loads an output, stored in the file
itself (GeoPackage default style, or a sidecar .qml) once the run's outputs are in place, and
a place in the layer list by kind. QGIS only: the provider imports it without the engine's
packages.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

from qgis.core import QgsProject

from ..core.paths import RESOURCES

STYLES = RESOURCES / "styles"
_POST_PROCESSORS = []  # QGIS does not own Python post-processors: keep them alive


#: output destination -> shipped style file, until the run's outputs are in place
#: (:meth:`qgis_glue.outputs.OutputStaging.commit` stores them with the files)
STYLE_REQUESTS: dict = {}


def style_output(context, dest_id: Optional[str], qml_name: str) -> None:
    """Style an output with a shipped QML style: when QGIS loads it on completion, and in
    the file itself once the run's outputs are in place (:func:`save_style_with_layer`), so
    that it opens styled in any project."""
    qml = STYLES / qml_name
    if not dest_id or not qml.exists():
        return
    STYLE_REQUESTS[dest_id] = str(qml)
    if context.willLoadLayerOnCompletion(dest_id):
        attach_style(context, dest_id, str(qml))


#: The longest field name a shapefile (dBase) keeps: longer ones are cut to it on writing.
DBF_NAME_LENGTH = 10

#: file written -> {field name declared: name GDAL wrote} for the fields GDAL renamed
#: (``qgis_io.write_sink`` reads them back from a shapefile; ``outputs.OutputStaging``
#: moves them to the final path): two names cut alike are numbered (``too_steep_long`` ->
#: ``too_steep_``, ``too_steep_lat`` -> ``too_stee_1``), which no rule can guess
WRITTEN_FIELD_NAMES: dict = {}


def _file_key(source: str) -> str:
    return str(Path(str(source).split("|")[0]))


def written_field_names(source: str) -> dict:
    """The fields GDAL renamed in the file ``source`` (:data:`WRITTEN_FIELD_NAMES`)."""
    return WRITTEN_FIELD_NAMES.get(_file_key(source), {})


def record_written_field_names(source: str, renamed: dict) -> None:
    if renamed:
        WRITTEN_FIELD_NAMES[_file_key(source)] = dict(renamed)


def move_written_field_names(renames: dict) -> None:
    """Follow files moved from one path to another (``{old: new}``)."""
    for old, new in renames.items():
        if _file_key(old) in WRITTEN_FIELD_NAMES:
            WRITTEN_FIELD_NAMES[_file_key(new)] = WRITTEN_FIELD_NAMES.pop(_file_key(old))


def style_for_fields(qml: str, field_names, written: Optional[dict] = None) -> str:
    """``qml`` with every field it names that the layer lacks named as the layer has it, in
    a temporary copy: as GDAL wrote it (``written``: declared -> written names, read back
    from the file), else cut to a shapefile's ten characters (``undesirable`` ->
    ``undesirabl``); ``qml`` itself when the layer has every field (a GeoPackage) or none
    can be matched. A shipped style names the engine's fields, whose rules would otherwise
    match nothing in a shapefile, or another field's values (tested in
    tests/test_alg_subdivide_parcels.py and tests/test_alg_tessellate_streets.py).
    """
    import re
    import tempfile

    have = set(field_names)
    written = written or {}
    text = Path(qml).read_text(encoding="utf-8")
    named = set(re.findall(r'(?:&quot;|(?:name|field|attr)=")([A-Za-z_][A-Za-z0-9_]*)'
                           r'(?:&quot;|")', text))
    renames = {}
    for name in named - have:
        cut = name[:DBF_NAME_LENGTH]
        if written.get(name) in have:
            renames[name] = written[name]
        elif len(name) > DBF_NAME_LENGTH and cut in have and cut not in written.values():
            renames[name] = cut
    if not renames:
        return qml
    for name, cut in renames.items():
        text = re.sub(rf'(&quot;|(?:name|field|attr)="){re.escape(name)}(&quot;|")',
                      rf"\g<1>{cut}\g<2>", text)
    # in Processing's temporary folder, which QGIS removes when it closes
    from qgis.core import QgsProcessingUtils

    out = Path(tempfile.mkdtemp(prefix="urbansynth-style-",
                                dir=QgsProcessingUtils.tempFolder())) / Path(qml).name
    out.write_text(text, encoding="utf-8")
    return str(out)


def save_style_with_layer(destination: str, qml: Optional[str]) -> Optional[str]:
    """Store ``qml`` with the written layer as its default style: in the GeoPackage's
    ``layer_styles`` table, or as the sidecar ``.qml`` QGIS reads for other files. A field
    GDAL renamed (:func:`written_field_names`) gets its full name as its alias there, which
    the plugin's tools read it by (``qgis_io.read_source``): a shapefile output of one tool
    is the input of the next. ``qml`` None: the aliases alone. Returns a warning, or None
    when the style was stored."""
    from qgis.core import QgsVectorLayer

    file = Path(destination.split("|")[0])
    if file.suffix.lower() == ".shp" and not file.exists() and file.with_suffix(".dbf").exists():
        destination = str(file.with_suffix(".dbf"))   # a table: GDAL wrote no .shp
    layer = QgsVectorLayer(destination, "output", "ogr")
    if not layer.isValid():
        return f"the output {destination} could not be opened to store its style"
    written = written_field_names(destination)
    if not layer.isSpatial():
        qml = None            # a table (a CSV, a layer without geometry): no symbology
        if not written:
            return None
    if qml is not None:
        message, ok = layer.loadNamedStyle(style_for_fields(qml, layer.fields().names(),
                                                            written))
        if not ok:
            return f"the style {qml} could not be read: {message}"
    _alias_written_names(layer, written)
    if layer.dataProvider().storageType() == "GPKG":
        _drop_stored_style(layer, layer.name())
        error = layer.saveStyleToDatabase(layer.name(), "Urban Synthesis default style",
                                          True, "")
        return f"the style could not be stored in {destination}: {error}" if error else None
    message, ok = layer.saveNamedStyle(str(Path(destination.split("|")[0]).with_suffix(".qml")))
    return None if ok else f"the style could not be saved next to {destination}: {message}"


def _alias_written_names(layer, written: dict) -> None:
    """Each field GDAL renamed (``written``: {declared: written}) gets its declared name as
    its alias."""
    for declared, name in written.items():
        index = layer.fields().indexOf(name)
        if index >= 0:
            layer.setFieldAlias(index, declared)


def _drop_stored_style(layer, name: str) -> None:
    """Delete the style ``name`` stored for ``layer``'s table in its GeoPackage (the one an
    earlier run into the same table stored). QGIS 3.22 asks 'A matching style already
    exists ... overwrite it?' in a modal message box before it saves over one: a second run
    into the same GeoPackage layer waited for an answer forever (qgis_process, scripts) or
    opened a dialog from Processing's worker thread."""
    n_related, ids, names, _, _ = layer.listStylesInDatabase()
    for style_id, style_name in list(zip(ids, names))[:n_related]:
        if style_name == name:
            layer.deleteStyleFromDatabase(style_id)


#: Where a styled output goes in the layer list, top first (points over lines over
#: buildings over areas): a later output is placed among the plugin's layers by this.
STACK = ("intersections.qml", "junctions.qml", "roads_by_level.qml", "buildings_by_height.qml",
         "street_surfaces.qml", "blocks.qml", "parcels_by_quality.qml")
_STACK_PROPERTY = "urban_synthesis/stack"


def attach_style(context, dest_id: str, qml: Optional[str]) -> None:
    """Give the layer QGIS loads on completion for ``dest_id`` the style file ``qml`` and
    its place in the layer list (:data:`STACK`), and the fields GDAL renamed their full
    names as aliases (Processing loads a file without its sidecar style, which holds them).
    ``qml`` None: the aliases alone."""
    from qgis.core import QgsProcessingLayerPostProcessorInterface

    class _Styler(QgsProcessingLayerPostProcessorInterface):
        def postProcessLayer(self, layer, ctx, feedback):  # noqa: N802
            if layer is None or not layer.isValid():
                return
            fields = layer.fields().names() if hasattr(layer, "fields") else []
            written = written_field_names(layer.source())
            if qml and layer.isSpatial():
                layer.loadNamedStyle(style_for_fields(qml, fields, written) if fields else qml)
            if fields:
                _alias_written_names(layer, written)
            layer.triggerRepaint()
            if qml:
                _stack(layer, ctx.project() or QgsProject.instance(), Path(qml).name)

    styler = _Styler()
    styler.qml = qml
    _POST_PROCESSORS.append(styler)
    context.layerToLoadOnCompletionDetails(dest_id).setPostProcessor(styler)


def _stack(layer, project, style: str) -> None:
    """Move the layer's node above the plugin's layers that belong below it (QGIS 3.22
    adds loaded outputs in the order of their file names: parcels would hide buildings)."""
    if project is None or style not in STACK:
        return
    rank = STACK.index(style)
    layer.setCustomProperty(_STACK_PROPERTY, rank)
    node = project.layerTreeRoot().findLayer(layer.id())
    if node is None or node.parent() is None:
        return
    root = node.parent()                 # the project's root, or Processing's results group
    others = [n for n in root.children() if n is not node]

    def rank_of(other):
        value = other.layer().customProperty(_STACK_PROPERTY) \
            if hasattr(other, "layer") and other.layer() is not None else None
        return None if value is None else int(value)

    ranks = [rank_of(n) for n in others]
    below = [i for i, r in enumerate(ranks) if r is not None and r > rank]
    above = [i for i, r in enumerate(ranks) if r is not None and r <= rank]
    if below:                            # right above the first layer that belongs below
        where = root.children().index(others[below[0]])
    elif above:                          # right below the last layer that belongs above
        where = root.children().index(others[above[-1]]) + 1
    else:
        return
    # the copy goes in before the original leaves: a layer that leaves the layer tree
    # leaves the project
    root.insertChildNode(where, node.clone())
    root.removeChildNode(node)


def attached_style(details) -> Optional[str]:
    """The style file :func:`attach_style` gave these layer details, if any."""
    return getattr(details.postProcessor(), "qml", None)
