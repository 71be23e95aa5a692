"""Dead ends that stop just short of another street, made clear dead ends.

A synthesised street whose dangling end lies a metre or two from another street, not on it,
is an *undershoot* (a dangle to QGIS's topology checker): a reader of the map cannot tell a
junction from a dead end there. The network invariants report such ends
(:data:`invariants.UNDERSHOOT_DISTANCE`, 2 m); the fragment synthesis and StreetGAN left 0-3
a run on the fidelity benchmark's towns: warped fragment streets and read-back streets that
end 0.8-1.4 m from a street, and stubs of 1-2 m left beside a junction by the noding. The
method meant a dead end there (its dead-end steering counted it), so it stays one:

- a new street's end within the distance of another line, not on it
  (:func:`invariants.short_ends`, the checker's rule), is cut back until it keeps
  :data:`invariants.CORRIDOR_HALF_WIDTH` (8 m) from every other line, as the dead-end
  steering's cul-de-sacs do; a street too short for that is dropped, a stub shorter than
  the distance beside a junction among them.

Joining such ends onto the street instead (a T) was measured and not kept: each closed a
small block (Mauren, fragments: the 10th-percentile block 6,050 -> 4,553 m² on seed 7) and
took the figures away from the towns on six of ten seeds.
Nothing here imports QGIS.
"""
from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np
import shapely

from ..core.geometry import substrings
from .invariants import CORRIDOR_HALF_WIDTH, UNDERSHOOT_DISTANCE, short_ends

__all__ = ["clear_undershoots"]

#: An end this close (m) to a line is on it (the noding's round-off), not short of it.
_ON_LINE = 1e-6
#: Steps (m) in which a dead end is cut back.
_STEP = 0.5


def clear_undershoots(geometry: Sequence, new: Sequence, distance: float = UNDERSHOOT_DISTANCE,
                      clear: float = CORRIDOR_HALF_WIDTH) -> Tuple[np.ndarray, np.ndarray]:
    """The network with no new street ending within ``distance`` m of another line.

    Parameters
    ----------
    geometry : a noded network of LineStrings (junctions shared by the lines' ends)
    new : bool per line, the synthesised ones (only they are cut back or dropped)
    distance : an end this close to another line is an undershoot
    clear : how far from every other line such an end is cut back to

    Returns
    -------
    (lines, kept): the lines, and which of the input lines they are (a cut-back line keeps
    its place; dropped ones are left out).

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> short = shapely.LineString([(50, 60), (50, 1.2)])        # 1.2 m short of the road
    >>> stub = shapely.LineString([(100, 0), (101.5, 0.5)])       # 1.6 m dead end
    >>> lines, kept = clear_undershoots([road, short, stub], [False, True, True])
    >>> [shapely.get_coordinates(g).round(6).tolist() for g in lines], kept.tolist()
    ([[[0.0, 0.0], [100.0, 0.0]], [[50.0, 60.0], [50.0, 8.2]]], [True, True, False])
    """
    geometry = np.asarray(geometry, dtype=object).copy()
    new = np.asarray(new, dtype=bool)
    kept = np.ones(len(geometry), bool)
    if len(geometry) < 2 or not new.any() or shapely.has_z(geometry).any():
        return geometry, kept
    index = np.arange(len(geometry))
    for _ in range(3):   # a dropped line may leave the line it continued dangling
        line, side = short_ends(geometry[kept], new[kept], _ON_LINE, distance)
        if not len(line):
            break
        order = np.lexsort((side, line))        # line by line, its first end first
        line, side = index[kept][line[order]], side[order]
        tree = shapely.STRtree(geometry)       # this round's lines, dropped ones filtered
        for i, end in zip(line.tolist(), side.tolist()):
            near = tree.query(geometry[i], predicate="dwithin", distance=clear)
            near = near[kept[near] & (near != i)]
            # a stub (shorter than the distance) has nothing to cut back to: dropped
            cut = _cut_back(geometry[i], end, geometry[near], clear)
            if cut is None:
                kept[i] = False
            else:
                geometry[i] = cut
    return geometry[kept], kept


def _cut_back(line, side: int, others: np.ndarray, clear: float):
    """``line`` cut back from its ``side`` end to the first point ``clear`` m from every one
    of ``others`` (the lines within that of it; in :data:`_STEP` m steps); None when less
    than that is left of it."""
    length = float(line.length)
    steps = np.arange(_STEP, length - UNDERSHOOT_DISTANCE, _STEP)
    at = length - steps if side == 1 else steps       # arc positions from the start
    pts = shapely.line_interpolate_point(line, at)
    free = ~shapely.dwithin(pts[:, None], others[None, :], clear).any(axis=1) if len(others) \
        else np.ones(len(pts), bool)
    if not free.any():
        return None
    s = float(at[np.argmax(free)])
    piece = substrings([line], np.array([0.0 if side == 1 else s]),
                       np.array([s if side == 1 else length]))
    # the end at the junction stays its coordinate to the last bit
    xy = shapely.get_coordinates(piece)
    kept_end = shapely.get_coordinates(shapely.get_point(line, 0 if side == 1 else -1))[0]
    xy[0 if side == 1 else -1] = kept_end
    return shapely.linestrings(xy)
