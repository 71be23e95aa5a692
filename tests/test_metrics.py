"""Engine tests of plugin.measure.metrics and plugin.measure.report (no QGIS)."""
import math

import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.measure import metrics as M
from urban_synthesis.plugin.measure import report as R
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress


def grid(n=4, spacing=100.0, overhang=0.0):
    """n horizontal and n vertical streets: (n-1)^2 square blocks."""
    end = (n - 1) * spacing
    h = [shapely.LineString([(-overhang, y), (end + overhang, y)]) for y in np.arange(n) * spacing]
    v = [shapely.LineString([(x, -overhang), (x, end + overhang)]) for x in np.arange(n) * spacing]
    return np.array(h + v, dtype=object)


def rhombus(side=10.0, angle=60.0):
    a = math.radians(angle)
    dx, dy = side * math.cos(a), side * math.sin(a)
    return shapely.Polygon([(0, 0), (side, 0), (side + dx, dy), (dx, dy)])


# --------------------------------------------------------------------------- roads

def test_grid_road_metrics():
    r = M.road_metrics(grid(4), area=300.0 * 300.0)
    deg = r.distribution("roads", "node_degree")
    # corners have degree 2 and are merged away; 8 T junctions on the sides, 4 crosses inside
    assert sorted(np.unique(deg, return_counts=True)[1]) == [4, 8]
    assert set(deg) == {3, 4}
    angles = r.distribution("roads", "intersection_angle")
    # crosses: 4 x 90; T junctions: 90, 90, 180
    assert np.allclose(np.sort(angles), np.r_[np.full(32, 90.0), np.full(8, 180.0)])
    assert r.scalar("roads", "dead_ends_per_km2") == 0
    assert r.scalar("roads", "intersections_per_km2") == pytest.approx(12 / 0.09)
    # 8 streets of 300 m on 0.09 km²
    assert r.scalar("roads", "street_length_km_per_km2") == pytest.approx(2.4 / 0.09)
    # bearings of both directions fall into 4 of 36 bins: ln 4, order 1
    assert r.scalar("roads", "orientation_entropy") == pytest.approx(math.log(4))
    assert r.scalar("roads", "orientation_order") == pytest.approx(1.0)
    assert set(np.round(r.distribution("roads", "street_bearing"))) == {0.0, 90.0}
    seg = r.distribution("roads", "segment_length")
    assert seg.sum() == pytest.approx(2400.0)


def test_dead_ends_and_default_area():
    r = M.road_metrics(grid(2, 100.0, overhang=50.0))
    # a '#' of two crossing pairs: 4 crosses, 8 dead ends; area = hull of the lines
    deg = r.distribution("roads", "node_degree")
    assert (deg == 1).sum() == 8 and (deg == 4).sum() == 4
    hull_km2 = shapely.convex_hull(shapely.union_all(grid(2, 100.0, 50.0))).area / 1e6
    assert r.scalar("roads", "dead_ends_per_km2") == pytest.approx(8 / hull_km2)


def test_bridges_do_not_make_intersections():
    lines = [shapely.LineString([(0, 50), (100, 50)]), shapely.LineString([(50, 0), (50, 100)])]
    flat = M.compute_layout_metrics(roads=lines)
    assert flat.scalar("roads", "intersections_per_km2") > 0
    bridge = M.compute_layout_metrics(roads=lines, road_z_layer=[0, 1])
    assert bridge.scalar("roads", "intersections_per_km2") == 0
    assert (bridge.distribution("roads", "node_degree") == 1).all()


def test_a_bridge_is_part_of_its_street():
    # a 430 m street whose middle 30 m bridge over a road: one segment, no node at its joints
    street = [shapely.LineString([(0, 0), (200, 0)]), shapely.LineString([(200, 0), (230, 0)]),
              shapely.LineString([(230, 0), (430, 0)])]
    below = shapely.LineString([(215, -100), (215, 100)])
    r = M.compute_layout_metrics(roads=street + [below], road_z_layer=[0, 1, 0, 0])
    assert sorted(r.distribution("roads", "segment_length").round(6).tolist()) == [200, 430]
    assert sorted(r.distribution("roads", "node_degree").tolist()) == [1, 1, 1, 1]
    assert r.scalar("roads", "nodes") == 4 and r.scalar("roads", "intersections_per_km2") == 0


def test_orientation_entropy_bounds():
    assert M.orientation_entropy([0.0, 90.0, 180.0, 270.0]) == pytest.approx(math.log(4))
    assert M.orientation_entropy([0.0]) == pytest.approx(math.log(2))
    uniform = np.arange(0.0, 360.0, 10.0)
    assert M.orientation_entropy(uniform) == pytest.approx(math.log(36))
    # bins are centred on multiples of 10 degrees: 4.9 and -4.9 share the 0 bin
    assert M.orientation_entropy([4.9, 355.1]) == pytest.approx(math.log(2))


def test_intersection_angles_use_the_first_metres():
    # a Y: two streets leave at +-30 degrees and bend away after 10 m
    stem = shapely.LineString([(0, 0), (0, -100)])
    left = shapely.LineString([(0, 0), (-5, 8.66), (-100, 8.66)])
    right = shapely.LineString([(0, 0), (5, 8.66), (100, 8.66)])
    r = M.road_metrics([stem, left, right], area=1e4, bearing_length=10.0)
    assert np.allclose(np.sort(r.distribution("roads", "intersection_angle")), [60, 150, 150],
                       atol=0.1)


# --------------------------------------------------------------------------- blocks

def test_block_metrics_of_grid_faces():
    r = M.compute_layout_metrics(roads=grid(4))
    area = r.distribution("blocks", "area")
    assert len(area) == 9 and np.allclose(area, 1e4)
    assert np.allclose(r.distribution("blocks", "compactness"), 1.0)
    assert np.allclose(r.distribution("blocks", "aspect_ratio"), 1.0)
    assert r.scalar("blocks", "b_max") == r.scalar("blocks", "b_min") == pytest.approx(400.0)
    assert r.scalar("blocks", "blocks_per_km2") == pytest.approx(9 / 0.09)
    assert r.scalar("blocks", "land_share") == pytest.approx(100.0)   # the hull: all blocks


def test_land_share_is_the_area_in_counted_blocks():
    """The same grid in a study area three times as wide: a third of it in blocks; a block
    outside the area does not count."""
    area = shapely.box(0, 0, 900, 300)
    r = M.compute_layout_metrics(roads=grid(4), area=area)
    assert r.scalar("blocks", "land_share") == pytest.approx(100.0 / 3)
    outside = M.block_metrics([shapely.box(0, 0, 100, 100), shapely.box(2000, 0, 2100, 100)],
                              area=area)
    assert outside.scalar("blocks", "land_share") == pytest.approx(100.0 * 1e4 / 270000)


def test_block_aspect_ratio_is_short_over_long():
    r = M.block_metrics([shapely.box(0, 0, 100, 25), rhombus(100.0, 60.0)], area=1e6)
    assert r.distribution("blocks", "aspect_ratio")[0] == pytest.approx(0.25)
    # rhombus: the best rectangle lies on a side: 150 x 86.6 for an area of 8660
    assert r.distribution("blocks", "compactness")[1] == pytest.approx(1 / 1.5)
    assert r.scalar("blocks", "blocks_per_km2") == 2


# --------------------------------------------------------------------------- parcels

def test_rectangle_parcel():
    r = M.parcel_metrics([shapely.box(0, 0, 30, 18)])
    assert r.scalar("parcels", "p_angle") == 0.0
    assert r.scalar("parcels", "p_area") == pytest.approx(1.0)
    assert r.scalar("parcels", "undesirable_count") == 0


def test_rhombus_parcel():
    r = M.parcel_metrics([rhombus(10.0, 60.0)])
    # corners of 60 and 120 degrees: all deviate by 30; the MBR holds 1.5 x the area
    assert r.scalar("parcels", "p_angle") == pytest.approx(30.0)
    assert r.scalar("parcels", "p_area") == pytest.approx(1.5)
    assert r.scalar("parcels", "undesirable_count") == 1
    assert r.scalar("parcels", "undesirable_share") == pytest.approx(100.0)


def test_straight_vertices_and_reflex_corners_are_handled():
    # a rectangle digitised with extra vertices on its sides (a 175-degree kink and a
    # collinear point): those are not corners
    p = shapely.Polygon([(0, 0), (15, 0), (30, 0), (30, 9), (30.8, 18), (0, 18)])
    angles, owner = M.corner_angles([p])
    assert len(angles) == 4 and (owner == 0).all()
    # an L-shape: its reflex corner (270 degrees) counts as 90
    ell = shapely.Polygon([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)])
    angles, _ = M.corner_angles([ell])
    assert np.allclose(angles, 90.0) and len(angles) == 6
    r = M.parcel_metrics([ell])
    assert r.scalar("parcels", "p_angle") == 0.0
    assert r.scalar("parcels", "p_area") == pytest.approx(4 / 3)


def test_land_use_shares():
    parcels = [shapely.box(0, 0, 40, 100), shapely.box(50, 0, 90, 100),
               shapely.box(100, 0, 110, 100)]
    r = M.parcel_metrics(parcels, area=shapely.box(0, 0, 110, 100),
                         landuse=["Residential", "park", "shop"])
    assert r.scalar("parcels", "l_r") == pytest.approx(4000 / 110)
    assert r.scalar("parcels", "l_p") == pytest.approx(4000 / 110)
    assert r.scalar("parcels", "l_o") == pytest.approx(1000 / 110)
    assert r.scalar("parcels", "l_s") == pytest.approx(2000 / 110)  # the land between parcels
    with pytest.raises(InputError, match="land-use values"):
        M.parcel_metrics(parcels, landuse=["r"])


def test_bubenec_plots_invariants():
    import pyogrio

    from conftest import BUBENEC

    plots = pyogrio.read_dataframe(BUBENEC, layer="plots").to_crs(32633)
    geoms = np.asarray(plots.geometry.array, dtype=object)
    r = M.parcel_metrics(geoms)
    n = len(geoms)
    assert r.scalar("parcels", "count") == n == 407
    p_area = r.distribution("parcels", "p_area")
    p_angle = r.distribution("parcels", "p_angle")
    assert len(p_area) == n and (p_area >= 1 - 1e-9).all()
    assert len(p_angle) == n and (p_angle >= 0).all() and (p_angle <= 90).all()
    assert 0 <= r.scalar("parcels", "p_angle") <= 90
    bad = (p_angle > 15) | (p_area > 1.2)
    assert r.scalar("parcels", "undesirable_count") == bad.sum()
    assert 0 < bad.sum() < n
    # cadastre parcels are mostly near-rectangular: the median is close to Yang's maps
    assert 1.0 <= np.median(p_area) < 1.3 and np.median(p_angle) < 15
    assert r.scalar("parcels", "p_n_per_km2") > 100


# --------------------------------------------------------------------------- footprints

def test_footprint_overlaps_coverage_and_outside():
    a = shapely.box(10, 10, 30, 30)
    b = shapely.box(20, 20, 40, 40)          # overlaps a by 10 x 10
    c = shapely.box(60, 10, 70, 20)          # alone
    d = shapely.box(95, 40, 110, 50)         # half outside the block, on the road
    blocks = [shapely.box(0, 0, 100, 100)]
    roads = [shapely.LineString([(103, -50), (103, 150)])]
    r = M.footprint_metrics([a, b, c, d], blocks=blocks, roads=roads, road_half_width=3.0,
                            area=1e4)
    assert r.scalar("buildings", "overlap_area") == pytest.approx(100.0)
    assert r.scalar("buildings", "overlapping_pairs") == 1
    assert r.scalar("buildings", "outside_blocks") == 1
    # footprint area inside the block: 400 + 400 + 100 + 50 = 950 of 10 000
    assert r.scalar("buildings", "coverage") == pytest.approx(0.095)
    # the road surface spans x = 100..106: d covers 6 x 10 of it
    assert r.scalar("buildings", "road_overlap_area") == pytest.approx(60.0)
    assert r.scalar("buildings", "road_overlap_count") == 1
    setback = r.distribution("buildings", "setback")
    assert setback[2] == pytest.approx(103 - 70 - 3) and setback[3] < 0
    assert r.scalar("buildings", "per_km2") == pytest.approx(400.0)


def test_touching_footprints_do_not_overlap():
    r = M.footprint_metrics([shapely.box(0, 0, 10, 10), shapely.box(10, 0, 20, 10)])
    assert r.scalar("buildings", "overlap_area") == 0
    assert r.scalar("buildings", "overlapping_pairs") == 0


# --------------------------------------------------------------------------- comparison

def test_identical_and_shifted_distributions():
    rng = np.random.default_rng(1)
    x = rng.normal(100.0, 10.0, 500)
    same = M.two_sample(x, x)
    assert same["wasserstein"] == 0 and same["ks_stat"] == 0 and same["ks_pvalue"] == 1
    shifted = M.two_sample(x + 20.0, x)
    assert shifted["wasserstein"] == pytest.approx(20.0)
    assert shifted["wasserstein_norm"] == pytest.approx(20.0 / np.std(x))
    assert shifted["ks_stat"] > 0.5 and shifted["ks_pvalue"] < 1e-6
    assert np.isnan(M.two_sample([], x)["wasserstein"])


def test_compare_rows():
    cand = M.compute_layout_metrics(roads=grid(4, 100.0))
    ex = M.compute_layout_metrics(roads=grid(5, 80.0))
    table = M.compare(cand, ex)
    assert list(table.columns) == [c for c, _ in M.COMPARISON_COLUMNS]
    seg = table[(table.kind == "roads") & (table.metric == "segment_length")].iloc[0]
    assert seg.statistic == "mean" and seg.wasserstein > 0 and seg.n_example > seg.n_candidate
    ent = table[(table.kind == "roads") & (table.metric == "orientation_entropy")].iloc[0]
    assert ent.statistic == "value" and ent.rel_diff == pytest.approx(0.0)
    blocks = table[(table.kind == "blocks") & (table.metric == "area")].iloc[0]
    assert blocks.rel_diff == pytest.approx(1e4 / 6400 - 1)
    self_table = M.compare(cand, cand)
    dist = self_table[self_table.statistic != "value"]
    assert (dist.wasserstein == 0).all() and (dist.ks_stat == 0).all()
    # kinds come in a fixed order, distributions before scalars
    assert list(dict.fromkeys(table.kind)) == ["layout", "invariants", "roads", "blocks"]
    alone = M.compare(cand)
    assert alone.example.isna().all() and (alone.n_example == 0).all()
    # bearings are axial: 175 and 5 degrees average to 0, not 90
    bearing = table[table.metric == "street_bearing"].iloc[0]
    assert bearing.statistic == "axial_mean"
    assert M._axial_mean(np.array([175.0, 5.0])) == pytest.approx(0.0, abs=1e-9) or \
        M._axial_mean(np.array([175.0, 5.0])) == pytest.approx(180.0)


def test_counts_agree_with_plain_noding_and_polygonising():
    """With snapping and the sliver filter off, the counts are those of shapely.node and
    shapely.polygonize on real, dirty OSM lines (footways, bridges and all)."""
    from helpers import _helsinki_lines

    lines = _helsinki_lines().to_crs(32635).geometry.values
    lines = shapely.get_parts(lines[shapely.get_type_id(lines) == 1])
    r = M.compute_layout_metrics(roads=lines, snap_tolerance=0.0, min_block_area=0.0,
                                 min_block_width=0.0)
    pieces = shapely.get_parts(shapely.node(shapely.multilinestrings(lines)))
    pieces = pieces[shapely.length(pieces) > 0]          # one zero-length OSM way
    ends = np.concatenate([shapely.get_coordinates(shapely.get_point(pieces, i))
                           for i in (0, -1)])
    _, degree = np.unique(ends[:, 0] + 1j * ends[:, 1], return_counts=True)
    faces = shapely.get_parts(shapely.polygonize(pieces))
    km2 = r.scalar("layout", "area_km2")
    assert r.scalar("roads", "dead_ends_per_km2") * km2 == pytest.approx((degree == 1).sum())
    assert r.scalar("roads", "intersections_per_km2") * km2 == pytest.approx((degree >= 3).sum())
    assert r.scalar("blocks", "count") == len(faces) > 1000
    assert r.scalar("roads", "street_length_km_per_km2") * km2 == pytest.approx(
        shapely.length(pieces).sum() / 1000)
    # the defaults drop the faces under 400 m² and thinner than 8 m, and say so
    d = M.compute_layout_metrics(roads=lines)
    assert d.scalar("blocks", "count") < 0.7 * len(faces)
    assert any("faces under 400 m²" in n and "dropped as slivers" in n for n in d.notes)


def test_drivable_only_and_edge_dead_ends():
    from helpers import _helsinki_lines

    df = _helsinki_lines().to_crs(32635)
    df = df[shapely.get_type_id(df.geometry.values) == 1]
    every = M.compute_layout_metrics(roads=df.geometry.values, road_class=df.highway.values)
    assert any("non-drivable" in n and "counted" in n for n in every.notes)
    cars = M.compute_layout_metrics(roads=df.geometry.values, road_class=df.highway.values,
                                    drivable_only=True)
    assert cars.scalar("roads", "street_length_km_per_km2") < \
        0.5 * every.scalar("roads", "street_length_km_per_km2")
    with pytest.raises(InputError, match="road class"):
        M.compute_layout_metrics(roads=df.geometry.values, drivable_only=True)
    # a grid clipped to a box: its 8 cut ends lie on the box's edge
    box = shapely.box(-30, -30, 330, 330)
    clipped = shapely.intersection(grid(4, 100.0, overhang=80.0), box)
    plain = M.compute_layout_metrics(roads=clipped, area=box)
    assert plain.scalar("roads", "dead_ends_per_km2") * 0.36 ** 2 == pytest.approx(16)
    assert plain.scalar("roads", "dead_end_share") == pytest.approx(16 / 32)
    edge = M.compute_layout_metrics(roads=clipped, area=box, edge_distance=1.0)
    assert edge.scalar("roads", "dead_ends_per_km2") == 0
    assert edge.scalar("roads", "degree4_share") == 1.0     # the 16 crosses
    assert edge.scalar("invariants", "dead_end_share") == 0


def test_invariants_are_reported():
    arterials = grid(2, 300.0)                      # a 300 m square
    streets = np.array([shapely.LineString([(150, -20), (150, 320)]),     # crosses twice
                        shapely.LineString([(0, 100), (300, 100)])], dtype=object)
    r = M.compute_layout_metrics(roads=np.concatenate([arterials, streets]),
                                 given_roads=arterials)
    assert r.scalar("invariants", "crossings_given") == 2
    assert r.scalar("invariants", "crossings_synthesised") == 1
    assert r.scalar("invariants", "violations") >= 3
    assert any("2 of 6 road lines are not on the 4 given roads" in n for n in r.notes)
    # a grid of long lines drawn over each other: 4 crossings inside; noded, it is planar
    assert M.compute_layout_metrics(roads=grid(4)).scalar("invariants", "violations") == 4
    noded = shapely.get_parts(shapely.node(shapely.multilinestrings(grid(4))))
    ok = M.compute_layout_metrics(roads=noded)
    assert ok.scalar("invariants", "violations") == 0
    table = M.compare(r, ok)
    row = table[(table.kind == "invariants") & (table.metric == "dead_end_share")].iloc[0]
    assert row.example == 0 and row.candidate > 0


def test_study_area_counts_only_what_is_inside():
    # the study area covers the left part of a 3 x 3 block grid (x <= 140)
    area = shapely.box(0, 0, 140, 300)
    r = M.compute_layout_metrics(roads=grid(4), area=area)
    assert r.scalar("layout", "area_km2") == pytest.approx(0.042)
    # street length inside: 4 horizontal x 140 m + 2 vertical x 300 m
    assert r.scalar("roads", "street_length_km_per_km2") == pytest.approx(1.16 / 0.042)
    # nodes at x = 0 (2 T's) and x = 100 (2 crosses + 2 T's)
    assert r.scalar("roads", "intersections_per_km2") == pytest.approx(6 / 0.042)
    # blocks whose point on surface lies inside: the 3 blocks of the left column
    assert r.scalar("blocks", "blocks_per_km2") == pytest.approx(3 / 0.042)
    assert len(r.distribution("blocks", "area")) == 9  # distributions keep every block


def test_a_street_along_the_edge_of_the_area_counts_whole():
    """A layout's outline street is built along its domain's edge: a nanometre outside it
    here and there, it counts all the same (clipped to the exact polygon it counted
    nothing where it lay outside)."""
    area = shapely.box(0, 0, 300, 300)
    shifted = grid(4)
    # the grid's outer streets lie on the area's edge, its left and bottom ones 1 nm out
    shifted = shapely.transform(shifted, lambda xy: np.where(xy == 0.0, -1e-9, xy))
    assert shapely.length(shapely.intersection(shifted, area)).sum() == pytest.approx(1800)
    r = M.compute_layout_metrics(roads=shifted, area=area)
    assert r.scalar("roads", "street_length_km_per_km2") == pytest.approx(2.4 / 0.09)
    # a street crossing the edge still counts only up to it
    r = M.compute_layout_metrics(roads=grid(4, overhang=50.0), area=area)
    assert r.scalar("roads", "street_length_km_per_km2") == pytest.approx(2.4 / 0.09)



def test_a_street_rounding_a_corner_outside_the_area_counts_within_the_edge_distance():
    """splitdomain's outline street rounds a reflex corner of its domain up to 0.9 m outside
    it: with EDGE_DISTANCE 1 m it counts whole and closes its blocks; cut at the exact
    boundary (EDGE_DISTANCE 0) it lost the rounded stretch, and the blocks behind it with it."""
    area = shapely.Polygon([(0, 0), (200, 0), (200, 100), (100, 100), (100, 200), (0, 200)])
    # the outline, its reflex corner (100, 100) rounded 0.5 m outside, and a street across
    outline = shapely.LineString([(0, 0), (200, 0), (200, 100), (101, 100.5), (100.5, 101),
                                  (100, 200), (0, 200), (0, 0)])
    across = [shapely.LineString([(0, 100), (100.75, 100.75)]),
              shapely.LineString([(100, 0), (100.75, 100.75)])]
    roads = [outline] + across
    whole = shapely.length(outline) + shapely.length(across).sum()
    kept = M.compute_layout_metrics(roads=roads, area=area, edge_distance=1.0)
    assert kept.scalar("roads", "street_length_km_per_km2") == pytest.approx(
        whole / 1e3 / 0.03)
    assert kept.scalar("blocks", "count") == 3
    cut = M.compute_layout_metrics(roads=roads, area=area)
    assert cut.scalar("roads", "street_length_km_per_km2") < whole / 1e3 / 0.03 - 3
    # a street across the edge still ends where it crosses it, also at a slant (the grown
    # area cuts it 2.2 m on, and that end moved onto the edge lay 2 m off the crossing)
    slant = shapely.LineString([(100, 50), (300, 150)])   # crosses x = 200 at y = 100
    part, = M.clip_lines([slant], area, tolerance=1.0)
    assert shapely.equals_exact(part, shapely.LineString([(100, 50), (200, 100)]), 1e-9)

def test_bad_input():
    with pytest.raises(InputError, match="no layer"):
        M.compute_layout_metrics()
    with pytest.raises(InputError, match="must contain lines"):
        M.compute_layout_metrics(roads=[shapely.Point(0, 0)])
    with pytest.raises(InputError, match="must contain polygons"):
        M.compute_layout_metrics(parcels=grid(2))
    with pytest.raises(InputError, match="no geometries"):
        M.compute_layout_metrics(buildings=[])
    with pytest.raises(InputError, match="half-width"):
        M.compute_layout_metrics(roads=grid(2), road_half_width=-1)
    # stray geometries of another dimension are dropped with a note
    r = M.compute_layout_metrics(buildings=[shapely.box(0, 0, 1, 1),
                                            shapely.LineString([(0, 0), (1, 1)])])
    assert r.scalar("buildings", "count") == 1 and any("ignored" in n for n in r.notes)


def test_cancel_stops_the_work():
    with pytest.raises(Canceled):
        M.compute_layout_metrics(roads=grid(4), progress=Progress(is_canceled=lambda: True))


# --------------------------------------------------------------------------- report

def test_report_is_self_contained(tmp_path):
    cand = M.compute_layout_metrics(roads=grid(4, 100.0),
                                    parcels=[shapely.box(0, 0, 30, 18), rhombus()],
                                    buildings=[shapely.box(10, 10, 30, 30)])
    ex = M.compute_layout_metrics(roads=grid(5, 80.0), parcels=[shapely.box(0, 0, 30, 20)])
    steps = []
    path = R.write_report(tmp_path / "r" / "report.html", cand, ex, title="Grid vs grid",
                          meta={"Layout": "grid <4>"}, progress=Progress(report=steps.append))
    text = open(path, encoding="utf-8").read()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert text.count("<img") >= 8 and "data:image/png;base64," in text
    for name in ("segment_length", "intersection_angle", "p_angle", "p_area", "orientation_entropy",
                 "Wasserstein", "grid &lt;4&gt;"):
        assert name in text
    assert "src='http" not in text and "<script" not in text
    assert steps and steps[-1] == pytest.approx(100.0)
    # the buildings exist only in the candidate: still plotted, no distance
    alone = R.render_report(cand)
    assert "Colours" not in alone and "Wasserstein</th>" not in alone
    assert alone.count("<img") >= 8


def test_report_speaks_to_a_planner_first():
    """A denser grid against a sparser one: the summary comes first, says in words which
    measures differ and by how much, maps both layouts, and explains its units."""
    def noded(n, spacing):
        return shapely.get_parts(shapely.node(shapely.multilinestrings(grid(n, spacing))))

    cand = M.compute_layout_metrics(roads=noded(6, 60.0))
    ex = M.compute_layout_metrics(roads=noded(4, 100.0))
    same = M.compute_layout_metrics(roads=noded(4, 100.0))
    text = R.render_report(cand, ex, maps={"Layout": {"roads": noded(6, 60.0)},
                                           "Example": {"roads": noded(4, 100.0)}})
    summary = text[text.index("<h2>Summary</h2>"):text.index("<h2>Inputs</h2>")]
    assert text.index("<h2>Summary</h2>") < text.index("<h3>Measures</h3>")
    assert "The street network is sound" in summary
    differs = summary[summary.index("What differs"):]
    assert "Junctions per km²: much more than the example" in differs
    assert "Street length per km² (how much street there is): much more" in differs
    assert summary.count(" map' src='data:image/png") == 2  # both layouts mapped up front
    assert "How to read the numbers" in text and "nats" in text[text.index("How to read"):]
    twin = R.render_report(same, ex)
    twin_summary = twin[twin.index("<h2>Summary</h2>"):twin.index("<h2>Inputs</h2>")]
    assert "What differs" not in twin_summary and "match the example" in twin_summary
    assert "about the same as the example" in twin_summary
    assert "Share of the area in city blocks (how much of it streets close)" in twin_summary


def test_bearings_compare_on_the_circle():
    """Streets at 5° and at 175° run 10° apart, not 170°: the comparison of bearings does
    not depend on where the circle of directions is cut."""
    rng = np.random.default_rng(0)
    north_east = rng.normal(5.0, 5.0, 2000) % 180.0
    north_west = rng.normal(-5.0, 5.0, 2000) % 180.0
    d = M.two_sample_axial(north_east, north_west)
    assert 8.0 < d["wasserstein"] < 12.0
    assert M.two_sample(north_east, north_west)["wasserstein"] > 100.0  # the linear trap
    turned = M.two_sample_axial(north_east, (north_east + 30.0) % 180.0)
    assert turned["wasserstein"] == pytest.approx(30.0, abs=1e-6)
    # the same shape cut elsewhere is the same distance (rotation invariance)
    again = M.two_sample_axial((north_east + 77.0) % 180.0, (north_west + 77.0) % 180.0)
    assert again["wasserstein"] == pytest.approx(d["wasserstein"], rel=1e-6)
    assert again["ks_stat"] == pytest.approx(d["ks_stat"], rel=1e-9)
    same = M.two_sample_axial(north_east, north_east)
    assert same["wasserstein"] == 0.0 and same["ks_pvalue"] == 1.0


def test_bearing_row_reports_the_turn_between_mean_directions():
    a, b = M.MetricsResult(), M.MetricsResult()
    a.add_distribution("roads", "street_bearing", np.array([176.0, 178.0, 177.0]), "°", "b")
    b.add_distribution("roads", "street_bearing", np.array([4.0, 6.0, 5.0]), "°", "b")
    row = M.compare(a, b).iloc[0]
    assert row.statistic == "axial_mean"
    assert row.rel_diff == pytest.approx(-8.0, abs=1e-6)


def test_a_dead_end_share_beyond_the_example_band_is_said_in_the_summary():
    """A sound network (every contact a junction) whose dead-end share is 33 % under the
    example's: the violation count leaves the share out (it needs an example), so the
    summary said 'sound' under a flagged row; it now says the share is beyond the band."""
    from urban_synthesis.plugin.network.invariants import DEAD_END_TOLERANCE

    given = [shapely.LineString([(0, 0), (400, 0)])]
    streets = [shapely.LineString([(100, 0), (100, 150)]), shapely.LineString([(300, 0), (300, 150)]),
               shapely.LineString([(100, 150), (300, 150)])]
    cand = M.compute_layout_metrics(roads=given + streets, given_roads=given)
    tee = M.compute_layout_metrics(roads=[shapely.LineString([(0, 0), (200, 0)]),
                                          shapely.LineString([(100, 0), (100, 100)])])
    table = M.compare(cand, tee)
    row = table[(table.metric == "dead_end_share") & (table.statistic == "value")].iloc[0]
    assert abs(row.rel_diff) > DEAD_END_TOLERANCE
    text = R.render_report(cand, tee)
    summary = text[text.index("<h2>Summary</h2>"):text.index("<h2>Inputs</h2>")]
    assert "The street network is sound" in summary
    assert f"beyond the ±{100 * DEAD_END_TOLERANCE:.0f} % the invariants allow" in summary
    import html

    assert html.escape(R.dead_end_breach(table)) in summary
    # within the band: nothing said
    assert R.dead_end_breach(M.compare(tee, tee)) is None


def test_the_plugins_own_road_classes_count_as_drivable():
    """A synthesis measured with DRIVABLE_ONLY keeps its streets: growroads' major / minor
    and StreetGAN's given / arterial / local classes are drivable (they were taken for
    footways and counted apart, or refused as 'no drivable class')."""
    from urban_synthesis.plugin.network import street_graph
    from urban_synthesis.plugin.roads import growth

    assert set(growth.ROAD_CLASSES) <= set(street_graph.SYNTHESISED_CLASSES)
    lines = grid(3, 100.0)
    classes = (["major", "minor", "local", "given", "arterial"] * len(lines))[:len(lines)]
    res = M.compute_layout_metrics(roads=lines, road_class=classes, drivable_only=True)
    every = M.compute_layout_metrics(roads=lines)
    assert res.scalar("roads", "street_length_km_per_km2") == pytest.approx(
        every.scalar("roads", "street_length_km_per_km2"))
    footway = M.compute_layout_metrics(roads=lines, road_class=["footway"] + classes[1:],
                                       drivable_only=True)
    assert any("1 line of non-drivable" in n for n in footway.notes)
    # every line drivable: nothing to say ('0 lines of non-drivable classes left out' was)
    assert not any("non-drivable" in n for n in res.notes)


def test_lines_without_a_class_beside_classed_ones_are_not_streets():
    """An OSM 'lines' layer holds rivers, railways, power lines and country borders without a
    'highway' class; measured with the defaults they counted as streets (Liechtenstein: 263
    of them, 650 km, and the border made the study area 1,220 km² instead of 251). They are
    left out, the notes say so; a layer without any class still counts every line."""
    lines = grid(3, 100.0)
    classes = ["residential"] * len(lines)
    far = shapely.LineString([(0, 0), (5000, 5000)])        # a border far out
    plain = M.compute_layout_metrics(roads=lines, road_class=classes)
    res = M.compute_layout_metrics(roads=np.r_[lines, [far, far.reverse()]],
                                   road_class=classes + [None, ""],
                                   road_z_layer=[0] * (len(lines) + 2))
    for name in ("street_length_km_per_km2", "intersections_per_km2"):
        assert res.scalar("roads", name) == pytest.approx(plain.scalar("roads", name))
    assert any("2 lines without a road class left out" in n for n in res.notes)
    unclassed = M.compute_layout_metrics(roads=lines, road_class=[None] * len(lines))
    assert unclassed.scalar("roads", "street_length_km_per_km2") == pytest.approx(
        plain.scalar("roads", "street_length_km_per_km2"))


def test_an_example_of_a_whole_region_is_flagged_as_mostly_empty_land():
    """A whole country's roads as the example (Liechtenstein, as an analyst reads the OSM
    extract) count their densities over the convex hull of 169 km² of mountains and
    valleys, a quarter of it settled: the report said a town had 10 times the example's
    junctions per km². The settled share is measured and the report says the figures per
    km² compare poorly; a town measured in its outline is not flagged."""
    from towns import LI_PBF, liechtenstein_towns
    from urban_synthesis.plugin.network import street_graph as sg

    if not LI_PBF.exists():
        pytest.skip(f"{LI_PBF} is missing")
    import pyogrio

    lines = pyogrio.read_dataframe(LI_PBF, layer="lines").to_crs(32632)
    roads = lines[lines.highway.isin(sg.DRIVABLE_CLASSES)].geometry.values
    vaduz = next(t for t in liechtenstein_towns() if t.name == "Vaduz")
    country = M.compute_layout_metrics(roads=roads)
    town = M.compute_layout_metrics(roads=vaduz.lines, area=vaduz.area)
    assert country.scalar("layout", "settled_share") < 0.3
    assert town.scalar("layout", "settled_share") > 0.9
    assert any("mostly of empty land" in n for n in country.notes)
    flagged = R.summary_html(M.compare(town, country), True)
    assert "compare poorly" in flagged and "the example's settle only" in flagged
    assert "compare poorly" not in R.summary_html(M.compare(town, town), True)
