"""Straight-line Cartesian paths (compute_cartesian_path)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.motion.cartesian import (
    STOP_COMPLETE,
    STOP_INVALID_STATE,
    STOP_JOINT_JUMP,
    STOP_UNREACHABLE,
    compute_cartesian_path,
)
from agiprobot_measurement.motion.ik import KDLIK, URAnalyticIK, pose_errors

# scanner pointing down about 0.5 m above the table, well inside the workspace
START_Q = np.array([-0.8, -1.6, -1.6, -1.5, 1.57, 0.0])


@pytest.fixture(scope="module")
def ik(kinematic_model, station):
    return URAnalyticIK(kinematic_model, station.robot)


def shifted(pose, dx=0.0, dy=0.0, dz=0.0):
    out = pose.copy()
    out[:3, 3] += [dx, dy, dz]
    return out


def assert_valid_path(model, result, max_joint_step=0.05):
    """Every state reaches its pose, lies within the limits, and the joints move continuously."""
    assert len(result.joint_path) == len(result.poses)
    position, angle = pose_errors(model.fk_batch(result.joint_path), result.poses)
    assert position.max() <= 1e-6 and angle.max() <= 1e-6
    assert model.within_limits(result.joint_path).all()
    if len(result.joint_path) > 1:
        assert np.abs(np.diff(result.joint_path, axis=0)).max() < max_joint_step


def test_200_mm_line_is_complete_with_2_mm_steps(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    end = shifted(start, dx=0.2)
    result = compute_cartesian_path(ik, START_Q, end, step_mm=2.0)
    assert result.fraction == 1.0 and result.stop_reason == STOP_COMPLETE
    assert result.joint_path.shape == (101, 6)
    np.testing.assert_array_equal(result.joint_path[0], START_Q)
    reached = kinematic_model.fk_batch(result.joint_path)
    np.testing.assert_allclose(np.linalg.norm(np.diff(reached[:, :3, 3], axis=0), axis=1), 0.002, atol=1e-6)
    # a straight line: every position on the segment, orientation unchanged
    offsets = reached[:, :3, 3] - start[:3, 3]
    np.testing.assert_allclose(offsets[:, 1:], 0.0, atol=1e-6)
    np.testing.assert_allclose(reached[:, :3, :3], np.broadcast_to(start[:3, :3], (101, 3, 3)), atol=1e-6)
    np.testing.assert_allclose(reached[-1], end, atol=1e-6)
    assert_valid_path(kinematic_model, result)


def test_orientation_is_slerped_along_the_line(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    end = shifted(start, dy=-0.1)
    turn = Rotation.from_rotvec([0.0, 0.3, 0.4])
    end[:3, :3] = turn.as_matrix() @ start[:3, :3]
    result = compute_cartesian_path(ik, START_Q, end, step_mm=2.0)
    assert result.fraction == 1.0
    assert len(result.poses) == 51  # 100 mm in 2 mm steps; 0.5 rad needs only 10 steps of 0.05 rad
    relative = Rotation.from_matrix(result.poses[:, :3, :3]) * Rotation.from_matrix(start[:3, :3]).inv()
    np.testing.assert_allclose(relative.as_rotvec(), np.linspace(0.0, 1.0, 51)[:, None] * [0.0, 0.3, 0.4], atol=1e-9)
    assert_valid_path(kinematic_model, result)


def test_several_waypoints_are_passed_exactly(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    corners = np.stack([shifted(start, dx=0.1), shifted(start, dx=0.1, dy=0.05), shifted(start, dy=0.05)])
    result = compute_cartesian_path(ik, START_Q, corners, step_mm=5.0)
    assert result.fraction == 1.0
    assert len(result.poses) == 1 + 20 + 10 + 20
    for index, corner in zip((20, 30, 50), corners, strict=True):
        np.testing.assert_allclose(result.poses[index], corner, atol=1e-12)
    assert_valid_path(kinematic_model, result)


def test_line_leaving_the_workspace_stops_with_valid_waypoints(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    result = compute_cartesian_path(ik, START_Q, shifted(start, dy=-3.0), step_mm=10.0)
    assert 0.0 < result.fraction < 1.0
    assert result.stop_reason == STOP_UNREACHABLE
    assert len(result.joint_path) - 1 == round(result.fraction * 300)
    assert_valid_path(kinematic_model, result, max_joint_step=0.5)
    # the robot's reach (about 1.3 m from the shoulder) is where the path ends
    reached = kinematic_model.fk(result.joint_path[-1])
    assert 0.8 < np.linalg.norm(reached[:3, 3] - start[:3, 3]) < 2.0


def test_validity_checker_cuts_the_path_at_the_first_invalid_state(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    limit_x = start[0, 3] + 0.1005  # states more than ~100 mm along the line are "in collision"
    calls = []

    def checker(states):
        calls.append(states.copy())
        return kinematic_model.fk_batch(states)[:, 0, 3] < limit_x

    result = compute_cartesian_path(ik, START_Q, shifted(start, dx=0.2), validity_checker=checker)
    assert len(calls) == 1 and calls[0].shape == (101, 6)
    assert result.stop_reason == STOP_INVALID_STATE
    assert result.fraction == pytest.approx(0.5)
    assert len(result.joint_path) == 51
    assert checker(result.joint_path).all()
    assert_valid_path(kinematic_model, result)


def test_invalid_start_state_gives_an_empty_path(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    result = compute_cartesian_path(
        ik, START_Q, shifted(start, dx=0.05), validity_checker=lambda q: np.zeros(len(q), dtype=bool)
    )
    assert result.fraction == 0.0 and result.stop_reason == STOP_INVALID_STATE
    assert result.joint_path.shape == (0, 6)


def test_jump_threshold_stops_the_path(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    result = compute_cartesian_path(ik, START_Q, shifted(start, dx=0.2), jump_threshold_rad=1e-4)
    assert result.stop_reason == STOP_JOINT_JUMP
    assert result.fraction == 0.0 and len(result.joint_path) == 1


def test_kdl_solver_follows_the_same_line(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    end = shifted(start, dx=0.2)
    kdl = compute_cartesian_path(KDLIK(kinematic_model, rng=0), START_Q, end)
    closed_form = compute_cartesian_path(ik, START_Q, end)
    assert kdl.fraction == 1.0
    assert_valid_path(kinematic_model, kdl)
    np.testing.assert_allclose(kdl.joint_path, closed_form.joint_path, atol=1e-5)


def test_bad_input_gives_clear_errors(kinematic_model, ik):
    start = kinematic_model.fk(START_Q)
    with pytest.raises(ValueError, match="start_q: expected 6 joint values"):
        compute_cartesian_path(ik, START_Q[:5], start)
    with pytest.raises(ValueError, match="outside the joint limits"):
        compute_cartesian_path(ik, np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]), start)
    nan_pose = start.copy()
    nan_pose[2, 3] = np.nan
    with pytest.raises(ValueError, match="waypoints: pose\\(s\\) \\[0\\] contain NaN"):
        compute_cartesian_path(ik, START_Q, nan_pose)
    with pytest.raises(ValueError, match="step_mm"):
        compute_cartesian_path(ik, START_Q, start, step_mm=0.0)
    with pytest.raises(ValueError, match="one bool per state"):
        compute_cartesian_path(ik, START_Q, shifted(start, dx=0.01), validity_checker=lambda q: True)
