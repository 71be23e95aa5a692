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


def _shell_blocks(text):
    """The README's command blocks: fenced ones and those indented by four spaces."""
    blocks = re.findall(r"^```(?:bash|sh)?\n(.*?)^```", text, flags=re.S | re.M)
    blocks += ["\n".join(line[4:] for line in m.group(0).splitlines())
               for m in re.finditer(r"(?:(?<=\n\n)|^)(?: {4}.*\S.*\n)+", text)]
    return blocks


def test_readme_qgis_process_blocks_run_as_written():
    """A block that calls qgis_process.bin itself (not scripts/qgis-process, which sets up
    everything) runs as pasted into a fresh shell: every variable it uses is set in it, a
    headless QGIS is told so, and a clean profile gets the plugin's packages before a tool
    runs (a trial pasted the install check: with XDG_DATA_HOME unset it unzipped into
    /QGIS/..., with it set unzip could not make the profile's folders, and the run would have
    stopped on the missing packages)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = [b for b in _shell_blocks(readme)
              if re.search(r"^\s*(export .*\n\s*)?qgis_process\.bin ", b, flags=re.M)]
    assert blocks, "the README's headless install check is gone"
    for block in blocks:
        set_here = set(re.findall(r"\b([A-Z_][A-Z0-9_]*)=", block))
        used = set(re.findall(r"\$\{?([A-Z_][A-Z0-9_]*)", block))
        assert used <= set_here | {"HOME", "PATH"}, (used - set_here, block)
        assert "QT_QPA_PLATFORM=offscreen" in block, block
        for folder in re.findall(r"unzip .* -d (\S+)", block):  # unzip makes one level only
            assert f"mkdir -p {folder}" in block, block
        runs = re.findall(r"qgis_process\.bin run (urbansynth:\w+)", block)
        if "unzip" in block and runs:  # a clean profile: QGIS's Python lacks the packages
            assert runs[0] == "urbansynth:installdependencies", block


def test_help_names_tools_as_the_toolbox_shows_them(qgis_processing):
    """A tool named in another tool's help ('e.g. the blocks of ...') is named as the toolbox
    lists it, so that a search finds it: not 'Extract blocks' for 'Extract city blocks'."""
    from qgis.core import QgsApplication

    registry = QgsApplication.processingRegistry()
    ours = registry.providerById("urbansynth").algorithms()
    shown = {a.displayName() for a in registry.algorithms()}
    verbs = {a.displayName().split()[0] for a in ours}
    for alg in ours:
        texts = [alg.shortHelpString() or ""] + [p.help() or "" for p in alg.parameterDefinitions()]
        for text in texts:
            for name in re.findall(r"'([A-Z][^']+)'", text):
                if name.split()[0] in verbs:
                    assert name in shown, (alg.name(), name)
