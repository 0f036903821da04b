#!/usr/bin/env python3
"""rostest: rviz renders the station off-screen, and the robot is visible in the picture.

Two snapshots, robot at 'home' and at 'up': both must show a scene (non-background pixels), and they must
differ where the robot moved, which only happens if rviz draws the robot model from tf.
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
from station_test_utils import place_robot

from agiprobot_measurement.ros.rviz_snapshot import OffscreenRviz
from agiprobot_measurement.station import PACKAGE_ROOT

ARTIFACTS = Path(os.environ.get("ROS_HOME", "/tmp")) / "test_artifacts"


class RvizSnapshotTest(unittest.TestCase):
    def test_snapshot_shows_the_robot(self):
        rospy.init_node("test_rviz_snapshot")
        place_robot("home")
        with OffscreenRviz(PACKAGE_ROOT / "rviz" / "station.rviz") as rviz:
            home = rviz.grab(ARTIFACTS / "station_home.png", settle_s=40)
            place_robot("up")
            rospy.sleep(0.5)
            up = rviz.grab(ARTIFACTS / "station_up.png", settle_s=20)
        a = cv2.imread(str(home.path)).astype(int)
        b = cv2.imread(str(up.path)).astype(int)
        changed = int((np.abs(a - b).max(axis=2) > 30)[60:-10].sum())
        print(f"snapshot home: {home.path} ({home.non_background_pixels} non-background pixels of {home.view_pixels})")
        print(f"snapshot up:   {up.path} ({up.non_background_pixels} non-background pixels)")
        print(f"pixels changed by the robot's motion: {changed}")
        self.assertGreater(home.non_background_fraction, 0.10)
        self.assertGreater(up.non_background_fraction, 0.10)
        self.assertGreater(changed, 5000, "moving the robot did not change the picture: robot not rendered")


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "rviz_snapshot", RvizSnapshotTest)
