"""Engine tests of plugin.measure.fidelity: the statistics of networks whose answer is known,
the three naive baselines (density, spacing, seeds) and the scoring (no QGIS)."""
import math

import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.core.progress import InputError
from urban_synthesis.plugin.measure import fidelity as F

BOX = shapely.box(0, 0, 600, 400)


def test_statistics_of_a_grid():
    """A 100 m grid over a 650 m x 450 m box, its lines 25 m in from the edges: 7 x 5
    crosses, the cut ends on the edge are not dead ends, 6 x 4 closed blocks of 1 ha."""
    box = shapely.box(0, 0, 650, 450)
    lines = F.grid_baseline(box, 100.0, angle=0.0)
    s = F.fidelity_statistics(lines, box)
    km2 = 0.2925
    assert s["intersections_per_km2"] == pytest.approx(35 / km2)
    assert s["dead_ends_per_km2"] == 0 and s["degree1_share"] == 0
    assert s["degree4_share"] == 1.0 and s["degree3_share"] == 0
    assert s["street_length_km_per_km2"] == pytest.approx((7 * 0.45 + 5 * 0.65) / km2)
    # 58 inner segments of 100 m, 24 stubs of 25 m to the edge
    assert s["segment_length_p50"] == pytest.approx(100.0)
    assert s["segment_length_p10"] == pytest.approx(25.0)
    assert s["orientation_entropy"] == pytest.approx(math.log(4), abs=1e-3)
    assert s["blocks_per_km2"] == pytest.approx(24 / km2)
    assert s["block_area_p50"] == pytest.approx(1e4)
    assert s["block_compactness_p50"] == pytest.approx(1.0)
    assert s["block_aspect_p50"] == pytest.approx(1.0)
    assert list(s) == [k for k, _ in F.STATISTICS] and len(s) == 16



def test_streets_cut_at_the_edge_are_counted_apart_from_dead_ends():
    """The grid above: its 24 ends on the box's edge are streets cut there, none a dead end;
    a given road's ends at the edge are not counted, nor is a cul-de-sac inside, and a street
    ending 2 m short of the edge is a dead end, not a cut."""
    box = shapely.box(0, 0, 650, 450)
    lines = F.grid_baseline(box, 100.0, angle=0.0)
    km2 = 0.2925
    assert F.edge_ends(lines, box) == pytest.approx(24 / km2)
    given = [g for g in lines if g.coords[0][1] == g.coords[-1][1] == 225.0]
    assert len(given) == 1
    assert F.edge_ends(lines, box, given) == pytest.approx(22 / km2)
    cul_de_sac = shapely.LineString([(75, 225), (75, 260)])
    short = shapely.LineString([(625, 175), (648, 175)])   # 2 m short of the eastern edge
    more = np.concatenate([lines, [cul_de_sac, short]])
    assert F.edge_ends(more, box, given) == pytest.approx(22 / km2)
    assert F.fidelity_statistics(more, box)["dead_ends_per_km2"] == pytest.approx(2 / km2)

def test_relative_errors_and_missing_statistics():
    s = F.fidelity_statistics(F.grid_baseline(BOX, 100.0, angle=0.0), BOX)
    assert all(v == 0 for v in F.relative_errors(s, s).values())
    # a network that closes no block: its block statistics count as error 1
    tree = [shapely.LineString([(0, 200), (600, 200)]), shapely.LineString([(300, 200),
                                                                            (300, 300)])]
    t = F.fidelity_statistics(tree, BOX)
    assert np.isnan(t["block_area_p50"]) and t["blocks_per_km2"] == 0
    e = F.relative_errors(t, s)
    assert e["block_area_p50"] == 1.0 and e["blocks_per_km2"] == 1.0
    with pytest.raises(InputError, match="no street"):
        F.fidelity_statistics([shapely.LineString([(1000, 0), (1100, 0)])], BOX)


@pytest.mark.parametrize("seed", [0, 1])
def test_random_baselines_reach_the_density_and_repeat_with_the_seed(seed):
    area = shapely.Point(0, 0).buffer(500.0)
    given = [shapely.LineString([(-600, 0), (600, 0)])]
    for make in (lambda rng: F.chord_baseline(area, 12.0, rng, given),
                 lambda rng: F.delaunay_baseline(area, 12.0, 90.0, rng, given)):
        a = make(np.random.default_rng(seed))
        b = make(np.random.default_rng(seed))
        assert all(x.equals(y) for x, y in zip(a, b))
        total = shapely.length(a).sum() + 1000.0          # the given road inside the disc
        assert total / 1e3 / (area.area / 1e6) == pytest.approx(12.0, rel=0.05)
        assert shapely.within(a, area.buffer(1e-6)).all()
    # Delaunay edges of points one spacing apart are about a spacing long
    d = F.delaunay_baseline(area, 12.0, 90.0, np.random.default_rng(seed), given)
    assert 50 < np.median(shapely.length(d)) < 130


def test_grid_baseline_spacing_and_orientation():
    square = shapely.box(0, 0, 500, 500)
    rotated = shapely.affinity.rotate(square, 30, origin="centroid")
    g = F.grid_baseline(rotated, 80.0)
    s = F.fidelity_statistics(g, rotated)
    assert s["segment_length_p50"] == pytest.approx(80.0, rel=1e-6)
    # aligned with the rotated square: two directions, 30 and 120 degrees
    assert s["orientation_entropy"] == pytest.approx(math.log(4), abs=0.05)
    with pytest.raises(InputError, match="spacing"):
        F.grid_baseline(square, 0.0)


def test_score_counts_wins_against_each_baseline():
    real = F.fidelity_statistics(F.grid_baseline(BOX, 100.0, angle=0.0), BOX)
    same = dict(real)
    off = {k: 2 * v for k, v in real.items()}
    sc = F.score([same, same], real, {"bad": [off], "perfect": [same]})
    assert sc["median_error"] == 0
    # where the real value is 0 (dead ends) both are exact: no win there
    assert sc["wins"]["bad"] == sum(1 for v in real.values() if v != 0)
    assert sc["wins"]["perfect"] == 0
