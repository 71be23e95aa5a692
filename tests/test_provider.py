"""The provider and the metadata of every algorithm (what the toolbox and qgis_process show)."""
import configparser

from conftest import ROOT


def test_every_algorithm_is_documented(qgis_processing):
    from qgis.core import QgsApplication

    from urban_synthesis.plugin.qgis_glue.toolbox import GROUPS

    provider = QgsApplication.processingRegistry().providerById("urbansynth")
    algs = provider.algorithms()
    assert {a.name() for a in algs} >= {
        "extractroadhierarchy", "extractblocks", "buildfragmentdatabase", "buildblockdatabase",
        "layoutmetrics", "growroads", "subdivideparcels", "synthesizeroadsfromfragments"}
    for alg in algs:
        assert alg.id() == f"urbansynth:{alg.name()}"
        assert alg.group() in GROUPS.values()
        assert len(alg.shortHelpString()) > 100, alg.name()
        assert not alg.icon().isNull(), alg.name()
        for p in alg.parameterDefinitions():
            # a model's outputs are named '<step id>:<OUTPUT NAME>'
            name = p.name().split(":")[-1]
            assert name == name.upper(), (alg.name(), p.name())
            assert p.help() and len(p.help()) > 15, (alg.name(), p.name())


def test_toolbox_table_matches_the_algorithms(qgis_processing):
    """The table that lists algorithms even when their packages are missing says what the
    classes say: same ids, display names and groups, in the provider."""
    from qgis.core import QgsApplication, QgsProcessingAlgorithm

    from urban_synthesis.plugin.qgis_glue.provider import UnavailableAlgorithm
    from urban_synthesis.plugin.qgis_glue.toolbox import ALGORITHMS, GROUPS, algorithm_id

    provider = QgsApplication.processingRegistry().providerById("urbansynth")
    for module, _, display_name, group_id in ALGORITHMS:
        alg = provider.algorithm(algorithm_id(module))
        assert alg is not None, module
        assert (alg.displayName(), alg.groupId(), alg.group()) == \
            (display_name, group_id, GROUPS[group_id])
        # a deprecated one stays out of the toolbox while its packages are missing too
        stand_in = UnavailableAlgorithm(module, display_name, group_id, ["shapely"])
        hidden = QgsProcessingAlgorithm.Flag.FlagHideFromToolbox
        assert bool(stand_in.flags() & hidden) == bool(alg.flags() & hidden), module


def test_missing_package_keeps_the_algorithm_listed_with_a_clear_message(qgis_processing):
    from qgis.core import QgsProcessingContext

    from urban_synthesis.plugin.qgis_glue.provider import UnavailableAlgorithm

    alg = UnavailableAlgorithm("extract_blocks", "Extract city blocks", "analysis", ["shapely"])
    assert alg.name() == "extractblocks" and "needs shapely" in alg.displayName()
    ok, message = alg.createInstance().checkParameterValues({}, QgsProcessingContext())
    assert not ok
    assert "shapely" in message and "Install Python dependencies" in message


def test_metadata_is_complete():
    meta = configparser.ConfigParser()
    meta.read(ROOT / "metadata.txt")
    general = meta["general"]
    for key in ("name", "qgisMinimumVersion", "description", "about", "version", "author",
                "email", "repository", "tracker", "tags", "icon", "hasProcessingProvider"):
        assert general.get(key), key
    assert general["hasProcessingProvider"] == "yes"
    assert (ROOT / general["icon"]).exists()


def test_shipped_model_says_which_packages_are_missing(qgis_processing, monkeypatch):
    """With the engine's packages missing the model's steps are stand-ins: the model says what
    to install (listed as '(needs …)', refused by its parameter check, and a run from another
    model stops with the same sentence), never an import traceback."""
    from qgis.core import QgsApplication, QgsProcessingContext, QgsProcessingException

    from urban_synthesis.plugin.qgis_glue import dependencies, provider

    model = QgsApplication.processingRegistry().algorithmById("urbansynth:synthesizedistrict")
    assert model is not None and "needs" not in model.displayName()
    monkeypatch.setattr(dependencies, "missing_packages", lambda: ["pandas"])
    context = QgsProcessingContext()
    ok, message = model.createInstance().checkParameterValues({}, context)
    assert not ok
    assert "pandas" in message and "Install Python dependencies" in message
    try:
        model.createInstance().processAlgorithm({}, context, None)
    except QgsProcessingException as error:
        assert type(error) is QgsProcessingException  # QGIS prints any other with a traceback
        assert "pandas" in str(error) and "Install Python dependencies" in str(error)
    else:
        raise AssertionError("the model ran without its packages")
    shown = provider.ShippedModel()
    assert shown.fromFile(str(provider.MODELS / "synthesize_district.model3"))
    shown.missing = ("pandas",)
    assert shown.displayName().endswith("(needs pandas)")
    assert shown.createInstance().displayName() == shown.displayName()


def test_changelog_names_every_tool():
    """The plugin manager shows the changelog: every tool of the toolbox table is named in it,
    by its id or as the toolbox lists it (the parenthesis aside), so that a tool added, split
    or renamed since a release is in it."""
    import re

    from urban_synthesis.plugin.qgis_glue.toolbox import ALGORITHMS, algorithm_id

    meta = configparser.ConfigParser()
    meta.read(ROOT / "metadata.txt")
    changelog = meta["general"]["changelog"].lower()
    for module, _, display_name, _ in ALGORITHMS:
        name = re.sub(r"\s*\(.*\)$", "", display_name).lower()
        assert algorithm_id(module) in changelog or name in changelog, display_name


def test_every_algorithm_file_stays_thin():
    """docs/ARCHITECTURE.md: an algorithm file stays under 350 lines (parameters, the
    adapter, one engine call, the log); more is engine work in the wrong place (growroads
    had grown to 353, two raster readers written twice)."""
    long = {p.name: n for p in sorted((ROOT / "processing_algorithms").glob("*.py"))
            if p.name != "common.py"
            and (n := len(p.read_text(encoding="utf-8").splitlines())) >= 350}
    assert not long, long


def test_a_parameter_no_tool_has_is_named_in_a_warning(qgis_processing):
    """QGIS ignores a parameter the tool does not have, so a typo on the command line ran
    the tool with the default (SNAP_TOLERENCE) and another tool's parameter (a road
    method's EXAMPLE_ROADS given to synthesizeroadsgan) did nothing, both without a word.
    Each is named in a warning, with the nearest names; a run with the tool's own
    parameters warns of none."""
    from conftest import helsinki_layer
    from helpers import log_feedback

    params = {"INPUT": helsinki_layer(), "OUTPUT": "memory:"}
    quiet, typo = log_feedback(), log_feedback()
    qgis_processing.run("urbansynth:extractroadhierarchy", params, feedback=quiet)
    qgis_processing.run("urbansynth:extractroadhierarchy",
                        dict(params, SNAP_TOLERENCE=3, EXAMPLE_ROADS="x"), feedback=typo)
    assert not [w for w in quiet.warnings if "not a parameter" in w]
    named = [w for w in typo.warnings if "not a parameter" in w]
    assert len(named) == 2
    assert any("SNAP_TOLERENCE" in w and "Did you mean SNAP_TOLERANCE?" in w for w in named)
    assert any(w.startswith("EXAMPLE_ROADS is not a parameter of extractroadhierarchy")
               for w in named)


def test_the_shipped_model_names_a_parameter_it_does_not_have(qgis_processing):
    """The model warns the same way (its outputs are named 'child:NAME', which are its own)."""
    from qgis.core import QgsApplication

    from urban_synthesis.plugin.qgis_glue import qgis_io

    model = QgsApplication.processingRegistry().algorithmById("urbansynth:synthesizedistrict")
    own = {"ARTERIALS": "a", "SEED": 1, "roads:ROADS": "memory:", "metrics:REPORT": "r.html"}
    assert qgis_io.unknown_parameters(model, own) == []
    said = qgis_io.unknown_parameters(model, dict(own, PARCELS_METHOD=2))
    assert said == ["PARCELS_METHOD is not a parameter of synthesizedistrict: ignored. Did you "
                    "mean PARCEL_METHOD or ROAD_METHOD?"]
