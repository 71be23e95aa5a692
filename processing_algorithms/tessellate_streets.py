"""urbansynth:tessellatestreets - street surfaces and junctions, draped on terrain
(Scharl 2010, ch. 5)."""

import numpy as np
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from ..plugin.buildings.attributes import unreadable_values
from ..plugin.network import street_graph as roads
from ..plugin.network import street_mesh, street_surfaces
from ..plugin.qgis_glue import qgis_io
from ..plugin.core.text import counted
from .common import AlgorithmBase, drivable_lines, parse_class_list


def _width_table():
    return ", ".join(f"{c} {w:g}" for c, w in street_surfaces.CLASS_WIDTHS.items())


class TessellateStreets(AlgorithmBase):
    GROUP_ID = "synthesis"
    ROADS = "ROADS"
    WIDTH_FIELD = "WIDTH_FIELD"
    CLASS_FIELD = "CLASS_FIELD"
    CLASSES = "CLASSES"
    DEFAULT_WIDTH = "DEFAULT_WIDTH"
    DEM = "DEM"
    MERGE_DISTANCE = "MERGE_DISTANCE"
    MERGE_OVERLAPPING = "MERGE_OVERLAPPING"
    MAX_LONGITUDINAL_SLOPE = "MAX_LONGITUDINAL_SLOPE"
    MAX_LATERAL_SLOPE = "MAX_LATERAL_SLOPE"
    SNAP_TOLERANCE = "SNAP_TOLERANCE"
    MESH_SPACING = "MESH_SPACING"
    Z_OFFSET = "Z_OFFSET"
    OUTPUT_SURFACES = "OUTPUT_SURFACES"
    OUTPUT_JUNCTIONS = "OUTPUT_JUNCTIONS"
    OUTPUT_MESH = "OUTPUT_MESH"
    OUTPUT_TIN = "OUTPUT_TIN"
    OUTPUT_OBJ = "OUTPUT_OBJ"

    def name(self):
        return "tessellatestreets"

    def displayName(self):  # noqa: N802
        return "Tessellate streets (surfaces and junctions)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Turns road centre lines into street surface polygons (one per street segment "
            "between junctions) and junction polygons (one per junction, any number of "
            "streets), after Scharl (2010, ch. 5): street outlines at half the width on both "
            "sides meet at the junction's corner points, and every street ends at a connecting "
            "line perpendicular to it. Junction centres closer than the merge distance become "
            "one junction.\n\n"
            "Widths come from the width field, else from the road class (OSM highway or "
            "road_class; halved for one-way lines), else from the hierarchy level, else the "
            "default width. Class widths (m): " + _width_table() + "; *_link 7. Level widths: "
            "0: 16, 1: 11, 2: 8, deeper: 6.\n\n"
            "With a DEM the outputs are 3D (PolygonZ): each junction lies in the terrain's "
            "tangent plane at its centre, streets follow the terrain between them, and every "
            "feature reports its longitudinal and lateral slope (%) with flags over the limits "
            "(Scharl: 12 % and 8 %).\n\n"
            "Polygons are valid, do not overlap within a vertical layer (bridges and tunnels "
            "may pass over other streets), and together cover the centre lines buffered by half "
            "their width. Outputs are in the roads' CRS.\n\n"
            "The 3D mesh (Scharl ch. 5.2) triangulates every street between its connecting "
            "lines (stations every mesh spacing, lifted by the z offset) and every junction "
            "(its street heads, in the terrain's tangent plane), with side faces down into the "
            "terrain wherever a street edge lies above it. It comes as MultiPolygon Z "
            "triangles (QGIS 3D shows them) and, as a file, as TIN Z features in a "
            "GeoPackage (written with GDAL; QGIS 3.22 reads them as MultiPolygon Z)."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Road centre lines", [QgsProcessing.SourceType.TypeVectorLine]),
            "Any line layer (OSM lines, grown or synthesized roads, a road shapefile). Lines "
            "are noded at crossings (not across bridges and tunnels) and joined through "
            "nodes of degree 2 where both are of one vertical layer.")
        self.add(QgsProcessingParameterField(
            self.WIDTH_FIELD, "Width field (m)", parentLayerParameterName=self.ROADS,
            optional=True),
            "Full street width in metres. Default: a field 'width_m' or 'width' (also OSM's "
            "width tag in other_tags) when there is one. Missing or unreadable widths take the "
            "class / level / default width.")
        self.add(QgsProcessingParameterField(
            self.CLASS_FIELD, "Road class field", defaultValue="highway",
            parentLayerParameterName=self.ROADS, optional=True),
            "Road class used to filter lines and to choose default widths (OSM 'highway', "
            "also searched in 'other_tags'; else a 'road_class' field; else a 'level' field).")
        self.add(QgsProcessingParameterString(
            self.CLASSES, "Classes to tessellate (comma-separated, empty = all)",
            defaultValue=",".join(roads.DRIVABLE_CLASSES), optional=True),
            "Only lines of these classes are kept when the layer has the class field.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.DEFAULT_WIDTH, "Default width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=street_surfaces.DEFAULT_WIDTH, minValue=0.5, maxValue=200.0),
            "Width of lines with neither a width nor a known class or level.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model", optional=True),
            "A DEM in any CRS, resampled bilinearly to the working CRS: outputs get Z, "
            "junctions the terrain's tangent plane, and slopes are measured. Heights in metres, "
            "or in the unit the raster declares (band unit or vertical CRS: feet are "
            "converted).")
        self.add(QgsProcessingParameterNumber(
            self.MERGE_DISTANCE, "Junction merge distance (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=3.0, minValue=0.0,
            maxValue=100.0),
            "Junction centres closer than this are merged into one junction at their "
            "centroid; the short streets between them vanish into it.")
        self.add(QgsProcessingParameterBoolean(
            self.MERGE_OVERLAPPING, "Merge junctions whose geometries meet",
            defaultValue=False),
            "Also merge the two junctions of a street whose heads reach each other (Scharl's "
            "rule). Off: such a street has no surface and the two junctions share their "
            "connecting line, which keeps the streets where they are.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_LONGITUDINAL_SLOPE, "Maximum longitudinal slope (%)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=12.0, minValue=0.0,
            maxValue=100.0),
            "Streets and junctions steeper than this along a street are flagged "
            "(too_steep_long), with a DEM.")
        self.add(QgsProcessingParameterNumber(
            self.MAX_LATERAL_SLOPE, "Maximum lateral slope (%)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=8.0, minValue=0.0,
            maxValue=100.0),
            "Streets and junctions steeper than this across a street are flagged "
            "(too_steep_lat), with a DEM.")
        self.add(QgsProcessingParameterNumber(
            self.SNAP_TOLERANCE, "Node snapping tolerance (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=1.0, minValue=0.0,
            maxValue=50.0),
            "Line ends closer than this are joined when the network is noded, in groups no "
            "wider than it.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MESH_SPACING, "Mesh station spacing (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=5.0, minValue=0.5, maxValue=100.0, optional=True),
            "Distance between the cross-sections of a street in the 3D mesh.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.Z_OFFSET, "Mesh lift above the terrain (m)",
            QgsProcessingParameterNumber.Type.Double, defaultValue=0.1, minValue=0.0,
            maxValue=10.0, optional=True),
            "The mesh is lifted this much above the draped height (Scharl: against "
            "z-fighting with the terrain); side faces close the gap.", advanced=True)
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_SURFACES, "Street surfaces", QgsProcessing.SourceType.TypeVectorPolygon),
            "One polygon per street segment between junctions: segment_id; edge_id (the "
            "edge of the cleaned street graph it paves); from_junction, to_junction "
            "(junction_id of its ends; a dead end's is the node's number without a junction "
            "polygon); road_class; z_layer (vertical layer: bridge +1, tunnel -1); width_m; "
            "length_m (of its centre line); area_m2. With a DEM: slope_long_pct (steepest "
            "grade along it, %), slope_lat_pct (steepest cross slope, %), too_steep_long, "
            "too_steep_lat (beyond the limits above).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_JUNCTIONS, "Junctions", QgsProcessing.SourceType.TypeVectorPolygon,
            optional=True, createByDefault=True),
            "One polygon per junction: junction_id (= from/to_junction of the surfaces); "
            "degree (streets meeting; 2 where a bridge or tunnel meets its approach, the "
            "joint between two vertical layers); merged_nodes (graph nodes merged into it, within "
            "MERGE_DISTANCE); z_layer; area_m2. With a DEM: z_centre (height of its plane "
            "at the centre); slope_pct (the plane's steepest slope, %); slope_long_pct, "
            "slope_lat_pct (the plane's largest grade along and across one of its streets, "
            "%); too_steep_long, too_steep_lat.")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT_MESH, "3D street mesh (triangles)", QgsProcessing.SourceType.TypeVectorPolygon,
            optional=True, createByDefault=False),
            "One MultiPolygon Z of triangles per street surface and junction: mesh_id, kind "
            "(street / junction), source_id (segment_id / junction_id), triangles, "
            "side_triangles, z_min, z_max. Flat (z = 0) without a DEM.")
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT_TIN, "3D street mesh as TIN Z GeoPackage", "GeoPackage (*.gpkg)",
            optional=True, createByDefault=False),
            "The same mesh as TIN Z features (layer 'street_mesh') in a GeoPackage file.")
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT_OBJ, "3D street mesh with texture coordinates (Wavefront OBJ)",
            "Wavefront OBJ (*.obj)", optional=True, createByDefault=False),
            "The same mesh as a Wavefront OBJ for 3D software, with Scharl's texture "
            "coordinates (u across each street, 0 on its left edge and 1 on its right; one "
            "texture row for streets, one for junctions, one for side faces), a material "
            "file <name>.mtl and the road texture <name>_texture.png beside it. x and y are "
            "in the working metric CRS minus an origin, both named in the file's first lines.")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        width_field = self.parameterAsString(parameters, self.WIDTH_FIELD, context)
        class_field = self.parameterAsString(parameters, self.CLASS_FIELD, context)
        frame = qgis_io.read_source(
            self, parameters, self.ROADS, context, feedback, kind="lines",
            required_fields=[width_field] if width_field else (),
            fields=[width_field, *qgis_io.WIDTH_FIELDS, class_field or "highway", "road_class",
                    "level", "oneway", *qgis_io.VERTICAL_LAYER_FIELDS])
        label = frame.name
        classes = parse_class_list(self.parameterAsString(parameters, self.CLASSES, context))
        default_width = self.number(parameters, self.DEFAULT_WIDTH, context)
        merge = self.number(parameters, self.MERGE_DISTANCE, context)
        max_long = self.number(parameters, self.MAX_LONGITUDINAL_SLOPE, context)
        max_lat = self.number(parameters, self.MAX_LATERAL_SLOPE, context)
        snap = self.number(parameters, self.SNAP_TOLERANCE, context)
        merge_heads = self.parameterAsBoolean(parameters, self.MERGE_OVERLAPPING, context)

        frame, road_class = drivable_lines(frame, class_field, classes, feedback)
        width_values = qgis_io.road_width_column(frame, width_field)
        class_for_width = road_class if road_class is not None else \
            qgis_io.osm_tag_column(frame, "road_class")
        widths, source = street_surfaces.road_widths(
            width_values, class_for_width, qgis_io.osm_tag_column(frame, "level"), n=len(frame),
            default_width=default_width, oneway=qgis_io.osm_tag_column(frame, "oneway"))
        counts = {k: int((source == k).sum()) for k in ("field", "class", "level", "default")}
        feedback.pushInfo("Widths from " + ", ".join(f"{k}: {v}" for k, v in counts.items() if v)
                          + f" lines; median {np.median(widths):.1f} m.")
        refused = [] if width_values is None else \
            unreadable_values(width_values, street_surfaces.parse_width)
        if refused:
            feedback.pushWarning(
                f"{counted(len(refused), 'width')} of {label} not used (not a number of metres "
                f"from 0.5 to 200: {', '.join(map(str, refused[:5]))}"
                f"{', ...' if len(refused) > 5 else ''}): those lines take their class width.")
        z_layer = qgis_io.osm_vertical_layers(frame)
        graph = qgis_io.run_engine(label, roads.clean_network, frame.geometry, class_for_width,
                                   None, z_layer, snap_tolerance=snap, min_dangle_length=0.0,
                                   progress=qgis_io.progress_for(feedback, 5, 25))
        feedback.pushInfo(f"Street graph: {counted(graph.n_edges, 'edge')}, "
                          f"{counted(len(graph.nodes), 'node')}.")

        dem = None
        dem_layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem_layer is not None:
            reach = float(widths.max()) * 4
            x0, y0, x1, y1 = shapely.total_bounds(graph.geometry)
            bounds = (x0 - reach, y0 - reach, x1 + reach, y1 + reach)
            cell = qgis_io.raster_cell_size(dem_layer, frame.crs, bounds, context,
                                            feedback=feedback)
            dem = qgis_io.read_raster(dem_layer, frame.crs, bounds, cell, feedback)
            feedback.pushInfo(f"DEM resampled to {cell:.1f} m cells.")

        result = qgis_io.run_engine(
            label, street_surfaces.tessellate_network, graph, widths[graph.source],
            merge_distance=merge, dem=dem, max_longitudinal_slope=max_long / 100.0,
            max_lateral_slope=max_lat / 100.0, merge_heads=merge_heads,
            progress=qgis_io.progress_for(feedback, 25, 90))
        st = result.stats
        feedback.pushInfo(
            f"{counted(st['surfaces'], 'street surface')} and "
            f"{counted(st['junctions'], 'junction')} (largest degree {st['max_degree']}); "
            f"{counted(st['merged_away'], 'junction centre')} merged away; "
            f"{counted(st['edges_without_surface'], 'street')} wholly inside "
            f"{'its junction' if st['edges_without_surface'] == 1 else 'their junctions'}; "
            f"{counted(st['cut_surfaces'] + st['cut_junctions'], 'polygon')} trimmed where "
            "they overlapped.")
        if st.get("dem_gap_edges"):
            feedback.pushWarning(
                f"{st['dem_gap_edges']} of {st['edges']} streets run (partly) where the DEM has "
                "no value: across a hole their heights are interpolated from its rim, beyond the "
                "DEM's edge they keep the edge's height, up to "
                f"{st['dem_gap_max_m']:,.0f} m from a cell with a value. Give a DEM without "
                "holes that covers every street for true heights.")
        if dem is not None:
            for what, table in (("street surfaces", result.surface_table),
                                ("junctions", result.junction_table)):
                n_long = int(table["too_steep_long"].fillna(False).astype(bool).sum())
                n_lat = int(table["too_steep_lat"].fillna(False).astype(bool).sum())
                if n_long or n_lat:
                    feedback.pushWarning(f"{what.capitalize()}: {n_long} steeper than "
                                         f"{max_long:g} % along, {n_lat} steeper than "
                                         f"{max_lat:g} % across (too_steep_long, _lat).")

        # PolygonZ with a DEM (write_sink keeps z through the reprojection)
        wkb = QgsWkbTypes.Type.MultiPolygonZ if dem is not None else QgsWkbTypes.Type.MultiPolygon
        results = {}
        tin_path = self.parameterAsFileOutput(parameters, self.OUTPUT_TIN, context) \
            if parameters.get(self.OUTPUT_TIN) else ""
        obj_path = self.parameterAsFileOutput(parameters, self.OUTPUT_OBJ, context) \
            if parameters.get(self.OUTPUT_OBJ) else ""
        if self.given(parameters, self.OUTPUT_MESH) or tin_path or obj_path:
            mesh = qgis_io.run_engine(
                label, street_mesh.street_mesh, result,
                spacing=self.number(parameters, self.MESH_SPACING, context),
                z_offset=self.number(parameters, self.Z_OFFSET, context))
            t = mesh.table
            feedback.pushInfo(f"3D mesh: {counted(len(mesh.triangles), 'triangle')} "
                              f"({int(mesh.side.sum())} in side faces) in "
                              f"{counted(len(t), 'feature')}.")
            geoms = qgis_io.reproject(mesh.geometries(), frame.crs, frame.source_crs, context)
            if self.given(parameters, self.OUTPUT_MESH):
                results[self.OUTPUT_MESH] = qgis_io.write_sink(
                    self, parameters, self.OUTPUT_MESH, context, geoms, t,
                    street_mesh.MESH_FIELDS, QgsWkbTypes.Type.MultiPolygonZ, frame.source_crs,
                    frame.source_crs, feedback)
                qgis_io.style_output(context, results[self.OUTPUT_MESH], "street_mesh.qml")
            if tin_path:
                qgis_io.run_engine(tin_path, street_mesh.write_tin_geopackage, tin_path,
                                   "street_mesh", geoms, t, street_mesh.MESH_FIELDS,
                                   frame.source_crs.toWkt())
                results[self.OUTPUT_TIN] = tin_path
            if obj_path:
                qgis_io.run_engine(obj_path, street_mesh.write_obj, obj_path, mesh,
                                   frame.crs.authid() or frame.crs.description())
                results[self.OUTPUT_OBJ] = obj_path
        for name, geoms, table, spec, qml in (
                (self.OUTPUT_SURFACES, result.surfaces, result.surface_table,
                 street_surfaces.SURFACE_FIELDS, "street_surfaces.qml"),
                (self.OUTPUT_JUNCTIONS, result.junctions, result.junction_table,
                 street_surfaces.JUNCTION_FIELDS, "junctions.qml")):
            if parameters.get(name) is None:
                continue
            dest = qgis_io.write_sink(self, parameters, name, context, geoms, table, spec, wkb,
                                      frame.source_crs, frame.crs, feedback)
            qgis_io.style_output(context, dest, qml)
            results[name] = dest
        feedback.setProgress(100)
        return results

