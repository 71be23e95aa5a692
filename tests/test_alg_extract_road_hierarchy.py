"""urbansynth:extractroadhierarchy through real QGIS (processing.run and qgis_process.bin)."""
import numpy as np
import pytest
import shapely

from conftest import BUBENEC, bubenec_layer, helsinki_layer, run_qgis_process
from helpers import assert_planar, layer_features, log_feedback


def test_helsinki_hierarchy(qgis_processing, tmp_path):
    out = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": "memory:"})
    roads_layer, points = out["OUTPUT"], out["OUTPUT_INTERSECTIONS"]
    assert roads_layer.crs().authid() == "EPSG:4326"  # back in the input CRS
    rows, geoms = layer_features(roads_layer)
    assert len(rows) > 150
    levels = np.array([r["level"] for r in rows])
    assert levels.min() == 0 and 3 <= levels.max() <= 5
    assert {"primary", "secondary", "residential"} <= {r["road_class"] for r in rows}
    assert all(r["road_class"] not in ("footway", "cycleway", "service") for r in rows)
    assert all(r["length_m"] > 0 for r in rows)
    # lengths are metric (not degrees): Helsinki's network is tens of kilometres
    assert 20_000 < sum(r["length_m"] for r in rows) < 200_000
    # primaries are arterials
    assert all(r["level"] == 0 for r in rows if r["road_class"] == "primary")
    # planar in a metric CRS (bridges may cross what they pass over)
    utm = shapely.transform(geoms, lambda c: c * [111_000 * np.cos(np.radians(60.17)), 111_000])
    assert_planar(utm, [r["osm_layer"] for r in rows])
    prow, _ = layer_features(points)
    assert points.featureCount() > 100
    deg = np.array([r["degree"] for r in prow])
    assert set(np.unique(deg)) <= {1, 2, 3, 4, 5, 6}
    assert all(r["level_a"] is not None for r in prow)


def test_its_own_output_keeps_its_classes(qgis_processing, tmp_path):
    """The hierarchy's output holds the OSM classes in 'road_class'. Read again (a town cut
    out of it, a second run with other settings), it was taken as a layer without classes:
    2 topological arterials instead of Helsinki's 22 primaries and secondaries. The road
    class rule (highway, else road_class) was not given the field to read."""
    first = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": str(tmp_path / "roads.gpkg"),
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    log = log_feedback()
    again = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": first, "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": None}, feedback=log)
    assert not any("no road classes" in m for m in log.messages)
    rows, _ = layer_features(again["OUTPUT"])
    from qgis.core import QgsVectorLayer

    before, _ = layer_features(QgsVectorLayer(first, "first run", "ogr"))
    assert sum(r["level"] == 0 for r in before) > 20
    assert sorted((r["level"], r["road_class"]) for r in rows) == \
        sorted((r["level"], r["road_class"]) for r in before)


def test_bubenec_without_classes_uses_topological_levels(qgis_processing):
    out = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": bubenec_layer("streets"), "PARCELS": bubenec_layer("plots"),
        "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": "memory:"})
    rows, _ = layer_features(out["OUTPUT"])
    assert out["OUTPUT"].crs().authid() == "EPSG:3857"
    levels = {r["level"] for r in rows}
    assert 0 in levels and len(levels) >= 2
    assert all(r["arterial_source"] in ("", "topological", "component") for r in rows)
    prow, _ = layer_features(out["OUTPUT_INTERSECTIONS"])
    # with parcels, intersections carry the mean parcel area nearby (Aliaga's a(v))
    areas = [r["parcel_area"] for r in prow if r["parcel_area"] is not None]
    assert len(areas) > len(prow) / 2 and 100 < np.median(areas) < 5000


def test_parcels_of_another_place_are_named_in_a_warning(qgis_processing):
    """Parcels that no intersection has within PARCEL_RADIUS (another town, or a layer in
    the wrong place) left every parcel_area empty without a word."""
    from qgis.core import NULL

    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "PARCELS": bubenec_layer("plots"),
        "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": "memory:"}, feedback=log)
    rows, _ = layer_features(out["OUTPUT_INTERSECTIONS"])
    assert all(r["parcel_area"] in (None, NULL) for r in rows)
    warned = [w for w in log.warnings if "No parcel of" in w]
    assert len(warned) == 1 and "bubenec (plots)" in warned[0] and "100 m" in warned[0]
    log = log_feedback()
    qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": bubenec_layer("streets"), "PARCELS": bubenec_layer("plots"),
        "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": "memory:"}, feedback=log)
    assert not any("No parcel of" in w for w in log.warnings)


def test_input_is_not_modified(qgis_processing, tmp_path):
    from qgis.core import QgsVectorLayer

    import shutil
    copy = tmp_path / "bubenec.gpkg"
    shutil.copy(BUBENEC, copy)
    before = copy.read_bytes()
    qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": f"{copy}|layername=streets", "OUTPUT": "memory:"})
    layer = QgsVectorLayer(f"{copy}|layername=streets", "s", "ogr")
    assert layer.featureCount() == 35
    assert copy.read_bytes() == before


def test_point_layer_is_rejected(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="lines are needed|line"):
        qgis_processing.run("urbansynth:extractroadhierarchy", {
            "INPUT": helsinki_layer("points"), "OUTPUT": "memory:"})


def test_empty_layer_is_rejected(qgis_processing):
    from qgis.core import QgsProcessingException, QgsVectorLayer

    empty = QgsVectorLayer("LineString?crs=EPSG:3067&field=highway:string", "empty roads", "memory")
    with pytest.raises(QgsProcessingException, match="empty roads.*empty"):
        qgis_processing.run("urbansynth:extractroadhierarchy", {"INPUT": empty, "OUTPUT": "memory:"})


def test_no_drivable_class_is_a_clear_error(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="drivable classes"):
        qgis_processing.run("urbansynth:extractroadhierarchy", {
            "INPUT": helsinki_layer("lines"), "CLASSES": "no_such_class", "OUTPUT": "memory:"})


def test_missing_explicit_class_field_is_a_clear_error(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="no field 'fclass'"):
        qgis_processing.run("urbansynth:extractroadhierarchy", {
            "INPUT": bubenec_layer("streets"), "CLASS_FIELD": "fclass", "OUTPUT": "memory:"})


def test_null_and_invalid_geometries_are_skipped_or_repaired(qgis_processing):
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer

    layer = QgsVectorLayer("LineString?crs=EPSG:3067&field=highway:string", "dirty", "memory")
    feats = []
    for wkt, cls in [("LINESTRING(0 0, 200 0)", "primary"), ("LINESTRING(100 -100, 100 100)", "residential"),
                     (None, "residential"), ("LINESTRING(50 50, 50 50)", "residential")]:
        f = QgsFeature(layer.fields())
        if wkt:
            f.setGeometry(QgsGeometry.fromWkt(wkt))
        f.setAttributes([cls])
        feats.append(f)
    layer.dataProvider().addFeatures(feats)
    fb = log_feedback()
    out = qgis_processing.run("urbansynth:extractroadhierarchy", {"INPUT": layer, "OUTPUT": "memory:"},
                              feedback=fb)
    assert out["OUTPUT"].featureCount() == 4
    assert any("null" in m for m in fb.messages)


def test_the_log_counts_in_the_right_number(qgis_processing):
    """'1 features with the same geometry ...', '1 features with a null or empty geometry
    ...' (every .osm.pbf of Liechtenstein's run said the first): one feature, one line, one
    geometry in the singular, several in the plural."""
    from helpers import memory_layer

    wkts = ["LINESTRING(0 0, 200 0)", "LINESTRING(100 -100, 100 100)", "LINESTRING(0 0, 200 0)",
            "LINESTRING(100 -100, 100 100)", "LINESTRING(200 0, 0 0)",
            "LINESTRING(300 0, 300 50)"]
    for n, roads in ((1, wkts[:3] + [None]), (3, wkts)):
        layer = memory_layer("LineString", [w for w in roads if w], "EPSG:3067",
                             "&field=highway:string", [["primary"]] * 6, name="twice")
        if None in roads:
            from qgis.core import QgsFeature

            layer.dataProvider().addFeatures([QgsFeature(layer.fields())])
        fb = log_feedback()
        qgis_processing.run("urbansynth:extractroadhierarchy", {
            "INPUT": layer, "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": None}, feedback=fb)
        log = "\n".join(fb.messages)
        assert f"{n} feature{'s' if n > 1 else ''} with the same geometry as an earlier one" in log
        if n == 1:
            assert "1 feature with a null or empty geometry skipped" in log
        assert "1 features" not in log and "1 lines" not in log and "1 streets" not in log


def test_cancel_stops_the_algorithm(qgis_processing):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    fb = QgsProcessingFeedback()
    fb.cancel()
    with pytest.raises(QgsProcessingException, match="Cancel"):
        qgis_processing.run("urbansynth:extractroadhierarchy", {
            "INPUT": helsinki_layer("lines"), "OUTPUT": "memory:"}, feedback=fb)


def test_qgis_process_run_exits_zero(tmp_path):
    out = tmp_path / "roads.gpkg"
    code, result, err = run_qgis_process("extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": out,
        "OUTPUT_INTERSECTIONS": tmp_path / "intersections.gpkg"})
    assert code == 0, err
    assert result is not None and "OUTPUT" in result["results"]
    import pyogrio

    assert pyogrio.read_info(out)["features"] > 150


def test_every_output_field_is_explained_in_the_help(qgis_processing):
    """The roads' osm_layer, node_from, tortuosity, arterial_source and every field of the
    intersections (dist_var_b, block_area ...) were named nowhere a user could read what
    they hold."""
    import re

    from qgis.core import QgsApplication

    from urban_synthesis.processing_algorithms import extract_road_hierarchy as erh

    alg = QgsApplication.processingRegistry().algorithmById("urbansynth:extractroadhierarchy")
    for output, fields in (("OUTPUT", erh.ROAD_FIELDS),
                           ("OUTPUT_INTERSECTIONS", erh.INTERSECTION_FIELDS)):
        text = alg.parameterDefinition(output).help()
        named = set(re.findall(r"[a-z_0-9]+", text))
        named |= {f"{stem}_{side}" for stem, sides in re.findall(r"([a-z_]+)_(a/b)", text)
                  for side in "ab"}
        missing = [name for name, _ in fields if name not in named]
        assert not missing, (output, missing)
