"""Drawn templates warped as drawn (Yang et al. 2013, sec. 4; `templates.warp_drawn`).

Three templates drawn as an analyst would in QGIS (`tests/helpers.py`): a pentagon of five
lots round a private park, a court of seven lots round a bent cul-de-sac drawn as its
surface (label S), and a court whose two sides are areas (label A) for the next level's
templates; and the shipped spike and loop, drawn templates built at the default
parcel size (`templates.built_in_drawn`). Each is warped onto regions of its own shape
turned and stretched, onto a skewed one and onto one with an extra corner (a 40° bend),
and laid out by `split_domain` in a region it fits. Prints the warp energies (selection
threshold 0.1), lot counts, times (best of three, wall and CPU, on this shared 2-core
machine) and the lots' p_angle / p_area beside those of the mean value warp alone (no
regression rounds, in the same run), writes
``tests/benchmarks/results/drawn_templates.json`` and the picture
``docs/drawn_templates.png`` (template as drawn | laid out in a region).

    python tests/benchmarks/bench_drawn_templates.py
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import shapely
import shapely.geometry
from shapely import affinity

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT / "build" / "plugins", ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from helpers import (drawn_area_court_template, drawn_court_template,  # noqa: E402
                     drawn_pentagon_template)
from urban_synthesis.plugin.planned import domain_split, templates  # noqa: E402

RESULTS = ROOT / "tests" / "benchmarks" / "results" / "drawn_templates.json"
PICTURE = ROOT / "docs" / "drawn_templates.png"


def _best(fn, n=3):
    best = None
    for _ in range(n):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        w, c = time.perf_counter() - w, time.process_time() - c
        if best is None or w < best[0]:
            best = (w, c, out)
    return best


def _quality(res):
    """Mean p_angle (°) and p_area of a warp's lots, parks and areas left out."""
    from urban_synthesis.plugin.parcels import subdivision

    lots = res.lots[~res.green & ~res.area] if res.area is not None else res.lots[~res.green]
    p_angle, p_area, _ = subdivision.lot_quality(lots)
    return round(float(np.nanmean(p_angle)), 2), round(float(np.nanmean(p_area)), 4)


def _regions(outline):
    xy = np.asarray(shapely.geometry.polygon.orient(outline).exterior.coords)[:-1]
    d = xy[1] - xy[0]
    # the first side's middle pushed out by 18 % of its length: a bend of about 40°
    bent = np.insert(xy, 1, 0.5 * (xy[0] + xy[1]) + 0.18 * np.array([d[1], -d[0]]), axis=0)
    return {
        "turned 30°, stretched 1.1 x 0.95": affinity.rotate(affinity.scale(outline, 1.1, 0.95),
                                                             30),
        "skewed (x += 0.25 y)": affinity.skew(outline, xs=14.0),
        "a 40° bend in one side": shapely.Polygon(bent),
    }


def main():
    pentagon, p_geoms, p_labels = drawn_pentagon_template()
    block, c_geoms, c_labels = drawn_court_template()
    area_block, a_geoms, a_labels = drawn_area_court_template()
    drawn = [("pentagon with a private park", pentagon, p_geoms, p_labels),
             ("court with a bent cul-de-sac", block, c_geoms, c_labels),
             ("court with two areas (A)", area_block, a_geoms, a_labels)]
    # (name, template, its outline, the other templates split_domain may use)
    cases = [(name, templates.templates_from_drawn(g, [name] * len(g), lab)[0], outline,
              "rows") for name, outline, g, lab in drawn]
    library = templates.load_library()
    lib_rest = [t for t in library if t.kind in ("rows", "park")]
    settings = domain_split.SplitSettings()
    for t in library:
        if t.kind in ("spike", "loop"):
            built = templates.built_in_drawn(t, settings.parcel_length, settings.parcel_width,
                                             settings.street_width)
            # its lots, and the street around them: the region's outline
            outline = shapely.simplify(templates.drawn_outline(built), 1e-6)
            cases.append((f"shipped {t.name}", built, outline.buffer(
                settings.street_width / 2, join_style="mitre"), "park"))
    rows, layouts = [], []
    print(f"{'template':32s} {'region':34s} {'energy':>8s} {'lots':>5s} {'wall s':>8s} "
          f"{'CPU s':>7s} p_angle p_area (mean value warp alone)")
    for name, t, outline, others in cases:
        for region_name, region in _regions(outline).items():
            wall, cpu, res = _best(lambda: templates.warp_drawn(region, t))
            row = {"template": name, "region": region_name,
                   "energy": None if res is None else round(float(res.energy), 4),
                   "lots": 0 if res is None else int(len(res.lots)),
                   "parks": 0 if res is None else int(res.green.sum()),
                   "streets": 0 if res is None else len(res.roads),
                   "wall_s": round(wall, 4), "cpu_s": round(cpu, 4)}
            if res is not None:
                # the lots' quality (Yang's p_angle, p_area), and the same template warped
                # by mean value coordinates alone (no regression rounds), side by side
                row["p_angle"], row["p_area"] = _quality(res)
                kept, templates.WARP_ITERATIONS = templates.WARP_ITERATIONS, 0
                try:
                    row["p_angle_mean_value_only"], row["p_area_mean_value_only"] = \
                        _quality(templates.warp_drawn(region, t))
                finally:
                    templates.WARP_ITERATIONS = kept
            rows.append(row)
            print(f"{name:32s} {region_name:34s} "
                  f"{row['energy'] if row['energy'] is not None else '-':>8} {row['lots']:5d} "
                  f"{wall:8.3f} {cpu:7.3f} " + (
                      f"{row['p_angle']:6.2f}° {row['p_area']:.3f}  "
                      f"({row['p_angle_mean_value_only']:.2f}° "
                      f"{row['p_area_mean_value_only']:.3f})" if res is not None else ""))
        region = affinity.rotate(affinity.scale(outline, 1.12, 1.12), 20)
        rest = lib_rest if others == "rows" else [x for x in lib_rest if x.kind == "park"]
        wall, cpu, lay = _best(lambda: domain_split.split_domain(
            region, seed=1, templates=[t] + rest), n=1)
        tab = lay.table
        mine = tab.template == t.name
        layouts.append((name, t, region, lay))
        rows.append({"template": name, "region": "split_domain, template plus a street",
                     "lots": int(mine.sum()), "parks": int((tab.land_use[mine] == "park").sum()),
                     "street_access": bool(tab.has_street_access[tab.land_use == "residential"]
                                           .all()),
                     "road_kinds": sorted(set(np.asarray(lay.road_kind).tolist())),
                     "wall_s": round(wall, 3), "cpu_s": round(cpu, 3)})
        print(f"{name:32s} {'split_domain in a fitting region':34s} {'':>8s} "
              f"{int(mine.sum()):5d} {wall:8.3f} {cpu:7.3f}")
    RESULTS.write_text(json.dumps({"benchmark": "drawn_templates", "rows": rows}, indent=1))
    _draw(layouts)
    print(f"wrote {RESULTS} and {PICTURE}")


def _draw(layouts):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(layouts), figsize=(5 * len(layouts), 10))
    axes = axes.T.ravel()
    colour = {"R": "#f4d6a0", "P": "#9ccf8a", "S": "#bbbbbb", "A": "#c9d7f0"}
    for k, (name, t, region, lay) in enumerate(layouts):
        ax = axes[2 * k]
        for coords, lab in zip(t.parcels, t.parcel_labels):
            xy = np.asarray(coords)
            ax.fill(xy[:, 0], xy[:, 1], color=colour[lab], ec="k", lw=0.6)
        for line in t.streets:
            xy = np.asarray(line)
            ax.plot(xy[:, 0], xy[:, 1], "r-", lw=1.2)
        ax.set_title(f"{name}: as drawn", fontsize=9)
        ax = axes[2 * k + 1]
        use = lay.table.land_use.to_numpy()
        for poly, u in zip(lay.parcels, use):
            for part in shapely.get_parts(poly):
                xy = np.asarray(part.exterior.coords)
                ax.fill(xy[:, 0], xy[:, 1], color=colour["P" if u == "park" else "R"],
                        ec="k", lw=0.6)
        for line, kind in zip(lay.roads, lay.road_kind):
            xy = shapely.get_coordinates(line)
            ax.plot(xy[:, 0], xy[:, 1], "r-" if kind != "outline" else "k-", lw=1.2)
        ax.set_title("laid out in a region turned 20°, 12 % larger", fontsize=9)
        ax.plot(*np.asarray(region.exterior.coords).T, "k-", lw=1.2)
        for a in axes[2 * k:2 * k + 2]:
            a.set_aspect("equal")
            a.axis("off")
    fig.suptitle("Templates warped as drawn (splitdomain): three drawn in QGIS (TEMPLATE_LAYER) "
                 "and the shipped spike and loop; lots (sand), parks (green), areas for the next "
                 "level (blue, as drawn), the template's own streets (red)", fontsize=10)
    fig.tight_layout()
    fig.savefig(PICTURE, dpi=80)
    plt.close(fig)


if __name__ == "__main__":
    main()
