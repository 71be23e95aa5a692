"""Crossings steered down to the example's share on large targets (issue 16, StreetGAN).

``network.small_blocks.fewer_crossings`` removes synthesised streets at 4-way junctions
until the share of crossings is the example's. It measures the share on the whole network
as the invariants count it; one street per measurement (``per_round=1``, the rule before)
grows with the square of the target's size. Here both side by side on StreetGAN networks
of the Helsinki model (a grid city's crossings, about 0.3 of the junctions) over squares of
2, 4 and 6 km, steered to 0.08 (the Liechtenstein towns' share): CPU seconds, streets
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
from urban_synthesis.plugin.network.small_blocks import fewer_crossings  # noqa: E402
from urban_synthesis.plugin.roads import streetgan  # noqa: E402

SHARE = 0.08
SIDES_M = (2000.0, 4000.0, 6000.0)


def run() -> dict:
    model = streetgan.load_model("streetgan_helsinki")
    rows = []
    for side in SIDES_M:
        area = shapely.box(0.0, 0.0, side, side)
        lines = streetgan.synthesize(area, model, seed=1).geometry
        before = invariants.crossing_share(lines, area)
        for label, per_round in (("rounds (default)", None), ("one street per round", 1)):
            c0 = time.process_time()
            out, _, removed = fewer_crossings(
                lines, np.ones(len(lines), dtype=bool), SHARE, area,
                lambda g, area=area: invariants.crossing_share(g, area), per_round=per_round)
            rows.append({"km2": side * side / 1e6, "variant": label, "edges": int(len(lines)),
                         "share_before": float(before), "removed": int(removed),
                         "share_after": float(invariants.crossing_share(out, area)),
                         "cpu_s": time.process_time() - c0})
            r = rows[-1]
            print(f"{r['km2']:6.0f} km²  {label:22s} {r['edges']:6d} edges  share "
                  f"{r['share_before']:.3f} -> {r['share_after']:.3f}  {r['removed']:4d} "
                  f"removed  {r['cpu_s']:7.2f} s CPU", flush=True)
    return {"machine": platform.processor() or platform.machine(),
            "load_average": list(os.getloadavg()), "target_share": SHARE, "rows": rows}


def main() -> None:
    print(f"StreetGAN (Helsinki model) networks steered to a crossing share of {SHARE}")
    out = run()
    path = ROOT / "tests" / "benchmarks" / "results" / "crossings.json"
    path.write_text(json.dumps(out, indent=1))
    print(f"written to {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
