"""urbansynth:layoutmetrics - quality and similarity metrics of a layout against its example."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from ..plugin.measure import metrics, report
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase


class LayoutMetrics(AlgorithmBase):
    GROUP_ID = "analysis"
    ROADS = "ROADS"
    BLOCKS = "BLOCKS"
    PARCELS = "PARCELS"
    BUILDINGS = "BUILDINGS"
    EXAMPLE_ROADS = "EXAMPLE_ROADS"
    EXAMPLE_BLOCKS = "EXAMPLE_BLOCKS"
    EXAMPLE_PARCELS = "EXAMPLE_PARCELS"
    EXAMPLE_BUILDINGS = "EXAMPLE_BUILDINGS"
    STUDY_AREA = "STUDY_AREA"
    EXAMPLE_STUDY_AREA = "EXAMPLE_STUDY_AREA"
    ROAD_HALF_WIDTH = "ROAD_HALF_WIDTH"
    LANDUSE_FIELD = "LANDUSE_FIELD"
    GIVEN_ROADS = "GIVEN_ROADS"
    DRIVABLE_ONLY = "DRIVABLE_ONLY"
    MIN_BLOCK_AREA = "MIN_BLOCK_AREA"
    MIN_BLOCK_WIDTH = "MIN_BLOCK_WIDTH"
    EDGE_DISTANCE = "EDGE_DISTANCE"
    SNAP_TOLERANCE = "SNAP_TOLERANCE"
    OUTPUT = "OUTPUT"
    OUTPUT_HTML = "OUTPUT_HTML"

    #: (parameter, engine argument, geometry kind) of the candidate and the example layers
    CANDIDATE = [(ROADS, "roads", "lines"), (BLOCKS, "blocks", "polygons"),
                 (PARCELS, "parcels", "polygons"), (BUILDINGS, "buildings", "polygons")]
    EXAMPLE = [(EXAMPLE_ROADS, "roads", "lines"), (EXAMPLE_BLOCKS, "blocks", "polygons"),
               (EXAMPLE_PARCELS, "parcels", "polygons"),
               (EXAMPLE_BUILDINGS, "buildings", "polygons")]

    def name(self):
        return "layoutmetrics"

    def displayName(self):  # noqa: N802
        return "Layout metrics"

    def shortHelpString(self):  # noqa: N802
        return (
            "Measures a layout and, when example layers are given, how closely it resembles "
            "its example.\n\n"
            "Give any of roads, blocks, parcels and buildings (at least one). Roads: segment "
            "length, node degree, intersection angle and street bearing distributions, dead ends, "
            "intersections and street length per km², orientation entropy. Blocks (the faces of "
            "the road graph when no block layer is given): area, compactness, aspect ratio, "
            "boundary length, blocks per km². Parcels: the Yang et al. 2013 Table 1 measures "
            "p_n, p_angle, p_area, undesirable parcels (p_angle > 15° or p_area > 1.2) and, with "
            "a land-use field, the land-use shares. Buildings: coverage, overlaps between "
            "footprints and with the road surface, footprints outside blocks, setback.\n\n"
            "Network invariants of the roads (against GIVEN_ROADS, the roads a synthesis was "
            "given): crossings without a junction, floating pieces, streets inside a given "
            "road's corridor, motorway / trunk contacts away from their junctions, dead-end "
            "share (flagged beyond ±30 % of the example's).\n\n"
            "Counting choices, all visible: roads are every line with a class, or every line "
            "of a layer without classes (an OSM layer's lines without 'highway' are rivers, "
            "railways, boundaries: left out; DRIVABLE_ONLY drops footways and other "
            "non-drivable OSM classes too); faces under MIN_BLOCK_AREA m² or thinner "
            "than MIN_BLOCK_WIDTH m are slivers, not blocks (0 and 0 keep every face of a plain "
            "polygonize); nodes within EDGE_DISTANCE m of the study area's boundary are clip "
            "ends, not dead ends, and streets within it count as inside (0: every node counts, "
            "streets are cut at the boundary).\n\n"
            "Outputs: a table with one row per measure (candidate and example values, "
            "Wasserstein distance and Kolmogorov-Smirnov statistic of every distribution) and "
            "an HTML report with histograms of example and candidate side by side. Each layer "
            "set is measured in its own local metric CRS."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        line, poly = [QgsProcessing.SourceType.TypeVectorLine], [QgsProcessing.SourceType.TypeVectorPolygon]
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads", line, optional=True),
            "Road centrelines of the layout to measure (e.g. a synthesis, or the output of "
            "Extract road hierarchy). They are noded into a street graph; nothing is filtered.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks", poly, optional=True),
            "City blocks. When missing, blocks are the faces of the road graph (as 'Extract "
            "city blocks' makes them).")
        self.add(QgsProcessingParameterFeatureSource(
            self.PARCELS, "Parcels", poly, optional=True),
            "Parcels (cadastre plots or a subdivision) for the Yang et al. 2013 parcel measures.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDINGS, "Buildings", poly, optional=True),
            "Building footprints for coverage, overlap and setback measures (of an OSM "
            "multipolygons layer, the polygons with a 'building' value).")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_ROADS, "Example roads", line, optional=True),
            "Roads of the example the layout should resemble.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_BLOCKS, "Example blocks", poly, optional=True),
            "Blocks of the example (else the faces of the example roads).")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_PARCELS, "Example parcels", poly, optional=True),
            "Parcels of the example.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_BUILDINGS, "Example buildings", poly, optional=True),
            "Building footprints of the example.")
        self.add(QgsProcessingParameterFeatureSource(
            self.STUDY_AREA, "Study area", poly, optional=True),
            "Polygon(s) whose area the densities (per km²) of the layout refer to. Default: the "
            "convex hull of all given layers.")
        self.add(QgsProcessingParameterFeatureSource(
            self.EXAMPLE_STUDY_AREA, "Example study area", poly, optional=True),
            "Polygon(s) for the densities of the example. Default: the convex hull of the "
            "example layers.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.ROAD_HALF_WIDTH, "Road half-width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=3.0, minValue=0.0, maxValue=100.0),
            "The road surface is the centrelines buffered by this on each side; footprints "
            "must not overlap it, and setbacks are measured from its edge.", advanced=True)
        self.add(QgsProcessingParameterField(
            self.LANDUSE_FIELD, "Land-use field of the parcels",
            parentLayerParameterName=self.PARCELS, optional=True),
            "Parcel field with the land use (residential / park / street / other labels, matched "
            "case-insensitively) for the Yang 2013 shares l_s, l_r, l_p, l_o. The example "
            "parcels use a field of the same name when they have one.", advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.GIVEN_ROADS, "Given roads (for the network invariants)", line, optional=True),
            "The roads the layout was given (e.g. the arterials of a synthesis). Road lines "
            "that are copies of them are left out of the check; the others must meet them at "
            "junctions, connect to them and not run along them. Without it the roads are "
            "checked on their own.")
        self.add(QgsProcessingParameterBoolean(
            self.DRIVABLE_ONLY, "Drivable streets only", defaultValue=False),
            "Keep only road lines whose OSM class (field 'highway', else 'road_class') is "
            "drivable: no footways, paths, cycleways, service roads or tracks. Off: every line "
            "with a class counts, and the log says how many non-drivable lines are counted "
            "(lines without a class, where others have one, are never streets).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_BLOCK_AREA, "Smallest block (m²)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=400.0, minValue=0.0, maxValue=1e6),
            "Faces of the road graph smaller than this are traffic islands, not blocks (as in "
            "'Extract city blocks'); the log counts them. 0 keeps every face.")
        self.add(QgsProcessingParameterNumber(
            self.MIN_BLOCK_WIDTH, "Thinnest block (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=8.0, minValue=0.0, maxValue=1000.0),
            "Faces whose mean width 2·area/perimeter is under this are slivers between dual "
            "carriageways; the log counts them. 0 keeps every face.")
        self.add(QgsProcessingParameterNumber(
            self.EDGE_DISTANCE, "Clip ends at the study-area edge (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=0.0, minValue=0.0, maxValue=1000.0),
            "Nodes closer than this to the study area's boundary are not counted in densities "
            "and shares (the cut ends of a clipped network are not dead ends), and a street "
            "that runs outside the boundary by up to this much counts as inside it (a layout's "
            "outline street rounding a corner). 0 counts every node inside the area or on its "
            "boundary.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.SNAP_TOLERANCE, "Node snapping (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=0.5, minValue=0.0, maxValue=10.0),
            "Road nodes closer than this are one node (in groups no wider than it), and edges "
            "between the same nodes this close are one street. 0 counts exactly what noding "
            "the lines gives.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Layout metrics table", QgsProcessing.SourceType.TypeVector),
            "One row per measure: kind, metric, statistic, unit, candidate and example values, "
            "rel_diff (the relative difference (candidate - example) / |example|; for street "
            "bearings, statistic axial_mean, the turn in degrees between the two mean "
            "directions, -90..90, as a relative difference of directions means nothing), "
            "Wasserstein distance (raw and divided by the example's standard deviation), "
            "Kolmogorov-Smirnov statistic and p-value, sample sizes.")
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT_HTML, "Layout metrics report", "HTML files (*.html)", optional=True,
            createByDefault=True),
            "Self-contained HTML report with the tables and the histograms (skip it to get "
            "only the table, e.g. in a model).")

    # ------------------------------------------------------------------ helpers

    def _read_set(self, parameters, context, feedback, layers, area_name, landuse_field):
        """Read one layer set (candidate or example) into engine arguments, one metric CRS
        (a layer given empty is left out, as if not given)."""
        kwargs, names, crs = {}, [], None
        for name, arg, kind in layers:
            if not self.given(parameters, name):
                continue
            frame = qgis_io.read_source(self, parameters, name, context, feedback, kind=kind,
                                        target_crs=crs, optional=True)
            if frame is None:   # empty: a model step before made nothing
                continue
            if arg == "buildings":   # an OSM multipolygons layer: its buildings only
                frame = self.only_buildings(frame, feedback)
            crs = frame.crs
            kwargs[arg] = frame.geometry
            if arg == "roads":  # bridges and tunnels cross without an intersection
                kwargs["road_z_layer"] = qgis_io.osm_vertical_layers(frame)
                kwargs["road_class"] = self._road_class(frame)
            names.append(f"{arg}: {frame.name} ({len(frame)} features)")
            variations = frame.attributes.get("variation", pd.Series(dtype=object)).nunique()
            if variations > 1:   # splitdomain's VARIATIONS: layouts over each other
                feedback.pushWarning(
                    f"Layer {frame.name} holds {variations} variations (field 'variation'): "
                    "they are measured as one network over itself. Measure one at a time "
                    "(select \"variation\" = 1 and use Selected features only).")
            if arg == "parcels" and landuse_field:
                if landuse_field in frame.attributes:
                    kwargs["landuse"] = frame.attributes[landuse_field].to_numpy(dtype=object)
                else:
                    feedback.pushInfo(f"{frame.name} has no field '{landuse_field}': no land-use "
                                      "shares for it.")
        if kwargs and self.given(parameters, area_name):
            area = qgis_io.read_source(self, parameters, area_name, context, feedback,
                                       kind="polygons", target_crs=crs, optional=True)
        else:
            area = None
        if area is not None:
            layers = np.concatenate([np.asarray(v, dtype=object) for k, v in kwargs.items()
                                     if k in ("roads", "blocks", "parcels", "buildings")])
            if not shapely.intersects(shapely.union_all(area.geometry),
                                      shapely.box(*shapely.total_bounds(layers))):
                raise QgsProcessingException(
                    f"The study area {area.name} does not overlap the layers it should "
                    "measure: every density would be 0. Give the study area of these layers "
                    "(or none: their convex hull is used).")
            kwargs["area"] = area.geometry
            names.append(f"study area: {area.name}")
        return kwargs, names, crs

    @staticmethod
    def _road_class(frame):
        """OSM class per road line ('highway', else 'road_class'), or None."""
        for name in ("highway", "road_class"):
            if name in frame.attributes:
                return frame.attributes[name].to_numpy(dtype=object)
        return None

    # ------------------------------------------------------------------ run

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        if not any(self.given(parameters, name) for name, _, _ in self.CANDIDATE):
            raise QgsProcessingException(
                "No layer to measure: give at least one of Roads, Blocks, Parcels or Buildings.")
        half_width = self.number(parameters, self.ROAD_HALF_WIDTH, context)
        landuse_field = self.parameterAsString(parameters, self.LANDUSE_FIELD, context)
        html_path = self.parameterAsFileOutput(parameters, self.OUTPUT_HTML, context)

        counting = dict(
            drivable_only=self.parameterAsBool(parameters, self.DRIVABLE_ONLY, context),
            min_block_area=self.number(parameters, self.MIN_BLOCK_AREA, context),
            min_block_width=self.number(parameters, self.MIN_BLOCK_WIDTH, context),
            edge_distance=self.number(parameters, self.EDGE_DISTANCE, context),
            snap_tolerance=self.number(parameters, self.SNAP_TOLERANCE, context))
        cand_args, cand_names, cand_crs = self._read_set(
            parameters, context, feedback, self.CANDIDATE, self.STUDY_AREA, landuse_field)
        if not cand_args:
            for name, _, _ in self.CANDIDATE:
                if self.given(parameters, name):  # every one given empty: refused by its name
                    try:   # (the warning above said the run would go on without it)
                        qgis_io.read_source(self, parameters, name, context, None, fields=[])
                    except QgsProcessingException as exc:
                        raise QgsProcessingException(
                            f"Nothing to measure, no layer holds a feature: {exc}") from exc
            raise QgsProcessingException(
                "No layer to measure could be loaded: check Roads, Blocks, Parcels and Buildings.")
        given = None
        if self.given(parameters, self.GIVEN_ROADS):
            given = qgis_io.read_source(self, parameters, self.GIVEN_ROADS, context, feedback,
                                        kind="lines", target_crs=cand_crs, optional=True)
        if given is not None:
            if "roads" not in cand_args:
                raise QgsProcessingException("Given roads need Roads to check against them.")
            cand_args.update(given_roads=given.geometry, given_class=self._road_class(given),
                             given_z_layer=qgis_io.osm_vertical_layers(given))
            cand_names.append(f"given roads: {given.name} ({len(given)} features)")
        if counting["drivable_only"] and "roads" in cand_args and \
                cand_args.get("road_class") is None:
            raise QgsProcessingException(
                "Drivable streets only needs a 'highway' or 'road_class' field in Roads.")
        feedback.setProgress(10)
        candidate = qgis_io.run_engine(
            "Layout", metrics.compute_layout_metrics, road_half_width=half_width,
            progress=qgis_io.progress_for(feedback, 10, 45), **counting, **cand_args)
        for note in candidate.notes:
            feedback.pushInfo(f"Layout: {note}")

        example = None
        ex_args, ex_names, ex_crs = self._read_set(
            parameters, context, feedback, self.EXAMPLE, self.EXAMPLE_STUDY_AREA, landuse_field)
        if ex_args:
            # an example without classes (a synthesis) keeps all its lines
            ex_counting = dict(counting, drivable_only=counting["drivable_only"]
                               and ex_args.get("road_class") is not None)
            example = qgis_io.run_engine(
                "Example", metrics.compute_layout_metrics, road_half_width=half_width,
                progress=qgis_io.progress_for(feedback, 50, 80), **ex_counting, **ex_args)
            for note in example.notes:
                feedback.pushInfo(f"Example: {note}")
        elif self.given(parameters, self.EXAMPLE_STUDY_AREA):
            feedback.pushWarning("An example study area was given without example layers; "
                                 "it is ignored.")
        table = metrics.compare(candidate, example)
        feedback.pushInfo(f"{len(table)} measures"
                          + (" compared with the example." if example is not None else "."))
        breach = report.dead_end_breach(table) if example is not None else None
        if breach:
            feedback.pushWarning(f"Invariants against the example: {breach}.")
        feedback.setProgress(82)

        results = {}
        # a geometry-less table: every row gets an empty point, which the sink drops
        results[self.OUTPUT] = qgis_io.write_sink(
            self, parameters, self.OUTPUT, context,
            np.array([shapely.Point()] * len(table), dtype=object), table,
            list(metrics.COMPARISON_COLUMNS), QgsWkbTypes.Type.NoGeometry,
            QgsCoordinateReferenceSystem(), QgsCoordinateReferenceSystem(), feedback)
        feedback.setProgress(85)

        meta = {"Layout": "; ".join(cand_names),
                "Layout CRS (metric)": cand_crs.authid() if cand_crs else ""}
        if example is not None:
            meta["Example"] = "; ".join(ex_names)
            meta["Example CRS (metric)"] = ex_crs.authid() if ex_crs else ""
        meta["Road half-width"] = f"{half_width:g} m"
        meta["Counting"] = (("drivable streets only" if counting["drivable_only"] else
                             "every road line") + f"; blocks from {counting['min_block_area']:g} "
                            f"m² and {counting['min_block_width']:g} m wide; clip ends within "
                            f"{counting['edge_distance']:g} m of the study-area edge not "
                            f"counted; nodes snapped within {counting['snap_tolerance']:g} m")
        if html_path:
            drawn = ("roads", "blocks", "parcels", "buildings")
            maps = {"Layout": {k: cand_args[k] for k in drawn if k in cand_args}}
            if example is not None:
                maps["Example"] = {k: ex_args[k] for k in drawn if k in ex_args}
            qgis_io.run_engine("Report", report.write_report, html_path, candidate, example,
                               table, "Layout metrics", meta,
                               progress=qgis_io.progress_for(feedback, 85, 100), maps=maps)
            results[self.OUTPUT_HTML] = html_path
        feedback.setProgress(100)
        return results
