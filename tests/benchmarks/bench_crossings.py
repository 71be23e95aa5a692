"""Streets removed from StreetGAN networks on large targets (issue 16): crossings steered
down to the example's share, small blocks merged.

``network.small_blocks.fewer_crossings`` removes synthesised streets at 4-way junctions
until the share of crossings is the example's, measured on the whole network as the
invariants count it; ``merge_small_blocks`` removes streets between blocks under the
example's 10th-percentile block until a tenth of the blocks are smaller, polygonising the
network between removals. One street per measurement (``per_round=1``, the rule before)
grows with the square of the target's size. Here both ways side by side on StreetGAN
networks over squares of 2, 4 and 6 km: the Helsinki model (a grid city's crossings,
about 0.17 of the junctions) steered to 0.08 (the Liechtenstein towns' share), and the
towns model's cells merged above 4,600 m² (the towns' p10 block): CPU seconds, streets
removed, the share reached.

    python tests/benchmarks/bench_crossings.py

Writes ``tests/benchmarks/results/crossings.json``.
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "plugins"))

from urban_synthesis.plugin.network import invariants  # noqa: E402
from urban_synthesis.plugin.network.small_blocks import (  # noqa: E402
    fewer_crossings, merge_small_blocks)
from urban_synthesis.plugin.roads import streetgan  # noqa: E402

SHARE = 0.08
MIN_BLOCK_M2 = 4600.0
SIDES_M = (2000.0, 4000.0, 6000.0)


def run() -> dict:
    helsinki = streetgan.load_model("streetgan_helsinki")
    towns = streetgan.load_model("streetgan_towns")
    rows = []
    for side in SIDES_M:
        area = shapely.box(0.0, 0.0, side, side)
        lines = streetgan.synthesize(area, helsinki, seed=1).geometry
        cells = streetgan.synthesize(area, towns, seed=1).geometry
        before = invariants.crossing_share(lines, area)
        for label, per_round in (("rounds (default)", None), ("one street per round", 1)):
            c0 = time.process_time()
            out, _, removed = fewer_crossings(
                lines, np.ones(len(lines), dtype=bool), SHARE, area,
                lambda g, area=area: invariants.crossing_share(g, area), per_round=per_round)
            rows.append({"km2": side * side / 1e6, "rule": "fewer crossings", "variant": label,
                         "edges": int(len(lines)), "before": float(before),
                         "removed": int(removed),
                         "after": float(invariants.crossing_share(out, area)),
                         "cpu_s": time.process_time() - c0})
            _print(rows[-1], "crossing share")
        small = _small_share(cells)
        for label, per_round in (("rounds (default)", None), ("one street per round", 1)):
            c0 = time.process_time()
            out, _, removed = merge_small_blocks(cells, np.ones(len(cells), dtype=bool),
                                                 MIN_BLOCK_M2, area, per_round=per_round)
            rows.append({"km2": side * side / 1e6, "rule": "merge small blocks",
                         "variant": label, "edges": int(len(cells)), "before": small,
                         "removed": int(removed), "after": _small_share(out),
                         "cpu_s": time.process_time() - c0})
            _print(rows[-1], "blocks under p10")
    return {"machine": platform.processor() or platform.machine(),
            "load_average": list(os.getloadavg()), "target_share": SHARE,
            "min_block_m2": MIN_BLOCK_M2, "rows": rows}


def _small_share(lines) -> float:
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.node(
        shapely.union_all(lines)))))
    return float((shapely.area(faces) < MIN_BLOCK_M2).mean()) if len(faces) else 0.0


def _print(r: dict, what: str) -> None:
    print(f"{r['km2']:6.0f} km²  {r['rule']:18s} {r['variant']:22s} {r['edges']:6d} edges  "
          f"{what} {r['before']:.3f} -> {r['after']:.3f}  {r['removed']:4d} removed  "
          f"{r['cpu_s']:7.2f} s CPU", flush=True)


def main() -> None:
    print(f"StreetGAN networks: the Helsinki model's steered to a crossing share of {SHARE}, "
          f"the towns model's blocks merged above {MIN_BLOCK_M2:,.0f} m²")
    out = run()
    path = ROOT / "tests" / "benchmarks" / "results" / "crossings.json"
    path.write_text(json.dumps(out, indent=1))
    print(f"written to {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
