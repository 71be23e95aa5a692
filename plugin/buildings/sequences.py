"""Resource-constrained k-shortest paths (RCKSP): the best sequences of elements.

Hartmann's thesis, ch. 3 (after Hartmann et al., "Efficient multi-constrained optimization
for example-based synthesis", The Visual Computer 31, 2015) synthesises content that is a
*sequence* of database elements -- building parts along a skeleton, facade elements along
a street frontage -- under constraints on the resources the sequence consumes (length,
floor area, counts). Each element ``e`` has a non-negative resource vector ``r(e)``;
consecutive elements pay a transition cost ``delta(e_i, e_j)`` (``inf`` forbids the pair).
A sequence ``X`` is feasible when ``lo_i <= sum_k r_i(X_k) <= hi_i`` for every constrained
resource ``i`` (``lo == hi``: an equality constraint); the j-th best solution minimises the
summed transition costs over the feasible sequences not yet returned (thesis eq. 3.1, 3.2).

The constrained problem becomes an unconstrained one on the **feasible intermediate
graph** (thesis sec. 3.3.1): a DAG whose nodes are the signatures ``(e, rc)`` -- element
``e`` placed after ``rc - r(e)`` was consumed, ``rc`` the consumption including ``e`` --
and whose source-to-sink paths are exactly the feasible sequences.

- **Construction by resource consumption, not by cost.** Resources are quantised to a
  grid (``resolution``: 0.2 m lengths, 1 m² floor areas in the thesis) and become integers;
  the first resource is the *primary* one (length, height): every element consumes at
  least one grid step of it and it must be bounded above, so its consumption orders the
  graph in levels.
- **Kept implicit** (:class:`ImplicitGraph`, ``method="graph"``, the default): the node
  set per primary level (the secondary consumptions present, as integer codes, and per
  code and element the cost of the cheapest prefix); no edge is stored -- the in-edges of
  ``(e, rc)`` are the nodes ``(e', rc - r(e))`` of its allowed predecessors, derived on
  demand. The nodes are grown level by level with one vectorised min-plus product of a
  level's cost table with the transitions (with one resource, ``min r_0`` levels at once).
  ``method="explicit"`` materialises every edge (:func:`build_graph`), the former
  engine, kept as a reference: same graph, same answers, 20-40 bytes per edge.
- **Pruning.** (a) overflow / underflow: a node is never created when it exceeds an
  upper bound or can no longer be completed -- the *backward growth* from the sink gives,
  per secondary resource, the set of (level, consumption) pairs from which the bounds are
  still reachable by elements allowed where they would start (the thesis's backward
  tree with the elements merged, a relaxation, so exact pruning); (b) dead ends: the k
  best paths are enumerated backwards from the sink, so nodes on no source-sink path are
  never visited. Infeasible problems (a 50 m street from 20 m buildings) are detected
  when nothing reaches the sink.
- **Several resources, equality and interval constraints**: nodes carry the vector of
  every constrained resource; unconstrained resources are only summed for the report.
- **Key points** (thesis sec. 3.3.4, "structure"): a :class:`KeyPoint` forces one of a set
  of elements to sit at a primary position -- a corner part at a skeleton vertex, end
  parts at the ends. An element sits at ``start + anchor`` (``anchor``: a corner's vertex
  lies inside it, a left end's at its start, a right end's at its end) and *no other
  element may touch the key point* (its closed extent may not contain it), so an element
  anchored at its start can only begin the sequence and one anchored at its end only end
  it. ``key_only`` elements (corners) appear nowhere but at key points that list them.
  ``start_mask`` confines elements to given start levels: the substructure copies of a
  1.5D structure (:mod:`structures`: T-junctions, virtual duplicates, local constraints).
- **Data terms**: ``position_cost[e, l]`` is added when ``e`` starts at grid level ``l``
  (the overlap data term of the footprint re-synthesis, thesis eq. 5.1), ``start_cost``
  and ``end_cost`` on the first and last element (a closed loop's closing transition).
- **Best and k best** (:meth:`ImplicitGraph.k_best`, :func:`k_best`): the graph is a DAG
  in consumption order, so the shortest-path labels (Dijkstra's in the thesis) are set
  level by level; the k best paths come from the Recursive Enumeration Algorithm of
  Jimenez and Marzal (1999), an exact k-shortest-paths algorithm equivalent in its output
  to Eppstein's (1998), run lazily from the sink: the j-th solution is optimal among the
  sequences not in the first j-1. Every sequence is one path (its nodes are determined
  by the sequence), so the k solutions are distinct sequences, in non-decreasing cost.

Complexity for one resource: at most ``n`` nodes per level, ``d`` successors each, ``L``
levels: O(L d n) time (thesis sec. 3.4), O(L n) memory (no edges). Not implemented:
dominance between nodes of different secondary consumption (it does not hold under
equality constraints, whose completions differ).

Worked example -- a 10 m frontage from a 3 m house (``0``), a 4 m house (``1``) and 1 m
of empty space (``2``); a house may not follow itself (repetition cost), the whole row must
be exactly 10 m long and hold at least two houses (resource 1 counts houses):

>>> import numpy as np
>>> inf = np.inf
>>> resources = [[3, 1], [4, 1], [1, 0]]          # length (m), houses
>>> transition = [[inf, 0.0, 0.2],                 # 3 m house -> 4 m house / gap
...               [0.0, inf, 0.2],
...               [0.1, 0.1, 0.5]]                 # gap -> house; gap -> gap
>>> best = solve(resources, transition, [Constraint.equal(0, 10), Constraint(1, lo=2)], k=3)
>>> [(s.cost, s.sequence) for s in best]
[(0.0, (0, 1, 0)), (0.4, (2, 1, 2, 1)), (0.5, (1, 2, 1, 2))]
>>> best[0].starts, best[0].totals.tolist()
((0.0, 3.0, 7.0), [10.0, 3.0])

References
----------
Hartmann, S. Example-based generation of virtual urban environments, thesis, ch. 3
(RCKSP via the intermediate graph), ch. 5.2 (frontage sequences), ch. 6 (building parts).
Hartmann, S., Trinchera, B., Klein, R. et al. Efficient multi-constrained optimization for
example-based synthesis. The Visual Computer 31(6-8), 2015.
Jimenez, V. M., Marzal, A. Computing the K shortest paths: a new algorithm and an
experimental comparison. WAE 1999, LNCS 1668.
Eppstein, D. Finding the k shortest paths. SIAM J. Computing 28(2), 1998.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import breadth_first_order

from ..core.progress import InputError, Progress, ensure

__all__ = ["Constraint", "KeyPoint", "Solution", "IntermediateGraph", "InfeasibleError",
           "build_graph", "k_best", "solve"]

#: Default cap on the number of graph states (memory guard, about 100 bytes per state).
MAX_STATES = 5_000_000


class InfeasibleError(InputError):
    """No sequence of the database satisfies the constraints."""


#: Candidate transitions expanded per slice of the forward sweep (a cancel is seen between
#: slices: about 0.1 s each).
_CHUNK = 1_000_000


def _unique(keys: np.ndarray, between=None):
    """``np.unique(keys, return_index=True, return_inverse=True)``, in slices of
    :data:`_CHUNK` keys with ``between()`` called between them (the cancel check of a large
    sweep). The same result: the first occurrence of each key is the first in slice order.

    >>> k = np.array([5, 3, 5, 9, 3, 1])
    >>> [a.tolist() for a in _unique(k)] == [a.tolist() for a in np.unique(
    ...     k, return_index=True, return_inverse=True)]
    True
    """
    between = between or (lambda: None)
    if len(keys) <= 4 * _CHUNK:
        return np.unique(keys, return_index=True, return_inverse=True)
    starts = range(0, len(keys), _CHUNK)
    parts = []
    for a in starts:
        between()
        u, first = np.unique(keys[a:a + _CHUNK], return_index=True)
        parts.append((u, first + a))
    between()
    u = np.concatenate([p[0] for p in parts])
    first = np.concatenate([p[1] for p in parts])
    order = np.argsort(u, kind="stable")        # equal keys stay in slice (index) order
    between()
    u, first = u[order], first[order]
    head = np.r_[True, u[1:] != u[:-1]]
    uk, first_idx = u[head], first[head]
    inv = np.empty(len(keys), dtype=np.int64)
    for a in starts:
        between()
        inv[a:a + _CHUNK] = np.searchsorted(uk, keys[a:a + _CHUNK])
    return uk, first_idx, inv

@dataclass(frozen=True)
class Constraint:
    """``lo <= sum of resource over the sequence <= hi`` (real units); ``lo == hi``: equality."""

    resource: int
    lo: float = 0.0
    hi: float = math.inf

    @classmethod
    def equal(cls, resource: int, value: float) -> "Constraint":
        return cls(resource, float(value), float(value))


@dataclass(frozen=True)
class KeyPoint:
    """One of ``elements`` must sit at primary ``position`` (real units); see the module doc."""

    position: float
    elements: Tuple[int, ...]


@dataclass(frozen=True)
class Solution:
    """One feasible sequence: its rank (1 = best), cost, elements, start positions (primary,
    real units) and resource totals (all resources, real units of the quantised values)."""

    rank: int
    cost: float
    sequence: Tuple[int, ...]
    starts: Tuple[float, ...]
    totals: np.ndarray = field(repr=False)


@dataclass
class IntermediateGraph:
    """The pruned feasible intermediate graph.

    Node 0 is the source, nodes ``1..n_states`` are the states in consumption order (every
    edge goes from a lower to a higher id), node ``n_states + 1`` the sink.
    ``element[v]`` / ``consumed[v]`` (quantised units of the constrained resources, primary
    first) describe state ``v`` (-1 / 0 for source and sink). Edges carry their full cost
    (transition + position data term, start and end costs on source and sink edges).
    """

    element: np.ndarray
    consumed: np.ndarray
    edge_src: np.ndarray
    edge_dst: np.ndarray
    edge_cost: np.ndarray
    constrained: Tuple[int, ...]
    n_forward_states: int
    units: np.ndarray = field(repr=False)
    resources: np.ndarray = field(repr=False)
    resolution: np.ndarray = field(repr=False)

    @property
    def n_states(self) -> int:
        return len(self.element) - 2

    @property
    def n_edges(self) -> int:
        return len(self.edge_src)

    @property
    def sink(self) -> int:
        return len(self.element) - 1


# --------------------------------------------------------------------------- set-up


def _as_mask(values, n: int, name: str) -> np.ndarray:
    """Element subset given as indices or as a boolean mask -> boolean mask of length n."""
    if values is None:
        return np.ones(n, dtype=bool)
    arr = np.asarray(values)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise InputError(f"{name} must be a boolean mask of length {n}")
        return arr.copy()
    idx = arr.astype(np.int64).ravel()
    if len(idx) and (idx.min() < 0 or idx.max() >= n):
        raise InputError(f"{name} lists an element index outside 0..{n - 1}")
    mask = np.zeros(n, dtype=bool)
    mask[idx] = True
    return mask


def _cost_vector(values, n: int, name: str) -> np.ndarray:
    if values is None:
        return np.zeros(n)
    v = np.broadcast_to(np.asarray(values, dtype=np.float64), (n,)).copy()
    if np.isnan(v).any() or (v < 0).any():
        raise InputError(f"{name} must be non-negative (inf forbids)")
    return v


def _bounds(constraints: Sequence[Constraint], m: int, res: np.ndarray):
    """Intersect constraints per resource; return {resource: (lo_units, hi_units)}."""
    lo = np.zeros(m)
    hi = np.full(m, np.inf)
    constrained = set()
    for c in constraints:
        r = int(c.resource)
        if not 0 <= r < m:
            raise InputError(f"constraint on resource {r}, but elements have {m} resources")
        if math.isnan(c.lo) or math.isnan(c.hi) or c.lo < 0 or c.hi < c.lo:
            raise InputError(f"constraint on resource {r} needs 0 <= lo <= hi "
                             f"(got {c.lo}, {c.hi})")
        lo[r] = max(lo[r], c.lo)
        hi[r] = min(hi[r], c.hi)
        constrained.add(r)
    if 0 not in constrained or not np.isfinite(hi[0]):
        raise InputError("the primary resource (0: length, height) needs an upper bound")
    lo_u = np.ceil(lo / res - 1e-9)
    hi_u = np.floor(hi / res + 1e-9)
    for r in sorted(constrained):
        if lo_u[r] > hi_u[r]:
            raise InfeasibleError(
                f"resource {r}: no multiple of the resolution {res[r]:g} lies in "
                f"[{lo[r]:g}, {hi[r]:g}]")
    order = [0] + sorted(constrained - {0})
    return order, lo_u, hi_u


def _start_mask(n, H0, U0, anchor, key_points, res0, first, key_only, position_cost,
                start_mask):
    """allowed[e, l]: may element e start at primary level l? (key points, first, data term,
    the caller's mask). Also returns the largest key point position (the sequence must
    reach it)."""
    allowed = np.ones((n, H0 + 1), dtype=bool)
    if start_mask is not None:
        allowed &= start_mask
    if position_cost is not None:
        allowed &= np.isfinite(position_cost)
    allowed[~first, 0] = False
    levels = np.arange(H0 + 1)
    satisfying_any = np.zeros((n, H0 + 1), dtype=bool)
    key_positions = [0]
    for kp in key_points:
        p = int(round(kp.position / res0))
        if abs(p * res0 - kp.position) > 1e-6 * max(1.0, abs(kp.position)) + 1e-9:
            raise InputError(f"key point {kp.position:g} is not on the resolution grid "
                             f"({res0:g}); round it first")
        if p < 0 or p > H0:
            raise InfeasibleError(f"key point {kp.position:g} lies outside the length bound")
        members = _as_mask(kp.elements, n, "key point elements")
        # only the start levels from which an element's closed extent reaches p
        lo = max(p - int(U0.max()), 0)
        lv = levels[lo:p + 1]
        touches = lv[None, :] + U0[:, None] >= p
        satisfying = members[:, None] & (lv[None, :] + anchor[:, None] == p)
        allowed[:, lo:p + 1] &= ~touches | satisfying
        satisfying_any[:, lo:p + 1] |= satisfying
        key_positions.append(p)
    if key_only.any():
        allowed[key_only] &= satisfying_any[key_only]
    return allowed, max(key_positions)


class _Grow:
    """Append-only arrays with amortised doubling (the forward sweep's node store)."""

    def __init__(self, width: int):
        self.e = np.empty(1024, dtype=np.int64)
        self.c = np.empty((1024, width), dtype=np.int64)
        self.n = 0

    def extend(self, e: np.ndarray, c: np.ndarray) -> None:
        need = self.n + len(e)
        if need > len(self.e):
            size = max(need, 2 * len(self.e))
            self.e = np.resize(self.e, size)
            grown = np.empty((size, self.c.shape[1]), dtype=np.int64)
            grown[:self.n] = self.c[:self.n]
            self.c = grown
        self.e[self.n:need] = e
        self.c[self.n:need] = c
        self.n = need


# --------------------------------------------------------------------------- graph


def _prepare(resources, transition, constraints: Sequence[Constraint], *,
             resolution=None, key_points: Sequence[KeyPoint] = (), first=None, last=None,
             key_only=None, anchor=None,
             position_cost: Union[None, np.ndarray, Callable[[np.ndarray], np.ndarray]] = None,
             start_cost=None, end_cost=None, start_mask=None, max_states: int = MAX_STATES,
             progress: Optional[Progress] = None) -> dict:
    """Validate and quantise the input; the start mask (see :func:`build_graph`)."""
    progress = ensure(progress)
    R = np.asarray(resources, dtype=np.float64)
    if R.ndim == 1:
        R = R[:, None]
    if R.ndim != 2 or R.shape[0] == 0 or R.shape[1] == 0:
        raise InputError("resources must be a non-empty (elements x resources) array")
    if not np.isfinite(R).all() or (R < 0).any():
        raise InputError("resources must be finite and non-negative")
    n, m = R.shape
    res = np.broadcast_to(np.asarray(1.0 if resolution is None else resolution,
                                     dtype=np.float64), (m,)).copy()
    if not (np.isfinite(res).all() and (res > 0).all()):
        raise InputError("resolution must be positive")
    U = np.rint(R / res).astype(np.int64)
    T = np.asarray(transition, dtype=np.float64)
    if T.shape != (n, n):
        raise InputError(f"transition must be an ({n}, {n}) matrix, got {T.shape}")
    if np.isnan(T).any() or (T < 0).any():
        raise InputError("transition costs must be non-negative (inf forbids a pair)")
    if (U[:, 0] < 1).any():
        bad = int(np.flatnonzero(U[:, 0] < 1)[0])
        raise InputError(f"element {bad} uses less than one grid step ({res[0]:g}) of the "
                         "primary resource; every element must advance along the structure")
    order, lo_u, hi_u = _bounds(constraints, m, res)
    H0 = int(hi_u[0])
    if H0 * n > 50_000_000:
        raise InputError(f"the primary bound is {H0} grid steps for {n} elements; "
                         "coarsen the resolution")
    U0 = U[:, 0]
    UC = U[:, order]
    lo_c = lo_u[order].astype(np.int64)
    # effective upper bounds: an unbounded resource is still bounded by the primary budget
    rate = UC / U0[:, None]
    hi_c = np.array([H0] + [int(min(hi_u[j], math.floor(H0 * rate[:, i].max() + 1e-9)))
                            for i, j in enumerate(order) if i > 0], dtype=np.int64)
    if (lo_c > hi_c).any():
        raise InfeasibleError("a lower bound cannot be reached within the primary bound")
    max_rate, min_rate = rate.max(axis=0), rate.min(axis=0)

    first_m = _as_mask(first, n, "first")
    last_m = _as_mask(last, n, "last")
    key_only_m = (np.zeros(n, dtype=bool) if key_only is None
                  else _as_mask(key_only, n, "key_only"))
    anchor_u = (np.zeros(n, dtype=np.int64) if anchor is None else
                np.rint(np.broadcast_to(np.asarray(anchor, dtype=np.float64), (n,))
                        / res[0]).astype(np.int64))
    PC = None
    if position_cost is not None:
        PC = (position_cost(np.arange(H0 + 1) * res[0]) if callable(position_cost)
              else position_cost)
        PC = np.asarray(PC, dtype=np.float64)
        if PC.ndim != 2 or PC.shape[0] != n or PC.shape[1] < H0 + 1:
            raise InputError(f"position_cost must be ({n}, >= {H0 + 1}), got {PC.shape}")
        PC = PC[:, :H0 + 1]
        if np.isnan(PC).any() or (PC < 0).any():
            raise InputError("position costs must be non-negative (inf forbids)")
    s_cost = _cost_vector(start_cost, n, "start_cost")
    e_cost = _cost_vector(end_cost, n, "end_cost")
    first_m &= np.isfinite(s_cost)
    last_m &= np.isfinite(e_cost)
    if start_mask is not None:
        start_mask = np.asarray(start_mask, dtype=bool)
        if start_mask.ndim != 2 or start_mask.shape[0] != n or start_mask.shape[1] < H0 + 1:
            raise InputError(f"start_mask must be ({n}, >= {H0 + 1}), got {start_mask.shape}")
        start_mask = start_mask[:, :H0 + 1]
    allowed, last_key = _start_mask(n, H0, U0, anchor_u, key_points, res[0], first_m,
                                    key_only_m, PC, start_mask)
    return dict(n=n, H0=H0, U=U, U0=U0, UC=UC, lo_c=lo_c, hi_c=hi_c, max_rate=max_rate,
                min_rate=min_rate, allowed=allowed, last_key=last_key, T=T, order=order,
                last_m=last_m, PC=PC, s_cost=s_cost, e_cost=e_cost, R=R, res=res,
                max_states=max_states, progress=progress)


def build_graph(resources, transition, constraints: Sequence[Constraint], *,
                resolution=None, key_points: Sequence[KeyPoint] = (), first=None, last=None,
                key_only=None, anchor=None,
                position_cost: Union[None, np.ndarray, Callable[[np.ndarray], np.ndarray]] = None,
                start_cost=None, end_cost=None, start_mask=None, max_states: int = MAX_STATES,
                progress: Optional[Progress] = None) -> IntermediateGraph:
    """Build the pruned feasible intermediate graph (thesis sec. 3.3.1-3.3.4).

    Parameters
    ----------
    resources : (n, m) array_like
        Non-negative resource vector per element (real units). Column 0 is the primary
        resource (length along the structure, height): every element must use at least
        one ``resolution[0]`` step of it.
    transition : (n, n) array_like
        ``delta(e_i, e_j) >= 0`` for ``e_j`` directly after ``e_i``; ``inf`` forbids it.
    constraints : sequence of :class:`Constraint`
        Bounds on resource totals; the primary resource needs a finite upper bound.
    resolution : float or (m,) array_like, optional
        Grid step per resource (default 1); resources are rounded to it and constraint
        bounds moved inwards onto it (the thesis quantises lengths to 0.2 m, areas to 1 m²).
    key_points : sequence of :class:`KeyPoint`
        Primary positions (real units, on the grid) where one of a set of elements must sit.
    first, last : index list or (n,) bool mask, optional
        Elements allowed at the front / back of the sequence (default: all).
    key_only : index list or (n,) bool mask, optional
        Elements that may appear only where a key point asks for them (corner parts).
    anchor : (n,) array_like, optional
        Where an element "sits" for key points, as primary offset from its start
        (default 0; a corner's vertex, a right end's length).
    position_cost : (n, >= H+1) array or callable, optional
        Data term ``cost[e, l]`` for element ``e`` starting at grid level ``l``
        (``H`` = upper bound of the primary in grid steps; ``inf`` forbids). A callable gets
        the real start positions ``l * resolution[0]`` and returns the (n, H+1) array.
    start_cost, end_cost : (n,) array_like, optional
        Extra cost of an element at the front / back (``inf`` forbids).
    start_mask : (n, >= H+1) bool array, optional
        Where each element may start (grid levels): the substructure copies of a 1.5D
        structure (:func:`parts.build_along_network`) are confined to their stretch so.
    max_states : int
        Raise :class:`InputError` rather than build a larger graph.

    Returns
    -------
    IntermediateGraph

    Raises
    ------
    InputError
        Malformed input (negative resources, missing primary bound, key point off grid).
    InfeasibleError
        No feasible sequence exists (the sink is unreachable).
    """
    p = _prepare(resources, transition, constraints, resolution=resolution,
                 key_points=key_points, first=first, last=last, key_only=key_only,
                 anchor=anchor, position_cost=position_cost, start_cost=start_cost,
                 end_cost=end_cost, start_mask=start_mask, max_states=max_states,
                 progress=progress)
    return _graph(**p)


def _graph(n, H0, U, U0, UC, lo_c, hi_c, max_rate, min_rate, allowed, last_key, T, order,
           last_m, PC, s_cost, e_cost, R, res, max_states, progress) -> IntermediateGraph:
    """Forward sweep, dead-end pruning, edge costs (the body of :func:`build_graph`)."""

    # state key = element + n * mixed-radix code of the consumption vector
    radix = hi_c + 1
    if n * float(np.prod(radix.astype(np.float64))) >= 2.0 ** 62:
        raise InputError("too many resource combinations to index; coarsen the resolution "
                         "of the secondary resources")
    stride = np.concatenate([[1], np.cumprod(radix[:-1])]).astype(np.int64)

    def feasible(c: np.ndarray) -> np.ndarray:
        ok = (c <= hi_c).all(axis=1)
        rest = (H0 - c[:, 0])[:, None]                     # primary budget left
        need = np.maximum(lo_c[0] - c[:, 0], 0)[:, None]   # primary still required
        ok &= (c[:, 1:] + rest * max_rate[None, 1:] >= lo_c[None, 1:] - 1e-9).all(axis=1)
        ok &= (c[:, 1:] + need * min_rate[None, 1:] <= hi_c[None, 1:] + 1e-9).all(axis=1)
        return ok

    succ = sparse.csr_matrix(np.isfinite(T))
    indptr, indices = succ.indptr.astype(np.int64), succ.indices.astype(np.int64)
    outdeg = np.diff(indptr)

    store = _Grow(len(order))
    keys_sorted = np.empty(0, dtype=np.int64)
    ids_sorted = np.empty(0, dtype=np.int64)

    def intern(e: np.ndarray, c: np.ndarray):
        nonlocal keys_sorted, ids_sorted
        keys = e + n * (c @ stride)
        uk, first_idx, inv = _unique(keys, lambda: progress.step(done))
        pos = np.searchsorted(keys_sorted, uk)
        found = pos < len(keys_sorted)
        found[found] = keys_sorted[pos[found]] == uk[found]
        ids = np.empty(len(uk), dtype=np.int64)
        ids[found] = ids_sorted[pos[found]]
        new = ~found
        new_ids = store.n + np.arange(int(new.sum()))
        ids[new] = new_ids
        store.extend(e[first_idx[new]], c[first_idx[new]])
        keys_sorted = np.insert(keys_sorted, pos[new], uk[new])
        ids_sorted = np.insert(ids_sorted, pos[new], new_ids)
        if store.n > max_states:
            raise InputError(f"the intermediate graph exceeds {max_states} states; coarsen "
                             "the resolution or tighten the constraints")
        return ids[inv], new_ids

    done = 0.0     # progress so far (the smallest level on the frontier)
    # initialisation: elements allowed at the front start at level 0
    e0 = np.flatnonzero(allowed[:, 0])
    c0 = UC[e0]
    ok = feasible(c0)
    init_nodes, frontier = intern(e0[ok], c0[ok])
    src_parts: List[np.ndarray] = []
    dst_parts: List[np.ndarray] = []
    while len(frontier):
        fe = store.e[frontier]
        deg = outdeg[fe]
        total = int(deg.sum())
        if total == 0:
            break
        # the frontier's successors, expanded and tested in slices of about _CHUNK
        # candidates in frontier order (the same candidates in the same order as at once),
        # so that a cancel is seen between slices of a large sweep
        cut = np.searchsorted(np.cumsum(deg), np.arange(_CHUNK, total, _CHUNK), "right")
        kept = []
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(frontier)]):
            progress.step(done)
            f, d = frontier[a:b], deg[a:b]
            src = np.repeat(f, d)
            offset = np.arange(len(src)) - np.repeat(np.cumsum(d) - d, d)
            dst_e = indices[np.repeat(indptr[store.e[f]], d) + offset]
            # cheap one-dimensional tests first (key points, data term, primary overflow)
            lvl = store.c[src, 0]
            ok = allowed[dst_e, lvl] & (lvl + U0[dst_e] <= H0)
            src, dst_e = src[ok], dst_e[ok]
            c_new = store.c[src] + UC[dst_e]
            if len(order) > 1:
                ok = feasible(c_new)
                src, dst_e, c_new = src[ok], dst_e[ok], c_new[ok]
            kept.append((src, dst_e, c_new))
        progress.step(done)
        src = np.concatenate([k[0] for k in kept])
        dst_e = np.concatenate([k[1] for k in kept])
        progress.step(done)
        c_new = np.concatenate([k[2] for k in kept])
        if not len(src):
            break
        progress.step(done)
        dst, frontier = intern(dst_e, c_new)
        src_parts.append(src)
        dst_parts.append(dst)
        if len(frontier):
            done = 0.9 * store.c[frontier, 0].min() / max(H0, 1)
            progress.step(done)
    N = store.n
    node_e, node_c = store.e[:N], store.c[:N]
    esrc = np.concatenate(src_parts) if src_parts else np.empty(0, dtype=np.int64)
    edst = np.concatenate(dst_parts) if dst_parts else np.empty(0, dtype=np.int64)

    terminal = (last_m[node_e] & (node_c >= lo_c).all(axis=1) & (node_c <= hi_c).all(axis=1)
                & (node_c[:, 0] >= last_key))
    if not terminal.any():
        raise InfeasibleError(_infeasible_message(U0, res[0], lo_c[0], H0))
    # dead-end pruning: backward breadth-first search from the sink on the reversed graph
    sink = N
    term = np.flatnonzero(terminal)
    rows = np.concatenate([edst, np.full(len(term), sink)])
    cols = np.concatenate([esrc, term])
    rev = sparse.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)),
                            shape=(N + 1, N + 1))
    alive = np.zeros(N + 1, dtype=bool)
    alive[breadth_first_order(rev, sink, directed=True, return_predecessors=False)] = True
    alive_init = np.unique(init_nodes[alive[init_nodes]])
    if not len(alive_init):
        raise InfeasibleError(_infeasible_message(U0, res[0], lo_c[0], H0))
    keep = np.flatnonzero(alive[:N])
    # renumber in consumption order: source 0, states 1.., sink last (a topological order)
    keep = keep[np.argsort(node_c[keep, 0], kind="stable")]
    new_id = np.full(N, -1, dtype=np.int64)
    new_id[keep] = np.arange(1, len(keep) + 1)
    sink_id = len(keep) + 1
    k_edge = alive[esrc] & alive[edst]
    es, ed = esrc[k_edge], edst[k_edge]
    e_s, e_d = node_e[es], node_e[ed]
    w = T[e_s, e_d]
    start_lvl_d = node_c[ed, 0] - U0[e_d]
    if PC is not None:
        w = w + PC[e_d, start_lvl_d]
    wi = s_cost[node_e[alive_init]] + (PC[node_e[alive_init], 0] if PC is not None else 0.0)
    term_alive = term[alive[term]]
    wt = e_cost[node_e[term_alive]]
    edge_src = np.concatenate([np.zeros(len(alive_init), dtype=np.int64), new_id[es],
                               new_id[term_alive]])
    edge_dst = np.concatenate([new_id[alive_init], new_id[ed],
                               np.full(len(term_alive), sink_id, dtype=np.int64)])
    edge_cost = np.concatenate([np.broadcast_to(wi, (len(alive_init),)), w, wt])
    by_dst = np.argsort(edge_dst, kind="stable")
    edge_src, edge_dst, edge_cost = edge_src[by_dst], edge_dst[by_dst], edge_cost[by_dst]
    element = np.concatenate([[-1], node_e[keep], [-1]])
    consumed = np.concatenate([np.zeros((1, len(order)), dtype=np.int64), node_c[keep],
                               np.zeros((1, len(order)), dtype=np.int64)])
    progress.step(1.0)
    return IntermediateGraph(element=element, consumed=consumed, edge_src=edge_src,
                             edge_dst=edge_dst, edge_cost=edge_cost.astype(np.float64),
                             constrained=tuple(order), n_forward_states=N, units=U,
                             resources=R, resolution=res)


def _infeasible_message(U0, res0, lo0, H0) -> str:
    lengths = sorted({round(float(u * res0), 6) for u in U0})
    shown = ", ".join(f"{v:g}" for v in lengths[:8]) + (" ..." if len(lengths) > 8 else "")
    span = (f"{lo0 * res0:g}" if lo0 == H0 else f"{lo0 * res0:g}..{H0 * res0:g}")
    return (f"no sequence of the elements (primary sizes {shown}) satisfies the constraints "
            f"(primary total {span}, with the other bounds, key points and allowed "
            "transitions)")


# --------------------------------------------------------------------------- paths


def _shortest(g: IntermediateGraph):
    """Single-source shortest distances on the DAG (ids are a topological order).

    Edges are stored sorted by destination, whose ids follow the primary level, so all
    edges into one level form one contiguous block whose sources lie on lower levels and
    are final: each level is one vectorised relaxation (minimum per destination).
    """
    V = len(g.element)
    dist = np.full(V, np.inf)
    dist[0] = 0.0
    best = np.full(V, -1, dtype=np.int64)
    dst = g.edge_dst
    if not len(dst):
        return dist, best
    level = g.consumed[:, 0].copy()
    level[-1] = level.max() + 1
    dlev = level[dst]
    chunk_at = np.r_[0, np.flatnonzero(np.diff(dlev)) + 1, len(dst)]
    group_at = np.r_[0, np.flatnonzero(np.diff(dst)) + 1]
    for a, b in zip(chunk_at[:-1], chunk_at[1:]):
        cand = dist[g.edge_src[a:b]] + g.edge_cost[a:b]
        gs = group_at[np.searchsorted(group_at, a):np.searchsorted(group_at, b)] - a
        mins = np.minimum.reduceat(cand, gs)
        hit = np.flatnonzero(cand <= np.repeat(mins, np.diff(np.r_[gs, b - a])))
        d = dst[a + hit]
        first = hit[np.r_[True, d[1:] != d[:-1]]]
        dist[dst[a + first]] = cand[first]
        best[dst[a + first]] = a + first
    return dist, best


def k_best(g: IntermediateGraph, k: int = 1) -> List[Tuple[float, List[int]]]:
    """The k cheapest source-sink paths as (cost, [state ids]) in non-decreasing cost.

    k = 1 reads the shortest-path tree; k > 1 runs the Recursive Enumeration Algorithm
    (Jimenez & Marzal 1999) lazily from the sink: the j-th path into a node is the best
    candidate among the first paths of its predecessors and the successors of the paths
    already used, so only the paths needed for the k answers are ever computed.
    """
    if k < 1:
        raise InputError("k must be at least 1")
    dist, best = _shortest(g)
    sink = g.sink
    if not np.isfinite(dist[sink]):
        return []
    src, cost = g.edge_src, g.edge_cost
    if k == 1:
        path, v = [], sink
        while v != 0:
            e = best[v]
            v = int(src[e])
            if v:
                path.append(v)
        return [(float(dist[sink]), path[::-1])]
    # incoming edges per node: edges are sorted by destination
    in_ptr = np.searchsorted(g.edge_dst, np.arange(len(g.element) + 1))

    def in_edges(v: int) -> List[tuple]:
        es = np.arange(in_ptr[v], in_ptr[v + 1])
        c = dist[src[es]] + cost[es]
        return [(float(c[i]), int(src[es[i]]), float(cost[es[i]]))
                for i in np.flatnonzero(np.isfinite(c))]

    return _enumerate(in_edges, k, source=0, sink=sink)


# --------------------------------------------------------------------------- implicit graph

#: Node keys of the implicit graph: (primary level p including the element, secondary
#: consumption code, element); the source and the sink.
SOURCE = (-1, -1, -1)
SINK = (-2, -2, -2)
#: Largest temporary (entries) of one min-plus product of a level's cost table.
_CHUNK = 1 << 21
#: Largest backward completion sets (levels x secondary values, booleans) kept.
_BACKWARD_CELLS = 1 << 28


class ImplicitGraph:
    """The pruned feasible intermediate graph of thesis sec. 3.3.1, kept implicit.

    A node of the thesis's graph is the signature ``N(e, l, rc)``: element ``e`` with the
    resource vector ``rc`` consumed up to and including it. Its in-edges need no storage:
    they come from the nodes ``(e', rc - r(e))`` of every allowed predecessor ``e'``, at a
    cost of ``delta(e', e)`` (+ the position data term of ``e``). So only the node set is
    kept, grouped by primary level ``p = rc_0`` (every element advances the primary, which
    orders the DAG): per level, the sorted integer codes of the secondary consumptions
    present and, per code and element, the cost of the cheapest prefix reaching that node
    (Dijkstra's distance label; ``inf``: no such node). With no secondary resource the
    table is one dense ``(levels x elements)`` array. Memory: 8 bytes per (code, element)
    cell of a level; no edge is ever stored (the thesis's 1000 m street: 25.5 M edges).

    The k best paths are then enumerated lazily from the sink
    (:meth:`k_best`, the recursive enumeration algorithm), which only ever visits nodes
    that lie on a source-sink path: the thesis's dead-end pruning is implicit.
    """

    def __init__(self, p: dict):
        self.p = p
        n, H0 = p["n"], p["H0"]
        UC = p["UC"]
        self.n, self.H0 = n, H0
        self.U0 = p["U0"]
        self.secondary = UC[:, 1:]
        self.lo_s, self.hi_s = p["lo_c"][1:], p["hi_c"][1:]
        radix = self.hi_s + 1
        if n * float(np.prod(radix.astype(np.float64))) >= 2.0 ** 62:
            raise InputError("too many resource combinations to index; coarsen the resolution "
                             "of the secondary resources")
        self.stride = np.concatenate([[1], np.cumprod(radix[:-1])]).astype(np.int64) \
            if len(radix) else np.zeros(0, dtype=np.int64)
        self.radix = radix
        self.code_e = self.secondary @ self.stride if len(radix) else np.zeros(n, np.int64)
        T = p["T"]
        self.T = T
        PC = p["PC"]
        self.PCt = None if PC is None else np.ascontiguousarray(PC.T)
        levels = np.arange(H0 + 1)
        # ok[l, e]: e may start at level l and end within the primary bound
        self.ok = np.ascontiguousarray(
            (p["allowed"] & (levels[None, :] + self.U0[:, None] <= H0)).T)
        self.n_states = 0
        self.dense = len(radix) == 0
        if self.dense:
            self._build_dense()
        else:
            self._build_sparse()

    # -- construction ---------------------------------------------------------------

    def _source_states(self):
        """Elements allowed at the front: (element, cost) at their own end level."""
        p = self.p
        e0 = np.flatnonzero(self.ok[0])
        c0 = p["s_cost"][e0] + (self.PCt[0, e0] if self.PCt is not None else 0.0)
        if not self.dense:
            ok = self._feasible(self.secondary[e0][None], (self.U0[e0])[None])[0]
            e0, c0 = e0[ok], c0[ok]
        return e0, c0

    def _guard(self, added: int) -> None:
        self.n_states += added
        if self.n_states > self.p["max_states"]:
            raise InputError(f"the intermediate graph exceeds {self.p['max_states']} states; "
                             "coarsen the resolution or tighten the constraints")

    def _build_dense(self) -> None:
        """One resource: ``D[p, e]`` relaxed by a min-plus product with the transitions.

        No element advances the primary by less than ``w = min r_0(e)`` steps, so the rows
        of ``w`` consecutive levels depend only on earlier ones: they are relaxed together
        (one vectorised product per ``w`` levels; 30 for the thesis's street of 6-30 m
        buildings on the 0.2 m grid).
        """
        n, H0, U0, T = self.n, self.H0, self.U0, self.T
        progress = self.p["progress"]
        D = np.full((H0 + 1, n), np.inf)
        e0, c0 = self._source_states()
        D[U0[e0], e0] = c0
        finite_T = np.isfinite(T)
        width = int(U0.min())
        budget = max(1, _CHUNK // (n * n))
        q, reported = 1, 0
        while q < H0:
            rows = D[q:min(q + width, H0)]
            live = rows < np.inf
            A = np.flatnonzero(live.any(axis=0))
            if not len(A):
                q += len(rows)
                continue
            ok = self.ok[q:q + len(rows)]
            B = np.flatnonzero(ok.any(axis=0) & finite_T[A].any(axis=0))
            if len(B):
                sub = T[np.ix_(A, B)]
                for a in range(0, len(rows), budget):
                    r = rows[a:a + budget, A]
                    cand = (r[:, :, None] + sub[None]).min(axis=1)
                    lv = q + a + np.arange(len(r))
                    if self.PCt is not None:
                        cand += self.PCt[lv][:, B]
                    # (level, element) targets are distinct within one product
                    i, j = np.nonzero(ok[a:a + len(r)][:, B] & (cand < np.inf))
                    tgt, col = lv[i] + U0[B[j]], B[j]
                    D[tgt, col] = np.minimum(D[tgt, col], cand[i, j])
            q += len(rows)
            if q - reported >= 512:
                reported = q
                progress.step(0.9 * q / H0)
        self.D = D
        self._guard(int(np.isfinite(D).sum()))

    def _backward_sets(self) -> None:
        """The backward growth (thesis sec. 3.3.1, from the sink): per secondary resource
        ``i``, ``G_i[p, c]`` is True when a prefix that consumed ``p`` primary steps and
        ``c`` of resource ``i`` can still be completed -- by elements allowed where they
        would start, ending in a terminal level with ``lo_i <= total <= hi_i``.

        The sets merge the thesis's backward tree over the elements (transitions are
        ignored: a relaxation), so they never cut a completable prefix; the forward growth
        creates a node only where every ``G_i`` allows it. This is exact over-/underflow
        pruning: a prefix that no multiset of allowed elements can complete is never made.
        Grown level by level from the top, ``min r_0`` levels at a time; left out (the
        weaker rate bounds only) when the sets would exceed :data:`_BACKWARD_CELLS`.
        """
        H0, U0 = self.H0, self.U0
        self.G = None
        if (H0 + 1) * int(self.radix.sum()) > _BACKWARD_CELLS:
            return
        top = max(int(self.p["lo_c"][0]), int(self.p["last_key"]), 1)
        width = int(U0.min())
        sets = []
        for i in range(len(self.radix)):
            R, lo, hi = int(self.radix[i]), int(self.lo_s[i]), int(self.hi_s[i])
            G = np.zeros((H0 + 1, R), dtype=bool)
            G[top:, lo:hi + 1] = True
            pairs, group = np.unique(np.c_[U0, self.secondary[:, i]], axis=0,
                                     return_inverse=True)
            group = group.ravel()
            starts = np.zeros((H0 + 1, len(pairs)), dtype=bool)
            for g in range(len(pairs)):
                starts[:, g] = self.ok[:, group == g].any(axis=1)
            hi_lvl = H0 - 1
            while hi_lvl >= 0:
                lo_lvl = max(0, hi_lvl - width + 1)
                lv = np.arange(lo_lvl, hi_lvl + 1)
                for g, (a, b) in enumerate(pairs):
                    at = lv[starts[lo_lvl:hi_lvl + 1, g]]
                    if not len(at) or b >= R:
                        continue
                    G[at, :R - b] |= G[at + a, b:]
                hi_lvl = lo_lvl - 1
            sets.append(G)
        self.G = sets

    def _feasible(self, c: np.ndarray, p_new: np.ndarray) -> np.ndarray:
        """May a node with secondary consumption ``c`` (..., m) end at primary level
        ``p_new`` (broadcast)? Within the upper bounds and completable: the backward sets,
        or (when too large to keep) the bounds still reachable at the extreme rates."""
        p = self.p
        hi, lo = self.hi_s, self.lo_s
        ok = (c <= hi).all(axis=-1)
        if self.G is not None:
            pn = np.broadcast_to(p_new, ok.shape)
            for i, G in enumerate(self.G):
                ci = np.minimum(c[..., i], hi[i])
                ok &= G[pn, ci]
            return ok
        rest = (self.H0 - p_new)[..., None]
        need = np.maximum(p["lo_c"][0] - p_new, 0)[..., None]
        ok &= (c + rest * p["max_rate"][1:] >= lo - 1e-9).all(axis=-1)
        ok &= (c + need * p["min_rate"][1:] <= hi + 1e-9).all(axis=-1)
        return ok

    def _decode(self, codes: np.ndarray) -> np.ndarray:
        return (codes[:, None] // self.stride[None, :]) % self.radix[None, :]

    def _build_sparse(self) -> None:
        """Several resources: per level, the codes present and a (codes x elements) table."""
        n, H0, U0, T = self.n, self.H0, self.U0, self.T
        progress = self.p["progress"]
        finite_T = np.isfinite(T)
        self._backward_sets()
        self.codes: List[Optional[np.ndarray]] = [None] * (H0 + 1)
        self.cols: List[Optional[np.ndarray]] = [None] * (H0 + 1)
        self.D: List[Optional[np.ndarray]] = [None] * (H0 + 1)
        pending: Dict[int, list] = {}
        by_size = np.argsort(U0, kind="stable")

        def push(levels_new, codes, elems, cost):
            # contributions to later levels (levels_new non-decreasing), one batch per level
            if not len(levels_new):
                return
            cut = np.r_[0, np.flatnonzero(np.diff(levels_new)) + 1, len(levels_new)]
            for a, b in zip(cut[:-1], cut[1:]):
                pending.setdefault(int(levels_new[a]), []).append(
                    (codes[a:b], elems[a:b], cost[a:b]))

        e0, c0 = self._source_states()
        o = np.argsort(U0[e0], kind="stable")
        push(U0[e0][o], self.code_e[e0][o], e0[o], c0[o])
        for q in range(1, H0 + 1):
            batch = pending.pop(q, None)
            if batch is None:
                continue
            codes = np.concatenate([b[0] for b in batch])
            elems = np.concatenate([b[1] for b in batch])
            cost = np.concatenate([b[2] for b in batch])
            uc, row = np.unique(codes, return_inverse=True)
            full = np.full(len(uc) * n, np.inf)
            np.minimum.at(full, row * n + elems, cost)
            full = full.reshape(len(uc), n)
            ue = np.flatnonzero((full < np.inf).any(axis=0))
            Dq = full[:, ue]
            self.codes[q], self.cols[q], self.D[q] = uc, ue, Dq
            self._guard(int((Dq < np.inf).sum()))
            if q % 64 == 0:
                progress.step(0.9 * q / H0)
            if q == H0:
                break
            B = by_size[self.ok[q, by_size] & finite_T[ue][:, by_size].any(axis=0)]
            if not len(B):
                continue
            # min-plus product of the level's table with the transitions, in chunks
            sub = T[np.ix_(ue, B)]
            step = max(1, _CHUNK // max(1, len(ue) * len(B)))
            if step >= len(uc):
                cand = (Dq[:, :, None] + sub[None]).min(axis=1)
            else:
                cand = np.empty((len(uc), len(B)))
                for a in range(0, len(uc), step):
                    cand[a:a + step] = (Dq[a:a + step, :, None] + sub[None]).min(axis=1)
            if self.PCt is not None:
                cand += self.PCt[q, B][None, :]
            p_new = q + U0[B]
            c_new = self._decode(uc)[:, None, :] + self.secondary[B][None, :, :]
            ok = (cand < np.inf) & self._feasible(c_new, p_new[None, :])
            b_i, r_i = np.nonzero(ok.T)          # grouped by element: p_new non-decreasing
            if len(b_i):
                push(p_new[b_i], uc[r_i] + self.code_e[B[b_i]], B[b_i], cand[r_i, b_i])

    # -- access ---------------------------------------------------------------------

    def _row(self, p: int, code: int):
        """(elements, costs) of the nodes at level p with secondary code ``code``."""
        if self.dense:
            return None, self.D[p]
        codes = self.codes[p]
        if codes is None:
            return None, None
        i = int(np.searchsorted(codes, code))
        if i == len(codes) or codes[i] != code:
            return None, None
        return self.cols[p], self.D[p][i]

    def in_edges(self, v) -> List[tuple]:
        """(cost through the best path of u, u, edge cost) for every in-neighbour u of v."""
        if v == SINK:
            return self.sink_edges()
        p, code, e = v
        q = p - int(self.U0[e])
        w0 = 0.0 if self.PCt is None else float(self.PCt[q, e])
        if q == 0:
            if code == int(self.code_e[e]) and self.ok[0, e]:
                w = float(self.p["s_cost"][e]) + w0
                return [(w, SOURCE, w)]
            return []
        prev = code - int(self.code_e[e])
        cols, dist = self._row(q, prev)
        if dist is None:
            return []
        w = self.T[cols if cols is not None else slice(None), e] + w0
        c = dist + w
        idx = np.flatnonzero(np.isfinite(c))
        el = idx if cols is None else cols[idx]
        return [(float(c[i]), (q, prev, int(x)), float(w[i])) for i, x in zip(idx, el)]

    def sink_edges(self) -> List[tuple]:
        """The terminal nodes: allowed at the back, every bound met, past the key points."""
        p = self.p
        last_m, e_cost = p["last_m"], p["e_cost"]
        out = []
        for lvl in range(max(int(p["lo_c"][0]), int(p["last_key"]), 1), self.H0 + 1):
            if self.dense:
                c = self.D[lvl] + e_cost
                idx = np.flatnonzero(np.isfinite(c) & last_m)
                out += [(float(c[i]), (lvl, 0, int(i)), float(e_cost[i])) for i in idx]
                continue
            codes = self.codes[lvl]
            if codes is None:
                continue
            cons = self._decode(codes)
            rows = np.flatnonzero(((cons >= self.lo_s) & (cons <= self.hi_s)).all(axis=1))
            cols = self.cols[lvl]
            keep = last_m[cols]
            if not len(rows) or not keep.any():
                continue
            c = self.D[lvl][np.ix_(rows, np.flatnonzero(keep))] + e_cost[cols[keep]][None, :]
            r_i, c_i = np.nonzero(np.isfinite(c))
            ec = e_cost[cols[keep]]
            out += [(float(c[a, b]), (lvl, int(codes[rows[a]]), int(cols[keep][b])),
                     float(ec[b])) for a, b in zip(r_i, c_i)]
        return out

    # -- paths ----------------------------------------------------------------------

    def k_best(self, k: int = 1) -> List[Tuple[float, List[tuple]]]:
        """The k cheapest source-sink paths as (cost, [node keys]), non-decreasing cost.

        The Recursive Enumeration Algorithm (Jimenez & Marzal 1999), lazily from the sink:
        the j-th path into a node is the best candidate among the first paths of its
        in-neighbours and the successors of the paths already used, so only the nodes and
        paths the k answers need are ever touched (exact, like Eppstein's, thesis sec. 3.3.1).
        """
        if k < 1:
            raise InputError("k must be at least 1")
        return _enumerate(self.in_edges, k)


def _enumerate(in_edges: Callable, k: int, source=SOURCE, sink=SINK) -> List[tuple]:
    """k shortest ``source``-``sink`` paths of a DAG given by ``in_edges`` (REA, see
    k_best): ``in_edges(v)`` lists (cost of the best path through u, u, edge cost) for the
    in-neighbours u of v; a path is (cost, [its nodes between source and sink])."""
    paths: Dict[object, list] = {source: [(0.0, None, 0.0, 0)]}
    heaps: Dict[object, list] = {}
    pushed: Dict[object, bool] = {}
    exhausted = {source}

    def ensure_path(v0: tuple, j0: int) -> None:
        stack = [(v0, j0)]
        while stack:
            v, j = stack[-1]
            P = paths.get(v)
            if P is not None and (len(P) >= j or v in exhausted):
                stack.pop()
                continue
            if P is None:
                heap = [(c, u, w, 1) for c, u, w in in_edges(v)]
                heapq.heapify(heap)
                heaps[v], P = heap, []
                paths[v] = P
                pushed[v] = True
            if not pushed[v]:
                _, u, w, r = P[-1]
                Pu = paths.get(u)
                if Pu is None or (len(Pu) <= r and u not in exhausted):
                    stack.append((u, r + 1))
                    continue
                if len(Pu) > r:
                    heapq.heappush(heaps[v], (Pu[r][0] + w, u, w, r + 1))
                pushed[v] = True
            if heaps[v]:
                P.append(heapq.heappop(heaps[v]))
                pushed[v] = False
            else:
                exhausted.add(v)

    out = []
    for j in range(1, k + 1):
        ensure_path(sink, j)
        if len(paths[sink]) < j:
            break
        c_total = paths[sink][j - 1][0]
        path, v, idx = [], sink, j - 1
        while v != source:
            ensure_path(v, idx + 1)
            _, u, _, r = paths[v][idx]
            v, idx = u, r - 1
            if v != source:
                path.append(v)
        out.append((float(c_total), path[::-1]))
    return out


def build_implicit_graph(resources, transition, constraints: Sequence[Constraint],
                         **options) -> ImplicitGraph:
    """The implicit intermediate graph (same options as :func:`build_graph`)."""
    return ImplicitGraph(_prepare(resources, transition, constraints, **options))


def solve(resources, transition, constraints: Sequence[Constraint], k: int = 1,
          method: str = "graph", **options) -> List[Solution]:
    """The k best feasible sequences (thesis eq. 3.2); see :func:`build_graph` for options.

    ``method``: ``"graph"`` (default) keeps the intermediate graph implicit
    (:class:`ImplicitGraph`: node tables per level, in-edges derived on demand, lazy k
    best); ``"explicit"`` materialises it (:func:`build_graph`, an edge list, then
    :func:`k_best`) -- the same graph and the same answers, at the memory cost of every
    edge; kept as a reference. Returns a list of :class:`Solution` (rank 1 first, costs
    non-decreasing; fewer than k when fewer feasible sequences exist). Raises
    :class:`InfeasibleError` when none does.
    """
    if method not in ("graph", "explicit"):
        raise InputError("method must be 'graph' or 'explicit'")
    if k < 1:
        raise InputError("k must be at least 1")
    p = _prepare(resources, transition, constraints, **options)
    U, res = p["U"], p["res"]
    U0 = p["U0"]
    if method == "explicit":
        g = _graph(**p)
        found = k_best(g, k)
        if not found:
            raise InfeasibleError("no feasible sequence (the graph has no finite-cost path)")
        paths = [(c, g.element[nodes], g.consumed[nodes, 0]) for c, nodes in found]
    else:
        g = ImplicitGraph(p)
        found = g.k_best(k)
        p["progress"].step(1.0)
        if not found:
            raise InfeasibleError(_infeasible_message(U0, res[0], p["lo_c"][0], p["H0"]))
        paths = [(c, np.array([v[2] for v in nodes], dtype=np.int64),
                  np.array([v[0] for v in nodes], dtype=np.int64)) for c, nodes in found]
    out = []
    for rank, (c, seq, ends) in enumerate(paths, start=1):
        starts = (ends - U0[seq]) * res[0]
        out.append(Solution(rank=rank, cost=c, sequence=tuple(int(s) for s in seq),
                            starts=tuple(float(s) for s in starts),
                            totals=U[seq].sum(axis=0) * res))
    return out
