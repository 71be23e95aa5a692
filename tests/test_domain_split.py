"""Engine tests of hierarchical domain splitting (Yang et al. 2013): cross field,
streamlines, templates, road-mesh optimisation and the whole pipeline on real data."""
import json

import numpy as np
import pytest
import shapely

from helpers import (assert_ends_meet_exactly, assert_planar, bubenec,
                     drawn_area_court_template, drawn_court_template, drawn_pentagon_template,
                     left_out_town)
from urban_synthesis.plugin.planned import cross_field
from urban_synthesis.plugin.planned import domain_split
from urban_synthesis.plugin.planned import mesh_optimisation
from urban_synthesis.plugin.measure import metrics
from urban_synthesis.plugin.planned import streamlines
from urban_synthesis.plugin.planned import templates
from urban_synthesis.plugin.parcels import subdivision as parcels_mod
from urban_synthesis.plugin.core.progress import InputError
from urban_synthesis.plugin.core.geometry import minimum_rectangle_corners

L, W, S = 30.0, 18.0, 15.0
LIB = templates.load_library(subset="strips")


def _axis_error(theta_rad, axis_deg):
    """|theta - axis| modulo 90 degrees."""
    d = (np.degrees(theta_rad) - axis_deg) % 90.0
    return np.minimum(d, 90.0 - d)


# --------------------------------------------------------------------------- cross field

def test_cross_field_follows_a_rotated_rectangle():
    rect = shapely.affinity.rotate(shapely.box(0, 0, 200, 80), 30, origin=(0, 0))
    field = cross_field.cross_field(rect, 5.0)
    pts = shapely.get_coordinates(shapely.sample_points(rect.buffer(-5), 200, rng=1)
                                  if hasattr(shapely, "sample_points") else
                                  shapely.points(np.c_[np.linspace(20, 150, 50),
                                                       np.linspace(20, 100, 50)]))
    pts = pts[shapely.contains_xy(rect, pts[:, 0], pts[:, 1])]
    theta, norm = field.angle(pts)
    assert _axis_error(theta, 30.0).max() < 1.0
    assert norm.min() > 0.5
    assert len(field.singularities) == 0


def test_cross_field_of_a_disc_has_singularities():
    # a disc's boundary turns once: the 4-RoSy field has index +1 inside, i.e. singularities
    field = cross_field.cross_field(shapely.Point(0, 0).buffer(100), 5.0)
    assert len(field.singularities) >= 1
    assert np.hypot(*field.singularities.T).min() < 60


def test_divergence_term_lowers_the_divergence_and_keeps_the_boundary():
    """The divergence term (Yang sec. 5: low-divergence fields keep parallel streets a
    constant distance apart) lowers div v of the boundary-parallel field; the boundary
    alignment stays."""
    disc = shapely.Point(0, 0).buffer(150)
    plain = cross_field.cross_field(disc, 5.0, divergence_weight=0.0)
    low = cross_field.cross_field(disc, 5.0)
    assert cross_field.divergence(low, disc) < 0.6 * cross_field.divergence(plain, disc)
    rect = shapely.affinity.rotate(shapely.box(0, 0, 200, 80), 30, origin=(0, 0))
    field = cross_field.cross_field(rect, 5.0)
    pts = shapely.get_coordinates(shapely.points(np.c_[np.linspace(20, 150, 50),
                                                       np.linspace(20, 100, 50)]))
    pts = pts[shapely.contains_xy(rect.buffer(-5), pts[:, 0], pts[:, 1])]
    theta, _ = field.angle(pts)
    assert _axis_error(theta, 30.0).max() < 1.0


def test_seeds_are_inner_vertices_of_a_delaunay_mesh():
    region = shapely.Polygon([(0, 0), (400, 0), (300, 200), (60, 200)])
    seeds = streamlines.seed_points(region, 9.0, np.random.default_rng(0), max_seeds=400)
    spacing = max(9.0, np.sqrt(2 * region.area / 400))
    from scipy.spatial import cKDTree

    nn = cKDTree(seeds).query(seeds, k=2)[0][:, 1]
    assert 100 < len(seeds) <= 400
    assert shapely.contains_xy(region, seeds[:, 0], seeds[:, 1]).all()
    # refinement leaves no empty hole wider than the spacing and no two seeds too close
    assert nn.min() >= 0.5 * spacing - 1e-9 and np.median(nn) < 1.5 * spacing
    grid = np.stack(np.meshgrid(np.linspace(0, 400, 60), np.linspace(0, 200, 30)), -1)
    grid = grid.reshape(-1, 2)
    grid = grid[shapely.contains_xy(region.buffer(-spacing), grid[:, 0], grid[:, 1])]
    assert cKDTree(seeds).query(grid)[0].max() < 1.5 * spacing


# --------------------------------------------------------------------------- streamlines

def test_streamlines_are_straight_and_end_on_the_boundary():
    rect = shapely.box(0, 0, 240, 120)
    rng = np.random.default_rng(3)
    field = cross_field.cross_field(rect, 5.0)
    seeds = streamlines.seed_points(rect, 9.0, rng, 40)
    cands = streamlines.trace_streamlines(field, rect, seeds, 10.0, 9.0, rng)
    assert len(cands.lines) >= 6
    xy = [shapely.get_coordinates(g) for g in cands.lines]
    for c in xy:
        d = c[-1] - c[0]
        assert _axis_error(np.arctan2(d[1], d[0]), 0.0) < 1.0  # straight along an axis
    ends = shapely.points(np.array([[c[0], c[-1]] for c in xy]).reshape(-1, 2))
    assert shapely.distance(rect.boundary, ends).max() < 1e-3
    # both orientations are candidates; the deactivation keeps same-orientation
    # candidates at least d_eps apart
    assert set(cands.orientation) == {0, 1}


def test_distance_to_boundary_score_prefers_template_widths():
    rect = shapely.box(0, 0, 300, 150)
    field = cross_field.cross_field(rect, 5.0)
    opt = streamlines.width_fit([L + S, 2 * L + S], 300.0, 0.12 * L)
    lines = np.array([shapely.LineString([(0, y), (300, y)]) for y in (45.0, 60.0, 75.0)],
                     dtype=object)
    cands = streamlines.Candidates(lines, np.zeros((3, 2)), np.zeros(3, int))
    _, parts = streamlines.score_streamlines(cands, field, rect, opt)
    # both sides count: at y = 75 both strips are 75 m (a double strip each); at 45 the
    # far side (105 m) is no sum of template widths, at 60 neither side fits well
    assert parts["db"][2] > 0.9 > 0.5 > max(parts["db"][0], parts["db"][1])
    # straight streamlines of a constant field have (almost) no divergence
    assert parts["div"].max() < 1e-3
    # continuity: a candidate continuing an existing street end (within 4 m, 20°)
    ends = np.array([[-2.0, 45.0, 1.0, 0.0]])  # a street ending at x=-2 heading +x
    _, parts = streamlines.score_streamlines(cands, field, rect, opt, ends=ends)
    assert parts["ct"].tolist() == [0.5, 1.0, 1.0]


# --------------------------------------------------------------------------- templates

def test_library_file_matches_the_generator(tmp_path):
    shipped = json.loads(templates.LIBRARY_PATH.read_text())
    path = templates.write_library(tmp_path / "lib.json")
    assert json.loads(path.read_text()) == shipped
    labels = {t.name: t.label for t in templates.load_library()}
    assert labels == {"parcel_strip": "L", "double_strip": "D", "spike": "S", "loop": "O",
                      "park": "A"}
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="cannot be read"):
        templates.load_library(bad)
    # a minimum count above the maximum can never be met
    doc = dict(shipped, templates=[dict(t, min_count=5) if t["name"] == "spike" else t
                                   for t in shipped["templates"]])
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="'spike' .* is not a valid template"):
        templates.load_library(bad)


def test_fit_energy_selects_by_depth():
    lib = {t.name: t for t in templates.load_library()}
    strip = shapely.box(0, 0, 200, L + S)
    double = shapely.box(0, 0, 200, 2 * L + S)
    e = {n: templates.fit_energy(strip, t, L, W, S) for n, t in lib.items()}
    assert e["parcel_strip"] < 0.05 and e["double_strip"] == np.inf
    e = {n: templates.fit_energy(double, t, L, W, S) for n, t in lib.items()}
    assert e["double_strip"] < 0.05 and e["parcel_strip"] == np.inf


def test_double_strip_takes_rows_as_deep_as_two_strips_back_to_back():
    """A double strip is two parcel strips back to back: its rows take the same depth
    tolerance (up to 1.45 parcel lengths), so a 98 m face between streets is one double
    strip, not a double and a single strip with a street between them."""
    lib = {t.name: t for t in templates.load_library()}
    assert lib["double_strip"].depth_scale[1] == lib["parcel_strip"].depth_scale[1]
    net = shapely.box(0, 0, 200, 98 - S)
    warp = templates.warp_rows(net, lib["double_strip"], L, W, None)
    assert warp is not None and warp.energy < 0.05 and len(warp.lots) == 2 * warp.columns
    assert templates.warp_rows(shapely.box(0, 0, 200, 2 * 1.5 * L), lib["double_strip"], L, W,
                               None) is None


def test_warp_tiles_a_curved_block_and_reduces_distortion():
    # a skewed, slightly curved double-strip block (already shrunk by its streets)
    bottom = [(0, 0), (60, -4), (120, -6), (180, -3)]
    top = [(195, 60), (130, 57), (70, 58), (20, 62)]
    block = shapely.Polygon(bottom + top)
    lib = {t.name: t for t in LIB}
    before = templates.warp_rows(block, lib["double_strip"], L, W,
                                 np.random.default_rng(1), iterations=0)
    after = templates.warp_rows(block, lib["double_strip"], L, W, np.random.default_rng(1))
    for res in (before, after):
        assert shapely.is_valid(res.lots).all()
        assert len(res.lots) == 2 * res.columns
        assert abs(shapely.area(res.lots).sum() - block.area) < 1e-6 * block.area
        assert abs(shapely.union_all(res.lots).area - block.area) < 1e-6 * block.area
    from urban_synthesis.plugin.parcels import subdivision as parcels
    assert (parcels.street_frontage(after.lots, block) >= parcels.MIN_FRONTAGE).all()
    # the alternating registration / regression makes the parcels more rectangular
    assert parcels.lot_quality(after.lots)[0].mean() < parcels.lot_quality(before.lots)[0].mean()


def test_templates_from_drawn_recognises_rows():
    strip = [shapely.box(i * 18, 0, (i + 1) * 18, 30) for i in range(3)]
    double = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
              for i in range(3) for j in range(2)]
    park = [shapely.box(0, 0, 40, 40)]
    geoms = strip + double + park
    names = ["a"] * 3 + ["b"] * 6 + ["c"]
    labels = ["R"] * 9 + ["P"]
    lib = {t.name: t for t in templates.templates_from_drawn(geoms, names, labels)}
    assert (lib["a"].kind, lib["a"].rows) == ("rows", 1)
    assert (lib["b"].kind, lib["b"].rows) == ("rows", 2)
    assert lib["c"].kind == "park"
    with pytest.raises(InputError, match="no parcel template"):
        templates.templates_from_drawn(park, ["c"], ["P"])


def test_drawn_template_labels_and_names_are_checked():
    """A label was read by its first letter: 'parcel' made a park and 'X' or a code a
    template no region could take (the layout fell back to rule-based parcels without a
    word); a feature without a template name became the template 'None'. Labels are one
    of R, P, A, S in either case (none: R), and both mistakes are refused by name."""
    double = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
              for i in range(3) for j in range(2)]
    (t,) = templates.templates_from_drawn(double, ["d"] * 6, ["r", " R ", None, "", "R", "R"])
    assert (t.kind, t.rows) == ("rows", 2)
    for label in ("parcel", "X", 1):
        with pytest.raises(InputError, match=f"template 'd': label '{label}' is none of R"):
            templates.templates_from_drawn(double, ["d"] * 6, ["R"] * 5 + [label])
    with pytest.raises(InputError, match="2 of 6 features have no template name"):
        templates.templates_from_drawn(double, ["d"] * 4 + [None, ""], ["R"] * 6)


def test_drawn_template_is_warped_as_drawn():
    """A template that is no strip (five lots round a park) is kept as drawn and warped
    onto a block of the same corners by mean value coordinates: the lots tile the block,
    the park stays a park of its drawn share, a block of the template's shape costs less
    than a skewed one, a mirrored block is matched by the mirrored template, a block with
    fewer vertices than the template has corners (a rectangle) is not matched, and one with
    an extra corner pays its turn."""
    from shapely import affinity

    outline, geoms, labels = drawn_pentagon_template()
    (t,) = templates.templates_from_drawn(geoms, ["pentagon"] * 6, labels)
    assert (t.kind, t.parcel_labels.count("P")) == ("drawn", 1)
    rng = np.random.default_rng(0)
    block = affinity.rotate(affinity.scale(outline, 1.1, 0.95), 30)
    xy = shapely.get_coordinates(shapely.segmentize(block.exterior, 5))[:-1]
    block = shapely.Polygon(xy + rng.normal(0, 0.3, xy.shape))   # a drawn-by-hand outline
    res = templates.warp_drawn(block, t)
    assert len(res.lots) == 6 and res.green.sum() == 1
    assert shapely.area(res.lots).sum() == pytest.approx(block.area, rel=1e-9)
    assert shapely.union_all(res.lots).area == pytest.approx(block.area, rel=1e-9)
    park_share = geoms[-1].area / outline.area
    assert shapely.area(res.lots[res.green])[0] / block.area == pytest.approx(park_share,
                                                                             rel=0.15)
    assert res.energy < 0.02
    skewed = shapely.Polygon([(0, 0), (130, 0), (160, 60), (70, 125), (-30, 50)])
    assert templates.warp_drawn(skewed, t).energy > 2 * res.energy
    mirrored = affinity.scale(outline, -1.0, 1.0)
    assert templates.warp_drawn(mirrored, t).energy < 1e-6
    assert templates.warp_drawn(shapely.box(0, 0, 130, 110), t) is None
    # a sixth corner (a 40° bend in one side) is a bend the warp absorbs, at the price of
    # its turn, as for the row templates: matched, but far above the selection threshold
    bent = templates.warp_drawn(shapely.Polygon([(0, 0), (60, -22), (120, 0), (140, 70),
                                                 (60, 120), (-20, 70)]), t)
    assert len(bent.lots) == 6 and np.radians(40) < bent.energy < np.radians(40) + 0.1


def test_a_drawn_template_is_prepared_once_and_again_when_its_drawing_changes():
    """warp_drawn keeps what it computes of a template alone (its outline, corners and
    sampled parcels) by the template's drawing: the same result as computed afresh, and a
    template whose parcel coordinates are redrawn in place (the template is frozen, its
    coordinate lists are not) is prepared again: twice as large, it no longer fits."""
    from shapely import affinity

    outline, geoms, labels = drawn_pentagon_template()
    (t,) = templates.templates_from_drawn(geoms, ["pentagon"] * 6, labels)
    block = affinity.rotate(affinity.scale(outline, 1.1, 0.95), 30)
    kept = templates.warp_drawn(block, t)
    templates._FRAMES.clear()
    fresh = templates.warp_drawn(block, t)
    assert kept.energy == fresh.energy
    assert all(a.equals_exact(b, 0.0) for a, b in zip(kept.lots, fresh.lots))
    for ring in t.parcels:
        ring[:] = [[2 * x, 2 * y] for x, y in ring]
    assert templates.warp_drawn(block, t) is None
    # three rows are no strip: drawn too, not an error
    rows3 = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
             for i in range(3) for j in range(3)]
    (t3,) = templates.templates_from_drawn(rows3, ["c"] * 9, ["R"] * 9)
    assert t3.kind == "drawn"


@pytest.mark.parametrize("name", ["spike", "loop"])
def test_drawn_lots_are_regressed_towards_their_drawn_shape(name, monkeypatch):
    """A drawn template's lots are registered to their drawn shapes and regressed (Yang
    sec. 4.1, as the rows are), not left where the mean value warp puts them: on a block
    skewed by 12°, the shipped spike's and loop's lots come out several times squarer than
    the mean value warp's alone (no regression rounds), still tiling the block with the
    template's street surface, no lot on the street, its centre line inside the surface and
    entering from the block's edge."""
    from shapely import affinity

    lib = {t.name: t for t in templates.load_library()}
    t = templates.built_in_drawn(lib[name], L, W, S)
    block = affinity.skew(templates.drawn_outline(t), 12)

    def warped():
        res = templates.warp_drawn(block, t)
        assert shapely.area(res.lots).sum() + res.surface.area == pytest.approx(block.area,
                                                                                rel=1e-9)
        with np.errstate(invalid="ignore"):
            assert shapely.area(shapely.intersection(res.lots, res.surface)).sum() < 1e-6
        for road in res.roads:
            assert shapely.within(road, res.surface.buffer(1e-6))
        p_angle, p_area, _ = parcels_mod.lot_quality(res.lots)
        return np.nanmean(p_angle), np.nanmean(p_area)

    regressed = warped()
    # the street still enters from the block's edge where the block's sides bend (the
    # street around the block takes it on there; 3-4 cm inside it before, on real blocks up
    # to metres: a floating street)
    xy = shapely.get_coordinates(shapely.segmentize(
        shapely.geometry.polygon.orient(templates.drawn_outline(t)).exterior, 10))[:-1]
    d = xy - xy.mean(axis=0)
    bent = affinity.skew(shapely.Polygon(xy.mean(axis=0) + d * (
        1 + 0.06 * np.sin(3 * np.arctan2(d[:, 1], d[:, 0])))[:, None]), 8)
    ends = np.concatenate([shapely.get_coordinates(r)[[0, -1]]
                           for r in templates.warp_drawn(bent, t).roads if not r.is_ring])
    assert shapely.distance(shapely.points(ends), bent.boundary).min() < 1e-9
    monkeypatch.setattr(templates, "WARP_ITERATIONS", 0)
    mean_value_only = warped()
    assert regressed[0] < 0.4 * mean_value_only[0] and regressed[0] < 5.0
    assert regressed[1] - 1 < 0.7 * (mean_value_only[1] - 1)


def test_a_drawn_lot_with_a_hole_stays_one_lot():
    """A lot drawn round a courtyard park (a polygon with a hole) is stored in two pieces
    without holes and warped back into one lot with its hole, the park inside it."""
    from shapely import affinity

    block = shapely.box(0, 0, 100, 80)
    park = shapely.box(35, 25, 65, 55)
    (t,) = templates.templates_from_drawn([shapely.difference(block, park), park],
                                          ["court"] * 2, ["R", "P"])
    assert t.kind == "drawn" and t.parcel_groups == (0, 0, 1)
    res = templates.warp_drawn(affinity.rotate(affinity.scale(block, 1.1, 0.95), 20), t)
    assert len(res.lots) == 2 and res.green.tolist() == [False, True]
    assert len(res.lots[0].interiors) == 1
    assert shapely.area(res.lots).sum() == pytest.approx(1.1 * 0.95 * block.area, rel=1e-9)


def test_drawn_template_settings_per_template():
    """Per-feature probability / min_count / max_count: each template takes the first value
    among its features (None and NaN are no value); bad values are refused by name."""
    outline, geoms, labels = drawn_pentagon_template()
    n = len(geoms)
    (t,) = templates.templates_from_drawn(geoms, ["p"] * n, labels, {
        "probability": [None, 0.5] + [0.9] * (n - 2), "max_count": [float("nan")] * n,
        "min_count": [2] + [None] * (n - 1)})
    assert (t.probability, t.max_count, t.min_count) == (0.5, None, 2)
    for settings, match in (({"min_count": ["many"] * n}, "'p': min_count 'many' is no number"),
                            ({"max_count": [-1] * n}, "'p': max_count must be a whole"),
                            ({"min_count": [1.5] * n}, "'p': min_count must be a whole"),
                            ({"min_count": [3] * n, "max_count": [2] * n},
                             "'p': min_count 3 is above max_count 2")):
        with pytest.raises(InputError, match=match):
            templates.templates_from_drawn(geoms, ["p"] * n, labels, settings)


def test_drawn_template_corners_keep_their_labels():
    """Corner labels (Yang sec. 4.1): an L of five lots has one concave corner; it warps
    onto an L-shaped block, turned and stretched, at no cost, but not onto a hexagon of
    six convex corners, where the concave corner would have to land on a convex one (the
    warp without labels took it at an energy of 0.18)."""
    from shapely import affinity

    lots = [shapely.box(0, 0, 18, 30), shapely.box(18, 0, 36, 30), shapely.box(36, 0, 54, 30),
            shapely.box(0, 30, 30, 48), shapely.box(0, 48, 30, 66)]
    (t,) = templates.templates_from_drawn(lots, ["L"] * 5, ["R"] * 5)
    assert t.kind == "drawn"
    block = affinity.rotate(affinity.scale(shapely.union_all(lots), 1.05, 1.0), 25)
    res = templates.warp_drawn(block, t)
    assert len(res.lots) == 5 and res.energy < 1e-6
    a = np.radians(np.arange(6) * 60)
    hexagon = shapely.Polygon(np.c_[33 * np.cos(a), 30 * np.sin(a)])
    assert (templates.region_corners(hexagon)[2] > templates.CORNER_TURN).all()
    assert templates.warp_drawn(hexagon, t) is None


def test_drawn_template_areas_are_filled_by_level_two_templates():
    """Yang's hierarchy (Fig. 4): the faces of a drawn template labelled A are regions of
    the next level. A court with a straight cul-de-sac, an area on each side of it (65 x
    80 m, between the street around and the cul-de-sac) and three lots across its end:
    each area becomes a double strip fronting both streets (before, the areas were kept
    as two parks), every lot with street access."""
    from shapely import affinity

    block, geoms, labels = drawn_area_court_template()
    (t,) = templates.templates_from_drawn(geoms, ["court"] * 6, labels)
    assert t.kind == "drawn" and t.parcel_labels.count("A") == 2
    lib = [t] + [x for x in templates.load_library() if x.kind in ("rows", "park")]
    outline = block.buffer(S / 2, join_style="mitre")
    lay = domain_split.split_domain(affinity.rotate(affinity.scale(outline, 1.1, 1.05), 15),
                                    seed=1, templates=lib)
    mine = (lay.table.template == "court").to_numpy()
    assert mine.all() and (lay.table.land_use == "residential").all()
    assert lay.table.has_street_access.all()
    # the three drawn lots, and two double strips of 2 x 4 or 2 x 5 parcels of about
    # the template's 30 x 18 m
    small = shapely.area(lay.parcels) < 1.3 * L * W
    assert 16 <= small.sum() <= 20 and (~small).sum() == 3
    assert (np.asarray(lay.road_kind) == "cul_de_sac").sum() == 1


def test_drawn_template_with_its_own_cul_de_sac():
    """A cul-de-sac drawn as a surface (S) among the parcels is the template's own street:
    its centre line (raster skeleton of the surface) runs from the outline to the turning
    head; warped onto a turned, stretched region it keeps its bend, runs on to the
    region's outline street, no lot covers it, and every lot has street access."""
    from shapely import affinity

    block, geoms, labels = drawn_court_template()
    (t,) = templates.templates_from_drawn(geoms, ["court"] * len(geoms), labels)
    assert t.kind == "drawn" and len(t.streets) == 1
    # a street that does not reach the outline would be a floating piece: refused by name
    island = shapely.Point(60, 60).buffer(8)
    lots = [shapely.difference(block, island)]
    with pytest.raises(InputError, match="'island'.*must be drawn as a surface that reaches"):
        templates.templates_from_drawn(lots + [island], ["island"] * 2, ["R", "S"])
    outline = templates.drawn_outline(t)
    ends = shapely.points(np.asarray(t.streets[0])[[0, -1]])
    assert sorted(np.round(shapely.distance(ends, shapely.boundary(outline)), 3))[0] == 0
    region = affinity.rotate(affinity.scale(block, 1.12, 1.15), 20)
    lib = [t] + [x for x in templates.load_library() if x.kind in ("rows", "park")]
    lay = domain_split.split_domain(region, seed=1, templates=lib)
    tab = lay.table
    assert (tab.template == "court").sum() == 7 and tab.has_street_access.all()
    kinds = np.asarray(lay.road_kind)
    (cds,) = lay.roads[kinds == "cul_de_sac"]
    d = shapely.distance(shapely.points(shapely.get_coordinates(cds)[[0, -1]]),
                         shapely.boundary(region))
    assert min(d) < 1e-3 and max(d) > 30            # from the outline street into the block
    chord = shapely.distance(shapely.get_point(cds, 0), shapely.get_point(cds, -1))
    assert cds.length / chord > 1.01                  # the drawn bend is kept
    with np.errstate(invalid="ignore"):
        covered = shapely.area(shapely.intersection(lay.parcels, shapely.buffer(cds, 3.0)))
    assert covered.max() < 1.0                        # its surface is no lot
    assert_planar(lay.roads)


def test_a_drawn_street_never_enters_from_a_motorway():
    """Edge labels for a drawn template's own street: with a motorway along the side its
    cul-de-sac enters from (as drawn, it would end on the motorway: an at-grade junction),
    the court is turned so that the cul-de-sac enters from a street."""
    from shapely import affinity

    block, geoms, labels = drawn_court_template()
    (t,) = templates.templates_from_drawn(geoms, ["court"] * len(geoms), labels)
    region = affinity.scale(block, 1.12, 1.15)
    x0, y0, x1, y1 = region.bounds
    motorway = shapely.LineString([(x0 - 50, y1), (x1 + 50, y1)])
    lib = [t] + [x for x in templates.load_library() if x.kind in ("rows", "park")]
    lay = domain_split.split_domain(region, key_roads=[motorway], key_road_classes=["motorway"],
                                    seed=1, templates=lib)
    assert (lay.table.template == "court").sum() == 7
    kinds = np.asarray(lay.road_kind)
    (cds,) = lay.roads[kinds == "cul_de_sac"]
    ends = shapely.points(shapely.get_coordinates(cds)[[0, -1]])
    assert shapely.distance(ends, motorway).min() > 20    # neither end near the motorway
    outline = shapely.union_all(lay.roads[kinds == "outline"])
    assert shapely.distance(ends, outline).min() < 1e-3    # it joins an outline street


def test_drawn_template_with_a_loop_street():
    """A loop street drawn as a ring-shaped surface with its connector: two centre lines
    (the ring, 2 x (90 + 60) m, and the connector), warped as drawn, kind 'loop', noded
    with the outline street, every lot with street access."""
    from shapely import affinity

    from urban_synthesis.plugin.roads.raster_graph import polygon_centre_lines

    block = shapely.box(0, 0, 160, 130)
    street = shapely.intersection(shapely.union(
        shapely.buffer(shapely.box(35, 35, 125, 95).exterior, 4, join_style="mitre"),
        shapely.buffer(shapely.LineString([(80, 0), (80, 35)]), 4, cap_style="flat")), block)
    lines = polygon_centre_lines(street)
    assert sorted(np.round(shapely.length(lines) / 10)) == [3, 30]
    rest = shapely.difference(block, street)
    cuts = [shapely.LineString([(x, -1), (x, 131)]) for x in (20, 80, 140)] + \
        [shapely.LineString([(-1, 65), (161, 65)])]
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.node(
        shapely.union_all([shapely.boundary(rest)] + cuts)))))
    lots = list(faces[shapely.within(shapely.point_on_surface(faces), rest)])
    (t,) = templates.templates_from_drawn(lots + [street], ["loop"] * (len(lots) + 1),
                                          ["R"] * len(lots) + ["S"])
    assert len(t.streets) == 2
    lib = [t] + [x for x in templates.load_library() if x.kind in ("rows", "park")]
    lay = domain_split.split_domain(affinity.rotate(affinity.scale(block, 1.1, 1.12), -15),
                                    seed=1, templates=lib)
    kinds = np.asarray(lay.road_kind)
    assert (kinds == "loop").sum() == 2 and any(r.is_ring for r in lay.roads[kinds == "loop"])
    # the drawn lots, four of them inside the ring (the ring-shaped surface is kept as
    # two pieces: as one outer ring it covered them, and one lot more came out)
    mine = (lay.table.template == "loop").to_numpy()
    assert mine.sum() == len(lots) == 12 and lay.table.has_street_access.all()
    (ring,) = [r for r in lay.roads[kinds == "loop"] if r.is_ring]
    assert shapely.within(shapely.point_on_surface(lay.parcels[mine]),
                          shapely.Polygon(ring)).sum() == 4
    assert_planar(lay.roads)


def test_split_domain_uses_a_drawn_template():
    """A region the drawn template fits (its outline and half a street all round) becomes
    the drawn lots and the private park, every lot with street access."""
    from shapely import affinity

    outline, geoms, labels = drawn_pentagon_template()
    lib = templates.templates_from_drawn(geoms, ["pentagon"] * 6, labels) + \
        [t for t in templates.load_library() if t.kind in ("rows", "park")]
    region = affinity.scale(outline, 1.1, 1.1)
    lay = domain_split.split_domain(region, seed=1, templates=lib)
    tab = lay.table
    assert (tab.template == "pentagon").sum() == 6
    assert (tab.land_use[tab.template == "pentagon"] == "park").sum() == 1
    assert tab.has_street_access[tab.land_use == "residential"].all()


# --------------------------------------------------------------------------- optimisation

def test_a_drawn_template_no_region_takes_is_named():
    """A template warped as drawn is not scaled to the parcel size: one drawn ten times too
    large fits no region and the layout fell back to rule-based parcels without a word.
    ``unused_drawn_templates`` names it with its size (the algorithm's warning)."""
    rows3 = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
             for i in range(4) for j in range(3)]
    big = [shapely.affinity.scale(g, 10, 10, origin=(0, 0)) for g in rows3]
    lib = templates.templates_from_drawn(rows3 + big, ["three"] * 12 + ["big"] * 12,
                                         ["R"] * 24)
    layouts = domain_split.split_variations([shapely.box(0, 0, 300, 200)], 1, seed=1,
                                            templates=lib)
    assert "three" in layouts[0].stats["templates"]
    (warning,) = domain_split.unused_drawn_templates(lib, layouts)
    assert warning.startswith("Drawn template 'big' (900 x 720 m) was used in no variation")


def test_mesh_optimisation_fits_strips_and_fairs_roads():
    outline = shapely.box(0, 0, 300, 150)
    # a wobbly street splitting the box into blocks of ~70 and ~80 m; the preferred width
    # of the lower block is 75 m (a double strip)
    x = np.linspace(0, 300, 31)
    y = 70 + 4 * np.sin(x / 15.0)
    free = [shapely.LineString(np.c_[x, y])]
    fixed = [outline.boundary]

    def width(face):
        return 75.0 if face.centroid.y < 70 else np.nan

    lines, stats = mesh_optimisation.optimise_roads(free, fixed, width, spacing=10.0)
    assert stats["converged"] and not stats["reverted"]
    assert 1 < stats["iterations"] < mesh_optimisation.ITERATIONS
    # the energy of eq. (3) goes down and the strip term most of all
    energy = np.asarray(stats["energy"])
    assert energy[stats["best_iteration"]] == energy.min() < 0.5 * energy[0]
    assert stats["shape_after"] < 0.2 * stats["shape_before"]
    xy = shapely.get_coordinates(lines[0])
    # ends stay on the fixed outline, the street straightens and moves towards y = 75
    assert np.allclose(xy[[0, -1], 0], [0, 300])
    assert np.abs(np.diff(xy[:, 1], 2)).max() < np.abs(np.diff(y, 2)).max()
    assert abs(np.median(xy[:, 1]) - 75) < abs(70 - 75)


def test_mesh_optimisation_slides_junctions_along_a_fixed_road():
    """A new street ending on a kept key road: its junction slides along the road (Yang
    sec. 6) and the optimisation converges instead of being undone."""
    outline = shapely.box(0, 0, 300, 400)
    key = shapely.LineString([(0, 100), (300, 100)])           # fixed: a kept main road
    side = shapely.LineString([(140, 100), (145, 250), (160, 400)])  # a new, slanted street
    fixed = [outline.boundary, key]

    def width(face):
        # the two 300 m long blocks either side of the new street prefer 150 m
        return 150.0 if face.centroid.y > 100 else np.nan

    lines, stats = mesh_optimisation.optimise_roads([side], fixed, width, spacing=10.0)
    assert not stats["reverted"] and stats["converged"] and stats["iterations"] >= 1
    xy = np.vstack([shapely.get_coordinates(g) for g in lines])
    ends = np.vstack([shapely.get_coordinates(g)[[0, -1]] for g in lines])
    on_key = ends[np.abs(ends[:, 1] - 100) < 1e-6]
    on_top = ends[np.abs(ends[:, 1] - 400) < 1e-6]
    # both junctions stay on their fixed roads and slide along them towards x = 150
    assert len(on_key) == 1 and len(on_top) == 1
    assert abs(on_key[0, 0] - 150) < 0.5 * abs(140 - 150)
    assert abs(on_top[0, 0] - 150) < 0.5 * abs(160 - 150)
    assert np.abs(xy[:, 0] - 150).max() < 6.0
    # the street still splits the upper block in two
    assert len(mesh_optimisation.faces_of(fixed + lines)) == 3


# --------------------------------------------------------------------------- pipeline

@pytest.fixture(scope="module")
def bubenec_hull():
    """The convex hull of Bubeneč's cadastre plots, cut to 450 m x 450 m around its centre
    (a real outline, small enough for a fast test)."""
    plots = bubenec("plots").geometry.to_numpy()
    hull = shapely.convex_hull(shapely.union_all(plots))
    c = hull.centroid
    return hull.intersection(shapely.box(c.x - 225, c.y - 225, c.x + 225, c.y + 225))


@pytest.fixture(scope="module")
def bubenec_layouts(bubenec_hull):
    return domain_split.split_variations(bubenec_hull, 2, seed=4, templates=LIB)


def test_bubenec_layout_quality(bubenec_layouts, bubenec_hull):
    lay = bubenec_layouts[0]
    t = lay.table
    res = t.land_use == "residential"
    assert res.sum() > 80
    assert shapely.is_valid(lay.parcels).all()
    # parcels do not overlap and stay inside the region, off the streets
    assert abs(shapely.union_all(lay.parcels).area - shapely.area(lay.parcels).sum()) < 1.0
    assert shapely.within(lay.parcels, bubenec_hull.buffer(1e-6)).all()
    streets = shapely.union_all(shapely.buffer(lay.roads, S / 2 - 0.01, cap_style="flat"))
    assert shapely.area(shapely.intersection(lay.parcels, streets)).sum() < 1.0
    # every residential parcel has street access
    assert t.has_street_access[res].all()
    # Yang's Table 1 quality: at the paper's "Our" level (2.1-3.2°, 1.04-1.06)
    m = domain_split.table1(lay)
    assert m["p_angle"] < 3.5 and m["p_area"] < 1.065
    assert m["undesirable_pct"] < 10
    real = metrics.parcel_metrics(bubenec("plots").geometry.to_numpy())
    assert m["p_angle"] < real.scalar("parcels", "p_angle")
    assert m["p_area"] < real.scalar("parcels", "p_area")
    # parcel sizes follow the template (30 x 18 m = 540 m²) within its tolerances
    area = t.area_m2[res & (~t.template.isin(domain_split.FALLBACK_PARCELS))]
    assert 0.6 * L * W < np.median(area) < 1.5 * L * W
    # streets: the outline plus streamline streets, land use shares add up
    assert (lay.road_level == domain_split.LEVEL_SPLIT).sum() >= 3
    assert abs(m["l_s"] + m["l_r"] + m["l_p"] + m["l_o"] - 100) < 1e-6
    assert lay.stats["optimisation"]["iterations"] >= 1


def test_variations_differ_and_seeds_repeat(bubenec_layouts, bubenec_hull):
    a, b = bubenec_layouts
    assert a.table.variation.iloc[0] == 1 and b.table.variation.iloc[0] == 2
    wa = set(shapely.to_wkb(a.roads))
    wb = set(shapely.to_wkb(b.roads))
    assert wa != wb
    again = domain_split.split_domain(bubenec_hull, templates=LIB, seed=4, variation=1)
    assert shapely.to_wkb(again.parcels).tolist() == shapely.to_wkb(a.parcels).tolist()


def test_key_roads_and_key_areas(bubenec_hull):
    c = bubenec_hull.centroid
    minx, miny, maxx, maxy = bubenec_hull.bounds
    key_road = shapely.LineString([(minx - 10, c.y), (maxx + 10, c.y)])
    park = c.buffer(40)
    lay = domain_split.split_domain(bubenec_hull, key_roads=[key_road], key_areas=[park],
                                    key_area_use=["school"], templates=LIB, seed=2)
    kept = lay.roads[lay.road_level == domain_split.LEVEL_KEY]
    assert len(kept) >= 1
    assert abs(shapely.length(kept).sum() -
               shapely.intersection(key_road, bubenec_hull.difference(park)).length) < 1.0
    t = lay.table
    school = t.land_use == "school"
    assert school.sum() == 1 and abs(t.area_m2[school].iloc[0] - park.area) < 1.0
    res = (t.land_use == "residential").to_numpy()
    assert not shapely.intersects(lay.parcels[res], key_road).any()
    with np.errstate(invalid="ignore"):
        assert shapely.area(shapely.intersection(lay.parcels[res], park)).sum() < 1e-6


def test_key_areas_keep_the_land_use_of_their_own_feature():
    """A key area's use was taken by the position of a part of the areas' union: two
    disjoint areas could swap their uses, and any overlap (or an area outside the region)
    made every use 'park'. Each use now stays with its features; where uses overlap, the
    first in the layer keeps the overlap and the parcels do not overlap."""
    region = [shapely.box(0, 0, 300, 200)]
    school, lake = shapely.box(200, 20, 260, 80), shapely.box(20, 20, 80, 80)
    outside = shapely.box(1000, 0, 1050, 50)
    lay = domain_split.split_domain(region, key_areas=[school, lake, outside],
                                    key_area_use=["school", "lake", "church"], seed=1)
    t = lay.table
    key = (t.template == "key_area").to_numpy()
    found = {u: g for u, g in zip(t.land_use[key], lay.parcels[key])}
    assert set(found) == {"school", "lake"}
    assert abs(found["school"].symmetric_difference(school).area) < 1e-6
    assert abs(found["lake"].symmetric_difference(lake).area) < 1e-6
    park = shapely.box(50, 50, 120, 110)
    lay = domain_split.split_domain(region, key_areas=[lake, park],
                                    key_area_use=["school", None], seed=1)
    t = lay.table
    key = (t.template == "key_area").to_numpy()
    assert sorted(t.land_use[key]) == ["park", "school"]
    school_lot = lay.parcels[key][(t.land_use[key] == "school").to_numpy()][0]
    assert abs(school_lot.area - lake.area) < 1e-6
    assert abs(shapely.union_all(lay.parcels[key]).area
               - shapely.area(lay.parcels[key]).sum()) < 1e-6


def test_bad_input():
    with pytest.raises(InputError, match="region"):
        domain_split.split_domain([shapely.LineString([(0, 0), (1, 1)])])
    with pytest.raises(InputError, match="region has no geometry"):
        domain_split.split_domain([])
    with pytest.raises(InputError, match="parcel length"):
        domain_split.split_domain([shapely.box(0, 0, 100, 100)],
                                  settings=domain_split.SplitSettings(parcel_length=-1))
    with pytest.raises(InputError, match="absurd"):
        domain_split.split_domain([shapely.box(0, 0, 100, 100)],
                                  settings=domain_split.SplitSettings(street_width=500))
    with pytest.raises(InputError, match="variations"):
        domain_split.split_variations([shapely.box(0, 0, 100, 100)], 0)
    with pytest.raises(InputError, match="rule-based parcels must be one of"):
        domain_split.split_domain([shapely.box(0, 0, 100, 100)],
                                  settings=domain_split.SplitSettings(fallback_parcels="voronoi"))
    with pytest.raises(InputError, match="no parcel template"):
        domain_split.split_domain([shapely.box(0, 0, 100, 100)],
                                  templates=[t for t in templates.load_library()
                                             if t.kind == "park"])


@pytest.mark.parametrize("method", domain_split.FALLBACK_PARCELS)
def test_rule_based_parcels_tile_the_block_with_street_access(method):
    """A region no template fits gets the rule-based parcels of ``fallback_parcels`` (here
    the whole region: no region may be split, ``max_regions=0``): they tile the net block
    without overlaps, every lot fronts on the street round it, lots are parcel-sized, and
    the parcels carry the method's name."""
    region = shapely.Polygon([(0, 0), (230, 30), (260, 170), (90, 210), (-30, 120)])
    s = domain_split.SplitSettings(max_regions=0, fallback_parcels=method, optimise=False)
    lay = domain_split.split_domain([region], seed=0, settings=s)
    t = lay.table
    assert set(t.template) == {method} and set(t.land_use) == {"residential"}
    assert t.has_street_access.all() and shapely.is_valid(lay.parcels).all()
    net = domain_split.net_block(region, s.street_width, None)
    union = shapely.union_all(lay.parcels)
    assert abs(shapely.area(union) - shapely.area(net)) < 1.0
    assert abs(shapely.area(lay.parcels).sum() - shapely.area(union)) < 1.0  # no overlaps
    lot = s.parcel_length * s.parcel_width
    assert 0.3 * lot <= shapely.area(lay.parcels).min() and np.median(t.area_m2) < 1.6 * lot


def test_minimum_template_count_is_met_by_repeating_the_search():
    """Yang's k2: a template may have to occur at least k2 times. Seed 0 lays out no
    spike in a 600 x 420 m region; with a minimum of three, the randomized search is
    repeated (the spike's probability doubled each time it falls short, in the choice of
    a template and in the width fit of the splits) until it has at least three, and the
    layout says how many searches it took."""
    import dataclasses

    lib = templates.load_library()
    region = shapely.box(0, 0, 600, 420)
    lay = domain_split.split_domain(region, seed=0, templates=lib)
    assert list(lay.block_template).count("spike") == 0
    assert (lay.stats["search_attempts"], lay.stats["min_count_short"]) == (1, 0)
    lib3 = [dataclasses.replace(t, min_count=3) if t.name == "spike" else t for t in lib]
    lay = domain_split.split_domain(region, seed=0, templates=lib3)
    assert 3 <= list(lay.block_template).count("spike") <= 4      # its max_count
    assert lay.stats["min_count_short"] == 0 and lay.stats["search_attempts"] > 1
    assert lay.table.has_street_access[lay.table.land_use == "residential"].all()


def test_built_in_spike_is_a_drawn_cul_de_sac_selected_by_its_warp_energy():
    """The shipped spike (Yang Fig. 2) is a drawn template at the layout's parcel size:
    a straight cul-de-sac, four lots on each side and two across its end. It is selected
    by its warp energy (a block of its shape, turned and stretched within its scales,
    costs nothing; a skewed one does), and split_domain makes it a cul-de-sac off the
    outline street that no lot covers, every lot with street access."""
    from shapely import affinity

    lib = {t.name: t for t in templates.load_library()}
    spike = templates.built_in_drawn(lib["spike"], L, W, S)
    assert (spike.kind, spike.name, spike.max_count) == ("drawn", "spike", 4)
    assert len(spike.parcels) == 11 and spike.parcel_labels.count("S") == 1
    net = templates.drawn_outline(spike)                  # 75 x 102 m of lots
    assert templates.warp_drawn(affinity.rotate(affinity.scale(net, 1.1, 0.9), 35),
                                spike).energy < 1e-3
    assert templates.warp_drawn(affinity.skew(net, 20), spike).energy > 0.05
    region = affinity.rotate(shapely.box(0, 0, 2 * L + 2 * S, 4 * W + L + S), 20)
    lay = domain_split.split_domain(region, seed=1, templates=[lib["spike"], lib["park"]])
    kinds = np.asarray(lay.road_kind)
    (cds,) = lay.roads[kinds == "cul_de_sac"]
    assert cds.length > 3 * W and shapely.within(cds, region.buffer(1e-6))
    # it starts on the outline street
    assert shapely.distance(shapely.points(shapely.get_coordinates(cds)[[0, -1]]),
                            region.boundary).min() < 1e-3
    assert (lay.table.template == "spike").sum() == 10
    assert lay.table.has_street_access.all() and shapely.is_valid(lay.parcels).all()
    # no lot on the street: its centre line is the skeleton of the drawn surface read
    # back at 0.25 m (templates._drawn_template), so within 0.3 m of the middle
    with np.errstate(invalid="ignore"):
        on_road = shapely.area(shapely.intersection(lay.parcels,
                                                    cds.buffer(S / 2 - 0.3, cap_style="flat")))
    assert on_road.sum() < 1e-3
    assert_planar(lay.roads)


def test_built_in_loop_fronts_every_lot_on_a_street_when_stretched():
    """The shipped loop (Yang Fig. 2/4): a ring street one lot deep inside the block with
    its connector, a band of lots round the block and two rows inside the ring. Its
    street surface is a ring (a polygon with a hole, kept as two pieces); warped onto a
    block stretched by 10 % and turned, every one of its 35 lots keeps its frontage on
    the block's streets or on the ring (measured on the warped surface: on the stretched
    ring the lots lie more than half a street width from its centre line, and the inner
    lots were merged away as lots without access)."""
    from shapely import affinity

    lib = {t.name: t for t in templates.load_library()}
    loop = templates.built_in_drawn(lib["loop"], L, W, S)
    assert loop.kind == "drawn" and loop.parcel_labels.count("S") == 2
    net = templates.drawn_outline(loop)
    region = affinity.rotate(affinity.scale(net.buffer(S / 2, join_style="mitre"), 1.1, 1.05),
                             -25)
    lay = domain_split.split_domain(region, seed=1, templates=[lib["loop"], lib["park"]])
    kinds = np.asarray(lay.road_kind)
    rings = [r for r in lay.roads[kinds == "loop"] if r.is_ring]
    assert len(rings) == 1 and (kinds == "loop").sum() == 2
    assert (lay.table.template == "loop").sum() == 35
    assert lay.table.has_street_access.all() and (lay.table.land_use == "residential").all()
    inside = shapely.within(shapely.point_on_surface(lay.parcels), shapely.Polygon(rings[0]))
    assert inside.sum() == 8
    assert_planar(lay.roads)


# --------------------------------------------------------------------------- bad parcels

def test_children_reject_a_band_too_thin_for_any_template():
    """A split whose child is thick at one end but a band thinner than any template
    elsewhere is rejected (the long sliver lots of curved streamlines near a boundary)."""
    splitter = domain_split._Splitter(LIB, domain_split.SplitSettings(),
                                      np.random.default_rng(0))
    region = shapely.box(0, 0, 300, 200)
    # an L-shaped child: 100 m wide on the right, a 25 m band along the bottom
    hook = shapely.LineString([(0, 25), (200, 25), (200, 200)])
    assert splitter._children(region, hook) is None
    got = splitter._children(region, shapely.LineString([(0, 100), (300, 100)]))
    assert got is not None and len(got[1]) == 2


def test_children_reject_a_street_down_a_narrow_arm_of_a_large_region():
    """A region with an arm 40 m wide (a town's envelope round a road leaving it): a
    street running out of the body down the middle of the arm leaves two 12.5 m slivers
    beside it, too shallow for any row, though each is a small part of its large child
    (Mauren's long lots 2-5 m deep). The split is rejected; a street across the body that
    leaves the arm whole is not."""
    splitter = domain_split._Splitter(LIB, domain_split.SplitSettings(),
                                      np.random.default_rng(0))
    region = shapely.union(shapely.box(0, 0, 400, 400), shapely.box(399, 100, 700, 140))
    down_the_arm = shapely.LineString([(0, 120), (700, 120)])
    assert splitter._children(region, down_the_arm) is None
    across = splitter._children(region, shapely.LineString([(0, 250), (400, 250)]))
    assert across is not None and len(across[1]) == 2


def test_splits_prefer_the_template_with_less_street():
    """A parcel strip (one row, a street on each side) gives 15 of every 45 m across to
    streets, a double strip 15 of 75: the width fit of the splits weights each template by
    its probability to WIDTH_FIT_PREFERENCE, so over five seeds in a 0.17 km2 quadrangle
    parcel strips are few and the streets take a small share of the land. With the
    probabilities as they are (power 1) parcel strips were 16 % of the lots and the streets
    27.2 % of the land (seeds 0-4)."""
    region = shapely.Polygon([(0, 0), (520, 0), (560, 300), (60, 360)])
    strips, streets = [], []
    for seed in range(5):
        lay = domain_split.split_domain(region, templates=LIB, seed=seed,
                                        settings=domain_split.SplitSettings(optimise=False))
        strips.append((lay.table.template == "parcel_strip").mean())
        streets.append(domain_split.table1(lay)["l_s"])
    assert np.mean(strips) < 0.10 and np.mean(streets) < 26.5


def test_acute_lot_keeps_the_rectangle_on_its_street_and_the_wedge_turns_green():
    """An undesirable lot larger than a parcel (a triangle where streets meet at an acute
    angle) is cut to the rectangle standing on its street edge; the wedge becomes green."""
    from urban_synthesis.plugin.parcels import subdivision as parcels

    # the shrunk block (its outline is street) and its corner lot on the x axis
    block = shapely.Polygon([(0, 0), (200, 0), (200, 100), (0, 45)])
    lot = shapely.Polygon([(0, 0), (60, 0), (0, 45)])          # 1350 m², p_angle 30°
    assert parcels.lot_quality([lot])[2][0]
    lots, front, green = domain_split._rectify(
        np.array([lot], dtype=object), parcels.street_frontage([lot], block),
        np.array([False]), np.array([True]), block, L, W)
    keep = lots[~green]
    assert len(keep) == 1 and len(lots) >= 2
    p_angle, p_area, bad = parcels.lot_quality(keep)
    assert p_angle[0] < 1e-6 and p_area[0] < 1.0 + 1e-6 and not bad[0]
    assert 0.5 * L * W <= keep[0].area <= lot.area
    # it stands on the street edge (y = 0); the pieces do not overlap and cover the lot
    # but for the 2 cm seam the green wedges are shrunk by
    assert front[~green][0] >= 0.6 * W
    assert abs(keep[0].bounds[1]) < 1e-6
    assert abs(shapely.union_all(lots).area - shapely.area(lots).sum()) < 1e-6
    assert shapely.within(lots, lot.buffer(1e-6)).all()
    assert 0 <= lot.area - shapely.area(lots).sum() < 0.02 * (lot.length + keep[0].length)


def test_minimum_rectangle_and_deep_nodes_are_exact():
    rng = np.random.default_rng(3)
    for _ in range(50):
        pts = rng.normal(size=(10, 2)) * [40, 12]
        ours = shapely.Polygon(minimum_rectangle_corners([shapely.multipoints(pts)])[0]).area
        ref = shapely.minimum_rotated_rectangle(shapely.multipoints(pts)).area
        assert abs(ours - ref) < 1e-6 * ref
    disc = shapely.Point(0, 0).buffer(100)
    field = cross_field.cross_field(disc, 5.0)
    xy = rng.uniform(-110, 110, (4000, 2))
    sure = field.surely_inside(xy)
    assert sure.sum() > 1000
    assert shapely.contains_xy(disc, xy[sure, 0], xy[sure, 1]).all()


@pytest.fixture(scope="module")
def bubenec_with_streets():
    """The whole hull of Bubeneč's plots with its 35 real streets kept (the bench's
    hardest region: acute junctions, curved streets, region corners)."""
    plots = bubenec("plots").geometry.to_numpy()
    streets = bubenec("streets").geometry.to_numpy()
    hull = shapely.convex_hull(shapely.union_all(plots))
    return hull, streets, domain_split.split_domain(hull, key_roads=streets, templates=LIB,
                                                    seed=1, variation=1)


def test_bubenec_with_real_streets_quality(bubenec_with_streets):
    """The hardest Bubeneč case (its 35 real streets kept, acute junctions): honest Table 1
    with the parks counted and no lot repair. Yang's "Our" rows (p_angle <= 3.2°, p_area
    <= 1.06) are NOT reached here (about 3.9° / 1.085, see the README); the assertions are
    what the method does reach, and that it beats the real cadastre on the same land."""
    hull, streets, lay = bubenec_with_streets
    t = lay.table
    res = (t.land_use == "residential").to_numpy()
    assert res.sum() > 400
    assert shapely.is_valid(lay.parcels).all()
    assert t.has_street_access[res].all()
    assert lay.stats["n_pocket_parks"] == 0           # the repair is off by default
    m = domain_split.table1(lay)
    assert m["p_count"] == len(lay.parcels)           # every designed parcel counts
    real = metrics.parcel_metrics(bubenec("plots").geometry.to_numpy())
    assert m["p_angle"] < min(4.5, real.scalar("parcels", "p_angle"))
    assert m["p_area"] < min(1.10, real.scalar("parcels", "p_area"))
    assert m["l_p"] < 6
    # no sliver lots: the residential parcels stay within the template's size range
    area = t.area_m2[res]
    assert area.max() < 4 * L * W and np.median(area) > 0.6 * L * W
    # the streets form a planar network: every crossing a junction, each junction one point
    assert_planar(lay.roads)
    assert_ends_meet_exactly(lay.roads)
    assert (shapely.length(lay.roads) >= 1.0).all()


def test_a_towns_junctions_are_one_point_each():
    """Mauren, its primary and secondary roads kept, as the fidelity benchmark lays it out:
    streets meeting a key road from its two sides a fraction of a metre apart (0.48-0.79 m
    of key road between them) and junctions computed twice (split-street pieces of 5 mm to
    0.8 m between two) were two junctions each; one now, no street under a metre, no two
    line ends within half a metre that differ; and the key roads stay the given roads (a
    first version moved a key road's piece by the collapsed 0.8 m: 5 crossings of the
    given road and 2 doubles)."""
    from urban_synthesis.plugin.network import invariants

    town, _ = left_out_town("Mauren")
    lay = domain_split.split_domain(shapely.get_parts(town.area), key_roads=town.given,
                                    seed=0, settings=domain_split.SplitSettings(optimise=False))
    assert_planar(lay.roads)
    assert_ends_meet_exactly(lay.roads)
    roads = np.asarray(lay.roads, dtype=object)
    new = roads[invariants.new_streets(roads, town.given)]
    # (a given road may end a fraction of a metre beyond a junction: its own end)
    assert shapely.length(new).min() >= 1.0
    check = invariants.check_network(new, town.given, town.given_class, town.area)
    assert len(check.crossings_given) == 0 and len(check.duplicates) == 0


def test_repair_is_optional_and_the_parks_count():
    """Table 1 counts every designed parcel (parks too); the repair (not in the paper)
    is off by default and only turns bad lots into parks, which still count."""
    region = shapely.Polygon([(0, 0), (420, -60), (470, 260), (30, 300)])
    off = domain_split.split_domain(region, templates=LIB, seed=3)
    on = domain_split.split_domain(region, templates=LIB, seed=3,
                                   settings=domain_split.SplitSettings(repair_lots=True))
    assert off.stats["n_pocket_parks"] == 0
    m_off, m_on = domain_split.table1(off), domain_split.table1(on)
    for lay, m in ((off, m_off), (on, m_on)):
        designed = (lay.table.template != "key_area").to_numpy()
        assert m["p_count"] == designed.sum()
        pm = metrics.parcel_metrics(lay.parcels[designed])
        assert m["p_angle"] == pytest.approx(pm.scalar("parcels", "p_angle"))
        assert m["p_area"] == pytest.approx(pm.scalar("parcels", "p_area"))
    # the repair never hides a bad lot: what it turns green still counts
    if on.stats["n_pocket_parks"]:
        assert m_on["l_p"] > m_off["l_p"]


def test_motorways_take_no_junction_and_dangles_are_continued():
    """Key roads of a limited-access class split the region but no new street ends on
    them, the outline street neither (it ended on the motorway where the outline crosses
    it: four junctions on it; it ends outside its corridor now); a key road ending inside
    the region is continued to the next street, here to the motorway's corridor (it met
    the motorway: a junction on it)."""
    region = shapely.box(0, 0, 600, 400)
    motorway = shapely.LineString([(-10, 200), (610, 200)])
    dangle = shapely.LineString([(300, 0), (300, 120)])       # ends 80 m short of it
    lay = domain_split.split_domain(region, key_roads=[motorway, dangle],
                                    key_road_classes=["motorway", "residential"],
                                    templates=LIB, seed=2)
    roads, kind = lay.roads, lay.road_kind
    on_motorway = shapely.dwithin(roads, motorway, 0.01) & ~shapely.within(
        roads, motorway.buffer(0.01))
    # no street touches the motorway; the outline and the continuation end 8 m off it
    assert not on_motorway.any()
    outline = roads[np.isin(kind, ("outline", "key"))]
    outline_ends = np.r_[shapely.get_point(outline, 0), shapely.get_point(outline, -1)]
    assert shapely.distance(outline_ends, motorway).min() == pytest.approx(8.0, abs=0.01)
    from urban_synthesis.plugin.network import invariants
    new = invariants.new_streets(roads, [motorway, dangle])
    contacts = invariants.check_network(roads[new], [motorway, dangle],
                                        ["motorway", "residential"]).controlled_access
    assert len(contacts) == 0
    key = shapely.union_all(roads[kind == "key"])
    assert key.length == pytest.approx(192.0, abs=0.01)     # 120 m + 80 m continued - 8 m
    assert shapely.dwithin(key, shapely.Point(300, 192), 1e-6)
    assert_planar(roads)
    res = (lay.table.land_use == "residential").to_numpy()
    # every lot reaches a street other than the motorway (which gives no access)
    others = roads[~shapely.within(roads, motorway.buffer(0.01))]
    with np.errstate(invalid="ignore"):
        access = shapely.length(shapely.intersection(
            shapely.boundary(lay.parcels[res]),
            shapely.buffer(shapely.union_all(others), S / 2 + 0.05, cap_style="flat")))
    assert (access >= 3.0).all()


def test_a_continued_key_road_stays_the_road_given_plus_a_new_street():
    """A key road ending inside the region is continued; the output keeps the road as given
    (a copy up to the noding grid) and the continuation as a street of its own that ends on
    it. As one line, the continuation made the whole road a new street doubling the given
    one (Mauren, Helsinki: duplicates, and crossings where rounding put it across)."""
    from urban_synthesis.plugin.network import invariants

    region = shapely.box(0, 0, 600, 400)
    road = shapely.LineString([(-10, 201.2345678), (150.1234567, 203.7654321),
                               (300.7654321, 197.1234567)])     # ends 300 m short of x = 600
    lay = domain_split.split_domain(region, key_roads=[road], templates=LIB, seed=2)
    new = invariants.new_streets(lay.roads, [road])
    check = invariants.check_network(lay.roads[new], [road], area=region)
    assert check.violations()["crossings_given"] == 0
    assert check.violations()["parallel_duplicates"] == 0, check.summary()
    copies = lay.roads[~new]
    assert shapely.union_all(copies).length == pytest.approx(
        shapely.intersection(road, region).length, abs=0.01)
    continued = lay.roads[new & (lay.road_kind == "key")]
    assert len(continued) and shapely.dwithin(continued, road.boundary.geoms[1], 1e-4).any()


def test_a_continuation_with_several_vertices_is_cut_where_the_given_road_ends():
    """A continued key road whose continuation has two vertices past the given road's end
    (a vertex where it was noded on its way): it is cut at the given road's end, not left
    one street that runs 13 m along the given road and on past its end (splitdomain on the
    fidelity benchmark's Mauren: a crossing of a given road without a junction)."""
    given = shapely.LineString([(0, 0), (40, 3), (80, 0)])
    continued = shapely.LineString([(20, 1.5), (40, 3), (80, 0), (100, -1.5), (140, -4.5)])
    lines, level, kind = domain_split._cut_continuations(
        [continued], [0], ["key"], [given])
    assert len(lines) == 2 and list(kind) == ["key", "key"]
    assert shapely.equals(lines[1], shapely.LineString([(80, 0), (100, -1.5), (140, -4.5)]))
    assert shapely.covers(shapely.buffer(given, 1e-6), lines[0])


def test_a_corner_on_a_long_street_side_is_a_parcel_joint():
    """A strip block whose long sides bend by 40° (a region corner, > CORNER_TURN) is
    taken by a row template: a parcel joint is pinned on each bend and its cost is the
    registration residual; a fifth corner on an end side is one the template cannot
    take (its turn is the penalty)."""
    t = np.radians(40)
    bend_top = (150 - 60 * np.tan(t / 2), 60)
    block = shapely.Polygon([(0, 0), (150, 0), (150 + 100 * np.cos(t), 100 * np.sin(t)),
                             (150 + 100 * np.cos(t) - 60 * np.sin(t),
                              100 * np.sin(t) + 60 * np.cos(t)), bend_top, (0, 60)])
    ring, idx, turn = templates.region_corners(block)
    assert len(idx) == 6                               # the two bends are corners
    *_, penalty = templates.region_frame(block, with_penalty=True)
    assert penalty == 0.0
    lib = {t.name: t for t in LIB}
    warp = templates.warp_rows(block, lib["double_strip"], L, W, None)
    assert warp is not None and warp.energy < 0.15
    # a parcel joint sits on each bend of the long sides: no lot straddles one
    corners = shapely.extract_unique_points(shapely.union_all(warp.lots))
    near = [float(shapely.distance(corners, shapely.Point(b))) for b in ((150, 0), bend_top)]
    assert max(near) < 1e-6
    # a notch in an end side stays a corner the template cannot take
    notched = shapely.Polygon([(0, 0), (200, 0), (200, 60), (0, 60), (-20, 30)])
    *_, penalty = templates.region_frame(notched, with_penalty=True)
    assert penalty > 0.5


def test_split_streets_meet_their_parent_at_a_node():
    """A split street ending on an earlier split street is a junction of the noded
    network (no false dead end) and the road mesh of the global optimisation has one
    block per leaf (it is evaluated, not reverted for a relabelling failure)."""
    region = shapely.Polygon([(0, 0), (520, -40), (560, 330), (20, 360)])
    lay = domain_split.split_domain(region, templates=LIB, seed=5)
    assert (lay.road_level == domain_split.LEVEL_SPLIT).sum() >= 3
    assert_planar(lay.roads)
    ends = np.vstack([shapely.get_coordinates(shapely.get_point(lay.roads, i)) for i in (0, -1)])
    _, count = np.unique(np.round(ends, 4), axis=0, return_counts=True)
    assert (count >= 2).all()                          # no dead end in a splitting layout
    assert domain_split.table1(lay)["s_d"] == 0
    opt = lay.stats["optimisation"]
    assert opt["iterations"] >= 1 and not opt.get("relabel_failed", False)
    assert "kept" in opt


def _joints(leaves, lines):
    """no_street_joints on hand-made leaves inside their bounding box (its outline a street)."""
    s = domain_split.SplitSettings()
    lib = {t.name: t for t in LIB}
    splitter = domain_split._Splitter(LIB, s, np.random.default_rng(0))
    box = shapely.box(*shapely.union_all([g for g, _ in leaves]).bounds)
    leaves = [[g, name, {}] for g, name in leaves]
    kept, joints, block = domain_split.no_street_joints(leaves, lines, [box.exterior], splitter,
                                                        lib, s)
    assert len(set(block.tolist())) == 2 - len(joints)  # joined leaves are one street block
    return kept, joints


def test_no_street_joints_put_rows_back_to_back_and_end_to_end():
    """Yang Fig. 4 edge labels: between two parcel strips the split street is dropped (the
    rows meet at their rear lot lines), between two double strips end to end too; along a
    double strip's long side, or past the longest row template, the street stays."""
    rear = shapely.LineString([(0, 48), (200, 48)])
    kept, joints = _joints([(shapely.box(0, 0, 200, 48), "parcel_strip"),
                            (shapely.box(0, 48, 200, 96), "parcel_strip")], [rear])
    assert kept == [] and len(joints) == 1 and shapely.hausdorff_distance(joints[0], rear) < 1e-6
    end = shapely.LineString([(150, 0), (150, 75)])
    kept, joints = _joints([(shapely.box(0, 0, 150, 75), "double_strip"),
                            (shapely.box(150, 0, 300, 75), "double_strip")], [end])
    assert kept == [] and len(joints) == 1
    # a double strip needs a street on both long sides
    side = shapely.LineString([(0, 75), (200, 75)])
    kept, joints = _joints([(shapely.box(0, 0, 200, 75), "double_strip"),
                            (shapely.box(0, 75, 200, 150), "double_strip")], [side])
    assert joints == [] and len(kept) == 1
    # joined, the block would be longer than the longest row (30 parcels): the street stays
    far = shapely.LineString([(380, 0), (380, 75)])
    kept, joints = _joints([(shapely.box(0, 0, 380, 75), "double_strip"),
                            (shapely.box(380, 0, 760, 75), "double_strip")], [far])
    assert joints == [] and len(kept) == 1


def test_a_parcel_strip_backs_onto_a_park_that_keeps_a_street():
    """A park the layout left in a small region (Yang's rule-based assignment) needs no
    street on every side: a parcel strip backs onto it without the split street between
    them. A park keeps a street along at least a parcel width of its outline: with the
    region's ends "no street" edges (a town's edge against fields) only one of the two
    streets along a park between two strips goes."""
    below = shapely.LineString([(0, 48), (200, 48)])
    kept, joints = _joints([(shapely.box(0, 0, 200, 48), "parcel_strip"),
                            (shapely.box(0, 48, 200, 90), "park")], [below])
    assert kept == [] and len(joints) == 1
    # a double strip still needs its street along the park
    kept, joints = _joints([(shapely.box(0, 0, 200, 75), "double_strip"),
                            (shapely.box(0, 75, 200, 117), "park")],
                           [shapely.LineString([(0, 75), (200, 75)])])
    assert joints == [] and len(kept) == 1
    s = domain_split.SplitSettings()
    splitter = domain_split._Splitter(LIB, s, np.random.default_rng(0))
    splitter.no_street = shapely.MultiLineString([[(0, 0), (0, 138)], [(200, 0), (200, 138)]])
    above = shapely.LineString([(0, 90), (200, 90)])
    leaves = [[shapely.box(0, 0, 200, 48), "parcel_strip", {}],
              [shapely.box(0, 48, 200, 90), "park", {}],
              [shapely.box(0, 90, 200, 138), "parcel_strip", {}]]
    kept, joints, _ = domain_split.no_street_joints(
        leaves, [below, above], [shapely.box(0, 0, 200, 138).exterior], splitter,
        {t.name: t for t in LIB}, s)
    assert len(joints) == 1 and len(kept) == 1
    assert {round(shapely.get_coordinates(g)[0, 1]) for g in kept + joints} == {48, 90}


def test_a_street_run_through_by_a_joint_is_dropped_whole():
    """A split street whose blocks on one side were joined before (a "no street" edge now
    meets it at a node of two pieces) is dropped whole when every block along it allows
    it: either of its two pieces alone would leave the other ending there (refused: no
    dead end is made). Three parcel strips: one along the bottom, two end to end along the
    top, a cross street between these two; no street is left and no dead end made."""
    s = domain_split.SplitSettings()
    splitter = domain_split._Splitter(LIB, s, np.random.default_rng(0))
    leaves = [[shapely.box(0, 0, 200, 48), "parcel_strip", {}],
              [shapely.box(0, 48, 100, 96), "parcel_strip", {}],
              [shapely.box(100, 48, 200, 96), "parcel_strip", {}]]
    lines = [shapely.LineString([(0, 48), (200, 48)]), shapely.LineString([(100, 48), (100, 96)])]
    kept, joints, block = domain_split.no_street_joints(
        leaves, lines, [shapely.box(0, 0, 200, 96).exterior], splitter,
        {t.name: t for t in LIB}, s)
    assert kept == [] and len(joints) == 3
    assert sum(shapely.length(joints)) == pytest.approx(248, abs=1e-6)
    assert len(set(block.tolist())) == 1  # one street block


def _rear_lot_lines(lay, template):
    """Shared outlines (longer than half a parcel width) of two residential lots of the
    template that lie more than a parcel depth from every street: rear lot lines of rows
    back to back (lots of one row share only side lines, which reach the street)."""
    t = lay.table
    lots = lay.parcels[((t.land_use == "residential") & (t.template == template)).to_numpy()]
    roads = shapely.union_all(lay.roads)
    rear = []
    for i, a in enumerate(lots):
        for b in lots[i + 1:]:
            shared = shapely.intersection(shapely.boundary(a), shapely.boundary(b))
            if shapely.length(shared) > 0.5 * W and shapely.distance(roads, shared) > L:
                rear.append(shared)
    return rear


def test_a_face_too_wide_for_the_old_double_strip_gets_rows_back_to_back():
    """A 92 m deep face between streets (the double strip took at most 90 m, 1.25 parcel
    lengths per row; the parcel strip 1.45) was split by a street into a double and a
    single strip. Its two rows now meet back to back along their rear lot lines, with no
    street between them, and every lot keeps its street access."""
    lay = domain_split.split_domain(shapely.box(0, 0, 200, 92), templates=LIB, seed=1)
    t = lay.table
    assert t.has_street_access[(t.land_use == "residential").to_numpy()].all()
    assert (lay.road_level == domain_split.LEVEL_SPLIT).sum() == 0
    assert len(_rear_lot_lines(lay, "double_strip")) >= 3


def test_rows_meet_end_to_end_without_a_street_and_keep_access():
    """An L-shaped band one double strip deep: the search splits it at the corner; the
    split streets no block needs become "no street" joints (rows end to end), the joined
    blocks count as one street block, no dead end is made, every lot keeps its access and
    the streets take less land than with every split street kept."""
    band = shapely.Polygon([(0, 0), (250, 0), (250, 75), (75, 75), (75, 250), (0, 250)])
    lay = domain_split.split_domain(band, templates=LIB, seed=1)
    t = lay.table
    assert t.has_street_access[(t.land_use == "residential").to_numpy()].all()
    assert lay.stats["n_no_street_joints"] >= 1 and lay.stats["n_inner_parks"] == 0
    assert len(lay.street_blocks) < len(lay.blocks)  # the block metrics see the joined block
    assert domain_split.table1(lay)["s_d"] == 0
    kept = domain_split.split_domain(band, templates=LIB, seed=1,
                                     settings=domain_split.SplitSettings(back_to_back=False))
    # a street across the band is 75 x 15 m of its 31,875 m2 (3.5 points of the land)
    assert domain_split.table1(lay)["l_s"] < domain_split.table1(kept)["l_s"] - 2


def test_outline_beside_a_key_road_is_no_second_street():
    """A region whose south side runs 6 m beside a key road just outside it (a settlement
    outline drawn along its main road): that side is no street of the result (the key road
    is), the outline's cut ends and the streets that ended there join the key road, and the
    network keeps every invariant but the dead-end share (splitdomain makes none)."""
    from urban_synthesis.plugin.network import invariants

    region = shapely.box(0, 0, 420, 300)
    keys = [shapely.LineString([(-60, -6), (480, -6)]),
            shapely.LineString([(210, -6), (210, 360)])]
    res = domain_split.split_domain([region], key_roads=keys, seed=1,
                                    settings=domain_split.SplitSettings(optimise=False))
    assert res.stats["n_outline_beside_key_roads"] >= 1
    g = res.roads
    new = g[invariants.new_streets(g, keys)]
    check = invariants.check_network(new, keys, area=region)
    v = check.violations()
    v.pop("dead_end_share")
    assert sum(v.values()) == 0, check.summary()
    # nothing runs along the south side, and streets reach the key road from the north
    south = shapely.LineString([(0, 0), (420, 0)]).buffer(1.0)
    assert shapely.length(shapely.intersection(new, south)).sum() < 2 * 3.0
    assert shapely.dwithin(new, keys[0], 1e-6).sum() >= 2
    assert_planar(g)


def test_no_split_street_runs_along_a_key_road_outside_the_region():
    """Schaan's outline (the fidelity benchmark's target) runs beside its level-0 roads, and
    where it lies in a road's corridor it is no street; with rows of up to 30 parcels a split
    street ran 108 m along such a road there (seed 0). Split streets keep out of every key
    road's corridor, the invariants' rule: no parallel duplicate on the real town."""
    from towns import LI_PBF, liechtenstein_towns
    from urban_synthesis.plugin.network import invariants

    if not LI_PBF.exists():
        pytest.skip(f"{LI_PBF} is missing")
    town = {t.name: t for t in liechtenstein_towns()}["Schaan"]
    lay = domain_split.split_domain(shapely.get_parts(town.area), key_roads=town.given, seed=0,
                                    settings=domain_split.SplitSettings(optimise=False))
    new = lay.roads[invariants.new_streets(lay.roads, town.given)]
    check = invariants.check_network(new, town.given, town.given_class, town.area)
    assert check.violations()["parallel_duplicates"] == 0
    assert check.violations()["crossings_given"] == 0 and check.n_components == 1


def _vertex_turns(lines) -> np.ndarray:
    """Turn (degrees) at every inner vertex of the lines."""
    turns = []
    for line in lines:
        d = np.diff(shapely.get_coordinates(line), axis=0)
        a = np.arctan2(d[:, 1], d[:, 0])
        turns.append(np.degrees(np.abs((np.diff(a) + np.pi) % (2 * np.pi) - np.pi)))
    return np.concatenate(turns) if turns else np.zeros(0)


def test_outline_street_is_a_curve_where_the_region_only_bends():
    """A region drawn as a 16-gon (a buffer's arc: a bend of 22.5 degrees every 86 m): the
    street along its outline bends as a curve, no vertex turning more than 5 degrees, and
    no lot along it keeps a kink of the polygon as a corner of 145-170 degrees (Yang's
    p_angle would count each as a 55-80 degree deviation). A square corner stays a corner."""
    disc = shapely.Point(0, 0).buffer(220, quad_segs=4)
    region = shapely.union(disc, shapely.box(0, -220, 220, 0))  # one square corner
    settings = domain_split.SplitSettings(optimise=False)
    lay = domain_split.split_domain([region], seed=3, settings=settings)
    outline = lay.roads[lay.road_kind == "outline"]
    turns = _vertex_turns(outline)
    assert turns.max() > 80  # the square corner
    assert np.sort(turns)[-2] <= 5.0 + 1e-6
    # on the outline, within the arcs' sagitta
    vertices = shapely.points(shapely.get_coordinates(outline))
    assert shapely.distance(vertices, region.exterior).max() < 1.2
    points, angles, owner = metrics.corners(lay.parcels)
    along = shapely.distance(shapely.points(points), region.exterior) < \
        settings.street_width / 2 + 3.0
    assert along.sum() > 20
    assert not ((angles[along] > 145) & (angles[along] < 170)).any()
    assert shapely.within(shapely.union_all(lay.parcels), region)


def test_outline_beside_a_key_road_inside_the_region_is_no_street():
    """A key road 20 m inside the top of a 400 x 300 m region, parallel to it (a town's edge
    road inside its envelope): a street along the top would leave a 5 m strip between the
    two streets, too shallow for any lot (Gamprin's slivers). The top is no street there:
    the strip's lots front on the key road, 12.5 m deep, and no outline street runs beside
    it (nor does any link street run along the region's side). Without a key road the
    whole outline is a street."""
    region = shapely.box(0, 0, 400, 300)
    key = shapely.LineString([(-20, 280), (420, 280)])
    settings = domain_split.SplitSettings(optimise=False)
    lay = domain_split.split_domain([region], key_roads=[key], seed=2, settings=settings)
    top = shapely.LineString([(0, 300), (400, 300)])
    streets = lay.roads[lay.road_kind != "key"]
    assert shapely.length(shapely.intersection(
        shapely.union_all(streets), shapely.buffer(top, 1.0))).sum() < 1.0
    in_strip = np.asarray(shapely.within(lay.parcels, shapely.box(-1, 279, 401, 301)))
    assert in_strip.sum() >= 6
    bounds = shapely.bounds(lay.parcels[in_strip])
    assert np.allclose(bounds[:, 1], 287.5) and np.allclose(bounds[:, 3], 300.0)  # 12.5 m
    assert np.isclose(shapely.area(lay.parcels[in_strip]).sum(), 400 * 12.5)
    assert lay.table[in_strip].has_street_access.all()
    # no street runs along the region's sides next to the strip (a link there would)
    for side in (shapely.LineString([(0, 280), (0, 300)]),
                 shapely.LineString([(400, 280), (400, 300)])):
        near = shapely.intersection(shapely.union_all(streets), shapely.buffer(side, 3.0))
        assert shapely.length(near) < 4.0
    plain = domain_split.split_domain([region], seed=2, settings=settings)
    outline = shapely.union_all(plain.roads[plain.road_kind == "outline"])
    assert shapely.length(shapely.intersection(outline, shapely.buffer(top, 1.0))) > 399


def test_inputs_with_heights_give_the_planar_layout():
    """Bubenec's cadastre plots with heights (Z: a cadastre exported in 3D) as the region
    give the layout of their plan: the same lots as without Z. They failed in the warp (a
    block's sides carried three coordinates). (Drawn templates with Z already gave their
    plan's template.)"""
    plots = bubenec("plots").geometry.to_numpy()
    c = shapely.centroid(shapely.union_all(plots))
    plots = plots[shapely.within(shapely.centroid(plots), shapely.buffer(c, 150))]
    settings = domain_split.SplitSettings(optimise=False)
    flat = domain_split.split_domain(plots, seed=2, settings=settings)
    high = domain_split.split_domain(shapely.force_3d(plots, 7.5), seed=2, settings=settings)
    assert not shapely.has_z(high.parcels).any() and len(high.parcels) == len(flat.parcels)
    assert shapely.equals(high.parcels, flat.parcels).all()


def test_lots_along_a_kinked_given_road_have_no_corner_at_its_kinks():
    """A given road across the region digitised as a polyline with kinks of 12-30 degrees
    (as OSM draws a curve): the lots on both sides of it keep half a street from its centre
    line, front on it, and have no corner of 145-170 degrees at the kinks (Yang's p_angle
    would count each as a 55-80 degree deviation); the road keeps every kink given."""
    region = shapely.box(0, 0, 600, 400)
    xs = np.array([-20.0, 90, 170, 260, 340, 430, 520, 620])
    ys = np.array([190.0, 190, 210, 200, 228, 212, 190, 190])   # turns of 12-30 degrees
    key = shapely.LineString(np.c_[xs, ys])
    settings = domain_split.SplitSettings(optimise=False)
    lay = domain_split.split_domain([region], key_roads=[key], seed=1, settings=settings)
    given = shapely.union_all(lay.roads[lay.road_kind == "key"])
    assert shapely.hausdorff_distance(given, shapely.clip_by_rect(key, 0, 0, 600, 400)) < 1e-3
    points, angles, owner = metrics.corners(lay.parcels)
    near = shapely.distance(shapely.points(points), key) < S / 2 + 2.0
    assert near.sum() > 30
    assert not ((angles[near] > 145) & (angles[near] < 170)).any()
    with np.errstate(invalid="ignore"):
        on_road = shapely.area(shapely.intersection(
            lay.parcels, shapely.buffer(key, S / 2 - 0.01, cap_style="flat")))
    assert on_road.sum() < 1e-3
    beside = shapely.distance(lay.parcels, key) < S / 2 + 0.5
    assert beside.sum() > 20
    assert lay.table[beside].has_street_access.all()


def test_a_joint_moves_where_its_two_lots_are_squarer():
    """A row's end lot cut by a slanted side beside a rectangle: the joint between them
    moves to where their summed p_area is lower (Yang's mean over the same two lots),
    their corners deviate no more, each keeps its frontage and stays within the pair's
    area range; a row of rectangles keeps its joints."""
    street = shapely.LineString([(-10, 0), (80, 0)])

    def frontage(lots):
        band = shapely.buffer(street, 0.05)
        return np.round(np.maximum(shapely.length(shapely.intersection(
            shapely.boundary(lots), band)) - 0.2, 0.0), 2)

    lots = np.array([shapely.box(0, 0, 18, 30),
                     shapely.Polygon([(18, 0), (38, 0), (26, 30), (18, 30)])], dtype=object)
    p_angle, p_area, _ = parcels_mod.lot_quality(lots)
    new, front, moved = domain_split.settle_joints(lots, frontage(lots), frontage, 0.3 * 540,
                                                   0.4 * 18)
    assert len(new) == 2 and moved == 1
    new_angle, new_area, _ = parcels_mod.lot_quality(new)
    assert new_area.sum() < p_area.sum() - 0.05
    assert new_angle.sum() <= p_angle.sum() + 1e-9
    assert shapely.symmetric_difference(shapely.union_all(new), shapely.union_all(lots)).area < 1e-6
    areas = shapely.area(new)
    assert (areas >= 420 - 1e-6).all() and (areas <= 540 + 1e-6).all()
    assert (front >= parcels_mod.MIN_FRONTAGE).all()
    np.testing.assert_allclose(front, frontage(new))
    row = np.array([shapely.box(18 * k, 0, 18 * (k + 1), 30) for k in range(4)], dtype=object)
    same, _, moved = domain_split.settle_joints(row, frontage(row), frontage)
    assert moved == 0
    assert sorted(g.wkt for g in same) == sorted(g.wkt for g in row)


def test_settled_joints_lower_p_area_and_keep_the_streets_and_lots():
    """On a parallelogram (its rows end at slanted sides) the settled joints give the
    same streets and as many lots, every one with access, at a lower p_area and no
    higher p_angle than the warp's joints."""
    region = shapely.Polygon([(0, 0), (300, 0), (380, 200), (80, 200)])
    lays = [domain_split.split_domain([region], seed=1, settings=domain_split.SplitSettings(
        optimise=False, settle_joints=on)) for on in (False, True)]
    before, after = (domain_split.table1(lay) for lay in lays)
    assert len(lays[0].roads) == len(lays[1].roads)
    assert all(shapely.equals_exact(a, b, 1e-9) for a, b in zip(lays[0].roads, lays[1].roads))
    assert len(lays[0].parcels) == len(lays[1].parcels)
    assert after["p_area"] < before["p_area"] - 0.005
    assert after["p_angle"] <= before["p_angle"]
    table = lays[1].table
    assert table.has_street_access[table.land_use == "residential"].all()
