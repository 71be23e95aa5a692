"""urbansynth:extractblocks - city blocks from roads; footprints and parcels assigned to blocks."""
import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from ..plugin.buildings import attributes as building_attributes
from ..plugin.network import blocks
from ..plugin.network import street_graph as roads
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase, parse_class_list

MEMBERSHIP_FIELDS = [("source_fid", "int"), ("block_id", "int"), ("block_share", "float"),
                     ("in_block", "bool"), ("area_m2", "float")]
BUILDING_FIELDS = MEMBERSHIP_FIELDS + building_attributes.ATTRIBUTE_FIELDS


class ExtractBlocks(AlgorithmBase):
    GROUP_ID = "analysis"
    ROADS = "ROADS"
    BOUNDARY = "BOUNDARY"
    CLASS_FIELD = "CLASS_FIELD"
    CLASSES = "CLASSES"
    BUILDINGS = "BUILDINGS"
    PARCELS = "PARCELS"
    MIN_BLOCK_AREA = "MIN_BLOCK_AREA"
    MIN_BLOCK_WIDTH = "MIN_BLOCK_WIDTH"
    STOREY_HEIGHT = "STOREY_HEIGHT"
    HEIGHT_FIELD = "HEIGHT_FIELD"
    LEVELS_FIELD = "LEVELS_FIELD"
    OUTPUT = "OUTPUT"
    OUTPUT_BUILDINGS = "OUTPUT_BUILDINGS"
    OUTPUT_PARCELS = "OUTPUT_PARCELS"

    def name(self):
        return "extractblocks"

    def displayName(self):  # noqa: N802
        return "Extract city blocks"

    def shortHelpString(self):  # noqa: N802
        return (
            "City blocks are the faces of the planar street graph (Hartmann, ch. 4.1 and 5.1): "
            "the road lines are filtered to drivable classes, cleaned and noded, and every "
            "closed face becomes a block; dead-end streets stay inside their block. Faces "
            "that are traffic islands or slivers between dual carriageways (smaller than the "
            "minimum area or narrower than the minimum mean width) are dropped, and so are "
            "the islands inside roundabouts (rings of lines tagged junction=roundabout, a "
            "field or a key of OSM's other_tags), whatever their size.\n\n"
            "Blocks get area, perimeter, compactness (area / minimum bounding rectangle), "
            "aspect ratio (shorter / longer side of that rectangle), dead-end and building "
            "counts and building coverage. Each building and parcel gets the block_id of the "
            "block holding most of its area (at least half); features outside every closed "
            "block (common at the edge of a clipped extract) are kept with an empty block_id "
            "and in_block = false. Buildings also get height_m (from height tags or fields, "
            "else levels x storey height, flagged height_estimated), levels and a normalised "
            "building_type from OSM tags. Outputs are in the CRS of their input layer.\n\n"
            "With a boundary (a district's outline), its outline closes the faces the roads "
            "leave open (an open sketch of arterials), and only faces inside it that a road "
            "reaches are blocks; 'Subdivide blocks into parcels' with the same boundary "
            "takes its edges as no street."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Road lines", [QgsProcessing.SourceType.TypeVectorLine]),
            "Any road line layer: the output of 'Extract road hierarchy', the 'lines' layer of "
            "an .osm.pbf file, or a cadastre street layer.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BOUNDARY, "Boundary (closes open faces)",
            [QgsProcessing.SourceType.TypeVectorPolygon], optional=True),
            "Optional polygon(s), e.g. a district's outline: the faces the roads leave open "
            "are closed by it, faces outside it are dropped, and so are faces inside it "
            "that no road reaches (no street to front). Its edges are no streets.")
        self.add(QgsProcessingParameterField(
            self.CLASS_FIELD, "Road class field", defaultValue="highway",
            parentLayerParameterName=self.ROADS, optional=True),
            "Field with the road class (OSM 'highway'; also searched in 'other_tags'). When "
            "the layer has no such field, every line is a block boundary.")
        self.add(QgsProcessingParameterString(
            self.CLASSES, "Drivable classes (comma-separated, empty = all)",
            defaultValue=",".join(roads.DRIVABLE_CLASSES), optional=True),
            "Only lines of these classes bound blocks (footways and service roads would cut "
            "blocks into courtyards). Leave empty to use every line.", advanced=True)
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDINGS, "Building footprints", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Footprints, e.g. the 'multipolygons' layer of an .osm.pbf file (only features with "
            "a 'building' value are used) or a cadastre building layer.")
        self.add(QgsProcessingParameterFeatureSource(
            self.PARCELS, "Parcels", [QgsProcessing.SourceType.TypeVectorPolygon],
            optional=True),
            "Cadastre parcels; each gets the block_id of the block holding most of it.")
        self.add(QgsProcessingParameterNumber(
            self.MIN_BLOCK_AREA, "Minimum block area (m²)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=blocks.MIN_BLOCK_AREA, minValue=0.0, maxValue=1e7),
            "Faces smaller than this are traffic islands or junction artefacts, not blocks.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_BLOCK_WIDTH, "Minimum mean block width (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=blocks.MIN_BLOCK_WIDTH,
            minValue=0.0, maxValue=1000.0),
            "Faces whose mean width (2 x area / perimeter) is under this are slivers between "
            "dual carriageways or slip roads.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.STOREY_HEIGHT, "Storey height (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=building_attributes.STOREY_HEIGHT, minValue=0.5, maxValue=20.0),
            "Metres per storey: heights are estimated from levels (and levels from heights) "
            "with it when a building has only one of them.", advanced=True)
        self.add(QgsProcessingParameterField(
            self.HEIGHT_FIELD, "Building height field (cadastre)",
            parentLayerParameterName=self.BUILDINGS, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "A field with the building height in metres; it wins over OSM height tags.",
            advanced=True)
        self.add(QgsProcessingParameterField(
            self.LEVELS_FIELD, "Number of storeys field (cadastre)",
            parentLayerParameterName=self.BUILDINGS, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "A field with the number of storeys; it wins over OSM building:levels.",
            advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "City blocks", QgsProcessing.SourceType.TypeVectorPolygon),
            "Block polygons with block_id, area_m2, perimeter_m, compactness, aspect_ratio, "
            "n_dead_ends, n_buildings, building_coverage, n_parcels and boundary_m (the "
            "length of its outline on the boundary, no street; 0 without one).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_BUILDINGS, "Buildings with blocks and attributes",
            QgsProcessing.SourceType.TypeVectorPolygon, optional=True, createByDefault=True),
            "The footprints with their fields plus block_id, in_block, height_m, "
            "height_estimated, levels, building_type and the raw tag values; without "
            "features (its fields only) when no BUILDINGS are given.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_PARCELS, "Parcels with blocks", QgsProcessing.SourceType.TypeVectorPolygon,
            optional=True, createByDefault=True),
            "The parcels with their fields plus block_id and in_block; without features "
            "when no PARCELS are given.")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        min_area = self.number(parameters, self.MIN_BLOCK_AREA, context)
        min_width = self.number(parameters, self.MIN_BLOCK_WIDTH, context)
        storey = self.number(parameters, self.STOREY_HEIGHT, context)
        class_field = self.parameterAsString(parameters, self.CLASS_FIELD, context)
        classes = parse_class_list(self.parameterAsString(parameters, self.CLASSES, context))

        frame, road_class = self.drivable_roads(parameters, self.ROADS, context, feedback,
                                                class_field, classes)
        buildings = self._buildings(parameters, context, feedback, frame.crs)
        if buildings is not None:
            heights, levels = self._cadastre_fields(parameters, context, buildings)
        parcels = qgis_io.read_source(self, parameters, self.PARCELS, context, feedback,
                                      kind="polygons", target_crs=frame.crs, optional=True)
        boundary = qgis_io.read_source(self, parameters, self.BOUNDARY, context, feedback,
                                       kind="polygons", target_crs=frame.crs, optional=True,
                                       fields=[])
        _, result = self.blocks_from_roads(
            frame, road_class, feedback, (5, 70),
            buildings=None if buildings is None else buildings.geometry,
            parcels=None if parcels is None else parcels.geometry,
            min_area=min_area, min_width=min_width,
            boundary=None if boundary is None else boundary.geometry,
            boundary_name=None if boundary is None else boundary.name)
        self._log(result.stats, feedback)

        results = {}
        results[self.OUTPUT] = qgis_io.write_sink(
            self, parameters, self.OUTPUT, context, result.geometry, result.table,
            blocks.BLOCK_FIELDS, QgsWkbTypes.Type.Polygon, frame.source_crs, frame.crs, feedback)
        qgis_io.style_output(context, results[self.OUTPUT], "blocks.qml")
        feedback.setProgress(80)
        if buildings is not None:
            attrs = self.building_attributes_of(buildings, height=heights, levels=levels,
                                                storey_height=storey)
            n_h = int(attrs["height_m"].notna().sum())
            n_est = int(attrs["height_estimated"].fillna(False).sum())
            feedback.pushInfo(f"Buildings: {n_h} of {len(buildings)} have a height "
                              f"({n_est} estimated from levels x {storey:g} m).")
            self._warn_unreadable(parameters, context, feedback, buildings.name,
                                  heights, levels)
            table = result.buildings.join(attrs)
            results[self.OUTPUT_BUILDINGS] = self._write_features(
                parameters, self.BUILDINGS, self.OUTPUT_BUILDINGS, context, feedback, buildings,
                table, BUILDING_FIELDS)
            qgis_io.style_output(context, results[self.OUTPUT_BUILDINGS],
                                 "buildings_by_height.qml")
        else:
            results[self.OUTPUT_BUILDINGS] = self._write_empty(
                parameters, self.BUILDINGS, self.OUTPUT_BUILDINGS, context, feedback,
                BUILDING_FIELDS, frame)
        feedback.setProgress(90)
        if parcels is not None:
            results[self.OUTPUT_PARCELS] = self._write_features(
                parameters, self.PARCELS, self.OUTPUT_PARCELS, context, feedback, parcels,
                result.parcels, MEMBERSHIP_FIELDS)
        else:
            results[self.OUTPUT_PARCELS] = self._write_empty(
                parameters, self.PARCELS, self.OUTPUT_PARCELS, context, feedback,
                MEMBERSHIP_FIELDS, frame)
        feedback.setProgress(100)
        return results

    # ----------------------------------------------------------------------- helpers

    def _buildings(self, parameters, context, feedback, crs):
        return self.only_buildings(qgis_io.read_source(
            self, parameters, self.BUILDINGS, context, feedback, kind="polygons",
            target_crs=crs, optional=True), feedback)

    def _warn_unreadable(self, parameters, context, feedback, label, heights, levels):
        """Values of the cadastre fields that are no height or number of storeys."""
        for name, values, parse, what in (
                (self.HEIGHT_FIELD, heights, building_attributes.parse_height,
                 "height in metres"),
                (self.LEVELS_FIELD, levels, building_attributes.parse_levels,
                 "number of storeys")):
            bad = [] if values is None else building_attributes.unreadable_values(values, parse)
            if bad:
                shown = ", ".join(repr(v) for v in bad[:3])
                feedback.pushWarning(
                    f"Layer {label}: {len(bad)} value(s) of field "
                    f"'{self.parameterAsString(parameters, name, context)}' are no {what} "
                    f"(e.g. {shown}): those buildings take it from their OSM tags or "
                    "estimate it from the other field, else have none.")

    def _cadastre_fields(self, parameters, context, frame):
        values = []
        for name in (self.HEIGHT_FIELD, self.LEVELS_FIELD):
            field = self.parameterAsString(parameters, name, context)
            if field and field not in frame.attributes:
                raise QgsProcessingException(
                    f"Layer {frame.name} has no field '{field}' (parameter {name}).")
            values.append(frame.attributes[field].to_numpy(dtype=object) if field else None)
        return values

    def _write_features(self, parameters, source_name, name, context, feedback, frame, table,
                        fields):
        """Write features with their source fields plus ``fields`` (ours win on a clash)."""
        source_fields = self.parameterAsSource(parameters, source_name, context).fields()
        ours = {f.lower() for f, _ in fields}
        replaced = [f.name() for f in source_fields
                    if frame.renamed.get(f.name(), f.name()).lower() in ours]
        if replaced:
            feedback.pushInfo(f"{frame.name}: field(s) {', '.join(replaced)} replaced by the "
                              "computed ones.")
        carried = [(name, kind) for name, kind in
                   qgis_io.carried_fields(source_fields, ours - {"fid"}, frame.renamed)
                   if name in frame.attributes]
        out = table.copy()
        for field, kind in carried:
            column = frame.attributes[field]
            out[field] = column if kind != "str" else column.map(_text)
        out["source_fid"] = frame.fids
        out["area_m2"] = shapely.area(frame.geometry)
        return qgis_io.write_sink(self, parameters, name, context, frame.geometry, out,
                                  carried + fields, QgsWkbTypes.Type.MultiPolygon, frame.source_crs,
                                  frame.crs, feedback)

    def _write_empty(self, parameters, source_name, name, context, feedback, fields, frame):
        """An output whose input is missing or empty, written empty with its fields when it
        was requested: a model step that reads it gets a layer, not a missing file."""
        dest = qgis_io.write_sink(self, parameters, name, context, np.empty(0, dtype=object),
                                  pd.DataFrame(), fields, QgsWkbTypes.Type.MultiPolygon,
                                  frame.source_crs, frame.crs, feedback)
        if dest is not None:
            feedback.pushInfo(f"No {source_name.lower()} given (or the layer is empty): "
                              f"{name} is written without features.")
        return dest

    @staticmethod
    def _log(stats, feedback):
        if "n_buildings" in stats:
            n, k = stats["n_buildings"], stats["n_buildings_in_blocks"]
            feedback.pushInfo(
                f"{k} of {n} buildings ({100.0 * k / max(n, 1):.0f} %) lie in a block; the "
                f"other {n - k} are outside every closed block (beyond the outermost street "
                "loop of the extract, or on a dropped sliver) and keep an empty block_id.")
        if "n_parcels" in stats:
            n, k = stats["n_parcels"], stats["n_parcels_in_blocks"]
            feedback.pushInfo(f"{k} of {n} parcels lie in a block; the other {n - k} keep an "
                              "empty block_id (street parcels, parcels across blocks, outside).")
        for what in ("buildings", "parcels"):
            if stats.get(f"n_{what}") and not stats[f"n_{what}_in_blocks"]:
                feedback.pushWarning(
                    f"None of the {stats[f'n_{what}']} {what} lies in a block: the layer "
                    "covers another area than the roads' closed blocks (a different town or "
                    "extract, or a layer without a CRS read in the wrong one?).")


def _text(value):
    """Dates and other Qt values as ISO text; plain values unchanged."""
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    to_string = getattr(value, "toString", None)
    if to_string is not None:
        try:
            from qgis.PyQt.QtCore import Qt

            return to_string(Qt.DateFormat.ISODate)
        except TypeError:
            return to_string()
    return str(value)
