"""urbansynth:synthesizepartbuildings - buildings made of parts along skeletons or stacked on
sites (Hartmann thesis ch. 6)."""
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from ..plugin.buildings import part_buildings, parts
from ..plugin.core.progress import InputError
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase


class SynthesizePartBuildings(AlgorithmBase):
    GROUP_ID = "synthesis"
    SKELETON = "SKELETON"
    PARTS_LIBRARY = "PARTS_LIBRARY"
    BUILDING_PARTS = "BUILDING_PARTS"
    BLOCKS = "BLOCKS"
    TARGET_FAR = "TARGET_FAR"
    PARTS_DEPTH = "PARTS_DEPTH"
    PARTS_HEIGHT = "PARTS_HEIGHT"
    PARTS_FAR_MIN = "PARTS_FAR_MIN"
    PARTS_FAR_MAX = "PARTS_FAR_MAX"
    PARTS_FLOOR_AREA = "PARTS_FLOOR_AREA"
    PARTS_COUNTS = "PARTS_COUNTS"
    K_SOLUTIONS = "K_SOLUTIONS"
    AREA_RESOLUTION = "AREA_RESOLUTION"
    CORNER_TOLERANCE = "CORNER_TOLERANCE"
    SKELETON_SIMPLIFY = "SKELETON_SIMPLIFY"
    SKELETON_NETWORK = "SKELETON_NETWORK"
    OUTPUT = "OUTPUT"

    #: The longest skeleton of one building (the part sequences grow with its length / 0.2 m).
    MAX_SKELETON_M = 5_000.0

    #: built-in parts databases (parts.py): key, label
    PARTS_LIBRARIES = (("terrace", "Built-in terrace parts (along the skeleton)"),
                       ("terrace_2m", "Built-in terrace parts, 2 m lengths only (fast FAR)"),
                       ("skyscraper", "Built-in skyscraper floors (stacked on the site)"))

    def name(self):
        return "synthesizepartbuildings"

    def displayName(self):  # noqa: N802
        return "Synthesize buildings from parts"

    def shortHelpString(self):  # noqa: N802
        return (
            "Per Skeleton feature one building made of the k best sequences of building parts "
            "meeting the constraints exactly (Hartmann thesis, ch. 6): the length of the "
            "skeleton, FAR or floor area, counts. End parts go at the ends of a line, corner "
            "parts at its vertices, parts follow a polygon's ring all round (a block's offset "
            "polygon); floor parts (the skyscraper library) are stacked to the height on the "
            "polygon as site.\n\n"
            "Output: one PolygonZ per part (z = base_m) with building_id, solution (1 = best), "
            "cost, kind, base_m, top_m, height_m, levels and floor_area_m2, for QGIS 3D "
            "(extrude by height_m), in the skeleton's CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        poly = [QgsProcessing.SourceType.TypeVectorPolygon]
        self.add(QgsProcessingParameterFeatureSource(
            self.SKELETON, "Skeletons", [QgsProcessing.SourceType.TypeVectorLine] + poly),
            "One building per feature. A line is the street-side facade line: parts extend "
            "away from the street, on the side opposite to a 'front' field (left / right of "
            "the line's direction; default right), with end parts at its ends and corner parts "
            "at its vertices. A polygon is filled all round its ring (e.g. a block buffered "
            "inward by half a street), or is the site a tower of floor parts stands on.")
        self.add(QgsProcessingParameterBoolean(
            self.SKELETON_NETWORK, "Lines are wing centrelines (T-junctions, 1.5D)",
            defaultValue=False),
            "Lines that touch form one building (thesis ch. 6, Fig. 6.6): each line is a "
            "wing's centreline, parts reach half their depth to both sides, T-parts sit "
            "where a wing ends on another one, corner parts at bends, end parts at free "
            "ends; at most one closed loop (a courtyard). A 'counts' field ('doors=2..4; "
            "straight=1') constrains the parts of that wing alone (local constraints).")
        self.add(QgsProcessingParameterEnum(
            self.PARTS_LIBRARY, "Built-in parts library",
            options=[p[1] for p in self.PARTS_LIBRARIES], defaultValue=0),
            "Used without a Building parts layer. Terrace: 36 straight, corner and end parts "
            "and 3 T-parts, "
            "3-5 levels of 3 m (the 2 m variant leaves out the 4.2-5 m infill parts so that "
            "FAR constraints stay fast, but fills only skeletons with sides on a 2 m grid). "
            "Skyscraper: 18 square floor parts of 20-40 m (thesis Fig. 6.5).")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDING_PARTS, "Building parts", poly, optional=True),
            "A parts database: footprint polygons (any position) with fields 'kind' (floor, "
            "straight, corner, end_left, end_right, tee), 'length_m' (along the skeleton; a "
            "floor's height) and 'height_m'; optional part_id, depth_m, levels, floor_area_m2, "
            "area_left_m2 / area_right_m2 (cross-sections), angle_deg (a corner's turn), "
            "branch_m / area_branch_m2 (a T-part's stub and branch cross-section) and "
            "numeric fields to count. Floor parts only: towers; otherwise parts along the "
            "skeleton.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks (sites)", poly, optional=True),
            "A building's site is the block holding most of its skeleton (without blocks: "
            "the skeleton polygon itself); FAR constraints refer to it.")
        number = QgsProcessingParameterNumber.Type.Double
        for name, label, default, lo, hi, text, advanced in (
                (self.TARGET_FAR, "Target floor-area ratio (0 = none)", 0.0, 0.0, 100.0,
                 "Every building's exact FAR on its site.", False),
                (self.PARTS_DEPTH, "Depth of the built-in terrace parts (m)", 12.0, 3.0, 50.0,
                 "How far the built-in terrace parts reach away from the street.", True),
                (self.PARTS_HEIGHT, "Tower height (m, floor parts)", 120.0, 0.2, 1000.0,
                 "Floor parts are stacked to exactly this height (on the 0.2 m grid).", False),
                (self.PARTS_FAR_MIN, "Minimum FAR (0 = none)", 0.0, 0.0, 100.0,
                 "Lower bound of each building's floor-area ratio on its site (a wide interval "
                 "with the full terrace library is slow: use a coarser floor-area grid or the "
                 "2 m library).", False),
                (self.PARTS_FAR_MAX, "Maximum FAR (0 = none)", 0.0, 0.0, 100.0,
                 "Upper bound of each building's floor-area ratio on its site.", False),
                (self.PARTS_FLOOR_AREA, "Exact floor area per building (m², 0 = none)", 0.0,
                 0.0, 1e7, "Each building's total floor area (sum of its parts' "
                 "floor_area_m2).", False)):
            self.add(QgsProcessingParameterNumber(name, label, number, defaultValue=default,
                                                  minValue=lo, maxValue=hi), text, advanced)
        self.add(QgsProcessingParameterString(
            self.PARTS_COUNTS, "Count constraints", optional=True),
            "Bounds on counts per building, 'name=lo..hi' or 'name=n' separated by ';', where "
            "name is a part kind or a numeric field of the parts, e.g. 'corner=4; doors=2..6' "
            "(the built-in terrace parts have doors and balconies).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.K_SOLUTIONS, "Solutions per building (k best)",
            QgsProcessingParameterNumber.Type.Integer, defaultValue=1, minValue=1, maxValue=50),
            "The k cheapest distinct part sequences (cost: cross-section disagreement between "
            "neighbours), all written with solution = 1..k in order of cost.")
        for name, label, default, lo, hi, text in (
                (self.AREA_RESOLUTION, "Floor-area grid (m²)", 1.0, 0.01, 1000.0,
                 "Grid of the floor-area sums (thesis: 1 m²). A coarser grid makes wide FAR "
                 "intervals much faster, meeting the bounds to half a grid step per part."),
                (self.CORNER_TOLERANCE, "Corner angle tolerance (°)", parts.CORNER_TOLERANCE,
                 0.0, 90.0, "A corner part fits a skeleton vertex whose turn is this close to "
                 "its angle."),
                (self.SKELETON_SIMPLIFY, "Skeleton simplification (m)", 0.5, 0.0, 50.0,
                 "Vertices closer than this to a straight line are dropped first, so that "
                 "digitising noise makes no corners.")):
            self.add(QgsProcessingParameterNumber(name, label, number, defaultValue=default,
                                                  minValue=lo, maxValue=hi), text, True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Building parts", QgsProcessing.SourceType.TypeVectorPolygon),
            "One PolygonZ per part with building_id, solution, base_m, top_m, height_m, "
            "levels and floor_area_m2.")

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        frame, kind, skeletons, building_ids, fronts = self._skeletons(parameters, context,
                                                                       feedback)
        longest = float(shapely.length(skeletons).max()) if len(skeletons) else 0.0
        self.bound_work(f"Layer {frame.name} (its longest skeleton {longest:,.0f} m)",
                        longest, self.MAX_SKELETON_M, "m of building along one skeleton",
                        "split long skeletons into the buildings they stand for")
        library, label = self._library(parameters, context, feedback)
        towers = set(library.table["kind"]) == {"floor"}
        if towers and kind != "polygons":
            raise QgsProcessingException(
                f"Layer {frame.name} has lines: floor parts ({label}) are stacked on sites, "
                "so the Skeleton must hold polygons.")
        far = qgis_io.run_engine("Parameters", part_buildings.far_bounds,
                                 self.number(parameters, self.TARGET_FAR, context),
                                 self.number(parameters, self.PARTS_FAR_MIN, context),
                                 self.number(parameters, self.PARTS_FAR_MAX, context))
        counts = qgis_io.run_engine(
            "Parameter PARTS_COUNTS", part_buildings.parse_counts,
            self.parameterAsString(parameters, self.PARTS_COUNTS, context), library, label)
        blocks = None
        if self.given(parameters, self.BLOCKS):
            blocks = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                         kind="polygons", target_crs=frame.crs).geometry
        local = None
        if kind == "lines" and self.parameterAsBoolean(parameters, self.SKELETON_NETWORK,
                                                       context):
            frame = qgis_io.read_source(self, parameters, self.SKELETON, context, feedback,
                                        kind="lines", fields=["counts"])
            lines, index = shapely.get_parts(frame.geometry, return_index=True)
            skeletons, building_ids, local = qgis_io.run_engine(
                f"Layer {frame.name}", part_buildings.wing_networks, lines,
                frame.fids[index], qgis_io.field_values(frame, "counts")[index], library,
                label)
            fronts = [None] * len(skeletons)
            feedback.pushInfo(f"{frame.name}: {len(lines)} wing lines form {len(skeletons)} "
                              "buildings.")
        floor_area = self.number(parameters, self.PARTS_FLOOR_AREA, context)
        height = self.number(parameters, self.PARTS_HEIGHT, context)
        feedback.pushInfo(f"{len(skeletons)} buildings from {label} ({len(library)} parts, "
                          f"{library.n_transitions} transitions)"
                          + (f", towers of {height:g} m." if towers else "."))
        result = qgis_io.run_engine(
            f"Layer {frame.name}", part_buildings.build_buildings, skeletons, building_ids,
            fronts, library, tower_height=height if towers else None,
            site_area=part_buildings.site_areas(skeletons, blocks), far=far,
            floor_area=floor_area if floor_area > 0 else None, counts=counts,
            k=self.number(parameters, self.K_SOLUTIONS, context),
            corner_tolerance=self.number(parameters, self.CORNER_TOLERANCE, context),
            area_resolution=self.number(parameters, self.AREA_RESOLUTION, context),
            local=local, progress=qgis_io.progress_for(feedback, 10, 90))
        for building_id, reason in result.failed[:10]:
            feedback.reportError(f"Layer {frame.name}, feature {building_id}: {reason}",
                                 fatalError=False)
        table = result.table
        feedback.pushInfo(
            f"{len(skeletons) - len(result.failed)} of {len(skeletons)} buildings made "
            f"({len(result.failed)} infeasible), {len(table)} parts; floor area "
            f"{table.loc[table.solution == 1, 'floor_area_m2'].sum():,.0f} m² in the best "
            "solutions.")
        # PolygonZ at each part's base (QGIS 3D: extrude by height_m)
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry,
                                  table, part_buildings.OUTPUT_FIELDS, QgsWkbTypes.Type.MultiPolygonZ,
                                  frame.source_crs, frame.crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    def _library(self, parameters, context, feedback):
        """The parts database (a Building parts layer, else a built-in one) and its name."""
        if self.given(parameters, self.BUILDING_PARTS):
            # any position: read in its own working CRS (projected into the target's zone
            # a library drawn elsewhere changed size); entries may share a shape
            frame = qgis_io.read_source(self, parameters, self.BUILDING_PARTS, context,
                                        feedback, kind="polygons", read_twice=True)
            table = frame.attributes.drop(columns=[c for c in frame.attributes
                                                   if c.lower() == "fid"])
            try:   # the engine's message names the layer already
                library = parts.library_from_table(table, frame.geometry,
                                                   name=f"Layer {frame.name}")
            except InputError as err:
                raise QgsProcessingException(str(err)) from err
            return library, frame.name
        key = self.PARTS_LIBRARIES[self.parameterAsEnum(parameters, self.PARTS_LIBRARY,
                                                        context)][0]
        if key == "skyscraper":
            return parts.skyscraper_library(), "the built-in skyscraper floors"
        depth = self.number(parameters, self.PARTS_DEPTH, context)
        return (parts.terrace_library(depth=depth, infill=key == "terrace"),
                "the built-in terrace parts")

    def _skeletons(self, parameters, context, feedback):
        """Skeleton parts (multi-part features split, lines merged and simplified) with the
        feature id each belongs to and its street side."""
        kind = "polygons" if qgis_io.geometry_kind(self, parameters, self.SKELETON,
                                                   context) == "polygons" else "lines"
        frame = qgis_io.read_source(self, parameters, self.SKELETON, context, feedback,
                                    kind=kind, fields=["front"])
        geoms = frame.geometry
        if kind == "lines":
            geoms = shapely.line_merge(geoms)
        tol = self.number(parameters, self.SKELETON_SIMPLIFY, context)
        if tol > 0:
            geoms = shapely.simplify(geoms, tol, preserve_topology=True)
        pieces, index = shapely.get_parts(geoms, return_index=True)
        if len(pieces) > len(geoms):
            feedback.pushInfo(f"{frame.name}: {len(pieces) - len(geoms)} extra parts of "
                              "multi-part features are built as buildings of their own "
                              "(same building_id).")
        front = qgis_io.field_values(frame, "front", "right")
        fronts = []
        for i in index:
            value = front[i]
            value = "right" if value is None or str(value).strip() == "" else \
                str(value).strip().lower()
            if value not in ("left", "right"):
                raise QgsProcessingException(
                    f"Layer {frame.name}, feature {frame.fids[i]}: front must be 'left' or "
                    f"'right' (the street side of the line), not '{front[i]}'.")
            fronts.append(value)
        return frame, kind, pieces, frame.fids[index], fronts
