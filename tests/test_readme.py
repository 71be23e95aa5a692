"""The README's parameter reference is what the code registers, its fidelity figures are the
committed benchmark's, every tool's help opens its entry, and the toolbox speaks one way (no
doubled "optional", one spelling, search tags)."""
import re

from conftest import ROOT
from helpers import load_script


def _script():
    return load_script("make_toolbox_reference")


def test_readme_reference_is_the_registered_parameters(qgis_processing):
    script = _script()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    expected = script.render(readme, script.reference(script.algorithms()))
    assert readme == expected, ("README.md's parameter reference differs from the code: run "
                                "`.venv/bin/python scripts/make_toolbox_reference.py`")


def test_every_help_button_opens_its_entry(qgis_processing):
    from qgis.core import QgsApplication, QgsProcessingAlgorithm, QgsProcessingModelAlgorithm

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    anchors = set(re.findall(r'<a id="([^"]+)"></a>', readme))
    documented = _script().algorithms()
    # every tool the toolbox shows (the shipped model has its own README section)
    shown = {a.name() for a in
             QgsApplication.processingRegistry().providerById("urbansynth").algorithms()
             if not isinstance(a, QgsProcessingModelAlgorithm)
             and not a.flags() & QgsProcessingAlgorithm.Flag.FlagHideFromToolbox}
    assert {a.name() for a in documented} == shown
    for alg in documented:
        assert alg.helpUrl().split("#")[1] in anchors, alg.name()


def test_toolbox_manners(qgis_processing):
    from qgis.core import QgsApplication, QgsProcessingParameterDefinition

    for alg in QgsApplication.processingRegistry().providerById("urbansynth").algorithms():
        texts = [alg.displayName(), alg.shortHelpString() or ""]
        if alg.name() != "synthesizedistrict":
            assert len(alg.tags()) >= 3, alg.name()
        for p in alg.parameterDefinitions():
            # QGIS appends "[optional]" itself
            if p.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional:
                assert "optional" not in p.description().lower(), (alg.name(), p.name())
            texts += [p.description(), p.help() or ""]
        for text in texts:
            # one spelling: American -ize (as the algorithm ids)
            assert not re.search(r"\b[Ss]ynthesis(e|ed|es|ing)\b", text), (alg.name(), text)


def test_readme_fidelity_figures_are_the_benchmarks():
    """The README's fidelity tables and the figures in its prose (each marked block) are the
    committed benchmark's results, as ``bench_fidelity.py`` writes them: no hand-kept figure
    drifts from the run."""
    import importlib.util
    import json
    import sys

    path = ROOT / "tests" / "benchmarks" / "bench_fidelity.py"
    spec = importlib.util.spec_from_file_location("bench_fidelity", path)
    bench = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_fidelity", bench)  # its dataclasses look their module up
    spec.loader.exec_module(bench)
    results = json.loads((ROOT / "tests" / "benchmarks" / "results" / "fidelity.json")
                         .read_text(encoding="utf-8"))
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = bench.readme_blocks(results)
    assert all(f"<!-- fidelity:{name} -->" in readme for name in blocks)
    assert readme == bench.sync_readme(readme, blocks), (
        "README.md's fidelity blocks differ from tests/benchmarks/results/fidelity.json: run "
        "`.venv/bin/python tests/benchmarks/bench_fidelity.py --tables-only`")
