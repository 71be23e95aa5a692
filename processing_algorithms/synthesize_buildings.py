"""urbansynth:synthesizebuildings - building attributes or models per footprint or parcel
(Hartmann thesis ch. 6, Scharl 2010 ch. 6)."""
from collections import namedtuple

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
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from ..plugin.buildings import attribute_transfer as transfer
from ..plugin.buildings import attributes as building_attributes
from ..plugin.buildings import bestfit as building_bestfit
from ..plugin.buildings import parts as building_parts
from ..plugin.buildings import structures as building_structures
from ..plugin.core.progress import InputError
from ..plugin.network import street_graph as roads
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase

#: One METHOD: its label in the dialog, the parameters it needs and the method that runs
#: it (a new method is one more entry of :data:`SynthesizeBuildings.METHODS`).
Method = namedtuple("Method", "key label needs handler")

TAG_FIELDS = ("height", "building:height", "building:levels", "levels", "roof:shape",
              "building:use", "amenity", "shop", "office", "tourism", "craft", "industrial",
              "religion", "healthcare", "leisure")
LIBRARY_RESERVED = {name for name, _ in building_bestfit.PLACEMENT_FIELDS}


class SynthesizeBuildings(AlgorithmBase):
    GROUP_ID = "synthesis"
    METHOD = "METHOD"
    FOOTPRINTS = "FOOTPRINTS"
    EXAMPLE_BUILDINGS = "EXAMPLE_BUILDINGS"
    HEIGHT_FIELD = "HEIGHT_FIELD"
    LEVELS_FIELD = "LEVELS_FIELD"
    ROADS = "ROADS"
    EXAMPLE_ROADS = "EXAMPLE_ROADS"
    BLOCKS = "BLOCKS"
    K_NEIGHBOURS = "K_NEIGHBOURS"
    CHOICE = "CHOICE"
    MIN_HEIGHT = "MIN_HEIGHT"
    MAX_HEIGHT = "MAX_HEIGHT"
    TARGET_FAR = "TARGET_FAR"
    STOREY_HEIGHT = "STOREY_HEIGHT"
    PARCELS = "PARCELS"
    BUILDING_LIBRARY = "BUILDING_LIBRARY"
    MIN_SETBACK = "MIN_SETBACK"
    STREET_REACH = "STREET_REACH"
    MAX_ANGLE = "MAX_ANGLE"
    SEED = "SEED"
    SKELETON = "SKELETON"
    PARTS_LIBRARY = "PARTS_LIBRARY"
    BUILDING_PARTS = "BUILDING_PARTS"
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

    CHOICES = (("medoid", "Most typical of the k (lowest error)"),
               ("random", "Random among the k (keeps the example's spread)"))
    #: built-in parts databases (building_parts): key, label
    PARTS_LIBRARIES = (("terrace", "Built-in terrace parts (along the skeleton)"),
                       ("terrace_2m", "Built-in terrace parts, 2 m lengths only (fast FAR)"),
                       ("skyscraper", "Built-in skyscraper floors (stacked on the site)"))

    def __init__(self):
        super().__init__()
        # method key -> label, needed parameters, handler
        self.METHODS = (
            Method("attributes", "Attributes from similar example buildings",
                   (self.FOOTPRINTS, self.EXAMPLE_BUILDINGS), self._attributes),
            Method("bestfit", "Best-fitting library building per parcel (Scharl)",
                   (self.PARCELS, self.ROADS), self._bestfit),
            Method("parts", "Part-based buildings along skeletons or stacked on sites (thesis)",
                   (self.SKELETON,), self._parts),
        )

    def name(self):
        return "synthesizebuildings"

    def displayName(self):  # noqa: N802
        return "Synthesize buildings"

    def shortHelpString(self):  # noqa: N802
        return (
            "Buildings for footprints or parcels.\n\n"
            "Attributes: every footprint (synthesised or real) gets height_m, levels, "
            "building_type and roof_shape copied from the most similar example building "
            "(shape, area, footprint coverage and grain around it, heights of the example "
            "buildings nearby, distance to roads and arterials when both road layers are "
            "given), so that heights and types follow the example; heights are kept in a "
            "range and levels scaled to a target floor-area ratio per block or district. "
            "Output: the footprints with those fields, source_id (the example's feature id) "
            "and similarity.\n\n"
            "Best fit (Scharl 2010, ch. 6): per parcel the largest building of a library "
            "(default: twelve built-in buildings) that fits inside it with every street "
            "access side facing a street and no blind side facing one (±30°), moved to the "
            "street with a minimum setback. Output: the placed footprints with source_id, "
            "rotation, offset_x/y, parcel_id and the library's attributes.\n\n"
            "Parts (Hartmann thesis, ch. 6): per Skeleton feature one building made of the k "
            "best sequences of building parts meeting the constraints exactly (length of the "
            "skeleton, FAR or floor area, counts): end parts at the ends of a line, corner "
            "parts at its vertices, parts following a polygon's ring all round (a block's "
            "offset polygon); floor parts (the skyscraper library) are stacked to the height "
            "on the polygon as site. Output: one PolygonZ per part (z = base_m) with "
            "building_id, solution (1 = best), cost, kind, base_m, top_m, height_m, levels and "
            "floor_area_m2, for QGIS 3D (extrude by height_m).\n\n"
            "Outputs are in the input layer's CRS, styled by height."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=[m.label for m in self.METHODS], defaultValue=0),
            "Attributes: needs Footprints and Example buildings. Best fit: needs Parcels and "
            "Roads (and optionally a Building library). Parts: needs a Skeleton (and "
            "optionally Building parts).")
        poly = [QgsProcessing.TypeVectorPolygon]
        line = [QgsProcessing.TypeVectorLine]
        self.add(QgsProcessingParameterFeatureSource(
            self.FOOTPRINTS, "Footprints (attributes)", poly, optional=True),
            "Building footprints to attribute, e.g. from 'Synthesize footprints' or a real "
            "layer with missing heights.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_BUILDINGS, "Example buildings (attributes)", poly, optional=True),
            "Buildings with heights or levels: an OSM multipolygons layer (height, "
            "building:levels, building, roof:shape tags; polygons without 'building' are "
            "skipped), a cadastre layer, or the buildings output of 'Extract city blocks'.")
        self.add(QgsProcessingParameterField(
            self.HEIGHT_FIELD, "Example height field (cadastre)",
            parentLayerParameterName=self.EXAMPLE_BUILDINGS, optional=True),
            "A field with heights in metres; wins over OSM tags and height_m.", advanced=True)
        self.add(QgsProcessingParameterField(
            self.LEVELS_FIELD, "Example levels field (cadastre)",
            parentLayerParameterName=self.EXAMPLE_BUILDINGS, optional=True),
            "A field with the number of storeys; wins over OSM tags and levels.", advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads (around the footprints or parcels)", line, optional=True),
            "Street centrelines. Best fit: which parcel and building sides face a street. "
            "Attributes: with Example roads, the distance to roads and to arterials (level "
            "0, or OSM motorway..secondary) becomes a feature.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_ROADS, "Example roads (attributes)", line, optional=True),
            "Street centrelines around the example buildings (with Roads).")
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks for the floor-area ratio (attributes, parts)", poly,
            optional=True),
            "With a target FAR: the FAR is met per block (a footprint belongs to the block "
            "holding it). Without blocks it is met for the whole district (the convex hull "
            "of the footprints). Parts: a building's site is the block holding most of its "
            "skeleton (without blocks: the skeleton polygon itself).")
        self.add(QgsProcessingParameterNumber(
            self.K_NEIGHBOURS, "Candidates per footprint (k)", QgsProcessingParameterNumber.Integer,
            defaultValue=9, minValue=1, maxValue=100),
            "The k most similar example buildings are candidates; 1 copies the most similar.")
        self.add(QgsProcessingParameterEnum(
            self.CHOICE, "Choice among the candidates", options=[c[1] for c in self.CHOICES],
            defaultValue=0),
            "Most typical: the candidate with the median height (weighted by similarity). "
            "Random: drawn with weights falling off with the feature distance (seeded).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_HEIGHT, "Minimum height (m)", QgsProcessingParameterNumber.Double,
            defaultValue=0.0, minValue=0.0, maxValue=1000.0),
            "Heights below are raised to it (levels follow).")
        self.add(QgsProcessingParameterNumber(
            self.MAX_HEIGHT, "Maximum height (m)", QgsProcessingParameterNumber.Double,
            defaultValue=300.0, minValue=0.1, maxValue=1000.0),
            "Heights above are lowered to it (levels follow).")
        self.add(QgsProcessingParameterNumber(
            self.TARGET_FAR, "Target floor-area ratio (0 = none)",
            QgsProcessingParameterNumber.Double, defaultValue=0.0, minValue=0.0, maxValue=100.0),
            "Floor area (footprint x levels) / ground area, met by scaling levels per block "
            "(with Blocks) or for the district. Parts: every building's exact FAR on its site "
            "(the block from Blocks holding it, else the skeleton polygon).")
        self.add(QgsProcessingParameterNumber(
            self.STOREY_HEIGHT, "Storey height (m)", QgsProcessingParameterNumber.Double,
            defaultValue=building_attributes.STOREY_HEIGHT, minValue=0.5, maxValue=20.0),
            "Metres per storey for examples with only a height or only levels.", advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.PARCELS, "Parcels (best fit)", poly, optional=True),
            "Parcels, e.g. from 'Subdivide blocks into parcels' (parcel_id is kept) or a "
            "cadastre.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDING_LIBRARY, "Building library (best fit)", poly, optional=True),
            "Library footprints (any position) with 'street_access_sides' and 'blind_sides': "
            "comma-separated edge indices of the exterior ring (edge i runs from vertex i to "
            "i+1). Empty: the built-in library of twelve buildings.")
        self.add(QgsProcessingParameterNumber(
            self.MIN_SETBACK, "Minimum setback (m)", QgsProcessingParameterNumber.Double,
            defaultValue=building_bestfit.DEFAULT_SETBACK, minValue=0.0, maxValue=100.0),
            "Distance kept between a building and its parcel's street sides.")
        self.add(QgsProcessingParameterNumber(
            self.STREET_REACH, "Street reach (m)", QgsProcessingParameterNumber.Double,
            defaultValue=building_bestfit.DEFAULT_REACH, minValue=0.1, maxValue=1000.0),
            "A side faces a street when a ray this long cast perpendicular from its centre "
            "hits a road centreline (setback plus half a street).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_ANGLE, "Maximum angle to the street (°)", QgsProcessingParameterNumber.Double,
            defaultValue=building_bestfit.MAX_ANGLE, minValue=0.0, maxValue=90.0),
            "A facing side is at most this far from parallel to the street (Scharl: 30°).",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.SEED, "Random seed", QgsProcessingParameterNumber.Integer, defaultValue=1,
            minValue=0),
            "The same seed gives the same result (random choice among the candidates).")
        self._init_parts(poly, line)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Buildings", QgsProcessing.TypeVectorPolygon),
            "Footprints with height_m, levels, building_type, roof_shape, source_id and "
            "similarity (attributes), placed library buildings (best fit) or building parts "
            "with building_id, solution, base_m, top_m and height_m (parts).")

    def _init_parts(self, poly, line):
        self.add(QgsProcessingParameterFeatureSource(
            self.SKELETON, "Skeleton (parts)", line + poly, optional=True),
            "One building per feature. A line is the street-side facade line: parts extend "
            "away from the street, on the side opposite to a 'front' field (left / right of "
            "the line's direction; default right), with end parts at its ends and corner parts "
            "at its vertices. A polygon is filled all round its ring (e.g. a block buffered "
            "inward by half a street), or is the site a tower of floor parts stands on.")
        self.add(QgsProcessingParameterEnum(
            self.PARTS_LIBRARY, "Built-in parts library (parts)",
            options=[p[1] for p in self.PARTS_LIBRARIES], defaultValue=0),
            "Used without a Building parts layer. Terrace: 36 straight, corner and end parts, "
            "3-5 levels of 3 m (the 2 m variant leaves out the 4.2-5 m infill parts so that "
            "FAR constraints stay fast, but fills only skeletons with sides on a 2 m grid). "
            "Skyscraper: 18 square floor parts of 20-40 m (thesis Fig. 6.5).")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDING_PARTS, "Building parts (parts)", poly, optional=True),
            "A parts database: footprint polygons (any position) with fields 'kind' (floor, "
            "straight, corner, end_left, end_right), 'length_m' (along the skeleton; a floor's "
            "height) and 'height_m'; optional part_id, depth_m, levels, floor_area_m2, "
            "area_left_m2 / area_right_m2 (cross-sections), angle_deg (a corner's turn) and "
            "numeric fields to count. Floor parts only: towers; otherwise parts along the "
            "skeleton.")
        self.add(QgsProcessingParameterNumber(
            self.PARTS_DEPTH, "Depth of the built-in terrace parts (m)",
            QgsProcessingParameterNumber.Double, defaultValue=12.0, minValue=3.0,
            maxValue=50.0),
            "How far the built-in terrace parts reach away from the street.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.PARTS_HEIGHT, "Tower height (m, floor parts)", QgsProcessingParameterNumber.Double,
            defaultValue=120.0, minValue=0.2, maxValue=1000.0),
            "Floor parts are stacked to exactly this height (on the 0.2 m grid).")
        self.add(QgsProcessingParameterNumber(
            self.PARTS_FAR_MIN, "Minimum FAR (parts, 0 = none)", 
            QgsProcessingParameterNumber.Double,
            defaultValue=0.0, minValue=0.0, maxValue=100.0),
            "Lower bound of each building's floor-area ratio on its site (see Target FAR; "
            "a wide interval with the full terrace library is slow: use a coarser floor-area "
            "grid or the 2 m library).")
        self.add(QgsProcessingParameterNumber(
            self.PARTS_FAR_MAX, "Maximum FAR (parts, 0 = none)", 
            QgsProcessingParameterNumber.Double,
            defaultValue=0.0, minValue=0.0, maxValue=100.0),
            "Upper bound of each building's floor-area ratio on its site.")
        self.add(QgsProcessingParameterNumber(
            self.PARTS_FLOOR_AREA, "Exact floor area per building (m², 0 = none)",
            QgsProcessingParameterNumber.Double, defaultValue=0.0, minValue=0.0,
            maxValue=1e7),
            "Each building's total floor area (sum of its parts' floor_area_m2).")
        self.add(QgsProcessingParameterString(
            self.PARTS_COUNTS, "Count constraints (parts)", optional=True),
            "Bounds on counts per building, 'name=lo..hi' or 'name=n' separated by ';', where "
            "name is a part kind or a numeric field of the parts, e.g. 'corner=4; doors=2..6' "
            "(the built-in terrace parts have doors and balconies).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.K_SOLUTIONS, "Solutions per building (k best)",
            QgsProcessingParameterNumber.Integer, defaultValue=1, minValue=1, maxValue=50),
            "The k cheapest distinct part sequences (cost: cross-section disagreement between "
            "neighbours), all written with solution = 1..k in order of cost.")
        self.add(QgsProcessingParameterNumber(
            self.AREA_RESOLUTION, "Floor-area grid (m²)", QgsProcessingParameterNumber.Double,
            defaultValue=1.0, minValue=0.01, maxValue=1000.0),
            "Grid of the floor-area sums (thesis: 1 m²). A coarser grid makes wide FAR "
            "intervals much faster, meeting the bounds to half a grid step per part.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.CORNER_TOLERANCE, "Corner angle tolerance (°)", 
            QgsProcessingParameterNumber.Double,
            defaultValue=building_parts.CORNER_TOLERANCE, minValue=0.0, maxValue=90.0),
            "A corner part fits a skeleton vertex whose turn is this close to its angle.",
            advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.SKELETON_NETWORK, "Skeleton lines are wing centrelines (T-junctions, 1.5D)",
            defaultValue=False),
            "Lines that touch form one building (thesis ch. 6, Fig. 6.6): each line is a "
            "wing's centreline, parts reach half their depth to both sides, T-parts sit "
            "where a wing ends on another one, corner parts at bends, end parts at free "
            "ends; at most one closed loop (a courtyard). A 'counts' field ('doors=2..4; "
            "straight=1') constrains the parts of that wing alone (local constraints).")
        self.add(QgsProcessingParameterNumber(
            self.SKELETON_SIMPLIFY, "Skeleton simplification (m)",
            QgsProcessingParameterNumber.Double, defaultValue=0.5, minValue=0.0, maxValue=50.0),
            "Vertices closer than this to a straight line are dropped first, so that digitising "
            "noise makes no corners.", advanced=True)

    # ----------------------------------------------------------------------- run

    def _method(self, parameters, context):
        method = self.METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        missing = [n for n in method.needs if not self.given(parameters, n)]
        if missing:
            names = ", ".join(self.parameterDefinition(n).description() for n in missing)
            return method, f"Method '{method.label}' needs: {names}."
        return method, None

    def input_error(self, parameters, context):
        return self._method(parameters, context)[1]

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        method, message = self._method(parameters, context)
        if message:
            raise QgsProcessingException(message)
        return method.handler(parameters, context, feedback)

    def _number(self, parameters, name, context, lo, hi):
        return qgis_io.check_number(self.parameterAsDouble(parameters, name, context), name, lo, hi)

    def _lines(self, parameters, name, context, feedback, crs):
        """Road lines (drivable classes when OSM) and the arterials among them."""
        frame = qgis_io.read_source(self, parameters, name, context, feedback, kind="lines",
                                    target_crs=crs, optional=True,
                                    fields=["highway", "other_tags", "level"])
        if frame is None:
            return None, None
        cls = qgis_io.osm_tag_column(frame, "highway")
        if cls is not None and any(c in roads.DRIVABLE_CLASSES for c in cls):
            frame = qgis_io.subset(frame, [c in roads.DRIVABLE_CLASSES for c in cls])
            cls = qgis_io.osm_tag_column(frame, "highway")
        if "level" in frame.attributes:
            level = pd.to_numeric(frame.attributes["level"], errors="coerce").to_numpy()
            art = level == 0
        elif cls is not None:
            art = np.array([c in roads.ARTERIAL_CLASSES for c in cls], dtype=bool)
        else:
            art = np.zeros(len(frame), dtype=bool)
        return frame.geometry, frame.geometry[art]

    # ----------------------------------------------------------------------- attributes

    def _examples(self, parameters, context, feedback, crs):
        hf = self.parameterAsString(parameters, self.HEIGHT_FIELD, context)
        lf = self.parameterAsString(parameters, self.LEVELS_FIELD, context)
        frame = qgis_io.read_source(
            self, parameters, self.EXAMPLE_BUILDINGS, context, feedback, kind="polygons",
            target_crs=crs, fields=["building", "other_tags", "height_m", "levels",
                                    "building_type", hf, lf, *TAG_FIELDS],
            required_fields=[f for f in (hf, lf) if f])
        if "building" in frame.attributes:
            value = frame.attributes["building"].to_numpy(dtype=object)
            keep = np.array([v is not None and str(v).strip() not in ("", "no") for v in value])
            if not keep.any():
                raise QgsProcessingException(f"Layer {frame.name} has no polygon with a "
                                             "'building' value.")
            if not keep.all():
                feedback.pushInfo(f"{frame.name}: {int((~keep).sum())} polygons without a "
                                  "'building' value skipped.")
                frame = qgis_io.subset(frame, keep)
        a = frame.attributes
        height = a[hf] if hf else (a["height_m"] if "height_m" in a else None)
        levels = a[lf] if lf else (a["levels"] if "levels" in a else None)
        attrs = qgis_io.run_engine(
            frame.name, building_attributes.building_attributes, len(frame),
            building=qgis_io.field_values(frame, "building"),
            other_tags=qgis_io.field_values(frame, "other_tags"),
            tags={k: a[k].to_numpy(dtype=object) for k in TAG_FIELDS if k in a},
            height=None if height is None else height.to_numpy(dtype=object),
            levels=None if levels is None else levels.to_numpy(dtype=object),
            storey_height=self._number(parameters, self.STOREY_HEIGHT, context, 0.5, 20.0))
        if "building_type" in a and "building" not in a:
            attrs["building_type"] = a["building_type"].to_numpy(dtype=object)
        n_h = int(np.isfinite(attrs["height_m"].to_numpy(dtype=float)).sum())
        feedback.pushInfo(f"{frame.name}: {n_h} of {len(frame)} example buildings have a "
                          "height or levels.")
        if n_h == 0:
            feedback.reportError(
                f"Layer {frame.name}: no example building has a height or a number of levels "
                "(OSM height / building:levels, height_m / levels, or the height field): only "
                "types and roof shapes are transferred, heights and levels stay empty.",
                fatalError=False)
        return frame, attrs

    def _attributes(self, parameters, context, feedback):
        far = self._number(parameters, self.TARGET_FAR, context, 0.0, 100.0)
        lo = self._number(parameters, self.MIN_HEIGHT, context, 0.0, 1000.0)
        hi = self._number(parameters, self.MAX_HEIGHT, context, 0.1, 1000.0)
        if hi <= lo:
            raise QgsProcessingException(f"The maximum height ({hi:g} m) must be larger than "
                                         f"the minimum height ({lo:g} m).")
        k = int(self._number(parameters, self.K_NEIGHBOURS, context, 1, 100))
        footprints = qgis_io.read_source(self, parameters, self.FOOTPRINTS, context, feedback,
                                         kind="polygons")
        crs = footprints.crs
        examples, attrs = self._examples(parameters, context, feedback, crs)
        feedback.setProgress(10)
        road_lines, arterials = self._lines(parameters, self.ROADS, context, feedback, crs)
        ex_lines, ex_arterials = self._lines(parameters, self.EXAMPLE_ROADS, context, feedback,
                                             crs)
        if (road_lines is None) != (ex_lines is None):
            feedback.pushInfo("Road distances are used only with both Roads and Example roads.")
        blocks = None
        if self.given(parameters, self.BLOCKS):
            blocks = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                         kind="polygons", target_crs=crs).geometry
        result = qgis_io.run_engine(
            examples.name, transfer.transfer_attributes, footprints.geometry, examples.geometry,
            attrs, example_ids=examples.fids, roads=road_lines, arterials=arterials,
            example_roads=ex_lines, example_arterials=ex_arterials, k=k,
            seed=int(self.parameterAsInt(parameters, self.SEED, context)),
            min_height=lo, max_height=hi, target_far=far if far > 0 else None, blocks=blocks,
            storey_height=self._number(parameters, self.STOREY_HEIGHT, context, 0.5, 20.0),
            choice_mode=self.CHOICES[self.parameterAsEnum(parameters, self.CHOICE, context)][0],
            progress=qgis_io.progress_for(feedback, 15, 85))
        s = result.stats
        if s["no_heights"]:
            feedback.reportError(
                f"No example building has a height or a number of levels: the "
                f"{s['n_footprints']} footprints get types and roofs from "
                f"{s['n_donors']} example buildings, and their heights stay empty.",
                fatalError=False)
        else:
            feedback.pushInfo(f"{s['n_footprints']} footprints attributed, "
                              f"{s['n_with_height']} with a height, from {s['n_donors']} "
                              f"example buildings with a height (features: {s['features']}).")
        if s["n_clipped"]:
            feedback.pushInfo(f"{s['n_clipped']} heights clipped into {lo:g}..{hi:g} m.")
        if far > 0:
            feedback.pushInfo(f"Floor-area ratio {s['far_min']:.2f}..{s['far_max']:.2f} "
                              f"(target {far:g}).")
            if s.get("n_outside_blocks"):
                feedback.pushInfo(f"{s['n_outside_blocks']} footprints lie in no block and "
                                  "keep their levels.")
        # the input's own fields first, then the new ones (replacing same-named fields)
        own = self._own_fields(parameters, self.FOOTPRINTS, context,
                               {n for n, _ in transfer.OUTPUT_FIELDS})
        table = result.table.copy()
        for n, _ in own:
            table[n] = footprints.attributes[n].to_numpy(dtype=object)
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, footprints.geometry,
                                  table, own + transfer.OUTPUT_FIELDS, QgsWkbTypes.MultiPolygon,
                                  footprints.source_crs, crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    def _own_fields(self, parameters, name, context, reserved):
        source = self.parameterAsSource(parameters, name, context)
        out = []
        for f in source.fields():
            if f.name() in reserved or f.name().lower() == "fid":
                continue
            typ = {2: "int", 3: "int", 4: "int", 5: "int", 6: "float", 1: "bool"}.get(int(f.type()), "str")
            out.append((f.name(), typ))
        return out

    # ----------------------------------------------------------------------- best fit

    def _library(self, parameters, context, feedback, crs):
        if not self.given(parameters, self.BUILDING_LIBRARY):
            feedback.pushInfo("Building library: the built-in library of twelve buildings.")
            return building_bestfit.default_library()
        frame = qgis_io.read_source(
            self, parameters, self.BUILDING_LIBRARY, context, feedback, kind="polygons",
            target_crs=crs, repair=False,
            required_fields=["street_access_sides", "blind_sides"])
        a = frame.attributes
        return qgis_io.run_engine(
            f"Layer {frame.name}", building_bestfit.library_from_table, frame.geometry,
            a["street_access_sides"].to_numpy(dtype=object), a["blind_sides"].to_numpy(dtype=object),
            source_ids=frame.fids, attributes=a)

    def _bestfit(self, parameters, context, feedback):
        parcels = qgis_io.read_source(self, parameters, self.PARCELS, context, feedback,
                                      kind="polygons", fields=["parcel_id"])
        crs = parcels.crs
        road_lines, _ = self._lines(parameters, self.ROADS, context, feedback, crs)
        library = self._library(parameters, context, feedback, crs)
        ids = None
        if "parcel_id" in parcels.attributes:
            ids = pd.to_numeric(parcels.attributes["parcel_id"], errors="coerce").to_numpy()
            if not np.isfinite(ids).all():
                ids = None
        result = qgis_io.run_engine(
            parcels.name, building_bestfit.fit_buildings, parcels.geometry, road_lines, library,
            parcel_ids=None if ids is None else ids.astype(np.int64),
            min_setback=self._number(parameters, self.MIN_SETBACK, context, 0.0, 100.0),
            reach=self._number(parameters, self.STREET_REACH, context, 0.1, 1000.0),
            max_angle=self._number(parameters, self.MAX_ANGLE, context, 0.0, 90.0),
            progress=qgis_io.progress_for(feedback, 10, 90))
        s = result.stats
        feedback.pushInfo(f"{s['n_placed']} of {s['n_parcels']} parcels got a building; "
                          f"{100 * s['empty_share']:.1f} % left empty ({s['no_street']} have "
                          "no side facing a street).")
        extra = []
        for col in result.table.columns:
            if col in LIBRARY_RESERVED or col.lower() == "fid":
                continue
            values = pd.to_numeric(result.table[col], errors="coerce")
            numeric = values.notna().sum() == result.table[col].notna().sum()
            extra.append((col, "float" if numeric else "str"))
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry,
                                  result.table, building_bestfit.PLACEMENT_FIELDS + extra,
                                  QgsWkbTypes.Polygon, parcels.source_crs, crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    # ----------------------------------------------------------------------- parts

    def _parts_library(self, parameters, context, feedback, crs):
        if self.given(parameters, self.BUILDING_PARTS):
            frame = qgis_io.read_source(self, parameters, self.BUILDING_PARTS, context,
                                        feedback, kind="polygons", target_crs=crs)
            table = frame.attributes.drop(columns=[c for c in frame.attributes
                                                   if c.lower() == "fid"])
            try:
                library = building_parts.library_from_table(table, frame.geometry,
                                                            name=f"Layer {frame.name}")
            except InputError as err:
                raise QgsProcessingException(str(err)) from err
            return library, frame.name
        key = self.PARTS_LIBRARIES[self.parameterAsEnum(parameters, self.PARTS_LIBRARY,
                                                        context)][0]
        if key == "skyscraper":
            return building_parts.skyscraper_library(), "the built-in skyscraper floors"
        depth = self._number(parameters, self.PARTS_DEPTH, context, 3.0, 50.0)
        return (building_parts.terrace_library(depth=depth, infill=key == "terrace"),
                "the built-in terrace parts")

    def _parts_counts(self, parameters, context, library, label):
        """'corner=4; doors=2..6' -> {'corner': (4, 4), 'doors': (2, 6)}, checked."""
        text = self.parameterAsString(parameters, self.PARTS_COUNTS, context) or ""
        try:
            return building_parts.parse_counts(text, library, label)
        except InputError as err:
            raise QgsProcessingException(str(err)) from err

    def _networks(self, parameters, context, feedback, library, label):
        """Buildings of touching wing lines (1.5D): one MultiLineString each, the smallest
        feature id, and the local constraints of its wings from a 'counts' field."""
        frame = qgis_io.read_source(self, parameters, self.SKELETON, context, feedback,
                                    kind="lines", fields=["counts"])
        lines, index = shapely.get_parts(frame.geometry, return_index=True)
        texts = qgis_io.field_values(frame, "counts", "")
        buildings, fids, local = [], [], []
        for group in building_structures.connected_networks(lines):
            buildings.append(shapely.multilinestrings(lines[group]))
            fids.append(int(frame.fids[index[group]].min()))
            wing = {}
            for k, i in enumerate(group):
                text = texts[index[i]]
                try:
                    counts = building_parts.parse_counts(
                        None if pd.isna(text) else str(text), library, label)
                except InputError as err:
                    raise QgsProcessingException(
                        f"Layer {frame.name}, feature {frame.fids[index[i]]}: {err}") from err
                if counts:
                    wing[k] = counts
            local.append(wing)
        feedback.pushInfo(f"{frame.name}: {len(lines)} wing lines form {len(buildings)} "
                          "buildings.")
        return frame, np.array(buildings, dtype=object), np.array(fids), local

    def _skeletons(self, parameters, context, feedback):
        """Skeleton parts (multi-part features split, lines merged) with their feature ids."""
        source = self.parameterAsSource(parameters, self.SKELETON, context)
        gtype = QgsWkbTypes.geometryType(source.wkbType()) if source is not None else None
        kind = "polygons" if gtype == QgsWkbTypes.PolygonGeometry else "lines"
        frame = qgis_io.read_source(self, parameters, self.SKELETON, context, feedback,
                                    kind=kind, fields=["front"])
        geoms = frame.geometry
        if kind == "lines":
            geoms = shapely.line_merge(geoms)
        tol = self._number(parameters, self.SKELETON_SIMPLIFY, context, 0.0, 50.0)
        if tol > 0:
            geoms = shapely.simplify(geoms, tol, preserve_topology=True)
        parts, index = shapely.get_parts(geoms, return_index=True)
        if len(parts) > len(geoms):
            feedback.pushInfo(f"{frame.name}: {len(parts) - len(geoms)} extra parts of "
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
        return frame, kind, parts, frame.fids[index], fronts

    def _sites(self, parameters, context, feedback, crs, parts):
        """Site area per skeleton part: the block holding most of it, else its own polygon."""
        area = np.where(shapely.get_type_id(parts) == 3, shapely.area(parts), np.nan)
        if not self.given(parameters, self.BLOCKS):
            return area
        blocks = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                     kind="polygons", target_crs=crs).geometry
        probe = shapely.buffer(parts, 1.0)
        tree = shapely.STRtree(blocks)
        i, j = tree.query(probe, predicate="intersects")
        if len(i):
            share = shapely.area(shapely.intersection(probe[i], blocks[j]))
            best = pd.DataFrame({"i": i, "j": j, "s": share}).sort_values("s").groupby("i").last()
            area[best.index.to_numpy()] = shapely.area(blocks[best["j"].to_numpy()])
        return area

    def _parts(self, parameters, context, feedback):
        frame, kind, parts, fids, fronts = self._skeletons(parameters, context, feedback)
        crs = frame.crs
        library, label = self._parts_library(parameters, context, feedback, crs)
        network = kind == "lines" and self.parameterAsBoolean(parameters,
                                                               self.SKELETON_NETWORK, context)
        local = [None] * len(parts)
        if network:
            frame, parts, fids, local = self._networks(parameters, context, feedback,
                                                       library, label)
            fronts = [None] * len(parts)
        kinds = set(library.table["kind"])
        towers = kinds == {"floor"}
        if towers and kind != "polygons":
            raise QgsProcessingException(
                f"Layer {frame.name} has lines: floor parts ({label}) are stacked on sites, "
                "so the Skeleton must hold polygons.")
        far = self._number(parameters, self.TARGET_FAR, context, 0.0, 100.0)
        lo = self._number(parameters, self.PARTS_FAR_MIN, context, 0.0, 100.0)
        hi = self._number(parameters, self.PARTS_FAR_MAX, context, 0.0, 100.0)
        if far > 0 and (lo > 0 or hi > 0):
            raise QgsProcessingException("Give either a Target FAR (exact) or a minimum / "
                                         "maximum FAR, not both.")
        if hi > 0 and hi < lo:
            raise QgsProcessingException(f"The maximum FAR ({hi:g}) is below the minimum "
                                         f"({lo:g}).")
        far_bounds = far if far > 0 else ((lo, hi if hi > 0 else np.inf) if lo > 0 or hi > 0
                                          else None)
        floor_area = self._number(parameters, self.PARTS_FLOOR_AREA, context, 0.0, 1e7)
        options = dict(
            floor_area=floor_area if floor_area > 0 else None,
            counts=self._parts_counts(parameters, context, library, label),
            k=int(self._number(parameters, self.K_SOLUTIONS, context, 1, 50)),
            area_resolution=self._number(parameters, self.AREA_RESOLUTION, context, 0.01,
                                         1000.0))
        site_area = self._sites(parameters, context, feedback, crs, parts)
        if far_bounds is not None and not np.isfinite(site_area).all():
            raise QgsProcessingException(
                f"Layer {frame.name}: a FAR needs a site for every building: give Blocks "
                "(the block holding each skeleton line is its site) or polygon skeletons.")
        height = self._number(parameters, self.PARTS_HEIGHT, context, 0.2, 1000.0)
        tolerance = self._number(parameters, self.CORNER_TOLERANCE, context, 0.0, 90.0)
        feedback.pushInfo(f"{len(parts)} buildings from {label} ({len(library)} parts, "
                          f"{library.n_transitions} transitions)"
                          + (f", towers of {height:g} m." if towers else "."))
        progress = qgis_io.progress_for(feedback, 10, 90)
        geoms, tables, failed = [], [], []
        for n, (skeleton, fid, front) in enumerate(zip(parts, fids, fronts)):
            sub = progress.sub(n / len(parts), (n + 1) / len(parts))
            if feedback.isCanceled():
                raise QgsProcessingException("Canceled by the user.")
            site = float(site_area[n]) if np.isfinite(site_area[n]) else None
            try:
                if towers:
                    result = qgis_io.run_engine(
                        frame.name, building_parts.stack_floors, library, height,
                        far=far_bounds, site=skeleton, site_area=site, progress=sub, **options)
                elif network:
                    result = qgis_io.run_engine(
                        frame.name, building_structures.build_along_network, skeleton,
                        library, far=far_bounds, site_area=site, local=local[n],
                        corner_tolerance=tolerance, progress=sub, **options)
                else:
                    result = qgis_io.run_engine(
                        frame.name, building_parts.build_along_skeleton, skeleton, library,
                        front=front, far=far_bounds, site_area=site,
                        corner_tolerance=tolerance, progress=sub, **options)
            except QgsProcessingException as err:
                if "Canceled" in str(err):
                    raise
                failed.append(f"feature {fid}: {str(err).split(': ', 1)[-1]}")
                continue
            table = result.table.copy()
            summary = result.summary.set_index("solution")
            table.insert(0, "building_id", int(fid))
            per_solution = summary.loc[table["solution"]]
            table["building_floor_area_m2"] = per_solution["floor_area_m2"].to_numpy()
            table["building_far"] = per_solution["far"].to_numpy()
            geoms.append(result.geometry)
            tables.append(table)
        if failed:
            for message in failed[:10]:
                feedback.reportError(f"Layer {frame.name}, {message}", fatalError=False)
            if not tables:
                raise QgsProcessingException(
                    f"Layer {frame.name}: no building could be made from {label}. "
                    f"{failed[0][0].upper()}{failed[0][1:]}")
        table = pd.concat(tables, ignore_index=True)
        geometry = np.concatenate(geoms)
        feedback.pushInfo(f"{len(tables)} of {len(parts)} buildings made ({len(failed)} "
                          f"infeasible), {len(table)} parts; floor area "
                          f"{table.loc[table.solution == 1, 'floor_area_m2'].sum():,.0f} m² "
                          "in the best solutions.")
        # PolygonZ at the part's base (QGIS 3D: extrude by height_m); back in the input CRS
        # first, since write_sink's reprojection is 2D
        geometry = qgis_io.reproject(geometry, crs, frame.source_crs, context)
        geometry = np.array([shapely.force_3d(g, z) for g, z in
                             zip(geometry, table["base_m"].to_numpy(float))], dtype=object)
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, geometry, table,
                                  PARTS_FIELDS, QgsWkbTypes.MultiPolygonZ, frame.source_crs,
                                  frame.source_crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}


#: the parts output: building_parts.PartsResult.table with the building it belongs to
PARTS_FIELDS = [("building_id", "int"), ("solution", "int"), ("cost", "float"),
                ("seq_index", "int"), ("part_id", "str"), ("kind", "str"), ("start_m", "float"),
                ("length_m", "float"), ("base_m", "float"), ("top_m", "float"),
                ("height_m", "float"), ("levels", "int"), ("floor_area_m2", "float"),
                ("building_floor_area_m2", "float"), ("building_far", "float")]
