"""Shared plumbing of the urbansynth algorithms (identity, icon, parameter help)."""
from pathlib import Path

import numpy as np
import pandas as pd
from qgis.core import (
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingParameterDefinition,
)
from qgis.PyQt.QtGui import QIcon

from ..plugin.qgis_glue import qgis_io
from ..plugin.qgis_glue.toolbox import GROUPS

ICON = Path(__file__).resolve().parent.parent / "resources" / "icons" / "urbansynth.svg"


class AlgorithmBase(QgsProcessingAlgorithm):
    """Base for every urbansynth algorithm: group, icon, instance creation and ``add``.

    Subclasses set ``GROUP_ID`` (a key of :data:`GROUPS`).
    """

    GROUP_ID = "analysis"

    def group(self):
        return GROUPS[self.GROUP_ID]

    def groupId(self):  # noqa: N802
        return self.GROUP_ID

    def createInstance(self):  # noqa: N802 (QGIS API)
        return type(self)()

    def icon(self):
        return QIcon(str(ICON))

    def helpUrl(self):  # noqa: N802
        return "https://github.com/urbansynth/urban_synthesis#toolbox-reference-provider-urbansynth"

    @staticmethod
    def given(parameters, name: str) -> bool:
        """Whether an optional parameter was given a value."""
        value = parameters.get(name)
        return value is not None and value != ""

    def input_error(self, parameters, context):
        """A message when the inputs do not go together (checked before the run, in the
        dialog and on the command line), else None. Overridden by algorithms that need it."""
        return None

    def checkParameterValues(self, parameters, context):  # noqa: N802 (QGIS API)
        ok, message = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, message
        message = self.input_error(parameters, context)
        return (False, message) if message else (True, "")

    def blocks_or_roads_error(self, parameters, done: str, to_do: str):
        """The message when not exactly one of BLOCKS and ROADS is given (``done``: what
        happens to blocks, e.g. 'filled'; ``to_do``: e.g. 'fill')."""
        blocks_given, roads_given = self.given(parameters, "BLOCKS"), self.given(parameters, "ROADS")
        if blocks_given and roads_given:
            return (f"Give either Blocks or Roads, not both: blocks are {done} as they are, "
                    "roads are first turned into blocks.")
        if not blocks_given and not roads_given:
            return f"Give the Blocks to {to_do}, or Roads to extract the blocks from."
        return None

    def database_paths(self, parameters, context, first: str, second: str, what: str):
        """The files of one or two example databases (parameters ``first`` and optional
        ``second``) and their names: the file stems, numbered when both are the same."""
        paths = [self.parameterAsFile(parameters, first, context)]
        extra = self.parameterAsFile(parameters, second, context)
        if extra:
            paths.append(extra)
        if not paths[0]:
            raise QgsProcessingException(f"A {what} database is needed ({first}).")
        names = [Path(p).stem for p in paths]
        if len(names) == 2 and names[0] == names[1]:
            names = [f"{n}_{k + 1}" for k, n in enumerate(names)]
        return paths, names

    def style_databases(self, parameters, context, feedback, target_crs, n_databases: int):
        """The STYLE polygons and the 0-based database each one chooses (its STYLE_FIELD
        holds 1..n_databases), or None without style polygons."""
        field = self.parameterAsString(parameters, "STYLE_FIELD", context) or "database"
        style = qgis_io.read_source(self, parameters, "STYLE", context, feedback,
                                    kind="polygons", target_crs=target_crs, optional=True,
                                    fields=[field])
        if style is None:
            return None
        if field not in style.attributes:
            raise QgsProcessingException(f"Layer {style.name} has no field '{field}' with the "
                                         "database number (1 or 2) per polygon.")
        values = pd.to_numeric(style.attributes[field], errors="coerce").to_numpy(
            dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(values) | (values != np.round(values)) | (values < 1) | \
            (values > n_databases)
        if bad.any():
            raise QgsProcessingException(
                f"Layer {style.name}: field '{field}' must hold a database number from 1 to "
                f"{n_databases} in every polygon ({int(bad.sum())} do not).")
        return style.geometry, values.astype(np.int64) - 1

    def add(self, parameter, help_text: str, advanced: bool = False):
        """Add a parameter with its help text (shown in the dialog and in qgis_process help)."""
        parameter.setHelp(help_text)
        if advanced:
            parameter.setFlags(parameter.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        if parameter.isDestination():
            self.addParameter(parameter, createOutput=True)
        else:
            self.addParameter(parameter)


def parse_class_list(text):
    """'primary, secondary' -> {'primary', 'secondary'}; empty -> empty set (keep all)."""
    if not text:
        return set()
    return {c.strip() for c in str(text).split(",") if c.strip()}


def drivable_lines(frame, class_field, classes, feedback):
    """Keep the lines of a drivable class.

    Returns (frame, road_class), road_class being None when the layer has no classes (no
    such field, not in OSM ``other_tags`` either, or all empty): then every line is kept.
    An explicitly chosen class field that does not exist is an error.
    """
    road_class = qgis_io.osm_tag_column(frame, class_field or "highway")
    if road_class is not None and all(c is None or c == "" for c in road_class):
        road_class = None
    if road_class is None:
        if class_field and class_field != "highway":
            raise QgsProcessingException(f"Layer {frame.name} has no field '{class_field}' "
                                         "with road classes.")
        feedback.pushInfo(f"{frame.name} has no road classes: every line is used.")
        return frame, None
    if not classes:
        return frame, road_class
    keep = np.array([c in classes for c in road_class], dtype=bool)
    n_keep = int(keep.sum())
    feedback.pushInfo(f"{n_keep} of {len(frame)} lines have a drivable class.")
    if n_keep == 0:
        raise QgsProcessingException(
            f"Layer {frame.name}: no line has one of the drivable classes "
            f"({', '.join(sorted(classes))}) in field '{class_field or 'highway'}'.")
    return qgis_io.subset(frame, keep), road_class[keep]
