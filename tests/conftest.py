"""Test fixtures: example data paths, a headless QGIS with the provider, qgis_process runs.

Engine tests need none of QGIS; tests that use the ``qgis_processing`` fixture run the
algorithms through ``processing.run`` in this process; ``run_qgis_process`` runs the real
``qgis_process.bin`` in a subprocess and returns its JSON results.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PLUGINS = ROOT / "build" / "plugins"
DATA = ROOT / "data" / "examples"
HELSINKI = DATA / "Helsinki.osm.pbf"
BUBENEC = DATA / "bubenec.gpkg"
#: The whole of Liechtenstein from OSM (tests/data, ODbL: see its ATTRIBUTION.txt), for
#: leave-one-town-out evaluation; URBANSYNTH_LIECHTENSTEIN overrides where it is.
LIECHTENSTEIN = Path(os.environ.get(
    "URBANSYNTH_LIECHTENSTEIN", ROOT / "tests" / "data" / "liechtenstein-2013-08-03.osm.pbf"))

# the plugin is imported as the package QGIS gives it: its folder name under build/plugins
if str(PLUGINS) not in sys.path:
    sys.path.insert(0, str(PLUGINS))
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def helsinki_layer(name="lines"):
    return f"{HELSINKI}|layername={name}"


def bubenec_layer(name):
    return f"{BUBENEC}|layername={name}"


@pytest.fixture(scope="session")
def qgis_app():
    from qgis.core import QgsApplication

    app = QgsApplication([], False)
    app.initQgis()
    yield app


@pytest.fixture(scope="session")
def qgis_processing(qgis_app):
    """Processing initialised with the urbansynth provider registered."""
    sys.path.insert(0, "/usr/share/qgis/python/plugins")
    from processing.core.Processing import Processing
    from qgis.core import QgsApplication

    Processing.initialize()
    from processing.core.ProcessingConfig import ProcessingConfig

    # OSM layers hold invalid polygons; QGIS's default setting stops on them. The suite runs
    # as a user who chose "Do not filter" (the plugin repairs them); tests of the other two
    # choices set them on their inputs (tests/test_invalid_geometries.py).
    ProcessingConfig.setSettingValue(ProcessingConfig.FILTER_INVALID_GEOMETRIES, 0)
    from urban_synthesis.plugin.qgis_glue.provider import UrbanSynthesisProvider

    provider = UrbanSynthesisProvider()
    QgsApplication.processingRegistry().addProvider(provider)
    import processing

    yield processing
    QgsApplication.processingRegistry().removeProvider(provider)


def run_qgis_process(alg_id, params, timeout=300):
    """Run ``qgis_process.bin --json run urbansynth:<alg_id> -- K=V ...``.

    Returns (exit code, parsed JSON or None, stderr). The exit code must be 0: the
    native-library crash (docs/ARCHITECTURE.md, "Native libraries") shows up as 134/139
    after the results were printed.
    """
    args = [str(ROOT / "scripts" / "qgis-process"), "--json", "run", f"urbansynth:{alg_id}", "--"]
    for key, value in params.items():
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            args.append(f"{key}={v}")
    proc = subprocess.run(args, capture_output=True, text=True, timeout=timeout)
    out = None
    start = proc.stdout.find("{")
    if start >= 0:
        try:
            out = json.loads(proc.stdout[start:])
        except json.JSONDecodeError:
            out = None
    return proc.returncode, out, proc.stderr + proc.stdout[:start if start >= 0 else None]
