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
