"""urbansynth:growroads through real QGIS (processing.run and qgis_process.bin)."""
import json

import numpy as np
import pytest
import shapely

from conftest import run_qgis_process
from helpers import assert_planar, layer_features, log_feedback, memory_layer

# a Helsinki-sized 1 km x 1 km square in ETRS-TM35FIN (EPSG:3067), central Helsinki
X0, Y0 = 385000.0, 6671000.0
CRS = "EPSG:3067"
SQUARE = f"POLYGON(({X0} {Y0}, {X0 + 1000} {Y0}, {X0 + 1000} {Y0 + 1000}, {X0} {Y0 + 1000}, " \
         f"{X0} {Y0}))"


def _write_geotiff(path, array, x0, y0, cell, epsg=3067):
    from osgeo import gdal, osr

    rows, cols = array.shape
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0, cell, 0.0, y0, 0.0, -cell))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(epsg)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(array)
    ds.FlushCache()
    ds = None
    return str(path)


@pytest.mark.parametrize("pattern", [0, 1, 2])
def test_patterns_on_a_helsinki_square(qgis_processing, pattern):
    out = qgis_processing.run("urbansynth:growroads", {
        "BOUNDARY": memory_layer("Polygon", [SQUARE], CRS), "MAJOR_PATTERN": pattern, "MINOR_PATTERN": pattern,
        "SEED": 3, "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.crs().authid() == "EPSG:3067"
    rows, geoms = layer_features(layer)
    assert len(rows) > 150
    assert [f.name() for f in layer.fields()] == ["edge_id", "level", "road_class", "pattern",
                                                  "width_m", "length_m"]
    assert {r["level"] for r in rows} == {0, 1}
    assert all(r["road_class"] == ("major" if r["level"] == 0 else "minor") for r in rows)
    assert {r["pattern"] for r in rows} == {["organic", "grid", "radial"][pattern]}
    np.testing.assert_allclose([r["length_m"] for r in rows], shapely.length(geoms), rtol=1e-9)
    square = shapely.from_wkt(SQUARE)
    assert shapely.covers(square.buffer(1e-6), geoms).all()
    assert_planar(geoms)


def test_geographic_boundary_terrain_obstacles_density_sketch(qgis_processing, tmp_path):
    """Every optional input at once; a WGS 84 boundary comes back in WGS 84."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsProject

    to_wgs = QgsCoordinateTransform(QgsCoordinateReferenceSystem(CRS),
                                    QgsCoordinateReferenceSystem("EPSG:4326"),
                                    QgsProject.instance())
    from qgis.core import QgsGeometry

    g = QgsGeometry.fromWkt(SQUARE)
    g.transform(to_wgs)
    boundary = memory_layer("Polygon", [g.asWkt(12)], "EPSG:4326")
    # a 25 m high hill (the DEM is in EPSG:3067, the boundary in WGS 84)
    cell = 10.0
    xs = X0 - 100 + cell * (np.arange(120) + 0.5)
    ys = Y0 + 1100 - cell * (np.arange(120) + 0.5)
    x, y = np.meshgrid(xs, ys)
    hill = 60.0 * np.exp(-((x - X0 - 300) ** 2 + (y - Y0 - 650) ** 2) / (2 * 180.0 ** 2))
    dem = _write_geotiff(tmp_path / "dem.tif", hill, X0 - 100, Y0 + 1100, cell)
    density = _write_geotiff(tmp_path / "density.tif", 1.0 + (x - X0) / 1000.0,
                             X0 - 100, Y0 + 1100, cell)
    lake = shapely.Point(X0 + 700, Y0 + 350).buffer(150)
    sketch = f"LINESTRING({X0 - 50} {Y0 + 500}, {X0 + 1050} {Y0 + 520})"
    out = qgis_processing.run("urbansynth:growroads", {
        "BOUNDARY": boundary, "MAJOR_ROADS": memory_layer("LineString", [sketch], CRS),
        "OBSTACLES": memory_layer("Polygon", [lake.wkt], CRS), "DEM": dem, "MAX_SLOPE": 8.0, "DENSITY": density,
        "MAJOR_PATTERN": 0, "MINOR_PATTERN": 2, "CENTER": f"{X0 + 500},{Y0 + 500} [EPSG:3067]",
        "SEED": 2, "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.crs().authid() == "EPSG:4326"
    rows, geoms = layer_features(layer)
    assert len(rows) > 100
    assert {r["pattern"] for r in rows} == {"sketch", "organic", "radial"}
    # lengths are metres, not degrees
    assert 20 < np.median([r["length_m"] for r in rows]) < 250
    # check the constraints in the metric CRS
    from urban_synthesis.plugin.roads.growth import segment_slopes
    from urban_synthesis.plugin.retrieval.shape_context import DemGrid

    back = QgsCoordinateTransform(QgsCoordinateReferenceSystem("EPSG:4326"),
                                  QgsCoordinateReferenceSystem(CRS),
                                  QgsProject.instance())
    metric = []
    for f in layer.getFeatures():
        fg = f.geometry()
        fg.transform(back)
        metric.append(shapely.from_wkb(bytes(fg.asWkb())))
    metric = np.array(metric, dtype=object)
    grown = np.array([r["pattern"] != "sketch" for r in rows])
    with np.errstate(invalid="ignore"):  # GEOS's empty results carry a NaN z
        inside = shapely.length(shapely.intersection(metric[grown], lake.buffer(-0.01)))
    assert inside.max() < 1e-6
    grid = DemGrid(hill, (X0 - 100, cell, 0.0, Y0 + 1100, 0.0, -cell))
    # the algorithm resamples the DEM with GDAL: allow for its interpolation
    assert segment_slopes(metric[grown], grid).max() <= 0.08 * 1.05


@pytest.mark.parametrize("params, match", [
    ({"BOUNDARY": "empty"}, r"Layer 'test input' is empty"),
    ({"BOUNDARY": "empty", "MAJOR_ROADS": "empty_lines"}, r"Layer 'test input' is empty"),
    ({"BOUNDARY": "points"}, "BOUNDARY|polygons"),
    ({"MINOR_SEGMENT_LENGTH": 100000.0}, "MINOR_SEGMENT_LENGTH"),
    ({"MAX_SLOPE": 0.0}, "MAX_SLOPE"),
    ({"SNAP_DISTANCE": 45.0}, "SNAP_DISTANCE"),
    ({"BOUNDARY": "tiny"}, "too small"),
    ({"OBSTACLES": "cover"}, "obstacles cover the whole boundary"),
])
def test_bad_input(qgis_processing, params, match):
    from qgis.core import QgsProcessingException

    layers = {
        "empty": lambda: memory_layer("Polygon", [], CRS),
        "empty_lines": lambda: memory_layer("LineString", [], CRS),
        "points": lambda: memory_layer("Point", [f"POINT({X0} {Y0})"], CRS),
        "tiny": lambda: memory_layer("Polygon", [f"POLYGON(({X0} {Y0}, {X0 + 5} {Y0}, "
                                                 f"{X0 + 5} {Y0 + 5}, {X0} {Y0}))"], CRS),
        "cover": lambda: memory_layer("Polygon", [shapely.from_wkt(SQUARE).buffer(5).wkt],
                                      CRS),
    }
    p = {"BOUNDARY": memory_layer("Polygon", [SQUARE], CRS), "OUTPUT": "memory:"}
    for k, v in params.items():
        p[k] = layers[v]() if isinstance(v, str) else v
    feedback = log_feedback()
    with pytest.raises(QgsProcessingException, match=match):
        qgis_processing.run("urbansynth:growroads", p, feedback=feedback)
    # no 'the run goes on without Boundary' before the boundary alone is refused
    assert not any("goes on without" in w for w in feedback.warnings) or \
        "MAJOR_ROADS" in params, feedback.warnings


def test_qgis_process_run(tmp_path):
    boundary = tmp_path / "boundary.geojson"
    boundary.write_text(json.dumps({
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::3067"}},
        "features": [{"type": "Feature", "properties": {},
                      "geometry": shapely.geometry.mapping(shapely.from_wkt(SQUARE))}]}))
    out = tmp_path / "roads.gpkg"
    code, result, err = run_qgis_process("growroads", {
        "BOUNDARY": str(boundary), "MAJOR_PATTERN": 2, "MINOR_PATTERN": 1, "SEED": 4,
        "OUTPUT": str(out)})
    assert code == 0, err
    assert result is not None and result["results"]["OUTPUT"].startswith(str(out))
    import pyogrio

    info = pyogrio.read_info(out)
    assert info["features"] > 150
    assert {"level", "road_class", "pattern", "length_m"} <= set(info["fields"])


def test_obstacle_raster_keeps_roads_out_of_masked_cells(qgis_processing, tmp_path):
    """Cells above 0 in an obstacle raster are obstacles, like obstacle polygons."""
    square = shapely.from_wkt(SQUARE)
    x0, y0, x1, y1 = square.bounds
    cell = 20.0
    cols, rows = int((x1 - x0) / cell), int((y1 - y0) / cell)
    mask = np.zeros((rows, cols), dtype=np.float32)
    mask[rows // 4: rows // 2, cols // 4: 3 * cols // 4] = 1.0  # a lake across the middle
    tif = _write_geotiff(tmp_path / "water.tif", mask, x0, y1, cell)
    out = qgis_processing.run("urbansynth:growroads", {
        "BOUNDARY": memory_layer("Polygon", [SQUARE], CRS), "OBSTACLE_RASTER": tif, "SEED": 2, "OUTPUT": "memory:"})
    _, geoms = layer_features(out["OUTPUT"])
    assert len(geoms) > 50
    lake = shapely.box(x0 + cols // 4 * cell, y1 - rows // 2 * cell,
                       x0 + 3 * cols // 4 * cell, y1 - rows // 4 * cell)
    inside = shapely.length(shapely.intersection(geoms, lake.buffer(-0.5)))
    assert inside.sum() < 1e-6


def test_no_boundary_grows_around_the_sketch_in_a_bulged_hull(qgis_processing):
    """Without a BOUNDARY the sketch bounds the growth and the bulged convex hull of the
    major nodes closes the outskirts (Scharl sec. 4.2.5); dead ends are removed at the end
    (Fig. 4.12), and can be kept."""
    from qgis.core import QgsProcessingException

    sketch = memory_layer("LineString", [f"LINESTRING({X0} {Y0 + 500}, {X0 + 1000} {Y0 + 500})",
                                         f"LINESTRING({X0 + 500} {Y0}, {X0 + 500} {Y0 + 1000})"],
                          CRS, name="sketch")
    params = {"MAJOR_ROADS": sketch, "SEED": 2, "OUTPUT": "memory:"}
    rows, geoms = layer_features(qgis_processing.run("urbansynth:growroads", params)["OUTPUT"])
    levels = np.array([r["level"] for r in rows])
    assert (levels == 1).sum() > 20                      # minor roads filled the quarters
    assert_planar(geoms)
    extent = shapely.box(X0 - 150, Y0 - 150, X0 + 1150, Y0 + 1150)
    assert shapely.within(shapely.union_all(geoms), extent.buffer(1e-6))
    # no dead end is left except the sketch's own
    ends = np.vstack([shapely.get_coordinates(shapely.get_point(geoms, i)) for i in (0, -1)])
    _, count = np.unique(ends.round(3), axis=0, return_counts=True)
    sketch_ends = {(X0, Y0 + 500), (X0 + 1000, Y0 + 500), (X0 + 500, Y0), (X0 + 500, Y0 + 1000)}
    dead = {tuple(p) for p, c in zip(np.unique(ends.round(3), axis=0), count) if c == 1}
    assert dead <= {tuple(np.round(p, 3)) for p in sketch_ends} | set()
    kept = layer_features(qgis_processing.run("urbansynth:growroads", {
        **params, "REMOVE_DEAD_ENDS": False})["OUTPUT"])[1]
    assert len(kept) > len(geoms)
    with pytest.raises(QgsProcessingException, match="boundary polygon or sketched"):
        qgis_processing.run("urbansynth:growroads", {"OUTPUT": "memory:"})


def test_a_radial_centre_without_a_crs_is_read_in_the_boundarys_crs(qgis_processing):
    """CENTER given as the boundary's own longitude and latitude, without '[EPSG:4326]',
    grows the same network as with it (it was read in the working UTM zone: a point 24 m
    east of the zone's origin, thousands of km from the boundary, and the spokes ran off
    towards it); a centre far from the boundary in the CRS it is read in is refused."""
    from qgis.core import QgsProcessingException

    from helpers import log_feedback

    lon, lat = 24.93, 60.16
    square = memory_layer("Polygon", [
        f"POLYGON(({lon} {lat}, {lon + 0.018} {lat}, {lon + 0.018} {lat + 0.009}, "
        f"{lon} {lat + 0.009}, {lon} {lat}))"], "EPSG:4326")
    centre = f"{lon + 0.006},{lat + 0.003}"
    runs, notes = {}, {}
    for given in (centre, centre + " [EPSG:4326]"):
        log = log_feedback()
        out = qgis_processing.run("urbansynth:growroads", {
            "BOUNDARY": square, "MAJOR_PATTERN": 2, "MINOR_PATTERN": 2, "CENTER": given,
            "SEED": 3, "MAX_SEGMENTS": 300, "OUTPUT": "memory:"}, feedback=log)
        runs[given] = sorted(shapely.to_wkt(g, rounding_precision=7)
                             for g in layer_features(out["OUTPUT"])[1])
        notes[given] = any("has no CRS: read in EPSG:4326" in m for m in log.messages)
    assert runs[centre] == runs[centre + " [EPSG:4326]"]
    assert notes == {centre: True, centre + " [EPSG:4326]": False}
    with pytest.raises(QgsProcessingException, match=r"centre of the radial pattern.*lies"):
        qgis_processing.run("urbansynth:growroads", {
            "BOUNDARY": square, "MAJOR_PATTERN": 2, "CENTER": f"{lon},{lat} [EPSG:3067]",
            "SEED": 3, "MAX_SEGMENTS": 300, "OUTPUT": "memory:"})
