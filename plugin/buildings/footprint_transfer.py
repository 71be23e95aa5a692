"""City-block layout transfer: conflicts and their relaxation (thesis ch. 5.1).

After the retrieved example block is rigidly aligned with the target (Procrustes on the
DTW correspondences, :mod:`database`), each example footprint is (1) deleted when it is
not inside the target block, (2) *conflicted* when it reaches into the street offset
(the road surface plus setback) and fixed otherwise. The thesis then relaxes the
conflicted footprints by position-based dynamics (Mueller et al. 2007): a vertex outside
the street offset polygon or inside another footprint is projected onto that outline
(the collision impulse), and Gauss-Seidel iterations restore the wall lengths. Here each
footprint is the thesis's rigid body: the projected vertices are followed by a
shape-matching step (the least-squares rigid pose of the rest shape onto them, the
PBD shape-matching constraint), so wall lengths are kept exactly, and the iteration stops
when no constraint is violated. What still conflicts afterwards is trimmed or dropped
by :func:`footprints.legalise`.

References
----------
Hartmann, thesis ch. 5.1 ("Conflicts", "Refinement by position-based dynamics");
Mueller, Heidelberger, Hennix, Ratcliff (2007), Position based dynamics.
"""
from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np
import shapely

from ..core import coordinates
from ..retrieval.shape_context import rigid_align

__all__ = ["classify", "relax"]

#: Relaxation iterations (the thesis gives none; conflicts settle in a few).
ITERATIONS = 20
#: Extra push past an outline (m) so that a projected vertex ends strictly inside.
PUSH = 0.05
#: Overlap (m²) below which two footprints count as sharing a wall, not colliding: the
#: wall shared by two OSM buildings overlaps by slivers that trimming removes anyway.
SLIVER = 0.05
#: Weight of the vertices that violate nothing in the shape-matching step.
FREE_WEIGHT = 0.05
#: Share of a footprint that must lie in the target block for it to be kept.
MIN_INSIDE = 0.5


def classify(footprints: Sequence, block, buildable,
             min_inside: float = MIN_INSIDE) -> Tuple[np.ndarray, np.ndarray]:
    """(keep, conflicted) masks.

    keep: at least ``min_inside`` of the footprint lies in the block (the thesis deletes
    every footprint even partly outside; with blocks of another city a building that
    crosses the boundary by a metre is better moved than lost, so only those mostly
    outside are deleted); conflicted: kept but not inside the street offset polygon
    ``buildable`` (it also covers the part outside the block).
    """
    fp = np.asarray(footprints, dtype=object)
    if len(fp) == 0:
        return np.zeros(0, bool), np.zeros(0, bool)
    with np.errstate(invalid="ignore"):
        share = shapely.area(shapely.intersection(fp, block)) / np.maximum(shapely.area(fp),
                                                                           1e-12)
    keep = share >= min_inside
    conflicted = keep & ~shapely.within(fp, buildable)
    return keep, conflicted


def _project(points: np.ndarray, outline) -> np.ndarray:
    """Nearest points of ``outline`` (a linear geometry) to ``points`` (p, 2)."""
    lines = shapely.shortest_line(shapely.points(points), outline)
    return shapely.get_coordinates(lines).reshape(-1, 2, 2)[:, 1]


def relax(footprints: Sequence, conflicted: np.ndarray, buildable,
          iterations: int = ITERATIONS) -> Tuple[np.ndarray, int]:
    """Move conflicted footprints into ``buildable`` and off each other, rigidly.

    Parameters
    ----------
    footprints : array of Polygon (aligned example footprints inside the block)
    conflicted : bool mask, the footprints that may move (the others stay fixed)
    buildable : Polygon / MultiPolygon, the block less the street offset
    iterations : int, Gauss-Seidel sweeps at most

    Returns
    -------
    (footprints with the conflicted ones moved, sweeps used)
    """
    fp = np.asarray(footprints, dtype=object).copy()
    original = fp.copy()
    movers = np.flatnonzero(conflicted)
    if len(movers) == 0:
        return fp, 0
    outline = shapely.boundary(buildable)
    shapely.prepare(buildable)
    rest = {i: shapely.get_coordinates(shapely.get_exterior_ring(fp[i]))[:-1] for i in movers}
    sweeps = 0
    for sweeps in range(1, iterations + 1):
        tree = shapely.STRtree(fp)
        violated = False
        for i in movers:
            poly = fp[i]
            hits = tree.query(poly, predicate="intersects")
            others = hits[hits != i]
            if others.size:
                others = others[shapely.area(shapely.intersection(fp[others], poly)) > SLIVER]
            inside = shapely.within(poly, buildable)
            if inside and not others.size:
                continue
            violated = True
            xy = shapely.get_coordinates(shapely.get_exterior_ring(poly))[:-1]
            target = xy.copy()
            out = ~shapely.contains_xy(buildable, xy[:, 0], xy[:, 1])
            if out.any():
                p = _project(xy[out], outline)
                step = p - xy[out]
                norm = np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-12)[:, None]
                target[out] = p + PUSH * step / norm
            shift = np.zeros(2)
            for j in others:
                other = fp[j]
                sub = shapely.contains_xy(other, xy[:, 0], xy[:, 1])
                if sub.any():
                    p = _project(xy[sub], shapely.boundary(other))
                    step = p - xy[sub]
                    norm = np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-12)[:, None]
                    target[sub] = p + PUSH * step / norm
                # the other's corners inside this one push it away as a whole
                oxy = shapely.get_coordinates(shapely.get_exterior_ring(other))[:-1]
                hit = shapely.contains_xy(poly, oxy[:, 0], oxy[:, 1])
                if hit.any():
                    p = _project(oxy[hit], shapely.boundary(poly))
                    push = oxy[hit] - p
                    k = int(np.argmax(np.hypot(push[:, 0], push[:, 1])))
                    n = max(float(np.hypot(*push[k])), 1e-12)
                    shift += push[k] * (1.0 + PUSH / n)
            target += shift
            # shape matching: the rigid pose of the rest shape nearest the targets; the
            # projected vertices weigh most (the constraint), the free ones anchor the turn
            moved_w = np.where(np.hypot(*(target - xy).T) > 1e-12, 1.0, FREE_WEIGHT)
            r, t, _ = rigid_align(rest[i], target, moved_w)
            fp[i] = coordinates.rigid([original[i]], r, t)[0]
        if not violated:
            break
    # a footprint the relaxation could not free goes back to where the example had it:
    # a rigid move that failed is no better a start for trimming than the original pose
    tree = shapely.STRtree(fp)
    for i in movers:
        hits = tree.query(fp[i], predicate="intersects")
        hits = hits[hits != i]
        overlap = hits.size and (shapely.area(shapely.intersection(fp[hits], fp[i])) > SLIVER).any()
        if overlap or not shapely.within(fp[i], buildable):
            fp[i] = original[i]
    return fp, sweeps
