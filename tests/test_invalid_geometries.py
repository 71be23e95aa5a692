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
    assert "1 feature with an invalid geometry skipped" in log


def test_do_not_filter_repairs(qgis_processing):
    from qgis.core import QgsFeatureRequest

    layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryNoCheck)
    assert layer.featureCount() == 10
    assert "1 invalid geometry repaired" in log
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


#: A junction polygon of a district synthesised in EPSG:4326 (Mauren), as the engine made it
#: in UTM 32N: valid there, with four vertices a fraction of a micrometre apart, which cross
#: its ring once the coordinates are written back in degrees.
JUNCTION_UTM = (
    "MULTIPOLYGON (((540686.8295413055 5228872.494258502, 540691.6917797572 5228866.141413688, "
    "540702.8533740195 5228874.592378947, 540700.4167971073 5228877.810482652, "
    "540700.4167978977 5228877.810481609, 540700.4167986879 5228877.810480565, "
    "540700.4167994782 5228877.810479522, 540698.0241934168 5228880.9705131175, "
    "540686.8625932172 5228872.519555718, 540686.8295413055 5228872.494258502)))")


def test_polygons_written_back_in_degrees_stay_valid(qgis_app):
    """Geometry written back to the input CRS is valid by construction: a polygon that the
    transform to degrees leaves crossing its own ring is made valid again, its area kept."""
    import numpy as np
    from qgis.core import QgsCoordinateReferenceSystem as Crs

    from urban_synthesis.plugin.qgis_glue import qgis_io

    utm = np.array([shapely.from_wkt(JUNCTION_UTM)], dtype=object)
    assert shapely.is_valid(utm[0])
    degrees = qgis_io.reproject(utm, Crs("EPSG:32632"), Crs("EPSG:4326"), None)
    assert not shapely.is_valid(degrees[0])       # what the plain transform gives
    for multi in (True, False):
        fixed = qgis_io.valid_after_transform(degrees, multi)
        assert shapely.is_valid(fixed[0]) and shapely.get_type_id(fixed[0]) in (3, 6)
        back = qgis_io.reproject(fixed, Crs("EPSG:4326"), Crs("EPSG:32632"), None)
        assert shapely.area(back[0]) == pytest.approx(shapely.area(utm[0]), rel=1e-6)
    assert qgis_io.valid_after_transform(utm)[0] is utm[0]    # a valid one is left as it is


def test_an_unreadable_geometry_that_stays_unreadable_is_not_called_repaired(qgis_processing):
    """A ring of two points, both the same (GEOS cannot read it; QGIS's repair gives
    nothing either): the
    log said '1 unreadable geometries repaired by QGIS, 1 skipped' of a building that was
    left out; now it says how many were repaired and how many skipped."""
    from qgis.core import QgsFeatureRequest

    roads, _ = _roads_and_buildings()
    ok = [shapely.box(x + 20, y + 20, x + 60, y + 60).wkt for x in (0, 100) for y in (0, 100)]
    buildings = memory_layer("Polygon", ok + ["POLYGON((20 220, 20 220))"],
                             "EPSG:32633", name="houses", fields="&field=building:string",
                             rows=[["yes"]] * 5)
    layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryNoCheck,
                      buildings)
    assert layer.featureCount() == 4
    assert "houses': 1 unreadable geometry: 0 repaired by QGIS, 1 skipped." in log


def test_an_unreadable_ring_repaired_into_a_line_is_no_building(qgis_processing):
    """A polygon ring of two points (OSM has them) is unreadable to GEOS; QGIS's repair
    makes a line of it, which was kept in a polygon layer: extractblocks stopped with 'Could
    not add feature with geometry type MultiLineString', buildblockdatabase stored it as a
    building, synthesizebuildingattributes stopped with '... 1 of the footprints are not
    polygons' naming the example layer. The line is no polygon: skipped."""
    from qgis.core import QgsFeatureRequest

    roads, _ = _roads_and_buildings()
    ok = [shapely.box(x + 20, y + 20, x + 60, y + 60).wkt for x in (0, 100) for y in (0, 100)]
    buildings = memory_layer("Polygon", ok + ["POLYGON((20 220, 60 260))"], "EPSG:32633",
                             name="houses", fields="&field=building:string",
                             rows=[["yes"]] * 5)
    layer, log = _run(qgis_processing, QgsFeatureRequest.InvalidGeometryCheck.GeometryNoCheck,
                      buildings)
    assert layer.featureCount() == 4
    assert all(f.geometry().type() == 2 for f in layer.getFeatures())
    assert "houses': 1 unreadable geometry: 0 repaired by QGIS, 1 skipped." in log
    out = qgis_processing.run("urbansynth:synthesizebuildingattributes", {
        "FOOTPRINTS": buildings, "EXAMPLE_BUILDINGS": layer, "OUTPUT": "memory:"})
    assert out["OUTPUT"].featureCount() == 4
