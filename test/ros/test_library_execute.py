#!/usr/bin/env python3
"""rostest: ``TrajectoryManager.execute`` in a user's ROS process drives the running station, as the original's
``execute`` drove the robot through MoveIt, and publishes the points each view measures."""

import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from sensor_msgs.msg import JointState, PointCloud, PointCloud2

from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.ros.plugins import in_ros_process  # registers the station executor
from agiprobot_measurement.station import PACKAGE_ROOT, load_robot_config

CUBE = str(PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl")


class LibraryExecuteTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("original_style_script")
        cls.lock = threading.Lock()
        cls.joint_state = None
        cls.measured_clouds = []
        cls.profiles = 0
        rospy.Subscriber("/joint_states", JointState, cls._on_joint_state, queue_size=1)
        rospy.Subscriber("/currently_measured_points", PointCloud, cls._on_measured, queue_size=50)
        rospy.Subscriber("/laser_scanner/profile", PointCloud2, cls._on_profile, queue_size=1000)
        deadline = time.monotonic() + 60
        while cls.joint_state is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert cls.joint_state is not None, "the station publishes no /joint_states"
        cls.manager = TrajectoryManager()
        cls.manager.current_state = cls.joint_state.copy()  # plan from where the robot is
        cls.manager.load_target_mesh(CUBE)
        cls.points, views = cls.manager.generate_samples_and_viewpoints(0.005, 0.1, 4, "none")
        cls.ordered = cls.manager.connect_viewpoints(cls.manager.solve_scp(views, "greedy"))
        assert len(cls.ordered) >= 3, f"need 3 views, planned {len(cls.ordered)}"

    @classmethod
    def _on_joint_state(cls, msg):
        with cls.lock:
            by_name = dict(zip(msg.name, msg.position, strict=True))  # the driver's order is alphabetical
            cls.joint_state = np.array([by_name[n] for n in load_robot_config().joint_names])

    @classmethod
    def _on_measured(cls, msg):
        with cls.lock:
            cls.measured_clouds.append(msg)

    @classmethod
    def _on_profile(cls, msg):
        with cls.lock:
            cls.profiles += 1

    def state(self):
        with self.lock:
            return self.joint_state.copy()

    def test_1_views_drive_the_station_and_publish_their_points(self):
        self.assertTrue(in_ros_process())
        first_two = self.ordered[:2]
        started = time.monotonic()
        self.assertTrue(self.manager.execute(first_two, surface_points=self.points))
        elapsed_s = time.monotonic() - started
        planned_s = sum(
            v.get_trajectory_to_view().duration + v.get_trajectory_for_measurement().duration for v in first_two
        )
        # the controller runs the trajectories in real time: no instant simulation
        self.assertGreater(elapsed_s, 0.8 * planned_s)
        time.sleep(0.5)
        end = first_two[-1].get_trajectory_for_measurement().end
        np.testing.assert_allclose(self.state(), end, atol=2e-3)
        with self.lock:
            clouds, profiles = list(self.measured_clouds), self.profiles
        self.assertEqual(len(clouds), 2, "one /currently_measured_points message per measured view")
        for cloud, view in zip(clouds, first_two, strict=True):
            self.assertEqual(cloud.header.frame_id, "world")
            self.assertEqual(len(cloud.points), len(view.measurable_indices))
            expected_m = np.asarray(self.points)[view.measurable_indices] / 1000.0
            got_m = np.array([[p.x, p.y, p.z] for p in cloud.points])
            np.testing.assert_allclose(got_m, expected_m, atol=1e-6)
        self.assertGreater(profiles, 0, "the scanner stitched during the measurement segments")

    def test_2_robot_trajectory_shaped_segments_execute_on_the_station(self):
        segments = self.manager.convert_viewpointlist_to_execution_plan(self.ordered[2:3])
        shaped = [s.joint_trajectory for s in segments]  # what a user's code would reach for first
        self.assertEqual(len(shaped[0].points), len(segments[0].trajectory))
        self.assertTrue(self.manager.execute(segments))
        time.sleep(0.5)
        np.testing.assert_allclose(self.state(), segments[-1].trajectory.end, atol=2e-3)

    def test_3_simulated_executor_stays_available_and_does_not_move_the_robot(self):
        before = self.state()
        back = self.manager.convert_viewpointlist_to_execution_plan(self.ordered[:1])
        self.manager.current_state = back[0].trajectory.start.copy()
        started = time.monotonic()
        self.assertTrue(self.manager.execute(back, executor="simulated"))
        self.assertLess(time.monotonic() - started, 1.0)
        time.sleep(0.3)
        np.testing.assert_allclose(self.state(), before, atol=1e-6)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "test_library_execute", LibraryExecuteTest)
