"""Mean value coordinates, warping and Poisson merging (plugin/retrieval/warp.py)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.retrieval import warp
from urban_synthesis.plugin.core.progress import InputError

SQUARE = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
# an L shape: concave at (4, 4)
ELL = np.array([[0, 0], [10, 0], [10, 4], [4, 4], [4, 10], [0, 10]], dtype=float)


def inside_points(poly, n=400, seed=0):
    rng = np.random.default_rng(seed)
    shape = shapely.Polygon(poly)
    b = shape.bounds
    pts = rng.uniform(b[:2], b[2:], size=(n * 3, 2))
    return pts[shapely.contains_xy(shape, pts[:, 0], pts[:, 1])][:n]


@pytest.mark.parametrize("poly", [SQUARE, ELL])
def test_partition_of_unity_and_linear_precision(poly):
    pts = inside_points(poly)
    lam = warp.mean_value_coordinates(pts, poly)
    assert lam.shape == (len(pts), len(poly))
    assert np.allclose(lam.sum(1), 1.0)
    assert np.allclose(lam @ poly, pts, atol=1e-9)
    if poly is SQUARE:  # positive inside a convex polygon
        assert (lam > 0).all()


def test_known_values_vertices_and_edges():
    lam = warp.mean_value_coordinates(np.array([[5.0, 5.0]]), SQUARE)
    assert np.allclose(lam, 0.25)
    # on a vertex: that vertex only; on an edge: linear along it
    lam = warp.mean_value_coordinates(np.array([[10.0, 0.0], [2.5, 0.0], [10, 7.5]]), SQUARE)
    assert np.allclose(lam[0], [0, 1, 0, 0])
    assert np.allclose(lam[1], [0.75, 0.25, 0, 0])
    assert np.allclose(lam[2], [0, 0.25, 0.75, 0])
    # a closing vertex repeated, or repeated consecutive vertices (DTW paths), change nothing
    pts = inside_points(SQUARE, 50)
    a = warp.mean_value_coordinates(pts, SQUARE)
    closed = np.vstack([SQUARE, SQUARE[:1]])
    b = warp.mean_value_coordinates(pts, closed)
    assert np.allclose(b[:, 1:4], a[:, 1:4]) and np.allclose(b[:, 0] + b[:, 4], a[:, 0])
    dup = np.vstack([SQUARE[:2], SQUARE[1:2], SQUARE[2:]])
    c = warp.mean_value_coordinates(pts, dup)
    assert np.allclose(c @ dup, pts)


def test_affine_maps_are_reproduced_and_boundary_goes_to_boundary():
    pts = inside_points(ELL, 200)
    m = np.array([[1.5, 0.3], [-0.2, 0.8]])
    t = np.array([100.0, -50.0])
    target = ELL @ m.T + t
    assert np.allclose(warp.warp_points(pts, ELL, target), pts @ m.T + t, atol=1e-8)
    # boundary samples land on the target boundary
    ring = shapely.LinearRing(ELL)
    on = shapely.get_coordinates(shapely.line_interpolate_point(ring, np.linspace(0, 1, 37)))
    square = np.array([[0, 0], [10, 0], [10, 5], [10, 10], [5, 10], [0, 10]], float)
    moved = warp.warp_points(on, ELL, square)
    assert np.allclose(shapely.distance(shapely.LinearRing(square), shapely.points(moved)), 0,
                       atol=1e-9)


def test_warp_is_smooth_and_keeps_points_inside_for_a_mild_deformation():
    rng = np.random.default_rng(3)
    target = SQUARE + rng.normal(0, 0.8, SQUARE.shape)
    pts = inside_points(SQUARE, 300)
    moved = warp.warp_points(pts, SQUARE, target)
    assert shapely.contains_xy(shapely.Polygon(target), moved[:, 0], moved[:, 1]).all()
    # warping lines densifies them first: a long straight street bends with the warp
    line = shapely.LineString([(1, 5), (9, 5)])
    out = warp.warp_geometries([line], SQUARE, target, max_segment=1.0)[0]
    assert shapely.get_num_coordinates(out) >= 9 and out.is_valid


def test_bad_polygons_are_input_errors():
    with pytest.raises(InputError):
        warp.mean_value_coordinates(np.zeros((1, 2)), np.zeros((2, 2)))
    with pytest.raises(InputError):
        warp.warp_points(np.zeros((1, 2)), SQUARE, ELL)


def test_many_points_reproduce_linear_precision():
    """10,000 points x 200 vertices in one vectorised call (speed: bench_foundation)."""
    poly = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 200, endpoint=False)),
                            np.sin(np.linspace(0, 2 * np.pi, 200, endpoint=False))]) * 100
    pts = np.random.default_rng(1).uniform(-60, 60, (10_000, 2))
    lam = warp.mean_value_coordinates(pts, poly)
    assert np.allclose(lam @ poly, pts)


# --------------------------------------------------------------------------- Poisson

def test_poisson_blend_keeps_gradients_and_matches_the_border():
    rows, cols = 40, 50
    yy, xx = np.mgrid[0:rows, 0:cols].astype(float)
    base = 100 + 0.0 * xx
    # a hill on a plateau at a very different height
    patch = 500 + 20.0 * np.exp(-((xx - 25) ** 2 + (yy - 19) ** 2) / (2 * 4.0 ** 2))
    mask = (xx > 10) & (xx < 40) & (yy > 8) & (yy < 30)
    out = warp.poisson_blend(base, patch, mask)
    assert np.array_equal(out[~mask], base[~mask])
    # continuous at the border (no 400 m step), and the hill survives in the middle:
    # f - g is harmonic, so the hill's relief above its surroundings is kept
    border = mask & ~(np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1)
                      & np.roll(mask, -1, 1))
    assert np.abs(out[border] - 100).max() < 1.0
    assert 115 < out[19, 25] < 121
    assert out[19, 25] == out[mask].max()
    # zero guidance gradients give the harmonic (here constant) interpolation of the border
    flat = warp.poisson_blend(base, np.zeros_like(base), mask)
    assert np.allclose(flat, 100)


def test_poisson_blend_regions_are_independent_and_nan_safe():
    base = np.full((20, 30), 10.0)
    g = np.full((20, 30), np.nan)
    labels = np.zeros((20, 30), int)
    mask = np.zeros((20, 30), bool)
    mask[5:15, 3:14] = True
    mask[5:15, 14:27] = True
    labels[:, 14:] = 1
    g[5:15, 3:14] = 0.0
    g[5:15, 14:27] = 1000.0  # another example patch at another absolute height
    out = warp.poisson_blend(base, g, mask, labels)
    assert np.isfinite(out).all()
    assert np.allclose(out, 10.0)  # constant patches: no gradient, no jump between them
    # a mask covering the whole grid (no boundary) is still solvable
    whole = warp.poisson_blend(base, np.arange(600.0).reshape(20, 30), np.ones((20, 30), bool))
    assert np.isfinite(whole).all() and abs(whole.mean() - 10) < 1e-3


def test_points_a_fraction_of_a_millimetre_from_an_edge_are_reproduced():
    """Street ends on a fragment boundary lie just off the chords of its samples."""
    poly = np.array([[0, 0], [400, 3], [410, 300], [5, 290]], dtype=float)
    e = poly[1] - poly[0]
    normal = np.array([-e[1], e[0]]) / np.hypot(*e)
    pts = np.array([poly[0] + 0.3 * e + s * 2e-4 * normal for s in (-1, 1)])
    lam = warp.mean_value_coordinates(pts, poly)
    assert np.allclose(lam @ poly, pts, atol=1e-6)


def test_the_blas_free_product_sums_in_the_same_order_as_the_elementwise_one():
    # the reference it replaced: (n, k, 2) products summed over k; equal to the last bit,
    # so that no warped vertex (and no decision after it) moved
    rng = np.random.default_rng(1)
    a = rng.random((3000, 257))
    a /= a.sum(axis=1, keepdims=True)
    b = rng.normal(0, 500, (257, 2))
    reference = (a[:, :, None] * b[None, :, :]).sum(axis=1)
    assert np.array_equal(warp.blas_free_product(a, b), reference)
    assert np.array_equal(warp.blas_free_product(a, b, chunk=100), reference)
