"""urbansynth:synthesizeroadsfromfragments through real QGIS (processing.run and qgis_process)."""
import numpy as np
import pytest
import shapely

from conftest import helsinki_layer, run_qgis_process

ALG = "urbansynth:synthesizeroadsfromfragments"


class Log:
    """Collects the algorithm's log lines (a QgsProcessingFeedback made lazily)."""

    def __new__(cls, cancel_after=None):
        from qgis.core import QgsProcessingFeedback

        class _Log(QgsProcessingFeedback):
            def __init__(self):
                super().__init__()
                self.messages = []
                self.progress = []

            def pushInfo(self, info):  # noqa: N802
                self.messages.append(info)

            def setProgress(self, value):  # noqa: N802
                self.progress.append(value)
                super().setProgress(value)
                if cancel_after is not None and len(self.progress) > cancel_after:
                    self.cancel()

        return _Log()


@pytest.fixture(scope="module")
def helsinki(qgis_processing, tmp_path_factory):
    """Helsinki levelled roads, their level 0 roads as a GeoPackage, and the fragment
    database, all made by the real algorithms."""
    folder = tmp_path_factory.mktemp("synth")
    roads = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": str(folder / "roads.gpkg"),
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    db = str(folder / "helsinki_fragments.gpkg")
    qgis_processing.run("urbansynth:buildfragmentdatabase", {"ROADS": roads, "OUTPUT": db})
    arterials = qgis_processing.run("native:extractbyattribute", {
        "INPUT": roads, "FIELD": "level", "OPERATOR": 0, "VALUE": "0",
        "OUTPUT": str(folder / "arterials.gpkg")})["OUTPUT"]
    return dict(roads=roads, db=db, arterials=arterials, folder=folder)


def layer_arrays(layer):
    import shapely as sh

    feats = list(layer.getFeatures())
    geoms = np.array([sh.from_wkb(bytes(f.geometry().asWkb())) for f in feats], dtype=object)
    attrs = {name: [f[name] for f in feats] for name in
             ("level", "source_fragment", "database", "fragment_id")}
    return geoms, attrs


def test_helsinki_synthesis_through_processing(qgis_processing, helsinki):
    from qgis.core import QgsCoordinateReferenceSystem

    from helpers import assert_planar

    log = Log()
    res = qgis_processing.run(ALG, {"ARTERIALS": helsinki["arterials"], "FRAGMENT_DB":
                                    helsinki["db"], "SEED": 3, "OUTPUT": "memory:"},
                              feedback=log)
    layer = res["OUTPUT"]
    assert layer.featureCount() == res["N_EDGES"] > 80
    assert res["N_INSERTED"] >= 1
    assert [f.name() for f in layer.fields()] == ["level", "source_fragment", "database",
                                                 "fragment_id", "length_m"]
    # written back in the input CRS (the hierarchy output keeps the OSM layer's WGS 84)
    assert layer.crs().authid() == "EPSG:4326"
    geoms, attrs = layer_arrays(layer)
    level = np.array(attrs["level"])
    assert set(level) >= {0, 1}
    src = np.array(attrs["source_fragment"], dtype=object)
    assert set(src[level == 0]) == {"arterial"}
    # every example fragment in the output was counted (the fill's were not)
    inserted = {s for s in src if s.startswith("helsinki_fragments:")}
    assert res["N_INSERTED"] >= len(inserted) > 0
    made = ("procedural", "statistics", "link", "close", "cul-de-sac")
    assert all(s.startswith("helsinki_fragments:") or s in made for s in src[level > 0])
    assert any(m.startswith("Level 0:") for m in log.messages)
    assert log.progress and max(log.progress) == pytest.approx(100)
    # planar in a metric CRS
    from urban_synthesis.plugin.qgis_glue import qgis_io

    utm = QgsCoordinateReferenceSystem("EPSG:32635")
    metric = qgis_io.reproject(geoms, layer.crs(), utm, None)
    assert shapely.is_valid(metric).all()
    assert (shapely.length(metric) > 1e-3).all()
    assert_planar(metric)


def test_relief_output_with_a_dem(qgis_processing, helsinki, tmp_path):
    """A synthetic DEM (a hill in the western half): OUTPUT_DEM is a GeoTIFF covering the
    arterials with finite heights; a database built with the same DEM carries relief."""
    from osgeo import gdal, osr

    layer = helsinki["arterials"]
    from qgis.core import QgsVectorLayer

    lyr = QgsVectorLayer(layer, "arterials") if isinstance(layer, str) else layer
    ext = lyr.extent()  # WGS 84
    nx, ny = 200, 200
    x0, y1 = ext.xMinimum() - 0.002, ext.yMaximum() + 0.002
    dx = (ext.width() + 0.004) / nx
    dy = (ext.height() + 0.004) / ny
    xs = x0 + dx * (np.arange(nx) + 0.5)
    ys = y1 - dy * (np.arange(ny) + 0.5)
    cx = ext.xMinimum() + ext.width() * 0.3
    cy = ext.center().y()
    hill = 10 + 30 * np.exp(-(((xs[None, :] - cx) / (ext.width() * 0.2)) ** 2
                              + ((ys[:, None] - cy) / (ext.height() * 0.3)) ** 2))
    dem_path = tmp_path / "hill.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(dem_path), nx, ny, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0, dx, 0, y1, 0, -dy))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(4326)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(hill.astype(np.float32))
    ds = None
    db = str(tmp_path / "hilly.gpkg")
    qgis_processing.run("urbansynth:buildfragmentdatabase", {
        "ROADS": helsinki["roads"], "DEM": str(dem_path), "OUTPUT": db})
    out = tmp_path / "relief.tif"
    res = qgis_processing.run(ALG, {"ARTERIALS": layer, "FRAGMENT_DB": db,
                                    "DEM": str(dem_path), "N_BEST": 1, "OUTPUT": "memory:",
                                    "OUTPUT_DEM": str(out)})
    assert res["OUTPUT_DEM"] == str(out)
    r = gdal.Open(str(out))
    a = r.GetRasterBand(1).ReadAsArray()
    assert r.RasterXSize > 50 and np.isfinite(a).mean() > 0.99
    assert 5 < np.nanmin(a) and np.nanmax(a) < 45
    assert "32635" in r.GetProjection() or "UTM zone 35N" in r.GetProjection()


def test_two_databases_with_style_polygons(qgis_processing, helsinki, tmp_path):
    """Database 2 (a copy under another name) inside a style polygon over the east half."""
    import shutil

    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer

    second = tmp_path / "other_city.gpkg"
    shutil.copy(helsinki["db"], second)
    arterials = QgsVectorLayer(helsinki["arterials"], "arterials")
    ext = arterials.extent()
    style = QgsVectorLayer("Polygon?crs=EPSG:4326&field=database:integer", "style", "memory")
    f = QgsFeature(style.fields())
    f.setGeometry(QgsGeometry.fromRect(ext.buffered(0.01)))
    f["database"] = 2
    style.dataProvider().addFeatures([f])
    res = qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                    "FRAGMENT_DB_2": str(second), "STYLE": style,
                                    "STYLE_FIELD": "database", "N_BEST": 1,
                                    "OUTPUT": "memory:"})
    _, attrs = layer_arrays(res["OUTPUT"])
    level = np.array(attrs["level"])
    # fragments only from database 2 (statistics splits and links have none)
    assert set(np.array(attrs["database"], dtype=object)[level > 0]) - {""} <= {"other_city"}
    assert (level > 0).any()


def test_errors(qgis_processing, helsinki, tmp_path):
    from qgis.core import QgsFeature, QgsGeometry, QgsProcessingException, QgsVectorLayer

    arterials = helsinki["arterials"]
    # missing and corrupt databases
    with pytest.raises(QgsProcessingException, match="does not exist"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB":
                                  str(tmp_path / "none.gpkg"), "OUTPUT": "memory:"})
    junk = tmp_path / "junk.gpkg"
    junk.write_bytes(b"not a database" * 20)
    with pytest.raises(QgsProcessingException, match="not a GeoPackage"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": str(junk),
                                  "OUTPUT": "memory:"})
    # arterials that close no face
    line = QgsVectorLayer("LineString?crs=EPSG:32635", "open", "memory")
    f = QgsFeature()
    f.setGeometry(QgsGeometry.fromWkt("LINESTRING(0 0, 500 0, 500 500)"))
    line.dataProvider().addFeatures([f])
    with pytest.raises(QgsProcessingException, match="enclose no face"):
        qgis_processing.run(ALG, {"ARTERIALS": line, "FRAGMENT_DB": helsinki["db"],
                                  "OUTPUT": "memory:"})
    # wrong geometry type
    poly = QgsVectorLayer("Polygon?crs=EPSG:32635", "poly", "memory")
    f = QgsFeature()
    f.setGeometry(QgsGeometry.fromWkt("POLYGON((0 0, 500 0, 500 500, 0 0))"))
    poly.dataProvider().addFeatures([f])
    with pytest.raises(QgsProcessingException, match="lines are needed"):
        qgis_processing.run(ALG, {"ARTERIALS": poly, "FRAGMENT_DB": helsinki["db"],
                                  "OUTPUT": "memory:"})
    # absurd N_BEST, style number out of range, relief output without a DEM
    with pytest.raises(QgsProcessingException, match="N_BEST"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                  "N_BEST": 500, "OUTPUT": "memory:"})
    style = QgsVectorLayer("Polygon?crs=EPSG:4326&field=database:integer", "style", "memory")
    f = QgsFeature(style.fields())
    f.setGeometry(QgsGeometry.fromWkt("POLYGON((24 60, 25 60, 25 61, 24 60))"))
    f["database"] = 3
    style.dataProvider().addFeatures([f])
    with pytest.raises(QgsProcessingException, match="database number from 1 to 1"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                  "STYLE": style, "OUTPUT": "memory:"})
    with pytest.raises(QgsProcessingException, match="OUTPUT_DEM needs an elevation model"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                  "OUTPUT": "memory:", "OUTPUT_DEM": str(tmp_path / "x.tif")})
    # a boundary no arterial reaches (another place, or a CRS mix-up): refused, not filled
    far = QgsVectorLayer("Polygon?crs=EPSG:32635", "far boundary", "memory")
    f = QgsFeature()
    f.setGeometry(QgsGeometry.fromWkt("POLYGON((0 0, 900 0, 900 900, 0 900, 0 0))"))
    far.dataProvider().addFeatures([f])
    with pytest.raises(QgsProcessingException, match="lies entirely outside the boundary "
                                                     "'?far boundary"):
        qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                  "BOUNDARY": far, "OUTPUT": "memory:"})


def test_cancel(qgis_processing, helsinki):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="Canceled"):
        qgis_processing.run(ALG, {"ARTERIALS": helsinki["arterials"],
                                  "FRAGMENT_DB": helsinki["db"], "OUTPUT": "memory:"},
                            feedback=Log(cancel_after=4))


def test_qgis_process_exits_zero(helsinki, tmp_path):
    out = tmp_path / "synth.gpkg"
    code, result, err = run_qgis_process("synthesizeroadsfromfragments", {
        "ARTERIALS": helsinki["arterials"], "FRAGMENT_DB": helsinki["db"], "SEED": 5,
        "OUTPUT": out})
    assert code == 0, err
    assert result["results"]["N_EDGES"] > 80
    import pyogrio

    df = pyogrio.read_dataframe(out)
    assert len(df) == result["results"]["N_EDGES"]
    assert {"level", "source_fragment", "database"} <= set(df.columns)


def test_boundary_closes_the_sketch_and_the_fill_is_logged(qgis_processing, helsinki, tmp_path):
    """Helsinki's arterials with their convex hull as BOUNDARY, through qgis_process: the
    hull closes the faces the clipped extract leaves open, the log counts each way of the
    fill, and the new streets keep the network invariants against the arterials."""
    from urban_synthesis.plugin.network import invariants

    hull = qgis_processing.run("qgis:minimumboundinggeometry", {
        "INPUT": helsinki["arterials"], "TYPE": 3,
        "OUTPUT": str(tmp_path / "hull.gpkg")})["OUTPUT"]
    out = tmp_path / "filled.gpkg"
    code, result, err = run_qgis_process("synthesizeroadsfromfragments", {
        "ARTERIALS": helsinki["arterials"], "BOUNDARY": hull, "FRAGMENT_DB": helsinki["db"],
        "SEED": 2, "OUTPUT": str(out)})
    assert code == 0, err
    import geopandas as gpd

    roads = gpd.read_file(out).to_crs(32635)
    arterials = gpd.read_file(helsinki["arterials"]).to_crs(32635)
    hull_m = gpd.read_file(hull).to_crs(32635).geometry.values[0]
    new = roads[roads["level"] > 0].geometry.values
    # far more streets than the faces the arterials close on their own (issue 15: 12 km)
    assert shapely.length(new).sum() > 1.5 * shapely.length(arterials.geometry.values).sum()
    assert shapely.within(roads.geometry.values, hull_m.buffer(0.01)).all()
    given = shapely.get_parts(shapely.intersection(arterials.geometry.values, hull_m))
    given = given[shapely.length(given) > 0.01]
    check = invariants.check_network(new, given, area=hull_m)
    v = check.violations()
    assert v["crossings_given"] == v["crossings_synthesised"] == v["overlaps"] == 0, v
    assert v["floating_pieces"] == 0 and v["parallel_duplicates"] == 0, v
    log = Log()
    res = qgis_processing.run(ALG, {"ARTERIALS": helsinki["arterials"], "BOUNDARY": hull,
                                    "FRAGMENT_DB": helsinki["db"], "SEED": 2,
                                    "OUTPUT": "memory:"}, feedback=log)
    assert res["N_EDGES"] == len(roads)
    fill = [m for m in log.messages if m.startswith("Fill:")]
    # the faces left empty are counted on the network returned, after the links
    empty = [m for m in log.messages if "left empty" in m]
    assert fill and empty and empty[0].endswith("left empty: 0.")


@pytest.mark.parametrize("field", ["highway", "road_class"])
def test_no_new_street_ends_on_a_trunk_whichever_field_holds_its_class(qgis_processing,
                                                                       helsinki, field):
    """Arterials taken from 'Extract road hierarchy' (its level-0 roads, as the demo and the
    district model take them) hold their OSM class in 'road_class', not 'highway': their
    trunk took new streets ending on it away from its junctions (9 on this sketch), as if
    the layer had no classes. The tools that filter classes read 'road_class' already."""
    from helpers import memory_layer

    sketch = ["LINESTRING (500000 5200000, 501200 5200000)",
              "LINESTRING (501200 5200000, 501200 5201000, 500000 5201000, 500000 5200000)",
              "LINESTRING (500600 5200000, 500600 5201000)"]
    arterials = memory_layer("LineString", sketch, "EPSG:32632", f"&field={field}:string",
                             [["trunk"], ["secondary"], ["secondary"]])
    res = qgis_processing.run(ALG, {"ARTERIALS": arterials, "FRAGMENT_DB": helsinki["db"],
                                    "SEED": 1, "OUTPUT": "memory:"})
    geoms, attrs = layer_arrays(res["OUTPUT"])
    new = geoms[np.array(attrs["level"]) > 0]
    assert len(new) > 50
    ends = shapely.points(np.concatenate([shapely.get_coordinates(shapely.get_point(new, k))
                                          for k in (0, -1)]))
    trunk = shapely.from_wkt(sketch[0])
    junctions = shapely.MultiPoint([(500000, 5200000), (500600, 5200000), (501200, 5200000)])
    on_trunk = shapely.dwithin(ends, trunk, 0.01) & ~shapely.dwithin(ends, junctions, 1.0)
    assert not on_trunk.any()
