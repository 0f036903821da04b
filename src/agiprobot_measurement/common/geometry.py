"""Rigid-body maths in one place: roll-pitch-yaw, quaternions (x, y, z, w), 4x4 poses, points.

Angles in radians, translations in the caller's unit (metres everywhere in the core).
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = [
    "GeometryError",
    "fit_plane",
    "invert_pose",
    "look_at",
    "matrix_to_quaternion",
    "matrix_to_rpy",
    "pose_from_quaternion",
    "pose_matrix",
    "pose_to_quaternion",
    "quaternion_to_matrix",
    "raise_elevation",
    "rpy_to_matrix",
    "slerp_unit",
    "transform_points",
    "wrap_to_pi",
    "yaw_quaternion",
]


class GeometryError(InputError):
    """A pose, quaternion or viewing direction that has no well-defined geometry (coincident points, zero
    quaternion, non-finite values)."""


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z) to a 3x3 rotation matrix."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def pose_matrix(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 transform from a translation and URDF roll-pitch-yaw."""
    pose = np.eye(4)
    pose[:3, :3] = rpy_to_matrix(np.asarray(rpy, dtype=float))
    pose[:3, 3] = xyz
    return pose


def matrix_to_rpy(rotation: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z) of a rotation matrix; inverse of :func:`rpy_to_matrix`."""
    r = np.asarray(rotation, dtype=float)
    pitch = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    if abs(math.cos(pitch)) < 1e-9:  # gimbal lock: put everything into yaw
        return np.array([0.0, pitch, math.atan2(-r[0, 1], r[1, 1])])
    return np.array([math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Pose (4x4) of an optical frame at ``eye`` looking at ``target``: z forward, x right, y down (image rows)."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) < 1e-9:
        raise GeometryError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise GeometryError("look_at: the viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = eye
    return pose


def transform_points(transform: np.ndarray, points_m: np.ndarray) -> np.ndarray:
    """``transform`` (4x4) applied to points (N, 3)."""
    return np.asarray(points_m, dtype=float) @ np.asarray(transform)[:3, :3].T + np.asarray(transform)[:3, 3]


def fit_plane(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane: (centroid (3,), unit normal (3,)) by SVD."""
    points = np.asarray(points_m, dtype=float)
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, vt[-1]


def yaw_quaternion(yaw_rad: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation by ``yaw_rad`` about z."""
    return np.array([0.0, 0.0, math.sin(yaw_rad / 2.0), math.cos(yaw_rad / 2.0)])


def matrix_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix (3x3, or the rotation block of a 4x4)."""
    r = np.asarray(rotation, dtype=float)[:3, :3]
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1])
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


def quaternion_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) in geometry_msgs order (x, y, z, w)."""
    x, y, z, w = np.moveaxis(np.asarray(q_xyzw, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def wrap_to_pi(angle_rad):
    """Angles mapped to [-pi, pi)."""
    return np.remainder(np.add(angle_rad, math.pi), (2.0 * math.pi)) - math.pi


def pose_from_quaternion(translation, quaternion_xyzw) -> np.ndarray:
    """4x4 pose from a translation and a quaternion (x, y, z, w); the quaternion is normalised.

    Raises ``ValueError`` for non-finite values or a zero quaternion.
    """
    q = np.asarray(quaternion_xyzw, dtype=float)
    t = np.asarray(translation, dtype=float)
    if q.shape != (4,) or t.shape != (3,):
        raise GeometryError(f"expected a translation (3,) and a quaternion (4,), got {t.shape} and {q.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
        raise GeometryError("translation and quaternion must be finite")
    norm = np.linalg.norm(q)
    if norm < 1e-6:
        raise GeometryError("zero quaternion (the identity is x = y = z = 0, w = 1)")
    pose = np.eye(4)
    pose[:3, :3] = quaternion_to_matrix(q / norm)
    pose[:3, 3] = t
    return pose


def pose_to_quaternion(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,), quaternion (x, y, z, w)) of a 4x4 pose."""
    pose = np.asarray(pose, dtype=float)
    return pose[:3, 3].copy(), matrix_to_quaternion(pose[:3, :3])


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (R^T, -R^T t)."""
    pose = np.asarray(pose, dtype=float)
    inverse = np.eye(4)
    inverse[:3, :3] = pose[:3, :3].T
    inverse[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inverse


def slerp_unit(u: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
    """The unit vector at ``t`` in [0, 1] along the great circle from unit ``u`` to unit ``v`` (straight up, +z,
    when they are opposite, where the circle is not defined)."""
    angle = math.acos(float(np.clip(np.dot(u, v), -1.0, 1.0)))
    if angle < 1e-9:
        return np.asarray(u, dtype=float)
    if math.pi - angle < 1e-3:
        return np.array([0.0, 0.0, 1.0])
    w = (math.sin((1 - t) * angle) * np.asarray(u) + math.sin(t * angle) * np.asarray(v)) / math.sin(angle)
    return w / np.linalg.norm(w)


def raise_elevation(direction: np.ndarray, lift_rad: float, max_elevation_rad: float = math.radians(89.0)):
    """Unit ``direction`` with its elevation above the xy-plane raised by ``lift_rad`` (at most to
    ``max_elevation_rad``), its azimuth kept; a vertical direction is returned as it is."""
    horizontal = math.hypot(direction[0], direction[1])
    if lift_rad == 0.0 or horizontal < 1e-6:
        return np.asarray(direction, dtype=float)
    elevation = min(math.atan2(direction[2], horizontal) + lift_rad, max_elevation_rad)
    azimuth = math.atan2(direction[1], direction[0])
    return np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                     math.sin(elevation)])  # fmt: skip
