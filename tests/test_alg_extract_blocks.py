"""urbansynth:extractblocks through real QGIS (processing.run and qgis_process.bin)."""
import numpy as np
import pytest
import shapely

from conftest import BUBENEC, bubenec_layer, helsinki_layer, run_qgis_process
from helpers import layer_features, log_feedback, memory_layer


def _memory_layer(kind, wkts=(), crs="EPSG:3857", **kwargs):
    return memory_layer(kind, wkts, crs, **kwargs)


def _utm_area(geoms, lat):
    """Approximate areas (m²) of EPSG:4326 geometries: scale degrees at the latitude."""
    scaled = shapely.transform(geoms, lambda c: c * [111_320 * np.cos(np.radians(lat)), 110_950])
    return shapely.area(scaled)


@pytest.fixture(scope="module")
def helsinki(qgis_processing):
    return qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": helsinki_layer("lines"), "BUILDINGS": helsinki_layer("multipolygons"),
        "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"})


def test_helsinki_blocks(helsinki):
    layer = helsinki["OUTPUT"]
    assert layer.crs().authid() == "EPSG:4326"  # back in the input CRS
    rows, geoms = layer_features(layer)
    assert 40 <= len(rows) <= 70
    assert [r["block_id"] for r in rows] == list(range(1, len(rows) + 1))
    assert shapely.is_valid(geoms).all()
    area = np.array([r["area_m2"] for r in rows])
    # metric areas, matching the geometry written back in degrees
    assert np.allclose(area, _utm_area(geoms, 60.17), rtol=0.02)
    assert area.min() >= 400 and 2_000 < np.median(area) < 30_000
    for key in ("compactness", "aspect_ratio", "building_coverage"):
        values = np.array([r[key] for r in rows])
        assert ((values > 0) & (values <= 1)).all() or key == "building_coverage", key
    assert sum(r["n_buildings"] for r in rows) > 250


def test_a_hierarchy_of_every_line_keeps_its_classes_for_the_blocks(qgis_processing,
                                                                    helsinki):
    """'Extract road hierarchy' with CLASSES empty keeps footways and cycleways, their OSM
    class in road_class: the blocks are made of the drivable ones, as from the OSM lines
    (road_class was not read: 336 courtyard blocks for 54 in a trial)."""
    every_line = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "CLASSES": "", "OUTPUT": "memory:"})["OUTPUT"]
    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": every_line, "OUTPUT": "memory:"})["OUTPUT"]
    assert abs(blocks.featureCount() - helsinki["OUTPUT"].featureCount()) <= 3


def test_a_layer_merged_with_itself_gives_the_same_blocks(qgis_processing):
    """Every street and building twice (a layer merged with itself): the same blocks with
    the same building counts, and the log says how many doubles were skipped (a doubled
    street split a block in two, and every block counted its buildings twice)."""
    from helpers import log_feedback

    def doubled(layer):
        return qgis_processing.run("native:mergevectorlayers", {
            "LAYERS": [layer, layer], "OUTPUT": "memory:"})["OUTPUT"]

    once = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
        "OUTPUT": "memory:"})["OUTPUT"]
    log = log_feedback()
    twice = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": doubled(bubenec_layer("streets")),
        "BUILDINGS": doubled(bubenec_layer("buildings")), "OUTPUT": "memory:"},
        feedback=log)["OUTPUT"]
    rows_once, rows_twice = layer_features(once)[0], layer_features(twice)[0]
    assert len(rows_twice) == len(rows_once)
    assert [r["n_buildings"] for r in rows_twice] == [r["n_buildings"] for r in rows_once]
    assert sum("with the same geometry as an earlier one skipped" in m
               for m in log.messages) == 2


def test_helsinki_buildings(helsinki):
    layer = helsinki["OUTPUT_BUILDINGS"]
    assert layer.crs().authid() == "EPSG:4326"
    rows, _ = layer_features(layer)
    # only polygons with a 'building' value: about 490 of Helsinki's multipolygons
    assert 450 < len(rows) < 520
    names = [f.name() for f in layer.fields()]
    for field in ("osm_id", "building", "source_fid", "block_id", "in_block", "height_m",
                  "height_estimated", "levels", "building_type", "building_tag"):
        assert field in names
    inside = [r for r in rows if r["in_block"]]
    assert all(r["block_id"] is not None for r in inside)
    assert all(r["block_id"] is None for r in rows if not r["in_block"])
    # docs/ARCHITECTURE.md: only about 62 % of Helsinki's buildings lie inside a closed block
    assert 0.5 < len(inside) / len(rows) < 0.75
    heights = [r for r in rows if r["height_m"] is not None]
    assert len(heights) > 150
    assert sum(1 for r in heights if r["height_estimated"]) > 100
    assert all(r["height_m"] > 0 for r in heights)
    assert {r["building_type"] for r in rows} <= {
        "residential", "commercial", "industrial", "public", "religious", "other", "unknown"}
    assert {"residential", "public", "religious"} <= {r["building_type"] for r in rows}


def test_bubenec_blocks_buildings_parcels(qgis_processing):
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
        "PARCELS": bubenec_layer("plots"), "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:",
        "OUTPUT_PARCELS": "memory:"})
    for key in ("OUTPUT", "OUTPUT_BUILDINGS", "OUTPUT_PARCELS"):
        assert out[key].crs().authid() == "EPSG:3857"
    blocks, _ = layer_features(out["OUTPUT"])
    assert len(blocks) == 7  # docs/ARCHITECTURE.md: Bubeneč has 7 closed blocks
    buildings, _ = layer_features(out["OUTPUT_BUILDINGS"])
    assert len(buildings) == 144
    assert "uID" in buildings[0]
    # the two north-western courtyard blocks are not closed by streets in this extract
    assert sum(r["in_block"] for r in buildings) == 96
    assert sum(b["n_buildings"] for b in blocks) == sum(r["in_block"] for r in buildings)
    # no height data in this cadastre extract: nothing is invented
    assert all(r["height_m"] is None and r["building_type"] == "unknown" for r in buildings)
    parcels, _ = layer_features(out["OUTPUT_PARCELS"])
    assert len(parcels) == 407
    assert {"ID", "KATUZE_KOD", "block_id", "in_block"} <= set(parcels[0])
    assert sum(r["in_block"] for r in parcels) == 143  # the rest: streets, open blocks
    assert sum(b["n_parcels"] for b in blocks) == sum(r["in_block"] for r in parcels)


GRID_WKT = [f"LINESTRING (0 {y}, 200 {y})" for y in (0, 100, 200)] + \
    [f"LINESTRING ({x} 0, {x} 200)" for x in (0, 100, 200)]


def _cadastre(rows):
    """Three buildings, one in each of three blocks of the grid, with a height ('vyska')
    and a number of storeys ('podlazi') per row."""
    return _memory_layer(
        "Polygon", ["POLYGON ((10 10, 30 10, 30 30, 10 30, 10 10))",
                    "POLYGON ((110 10, 130 10, 130 30, 110 30, 110 10))",
                    "POLYGON ((10 110, 30 110, 30 130, 10 130, 10 110))"],
        crs="EPSG:32633", fields="&field=vyska:double&field=podlazi:integer",
        rows=rows)


def test_cadastre_height_and_levels_fields(qgis_processing):
    """A metric cadastre: heights and storeys from fields named by the user."""
    roads_layer = _memory_layer("LineString", GRID_WKT, crs="EPSG:32633")
    buildings = _cadastre([(12.5, None), (None, 4), (None, None)])
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": roads_layer, "BUILDINGS": buildings, "HEIGHT_FIELD": "vyska",
        "LEVELS_FIELD": "podlazi", "STOREY_HEIGHT": 3.5, "OUTPUT": "memory:",
        "OUTPUT_BUILDINGS": "memory:"})
    blocks, geoms = layer_features(out["OUTPUT"])
    assert len(blocks) == 4
    assert [round(b["area_m2"]) for b in blocks] == [10_000] * 4
    assert out["OUTPUT"].crs().authid() == "EPSG:32633"
    rows, _ = layer_features(out["OUTPUT_BUILDINGS"])
    assert [r["block_id"] for r in rows] == [1, 2, 3]
    assert [r["height_m"] for r in rows] == [12.5, 14.0, None]
    assert [r["height_estimated"] for r in rows] == [False, True, None]
    assert [r["levels"] for r in rows] == [4.0, 4.0, None]   # round(12.5 / 3.5) = 4
    assert rows[0]["vyska"] == 12.5 and rows[1]["podlazi"] == 4  # source fields kept


def test_unreadable_cadastre_values_and_buildings_off_the_blocks_are_warned(qgis_processing):
    """A cadastre field with a negative or an absurd value gave those buildings no height
    and said nothing; buildings of another area than the roads were an info line."""
    roads_layer = _memory_layer("LineString", GRID_WKT, crs="EPSG:32633")
    buildings = _cadastre([(5000.0, 3), (-4.0, -2), (9.0, None)])
    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": roads_layer, "BUILDINGS": buildings, "HEIGHT_FIELD": "vyska",
        "LEVELS_FIELD": "podlazi", "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"},
        feedback=log)
    rows, _ = layer_features(out["OUTPUT_BUILDINGS"])
    assert [r["height_m"] for r in rows] == [9.0, None, 9.0]   # 3 storeys x 3 m; nothing; 9
    assert any("2 value(s) of field 'vyska' are no height in metres (e.g. 5000.0, -4.0)" in w
               for w in log.warnings), log.warnings
    assert any("1 value(s) of field 'podlazi' are no number of storeys (e.g. -2.0)" in w
               for w in log.warnings), log.warnings
    far = _memory_layer("Polygon", ["POLYGON ((5010 10, 5030 10, 5030 30, 5010 30, 5010 10))"],
                        crs="EPSG:32633")
    log = log_feedback()
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": roads_layer, "BUILDINGS": far, "OUTPUT": "memory:",
        "OUTPUT_BUILDINGS": "memory:"}, feedback=log)
    assert any("None of the 1 buildings lies in a block" in w for w in log.warnings), \
        log.warnings


@pytest.mark.parametrize("given", ["empty layer", "not given"])
def test_outputs_of_a_missing_optional_input_are_written_empty(qgis_processing, tmp_path,
                                                               given):
    """Buildings and parcels left out, or given as empty layers: their requested outputs
    are still written, without features but with their fields, so that a model step that
    reads them gets a layer (they were not written: the next step failed on a missing
    file)."""
    roads_layer = _memory_layer("LineString", GRID_WKT, crs="EPSG:32633")
    params = {"ROADS": roads_layer, "OUTPUT": "memory:",
              "OUTPUT_BUILDINGS": str(tmp_path / "buildings.gpkg"),
              "OUTPUT_PARCELS": str(tmp_path / "parcels.gpkg")}
    if given == "empty layer":
        params["BUILDINGS"] = _memory_layer("Polygon", crs="EPSG:32633")
        params["PARCELS"] = _memory_layer("Polygon", crs="EPSG:32633")
    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractblocks", params, feedback=log)
    for key, field in (("OUTPUT_BUILDINGS", "height_m"), ("OUTPUT_PARCELS", "block_id")):
        from qgis.core import QgsVectorLayer

        layer = QgsVectorLayer(out[key], key, "ogr")
        assert layer.isValid() and layer.featureCount() == 0, key
        assert field in layer.fields().names(), layer.fields().names()
        assert layer.crs().authid() == "EPSG:32633"
        assert any(f"{key} is written without features" in m for m in log.messages), log.messages
    # a next step reads it like any layer
    assert qgis_processing.run("native:buffer", {
        "INPUT": out["OUTPUT_BUILDINGS"], "DISTANCE": 1.0,
        "OUTPUT": "memory:"})["OUTPUT"].featureCount() == 0


def test_missing_class_field_is_rejected(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="no field 'druh'"):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": bubenec_layer("streets"), "CLASS_FIELD": "druh", "OUTPUT": "memory:"})


def test_cancel_stops_the_algorithm(qgis_processing):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    feedback = QgsProcessingFeedback()
    feedback.cancel()
    with pytest.raises(QgsProcessingException, match="[Cc]ancel"):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": bubenec_layer("streets"), "OUTPUT": "memory:"}, feedback=feedback)


def test_point_layer_is_rejected(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="line"):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": helsinki_layer("points"), "OUTPUT": "memory:"})


def test_empty_layer_is_rejected(qgis_processing):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="empty"):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": _memory_layer("LineString"), "OUTPUT": "memory:"})


def test_layer_without_crs_is_rejected(qgis_processing, tmp_path):
    """A shapefile without .prj: its units are unknown, so no silent guess of metres."""
    import geopandas as gpd
    from qgis.core import QgsProcessingException

    streets = gpd.read_file(BUBENEC, layer="streets")
    path = tmp_path / "no_prj.shp"
    streets.set_crs(None, allow_override=True).to_file(path)
    assert not path.with_suffix(".prj").exists()
    with pytest.raises(QgsProcessingException, match="no_prj.*no coordinate reference system"):
        qgis_processing.run("urbansynth:extractblocks", {"ROADS": str(path), "OUTPUT": "memory:"})


def test_roads_without_closed_face_are_rejected(qgis_processing):
    from qgis.core import QgsProcessingException

    tree = _memory_layer("LineString", ["LINESTRING (0 0, 500 0)", "LINESTRING (100 0, 100 300)",
                                        "LINESTRING (300 0, 300 300)"])
    with pytest.raises(QgsProcessingException, match="no closed block"):
        qgis_processing.run("urbansynth:extractblocks", {"ROADS": tree, "OUTPUT": "memory:"})


@pytest.mark.parametrize("name, value", [("MIN_BLOCK_AREA", -1), ("STOREY_HEIGHT", 0)])
def test_absurd_parameters_are_rejected(qgis_processing, name, value):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": bubenec_layer("streets"), name: value, "OUTPUT": "memory:"})


def test_qgis_process_writes_geopackage(tmp_path):
    """The real qgis_process.bin exits 0 (the native-library crash of docs/ARCHITECTURE.md)."""
    blocks_out, buildings_out = tmp_path / "blocks.gpkg", tmp_path / "buildings.gpkg"
    code, result, stderr = run_qgis_process("extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
        "OUTPUT": blocks_out, "OUTPUT_BUILDINGS": buildings_out})
    assert code == 0, stderr
    assert blocks_out.exists() and buildings_out.exists()
    import pyogrio

    df = pyogrio.read_dataframe(blocks_out)
    assert len(df) == 7 and df.crs.to_epsg() == 3857
    assert set(df.columns) >= {"block_id", "area_m2", "compactness", "aspect_ratio"}
    assert len(pyogrio.read_dataframe(buildings_out)) == 144
    assert result is not None and "OUTPUT" in result.get("results", {})


@pytest.mark.parametrize("crs, said", [
    ("EPSG:4326", "is in EPSG:4326 (WGS 84) (not in metres): worked in EPSG:32635"),
    ("EPSG:3857", "(more than 1 % off true scale here): worked in EPSG:32635"),
    ("EPSG:3067", "worked in its own CRS, EPSG:3067"),
])
def test_the_log_names_the_working_crs(qgis_processing, crs, said):
    """Every length and area is measured in the working CRS: the log says which one it is
    and why (it said nothing), and which CRS a second layer is projected to."""
    from qgis.core import (QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsGeometry,
                           QgsProject)

    tr = QgsCoordinateTransform(QgsCoordinateReferenceSystem("EPSG:3067"),
                                QgsCoordinateReferenceSystem(crs), QgsProject.instance())
    x0, y0 = 385000.0, 6671000.0        # central Helsinki in ETRS-TM35FIN
    grid = [f"LINESTRING({x0 + 100 * i} {y0}, {x0 + 100 * i} {y0 + 300})" for i in range(4)] + \
        [f"LINESTRING({x0} {y0 + 100 * j}, {x0 + 300} {y0 + 100 * j})" for j in range(4)]
    wkts = []
    for w in grid:
        g = QgsGeometry.fromWkt(w)
        g.transform(tr)
        wkts.append(g.asWkt(9))
    house = f"POLYGON(({x0 + 20} {y0 + 20}, {x0 + 40} {y0 + 20}, {x0 + 40} {y0 + 40}, " \
            f"{x0 + 20} {y0 + 40}, {x0 + 20} {y0 + 20}))"
    log = log_feedback()
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": _memory_layer("LineString", wkts, crs, name="grid"), "CLASSES": "",
        "BUILDINGS": _memory_layer("Polygon", [house], "EPSG:3067", name="house"),
        "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"}, feedback=log)
    assert any(m.startswith("'grid'") and said in m for m in log.messages), log.messages
    work = said.split("worked in ")[-1].split(" ")[-1].rstrip(",")
    if crs == "EPSG:3067":
        assert any(m.startswith("'house'") and "worked in its own CRS, EPSG:3067" in m
                   for m in log.messages)
    else:
        assert any(m.startswith("'house'") and f"projected to the working CRS, {work}" in m
                   for m in log.messages), log.messages


def test_roundabout_islands_of_osm_are_no_blocks(qgis_processing):
    """Liechtenstein's OSM lines: the islands of its junction=roundabout rings (in
    other_tags) became blocks (371); 6 of them are over the minimum block area. They are
    dropped, and the log counts them."""
    from conftest import LIECHTENSTEIN

    if not LIECHTENSTEIN.exists():
        pytest.skip(f"{LIECHTENSTEIN} is not there")
    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": f"{LIECHTENSTEIN}|layername=lines", "OUTPUT": "memory:"}, feedback=log)
    assert out["OUTPUT"].featureCount() == 365
    assert any("6 roundabout islands dropped" in m for m in log.messages), log.messages
    # the same from the road hierarchy of those lines (it had no junction field: the
    # islands were blocks again in the chain the demo runs)
    ranked = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": f"{LIECHTENSTEIN}|layername=lines", "OUTPUT": "memory:",
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    assert "roundabout" in {f["junction"] for f in ranked.getFeatures()}
    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractblocks", {"ROADS": ranked, "OUTPUT": "memory:"},
                              feedback=log)
    assert any("6 roundabout islands dropped" in m for m in log.messages), log.messages
    assert out["OUTPUT"].featureCount() == 365
    # a layer with its own junction field, as a hand-drawn one would have
    ring = shapely.LineString(shapely.Point(100, 100).buffer(12.5, quad_segs=16).exterior.coords)
    wkts = ["LINESTRING (0 0, 200 0, 200 200, 0 200, 0 0)", shapely.to_wkt(ring),
            "LINESTRING (100 0, 100 87.5)", "LINESTRING (100 112.5, 100 200)",
            "LINESTRING (0 100, 87.5 100)", "LINESTRING (112.5 100, 200 100)"]
    layer = memory_layer("LineString", wkts, "EPSG:32632",
                         fields="&field=highway:string&field=junction:string",
                         rows=[["residential", "roundabout" if i == 1 else None]
                               for i in range(6)])
    log = log_feedback()
    out = qgis_processing.run("urbansynth:extractblocks", {"ROADS": layer, "OUTPUT": "memory:"},
                              feedback=log)
    assert out["OUTPUT"].featureCount() == 4
    assert any("1 roundabout island dropped" in m for m in log.messages), log.messages
