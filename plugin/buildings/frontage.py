"""Frontage: how a footprint faces its nearest street.

A footprint's *axis* is the direction of the long side of its minimum rotated rectangle;
its *street direction* that of the nearest street segment (road centreline, or the block
outline, which runs along the centrelines). Their difference, folded to the rectangle's
symmetry (modulo 90°), is the footprint's angle to its street. Real towns keep it small
(Liechtenstein: most footprints within 10° of their street); a block layout moved rigidly
into a block of another shape loses it. The thesis names the problem ("non-constant
setback", Hartmann ch. 5.1.6) and leaves the orientation of re-synthesised footprints
unspecified (ch. 5.2); :func:`align_to_frontage` keeps each footprint's angle to its
street from the example block in the target block. The layout of a block of another
shape also leaves frontage empty -- the dead-end streets inside a target block, which the
example block did not have, and the sides of irregular blocks; :func:`fill_frontage`
builds it up to the share of frontage the example block has built (a simplification of
ours: the thesis leaves such blocks under-filled, ch. 5.1.6, "irregular blocks poorly
covered").

Hand-written here: the folding of angles and the greedy frontage fill; rectangles,
nearest segments, distances and rotations are shapely's and :mod:`core.coordinates`'.

References
----------
Hartmann, S., thesis ch. 5.1 (layout transfer, artefacts), ch. 5.2 (re-synthesis along
street segments).
"""
from __future__ import annotations

from typing import List, Optional, Sequence, Tuple

import numpy as np
import shapely

from ..core import coordinates
from ..core.geometry import minimum_rectangles, two_point_segments

__all__ = ["REACH", "SERVE", "fold", "main_axis", "street_segments", "nearest_street",
           "street_angle", "relative_angle", "align_to_frontage", "street_points",
           "served_share", "fill_frontage"]

#: Footprints farther than this from every street (m) have no frontage: interior
#: buildings (the thesis's grouping distance tau is 25 m, ch. 5.2).
REACH = 30.0


def fold(angle: np.ndarray) -> np.ndarray:
    """Angles (radians) folded into [-pi/4, pi/4): a rectangle's axes are 90° apart."""
    return (np.asarray(angle, dtype=np.float64) + np.pi / 4) % (np.pi / 2) - np.pi / 4


def main_axis(polygons: Sequence) -> np.ndarray:
    """Direction (radians) of the long side of each polygon's minimum-area rectangle
    (:func:`core.geometry.minimum_rectangles`, rotating calipers)."""
    return np.radians(minimum_rectangles(np.asarray(polygons, dtype=object))[2])


def street_segments(lines: Sequence) -> np.ndarray:
    """Two-point segments of lines or polygon outlines (the streets a footprint may face;
    :func:`core.geometry.two_point_segments`)."""
    return two_point_segments(lines)


def nearest_street(geoms: Sequence, segments: np.ndarray
                   ) -> Tuple[np.ndarray, np.ndarray]:
    """(direction in radians, distance in m) of the nearest street segment to each geometry
    (NaN / inf when there is none)."""
    geoms = np.asarray(geoms, dtype=object)
    direction = np.full(len(geoms), np.nan)
    dist = np.full(len(geoms), np.inf)
    if not len(segments) or not len(geoms):
        return direction, dist
    tree = shapely.STRtree(segments)
    (i, j), d = tree.query_nearest(geoms, return_distance=True, all_matches=False)
    xy = shapely.get_coordinates(segments[j]).reshape(-1, 2, 2)
    v = xy[:, 1] - xy[:, 0]
    direction[i] = np.arctan2(v[:, 1], v[:, 0])
    dist[i] = d
    return direction, dist


def relative_angle(polygons: Sequence, segments: np.ndarray
                   ) -> Tuple[np.ndarray, np.ndarray]:
    """Signed angle (radians, folded to [-45°, 45°)) of each footprint's axis to its
    nearest street, and its distance to that street."""
    direction, dist = nearest_street(polygons, segments)
    return fold(main_axis(polygons) - direction), dist


def street_angle(polygons: Sequence, lines: Sequence) -> np.ndarray:
    """Unsigned angle (degrees, 0-45) of each footprint to its nearest street segment."""
    polygons = np.asarray(polygons, dtype=object)
    if not len(polygons):
        return np.zeros(0)
    rel, _ = relative_angle(polygons, street_segments(lines))
    return np.degrees(np.abs(rel))


def align_to_frontage(polygons: Sequence, example_angle: np.ndarray,
                      target_segments: np.ndarray, reach: float = REACH,
                      mask: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Rotate each footprint about its centroid so that its angle to its nearest target
    street equals the angle its example had to the example's nearest street.

    Parameters
    ----------
    polygons : footprints placed in the target block (e.g. rigidly transferred)
    example_angle : (n,) signed angle (radians, :func:`relative_angle`) of each footprint to
        its street in the example block; NaN: leave it as it is
    target_segments : street segments of the target (:func:`street_segments`)
    reach : footprints farther than this from every target street keep their orientation
    mask : optional (n,) bool, only these may turn

    Returns
    -------
    (rotated footprints, rotation applied in radians)
    """
    polygons = np.asarray(polygons, dtype=object)
    out = polygons.copy()
    turn = np.zeros(len(polygons))
    if not len(polygons):
        return out, turn
    rel, dist = relative_angle(polygons, target_segments)
    ok = np.isfinite(example_angle) & np.isfinite(rel) & (dist <= reach)
    if mask is not None:
        ok &= mask
    turn[ok] = fold(np.asarray(example_angle)[ok] - rel[ok])
    idx = np.flatnonzero(ok & (np.abs(turn) > 1e-9))
    if len(idx):
        cen = shapely.get_coordinates(shapely.centroid(polygons[idx]))
        out[idx] = coordinates.rotate(polygons[idx], turn[idx], cen)
    return out, turn


#: A street point is served when a footprint stands within this distance (m): the
#: thesis's grouping distance tau (ch. 5.2).
SERVE = 25.0
#: Street points are sampled this far apart (m).
SAMPLE_STEP = 5.0
#: Example footprints tried per unserved street point.
TRIES = 6


def street_points(lines: Sequence, step: float = SAMPLE_STEP) -> Tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along lines (or polygon outlines), with the direction
    (radians) of the street at each."""
    seg = street_segments(lines)
    if not len(seg):
        return np.zeros((0, 2)), np.zeros(0)
    xy = shapely.get_coordinates(seg).reshape(-1, 2, 2)
    length = np.hypot(*(xy[:, 1] - xy[:, 0]).T)
    n = np.maximum(1, np.floor(length / step)).astype(np.int64)
    s = np.repeat(np.arange(len(seg)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    t = (k + 0.5) / n[s]
    pts = xy[s, 0] + t[:, None] * (xy[s, 1] - xy[s, 0])
    d = xy[:, 1] - xy[:, 0]
    return pts, np.arctan2(d[s, 1], d[s, 0])


def served_share(lines: Sequence, polygons: Sequence, reach: float = SERVE) -> float:
    """Share of the street points (:func:`street_points`) with a footprint within reach."""
    pts, _ = street_points(lines)
    polygons = np.asarray(polygons, dtype=object)
    if not len(pts):
        return 0.0
    if not len(polygons):
        return 0.0
    return float(np.mean(shapely.distance(shapely.points(pts), shapely.union_all(polygons))
                         <= reach))


def fill_frontage(placed: Sequence, buildable, lines: Sequence, examples: Sequence,
                  example_angle: np.ndarray, example_offset: np.ndarray, share: float,
                  rng: np.random.Generator, gap: float = 0.01, reach: float = SERVE,
                  tries: int = TRIES) -> Tuple[List, List[int]]:
    """Place example footprints along the street frontage a layout leaves empty -- the
    dead-end streets inside a block (cul-de-sacs) and the sides of irregular blocks that a
    rigid fit of another block's layout does not reach -- until the share of served
    street points equals the example block's.

    Each added footprint is an example footprint that faces a street in its block: turned
    so that it keeps its example angle to the target street (:func:`align_to_frontage`)
    and set back by its example distance (centroid to street), on the side of the street
    where it fits inside ``buildable`` without touching the footprints already there.
    Unserved street points are visited in a seeded random order.

    Parameters
    ----------
    placed : footprints already in the block (legal)
    buildable : where footprints may stand
    lines : the block's streets (outline and the roads inside it)
    examples, example_angle, example_offset : street-facing example footprints (any
        frame), their signed angle to their street (radians) and centroid distance to it
    share : the example block's served share (:func:`served_share`)
    rng : numpy Generator (the block's)

    Returns
    -------
    (added footprints, index into ``examples`` of each)
    """
    examples = np.asarray(examples, dtype=object)
    pts, direction = street_points(lines)
    added: List = []
    source: List[int] = []
    if not len(examples) or not len(pts) or share <= 0:
        return added, source
    point_geoms = shapely.points(pts)
    placed = np.asarray(placed, dtype=object)
    if len(placed):
        served = shapely.distance(point_geoms, shapely.union_all(placed)) <= reach
    else:
        served = np.zeros(len(pts), dtype=bool)
    if served.mean() >= share:
        return added, source
    # footprints already there, grown by the gap, with their bounding boxes (quick test)
    taken = list(shapely.buffer(placed, gap, quad_segs=2, join_style="mitre")) \
        if len(placed) else []
    boxes = [shapely.bounds(g) for g in taken]
    shapely.prepare(buildable)
    cen = shapely.get_coordinates(shapely.centroid(examples))
    centred = coordinates.translate(examples, -cen)
    axis = main_axis(centred)

    def free(poly) -> bool:
        x0, y0, x1, y1 = shapely.bounds(poly)
        for g, (a0, b0, a1, b1) in zip(taken, boxes):
            if a0 <= x1 and x0 <= a1 and b0 <= y1 and y0 <= b1 and shapely.intersects(poly, g):
                return False
        return True

    for i in rng.permutation(len(pts)):
        if served.mean() >= share:
            break
        if served[i]:
            continue
        normal = np.array([-np.sin(direction[i]), np.cos(direction[i])])
        # the candidates in the order they are tried: example k, then its two sides
        ks = rng.integers(len(examples), size=tries)
        sides = np.array([rng.permutation([1.0, -1.0]) for _ in ks]).ravel()
        ks = np.repeat(ks, 2)
        turn = fold(direction[i] + example_angle[ks] - axis[ks])
        centre = pts[i] + (sides * example_offset[ks])[:, None] * normal[None, :]
        inside = shapely.contains_xy(buildable, centre[:, 0], centre[:, 1])
        if not inside.any():
            continue
        ks, turn, centre = ks[inside], turn[inside], centre[inside]

        def place(xy, j, turn=turn, centre=centre):
            c, s_ = np.cos(turn[j]), np.sin(turn[j])
            return np.column_stack([c * xy[:, 0] - s_ * xy[:, 1],
                                    s_ * xy[:, 0] + c * xy[:, 1]]) + centre[j]
        candidates = coordinates.transform(centred[ks], place)
        for j in np.flatnonzero(shapely.within(candidates, buildable)):
            if free(candidates[j]):
                added.append(candidates[j])
                source.append(int(ks[j]))
                g = shapely.buffer(candidates[j], gap, quad_segs=2, join_style="mitre")
                taken.append(g)
                boxes.append(shapely.bounds(g))
                served |= shapely.distance(point_geoms, candidates[j]) <= reach
                break
    return added, source
