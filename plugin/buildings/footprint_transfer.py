"""City-block layout transfer: conflicts and their relaxation (thesis ch. 5.1).

After the retrieved example block is rigidly aligned with the target (Procrustes on the
DTW correspondences, :mod:`database`), each example footprint is (1) deleted when it is
not inside the target block, (2) *conflicted* when it reaches into the street offset
(the road surface plus setback) and fixed otherwise. The thesis then relaxes the
conflicted footprints by position-based dynamics (Mueller et al. 2007): a vertex outside
the street offset polygon or inside another footprint is projected onto that outline
(the collision impulse), and Gauss-Seidel iterations with explicit Verlet integration
restore the wall lengths. Two relaxations, used one after the other (:func:`relax`):

- :func:`relax_rigid`: each footprint the thesis's rigid body -- the projected vertices
  are followed by a shape-matching step (the least-squares rigid pose of the rest shape
  onto them, the PBD shape-matching constraint), so wall lengths are kept exactly;
- :func:`relax_pbd`: the thesis's particle system -- corner particles, wall-length and
  shape constraints (soft), collision constraints (hard), Verlet integration -- for the
  footprints the rigid step could not free (a gap a little narrower than the building,
  a road between two of its corners).

What still conflicts afterwards is trimmed or dropped by :func:`footprints.legalise`.

References
----------
Hartmann, thesis ch. 5.1 ("Conflicts", "Refinement by position-based dynamics");
Mueller, Heidelberger, Hennix, Ratcliff (2007), Position based dynamics.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import shapely

from ..core import coordinates
from ..core.progress import InputError
from ..retrieval.shape_context import rigid_align

__all__ = ["classify", "relax", "relax_rigid", "relax_pbd"]

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
          method: str = "rigid+pbd") -> Tuple[np.ndarray, int]:
    """Resolve the conflicts of transferred footprints (thesis ch. 5.1, refinement).

    ``method``: ``"rigid"`` (:func:`relax_rigid`: PBD shape matching, each footprint
    congruent), ``"pbd"`` (:func:`relax_pbd`: the thesis's particles, wall constraints and
    collision projection with Verlet integration; a footprint may give a little to fit a
    gap) or ``"rigid+pbd"`` (default): rigid first, PBD for the footprints it could not
    free. Measured on the leave-one-town-out transfers of the Liechtenstein towns
    (tests/benchmarks/bench_footprints.py): of 330 conflicted footprints rigid frees 231,
    PBD 261, both 268 -- fewer trimmed and deleted footprints -- at about 1.5x the time.

    Returns
    -------
    (footprints with the conflicted ones moved, sweeps / steps used)
    """
    if method == "rigid":
        return relax_rigid(footprints, conflicted, buildable)
    if method == "pbd":
        return relax_pbd(footprints, conflicted, buildable)
    if method != "rigid+pbd":
        raise InputError(f"unknown relaxation {method!r} (rigid, pbd or rigid+pbd)")
    fp = np.asarray(footprints, dtype=object)
    moved, sweeps = relax_rigid(fp, conflicted, buildable)
    still = np.asarray(conflicted, dtype=bool) & shapely.equals_exact(moved, fp, 0.0)
    if not still.any():
        return moved, sweeps
    moved, steps = relax_pbd(moved, still, buildable)
    return moved, sweeps + steps


def _overlap(polygons, polygon) -> np.ndarray:
    """Which of ``polygons`` overlap ``polygon`` by more than a sliver; an area the overlay
    could not give (NaN) counts as an overlap, not as none. GEOS's overlay raises the
    floating-point "invalid" flag on some nearly collinear footprint edges with a correct
    result, which numpy printed as a RuntimeWarning in the Processing log (three times in a
    district of 938 Vaduz blocks): it is silenced here."""
    with np.errstate(invalid="ignore"):
        area = shapely.area(shapely.intersection(polygons, polygon))
    return ~(area <= SLIVER)


def relax_rigid(footprints: Sequence, conflicted: np.ndarray, buildable,
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
                others = others[_overlap(fp[others], poly)]
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
        overlap = hits.size and _overlap(fp[hits], fp[i]).any()
        if overlap or not shapely.within(fp[i], buildable):
            fp[i] = original[i]
    return fp, sweeps


# --------------------------------------------------------------------------- PBD

#: Position-based dynamics: time steps at most, solver iterations per step, velocity kept
#: per step (Verlet damping), stiffness of the wall-length and of the shape (diagonal)
#: constraints (Mueller et al. 2007, sec. 3.3: k in [0, 1]).
PBD_STEPS = 30
PBD_ITERATIONS = 4
PBD_DAMPING = 0.5
PBD_WALL_STIFFNESS = 0.9
PBD_SHAPE_STIFFNESS = 0.5
#: A relaxed footprint is accepted when every wall keeps its length within this share and
#: its area within this share of the original (a wall may give a little; no crumpling).
PBD_MAX_STRAIN = 0.10
#: The iteration stops when no collision is left and no wall or diagonal is strained by
#: more than this share.
PBD_TOLERANCE = 0.02
#: Collision-free but still strained footprints that move less than this per step (m)
#: have settled (squeezed into a gap a little narrower than they are).
STALL = 1e-3
#: Fixed footprints within this distance (m) of a mover take part in its relaxation.
NEIGHBOURHOOD = 10.0
#: The street offset outline is sampled this densely (m) for the collision test.
OUTLINE_STEP = 1.0


def _rings(polys: np.ndarray):
    """Unique ring vertices (p, 2), owner per vertex, ring start offsets."""
    rings = shapely.get_exterior_ring(polys)
    xy, owner = shapely.get_coordinates(rings, return_index=True)
    last = np.r_[owner[1:] != owner[:-1], True]
    keep = ~last                                    # drop each ring's closing vertex
    xy, owner = xy[keep], owner[keep]
    start = np.r_[0, np.flatnonzero(owner[1:] != owner[:-1]) + 1]
    return xy, owner, start


def _constraints(owner: np.ndarray, start: np.ndarray):
    """Index pairs of wall edges and of shape (diagonal) links of every ring."""
    counts = np.diff(np.r_[start, len(owner)])
    walls, shape = [], []
    for s, c in zip(start, counts):
        idx = np.arange(s, s + c)
        walls.append(np.c_[idx, np.roll(idx, -1)])
        if c > 3:
            i, j = np.triu_indices(c, 2)
            adjacent = (i == 0) & (j == c - 1)
            shape.append(np.c_[idx[i[~adjacent]], idx[j[~adjacent]]])
    walls = np.vstack(walls) if walls else np.zeros((0, 2), np.int64)
    shape = np.vstack(shape) if shape else np.zeros((0, 2), np.int64)
    return walls, shape


def _strain(p, pairs, rest):
    """Relative length change of each distance constraint."""
    return np.abs(np.hypot(*(p[pairs[:, 1]] - p[pairs[:, 0]]).T) - rest) / np.maximum(rest, 1e-9)


def _project_distances(p, pairs, rest, inv_mass, stiffness):
    """One Jacobi pass of the distance constraints |p_i - p_j| = rest (averaged)."""
    if not len(pairs):
        return p
    d = p[pairs[:, 1]] - p[pairs[:, 0]]
    length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    wi, wj = inv_mass[pairs[:, 0]], inv_mass[pairs[:, 1]]
    wsum = np.maximum(wi + wj, 1e-12)
    corr = (stiffness * (length - rest) / length / wsum)[:, None] * d
    delta = np.zeros_like(p)
    count = np.zeros(len(p))
    np.add.at(delta, pairs[:, 0], wi[:, None] * corr)
    np.add.at(delta, pairs[:, 1], -wj[:, None] * corr)
    np.add.at(count, pairs[:, 0], wi > 0)
    np.add.at(count, pairs[:, 1], wj > 0)
    return p + delta / np.maximum(count, 1.0)[:, None]


class _Rings:
    """Vertex rings of footprints as flat particle arrays, with a padded index for
    vectorised nearest-wall queries."""

    def __init__(self, polys: np.ndarray):
        self.xy, self.owner, self.start = _rings(polys)
        self.count = np.diff(np.r_[self.start, len(self.owner)])
        m = int(self.count.max())
        j = np.arange(m + 1)
        self.pad = self.start[:, None] + np.minimum(j[None, :], self.count[:, None]) \
            % self.count[:, None]
        self.edge_ok = j[None, :m] < self.count[:, None]
        self.ring_idx = np.repeat(np.arange(len(self.start)), self.count + 1)
        self.closed = np.concatenate([np.r_[np.arange(s, s + c), s]
                                      for s, c in zip(self.start, self.count)])

    def polygons(self, p: np.ndarray) -> np.ndarray:
        return shapely.polygons(shapely.linearrings(p[self.closed], indices=self.ring_idx))

    def nearest_wall(self, p: np.ndarray, pts: np.ndarray, ring: np.ndarray):
        """For points ``pts`` (k, 2) and ring ids: the nearest point on the ring's walls,
        the wall's first and second vertex (particle ids) and the parameter t."""
        idx = self.pad[ring]                                  # (k, m + 1)
        A, B = p[idx[:, :-1]], p[idx[:, 1:]]
        d = B - A
        t = np.einsum("kmi,kmi->km", pts[:, None, :] - A, d) / \
            np.maximum(np.einsum("kmi,kmi->km", d, d), 1e-18)
        t = np.clip(t, 0.0, 1.0)
        C = A + t[..., None] * d
        dist = np.hypot(*(pts[:, None, :] - C).transpose(2, 0, 1))
        dist[~self.edge_ok[ring]] = np.inf
        k = np.argmin(dist, axis=1)
        rows = np.arange(len(ring))
        return C[rows, k], idx[rows, k], idx[rows, k + 1], t[rows, k]


def _inside(polys: np.ndarray, xy: np.ndarray):
    """(point, polygon) index pairs of the points strictly inside the polygons (bounding
    boxes from an STRtree, then a vectorised point-in-polygon test)."""
    bounds = shapely.bounds(polys)
    tree = shapely.STRtree(shapely.box(*bounds.T))
    pi, gj = tree.query(shapely.points(xy))
    if not len(pi):
        return pi, gj
    inside = shapely.contains_xy(polys[gj], xy[pi, 0], xy[pi, 1])
    return pi[inside], gj[inside]


def _collide(p, rings: "_Rings", movable, buildable, outline, outline_pts):
    """Collision projection (thesis ch. 5.1, the "collision impulse").

    (1) A movable corner outside the street offset polygon goes onto its outline and
    (2) one inside another footprint onto that footprint's outline (PUSH beyond);
    (3) a point that must stay outside a movable footprint -- a corner of another
    footprint or a point of the street offset outline (densified, so that a road crossing
    a footprint between its corners is seen) -- pushes the footprint's nearest wall out
    past it (both wall ends, by the lever rule). Returns the new positions and whether any
    constraint was violated.
    """
    p = p.copy()
    violated = False
    owner = rings.owner
    mv = np.flatnonzero(movable)
    out = mv[~shapely.contains_xy(buildable, p[mv, 0], p[mv, 1])]
    if len(out):
        violated = True
        q = _project(p[out], outline)
        step = q - p[out]
        norm = np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-12)[:, None]
        p[out] = q + PUSH * step / norm
    polys = rings.polygons(p)
    vi, fj = _inside(polys, p)
    keep = (owner[vi] != fj) & movable[vi]
    vi, fj = vi[keep], fj[keep]
    if len(vi):
        violated = True
        q, *_ = rings.nearest_wall(p, p[vi], fj)
        step = q - p[vi]
        norm = np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-12)[:, None]
        delta = np.zeros_like(p)
        hits = np.zeros(len(p))
        np.add.at(delta, vi, q + PUSH * step / norm - p[vi])
        np.add.at(hits, vi, 1.0)
        p += delta / np.maximum(hits, 1.0)[:, None]
    # points that must stay outside the movable footprints push their walls
    moving_rings = np.flatnonzero(np.bincount(owner[mv], minlength=len(rings.start)) > 0)
    if len(moving_rings):
        polys = rings.polygons(p)
        obstacles = np.vstack([outline_pts, p])
        own = np.r_[np.full(len(outline_pts), -1), owner]
        oi, fj = _inside(polys[moving_rings], obstacles)
        fj = moving_rings[fj]
        keep = own[oi] != fj
        oi, fj = oi[keep], fj[keep]
        if len(oi):
            violated = True
            c, i0, i1, t = rings.nearest_wall(p, obstacles[oi], fj)
            push = obstacles[oi] - c
            n = np.maximum(np.hypot(push[:, 0], push[:, 1]), 1e-12)[:, None]
            push = push * (1.0 + PUSH / n)
            delta = np.zeros_like(p)
            hits = np.zeros(len(p))
            np.add.at(delta, i0, (1 - t)[:, None] * push)
            np.add.at(delta, i1, t[:, None] * push)
            np.add.at(hits, i0, 1 - t)
            np.add.at(hits, i1, t)
            p += np.where(movable[:, None], delta / np.maximum(hits, 1.0)[:, None], 0.0)
    return p, violated


def relax_pbd(footprints: Sequence, conflicted: np.ndarray, buildable,
              steps: Optional[int] = None) -> Tuple[np.ndarray, int]:
    """Move conflicted footprints into ``buildable`` and off each other by position-based
    dynamics (thesis ch. 5.1, Mueller et al. 2007).

    Each footprint is a graph of corner particles and wall edges with their rest lengths
    (plus its diagonals, so that a footprint keeps its shape and does not shear). Per time
    step: explicit Verlet integration (predicted positions from the damped velocities),
    then Gauss-Seidel-style passes projecting the wall-length and shape constraints (soft,
    stiffness :data:`PBD_WALL_STIFFNESS` / :data:`PBD_SHAPE_STIFFNESS`) and the collision
    constraints (hard: a corner outside the street offset polygon or inside another
    footprint is set onto that outline, the thesis's "collision impulse"); the velocities
    are the positions' change. Footprints that are not conflicted are fixed (infinite
    mass). Stops when no constraint is violated. A footprint whose walls were strained
    by more than :data:`PBD_MAX_STRAIN`, that is invalid, or still collides goes back to
    its example pose (:func:`footprints.legalise` trims it then).

    Hand-written: no library does PBD on 2D polygons; the constraint projections are the
    paper's formulas, vectorised with numpy, the geometry tests shapely's.

    Returns
    -------
    (footprints with the conflicted ones moved, steps used)
    """
    everything = np.asarray(footprints, dtype=object).copy()
    if not np.asarray(conflicted, dtype=bool).any():
        return everything, 0
    # the particle system: the movers and the fixed footprints within reach of them
    reach = shapely.buffer(shapely.union_all(everything[np.asarray(conflicted, bool)]),
                           NEIGHBOURHOOD)
    local = np.flatnonzero(shapely.intersects(everything, reach))
    fp = everything[local]
    conflicted = np.asarray(conflicted, dtype=bool)[local]
    original = fp.copy()
    movers = np.flatnonzero(conflicted)
    rings = _Rings(fp)
    x, owner = rings.xy.copy(), rings.owner
    movable = np.asarray(conflicted, dtype=bool)[owner]
    inv_mass = movable.astype(np.float64)
    walls, shape = _constraints(owner, rings.start)
    rest_w = np.hypot(*(x[walls[:, 1]] - x[walls[:, 0]]).T)
    rest_s = np.hypot(*(x[shape[:, 1]] - x[shape[:, 0]]).T)
    outline = shapely.boundary(buildable)
    # the outline near the movers, densified: a road crossing a footprint is seen
    near = shapely.intersection(outline, shapely.buffer(shapely.union_all(fp[movers]), 5.0))
    outline_pts = shapely.get_coordinates(shapely.segmentize(near, OUTLINE_STEP)) \
        if not shapely.is_empty(near) else np.zeros((0, 2))
    shapely.prepare(buildable)
    v = np.zeros_like(x)
    step = stuck = 0
    for step in range(1, (PBD_STEPS if steps is None else steps) + 1):
        p = x + PBD_DAMPING * v                                  # Verlet prediction
        for _ in range(PBD_ITERATIONS):
            p = _project_distances(p, walls, rest_w, inv_mass, PBD_WALL_STIFFNESS)
            p = _project_distances(p, shape, rest_s, inv_mass, PBD_SHAPE_STIFFNESS)
            p, _ = _collide(p, rings, movable, buildable, outline, outline_pts)
        v = p - x
        x = p
        _, violated = _collide(x, rings, movable, buildable, outline, outline_pts)
        # the soft constraints count too: stop when the walls and the shape are restored
        strained = _strain(x, walls, rest_w).max(initial=0.0) > PBD_TOLERANCE or \
            _strain(x, shape, rest_s).max(initial=0.0) > PBD_TOLERANCE
        settled = np.abs(v).max() < STALL
        stuck = stuck + 1 if settled else 0
        if (not violated and (not strained or settled)) or stuck >= 5:
            break
    result = rings.polygons(x)
    fp[movers] = result[movers]
    # acceptance: walls within the strain, valid, inside, free of the others
    strain = _strain(x, walls, rest_w)
    worst = np.zeros(len(fp))
    np.maximum.at(worst, owner[walls[:, 0]], strain)
    for i in movers:      # strained, crumpled or still outside: back to the example pose
        if not (worst[i] <= PBD_MAX_STRAIN and shapely.is_valid(fp[i])
                and abs(shapely.area(fp[i]) / shapely.area(original[i]) - 1) <= PBD_MAX_STRAIN
                and shapely.within(fp[i], buildable)):
            fp[i] = original[i]
    tree = shapely.STRtree(fp)
    for i in movers:      # still colliding with a footprint: back as well
        hits = tree.query(fp[i], predicate="intersects")
        hits = hits[(hits != i) & shapely.is_valid(fp[hits])]
        if hits.size and _overlap(fp[hits], fp[i]).any():
            fp[i] = original[i]
    everything[local] = fp
    return everything, step
