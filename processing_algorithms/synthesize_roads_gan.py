"""urbansynth:synthesizeroadsgan - StreetGAN road networks (Hartmann thesis ch. 4.2)."""
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterExtent,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsWkbTypes,
)

from ..plugin.network import crossings
from ..plugin.network import edge_streets
from ..plugin.network import street_graph as roads
from ..plugin.qgis_glue import qgis_io
from ..plugin.retrieval.shape_context import DemGrid
from ..plugin.roads import streetgan
from .common import AlgorithmBase, drivable_lines

#: The shipped generator used unless another is chosen: trained on the most towns.
DEFAULT_MODEL = "streetgan_towns"
ROAD_FIELDS = [("edge_id", "int"), ("level", "int"), ("road_class", "str"), ("length_m", "float"),
               ("model", "str"), ("seed", "int")]


class SynthesizeRoadsGan(AlgorithmBase):
    GROUP_ID = "synthesis"
    TARGET = "TARGET"
    EXTENT = "EXTENT"
    GIVEN_ROADS = "GIVEN_ROADS"
    MODEL = "MODEL"
    MODEL_FILE = "MODEL_FILE"
    SEED = "SEED"
    CELL_SIZE = "CELL_SIZE"
    MAX_GAP = "MAX_GAP"
    MIN_DEAD_END = "MIN_DEAD_END"
    FROM_EDGE = "FROM_EDGE"
    DEAD_END_SHARE = "DEAD_END_SHARE"
    MIN_BLOCK_AREA = "MIN_BLOCK_AREA"
    MEDIAN_BLOCK_AREA = "MEDIAN_BLOCK_AREA"
    CROSSING_SHARE = "CROSSING_SHARE"
    EDGE_JOIN = "EDGE_JOIN"
    OUTPUT = "OUTPUT"
    OUTPUT_RASTER = "OUTPUT_RASTER"

    def __init__(self):
        super().__init__()
        self.models = streetgan.shipped_models()

    def name(self):
        return "synthesizeroadsgan"

    def displayName(self):  # noqa: N802
        return "Synthesize roads (StreetGAN)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Generates a road network over a target polygon or extent with a trained StreetGAN "
            "generator (Hartmann thesis ch. 4.2): a fully convolutional spatial GAN turns a "
            "field of random noise into a road image of any size (3 m per pixel; large areas "
            "run in tiles that stitch without seams), and the image is turned into a clean "
            "vector graph: threshold, erosion and dilations, Zhang-Suen thinning, the "
            "skeleton's pixel graph without its artefact triangles, chains between junctions, "
            "smoothing, Douglas-Peucker at 3 m, removal of dead ends up to 25 m (measured from "
            "the road's edge by default).\n\n"
            "Models: the shipped generators (each has a model card in resources/models saying "
            "what it was trained on), or any .onnx generator with its card (.json of the same "
            "name) next to it, as written by tools/streetgan/train.py.\n\n"
            "GIVEN_ROADS (e.g. the district's arterials) are respected and kept: nothing is "
            "generated in their corridor, generated streets that reach them end on them (T "
            "junctions, crossings from both sides; motorways and trunks get none), junction "
            "clusters of the skeleton merge so that crossings stay 4-way, everything is noded "
            "and pieces that reach no given road are joined by a short connector or dropped: "
            "one network whose every crossing is a junction.\n\n"
            "Output: planar roads clipped to the target with level (0 = longest continuous "
            "streets, or the given roads), length_m, model and seed, in the target's CRS (the "
            "given roads whole, split at the new junctions, road_class 'given'); optionally "
            "the generator's image as a GeoTIFF in the working metric CRS. The same seed "
            "gives the same network."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.TARGET, "Target polygon(s)", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Area to fill with roads; several polygons are merged. Give this or an extent.")
        self.add(QgsProcessingParameterExtent(self.EXTENT, "Target extent",
                                              optional=True),
            "A rectangle to fill with roads when no target polygon is given, with its CRS "
            "('xmin,xmax,ymin,ymax [EPSG:code]'; else the project's): one without a CRS "
            "is refused.")
        self.add(QgsProcessingParameterFeatureSource(
            self.GIVEN_ROADS, "Given roads (kept)", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Roads the new network must respect and connect to (arterials, existing roads): "
            "kept in the output, no generated street in their corridor, new streets end on "
            "them. An OSM 'lines' layer is filtered to drivable classes.")
        default = self.models.index(DEFAULT_MODEL) if DEFAULT_MODEL in self.models else 0
        self.add(QgsProcessingParameterEnum(
            self.MODEL, "Model", options=self.models or ["(no model shipped)"],
            defaultValue=default),
            "A shipped generator: " + "; ".join(self._describe(m) for m in self.models) + ".")
        self.add(QgsProcessingParameterFile(
            self.MODEL_FILE, "Model file (.onnx)", extension="onnx", optional=True),
            "A generator exported by tools/streetgan/train.py, with its model card "
            "(<name>.json) next to it; used instead of the shipped model when given.")
        self.add_seed(
            "Seed of the noise field: the same seed and target give the same network.")
        self.add(QgsProcessingParameterNumber(
            self.CELL_SIZE, "Cell size (m, 0 = the model's)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.0, minValue=0.0, maxValue=100.0),
            "Metres per generated pixel. The models learnt 3 m per pixel; another value scales "
            "the whole network (blocks get larger or smaller).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_DEAD_END, "Shortest dead end kept (m)", QgsProcessingParameterNumber.Type.Double,
            optional=True, minValue=0.0, maxValue=1000.0),
            "Dead-end streets this long or shorter are removed (metres at any cell size). "
            "Empty: the model's value from its card (the thesis's 25 m; 120 m for the grid "
            "model, whose example has no dead ends), scaled with the network where CELL_SIZE "
            "is not the model's.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_GAP, "Close gaps up to (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.0, minValue=0.0, maxValue=500.0),
            "A dead end that stops this close before another road is extended straight to "
            "it (0 = off, as in the thesis).", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.FROM_EDGE, "Measure dead ends from the road's edge", defaultValue=True),
            "Checked: a dead end's length runs from the edge of the road it leaves to the "
            "road's end (removes the skeleton spurs of wide generated roads, keeps side "
            "streets). Unchecked: the thesis's skeleton length.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.DEAD_END_SHARE, "Dead-end share to steer to (0-1)",
            QgsProcessingParameterNumber.Type.Double, optional=True, minValue=0.0, maxValue=1.0),
            "The example's share of dead ends among the street ends and junctions (layoutmetrics' "
            "dead_end_share of the example, e.g. 0.28 for the Liechtenstein towns): the "
            "generated streets' share is steered into ±30 % of it by closing dead ends with "
            "short streets (or removing the shortest dead-end street where none reaches), or "
            "adding cul-de-sacs and cutting T stems short. Empty: the "
            "network as read back from the image.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.CROSSING_SHARE, "Share of 4-way junctions to steer to (0-1)",
            QgsProcessingParameterNumber.Type.Double, optional=True, minValue=0.0, maxValue=1.0),
            "The example's share of 4-way junctions among the street ends and junctions "
            "(layoutmetrics' degree4_share of the example, e.g. 0.08 for the Liechtenstein "
            "towns): while the generated network has fewer, T junctions become crossings, "
            "their generated street continued straight across to the next street, generated "
            "or a given road that takes junctions (not a motorway or trunk), crossing nothing, "
            f"inside the target, along no given road, at {crossings.MIN_ANGLE:g}° or more to "
            "the street it crosses (where that leaves too few, a T whose street meets "
            "nothing in reach goes on to the target's edge, up to "
            f"{crossings.EDGE_REACH:g} times as far, where the network leaves it); "
            "while it has more, "
            "generated streets at crossings are removed where both their ends stay "
            "junctions, smallest merged blocks first, then, where none is left, the shortest "
            "generated dead-end street at a crossing. Empty: the junctions as read back "
            "from the image.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_BLOCK_AREA, "Smallest block (m², the example's 10th percentile)",
            QgsProcessingParameterNumber.Type.Double, optional=True, minValue=1.0),
            "The generator draws cells of its own size (on the Liechtenstein towns a quarter "
            "of the real blocks). With the example's 10th-percentile block area (layoutmetrics "
            "of the example, blocks / area), generated streets between blocks under it are "
            "removed, smallest first and only where both ends stay junctions, until at most a "
            "tenth of the blocks are smaller: bigger blocks, longer segments, fewer streets. "
            "Empty: the cells as read back.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MEDIAN_BLOCK_AREA, "Median block (m², the example's)",
            QgsProcessingParameterNumber.Type.Double, optional=True, minValue=1.0),
            "The example's median block area (layoutmetrics of the example): generated "
            "streets are removed the same way, before the smallest blocks, until at most half "
            "the blocks are smaller (before the edge streets of EDGE_JOIN, which close cells "
            "of any size). A small cell with no removable street to another block (at the "
            "network's edge) opens onto the land around it. Empty: not held to the example's "
            "median.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.EDGE_JOIN, "Join streets cut by the target's edge (m apart at most)",
            QgsProcessingParameterNumber.Type.Double, minValue=0.0, maxValue=5000.0,
            defaultValue=edge_streets.EDGE_JOIN_MAX),
            "The generator draws beyond the target and its streets are clipped to it: two "
            "neighbouring streets (or a given road) that end on the target's edge at most "
            "this far apart along it are joined by a street along the edge, which closes the "
            "cell between them into a block, as a town's outer streets close theirs (none "
            f"under {edge_streets.EDGE_JOIN_MIN:g} m, none ending on a motorway or trunk, "
            "none along a road that follows the edge). 0: the streets stay cut at the edge "
            "(the thesis).", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "StreetGAN roads", QgsProcessing.SourceType.TypeVectorLine),
            "Roads with edge_id, level, road_class, length_m, model, seed.")
        self.add(QgsProcessingParameterRasterDestination(
            self.OUTPUT_RASTER, "Generator image", optional=True, createByDefault=False),
            "The generator's image (0 .. 255, roads bright) as a GeoTIFF in the working CRS.")

    @staticmethod
    def _describe(name):
        try:
            import json

            card = json.loads((streetgan.MODELS_DIR / f"{name}.json").read_text())
            return f"{name} ({card.get('title', '')})"
        except (OSError, ValueError):
            return name

    def _target(self, parameters, context, feedback):
        """(target geometries in the working CRS, working CRS, output CRS, label)."""
        if parameters.get(self.TARGET) not in (None, ""):
            frame = qgis_io.read_source(self, parameters, self.TARGET, context, feedback,
                                        kind="polygons", fields=[])
            return frame.geometry, frame.crs, frame.source_crs, frame.name
        if parameters.get(self.EXTENT) in (None, ""):
            raise QgsProcessingException("Give a target polygon layer (TARGET) or an extent "
                                         "(EXTENT).")
        rect, crs = qgis_io.extent_parameter(self, parameters, self.EXTENT, context,
                                             "target extent")
        if rect.isNull() or rect.width() <= 0 or rect.height() <= 0:
            raise QgsProcessingException("The target extent has no area.")
        work = qgis_io.working_crs(crs, rect, context)
        feedback.pushInfo(qgis_io.working_crs_note("The target extent", crs, work))
        box = shapely.box(rect.xMinimum(), rect.yMinimum(), rect.xMaximum(), rect.yMaximum())
        box = shapely.segmentize(box, max(rect.width(), rect.height()) / 50)
        geoms = qgis_io.reproject(np.array([box], dtype=object), crs, work, context)
        return geoms, work, crs, "target extent"

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        geoms, work, out_crs, label = self._target(parameters, context, feedback)
        model_file = self.parameterAsFile(parameters, self.MODEL_FILE, context)
        if model_file:
            model = model_file
        else:
            if not self.models:
                raise QgsProcessingException("No StreetGAN model is shipped: give MODEL_FILE.")
            index = self.parameterAsEnum(parameters, self.MODEL, context)
            if not 0 <= index < len(self.models):
                raise QgsProcessingException(f"Parameter {self.MODEL} must be 0 .. "
                                             f"{len(self.models) - 1}.")
            model = self.models[index]
        seed = self.seed(parameters, context)
        cell = self.number(parameters, self.CELL_SIZE, context)
        max_gap = self.number(parameters, self.MAX_GAP, context)
        min_dead = None  # the model card's value
        if parameters.get(self.MIN_DEAD_END) not in (None, ""):
            min_dead = self.number(parameters, self.MIN_DEAD_END, context)
        share = None  # as read back
        if parameters.get(self.DEAD_END_SHARE) not in (None, ""):
            share = self.number(parameters, self.DEAD_END_SHARE, context)
        crossing_share = None  # as read back
        if parameters.get(self.CROSSING_SHARE) not in (None, ""):
            crossing_share = self.number(parameters, self.CROSSING_SHARE, context)
        min_block = None
        if parameters.get(self.MIN_BLOCK_AREA) not in (None, ""):
            min_block = self.number(parameters, self.MIN_BLOCK_AREA, context)
        median_block = None
        if parameters.get(self.MEDIAN_BLOCK_AREA) not in (None, ""):
            median_block = self.number(parameters, self.MEDIAN_BLOCK_AREA, context)
        gen = qgis_io.run_engine(f"Model '{Path(str(model)).name}'", streetgan.load_model, model)
        feedback.pushInfo(f"Model {gen.name}: {gen.card.get('title', '')}, "
                          f"{gen.cell_size:g} m per pixel.")
        given, given_class = None, None
        frame = qgis_io.read_source(self, parameters, self.GIVEN_ROADS, context, feedback,
                                    kind="lines", target_crs=work, optional=True,
                                    fields=list(qgis_io.ROAD_CLASS_FIELDS))
        if frame is not None:
            frame, given_class = drivable_lines(frame, None, set(roads.DRIVABLE_CLASSES),
                                                feedback)
            given = frame.geometry
            self.require_roads_reach(frame, geoms, "the target extent" if label ==
                                     "target extent" else f"the target {label}")
        feedback.setProgress(5)
        result = qgis_io.run_engine(
            f"Target {label}", streetgan.synthesize, geoms, gen, seed=seed,
            cell_size=cell or None, max_gap=max_gap, min_dead_end=min_dead,
            from_edge=self.parameterAsBoolean(parameters, self.FROM_EDGE, context),
            progress=qgis_io.progress_for(feedback, 5, 90), given=given,
            given_class=given_class, dead_end_share=share, min_block_area=min_block,
            median_block_area=median_block, crossing_share=crossing_share,
            edge_join=self.number(parameters, self.EDGE_JOIN, context))
        s = result.stats
        n_new = int((~result.given).sum())
        feedback.pushInfo(f"Generated {s['pixels'][0]} x {s['pixels'][1]} px in "
                          f"{s['generate_s']:.2f} s; graph in {s['vectorize_s']:.2f} s; "
                          f"{n_new} new road edges, {s.get('junctions_merged', 0)} skeleton "
                          "junctions merged into crossings.")
        if given is not None:
            feedback.pushInfo(
                f"Given roads kept ({int(result.given.sum())} pieces); "
                f"{s['n_joined_to_drawn_roads'] + s['n_attached']} new streets end on them; "
                f"{s['n_joined']} pieces joined by a connector, {s['n_dropped_edges']} edges "
                f"of pieces that reach no road dropped; {s['n_given_joined']} "
                f"street(s) joining given roads that lay apart; {s['n_components']} "
                "connected component(s).")
        if s.get("edge_streets"):
            feedback.pushInfo(f"{s['edge_streets']} street(s) along the target's edge join "
                              "streets that the edge cut.")
        if min_block is not None or median_block is not None:
            under = " and ".join(f"{a:,.0f} m² ({what})" for a, what in
                                 ((median_block, "median"), (min_block, "10th percentile"))
                                 if a is not None)
            feedback.pushInfo(f"{s['small_blocks_merged']} generated street(s) at blocks "
                              f"under {under} removed.")
        if crossing_share is not None:
            feedback.pushInfo(f"4-way junctions steered to {crossing_share:.2f}: "
                              f"{s['crossings_made']} T junction(s) made crossings, "
                              f"{s['crossing_streets_removed']} street(s) at crossings "
                              "removed.")
        if share is not None:
            feedback.pushInfo(f"Dead-end share steered to {share:.2f}: "
                              f"{s['dead_ends_closed']} dead end(s) closed (or removed "
                              "where no short street reaches another), "
                              f"{s['dead_ends_opened']} opened.")
        if n_new == 0:
            feedback.reportError("The generator drew no road inside the target: try another "
                                 "seed or a larger target.")
        table = pd.DataFrame({
            "edge_id": np.arange(len(result.geometry)), "level": result.level,
            "road_class": np.where(result.given, "given",
                                   np.where(result.level == 0, "arterial", "local")),
            "length_m": shapely.length(result.geometry) if len(result.geometry) else [],
            "model": gen.name, "seed": seed})
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry, table,
                                  ROAD_FIELDS, QgsWkbTypes.Type.LineString, out_crs, work, feedback)
        qgis_io.style_output(context, dest, "roads_by_level.qml")
        outputs = {self.OUTPUT: dest}
        raster = self.parameterAsOutputLayer(parameters, self.OUTPUT_RASTER, context)
        if raster:
            qgis_io.write_geotiff(raster, DemGrid(result.image, result.geotransform),
                                  work.toWkt(), "The generator image")
            outputs[self.OUTPUT_RASTER] = raster
        feedback.setProgress(100)
        return outputs
