"""StreetGAN evidence and performance (issue 5, thesis ch. 4.2).

    QT_QPA_PLATFORM=offscreen .venv/bin/python tests/benchmarks/bench_gan.py [--cards]

For each shipped model: the thesis's block measures (area, compactness, aspect ratio) and
dead ends per km² of generated networks against the network the model was trained on,
as two-sample distances (Wasserstein / the example's spread, KS), next to the same for
(a) the training network itself sent through raster -> graph (what the post-processing
alone changes), (b) the thesis's post-processing (dead ends measured along the skeleton,
not from the road's edge), (c) the raw,
untrained generator and (d) a random-noise image. Every network is clipped to the same
window (the training network's extent less 30 m); dead ends on the window's edge are cut
streets, not dead ends, and are not counted.

For a model whose card names held-out towns (``streetgan_towns``: Liechtenstein towns it
never saw), each held-out town instead: its outline as the target, its level-0 roads given
(kept, joined), 3 seeds, the 16 statistics of the fidelity issue (issue 15) as relative
errors against the town's real drivable streets, beside the ceiling: the real network
itself rasterised and sent through the same post-processing (what the raster pipeline
alone loses), and the network invariants of every run.

Every synthesis here runs without the edge streets (``edge_join=0``): the cards measure the
generator and its read-back as the thesis has them; what the tool's default adds at the
target's edge is measured by the fidelity benchmark (``bench_fidelity.py``).

Performance: a 769 x 769 image (z of 25 x 25 x 100) with onnxruntime, raster -> graph of
that image, and a whole synthesis per km². Prints tables, writes
tests/benchmarks/results/gan.json and docs/streetgan.png; ``--cards`` also stores the
evaluation in the model cards (resources/models/*.json).
"""
from __future__ import annotations

import argparse
import importlib.util
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

from urban_synthesis.plugin.measure import metrics  # noqa: E402
from urban_synthesis.plugin.roads import raster_graph  # noqa: E402
from urban_synthesis.plugin.roads import streetgan  # noqa: E402

SEEDS = (1, 2, 3)
DEFAULT = "StreetGAN (dead ends from road edge)"
THESIS = {"generate_769_s": 0.08, "raster_to_graph_s": 5.1}
#: where ``make train-gan`` leaves the raw generators (train.py writes <out>_untrained.onnx)
UNTRAINED_DIRS = (ROOT / "build" / "streetgan", ROOT / "build" / "streetgan" / "models")


def _prepare():
    spec = importlib.util.spec_from_file_location("sg_prepare", ROOT / "tools" / "streetgan" / "prepare.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def training_lines(card: dict) -> np.ndarray:
    prep = _prepare()
    name = card.get("training_data", {}).get("name")
    fn = {"helsinki": prep.helsinki_lines, "grid": prep.grid_lines}.get(name)
    if fn is None:
        raise SystemExit(f"unknown training data {name!r} in card {card.get('name')}")
    return np.asarray(fn(), dtype=object)


def window_metrics(lines, window):
    """Metrics of the part of a network inside ``window``; cut ends are not dead ends."""
    lines = np.asarray(lines, dtype=object)
    with np.errstate(invalid="ignore", divide="ignore"):
        parts = shapely.get_parts(shapely.intersection(lines, window)) if len(lines) else lines
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)]
    if len(parts) == 0:
        return None
    return metrics.compute_layout_metrics(roads=parts, area=window.buffer(-2.0))


MEASURES = (("blocks", "area"), ("blocks", "compactness"), ("blocks", "aspect_ratio"))


def pooled(results):
    """Distributions pooled over several networks; dead ends and blocks per km² averaged."""
    results = [r for r in results if r is not None]
    out = {"networks": len(results)}
    for kind, name in MEASURES:
        vals = [r.distribution(kind, name) for r in results if r.has(kind, name)]
        out[name] = np.concatenate(vals) if vals else np.empty(0)
    for key, (kind, name) in {"dead_ends_per_km2": ("roads", "dead_ends_per_km2"),
                              "blocks_per_km2": ("blocks", "blocks_per_km2"),
                              "street_km_per_km2": ("roads", "street_length_km_per_km2")}.items():
        v = [r.scalar(kind, name) for r in results if r.has(kind, name)]
        out[key] = float(np.mean(v)) if v else float("nan")
    return out


def distances(cand, real):
    row = {"networks": cand["networks"], "blocks": int(len(cand["area"])) // max(cand["networks"], 1)}
    for _, name in MEASURES:
        d = metrics.two_sample(cand[name], real[name])
        row[f"{name}_w"] = round(float(d["wasserstein_norm"]), 3)
        row[f"{name}_ks"] = round(float(d["ks_stat"]), 3)
    row["dead_ends_per_km2"] = round(cand["dead_ends_per_km2"], 1)
    row["dead_end_ratio"] = round(cand["dead_ends_per_km2"] / real["dead_ends_per_km2"], 2) \
        if real["dead_ends_per_km2"] > 0 else float("nan")
    row["blocks_per_km2"] = round(cand["blocks_per_km2"], 1)
    row["street_km_per_km2"] = round(cand["street_km_per_km2"], 2)
    return row


def untrained_generator(name: str, card: dict):
    paths = [d / f"{name}_untrained.onnx" for d in UNTRAINED_DIRS if (d / f"{name}_untrained.onnx").exists()]
    if not paths:
        return None
    path = paths[0]
    raw_card = {k: v for k, v in card.items() if k != "onnx_sha256"}
    return streetgan.load_model(path, card=raw_card)


def noise_image(rows, cols, seed):
    return np.random.default_rng(seed).uniform(0, 255, size=(rows, cols))


def evaluate_model(name: str, figures: dict) -> dict:
    gen = streetgan.load_model(name)
    card = gen.card
    real_lines = training_lines(card)
    x0, y0, x1, y1 = shapely.total_bounds(real_lines)
    window = shapely.box(x0 + 30, y0 + 30, x1 - 30, y1 - 30)
    real = pooled([window_metrics(real_lines, window)])
    # the same window at the origin for the syntheses
    wx0, wy0, wx1, wy1 = window.bounds
    target = shapely.box(0, 0, wx1 - wx0, wy1 - wy0)
    real_o = pooled([window_metrics(shapely.transform(real_lines, lambda c: c - [wx0, wy0]), target)])
    rows = {"real (training network)": distances(real_o, real_o)}
    # (a) round trip: the training raster itself through raster -> graph
    img, gt = raster_graph.rasterize_lines(real_lines, width_px=gen.line_width_px, margin=0.0)
    trip = raster_graph.raster_to_graph(img, gt, **gen.morphology)
    rows["real -> raster -> graph"] = distances(pooled([window_metrics(trip.geometry, window)]), real)
    variants = {DEFAULT: dict(model=gen, from_edge=True),
                "StreetGAN, thesis post-processing": dict(model=gen, from_edge=False)}
    raw = untrained_generator(name, card)
    if raw is not None:
        variants["untrained generator"] = dict(model=raw, from_edge=True)
    samples = {}
    for label, kw in variants.items():
        res = [streetgan.synthesize(target, kw["model"], seed=s, from_edge=kw["from_edge"],
                                    edge_join=0) for s in SEEDS]
        samples[label] = res[0]
        rows[label] = distances(pooled([window_metrics(r.geometry, target) for r in res]), real_o)
    if raw is None:
        rows["untrained generator"] = {"note": f"missing build/streetgan/{name}_untrained.onnx "
                                               "(make train-gan writes it)"}
    # (d) random noise through the same pipeline
    rr, cc = samples[DEFAULT].image.shape
    res = []
    for s in SEEDS:
        rg = raster_graph.raster_to_graph(noise_image(rr, cc, s), (-96.0, 3.0, 0.0, target.bounds[3] + 96.0, 0.0, -3.0),
                                          **gen.morphology)
        res.append(window_metrics(rg.geometry, target))
    rows["random noise image"] = distances(pooled(res), real_o)
    figures[name] = dict(real=shapely.transform(real_lines, lambda c: c - [wx0, wy0]), target=target,
                         sample=samples[DEFAULT], title=card.get("title", name))
    return {"model": name, "title": card.get("title"), "window_km2": round(target.area / 1e6, 3),
            "seeds": list(SEEDS), "rows": rows}


#: Short labels of the statistics of the fidelity issue (issue 15), in the order of
#: :data:`plugin.measure.fidelity.STATISTICS` (their one home).
FIDELITY_LABELS = ("intersections/km²", "dead ends/km²", "km/km²", "degree-1 share",
                   "degree-3 share", "degree-4 share", "segment p10", "segment median",
                   "segment p90", "orientation entropy", "blocks/km²", "block area p10",
                   "block area median", "block area p90", "compactness median",
                   "aspect ratio median")


def fidelity_values(lines, area) -> np.ndarray:
    """The fidelity statistics (:func:`plugin.measure.fidelity.fidelity_statistics`) of the
    network ``lines`` inside ``area`` as an array; NaN where no street lies inside."""
    from urban_synthesis.plugin.core.progress import InputError
    from urban_synthesis.plugin.measure import fidelity

    try:
        stats = fidelity.fidelity_statistics(lines, area)
    except InputError:
        return np.full(len(fidelity.STATISTICS), np.nan)
    return np.array([stats[k] for k, _ in fidelity.STATISTICS], dtype=float)


def _relative_errors(values, real):
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(values - real) / np.abs(real)
    return np.where(np.isfinite(values), np.where(np.isfinite(err), err, 0.0), 1.0)


def _li():
    sys.path.insert(0, str(ROOT / "tools"))
    import liechtenstein

    return liechtenstein


def evaluate_held_out(name: str, figures: dict) -> dict:
    """The towns a model never saw (its card's ``training_data.held_out``): the fidelity
    statistics of the model, steered to the example's statistics (the other towns, as the
    fidelity benchmark steers it) and as read back, and of the raster round trip of the
    real network (the ceiling), relative errors against the real town, and the invariants."""
    from urban_synthesis.plugin.measure import fidelity
    from urban_synthesis.plugin.network import invariants

    li = _li()
    gen = streetgan.load_model(name)
    towns = {}
    for town in gen.card["training_data"]["held_out"]:
        case = li.leave_one_out(town)
        area, given, cls = case["area"], case["given"], case["given_class"]
        real = fidelity_values(case["real"], area)

        def real_raster(model, rows, cols, seed, tile, progress, case=case):
            x0, _, _, y1 = case["area"].bounds
            x0, y1 = x0 - 96.0, y1 + 96.0
            img, _ = raster_graph.rasterize_lines(np.concatenate([case["real"], case["given"]]),
                                                  3.0, gen.line_width_px,
                                                  bounds=(x0, y1 - rows * 3.0,
                                                                   x0 + cols * 3.0, y1))
            return img[:rows, :cols].astype(np.float32)

        # what an analyst with the example passes, as the fidelity benchmark steers it
        steering = streetgan.example_steering(fidelity.fidelity_statistics(
            case["example"], case["example_area"]))
        rows = {}
        for label, kw in (("real -> raster -> graph (ceiling)", dict(generate_fn=real_raster)),
                          (name, steering),
                          (f"{name}, as read back (no example statistics)", {})):
            vals, viols, comps = [], [], []
            seeds = (1,) if "generate_fn" in kw else SEEDS
            for seed in seeds:
                res = streetgan.synthesize(area, gen, seed=seed, given=given, given_class=cls,
                                           edge_join=0, **kw)
                new = res.geometry[~res.given]
                vals.append(fidelity_values(np.concatenate([new, given]), area))
                check = invariants.check_network(new, given, cls, area)
                v = check.violations()
                v.pop("dead_end_share")
                viols.append(int(sum(v.values())))
                comps.append(check.floating_pieces)
                if label == name and seed == SEEDS[0]:
                    figures[f"{name}:{town}"] = dict(real=case["real"], given=given, area=area,
                                                     sample=res, title=town)
            v = np.nanmean(vals, axis=0)
            err = _relative_errors(v, real)
            rows[label] = {"values": [round(float(x), 4) for x in v],
                           "relative_errors": [round(float(x), 3) for x in err],
                           "median_relative_error": round(float(np.median(err)), 3),
                           "violations": viols, "floating_pieces": comps}
        towns[town] = {"area_km2": round(area.area / 1e6, 2),
                       "real": [round(float(x), 4) for x in real], "rows": rows,
                       "example_steering": {k: round(float(v), 4) for k, v in steering.items()}}
    return {"model": name, "title": gen.card.get("title"), "against": "towns never seen in "
            "training (leave-one-town-out), their level-0 roads given",
            "statistics": list(FIDELITY_LABELS), "seeds": list(SEEDS),
            "towns": towns}


#: Raster representations compared by :func:`representation_ceiling`: (label, cell size m,
#: line width px, erosions, dilations).
REPRESENTATIONS = (("thesis: 3 m, 15 px lines, 1 erosion + 5 dilations", 3.0, 15, 1, 5),
                   ("3 m, 5 px lines, 1 + 1", 3.0, 5, 1, 1),
                   ("2 m, 5 px lines, 1 + 1", 2.0, 5, 1, 1),
                   ("3 m, 15 px lines, 1 + 1 (streetgan_towns read-back)", 3.0, 15, 1, 1),
                   ("3 m, 15 px lines, 2 + 2 (streetgan_helsinki read-back)", 3.0, 15, 2, 2))


def representation_ceiling(towns=("Eschen", "Mauren", "Triesen")) -> dict:
    """What the raster representation alone loses: each town's real drivable streets
    rasterised and read back (no generator), median relative error of the 16 fidelity
    statistics against the real network, and blocks per km², per representation."""
    li = _li()
    out = {"towns": list(towns), "rows": {}}
    for label, cell, width, erosions, dilations in REPRESENTATIONS:
        errs, blocks = [], []
        for town in towns:
            case = li.leave_one_out(town)
            lines = np.concatenate([case["real"], case["given"]])
            real = fidelity_values(lines, case["area"])
            img, gt = raster_graph.rasterize_lines(lines, cell, width,
                                                   bounds=case["area"].buffer(96.0).bounds)
            merge = streetgan.junction_merge_distance(width, cell)
            rg = raster_graph.raster_to_graph(img.astype(np.float32), gt, erosions=erosions,
                                              dilations=dilations, simplify=cell,
                                              merge_junctions=merge)
            v = fidelity_values(rg.geometry, case["area"])
            errs.append(round(float(np.median(_relative_errors(v, real))), 3))
            blocks.append([round(float(real[10]), 1), round(float(v[10]), 1)])
        out["rows"][label] = {"median_relative_error": errs,
                              "blocks_per_km2_real_and_read_back": blocks}
    return out


def performance(name: str) -> dict:
    gen = streetgan.load_model(name)
    z = streetgan.noise(25, 25, gen.channels, np.random.default_rng(0))
    gen.run(z)  # warm-up (session initialisation)
    t_gen, c_gen = [], []
    for _ in range(5):
        t, c = time.perf_counter(), time.process_time()
        img = gen.run(z)
        t_gen.append(time.perf_counter() - t)
        c_gen.append(time.process_time() - c)
    gt = (0.0, 3.0, 0.0, 769 * 3.0, 0.0, -3.0)
    t_rg, c_rg, stats = [], [], None
    for _ in range(3):
        t, c = time.perf_counter(), time.process_time()
        r = raster_graph.raster_to_graph(
            img, gt, merge_junctions=gen.merge_distance(), **gen.morphology)
        t_rg.append(time.perf_counter() - t)
        c_rg.append(time.process_time() - c)
        stats = r.stats
    target = shapely.box(0, 0, 2000, 2000)
    t = time.perf_counter()
    res = streetgan.synthesize(target, gen, seed=5, edge_join=0)
    t_total = time.perf_counter() - t
    return {"model": name, "image_px": list(img.shape), "image_km2": round((769 * 3.0) ** 2 / 1e6, 2),
            "generate_769_s": round(float(np.median(t_gen)), 3),
            "generate_769_cpu_s": round(float(np.median(c_gen)), 3),
            "raster_to_graph_769_s": round(float(np.median(t_rg)), 3),
            "raster_to_graph_769_cpu_s": round(float(np.median(c_rg)), 3),
            "raster_to_graph_steps_s": stats["seconds"],
            "synthesis_4km2_s": round(t_total, 2),
            "synthesis_s_per_km2": round(t_total / 4.0, 3),
            "synthesis_edges": int(len(res.geometry))}


def picture(figures: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(figures)
    fig, axes = plt.subplots(n, 3, figsize=(12, 4.2 * n), squeeze=False)
    for row, (name, f) in zip(axes, figures.items()):
        x0, y0, x1, y1 = f["target"].bounds
        for ax, lines, title in ((row[0], f["real"], f"training network: {f['title']}"),
                                 (row[2], f["sample"].geometry, "StreetGAN graph (seed 1)")):
            for g in shapely.get_parts(np.asarray(lines, dtype=object)):
                c = shapely.get_coordinates(g)
                ax.plot(c[:, 0], c[:, 1], color="k", lw=0.8)
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
            ax.set_title(title, fontsize=9)
        gt = f["sample"].geotransform
        img = f["sample"].image
        ext = (gt[0], gt[0] + img.shape[1] * gt[1], gt[3] + img.shape[0] * gt[5], gt[3])
        row[1].imshow(img, cmap="gray", extent=ext)
        row[1].set_xlim(x0, x1)
        row[1].set_ylim(y0, y1)
        row[1].set_title(f"generator image ({name}, seed 1)", fontsize=9)
        for ax in row:
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


def held_out_picture(figures: dict, path: Path) -> None:
    """Per held-out town: the real streets | the model's network (given roads in red).
    Data (c) OpenStreetMap contributors, ODbL."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(figures)
    if not n:
        return
    fig, axes = plt.subplots(n, 2, figsize=(9, 4.5 * n), squeeze=False)
    for row, (key, f) in zip(axes, figures.items()):
        res = f["sample"]
        for ax, lines, title in ((row[0], f["real"], f"{f['title']}: real streets"),
                                 (row[1], res.geometry[~res.given],
                                  f"{f['title']}: {key.split(':')[0]} (seed 1, never seen)")):
            for g in shapely.get_parts(np.asarray(lines, dtype=object)):
                c = shapely.get_coordinates(g)
                ax.plot(c[:, 0], c[:, 1], color="k", lw=0.7)
            for g in f["given"]:
                c = shapely.get_coordinates(g)
                ax.plot(c[:, 0], c[:, 1], color="r", lw=1.4)
            c = shapely.get_coordinates(f["area"].exterior)
            ax.plot(c[:, 0], c[:, 1], color="0.6", lw=0.6, ls="--")
            ax.set_title(title, fontsize=9)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
    fig.text(0.01, 0.003, "Data (c) OpenStreetMap contributors, ODbL", fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cards", action="store_true", help="store the evaluation in the model cards")
    args = ap.parse_args()
    models = streetgan.shipped_models()
    figures, evidence, perf, held, held_figures = {}, [], [], [], {}
    for name in models:
        card = streetgan.load_model(name).card
        if card.get("training_data", {}).get("held_out"):
            held.append(evaluate_held_out(name, held_figures))
        else:
            evidence.append(evaluate_model(name, figures))
        perf.append(performance(name))
    ceiling = representation_ceiling()
    cols = ("networks", "blocks", "area_w", "area_ks", "compactness_w", "compactness_ks",
            "aspect_ratio_w", "aspect_ratio_ks", "dead_ends_per_km2", "dead_end_ratio")
    for ev in evidence:
        print(f"\n{ev['model']} ({ev['title']}), window {ev['window_km2']} km², seeds {ev['seeds']}")
        print(f"{'network':40s} " + " ".join(f"{c[:14]:>14s}" for c in cols))
        for label, row in ev["rows"].items():
            print(f"{label:40s} " + " ".join(f"{row.get(c, ''):>14}" for c in cols))
    for ev in held:
        print(f"\n{ev['model']} ({ev['title']}) on {ev['against']}, seeds {ev['seeds']}")
        for town, t in ev["towns"].items():
            print(f"  {town} ({t['area_km2']} km²)")
            print(f"    {'statistic':22s} {'real':>10s} " + " ".join(
                f"{lab[:24]:>24s}" for lab in t["rows"]))
            for i, stat in enumerate(ev["statistics"]):
                print(f"    {stat:22s} {t['real'][i]:10.4g} " + " ".join(
                    f"{r['values'][i]:11.4g} ({r['relative_errors'][i]:5.2f})    "
                    for r in t["rows"].values()))
            for lab, r in t["rows"].items():
                print(f"    {lab}: median relative error {r['median_relative_error']:.3f}; "
                      f"invariant violations {r['violations']}, floating pieces "
                      f"{r['floating_pieces']}")
    print(f"\nthe representation alone: real streets rasterised and read back "
          f"({', '.join(ceiling['towns'])}), median relative error / blocks per km² "
          "(real, read back)")
    for label, row in ceiling["rows"].items():
        print(f"  {label:50s} {row['median_relative_error']}  "
              f"{row['blocks_per_km2_real_and_read_back']}")
    print("\nperformance (2-core CPU, onnxruntime)     thesis (Titan X / 1 core)")
    for p in perf:
        print(f"{p['model']:22s} generate 769x769 {p['generate_769_s']:.3f} s wall, "
              f"{p['generate_769_cpu_s']:.3f} s CPU (thesis {THESIS['generate_769_s']} s); "
              f"raster->graph {p['raster_to_graph_769_s']:.3f} s wall, "
              f"{p['raster_to_graph_769_cpu_s']:.3f} s CPU (thesis "
              f"{THESIS['raster_to_graph_s']} s); synthesis {p['synthesis_s_per_km2']:.3f} s/km²")
    load = os.getloadavg()
    print(f"(load average {load[0]:.1f} on {os.cpu_count()} cores while measuring: the machine "
          "is shared, so these are upper bounds)")
    out = {"machine": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
           "load_average": [round(x, 2) for x in load], "thesis": THESIS,
           "evidence": evidence, "held_out": held, "representation_ceiling": ceiling,
           "performance": perf}
    res_dir = ROOT / "tests" / "benchmarks" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    (res_dir / "gan.json").write_text(json.dumps(out, indent=1))
    picture(figures, ROOT / "docs" / "streetgan.png")
    held_out_picture(held_figures, ROOT / "docs" / "streetgan_towns.png")
    if args.cards:
        by_model = {p["model"]: p for p in perf}
        for ev in evidence:
            path = streetgan.MODELS_DIR / f"{ev['model']}.json"
            card = json.loads(path.read_text())
            card["evaluation"] = {"against": "the training network, same window", **ev,
                                  "performance": by_model[ev["model"]]}
            path.write_text(json.dumps(card, indent=1))
        for ev in held:
            path = streetgan.MODELS_DIR / f"{ev['model']}.json"
            card = json.loads(path.read_text())
            card["evaluation"] = {**ev, "performance": by_model[ev["model"]]}
            path.write_text(json.dumps(card, indent=1))
    print(f"\nwrote {res_dir / 'gan.json'}, docs/streetgan.png and docs/streetgan_towns.png")


if __name__ == "__main__":
    main()
