"""numpy <-> ROS message conversions used by the nodes (needs the ROS message packages, not a master).

Poses and transforms: 4x4 matrices in metres <-> geometry_msgs Pose, Transform, TransformStamped, built on
:mod:`agiprobot_measurement.common.geometry` (quaternions in geometry_msgs' order x, y, z, w). Clouds: (N, 3) points
in metres <-> sensor_msgs/PointCloud2."""

from __future__ import annotations

import numpy as np
import rospy
from geometry_msgs.msg import Point, Point32, Pose, PoseStamped, Quaternion, Transform, TransformStamped, Vector3
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud, PointCloud2, PointField
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg
from trajectory_msgs.msg import JointTrajectoryPoint

from agiprobot_measurement.common.geometry import pose_from_quaternion, pose_to_quaternion
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.trajectory import JointTrajectory, TrajectoryError, seconds_to_duration
from agiprobot_measurement.planning.plan.plan_io import ExecutionPlan, PlanError, PlanSegment, kind_at
from agiprobot_measurement.ros.errors import MessageError

__all__ = [
    "cloud_xyz",
    "joint_trajectory_from_msg",
    "joint_trajectory_to_msg",
    "matrix_to_pose",
    "matrix_to_transform",
    "plan_from_joint_trajectory_msgs",
    "plan_to_joint_trajectory_msgs",
    "pose_stamped",
    "pose_to_matrix",
    "sensor_path",
    "transform_stamped",
    "transform_to_matrix",
    "xyz_array",
    "xyz_cloud",
    "xyz_point_cloud",
    "xyzw_array",
]

_XYZ = [
    PointField("x", 0, PointField.FLOAT32, 1),
    PointField("y", 4, PointField.FLOAT32, 1),
    PointField("z", 8, PointField.FLOAT32, 1),
]
_XYZRGB = [*_XYZ, PointField("rgb", 12, PointField.FLOAT32, 1)]


def xyz_point_cloud(points_m: np.ndarray, header: Header) -> PointCloud:
    """The old ``sensor_msgs/PointCloud`` (a list of Point32, metres) of (N, 3) points: what the original planner
    published on /currently_measured_points."""
    message = PointCloud(header=header)
    message.points = [Point32(*p) for p in np.asarray(points_m, dtype=float).reshape(-1, 3).tolist()]
    return message


def xyz_cloud(points_m: np.ndarray, header: Header, colors_rgb: np.ndarray | None = None) -> PointCloud2:
    """An unorganized PointCloud2 (x, y, z float32 [+ rgb packed as float32]) from (N, 3) points in metres.

    ``colors_rgb``: (N, 3) uint8 or floats in [0, 1]."""
    points = np.asarray(points_m, dtype=np.float32).reshape(-1, 3)
    n = points.shape[0]
    if colors_rgb is None:
        data = np.ascontiguousarray(points)
        fields, step = _XYZ, 12
    else:
        colors = np.asarray(colors_rgb)
        if colors.dtype != np.uint8:
            colors = np.clip(np.round(colors * 255.0), 0, 255).astype(np.uint8)
        packed = (colors[:, 0].astype(np.uint32) << 16) | (colors[:, 1].astype(np.uint32) << 8) | colors[:, 2]
        data = np.empty((n, 4), dtype=np.float32)
        data[:, :3] = points
        data[:, 3] = packed.view(np.float32)
        fields, step = _XYZRGB, 16
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = 1, n
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = step
    msg.row_step = step * n
    msg.is_dense = True
    msg.data = data.tobytes()
    return msg


def cloud_xyz(msg: PointCloud2) -> np.ndarray:
    """(N, 3) float64 points (the cloud's unit, metres) of a PointCloud2 with float32 x, y, z fields."""
    offsets = {f.name: f.offset for f in msg.fields}
    if not {"x", "y", "z"} <= set(offsets):
        raise MessageError("point cloud without x, y, z fields")
    n = msg.width * msg.height
    if n == 0:
        return np.zeros((0, 3))
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(n, msg.point_step)
    out = np.empty((n, 3))
    for i, name in enumerate("xyz"):
        out[:, i] = raw[:, offsets[name] : offsets[name] + 4].copy().view(np.float32).reshape(-1)
    return out[np.all(np.isfinite(out), axis=1)]


def transform_to_matrix(transform) -> np.ndarray:
    """4x4 matrix (metres) of a geometry_msgs/TransformStamped or Transform; the quaternion is normalised.

    Raises :class:`~agiprobot_measurement.errors.InputError` for NaN or infinite values or a zero quaternion."""
    transform = getattr(transform, "transform", transform)
    t, r = transform.translation, transform.rotation
    return _pose_matrix((t.x, t.y, t.z), (r.x, r.y, r.z, r.w), "transform")


def pose_to_matrix(pose: Pose) -> np.ndarray:
    """4x4 matrix of a geometry_msgs/Pose; the quaternion is normalised.

    Raises :class:`~agiprobot_measurement.errors.InputError` for NaN or infinite values or a zero quaternion."""
    p, q = pose.position, pose.orientation
    return _pose_matrix((p.x, p.y, p.z), (q.x, q.y, q.z, q.w), "pose")


def _pose_matrix(translation, quaternion_xyzw, what: str) -> np.ndarray:
    # the messages the nodes' clients have always seen for a bad pose
    if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(quaternion_xyzw))):
        raise InputError(f"{what} contains NaN or infinite values")
    try:
        return pose_from_quaternion(translation, quaternion_xyzw)
    except ValueError as exc:
        raise InputError(f"{what} has a zero quaternion") from exc


def matrix_to_pose(matrix: np.ndarray) -> Pose:
    """geometry_msgs/Pose of a 4x4 matrix (metres)."""
    translation, q = pose_to_quaternion(matrix)
    return Pose(Point(*translation), Quaternion(*q))


def matrix_to_transform(matrix: np.ndarray) -> Transform:
    """geometry_msgs/Transform of a 4x4 matrix (metres)."""
    translation, q = pose_to_quaternion(matrix)
    return Transform(Vector3(*translation), Quaternion(*q))


def xyz_array(msg) -> np.ndarray:
    """(3,) float array of a geometry_msgs Point or Vector3."""
    return np.array([msg.x, msg.y, msg.z], dtype=float)


def xyzw_array(msg) -> np.ndarray:
    """(4,) float array (x, y, z, w) of a geometry_msgs/Quaternion, as it is (not normalised)."""
    return np.array([msg.x, msg.y, msg.z, msg.w], dtype=float)


def transform_stamped(matrix: np.ndarray, parent_frame: str, child_frame: str, stamp) -> TransformStamped:
    """geometry_msgs/TransformStamped parent_frame <- child_frame of a 4x4 matrix (metres), for tf."""
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent_frame
    msg.child_frame_id = child_frame
    msg.transform = matrix_to_transform(matrix)
    return msg


def joint_trajectory_to_msg(trajectory: JointTrajectory):
    """A ``trajectory_msgs/JointTrajectory`` of a :class:`JointTrajectory` (times rounded to the nanosecond, so
    stored {secs, nsecs} survive a round trip)."""
    msg = JointTrajectoryMsg()
    msg.header.frame_id = trajectory.frame_id
    msg.joint_names = list(trajectory.joint_names)
    effort = trajectory.effort if trajectory.has_effort() else None
    for i, t in enumerate(trajectory.time_from_start):
        point = JointTrajectoryPoint()
        point.positions = trajectory.positions[i].tolist()
        if trajectory.velocities is not None:
            point.velocities = trajectory.velocities[i].tolist()
        if trajectory.accelerations is not None:
            point.accelerations = trajectory.accelerations[i].tolist()
        if effort is not None:
            point.effort = [float(e) for e in effort[i]]
        stamp = seconds_to_duration(float(t))
        point.time_from_start = rospy.Duration(stamp["secs"], stamp["nsecs"])
        msg.points.append(point)
    return msg


def joint_trajectory_from_msg(msg) -> JointTrajectory:
    """A :class:`JointTrajectory` of a ``trajectory_msgs/JointTrajectory`` message."""
    return JointTrajectory.from_msg(msg)


def plan_to_joint_trajectory_msgs(plan: ExecutionPlan) -> list:
    """The plan's segments as ``trajectory_msgs/JointTrajectory`` messages."""
    return [joint_trajectory_to_msg(s.trajectory) for s in plan.segments]


def plan_from_joint_trajectory_msgs(messages, metadata: dict | None = None) -> ExecutionPlan:
    """A plan from ``trajectory_msgs/JointTrajectory`` messages in C-M-C-M-... order."""
    segments = []
    for index, message in enumerate(messages):
        try:
            segments.append(PlanSegment(kind_at(index), joint_trajectory_from_msg(message)))
        except (TrajectoryError, ValueError, AttributeError) as exc:
            raise PlanError(f"segment {index}: {exc}") from exc
    return ExecutionPlan(dict(metadata or {}), segments)


def pose_stamped(pose: np.ndarray, header: Header) -> PoseStamped:
    return PoseStamped(header=header, pose=matrix_to_pose(np.asarray(pose, dtype=float)))


def sensor_path(poses, header: Header) -> Path:
    """nav_msgs/Path of the sensor's poses (world <- sensor, 4x4) in the order they were taken."""
    return Path(header=header, poses=[pose_stamped(p, header) for p in poses])
