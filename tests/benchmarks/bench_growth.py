"""Procedural road growth benchmark (issue 8): speed and pattern evidence.

1. Speed: :func:`growth.grow_roads` on a 7 km x 7 km square, each pattern for major and
   minor roads, stopped by ``max_segments`` at 1,000, 5,000 and 10,000 grown segments
   (segments placed by the growth loop, before the final noding; the planar output has
   more edges because junctions split segments). Seconds are wall time of the whole call
   (sketch, both stages, quarters, final cleaning). Target: 10,000 segments under 10 s.
   Next to Scharl 2010's figures (ch. 4.2 / 8: 155 segments in 4.21 s, 239 in 1.21 s) and a
   constrained run (DEM with a steep hill + MAX_SLOPE 8 %, two obstacles).
2. Evidence: on a 1 km x 1 km square, per pattern over 5 seeds, the orientation entropy
   (Boeing 2019; ln 4 = 1.386 for a grid, ln 36 = 3.584 for uniform bearings), the mean
   |junction angle - 90°|, the share of junction angles within 10° of 90°, and the
   segment lengths (between junctions / dead ends), dead ends and intersections per km².

Prints both tables and writes tests/benchmarks/results/growth.json (and a picture of the
patterns, growth_patterns.png).
Run: .venv/bin/python tests/benchmarks/bench_growth.py [--quick]
"""
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT / "build" / "plugins") not in sys.path:
    sys.path.insert(0, str(ROOT / "build" / "plugins"))
RESULTS = Path(__file__).resolve().parent / "results"

from urban_synthesis.plugin.roads import growth  # noqa: E402
from urban_synthesis.plugin.retrieval.shape_context import DemGrid  # noqa: E402

#: Scharl 2010: street network creation times reported in the thesis.
SCHARL = [{"segments": 155, "seconds": 4.21}, {"segments": 239, "seconds": 1.21}]


def timed_growth(pattern, n_segments, size=7000.0, seed=1, **kwargs):
    s = growth.GrowthSettings(major_pattern=pattern, minor_pattern=pattern,
                              max_segments=n_segments)
    t0 = time.perf_counter()
    r = growth.grow_roads(shapely.box(0, 0, size, size), settings=s, seed=seed, **kwargs)
    dt = time.perf_counter() - t0
    return {"pattern": pattern, "target": n_segments, "segments": r.stats["segments"],
            "major": r.stats["major_segments"], "minor": r.stats["minor_segments"],
            "edges": int(len(r.geometry)), "proposals": r.stats["proposals"],
            "seconds": dt, "segments_per_s": r.stats["segments"] / dt}


def _constrained_inputs(pattern):
    cell = 5.0
    xs = np.arange(-50.0, 1100.0, cell)
    ys = np.arange(1100.0, -50.0, -cell)
    x, y = np.meshgrid(xs + cell / 2, ys - cell / 2)
    z = 90.0 * np.exp(-((x - 350) ** 2 + (y - 700) ** 2) / (2 * 200.0 ** 2))
    dem = DemGrid(z, (xs[0], cell, 0.0, ys[0], 0.0, -cell))
    obstacles = [shapely.Point(650, 450).buffer(150), shapely.box(120, 150, 300, 330)]
    s = growth.GrowthSettings(major_pattern=pattern, minor_pattern=pattern, max_slope=0.08)
    return dem, obstacles, s


def constrained_run(pattern="organic", seed=1):
    """1 km² with a 90 m hill (27 % at its steepest), MAX_SLOPE 8 %, a lake and a park."""
    dem, obstacles, s = _constrained_inputs(pattern)
    t0 = time.perf_counter()
    r = growth.grow_roads(shapely.box(0, 0, 1000, 1000), settings=s, dem=dem,
                          obstacles=obstacles, seed=seed)
    dt = time.perf_counter() - t0
    slope = float(growth.segment_slopes(r.geometry, dem).max())
    with np.errstate(invalid="ignore"):  # GEOS's empty results carry a NaN z
        inside = float(shapely.length(shapely.intersection(
            r.geometry, shapely.union_all(obstacles))).max())
    return {"pattern": f"{pattern} + DEM 8 % + obstacles", "target": None,
            "segments": r.stats["segments"], "edges": int(len(r.geometry)),
            "seconds": dt, "segments_per_s": r.stats["segments"] / dt,
            "max_slope": slope, "max_length_in_obstacles_m": inside,
            "rejected": r.stats["rejected"]}


def pattern_evidence(seeds=(1, 2, 3, 4, 5), size=1000.0):
    box = shapely.box(0, 0, size, size)
    out = {}
    for pattern in growth.PATTERNS:
        rows = []
        for seed in seeds:
            s = growth.GrowthSettings(major_pattern=pattern, minor_pattern=pattern)
            r = growth.grow_roads(box, settings=s, seed=seed)
            st = growth.network_statistics(r.geometry, area=box)
            st["segments"] = r.stats["segments"]
            rows.append(st)
        keys = rows[0].keys()
        out[pattern] = {k: {"mean": float(np.mean([r[k] for r in rows])),
                            "sd": float(np.std([r[k] for r in rows]))} for k in keys}
    return out


def draw_patterns(path, seed=1):
    """A picture of the three patterns and the constrained run (major black, minor orange)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - matplotlib is a bench extra
        return None
    box = shapely.box(0, 0, 1000, 1000)
    fig, axes = plt.subplots(1, 4, figsize=(20, 5.4))
    runs = [(p, growth.grow_roads(box, settings=growth.GrowthSettings(
        major_pattern=p, minor_pattern=p), seed=seed), None) for p in growth.PATTERNS]
    dem, obstacles, s = _constrained_inputs("organic")
    runs.append(("organic, DEM 8 %, obstacles",
                 growth.grow_roads(box, settings=s, dem=dem, obstacles=obstacles, seed=seed),
                 (dem, obstacles)))
    for ax, (title, r, extra) in zip(axes, runs):
        if extra is not None:
            d, obs = extra
            x0, dx, _, y0, _, dy = d.geotransform
            rows, cols = d.array.shape
            ax.contour(x0 + dx * (np.arange(cols) + 0.5), y0 + dy * (np.arange(rows) + 0.5),
                       d.array, levels=12, colors="0.75", linewidths=0.6)
            for o in obs:
                ax.fill(*o.exterior.xy, color="lightblue")
        for lines, colour, width in ((r.geometry[r.level == 1], "tab:orange", 0.7),
                                     (r.geometry[r.level == 0], "black", 1.8)):
            for g in lines:
                c = shapely.get_coordinates(g)
                ax.plot(c[:, 0], c[:, 1], color=colour, lw=width)
        ax.plot(*box.exterior.xy, color="green", lw=0.8)
        ax.set_title(f"{title} ({r.stats['segments']} segments)")
        ax.set_aspect("equal")
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def print_tables(results):
    print("\nGrowth speed (grown segments; Scharl 2010 for comparison)")
    print(f"{'run':34s} {'segments':>9s} {'edges':>7s} {'seconds':>8s} {'seg/s':>8s}")
    for row in SCHARL:
        print(f"{'Scharl 2010 (thesis)':34s} {row['segments']:9d} {'':>7s} "
              f"{row['seconds']:8.2f} {row['segments'] / row['seconds']:8.1f}")
    for row in results["speed"]:
        name = f"ours {row['pattern']}" + (f" cap {row['target']}" if row["target"] else "")
        print(f"{name:34s} {row['segments']:9d} {row['edges']:7d} {row['seconds']:8.2f} "
              f"{row['segments_per_s']:8.0f}")
    c = results.get("constrained")
    if c:
        print(f"{'ours ' + c['pattern']:34s} {c['segments']:9d} {c['edges']:7d} "
              f"{c['seconds']:8.2f} {c['segments_per_s']:8.0f}   max slope "
              f"{100 * c['max_slope']:.2f} %, in obstacles {c['max_length_in_obstacles_m']:.1e} m")
    ev = results["evidence"]
    print("\nPattern evidence, 1 km² square, mean ± sd over 5 seeds "
          "(entropy: grid ln 4 = 1.386, uniform ln 36 = 3.584)")
    cols = [("orientation_entropy", "entropy", 3), ("mean_abs_angle_dev_90", "|a-90| °", 1),
            ("share_right_angles", "90±10°", 2), ("segment_length_mean", "len mean", 1),
            ("segment_length_median", "len med", 1), ("segment_length_cv", "len CV", 2),
            ("dead_ends_per_km2", "dead/km²", 0), ("intersections_per_km2", "int/km²", 0),
            ("segments", "grown", 0)]
    print(f"{'pattern':8s} " + " ".join(f"{c[1]:>14s}" for c in cols))
    for pattern, st in ev.items():
        cells = [f"{st[k]['mean']:.{d}f}±{st[k]['sd']:.{d}f}" for k, _, d in cols]
        print(f"{pattern:8s} " + " ".join(f"{c:>14s}" for c in cells))


def main(quick=False):
    results = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                           "platform": platform.platform()},
               "scharl_2010": SCHARL, "speed": []}
    timed_growth("grid", 200)  # warm-up (imports, caches)
    targets = (1000,) if quick else (1000, 5000, 10000)
    for pattern in growth.PATTERNS:
        for n in targets:
            results["speed"].append(timed_growth(pattern, n))
            row = results["speed"][-1]
            print(f"{pattern:8s} {row['segments']:6d} segments {row['seconds']:6.2f} s",
                  flush=True)
    results["constrained"] = constrained_run()
    results["evidence"] = pattern_evidence(seeds=(1, 2) if quick else (1, 2, 3, 4, 5))
    print_tables(results)
    RESULTS.mkdir(exist_ok=True)
    if not quick:
        picture = draw_patterns(RESULTS / "growth_patterns.png")
        if picture is not None:
            results["picture"] = str(picture.relative_to(ROOT))
            print(f"\npicture {picture}")
    out = RESULTS / ("growth_quick.json" if quick else "growth.json")
    out.write_text(json.dumps(results, indent=2, default=float))
    print(f"\nwritten {out}")
    return results


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
