"""Urban Synthesis: the engine (pure Python on shapely 2, numpy, scipy, OpenCV, onnxruntime)
and, in ``qgis_glue``, the only code that imports QGIS.

Folders follow the pipeline (docs/ARCHITECTURE.md):

- ``core``: progress and cancellation, exact coordinate transforms, resource paths
- ``network``: real roads -> planar street graph, hierarchy, blocks, fragments, street surfaces
- ``retrieval``: shape context, warps, the example databases
- ``roads``: road synthesis (fragments, random walks, growth, StreetGAN)
- ``parcels``: blocks -> lots (recursive, skeleton, Voronoi)
- ``planned``: planned layouts by domain splitting (Yang et al. 2013)
- ``buildings``: footprints, attributes, library buildings, part-based buildings
- ``measure``: layout metrics and the report
- ``scale``: Dask partitions and the QGIS-free command line
- ``qgis_glue``: the provider, the plugin object and the QGIS <-> engine adapter
"""
