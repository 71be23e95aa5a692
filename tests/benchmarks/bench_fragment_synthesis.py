"""Fragment-based road synthesis (issue 3): runtime per km² and per fragment, and the
two-sample distances of the reproduction experiment.

Run ``.venv/bin/python tests/benchmarks/bench_fragment_synthesis.py``. It builds the
Helsinki and Bubenec fragment databases with the engine (road hierarchy -> fragments ->
GeoPackage), then:

- times :func:`synthesis_fragments.synthesize` (best of 3 after a warm-up) on Helsinki's
  own level 0 roads (0.35 km² of faces) and on a 1 km² sketch (a noisy 4 x 4 grid of
  arterials 250 m apart), per km² of filled faces and per query fragment;
- reproduces the thesis's Bonn experiment on Helsinki: arterials = its level 0 roads,
  database = its own fragments, and reports the normalised Wasserstein distance (W / the
  example's standard deviation) and the KS statistic of segment length, node degree,
  intersection angle and block area between the original roads inside the arterials'
  faces and: the fragment synthesis (N_BEST = 3, mean of seeds 0-4), the same with
  N_BEST = 1 (self-retrieval: exact), a plain grid of Helsinki's median block size, the
  synthesis from Bubenec's database, and the bare arterials.

The thesis reports no runtime (ch. 4.1.4). Results go to
``tests/benchmarks/results/fragment_synthesis.json``.
"""
from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT / "build" / "plugins", ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from urban_synthesis.plugin import (  # noqa: E402
    blocks, database, fragments, hierarchy, metrics, roads)
from urban_synthesis.plugin import synthesis_fragments as sf  # noqa: E402

RESULTS = ROOT / "tests" / "benchmarks" / "results" / "fragment_synthesis.json"
MEASURES = ("segment_length", "node_degree", "intersection_angle", "area")


def build_databases(folder: Path):
    from helpers import bubenec, helsinki_roads

    df = helsinki_roads()
    g = roads.clean_network(df.geometry.values, df.highway.values, None, df.z.values)
    h = hierarchy.road_hierarchy(g, "both", roads.ARTERIAL_CLASSES, 0.1, 45.0)
    levels = h.street_level[h.streets.street_id]
    f = fragments.extract_fragments(g.geometry, levels)
    database.write_fragment_database(str(folder / "helsinki.gpkg"), f, "EPSG:32635")
    bs = roads.clean_network(bubenec("streets").geometry.values)
    hb = hierarchy.road_hierarchy(bs, "both", roads.ARTERIAL_CLASSES, 0.1, 45.0)
    fb = fragments.extract_fragments(bs.geometry, hb.street_level[hb.streets.street_id])
    database.write_fragment_database(str(folder / "bubenec.gpkg"), fb, "EPSG:32633")
    return (g.geometry, levels, database.load_fragment_database(folder / "helsinki.gpkg"),
            database.load_fragment_database(folder / "bubenec.gpkg"))


def sketch_1km2(seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for x in np.linspace(0, 1000, 5):
        out.append(shapely.LineString([(x + rng.normal(0, 15), y)
                                       for y in np.linspace(-40, 1040, 9)]))
        out.append(shapely.LineString([(y, x + rng.normal(0, 15))
                                       for y in np.linspace(-40, 1040, 9)]))
    return np.array(out, dtype=object)


def time_synthesis(arterials, dbs, repeat: int = 3):
    sf.synthesize(arterials, dbs, seed=0)  # warm-up
    best, res = np.inf, None
    for seed in range(repeat):
        t = time.perf_counter()
        r = sf.synthesize(arterials, dbs, seed=seed)
        dt = time.perf_counter() - t
        if dt < best:
            best, res = dt, r
    km2 = res.stats["area_km2"]
    n_q = res.stats["n_queries"]
    n_ins = int((res.queries.outcome == "fragment").sum())
    return dict(seconds=best, area_km2=km2, s_per_km2=best / km2, queries=n_q,
                ms_per_query=1000 * best / n_q, inserted=n_ins, edges=len(res.geometry),
                levels=sorted(int(k) for k in res.stats["levels"]))


def clipped_metrics(lines, area):
    with np.errstate(invalid="ignore"):
        parts = shapely.get_parts(shapely.intersection(np.asarray(lines, object), area))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)]
    return metrics.compute_layout_metrics(roads=parts)


def distances(candidate, reference):
    c = metrics.compare(candidate, reference)
    c = c[c.statistic == "mean"].set_index("metric")
    return {k: dict(w_norm=float(c.loc[k, "wasserstein_norm"]), ks=float(c.loc[k, "ks_stat"]))
            for k in MEASURES}


def mean_of(runs):
    return {k: {s: float(np.mean([r[k][s] for r in runs])) for s in ("w_norm", "ks")}
            for k in MEASURES}


def reproduction(lines, levels, hel, bub, seeds=range(5)):
    arterials = lines[levels == 0]
    faces, _ = blocks.block_faces(arterials)
    area = shapely.union_all(faces)
    original = clipped_metrics(lines, area)
    spacing = float(np.sqrt(np.median(metrics.compute_layout_metrics(roads=lines)
                                      .distribution("blocks", "area"))))
    rows = {}
    rows["fragments, Helsinki db, N_BEST=3"] = mean_of(
        [distances(clipped_metrics(sf.synthesize(arterials, [hel], seed=s).geometry, area),
                   original) for s in seeds])
    rows["fragments, Helsinki db, N_BEST=1 (self-retrieval)"] = distances(
        clipped_metrics(sf.synthesize(arterials, [hel], n_best=1).geometry, area), original)
    rows[f"plain grid, {spacing:.0f} m"] = distances(
        clipped_metrics(np.concatenate([arterials, sf.grid_streets(faces, spacing)]), area),
        original)
    rows["fragments, Bubenec db, N_BEST=3"] = mean_of(
        [distances(clipped_metrics(sf.synthesize(arterials, [bub], seed=s).geometry, area),
                   original) for s in seeds])
    rows["arterials only"] = distances(clipped_metrics(arterials, area), original)
    return rows, spacing, float(area.area) / 1e6


def main():
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        lines, levels, hel, bub = build_databases(Path(tmp))
        timing = {
            "Helsinki level 0 roads, Helsinki db": time_synthesis(lines[levels == 0], [hel]),
            "1 km² sketch, Helsinki db": time_synthesis(sketch_1km2(), [hel]),
            "1 km² sketch, Bubenec db": time_synthesis(sketch_1km2(), [bub]),
        }
        rows, spacing, km2 = reproduction(lines, levels, hel, bub)
    print("Fragment synthesis runtime (thesis: not reported)")
    print(f"{'input':40s} {'km²':>6s} {'s':>6s} {'s/km²':>7s} {'queries':>8s} "
          f"{'ms/query':>9s} {'inserted':>9s} {'edges':>6s}")
    for name, t in timing.items():
        print(f"{name:40s} {t['area_km2']:6.3f} {t['seconds']:6.2f} {t['s_per_km2']:7.2f} "
              f"{t['queries']:8d} {t['ms_per_query']:9.1f} {t['inserted']:9d} {t['edges']:6d}")
    print(f"\nReproduction of Helsinki ({km2:.3f} km² of level 0 faces): normalised "
          "Wasserstein distance (KS) to the original roads inside the faces")
    print(f"{'layout':50s} " + " ".join(f"{m:>22s}" for m in MEASURES))
    for name, r in rows.items():
        print(f"{name:50s} " + " ".join(f"{r[m]['w_norm']:12.3f} ({r[m]['ks']:5.2f})   "
                                        for m in MEASURES))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "machine": f"{platform.processor() or platform.machine()}, "
                   f"{__import__('os').cpu_count()} CPUs, Python {platform.python_version()}",
        "thesis_runtime": "not reported (ch. 4.1.4)",
        "timing": timing, "reproduction_area_km2": km2, "grid_spacing_m": spacing,
        "reproduction_distances": rows}, indent=2))
    print(f"\nwritten {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
