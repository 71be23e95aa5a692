"""QGIS plugin object: registers the Processing provider (also headless, for qgis_process)."""
from qgis.core import QgsApplication

from .provider import UrbanSynthesisProvider


class UrbanSynthesisPlugin:
    def __init__(self, iface):
        self.iface = iface
        self.provider = None

    def initProcessing(self):  # noqa: N802 (QGIS API name)
        self.provider = UrbanSynthesisProvider()
        QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):  # noqa: N802
        self.initProcessing()

    def unload(self):
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
