"""urbansynth:splitdomain - street and parcel layouts by hierarchical domain splitting."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsProcessing,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.parcels import subdivision as parcels
from ..plugin.planned import domain_split, templates
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase


class SplitDomain(AlgorithmBase):
    GROUP_ID = "synthesis"
    REGION = "REGION"
    KEY_ROADS = "KEY_ROADS"
    KEY_AREAS = "KEY_AREAS"
    KEY_AREA_USE_FIELD = "KEY_AREA_USE_FIELD"
    TEMPLATES = "TEMPLATES"
    TEMPLATE_LAYER = "TEMPLATE_LAYER"
    PARCEL_LENGTH = "PARCEL_LENGTH"
    PARCEL_WIDTH = "PARCEL_WIDTH"
    STREET_WIDTH = "STREET_WIDTH"
    VARIATIONS = "VARIATIONS"
    SEED = "SEED"
    OPTIMISE = "OPTIMISE"
    REPAIR_LOTS = "REPAIR_LOTS"
    SETTLE_JOINTS = "SETTLE_JOINTS"
    OUTLINE_STREETS = "OUTLINE_STREETS"
    BACK_TO_BACK = "BACK_TO_BACK"
    FALLBACK_PARCELS = "FALLBACK_PARCELS"
    KEY_ROAD_CLASS_FIELD = "KEY_ROAD_CLASS_FIELD"
    OUTPUT_ROADS = "OUTPUT_ROADS"
    OUTPUT_PARCELS = "OUTPUT_PARCELS"
    OUTPUT_METRICS = "OUTPUT_METRICS"

    #: The most parcels one run lays out (about 11 km² of the paper's 30 x 18 m parcels;
    #: 1.5 km² take about 10 s on one core).
    MAX_PARCELS = 20_000

    #: TEMPLATES enum: (library subset, label), in enum order
    SUBSETS = [("strips", "Single-family: parcel strips and double strips (the paper's "
                          "comparison set)"),
               ("all", "All shipped: parcel strips, double strips, spikes (cul-de-sacs), "
                       "loops, parks"),
               ("double_strips", "Double strips only")]

    def name(self):
        return "splitdomain"

    def displayName(self):  # noqa: N802
        return "Split domain into streets and parcels (Yang 2013)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Lays out streets and parcels inside a region by hierarchical domain splitting "
            "(Yang et al. 2013, 'Urban Pattern'). A region is replaced by a template (parcel "
            "strip, double strip, spike / cul-de-sac, loop) warped onto it when one fits, "
            "chosen by its warp energy; otherwise "
            "it is split along the best-scoring streamline of a smooth cross field aligned "
            "with its boundary, recursively. The street mesh is then optimised (strip "
            "fitting, fairness, closeness) and the templates re-warped.\n\n"
            "Key roads are kept and split the region (a key road ending inside it is "
            "continued to the next street); motorways (class motorway / motorway_link in the "
            "class field) take no junction and give no frontage. Key areas (parks, schools, "
            "lakes) are left out and kept as parcels of their land use. The region outline "
            "counts as a street unless 'Outline is a street' is off. Several variations can "
            "be made at once; each parcel has street access, land use and Yang's quality "
            "(p_angle, p_area, undesirable). The metrics table has one row per variation "
            "with the paper's Table 1 columns, counting every designed parcel, parks "
            "included. Each joint between two lots is then moved to where the two are "
            "squarest (on by default, not in the paper). The optional lot repair (off by "
            "default, not in the paper) cuts "
            "misshapen lots to the rectangle on their street and turns the wedges into "
            "pocket parks, which still count. Outputs are in the region's CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.REGION, "Region", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "Polygon(s) to lay out (holes allowed). Their outlines are taken as streets.")
        self.add(QgsProcessingParameterFeatureSource(
            self.KEY_ROADS, "Key roads (kept)", [QgsProcessing.SourceType.TypeVectorLine], optional=True),
            "Main roads the design must keep; the parts inside the region split it.")
        self.add(QgsProcessingParameterFeatureSource(
            self.KEY_AREAS, "Key areas (parks, school, lake)", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Areas left out of the layout and kept as parcels of their own land use.")
        self.add(QgsProcessingParameterField(
            self.KEY_AREA_USE_FIELD, "Land-use field of the key areas",
            parentLayerParameterName=self.KEY_AREAS, optional=True),
            "Text field with the land use of each key area (default: park). Areas of one use "
            "are merged; where areas of different uses overlap, the first in the layer keeps "
            "the overlap.", advanced=True)
        self.add(QgsProcessingParameterEnum(
            self.TEMPLATES, "Templates", options=[label for _, label in self.SUBSETS],
            defaultValue=0),
            "Which templates of the shipped library (resources/templates/library.json) may "
            "be used. Ignored when a template layer is given.")
        self.add(QgsProcessingParameterFeatureSource(
            self.TEMPLATE_LAYER, "Template layer (drawn templates)",
            [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "User templates drawn in QGIS: one polygon per parcel or area, a text field "
            "'template' (the template each belongs to) and 'label' with the paper's labels "
            "(one letter; a feature without one is a parcel, any other label is refused): "
            "R parcel, P park, A area (a region of the next level, filled with parcel rows "
            "or parcelled: Yang's hierarchical templates), S the template's own street drawn "
            "as its surface (a cul-de-sac of any shape with its turning head, or a loop "
            "street as a ring with its connector; S alone marks the built-in spike). Rows of "
            "parcels are recognised from the drawing (1 row: strip, 2: double strip) and "
            "repeat along any street at the parcel length and width below, not as drawn; "
            "any other template (more rows, a park among the parcels, any shape) is warped "
            "as drawn onto a region corner to corner (a region's extra corners cost their "
            "turn), within 0.75-1.35 x its length and 0.8-1.25 x its "
            "depth, and chosen by its warp energy. Optional fields per template (the first "
            "value among its features): 'probability' (how common it is, default 1), "
            "'max_count' and 'min_count' (at most / at least this many per layout: Yang's k1 "
            "and k2; a minimum is met by repeating the search, up to 8 times, and the log says "
            "when it could not be).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.PARCEL_LENGTH, "Parcel length (depth, m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=30.0, minValue=1.0, maxValue=1000.0),
            "Depth of a parcel from its street (the paper: 30 m).")
        self.add(QgsProcessingParameterNumber(
            self.PARCEL_WIDTH, "Parcel width (frontage, m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=18.0, minValue=1.0, maxValue=1000.0),
            "Width of a parcel along its street (the paper: 18 m).")
        self.add(QgsProcessingParameterNumber(
            self.STREET_WIDTH, "Street width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=15.0, minValue=1.0, maxValue=200.0),
            "Full width of every street (the paper: 15 m); parcels stop at its edge, which "
            "bends as an arc where a street bends by up to 35° (a key road keeps its kinks).")
        self.add(QgsProcessingParameterNumber(
            self.VARIATIONS, "Variations", QgsProcessingParameterNumber.Type.Integer,
            defaultValue=1, minValue=1, maxValue=100),
            "Number of layouts to make (field 'variation' in every output).")
        self.add_seed(
            "The same seed gives the same layouts; variation v draws from (seed, v).")
        self.add(QgsProcessingParameterBoolean(
            self.OPTIMISE, "Optimise the street mesh", defaultValue=True),
            "Global optimisation of the streets made by splitting (strip fitting, fairness, "
            "closeness; w = 1, 0.8, 0.2; 10 iterations), then templates re-warped.",
            advanced=True)
        self.add(QgsProcessingParameterField(
            self.KEY_ROAD_CLASS_FIELD, "Road class field of the key roads",
            defaultValue="highway", parentLayerParameterName=self.KEY_ROADS, optional=True),
            "OSM-style class per key road; motorway and motorway_link take no junction.",
            advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.OUTLINE_STREETS, "Outline is a street", defaultValue=True),
            "On: the region is bounded by streets (the paper's boundary condition), laid as "
            "curves where the outline only bends (by under 35°, e.g. a buffer's arcs). Off: "
            "the outline is a 'no street' edge (a town's edge against fields): parcels back "
            "onto it and no street land is kept along it.", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.BACK_TO_BACK, "Rows back to back where no street is needed", defaultValue=True),
            "On: a split street between two blocks of parcel rows that both keep their "
            "template and street access without it becomes a 'no street' edge (two parcel "
            "strips back to back along their rear lot lines, rows end to end), up to a block "
            "as long as the longest row; so does one between parcel rows or a park and a "
            "park left in a small region (rows back onto it; the park keeps a street along "
            "at least a parcel width). A street cut in pieces where such edges meet it is "
            "dropped whole, when no block needs any piece and none would be left a dead "
            "end. Off: every split street is kept.", advanced=True)
        self.add(QgsProcessingParameterEnum(
            self.FALLBACK_PARCELS, "Parcels where no template fits",
            options=[parcels.METHODS[k].label for k in domain_split.FALLBACK_PARCELS],
            defaultValue=0),
            "How a region that no template fits and no street splits is parcelled (the "
            "paper's rule-based assignment): recursive cuts across its long axis or its "
            "longest side, whichever leaves squarer lots (default; squarer lots on odd "
            "leftover regions) or the straight-skeleton strips the "
            "paper names (Vanegas et al. 2012).", advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.SETTLE_JOINTS, "Settle joints where lots are squarest (not in the paper)",
            defaultValue=True),
            "After the templates are warped, each joint between two lots on a street is cut "
            "again by one straight line where the two lots' p_area falls most without a "
            "worse corner angle, a lot outside the pair's area range or a lot off the street. "
            "Streets and lot count stay. Off: the warp's joints, about 20-35 % faster.",
            advanced=True)
        self.add(QgsProcessingParameterBoolean(
            self.REPAIR_LOTS, "Repair misshapen lots (not in the paper)", defaultValue=False),
            "Optional post-process: a misshapen lot keeps the largest rectangle on its street "
            "and its wedges become pocket parks; a misshapen lot smaller than a parcel becomes "
            "a pocket park. The parks still count in the metrics.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_ROADS, "Streets", QgsProcessing.SourceType.TypeVectorLine),
            "Street centre lines, noded at every junction, with level (0 key road, 1 region "
            "outline, 2 split street, 3 cul-de-sac), kind, variation and length_m.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_PARCELS, "Parcels", QgsProcessing.SourceType.TypeVectorPolygon),
            "Parcels with variation, land_use, template, area_m2, frontage_m, "
            "has_street_access, p_angle, p_area and undesirable, styled by quality.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_METRICS, "Layout metrics (Table 1)", QgsProcessing.SourceType.TypeVector,
            optional=True),
            "One row per variation: land use (l_s, l_r, l_p, l_o %), blocks (b_n per km², "
            "b_max, b_avg, b_min m), streets (s_l km/km², s_i, s_d per km²), parcels "
            "(p_n per km², count, p_angle, p_area, undesirable) and the stage times.")

    # ----------------------------------------------------------------------- run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        number = {name: self.number(parameters, name, context)
                  for name in (self.PARCEL_LENGTH, self.PARCEL_WIDTH, self.STREET_WIDTH)}
        variations = self.number(parameters, self.VARIATIONS, context)
        seed = self.seed(parameters, context)
        switches = {key: self.parameterAsBoolean(parameters, name, context) for key, name in (
            ("optimise", self.OPTIMISE), ("repair_lots", self.REPAIR_LOTS),
            ("settle_joints", self.SETTLE_JOINTS), ("outline_streets", self.OUTLINE_STREETS),
            ("back_to_back", self.BACK_TO_BACK))}
        settings = domain_split.SplitSettings(
            parcel_length=number[self.PARCEL_LENGTH], parcel_width=number[self.PARCEL_WIDTH],
            street_width=number[self.STREET_WIDTH], **switches,
            fallback_parcels=domain_split.FALLBACK_PARCELS[
                self.parameterAsEnum(parameters, self.FALLBACK_PARCELS, context)])
        qgis_io.run_engine("Parameters", settings.validate)

        region = qgis_io.read_source(self, parameters, self.REGION, context, feedback,
                                     kind="polygons", fields=[])
        crs = region.crs
        lot = number[self.PARCEL_LENGTH] * number[self.PARCEL_WIDTH]
        self.bound_work(
            f"Region {region.name} ({shapely.area(shapely.union_all(region.geometry)) / 1e6:,.1f}"
            f" km², {variations} variation(s)) at {number[self.PARCEL_LENGTH]:g} x "
            f"{number[self.PARCEL_WIDTH]:g} m parcels",
            variations * shapely.area(shapely.union_all(region.geometry)) / lot,
            self.MAX_PARCELS, "parcels", "split the region into districts and run them one by "
            "one, or use larger parcels")
        class_field = self.parameterAsString(parameters, self.KEY_ROAD_CLASS_FIELD, context)
        key_roads = qgis_io.read_source(self, parameters, self.KEY_ROADS, context, feedback,
                                        kind="lines", fields=[class_field] if class_field else [],
                                        target_crs=crs, optional=True)
        if key_roads is not None:
            reach = shapely.buffer(shapely.union_all(region.geometry), 1.0)
            away = int((~shapely.intersects(key_roads.geometry, reach)).sum())
            if away:
                feedback.pushWarning(
                    f"{away} of {len(key_roads)} key roads of {key_roads.name} do not reach "
                    f"the region {region.name}: they play no part in the layout.")
        key_classes = None
        if key_roads is not None and class_field:
            key_classes = qgis_io.osm_tag_column(key_roads, class_field)
        use_field = self.parameterAsString(parameters, self.KEY_AREA_USE_FIELD, context)
        key_areas = qgis_io.read_source(
            self, parameters, self.KEY_AREAS, context, feedback, kind="polygons",
            fields=[use_field] if use_field else [], target_crs=crs, optional=True,
            required_fields=[use_field] if use_field else ())
        key_use = None
        if key_areas is not None and use_field:
            key_use = key_areas.attributes[use_field].to_numpy(dtype=object)
        lib = self._templates(parameters, context, feedback)
        feedback.setProgress(5)

        layouts = qgis_io.run_engine(
            region.name, domain_split.split_variations, region.geometry, variations, seed,
            key_roads=None if key_roads is None else key_roads.geometry,
            key_areas=None if key_areas is None else key_areas.geometry,
            key_area_use=key_use, templates=lib, settings=settings,
            key_road_classes=key_classes,
            progress=qgis_io.progress_for(feedback, 5, 85))
        rows = []
        for v, lay in enumerate(layouts, start=1):
            m = qgis_io.run_engine(region.name, domain_split.table1, lay)
            rows.append(dict(variation=v, **m))
            st = lay.stats
            if not st["n_parcels"]:
                feedback.pushWarning(f"Variation {v}: no parcels: " + (
                    "the key areas cover the region, or what is left of it is too small for "
                    "a lot (the streets and key areas are written;" if key_areas is not None
                    else "the region is too small for a lot (its streets are written;")
                    + " the metrics of this variation are empty).")
            feedback.pushInfo(domain_split.variation_summary(v, st, m))
            if st["min_count_short"]:
                feedback.pushWarning(
                    f"Variation {v}: {st['min_count_short']} templates short of their "
                    f"min_count after {st['search_attempts']} searches (templates "
                    f"{st['templates']}).")
            elif st["search_attempts"] > 1:
                feedback.pushInfo(f"Variation {v}: every min_count met after "
                                  f"{st['search_attempts']} searches.")
        for warning in domain_split.unused_drawn_templates(lib, layouts):
            feedback.pushWarning(warning)
        feedback.setProgress(88)

        road_geoms = np.concatenate([lay.roads for lay in layouts])
        road_table = pd.DataFrame({
            "road_id": np.arange(1, len(road_geoms) + 1),
            "level": np.concatenate([lay.road_level for lay in layouts]),
            # plain Python strings: numpy's str_ does not convert to a QVariant
            "kind": [str(k) for lay in layouts for k in lay.road_kind],
            "variation": np.concatenate([np.full(len(lay.roads), v)
                                         for v, lay in enumerate(layouts, start=1)]),
            "length_m": shapely.length(road_geoms)})
        parcel_geoms = np.concatenate([lay.parcels for lay in layouts])
        parcel_table = pd.concat([lay.table for lay in layouts], ignore_index=True)
        parcel_table["parcel_id"] = np.arange(1, len(parcel_table) + 1)
        results = {}
        results[self.OUTPUT_ROADS] = qgis_io.write_sink(
            self, parameters, self.OUTPUT_ROADS, context, road_geoms, road_table,
            domain_split.ROAD_FIELDS, QgsWkbTypes.Type.LineString, region.source_crs, crs, feedback)
        qgis_io.style_output(context, results[self.OUTPUT_ROADS], "roads_by_level.qml")
        results[self.OUTPUT_PARCELS] = qgis_io.write_sink(
            self, parameters, self.OUTPUT_PARCELS, context, parcel_geoms, parcel_table,
            domain_split.PARCEL_FIELDS, QgsWkbTypes.Type.MultiPolygon, region.source_crs, crs,
            feedback)
        qgis_io.style_output(context, results[self.OUTPUT_PARCELS], "parcels_by_quality.qml")
        metrics_table = pd.DataFrame(rows)
        results[self.OUTPUT_METRICS] = qgis_io.write_sink(
            self, parameters, self.OUTPUT_METRICS, context,
            np.array([shapely.Point()] * len(metrics_table), dtype=object), metrics_table,
            domain_split.METRIC_FIELDS, QgsWkbTypes.Type.NoGeometry,
            QgsCoordinateReferenceSystem(), QgsCoordinateReferenceSystem(), feedback)
        feedback.setProgress(100)
        return results

    def _templates(self, parameters, context, feedback):
        """The shipped library subset, or the templates drawn in the template layer."""
        given = parameters.get(self.TEMPLATE_LAYER)
        if given is None or given == "":
            subset = self.SUBSETS[self.parameterAsEnum(parameters, self.TEMPLATES, context)][0]
            return qgis_io.run_engine("Template library", templates.load_library,
                                      templates.LIBRARY_PATH, subset)
        optional = ["probability", "min_count", "max_count"]
        frame = qgis_io.read_source(self, parameters, self.TEMPLATE_LAYER, context, feedback,
                                    kind="polygons", fields=["template", "label"] + optional,
                                    required_fields=["template", "label"],
                                    read_twice=True)   # drawn anywhere: its own working CRS
        settings = {k: frame.attributes[k].to_numpy(dtype=object) for k in optional
                    if k in frame.attributes}
        lib = qgis_io.run_engine(frame.name, templates.templates_from_drawn, frame.geometry,
                                 frame.attributes["template"].to_numpy(dtype=object),
                                 frame.attributes["label"].to_numpy(dtype=object), settings)
        feedback.pushInfo(f"{len(lib)} templates drawn in {frame.name}: "
                          + ", ".join(f"{t.name} ({t.label})" for t in lib))
        return lib
