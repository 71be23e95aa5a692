"""Coordinate transforms of shapely geometries that keep rings closed on every processor.

A BLAS matrix product is not bitwise reproducible across rows and processor kernels: the
first and the closing vertex of a ring, equal on input, can come out of one product
1e-10 apart, and GEOS then rejects the ring ("Points of LinearRing do not form a closed
linestring"). Every transform here maps each *distinct* (geometry, x, y) row once and
scatters the result back, so vertices that were equal stay equal, whatever the kernel.

Examples
--------
>>> import numpy as np, shapely
>>> ring = shapely.Polygon([(0, 0), (3, 0), (3, 1), (0, 1)])
>>> moved = transform([ring], lambda xy, index: xy @ np.array([[0.0, 1.0], [-1.0, 0.0]]))
>>> bool(shapely.is_valid(moved[0])), round(float(moved[0].area), 9)
(True, 3.0)
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import shapely

__all__ = ["transform", "rigid", "rotate", "translate"]


def transform(geoms: Sequence, fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
              include_z: bool = False) -> np.ndarray:
    """Map the vertices of ``geoms`` by ``fn(xy, index)``, each distinct vertex once.

    Parameters
    ----------
    geoms : array of shapely geometries (None allowed)
    fn : callable
        ``fn(coords, index) -> new coords``: ``coords`` is (n, 2) (or (n, 3) with
        ``include_z``), ``index`` the position in ``geoms`` of the geometry of each row,
        so that a transform can differ per geometry.
    include_z : bool
        Pass and set z as well.

    Returns
    -------
    ndarray of new geometries (the input is not modified).
    """
    geoms = np.asarray(geoms, dtype=object)
    coords, index = shapely.get_coordinates(geoms, include_z=include_z, return_index=True)
    if len(coords) == 0:
        return geoms.copy()
    keyed = np.column_stack([index.astype(np.float64), coords])
    unique, inverse = np.unique(keyed, axis=0, return_inverse=True)
    mapped = np.asarray(fn(unique[:, 1:], unique[:, 0].astype(np.int64)), dtype=np.float64)
    return shapely.set_coordinates(geoms.copy(), mapped[inverse.ravel()])


def rigid(geoms: Sequence, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``R x + t`` on every vertex (one 2 x 2 rotation, one translation)."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    return transform(geoms, lambda xy, _: apply_affine(xy, r, t))


def apply_affine(xy: np.ndarray, matrix: np.ndarray, translation) -> np.ndarray:
    """``M x + t`` for (n, 2) points, written out: a BLAS product of (n, 2) by (2, 2)
    rounds differently under different processor kernels; this is the same on all."""
    xy = np.asarray(xy, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    return np.column_stack([m[0, 0] * xy[..., 0] + m[0, 1] * xy[..., 1] + t[0],
                            m[1, 0] * xy[..., 0] + m[1, 1] * xy[..., 1] + t[1]])


def rotate(geoms: Sequence, angles, centres) -> np.ndarray:
    """Rotate each geometry by its angle (radians, counter-clockwise) about its centre.

    ``angles`` is a scalar or one value per geometry; ``centres`` one (2,) point or one per
    geometry.
    """
    geoms = np.asarray(geoms, dtype=object)
    n = len(geoms)
    angles = np.broadcast_to(np.asarray(angles, dtype=np.float64), (n,))
    centres = np.broadcast_to(np.asarray(centres, dtype=np.float64), (n, 2))

    def fn(xy, i):
        c, s = np.cos(angles[i]), np.sin(angles[i])
        rel = xy - centres[i]
        return np.column_stack([c * rel[:, 0] - s * rel[:, 1],
                                s * rel[:, 0] + c * rel[:, 1]]) + centres[i]
    return transform(geoms, fn)


def translate(geoms: Sequence, offsets) -> np.ndarray:
    """Move each geometry by its offset (one (2,) offset or one per geometry)."""
    geoms = np.asarray(geoms, dtype=object)
    offsets = np.broadcast_to(np.asarray(offsets, dtype=np.float64), (len(geoms), 2))
    return transform(geoms, lambda xy, i: xy + offsets[i])
