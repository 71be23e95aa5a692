"""Parcels: blocks shrunk by their streets and split into lots.

The methods form a registry (:data:`subdivision.METHODS`): recursive and skeleton
(Scharl 2010) in :mod:`subdivision`, Voronoi rows along the OBB (Aliaga et al. 2008) in
:mod:`voronoi`, which registers itself when this package is imported.
"""
from . import subdivision, voronoi  # noqa: F401  (voronoi registers 'voronoi-obb')
