"""Every rviz marker of the package: colours, clear markers, primitives and the builders per domain, in one place
(each domain's colours head its section).

- primitives: :func:`clear` (a DELETEALL, so a smaller set replaces a larger one), :func:`arrow`, :func:`sphere`;
- station scene: :func:`scene_marker_array` (table, obstacles, chessboards, part);
- measurement planning: :func:`scan_line_markers`, :func:`path_marker`, :func:`part_markers`;
- MILD: :func:`frustum_marker_array` (the camera frustum), :func:`ik_markers` (the IK's picture);
- 3D next-best-view: :func:`voxel_markers` (one CUBE_LIST per layer, as octomap_server's
  ``occupied_cells_vis_array``), :func:`candidate_markers` (arrows along the sensor's z axis, feasible ones coloured
  by utility, rejected ones grey in ``rejected/<reason>`` namespaces), :func:`frustum_marker`, :func:`mesh_marker`.

Metres and radians; needs the message packages only.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.ros.conversions import matrix_to_pose
from agiprobot_measurement.ros.errors import MessageError
from agiprobot_measurement.station import Scene, chessboard_dark_squares

__all__ = [
    "BLUE",
    "FRONTIER_RGBA",
    "GREEN",
    "MAX_CUBES",
    "MAX_TRIANGLES",
    "MESH_RGBA",
    "MILD_FRUSTUM_RGBA",
    "NBV_FRUSTUM_RGBA",
    "OCCLUSION_RGBA",
    "PART_RGBA",
    "PATH_RGBA",
    "RED",
    "REJECTED_RGBA",
    "SCAN_LINE_RGBA",
    "arrow",
    "candidate_markers",
    "clear",
    "deviation_markers",
    "frustum_marker",
    "frustum_marker_array",
    "ik_markers",
    "mesh_marker",
    "part_markers",
    "path_marker",
    "scan_line_markers",
    "scene_marker_array",
    "sphere",
    "utility_colors",
    "voxel_markers",
]


# ---------------------------------------------------------------------------------------------------- primitives
def clear(header: Header) -> Marker:
    """A DELETEALL marker: every marker of the topic before it is removed."""
    marker = Marker(action=Marker.DELETEALL)
    marker.header = header
    return marker


def _marker(frame_id: str, stamp, ns: str, marker_id: int, marker_type: int, colour, scale) -> Marker:
    marker = Marker()
    marker.header = Header(frame_id=frame_id, stamp=stamp)
    marker.ns, marker.id, marker.type, marker.action = ns, marker_id, marker_type, Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x, marker.scale.y, marker.scale.z = scale
    marker.color = ColorRGBA(*colour)
    return marker


def arrow(frame_id, stamp, ns, marker_id, start, end, colour, shaft_m=0.02) -> Marker:
    marker = _marker(frame_id, stamp, ns, marker_id, Marker.ARROW, colour, (shaft_m, 2 * shaft_m, 3 * shaft_m))
    marker.points = [Point(*np.asarray(start, dtype=float)), Point(*np.asarray(end, dtype=float))]
    return marker


def sphere(frame_id, stamp, ns, marker_id, centre, colour, diameter_m=0.05) -> Marker:
    marker = _marker(frame_id, stamp, ns, marker_id, Marker.SPHERE, colour, (diameter_m,) * 3)
    marker.pose.position = Point(*np.asarray(centre, dtype=float))
    return marker


# --------------------------------------------------------------------------------------------------- station scene
def _chessboard_squares(board, frame_id: str, namespace: str, marker_id: int) -> Marker:
    """The dark squares of a chessboard object as one CUBE_LIST in the board frame (printed on its face)."""
    marker = Marker()
    marker.header.frame_id = frame_id
    marker.ns = namespace
    marker.id = marker_id
    marker.action = Marker.ADD
    marker.type = Marker.CUBE_LIST
    marker.pose = matrix_to_pose(board.pose)
    marker.scale.x = marker.scale.y = board.square_m
    marker.scale.z = 0.0004
    marker.color.r = marker.color.g = marker.color.b = 0.05
    marker.color.a = 1.0
    marker.points = [
        Point(x=float(x), y=float(y), z=0.0002) for x, y in chessboard_dark_squares(board.inner_corners, board.square_m)
    ]
    return marker


def scene_marker_array(scene: Scene, namespace: str = "scene") -> MarkerArray:
    markers = MarkerArray()
    for i, obj in enumerate(scene.objects):
        marker = Marker()
        marker.header.frame_id = scene.frame_id
        marker.ns = namespace
        marker.id = i
        marker.action = Marker.ADD
        marker.pose = matrix_to_pose(obj.pose)
        marker.color.r, marker.color.g, marker.color.b, marker.color.a = obj.color_rgba
        if obj.type in ("box", "chessboard"):
            size, centre = obj.solid_box()
            marker.type = Marker.CUBE
            marker.pose = matrix_to_pose(centre)
            marker.scale.x, marker.scale.y, marker.scale.z = (float(v) for v in size)
            if obj.type == "chessboard":
                markers.markers.append(_chessboard_squares(obj, scene.frame_id, f"{namespace}_chessboard", i))
        elif obj.type == "cylinder":
            marker.type = Marker.CYLINDER
            marker.scale.x = marker.scale.y = 2.0 * obj.radius_m
            marker.scale.z = obj.length_m
        elif obj.type == "sphere":
            marker.type = Marker.SPHERE
            marker.scale.x = marker.scale.y = marker.scale.z = 2.0 * obj.radius_m
        else:
            marker.type = Marker.MESH_RESOURCE
            marker.mesh_resource = f"file://{obj.mesh}"
            marker.scale.x = marker.scale.y = marker.scale.z = obj.mesh_scale
        markers.markers.append(marker)
    if scene.part is not None:
        marker = Marker()
        marker.header.frame_id = scene.frame_id
        marker.ns = "part"
        marker.id = 0
        marker.type = Marker.MESH_RESOURCE
        marker.mesh_resource = f"file://{scene.part.mesh}"
        marker.pose = matrix_to_pose(scene.part.pose)
        marker.scale.x = marker.scale.y = marker.scale.z = scene.part.scale_to_m
        marker.color.r, marker.color.g, marker.color.b, marker.color.a = scene.part.color_rgba
        markers.markers.append(marker)
    return markers


# ---------------------------------------------------------------------------------------------- measurement plan
#: measurement planning: scan lines, the scanner's path, the part
SCAN_LINE_RGBA = (1.0, 0.55, 0.0, 1.0)
PATH_RGBA = (0.3, 0.8, 1.0, 0.8)
PART_RGBA = (0.8, 0.8, 0.2, 1.0)


def scan_line_markers(scan_lines_mm, header) -> MarkerArray:
    """An arrow and a number per scan line ((start, end) mm), after a DELETEALL of the previous plan's."""
    markers = MarkerArray(markers=[clear(header)])
    for i, (start, end) in enumerate(scan_lines_mm):
        arrow = Marker(header=header, ns="scan_lines", id=i, type=Marker.ARROW, action=Marker.ADD)
        arrow.points = [Point(*(start / 1000.0)), Point(*(end / 1000.0))]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.004, 0.01, 0.015
        arrow.color = ColorRGBA(*SCAN_LINE_RGBA)
        arrow.pose.orientation.w = 1.0
        text = Marker(header=header, ns="view_numbers", id=i, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
        text.pose.position = Point(*(start / 1000.0 + [0, 0, 0.02]))
        text.pose.orientation.w = 1.0
        text.scale.z = 0.03
        text.color = ColorRGBA(1.0, 1.0, 1.0, 1.0)
        text.text = str(i + 1)
        markers.markers.extend([arrow, text])
    return markers


def path_marker(plan, kinematics, header) -> Marker:
    """The scanner's path through ``plan`` (every 0.1 s) as a line strip; empty without plan or kinematics."""
    path = Marker(header=header, ns="planned_path", id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    path.scale.x = 0.002
    path.color = ColorRGBA(*PATH_RGBA)
    path.pose.orientation.w = 1.0
    if plan is not None and kinematics is not None:
        for segment in plan.segments:
            trajectory = segment.trajectory
            times = np.linspace(0, trajectory.duration, max(2, int(trajectory.duration / 0.1)))
            positions, _, _ = trajectory.sample(times)
            tips = kinematics.fk_batch(positions)[:, :3, 3]
            path.points.extend(Point(*p) for p in tips)
    return path


def part_markers(part, header) -> MarkerArray:
    """The part's mesh where the plan puts it (a planning ``PlanPart``: mesh file, placement in mm; empty without
    a part)."""
    markers = MarkerArray()
    if part is not None:
        placement_mm = part.placement_mm
        marker = Marker(header=header, ns="part", id=0, type=Marker.MESH_RESOURCE, action=Marker.ADD)
        marker.mesh_resource = f"file://{part.mesh_file}"
        scale = np.linalg.norm(placement_mm[:3, 0]) / 1000.0  # the file's unit -> m
        rigid = placement_mm.copy()
        rigid[:3, :3] /= np.linalg.norm(placement_mm[:3, :3], axis=0)
        rigid[:3, 3] /= 1000.0
        marker.pose = matrix_to_pose(rigid)
        marker.scale.x = marker.scale.y = marker.scale.z = scale
        marker.color = ColorRGBA(*PART_RGBA)
        markers.markers.append(marker)
    return markers


# ---------------------------------------------------------------------------------------------------------- MILD
#: MILD: the IK's picture (requested view green; solutions blue, pose corrections red) and the camera frustum
GREEN = (0.1, 0.8, 0.1, 1.0)
BLUE = (0.1, 0.3, 1.0, 1.0)
RED = (0.9, 0.1, 0.1, 1.0)
MILD_FRUSTUM_RGBA = (1.0, 0.6, 0.0, 1.0)


def frustum_marker_array(corners: np.ndarray, frame_id: str, stamp, ns: str = "camera_frustum") -> MarkerArray:
    """The frustum's 12 edges (LINE_LIST) from the 8 corners of MildRobotModel.frustum_corners."""
    lines = _marker(frame_id, stamp, ns, 0, Marker.LINE_LIST, MILD_FRUSTUM_RGBA, (0.01, 0.0, 0.0))
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    for a, b in edges:
        lines.points += [Point(*corners[a]), Point(*corners[b])]
    return MarkerArray(markers=[lines])


def ik_markers(model, solution, requested_position, frame_id: str, stamp, colour=BLUE, suffix: str = "") -> list:
    """The IK's picture (the original's namespaces): the requested view (green), the solution's chain from the base
    through pan, tilt and camera to the achieved view centre, and every rated pan sample's base pose coloured from
    red (rating 0) to green (rating 1)."""
    markers = [
        arrow(frame_id, stamp, "targetCameraVector", 0, requested_position, solution.requested_view_centre_m, GREEN)
    ]
    if solution.state is None:
        return markers
    f = model.kinematics.frames
    poses = model.frame_poses(solution.state)
    point = {name: pose[:3, 3] for name, pose in poses.items()}
    base = point[f.base_frame]
    chain = [  # (namespace, from, to): arrows; a point alone: sphere
        ("baseToPanVector", base, point[f.ptu_pan_frame]),
        ("panBaseVector", point[f.ptu_pan_frame_rotated], None),
        ("panToTiltVector", point[f.ptu_pan_frame_rotated], point[f.ptu_tilt_frame]),
        ("tiltBaseVector", point[f.ptu_tilt_frame], None),
        ("tiltToCamVector", point[f.ptu_tilt_frame], point[f.camera_mount_frame]),
        ("camToActualViewCenterVector", point[f.camera_mount_frame], solution.achieved_view_centre_m),
    ]
    markers += [
        sphere(frame_id, stamp, "basePose" + suffix, 0, base, colour, 0.08),
        arrow(frame_id, stamp, "basePose" + suffix, 1, base, base + 0.3 * poses[f.base_frame][:3, 0], colour, 0.03),
    ]
    for ns, a, b in chain:
        if b is None:
            markers.append(sphere(frame_id, stamp, ns + suffix, 0, a, colour))
        else:
            markers.append(arrow(frame_id, stamp, ns + suffix, 0, a, b, colour))
    if solution.samples is not None:
        for i, (_, x, y, rotation, rating) in enumerate(solution.samples):
            start = np.array([x, y, 0.02])
            end = start + 0.15 * np.array([np.cos(rotation), np.sin(rotation), 0.0])
            rating = float(np.clip(rating, 0.0, 1.0))
            markers.append(arrow(frame_id, stamp, "iterationVector", i, start, end, (1 - rating, rating, 0, 1), 0.01))
    return markers


# ---------------------------------------------------------------------------------------- 3D next-best-view
#: 3D next-best-view: the view frustum, frontier and occlusion voxels, rejected candidates, the fused mesh
NBV_FRUSTUM_RGBA = (0.2, 0.9, 1.0, 0.8)
FRONTIER_RGBA = (1.0, 0.85, 0.0, 0.6)
OCCLUSION_RGBA = (0.9, 0.2, 0.9, 0.35)
REJECTED_RGBA = (0.55, 0.55, 0.55, 0.5)
MESH_RGBA = (0.75, 0.75, 0.8, 1.0)
#: a CUBE_LIST larger than this is thinned to every k-th voxel (rviz and the wire stay responsive)
MAX_CUBES = 200_000
#: a mesh larger than this is shown with every k-th triangle
MAX_TRIANGLES = 150_000


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
    markers = MarkerArray(markers=[clear(header)])
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


def deviation_markers(
    points_m: np.ndarray, rgb: np.ndarray, header: Header, point_m: float = 0.002, max_points: int = MAX_CUBES
) -> MarkerArray:
    """The inspected points (K, 3, world m) as one POINTS marker in namespace ``deviations``, each in its colour
    ``rgb`` (K, 3, uint8: the report's colour map), thinned evenly to ``max_points``."""
    points = np.asarray(points_m, dtype=float).reshape(-1, 3)
    colours = np.asarray(rgb, dtype=float).reshape(-1, 3) / 255.0
    if len(points) > max_points:
        keep = slice(None, None, int(np.ceil(len(points) / max_points)))
        points, colours = points[keep], colours[keep]
    markers = MarkerArray(markers=[clear(header)])
    marker = Marker(header=header, ns="deviations", id=0, type=Marker.POINTS, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = float(point_m)
    marker.color = ColorRGBA(1.0, 1.0, 1.0, 1.0)
    marker.points = [Point(*p) for p in points.tolist()]
    marker.colors = [ColorRGBA(r, g, b, 1.0) for r, g, b in colours.tolist()]
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
    markers = MarkerArray(markers=[clear(header)])
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
    marker.color = ColorRGBA(*NBV_FRUSTUM_RGBA)
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
