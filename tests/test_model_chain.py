"""The algorithms chain in a Processing model (what the model designer builds): roads ->
hierarchy -> blocks -> block database, saved as .model3, reloaded and run."""
import pyogrio

from conftest import helsinki_layer


def build_model():
    from qgis.core import (
        QgsProcessing, QgsProcessingModelAlgorithm, QgsProcessingModelChildAlgorithm,
        QgsProcessingModelChildParameterSource as Source, QgsProcessingModelOutput,
        QgsProcessingModelParameter, QgsProcessingParameterFeatureSource,
    )

    model = QgsProcessingModelAlgorithm("Example databases from OSM", "urbansynth tests")
    model.addModelParameter(QgsProcessingParameterFeatureSource(
        "roads", "Roads", [QgsProcessing.SourceType.TypeVectorLine]), QgsProcessingModelParameter("roads"))
    model.addModelParameter(QgsProcessingParameterFeatureSource(
        "buildings", "Buildings", [QgsProcessing.SourceType.TypeVectorPolygon]),
        QgsProcessingModelParameter("buildings"))

    def child(alg_id, child_id, sources, outputs):
        from qgis.core import QgsApplication

        c = QgsProcessingModelChildAlgorithm(alg_id)
        c.setChildId(child_id)
        # the model designer's dialog fills every other parameter with its default
        alg = QgsApplication.processingRegistry().algorithmById(alg_id)
        for definition in alg.parameterDefinitions():
            if definition.isDestination() or definition.name() in sources:
                continue
            if definition.defaultValue() is not None:
                c.addParameterSources(definition.name(), [Source.fromStaticValue(definition.defaultValue())])
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
