"""Geometry built from transformed coordinates is closed and valid by construction.

Random valid polygons with holes, at projected-CRS magnitudes (1e5-1e6 m, where a matrix
product's rounding shows), go through every transform the engine builds geometry with:
rigid alignment, per-geometry rotation and translation, anisotropic scaling, and
mean-value-coordinate warps. ``make test`` runs this file under two BLAS kernels.
"""
import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from urban_synthesis.plugin.core import coordinates
from urban_synthesis.plugin.buildings import footprint_resynthesis
from urban_synthesis.plugin.retrieval import shape_context
from urban_synthesis.plugin.retrieval import warp


@st.composite
def polygons_with_holes(draw):
    """A star-shaped outer ring (always simple) with up to two star-shaped holes."""
    n = draw(st.integers(6, 40))
    cx = draw(st.floats(1e5, 1e6))
    cy = draw(st.floats(1e5, 7e6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    # angular gaps under 120 degrees: every edge stays >= 10 m from the centre
    angles = (np.arange(n) + rng.uniform(-0.45, 0.45, n)) * 2 * np.pi / n
    radius = rng.uniform(20.0, 60.0, n)
    outer = np.column_stack([cx + radius * np.cos(angles), cy + radius * np.sin(angles)])
    holes = []
    for k in range(draw(st.integers(0, 2))):
        m = 6
        a = np.linspace(0, 2 * np.pi, m, endpoint=False) + rng.uniform(0, 1)
        r = rng.uniform(1.0, 2.9, m)
        centre = np.array([cx + (-4.0 if k == 0 else 4.0), cy])
        holes.append(centre + np.column_stack([r * np.cos(a), r * np.sin(a)]))
    poly = shapely.Polygon(outer, holes)
    assert poly.is_valid
    return poly


def _assert_closed_valid(geoms, reference=None, area_rtol=None):
    for g in geoms:
        assert g.is_valid, shapely.is_valid_reason(g)
        for ring in [g.exterior, *g.interiors]:
            xy = np.asarray(ring.coords)
            assert (xy[0] == xy[-1]).all()
    if reference is not None:
        assert np.allclose(shapely.area(geoms), shapely.area(reference), rtol=area_rtol)


@settings(max_examples=60, deadline=None)
@given(st.lists(polygons_with_holes(), min_size=1, max_size=6),
       st.floats(-np.pi, np.pi), st.floats(-1e4, 1e4), st.floats(-1e4, 1e4))
def test_rigid_transforms_keep_rings_closed_and_areas(polys, angle, tx, ty):
    polys = np.array(polys, dtype=object)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    for out in (coordinates.rigid(polys, rot, (tx, ty)),
                shape_context.transform_geometries(polys, rot, np.array([tx, ty])),
                coordinates.rotate(polys, np.linspace(-angle, angle, len(polys)),
                                   shapely.get_coordinates(shapely.centroid(polys))),
                coordinates.translate(polys, np.column_stack([np.full(len(polys), tx),
                                                              np.full(len(polys), ty)]))):
        _assert_closed_valid(out, polys, area_rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.lists(polygons_with_holes(), min_size=1, max_size=4), st.floats(0.5, 2.0),
       st.floats(0, np.pi))
def test_scaling_along_a_direction(polys, factor, direction):
    polys = np.array(polys, dtype=object)
    u = np.array([np.cos(direction), np.sin(direction)])
    out = footprint_resynthesis._scale_along(polys, u, factor)
    _assert_closed_valid(out)
    assert np.allclose(shapely.area(out), factor * shapely.area(polys), rtol=1e-7)


@settings(max_examples=40, deadline=None)
@given(polygons_with_holes(), st.floats(0.7, 1.4), st.floats(0.7, 1.4), st.floats(-0.3, 0.3),
       st.lists(st.floats(-6.0, 6.0), min_size=16, max_size=16))
def test_mean_value_warps(poly, sx, sy, shear, jitter):
    """An affine map of the cage is reproduced exactly; a mildly bent cage stays a valid,
    closed polygon."""
    x0, y0, x1, y1 = poly.bounds
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    t = np.linspace(0, 1, 4, endpoint=False)
    side = max(x1 - x0, y1 - y0) + 40.0
    square = np.concatenate([
        np.column_stack([t, np.zeros(4)]), np.column_stack([np.ones(4), t]),
        np.column_stack([1 - t, np.ones(4)]), np.column_stack([np.zeros(4), 1 - t])])
    cage = (square - 0.5) * side + [cx, cy]
    affine = np.array([[sx, shear], [0.0, sy]])
    target = (cage - [cx, cy]) @ affine.T + [cx, cy]
    out = warp.warp_geometries([poly], cage, target)
    expected = coordinates.transform([poly], lambda xy, _: (xy - [cx, cy]) @ affine.T + [cx, cy])
    _assert_closed_valid(out)
    assert np.allclose(shapely.get_coordinates(out), shapely.get_coordinates(expected), atol=1e-6)
    bent = target + np.asarray(jitter).reshape(8, 2).repeat(2, axis=0)
    _assert_closed_valid(warp.warp_geometries([poly], cage, bent, max_segment=5.0))
