"""urbansynth:synthesizebuildingattributes - heights, levels, types and roofs of footprints
copied from similar example buildings (Hartmann thesis ch. 6)."""
import numpy as np
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.buildings import attribute_transfer as transfer
from ..plugin.buildings import attributes as building_attributes
from ..plugin.core.text import counted
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase



class SynthesizeBuildingAttributes(AlgorithmBase):
    GROUP_ID = "synthesis"
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
    KEEP_GIVEN = "KEEP_GIVEN"
    SEED = "SEED"
    OUTPUT = "OUTPUT"

    CHOICES = (("medoid", "Most typical of the k (lowest error)"),
               ("random", "Random among the k (keeps the example's spread)"))

    def name(self):
        return "synthesizebuildingattributes"

    def displayName(self):  # noqa: N802
        return "Synthesize building attributes (by example)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Every footprint (synthesized or real) gets height_m, levels, building_type and "
            "roof_shape copied from the most similar example building (Hartmann thesis, "
            "ch. 6): similar in shape, area, footprint coverage and grain around it, heights "
            "of the example buildings nearby and, when both road layers are given, distance "
            "to roads and arterials. Heights are kept in a range and levels scaled to a "
            "target floor-area ratio per block or district.\n\n"
            "Output: the footprints with their own fields plus those, source_id (the "
            "example's feature id) and similarity, in the footprints' CRS, styled by height."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        poly = [QgsProcessing.SourceType.TypeVectorPolygon]
        line = [QgsProcessing.SourceType.TypeVectorLine]
        self.add(QgsProcessingParameterFeatureSource(self.FOOTPRINTS, "Footprints", poly),
                 "Building footprints to attribute, e.g. from 'Synthesize building footprints' "
                 "or a real layer with missing heights (with KEEP_GIVEN on). A layer with a 'building' field (OSM "
                 "multipolygons) gives only its polygons with a building value; the others "
                 "(forests, water, boundaries) are skipped and counted.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_BUILDINGS, "Example buildings", poly),
            "Buildings with heights or levels: an OSM multipolygons layer (height, "
            "building:levels, building, roof:shape tags; polygons without 'building' are "
            "skipped), a cadastre layer, or the buildings output of 'Extract city blocks'.")
        for name, label, text in (
                (self.HEIGHT_FIELD, "Example height field (cadastre)",
                 "A numeric field with heights in metres; wins over OSM tags and height_m."),
                (self.LEVELS_FIELD, "Example levels field (cadastre)",
                 "A numeric field with the number of storeys; wins over OSM tags and levels.")):
            self.add(QgsProcessingParameterField(
                name, label, parentLayerParameterName=self.EXAMPLE_BUILDINGS,
                type=QgsProcessingParameterField.DataType.Numeric, optional=True), text, advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads around the footprints", line, optional=True),
            "With Example roads, the distance to roads and to arterials (level 0, or OSM "
            "motorway..secondary) becomes a feature.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_ROADS, "Example roads", line, optional=True),
            "Street centrelines around the example buildings (with Roads).")
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks for the floor-area ratio", poly, optional=True),
            "With a target FAR: the FAR is met per block (a footprint belongs to the block "
            "holding it). Without blocks it is met for the whole district (the convex hull "
            "of the footprints).")
        self.add(QgsProcessingParameterNumber(
            self.K_NEIGHBOURS, "Candidates per footprint (k)",
            QgsProcessingParameterNumber.Type.Integer, defaultValue=9, minValue=1, maxValue=100),
            "The k most similar example buildings are candidates; 1 copies the most similar.")
        self.add(QgsProcessingParameterEnum(
            self.CHOICE, "Choice among the candidates", options=[c[1] for c in self.CHOICES],
            defaultValue=0),
            "Most typical: the candidate with the median height (weighted by similarity). "
            "Random: drawn with weights falling off with the feature distance (seeded).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_HEIGHT, "Minimum height (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.0, minValue=0.0, maxValue=1000.0),
            "Heights below are raised to it (levels follow).")
        self.add(QgsProcessingParameterNumber(
            self.MAX_HEIGHT, "Maximum height (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=300.0, minValue=0.1, maxValue=1000.0),
            "Heights above are lowered to it (levels follow).")
        self.add(QgsProcessingParameterNumber(
            self.TARGET_FAR, "Target floor-area ratio (0 = none)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=0.0, minValue=0.0, maxValue=100.0),
            "Floor area (footprint x levels) / ground area, met by scaling levels per block "
            "(with Blocks) or for the district.")
        self.add(QgsProcessingParameterNumber(
            self.STOREY_HEIGHT, "Storey height (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=building_attributes.STOREY_HEIGHT, minValue=0.5, maxValue=20.0),
            "Metres per storey for examples with only a height or only levels.", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            # optional: a model saved before it existed still validates
            self.KEEP_GIVEN, "Keep the footprints' own heights and types", defaultValue=False,
            optional=True),
            "On (for a real layer with missing heights): a footprint that has a height or a "
            "number of storeys of its own (height_m / levels fields, OSM height / "
            "building:levels tags) keeps them, and a known building type or roof shape too; "
            "only what it lacks is copied (height_given says which kept theirs; their levels "
            "stay as they are under a target FAR). Off (the default, for synthesized "
            "footprints, which carry their source building's height): every footprint takes "
            "its donor's.")
        self.add_seed("The same seed gives the same result (random choice among the "
                      "candidates).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Buildings with attributes", QgsProcessing.SourceType.TypeVectorPolygon),
            "Footprints with height_m, levels, building_type, roof_shape, source_id (the "
            "example building's feature id), similarity (1 / (1 + feature distance) to it: 1 "
            "is an identical example), floor_area_m2 (footprint area x levels) and "
            "height_given (the footprint kept its own height: KEEP_GIVEN).")

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        far = self.number(parameters, self.TARGET_FAR, context)
        lo = self.number(parameters, self.MIN_HEIGHT, context)
        hi = self.number(parameters, self.MAX_HEIGHT, context)
        if hi <= lo:
            raise QgsProcessingException(f"The maximum height ({hi:g} m) must be larger than "
                                         f"the minimum height ({lo:g} m).")
        footprints = self.only_buildings(
            qgis_io.read_source(self, parameters, self.FOOTPRINTS, context, feedback,
                                kind="polygons"), feedback)
        crs = footprints.crs
        examples, attrs = self._examples(parameters, context, feedback, footprints)
        feedback.setProgress(10)
        road_lines, arterials = self.roads_and_arterials(parameters, self.ROADS, context,
                                                         feedback, crs)
        ex_lines, ex_arterials = self.roads_and_arterials(parameters, self.EXAMPLE_ROADS,
                                                          context, feedback, examples.crs)
        if (road_lines is None) != (ex_lines is None):
            feedback.pushInfo("Road distances are used only with both Roads and Example roads.")
        blocks = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                     kind="polygons", target_crs=crs, optional=True)
        if blocks is not None:
            blocks = blocks.geometry
        given = self._attributes_of(footprints, "", "", parameters, context) \
            if self.parameterAsBool(parameters, self.KEEP_GIVEN, context) else None
        if given is not None and "height_m" in footprints.attributes:
            refused = building_attributes.unreadable_values(
                footprints.attributes["height_m"].to_numpy(dtype=object),
                building_attributes.parse_height)
            if refused:
                feedback.pushWarning(
                    f"{counted(len(refused), 'height')} of {footprints.name} not kept (no height "
                    f"from 0 to 1,000 m: {', '.join(map(str, refused[:5]))}"
                    f"{', ...' if len(refused) > 5 else ''}): those footprints get one from "
                    "the example.")
        result = qgis_io.run_engine(
            examples.name, transfer.transfer_attributes, footprints.geometry, examples.geometry,
            attrs, example_ids=examples.fids, roads=road_lines, arterials=arterials,
            example_roads=ex_lines, example_arterials=ex_arterials,
            k=self.number(parameters, self.K_NEIGHBOURS, context),
            seed=self.seed(parameters, context), min_height=lo, max_height=hi,
            target_far=far if far > 0 else None, blocks=blocks,
            storey_height=self.number(parameters, self.STOREY_HEIGHT, context),
            choice_mode=self.CHOICES[self.parameterAsEnum(parameters, self.CHOICE, context)][0],
            given=given, progress=qgis_io.progress_for(feedback, 15, 85))
        self._log(result.stats, lo, hi, far, blocks is not None, feedback)
        # the input's own fields first, then the new ones (replacing same-named fields)
        own = qgis_io.carried_fields(
            self.parameterAsSource(parameters, self.FOOTPRINTS, context).fields(),
            [n for n, _ in transfer.OUTPUT_FIELDS], footprints.renamed)
        table = result.table.copy()
        for n, _ in own:
            if n in footprints.attributes:
                table[n] = footprints.attributes[n].to_numpy(dtype=object)
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, footprints.geometry,
                                  table, own + transfer.OUTPUT_FIELDS, QgsWkbTypes.Type.MultiPolygon,
                                  footprints.source_crs, crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    def _examples(self, parameters, context, feedback, footprints):
        """The example buildings (only those with a 'building' value when the layer has
        that field) and their attributes (height, levels, type, roof), in their own working
        CRS, or the footprints' where they overlap (:func:`qgis_io.example_in_place`)."""
        hf = self.parameterAsString(parameters, self.HEIGHT_FIELD, context)
        lf = self.parameterAsString(parameters, self.LEVELS_FIELD, context)
        frame = qgis_io.read_source(
            self, parameters, self.EXAMPLE_BUILDINGS, context, feedback, kind="polygons",
            fields=["building", "other_tags", "height_m", "levels", "building_type", hf, lf,
                    *building_attributes.TAG_FIELDS],
            required_fields=[f for f in (hf, lf) if f])
        frame = qgis_io.example_in_place(self.only_buildings(frame, feedback),
                                         footprints.geometry, footprints.crs, context, feedback)
        attrs = self._attributes_of(frame, hf, lf, parameters, context)
        n_h = int(np.isfinite(attrs["height_m"].to_numpy(dtype=float)).sum())
        feedback.pushInfo(f"{frame.name}: {n_h} of {len(frame)} example buildings have a "
                          "height or levels.")
        if n_h == 0:
            # a warning, not an error: the run goes on and writes types and roofs
            feedback.pushWarning(
                f"Layer {frame.name}: no example building has a height or a number of levels "
                "(OSM height / building:levels, height_m / levels, or the height field): only "
                "types and roof shapes are transferred, heights and levels stay empty.")
        return frame, attrs

    def _attributes_of(self, frame, hf, lf, parameters, context):
        """Height, levels, type and roof of each building of ``frame``: from the fields
        ``hf`` / ``lf`` when named, else height_m / levels, and the OSM tags."""
        a = frame.attributes
        height = a[hf] if hf else (a["height_m"] if "height_m" in a else None)
        levels = a[lf] if lf else (a["levels"] if "levels" in a else None)
        attrs = self.building_attributes_of(
            frame, height=None if height is None else height.to_numpy(dtype=object),
            levels=None if levels is None else levels.to_numpy(dtype=object),
            storey_height=self.number(parameters, self.STOREY_HEIGHT, context))
        if "building_type" in a and "building" not in a:
            attrs["building_type"] = a["building_type"].to_numpy(dtype=object)
        return attrs

    @staticmethod
    def _log(s, lo, hi, far, per_block, feedback):
        if s["no_heights"]:   # the error naming the example layer was given as it was read
            feedback.pushInfo(
                f"{counted(s['n_footprints'], 'footprint')} attributed with types and roofs "
                f"from {counted(s['n_donors'], 'example building')}; heights and levels stay "
                "empty.")
        else:
            feedback.pushInfo(f"{counted(s['n_footprints'], 'footprint')} attributed, "
                              f"{s['n_with_height']} with a height, from "
                              f"{counted(s['n_donors'], 'example building')} with a height "
                              f"(features: {s['features']}).")
        if s.get("n_height_given"):
            feedback.pushInfo(counted(s["n_height_given"], "footprint keeps its own height",
                                      "footprints keep their own height") + " (KEEP_GIVEN).")
        if s["n_clipped"]:
            feedback.pushInfo(f"{counted(s['n_clipped'], 'height')} clipped into "
                              f"{lo:g}..{hi:g} m.")
        if far > 0:
            feedback.pushInfo(f"Floor-area ratio {s['far_min']:.2f}..{s['far_max']:.2f} "
                              f"(target {far:g}).")

            def stays(n):   # the target is met per block, or for the district as a whole
                if not per_block:
                    return "The district stays", "its footprints cover", "it"
                one = n == 1
                return (counted(n, "block stays", "blocks stay"),
                        "its footprints cover" if one else "their footprints cover",
                        "it" if one else "them")
            if s.get("n_blocks_short_of_far"):
                who, cover, it = stays(s["n_blocks_short_of_far"])
                feedback.pushWarning(
                    f"{who} more than {100 * transfer.FAR_SHORT:.0f} % under the target "
                    f"floor-area ratio: {cover} too little of {it}; "
                    f"{counted(s['n_at_max_height'], 'footprint stands', 'footprints stand')} "
                    f"at the maximum height ({hi:g} m). Raise MAX_HEIGHT or lower the target, "
                    "or give denser footprints.")
            if s.get("n_blocks_over_far"):
                who, cover, it = stays(s["n_blocks_over_far"])
                feedback.pushWarning(
                    f"{who} more than {100 * transfer.FAR_SHORT:.0f} % over the target "
                    f"floor-area ratio: {cover} more than it at the minimum height "
                    f"({lo:g} m). Raise the target or lower MIN_HEIGHT, or give sparser "
                    "footprints.")
            if s.get("n_outside_blocks"):
                feedback.pushInfo(counted(s["n_outside_blocks"], "footprint lies in no block "
                                          "and keeps its levels.", "footprints lie in no "
                                          "block and keep their levels."))
