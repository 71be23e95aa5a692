"""The dead-end steering of any network of lines (network/dead_ends.py)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.network import dead_ends, invariants


def street_grid(n: int = 5, spacing: float = 100.0) -> np.ndarray:
    """n x n streets crossing at every node: no dead end at all."""
    top = (n - 1) * spacing
    return np.array([shapely.LineString([(0, i * spacing), (top, i * spacing)]) for i in range(n)]
                    + [shapely.LineString([(i * spacing, 0), (i * spacing, top)])
                       for i in range(n)], dtype=object)


def noded(lines):
    return shapely.get_parts(shapely.node(shapely.multilinestrings(list(lines))))


AREA = shapely.box(-100, -100, 500, 500)


def test_a_share_inside_the_band_is_left_alone():
    lines = noded(street_grid())
    share = invariants.dead_end_share(lines, AREA)
    assert share == 0.0
    out, is_new, counts = dead_ends.steer_into_band(lines, np.ones(len(lines), bool), share,
                                                    AREA, np.random.default_rng(0))
    assert counts == (0, 0) and len(out) == len(lines)
    assert shapely.equals(shapely.union_all(out), shapely.union_all(lines))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_share_outside_the_band_comes_nearer_or_stays(seed):
    """A grid with no dead end, the example's share 0.3 (band 0.21-0.39): cul-de-sacs are
    opened into its blocks and the share comes into the band, the network planar; with no
    line it may change, the network is returned as it was."""
    lines = noded(street_grid())
    out, is_new, counts = dead_ends.steer_into_band(lines, np.ones(len(lines), bool), 0.3,
                                                    AREA, np.random.default_rng(seed))
    assert counts[1] > 0
    now = invariants.dead_end_share(out, AREA)
    assert abs(now - 0.3) <= invariants.DEAD_END_TOLERANCE * 0.3, now
    assert invariants.check_network(out[is_new], out[~is_new], area=AREA).ok
    kept, kept_new, none = dead_ends.steer_into_band(lines, np.zeros(len(lines), bool), 0.3,
                                                     AREA, np.random.default_rng(seed))
    assert none == (0, 0) and len(kept) == len(lines) and not kept_new.any()
