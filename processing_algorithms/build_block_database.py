"""urbansynth:buildblockdatabase - example blocks with their footprints and building attributes."""
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterString,
)

from ..plugin.buildings import attributes as building_attributes
from ..plugin.core.ids import as_numbers, whole_ids
from ..plugin.core.text import counted
from ..plugin.network import blocks
from ..plugin.qgis_glue import qgis_io
from ..plugin.retrieval import database
from .common import AlgorithmBase


class BuildBlockDatabase(AlgorithmBase):
    GROUP_ID = "databases"
    BLOCKS = "BLOCKS"
    BUILDINGS = "BUILDINGS"
    BLOCK_ID_FIELD = "BLOCK_ID_FIELD"
    OUTPUT = "OUTPUT"
    N_BLOCKS = "N_BLOCKS"
    N_BUILDINGS = "N_BUILDINGS"

    def name(self):
        return "buildblockdatabase"

    def displayName(self):  # noqa: N802
        return "Build block database"

    def shortHelpString(self):  # noqa: N802
        return (
            "Stores example city blocks with their building footprints and attributes in a "
            "GeoPackage example database for footprint synthesis by example (Hartmann, ch. 5.1 "
            "and 5.2).\n\n"
            "Use the blocks and buildings written by 'Extract city blocks'. Buildings are "
            "matched to blocks by the block id field; when the buildings have no such field, "
            "or an id names a block the building does not lie in (blocks numbered anew), they "
            "are assigned by location (the block holding most of their area). Buildings "
            "outside every block are left out. In an OSM multipolygons layer only the polygons "
            "with a 'building' value are buildings.\n\n"
            "The database holds the blocks (area, perimeter, aspect ratio, compactness, number "
            "of buildings, coverage), the footprints (block_id, height_m, levels, building_type "
            "...) and 100 boundary samples with scale-aware shape-context histograms per block."
        )

    def initAlgorithm(self, config=None):  # noqa: N802
        self.add(QgsProcessingParameterFeatureSource(
            self.BLOCKS, "Blocks", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "City block polygons, e.g. the blocks output of 'Extract city blocks'.")
        self.add(QgsProcessingParameterFeatureSource(
            self.BUILDINGS, "Buildings", [QgsProcessing.SourceType.TypeVectorPolygon]),
            "Building footprints, e.g. the buildings output of 'Extract city blocks' (with "
            "block_id, height_m, levels, building_type). In a layer with a 'building' field "
            "(OSM multipolygons) only the polygons with a value in it are buildings; their "
            "height, levels and type are then read from the OSM tags.")
        self.add(QgsProcessingParameterString(
            self.BLOCK_ID_FIELD, "Block id field", defaultValue="block_id", optional=True),
            "Field naming the block in both layers. Blocks without it are numbered 1..n; "
            "buildings without it are assigned to blocks by location.")
        self.add(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Block database", fileFilter="GeoPackage (*.gpkg)"),
            "GeoPackage file to write (replaced if it exists).")
        self.addOutput(QgsProcessingOutputNumber(self.N_BLOCKS, "Number of blocks"))
        self.addOutput(QgsProcessingOutputNumber(self.N_BUILDINGS, "Number of buildings"))

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        id_field = (self.parameterAsString(parameters, self.BLOCK_ID_FIELD, context) or "").strip()
        output = self.parameterAsFileOutput(parameters, self.OUTPUT, context)
        # only the fields the database keeps: wide OSM layers are slow to convert
        block_frame = qgis_io.read_source(self, parameters, self.BLOCKS, context, feedback,
                                          kind="polygons", fields=[id_field])
        label = block_frame.name
        feedback.setProgress(10)
        # an OSM multipolygons layer: its buildings only, their attributes from the tags
        building_frame = self.only_buildings(qgis_io.read_source(
            self, parameters, self.BUILDINGS, context, feedback, kind="polygons",
            target_crs=block_frame.crs, fields=[id_field, *database.BUILDING_FIELDS, "building",
                                                "other_tags", *building_attributes.TAG_FIELDS]),
            feedback)
        feedback.setProgress(25)

        if id_field and id_field not in block_frame.attributes:
            if id_field != "block_id":   # a field named by the user: a typo is an error
                raise QgsProcessingException(
                    f"Layer {label} has no field '{id_field}' (fields: "
                    f"{', '.join(block_frame.attributes.columns) or 'none'}).")
            feedback.pushInfo(f"{label} has no field 'block_id': blocks are numbered 1..n and "
                              "buildings assigned by location.")
        parts, owner = shapely.get_parts(block_frame.geometry, return_index=True)
        if len(parts) > len(block_frame):
            # a block is one face (a dissolved layer holds many): each part is a block of its
            # own, numbered anew, its buildings found by location
            n_multi = int((np.bincount(owner) > 1).sum())
            feedback.pushInfo(f"{label}: {counted(n_multi, 'block')} of several parts split "
                              f"into {len(parts)} blocks of one face each; blocks are numbered 1..n "
                              "and buildings assigned by location.")
            block_frame = qgis_io.Frame(parts, block_frame.attributes.iloc[owner].reset_index(
                drop=True).drop(columns=[c for c in (id_field,) if c], errors="ignore"),
                block_frame.fids[owner], block_frame.source_crs, block_frame.crs,
                block_frame.name)
        block_ids = None
        if id_field and id_field in block_frame.attributes:
            # the blocks' own ids, when they are usable, so that buildings can refer to them
            block_ids = whole_ids(block_frame.attributes[id_field])
            if block_ids is None:
                feedback.pushInfo(f"{label}: field '{id_field}' is not a unique whole number per "
                                  "block; blocks are numbered 1..n and buildings assigned by "
                                  "location.")
        own_ids = block_ids is not None
        if block_ids is None:
            block_ids = np.arange(1, len(block_frame) + 1)

        b_label = building_frame.name
        by_field = own_ids and id_field in building_frame.attributes
        if by_field:
            bid = as_numbers(building_frame.attributes[id_field])
            known = np.isin(bid, block_ids) & np.isfinite(bid)
            # an id counts only where the building lies in the block it names: blocks
            # numbered anew (extracted again, or another town's) name other blocks
            named = np.flatnonzero(known)
            a = building_frame.geometry[named]
            b = block_frame.geometry[pd.Index(block_ids).get_indexer(bid[named])]
            elsewhere = ~shapely.intersects(a, b) | shapely.touches(a, b)
            if elsewhere.any():
                feedback.pushWarning(
                    f"{b_label}: {int(elsewhere.sum())} of {counted(len(named), 'building')} "
                    f"lie outside the block of {label} that '{id_field}' names (were the "
                    "blocks numbered anew?): they are assigned by location.")
                known[named[elsewhere]] = False
                bid[named[elsewhere]] = np.nan
            if not known.any():
                feedback.pushInfo(f"{b_label}: no building lies in a block it names in "
                                  f"'{id_field}'; buildings are assigned by location.")
                by_field = False
            elif not known.all():
                # the others (an id of no block here, or none) are placed by location
                index, _ = blocks.assign_to_blocks(block_frame.geometry,
                                                   building_frame.geometry[~known])
                located = index >= 0
                bid[np.flatnonzero(~known)[located]] = block_ids[index[located]]
                if located.any():
                    feedback.pushInfo(f"{b_label}: " + counted(
                        located.sum(), "building names", "buildings name") + f" no block of "
                        f"{label} it lies in in '{id_field}': assigned by location.")
                known = np.isin(bid, block_ids) & np.isfinite(bid)
        if not by_field:
            index, _ = blocks.assign_to_blocks(block_frame.geometry, building_frame.geometry)
            known = index >= 0
            bid = np.where(known, block_ids[np.maximum(index, 0)], -1)
        if (~known).any():
            feedback.pushInfo(f"{b_label}: {int((~known).sum())} of "
                              f"{counted(len(known), 'building')} "
                              f"{'lies' if (~known).sum() == 1 else 'lie'} in no block and "
                              f"{'is' if (~known).sum() == 1 else 'are'} left out.")
        if not known.any():
            raise QgsProcessingException(
                f"Layer {b_label}: no building lies in one of the blocks of {label}; "
                "check that the two layers cover the same area.")
        attrs = self._attributes(building_frame, feedback).loc[known]
        source = f"blocks {label}, buildings {b_label}"
        qgis_io.run_engine(label, database.write_block_database, output, block_frame.geometry,
                           building_frame.geometry[known], bid[known].astype(np.int64),
                           qgis_io.crs_text(block_frame.crs), block_ids=block_ids,
                           building_attributes=attrs, source=source,
                           extra={"name": self.database_name(b_label)},
                           progress=qgis_io.progress_for(feedback, 30, 100))
        n_buildings = int(known.sum())
        # the file's name, not ``output``: that is the run's staging copy until it succeeds
        feedback.pushInfo(f"Block database written: {Path(output).name} "
                          f"({counted(len(block_frame), 'block')}, "
                          f"{counted(n_buildings, 'building')}).")
        return {self.OUTPUT: output, self.N_BLOCKS: len(block_frame),
                self.N_BUILDINGS: n_buildings}

    def _attributes(self, frame, feedback):
        """The stored building attributes: the layer's own (the buildings of 'Extract city
        blocks'), else -- an OSM layer, with a 'building' field and no building_type -- read
        from its tags as 'Extract city blocks' reads them."""
        a = frame.attributes
        if "building" in a and not any(c in a for c in database.BUILDING_FIELDS):
            attrs = self.building_attributes_of(frame)
            feedback.pushInfo(f"{frame.name}: height, levels and type read from the OSM tags "
                              f"({int(attrs['height_m'].notna().sum())} of "
                              f"{counted(len(frame), 'building')} with a height).")
            return attrs[list(database.BUILDING_FIELDS)]
        return a[[c for c in database.BUILDING_FIELDS if c in a]]
