"""Per-block and per-tile work beyond one machine, on Dask (dask.distributed).

**Footprints by example** (thesis ch. 5.1 transfer, ch. 5.2 guided re-synthesis). The
footprints of a block depend only on the block, the road centrelines touching it, the
block databases and the seed (:func:`footprints.synthesize_block` is a pure function; its
random numbers come from the seed and where the block lies), so a district splits into
independent partitions of blocks:

1. the driver reads the block layer once (a GeoPackage, or PostGIS through a GDAL
   ``PG:`` connection string) and cuts it into spatially compact partitions: blocks in
   Z-order (Morton key of their bounding-box centres), split into runs of equal size;
2. the block databases and the road centrelines are sent to every worker once
   (``client.scatter(..., broadcast=True)``); each worker builds its road index lazily,
   once, from the same array as the serial run, so its STR-tree answers in the same order;
3. each task reads its own blocks from the source by feature id, reprojects them to the
   driver's metric CRS, calls :func:`footprints.synthesize_block` with the block's
   *global* index (its default id) and returns footprints + statistics;
4. the driver merges the partitions in block order.

Result: the same footprints, attributes and order as :func:`footprints.synthesize_footprints`
on the whole layer, for any number of workers and partitions (tested WKB-equal). Tasks
are pure, so a lost worker's partition is simply run again (``retries``).

**StreetGAN tiles** (thesis ch. 4.2, :mod:`streetgan`). The driver draws the noise field
once from the seed; every tile of :func:`streetgan.tile_plan` (the serial run's tiles)
is a task that gets its noise window and the model's path and runs the generator,
opened once per worker process; the driver stitches the cores (``np.array_equal`` to
:func:`streetgan.generate`) and extracts the road graph once.

**Building attributes** (:mod:`building_attribute_transfer`). Footprints are cut into
Z-order partitions; each task reads its partition plus a halo of every footprint whose
centroid lies within ``CONTEXT_RADIUS`` (150 m) + 10 m of it, in layer order, so the
coverage and grain features see exactly the serial run's neighbours in the same order.
The example side (features, donors) and the standardisation (feature columns chosen from
all targets, mean and spread) are computed once on the driver; the random donor choice
takes each footprint's draw from the serial run's single stream. The table equals
:func:`building_attribute_transfer.transfer_attributes` (``medoid`` and ``random``);
a target floor-area ratio (a whole-district adjustment) is not offered on Dask.

Not distributed (and why): street tessellation is a whole-network computation
(:mod:`street_surfaces`) that was left serial.

Nothing here imports QGIS; pyogrio/geopandas/dask are imported where used.

References
----------
Hartmann, S., thesis ch. 5.1 / 5.2 (footprints per block); Dask distributed,
``Client.scatter`` / ``Client.submit`` (https://distributed.dask.org).
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..buildings import footprints
from ..core import crs as crs_rule
from ..core.destinations import STAGING_PREFIX, make_folders, remove_empty_folders
from ..core.ids import ids_or_numbers
from ..core.progress import InputError, Progress, ensure

__all__ = ["Source", "parse_source", "metric_crs", "read_layer", "BlockTable", "read_blocks",
           "read_lines", "morton_keys", "spatial_partitions", "RoadIndex", "FootprintJob",
           "footprints_serial", "footprints_distributed", "write_footprints",
           "gan_generate_distributed", "gan_synthesize_distributed",
           "read_area", "write_lines", "AttributeJob", "read_footprints", "halo_partitions",
           "attributes_serial", "attributes_distributed", "for_workers", "layer_name",
           "parse_output",
           "write_layer"]



# --------------------------------------------------------------------------- sources

@dataclass(frozen=True)
class Source:
    """A vector layer: a file or GDAL connection string (``PG:...``) and a layer name."""

    path: str
    layer: Optional[str] = None

    def __str__(self):
        return f"{self.path}:{self.layer}" if self.layer else self.path


def parse_source(spec: str) -> Source:
    """``file.gpkg:layer``, ``file.gpkg|layername=layer`` (QGIS), ``file.gpkg`` (first
    layer) or ``PG:dbname=... |layername=schema.table``."""
    spec = str(spec).strip()
    if "|layername=" in spec:
        path, layer = spec.split("|layername=", 1)
        return Source(path.strip(), layer.split("|", 1)[0].strip() or None)
    if not spec.upper().startswith("PG:") and ":" in spec:
        path, layer = spec.rsplit(":", 1)
        # a Windows drive letter or a path without layer keeps its colon
        if path and "/" not in layer and "\\" not in layer and len(path) > 1:
            return Source(path, layer or None)
    return Source(spec, None)


def _pyproj_crs(crs):
    from pyproj import CRS

    return CRS.from_user_input(crs)


def metric_crs(crs, bounds_lonlat) -> str:
    """The CRS the engine works in for a layer in ``crs`` (a pyproj CRS or anything it
    reads), by the plugin's rule :func:`core.crs.working_crs`: the CRS itself (as WKT) when
    it is projected in metres and its scale at the data's centre is within 1 % of true (not
    Web Mercator, World Mercator ...: PROJ's scale factors), else the UTM zone of the data's
    centre.
    ``bounds_lonlat``: (xmin, ymin, xmax, ymax) in degrees. A layer without a CRS is refused
    (its units are unknown: a guess would give silently wrong sizes)."""
    if crs is None:
        raise InputError("the layer has no coordinate reference system (CRS), so its units "
                         "are unknown: assign its CRS and run again")
    c = _pyproj_crs(crs)
    authority = c.to_authority()
    metres = c.is_projected and bool(c.axis_info) and \
        all(a.unit_name in ("metre", "meter") for a in c.axis_info[:2])
    centre = ((bounds_lonlat[0] + bounds_lonlat[2]) / 2.0,
              (bounds_lonlat[1] + bounds_lonlat[3]) / 2.0)
    def scale_error() -> float:
        from pyproj import Proj

        try:
            f = Proj(c).get_factors(*centre)
        except Exception:  # noqa: BLE001 - a CRS PROJ has no factors for: taken as true
            return 0.0
        return max(abs(f.meridional_scale - 1.0), abs(f.parallel_scale - 1.0))

    code = crs_rule.working_crs(":".join(authority) if authority else None, metres, centre,
                                scale_error)
    return c.to_wkt() if code is None else code


def read_layer(source: Source, fids: Optional[Sequence[int]] = None, columns=None):
    """The layer as a GeoDataFrame indexed by feature id (all features or ``fids``)."""
    import pyogrio
    from pyogrio.errors import DataLayerError, DataSourceError

    is_file = not source.path.upper().startswith("PG:")
    if is_file and not Path(source.path).exists():
        raise InputError(f"{source.path}: no such file")
    try:
        layers = [str(n) for n in pyogrio.list_layers(source.path)[:, 0]]
    except DataSourceError as exc:
        raise InputError(f"{source.path}: cannot be opened as a vector data source ({exc})") \
            from exc
    if source.layer is not None and source.layer not in layers:
        raise InputError(f"{source.path} has no layer '{source.layer}' "
                         f"(layers: {', '.join(layers) or 'none'})")
    if not layers:
        raise InputError(f"{source.path} holds no layer")
    try:
        df = pyogrio.read_dataframe(
            source.path, layer=source.layer or layers[0], columns=columns, fid_as_index=True,
            fids=None if fids is None else np.asarray(fids, dtype=np.int64),
            on_invalid="ignore")
    except (DataLayerError, DataSourceError) as exc:
        raise InputError(f"{source}: cannot be read ({exc})") from exc
    if fids is not None:
        df = df.loc[np.asarray(fids, dtype=np.int64)]   # in the order asked for
    return df


def for_workers(source: Source) -> Source:
    """The source as the workers re-read it: a relative file path made absolute here (a
    worker of a --scheduler cluster runs in a folder of its own: 'demo.gpkg' was 'no such
    file' there); connection strings as they are."""
    if source.path.upper().startswith("PG:") or Path(source.path).is_absolute():
        return source
    return Source(str(Path(source.path).absolute()), source.layer)


def layer_name(source: Source) -> Optional[str]:
    """The layer :func:`read_layer` reads: the one named, else a GeoPackage's first layer;
    None for a file of one unnamed layer (a shapefile, a GeoJSON), a connection string or
    a file that cannot be opened (the file is then taken as read whole)."""
    if source.layer is not None:
        return source.layer
    if source.path.upper().startswith("PG:") or \
            Path(source.path).suffix.lower() != ".gpkg":
        return None
    import pyogrio

    try:
        layers = pyogrio.list_layers(source.path)
    except Exception:  # noqa: BLE001 - unreadable: reported where it is read
        return None
    return str(layers[0, 0]) if len(layers) else None


def parse_output(spec: str, default_layer: str) -> Source:
    """An output GeoPackage and its layer: ``file.gpkg``, ``file.gpkg:layer`` or
    ``file.gpkg|layername=layer`` (the layer defaults to ``default_layer``). Refused
    before any work: a name not ending in .gpkg (the file is written as a GeoPackage
    whatever it is called), a connection string, and a folder that cannot be written."""
    src = parse_source(spec)
    if not src.path or src.path.upper().startswith("PG:"):
        raise InputError(f"--out {spec}: the output is a GeoPackage file (file.gpkg or "
                         "file.gpkg:layer)")
    if Path(src.path).suffix.lower() != ".gpkg":
        raise InputError(f"--out {spec}: the output is written as a GeoPackage, but "
                         f"{src.path} does not end in .gpkg: name it so, or another "
                         "program will misread it")
    if Path(src.path).is_dir():
        raise InputError(f"--out {spec}: {src.path} is a folder, not a GeoPackage file")
    probe = Path(src.path).absolute().parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f"--out {spec}: the folder {Path(src.path).absolute().parent} "
                         f"cannot be written ({probe} is "
                         f"{'not a folder' if not probe.is_dir() else 'read-only'})")
    return Source(src.path, src.layer or default_layer)


def write_layer(gdf, path: str, layer: str) -> int:
    """Write a GeoDataFrame to a layer of a GeoPackage, replacing a layer of that name and
    keeping the file's other layers; returns the feature count.

    Nothing is half-written: the file is written in a hidden staging folder next to it
    (a copy of the existing file, when there is one) and moved into place in one step
    (``os.replace``) when it is complete. A failure or Ctrl-C leaves the destination as it
    was and removes the staging folder and any folder this call created."""
    from pyogrio.errors import DataLayerError, DataSourceError

    final = Path(path)
    folder = final.absolute().parent
    made = []
    try:
        made = make_folders(folder)
        staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=folder))
    except OSError as exc:
        remove_empty_folders(made)
        raise InputError(f"{final}: the folder {folder} cannot be written "
                         f"({exc.strerror or exc})") from exc
    try:
        temp = staging / final.name
        if final.exists():
            shutil.copy2(final, temp)    # the file's other layers are kept
        try:
            gdf.to_file(temp, layer=layer, driver="GPKG", engine="pyogrio")
        except (DataLayerError, DataSourceError) as exc:
            hint = " (the file exists: is it a GeoPackage?)" if final.exists() else ""
            raise InputError(f"{final}: layer '{layer}' cannot be written{hint}: "
                             f"{exc}") from exc
        os.replace(temp, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        remove_empty_folders(made)
        raise
    shutil.rmtree(staging, ignore_errors=True)
    return len(gdf)


def _layer_crs(df, source):
    """The CRS of a read layer; a layer without one, or with GeoPackage's placeholders for
    none ('Undefined geographic SRS', srs_id 0; 'Undefined Cartesian SRS', -1), is refused
    by name, as the QGIS adapter refuses it (``qgis_io.usable_crs``): a secondary layer
    (roads, example buildings) without a CRS was used as if in the working CRS, roads in
    feet or degrees silently nowhere near the blocks."""
    if df.crs is None or str(df.crs.name or "").lower().startswith("undefined"):
        raise InputError(f"{source}: the layer has no coordinate reference system (CRS), so "
                         "its units are unknown: assign its CRS and run again")
    return df.crs


def _to_metric(df, work_crs: str, source="the layer") -> np.ndarray:
    """Geometries in the working CRS (the same call in the serial and the partition run,
    so coordinates agree to the bit)."""
    if _pyproj_crs(_layer_crs(df, source)) == _pyproj_crs(work_crs):
        return np.asarray(df.geometry.values, dtype=object)
    return np.asarray(df.geometry.to_crs(work_crs).values, dtype=object)


@dataclass
class BlockTable:
    """Target blocks of a source: feature ids, metric geometry, output ids, CRSs."""

    source: Source
    fids: np.ndarray
    geometry: np.ndarray
    block_ids: np.ndarray
    crs: Optional[str]       # of the source (outputs are written in it)
    work_crs: str            # metric CRS of the engine

    def __len__(self):
        return len(self.fids)


def _block_ids(df) -> np.ndarray:
    """The layer's block_id when it is a unique whole number per block, else 1..n (the
    rule of urbansynth:synthesizefootprints)."""
    return ids_or_numbers(df["block_id"] if "block_id" in df.columns else None, len(df))


def _polygon_table(source: str, df, ids: np.ndarray, work_crs) -> "BlockTable":
    """Polygons of a read layer in the metric working CRS (chosen from the data when
    ``work_crs`` is None), with their feature ids and output ids."""
    crs = _layer_crs(df, source).to_wkt()
    if work_crs is None:
        work_crs = metric_crs(df.crs, df.geometry.to_crs(4326).total_bounds)
    return BlockTable(source, df.index.to_numpy(dtype=np.int64),
                      _to_metric(df, work_crs, source), ids, crs, work_crs)


def read_blocks(source: Source, work_crs: Optional[str] = None) -> BlockTable:
    """Read a polygon layer of target blocks (in layer order) into the working CRS."""
    df = read_layer(source)
    name = str(source)
    if len(df) == 0:
        raise InputError(f"{name}: the layer holds no block")
    types = set(shapely.get_type_id(df.geometry.dropna().values).tolist())
    if not types or not types <= {3, 6}:
        raise InputError(f"{name}: blocks must be polygons (found "
                         f"{', '.join(sorted(set(df.geometry.geom_type.dropna())))})")
    return _polygon_table(source, df, _block_ids(df), work_crs)


def read_lines(source: Source, work_crs: str) -> np.ndarray:
    """Road centrelines of a line layer in the working CRS (in layer order)."""
    df = read_layer(source)
    df = df[df.geometry.notna()]
    if len(df) == 0:
        raise InputError(f"{source}: the layer holds no road")
    if not set(shapely.get_type_id(df.geometry.values).tolist()) <= {1, 5}:
        raise InputError(f"{source}: roads must be lines")
    return _to_metric(df, work_crs, source)


# --------------------------------------------------------------------------- partitions

def morton_keys(geoms: np.ndarray, bits: int = 16) -> np.ndarray:
    """Z-order key of each geometry's bounding-box centre (empty ones sort last)."""
    b = shapely.bounds(np.asarray(geoms, dtype=object))
    cx, cy = (b[:, 0] + b[:, 2]) / 2.0, (b[:, 1] + b[:, 3]) / 2.0
    ok = np.isfinite(cx) & np.isfinite(cy)
    keys = np.full(len(b), np.iinfo(np.int64).max, dtype=np.int64)
    if not ok.any():
        return keys
    scale = (1 << bits) - 1

    def q(v):
        lo, hi = v[ok].min(), v[ok].max()
        return np.round((v[ok] - lo) / (hi - lo or 1.0) * scale).astype(np.uint64)

    x, y = q(cx), q(cy)
    key = np.zeros(int(ok.sum()), dtype=np.uint64)
    for i in range(bits):   # interleave the bits of x and y
        key |= ((x >> np.uint64(i)) & np.uint64(1)) << np.uint64(2 * i)
        key |= ((y >> np.uint64(i)) & np.uint64(1)) << np.uint64(2 * i + 1)
    keys[ok] = key.astype(np.int64)
    return keys


def spatial_partitions(geoms: np.ndarray, n_partitions: int) -> List[np.ndarray]:
    """Block indices in ``n_partitions`` spatially compact runs of (nearly) equal size
    (Z-order), each sorted by index."""
    n = len(geoms)
    if n == 0:
        return []
    order = np.argsort(morton_keys(geoms), kind="stable")
    parts = np.array_split(order, max(1, min(int(n_partitions), n)))
    return [np.sort(p) for p in parts if len(p)]


class RoadIndex:
    """Road centrelines with an STR-tree built on first use (once per worker).

    The tree is rebuilt from the same array in the same order as in
    :func:`footprints.synthesize_footprints`, so ``near`` returns the same roads in the
    same order there and on every worker; it is not pickled."""

    def __init__(self, lines):
        self.lines = np.asarray(lines, dtype=object)
        self._tree = None

    def __getstate__(self):
        return {"lines": self.lines}

    def __setstate__(self, state):
        self.lines, self._tree = state["lines"], None

    def near(self, block):
        if block is None or len(self.lines) == 0:
            return None
        if self._tree is None:
            self._tree = shapely.STRtree(self.lines)
        return self.lines[self._tree.query(block, predicate="intersects")]


@dataclass
class FootprintJob:
    """What every block of a run shares (sent to each worker once)."""

    examples: Sequence[footprints.ExampleSet]
    roads: Optional[RoadIndex] = None
    method: str = "transfer"
    seed: int = 0
    street_width: float = footprints.STREET_WIDTH
    setback: float = 0.0
    n_best: int = 1


def _check(job: FootprintJob):
    if job.method not in footprints.METHODS:
        raise InputError(f"unknown method '{job.method}' (use one of "
                         f"{', '.join(footprints.METHODS)})")
    if not (np.isfinite(job.street_width) and job.street_width >= 0):
        raise InputError("the street width must be a non-negative number of metres")
    if not (np.isfinite(job.setback) and job.setback >= 0):
        raise InputError("the setback must be a non-negative number of metres")
    if not job.examples:
        raise InputError("at least one block database is needed")
    if int(job.n_best) < 1:
        raise InputError("n_best must be at least 1")


def _run_blocks(job: FootprintJob, geoms, index, ids, choice) -> List:
    """Footprints of some blocks (global ``index`` seeds each block's random choice):
    one (index, BlockLayout) per block."""
    out = []
    for g, i, bid, c in zip(geoms, index, ids, choice):
        near = job.roads.near(g) if job.roads is not None else None
        out.append((int(i), footprints.synthesize_block(
            g, job.examples, job.method, job.seed, int(i), job.street_width, job.setback,
            near, int(c), job.n_best, int(bid))))
    return out


def _run_partition(source: Source, work_crs: str, fids, index, ids, choice,
                   job: FootprintJob) -> List:
    """A Dask task: read this partition's blocks from the source, synthesise them."""
    df = read_layer(source, fids=fids)
    return _run_blocks(job, _to_metric(df, work_crs, source), index, ids, choice)


def _merge(parts: Sequence[List], seconds: float) -> footprints.FootprintResult:
    """Partitions back in block order (a Z-order partition is no run of indices)."""
    layouts = sorted((item for p in parts for item in p), key=lambda item: item[0])
    geoms = [g for _, lay in layouts for g in lay.geometry]
    tables = [lay.table for _, lay in layouts if len(lay.table)]
    table = pd.concat(tables, ignore_index=True) if tables else \
        pd.DataFrame(columns=[f for f, _ in footprints.OUTPUT_FIELDS])
    stats = pd.DataFrame([lay.stats for _, lay in layouts])
    return footprints.FootprintResult(np.array(geoms, dtype=object), table, stats, seconds)


# --------------------------------------------------------------------------- runs

def footprints_serial(blocks: BlockTable, job: FootprintJob,
                      block_database: Optional[Sequence[int]] = None,
                      progress: Optional[Progress] = None) -> footprints.FootprintResult:
    """The single-process reference: :func:`footprints.synthesize_footprints`."""
    _check(job)
    return footprints.synthesize_footprints(
        blocks.geometry, job.examples, job.method, street_width=job.street_width,
        setback=job.setback, seed=job.seed,
        roads=None if job.roads is None else job.roads.lines,
        block_database=block_database, block_ids=blocks.block_ids, n_best=job.n_best,
        progress=progress)


def footprints_distributed(client, blocks: BlockTable, job: FootprintJob,
                           block_database: Optional[Sequence[int]] = None,
                           n_partitions: Optional[int] = None, retries: int = 2,
                           progress: Optional[Progress] = None
                           ) -> footprints.FootprintResult:
    """Footprints of every block on a Dask cluster, equal to :func:`footprints_serial`.

    Parameters
    ----------
    client : distributed.Client
    blocks : the blocks as read by the driver (:func:`read_blocks`); each task re-reads
        its partition from ``blocks.source`` by feature id (the workers must reach it:
        a shared file system or a PostGIS server)
    job : databases, roads and parameters, broadcast to every worker once
    block_database : per block, the database index (-1: the best match of all)
    n_partitions : default 4 per worker, at most one per block
    retries : a task lost with its worker is run again (tasks are pure)

    Returns
    -------
    footprints.FootprintResult, blocks in layer order
    """
    from distributed import as_completed

    _check(job)
    progress = ensure(progress)
    t0 = time.perf_counter()
    n = len(blocks)
    choice = np.full(n, -1) if block_database is None else np.asarray(block_database)
    if n_partitions is None:
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        n_partitions = 4 * workers
    parts = spatial_partitions(blocks.geometry, n_partitions)
    shared = client.scatter(job, broadcast=True, hash=False)
    futures = [client.submit(_run_partition, for_workers(blocks.source), blocks.work_crs,
                             blocks.fids[p], p, blocks.block_ids[p], choice[p], shared,
                             pure=False, retries=retries) for p in parts]
    done, results = 0, []
    try:
        for fut in as_completed(futures):
            results.append(fut.result())
            done += len(results[-1])
            progress.step(done / max(n, 1))
    finally:
        for f in futures:
            f.cancel()
        shared.release()
    return _merge(results, time.perf_counter() - t0)


def write_footprints(path: str, result: footprints.FootprintResult, work_crs: str,
                     crs: Optional[str], layer: str = "footprints") -> int:
    """Write footprints (in the source CRS) to a GeoPackage layer; returns the count."""
    import geopandas as gpd

    table = result.table.copy()
    for name, kind in footprints.OUTPUT_FIELDS:
        if name not in table:
            table[name] = pd.Series(dtype=object)
        if kind == "int":
            table[name] = pd.to_numeric(table[name]).astype("int64")
        elif kind == "float":
            table[name] = pd.to_numeric(table[name]).astype(float)
        else:
            table[name] = table[name].astype(object)
    table = table[[f for f, _ in footprints.OUTPUT_FIELDS]]
    gdf = gpd.GeoDataFrame(table, geometry=list(result.geometry), crs=work_crs)
    if crs is not None and _pyproj_crs(crs) != _pyproj_crs(work_crs):
        gdf = gdf.to_crs(crs)
    return write_layer(gdf, path, layer)


# --------------------------------------------------------------------------- StreetGAN tiles

#: generators loaded in this process, by (path, threads): a worker opens each model once
_GENERATORS: dict = {}


def _generator(path: str, threads: int = 0):
    from ..roads import streetgan

    key = (str(path), int(threads))
    if key not in _GENERATORS:
        _GENERATORS[key] = streetgan.load_model(path, threads=threads)
    return _GENERATORS[key]


def _gan_tile(path: str, threads: int, z: np.ndarray, window) -> np.ndarray:
    """A Dask task: the generator on one noise window, cropped to the window's core."""
    img = _generator(path, threads).run(z)
    return img[window.crop_r:window.crop_r + window.h, window.crop_c:window.crop_c + window.w]


def gan_generate_distributed(client, model, rows_px: int, cols_px: int, seed: int = 0,
                             tile: Optional[int] = 24, progress: Optional[Progress] = None,
                             threads: int = 0, retries: int = 2) -> np.ndarray:
    """:func:`streetgan.generate` with its tiles run on a Dask cluster: the same image
    (``np.array_equal``) for the same seed.

    The driver draws the noise field once from ``seed`` (as ``generate`` does) and sends
    each task its noise window; the task runs the generator opened from ``model.path``
    (the workers must reach the file), once per worker process. Tiles are as large as in
    the serial run, so each window is the same computation on the same input.
    """
    from distributed import as_completed

    from ..roads import streetgan

    progress = ensure(progress)
    gen = model if isinstance(model, streetgan.Generator) else streetgan.load_model(model)
    if rows_px < 2 or cols_px < 2:
        raise InputError(f"the image must be at least 2 x 2 pixels, not {rows_px} x {cols_px}")
    s = gen.scale
    mr, mc = streetgan.noise_size(rows_px, s), streetgan.noise_size(cols_px, s)
    z = streetgan.noise(mr, mc, gen.channels, np.random.default_rng(seed))
    plan = streetgan.tile_plan(mr, mc, tile, s)
    out = np.empty((s * (mr - 1) + 1, s * (mc - 1) + 1), np.float32)
    path = str(Path(gen.path).resolve())
    futures = {}
    for w in plan:
        r0, r1, c0, c1 = w.noise
        fut = client.submit(_gan_tile, path, threads, np.ascontiguousarray(z[:, :, r0:r1, c0:c1]),
                            w, pure=False, retries=retries)
        futures[fut] = w
    try:
        for done, fut in enumerate(as_completed(list(futures)), 1):
            w = futures[fut]
            out[w.dest_r:w.dest_r + w.h, w.dest_c:w.dest_c + w.w] = fut.result()
            progress.step(done / len(plan))
    finally:
        for f in futures:
            f.cancel()
    return out[:rows_px, :cols_px]


def gan_synthesize_distributed(client, target, model, seed: int = 0, threads: int = 0,
                               progress: Optional[Progress] = None, **kwargs):
    """:func:`streetgan.synthesize` with the generator tiles on Dask; the raster-to-graph
    step runs once on the driver. Same result as the serial call for the same seed."""
    from ..roads import streetgan

    gen = model if isinstance(model, streetgan.Generator) else streetgan.load_model(model)

    def generate_fn(g, rows, cols, seed_, tile, prog):
        return gan_generate_distributed(client, g, rows, cols, seed_, tile, prog, threads)

    return streetgan.synthesize(target, gen, seed, progress=progress,
                                generate_fn=generate_fn, **kwargs)


def read_area(source: Source, work_crs: Optional[str] = None):
    """A target polygon layer as (union of its polygons in the metric CRS, source CRS,
    working CRS)."""
    df = read_layer(source)
    df = df[df.geometry.notna()]
    if len(df) == 0:
        raise InputError(f"{source}: the layer holds no polygon")
    if not set(shapely.get_type_id(df.geometry.values).tolist()) <= {3, 6}:
        raise InputError(f"{source}: the target must be polygons")
    crs = _layer_crs(df, source).to_wkt()
    if work_crs is None:
        work_crs = metric_crs(df.crs, df.geometry.to_crs(4326).total_bounds)
    return _to_metric(df, work_crs, source), crs, work_crs


def write_lines(path: str, geometry, table: pd.DataFrame, work_crs: str, crs: Optional[str],
                layer: str = "roads") -> int:
    """Write lines with a table (in the source CRS) to a GeoPackage layer."""
    import geopandas as gpd

    gdf = gpd.GeoDataFrame(table.reset_index(drop=True), geometry=list(geometry), crs=work_crs)
    if crs is not None and _pyproj_crs(crs) != _pyproj_crs(work_crs):
        gdf = gdf.to_crs(crs)
    return write_layer(gdf, path, layer)


# --------------------------------------------------------------------------- building attributes

#: metres added to the context radius around a partition (centroids on the boundary)
HALO_MARGIN = 10.0


@dataclass
class AttributeJob:
    """Examples and parameters of a building-attribute run (:func:`attributes_serial`,
    :func:`attributes_distributed`)."""

    examples: np.ndarray
    example_attributes: pd.DataFrame
    example_ids: Optional[np.ndarray] = None
    roads: Optional[np.ndarray] = None
    arterials: Optional[np.ndarray] = None
    example_roads: Optional[np.ndarray] = None
    example_arterials: Optional[np.ndarray] = None
    k: int = 9
    seed: int = 0
    min_height: float = 0.0
    max_height: float = 1000.0
    storey_height: float = 0.0       # 0: the engine's default
    choice_mode: str = "medoid"

    def engine_kwargs(self) -> dict:
        kw = dict(example_ids=self.example_ids, roads=self.roads, arterials=self.arterials,
                  example_roads=self.example_roads, example_arterials=self.example_arterials,
                  k=self.k, seed=self.seed, min_height=self.min_height,
                  max_height=self.max_height, choice_mode=self.choice_mode)
        if self.storey_height:
            kw["storey_height"] = self.storey_height
        return kw


@dataclass
class _AttributeShared:
    """Broadcast to every worker once: the target roads and the (later standardised)
    donor model."""

    roads: Optional[np.ndarray]
    arterials: Optional[np.ndarray]
    model: object


def read_footprints(source: Source, work_crs: Optional[str] = None) -> BlockTable:
    """Read a polygon layer of target footprints (in layer order) into the working CRS
    (a :class:`BlockTable`; its ``block_ids`` are 1..n)."""
    df = read_layer(source, columns=[])
    if len(df) == 0:
        raise InputError(f"{source}: the layer holds no footprint")
    missing = df.geometry.isna().to_numpy() | shapely.is_empty(df.geometry.values)
    if missing.any():
        # one output row per footprint: a footprint without an outline cannot be given one
        ids = df.index[missing].tolist()
        raise InputError(f"{source}: {len(ids)} footprint(s) have no geometry (feature id "
                         f"{', '.join(map(str, ids[:10]))}{' ...' if len(ids) > 10 else ''}):"
                         " remove them or give them their outline")
    if not set(shapely.get_type_id(df.geometry.values).tolist()) <= {3, 6}:
        raise InputError(f"{source}: footprints must be polygons (found "
                         f"{', '.join(sorted(set(df.geometry.geom_type)))})")
    return _polygon_table(source, df, np.arange(1, len(df) + 1, dtype=np.int64), work_crs)


def halo_partitions(geoms: np.ndarray, n_partitions: int, radius: float):
    """Spatial partitions of footprints, each with its halo: ``(core, halo)`` index arrays,
    ``halo`` (sorted, the core included) holding every footprint whose centroid lies
    within ``radius`` of the core's centroid bounding box."""
    c = shapely.get_coordinates(shapely.centroid(np.asarray(geoms, dtype=object)))
    out = []
    for core in spatial_partitions(geoms, n_partitions):
        lo, hi = c[core].min(axis=0) - radius, c[core].max(axis=0) + radius
        halo = np.flatnonzero(((c >= lo) & (c <= hi)).all(axis=1))
        out.append((core, halo))
    return out


def _check_attributes(job: AttributeJob):
    if job.choice_mode not in ("medoid", "random"):
        raise InputError(f"unknown choice mode '{job.choice_mode}' (medoid, random)")
    if not (job.k >= 1):
        raise InputError("k must be at least 1")
    if not (0 <= job.min_height < job.max_height):
        raise InputError(f"the height range {job.min_height:g}..{job.max_height:g} m is empty")


def attributes_serial(footprints_: BlockTable, job: AttributeJob,
                      progress: Optional[Progress] = None):
    """The single-process reference: :func:`building_attribute_transfer.transfer_attributes`
    on the whole layer (no target FAR)."""
    from ..buildings import attribute_transfer as bt

    _check_attributes(job)
    return bt.transfer_attributes(footprints_.geometry, job.examples, job.example_attributes,
                                  progress=progress, **job.engine_kwargs())


def _attr_features(source: Source, work_crs: str, fids, core_pos, shared: _AttributeShared):
    """A Dask task: read a partition and its halo, compute the core's features."""
    from ..buildings import attribute_transfer as bt

    g = _to_metric(read_layer(source, fids=fids, columns=[]), work_crs, source)
    fp = g[core_pos]
    f_t = bt.target_features(fp, g, shared.roads, shared.arterials, shared.model)
    return f_t, shapely.area(fp)


def _finite_columns(features) -> dict:
    f_t = features[0]
    return {c: bool(np.isfinite(f_t[c].to_numpy(dtype=float)).any()) for c in f_t.columns}


def _attr_match(features, model, k, choice_mode, uniforms, min_height, max_height):
    """A Dask task: donors and attributes of a partition's core footprints."""
    from ..buildings import attribute_transfer as bt

    f_t, area = features
    return bt.match_attributes(f_t, area, model, k, choice_mode, uniforms, min_height,
                               max_height)


def attributes_distributed(client, footprints_: BlockTable, job: AttributeJob,
                           n_partitions: Optional[int] = None, retries: int = 2,
                           progress: Optional[Progress] = None):
    """Building attributes of every footprint on a Dask cluster, equal to
    :func:`attributes_serial` (same values, same order).

    1. the driver builds the donor model from the examples once
       (:func:`building_attribute_transfer.donor_model`) and broadcasts it with the roads;
    2. each task reads a spatial partition of footprints plus a halo of
       ``CONTEXT_RADIUS + HALO_MARGIN`` m (by feature id, in layer order) and computes
       the core's features, which stay on the worker;
    3. the driver chooses the feature columns from all targets (some finite value) and
       standardises once (:meth:`DonorModel.standardise`), broadcasts the model again;
    4. each task matches its core; for ``choice_mode='random'`` the driver draws the
       serial run's one stream (``default_rng(seed).random((n, 1))``) and gives every
       task its footprints' draws, so the random choice is the serial one too.

    A target floor-area ratio is a whole-district step and is not offered here.
    """
    from distributed import as_completed

    from ..buildings import attribute_transfer as bt

    _check_attributes(job)
    progress = ensure(progress)
    t0 = time.perf_counter()
    n = len(footprints_)
    roads, art = job.roads, job.arterials
    use_roads = bool(roads is not None and job.example_roads is not None and len(roads)
                     and len(job.example_roads))
    use_art = bool(art is not None and job.example_arterials is not None and len(art)
                   and len(job.example_arterials))
    kw = {"storey_height": job.storey_height} if job.storey_height else {}
    model = bt.donor_model(job.examples, job.example_attributes, job.example_ids,
                           job.example_roads, job.example_arterials, use_roads, use_art, **kw)
    if n_partitions is None:
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        n_partitions = 4 * workers
    parts = halo_partitions(footprints_.geometry, n_partitions,
                            bt.CONTEXT_RADIUS + HALO_MARGIN)
    shared = client.scatter(_AttributeShared(roads if use_roads else None,
                                             art if use_art else None, model),
                            broadcast=True, hash=False)
    feats, model_f, matches = [], None, []
    try:
        for core, halo in parts:
            feats.append(client.submit(_attr_features, for_workers(footprints_.source),
                                       footprints_.work_crs, footprints_.fids[halo],
                                       np.searchsorted(halo, core), shared, pure=False,
                                       retries=retries))
        finite = client.gather([client.submit(_finite_columns, f, pure=False) for f in feats])
        progress.step(0.5)
        target_finite = {c: any(f[c] for f in finite) for c in finite[0]}
        std = model.standardise(target_finite)
        model_f = client.scatter(std, broadcast=True, hash=False)
        draws = np.random.default_rng(job.seed).random((n, 1)) \
            if job.choice_mode == "random" else None
        index = {}
        for (core, _), f in zip(parts, feats):
            fut = client.submit(_attr_match, f, model_f, job.k, job.choice_mode,
                                None if draws is None else draws[core], job.min_height,
                                job.max_height, pure=False, retries=retries)
            index[fut] = core
            matches.append(fut)
        order, tables, done = [], [], 0
        for fut in as_completed(matches):
            order.append(index[fut])
            tables.append(fut.result())
            done += len(order[-1])
            progress.step(0.5 + 0.5 * done / max(n, 1))
    finally:
        for f in feats + matches:
            f.cancel()
        shared.release()
        if model_f is not None:
            model_f.release()
    pos = np.concatenate(order)
    table = pd.concat(tables, ignore_index=True).iloc[np.argsort(pos, kind="stable")] \
        .reset_index(drop=True)
    stats = {"n_footprints": n, "n_examples": len(job.examples),
             "n_donors": int(model.donor.sum()), "features": ",".join(std.cols),
             "partitions": len(parts), "halo_footprints": int(sum(len(h) - len(c)
                                                                  for c, h in parts)),
             "seconds": time.perf_counter() - t0}
    return bt.AttributeTransfer(table, stats)
