"""urbansynth:rasterroadstovector - road raster to a clean vector graph (thesis ch. 4.2.4)."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBand,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsWkbTypes,
)

from ..plugin.qgis_glue import qgis_io
from ..plugin.roads import raster_graph
from .common import AlgorithmBase

FIELDS = [("edge_id", "int"), ("length_m", "float"), ("node_from", "int"), ("node_to", "int")]


class RasterRoadsToVector(AlgorithmBase):
    GROUP_ID = "analysis"
    INPUT = "INPUT"
    BAND = "BAND"
    THRESHOLD = "THRESHOLD"
    SIMPLIFY = "SIMPLIFY"
    MIN_DEAD_END = "MIN_DEAD_END"
    MAX_GAP = "MAX_GAP"
    FROM_EDGE = "FROM_EDGE"
    OUTPUT = "OUTPUT"

    #: The largest raster one run vectorises (thinning and the pixel graph hold it whole).
    MAX_PIXELS = 100_000_000

    def name(self):
        return "rasterroadstovector"

    def displayName(self):  # noqa: N802
        return "Road raster to vector graph"

    def shortHelpString(self):  # noqa: N802
        return (
            "Turns a road raster (a road mask, a classified image, a StreetGAN image) into a "
            "clean planar road network, with the post-processing of the StreetGAN thesis "
            "(Hartmann, ch. 4.2.4): threshold, one erosion and five dilations with a 3 x 3 "
            "cross, Zhang-Suen thinning, the skeleton's pixel graph without its 0.5 px² "
            "artefact triangles, chains between nodes of degree other than 2, five rounds of "
            "smoothing, Douglas-Peucker simplification and removal of short dead ends.\n\n"
            "Roads are pixels brighter than the threshold; no-data pixels are background. "
            "Lengths are in the raster's units "
            "(use a projected raster in metres); the raster is read at its own resolution.\n\n"
            "Output: road edges with edge_id, length_m (metres on the ground, also for a "
            "raster in feet or Web Mercator), node_from, node_to, in the raster's CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterRasterLayer(self.INPUT, "Road raster"),
                 "A north-up raster where roads are bright (above the threshold).")
        # optional: QGIS 3.22 does not fall back to a band parameter's default by itself
        self.add(QgsProcessingParameterBand(self.BAND, "Band", defaultValue=1,
                                            parentLayerParameterName=self.INPUT, optional=True),
                 "The band holding the road values (default 1).")
        self.add(QgsProcessingParameterNumber(
            self.THRESHOLD, "Threshold", QgsProcessingParameterNumber.Type.Double, defaultValue=127.0),
            "Pixels above this value are road (thesis: 127 of 0 .. 255; use 0 for a 0/1 mask).")
        self.add(QgsProcessingParameterNumber(
            self.SIMPLIFY, "Simplification tolerance (map units)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=3.0, minValue=0.0, maxValue=1000.0),
            "Douglas-Peucker tolerance (thesis: 3 m).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_DEAD_END, "Shortest dead end kept (map units)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=25.0, minValue=0.0,
            maxValue=10000.0),
            "Dead-end chains this long or shorter are removed (thesis: 25 m).")
        self.add(QgsProcessingParameterNumber(
            self.MAX_GAP, "Close gaps up to (map units)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.0, minValue=0.0, maxValue=1000.0),
            "Extend dead ends straight ahead by up to this to meet a road (0 = off, as in the "
            "thesis).", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.FROM_EDGE, "Measure dead ends from the road's edge", defaultValue=True),
            "Checked: a dead end's length runs from the edge of the road it leaves to the "
            "road's end (removes skeleton spurs of wide roads, keeps side streets). "
            "Unchecked: the thesis's skeleton length.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Road graph", QgsProcessing.SourceType.TypeVectorLine),
            "Planar road edges between junctions and dead ends.")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from osgeo import gdal

        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        if layer is None or not layer.isValid():
            raise QgsProcessingException("The road raster could not be loaded.")
        band = self.parameterAsInt(parameters, self.BAND, context) or 1
        if not 1 <= band <= layer.bandCount():
            raise QgsProcessingException(f"Raster '{layer.name()}' has no band {band} "
                                         f"(bands 1 .. {layer.bandCount()}).")
        if not qgis_io.usable_crs(layer.crs()):
            raise QgsProcessingException(
                f"Raster '{layer.name()}' has no coordinate reference system (CRS), so its "
                "units are unknown. Assign its CRS (Layer Properties > Source) and run again.")
        if layer.width() * layer.height() > self.MAX_PIXELS:
            raise QgsProcessingException(
                f"Raster '{layer.name()}' has {layer.width()} x {layer.height()} pixels, more "
                f"than the {self.MAX_PIXELS / 1e6:.0f} million one run turns into roads: clip "
                "it to the area you need (Clip raster by extent) and run the parts.")
        if layer.crs().isGeographic():
            raise QgsProcessingException(
                f"Raster '{layer.name()}' is in geographic coordinates (degrees): lengths and "
                "tolerances need a projected raster in metres; reproject it first (Warp).")
        ds = gdal.Open(layer.source().split("|")[0])
        if ds is None:
            raise QgsProcessingException(f"Raster '{layer.name()}' cannot be read by GDAL.")
        array = ds.GetRasterBand(band).ReadAsArray()
        nodata = ds.GetRasterBand(band).GetNoDataValue()
        gt = ds.GetGeoTransform()
        ds = None
        if array is None or array.size == 0:
            raise QgsProcessingException(f"Raster '{layer.name()}' band {band} is empty.")
        array = array.astype(np.float64)
        if nodata is not None:
            array[array == nodata] = np.nan
        threshold = self.number(parameters, self.THRESHOLD, context)
        valid = np.isfinite(array)
        if not valid.any():
            raise QgsProcessingException(f"Raster '{layer.name()}' band {band} holds no value "
                                         "(every pixel is no-data).")
        # no-data pixels are background, never road (a road mask written with the background
        # as no-data, gdal_rasterize -a_nodata 0, has only road values left)
        above = float((array[valid] > threshold).sum()) / array.size
        low, high = float(np.nanmin(array)), float(np.nanmax(array))
        if above == 0.0:
            raise QgsProcessingException(
                f"Raster '{layer.name()}': no pixel is above the threshold {threshold:g} (values "
                f"{low:g} .. {high:g}): lower THRESHOLD below the road values.")
        if above == 1.0:
            raise QgsProcessingException(
                f"Raster '{layer.name()}': every pixel is above the threshold {threshold:g} "
                f"(values {low:g} .. {high:g}), so roads cannot be told from the background: "
                "set THRESHOLD between the background and the road values.")
        if above > 0.5:  # roads are a minority of any road image: likely dark roads
            feedback.pushWarning(
                f"Raster '{layer.name()}': {100 * above:.0f} % of the pixels are above the "
                f"threshold {threshold:g}, so most of the image would be road: if its roads "
                "are dark on a bright background, invert it first (Raster calculator: "
                f"{low + high:g} - value); else raise THRESHOLD.")
        no_data = int(array.size - valid.sum())
        feedback.pushInfo(f"{array.shape[1]} x {array.shape[0]} px (width x height), "
                          f"{100 * above:.1f} % above the threshold (values {low:g} .. {high:g})"
                          + (f"; {no_data} no-data pixels taken as background." if no_data
                             else "."))
        result = qgis_io.run_engine(
            f"Raster '{layer.name()}'", raster_graph.raster_to_graph, array, gt,
            threshold=threshold, simplify=self.number(parameters, self.SIMPLIFY, context),
            min_dead_end=self.number(parameters, self.MIN_DEAD_END, context),
            max_gap=self.number(parameters, self.MAX_GAP, context),
            from_edge=self.parameterAsBoolean(parameters, self.FROM_EDGE, context),
            progress=qgis_io.progress_for(feedback, 0, 90))
        g = result.graph
        n = len(result.geometry)
        feedback.pushInfo(f"{result.stats['skeleton_pixels']} skeleton pixels, "
                          f"{result.stats['artefact_edges']} artefact edges removed, {n} road "
                          f"edges in {result.stats['seconds']['total']:.2f} s.")
        if n == 0:
            raise QgsProcessingException(
                f"Raster '{layer.name()}': the pixels above the threshold {threshold:g} thin "
                "to no road edge (only pieces shorter than the shortest dead end kept, "
                f"{self.number(parameters, self.MIN_DEAD_END, context):g}): lower "
                "MIN_DEAD_END or check the threshold.")
        # length_m in true metres: a raster in feet or in Web Mercator (1.5 x at 50°) is
        # measured in the working CRS, as the other tools measure (docs/ARCHITECTURE.md)
        work = qgis_io.working_crs(layer.crs(), layer.extent(), context)
        lengths = shapely.length(qgis_io.reproject(result.geometry, layer.crs(), work, context))
        if work != layer.crs():
            feedback.pushInfo(
                f"Raster '{layer.name()}' is in {qgis_io.crs_label(layer.crs())}, whose units "
                "are not metres on the ground here: SIMPLIFY, MIN_DEAD_END and MAX_GAP are in "
                f"its units; length_m is measured in {qgis_io.crs_label(work)}.")
        table = pd.DataFrame({"edge_id": np.arange(n),
                              "length_m": lengths if n else [],
                              "node_from": g.u if n else [], "node_to": g.v if n else []})
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry, table,
                                  FIELDS, QgsWkbTypes.Type.LineString, layer.crs(), layer.crs(),
                                  feedback)
        qgis_io.style_output(context, dest, "road_edges.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}
