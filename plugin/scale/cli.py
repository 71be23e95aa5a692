"""Command line without QGIS: district-scale batch runs, serial or on Dask.

    PYTHONPATH=build/plugins .venv/bin/python -m urban_synthesis.plugin.scale.cli footprints \\
        --blocks blocks.gpkg:blocks --db helsinki_blocks.gpkg --method transfer --seed 1 \\
        --out footprints.gpkg --workers 2            # or --scheduler tcp://host:8786
    ... cli gan --target area.gpkg:target --model streetgan_helsinki --seed 1 \\
        --out roads.gpkg --workers 2
    ... cli attributes --footprints fp.gpkg:footprints --examples Helsinki.osm.pbf:multipolygons \\
        --roads fp.gpkg:roads --example-roads Helsinki.osm.pbf:lines --out buildings.gpkg \\
        --workers 2

Subcommands: ``footprints`` (footprints by example per block, :mod:`footprints`), ``gan``
(StreetGAN road network: generator tiles on the workers, raster-to-graph once here,
:mod:`streetgan`), ``attributes`` (height, levels, type, roof by example,
:mod:`building_attribute_transfer`, partitions with a halo).
``--workers 0`` runs in this process (the engine's own function); ``--workers N`` starts
a local Dask cluster of N single-threaded worker processes; ``--scheduler`` connects to a
running cluster instead. The result is the same in every case (:mod:`distributed`).
Sources are read with pyogrio: a GeoPackage ``file:layer`` or ``file|layername=layer``, or
PostGIS ``PG:dbname=... |layername=schema.table``.
``--out`` is a GeoPackage ``file.gpkg`` or ``file.gpkg:layer``: the layer is replaced, the
file's other layers are kept; it is written under a temporary name and moved into place
when complete, and refused before any work when it would modify an input
(:func:`core.destinations.overwrite_error`, the rule of the QGIS tools).
Progress goes to stderr in steps of 10 % (not with ``--quiet``), the summary to stdout as
one JSON line.
Exit status: 0 done, 2 bad input (the message names the layer or file), 1 other errors,
130 interrupted (Ctrl-C: nothing written).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import shapely

from ..buildings import footprints
from ..core.destinations import Input, overwrite_error
from ..core.progress import InputError, Progress
from ..core.seeds import MAX_SEED, check_seed
from ..retrieval import database
from . import distributed

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
    f.add_argument("--method", choices=footprints.METHODS, default="transfer",
                   help="transfer: the best-matching example block's footprints copied in "
                        "and relaxed (ch. 5.1); resynthesis: a new layout composed from the "
                        "example's footprints per street segment (ch. 5.2) (default "
                        "%(default)s)")
    _seed_arg(f)
    f.add_argument("--street-width", type=float, default=footprints.STREET_WIDTH,
                   help="full road width in m, kept free around --roads (default "
                        "%(default)s)")
    f.add_argument("--setback", type=float, default=0.0,
                   help="extra distance in m behind the road surface kept free (default "
                        "%(default)s)")
    f.add_argument("--n-best", type=int, default=1,
                   help="random choice among the n best example blocks (default "
                        "%(default)s: always the best)")
    f.add_argument("--min-example-buildings", type=int, default=1,
                   help="example blocks with fewer footprints are not used (default "
                        "%(default)s)")
    f.add_argument("--out", required=True, help="output GeoPackage: file.gpkg (layer "
                   "'footprints') or file.gpkg:layer; written in the CRS of --blocks")
    _cluster_args(f)

    g = sub.add_parser("gan", help="StreetGAN road network over a target area (thesis ch. "
                       "4.2): generator tiles on the workers, graph extraction here")
    g.add_argument("--target", required=True, help="target area polygons (their union)")
    g.add_argument("--model", default="streetgan_helsinki",
                   help="shipped model name or .onnx file with its .json card (default "
                        "%(default)s)")
    _seed_arg(g)
    g.add_argument("--tile", type=int, default=24,
                   help="noise cells per generator tile, one task each (default "
                        "%(default)s; the image does not depend on it)")
    g.add_argument("--cell-size", type=float, help="metres per pixel (default: the "
                   "model's)")
    g.add_argument("--out", required=True, help="output GeoPackage: file.gpkg (layer "
                   "'roads') or file.gpkg:layer; written in the CRS of --target")
    _cluster_args(g)

    a = sub.add_parser("attributes", help="height, levels, type and roof of footprints "
                       "from the most similar example buildings")
    a.add_argument("--footprints", required=True, help="target footprint polygons")
    a.add_argument("--examples", required=True,
                   help="example buildings with heights or levels (OSM multipolygons, or "
                        "height_m / levels / building_type / roof_shape fields)")
    a.add_argument("--roads", help="roads around the footprints (with --example-roads)")
    a.add_argument("--example-roads", help="roads around the examples")
    a.add_argument("--k", type=int, default=9,
                   help="candidate example buildings per footprint (default %(default)s)")
    _seed_arg(a, "(random choice mode)")
    a.add_argument("--choice-mode", choices=("medoid", "random"), default="medoid",
                   help="medoid: the candidate of similarity-weighted median height; random: "
                        "one drawn by similarity (default %(default)s)")
    a.add_argument("--min-height", type=float, default=0.0,
                   help="lowest height in m given to a building (default %(default)s)")
    a.add_argument("--max-height", type=float, default=1000.0,
                   help="highest height in m given to a building (default %(default)s)")
    a.add_argument("--out", required=True, help="output GeoPackage: file.gpkg (layer "
                   "'buildings') or file.gpkg:layer; written in the CRS of --footprints")
    _cluster_args(a)
    return p


def _seed_arg(p, what=""):
    p.add_argument("--seed", type=int, default=1,
                   help=f"random seed {what + ' ' if what else ''}0 .. {MAX_SEED}: the same "
                        "seed gives the same result (default %(default)s)")


def _cluster_args(p):
    p.add_argument("--workers", type=int, default=0,
                   help="0 = in this process (default); N = local Dask cluster of N "
                        "processes")
    p.add_argument("--scheduler", help="address of a running Dask scheduler "
                   "(tcp://host:8786); overrides --workers")
    p.add_argument("--partitions", type=int, help="number of partitions (default 4 per "
                   "worker; gan: one per tile, this option is not used)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress on stderr and no summary line on stdout")


def _check_args(args):
    """Numbers every subcommand shares, checked before any work."""
    check_seed(args.seed)
    if args.workers < 0:
        raise InputError("--workers must be 0 or more")
    if args.partitions is not None and args.partitions < 1:
        raise InputError("--partitions must be at least 1")


def _inputs(*options) -> list:
    """(option name, source spec or list of database paths read whole) -> the files the
    run reads, for :func:`core.destinations.overwrite_error`."""
    out = []
    for name, spec, whole in options:
        for one in (spec if isinstance(spec, (list, tuple)) else [spec]):
            if not one:
                continue
            src = distributed.parse_source(one)
            if src.path.upper().startswith("PG:"):
                continue
            out.append(Input(name, Path(src.path),
                             None if whole else distributed.layer_name(src)))
    return out


def _destination(args, default_layer: str, inputs: list) -> distributed.Source:
    """``--out`` as (GeoPackage, layer), refused before any work when it would modify an
    input or cannot be written."""
    out = distributed.parse_output(args.out, default_layer)
    message = overwrite_error(f"--out {args.out}", Path(out.path), out.layer, inputs)
    if message:
        raise InputError(message)
    return out


def _progress(args, what: str):
    """Progress on stderr in steps of 10 % (None with --quiet)."""
    if args.quiet:
        return None
    last = [-1]

    def report(percent):
        step = int(percent // 10) * 10
        if step > last[0]:
            last[0] = step
            print(f"{what}: {step} %", file=sys.stderr, flush=True)

    return Progress(report)


@contextlib.contextmanager
def _client(args):
    """A Dask client for --scheduler / --workers N (None for a serial run)."""
    if not (args.scheduler or args.workers > 0):
        yield None
        return
    from distributed import Client, LocalCluster

    if args.scheduler:
        try:
            client, cluster = Client(args.scheduler), None
        except (OSError, ValueError, TypeError) as exc:
            raise InputError(f"--scheduler {args.scheduler}: cannot connect to a Dask "
                             f"scheduler there ({exc})") from exc
    else:
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    try:
        yield client
    except KeyboardInterrupt:
        # the workers are stopped below; their warnings about it are no news on Ctrl-C
        import logging

        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _mode(client) -> str:
    return "serial" if client is None else \
        f"dask ({len(client.scheduler_info()['workers'])} workers)"


def _run(args, serial, on_dask):
    """``serial()``, or ``on_dask(client)`` with --workers / --scheduler; returns
    (result, seconds, mode)."""
    with _client(args) as client:
        t0 = time.perf_counter()
        result = serial() if client is None else on_dask(client)
        return result, time.perf_counter() - t0, _mode(client)


def _footprints(args) -> dict:
    if args.n_best < 1:
        raise InputError("--n-best must be at least 1")
    out = _destination(args, "footprints", _inputs(("--blocks", args.blocks, False),
                                                   ("--roads", args.roads, False),
                                                   ("--db", args.db, True)))
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
    progress = _progress(args, "footprints")
    result, seconds, mode = _run(
        args, lambda: distributed.footprints_serial(blocks, job, progress=progress),
        lambda client: distributed.footprints_distributed(
            client, blocks, job, n_partitions=args.partitions, progress=progress))
    n = distributed.write_footprints(out.path, result, blocks.work_crs, blocks.crs,
                                     layer=out.layer)
    return {"mode": mode, "blocks": len(blocks), "footprints": n,
            "seconds": round(seconds, 3), "out": str(args.out)}


def _gan(args) -> dict:
    from ..roads import streetgan

    if args.tile is not None and args.tile < 1:
        raise InputError("--tile must be at least 1 noise cell")
    out = _destination(args, "roads", _inputs(("--target", args.target, False)))
    area, crs, work_crs = distributed.read_area(distributed.parse_source(args.target))
    gen = streetgan.load_model(args.model)
    progress = _progress(args, "gan")
    result, seconds, mode = _run(
        args, lambda: streetgan.synthesize(area, gen, args.seed, tile=args.tile,
                                           cell_size=args.cell_size, progress=progress),
        lambda client: distributed.gan_synthesize_distributed(
            client, area, gen, args.seed, tile=args.tile, cell_size=args.cell_size,
            progress=progress))
    n = distributed.write_lines(out.path, result.geometry,
                                pd.DataFrame({"level": result.level.astype(np.int64)}),
                                work_crs, crs, layer=out.layer)
    return {"mode": mode, "pixels": result.stats["pixels"], "edges": n,
            "generate_s": result.stats["generate_s"], "seconds": round(seconds, 3),
            "out": str(args.out)}


def _read_buildings(spec: str, work_crs: str):
    """Example buildings (polygonal parts of valid geometry; OSM rows without a building
    tag left out) and their attributes (:func:`building_attributes.building_attributes`)."""
    from ..buildings import attributes as building_attributes

    src = distributed.parse_source(spec)
    df = distributed.read_layer(src)
    if "building" in df.columns:
        df = df[df.building.notna()]
    df = df[df.geometry.notna()]
    g = distributed._to_metric(df, work_crs, src)
    g = shapely.make_valid(g)
    g = np.array([shapely.union_all([p for p in shapely.get_parts(x)
                                     if shapely.get_type_id(p) == 3]) for x in g], dtype=object)
    ok = np.isin(shapely.get_type_id(g), (3, 6)) & ~shapely.is_empty(g)
    df, g = df[ok], g[ok]
    if len(df) == 0:
        raise InputError(f"{src}: the layer holds no building polygon")
    cols = set(df.columns)
    attrs = building_attributes.building_attributes(
        len(df), building=df["building"].to_numpy(dtype=object) if "building" in cols else None,
        other_tags=df["other_tags"].to_numpy(dtype=object) if "other_tags" in cols else None,
        tags={k: df[k].to_numpy(dtype=object) for k in ("amenity", "shop", "office",
                                                        "roof_shape") if k in cols},
        height=df["height_m"].to_numpy(dtype=object) if "height_m" in cols else None,
        levels=df["levels"].to_numpy(dtype=object) if "levels" in cols else None)
    if "building_type" in cols and "building" not in cols:
        attrs["building_type"] = df["building_type"].to_numpy(dtype=object)
    if "roof_shape" in cols:
        attrs["roof_shape"] = df["roof_shape"].to_numpy(dtype=object)
    return g, attrs, df.index.to_numpy(dtype=np.int64)


def _read_roads(spec: str, work_crs: str):
    """Road lines (drivable classes when OSM) and the arterials among them, by the rule of
    the building tools (:func:`street_graph.drivable_and_arterial`)."""
    from ..network import street_graph as roads

    src = distributed.parse_source(spec)
    df = distributed.read_layer(src)
    df = df[df.geometry.notna()]
    if len(df) == 0 or not set(shapely.get_type_id(df.geometry.values).tolist()) <= {1, 5}:
        raise InputError(f"{src}: roads must be a non-empty line layer")
    keep, art = roads.drivable_and_arterial(
        df["highway"].to_numpy(dtype=object) if "highway" in df.columns else None,
        df["level"].to_numpy(dtype=object) if "level" in df.columns else None, len(df))
    g = distributed._to_metric(df, work_crs, src)
    return g[keep], g[art]


def _attributes(args) -> dict:
    from ..buildings import attribute_transfer as bt

    out = _destination(args, "buildings", _inputs(
        ("--footprints", args.footprints, False), ("--examples", args.examples, False),
        ("--roads", args.roads, False), ("--example-roads", args.example_roads, False)))
    fp = distributed.read_footprints(distributed.parse_source(args.footprints))
    ex, attrs, ex_ids = _read_buildings(args.examples, fp.work_crs)
    rl = art = erl = eart = None
    if args.roads:
        rl, art = _read_roads(args.roads, fp.work_crs)
    if args.example_roads:
        erl, eart = _read_roads(args.example_roads, fp.work_crs)
    job = distributed.AttributeJob(ex, attrs, ex_ids, rl, art, erl, eart, k=args.k,
                                   seed=args.seed, min_height=args.min_height,
                                   max_height=args.max_height, choice_mode=args.choice_mode)
    progress = _progress(args, "attributes")
    result, seconds, mode = _run(
        args, lambda: distributed.attributes_serial(fp, job, progress=progress),
        lambda client: distributed.attributes_distributed(
            client, fp, job, n_partitions=args.partitions, progress=progress))
    table = result.table.copy()
    for name, kind in bt.OUTPUT_FIELDS:
        if kind == "str":
            table[name] = table[name].astype(object)
    n = distributed.write_lines(out.path, fp.geometry, table, fp.work_crs, fp.crs,
                                layer=out.layer)
    return {"mode": mode, "footprints": n, "donors": int(result.stats["n_donors"]),
            "features": result.stats["features"], "seconds": round(seconds, 3),
            "out": str(args.out)}


COMMANDS = {"footprints": _footprints, "gan": _gan, "attributes": _attributes}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        _check_args(args)
        summary = COMMANDS[args.command](args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted: nothing was written ({args.out} is as it was)", file=sys.stderr)
        return 130
    if not args.quiet:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
