"""Engine tests of plugin.network.invariants: hand-made networks whose answer is known, and
real Helsinki streets checked against their own arterials (no QGIS)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.network import invariants as I

from helpers import nearly_coincident_streets

L = shapely.LineString
ARTERIAL = [L([(0, 0), (200, 0)])]


def test_street_drawn_over_an_arterial_is_a_crossing_and_floats():
    c = I.check_network([L([(100, -50), (100, 50)])], ARTERIAL)
    assert c.violations()["crossings_given"] == 1
    assert shapely.get_coordinates(c.crossings_given).tolist() == [[100.0, 0.0]]
    # a crossing does not connect: the street is a floating piece
    assert c.floating_pieces == 1 and c.n_components == 2 and not c.ok


def test_street_ending_on_an_arterial_is_a_junction():
    # the arterial has no vertex at x = 100: a T still joins the network
    c = I.check_network([L([(100, 0), (100, 80)])], ARTERIAL)
    assert c.ok and c.n_components == 1 and c.floating_pieces == 0


def test_street_through_a_shared_vertex_is_a_junction():
    given = [L([(0, 0), (100, 0), (200, 0)])]
    c = I.check_network([L([(100, -50), (100, 0), (100, 50)])], given)
    assert c.violations()["crossings_given"] == 0 and c.n_components == 1
    # a vertex on one side only is not enough
    c = I.check_network([L([(100, -50), (100, 50)])], given)
    assert c.violations()["crossings_given"] == 1


def test_end_within_the_tolerance_touches():
    near = L([(100, 1e-7), (100, 80)])     # interpolated onto the arterial up to round-off
    assert I.check_network([near], ARTERIAL).ok
    short = L([(100, 0.5), (100, 80)])     # half a metre short: floating, an undershoot
    c = I.check_network([short], ARTERIAL)
    assert c.floating_pieces == 1 and len(c.undershoots) == 1


def test_a_street_leaving_the_target_is_a_violation():
    """A street that cuts across the land between two arms of a concave target (the random
    walk's straight steps did, up to 1.7 km on the fidelity benchmark's towns) leaves the
    target; one along its edge, within a metre, does not; without a target the check does
    not run and is not reported (a study area may be smaller than the layout it measures)."""
    target = shapely.union_all([shapely.box(0, 0, 200, 60), shapely.box(0, 140, 200, 200),
                                shapely.box(0, 0, 40, 200)])               # a C shape
    across = L([(150, 30), (150, 170)])                                      # over the gap
    along = L([(40.5, 60), (40.5, 140)])                                     # its inner edge
    streets = [L([(100, 0), (100, 30)]), L([(100, 30), (150, 30)]), across, along]
    c = I.check_network(streets, ARTERIAL, target=target)
    assert c.violations()["outside_target"] == 1
    assert shapely.length(c.outside).sum() == pytest.approx(80.0 - 2 * I.EDGE_DISTANCE)
    unchecked = I.check_network(streets, ARTERIAL)   # no target: the check does not run
    assert unchecked.outside is None and "outside_target" not in unchecked.violations()
    assert "outside_target" not in set(unchecked.table().check) | set(unchecked.counts())
    kept = I.check_network(streets[:2] + [along], ARTERIAL, target=target)
    assert kept.violations()["outside_target"] == 0 and len(kept.outside) == 0


def test_synthesised_streets_crossing_each_other_and_themselves():
    streets = [L([(50, 0), (50, 100)]), L([(150, 0), (150, 100)]),
               L([(20, 50), (180, 50)]),                              # crosses both
               L([(60, 70), (90, 90), (90, 70), (60, 90)])]           # a bow tie
    c = I.check_network(streets, ARTERIAL)
    assert c.violations()["crossings_synthesised"] == 3
    xy = sorted(map(tuple, shapely.get_coordinates(c.crossings_synthesised).round(6)))
    assert xy == [(50.0, 50.0), (75.0, 80.0), (150.0, 50.0)]
    # noded, the same streets are a planar network with no crossing
    noded = shapely.get_parts(shapely.node(shapely.multilinestrings(streets[:3])))
    assert I.check_network(noded, ARTERIAL).violations()["crossings_synthesised"] == 0


def test_self_crossings_of_a_street_whose_noding_fails():
    """A street that runs back along itself within micrometres (GEOS's floating-point
    noding of it fails): it is snap-rounded, and its self-crossings lie on it."""
    a, b, c = nearly_coincident_streets()
    street = L(list(a.coords) + list(b.coords)[::-1] + list(c.coords))
    check = I.check_network([street])
    assert check.violations()["crossings_synthesised"] > 0
    assert (shapely.distance(check.crossings_synthesised, street) <= I.JUNCTION_TOLERANCE).all()


def test_crossing_count_agrees_with_pairwise_intersections():
    rng = np.random.default_rng(7)
    ends = rng.uniform(0, 500, (60, 2, 2))
    lines = shapely.linestrings(ends)
    # straight segments in general position: every intersecting pair is one crossing
    a, b = shapely.STRtree(lines).query(lines, predicate="intersects")
    expected = int((a < b).sum())
    c = I.check_network(lines)
    assert expected > 50
    assert c.violations()["crossings_synthesised"] == expected


def test_floating_pieces_without_and_with_given_roads():
    island = [L([(0, 300), (100, 300)]), L([(100, 300), (100, 400)])]
    c = I.check_network([L([(100, 0), (100, 80)])] + island, ARTERIAL)
    assert c.floating_pieces == 1 and c.n_components == 2
    # without given roads, every component after the first floats
    assert I.check_network(island + [L([(300, 0), (400, 0)])]).floating_pieces == 1


def test_parallel_duplicate_inside_the_corridor():
    beside = L([(20, 5), (180, 5)])             # 5 m off the arterial, 160 m long
    across = L([(100, 0), (100, 80)])            # leaves it at a right angle
    oblique = L([(100, 0), (160, 40)])           # at 34 degrees: 14 m in the corridor
    c = I.check_network([beside, across, oblique], ARTERIAL)
    assert c.violations()["parallel_duplicates"] == 1
    assert c.duplicates[0].length == pytest.approx(160.0)
    # 12 m away it is a street of its own (a frontage road), not a duplicate
    assert I.check_network([L([(20, 12), (180, 12)])], ARTERIAL).violations()[
        "parallel_duplicates"] == 0


def test_overlap_with_a_given_road():
    c = I.check_network([L([(50, 0), (150, 0)])], ARTERIAL)
    assert c.violations()["overlaps"] == 1 and c.overlaps[0].length == pytest.approx(100.0)
    assert c.violations()["parallel_duplicates"] == 1


def test_motorway_is_met_only_at_existing_junctions():
    given = [L([(0, 0), (200, 0)]), L([(200, 0), (400, 0)]),      # a motorway in two ways
             L([(200, 0), (200, -150)])]                          # a road joining it at x=200
    cls = ["motorway", "motorway", "secondary"]
    at_junction = L([(200, 0), (200, 120)])
    mid_way = L([(100, 0), (100, 120)])
    c = I.check_network([at_junction, mid_way], given, cls)
    assert c.violations()["controlled_access"] == 1
    assert shapely.get_coordinates(c.controlled_access).tolist() == [[100.0, 0.0]]
    # where the motorway ways only continue each other (degree 2) there is no junction
    c = I.check_network([L([(200, 0), (200, 120)])], given[:2], cls[:2])
    assert c.violations()["controlled_access"] == 1
    # the same street onto a secondary road is fine
    assert I.check_network([mid_way], given, ["secondary"] * 3).ok


def test_bridges_of_the_given_roads_are_not_crossings():
    bridge = [L([(0, 0), (200, 0)])]
    street = [L([(100, -50), (100, 50)])]
    c = I.check_network(street, bridge, given_layer=[1])
    assert c.violations()["crossings_given"] == 0
    # but passing under a bridge does not connect
    assert c.floating_pieces == 1


def test_dead_end_share_counts_inside_and_away_from_the_edge():
    # a '#': 4 crosses and 8 dead ends
    h = [L([(-50, y), (150, y)]) for y in (0, 100)]
    v = [L([(x, -50), (x, 150)]) for x in (0, 100)]
    assert I.dead_end_share(h + v) == pytest.approx(8 / 12)
    # clipped to the area whose edge the ends lie on: no dead end counts
    area = shapely.box(-50, -50, 150, 150)
    assert I.dead_end_share(h + v, area) == 0.0
    assert I.dead_end_share(h + v, area, edge_distance=0.0) == pytest.approx(8 / 12)
    # the vertical streets noded at the crossings: a junction with the given ones at each
    v = shapely.get_parts(shapely.node(shapely.multilinestrings(h + v)))[6:]
    c = I.check_network(v, h, example_dead_end_share=0.25)
    assert c.dead_end_share == pytest.approx(8 / 12) and c.violations()["dead_end_share"] == 1
    c = I.check_network(v, h, example_dead_end_share=0.6)
    assert c.dead_end_ok and c.ok



def test_dead_end_share_of_pieces_meeting_below_the_millimetre():
    """A square block in four pieces with a stem at one corner: one dead end (the stem's)
    among two counted nodes. Two pieces of the square meet at a corner that is one node to
    the millimetre but differs below it (a piece rounded to a millimetre grid, one not):
    merging the chain used to keep only its first piece, the corner it lost became a dead
    end and the share doubled."""
    from urban_synthesis.plugin.network.street_graph import clean_network

    off = 4e-4    # under half a millimetre: the same node
    square = [L([(0, 0), (100 + off, 0)]), L([(100, 0), (100, 100)]),
              L([(100, 100), (0, 100)]), L([(0, 100), (0, 0)])]
    stem = [L([(0, 0), (-60, -60)])]
    assert I.dead_end_share(square + stem) == pytest.approx(0.5)
    g = clean_network(square + stem, snap_tolerance=0.5, min_dangle_length=0.0)
    assert g.n_edges == 2 and shapely.length(g.geometry).sum() == pytest.approx(
        400 + 60 * np.sqrt(2))


def test_table_and_summary():
    c = I.check_network([L([(100, -50), (100, 50)])], ARTERIAL, example_dead_end_share=0.5)
    t = c.table()
    assert list(t.check) == [name for name, _, _ in I.CHECKS if name != "outside_target"]
    with_target = I.check_network([L([(100, -50), (100, 50)])], ARTERIAL,
                                  target=shapely.box(0, -100, 200, 100))
    assert list(with_target.table().check) == [name for name, _, _ in I.CHECKS]
    assert t.violations.sum() == c.n_violations
    assert "1 crossing of a given road" in c.summary()


def test_bad_input():
    with pytest.raises(InputError, match="must be lines"):
        I.check_network([shapely.Point(0, 0)])
    with pytest.raises(InputError, match="road classes"):
        I.check_network(ARTERIAL, ARTERIAL, ["primary", "primary"])
    with pytest.raises(InputError, match="corridor"):
        I.check_network(ARTERIAL, corridor_half_width=-1)
    with pytest.raises(Canceled):
        I.check_network(ARTERIAL, progress=Progress(is_canceled=lambda: True))
    # nothing synthesised is no violation
    assert I.check_network([], ARTERIAL).ok


def test_real_streets_keep_the_invariants_of_their_own_arterials():
    """Helsinki's real minor streets against its real level-0 roads: the checker must pass
    a real city (bridges carry their OSM layer), and catch what a sloppy synthesis does."""
    from helpers import helsinki_roads
    from urban_synthesis.plugin.network import hierarchy, street_graph

    df = helsinki_roads()
    g = street_graph.clean_network(df.geometry.values, df.highway.values, df.name.values,
                                   df.z.values)
    level = hierarchy.road_hierarchy(g).edge_level
    given, minor = g.geometry[level == 0], g.geometry[level > 0]
    c = I.check_network(minor, given, g.road_class[level == 0],
                        given_layer=g.z_layer[level == 0])
    v = c.violations()
    assert len(minor) > 100
    assert v["crossings_given"] == v["crossings_synthesised"] == v["overlaps"] == 0
    assert v["parallel_duplicates"] == 0 and v["controlled_access"] == 0
    assert c.floating_pieces <= 1        # one clipped-off piece at the extract's edge
    assert 0.1 < c.dead_end_share < 0.5
    # shifted by 30 m across the arterials, the same streets cross them without junctions
    moved = shapely.transform(minor, lambda xy: xy + [30.0, 30.0])
    v = I.check_network(moved, given).violations()
    assert v["crossings_given"] > 20 and v["floating_pieces"] > 5



def test_a_link_starts_exactly_at_its_piece():
    """A link leaves its piece at the end of one of its lines as the lines have it (the
    graph's nodes are rounded to the millimetre): no gap beside the piece's street."""
    from helpers import assert_no_gaps
    from urban_synthesis.plugin.network.links import link_floating_pieces

    road = shapely.LineString([(0.000437, 0.000381), (100.000437, 0.000381)])
    piece = shapely.LineString([(40.000437, 30.000381), (60.000437, 30.000381)])
    links, keep = link_floating_pieces([road, piece], [True, False])
    assert len(links) == 1 and keep.all()
    start = shapely.get_point(links[0], 0)
    assert shapely.distance(start, shapely.boundary(piece)) == 0.0
    assert shapely.distance(shapely.get_point(links[0], -1), road) < 1e-9
    assert_no_gaps(np.array([road, piece, links[0]], dtype=object))


def test_a_piece_in_the_other_arm_of_a_concave_target_is_linked_along_the_arms():
    """A target shaped like an upturned U: the anchored road in the west arm, a floating
    street in the east arm. A straight link would cross the bay between the arms, outside
    the target: without ``bent`` the piece stays unlinked; with it the link runs up the east
    arm, across the top and down the west arm onto the road, inside the target, crossing
    nothing, planar and in one piece with the road."""
    from urban_synthesis.plugin.network.links import allowed_area, link_floating_pieces

    target = shapely.union_all([shapely.box(0, 0, 100, 500), shapely.box(300, 0, 400, 500),
                                shapely.box(0, 430, 400, 500)])
    road, street = L([(50, 0), (50, 380)]), L([(350, 60), (350, 300)])
    links, keep = link_floating_pieces([road, street], [True, False], inside=target,
                                       drop_unlinked=False)
    assert len(links) == 0 and keep.all()
    links, keep = link_floating_pieces([road, street], [True, False], inside=target,
                                       bent=True)
    assert len(links) == 1 and keep.all()
    link = links[0]
    assert len(link.coords) >= 3                     # it turns at the arms' corners
    assert shapely.covers(allowed_area(target), link)
    assert not shapely.intersects(link, shapely.box(110, 0, 290, 420))   # not across the bay
    assert shapely.distance(shapely.get_point(link, 0), street) < 1e-6
    assert shapely.distance(shapely.get_point(link, -1), road) < 1e-6
    c = I.check_network([street, link], [road], target=target)
    assert c.ok and c.n_components == 1 and c.floating_pieces == 0


def test_a_finely_toothed_target_keeps_the_bent_links_graph_small():
    """A strip with 1,200 teeth: its outline shrunk for the bent links has about 6,000
    reflex corners (each valley an arc), whose legs (18 million pairs) would be checked one
    by one; the graph keeps at most MAX_PATH_CORNERS, the outline simplified further."""
    from urban_synthesis.plugin.network.links import MAX_PATH_CORNERS, PathsInside

    top = [xy for i in range(1200) for xy in ((20 * i, 40.0), (20 * i + 10, 90.0))]
    comb = shapely.Polygon([(0, 0), (24000, 0), (24000, 40)] + top[::-1])
    assert comb.is_valid
    assert len(PathsInside(comb).corners) <= MAX_PATH_CORNERS


def test_the_dead_end_share_keeps_bridges_apart_like_the_road_metrics():
    """A bridge over a street makes no junction: layoutmetrics' roads row said so, but the
    invariants' dead-end share noded the two (Liechtenstein, one table: 0.3032 and 0.3025,
    503 dead ends of 1,659 nodes and of 1,663). Both count the same nodes now."""
    from urban_synthesis.plugin.measure import metrics as M

    lines = [shapely.LineString([(0, 0), (200, 0)]), shapely.LineString([(100, -100), (100, 100)]),
             shapely.LineString([(200, 0), (200, 80)]), shapely.LineString([(200, 0), (260, 0)])]
    layer = [0, 1, 0, 0]
    res = M.compute_layout_metrics(roads=lines, road_z_layer=layer)
    # ends: (0,0), (100,-100), (100,100), (200,80), (260,0); junction (200,0): 5 of 6
    assert res.scalar("roads", "dead_end_share") == pytest.approx(5 / 6)
    assert res.scalar("invariants", "dead_end_share") == pytest.approx(5 / 6)
    assert I.dead_end_share(lines, z_layer=layer) == pytest.approx(5 / 6)
    assert I.dead_end_share(lines) == pytest.approx(5 / 7)   # noded: (100, 0) a junction


def test_the_summary_names_each_count_in_its_number():
    """layoutmetrics' log line: '1 floating pieces', and a measured real network (no given
    roads) was '2044 synthesised lines against 0 given'."""
    street = shapely.LineString([(0, 0), (100, 0)])
    apart = shapely.LineString([(0, 50), (100, 50)])
    alone = I.check_network([street, apart]).summary()
    assert alone.startswith("2 lines: 2 connected components"), alone
    given = I.check_network([apart], [street]).summary()
    assert given.startswith("1 synthesised line against 1 given: 2 connected components")
    assert given.endswith(": 1 floating piece."), given
