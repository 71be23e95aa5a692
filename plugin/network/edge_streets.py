"""Streets cut by the target's edge joined along it, as a town's edge streets join them.

A synthesis that draws over the whole target and beyond (StreetGAN's generator) is clipped
to it: every street that ran out of the target ends on its edge, and the cells between
those streets stay open to the outside. A town's own outer streets close their blocks
instead (the fidelity benchmark's towns: 0.3-4.6 streets per km² reach the envelope's
edge; StreetGAN's clipped networks 11-19, with 0.13-0.30 of the land in closed blocks
against the towns' 0.33-0.80). :func:`join_along_edge` runs a street along the target's
edge between two neighbouring streets that end on it, where they are no more than
``max_length`` apart along it: the open cell between them becomes a block.

Not in the papers: the thesis's read-back clips the network and leaves the stubs.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import shapely
from shapely.ops import substring

from .invariants import CORRIDOR_HALF_WIDTH, corridor_of, doubles_a_street

__all__ = ["join_along_edge", "EDGE_JOIN_MAX", "EDGE_JOIN_MIN"]

#: Longest edge street (m): about the side of a town's largest blocks (the benchmark's
#: examples, 90th percentile 110 000-150 000 m², 330-390 m across). With it StreetGAN closes
#: 0.44 of the fidelity benchmark's towns into blocks (median town, 10 seeds; the towns
#: 0.61); 1000 m closed 0.56-0.80 of the nine Liechtenstein towns at about the same error,
#: no limit 0.86-0.96 of four of them (3 seeds, joined before the small-block merge)
EDGE_JOIN_MAX = 400.0
#: Shortest edge street (m): about the side of the examples' smallest blocks (10th
#: percentile, 4 400-5 700 m²); two streets ending closer on the edge would close a sliver
EDGE_JOIN_MIN = 60.0


def _ring_pieces(ring, pos, xy, ok, max_length, min_length):
    """The stretches of a closed ``ring`` between consecutive stops at ``pos`` (m along it,
    sorted; ``xy`` the stops), kept where both stops may take a street (``ok``) and the
    length is in range; each ends exactly at its stops (the lines' own points)."""
    total = ring.length
    out = []
    n = len(pos)
    for i in range(n if n > 1 else 0):
        a, b = pos[i], pos[(i + 1) % n]
        if not (ok[i] and ok[(i + 1) % n]):
            continue
        length = b - a if i + 1 < n else total - a + b
        if not min_length <= length <= max_length:
            continue
        if i + 1 < n:
            piece = substring(ring, a, b)
        else:   # round the ring's start vertex
            piece = shapely.line_merge(shapely.union(substring(ring, a, total),
                                                     substring(ring, 0.0, b)))
        if shapely.get_type_id(piece) == 1:
            coords = shapely.get_coordinates(piece)
            coords[0], coords[-1] = xy[i], xy[(i + 1) % n]
            out.append(shapely.linestrings(coords))
    return out


def _stops(edge, lines):
    """Where lines meet the edge rings: every vertex of a line on a ring (the end of a
    clipped street or of a given road clipped to the target; a street that touches the edge
    and turns back, whose vertex there lies on the ring only up to round-off: an edge
    street past it met it without a junction) and every crossing of one (a given road that
    runs on). Returns the ring, the point (x, y) and the line of each."""
    ring, li = shapely.STRtree(lines).query(edge, predicate="dwithin", distance=1e-3)
    ends, of = shapely.get_coordinates(lines[li], return_index=True)
    at = shapely.dwithin(edge[ring[of]], shapely.points(ends), 1e-3)
    with np.errstate(invalid="ignore"):
        cross = shapely.intersection(edge[ring], lines[li])
    parts, k = shapely.get_parts(cross, return_index=True)
    full = ~shapely.is_empty(parts)   # a line within a millimetre that does not meet it
    point = full & (shapely.get_type_id(parts) == 0)
    # a line along the edge for a stretch: its two ends there are stops
    along = full & (shapely.get_type_id(parts) == 1)
    xy = np.vstack([ends[at], shapely.get_coordinates(parts[point]),
                    shapely.get_coordinates(shapely.get_point(parts[along], 0)),
                    shapely.get_coordinates(shapely.get_point(parts[along], -1))])
    idx = np.r_[of[at], k[point], k[along], k[along]]
    return ring[idx], xy, li[idx]


def join_along_edge(lines: Sequence, area, takes_junction: Optional[np.ndarray] = None,
                    max_length: float = EDGE_JOIN_MAX, min_length: float = EDGE_JOIN_MIN,
                    corridor: float = CORRIDOR_HALF_WIDTH) -> Tuple[np.ndarray, int]:
    """Edge streets between the streets that end on the edge of ``area``.

    Parameters
    ----------
    lines : array of LineString, a noded network inside ``area``
    area : Polygon / MultiPolygon, the target
    takes_junction : bool mask over ``lines``, optional: False for a motorway or trunk,
        which takes no edge street where it leaves (it is met only at its own junctions)
    max_length, min_length : m, the longest and shortest edge street
    corridor : m, no edge street runs along a line for more than
        :data:`invariants.MIN_DUPLICATE_LENGTH` inside this corridor of it (a given road or
        a synthesised street that itself follows the edge)

    Returns
    -------
    streets : array of LineString, the new edge streets (each ends on two stops: line
        vertices on the edge, or crossings of it; not yet noded into ``lines``)
    n : their number

    Examples
    --------
    A road across a 300 m square and three streets from it to the northern edge, 100 m
    apart: edge streets close the four cells north of the road (the corner ones from the
    road's ends round the corners, 250 m) and, up to 400 m, none south of it (500 m):

    >>> square = shapely.box(0, 0, 300, 300)
    >>> road = shapely.LineString([(-50, 100), (350, 100)])
    >>> streets = [shapely.LineString([(x, 100), (x, 300)]) for x in (50, 150, 250)]
    >>> edge, n = join_along_edge([road] + streets, square, max_length=400)
    >>> n, sorted(round(g.length) for g in edge)
    (4, [100, 100, 250, 250])
    """
    lines = np.asarray(lines, dtype=object)
    edge = shapely.get_parts(shapely.boundary(area))
    if not len(lines) or not len(edge):
        return np.empty(0, dtype=object), 0
    ok = np.ones(len(lines), dtype=bool) if takes_junction is None else \
        np.asarray(takes_junction, dtype=bool)
    ring, xy, line = _stops(edge, lines)
    if not len(xy):
        return np.empty(0, dtype=object), 0
    # one stop per point, taking a street only where every line there takes a junction
    _, first, inverse = np.unique(np.c_[ring, np.round(xy, 4)], axis=0, return_index=True,
                                  return_inverse=True)
    stop_ok = np.ones(len(first), dtype=bool)
    np.logical_and.at(stop_ok, inverse.ravel(), ok[line])
    ring, xy = ring[first], xy[first]
    out = []
    for r in np.unique(ring):
        on = ring == r
        pos = shapely.line_locate_point(edge[r], shapely.points(xy[on]))
        order = np.argsort(pos)
        out.extend(_ring_pieces(edge[r], pos[order], xy[on][order], stop_ok[on][order],
                                max_length, min_length))
    if not out:
        return np.empty(0, dtype=object), 0
    streets = np.asarray(out, dtype=object)
    # no edge street along a given road or along a street that itself follows the edge
    bad = doubles_a_street(streets, corridor_of(lines, corridor))
    streets = streets[~bad]
    return streets, len(streets)
