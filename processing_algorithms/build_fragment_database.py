"""urbansynth:buildfragmentdatabase - road fragments per level, shape and terrain descriptors."""
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
)

from ..plugin.network import blocks, fragments, invariants
from ..plugin.qgis_glue import qgis_io
from ..plugin.retrieval import database
from .common import AlgorithmBase


class BuildFragmentDatabase(AlgorithmBase):
    GROUP_ID = "databases"
    ROADS = "ROADS"
    LEVEL_FIELD = "LEVEL_FIELD"
    DEM = "DEM"
    MIN_AREA = "MIN_AREA"
    MIN_WIDTH = "MIN_WIDTH"
    DEM_CELL_SIZE = "DEM_CELL_SIZE"
    OUTPUT = "OUTPUT"
    N_FRAGMENTS = "N_FRAGMENTS"

    def name(self):
        return "buildfragmentdatabase"

    def displayName(self):  # noqa: N802
        return "Build fragment database"

    def shortHelpString(self):  # noqa: N802
        return (
            "Decomposes a levelled road network into hierarchical fragments and stores them, "
            "with shape and terrain descriptors, in a GeoPackage example database for "
            "fragment-based road synthesis (Hartmann, ch. 4.1).\n\n"
            "For each street level l, a fragment is a closed face of the streets with level <= l; "
            "its interior streets are those of level l + 1 inside it, and a fragment whose "
            "interior holds only dead ends is flagged as a city block. Use the output of "
            "'Extract road hierarchy' as input.\n\n"
            "The database holds the fragments (area, aspect ratio, compactness, relief change), "
            "their interior streets, 100 boundary samples with scale-aware shape-context "
            "histograms and, with a DEM, slope descriptors and a relief patch per fragment. "
            "Its metadata records the example's dead-end share (street ends on the convex "
            "hull of the lines are taken as an extract's edge, not as dead ends), which the "
            "fragment synthesis steers its streets to."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.ROADS, "Roads with levels", [QgsProcessing.SourceType.TypeVectorLine]),
            "Street lines with a hierarchy level per line (0 = arterial), e.g. the output of "
            "'Extract road hierarchy'.")
        self.add(QgsProcessingParameterField(
            self.LEVEL_FIELD, "Level field", defaultValue="level",
            parentLayerParameterName=self.ROADS, type=QgsProcessingParameterField.DataType.Numeric,
            optional=True),
            "Integer street level (0 = arterial, larger = more local); 'level' when left empty. "
            "Only the order counts: levels 1, 2, 3 or 10, 20, 30 are stored as 0, 1, 2.")
        self.add(QgsProcessingParameterRasterLayer(
            self.DEM, "Elevation model", optional=True),
            "A DEM in any CRS: adds the relief change, mean slope, slope descriptors and a "
            "relief patch to every fragment (thesis ch. 4.1, terrain term). Heights in metres, or "
            "in the unit the raster declares (band unit or vertical CRS: feet are converted).")
        self.add(QgsProcessingParameterNumber(
            self.MIN_AREA, "Minimum fragment area (m²)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=blocks.MIN_BLOCK_AREA, minValue=0.0, maxValue=1e6),
            "Faces smaller than this are junction islands and road slivers, not fragments.",
            advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.MIN_WIDTH, "Minimum fragment width (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=blocks.MIN_BLOCK_WIDTH, minValue=0.0, maxValue=1000.0),
            "Faces whose mean width 2·area/perimeter is under this are strips between dual "
            "carriageways, not fragments.", advanced=True)
        self.add(QgsProcessingParameterNumber(
            self.DEM_CELL_SIZE, "DEM cell size (m)", QgsProcessingParameterNumber.Type.Double,
            defaultValue=fragments.RELIEF_CELL_SIZE, minValue=0.5, maxValue=100.0),
            "The DEM is resampled to this cell size in the working CRS; relief patches use it.",
            advanced=True)
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Fragment database", fileFilter="GeoPackage (*.gpkg)"),
            "GeoPackage file to write (replaced if it exists).")
        self.addOutput(QgsProcessingOutputNumber(self.N_FRAGMENTS, "Number of fragments"))

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        level_field = self.parameterAsString(parameters, self.LEVEL_FIELD, context) or "level"
        source = self.parameterAsSource(parameters, self.ROADS, context)
        if source is not None and level_field not in source.fields().names() and \
                level_field not in qgis_io.field_aliases(self, parameters, self.ROADS, context,
                                                         source):
            raise QgsProcessingException(
                f"Layer {qgis_io.layer_name(self, parameters, self.ROADS, context)} has no "
                f"field '{level_field}' with the street levels: run 'Extract road hierarchy' "
                "on the roads first (its roads have 'level'), or name the level field in "
                "LEVEL_FIELD.")
        frame = qgis_io.read_source(self, parameters, self.ROADS, context, feedback,
                                    kind="lines", required_fields=[level_field],
                                    fields=[level_field])
        label = frame.name
        min_area = self.number(parameters, self.MIN_AREA, context)
        min_width = self.number(parameters, self.MIN_WIDTH, context)
        cell = self.number(parameters, self.DEM_CELL_SIZE, context)
        output = self.parameterAsFileOutput(parameters, self.OUTPUT, context)

        levels = pd.to_numeric(frame.attributes[level_field], errors="coerce").to_numpy(
            dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(levels) | (levels < 0) | (levels != np.round(levels))
        if bad.all():
            raise QgsProcessingException(
                f"Layer {label}: field '{level_field}' holds no street level (whole numbers "
                ">= 0, 0 = arterial). Run 'Extract road hierarchy' first.")
        if bad.any():
            feedback.pushInfo(f"{label}: {int(bad.sum())} lines without a valid level skipped.")
        lines, levels = frame.geometry[~bad], levels[~bad].astype(np.int64)
        feedback.setProgress(5)

        dem = None
        dem_layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem_layer is not None:
            dem = qgis_io.read_raster(dem_layer, frame.crs, shapely.total_bounds(lines), cell, feedback)
            feedback.pushInfo(f"DEM resampled to {dem.array.shape[1]} x {dem.array.shape[0]} "
                              f"cells of {cell:g} m.")
        feedback.setProgress(15)

        frags = qgis_io.run_engine(label, fragments.extract_fragments, lines, levels,
                                   min_area=min_area, min_width=min_width, dem=dem,
                                   cell_size=cell, progress=qgis_io.progress_for(feedback, 15, 60))
        counts = frags.counts
        values = counts["level_values"]
        if values != list(range(len(values))):
            shown = ", ".join(map(str, values[:6])) + (f", ... {values[-1]}"
                                                       if len(values) > 6 else "")
            feedback.pushInfo(f"{label}: levels {shown} of field '{level_field}' are the "
                              f"levels 0 to {len(values) - 1} of the database (only their "
                              "order counts).")
        for level, n in counts["per_level"].items():
            feedback.pushInfo(f"Level {level}: {n} fragments "
                              f"({counts['blocks_per_level'].get(level, 0)} city blocks).")
        if counts["n_unassigned_streets"]:
            feedback.pushInfo(f"{counts['n_unassigned_streets']} street edges (between "
                              "junctions) of level >= 1 lie in no closed fragment (open edges "
                              "of the network) and are not stored.")
        # the fragments hold no dead end outside a closed face: the synthesis steers its
        # share to the example's, recorded here
        share = invariants.dead_end_share_of_extract(lines)
        if np.isfinite(share):
            feedback.pushInfo(f"Dead-end share of the example: {share:.2f} (street ends on "
                              "the convex hull of the lines are taken as an extract's edge).")
        source = f"{label} (field '{level_field}')" + (
            f", DEM '{dem_layer.name()}'" if dem_layer is not None else "")
        qgis_io.run_engine(label, database.write_fragment_database, output, frags,
                           qgis_io.crs_text(frame.crs), source=source, elevation=dem,
                           extra={"name": self.database_name(label),
                                  "min_area_m2": min_area, "min_width_m": min_width,
                                  "relief_cell_m": cell if dem is not None else None,
                                  **({"dead_end_share": share} if np.isfinite(share) else {})},
                           progress=qgis_io.progress_for(feedback, 60, 100))
        # the file's name, not ``output``: that is the run's staging copy until it succeeds
        feedback.pushInfo(f"Fragment database written: {Path(output).name} ({len(frags)} "
                          "fragments).")
        return {self.OUTPUT: output, self.N_FRAGMENTS: len(frags)}
