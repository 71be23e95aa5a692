"""Example databases: GeoPackage round trip, validation, retrieval (plugin/retrieval/database.py)."""
import os
import sqlite3

import numpy as np
import pandas as pd
import pytest
import shapely

from test_fragments import levelled_grid
from urban_synthesis.plugin.retrieval import database as db
from urban_synthesis.plugin.network import fragments as fr
from urban_synthesis.plugin.retrieval import shape_context as sc
from urban_synthesis.plugin.core.progress import InputError

CRS = "EPSG:32635"


def rotation(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def ramp_dem():
    x = -10 + 2.5 + 5 * np.arange(86)
    y = 410 - 2.5 - 5 * np.arange(86)
    return sc.DemGrid(0.1 * x[None, :] + 0.05 * y[:, None], (-10, 5, 0, 410, 0, -5))


@pytest.fixture(scope="module")
def fragment_db(tmp_path_factory):
    lines, levels = levelled_grid()
    dem = ramp_dem()
    frags = fr.extract_fragments(lines, levels, dem=dem)
    path = tmp_path_factory.mktemp("db") / "fragments.gpkg"
    db.write_fragment_database(str(path), frags, CRS, source="levelled grid", elevation=dem)
    return path, frags


def sample_blocks():
    """Seven distinct block shapes with a few footprints each."""
    rng = np.random.default_rng(4)
    shapes = [shapely.box(0, 0, 100, 60), shapely.box(0, 0, 150, 40),
              shapely.Polygon([(0, 0), (120, 0), (60, 90)]),
              shapely.Polygon([(0, 0), (80, 0), (110, 50), (40, 90), (-20, 50)]),
              shapely.Point(0, 0).buffer(55, quad_segs=6),
              shapely.Polygon([(0, 0), (140, 0), (140, 30), (40, 30), (40, 100), (0, 100)]),
              shapely.box(0, 0, 70, 70)]
    blocks, buildings, owner = [], [], []
    for k, s in enumerate(shapes):
        s = shapely.affinity.translate(s, 300 * k, 0)
        blocks.append(s)
        inner = s.buffer(-12)
        for _ in range(3):
            p = shapely.Point(inner.centroid.x + rng.uniform(-15, 15),
                              inner.centroid.y + rng.uniform(-10, 10))
            buildings.append(p.buffer(6, quad_segs=1))
            owner.append(10 + k)
    return np.array(blocks, dtype=object), np.array(buildings, dtype=object), np.array(owner)


@pytest.fixture(scope="module")
def block_db(tmp_path_factory):
    blocks, buildings, owner = sample_blocks()
    attrs = pd.DataFrame({"height_m": np.arange(len(buildings), dtype=float) + 3,
                          "levels": [1, None, 3] * 7, "building_type": ["house"] * 21,
                          "height_estimated": [True, False, True] * 7})
    path = tmp_path_factory.mktemp("db") / "blocks.gpkg"
    db.write_block_database(str(path), blocks, buildings, owner, CRS,
                            block_ids=np.arange(10, 17), building_attributes=attrs,
                            source="synthetic blocks")
    return path


# --------------------------------------------------------------------------- round trip

def test_fragment_database_round_trip(fragment_db):
    import pyogrio

    path, frags = fragment_db
    layers = dict(pyogrio.list_layers(path))
    assert layers["fragments"] == "Polygon" and layers["fragment_streets"] == "LineString"
    assert {"descriptors", "relief", "metadata"} <= set(layers)
    d = db.load_fragment_database(path)
    assert len(d) == len(frags) == 13
    assert d.metadata["format"] == "urbansynth-fragments" and d.metadata["format_version"] == "1"
    assert d.crs == CRS and d.metadata["source"] == "levelled grid"
    assert d.metadata["n_samples"] == "100" and float(d.metadata["sc_scale_m"]) > 0
    assert np.array_equal(d.ids, frags.table.fragment_id)
    assert np.array_equal(d.levels, frags.table.level)
    assert np.array_equal(d.table.is_block, frags.table.is_block)
    assert shapely.equals(d.geometry, frags.geometry).all()
    assert len(d.street_geometry) == len(frags.street_geometry)
    assert len(d.streets_of(1)) == 2
    # descriptors: arrays ready for retrieval, equal to a fresh computation
    desc = d.descriptors
    assert desc.samples.shape == (13, 100, 2) and desc.counts.shape == (13, 100, 40)
    assert desc.slopes.shape == (13, 100, 40) and desc.slopes.dtype == np.float32
    fresh = db.compute_descriptors(frags.geometry, desc.scale, elevation=ramp_dem())
    assert np.array_equal(fresh.counts, desc.counts)
    assert np.allclose(fresh.samples, desc.samples)
    # relief patches come back per fragment
    heights, gt = d.relief[1]
    assert heights.shape == frags.patches[0].shape and gt[1] == 5.0
    assert np.allclose(heights, frags.patches[0])


def test_block_database_round_trip(block_db):
    d = db.load_block_database(block_db)
    assert len(d) == 7 and list(d.ids) == list(range(10, 17))
    assert d.metadata["format"] == "urbansynth-blocks" and d.metadata["n_buildings"] == "21"
    assert d.descriptors.slopes is None
    assert (d.table.n_buildings == 3).all()
    assert ((d.table.coverage > 0) & (d.table.coverage < 1)).all()
    geoms, rows = d.buildings_of(12)
    assert len(geoms) == 3 and set(rows.block_id) == {12}
    b = d.buildings
    assert b.levels.isna().sum() == 7 and b.height_estimated.dtype == bool
    assert list(b.building_type.unique()) == ["house"]


def test_block_database_footprints_are_multipolygons_as_the_layer_declares(block_db):
    """Polygon footprints (a cadastre, the output of 'Synthesize building footprints') went
    into the MultiPolygon 'buildings' layer as they were: a GeoPackage against the
    specification, and GDAL printed 'A geometry of type POLYGON is inserted into layer
    buildings of geometry type MULTIPOLYGON ...' on every such run (the promotion compared
    shapely's type ids with OGR's, off by one for polygons)."""
    from osgeo import ogr

    ds = ogr.Open(str(block_db))
    layer = ds.GetLayerByName("buildings")
    assert layer.GetGeomType() == ogr.wkbMultiPolygon
    kinds = {f.GetGeometryRef().GetGeometryType() for f in layer}
    assert kinds == {ogr.wkbMultiPolygon}, kinds


def test_buildings_drawn_either_way_round_give_the_same_database(tmp_path):
    """A shapefile stores outer rings clockwise, OSM ways run either way (24 of Helsinki's
    493 buildings counter-clockwise): the same buildings from a shapefile and from memory
    gave two databases. Both are written counter-clockwise, as the blocks are."""
    blocks, buildings, owner = sample_blocks()
    written = []
    for sign in (1.0, -1.0):
        turned = [shapely.geometry.polygon.orient(b, sign) for b in buildings]
        path = tmp_path / f"db{sign:+.0f}.gpkg"
        db.write_block_database(str(path), blocks, turned, owner, CRS, block_ids=range(10, 17))
        written.append(db.load_block_database(path).building_geometry)
    assert shapely.to_wkb(written[0]).tolist() == shapely.to_wkb(written[1]).tolist()
    outer = shapely.get_exterior_ring(shapely.get_geometry(written[0], 0))
    assert shapely.is_ccw(outer).all()


def test_writing_replaces_an_existing_file(tmp_path):
    blocks, buildings, owner = sample_blocks()
    path = tmp_path / "blocks.gpkg"
    path.write_bytes(b"old content")
    db.write_block_database(str(path), blocks[:2], buildings[:6], owner[:6] - 9, CRS)
    db.write_block_database(str(path), blocks[:3], buildings[:6], owner[:6] - 9, CRS)
    assert len(db.load_block_database(path)) == 3
    assert [p.name for p in tmp_path.iterdir()] == ["blocks.gpkg"]  # no temporary files left


def test_bad_block_inputs_are_input_errors(tmp_path):
    blocks, buildings, owner = sample_blocks()
    with pytest.raises(InputError, match="not among the blocks"):
        db.write_block_database(str(tmp_path / "x.gpkg"), blocks, buildings, owner + 100, CRS)
    with pytest.raises(InputError, match="unique"):
        db.write_block_database(str(tmp_path / "x.gpkg"), blocks, buildings, owner, CRS,
                                block_ids=np.zeros(7))
    with pytest.raises(InputError, match="no blocks"):
        db.write_block_database(str(tmp_path / "x.gpkg"), [], [], [], CRS)
    assert not (tmp_path / "x.gpkg").exists()


# --------------------------------------------------------------------------- validation

def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        db.load_block_database(tmp_path / "nope.gpkg")


def test_garbage_file(tmp_path):
    path = tmp_path / "garbage.gpkg"
    path.write_bytes(os.urandom(4096))
    with pytest.raises(InputError, match="not a GeoPackage"):
        db.load_fragment_database(path)


def test_damaged_geopackage(tmp_path, block_db):
    data = bytearray(block_db.read_bytes())
    # keep the SQLite header, overwrite the schema and data pages with garbage
    data[100:] = os.urandom(len(data) - 100)
    path = tmp_path / "damaged.gpkg"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="damaged|not a GeoPackage"):
        db.load_block_database(path)


def test_plain_sqlite_and_foreign_geopackage(tmp_path):
    plain = tmp_path / "plain.gpkg"
    con = sqlite3.connect(plain)
    con.execute("CREATE TABLE t (a)")
    con.commit()
    con.close()
    with pytest.raises(InputError, match="SQLite database but not a GeoPackage"):
        db.load_block_database(plain)
    from conftest import BUBENEC

    with pytest.raises(InputError, match="not an Urban Synthesis"):
        db.load_block_database(BUBENEC)


def test_wrong_kind_and_newer_version(tmp_path, fragment_db, block_db):
    path, _ = fragment_db
    with pytest.raises(InputError, match="is a fragment database; a block database"):
        db.load_block_database(path)
    with pytest.raises(InputError, match="is a block database; a fragment database"):
        db.load_fragment_database(block_db)
    newer = tmp_path / "newer.gpkg"
    newer.write_bytes(block_db.read_bytes())
    con = sqlite3.connect(newer)
    con.execute("UPDATE metadata SET value = '2' WHERE key = 'format_version'")
    con.commit()
    con.close()
    with pytest.raises(InputError, match="format version 2; this plugin reads versions 1 to 1"):
        db.load_block_database(newer)


# --------------------------------------------------------------------------- retrieval

def test_each_block_retrieves_itself_when_moved(block_db):
    d = db.load_block_database(block_db)
    for k in range(len(d)):
        r_true, t_true = rotation(0.4 + k), np.array([5000.0 * k, -2000.0])
        query = sc.transform_geometries([d.geometry[k]], r_true, t_true)[0]
        matches = d.query(query, n_best=3)
        best = matches[0]
        assert best.index == k and best.id == d.ids[k]
        # (a regular polygon puts samples exactly on angular bin borders, where round-off
        # after the rotation flips a few counts: a small cost, far below the next shape's)
        assert best.cost < 0.05 and best.cost < 0.1 * matches[1].cost
        assert [m.cost for m in matches] == sorted(m.cost for m in matches)
        # the alignment maps the example (and so its footprints) onto the query
        assert np.allclose(best.rotation, r_true, atol=1e-6) and best.rms < 1e-6
        assert best.transform([d.geometry[k]])[0].symmetric_difference(query).area < 1e-3
        footprints, _ = d.buildings_of(best.id)
        moved = best.transform(footprints)
        expected = sc.transform_geometries(footprints, r_true, t_true)
        assert (shapely.area(shapely.symmetric_difference(moved, expected)) < 1e-3).all()


def test_prefilter_keeps_the_nearest_candidates(block_db):
    d = db.load_block_database(block_db)
    m = d.table.iloc[3]
    rows = d.prefilter(3, area=m.area_m2, aspect=m.aspect_ratio, perimeter=m.perimeter_m)
    assert len(rows) == 3 and rows[0] == 3
    assert len(d.prefilter(50, area=1000.0, aspect=0.5)) == 7
    with pytest.raises(InputError):
        d.prefilter(0, area=1000.0, aspect=0.5)


def test_fragment_retrieval_by_level_and_slope(fragment_db):
    path, frags = fragment_db
    d = db.load_fragment_database(path)
    levels = d.levels
    # a level 1 quarter, moved: retrieved among level 1 fragments, itself first
    k = int(np.flatnonzero(levels == 1)[0])
    q = sc.transform_geometries([d.geometry[k]], rotation(0.0), np.array([0.0, 0.0]))[0]
    best = d.query_best(q, level=1, relief=float(d.table.relief_m[k]))
    assert d.levels[best.index] == 1 and best.cost == pytest.approx(0, abs=1e-3)
    # the four quarters have the same shape: only the slope term can tell them apart; with
    # the database's own terrain the query's quarter wins, without it any quarter may
    for k in np.flatnonzero(levels == 1):
        matches = d.query(d.geometry[k], level=1, elevation=ramp_dem(), gamma=0.5, n_best=4)
        assert matches[0].index == k
    # a level absent from the database falls back to the nearest level present
    assert (d.levels[d.prefilter(5, level=7, area=1e4, aspect=1.0)] == 2).all()


def test_retrieval_is_repeatable(block_db):
    """The same query gives the same best block every time (speed: bench_foundation)."""
    d = db.load_block_database(block_db)
    q = sc.transform_geometries([d.geometry[2]], rotation(1.0), np.array([10.0, 10.0]))[0]
    first = d.query_best(q)
    assert all(d.query_best(q).index == first.index == 2 for _ in range(3))
