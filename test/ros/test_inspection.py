#!/usr/bin/env python3
"""rostest: the inspection node's action on simulated parts with known truth (``inspection.cases``): a cube with a
1 mm dent scanned by the simulated PhoXi S, given as a cloud file, is not conform, with feedback per stage, a complete
report and the deviation markers; a null part published as a PointCloud2 (metres, world) has no flag and conform features; a spec outside
the allowed folders, a topic nobody publishes and an existing report folder are refused, and nothing is written."""

import shutil
import unittest
from pathlib import Path

import actionlib
import numpy as np
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from agiprobot_measurement.inspection.cases import build_case, spec_path
from agiprobot_measurement.msg import InspectCloudAction, InspectCloudGoal
from agiprobot_measurement.ros.conversions import xyz_cloud

REPORT_FILES = {"report.json", "report.html", "deviation_map.png", "histogram.png", "deviations.ply"}


class InspectionNodeTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_inspection")
        cls.root = Path(rospy.get_param("~root"))
        cls.inputs = cls.root / "inputs"
        # the test's own inputs and outputs from an earlier run (the goals below refuse to overwrite an output folder)
        for name in ("inputs", "dent", "null"):
            shutil.rmtree(cls.root / name, ignore_errors=True)
        cls.inputs.mkdir(parents=True)
        cls.client = actionlib.SimpleActionClient("/inspection/inspect_cloud", InspectCloudAction)
        assert cls.client.wait_for_server(rospy.Duration(60)), "no inspection action server"

    def _send(self, goal, timeout_s=120.0):
        stages = []
        self.client.send_goal(goal, feedback_cb=lambda fb: stages.append(fb.stage))
        self.assertTrue(self.client.wait_for_result(rospy.Duration(timeout_s)), "no result in time")
        return self.client.get_state(), self.client.get_result(), stages

    def test_1_dented_cube_from_a_file_is_not_conform(self):
        case = build_case("dent", 1.0, 0, "phoxi_low")
        cloud = self.inputs / "dent.npy"
        np.save(cloud, np.column_stack([case.points_mm, case.sigma_mm]))
        nominal = self.inputs / "cube.stl"
        case.nominal.export(nominal)
        goal = InspectCloudGoal(
            cloud_file=str(cloud),
            nominal_file=str(nominal),
            spec_file=str(spec_path("cube_100")),
            placement=case.part.nominal_placement.reshape(-1).tolist(),
            output_dir="dent",
        )
        state, result, stages = self._send(goal)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertEqual(result.verdict, "not conform")
        self.assertGreaterEqual(result.surface_flags, 1)
        self.assertEqual(result.points, len(case.points_mm))
        self.assertLess(result.registration_residual_mm, 0.2)
        for stage in ("check", "register", "deviations", "regions", "features", "report", "done"):
            self.assertIn(stage, stages)
        self.assertEqual(stages[-1], "done")
        self.assertEqual(Path(result.report_dir), self.root / "dent")
        self.assertTrue(REPORT_FILES <= {p.name for p in Path(result.report_dir).iterdir()})
        markers = rospy.wait_for_message("/inspection/deviations", MarkerArray, timeout=10)
        points = [m for m in markers.markers if m.ns == "deviations"]
        self.assertEqual(len(points), 1)
        self.assertGreater(len(points[0].points), 1000)
        self.assertEqual(len(points[0].points), len(points[0].colors))
        # drawn in the world: near the part's planned place (m)
        centre = np.mean([(p.x, p.y, p.z) for p in points[0].points], axis=0)
        self.assertLess(np.linalg.norm(centre - case.part.nominal_placement[:3, 3] / 1000.0), 0.1)

    def test_2_null_part_from_a_topic_is_conform(self):
        case = build_case("null", 0.0, 1, "phoxi_low")
        nominal = self.inputs / "cube_null.stl"
        case.nominal.export(nominal)
        publisher = rospy.Publisher(
            "/test_inspection/cloud", type(xyz_cloud(np.zeros((1, 3)), Header())), queue_size=1, latch=True
        )
        publisher.publish(xyz_cloud(case.points_mm / 1000.0, Header(frame_id="world", stamp=rospy.Time.now())))
        rospy.sleep(1.0)
        goal = InspectCloudGoal(
            cloud_topic="/test_inspection/cloud",
            nominal_file=str(nominal),
            spec_file=str(spec_path("cube_100")),
            placement=case.part.nominal_placement.reshape(-1).tolist(),
            output_dir="null",
        )
        state, result, _ = self._send(goal)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        # no flag; without per-point noise from the topic, a region may stay indeterminate (ISO 14253-1)
        self.assertEqual(result.surface_flags, 0, result.features)
        self.assertNotEqual(result.verdict, "not conform", result.features)
        self.assertTrue(all(feature.endswith(": conform") for feature in result.features), result.features)

    def test_3_refused_goals_write_nothing(self):
        before = sorted(p.name for p in self.root.iterdir())
        nominal = self.inputs / "cube.stl"
        spec = str(spec_path("cube_100"))
        for goal, words in (
            (
                InspectCloudGoal(
                    cloud_file=str(self.inputs / "dent.npy"), nominal_file=str(nominal), spec_file="/etc/hostname"
                ),
                "outside the allowed folder",
            ),
            (
                InspectCloudGoal(cloud_topic="/nobody/publishes", nominal_file=str(nominal), spec_file=spec),
                "nobody publishes it",
            ),
            (
                InspectCloudGoal(
                    cloud_file=str(self.inputs / "dent.npy"),
                    nominal_file=str(nominal),
                    spec_file=spec,
                    output_dir="dent",
                ),
                "not empty",
            ),
            (
                InspectCloudGoal(
                    cloud_file=str(self.inputs / "dent.npy"),
                    nominal_file=str(nominal),
                    spec_file=spec,
                    placement=[1.0, 2.0],
                ),
                "placement",
            ),
        ):
            state, result, _ = self._send(goal, timeout_s=30.0)
            self.assertEqual(state, GoalStatus.ABORTED, result.error)
            self.assertIn(words, result.error)
        self.assertEqual(sorted(p.name for p in self.root.iterdir()), before)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "inspection_node", InspectionNodeTest)
