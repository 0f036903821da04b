"""The batched scan-line verification agrees with the one-line-at-a-time check on random lines: same verdicts,
same accepted scan-line ranges, same kept points, the same joint paths."""

import copy

import numpy as np
import pytest

from agiprobot_measurement.motion import cartesian_batch
from agiprobot_measurement.motion.cartesian_kernels import follow_paths
from agiprobot_measurement.planning.candidates.mechanics import check_scan_line, check_scan_lines
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def cube_views():
    manager = TrajectoryManager(seed=5)
    manager.load_target_mesh(str(CUBE))
    # tilted views of the cube's sides start low: some collide with the fixture or the table, some are shortened
    _, views = manager.generate_samples_and_viewpoints(0.004, 0.1, 4, "full")
    return manager, views


def _check_both(manager, views, indices, settings=None):
    settings = settings or manager.run.mechanics
    kw = dict(ik=manager.ik, collision=manager.collision, preferred_state=manager.preferred_state, scan_speed_mm_s=50.0)
    one = [copy.deepcopy(views[i]) for i in indices]
    many = [copy.deepcopy(views[i]) for i in indices]
    one_paths = [check_scan_line(v, settings, **kw) for v in one]
    many_paths = check_scan_lines(many, settings, chunk=37, **kw)
    return one, many, one_paths, many_paths


def _assert_same(one, many, one_paths, many_paths):
    for a, b, p, q in zip(one, many, one_paths, many_paths, strict=True):
        assert (p is None) == (q is None)
        assert a.mechanics_verified and b.mechanics_verified and a.mechanics_valid == b.mechanics_valid
        if p is None:
            continue
        assert b.scan_line == pytest.approx(a.scan_line, abs=1e-9)
        assert np.array_equal(a.measurable_indices, b.measurable_indices)
        assert b.estimated_duration_s == pytest.approx(a.estimated_duration_s)
        assert p.shape == q.shape
        np.testing.assert_allclose(q, p, atol=1e-6)


def test_batched_verification_agrees_with_one_line_at_a_time(cube_views):
    manager, views = cube_views
    rng = np.random.default_rng(11)
    indices = rng.choice(len(views), size=min(240, len(views)), replace=False)
    one, many, one_paths, many_paths = _check_both(manager, views, indices)
    _assert_same(one, many, one_paths, many_paths)
    valid = np.array([p is not None for p in one_paths])
    shortened = np.array([p is not None and len(a.measurable_indices) < len(views[i].measurable_indices)
                          for a, p, i in zip(one, one_paths, indices, strict=True)])  # fmt: skip
    # not vacuous: both verdicts occur, and some accepted lines were shortened (partial acceptance)
    assert valid.sum() >= 20 and (~valid).sum() >= 5
    assert shortened.sum() >= 1


def test_batched_verification_agrees_when_every_line_takes_the_exact_walk(cube_views, monkeypatch):
    # a margin beyond pi makes the continuation give up on every line: all go through the closed-form branches
    manager, views = cube_views
    monkeypatch.setattr(cartesian_batch, "TRACK_MARGIN_RAD", 10.0)
    indices = np.random.default_rng(12).choice(len(views), size=min(80, len(views)), replace=False)
    _assert_same(*_check_both(manager, views, indices))


def test_batched_verification_agrees_with_a_small_jump_threshold(cube_views):
    # a tight jump threshold makes many lines stop early (joint jumps): the attempts in both directions and all
    # branches are compared
    manager, views = cube_views
    settings = dict(manager.run.mechanics, joint_jump_threshold=0.02)
    indices = np.random.default_rng(13).choice(len(views), size=min(80, len(views)), replace=False)
    one, many, one_paths, many_paths = _check_both(manager, views, indices, settings)
    _assert_same(one, many, one_paths, many_paths)


def test_a_line_whose_first_branch_fails_is_run_on_another_branch_or_direction(cube_views, monkeypatch):
    """Lines whose first attempt (the start branch nearest the preferred state, first direction) stops short are
    tried on the next branches and the other direction: some run completely there, and the one-line check agrees."""
    from agiprobot_measurement.planning.candidates import mechanics

    manager, views = cube_views
    rounds = []
    real = mechanics.compute_cartesian_paths

    def recorded(*args, **kwargs):
        paths = real(*args, **kwargs)
        rounds.append(paths.fractions.copy())
        return paths

    monkeypatch.setattr(mechanics, "compute_cartesian_paths", recorded)
    settings = dict(manager.run.mechanics, joint_jump_threshold=0.05)
    indices = np.random.default_rng(14).choice(len(views), size=min(120, len(views)), replace=False)
    one, many, one_paths, many_paths = _check_both(manager, views, indices, settings)
    _assert_same(one, many, one_paths, many_paths)
    # the first round's short lines, and lines completed in a later round (another branch or the other direction)
    assert len(rounds) >= 2 and (rounds[0] < 1.0).sum() >= 3
    assert any((later >= 1.0).any() for later in rounds[1:])


@pytest.mark.parametrize("stride", [1, 3, 8, 1000])
def test_coarse_first_collision_check_cuts_paths_where_checking_every_state_does(cube_views, monkeypatch, stride):
    """The batch checks every stride-th state first and then only the states before each path's first invalid one:
    the cuts equal those of one check of every state, for a checker that rejects states at random."""
    manager, _ = cube_views
    monkeypatch.setattr(cartesian_batch, "COARSE_STRIDE", stride)
    rng = np.random.default_rng(14)
    picked = range(60)
    starts_q = np.array([manager.preferred_state] * len(picked))
    targets = manager.ik.model.fk(starts_q)
    targets[:, :3, 3] += rng.normal(0.0, 0.1, size=(len(picked), 3))

    def checker(q):  # a state is invalid when a hash of it falls below 5 %: invalid states spread along the paths
        return np.abs(np.sin(q @ np.arange(1.0, q.shape[1] + 1.0) * 1e3)) > 0.05

    calls = []

    def counting(q):
        calls.append(len(q))
        return checker(q)

    free = cartesian_batch.compute_cartesian_paths(manager.ik, starts_q, targets, step_mm=2.0)
    checked = cartesian_batch.compute_cartesian_paths(manager.ik, starts_q, targets, step_mm=2.0,
                                                      validity_checker=counting)  # fmt: skip
    cut = 0
    for k in range(len(picked)):
        path = free.joint_path(k)
        ok = checker(path)
        first_bad = int(np.argmin(ok)) if not ok.all() else len(path)
        np.testing.assert_array_equal(checked.joint_path(k), path[:first_bad])
        cut += first_bad < len(path)
    assert cut >= 10  # not vacuous: many paths are cut
    if 1 < stride < 100:
        assert sum(calls) < len(free.states)  # the states after a coarse cut were never checked


def _walk_over_every_branch(ik, starts_q, targets, step_mm, jump_rad):
    """The reference: every waypoint's closed-form branches, the nearest-branch walk over each whole path."""
    poses, offsets = cartesian_batch.line_poses(ik.model.fk(starts_q), targets, step_mm * 1e-3, 0.05)
    solutions, valid = ik.solve_all(poses, np.repeat(starts_q, np.diff(offsets), axis=0))
    solutions = np.where(valid[..., None], solutions, 0.0)
    lower, upper = np.asarray(ik.model.lower, dtype=float), np.asarray(ik.model.upper, dtype=float)
    states, counts, codes = follow_paths(solutions, valid, offsets, starts_q, jump_rad, lower, upper)
    kept = np.concatenate([np.arange(c + 1) + offsets[i] + i for i, c in enumerate(counts)])
    return states[kept], codes


@pytest.mark.parametrize(
    ("elbow_rad", "tracked_share"),
    [((0.4, 0.9), 0.5), ((-0.35, 0.1), 0.6)],
    ids=["bent_elbow", "stretched_elbow"],
)
def test_tracked_paths_equal_the_walk_over_every_branch(cube_views, monkeypatch, elbow_rad, tracked_share):
    """Paths whose elbow's mirror branch lies within the jump threshold (|q3| 0.4-0.9 rad), and paths of a nearly
    stretched arm (q3 -0.35 to 0.1 rad, the elbow's upper limit: the mirror solved for, lines leaving the workspace,
    a joint at its limit) are tracked by continuation as far as it can show the walk's choice, and walked over every
    closed-form branch from there: they end where the walk over every branch of every waypoint ends them."""
    manager, _ = cube_views
    ik = manager.ik
    rng = np.random.default_rng(15)
    n = 120
    starts_q = np.tile(manager.preferred_state, (n, 1)) + rng.normal(0.0, 0.3, size=(n, 6))
    lo, hi = elbow_rad
    starts_q[:, 2] = rng.uniform(lo, hi, size=n) * (rng.choice([-1.0, 1.0], size=n) if lo > 0 else 1.0)
    starts_q = np.clip(starts_q, ik.model.lower, ik.model.upper)
    targets = ik.model.fk(starts_q)
    targets[:, :3, 3] += rng.normal(0.0, 0.08, size=(n, 3))
    runs = []
    track = cartesian_batch.track_paths

    def recording(*args):
        out = track(*args)
        runs.append((out[1].copy(), out[2].copy()))
        return out

    monkeypatch.setattr(cartesian_batch, "track_paths", recording)
    tracked = cartesian_batch.compute_cartesian_paths(ik, starts_q, targets, step_mm=2.0, jump_threshold_rad=1.5)
    states, codes = _walk_over_every_branch(ik, starts_q, targets, 2.0, 1.5)
    np.testing.assert_array_equal(tracked.stop_codes, codes)
    assert len(tracked.states) == len(states)
    # next to the elbow's singularity Newton's state and the refined closed form's differ by ~1e-6 rad
    np.testing.assert_allclose(tracked.states, states, atol=1e-5)
    counts, track_codes = runs[0]
    # not vacuous: most waypoints were settled by the continuation alone, the rest walked on from where it stopped
    settled = np.where(
        track_codes < cartesian_batch.TRACK_EXACT, tracked.offsets[1:] - tracked.offsets[:-1] - 1, counts
    )
    assert settled.sum() > tracked_share * (len(states) - n)
    assert np.any((track_codes >= cartesian_batch.TRACK_EXACT) & (counts > 0))
    if lo < 0:  # the stretched arm: lines that leave the workspace are tracked up to its edge, then end there
        assert np.sum((track_codes >= cartesian_batch.TRACK_EXACT) & (counts > 0) & (tracked.stop_codes == 1)) >= 20
