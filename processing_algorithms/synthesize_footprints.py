"""urbansynth:synthesizefootprints - building footprints by example (block transfer, re-synthesis)."""

import numpy as np
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.buildings import footprints
from ..plugin.core.geometry import MIN_BUILDABLE_AREA, MIN_BUILDABLE_WIDTH
from ..plugin.core.text import counted
from ..plugin.qgis_glue import qgis_io
from ..plugin.retrieval import database
from .common import AlgorithmBase


class SynthesizeFootprints(AlgorithmBase):
    GROUP_ID = "synthesis"
    BLOCKS = "BLOCKS"
    ROADS = "ROADS"
    BLOCK_DB = "BLOCK_DB"
    BLOCK_DB_2 = "BLOCK_DB_2"
    STYLE = "STYLE"
    STYLE_FIELD = "STYLE_FIELD"
    METHOD = "METHOD"
    STREET_WIDTH = "STREET_WIDTH"
    SETBACK = "SETBACK"
    SEED = "SEED"
    N_BEST = "N_BEST"
    MIN_EXAMPLE_BUILDINGS = "MIN_EXAMPLE_BUILDINGS"
    OUTPUT = "OUTPUT"
    N_FOOTPRINTS = "N_FOOTPRINTS"

    MAX_WIDTH = 200.0
    MAX_N_BEST = 10

    def name(self):
        return "synthesizefootprints"

    def displayName(self):  # noqa: N802
        return "Synthesize building footprints"

    def shortHelpString(self):  # noqa: N802
        return (
            "Fills city blocks with building footprints taken from example blocks (Hartmann, "
            "thesis ch. 5.1 and 5.2).\n\n"
            "For each target block the most similar block of a block database is retrieved "
            "(prefilter by area, perimeter and aspect ratio to 10 candidates, shape context "
            "with cyclic dynamic time warping on the boundary) and rigidly aligned with it.\n"
            "Transfer copies its footprints: those outside the block are deleted, those "
            "reaching into the street are moved rigidly (position-based relaxation, wall "
            "lengths kept). Re-synthesis warps the example into the block as a guidance map "
            "and composes each street's row anew from the undeformed example buildings "
            "(dynamic programming on 1 m steps): corner buildings stay, buildings are "
            "repeated or left out to fit a longer or shorter street, none is distorted.\n\n"
            "Every footprint lies inside its block and off the road surface (half the street "
            "width from each centreline, plus the setback, and off the areas to keep clear, "
            "e.g. the street surfaces of 'Tessellate streets (surfaces and junctions)'), and "
            f"off land that would get no parcel: pieces nowhere {MIN_BUILDABLE_WIDTH:g} m wide "
            f"(a strip between wide streets) or under {MIN_BUILDABLE_AREA:g} m² (a roundabout's "
            "island). None overlaps another; what "
            "still conflicts is trimmed or dropped. Databases come from 'Build block "
            "database'; a second one mixes styles, chosen per area by STYLE polygons.\n\n"
            "Output: footprints with the example building's height_m, levels and "
            "building_type, source_block and source_building (ids in the database), "
            "block_id, database, method and placement, in the input CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks", [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Target block polygons outlined by street centrelines, e.g. the output of "
            "'Extract city blocks' (its block_id is kept). Give either Blocks or Roads.")
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads (instead of blocks)", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Road centrelines: blocks are extracted from them as 'Extract city blocks' does, "
            "and dead-end streets inside a block stay free of buildings too.")
        self.add(QgsProcessingParameterFile(
            self.BLOCK_DB, "Block database", extension="gpkg"),
            "A GeoPackage written by 'Build block database' (database 1).")
        self.add(QgsProcessingParameterFile(
            self.BLOCK_DB_2, "Second block database", extension="gpkg",
            optional=True),
            "Another city's block database (database 2), to mix two styles.")
        self.add(QgsProcessingParameterFeatureSource(
            self.STYLE, "Style polygons", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Polygons saying which database to use where (a block uses the polygon holding a "
            "point inside it; database 1 elsewhere). Without them each block takes the best "
            "match of all databases.")
        self.add(QgsProcessingParameterField(
            self.STYLE_FIELD, "Style field (database number)", defaultValue="database",
            parentLayerParameterName=self.STYLE, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "Integer field of the style polygons: 1 = the first database, 2 = the second.")
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=["Block layout transfer (ch. 5.1)",
                                            "Guided re-synthesis (ch. 5.2)"], defaultValue=0),
            "Transfer copies the aligned example layout; re-synthesis re-composes it along "
            "each street from the example's buildings, so it adapts to blocks of a "
            "different size.")
        self.add(QgsProcessingParameterNumber(
            self.STREET_WIDTH, "Street width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=footprints.STREET_WIDTH, minValue=0.0, maxValue=self.MAX_WIDTH),
            "Full width of the road surface: no footprint comes closer than half of it to a "
            "centreline (block boundary). 0 builds up to the block outline.")
        self.add(QgsProcessingParameterNumber(
            self.SETBACK, "Setback (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.0, minValue=0.0, maxValue=self.MAX_WIDTH),
            "Extra distance between the road surface and the footprints.")
        self.add_keep_clear("footprint", "The setback is kept from them too.")
        self.add_seed(
            "With N best > 1 each block picks one of its best matches at random; the same "
            "seed gives the same footprints, block by block.")
        self.add(QgsProcessingParameterNumber(
            self.N_BEST, "Random choice among the N best matches",
            QgsProcessingParameterNumber.Type.Integer, defaultValue=1, minValue=1,
            maxValue=self.MAX_N_BEST),
            "1 always takes the best-matching example block; larger values add variety.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_EXAMPLE_BUILDINGS, "Minimum footprints of an example block",
            QgsProcessingParameterNumber.Type.Integer, defaultValue=1, minValue=0, maxValue=10000),
            "Example blocks with fewer footprints are never retrieved (in an OSM extract, "
            "empty blocks are mostly artefacts of the clip). 0 lets empty blocks stay empty.",
            advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Footprints", QgsProcessing.SourceType.TypeVectorPolygon),
            "Footprints with block_id, height_m, levels, building_type, source_block and "
            "source_building (the example block and building in the database), database "
            "(its name), method and placement: 'copied' or 'moved' (off the street) by "
            "transfer; 'fixed', 'repeatable' or 'interior' (the kind of element along the "
            "street) by re-synthesis; 'filled' where empty street frontage was built up; "
            "any of them followed by ', trimmed' when cut back to the buildable land. Styled "
            "by height.")
        self.addOutput(QgsProcessingOutputNumber(self.N_FOOTPRINTS, "Number of footprints"))

    # ----------------------------------------------------------------------- checks

    def input_error(self, parameters, context):
        return self.blocks_or_roads_error(parameters, "filled", "fill")

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        message = self.input_error(parameters, context)
        if message:
            raise QgsProcessingException(message)
        method = footprints.METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        street_width = self.number(parameters, self.STREET_WIDTH, context)
        setback = self.number(parameters, self.SETBACK, context)
        seed = self.seed(parameters, context)
        n_best = self.number(parameters, self.N_BEST, context)
        min_b = self.number(parameters, self.MIN_EXAMPLE_BUILDINGS, context)
        examples = self._databases(parameters, context, feedback, min_b)
        feedback.setProgress(5)

        if self.given(parameters, self.BLOCKS):
            frame, block_geoms, block_ids, road_lines = self._blocks(parameters, context,
                                                                     feedback)
        else:
            frame, block_geoms, block_ids, road_lines = self._blocks_from_roads(
                parameters, context, feedback)
        choice = self._style(parameters, context, feedback, frame, block_geoms, len(examples))
        keep_clear = self.keep_clear_areas(parameters, context, feedback, frame, block_geoms)
        feedback.setProgress(15)

        result = qgis_io.run_engine(
            frame.name, footprints.synthesize_footprints, block_geoms, examples, method,
            street_width=street_width, setback=setback, seed=seed, roads=road_lines,
            block_database=choice, block_ids=block_ids, n_best=n_best, keep_clear=keep_clear,
            progress=qgis_io.progress_for(feedback, 15, 92))
        self._log(result, method, feedback)
        dest = qgis_io.write_sink(
            self, parameters, self.OUTPUT, context, result.geometry, result.table,
            footprints.OUTPUT_FIELDS, QgsWkbTypes.Type.Polygon, frame.source_crs, frame.crs,
            feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest, self.N_FOOTPRINTS: len(result.geometry)}

    # ----------------------------------------------------------------------- helpers

    def _databases(self, parameters, context, feedback, min_buildings):
        paths, names = self.database_paths(parameters, context, self.BLOCK_DB, self.BLOCK_DB_2,
                                           "block")
        examples = []
        for k, (p, n) in enumerate(zip(paths, names)):
            label = f"Block database {k + 1} ({p})"
            db = qgis_io.run_engine(label, database.load_block_database, p)
            ex = qgis_io.run_engine(label, footprints.prepare_examples, db, n, min_buildings)
            feedback.pushInfo(f"database {k + 1} '{n}': {counted(len(db), 'block')}, "
                              f"{counted(len(db.buildings), 'footprint')}, "
                              f"{counted(len(ex.usable), 'block')} with at least "
                              f"{counted(min_buildings, 'footprint')} retrievable.")
            examples.append(ex)
        return examples

    def _blocks(self, parameters, context, feedback):
        # each part of a multi-part feature is a block: repaired whole, the parts of a
        # collected layer merged across the streets between them
        frame = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                    kind="polygons", fields=["block_id"], parts=True)
        ids = self.block_ids(frame, feedback)
        feedback.pushInfo(f"{counted(len(frame), 'block')} read from {frame.name}; every block edge is "
                          "taken as a street centreline.")
        return frame, frame.geometry, ids, None

    def _blocks_from_roads(self, parameters, context, feedback):
        frame, road_class = self.drivable_roads(parameters, self.ROADS, context, feedback)
        graph, extraction = self.blocks_from_roads(frame, road_class, feedback, (5, 15))
        return (frame, extraction.geometry, extraction.table["block_id"].to_numpy(),
                graph.geometry)

    def _style(self, parameters, context, feedback, frame, block_geoms, n_db):
        """Per block, the database index (-1: the best match of all)."""
        style = self.style_databases(parameters, context, feedback, frame.crs, n_db)
        if style is None:
            return None
        style_polygons, style_database = style
        points = shapely.point_on_surface(np.asarray(block_geoms, dtype=object))
        hit_block, hit_poly = shapely.STRtree(style_polygons).query(points, predicate="within")
        choice = np.zeros(len(points), dtype=np.int64)        # database 1 elsewhere
        choice[hit_block] = style_database[hit_poly]
        feedback.pushInfo(f"Style polygons: {int(np.bincount(choice, minlength=n_db)[-1])} of "
                          f"{len(choice)} blocks use database {n_db}.")
        return choice

    @staticmethod
    def _log(result, method, feedback):
        s = result.blocks
        filled = int((s.n_placed > 0).sum()) if len(s) else 0
        feedback.pushInfo(
            f"{counted(len(result.geometry), 'footprint')} ({method}) in {filled} of "
            f"{counted(len(s), 'block')}, "
            f"{result.seconds:.1f} s.")
        if len(s):
            if int(s.example.isna().sum()):
                feedback.pushInfo(f"{counted(s.example.isna().sum(), 'block')} got no example "
                                  "(too small once the street width and the areas kept clear are taken off, or "
                                  "larger than a district).")
            if s.example.notna().any():
                feedback.pushInfo(
                    f"{counted(s.n_deleted.sum(), 'example footprint')} outside their block "
                    f"deleted, {int(s.n_conflicted.sum())} moved off the street, "
                    f"{int(s.n_trimmed.sum())} trimmed and {int(s.n_dropped.sum())} dropped to "
                    "keep footprints apart and off the road surface.")
        if len(result.geometry) == 0:
            # an empty layer is no result a user should find only by opening it
            feedback.pushWarning(
                "No footprint was made: " + ("every block got no example (see above): lower "
                "the street width, the setback or the areas kept clear, or give larger blocks."
                if len(s) and s.example.isna().all() else "no example footprint stayed inside "
                "its block and off the road surface (see the counts above)."))
