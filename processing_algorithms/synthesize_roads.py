"""urbansynth:synthesizeroads - one entry point that runs the road synthesis method chosen by
METHOD (the district model uses it so that the method is a model parameter)."""
from collections import namedtuple

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsCoordinateTransform,
    QgsCsException,
    QgsFeature,
    QgsGeometry,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingMultiStepFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFile,
    QgsProcessingParameterRasterLayer,
    QgsProcessingUtils,
    QgsVectorLayer,
    QgsWkbTypes,
)

from ..plugin.measure import fidelity
from ..plugin.qgis_glue import qgis_io
from ..plugin.roads import streetgan
from .common import AlgorithmBase, fill_quantile_parameter
from .synthesize_roads_from_fragments import bound_district

#: One METHOD: its label and the algorithm that runs it. New methods are
#: appended (the enum index is what models and command lines store).
Method = namedtuple("Method", "key label algorithm")
METHODS = (
    Method("fragments", "Fragments of the example (Hartmann thesis ch. 4.1)",
           "urbansynth:synthesizeroadsfromfragments"),
    Method("growth", "Procedural growth, grid major and organic minor roads (Scharl 2010)",
           "urbansynth:growroads"),
    Method("gan", "StreetGAN generator trained on real towns (Hartmann thesis ch. 4.2)",
           "urbansynth:synthesizeroadsgan"),
)
#: The shipped StreetGAN generator the 'gan' method uses (Helsinki + 8 Liechtenstein towns).
GAN_MODEL = "streetgan_towns"


class SynthesizeRoads(AlgorithmBase):
    GROUP_ID = "synthesis"
    METHOD = "METHOD"
    EXAMPLE_ROADS = "EXAMPLE_ROADS"
    ARTERIALS = "ARTERIALS"
    BOUNDARY = "BOUNDARY"
    FRAGMENT_DB = "FRAGMENT_DB"
    DEM = "DEM"
    SEED = "SEED"
    FILL_QUANTILE = "FILL_QUANTILE"
    OUTPUT = "OUTPUT"
    OUTPUT_BOUNDARY = "OUTPUT_BOUNDARY"

    def name(self):
        return "synthesizeroads"

    def displayName(self):  # noqa: N802
        return "Synthesize roads (choose the method)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Synthesizes the streets of a district with the method chosen by METHOD, from one "
            "set of inputs, so that a Processing model can switch methods with a parameter "
            "(the shipped model 'Synthesize a district like an example' does). Every method "
            "keeps the ARTERIALS inside the district and connects the new streets to them.\n\n"
            "- Fragments: the faces of the ARTERIALS are filled level by level with warped "
            "fragments of the example (FRAGMENT_DB, or a database built here from "
            "EXAMPLE_ROADS).\n"
            "- Procedural growth: grid major roads and organic minor roads grow inside the "
            "BOUNDARY from the ARTERIALS (the example is not used).\n"
            "- StreetGAN: a generator trained on real towns fills the BOUNDARY; the ARTERIALS "
            "are kept and the generated streets join them.\n\n"
            "Without a BOUNDARY, the convex hull of the arterials is the district. Each method "
            "is also a tool of its own with every option; this one uses their defaults. An "
            "input the chosen method does not read is named in a warning and ignored."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=[m.label for m in METHODS], defaultValue=0),
            "Which road synthesis runs: fragments (example-based, thesis ch. 4.1), "
            "procedural growth (Scharl 2010) or the StreetGAN generator (thesis ch. 4.2).")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_ROADS, "Example roads with levels", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Fragments: the example city's roads as written by 'Extract road hierarchy' "
            "(field level), from which the fragment database is built when no FRAGMENT_DB "
            "is given. StreetGAN: the generated streets keep the example's dead-end share "
            "(measured inside the example's hull, ±30 %) and its share of 4-way junctions, "
            "and its cells are merged up to the example's median and 10th-percentile block "
            "areas.")
        self.add(QgsProcessingParameterFeatureSource(
            self.ARTERIALS, "Arterial roads of the district", [QgsProcessing.SourceType.TypeVectorLine]),
            "Sketched or real arterials: they are kept and the new streets connect to them.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BOUNDARY, "District boundary", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Polygon(s) the district fills (all methods; fragments close the faces the "
            "arterials leave open with it). Default: the convex hull "
            "of the arterials.")
        self.add(QgsProcessingParameterFile(
            self.FRAGMENT_DB, "Fragment database", extension="gpkg", optional=True),
            "Fragments only: a database from 'Build fragment database'. Default: built from "
            "the example roads.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Terrain (DEM)", optional=True),
            "Fragments and growth take the terrain into account (slope term, maximum slope).")
        self.add(fill_quantile_parameter(self.FILL_QUANTILE),
            "Fragments only: faces larger than this quantile of the example's block areas are "
            "filled with streets. An example whose largest blocks are parks or yards (central "
            "Helsinki) keeps them with a higher value (98).", advanced=True)
        self.add_seed("The same seed and inputs give the same network.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Synthesized roads", QgsProcessing.SourceType.TypeVectorLine),
            "The new road network with level (0 = arterial), styled by level.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_BOUNDARY, "District outline", QgsProcessing.SourceType.TypeVectorPolygon,
            optional=True, createByDefault=False),
            "The polygon the district fills: the BOUNDARY given, or the arterials' convex "
            "hull (what 'Extract city blocks' and 'Subdivide blocks into parcels' take as "
            "BOUNDARY to close the faces the streets leave open, as the district model does).")

    def input_error(self, parameters, context):
        method = METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        if method.key == "fragments" and not self.given(parameters, self.FRAGMENT_DB) \
                and not self.given(parameters, self.EXAMPLE_ROADS):
            return ("Method 'fragments' needs a Fragment database (FRAGMENT_DB) or Example "
                    "roads with levels (EXAMPLE_ROADS) to build one from.")
        return None

    def unused_inputs(self, parameters, method):
        """The optional inputs given that ``method`` does not read (an analyst who switched
        the method in a model would otherwise not know)."""
        uses = {"fragments": {self.FRAGMENT_DB, self.DEM, self.FILL_QUANTILE},
                "growth": {self.DEM}, "gan": {self.EXAMPLE_ROADS}}[method.key]
        if method.key == "fragments" and not self.given(parameters, self.FRAGMENT_DB):
            uses.add(self.EXAMPLE_ROADS)  # the database is built from it
        given = {n: self.given(parameters, n)
                 for n in (self.EXAMPLE_ROADS, self.FRAGMENT_DB, self.DEM)}
        # a number is always given (a model passes its default): set, it differs from that
        try:
            given[self.FILL_QUANTILE] = float(parameters.get(self.FILL_QUANTILE)) != \
                self.parameterDefinition(self.FILL_QUANTILE).defaultValue()
        except (TypeError, ValueError):  # not given, or an expression
            pass
        return [n for n, set_ in given.items() if set_ and n not in uses]

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        message = self.input_error(parameters, context)
        if message:
            raise QgsProcessingException(message)
        method = METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        seed = self.seed(parameters, context)
        feedback.pushInfo(f"Method: {method.label}")
        for name in self.unused_inputs(parameters, method):
            feedback.pushWarning(
                f"{self.parameterDefinition(name).description()} ({name}) is not used by the "
                f"method '{method.label}': it is ignored.")
        # read here first: wrong geometry types, empty layers and missing CRSs are reported
        # with the user's layer names, before any step runs
        arterials = qgis_io.read_source(self, parameters, self.ARTERIALS, context, feedback,
                                        kind="lines", fields=[])
        if method.key == "fragments":   # before a fragment database is built for it
            bound_district(self, arterials)
        boundary = qgis_io.read_source(self, parameters, self.BOUNDARY, context, feedback,
                                       kind="polygons", target_crs=arterials.crs,
                                       optional=True, fields=[])
        if boundary is not None:
            area = shapely.union_all(boundary.geometry)
            area_name = f"boundary {boundary.name}"
        else:
            area_name = f"convex hull of the arterials {arterials.name}"
            area = shapely.convex_hull(shapely.union_all(arterials.geometry))
            if shapely.area(area) <= 0:
                raise QgsProcessingException(
                    f"The arterials {arterials.name} lie on one line: their convex hull has no "
                    "area. Give a District boundary (BOUNDARY).")
        held_to = {}
        if method.key == "gan" and self.given(parameters, self.EXAMPLE_ROADS):
            # what the generator is held to (one rule: streetgan.example_steering): the
            # example's dead-end and crossing shares, its median and smallest-tenth blocks
            example = qgis_io.read_source(self, parameters, self.EXAMPLE_ROADS, context,
                                          feedback, kind="lines", fields=[])
            stats = qgis_io.run_engine(example.name, fidelity.statistics_of_extract,
                                       example.geometry)
            held_to = {arg.upper(): v for arg, v in streetgan.example_steering(stats).items()}
            feedback.pushInfo(f"{example.name} (inside its hull): dead-end share "
                              f"{stats['degree1_share']:.2f}, 4-way junctions "
                              f"{stats['degree4_share']:.2f}, blocks "
                              f"{stats['block_area_p10']:,.0f} m² (10th percentile) and "
                              f"{stats['block_area_p50']:,.0f} m² (median).")
        results = self._child_method(parameters, context, feedback, method, arterials, area,
                                     area_name, seed, held_to)
        outline = qgis_io.write_sink(
            self, parameters, self.OUTPUT_BOUNDARY, context, np.array([area], dtype=object),
            pd.DataFrame({"outline": [area_name], "area_m2": [float(shapely.area(area))]}),
            [("outline", "str"), ("area_m2", "float")], QgsWkbTypes.Type.MultiPolygon,
            arterials.source_crs, arterials.crs, feedback)
        if outline is not None:
            results[self.OUTPUT_BOUNDARY] = outline
        return results

    def _child_method(self, parameters, context, feedback, method, arterials, area, area_name,
                      seed, held_to=None):
        import processing  # QGIS's Processing plugin, present wherever algorithms run

        fragment_db = self.parameterAsFile(parameters, self.FRAGMENT_DB, context)
        need_db = method.key == "fragments" and not fragment_db
        steps = _ChildSteps(1 + need_db + (method.key == "gan"), feedback)

        def run(alg_id, params):
            child = processing.run(alg_id, params, context=context, feedback=steps,
                                   is_child_algorithm=True)
            qgis_io.stop_if_canceled(feedback)
            return child

        dem = parameters.get(self.DEM)
        if need_db:
            # named after the example: the roads' 'database' field and the log name it
            example = qgis_io.layer_name(self, parameters, self.EXAMPLE_ROADS, context)
            fragment_db = run("urbansynth:buildfragmentdatabase",
                              {"ROADS": parameters[self.EXAMPLE_ROADS],
                               "DEM": self._example_dem(parameters, context, feedback),
                               "OUTPUT": QgsProcessingUtils.generateTempFilename(
                                   self.database_name(example)
                                   + "_fragments.gpkg")})["OUTPUT"]
            steps.setCurrentStep(1)
        # every method fills the district: the boundary given, or the arterials' convex hull,
        # as a layer in the arterials' CRS: every method writes its roads in its target's
        # CRS, so all of them write in the arterials' (a boundary in another CRS gave its
        # own to growth's and StreetGAN's roads, and so to every output of the district)
        boundary = self._area_layer(area, arterials, context, area_name)
        if method.key == "fragments":
            params = {"ARTERIALS": parameters[self.ARTERIALS], "BOUNDARY": boundary,
                      "FRAGMENT_DB": fragment_db, "DEM": dem, "SEED": seed,
                      "FILL_QUANTILE": self.number(parameters, self.FILL_QUANTILE, context)}
        elif method.key == "gan":
            models = streetgan.shipped_models()  # the MODEL enum lists them by name
            if GAN_MODEL not in models:
                raise QgsProcessingException(
                    f"The StreetGAN model '{GAN_MODEL}' is missing from resources/models "
                    "(reinstall the plugin).")
            # the arterials inside the district, as the other methods keep them (StreetGAN
            # keeps its given roads whole: 4.8 of 7.5 km lay outside a district)
            inside = run("native:clip", {"INPUT": parameters[self.ARTERIALS],
                                         "OVERLAY": boundary, "OUTPUT": "memory:"})["OUTPUT"]
            steps.setCurrentStep(1)
            params = {"TARGET": boundary, "SEED": seed, "MODEL": models.index(GAN_MODEL),
                      "GIVEN_ROADS": inside}
            params.update(held_to or {})
        else:
            params = {"BOUNDARY": boundary, "MAJOR_ROADS": parameters[self.ARTERIALS],
                      "DEM": dem, "SEED": seed}
        # the destination as a path/URI (a model or a command line may leave it unset)
        params["OUTPUT"] = self.parameterAsOutputLayer(parameters, self.OUTPUT, context) \
            or QgsProcessing.TEMPORARY_OUTPUT
        result = run(method.algorithm, params)
        return {self.OUTPUT: result["OUTPUT"]}

    def _example_dem(self, parameters, context, feedback):
        """The DEM the example's fragment database is built with: the DEM is the district's
        terrain, and the example's only where it reaches the example roads (the same town).
        A DEM of another place is left out, with a warning (the database was built on it and
        stopped: 'no value over the input's extent')."""
        layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if layer is None:
            return None
        example = self.parameterAsSource(parameters, self.EXAMPLE_ROADS, context)
        if not layer.crs().isValid() or not example.sourceCrs().isValid():
            return parameters[self.DEM]  # the child names the layer without a CRS
        try:
            extent = QgsCoordinateTransform(layer.crs(), example.sourceCrs(),
                                            context.transformContext()) \
                .transformBoundingBox(layer.extent())
        except QgsCsException:
            extent = None
        if extent is not None and extent.intersects(example.sourceExtent()):
            return parameters[self.DEM]
        name = qgis_io.layer_name(self, parameters, self.EXAMPLE_ROADS, context)
        feedback.pushWarning(
            f"The DEM '{layer.name()}' does not reach the example roads {name}: their fragment "
            "database is built without relief, so the terrain does not steer the choice of "
            "fragments (give a FRAGMENT_DB built with the example's own DEM for that).")
        return None

    @staticmethod
    def _area_layer(area, arterials, context, name: str):
        """The district (the boundary given, or the arterials' convex hull) as a layer in the
        arterials' CRS, named so that messages say what it is."""
        hull = qgis_io.reproject(np.array([area], dtype=object), arterials.crs,
                                 arterials.source_crs, context)[0]
        # the names given are quoted for messages: the child quotes this one again
        layer = QgsVectorLayer(f"MultiPolygon?crs={arterials.source_crs.authid()}",
                               name.replace("'", ""), "memory")
        if not layer.crs().isValid():
            layer.setCrs(arterials.source_crs)
        feature = QgsFeature()
        feature.setGeometry(QgsGeometry.fromWkt(hull.wkt))
        layer.dataProvider().addFeatures([feature])
        context.temporaryLayerStore().addMapLayer(layer)
        return layer.id()


class _ChildSteps(QgsProcessingMultiStepFeedback):
    """The feedback of the method run as a child: everything but ``processing.run``'s dump
    of the child's results, which names this run's staging copies of the outputs (paths
    gone once the run succeeds)."""

    def pushInfo(self, info):  # noqa: N802 (QGIS API)
        if not str(info).startswith("Results: "):
            super().pushInfo(info)
