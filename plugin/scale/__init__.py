"""Beyond one process: Dask partitions and the QGIS-free command line."""
