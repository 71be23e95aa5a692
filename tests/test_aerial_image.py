"""Aerial-image synthesis per parcel (Aliaga et al. 2008, sec. 3.2), engine tests.

Exact warps on synthetic rasters whose expected pixel values are known (linear gradients:
the bilinear remap reproduces them up to cv2's 1/32-pixel map precision), the street side,
matching, roads, reproducibility, and a real satellite image (SpaceNet 4, Atlanta).
"""
import numpy as np
import pytest
import shapely

from conftest import DATA
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.imagery import aerial_image as ai

PX = 0.5
#: cv2.remap quantises map coordinates to 1/32 pixel: the largest error of a gradient of
#: 1 unit per metre sampled at 0.5 m pixels (plus float32 map rounding at 1e3 m offsets)
GRADIENT_TOL = PX / 32 * 1.5 + 1e-3


def _gradient_image(x0=1000.0, y0=2000.0, size=400):
    """A 3-band float image whose bands are x, y and x + 2y at each pixel centre."""
    cols = np.arange(size)
    x = x0 + (cols + 0.5) * PX
    y = y0 - (cols + 0.5) * PX
    xx, yy = np.meshgrid(x, y)
    return ai.GeoImage(np.dstack([xx, yy, xx + 2 * yy]), (x0, PX, 0.0, y0, 0.0, -PX))


def _affine(poly, angle_deg, scale_a, scale_b, centre, to):
    """poly scaled by (scale_a, scale_b) along x / y about ``centre``, rotated, moved to
    ``to``; returns the new polygon and the inverse map (new world xy -> example xy)."""
    c = np.asarray(centre, float)
    t = np.radians(angle_deg)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    scale = np.diag([scale_a, scale_b])
    m = rot @ scale
    xy = np.asarray(poly.exterior.coords)[:-1]
    new = (xy - c) @ m.T + np.asarray(to, float)
    inv = np.linalg.inv(m)
    return shapely.Polygon(new), lambda p: (p - np.asarray(to, float)) @ inv.T + c


def _pixels_inside(result, poly, margin=1.0):
    """Centres of output pixels at least ``margin`` m inside ``poly``: (rows, cols, xy)."""
    img = result.image
    x0, dx, _, y0, _, dy = img.geotransform
    rows, cols = img.shape
    cc, rr = np.meshgrid(np.arange(cols), np.arange(rows))
    xy = np.column_stack([x0 + (cc.ravel() + 0.5) * dx, y0 + (rr.ravel() + 0.5) * dy])
    inside = shapely.contains_xy(shapely.buffer(poly, -margin), xy[:, 0], xy[:, 1])
    return rr.ravel()[inside], cc.ravel()[inside], xy[inside]


def test_exact_warp_onto_a_rotated_scaled_moved_parcel():
    """A 40 x 20 m example parcel (street along its south side) onto a parcel 1.5 x as long,
    0.75 x as wide, turned 30 degrees and 5 km away (street along its turned south side):
    every pixel takes the value of the example point the affine map sends it to."""
    example = _gradient_image()
    ex_parcel = shapely.box(1020, 1890, 1060, 1910)
    centre = (1040, 1900)
    new, inverse = _affine(ex_parcel, 30, 1.5, 0.75, centre, (6000, 7000))
    street, _ = _affine(shapely.box(1000, 1884, 1100, 1886), 30, 1.5, 0.75, centre, (6000, 7000))
    res = ai.synthesize_image(example, [ex_parcel], [new], roads=[street.exterior],
                              example_roads=None, settings=ai.ImageSettings(pixel_size=PX))
    assert res.stats["n_matched"] == 1 and res.table.example_parcel.tolist() == [0]
    assert res.table.stretch.iloc[0] == pytest.approx(1.5)
    rr, cc, xy = _pixels_inside(res, new)
    assert len(rr) > 0.9 * new.area / PX ** 2 - 400
    expected = inverse(xy)
    got = res.image.array[rr, cc]
    np.testing.assert_allclose(got[:, 0], expected[:, 0], atol=GRADIENT_TOL)
    np.testing.assert_allclose(got[:, 1], expected[:, 1], atol=GRADIENT_TOL)
    np.testing.assert_allclose(got[:, 2], expected[:, 0] + 2 * expected[:, 1],
                               atol=3 * GRADIENT_TOL)
    assert (res.alpha[rr, cc] == 255).all()
    # off the parcel the image is transparent
    outside = ~shapely.contains_xy(shapely.buffer(new, 1.0), *_all_centres(res).T)
    assert (res.alpha.ravel()[outside] == 0).all()


def _all_centres(res):
    x0, dx, _, y0, _, dy = res.image.geotransform
    rows, cols = res.image.shape
    cc, rr = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([x0 + (cc.ravel() + 0.5) * dx, y0 + (rr.ravel() + 0.5) * dy])


def test_street_side_goes_to_the_street_side():
    """The same example onto an unturned copy whose street is on the north: the example
    is turned half a turn (not mirrored), so its south (street) edge lands on the north."""
    example = _gradient_image()
    ex_parcel = shapely.box(1020, 1890, 1060, 1910)
    new = shapely.box(5020, 7890, 5060, 7910)
    res = ai.synthesize_image(
        example, [ex_parcel], [new], roads=[shapely.LineString([(5000, 7915), (5100, 7915)])],
        example_roads=[shapely.LineString([(1000, 1885), (1100, 1885)])])
    rr, cc, xy = _pixels_inside(res, new)
    got = res.image.array[rr, cc]
    # half a turn about the centres: example = centre_e - (p - centre_n)
    expected = np.array([1040, 1900]) - (xy - np.array([5040, 7900]))
    np.testing.assert_allclose(got[:, :2], expected, atol=GRADIENT_TOL)


def test_concave_parcel_follows_the_scanline_grid():
    """An L-shaped parcel onto a copy moved 3 km: the warp is the identity up to the move
    (the same scanlines, the same p_a / p_b); the explicit s x n grid of the paper lies in
    the parcel and has s scanlines of n points."""
    example = _gradient_image()
    ell = shapely.Polygon([(1010, 1850), (1070, 1850), (1070, 1870), (1030, 1870),
                           (1030, 1900), (1010, 1900)])
    moved = shapely.affinity.translate(ell, 3000, 3000)
    res = ai.synthesize_image(example, [ell], [moved])
    rr, cc, xy = _pixels_inside(res, moved)
    np.testing.assert_allclose(res.image.array[rr, cc, :2], xy - 3000, atol=GRADIENT_TOL)
    frames = ai.parcel_frames([ell])
    grid = ai.scanline_grid([ell], frames, 12, 5)
    assert grid.shape == (1, 12, 5, 2)
    pts = shapely.points(grid.reshape(-1, 2))
    assert shapely.covers(shapely.buffer(ell, 1e-6), pts).all()
    # p_a and p_b of every scanline are on the outline
    ends = shapely.points(grid[0, :, [0, -1]].reshape(-1, 2))
    assert (shapely.distance(ell.exterior, ends) < 1e-6).all()


def test_matching_by_obb_size_aspect_and_street_side():
    """Sec. 3.2: the example parcel whose OBB is most similar in area and aspect ratio,
    with the same side on the street; none within the stretch limit: no match."""
    street = shapely.LineString([(-100, -1), (1000, -1)])
    examples = [shapely.box(0, 0, 20, 40),    # short side on the street, 20 x 40
                shapely.box(100, 0, 140, 20),  # long side on the street, 40 x 20
                shapely.box(200, 0, 230, 60)]  # long side 60, short 30 on the street
    ex_frames = ai.parcel_frames(examples, [street])
    assert ex_frames.front_on_long_side.tolist() == [False, True, False]
    new = [shapely.box(500, 0, 542, 21),      # long side on the street: 1 (not 0)
           shapely.box(600, 0, 621, 42),      # short side: 0
           shapely.box(700, 0, 732, 61),      # short side: 2
           shapely.box(800, 0, 1000, 200)]    # far too large: none
    frames = ai.parcel_frames(new, [street])
    index, stretch = ai.match_parcels(frames, ex_frames, ai.ImageSettings(candidates=1),
                                      np.random.default_rng(0))
    assert index.tolist() == [1, 0, 2, -1]
    assert stretch[:3] == pytest.approx([1.05, 1.05, 32 / 30])
    assert stretch[3] > 2


def test_unmatched_parcels_stay_transparent_and_are_counted():
    example = _gradient_image()
    res = ai.synthesize_image(example, [shapely.box(1020, 1890, 1060, 1910)],
                              [shapely.box(0, 0, 40, 20), shapely.box(100, 0, 400, 150)])
    assert res.stats["n_matched"] == 1 and res.stats["n_unmatched"] == 1
    assert res.table.example_parcel.tolist() == [0, -1]
    rr, cc, _ = _pixels_inside(res, shapely.box(100, 0, 400, 150))
    assert (res.alpha[rr, cc] == 0).all()
    rr, cc, _ = _pixels_inside(res, shapely.box(0, 0, 40, 20))
    assert (res.alpha[rr, cc] == 255).all()


def test_roads_painted_from_the_example_road_across_and_along():
    """Example road along y = 1950, 10 m wide; the image's band 1 is y, so a road pixel
    at offset d across a new road (diagonal, 5 m wide) must read 1950 + 2 d (the widths'
    ratio), and band 0 (x) must advance with the distance along the new road."""
    example = _gradient_image()
    ex_road = shapely.LineString([(1005, 1950), (1195, 1950)])
    road = shapely.LineString([(0, 0), (60, 60)])
    res = ai.synthesize_image(
        example, [shapely.box(1020, 1890, 1060, 1910)], [shapely.box(200, 200, 240, 220)],
        roads=[road], example_roads=[ex_road],
        settings=ai.ImageSettings(road_width=5.0, example_road_width=10.0))
    assert res.stats["roads_painted"] and res.stats["n_road_pixels"] > 0
    xy = _all_centres(res)
    u = np.array([1, 1]) / np.sqrt(2)
    n = np.array([-u[1], u[0]])
    t, d = xy @ u, xy @ n
    on = (np.abs(d) < 2.0) & (t > 3) & (t < 60 * np.sqrt(2) - 3)
    band = res.image.array.reshape(-1, 3)
    assert (res.alpha.ravel()[on] == 255).all()
    np.testing.assert_allclose(band[on, 1], 1950 + 2 * d[on], atol=2 * GRADIENT_TOL)
    # the example road is 190 m long, longer than the new one: along = x - 1005 (+ inset)
    np.testing.assert_allclose(band[on, 0] - t[on], band[on, 0][0] - t[on][0], atol=0.05)


def test_same_seed_same_image_and_seeds_vary_the_choice():
    example = _gradient_image()
    ex = [shapely.box(1010 + 45 * i, 1850 + (i % 2), 1050 + 45 * i, 1870 + (i % 2))
          for i in range(6)]
    new = [shapely.box(50 * i, 0, 50 * i + 40, 20) for i in range(10)]
    settings = ai.ImageSettings(candidates=6, near_best=0.01)
    a = ai.synthesize_image(example, ex, new, settings=settings, seed=3)
    b = ai.synthesize_image(example, ex, new, settings=settings, seed=3)
    c = ai.synthesize_image(example, ex, new, settings=settings, seed=4)
    np.testing.assert_array_equal(a.image.array, b.image.array)
    assert a.table.example_parcel.tolist() == b.table.example_parcel.tolist()
    assert a.table.example_parcel.tolist() != c.table.example_parcel.tolist()
    assert len(set(a.table.example_parcel)) >= 3  # identical parcels, varied images


def test_bad_input_and_cancellation():
    example = _gradient_image()
    ex = [shapely.box(1020, 1890, 1060, 1910)]
    with pytest.raises(InputError, match="no example parcel lies on the example image"):
        ai.synthesize_image(example, [shapely.box(0, 0, 10, 10)], ex)
    with pytest.raises(InputError, match="new parcels must be polygons"):
        ai.synthesize_image(example, ex, [shapely.LineString([(0, 0), (1, 1)])])
    with pytest.raises(InputError, match="no new parcels"):
        ai.synthesize_image(example, ex, [])
    with pytest.raises(InputError, match="pixel size must be positive"):
        ai.synthesize_image(example, ex, ex, settings=ai.ImageSettings(pixel_size=0))
    with pytest.raises(InputError, match="larger pixel size"):
        ai.synthesize_image(example, ex, [shapely.box(0, 0, 1e5, 1e5)],
                            settings=ai.ImageSettings(pixel_size=0.5))
    with pytest.raises(InputError, match="north up"):
        ai.GeoImage(np.zeros((2, 2)), (0, 1, 0.1, 0, 0, -1))
    calls = []
    with pytest.raises(Canceled):
        ai.synthesize_image(example, ex, [shapely.box(0, 0, 40, 20)],
                            progress=Progress(report=calls.append,
                                              is_canceled=lambda: len(calls) > 3))
    assert len(calls) == 4  # stopped at the next step after the request


# --------------------------------------------------------------------------- real image

ATLANTA_IMAGE = DATA / "atlanta_pan_0.5m.tif"
ATLANTA_BUILDINGS = DATA / "atlanta_buildings.geojson"
#: The road crossing the image's north-west quarter, digitised by eye from the image
#: (pixel column, row): the only example road used.
ATLANTA_ROAD_PX = [(0, 118), (25, 132), (115, 185), (150, 197), (225, 260), (280, 310),
                   (415, 420), (460, 450)]
ATLANTA_ROAD_WIDTH = 7.0


def atlanta_example():
    """(GeoImage, parcels, road) of the SpaceNet 4 tile: the parcels are the Voronoi cells
    of the OpenStreetMap buildings on it (a morphological tessellation), clipped to the
    image and cut by the digitised road."""
    from osgeo import gdal

    import pyogrio

    if not ATLANTA_IMAGE.exists():
        pytest.skip("run scripts/fetch_example_data.py (the SpaceNet tile of solaris)")
    ds = gdal.Open(str(ATLANTA_IMAGE))
    image = ai.GeoImage(ds.ReadAsArray(), ds.GetGeoTransform())
    x0, dx, _, y0, _, dy = image.geotransform
    road = shapely.LineString([(x0 + (c + 0.5) * dx, y0 + (r + 0.5) * dy)
                               for c, r in ATLANTA_ROAD_PX])
    buildings = pyogrio.read_dataframe(ATLANTA_BUILDINGS).geometry.values
    box = shapely.box(*image.bounds).buffer(-1.0)
    cells = shapely.get_parts(shapely.voronoi_polygons(
        shapely.multipoints(shapely.centroid(buildings)), extend_to=box))
    cells = shapely.difference(shapely.intersection(cells, box),
                               shapely.buffer(road, ATLANTA_ROAD_WIDTH / 2 + 1.0))
    parts = shapely.get_parts(cells)
    parts = parts[(shapely.get_type_id(parts) == 3) & (shapely.area(parts) > 100)]
    return image, parts, road


def _label(image, polygons):
    """Pixels whose centre is in polygon i (and 1 m from its outline): i + 1, else 0."""
    from osgeo import gdal, ogr

    rows, cols = image.shape
    mem = gdal.GetDriverByName("MEM").Create("", cols, rows, 1, gdal.GDT_Int32)
    mem.SetGeoTransform(image.geotransform)
    vec = ogr.GetDriverByName("Memory").CreateDataSource("")
    layer = vec.CreateLayer("p")
    layer.CreateField(ogr.FieldDefn("id", ogr.OFTInteger))
    for i, poly in enumerate(shapely.buffer(np.asarray(polygons, dtype=object), -1.0)):
        feature = ogr.Feature(layer.GetLayerDefn())
        feature.SetField("id", i + 1)
        feature.SetGeometry(ogr.CreateGeometryFromWkb(shapely.to_wkb(poly)))
        layer.CreateFeature(feature)
    gdal.RasterizeLayer(mem, [1], layer, options=["ATTRIBUTE=id"])
    return mem.ReadAsArray()


def test_real_satellite_image_of_atlanta():
    """New parcels (a 3 x 3 grid of blocks cut into lots about as large as the example's
    cells) filled from a real 0.5 m WorldView-2 tile: most parcels matched; each matched
    parcel is opaque, and its mean brightness follows the example cell it came from (the
    warp moves pixels, it does not invent them)."""
    from urban_synthesis.plugin.parcels import subdivision as parcels

    image, ex_parcels, road = atlanta_example()
    assert len(ex_parcels) > 30
    mean_area = float(np.median(shapely.area(ex_parcels)))
    blocks = [shapely.box(150 * i, 110 * j, 150 * i + 130, 110 * j + 90)
              for i in range(3) for j in range(3)]
    lots = parcels.subdivide_blocks(
        blocks, "voronoi-obb", parcels.SubdivisionSettings(
            options={"mean_area": mean_area, "area_sd": 0.3 * mean_area}), seed=2,
        street_width=0).geometry
    res = ai.synthesize_image(image, ex_parcels, lots, roads=None, example_roads=[road],
                              settings=ai.ImageSettings(road_width=ATLANTA_ROAD_WIDTH), seed=1)
    assert res.image.array.dtype == np.uint16 and res.image.array.shape[2] == 1
    matched = res.table.example_parcel.to_numpy() >= 0
    assert matched.mean() > 0.7
    new_label = _label(res.image, lots)
    ex_label = _label(image, ex_parcels)
    new_mean, ex_mean = [], []
    for i in np.flatnonzero(matched):
        inside = new_label == i + 1
        assert (res.alpha[inside] == 255).all()
        new_mean.append(res.image.array[inside, 0].mean())
        ex_mean.append(image.array[ex_label == res.table.example_parcel.iloc[i] + 1, 0].mean())
    assert np.corrcoef(new_mean, ex_mean)[0, 1] > 0.9
    np.testing.assert_allclose(new_mean, ex_mean, rtol=0.15)


def test_roads_far_beyond_the_parcels_do_not_refuse_the_image():
    """A region's roads (Liechtenstein's whole hierarchy, 22 km) with a town's parcels: the
    image of every road would have 44,494 x 21,174 pixels and the run was refused ('use a
    larger pixel size'). The image covers the parcels and the roads near them; the roads
    far off are counted; a road along the parcels is still painted."""
    example = _gradient_image()
    ex_road = shapely.LineString([(1005, 1950), (1195, 1950)])
    near = shapely.LineString([(190, 195), (250, 195)])
    far = shapely.LineString([(20000, 30000), (80000, 30000)])
    res = ai.synthesize_image(
        example, [shapely.box(1020, 1890, 1060, 1910)], [shapely.box(200, 200, 240, 220)],
        roads=[near, far], example_roads=[ex_road],
        settings=ai.ImageSettings(road_width=5.0, example_road_width=10.0))
    assert res.stats["n_roads_beyond"] == 1
    assert res.stats["roads_painted"] and res.stats["n_road_pixels"] > 0
    assert res.stats["cols"] * PX < 100 and res.stats["rows"] * PX < 100
    # a layout that fits keeps every road, as before
    whole = ai.synthesize_image(
        example, [shapely.box(1020, 1890, 1060, 1910)], [shapely.box(200, 200, 240, 220)],
        roads=[near, shapely.LineString([(0, 0), (60, 60)])], example_roads=[ex_road],
        settings=ai.ImageSettings(road_width=5.0, example_road_width=10.0))
    assert whole.stats["n_roads_beyond"] == 0 and whole.stats["cols"] * PX > 240
