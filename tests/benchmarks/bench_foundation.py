"""Foundation benchmark (issue 2): algorithm time measured inside one QGIS process.

1. Helsinki: extractroadhierarchy + extractblocks + buildblockdatabase through
   processing.run (QGIS start-up excluded; median of 3 runs after a warm-up). Target < 5 s.
2. Scale: the same chain on Helsinki tiled 1x1 and 10x10 (100x the work); reports
   t(10x10) / (100 t(1x1)). Target <= 1.5.
3. Peers on the same roads: our block extraction vs momepy's block generation (ratio, target >= 2).

Prints a table and writes tests/benchmarks/results/foundation.json.
Run: make bench  (or .venv/bin/python tests/benchmarks/bench_foundation.py [--quick])
"""
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "plugins"))
sys.path.insert(0, "/usr/share/qgis/python/plugins")
sys.path.insert(0, str(Path(__file__).resolve().parent))
DATA = ROOT / "data" / "examples"
HELSINKI = DATA / "Helsinki.osm.pbf"
RESULTS = Path(__file__).resolve().parent / "results"


def start_qgis():
    from qgis.core import QgsApplication

    app = QgsApplication([], False)
    app.initQgis()
    from processing.core.Processing import Processing

    Processing.initialize()
    from urban_synthesis.plugin.qgis_glue.provider import UrbanSynthesisProvider

    provider = UrbanSynthesisProvider()
    QgsApplication.processingRegistry().addProvider(provider)
    import processing

    return app, provider, processing


def chain(processing, roads_src, buildings_src, workdir):
    """Run the three algorithms; returns per-algorithm seconds."""
    times = {}
    t = time.perf_counter()
    h = processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": roads_src, "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": "memory:"})
    times["extractroadhierarchy"] = time.perf_counter() - t
    t = time.perf_counter()
    b = processing.run("urbansynth:extractblocks", {
        "ROADS": h["OUTPUT"], "BUILDINGS": buildings_src, "OUTPUT": "memory:",
        "OUTPUT_BUILDINGS": "memory:"})
    times["extractblocks"] = time.perf_counter() - t
    t = time.perf_counter()
    db = Path(workdir) / f"blocks_{time.monotonic_ns()}.gpkg"
    processing.run("urbansynth:buildblockdatabase", {
        "BLOCKS": b["OUTPUT"], "BUILDINGS": b["OUTPUT_BUILDINGS"], "OUTPUT": str(db)})
    times["buildblockdatabase"] = time.perf_counter() - t
    times["total"] = sum(times.values())
    times["n_roads"] = h["OUTPUT"].featureCount()
    times["n_blocks"] = b["OUTPUT"].featureCount()
    return times


def median_runs(fn, n):
    runs = [fn() for _ in range(n)]
    keys = [k for k in runs[0] if isinstance(runs[0][k], float)]
    out = {k: statistics.median(r[k] for r in runs) for k in keys}
    out.update({k: v for k, v in runs[0].items() if k not in keys})
    return out


def tiled_inputs(workdir, n):
    """Helsinki drivable roads and buildings in UTM 35N, tiled n x n, as GeoPackages."""
    import geopandas as gpd
    import pandas as pd
    import pyogrio
    import shapely

    from urban_synthesis.plugin.network import street_graph as roads_mod

    lines = pyogrio.read_dataframe(HELSINKI, layer="lines")
    lines = lines[lines.highway.isin(roads_mod.DRIVABLE_CLASSES)].to_crs(32635)
    # 2-point rings of dirty OSM: GEOS cannot read them; the algorithm itself repairs them
    polys = pyogrio.read_dataframe(HELSINKI, layer="multipolygons", on_invalid="ignore")
    polys = polys[polys.building.notna() & polys.geometry.notna()].to_crs(32635)
    x0, y0, x1, y1 = lines.total_bounds
    dx, dy = x1 - x0 + 50.0, y1 - y0 + 50.0
    out = []
    for name, df in (("roads", lines), ("buildings", polys)):
        parts = []
        for i in range(n):
            for j in range(n):
                t = df.copy()
                t["geometry"] = shapely.transform(df.geometry.values, lambda c, i=i, j=j: c + [i * dx, j * dy])
                parts.append(t)
        tiled = gpd.GeoDataFrame(pd.concat(parts, ignore_index=True), crs=32635)
        path = Path(workdir) / f"{name}_{n}x{n}.gpkg"
        tiled.to_file(path, layer=name, driver="GPKG")
        out.append(f"{path}|layername={name}")
    return out


def main(quick=False):
    app, provider, processing = start_qgis()
    results = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                           "platform": platform.platform()}}
    with tempfile.TemporaryDirectory() as tmp:
        hel_roads = f"{HELSINKI}|layername=lines"
        hel_buildings = f"{HELSINKI}|layername=multipolygons"
        chain(processing, hel_roads, hel_buildings, tmp)  # warm-up: imports, caches
        runs = 1 if quick else 3
        hel = median_runs(lambda: chain(processing, hel_roads, hel_buildings, tmp), runs)
        results["helsinki"] = hel

        scale = {}
        for n in ((1, 3) if quick else (1, 10)):
            r_src, b_src = tiled_inputs(tmp, n)
            scale[f"{n}x{n}"] = median_runs(lambda: chain(processing, r_src, b_src, tmp), 1 if n > 1 else runs)
        keys = list(scale)
        big_n = int(keys[-1].split("x")[0]) ** 2
        scale["growth_vs_linear"] = scale[keys[-1]]["total"] / (big_n * scale[keys[0]]["total"])
        results["scale"] = scale

        try:
            import momepy  # noqa: F401 (fail here, not half-way, without momepy)
            from bench_blocks import bench_block_extraction, helsinki_drivable_lines, tile_lines

            lines = helsinki_drivable_lines()
            results["peers"] = {
                "helsinki": bench_block_extraction(lines, repeat=5, crs=32635),
                "tiled_10x10": bench_block_extraction(tile_lines(lines), repeat=2, crs=32635),
            }
        except ImportError as exc:  # momepy not installed: say so rather than skip silently
            results["peers"] = {"error": f"momepy not available: {exc}"}

    print_table(results)
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / ("foundation_quick.json" if quick else "foundation.json")
    out.write_text(json.dumps(results, indent=2, default=float))
    print(f"\nwrote {out}")
    return results


def print_table(r):
    h = r["helsinki"]
    print("\nFoundation benchmark (algorithm time inside one QGIS process, seconds)")
    print(f"{'case':34s} {'hierarchy':>10s} {'blocks':>10s} {'block db':>10s} {'total':>10s} {'target':>12s}")
    print(f"{'Helsinki (' + str(h['n_roads']) + ' roads, ' + str(h['n_blocks']) + ' blocks)':34s} "
          f"{h['extractroadhierarchy']:10.3f} {h['extractblocks']:10.3f} {h['buildblockdatabase']:10.3f} "
          f"{h['total']:10.3f} {'< 5 s':>12s}")
    for k, v in r["scale"].items():
        if isinstance(v, dict):
            print(f"{'tiled ' + k + ' (' + str(v['n_roads']) + ' roads)':34s} {v['extractroadhierarchy']:10.3f} "
                  f"{v['extractblocks']:10.3f} {v['buildblockdatabase']:10.3f} {v['total']:10.3f}")
    print(f"{'growth vs linear':34s} {r['scale']['growth_vs_linear']:54.2f}x {'<= 1.5x':>5s}")
    p = r.get("peers", {})
    if "error" in p:
        print("peers:", p["error"])
    else:
        print("\nBlock extraction vs momepy (best of repeated runs, seconds; same cleaned edges)")
        print(f"{'roads':14s} {'edges':>7s} {'blocks':>7s} {'ours':>9s} {'ours+noding':>12s} "
              f"{'ours+cleaning':>14s} {'momepy enclosures':>18s} {'ratio':>6s} {'from lines':>10s} "
              f"{'w/ cleaning':>11s}")
        for k, v in p.items():
            print(f"{k:14s} {v['n_edges']:7d} {v['n_blocks']:7d} {v['ours_s']:9.4f} "
                  f"{v['ours_from_lines_s']:12.4f} {v['ours_with_cleaning_s']:14.4f} "
                  f"{v.get('momepy_enclosures_s', float('nan')):18.4f} {v.get('ratio', 0):5.1f}x "
                  f"{v.get('ratio_from_lines', 0):9.1f}x {v.get('ratio_with_cleaning', 0):10.1f}x")
        print("target: block extraction >= 2x faster than momepy (momepy "
              f"{next(iter(p.values())).get('momepy_version')})")
    print("Papers: the thesis and Aliaga et al. report no preprocessing times.")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
