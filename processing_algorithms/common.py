"""Shared plumbing of the urbansynth algorithms (identity, icon, parameter help)."""
from pathlib import Path

from qgis.core import QgsProcessingAlgorithm, QgsProcessingParameterDefinition
from qgis.PyQt.QtGui import QIcon

ICON = Path(__file__).resolve().parent.parent / "resources" / "icons" / "urbansynth.svg"


class AlgorithmBase(QgsProcessingAlgorithm):
    """Base for every urbansynth algorithm: icon, instance creation and ``add``."""

    def createInstance(self):  # noqa: N802 (QGIS API)
        return type(self)()

    def icon(self):
        return QIcon(str(ICON))

    def helpUrl(self):  # noqa: N802
        return "https://example.org/urbansynth/urban_synthesis#toolbox-reference"

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
