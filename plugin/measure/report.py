"""HTML report of layout metrics: a candidate layout against its example.

One self-contained HTML file (CSS inline, plots as base64 PNG): a table of the scalar
measures, a table of the two-sample distances of every distribution, and one histogram per
distribution with the example and the candidate overlaid on the same bins (shares, so that
layers of different sizes compare), plus orientation roses of the street bearings
(Boeing 2019, Fig. 2). The measures come from :mod:`plugin.measure.metrics`.

Plots are drawn with matplotlib's Agg canvas on ``matplotlib.figure.Figure`` objects, never
through pyplot: no GUI backend is loaded and the global backend of the host (QGIS uses Qt)
is left untouched.
"""
from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import math
import warnings
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely

from ..core.progress import Progress, ensure
from ..network.invariants import CHECKS, DEAD_END_TOLERANCE
from .metrics import SETTLED_SHARE_LOW, Distribution, MetricsResult, compare

__all__ = ["render_report", "write_report", "histogram_png", "rose_png", "map_png",
           "summary_html"]

EXAMPLE_COLOR = "#3b6fb6"
CANDIDATE_COLOR = "#e07b39"
#: Scalars that docs/ARCHITECTURE.md requires to be 0 in a synthesis: flagged when they are not.
MUST_BE_ZERO = {("buildings", "overlap_area"), ("buildings", "overlapping_pairs"),
                ("buildings", "outside_blocks"), ("buildings", "road_overlap_area"),
                ("buildings", "road_overlap_count"), ("invariants", "violations")} | {
    ("invariants", name) for name, _, is_violation in CHECKS
    if is_violation and name != "dead_end_share"}
#: Scalars flagged when they differ from the example's by more than this share.
NEAR_EXAMPLE = {("invariants", "dead_end_share"): DEAD_END_TOLERANCE}
_KIND_TITLES = {"layout": "Layout", "invariants": "Network invariants", "roads": "Roads",
                "blocks": "Blocks", "parcels": "Parcels", "buildings": "Building footprints"}

_CSS = """
body { font-family: "Segoe UI", Helvetica, Arial, sans-serif; color: #222; margin: 2em auto;
       max-width: 1180px; padding: 0 1em; line-height: 1.4; }
h1 { font-weight: 600; margin-bottom: 0.1em; }
h2 { border-bottom: 2px solid #3b6fb6; padding-bottom: 0.2em; margin-top: 1.8em; }
h3 { margin: 1.2em 0 0.4em; color: #3b6fb6; }
.sub { color: #666; margin-top: 0; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.92em; }
th, td { padding: 0.3em 0.7em; border-bottom: 1px solid #ddd; text-align: right; }
th { background: #f2f5fa; text-align: center; }
td.name, th.name { text-align: left; }
td.warn { color: #b00020; font-weight: 600; }
tr:hover td { background: #fafbfd; }
.legend span { display: inline-block; width: 0.9em; height: 0.9em; margin: 0 0.3em -0.1em 1em; }
.grid.maps { grid-template-columns: repeat(auto-fill, minmax(360px, 1fr)); }
p.warn { color: #b00020; }
dt { font-weight: 600; margin-top: 0.5em; }
.grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(540px, 1fr)); gap: 1em; }
figure { margin: 0; border: 1px solid #e3e3e3; border-radius: 4px; padding: 0.4em;
         background: #fff; }
figure img { width: 100%; height: auto; }
figcaption { font-size: 0.85em; color: #555; padding: 0.2em 0.4em; }
.notes { font-size: 0.9em; color: #444; }
footer { margin-top: 3em; font-size: 0.8em; color: #888; }
"""


# --------------------------------------------------------------------------- formatting

def _fmt(value, digits: int = 4) -> str:
    if value is None:
        return "–"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return html.escape(str(value))
    if not math.isfinite(v):
        return "–"
    if v == int(v) and abs(v) < 1e9:
        return f"{int(v):,}".replace(",", "\u202f")
    return f"{v:.{digits}g}"


def _pct(value) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "–"
    return f"{100 * v:+.1f} %" if math.isfinite(v) else "–"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(width: float, height: float, layout: Optional[str] = None):
    # a bare Figure on an Agg canvas: pyplot (and with it a GUI backend) is never imported,
    # and matplotlib.use() is not called, since switching the global backend would close the
    # figures of anything else plotting in the same QGIS process
    with warnings.catch_warnings():
        # a Debian matplotlib next to the venv's makes mpl_toolkits warn; 3D is not used
        warnings.filterwarnings("ignore", message="Unable to import Axes3D")
        import matplotlib.projections  # noqa: F401
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


# --------------------------------------------------------------------------- plots

def _bins(dist_name: str, unit: str,
          values: Sequence[np.ndarray]) -> Tuple[np.ndarray, bool, Optional[float]]:
    """Common bins of all samples: integers for degrees, log bins for areas spanning decades.

    Returns (edges, log_x, clip) where ``clip`` is the upper value beyond which outliers
    are gathered into the last bin (None when nothing is clipped).
    """
    present = [v for v in values if len(v)]
    allv = np.concatenate(present) if present else np.zeros(1)
    lo, hi = float(np.min(allv)), float(np.max(allv))
    if dist_name == "node_degree":
        return np.arange(math.floor(lo) - 0.5, math.ceil(hi) + 1.5, 1.0), False, None
    if unit == "°":
        top = 90.0 if hi <= 90.0 else 180.0 if hi <= 180.0 else 360.0
        return np.linspace(0.0, top, 37), False, None
    positive = allv[allv > 0]
    if unit == "m²" and len(positive) and positive.max() / positive.min() > 100:
        edges = np.logspace(np.log10(positive.min()), np.log10(positive.max()), 31)
        return edges, True, None
    clip = None
    if len(allv) > 20:
        q = float(np.quantile(allv, 0.99))
        if q < hi and q > lo:
            clip, hi = q, q
    if hi <= lo:
        hi = lo + 1.0
    return np.linspace(lo, hi, 31), False, clip


def histogram_png(label: str, unit: str, candidate: Optional[np.ndarray],
                  example: Optional[np.ndarray], distances: Optional[Dict] = None,
                  name: str = "") -> str:
    """Overlaid histograms (shares per bin) of a candidate and an example sample, as base64 PNG."""
    samples = [(example, "Example", EXAMPLE_COLOR), (candidate, "Candidate", CANDIDATE_COLOR)]
    samples = [(np.asarray(v, float), t, c) for v, t, c in samples if v is not None and len(v)]
    fig = _figure(5.6, 3.5)
    fig.subplots_adjust(left=0.13, right=0.97, bottom=0.14, top=0.84)
    ax = fig.add_subplot()
    if not samples:
        ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
        return _png(fig)
    edges, log_x, clip = _bins(name, unit, [v for v, _, _ in samples])
    for values, title, color in samples:
        clipped = clip is not None or name == "node_degree"
        v = np.clip(values, edges[0], edges[-1]) if clipped else values
        share = np.histogram(v, bins=edges)[0] / len(v)
        # stairs draw one artist per sample, much faster than hist's one patch per bar
        ax.stairs(share, edges, fill=True, color=color, alpha=0.35)
        ax.stairs(share, edges, color=color, linewidth=1.6, label=f"{title} (n = {len(values):,})")
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(f"{label} ({unit})" if unit else label)
    ax.set_ylabel("Share per bin")
    fig.suptitle(label, fontsize=11, fontweight="bold", y=0.97)
    if distances and np.isfinite(distances.get("wasserstein", np.nan)):
        d = {k: _fmt(v, 3) for k, v in distances.items()}
        w_unit = f" {unit}" if unit else ""
        ax.set_title(f"Wasserstein {d['wasserstein']}{w_unit}  ·  W/σ {d['wasserstein_norm']}  ·  "
                     f"KS D {d['ks_stat']} (p = {_fmt(distances['ks_pvalue'], 2)})",
                     fontsize=8, color="#444")
    ax.grid(alpha=0.25)
    ax.legend(fontsize=8, frameon=False, loc="upper right")
    if clip is not None:
        ax.text(0.01, 0.98, f"values > {_fmt(clip, 3)} in the last bin", transform=ax.transAxes,
                ha="left", va="top", fontsize=7, color="#666")
    return _png(fig)


def rose_png(candidate: Optional[np.ndarray], example: Optional[np.ndarray]) -> str:
    """Orientation roses (36 bins, both directions, as OSMnx) of example and candidate (PNG)."""
    samples = [(example, "Example", EXAMPLE_COLOR), (candidate, "Candidate", CANDIDATE_COLOR)]
    samples = [(np.asarray(v, float), t, c) for v, t, c in samples if v is not None and len(v)]
    fig = _figure(2.9 * max(len(samples), 1) + 0.4, 3.3, layout="tight")
    width = 2 * np.pi / 36
    for k, (values, title, color) in enumerate(samples):
        ax = fig.add_subplot(1, len(samples), k + 1, projection="polar")
        both = np.concatenate([values % 360.0, (values + 180.0) % 360.0])
        counts = np.bincount((np.floor(((both + 5.0) % 360.0) / 10.0).astype(int)) % 36,
                             minlength=36)
        share = counts / counts.sum()
        ax.set_theta_zero_location("N")
        ax.set_theta_direction("clockwise")
        ax.bar(np.arange(36) * width, share, width=width, color=color, alpha=0.8,
               edgecolor="white", linewidth=0.5)
        ax.set_yticklabels([])
        ax.set_xticks(np.radians([0, 90, 180, 270]))
        ax.set_xticklabels(["N", "E", "S", "W"])
        ax.set_title(title, fontsize=10, fontweight="bold")
    return _png(fig)


def map_png(layers: Dict[str, np.ndarray], title: str, extent=None) -> str:
    """A thumbnail map of one layout (metric CRS): blocks, parcels, buildings, roads; a
    100 m / 500 m scale bar. ``extent`` (x0, y0, x1, y1) frames it, else its own bounds."""
    from matplotlib.collections import LineCollection, PolyCollection

    fig = _figure(4.2, 4.2)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.02, top=0.9)
    ax = fig.add_subplot()
    styles = {"blocks": ("#f2efe9", "#c8c2b6"), "parcels": ("none", "#d9a066"),
              "buildings": ("#5a6b84", "#3b475a")}
    for name, (face, edge) in styles.items():
        geoms = layers.get(name)
        if geoms is None or not len(geoms):
            continue
        rings = shapely.get_exterior_ring(shapely.get_parts(np.asarray(geoms, dtype=object)))
        rings = rings[~shapely.is_missing(rings)]
        polys = [shapely.get_coordinates(r) for r in rings]
        ax.add_collection(PolyCollection(polys, facecolors=face, edgecolors=edge,
                                         linewidths=0.3))
    roads = layers.get("roads")
    if roads is not None and len(roads):
        parts = shapely.get_parts(np.asarray(roads, dtype=object))
        ax.add_collection(LineCollection([shapely.get_coordinates(g) for g in parts],
                                         colors="#333333", linewidths=0.6))
    every = [np.asarray(g, dtype=object) for g in layers.values() if g is not None and len(g)]
    if extent is None and every:
        extent = shapely.total_bounds(np.concatenate(every))
    if extent is not None and np.isfinite(extent).all():
        x0, y0, x1, y1 = extent
        side = max(x1 - x0, y1 - y0, 1.0)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        ax.set_xlim(cx - side / 2, cx + side / 2)
        ax.set_ylim(cy - side / 2, cy + side / 2)
        bar = 500.0 if side > 2500 else 100.0
        bx, by = cx - side / 2 + 0.05 * side, cy - side / 2 + 0.05 * side
        ax.plot([bx, bx + bar], [by, by], color="black", linewidth=2)
        ax.text(bx + bar / 2, by + 0.015 * side, f"{bar:g} m", ha="center", fontsize=8)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title, fontsize=11, fontweight="bold")
    return _png(fig)


#: The measures of the plain-language summary: (kind, metric, a scalar?) -> what it says
#: to a planner.
SUMMARY_MEASURES = {
    ("roads", "street_length_km_per_km2", True): "street length per km² (how much street "
                                                 "there is)",
    ("roads", "intersections_per_km2", True): "junctions per km²",
    ("roads", "dead_end_share", True): "share of street ends that are dead ends",
    ("roads", "degree4_share", True): "share of four-way crossings",
    ("roads", "orientation_order", True): "how grid-like the streets are",
    ("blocks", "blocks_per_km2", True): "city blocks per km²",
    ("blocks", "land_share", True): "share of the area in city blocks (how much of it "
                                    "streets close)",
    ("blocks", "area", False): "block sizes",
    ("roads", "segment_length", False): "lengths of streets between junctions",
    ("parcels", "p_n_per_km2", True): "parcels per km²",
    ("parcels", "area", False): "parcel sizes",
    ("buildings", "per_km2", True): "buildings per km²",
    ("buildings", "coverage", True): "share of block land covered by buildings",
    ("buildings", "area", False): "building footprint sizes",
}
#: |relative difference| up to which a value "matches" the example, and "is close"
MATCH, CLOSE = 0.10, 0.30
#: W / sigma up to which two distributions are "alike", "fairly alike"
ALIKE, FAIRLY_ALIKE = 0.25, 0.6


def _judge(row) -> Tuple[str, bool, float]:
    """(sentence fragment, matches the example, size of the difference) of one comparison
    row: scalars by their relative difference, distributions by W / sigma."""
    if row.statistic == "value":
        rel = float(row.rel_diff)
        direction = "more" if rel > 0 else "less"
        if abs(rel) <= MATCH:
            return "about the same as the example", True, abs(rel)
        word = "somewhat" if abs(rel) <= CLOSE else "much"
        return (f"{word} {direction} than the example ({abs(rel) * 100:.0f} % {direction})",
                False, abs(rel))
    wn = float(row.wasserstein_norm)
    if wn <= ALIKE:
        return "distributed like the example's", True, wn
    if wn <= FAIRLY_ALIKE:
        return "fairly like the example's", False, wn
    ratio = row.candidate / row.example if row.example else np.nan
    trend = "" if not np.isfinite(ratio) else \
        (f" (on average {ratio:.1f}× the example's)" if ratio >= 1 else
         f" (on average {1 / ratio:.1f}× smaller than the example's)")
    return "unlike the example's" + trend, False, wn


def dead_end_breach(comparison: pd.DataFrame) -> Optional[str]:
    """The sentence on the layout's dead-end share when it lies beyond the invariants' band
    around the example's (:data:`NEAR_EXAMPLE`), else None: the one invariant that needs an
    example, so the violation count leaves it out and the summary and the log say it."""
    key = ("invariants", "dead_end_share")
    rows = comparison[(comparison.kind == key[0]) & (comparison.metric == key[1])
                      & (comparison.statistic == "value")]
    if rows.empty:
        return None
    r = rows.iloc[0]
    if not (np.isfinite(r.rel_diff) and abs(r.rel_diff) > NEAR_EXAMPLE[key]):
        return None
    return (f"its dead-end share {r.candidate:.2f} is {100 * abs(r.rel_diff):.0f} % "
            f"{'above' if r.rel_diff > 0 else 'below'} the example's {r.example:.2f}, beyond "
            f"the ±{100 * NEAR_EXAMPLE[key]:.0f} % the invariants allow")


def summary_html(comparison: pd.DataFrame, has_example: bool) -> str:
    """The plain-language summary: what matches the example, what does not, by how much,
    and whether the street network is sound (the invariants)."""
    rows = {(r.kind, r.metric, r.statistic == "value"): r
            for r in comparison.itertuples(index=False)}
    out = ["<h2>Summary</h2>"]
    inv = rows.get(("invariants", "violations", True))
    if inv is not None and np.isfinite(inv.candidate):
        breach = dead_end_breach(comparison) if has_example else None
        if inv.candidate == 0:
            out.append(("<p class='warn'>" if breach else "<p>")
                       + "The street network is sound: every crossing is a junction, it "
                       "is connected to the given roads, and no new street doubles one"
                       + (f"; but {html.escape(breach)}.</p>" if breach else ".</p>"))
        else:
            problems = [f"{_fmt(rows[('invariants', name, True)].candidate)} × "
                        f"{html.escape(label.lower())}"
                        for name, label, is_violation in CHECKS
                        if is_violation and name != "dead_end_share"
                        and ("invariants", name, True) in rows
                        and rows[("invariants", name, True)].candidate > 0]
            out.append("<p class='warn'><b>The street network has "
                       f"{_fmt(inv.candidate)} problems</b>: {'; '.join(problems)}.</p>")
            if breach:
                out.append(f"<p class='warn'>Also, {html.escape(breach)}.</p>")
    if not has_example:
        out.append("<p>No example was given: the tables below describe the layout alone.</p>")
        return "".join(out)
    settled = rows.get(("layout", "settled_share", True))
    sparse = [f"{who} settle only {share:.0%}" for who, share in
              (("the layout's streets", settled.candidate), ("the example's", settled.example))
              if np.isfinite(share) and share < SETTLED_SHARE_LOW] if settled else []
    if sparse:
        out.append("<p class='warn'><b>The figures per km² compare poorly</b>: "
                   f"{' and '.join(sparse)} of the area their densities are counted in; the "
                   "rest is empty land around them (a whole region's extract). Give a study "
                   "area for each side, such as the town's outline.</p>")
    good, bad = [], []
    for key, what in SUMMARY_MEASURES.items():
        row = rows.get(key)
        if row is None:
            continue
        scalar = key[2]
        if not np.isfinite(row.rel_diff if scalar else row.wasserstein_norm):
            continue
        verdict, matches, size = _judge(row)
        unit = f" {row.unit}" if row.unit else ""
        value = f": {_fmt(row.candidate, 3)}{unit} against {_fmt(row.example, 3)}{unit}" \
            if scalar else ""
        sentence = f"{what[0].upper() + what[1:]}: {verdict}{value}."
        (good if matches else bad).append((size, html.escape(sentence)))
    n = len(good) + len(bad)
    if n:
        out.append(f"<p>Of the {n} main measures, <b>{len(good)} match the example</b> "
                   f"(values within {MATCH * 100:.0f} %, distributions with W / σ under "
                   f"{ALIKE:g}) and <b>{len(bad)} differ</b>.</p>")
    if good:
        out.append("<h3>What matches the example</h3><ul>" + "".join(
            f"<li>{t}</li>" for _, t in sorted(good)) + "</ul>")
    if bad:
        out.append("<h3>What differs, largest differences first</h3><ul>" + "".join(
            f"<li>{t}</li>" for _, t in sorted(bad, reverse=True)) + "</ul>")
    return "".join(out)


GLOSSARY = """
<h2>How to read the numbers</h2>
<dl class='notes'>
<dt>km/km², 1/km²</dt><dd>per square kilometre of the study area (or of the layout's own
extent): street kilometres, junctions, blocks, buildings.</dd>
<dt>Dead-end share, degree shares</dt><dd>of all street ends and junctions (nodes where
a street only bends are not counted): a dead end has one street, a T-junction three, a
crossing four.</dd>
<dt>Orientation entropy (nats) and order</dt><dd>how spread the street directions are
(Boeing 2019): entropy 1.39 nats for a perfect grid, 3.58 nats when every direction is
equally common; order φ rescales it to 1 for a perfect grid and 0 for no preferred
direction.</dd>
<dt>Street bearing</dt><dd>the direction of each street piece in degrees from north, the same
for both ways along it (0–180°); compared on the circle, so 5° and 175° are 10° apart; the
mean row gives the mean direction of each side and the turn between them.</dd>
<dt>Wasserstein distance (W) and W / σ</dt><dd>how far one distribution has to move to
become the other, in the measure's unit; W / σ divides by the example's spread: under 0.25
the two are alike, above 1 they are clearly different. For bearings, the distance on the
circle.</dd>
<dt>KS D and p</dt><dd>the largest gap between the two cumulative distributions (0 to 1) and
the chance of a gap that large between samples of one distribution; with thousands of
values even small differences get a small p, so read D and W / σ as the size of the
difference. For bearings, Kuiper's V, its version on the circle.</dd>
<dt>p_angle, p_area (parcels)</dt><dd>Yang et al. 2013: the mean deviation of a parcel's
corners from 90° and its area over that of its minimum bounding rectangle (1 = a rectangle);
a parcel is undesirable above 15° or 1.2.</dd>
<dt>Difference</dt><dd>(candidate − example) / |example|.</dd>
</dl>
"""


# --------------------------------------------------------------------------- html

def _scalar_table(rows: pd.DataFrame, has_example: bool, labels: Dict) -> str:
    head = ["<tr><th class='name'>Measure</th><th>Unit</th><th>Candidate</th>"]
    if has_example:
        head.append("<th>Example</th><th>Difference</th>")
    head.append("</tr>")
    body = []
    for r in rows.itertuples(index=False):
        key = (r.kind, r.metric)
        warn = key in MUST_BE_ZERO and np.isfinite(r.candidate) and r.candidate > 0
        warn |= bool(key in NEAR_EXAMPLE and np.isfinite(r.rel_diff)
                     and abs(r.rel_diff) > NEAR_EXAMPLE[key])
        cells = [f"<td class='name'>{html.escape(labels.get(key, r.metric))}"
                 f" <small>({html.escape(r.metric)})</small></td>",
                 f"<td>{html.escape(r.unit or '')}</td>",
                 f"<td class='{'warn' if warn else ''}'>{_fmt(r.candidate)}</td>"]
        if has_example:
            cells.append(f"<td>{_fmt(r.example)}</td><td>{_pct(r.rel_diff)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return "<table>" + "".join(head) + "".join(body) + "</table>"


def _distance_table(rows: pd.DataFrame, has_example: bool, labels: Dict) -> str:
    head = "<tr><th class='name'>Distribution</th><th>Unit</th><th>n cand.</th><th>mean cand.</th>"
    if has_example:
        head += ("<th>n ex.</th><th>mean ex.</th><th>Wasserstein</th><th>W / σ<sub>ex</sub></th>"
                 "<th>KS D</th><th>KS p</th>")
    head += "</tr>"
    body = []
    for r in rows.itertuples(index=False):
        cells = [f"<td class='name'>{html.escape(labels.get((r.kind, r.metric), r.metric))}"
                 f" <small>({html.escape(r.metric)})</small></td>",
                 f"<td>{html.escape(r.unit or '')}</td>", f"<td>{_fmt(r.n_candidate)}</td>",
                 f"<td>{_fmt(r.candidate)}</td>"]
        if has_example:
            cells += [f"<td>{_fmt(r.n_example)}</td>", f"<td>{_fmt(r.example)}</td>",
                      f"<td>{_fmt(r.wasserstein)}</td>", f"<td>{_fmt(r.wasserstein_norm, 3)}</td>",
                      f"<td>{_fmt(r.ks_stat, 3)}</td>", f"<td>{_fmt(r.ks_pvalue, 3)}</td>"]
        body.append("<tr>" + "".join(cells) + "</tr>")
    return "<table>" + head + "".join(body) + "</table>"


def _find(result: Optional[MetricsResult], kind: str, name: str) -> Optional[Distribution]:
    if result is None:
        return None
    return next((d for d in result.distributions if d.kind == kind and d.name == name), None)


def render_report(candidate: MetricsResult, example: Optional[MetricsResult] = None,
                  comparison: Optional[pd.DataFrame] = None, title: str = "Layout metrics",
                  meta: Optional[Dict[str, str]] = None,
                  progress: Optional[Progress] = None,
                  maps: Optional[Dict[str, Dict[str, np.ndarray]]] = None) -> str:
    """The HTML report as a string.

    Parameters
    ----------
    candidate : MetricsResult
        Measures of the layout under test.
    example : MetricsResult, optional
        Measures of its example; without one the report describes the candidate alone.
    comparison : DataFrame, optional
        ``metrics.compare(candidate, example)``; computed when not given.
    title : str
    meta : dict, optional
        Lines for the header table (input layers, CRS, parameters).
    progress : Progress, optional
        Stepped once per plot (raises ``Canceled`` when the user cancels).
    maps : dict, optional
        ``{"Candidate": layers, "Example": layers}``, layers a dict of geometry arrays
        (roads, blocks, parcels, buildings) in a metric CRS: thumbnail maps side by side,
        each framed on its own extent at its own scale (with a scale bar).
    """
    progress = ensure(progress)
    has_example = example is not None
    if comparison is None:
        comparison = compare(candidate, example)
    labels = {}
    for side in (example, candidate):
        if side is not None:
            for m in side.scalars + side.distributions:
                labels[(m.kind, m.name)] = m.label
    out: List[str] = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p class='sub'>Urban Synthesis · layout metrics · generated "
        f"{_dt.datetime.now().strftime('%Y-%m-%d %H:%M')}</p>",
    ]
    out.append(summary_html(comparison, has_example))
    if maps:
        thumbs = [f"<figure><img alt='{html.escape(name)} map' src='data:image/png;base64,"
                  f"{map_png(layers, name)}'><figcaption>{html.escape(name)}: roads, blocks, "
                  "parcels and buildings.</figcaption></figure>"
                  for name, layers in maps.items() if layers]
        out.append("<div class='grid maps'>" + "".join(thumbs) + "</div>")
    out.append("<h2>Inputs</h2>")
    if meta:
        out.append("<table>" + "".join(
            f"<tr><td class='name'><b>{html.escape(str(k))}</b></td>"
            f"<td class='name'>{html.escape(str(v))}</td></tr>" for k, v in meta.items())
                   + "</table>")
    if has_example:
        out.append("<p class='legend'>Colours:"
                   f"<span style='background:{EXAMPLE_COLOR}'></span>example"
                   f"<span style='background:{CANDIDATE_COLOR}'></span>candidate. "
                   "Wasserstein: earth mover's distance in the unit of the measure; W / σ: the "
                   "same divided by the example's standard deviation; KS: two-sample "
                   "Kolmogorov–Smirnov statistic D and its p-value (a small p says the samples "
                   "differ; with thousands of values even small differences are significant, "
                   "so read D and W / σ as effect sizes). Difference: (candidate − example) / "
                   "|example|.</p>")
    notes = [("Candidate", candidate.notes)] + ([("Example", example.notes)] if has_example else [])
    if any(n for _, n in notes):
        out.append("<div class='notes'><b>Notes</b><ul>" + "".join(
            f"<li>{who}: {html.escape(n)}</li>" for who, ns in notes for n in ns) + "</ul></div>")

    kinds = [k for k in dict.fromkeys(comparison["kind"])]
    is_dist = comparison["statistic"] != "value"
    dist_rows = comparison[is_dist]
    n_plots = max(1, len(dist_rows) + int(any(dist_rows["metric"] == "street_bearing")))
    done = 0
    for kind in kinds:
        rows = comparison[comparison["kind"] == kind]
        out.append(f"<h2>{html.escape(_KIND_TITLES.get(kind, kind.title()))}</h2>")
        scal = rows[rows["statistic"] == "value"]
        if len(scal):
            out.append("<h3>Measures</h3>" + _scalar_table(scal, has_example, labels))
        dist = rows[rows["statistic"] != "value"]
        if not len(dist):
            continue
        out.append("<h3>Distributions</h3>" + _distance_table(dist, has_example, labels))
        figures = []
        for r in dist.itertuples(index=False):
            c = _find(candidate, kind, r.metric)
            e = _find(example, kind, r.metric)
            distances = {k: getattr(r, k) for k in ("wasserstein", "wasserstein_norm",
                                                     "ks_stat", "ks_pvalue")}
            label = labels.get((kind, r.metric), r.metric)
            png = histogram_png(label, r.unit or "", None if c is None else c.values,
                                None if e is None else e.values, distances, r.metric)
            figures.append(f"<figure><img alt='{html.escape(label)} histogram' "
                           f"src='data:image/png;base64,{png}'><figcaption>"
                           f"{html.escape(label)}: share of elements per bin."
                           "</figcaption></figure>")
            done += 1
            progress.step(done / n_plots)
            if r.metric == "street_bearing":
                png = rose_png(None if c is None else c.values, None if e is None else e.values)
                figures.append("<figure><img alt='street orientation roses' "
                               f"src='data:image/png;base64,{png}'><figcaption>Street "
                               "orientation (share of street length per 10° bin, both "
                               "directions).</figcaption></figure>")
                done += 1
                progress.step(done / n_plots)
        out.append("<div class='grid'>" + "".join(figures) + "</div>")
    out.append(GLOSSARY)
    out.append("<footer>Measures: docs/ARCHITECTURE.md “Quality measures” (network "
               "invariants: every crossing a junction, connected to the given roads, no street in a given "
               "road's corridor, motorways met only at their junctions); Yang et al. 2013, Table 1 "
               "(p_angle, p_area, b_n, b_max/b_avg/b_min, s_l, s_i, s_d); Hartmann thesis ch. 4.2 "
               "(block area, compactness, aspect ratio); Boeing 2019 (orientation entropy)."
               "</footer></body></html>")
    progress.step(1.0)
    return "\n".join(out)


def write_report(path, candidate: MetricsResult, example: Optional[MetricsResult] = None,
                 comparison: Optional[pd.DataFrame] = None, title: str = "Layout metrics",
                 meta: Optional[Dict[str, str]] = None,
                 progress: Optional[Progress] = None,
                 maps: Optional[Dict[str, Dict[str, np.ndarray]]] = None) -> str:
    """Write :func:`render_report` to ``path`` (UTF-8) and return the path."""
    text = render_report(candidate, example, comparison, title, meta, progress, maps)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return str(path)
