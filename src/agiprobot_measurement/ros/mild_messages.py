"""ROS messages of the MILD nodes: state conversions, the map as OccupancyGrid, frustum and IK markers (pose and
transform conversions: :mod:`agiprobot_measurement.ros.conversions`).

Needs the message packages (geometry_msgs, nav_msgs, visualization_msgs and this package's), not a master. Metres
and radians throughout.
"""

from __future__ import annotations

import numpy as np
from asr_robot_model_services.msg import RobotStateMessage
from geometry_msgs.msg import Point, Quaternion
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.common.geometry import yaw_quaternion
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.occupancy_map import OccupancyMap
from agiprobot_measurement.mild.state import RobotState

__all__ = [
    "BLUE",
    "FRUSTUM_COLOUR",
    "GREEN",
    "RED",
    "arrow",
    "base_quaternion",
    "delete_all",
    "frustum_marker_array",
    "ik_markers",
    "occupancy_from_msg",
    "occupancy_grid_msg",
    "sphere",
    "state_from_msg",
    "state_to_msg",
    "yaw_of",
]

GREEN = (0.1, 0.8, 0.1, 1.0)
BLUE = (0.1, 0.3, 1.0, 1.0)
RED = (0.9, 0.1, 0.1, 1.0)
FRUSTUM_COLOUR = (1.0, 0.6, 0.0, 1.0)


def state_from_msg(msg: RobotStateMessage) -> RobotState:
    return RobotState(msg.pan, msg.tilt, msg.rotation, msg.x, msg.y)


def state_to_msg(state: RobotState) -> RobotStateMessage:
    return RobotStateMessage(pan=state.pan, tilt=state.tilt, rotation=state.rotation, x=state.x, y=state.y)


def yaw_of(q: Quaternion) -> float:
    """Rotation about z (rad) of a quaternion (the base's heading)."""
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


def base_quaternion(rotation_rad: float) -> Quaternion:
    return Quaternion(*yaw_quaternion(rotation_rad))


def occupancy_grid_msg(grid: OccupancyMap, frame_id: str, stamp, inflated: bool = False) -> OccupancyGrid:
    msg = OccupancyGrid()
    msg.header = Header(frame_id=frame_id, stamp=stamp)
    msg.info.map_load_time = stamp
    msg.info.resolution = grid.resolution_m
    msg.info.height, msg.info.width = grid.shape
    msg.info.origin.position = Point(grid.origin_xy_m[0], grid.origin_xy_m[1], 0.0)
    msg.info.origin.orientation = base_quaternion(grid.origin_yaw_rad)
    data = grid.costmap if inflated else grid.occupancy
    msg.data = data.astype(np.int8).ravel().tolist()  # rows from the origin upwards: OccupancyGrid's order
    return msg


def occupancy_from_msg(
    msg: OccupancyGrid, inscribed_radius_m: float, inflation_radius_m: float, cost_scaling_per_m: float, source: str
) -> OccupancyMap:
    """A received nav_msgs/OccupancyGrid (a map_server's /map) as the model's map, inflated with the given radii.
    A grid whose data does not match width x height is an InputError naming ``source``."""
    width, height = int(msg.info.width), int(msg.info.height)
    if width * height == 0 or len(msg.data) != width * height:
        raise InputError(f"{source}: OccupancyGrid of {width} x {height} cells carries {len(msg.data)} values")
    values = np.asarray(msg.data, dtype=np.int16).reshape(height, width)
    values = np.where((values < 0) | (values > 100), -1, values).astype(np.int8)
    origin = msg.info.origin
    return OccupancyMap(
        values,
        float(msg.info.resolution),
        np.array([origin.position.x, origin.position.y]),
        yaw_of(origin.orientation),
        inscribed_radius_m,
        inflation_radius_m,
        cost_scaling_per_m,
        source=source,
    )


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


def delete_all(frame_id, stamp) -> Marker:
    marker = Marker()
    marker.header = Header(frame_id=frame_id, stamp=stamp)
    marker.action = Marker.DELETEALL
    return marker


def frustum_marker_array(corners: np.ndarray, frame_id: str, stamp, ns: str = "camera_frustum") -> MarkerArray:
    """The frustum's 12 edges (LINE_LIST) from the 8 corners of MildRobotModel.frustum_corners."""
    lines = _marker(frame_id, stamp, ns, 0, Marker.LINE_LIST, FRUSTUM_COLOUR, (0.01, 0.0, 0.0))
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
