"""The algorithms chain in a Processing model (what the model designer builds): roads ->
hierarchy -> blocks -> block database, saved as .model3, reloaded and run."""
import pyogrio
import pytest

from conftest import bubenec_layer, helsinki_layer


def add_child(model, alg_id, child_id, sources, outputs):
    """A step of ``model`` as the model designer adds it: every parameter not given in
    ``sources`` keeps its default; ``outputs`` names model outputs by the step's output."""
    from qgis.core import (QgsApplication, QgsProcessingModelChildAlgorithm,
                           QgsProcessingModelChildParameterSource as Source,
                           QgsProcessingModelOutput)

    c = QgsProcessingModelChildAlgorithm(alg_id)
    c.setChildId(child_id)
    alg = QgsApplication.processingRegistry().algorithmById(alg_id)
    for definition in alg.parameterDefinitions():
        if definition.isDestination() or definition.name() in sources:
            continue
        if definition.defaultValue() is not None:
            c.addParameterSources(definition.name(),
                                  [Source.fromStaticValue(definition.defaultValue())])
    for name, src in sources.items():
        c.addParameterSources(name, [src])
    model_outputs = {}
    for out_name, child_output in outputs.items():
        o = QgsProcessingModelOutput(out_name)
        o.setChildId(child_id)
        o.setChildOutputName(child_output)
        model_outputs[out_name] = o
    c.setModelOutputs(model_outputs)
    model.addChildAlgorithm(c)


def build_model():
    from qgis.core import (
        QgsProcessing, QgsProcessingModelAlgorithm, QgsProcessingModelChildParameterSource as Source, QgsProcessingModelParameter, QgsProcessingParameterFeatureSource,
    )

    model = QgsProcessingModelAlgorithm("Example databases from OSM", "urbansynth tests")
    model.addModelParameter(QgsProcessingParameterFeatureSource(
        "roads", "Roads", [QgsProcessing.SourceType.TypeVectorLine]), QgsProcessingModelParameter("roads"))
    model.addModelParameter(QgsProcessingParameterFeatureSource(
        "buildings", "Buildings", [QgsProcessing.SourceType.TypeVectorPolygon]),
        QgsProcessingModelParameter("buildings"))

    def child(alg_id, child_id, sources, outputs):
        add_child(model, alg_id, child_id, sources, outputs)

    child("urbansynth:extractroadhierarchy", "hierarchy",
          {"INPUT": Source.fromModelParameter("roads")}, {"hierarchy_roads": "OUTPUT"})
    child("urbansynth:extractblocks", "blocks",
          {"ROADS": Source.fromChildOutput("hierarchy", "OUTPUT"),
           "BUILDINGS": Source.fromModelParameter("buildings")},
          {"blocks": "OUTPUT", "assigned_buildings": "OUTPUT_BUILDINGS"})
    child("urbansynth:buildblockdatabase", "database",
          {"BLOCKS": Source.fromChildOutput("blocks", "OUTPUT"),
           "BUILDINGS": Source.fromChildOutput("blocks", "OUTPUT_BUILDINGS")},
          {"block_database": "OUTPUT"})
    return model


def test_model_chain_runs_and_round_trips(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingModelAlgorithm

    model = build_model()
    path = tmp_path / "chain.model3"
    assert model.toFile(str(path))
    loaded = QgsProcessingModelAlgorithm()
    assert loaded.fromFile(str(path))
    assert loaded.validate()[0], loaded.validate()[1]
    outputs = {d.name(): d for d in loaded.destinationParameterDefinitions()}
    db = tmp_path / "blocks.gpkg"
    params = {"roads": helsinki_layer("lines"), "buildings": helsinki_layer("multipolygons")}
    for name in outputs:
        params[name] = str(db) if name.endswith("block_database") else str(tmp_path / f"{name.replace(':', '_')}.gpkg")
    result = qgis_processing.run(loaded, params)
    assert db.exists()
    layers = {row[0] for row in pyogrio.list_layers(db)}
    assert {"blocks", "buildings", "metadata"} <= layers
    assert pyogrio.read_info(db, layer="blocks")["features"] > 30
    assert any(k.endswith("blocks") for k in result)


def test_an_optional_input_a_step_left_empty_is_not_given(qgis_processing, tmp_path):
    """A model step that made nothing (here QGIS's filter on a level no road has) feeds an
    optional input: the next step runs without it and says so, where every tool stopped
    the whole model with 'Layer ... is empty'."""
    from qgis.core import (
        QgsProcessing, QgsProcessingModelAlgorithm,
        QgsProcessingModelChildParameterSource as Source,
        QgsProcessingModelParameter,
        QgsProcessingParameterFeatureSource,
    )

    from helpers import log_feedback

    model = QgsProcessingModelAlgorithm("Metrics against no given roads", "urbansynth tests")
    model.addModelParameter(QgsProcessingParameterFeatureSource(
        "roads", "Roads", [QgsProcessing.SourceType.TypeVectorLine]),
        QgsProcessingModelParameter("roads"))
    steps = (
        ("native:extractbyattribute", "none", {
            "INPUT": Source.fromModelParameter("roads"), "FIELD": Source.fromStaticValue("fid"),
            "OPERATOR": Source.fromStaticValue(0), "VALUE": Source.fromStaticValue("-1")}, {}),
        ("urbansynth:layoutmetrics", "metrics", {
            "ROADS": Source.fromModelParameter("roads"),
            "GIVEN_ROADS": Source.fromChildOutput("none", "OUTPUT"),
            "BUILDINGS": Source.fromChildOutput("none_buildings", "OUTPUT")},
         {"metrics": "OUTPUT"}),
        ("native:polygonfromlayerextent", "extent", {
            "INPUT": Source.fromModelParameter("roads")}, {}),
        ("native:extractbyattribute", "none_buildings", {
            "INPUT": Source.fromChildOutput("extent", "OUTPUT"),
            "FIELD": Source.fromStaticValue("WIDTH"), "OPERATOR": Source.fromStaticValue(2),
            "VALUE": Source.fromStaticValue("1e12")}, {}),
    )
    for alg_id, child_id, sources, outputs in steps:
        add_child(model, alg_id, child_id, sources, outputs)
    assert model.validate()[0], model.validate()[1]
    log = log_feedback()
    out = tmp_path / "metrics.gpkg"
    qgis_processing.run(model, {"roads": bubenec_layer("streets"),
                                "metrics:metrics": str(out)}, feedback=log)
    assert pyogrio.read_info(out)["features"] > 5
    for name in ("GIVEN_ROADS", "BUILDINGS"):
        assert any("is empty" in w and f"({name}), as if it were not given" in w
                   for w in log.warnings), (name, log.warnings)


@pytest.mark.parametrize("alg_id, name, params", [
    ("synthesizeroads", "BOUNDARY", {"METHOD": 1}),
    ("synthesizebuildingattributes", "BLOCKS", {}),
    ("layoutmetrics", "BLOCKS", {}),
])
def test_each_tool_runs_without_an_empty_optional_layer(qgis_processing, tmp_path, alg_id,
                                                        name, params):
    from helpers import log_feedback, memory_layer

    base = {
        "synthesizeroads": {"ARTERIALS": bubenec_layer("streets"), "SEED": 2},
        "synthesizebuildingattributes": {"FOOTPRINTS": bubenec_layer("buildings"),
                                         "EXAMPLE_BUILDINGS": bubenec_layer("buildings")},
        "layoutmetrics": {"ROADS": bubenec_layer("streets")},
    }[alg_id]
    params = dict(base, **params)
    log = log_feedback()
    empty = memory_layer("Polygon", [], "EPSG:3857", name="nothing made")
    result = qgis_processing.run(f"urbansynth:{alg_id}", dict(
        params, **{name: empty, "OUTPUT": str(tmp_path / "out.gpkg")}), feedback=log)
    assert pyogrio.read_info(result["OUTPUT"])["features"] > 0
    assert any("'nothing made' is empty: the run goes on without" in w and name in w
               for w in log.warnings), log.warnings
    if alg_id == "synthesizeroads":   # the arterials' hull is filled, and said so
        assert not any("boundary 'nothing made'" in m for m in log.messages + log.warnings)
