"""urbansynth:growroads - procedural road growth with street patterns (Scharl 2010, ch. 4.2)."""

import numpy as np
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterPoint,
    QgsProcessingParameterRasterLayer,
    QgsWkbTypes,
)

from ..plugin.core.progress import InputError
from ..plugin.qgis_glue import qgis_io
from ..plugin.roads import growth
from .common import AlgorithmBase

ROAD_FIELDS = [("edge_id", "int"), ("level", "int"), ("road_class", "str"), ("pattern", "str"),
               ("width_m", "float"), ("length_m", "float")]
class GrowRoads(AlgorithmBase):
    GROUP_ID = "synthesis"
    BOUNDARY = "BOUNDARY"
    MAJOR_ROADS = "MAJOR_ROADS"
    GROW_MAJOR = "GROW_MAJOR"
    REMOVE_DEAD_ENDS = "REMOVE_DEAD_ENDS"
    MAJOR_PATTERN = "MAJOR_PATTERN"
    MINOR_PATTERN = "MINOR_PATTERN"
    CENTER = "CENTER"
    MAJOR_SEGMENT_LENGTH = "MAJOR_SEGMENT_LENGTH"
    MINOR_SEGMENT_LENGTH = "MINOR_SEGMENT_LENGTH"
    LENGTH_DEVIATION = "LENGTH_DEVIATION"
    ANGLE_DEVIATION = "ANGLE_DEVIATION"
    BRANCH_PROBABILITY = "BRANCH_PROBABILITY"
    SNAP_DISTANCE = "SNAP_DISTANCE"
    MIN_STREET_DISTANCE = "MIN_STREET_DISTANCE"
    MAJOR_WIDTH = "MAJOR_WIDTH"
    MINOR_WIDTH = "MINOR_WIDTH"
    MAX_SEGMENTS = "MAX_SEGMENTS"
    DEM = "DEM"
    MAX_SLOPE = "MAX_SLOPE"
    OBSTACLES = "OBSTACLES"
    OBSTACLE_RASTER = "OBSTACLE_RASTER"
    DENSITY = "DENSITY"
    SEED = "SEED"
    OUTPUT = "OUTPUT"

    PATTERN_KEYS = list(growth.PATTERNS)  # organic, grid, radial
    #: GrowthSettings names -> parameter names, for the engine's messages
    ENGINE_NAMES = {"major_length": MAJOR_SEGMENT_LENGTH, "minor_length": MINOR_SEGMENT_LENGTH,
                    "snap_distance": SNAP_DISTANCE, "min_street_distance": MIN_STREET_DISTANCE,
                    "max_slope": MAX_SLOPE}

    def name(self):
        return "growroads"

    def displayName(self):  # noqa: N802
        return "Grow roads (procedural patterns)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Grows a street network inside a boundary polygon, procedurally, after Parish & "
            "Müller (2001) and Weber et al. (2009) as described by Scharl (2010, ch. 4.2).\n\n"
            "Major roads grow first over the whole boundary (from the sketched major roads, if "
            "given, else from a seed at the centre or the densest place); then every quarter "
            "(face of the major network, and the outskirts between the major roads and the "
            "boundary) is filled with minor roads. Each level follows its pattern: organic "
            "(random turns, branches at varied angles), grid (main directions, right-angle "
            "branches, regular blocks) or radial (spokes and rings around the centre point).\n\n"
            "Local constraints keep the network clean: streets end at the first road they cross, "
            "snap to nearby junctions, extend to a road just ahead, are clipped to the boundary, "
            "near-parallel duplicates are dropped; with a DEM no grown segment is steeper than "
            "the maximum slope (streets turn to follow the terrain), and no road enters the "
            "obstacles (water, parks). A density raster guides seeds and growth. Pieces of "
            "the network that reach no sketched road (a boundary of several parts apart grows "
            "one in each) are joined by the shortest road that crosses nothing and keeps to "
            "the slope and the obstacles (pattern 'link'): straight where that stays inside "
            "the boundary, else bent along its arm; only where no road inside reaches a piece "
            "(a part of the boundary apart from the rest) does a link leave it, the only road "
            "that does.\n\n"
            "Output: planar roads with level (0 major, 1 minor), road_class, pattern, width_m and "
            "length_m, one straight feature per grown segment, in the boundary's CRS. The same "
            "seed gives the same network."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        d = growth.GrowthSettings()
        patterns = ["Organic", "Grid", "Radial"]
        self.add(QgsProcessingParameterFeatureSource(
            self.BOUNDARY, "Boundary", [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Polygon(s) of the city region: every road is grown inside them (Scharl's mask; "
            "only a 'link' joining parts that lie apart leaves them). Several features are "
            "merged. Without a boundary, roads grow around the sketched "
            "major roads (one major segment length beyond their extent) and the outskirts are "
            "closed by Scharl's bulged convex hull of the major nodes (sec. 4.2.5).")
        self.add(QgsProcessingParameterFeatureSource(
            self.MAJOR_ROADS, "Sketched major roads", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Major roads drawn by hand: clipped to the boundary and kept as they are (level 0, "
            "pattern 'sketch'); growth continues from their dead ends and branches off them.")
        self.add(QgsProcessingParameterBoolean(
            self.REMOVE_DEAD_ENDS, "Remove dead-end roads at the end", defaultValue=True),
            "Scharl Fig. 4.12: grown streets with a free end are pruned until every grown "
            "street ends at a junction (sketched roads stay).", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.GROW_MAJOR, "Grow more major roads", defaultValue=True),
            "Unchecked with sketched major roads: keep only the sketch as the major network and "
            "fill its quarters with minor roads.")
        self.add(QgsProcessingParameterEnum(
            self.MAJOR_PATTERN, "Major road pattern", options=patterns, defaultValue=1),
            "Organic: random turns of up to the angle deviation, branches at 90° ± it. Grid: "
            "main directions from the sketch or the boundary's rectangle, right-angle branches. "
            "Radial: spokes out of the centre point and rings around it.")
        self.add(QgsProcessingParameterEnum(
            self.MINOR_PATTERN, "Minor road pattern", options=patterns, defaultValue=1),
            "Pattern inside the quarters; a grid quarter takes the direction of its own "
            "minimum bounding rectangle.")
        self.add(QgsProcessingParameterPoint(
            self.CENTER, "Centre of the radial pattern", optional=True),
            "Spokes and rings of the radial pattern are around this point; default: the "
            "boundary's centroid. Read in its own CRS ('x,y [EPSG:code]'), else the "
            "project's, else the boundary's; a centre further from the boundary than its "
            "diagonal is refused.")
        self.add(QgsProcessingParameterNumber(
            self.MAJOR_SEGMENT_LENGTH, "Major segment length (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=d.major_length, minValue=5.0,
            maxValue=10000.0),
            "Nominal length of one major road segment: about the side of a quarter.")
        self.add(QgsProcessingParameterNumber(
            self.MINOR_SEGMENT_LENGTH, "Minor segment length (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=d.minor_length, minValue=5.0,
            maxValue=10000.0),
            "Nominal length of one minor road segment: about the side of a city block.")
        self.add(QgsProcessingParameterNumber(
            self.LENGTH_DEVIATION, "Segment length deviation (%)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=100 * d.length_deviation,
            minValue=0.0, maxValue=90.0),
            "Each segment is the nominal length ± up to this share (a fifth of it for grids, "
            "whose blocks stay regular).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.ANGLE_DEVIATION, "Angle deviation (degrees)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=d.angle_deviation, minValue=0.0,
            maxValue=90.0),
            "Largest random turn of an organic street per segment, and of an organic branch "
            "away from 90°. Grid streets deviate at most a tenth of it (2° at most); radial "
            "streets are re-oriented exactly.")
        self.add(QgsProcessingParameterNumber(
            self.BRANCH_PROBABILITY, "Branch probability",
            QgsProcessingParameterNumber.Type.Double, defaultValue=d.branch_probability,
            minValue=0.0, maxValue=1.0),
            "Chance that a new street branches off each side of a street end.")
        self.add(QgsProcessingParameterNumber(
            self.SNAP_DISTANCE, "Snapping distance (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=d.snap_distance, minValue=0.0, maxValue=5000.0),
            "A street end this close to a junction snaps to it, and to a road this close "
            "ahead is extended to it; must be under half the shorter segment length.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_STREET_DISTANCE, "Minimum street distance (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=d.min_street_distance,
            minValue=0.0, maxValue=5000.0),
            "Near-parallel streets closer than this are duplicates: the newer one is dropped.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAJOR_WIDTH, "Major road width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=d.major_width, minValue=0.0, maxValue=200.0),
            "Written to width_m of major roads (used by street surfaces).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MINOR_WIDTH, "Minor road width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=d.minor_width, minValue=0.0, maxValue=200.0),
            "Written to width_m of minor roads.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_SEGMENTS, "Maximum number of segments", QgsProcessingParameterNumber.Type.Integer,
            defaultValue=d.max_segments, minValue=1, maxValue=1000000),
            "Safety cap: growth stops after this many segments (quarters nearest the centre "
            "are filled first).", advanced=True)
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model", optional=True),
            "A DEM in any CRS, resampled bilinearly to the boundary's working CRS: grown "
            "segments steeper than the maximum slope turn (by up to 45°) or are dropped. "
            "Areas without heights count as flat. Heights in metres, or in the unit the raster "
            "declares (band unit or vertical CRS: feet are converted).")
        self.add(QgsProcessingParameterNumber(
            self.MAX_SLOPE, "Maximum slope (%)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=100 * d.max_slope, minValue=0.1, maxValue=100.0),
            "Steepest grade of a grown segment along its length, with a DEM.")
        self.add(QgsProcessingParameterFeatureSource(
            self.OBSTACLES, "Obstacles", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Water, parks, protected land: no grown road enters them; streets are shortened "
            "or turn away.")
        self.add(QgsProcessingParameterRasterLayer(
            self.OBSTACLE_RASTER, "Obstacle raster", optional=True),
            "A raster in any CRS whose cells with a value above 0 are obstacles (a water or "
            "land-use mask); used together with the obstacle polygons.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DENSITY, "Population density", optional=True),
            "Any density raster (normalised by its maximum): the first seed goes to the "
            "densest place near the centre, major roads head for population, and growth, "
            "branching and block size follow density; nothing grows where it is 0.")
        self.add_seed(
            "The same seed and inputs give the same network.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Grown roads", QgsProcessing.SourceType.TypeVectorLine),
            "Roads with level (0 major, 1 minor), road_class, pattern, width_m, length_m.")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        # a boundary given empty is one not given only where a sketch bounds the growth;
        # alone it is refused by its name (it warned 'goes on without Boundary', then failed)
        frame = qgis_io.read_source(
            self, parameters, self.BOUNDARY, context, feedback, kind="polygons", fields=[],
            optional=self.given(parameters, self.MAJOR_ROADS) or
            not self.given(parameters, self.BOUNDARY))
        if frame is None:  # no boundary: the sketch bounds the growth (bulged hull)
            if not self.given(parameters, self.MAJOR_ROADS):
                raise QgsProcessingException(
                    "Give a boundary polygon or sketched major roads: without either there "
                    "is no place to grow roads.")
            frame = qgis_io.read_source(self, parameters, self.MAJOR_ROADS, context, feedback,
                                        kind="lines", fields=[])  # given empty: refused
        boundary = frame.geometry if shapely.get_dimensions(frame.geometry).max() == 2 else None
        label = frame.name
        crs = frame.crs
        settings = growth.GrowthSettings(
            major_pattern=self.PATTERN_KEYS[self.parameterAsEnum(parameters, self.MAJOR_PATTERN,
                                                                 context)],
            minor_pattern=self.PATTERN_KEYS[self.parameterAsEnum(parameters, self.MINOR_PATTERN,
                                                                 context)],
            major_length=self.number(parameters, self.MAJOR_SEGMENT_LENGTH, context),
            minor_length=self.number(parameters, self.MINOR_SEGMENT_LENGTH, context),
            length_deviation=self.number(parameters, self.LENGTH_DEVIATION, context) / 100.0,
            angle_deviation=self.number(parameters, self.ANGLE_DEVIATION, context),
            branch_probability=self.number(parameters, self.BRANCH_PROBABILITY, context),
            snap_distance=self.number(parameters, self.SNAP_DISTANCE, context),
            min_street_distance=self.number(parameters, self.MIN_STREET_DISTANCE, context),
            major_width=self.number(parameters, self.MAJOR_WIDTH, context),
            minor_width=self.number(parameters, self.MINOR_WIDTH, context),
            max_segments=self.number(parameters, self.MAX_SEGMENTS, context),
            max_slope=self.number(parameters, self.MAX_SLOPE, context) / 100.0,
            grow_major=self.parameterAsBoolean(parameters, self.GROW_MAJOR, context),
            remove_dead_ends=self.parameterAsBoolean(parameters, self.REMOVE_DEAD_ENDS, context),
        )
        seed = self.seed(parameters, context)
        try:
            settings = settings.validated()
        except InputError as exc:
            message = str(exc)
            for engine_name, name in self.ENGINE_NAMES.items():  # say it in the toolbox's words
                message = message.replace(engine_name, name)
            raise QgsProcessingException(f"Invalid parameters: {message}.") from exc

        sketch = qgis_io.read_source(self, parameters, self.MAJOR_ROADS, context, feedback,
                                     kind="lines", target_crs=crs, optional=True, fields=[])
        obstacles = qgis_io.read_source(self, parameters, self.OBSTACLES, context, feedback,
                                        kind="polygons", target_crs=crs, optional=True, fields=[])
        bounds = shapely.total_bounds(frame.geometry)
        if boundary is None:  # around the sketch, as the engine grows there
            reach = settings.major_length
            bounds = (bounds[0] - reach, bounds[1] - reach, bounds[2] + reach, bounds[3] + reach)
        center = None
        if parameters.get(self.CENTER) not in (None, ""):
            center = qgis_io.point_parameter(
                self, parameters, self.CENTER, context, crs, frame.source_crs,
                "The centre of the radial pattern", feedback, near=bounds, near_label=label)
        feedback.setProgress(5)
        dem = None
        dem_layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem_layer is not None:
            cell = qgis_io.raster_cell_size(dem_layer, crs, bounds, context, feedback=feedback)
            dem = qgis_io.read_raster(dem_layer, crs, bounds, cell, feedback)
            feedback.pushInfo(f"DEM resampled to {cell:.1f} m cells; maximum slope "
                              f"{100 * settings.max_slope:g} %.")
        density = self._grid(parameters, self.DENSITY, "Density raster", context, crs, bounds)
        grid = self._grid(parameters, self.OBSTACLE_RASTER, "Obstacle raster", context, crs,
                          bounds)
        if grid is not None:
            with np.errstate(invalid="ignore"):
                cells = growth.mask_polygons(np.isfinite(grid.array) & (grid.array > 0),
                                             grid.geotransform)
            feedback.pushInfo(f"Obstacle raster: {len(cells)} obstacle areas.")
            if len(cells):
                obstacles_geoms = cells if obstacles is None else \
                    np.concatenate([obstacles.geometry, cells])
            else:
                obstacles_geoms = None if obstacles is None else obstacles.geometry
        else:
            obstacles_geoms = None if obstacles is None else obstacles.geometry
        feedback.setProgress(10)

        result = qgis_io.run_engine(
            label, growth.grow_roads, boundary, settings=settings,
            major_roads=None if sketch is None else sketch.geometry, center=center, dem=dem,
            obstacles=obstacles_geoms, density=density,
            seed=seed, progress=qgis_io.progress_for(feedback, 10, 90))
        st = result.stats
        feedback.pushInfo(
            f"{st['segments']} segments grown ({st['major_segments']} major, "
            f"{st['minor_segments']} minor) in {st['quarters']} quarters from "
            f"{st['proposals']} proposals in {st['seconds']:.1f} s; output: "
            f"{len(result.geometry)} planar edges.")
        if st.get("dead_ends_removed"):
            feedback.pushInfo(f"{st['dead_ends_removed']} dead-end edges removed at the end.")
        if st.get("links"):
            feedback.pushInfo(f"{st['links']} road(s) added to join pieces of the network "
                              "that reached no sketched road (pattern 'link').")
        if st.get("pieces_apart"):
            feedback.pushWarning(
                f"{st['pieces_apart']} piece(s) of the network stay apart from the rest: no "
                "buildable link (no steeper than the maximum slope, clear of obstacles) "
                "reaches them.")
        if self.parameterAsBoolean(parameters, self.REMOVE_DEAD_ENDS, context) \
                and st.get("dead_ends_left") and not st.get("dead_ends_removed"):
            feedback.pushWarning(
                f"{st['dead_ends_left']} dead ends are kept: removing them would remove every "
                "grown road (the network is all tree, as on steep terrain).")
        if st.get("bulged_hull"):
            feedback.pushInfo("No boundary: the quarters were closed by the bulged convex hull "
                              "of the major nodes.")
        if st["rejected"]:
            feedback.pushInfo("Proposals dropped by the local constraints: " + ", ".join(
                f"{k} {v}" for k, v in st["rejected"].items()) + ".")
        if st["capped"]:
            feedback.pushWarning(f"Growth stopped at the cap of {settings.max_segments} "
                                 f"segments ({self.MAX_SEGMENTS}); outer quarters may be empty.")
        table = result.table()
        table.insert(0, "edge_id", np.arange(1, len(table) + 1))
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry, table,
                                  ROAD_FIELDS, QgsWkbTypes.Type.LineString, frame.source_crs, crs,
                                  feedback)
        qgis_io.style_output(context, dest, "roads_by_level.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    def _grid(self, parameters, name, what, context, crs, bounds):
        """A raster parameter (not heights) on its own cell size over ``bounds``, or None."""
        layer = self.parameterAsRasterLayer(parameters, name, context)
        if layer is None:
            return None
        cell = qgis_io.raster_cell_size(layer, crs, bounds, context)
        try:
            return qgis_io.read_raster(layer, crs, bounds, cell, what=what, heights=False)
        except QgsProcessingException as exc:
            raise QgsProcessingException(
                f"{what} '{layer.name()}' has no value over the boundary or cannot be "
                "reprojected: check that they overlap.") from exc
