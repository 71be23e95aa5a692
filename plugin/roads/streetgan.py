"""StreetGAN: road networks from a trained spatial GAN generator (Hartmann thesis ch. 4.2).

The generator (trained offline by ``tools/streetgan/train.py``, exported to ONNX) is fully
convolutional (SGAN, Jetchev et al. 2016): a noise field z of 100 x m_rows x m_cols values,
uniform in [-1, 1], becomes an image of 32 (m - 1) + 1 pixels per axis (five stride-2
up-convolutions; m = 25 -> 769 px). This module runs it with onnxruntime (no PyTorch):

- :func:`load_model` opens a generator and its JSON model card (``<name>.json`` next to the
  ``.onnx`` file) and checks both: a missing or corrupt file, a checksum that does not match
  the card, an input that is not 100-channel noise or an output that is not one channel are
  errors that say so;
- :func:`generate` draws the noise for any pixel size from a seed and runs the generator in
  one pass or in overlapping tiles of the same noise field; the generator is local (an
  output pixel sees about two noise cells either side), so tiles with a margin of
  :data:`TILE_MARGIN` cells stitch without seams: the result equals the one-pass image;
- :func:`synthesize` covers a target area at the model's cell size (3 m), extracts the road
  graph (:func:`plugin.roads.raster_graph.raster_to_graph`) and clips it to the target.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import shapely

from ..core.paths import RESOURCES
from ..core.progress import InputError, Progress, ensure
from . import raster_graph

__all__ = ["MODELS_DIR", "Generator", "shipped_models", "load_model", "noise", "noise_size",
           "generate", "synthesize", "StreetGanResult", "SCALE", "TILE_MARGIN", "tile_plan",
           "TileWindow"]

MODELS_DIR = RESOURCES / "models"
#: pixels per noise cell (five stride-2 layers)
SCALE = 32
#: Dead ends this short (m) are removed unless a model card says otherwise (thesis).
DEFAULT_MIN_DEAD_END = 25.0
#: noise cells of context added around each tile; the generator's reach is < 2 cells
TILE_MARGIN = 3


def shipped_models() -> list:
    """Names of the generators shipped in resources/models (``<name>.onnx`` + ``<name>.json``)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.onnx") if p.with_suffix(".json").exists())


@dataclass
class Generator:
    """An ONNX generator and its model card."""

    path: Path
    card: dict
    session: object
    input_name: str
    channels: int
    scale: int = SCALE

    @property
    def cell_size(self) -> float:
        return float(self.card.get("cell_size_m", raster_graph.CELL_SIZE))

    @property
    def name(self) -> str:
        return str(self.card.get("name", self.path.stem))

    def run(self, z: np.ndarray) -> np.ndarray:
        """Generator output for a noise field (1, channels, m_rows, m_cols) -> (rows, cols)
        grey values 0 .. 255 (road bright)."""
        z = np.asarray(z, dtype=np.float32)
        if z.ndim != 4 or z.shape[0] != 1 or z.shape[1] != self.channels:
            raise InputError(f"the generator '{self.name}' takes noise of shape (1, "
                             f"{self.channels}, m, n), not {tuple(z.shape)}")
        if min(z.shape[2:]) < 2:
            raise InputError(f"the noise field must be at least 2 x 2 cells, not "
                             f"{z.shape[2]} x {z.shape[3]}")
        try:
            out = self.session.run(None, {self.input_name: z})[0]
        except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own types
            raise InputError(f"the generator '{self.name}' failed on a noise field of "
                             f"{z.shape[2]} x {z.shape[3]} cells: {exc}") from exc
        if out.ndim != 4 or out.shape[1] != 1:
            raise InputError(f"the generator '{self.name}' must output one channel, not an "
                             f"array of shape {tuple(out.shape)}")
        return (np.clip(out[0, 0], -1.0, 1.0) + 1.0) * 127.5


def _resolve(model) -> Path:
    p = Path(str(model))
    if p.suffix.lower() != ".onnx" and not p.exists():
        if str(model) in shipped_models():
            return MODELS_DIR / f"{model}.onnx"
        raise InputError(f"unknown StreetGAN model '{model}': use one of "
                         f"{', '.join(shipped_models()) or '(none shipped)'} or an .onnx file")
    return p


def load_model(model, threads: int = 0, card: Optional[dict] = None) -> Generator:
    """Open a shipped model by name, or an ``.onnx`` file with its card next to it.

    ``card`` (a dict) replaces the JSON card, e.g. for an untrained generator in an
    evaluation; ``threads`` limits onnxruntime's threads (0: its default).

    Raises
    ------
    InputError
        Missing file or card, unreadable card, checksum mismatch (a corrupt or replaced
        file), a file onnxruntime cannot load, an input that is not (batch, channels, m, n)
        noise with the card's channel count, or an output that is not one channel.
    """
    path = _resolve(model)
    if not path.is_file():
        raise InputError(f"the model file {path} does not exist")
    card_path = path.with_suffix(".json")
    if card is None and not card_path.is_file():
        raise InputError(f"the model card {card_path.name} is missing next to {path.name}: "
                         "a generator needs its card (cell size, noise channels)")
    try:
        card = json.loads(card_path.read_text()) if card is None else card
        if not isinstance(card, dict):
            raise ValueError("not a JSON object")
    except (ValueError, OSError) as exc:
        raise InputError(f"the model card {card_path} cannot be read: {exc}") from exc
    data = path.read_bytes()
    sha = card.get("onnx_sha256")
    if sha and hashlib.sha256(data).hexdigest() != sha:
        raise InputError(f"the model file {path} is corrupt: its checksum does not match "
                         f"the one in {card_path.name}")
    try:
        import onnxruntime as ort
    except ImportError as exc:  # pragma: no cover - requirements.txt installs it
        raise InputError("onnxruntime is not installed: pip install -r requirements.txt") from exc
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    if threads:
        opts.intra_op_num_threads = int(threads)
    try:
        session = ort.InferenceSession(data, sess_options=opts,
                                       providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001
        raise InputError(f"the model file {path} is not a valid ONNX model (corrupt?): "
                         f"{str(exc).splitlines()[0][:200]}") from exc
    inputs, outputs = session.get_inputs(), session.get_outputs()
    expected = int(card.get("input", {}).get("channels", 100))
    if len(inputs) != 1 or len(inputs[0].shape) != 4:
        raise InputError(f"the model {path.name} must take one 4-D noise input (batch, "
                         f"channels, m, n), not {[tuple(i.shape) for i in inputs]}")
    ch = inputs[0].shape[1]
    if not isinstance(ch, int) or ch != expected:
        raise InputError(f"the model {path.name} takes {ch} input channels, its card says "
                         f"{expected}")
    if len(outputs) != 1 or len(outputs[0].shape) != 4 or outputs[0].shape[1] not in (1, "1"):
        raise InputError(f"the model {path.name} must output one image channel, not "
                         f"{[tuple(o.shape) for o in outputs]}")
    scale = int(card.get("scale", SCALE))
    return Generator(path, card, session, inputs[0].name, expected, scale)


def noise_size(pixels: int, scale: int = SCALE) -> int:
    """Noise cells m for at least ``pixels`` output pixels: scale (m - 1) + 1 >= pixels."""
    return max(2, int(math.ceil((int(pixels) - 1) / scale)) + 1)


def noise(rows: int, cols: int, channels: int, rng: np.random.Generator) -> np.ndarray:
    """The spatial noise field z, i.i.d. uniform in [-1, 1] (thesis), shape (1, c, rows, cols)."""
    return rng.uniform(-1.0, 1.0, size=(1, channels, rows, cols)).astype(np.float32)


def _spans(m: int, tile: int):
    """(core start, core end) noise ranges of tiles along one axis."""
    starts = list(range(0, m, tile))
    return [(a, min(a + tile, m)) for a in starts]


def generate(model: Generator, rows_px: int, cols_px: int, seed: int = 0,
             tile: Optional[int] = 24, progress: Optional[Progress] = None) -> np.ndarray:
    """A generator image of at least rows_px x cols_px pixels (cropped to exactly that).

    The noise field is drawn once from ``seed``; with ``tile`` (noise cells per tile) the
    generator runs on overlapping windows of it and each window keeps its core, which
    equals the one-pass result (``tile=None``) because the generator is local.
    """
    progress = ensure(progress)
    if rows_px < 2 or cols_px < 2:
        raise InputError(f"the image must be at least 2 x 2 pixels, not {rows_px} x {cols_px}")
    s = model.scale
    mr, mc = noise_size(rows_px, s), noise_size(cols_px, s)
    z = noise(mr, mc, model.channels, np.random.default_rng(seed))
    if tile is None or (mr <= tile + 2 * TILE_MARGIN and mc <= tile + 2 * TILE_MARGIN):
        img = model.run(z)
        progress.step(1.0)
        return img[:rows_px, :cols_px]
    out = np.empty((s * (mr - 1) + 1, s * (mc - 1) + 1), np.float32)
    spans_r, spans_c = _spans(mr, tile), _spans(mc, tile)
    done, total = 0, len(spans_r) * len(spans_c)
    for r0, r1 in spans_r:
        for c0, c1 in spans_c:
            pr0, pr1 = max(0, r0 - TILE_MARGIN), min(mr, r1 + TILE_MARGIN)
            pc0, pc1 = max(0, c0 - TILE_MARGIN), min(mc, c1 + TILE_MARGIN)
            img = model.run(z[:, :, pr0:pr1, pc0:pc1])
            # noise cell i is output pixel s * i; the core keeps pixels s*r0 .. s*r1 - 1
            # (and the very last pixel row / column at the far edge)
            gr1 = s * r1 if r1 < mr else s * (mr - 1) + 1
            gc1 = s * c1 if c1 < mc else s * (mc - 1) + 1
            lr, lc = s * (r0 - pr0), s * (c0 - pc0)
            out[s * r0:gr1, s * c0:gc1] = img[lr:lr + gr1 - s * r0, lc:lc + gc1 - s * c0]
            done += 1
            progress.step(done / total)
    return out[:rows_px, :cols_px]


@dataclass(frozen=True)
class TileWindow:
    """One tile of :func:`generate`: the noise window it runs on and where its core goes.

    ``noise`` = (row0, row1, col0, col1) cells of z; the generator's output on that window,
    cropped to ``[crop_r:crop_r + h, crop_c:crop_c + w]``, fills ``out[dest_r:dest_r + h,
    dest_c:dest_c + w]`` of the full image."""

    noise: tuple
    crop_r: int
    crop_c: int
    dest_r: int
    dest_c: int
    h: int
    w: int


def tile_plan(mr: int, mc: int, tile: Optional[int], scale: int = SCALE) -> list:
    """The tiles :func:`generate` runs for an mr x mc noise field, in its order (for
    running them elsewhere, e.g. on Dask workers: the stitched image is the same)."""
    full = (scale * (mr - 1) + 1, scale * (mc - 1) + 1)
    if tile is None or (mr <= tile + 2 * TILE_MARGIN and mc <= tile + 2 * TILE_MARGIN):
        return [TileWindow((0, mr, 0, mc), 0, 0, 0, 0, full[0], full[1])]
    s, out = scale, []
    for r0, r1 in _spans(mr, tile):
        for c0, c1 in _spans(mc, tile):
            pr0, pr1 = max(0, r0 - TILE_MARGIN), min(mr, r1 + TILE_MARGIN)
            pc0, pc1 = max(0, c0 - TILE_MARGIN), min(mc, c1 + TILE_MARGIN)
            gr1 = s * r1 if r1 < mr else full[0]
            gc1 = s * c1 if c1 < mc else full[1]
            out.append(TileWindow((pr0, pr1, pc0, pc1), s * (r0 - pr0), s * (c0 - pc0),
                                  s * r0, s * c0, gr1 - s * r0, gc1 - s * c0))
    return out


@dataclass
class StreetGanResult:
    """Result of :func:`synthesize`.

    Attributes
    ----------
    geometry : ndarray of LineString, planar street edges clipped to the target (metric CRS)
    level : int array, stream-order level from street continuity (0 = the longest streets)
    image : (rows, cols) float32 grey values 0 .. 255 of the generator
    geotransform : GDAL geotransform of ``image``
    stats : dict with timings (``generate_s``, ``vectorize_s``), sizes and counts
    """

    geometry: np.ndarray
    level: np.ndarray
    image: np.ndarray
    geotransform: tuple
    stats: dict = field(default_factory=dict)


def synthesize(target, model, seed: int = 0, cell_size: Optional[float] = None,
               margin: float = 96.0, max_gap: float = 0.0, min_dead_end: Optional[float] = None,
               from_edge: bool = True,
               tile: Optional[int] = 24, levels: bool = True,
               progress: Optional[Progress] = None, generate_fn=None) -> StreetGanResult:
    """Generate a road network over a target polygon (thesis ch. 4.2).

    Parameters
    ----------
    target : Polygon / MultiPolygon (or array of them), metric CRS
    model : Generator, or a shipped model name / .onnx path for :func:`load_model`
    seed : int, seed of the noise field
    cell_size : metres per pixel; default the model's (3 m: the scale it learnt)
    margin : metres generated around the target's bounds and cut away after vectorising,
        so that the image border does not leave stubs inside the target
    max_gap, min_dead_end, from_edge : see :func:`plugin.roads.raster_graph.raster_to_graph`;
        ``min_dead_end`` None takes the model card's ``postprocess.min_dead_end_m``
        (chosen on validation seeds when the model was made), else the thesis's 25 m
    tile : noise cells per tile (None: one pass)
    levels : derive a ``level`` per edge from street continuity (plugin.network.hierarchy)
    generate_fn : replaces :func:`generate` (same signature and result), e.g. to run the
        tiles on a Dask cluster (plugin.scale.distributed)
    """
    progress = ensure(progress)
    gen = model if isinstance(model, Generator) else load_model(model)
    geoms = shapely.get_parts(np.asarray(target, dtype=object).ravel())
    geoms = geoms[~shapely.is_empty(geoms)]
    area = shapely.make_valid(shapely.union_all(geoms)) if len(geoms) else None
    if area is None or area.is_empty or area.area <= 0:
        raise InputError("the target has no area")
    cell = float(cell_size) if cell_size else gen.cell_size
    if not (math.isfinite(cell) and cell > 0):
        raise InputError(f"the cell size must be a positive number of metres, not {cell_size}")
    x0, y0, x1, y1 = area.bounds
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    cols, rows = int(math.ceil((x1 - x0) / cell)) + 1, int(math.ceil((y1 - y0) / cell)) + 1
    if rows * cols > 60_000_000:
        raise InputError(f"the target needs {rows} x {cols} pixels at {cell:g} m: more than "
                         "60 million; use a larger cell size or a smaller target")
    t = time.perf_counter()
    image = (generate_fn or generate)(gen, rows, cols, seed, tile, progress.sub(0.0, 0.5))
    t_gen = time.perf_counter() - t
    gt = (x0, cell, 0.0, y1, 0.0, -cell)
    t = time.perf_counter()
    scale = cell / gen.cell_size  # lengths in the model's pixels stay the thesis's
    if min_dead_end is None:
        min_dead_end = float(gen.card.get("postprocess", {}).get("min_dead_end_m",
                                                                 DEFAULT_MIN_DEAD_END))
    rg = raster_graph.raster_to_graph(image, gt, simplify=3.0 * scale,
                                      min_dead_end=min_dead_end * scale, max_gap=max_gap * scale,
                                      from_edge=from_edge,
                                      progress=progress.sub(0.5, 0.85))
    lines = rg.geometry
    if len(lines):
        with np.errstate(invalid="ignore"):
            clipped = shapely.intersection(lines, area)
        parts = shapely.get_parts(clipped)
        parts = shapely.get_parts(shapely.line_merge(parts)) if len(parts) else parts
        lines = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 1e-6)]
    t_vec = time.perf_counter() - t
    level = np.zeros(len(lines), dtype=np.int64)
    if levels and len(lines):
        from ..network.hierarchy import road_hierarchy
        from ..network.street_graph import clean_network

        graph = clean_network(lines, snap_tolerance=0.5, min_dangle_length=0.0)
        lines = graph.geometry
        level = np.asarray(road_hierarchy(graph, method="topological").edge_level, dtype=np.int64)
    progress.step(1.0)
    stats = dict(rg.stats, pixels=[rows, cols], cell_size_m=cell, generate_s=round(t_gen, 4),
                 vectorize_s=round(t_vec, 4), area_km2=area.area / 1e6, model=gen.name,
                 seed=int(seed), edges_clipped=int(len(lines)))
    return StreetGanResult(np.asarray(lines, dtype=object), level, image, gt, stats)
