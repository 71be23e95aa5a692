"""Urban Synthesis QGIS plugin entry point."""


def classFactory(iface):  # noqa: N802 (QGIS API name)
    from .plugin.qgis_glue.plugin import UrbanSynthesisPlugin

    return UrbanSynthesisPlugin(iface)
