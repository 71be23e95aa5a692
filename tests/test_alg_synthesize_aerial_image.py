"""urbansynth:synthesizeaerialimage through real QGIS (processing.run and qgis_process.bin),
on the real SpaceNet 4 tile of Atlanta (0.5 m, EPSG:32616)."""
import numpy as np
import pytest
import shapely

from conftest import run_qgis_process
from helpers import log_feedback
from test_aerial_image import ATLANTA_IMAGE, ATLANTA_ROAD_WIDTH, atlanta_example

ALG = "urbansynth:synthesizeaerialimage"


@pytest.fixture(scope="module")
def layers(tmp_path_factory):
    """GeoPackages: the example parcels and road (UTM 16N), new parcels and streets of a
    3 x 3 block grid in Web Mercator near Prague (another CRS, another continent)."""
    import geopandas as gpd

    from urban_synthesis.plugin.parcels import subdivision as parcels

    image, ex_parcels, road = atlanta_example()
    folder = tmp_path_factory.mktemp("aerial")
    gpd.GeoDataFrame({"id": np.arange(len(ex_parcels))}, geometry=ex_parcels,
                     crs="EPSG:32616").to_file(folder / "example.gpkg", layer="parcels")
    gpd.GeoDataFrame({"id": [1]}, geometry=[road], crs="EPSG:32616").to_file(
        folder / "example.gpkg", layer="roads")
    mean_area = float(np.median(shapely.area(ex_parcels)))
    blocks = [shapely.box(150 * i, 110 * j, 150 * i + 130, 110 * j + 90)
              for i in range(3) for j in range(3)]
    lots = parcels.subdivide_blocks(blocks, "voronoi-obb", parcels.SubdivisionSettings(
        options={"mean_area": mean_area, "area_sd": 0.3 * mean_area}), seed=2,
        street_width=0).geometry
    lots = np.append(lots, shapely.box(500, 0, 900, 300))  # far larger than any example
    streets = [shapely.LineString([(-10, 100 + 110 * j), (440, 100 + 110 * j)])
               for j in range(-1, 3)] + \
        [shapely.LineString([(140 + 150 * i, -20), (140 + 150 * i, 330)]) for i in range(-1, 3)]
    # metres at 50 deg N are 1 / cos(50 deg) Web Mercator units
    scale = 1 / np.cos(np.radians(50.1))
    origin = np.array([1605000.0, 6460000.0])
    new = gpd.GeoDataFrame({"id": np.arange(len(lots))}, geometry=lots, crs="EPSG:3857")
    new.geometry = new.geometry.scale(scale, scale, origin=(0, 0)).translate(*origin)
    new.to_file(folder / "new.gpkg", layer="parcels")
    roads = gpd.GeoDataFrame({"id": np.arange(len(streets))}, geometry=streets, crs="EPSG:3857")
    roads.geometry = roads.geometry.scale(scale, scale, origin=(0, 0)).translate(*origin)
    roads.to_file(folder / "new.gpkg", layer="roads")
    return {"EXAMPLE_IMAGE": str(ATLANTA_IMAGE),
            "EXAMPLE_PARCELS": f"{folder / 'example.gpkg'}|layername=parcels",
            "EXAMPLE_ROADS": f"{folder / 'example.gpkg'}|layername=roads",
            "PARCELS": f"{folder / 'new.gpkg'}|layername=parcels",
            "ROADS": f"{folder / 'new.gpkg'}|layername=roads",
            "folder": folder, "n_lots": len(lots)}


def _params(layers, **extra):
    keys = ("EXAMPLE_IMAGE", "EXAMPLE_PARCELS", "EXAMPLE_ROADS", "PARCELS", "ROADS")
    return dict({k: layers[k] for k in keys}, EXAMPLE_ROAD_WIDTH=ATLANTA_ROAD_WIDTH, **extra)


def test_geotiff_in_the_parcels_crs_with_alpha_and_overviews(qgis_processing, layers, tmp_path):
    from osgeo import gdal, osr

    feedback = log_feedback()
    target = tmp_path / "aerial.tif"
    out = qgis_processing.run(ALG, _params(layers, SEED=3, OUTPUT_IMAGE=str(target)),
                              feedback=feedback)
    assert out["OUTPUT_IMAGE"] == str(target) and target.exists()
    ds = gdal.Open(str(target))
    srs = osr.SpatialReference(wkt=ds.GetProjection())
    assert srs.GetAuthorityCode(None) == "3857"  # the parcels' CRS, not the working UTM
    assert ds.RasterCount == 2
    assert ds.GetRasterBand(2).GetColorInterpretation() == gdal.GCI_AlphaBand
    assert ds.GetRasterBand(1).DataType == gdal.GDT_UInt16  # the example's own type
    assert ds.GetRasterBand(1).GetOverviewCount() >= 2
    alpha = ds.GetRasterBand(2).ReadAsArray()
    assert 0.3 < (alpha > 0).mean() < 0.95
    log = "\n".join(feedback.messages)
    assert "1 parcel: no example parcel" in log  # the 400 x 300 m one
    assert "road pixels painted" in log
    assert f"of {layers['n_lots']} parcels filled" in log
    # the large unmatched parcel is transparent: its centre (Web Mercator) has alpha 0
    gt = ds.GetGeoTransform()
    scale = 1 / np.cos(np.radians(50.1))
    cx, cy = 1605000.0 + 700 * scale, 6460000.0 + 150 * scale
    col, row = int((cx - gt[0]) / gt[1]), int((cy - gt[3]) / gt[5])
    assert alpha[row - 20:row + 20, col - 20:col + 20].max() == 0
    # same seed, same pixels
    again = tmp_path / "again.tif"
    qgis_processing.run(ALG, _params(layers, SEED=3, OUTPUT_IMAGE=str(again)))
    np.testing.assert_array_equal(gdal.Open(str(again)).ReadAsArray(), ds.ReadAsArray())


def test_bad_input(qgis_processing, layers, tmp_path):
    from qgis.core import QgsProcessingException

    from helpers import memory_layer

    def fails(match, **changes):
        with pytest.raises(QgsProcessingException, match=match):
            qgis_processing.run(ALG, dict(_params(layers, OUTPUT_IMAGE=str(tmp_path / "x.tif")),
                                          **changes))

    fails("has lines; polygons are needed", PARCELS=layers["ROADS"])
    far = memory_layer("Polygon", ["POLYGON ((0 0, 50 0, 50 30, 0 30, 0 0))"], "EPSG:32616",
                       name="far away parcels")
    fails("no value over the example's extent", EXAMPLE_PARCELS=far)
    fails("empty", PARCELS=memory_layer("Polygon", [], "EPSG:3857"))
    fails("PIXEL_SIZE", PIXEL_SIZE=-1)


def test_no_match_at_all_is_a_warning_naming_the_stretch(qgis_processing, layers, tmp_path):
    """MAX_STRETCH 1 (its lower limit) matches no parcel: the log said, as information,
    '0 of 10 parcels filled from 0 of 46 example parcels on the image (median stretch nan)'
    and the image was wholly transparent."""
    from helpers import log_feedback

    log = log_feedback()
    qgis_processing.run(ALG, _params(layers, OUTPUT_IMAGE=str(tmp_path / "none.tif"),
                                     MAX_STRETCH=1.0), feedback=log)
    assert not any("nan" in m for m in log.messages + log.warnings)
    assert any("every parcel is transparent" in w and "MAX_STRETCH" in w and "(1)" in w
               for w in log.warnings), log.warnings


def test_qgis_process_run(layers, tmp_path):
    """One real qgis_process.bin run: exit code 0 (no native-library crash at exit)."""
    target = tmp_path / "aerial_cli.tif"
    code, out, err = run_qgis_process("synthesizeaerialimage", dict(
        _params(layers, PIXEL_SIZE=1.0, SEED=1), OUTPUT_IMAGE=str(target)))
    assert code == 0, err
    assert out is not None and target.exists()
    from osgeo import gdal

    ds = gdal.Open(str(target))
    assert ds.RasterCount == 2 and abs(ds.GetGeoTransform()[1]) > 1.2  # 1 m in 3857 units


def test_an_image_named_with_dots_loads_under_its_full_name(qgis_processing, layers, tmp_path,
                                                            monkeypatch):
    """'my.town.v2.tif' loaded as 'my' (QGIS 3.22 names a loaded output after its file name
    up to the first dot); it loads as 'my.town.v2' (outputs.OutputStaging). QGIS names
    outputs in the system temporary folder after the output instead: TMPDIR is moved."""
    from qgis.core import (QgsProcessingContext, QgsProcessingOutputLayerDefinition,
                           QgsProcessingUtils, QgsProject)

    (tmp_path / "elsewhere").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "elsewhere"))
    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    target = tmp_path / "my.town.v2.tif"
    output = QgsProcessingOutputLayerDefinition(str(target), QgsProject.instance())
    qgis_processing.run(ALG, _params(layers, SEED=3, OUTPUT_IMAGE=output), context=context)
    (key, details), = context.layersToLoadOnCompletion().items()
    assert key == str(target)
    layer = QgsProcessingUtils.mapLayerFromString(key, context)
    details.setOutputLayerName(layer)           # what Processing does when it loads it
    assert layer.name() == "my.town.v2"
