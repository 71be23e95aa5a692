"""Write the README's toolbox reference from the registered algorithms (run with the venv's
python): every algorithm's id, name, group, help and a table of its parameters and outputs,
between the README's toolbox-reference markers (anchors ``#alg-<name>``: each algorithm's
help button opens its section). tests/test_readme.py checks that the README
holds exactly what this script writes, so the reference cannot drift from the code.
"""
import os
import re
import sys
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
BEGIN, END = "<!-- toolbox-reference:begin -->", "<!-- toolbox-reference:end -->"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def _default(p) -> str:
    from qgis.core import QgsProcessingParameterEnum

    value = p.defaultValue()
    if p.isDestination() or value is None or value == "":
        return ""
    if isinstance(p, QgsProcessingParameterEnum):
        options = p.options()
        keys = value if isinstance(value, list) else [value]
        try:
            return ", ".join(f"{int(k)} ({options[int(k)]})" for k in keys)
        except (ValueError, IndexError, TypeError):
            return _cell(value)
    if isinstance(value, float) and value == int(value):
        value = int(value)
    return f"`{_cell(value)}`"


def _kind(p) -> str:
    from qgis.core import QgsProcessingParameterEnum, QgsProcessingParameterNumber

    kind = p.type()
    if isinstance(p, QgsProcessingParameterNumber):
        lo, hi = p.minimum(), p.maximum()
        rng = [] if lo <= -1e300 else [f"≥ {lo:g}"]
        rng += [] if hi >= 1e300 else [f"≤ {hi:g}"]
        integer = p.dataType() == QgsProcessingParameterNumber.Type.Integer
        return ("integer" if integer else "number") + (f" ({', '.join(rng)})" if rng else "")
    if isinstance(p, QgsProcessingParameterEnum):
        return "enum: " + "; ".join(f"{i} {o}" for i, o in enumerate(p.options()))
    return kind


def reference(algorithms) -> str:
    from qgis.core import QgsProcessingParameterDefinition

    out = []
    for alg in algorithms:
        out.append(f'<a id="alg-{alg.name()}"></a>\n')
        out.append(f"#### {alg.name()} — {alg.displayName()}\n")
        tags = ", ".join(alg.tags())
        out.append(f"`{alg.id()}` · group *{alg.group()}*" + (f" · search: {tags}" if tags else "")
                   + "\n")
        out.append(_cell(alg.shortHelpString().split("\n\n")[0]) + "\n")
        out.append("| parameter | kind | default | meaning |")
        out.append("|---|---|---|---|")
        for p in alg.parameterDefinitions():
            optional = bool(p.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional)
            advanced = bool(p.flags() & QgsProcessingParameterDefinition.Flag.FlagAdvanced)
            tags = ", ".join(t for t, on in (("optional", optional), ("advanced", advanced)) if on)
            name = f"`{p.name()}`" + (f" ({tags})" if tags else "")
            out.append(f"| {name} | {_cell(_kind(p))} | {_default(p)} | "
                       f"{_cell(p.description())}: {_cell(p.help())} |")
        out.append("")
    return "\n".join(out)


def algorithms():
    from qgis.core import QgsApplication, QgsProcessingAlgorithm

    provider = QgsApplication.processingRegistry().providerById("urbansynth")
    from urban_synthesis.plugin.qgis_glue.toolbox import ALGORITHMS, algorithm_id

    order = [algorithm_id(module) for module, *_ in ALGORITHMS]
    shown = [a for a in provider.algorithms() if a.name() in order
             and not (a.flags() & QgsProcessingAlgorithm.Flag.FlagHideFromToolbox)]
    return sorted(shown, key=lambda a: order.index(a.name()))


def render(readme_text: str, generated: str) -> str:
    pattern = re.compile(re.escape(BEGIN) + ".*?" + re.escape(END), re.S)
    if not pattern.search(readme_text):
        raise SystemExit(f"README.md has no {BEGIN} ... {END} section")
    return pattern.sub(lambda _: f"{BEGIN}\n\n{generated}\n{END}", readme_text)


def main():
    from qgis.core import QgsApplication

    app = QgsApplication([], False)
    app.initQgis()
    sys.path.insert(0, str(ROOT / "build" / "plugins"))
    sys.path.insert(0, "/usr/share/qgis/python/plugins")
    from processing.core.Processing import Processing

    Processing.initialize()
    from urban_synthesis.plugin.qgis_glue.provider import UrbanSynthesisProvider

    provider = UrbanSynthesisProvider()  # kept referenced: QGIS does not own it
    QgsApplication.processingRegistry().addProvider(provider)
    README.write_text(render(README.read_text(encoding="utf-8"), reference(algorithms())),
                      encoding="utf-8")
    print(f"toolbox reference written to {README}")


if __name__ == "__main__":
    main()
