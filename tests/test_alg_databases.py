"""urbansynth:buildfragmentdatabase and :buildblockdatabase through real QGIS."""

import numpy as np
import pytest

from conftest import bubenec_layer, helsinki_layer, run_qgis_process
from helpers import log_feedback


@pytest.fixture(scope="module")
def helsinki_roads(qgis_processing):
    """Helsinki roads with levels, from the real hierarchy algorithm."""
    return qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": "memory:",
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]


@pytest.fixture(scope="module")
def helsinki_blocks(qgis_processing):
    """Helsinki blocks with buildings (block_id, height_m ...), from the real algorithm."""
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": helsinki_layer("lines"), "BUILDINGS": helsinki_layer("multipolygons"),
        "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"})
    return out["OUTPUT"], out["OUTPUT_BUILDINGS"]


# --------------------------------------------------------------------------- fragments

def test_helsinki_fragment_database(qgis_processing, helsinki_roads, tmp_path):
    from urban_synthesis.plugin.retrieval import database

    roads = helsinki_roads
    out = tmp_path / "helsinki_fragments.gpkg"
    log = log_feedback()
    res = qgis_processing.run("urbansynth:buildfragmentdatabase", {
        "ROADS": roads, "OUTPUT": str(out)}, feedback=log)
    assert res["OUTPUT"] == str(out)
    d = database.load_fragment_database(out)
    assert len(d) == res["N_FRAGMENTS"] >= 50
    assert d.crs == "EPSG:32635"  # the metric working CRS (UTM 35N), recorded
    counts = d.table.groupby("level").size()
    assert counts.index.min() == 0 and len(counts) >= 2
    assert any(m.startswith("Level 0:") for m in log.messages)
    # the log names the file written, not the run's staging copy (gone after the run)
    assert any(m.startswith("Fragment database written: helsinki_fragments.gpkg")
               for m in log.messages)
    assert not any(".urbansynth-run-" in m for m in log.messages)
    assert d.table.is_block.any() and (~d.table.is_block).any()
    assert (d.streets.level.to_numpy() == d.table.set_index("fragment_id").level.loc[
        d.streets.fragment_id].to_numpy() + 1).all()
    assert d.relief is None and d.descriptors.slopes is None
    # the example's dead-end share, for the synthesis to steer to: Helsinki's, its extract's
    # cut ends on the hull not counted (0.18; counted, the share would be 0.28)
    assert 0.12 < float(d.metadata["dead_end_share"]) < 0.24
    assert any(m.startswith("Dead-end share of the example") for m in log.messages)
    # a database fragment, moved, is retrieved as itself
    from urban_synthesis.plugin.retrieval import shape_context as sc

    k = int(np.argmax(d.table.area_m2.to_numpy() * (d.levels == 1)))
    q = sc.transform_geometries([d.geometry[k]], np.array([[0.0, -1.0], [1.0, 0.0]]),
                                np.array([100.0, 50.0]))[0]
    assert d.query_best(q, level=1).index == k


def test_fragment_database_with_dem(qgis_processing, tmp_path):
    """A synthetic DEM (GeoTIFF in EPSG:3857, a hill) under Bubeneč's streets."""
    from osgeo import gdal, osr

    from urban_synthesis.plugin.retrieval import database

    roads = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": bubenec_layer("streets"), "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": None})
    layer = roads["OUTPUT"]
    ext = layer.extent()
    dem_path = tmp_path / "hill.tif"
    nx, ny, cell = 120, 120, (ext.width() + 200) / 120
    x0, y1 = ext.xMinimum() - 100, ext.yMaximum() + 100
    xs = x0 + cell * (np.arange(nx) + 0.5)
    ys = y1 - cell * (np.arange(ny) + 0.5)
    cx, cy = ext.center().x(), ext.center().y()
    r2 = (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2
    hill = 200 + 30 * np.exp(-r2 / (2 * 300.0 ** 2))
    ds = gdal.GetDriverByName("GTiff").Create(str(dem_path), nx, ny, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0, cell, 0, y1, 0, -cell))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(3857)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(hill.astype(np.float32))
    ds = None
    out = tmp_path / "bubenec_fragments.gpkg"
    res = qgis_processing.run("urbansynth:buildfragmentdatabase", {
        "ROADS": layer, "DEM": str(dem_path), "OUTPUT": str(out)})
    d = database.load_fragment_database(out)
    assert len(d) == res["N_FRAGMENTS"] >= 1
    assert d.metadata["has_relief"] == "1" and d.descriptors.slopes is not None
    relief = d.table.relief_m.to_numpy()
    assert (relief > 0).all() and (relief < 30).all()
    assert (d.table.elevation_m > 200).all() and (d.table.elevation_m < 231).all()
    heights, gt = d.relief[int(d.ids[0])]
    assert np.nanmax(heights) <= 231 and gt[1] == 5.0
    assert np.abs(d.descriptors.slopes).max() < 0.5  # a gentle hill


def test_fragment_errors(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException, QgsVectorLayer

    # no level field: raw streets, with the tool that gives them one named
    with pytest.raises(QgsProcessingException,
                       match="streets.*no field 'level'.*run 'Extract road hierarchy'"):
        qgis_processing.run("urbansynth:buildfragmentdatabase", {
            "ROADS": bubenec_layer("streets"), "OUTPUT": str(tmp_path / "a.gpkg")})
    # levels, but no closed fragment
    lines = QgsVectorLayer("LineString?crs=EPSG:3067&field=level:integer", "open roads", "memory")
    from qgis.core import QgsFeature, QgsGeometry

    feats = []
    for wkt, level in [("LINESTRING(0 0, 500 0)", 0), ("LINESTRING(250 0, 250 300)", 1)]:
        f = QgsFeature(lines.fields())
        f.setGeometry(QgsGeometry.fromWkt(wkt))
        f.setAttributes([level])
        feats.append(f)
    lines.dataProvider().addFeatures(feats)
    with pytest.raises(QgsProcessingException, match="open roads.*no closed fragment"):
        qgis_processing.run("urbansynth:buildfragmentdatabase", {
            "ROADS": lines, "OUTPUT": str(tmp_path / "b.gpkg")})
    assert not (tmp_path / "b.gpkg").exists()
    # empty layer, polygons instead of lines
    empty = QgsVectorLayer("LineString?crs=EPSG:3067&field=level:integer", "empty roads", "memory")
    with pytest.raises(QgsProcessingException, match="empty roads.*empty"):
        qgis_processing.run("urbansynth:buildfragmentdatabase", {
            "ROADS": empty, "OUTPUT": str(tmp_path / "c.gpkg")})
    with pytest.raises(QgsProcessingException):
        qgis_processing.run("urbansynth:buildfragmentdatabase", {
            "ROADS": bubenec_layer("plots"), "OUTPUT": str(tmp_path / "d.gpkg")})


def test_fragment_cancel(qgis_processing, helsinki_roads, tmp_path):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    fb = QgsProcessingFeedback()
    fb.cancel()
    with pytest.raises(QgsProcessingException, match="Cancel"):
        qgis_processing.run("urbansynth:buildfragmentdatabase", {
            "ROADS": helsinki_roads, "OUTPUT": str(tmp_path / "x.gpkg")}, feedback=fb)
    assert not (tmp_path / "x.gpkg").exists()


# --------------------------------------------------------------------------- blocks

def test_helsinki_block_database(qgis_processing, helsinki_blocks, tmp_path):
    from urban_synthesis.plugin.retrieval import database

    blocks, buildings = helsinki_blocks
    out = tmp_path / "helsinki_blocks.gpkg"
    out.write_bytes(b"an older file is replaced")
    log = log_feedback()
    res = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": str(out)}, feedback=log)
    d = database.load_block_database(out)
    assert len(d) == res["N_BLOCKS"] == blocks.featureCount()
    in_block = sum(1 for f in buildings.getFeatures() if f["in_block"])
    assert res["N_BUILDINGS"] == len(d.buildings) == in_block
    assert list(d.ids) == list(range(1, len(d) + 1))  # extractblocks' block_id
    assert int(d.table.n_buildings.sum()) == in_block
    assert {"height_m", "levels", "building_type", "height_estimated"} <= set(d.buildings.columns)
    # attributes are carried over: as many heights as the blocks' buildings have
    def has_height(f):
        h = f["height_m"]
        return h is not None and not (hasattr(h, "isNull") and h.isNull()) and h == h

    with_height = sum(1 for f in buildings.getFeatures() if f["in_block"] and has_height(f))
    assert d.buildings.height_m.notna().sum() == with_height > 50
    assert any("left out" in m for m in log.messages)  # buildings outside every block
    assert any(m.startswith("Block database written: helsinki_blocks.gpkg")
               for m in log.messages)
    assert not any(".urbansynth-run-" in m for m in log.messages)
    # each stored block retrieves itself
    hits = 0
    for k in range(0, len(d), 5):
        hits += d.query_best(d.geometry[k]).index == k
    assert hits == len(range(0, len(d), 5))
    # performance budget of the foundation issue: the whole chain well under 5 s


def test_bubenec_block_database_assigns_by_location(qgis_processing, tmp_path):
    """Raw Bubeneč buildings have no block_id: they are assigned to blocks by location."""
    from urban_synthesis.plugin.retrieval import database

    blocks = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": "memory:"})["OUTPUT"]
    out = tmp_path / "bubenec_blocks.gpkg"
    log = log_feedback()
    res = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": bubenec_layer("buildings"), "OUTPUT": str(out)},
        feedback=log)
    d = database.load_block_database(out)
    assert len(d) == blocks.featureCount() >= 5
    assert 50 < res["N_BUILDINGS"] <= 144
    assert d.crs != "EPSG:3857"  # Web Mercator is replaced by a metric UTM zone
    assert (d.table.coverage[d.table.n_buildings > 0] > 0.05).all()


def test_an_osm_multipolygons_layer_gives_its_buildings_only(qgis_processing,
                                                             helsinki_blocks, tmp_path):
    """The raw OSM multipolygons as BUILDINGS (the help's 'OSM multipolygons' of the district
    model): only the polygons with a building value are stored, with their heights, levels
    and types read from the tags, as 'Extract city blocks' gives them. Parks, land use and
    water were stored as buildings (Liechtenstein: 2,671 for 2,469, one of 84 ha that the
    footprint synthesis placed as a building) and every height was lost."""
    from urban_synthesis.plugin.retrieval import database

    blocks, buildings = helsinki_blocks
    log = log_feedback()
    raw = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": helsinki_layer("multipolygons"),
        "OUTPUT": str(tmp_path / "raw.gpkg")}, feedback=log)
    prepared = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "prepared.gpkg")})
    d = database.load_block_database(tmp_path / "raw.gpkg")
    p = database.load_block_database(tmp_path / "prepared.gpkg")
    assert raw["N_BUILDINGS"] == prepared["N_BUILDINGS"] == len(d.buildings)
    assert d.buildings.area_m2.max() == pytest.approx(p.buildings.area_m2.max())
    assert d.buildings.height_m.notna().sum() == p.buildings.height_m.notna().sum() > 50
    assert (d.buildings.building_type.value_counts().to_dict()
            == p.buildings.building_type.value_counts().to_dict())
    assert any("without a 'building' value skipped" in m for m in log.messages)


def test_buildings_naming_a_block_elsewhere_are_placed_by_location(qgis_processing,
                                                                   helsinki_blocks, tmp_path):
    """Blocks numbered anew (extracted again, or edited) with the buildings of the earlier
    run: a block_id that names a block the building does not lie in is not trusted, the
    building is assigned by location, with a warning. Every building was stored in the block
    its stale id named (0 of 295 inside their stored block), and the footprint synthesis on
    that database made 6 footprints for 314, all others 'outside their block'."""
    import shapely

    from urban_synthesis.plugin.retrieval import database

    blocks, buildings = helsinki_blocks
    renumbered = qgis_processing.run("native:fieldcalculator", {
        "INPUT": blocks, "FIELD_NAME": "block_id", "FIELD_TYPE": 1, "FIELD_LENGTH": 10,
        "FORMULA": f'{blocks.featureCount() + 1} - "block_id"', "OUTPUT": "memory:"})["OUTPUT"]
    log = log_feedback()
    res = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": renumbered, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "r.gpkg")},
        feedback=log)
    whole = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "w.gpkg")})
    d = database.load_block_database(tmp_path / "r.gpkg")
    assert res["N_BUILDINGS"] == whole["N_BUILDINGS"] == len(d.buildings)
    block_of = dict(zip(d.ids, d.geometry))
    inside = shapely.intersects(np.asarray(d.building_geometry, dtype=object),
                                np.array([block_of[i] for i in d.buildings.block_id],
                                         dtype=object))
    assert inside.all(), f"{(~inside).sum()} buildings stored in a block they do not touch"
    assert any("outside the block" in w and "assigned by location" in w for w in log.warnings)
    # ids that are right raise no warning
    log = log_feedback()
    qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "w2.gpkg")},
        feedback=log)
    assert not any("outside the block" in w for w in log.warnings)


def test_a_dissolved_block_layer_gives_one_block_per_face(qgis_processing, helsinki_blocks,
                                                           tmp_path):
    """Helsinki's blocks dissolved into one multi-part feature, its buildings still naming
    their old blocks: each part is a block, the buildings found by location (it stored the
    largest part and said 'N of M buildings lie in no block'); a block id field that is not there
    is an error naming it (it fell back silently)."""
    from qgis.core import QgsProcessingException

    from urban_synthesis.plugin.retrieval import database

    blocks, buildings = helsinki_blocks
    one = qgis_processing.run("native:dissolve", {"INPUT": blocks, "OUTPUT": "memory:"})["OUTPUT"]
    assert one.featureCount() == 1
    log = log_feedback()
    res = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": one, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "d.gpkg")},
        feedback=log)
    d = database.load_block_database(tmp_path / "d.gpkg")
    whole = qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": str(tmp_path / "w.gpkg")})
    # the blocks touch: the dissolved feature's parts are the blocks' connected groups
    n_parts = next(one.getFeatures()).geometry().constGet().numGeometries()
    assert n_parts > 1 and len(d) == n_parts
    assert res["N_BUILDINGS"] >= 0.95 * whole["N_BUILDINGS"]
    assert any("split into" in m and "one face each" in m for m in log.messages)
    with pytest.raises(QgsProcessingException, match="no field 'blok_id'"):
        qgis_processing.run("urbansynth:buildblockdatabase", {
            "BLOCKS": blocks, "BUILDINGS": buildings, "BLOCK_ID_FIELD": "blok_id",
            "OUTPUT": str(tmp_path / "e.gpkg")})


def test_a_shapefile_chain_keeps_the_fields_it_can_tell_apart(qgis_processing, tmp_path):
    """Blocks and buildings written as shapefiles cut field names to ten characters: the
    database reads height_estimated from 'height_est' (it was lost without a word), and
    building_type apart from building_tag (both cut to 'building_t', the second numbered
    'building_1' by GDAL) by the full names extractblocks keeps as their aliases."""
    from urban_synthesis.plugin.retrieval import database

    log = log_feedback()
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": helsinki_layer("lines"), "BUILDINGS": helsinki_layer("multipolygons"),
        "OUTPUT": str(tmp_path / "blocks.shp"), "OUTPUT_BUILDINGS": str(tmp_path / "b.shp")},
        feedback=log)
    # OSM's other_tags run past dBase's 254 bytes: cut, and said (GDAL cut them silently;
    # a declared width of 254 refused them)
    cut = [w for w in log.warnings if "text values hold at most 254 bytes" in w]
    assert len(cut) == 1 and cut[0].startswith("Output OUTPUT_BUILDINGS"), log.warnings
    log = log_feedback()
    qgis_processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": str(tmp_path / "blocks.shp"), "BUILDINGS": str(tmp_path / "b.shp"),
        "OUTPUT": str(tmp_path / "db.gpkg")}, feedback=log)
    d = database.load_block_database(tmp_path / "db.gpkg")
    assert d.buildings.height_estimated.notna().sum() > 50
    assert any("'height_estimated' read from 'height_est'" in m for m in log.messages)
    assert not any("cannot be told apart" in m for m in log.messages)
    assert any("'building_tag' read from 'building_1'" in m for m in log.messages)
    assert d.buildings.building_type.notna().sum() > 50


def test_block_errors(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException, QgsVectorLayer

    empty = QgsVectorLayer("Polygon?crs=EPSG:3067&field=block_id:integer", "empty blocks", "memory")
    with pytest.raises(QgsProcessingException, match="empty blocks.*empty"):
        qgis_processing.run("urbansynth:buildblockdatabase", {
            "BLOCKS": empty, "BUILDINGS": bubenec_layer("buildings"),
            "OUTPUT": str(tmp_path / "a.gpkg")})
    with pytest.raises(QgsProcessingException):
        qgis_processing.run("urbansynth:buildblockdatabase", {
            "BLOCKS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
            "OUTPUT": str(tmp_path / "b.gpkg")})
    # blocks far away from the buildings: nothing to store
    far = QgsVectorLayer("Polygon?crs=EPSG:3067", "far blocks", "memory")
    from qgis.core import QgsFeature, QgsGeometry

    f = QgsFeature(far.fields())
    f.setGeometry(QgsGeometry.fromWkt("POLYGON((0 0, 100 0, 100 100, 0 100, 0 0))"))
    far.dataProvider().addFeatures([f])
    with pytest.raises(QgsProcessingException, match="no building lies in one of the blocks"):
        qgis_processing.run("urbansynth:buildblockdatabase", {
            "BLOCKS": far, "BUILDINGS": bubenec_layer("buildings"),
            "OUTPUT": str(tmp_path / "c.gpkg")})


# --------------------------------------------------------------------------- qgis_process

def test_qgis_process_fragment_database_exits_zero(tmp_path):
    from urban_synthesis.plugin.retrieval import database

    roads = tmp_path / "roads.gpkg"
    code, _, err = run_qgis_process("extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": roads})
    assert code == 0, err
    out = tmp_path / "fragments.gpkg"
    code, result, err = run_qgis_process("buildfragmentdatabase", {
        "ROADS": roads, "OUTPUT": out})
    assert code == 0, err
    assert result["results"]["N_FRAGMENTS"] >= 50
    assert len(database.load_fragment_database(out)) == result["results"]["N_FRAGMENTS"]


def test_qgis_process_block_database_exits_zero(tmp_path):
    from urban_synthesis.plugin.retrieval import database

    blocks, buildings = tmp_path / "blocks.gpkg", tmp_path / "buildings.gpkg"
    code, _, err = run_qgis_process("extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
        "OUTPUT": blocks, "OUTPUT_BUILDINGS": buildings})
    assert code == 0, err
    out = tmp_path / "blocks_db.gpkg"
    code, result, err = run_qgis_process("buildblockdatabase", {
        "BLOCKS": blocks, "BUILDINGS": buildings, "OUTPUT": out})
    assert code == 0, err
    d = database.load_block_database(out)
    assert len(d) == result["results"]["N_BLOCKS"] >= 5
    assert len(d.buildings) == result["results"]["N_BUILDINGS"] > 50
