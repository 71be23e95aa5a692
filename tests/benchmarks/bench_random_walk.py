"""Evidence and timings of the Aliaga et al. 2008 synthesis (issue 4).

- Copy-and-reconnect (fig. 8): Helsinki's attributed intersection points reconnected in
  place, 5 seeds: share of the original street segments recovered (same two end points),
  precision, and the W / sigma and KS distances (:func:`metrics.compare`) of the street
  metric distributions against the original network over the same hull.
- Expand (fig. 9 / 13): a 300 m hole cut into the densest part of Helsinki, refilled from
  the rest of Helsinki's points; dead ends of the existing network at the hole (seam ends)
  joined by new streets, against the example's own dead-end share.
- Blend (figs. 10-12): Helsinki x Bubeneč over a 2 km square with BLEND 0 ... 1 (3 seeds
  each): densities, the points' interpolated street distance, segment lengths, block areas,
  tortuosity, dead ends and the W / sigma distance of the segment-length distribution to
  the two pure syntheses; whether each moves monotonically (issue 19 part 2).
- Parcels (sec. 3.1.2): voronoi-obb on Bubeneč's blocks with the cadastre's parcel areas,
  against the cadastre and the recursive / skeleton methods (Yang 2013 parcel metrics).
- Performance: CPU (process) and wall time for 1,000 ... 10,000 points (Helsinki over
  growing squares), whole syntheses and the walks alone; the CPU time is the one-thread
  cost, the wall time depends on the load. The paper gives no figure ("interactive");
  issue 16 asks for 10,000 points < 10 s.

Writes ``tests/benchmarks/results/random_walk.json``.
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
if str(ROOT / "build" / "plugins") not in sys.path:
    sys.path.insert(0, str(ROOT / "build" / "plugins"))

from urban_synthesis.plugin.network import blocks  # noqa: E402
from urban_synthesis.plugin.network import invariants  # noqa: E402
from urban_synthesis.plugin.measure import metrics  # noqa: E402
from urban_synthesis.plugin.parcels import subdivision as parcels  # noqa: E402
from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402
from urban_synthesis.plugin.roads import intersection_quadtree as iq  # noqa: E402
from urban_synthesis.plugin.roads import random_walk as rw  # noqa: E402

SEEDS = range(5)
DISTS = ("segment_length", "node_degree", "intersection_angle", "street_bearing")


def _read(layer, path, crs):
    import pyogrio

    return pyogrio.read_dataframe(path, layer=layer).to_crs(crs)


def helsinki_points():
    df = _read("lines", ROOT / "data" / "examples" / "Helsinki.osm.pbf", 32635)
    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)]
    return iq.points_from_roads(df.geometry.values, df.highway.values)


def _edges(res):
    src = res.points.source
    return {tuple(sorted((src[a], src[b]))) for a, b in zip(res.table.node_from, res.table.node_to)
            if src[a] >= 0 and src[b] >= 0}


def copy_and_reconnect(pts, graph, shapes):
    hull = shapely.convex_hull(shapely.multipoints(pts.xy)).buffer(1.0)
    m_orig = metrics.compute_layout_metrics(roads=graph.geometry, area=hull)
    original = {tuple(sorted(e)) for e in zip(graph.u, graph.v)}
    # the example's dead-end share as the tool measures it (inside the extract's hull: its
    # cut ends are no dead ends) and as the walk counts its own
    share = invariants.dead_end_share_of_extract(graph.geometry)
    runs = []
    for seed in SEEDS:
        res = rw.synthesize(pts, hull, seed=seed, in_place=True, shapes=shapes,
                            dead_end_share=share)
        got = _edges(res)
        m = metrics.compute_layout_metrics(roads=res.geometry, area=hull)
        t = metrics.compare(m, m_orig).set_index("metric")
        check = invariants.check_network(res.geometry)
        row = {"seed": seed, "recovered": len(got & original) / len(original),
               "precision": len(got & original) / len(got), "segments": len(res.table),
               "dead_end_share": res.stats["dead_end_share"],
               "mean_tortuosity": res.stats["mean_tortuosity"],
               "components": check.n_components, "violations": check.n_violations}
        for name in DISTS + ("area", "compactness"):
            row[f"{name}_W_sigma"] = float(t.loc[name, "wasserstein_norm"])
            row[f"{name}_KS"] = float(t.loc[name, "ks_stat"])
        for name in ("intersections_per_km2", "dead_ends_per_km2", "orientation_order"):
            row[name] = float(t.loc[name, "candidate"])
            row[f"{name}_example"] = float(t.loc[name, "example"])
        runs.append(row)
    mean = {k: float(np.mean([r[k] for r in runs])) for k in runs[0] if k != "seed"}
    return {"runs": runs, "mean": mean, "example_segments": len(original),
            "example_dead_end_share": float(share),
            "example_mean_tortuosity": shapes.mean_tortuosity()}


def expand(graph):
    from scipy.spatial import cKDTree

    crowd = [len(x) for x in cKDTree(graph.nodes).query_ball_point(graph.nodes, 300)]
    hole = shapely.Point(graph.nodes[int(np.argmax(crowd))]).buffer(300)
    outside = shapely.get_parts(shapely.difference(graph.geometry, hole))
    outside = outside[shapely.length(outside) > 1]
    example, eg, eh = iq.points_from_roads(outside)
    shapes = rw.street_shapes(eg, eh.edge_level)
    inside = int(shapely.contains_xy(hole, graph.nodes[:, 0], graph.nodes[:, 1]).sum())
    # the example's dead-end share inside its own area (the extract's edge and the hole's
    # outline cut streets: those ends are no dead ends)
    study = shapely.difference(shapely.convex_hull(shapely.multilinestrings(outside)), hole)
    share = invariants.dead_end_share(outside, study)
    runs = []
    for seed in SEEDS:
        res = rw.synthesize(example, hole, existing_lines=outside, seed=seed, shapes=shapes,
                            dead_end_share=share)
        st = res.stats
        check = invariants.check_network(res.geometry, outside, area=hole,
                                         example_dead_end_share=share)
        runs.append({"seed": seed, "points": st["n_points"], "segments": st["n_edges"],
                     "seam_ends": st["n_seam_ends"], "seam_joined": st["n_seam_ends_connected"],
                     "seam_open_share": 1 - st["n_seam_ends_connected"] / st["n_seam_ends"],
                     "new_dead_end_share": st["dead_end_share"],
                     "network_dead_end_share": check.dead_end_share,
                     "relaxed_seam_joins": st["n_seam_joins_relaxed"],
                     "road_junctions": st["n_road_junctions"],
                     "violations": check.n_violations})
    mean = {k: float(np.mean([r[k] for r in runs])) for k in runs[0] if k != "seed"}
    return {"runs": runs, "mean": mean, "original_points_in_hole": inside,
            "example_dead_end_share": float(share)}


BLEND_STATS = ("points_per_km2", "point_dist_mean", "intersections_per_km2",
               "street_km_per_km2", "segment_length_mean", "block_area_median",
               "mean_tortuosity", "dead_end_share")


def blend(pts, shapes):
    """Issue 19 part 2: BLEND 0 ... 1 of Helsinki (A) and Bubeneč (B) over the same 2 km
    square: every statistic should move monotonically from A's to B's."""
    bub = _read("streets", ROOT / "data" / "examples" / "bubenec.gpkg", 32635)
    bpts, bgraph, bh = iq.points_from_roads(bub.geometry.values, example=1)
    bshapes = rw.street_shapes(bgraph, bh.edge_level)
    c = np.median(pts.xy, axis=0)
    target = shapely.box(*(c - 1000), *(c + 1000))
    km2 = target.area / 1e6
    pure = {}
    rows = []
    for beta in (0.0, 0.25, 0.5, 0.75, 1.0):
        acc = []
        for seed in range(3):
            res = rw.synthesize(pts, target, example_b=bpts, blend=beta, seed=seed,
                                in_place=False, shapes=shapes, shapes_b=bshapes)
            m = metrics.compute_layout_metrics(roads=res.geometry, area=target)
            acc.append((res, m))
        seg = np.concatenate([m.distribution("roads", "segment_length") for _, m in acc])
        if beta in (0.0, 1.0):
            pure[beta] = seg
        new = [r.points.example >= 0 for r, _ in acc]
        rows.append({
            "blend": beta,
            "points_per_km2": float(np.mean([k.sum() for k in new]) / km2),
            "share_b": float(np.mean([(r.points.example[k] == 1).mean()
                                      for (r, _), k in zip(acc, new)])),
            "point_dist_mean": float(np.mean([r.points.dist_mean[k, 0].mean()
                                              for (r, _), k in zip(acc, new)])),
            "intersections_per_km2": float(np.mean([m.scalar("roads", "intersections_per_km2")
                                                    for _, m in acc])),
            "street_km_per_km2": float(np.mean([m.scalar("roads", "street_length_km_per_km2")
                                                for _, m in acc])),
            "segment_length_mean": float(seg.mean()),
            "block_area_median": float(np.median(np.concatenate(
                [m.distribution("blocks", "area") for _, m in acc if m.has("blocks", "area")]))),
            "mean_tortuosity": float(np.mean([r.stats["mean_tortuosity"] for r, _ in acc])),
            "dead_end_share": float(np.mean([m.scalar("roads", "dead_end_share")
                                             for _, m in acc])),
            "_seg": seg})
    for r in rows:
        seg = r.pop("_seg")
        r["W_sigma_to_blend0"] = float(metrics.two_sample(seg, pure[0.0])["wasserstein_norm"])
        r["W_sigma_to_blend1"] = float(metrics.two_sample(seg, pure[1.0])["wasserstein_norm"])
    monotone = {}
    for k in BLEND_STATS + ("W_sigma_to_blend0",):
        d = np.diff([r[k] for r in rows])
        monotone[k] = bool((d >= 0).all() or (d <= 0).all())
    return {"rows": rows, "target_km2": km2, "points_helsinki": len(pts),
            "points_bubenec": len(bpts), "monotone": monotone}


def parcels_evidence():
    streets = _read("streets", ROOT / "data" / "examples" / "bubenec.gpkg", 32633).geometry.values
    plots = _read("plots", ROOT / "data" / "examples" / "bubenec.gpkg", 32633).geometry.values
    extraction = blocks.extract_blocks(streets, parcels=plots)
    real = plots[extraction.parcels.in_block.to_numpy()]
    area = shapely.union_all(extraction.geometry)

    def row(label, geoms, seconds=None, access=None):
        m = metrics.parcel_metrics(geoms, area=area)
        d = metrics.two_sample(shapely.area(geoms), shapely.area(real))
        return {"label": label, "count": len(geoms),
                "p_angle": m.scalar("parcels", "p_angle"), "p_area": m.scalar("parcels", "p_area"),
                "undesirable_share": m.scalar("parcels", "undesirable_share"),
                "median_area": float(np.median(shapely.area(geoms))),
                "area_W_sigma": d["wasserstein_norm"], "area_KS": d["ks_stat"],
                "valid": bool(shapely.is_valid(geoms).all()), "with_access": access,
                "ms_per_block": None if seconds is None else
                1000 * seconds / len(extraction.geometry)}

    rows = [row("Bubeneč cadastre", real)]
    runs = [("voronoi-obb, cadastre areas", "voronoi-obb",
             parcels.SubdivisionSettings(options={"parcel_areas": shapely.area(real)})),
            ("voronoi-obb, defaults (486 m²)", "voronoi-obb", parcels.SubdivisionSettings()),
            ("recursive, max 500 m²", "recursive", parcels.SubdivisionSettings(max_area=500)),
            ("skeleton, max 500 m²", "skeleton", parcels.SubdivisionSettings(max_area=500))]
    for label, method, settings in runs:
        t0 = time.perf_counter()
        res = parcels.subdivide_blocks(extraction.geometry, method, settings, seed=1,
                                       roads=streets)
        seconds = time.perf_counter() - t0
        owner = res.table.block_id.to_numpy() - 1
        inside = bool(shapely.within(res.geometry, shapely.buffer(res.blocks[owner], 1e-6)).all())
        r = row(label, res.geometry, seconds, float(res.table.has_street_access.mean()))
        r["inside_block"] = inside
        rows.append(r)
    return {"rows": rows}


def performance(pts, shapes):
    """CPU and wall time of whole syntheses (placement, walks, one network, shapes), of the
    same without the ring rule (``WalkSettings.min_face`` 0) at 10,000 points, and of the
    walks alone (no joins, no crossings matched, no closing, parabolas) for the same
    points."""
    density = iq.example_density(pts)
    c = pts.xy.mean(axis=0)
    walks_only = rw.WalkSettings(close_ends=False, join_pieces=False, match_crossings=False)
    rows = []
    for n in (1000, 2000, 5000, 10000):
        side = np.sqrt(n / density)  # placement fills at the example's density
        square = shapely.box(*(c - side / 2), *(c + side / 2))
        for label, kw in (("one network, example shapes", dict(shapes=shapes)),
                          # the cost of the ring rule, side by side
                          ("same, short rings allowed", dict(
                              shapes=shapes, settings=rw.WalkSettings(min_face=0.0))),
                          ("walks only (as before)", dict(settings=walks_only))):
            if label.startswith("walks") and n not in (1000, 10000):
                continue
            if label.startswith("same") and n != 10000:
                continue
            best, best_cpu = None, None
            for _ in range(1 if n > 2000 else 2):
                t0, c0 = time.perf_counter(), time.process_time()
                res = rw.synthesize(pts, square, seed=1, in_place=False, **kw)
                t, cpu = time.perf_counter() - t0, time.process_time() - c0
                best = t if best is None else min(best, t)
                best_cpu = cpu if best_cpu is None else min(best_cpu, cpu)
            rows.append({"variant": label, "target_points": n, "points": res.stats["n_points"],
                         "segments": res.stats["n_edges"], "seconds": best,
                         "cpu_seconds": best_cpu,
                         "us_per_point": 1e6 * best_cpu / res.stats["n_points"]})
    return {"rows": rows, "issue_targets_s": {"10000": 10.0},
            "load_average": list(os.getloadavg()), "paper": "interactive; no figure"}


def _print(out):
    c = out["copy_and_reconnect"]
    m = c["mean"]
    print("Copy-and-reconnect (Aliaga fig. 8): Helsinki's points reconnected in place, "
          f"{len(c['runs'])} seeds (example: {c['example_segments']} segments)")
    print(f"  recovered {100 * m['recovered']:.1f} % of the original segments "
          f"(precision {100 * m['precision']:.1f} %), {m['segments']:.0f} segments; dead-end "
          f"share {100 * m['dead_end_share']:.1f} % "
          f"(example {100 * c['example_dead_end_share']:.1f} %); mean tortuosity "
          f"{m['mean_tortuosity']:.3f} (example {c['example_mean_tortuosity']:.3f}); "
          f"{m['components']:.1f} component(s), {m['violations']:.1f} invariant violations")
    print(f"  {'distribution':22s} {'W/sigma':>8s} {'KS':>6s}")
    for name in DISTS + ("area", "compactness"):
        print(f"  {name:22s} {m[name + '_W_sigma']:8.3f} {m[name + '_KS']:6.3f}")
    for name in ("intersections_per_km2", "dead_ends_per_km2", "orientation_order"):
        print(f"  {name:22s} {m[name]:8.2f} (example {m[name + '_example']:.2f})")
    e = out["expand"]
    me = e["mean"]
    print(f"\nExpand (fig. 9/13): 300 m hole in Helsinki ({e['original_points_in_hole']} original "
          f"points), refilled from the rest, {len(e['runs'])} seeds")
    print(f"  {me['points']:.1f} points, {me['segments']:.1f} segments; seam ends joined "
          f"{me['seam_joined']:.1f} of {me['seam_ends']:.0f} "
          f"(open {100 * me['seam_open_share']:.1f} %, "
          f"example dead-end share {100 * e['example_dead_end_share']:.1f} %); new points' "
          f"dead-end share {100 * me['new_dead_end_share']:.1f} %, the network's "
          f"{100 * me['network_dead_end_share']:.1f} %; {me['road_junctions']:.1f} junctions on "
          f"the existing roads; {me['violations']:.1f} invariant violations")
    b = out["blend"]
    print(f"\nBlend (figs. 10-12): Helsinki x Bubeneč over {b['target_km2']:.1f} km², "
          "3 seeds each")
    head = f"  {'BLEND':>5s} {'pts/km2':>8s} {'B share':>7s} {'pt mu_d':>7s} {'int/km2':>8s} " \
           f"{'km/km2':>7s} {'seg mean':>8s} {'blk med':>8s} {'tort':>6s} {'dead':>5s} " \
           f"{'W/s to 0':>8s} {'W/s to 1':>8s}"
    print(head)
    for r in b["rows"]:
        print(f"  {r['blend']:5.2f} {r['points_per_km2']:8.1f} {r['share_b']:7.2f} "
              f"{r['point_dist_mean']:7.1f} {r['intersections_per_km2']:8.1f} "
              f"{r['street_km_per_km2']:7.2f} {r['segment_length_mean']:8.1f} "
              f"{r['block_area_median']:8.0f} {r['mean_tortuosity']:6.3f} "
              f"{r['dead_end_share']:5.2f} {r['W_sigma_to_blend0']:8.3f} "
              f"{r['W_sigma_to_blend1']:8.3f}")
    print("  monotone from BLEND 0 to 1: " + ", ".join(
        f"{k} {'yes' if v else 'NO'}" for k, v in b["monotone"].items()))
    print("\nParcels on Bubeneč's 7 blocks (Yang 2013 metrics; area distances to the cadastre)")
    print(f"  {'':32s} {'n':>4s} {'p_angle':>7s} {'p_area':>6s} {'undes.%':>7s} {'median':>7s} "
          f"{'W/sigma':>7s} {'KS':>5s} {'access':>6s} {'ms/blk':>6s}")
    for r in out["parcels"]["rows"]:
        acc = "" if r["with_access"] is None else f"{100 * r['with_access']:.0f} %"
        ms = "" if r["ms_per_block"] is None else f"{r['ms_per_block']:.1f}"
        print(f"  {r['label']:32s} {r['count']:4d} {r['p_angle']:7.2f} {r['p_area']:6.3f} "
              f"{r['undesirable_share']:7.1f} {r['median_area']:7.0f} {r['area_W_sigma']:7.3f} "
              f"{r['area_KS']:5.2f} {acc:>6s} {ms:>6s}")
    p = out["performance"]
    print("\nPerformance (issue 16: 10,000 points < 10 s; paper: interactive, no figure)")
    print(f"  {'variant':30s} {'points':>7s} {'segments':>8s} {'CPU s':>8s} {'wall s':>8s} "
          f"{'us/point':>8s}")
    for r in p["rows"]:
        print(f"  {r['variant']:30s} {r['points']:7d} {r['segments']:8d} {r['cpu_seconds']:8.2f} "
              f"{r['seconds']:8.2f} {r['us_per_point']:8.0f}")
    print("  (CPU s: process time of the run, one thread; wall s: elapsed, on a shared machine "
          f"with load average {p['load_average'][0]:.1f} on 2 cores: both are inflated)")


def bench():
    pts, graph, h = helsinki_points()
    shapes = rw.street_shapes(graph, h.edge_level)
    return {"machine": {"python": platform.python_version(), "platform": platform.platform()},
            "copy_and_reconnect": copy_and_reconnect(pts, graph, shapes), "expand": expand(graph),
            "blend": blend(pts, shapes), "parcels": parcels_evidence(),
            "performance": performance(pts, shapes)}


if __name__ == "__main__":
    import warnings

    warnings.filterwarnings("ignore")
    result = bench()
    _print(result)
    target = ROOT / "tests" / "benchmarks" / "results" / "random_walk.json"
    target.write_text(json.dumps(result, indent=2, ensure_ascii=False), encoding="utf-8")
    print(f"\nwritten to {target.relative_to(ROOT)}")
