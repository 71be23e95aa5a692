"""StreetGAN engine (plugin.roads.streetgan): shipped ONNX generators run with onnxruntime (no torch)."""
import json
import shutil

import numpy as np
import pytest
import shapely
import shapely.affinity

from helpers import (assert_ends_meet_exactly, assert_exact_junctions, assert_planar,
                     helsinki_roads, left_out_town, nearly_coincident_streets)
from urban_synthesis.plugin.measure import metrics
from urban_synthesis.plugin.roads import raster_graph
from urban_synthesis.plugin.roads import streetgan
from urban_synthesis.plugin.core.progress import InputError


@pytest.fixture(scope="module")
def models():
    names = streetgan.shipped_models()
    return {n: streetgan.load_model(n) for n in names}


def test_at_least_two_shipped_models_with_cards(models):
    assert len(models) >= 2
    sources = set()
    for name, gen in models.items():
        card = gen.card
        assert gen.path.stat().st_size < 8e6  # small enough to ship
        assert card["cell_size_m"] == 3.0 and card["line_width_px"] == 15
        assert card["input"]["channels"] == 100 and card["scale"] == 32
        t = card["training"]
        assert t["patch_px"] == 32 * (t["noise_m"] - 1) + 1 and t["patch_px"] >= 161
        assert t["epochs"] >= 1 and len(t["losses"]) == t["epochs"]
        assert card["training_data"]["source"]
        sources.add(card["training_data"]["name"])
    assert len(sources) >= 2  # different styles: different training networks


@pytest.mark.parametrize("m", [2, 11, 25])
def test_output_size_is_32_m_minus_1_plus_1(models, m):
    gen = next(iter(models.values()))
    img = gen.run(streetgan.noise(m, m + 1, 100, np.random.default_rng(0)))
    assert img.shape == (32 * (m - 1) + 1, 32 * m + 1)
    assert img.min() >= 0 and img.max() <= 255


def test_tiles_stitch_without_seams(models):
    gen = next(iter(models.values()))
    one = streetgan.generate(gen, 700, 900, seed=4, tile=None)
    tiled = streetgan.generate(gen, 700, 900, seed=4, tile=6)
    assert one.shape == tiled.shape == (700, 900)
    assert np.allclose(one, tiled, atol=0.05)


def test_seeded_and_not_constant(models):
    for gen in models.values():
        a = streetgan.generate(gen, 321, 321, seed=1)
        b = streetgan.generate(gen, 321, 321, seed=1)
        c = streetgan.generate(gen, 321, 321, seed=2)
        assert np.array_equal(a, b) and not np.array_equal(a, c)
        road = (a > 127).mean()
        assert 0.1 < road < 0.9  # roads and blocks, not a blank or saturated image


def _copy(tmp_path, name="streetgan_helsinki"):
    src = streetgan.MODELS_DIR / f"{name}.onnx"
    dst = tmp_path / "model.onnx"
    shutil.copy(src, dst)
    shutil.copy(src.with_suffix(".json"), dst.with_suffix(".json"))
    return dst


def test_model_errors(tmp_path, models):
    with pytest.raises(InputError, match="does not exist"):
        streetgan.load_model(tmp_path / "nothing.onnx")
    with pytest.raises(InputError, match="unknown StreetGAN model"):
        streetgan.load_model("no_such_model")
    path = _copy(tmp_path)
    assert streetgan.load_model(path).channels == 100
    # corrupt file: the card's checksum no longer matches
    data = bytearray(path.read_bytes())
    data[len(data) // 2:len(data) // 2 + 64] = bytes(64)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="corrupt"):
        streetgan.load_model(path)
    # no checksum in the card: onnxruntime itself refuses the garbage
    card = json.loads(path.with_suffix(".json").read_text())
    card.pop("onnx_sha256")
    path.with_suffix(".json").write_text(json.dumps(card))
    path.write_bytes(b"not an onnx model at all")
    with pytest.raises(InputError, match="not a valid ONNX model"):
        streetgan.load_model(path)
    # missing and unreadable card
    path = _copy(tmp_path)
    path.with_suffix(".json").write_text("{broken")
    with pytest.raises(InputError, match="cannot be read"):
        streetgan.load_model(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(InputError, match="card .* is missing"):
        streetgan.load_model(path)
    # a card that promises another channel count than the network takes
    path = _copy(tmp_path)
    card = json.loads(path.with_suffix(".json").read_text())
    card["input"]["channels"] = 3
    path.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(InputError, match="takes 100 input channels, its card says 3"):
        streetgan.load_model(path)
    # wrong input size / channel count at run time
    gen = next(iter(models.values()))
    with pytest.raises(InputError, match=r"noise of shape \(1, 100"):
        gen.run(np.zeros((1, 3, 11, 11), np.float32))
    with pytest.raises(InputError, match="at least 2 x 2"):
        gen.run(np.zeros((1, 100, 1, 5), np.float32))


@pytest.mark.parametrize("key, value, message", [
    (("cell_size_m",), 0, "cell_size_m must be a number above 0, not 0"),
    (("cell_size_m",), -3, "cell_size_m must be a number above 0, not -3"),
    (("scale",), 0, "scale must be a whole number of 1 or more, not 0"),
    (("scale",), "abc", "scale must be a whole number of 1 or more, not 'abc'"),
    (("input",), "x", "input must be a JSON object, not 'x'"),
    (("line_width_px",), 0, "line_width_px must be a whole number of 1 or more"),
    (("postprocess", "erosions"), -1, "postprocess.erosions must be a whole number of 0 or more"),
    (("postprocess", "min_dead_end_m"), "25",
     "postprocess.min_dead_end_m must be a number of 0 or more"),
])
def test_model_card_with_unusable_numbers_is_refused(tmp_path, key, value, message):
    """A hand-edited card: a zero scale was a ZeroDivisionError, a string a TypeError or
    AttributeError ("a defect of Urban Synthesis"), a zero or negative cell size blamed the
    target ("the cell size must be a positive number of metres, not None")."""
    path = _copy(tmp_path)
    card = json.loads(path.with_suffix(".json").read_text())
    holder = card
    for k in key[:-1]:
        holder = holder.setdefault(k, {})
    holder[key[-1]] = value
    path.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(InputError, match=f"model card model.json: {message}"):
        streetgan.load_model(path)


def _window_metrics(lines, window):
    parts = shapely.get_parts(shapely.intersection(np.asarray(lines, dtype=object), window))
    parts = parts[(shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.01)]
    return metrics.compute_layout_metrics(roads=parts, area=window.buffer(-2.0))


def test_helsinki_model_against_helsinki(models):
    """Generated vs training network in the same window: planar, clipped, dead ends per km²
    within 2x of the example's, block areas closer to Helsinki's than a random-noise image's."""
    lines = np.asarray(helsinki_roads().geometry.values, dtype=object)
    x0, y0, x1, y1 = shapely.total_bounds(lines)
    window = shapely.box(0, 0, x1 - x0 - 60, y1 - y0 - 60)
    real = _window_metrics(shapely.transform(lines, lambda c: c - [x0 + 30, y0 + 30]), window)
    res = streetgan.synthesize(window, models["streetgan_helsinki"], seed=1)
    assert len(res.geometry) > 20
    assert_planar(res.geometry)
    assert shapely.covers(window.buffer(1e-6), res.geometry).all()
    assert set(np.unique(res.level)) >= {0, 1}
    gen = _window_metrics(res.geometry, window)
    ratio = gen.scalar("roads", "dead_ends_per_km2") / real.scalar("roads", "dead_ends_per_km2")
    assert 0.5 <= ratio <= 2.0
    rr, cc = res.image.shape
    noise = raster_graph.raster_to_graph(np.random.default_rng(1).uniform(0, 255, (rr, cc)),
                                         res.geotransform)
    base = _window_metrics(noise.geometry, window)
    d_gen = metrics.two_sample(gen.distribution("blocks", "area"), real.distribution("blocks", "area"))
    d_base = metrics.two_sample(base.distribution("blocks", "area"), real.distribution("blocks", "area"))
    assert d_gen["wasserstein_norm"] < d_base["wasserstein_norm"]


def test_given_roads_are_kept_and_joined(models):
    """An arterial through the target and a motorway along one edge: the arterial is kept
    whole, generated streets end on it (junctions from both sides) and never run in its
    corridor, the motorway gets no junction, and the result is one network whose every
    contact is a junction."""
    from urban_synthesis.plugin.network import invariants

    target = shapely.box(0, 0, 1500, 1200)
    arterial = shapely.LineString([(-100, 610), (700, 560), (1600, 640)])
    motorway = shapely.LineString([(-100, 40), (1600, 60)])
    res = streetgan.synthesize(target, models["streetgan_helsinki"], seed=2,
                               given=[arterial, motorway], given_class=["primary", "motorway"])
    kept = shapely.union_all(res.geometry[res.given])
    assert kept.length == pytest.approx(arterial.length + motorway.length, rel=1e-9)
    new = res.geometry[~res.given]
    check = invariants.check_network(new, [arterial, motorway], ["primary", "motorway"],
                                     target, target=target)
    v = check.violations()
    v.pop("dead_end_share")
    assert sum(v.values()) == 0, check.summary()
    assert check.floating_pieces == 0
    # streets end on the arterial, from both sides: at least one junction per 400 m of its
    # 1.5 km in the target (the Liechtenstein towns' level-0 roads have one per 150-700 m;
    # with the card's read-back this model makes 5-10 here over seeds 0-7, the thesis's
    # five dilations made 10-29)
    ends = shapely.points(shapely.get_coordinates(shapely.boundary(new)))
    assert shapely.dwithin(arterial, ends, 1e-6).sum() >= 4
    near = new[shapely.dwithin(new, arterial, 1e-6)]
    mid = shapely.get_coordinates(shapely.line_interpolate_point(near, 0.5, normalized=True))
    sides = np.sign(mid[:, 1] - np.interp(mid[:, 0], [-100, 700, 1600], [610, 560, 640]))
    assert set(sides) == {-1.0, 1.0}
    assert not shapely.dwithin(motorway, new, 1.0).any()
    assert (res.level[res.given] == 0).all() and (res.level[~res.given] >= 1).all()
    # split where the streets meet it, the arterial's pieces end at the streets' ends
    assert_exact_junctions(res.geometry)
    # the same seed gives the same network
    again = streetgan.synthesize(target, models["streetgan_helsinki"], seed=2,
                                 given=[arterial, motorway], given_class=["primary", "motorway"])
    assert len(again.geometry) == len(res.geometry)
    assert shapely.equals_exact(again.geometry, res.geometry, 0.0).all()


def test_a_floating_piece_joins_through_a_piece_that_joined_first():
    """Two generated streets parallel to a given road, 60 m and 140 m from it: with
    connectors up to 90 m the near one joins the road and the far one joins the near one
    (the walk's REPEAT); nothing is dropped and every contact is a junction."""
    road = shapely.LineString([(0, 0), (1000, 0)])
    near = shapely.LineString([(300, 60), (600, 60)])
    far = shapely.LineString([(300, 140), (600, 140)])
    lines, is_given, stats = streetgan.attach_to_given([near, far], [road], ["residential"],
                                                       join_distance=90.0)
    assert stats["n_joined"] == 2 and stats["n_dropped_edges"] == 0
    assert stats["n_components"] == 1
    new = lines[~is_given]
    assert shapely.length(new).sum() == pytest.approx(600 + 60 + 80, abs=1e-6)
    assert_planar(lines)
    # out of reach of both (a third street 200 m beyond): dropped, and said so
    lost = shapely.LineString([(300, 340), (600, 340)])
    _, _, stats = streetgan.attach_to_given([near, far, lost], [road], ["residential"],
                                            join_distance=90.0)
    assert stats["n_joined"] == 2 and stats["dropped_m"] == pytest.approx(300.0)


def test_a_target_in_two_parts_apart_gets_a_network_in_each(models):
    """Two squares 400 m apart, no given roads: the longest piece anchored and no link
    inside the target reaches the other square, so all its streets were dropped (the first
    square left empty on seeds 1 and 2). Each part now anchors its own longest piece."""
    first = shapely.box(0, 0, 500, 500)
    second = shapely.box(900, 0, 1300, 400)
    res = streetgan.synthesize(shapely.MultiPolygon([first, second]), "streetgan_towns", seed=1)
    for part in (first, second):
        assert shapely.intersects(res.geometry, part).sum() >= 5


def test_a_dead_end_length_given_in_metres_stays_metres_at_another_cell_size():
    """CELL_SIZE 6 m (twice the model's 3 m) with MIN_DEAD_END 50 m: the given 50 m was
    scaled with the network to 100 m, so a spur of about 80 m was removed. A length the
    user gives is metres; only the card's own length scales with the cell size."""
    def road_with_a_spur(gen, rows, cols, seed, tile, progress):
        img = np.zeros((rows, cols), np.float32)
        r, c = rows // 2, cols // 2
        img[r - 2:r + 3, :] = 255            # a road across, 5 px wide
        img[r - 16:r, c - 2:c + 3] = 255     # a spur 16 px (96 m) up from its centre line
        return img

    def edges(min_dead_end):
        return streetgan.synthesize(shapely.box(0, 0, 600, 600), "streetgan_towns",
                                    cell_size=6.0, min_dead_end=min_dead_end, levels=False,
                                    generate_fn=road_with_a_spur).geometry

    assert len(edges(50.0)) == 3            # the road on both sides of the spur, the spur
    assert len(edges(100.0)) == 1           # the spur is under 100 m
    # the card's 25 m is the model's length: doubled with the network (the spur stays)
    assert len(edges(None)) == 3


def test_a_large_piece_is_worth_a_longer_street_to_it():
    """A part of the settlement the generator drew apart from the rest (a grid of 2.4 km of
    streets, 250 m from the given road) joins by a 250 m street: up to half of its own
    streets (PIECE_LINK_SHARE), at most MAX_PIECE_LINK; a single 300 m street as far off
    (it may take 150 m), or the same grid beyond MAX_PIECE_LINK, is dropped (connectors up
    to 90 m)."""
    road = shapely.LineString([(0, 0), (1000, 0)])
    grid = [shapely.LineString([(300, y), (600, y)]) for y in (250, 350, 450, 550)] + \
        [shapely.LineString([(x, 250), (x, 550)]) for x in (300, 400, 500, 600)]
    lines, is_given, stats = streetgan.attach_to_given(grid, [road], ["residential"],
                                                       join_distance=90.0)
    assert stats["n_joined"] == 1 and stats["n_dropped_edges"] == 0
    assert stats["n_components"] == 1
    new = lines[~is_given]
    assert shapely.length(new).sum() == pytest.approx(2400 + 250, abs=1e-6)
    assert_planar(lines)
    single = shapely.LineString([(300, 250), (600, 250)])
    _, _, stats = streetgan.attach_to_given([single], [road], ["residential"],
                                            join_distance=90.0)
    assert stats["n_joined"] == 0 and stats["dropped_m"] == pytest.approx(300.0)
    beyond = shapely.affinity.translate(shapely.MultiLineString(grid), 0,
                                        streetgan.MAX_PIECE_LINK)
    _, _, stats = streetgan.attach_to_given(list(beyond.geoms), [road], ["residential"],
                                            join_distance=90.0)
    assert stats["n_joined"] == 0 and stats["dropped_m"] == pytest.approx(2400.0)


def test_given_roads_apart_are_joined_through_the_streets():
    """A lane the level-0 roads do not reach (in the benchmark: Gamprin, Triesen,
    Triesenberg and Helsinki's given roads are two pieces each): the shortest clear street
    joins it to the rest, here from the generated street whose end is nearest (the real
    streets join them); a motorway apart takes no junction; every given road stays whole."""
    road = shapely.LineString([(0, 0), (1000, 0)])
    lane = shapely.LineString([(300, 200), (600, 200)])
    street = shapely.LineString([(450, 0), (450, 120)])     # on the road, 80 m short of the lane
    lines, is_given, stats = streetgan.attach_to_given([street], [road, lane],
                                                       ["primary", "unclassified"],
                                                       join_distance=90.0)
    assert stats["n_given_joined"] == 1 and stats["n_components"] == 1
    assert shapely.length(lines[~is_given]).sum() == pytest.approx(120 + 80, abs=1e-6)
    assert shapely.length(lines[is_given]).sum() == pytest.approx(1300, abs=1e-6)
    assert_planar(lines)
    # the lane a motorway: no street ends on it, and it is kept as it is
    lines, is_given, stats = streetgan.attach_to_given([street], [road, lane],
                                                       ["primary", "motorway"],
                                                       join_distance=90.0)
    assert stats["n_given_joined"] == 0 and stats["n_components"] == 2
    assert shapely.length(lines[is_given]).sum() == pytest.approx(1300, abs=1e-6)
    # out of reach (a 300 m lane takes a link of up to 90 m): apart, nothing dropped
    far = shapely.affinity.translate(lane, 0, 100)
    lines, is_given, stats = streetgan.attach_to_given([street], [road, far],
                                                       ["primary", "unclassified"],
                                                       join_distance=90.0)
    assert stats["n_given_joined"] == 0 and stats["n_components"] == 2
    assert stats["n_dropped_edges"] == 0


def test_dead_end_share_is_steered_into_the_examples_band(models):
    """The read-back leaves the dead-end share where the morphology puts it; with the
    example's share given, it is steered into the invariants' band (±30 %) both ways, the
    given roads kept whole, every other invariant kept."""
    from urban_synthesis.plugin.network import invariants

    target = shapely.box(0, 0, 1500, 1200)
    arterial = shapely.LineString([(-100, 610), (700, 560), (1600, 640)])
    plain = streetgan.synthesize(target, models["streetgan_helsinki"], seed=2,
                                 given=[arterial], given_class=["primary"])
    own = invariants.dead_end_share(plain.geometry, target)
    for share in (0.7 * own, 1.6 * own):
        res = streetgan.synthesize(target, models["streetgan_helsinki"], seed=2,
                                   given=[arterial], given_class=["primary"],
                                   dead_end_share=share)
        kept = shapely.union_all(res.geometry[res.given])
        assert kept.length == pytest.approx(arterial.length, rel=1e-9)
        check = invariants.check_network(res.geometry[~res.given], [arterial], ["primary"],
                                         target, example_dead_end_share=share)
        assert check.ok, (share, own, check.summary())
        assert res.stats["dead_ends_closed"] + res.stats["dead_ends_opened"] > 0
    with pytest.raises(InputError, match="dead-end share"):
        streetgan.synthesize(target, models["streetgan_helsinki"], dead_end_share=1.5)
    with pytest.raises(InputError, match="smallest block area"):
        streetgan.synthesize(target, models["streetgan_helsinki"], min_block_area=-5.0)


def test_a_dead_end_no_street_reaches_is_pruned(models):
    """Bubenec from the towns model with Helsinki's dead-end share, seed 1: the dead
    ends read back put the share above the band around 0.18, and none is within reach of
    another street, so no closing street can be drawn (found with the earlier towns model,
    seed 4 of the fidelity benchmark, where the share stayed out of the band). The
    shortest dead-end streets are removed where their other end stays a junction (two
    here, no street closed); the network stays one piece, inside the band."""
    from towns import bubenec_town, helsinki_town
    from urban_synthesis.plugin.measure import fidelity
    from urban_synthesis.plugin.network import invariants

    target, example = bubenec_town(), helsinki_town()
    share = fidelity.fidelity_statistics(example.lines, example.area)["degree1_share"]
    res = streetgan.synthesize(target.area, models["streetgan_towns"], seed=1,
                               given=target.given, given_class=target.given_class,
                               dead_end_share=share)
    check = invariants.check_network(res.geometry[~res.given], target.given,
                                     target.given_class, target.area,
                                     example_dead_end_share=share)
    assert check.ok, check.summary()
    assert res.stats["dead_ends_closed"] >= 1


@pytest.mark.parametrize("seed", [2, 4])
def test_dead_ends_stay_in_their_band_after_the_crossings(models, seed):
    """Bubenec (about nine counted nodes: one dead end is 0.11 of the share, the band around
    Helsinki's 0.18 is 0.13-0.23) with every example statistic the fidelity benchmark passes:
    the crossings, matched after the dead ends were steered, moved the towns model's share
    out of the band in these runs (0.07 and 0.12). The dead ends are steered once more where
    the share left it: every invariant holds."""
    from towns import bubenec_town, helsinki_town
    from urban_synthesis.plugin.measure import fidelity
    from urban_synthesis.plugin.network import invariants

    target, example = bubenec_town(), helsinki_town()
    stats = fidelity.fidelity_statistics(example.lines, example.area)
    res = streetgan.synthesize(target.area, models["streetgan_towns"], seed=seed,
                               given=target.given, given_class=target.given_class,
                               **streetgan.example_steering(stats))
    check = invariants.check_network(res.geometry[~res.given], target.given,
                                     target.given_class, target.area,
                                     example_dead_end_share=stats["degree1_share"])
    assert check.ok, check.summary()


def test_no_street_ends_a_few_decimetres_from_a_junction(models):
    """Balzers from the other Liechtenstein towns' statistics (the fidelity benchmark's seed
    1, the Helsinki model: it never saw Balzers): a generated street ended 13 cm from
    another's end and two 7-11 cm from a junction, one network to the invariants, which
    merge nodes within 0.5 m, but two gaps to a tool that joins lines only where they
    share a point. Such ends are one point now, and no street of a few decimetres is left
    between them."""
    from urban_synthesis.plugin.measure import fidelity
    from urban_synthesis.plugin.network import invariants

    target, others = left_out_town("Balzers")
    stats = fidelity.fidelity_statistics(np.concatenate([t.lines for t in others]),
                                         shapely.union_all([t.area for t in others]))
    res = streetgan.synthesize(target.area, models["streetgan_helsinki"], seed=1,
                               given=target.given, given_class=target.given_class,
                               **streetgan.example_steering(stats))
    assert_ends_meet_exactly(res.geometry, of=~res.given)
    assert_exact_junctions(res.geometry)
    check = invariants.check_network(res.geometry[~res.given], target.given,
                                     target.given_class, target.area,
                                     example_dead_end_share=stats["degree1_share"],
                                     target=target.area)
    assert check.ok, check.summary()


def test_the_given_pieces_on_a_motorway_take_no_street_across():
    """Which noded lines a street going on across may end on: generated ones and given
    pieces off the motorways and trunks (invariants.CONTROLLED_ACCESS)."""
    motorway = shapely.LineString([(0, 0), (200, 0)])
    primary = shapely.LineString([(0, 100), (200, 100)])
    lines = np.array([shapely.LineString([(0, 0), (100, 0)]),        # motorway, piece 1
                      shapely.LineString([(100, 0), (200, 0)]),      # motorway, piece 2
                      shapely.LineString([(0, 100), (200, 100)]),    # primary
                      shapely.LineString([(100, 0), (100, 100)])],   # generated, ends on both
                     dtype=object)
    is_given = np.array([True, True, True, False])
    given, cls = np.array([motorway, primary], dtype=object), np.array(["motorway", "primary"])
    closed = given[~streetgan._open_roads(cls)]
    assert streetgan._on_roads(lines, is_given, closed).tolist() == [True, True, False, False]


def test_new_streets_whose_noding_fails_are_snap_rounded():
    """Generated streets that defeat GEOS's floating-point noding are noded on the
    millimetre grid: planar, every street kept to that grid."""
    lines = nearly_coincident_streets()
    noded, is_given = streetgan._noded_with_given(lines, [])
    assert_planar(noded)
    assert not is_given.any()
    assert shapely.covers(shapely.buffer(shapely.union_all(noded), 1e-3), lines).all()
