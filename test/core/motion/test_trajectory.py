"""JointTrajectory interpolation, conversions and the safety checks (check_trajectory, check_continuity)."""

import numpy as np
import pytest

from agiprobot_measurement.motion.trajectory import (
    CheckTolerances,
    JointTrajectory,
    TrajectoryError,
    check_continuity,
    check_trajectory,
    motion_peaks,
)
from agiprobot_measurement.station import load_joint_limits

NAMES = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
START = np.array([0.5, -1.5, -1.5, -1.0, 1.5, 0.0])


@pytest.fixture(scope="module")
def limits():
    return load_joint_limits()


def quintic_move(start, goal, duration_s, count=21) -> JointTrajectory:
    """A rest-to-rest minimum-jerk move with exact velocities and accelerations at the knots."""
    t = np.linspace(0.0, duration_s, count)
    tau = t / duration_s
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    sd = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / duration_s
    sdd = (60 * tau - 180 * tau**2 + 120 * tau**3) / duration_s**2
    delta = np.asarray(goal) - np.asarray(start)
    return JointTrajectory(NAMES, t, start + s[:, None] * delta, sd[:, None] * delta, sdd[:, None] * delta)


@pytest.fixture
def good(limits):
    return quintic_move(START, START + np.array([0.4, -0.2, 0.3, 0.5, -0.4, 0.6]), 3.0)


# ------------------------------------------------------------------------------------- interpolation
def test_interpolation_passes_through_knots(good):
    pos, vel, _ = good.sample(good.time_from_start)
    np.testing.assert_allclose(pos, good.positions, atol=1e-12)
    np.testing.assert_allclose(vel, good.velocities, atol=1e-12)


def test_interpolation_without_velocities_passes_through_knots():
    t = np.array([0.0, 1.0, 2.5, 3.0])
    q = np.outer([0.0, 0.3, 0.2, 0.6], np.ones(6))
    trajectory = JointTrajectory(NAMES, t, q)
    pos, vel, _ = trajectory.sample(t)
    np.testing.assert_allclose(pos, q, atol=1e-12)
    # estimated velocities: zero at the ends and where the path turns (0.3 is a local maximum)
    np.testing.assert_allclose(vel[[0, 1, 3]], 0.0, atol=1e-12)


def test_interpolation_holds_outside_the_time_range(good):
    pos, vel, acc = good.sample(np.array([-1.0, good.duration + 1.0]))
    np.testing.assert_allclose(pos, good.positions[[0, -1]])
    assert np.all(vel == 0.0) and np.all(acc == 0.0)


def test_interpolation_is_smooth_between_knots(good):
    """Between knots the Hermite interpolation of an exact quintic stays close to it."""
    times = np.linspace(0.0, good.duration, 1001)
    pos, _, _ = good.sample(times)
    tau = times / good.duration
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    exact = good.start + s[:, None] * (good.end - good.start)
    assert np.abs(pos - exact).max() < 1e-4


# ------------------------------------------------------------------------------------------- checks
def test_check_accepts_a_good_trajectory(good, limits):
    assert check_trajectory(good, limits)
    assert check_trajectory(good, limits, current_positions=good.start + 1e-3)


def test_check_accepts_a_single_point(limits):
    assert check_trajectory(JointTrajectory(NAMES, [0.0], START[None]), limits)


def test_check_accepts_other_joint_order(good, limits):
    assert check_trajectory(good.reordered(NAMES[::-1]), limits)


def test_check_rejects_non_increasing_time(good, limits):
    t = good.time_from_start.copy()
    t[5] = t[4]
    bad = JointTrajectory(NAMES, t, good.positions, good.velocities, good.accelerations)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "strictly increasing at point 5" in verdict.reason


def test_check_rejects_negative_start_time(good, limits):
    bad = JointTrajectory(NAMES, good.time_from_start - 0.5, good.positions, good.velocities)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "negative" in verdict.reason


@pytest.mark.parametrize("field", ["positions", "velocities", "accelerations", "time_from_start"])
def test_check_rejects_nan(good, limits, field):
    bad = good.copy()
    values = getattr(bad, field)
    if values.ndim == 2:
        values[3, 2] = np.nan
    else:
        values[3] = np.nan
    verdict = check_trajectory(bad, limits)
    assert not verdict and "NaN" in verdict.reason


def test_check_rejects_wrong_joint_names(good, limits):
    names = [*NAMES[:-1], "wrist_4_joint"]
    bad = JointTrajectory(names, good.time_from_start, good.positions, good.velocities)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "wrist_4_joint" in verdict.reason and "wrist_3_joint" in verdict.reason


def test_check_rejects_position_limit_violation(limits):
    start = START.copy()
    start[1] = 0.3  # shoulder_lift upper limit is 0.52
    bad = quintic_move(start, start + np.array([0, 0.4, 0, 0, 0, 0]), 4.0)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "position limit" in verdict.reason and "shoulder_lift_joint" in verdict.reason


def test_check_rejects_position_overshoot_between_knots(limits):
    """Knots inside the limits, but the interpolation between them leaves them: judged densely."""
    q = np.tile(START, (3, 1))
    q[:, 2] = [0.0, 0.1, 0.0]  # elbow upper limit 0.1, reached only at the middle knot
    v = np.zeros_like(q)
    v[0, 2] = 0.5  # the Hermite cubic then rises above 0.1 before the middle knot
    bad = JointTrajectory(NAMES, [0.0, 1.0, 2.0], q, v)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "elbow_joint" in verdict.reason


def test_check_rejects_velocity_violation(limits):
    # 3.0 rad of shoulder_pan (limit 1.8 rad/s) in 2 s: minimum jerk peaks at 1.875 * 3 / 2 = 2.8 rad/s
    bad = quintic_move(START, START + np.array([3.0, 0, 0, 0, 0, 0]), 2.0)
    bad.accelerations = None
    verdict = check_trajectory(bad, limits, tolerances=CheckTolerances(acceleration_fraction=10.0))
    assert not verdict and "velocity limit" in verdict.reason and "shoulder_pan_joint" in verdict.reason


def test_check_rejects_listed_acceleration_violation(good, limits):
    bad = good.copy()
    bad.accelerations[4, 2] = 1.2  # elbow limit 1.0 rad/s^2 (+5 % tolerance)
    verdict = check_trajectory(bad, limits)
    assert not verdict and "acceleration limit" in verdict.reason and "elbow_joint" in verdict.reason


def test_check_rejects_wrong_start(good, limits):
    verdict = check_trajectory(good, limits, current_positions=good.start + np.array([0, 0, 0, 0.1, 0, 0]))
    assert not verdict and "current state" in verdict.reason and "wrist_1_joint" in verdict.reason


def test_check_rejects_empty(limits):
    assert not check_trajectory(JointTrajectory(NAMES, np.zeros(0), np.zeros((0, 6))), limits)


def test_motion_peaks_agree_with_the_check(good, limits):
    vel, acc = motion_peaks(good)
    assert np.all(acc == np.abs(good.accelerations).max(axis=0))
    # scaled so one joint sits 2 % above its velocity limit: the check (1 % tolerance) must reject it
    ratio = float(np.max(vel / limits.max_velocity))
    fast = good.time_scaled(ratio / 1.02)
    fast.accelerations = None
    assert np.max(motion_peaks(fast)[0] / limits.max_velocity) == pytest.approx(1.02)
    tolerances = CheckTolerances(acceleration_fraction=100.0)
    assert not check_trajectory(fast, limits, tolerances=tolerances)
    assert check_trajectory(good.time_scaled(ratio / 1.005), limits, tolerances=tolerances)


# --------------------------------------------------------------------------------------- continuity
def test_continuity(good):
    following = quintic_move(good.end, good.end + 0.1, 1.0)
    assert check_continuity(good, following)
    assert check_continuity(good, following.reordered(NAMES[::-1]))
    jump = quintic_move(good.end + np.array([0, 0, 0.01, 0, 0, 0]), good.end, 1.0)
    verdict = check_continuity(good, jump)
    assert not verdict and "elbow_joint" in verdict.reason
    assert check_continuity(good, jump, tolerance_rad=0.02)


# ----------------------------------------------------------------------------- editing and conversions
def test_time_scaled_scales_peaks_exactly(good):
    vel, acc = motion_peaks(good)
    slow = good.time_scaled(2.0)
    assert slow.duration == pytest.approx(2 * good.duration)
    vel2, acc2 = motion_peaks(slow)
    np.testing.assert_allclose(vel2, vel / 2, rtol=1e-9)
    np.testing.assert_allclose(acc2, acc / 4, rtol=1e-12)
    with pytest.raises(TrajectoryError):
        good.time_scaled(0.0)


def test_concatenated(good):
    following = quintic_move(good.end, good.end + 0.1, 1.0)
    both = good.concatenated(following)
    assert len(both) == len(good) + len(following) - 1
    assert both.duration == pytest.approx(good.duration + following.duration)
    assert np.all(np.diff(both.time_from_start) > 0)
    np.testing.assert_array_equal(both.end, following.end)
    with pytest.raises(TrajectoryError, match="jumps"):
        good.concatenated(quintic_move(good.end + 0.1, good.end, 1.0))


def test_dict_round_trip_is_exact(good):
    good.time_from_start = good.time_from_start + 1.234567891
    data = good.to_dict()
    again = JointTrajectory.from_dict(data)
    assert again.to_dict() == data
    np.testing.assert_array_equal(again.positions, good.positions)
    np.testing.assert_array_equal(again.accelerations, good.accelerations)


def test_dict_round_trip_keeps_effort(good):
    data = good.to_dict()
    for i, point in enumerate(data["points"]):
        point["effort"] = [float(i)] * 6
    again = JointTrajectory.from_dict(data)
    assert again.to_dict() == data
    assert again.reordered(NAMES[::-1]).effort[3] == [3.0] * 6


def test_from_dict_rejects_bad_points():
    with pytest.raises(TrajectoryError):
        JointTrajectory.from_dict({"joint_names": NAMES, "points": [{"positions": [0.0] * 5}]})
    with pytest.raises(TrajectoryError):
        JointTrajectory.from_dict([1, 2])


def test_msg_round_trip(good):
    pytest.importorskip("rospy")
    from agiprobot_measurement.ros.conversions import joint_trajectory_from_msg, joint_trajectory_to_msg

    again = joint_trajectory_from_msg(joint_trajectory_to_msg(good))
    assert again.to_dict() == good.to_dict()
    np.testing.assert_array_equal(again.time_from_start, JointTrajectory.from_dict(good.to_dict()).time_from_start)
