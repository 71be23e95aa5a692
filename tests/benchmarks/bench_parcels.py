"""Parcel subdivision on Bubeneč's blocks against its cadastre and Yang et al. 2013, Table 1.

Yang's parcel metrics (sec. 7: p_n parcels per km², p_angle the mean deviation of parcel
corners from 90°, p_area the mean minimum-bounding-rectangle area / parcel area, and the
undesirable parcels with p_angle > 15° or p_area > 1.2, Fig. 12) are computed with
:func:`metrics.parcel_metrics` for

- Bubeneč's real cadastre parcels that lie in the 7 blocks closed by its streets;
- ``recursive`` and ``skeleton`` subdivisions of the same blocks (shrunk by 6 m, the
  default 12 m street), with the default settings and with a maximum area of 500 m²
  (which gives about the cadastre's parcel count: its median parcel is 361 m²), and a
  deliberately jittered recursive run (irregularity 1) as a control;

and printed next to Yang 2013 Table 1's Map (real layouts), CE1 (CityEngine: Weber et al.
street growth + Vanegas et al. 2012 parcels) and Our rows for Salisbury, Hempstead and
Villagepark. p_n counts parcels per km² of the blocks (Yang: of the whole region, streets
included; our density is per km² of block land, so it is higher for the same parcels).

Time per block is the best of several runs of :func:`parcels.subdivide_blocks` (shrinking
included) on Bubeneč (7 blocks) and on Helsinki's 54 blocks.

Liechtenstein (issue 19, part 4): ``voronoi-obb`` (Aliaga et al. 2008, sec. 3.1.2) with the
default settings on the real blocks of each of the eleven municipalities (OSM admin_level
8; blocks of the whole country's drivable OSM streets by the network engine, a block
belonging to the town its inner point lies in), never tuned on: lots narrower than the
minimum width (the short side of the minimum bounding rectangle) and without street access
must both be zero; beside them the median width and area, the share of lots more than ten
times longer than wide, and the numbers of the method before this change (commit 98b3624,
the same blocks and seed). CPU and wall seconds per town (a shared machine: wall time is
noisy). Writes ``tests/benchmarks/results/parcels.json``.
"""
from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

import shapely

ROOT = Path(__file__).resolve().parents[2]
for _path in (ROOT / "build" / "plugins", ROOT / "tests"):
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

from urban_synthesis.plugin.network import blocks  # noqa: E402
from urban_synthesis.plugin.measure import metrics  # noqa: E402
from urban_synthesis.plugin.parcels import subdivision as parcels  # noqa: E402
from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402

__all__ = ["YANG_TABLE1", "YANG_FIG12_UNDESIRABLE", "bubenec_inputs", "yang_metrics",
           "bench_towns", "bench_parcels"]

#: Yang et al. 2013, Table 1: p_n (per km²), p_angle (°), p_area per region and method.
YANG_TABLE1 = {
    ("Salisbury", "Map"): (879, 5.840, 1.118), ("Salisbury", "CE1"): (874, 5.012, 1.076),
    ("Salisbury", "CE2"): (958, 3.681, 1.071), ("Salisbury", "Our"): (1062, 3.188, 1.063),
    ("Hempstead", "Map"): (1152, 7.502, 1.112), ("Hempstead", "CE1"): (965, 4.650, 1.082),
    ("Hempstead", "CE2"): (1176, 2.188, 1.054), ("Hempstead", "Our"): (1271, 2.136, 1.042),
    ("Villagepark", "Map"): (577, 4.932, 1.102), ("Villagepark", "CE1"): (986, 4.321, 1.076),
    ("Villagepark", "CE2"): (1094, 2.874, 1.058), ("Villagepark", "Our"): (1282, 2.266, 1.045),
}
#: Yang et al. 2013, Fig. 12 (Salisbury): number of undesirable parcels.
YANG_FIG12_UNDESIRABLE = {"CE1": 119, "Map": 138, "CE2": 57, "Our": 48}

#: voronoi-obb before issue 19 (commit 98b3624) on the same blocks, seed 1, defaults:
#: town -> (lots, median width m, lots under 8 m, lots without street access).
BEFORE_ISSUE_19 = {
    "Triesen": (3772, 5.2, 2469, 0), "Schellenberg": (550, 4.1, 389, 0),
    "Gamprin": (8429, 0.8, 8300, 6562), "Triesenberg": (4998, 3.7, 4042, 187),
    "Eschen": (4156, 4.7, 3157, 294), "Ruggell": (3880, 1.5, 3484, 1806),
    "Mauren": (4907, 3.2, 4160, 854), "Schaan": (3907, 6.9, 2674, 570),
    "Balzers": (3750, 5.9, 2478, 378), "Planken": (6152, 0.9, 6034, 5522),
    "Vaduz": (6798, 2.5, 5467, 709),
}

RUNS = [  # label, method, settings
    ("recursive (defaults)", "recursive", {}),
    ("recursive, max 500 m²", "recursive", {"max_area": 500}),
    ("recursive, max 500 m², irregularity 1", "recursive", {"max_area": 500, "irregularity": 1.0}),
    ("skeleton (defaults)", "skeleton", {}),
    ("skeleton, max 500 m²", "skeleton", {"max_area": 500}),
    ("voronoi-obb (defaults, 486 m²)", "voronoi-obb", {}),
    ("voronoi-obb, cadastre areas", "voronoi-obb", {"options": "cadastre"}),
    ("voronoi-obb, cadastre areas, its limits (3 m, 50 m²)", "voronoi-obb",
     {"options": "cadastre", "min_width": 3.0, "min_area": 50.0}),
]


def _best(fn, repeat: int = 3, budget_s: float = 1.0):
    """Best time of at least ``repeat`` runs after a warm-up run."""
    out = fn()
    times = []
    while len(times) < repeat or (sum(times) < budget_s and len(times) < 50):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def bubenec_inputs(crs: int = 32633):
    """Bubeneč streets, its blocks and its cadastre parcels that lie in a block (UTM 33N)."""
    import pyogrio

    gpkg = ROOT / "data" / "examples" / "bubenec.gpkg"
    streets = pyogrio.read_dataframe(gpkg, layer="streets").to_crs(crs).geometry.values
    plots = pyogrio.read_dataframe(gpkg, layer="plots").to_crs(crs).geometry.values
    extraction = blocks.extract_blocks(streets, parcels=plots)
    return streets, extraction, plots[extraction.parcels.in_block.to_numpy()]


def helsinki_inputs(crs: int = 32635):
    """Helsinki's cleaned drivable street graph and its blocks."""
    import pyogrio

    df = pyogrio.read_dataframe(ROOT / "data" / "examples" / "Helsinki.osm.pbf", layer="lines")
    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(crs)
    graph = roads.clean_network(df.geometry.values, df.highway.values, merge_degree2=False)
    return graph.geometry, blocks.extract_blocks(graph)


def yang_metrics(geoms, area) -> dict:
    """Yang 2013's parcel scalars of :func:`metrics.parcel_metrics`."""
    r = metrics.parcel_metrics(geoms, area=area)
    return {k: r.scalar("parcels", k) for k in (
        "count", "p_n_per_km2", "p_angle", "p_area", "undesirable_count", "undesirable_share")}


def bench_parcels(seed: int = 1) -> dict:
    """Metrics of every run and of the cadastre, timings per block; see the module doc."""
    streets, extraction, real = bubenec_inputs()
    area = shapely.union_all(extraction.geometry)
    n_blocks = len(extraction.geometry)
    rows = [dict(label="Bubeneč cadastre (real parcels in the blocks)", method="cadastre",
                 **yang_metrics(real, area))]
    for label, method, kwargs in RUNS:
        if kwargs.get("options") == "cadastre":
            kwargs = dict(kwargs, options={"parcel_areas": shapely.area(real)})
        settings = parcels.SubdivisionSettings(**kwargs)
        seconds, result = _best(lambda: parcels.subdivide_blocks(
            extraction.geometry, method, settings, seed=seed, roads=streets))
        _, width, _ = blocks.minimum_rectangles(result.geometry)
        rows.append(dict(label=label, method=method,
                         settings={k: v for k, v in kwargs.items() if k != "options"},
                         under_min_width=int((width < settings.min_width).sum()),
                         ms_per_block=1000 * seconds / n_blocks,
                         with_access_share=float(result.table.has_street_access.mean()),
                         over_max_area=result.stats["n_over_max_area"],
                         **yang_metrics(result.geometry, area)))
    h_streets, h_blocks = helsinki_inputs()
    helsinki = {"n_blocks": len(h_blocks.geometry)}
    for method in parcels.method_names():
        seconds, result = _best(lambda: parcels.subdivide_blocks(
            h_blocks.geometry, method, seed=seed, roads=h_streets), repeat=2)
        helsinki[method] = {"ms_per_block": 1000 * seconds / len(h_blocks.geometry),
                            "n_lots": len(result.geometry),
                            "valid": bool(shapely.is_valid(result.geometry).all()),
                            "with_access_share": float(result.table.has_street_access.mean())}
    return {"machine": {"python": platform.python_version(), "platform": platform.platform()},
            "liechtenstein": bench_towns(seed),
            "bubenec": {"n_blocks": n_blocks, "blocks_km2": shapely.area(area) / 1e6,
                        "rows": rows},
            "helsinki": helsinki,
            "yang2013_table1": {f"{k[0]} {k[1]}": dict(zip(("p_n_per_km2", "p_angle", "p_area"), v))
                                for k, v in YANG_TABLE1.items()},
            "yang2013_fig12_undesirable_salisbury": YANG_FIG12_UNDESIRABLE}


def bench_towns(seed: int = 1, method: str = "voronoi-obb") -> list:
    """One row per Liechtenstein municipality; see the module doc."""
    import numpy as np

    from helpers import liechtenstein_town_blocks, liechtenstein_towns

    settings = parcels.SubdivisionSettings()
    rows = []
    for town in liechtenstein_towns():
        streets, town_blocks = liechtenstein_town_blocks(town)
        t0, c0 = time.perf_counter(), time.process_time()
        result = parcels.subdivide_blocks(town_blocks, method, settings, seed=seed,
                                          roads=streets)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        length, width, _ = blocks.minimum_rectangles(result.geometry)
        rows.append({
            "town": town, "n_blocks": len(town_blocks), "n_lots": len(result.geometry),
            "median_width_m": float(np.median(width)),
            "under_min_width": int((width < settings.min_width).sum()),
            "without_access": int((~result.table.has_street_access).sum()),
            "longer_than_10x_share": float(np.mean(length > 10 * width)),
            "median_area_m2": float(np.median(result.table.area_m2)),
            "valid": bool(shapely.is_valid(result.geometry).all()),
            "cpu_s": cpu, "wall_s": wall,
            "before_issue_19": dict(zip(("n_lots", "median_width_m", "under_min_width",
                                         "without_access"), BEFORE_ISSUE_19.get(town, ()))),
        })
    return rows


def _print(result: dict) -> None:
    towns = result["liechtenstein"]
    print("Liechtenstein towns, voronoi-obb, defaults (min width 8 m, lot width 18 m -> "
          "486 m²); before = commit 98b3624\n")
    head = (f"{'town':13s} {'blocks':>6s} {'lots':>5s} {'med. width':>10s} {'< 8 m':>6s} "
            f"{'no access':>9s} {'>10:1':>6s} {'med. m²':>7s} {'cpu s':>6s} {'wall s':>6s}"
            f" | {'before: lots':>12s} {'med. width':>10s} {'< 8 m':>6s} {'no access':>9s}")
    print(head)
    print("-" * len(head))
    for r in towns:
        b = r["before_issue_19"]
        print(f"{r['town']:13s} {r['n_blocks']:6d} {r['n_lots']:5d} {r['median_width_m']:10.1f} "
              f"{r['under_min_width']:6d} {r['without_access']:9d} "
              f"{100 * r['longer_than_10x_share']:5.1f}% {r['median_area_m2']:7.0f} "
              f"{r['cpu_s']:6.2f} {r['wall_s']:6.2f} | {b.get('n_lots', 0):12d} "
              f"{b.get('median_width_m', 0):10.1f} {b.get('under_min_width', 0):6d} "
              f"{b.get('without_access', 0):9d}")
    print(f"goal: zero lots under 8 m and zero without access in every town -> "
          f"{sum(r['under_min_width'] for r in towns)} and "
          f"{sum(r['without_access'] for r in towns)}\n")
    b = result["bubenec"]
    print(f"Bubeneč: {b['n_blocks']} blocks, {b['blocks_km2']:.4f} km² of block land; "
          "Yang 2013 parcel metrics (p_n per km² of blocks)\n")
    head = f"{'':52s} {'parcels':>7s} {'p_n/km²':>8s} {'p_angle':>7s} {'p_area':>6s} " \
           f"{'undesirable':>14s} {'ms/block':>8s} {'< min w':>7s} {'access':>6s}"
    print(head)
    print("-" * len(head))
    for r in b["rows"]:
        ms = f"{r['ms_per_block']:8.1f}" if "ms_per_block" in r else f"{'':8s}"
        extra = f" {r['under_min_width']:7d} {100 * r['with_access_share']:5.0f}%" \
            if "under_min_width" in r else ""
        print(f"{r['label']:52s} {r['count']:7.0f} {r['p_n_per_km2']:8.0f} {r['p_angle']:7.2f} "
              f"{r['p_area']:6.3f} {r['undesirable_count']:5.0f} ({r['undesirable_share']:4.1f} %) "
              f"{ms}{extra}")
    print("\nYang et al. 2013, Table 1 (p_n per km² of the region; undesirable: Fig. 12)")
    for (region, method), (p_n, p_angle, p_area) in YANG_TABLE1.items():
        if method == "CE2":
            continue
        bad = YANG_FIG12_UNDESIRABLE.get(method) if region == "Salisbury" else None
        label = f"{region} {method}" + (" (real)" if method == "Map" else " (CityEngine)"
                                        if method == "CE1" else "")
        print(f"{label:52s} {'':7s} {p_n:8.0f} {p_angle:7.2f} {p_area:6.3f} "
              f"{'' if bad is None else f'{bad:5d}':>14s}")
    h = result["helsinki"]
    print(f"\nHelsinki ({h['n_blocks']} blocks): " + ", ".join(
        f"{m} {h[m]['ms_per_block']:.1f} ms/block ({h[m]['n_lots']} lots, valid {h[m]['valid']}, "
        f"{100 * h[m]['with_access_share']:.0f} % with access)" for m in parcels.method_names()))


if __name__ == "__main__":
    import warnings

    warnings.filterwarnings("ignore")
    out = bench_parcels()
    _print(out)
    target = ROOT / "tests" / "benchmarks" / "results" / "parcels.json"
    target.write_text(json.dumps(out, indent=2, ensure_ascii=False), encoding="utf-8")
    print(f"\nwritten to {target.relative_to(ROOT)}")
