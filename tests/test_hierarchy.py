"""Engine tests of streets, stream-order levels and intersection attributes."""
import numpy as np
import pytest
from shapely.geometry import LineString

from urban_synthesis.plugin.network import hierarchy
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.core.progress import InputError

from helpers import helsinki_roads


def fishbone():
    """A primary road (y=0), residential side streets every 100 m, and a lane off each."""
    lines = [LineString([(0, 0), (500, 0)])]
    classes = ["primary"]
    for x in (100, 200, 300, 400):
        lines.append(LineString([(x, 0), (x, 200)]))
        classes.append("residential")
        lines.append(LineString([(x, 100), (x + 40, 100)]))
        classes.append("residential")
    return roads.clean_network(lines, road_class=classes, min_dangle_length=0), classes


def test_straight_roads_through_crossing_form_two_streets():
    g = roads.clean_network([LineString([(0, 0), (200, 0)]), LineString([(100, -100), (100, 100)])])
    s = hierarchy.build_streets(g)
    assert s.n == 2
    assert sorted(s.length) == pytest.approx([200, 200])
    assert s.straightness == pytest.approx([1, 1])


def test_sharp_turn_ends_a_street():
    g = roads.clean_network([LineString([(0, 0), (100, 0)]), LineString([(100, 0), (100, 100)]),
                             LineString([(100, 0), (200, 0)])], min_dangle_length=0)
    s = hierarchy.build_streets(g, max_deflection=45)
    assert s.n == 2  # the straight road, and the perpendicular branch


def test_stream_order_levels_on_fishbone():
    g, _ = fishbone()
    h = hierarchy.road_hierarchy(g, method="osm")
    level = h.edge_level
    cls = g.road_class
    assert set(level[cls == "primary"]) == {0}
    # side streets meet the primary -> 1; lanes meet side streets -> 2
    lane = np.isclose(g.length, 40)
    assert set(level[lane]) == {2}
    assert set(level[(cls == "residential") & ~lane]) == {1}


def test_loops_are_handled_and_every_street_is_labelled():
    # arterial with a residential loop attached at two points and a cul-de-sac off the loop
    lines = [LineString([(0, 0), (400, 0)]),
             LineString([(100, 0), (100, 100), (300, 100), (300, 0)]),
             LineString([(200, 100), (200, 160)])]
    g = roads.clean_network(lines, road_class=["primary", "residential", "residential"])
    h = hierarchy.road_hierarchy(g, method="osm")
    assert (h.street_level >= 0).all()
    assert h.edge_level[g.road_class == "primary"].max() == 0
    assert sorted(set(h.edge_level)) == [0, 1, 2]


def test_topological_method_picks_longest_straightest_street():
    lines = [LineString([(0, 0), (1000, 0)])] + \
            [LineString([(x, 0), (x, 80)]) for x in range(100, 1000, 100)]
    g = roads.clean_network(lines)
    h = hierarchy.road_hierarchy(g, method="topological", arterial_share=0.5)
    long_edges = g.geometry[h.edge_level == 0]
    assert all(abs(geom.coords[0][1]) < 1e-9 and abs(geom.coords[-1][1]) < 1e-9 for geom in long_edges)
    assert set(h.edge_level) == {0, 1}


def test_disconnected_part_without_arterial_starts_at_level_1():
    lines = [LineString([(0, 0), (100, 0)]), LineString([(0, 500), (100, 500)]),
             LineString([(50, 500), (50, 560)])]
    g = roads.clean_network(lines, road_class=["primary", "residential", "residential"])
    level, kind = hierarchy.assign_levels(g, hierarchy.build_streets(g), method="osm")
    assert sorted(level) == [0, 1, 2]
    assert "component" in set(kind)


def test_bad_method_and_share():
    g, _ = fishbone()
    s = hierarchy.build_streets(g)
    with pytest.raises(InputError):
        hierarchy.assign_levels(g, s, method="nope")
    with pytest.raises(InputError):
        hierarchy.assign_levels(g, s, arterial_share=0)


def test_grid_intersection_attributes():
    lines = [LineString([(0, y), (300, y)]) for y in (0, 100, 200, 300)] + \
            [LineString([(x, 0), (x, 300)]) for x in (0, 100, 200, 300)]
    g = roads.clean_network(lines)
    h = hierarchy.road_hierarchy(g, method="topological", arterial_share=0.2)
    df = hierarchy.intersection_attributes(g, h.streets, h.street_level)
    # the four corners have degree 2: merged away, they are no intersections
    assert len(df) == 12
    assert (df.degree.values >= 3).all()
    inner = df[df.degree == 4]
    assert len(inner) == 4
    assert inner.dist_mean_a.values == pytest.approx(100)
    assert inner.dist_var_a.values == pytest.approx(0, abs=1e-6)
    assert inner.angle_mean_a.values == pytest.approx(0, abs=1e-6)
    assert inner.tortuosity_a.values == pytest.approx(1)
    assert inner.block_area.values == pytest.approx(10000)
    # street a is never less important than street b
    both = df.dropna(subset=["level_b"])
    assert (both.level_a <= both.level_b).all()


def test_tortuosity_of_a_curved_street():
    arc = LineString([(0, 0), (50, 30), (100, 0)])
    g = roads.clean_network([arc, LineString([(100, 0), (200, 0)]), LineString([(100, 0), (100, -50)])],
                            min_dangle_length=0)
    # 31 degrees of deflection: with a 20 degree limit the arc is a street of its own
    h = hierarchy.road_hierarchy(g, method="topological", max_deflection=20)
    df = hierarchy.intersection_attributes(g, h.streets, h.street_level)
    expected = 2 * np.hypot(50, 30) / 100
    assert np.nanmax(df[["tortuosity_a", "tortuosity_b"]].values) == pytest.approx(expected)


def test_helsinki_levels_and_attributes():
    df = helsinki_roads()
    g = roads.clean_network(df.geometry.values, df.highway.values, df.name.values, df.z.values)
    h = hierarchy.road_hierarchy(g)
    levels = np.bincount(h.street_level)
    # the thesis: "typically four to five street levels"
    assert 3 <= len(levels) <= 6
    assert (h.edge_level[np.isin(g.road_class, ["primary", "secondary"])] == 0).all()
    ia = hierarchy.intersection_attributes(g, h.streets, h.street_level)
    assert len(ia) == len(g.nodes)
    assert ia.level_a.notna().all()
    assert (ia.tortuosity_a.dropna() >= 1 - 1e-6).all()
    assert (ia.angle_mean_a.dropna().between(0, 180)).all()
    assert ia.block_area.notna().mean() > 0.5
