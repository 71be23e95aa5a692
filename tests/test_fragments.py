"""Hierarchical fragments (plugin/network/fragments.py)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.network import fragments as fr
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.retrieval.shape_context import DemGrid


def levelled_grid():
    """A 400 m square: level 0 outer ring, level 1 middle cross, level 2 lines splitting the
    south-west quarter in four and the south-east quarter in two, a level 2 dead end in the
    north-east quarter (a block at level 1) and a level 3 dead end in the south-west cell."""
    lines, levels = [], []
    lines.append(shapely.LineString([(0, 0), (400, 0), (400, 400), (0, 400), (0, 0)]))
    levels.append(0)
    lines += [shapely.LineString([(200, 0), (200, 400)]),
              shapely.LineString([(0, 200), (400, 200)])]
    levels += [1, 1]
    for x in (100, 300):
        lines.append(shapely.LineString([(x, 0), (x, 200)]))
        levels.append(2)
    for y in (100,):
        lines.append(shapely.LineString([(0, y), (200, y)]))
        levels.append(2)
    lines.append(shapely.LineString([(300, 400), (300, 320)]))  # north-east: a dead end
    levels.append(2)
    lines.append(shapely.LineString([(50, 0), (50, 60)]))       # level 3 dead end
    levels.append(3)
    return np.array(lines, dtype=object), np.array(levels)


def test_fragments_per_level_on_a_levelled_grid():
    lines, levels = levelled_grid()
    f = fr.extract_fragments(lines, levels)
    t = f.table
    assert f.counts["per_level"] == {0: 1, 1: 4, 2: 8}
    assert list(t["fragment_id"]) == list(range(1, 14))
    # level 0: the whole square, split by the level 1 cross: not a block
    row0 = t[t.level == 0].iloc[0]
    assert row0.area_m2 == pytest.approx(160000) and not row0.is_block
    assert row0.n_interior == 2 and row0.interior_length_m == pytest.approx(800)
    # level 1: four quarters; north-west has no level 2 street (a block), north-east only a
    # dead end (a block), the two southern quarters are split (not blocks)
    q = t[t.level == 1]
    assert np.allclose(q.area_m2, 40000)
    centres = shapely.get_coordinates(shapely.centroid(f.geometry[q.index]))
    blocks = dict(zip(map(tuple, np.round(centres)), q.is_block))
    assert blocks == {(100, 100): False, (300, 100): False, (100, 300): True, (300, 300): True}
    interior = dict(zip(map(tuple, np.round(centres)), q.n_interior))
    assert interior == {(100, 100): 2, (300, 100): 1, (100, 300): 0, (300, 300): 1}
    # level 2: all faces of the level <= 2 subgraph are blocks (the level 3 street is a dead end)
    assert t[t.level == 2].is_block.all()
    assert f.counts["blocks_per_level"] == {0: 0, 1: 2, 2: 8}


def test_interior_streets_are_exactly_one_level_deeper_and_inside():
    lines, levels = levelled_grid()
    f = fr.extract_fragments(lines, levels)
    frag_level = f.table["level"].to_numpy()[f.street_fragment]
    assert (f.street_level == frag_level + 1).all()
    assert (levels[f.street_source] == f.street_level).all()
    within = shapely.covers(shapely.buffer(f.geometry[f.street_fragment], 1e-6), f.street_geometry)
    assert within.all()
    # every street of level >= 1 is inside some fragment of the grid
    assert f.counts["n_unassigned_streets"] == 0


def test_a_street_through_several_faces_is_clipped_to_each():
    ring = shapely.LineString([(0, 0), (300, 0), (300, 100), (0, 100), (0, 0)])
    walls = [shapely.LineString([(100, 0), (100, 100)]), shapely.LineString([(200, 0), (200, 100)])]
    long_street = shapely.LineString([(0, 50), (300, 50)])  # one feature crossing three faces
    f = fr.extract_fragments([ring] + walls + [long_street], [0, 0, 0, 1])
    assert f.counts["per_level"] == {0: 3}
    assert len(f.street_geometry) == 3
    assert np.allclose(shapely.length(f.street_geometry), 100)
    assert sorted(f.street_fragment.tolist()) == [0, 1, 2]


def test_slivers_are_dropped_and_no_fragment_is_an_error():
    lines, levels = levelled_grid()
    # a 3 m wide strip along the south edge: a sliver, not a fragment
    sliver = shapely.LineString([(0, 3), (400, 3)])
    f = fr.extract_fragments(np.r_[lines, [sliver]], np.r_[levels, 0])
    assert f.counts["per_level"][0] == 1 and f.counts["n_faces_dropped"] >= 1
    with pytest.raises(InputError, match="no closed fragment"):
        fr.extract_fragments([shapely.LineString([(0, 0), (100, 0)]),
                              shapely.LineString([(50, 0), (50, 50)])], [0, 1])
    # faces dropped by the width limit alone: the message names it (it gave the area
    # limit only, 'larger than 400 m²', though the 400 m square is 160,000 m²)
    with pytest.raises(InputError, match="at least 400 m² and 1000 m mean width"):
        fr.extract_fragments(lines, levels, min_width=1000.0)
    with pytest.raises(InputError, match="two street levels"):
        fr.extract_fragments(lines, np.zeros(len(lines), int))
    with pytest.raises(InputError, match="whole numbers"):
        fr.extract_fragments(lines, np.r_[levels[:-1], 1.5])
    with pytest.raises(InputError, match="one level per line"):
        fr.extract_fragments(lines, levels[:-1])


def test_only_the_order_of_the_levels_counts():
    """Levels 3, 5, 7, 9 or 10, 20, 30, 40 are the levels 0..3 of a hierarchy: a value between
    them that no street has made every fragment of the level above it a block (and stored
    each face twice), and levels near 2^40 looped for hours."""
    lines, levels = levelled_grid()
    f = fr.extract_fragments(lines, levels)
    for given in (levels * 2 + 3, levels * 10 + 10, levels + 2 ** 40):
        g = fr.extract_fragments(lines, given)
        assert g.counts["per_level"] == f.counts["per_level"]
        assert g.counts["blocks_per_level"] == f.counts["blocks_per_level"]
        assert g.table["level"].tolist() == f.table["level"].tolist()
        assert g.street_level.tolist() == f.street_level.tolist()
        assert g.counts["level_values"] == sorted(set(given.tolist()))
        assert g.counts["n_unassigned_streets"] == 0
    assert f.counts["level_values"] == [0, 1, 2, 3]
    with pytest.raises(InputError, match=r"one level \(7\)"):
        fr.extract_fragments(lines, np.full(len(lines), 7))


def test_relief_statistics_and_patches():
    lines, levels = levelled_grid()
    # plane z = 0.1 x + 0.2 y on 5 m cells over the grid (north-up: rows go south)
    x = -10 + 2.5 + 5 * np.arange(86)
    y = 410 - 2.5 - 5 * np.arange(86)
    z = 0.1 * x[None, :] + 0.2 * y[:, None]
    dem = DemGrid(z, (-10, 5, 0, 410, 0, -5))
    f = fr.extract_fragments(lines, levels, dem=dem)
    t = f.table
    # a 100 m face: cell centres span 95 m in x and y -> relief 0.3 * 95
    small = t[np.isclose(t.area_m2, 10000)]
    assert np.allclose(small.relief_m, 0.3 * 95, atol=1e-6)
    assert np.allclose(t.mean_slope, np.hypot(0.1, 0.2), atol=1e-6)
    whole = t[t.level == 0].iloc[0]
    assert whole.elevation_m == pytest.approx(0.1 * 200 + 0.2 * 200)
    assert len(f.patches) == len(t)
    p0, g0 = f.patches[0], f.patch_transform[0]
    assert p0.dtype == np.float32 and p0.shape == (80, 80)
    assert tuple(g0) == (0, 5, 0, 400, 0, -5)
    # the patch's north-west cell centre is (2.5, 397.5)
    assert p0[0, 0] == pytest.approx(0.1 * 2.5 + 0.2 * 397.5, abs=1e-4)


def test_progress_and_cancel():
    lines, levels = levelled_grid()
    seen = []
    fr.extract_fragments(lines, levels, progress=Progress(report=seen.append))
    assert seen and seen[-1] == pytest.approx(100)
    with pytest.raises(Canceled):
        fr.extract_fragments(lines, levels, progress=Progress(is_canceled=lambda: True))


def test_helsinki_fragments_invariants():
    """Real data: levels from the road hierarchy engine on Helsinki's drivable roads."""
    from helpers import helsinki_roads

    from urban_synthesis.plugin.network import hierarchy
    from urban_synthesis.plugin.network import street_graph as roads

    df = helsinki_roads()
    g = roads.clean_network(df.geometry.values, df.highway.values, None, df.z.values)
    h = hierarchy.road_hierarchy(g, "both", roads.ARTERIAL_CLASSES, 0.1, 45.0)
    levels = h.street_level[h.streets.street_id]
    f = fr.extract_fragments(g.geometry, levels)
    t = f.table
    per_level = f.counts["per_level"]
    assert per_level[0] >= 5 and sum(per_level.values()) >= 50
    assert set(per_level) == set(range(levels.max()))
    assert shapely.is_valid(f.geometry).all()
    # fragments of one level do not overlap
    for level in per_level:
        geoms = f.geometry[t.level.to_numpy() == level]
        a, b = shapely.STRtree(geoms).query(geoms, predicate="overlaps")
        assert not (a != b).any()
    # a fragment of level l + 1 lies inside one fragment of level l or outside all of them
    # (the extract is clipped: deeper streets close faces beyond the outermost arterials),
    # never across a boundary; the fragments inside a parent fit in it
    for level in range(1, max(per_level) + 1):
        child = f.geometry[t.level.to_numpy() == level]
        parent = f.geometry[t.level.to_numpy() == level - 1]
        with np.errstate(invalid="ignore"):
            share = shapely.area(shapely.intersection(child, shapely.union_all(parent))) \
                / shapely.area(child)
        assert ((share < 1e-6) | (share > 1 - 1e-6)).all()
        c_idx, p_idx = shapely.STRtree(parent).query(shapely.point_on_surface(child),
                                                     predicate="within")
        assert len(c_idx) >= 0.3 * len(child)
        filled = np.bincount(p_idx, weights=shapely.area(child[c_idx]), minlength=len(parent))
        assert (filled <= shapely.area(parent) + 1e-3).all()
    assert (f.street_level == t.level.to_numpy()[f.street_fragment] + 1).all()
    assert (t.aspect_ratio > 0).all() and (t.aspect_ratio <= 1).all()


def test_relief_of_a_fragment_off_the_dem_is_unknown_not_flat():
    """A DEM covering only the west: a fragment in the east had relief 0 (flat) beside a
    NULL slope and elevation; its relief is unknown too. The one on the DEM keeps its
    relief (a 10 % slope over 50 m: 5 m, less half a relief cell at each side)."""
    x = np.arange(0, 100, 1.0) + 0.5
    z = np.tile(0.1 * x, (100, 1))
    z[:, 60:] = np.nan
    dem = DemGrid(z, (0, 1.0, 0, 100, 0, -1.0))
    west, east = shapely.box(5, 20, 55, 70), shapely.box(70, 20, 95, 70)
    relief, slope, elevation, _, _ = fr.relief_patches(np.array([west, east]), dem)
    assert relief[0] == pytest.approx(5.0 - 0.1 * fr.RELIEF_CELL_SIZE, abs=0.05)
    assert np.isnan(relief[1]) and np.isnan(elevation[1]) and np.isnan(slope[1])


def test_a_street_split_where_nothing_joins_it_is_one_interior_street():
    """A bridge apart from its approach, or an OSM way cut at an arbitrary point, gives the
    same fragments as the street cut only at its junctions."""
    lines, levels = levelled_grid()
    east_west = np.flatnonzero([g.equals(shapely.LineString([(0, 200), (400, 200)]))
                                for g in lines])[0]

    def cut_at(xs):
        x = [0, *xs, 400]
        pieces = [shapely.LineString([(a, 200), (b, 200)]) for a, b in zip(x[:-1], x[1:])]
        return (np.r_[np.delete(lines, east_west), np.array(pieces, dtype=object)],
                np.r_[np.delete(levels, east_west), np.ones(len(pieces), int)])

    def rows(f):
        return sorted(map(tuple, f.table[["level", "area_m2", "n_interior", "interior_length_m",
                                          "is_block"]].round(6).values.tolist()))

    # x = 100: the level 2 street ends there; x = 200: the level 1 street crosses
    at_junctions = fr.extract_fragments(*cut_at([100, 200]))
    also_at_350 = fr.extract_fragments(*cut_at([100, 200, 350]))
    assert rows(also_at_350) == rows(at_junctions)
    top = also_at_350.street_level == 1
    assert sorted(np.round(shapely.length(also_at_350.street_geometry[top])).tolist()) == \
        [100, 100, 200, 400]
    assert also_at_350.counts["n_unassigned_streets"] == 0
