"""The engine's docstring examples run as tests (numpy-style Examples sections).

Every module of plugin/ outside qgis_glue is imported without QGIS and its doctests run;
qgis_glue (the only QGIS code) is left to the algorithm tests. A module whose import
fails is a failure here, so an engine module that starts importing QGIS shows up too.
"""
import doctest
import importlib
import pkgutil

import numpy as np
import pytest

import urban_synthesis.plugin as engine

MODULES = sorted(
    m.name for m in pkgutil.walk_packages(engine.__path__, prefix=engine.__name__ + ".")
    if ".qgis_glue" not in m.name and not m.ispkg)


def test_the_engine_is_walked():
    stages = {name.split(".")[2] for name in MODULES}
    assert {"core", "network", "retrieval", "roads", "parcels", "planned", "buildings",
            "measure", "scale"} <= stages


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(name)
    options = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    with np.printoptions(legacy="1.25") if np.__version__ >= "2" else np.errstate():
        result = doctest.testmod(module, optionflags=options, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples fail in {name}"
