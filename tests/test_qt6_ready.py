"""The code is ready for Qt 6 / QGIS 4: a static check over every Python file of the plugin.

QGIS 4 runs on PyQt6, where enum members are reached only through their enum
(``QgsProcessing.SourceType.TypeVectorLine``, ``Qt.AlignmentFlag.AlignLeft``), ``exec_`` and
``QRegExp`` are gone and PyQt5 cannot be imported. QGIS 3.22 accepts the scoped spelling too,
so the code uses it now. Field types stay ``QVariant`` types in one place only (qgis_io):
QGIS 3.22's QgsField has no QMetaType constructor yet (3.38 adds it).
"""
import ast
import re

import pytest

from conftest import ROOT

FILES = sorted(p for folder in ("plugin", "processing_algorithms", "scripts", "tests")
               for p in (ROOT / folder).rglob("*.py")
               if p.name != "test_qt6_ready.py") + [ROOT / "__init__.py"]
REMOVED = {r"\bPyQt5\b": "import through qgis.PyQt, not PyQt5",
           r"\.exec_\(": "exec_() is exec() in PyQt6",
           r"\bQRegExp\b": "QRegExp is gone in Qt 6 (QRegularExpression)",
           r"\bQDesktopWidget\b": "QDesktopWidget is gone in Qt 6 (QScreen)"}
QVARIANT_HOME = ROOT / "plugin" / "qgis_glue" / "qgis_io.py"


def _attribute_chains(tree):
    """(line, 'Name.Attr') of every attribute read on a bare name."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            yield node.lineno, node.value.id, node.attr


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_api_that_qt6_removed(path):
    text = path.read_text(encoding="utf-8")
    for pattern, why in REMOVED.items():
        for m in re.finditer(pattern, text):
            line = text.count("\n", 0, m.start()) + 1
            pytest.fail(f"{path.name}:{line}: {why}")
    if path != QVARIANT_HOME:
        assert "QVariant." not in text, f"{path.name}: field types belong in qgis_io"


def test_enums_are_scoped(qgis_app):
    """Every enum member is reached through its enum type (checked on the live classes)."""
    import qgis.core
    import qgis.PyQt.QtCore
    import qgis.PyQt.QtGui

    modules = (qgis.core, qgis.PyQt.QtCore, qgis.PyQt.QtGui)
    unscoped = []
    for path in FILES:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for line, owner, attr in _attribute_chains(tree):
            cls = next((getattr(m, owner) for m in modules if hasattr(m, owner)), None)
            if cls is None or not isinstance(cls, type) or not hasattr(cls, attr):
                continue
            value = getattr(cls, attr)
            enum_type = type(value)
            if isinstance(value, int) and enum_type is not int and \
                    getattr(cls, enum_type.__name__, None) is enum_type:
                unscoped.append(f"{path.relative_to(ROOT)}:{line}: {owner}.{attr} -> "
                                f"{owner}.{enum_type.__name__}.{attr}")
    assert not unscoped, "\n".join(unscoped)
