"""Engine tests of plugin/buildings/parts.py (thesis ch. 6: part-based buildings).

The thesis's skyscraper case (120 m, FAR 10 / 15 / 20 from 18 floor parts) must be met
exactly; buildings along skeletons must have valid, non-overlapping parts with end parts
at the ends and corner parts at the vertices; k-best solutions are distinct and ordered by
cost; infeasible constraints and malformed libraries give clear errors.
"""
import numpy as np
import pandas as pd
import pytest
import shapely

from helpers import bubenec
from urban_synthesis.plugin.network import blocks
from urban_synthesis.plugin.buildings import parts as bp
from urban_synthesis.plugin.core.progress import InputError
from urban_synthesis.plugin.buildings.sequences import InfeasibleError

SITE = shapely.box(0, 0, 40, 40)          # 1,600 m² plot


@pytest.fixture(scope="module")
def sky():
    return bp.skyscraper_library()


@pytest.fixture(scope="module")
def terrace():
    return bp.terrace_library()


def assert_no_overlaps(geoms, tol=1e-6):
    geoms = np.asarray(geoms, dtype=object)
    assert shapely.is_valid(geoms).all()
    tree = shapely.STRtree(geoms)
    i, j = tree.query(geoms, predicate="intersects")
    pairs = i < j
    if pairs.any():
        inter = shapely.area(shapely.intersection(geoms[i[pairs]], geoms[j[pairs]]))
        assert inter.max() < tol, inter.max()


def test_a_tower_stands_on_its_site_not_in_its_courtyard(sky):
    """A courtyard block (80 x 60 m, a 40 x 20 m courtyard in the middle) and an L: the
    floors were centred on the centroid, in the courtyard or outside the L, so the whole
    tower stood off its site. They now stand on the point furthest inside the site; a
    site that covers its centroid keeps the centroid (the thesis's plot)."""
    courtyard = shapely.box(0, 0, 80, 60).difference(shapely.box(20, 20, 60, 40))
    ell = shapely.Polygon([(0, 0), (100, 0), (100, 30), (30, 30), (30, 100), (0, 100)])
    for site in (courtyard, ell):
        assert not site.covers(site.centroid)
        res = bp.stack_floors(sky, 40.0, site=site)
        centres = shapely.centroid(res.geometry)
        assert shapely.within(centres, site).all()
        floors = shapely.union_all(res.geometry)
        assert floors.intersection(site).area >= 0.95 * floors.area
    res = bp.stack_floors(sky, 40.0, site=SITE)
    np.testing.assert_allclose(shapely.get_coordinates(shapely.centroid(res.geometry)),
                               np.tile(SITE.centroid.coords[0], (len(res.geometry), 1)))


def test_skyscraper_library_matches_the_thesis_database(sky):
    assert len(sky) == 18
    assert 75 <= sky.n_transitions <= 85          # thesis: 80 transitions
    assert set(sky.table.kind) == {"floor"}


@pytest.mark.parametrize("far", [10.0, 15.0, 20.0])
def test_skyscrapers_meet_height_and_far_exactly(sky, far):
    res = bp.stack_floors(sky, 120.0, far=far, site=SITE, k=3)
    assert len(res.summary) == 3
    for rank, parts in res.table.groupby("solution"):
        parts = parts.sort_values("seq_index")
        # exact: the floor areas and heights of the chosen parts, summed independently
        assert parts.floor_area_m2.sum() == far * 1600.0
        assert parts.height_m.sum() == 120.0
        assert parts.levels.sum() == 30
        np.testing.assert_allclose(parts.base_m.to_numpy()[1:], parts.top_m.to_numpy()[:-1])
        assert parts.top_m.max() == 120.0
        geoms = res.geometry[parts.index.to_numpy()]
        # setbacks only: each floor stands inside the one below it, inside the site
        for below, above in zip(geoms[:-1], geoms[1:]):
            assert above.buffer(-1e-6).within(below)
        assert shapely.union_all(geoms).within(SITE.buffer(1e-6))
    costs = res.summary.cost.to_numpy()
    assert (np.diff(costs) >= -1e-9).all()
    seqs = [tuple(p.sort_values("seq_index").part_id) for _, p in res.table.groupby("solution")]
    assert len(set(seqs)) == len(seqs)


def test_larger_far_makes_a_chubbier_tower(sky):
    mean_footprint = []
    for far in (10.0, 15.0, 20.0):
        parts = bp.stack_floors(sky, 120.0, far=far, site_area=1600.0).table
        mean_footprint.append((parts.floor_area_m2.sum()) / parts.levels.sum())
    assert mean_footprint[0] < mean_footprint[1] < mean_footprint[2]


def test_k_best_towers_are_the_cheapest(sky):
    """The k best agree with a brute-force enumeration of towers on a small case."""
    t = sky.table
    floors = range(len(t))
    h_units = (t.length_m / 0.2).round().astype(int).to_numpy()
    target_h, target_a = 40.0, 8 * 784.0 + 2 * 576.0
    feasible = []

    def rec(seq, h):
        if h == int(target_h / 0.2):
            if t.floor_area_m2.to_numpy()[seq].sum() == target_a:
                feasible.append(sum(sky.transition[a, b] for a, b in zip(seq, seq[1:])))
            return
        for e in floors:
            if h + h_units[e] <= target_h / 0.2 and (not seq or np.isfinite(
                    sky.transition[seq[-1], e])):
                rec(seq + [e], h + h_units[e])

    rec([], 0)
    res = bp.stack_floors(sky, target_h, floor_area=target_a, k=6)
    want = sorted(feasible)[:6]
    assert len(want) >= 2
    np.testing.assert_allclose(res.summary.cost, want)


def test_infeasible_towers_are_reported(sky):
    with pytest.raises(InfeasibleError, match="no tower of 120 m"):
        bp.stack_floors(sky, 120.0, far=30.5, site_area=1600.0)   # > 30 levels x 1,600 m²
    with pytest.raises(InfeasibleError):
        bp.stack_floors(sky, 121.0, far=10.0, site_area=1600.0)   # not a multiple of 4 m
    with pytest.raises(InputError, match="site area"):
        bp.stack_floors(sky, 120.0, far=10.0)


L_SKELETON = shapely.LineString([(0, 0), (50, 0), (50, 40), (90, 40)])


@pytest.mark.parametrize("front", ["right", "left"])
def test_parts_along_an_open_skeleton(terrace, front):
    res = bp.build_along_skeleton(L_SKELETON, terrace, front=front, k=4)
    assert 1 <= len(res.summary) <= 4
    assert (np.diff(res.summary.cost) >= -1e-9).all()
    seqs = set()
    for rank, parts in res.table.groupby("solution"):
        parts = parts.sort_values("seq_index")
        seqs.add(tuple(parts.part_id))
        geoms = res.geometry[parts.index.to_numpy()]
        assert_no_overlaps(geoms)
        assert parts.length_m.sum() == pytest.approx(L_SKELETON.length)
        assert parts.kind.iloc[0] == "end_left" and parts.kind.iloc[-1] == "end_right"
        corners = parts[parts.kind == "corner"]
        assert len(corners) == 2 and (parts.kind.iloc[1:-1] != "end_left").all()
        # corner parts sit on the skeleton's vertices: the vertex is the middle of the part
        mids = np.sort((corners.start_m + corners.length_m / 2).to_numpy())
        vertex_at = np.array([50.0, 90.0])
        if front == "left":
            vertex_at = np.sort(L_SKELETON.length - vertex_at)
        np.testing.assert_allclose(mids, vertex_at, atol=0.2)
        for g in geoms[(parts.kind == "corner").to_numpy()]:
            assert min(g.distance(shapely.Point(50, 0)), g.distance(shapely.Point(50, 40))) < 1e-6
        # the building lies on the side away from the street: along the first leg
        # (0, 0)-(50, 0), left of the direction of travel for a street on the right
        near = geoms[shapely.intersects(geoms, shapely.box(0, -20, 30, 20))]
        side = np.sign(shapely.get_coordinates(shapely.centroid(near))[:, 1])
        assert (side == (1 if front == "right" else -1)).all()
    assert len(seqs) == len(res.summary)


BLOCK = shapely.box(0, 0, 80, 60)


def test_block_filling_ring(terrace):
    """A closed skeleton (block offset polygon): one building along the whole perimeter."""
    res = bp.build_along_skeleton(BLOCK, terrace, k=3)
    strip = BLOCK.difference(shapely.box(12, 12, 68, 48))      # 12 m deep perimeter strip
    for rank, parts in res.table.groupby("solution"):
        geoms = res.geometry[parts.index.to_numpy()]
        assert_no_overlaps(geoms)
        union = shapely.union_all(geoms)
        assert union.within(BLOCK.buffer(1e-6))
        assert shapely.area(union) == pytest.approx(strip.area, rel=1e-6)
        assert (parts.kind == "corner").sum() == 4
        assert parts.length_m.sum() == pytest.approx(BLOCK.length)
        assert not parts.kind.isin(["end_left", "end_right"]).any()


def test_far_and_count_constraints_along_a_skeleton(terrace):
    coarse = bp.terrace_library(infill=False)     # 2 m lengths: few floor-area sums
    assert len(coarse) == 26      # 23 parts along a facade line + 3 T-parts
    res = bp.build_along_skeleton(BLOCK, coarse, k=2, far=(2.0, 2.2), site_area=BLOCK.area,
                                  counts={"corner": (4, 4)})
    assert ((res.summary.far >= 2.0 - 1e-9) & (res.summary.far <= 2.2 + 1e-9)).all()
    for _, parts in res.table.groupby("solution"):
        assert 2.0 * BLOCK.area <= parts.floor_area_m2.sum() <= 2.2 * BLOCK.area
    res = bp.build_along_skeleton(L_SKELETON, terrace, counts={"doors": (5, 5)})
    table = terrace.table.set_index("part_id")
    assert table.loc[res.table.part_id, "doors"].sum() == 5
    # an exact floor area: take one that a wider interval shows to be reachable
    free = bp.build_along_skeleton(L_SKELETON, coarse).summary.floor_area_m2.iloc[0]
    wider = bp.build_along_skeleton(L_SKELETON, coarse, floor_area=(free + 1, free + 500))
    target = wider.summary.floor_area_m2.iloc[0]
    assert free + 1 <= target <= free + 500
    exact = bp.build_along_skeleton(L_SKELETON, coarse, floor_area=target)
    assert exact.table.floor_area_m2.sum() == target
    # a coarse floor-area grid keeps the full library usable: bounds met to the grid
    ring = bp.build_along_skeleton(shapely.box(0, 0, 40, 30), terrace, far=(3.5, 3.7),
                                   site_area=1200.0, area_resolution=50.0)
    n_parts = ring.summary.n_parts.iloc[0]
    area = ring.summary.floor_area_m2.iloc[0]
    assert 3.5 * 1200 - 25 * n_parts <= area <= 3.7 * 1200 + 25 * n_parts


def test_skeleton_errors(terrace):
    sharp = shapely.LineString([(0, 0), (50, 0), (0, 10)])      # a 169° turn
    with pytest.raises(InfeasibleError, match="no corner part fits"):
        bp.build_along_skeleton(sharp, terrace)
    with pytest.raises(InfeasibleError, match="fills the"):
        bp.build_along_skeleton(L_SKELETON, terrace, far=50.0, site_area=BLOCK.area)
    with pytest.raises(InputError, match="neither a part kind nor a field"):
        bp.build_along_skeleton(L_SKELETON, terrace, counts={"chimneys": (1, 2)})
    with pytest.raises(InputError, match="front"):
        bp.build_along_skeleton(L_SKELETON, terrace, front="up")


def test_library_from_a_layer_table():
    """What a Processing algorithm passes: part footprints and a table with few fields."""
    geoms = [shapely.box(0, 0, 6, 10), shapely.box(0, 0, 8, 10), shapely.box(0, 0, 4, 10),
             shapely.box(0, 0, 4, 10), shapely.box(0, 0, 20, 10)]
    table = pd.DataFrame({"kind": ["straight", "Straight", "end_left", "end_right", "corner"],
                          "length_m": [6, 8, 4, 4, 20], "height_m": [9, 12, 9, 9, 12]})
    lib = bp.library_from_table(table, geoms)
    assert lib.table.depth_m.tolist() == [10, 10, 10, 10, 10]
    assert lib.table.levels.tolist() == [3, 4, 3, 3, 4]
    np.testing.assert_allclose(lib.transition[0, 1], abs(90 - 120))
    assert np.isinf(lib.transition[3, 0]) and np.isinf(lib.transition[0, 2])
    res = bp.build_along_skeleton(shapely.LineString([(0, 0), (40, 0), (40, 30)]), lib, k=2)
    assert_no_overlaps(res.geometry[res.table.solution.to_numpy() == 1])
    with pytest.raises(InputError, match="missing field"):
        bp.library_from_table(table.drop(columns="height_m"), name="BUILDING_PARTS")
    with pytest.raises(InputError, match="unknown part kind"):
        bp.library_from_table(table.assign(kind="tower"))
    with pytest.raises(InputError, match="positive"):
        bp.library_from_table(table.assign(length_m=0))
    with pytest.raises(InputError, match="too short"):
        bp.library_from_table(table.assign(length_m=[6, 8, 4, 4, 12]), geoms)
    with pytest.raises(InputError, match="empty"):
        bp.library_from_table(table.iloc[:0])


def test_real_blocks_of_bubenec():
    """Block-filling buildings on Bubeneč's real blocks (extracted from its streets, offset
    by a 6 m half street): every building that can be made has valid parts inside its block
    that do not overlap, and its length is the skeleton's; blocks the library cannot
    handle (a sharp corner, a too short side) are reported as infeasible."""
    extraction = blocks.extract_blocks(bubenec("streets").geometry.values)
    lib = bp.terrace_library()
    made, refused = 0, 0
    for block in extraction.geometry:
        skeleton = shapely.buffer(block, -6.0, join_style="mitre").simplify(0.5)
        try:
            res = bp.build_along_skeleton(skeleton, lib)
        except InfeasibleError as err:
            assert "no corner part fits" in str(err) or "fills the" in str(err)
            refused += 1
            continue
        made += 1
        assert_no_overlaps(res.geometry)
        assert shapely.union_all(res.geometry).within(block)
        assert res.summary.length_m.iloc[0] == pytest.approx(skeleton.length, abs=0.1)
        assert (res.table.kind == "corner").sum() >= 4
    assert made >= 4 and made + refused == len(extraction.geometry) == 7


def test_a_ring_narrower_than_the_parts_is_refused_not_built_into_its_courtyard():
    """A polygon skeleton is filled inward by the parts' depth: a perimeter block whose
    courtyard lies 8 m from its outline took 12 m terrace parts, 800 m² of them standing in
    the courtyard, and nothing said so. Such a polygon is now infeasible, named; 8 m parts
    fill it, inside it and without overlaps."""
    ring = shapely.box(0, 0, 80, 60).difference(shapely.box(8, 8, 72, 52))
    with pytest.raises(InfeasibleError, match=r"narrower than its parts' depth \(12 m\).*"
                                              r"800 m² of them would stand outside it"):
        bp.build_along_skeleton(ring, bp.terrace_library(depth=12.0))
    result = bp.build_along_skeleton(ring, bp.terrace_library(depth=8.0))
    placed = result.geometry[result.table["solution"].to_numpy() == 1]
    union = shapely.union_all(placed)
    assert shapely.area(shapely.difference(union, ring)) < 1e-6
    assert shapely.area(placed).sum() == pytest.approx(union.area, abs=1e-6)
    assert union.area == pytest.approx(ring.area, rel=0.02)


def test_a_tower_wider_than_its_site_is_refused_not_built_over_its_neighbours():
    """Floor parts are squares 20-32 m wide centred on the site: on a plot 15 m wide they
    stood 2.5 m over the neighbours' land on both sides (a quarter of each floor), unsaid.
    A few m² over a courtyard's corner stay allowed (the test above)."""
    lib = bp.skyscraper_library()
    with pytest.raises(InfeasibleError, match=r"floors do not fit on the site: 100 m² of a "
                                              r"floor 20 m wide would stand beyond it"):
        bp.stack_floors(lib, 80.0, site=shapely.box(0, 0, 100, 15))
    wide = shapely.box(0, 0, 60, 60)
    result = bp.stack_floors(lib, 80.0, site=wide)
    assert shapely.area(shapely.difference(result.geometry, wide)).max() < 1e-9
