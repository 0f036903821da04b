"""Pose and transform message conversions (agiprobot_measurement.ros.conversions): one set for every node."""

import numpy as np
import pytest
from geometry_msgs.msg import Point, Pose, Quaternion, Transform, TransformStamped, Vector3

from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.ros.conversions import (
    matrix_to_pose,
    matrix_to_transform,
    pose_to_matrix,
    transform_stamped,
    transform_to_matrix,
    xyz_array,
    xyzw_array,
)

POSE = pose_matrix([0.5, -1.0, 2.0], [0.3, -0.4, 2.5])


def test_pose_and_transform_round_trips():
    np.testing.assert_allclose(pose_to_matrix(matrix_to_pose(POSE)), POSE, atol=1e-12)
    np.testing.assert_allclose(transform_to_matrix(matrix_to_transform(POSE)), POSE, atol=1e-12)
    q = matrix_to_pose(POSE).orientation
    assert q.w >= 0.0 and np.linalg.norm(xyzw_array(q)) == pytest.approx(1.0)


def test_transform_stamped_names_the_frames_and_reads_back():
    msg = transform_stamped(POSE, "map", "base_link", stamp=None)
    assert isinstance(msg, TransformStamped)
    assert (msg.header.frame_id, msg.child_frame_id) == ("map", "base_link")
    np.testing.assert_allclose(xyz_array(msg.transform.translation), POSE[:3, 3])
    np.testing.assert_allclose(transform_to_matrix(msg), POSE, atol=1e-12)


def test_quaternions_are_normalised_and_bad_poses_refused():
    pose = Pose(Point(1.0, 2.0, 3.0), Quaternion(0.0, 0.0, 0.0, 2.0))
    np.testing.assert_allclose(pose_to_matrix(pose), pose_matrix([1.0, 2.0, 3.0], [0.0, 0.0, 0.0]))
    with pytest.raises(InputError, match="pose has a zero quaternion"):
        pose_to_matrix(Pose(Point(0.0, 0.0, 0.0), Quaternion(0.0, 0.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="pose contains NaN or infinite values"):
        pose_to_matrix(Pose(Point(np.nan, 0.0, 0.0), Quaternion(0.0, 0.0, 0.0, 1.0)))
    with pytest.raises(InputError, match="transform contains NaN"):
        transform_to_matrix(Transform(Vector3(0.0, 0.0, 0.0), Quaternion(np.inf, 0.0, 0.0, 1.0)))
