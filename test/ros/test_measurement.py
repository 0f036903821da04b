#!/usr/bin/env python3
"""rostest: the trajectory_manager node with the simulated station and laser line scanner.

The tests run in order (test_1..., test_2...): plan, execute (with an rviz snapshot during execution), cancel,
bad goals, services, and finally the recorded bag against the live figures.
"""

import os
import sys
import threading
import time
import unittest
from pathlib import Path

import numpy as np
import rosnode
import rospy
import rostest
import yaml
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import Pose
from sensor_msgs.msg import JointState, PointCloud, PointCloud2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_test_utils import JOINTS, quick_goal

from agiprobot_measurement.msg import ExecutePlanAction, ExecutePlanGoal, PlanMeasurementAction
from agiprobot_measurement.planning.plan.plan_io import load_execution_plan
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.ros.bag_coverage import coverage_from_bag
from agiprobot_measurement.ros.rviz_snapshot import OffscreenRviz
from agiprobot_measurement.srv import GetCoverageReport, LoadPlan, StorePlan
from agiprobot_measurement.station import PACKAGE_ROOT

ARTIFACTS = Path(os.environ.get("ROS_HOME", "/tmp")) / "test_artifacts"
STATE = {}  # shared between the ordered tests


class MeasurementNodeTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_measurement_node")
        cls.planner = ActionClient("/trajectory_manager/plan_measurement", PlanMeasurementAction)
        cls.executor = ActionClient("/trajectory_manager/execute_plan", ExecutePlanAction)
        assert cls.planner.wait_for_server(rospy.Duration(60)), "no plan_measurement action"
        assert cls.executor.wait_for_server(rospy.Duration(10)), "no execute_plan action"
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        # a bag of an earlier run; this run's is still <bag>.active until the recorder stops
        Path(rospy.get_param("~bag")).unlink(missing_ok=True)

    def _plan(self, goal, timeout_s=240.0, feedback=None):
        self.planner.send_goal(goal, feedback_cb=feedback)
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(timeout_s)), "planning timed out")
        return self.planner.get_state(), self.planner.get_result()

    # ------------------------------------------------------------------------------------- planning
    def test_1_plan_demo_part(self):
        stages = []
        plan_file = ARTIFACTS / "measurement_test_plan.yaml"
        plan_file.unlink(missing_ok=True)
        state, result = self._plan(
            quick_goal(plan_file=str(plan_file)),
            feedback=lambda fb: stages.append(fb.stage) if not stages or stages[-1] != fb.stage else None,
        )
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        for stage in ("sampling", "metrology", "mechanics", "set cover", "connection"):
            self.assertIn(stage, stages, f"no feedback for stage {stage}")
        self.assertGreaterEqual(result.coverage, 0.99)
        self.assertGreater(result.number_of_views, 0)
        # the three numbers: covered <= coverable by executable views <= metrologically coverable <= samples
        self.assertLessEqual(result.number_covered, result.number_coverable_executable)
        self.assertLessEqual(result.number_coverable_executable, result.number_coverable_metrology)
        self.assertLessEqual(result.number_coverable_metrology, result.number_of_samples)
        self.assertAlmostEqual(result.coverage, result.number_covered / result.number_coverable_executable, places=6)
        self.assertGreaterEqual(result.optimality_gap, 0.0)
        self.assertFalse(result.time_limit_hit)
        self.assertEqual(result.tilt_mode_used, "none")
        self.assertGreater(result.reachable_share, 0.9)
        self.assertEqual(result.plan_file, str(plan_file))
        plan = load_execution_plan(plan_file)
        self.assertEqual(len(plan.segments), 2 * result.number_of_views)
        STATE["plan"] = plan
        STATE["predicted"] = result.coverage
        print(f"planned {result.number_of_views} views, coverage {100 * result.coverage:.1f} %, stages {stages}")

    # ------------------------------------------------------------------------------------ execution
    def test_2_execute_plan(self):
        plan = STATE["plan"]
        joint_states, profiles, current, phases = [], [], [], []
        subs = [
            rospy.Subscriber(  # by name: the driver publishes the joints in alphabetical order
                "/joint_states",
                JointState,
                lambda m: joint_states.append(
                    np.array([dict(zip(m.name, m.position, strict=True))[n] for n in JOINTS])
                ),
            ),
            rospy.Subscriber("/laser_scanner/profile", PointCloud2, lambda m: profiles.append(time.monotonic())),
            rospy.Subscriber(
                "/currently_measured_points",
                PointCloud,  # as the original published it
                lambda m: current.append((time.monotonic(), len(m.points))),
            ),
        ]
        snapshot = {}

        def feedback(fb):
            phases.append((time.monotonic(), fb.phase, fb.segment))
            if fb.phase == "measure" and "thread" not in snapshot and fb.segment >= fb.number_of_segments // 2:
                snapshot["thread"] = threading.Thread(target=self._snapshot, args=(snapshot,), daemon=True)
                snapshot["thread"].start()

        self.executor.send_goal(ExecutePlanGoal(plan_file=""), feedback_cb=feedback)
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(300)), "execution timed out")
        result = self.executor.get_result()
        for sub in subs:
            sub.unregister()
        self.assertEqual(self.executor.get_state(), GoalStatus.SUCCEEDED, result.error)
        self.assertEqual(result.segments_executed, len(plan.segments))
        # the robot followed every segment: it passed through each segment's end within 1e-3 rad
        states = np.array(joint_states)
        for index, segment in enumerate(plan.segments):
            closest = np.abs(states - segment.trajectory.end).max(axis=1).min()
            self.assertLess(closest, 1e-3, f"segment {index + 1}: the robot never reached its end")
        # profiles and currently measured points only during measurement segments
        windows = []
        for (start, phase, _), nxt in zip(phases, [*phases[1:], (time.monotonic(), "", 0)], strict=True):
            if phase == "measure":
                windows.append((start, nxt[0]))
        self.assertTrue(profiles, "no scanner profiles during execution")
        slack = 1.0  # messages in flight between the phase feedback and the scanner switching
        outside = [t for t in profiles if not any(a - slack <= t <= b + slack for a, b in windows)]
        self.assertLess(len(outside), 0.02 * len(profiles), f"{len(outside)} profiles outside measurement segments")
        nonempty = [t for t, n in current if n > 0]
        self.assertGreaterEqual(len(nonempty), len(windows))
        for t in nonempty:
            self.assertTrue(any(a - slack <= t <= b + slack for a, b in windows))
        print(
            f"executed {result.segments_executed} segments; {len(profiles)} profiles; coverage predicted "
            f"{100 * result.predicted_coverage:.1f} %, measured {100 * result.measured_coverage:.1f} %"
        )
        self.assertLessEqual(abs(result.measured_coverage - result.predicted_coverage), 0.05)
        self.assertGreaterEqual(result.predicted_coverage, 0.99)
        STATE["measured"] = result.measured_coverage
        if "thread" in snapshot:
            snapshot["thread"].join(timeout=120)
        self.assertIn("stats", snapshot, snapshot.get("error", "no snapshot taken"))
        stats = snapshot["stats"]
        print(f"snapshot during execution: {stats}")
        self.assertGreater(stats["part"], 100, "the part is not visible")
        self.assertGreater(stats["robot"], 1000, "the robot is not visible")
        self.assertGreater(stats["measured_points"], 100, "no measured points visible")

    @staticmethod
    def _snapshot(out):
        import cv2

        try:
            with OffscreenRviz(PACKAGE_ROOT / "rviz" / "measurement.rviz") as rviz:
                shot = rviz.grab(ARTIFACTS / "measurement_execution.png", settle_s=20)
            image = cv2.imread(str(shot.path))[60:-10, :, ::-1].astype(int)
            r, g, b = image[..., 0], image[..., 1], image[..., 2]
            out["stats"] = {
                "file": str(shot.path),
                "non_background": shot.non_background_pixels,
                # yellow part (lit), blue-grey robot housings, light-blue measured cloud (unlit points)
                "part": int(((r > 90) & (g > 90) & (b < 0.7 * g) & (np.abs(r - g) < 60)).sum()),
                "robot": int(((b > r + 40) & (g < 170) & (b > 100)).sum()),
                "measured_points": int(((np.abs(r - 80) < 30) & (np.abs(g - 200) < 30) & (b > 225)).sum()),
            }
        except Exception as exc:  # reported by the test, which fails without stats
            out["error"] = f"{type(exc).__name__}: {exc}"

    # ---------------------------------------------------------------------------------------- cancel
    def test_3_cancel_during_planning(self):
        stages = []
        self.planner.send_goal(
            quick_goal(sampling_density=0.03, orientations_around_boresight=12, viewpoint_tilt_mode="full"),
            feedback_cb=lambda fb: stages.append(fb.stage),
        )
        deadline = time.monotonic() + 60
        while "metrology" not in stages and time.monotonic() < deadline:
            rospy.sleep(0.05)
        self.planner.cancel_goal()
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(60)))
        self.assertEqual(self.planner.get_state(), GoalStatus.PREEMPTED)
        self.assertIn("cancelled", self.planner.get_result().error)

    def test_4_cancel_during_execution(self):
        self.executor.send_goal(ExecutePlanGoal(plan_file=""))
        rospy.sleep(4.0)
        self.executor.cancel_goal()
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(30)))
        self.assertEqual(self.executor.get_state(), GoalStatus.PREEMPTED)
        self.assertIn("cancelled", self.executor.get_result().error)
        first = rospy.wait_for_message("/joint_states", JointState, timeout=5).position
        rospy.sleep(0.5)
        second = rospy.wait_for_message("/joint_states", JointState, timeout=5).position
        np.testing.assert_allclose(first, second, atol=1e-9, err_msg="the robot kept moving after the cancel")

    # ------------------------------------------------------------------------------------ bad goals
    def test_5_bad_goals_abort_with_their_reason(self):
        far = Pose()
        far.position.x = 3.0
        far.orientation.w = 1.0
        nan_pose = Pose()
        nan_pose.position.x = float("nan")
        nan_pose.orientation.w = 1.0
        sunk = Pose()
        sunk.position.z = -0.03  # 30 mm into the fixture
        sunk.orientation.w = 1.0
        cases = [
            (quick_goal(part_file="/nonexistent/part.stl"), "not found"),
            (quick_goal(sampling_density=-0.5), "sampling_density"),
            (quick_goal(solver_type="IP_uncert"), "IP_uncertainty"),
            (quick_goal(viewpoint_tilt_mode="sideways"), "viewpoint_tilt_mode"),
            (quick_goal(units="furlong"), "furlong"),
            (quick_goal(part_pose=far), "reach"),
            (quick_goal(part_pose=nan_pose), "NaN"),
            (quick_goal(part_pose=sunk), "overlaps scene object 'fixture'"),
            (quick_goal(placement="shelf"), "placement"),
        ]
        for goal, reason in cases:
            state, result = self._plan(goal, timeout_s=120)
            self.assertEqual(state, GoalStatus.ABORTED, f"expected abort for {reason}")
            self.assertIn(reason, result.error)
        # a plan for another robot
        other = ARTIFACTS / "plan_for_another_robot.yaml"
        data = yaml.safe_load((ARTIFACTS / "measurement_test_plan.yaml").read_text())
        for segment in data[1:]:
            segment["joint_trajectory"]["joint_names"] = [f"arm_joint_{i}" for i in range(6)]
        other.write_text(yaml.safe_dump(data))
        self.executor.send_goal(ExecutePlanGoal(plan_file=str(other)))
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(30)))
        self.assertEqual(self.executor.get_state(), GoalStatus.ABORTED)
        self.assertIn("joint", self.executor.get_result().error)
        self.executor.send_goal(ExecutePlanGoal(plan_file="/nonexistent/plan.yaml"))
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(30)))
        self.assertEqual(self.executor.get_state(), GoalStatus.ABORTED)
        # and the node still serves a good goal
        state, result = self._plan(quick_goal(solver_type="greedy"))
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)

    # ------------------------------------------------------------------------------------ services
    def test_6_plan_services(self):
        store = rospy.ServiceProxy("/trajectory_manager/store_plan", StorePlan)
        load = rospy.ServiceProxy("/trajectory_manager/load_plan", LoadPlan)
        report = rospy.ServiceProxy("/trajectory_manager/get_coverage_report", GetCoverageReport)
        target = ARTIFACTS / "stored_by_service"
        Path(str(target) + ".yaml").unlink(missing_ok=True)
        reply = store(plan_file=str(target))
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(reply.plan_file, str(target) + ".yaml")
        # an existing plan is replaced only on request
        again = store(plan_file=str(target))
        self.assertFalse(again.success)
        self.assertIn("exists", again.message)
        self.assertTrue(store(plan_file=str(target), overwrite=True).success)
        loaded = load(reply.plan_file)
        self.assertTrue(loaded.success, loaded.message)
        self.assertGreater(loaded.number_of_segments, 0)
        self.assertFalse(load("/nonexistent.yaml").success)
        self.assertFalse(store(plan_file="/nonexistent_dir/plan.yaml").success)
        figure = ARTIFACTS / "coverage_report.png"
        figure.unlink(missing_ok=True)
        got = report(str(figure))
        self.assertTrue(got.success, got.message)
        self.assertTrue(figure.exists())
        self.assertGreaterEqual(got.predicted_coverage, 0.99)
        self.assertIn("coverage_of_coverable", got.report_yaml)

    # ------------------------------------------------------------------------------------ the bag
    def test_7_bag_reproduces_the_measured_coverage(self):
        bag = Path(rospy.get_param("~bag"))
        rosnode.kill_nodes(["/station_recorder"])
        for _ in range(150):
            if bag.exists():
                break
            time.sleep(0.1)
        self.assertTrue(bag.exists(), f"no bag at {bag}")
        # the bag holds every execution of this test: recompute the first (test 2's) from the bag alone
        result = coverage_from_bag(bag, radius_mm=1.0, execution_index=0)
        print(f"bag: {result}; live measured {STATE['measured']:.4f}")
        self.assertAlmostEqual(result.measured_coverage, STATE["measured"], places=3)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "measurement_node", MeasurementNodeTest)
