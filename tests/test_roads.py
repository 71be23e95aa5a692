"""Engine tests of road cleaning: hand-made cases with known answers + invariants on Helsinki."""
import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.network.invariants import check_network

from helpers import assert_planar, helsinki_roads, liechtenstein_roads, nearly_coincident_streets


def test_crossing_lines_are_noded():
    g = roads.clean_network([LineString([(0, 0), (100, 0)]), LineString([(50, -50), (50, 50)])])
    assert g.n_edges == 4
    assert len(g.nodes) == 5
    assert sorted(g.degree) == [1, 1, 1, 1, 4]


def test_bridge_does_not_connect_to_road_below():
    g = roads.clean_network([LineString([(0, 0), (100, 0)]), LineString([(50, -50), (50, 50)])],
                            z_layer=[0, 1])
    assert g.n_edges == 2
    assert sorted(g.degree) == [1, 1, 1, 1]


def test_bridge_connects_where_it_shares_a_node():
    # the bridge starts on a vertex (an OSM node) of the ground road
    ground = LineString([(0, 0), (50, 0), (100, 0)])
    bridge = LineString([(50, 0), (50, 80)])
    g = roads.clean_network([ground, bridge], z_layer=[0, 1])
    assert g.n_edges == 3
    assert sorted(g.degree) == [1, 1, 1, 3]


def test_a_bridge_is_not_merged_into_its_approaches():
    # long ground approaches, a short bridge over a road: merged, the chain took the ground
    # layer of its longest part and crossed the road below without a junction
    approaches = [LineString([(0, 0), (200, 0)]), LineString([(230, 0), (430, 0)])]
    bridge = LineString([(200, 0), (230, 0)])
    below = LineString([(215, -100), (215, 100)])
    g = roads.clean_network(approaches + [bridge, below], z_layer=[0, 0, 1, 0],
                            min_dangle_length=0)
    assert sorted(np.round(g.length[g.z_layer == 1]).tolist()) == [30]
    assert_planar(g.geometry, g.z_layer)


def test_degree2_chains_are_merged_with_longest_part_attributes():
    parts = [LineString([(0, 0), (10, 0)]), LineString([(10, 0), (60, 0)]),
             LineString([(60, 0), (70, 5)])]
    g = roads.clean_network(parts, road_class=["service", "residential", "service"],
                            min_dangle_length=0)
    assert g.n_edges == 1
    assert g.road_class[0] == "residential"
    assert g.length[0] == pytest.approx(10 + 50 + np.hypot(10, 5))


def test_duplicates_and_reversed_duplicates_are_dropped():
    a = LineString([(0, 0), (100, 0)])
    g = roads.clean_network([a, a.reverse(), LineString([(0, 0), (100, 0.2)])],
                            road_class=["residential", "primary", "residential"])
    assert g.n_edges == 1
    assert g.road_class[0] == "primary"  # the more important duplicate is kept


def test_short_dangles_are_pruned_long_ones_kept():
    base = [LineString([(0, 0), (100, 0)]), LineString([(0, 0), (0, 100)]),
            LineString([(0, 100), (100, 100)]), LineString([(100, 0), (100, 100)])]
    stub = LineString([(50, 0), (50, 2)])
    street = LineString([(50, 100), (50, 60)])
    g = roads.clean_network(base + [stub, street], min_dangle_length=5.0)
    lengths = np.sort(g.length)
    assert lengths[0] == pytest.approx(40.0)  # the 40 m dead end survives
    assert not np.any(np.isclose(lengths, 2.0))


def test_close_nodes_are_snapped():
    g = roads.clean_network([LineString([(0, 0), (100, 0)]), LineString([(100.4, 0.3), (200, 0)]),
                             LineString([(100, 0), (100, 100)])], snap_tolerance=1.0)
    assert sorted(g.degree) == [1, 1, 1, 3]


def test_snapped_ends_that_now_cross_a_street_are_noded():
    """Two dead ends 5 m apart on either side of a road, merged at a 10 m snapping tolerance:
    the street they make crosses the road, and the crossing is a junction (snapping moved
    the ends after the noding, and the street crossed the road without one). At the
    default 1 m they stay two dead ends beside an unbroken road."""
    road = LineString([(0, 0), (100, 0)])
    north, south = LineString([(50, 50), (50, 2)]), LineString([(50, -50), (50, -3)])
    g = roads.clean_network([road, north, south], snap_tolerance=10.0)
    assert g.n_edges == 4 and sorted(g.degree) == [1, 1, 1, 1, 4]
    assert_planar(g.geometry)
    apart = roads.clean_network([road, north, south])
    assert apart.n_edges == 3 and sorted(apart.degree) == [1] * 6


@pytest.mark.parametrize("snap_tolerance", [20.0, 50.0])
@pytest.mark.parametrize("place", ["helsinki", "liechtenstein"])
def test_large_snapping_tolerances_keep_the_network_planar(place, snap_tolerance):
    """Up to the largest SNAP_TOLERANCE (50 m), every crossing of two edges of one vertical
    layer is a node and no edge runs back over itself. Moved ends crossed edges without a
    junction (Liechtenstein: 13 crossings at 50 m; Helsinki: 2 at 20 m, 16 at 50 m), and a
    stub whose far end merged with its start doubled back over itself."""
    df = helsinki_roads() if place == "helsinki" else liechtenstein_roads()
    g = roads.clean_network(df.geometry.values, df.highway.values, df.name.values, df.z.values,
                            snap_tolerance=snap_tolerance)
    check = check_network(g.geometry, synthesised_layer=g.z_layer, corridor_half_width=0)
    assert len(check.crossings_synthesised) == 0 and len(check.overlaps) == 0
    assert shapely.is_simple(g.geometry).all()
    assert_planar(g.geometry, g.z_layer)


def _farthest_end_from_its_street(g, lines):
    """How far the graph's edge ends lie from the input line each edge came from: how far
    snapping moved them (m)."""
    own = np.asarray(lines, dtype=object)[g.source]
    return max(shapely.distance(shapely.points(g.nodes[g.u]), own).max(),
               shapely.distance(shapely.points(g.nodes[g.v]), own).max())


def test_snapping_does_not_chain_close_nodes():
    """Four streets ending in a row, each 0.8 x the tolerance from the next: two merged nodes
    of two ends each, none wider than the tolerance; merged in a chain, they were one node
    2.4 x the tolerance wide that moved the outer ends by 1.2 x it."""
    tol = 10.0
    streets = [LineString([(8.0 * i, 0), (50.0 * i, 100)]) for i in range(4)]  # fanning out
    g = roads.clean_network(streets, snap_tolerance=tol, min_dangle_length=0.0,
                            merge_degree2=False)
    assert g.n_edges == 4 and sorted(g.degree) == [1, 1, 1, 1, 2, 2]
    bottom = g.nodes[g.degree == 2]
    assert sorted(map(tuple, bottom.round(9).tolist())) == [(4.0, 0.0), (20.0, 0.0)]
    assert _farthest_end_from_its_street(g, streets) == pytest.approx(4.0)
    labels = roads.snap_clusters(np.array([[8.0 * i, 0] for i in range(4)]), tol)
    assert labels.tolist() == [0, 0, 1, 1]


@pytest.mark.parametrize("place", ["helsinki", "liechtenstein"])
def test_snapped_nodes_are_no_wider_than_the_tolerance(place):
    """At the largest SNAP_TOLERANCE (50 m) no group of merged nodes is wider than 50 m, and
    no edge end is moved farther than that from its street. Chained, the merged nodes were
    up to 381 m apart on Liechtenstein and 838 m on Helsinki (228 nodes in one), and ends
    moved up to 182 m and 475 m off their street."""
    tol = 50.0
    df = helsinki_roads() if place == "helsinki" else liechtenstein_roads()
    ends = shapely.get_coordinates(shapely.boundary(roads.node_lines(df.geometry.values)))
    ends = np.unique(ends, axis=0)
    labels = roads.snap_clusters(ends, tol)
    order = np.argsort(labels, kind="stable")
    groups = np.split(ends[order], np.flatnonzero(np.diff(labels[order])) + 1)
    assert max(len(p) for p in groups) > 2  # the clustering does have work to do
    span = max(np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)).max() for p in groups)
    assert span <= tol
    g = roads.clean_network(df.geometry.values, df.highway.values, df.name.values, df.z.values,
                            snap_tolerance=tol, min_dangle_length=0.0, merge_degree2=False)
    assert _farthest_end_from_its_street(g, df.geometry.values) <= tol


def test_an_end_a_rounding_error_off_a_street_is_a_junction():
    """A street put onto another by interpolation ends 1e-5 m beside it: one T junction
    (degrees 1, 1, 1 and 3), not a dead end beside an unbroken street; with snapping off (0)
    the lines are noded as they are."""
    main = LineString([(0, 0), (100, 0)])
    side = LineString([(40, 50), (40.0, 1e-5)])
    g = roads.clean_network([main, side], min_dangle_length=0.0, merge_degree2=False)
    assert g.n_edges == 3 and sorted(g.degree) == [1, 1, 1, 3]
    plain = roads.clean_network([main, side], snap_tolerance=0.0, min_dangle_length=0.0,
                                merge_degree2=False)
    assert plain.n_edges == 2 and sorted(plain.degree) == [1, 1, 1, 1]
    # a centimetre off is no junction (a gap, for the undershoot checks to report)
    apart = roads.clean_network([main, LineString([(40, 50), (40, 0.01)])],
                                min_dangle_length=0.0, merge_degree2=False)
    assert apart.n_edges == 2


@pytest.mark.parametrize("snap_tolerance", [1.0, 0.0])
def test_nearly_coincident_lines_are_noded_on_a_millimetre_grid(snap_tolerance):
    """Three streets that run within micrometres of each other defeat GEOS's floating-point
    noding (GEOS 3.11: "noding failed to converge"); the cleaning nodes them by
    snap-rounding instead: a planar network that keeps every street to the cleaning's
    tolerance (near-duplicates merge within the snapping distance, else the millimetre grid)."""
    lines = nearly_coincident_streets()
    g = roads.clean_network(lines, snap_tolerance=snap_tolerance, min_dangle_length=0.0,
                            merge_degree2=False)
    assert_planar(g.geometry, g.z_layer)
    network = shapely.buffer(shapely.union_all(g.geometry),
                             max(snap_tolerance, roads.JUNCTION_TOLERANCE))
    assert shapely.covers(network, lines).all()


def test_other_tags_and_vertical_layer():
    tags = roads.parse_other_tags('"bridge"=>"yes","layer"=>"2","name:fi"=>"Katu \\"x\\""')
    assert tags == {"bridge": "yes", "layer": "2", "name:fi": 'Katu "x"'}
    assert roads.vertical_layer("2", "yes", None) == 2
    assert roads.vertical_layer(None, "yes", None) == 1
    assert roads.vertical_layer(None, None, "yes") == -1
    assert roads.vertical_layer("x", None, None) == 0
    assert roads.parse_other_tags(None) == {}


def test_bad_input_raises_input_error():
    with pytest.raises(InputError):
        roads.clean_network([])
    with pytest.raises(InputError):
        roads.clean_network([LineString([(0, 0), (0, 0)])])
    with pytest.raises(InputError):
        roads.clean_network([LineString([(0, 0), (1, 0)])], snap_tolerance=-1)


def test_cancel_stops_cleaning():
    with pytest.raises(Canceled):
        roads.clean_network([LineString([(0, 0), (1, 0)])], progress=Progress(is_canceled=lambda: True))


def test_helsinki_graph_invariants():
    df = helsinki_roads()
    g = roads.clean_network(df.geometry.values, df.highway.values, df.name.values, df.z.values)
    assert g.n_edges > 150
    assert (g.length > 0).all()
    # no degree-2 nodes are left except on isolated rings (u == v) and where a bridge or
    # tunnel meets its approach (two vertical layers)
    deg = g.degree
    ring_nodes = set(g.u[g.u == g.v])
    layers = [set(g.z_layer[(g.u == n) | (g.v == n)]) for n in np.flatnonzero(deg == 2)]
    assert all(n in ring_nodes or len(z) == 2
               for n, z in zip(np.flatnonzero(deg == 2), layers))
    assert sum(len(z) == 2 for z in layers) > 0  # Helsinki has bridges
    # no duplicate edges
    lo, hi = np.minimum(g.u, g.v), np.maximum(g.u, g.v)
    pairs = set()
    for i, (a, b) in enumerate(zip(lo, hi)):
        if (a, b) in pairs:
            others = [j for j in range(i) if (lo[j], hi[j]) == (a, b)]
            assert all(shapely.hausdorff_distance(g.geometry[i], g.geometry[j]) > 1.0 for j in others)
        pairs.add((a, b))
    assert_planar(g.geometry, g.z_layer)


def test_a_loop_under_a_millimetre_is_no_street():
    """A loop 0.4 mm long at a junction (left by noding or snapping) is a point once its ends
    are pinned onto its node: merging the chains made it an empty line and the graph's
    ends and edges fell out of step (a ValueError on splitdomain's Vaduz network)."""
    lines = [LineString([(0, 0), (10, 0)]), LineString([(10, 0), (20, 0)]),
             LineString([(20, 0), (30, 5)]), LineString([(20, 0), (20, 8)]),
             LineString([(20, 0), (20.0004, 0.0001)])]
    g = roads.graph_from_lines(lines, [None] * 5, [None] * 5, [0] * 5, list(range(5)))
    merged = roads.merge_degree2_chains(g)
    assert sorted(np.round(merged.length, 4).tolist()) == [8.0, 11.1803, 20.0]
    assert sorted(merged.degree.tolist()) == [1, 1, 1, 3]
