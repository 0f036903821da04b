"""Tests of the viewpoint-selection set cover (agiprobot_measurement.planning.cover.solve)."""

import itertools
import time

import numpy as np
import pytest
from scipy import sparse

from agiprobot_measurement.planning.cover import columns as cover_columns
from agiprobot_measurement.planning.cover import greedy as cover_greedy
from agiprobot_measurement.planning.cover import reduction as cover_reduction
from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES, SetCoverError, solve_set_cover
from agiprobot_measurement.testing.set_cover_instances import cube_instance, random_instance

IP_SOLVERS = ("IP_basic", "IP_uncertainty", "IP_time")


def _mask(matrix) -> np.ndarray:
    dense = matrix.toarray() if sparse.issparse(matrix) else np.asarray(matrix)
    return (dense != 0) & ~np.isnan(dense.astype(float))


def _brute_force(mask: np.ndarray, costs: np.ndarray) -> float:
    """Cheapest cover of the coverable rows over all subsets of columns (small instances only)."""
    n_cols = mask.shape[1]
    coverable = mask.any(axis=1)
    col_bits = [int(sum(1 << i for i in np.nonzero(mask[:, j])[0])) for j in range(n_cols)]
    target = int(sum(1 << i for i in np.nonzero(coverable)[0]))
    best = np.inf
    for subset in range(1 << n_cols):
        bits, cost = 0, 0.0
        for j in range(n_cols):
            if subset >> j & 1:
                bits |= col_bits[j]
                cost += costs[j]
        if bits & target == target:
            best = min(best, cost)
    return best


def _min_count(mask: np.ndarray) -> int:
    coverable = mask.any(axis=1)
    for k in range(mask.shape[1] + 1):
        for subset in itertools.combinations(range(mask.shape[1]), k):
            if np.all(mask[:, list(subset)].any(axis=1) | ~coverable):
                return k
    raise AssertionError("unreachable")


def _assert_valid_cover(result, matrix):
    mask = _mask(matrix)
    coverable = mask.any(axis=1)
    assert np.all(np.diff(result.selected) > 0)
    covered = mask[:, result.selected].any(axis=1) if result.selected.size else np.zeros(mask.shape[0], bool)
    np.testing.assert_array_equal(result.covered, covered)
    np.testing.assert_array_equal(result.covered, coverable)
    assert result.n_coverable == int(coverable.sum())
    assert result.covers_all_coverable
    np.testing.assert_array_equal(result.uncoverable, np.nonzero(~coverable)[0])


def _naive_greedy(mask: np.ndarray, tie: np.ndarray) -> list[int]:
    """Reference greedy: recompute every gain every step."""
    covered = ~mask.any(axis=1)
    picks = []
    while not covered.all():
        gains = (mask & ~covered[:, None]).sum(axis=0)
        best = max(range(mask.shape[1]), key=lambda j: (gains[j], -tie[j], -j))
        picks.append(best)
        covered |= mask[:, best]
    return picks


# ---------------------------------------------------------------------------------------------------------
# Validity and optimality


@pytest.fixture(scope="module")
def small_cube():
    return cube_instance(n_points=300, n_orientations=6, valid_fraction=0.6, seed=3)


@pytest.mark.parametrize("solver_type", SOLVER_TYPES)
def test_every_solver_covers_every_coverable_point(solver_type, small_cube):
    for matrix, durations in [
        (small_cube.matrix, small_cube.durations_s),
        *[
            (inst.matrix, inst.durations_s)
            for inst in (random_instance(40, 30, 0.1, seed=s, uncoverable=3) for s in range(3))
        ],
    ]:
        result = solve_set_cover(matrix, solver_type, durations_s=durations)
        _assert_valid_cover(result, matrix)
        if solver_type != "greedy":
            assert result.proven_optimal and result.gap == 0.0


@pytest.mark.parametrize("seed", range(12))
def test_ip_basic_equals_brute_force(seed):
    inst = random_instance(14, 11, density=0.22, seed=seed, uncoverable=seed % 3)
    expected = _min_count(_mask(inst.matrix))
    for reduce in (True, False):
        result = solve_set_cover(inst.matrix, "IP_basic", reduce=reduce)
        _assert_valid_cover(result, inst.matrix)
        assert result.n_selected == expected == result.objective
        assert result.proven_optimal and result.gap == 0.0
        assert result.lower_bound == pytest.approx(expected)


@pytest.mark.parametrize("seed", range(8))
def test_weighted_ips_equal_brute_force(seed):
    inst = random_instance(12, 10, density=0.3, seed=100 + seed)
    mask = _mask(inst.matrix)
    worst = np.where(mask, inst.matrix.toarray(), 0.0).max(axis=0)
    for solver_type, costs in (("IP_time", inst.durations_s), ("IP_uncertainty", worst)):
        expected = _brute_force(mask, costs)
        for reduce in (True, False):
            result = solve_set_cover(inst.matrix, solver_type, durations_s=inst.durations_s, reduce=reduce)
            _assert_valid_cover(result, inst.matrix)
            assert result.objective == pytest.approx(expected, rel=1e-9)
            assert result.objective == pytest.approx(costs[result.selected].sum())
            assert result.proven_optimal


def test_cbc_backend_agrees_with_highs():
    for seed in range(4):
        inst = random_instance(30, 25, density=0.12, seed=200 + seed)
        for solver_type in IP_SOLVERS:
            kw = {"durations_s": inst.durations_s}
            highs = solve_set_cover(inst.matrix, solver_type, backend="highs", **kw)
            cbc = solve_set_cover(inst.matrix, solver_type, backend="cbc", reduce=False, **kw)
            _assert_valid_cover(cbc, inst.matrix)
            assert cbc.objective == pytest.approx(highs.objective, rel=1e-9)
            assert cbc.solver == f"{solver_type}/cbc"


def test_weighted_objectives_differ_from_the_smallest_cover():
    # Points 0-3. View 0 and view 3 each cover everything (one view), views 1 and 2 cover halves.
    #            view:   0     1     2     3
    covers = np.array(
        [
            [1, 1, 0, 1],
            [1, 1, 0, 1],
            [1, 0, 1, 1],
            [1, 0, 1, 1],
        ],
        dtype=bool,
    )
    worst = np.array([0.9, 0.1, 0.1, 0.95])
    uncertainty = sparse.csc_array(covers * worst[None, :])
    durations = np.array([10.0, 2.0, 2.0, 3.0])

    basic = solve_set_cover(uncertainty, "IP_basic", durations_s=durations)
    assert basic.n_selected == 1
    timed = solve_set_cover(uncertainty, "IP_time", durations_s=durations)
    assert timed.selected.tolist() == [3] and timed.objective == pytest.approx(3.0)
    certain = solve_set_cover(uncertainty, "IP_uncertainty", durations_s=durations)
    assert certain.selected.tolist() == [1, 2] and certain.objective == pytest.approx(0.2)
    # The same costs given separately from a boolean matrix, per view and per entry.
    assert solve_set_cover(covers, "IP_uncertainty", uncertainties=worst).selected.tolist() == [1, 2]
    assert solve_set_cover(covers, "IP_uncertainty", uncertainties=uncertainty).selected.tolist() == [1, 2]


# ---------------------------------------------------------------------------------------------------------
# Greedy


def test_greedy_tie_break_prefers_lower_uncertainty():
    # Views 0 and 1 both cover three new points first. View 1 has the lower worst uncertainty, so greedy
    # takes it and then needs view 2 for point 0: {1, 2}. Taking view 0 first leaves point 3, which views 1
    # and 3 tie on: view 3 when it is the more certain one ({0, 3}), view 1 by index without uncertainties.
    covers = np.array(
        [
            [1, 0, 1, 0],
            [1, 1, 0, 0],
            [1, 1, 0, 0],
            [0, 1, 0, 1],
        ],
        dtype=bool,
    )
    low_on_1 = sparse.csc_array(covers * np.array([0.5, 0.1, 0.3, 0.3])[None, :])
    assert solve_set_cover(low_on_1, "greedy").selected.tolist() == [1, 2]
    low_on_0 = sparse.csc_array(covers * np.array([0.1, 0.5, 0.3, 0.3])[None, :])
    assert solve_set_cover(low_on_0, "greedy").selected.tolist() == [0, 3]
    # Per-view uncertainties given separately; without any, the lower index wins.
    assert solve_set_cover(covers, "greedy", uncertainties=[0.5, 0.1, 0.3, 0.3]).selected.tolist() == [1, 2]
    assert solve_set_cover(covers, "greedy").selected.tolist() == [0, 1]


def test_greedy_tie_break_uses_the_worst_point_of_a_view():
    # View 0: uncertainties 0.05 and 0.4 (worst 0.4); view 1: 0.2 and 0.2 (worst 0.2) -> view 1.
    matrix = sparse.csc_array(np.array([[0.05, 0.2], [0.4, 0.2]]))
    assert solve_set_cover(matrix, "greedy").selected.tolist() == [1]


@pytest.mark.parametrize("seed", range(10))
def test_lazy_greedy_matches_naive_greedy(seed):
    rng = np.random.default_rng(seed)
    mask = rng.random((60, 80)) < 0.08
    # Few distinct uncertainty values and equal-sized columns make ties common.
    tie = rng.choice([0.1, 0.2, 0.3], 80)
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    n_coverable = int(mask.any(axis=1).sum())
    assert cover_greedy.greedy_cover(cols, tie, n_coverable) == _naive_greedy(mask, tie)


def test_greedy_selection_is_irredundant(small_cube):
    result = solve_set_cover(small_cube.matrix, "greedy")
    mask = _mask(small_cube.matrix)[:, result.selected]
    counts = mask.sum(axis=1)
    for j in range(mask.shape[1]):
        assert np.any(counts[mask[:, j]] == 1), "a selected view covers nothing on its own"


# ---------------------------------------------------------------------------------------------------------
# Reductions


def _instance_with_dominance(seed: int) -> tuple[sparse.csc_array, np.ndarray]:
    """Random columns plus duplicates and subsets of them at various costs."""
    rng = np.random.default_rng(seed)
    base = rng.random((14, 6)) < 0.35
    extra = []
    for j in range(6):
        extra.append(base[:, j].copy())  # duplicate
        sub = base[:, j] & (rng.random(14) < 0.6)  # subset
        if sub.any():
            extra.append(sub)
    mask = np.column_stack([base, *extra])
    perm = rng.permutation(mask.shape[1])[:11]
    return sparse.csc_array(mask[:, perm]), rng.choice([1.0, 2.0, 3.0], perm.size)


@pytest.mark.parametrize("seed", range(10))
def test_duplicate_and_dominated_removal_keeps_optimality(seed):
    matrix, durations = _instance_with_dominance(seed)
    mask = _mask(matrix)
    expected_count = _min_count(mask)
    expected_time = _brute_force(mask, durations)
    stats_seen = 0
    for solver_type, expected in (("IP_basic", expected_count), ("IP_time", expected_time)):
        result = solve_set_cover(matrix, solver_type, durations_s=durations)
        _assert_valid_cover(result, matrix)
        assert result.objective == pytest.approx(expected)
        stats_seen += result.stats["duplicate_cols"] + result.stats["dominated_cols"]
    assert stats_seen > 0


def _naive_dominated(mask: np.ndarray, costs: np.ndarray) -> np.ndarray:
    n = mask.shape[1]
    out = np.zeros(n, dtype=bool)
    for a in range(n):
        for b in range(n):
            subset = not np.any(mask[:, a] & ~mask[:, b])
            strict = mask[:, b].sum() > mask[:, a].sum()
            if a != b and subset and strict and costs[b] <= costs[a]:
                out[a] = True
    return out


@pytest.mark.parametrize("seed", range(8))
def test_dominated_columns_match_naive_check(seed):
    rng = np.random.default_rng(seed)
    # Nested random sets (subsets of a few big ones) and enough columns to span several pool words.
    big = rng.random((90, 8)) < 0.5
    cols = [big[:, rng.integers(8)] & (rng.random(90) < rng.uniform(0.3, 1.0)) for _ in range(300)]
    mask = np.column_stack([c for c in cols if c.any()])
    costs = rng.choice([1.0, 1.5, 2.0], mask.shape[1]) if seed % 2 else np.ones(mask.shape[1])
    columns, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    dup = cover_reduction.duplicate_columns(columns, np.lexsort((np.arange(mask.shape[1]), costs)))
    keep = np.nonzero(~dup)[0]
    dominated, complete = cover_reduction.dominated_columns(columns.take(keep), costs[keep], time.perf_counter() + 60)
    assert complete
    np.testing.assert_array_equal(dominated, _naive_dominated(mask[:, keep], costs[keep]))


def test_duplicates_and_implied_rows_match_naive_check():
    rng = np.random.default_rng(7)
    mask = rng.random((40, 25)) < 0.3
    mask[:, 5] = mask[:, 3]
    mask[:, 9] = mask[:, 3]
    mask = mask[:, mask.any(axis=0)]
    columns, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    dup = cover_reduction.duplicate_columns(columns, np.arange(columns.n_cols))
    expected = [any(np.array_equal(mask[:, i], mask[:, j]) for i in range(j)) for j in range(mask.shape[1])]
    np.testing.assert_array_equal(dup, expected)

    rows = mask[mask.any(axis=1)]
    row_sets = cover_columns.measurable_columns(sparse.csc_array(rows.T))[0]
    candidates = np.nonzero(~cover_reduction.duplicate_columns(row_sets, np.arange(row_sets.n_cols)))[0]
    implied, complete = cover_reduction.implied_rows(row_sets, candidates, time.perf_counter() + 60)
    assert complete
    for b in range(rows.shape[0]):
        strict_subset_exists = any(
            a != b
            and a in candidates
            and b in candidates
            and rows[a].sum() < rows[b].sum()
            and not np.any(rows[a] & ~rows[b])
            for a in range(rows.shape[0])
        )
        assert implied[b] == strict_subset_exists


def test_forced_views_are_taken():
    # Point 0 is seen only by view 2: the reductions force it; the rest is left to the programme.
    covers = np.array([[0, 0, 1, 0], [1, 0, 1, 0], [0, 1, 0, 1], [1, 1, 0, 0]], dtype=bool)
    result = solve_set_cover(covers, "IP_basic")
    assert 2 in result.selected.tolist()
    assert result.n_selected == _min_count(covers)
    assert result.stats["forced_cols"] >= 1


# ---------------------------------------------------------------------------------------------------------
# Uncoverable points, empty inputs, errors, formats


def test_uncoverable_points_are_reported():
    covers = np.array([[1, 0], [0, 0], [0, 1], [0, 0]], dtype=bool)
    for solver_type in SOLVER_TYPES:
        result = solve_set_cover(covers, solver_type, uncertainties=[0.1, 0.2], durations_s=[1.0, 1.0])
        assert result.uncoverable.tolist() == [1, 3]
        assert result.n_coverable == 2 and result.covers_all_coverable
        assert result.covered.tolist() == [True, False, True, False]
        assert "2 point(s) measurable by no view" in result.message


@pytest.mark.parametrize("shape", [(0, 0), (0, 4), (5, 0), (3, 4)])
@pytest.mark.parametrize("solver_type", SOLVER_TYPES)
def test_empty_or_uncoverable_matrix_gives_empty_selection(shape, solver_type):
    matrix = sparse.csc_array(shape, dtype=bool)
    result = solve_set_cover(matrix, solver_type, uncertainties=np.ones(shape[1]), durations_s=np.ones(shape[1]))
    assert result.n_selected == 0 and result.n_coverable == 0
    assert result.objective == 0.0 and result.proven_optimal
    assert result.covered.shape == (shape[0],) and not result.covered.any()
    assert "no coverable points" in result.message


def test_unknown_solver_type_lists_valid_names():
    with pytest.raises(ValueError) as err:
        solve_set_cover(np.eye(3, dtype=bool), "IP_uncert")
    for name in SOLVER_TYPES:
        assert repr(name) in str(err.value)
    assert "'IP_uncert'" in str(err.value)
    with pytest.raises(ValueError, match="'highs', 'cbc'"):
        solve_set_cover(np.eye(3, dtype=bool), "IP_basic", backend="gurobi")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"solver_type": "IP_time"}, "durations_s"),
        ({"solver_type": "IP_time", "durations_s": [1.0, 2.0]}, "one value per view"),
        ({"solver_type": "IP_time", "durations_s": [1.0, -2.0, 1.0]}, "non-negative"),
        ({"solver_type": "IP_uncertainty"}, "uncertainties"),
        ({"solver_type": "greedy", "uncertainties": [0.1, np.nan, 0.1]}, "finite"),
        ({"solver_type": "greedy", "uncertainties": np.ones((2, 3))}, "shape"),
        ({"solver_type": "IP_basic", "time_limit_s": 0.0}, "time_limit_s"),
    ],
)
def test_invalid_arguments_raise(kwargs, message):
    with pytest.raises(SetCoverError, match=message):
        solve_set_cover(np.eye(3, dtype=bool), **kwargs)


def test_negative_uncertainty_in_matrix_raises():
    with pytest.raises(SetCoverError, match="non-negative"):
        solve_set_cover(np.array([[0.1, -0.2], [0.0, 0.3]]), "greedy")


def test_input_formats_agree():
    inst = random_instance(30, 20, density=0.15, seed=5)
    dense = inst.matrix.toarray()
    with_nan = np.where(dense == 0, np.nan, dense)  # NaN marks "not measurable" too
    coo = sparse.coo_array(inst.matrix)
    duplicated = sparse.coo_array(
        (np.concatenate([coo.data, coo.data * 0.5]), (np.tile(coo.row, 2), np.tile(coo.col, 2))),
        shape=coo.shape,
    )
    reference = solve_set_cover(inst.matrix, "IP_basic")
    for matrix in (dense, with_nan, sparse.csr_matrix(dense), coo, duplicated, dense != 0):
        result = solve_set_cover(matrix, "IP_basic")
        assert result.n_selected == reference.n_selected
        _assert_valid_cover(result, dense)
    greedy = solve_set_cover(inst.matrix, "greedy")
    assert solve_set_cover(sparse.csr_array(inst.matrix), "greedy").selected.tolist() == greedy.selected.tolist()


def test_caller_matrix_is_not_modified():
    matrix = sparse.csc_array(
        (np.array([0.1, 0.2, 0.3]), np.array([1, 0, 0]), np.array([0, 2, 3])), shape=(2, 2)
    )  # unsorted indices in column 0
    before = (matrix.data.copy(), matrix.indices.copy(), matrix.indptr.copy())
    solve_set_cover(matrix, "IP_basic")
    for a, b in zip(before, (matrix.data, matrix.indices, matrix.indptr), strict=True):
        np.testing.assert_array_equal(a, b)


def test_time_limit_returns_a_cover_with_its_gap():
    inst = random_instance(150, 400, density=0.03, seed=11)
    result = solve_set_cover(inst.matrix, "IP_time", durations_s=inst.durations_s, time_limit_s=0.05)
    _assert_valid_cover(result, inst.matrix)
    if not result.proven_optimal:
        assert result.gap is None or result.gap > 0.0


def test_mip_gap_is_respected():
    inst = random_instance(80, 120, density=0.05, seed=12)
    exact = solve_set_cover(inst.matrix, "IP_time", durations_s=inst.durations_s)
    loose = solve_set_cover(inst.matrix, "IP_time", durations_s=inst.durations_s, mip_gap=0.05)
    _assert_valid_cover(loose, inst.matrix)
    assert loose.objective <= exact.objective * 1.05 + 1e-9
    assert loose.gap is not None and loose.gap <= 0.05 + 1e-9


# ---------------------------------------------------------------------------------------------------------
# Realistic instance (the original's cube benchmark size)


@pytest.fixture(scope="module")
def cube_9k():
    return cube_instance()


def test_realistic_instance(cube_9k):
    assert 1500 == cube_9k.n_points and 8000 < cube_9k.n_views < 10000
    greedy = solve_set_cover(cube_9k.matrix, "greedy")
    basic = solve_set_cover(cube_9k.matrix, "IP_basic", time_limit_s=60)
    _assert_valid_cover(greedy, cube_9k.matrix)
    _assert_valid_cover(basic, cube_9k.matrix)
    assert basic.proven_optimal and basic.gap == 0.0
    assert basic.n_selected <= greedy.n_selected
    # Targets are 1 s and 10 s; the bounds here only catch gross regressions on a loaded test machine.
    assert greedy.solve_time_s < 5.0
    assert basic.solve_time_s < 30.0


def test_restrict_matches_the_dense_submatrix():
    rng = np.random.default_rng(11)
    for trial in range(20):
        mask = rng.random((int(rng.integers(1, 60)), int(rng.integers(1, 40)))) < rng.uniform(0.05, 0.6)
        columns, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
        row_keep = rng.random(mask.shape[0]) < (1.0 if trial % 5 == 0 else 0.6)
        which = rng.permutation(mask.shape[1])[: int(rng.integers(0, mask.shape[1] + 1))]
        got = cover_reduction.restrict(columns, row_keep, which)
        expected = mask[row_keep][:, which]
        assert got.n_rows == expected.shape[0] and got.n_cols == which.size
        for k in range(which.size):
            np.testing.assert_array_equal(got.col(k), np.flatnonzero(expected[:, k]))
