"""Urban Synthesis engine (pure Python, no QGIS) and the QGIS glue modules.

Engine modules (hierarchy, blocks, fragments, ...) never import qgis; only ``qgis_io``,
``provider`` and ``plugin`` do.
"""
