"""urbansynth:subdivideparcels - blocks shrunk by their streets and subdivided into parcels."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.parcels import subdivision as parcels
from ..plugin.core.ids import as_numbers
from ..plugin.core.text import counted
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase

#: Block fields that size the Voronoi parcels (Aliaga's a(v) and sigma_b), when present.
PARCEL_SIZE_FIELDS = ("parcel_area", "parcel_area_sd")


class SubdivideParcels(AlgorithmBase):
    GROUP_ID = "synthesis"
    BLOCKS = "BLOCKS"
    ROADS = "ROADS"
    BOUNDARY = "BOUNDARY"
    STREET_WIDTH_FIELD = "STREET_WIDTH_FIELD"
    METHOD = "METHOD"
    MAX_AREA = "MAX_AREA"
    MIN_AREA = "MIN_AREA"
    MIN_WIDTH = "MIN_WIDTH"
    LOT_WIDTH = "LOT_WIDTH"
    IRREGULARITY = "IRREGULARITY"
    STREET_WIDTH = "STREET_WIDTH"
    FORCE_STREET_ACCESS = "FORCE_STREET_ACCESS"
    BUILDINGS = "BUILDINGS"
    SEED = "SEED"
    OUTPUT = "OUTPUT"

    MAX_AREA_LIMIT = 1e7
    #: The most parcels one run makes (about 1 ms each).
    MAX_PARCELS = 200_000
    MAX_WIDTH_LIMIT = 1000.0

    def name(self):
        return "subdivideparcels"

    def displayName(self):  # noqa: N802
        return "Subdivide blocks into parcels"

    def shortHelpString(self):  # noqa: N802
        return (
            "Subdivides city blocks into building parcels (Scharl 2010, ch. 4.2.6). Blocks "
            "come from a block layer (e.g. the output of 'Extract city blocks') or are "
            "extracted from road lines; they are first shrunk by half the street width on "
            "every side (per road with a width field), so parcels stop at the street's edge, "
            "and lose the areas to keep clear (e.g. the street surfaces of 'Tessellate "
            "streets (surfaces and junctions)').\n\n"
            "Recursive (Weber et al. 2009, CityEngine 'Recursive') cuts a lot perpendicular "
            "to its long axis near the middle until it is under the maximum area, never "
            "below the minimum area or width and, with 'Force street access', never cutting "
            "a lot off the street. Skeleton (Vanegas et al. 2012, CityEngine 'Skeleton') "
            "makes strips along each street and cuts them every lot width, so every parcel "
            "has frontage; corner regions go to one street's strip.\n\n"
            "Parcels get block_id, area_m2, frontage_m (length on the street), "
            "has_street_access and Yang et al.'s (2013) quality: p_angle (mean deviation of "
            "the corners from 90°), p_area (minimum bounding rectangle area / area) and "
            "undesirable (p_angle > 15 or p_area > 1.2). Output is in the input layer's CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        # METHOD values in the order of the engine's registry, read when the algorithm is
        # built: methods registered later are appended, so enum indices stay valid
        self.method_keys = list(parcels.method_names())
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks", [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Block polygons outlined by street centrelines, e.g. 'Extract city blocks' "
            "(block_id kept); a hole (a pond, a park) is land kept free, whose edge is no "
            "street. Give either Blocks or Roads.")
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads (instead of blocks)", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Road centrelines: blocks are extracted from them as 'Extract city blocks' does "
            "(OSM lines are filtered to drivable 'highway' classes; a layer without that field "
            "uses every line), and each block is shrunk by the width of its own streets. "
            "Give either Blocks or Roads.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BOUNDARY, "Boundary (its edges are no street)",
            [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Optional polygon(s), e.g. the district outline given to 'Extract city blocks': "
            "block edges on it are no street (no street width, no frontage, no skeleton "
            "strip), so the lots of a block the outline closes front its streets and reach "
            "back to the outline. With Roads, it also closes the faces the roads leave open.")
        self.add(QgsProcessingParameterField(
            self.STREET_WIDTH_FIELD, "Street width field (on roads)",
            parentLayerParameterName=self.ROADS, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "Full street width in metres per road line; roads with an empty value use the "
            "street width below. Only with Roads.")
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Subdivision method",
            options=[parcels.METHODS[k].label for k in self.method_keys], defaultValue=0),
            "Recursive: split lots across their long axis until under the maximum area "
            "(Scharl 4.2.6). Skeleton: strips along every street cut every lot width, every "
            "parcel with street frontage (Vanegas et al. 2012). Voronoi along the OBB axis: one "
            "or two rows of parcels along the block's oriented bounding box, spacing jittered "
            "with a Gaussian, each parcel with street access and at least the minimum width; "
            "parcel size from the blocks' parcel_area field (e.g. the blocks of 'Synthesize "
            "roads by random walks (intersection points)'), else lot width² x 1.5 (Aliaga et "
            "al. 2008, sec. 3.1.2).")
        self.add(QgsProcessingParameterNumber(
            self.MAX_AREA, "Maximum parcel area (m²)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_MAX_AREA, minValue=1.0, maxValue=self.MAX_AREA_LIMIT),
            "Recursive: lots larger than this are split again. Skeleton: lots are made "
            "narrower than the lot width to stay under it (never under the minimum width).")
        self.add(QgsProcessingParameterNumber(
            self.LOT_WIDTH, "Lot width along the street (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_LOT_WIDTH, minValue=parcels.MIN_FRONTAGE,
            maxValue=self.MAX_WIDTH_LIMIT),
            "Skeleton: target frontage of a parcel (Yang et al. 2013 aim at 18 m; at least "
            f"{parcels.MIN_FRONTAGE:g} m, the frontage that counts as street access). Voronoi along "
            "the OBB axis: sets the mean parcel area (lot width² x 1.5) of blocks without a "
            "parcel_area.")
        self.add(QgsProcessingParameterNumber(
            self.IRREGULARITY, "Irregularity (0-1)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_IRREGULARITY, minValue=0.0, maxValue=1.0),
            "0 gives regular lots. Recursive: cuts move up to 25 % of the lot length off the "
            "middle and turn up to 15° off the perpendicular at 1. Skeleton: cuts move up to "
            "40 % of a lot width at 1.")
        self.add(QgsProcessingParameterNumber(
            self.STREET_WIDTH, "Street width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_STREET_WIDTH, minValue=0.0,
            maxValue=self.MAX_WIDTH_LIMIT),
            "Full width of the streets (blocks shrink by half of it on every side); with "
            "Roads and a street width field, the width of roads without a value. 0 keeps "
            "the blocks as they are.")
        self.add_keep_clear("parcel", "Their edges count as street frontage, as the block "
                            "outline does: other land to keep free goes in as block holes.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDINGS, "Buildings to keep whole",
            [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Building footprints already in the blocks (e.g. of 'Synthesize building "
            "footprints'), each to stand on one parcel. Skeleton: a cut across a building "
            "moves to the nearest end of a building that lies in no building (on the party "
            "wall of two that touch), by up to half a lot width and never under the minimum "
            "width. Any method: the lots a building stands on (over 1 m² of it on "
            "each) merge into one parcel, a row of touching buildings across lots merging "
            "them all up to 16 times the maximum parcel area (one building's own lots may "
            "make a larger parcel); a piece of land under the minimum area keeps a parcel "
            "when a building stands on it. Merged parcels may exceed the maximum area.")
        self.add(QgsProcessingParameterBoolean(
            self.FORCE_STREET_ACCESS, "Force street access", defaultValue=True),
            "Recursive: a cut that would leave a lot without street frontage is not made "
            "(the lot stays larger). Any method: lots left without frontage are merged into "
            "a neighbour. Off: recursive makes inner lots (Scharl's deleteInnerLots off).")
        self.add_seed(
            "The same seed gives the same parcels; each block draws its own random numbers, "
            "so a block's parcels do not change when other blocks are added.")
        self.add(QgsProcessingParameterNumber(
            self.MIN_AREA, "Minimum parcel area (m²)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_MIN_AREA, minValue=0.0, maxValue=self.MAX_AREA_LIMIT),
            "No cut makes a parcel smaller; smaller skeleton pieces merge into a neighbour; "
            "pieces of shrunk blocks smaller than this get no parcel.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_WIDTH, "Minimum parcel width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=parcels.DEFAULT_MIN_WIDTH, minValue=0.0, maxValue=self.MAX_WIDTH_LIMIT),
            "No cut makes a parcel narrower (the short side of its minimum bounding "
            "rectangle); land of a shrunk block nowhere this wide (a strip between wide "
            "streets, a roundabout's island) gets no parcel.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Parcels", QgsProcessing.SourceType.TypeVectorPolygon),
            "Parcels with parcel_id, block_id, area_m2, frontage_m, has_street_access, "
            "p_angle, p_area, undesirable and method, styled by Yang's quality.")

    # ----------------------------------------------------------------------- checks

    def input_error(self, parameters, context):
        message = self.blocks_or_roads_error(parameters, "subdivided", "subdivide")
        if message is None and self.given(parameters, self.BLOCKS) \
                and self.given(parameters, self.STREET_WIDTH_FIELD):
            message = "The street width field belongs to Roads; with Blocks use Street width."
        return message

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        message = self.input_error(parameters, context)
        if message:
            raise QgsProcessingException(message)
        method = self.method_keys[self.parameterAsEnum(parameters, self.METHOD, context)]
        number = {name: self.number(parameters, name, context)
                  for name in (self.MAX_AREA, self.MIN_AREA, self.MIN_WIDTH, self.LOT_WIDTH,
                               self.IRREGULARITY, self.STREET_WIDTH)}
        if number[self.MAX_AREA] <= number[self.MIN_AREA]:
            raise QgsProcessingException(
                f"The maximum parcel area ({number[self.MAX_AREA]:g} m²) must be larger than "
                f"the minimum parcel area ({number[self.MIN_AREA]:g} m²).")
        settings = parcels.SubdivisionSettings(
            max_area=number[self.MAX_AREA], min_area=number[self.MIN_AREA],
            min_width=number[self.MIN_WIDTH], lot_width=number[self.LOT_WIDTH],
            irregularity=number[self.IRREGULARITY],
            force_street_access=self.parameterAsBoolean(
                parameters, self.FORCE_STREET_ACCESS, context))
        qgis_io.run_engine("Parameters", settings.validate)
        seed = self.seed(parameters, context)

        size = {}
        if self.given(parameters, self.BLOCKS):
            frame, block_geoms, block_ids, road_lines, road_widths = \
                self._blocks(parameters, context, feedback)
            size = self._parcel_sizes(frame, method, feedback)
            boundary = self._boundary(parameters, context, feedback, frame)
        else:
            frame, block_geoms, block_ids, road_lines, road_widths, boundary = \
                self._blocks_from_roads(parameters, context, feedback)

        keep_clear = self.keep_clear_areas(parameters, context, feedback, frame, block_geoms)
        keep_whole = self.optional_polygons(parameters, self.BUILDINGS, context, feedback,
                                            frame, block_geoms, "buildings kept whole")
        area = float(shapely.area(np.asarray(block_geoms, dtype=object)).sum())
        self.bound_work(f"Blocks {frame.name} ({area / 1e6:,.1f} km²) at a maximum parcel area "
                        f"of {number[self.MAX_AREA]:g} m²", 2 * area / number[self.MAX_AREA],
                        self.MAX_PARCELS, "parcels",
                        "subdivide the blocks in parts, or raise the maximum parcel area")
        result = qgis_io.run_engine(
            frame.name, parcels.subdivide_blocks, block_geoms, method, settings, seed=seed,
            block_ids=block_ids, street_width=number[self.STREET_WIDTH], roads=road_lines,
            road_widths=road_widths, keep_clear=keep_clear, keep_whole=keep_whole,
            boundary=None if boundary is None else boundary.geometry,
            progress=qgis_io.progress_for(feedback, 30, 90), **size)
        for line in parcels.summary(result.stats, method):
            feedback.pushInfo(line)
        if len(result.geometry) == 0:
            clear = keep_clear is not None
            raise QgsProcessingException(
                f"{frame.name}: no parcel: every block is narrower than its streets"
                f"{', covered by the areas to keep clear,' if clear else ''} or smaller than "
                "the minimum parcel area or width (lower the street width or the minimum area "
                f"or width{', or check the areas to keep clear' if clear else ''}).")
        dest = qgis_io.write_sink(
            self, parameters, self.OUTPUT, context, result.geometry, result.table,
            parcels.PARCEL_FIELDS, QgsWkbTypes.Type.Polygon, frame.source_crs, frame.crs, feedback)
        qgis_io.style_output(context, dest, "parcels_by_quality.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    # ----------------------------------------------------------------------- helpers

    def _blocks(self, parameters, context, feedback):
        frame = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback, parts=True,
                                    kind="polygons", fields=["block_id", *PARCEL_SIZE_FIELDS])
        ids = self.block_ids(frame, feedback)
        feedback.pushInfo(f"{counted(len(frame), 'block')} read from {frame.name}; every block edge is "
                          "taken as a street.")
        feedback.setProgress(30)
        return frame, frame.geometry, ids, None, None

    @staticmethod
    def _parcel_sizes(frame, method, feedback) -> dict:
        """The blocks' own parcel_area (and parcel_area_sd) for the engine, when present."""
        if "parcel_area" not in frame.attributes:
            return {}
        size = {}
        for field in PARCEL_SIZE_FIELDS:
            if field not in frame.attributes:
                continue
            raw = pd.Series(np.asarray(frame.attributes[field], dtype=object))
            size[field] = as_numbers(raw)
            # NULL or empty: the default size; a value that is there and no finite number
            # ('x', 'inf') is an input error, not a silent default
            given = raw.notna().to_numpy() & (raw.astype(str).str.strip() != "").to_numpy()
            unreadable = given & ~np.isfinite(size[field])
            if unreadable.any():
                example = raw[unreadable].iloc[0]
                raise QgsProcessingException(
                    f"Layer {frame.name}: {field} is not a finite number in "
                    f"{int(unreadable.sum())} of its blocks (e.g. {example!r}); leave it empty "
                    "(NULL) where a block should take the default parcel size.")
        area = size["parcel_area"]
        bad = np.isfinite(area) & (area <= 0)
        if bad.any():
            raise QgsProcessingException(
                f"Layer {frame.name}: {int(bad.sum())} blocks have a parcel_area that is not "
                "positive.")
        if (size.get("parcel_area_sd", np.zeros(1)) < 0).any():
            raise QgsProcessingException(
                f"Layer {frame.name}: parcel_area_sd must not be negative.")
        n = int(np.isfinite(area).sum())
        if method == "voronoi-obb":
            feedback.pushInfo(f"{n} of {len(area)} blocks have their own parcel_area (the "
                              "others use lot width² x 1.5).")
        else:
            feedback.pushInfo(f"{frame.name} has parcel_area; only the Voronoi method sizes "
                              f"parcels by it ({method} uses the maximum area and lot width).")
        return size

    def _boundary(self, parameters, context, feedback, frame):
        """The optional BOUNDARY in the working CRS of ``frame`` (the blocks or roads)."""
        return qgis_io.read_source(self, parameters, self.BOUNDARY, context, feedback,
                                   kind="polygons", target_crs=frame.crs, optional=True,
                                   fields=[])

    def _blocks_from_roads(self, parameters, context, feedback):
        width_field = self.parameterAsString(parameters, self.STREET_WIDTH_FIELD, context)
        frame, road_class = self.drivable_roads(
            parameters, self.ROADS, context, feedback, fields=[width_field],
            required_fields=[width_field] if width_field else ())
        widths = None
        if width_field:
            widths = as_numbers(frame.attributes[width_field])
            if (widths < 0).any():
                raise QgsProcessingException(
                    f"Layer {frame.name}: {int((widths < 0).sum())} roads have a negative "
                    f"street width in field '{width_field}'.")
            n_missing = int(np.isnan(widths).sum())
            if n_missing:
                feedback.pushInfo(f"{frame.name}: {n_missing} roads have no width in "
                                  f"'{width_field}' and use the street width.")
        boundary = self._boundary(parameters, context, feedback, frame)
        graph, extraction = self.blocks_from_roads(
            frame, road_class, feedback, (5, 30),
            boundary=None if boundary is None else boundary.geometry,
            boundary_name=None if boundary is None else boundary.name)
        road_widths = None if widths is None else widths[graph.source]
        return (frame, extraction.geometry, extraction.table["block_id"].to_numpy(),
                graph.geometry, road_widths, boundary)
