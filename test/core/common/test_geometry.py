"""common.geometry: the one home of rpy / quaternion / pose maths, checked against scipy's Rotation."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.common import geometry as g

RNG = np.random.default_rng(7)
ROTATIONS = Rotation.random(50, random_state=3)


def test_rpy_round_trip_matches_scipy_fixed_axes():
    for rpy in RNG.uniform(-math.pi, math.pi, (50, 3)) * [1, 0.49, 1]:
        matrix = g.rpy_to_matrix(rpy)
        assert np.allclose(matrix, Rotation.from_euler("xyz", rpy).as_matrix())
        assert np.allclose(g.rpy_to_matrix(g.matrix_to_rpy(matrix)), matrix)


def test_quaternion_round_trip_and_sign():
    for rotation in ROTATIONS:
        matrix = rotation.as_matrix()
        q = g.matrix_to_quaternion(matrix)
        assert q[3] >= 0.0
        assert np.isclose(np.linalg.norm(q), 1.0)
        expected = rotation.as_quat()
        assert np.allclose(q, expected if expected[3] >= 0 else -expected, atol=1e-9)
        assert np.allclose(g.quaternion_to_matrix(q), matrix)
    # batched: (..., 4) -> (..., 3, 3)
    assert np.allclose(g.quaternion_to_matrix(ROTATIONS.as_quat()), ROTATIONS.as_matrix())


def test_pose_from_quaternion_normalises_and_refuses_bad_input():
    q = ROTATIONS[0].as_quat() * 3.0
    pose = g.pose_from_quaternion([1.0, 2.0, 3.0], q)
    assert np.allclose(pose[:3, :3], ROTATIONS[0].as_matrix())
    assert np.allclose(pose[:3, 3], [1, 2, 3])
    translation, quaternion = g.pose_to_quaternion(pose)
    assert np.allclose(g.pose_from_quaternion(translation, quaternion), pose)
    with pytest.raises(ValueError, match="zero quaternion"):
        g.pose_from_quaternion([0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        g.pose_from_quaternion([np.nan, 0, 0], [0, 0, 0, 1])
    with pytest.raises(ValueError, match="expected"):
        g.pose_from_quaternion([0, 0], [0, 0, 0, 1])


def test_invert_pose_and_transform_points():
    pose = g.pose_matrix([0.1, -0.2, 0.3], [0.3, -0.2, 1.0])
    assert np.allclose(g.invert_pose(pose) @ pose, np.eye(4))
    points = RNG.normal(size=(10, 3))
    moved = g.transform_points(pose, points)
    assert np.allclose(g.transform_points(g.invert_pose(pose), moved), points)


def test_look_at_points_z_at_the_target_and_refuses_degenerate_cases():
    pose = g.look_at([0, 0, 1], [1, 0, 0])
    assert np.allclose(pose[:3, 2], np.array([1, 0, -1]) / math.sqrt(2))
    assert np.isclose(np.linalg.det(pose[:3, :3]), 1.0)
    with pytest.raises(ValueError, match="coincide"):
        g.look_at([0, 0, 1], [0, 0, 1])
    with pytest.raises(ValueError, match="parallel"):
        g.look_at([0, 0, 1], [0, 0, 0])


def test_wrap_yaw_and_plane():
    assert np.allclose(g.wrap_to_pi([3 * math.pi, -math.pi, 0.5]), [-math.pi, -math.pi, 0.5])
    assert np.allclose(g.quaternion_to_matrix(g.yaw_quaternion(0.7)), Rotation.from_euler("z", 0.7).as_matrix())
    points = np.column_stack([RNG.uniform(size=(30, 2)), np.full(30, 2.0)])
    centroid, normal = g.fit_plane(points)
    assert np.isclose(centroid[2], 2.0) and np.isclose(abs(normal[2]), 1.0)


def test_great_circle_points_and_raised_elevations():
    from agiprobot_measurement.common.geometry import raise_elevation, slerp_unit

    east, north = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert np.allclose(slerp_unit(east, north, 0.5), np.array([1, 1, 0]) / math.sqrt(2))
    assert np.allclose(slerp_unit(east, north, 1 / 3), [math.cos(math.pi / 6), math.sin(math.pi / 6), 0])
    assert np.allclose(slerp_unit(east, north, 0.0), east) and np.allclose(slerp_unit(east, north, 1.0), north)
    assert np.allclose(slerp_unit(east, -east, 0.5), [0, 0, 1])  # opposite: over the top
    raised = raise_elevation(east, math.radians(30))
    assert np.allclose(raised, [math.cos(math.radians(30)), 0, math.sin(math.radians(30))])
    assert math.degrees(math.asin(raise_elevation(raised, math.radians(80))[2])) == pytest.approx(89.0)
    assert np.allclose(raise_elevation(np.array([0, 0, 1.0]), 0.5), [0, 0, 1])
