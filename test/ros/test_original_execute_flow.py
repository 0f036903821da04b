#!/usr/bin/env python3
"""rostest: the original planner's ``execute()`` flow, written as its script did, against the station's real-cell
names only.

The original's ``TrajectoryManager.execute`` (beckersven/robot_control_software, agiprobot_measurement
trajectory_manager.py) switched the stitcher off with ``/switch_stitch_mode`` (std_srvs/SetBool, after waiting 5 s
for the service) before each approach and on before each measurement trajectory, executed each segment (through
MoveIt there; here straight to the UR driver's ``/scaled_pos_joint_traj_controller/follow_joint_trajectory``, which
move_group's execution would have called), waited 0.1 s between segments and switched stitching off at the end. This
script does exactly that with nothing of the project but the planner (for the segments), so it shows that the
names and types a script of the original needs are served: the stitched cloud (``stitched_point_cloud``,
sensor_msgs/PointCloud in the world frame) grows during measurement segments only and lies on the part.
The part is handed to the simulated sensor first (``/scancontrol_driver/set_target``, simulation only).
"""

import threading
import time
import unittest

import actionlib
import numpy as np
import rospy
import rostest
import trimesh
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal, FollowJointTrajectoryResult
from sensor_msgs.msg import JointState, PointCloud
from std_srvs.srv import SetBool, Trigger

from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.ros.conversions import joint_trajectory_to_msg
from agiprobot_measurement.srv import SetScanTarget
from agiprobot_measurement.station import PACKAGE_ROOT, load_robot_config

CUBE = str(PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl")
ACTION = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"


class OriginalExecuteFlowTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("original_execute_flow")
        cls.lock = threading.Lock()
        cls.joint_state = None
        cls.stitched = None
        rospy.Subscriber("/joint_states", JointState, cls._on_joint_state, queue_size=1)
        rospy.Subscriber("/stitched_point_cloud", PointCloud, cls._on_stitched, queue_size=5)
        deadline = time.monotonic() + 60
        while cls.joint_state is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert cls.joint_state is not None, "the station publishes no /joint_states"
        cls.manager = TrajectoryManager()
        cls.manager.current_state = cls.joint_state.copy()
        cls.manager.load_target_mesh(CUBE)
        cls.points, views = cls.manager.generate_samples_and_viewpoints(0.005, 0.1, 4, "none")
        ordered = cls.manager.connect_viewpoints(cls.manager.solve_scp(views, "greedy"))
        assert len(ordered) >= 2, f"need 2 views, planned {len(ordered)}"
        cls.segments = cls.manager.convert_viewpointlist_to_execution_plan(ordered[:2])

    @classmethod
    def _on_joint_state(cls, msg):
        with cls.lock:
            by_name = dict(zip(msg.name, msg.position, strict=True))
            cls.joint_state = np.array([by_name[n] for n in load_robot_config().joint_names])

    @classmethod
    def _on_stitched(cls, msg):
        with cls.lock:
            cls.stitched = msg

    def stitched_points_m(self) -> np.ndarray:
        with self.lock:
            cloud = self.stitched
        if cloud is None:
            return np.zeros((0, 3))
        return np.array([[p.x, p.y, p.z] for p in cloud.points]).reshape(-1, 3)

    def test_stitching_only_during_measurement_segments_with_the_original_names(self):
        # simulation only: the sensor scans the planned part where the planner put it
        params = self.manager.parameters
        placement = np.asarray(params["part_transform_mm"], dtype=float).reshape(-1).tolist()
        rospy.wait_for_service("/scancontrol_driver/set_target", timeout=10)
        reply = rospy.ServiceProxy("/scancontrol_driver/set_target", SetScanTarget)(CUBE, "mm", placement)
        self.assertTrue(reply.success, reply.message)

        # ---- the original's execute(), line for line in its order
        rospy.wait_for_service("/switch_stitch_mode", timeout=5)
        switch = rospy.ServiceProxy("/switch_stitch_mode", SetBool)
        self.assertTrue(rospy.ServiceProxy("/clear_stitched_point_cloud", Trigger)().success)
        robot = actionlib.SimpleActionClient(ACTION, FollowJointTrajectoryAction)
        self.assertTrue(robot.wait_for_server(rospy.Duration(10)))
        counts = []
        for index, segment in enumerate(self.segments):
            measuring = index % 2 == 1  # C-M-C-M: approaches and measurement trajectories alternate
            answer = switch(measuring)
            self.assertTrue(answer.success)
            self.assertEqual(answer.message, "activated stitching" if measuring else "deactivated stitching")
            trajectory = joint_trajectory_to_msg(segment.trajectory)
            trajectory.header.stamp = rospy.Time(0)
            robot.send_goal(FollowJointTrajectoryGoal(trajectory=trajectory))
            self.assertTrue(robot.wait_for_result(rospy.Duration(segment.trajectory.duration + 30.0)))
            self.assertEqual(robot.get_result().error_code, FollowJointTrajectoryResult.SUCCESSFUL)
            rospy.sleep(0.1)
            if not measuring:
                counts.append(len(self.stitched_points_m()))
        self.assertEqual(switch(False).message, "deactivated stitching")
        time.sleep(1.5)  # the last stitched cloud is published at switch-off
        counts.append(len(self.stitched_points_m()))

        # nothing before the first measurement; the approach between the two views added nothing after the
        # first view's cloud; the second view added points
        self.assertEqual(counts[0], 0, "the stitcher stitched during the first approach")
        self.assertGreater(counts[1], 0, "the first measurement segment stitched nothing")
        self.assertGreater(counts[2], counts[1], "the second measurement segment added nothing")
        points_mm = self.stitched_points_m() * 1000.0
        # every stitched point lies on the part (the sensor's noise and the display thinning aside)
        distance_mm = np.abs(trimesh.proximity.signed_distance(self.manager.target_mesh, points_mm))
        self.assertLess(float(np.percentile(distance_mm, 95)), 1.0)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "original_execute_flow", OriginalExecuteFlowTest)
