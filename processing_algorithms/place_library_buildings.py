"""urbansynth:placelibrarybuildings - the best-fitting library building per parcel
(Scharl 2010, ch. 6)."""
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsWkbTypes,
)

from ..plugin.buildings import bestfit
from ..plugin.core.text import counted
from ..plugin.qgis_glue import qgis_io
from .common import AlgorithmBase

class PlaceLibraryBuildings(AlgorithmBase):
    GROUP_ID = "synthesis"
    PARCELS = "PARCELS"
    ROADS = "ROADS"
    BUILDING_LIBRARY = "BUILDING_LIBRARY"
    MIN_SETBACK = "MIN_SETBACK"
    STREET_REACH = "STREET_REACH"
    MAX_ANGLE = "MAX_ANGLE"
    DEM = "DEM"
    MAX_PARCEL_SLOPE = "MAX_PARCEL_SLOPE"
    OUTPUT = "OUTPUT"

    def name(self):
        return "placelibrarybuildings"

    def displayName(self):  # noqa: N802
        return "Place library buildings on parcels (best fit)"

    def shortHelpString(self):  # noqa: N802
        return (
            "Per parcel, the largest building of a library that fits inside it (Scharl 2010, "
            "ch. 6): every street access side of the building faces a street and no blind "
            "side faces one (within the maximum angle), and the building is moved to the "
            "street with a minimum setback. The default library holds twelve built-in "
            "buildings.\n\n"
            "Output: the placed footprints with source_id, rotation, offset_x, offset_y, parcel_id "
            "and the library's attributes, in the parcels' CRS, styled by height."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        poly = [QgsProcessing.SourceType.TypeVectorPolygon]
        self.add(QgsProcessingParameterFeatureSource(self.PARCELS, "Parcels", poly),
                 "Parcels, e.g. from 'Subdivide blocks into parcels' or a cadastre. Their "
                 "parcel_id is kept when it is a unique whole number per parcel; else (text, "
                 "repeated, missing) parcels are numbered 1..n in layer order, as the log says.")
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads", [QgsProcessing.SourceType.TypeVectorLine]),
            "Street centrelines: which parcel and building sides face a street.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDING_LIBRARY, "Building library", poly, optional=True),
            "Library footprints (any position) with 'street_access_sides' and 'blind_sides': "
            "comma-separated edge indices of the exterior ring (edge i runs from vertex i to "
            "i+1). Empty: the built-in library of twelve buildings.")
        self.add(QgsProcessingParameterNumber(
            self.MIN_SETBACK, "Minimum setback (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=bestfit.DEFAULT_SETBACK, minValue=0.0, maxValue=100.0),
            "Distance kept between a building and its parcel's street sides, and between a "
            "building and any road centreline running through or beside its parcel (a "
            "building never crosses a road).")
        self.add(QgsProcessingParameterNumber(
            self.STREET_REACH, "Street reach (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=bestfit.DEFAULT_REACH, minValue=0.1, maxValue=1000.0),
            "A side faces a street when a ray this long cast perpendicular from its centre "
            "hits a road centreline (setback plus half a street).", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MAX_ANGLE, "Maximum angle to the street (°)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=bestfit.MAX_ANGLE, minValue=0.0, maxValue=90.0),
            "A facing side is at most this far from parallel to the street (Scharl: 30°).",
            advanced=True)
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model", optional=True),
            "Best fit on terrain (Scharl ch. 6.2): each building goes down to the ground of its "
            "lowest corner (base_z, sunk_m; footprints get Z) and parcels steeper than the "
            "maximum parcel slope stay empty.")
        self.add(QgsProcessingParameterNumber(
            self.MAX_PARCEL_SLOPE, "Maximum parcel slope (%)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=100 * bestfit.DEFAULT_MAX_PARCEL_SLOPE, minValue=0.0, maxValue=1000.0),
            "With an elevation model: parcels whose fitted terrain plane is steeper than this "
            "get no building (Scharl's maxParcelSlope).")
        self.add(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Placed buildings", QgsProcessing.SourceType.TypeVectorPolygon),
            "Placed library buildings with parcel_id, source_id (the library building), "
            "rotation (°, about its centroid) and offset_x, offset_y (m: the move of its "
            "centroid in the metric working CRS the log names, not in the output's CRS) "
            "that place it, area_m2, parcel_share (of the "
            "parcel's area), base_z, parcel_slope_pct and sunk_m (with an elevation model), "
            "then the library's own fields (those of the built-in library: name, height_m, "
            "levels, building_type, roof_shape, street_access_sides, blind_sides).")

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        parcels = qgis_io.read_source(self, parameters, self.PARCELS, context, feedback,
                                      kind="polygons", fields=["parcel_id"])
        crs = parcels.crs
        road_lines, _ = self.roads_and_arterials(parameters, self.ROADS, context, feedback, crs)
        library = self._library(parameters, context, feedback)
        ids = self.block_ids(parcels, feedback, "parcel_id", "parcel")
        result = qgis_io.run_engine(
            parcels.name, bestfit.fit_buildings, parcels.geometry, road_lines, library,
            parcel_ids=ids, min_setback=self.number(parameters, self.MIN_SETBACK, context),
            reach=self.number(parameters, self.STREET_REACH, context),
            max_angle=self.number(parameters, self.MAX_ANGLE, context),
            dem=self._dem(parameters, context, feedback, parcels),
            max_parcel_slope=self.number(parameters, self.MAX_PARCEL_SLOPE, context) / 100.0,
            progress=qgis_io.progress_for(feedback, 10, 90))
        s = result.stats
        feedback.pushInfo(f"{s['n_placed']} of {counted(s['n_parcels'], 'parcel')} got a "
                          f"building; {100 * s['empty_share']:.1f} % left empty "
                          f"({counted(s['no_street'], 'has', 'have')} no side facing a street, "
                          f"{counted(s['no_fit'], 'fits', 'fit')} no library building with the "
                          "minimum setback and the side rules).")
        if s.get("crossed_by_road"):
            feedback.pushInfo(counted(s["crossed_by_road"], "parcel stays", "parcels stay")
                              + " empty because a road centreline runs through or along "
                              "the parcel and no library building fits clear of it with the "
                              "minimum setback.")
        if s.get("too_steep"):
            feedback.pushInfo(counted(s["too_steep"], "parcel is steeper than the maximum "
                                      "parcel slope and stays empty.", "parcels are steeper "
                                      "than the maximum parcel slope and stay empty."))
        if s.get("no_terrain"):
            feedback.pushWarning(f"{counted(s['no_terrain'], 'parcel stays', 'parcels stay')} "
                                 "empty because the DEM has no "
                                 "value under them (or under their building's corners): it "
                                 "has holes there or does not reach them.")
        if s["n_placed"] == 0:
            feedback.pushWarning("No parcel got a building: " + (
                "no parcel side faces a street within the street reach (are the roads the "
                "parcels' roads?)." if s["no_street"] == s["n_parcels"] else
                "no library building fits with the minimum setback and the side rules (a "
                "smaller setback, or smaller buildings in the library)." if s["no_fit"] ==
                s["n_parcels"] - s["no_street"] else "see the counts above."))
        # with a DEM the buildings stand at their base height: PolygonZ whatever is placed
        with_dem = self.given(parameters, self.DEM)
        dest = qgis_io.write_sink(self, parameters, self.OUTPUT, context, result.geometry,
                                  result.table, bestfit.PLACEMENT_FIELDS + bestfit.library_fields(library),
                                  QgsWkbTypes.Type.PolygonZ if with_dem else QgsWkbTypes.Type.Polygon,
                                  parcels.source_crs, crs, feedback)
        qgis_io.style_output(context, dest, "buildings_by_height.qml")
        feedback.setProgress(100)
        return {self.OUTPUT: dest}

    def _dem(self, parameters, context, feedback, frame):
        """The elevation model resampled to the parcels' working CRS, or None."""
        layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if layer is None:
            return None
        x0, y0, x1, y1 = shapely.total_bounds(frame.geometry)
        bounds = (x0 - 10, y0 - 10, x1 + 10, y1 + 10)
        cell = qgis_io.raster_cell_size(layer, frame.crs, bounds, context, feedback=feedback)
        return qgis_io.read_raster(layer, frame.crs, bounds, cell, feedback)

    def _library(self, parameters, context, feedback):
        if not self.given(parameters, self.BUILDING_LIBRARY):
            feedback.pushInfo("Building library: the built-in library of twelve buildings.")
            return bestfit.default_library()
        frame = qgis_io.read_source(
            self, parameters, self.BUILDING_LIBRARY, context, feedback, kind="polygons",
            repair=False, required_fields=["street_access_sides", "blind_sides"],
            read_twice=True)   # any position: its own working CRS keeps its sizes
        a = frame.attributes
        return qgis_io.run_engine(
            f"Layer {frame.name}", bestfit.library_from_table, frame.geometry,
            a["street_access_sides"].to_numpy(dtype=object),
            a["blind_sides"].to_numpy(dtype=object), source_ids=frame.fids, attributes=a)
