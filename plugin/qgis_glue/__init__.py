"""The QGIS side: the Processing provider, the plugin object, and ``qgis_io``, the only
module that converts between QGIS objects and engine data. Nothing outside this folder (and
``processing_algorithms``) imports QGIS."""
