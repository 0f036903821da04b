"""The ``scene_publisher`` node: the station scene (table, obstacles, part) as a latched MarkerArray.

Parameters: ~scene (path, default config/scene.yaml), ~publish_part (true: also the scene file's part).
Topic: ~markers (visualization_msgs/MarkerArray).
"""

from __future__ import annotations

import rospy
from visualization_msgs.msg import MarkerArray

from agiprobot_measurement.ros.markers import scene_marker_array
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import flag, param
from agiprobot_measurement.station import Scene, load_scene

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


def _start():
    scene = load_scene(param("~scene", None) or None)
    return publish_scene(scene, param("~publish_part", True, flag))


def main():
    run_node("scene_publisher", _start).unregister()
