"""Street shapes: how a random walk's segments bend (Aliaga et al. 2008, fig. 5c).

Each segment between two intersection points becomes a polyline. With the example's
streets at hand (:func:`street_shapes`), its shape is that of an example segment of the
same level and a similar chord length, at the quantile of the segment's tortuosity
attribute (:func:`_pick_shapes`), scaled onto the new chord and mirrored at random, so that
the new streets bend like the example's: the same tortuosity and turn distribution.
Without them (an example given as points only), a parabola of the points' tortuosity
attribute (:func:`_bend`). Shapes that would cross another street, leave the target or run
along a given road are redrawn, then flattened, then straightened (chords are planar), and
the tortuosity lost that way is made up on other segments (:func:`draw_geometry`).

Nothing here imports QGIS.

References
----------
Aliaga, D. G., Vanegas, C. A., Benes, B. (2008). Interactive example-based urban layout
    synthesis. ACM TOG 27(5), sec. 3.1.1, fig. 5c.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import cKDTree

from ..core import coordinates
from ..core.geometry import pinned_ends
from ..network.invariants import MIN_DUPLICATE_LENGTH, corridor_of
from ..network.links import allowed_area
from . import intersection_quadtree as iq

__all__ = ["StreetShapes", "street_shapes", "example_from_roads", "draw_geometry",
           "blend_shapes"]


@dataclass
class StreetShapes:
    """Shapes of an example's street segments (between intersection points), in a frame
    where each chord runs from (0, 0) to (1, 0) (fig. 5c: the poly-line of a segment).

    geometry : array of normalised LineStrings
    chord : (m,) chord length of each segment (m)
    tortuosity : (m,) length / chord
    level : (m,) hierarchy level of each segment's street
    """

    geometry: np.ndarray
    chord: np.ndarray
    tortuosity: np.ndarray
    level: np.ndarray

    def __len__(self) -> int:
        return len(self.geometry)

    def mean_tortuosity(self) -> float:
        return float(self.tortuosity.mean()) if len(self) else 1.0


def example_from_roads(lines, road_class=None, example: int = 0):
    """An example's intersection points and street shapes from its road lines
    (:func:`intersection_quadtree.points_from_roads`, :func:`street_shapes`)."""
    points, graph, h = iq.points_from_roads(lines, road_class, example=example)
    return points, street_shapes(graph, h.edge_level)


def street_shapes(graph, edge_level, simplify: float = 0.002) -> StreetShapes:
    """The segments of an example road graph as normalised shapes (:class:`StreetShapes`).

    Parameters
    ----------
    graph : plugin.network.street_graph.RoadGraph (edges between intersections and ends,
        as :func:`intersection_quadtree.points_from_roads` makes it)
    edge_level : int per edge, its street's level (``Hierarchy.edge_level``)
    simplify : Douglas-Peucker tolerance in chord lengths (0.2 % of the chord)
    """
    geoms = np.asarray(graph.geometry, dtype=object)
    level = np.asarray(edge_level, dtype=np.int64)
    a = graph.nodes[graph.u]
    b = graph.nodes[graph.v]
    chord = np.linalg.norm(b - a, axis=1)
    length = shapely.length(geoms)
    keep = (chord > 1.0) & (graph.u != graph.v)
    geoms, level, a, b, chord, length = (x[keep] for x in (geoms, level, a, b, chord, length))
    if not len(geoms):
        return StreetShapes(np.empty(0, dtype=object), np.zeros(0), np.zeros(0),
                            np.zeros(0, dtype=np.int64))
    d = (b - a) / chord[:, None]

    def to_frame(xy, index):
        rel = xy - a[index]
        return np.column_stack([(rel * d[index]).sum(axis=1),
                                rel[:, 0] * -d[index, 1] + rel[:, 1] * d[index, 0]]) \
            / chord[index, None]

    norm = coordinates.transform(geoms, to_frame)
    norm = shapely.simplify(norm, simplify)
    return StreetShapes(norm, chord, np.maximum(length / chord, 1.0), level)


def _pick_shapes(shapes: StreetShapes, chord, level, tortuosity, rng, k: int = 24,
                 quantile=None):
    """For each new segment, one of the ``k`` example segments of its level nearest in
    chord length: the one at the quantile of the segment's tortuosity attribute among all
    new segments (quantile matching: curvier streets get the curvier of the candidates,
    and the tortuosity distribution of the library is kept, mean included), or at the
    given ``quantile``; -1 when the library is empty."""
    out = np.full(len(chord), -1, dtype=np.int64)
    if not len(shapes):
        return out
    if quantile is None:
        tortuosity = np.asarray(tortuosity, dtype=float)
        # quantile of each segment's attribute, ties broken at random: uniform on (0, 1)
        order = np.lexsort((rng.random(len(chord)), tortuosity))
        quant = np.empty(len(chord))
        quant[order] = (np.arange(len(chord)) + rng.random(len(chord))) / max(len(chord), 1)
    else:
        quant = np.asarray(quantile, dtype=float)
    logc = np.log(np.maximum(shapes.chord, 1.0))
    for lv in np.unique(level):
        sel = np.flatnonzero(level == lv)
        pool = np.flatnonzero(shapes.level == lv)
        if len(pool) < k:
            pool = np.arange(len(shapes))
        kk = min(k, len(pool))
        _, idx = cKDTree(logc[pool, None]).query(np.log(np.maximum(chord[sel], 1.0))[:, None],
                                                 k=kk)
        idx = pool[np.asarray(idx).reshape(len(sel), kk)]
        ranked = np.take_along_axis(idx, np.argsort(shapes.tortuosity[idx], axis=1), axis=1)
        pos = np.minimum((quant[sel] * kk).astype(np.int64), kk - 1)
        out[sel] = ranked[np.arange(len(sel)), pos]
    return out


def _shape_lines(shapes: StreetShapes, pick, a_xy, b_xy, mirror):
    """The picked normalised shapes mapped onto the chords a -> b (mirrored where
    ``mirror`` is -1), with end points exactly a and b."""
    chord = b_xy - a_xy
    normal = np.column_stack([-chord[:, 1], chord[:, 0]]) * mirror[:, None]
    base = shapes.geometry[pick]

    def onto(xy, index):
        return a_xy[index] + xy[:, :1] * chord[index] + xy[:, 1:2] * normal[index]

    return pinned_ends(_map_vertices(base, onto), a_xy, b_xy)


def _map_vertices(lines, fn):
    """The lines with every vertex mapped by ``fn(xy, index)`` (``index``: the line of
    each vertex). For maps made of elementwise arithmetic only, as here: equal vertices
    stay equal without the distinct-vertex pass of :func:`coordinates.transform` (which
    guards against BLAS products), and the result is the same."""
    coords, index = shapely.get_coordinates(lines, return_index=True)
    if not len(coords):
        return np.asarray(lines, dtype=object).copy()
    return shapely.set_coordinates(np.asarray(lines, dtype=object).copy(), fn(coords, index))


def _bend(a, b, tortuosity, max_sagitta, sign, n=9):
    """A parabolic arc from a to b whose length / chord is about ``tortuosity`` (fig. 5c),
    for examples given as points (no street shapes)."""
    chord = b - a
    length = float(np.linalg.norm(chord))
    t = np.linspace(0.0, 1.0, n)
    sag = length * min(math.sqrt(max(3.0 * (tortuosity - 1.0) / 8.0, 0.0)), max_sagitta)
    if sag < 0.5 or length == 0:
        return shapely.LineString([a, b])
    normal = np.array([-chord[1], chord[0]]) / length
    pts = a + t[:, None] * chord + (sign * sag * 4.0 * t * (1.0 - t))[:, None] * normal
    return shapely.LineString(pts)


def _conflicts(lines, others, subset=None, tree=None, area=None, chord_inside=None,
               corridor=None, chord_in_corridor=None):
    """Indices of the bent lines (of ``subset``, default all) that meet another line (or a
    given line) anywhere but at shared end points, and of the lines they meet. ``tree``:
    an STRtree of ``lines`` + ``others`` whose envelopes are still valid (optional). With
    ``area`` (prepared), bent lines whose chord lies in it (``chord_inside``) but that
    bulge out of it conflict too; with ``corridor`` (the given roads' corridors, prepared),
    bent lines that run in it over 10 m longer than their chord does
    (``chord_in_corridor``), or longer than the invariants allow (a chord may run up to
    that: the two allowances added up to a double), double a given road and conflict
    too."""
    if subset is None:  # chords never cross each other: only bent lines can
        cand = np.arange(len(lines))
        bent = cand[shapely.get_num_coordinates(lines[cand]) > 2]
    else:  # changed lines, bent or not (a new chord can cut an unchanged bend)
        bent = np.unique(np.asarray(subset, dtype=np.int64))
    if len(bent) == 0:
        return np.zeros(0, dtype=np.int64)
    out_of_area = np.zeros(0, dtype=np.int64)
    if area is not None:
        check = bent[chord_inside[bent]]
        out_of_area = check[~shapely.contains(area, lines[check])]  # area is prepared
    if corridor is not None:
        check = bent[shapely.intersects(corridor, lines[bent])]
        if len(check):
            with np.errstate(invalid="ignore"):
                run = shapely.length(shapely.intersection(lines[check], corridor))
            double = (run > chord_in_corridor[check] + 10.0) | (run > MIN_DUPLICATE_LENGTH)
            out_of_area = np.r_[out_of_area, check[double]]
    allg = np.concatenate([lines, others]) if len(others) else lines
    if tree is None:
        tree = shapely.STRtree(allg)
    a, b = tree.query(lines[bent], predicate="intersects")
    a = bent[a]
    # a pair of two queried lines is found twice: its relation is tested once (the pattern
    # is symmetric, and both lines of a bad pair are reported)
    queried = np.zeros(len(allg), dtype=bool)
    queried[bent] = True
    sel = (a < b) | ((a > b) & ~queried[b])
    a, b = a[sel], b[sel]
    if len(a) == 0:
        return np.unique(out_of_area)
    # only boundary meets boundary: interiors and interior-boundary contacts are empty
    ok = shapely.relate_pattern(lines[a], allg[b], "FF*F*****")
    other = b[~ok]
    return np.unique(np.concatenate([a[~ok], other[other < len(lines)], out_of_area]))


def draw_geometry(xy, a, b, level, tort, shapes, settings, rng, others, area=None):
    """Polylines of the segments a -> b: example shapes (redrawn where they would cross),
    else parabolas; lines that still cross are straightened (chords are planar).
    ``settings``: the walk's :class:`random_walk.WalkSettings` (``max_sagitta``,
    ``shape_retries``)."""
    straight = shapely.linestrings(np.stack([xy[a], xy[b]], axis=1))
    n = len(a)
    if shapes is not None and len(shapes):
        chord = np.linalg.norm(xy[b] - xy[a], axis=1)

        def draw(idx):
            pick = _pick_shapes(shapes, chord[idx], level[idx], tort[idx], rng)
            mirror = rng.choice([-1.0, 1.0], size=len(idx))
            return _shape_lines(shapes, pick, xy[a[idx]], xy[b[idx]], mirror)

        lines = draw(np.arange(n)) if n else straight.copy()
        drawn_t = shapely.length(lines) / np.maximum(chord, 1e-9)
        # the mean the segments should keep: the example's (the drawn shapes have it
        # up to the chord lengths of the new segments)
        drawn_mean = shapes.mean_tortuosity()
    else:
        sign = rng.choice([-1.0, 1.0], size=n)
        lines = np.array([_bend(xy[i], xy[j], t, settings.max_sagitta, sg)
                          for i, j, t, sg in zip(a, b, tort, sign)], dtype=object)

        def draw(idx):
            return np.array([_bend(xy[a[i]], xy[b[i]], tort[i], settings.max_sagitta,
                                   rng.choice([-1.0, 1.0])) for i in idx], dtype=object)
    others = np.asarray(others, dtype=object)
    n_redrawn = 0
    inside = None
    if area is not None:  # a bend may not bulge out of the target where its chord is in
        area = allowed_area(area)
        inside = shapely.contains(area, straight)  # prepared: faster than within
    corridor, chord_run = None, None
    if len(others):  # no bend may run along a given road (the invariants' corridor)
        corridor = corridor_of(others)
        with np.errstate(invalid="ignore"):
            chord_run = shapely.length(shapely.intersection(straight, corridor))
    conflicts = functools.partial(_conflicts, area=area, chord_inside=inside,
                                  corridor=corridor, chord_in_corridor=chord_run)
    bad = conflicts(lines, others)
    # the changed lines are checked again (against all): a line that did not change and
    # crossed nothing cannot cross anything now but a changed line
    for _ in range(settings.shape_retries):
        if not len(bad):
            break
        lines[bad] = draw(bad)
        n_redrawn += len(bad)
        bad = conflicts(lines, others, subset=bad)
    # then flatter versions of the last shape (its offsets from the chord scaled down),
    # then the chord itself
    for scale in (0.6, 0.3, 0.0, 0.0, 0.0):
        if not len(bad):
            break
        lines[bad] = _flatten(lines[bad], xy[a[bad]], xy[b[bad]], scale) if scale > 0 \
            else straight[bad]
        bad = conflicts(lines, others, subset=bad)
    if shapes is not None and len(shapes) and n:
        lines = _restore_tortuosity(lines, chord, level, drawn_mean, shapes, xy, a, b, others,
                                    rng, conflicts, drawn_t)
    return lines, straight, n_redrawn


def _restore_tortuosity(lines, chord, level, target, shapes, xy, a, b, others, rng,
                        conflicts=_conflicts, drawn=None, rounds: int = 20,
                        tolerance: float = 0.002):
    """Make up the tortuosity lost to flattened shapes: segments that lost their bend
    (``drawn``: the tortuosity first drawn), then bent segments flatter than the target, get
    a curvier shape of their level and chord (the upper half of the quantiles of
    :func:`_pick_shapes`, below the example's 95th percentile) where it fits without
    crossing, until the mean tortuosity is the target (the example's mean over its
    segments)."""
    lines = lines.copy()
    ll = np.maximum(chord, 1e-9)
    stuck = drawn is None
    for _ in range(rounds):
        t = shapely.length(lines) / ll
        deficit = target * len(lines) - t.sum()
        if deficit <= tolerance * len(lines):
            break
        # the segments that lost their bend first (the shape distribution stays the
        # example's), then any segment flatter than the target
        low = np.flatnonzero(t < drawn - 1e-6) if not stuck else np.zeros(0, int)
        if not len(low):
            # segments drawn straight stay straight (a grid's streets keep their bearings)
            low = np.flatnonzero((t < target) & (drawn > 1.005)) if drawn is not None \
                else np.flatnonzero(t < target)
        if not len(low):
            break
        prop_idx = rng.permutation(low)[:max(1, min(len(low), int(np.ceil(4 * deficit
                                                                          / 0.05))))]
        pick = _pick_shapes(shapes, chord[prop_idx], level[prop_idx], None, rng,
                            quantile=0.5 + 0.5 * rng.random(len(prop_idx)))
        cand = _shape_lines(shapes, pick, xy[a[prop_idx]], xy[b[prop_idx]],
                            rng.choice([-1.0, 1.0], size=len(prop_idx)))
        gain = shapely.length(cand) / ll[prop_idx] - t[prop_idx]
        # not the rare hairpins of the example's tail (above its 95th percentile)
        gain[shapely.length(cand) / ll[prop_idx] > np.quantile(shapes.tortuosity, 0.95)] = 0.0
        # take the gains in order until the deficit is met
        order = np.argsort(-gain)
        keep = order[(gain[order] > 0) & (np.cumsum(np.maximum(gain[order], 0)) <= deficit
                                          + gain[order].clip(0))]
        if not len(keep):
            continue
        # accept the proposals that cross nothing; a rejected one keeps its old shape, which
        # the accepted ones are checked against again, until none is left to reject
        take = prop_idx[keep]
        trial = lines.copy()
        trial[take] = cand[keep]
        check = take  # the lines whose pairs are tested
        while len(take):
            ok = ~np.isin(take, conflicts(trial, others, subset=check))
            if ok.all():
                lines = trial
                break
            # the rejected keep their old shapes: only their pairs with the proposals left
            # are new (the other pairs were tested and stay as they were)
            check = take[~ok]
            trial[check] = lines[check]
            take = take[ok]
        # no flattened segment takes a bend any more: the other segments may
        stuck = stuck or len(take) < 0.1 * len(prop_idx)
    return lines


def _flatten(lines, a_xy, b_xy, scale):
    """Lines with their offsets from the chord a -> b scaled by ``scale`` (same ends)."""
    chord = b_xy - a_xy

    def towards_chord(xy, index):
        rel = xy - a_xy[index]
        ll = np.maximum((chord[index] ** 2).sum(axis=1), 1e-12)
        t = (rel * chord[index]).sum(axis=1) / ll
        foot = a_xy[index] + t[:, None] * chord[index]
        return foot + scale * (xy - foot)

    return pinned_ends(_map_vertices(lines, towards_chord), a_xy, b_xy)


def blend_shapes(a: StreetShapes, b: StreetShapes, beta: float, rng) -> StreetShapes:
    """A shape library with a share ``beta`` of B's shapes (a spatially varying blend gives
    its mean weight): segments then bend like a beta-mixture of both examples'."""
    n = max(len(a), len(b))
    take_b = rng.random(n) < beta
    ia = rng.integers(0, len(a), n) if len(a) else np.zeros(n, np.int64)
    ib = rng.integers(0, len(b), n) if len(b) else np.zeros(n, np.int64)
    if not len(b):
        take_b[:] = False
    if not len(a):
        take_b[:] = True

    def pick(field_):
        return np.where(take_b, getattr(b, field_)[ib] if len(b) else 0,
                        getattr(a, field_)[ia] if len(a) else 0)

    geometry = np.where(take_b, b.geometry[ib] if len(b) else None,
                        a.geometry[ia] if len(a) else None)
    return StreetShapes(geometry, pick("chord"), pick("tortuosity"), pick("level"))
