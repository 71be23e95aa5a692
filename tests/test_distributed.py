"""Work on Dask (plugin.scale.distributed, plugin.scale.cli): on a local cluster of 2 worker processes,
footprints (both methods) and building attributes (medoid and random) from partitions of
a GeoPackage source, and StreetGAN tiles, give exactly the serial result.

Inputs are built here from data/examples: the Helsinki block database (blocks +
footprints through the engine, as in test_footprints) and, as targets, Bubeneč's street
blocks plus the Helsinki blocks written to a GeoPackage in WGS 84 (so that every
partition reprojects to UTM on its own) together with the Helsinki roads; for attributes,
the Helsinki OSM buildings (a third of the known heights hidden) as targets and examples;
for StreetGAN, the shipped Helsinki generator.
"""
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pyogrio
import pytest
import shapely

from conftest import ROOT
from helpers import helsinki_roads, same_footprints
from urban_synthesis.plugin.network import blocks
from urban_synthesis.plugin.scale import distributed
from urban_synthesis.plugin.buildings import footprints
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.core.progress import InputError


@pytest.fixture(scope="module")
def district(tmp_path_factory):
    import geopandas as gpd
    from test_footprints import helsinki_example_db

    tmp = tmp_path_factory.mktemp("dist")
    db_path = tmp / "helsinki_blocks.gpkg"
    helsinki_example_db(db_path)
    df = helsinki_roads()
    graph = roads.clean_network(df.geometry.values, df.highway.values, z_layer=df.z.values)
    r = blocks.extract_blocks(graph)
    src = tmp / "targets.gpkg"
    # shuffled block ids, so that the output ids are provably the layer's
    ids = np.random.default_rng(5).permutation(len(r.geometry)) + 100
    gpd.GeoDataFrame({"block_id": ids}, geometry=list(r.geometry), crs=32635) \
        .to_crs(4326).to_file(src, layer="blocks", driver="GPKG", engine="pyogrio")
    gpd.GeoDataFrame({"n": np.arange(len(graph.geometry))}, geometry=list(graph.geometry),
                     crs=32635).to_file(src, layer="roads", driver="GPKG", engine="pyogrio")
    # a small layer for the command-line runs (the 16 blocks nearest the first one)
    c = shapely.centroid(r.geometry)
    near = np.argsort(shapely.distance(c, c[0]), kind="stable")[:16]
    gpd.GeoDataFrame({"block_id": ids[near]}, geometry=list(r.geometry[near]), crs=32635) \
        .to_crs(4326).to_file(src, layer="small", driver="GPKG", engine="pyogrio")
    return dict(db=db_path, src=src, ids=ids)


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


def _job(district, method, with_roads=True, n_best=2):
    src = district["src"]
    b = distributed.read_blocks(distributed.Source(str(src), "blocks"))
    rd = distributed.RoadIndex(distributed.read_lines(distributed.Source(str(src), "roads"),
                                                      b.work_crs)) if with_roads else None
    from urban_synthesis.plugin.retrieval import database

    ex = footprints.prepare_examples(database.load_block_database(district["db"]), "helsinki")
    return b, distributed.FootprintJob([ex], rd, method, seed=7, n_best=n_best)


def test_source_parsing_and_partitions():
    assert distributed.parse_source("a/b.gpkg:blocks") == distributed.Source("a/b.gpkg", "blocks")
    assert distributed.parse_source("a/b.gpkg|layername=x|subset=1") == \
        distributed.Source("a/b.gpkg", "x")
    assert distributed.parse_source("a/b.gpkg") == distributed.Source("a/b.gpkg", None)
    pg = distributed.parse_source("PG:dbname=city host=db |layername=public.blocks")
    assert pg == distributed.Source("PG:dbname=city host=db", "public.blocks")
    # a 20 x 20 grid of squares in 4 Z-order partitions: the 4 quadrants, exactly
    xy = np.array([(x, y) for y in range(20) for x in range(20)], dtype=float)
    grid = shapely.box(xy[:, 0], xy[:, 1], xy[:, 0] + 1, xy[:, 1] + 1)
    parts = distributed.spatial_partitions(grid, 4)
    assert sorted(np.concatenate(parts).tolist()) == list(range(400))
    quad = [set(((xy[p, 0] >= 10) * 1 + (xy[p, 1] >= 10) * 2).tolist()) for p in parts]
    assert sorted(len(q) for q in quad) == [1, 1, 1, 1] and \
        sorted(q.pop() for q in quad) == [0, 1, 2, 3]


def test_metric_crs_rule():
    assert distributed.metric_crs("EPSG:4326", (24.9, 60.1, 25.0, 60.2)) == "EPSG:32635"
    assert distributed.metric_crs("EPSG:3857", (14.3, 50.0, 14.4, 50.1)) == "EPSG:32633"
    assert distributed.metric_crs("EPSG:4326", (-70.7, -33.5, -70.6, -33.4)) == "EPSG:32719"
    kept = distributed.metric_crs("EPSG:32635", (24.9, 60.1, 25.0, 60.2))
    from pyproj import CRS
    assert CRS.from_user_input(kept) == CRS.from_epsg(32635)


@pytest.mark.parametrize("method", footprints.METHODS)
def test_distributed_equals_serial(district, client, method):
    b, job = _job(district, method)
    serial = distributed.footprints_serial(b, job)
    # the serial reference is the plugin's own driver on the blocks in layer order
    assert len(serial.geometry) > 100
    assert serial.table.block_id.isin(district["ids"]).all()
    assert serial.table.source_block.nunique() > 5
    # few large partitions for one method, one per 2 blocks for the other
    parts = 5 if method == "transfer" else len(b) // 2
    dist = distributed.footprints_distributed(client, b, job, n_partitions=parts)
    assert same_footprints(serial, dist) is None
    # block statistics agree too (all but the timing)
    cols = [c for c in serial.blocks.columns if c != "seconds"]
    pd.testing.assert_frame_equal(serial.blocks[cols], dist.blocks[cols], check_dtype=False)


def test_roads_and_seed_matter(district):
    """The comparison above is not vacuous: roads and the seed change the result."""
    b, job = _job(district, "transfer")
    sub = distributed.BlockTable(b.source, b.fids[:12], b.geometry[:12], b.block_ids[:12],
                                 b.crs, b.work_crs)
    base = distributed.footprints_serial(sub, job)
    other_seed = distributed.footprints_serial(sub, distributed.FootprintJob(
        job.examples, job.roads, "transfer", seed=8, n_best=2))
    assert same_footprints(base, other_seed) is not None
    no_roads = distributed.footprints_serial(sub, distributed.FootprintJob(
        job.examples, None, "transfer", seed=7, n_best=2))
    assert same_footprints(base, no_roads) is not None


def test_cli_end_to_end(district, tmp_path):
    out = tmp_path / "fp.gpkg"
    cmd = [sys.executable, "-m", "urban_synthesis.plugin.scale.cli", "footprints",
           "--blocks", f"{district['src']}:small", "--roads", f"{district['src']}:roads",
           "--db", str(district["db"]), "--method", "resynthesis", "--seed", "3",
           "--out", str(out), "--workers", "2", "--partitions", "3"]
    env = {"PYTHONPATH": str(ROOT / "build" / "plugins"), "PATH": "/usr/bin:/bin"}
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert summary["mode"] == "dask (2 workers)"
    df = pyogrio.read_dataframe(out, layer="footprints")
    assert summary["blocks"] == 16
    assert len(df) == summary["footprints"] > 30
    assert df.crs.to_epsg() == 4326          # written back in the input CRS
    assert set(f for f, _ in footprints.OUTPUT_FIELDS) <= set(df.columns)
    g = shapely.make_valid(df.to_crs(32635).geometry.values)
    assert shapely.is_valid(df.geometry.values).all()
    # no two footprints overlap (legalise keeps 1 cm apart; WGS 84 rounding aside)
    tree = shapely.STRtree(g)
    a, c = tree.query(g, predicate="intersects")
    overlap = shapely.area(shapely.intersection(g[a[a < c]], g[c[a < c]]))
    assert overlap.sum() < 1e-3
    # equal to the serial run of the same CLI (compared after the same write)
    out0 = tmp_path / "fp0.gpkg"
    res0 = subprocess.run(cmd[:-4] + ["--out", str(out0), "--workers", "0"], cwd=ROOT,
                          capture_output=True, text=True, env=env, timeout=120)
    assert res0.returncode == 0, res0.stderr[-2000:]
    df0 = pyogrio.read_dataframe(out0, layer="footprints")
    assert (shapely.to_wkb(df0.geometry.values) == shapely.to_wkb(df.geometry.values)).all()
    pd.testing.assert_frame_equal(df0.drop(columns="geometry"), df.drop(columns="geometry"))


def test_cli_bad_input(district, tmp_path):
    env = {"PYTHONPATH": str(ROOT / "build" / "plugins"), "PATH": "/usr/bin:/bin"}
    base = [sys.executable, "-m", "urban_synthesis.plugin.scale.cli", "footprints",
            "--out", str(tmp_path / "x.gpkg")]
    res = subprocess.run(base + ["--blocks", f"{district['src']}:nosuch", "--db",
                                 str(district["db"])], cwd=ROOT, capture_output=True,
                         text=True, env=env, timeout=60)
    assert res.returncode == 2
    assert "has no layer 'nosuch'" in res.stderr and "blocks" in res.stderr
    res = subprocess.run(base + ["--blocks", f"{district['src']}:blocks", "--db",
                                 str(tmp_path / "missing.gpkg")], cwd=ROOT,
                         capture_output=True, text=True, env=env, timeout=60)
    assert res.returncode == 2 and "missing.gpkg" in res.stderr
    assert not (tmp_path / "x.gpkg").exists()


def test_engine_errors(district, tmp_path):
    with pytest.raises(InputError, match="no such file"):
        distributed.read_blocks(distributed.Source(str(tmp_path / "none.gpkg"), "blocks"))
    with pytest.raises(InputError, match="must be polygons"):
        distributed.read_blocks(distributed.Source(str(district["src"]), "roads"))
    b, job = _job(district, "transfer", with_roads=False)
    with pytest.raises(InputError, match="unknown method"):
        distributed.footprints_serial(b, distributed.FootprintJob(job.examples, None, "x"))


def test_a_layer_without_a_crs_is_refused_by_name(tmp_path):
    """Roads or example buildings without a CRS (a shapefile without its .prj, a GeoPackage
    layer of srs_id 0) beside blocks with one: they were used as if in the working CRS
    (roads in feet or degrees lay nowhere near the blocks, and the run went on without
    them); now refused by name, as the QGIS tools refuse them."""
    import geopandas as gpd

    from urban_synthesis.plugin.scale import cli

    line = shapely.LineString([(385000, 6671000), (385300, 6671000)])
    square = shapely.box(385000, 6671000, 385100, 6671100)
    shp = tmp_path / "roads_no_prj.shp"
    gpd.GeoDataFrame({"highway": ["residential"]}, geometry=[line]).to_file(shp)
    assert not shp.with_suffix(".prj").exists()
    undefined = tmp_path / "undefined.gpkg"
    pyogrio.write_dataframe(gpd.GeoDataFrame({"building": ["yes"]}, geometry=[square]),
                            undefined, layer="buildings")          # srs_id 0 in the file
    with pytest.raises(InputError, match="roads_no_prj.*no coordinate reference system"):
        distributed.read_lines(distributed.parse_source(str(shp)), "EPSG:32635")
    with pytest.raises(InputError, match="roads_no_prj.*no coordinate reference system"):
        cli._read_roads(str(shp), "EPSG:32635")
    with pytest.raises(InputError, match="undefined.*no coordinate reference system"):
        cli._read_buildings(str(undefined), "EPSG:32635")
    with pytest.raises(InputError, match="undefined.*no coordinate reference system"):
        distributed.read_blocks(distributed.parse_source(str(undefined)))


# --------------------------------------------------------------------------- StreetGAN tiles

def test_gan_tiles_equal_serial_image_and_network(client):
    from urban_synthesis.plugin.roads import streetgan

    gen = streetgan.load_model("streetgan_helsinki")
    # 23 x 29 noise cells in tiles of 6: 20 tasks, each with its margin of context
    assert len(streetgan.tile_plan(23, 29, 6)) == 20
    one = streetgan.generate(gen, 700, 900, seed=4, tile=6)
    dist = distributed.gan_generate_distributed(client, gen, 700, 900, seed=4, tile=6)
    assert dist.shape == one.shape == (700, 900) and dist.dtype == one.dtype
    assert np.array_equal(one, dist)
    assert dist.std() > 10          # a real image, not a constant
    # one onnxruntime thread per worker (as on a cluster) gives the same pixels
    single = distributed.gan_generate_distributed(client, gen, 700, 900, seed=4, tile=6,
                                                  threads=1)
    assert np.array_equal(one, single)
    other = distributed.gan_generate_distributed(client, gen, 700, 900, seed=5, tile=6)
    assert not np.array_equal(one, other)
    # the network over a 1.2 x 1 km target: identical edges and levels
    target = shapely.box(0, 0, 1200, 1000)
    a = streetgan.synthesize(target, gen, seed=2, tile=8)
    b = distributed.gan_synthesize_distributed(client, target, gen, seed=2, tile=8)
    assert np.array_equal(a.image, b.image)
    assert len(a.geometry) > 50
    assert (shapely.to_wkb(a.geometry) == shapely.to_wkb(b.geometry)).all()
    assert np.array_equal(a.level, b.level)


# --------------------------------------------------------------------------- attributes

@pytest.fixture(scope="module")
def buildings(tmp_path_factory):
    """Helsinki buildings in a WGS 84 GeoPackage (targets) and as examples with a third of
    the known heights hidden, with the drivable roads and arterials."""
    import geopandas as gpd
    from test_building_synthesis import helsinki_buildings

    g, attrs, rl, art, _ = helsinki_buildings()
    known = np.flatnonzero(np.isfinite(attrs.height_m.to_numpy(float)))
    hide = np.random.default_rng(0).choice(known, size=len(known) // 3, replace=False)
    shown = attrs.copy()
    shown.loc[hide, ["height_m", "levels"]] = np.nan
    src = tmp_path_factory.mktemp("attr") / "targets.gpkg"
    gpd.GeoDataFrame({"n": np.arange(len(g))}, geometry=list(g), crs=32635).to_crs(4326) \
        .to_file(src, layer="footprints", driver="GPKG", engine="pyogrio")
    fp = distributed.read_footprints(distributed.Source(str(src), "footprints"))
    return dict(fp=fp, g=g, attrs=shown, roads=rl, art=art, src=src, hide=hide,
                truth=attrs.height_m.to_numpy(float))


def _attr_job(b, mode="medoid", seed=3, roads=True):
    return distributed.AttributeJob(b["g"], b["attrs"], np.arange(1000, 1000 + len(b["g"])),
                                    b["roads"] if roads else None, b["art"] if roads else None,
                                    b["roads"], b["art"], k=9, seed=seed, min_height=3.0,
                                    max_height=60.0, choice_mode=mode)


@pytest.mark.parametrize("mode", ["medoid", "random"])
def test_attributes_distributed_equals_serial(buildings, client, mode):
    b = buildings
    job = _attr_job(b, mode)
    serial = distributed.attributes_serial(b["fp"], job)
    dist = distributed.attributes_distributed(client, b["fp"], job, n_partitions=6)
    assert dist.stats["partitions"] == 6 and dist.stats["halo_footprints"] > 100
    assert dist.stats["features"] == serial.stats["features"]
    assert "neighbour_height" in dist.stats["features"] and "road_distance" in \
        dist.stats["features"]
    pd.testing.assert_frame_equal(serial.table, dist.table, check_exact=True)
    t = dist.table
    assert len(t) == len(b["g"]) and t.source_id.between(1000, 999 + len(b["g"])).all()
    assert t.height_m.between(3.0, 60.0).all() and (t.levels >= 1).all()
    truth, pred = b["truth"][b["hide"]], t.height_m.to_numpy()[b["hide"]]
    if mode == "medoid":
        # the hidden heights are predicted far better than a constant guess
        assert np.mean(np.abs(pred - truth)) < 0.8 * np.mean(np.abs(truth - np.median(truth)))
    else:
        # the random choice keeps the example heights' spread (two-sample KS)
        from scipy.stats import ks_2samp

        shown = b["attrs"].height_m.dropna().to_numpy(float)
        assert ks_2samp(t.height_m.to_numpy(), shown).pvalue > 0.01
        assert np.std(pred) > 0.7 * np.std(truth)
        other = distributed.attributes_distributed(client, b["fp"], _attr_job(b, mode, seed=4),
                                                   n_partitions=6)
        assert (other.table.source_id != t.source_id).sum() > 20


def test_attribute_halo_is_needed(buildings, client, monkeypatch):
    """Without the halo the context features of footprints near a partition edge change,
    so the equality above is not vacuous; without roads the feature set changes."""
    from urban_synthesis.plugin.buildings import attribute_transfer as bt

    b = buildings
    job = _attr_job(b)
    serial = distributed.attributes_serial(b["fp"], job)
    monkeypatch.setattr(bt, "CONTEXT_RADIUS", 0.0)
    monkeypatch.setattr(distributed, "HALO_MARGIN", 0.0)
    cut = distributed.attributes_distributed(client, b["fp"], job, n_partitions=6)
    assert (cut.table.similarity != serial.table.similarity).sum() > 50
    monkeypatch.undo()
    bare = distributed.attributes_distributed(client, b["fp"], _attr_job(b, roads=False),
                                              n_partitions=3)
    assert "road_distance" not in bare.stats["features"]
    pd.testing.assert_frame_equal(
        distributed.attributes_serial(b["fp"], _attr_job(b, roads=False)).table, bare.table,
        check_exact=True)
    with pytest.raises(InputError, match="unknown choice mode"):
        distributed.attributes_distributed(client, b["fp"], _attr_job(b, "best"))


def _cli(args, timeout=120):
    env = {"PYTHONPATH": str(ROOT / "build" / "plugins"), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "urban_synthesis.plugin.scale.cli", *args],
                          cwd=ROOT, capture_output=True, text=True, env=env, timeout=timeout)


def test_cli_gan_and_attributes(buildings, tmp_path):
    """Both subcommands on the real example data, 2 workers vs in-process: same files."""
    import geopandas as gpd

    area = tmp_path / "area.gpkg"
    gpd.GeoDataFrame(geometry=[shapely.box(385000, 6671500, 386300, 6672900)], crs=32635) \
        .to_crs(4326).to_file(area, layer="target", driver="GPKG", engine="pyogrio")
    osm = ROOT / "data" / "examples" / "Helsinki.osm.pbf"
    runs = {}
    for w in ("2", "0"):
        g = _cli(["gan", "--target", f"{area}:target", "--model", "streetgan_helsinki",
                  "--seed", "1", "--tile", "6", "--out", str(tmp_path / f"roads{w}.gpkg"),
                  "--workers", w])
        assert g.returncode == 0, g.stderr[-2000:]
        a = _cli(["attributes", "--footprints", f"{buildings['src']}:footprints",
                  "--examples", f"{osm}:multipolygons", "--roads", f"{osm}:lines",
                  "--example-roads", f"{osm}:lines", "--seed", "2", "--choice-mode", "random",
                  "--out", str(tmp_path / f"b{w}.gpkg"), "--workers", w, "--partitions", "4"])
        assert a.returncode == 0, a.stderr[-2000:]
        runs[w] = [json.loads(r.stdout.strip().splitlines()[-1]) for r in (g, a)]
    assert runs["2"][0]["mode"] == runs["2"][1]["mode"] == "dask (2 workers)"
    assert runs["0"][0]["mode"] == "serial"
    r2, r0 = (pyogrio.read_dataframe(tmp_path / f"roads{w}.gpkg", layer="roads")
              for w in ("2", "0"))
    assert len(r0) == runs["0"][0]["edges"] > 50 and r0.crs.to_epsg() == 4326
    assert (shapely.to_wkb(r0.geometry.values) == shapely.to_wkb(r2.geometry.values)).all()
    assert (r0.level.to_numpy() == r2.level.to_numpy()).all() and r0.level.nunique() > 3
    b2, b0 = (pyogrio.read_dataframe(tmp_path / f"b{w}.gpkg", layer="buildings")
              for w in ("2", "0"))
    assert len(b0) == len(buildings["g"]) and b0.crs.to_epsg() == 4326
    pd.testing.assert_frame_equal(b0.drop(columns="geometry"), b2.drop(columns="geometry"),
                                  check_exact=True)
    assert b0.height_m.notna().all() and b0.building_type.nunique() > 3


def test_cli_gan_and_attributes_bad_input(buildings, tmp_path):
    out = str(tmp_path / "x.gpkg")
    r = _cli(["gan", "--target", f"{buildings['src']}:nosuch", "--out", out])
    assert r.returncode == 2 and "has no layer 'nosuch'" in r.stderr
    r = _cli(["gan", "--target", f"{buildings['src']}:footprints", "--model", "nosuchmodel",
              "--out", out])
    assert r.returncode == 2 and "unknown StreetGAN model 'nosuchmodel'" in r.stderr
    osm = ROOT / "data" / "examples" / "Helsinki.osm.pbf"
    r = _cli(["attributes", "--footprints", f"{osm}:lines", "--examples",
              f"{osm}:multipolygons", "--out", out])
    assert r.returncode == 2 and "footprints must be polygons" in r.stderr and "lines" in r.stderr
    assert not (tmp_path / "x.gpkg").exists()
