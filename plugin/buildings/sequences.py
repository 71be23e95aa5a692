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

- **Construction by resource consumption, not by cost** (:func:`build_graph`). Resources
  are quantised to a grid (``resolution``: 0.2 m lengths, 1 m² floor areas in the thesis);
  the first resource is the *primary* one (length, height): every element consumes at least
  one grid step of it and it must be bounded above, so consumption orders the graph. The
  forward sweep grows the states level by level from the source, vectorised over whole
  waves of states (numpy), a node being created only if its signature is new.
- **Pruning.** (a) overflow / underflow: a state is never created when it exceeds an
  upper bound, or when even the most (least) resource-dense elements cannot reach (stay
  under) a bound within the primary budget that is left; (b) dead ends: the backward sweep
  from the sink (breadth-first search on the reversed graph, scipy) keeps only the nodes
  that can still complete a feasible sequence. The node set is the thesis's bidirectionally
  grown graph (the nodes on a source-sink path); the growth here is forward then backward
  rather than interleaved, which gives the same graph. Infeasible problems (a 50 m street
  from 20 m buildings) are detected when nothing reaches the sink.
- **Several resources, equality and interval constraints**: states carry the vector of
  every constrained resource; unconstrained resources are only summed for the report.
- **Key points** (thesis sec. 3.3.4, "structure"): a :class:`KeyPoint` forces one of a set
  of elements to sit at a primary position -- a corner part at a skeleton vertex, end
  parts at the ends. An element sits at ``start + anchor`` (``anchor``: a corner's vertex
  lies inside it, a left end's at its start, a right end's at its end) and *no other
  element may touch the key point* (its closed extent may not contain it), so an element
  anchored at its start can only begin the sequence and one anchored at its end only end
  it. ``key_only`` elements (corners) appear nowhere but at key points that list them.
- **Data terms**: ``position_cost[e, l]`` is added when ``e`` starts at grid level ``l``
  (the overlap data term of the footprint re-synthesis, thesis eq. 5.1), ``start_cost``
  and ``end_cost`` on the first and last element (a closed loop's closing transition).
- **Best and k best** (:func:`k_best`): the graph is a DAG in consumption order, so the
  shortest path (Dijkstra in the thesis) is a dynamic program over the levels, vectorised;
  the k best paths come from the Recursive Enumeration Algorithm of Jimenez and Marzal
  (1999), an exact k-shortest-paths algorithm equivalent in its output to Eppstein's
  (1998): the j-th solution is optimal among the sequences not in the first j-1. Every
  sequence is one path (its states are determined by the sequence), so the k solutions are
  distinct sequences, in non-decreasing cost. For k = 1 with only the primary resource
  constrained (a frontage of exact length) :func:`solve` keeps the same DAG implicit, as
  an (elements x levels) cost table relaxed level by level (``method="dense"``).

Complexity for one resource: at most ``n`` nodes per level, ``d`` successors each, ``L``
levels: O(L d n) (thesis sec. 3.4). Not implemented: 1.5D structures (T-junction parts
with virtual duplicates, sec. 3.3.4); :mod:`building_parts` cuts closed loops itself.

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


def _start_mask(n, H0, U0, anchor, key_points, res0, first, key_only, position_cost):
    """allowed[e, l]: may element e start at primary level l? (key points, first, data term)."""
    allowed = np.ones((n, H0 + 1), dtype=bool)
    if position_cost is not None:
        allowed &= np.isfinite(position_cost)
    allowed[~first, 0] = False
    levels = np.arange(H0 + 1)
    satisfying_any = np.zeros((n, H0 + 1), dtype=bool)
    key_positions = []
    for kp in key_points:
        p = int(round(kp.position / res0))
        if abs(p * res0 - kp.position) > 1e-6 * max(1.0, abs(kp.position)) + 1e-9:
            raise InputError(f"key point {kp.position:g} is not on the resolution grid "
                             f"({res0:g}); round it first")
        if p < 0 or p > H0:
            raise InfeasibleError(f"key point {kp.position:g} lies outside the length bound")
        members = _as_mask(kp.elements, n, "key point elements")
        touches = (levels[None, :] <= p) & (p <= levels[None, :] + U0[:, None])
        satisfying = members[:, None] & (levels[None, :] + anchor[:, None] == p)
        allowed &= ~touches | satisfying
        satisfying_any |= satisfying
        key_positions.append(p)
    if key_only.any():
        allowed[key_only] &= satisfying_any[key_only]
    return allowed, (max(key_positions) if key_positions else 0)


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
             start_cost=None, end_cost=None, max_states: int = MAX_STATES,
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
    allowed, last_key = _start_mask(n, H0, U0, anchor_u, key_points, res[0], first_m,
                                    key_only_m, PC)
    return dict(n=n, H0=H0, U=U, U0=U0, UC=UC, lo_c=lo_c, hi_c=hi_c, max_rate=max_rate,
                min_rate=min_rate, allowed=allowed, last_key=last_key, T=T, order=order,
                last_m=last_m, PC=PC, s_cost=s_cost, e_cost=e_cost, R=R, res=res,
                max_states=max_states, progress=progress)


def build_graph(resources, transition, constraints: Sequence[Constraint], *,
                resolution=None, key_points: Sequence[KeyPoint] = (), first=None, last=None,
                key_only=None, anchor=None,
                position_cost: Union[None, np.ndarray, Callable[[np.ndarray], np.ndarray]] = None,
                start_cost=None, end_cost=None, max_states: int = MAX_STATES,
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
                 end_cost=end_cost, max_states=max_states, progress=progress)
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
    paths: Dict[int, List[Tuple[float, int, int]]] = {0: [(0.0, -1, 0)]}
    heaps: Dict[int, list] = {}
    pushed: Dict[int, bool] = {}
    exhausted = {0}

    def ensure_path(v0: int, j0: int) -> None:
        stack = [(v0, j0)]
        while stack:
            v, j = stack[-1]
            P = paths.get(v)
            if P is not None and (len(P) >= j or v in exhausted):
                stack.pop()
                continue
            if P is None:
                es = np.arange(in_ptr[v], in_ptr[v + 1])
                c = dist[src[es]] + cost[es]
                heap = [(float(ci), int(ei), 1) for ci, ei in zip(c, es) if np.isfinite(ci)]
                heapq.heapify(heap)
                heaps[v], P = heap, []
                paths[v] = P
                pushed[v] = True
            if not pushed[v]:
                c_last, e_last, r_last = P[-1]
                u = int(src[e_last])
                Pu = paths.get(u)
                if Pu is None or (len(Pu) <= r_last and u not in exhausted):
                    stack.append((u, r_last + 1))
                    continue
                if len(Pu) > r_last:
                    heapq.heappush(heaps[v], (Pu[r_last][0] + float(cost[e_last]),
                                              e_last, r_last + 1))
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
        while v != 0:
            ensure_path(v, idx + 1)
            _, e, r = paths[v][idx]
            v, idx = int(src[e]), r - 1
            if v:
                path.append(v)
        out.append((float(c_total), path[::-1]))
    return out


def _dense_best(n, H0, U, U0, lo_c, hi_c, allowed, last_key, T, order, last_m, PC, s_cost,
                e_cost, progress, **_) -> Optional[Tuple[float, List[int], List[int]]]:
    """k = 1 with only the primary resource constrained: the same DAG, kept implicit.

    ``D[e, c]``: cheapest prefix ending with ``e`` at consumption ``c``; levels in order,
    each relaxing all (predecessor, successor) pairs at once (an n x n minimum), so the
    cost is O(L n^2) vectorised with no node tables (the frontage sequences of ch. 5.2).
    Returns (cost, elements, ends) or None when infeasible.
    """
    D = np.full((n, H0 + 1), np.inf)
    P = np.full((n, H0 + 1), -1, dtype=np.int64)
    col = np.arange(n)
    e0 = np.flatnonzero(allowed[:, 0] & (U0 <= H0))
    D[e0, U0[e0]] = s_cost[e0] + (PC[e0, 0] if PC is not None else 0.0)
    T_or_inf = np.where(np.isfinite(T), T, np.inf)
    for lvl in range(1, H0):
        ends = D[:, lvl]
        live = np.isfinite(ends)
        if not live.any():
            continue
        cand = ends[live, None] + T_or_inf[live]
        arg = cand.argmin(axis=0)
        inc = cand[arg, col] + (PC[:, lvl] if PC is not None else 0.0)
        tgt = lvl + U0
        ok = allowed[:, lvl] & (tgt <= H0) & np.isfinite(inc)
        if not ok.any():
            continue
        e_ok, t_ok = col[ok], tgt[ok]
        better = inc[ok] < D[e_ok, t_ok]
        D[e_ok[better], t_ok[better]] = inc[ok][better]
        P[e_ok[better], t_ok[better]] = np.flatnonzero(live)[arg[ok][better]]
        if lvl % 256 == 0:
            progress.step(0.9 * lvl / H0)
    c_lo = max(int(lo_c[0]), int(last_key), 1)
    total = D[:, c_lo:H0 + 1] + e_cost[:, None]
    total[~last_m] = np.inf
    if not np.isfinite(total).any():
        return None
    e, c = np.unravel_index(np.argmin(total), total.shape)
    cost = float(total[e, c])
    c += c_lo
    seq, ends = [], []
    while e >= 0:
        seq.append(int(e))
        ends.append(int(c))
        e, c = P[e, c], c - U0[e]
    return cost, seq[::-1], ends[::-1]


def solve(resources, transition, constraints: Sequence[Constraint], k: int = 1,
          method: str = "auto", **options) -> List[Solution]:
    """The k best feasible sequences (thesis eq. 3.2); see :func:`build_graph` for options.

    ``method``: ``"graph"`` builds the intermediate graph (any k, any constraints);
    ``"dense"`` keeps it implicit (k = 1, only the primary resource constrained: the
    frontage case, several times faster); ``"auto"`` picks dense where it applies.
    Returns a list of :class:`Solution` (rank 1 first, costs non-decreasing; fewer than k
    when fewer feasible sequences exist). Raises :class:`InfeasibleError` when none does.
    """
    if method not in ("auto", "graph", "dense"):
        raise InputError("method must be 'auto', 'graph' or 'dense'")
    p = _prepare(resources, transition, constraints, **options)
    dense_ok = k == 1 and len(p["order"]) == 1
    if method == "dense" and not dense_ok:
        raise InputError("the dense method needs k = 1 and only the primary resource "
                         "constrained")
    U, res = p["U"], p["res"]
    if dense_ok and method != "graph":
        found = _dense_best(**p)
        if found is None:
            raise InfeasibleError(_infeasible_message(p["U0"], res[0], p["lo_c"][0], p["H0"]))
        cost, seq, ends = found
        seq = np.asarray(seq)
        starts = (np.asarray(ends) - U[seq, 0]) * res[0]
        p["progress"].step(1.0)
        return [Solution(rank=1, cost=cost, sequence=tuple(int(x) for x in seq),
                         starts=tuple(float(x) for x in starts),
                         totals=U[seq].sum(axis=0) * res)]
    g = _graph(**p)
    found = k_best(g, k)
    if not found:
        raise InfeasibleError("no feasible sequence (the graph has no finite-cost path)")
    U0 = g.units[:, 0]
    out = []
    for rank, (c, nodes) in enumerate(found, start=1):
        seq = g.element[nodes]
        starts = (g.consumed[nodes, 0] - U0[seq]) * g.resolution[0]
        totals = g.units[seq].sum(axis=0) * g.resolution
        out.append(Solution(rank=rank, cost=c, sequence=tuple(int(s) for s in seq),
                            starts=tuple(float(s) for s in starts), totals=totals))
    return out
