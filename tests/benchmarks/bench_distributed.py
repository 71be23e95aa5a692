"""Footprints on Dask (issue 10, part 3): throughput on a 10x tiled district.

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

from urban_synthesis.plugin import (blocks, database, distributed,  # noqa: E402
                                    footprints, roads)

TILES = 10


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
                client.run(lambda: __import__("urban_synthesis.plugin.distributed"))
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
                    equal_to_serial=distributed.same_footprints(serial, res) is None)
            print(f"  {method} done, load average {os.getloadavg()[0]:.2f}", flush=True)
        results["runs"] = rows
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
    target = ROOT / "tests" / "benchmarks" / "results" / "distributed.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(results, indent=2, ensure_ascii=False), encoding="utf-8")
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
