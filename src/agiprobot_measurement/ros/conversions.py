"""numpy <-> ROS message conversions used by the nodes (needs the ROS message packages, not a master)."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Pose, TransformStamped
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

__all__ = [
    "cloud_xyz",
    "pose_to_matrix",
    "transform_to_matrix",
    "xyz_cloud",
]

_XYZ = [
    PointField("x", 0, PointField.FLOAT32, 1),
    PointField("y", 4, PointField.FLOAT32, 1),
    PointField("z", 8, PointField.FLOAT32, 1),
]
_XYZRGB = [*_XYZ, PointField("rgb", 12, PointField.FLOAT32, 1)]


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
        raise ValueError("point cloud without x, y, z fields")
    n = msg.width * msg.height
    if n == 0:
        return np.zeros((0, 3))
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(n, msg.point_step)
    out = np.empty((n, 3))
    for i, name in enumerate("xyz"):
        out[:, i] = raw[:, offsets[name] : offsets[name] + 4].copy().view(np.float32).reshape(-1)
    return out[np.all(np.isfinite(out), axis=1)]


def transform_to_matrix(transform: TransformStamped) -> np.ndarray:
    """4x4 matrix (metres) of a geometry_msgs/TransformStamped."""
    from scipy.spatial.transform import Rotation

    t, r = transform.transform.translation, transform.transform.rotation
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    matrix[:3, 3] = [t.x, t.y, t.z]
    return matrix


def pose_to_matrix(pose: Pose) -> np.ndarray:
    """4x4 matrix of a geometry_msgs/Pose; raises ValueError for NaN or a zero quaternion."""
    from scipy.spatial.transform import Rotation

    q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w])
    p = np.array([pose.position.x, pose.position.y, pose.position.z])
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
        raise ValueError("pose contains NaN or infinite values")
    if np.linalg.norm(q) < 1e-9:
        raise ValueError("pose has a zero quaternion")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    matrix[:3, 3] = p
    return matrix
