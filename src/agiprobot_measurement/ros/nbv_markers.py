"""rviz messages of the 3D next-best-view loop: voxels, candidate views, the sensor's path, the next view, frustum.

Voxels are one CUBE_LIST per layer, as octomap_server's ``occupied_cells_vis_array`` (the octomap rviz plugin and
octomap_msgs are not in Debian's ROS). Candidate views are arrows along the sensor's viewing direction (its z axis):
feasible ones coloured by utility (blue = lowest, red = highest of the set), rejected ones grey, one namespace per
rejection reason (``rejected/<reason>``) so rviz can show or hide each. Every MarkerArray starts with a DELETEALL, so
a smaller set replaces a larger one. World frame, metres. Needs the message packages only.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Path
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.ros.conversions import matrix_to_pose
from agiprobot_measurement.ros.errors import MessageError

__all__ = [
    "FRONTIER_RGBA",
    "OCCLUSION_RGBA",
    "REJECTED_RGBA",
    "candidate_markers",
    "frustum_marker",
    "mesh_marker",
    "pose_stamped",
    "sensor_path",
    "utility_colors",
    "voxel_markers",
]

FRONTIER_RGBA = (1.0, 0.85, 0.0, 0.6)
OCCLUSION_RGBA = (0.9, 0.2, 0.9, 0.35)
REJECTED_RGBA = (0.55, 0.55, 0.55, 0.5)
#: a CUBE_LIST larger than this is thinned to every k-th voxel (rviz and the wire stay responsive)
MAX_CUBES = 200_000
#: a mesh larger than this is shown with every k-th triangle
MAX_TRIANGLES = 150_000
MESH_RGBA = (0.75, 0.75, 0.8, 1.0)


def _clear(header: Header) -> Marker:
    marker = Marker(action=Marker.DELETEALL)
    marker.header = header
    return marker


def _height_colors(z: np.ndarray) -> np.ndarray:
    """(K, 3) colours by height (blue low ... red high), as octomap_server colours its cells."""
    span = float(np.ptp(z)) if len(z) else 0.0
    t = (z - z.min()) / span if span > 0 else np.full(len(z), 0.5)
    return np.stack([t, 1.0 - np.abs(2.0 * t - 1.0), 1.0 - t], axis=1)


def voxel_markers(
    centres_m: np.ndarray,
    size_m: float,
    header: Header,
    ns: str,
    rgba: tuple[float, float, float, float] | None = None,
    max_cubes: int = MAX_CUBES,
) -> MarkerArray:
    """One CUBE_LIST of voxels (centres (K, 3), edge ``size_m``): ``rgba`` for all, or coloured by height (None)."""
    centres = np.asarray(centres_m, dtype=float).reshape(-1, 3)
    if len(centres) > max_cubes:
        centres = centres[:: int(np.ceil(len(centres) / max_cubes))]
    markers = MarkerArray(markers=[_clear(header)])
    marker = Marker(header=header, ns=ns, id=0, type=Marker.CUBE_LIST, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = float(size_m)
    marker.points = [Point(*p) for p in centres.tolist()]
    if rgba is None:
        marker.color = ColorRGBA(1.0, 1.0, 1.0, 1.0)
        marker.colors = [ColorRGBA(r, g, b, 1.0) for r, g, b in _height_colors(centres[:, 2]).tolist()]
    else:
        marker.color = ColorRGBA(*rgba)
    markers.markers.append(marker)
    return markers


def utility_colors(utilities: np.ndarray) -> np.ndarray:
    """(V, 3) colours of utilities: blue (lowest) through green to red (highest); all green when they are equal."""
    u = np.asarray(utilities, dtype=float)
    finite = np.isfinite(u)
    if not finite.any():
        return np.tile([0.0, 1.0, 0.0], (len(u), 1))
    low, high = float(u[finite].min()), float(u[finite].max())
    t = np.clip((np.where(finite, u, low) - low) / (high - low), 0.0, 1.0) if high > low else np.full(len(u), 0.5)
    return np.stack([t, 1.0 - np.abs(2.0 * t - 1.0), 1.0 - t], axis=1)


def candidate_markers(
    poses: np.ndarray,
    utilities: np.ndarray,
    reasons,
    header: Header,
    length_m: float = 0.06,
) -> MarkerArray:
    """Arrows of candidate views (poses (V, 4, 4) world <- sensor): from the sensor along its z axis. ``reasons[i]``
    "" = feasible (coloured by ``utilities[i]``), else why it was rejected (grey, namespace ``rejected/<reason>``)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
    utilities = np.asarray(utilities, dtype=float).reshape(-1)
    reasons = ["" if r is None else str(r) for r in reasons]
    if not (len(poses) == len(utilities) == len(reasons)):
        raise MessageError(f"{len(poses)} poses, {len(utilities)} utilities and {len(reasons)} reasons")
    feasible = np.array([r == "" for r in reasons], dtype=bool)
    colors = np.zeros((len(poses), 3))
    if feasible.any():
        colors[feasible] = utility_colors(utilities[feasible])
    markers = MarkerArray(markers=[_clear(header)])
    counts: dict[str, int] = {}
    for i, pose in enumerate(poses):
        ns = "feasible" if feasible[i] else f"rejected/{reasons[i]}"
        counts[ns] = counts.get(ns, -1) + 1
        arrow = Marker(header=header, ns=ns, id=counts[ns], type=Marker.ARROW, action=Marker.ADD)
        start = pose[:3, 3]
        arrow.points = [Point(*start), Point(*(start + length_m * pose[:3, 2]))]
        arrow.pose.orientation.w = 1.0
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.003, 0.008, 0.012
        arrow.color = ColorRGBA(*colors[i], 0.9) if feasible[i] else ColorRGBA(*REJECTED_RGBA)
        markers.markers.append(arrow)
    return markers


def pose_stamped(pose: np.ndarray, header: Header) -> PoseStamped:
    return PoseStamped(header=header, pose=matrix_to_pose(np.asarray(pose, dtype=float)))


def sensor_path(poses, header: Header) -> Path:
    """nav_msgs/Path of the sensor's poses (world <- sensor, 4x4) in the order they were taken."""
    return Path(header=header, poses=[pose_stamped(p, header) for p in poses])


def frustum_marker(pose: np.ndarray, fov_h_rad: float, fov_v_rad: float, range_m: tuple, header: Header) -> Marker:
    """LINE_LIST of a view's frustum (pose world <- sensor, full angles, (near, far) range m)."""
    pose = np.asarray(pose, dtype=float)
    tan_h, tan_v = np.tan(fov_h_rad / 2.0), np.tan(fov_v_rad / 2.0)
    corners = []
    for depth in range_m:
        corners.append(
            [[sx * tan_h * depth, sy * tan_v * depth, depth] for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        )
    near, far = (np.asarray(c) @ pose[:3, :3].T + pose[:3, 3] for c in corners)
    origin = pose[:3, 3]
    segments = []
    for ring in (near, far):
        segments += [(ring[i], ring[(i + 1) % 4]) for i in range(4)]
    segments += [(origin, far[i]) for i in range(4)]
    marker = Marker(header=header, ns="frustum", id=0, type=Marker.LINE_LIST, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = 0.002
    marker.color = ColorRGBA(0.2, 0.9, 1.0, 0.8)
    marker.points = [Point(*p) for segment in segments for p in segment]
    return marker


def mesh_marker(
    vertices_m: np.ndarray, faces: np.ndarray, header: Header, max_triangles: int = MAX_TRIANGLES
) -> Marker:
    """TRIANGLE_LIST of a mesh (world frame); beyond ``max_triangles`` every k-th triangle (a preview)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) > max_triangles:
        faces = faces[:: int(np.ceil(len(faces) / max_triangles))]
    marker = Marker(header=header, ns="mesh", id=0, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 1.0
    marker.color = ColorRGBA(*MESH_RGBA)
    corners = np.asarray(vertices_m, dtype=float)[faces.reshape(-1)]
    marker.points = [Point(*p) for p in corners.tolist()]
    return marker
