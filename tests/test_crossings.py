"""The crossing-share steering of a network of lines (network/crossings.py)."""

import numpy as np
import pytest
import shapely

from helpers import assert_no_gaps, assert_planar
from urban_synthesis.plugin.measure import fidelity
from urban_synthesis.plugin.network.crossings import match_crossings, streets_across


def _ladder(bottom_given=False):
    """Three east-west streets 100 m apart and four stems between the upper two: eight T
    junctions, no crossing. The stems' T's on the middle street can go on south to the
    bottom street."""
    rows = [shapely.LineString([(0, y), (500, y)]) for y in (-100, 0, 100)]
    stems = [shapely.LineString([(x, 0), (x, 100)]) for x in (100, 200, 300, 400)]
    lines = np.array(rows + stems, dtype=object)
    is_new = np.ones(len(lines), bool)
    if bottom_given:
        is_new[0] = False
    return lines, is_new


def _noded(lines, is_new):
    from urban_synthesis.plugin.network.street_graph import renode

    return renode(lines, is_new, np.zeros(len(lines), np.int64))


AREA = shapely.box(-50, -150, 550, 150)


def test_t_junctions_become_straight_crossings_up_to_the_share():
    lines, is_new = _ladder()
    pieces, parent = _noded(lines, is_new)
    before = fidelity.fidelity_statistics(pieces, AREA)["degree4_share"]
    assert before == 0.0
    # the middle street's T's and the ends of the three streets are the nodes: two of the
    # four stems going on south (two crossings, two new T's: 2 of 16) reach a share of 0.1
    out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.1, AREA,
                                     np.random.default_rng(0), reach=150.0)
    assert made == 2
    assert fidelity.fidelity_statistics(out, AREA)["degree4_share"] == pytest.approx(2 / 16)
    assert_planar(out)
    assert new.all()
    # each one its stem straight on south, onto the bottom street
    south = [g for g in out if g.bounds[1] == -100 and g.bounds[3] == 0]
    assert len(south) == made and all(g.bounds[0] == g.bounds[2] for g in south)
    # a share the stems cannot reach: every stem goes on south; then the top street's T's,
    # with no street across in reach, go on north to the target's edge 50 m away (their
    # ends there are where the network leaves the target, no dead ends): 8 of 18, no more
    out, _, (made, _) = match_crossings(pieces, is_new[parent], 0.9, AREA,
                                   np.random.default_rng(0), reach=150.0)
    assert made == 8
    assert fidelity.fidelity_statistics(out, AREA)["degree4_share"] == pytest.approx(8 / 18)
    north = [g for g in out if g.bounds[1] == 100 and g.bounds[3] == 150]
    assert len(north) == 4 and all(g.bounds[0] == g.bounds[2] for g in north)


def test_streets_across_are_what_match_crossings_adds_with_their_stems():
    """The streets alone (a method that keeps its own lines, the random walk's table, adds
    them as they are): each from the end of the T's own street it continues, straight on
    to the street it meets, which is not split; noded, they are match_crossings' result."""
    lines, is_new = _ladder()
    pieces, parent = _noded(lines, is_new)
    streets, stems = streets_across(pieces, is_new[parent], 0.1, AREA,
                                    np.random.default_rng(0), reach=150.0)
    out, _, (made, _) = match_crossings(pieces, is_new[parent], 0.1, AREA,
                                        np.random.default_rng(0), reach=150.0)
    assert len(streets) == len(stems) == made == 2
    for street, stem in zip(streets, stems):
        stem_line = pieces[stem]
        start = shapely.get_point(street, 0)
        # the stem is one of the four north-south stems, and the street starts at its end
        assert stem_line.bounds[0] == stem_line.bounds[2] and stem_line.bounds[1] == 0
        assert start.equals(shapely.get_point(stem_line, 0)) or \
            start.equals(shapely.get_point(stem_line, -1))
        # straight on south, onto the bottom street (a T on it)
        assert street.bounds[0] == street.bounds[2] == stem_line.bounds[0]
        assert (street.bounds[1], street.bounds[3]) == (-100, 0)
    assert sorted(round(g.length, 6) for g in streets) == \
        sorted(round(g.length, 6) for g in out if g.bounds[1] == -100 and g.bounds[3] == 0)
    # at or over the share: nothing
    none, no_stems = streets_across(pieces, is_new[parent], 0.0, AREA, np.random.default_rng(0))
    assert len(none) == len(no_stems) == 0


def test_a_crossing_street_starts_exactly_at_its_junction():
    """The cleaned graph's nodes are rounded to the millimetre: the street that goes on
    across starts at the junction of the lines themselves, not up to 0.7 mm beside it."""
    lines, is_new = _ladder()
    off = np.array([0.000437, 0.000381])   # off the millimetre grid
    lines = shapely.transform(lines, lambda xy: xy + off)
    pieces, parent = _noded(lines, is_new)
    out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.9, AREA,
                                         np.random.default_rng(0), reach=150.0)
    assert made == 8   # four south onto the bottom street, four north to the edge
    assert_planar(out)
    assert_no_gaps(out)
    # every end at a junction of the input is that junction, not a point beside it
    ends_in = shapely.points(np.unique(shapely.get_coordinates(shapely.boundary(pieces)),
                                       axis=0))
    ends_out = shapely.points(np.unique(shapely.get_coordinates(shapely.boundary(out)),
                                        axis=0))
    near = shapely.STRtree(ends_in).query(ends_out, predicate="dwithin", distance=1e-3)
    assert len(near[0]) >= len(ends_in)
    assert (shapely.distance(ends_out[near[0]], ends_in[near[1]]) == 0.0).all()


def test_no_street_ends_on_a_given_road_or_out_of_reach():
    # the target's edge 400 m from the outer streets: beyond EDGE_REACH x 150 m too
    far = shapely.box(-50, -500, 550, 500)
    lines, is_new = _ladder(bottom_given=True)
    pieces, parent = _noded(lines, is_new)
    out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.5, far,
                                     np.random.default_rng(0), reach=150.0)
    assert made == 0 and len(out) == len(pieces)
    lines, is_new = _ladder()
    pieces, parent = _noded(lines, is_new)
    out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.5, far,
                                     np.random.default_rng(0), reach=80.0)
    assert made == 0


def test_a_street_across_goes_on_to_the_edge_when_no_street_is_in_reach():
    """Still under the share when no T's street can go on to a street (the bottom road is
    given, the top street's T's face the open land): a T whose street meets nothing in reach
    goes on straight to the target's edge, where the network leaves the target (a piece cut
    out of a city, Bubeneč), and ends on it exactly; an end there is no dead end."""
    from urban_synthesis.plugin.network import invariants

    lines, is_new = _ladder(bottom_given=True)
    pieces, parent = _noded(lines, is_new)
    before = invariants.dead_end_share(pieces, AREA)
    out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.5, AREA,
                                         np.random.default_rng(0), reach=150.0)
    assert made == 4   # the top street's four T's, north; the middle ones meet the given road
    added = out[new & ~shapely.covered_by(out, shapely.union_all(pieces).buffer(1e-6))]
    assert len(added) == 4
    for street in added:
        xy = shapely.get_coordinates(street)
        assert xy[0, 0] == xy[-1, 0] and sorted(xy[[0, -1], 1]) == [100.0, 150.0]
    assert (shapely.distance(shapely.boundary(AREA),
                             shapely.points(shapely.get_coordinates(added)[1::2])) == 0).all()
    assert invariants.crossing_share(out, AREA) == pytest.approx(4 / 14)
    assert invariants.dead_end_share(out, AREA) == pytest.approx(before)
    check = invariants.check_network(out[new], out[~new], None, AREA, target=AREA)
    assert len(check.outside) == len(check.crossings_given) == 0
    assert len(check.crossings_synthesised) == 0
    assert_planar(out)


def test_a_street_goes_on_to_an_edge_beyond_the_reach_of_a_street_across():
    """The edge lies farther than the next street would (a town cut out of a city): a T
    whose street meets nothing goes on to it up to EDGE_REACH times the reach of a street
    across: 200 m north of the top street with a reach of 150 m, all four; 400 m, none."""
    from urban_synthesis.plugin.network.crossings import EDGE_REACH

    assert 150.0 < 200.0 <= EDGE_REACH * 150.0 < 400.0
    lines, is_new = _ladder(bottom_given=True)
    pieces, parent = _noded(lines, is_new)
    for top, north in ((300.0, 4), (500.0, 0)):
        area = shapely.box(-50, -150, 550, top)
        out, new, (made, _) = match_crossings(pieces, is_new[parent], 0.5, area,
                                             np.random.default_rng(0), reach=150.0)
        assert made == north
        added = [g for g in out if g.bounds[1] == 100 and g.bounds[3] == top]
        assert len(added) == north and all(g.bounds[0] == g.bounds[2] for g in added)
        assert_planar(out)


def test_a_street_across_ends_on_a_given_road_that_may_take_one():
    """StreetGAN's rule: where the first street across is a given road that takes junctions
    (``may_end_on``), the T's street goes on to it; the given road is split at the new T
    and its pieces stay given."""
    lines, is_new = _ladder(bottom_given=True)
    pieces, parent = _noded(lines, is_new)
    new_in = is_new[parent]
    out, new, (made, _) = match_crossings(pieces, new_in, 0.1, AREA,
                                         np.random.default_rng(0), reach=150.0,
                                         may_end_on=np.ones(len(pieces), bool))
    assert made == 2
    assert fidelity.fidelity_statistics(out, AREA)["degree4_share"] == pytest.approx(2 / 16)
    assert_planar(out)
    assert_no_gaps(out)
    south = [g for g in out if g.bounds[1] == -100 and g.bounds[3] == 0]
    assert len(south) == made and all(new[out.tolist().index(g)] for g in south)
    # the bottom road, given, now in three pieces with a vertex at each new T
    bottom = [g for g, n in zip(out, new) if g.bounds[1] == g.bounds[3] == -100]
    assert len(bottom) == 3 and not any(new[out.tolist().index(g)] for g in bottom)
    assert sum(g.length for g in bottom) == pytest.approx(500.0)
    # a given road that may take none (a motorway) keeps the old rule: nothing ends on it
    # (the crossings are made to the north instead, where the target's edge is in reach)
    out, new, (made, _) = match_crossings(pieces, new_in, 0.1, AREA, np.random.default_rng(0),
                                          reach=150.0, may_end_on=new_in)
    assert made == 2
    bottom = shapely.LineString([(0, -100), (500, -100)])
    assert not shapely.intersects(out[new], bottom).any()


def test_too_many_crossings_lose_streets_between_junctions():
    """A 5 x 4 grid of streets 100 m apart: 6 crossings among 16 counted nodes (the T's on
    its edge; its corners are bends). Down to a share of 0.25, streets at crossings go,
    smallest merged blocks first: no dead end is made, nothing floats, the given outline
    stays, and blocks merge."""
    from urban_synthesis.plugin.network import invariants

    rows = [shapely.LineString([(0, y), (400, y)]) for y in (0, 100, 200, 300)]
    cols = [shapely.LineString([(x, 0), (x, 300)]) for x in (0, 100, 200, 300, 400)]
    lines = np.array(rows + cols, dtype=object)
    is_new = np.ones(len(lines), bool)
    is_new[[0, 3, 4, 8]] = False   # the outline is given
    pieces, parent = _noded(lines, is_new)
    area = shapely.box(-20, -20, 420, 320)
    before = invariants.crossing_share(pieces, area)
    assert before == pytest.approx(6 / 16)
    out, new, (made, removed) = match_crossings(pieces, is_new[parent], 0.25, area,
                                                np.random.default_rng(0))
    assert made == 0 and removed >= 1
    assert invariants.crossing_share(out, area) <= 0.25
    assert invariants.dead_end_share(out, area) == 0.0
    assert_planar(out)
    check = invariants.check_network(out[new], out[~new], None, area)
    assert check.floating_pieces == 0
    outline = shapely.union_all(out[~new])
    assert outline.equals(shapely.union_all(lines[~is_new]))
    faces = shapely.get_parts(shapely.polygonize(out))
    assert len(faces) == 12 - removed
    # a share the network already has: nothing changes
    same, _, (made, removed) = match_crossings(pieces, is_new[parent], before, area,
                                               np.random.default_rng(0))
    assert (made, removed) == (0, 0) and same is pieces


@pytest.mark.parametrize("share", [-0.1, 1.5])
def test_streetgan_refuses_a_share_outside_0_1(share):
    from urban_synthesis.plugin.core.progress import InputError
    from urban_synthesis.plugin.roads import streetgan

    with pytest.raises(InputError, match="crossing share"):
        streetgan.synthesize(shapely.box(0, 0, 300, 300), "streetgan_towns",
                             crossing_share=share)


def test_no_street_goes_on_along_the_street_it_crosses():
    """A street that meets a through street at a shallow angle (30 degrees, the through
    street bending by 10 degrees there): going straight on would leave the junction 20
    degrees from the through street, running beside it (with a given road: a crossing that
    noding left a millimetre off the junction, Helsinki's fragments). It is not continued;
    the square T beside it is."""
    west = shapely.LineString([(-200, 0), (0, 0)])
    east = shapely.LineString([(0, 0), (200, -35)])
    shallow = shapely.LineString([(-173.2, 100), (0, 0)])
    square = shapely.LineString([(-100, 0), (-100, 150)])
    south = shapely.LineString([(100, -17.5), (100, -200)])
    south_west = shapely.LineString([(-200, -120), (150, -120)])
    lines = np.array([west, east, shallow, square, south, south_west], dtype=object)
    lines, _ = _noded(lines, np.ones(len(lines), bool))
    # the edge out of reach (EDGE_REACH): no T goes on to it
    area = shapely.box(-1000, -1000, 1000, 1000)
    out, is_new, (made, removed) = match_crossings(lines, np.ones(len(lines), bool), 1.0, area,
                                                   np.random.default_rng(0))
    assert made == 1 and removed == 0
    added = out[~shapely.covered_by(out, shapely.union_all(lines).buffer(1e-6))]
    assert len(added) >= 1
    xs = shapely.get_coordinates(shapely.union_all(added))[:, 0]
    assert np.allclose(xs, -100.0)   # the square T's street went on south, nothing at (0, 0)
    assert_planar(out)
