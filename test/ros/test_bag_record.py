#!/usr/bin/env python3
"""rostest: a bag recorded by station.launch during a motion replays and reproduces the joint states."""

import os
import subprocess
import sys
import time
import unittest
from pathlib import Path

import numpy as np
import rosbag
import rosnode
import rospy
import rostest
from sensor_msgs.msg import JointState

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_test_utils import LIMITS, NAMED, action_client, make_trajectory, place_robot

from agiprobot_measurement.motion.point_to_point import point_to_point


class BagRecordTest(unittest.TestCase):
    def test_recorded_motion_replays(self):
        rospy.init_node("test_bag_record")
        bag_path = Path(rospy.get_param("~bag"))
        bag_path.unlink(missing_ok=True)  # a bag of an earlier run; this run's is still <bag>.active
        live = {}
        sub = rospy.Subscriber("/joint_states", JointState, lambda m: live.__setitem__(m.header.stamp, m.position))
        place_robot("home")
        client = action_client()
        rospy.sleep(1.0)  # the recorder subscribes at start-up
        trajectory = point_to_point(NAMED["home"], NAMED["up"], LIMITS)
        client.send_goal(
            make_trajectory(
                trajectory.positions, trajectory.time_from_start, trajectory.velocities, trajectory.accelerations
            )
        )
        self.assertTrue(client.wait_for_result(rospy.Duration(trajectory.duration + 10)))
        self.assertTrue(client.get_result().success)
        rospy.sleep(0.5)
        sub.unregister()
        # stop the recorder cleanly: rosbag closes the bag and renames .bag.active -> .bag
        rosnode.kill_nodes(["/station_recorder"])
        for _ in range(100):
            if bag_path.exists():
                break
            time.sleep(0.1)
        self.assertTrue(bag_path.exists(), f"no bag at {bag_path}")

        with rosbag.Bag(str(bag_path)) as bag:
            recorded = {m.header.stamp: m.position for _, m, _ in bag.read_messages(topics=["/joint_states"])}
            tf_count = bag.get_message_count(topic_filters=["/tf"])
        self.assertGreater(tf_count, 50)
        moving = [stamp for stamp, pos in recorded.items() if 0.01 < np.abs(np.subtract(pos, NAMED["home"])).max()]
        self.assertGreater(len(moving), 100, "the bag does not contain the motion")
        common = set(recorded) & set(live)
        self.assertGreater(len(common), 0.9 * len(live) - 100)
        for stamp in common:
            np.testing.assert_allclose(recorded[stamp], live[stamp], atol=1e-12)

        # replay into another topic and compare with the bag's content
        replayed = {}
        rospy.Subscriber(
            "/replayed/joint_states", JointState, lambda m: replayed.__setitem__(m.header.stamp, m.position)
        )
        rospy.sleep(0.5)
        env = dict(os.environ)
        subprocess.run(
            ["rosbag", "play", "--quiet", "--rate=4", str(bag_path), "/joint_states:=/replayed/joint_states"],
            env=env,
            check=True,
            timeout=60,
        )
        rospy.sleep(0.5)
        print(f"recorded {len(recorded)} joint states, replayed {len(replayed)}")
        self.assertGreater(len(replayed), 0.95 * len(recorded))
        for stamp, position in replayed.items():
            np.testing.assert_allclose(position, recorded[stamp], atol=1e-12)
        final = replayed[max(replayed)]
        np.testing.assert_allclose(final, NAMED["up"], atol=1e-3)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "bag_record", BagRecordTest)
