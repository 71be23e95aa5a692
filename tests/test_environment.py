"""Guards against the native-library clash (docs/ARCHITECTURE.md, "Native libraries": PyPI
wheels bundling PROJ/GDAL/GEOS crash QGIS at exit): the venv must use Debian's pyproj and shapely/pyogrio built on Debian's
GEOS/GDAL. The qgis_process tests of each algorithm assert exit code 0 on top of this."""
import subprocess
import sys

import pytest


def test_pyproj_is_debians():
    import pyproj

    assert pyproj.__file__.startswith("/usr/lib/python3/dist-packages/"), pyproj.__file__


def test_shapely_uses_system_geos():
    import shapely

    out = subprocess.run(["geos-config", "--version"], capture_output=True, text=True)
    if out.returncode != 0:
        pytest.skip("geos-config not available")
    system = tuple(int(x) for x in out.stdout.strip().split(".")[:2])
    assert shapely.geos_version[:2] == system


def test_pyogrio_uses_system_gdal():
    import pyogrio
    from osgeo import gdal

    assert pyogrio.__gdal_version_string__.split(".")[:2] == gdal.__version__.split(".")[:2]


def test_engine_modules_do_not_import_qgis():
    """The engine stays free of QGIS: importing it must not load qgis."""
    code = ("import sys; sys.path.insert(0, 'build/plugins');"
            "import urban_synthesis.plugin.network.street_graph, urban_synthesis.plugin.network.hierarchy;"
            "import pkgutil, importlib, urban_synthesis.plugin as p;"
            "glue = {'qgis_io', 'provider', 'plugin'};"
            "[importlib.import_module('urban_synthesis.plugin.' + m.name) for m in pkgutil.iter_modules(p.__path__) if m.name not in glue];"
            "bad = [m for m in sys.modules if m == 'qgis' or m.startswith('qgis.')];"
            "print(bad); sys.exit(1 if bad else 0)")
    from conftest import ROOT

    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
