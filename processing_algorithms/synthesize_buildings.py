"""urbansynth:synthesizebuildings - building attributes or models per footprint or parcel
(Hartmann thesis ch. 6, Scharl 2010 ch. 6)."""
from collections import namedtuple

import numpy as np
import pandas as pd
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

from ..plugin import building_attribute_transfer as transfer
from ..plugin import building_attributes, building_bestfit, qgis_io, roads
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
    OUTPUT = "OUTPUT"

    CHOICES = (("medoid", "Most typical of the k (lowest error)"),
               ("random", "Random among the k (keeps the example's spread)"))

    def __init__(self):
        super().__init__()
        # method key -> label, needed parameters, handler
        self.METHODS = (
            Method("attributes", "Attributes from similar example buildings",
                   (self.FOOTPRINTS, self.EXAMPLE_BUILDINGS), self._attributes),
            Method("bestfit", "Best-fitting library building per parcel (Scharl)",
                   (self.PARCELS, self.ROADS), self._bestfit),
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
            "Outputs are in the input layer's CRS, styled by height."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=[m.label for m in self.METHODS], defaultValue=0),
            "Attributes: needs Footprints and Example buildings. Best fit: needs Parcels and "
            "Roads (and optionally a Building library).")
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
            self.BLOCKS, "Blocks for the floor-area ratio (attributes)", poly, optional=True),
            "With a target FAR: the FAR is met per block (a footprint belongs to the block "
            "holding it). Without blocks it is met for the whole district (the convex hull "
            "of the footprints).")
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
            "(with Blocks) or for the district.")
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
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Buildings", QgsProcessing.TypeVectorPolygon),
            "Footprints with height_m, levels, building_type, roof_shape, source_id and "
            "similarity (attributes) or placed library buildings (best fit).")

    # ----------------------------------------------------------------------- run

    def _given(self, parameters, name):
        value = parameters.get(name)
        return value is not None and value != ""

    def _method(self, parameters, context):
        method = self.METHODS[self.parameterAsEnum(parameters, self.METHOD, context)]
        missing = [n for n in method.needs if not self._given(parameters, n)]
        if missing:
            names = ", ".join(self.parameterDefinition(n).description() for n in missing)
            return method, f"Method '{method.label}' needs: {names}."
        return method, None

    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, message = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, message
        _, message = self._method(parameters, context)
        return (False, message) if message else (True, "")

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
        if self._given(parameters, self.BLOCKS):
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
        feedback.pushInfo(f"{s['n_footprints']} footprints attributed from {s['n_donors']} "
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
        if not self._given(parameters, self.BUILDING_LIBRARY):
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
