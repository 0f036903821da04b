"""ViewPoint construction, the documented getters/setters, trajectory reversal and the pose generator."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.candidates.viewpoint import (
    TILT_MODES,
    TILT_STEPS,
    ViewPoint,
    build_viewpoints,
    generate_viewpoint_poses,
    orientation_angles,
    reverse_trajectory,
    select_limited_tilt,
)
from agiprobot_measurement.sensors.laser_line.model import SensorModel

STANDOFF = 181.82


@pytest.fixture(scope="module")
def sensor():
    return SensorModel.from_config()


def angles_seen_from_anchor(pose, point, normal):
    """psi, theta and z of ``point`` from the anchor pose (reference page definitions, t0 = 0 here)."""
    t, l, s = pose[:3, 0], pose[:3, 1], pose[:3, 2]
    v = point - pose[:3, 3]
    psi = math.atan2(t @ normal, -(s @ normal))
    v1, v2 = np.array([v @ l, v @ s]), np.array([normal @ l, normal @ s])
    theta = math.acos(-(v1 @ v2) / (np.linalg.norm(v1) * np.linalg.norm(v2)))
    return psi, theta, s @ v, t @ v


def assert_rotation(matrix):
    assert np.allclose(matrix.T @ matrix, np.eye(3), atol=1e-12)
    assert np.linalg.det(matrix) == pytest.approx(1.0)


@pytest.mark.parametrize("normal", [(0, 0, 1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0.3, -0.4, 0.866), (0, 0, -1)])
def test_anchor_lies_on_the_normal_and_looks_at_the_point(normal):
    point = np.array([10.0, -20.0, 30.0])
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    view = ViewPoint(point, normal, 0.7, STANDOFF)
    rotation = view.get_orientation_matrix()
    assert_rotation(rotation)
    assert np.allclose(view.get_anchor_position(), point + STANDOFF * normal)
    assert np.allclose(rotation[:, 2], -normal)
    psi, theta, z, t0 = angles_seen_from_anchor(view.get_anchor_pose(), point, normal)
    assert psi == pytest.approx(0.0, abs=1e-12) and theta == pytest.approx(0.0, abs=1e-7)
    assert z == pytest.approx(STANDOFF) and t0 == pytest.approx(0.0, abs=1e-9)


def test_orientation_rotates_the_trajectory_around_the_boresight():
    point, normal = np.zeros(3), np.array([0.0, 0.0, 1.0])
    base = ViewPoint(point, normal, 0.0, STANDOFF).get_orientation_matrix()
    assert np.allclose(base[:, 0], [1, 0, 0])  # world x is the reference trajectory direction
    turned = ViewPoint(point, normal, math.pi / 2, STANDOFF).get_orientation_matrix()
    assert np.allclose(turned[:, 2], base[:, 2])
    assert turned[:, 0] @ base[:, 0] == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(turned[:, 0], base[:, 1])


@pytest.mark.parametrize("tilt_theta,tilt_psi", [(0.3, 0.0), (-0.3, 0.0), (0.0, 0.25), (0.0, -0.25), (0.2, 0.3)])
def test_tilts_set_psi_and_theta(tilt_theta, tilt_psi):
    point, normal = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.6, 0.8])
    view = ViewPoint(point, normal, 1.1, STANDOFF, tilt_theta=tilt_theta, tilt_psi=tilt_psi)
    pose = view.get_anchor_pose()
    assert_rotation(pose[:3, :3])
    psi, theta, z, t0 = angles_seen_from_anchor(pose, point, normal)
    assert psi == pytest.approx(tilt_psi, abs=1e-12)  # psi is exact
    if tilt_psi == 0.0:
        assert theta == pytest.approx(abs(tilt_theta), abs=1e-9)
    # the boresight still passes through the surface point at the standoff
    assert z == pytest.approx(STANDOFF) and t0 == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(pose[:3, 3] + STANDOFF * pose[:3, 2], point)


def test_documented_getters_and_setters():
    view = ViewPoint([1, 2, 3], [0, 0, 1], 0.0, STANDOFF)
    assert np.allclose(view.get_surface_point(), [1, 2, 3])
    normal = view.get_surface_normal()
    assert np.allclose(normal, [0, 0, 1])
    normal[2] = -1.0  # a copy: the view keeps its normal
    assert np.allclose(view.get_surface_normal(), [0, 0, 1])
    matrix = view.get_surface_point(as_matrix=True)
    assert matrix.shape == (4, 4) and np.allclose(matrix[:3, 3], [1, 2, 3]) and np.allclose(matrix[:3, :3], np.eye(3))
    anchor = view.get_anchor_position(as_matrix=True)
    assert anchor.shape == (4, 4) and np.allclose(anchor[:3, 3], [1, 2, 3 + STANDOFF])
    assert view.get_measurable_surface_point_indices() == []
    view.set_measurable_surface_point_indices_and_uncertainties([4, 7], [0.1, 0.2])
    assert view.get_measurable_surface_point_indices() == [4, 7]
    assert view.get_measurable_surface_point_uncertainties() == [0.1, 0.2]
    view.set_measurable_surface_point_indices_and_uncertainties([4], [0.1], trajectory_distances=[-3.0])
    assert view.get_measurable_surface_point_trajectory_distances() == [-3.0]
    with pytest.raises(ValueError, match="same length"):
        view.set_measurable_surface_point_indices_and_uncertainties([1, 2], [0.1])
    assert view.get_trajectory_for_measurement() is None and view.get_trajectory_to_view() is None
    view.set_trajectory_to_view("to")
    view.set_trajectory_for_measurement("measure")
    assert view.get_trajectory_to_view() == "to" and view.get_trajectory_for_measurement() == "measure"


def test_invalid_construction():
    with pytest.raises(ValueError):
        ViewPoint([0, 0, 0], [0, 0, 0], 0.0, STANDOFF)
    with pytest.raises(ValueError):
        ViewPoint([0, 0, 0], [0, 0, 1], 0.0, -1.0)
    with pytest.raises(ValueError):
        ViewPoint([0, 0, 0], [0, 0, 1], float("nan"), STANDOFF)


def test_reversing_the_measurement_trajectory():
    names = [f"j{i}" for i in range(6)]
    times = np.array([0.0, 0.5, 2.0])
    positions = np.array([[0.0] * 6, [0.1] * 6, [0.4] * 6])
    velocities = np.array([[0.0] * 6, [0.3] * 6, [0.0] * 6])
    trajectory = JointTrajectory(names, times, positions, velocities, None)
    view = ViewPoint([0, 0, 0], [0, 0, 1], 0.0, STANDOFF)
    view.set_trajectory_for_measurement(trajectory)
    view.scan_line = (-40.0, 60.0)
    start, end = view.get_scan_line_poses()
    view.reverse_trajectory_for_measurement()
    reversed_ = view.get_trajectory_for_measurement()
    assert reversed_.duration == trajectory.duration
    np.testing.assert_allclose(reversed_.time_from_start, [0.0, 1.5, 2.0])
    np.testing.assert_array_equal(reversed_.start, trajectory.end)
    np.testing.assert_array_equal(reversed_.end, trajectory.start)
    np.testing.assert_array_equal(reversed_.velocities[1], -velocities[1])
    assert view.scan_line == (60.0, -40.0) and view.reversed
    new_start, new_end = view.get_scan_line_poses()
    assert np.allclose(new_start, end) and np.allclose(new_end, start)
    assert np.allclose(start[:3, 3], [-40.0, 0.0, STANDOFF])
    view.reverse_trajectory_for_measurement()
    again = view.get_trajectory_for_measurement()
    np.testing.assert_allclose(again.positions, trajectory.positions)
    np.testing.assert_allclose(again.time_from_start, trajectory.time_from_start)
    assert not view.reversed


def test_reversing_a_message_like_trajectory():
    def point(t, q, v):
        return SimpleNamespace(time_from_start=t, positions=q, velocities=v, accelerations=[])

    msg = SimpleNamespace(
        joint_trajectory=SimpleNamespace(
            points=[point(0.0, [0.0], [0.0]), point(1.0, [1.0], [2.0]), point(3.0, [2.0], [0.0])]
        )
    )
    flipped = reverse_trajectory(msg)
    points = flipped.joint_trajectory.points
    assert [p.time_from_start for p in points] == [0.0, 2.0, 3.0]
    assert [p.positions for p in points] == [[2.0], [1.0], [0.0]]
    assert points[1].velocities == [-2.0]
    assert msg.joint_trajectory.points[0].positions == [0.0]  # the original is untouched
    with pytest.raises(TypeError):
        reverse_trajectory(42)


def test_orientation_angles():
    np.testing.assert_allclose(orientation_angles(4), [0, math.pi / 2, math.pi, 3 * math.pi / 2])
    with pytest.raises(ValueError):
        orientation_angles(0)


def test_generator_counts_order_and_poses(sensor):
    rng = np.random.default_rng(0)
    points = rng.uniform(-50, 50, size=(5, 3))
    normals = rng.normal(size=(5, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    none = generate_viewpoint_poses(points, normals, 3, "none", sensor)
    assert none.poses.shape == (15, 4, 4)
    np.testing.assert_array_equal(none.sample_index, np.repeat(np.arange(5), 3))
    np.testing.assert_array_equal(none.orientation_index, np.tile(np.arange(3), 5))
    assert (none.tilt_index == 0).all()
    full = generate_viewpoint_poses(points, normals, 3, "full", sensor)
    assert full.poses.shape == (5 * 3 * 9, 4, 4)
    limited = generate_viewpoint_poses(points, normals, 3, "limited", sensor)
    np.testing.assert_array_equal(limited.poses, full.poses)
    # untilted candidates of 'full' are the 'none' candidates
    np.testing.assert_allclose(full.poses[full.tilt_index == 0], none.poses, atol=1e-12)
    poses, samples, orientations, tilts = full  # unpacks as the documented 4-tuple
    d = sensor.get_median_deviation_angle()
    for j in (0, 13, 40, 134):
        theta_step, psi_step = TILT_STEPS[tilts[j]]
        view = ViewPoint(
            points[samples[j]],
            normals[samples[j]],
            2 * math.pi * orientations[j] / 3,
            sensor.get_optimal_standoff(),
            tilt_theta=theta_step * d,
            tilt_psi=psi_step * d,
        )
        np.testing.assert_allclose(view.get_anchor_pose(), poses[j], atol=1e-9)
    views = build_viewpoints(full, points, normals, 3, "full", sensor, selection=[0, 13, 40])
    for view, j in zip(views, [0, 13, 40], strict=True):
        np.testing.assert_allclose(view.get_anchor_pose(), poses[j], atol=1e-9)
        assert view.metadata["candidate"] == j


def test_unknown_tilt_mode_lists_the_valid_ones(sensor):
    with pytest.raises(ValueError) as info:
        generate_viewpoint_poses(np.zeros((1, 3)), [[0, 0, 1]], 2, "sideways", sensor)
    for mode in TILT_MODES:
        assert mode in str(info.value)


def test_tilt_steps_start_with_the_optimum_and_cover_the_grid():
    assert tuple(TILT_STEPS[0]) == (0, 0)
    assert {tuple(row) for row in TILT_STEPS} == {(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)}
    # single-axis deviations come before combined ones
    assert (np.abs(TILT_STEPS[1:5]).sum(axis=1) == 1).all()


def test_select_limited_tilt():
    sample = np.repeat([0, 1, 2], 3)
    orientation = np.zeros(9, dtype=int)
    tilt = np.tile([0, 1, 2], 3)
    valid = np.array([True, True, False, False, False, True, False, False, False])
    keep = select_limited_tilt(valid, sample, orientation, tilt)
    # sample 0: the optimum works; sample 1: the first working deviation; sample 2: nothing
    np.testing.assert_array_equal(np.flatnonzero(keep), [0, 5])
