"""Imagery: aerial-view images of synthesised layouts (Aliaga et al. 2008, sec. 3.2).

Image synthesis is the stage after parcels: it reads the example's registered aerial image,
its parcels and roads, and the new layout's parcels and roads, and renders a new image
(:mod:`aerial_image`). Rasters are plain numpy arrays with a GDAL geotransform here; reading
and writing GeoTIFFs is the QGIS glue's job.
"""
from .aerial_image import (  # noqa: F401
    GeoImage, ImageSettings, ImageSynthesis, ParcelFrames, match_parcels, parcel_frames,
    scanline_extents, scanline_grid, synthesize_image,
)
