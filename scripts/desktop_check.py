"""Desktop check, run INSIDE QGIS desktop (started by scripts/run_desktop_check.py).

The same file is executed twice by QGIS:

1. as ``PYQGIS_STARTUP`` (before plugins load, ``qgis.utils.iface`` still None): it starts
   collecting every message of the QGIS message log, so plugin-loading errors are seen too,
   and arms a watchdog that still fires when a Python error dialog blocks the startup;
2. as ``qgis --code`` (after the main window is up and the plugins are started): it schedules
   the checks in the event loop.

The checks: the ``urbansynth`` provider is registered with all its algorithms, each has an
icon, help text and help on every parameter, is listed in the Processing toolbox and its
dialog builds; example outputs (roads, blocks, buildings of Helsinki) are made with
``processing.runAndLoadResults`` so the shipped QML styles apply on load, the map zooms to
them, the main window is saved as a PNG, a JSON result is written and QGIS quits.

Environment (set by the launcher): US_DESKTOP_RESULT (JSON path), US_DESKTOP_SCREENSHOT (PNG
path), US_DESKTOP_WORK (folder for the outputs), US_DESKTOP_HELSINKI (the .osm.pbf),
US_DESKTOP_TIMEOUT (seconds before the watchdog writes what it has and quits).
"""
import json
import os
import sys
import time
import traceback

from qgis.core import Qgis, QgsApplication, QgsProject
from qgis.PyQt.QtCore import QTimer

_STATE = "_urbansynth_desktop_check"  # a module in sys.modules shared by both executions
PROVIDER_ID = "urbansynth"


def _state():
    """Shared state across the two executions (both run in QGIS's __main__ namespace)."""
    import types

    state = sys.modules.get(_STATE)
    if state is None:
        state = types.ModuleType(_STATE)
        state.log = []
        state.t0 = time.time()
        state.result = {"errors": []}
        state.done = False

        def collect(message, tag, level):
            state.log.append({"tag": tag, "level": int(level), "message": message,
                              "t": round(time.time() - state.t0, 2)})

        state.collect = collect
        QgsApplication.messageLog().messageReceived.connect(collect)
        sys.modules[_STATE] = state
    return state


def _finish(state, code=0):
    result = state.result
    if state.done:
        return
    state.done = True
    result["log"] = list(state.log)
    result["elapsed_s"] = round(time.time() - state.t0, 1)
    with open(os.environ["US_DESKTOP_RESULT"], "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    QgsProject.instance().clear()  # nothing to save: no "save project?" prompt on exit
    QgsApplication.exit(code)


def _algorithm_problems(alg):
    problems = []
    if alg.icon().isNull():
        problems.append("no icon")
    if not alg.shortHelpString().strip():
        problems.append("no shortHelpString")
    for p in alg.parameterDefinitions():
        if not (p.help() or "").strip():
            problems.append(f"parameter {p.name()} has no help")
    return problems


def _toolbox_algorithm_ids():
    """Algorithm ids shown under the provider in the Processing toolbox dock."""
    from processing.gui.ProcessingToolbox import ProcessingToolbox
    from qgis.utils import iface

    toolbox = iface.mainWindow().findChild(ProcessingToolbox)
    if toolbox is None:
        return None
    tree = toolbox.algorithmTree
    model = tree.model()
    found = []

    def walk(parent):
        for row in range(model.rowCount(parent)):
            index = model.index(row, 0, parent)
            alg = tree.algorithmForIndex(index)
            if alg is not None and alg.provider() and alg.provider().id() == PROVIDER_ID:
                found.append(alg.id())
            walk(index)

    walk(model.index(-1, -1))  # the invisible root
    return sorted(set(found))


def _dialog_errors(alg_ids):
    """Build (without showing) every algorithm's dialog: parameter widgets must all work."""
    import processing

    errors = {}
    for alg_id in alg_ids:
        try:
            dialog = processing.createAlgorithmDialog(alg_id)
            if dialog is None:
                errors[alg_id] = "no dialog"
            else:
                dialog.deleteLater()
        except Exception:  # noqa: BLE001 (reported, not hidden)
            errors[alg_id] = traceback.format_exc()
    return errors


def _run_and_load(result, work, helsinki):
    """Helsinki roads, blocks and buildings made and loaded as a user would from the dialog."""
    import processing
    from processing.core.ProcessingConfig import ProcessingConfig

    # Helsinki's OSM polygons include invalid ones and QGIS stops on them by default: the
    # user answers the plugin's message by choosing "Do not filter" (the plugin repairs)
    ProcessingConfig.setSettingValue(ProcessingConfig.FILTER_INVALID_GEOMETRIES, 0)
    roads = os.path.join(work, "roads.gpkg")
    blocks = os.path.join(work, "blocks.gpkg")
    buildings = os.path.join(work, "buildings.gpkg")
    processing.runAndLoadResults("urbansynth:extractblocks", {
        "ROADS": f"{helsinki}|layername=lines", "BUILDINGS": f"{helsinki}|layername=multipolygons",
        "OUTPUT": blocks, "OUTPUT_BUILDINGS": buildings})
    processing.runAndLoadResults("urbansynth:extractroadhierarchy", {
        "INPUT": f"{helsinki}|layername=lines", "OUTPUT": roads})
    loaded = {}
    for layer in QgsProject.instance().mapLayers().values():
        path = layer.source().split("|")[0]
        for key, target in (("roads", roads), ("blocks", blocks), ("buildings", buildings)):
            if os.path.abspath(path) == os.path.abspath(target):
                renderer = layer.renderer()
                info = {"name": layer.name(), "features": layer.featureCount(),
                        "renderer": renderer.type() if renderer else None}
                if renderer is not None and renderer.type() == "categorizedSymbol":
                    info["attribute"] = renderer.classAttribute()
                    info["categories"] = len(renderer.categories())
                    info["colors"] = {str(c.value()): c.symbol().color().name()
                                      for c in renderer.categories()}
                if renderer is not None and renderer.type() == "RuleRenderer":
                    info["rules"] = len(renderer.rootRule().children())
                loaded[key] = info
    result["layers"] = loaded
    return QgsProject.instance().mapLayers().values()


def _zoom_and_render(layers, then):
    """Zoom to the loaded layers in a metric CRS, wait until the canvas has drawn them, then
    call ``then``."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsRectangle
    from qgis.utils import iface

    canvas = iface.mapCanvas()
    fired = []

    def rendered():
        if not fired:
            fired.append(True)
            # a short pause lets the widgets (toolbox, layer tree) repaint too
            QTimer.singleShot(500, then)

    def zoom():
        # ETRS-TM35FIN (Finland's national grid), once QGIS has taken the first layer's CRS
        QgsProject.instance().setCrs(QgsCoordinateReferenceSystem("EPSG:3067"))
        extent = QgsRectangle()
        extent.setMinimal()
        for layer in layers:
            transform = QgsCoordinateTransform(layer.crs(), canvas.mapSettings().destinationCrs(),
                                               QgsProject.instance())
            extent.combineExtentWith(transform.transformBoundingBox(layer.extent()))
        if not extent.isEmpty():
            canvas.setExtent(extent)
            canvas.zoomByFactor(1.05)
        _state().result["map_crs"] = canvas.mapSettings().destinationCrs().authid()
        canvas.mapCanvasRefreshed.connect(rendered)
        canvas.refresh()
        QTimer.singleShot(15000, rendered)  # never wait forever

    QTimer.singleShot(300, zoom)  # the layer tree adds new layers (and sets the CRS) deferred


def _show_toolbox_provider():
    """Expand the Urban Synthesis branch of the Processing toolbox for the screenshot."""
    from processing.gui.ProcessingToolbox import ProcessingToolbox
    from qgis.PyQt.QtWidgets import QAbstractItemView
    from qgis.utils import iface

    toolbox = iface.mainWindow().findChild(ProcessingToolbox)
    if toolbox is None:
        return
    toolbox.setVisible(True)
    toolbox.raise_()
    tree = toolbox.algorithmTree
    model = tree.model()
    for row in range(model.rowCount()):
        index = model.index(row, 0)
        if str(model.data(index)) == "Urban Synthesis":
            tree.expand(index)
            for sub in range(model.rowCount(index)):
                tree.expand(model.index(sub, 0, index))
            tree.scrollTo(index, QAbstractItemView.PositionAtTop)


def _screenshot(result, path):
    from qgis.utils import iface

    image = iface.mainWindow().grab().toImage()
    result["screenshot"] = path if image.save(path) else None
    result["screenshot_size"] = [image.width(), image.height()]


def run_checks():
    from qgis.PyQt.QtWidgets import QApplication
    from qgis.utils import iface, plugins

    state = _state()
    result = state.result
    result.update(qgis_version=Qgis.QGIS_VERSION, plugin_loaded="urban_synthesis" in plugins)
    try:
        win = iface.mainWindow()
        win.resize(1500, 900)
        result["main_window_visible"] = win.isVisible()
        modal = QApplication.activeModalWidget()
        if modal is not None:  # e.g. a Python error dialog raised while plugins loaded
            result["errors"].append(f"modal dialog open at start: {modal.windowTitle()}")
            modal.close()
        provider = QgsApplication.processingRegistry().providerById(PROVIDER_ID)
        result["provider"] = provider is not None
        if provider is None:
            _finish(state, 1)
            return
        result["provider_name"] = provider.name()
        result["provider_icon"] = not provider.icon().isNull()
        algs = provider.algorithms()
        if not algs:  # loadAlgorithms() failed: the log has the traceback
            result["errors"].append("the urbansynth provider has no algorithms")
            _finish(state, 1)
            return
        result["algorithms"] = sorted(a.id() for a in algs)
        result["algorithm_problems"] = {a.id(): p for a in algs if (p := _algorithm_problems(a))}
        result["toolbox_algorithms"] = _toolbox_algorithm_ids()
        result["dialog_errors"] = _dialog_errors(result["algorithms"])
        layers = _run_and_load(result, os.environ["US_DESKTOP_WORK"],
                               os.environ["US_DESKTOP_HELSINKI"])
        _show_toolbox_provider()
    except Exception:  # noqa: BLE001 (written into the result, the test shows it)
        result["errors"].append(traceback.format_exc())
        _finish(state, 1)
        return

    def shoot():
        try:
            _screenshot(result, os.environ["US_DESKTOP_SCREENSHOT"])
        except Exception:  # noqa: BLE001
            result["errors"].append(traceback.format_exc())
        _finish(state, 0 if not result["errors"] else 1)

    _zoom_and_render(list(layers), shoot)


def _abort(reason):
    """Write what is known and leave, also from inside a modal dialog's event loop (a Python
    error dialog raised while plugins load blocks the startup before the --code run)."""
    from qgis.PyQt.QtWidgets import QApplication, QTextEdit

    state = _state()
    if state.done:  # finished, QGIS is shutting down
        return
    state.result["errors"].append(reason)
    modal = QApplication.activeModalWidget()
    if modal is not None:
        texts = [w.toPlainText()[:3000] for w in modal.findChildren(QTextEdit)]
        state.result["errors"].append(f"modal dialog '{modal.windowTitle()}': {' '.join(texts)}")
    _finish(state, 2)
    os._exit(2)  # the main event loop may not even have started: leave now


def _watch_for_modal_dialogs():
    """Nothing in a clean start opens a modal dialog: one open for 2 s is an error report."""
    from qgis.PyQt.QtWidgets import QApplication

    state = _state()
    if QApplication.activeModalWidget() is None:
        state.modal_seen = None
    elif state.modal_seen is None:
        state.modal_seen = time.time()
    elif time.time() - state.modal_seen > 2:
        _abort("a modal dialog blocked QGIS")


def main():
    from qgis import utils

    state = _state()  # from the startup run on, every log message is collected
    if utils.iface is None:  # startup run: arm the watchdogs
        state.modal_seen = None
        state.modal_timer = QTimer()
        state.modal_timer.timeout.connect(_watch_for_modal_dialogs)
        state.modal_timer.start(500)
        QTimer.singleShot(int(float(os.environ.get("US_DESKTOP_TIMEOUT", "90")) * 1000),
                          lambda: _abort("watchdog: the checks did not finish in time"))
        return
    # --code run: the event loop starts after this file returns
    QTimer.singleShot(200, run_checks)


main()
