"""The simulated UR10e's joint trajectory controller (motion.jtc), driven with a fake clock."""

import math

import numpy as np
import pytest

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.motion.jtc import (
    UR10E_JOINT_NAMES,
    UR10E_VELOCITY_LIMITS_RAD_S,
    ErrorCode,
    GoalEnd,
    GoalRejected,
    JointTolerance,
    JointTrajectoryController,
    PlacementRefused,
    TrajectoryGoal,
    TrajectoryPoint,
    resolve_initial_state,
)

#: integration_test.py's joint order: elbow first
TEST_ORDER = [
    "elbow_joint",
    "shoulder_lift_joint",
    "shoulder_pan_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
DT = 0.002  # the driver's 500 Hz loop


def goal(values, times, names=TEST_ORDER, **kw):
    points = [TrajectoryPoint([v] * 6 if np.isscalar(v) else list(v), t) for v, t in zip(values, times, strict=True)]
    return TrajectoryGoal(names, points, **kw)


class Run:
    """A controller with a fake clock."""

    def __init__(self, start=(0.3, -1.2, 1.0, 0.0, 0.5, 0.0), **kw):
        self.t = 0.0
        self.c = JointTrajectoryController(start, **kw)
        self.log = []  # (t, positions)

    def step(self, seconds, dt=DT):
        ended = []
        for _ in range(round(seconds / dt)):
            self.t += dt
            ended += self.c.update(self.t)
            self.log.append((self.t, self.c.positions()))
        return ended

    def until_end(self, goal_id, limit_s=60.0, dt=DT):
        stop = self.t + limit_s
        while self.t < stop:
            self.t += dt
            for outcome in self.c.update(self.t):
                if outcome.goal_id == goal_id:
                    return outcome
        raise AssertionError("goal did not end")

    def send(self, g):
        goal_id, ended = self.c.accept(g, self.t)
        assert ended == []
        return goal_id


def test_integration_test_cases_a_to_d():
    run = Run()
    # (a) from wherever the robot is, through 0, -0.5, -1.0
    a = run.send(goal([0.0, -0.5, -1.0], [6.0, 9.0, 12.0]))
    outcome = run.until_end(a)
    assert (outcome.end, outcome.code) == (GoalEnd.SUCCEEDED, ErrorCode.SUCCESSFUL)
    assert 12.0 <= run.t < 12.6
    np.testing.assert_allclose(run.c.positions(), -1.0, atol=0.1)
    # (b) times not increasing
    with pytest.raises(GoalRejected) as rejected:
        run.c.accept(goal([0.0, -0.5], [6.0, 3.0]), run.t)
    assert rejected.value.code is ErrorCode.INVALID_GOAL
    assert "not strictly increasing in time" in rejected.value.reason
    # (c) 1 rad in 0.5 s: the robot lags, reaches the goal within goal_time 0.6 s
    start = run.t
    c = run.send(goal([0.0, -1.0], [6.0, 6.5]))
    outcome = run.until_end(c)
    assert outcome.end is GoalEnd.SUCCEEDED
    assert 6.5 < run.t - start < 7.1
    # (d) the same with goal_time_tolerance 0.01 s
    start = run.t
    d = run.send(goal([0.0, -1.0], [6.0, 6.5], goal_time_tolerance_s=0.01))
    outcome = run.until_end(d)
    assert (outcome.end, outcome.code) == (GoalEnd.ABORTED, ErrorCode.GOAL_TOLERANCE_VIOLATED)
    assert "goal error" in outcome.text
    assert run.t - start == pytest.approx(6.51, abs=0.01)


def test_joint_order_is_mapped_by_name():
    run = Run(start=(0.0,) * 6)
    target = {name: 0.1 * (i + 1) for i, name in enumerate(TEST_ORDER)}
    g = run.send(goal([[target[n] for n in TEST_ORDER]], [1.0]))
    assert run.until_end(g).end is GoalEnd.SUCCEEDED
    run.step(0.5)
    expected = [target[n] for n in UR10E_JOINT_NAMES]
    np.testing.assert_allclose(run.c.positions(), expected, atol=1e-4)


@pytest.mark.parametrize(
    ("names", "code"),
    [
        (TEST_ORDER[:5], ErrorCode.INVALID_JOINTS),
        ([*TEST_ORDER[:5], "gripper_joint"], ErrorCode.INVALID_JOINTS),
        ([*TEST_ORDER[:5], "elbow_joint"], ErrorCode.INVALID_JOINTS),
    ],
)
def test_wrong_joint_names_are_invalid_joints(names, code):
    run = Run()
    points = [TrajectoryPoint([0.0] * len(names), 1.0)]
    with pytest.raises(GoalRejected) as rejected:
        run.c.accept(TrajectoryGoal(names, points), run.t)
    assert rejected.value.code is code


@pytest.mark.parametrize(
    ("points", "words"),
    [
        ([], "no waypoints"),
        ([TrajectoryPoint([0.0] * 5, 1.0)], "Size mismatch"),
        ([TrajectoryPoint([0.0] * 6, 1.0, velocities=[0.0] * 3)], "Size mismatch"),
        ([TrajectoryPoint([math.nan] + [0.0] * 5, 1.0)], "not finite"),
        ([TrajectoryPoint([0.0] * 6, 1.0), TrajectoryPoint([0.1] * 6, 1.0)], "not strictly increasing"),
        ([TrajectoryPoint([0.0] * 6, math.inf)], "invalid time_from_start"),
    ],
)
def test_invalid_goals(points, words):
    run = Run()
    before = run.c.positions()
    with pytest.raises(GoalRejected) as rejected:
        run.c.accept(TrajectoryGoal(TEST_ORDER, points), run.t)
    assert rejected.value.code is ErrorCode.INVALID_GOAL
    assert words in rejected.value.reason
    run.step(0.2)
    np.testing.assert_array_equal(run.c.positions(), before)


def test_points_in_the_past_are_rejected():
    run = Run()
    run.step(5.0)
    with pytest.raises(GoalRejected, match="before the current time"):
        run.c.accept(goal([0.0], [1.0], start_s=run.t - 3.0), run.t)


def test_first_point_at_zero_is_dropped_and_the_motion_starts_at_the_desired_state():
    run = Run(start=(0.0,) * 6)
    # a first point far from the robot at t=0: the JTC drops it, no jump
    g = run.send(goal([0.5, 0.2], [0.0, 2.0]))
    run.step(0.1)
    assert np.abs(run.c.positions()).max() < 0.02
    assert run.until_end(g).end is GoalEnd.SUCCEEDED
    np.testing.assert_allclose(run.c.positions(), 0.2, atol=0.1)


def test_linear_interpolation_of_positions_only():
    run = Run(start=(0.0,) * 6, tracking_time_constant_s=0.0)
    run.send(goal([1.0], [2.0]))
    run.step(1.0)
    snapshot = run.c.snapshot()
    np.testing.assert_allclose(snapshot.desired_positions, 0.5, atol=1e-2)
    np.testing.assert_allclose(snapshot.desired_velocities, 0.5, atol=1e-9)
    assert snapshot.time_from_start_s == pytest.approx(1.0, abs=DT)


def test_too_fast_segment_is_followed_at_the_speed_limit_and_violates_the_path_tolerance():
    run = Run(start=(0.0,) * 6)
    g = run.send(goal([0.0, -2.0], [0.01, 0.5]))  # 4 rad/s, the limits are 2.09 / 3.14 rad/s
    run.step(0.08)
    assert run.c.active_goal_id == g
    speeds = np.abs(run.c.velocities())
    limits = np.array([UR10E_VELOCITY_LIMITS_RAD_S[n] for n in UR10E_JOINT_NAMES])
    assert np.all(speeds <= limits + 1e-9)
    np.testing.assert_allclose(speeds, limits, rtol=1e-6)
    outcome = run.until_end(g)
    assert (outcome.end, outcome.code) == (GoalEnd.ABORTED, ErrorCode.PATH_TOLERANCE_VIOLATED)
    assert outcome.text.startswith("shoulder_pan_joint path error ")
    assert abs(float(outcome.text.split()[-1])) > 0.2


def test_erased_path_tolerance_lets_the_slow_robot_finish():
    run = Run(start=(0.0,) * 6)
    erased = [JointTolerance(n, position=-1.0) for n in UR10E_JOINT_NAMES]
    g = run.send(goal([0.0, -2.0], [0.01, 0.5], path_tolerance=erased, goal_time_tolerance_s=2.0))
    assert run.until_end(g).end is GoalEnd.SUCCEEDED


def test_goal_tolerance_override_per_joint():
    run = Run(start=(0.0,) * 6)
    tight = [JointTolerance("wrist_3_joint", position=1e-9, velocity=1e-12)]
    g = run.send(goal([0.0, -1.0], [1.0, 1.5], goal_tolerance=tight, goal_time_tolerance_s=0.05))
    outcome = run.until_end(g)
    assert outcome.code is ErrorCode.GOAL_TOLERANCE_VIOLATED
    assert outcome.text.startswith("wrist_3_joint goal error")


def test_negative_goal_time_tolerance_means_zero():
    run = Run(start=(0.0,) * 6)
    g = run.send(goal([0.0, -1.0], [1.0, 1.5], goal_time_tolerance_s=-1.0))
    start = run.t
    outcome = run.until_end(g)
    assert outcome.code is ErrorCode.GOAL_TOLERANCE_VIOLATED
    assert run.t - start == pytest.approx(1.5, abs=2 * DT)


def test_cancel_preempts_at_once_and_stops_within_the_stop_duration():
    run = Run(start=(0.0,) * 6)
    g = run.send(goal([1.0], [4.0]))
    run.step(2.0)
    ended = run.c.cancel(g, run.t)
    assert [(o.goal_id, o.end) for o in ended] == [(g, GoalEnd.PREEMPTED)]
    at_cancel = run.c.positions()
    run.step(1.0)
    stopped = run.c.positions()
    # 0.25 rad/s braked evenly in 0.5 s: about 0.0625 rad further
    np.testing.assert_allclose(stopped - at_cancel, 0.0625, atol=0.01)
    run.step(0.5)
    np.testing.assert_allclose(run.c.positions(), stopped, atol=1e-6)
    assert run.c.active_goal_id is None


def test_a_new_goal_preempts_the_active_one():
    run = Run(start=(0.0,) * 6)
    first = run.send(goal([1.0], [4.0]))
    run.step(1.0)
    second, ended = run.c.accept(goal([0.0], [2.0]), run.t)
    assert [(o.goal_id, o.end) for o in ended] == [(first, GoalEnd.PREEMPTED)]
    assert run.until_end(second).end is GoalEnd.SUCCEEDED


def test_speed_scaling_stretches_the_trajectory_time():
    durations = []
    for slider in (1.0, 0.3):
        run = Run(start=(0.0,) * 6)
        assert run.c.set_speed_slider(slider)
        assert run.c.speed_scaling == pytest.approx(slider)
        g = run.send(goal([0.5], [2.0]))
        run.until_end(g)
        durations.append(run.t)
    assert durations[1] / durations[0] == pytest.approx(1 / 0.3, rel=0.05)


@pytest.mark.parametrize("fraction", [0.0, 1.5, -0.2, math.nan])
def test_speed_slider_outside_its_range_is_refused(fraction):
    run = Run()
    assert not run.c.set_speed_slider(fraction)
    assert run.c.speed_slider_fraction == 1.0


def test_stopped_program_preempts_and_rejects_until_it_runs_again():
    run = Run(start=(0.0,) * 6)
    g = run.send(goal([1.0], [4.0]))
    run.step(1.0)
    ended = run.c.set_program_running(False, run.t)
    assert [(o.goal_id, o.end) for o in ended] == [(g, GoalEnd.PREEMPTED)]
    halted = run.c.positions()
    run.step(0.5)
    np.testing.assert_allclose(run.c.positions(), halted, atol=1e-9)
    assert run.c.speed_scaling == 0.0
    with pytest.raises(GoalRejected) as rejected:
        run.c.accept(goal([0.0], [1.0]), run.t)
    assert rejected.value.code is ErrorCode.INVALID_GOAL
    run.c.set_program_running(True, run.t)
    g = run.send(goal([0.0], [1.0]))
    assert run.until_end(g).end is GoalEnd.SUCCEEDED


def test_protective_stop_halts_and_needs_unlock_and_play():
    run = Run(start=(0.0,) * 6)
    g = run.send(goal([1.0], [4.0]))
    run.step(1.0)
    ended = run.c.protective_stop(run.t)
    assert [(o.goal_id, o.end) for o in ended] == [(g, GoalEnd.PREEMPTED)]
    halted = run.c.positions()
    run.step(0.5)
    np.testing.assert_array_equal(run.c.positions(), halted)
    with pytest.raises(GoalRejected):
        run.c.accept(goal([0.0], [1.0]), run.t)
    with pytest.raises(PlacementRefused, match="protective"):
        run.c.set_program_running(True, run.t)
    assert run.c.unlock_protective_stop()
    with pytest.raises(GoalRejected):
        run.c.accept(goal([0.0], [1.0]), run.t)  # the program is still stopped
    run.c.set_program_running(True, run.t)
    g = run.send(goal([0.0], [1.0]))
    assert run.until_end(g).end is GoalEnd.SUCCEEDED


def test_place_moves_at_once_and_is_refused_while_a_goal_runs():
    run = Run(start=(0.0,) * 6)
    run.c.place([0.1] * 6)
    run.step(0.1)
    np.testing.assert_allclose(run.c.positions(), 0.1)
    run.send(goal([1.0], [4.0]))
    with pytest.raises(PlacementRefused, match="executing"):
        run.c.place([0.0] * 6)
    with pytest.raises(PlacementRefused):
        JointTrajectoryController([0.0] * 5)


def test_feedback_snapshot_has_desired_actual_error():
    run = Run(start=(0.0,) * 6)
    run.send(goal([1.0], [2.0]))
    run.step(1.0)
    snap = run.c.snapshot()
    np.testing.assert_allclose(snap.error_positions, snap.desired_positions - snap.actual_positions)
    assert snap.goal_id is not None
    assert 0.0 < snap.error_positions[0] < 0.2  # the robot lags the desired position


def test_resolve_initial_state():
    named = {"home": np.zeros(6)}
    np.testing.assert_array_equal(resolve_initial_state("home", named, 6), np.zeros(6))
    np.testing.assert_array_equal(resolve_initial_state([0.1] * 6, named, 6), [0.1] * 6)
    with pytest.raises(ConfigError):
        resolve_initial_state("nowhere", named, 6)
    with pytest.raises(ConfigError):
        resolve_initial_state([0.1] * 5, named, 6)
