"""The ``scene_publisher`` node: the station scene (table, obstacles, part) as a latched MarkerArray.

Parameters: ~scene (path, default config/scene.yaml), ~publish_part (true: also the scene file's part).
Topic: ~markers (visualization_msgs/MarkerArray).
"""

from __future__ import annotations

import rospy
from visualization_msgs.msg import MarkerArray

from agiprobot_measurement.ros.markers import scene_marker_array
from agiprobot_measurement.station import ConfigError, Scene, load_scene

__all__ = [
    "main",
    "publish_scene",
]


def publish_scene(scene: Scene, publish_part: bool = True) -> rospy.Publisher:
    """Publishes ``scene`` (without its part unless ``publish_part``) latched on ``~markers``."""
    publisher = rospy.Publisher("~markers", MarkerArray, queue_size=1, latch=True)
    if not publish_part:
        # another node (trajectory_manager) shows the part it actually plans for
        scene = scene.without_part()
    publisher.publish(scene_marker_array(scene))
    rospy.loginfo("scene_publisher: %d objects%s", len(scene.objects), " and the part" if scene.part else "")
    return publisher


def main():
    rospy.init_node("scene_publisher")
    try:
        scene = load_scene(rospy.get_param("~scene", None) or None)
    except ConfigError as exc:
        rospy.logfatal("scene_publisher: %s", exc)
        raise SystemExit(1) from exc
    publisher = publish_scene(scene, bool(rospy.get_param("~publish_part", True)))
    rospy.spin()
    publisher.unregister()
