"""The shared rules of plugin/core: working CRS, identifiers, geometry helpers (one home
each, used by every stage that needs them)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.core import crs, geometry, ids
from urban_synthesis.plugin.core.progress import InputError


def test_working_crs_rule():
    # projected in metres: kept; Web Mercator and degrees: the UTM zone of the centre
    assert crs.working_crs("EPSG:32633", True, (14.4, 50.1)) is None
    assert crs.working_crs("EPSG:3857", True, (14.4, 50.1)) == "EPSG:32633"
    assert crs.working_crs("ESRI:102100", True, (14.4, 50.1)) == "EPSG:32633"
    assert crs.working_crs("EPSG:4326", False, (24.9, 60.2)) == "EPSG:32635"
    assert crs.working_crs(None, False, (-70.6, -33.4)) == "EPSG:32719"
    assert crs.working_crs("EPSG:4326", False, (179.99, 0.0)) == "EPSG:32660"
    calls = []
    assert crs.working_crs("EPSG:2056", True, lambda: calls.append(1)) is None
    assert not calls                     # the centre is computed only when needed
    with pytest.raises(InputError, match="not finite"):
        crs.working_crs("EPSG:4326", False, (float("nan"), 0.0))
    # a projected CRS in metres whose scale at the data is more than 1 % off true (World
    # Mercator, a plate carree in metres: 1.56 x at 50 degrees) is replaced as Web Mercator is
    assert crs.working_crs("EPSG:3395", True, (14.4, 50.1), lambda: 0.56) == "EPSG:32633"
    assert crs.working_crs("EPSG:4087", True, (14.4, 50.1), lambda: 0.56) == "EPSG:32633"
    assert crs.working_crs("EPSG:3035", True, (-9.1, 38.7), lambda: 0.003) is None
    assert crs.working_crs("EPSG:3395", True, (14.4, 50.1), lambda: float("nan")) is None


def test_the_dask_runner_uses_the_same_rule():
    from urban_synthesis.plugin.scale import distributed

    assert distributed.metric_crs("EPSG:4326", (24.9, 60.1, 25.0, 60.2)) == "EPSG:32635"
    assert distributed.metric_crs("EPSG:3857", (14.3, 50.0, 14.4, 50.1)) == "EPSG:32633"
    assert "UTM zone 35N" in distributed.metric_crs("EPSG:32635", (24.9, 60.1, 25.0, 60.2))
    # PROJ's scale factors: World Mercator and a plate carree in metres are not true at 47 N,
    # Europe's equal-area grid is within 0.3 % even at Lisbon
    for stretched in ("EPSG:3395", "EPSG:4087"):
        assert distributed.metric_crs(stretched, (9.5, 47.0, 9.6, 47.2)) == "EPSG:32632"
    assert "LAEA" in distributed.metric_crs("EPSG:3035", (-9.2, 38.6, -9.0, 38.8))
    with pytest.raises(InputError, match="no coordinate reference system"):
        distributed.metric_crs(None, (24.9, 60.1, 25.0, 60.2))


def test_whole_ids_are_never_truncated():
    assert ids.whole_ids([4, 2, 9]).tolist() == [4, 2, 9]
    assert ids.whole_ids(np.array(["4", "2"], dtype=object)).tolist() == [4, 2]
    for bad in ([1.5, 2], [1, 1], [1, None], ["a", 2], [], [2 ** 60, 1]):
        assert ids.whole_ids(bad) is None, bad
    assert ids.ids_or_numbers([1.5, 7]).tolist() == [1, 2]
    assert ids.ids_or_numbers(None, 3).tolist() == [1, 2, 3]


def test_minimum_rectangles_match_shapely():
    rng = np.random.default_rng(3)
    polys = [shapely.convex_hull(shapely.multipoints(rng.normal(size=(12, 2)) * [40, 12]))
             for _ in range(60)]
    length, width, angle = geometry.minimum_rectangles(polys)
    corners = geometry.minimum_rectangle_corners(polys)
    for p, a, b, c in zip(polys, length, width, corners):
        ref = shapely.minimum_rotated_rectangle(p)
        assert a * b == pytest.approx(ref.area, rel=1e-9)
        rect = shapely.Polygon(c)
        assert rect.is_valid and rect.area == pytest.approx(ref.area, rel=1e-9)
        assert rect.buffer(1e-6).covers(p)
    # the long side's direction
    box = shapely.affinity.rotate(shapely.box(0, 0, 50, 10), 120, origin=(0, 0))
    assert geometry.minimum_rectangles([box])[2][0] == pytest.approx(120.0)
    # degenerate input: zero sides, a flat rectangle along a line
    line = shapely.LineString([(0, 0), (3, 4)])
    assert geometry.minimum_rectangles([line])[0].tolist() == [0.0]
    assert geometry.minimum_rectangle_corners([line])[0].tolist() == \
        [[0, 0], [3, 4], [3, 4], [0, 0]]


def test_largest_polygons_and_substrings():
    two = shapely.MultiPolygon([shapely.box(0, 0, 1, 1), shapely.box(5, 5, 8, 8)])
    assert geometry.largest_polygons([two, None])[0].equals(shapely.box(5, 5, 8, 8))
    line = shapely.LineString([(0, 0), (10, 0), (10, 10)])
    pieces = geometry.substrings([line] * 3, np.array([0.0, 5.0, 9.0]),
                                 np.array([10.0, 15.0, 20.0]))
    assert shapely.length(pieces).tolist() == [10.0, 10.0, 11.0]
    assert shapely.equals(pieces[1], shapely.LineString([(5, 0), (10, 0), (10, 5)]))
    starts = geometry.group_starts(np.array([3, 3, 1, 1, 1, 2]))
    assert np.flatnonzero(starts).tolist() == [0, 2, 5]


def test_rounded_bends_keeps_holes_of_any_vertex_count():
    """A region with a round hole (a 16-gon: bends of 22.5 degrees, rounded) and a square
    hole (corners, kept): both holes survive as rings of different lengths. The sweep's
    region of cadastre plots failed here (the holes as one coordinate array)."""
    outer = shapely.box(-300, -300, 300, 300)
    round_hole = shapely.Point(-120, 0).buffer(60, quad_segs=4)
    square_hole = shapely.box(80, -40, 160, 40)
    region = shapely.Polygon(outer.exterior.coords,
                             [round_hole.exterior.coords, square_hole.exterior.coords])
    out = geometry.rounded_bends(region, max_turn=35.0, reach=7.5)
    assert out.is_valid and len(out.interiors) == 2
    counts = sorted(len(r.coords) for r in out.interiors)
    assert counts[0] == 5 and counts[1] > 17   # the square as it was, the 16-gon rounded
    assert shapely.hausdorff_distance(out, region) < 1.0


def test_first_hits_are_the_nearest_crossings_shapely_finds():
    # a concave outline with a hole: rays from inside meet it once or many times
    rng = np.random.default_rng(4)
    region = shapely.Polygon([(0, 0), (100, 0), (100, 60), (60, 60), (60, 20), (40, 20),
                              (40, 60), (0, 60)], [[(10, 10), (20, 10), (20, 20), (10, 20)]])
    outline = shapely.boundary(region)
    origins = np.column_stack([rng.uniform(0, 100, 300), rng.uniform(0, 60, 300)])
    origins = origins[shapely.contains_xy(region, *origins.T)]
    angle = rng.uniform(0, 2 * np.pi, len(origins))
    directions = np.column_stack([np.cos(angle), np.sin(angle)])
    got = geometry.first_hits(origins, directions, [outline], reach=50.0, start=0.01)
    rays = shapely.linestrings(np.stack([origins + 0.01 * directions,
                                         origins + 50.0 * directions], axis=1))
    expected = shapely.distance(shapely.points(origins), shapely.intersection(rays, outline))
    assert np.isnan(got).sum() == np.isnan(expected).sum() > 0  # some rays end short of it
    np.testing.assert_allclose(got[~np.isnan(got)], expected[~np.isnan(expected)],
                               rtol=0, atol=1e-9)
