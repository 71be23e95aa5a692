"""urbansynth:installdependencies — the engine's Python packages for QGIS's own Python.

Imports nothing but qgis and the standard library: it has to run when they are missing.
"""
from pathlib import Path

from qgis.core import (QgsProcessingAlgorithm, QgsProcessingException,
                       QgsProcessingOutputString, QgsProcessingParameterBoolean)
from qgis.PyQt.QtGui import QIcon

from ..plugin.qgis_glue import dependencies, toolbox

ICON = Path(__file__).resolve().parent.parent / "resources" / "icons" / "urbansynth.svg"


class InstallDependencies(QgsProcessingAlgorithm):
    REINSTALL = "REINSTALL"
    INSTALLED = "INSTALLED"

    def name(self):
        return "installdependencies"

    def displayName(self):  # noqa: N802
        return "Install Python dependencies"

    def group(self):
        return "Setup"

    def groupId(self):  # noqa: N802
        return "setup"

    def icon(self):
        return QIcon(str(ICON))

    def tags(self):
        return list(toolbox.TAGS[self.name()])

    def helpUrl(self):  # noqa: N802
        return toolbox.help_url(self.name())

    def createInstance(self):  # noqa: N802
        return type(self)()

    def shortHelpString(self):  # noqa: N802
        return (
            "Installs the Python packages the Urban Synthesis tools need (shapely 2, pandas, "
            "OpenCV, onnxruntime, and scipy or matplotlib when QGIS lacks them) with QGIS's "
            "own Python and pip, into a folder of this plugin inside your QGIS profile "
            "(python/dependencies/urban_synthesis), not into your system. Packages QGIS "
            "already has (numpy, GDAL) are kept as they are.\n\n"
            "On Linux shapely is built against the system GEOS, which needs its headers "
            "(Debian/Ubuntu: sudo apt install libgeos-dev python3-dev build-essential). "
            "Needs access to the Python package index. Restart QGIS afterwards if a tool "
            "still reports a missing package.")

    def initAlgorithm(self, config=None):  # noqa: N802
        reinstall = QgsProcessingParameterBoolean(
            self.REINSTALL, "Reinstall all packages, even those that import", defaultValue=False)
        reinstall.setHelp("Install every package of the plugin's requirements again, e.g. "
                          "after a QGIS upgrade changed its Python.")
        self.addParameter(reinstall)
        self.addOutput(QgsProcessingOutputString(self.INSTALLED, "Installed packages"))

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        site = dependencies.private_site()
        packages = (list(dependencies.RUNTIME_PACKAGES.values())
                    if self.parameterAsBool(parameters, self.REINSTALL, context)
                    else dependencies.missing_packages())
        packages = [p for p in packages if p not in dependencies.QGIS_OWNED]
        if not packages:
            feedback.pushInfo("Every package the tools need is already there.")
            return {self.INSTALLED: ""}
        feedback.pushInfo(f"Installing {', '.join(packages)} into {site}")
        try:
            dependencies.install(packages, site, feedback.pushConsoleInfo,
                                 feedback.isCanceled, feedback.setProgress)
        except RuntimeError as error:
            raise QgsProcessingException(str(error)) from error
        still = dependencies.missing_packages()
        if still:
            raise QgsProcessingException(
                f"pip finished, but {', '.join(still)} still cannot be imported: restart QGIS "
                "and run this tool again; the log above shows what pip did.")
        feedback.pushInfo(f"Installed {', '.join(packages)}. The Urban Synthesis tools are "
                          "ready; restart QGIS if the toolbox still shows them as unavailable.")
        return {self.INSTALLED: ", ".join(packages)}
