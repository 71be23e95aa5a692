"""Streets that stop just short of another street made to meet it.

A synthesised street whose dangling end lies a metre or two from another street, not on it,
is a dead end to a router and an *undershoot* (a dangle) to QGIS's topology checker, though
a reader of the map takes it for a junction. The network invariants report such ends
(:data:`invariants.UNDERSHOOT_DISTANCE`, 2 m); the fragment synthesis and StreetGAN left 0-3
a run on the fidelity benchmark's towns: warped fragment streets and read-back streets that
end 0.8-1.4 m from a street, and stubs of 1-2 m left beside a junction by the noding. Here:

- a new dead-end line shorter than the distance (a stub, not a street) is dropped;
- a new street's dangling end within the distance of another line is joined onto it by the
  straight piece to its nearest point (a T), where that piece crosses nothing, stays inside
  the target and the line may be met (not a motorway or trunk away from its junctions); the
  line met is split there, so the junction is a vertex of every line through it.

Not in the papers: they end streets on streets or leave them open, never a metre short.
Nothing here imports QGIS.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import shapely

from ..core.geometry import pinned_ends, substrings
from .invariants import UNDERSHOOT_DISTANCE
from .links import allowed_area

__all__ = ["join_undershoots"]

#: An end this close (m) to a line is on it (the noding's round-off), not short of it.
_ON_LINE = 1e-6


def _end_counts(geometry: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The first and last points of the lines (n, 2) each, and how many line ends lie at
    each (n,) each."""
    first = shapely.get_coordinates(shapely.get_point(geometry, 0))
    last = shapely.get_coordinates(shapely.get_point(geometry, -1))
    _, inverse, count = np.unique(np.concatenate([first, last]), axis=0, return_inverse=True,
                                  return_counts=True)
    at = count[inverse.ravel()]
    return np.stack([first, last], axis=1), at.reshape(2, -1).T


def _dangling(geometry: np.ndarray, new: np.ndarray, others: np.ndarray
              ) -> Tuple[np.ndarray, np.ndarray]:
    """(line, which end) of the ends of new lines that no other line's end shares and that
    lie on no line but their own: a street's dead end."""
    ends, count = _end_counts(geometry)
    line, side = np.nonzero((count == 1) & new[:, None])
    if not len(line):
        return line, side
    pts = shapely.points(ends[line, side])
    allg = np.concatenate([geometry, others])
    e_i, l_i = shapely.STRtree(allg).query(pts, predicate="dwithin", distance=_ON_LINE)
    on_other = np.zeros(len(pts), bool)
    on_other[e_i[l_i != line[e_i]]] = True
    return line[~on_other], side[~on_other]


def join_undershoots(geometry: Sequence, new: Sequence, target=None,
                     closed_roads: Optional[Sequence] = None,
                     others: Optional[Sequence] = None,
                     distance: float = UNDERSHOOT_DISTANCE) -> Tuple[np.ndarray, np.ndarray]:
    """The network with no new street ending within ``distance`` m of another line.

    Parameters
    ----------
    geometry : a noded network of LineStrings (junctions shared by the lines' ends)
    new : bool per line, the synthesised ones (only their ends are moved or dropped)
    target : polygon a joining piece must stay inside (within the links' 1 m), optional
    closed_roads : roads no street may end on (motorways and trunks): the lines of the
        network along them (their middle within a millimetre) are not met
    others : lines not in the network that a joining piece may not cross either (given
        roads kept apart), optional

    Returns
    -------
    (lines, parent): the lines, and for each the index of the input line it is (a line met
    by a join is split in two pieces with the same parent; a dropped stub has none).

    >>> road = shapely.LineString([(0, 0), (100, 0)])
    >>> short = shapely.LineString([(50, 60), (50, 1.2)])        # 1.2 m short of the road
    >>> lines, parent = join_undershoots([road, short], [False, True])
    >>> [g.wkt for g in lines], parent.tolist()
    (['LINESTRING (0 0, 50 0)', 'LINESTRING (50 60, 50 1.2, 50 0)', \
'LINESTRING (50 0, 100 0)'], [0, 1, 0])
    """
    geometry = np.asarray(geometry, dtype=object)
    new = np.asarray(new, dtype=bool)
    parent = np.arange(len(geometry))
    others = np.empty(0, dtype=object) if others is None else np.asarray(others, dtype=object)
    if len(geometry) < 2 or not new.any() or shapely.has_z(geometry).any():
        return geometry.copy(), parent
    closed = np.zeros(len(geometry), bool)
    if closed_roads is not None and len(closed_roads):
        mid = shapely.line_interpolate_point(geometry, 0.5, normalized=True)
        hit, _ = shapely.STRtree(np.asarray(closed_roads, dtype=object)).query(
            mid, predicate="dwithin", distance=1e-3)
        closed[hit] = True
        closed &= ~new
    # stubs: a new line with a dead end, shorter than the distance (rounds: a chain of them)
    for _ in range(3):
        line, _side = _dangling(geometry, new, others)
        stub = np.zeros(len(geometry), bool)
        stub[line] = shapely.length(geometry[line]) < distance
        if not stub.any():
            break
        geometry, new, closed, parent = (x[~stub] for x in (geometry, new, closed, parent))
    area = None if target is None else allowed_area(target)
    # joins, shortest gap first; each join splits a line, so the ends are found again
    tried = set()
    while True:
        line, side = _dangling(geometry, new, others)
        if not len(line):
            break
        ends = shapely.get_point(geometry[line], np.where(side == 0, 0, -1))
        e_i, l_i = shapely.STRtree(geometry).query(ends, predicate="dwithin",
                                                   distance=distance)
        keep = (l_i != line[e_i]) & ~closed[l_i]
        e_i, l_i = e_i[keep], l_i[keep]
        if not len(e_i):
            break
        gap = shapely.distance(ends[e_i], geometry[l_i])
        done = False
        for k in np.argsort(gap, kind="stable"):
            i, j, end = int(line[e_i[k]]), int(l_i[k]), ends[e_i[k]]
            key = (shapely.get_coordinates(end).tobytes(), shapely.to_wkb(geometry[j]))
            if key in tried:
                continue
            tried.add(key)
            piece = shapely.shortest_line(end, geometry[j])
            if _blocked(piece, i, j, geometry, others, area):
                continue
            geometry, new, closed, parent = _join(geometry, new, closed, parent, i,
                                                  int(side[e_i[k]]), j, piece)
            done = True
            break
        if not done:
            break
    return geometry, parent


def _blocked(piece, i: int, j: int, geometry: np.ndarray, others: np.ndarray, area) -> bool:
    """Whether the joining ``piece`` from line i's end onto line j may not be laid: it
    leaves the target, or meets a line other than i at its start and j at its end."""
    if area is not None and not shapely.covers(area, piece):
        return True
    hits = shapely.STRtree(geometry).query(piece, predicate="intersects")
    a, b = shapely.get_point(piece, 0), shapely.get_point(piece, -1)
    for h in hits:
        meet = shapely.intersection(piece, geometry[h])
        allowed = a if h == i else b if h == j else None
        # one point, the allowed one up to the intersection's round-off
        if allowed is None or shapely.get_type_id(meet) != 0 or \
                shapely.distance(meet, allowed) > _ON_LINE:
            return True
    return len(others) > 0 and bool(shapely.intersects(others, piece).any())


def _join(geometry, new, closed, parent, i: int, side: int, j: int, piece):
    """Line i extended from its ``side`` end by ``piece`` onto line j, which is split where
    the piece meets it (unless that is one of its ends)."""
    q = shapely.get_coordinates(piece)[-1]
    xy = shapely.get_coordinates(geometry[i])
    xy = np.vstack([xy, q]) if side == 1 else np.vstack([q, xy])
    geometry = geometry.copy()
    geometry[i] = shapely.linestrings(xy)
    target = geometry[j]
    at = float(shapely.line_locate_point(target, shapely.points(q)))
    if _ON_LINE < at < target.length - _ON_LINE:
        start = shapely.get_coordinates(shapely.get_point(target, 0))[0]
        stop = shapely.get_coordinates(shapely.get_point(target, -1))[0]
        two = substrings([target, target], np.array([0.0, at]), np.array([at, target.length]))
        two = pinned_ends(two, np.array([start, q]), np.array([q, stop]))
        geometry = np.concatenate([geometry[:j], two[:1], geometry[j + 1:], two[1:]])
        new, closed, parent = (np.r_[x[:j], x[j], x[j + 1:], x[j]] for x in (new, closed, parent))
    return geometry, new, closed, parent
