"""urbansynth:synthesizeaerialimage - an aerial image of new parcels from an example image."""
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
)

from ..plugin.imagery import aerial_image
from ..plugin.qgis_glue import qgis_io
from ..plugin.core.text import counted
from .common import AlgorithmBase


class SynthesizeAerialImage(AlgorithmBase):
    GROUP_ID = "synthesis"
    PARCELS = "PARCELS"
    ROADS = "ROADS"
    EXAMPLE_IMAGE = "EXAMPLE_IMAGE"
    EXAMPLE_PARCELS = "EXAMPLE_PARCELS"
    EXAMPLE_ROADS = "EXAMPLE_ROADS"
    PIXEL_SIZE = "PIXEL_SIZE"
    ROAD_WIDTH = "ROAD_WIDTH"
    EXAMPLE_ROAD_WIDTH = "EXAMPLE_ROAD_WIDTH"
    MAX_STRETCH = "MAX_STRETCH"
    SCANLINES = "SCANLINES"
    SEED = "SEED"
    OUTPUT_IMAGE = "OUTPUT_IMAGE"

    #: the example image is read at its own resolution, but at most this many pixels a side
    #: (what cv2.remap can address)
    MAX_EXAMPLE_PIXELS = 30000

    def name(self):
        return "synthesizeaerialimage"

    def displayName(self):  # noqa: N802
        return "Synthesize aerial image of parcels (Aliaga et al. 2008)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Renders an aerial-view image of new parcels from an example's aerial image "
            "(Aliaga, Vanegas & Benes 2008, sec. 3.2). Each new parcel gets the pixels of the "
            "example parcel whose oriented bounding box is most similar in area and aspect "
            "ratio and that faces the street with the same (long or short) side, warped "
            "through the paper's grid of scanlines across the main axis. New roads are "
            "painted from the example's road pixels along and across the roads.\n\n"
            "Parcels without an example parcel within the largest stretch stay transparent "
            "and are counted in the log. The output is a GeoTIFF in the parcels' CRS with "
            "the example's bands, an alpha band and overviews; it covers the parcels and the "
            "new roads (those far beyond the parcels are left out where the image would "
            "otherwise be too large)."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.PARCELS, "New parcels", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "The parcels to render, e.g. the output of 'Subdivide blocks into parcels'. The "
            "image is in their CRS.")
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "New roads", [QgsProcessing.SourceType.TypeVectorLine], optional=True),
            "Centrelines of the new streets: painted from the example's roads, and used to "
            "find each parcel's street side (without them: the outline of all parcels).")
        self.add(QgsProcessingParameterRasterLayer(
            self.EXAMPLE_IMAGE, "Example aerial image"),
            "A georeferenced aerial or satellite image of the example (RGB, grey or more "
            "bands, any CRS); read at its own resolution over the example parcels.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_PARCELS, "Example parcels (or blocks)", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "The example's parcels (a cadastre) or blocks on the image; those not wholly on "
            "the image are not used.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_ROADS, "Example roads", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Centrelines of the example's streets on the image: their pixels paint the new "
            "roads, and they give each example parcel's street side.")
        self.add(QgsProcessingParameterNumber(
            self.PIXEL_SIZE, "Pixel size (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.5, minValue=0.01, maxValue=100.0),
            "Ground size of an output pixel.")
        self.add(QgsProcessingParameterNumber(
            self.ROAD_WIDTH, "New road width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=12.0, minValue=0.0, maxValue=200.0),
            "Full width of the painted new roads (0: roads are not painted).")
        self.add(QgsProcessingParameterNumber(
            self.EXAMPLE_ROAD_WIDTH, "Example road width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=8.0, minValue=0.1, maxValue=200.0),
            "Full width of the example's roads on the image.")
        self.add_seed(
            "Among the nearly best example parcels one is drawn per parcel (against "
            "repetition), and an example road per new road: the same seed, the same image.")
        self.add(QgsProcessingParameterNumber(
            self.MAX_STRETCH, "Largest stretch", QgsProcessingParameterNumber.Type.Double,
            defaultValue=2.0, minValue=1.0, maxValue=100.0),
            "An example parcel is a good match when neither side of its bounding box must be "
            "stretched or shrunk by more than this factor.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.SCANLINES, "Scanlines per parcel (s)", QgsProcessingParameterNumber.Type.Integer,
            defaultValue=32, minValue=2, maxValue=1000),
            "The paper's s: scanlines across each parcel's main axis that carry the warp.",
            advanced=True)
        self.add(QgsProcessingParameterRasterDestination(
            self.OUTPUT_IMAGE, "Aerial image"),
            "GeoTIFF with the example's bands, an alpha band and overviews.")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        image_layer = self.parameterAsRasterLayer(parameters, self.EXAMPLE_IMAGE, context)
        if image_layer is None:
            raise QgsProcessingException("The example image could not be loaded.")
        settings = aerial_image.ImageSettings(
            pixel_size=self.number(parameters, self.PIXEL_SIZE, context),
            road_width=self.number(parameters, self.ROAD_WIDTH, context),
            example_road_width=self.number(parameters, self.EXAMPLE_ROAD_WIDTH, context),
            max_stretch=self.number(parameters, self.MAX_STRETCH, context),
            scanlines=self.number(parameters, self.SCANLINES, context))
        seed = self.seed(parameters, context)
        target = qgis_io.read_source(self, parameters, self.PARCELS, context, feedback,
                                     kind="polygons", fields=[], progress_range=(0, 5))
        roads = qgis_io.read_source(self, parameters, self.ROADS, context, feedback,
                                    kind="lines", target_crs=target.crs, optional=True,
                                    fields=[], progress_range=(5, 10))
        example = qgis_io.read_source(self, parameters, self.EXAMPLE_PARCELS, context, feedback,
                                      kind="polygons", fields=[], progress_range=(10, 15))
        example_roads = qgis_io.read_source(
            self, parameters, self.EXAMPLE_ROADS, context, feedback, kind="lines",
            target_crs=example.crs, optional=True, fields=[], progress_range=(15, 20))
        bounds = shapely.total_bounds(example.geometry)
        margin = 2.0 * settings.example_road_width
        bounds = (bounds[0] - margin, bounds[1] - margin, bounds[2] + margin, bounds[3] + margin)
        cell = qgis_io.raster_cell_size(image_layer, example.crs, bounds, context,
                                        max_cells=self.MAX_EXAMPLE_PIXELS, min_cell=0.0)
        image = qgis_io.read_image(image_layer, example.crs, bounds, cell, "Example image")
        feedback.pushInfo(f"Example image '{image_layer.name()}' read at {cell:.2f} m per pixel "
                          f"({image.shape[1]} x {image.shape[0]} pixels, "
                          f"{counted(image.array.shape[2], 'band')}).")
        feedback.setProgress(25)

        result = qgis_io.run_engine(
            target.name, aerial_image.synthesize_image, image, example.geometry,
            target.geometry, roads=None if roads is None else roads.geometry,
            example_roads=None if example_roads is None else example_roads.geometry,
            settings=settings, seed=seed, progress=qgis_io.progress_for(feedback, 25, 90))
        self._log(result.stats, feedback, roads is not None, example_roads is not None,
                  settings.max_stretch)
        path = self.parameterAsOutputLayer(parameters, self.OUTPUT_IMAGE, context)
        qgis_io.write_image(path, result.image, result.alpha, target.crs, target.source_crs)
        feedback.setProgress(100)
        return {self.OUTPUT_IMAGE: path}

    @staticmethod
    def _log(stats, feedback, with_roads: bool, with_example_roads: bool, max_stretch=None):
        if not stats["n_matched"]:
            feedback.pushWarning(
                f"None of the {counted(stats['n_parcels'], 'parcel')} has an example parcel "
                f"of a similar size and shape facing the street alike within the largest "
                f"stretch ({max_stretch:g}): every parcel is transparent. Raise MAX_STRETCH, "
                "or give example parcels nearer the new ones in size and shape.")
        else:
            feedback.pushInfo(
                f"{stats['n_matched']} of {counted(stats['n_parcels'], 'parcel')} filled from "
                f"{stats['n_example_used']} of "
                f"{counted(stats['n_example_on_image'], 'example parcel')} on the "
                f"image (median stretch {stats['median_stretch']:.2f}).")
        if stats["n_unmatched"] and stats["n_matched"]:
            feedback.pushInfo(
                f"{counted(stats['n_unmatched'], 'parcel')}: no example parcel of a similar "
                "size and shape facing the street alike (within the largest stretch); left "
                "transparent.")
        skipped = stats["n_example_parcels"] - stats["n_example_on_image"]
        if skipped:
            feedback.pushInfo(f"{counted(skipped, 'example parcel')} not wholly on the image: "
                              "not used.")
        if stats["roads_painted"]:
            feedback.pushInfo(f"{stats['n_road_pixels']} road pixels painted from the example "
                              "roads.")
        if stats.get("n_roads_beyond"):
            feedback.pushWarning(
                f"The new roads reach so far beyond the parcels that an image of them all "
                f"would be too large: it covers the parcels, and "
                f"{counted(stats['n_roads_beyond'], 'road')} farther than a road width from "
                "them are left out.")
        if not stats["roads_painted"] and with_roads:
            feedback.pushInfo("The new roads are not painted: "
                              + ("no example road lies on the image." if with_example_roads
                                 else "give the example's roads (EXAMPLE_ROADS)."))
        feedback.pushInfo(f"Image of {stats['cols']} x {stats['rows']} pixels.")
