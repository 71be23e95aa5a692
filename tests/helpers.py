"""Shared test helpers (plain functions, importable from any test module)."""
from functools import lru_cache

import numpy as np
import shapely
from scipy.spatial import cKDTree

from conftest import BUBENEC, HELSINKI, LIECHTENSTEIN, ROOT


@lru_cache(maxsize=1)
def _helsinki_lines():
    import pyogrio

    return pyogrio.read_dataframe(HELSINKI, layer="lines")


def helsinki_roads(crs=32635):
    """Drivable Helsinki roads in UTM 35N with a vertical layer column ``z``."""
    return _drivable(_helsinki_lines(), crs)


@lru_cache(maxsize=1)
def liechtenstein_roads(crs=32632):
    """Drivable roads of the Liechtenstein extract in UTM 32N with a vertical layer ``z``."""
    import pyogrio
    import pytest

    if not LIECHTENSTEIN.exists():
        pytest.skip(f"{LIECHTENSTEIN} is not there (see DESIGN.md, real example data)")
    return _drivable(pyogrio.read_dataframe(LIECHTENSTEIN, layer="lines",
                                            columns=["highway", "name", "other_tags"]), crs)


def _drivable(df, crs):
    """The drivable OSM lines of ``df`` in ``crs``, with their vertical layer ``z``."""
    from urban_synthesis.plugin.network import street_graph as roads

    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(crs).reset_index(drop=True)
    tags = [roads.parse_other_tags(t) for t in df.other_tags]
    df["z"] = [roads.vertical_layer(t.get("layer"), t.get("bridge"), t.get("tunnel")) for t in tags]
    return df


def bubenec(layer, crs=32633):
    import pyogrio

    return pyogrio.read_dataframe(BUBENEC, layer=layer).to_crs(crs)


@lru_cache(maxsize=1)
def _liechtenstein(crs=32632):
    """Municipalities (admin_level 8), drivable street graph and its blocks (UTM 32N)."""
    import pyogrio
    import pytest

    from urban_synthesis.plugin.network import blocks
    from urban_synthesis.plugin.network import street_graph as roads

    if not LIECHTENSTEIN.exists():
        pytest.skip(f"{LIECHTENSTEIN} is not there (see DESIGN.md, real example data)")
    towns = pyogrio.read_dataframe(LIECHTENSTEIN, layer="multipolygons",
                                   columns=["name", "admin_level"])
    towns = towns[towns.admin_level == "8"].to_crs(crs)
    lines = pyogrio.read_dataframe(LIECHTENSTEIN, layer="lines", columns=["highway"])
    lines = lines[lines.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(crs)
    graph = roads.clean_network(lines.geometry.values, lines.highway.values,
                                merge_degree2=False)
    extraction = blocks.extract_blocks(graph)
    return dict(zip(towns.name, towns.geometry.values)), graph.geometry, extraction.geometry


def liechtenstein_towns():
    """Names of Liechtenstein's eleven municipalities (OSM admin_level 8), sorted."""
    return sorted(_liechtenstein()[0])


def liechtenstein_town_blocks(name):
    """(streets, blocks) of one municipality: the blocks of the whole country's drivable
    OSM streets (network engine) whose inner point lies in it, and all the streets."""
    towns, streets, faces = _liechtenstein()
    inside = shapely.within(shapely.point_on_surface(faces), towns[name])
    return streets, faces[inside]


def nearly_coincident_streets():
    """Three streets that run within micrometres of each other: GEOS 3.11's floating-point
    noding of them fails ("noding failed to converge"), so every noding must fall back."""
    return [shapely.LineString(c) for c in (
        [(77.00735619262085, 57.556184583855725), (44.38386934590856, 30.78118255017394),
         (43.32301592517176, 29.87454805888664), (24.19750630645411, 15.707296558780584)],
        [(51.08000511538115, 36.50388428363308), (39.97507855416211, 27.01330872721192),
         (34.70993543433117, 23.609118397186904)],
        [(60.17810317831416, 35.52856130893541), (46.00965723295924, 32.17062557992293),
         (26.786254673586992, 15.741777227304771)])]


def assert_planar(lines, z_layer=None, tol=1e-6):
    """No two edges of the same vertical layer meet except at shared end points."""
    lines = np.asarray(lines, dtype=object)
    z = np.zeros(len(lines), dtype=int) if z_layer is None else np.asarray(z_layer)
    tree = shapely.STRtree(lines)
    a, b = tree.query(lines, predicate="intersects")
    sel = (a < b) & (z[a] == z[b])
    a, b = a[sel], b[sel]
    # end points, not boundaries: a closed line (a loop) has an empty boundary, and two
    # loops at one node met away from a node for this check
    ends = shapely.multipoints(np.stack([shapely.get_point(lines[a], 0), shapely.get_point(
        lines[a], -1), shapely.get_point(lines[b], 0), shapely.get_point(lines[b], -1)], axis=1)) \
        if len(a) else []
    inter = shapely.intersection(lines[a], lines[b])
    # the intersection of two edges must be a subset of their end points
    bad = ~shapely.covers(shapely.buffer(ends, tol), inter) if len(a) else np.zeros(0, bool)
    assert not bad.any(), f"{int(bad.sum())} pairs of edges cross or overlap away from a node"


def _ends_beside(lines, reach):
    """(ends, owner, e, l): the lines' end points, the line of each, and the pairs of an end
    ``e`` within ``reach`` m of another line ``l``."""
    ends = np.concatenate([shapely.get_point(lines, 0), shapely.get_point(lines, -1)])
    owner = np.r_[np.arange(len(lines)), np.arange(len(lines))]
    e, l = shapely.STRtree(lines).query(ends, predicate="dwithin", distance=reach)
    other = owner[e] != l
    return ends, owner, e[other], l[other]


def assert_no_gaps(lines, reach=0.5, of=None):
    """No dangle beside a line: a line end that touches no other line (to round-off, 1e-9
    m) lies no nearer than ``reach`` m to one. A gap under the invariants' snap tolerance
    counts as a junction for them, but a GIS network tool sees a dangle there. ``of`` (a
    mask): only these lines' ends (the synthesised streets among given roads, whose OSM data
    has gaps of its own)."""
    lines = np.asarray(lines, dtype=object)
    ends, owner, e, l = _ends_beside(lines, reach)
    d = shapely.distance(ends[e], lines[l])
    touching = np.zeros(len(ends), bool)
    touching[e[d <= 1e-9]] = True
    dangle = ~touching[e] & (d > 1e-9)
    if of is not None:
        dangle &= np.asarray(of, dtype=bool)[owner[e]]
    assert not dangle.any(), \
        f"{len(np.unique(e[dangle]))} line ends {d[dangle].min():.1e}-{d[dangle].max():.1e} " \
        "m beside a line they do not touch"


def assert_ends_meet_exactly(lines, reach=0.5, of=None):
    """Line ends within ``reach`` m of each other are one point to the last bit: no street
    ends a few decimetres (or 1e-9 m) from a junction or from another street's end, and no
    street of a few decimetres joins two junctions. The invariants merge such ends within
    their snap tolerance; a network tool without one reads a gap or a dangle there. ``of``
    (a mask): only pairs with one of these lines' ends (the OSM given roads have gaps of
    their own)."""
    lines = np.asarray(lines, dtype=object)
    n = len(lines)
    ends = shapely.get_coordinates(np.concatenate([shapely.get_point(lines, 0),
                                                   shapely.get_point(lines, -1)]))
    pairs = cKDTree(ends).query_pairs(reach, output_type="ndarray")
    apart = (ends[pairs[:, 0]] != ends[pairs[:, 1]]).any(axis=1) if len(pairs) else \
        np.zeros(0, bool)
    if of is not None and len(pairs):
        mine = np.r_[np.asarray(of, dtype=bool), np.asarray(of, dtype=bool)]
        apart &= mine[pairs[:, 0]] | mine[pairs[:, 1]]
    d = np.hypot(*(ends[pairs[apart, 0]] - ends[pairs[apart, 1]]).T) if apart.any() else []
    assert not apart.any(), f"{int(apart.sum())} pairs of line ends {min(d):.1e}-{max(d):.1e} " \
        f"m apart (of {n} lines)"


def assert_exact_junctions(lines):
    """Every line end on another line (within 1e-6 m) is a vertex of that line to the last
    bit: the network is noded exactly, as a tool that builds its graph from vertices (QGIS's
    network analysis with no topology tolerance) needs it."""
    lines = np.asarray(lines, dtype=object)
    ends, _, e, l = _ends_beside(lines, 1e-6)
    off = shapely.distance(ends[e], shapely.extract_unique_points(lines[l])) > 0.0
    assert not off.any(), f"{int(off.sum())} line ends on a line but at none of its vertices"


def layer_features(layer):
    """A QGIS layer's features as (rows: list of dicts with NULL as None, shapely geometries)."""
    from qgis.PyQt.QtCore import QVariant

    feats = list(layer.getFeatures())
    names = [f.name() for f in layer.fields()]
    rows = [{k: None if isinstance(v, QVariant) and v.isNull() else v
             for k, v in zip(names, f.attributes())} for f in feats]
    geoms = shapely.from_wkb([bytes(f.geometry().asWkb()) if f.hasGeometry() else None
                              for f in feats]) if feats else np.empty(0, dtype=object)
    return rows, geoms


def layer_rows(layer):
    """A QGIS layer's attribute rows (dicts, NULL as None)."""
    return layer_features(layer)[0]


def clipped_metrics(lines, area):
    """Layout metrics of the part of a network inside ``area`` (the same cut for an
    original, a synthesis and a baseline)."""
    from urban_synthesis.plugin.measure import metrics

    with np.errstate(invalid="ignore", divide="ignore"):  # empty intersections outside
        parts = shapely.get_parts(shapely.intersection(np.asarray(lines, object), area))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)]
    return metrics.compute_layout_metrics(roads=parts)


def memory_layer(kind, wkts=(), crs="EPSG:3857", fields="", rows=None, name="test input"):
    """A QGIS memory layer of ``kind`` (Point, LineString, Polygon) from WKT strings.

    ``fields`` in the memory provider's syntax (e.g. '&field=h:double'); ``rows`` one
    attribute list per geometry.
    """
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer

    layer = QgsVectorLayer(f"{kind}?crs={crs}{fields}", name, "memory")
    feats = []
    for i, wkt in enumerate(wkts):
        f = QgsFeature(layer.fields())
        f.setGeometry(QgsGeometry.fromWkt(wkt))
        if rows is not None:
            f.setAttributes(list(rows[i]))
        feats.append(f)
    layer.dataProvider().addFeatures(feats)
    return layer


def log_feedback():
    """A QgsProcessingFeedback that keeps what the algorithm says: ``messages`` (info),
    ``warnings`` (reportError / pushWarning)."""
    from qgis.core import QgsProcessingFeedback

    class Log(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.messages, self.warnings = [], []

        def pushInfo(self, info):  # noqa: N802
            self.messages.append(info)

        def pushWarning(self, warning):  # noqa: N802
            self.warnings.append(warning)

        def reportError(self, error, fatalError=False):  # noqa: N802,N803
            self.warnings.append(error)

    return Log()


# ------------------------------------------------ evidence of the fragment synthesis (issue 3)

#: distributions compared in the style-transfer evidence -> column names
STYLE_MEASURES = {("roads", "segment_length"): "segment_length",
                  ("roads", "intersection_angle"): "intersection_angle",
                  ("blocks", "area"): "block_area", ("blocks", "compactness"): "block_compactness"}


def style_distances(m, example):
    """Normalised Wasserstein distance (W / the example's spread) per distribution of
    :data:`STYLE_MEASURES` and |difference| (nats) of the orientation entropy."""
    from urban_synthesis.plugin.measure import metrics

    d = {key: float(metrics.two_sample(m.distribution(kind, name),
                                       example.distribution(kind, name))["wasserstein_norm"])
         for (kind, name), key in STYLE_MEASURES.items()}
    d["orientation_entropy"] = float(abs(m.scalar("roads", "orientation_entropy")
                                         - example.scalar("roads", "orientation_entropy")))
    return d


def right_angle_share(m):
    """Share of intersection angles within 90 +- 10 degrees."""
    a = m.distribution("roads", "intersection_angle")
    return float(np.mean(np.abs(a - 90.0) <= 10.0))


def sketch_cells(cell=250.0, n=4, seed=0):
    """A noisy n x n grid of arterials ``cell`` m apart (faces both example databases have
    fragments of a similar size for)."""
    rng = np.random.default_rng(seed)
    out = []
    for x in np.arange(0, cell * n + 1, cell):
        ys = np.linspace(-30, cell * n + 30, 6)
        out.append(shapely.LineString([(x + rng.normal(0, 8), y) for y in ys]))
        out.append(shapely.LineString([(y, x + rng.normal(0, 8)) for y in ys]))
    return np.array(out, dtype=object)


def same_footprints(a, b, tol: float = 0.0):
    """None when two results hold the same footprints in the same order (WKB-equal, or
    coordinates within ``tol``) with the same attributes; else what differs (two
    ``footprints.FootprintResult``: the serial and the Dask run of tests/test_distributed.py)."""
    import pandas as pd

    if len(a.geometry) != len(b.geometry):
        return f"{len(a.geometry)} vs {len(b.geometry)} footprints"
    ga, gb = np.asarray(a.geometry, dtype=object), np.asarray(b.geometry, dtype=object)
    same = shapely.to_wkb(ga) == shapely.to_wkb(gb) if tol == 0 else \
        shapely.equals_exact(ga, gb, tolerance=tol)
    if not np.all(same):
        return f"{int((~np.asarray(same)).sum())} footprints differ in geometry"
    ta, tb = a.table.reset_index(drop=True), b.table.reset_index(drop=True)
    try:
        pd.testing.assert_frame_equal(ta, tb, check_dtype=False)
    except AssertionError as exc:
        return f"attributes differ: {exc}"
    return None


# ------------------------------------------ Liechtenstein towns (leave-one-town-out checks)

def liechtenstein_town(name):
    """A town of ``tools/liechtenstein.py`` as a leave-one-town-out case, in UTM 32N: dict
    with ``area`` (its outline), ``real`` (its drivable streets), ``given`` + ``given_class``
    (its level-0 roads, from the hierarchy of the whole country) and ``example`` +
    ``example_class`` (the streets of all other towns)."""
    import sys

    from conftest import ROOT

    if str(ROOT / "tools") not in sys.path:
        sys.path.insert(0, str(ROOT / "tools"))
    import liechtenstein

    return liechtenstein.leave_one_out(name)


def left_out_town(name):
    """A Liechtenstein town of the fidelity benchmark (``tests/towns.py``) and the other
    towns, its example: (town, others); the test is skipped without the OSM extract."""
    import pytest
    from towns import LI_PBF, liechtenstein_towns

    if not LI_PBF.exists():
        pytest.skip(f"{LI_PBF} is missing")
    towns = liechtenstein_towns()
    return next(t for t in towns if t.name == name), [t for t in towns if t.name != name]


def load_script(name: str):
    """A script of scripts/ (not a package) imported as a module."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def drawn_pentagon_template():
    """A drawn template: five lots round a private park (the paper's template with a
    park), in metres."""
    outer = np.array([(0, 0), (120, 0), (140, 70), (60, 120), (-20, 70)], dtype=float)
    inner = outer.mean(axis=0) + 0.35 * (outer - outer.mean(axis=0))
    lots = [shapely.Polygon([outer[i], outer[(i + 1) % 5], inner[(i + 1) % 5], inner[i]])
            for i in range(5)]
    geoms = lots + [shapely.Polygon(inner)]
    return shapely.Polygon(outer), geoms, ["R"] * 5 + ["P"]


def drawn_area_court_template():
    """A drawn template of two levels (Yang Fig. 4): a 140 x 110 m block with a straight
    10 m cul-de-sac from its south side, an area (label A) of 65 x 80 m on each side of it,
    to be filled by the next level's templates, and three lots across its end."""
    geoms = [shapely.box(65, 0, 75, 80), shapely.box(0, 0, 65, 80), shapely.box(75, 0, 140, 80),
             shapely.box(0, 80, 140 / 3, 110), shapely.box(140 / 3, 80, 280 / 3, 110),
             shapely.box(280 / 3, 80, 140, 110)]
    return shapely.box(0, 0, 140, 110), geoms, ["S", "A", "A", "R", "R", "R"]


def drawn_court_template():
    """A drawn template: a 120 x 90 m block with a bent cul-de-sac (8 m, a round turning
    head) from the middle of its south side, seven lots round it."""
    block = shapely.box(0, 0, 120, 90)
    axis = shapely.LineString([(60, 0), (60, 30), (70, 55)])
    street = shapely.intersection(shapely.union(shapely.buffer(axis, 4, cap_style="flat"),
                                                shapely.Point(70, 55).buffer(10)), block)
    rest = shapely.difference(block, street)
    cuts = [shapely.LineString([(30, -1), (30, 91)]), shapely.LineString([(90, -1), (90, 91)]),
            shapely.LineString([(-1, 45), (121, 45)])]
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.node(
        shapely.union_all([shapely.boundary(rest)] + cuts)))))
    lots = list(faces[shapely.within(shapely.point_on_surface(faces), rest)])
    return block, lots + [street], ["R"] * len(lots) + ["S"]
