"""Command line without QGIS: footprints by example for a whole district, serial or on Dask.

    PYTHONPATH=build/plugins .venv/bin/python -m urban_synthesis.plugin.cli footprints \\
        --blocks blocks.gpkg:blocks --db helsinki_blocks.gpkg --method transfer --seed 1 \\
        --out footprints.gpkg --workers 2            # or --scheduler tcp://host:8786

``--workers 0`` runs in this process (:func:`footprints.synthesize_footprints`);
``--workers N`` starts a local Dask cluster of N single-threaded worker processes;
``--scheduler`` connects to a running cluster instead. The result is the same in every
case (:mod:`distributed`). Sources are read with pyogrio: a GeoPackage ``file:layer`` or
``file|layername=layer``, or PostGIS ``PG:dbname=... |layername=schema.table``.
Exit status: 0 done, 2 bad input (the message names the layer or file), 1 other errors.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from . import database, distributed, footprints
from .progress import InputError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="urbansynth-batch",
        description="Urban Synthesis batch runs without QGIS (serial or on Dask).")
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("footprints", help="fill city blocks with footprints by example "
                       "(thesis ch. 5.1 transfer / 5.2 re-synthesis)")
    f.add_argument("--blocks", required=True,
                   help="target block polygons: file.gpkg:layer, file|layername=layer or "
                        "'PG:... |layername=table' (a block_id field is kept when unique)")
    f.add_argument("--roads", help="optional road centrelines near the blocks (their "
                   "surface, dead ends included, stays free of buildings)")
    f.add_argument("--db", action="append", required=True,
                   help="block database GeoPackage from 'Build block database' (repeat for "
                        "several: each block takes the best match of all)")
    f.add_argument("--method", choices=footprints.METHODS, default="transfer")
    f.add_argument("--seed", type=int, default=1)
    f.add_argument("--street-width", type=float, default=footprints.STREET_WIDTH,
                   help="full road width in m (default %(default)s)")
    f.add_argument("--setback", type=float, default=0.0)
    f.add_argument("--n-best", type=int, default=1,
                   help="random choice among the n best example blocks")
    f.add_argument("--min-example-buildings", type=int, default=1)
    f.add_argument("--out", required=True, help="output GeoPackage (layer 'footprints')")
    f.add_argument("--workers", type=int, default=0,
                   help="0 = in this process; N = local Dask cluster of N processes")
    f.add_argument("--scheduler", help="address of a running Dask scheduler "
                   "(tcp://host:8786); overrides --workers")
    f.add_argument("--partitions", type=int, help="number of partitions (default 4 per "
                   "worker)")
    f.add_argument("--quiet", action="store_true")
    return p


def _footprints(args) -> dict:
    if args.n_best < 1:
        raise InputError("--n-best must be at least 1")
    if args.workers < 0:
        raise InputError("--workers must be 0 or more")
    blocks = distributed.read_blocks(distributed.parse_source(args.blocks))
    roads = None
    if args.roads:
        roads = distributed.RoadIndex(distributed.read_lines(
            distributed.parse_source(args.roads), blocks.work_crs))
    examples = []
    for k, path in enumerate(args.db):
        name = Path(path).stem if len(args.db) == 1 else f"{Path(path).stem}_{k + 1}"
        examples.append(footprints.prepare_examples(database.load_block_database(path), name,
                                                    args.min_example_buildings))
    job = distributed.FootprintJob(examples, roads, args.method, args.seed,
                                   args.street_width, args.setback, args.n_best)
    t0 = time.perf_counter()
    if args.scheduler or args.workers > 0:
        from distributed import Client, LocalCluster

        if args.scheduler:
            client, cluster = Client(args.scheduler), None
        else:
            cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
            client = Client(cluster)
        try:
            result = distributed.footprints_distributed(client, blocks, job,
                                                        n_partitions=args.partitions)
            mode = f"dask ({len(client.scheduler_info()['workers'])} workers)"
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        result = distributed.footprints_serial(blocks, job)
        mode = "serial"
    seconds = time.perf_counter() - t0
    n = distributed.write_footprints(args.out, result, blocks.work_crs, blocks.crs)
    return {"mode": mode, "blocks": len(blocks), "footprints": n,
            "seconds": round(seconds, 3), "out": str(args.out)}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        summary = _footprints(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
