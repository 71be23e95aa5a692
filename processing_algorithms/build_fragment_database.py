"""urbansynth:buildfragmentdatabase - road fragments per level, shape and terrain descriptors."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
)

from ..plugin import blocks, database, fragments, qgis_io
from ..plugin.shape_context import DemGrid
from .common import AlgorithmBase


def _crs_text(crs: QgsCoordinateReferenceSystem) -> str:
    """What the database records as its CRS: the authority id, else the WKT."""
    return crs.authid() or crs.toWkt(QgsCoordinateReferenceSystem.WKT_PREFERRED)


def read_dem(layer, work_crs: QgsCoordinateReferenceSystem, bounds, cell_size: float,
             feedback=None) -> DemGrid:
    """Warp a raster layer into the working CRS over ``bounds`` (+ a margin) with GDAL.

    The engine works on a numpy grid with a geotransform; GDAL (the same library QGIS uses)
    reprojects and resamples the DEM bilinearly into an in-memory dataset first.
    """
    from osgeo import gdal

    source = layer.source().split("|")[0]
    margin = 4 * cell_size
    x0, y0, x1, y1 = bounds
    options = gdal.WarpOptions(
        format="MEM", dstSRS=_crs_text(work_crs), srcSRS=_crs_text(layer.crs()) or None,
        outputBounds=(x0 - margin, y0 - margin, x1 + margin, y1 + margin),
        xRes=cell_size, yRes=cell_size, resampleAlg="bilinear", dstNodata=float("nan"),
        outputType=gdal.GDT_Float32, multithread=False)
    # no gdal.UseExceptions(): it would switch the bindings' error mode for all of QGIS
    try:
        ds = gdal.Warp("", source, options=options)
    except RuntimeError as exc:  # exceptions already enabled by someone else
        raise QgsProcessingException(
            f"DEM '{layer.name()}' cannot be read or reprojected: {exc}") from exc
    if ds is None:
        raise QgsProcessingException(f"DEM '{layer.name()}' cannot be read or reprojected: "
                                     f"{gdal.GetLastErrorMsg() or 'unknown GDAL error'}.")
    band = ds.GetRasterBand(1)
    grid = band.ReadAsArray().astype(np.float64)
    nodata = band.GetNoDataValue()
    dem = DemGrid(grid, ds.GetGeoTransform(), nodata)
    valid = np.isfinite(dem.array)
    if not valid.any():
        raise QgsProcessingException(
            f"DEM '{layer.name()}' has no value over the roads' extent: check that they overlap.")
    if feedback is not None and not valid.all():
        feedback.pushInfo(f"DEM: {100 * (1 - valid.mean()):.0f} % of the roads' extent has no "
                          "height; slopes there are taken as 0.")
    return dem


class BuildFragmentDatabase(AlgorithmBase):
    ROADS = "ROADS"
    LEVEL_FIELD = "LEVEL_FIELD"
    DEM = "DEM"
    MIN_AREA = "MIN_AREA"
    MIN_WIDTH = "MIN_WIDTH"
    DEM_CELL_SIZE = "DEM_CELL_SIZE"
    OUTPUT = "OUTPUT"
    N_FRAGMENTS = "N_FRAGMENTS"

    def name(self):
        return "buildfragmentdatabase"

    def displayName(self):  # noqa: N802
        return "Build fragment database"

    def group(self):
        return "Example databases"

    def groupId(self):  # noqa: N802
        return "databases"

    def shortHelpString(self):  # noqa: N802
        return (
            "Decomposes a levelled road network into hierarchical fragments and stores them, "
            "with shape and terrain descriptors, in a GeoPackage example database for "
            "fragment-based road synthesis (Hartmann, ch. 4.1).\n\n"
            "For each street level l, a fragment is a closed face of the streets with level <= l; "
            "its interior streets are those of level l + 1 inside it, and a fragment whose "
            "interior holds only dead ends is flagged as a city block. Use the output of "
            "'Extract road hierarchy' as input.\n\n"
            "The database holds the fragments (area, aspect ratio, compactness, relief change), "
            "their interior streets, 100 boundary samples with scale-aware shape-context "
            "histograms and, with a DEM, slope descriptors and a relief patch per fragment."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads with levels", [QgsProcessing.TypeVectorLine]),
            "Street lines with a hierarchy level per line (0 = arterial), e.g. the output of "
            "'Extract road hierarchy'.")
        self.add(QgsProcessingParameterField(
            self.LEVEL_FIELD, "Level field", defaultValue="level",
            parentLayerParameterName=self.ROADS, type=QgsProcessingParameterField.Numeric,
            optional=True),
            "Integer street level (0 = arterial, larger = more local); 'level' when left empty.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model (optional)", optional=True),
            "A DEM in any CRS: adds the relief change, mean slope, slope descriptors and a "
            "relief patch to every fragment (thesis ch. 4.1, terrain term).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_AREA, "Minimum fragment area (m²)", QgsProcessingParameterNumber.Double,
            defaultValue=blocks.MIN_BLOCK_AREA, minValue=0.0, maxValue=1e6),
            "Faces smaller than this are junction islands and road slivers, not fragments.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_WIDTH, "Minimum fragment width (m)", QgsProcessingParameterNumber.Double,
            defaultValue=blocks.MIN_BLOCK_WIDTH, minValue=0.0, maxValue=1000.0),
            "Faces whose mean width 2·area/perimeter is under this are strips between dual "
            "carriageways, not fragments.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.DEM_CELL_SIZE, "DEM cell size (m)", QgsProcessingParameterNumber.Double,
            defaultValue=fragments.RELIEF_CELL_SIZE, minValue=0.5, maxValue=100.0),
            "The DEM is resampled to this cell size in the working CRS; relief patches use it.",
            advanced=True)
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Fragment database", fileFilter="GeoPackage (*.gpkg)"),
            "GeoPackage file to write (replaced if it exists).")
        self.addOutput(QgsProcessingOutputNumber(self.N_FRAGMENTS, "Number of fragments"))

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        level_field = self.parameterAsString(parameters, self.LEVEL_FIELD, context) or "level"
        frame = qgis_io.read_source(self, parameters, self.ROADS, context, feedback,
                                    kind="lines", required_fields=[level_field],
                                    fields=[level_field])
        label = frame.name
        min_area = qgis_io.check_number(self.parameterAsDouble(parameters, self.MIN_AREA, context),
                                        self.MIN_AREA, 0.0, 1e6)
        min_width = qgis_io.check_number(
            self.parameterAsDouble(parameters, self.MIN_WIDTH, context), self.MIN_WIDTH, 0, 1000)
        cell = qgis_io.check_number(self.parameterAsDouble(parameters, self.DEM_CELL_SIZE, context),
                                    self.DEM_CELL_SIZE, 0.5, 100.0)
        output = self.parameterAsFileOutput(parameters, self.OUTPUT, context)

        levels = pd.to_numeric(frame.attributes[level_field], errors="coerce").to_numpy(
            dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(levels) | (levels < 0) | (levels != np.round(levels))
        if bad.all():
            raise QgsProcessingException(
                f"Layer {label}: field '{level_field}' holds no street level (whole numbers "
                ">= 0, 0 = arterial). Run 'Extract road hierarchy' first.")
        if bad.any():
            feedback.pushInfo(f"{label}: {int(bad.sum())} lines without a valid level skipped.")
        lines, levels = frame.geometry[~bad], levels[~bad].astype(np.int64)
        feedback.setProgress(5)

        dem = None
        dem_layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem_layer is not None:
            dem = read_dem(dem_layer, frame.crs, shapely.total_bounds(lines), cell, feedback)
            feedback.pushInfo(f"DEM resampled to {dem.array.shape[1]} x {dem.array.shape[0]} "
                              f"cells of {cell:g} m.")
        feedback.setProgress(15)

        frags = qgis_io.run_engine(label, fragments.extract_fragments, lines, levels,
                                   min_area=min_area, min_width=min_width, dem=dem,
                                   cell_size=cell, progress=qgis_io.progress_for(feedback, 15, 60))
        counts = frags.counts
        for level, n in counts["per_level"].items():
            feedback.pushInfo(f"Level {level}: {n} fragments "
                              f"({counts['blocks_per_level'].get(level, 0)} city blocks).")
        if counts["n_unassigned_streets"]:
            feedback.pushInfo(f"{counts['n_unassigned_streets']} streets of level >= 1 lie in "
                              "no closed fragment (open edges of the network) and are not stored.")
        source = f"{label} (field '{level_field}')" + (
            f", DEM '{dem_layer.name()}'" if dem_layer is not None else "")
        qgis_io.run_engine(label, database.write_fragment_database, output, frags,
                           _crs_text(frame.crs), source=source, elevation=dem,
                           extra={"min_area_m2": min_area, "min_width_m": min_width,
                                  "relief_cell_m": cell if dem is not None else None},
                           progress=qgis_io.progress_for(feedback, 60, 100))
        feedback.pushInfo(f"Fragment database written: {output} ({len(frags)} fragments).")
        return {self.OUTPUT: output, self.N_FRAGMENTS: len(frags)}
