"""StreetGAN: road networks from a trained spatial GAN generator (Hartmann thesis ch. 4.2).

The generator (trained offline by ``tools/streetgan/train.py``, exported to ONNX) is fully
convolutional (SGAN, Jetchev et al. 2016): a noise field z of 100 x m_rows x m_cols values,
uniform in [-1, 1], becomes an image of 32 (m - 1) + 1 pixels per axis (five stride-2
up-convolutions; m = 25 -> 769 px). This module runs it with onnxruntime (no PyTorch):

- :func:`load_model` opens a generator and its JSON model card (``<name>.json`` next to the
  ``.onnx`` file) and checks both: a missing or corrupt file, a checksum that does not match
  the card, a card number the run cannot use (a zero cell size, a string), an input that
  is not 100-channel noise or an output that is not one channel are errors that say so;
- :func:`generate` draws the noise for any pixel size from a seed and runs the generator in
  one pass or in overlapping tiles of the same noise field; the generator is local (an
  output pixel sees about two noise cells either side), so tiles with a margin of
  :data:`TILE_MARGIN` cells stitch without seams: the result equals the one-pass image;
- :func:`synthesize` covers a target area at the model's cell size (3 m), extracts the road
  graph (:func:`plugin.roads.raster_graph.raster_to_graph`) and clips it to the target.

Given roads (the arterials of a district; the thesis's "future work": "the urban planner
might also incorporate existing objects", ch. 4.2.8) are respected and kept:

- the generator's image is blanked in the corridor of every given road (half a rasterised
  road width plus the invariant checker's corridor, :data:`GIVEN_CORRIDOR`), so that no
  generated street runs along or over a given road;
- after vectorising, junction clusters are merged (two 3-way skeleton nodes a few pixels
  apart are one crossing of the image, :func:`raster_graph.merge_junction_clusters`);
- every generated dead end that points at a given road within reach of the corridor is
  extended straight onto it (a T junction; from both sides a crossing), except onto
  motorways and trunks, which are crossed only at their own junctions;
- all lines are noded together (every contact is a junction), and generated pieces that
  reach neither a given road nor (without given roads) the largest piece are joined by
  the shortest clear connector within :data:`JOIN_DISTANCE` road widths, or within half
  of the piece's own street length up to 400 m (:data:`PIECE_LINK_SHARE`,
  :data:`MAX_PIECE_LINK`), nearest first (a piece may join through one that joined before
  it; :mod:`network.links`), or dropped;
- streets cut by the target's edge are joined along it where they end at most
  ``edge_join`` m apart on it (:func:`network.edge_streets.join_along_edge`; not in the
  thesis): the cells the clip opened close as a town's outer blocks do;
- the given roads are returned whole (split at the new junctions), level 0; the generated
  streets rank below them.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Mapping, Optional

import numpy as np
import shapely

from ..core.paths import RESOURCES
from ..core.progress import InputError, Progress, ensure, require
from ..network.edge_streets import EDGE_JOIN_MAX, join_along_edge
from ..network.invariants import connected_pieces
from ..network.links import join_pieces, link_floating_pieces
from . import raster_graph

__all__ = ["MODELS_DIR", "Generator", "shipped_models", "load_model", "noise", "noise_size",
           "generate", "synthesize", "example_steering", "StreetGanResult", "SCALE",
           "TILE_MARGIN", "tile_plan", "TileWindow", "attach_to_given", "GIVEN_CORRIDOR",
           "JOIN_DISTANCE", "PIECE_LINK_SHARE", "MAX_PIECE_LINK", "junction_merge_distance"]

MODELS_DIR = RESOURCES / "models"
#: pixels per noise cell (five stride-2 layers)
SCALE = 32
#: Dead ends this short (m) are removed unless a model card says otherwise (thesis).
DEFAULT_MIN_DEAD_END = 25.0
#: noise cells of context added around each tile; the generator's reach is < 2 cells
TILE_MARGIN = 3
#: m beyond half a rasterised road width in which generation is blanked along a given road
#: (the invariant checker's corridor: no generated street may run there)
GIVEN_CORRIDOR = 8.0
#: floating generated pieces are joined by connectors up to this many road widths long ...
JOIN_DISTANCE = 2.0
#: ... or, for a larger piece (a part of the settlement the generator drew apart from the
#: rest), up to this share of the piece's own street length (a quarter until 2026-12-06
#: dropped 2.5 km of Eschen's 9.4, seed 1, and left the north of the town empty) ...
PIECE_LINK_SHARE = 0.5
#: ... and at most this long (m; about the longest street segments, 90th percentile, of
#: the fidelity benchmark's towns: 250-390 m)
MAX_PIECE_LINK = 400.0


def junction_merge_distance(line_width_px: float, cell_size: float) -> float:
    """Junctions joined by an edge this short (m) merge into one: half the width of a road
    drawn ``line_width_px`` wide at ``cell_size`` m per pixel (two 3-way skeleton nodes that
    close are one crossing of the image)."""
    return 0.5 * line_width_px * cell_size


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

    @property
    def line_width_px(self) -> int:
        """Width (px) of the roads in the model's images (thesis: 15)."""
        return int(self.card.get("line_width_px", raster_graph.LINE_WIDTH_PX))

    def merge_distance(self, cell_size: Optional[float] = None) -> float:
        """:func:`junction_merge_distance` of the model's roads at ``cell_size`` m per pixel
        (default the model's)."""
        return junction_merge_distance(self.line_width_px, cell_size or self.cell_size)

    @property
    def morphology(self) -> dict:
        """Erosions and dilations of the road mask before thinning, as the card says (the
        thesis's 1 and 5, made for 15 px lines)."""
        post = self.card.get("postprocess", {})
        return {"erosions": int(post.get("erosions", 1)),
                "dilations": int(post.get("dilations", 5))}

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


#: The numbers a model card may hold: key path, whole number or not, least value, and
#: whether the least value itself is allowed (0 erosions is; a 0 m cell is not).
_CARD_NUMBERS = ((("cell_size_m",), False, 0.0, False),
                 (("line_width_px",), True, 1, True),
                 (("scale",), True, 1, True),
                 (("input", "channels"), True, 1, True),
                 (("postprocess", "erosions"), True, 0, True),
                 (("postprocess", "dilations"), True, 0, True),
                 (("postprocess", "min_dead_end_m"), False, 0.0, True))


def _check_card(card: dict, name: str) -> None:
    """Refuse a model card whose numbers the generator and the read-back cannot use (a
    string, a zero cell size or scale, negative morphology), naming the card and the key.

    >>> _check_card({"cell_size_m": 3.0, "postprocess": {"erosions": 1}}, "m.json")
    >>> try:
    ...     _check_card({"cell_size_m": 0}, "m.json")
    ... except InputError as exc:
    ...     print(exc)
    the model card m.json: cell_size_m must be a number above 0, not 0
    """
    for keys, whole, least, inclusive in _CARD_NUMBERS:
        holder, what = card, ".".join(keys)
        for key in keys[:-1]:
            holder = holder.get(key, {})
            if not isinstance(holder, dict):
                raise InputError(f"the model card {name}: {key} must be a JSON object, not "
                                 f"{holder!r}")
        if keys[-1] not in holder:
            continue
        value = holder[keys[-1]]
        number = isinstance(value, (int, float)) and not isinstance(value, bool) and \
            math.isfinite(value)
        if whole and number and value != int(value):
            number = False
        if not number or value < least or (value == least and not inclusive):
            kind = "a whole number" if whole else "a number"
            bound = f"of {least:g} or more" if inclusive else f"above {least:g}"
            raise InputError(f"the model card {name}: {what} must be {kind} {bound}, not "
                             f"{value!r}")


def load_model(model, threads: int = 0, card: Optional[dict] = None) -> Generator:
    """Open a shipped model by name, or an ``.onnx`` file with its card next to it.

    ``card`` (a dict) replaces the JSON card, e.g. for an untrained generator in an
    evaluation; ``threads`` limits onnxruntime's threads (0: its default).

    Raises
    ------
    InputError
        Missing file or card, unreadable card or one whose numbers cannot be used
        (:func:`_check_card`), checksum mismatch (a corrupt or replaced file), a file
        onnxruntime cannot load, an input that is not (batch, channels, m, n)
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
    _check_card(card, card_path.name)
    data = path.read_bytes()
    sha = card.get("onnx_sha256")
    if sha and hashlib.sha256(data).hexdigest() != sha:
        raise InputError(f"the model file {path} is corrupt: its checksum does not match "
                         f"the one in {card_path.name}")
    ort = require("onnxruntime", "onnxruntime")
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    # idle worker threads sleep instead of spinning: the same output, and on a shared
    # 2-core machine the 769 px image took 0.18 s wall / 0.16 s CPU with spinning, 0.11 s /
    # 0.10 s without (the spinning threads took the core the work needed)
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
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
    geometry : ndarray of LineString, planar street edges: the generated streets clipped to
        the target and, when roads were given, the given roads (whole, split at the new
        junctions) (metric CRS)
    level : int array, stream-order level from street continuity (0 = the longest streets;
        with given roads, 0 = the given roads and the generated streets from 1)
    given : bool array, the edge is (a piece of) a given road
    image : (rows, cols) float32 grey values 0 .. 255 of the generator
    geotransform : GDAL geotransform of ``image``
    stats : dict with timings (``generate_s``, ``vectorize_s``), sizes and counts
    """

    geometry: np.ndarray
    level: np.ndarray
    image: np.ndarray
    geotransform: tuple
    stats: dict = field(default_factory=dict)
    given: Optional[np.ndarray] = None

    def __post_init__(self):
        if self.given is None:
            self.given = np.zeros(len(self.geometry), dtype=bool)


def example_steering(stats: Mapping[str, float]) -> Dict[str, float]:
    """What :func:`synthesize` is steered to, from an example's fidelity statistics
    (:func:`measure.fidelity.fidelity_statistics` inside the example's area): its dead-end
    and crossing shares, its 10th-percentile block area as ``min_block_area`` and its median
    block as ``median_block_area``, the arguments an analyst with the example passes; a
    statistic the example has not (NaN: it closes no block) is left out.

    >>> example_steering({"degree1_share": 0.28, "degree4_share": 0.08,
    ...                   "block_area_p10": 4600.0, "block_area_p50": float("nan")})
    {'dead_end_share': 0.28, 'crossing_share': 0.08, 'min_block_area': 4600.0}
    """
    keys = (("dead_end_share", "degree1_share"), ("crossing_share", "degree4_share"),
            ("min_block_area", "block_area_p10"), ("median_block_area", "block_area_p50"))
    return {arg: float(stats[k]) for arg, k in keys if math.isfinite(stats[k])}


def synthesize(target, model, seed: int = 0, cell_size: Optional[float] = None,
               margin: float = 96.0, max_gap: float = 0.0, min_dead_end: Optional[float] = None,
               from_edge: bool = True,
               tile: Optional[int] = 24, levels: bool = True,
               progress: Optional[Progress] = None, generate_fn=None, given=None,
               given_class=None, merge_junctions: Optional[float] = None,
               dead_end_share: Optional[float] = None,
               min_block_area: Optional[float] = None,
               crossing_share: Optional[float] = None,
               median_block_area: Optional[float] = None,
               edge_join: Optional[float] = EDGE_JOIN_MAX) -> StreetGanResult:
    """Generate a road network over a target polygon (thesis ch. 4.2).

    Parameters
    ----------
    target : Polygon / MultiPolygon (or array of them), metric CRS
    model : Generator, or a shipped model name / .onnx path for :func:`load_model`
    seed : int, seed of the noise field
    cell_size : metres per pixel; default the model's (3 m: the scale it learnt)
    margin : metres generated around the target's bounds and cut away after vectorising,
        so that the image border does not leave stubs inside the target
    max_gap, min_dead_end, from_edge : see :func:`plugin.roads.raster_graph.raster_to_graph`
        (metres, whatever the cell size); ``min_dead_end`` None takes the model card's
        ``postprocess.min_dead_end_m`` (chosen on validation seeds when the model was made),
        else the thesis's 25 m, scaled by ``cell_size`` over the model's cell size as the
        whole network is;
        the road mask's erosions and dilations are the card's ``postprocess.erosions`` /
        ``dilations`` (else the thesis's 1 and 5, made for 15 px lines)
    tile : noise cells per tile (None: one pass)
    levels : derive a ``level`` per edge from street continuity (plugin.network.hierarchy)
    generate_fn : replaces :func:`generate` (same signature and result), e.g. to run the
        tiles on a Dask cluster (plugin.scale.distributed)
    given : array of LineString, optional, roads to respect and keep (see the module
        docstring); ``given_class`` their OSM highway classes (motorways and trunks get no
        new junctions)
    merge_junctions : m; junctions closer than this merge into one (default half a
        rasterised road width, :meth:`Generator.merge_distance`; 0: the thesis's graph)
    dead_end_share : float in [0, 1], optional, the example's dead-end share: the generated
        streets' is steered into the invariants' band around it (the fragment synthesis'
        rule, :func:`network.dead_ends.steer_dead_ends`: dead ends closed by short streets, or
        cul-de-sacs added and T stems cut short; steered once more after the crossings where
        the share left the band); None: the network as read back (not in the thesis: its
        read-back leaves the share wherever the morphology puts it)
    min_block_area : m², optional, the example's 10th-percentile block area: generated
        streets between blocks under it are removed until at most a tenth of the blocks
        are smaller (:func:`network.small_blocks.merge_small_blocks`; not in the thesis:
        the generator draws cells of its own size); None: the cells as read back
    median_block_area : m², optional, the example's median block area: merged the same way
        first, until at most half the blocks are smaller
    crossing_share : float in [0, 1], optional, the example's share of 4-way junctions:
        the network's is steered to it (:func:`network.crossings.match_crossings`: T
        junctions become crossings, their generated street continued straight across to the
        next street, generated or a given road that takes junctions (not a motorway or
        trunk), else to the target's edge, or generated streets at crossings are removed,
        smallest merged blocks first, then dead-end streets at crossings;
        not in the thesis); None: the junctions as read back
    edge_join : m, optional; two streets that end on the target's edge at most this far
        apart along it are joined by a street along the edge, which closes the cell between
        them (:func:`network.edge_streets.join_along_edge`, after the small blocks are
        merged; default :data:`network.edge_streets.EDGE_JOIN_MAX`); None or 0: the
        streets stay cut at the edge (the thesis)
    """
    progress = ensure(progress)
    gen = model if isinstance(model, Generator) else load_model(model)
    geoms = shapely.get_parts(np.asarray(target, dtype=object).ravel())
    geoms = geoms[~shapely.is_empty(geoms)]
    area = shapely.make_valid(shapely.union_all(geoms)) if len(geoms) else None
    if area is None or area.is_empty or area.area <= 0:
        raise InputError("the target has no area")
    for name, value in (("dead-end", dead_end_share), ("crossing", crossing_share)):
        if value is not None and not 0 <= value <= 1:
            raise InputError(f"the {name} share must lie in [0, 1], got {value}")
    for name, value in (("smallest", min_block_area), ("median", median_block_area)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"the {name} block area must be a positive number of m², not "
                             f"{value}")
    cell = float(cell_size) if cell_size else gen.cell_size
    if not (math.isfinite(cell) and cell > 0):
        raise InputError(f"the cell size must be a positive number of metres, not {cell_size}")
    x0, y0, x1, y1 = area.bounds
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    cols, rows = int(math.ceil((x1 - x0) / cell)) + 1, int(math.ceil((y1 - y0) / cell)) + 1
    if rows * cols > 60_000_000:
        raise InputError(f"the target needs {rows} x {cols} pixels at {cell:g} m: more than "
                         "60 million; use a larger cell size or a smaller target")
    given_lines, given_cls = _given(given, given_class)
    t = time.perf_counter()
    image = (generate_fn or generate)(gen, rows, cols, seed, tile, progress.sub(0.0, 0.5))
    t_gen = time.perf_counter() - t
    gt = (x0, cell, 0.0, y1, 0.0, -cell)
    t = time.perf_counter()
    scale = cell / gen.cell_size  # lengths in the model's pixels stay the thesis's
    width = gen.line_width_px * cell
    if min_dead_end is None:   # the card's length is the model's, in its pixels
        min_dead_end = scale * float(gen.card.get("postprocess", {}).get(
            "min_dead_end_m", DEFAULT_MIN_DEAD_END))
    merge = gen.merge_distance(cell) if merge_junctions is None else float(merge_junctions)
    corridor = 0.5 * width + GIVEN_CORRIDOR
    open_given = given_lines[_open_roads(given_cls)] if len(given_lines) else given_lines
    if len(given_lines):
        # no generated road in a given road's corridor; the given roads that take junctions
        # are drawn in, so that generated streets that reach them join them in the skeleton
        image = _blank_corridors(image, gt, given_lines, corridor)
        if len(open_given):
            drawn, _ = raster_graph.rasterize_lines(
                open_given, cell_size=cell, width_px=gen.line_width_px,
                bounds=(gt[0], gt[3] + gt[5] * image.shape[0], gt[0] + gt[1] * image.shape[1],
                        gt[3]))
            drawn = drawn[:image.shape[0], :image.shape[1]]
            image[:drawn.shape[0], :drawn.shape[1]] = np.maximum(
                image[:drawn.shape[0], :drawn.shape[1]], drawn.astype(np.float32))
    # the mask's morphology suits the line width the model drew (thesis: 1 and 5 for 15 px)
    rg = raster_graph.raster_to_graph(image, gt, **gen.morphology,
                                      simplify=3.0 * scale,
                                      min_dead_end=min_dead_end, max_gap=max_gap,
                                      from_edge=from_edge, merge_junctions=merge,
                                      progress=progress.sub(0.5, 0.85))
    lines = rg.geometry
    n_cut = 0
    if len(lines) and len(open_given):
        # the skeleton of the drawn roads goes; streets that reached them end on them
        lines, n_cut = _cut_at_given(lines, open_given, 0.5 * width)
    if len(lines):
        with np.errstate(invalid="ignore"):
            clipped = shapely.intersection(lines, area)
        parts = shapely.get_parts(clipped)
        parts = shapely.get_parts(shapely.line_merge(parts)) if len(parts) else parts
        lines = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 1e-6)]
    lines, is_given, attach = attach_to_given(lines, given_lines, given_cls, area,
                                              reach=corridor + 0.75 * width,
                                              join_distance=JOIN_DISTANCE * width)
    n_merged = 0
    # the median first (half the blocks may be under it), then the smallest tenth
    for block, share in ((median_block_area, 0.5), (min_block_area, 0.1)):
        if block is not None and len(lines) > 1:
            from ..network.small_blocks import merge_small_blocks

            lines, is_new, n = merge_small_blocks(lines, ~is_given, float(block), area, share)
            is_given = ~is_new
            n_merged += n
    n_edge = 0
    if edge_join:
        # after the small blocks are merged: joined before, the cells it closed at the edge
        # were small blocks to merge, which removed more of the generated streets (Balzers,
        # seed 0: 63 for 48) and took the segments and intersections further from the towns
        # (closing only the cells as large as the example's median block left 12.4 streets
        # per km² cut at the edge, not 3.7, and 0.37 of the land in blocks, not 0.44)
        lines, is_given, n_edge = _join_edge(lines, is_given, area, given_lines, given_cls,
                                             edge_join)
    steered = (0, 0)
    if dead_end_share is not None and len(lines) > 1:
        from ..network.dead_ends import steer_dead_ends

        lines, is_new, steered = steer_dead_ends(lines, ~is_given, float(dead_end_share),
                                                 area, np.random.default_rng(seed))
        is_given = ~is_new
    # after the dead ends: a crossing made (a new T) or a street removed at one moves the
    # dead-end share only through its count of nodes; steered before them, the dead ends
    # missed their band on a small network (Bubenec seed 4: 1 of 9 nodes, 0.11 < 0.12)
    crossings = (0, 0)
    if crossing_share is not None and len(lines) > 1:
        from ..network.crossings import match_crossings

        lines, is_new, crossings = match_crossings(
            lines, ~is_given, float(crossing_share), area, np.random.default_rng(seed),
            given=given_lines,
            may_end_on=~_on_roads(lines, is_given, given_lines[~_open_roads(given_cls)]))
        is_given = ~is_new
    if dead_end_share is not None and len(lines) > 1:
        # on a small network one step moves the share far (Bubenec, about nine nodes: one
        # dead end is 0.11 of it), and a crossing made or removed moves it too: where it
        # left the invariants' band, the dead ends are steered once more
        from ..network.dead_ends import steer_into_band

        lines, is_new, again = steer_into_band(lines, ~is_given, float(dead_end_share), area,
                                               np.random.default_rng(seed + 1))
        is_given = ~is_new
        steered = (steered[0] + again[0], steered[1] + again[1])
    if len(lines) > 1:
        # what the invariants read within their tolerance, exactly: no street ending a few
        # decimetres from a junction, no street of a few decimetres between two
        from ..network.invariants import SNAP_TOLERANCE
        from ..network.street_graph import close_short_gaps

        lines, keep = close_short_gaps(lines, ~is_given, SNAP_TOLERANCE)
        is_given = is_given[keep]
        # nor a metre or two short of one (a read-back street's end, a stub by a junction)
        from ..network.undershoots import clear_undershoots

        lines, keep = clear_undershoots(lines, ~is_given)
        is_given = is_given[keep]
    t_vec = time.perf_counter() - t
    level = np.zeros(len(lines), dtype=np.int64)
    if levels and len(lines):
        from ..network.hierarchy import road_hierarchy
        from ..network.street_graph import clean_network

        new = ~is_given
        level = np.zeros(len(lines), dtype=np.int64)
        if new.any():
            graph = clean_network(lines[new], snap_tolerance=0.0, min_dangle_length=0.0,
                                  merge_degree2=False)
            # levels of the generated streets (0 = their longest), ranked below given roads
            lv = np.asarray(road_hierarchy(graph, method="topological").edge_level)
            # back onto the lines (cleaning kept the noded lines as they were)
            idx = shapely.STRtree(graph.geometry).query(
                shapely.line_interpolate_point(lines[new], 0.5, normalized=True),
                predicate="dwithin", distance=1e-6)
            got = np.zeros(new.sum(), dtype=np.int64)
            got[idx[0]] = lv[idx[1]]
            level[new] = got + (1 if is_given.any() else 0)
    progress.step(1.0)
    stats = dict(rg.stats, pixels=[rows, cols], cell_size_m=cell, generate_s=round(t_gen, 4),
                 vectorize_s=round(t_vec, 4), area_km2=area.area / 1e6, model=gen.name,
                 seed=int(seed), edges_clipped=int((~is_given).sum()),
                 n_joined_to_drawn_roads=int(n_cut), dead_ends_closed=int(steered[0]),
                 dead_ends_opened=int(steered[1]), small_blocks_merged=int(n_merged),
                 crossings_made=int(crossings[0]), crossing_streets_removed=int(crossings[1]),
                 edge_streets=int(n_edge),
                 **attach)
    return StreetGanResult(np.asarray(lines, dtype=object), level, image, gt, stats, is_given)


def _join_edge(lines, is_given, area, given_lines, given_cls, edge_join):
    """:func:`network.edge_streets.join_along_edge` noded into the network (a motorway or
    trunk leaving the target takes no edge street)."""
    if len(lines) < 2:
        return lines, is_given, 0
    closed = _on_roads(lines, is_given, given_lines[~_open_roads(given_cls)])
    edge, n = join_along_edge(lines, area, ~closed, max_length=float(edge_join))
    if n:
        lines, is_given = _noded_with_given(np.concatenate([lines[~is_given], edge]),
                                            lines[is_given])
    return lines, is_given, n


def _given(given, given_class):
    """Single-part given lines and their classes."""
    if given is None:
        return np.empty(0, dtype=object), np.empty(0, dtype=object)
    arr = np.asarray(given, dtype=object).ravel()
    cls = np.asarray(given_class if given_class is not None else [None] * len(arr),
                     dtype=object).ravel()
    if len(cls) != len(arr):
        raise InputError(f"{len(cls)} road classes for {len(arr)} given roads")
    ok = ~(shapely.is_missing(arr) | shapely.is_empty(arr))
    arr, cls = arr[ok], cls[ok]
    if len(arr) and not np.isin(shapely.get_type_id(arr), (1, 5)).all():
        raise InputError("the given roads must be lines")
    parts, src = shapely.get_parts(arr, return_index=True)
    keep = shapely.length(parts) > 0
    return shapely.force_2d(parts[keep]), cls[src[keep]]


def _open_roads(given_class) -> np.ndarray:
    """Given roads that may take new junctions (not motorways / trunks)."""
    from ..network.invariants import is_controlled_access

    return ~is_controlled_access(given_class)


def _on_roads(lines, is_given, roads) -> np.ndarray:
    """Which of the given pieces among ``lines`` lie along one of ``roads`` (their middle
    within a millimetre of it)."""
    on = np.zeros(len(lines), dtype=bool)
    if len(roads) and is_given.any():
        idx = np.flatnonzero(is_given)
        mid = shapely.line_interpolate_point(np.asarray(lines, dtype=object)[idx], 0.5,
                                             normalized=True)
        hit, _ = shapely.STRtree(roads).query(mid, predicate="dwithin", distance=1e-3)
        on[idx[np.unique(hit)]] = True
    return on


def _cut_at_given(lines, given, half_width):
    """Generated lines outside the drawn given roads (a band of ``half_width`` m), each end
    that stopped at the band continued straight onto the nearest point of the given road.
    Returns (lines, number of such junctions)."""
    band = shapely.union_all(shapely.buffer(given, half_width, quad_segs=8))
    with np.errstate(invalid="ignore"):
        outside = shapely.get_parts(shapely.difference(lines, band))
    outside = outside[(shapely.get_type_id(outside) == 1) & (shapely.length(outside) > 1e-6)]
    if not len(outside):
        return outside, 0
    edge = shapely.boundary(band)
    ends = np.vstack([shapely.get_coordinates(shapely.get_point(outside, 0)),
                      shapely.get_coordinates(shapely.get_point(outside, -1))])
    pts = shapely.points(ends)
    on_band = shapely.dwithin(edge, pts, 1e-3)
    pts_on = pts[on_band]
    if not len(pts_on):
        return outside, 0
    gi = shapely.STRtree(given).nearest(pts_on)
    foot = shapely.get_point(shapely.shortest_line(pts_on, given[gi]), 1)
    conn = shapely.linestrings(np.stack([shapely.get_coordinates(pts_on),
                                         shapely.get_coordinates(foot)], axis=1))
    conn = conn[shapely.length(conn) > 1e-6]
    # one connector per end point (two lines ending at one point need one)
    _, first = np.unique(np.round(shapely.get_coordinates(shapely.get_point(conn, 0)), 6),
                         axis=0, return_index=True)
    conn = conn[np.sort(first)]
    return np.concatenate([outside, conn]), len(conn)


def _blank_corridors(image, gt, lines, corridor):
    """The image with every pixel within ``corridor`` m of a given road set to 0 (black)."""
    cv2 = raster_graph._cv2()

    cell = abs(gt[1])
    mask, _ = raster_graph.rasterize_lines(lines, cell_size=cell, width_px=1,
                                           bounds=(gt[0], gt[3] + gt[5] * image.shape[0],
                                                   gt[0] + gt[1] * image.shape[1], gt[3]))
    mask = mask[:image.shape[0], :image.shape[1]]
    if mask.shape != image.shape:
        pad = np.zeros(image.shape, np.uint8)
        pad[:mask.shape[0], :mask.shape[1]] = mask
        mask = pad
    dist = cv2.distanceTransform(np.where(mask > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    out = np.array(image, dtype=np.float32, copy=True)
    out[dist * cell <= corridor] = 0.0
    return out


def _end_directions(lines, probe: float = 10.0):
    """Start and end points of lines and the direction each end points to (outwards, from
    the line's last ``probe`` m)."""
    length = shapely.length(lines)
    p0 = shapely.get_coordinates(shapely.get_point(lines, 0))
    p1 = shapely.get_coordinates(shapely.get_point(lines, -1))
    q0 = shapely.get_coordinates(shapely.line_interpolate_point(lines, np.minimum(probe,
                                                                                  length / 2)))
    q1 = shapely.get_coordinates(shapely.line_interpolate_point(
        lines, np.maximum(length - probe, length / 2)))
    d0, d1 = p0 - q0, p1 - q1
    d0 /= np.maximum(np.linalg.norm(d0, axis=1), 1e-9)[:, None]
    d1 /= np.maximum(np.linalg.norm(d1, axis=1), 1e-9)[:, None]
    return np.vstack([p0, p1]), np.vstack([d0, d1])


def _noded_with_given(new, given):
    """New lines noded among themselves and the given roads split where new lines end on
    them (:func:`street_graph.split_at_ends`: the given roads are not noded with each other,
    a bridge stays a bridge). Returns (lines, is_given)."""
    from ..network.street_graph import node_lines, snap_ends_onto_lines, split_at_ends

    new = np.asarray(new, dtype=object)
    given = np.asarray(given, dtype=object)
    if len(new):
        # a connector's end lies on the street it meets only up to round-off: a vertex first
        new = node_lines(snap_ends_onto_lines(new))
        new = new[shapely.length(new) > 1e-6]
    pieces = split_at_ends(given, new)
    return np.concatenate([new, pieces]), np.r_[np.zeros(len(new), bool),
                                                 np.ones(len(pieces), bool)]


def attach_to_given(lines, given, given_class=None, area=None, reach: float = 60.0,
                    join_distance: float = 90.0, max_angle: float = 60.0):
    """Generated streets joined to the given roads and to each other: one noded network.

    Parameters
    ----------
    lines : array of LineString, the generated streets
    given : array of LineString, the given roads (kept whole)
    given_class : OSM classes of the given roads (motorway / trunk: no new junctions)
    area : Polygon, optional; dead ends on its boundary are clip ends (not extended)
    reach : m; a dead end this close to a given road, pointing at it (within ``max_angle``
        degrees), is extended straight onto it
    join_distance : m; the longest connector that joins a floating piece (to the network
        or to a piece that joined it before: :func:`network.links.link_floating_pieces`);
        a larger piece may take one up to :data:`PIECE_LINK_SHARE` of its street length,
        at most :data:`MAX_PIECE_LINK`

    Returns
    -------
    lines : the noded network (generated pieces and given pieces)
    is_given : bool per line
    stats : dict (n_attached, n_joined, n_dropped_edges, dropped_m: their length,
        n_given_joined: links that join given roads apart, n_components)
    """
    lines = np.asarray(lines, dtype=object)
    given = np.asarray(given, dtype=object)
    stats = {"n_attached": 0, "n_joined": 0, "n_dropped_edges": 0, "dropped_m": 0.0,
             "n_given_joined": 0}
    if not len(lines):
        return given.copy(), np.ones(len(given), dtype=bool), dict(stats, n_components=int(
            len(given) > 0))
    connectors = []
    cls = np.asarray(given_class if given_class is not None else [None] * len(given),
                     dtype=object)
    closed = given[~_open_roads(cls)] if len(given) else given
    if len(given):
        targets = given[_open_roads(cls)]
        if len(targets):
            ends, dirs = _end_directions(lines)
            # dead ends: end points no other line touches
            tree = shapely.STRtree(lines)
            pts = shapely.points(ends)
            e_i, l_i = tree.query(pts, predicate="dwithin", distance=0.5)
            touches = np.bincount(e_i, minlength=len(ends))
            dead = touches <= 1
            if area is not None:
                dead &= ~shapely.dwithin(shapely.boundary(area), pts, 1.0)
            gtree = shapely.STRtree(targets)
            cand = np.flatnonzero(dead)
            if len(cand):
                gi = gtree.nearest(pts[cand])
                near = shapely.get_coordinates(shapely.get_point(
                    shapely.shortest_line(pts[cand], targets[gi]), 1))
                vec = near - ends[cand]
                dist = np.linalg.norm(vec, axis=1)
                cosang = (vec * dirs[cand]).sum(axis=1) / np.maximum(dist, 1e-9)
                ok = (dist <= reach) & (dist > 1e-6) & (cosang >= np.cos(np.radians(max_angle)))
                conn = shapely.linestrings(np.stack([ends[cand[ok]], near[ok]], axis=1))
                # a connector may not cross another generated street (it would end there)
                if len(conn):
                    ci, li = tree.query(conn, predicate="intersects")
                    own = np.zeros(len(ci), dtype=bool)
                    touch_start = shapely.dwithin(lines[li], shapely.points(ends[cand[ok]][ci]),
                                                  0.5)
                    own |= touch_start
                    bad = np.zeros(len(conn), dtype=bool)
                    bad[ci[~own]] = True
                    conn = conn[~bad]
                connectors.extend(conn.tolist())
                stats["n_attached"] = len(conn)
    noded, is_given = _noded_with_given(
        np.concatenate([lines, np.asarray(connectors, dtype=object)]), given)

    # pieces that reach no given road (without given roads: the longest piece) are joined
    # by the shortest clear connector, nearest first, so that a joined piece anchors the
    # next (the one home of the rule, network.links), at most join_distance long (a larger
    # piece: PIECE_LINK_SHARE of its streets, up to MAX_PIECE_LINK) and never
    # onto a motorway or trunk; the rest is dropped
    closed_zone = shapely.union_all(shapely.buffer(closed, 0.01)) if len(closed) else None

    def takes_link(net, net_given):  # a line a link may end on: not a motorway or trunk
        ok = np.ones(len(net), dtype=bool)
        if closed_zone is not None:
            ok[net_given] = ~shapely.covers(closed_zone, net[net_given])
        return ok

    def longest_link(piece_m):
        return max(join_distance, min(PIECE_LINK_SHARE * piece_m, MAX_PIECE_LINK))

    add, keep = link_floating_pieces(noded, is_given, drop_unlinked=True,
                                     ends_on=takes_link(noded, is_given),
                                     max_length=longest_link, inside=area)
    drop = ~keep
    stats["n_joined"] = len(add)
    stats["n_dropped_edges"] = int(drop.sum())
    stats["dropped_m"] = round(float(shapely.length(noded[drop]).sum()), 1)
    noded, is_given = noded[keep], is_given[keep]
    if len(add):
        noded, is_given = _noded_with_given(np.concatenate([noded[~is_given], add]),
                                            noded[is_given])
    # given roads apart inside the area (and the streets on each) are joined into one
    # network by the same rule, as the real streets join them
    bridge = join_pieces(noded, ends_on=takes_link(noded, is_given), max_length=longest_link,
                         inside=area)
    stats["n_given_joined"] = len(bridge)
    if len(bridge):
        noded, is_given = _noded_with_given(np.concatenate([noded[~is_given], bridge]),
                                            noded[is_given])
    stats["n_components"] = int(len(np.unique(connected_pieces(noded)))) if len(noded) else 0
    return noded, is_given, stats
