"""Motorways and trunks take no new junction.

The fidelity issue's invariant: a synthesised street meets a motorway or trunk only at one
of the given network's own junctions (an interchange, a road that crosses it). A method's
steps can still end a street on one: a walk's junction slot on a given road, a T onto the
nearest street, a fragment's street warped onto the outline of its face. Such a street
goes where its other end is a junction or a dead end (no dead end is made: the dead-end
share stays as the method steered it); where it is one piece of a longer street (its other
end joins just one more), it ends short of the road where it leaves the road's corridor (a
dead end, as side streets end at a motorway's fence). A piece that reached the network only
there is linked again by the shortest clear street that ends on no such road
(:func:`links.link_floating_pieces`), and goes where only the motorway reaches it (a strip
between the motorway and the target's edge). The contacts are the invariants' own
(:func:`invariants.check_network`), so the rule and the check cannot disagree. This module
is the one home of that rule.

Nothing here imports QGIS.
"""
from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np
import shapely

from .invariants import (CORRIDOR_HALF_WIDTH, JUNCTION_TOLERANCE, _node_degrees,
                         check_network, connected_pieces, doubles_a_street,
                         is_controlled_access)
from .links import link_floating_pieces

__all__ = ["classes_on", "end_short_of_controlled_access", "ended_short"]

#: m: a contact point and a street's end this close are one.
END_TOLERANCE = 0.01


def classes_on(pieces: Sequence, roads: Sequence, road_class: Sequence) -> np.ndarray:
    """The class of the road each piece of a given road lies on (a method nodes and cuts
    the given roads; the nearest road to the piece's middle is its own)."""
    pieces = np.asarray(pieces, dtype=object)
    cls = np.asarray(road_class, dtype=object)
    if not len(pieces):
        return np.empty(0, dtype=object)
    mid = shapely.line_interpolate_point(pieces, 0.5, normalized=True)
    return cls[shapely.STRtree(np.asarray(roads, dtype=object)).nearest(mid)]


def ended_short(line, start, corridor):
    """The part of ``line`` from its end ``start`` to where it enters ``corridor`` (a
    controlled-access road's corridor), None when nothing of it is left."""
    with np.errstate(invalid="ignore"):
        parts = shapely.get_parts(shapely.difference(line, corridor))
    parts = parts[shapely.dwithin(parts, start, END_TOLERANCE)] if len(parts) else parts
    if not len(parts) or parts[0].length <= END_TOLERANCE:
        return None
    return parts[0]


def end_short_of_controlled_access(lines: Sequence, is_new: Sequence, roads: Sequence,
                                   road_class: Sequence,
                                   area=None) -> Tuple[np.ndarray, np.ndarray, dict]:
    """New streets that end on a motorway or trunk away from its junctions end short of it.

    Parameters
    ----------
    lines : array of LineString, the network (new streets and given roads), metric CRS
    is_new : bool per line
    roads, road_class : the given roads as given (lines or multilines), and the OSM class
        of each (the given lines of ``lines`` may be pieces of them)
    area : Polygon(s), optional, the target: a joining street stays in it

    Returns
    -------
    (lines, source, stats): the network; per line its index in ``lines`` (-1: a street
    added to join a piece cut off); stats ``n_ended_short`` (streets cut back out of the
    road's corridor), ``n_removed`` (streets that went), ``n_joined`` (pieces linked
    again), ``n_dropped`` (streets of pieces only a motorway or trunk reaches).

    A side street off a road, in two pieces, whose second ends on the motorway beside the
    road's junction with it, and a short street from the road onto the motorway:

    >>> motorway = shapely.LineString([(0, 0), (200, 0)])
    >>> road = shapely.LineString([(100, 0), (100, 100)])
    >>> side = [shapely.LineString([(100, 60), (50, 60)]),
    ...         shapely.LineString([(50, 60), (50, 0)])]
    >>> spur = shapely.LineString([(100, 30), (130, 0)])
    >>> out, source, stats = end_short_of_controlled_access(
    ...     side + [spur, motorway, road], [True, True, True, False, False], [motorway, road],
    ...     ["motorway", "secondary"])
    >>> out[1].coords[-1], source.tolist()
    ((50.0, 8.0), [0, 1, 3, 4])
    >>> stats
    {'n_ended_short': 1, 'n_removed': 1, 'n_joined': 0, 'n_dropped': 0}
    """
    lines = np.asarray(lines, dtype=object)
    is_new = np.asarray(is_new, dtype=bool)
    stats = {"n_ended_short": 0, "n_removed": 0, "n_joined": 0, "n_dropped": 0}
    source = np.arange(len(lines))
    given_idx = np.flatnonzero(~is_new)
    if not is_controlled_access(road_class).any() or not is_new.any() or not len(given_idx):
        return lines, source, stats
    given_class = classes_on(lines[given_idx], roads, road_class)
    ca = is_controlled_access(given_class)
    new_idx = np.flatnonzero(is_new)
    contacts = check_network(lines[new_idx], lines[given_idx], given_class,
                             area).controlled_access
    if not len(contacts):
        return lines, source, stats
    # the corridor the streets end outside of (the invariants' own width)
    corridor = shapely.buffer(shapely.union_all(lines[given_idx[ca]]), CORRIDOR_HALF_WIDTH)
    contact_tree = shapely.STRtree(contacts)
    out = lines.copy()
    keep = np.ones(len(lines), dtype=bool)
    # the new streets with an end at a contact, and the degree of the network at the other
    at = np.zeros((len(lines), 2), dtype=bool)
    for k, end in enumerate((0, -1)):
        hit, _ = contact_tree.query(shapely.get_point(lines[new_idx], end), predicate="dwithin",
                                    distance=END_TOLERANCE)
        at[new_idx[hit], k] = True
    touching = np.flatnonzero(at.any(axis=1))
    other = shapely.get_point(lines[touching], np.where(at[touching, 0], -1, 0))
    other_degree = dict(zip(touching.tolist(),
                            _node_degrees(lines, other, JUNCTION_TOLERANCE).tolist()))
    for i in touching:
        line = lines[i]
        if at[i].all() or other_degree[i] != 2:
            # both ends on it, or the other end is a junction (it stays one) or a dead end:
            # the street goes, and no dead end is made (the share stays as steered)
            keep[i] = False
            stats["n_removed"] += 1
            continue
        short = ended_short(line, shapely.get_point(line, -1 if at[i, 0] else 0), corridor)
        if short is None:
            keep[i] = False
            stats["n_removed"] += 1
            continue
        out[i] = short
        stats["n_ended_short"] += 1
    out, source, is_new = out[keep], source[keep], is_new[keep]
    # a piece that met the network only on the motorway is linked again, not onto one nor
    # along it in its corridor (Balzers: a link ran 60 m along it); one that only the
    # motorway reaches goes, as a method drops a piece no link reaches
    on_ca = np.zeros(len(lines), dtype=bool)
    on_ca[given_idx[ca]] = True
    links, kept = link_floating_pieces(
        out, ~is_new, ends_on=~on_ca[source], pieces=connected_pieces(out), inside=area,
        accept=lambda link: not doubles_a_street([link], corridor)[0])
    stats["n_joined"] = len(links)
    stats["n_dropped"] = int((~kept).sum())
    out, source = out[kept], source[kept]
    if len(links):
        out = np.concatenate([out, links])
        source = np.r_[source, np.full(len(links), -1)]
    return out, source, stats
