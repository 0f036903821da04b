"""ROS messages of the MILD nodes: state conversions and the map as OccupancyGrid (pose and transform conversions:
:mod:`agiprobot_measurement.ros.conversions`; the frustum and IK markers: :mod:`agiprobot_measurement.ros.markers`).

Needs the message packages (geometry_msgs, nav_msgs, visualization_msgs and this package's), not a master. Metres
and radians throughout.
"""

from __future__ import annotations

import numpy as np
from asr_robot_model_services.msg import RobotStateMessage
from geometry_msgs.msg import Point, Quaternion
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import Header

from agiprobot_measurement.common.geometry import yaw_quaternion
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.occupancy_map import OccupancyMap
from agiprobot_measurement.mild.state import RobotState

__all__ = [
    "base_quaternion",
    "occupancy_from_msg",
    "occupancy_grid_msg",
    "state_from_msg",
    "state_to_msg",
    "yaw_of",
]


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
