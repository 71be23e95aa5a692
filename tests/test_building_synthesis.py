"""Engine tests of building_attribute_transfer and building_bestfit (plain shapely)."""
import math
from functools import lru_cache

import numpy as np
import pandas as pd
import pytest
import shapely
import shapely.affinity

from conftest import HELSINKI
from helpers import bubenec
from urban_synthesis.plugin.network import blocks
from urban_synthesis.plugin.buildings import attributes as building_attributes
from urban_synthesis.plugin.measure import metrics
from urban_synthesis.plugin.parcels import subdivision as parcels
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.buildings import attribute_transfer as bt
from urban_synthesis.plugin.buildings import bestfit as bf
from urban_synthesis.plugin.core.progress import InputError


# --------------------------------------------------------------------------- attributes

def test_features_of_known_shapes():
    squares = np.array([shapely.box(x, 0, x + 10, 10) for x in (0, 20)] +
                       [shapely.box(1000, 0, 1040, 10)], dtype=object)
    f = bt.footprint_features(squares)
    assert f.log_area.tolist() == pytest.approx([math.log(100)] * 2 + [math.log(400)])
    assert f.compactness[0] == pytest.approx(math.pi / 4)
    assert f.elongation.tolist() == pytest.approx([1.0, 1.0, 0.25])
    # the two squares 20 m apart see each other within 50 m; the far one only itself
    assert f.coverage_50[0] == pytest.approx(200 / (math.pi * 50 ** 2))
    assert f.coverage_50[2] == pytest.approx(400 / (math.pi * 50 ** 2))
    assert f.road_distance.isna().all()
    road = np.array([shapely.LineString([(0, -5), (2000, -5)])], dtype=object)
    f = bt.footprint_features(squares, roads=road, arterials=road)
    assert f.road_distance.tolist() == pytest.approx([math.log1p(5)] * 3)


def _grid(n=10, size=12.0, gap=8.0):
    return np.array([shapely.box(i * (size + gap), j * (size + gap), i * (size + gap) + size,
                                 j * (size + gap) + size)
                     for i in range(n) for j in range(n)], dtype=object)


def test_copy_itself_clip_and_far():
    ex = _grid()
    rng = np.random.default_rng(0)
    ex = np.array([shapely.affinity.scale(g, s, s) for g, s in
                   zip(ex, rng.uniform(0.5, 1.2, len(ex)))], dtype=object)
    h = rng.uniform(6, 40, len(ex)).round(1)
    attrs = pd.DataFrame({"height_m": h, "levels": np.round(h / 3.0),
                          "building_type": ["residential"] * len(ex), "roof_shape": "flat"})
    out = bt.transfer_attributes(ex, ex, attrs, example_ids=np.arange(100, 200), k=1)
    # identical buildings: each copies itself
    assert out.table.source_id.tolist() == list(range(100, 200))
    assert np.allclose(out.table.height_m, h) and np.allclose(out.table.similarity, 1.0)
    clipped = bt.transfer_attributes(ex, ex, attrs, k=1, min_height=10, max_height=30)
    assert clipped.table.height_m.between(10, 30).all()
    assert (clipped.table.levels >= 1).all()
    for far, blk in ((1.5, None), (2.5, [shapely.box(-5, -5, 100, 200),
                                         shapely.box(100, -5, 200, 200)])):
        r = bt.transfer_attributes(ex, ex, attrs, k=3, seed=1, target_far=far, blocks=blk)
        a = shapely.area(ex)
        ground = [shapely.area(shapely.convex_hull(shapely.union_all(ex)))] if blk is None \
            else shapely.area(blk)
        groups = [np.ones(len(ex), bool)] if blk is None else \
            [shapely.within(shapely.point_on_surface(ex), b) for b in blk]
        for g, ga in zip(groups, ground):
            achieved = float((a[g] * r.table.levels.to_numpy()[g]).sum() / ga)
            # within one storey of the smallest footprint of the group
            assert abs(achieved - far) <= a[g].min() / ga + 1e-9
        assert r.stats["far_min"] == pytest.approx(far, abs=0.01)
    # a block its footprints cannot fill to the target under the height limit: the shed in
    # it goes to the limit, and the stats say the block stays short and the shed is capped
    shed = np.array([shapely.box(0, 0, 4, 4), shapely.box(200, 0, 230, 30)], dtype=object)
    blocks = [shapely.box(-10, -10, 120, 120), shapely.box(190, -10, 240, 40)]
    r = bt.transfer_attributes(shed, ex, attrs, k=3, seed=1, target_far=1.0, blocks=blocks,
                               max_height=60)
    assert r.stats["n_blocks_short_of_far"] == 1 and r.stats["n_at_max_height"] == 1
    assert r.table.height_m.iloc[0] <= 60 and r.table.height_m.iloc[1] < 60
    # examples without heights: types come across, heights and levels stay empty
    bare = attrs.assign(height_m=np.nan, levels=np.nan)
    r = bt.transfer_attributes(ex, ex, bare)
    assert r.table["height_m"].isna().all() and r.table["levels"].isna().all()
    assert (r.table["building_type"] == "residential").all()
    with pytest.raises(InputError, match="no example building has a height"):
        bt.transfer_attributes(ex, ex, bare, target_far=2.0)
    with pytest.raises(InputError, match="height range"):
        bt.transfer_attributes(ex, ex, attrs, min_height=50, max_height=20)


@lru_cache(maxsize=1)
def helsinki_buildings():
    import pyogrio

    df = pyogrio.read_dataframe(HELSINKI, layer="multipolygons", on_invalid="ignore")
    df = df[df.building.notna() & df.geometry.notna()].to_crs(32635).reset_index(drop=True)
    g = shapely.make_valid(df.geometry.values)
    g = np.array([shapely.union_all([p for p in shapely.get_parts(x)
                                     if shapely.get_type_id(p) == 3]) for x in g], dtype=object)
    ok = np.isin(shapely.get_type_id(g), (3, 6)) & ~shapely.is_empty(g)
    df, g = df[ok].reset_index(drop=True), g[ok]
    attrs = building_attributes.building_attributes(
        len(df), building=df.building.values, other_tags=df.other_tags.values,
        tags={k: df[k].values for k in ("amenity", "shop", "office")})
    lines = pyogrio.read_dataframe(HELSINKI, layer="lines")
    lines = lines[lines.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(32635)
    rl = lines.geometry.values
    art = rl[lines.highway.isin(roads.ARTERIAL_CLASSES).values]
    bl = blocks.extract_blocks(roads.clean_network(rl, lines.highway.values)).geometry
    return g, attrs, rl, art, bl


def hidden_height_experiment(seed=0, share=0.3, k=9, choice_mode="medoid"):
    """Hide ``share`` of the known Helsinki heights, predict them; MAE of ours and of the
    block-median baseline, and the predictions."""
    g, attrs, rl, art, bl = helsinki_buildings()
    known = np.flatnonzero(np.isfinite(attrs.height_m.to_numpy(float)))
    hide = np.random.default_rng(seed).choice(known, size=round(share * len(known)),
                                              replace=False)
    shown = attrs.copy()
    shown.loc[hide, ["height_m", "levels"]] = np.nan
    r = bt.transfer_attributes(g[hide], g, shown, k=k, seed=seed, choice_mode=choice_mode,
                               footprint_context=g, roads=rl, arterials=art,
                               example_roads=rl, example_arterials=art)
    truth = attrs.height_m.to_numpy(float)[hide]
    base = bt.block_median_baseline(g, shown.height_m.to_numpy(float), bl)[hide]
    return dict(mae=float(np.mean(np.abs(r.table.height_m - truth))),
                baseline_mae=float(np.mean(np.abs(base - truth))), predicted=r.table,
                truth=truth, example_heights=shown.height_m.dropna().to_numpy(float),
                example_types=attrs.building_type.to_numpy()[known], n_hidden=len(hide))


def test_helsinki_hidden_heights_beat_block_median():
    e = hidden_height_experiment(seed=0)
    print(f"Helsinki, {e['n_hidden']} hidden heights: MAE {e['mae']:.2f} m, "
          f"block median {e['baseline_mae']:.2f} m")
    assert e["mae"] < e["baseline_mae"]
    # the predicted heights follow the example's distribution (one example spread apart
    # is 1.0) and the types come from the example's vocabulary
    d = metrics.two_sample(e["predicted"].height_m, e["example_heights"])
    assert d["wasserstein_norm"] < 0.35, d
    assert set(e["predicted"].building_type) <= set(building_attributes.BUILDING_TYPES)


def test_random_choice_is_seeded_and_keeps_the_spread():
    g, attrs, *_ = helsinki_buildings()
    known = np.isfinite(attrs.height_m.to_numpy(float))
    a = bt.transfer_attributes(g, g[known], attrs[known].reset_index(drop=True), k=9, seed=4,
                               choice_mode="random")
    b = bt.transfer_attributes(g, g[known], attrs[known].reset_index(drop=True), k=9, seed=4,
                               choice_mode="random")
    c = bt.transfer_attributes(g, g[known], attrs[known].reset_index(drop=True), k=9, seed=5,
                               choice_mode="random")
    assert a.table.equals(b.table) and not a.table.source_id.equals(c.table.source_id)
    ex_h = attrs.height_m.to_numpy(float)[known]
    assert metrics.two_sample(a.table.height_m, ex_h)["wasserstein_norm"] < 0.3
    # types: every example type appears with a share close to the example's
    share = pd.Series(a.table.building_type).value_counts(normalize=True)
    ex_share = pd.Series(attrs.building_type[known]).value_counts(normalize=True)
    assert (share.reindex(ex_share.index).fillna(0) - ex_share).abs().max() < 0.15


# --------------------------------------------------------------------------- best fit

def test_parse_sides():
    assert bf.parse_sides("0, 2", 4, "x") == (0, 2)
    assert bf.parse_sides(None, 4, "x") == () and bf.parse_sides("", 4, "x") == ()
    assert bf.parse_sides(3, 4, "x") == (3,)
    with pytest.raises(InputError, match="edge 4 does not exist"):
        bf.parse_sides("4", 4, "x")
    with pytest.raises(InputError, match="not a list"):
        bf.parse_sides("front", 4, "x")
    with pytest.raises(InputError, match="both street access and blind"):
        bf.library_from_table([shapely.box(0, 0, 5, 5)], ["0"], ["0,1"])


def _ray_hit(mid, normal, lines, reach, step=0.25):
    """Independent facing test: march along the normal until a road is within 0.2 m;
    return the road's direction there (unit vector) or None."""
    for t in np.arange(step, reach + step, step):
        p = shapely.Point(mid + normal * t)
        d = shapely.distance(p, lines)
        if d.min() < 0.2:
            line = lines[int(np.argmin(d))]
            c = np.asarray(line.coords)[:, :2]
            seg = np.argmin([shapely.distance(p, shapely.LineString(c[i:i + 2]))
                             for i in range(len(c) - 1)])
            v = c[seg + 1] - c[seg]
            return v / np.hypot(*v)
    return None


def assert_constraints(result, parcels_geoms, parcel_ids, lines, library, reach):
    """Every placed building inside its parcel, equal to its library footprint moved by
    rotation and offset, access sides facing a street (±30°), blind sides not."""
    by_id = dict(zip(parcel_ids, parcels_geoms))
    lib = {b.source_id: b for b in library}
    cos30 = math.cos(math.radians(30.0))
    for g, row in zip(result.geometry, result.table.itertuples()):
        parcel = by_id[row.parcel_id]
        assert parcel.buffer(1e-6).contains(g)
        b = lib[row.source_id]
        moved = shapely.affinity.translate(shapely.affinity.rotate(
            b.footprint, row.rotation, origin=b.footprint.centroid), row.offset_x, row.offset_y)
        assert shapely.equals_exact(moved, g, 1e-6)
        mids, dirs, normals = bf.side_normals(np.asarray(g.exterior.coords))
        for i in b.access:
            v = _ray_hit(mids[i], normals[i], lines, reach)
            assert v is not None and abs(v @ dirs[i]) >= cos30 - 1e-6, (row, i)
        for i in b.blind:
            v = _ray_hit(mids[i], normals[i], lines, reach)
            assert v is None or abs(v @ dirs[i]) < cos30 + 1e-6, (row, i)


def test_fit_on_a_street():
    # three parcels south of an east-west street, one in the corner of a north-south one
    street = [shapely.LineString([(-50, 0), (200, 0)]), shapely.LineString([(75, -100), (75, 0)])]
    plots = [shapely.box(0, -35, 20, -5), shapely.box(20, -40, 70, -5),
             shapely.box(80, -30, 90, -5), shapely.box(0, -80, 7, -70)]
    lib = bf.default_library()
    r = bf.fit_buildings(plots, street, lib, min_setback=2.0)
    assert r.stats["n_placed"] == 3 and r.stats["no_street"] == 1
    assert r.stats["empty_share"] == pytest.approx(0.25)
    assert_constraints(r, plots, [1, 2, 3, 4], np.array(street, dtype=object), lib, 20.0)
    # the largest that fits: the 36 x 20 office (720 m²) in the 50 x 35 parcel
    row = r.table.set_index("parcel_id").loc[2]
    assert row.source_id == 9 and row.area_m2 == pytest.approx(720)
    # moved to the street keeping the setback: front side at y = -5 - 2
    assert shapely.bounds(r.geometry[1])[3] == pytest.approx(-7.0)
    # a 7 m x 12 m row house with blind side walls (edges 1, 3) may not sit on the corner
    # lot where its side would face the north-south street
    row_house = [b for b in lib if b.attributes["name"] == "terraced house"]
    corner = [shapely.box(76.5, -15, 84.5, -4)]
    r = bf.fit_buildings(corner, street, row_house, min_setback=0.0)
    assert r.stats["n_placed"] == 0
    r = bf.fit_buildings([shapely.box(120, -17, 128, -4)], street, row_house)
    assert r.stats["n_placed"] == 1


def test_a_street_drawn_on_the_parcel_side_faces_it():
    """A parcel whose front lies on the road's centre line (blocks cut by their streets'
    centre lines, a cadastre drawn to them) faces that road, as one a metre off does."""
    lib = bf.default_library()
    for gap in (0.0, 1.0):
        street = [shapely.LineString([(-50, gap), (200, gap)])]
        r = bf.fit_buildings([shapely.box(0, -36, 60, 0)], street, lib, min_setback=2.0)
        assert r.stats["n_placed"] == 1 and r.stats["no_street"] == 0, gap
        assert_constraints(r, [shapely.box(0, -36, 60, 0)], [1], np.array(street, dtype=object),
                           lib, 20.0)


def _clear_of(result, lines, setback):
    """No placed building crosses a road centreline; each keeps the setback from all."""
    lines = np.asarray(lines, dtype=object)
    for g in result.geometry:
        assert not shapely.intersects(g, lines).any()
        assert shapely.distance(g, lines).min() >= setback - 1e-6


def test_fit_keeps_clear_of_a_road_through_the_parcel():
    """A road centreline running into (a dead end) or across a parcel (parcels made from
    blocks that cover their dead-end streets) is a street side for the setback: no
    building crosses it or comes nearer than the minimum setback (buildings were placed
    across such roads); a parcel with no room left beside it stays empty, counted."""
    lib = bf.default_library()
    parcel = [shapely.box(0, -40, 60, -5)]
    street = shapely.LineString([(-50, 0), (200, 0)])
    dead_end = shapely.LineString([(20, 0), (20, -25)])
    for setback in (2.0, 0.0):
        r = bf.fit_buildings(parcel, [street, dead_end], lib, min_setback=setback)
        assert r.stats["n_placed"] == 1 and r.stats["crossed_by_road"] == 0, setback
        _clear_of(r, [street, dead_end], setback)
        assert_constraints(r, parcel, [1], np.array([street, dead_end], dtype=object), lib,
                           20.0)
    # (off the middle: a perpendicular road hit first hides the street from the side's
    # ray.) Without the dead end the 36 m office sits on the middle, across it
    r = bf.fit_buildings(parcel, [street], lib, min_setback=2.0)
    assert r.table.source_id.tolist() == [9] and shapely.intersects(r.geometry[0], dead_end)
    # a road across the whole parcel: the building lies on one side of it, clear by 2 m
    across = shapely.LineString([(20, 10), (20, -60)])
    r = bf.fit_buildings(parcel, [street, across], lib, min_setback=2.0)
    assert r.stats["n_placed"] == 1
    _clear_of(r, [street, across], 2.0)
    x0, _, x1, _ = shapely.bounds(r.geometry[0])
    assert x1 <= 18 + 1e-6 or x0 >= 22 - 1e-6
    # a road across a small parcel leaves 6 m, no room for the narrowest house (7 m): empty,
    # counted as crossed by a road, not as no fit; without that road a house fits
    small = [shapely.box(0, -17, 10, -5)]
    r = bf.fit_buildings(small, [street, shapely.LineString([(3, 10), (3, -30)])], lib)
    assert r.stats["n_placed"] == 0 and r.stats["crossed_by_road"] == 1
    assert r.stats["no_fit"] == 0
    r = bf.fit_buildings(small, [street], lib)
    assert r.stats["n_placed"] == 1 and r.stats["crossed_by_road"] == 0


def test_fit_on_a_slope_sinks_to_the_lowest_corner_and_skips_steep_parcels():
    """Scharl ch. 6.2: on a slope the building goes down until every vertex is on the
    ground or beneath; a parcel steeper than maxParcelSlope gets no building."""
    from urban_synthesis.plugin.retrieval.shape_context import DemGrid

    # terrain rising 10 % to the south (y < 0) for x < 100, 40 % beyond x = 100
    cell = 1.0
    x, y = np.meshgrid(np.arange(-60, 220, cell) + 0.5, 20 - np.arange(140) * cell - 0.5)
    z = 100 + np.where(x < 100, -0.10, -0.40) * y
    dem = DemGrid(z, (-60, cell, 0, 20, 0, -cell))
    street = [shapely.LineString([(-50, 0), (210, 0)])]
    gentle, steep = shapely.box(20, -40, 70, -5), shapely.box(120, -40, 170, -5)
    lib = bf.default_library()
    r = bf.fit_buildings([gentle, steep], street, lib, dem=dem, max_parcel_slope=0.25)
    assert r.stats["n_placed"] == 1 and r.stats["too_steep"] == 1
    row = r.table.iloc[0]
    assert row.parcel_id == 1 and row.parcel_slope_pct == pytest.approx(10.0, abs=0.1)
    g = r.geometry[0]
    xy = shapely.get_coordinates(g)
    ground = 100 - 0.10 * xy[:, 1]
    # the base is the lowest corner's ground: every vertex on the ground or beneath
    assert shapely.has_z(g) and np.allclose(shapely.get_coordinates(g, include_z=True)[:, 2],
                                            row.base_z)
    assert row.base_z == pytest.approx(ground.min(), abs=1e-6)
    assert (row.base_z <= ground + 1e-6).all()
    # sunk by the rise across the footprint: 10 % of its depth
    depth = np.ptp(xy[:, 1])
    assert row.sunk_m == pytest.approx(0.10 * depth, abs=1e-6)
    # the limit is Scharl's threshold: at 45 % the steep parcel gets its building too
    r = bf.fit_buildings([gentle, steep], street, lib, dem=dem, max_parcel_slope=0.45)
    assert r.stats["n_placed"] == 2 and r.stats["too_steep"] == 0
    # without a DEM nothing changes: flat footprints, no slope columns
    r = bf.fit_buildings([gentle, steep], street, lib)
    assert r.stats["n_placed"] == 2 and not shapely.has_z(r.geometry).any()
    assert r.table.base_z.isna().all()


def test_fit_where_the_dem_has_no_value_leaves_the_parcel_empty_and_says_so():
    """A DEM with a hole over one parcel and ending inside another: neither gets a
    building at a guessed height (they crashed on a NaN base height, or were counted as
    too steep), the third one, on the terrain, gets its building."""
    from urban_synthesis.plugin.retrieval.shape_context import DemGrid

    cell = 1.0
    x, y = np.meshgrid(np.arange(-60, 220, cell) + 0.5, 20 - np.arange(140) * cell - 0.5)
    z = 100 - 0.10 * y
    z[(x > 10) & (x < 80)] = np.nan            # a hole over the first parcel
    z[x > 150] = np.nan                        # the DEM ends inside the third
    dem = DemGrid(z, (-60, cell, 0, 20, 0, -cell))
    street = [shapely.LineString([(-50, 0), (210, 0)])]
    in_hole, on_terrain, at_edge = (shapely.box(20, -40, 70, -5), shapely.box(90, -40, 140, -5),
                                    shapely.box(145, -40, 195, -5))
    r = bf.fit_buildings([in_hole, on_terrain, at_edge], street, bf.default_library(),
                         dem=dem, max_parcel_slope=0.25)
    assert r.stats["n_placed"] == 1 and r.table.parcel_id.tolist() == [2]
    assert r.stats["no_terrain"] == 2 and r.stats["too_steep"] == 0
    assert np.isfinite(r.table.base_z).all()


@pytest.fixture(scope="module")
def bubenec_inputs():
    streets = bubenec("streets").geometry.values
    plots = bubenec("plots").geometry.values
    bl = blocks.extract_blocks(roads.clean_network(streets)).geometry
    sub = parcels.subdivide_blocks(bl, "skeleton", seed=1, roads=streets)
    return streets, plots, sub.geometry, sub.table.parcel_id.to_numpy()


@pytest.mark.parametrize("which", ["cadastre", "subdivided"])
def test_bubenec_best_fit(bubenec_inputs, which):
    streets, plots, sub, sub_ids = bubenec_inputs
    geoms, ids = (plots, np.arange(1, len(plots) + 1)) if which == "cadastre" else (sub, sub_ids)
    lib = bf.default_library()
    r = bf.fit_buildings(geoms, streets, lib, parcel_ids=ids, min_setback=1.0)
    print(f"Bubeneč {which}: {r.stats}")
    assert r.stats["n_placed"] > 0.3 * len(geoms)
    assert_constraints(r, geoms, ids, np.asarray(streets, dtype=object), lib, bf.DEFAULT_REACH)
    assert shapely.is_valid(r.geometry).all()
    # parcels are disjoint, so the buildings are
    tree = shapely.STRtree(r.geometry)
    i, j = tree.query(r.geometry, predicate="intersects")
    over = shapely.area(shapely.intersection(r.geometry[i[i < j]], r.geometry[j[i < j]]))
    assert (over < 1e-6).all()
