"""Footprints on Dask (plugin.distributed, plugin.cli): partitions of a GeoPackage source on
a local cluster of 2 worker processes give exactly the serial result, for both methods.

Inputs are built here from data/examples: the Helsinki block database (blocks +
footprints through the engine, as in test_footprints) and, as targets, Bubeneč's street
blocks plus the Helsinki blocks written to a GeoPackage in WGS 84 (so that every
partition reprojects to UTM on its own) together with the Helsinki roads.
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
from helpers import helsinki_roads
from urban_synthesis.plugin import blocks, distributed, footprints, roads
from urban_synthesis.plugin.progress import InputError


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
    from urban_synthesis.plugin import database

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
    assert distributed.same_footprints(serial, dist) is None
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
    assert distributed.same_footprints(base, other_seed) is not None
    no_roads = distributed.footprints_serial(sub, distributed.FootprintJob(
        job.examples, None, "transfer", seed=7, n_best=2))
    assert distributed.same_footprints(base, no_roads) is not None


def test_cli_end_to_end(district, tmp_path):
    out = tmp_path / "fp.gpkg"
    cmd = [sys.executable, "-m", "urban_synthesis.plugin.cli", "footprints",
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
    base = [sys.executable, "-m", "urban_synthesis.plugin.cli", "footprints",
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
