"""QGIS desktop (3.22) started headless under Xvfb with the plugin enabled in a fresh profile.

scripts/run_desktop_check.py starts ``qgis`` with scripts/desktop_check.py as the startup
script; inside QGIS it checks the provider, the toolbox, every algorithm dialog, loads styled
Helsinki outputs, collects the message log and saves a screenshot (out/desktop.png).
"""
import shutil

import numpy as np
import pytest

from conftest import ROOT
from helpers import load_script

PNG = ROOT / "out"


def _launcher():
    return load_script("run_desktop_check")


@pytest.fixture(scope="module")
def desktop(tmp_path_factory):
    for tool in ("xvfb-run", "/usr/bin/qgis"):
        if shutil.which(tool) is None:
            pytest.fail(f"{tool} is missing: run `make setup` (installs qgis and xvfb)")
    launcher = _launcher()
    result, code, output = launcher.run(ROOT / "out", timeout=120,
                                        work=tmp_path_factory.mktemp("desktop"))
    assert result is not None, f"QGIS desktop wrote no result (exit {code}):\n{output[-4000:]}"
    return launcher, result, code, output


def test_desktop_starts_and_exits_cleanly(desktop):
    launcher, result, code, output = desktop
    assert code == 0, f"QGIS desktop exit code {code}:\n{output[-4000:]}"
    assert result["errors"] == [], result["errors"]
    assert result["qgis_version"].startswith("3.22")
    assert result["plugin_loaded"] and result["main_window_visible"]
    assert result["elapsed_s"] < 90


def test_provider_and_every_algorithm_registered(desktop, qgis_processing):
    from qgis.core import QgsApplication

    _, result, _, _ = desktop
    assert result["provider"] and result["provider_name"] == "Urban Synthesis"
    assert result["provider_icon"]
    # the same algorithms as the provider lists (loaded in this process from the checkout)
    from qgis.core import QgsProcessingAlgorithm

    algorithms = QgsApplication.processingRegistry().providerById("urbansynth").algorithms()
    expected = sorted(a.id() for a in algorithms)
    assert result["algorithms"] == expected
    # deprecated tools stay runnable by id but out of the toolbox
    shown = sorted(a.id() for a in algorithms
                   if not a.flags() & QgsProcessingAlgorithm.Flag.FlagHideFromToolbox)
    assert result["toolbox_algorithms"] == shown and len(shown) >= len(expected) - 1
    assert result["algorithm_problems"] == {}  # icon, help and help on every parameter
    assert result["dialog_errors"] == {}


def test_outputs_load_with_their_styles(desktop):
    _, result, _, _ = desktop
    layers = result["layers"]
    roads, buildings, blocks = layers["roads"], layers["buildings"], layers["blocks"]
    assert roads["renderer"] == "categorizedSymbol" and roads["attribute"] == "level"
    assert roads["categories"] >= 4 and roads["features"] > 150
    assert buildings["renderer"] == "RuleRenderer" and buildings["rules"] >= 3
    assert buildings["features"] > 400  # Helsinki has ~480 valid building polygons
    assert blocks["features"] > 20


def test_message_log_has_no_python_errors(desktop):
    launcher, result, _, output = desktop
    log = result["log"]
    loaded = [e["message"] for e in log if e["tag"] == "Plugins"]
    assert any("urban_synthesis" in m for m in loaded), loaded
    assert launcher.python_errors(result) == []
    assert [e for e in log if e["tag"] == "Python error"] == []
    assert not [line for line in output.splitlines()
                if "Traceback" in line or "urban_synthesis" in line and "Error" in line]


def test_screenshot_shows_the_styled_map(desktop):
    from PIL import Image

    _, result, _, _ = desktop
    path = ROOT / "out" / "desktop.png"
    assert result["screenshot"] == str(path) and path.exists()
    image = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert image.shape[:2] == (result["screenshot_size"][1], result["screenshot_size"][0])
    assert image.shape[0] >= 600 and image.shape[1] >= 1000
    assert image.std() > 20  # not blank
    packed = (image[..., 0] << 16) | (image[..., 1] << 8) | image[..., 2]
    assert len(np.unique(packed)) > 200  # a rendered map and widgets, not a flat fill
    # arterial roads drawn in the colour of level 0 of roads_by_level.qml
    color = result["layers"]["roads"]["colors"]["0"]
    rgb = np.array([int(color[i:i + 2], 16) for i in (1, 3, 5)])
    near = np.abs(image - rgb).sum(axis=2) < 30
    assert near.sum() > 2000, (color, int(near.sum()))


def test_a_broken_plugin_is_reported_not_hung(tmp_path):
    """The check fails loudly when the plugin breaks at load (Python error dialog at startup)."""
    plugins = tmp_path / "plugins"
    broken = plugins / "urban_synthesis"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("plugin", "processing_algorithms", "resources"):
        shutil.copytree(ROOT / folder, broken / folder, ignore=ignore)
    for name in ("__init__.py", "metadata.txt"):
        shutil.copy(ROOT / name, broken / name)
    with open(broken / "processing_algorithms" / "common.py", "a") as f:
        f.write("\nraise RuntimeError('deliberately broken for the desktop test')\n")
    launcher = _launcher()
    result, code, output = launcher.run(tmp_path / "out", plugins_dir=plugins, timeout=60,
                                        work=tmp_path / "work")
    assert code != 0
    assert result is not None, output[-2000:]
    problems = " ".join(launcher.summary(result))
    assert "deliberately broken for the desktop test" in problems
    assert launcher.python_errors(result)
