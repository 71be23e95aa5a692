"""urbansynth:synthesizeroadsfromfragments - hierarchical road synthesis from fragment databases."""

import numpy as np
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsWkbTypes,
)

from ..plugin.qgis_glue import qgis_io
from ..plugin.retrieval import database
from ..plugin.roads import from_fragments as synthesis_fragments
from .common import AlgorithmBase, fill_quantile_parameter


class SynthesizeRoadsFromFragments(AlgorithmBase):
    GROUP_ID = "synthesis"
    ARTERIALS = "ARTERIALS"
    BOUNDARY = "BOUNDARY"
    FILL = "FILL"
    FILL_QUANTILE = "FILL_QUANTILE"
    FRAGMENT_DB = "FRAGMENT_DB"
    FRAGMENT_DB_2 = "FRAGMENT_DB_2"
    DEM = "DEM"
    STYLE = "STYLE"
    STYLE_FIELD = "STYLE_FIELD"
    N_BEST = "N_BEST"
    MAX_LEVEL = "MAX_LEVEL"
    SEED = "SEED"
    GAMMA = "GAMMA"
    DEM_CELL_SIZE = "DEM_CELL_SIZE"
    OUTPUT = "OUTPUT"
    OUTPUT_DEM = "OUTPUT_DEM"
    N_EDGES = "N_EDGES"
    N_INSERTED = "N_INSERTED"

    #: The largest district one run fills (the fragment search takes about 2-3 s per km²).
    MAX_AREA_KM2 = 50.0

    def name(self):
        return "synthesizeroadsfromfragments"

    def displayName(self):  # noqa: N802
        return "Synthesize roads from fragments"

    def shortHelpString(self):  # noqa: N802
        return (
            "Fills sketched arterial roads with streets taken from real example cities, level "
            "by level (Hartmann, thesis ch. 4.1).\n\n"
            "The closed faces of the arterials are the level 0 query fragments. For each, a "
            "fragment of the same level with a similar boundary shape (scale-aware shape "
            "context with cyclic dynamic time warping) and, with a DEM, similar slopes is "
            "retrieved from a fragment database; one of the N best is chosen at random and its "
            "interior streets are warped into the face with mean value coordinates. The new "
            "faces are then filled with the next level's fragments, until the databases have no "
            "deeper level. A warp that would put junctions outside a very concave face is "
            "replaced by a simple split of the face.\n\n"
            "With a BOUNDARY (the target area), the arterials are clipped to it and its outline "
            "closes the faces they leave open; the outline itself is no street. With FILL (on "
            "by default), no face larger than the example's p90 block area stays empty: it gets "
            "a fragment of any level at scale, else is split along a scaled fragment's streets, "
            "else by a street that cuts off a piece of the example's block size; the log counts "
            "each way. Pieces that reach only the boundary are linked to the arterials by the "
            "shortest street that crosses nothing, bent along the boundary where a straight "
            "one would leave it (a hamlet at the end of a narrow arm).\n\n"
            "Databases come from 'Build fragment database'. A second database mixes two "
            "styles: without style polygons the best-matching fragments of both compete, with "
            "STYLE polygons the field STYLE_FIELD (1 or 2) says which database to use inside "
            "each polygon. With a DEM the slope term steers the choice and OUTPUT_DEM receives "
            "the relief of the inserted fragments merged into the DEM by a Poisson solve "
            "(GeoTIFF in the metric working CRS).\n\n"
            "Output: one planar road network with level (0 = arterial), source_fragment "
            "('<database>:<fragment id>', 'arterial', 'procedural', 'statistics' for a split "
            "from the example's block sizes, 'link' joining a piece to the arterials, 'close' "
            "and 'cul-de-sac' where the dead-end share was steered to the example's, recorded "
            "in the database) and database."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.ARTERIALS, "Arterial roads", [QgsProcessing.SourceType.TypeVectorLine]),
            "Sketched arterials, or the level 0 roads of a real city: lines that close faces to "
            "fill. They are noded and cleaned first. With OSM classes (a 'highway' field or "
            "tag, or the road_class of 'Extract road hierarchy'), a new street ends on no "
            "motorway or trunk away from its junctions: it ends short of it, or goes where its "
            "other end is a junction.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BOUNDARY, "Target boundary", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "The area to fill (e.g. a town's outline): closes the faces the arterials leave "
            "open. Without it only the faces the arterials close are filled.")
        self.add(QgsProcessingParameterBoolean(
            self.FILL, "Fill every face down to the example's block sizes", defaultValue=True),
            "No face larger than the example's p90 block area stays empty (fragments of any "
            "level, scaled fragments, then splits from the example's block dimensions). Off: "
            "the thesis's Function 2 alone, which keeps a face empty when its match is a block.",
            advanced=True)
        self.add(fill_quantile_parameter(self.FILL_QUANTILE),
            "Faces larger than this quantile of the example's block areas are filled (90: the "
            "p90). A city whose large blocks are parks or yards (Helsinki) keeps them empty "
            "with a higher value.", advanced=True)
        self.add(QgsProcessingParameterFile(
            self.FRAGMENT_DB, "Fragment database", extension="gpkg"),
            "A GeoPackage written by 'Build fragment database' (database 1).")
        self.add(QgsProcessingParameterFile(
            self.FRAGMENT_DB_2, "Second fragment database", extension="gpkg",
            optional=True),
            "Another city's fragment database (database 2), to mix two styles.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model", optional=True),
            "The desired terrain: adds the slope term to the retrieval and is the base of "
            "OUTPUT_DEM.")
        self.add(QgsProcessingParameterFeatureSource(
            self.STYLE, "Style polygons", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Polygons saying which database to use where (a face uses the polygon holding a "
            "point inside it; database 1 elsewhere).")
        self.add(QgsProcessingParameterField(
            self.STYLE_FIELD, "Style field (database number)", defaultValue="database",
            parentLayerParameterName=self.STYLE, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "Integer field of the style polygons: 1 = the first database, 2 = the second.")
        self.add(QgsProcessingParameterNumber(
            self.N_BEST, "Random choice among the N best matches",
            QgsProcessingParameterNumber.Type.Integer, defaultValue=3, minValue=1,
            maxValue=synthesis_fragments.MAX_N_BEST),
            "1 always takes the best-matching fragment; larger values add variety.")
        self.add(QgsProcessingParameterNumber(
            self.MAX_LEVEL, "Deepest street level", QgsProcessingParameterNumber.Type.Integer,
            optional=True, minValue=1, maxValue=synthesis_fragments.MAX_LEVELS),
            "Stop after synthesizing streets of this level (default: as deep as the databases go). "
            "With it the fill and the dead-end steering are off: a network of these levels "
            "only, whose faces may stay larger than the example's blocks.")
        self.add_seed(
            "The same seed with the same inputs gives the same network.")
        self.add(QgsProcessingParameterNumber(
            self.GAMMA, "Shape weight gamma", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.5, minValue=0.0, maxValue=1.0),
            "Weight of the shape cost against the slope cost (thesis eq. 4.2); 1 ignores the "
            "terrain.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.DEM_CELL_SIZE, "DEM cell size (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=5.0, minValue=0.5, maxValue=100.0),
            "The DEM is resampled to this cell size in the metric working CRS.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Synthesized roads", QgsProcessing.SourceType.TypeVectorLine),
            "The road network with level, source_fragment and database per edge.")
        dem_out = QgsProcessingParameterRasterDestination(
            self.OUTPUT_DEM, "Synthesized relief", optional=True, createByDefault=False)
        self.add(dem_out, "The DEM with the relief of the inserted fragments merged in "
                          "(needs a DEM and a database built with one).")
        self.addOutput(QgsProcessingOutputNumber(self.N_EDGES, "Number of road edges"))
        self.addOutput(QgsProcessingOutputNumber(
            self.N_INSERTED, "Fragments inserted (by level and by the fill)"))

    def _databases(self, parameters, context):
        paths, names = self.database_paths(parameters, context, self.FRAGMENT_DB,
                                           self.FRAGMENT_DB_2, "fragment")
        dbs = [qgis_io.run_engine(f"Fragment database {k + 1}", database.load_fragment_database,
                                  p) for k, p in enumerate(paths)]
        for k, d in enumerate(dbs):
            if len(d) == 0:
                raise QgsProcessingException(f"Fragment database {k + 1} ({paths[k]}) holds no "
                                             "fragment.")
        return dbs, names

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        frame = qgis_io.read_source(self, parameters, self.ARTERIALS, context, feedback,
                                    kind="lines", fields=list(qgis_io.ROAD_CLASS_FIELDS))
        label = frame.name
        bound_district(self, frame)
        n_best = self.number(parameters, self.N_BEST, context)
        max_level = self.number(parameters, self.MAX_LEVEL, context)
        if max_level is not None and self.parameterAsBool(parameters, self.FILL, context):
            feedback.pushInfo(f"MAX_LEVEL {max_level}: the fill and the dead-end steering are "
                              "off (streets of levels 1 to it only; faces larger than the "
                              "example's blocks may stay empty).")
        seed = self.seed(parameters, context)
        gamma = self.number(parameters, self.GAMMA, context)
        cell = self.number(parameters, self.DEM_CELL_SIZE, context)
        dem_out = self.parameterAsOutputLayer(parameters, self.OUTPUT_DEM, context) \
            if parameters.get(self.OUTPUT_DEM) else ""
        dbs, names = self._databases(parameters, context)
        feedback.pushInfo("; ".join(f"database {k + 1} '{n}': {len(d)} fragments, levels "
                                    f"{', '.join(str(int(v)) for v in np.unique(d.levels))}"
                                    + (", with relief" if d.relief is not None else "")
                                    for k, (n, d) in enumerate(zip(names, dbs))))
        feedback.setProgress(5)

        style_polys = style_db = None
        style = self.style_databases(parameters, context, feedback, frame.crs, len(dbs))
        if style is not None:
            style_polys, style_db = style
        feedback.setProgress(8)

        dem = None
        dem_layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem_layer is not None:
            dem = qgis_io.read_raster(dem_layer, frame.crs, shapely.total_bounds(frame.geometry), cell,
                           feedback)
        elif dem_out:
            raise QgsProcessingException("OUTPUT_DEM needs an elevation model (DEM) to merge the "
                                         "fragments' relief into.")
        feedback.setProgress(12)

        boundary = None
        boundary_frame = qgis_io.read_source(self, parameters, self.BOUNDARY, context,
                                             feedback, kind="polygons", target_crs=frame.crs,
                                             fields=[], optional=True)
        if boundary_frame is not None:
            boundary = boundary_frame.geometry
            self.require_roads_reach(frame, boundary, f"the boundary {boundary_frame.name}")
        result = qgis_io.run_engine(
            label, synthesis_fragments.synthesize, frame.geometry, dbs, dem=dem,
            style_polygons=style_polys, style_database=style_db, n_best=n_best, seed=seed,
            max_level=max_level, gamma=gamma, names=names, boundary=boundary,
            fill=self.parameterAsBool(parameters, self.FILL, context),
            fill_quantile=self.number(parameters, self.FILL_QUANTILE, context),
            progress=qgis_io.progress_for(feedback, 12, 92),
            # motorways and trunks among them take no new junction
            arterial_class=qgis_io.road_classes(frame)[0])
        q = result.queries
        n_inserted = int((q.outcome == "fragment").sum())
        n_split = int((q.outcome == "procedural").sum())
        n_block = int((q.outcome == "block").sum())
        n_fill = int(q.outcome.str.startswith("fill_").sum())
        # the fill stage inserts example fragments too (at scale or scaled)
        n_fill_fragments = int(q.outcome.isin(["fill_fragment", "fill_scaled"]).sum())
        n_rest = len(q) - n_inserted - n_split - n_block - n_fill  # each query one outcome
        feedback.pushInfo(
            f"{len(q)} query fragments: {n_inserted} filled from examples, "
            f"{n_split} split procedurally, {n_block} kept as blocks, "
            f"{n_fill} filled by the fill stage, {n_rest} left as they are (too small, or no "
            "fragment or split fits); "
            f"{len(result.geometry)} road edges over {result.stats['area_km2']:.3f} km² in "
            f"{result.stats['seconds']:.1f} s.")

        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry,
                                  result.table, synthesis_fragments.EDGE_FIELDS,
                                  QgsWkbTypes.Type.LineString, frame.source_crs, frame.crs, feedback)
        qgis_io.style_output(context, dest, "roads_by_level.qml")
        outputs = {self.OUTPUT: dest, self.N_EDGES: len(result.geometry),
                   self.N_INSERTED: n_inserted + n_fill_fragments}
        if dem_out:
            if not any(d.relief is not None for d in dbs):
                feedback.pushInfo("No database has relief: OUTPUT_DEM is the input DEM resampled.")
            qgis_io.write_geotiff(dem_out, result.dem, frame.crs.toWkt(), "The merged relief")
            outputs[self.OUTPUT_DEM] = dem_out
        feedback.setProgress(100)
        return outputs


def bound_district(alg, arterials):
    """The fragment synthesis' work limit, one home: the convex hull of the ``arterials`` (a
    Frame in the working CRS) up to MAX_AREA_KM2. Checked by this tool and, before it builds
    a fragment database from the example (seconds to minutes on a large one), by
    'Synthesize roads (choose the method)'."""
    hull = shapely.area(shapely.convex_hull(shapely.union_all(arterials.geometry))) / 1e6
    alg.bound_work(f"Arterials {arterials.name} (convex hull {hull:,.1f} km²)", hull,
                   SynthesizeRoadsFromFragments.MAX_AREA_KM2, "km² of district",
                   "split the arterials into districts and run them one by one")
