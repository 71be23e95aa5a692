"""Engine tests of plugin/buildings/structures.py (thesis sec. 3.3.4, ch. 6: 1.5D structures).

- Exactness: the k best buildings of a T-shaped skeleton and of a loop with a T-junction
  (small random part libraries, fixed seeds) have the costs of the k cheapest among all
  part sequences, enumerated by brute force with the thesis's merge rules: the T-part pays
  its incoming transition, the branch cross-section into the branch and -- through its
  virtual duplicate -- its own outgoing transition to the part after the branch; a loop
  pays its closing transition.
- The thesis's most complex building (Fig. 6.6: nested T-parts and a closed loop): the
  parts cover the skeleton's wings exactly without overlaps, corner parts at the corners,
  T-parts at the T-junctions, end parts at the free ends; k best distinct and ordered;
  local constraints per wing (Fig. 6.7) are met and change the parts chosen.
- Clear errors for networks that are no 1.5D structure.
"""
import itertools
import math

import numpy as np
import pandas as pd
import pytest
import shapely

from urban_synthesis.plugin.buildings import parts as bp
from urban_synthesis.plugin.buildings import structures as st
from urban_synthesis.plugin.buildings.sequences import InfeasibleError
from urban_synthesis.plugin.core.progress import InputError

Q = 0.2
DEPTH = 2.0


def small_library(seed: int) -> bp.PartsLibrary:
    """Straights 1.0 / 1.0 / 1.2 / 1.6 m, two 90° corners (legs 2 m), two T-parts (2.0 m
    with no stub, 2.4 m reaching 1.4 m into the branch), end parts; random heights."""
    rng = np.random.default_rng(seed)
    rows = [dict(kind="straight", length_m=x) for x in (1.0, 1.0, 1.2, 1.6)]
    rows += [dict(kind="corner", length_m=4.0, angle_deg=90.0) for _ in range(2)]
    rows += [dict(kind="tee", length_m=2.0, branch_m=1.0), dict(kind="tee", length_m=2.4,
                                                                branch_m=1.4)]
    rows += [dict(kind="end_left", length_m=1.0)] + [dict(kind="end_right", length_m=1.0)
                                                     for _ in range(2)]
    t = pd.DataFrame(rows)
    t["depth_m"] = DEPTH
    t["height_m"] = rng.uniform(3.0, 12.0, len(t)).round(2)   # few ties between costs
    t["area_branch_m2"] = DEPTH * rng.uniform(3.0, 12.0, len(t)).round(2)
    return bp.library_from_table(t, name="small")


def fills(length: float, straights, U):
    """Every sequence of straight parts whose lengths sum to ``length`` exactly."""
    target = int(round(length / Q))
    out = []

    def rec(seq, left):
        if left == 0:
            out.append(tuple(seq))
            return
        for e in straights:
            if U[e] <= left:
                rec(seq + [e], left - U[e])

    if target >= 0:
        rec([], target)
    return out


def chain_cost(T, seq):
    return sum(T[a, b] for a, b in zip(seq, seq[1:]))


def brute_t_shape(lib):
    """All buildings of the T skeleton: root (0,0)-(10,0), T at (5,0), branch to (5,5)."""
    t = lib.table
    T = lib.transition
    kind = t.kind.to_numpy()
    U = np.rint(t.length_m.to_numpy() / Q).astype(int)
    L = t.length_m.to_numpy()
    branch = t.branch_m.to_numpy()
    abr, aleft = t.area_branch_m2.to_numpy(), t.area_left_m2.to_numpy()
    S = np.flatnonzero(kind == "straight")
    out = []
    for e1 in np.flatnonzero(kind == "end_left"):
        for j in np.flatnonzero(kind == "tee"):
            for e3 in np.flatnonzero(kind == "end_right"):
                for e2 in np.flatnonzero(kind == "end_right"):
                    fa = fills(5.0 - L[j] / 2 - L[e1], S, U)
                    fc = fills(5.0 - branch[j] - L[e3], S, U)
                    fb = fills(10.0 - 5.0 - L[j] / 2 - L[e2], S, U)
                    for a, c, b in itertools.product(fa, fc, fb):
                        root_a = (e1,) + a + (j,)
                        child = c + (e3,)
                        rest = b + (e2,)
                        cost = (chain_cost(T, root_a) + abs(abr[j] - aleft[child[0]])
                                + chain_cost(T, child) + T[j, rest[0]] + chain_cost(T, rest))
                        if np.isfinite(cost):
                            out.append((cost, root_a + child + rest))
    return sorted(out)


def brute_loop_with_tee(lib):
    """All buildings of an 8.4 m x 4 m ring (cut at (0,0), counter-clockwise) with a T at
    (4.2,0) and a branch to (4.2,-4): cut corner, the sides, closing transition."""
    t = lib.table
    T = lib.transition
    kind = t.kind.to_numpy()
    U = np.rint(t.length_m.to_numpy() / Q).astype(int)
    L = t.length_m.to_numpy()
    branch = t.branch_m.to_numpy()
    abr, aleft = t.area_branch_m2.to_numpy(), t.area_left_m2.to_numpy()
    S = np.flatnonzero(kind == "straight")
    C = np.flatnonzero(kind == "corner")
    out = []
    for c0, c1, c2, c3 in itertools.product(C, repeat=4):
        for j in np.flatnonzero(kind == "tee"):
            for e3 in np.flatnonzero(kind == "end_right"):
                leg = L[C[0]] / 2
                f1 = fills(4.2 - L[j] / 2 - leg, S, U)
                fc = fills(4.0 - branch[j] - L[e3], S, U)
                f2 = fills(8.4 - leg - 4.2 - L[j] / 2, S, U)
                f3 = fills(4.0 - 2 * leg, S, U)      # corner next to corner
                f4 = fills(8.4 - 2 * leg, S, U)
                f5 = fills(4.0 - 2 * leg, S, U)
                for a, c, b, d, e, f in itertools.product(f1, fc, f2, f3, f4, f5):
                    first = (c0,) + a + (j,)
                    child = c + (e3,)
                    rest = b + (c1,) + d + (c2,) + e + (c3,) + f
                    cost = (chain_cost(T, first) + abs(abr[j] - aleft[child[0]])
                            + chain_cost(T, child) + T[j, rest[0]] + chain_cost(T, rest)
                            + T[rest[-1], c0])
                    if np.isfinite(cost):
                        out.append((cost, first + child + rest))
    return sorted(out)


T_SKELETON = [shapely.LineString([(0, 0), (5, 0), (10, 0)]),
              shapely.LineString([(5, 0), (5, 5)])]
LOOP_SKELETON = [shapely.LineString([(0, 0), (4.2, 0), (8.4, 0), (8.4, 4), (0, 4), (0, 0)]),
                 shapely.LineString([(4.2, 0), (4.2, -4)])]


def check_against(res, truth, k):
    got = res.summary.cost.to_numpy()
    assert len(got) == min(k, len(truth))
    np.testing.assert_allclose(got, [c for c, _ in truth[:k]], atol=1e-9)
    table = {seq: c for c, seq in truth}
    seqs = [s.sequence for s in res.solutions]
    assert len(set(seqs)) == len(seqs)
    for s in res.solutions:
        assert s.sequence in table, s.sequence
        assert table[s.sequence] == pytest.approx(s.cost)


@pytest.mark.parametrize("seed", range(8))
def test_t_shape_k_best_match_brute_force(seed):
    lib = small_library(seed)
    truth = brute_t_shape(lib)
    kind = lib.table.kind.to_numpy()
    assert len(truth) > 20           # not vacuous: many buildings, both T-parts among them
    assert len({next(e for e in seq if kind[e] == "tee") for _, seq in truth}) == 2
    res = st.build_along_network(T_SKELETON, lib, k=6)
    check_against(res, truth, 6)


@pytest.mark.parametrize("seed", range(4))
def test_loop_with_tee_k_best_match_brute_force(seed):
    lib = small_library(100 + seed)
    truth = brute_loop_with_tee(lib)
    assert len(truth) > 100
    res = st.build_along_network(LOOP_SKELETON, lib, k=5)
    check_against(res, truth, 5)


def test_the_tee_choice_depends_on_all_three_neighbours():
    """Fig. 3.4: the branch's cross-section decides the T-part when the through wing
    cannot (through cross-sections equal)."""
    rows = [dict(kind="straight", length_m=1.0, height_m=6.0),
            dict(kind="tee", length_m=2.0, height_m=6.0, area_branch_m2=2 * 6.0),
            dict(kind="tee", length_m=2.0, height_m=6.0, area_branch_m2=2 * 12.0),
            dict(kind="end_left", length_m=1.0, height_m=6.0),
            dict(kind="end_right", length_m=1.0, height_m=6.0),
            dict(kind="end_right", length_m=1.0, height_m=12.0)]
    t = pd.DataFrame(rows)
    t["depth_m"] = DEPTH
    lib = bp.library_from_table(t)
    # a branch of one straight and an end: its first part is 6 m tall -> the T-part whose
    # branch cross-section is 12 m² (6 m x 2 m) is free, the other costs 12
    res = st.build_along_network(T_SKELETON, lib, k=2)
    best = res.table[res.table.solution == 1]
    assert best[best.kind == "tee"].part_id.tolist() == [1]
    assert res.summary.cost.iloc[0] < res.summary.cost.iloc[1]


# --------------------------------------------------------------------------- the thesis


COMPLEX = [shapely.LineString([(0, 0), (24, 0), (48, 0), (48, 18), (48, 36), (24, 36),
                               (0, 36), (0, 0)]),                 # courtyard loop
           shapely.LineString([(24, 0), (24, -18), (24, -30)]),   # south wing (a T on it)
           shapely.LineString([(24, -18), (44, -18)]),            # nested wing
           shapely.LineString([(24, 36), (24, 60)]),              # north wing
           shapely.LineString([(48, 18), (72, 18)])]              # east wing


def wings_area(lines, depth):
    return shapely.union_all([shapely.buffer(ln, depth / 2, cap_style="flat",
                                             join_style="mitre") for ln in lines])


def test_decomposition_of_the_complex_skeleton():
    wings = st.skeleton_network(COMPLEX)
    assert wings[0].closed and wings[0].kind.count("corner") == 4
    assert wings[0].kind.count("tee") == 3
    assert [w.parent for w in wings] == [None, (0, 1), (1, 1), (0, 3), (0, 5)]
    assert sum(w.length for w in wings) == pytest.approx(168 + 30 + 20 + 24 + 24)


def test_the_thesis_complex_building():
    lib = bp.terrace_library()
    res = st.build_along_network(COMPLEX, lib, k=5)
    costs = res.summary.cost.to_numpy()
    assert len(costs) == 5 and (np.diff(costs) >= -1e-9).all()
    assert len({s.sequence for s in res.solutions}) == 5
    target = wings_area(COMPLEX, 12.0)
    corners = np.array([(0, 0), (48, 0), (48, 36), (0, 36)], float)
    tees = np.array([(24, 0), (24, -18), (24, 36), (48, 18)], float)
    for rank, parts in res.table.groupby("solution"):
        geoms = res.geometry[parts.index.to_numpy()]
        assert shapely.is_valid(geoms).all()
        union = shapely.union_all(geoms)
        assert shapely.symmetric_difference(union, target).area < 1e-6
        assert shapely.area(geoms).sum() == pytest.approx(target.area, abs=1e-6)  # no overlap
        assert parts.length_m.sum() + lib.table.set_index("part_id").loc[
            parts.part_id[parts.kind == "tee"], "branch_m"].sum() == pytest.approx(266.0)
        # every key part sits on its vertex
        for kind, points in (("corner", corners), ("tee", tees)):
            sel = geoms[(parts.kind == kind).to_numpy()]
            assert len(sel) == len(points)
            hit = shapely.contains_xy(sel[:, None], points[None, :, 0], points[None, :, 1])
            assert (hit.sum(axis=0) == 1).all() and (hit.sum(axis=1) == 1).all()
        ends = geoms[parts.kind.str.startswith("end").to_numpy()]
        assert len(ends) == 4
        tips = np.array([(24, -30), (44, -18), (24, 60), (72, 18)], float)
        assert (shapely.distance(ends[:, None], shapely.points(tips)[None]) < 1e-6).sum() == 4
        # the floor area reported is the placed footprints x levels
        assert (shapely.area(geoms) * parts.levels).sum() == pytest.approx(
            res.summary.floor_area_m2[rank - 1], abs=0.5 * len(parts))


def test_local_constraints_per_wing():
    """Fig. 6.7: the east wing (line 4) with exactly three doors, the north wing (line 3)
    with a single straight part -- which only the wide T-part (reaching 4 m into the
    wing) leaves room for."""
    lib = bp.terrace_library()
    free = st.build_along_network(COMPLEX, lib)
    res = st.build_along_network(COMPLEX, lib, local={4: {"doors": (3, 3)},
                                                      3: {"straight": (1, 1)}}, k=3)
    table = lib.table.set_index("part_id")
    for _, parts in res.table.groupby("solution"):
        east = parts[parts.wing == 4]
        assert table.loc[east.part_id, "doors"].sum() == 3
        north = parts[(parts.wing == 3) & (parts.kind == "straight")]
        assert len(north) == 1
        geoms = res.geometry[parts.index.to_numpy()]
        tee_north = geoms[(parts.kind == "tee").to_numpy()
                          & shapely.contains_xy(geoms, 24.0, 36.0)]
        assert table.loc[parts.part_id[(parts.kind == "tee").to_numpy()
                                       & shapely.contains_xy(geoms, 24.0, 36.0)],
                         "branch_m"].iloc[0] == pytest.approx(10.0)
        assert len(tee_north) == 1
    north_free = free.table[(free.table.wing == 3) & (free.table.kind == "straight")]
    assert len(north_free) != 1


def test_far_on_the_complex_building():
    lib = bp.terrace_library()
    res = st.build_along_network(COMPLEX, lib, k=3, far=(2.6, 2.8), site_area=4800.0,
                                 area_resolution=10.0)
    for _, parts in res.table.groupby("solution"):
        # met on the 10 m² grid: each part's area rounded by at most 5 m²
        assert 2.6 * 4800 - 5 * len(parts) <= parts.floor_area_m2.sum() <= 2.8 * 4800 + 5 * len(parts)


def test_network_errors():
    lib = bp.terrace_library()
    with pytest.raises(InputError, match="joins 4 wings"):
        st.build_along_network([shapely.LineString([(0, 0), (20, 0), (40, 0)]),
                                shapely.LineString([(20, -20), (20, 0), (20, 20)])], lib)
    with pytest.raises(InputError, match="falls apart"):
        st.build_along_network([shapely.LineString([(0, 0), (40, 0)]),
                                shapely.LineString([(0, 30), (40, 30)])], lib)
    with pytest.raises(InputError, match="no T-junction"):
        st.build_along_network([shapely.LineString([(0, 0), (20, 0), (40, 0)]),
                                shapely.LineString([(20, 0), (35, 15)])], lib)
    with pytest.raises(InputError, match="H"):
        st.build_along_network([shapely.LineString([(0, 0), (0, 20), (0, 40)]),
                                shapely.LineString([(40, 0), (40, 20), (40, 40)]),
                                shapely.LineString([(0, 20), (40, 20)])], lib)
    with pytest.raises(InputError, match="loops"):
        st.build_along_network([shapely.LineString([(0, 0), (15, 0), (30, 0), (30, 30),
                                                    (15, 30), (0, 30), (0, 0)]),
                                shapely.LineString([(15, 0), (15, 30)])], lib)
    no_tees = bp.library_from_table(lib.table[lib.table.kind != "tee"])
    with pytest.raises(InputError, match="no T-parts"):
        st.build_along_network(T_SKELETON_BIG, no_tees)
    with pytest.raises(InfeasibleError):
        st.build_along_network(T_SKELETON_BIG, lib, counts={"doors": (1000, 1000)})
    with pytest.raises(InputError, match="line 7"):
        st.build_along_network(T_SKELETON_BIG, lib, local={7: {"doors": (1, 2)}})


T_SKELETON_BIG = [shapely.LineString([(0, 0), (30, 0), (60, 0)]),
                  shapely.LineString([(30, 0), (30, 24)])]


def test_real_units_and_inputs_unchanged():
    """Wings off the 0.2 m grid are filled to their real length; the input is not
    modified."""
    lines = [shapely.LineString([(0.03, 0), (30.07, 0), (60.11, 0)]),
             shapely.LineString([(30.07, 0), (30.07, 24.05)])]
    before = [ln.wkb for ln in lines]
    res = st.build_along_network(lines, bp.terrace_library())
    assert [ln.wkb for ln in lines] == before
    union = shapely.union_all(res.geometry)
    assert shapely.symmetric_difference(union, wings_area(lines, 12.0)).area < 0.2 * 12 * 4
    # 60.08 m + 23.98 m of wings, each stretch on the 0.2 m grid
    assert math.isclose(res.summary.length_m.iloc[0], 84.0, abs_tol=1e-9)


def test_wings_drawn_onto_a_side_and_grouped_into_buildings():
    """A wing snapped onto another wing's side (no vertex there) makes a T-junction; lines
    that touch form one building, others their own (the Processing algorithm's rule)."""
    lines = [shapely.LineString([(0, 0), (60, 0)]), shapely.LineString([(30, 0), (30, 24)]),
             shapely.LineString([(100, 0), (140, 0)]),
             shapely.LineString([(0, 100), (60, 100), (60, 150), (0, 150), (0, 100)]),
             shapely.LineString([(60, 125), (90, 125)])]
    groups = st.connected_networks(lines)
    assert [g.tolist() for g in groups] == [[0, 1], [2], [3, 4]]
    wings = st.skeleton_network([lines[i] for i in groups[0]])
    assert wings[0].kind == ["tip", "tee", "tip"]
    ring = st.skeleton_network([lines[i] for i in groups[2]])
    assert ring[0].closed and ring[0].kind.count("tee") == 1
    res = st.build_along_network([lines[i] for i in groups[2]], bp.terrace_library())
    assert shapely.symmetric_difference(shapely.union_all(res.geometry),
                                        wings_area([lines[3], lines[4]], 12.0)).area < 1e-6
