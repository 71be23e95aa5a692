"""Work on Dask (issue 10, part 3): footprints and building attributes on a 10x tiled
district, StreetGAN generator tiles on large targets; serial vs 1 and 2 Dask workers.

District: Helsinki's street blocks (:func:`blocks.extract_blocks` on the drivable roads of
data/examples/Helsinki.osm.pbf) tiled 10 times by translation, written with the tiled
roads to a GeoPackage; database: the Helsinki block database (blocks + footprints, built
through the engine as in test_footprints). Each method runs

- serially (:func:`footprints.synthesize_footprints` via :func:`distributed.footprints_serial`),
- on a local Dask cluster with 1 and with 2 single-threaded worker processes, partitions
  read by each task from the GeoPackage (4 per worker),

and the Dask results are checked WKB-equal to the serial one. Blocks/s and speed-up are
wall-clock times (cluster start-up excluded, the broadcast of the database and roads
included; ``block_seconds`` is the sum of the per-block times measured inside the
tasks, so that scheduling overhead and CPU contention can be told apart). The machine has 2 CPU cores shared with other jobs: the load average is
recorded, and 2 workers cannot exceed 2x.

StreetGAN: :func:`streetgan.generate` (the serial tiles, onnxruntime with its default
threads) vs :func:`distributed.gan_generate_distributed` (the same tiles as tasks, one
onnxruntime thread per worker) on square targets of 3 x 3 and 12 x 12 km at 3 m/pixel
(+ 96 m margin), images checked ``np.array_equal``; for 3 x 3 km also the whole
:func:`streetgan.synthesize` (graph extraction on the driver) with the network compared.
Attributes: the Helsinki OSM buildings tiled 10x (and 100x) with their roads as targets,
the Helsinki buildings as examples (medoid, k = 9), :func:`distributed.attributes_serial`
vs :func:`distributed.attributes_distributed`, tables checked exactly equal.

Prints a table and writes ``tests/benchmarks/results/distributed.json``.
"""
from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT / "build" / "plugins", ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from urban_synthesis.plugin.network import blocks  # noqa: E402
from urban_synthesis.plugin.retrieval import database  # noqa: E402
from urban_synthesis.plugin.scale import distributed  # noqa: E402
from urban_synthesis.plugin.buildings import footprints  # noqa: E402
from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402
from helpers import same_footprints  # noqa: E402

TILES = 10
GAN_SIDES_KM = (3, 12)
ATTRIBUTE_TILES = (10, 100)


def tiled_district(tmp: Path):
    import geopandas as gpd
    from helpers import helsinki_roads

    df = helsinki_roads()
    graph = roads.clean_network(df.geometry.values, df.highway.values, z_layer=df.z.values)
    r = blocks.extract_blocks(graph)
    x0, y0, x1, y1 = shapely.total_bounds(graph.geometry)
    side = int(np.ceil(np.sqrt(TILES)))
    bl, rd = [], []
    for k in range(TILES):
        dx, dy = (k % side) * (x1 - x0 + 200), (k // side) * (y1 - y0 + 200)
        bl.extend(shapely.transform(r.geometry, lambda c, dx=dx, dy=dy: c + [dx, dy]))
        rd.extend(shapely.transform(graph.geometry, lambda c, dx=dx, dy=dy: c + [dx, dy]))
    path = tmp / "district.gpkg"
    gpd.GeoDataFrame({"block_id": np.arange(1, len(bl) + 1)}, geometry=bl, crs=32635) \
        .to_file(path, layer="blocks", driver="GPKG", engine="pyogrio")
    gpd.GeoDataFrame(geometry=rd, crs=32635).to_file(path, layer="roads", driver="GPKG",
                                                     engine="pyogrio")
    return path, len(r.geometry)


def main():
    warnings.simplefilter("ignore")
    from distributed import Client, LocalCluster

    from test_footprints import helsinki_example_db

    results = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                           "platform": platform.platform(),
                           "note": "2 CPU cores shared with other engineers' jobs",
                           "load_average": list(os.getloadavg())}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        db_path = tmp / "helsinki_blocks.gpkg"
        helsinki_example_db(db_path)
        ex = footprints.prepare_examples(database.load_block_database(db_path), "helsinki")
        src, n_base = tiled_district(tmp)
        b = distributed.read_blocks(distributed.Source(str(src), "blocks"))
        rd = distributed.RoadIndex(distributed.read_lines(distributed.Source(str(src), "roads"),
                                                          b.work_crs))
        results["district"] = dict(tiles=TILES, base_blocks=n_base, blocks=len(b),
                                   roads=len(rd.lines), database_blocks=len(ex.db))
        rows = {}
        for method in footprints.METHODS:
            job = distributed.FootprintJob([ex], rd, method, seed=1)
            t0 = time.perf_counter()
            serial = distributed.footprints_serial(b, job)
            ts = time.perf_counter() - t0
            rows[f"{method}, serial"] = dict(blocks=len(b), footprints=len(serial.geometry),
                                             seconds=ts, blocks_per_s=len(b) / ts,
                                             speedup=1.0,
                                             block_seconds=float(serial.blocks.seconds.sum()),
                                             equal_to_serial=True)
            for workers in (1, 2):
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                       processes=True, dashboard_address=None)
                client = Client(cluster)
                # imports done before the clock starts (a long-lived cluster has them)
                client.run(lambda: __import__("urban_synthesis.plugin.scale.distributed"))
                try:
                    t0 = time.perf_counter()
                    res = distributed.footprints_distributed(client, b, job)
                    td = time.perf_counter() - t0
                finally:
                    client.close()
                    cluster.close()
                rows[f"{method}, dask {workers} worker(s)"] = dict(
                    blocks=len(b), footprints=len(res.geometry), seconds=td,
                    blocks_per_s=len(b) / td, speedup=ts / td,
                    block_seconds=float(res.blocks.seconds.sum()),
                    equal_to_serial=same_footprints(serial, res) is None)
            print(f"  {method} done, load average {os.getloadavg()[0]:.2f}", flush=True)
        results["runs"] = rows
        results["gan"] = bench_gan()
        results["attributes"] = bench_attributes(tmp)
    results["machine"]["load_average_end"] = list(os.getloadavg())
    print(f"\nFootprints on a {TILES}x tiled Helsinki district "
          f"({results['district']['blocks']} blocks); 2 shared CPU cores, "
          f"load average {results['machine']['load_average'][0]:.1f} -> "
          f"{results['machine']['load_average_end'][0]:.1f}")
    keys = list(next(iter(rows.values())).keys())
    print("  " + " | ".join(["run"] + keys))
    for name, row in rows.items():
        vals = [f"{v:.2f}" if isinstance(v, float) else str(v) for v in row.values()]
        print("  " + " | ".join([name] + vals))
    for key, title in (("gan", "StreetGAN generator tiles (streetgan_helsinki, tile 24)"),
                       ("attributes", "Building attributes (medoid, k = 9)")):
        print(f"\n{title}")
        rows = results[key]
        keys = list(next(iter(rows.values())).keys())
        print("  " + " | ".join(["run"] + keys))
        for name, row in rows.items():
            vals = [f"{v:.2f}" if isinstance(v, float) else str(v) for v in row.values()]
            print("  " + " | ".join([name] + vals))
    target = ROOT / "tests" / "benchmarks" / "results" / "distributed.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(results, indent=2, ensure_ascii=False), encoding="utf-8")
    print(f"\nwrote {target}")


def _cluster(workers):
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    client = Client(cluster)
    client.run(lambda: __import__("urban_synthesis.plugin.scale.distributed"))
    return cluster, client


def bench_gan():
    from urban_synthesis.plugin.roads import streetgan

    gen = streetgan.load_model("streetgan_helsinki")
    rows = {}
    for km in GAN_SIDES_KM:
        px = int(np.ceil((km * 1000 + 2 * 96) / gen.cell_size)) + 1
        mr = streetgan.noise_size(px, gen.scale)
        n_tiles = len(streetgan.tile_plan(mr, mr, 24, gen.scale))
        t0 = time.perf_counter()
        ref = streetgan.generate(gen, px, px, seed=1)
        ts = time.perf_counter() - t0
        base = dict(pixels=px * px, tiles=n_tiles)
        rows[f"{km} x {km} km image, serial"] = dict(base, seconds=ts,
                                                     mpixel_per_s=px * px / ts / 1e6,
                                                     speedup=1.0, equal_to_serial=True)
        for workers in (1, 2):
            cluster, client = _cluster(workers)
            try:
                # the first call opens the model on the workers: timed apart
                t0 = time.perf_counter()
                distributed.gan_generate_distributed(client, gen, 64, 64, seed=0, threads=1)
                t_open = time.perf_counter() - t0
                t0 = time.perf_counter()
                img = distributed.gan_generate_distributed(client, gen, px, px, seed=1,
                                                           threads=1)
                td = time.perf_counter() - t0
                rows[f"{km} x {km} km image, dask {workers} worker(s)"] = dict(
                    base, seconds=td, mpixel_per_s=px * px / td / 1e6, speedup=ts / td,
                    equal_to_serial=bool(np.array_equal(ref, img)), model_open_s=t_open)
                if km == GAN_SIDES_KM[0] and workers == 2:
                    target = shapely.box(0, 0, km * 1000, km * 1000)
                    t0 = time.perf_counter()
                    a = streetgan.synthesize(target, gen, seed=1)
                    ta = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    b = distributed.gan_synthesize_distributed(client, target, gen, seed=1,
                                                               threads=1)
                    tb = time.perf_counter() - t0
                    same = bool(len(a.geometry) == len(b.geometry) and np.all(
                        shapely.to_wkb(a.geometry) == shapely.to_wkb(b.geometry)) and
                        np.array_equal(a.level, b.level))
                    rows[f"{km} x {km} km network, serial"] = dict(
                        base, seconds=ta, mpixel_per_s=px * px / ta / 1e6, speedup=1.0,
                        equal_to_serial=True, edges=len(a.geometry))
                    rows[f"{km} x {km} km network, dask 2 worker(s)"] = dict(
                        base, seconds=tb, mpixel_per_s=px * px / tb / 1e6, speedup=ta / tb,
                        equal_to_serial=same, edges=len(b.geometry))
            finally:
                client.close()
                cluster.close()
        print(f"  gan {km} km done, load average {os.getloadavg()[0]:.2f}", flush=True)
    return rows


def tiled_buildings(tmp: Path, tiles: int):
    """Helsinki OSM buildings and drivable roads tiled ``tiles`` times by translation."""
    import geopandas as gpd
    from test_building_synthesis import helsinki_buildings

    g, attrs, rl, art, _ = helsinki_buildings()
    x0, y0, x1, y1 = shapely.total_bounds(np.concatenate([g, rl]))
    side = int(np.ceil(np.sqrt(tiles)))
    fp, rd = [], []
    for k in range(tiles):
        dx, dy = (k % side) * (x1 - x0 + 200), (k // side) * (y1 - y0 + 200)
        fp.extend(shapely.transform(g, lambda c, dx=dx, dy=dy: c + [dx, dy]))
        rd.append((shapely.transform(rl, lambda c, dx=dx, dy=dy: c + [dx, dy]),
                   shapely.transform(art, lambda c, dx=dx, dy=dy: c + [dx, dy])))
    path = tmp / f"buildings_{tiles}.gpkg"
    gpd.GeoDataFrame({"n": np.arange(len(fp))}, geometry=fp, crs=32635) \
        .to_file(path, layer="footprints", driver="GPKG", engine="pyogrio")
    roads_all = np.concatenate([r for r, _ in rd])
    art_all = np.concatenate([a for _, a in rd])
    return path, (g, attrs, rl, art), roads_all, art_all


def bench_attributes(tmp: Path):
    import pandas as pd

    rows = {}
    for tiles in ATTRIBUTE_TILES:
        path, (g, attrs, rl, art), roads_all, art_all = tiled_buildings(tmp, tiles)
        fp = distributed.read_footprints(distributed.Source(str(path), "footprints"))
        job = distributed.AttributeJob(g, attrs, None, roads_all, art_all, rl, art, k=9,
                                       seed=1, choice_mode="medoid")
        t0 = time.perf_counter()
        serial = distributed.attributes_serial(fp, job)
        ts = time.perf_counter() - t0
        rows[f"{tiles}x Helsinki, serial"] = dict(footprints=len(fp), seconds=ts,
                                                  footprints_per_s=len(fp) / ts, speedup=1.0,
                                                  equal_to_serial=True)
        for workers in (1, 2):
            cluster, client = _cluster(workers)
            try:
                t0 = time.perf_counter()
                res = distributed.attributes_distributed(client, fp, job)
                td = time.perf_counter() - t0
            finally:
                client.close()
                cluster.close()
            try:
                pd.testing.assert_frame_equal(serial.table, res.table, check_exact=True)
                same = True
            except AssertionError:
                same = False
            rows[f"{tiles}x Helsinki, dask {workers} worker(s)"] = dict(
                footprints=len(fp), seconds=td, footprints_per_s=len(fp) / td,
                speedup=ts / td, equal_to_serial=same, partitions=res.stats["partitions"],
                halo_footprints=res.stats["halo_footprints"])
        print(f"  attributes {tiles}x done, load average {os.getloadavg()[0]:.2f}", flush=True)
    return rows


if __name__ == "__main__":
    main()
