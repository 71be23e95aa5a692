"""Procedural road growth (plugin.roads.growth): patterns, local constraints, invariants."""
from functools import lru_cache

import numpy as np
import pytest
import shapely

from helpers import assert_planar, nearly_coincident_streets
from urban_synthesis.plugin.roads import growth
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.retrieval.shape_context import DemGrid

BOX = shapely.box(0, 0, 1000, 1000)


@lru_cache(maxsize=None)
def _grown(pattern, seed=1):
    s = growth.GrowthSettings(major_pattern=pattern, minor_pattern=pattern)
    return growth.grow_roads(BOX, settings=s, seed=seed)


@lru_cache(maxsize=None)
def _stats(pattern):
    return growth.network_statistics(_grown(pattern).geometry)


def _edge_keys(lines):
    """End points of each edge, rounded to the millimetre and ordered: one key per edge."""
    a = np.round(shapely.get_coordinates(shapely.get_point(lines, 0)), 3)
    b = np.round(shapely.get_coordinates(shapely.get_point(lines, -1)), 3)
    return {tuple(sorted([tuple(p), tuple(q)])) for p, q in zip(a, b)}, len(lines)


def _hill(peak=90.0, sigma=200.0, centre=(350.0, 700.0), cell=5.0):
    xs = np.arange(-50.0, 1100.0, cell)
    ys = np.arange(1100.0, -50.0, -cell)
    x, y = np.meshgrid(xs + cell / 2, ys - cell / 2)
    z = peak * np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * sigma ** 2))
    return DemGrid(z, (xs[0], cell, 0.0, ys[0], 0.0, -cell))


# --------------------------------------------------------------------------- patterns

def test_grid_is_a_grid():
    st = _stats("grid")
    # four dominant bearings (N, S, E, W): close to ln 4 = 1.386 of a perfect grid
    assert st["orientation_entropy"] < 1.65
    # junction angles cluster at 90 degrees
    assert st["mean_abs_angle_dev_90"] < 5.0
    assert st["share_right_angles"] > 0.9


def test_pattern_distributions_differ_as_expected():
    grid, radial, organic = _stats("grid"), _stats("radial"), _stats("organic")
    # radial rings and organic turns spread the bearings over all directions
    assert radial["orientation_entropy"] > grid["orientation_entropy"] + 1.5
    assert organic["orientation_entropy"] > grid["orientation_entropy"] + 1.5
    assert min(radial["orientation_entropy"], organic["orientation_entropy"]) > 3.2
    # spokes meet rings at right angles; organic streets meet at varied angles
    assert grid["mean_abs_angle_dev_90"] < radial["mean_abs_angle_dev_90"] \
        < organic["mean_abs_angle_dev_90"] - 5.0
    assert organic["share_right_angles"] < radial["share_right_angles"] - 0.2
    # grid blocks are regular: lengths vary least
    for st in (grid, radial, organic):
        assert 30.0 < st["segment_length_median"] < 160.0


def test_levels_patterns_and_attributes():
    r = _grown("grid")
    assert set(r.level.tolist()) == {growth.MAJOR, growth.MINOR}
    assert set(r.pattern.tolist()) == {"grid"}
    assert (r.road_class == np.where(r.level == 0, "major", "minor")).all()
    t = r.table()
    assert list(t.columns) == ["level", "road_class", "pattern", "width_m", "length_m"]
    assert (t.length_m > 0).all()
    assert r.stats["major_segments"] > 0 and r.stats["minor_segments"] > 0
    assert not r.stats["capped"]


def test_grid_axis_follows_a_rotated_boundary():
    box = shapely.affinity.rotate(shapely.box(0, 0, 800, 800), 30, origin=(0, 0))
    r = growth.grow_roads(box, settings=growth.GrowthSettings(), seed=2)
    from urban_synthesis.plugin.measure.metrics import street_bearings

    b, w = street_bearings(r.geometry)
    axial = np.degrees(np.arctan2((w * np.sin(np.radians(4 * b))).sum(),
                                  (w * np.cos(np.radians(4 * b))).sum())) / 4 % 90
    # compass bearing of a 30 degree counter-clockwise grid: 60 (and 150, 240, 330)
    assert abs(axial - 60.0) < 3.0


def test_radial_spokes_meet_at_the_centre():
    r = growth.grow_roads(BOX, settings=growth.GrowthSettings(major_pattern="radial"),
                          center=(400, 600), seed=3)
    ends = np.concatenate([shapely.get_coordinates(shapely.get_point(r.geometry, 0)),
                           shapely.get_coordinates(shapely.get_point(r.geometry, -1))])
    at_centre = np.hypot(ends[:, 0] - 400, ends[:, 1] - 600) < 1e-6
    assert at_centre.sum() >= 5  # six spokes, unless a minor road was denied a start


# --------------------------------------------------------------------------- invariants

@pytest.mark.parametrize("pattern", growth.PATTERNS)
def test_constraints_hold_with_obstacles_and_terrain(pattern):
    boundary = shapely.Polygon([(0, 0), (1000, 80), (950, 950), (60, 1000)])
    lake = shapely.Point(650, 450).buffer(150)
    park = shapely.box(120, 150, 300, 330)
    dem = _hill()
    limit = 0.08
    s = growth.GrowthSettings(major_pattern=pattern, minor_pattern=pattern, max_slope=limit)
    r = growth.grow_roads(boundary, settings=s, obstacles=[lake, park], dem=dem, seed=5)
    lines = r.geometry
    assert len(lines) > 80
    # every segment inside the boundary, none in an obstacle
    assert shapely.covers(boundary.buffer(1e-6), lines).all()
    with np.errstate(invalid="ignore"):  # GEOS's empty results carry a NaN z
        inside = shapely.length(shapely.intersection(lines, shapely.union_all([lake, park])))
    assert inside.max() < 1e-6
    # no segment steeper than the limit (the hill reaches 27 %): exactly on the bilinear
    # surface, and as sampled every 5 m, 1 m and 0.25 m along each segment
    assert growth.segment_slopes(lines, dem).max() <= limit
    for step in (5.0, 1.0, 0.25):
        assert growth.chord_slopes(lines, dem, step).max() <= limit
    assert r.stats["rejected"].get("slope", 0) > 0  # the terrain did constrain growth
    # planar, clean, no duplicate edges, no zero-length edges
    assert_planar(lines)
    keys, n = _edge_keys(lines)
    assert len(keys) == n
    assert shapely.length(lines).min() > 1.0


def test_output_is_planar_without_duplicates():
    for pattern in growth.PATTERNS:
        lines = _grown(pattern).geometry
        assert_planar(lines)
        keys, n = _edge_keys(lines)
        assert len(keys) == n
        assert shapely.covers(BOX.buffer(1e-6), lines).all()
        assert (shapely.get_num_coordinates(lines) == 2).all()  # one straight segment each


def test_near_parallel_duplicates_are_dropped():
    """No two non-adjacent near-parallel edges run side by side closer than the minimum."""
    s = growth.GrowthSettings(major_pattern="organic", minor_pattern="organic")
    lines = growth.grow_roads(BOX, settings=s, seed=4).geometry
    mids = shapely.line_interpolate_point(lines, 0.5, normalized=True)
    tree = shapely.STRtree(lines)
    i, j = tree.query(mids, predicate="dwithin", distance=0.5 * s.min_street_distance)
    sel = i != j
    i, j = i[sel], j[sel]
    v = shapely.get_coordinates(shapely.get_point(lines, -1)) - \
        shapely.get_coordinates(shapely.get_point(lines, 0))
    u = v / np.hypot(v[:, 0], v[:, 1])[:, None]
    parallel = np.abs((u[i] * u[j]).sum(axis=1)) > 0.99
    touching = shapely.intersects(lines[i], lines[j])
    assert not (parallel & ~touching).any()


def test_a_part_of_the_boundary_no_sketch_reaches_is_linked():
    """Two settlements 300 m apart, a sketched road through the west one only: both grow a
    network, the east one is joined by one straight 'link' road (the only road outside the
    boundary), planar, one piece with the sketch. With a lake between them the link would
    enter it: the east piece then stays unlinked rather than crossing the obstacle."""
    from urban_synthesis.plugin.network import invariants

    west, east = shapely.box(0, 0, 600, 600), shapely.box(900, 0, 1500, 600)
    boundary = shapely.union_all([west, east])
    sketch = np.array([shapely.LineString([(0, 300), (600, 310)])])
    res = growth.grow_roads(boundary, major_roads=sketch, seed=2)
    g = res.geometry
    assert_planar(g)
    outside = ~shapely.covers(boundary.buffer(1e-6), g)
    assert outside.any() and (res.pattern[outside] == "link").all()
    assert res.stats["links"] >= 1 and (res.pattern == "link").sum() >= outside.sum()
    new = g[invariants.new_streets(g, sketch)]
    check = invariants.check_network(new, sketch, area=boundary)
    assert check.floating_pieces == 0 and len(check.crossings_given) == 0
    assert shapely.intersects(g, east).sum() > 10
    lake = shapely.box(650, -1000, 850, 1600)
    res = growth.grow_roads(boundary, major_roads=sketch, obstacles=lake, seed=2)
    assert not shapely.intersects(res.geometry, lake).any()
    assert res.stats["links"] == 0 and shapely.intersects(res.geometry, east).sum() > 10


def test_a_piece_in_an_arm_of_a_concave_boundary_is_linked_inside_it():
    """Two arms joined at the top by a 40 m strip, the sketched road in the west arm: with
    this seed the east arm grows a network of its own, and the straight road that joined it
    before crossed the bay between the arms, outside the boundary. Now its link bends along
    the arms (straight legs): every road inside the boundary, one piece with the sketch."""
    from urban_synthesis.plugin.network import invariants

    west, east = shapely.box(0, 0, 250, 700), shapely.box(550, 0, 800, 700)
    boundary = shapely.union_all([west, east, shapely.box(0, 660, 800, 700)])
    sketch = np.array([shapely.LineString([(125, 0), (125, 650)])])
    res = growth.grow_roads(boundary, major_roads=sketch, seed=2)
    g = res.geometry
    assert res.stats["links"] >= 1
    assert shapely.covers(boundary.buffer(1.0), g).all()
    legs = g[res.pattern == "link"]
    assert len(legs) > res.stats["links"] and (shapely.get_num_coordinates(legs) == 2).all()
    assert_planar(g)
    new = g[invariants.new_streets(g, sketch)]
    check = invariants.check_network(new, sketch, area=boundary, target=boundary)
    assert check.floating_pieces == 0 and check.violations()["outside_target"] == 0
    assert shapely.intersects(g, east).sum() > 10


def test_sketched_major_roads_are_kept_and_bound_quarters():
    sketch = [shapely.LineString([(-100, 500), (1100, 520)]),
              shapely.LineString([(480, -50), (520, 1050)])]
    s = growth.GrowthSettings(grow_major=False, minor_pattern="organic")
    r = growth.grow_roads(BOX, settings=s, major_roads=sketch, seed=6)
    major = r.geometry[r.level == 0]
    assert set(r.pattern[r.level == 0].tolist()) == {"sketch"}
    assert r.stats["major_segments"] == 0 and r.stats["sketched_segments"] > 0
    # the sketch, clipped to the boundary, is all there
    clipped = shapely.intersection(shapely.union_all(sketch), BOX)
    assert abs(shapely.length(shapely.union_all(major)) - clipped.length) < 1e-6
    # minor roads fill the four quarters and never cross the sketch
    minor = r.geometry[r.level == 1]
    assert r.stats["quarters"] == 4
    for quarter in shapely.get_parts(shapely.polygonize(list(major) + [BOX.exterior])):
        assert shapely.intersects(minor, quarter.buffer(-1)).sum() > 5
    assert_planar(r.geometry)


def test_sketch_whose_noding_fails_is_snap_rounded():
    """A sketch that defeats GEOS's floating-point noding is noded on the millimetre grid:
    a planar network that keeps the sketch to that grid."""
    sketch = nearly_coincident_streets()
    r = growth.grow_roads(shapely.box(0, 0, 100, 80), major_roads=sketch, seed=1)
    assert_planar(r.geometry)
    kept = shapely.buffer(shapely.union_all(r.geometry[r.pattern == "sketch"]), 1e-3)
    assert shapely.covers(kept, sketch).all()


def test_sketch_grows_major_roads_when_asked():
    sketch = [shapely.LineString([(0, 500), (600, 500)])]
    r = growth.grow_roads(BOX, settings=growth.GrowthSettings(), major_roads=sketch, seed=6)
    grown = (r.level == 0) & (r.pattern == "grid")
    assert grown.sum() > 10
    # the grid takes the sketch's direction: grown major roads are axis-parallel
    v = shapely.get_coordinates(shapely.get_point(r.geometry[grown], -1)) - \
        shapely.get_coordinates(shapely.get_point(r.geometry[grown], 0))
    ang = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 90
    assert np.median(np.minimum(ang, 90 - ang)) < 2.0


def test_density_steers_growth():
    # people live in the east half only
    xs = np.arange(0, 1000, 10.0)
    grid = np.tile(np.where(xs + 5 > 500, 100.0, 0.0), (100, 1))
    dens = (grid, (0.0, 10.0, 0.0, 1000.0, 0.0, -10.0))
    s = growth.GrowthSettings(major_pattern="organic", minor_pattern="organic")
    r = growth.grow_roads(BOX, settings=s, density=dens, seed=7)
    with np.errstate(invalid="ignore"):  # GEOS's empty results carry a NaN z
        west = shapely.length(shapely.intersection(r.geometry, shapely.box(0, 0, 450, 1000)))
        east = shapely.length(shapely.intersection(r.geometry, shapely.box(550, 0, 1000, 1000)))
    west, east = west.sum(), east.sum()
    assert east > 5 * west
    assert r.stats["segments"] > 50


# --------------------------------------------------------------------------- determinism

def test_same_seed_same_network_other_seed_other_network():
    s = growth.GrowthSettings(major_pattern="organic", minor_pattern="radial")
    a = growth.grow_roads(BOX, settings=s, seed=11)
    b = growth.grow_roads(BOX, settings=s, seed=11)
    c = growth.grow_roads(BOX, settings=s, seed=12)
    assert (shapely.to_wkb(a.geometry) == shapely.to_wkb(b.geometry)).all()
    assert (a.level == b.level).all()
    assert len(a.geometry) != len(c.geometry) or \
        not (shapely.to_wkb(a.geometry) == shapely.to_wkb(c.geometry)).all()


def test_cancellation_raises():
    calls = []

    def canceled():
        calls.append(1)
        return len(calls) > 3

    with pytest.raises(Canceled):
        growth.grow_roads(BOX, settings=growth.GrowthSettings(major_pattern="organic"),
                          seed=1, progress=Progress(is_canceled=canceled))


def test_cap_stops_growth():
    r = growth.grow_roads(BOX, settings=growth.GrowthSettings(max_segments=40), seed=1)
    assert r.stats["segments"] == 40 and r.stats["capped"]


# --------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs, match", [
    ({"obstacles": BOX.buffer(10)}, "obstacles cover the whole boundary"),
    # the boundary moved by 5 cm (an obstacle equal to it, reprojected from another CRS):
    # a sliver along one side, nowhere a metre wide; growth stopped in a numpy error
    ({"obstacles": shapely.affinity.translate(BOX, 0.05, 0)},
     "obstacles cover the whole boundary"),
    ({"boundary": shapely.box(0, 0, 5, 5)}, "too small"),
    ({"boundary": shapely.LineString([(0, 0), (1, 1)])}, "no polygon"),
    ({"settings": growth.GrowthSettings(snap_distance=40)}, "snap_distance"),
    ({"settings": growth.GrowthSettings(major_pattern="spiral")}, "major_pattern"),
    ({"settings": growth.GrowthSettings(minor_length=1e6)}, "minor_length"),
    ({"settings": growth.GrowthSettings(min_street_distance=100)}, "min_street_distance"),
    ({"center": (np.nan, 0)}, "centre"),
])
def test_bad_input(kwargs, match):
    boundary = kwargs.pop("boundary", BOX)
    with pytest.raises(InputError, match=match):
        growth.grow_roads(boundary, seed=1, **kwargs)


# --------------------------------------------------------------------------- helpers

def test_segment_slopes_on_a_plane():
    # z = 0.1 x: a line along x climbs 10 %, along y not at all, diagonally 7.07 %
    xs = np.arange(0, 200, 2.0)
    z = np.tile(0.1 * (xs + 1.0), (100, 1))
    dem = (z, (0.0, 2.0, 0.0, 200.0, 0.0, -2.0))
    lines = [shapely.LineString([(20, 50), (150, 50)]), shapely.LineString([(50, 20), (50, 150)]),
             shapely.LineString([(20, 20), (120, 120)])]
    expected = [0.1, 0.0, 0.1 / np.sqrt(2)]
    np.testing.assert_allclose(growth.segment_slopes(lines, dem), expected, atol=1e-9)
    np.testing.assert_allclose(growth.chord_slopes(lines, dem, 3.0), expected, atol=1e-9)


def test_segment_slopes_bound_any_sampling():
    """The exact bilinear grade is at least every chord grade, however fine the chords."""
    dem = _hill(cell=7.0)
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 1000, (200, 2))
    q = p + rng.uniform(-80, 80, (200, 2))
    lines = shapely.linestrings(np.stack([p, q], axis=1))
    exact = growth.segment_slopes(lines, dem)
    for step in (10.0, 1.0, 0.1):
        chords = growth.chord_slopes(lines, dem, step)
        assert (chords <= exact + 1e-12).all()
    assert np.allclose(growth.chord_slopes(lines, dem, 0.05), exact, rtol=0.02, atol=1e-4)


def test_network_statistics_of_a_perfect_grid():
    lines = [shapely.LineString([(0, y), (300, y)]) for y in (0, 100, 200, 300)] + \
            [shapely.LineString([(x, 0), (x, 300)]) for x in (0, 100, 200, 300)]
    st = growth.network_statistics(lines)
    assert st["orientation_entropy"] == pytest.approx(np.log(4), abs=1e-9)
    assert st["mean_abs_angle_dev_90"] == pytest.approx(0.0, abs=1e-9)
    assert st["segment_length_median"] == pytest.approx(100.0)


def test_bulged_hull_without_a_boundary_and_dead_ends_removed():
    """Scharl sec. 4.2.5: without a boundary the outskirts are closed by the convex hull of
    the major nodes, its sides split in four and bulged outwards at random; Fig. 4.12: the
    dead-end roads are removed at the end."""
    from urban_synthesis.plugin.retrieval.shape_context import DemGrid

    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 500, (40, 2))
    hull = growth.bulged_hull(pts, np.random.default_rng(1))
    convex = shapely.convex_hull(shapely.multipoints(pts))
    n_hull = len(shapely.get_coordinates(convex)) - 1
    # 4 sides per hull side, every new node pushed out: the bulged outline contains the
    # hull, is larger, and is not convex in general
    assert len(shapely.get_coordinates(hull)) - 1 == 4 * n_hull
    assert hull.is_valid and hull.buffer(1e-6).contains(convex) and hull.area > convex.area
    assert shapely.convex_hull(hull).area > hull.area
    # the same seed, the same outline
    again = growth.bulged_hull(pts, np.random.default_rng(1))
    assert shapely.equals_exact(hull, again, 0)

    flat = DemGrid(np.zeros((100, 100)), (0, 10, 0, 1000, 0, -10))
    res = growth.grow_roads(None, dem=flat, seed=3)
    assert res.stats["bulged_hull"] and res.stats["quarters"] >= 4
    # minor roads fill the outskirts beyond the outermost major roads
    major = shapely.union_all(res.geometry[res.level == growth.MAJOR])
    minor = res.geometry[res.level == growth.MINOR]
    assert (shapely.length(minor) > 0).sum() > 50
    assert shapely.within(shapely.union_all(res.geometry), shapely.box(0, 0, 1000, 1000)
                          .buffer(1e-6))
    assert not shapely.within(shapely.union_all(minor), shapely.convex_hull(major))
    # no dead end is left, and pruning only removed grown edges
    stats = growth.network_statistics(res.geometry)
    assert stats["dead_ends_per_km2"] == 0 and res.stats["dead_ends_removed"] > 0
    kept = growth.grow_roads(None, dem=flat, seed=3,
                             settings=growth.GrowthSettings(remove_dead_ends=False))
    assert growth.network_statistics(kept.geometry)["dead_ends_per_km2"] > 0
    assert len(kept.geometry) == len(res.geometry) + res.stats["dead_ends_removed"]
    with pytest.raises(InputError, match="no boundary"):
        growth.grow_roads(None, seed=1)


def test_pieces_apart_and_dead_ends_left_are_counted():
    """What the log warns of when linking or pruning could not do all (steep terrain): a
    T of grown roads on a sketched road, and a grown road apart from it."""
    lines = np.array([shapely.LineString([(0, 0), (50, 0)]),        # sketched (noded)
                      shapely.LineString([(50, 0), (100, 0)]),      # sketched
                      shapely.LineString([(50, 0), (50, 60)]),      # grown, a dead end
                      shapely.LineString([(0, 200), (80, 200)])],   # grown, apart
                     dtype=object)
    result = growth.GrowthResult(lines, np.array([0, 0, 1, 1]),
                                 np.array(["sketch", "sketch", "grid", "organic"],
                                          dtype=object), np.full(4, 8.0), {})
    assert growth.pieces_and_dead_ends(result) == (1, 3)
    # without a sketch, every piece besides one is apart
    result.pattern[:2] = "grid"
    assert growth.pieces_and_dead_ends(result)[0] == 1
