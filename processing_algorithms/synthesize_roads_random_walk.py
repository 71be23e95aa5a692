"""urbansynth:synthesizeroadsrandomwalk - join / expand / blend by attributed intersections."""
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.network import invariants
from ..plugin.network import street_graph as roads
from ..plugin.qgis_glue import qgis_io
from ..plugin.roads import intersection_quadtree, random_walk
from .common import AlgorithmBase, drivable_lines


class SynthesizeRoadsRandomWalk(AlgorithmBase):
    GROUP_ID = "synthesis"
    EXAMPLE = "EXAMPLE"
    TARGET = "TARGET"
    EXISTING_ROADS = "EXISTING_ROADS"
    EXAMPLE_B = "EXAMPLE_B"
    BLEND = "BLEND"
    BLEND_FIELD = "BLEND_FIELD"
    PLACEMENT = "PLACEMENT"
    THRESHOLD = "THRESHOLD"
    MIN_ANGLE = "MIN_ANGLE"
    SEED = "SEED"
    OUTPUT = "OUTPUT"
    OUTPUT_INTERSECTIONS = "OUTPUT_INTERSECTIONS"
    OUTPUT_BLOCKS = "OUTPUT_BLOCKS"
    OUTPUT_EXISTING = "OUTPUT_EXISTING"

    PLACEMENTS = [None, True, False]
    #: The most intersection points one run connects (about 250 km² at Helsinki's density).
    MAX_POINTS = 20_000

    def name(self):
        return "synthesizeroadsrandomwalk"

    def displayName(self):  # noqa: N802
        return "Synthesize roads by random walks (intersection points)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Makes a street network in the style of an example city from its attributed "
            "intersection points (Aliaga, Vanegas and Benes 2008).\n\n"
            "The example's intersections (the OUTPUT_INTERSECTIONS of 'Extract road hierarchy', "
            "or roads they are computed from) carry the levels of the two streets through "
            "them, their tortuosity and the mean and variance of the distance and turn angle "
            "between consecutive intersections. They are organised in an adaptive quadtree and "
            "copied into the TARGET polygons (in place where the example covers the target, "
            "else tiled, then patches of its built-up parts); what copies leave empty is "
            "filled with points drawn from the quadtree leaves' densities and level "
            "probabilities. Streets are random walks, level by level: each step goes to a "
            "point drawn by a Gaussian on (distance, angle) from the base point's statistics, "
            "never to a point of another level, a point with all its connections (at most 4) "
            "or across a street. T junctions that were crossings in the example, then "
            "junctions on the existing roads, become crossings (their street goes on "
            "straight across) until the share of 4-way junctions is the example's. "
            "These steps after the walks close no ring of streets shorter than 1.5 times "
            "the square root of the example's block area around the point (a block a "
            "seventh of its neighbours'; a stub closes one only where it closes no other "
            "way). "
            "Stubs close until the dead-end share is the example's (with "
            "roads as the example: measured inside their convex hull, where the streets cut "
            "at its edge are no dead ends), and "
            "every piece is joined to the rest (or to the existing roads) by a step, else "
            "by the shortest street through the target (bent along it), or dropped where "
            "none reaches it (a part of the target apart keeps its longest piece, with a "
            "warning): one network whose every crossing is a junction. Segments take the "
            "shapes of the example's street segments (with roads as the example: the same "
            "tortuosity and bends), else parabolas of the points' tortuosity.\n\n"
            "EXISTING_ROADS: their dead ends at the target continue into the new streets "
            "(expand), and new streets meet them at junctions spaced like the example's "
            "intersections along its arterials. EXAMPLE_B with BLEND (0 = only the example, "
            "1 = only B) or a blend field on the targets mixes two styles: a share BLEND of "
            "the area takes B's point layout and every point's street statistics are "
            "interpolated by BLEND. Output: planar roads with level (0 = most important) in "
            "the target's CRS; optionally the points used."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        types = [QgsProcessing.SourceType.TypeVectorPoint, QgsProcessing.SourceType.TypeVectorLine]
        self.add(QgsProcessingParameterFeatureSource(self.EXAMPLE, "Example", types),
                 "Intersection points of 'Extract road hierarchy' (with level_a, dist_mean_a, "
                 "...) or example roads (an OSM 'lines' layer is filtered to drivable classes) "
                 "from which the points are computed.")
        self.add(QgsProcessingParameterFeatureSource(
            self.TARGET, "Target area", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "Polygon(s) where the new streets go; the output is in this layer's CRS.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXISTING_ROADS, "Existing roads (expand)", [QgsProcessing.SourceType.TypeVectorLine],
            optional=True),
            "Roads in or around the target to expand from (e.g. its arterials): their dead "
            "ends at the target continue into the new streets, new streets meet them only at "
            "junctions, and the result is one network with them. With OSM classes (a "
            "'highway' field or tag, or the road_class of 'Extract road hierarchy'), a new "
            "street ends on no motorway or trunk away from its "
            "junctions: it ends short of it, or goes where its other end is a junction.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_B, "Second example (blend)", types, optional=True),
            "Points or roads of a second city; its style is blended with the example's.")
        self.add(QgsProcessingParameterNumber(
            self.BLEND, "Blend weight of the second example (0-1)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=0.5, minValue=0.0, maxValue=1.0),
            "0 keeps only the example's points, 1 only the second example's; in between, "
            "densities and level mixes follow the share of the area each example's layout "
            "takes, and every point's street distances, turn angles (means and variances), "
            "tortuosity and parcel area are interpolated by the weight. Used only with a "
            "second example.")
        self.add(QgsProcessingParameterField(
            self.BLEND_FIELD, "Blend weight field (on the targets)",
            parentLayerParameterName=self.TARGET, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "A 0-1 weight per target polygon for a spatially varying blend; empty values use "
            "the blend weight above.")
        self.add_seed(
            "The same seed and inputs give the same network.")
        self.add(QgsProcessingParameterEnum(
            self.PLACEMENT, "Placement of the example's points",
            options=["Automatic (in place where the example covers the target)", "In place",
                     "Shifted / tiled over the target"], defaultValue=0),
            "In place copies the points at their own coordinates (copy-and-reconnect); shifted "
            "tiles the example over the target at the shift that fills it best.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.THRESHOLD, "Transition probability threshold",
            QgsProcessingParameterNumber.Type.Double,
            defaultValue=random_walk.WalkSettings.threshold, minValue=0.0, maxValue=1.0),
            "Steps less probable than this (the Gaussian's peak is 1) are never taken: higher "
            "values keep streets closer to the example's spacing and turns, with more dead "
            "ends.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_ANGLE, "Minimum angle between streets (degrees)",
            QgsProcessingParameterNumber.Type.Double,
            defaultValue=random_walk.WalkSettings.min_angle, minValue=0.0, maxValue=89.0),
            "Walk steps keep streets this far apart at a junction; later joins may not.",
            advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Synthesized roads", QgsProcessing.SourceType.TypeVectorLine),
            "New road segments with level, length_m, tortuosity and origin ('walk'; 'seam' "
            "joins to existing roads; 'close' steps closing stubs; 'dead_end' streets to the "
            "example's street ends no walk reached; 'cross' crossing streets completed; "
            "'across' a T junction's street continued across, making it a crossing, one "
            "step onto a point or street; 'across_street' the same where the share of "
            "4-way junctions was still under the example's: straight on to the street it "
            "meets; 'join' steps joining pieces of the network; 'piece_link' streets "
            "through the target to pieces no step reached; 'given_join' streets joining "
            "given roads that lie apart).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_INTERSECTIONS, "Intersection points used", QgsProcessing.SourceType.TypeVectorPoint,
            optional=True, createByDefault=False),
            "The attributed points placed in the target (example 0 = first, 1 = second, -1 = a "
            "node of the existing roads in the target or at a new street's end, -2 = a junction "
            "slot offered on an existing road) with the connections they got: degree is what the "
            "point had in its example, connections what it got here (0: not taken).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_BLOCKS, "Blocks", QgsProcessing.SourceType.TypeVectorPolygon, optional=True,
            createByDefault=False),
            "The faces the new streets close, cut to the target (block_id, area_m2, "
            "neighbours in the block graph, parcel_area: the mean parcel or block area of "
            "the example points on the outline), ready for 'Subdivide blocks into parcels'.")

        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_EXISTING, "Existing roads with the new junctions",
            QgsProcessing.SourceType.TypeVectorLine, optional=True, createByDefault=False),
            "The EXISTING_ROADS (drivable ones, one feature per part) with a vertex wherever a "
            "new street ends on them, in the fields of the synthesized roads (origin "
            "'given', level 0, node_from and node_to -1): merged with them, one network that "
            "QGIS's network analysis, which joins lines only at vertices, can route through. "
            "The input layer is not changed.")

    # ----------------------------------------------------------------------- reading

    def _read_example(self, parameters, name, context, feedback, work_crs, target_src, index):
        # the fields of what it holds: a roads layer's 'tortuosity' is no cut 'tortuosity_a'
        points, lines = intersection_quadtree.TABLE_FIELDS, qgis_io.ROAD_CLASS_FIELDS
        fields = {"points": points, "lines": lines}.get(
            qgis_io.geometry_kind(self, parameters, name, context), points + lines)
        frame = qgis_io.read_source(self, parameters, name, context, feedback, fields=fields)
        # an example elsewhere keeps its own metric CRS (it is shifted onto the target anyway);
        # one that overlaps the target is used in the target's CRS, so it can stay in place
        frame = qgis_io.example_in_place(frame, target_src, work_crs, context, feedback)
        kinds = set(shapely.get_type_id(frame.geometry).tolist())
        if kinds <= {0, 4}:
            geoms = shapely.get_parts(frame.geometry)
            if len(geoms) != len(frame.geometry):
                raise QgsProcessingException(f"Layer {frame.name}: multipoint features; give "
                                             "one point per intersection.")
            xy = shapely.get_coordinates(geoms)
            points = qgis_io.run_engine(frame.name, intersection_quadtree.points_from_table,
                                        xy, frame.attributes, index)
            shapes, share = None, None
            feedback.pushInfo(f"{frame.name}: {len(points)} attributed intersection points "
                              "(no street shapes: segments bend as parabolas of the points' "
                              "tortuosity; give the example's roads instead to bend them "
                              "like its streets).")
        elif kinds <= {1, 5}:
            frame, road_class = drivable_lines(frame, None, set(roads.DRIVABLE_CLASSES),
                                               feedback)
            points, shapes = qgis_io.run_engine(frame.name, random_walk.example_from_roads,
                                                frame.geometry, road_class, index)
            # the share the network invariants hold the result to (the fragment database's)
            share = invariants.dead_end_share_of_extract(frame.geometry)
            feedback.pushInfo(f"{frame.name}: {len(points)} intersection points and "
                              f"{len(shapes)} street segment shapes (mean tortuosity "
                              f"{shapes.mean_tortuosity():.3f}) computed from the roads.")
        else:
            raise QgsProcessingException(f"Layer {frame.name} has polygons; intersection "
                                         "points or road lines are needed.")
        if len(points) < 3:
            raise QgsProcessingException(f"Layer {frame.name}: {len(points)} intersection "
                                         "points are too few to learn a street style from.")
        return frame, points, shapes, share

    def _bound(self, target, *examples):
        """The points the target receives (its area at the densest example's) within bounds."""
        area = shapely.area(shapely.union_all(target.geometry))
        density = max(len(p) / max(shapely.area(shapely.convex_hull(shapely.multipoints(p.xy))),
                                   1.0) for p in examples if p is not None)
        self.bound_work(f"Target {target.name} ({area / 1e6:,.1f} km² at the example's "
                        f"{density * 1e6:,.0f} intersections per km²)", area * density,
                        self.MAX_POINTS, "intersection points",
                        "split the target into districts and run them one by one")

    def _blend(self, parameters, context, target, field):
        beta = self.number(parameters, self.BLEND, context)
        if not field:
            return beta
        return qgis_io.run_engine(target.name, intersection_quadtree.blend_by_polygons,
                                  target.geometry, target.attributes[field], beta)

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        field = self.parameterAsString(parameters, self.BLEND_FIELD, context)
        target = qgis_io.read_source(self, parameters, self.TARGET, context, feedback,
                                     kind="polygons", fields=[field] if field else [],
                                     required_fields=[field] if field else ())
        seed = self.seed(parameters, context)
        settings = random_walk.WalkSettings(
            threshold=self.number(parameters, self.THRESHOLD, context),
            min_angle=self.number(parameters, self.MIN_ANGLE, context))
        placement = self.PLACEMENTS[self.parameterAsEnum(parameters, self.PLACEMENT, context)]
        feedback.setProgress(5)
        _, points, shapes, share = self._read_example(parameters, self.EXAMPLE, context, feedback,
                                               target.crs, target.geometry, 0)
        points_b, shapes_b, blend = None, None, 0.0
        if parameters.get(self.EXAMPLE_B) not in (None, ""):
            _, points_b, shapes_b, _ = self._read_example(parameters, self.EXAMPLE_B, context,
                                                       feedback, target.crs, target.geometry, 1)
            blend = self._blend(parameters, context, target, field)
        elif field:
            feedback.pushInfo("The blend weight field is ignored: there is no second example.")
        self._bound(target, points, points_b)
        existing = qgis_io.read_source(self, parameters, self.EXISTING_ROADS, context, feedback,
                                       kind="lines", target_crs=target.crs, optional=True,
                                       fields=list(qgis_io.ROAD_CLASS_FIELDS))
        existing_lines = existing_class = None
        if existing is not None:
            existing, existing_class = drivable_lines(existing, None,
                                                      set(roads.DRIVABLE_CLASSES), feedback)
            existing_lines = existing.geometry
            # a road whose dead end is within the seam distance of the target is continued
            self.require_roads_reach(existing, target.geometry, f"the target {target.name}",
                                     reach=random_walk.seam_distance(points, settings))
        elif self.given(parameters, self.OUTPUT_EXISTING):
            raise QgsProcessingException("Existing roads with the new junctions "
                                         "(OUTPUT_EXISTING) need EXISTING_ROADS.")
        feedback.setProgress(15)
        result = qgis_io.run_engine(
            target.name, random_walk.synthesize, points, target.geometry, existing_lines,
            points_b, blend, seed, settings, placement,
            progress=qgis_io.progress_for(feedback, 15, 90), shapes=shapes, shapes_b=shapes_b,
            # a blend mixes the two examples' shares among their points
            dead_end_share=share if points_b is None else None, given_class=existing_class)
        st = result.stats
        feedback.pushInfo(
            f"{st['n_points']} points placed ({st['n_points_generated']} drawn from the "
            f"quadtree model; quadtree leaves: "
            f"{', '.join(str(n) for n in st['quadtree_leaves'])}); {st['n_points_connected']} "
            f"connected by {st['n_edges']} segments on {st['n_levels']} levels; "
            f"{st['n_dead_ends']} dead ends ({100 * st['dead_end_share']:.0f} %, the "
            f"example's {100 * st['example_dead_end_share']:.0f} %).")
        feedback.pushInfo(
            f"{'Network' if st.get('n_pieces_left_apart') else 'One network'}: "
            f"{st['n_closed']} stubs closed, {st['n_crossings_made']} crossing "
            f"streets completed, {st['n_crossings_matched']} T junctions made crossings "
            f"({100 * st['crossing_share']:.0f} % 4-way junctions, the example's "
            f"{100 * st['example_crossing_share']:.0f} %), "
            f"{st['n_joins'] + st['n_join_splits']} pieces joined "
            f"({st['n_join_splits']} by a new junction on a street), "
            f"{st['n_pieces_linked']} pieces out of a step's reach linked by a street "
            f"through the target, {st['n_dropped_edges']} segments of pieces that no such "
            "street reaches dropped; "
            f"{st['n_small_faces_refused']} steps refused that would close a block far "
            "smaller than the example's around them. "
            f"Mean tortuosity {st['mean_tortuosity']:.3f} (example "
            f"{st['example_mean_tortuosity']:.3f}).")
        if "n_seam_ends" in st:
            feedback.pushInfo(f"Existing roads: {st['n_seam_ends_connected']} of "
                              f"{st['n_seam_ends']} dead ends at the target joined the new "
                              f"streets ({st['n_seam_ends_closed']} of them as a T onto the "
                              "nearest street: the streets the target cuts stay open no "
                              "more often than the example's streets end); "
                              f"{st['n_road_junctions']} junctions on them.")
        if st.get("n_controlled_access_ended_short"):
            feedback.pushInfo(f"{st['n_controlled_access_ended_short']} new street(s) that "
                              "ended on a motorway or trunk away from its junctions end short "
                              "of it, or went where their other end is a junction; "
                              f"{st['n_controlled_access_dropped']} street(s) of pieces that "
                              "only such a road reached dropped.")
        if st.get("n_pieces_left_apart"):
            feedback.pushWarning(f"{st['n_pieces_left_apart']} piece(s) of the network stay "
                                 "apart: no street through the target reaches them.")
        results = {self.OUTPUT: qgis_io.write_sink(
            self, parameters, self.OUTPUT, context, result.geometry, result.table,
            random_walk.ROAD_FIELDS, QgsWkbTypes.Type.LineString, target.source_crs, target.crs,
            feedback)}
        qgis_io.style_output(context, results[self.OUTPUT], "roads_by_level.qml")
        if self.given(parameters, self.OUTPUT_EXISTING):
            given, table = random_walk.given_with_junctions(existing_lines, result.geometry)
            results[self.OUTPUT_EXISTING] = qgis_io.write_sink(
                self, parameters, self.OUTPUT_EXISTING, context, given, table,
                random_walk.ROAD_FIELDS, QgsWkbTypes.Type.LineString, target.source_crs,
                target.crs, feedback)
            qgis_io.style_output(context, results[self.OUTPUT_EXISTING], "roads_by_level.qml")
        if self.given(parameters, self.OUTPUT_INTERSECTIONS):
            results[self.OUTPUT_INTERSECTIONS] = qgis_io.write_sink(
                self, parameters, self.OUTPUT_INTERSECTIONS, context,
                *random_walk.points_used(result, target.geometry), random_walk.POINT_FIELDS,
                QgsWkbTypes.Type.Point, target.source_crs, target.crs, feedback)
            qgis_io.style_output(context, results[self.OUTPUT_INTERSECTIONS], "intersections.qml")
        if self.given(parameters, self.OUTPUT_BLOCKS):
            faces, table = random_walk.block_table(result, target=target.geometry)
            feedback.pushInfo(f"{len(faces)} blocks closed by the new streets.")
            results[self.OUTPUT_BLOCKS] = qgis_io.write_sink(
                self, parameters, self.OUTPUT_BLOCKS, context, faces, table,
                random_walk.BLOCK_FIELDS, QgsWkbTypes.Type.Polygon, target.source_crs, target.crs,
                feedback)
            qgis_io.style_output(context, results[self.OUTPUT_BLOCKS], "blocks.qml")
        feedback.setProgress(100)
        return results

