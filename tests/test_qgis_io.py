"""The QGIS adapter's rules that no algorithm test pins down on its own
(plugin/qgis_glue/qgis_io.py)."""
import math

import numpy as np
import pytest


def test_a_raster_in_degrees_keeps_its_resolution_in_metres(qgis_processing, tmp_path):
    """A DEM in EPSG:4326 with 0.00005° pixels at 60° N (2.8 m east-west, 5.6 m north-south):
    its cell in the working CRS was the bounding box of the pixel's diagonal (5.6 m and
    more); it is now the square of the pixel's area (about 3.9 m)."""
    from osgeo import gdal, osr
    from qgis.core import (QgsCoordinateReferenceSystem, QgsProcessingContext,
                           QgsRasterLayer)

    from urban_synthesis.plugin.qgis_glue import qgis_io

    path = tmp_path / "dem_4326.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(path), 200, 200, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((24.95, 5e-5, 0.0, 60.17, 0.0, -5e-5))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(4326)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(np.zeros((200, 200), np.float32))
    ds = None
    layer = QgsRasterLayer(str(path), "dem")
    utm = QgsCoordinateReferenceSystem("EPSG:32635")
    cell = qgis_io.raster_cell_size(layer, utm, (0.0, 0.0, 500.0, 500.0),
                                    QgsProcessingContext())
    east, north = 5e-5 * 111_320 * math.cos(math.radians(60.17)), 5e-5 * 111_400
    assert cell == pytest.approx(math.sqrt(east * north), rel=0.02)


def test_a_raster_coarsened_for_a_large_extent_says_why(qgis_processing, tmp_path):
    """A 10 m DEM over a 22 km extent is read at 10.7 m cells (at most 2,048 across); the
    log said only 'DEM resampled to 10.7 m cells', as if the DEM were that coarse."""
    from osgeo import gdal, osr
    from qgis.core import (QgsCoordinateReferenceSystem, QgsProcessingContext,
                           QgsRasterLayer)

    from helpers import log_feedback
    from urban_synthesis.plugin.qgis_glue import qgis_io

    path = tmp_path / "dem_10m.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(path), 100, 100, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((500_000.0, 10.0, 0.0, 5_200_000.0, 0.0, -10.0))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    ds.SetProjection(srs.ExportToWkt())
    ds = None
    layer = QgsRasterLayer(str(path), "dem_10m")
    utm = QgsCoordinateReferenceSystem("EPSG:32632")
    log = log_feedback()
    small = qgis_io.raster_cell_size(layer, utm, (0.0, 0.0, 1_000.0, 1_000.0),
                                     QgsProcessingContext(), feedback=log)
    assert small == pytest.approx(10.0) and not log.messages
    large = qgis_io.raster_cell_size(layer, utm, (0.0, 0.0, 22_000.0, 1_000.0),
                                     QgsProcessingContext(), feedback=log)
    assert large == pytest.approx(22_000 / 2048)
    assert log.messages == ["Raster dem_10m: its 10.0 m cells are read as 10.7 m cells, so "
                            "that the 22.0 km extent spans at most 2,048 cells."]
