"""Time parameterisation: time-optimal within the joint limits, and constant Cartesian speed for scan lines."""

import time

import numpy as np
import pytest

from agiprobot_measurement.motion.time_parameterization import (
    TimeParameterizationError,
    constant_speed_scan_trajectory,
    time_optimal_trajectory,
)
from agiprobot_measurement.motion.trajectory import check_trajectory, motion_peaks
from agiprobot_measurement.station import load_joint_limits

LIMIT_SLACK = 1e-6
START = np.array([0.5, -1.5, -1.5, -1.0, 1.5, 0.0])


@pytest.fixture(scope="module")
def limits():
    return load_joint_limits()


def random_path(limits, seed: int, count: int, step_rad: float = 0.15) -> np.ndarray:
    rng = np.random.default_rng(seed)
    path = START + np.cumsum(rng.normal(0.0, step_rad, (count, 6)), axis=0)
    path[0] = START
    return np.clip(path, limits.lower + 0.2, limits.upper - 0.2)


def assert_within(trajectory, limits, velocity_scale=1.0, acceleration_scale=1.0):
    vel, acc = motion_peaks(trajectory)
    assert np.all(vel <= limits.max_velocity * velocity_scale + LIMIT_SLACK), vel
    assert np.all(acc <= limits.max_acceleration * acceleration_scale + LIMIT_SLACK), acc
    assert np.all(np.diff(trajectory.time_from_start) > 0)
    assert trajectory.time_from_start[0] == 0.0
    np.testing.assert_array_equal(trajectory.velocities[[0, -1]], 0.0)
    assert check_trajectory(trajectory, limits)


def passes_through(trajectory, waypoints) -> bool:
    return all(np.any(np.all(np.abs(trajectory.positions - w) < 1e-9, axis=1)) for w in waypoints)


# ---------------------------------------------------------------------------------------- time-optimal
@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("count", [2, 3, 8, 40])
def test_random_paths_stay_within_limits(limits, seed, count):
    path = random_path(limits, seed, count)
    trajectory = time_optimal_trajectory(path, limits)
    assert_within(trajectory, limits)
    assert passes_through(trajectory, path)
    np.testing.assert_allclose(trajectory.start, path[0])
    np.testing.assert_allclose(trajectory.end, path[-1])


@pytest.mark.parametrize("seed", range(3))
def test_scaling_factors(limits, seed):
    path = random_path(limits, seed, 6)
    full = time_optimal_trajectory(path, limits)
    slow = time_optimal_trajectory(path, limits, velocity_scaling_factor=0.3, acceleration_scaling_factor=0.2)
    assert_within(slow, limits, 0.3, 0.2)
    assert slow.duration > full.duration * 1.5


def test_straight_move_is_time_optimal(limits):
    """A single-joint move is the bang-bang profile: 3 rad of shoulder_pan at 1 rad/s^2 (never reaching
    1.8 rad/s) takes 2 * sqrt(3 / 1) s."""
    goal = START + np.array([3.0, 0, 0, 0, 0, 0])
    trajectory = time_optimal_trajectory([START, goal], limits)
    assert trajectory.duration == pytest.approx(2 * np.sqrt(3.0), rel=0.01)
    assert_within(trajectory, limits)
    # with the velocity limit binding: 6 rad at 1.8 rad/s and 1 rad/s^2 -> 6 / 1.8 + 1.8 s
    far = np.array([-3.0, -1.5, -1.5, -1.0, 1.5, 0.0])
    trajectory = time_optimal_trajectory([far, far + np.array([6.0, 0, 0, 0, 0, 0])], limits)
    assert trajectory.duration == pytest.approx(6 / 1.8 + 1.8, rel=0.01)
    assert np.max(np.abs(trajectory.velocities[:, 0])) == pytest.approx(1.8, rel=1e-3)


def test_joint_names_order(limits):
    path = random_path(limits, 1, 5)
    names = list(limits.names)[::-1]
    trajectory = time_optimal_trajectory(path[:, ::-1], limits, joint_names=names)
    assert trajectory.joint_names == names
    reference = time_optimal_trajectory(path, limits)
    np.testing.assert_allclose(trajectory.reordered(list(limits.names)).positions, reference.positions, atol=1e-9)
    with pytest.raises(TimeParameterizationError, match="joint names"):
        time_optimal_trajectory(path, limits, joint_names=[*names[:-1], "other"])


def test_knots_only_at_waypoints(limits):
    path = random_path(limits, 2, 30, step_rad=0.02)
    trajectory = time_optimal_trajectory(path, limits, sample_step_s=None)
    assert len(trajectory) == len(path)
    np.testing.assert_array_equal(trajectory.positions, path)
    assert_within(trajectory, limits)


def test_single_and_repeated_waypoints(limits):
    single = time_optimal_trajectory(START, limits)
    assert len(single) == 1 and single.duration == 0.0
    np.testing.assert_array_equal(single.positions[0], START)
    assert check_trajectory(single, limits)
    still = time_optimal_trajectory([START, START, START], limits)
    assert len(still) == 1
    goal = START + 0.3
    repeated = time_optimal_trajectory([START, START, goal, goal, goal], limits)
    assert_within(repeated, limits)
    np.testing.assert_allclose(repeated.end, goal)


@pytest.mark.parametrize(
    ("waypoints", "match"),
    [
        (np.zeros((0, 6)), "no waypoints"),
        (np.zeros((3, 5)), r"shape \(K, 6\)"),
        (np.zeros((2, 3, 6)), r"shape \(K, 6\)"),
        ([[0.0] * 6, [0.0, np.nan, 0, 0, 0, 0]], "waypoint 1 contains NaN"),
        ([[0.0] * 6, [0.0, 0, 0, np.inf, 0, 0]], "waypoint 1 contains NaN or infinite"),
        ([[0.0] * 6, [0.0, 1.0, 0, 0, 0, 0]], "waypoint 1: shoulder_lift_joint .* outside"),
        ([["a"] * 6], "numbers"),
    ],
)
def test_bad_waypoints(limits, waypoints, match):
    with pytest.raises(TimeParameterizationError, match=match):
        time_optimal_trajectory(waypoints, limits)


@pytest.mark.parametrize("factor", [0.0, -0.5, 1.5, np.nan])
def test_bad_scaling_factor(limits, factor):
    with pytest.raises(TimeParameterizationError, match="velocity_scaling_factor"):
        time_optimal_trajectory([START, START + 0.1], limits, velocity_scaling_factor=factor)


def test_densified_path_follows_the_polyline(limits):
    """A sharp corner: the spline through three waypoints swings wide; densified, it hugs the polyline."""
    corner = START + np.array([0.8, 0, 0, 0, 0, 0])
    path = [START, corner, corner + np.array([0, 0, 0.8, 0, 0, 0])]

    def deviation(trajectory):
        pos, _, _ = trajectory.sample(trajectory.dense_times())
        # distance of each sample to the two legs of the polyline
        d = []
        for a, b in ((path[0], path[1]), (path[1], path[2])):
            t = np.clip((pos - a) @ (b - a) / np.dot(b - a, b - a), 0, 1)
            d.append(np.linalg.norm(pos - (a + t[:, None] * (b - a)), axis=1))
        return np.min(d, axis=0).max()

    loose = time_optimal_trajectory(path, limits)
    tight = time_optimal_trajectory(path, limits, max_waypoint_step_rad=0.01)
    assert_within(tight, limits)
    assert deviation(tight) < 0.01 < deviation(loose)


def test_hundred_waypoints_is_fast(limits):
    path = random_path(limits, 7, 100, step_rad=0.03)
    started = time.perf_counter()
    trajectory = time_optimal_trajectory(path, limits)
    elapsed = time.perf_counter() - started
    assert_within(trajectory, limits)
    assert elapsed < 5.0, f"{elapsed:.2f} s for 100 waypoints"


# ------------------------------------------------------------------------------------------ scan lines
DIRECTION_RAD_PER_MM = np.array([1.0, -0.5, 0.8, 0.3, -0.2, 0.4]) * 1e-3


def line_path(length_mm: float, spacing_mm: float = 2.0, direction=DIRECTION_RAD_PER_MM):
    s = np.arange(0.0, length_mm + 1e-9, spacing_mm)
    return START + np.outer(s, direction)


def path_speed(trajectory, direction=DIRECTION_RAD_PER_MM):
    """Path speed (mm/s) and acceleration (mm/s^2) of a trajectory along a straight joint-space line."""
    unit = direction / np.dot(direction, direction)
    return trajectory.velocities @ unit, trajectory.accelerations @ unit


def test_scan_holds_the_requested_speed(limits):
    result = constant_speed_scan_trajectory(line_path(200.0), limits, scan_speed_mm_s=50.0, spacing_mm=2.0)
    trajectory = result.trajectory
    assert_within(trajectory, limits)
    assert result.reached_scan_speed and not result.speed_reduced and result.speed_limited_by == ""
    assert result.scan_speed_mm_s == pytest.approx(50.0, rel=1e-6)
    assert result.line_length_mm == pytest.approx(200.0)
    assert result.cruise_length_mm > 190.0
    speed, _ = path_speed(trajectory)
    t = trajectory.time_from_start
    cruise = (t >= result.cruise_start_s) & (t <= result.cruise_end_s)
    np.testing.assert_allclose(speed[cruise], 50.0, rtol=1e-6)
    assert np.all(speed <= 50.0 * (1 + 1e-6))
    # ramps at both ends, at rest at the ends
    assert 0.0 < result.cruise_start_s and result.cruise_end_s < trajectory.duration
    assert trajectory.duration == pytest.approx(result.cruise_end_s + result.cruise_start_s, rel=0.05)


def test_scan_ramp_acceleration(limits):
    result = constant_speed_scan_trajectory(
        line_path(200.0), limits, scan_speed_mm_s=100.0, spacing_mm=2.0, ramp_acceleration_mm_s2=200.0
    )
    _, acceleration = path_speed(result.trajectory)
    assert np.abs(acceleration).max() <= 200.0 * (1 + 1e-5)
    # from rest to 100 mm/s at 200 mm/s^2 takes 0.5 s
    assert result.cruise_start_s == pytest.approx(0.5, rel=0.05)
    assert result.scan_speed_mm_s == pytest.approx(100.0, rel=1e-6)


def test_scan_speed_lowered_by_joint_velocity_limits(limits):
    # 10 mrad of shoulder_pan per mm: its 1.8 rad/s allow at most 180 mm/s
    direction = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0]) * 1e-3
    path = np.array([-3.0, -1.5, -1.5, -1.0, 1.5, 0.0]) + np.outer(np.arange(0, 500.1, 2.0), direction)
    result = constant_speed_scan_trajectory(path, limits, scan_speed_mm_s=300.0, spacing_mm=2.0)
    assert_within(result.trajectory, limits)
    assert result.reached_scan_speed and result.speed_reduced
    assert "velocity" in result.speed_limited_by
    assert result.scan_speed_mm_s == pytest.approx(180.0, rel=1e-3)
    assert result.scan_speed_mm_s <= 180.0
    speed, _ = path_speed(result.trajectory, direction)
    t = result.trajectory.time_from_start
    cruise = (t >= result.cruise_start_s) & (t <= result.cruise_end_s)
    np.testing.assert_allclose(speed[cruise], result.scan_speed_mm_s, rtol=1e-6)


def test_scan_too_short_to_reach_the_speed(limits):
    result = constant_speed_scan_trajectory(line_path(20.0), limits, scan_speed_mm_s=1000.0, spacing_mm=2.0)
    assert not result.reached_scan_speed and result.speed_reduced
    assert "too short" in result.speed_limited_by
    assert result.cruise_length_mm == 0.0
    assert 0 < result.scan_speed_mm_s < 1000.0
    assert_within(result.trajectory, limits)


def test_scan_errors(limits):
    path = line_path(20.0)
    with pytest.raises(TimeParameterizationError, match="exactly one"):
        constant_speed_scan_trajectory(path, limits, 50.0)
    with pytest.raises(TimeParameterizationError, match="exactly one"):
        constant_speed_scan_trajectory(path, limits, 50.0, spacing_mm=2.0, tip_positions_m=np.zeros((len(path), 3)))
    with pytest.raises(TimeParameterizationError, match="scan_speed_mm_s"):
        constant_speed_scan_trajectory(path, limits, 0.0, spacing_mm=2.0)
    with pytest.raises(TimeParameterizationError, match="tip_positions_m"):
        constant_speed_scan_trajectory(path, limits, 50.0, tip_positions_m=np.zeros((3, 3)))
    with pytest.raises(TimeParameterizationError, match="coincide"):
        constant_speed_scan_trajectory(path, limits, 50.0, tip_positions_m=np.zeros((len(path), 3)))
    with pytest.raises(TimeParameterizationError, match="at least 2"):
        constant_speed_scan_trajectory(path[:1], limits, 50.0, spacing_mm=2.0)
    with pytest.raises(TimeParameterizationError, match="NaN"):
        constant_speed_scan_trajectory(np.full((3, 6), np.nan), limits, 50.0, spacing_mm=2.0)


def _line_by_ik(kinematic_model, q, count, spacing_m):
    """Joint waypoints whose tip poses lie on a straight line along the tip's x axis (damped Newton IK)."""
    start = kinematic_model.fk(q)

    def error(pose, goal):
        rotation = 0.5 * sum(np.cross(pose[:3, i], goal[:3, i]) for i in range(3))
        return np.concatenate([goal[:3, 3] - pose[:3, 3], rotation])

    waypoints = []
    for i in range(count):
        goal = start.copy()
        goal[:3, 3] += start[:3, 0] * i * spacing_m
        for _ in range(30):
            pose = kinematic_model.fk(q)
            e = error(pose, goal)
            if np.linalg.norm(e) < 1e-12:
                break
            jacobian = np.column_stack(
                [error(pose, kinematic_model.fk(q + 1e-7 * np.eye(6)[j])) / 1e-7 for j in range(6)]
            )
            q = q + np.linalg.solve(jacobian, e)
        waypoints.append(q)
    return np.array(waypoints)


def test_scan_tip_moves_at_constant_cartesian_speed(kinematic_model, station):
    """Through the real kinematics: IK along a 200 mm line, then FK of the interpolated motion."""
    waypoints = _line_by_ik(kinematic_model, np.array([0.5, -1.8, -1.6, -1.2, 1.57, 0.0]), 101, 0.002)
    tips_m = kinematic_model.fk(waypoints)[:, :3, 3]
    assert np.linalg.norm(np.diff(tips_m, axis=0), axis=1) == pytest.approx(0.002, abs=1e-9)
    result = constant_speed_scan_trajectory(waypoints, station.limits, 100.0, tip_positions_m=tips_m)
    assert_within(result.trajectory, station.limits)
    assert result.scan_speed_mm_s == pytest.approx(100.0, rel=1e-6)
    times = np.linspace(result.cruise_start_s, result.cruise_end_s, 500)
    positions, _, _ = result.trajectory.sample(times)
    tips = kinematic_model.fk(positions)[:, :3, 3]
    speed_mm_s = np.linalg.norm(np.diff(tips, axis=0), axis=1) / np.diff(times) * 1000.0
    np.testing.assert_allclose(speed_mm_s, 100.0, rtol=2e-3)
    # the same with spacing_mm gives the same timing
    spaced = constant_speed_scan_trajectory(waypoints, station.limits, 100.0, spacing_mm=2.0)
    assert spaced.trajectory.duration == pytest.approx(result.trajectory.duration, rel=1e-6)
