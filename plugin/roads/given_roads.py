"""Generated streets joined to the roads they were given (arterials, a sketch).

A generator that knows nothing of the given roads (StreetGAN paints a whole target, thesis
ch. 4.2) still has to keep them: the network invariants (docs/ARCHITECTURE.md, "Quality
measures") want every given road in the result, every crossing a junction, the new streets
connected to the given ones and no new street doubling a given road. :func:`join_given_roads`
does that after the fact: new streets are cut back out of a corridor around the given roads,
each cut end inside the corridor's reach is carried straight on to the given road, and the
union is noded so that every crossing is a junction.

Nothing here imports QGIS.

Examples
--------
>>> import shapely
>>> given = [shapely.LineString([(0, 0), (200, 0)])]
>>> new = [shapely.LineString([(100, -50), (100, 50)]),   # crosses the given road
...        shapely.LineString([(0, 3), (200, 3)])]        # doubles it: dropped
>>> lines, level = join_given_roads(new, [1, 1], given, corridor=10.0)
>>> sorted(zip(level.tolist(), [round(g.length) for g in lines]))
[(0, 100), (0, 100), (2, 50), (2, 50)]
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import shapely

from ..core.progress import InputError

__all__ = ["CORRIDOR", "join_given_roads"]

#: Half-width (m) of the corridor around a given road inside which no new street runs.
CORRIDOR = 15.0
#: New pieces shorter than this (m) after the cut are dropped (slivers of the corridor edge).
MIN_PIECE = 5.0


def join_given_roads(new: Sequence, new_level: Optional[Sequence], given: Sequence,
                     corridor: float = CORRIDOR):
    """The given roads (level 0) and the new streets outside their corridor (their level +
    1), joined and noded.

    Parameters
    ----------
    new : array of LineString, the generated streets (metric CRS)
    new_level : their levels (0 = most important), or None (all 0)
    given : array of LineString, the roads to keep as they are
    corridor : half-width (m) of the band around the given roads kept free of new streets

    Returns
    -------
    (lines, level) : noded LineStrings (every crossing a shared vertex) and their levels
    """
    given = np.asarray([g for g in np.asarray(given, dtype=object).ravel()
                        if g is not None and not shapely.is_empty(g)], dtype=object)
    new = np.asarray(new, dtype=object)
    level = np.zeros(len(new), dtype=np.int64) if new_level is None \
        else np.asarray(new_level, dtype=np.int64)
    if not (corridor >= 0):
        raise InputError(f"the corridor must be a distance of 0 m or more, not {corridor}")
    if len(given) == 0:
        return new, level
    given = shapely.get_parts(given)
    band = shapely.buffer(shapely.union_all(given), corridor) if corridor > 0 else None
    pieces, piece_level = [], []
    if len(new):
        kept = new if band is None else shapely.difference(new, band)
        parts, index = shapely.get_parts(kept, return_index=True)
        keep = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) >= MIN_PIECE)
        parts, index = parts[keep], index[keep]
        if band is not None and len(parts):
            parts = _reach_the_given_roads(parts, band, shapely.union_all(given), corridor)
        pieces, piece_level = list(parts), list(level[index] + 1)
    lines = np.concatenate([given, np.asarray(pieces, dtype=object)])
    levels = np.concatenate([np.zeros(len(given), dtype=np.int64),
                             np.asarray(piece_level, dtype=np.int64)])
    # node everything: each line split at every crossing with every other line
    noded = shapely.get_parts(shapely.node(shapely.multilinestrings(lines)))
    noded = noded[shapely.length(noded) > 1e-6]   # noding leaves points at shared vertices
    probe = shapely.line_interpolate_point(noded, 0.5, normalized=True)
    owner = np.full(len(noded), -1)
    tree = shapely.STRtree(lines)
    hit_point, hit_line = tree.query(probe, predicate="dwithin", distance=1e-6)
    # a piece lying on two lines (a new street ending on a given road) takes the lower level
    order = np.lexsort((levels[hit_line], hit_point))
    first = order[np.r_[True, hit_point[order][1:] != hit_point[order][:-1]]]
    owner[hit_point[first]] = hit_line[first]
    ok = owner >= 0
    return noded[ok], levels[owner[ok]]


def _reach_the_given_roads(parts, band, given_union, corridor):
    """Each end of a new piece on the corridor's edge carried straight on to the given road
    (the piece was cut there: it used to reach the road)."""
    edge = shapely.boundary(band)
    out = []
    for line in parts:
        xy = shapely.get_coordinates(line)
        for end in (0, -1):
            point = shapely.Point(xy[end])
            if shapely.distance(point, edge) > 1e-6:
                continue
            target = shapely.get_coordinates(
                shapely.shortest_line(point, given_union))[-1]
            if np.hypot(*(target - xy[end])) <= 1.5 * corridor:
                xy = np.vstack([target, xy]) if end == 0 else np.vstack([xy, target])
        out.append(shapely.LineString(xy))
    return np.asarray(out, dtype=object)
