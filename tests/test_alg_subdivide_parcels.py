"""urbansynth:subdivideparcels through real QGIS (processing.run and qgis_process.bin)."""
import numpy as np
import pytest
import shapely

from conftest import bubenec_layer, run_qgis_process
from helpers import layer_features, memory_layer
from urban_synthesis.plugin.parcels import subdivision as parcels
from urban_synthesis.plugin.core.paths import RESOURCES

ALG = "urbansynth:subdivideparcels"
FIELDS = [name for name, _ in parcels.PARCEL_FIELDS]
#: Web Mercator areas are 1 / cos²(latitude) too large; Bubeneč lies at 50.1° N
MERCATOR_AREA = 1.0 / np.cos(np.radians(50.1)) ** 2


def _memory_layer(kind, wkts=(), crs="EPSG:32633", **kwargs):
    return memory_layer(kind, wkts, crs, **kwargs)


@pytest.fixture(scope="module")
def bubenec_blocks(qgis_processing):
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": "memory:"})
    return layer_features(out["OUTPUT"])


def test_collected_blocks_are_cut_block_by_block(qgis_processing):
    """Bubeneč's blocks gathered into one multi-part feature ('Collect geometries') give the
    parcels of the blocks one by one: the repair of the invalid collection merged the blocks
    across their streets, and lots spanned them (Helsinki: 449 parcels for 764)."""
    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": "memory:"})["OUTPUT"]
    one = qgis_processing.run("native:collect", {"INPUT": blocks,
                                                 "OUTPUT": "memory:"})["OUTPUT"]
    collected = qgis_processing.run("urbansynth:subdivideparcels", {
        "BLOCKS": one, "SEED": 1, "OUTPUT": "memory:"})["OUTPUT"]
    apart = qgis_processing.run("urbansynth:subdivideparcels", {
        "BLOCKS": blocks, "SEED": 1, "OUTPUT": "memory:"})["OUTPUT"]
    _, g = layer_features(collected)
    _, g0 = layer_features(apart)
    assert len(g) == len(g0)
    assert np.allclose(np.sort(shapely.area(g)), np.sort(shapely.area(g0)))


@pytest.mark.parametrize("method", [0, 1], ids=["recursive", "skeleton"])
def test_bubenec_from_roads(qgis_processing, bubenec_blocks, method):
    out = qgis_processing.run(ALG, {"ROADS": bubenec_layer("streets"), "METHOD": method,
                                    "SEED": 3, "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.crs().authid() == "EPSG:3857"  # back in the input CRS
    assert [f.name() for f in layer.fields()] == FIELDS
    rows, geoms = layer_features(layer)
    assert 50 < len(rows) < 200
    assert shapely.is_valid(geoms).all()
    assert [r["parcel_id"] for r in rows] == list(range(1, len(rows) + 1))
    assert {r["method"] for r in rows} == {parcels.method_names()[method]}
    # metric areas and lengths, computed in UTM, not in Web Mercator
    area = np.array([r["area_m2"] for r in rows])
    assert np.allclose(area * MERCATOR_AREA, shapely.area(geoms), rtol=0.01)
    assert area.min() >= parcels.DEFAULT_MIN_AREA - 1e-6
    # every parcel with street frontage (skeleton by construction, recursive with the
    # default FORCE_STREET_ACCESS), inside the block of its block_id, 6 m off the streets
    assert all(r["has_street_access"] and r["frontage_m"] >= parcels.MIN_FRONTAGE for r in rows)
    block_rows, block_geoms = bubenec_blocks
    by_id = {r["block_id"]: g for r, g in zip(block_rows, block_geoms)}
    assert {r["block_id"] for r in rows} == set(by_id)
    for r, g in zip(rows, geoms):
        assert shapely.within(g, by_id[r["block_id"]])
    for r in rows:
        assert isinstance(r["undesirable"], bool)
        assert r["undesirable"] == (r["p_angle"] > 15 or r["p_area"] > 1.2)


@pytest.mark.parametrize("stretched", ["EPSG:3395", "EPSG:4087"])
def test_a_crs_in_metres_that_is_not_true_is_not_worked_in(qgis_processing, stretched):
    """World Mercator and a plate carree in metres stretch lengths by 1.47 at Vaduz (47 N):
    the parcels are cut in true metres (the UTM zone), as from the same block in UTM, and
    their area_m2 is their true area."""
    from pyproj import Transformer

    block = shapely.box(758500, 5223000, 758800, 5223240)   # UTM 32N
    to = Transformer.from_crs("EPSG:32632", stretched, always_xy=True)
    back = Transformer.from_crs(stretched, "EPSG:32632", always_xy=True)
    counts = []
    for crs, geom in (("EPSG:32632", block), (stretched, shapely.transform(
            shapely.segmentize(block, 10.0), lambda xy: np.column_stack(to.transform(*xy.T))))):
        out = qgis_processing.run(ALG, {"BLOCKS": _memory_layer("Polygon", [geom.wkt], crs),
                                        "METHOD": 0, "SEED": 1, "OUTPUT": "memory:"})
        rows, geoms = layer_features(out["OUTPUT"])
        true = shapely.area(shapely.transform(
            geoms, lambda xy: np.column_stack(back.transform(*xy.T)))) \
            if crs != "EPSG:32632" else shapely.area(geoms)
        assert np.allclose([r["area_m2"] for r in rows], true, rtol=0.01)
        counts.append(len(rows))
    assert counts[1] == pytest.approx(counts[0], rel=0.1)   # 1.47 x would give 2.2 x as many


def test_blocks_input_keeps_block_ids_and_seed(qgis_processing):
    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": "memory:"})["OUTPUT"]
    params = {"BLOCKS": blocks, "METHOD": 0, "IRREGULARITY": 0.8, "MAX_AREA": 600,
              "STREET_WIDTH": 10, "OUTPUT": "memory:"}
    first = layer_features(qgis_processing.run(ALG, dict(params, SEED=5))["OUTPUT"])
    again = layer_features(qgis_processing.run(ALG, dict(params, SEED=5))["OUTPUT"])
    other = layer_features(qgis_processing.run(ALG, dict(params, SEED=6))["OUTPUT"])
    assert shapely.to_wkb(first[1]).tolist() == shapely.to_wkb(again[1]).tolist()
    assert shapely.to_wkb(first[1]).tolist() != shapely.to_wkb(other[1]).tolist()
    assert {r["block_id"] for r in first[0]} == set(range(1, 8))
    area = np.array([r["area_m2"] for r in first[0]])
    # recursive splits until under MAX_AREA, except where a cut would cut a lot off the street
    assert np.mean(area <= 600 * 1.001) > 0.8
    assert all(r["has_street_access"] for r in first[0])


def test_street_width_field(qgis_processing):
    """Per-road widths: the two 200 m roads at y = 0 and y = 200 are 20 m wide."""
    wkts = [f"LINESTRING (0 {y}, 200 {y})" for y in (0, 100, 200)] + \
        [f"LINESTRING ({x} 0, {x} 200)" for x in (0, 100, 200)]
    roads = _memory_layer("LineString", wkts, fields="&field=width:double",
                          rows=[(20.0,), (None,), (20.0,), (None,), (None,), (None,)])
    out = qgis_processing.run(ALG, {"ROADS": roads, "STREET_WIDTH_FIELD": "width",
                                    "STREET_WIDTH": 8, "METHOD": 1, "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert out["OUTPUT"].crs().authid() == "EPSG:32633"
    per_block = {}
    for r in rows:
        per_block[r["block_id"]] = per_block.get(r["block_id"], 0.0) + r["area_m2"]
    # every block: 100 m minus 4 + 4 m across, 100 m minus 10 (20 m road) + 4 m along
    assert sorted(per_block) == [1, 2, 3, 4]
    assert all(a == pytest.approx(92 * 86, rel=1e-4) for a in per_block.values())
    assert shapely.is_valid(geoms).all()


def test_parcels_stay_off_the_areas_kept_clear_in_another_crs(qgis_processing):
    """A dead end's surface inside the block, given in degrees: no parcel takes any of it,
    and the parcels (with no street width) fill the rest of the block."""
    from pyproj import Transformer

    block = shapely.box(500000, 5550000, 500120, 5550080)
    dead_end = shapely.buffer(shapely.LineString([(500060, 5550080), (500060, 5550030)]), 4.0)
    to_degrees = Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True)
    in_degrees = shapely.transform(dead_end, lambda xy: np.column_stack(
        to_degrees.transform(xy[:, 0], xy[:, 1])))
    out = qgis_processing.run(ALG, {
        "BLOCKS": _memory_layer("Polygon", [block.wkt]),
        "KEEP_CLEAR": memory_layer("Polygon", [in_degrees.wkt], "EPSG:4326"),
        "STREET_WIDTH": 0, "METHOD": 1, "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert len(rows) >= 4
    # the surface came through two transforms: a micrometre of round-off at most
    assert shapely.area(shapely.intersection(geoms, dead_end)).max() < 0.01
    assert shapely.area(shapely.union_all(geoms)) == pytest.approx(
        shapely.area(shapely.difference(block, dead_end)), rel=1e-3)


def test_keep_clear_and_buildings_layers_that_are_empty_or_elsewhere(qgis_processing):
    """An empty optional layer (a chained step that made nothing) is nothing to keep clear
    or whole, not an error; one that reaches no block is warned of; one that covers every
    block is named in the error."""
    from qgis.core import QgsProcessingException

    from helpers import log_feedback

    block = _memory_layer("Polygon", ["POLYGON ((0 0, 120 0, 120 80, 0 80, 0 0))"])
    empty = _memory_layer("Polygon", [], name="no surfaces")
    far = _memory_layer("Polygon", ["POLYGON ((5000 0, 5010 0, 5010 10, 5000 10, 5000 0))"],
                        name="far surfaces")
    cover = _memory_layer("Polygon", ["POLYGON ((-1 -1, 121 -1, 121 81, -1 81, -1 -1))"],
                          name="all surface")
    base = {"BLOCKS": block, "STREET_WIDTH": 0, "METHOD": 1, "OUTPUT": "memory:"}
    log = log_feedback()
    out = qgis_processing.run(ALG, dict(base, KEEP_CLEAR=empty, BUILDINGS=empty), feedback=log)
    assert out["OUTPUT"].featureCount() > 1
    assert any("is empty: no areas kept clear" in m for m in log.messages)
    log = log_feedback()
    qgis_processing.run(ALG, dict(base, KEEP_CLEAR=far, BUILDINGS=far), feedback=log)
    assert any("The polygon of 'far surfaces' reaches no block" in w
               for w in log.warnings)
    with pytest.raises(QgsProcessingException, match="covered by the areas to keep clear"):
        qgis_processing.run(ALG, dict(base, KEEP_CLEAR=cover))


def test_bad_input(qgis_processing):
    from qgis.core import QgsProcessingException

    def fails(params, match):
        with pytest.raises(QgsProcessingException, match=match):
            qgis_processing.run(ALG, dict(params, OUTPUT="memory:"))

    streets = bubenec_layer("streets")
    fails({}, "Give the Blocks to subdivide, or Roads")
    fails({"ROADS": streets, "BLOCKS": bubenec_layer("plots")}, "not both")
    fails({"ROADS": streets, "MAX_AREA": 100, "MIN_AREA": 200}, "must be larger than")
    fails({"ROADS": streets, "LOT_WIDTH": 5, "MIN_WIDTH": 8}, "lot width")
    # narrower than a driveway: no lot could have street access (57,431 'without street
    # frontage' on Bubeneč at 0.1 m, after 214 s)
    fails({"ROADS": streets, "LOT_WIDTH": 1.0}, "LOT_WIDTH")
    fails({"ROADS": _memory_layer("LineString")}, "empty")
    fails({"ROADS": bubenec_layer("buildings")}, "has polygons; lines are needed")
    fails({"BLOCKS": streets}, "has lines; polygons are needed")
    negative = _memory_layer("LineString", ["LINESTRING (0 0, 100 0)"],
                             fields="&field=width:double", rows=[(-4.0,)])
    fails({"ROADS": negative, "STREET_WIDTH_FIELD": "width"}, "negative street width")
    fails({"BLOCKS": bubenec_layer("plots"), "STREET_WIDTH_FIELD": "ID"}, "belongs to Roads")
    fails({"ROADS": _memory_layer("LineString", ["LINESTRING (0 0, 100 0)"])},
          "no closed block")
    fails({"BLOCKS": _memory_layer("Polygon", ["POLYGON ((0 0, 8 0, 8 100, 0 100, 0 0))"])},
          "no parcel")


def test_a_layer_of_geometry_collections_gives_its_polygons(qgis_processing):
    """A layer of collections or mixed types (a GeoPackage 'GEOMETRY' column) is read for
    the parts of the kind a tool needs: the block inside a collection is subdivided, a
    feature without any polygon is skipped and counted; a layer without any is refused by
    name as having no polygons (not 'no geometry')."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsProcessingException

    from helpers import log_feedback

    def collections(wkts, name):
        layer = _memory_layer("GeometryCollection", wkts, name=name)
        layer.setCrs(QgsCoordinateReferenceSystem("EPSG:32633"))  # the URI's is not taken
        return layer

    block = "POLYGON ((0 0, 120 0, 120 60, 0 60, 0 0))"
    mixed = collections([f"GEOMETRYCOLLECTION ({block}, LINESTRING (0 70, 120 70))",
                         "GEOMETRYCOLLECTION (POINT (10 10))"], "mixed blocks")
    log = log_feedback()
    rows, geoms = layer_features(qgis_processing.run(
        ALG, {"BLOCKS": mixed, "SEED": 1, "OUTPUT": "memory:"}, feedback=log)["OUTPUT"])
    assert len(rows) >= 4 and shapely.covers(shapely.from_wkt(block).buffer(1e-6), geoms).all()
    assert any("mixed blocks" in m and "1 feature without polygons skipped" in m
               for m in log.messages)
    points_only = collections(["GEOMETRYCOLLECTION (POINT (10 10))"], "point collections")
    with pytest.raises(QgsProcessingException, match="point collections'? has no polygons"):
        qgis_processing.run(ALG, {"BLOCKS": points_only, "OUTPUT": "memory:"})


def test_points_in_a_polygon_layer_are_skipped_and_counted(qgis_processing, tmp_path):
    """A GeoJSON file QGIS types as polygons may hold points too: they were counted as
    areas to keep clear ('4 areas'); they are skipped, counted, and the polygon is used."""
    import json

    from qgis.core import QgsVectorLayer

    from helpers import log_feedback

    path = tmp_path / "surfaces.geojson"
    square = {"type": "Polygon", "coordinates": [[[50, -5], [60, -5], [60, 70], [50, 70],
                                                  [50, -5]]]}
    point = {"type": "Point", "coordinates": [5, 5]}
    path.write_text(json.dumps({
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32633"}},
        "features": [{"type": "Feature", "properties": {}, "geometry": g}
                     for g in (square, point, point, point)]}))
    clear = QgsVectorLayer(str(path), "surfaces", "ogr")
    log = log_feedback()
    rows, geoms = layer_features(qgis_processing.run(ALG, {
        "BLOCKS": _memory_layer("Polygon", ["POLYGON ((0 0, 120 0, 120 60, 0 60, 0 0))"]),
        "KEEP_CLEAR": clear, "STREET_WIDTH": 0, "METHOD": 1, "OUTPUT": "memory:"},
        feedback=log)["OUTPUT"])
    assert shapely.area(shapely.intersection(geoms, shapely.box(50, 0, 60, 60))).max() < 1e-6
    assert any("3 features without polygons skipped" in m for m in log.messages)
    assert any("1 of the 1 polygon of 'surfaces' reaches" in m for m in log.messages)


def test_qgis_process_run(tmp_path):
    """One real qgis_process.bin run: exit code 0 (no native-library crash at exit)."""
    target = tmp_path / "parcels.gpkg"
    code, out, err = run_qgis_process("subdivideparcels", {
        "ROADS": bubenec_layer("streets"), "METHOD": 1, "MAX_AREA": 800, "SEED": 2,
        "OUTPUT": str(target)})
    assert code == 0, err
    assert out is not None and target.exists()
    import pyogrio

    df = pyogrio.read_dataframe(target)
    assert 60 < len(df) < 200 and list(df.columns[:len(FIELDS)]) == FIELDS
    assert df.has_street_access.all()
    # skeleton lots are narrowed to stay under MAX_AREA; corner lots take the corner too
    assert df.area_m2.median() < 800 and (df.area_m2 <= 800 * 1.001).mean() > 0.75


def test_quality_style(qgis_app):
    """The shipped style colours parcels by Yang's criteria (Fig. 12: good / undesirable)."""
    from qgis.core import QgsRuleBasedRenderer, QgsVectorLayer

    qml = RESOURCES / "styles" / "parcels_by_quality.qml"
    layer = QgsVectorLayer("Polygon?field=undesirable:boolean&field=has_street_access:boolean",
                           "parcels", "memory")
    message, ok = layer.loadNamedStyle(str(qml))
    assert ok, message
    renderer = layer.renderer()
    assert isinstance(renderer, QgsRuleBasedRenderer)
    rules = renderer.rootRule().children()
    assert [r.filterExpression() for r in rules[:2]] == [
        '"undesirable" AND "has_street_access"', 'NOT "undesirable" AND "has_street_access"']
    assert rules[0].symbol().color().name() != rules[1].symbol().color().name()


def test_a_shapefile_output_keeps_its_quality_style(qgis_processing, tmp_path):
    """A shapefile cuts field names to ten characters (undesirable -> undesirabl,
    has_street_access -> has_street): the style saved beside it names the fields as the
    file has them, so that its rules still tell good lots from undesirable ones."""
    from qgis.core import QgsFeatureRequest, QgsRenderContext, QgsVectorLayer

    out = tmp_path / "parcels.shp"
    qgis_processing.run(ALG, {"ROADS": bubenec_layer("streets"), "METHOD": 0, "SEED": 3,
                              "OUTPUT": str(out)})
    layer = QgsVectorLayer(str(out), "parcels", "ogr")   # opens with the sidecar .qml
    names = layer.fields().names()
    assert {"undesirabl", "has_street"} <= set(names) and "undesirable" not in names
    rules = layer.renderer().rootRule().children()
    assert rules[0].filterExpression() == '"undesirabl" AND "has_street"'
    # every feature falls in one of the rules (none did: the rules named missing fields)
    context = QgsRenderContext()
    renderer = layer.renderer().clone()
    renderer.startRender(context, layer.fields())
    for feature in layer.getFeatures(QgsFeatureRequest()):
        assert renderer.symbolsForFeature(feature, context), feature.attributes()
    renderer.stopRender(context)


#: A count of one with a plural noun ('1 parcels stay', '1 blocks read', '1 geometries').
ONE_PLURAL = r"(?<![\d.,])1 (parcels|blocks|lots|buildings|footprints|geometries|features|" \
             r"heights|polygons)\b"


def test_the_log_counts_one_in_the_singular(qgis_processing):
    """One block that no cut can split, with one building: the log said '1 parcels stay
    larger than the maximum area', '1 blocks read', '(1 of the 1 buildings stand ...)'."""
    import re

    from helpers import log_feedback

    block = _memory_layer("Polygon", [shapely.box(0, 0, 40, 40).wkt])
    house = _memory_layer("Polygon", [shapely.box(5, 5, 15, 15).wkt])
    log = log_feedback()
    qgis_processing.run(ALG, {"BLOCKS": block, "BUILDINGS": house, "STREET_WIDTH": 0,
                              "MAX_AREA": 1000, "MIN_AREA": 900, "OUTPUT": "memory:"},
                        feedback=log)
    text = "\n".join(log.messages)
    assert "1 parcel (recursive) in 1 block." in text
    assert "1 parcel stays larger than the maximum area" in text
    assert "1 block read from" in text
    assert not re.search(ONE_PLURAL, text), text


def test_a_selection_of_a_memory_layer_gives_the_parcels_of_the_same_blocks(qgis_processing):
    """A memory layer's selection is served in the order of a hash set, which Qt seeds
    anew in each process: with "Selected features only" (every block selected) one SEED
    gave 80, 81 or 82 parcels from one run of QGIS to the next, where the whole layer
    gave 82. A selection is read in the layer's order: the parcels of the whole layer."""
    from qgis.core import QgsProcessingFeatureSourceDefinition, QgsProject

    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "CLASS_FIELD": "", "OUTPUT": "memory:"})["OUTPUT"]
    QgsProject.instance().addMapLayer(blocks)
    try:
        blocks.selectAll()
        runs = []
        for given in (blocks, QgsProcessingFeatureSourceDefinition(blocks.id(), True)):
            out = qgis_processing.run(ALG, {"BLOCKS": given, "SEED": 1, "OUTPUT": "memory:"})
            runs.append([g.wkt for g in layer_features(out["OUTPUT"])[1]])
        assert len(runs[0]) > 50 and runs[0] == runs[1]
    finally:
        QgsProject.instance().removeMapLayer(blocks.id())


def test_a_district_boundary_closes_open_faces_and_is_no_street(qgis_processing):
    """An open sketch (a road across the district, one north from it) and its district's
    outline, given in another CRS: 'Extract city blocks' closes the faces with it, and
    'Subdivide blocks into parcels' with the same boundary keeps every lot on a street (the
    lots behind reach back to the outline, which keeps no street width); with Roads
    instead of Blocks the boundary closes the faces too."""
    from helpers import log_feedback

    x0, y0 = 458_000, 5_553_000
    sketch = _memory_layer("LineString", [
        f"LINESTRING ({x0} {y0 + 50}, {x0 + 260} {y0 + 50})",
        f"LINESTRING ({x0 + 100} {y0 + 50}, {x0 + 100} {y0 + 300})"])
    district = shapely.Polygon([(x0 + 10, y0), (x0 + 190, y0), (x0 + 230, y0 + 120),
                                (x0 + 160, y0 + 230), (x0 + 20, y0 + 200)])
    outline = qgis_processing.run("native:reprojectlayer", {
        "INPUT": _memory_layer("Polygon", [district.wkt]), "TARGET_CRS": "EPSG:4326",
        "OUTPUT": "memory:"})["OUTPUT"]
    log = log_feedback()
    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": sketch, "BOUNDARY": outline, "OUTPUT": "memory:"}, feedback=log)["OUTPUT"]
    rows, faces = layer_features(blocks)
    assert len(rows) == 3 and all(r["boundary_m"] > 100 for r in rows)
    assert any("3 blocks lie on the boundary" in m for m in log.messages), log.messages
    assert abs(shapely.area(faces).sum() - district.area) < 1.0
    streets = shapely.buffer(shapely.union_all([shapely.from_wkt(
        f"LINESTRING ({x0} {y0 + 50}, {x0 + 260} {y0 + 50})"), shapely.from_wkt(
        f"LINESTRING ({x0 + 100} {y0 + 50}, {x0 + 100} {y0 + 300})")]), 6, cap_style="flat")
    land = shapely.area(shapely.difference(district, streets))
    for inputs in ({"BLOCKS": blocks}, {"ROADS": sketch}):
        log = log_feedback()
        out = qgis_processing.run(ALG, dict(inputs, BOUNDARY=outline, METHOD=1, SEED=2,
                                            STREET_WIDTH=12, OUTPUT="memory:"),
                                  feedback=log)["OUTPUT"]
        parcel_rows, lots = layer_features(out)
        assert all(r["has_street_access"] for r in parcel_rows)
        assert abs(shapely.area(lots).sum() - land) < 0.005 * land, list(inputs)
        assert any("3 blocks lie on the boundary" in m for m in log.messages), log.messages
    plain = qgis_processing.run(ALG, {"BLOCKS": blocks, "METHOD": 1, "SEED": 2,
                                      "STREET_WIDTH": 12, "OUTPUT": "memory:"})["OUTPUT"]
    # without the boundary its edges are streets: 6 m kept along them
    assert shapely.area(layer_features(plain)[1]).sum() < land - 0.9 * 6 * district.length
