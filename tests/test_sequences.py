"""Engine tests of plugin/buildings/sequences.py (thesis ch. 3: resource-constrained k shortest paths).

The solver is checked against an independent brute-force enumeration of every sequence on
many small random instances (fixed seeds): same optimal cost, same k-best costs, the same
verdict on infeasible instances; each of equality / interval constraints, several
resources, key points (anchors, key-only elements), data terms and start / end costs is
exercised on its own family of instances.
"""
import doctest
import math

import numpy as np
import pytest

from urban_synthesis.plugin.buildings import sequences
from urban_synthesis.plugin.core.progress import Canceled, InputError, Progress
from urban_synthesis.plugin.buildings.sequences import Constraint, InfeasibleError, KeyPoint, solve

INF = math.inf


def brute_force(U, T, bounds, *, key_points=(), first=None, last=None, key_only=None,
                anchor=None, position_cost=None, start_cost=None, end_cost=None):
    """Every feasible sequence's cost, by depth-first enumeration (grid units throughout).

    ``bounds``: {resource: (lo, hi)}; key point semantics as documented in sequences: one
    listed element sits at the position (start + anchor == p), no other element touches it.
    """
    n = len(U)
    H = bounds[0][1]
    anchor = np.zeros(n, int) if anchor is None else np.asarray(anchor)
    key_only = set() if key_only is None else set(key_only)
    first = set(range(n)) if first is None else set(first)
    last = set(range(n)) if last is None else set(last)
    sc = np.zeros(n) if start_cost is None else np.asarray(start_cost, float)
    ec = np.zeros(n) if end_cost is None else np.asarray(end_cost, float)
    out = []

    def valid(seq, starts):
        tot = U[list(seq)].sum(axis=0)
        for r, (lo, hi) in bounds.items():
            if not lo <= tot[r] <= hi:
                return False
        if seq[0] not in first or seq[-1] not in last:
            return False
        sat_used = [False] * len(seq)
        for p, members in key_points:
            hit = False
            for i, (e, s) in enumerate(zip(seq, starts)):
                satisfying = e in members and s + anchor[e] == p
                if satisfying:
                    hit = True
                    sat_used[i] = True
                elif s <= p <= s + U[e, 0]:
                    return False
            if not hit:
                return False
        return all(sat_used[i] or e not in key_only for i, e in enumerate(seq))

    def cost_of(seq, starts):
        c = sc[seq[0]] + ec[seq[-1]]
        c += sum(T[a, b] for a, b in zip(seq, seq[1:]))
        if position_cost is not None:
            c += sum(position_cost[e, s] for e, s in zip(seq, starts))
        return c

    def rec(seq, starts, used):
        if seq and valid(seq, starts):
            c = cost_of(seq, starts)
            if np.isfinite(c):
                out.append((c, tuple(seq)))
        for e in range(n):
            if used + U[e, 0] > H:
                continue
            if seq and not np.isfinite(T[seq[-1], e]):
                continue
            rec(seq + [e], starts + [used], used + U[e, 0])

    rec([], [], 0)
    return sorted(out)


def random_instance(rng, n_res=1, p_forbid=0.25, max_len=4, max_sec=3):
    n = int(rng.integers(2, 6))
    U = np.zeros((n, n_res), dtype=int)
    U[:, 0] = rng.integers(2, max_len + 1, n)
    U[0, 0] = 1   # one unit-length element (like 1 m of empty space); more would make the
    #               brute-force enumeration explode
    if n_res > 1:
        U[:, 1:] = rng.integers(0, max_sec + 1, (n, n_res - 1))
    T = rng.uniform(0, 1, (n, n)).round(3)
    T[rng.uniform(size=(n, n)) < p_forbid] = INF
    return U, T


def check(U, T, bounds, k, **kw):
    """Solver vs brute force: same costs of the k best, or both infeasible."""
    truth = brute_force(U, T, bounds, **kw)
    constraints = [Constraint(r, lo, hi) for r, (lo, hi) in bounds.items()]
    opts = dict(kw)
    if "key_points" in opts:
        opts["key_points"] = [KeyPoint(p, tuple(m)) for p, m in opts["key_points"]]
    if not truth:
        with pytest.raises(InfeasibleError):
            solve(U, T, constraints, k=k, **opts)
        with pytest.raises(InfeasibleError):
            solve(U, T, constraints, k=k, method="explicit", **opts)
        return 0
    sols = solve(U, T, constraints, k=k, **opts)
    # the implicit graph and the explicit edge list agree (two independent builders)
    explicit = solve(U, T, constraints, k=k, method="explicit", **opts)
    assert np.allclose([s.cost for s in explicit], [s.cost for s in sols], atol=1e-9)
    want = [c for c, _ in truth[:k]]
    assert np.allclose([s.cost for s in sols], want, atol=1e-9), (sols, truth[:k])
    # every returned sequence is feasible, distinct, with the cost it claims
    feasible = {seq: c for c, seq in truth}
    assert len({s.sequence for s in sols}) == len(sols)
    for s in sols:
        assert s.sequence in feasible
        assert feasible[s.sequence] == pytest.approx(s.cost)
        assert np.allclose(s.totals, U[list(s.sequence)].sum(axis=0))
    assert [s.rank for s in sols] == list(range(1, len(sols) + 1))
    return len(sols)


def test_module_doctest():
    assert doctest.testmod(sequences).failed == 0


@pytest.mark.parametrize("seed", range(40))
def test_single_resource_equality_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    U, T = random_instance(rng)
    if seed % 8 == 0:   # even lengths only, odd total: infeasible
        U[:, 0] = 2 * rng.integers(1, 3, len(U))
    L = int(rng.integers(4, 13)) | (1 if seed % 8 == 0 else 0)
    check(U, T, {0: (L, L)}, k=1)
    check(U, T, {0: (L, L)}, k=6)


@pytest.mark.parametrize("seed", range(30))
def test_interval_and_several_resources_match_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    n_res = 2 + seed % 2
    U, T = random_instance(rng, n_res=n_res)
    lo = int(rng.integers(3, 9))
    bounds = {0: (lo, lo + int(rng.integers(0, 4)))}
    for r in range(1, n_res):
        a = int(rng.integers(0, 6))
        # alternate equality and interval constraints on the secondary resources
        bounds[r] = (a, a) if (seed + r) % 2 else (a, a + int(rng.integers(1, 4)))
    check(U, T, bounds, k=1)
    check(U, T, bounds, k=8)


@pytest.mark.parametrize("seed", range(30))
def test_key_points_match_brute_force(seed):
    rng = np.random.default_rng(200 + seed)
    U, T = random_instance(rng, p_forbid=0.1)
    n = len(U)
    L = int(rng.integers(6, 13))
    anchor = np.array([int(rng.integers(0, U[e, 0] + 1)) for e in range(n)])
    kps = []
    for p in sorted(set(rng.integers(0, L + 1, int(rng.integers(1, 3))).tolist())):
        kps.append((p, sorted(set(rng.integers(0, n, 2).tolist()))))
    key_only = [int(rng.integers(0, n))] if seed % 2 else None
    for k in (1, 5):
        check(U, T, {0: (L - seed % 3, L)}, k=k, key_points=kps, anchor=anchor,
              key_only=key_only)


@pytest.mark.parametrize("seed", range(25))
def test_data_terms_and_end_costs_match_brute_force(seed):
    rng = np.random.default_rng(300 + seed)
    U, T = random_instance(rng, n_res=2)
    n = len(U)
    L = int(rng.integers(5, 12))
    pc = rng.uniform(0, 2, (n, L + 1)).round(3)
    pc[rng.uniform(size=pc.shape) < 0.15] = INF
    sc = rng.uniform(0, 1, n).round(3)
    ec = rng.uniform(0, 1, n).round(3)
    ec[0] = INF
    first = sorted(set(rng.integers(0, n, 2).tolist()))
    opts = dict(position_cost=pc, start_cost=sc, end_cost=ec, first=first,
                last=list(range(1, n)))
    check(U, T, {0: (L, L), 1: (0, int(rng.integers(2, 8)))}, k=4, **opts)
    check(U, T, {0: (L - 2, L)}, k=3, **opts)   # single resource: the dense table


def test_brute_force_families_are_not_trivial():
    """The random families above contain feasible and infeasible instances and k-best lists
    longer than one (so the comparisons are not vacuous)."""
    found, infeasible, long_lists = 0, 0, 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        U, T = random_instance(rng)
        if seed % 8 == 0:
            U[:, 0] = 2 * rng.integers(1, 3, len(U))
        L = int(rng.integers(4, 13)) | (1 if seed % 8 == 0 else 0)
        sols = brute_force(U, T, {0: (L, L)})
        found += bool(sols)
        infeasible += not sols
        long_lists += len(sols) >= 6
    assert found >= 20 and infeasible >= 2 and long_lists >= 10


def test_real_valued_resources_on_a_grid():
    """Lengths on a 0.2 m grid and areas on 1 m² are met exactly (thesis ch. 6)."""
    R = np.array([[2.4, 30.0], [3.0, 36.0], [4.2, 50.0], [0.6, 5.0]])
    T = np.ones((4, 4)) - np.eye(4) * 0.5
    sols = solve(R, T, [Constraint.equal(0, 19.8), Constraint(1, 230, 240)],
                 resolution=[0.2, 1.0], k=5)
    assert len(sols) == 5
    for s in sols:
        assert s.totals[0] == pytest.approx(19.8)
        assert 230 <= s.totals[1] <= 240
        assert sum(R[list(s.sequence), 0]) == pytest.approx(19.8)
    assert [s.cost for s in sols] == sorted(s.cost for s in sols)


def test_infeasible_street_is_reported():
    """The thesis's example: a 50 m street from a database of 20 m buildings."""
    with pytest.raises(InfeasibleError, match="primary sizes 20"):
        solve([[20.0]], [[0.0]], [Constraint.equal(0, 50)])
    with pytest.raises(InfeasibleError):  # the interval holds no grid value
        solve([[1.0]], [[0.0]], [Constraint(0, 2.3, 2.7)])


def test_k_larger_than_the_number_of_solutions():
    sols = solve([[1], [2]], np.zeros((2, 2)), [Constraint.equal(0, 3)], k=10)
    assert sorted(s.sequence for s in sols) == [(0, 0, 0), (0, 1), (1, 0)]


def test_frontage_with_position_data_term():
    """A 1 m-grid frontage: the data term pulls each element to where its guide lies."""
    L = 40
    lengths = np.array([12, 8, 1])          # a corner house, a row house, 1 m empty space
    pos = np.zeros((3, L + 1))
    pos[0] = np.abs(np.arange(L + 1) - 0) * 5.0          # corner house belongs at 0
    pos[1] = 2.0
    pos[1, [12, 20, 28]] = 0.0                           # row houses where the guide has them
    pos[2] = 0.5
    T = np.array([[INF, 0, 0], [INF, 0.95, 0], [INF, 0, 0.05]])
    best = solve(lengths[:, None], T, [Constraint.equal(0, L)], position_cost=pos)[0]
    assert best.sequence[:4] == (0, 1, 1, 1)
    assert best.starts[:4] == (0.0, 12.0, 20.0, 28.0)
    assert best.totals[0] == L


def test_bad_input_is_rejected():
    with pytest.raises(InputError, match="primary resource"):
        solve([[0.0], [1.0]], np.zeros((2, 2)), [Constraint.equal(0, 3)])
    with pytest.raises(InputError, match="upper bound"):
        solve([[1.0]], [[0.0]], [Constraint(0, 1)])
    with pytest.raises(InputError, match="non-negative"):
        solve([[-1.0]], [[0.0]], [Constraint.equal(0, 3)])
    with pytest.raises(InputError, match="transition"):
        solve([[1.0]], np.zeros((2, 2)), [Constraint.equal(0, 3)])
    with pytest.raises(InputError, match="grid"):
        solve([[1.0]], [[0.0]], [Constraint.equal(0, 3)], key_points=[KeyPoint(1.5, (0,))])
    with pytest.raises(InputError, match="method"):
        solve([[1.0]], [[0.0]], [Constraint.equal(0, 3)], k=2, method="dense")
    with pytest.raises(InputError, match="states"):
        solve(np.arange(1, 6)[:, None], np.zeros((5, 5)), [Constraint.equal(0, 200)],
              max_states=100, k=2)


def test_cancellation():
    def canceled():
        return True

    with pytest.raises(Canceled):
        solve([[1], [2]], np.zeros((2, 2)), [Constraint.equal(0, 30)],
              progress=Progress(is_canceled=canceled))


@pytest.mark.parametrize("seed", range(15))
def test_start_mask_matches_brute_force(seed):
    """A start mask confines elements to start levels (the substructure copies of a 1.5D
    structure): the same answers as a data term that forbids the masked starts."""
    rng = np.random.default_rng(400 + seed)
    U, T = random_instance(rng, n_res=1 + seed % 2, p_forbid=0.1)
    n = len(U)
    L = int(rng.integers(6, 13))
    mask = rng.uniform(size=(n, L + 1)) < 0.6
    bounds = {0: (L, L)} if seed % 2 == 0 else {0: (L, L), 1: (0, int(rng.integers(2, 8)))}
    truth = brute_force(U, T, bounds, position_cost=np.where(mask, 0.0, INF))
    constraints = [Constraint(r, lo, hi) for r, (lo, hi) in bounds.items()]
    if not truth:
        with pytest.raises(InfeasibleError):
            solve(U, T, constraints, k=3, start_mask=mask)
        return
    sols = solve(U, T, constraints, k=3, start_mask=mask)
    assert np.allclose([s.cost for s in sols], [c for c, _ in truth[:3]], atol=1e-9)
    for s in sols:
        starts = np.rint(np.asarray(s.starts)).astype(int)
        assert mask[list(s.sequence), starts].all()
