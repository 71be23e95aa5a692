"""Engine tests of city blocks: faces, slivers, shape measures, buildings and parcels."""
import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon, box

from urban_synthesis.plugin.network import blocks
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.core.progress import InputError

from helpers import bubenec, helsinki_roads, nearly_coincident_streets


def grid(n=3, step=100.0):
    """n horizontal and n vertical streets, ``step`` apart: (n-1)² square blocks."""
    ext = (n - 1) * step
    return [LineString([(0, i * step), (ext, i * step)]) for i in range(n)] + \
        [LineString([(i * step, 0), (i * step, ext)]) for i in range(n)]


def test_street_grid_gives_four_square_blocks():
    g = roads.clean_network(grid())
    r = blocks.extract_blocks(g)
    t = r.table
    assert list(t.block_id) == [1, 2, 3, 4]
    assert t.area_m2.to_numpy() == pytest.approx([10_000] * 4)
    assert t.perimeter_m.to_numpy() == pytest.approx([400] * 4)
    assert t.compactness.to_numpy() == pytest.approx([1] * 4)
    assert t.aspect_ratio.to_numpy() == pytest.approx([1] * 4)
    # ids follow the lower-left corner: row by row from the south-west
    assert [tuple(np.round(shapely.bounds(p)[:2])) for p in r.geometry] == \
        [(0, 0), (100, 0), (0, 100), (100, 100)]
    assert r.stats == {"n_faces": 4, "n_small": 0, "n_thin": 0, "n_roundabout": 0,
                       "n_blocks": 4}


def test_dead_end_street_stays_inside_its_block():
    lines = grid() + [LineString([(50, 0), (50, 60)])]
    r = blocks.extract_blocks(roads.clean_network(lines))
    assert len(r.geometry) == 4
    assert r.table.area_m2.to_numpy() == pytest.approx([10_000] * 4)
    assert list(r.table.n_dead_ends) == [1, 0, 0, 0]


def test_sliver_faces_are_dropped():
    lines = grid() + [
        LineString([(0, 106), (200, 106)]),          # second carriageway 6 m north of y=100
        LineString([(100, 0), (90, 10), (100, 20)]),  # a 100 m² traffic island
    ]
    r = blocks.extract_blocks(roads.clean_network(lines, min_dangle_length=0))
    assert r.stats["n_small"] == 1
    assert r.stats["n_thin"] == 2       # the 6 m strip between the carriageways, both halves
    assert len(r.geometry) == 4
    assert (r.table.area_m2 > 9_000).all()


def roundabout_cross(radius=12.5):
    """A 200 m square of streets, a cross through it meeting at a roundabout of ``radius``
    in the middle (25 m across: 491 m² and 12.5 m mean width, a block by area and width)."""
    ring = LineString(shapely.Point(100, 100).buffer(radius, quad_segs=16).exterior.coords)
    square = LineString([(0, 0), (200, 0), (200, 200), (0, 200), (0, 0)])
    arms = [LineString([(100, 0), (100, 100 - radius)]),
            LineString([(100, 100 + radius), (100, 200)]),
            LineString([(0, 100), (100 - radius, 100)]),
            LineString([(100 + radius, 100), (200, 100)])]
    return [square, ring, *arms], np.array([False, True, False, False, False, False])


def test_a_roundabout_island_is_no_block():
    """The island inside a junction=roundabout ring is road furniture: it became a block
    (and then got a parcel and footprints); with the roads' roundabout flags it is dropped
    and counted, from lines, from a graph and through blocks_from_roads."""
    lines, ring = roundabout_cross()
    plain = blocks.extract_blocks(lines)
    assert plain.stats["n_blocks"] == 5 and plain.stats["n_roundabout"] == 0
    r = blocks.extract_blocks(lines, roundabout=ring)
    assert r.stats["n_blocks"] == 4 and r.stats["n_roundabout"] == 1
    assert not shapely.intersects(r.geometry, shapely.Point(100, 100)).any()
    graph, r = blocks.blocks_from_roads(lines, roundabout=ring)
    assert r.stats["n_blocks"] == 4 and r.stats["n_roundabout"] == 1
    assert (r.table.area_m2 > 9_000).all()
    g = roads.clean_network(lines, merge_degree2=False)
    r = blocks.extract_blocks(g, roundabout=ring[g.source])
    assert r.stats["n_roundabout"] == 1
    # a face only partly on the ring (a block beside it) stays
    assert blocks.roundabout_islands(r.geometry, g.geometry, ring[g.source]).sum() == 0
    with pytest.raises(InputError, match="roundabout flags"):
        blocks.extract_blocks(lines, roundabout=ring[:3])


def test_liechtenstein_roundabout_islands_are_no_blocks():
    """Liechtenstein (2013) has 13 junction=roundabout rings; 6 of their islands, 400 to
    492 m², were blocks (the 7 smaller ones fall under the minimum block area)."""
    import pyogrio

    from conftest import LIECHTENSTEIN

    if not LIECHTENSTEIN.exists():
        pytest.skip(f"{LIECHTENSTEIN} is not there")
    lines = pyogrio.read_dataframe(LIECHTENSTEIN, layer="lines",
                                   columns=["highway", "other_tags"])
    lines = lines[lines.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(32632)
    ring = lines.other_tags.fillna("").str.contains('"junction"=>"roundabout"').to_numpy()
    _, before = blocks.blocks_from_roads(lines.geometry.values, lines.highway.values)
    _, after = blocks.blocks_from_roads(lines.geometry.values, lines.highway.values,
                                        roundabout=ring)
    assert ring.sum() == 13 and after.stats["n_roundabout"] == 6
    assert after.stats["n_blocks"] == before.stats["n_blocks"] - 6
    islands = shapely.polygonize(lines.geometry.values[ring]).geoms
    assert not shapely.intersects(after.geometry[:, None],
                                  shapely.point_on_surface(islands)[None, :]).any()


def test_lines_and_graph_give_the_same_blocks():
    lines = grid(4)
    from_graph = blocks.extract_blocks(roads.clean_network(lines))
    from_lines = blocks.extract_blocks(lines)
    assert len(from_graph.geometry) == len(from_lines.geometry) == 9
    assert shapely.equals(from_graph.geometry, from_lines.geometry).all()


def test_block_ids_do_not_depend_on_line_order():
    lines = grid(4)
    a = blocks.extract_blocks(lines)
    b = blocks.extract_blocks(lines[::-1])
    assert shapely.equals(a.geometry, b.geometry).all()
    assert a.table.equals(b.table)


def test_building_straddling_two_blocks_is_assigned_once():
    buildings = [
        box(10, 10, 30, 30),     # inside block 1
        box(90, 20, 130, 40),    # 10 m in block 1, 30 m in block 2 -> block 2
        box(190, 190, 230, 230),  # mostly outside the grid -> none
        box(-50, -50, -40, -40),  # far outside -> none
    ]
    r = blocks.extract_blocks(roads.clean_network(grid()), buildings=buildings)
    b = r.buildings
    assert list(b.block_id.astype("float").fillna(0)) == [1, 2, 0, 0]
    assert list(b.in_block) == [True, True, False, False]
    assert b.block_share.to_numpy() == pytest.approx([1, 0.75, 0, 0])
    assert list(r.table.n_buildings) == [1, 1, 0, 0]
    # coverage counts the part inside the block only
    assert r.table.building_coverage.to_numpy() == pytest.approx([0.04, 0.06, 0, 0])
    assert r.stats["n_buildings_in_blocks"] == 2


def test_parcels_get_blocks():
    parcels = [box(0, 0, 50, 100), box(50, 0, 100, 100), box(0, 95, 200, 105)]  # last: a street
    r = blocks.extract_blocks(grid(), parcels=parcels)
    assert list(r.parcels.block_id.astype("float").fillna(0)) == [1, 1, 0]
    assert list(r.table.n_parcels) == [2, 0, 0, 0]


def test_no_closed_face_is_an_input_error():
    tree = [LineString([(0, 0), (500, 0)]), LineString([(100, 0), (100, 300)])]
    with pytest.raises(InputError, match="no closed block"):
        blocks.extract_blocks(roads.clean_network(tree))


def test_only_slivers_is_an_input_error():
    with pytest.raises(InputError, match="lower the minimum"):
        blocks.extract_blocks(grid(), min_area=20_000)
    with pytest.raises(InputError, match="negative"):
        blocks.extract_blocks(grid(), min_area=-1)


def test_faces_of_streets_whose_noding_fails():
    """Streets that defeat GEOS's floating-point noding are snap-rounded on the millimetre
    grid (street_graph.node_lines): the faces of that noding, bounded by the streets."""
    lines = nearly_coincident_streets()
    faces, area, _ = blocks.planar_faces(lines)
    ref = shapely.get_parts(shapely.polygonize(roads.node_lines(lines)))
    assert len(faces) == len(ref) > 0 and shapely.is_valid(faces).all()
    assert sorted(area) == pytest.approx(sorted(shapely.area(ref)))
    streets = shapely.buffer(shapely.union_all(lines), roads.JUNCTION_TOLERANCE)
    assert shapely.covers(streets, shapely.boundary(faces)).all()


def test_planar_faces_match_polygonize_with_holes_and_bridges():
    outer = LineString([(0, 0), (300, 0), (300, 300), (0, 300), (0, 0)])
    island = LineString([(100, 100), (200, 100), (200, 200), (100, 200), (100, 100)])
    pond = LineString([(20, 20), (40, 20), (40, 40), (20, 40), (20, 20)])
    bridge = LineString([(200, 150), (300, 150)])   # joins the island to the outer loop
    dangle = LineString([(10, 10), (20, 20)])       # a dead end hanging off the pond
    lines = [outer, island, pond, bridge, dangle]
    faces, area, perimeter = blocks.planar_faces(lines)
    ref = shapely.get_parts(shapely.polygonize(shapely.get_parts(
        shapely.node(shapely.multilinestrings(lines)))))
    assert len(faces) == len(ref) == 3
    assert sorted(area) == pytest.approx(sorted(shapely.area(ref)))
    assert area == pytest.approx(shapely.area(faces))
    assert perimeter == pytest.approx(shapely.length(faces))
    big = faces[np.argmax(area)]
    assert shapely.get_num_interior_rings(big) == 2   # the island and the pond
    assert shapely.is_valid(faces).all()


def test_minimum_rectangle_of_a_rotated_rectangle():
    rect = shapely.affinity.rotate(box(0, 0, 40, 10), 30, origin=(0, 0))
    length, width, angle = blocks.minimum_rectangles([rect, Polygon([(0, 0), (4, 0), (0, 3)])])
    assert length == pytest.approx([40, 4])
    assert width == pytest.approx([10, 3])
    assert angle[0] == pytest.approx(30)
    m = blocks.shape_metrics([rect])
    assert m.compactness[0] == pytest.approx(1) and m.aspect_ratio[0] == pytest.approx(0.25)


# --------------------------------------------------------------------------- real data

@pytest.fixture(scope="module")
def helsinki_graph():
    df = helsinki_roads()
    return roads.clean_network(df.geometry.values, df.highway.values, z_layer=df.z.values)


def _helsinki_buildings():
    import pyogrio

    from conftest import HELSINKI

    df = pyogrio.read_dataframe(HELSINKI, layer="multipolygons", on_invalid="ignore")
    df = df[df.building.notna() & df.geometry.notna()].to_crs(32635)
    return shapely.make_valid(df.geometry.values)


def assert_blocks_are_a_partition(r, buildings=None):
    geoms = r.geometry
    assert shapely.is_valid(geoms).all()
    assert (shapely.get_type_id(geoms) == 3).all()
    tree = shapely.STRtree(geoms)
    a, b = tree.query(geoms, predicate="intersects")
    sel = a < b
    overlap = shapely.area(shapely.intersection(geoms[a[sel]], geoms[b[sel]]))
    assert overlap.max(initial=0) < 1e-3, "blocks overlap"
    if buildings is not None:
        index = r.buildings.block_id.astype("float").fillna(0).to_numpy().astype(int) - 1
        inside = index >= 0
        # the assigned block holds at least half of the building, and no block holds more
        share = shapely.area(shapely.intersection(buildings[inside], geoms[index[inside]])) / \
            shapely.area(buildings[inside])
        assert (share >= 0.5 - 1e-9).all()
        g, k = tree.query(buildings, predicate="intersects")
        best = np.zeros(len(buildings))
        np.maximum.at(best, g, shapely.area(shapely.intersection(buildings[g], geoms[k])))
        assert (best[~inside] < 0.5 * shapely.area(buildings[~inside]) + 1e-6).all()


def test_helsinki_blocks_properties(helsinki_graph):
    buildings = _helsinki_buildings()
    r = blocks.extract_blocks(helsinki_graph, buildings=buildings)
    assert_blocks_are_a_partition(r, buildings)
    t = r.table
    assert 40 <= len(t) <= 70
    assert r.stats["n_faces"] - r.stats["n_small"] - r.stats["n_thin"] == len(t)
    assert t.area_m2.min() >= blocks.MIN_BLOCK_AREA
    assert 2_000 < t.area_m2.median() < 30_000          # city blocks, not districts
    # mostly rectangular blocks; an L-shaped face around a loop goes down to about 0.2
    assert (t.compactness.between(0.1, 1)).all() and t.compactness.median() > 0.75
    assert (t.aspect_ratio.between(0.05, 1)).all() and 0.3 < t.aspect_ratio.median() < 0.8
    # docs/ARCHITECTURE.md: about 62 % of Helsinki's buildings lie inside a closed block
    share_inside = r.stats["n_buildings_in_blocks"] / len(buildings)
    assert 0.5 < share_inside < 0.75
    assert t.n_buildings.sum() == r.stats["n_buildings_in_blocks"]


def test_planar_faces_match_polygonize_on_helsinki(helsinki_graph):
    lines = helsinki_graph.geometry
    faces, area, _ = blocks.planar_faces(lines)
    ref = shapely.get_parts(shapely.polygonize(shapely.get_parts(
        shapely.node(shapely.multilinestrings(lines)))))
    assert len(faces) == len(ref)
    assert np.sort(area) == pytest.approx(np.sort(shapely.area(ref)))


def test_tiled_helsinki_repeats_the_blocks(helsinki_graph):
    lines = helsinki_graph.geometry
    x0, y0, x1, y1 = shapely.total_bounds(lines)
    w, h = x1 - x0, y1 - y0
    tiles = np.concatenate([shapely.transform(lines, lambda c, i=i, j=j: c + [i * w, j * h])
                            for i in range(3) for j in range(3)])
    one = blocks.extract_blocks(lines)
    nine = blocks.extract_blocks(tiles)
    assert len(nine.geometry) == 9 * len(one.geometry)
    assert nine.table.area_m2.sum() == pytest.approx(9 * one.table.area_m2.sum())


def test_bubenec_blocks_properties():
    streets, buildings, plots = bubenec("streets"), bubenec("buildings"), bubenec("plots")
    r = blocks.extract_blocks(roads.clean_network(streets.geometry.values),
                              buildings=buildings.geometry.values, parcels=plots.geometry.values)
    assert len(r.geometry) == 7   # docs/ARCHITECTURE.md: Bubeneč has 7 closed blocks
    assert_blocks_are_a_partition(r, buildings.geometry.values)
    assert r.table.compactness.min() > 0.5   # triangles at the oblique streets
    assert r.table.n_parcels.sum() == r.parcels.in_block.sum() > 100
    assert r.table.n_buildings.sum() == 96   # the two north-western courtyards are open


# --------------------------------------------------------------------------- boundary

def open_sketch():
    """Arterials that close no face: a road across a 180 x 200 m district and a road north
    from it that runs out of the district (both reach past its outline)."""
    return [LineString([(0, 50), (200, 50)]), LineString([(100, 50), (100, 300)])]


@pytest.mark.parametrize("as_graph", [False, True])
def test_a_boundary_closes_the_faces_an_open_sketch_leaves(as_graph):
    district = box(10, 0, 190, 200)
    lines = open_sketch()
    with pytest.raises(InputError, match="no closed"):   # the roads alone close nothing
        blocks.extract_blocks(roads.clean_network(lines) if as_graph else lines)
    r = blocks.extract_blocks(roads.clean_network(lines) if as_graph else lines,
                              boundary=district)
    # three blocks tile the district: south of the road, and west and east of the road north
    assert len(r.geometry) == 3
    assert sum(shapely.area(r.geometry)) == pytest.approx(district.area)
    assert shapely.within(r.geometry, district.buffer(1e-6)).all()
    np.testing.assert_allclose(sorted(r.table.area_m2), [9_000, 13_500, 13_500])
    # the length of each outline on the district's edge: no street there
    south = np.argmin(shapely.bounds(r.geometry)[:, 1])
    assert r.table.boundary_m[south] == pytest.approx(50 + 180 + 50)
    assert r.table.boundary_m.sum() == pytest.approx(district.length)
    assert r.stats["n_on_boundary"] == 3 and r.stats["n_outside"] == 0


def test_a_boundary_drops_faces_outside_it_and_land_no_road_reaches():
    district = shapely.union_all([box(10, 0, 190, 200), box(500, 0, 600, 100)])
    r = blocks.extract_blocks(grid() + open_sketch(), boundary=district)
    assert r.stats["n_without_street"] == 1          # the second square, far from the roads
    assert r.stats["n_outside"] >= 1                 # the grid's faces beyond x = 190
    assert shapely.within(r.geometry, district.buffer(1e-6)).all()
    assert not shapely.intersects(r.geometry, box(500, 0, 600, 100)).any()
    assert (r.table.boundary_m >= 0).all()
    without = blocks.extract_blocks(grid() + open_sketch())
    assert (without.table.boundary_m == 0).all()      # no boundary: no edge on one


def test_a_boundary_no_road_reaches_is_a_clear_error():
    with pytest.raises(InputError, match="no block inside the boundary.*1 have no road"):
        blocks.extract_blocks(open_sketch(), boundary=box(1000, 0, 1100, 100))
