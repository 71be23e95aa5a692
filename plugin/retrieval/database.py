"""Example databases as GeoPackage files: fragments and blocks, with retrieval.

The thesis keeps its examples in a "hierarchical database" of fragments (ch. 4.1.2) and a
block database D^m of real blocks with their footprints (ch. 5.1). Here both are
GeoPackages, an embedded spatial database that QGIS opens directly:

fragment database (format ``urbansynth-fragments``)
    ``fragments`` (polygons + the prefilter scalars), ``fragment_streets`` (interior
    streets with fragment_id and level), ``descriptors``, ``relief`` (when a DEM was given),
    ``metadata``.
block database (format ``urbansynth-blocks``)
    ``blocks`` (polygons + prefilter scalars), ``buildings`` (footprints with block_id and
    attributes), ``descriptors``, ``metadata``.

``descriptors`` holds per shape its 100 boundary samples (float64 x, y), the shape-context
histograms (uint8 counts, 100 x 40) and, for fragments with a DEM, the slope descriptors
(float32, 100 x 40), as BLOBs, so that loading a database gives numpy arrays ready for
vectorised retrieval without recomputation. ``metadata`` is a key/value table: format,
format version, CRS, source, sampling and histogram parameters (the absolute radial scale
of the shape context must be the same for database and query), creation time.

Spatial layers are written with GDAL's own bindings (:mod:`core.vector_io`, the GDAL every
QGIS ships); the non-spatial tables, which hold binary descriptor arrays, with the standard
library's sqlite3, registered in ``gpkg_contents`` as attribute tables.

Retrieval (:meth:`ExampleDatabase.prefilter`, :meth:`ExampleDatabase.query`) follows the
thesis: prefilter by area, aspect ratio and relief change (fragments, ch. 4.1.2) or by
area, perimeter and aspect ratio (blocks, ch. 5.1) to c = 10 candidates, then shape context
(+ slope term) with cyclic DTW on the candidates, and a rigid alignment of the best match
from the DTW correspondences.

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 4.1.2
(hierarchical fragment database, retrieval with prefilter c = 10) and ch. 5.1 (block
database, retrieval, Procrustes alignment).
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import sqlite3
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import pandas as pd
import shapely

from ..core import vector_io
from ..core.geometry import counter_clockwise
from ..core.progress import InputError, Progress, ensure
from ..network.blocks import shape_metrics
from ..network.fragments import Fragments
from . import shape_context as sc

__all__ = [
    "FRAGMENT_FORMAT", "BLOCK_FORMAT", "FORMAT_VERSION", "N_CANDIDATES", "BUILDING_FIELDS",
    "Descriptors", "Match", "ExampleDatabase", "FragmentDatabase", "BlockDatabase",
    "compute_descriptors", "write_fragment_database", "write_block_database",
    "load_fragment_database", "load_block_database", "read_metadata",
]

FRAGMENT_FORMAT = "urbansynth-fragments"
BLOCK_FORMAT = "urbansynth-blocks"
#: Version of both formats written by this module; readers accept versions up to it.
FORMAT_VERSION = 1
#: Candidates kept by the prefilter for the DTW comparison (thesis: c = 10).
N_CANDIDATES = 10
#: Building attributes copied into a block database when present.
BUILDING_FIELDS = ("height_m", "height_estimated", "levels", "building_type", "building_tag")

_GPKG_APPLICATION_IDS = {0x47504B47, 0x47503130, 0x47503131}  # 'GPKG', 'GP10', 'GP11'
_KINDS = {FRAGMENT_FORMAT: "fragment", BLOCK_FORMAT: "block"}


# --------------------------------------------------------------------------- descriptors

@dataclass
class Descriptors:
    """Shape descriptors of k shapes, as stored in a database's ``descriptors`` table.

    Attributes
    ----------
    samples : (k, n, 2) float64 boundary samples (counter-clockwise, canonical start)
    counts : (k, n, B) uint8 shape-context histogram counts
    slopes : (k, n, B) float32 slope descriptors, or None without terrain
    scale : float, the shape-context scale in metres (radial edges = scale * logspace)
    n_angular : int
    """

    samples: np.ndarray
    counts: np.ndarray
    slopes: Optional[np.ndarray]
    scale: float
    n_angular: int = sc.N_ANGULAR
    n_radial: int = sc.N_RADIAL
    inner: float = sc.INNER
    outer: float = sc.OUTER

    @property
    def edges(self) -> np.ndarray:
        return sc.radial_edges(self.scale, self.n_radial, self.inner, self.outer)

    def parameters(self) -> Dict[str, str]:
        return {
            "n_samples": str(self.samples.shape[1]), "n_angular": str(self.n_angular),
            "n_radial": str(self.n_radial), "sc_inner": repr(self.inner),
            "sc_outer": repr(self.outer), "sc_scale_m": repr(self.scale),
            "sample_start": "ring vertex farthest from the centroid; counter-clockwise",
            "histogram_encoding": "uint8 counts; bin = radial * n_angular + angular; "
                                  "angular bin a centred a*360/n_angular deg from the tangent",
            "has_slopes": str(int(self.slopes is not None)),
        }


def compute_descriptors(polygons: Sequence, scale: Optional[float] = None,
                        n_samples: int = sc.N_SAMPLES, n_angular: int = sc.N_ANGULAR,
                        n_radial: int = sc.N_RADIAL,
                        elevation=None) -> Descriptors:
    """Boundary samples, shape contexts and (optionally) slope descriptors of polygons.

    Parameters
    ----------
    polygons : array of Polygon (metric CRS)
    scale : float, optional
        Shape-context scale in metres; by default the median mean inter-sample distance of
        these polygons (:func:`shape_context.default_scale`), stored with the database.
    n_samples, n_angular, n_radial : int
        Thesis ch. 5.1: 100 samples, 8 x 5 bins.
    elevation : callable, optional
        ``elevation(xy) -> heights`` (a :class:`shape_context.DemGrid`): adds the slope
        descriptors of the thesis's eq. 4.3.

    Returns
    -------
    Descriptors
    """
    samples = sc.sample_boundaries(polygons, n_samples)
    if scale is None:
        scale = sc.default_scale(samples)
    edges = sc.radial_edges(scale, n_radial)
    counts = sc.shape_contexts(samples, edges, n_angular)
    slopes = None
    if elevation is not None:
        slopes = sc.slope_descriptors(samples, elevation, edges, n_angular)
    return Descriptors(samples, counts, slopes, float(scale), n_angular, n_radial)


# --------------------------------------------------------------------------- writing

def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def _register_table(con: sqlite3.Connection, table: str, description: str) -> None:
    con.execute("INSERT OR REPLACE INTO gpkg_contents (table_name, data_type, identifier, "
                "description, last_change) VALUES (?, 'attributes', ?, ?, "
                "strftime('%Y-%m-%dT%H:%M:%fZ','now'))", (table, table, description))


def _write_tables(path: str, descriptors: Descriptors, ids: np.ndarray, id_name: str,
                  metadata: Dict[str, str], relief=None) -> None:
    """Add the non-spatial tables (descriptors, metadata, relief) to a GeoPackage."""
    con = sqlite3.connect(path)
    # the file is a temporary one, renamed into place when complete: no need to pay for
    # journal and fsync (they took longer than writing the descriptors)
    con.execute("PRAGMA synchronous = OFF")
    con.execute("PRAGMA journal_mode = MEMORY")
    try:
        with con:
            con.execute(f"CREATE TABLE descriptors (fid INTEGER PRIMARY KEY AUTOINCREMENT, "
                        f"{id_name} INTEGER NOT NULL UNIQUE, n_samples INTEGER NOT NULL, "
                        "samples BLOB NOT NULL, shape_context BLOB NOT NULL, slopes BLOB)")
            n = descriptors.samples.shape[1]
            slopes = descriptors.slopes
            rows = ((int(i), n, descriptors.samples[k].astype("<f8").tobytes(),
                     descriptors.counts[k].astype(np.uint8).tobytes(),
                     None if slopes is None else slopes[k].astype("<f4").tobytes())
                    for k, i in enumerate(ids))
            con.executemany(f"INSERT INTO descriptors ({id_name}, n_samples, samples, "
                            "shape_context, slopes) VALUES (?, ?, ?, ?, ?)", rows)
            _register_table(con, "descriptors", "Boundary samples (float64 x,y), shape-context "
                            "counts (uint8) and slope descriptors (float32) per shape")
            if relief is not None:
                patches, transforms = relief
                con.execute(f"CREATE TABLE relief (fid INTEGER PRIMARY KEY AUTOINCREMENT, "
                            f"{id_name} INTEGER NOT NULL UNIQUE, x_min REAL, y_max REAL, "
                            "cell_size REAL, n_rows INTEGER, n_cols INTEGER, "
                            "heights BLOB NOT NULL)")
                con.executemany(
                    f"INSERT INTO relief ({id_name}, x_min, y_max, cell_size, n_rows, n_cols, "
                    "heights) VALUES (?, ?, ?, ?, ?, ?, ?)",
                    ((int(i), float(t[0]), float(t[3]), float(t[1]), int(p.shape[0]),
                      int(p.shape[1]), p.astype("<f4").tobytes())
                     for i, p, t in zip(ids, patches, transforms)))
                _register_table(con, "relief", "Relief patch (float32 heights, rows north to "
                                "south) over each fragment's bounding box")
            con.execute("CREATE TABLE metadata (fid INTEGER PRIMARY KEY AUTOINCREMENT, "
                        "key TEXT NOT NULL UNIQUE, value TEXT)")
            con.executemany("INSERT INTO metadata (key, value) VALUES (?, ?)",
                            sorted(metadata.items()))
            _register_table(con, "metadata", "Urban Synthesis database format, version, CRS, "
                            "source and descriptor parameters")
    finally:
        con.close()


def _plain_column(values: pd.Series) -> pd.Series:
    """An attribute column GDAL can store: numbers stay numbers, anything else text.

    Attribute tables read from QGIS hold Python objects (ints with None for nulls, bools,
    strings); a GeoPackage field has one type.
    """
    v = values.reset_index(drop=True)
    if v.dtype != object:
        return v
    present = v.dropna()
    if len(present) and all(isinstance(x, (bool, np.bool_)) for x in present):
        return v.astype("boolean")
    if all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in present):
        return v.astype("Int64")
    if all(isinstance(x, (int, float, np.integer, np.floating)) for x in present):
        return pd.to_numeric(v, errors="coerce").astype(np.float64)
    return v.map(lambda x: None if x is None or (isinstance(x, float) and np.isnan(x))
                 else str(x)).astype(object)


def _largest_parts(geoms: np.ndarray) -> np.ndarray:
    parts, idx = shapely.get_parts(geoms, return_index=True)
    poly = shapely.get_type_id(parts) == 3
    parts, idx = parts[poly], idx[poly]
    if len(np.unique(idx)) != len(geoms):
        raise InputError("every block must be a polygon")
    order = np.lexsort((-shapely.area(parts), idx))
    return parts[order[np.r_[True, idx[order][1:] != idx[order][:-1]]]]


def _atomic_target(path: str) -> str:
    """A temporary file next to ``path``: the database appears complete or not at all."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(folder):
        raise InputError(f"the output folder {folder} does not exist")
    return os.path.join(folder, f".{os.path.basename(path)}.{uuid.uuid4().hex[:8]}.tmp.gpkg")


@contextlib.contextmanager
def _atomic_gpkg(path: str):
    """Yield a temporary file next to ``path``; it replaces ``path`` only when the block
    completes, so a failure or a cancel never leaves a half-written database behind."""
    tmp = _atomic_target(path)
    sidecars = ("-wal", "-shm", "-journal")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    finally:
        for suffix in sidecars:
            if os.path.exists(tmp + suffix):
                os.remove(tmp + suffix)


def _metadata(fmt: str, crs: str, source: str, descriptors: Descriptors,
              extra: Dict) -> Dict[str, str]:
    meta = {"format": fmt, "format_version": str(FORMAT_VERSION), "crs": crs,
            "source": source or "", "created": _now(), "generator": "Urban Synthesis (QGIS)"}
    meta.update(descriptors.parameters())
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in extra.items()})
    return meta


def write_fragment_database(path: str, fragments: Fragments, crs: str, source: str = "",
                            scale: Optional[float] = None, elevation=None,
                            extra: Optional[Dict] = None,
                            progress: Optional[Progress] = None) -> Descriptors:
    """Write a fragment database (GeoPackage), replacing any file at ``path``.

    Parameters
    ----------
    path : str, the .gpkg file
    fragments : Fragments from :func:`fragments.extract_fragments`
    crs : str, the metric CRS of the geometries (authority id such as 'EPSG:32635' or WKT)
    source : str, what the database was built from (recorded in metadata)
    scale : float, optional shape-context scale (default: from these fragments)
    elevation : callable, optional; the DEM used for the slope descriptors
    extra : dict, more metadata entries

    Returns
    -------
    Descriptors, as written.

    References
    ----------
    Hartmann, thesis ch. 4.1.2 (fragments with boundary, interior streets and relief in a
    hierarchical database).
    """
    progress = ensure(progress)
    if len(fragments) == 0:
        raise InputError("no fragments to write")
    desc = compute_descriptors(fragments.geometry, scale, elevation=elevation)
    progress.step(0.4)
    table = fragments.table
    ids = table["fragment_id"].to_numpy()
    with _atomic_gpkg(path) as tmp:
        vector_io.write_layer(tmp, "fragments", table, fragments.geometry, crs, "Polygon")
        progress.step(0.6)
        streets = pd.DataFrame({
            "fragment_id": ids[fragments.street_fragment] if len(fragments.street_fragment)
            else np.zeros(0, np.int64),
            "level": fragments.street_level,
            "length_m": shapely.length(fragments.street_geometry),
        })
        vector_io.write_layer(tmp, "fragment_streets", streets, fragments.street_geometry, crs,
                              "LineString")
        progress.step(0.8)
        relief = None
        if fragments.patches is not None:
            relief = (fragments.patches, fragments.patch_transform)
        levels = table.groupby("level").size()
        meta = _metadata(FRAGMENT_FORMAT, crs, source, desc, {
            "n_fragments": len(table), "levels": [int(v) for v in levels.index],
            "fragments_per_level": {str(int(k)): int(v) for k, v in levels.items()},
            "has_relief": str(int(relief is not None)),
            **(extra or {})})
        _write_tables(tmp, desc, ids, "fragment_id", meta, relief)
    progress.step(1.0)
    return desc


def write_block_database(path: str, blocks: Sequence, buildings: Sequence,
                         building_block: Sequence, crs: str,
                         block_ids: Optional[Sequence] = None,
                         building_attributes: Optional[pd.DataFrame] = None,
                         source: str = "", scale: Optional[float] = None,
                         extra: Optional[Dict] = None,
                         progress: Optional[Progress] = None) -> Descriptors:
    """Write a block database (GeoPackage), replacing any file at ``path``.

    Parameters
    ----------
    path : str, the .gpkg file
    blocks : array of Polygon (metric CRS)
    buildings : array of Polygon / MultiPolygon footprints
    building_block : per building, the block id it belongs to (must be in ``block_ids``)
    crs : str, the CRS of the geometries (authority id or WKT)
    block_ids : per block, its id (default 1..n)
    building_attributes : DataFrame, one row per building (e.g. :data:`BUILDING_FIELDS`)
    source, scale, extra : as in :func:`write_fragment_database`

    Returns
    -------
    Descriptors of the blocks, as written.

    References
    ----------
    Hartmann, thesis ch. 5.1: the block database D^m of blocks D = (B, P) with their
    footprints, retrieved by shape context on 100 boundary samples.
    """
    progress = ensure(progress)
    blocks = np.asarray(blocks, dtype=object)
    buildings = np.asarray(buildings, dtype=object)
    if len(blocks) == 0:
        raise InputError("no blocks to write")
    # a block is one face: keep the largest part of a multipolygon (exterior_rings does the
    # same for the descriptors), so the layer holds plain polygons
    if (shapely.get_type_id(blocks) != 3).any():
        blocks = _largest_parts(blocks)
    # one way round (a shapefile's are clockwise, OSM's either way): the same blocks and
    # buildings, the same database
    blocks = counter_clockwise(blocks)
    buildings = counter_clockwise(buildings)
    ids = np.arange(1, len(blocks) + 1) if block_ids is None else np.asarray(block_ids)
    if len(ids) != len(blocks) or len(np.unique(ids)) != len(ids):
        raise InputError("block ids must be unique, one per block")
    ids = ids.astype(np.int64)
    bb = np.asarray(building_block, dtype=np.int64)
    if len(bb) != len(buildings):
        raise InputError("one block id per building is needed")
    if len(bb) and not np.isin(bb, ids).all():
        raise InputError("some buildings name a block id that is not among the blocks")
    pos = np.searchsorted(np.sort(ids), bb)
    desc = compute_descriptors(blocks, scale)
    progress.step(0.4)
    metrics = shape_metrics(blocks)
    order = np.argsort(ids)
    block_index = order[pos] if len(bb) else np.zeros(0, np.int64)
    b_area = shapely.area(buildings) if len(buildings) else np.zeros(0)
    n_b = np.bincount(block_index, minlength=len(blocks))
    covered = np.bincount(block_index, weights=b_area, minlength=len(blocks))
    table = pd.DataFrame({
        "block_id": ids,
        "area_m2": metrics["area_m2"].to_numpy(), "perimeter_m": metrics["perimeter_m"].to_numpy(),
        "compactness": metrics["compactness"].to_numpy(),
        "aspect_ratio": metrics["aspect_ratio"].to_numpy(),
        "n_buildings": n_b,
        "coverage": np.minimum(covered / np.maximum(metrics["area_m2"].to_numpy(), 1e-9), 1.0),
    })
    attrs = pd.DataFrame(index=range(len(buildings))) if building_attributes is None \
        else building_attributes.reset_index(drop=True)
    btable = pd.DataFrame({"building_id": np.arange(1, len(buildings) + 1), "block_id": bb,
                           "area_m2": b_area})
    for name in attrs.columns:
        if name not in btable:
            btable[name] = _plain_column(attrs[name])
    with _atomic_gpkg(path) as tmp:
        vector_io.write_layer(tmp, "blocks", table, blocks, crs, "Polygon")
        progress.step(0.6)
        vector_io.write_layer(tmp, "buildings", btable, buildings, crs, "MultiPolygon")
        progress.step(0.8)
        meta = _metadata(BLOCK_FORMAT, crs, source, desc, {
            "n_blocks": len(blocks), "n_buildings": len(buildings), **(extra or {})})
        _write_tables(tmp, desc, ids, "block_id", meta)
    progress.step(1.0)
    return desc


# --------------------------------------------------------------------------- reading

def _open(path) -> sqlite3.Connection:
    """Open a GeoPackage read-only, with a clear InputError for anything else."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"the database file {p} does not exist")
    if not p.is_file():
        raise InputError(f"{p} is not a file")
    with open(p, "rb") as fh:
        header = fh.read(100)
    if len(header) < 100 or not header.startswith(b"SQLite format 3\x00"):
        raise InputError(f"{p} is not a GeoPackage (not an SQLite database file)")
    try:
        con = sqlite3.connect(p.resolve().as_uri() + "?mode=ro", uri=True)
        app_id = con.execute("PRAGMA application_id").fetchone()[0]
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{p} is damaged and cannot be read as a GeoPackage ({exc})") from exc
    if app_id not in _GPKG_APPLICATION_IDS or "gpkg_contents" not in tables:
        con.close()
        raise InputError(f"{p} is an SQLite database but not a GeoPackage")
    return con


def read_metadata(path) -> Dict[str, str]:
    """The ``metadata`` key/value table of an Urban Synthesis database.

    Raises
    ------
    InputError
        Missing file, not a GeoPackage, damaged file, or a GeoPackage that is not an
        Urban Synthesis database.
    """
    con = _open(path)
    try:
        try:
            rows = con.execute("SELECT key, value FROM metadata").fetchall()
        except sqlite3.OperationalError as exc:
            raise InputError(f"{path} is a GeoPackage but not an Urban Synthesis example "
                             "database (it has no metadata table)") from exc
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{path} is damaged ({exc})") from exc
    finally:
        con.close()
    return dict(rows)


def _check_format(path, meta: Dict[str, str], expected: str) -> int:
    fmt = meta.get("format")
    if fmt != expected:
        got = _KINDS.get(fmt)
        what = f"a {got} database" if got else f"of unknown format {fmt!r}"
        raise InputError(f"{path} is {what}; a {_KINDS[expected]} database "
                         f"(format '{expected}') is needed")
    try:
        version = int(meta.get("format_version", ""))
    except ValueError as exc:
        raise InputError(f"{path} has no valid format version") from exc
    if version > FORMAT_VERSION or version < 1:
        raise InputError(f"{path} has format version {version}; this plugin reads versions "
                         f"1 to {FORMAT_VERSION} (update the plugin or rebuild the database)")
    return version


def _read_descriptors(con, path, id_name: str, meta: Dict[str, str]):
    try:
        rows = con.execute(f"SELECT {id_name}, n_samples, samples, shape_context, slopes "
                           "FROM descriptors ORDER BY fid").fetchall()
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{path}: the descriptors table cannot be read ({exc})") from exc
    try:
        n = int(meta["n_samples"])
        n_bins = int(meta["n_angular"]) * int(meta["n_radial"])
        ids = np.array([r[0] for r in rows], dtype=np.int64)
        samples = np.frombuffer(b"".join(r[2] for r in rows), dtype="<f8").reshape(-1, n, 2)
        counts = np.frombuffer(b"".join(r[3] for r in rows), dtype=np.uint8).reshape(-1, n, n_bins)
        slopes = None
        if rows and all(r[4] is not None for r in rows):
            slopes = np.frombuffer(b"".join(r[4] for r in rows),
                                   dtype="<f4").reshape(-1, n, n_bins)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{path}: the descriptors are inconsistent with the metadata "
                         f"({exc})") from exc
    if len(samples) != len(ids) or len(counts) != len(ids):
        raise InputError(f"{path}: the descriptors table is incomplete")
    desc = Descriptors(samples, counts, slopes, float(meta["sc_scale_m"]), int(meta["n_angular"]),
                       int(meta["n_radial"]), float(meta.get("sc_inner", sc.INNER)),
                       float(meta.get("sc_outer", sc.OUTER)))
    return ids, desc


@dataclass
class Match:
    """One retrieved example shape.

    Attributes
    ----------
    index : int, row in the database's arrays
    id : int, fragment_id or block_id
    cost : float, total cyclic DTW cost (sum of point costs along the path)
    offset : int, the example sample matched with the query's first sample
    path : (p, 2) int array, (query sample, example sample) correspondences
    rotation, translation : the rigid transform ``x -> R x + t`` that maps the example onto
        the query (least squares over the correspondences, thesis ch. 5.1)
    rms : float, root mean square distance of the corresponding samples after alignment (m)
    """

    index: int
    id: int
    cost: float
    offset: int
    path: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    rms: float

    def transform(self, geoms: Sequence) -> np.ndarray:
        """Apply the alignment to example geometries (e.g. its footprints or streets)."""
        return sc.transform_geometries(geoms, self.rotation, self.translation)


@dataclass
class ExampleDatabase:
    """A loaded example database: shapes, their attributes and descriptors.

    Attributes
    ----------
    path : str
    metadata : dict of str
    crs : str, CRS of all geometries (authority id or WKT)
    geometry : ndarray of Polygon, one per shape (fragments or blocks)
    table : DataFrame, their attributes (the prefilter scalars among them)
    ids : int array, fragment_id / block_id per row
    descriptors : Descriptors
    """

    path: str
    metadata: Dict[str, str]
    crs: str
    geometry: np.ndarray
    table: pd.DataFrame
    ids: np.ndarray
    descriptors: Descriptors
    _hist: Optional[np.ndarray] = field(default=None, repr=False)

    def __len__(self):
        return len(self.ids)

    @property
    def histograms(self) -> np.ndarray:
        """Normalised shape-context histograms (k, n, B) float32, computed once."""
        if self._hist is None:
            self._hist = sc.normalised_histograms(self.descriptors.counts)
        return self._hist

    # ------------------------------------------------------------------ retrieval

    def _features(self, rows: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _query_features(self, **scalars) -> np.ndarray:
        raise NotImplementedError

    def _candidate_rows(self, level: Optional[int]) -> np.ndarray:
        return np.arange(len(self))

    def prefilter(self, c: int = N_CANDIDATES, level: Optional[int] = None,
                  **scalars) -> np.ndarray:
        """Indices of the ``c`` shapes nearest the query in the prefilter features.

        Features are standardised over the database (log area, aspect ratio and, for
        fragments, relief change; log perimeter for blocks), so each counts about equally;
        the nearest ``c`` by Euclidean distance are returned, nearest first.

        Parameters
        ----------
        c : int, number of candidates (thesis: 10)
        level : int, fragments only: retrieve among this level (the nearest level present
            when the database has none of it)
        area, aspect, relief, perimeter : float, the query's scalars (keywords; relief is
            ignored without relief in the database, perimeter without blocks)

        Returns
        -------
        int array of row indices, at most ``c`` long.

        References
        ----------
        Hartmann, thesis ch. 4.1.2 ("cluster the database fragments of level l by size,
        aspect ratio and relative elevation change, and keep the first c = 10 candidates")
        and ch. 5.1 ("pre-prune by area, outline length and aspect ratio").
        """
        if c < 1:
            raise InputError("at least one candidate is needed")
        rows = self._candidate_rows(level)
        if len(rows) == 0:
            return rows
        feats = self._features(rows)
        q = self._query_features(**scalars)
        mu = np.nanmean(feats, axis=0)
        sd = np.nanstd(feats, axis=0)
        sd = np.where(sd > 1e-12, sd, 1.0)
        z = (feats - mu) / sd
        zq = (q - mu) / sd
        d = np.nansum((z - zq) ** 2, axis=1)
        if len(rows) > c:
            keep = np.argpartition(d, c - 1)[:c]
        else:
            keep = np.arange(len(rows))
        keep = keep[np.argsort(d[keep], kind="stable")]
        return rows[keep]

    def query(self, polygon=None, samples: Optional[np.ndarray] = None,
              candidates: Optional[np.ndarray] = None, c: int = N_CANDIDATES,
              level: Optional[int] = None, elevation=None, gamma: float = 0.5,
              n_best: int = 1, relief: Optional[float] = None,
              exact: bool = False) -> List[Match]:
        """The best matching example shapes for a query, best first.

        The query is a polygon (sampled here, prefilter scalars computed from it) or
        ``samples`` (k = 1, n, 2) with explicit ``candidates``. Candidates are scored by
        shape context (+ the slope term when ``elevation`` is given and the database has
        slope descriptors: ``gamma C^S + (1 - gamma) C^E``) with cyclic DTW; the ``n_best``
        are aligned to the query by a least-squares rigid transform.

        Parameters
        ----------
        polygon : Polygon, optional, the query shape (metric CRS of the database)
        samples : (n, 2) array, optional, the query's boundary samples
        candidates : int array, optional, rows to score (default: :meth:`prefilter`)
        c : int, prefilter size (thesis: 10)
        level : int, fragments: the query level
        elevation : callable, optional, the query's terrain (``DemGrid``)
        gamma : float in [0, 1], weight of the shape term (the thesis gives none)
        n_best : int, matches returned
        relief : float, the query's relief change for the prefilter (default: none)
        exact : bool, try every DTW start offset and path (slower; default uses the
            offset ranking and the adjustment window of :func:`cyclic_dtw_costs`)

        Returns
        -------
        list of Match, lowest cost first.

        References
        ----------
        Hartmann, thesis ch. 4.1.2 (retrieval, eqs. 4.1-4.3) and ch. 5.1 (retrieval and
        alignment).
        """
        desc = self.descriptors
        n = desc.samples.shape[1]
        if samples is None:
            if polygon is None:
                raise InputError("a query polygon or its boundary samples are needed")
            samples = sc.sample_boundaries([polygon], n)[0]
        samples = np.asarray(samples, dtype=np.float64)
        if samples.shape != (n, 2):
            raise InputError(f"the query needs {n} boundary samples, got {samples.shape}")
        if candidates is None:
            if polygon is None:
                raise InputError("without a query polygon, give the candidate rows")
            m = shape_metrics([polygon])
            candidates = self.prefilter(c, level=level, area=float(m["area_m2"][0]),
                                        aspect=float(m["aspect_ratio"][0]),
                                        perimeter=float(m["perimeter_m"][0]), relief=relief)
        candidates = np.asarray(candidates, dtype=np.int64)
        if len(candidates) == 0:
            return []
        edges = desc.edges
        qh = sc.normalised_histograms(sc.shape_contexts(samples, edges, desc.n_angular))
        qsl = csl = None
        if elevation is not None and desc.slopes is not None and gamma < 1:
            qsl = sc.slope_descriptors(samples, elevation, edges, desc.n_angular)
            csl = desc.slopes[candidates]
        cost = sc.combined_cost(qh[None], self.histograms[candidates],
                                None if qsl is None else qsl[None], csl, gamma)
        if exact:
            totals, offsets = sc.cyclic_dtw_costs(cost, None, None)
        else:
            totals, offsets = sc.cyclic_dtw_costs(cost)
        order = np.argsort(totals, kind="stable")[:max(1, int(n_best))]
        matches = []
        for k in order:
            total, path = sc.dtw_path(cost[k], int(offsets[k]))
            row = int(candidates[k])
            r, t, rms = sc.rigid_align(desc.samples[row][path[:, 1]], samples[path[:, 0]])
            matches.append(Match(row, int(self.ids[row]), float(totals[k]), int(offsets[k]),
                                 path, r, t, rms))
        return matches

    def query_best(self, polygon=None, **kwargs) -> Optional[Match]:
        """The single best match of :meth:`query` (None for an empty candidate set)."""
        matches = self.query(polygon, n_best=1, **kwargs)
        return matches[0] if matches else None


@dataclass
class FragmentDatabase(ExampleDatabase):
    """A loaded fragment database (:func:`load_fragment_database`).

    Extra attributes: ``streets`` (DataFrame with fragment_id, level, length_m) and
    ``street_geometry``; ``relief`` {fragment_id: (heights float32 array, geotransform)}
    when the database has relief.
    """

    streets: Optional[pd.DataFrame] = None
    street_geometry: Optional[np.ndarray] = None
    relief: Optional[Dict[int, tuple]] = None

    @property
    def levels(self) -> np.ndarray:
        return self.table["level"].to_numpy()

    def _candidate_rows(self, level):
        if level is None:
            return np.arange(len(self))
        levels = self.levels
        present = np.unique(levels)
        if len(present) == 0:
            return np.zeros(0, dtype=np.int64)
        nearest = present[np.argmin(np.abs(present - level) + 1e-3 * (present > level))]
        return np.flatnonzero(levels == nearest)

    def _features(self, rows):
        t = self.table.iloc[rows]
        f = [np.log(np.maximum(t["area_m2"].to_numpy(), 1e-9)), t["aspect_ratio"].to_numpy()]
        if t["relief_m"].notna().any():
            f.append(t["relief_m"].to_numpy(dtype=np.float64))
        return np.column_stack(f)

    def _query_features(self, area=None, aspect=None, relief=None, **_):
        if area is None or aspect is None:
            raise InputError("the fragment prefilter needs the query's area and aspect ratio")
        f = [np.log(max(area, 1e-9)), aspect]
        if self.table["relief_m"].notna().any():
            f.append(np.nan if relief is None else relief)
        return np.array(f, dtype=np.float64)

    def streets_of(self, fragment_id: int) -> np.ndarray:
        """Interior street geometries of one fragment."""
        return self.street_geometry[self.streets["fragment_id"].to_numpy() == fragment_id]


@dataclass
class BlockDatabase(ExampleDatabase):
    """A loaded block database (:func:`load_block_database`).

    Extra attributes: ``buildings`` (DataFrame with building_id, block_id and the building
    attributes) and ``building_geometry``.
    """

    buildings: Optional[pd.DataFrame] = None
    building_geometry: Optional[np.ndarray] = None

    def _features(self, rows):
        t = self.table.iloc[rows]
        return np.column_stack([np.log(np.maximum(t["area_m2"].to_numpy(), 1e-9)),
                                np.log(np.maximum(t["perimeter_m"].to_numpy(), 1e-9)),
                                t["aspect_ratio"].to_numpy()])

    def _query_features(self, area=None, aspect=None, perimeter=None, **_):
        if area is None or aspect is None:
            raise InputError("the block prefilter needs the query's area and aspect ratio")
        per = np.nan if perimeter is None else np.log(max(perimeter, 1e-9))
        return np.array([np.log(max(area, 1e-9)), per, aspect], dtype=np.float64)

    def buildings_of(self, block_id: int):
        """Footprints and attribute rows of one block."""
        sel = self.buildings["block_id"].to_numpy() == block_id
        return self.building_geometry[sel], self.buildings[sel]


def _load(path, fmt: str, shape_layer: str, id_name: str):
    meta = read_metadata(path)
    _check_format(path, meta, fmt)
    con = _open(path)
    try:
        ids, desc = _read_descriptors(con, path, id_name, meta)
        relief = None
        if fmt == FRAGMENT_FORMAT and meta.get("has_relief") == "1":
            try:
                rows = con.execute(f"SELECT {id_name}, x_min, y_max, cell_size, n_rows, n_cols, "
                                   "heights FROM relief").fetchall()
            except sqlite3.DatabaseError as exc:
                raise InputError(f"{path}: the relief table cannot be read ({exc})") from exc
            relief = {int(r[0]): (np.frombuffer(r[6], dtype="<f4").reshape(r[4], r[5]),
                                  (r[1], r[3], 0.0, r[2], 0.0, -r[3])) for r in rows}
    finally:
        con.close()
    table, geoms = vector_io.read_layer(path, shape_layer)
    if id_name not in table or len(table) != len(ids):
        raise InputError(f"{path}: layer '{shape_layer}' does not match its descriptors")
    # align the shape rows with the descriptor rows by id
    pos = pd.Index(table[id_name].to_numpy()).get_indexer(ids)
    if (pos < 0).any():
        raise InputError(f"{path}: layer '{shape_layer}' does not match its descriptors")
    table = table.iloc[pos].reset_index(drop=True)
    return meta, ids, desc, table, geoms[pos], relief


def load_fragment_database(path) -> FragmentDatabase:
    """Open a fragment database written by :func:`write_fragment_database`.

    Raises
    ------
    InputError
        With a sentence saying what is wrong: missing file, not a GeoPackage, damaged,
        not an Urban Synthesis database, a block database instead, a newer format version.
    """
    meta, ids, desc, table, geoms, relief = _load(path, FRAGMENT_FORMAT, "fragments",
                                                  "fragment_id")
    streets, street_geoms = vector_io.read_layer(path, "fragment_streets")
    return FragmentDatabase(str(path), meta, meta.get("crs", ""), geoms, table, ids, desc,
                            streets=streets, street_geometry=street_geoms, relief=relief)


def load_block_database(path) -> BlockDatabase:
    """Open a block database written by :func:`write_block_database`.

    Raises
    ------
    InputError
        As :func:`load_fragment_database`.
    """
    meta, ids, desc, table, geoms, _ = _load(path, BLOCK_FORMAT, "blocks", "block_id")
    buildings, building_geoms = vector_io.read_layer(path, "buildings")
    return BlockDatabase(str(path), meta, meta.get("crs", ""), geoms, table, ids, desc,
                         buildings=buildings, building_geometry=building_geoms)
