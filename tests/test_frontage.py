"""Engine tests of plugin/buildings/frontage.py and its use by the footprint synthesis.

- Axes and angles to the street against an independent per-polygon computation on random
  rotated rectangles and L-shapes (seeded).
- align_to_frontage gives every footprint near a street its example angle, leaves the
  others, and moves nothing but by a rotation about the centroid (congruent copies).
- Through the block transfer and the re-synthesis: footprints that face their street in
  the example block face it in a block of another shape (a rigid fit alone turns them);
  trimmed slivers below the example's 10th percentile area are dropped.
"""
import math

import numpy as np
import pytest
import shapely

from test_footprints import assert_legal
from urban_synthesis.plugin.buildings import footprints
from urban_synthesis.plugin.core.geometry import largest_polygons
from urban_synthesis.plugin.buildings import frontage as fr
from urban_synthesis.plugin.retrieval import database


def rotated_box(cx, cy, w, h, deg):
    box = shapely.box(-w / 2, -h / 2, w / 2, h / 2)
    a = math.radians(deg)
    xy = shapely.get_coordinates(box)
    rot = xy @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
    return shapely.Polygon(rot + [cx, cy])


def brute_street_angle(poly, lines):
    """Per polygon: long side of shapely's minimum rotated rectangle; nearest line
    segment by distance over all segments; folded difference in degrees."""
    rect = np.asarray(poly.minimum_rotated_rectangle.exterior.coords)
    sides = np.diff(rect, axis=0)[:2]
    v = sides[np.argmax(np.hypot(*sides.T))]
    axis = math.atan2(v[1], v[0])
    best = None
    for ln in lines:
        xy = np.asarray(ln.coords)
        for a, b in zip(xy[:-1], xy[1:]):
            d = shapely.LineString([a, b]).distance(poly)
            if best is None or d < best[0]:
                best = (d, math.atan2(b[1] - a[1], b[0] - a[0]))
    diff = (axis - best[1] + math.pi / 4) % (math.pi / 2) - math.pi / 4
    return abs(math.degrees(diff))


@pytest.mark.parametrize("seed", range(5))
def test_street_angle_matches_a_direct_computation(seed):
    rng = np.random.default_rng(seed)
    lines = [shapely.LineString(rng.uniform(0, 200, (4, 2))) for _ in range(3)]
    polys = []
    for _ in range(25):
        cx, cy = rng.uniform(20, 180, 2)
        w, h = rng.uniform(5, 30, 2)
        p = rotated_box(cx, cy, w, h, rng.uniform(-90, 90))
        if rng.random() < 0.4:   # an L-shape
            p = shapely.difference(p, rotated_box(cx + w / 4, cy + h / 4, w / 2, h / 2, 0))
            p = largest_polygons(np.array([p], dtype=object))[0]
        d = sorted(shapely.LineString([a, b]).distance(p) for ln in lines
                   for a, b in zip(np.asarray(ln.coords)[:-1], np.asarray(ln.coords)[1:]))
        if d[1] - d[0] > 1e-3:       # a unique nearest segment (no tie, no crossing)
            polys.append(p)
    assert len(polys) >= 10
    got = fr.street_angle(polys, lines)
    want = [brute_street_angle(p, lines) for p in polys]
    assert np.all((got >= 0) & (got <= 45))
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_main_axis_of_rotated_rectangles():
    for deg in (-60, -7, 0, 12, 33, 80):
        axis = math.degrees(fr.main_axis([rotated_box(0, 0, 20, 8, deg)])[0])
        assert (axis - deg) % 180 == pytest.approx(0, abs=1e-6) or \
            (axis - deg) % 180 == pytest.approx(180, abs=1e-6)


def test_align_to_frontage_keeps_the_example_angle():
    street = shapely.LineString([(0, 0), (200, 70)])          # about 19.3° to the x axis
    theta = math.degrees(math.atan2(70, 200))
    near = [rotated_box(x, 0.35 * x + 15, 12, 8, 0.0) for x in (30, 80, 130)]
    far = [rotated_box(100, 150, 12, 8, 5.0)]
    polys = np.array(near + far, dtype=object)
    wanted = np.radians([0.0, 8.0, -20.0, 0.0])
    out, turn = fr.align_to_frontage(polys, wanted, fr.street_segments([street]))
    rel, dist = fr.relative_angle(out, fr.street_segments([street]))
    np.testing.assert_allclose(np.degrees(rel[:3]), [0.0, 8.0, -20.0], atol=1e-6)
    assert out[3].equals(polys[3]) and turn[3] == 0.0       # beyond reach: untouched
    assert math.degrees(turn[0]) == pytest.approx(theta)    # the smallest turn onto the street
    for a, b in zip(polys, out):   # a rotation about the centroid: congruent, same centre
        assert a.area == pytest.approx(b.area)
        assert shapely.centroid(a).distance(shapely.centroid(b)) < 1e-9
        assert sorted(np.round(np.hypot(*np.diff(np.asarray(a.exterior.coords), axis=0).T), 6)) == \
            sorted(np.round(np.hypot(*np.diff(np.asarray(b.exterior.coords), axis=0).T), 6))
    # NaN: no example angle, left as it is
    out2, turn2 = fr.align_to_frontage(polys, np.full(4, np.nan), fr.street_segments([street]))
    assert (turn2 == 0).all()


def street_facing_database(path):
    """One 120 m x 70 m block with two rows of houses parallel to its long streets."""
    block = shapely.box(0, 0, 120, 70)
    houses = [shapely.box(x, 6, x + 14, 16) for x in range(8, 104, 20)] + \
             [shapely.box(x, 54, x + 14, 64) for x in range(8, 104, 20)]
    database.write_block_database(str(path), [block], houses, np.ones(len(houses), np.int64),
                                  "EPSG:32632")
    return footprints.prepare_examples(database.load_block_database(path), "rows")


@pytest.mark.parametrize("method", footprints.METHODS)
def test_footprints_face_the_streets_of_a_block_of_another_shape(tmp_path, method):
    ex = street_facing_database(tmp_path / "rows.gpkg")
    assert np.nanmax(np.abs(ex.frontage_angle)) < 1e-9
    # a trapezoid: its long sides 8° apart, so no rigid fit squares both rows
    target = shapely.Polygon([(0, 0), (124, 0), (118, 62), (6, 78)])
    r = footprints.synthesize_footprints([target], [ex], method, street_width=6.0)
    assert len(r.geometry) >= 6
    assert_legal(r.geometry, np.full(len(r.geometry), target, dtype=object),
                 shapely.difference(target, shapely.buffer(target, -3.0)))
    angles = fr.street_angle(r.geometry, [target.exterior])
    assert np.mean(angles <= 1.0) >= 0.9, np.round(angles, 1)
    # the rigid fit alone leaves a row turned by about half the 8°
    rigid = footprints._retrieve(target, [ex], -1, 1, np.random.default_rng(0))[1]
    moved = rigid.transform(ex.polygons)
    assert np.mean(fr.street_angle(moved, [target.exterior]) > 2.0) >= 0.4


def test_slivers_are_dropped_intact_footprints_kept():
    block = shapely.box(0, 0, 100, 100)
    big = shapely.box(10, 10, 40, 40)
    shed = shapely.box(60, 60, 64, 64)                 # 16 m², intact: kept
    sliver = shapely.box(37, 10, 44, 24)               # 57 % (56 m²) left after big
    blocker = shapely.box(60, 40, 64, 54)
    small_cut = shapely.box(63.9, 40, 70, 54)          # 85 m², loses < 10 %: kept
    polys = [big, shed, sliver, blocker, small_cut]
    out, idx, status = footprints.legalise(polys, [0, 1, 2, 3, 4], block, block,
                                           min_area=100.0)
    assert idx == [0, 1, 3, 4]
    assert status[idx.index(4)] == "trimmed"
    out, idx, _ = footprints.legalise(polys, [0, 1, 2, 3, 4], block, block, min_area=0.0)
    assert 2 in idx                                     # without the rule the sliver stays


@pytest.mark.parametrize("method", footprints.METHODS)
def test_cul_de_sac_is_filled_along_its_frontage(tmp_path, method):
    """A dead-end street inside the target block, which the example block did not have:
    with the frontage fill, houses stand along it (facing it), legally, up to the share of
    frontage the example block has built; without it the dead end stays bare."""
    ex = street_facing_database(tmp_path / "rows.gpkg")
    example_share = fr.served_share([ex.db.geometry[0]], ex.polygons)
    block = shapely.box(0, 0, 200, 160)
    dead_end = shapely.LineString([(100, 0), (100, 120)])
    roads = np.array([block.exterior, dead_end], dtype=object)
    runs = {}
    for fill in (False, True):
        layout = footprints.synthesize_block(block, [ex], method, roads=roads, fill=fill)
        runs[fill] = layout
        surface = shapely.buffer(shapely.union_all(roads), 3.0)
        assert_legal(layout.geometry, np.full(len(layout.geometry), block, dtype=object),
                     shapely.intersection(surface, block))
    filled = runs[True]
    added = np.array(filled.geometry, dtype=object)[(filled.table.placement == "filled").to_numpy()]
    assert filled.stats["n_filled"] == len(added) > 0
    inner = [shapely.intersection(dead_end, shapely.buffer(block, -0.5))]
    bare = fr.served_share(inner, runs[False].geometry)
    full = fr.served_share(inner, filled.geometry)
    assert bare < 0.9 and full >= example_share - 0.05
    # the block as a whole is built up to the example's share (here all its frontage)
    everything = [block.exterior, inner[0]]
    assert fr.served_share(everything, runs[False].geometry) < example_share - 0.1
    assert fr.served_share(everything, filled.geometry) >= example_share - 0.05
    # added houses face their street as the example's do (angle 0)
    assert np.max(fr.street_angle(added, roads)) < 1.0
    # same seed, same result
    again = footprints.synthesize_block(block, [ex], method, roads=roads)
    assert [g.wkb for g in again.geometry] == [g.wkb for g in filled.geometry]
