#!/usr/bin/env python3
"""rostest: rviz/mild.rviz renders the map, the MILD and its camera frustum off-screen.

Two snapshots with the robot at two places: the red base and the orange frustum lines must be visible in both and
must have moved between them, which only happens when rviz draws the robot model from tf and the frustum markers.
"""

import os
import sys
import unittest
from pathlib import Path

import cv2
import numpy as np
import rospy
import rostest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mild_test_utils import place, proxies

from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.rviz_snapshot import OffscreenRviz
from agiprobot_measurement.station import PACKAGE_ROOT

ARTIFACTS = Path(os.environ.get("ROS_HOME", "/tmp")) / "test_artifacts"


def masks(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of the base's red (0.75, 0.2, 0.15, shaded) and of the frustum's orange (1.0, 0.6, 0.0) in the 3D view."""
    rgb = cv2.imread(str(path))[60:-10, :, ::-1].astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    red = (r > 90) & (r > 2.5 * g) & (r > 2.5 * b)
    orange = (r > 200) & (g > 110) & (g < 190) & (b < 60)
    return red, orange


def centroid(mask: np.ndarray) -> np.ndarray:
    return np.argwhere(mask).mean(axis=0)


class MildRvizSnapshotTest(unittest.TestCase):
    def test_robot_frustum_and_map_are_drawn(self):
        rospy.init_node("test_mild_rviz_snapshot")
        services = proxies()
        place(services, RobotState(0.0, 0.0, 0.0, 1.0, 1.0))
        with OffscreenRviz(PACKAGE_ROOT / "rviz" / "mild.rviz") as rviz:
            first = rviz.grab(ARTIFACTS / "mild_first.png", settle_s=20)
            place(services, RobotState(0.3, -0.2, 1.2, 3.0, 2.5))
            rospy.sleep(1.0)  # the frustum is republished at 2 Hz
            second = rviz.grab(ARTIFACTS / "mild_second.png", settle_s=15)
        print(f"snapshots: {first.path}, {second.path}")
        red_a, orange_a = masks(first.path)
        red_b, orange_b = masks(second.path)
        print(
            f"red base pixels {red_a.sum()} / {red_b.sum()}, orange frustum pixels {orange_a.sum()} / {orange_b.sum()}"
        )
        self.assertGreater(first.non_background_fraction, 0.3, "the map should fill much of the view")
        for red, orange in ((red_a, orange_a), (red_b, orange_b)):
            self.assertGreater(red.sum(), 500, "the MILD's base is not drawn")
            self.assertGreater(orange.sum(), 200, "the camera frustum is not drawn")
        self.assertGreater(np.linalg.norm(centroid(red_a) - centroid(red_b)), 20.0, "the robot did not move on screen")
        self.assertGreater(np.linalg.norm(centroid(orange_a) - centroid(orange_b)), 20.0, "the frustum did not move")


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "mild_rviz_snapshot", MildRvizSnapshotTest)
