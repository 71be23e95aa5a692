"""urbansynth:extractroadhierarchy - clean, node and rank a road layer."""
import numpy as np
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from ..plugin.network import hierarchy, street_surfaces
from ..plugin.network import street_graph as roads
from ..plugin.qgis_glue import qgis_io
from ..plugin.core.text import counted
from .common import AlgorithmBase, drivable_lines, parse_class_list

ROAD_FIELDS = [
    ("edge_id", "int"), ("level", "int"), ("road_class", "str"), ("length_m", "float"),
    ("street_id", "int"), ("name", "str"), ("osm_layer", "int"), ("node_from", "int"),
    ("node_to", "int"), ("tortuosity", "float"), ("arterial_source", "str"),
    ("width_m", "float"), ("oneway", "str"), ("junction", "str"),
]
INTERSECTION_FIELDS = [
    ("node_id", "int"), ("degree", "int"), ("street_a", "int"), ("street_b", "int"),
    ("level_a", "int"), ("level_b", "int"), ("tortuosity_a", "float"), ("tortuosity_b", "float"),
    ("dist_mean_a", "float"), ("dist_var_a", "float"), ("dist_mean_b", "float"),
    ("dist_var_b", "float"), ("angle_mean_a", "float"), ("angle_var_a", "float"),
    ("angle_mean_b", "float"), ("angle_var_b", "float"), ("block_area", "float"),
    ("parcel_area", "float"),
]


class ExtractRoadHierarchy(AlgorithmBase):
    GROUP_ID = "analysis"
    INPUT = "INPUT"
    CLASS_FIELD = "CLASS_FIELD"
    CLASSES = "CLASSES"
    METHOD = "METHOD"
    ARTERIAL_CLASSES = "ARTERIAL_CLASSES"
    ARTERIAL_SHARE = "ARTERIAL_SHARE"
    SNAP_TOLERANCE = "SNAP_TOLERANCE"
    MIN_DANGLE_LENGTH = "MIN_DANGLE_LENGTH"
    MAX_DEFLECTION = "MAX_DEFLECTION"
    PARCELS = "PARCELS"
    PARCEL_RADIUS = "PARCEL_RADIUS"
    OUTPUT = "OUTPUT"
    OUTPUT_INTERSECTIONS = "OUTPUT_INTERSECTIONS"

    METHOD_KEYS = ["osm", "topological", "both"]

    def name(self):
        return "extractroadhierarchy"

    def displayName(self):  # noqa: N802
        return "Extract road hierarchy"

    def shortHelpString(self):  # noqa: N802
        return (
            "Cleans a road line layer into a planar street graph and ranks every street.\n\n"
            "Lines are filtered to drivable classes, noded at real crossings (bridges and tunnels, "
            "from the OSM tags layer/bridge/tunnel, only connect where they share a node), "
            "close nodes are snapped, duplicates and dangling slivers dropped and chains through "
            "degree-2 nodes merged. Edges are grouped into continuous streets by the straightest "
            "continuation at each intersection; level 0 are arterials (OSM classes, or the longest "
            "and straightest streets), and every street meeting a level-k street gets level k+1 "
            "(stream order with loops handled; Hartmann, ch. 4.1; Aliaga et al. 2008, sec. 5).\n\n"
            "Outputs: roads with level, road_class, length_m and street_id; intersection points with "
            "the attributes of Aliaga et al. 2008 (levels of the two streets, tortuosity, mean and "
            "variance of the distance and angle between consecutive intersections, mean block or "
            "parcel area nearby). Results are in the input CRS; the work is done in a local metric CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.INPUT, "Road lines", [QgsProcessing.SourceType.TypeVectorLine]),
            "Any line layer: the 'lines' layer of an .osm.pbf file, a cadastre or road shapefile.")
        self.add(QgsProcessingParameterField(
            self.CLASS_FIELD, "Road class field", defaultValue="highway",
            parentLayerParameterName=self.INPUT, optional=True),
            "Field with the road class (OSM 'highway'). If the layer lacks it, an OSM "
            "'other_tags' field is searched, then the road_class this tool writes; without "
            "classes, all lines are used and arterials are chosen topologically.")
        self.add(QgsProcessingParameterString(
            self.CLASSES, "Drivable classes (comma-separated, empty = all)",
            defaultValue=",".join(roads.DRIVABLE_CLASSES), optional=True),
            "Only lines with one of these classes are kept. Leave empty to keep every line.",
            advanced=True)
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Arterial selection", options=[
                "OSM classes", "Topological (longest / straightest streets)",
                "Both (OSM classes where present, else topological)"], defaultValue=2),
            "How level-0 streets are chosen before the stream-order propagation.")
        self.add(QgsProcessingParameterString(
            self.ARTERIAL_CLASSES, "Arterial classes (comma-separated)",
            defaultValue=",".join(roads.ARTERIAL_CLASSES)),
            "Road classes taken as arterials (level 0) by the OSM-class method.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.ARTERIAL_SHARE, "Arterial share of street length (topological)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=0.1, minValue=0.001, maxValue=1.0),
            "Share of the total street length taken as arterials when they are chosen "
            "topologically (Aliaga et al.: 'a small percentage of the longest streets').",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.SNAP_TOLERANCE, "Node snapping tolerance (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=1.0, minValue=0.0, maxValue=50.0),
            "Intersections closer than this are merged, in groups no wider than it (a row of "
            "close nodes is not chained into one); duplicate edges within it are dropped.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_DANGLE_LENGTH, "Minimum dead-end length (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=5.0, minValue=0.0, maxValue=500.0),
            "Dead-end edges shorter than this are removed as digitising slivers.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_DEFLECTION, "Maximum deflection of a continuous street (degrees)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=45.0, minValue=0.0, maxValue=90.0),
            "Two edges continue one street through an intersection if they deflect less than this.",
            advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.PARCELS, "Parcels", [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Cadastre parcels: when given, intersections get the mean parcel area nearby "
            "(Aliaga's a(v)); otherwise only the mean block area.")
        self.add(QgsProcessingParameterNumber(
            self.PARCEL_RADIUS, "Parcel search radius (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=100.0, minValue=1.0, maxValue=5000.0),
            "Parcels within this distance of an intersection count as nearby.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Road hierarchy", QgsProcessing.SourceType.TypeVectorLine),
            "Cleaned road edges between intersections and street ends: edge_id; level (0 = "
            "arterial, k + 1 = meets a level-k street); road_class; length_m; street_id (the "
            "continuous street the edge is part of); name; osm_layer (vertical layer: bridge "
            "+1, tunnel -1; the tools that read this layer keep such edges apart); node_from, "
            "node_to (node_id in Intersections); tortuosity (length / straight distance "
            "between its ends; empty for a closed loop); arterial_source (how its street "
            "was seeded: osm = an arterial class, topological = longest / straightest, "
            "component = the longest street of a part not connected to an arterial, which "
            "starts at level 1; empty for streets levelled from their neighbours); width_m (the "
            "line's own width, from its width_m field or OSM width tag, else empty); oneway "
            "(OSM oneway: tessellatestreets gives a one-way carriageway half its class "
            "width); junction (OSM junction: the island of a roundabout is no block).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_INTERSECTIONS, "Intersections", QgsProcessing.SourceType.TypeVectorPoint,
            optional=True, createByDefault=True),
            "Intersection and street-end points with the Aliaga et al. 2008 attributes: "
            "node_id; degree; street_a, street_b (street_id of the two most important streets "
            "through it: lower level, then longer; street_b empty at a street's end); "
            "level_a/b; and of each of the two streets: tortuosity_a/b (mean over its edges), "
            "dist_mean_a/b and dist_var_a/b (mean and variance, m and m², of the straight "
            "distance between its consecutive intersections), angle_mean_a/b and "
            "angle_var_a/b (degrees, °², of its turns at them; empty for a street without "
            "one); block_area (mean area, m², of the blocks around the point; empty where "
            "none closes); parcel_area (mean area of the parcels within the search radius, "
            "with Parcels).")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        class_field = self.parameterAsString(parameters, self.CLASS_FIELD, context)
        frame = qgis_io.read_source(self, parameters, self.INPUT, context, feedback, kind="lines",
                                    fields=[class_field or "highway", "name", "oneway",
                                            "junction",
                                            *qgis_io.WIDTH_FIELDS, *qgis_io.VERTICAL_LAYER_FIELDS,
                                            *qgis_io.ROAD_CLASS_FIELDS])
        label = frame.name
        classes = parse_class_list(self.parameterAsString(parameters, self.CLASSES, context))
        method = self.METHOD_KEYS[self.parameterAsEnum(parameters, self.METHOD, context)]
        arterial = parse_class_list(self.parameterAsString(parameters, self.ARTERIAL_CLASSES, context))
        share = self.number(parameters, self.ARTERIAL_SHARE, context)
        snap = self.number(parameters, self.SNAP_TOLERANCE, context)
        dangle = self.number(parameters, self.MIN_DANGLE_LENGTH, context)
        deflection = self.number(parameters, self.MAX_DEFLECTION, context)
        radius = self.number(parameters, self.PARCEL_RADIUS, context)

        frame, road_class = drivable_lines(frame, class_field, classes, feedback)
        if road_class is None and method == "osm":
            feedback.pushInfo("Without road classes, arterials are chosen topologically.")
            method = "topological"
        z_layer = qgis_io.osm_vertical_layers(frame)
        name = qgis_io.osm_tag_column(frame, "name")

        graph = qgis_io.run_engine(label, roads.clean_network, frame.geometry, road_class, name,
                                   z_layer, snap_tolerance=snap, min_dangle_length=dangle,
                                   progress=qgis_io.progress_for(feedback, 5, 40))
        feedback.pushInfo(f"Street graph: {counted(graph.n_edges, 'edge')}, "
                          f"{counted(len(graph.nodes), 'node')}.")
        h = qgis_io.run_engine(label, hierarchy.road_hierarchy, graph, method, arterial or
                               roads.ARTERIAL_CLASSES, share, deflection,
                               progress=qgis_io.progress_for(feedback, 40, 70))
        counts = ", ".join(f"level {lv}: {n}" for lv, n in enumerate(
            np.bincount(h.street_level)) if n)
        feedback.pushInfo(f"{counted(h.streets.n, 'street')} ({counts}).")

        parcels = None
        parcels_frame = qgis_io.read_source(self, parameters, self.PARCELS, context, feedback,
                                            kind="polygons", target_crs=frame.crs, optional=True)
        if parcels_frame is not None:
            parcels = parcels_frame.geometry
        results = {}
        table = h.roads_table()
        # what a street surface needs (tessellatestreets after this tool): each line's own
        # width, and one-way (a dual carriageway's two lines get half a class width each)
        widths = qgis_io.road_width_column(frame)
        table["width_m"] = np.nan if widths is None else \
            [street_surfaces.parse_width(w) for w in widths[graph.source]]
        # and what 'Extract city blocks' reads after it: a roundabout's ring (its island)
        for tag in ("oneway", "junction"):
            values = qgis_io.osm_tag_column(frame, tag)
            table[tag] = None if values is None else values[graph.source]
        results[self.OUTPUT] = qgis_io.write_sink(
            self, parameters, self.OUTPUT, context, graph.geometry, table, ROAD_FIELDS,
            QgsWkbTypes.Type.LineString, frame.source_crs, frame.crs, feedback)
        qgis_io.style_output(context, results[self.OUTPUT], "roads_by_level.qml")
        feedback.setProgress(85)
        if self.OUTPUT_INTERSECTIONS in parameters and parameters[self.OUTPUT_INTERSECTIONS] is not None:
            table = hierarchy.intersection_attributes(graph, h.streets, h.street_level,
                                                      parcels=parcels, parcel_radius=radius)
            if parcels is not None:
                self._report_parcels(table, parcels_frame.name, label, radius, feedback)
            points = shapely.points(graph.nodes)
            results[self.OUTPUT_INTERSECTIONS] = qgis_io.write_sink(
                self, parameters, self.OUTPUT_INTERSECTIONS, context, points, table,
                INTERSECTION_FIELDS, QgsWkbTypes.Type.Point, frame.source_crs, frame.crs, feedback)
            qgis_io.style_output(context, results[self.OUTPUT_INTERSECTIONS], "intersections.qml")
        feedback.setProgress(100)
        return results

    @staticmethod
    def _report_parcels(table, parcels_name, label, radius, feedback):
        """Say which intersections found no parcel within the radius: parcels of another
        place (or CRS mix-up) left every parcel_area empty without a word."""
        near = np.isfinite(table["parcel_area"].to_numpy(dtype=np.float64, na_value=np.nan))
        if not near.any():
            feedback.pushWarning(
                f"No parcel of {parcels_name} lies within {radius:g} m of an intersection of "
                f"{label}: parcel_area stays empty. Check that both layers cover the same "
                "place.")
        elif not near.all():
            feedback.pushInfo(f"{int((~near).sum())} of {len(near)} intersections have no "
                              f"parcel within {radius:g} m: their parcel_area stays empty.")
