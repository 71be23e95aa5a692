"""QGIS plugin object: registers the Processing provider (also headless, for qgis_process)
and, on the desktop, the Plugins-menu action that installs the engine's Python packages."""
from qgis.core import Qgis, QgsApplication

from . import dependencies
from .provider import ICON, UrbanSynthesisProvider

MENU = "&Urban Synthesis"
INSTALLER = "urbansynth:installdependencies"


class UrbanSynthesisPlugin:
    def __init__(self, iface):
        self.iface = iface
        self.provider = None
        self.install_action = None

    def initProcessing(self):  # noqa: N802 (QGIS API name)
        self.provider = UrbanSynthesisProvider()
        QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):  # noqa: N802
        self.initProcessing()
        from qgis.PyQt.QtGui import QIcon
        from qgis.PyQt.QtWidgets import QAction

        self.install_action = QAction(QIcon(str(ICON)), "Install Python dependencies…",
                                      self.iface.mainWindow())
        self.install_action.triggered.connect(self.open_installer)
        self.iface.addPluginToMenu(MENU, self.install_action)
        missing = dependencies.missing_packages()
        if missing:
            self.iface.messageBar().pushMessage(
                "Urban Synthesis", dependencies.missing_message(missing), Qgis.MessageLevel.Warning, 0)

    def open_installer(self):
        import processing

        processing.execAlgorithmDialog(INSTALLER)
        if not dependencies.missing_packages() and self.provider is not None:
            self.provider.refreshAlgorithms()

    def unload(self):
        if self.install_action is not None:
            self.iface.removePluginMenu(MENU, self.install_action)
            self.install_action = None
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
