"""Processing's invalid features filtering is respected: 'Stop' stops with a message that
names the layer and the feature, 'Skip' leaves the invalid features out, 'Do not filter'
lets the plugin repair them; an input's own setting (the dialog's per-input option) wins
over Processing's."""
import pytest
import shapely

from helpers import log_feedback, memory_layer

ALG = "urbansynth:extractblocks"


def _roads_and_buildings():
    grid = [f"LINESTRING({x} -10, {x} 310)" for x in (0, 100, 200, 300)] + \
        [f"LINESTRING(-10 {y}, 310 {y})" for y in (0, 100, 200, 300)]
    roads = memory_layer("LineString", grid, "EPSG:32633", name="streets")
    bowtie = "POLYGON((20 20, 80 80, 80 20, 20 80, 20 20))"    # self-intersecting
    ok = [shapely.box(x + 20, y + 20, x + 60, y + 60).wkt for x in (0, 100, 200)
          for y in (0, 100, 200)]
    buildings = memory_layer("Polygon", ok + [bowtie], "EPSG:32633", name="houses",
                             fields="&field=building:string", rows=[["yes"]] * 10)
    return roads, buildings


def _run(processing, check, buildings_value=None):
    from qgis.core import QgsProcessingContext, QgsProject

    roads, buildings = _roads_and_buildings()
    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    context.setInvalidGeometryCheck(check)
    feedback = log_feedback()
    res = processing.run(ALG, {"ROADS": roads, "BUILDINGS": buildings_value or buildings,
                               "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"},
                         context=context, feedback=feedback)
    layer = context.getMapLayer(res["OUTPUT_BUILDINGS"]) \
        if isinstance(res["OUTPUT_BUILDINGS"], str) else res["OUTPUT_BUILDINGS"]
    return layer, " ".join(feedback.messages)


def test_stop_names_the_layer_and_the_feature(qgis_processing):
    from qgis.core import QgsFeatureRequest, QgsProcessingException

    with pytest.raises(QgsProcessingException, match=r"houses.*feature \d+ has an invalid "
                                                     r"geometry \(Self-intersection"):
        _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryAbortOnInvalid)


def test_skip_leaves_the_invalid_feature_out(qgis_processing):
    from qgis.core import QgsFeatureRequest

    layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometrySkipInvalid)
    assert layer.featureCount() == 9
    assert "1 features with an invalid geometry skipped" in log


def test_do_not_filter_repairs(qgis_processing):
    from qgis.core import QgsFeatureRequest

    layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryNoCheck)
    assert layer.featureCount() == 10
    assert "1 invalid geometries repaired" in log
    assert all(f.geometry().isGeosValid() for f in layer.getFeatures())


def test_the_inputs_own_setting_wins(qgis_processing):
    from qgis.core import QgsFeatureRequest, QgsProcessingFeatureSourceDefinition

    _, buildings = _roads_and_buildings()
    definition = QgsProcessingFeatureSourceDefinition(
        buildings.id(), False, -1,
        QgsProcessingFeatureSourceDefinition.Flag.FlagOverrideDefaultGeometryCheck,
        QgsFeatureRequest.InvalidGeometryCheck.GeometrySkipInvalid)
    from qgis.core import QgsProject

    QgsProject.instance().addMapLayer(buildings)
    try:
        layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryAbortOnInvalid,
                          definition)
    finally:
        QgsProject.instance().removeMapLayer(buildings.id())
    assert layer.featureCount() == 9
