#!/usr/bin/env python3
"""rostest: replay.launch plays a bag with use_sim_time; joint states, clock and tf come from the bag."""

import threading
import unittest

import numpy as np
import rosbag
import rospy
import rostest
import tf2_ros
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState


class ReplayTest(unittest.TestCase):
    def test_replay_reproduces_the_bag(self):
        rospy.init_node("test_replay")
        self.assertTrue(rospy.get_param("/use_sim_time"), "replay.launch must set use_sim_time")
        with rosbag.Bag(rospy.get_param("~bag")) as bag:
            recorded = {m.header.stamp: m.position for _, m, _ in bag.read_messages(topics=["/joint_states"])}
            start, end = bag.get_start_time(), bag.get_end_time()
        replayed, clocks = {}, []
        done = threading.Event()

        def on_joint_state(msg):
            replayed[msg.header.stamp] = msg.position
            if msg.header.stamp.to_sec() >= end - 0.5:
                done.set()

        joint_sub = rospy.Subscriber("/joint_states", JointState, on_joint_state)
        rospy.Subscriber("/clock", Clock, lambda m: clocks.append(m.clock.to_sec()))
        buffer = tf2_ros.Buffer()
        tf2_ros.TransformListener(buffer)
        self.assertTrue(done.wait(timeout=60.0), "the bag did not play to its end")
        joint_sub.unregister()  # the subscriber must stop adding before we compare
        rospy.sleep(0.3)
        print(f"bag: {len(recorded)} joint states over {end - start:.1f} s; replayed {len(replayed)}")
        self.assertGreater(len(replayed), 0.9 * len(recorded))
        for stamp, position in replayed.items():
            np.testing.assert_allclose(position, recorded[stamp], atol=1e-12)
        # simulated time follows the bag, not the wall clock
        self.assertGreater(len(clocks), 10)
        self.assertTrue(start - 1.0 <= clocks[-1] <= end + 1.0)
        now = rospy.Time.now().to_sec()
        self.assertTrue(start - 1.0 <= now <= end + 1.0, f"rospy time {now} is not the bag's time")
        transform = buffer.lookup_transform("world", "laser_emitter_frame", rospy.Time(0), rospy.Duration(5.0))
        self.assertGreater(abs(transform.transform.translation.z), 0.0)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "replay", ReplayTest)
