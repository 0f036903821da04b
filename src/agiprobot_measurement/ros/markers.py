"""rviz markers for a station scene (table, obstacles, part). Needs the ROS message packages only."""

from __future__ import annotations

from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.ros.conversions import matrix_to_pose
from agiprobot_measurement.station import Scene, chessboard_dark_squares

__all__ = [
    "scene_marker_array",
]


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
