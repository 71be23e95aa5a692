"""Shape context, cyclic DTW and rigid alignment (plugin/retrieval/shape_context.py)."""
from functools import lru_cache

import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.retrieval import shape_context as sc
from urban_synthesis.plugin.core.progress import InputError

POLY = shapely.Polygon([(0, 0), (60, 0), (80, 30), (40, 70), (0, 50), (10, 20)])


def rotation(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def moved(poly, angle, shift):
    return sc.transform_geometries([poly], rotation(angle), np.asarray(shift, float))[0]


def descriptors(polys, scale=None, n_angular=8):
    s = sc.sample_boundaries(polys)
    scale = scale or sc.default_scale(s[:1])
    return s, sc.normalised_histograms(sc.shape_contexts(s, sc.radial_edges(scale), n_angular))


def brute_force_cyclic_dtw(cost):
    """Every offset, every monotone path: the definition, for tiny matrices."""
    n, m = cost.shape
    best = np.inf
    for off in range(m):
        c = np.roll(cost, -off, axis=1)

        @lru_cache(None)
        def d(i, j):
            if i == 0 and j == 0:
                return c[0, 0]
            prev = [d(i - 1, j)] if i else []
            prev += [d(i, j - 1)] if j else []
            prev += [d(i - 1, j - 1)] if i and j else []
            return c[i, j] + min(prev)

        best = min(best, d(n - 1, m - 1))
    return best


def reference_histograms(samples, edges, n_angular):
    """Straightforward per-point loop with arctan2: what the vectorised code must equal."""
    n = len(samples)
    phi = sc.tangent_angles(samples)
    out = np.zeros((n, (len(edges) - 1) * n_angular), dtype=int)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            d = samples[j] - samples[i]
            r = np.hypot(*d)
            a = (np.arctan2(d[1], d[0]) - phi[i] + np.pi / n_angular) % (2 * np.pi)
            abin = min(int(a / (2 * np.pi / n_angular)), n_angular - 1)
            rbin = int(np.searchsorted(edges[1:-1], r, side="right"))
            out[i, rbin * n_angular + abin] += 1
    return out


# --------------------------------------------------------------------------- sampling

def test_samples_are_uniform_ccw_and_start_at_the_farthest_vertex():
    s = sc.sample_boundaries([shapely.box(0, 0, 40, 10)], n=10)[0]
    step = np.hypot(*np.diff(np.vstack([s, s[:1]]), axis=0).T)
    assert np.allclose(step, 10.0)
    # counter-clockwise even though box() is given clockwise-agnostic: signed area > 0
    x, y = s[:, 0], s[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0
    # the four corners are equally far from the centre: the first in ring order wins
    assert tuple(s[0]) in {(40, 0), (40, 10), (0, 10), (0, 0)}
    # a clockwise ring gives the same samples
    cw = shapely.Polygon(list(shapely.box(0, 0, 40, 10).exterior.coords)[::-1])
    assert np.allclose(sc.sample_boundaries([cw], n=10)[0], s)


def test_multipolygon_uses_largest_part_and_empty_is_rejected():
    mp = shapely.MultiPolygon([shapely.box(0, 0, 1, 1), shapely.box(10, 10, 30, 30)])
    s = sc.sample_boundaries([mp], n=8)[0]
    assert s.min() >= 10
    with pytest.raises(InputError):
        sc.sample_boundaries([shapely.Polygon()])


def test_rigid_motion_moves_the_samples_with_the_shape():
    s = sc.sample_boundaries([POLY, moved(POLY, 0.7, (1000, -500))])
    assert np.allclose(sc.apply_rigid(s[0], rotation(0.7), (1000, -500)), s[1], atol=1e-9)


# --------------------------------------------------------------------------- histograms

@pytest.mark.parametrize("n_angular", [8, 6])
def test_vectorised_histograms_equal_the_per_point_definition(n_angular):
    s = sc.sample_boundaries([POLY], n=40)[0]
    edges = sc.radial_edges(30.0)
    fast = sc.shape_contexts(s, edges, n_angular)
    assert fast.shape == (40, 5 * n_angular)
    assert (fast.sum(axis=1) == 39).all()
    ref = reference_histograms(s, edges, n_angular)
    # points exactly on a bin border may fall either way under round-off
    assert np.abs(fast.astype(int) - ref).sum() <= 4


def test_rotation_and_translation_give_the_same_descriptors_and_zero_cost():
    s, h = descriptors([POLY, moved(POLY, 0.7, (1000, -500)), moved(POLY, 2.9, (-3e5, 6.6e6))])
    assert np.array_equal(h[0], h[1]) and np.array_equal(h[0], h[2])
    r = sc.cyclic_dtw(sc.chi2_cost(h[0], h[1]))
    assert r.cost == pytest.approx(0, abs=1e-4) and r.offset == 0


def test_dtw_finds_the_start_offset_of_a_shifted_sequence():
    _, h = descriptors([POLY])
    for shift in (1, 17, 63):
        rolled = np.roll(h[0], -shift, axis=0)     # the same boundary started elsewhere
        r = sc.cyclic_dtw(sc.chi2_cost(h[0], rolled))
        assert r.cost == pytest.approx(0, abs=1e-4)
        assert r.offset == (100 - shift) % 100
        assert np.array_equal(r.sigma, (np.arange(100) - shift) % 100)
        fast_cost, fast_off = sc.cyclic_dtw_costs(sc.chi2_cost(h[0], rolled))
        assert fast_off == r.offset and fast_cost == pytest.approx(0, abs=1e-4)


def test_scale_aware_larger_shape_costs_more():
    # scale-aware (thesis ch. 4.1.2): bins are in metres, so a 2x copy is a worse match
    # than the shape itself and than a slightly scaled copy
    polys = [POLY, shapely.affinity.scale(POLY, 2, 2), shapely.affinity.scale(POLY, 1.1, 1.1)]
    _, h = descriptors(polys)
    self_cost = sc.cyclic_dtw(sc.chi2_cost(h[0], h[0])).cost
    double = sc.cyclic_dtw(sc.chi2_cost(h[0], h[1])).cost
    slight = sc.cyclic_dtw(sc.chi2_cost(h[0], h[2])).cost
    assert self_cost == pytest.approx(0, abs=1e-4)
    assert double > 5 * slight > 0


def test_chi2_matches_its_definition_and_broadcasts():
    rng = np.random.default_rng(3)
    a = rng.random((2, 5, 7)) * (rng.random((2, 5, 7)) > 0.4)
    b = rng.random((2, 6, 7)) * (rng.random((2, 6, 7)) > 0.4)
    a /= np.maximum(a.sum(-1, keepdims=True), 1e-9)
    b /= np.maximum(b.sum(-1, keepdims=True), 1e-9)
    x, y = a[:, :, None, :], b[:, None, :, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = 0.5 * np.nansum((x - y) ** 2 / (x + y), axis=-1)
    got = sc.chi2_cost(a, b)
    assert got.shape == (2, 5, 6)
    assert np.allclose(got, ref, atol=1e-5)
    with np.errstate(invalid="ignore", divide="ignore"):
        ref0 = 0.5 * np.nansum((a[0][None, :, None, :] - y) ** 2 / (a[0][None, :, None, :] + y),
                               axis=-1)
    assert np.allclose(sc.chi2_cost(a[0], b), ref0, atol=1e-5)  # (n,B) against (2,m,B)


# --------------------------------------------------------------------------- DTW

def test_cyclic_dtw_equals_brute_force_on_tiny_inputs():
    rng = np.random.default_rng(7)
    for _ in range(40):
        cost = rng.random((rng.integers(1, 6), rng.integers(1, 6)))
        ref = brute_force_cyclic_dtw(cost)
        assert sc.cyclic_dtw(cost).cost == pytest.approx(ref)
        total, off = sc.cyclic_dtw_costs(cost, n_offsets=None, window=None)
        assert total == pytest.approx(ref)
        # the path is monotone, starts at the offset and closes the cycle
        r = sc.cyclic_dtw(cost)
        assert tuple(r.path[0]) == (0, r.offset)
        assert tuple(r.path[-1]) == (cost.shape[0] - 1, (r.offset - 1) % cost.shape[1])
        assert cost[r.path[:, 0], r.path[:, 1]].sum() == pytest.approx(ref)


def test_batched_dtw_equals_one_by_one():
    rng = np.random.default_rng(11)
    costs = rng.random((3, 12, 12))
    total, off = sc.cyclic_dtw_costs(costs, n_offsets=None, window=None)
    assert total[0] == pytest.approx(brute_force_cyclic_dtw(costs[0]))
    for k in range(3):
        r = sc.cyclic_dtw(costs[k])
        assert total[k] == pytest.approx(r.cost) and off[k] == r.offset


def test_fast_dtw_is_an_upper_bound_and_exact_for_similar_shapes():
    rng = np.random.default_rng(5)
    polys = [POLY] + [shapely.Polygon(np.asarray(POLY.exterior.coords)[:-1]
                                      + rng.normal(0, 3, (6, 2))) for _ in range(6)]
    _, h = descriptors(polys)
    cost = sc.chi2_cost(h[0][None], h[1:])
    exact, exact_off = sc.cyclic_dtw_costs(cost, None, None)
    fast, fast_off = sc.cyclic_dtw_costs(cost)
    assert (fast >= exact - 1e-4).all()
    assert np.allclose(fast, exact, atol=1e-4)
    assert np.array_equal(np.argsort(fast), np.argsort(exact))


# --------------------------------------------------------------------------- terrain

def test_dem_grid_is_bilinear_and_clamped():
    dem = sc.DemGrid(np.array([[0.0, 10.0], [20.0, 30.0]]), (0, 10, 0, 20, 0, -10))
    assert dem(np.array([5.0, 15.0])) == pytest.approx(0.0)        # centre of cell (0, 0)
    assert dem(np.array([10.0, 10.0])) == pytest.approx(15.0)      # between four centres
    assert dem(np.array([-100.0, 15.0])) == pytest.approx(0.0)     # clamped to the edge
    with pytest.raises(InputError):
        sc.DemGrid(np.zeros((2, 2)), (0, 1, 0.5, 0, 0, -1))


def test_slope_descriptors_and_elevation_cost():
    s = sc.sample_boundaries([POLY])
    edges = sc.radial_edges(40.0)
    flat = sc.slope_descriptors(s, lambda xy: np.zeros(xy.shape[:-1]), edges)
    ramp = sc.slope_descriptors(s, lambda xy: 0.1 * xy[..., 0], edges)
    steep = sc.slope_descriptors(s, lambda xy: 5.0 * xy[..., 0], edges)
    assert flat.shape == (1, 100, 40) and not flat.any()
    # on a plane z = 0.1 x the slope to a bin centre is 0.1 cos(direction): within +-0.1
    assert np.abs(ramp).max() <= 0.1 + 1e-6 and np.abs(ramp).max() > 0.09
    assert np.abs(steep).max() == pytest.approx(1.0)  # clipped to the urban maximum
    ce = sc.elevation_cost(flat[0], ramp[0])
    assert ce.shape == (100, 100) and (ce >= 0).all() and (ce <= 1).all()
    assert np.allclose(np.diag(sc.elevation_cost(ramp[0], ramp[0])), 0, atol=1e-3)
    # eq. 4.2: gamma weights shape against slope
    _, h = descriptors([POLY])
    both = sc.combined_cost(h[0], h[0], flat[0], ramp[0], gamma=0.5)
    assert np.allclose(both, 0.5 * sc.chi2_cost(h[0], h[0]) + 0.5 * ce, atol=1e-6)
    assert np.allclose(sc.combined_cost(h[0], h[0], flat[0], ramp[0], gamma=1.0),
                       sc.chi2_cost(h[0], h[0]))


# --------------------------------------------------------------------------- alignment

def test_procrustes_recovers_a_known_rotation_and_translation():
    rng = np.random.default_rng(2)
    src = rng.random((50, 2)) * 100
    r_true, t_true = rotation(2.2), np.array([350.0, -40.0])
    dst = sc.apply_rigid(src, r_true, t_true)
    r, t, rms = sc.rigid_align(src, dst)
    assert np.allclose(r, r_true) and np.allclose(t, t_true) and rms < 1e-9
    # with noise: still close, and never a reflection
    r2, t2, rms2 = sc.rigid_align(src, dst + rng.normal(0, 0.5, dst.shape))
    assert np.allclose(r2, r_true, atol=0.02) and 0.3 < rms2 < 1.0
    _, _, _ = sc.rigid_align(src, src * [1, -1])
    assert np.linalg.det(sc.rigid_align(src, src * [1, -1])[0]) == pytest.approx(1.0)


def test_alignment_from_dtw_correspondences_maps_the_shape_back():
    q = moved(POLY, -1.3, (500, 80))
    s = sc.sample_boundaries([POLY, q])
    s_rolled = np.roll(s[1], 23, axis=0)
    _, h = descriptors([POLY])
    edges = sc.radial_edges(sc.default_scale(s[:1]))
    hq = sc.normalised_histograms(sc.shape_contexts(s_rolled, edges))
    r = sc.cyclic_dtw(sc.chi2_cost(hq, h[0]))
    rot, t, rms = sc.rigid_align(s[0][r.path[:, 1]], s_rolled[r.path[:, 0]])
    assert np.allclose(rot, rotation(-1.3), atol=1e-6) and rms < 1e-6
    moved_back = sc.transform_geometries([POLY], rot, t)[0]
    assert moved_back.symmetric_difference(q).area < 1e-6
