#!/usr/bin/env python3
"""rostest: the calibration node on the simulated station (flange disc, PhoXi rendered at its true pose).

Ordered tests: a missing flag point file gives a clear error and the node keeps serving; the automatic collection
produces a calibration within 0.3 mm / 0.1 deg of the true camera pose, its YAML and the static tf; a sample with
no flange in view is rejected with its reason and the session goes on; test mode finds the chessboard of the
calibration scene, moves the flange to each of its 88 corners and reports the positioning error per corner; the
manual services (flag points at the robot's pose, samples, remove, save, load) keep the data file
current sample by sample; with use_auto_judge false a run waits for the operator's answer at every detection.
Refused before the robot moves, with a short reply that quotes no file: a flag point file outside the node's
folders, an empty name, a bad ~zigzag; a 63 MB data file of NUL bytes gives a short load_samples reply.
"""

import threading
import time
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from agiprobot_measurement.calibration.registration import pose_error, read_result_yaml
from agiprobot_measurement.calibration.simulation import nominal_camera_pose
from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.srv import SetJointState

CAMERA_FRAME = "PhoXi3Dscanner_sensor"
OUT_OF_VIEW = [0.0, -1.5707, 0.0, -1.5707, 0.0, 0.0]  # named state "up": the flange above the scanner's view
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


def _positions(state):
    """The joint positions in kinematic order (the driver publishes them in alphabetical order)."""
    by_name = dict(zip(state.name, state.position, strict=True))
    return [by_name[name] for name in JOINTS]


def _service(name):
    rospy.wait_for_service(name, 60.0)
    return rospy.ServiceProxy(name, Trigger)


class CalibrationNodeTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_calibration_node")
        cls.output_dir = Path(rospy.get_param("~output_dir"))
        cls.run_collection = _service("/calibration/run")
        cls.take_sample = _service("/calibration/take_sample")
        cls.list_samples = _service("/calibration/list_samples")
        cls.compute_fine = _service("/calibration/compute_fine")
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def _run_with(self, **params):
        """``~run`` with the node's parameters set to ``params`` for this call only: (response, seconds)."""
        originals = {key: rospy.get_param(f"/calibration/{key}") for key in params}
        for key, value in params.items():
            rospy.set_param(f"/calibration/{key}", value)
        try:
            start = time.monotonic()
            response = self.run_collection()
            return response, time.monotonic() - start
        finally:
            for key, value in originals.items():
                rospy.set_param(f"/calibration/{key}", value)

    def test_1_missing_flag_file_is_a_clear_error(self):
        response, _ = self._run_with(flag_points_file=str(self.output_dir / "missing_flags.txt"))
        self.assertFalse(response.success)
        self.assertIn("missing_flags.txt", response.message)
        self.assertIn("not found", response.message)
        self.assertTrue(self.list_samples().success, "the node keeps serving")

    def test_1b_flag_file_outside_the_node_folders_is_refused_unread(self):
        for name in ("/etc/os-release", "/nonexistent/flags.txt", str(self.output_dir / ".." / "x.txt")):
            response, seconds = self._run_with(flag_points_file=name)
            self.assertFalse(response.success)
            self.assertLess(seconds, 5.0)
            self.assertNotIn("PRETTY_NAME", response.message)
            self.assertIn("~flag_points_file", response.message)
        response, _ = self._run_with(flag_points_file="")
        self.assertFalse(response.success)
        self.assertIn("empty", response.message)
        self.output_dir.mkdir(parents=True, exist_ok=True)
        secret = self.output_dir / "secret.txt"
        secret.write_text("TOKEN=abcdef0123456789\n")
        response, _ = self._run_with(flag_points_file=str(secret))
        self.assertFalse(response.success)
        self.assertIn("secret.txt:1", response.message)
        self.assertNotIn("TOKEN", response.message)

    def test_1c_bad_zigzag_is_refused_before_the_robot_moves(self):
        for zigzag, key in (
            ("lots", "~zigzag must be a mapping"),
            ({"fractions": [1e9, -5], "jitter_m": 0.03, "seed": 0}, "~zigzag.fractions[0]"),
            ({"fractions": [0.5], "jitter_m": 1e308}, "~zigzag.jitter_m"),
            ({"fractions": [0.5], "seed": -1}, "~zigzag.seed"),
        ):
            response, seconds = self._run_with(zigzag=zigzag)
            self.assertFalse(response.success)
            self.assertIn(key, response.message)
            self.assertNotIn("internal error", response.message)
            self.assertLess(seconds, 5.0, "refused before any motion")

    def test_2_automatic_collection_is_accurate(self):
        response = self.run_collection()
        self.assertTrue(response.success, response.message)
        result_file = self.output_dir / "calibration_result.yaml"
        self.assertTrue(result_file.is_file())
        self.assertTrue((self.output_dir / "calibration_data.txt").is_file())
        estimate = read_result_yaml(result_file)
        world_from_base = transform_to_matrix(
            self.tf_buffer.lookup_transform("world", "base", rospy.Time(0), rospy.Duration(10.0))
        )
        truth = np.linalg.inv(world_from_base) @ nominal_camera_pose()
        t_mm, r_deg = pose_error(estimate, truth)
        rospy.loginfo("calibration error: %.3f mm, %.4f deg (%s)", t_mm, r_deg, response.message)
        self.assertLess(t_mm, 0.3, response.message)
        self.assertLess(r_deg, 0.1, response.message)
        published = transform_to_matrix(
            self.tf_buffer.lookup_transform("base", CAMERA_FRAME, rospy.Time(0), rospy.Duration(10.0))
        )
        np.testing.assert_allclose(published, estimate, atol=1e-6)

    def test_3_no_flange_in_view_is_rejected_and_collection_goes_on(self):
        set_state = rospy.ServiceProxy("/ur_driver_sim/set_joint_state", SetJointState)
        before = self.list_samples().message.count("path")
        placed = set_state(positions=[], named_state="up")
        self.assertTrue(placed.success, placed.message)
        deadline = rospy.Time.now() + rospy.Duration(10.0)
        while rospy.Time.now() < deadline:  # joint states and tf of the new pose are out
            state = rospy.wait_for_message("/joint_states", JointState, 5.0)
            if np.allclose(_positions(state), OUT_OF_VIEW, atol=1e-3):
                break
        rospy.sleep(0.5)
        response = self.take_sample()
        self.assertFalse(response.success, response.message)
        self.assertIn("rejected", response.message)
        listing = self.list_samples().message
        self.assertIn("rejected sample", listing)
        self.assertEqual(listing.count(" path "), before)
        self.assertTrue(self.compute_fine().success, "the session goes on after a rejected sample")

    def test_4_test_mode_moves_to_every_corner(self):
        import yaml

        rospy.set_param("/calibration/mode", "test")
        try:
            response = self.run_collection()
        finally:
            rospy.set_param("/calibration/mode", "cal_fine")
        self.assertTrue(response.success, response.message)
        self.assertIn("positioning error against the true corners", response.message)
        report = yaml.safe_load((self.output_dir / "test_result.yaml").read_text())
        summary, corners = report["summary"], report["corners"]
        rospy.loginfo("test mode: %s", summary)
        self.assertEqual(summary["corners_detected"], 88)
        self.assertEqual(summary["corners_reached"], 88, [c.get("error") for c in corners if "error" in c])
        self.assertEqual(sorted(c["corner"] for c in corners), list(range(88)))
        errors = np.array([c["positioning_error_mm"] for c in corners])
        self.assertLess(errors.max(), 1.0, summary)  # calibration + corner detection, mm
        self.assertAlmostEqual(summary["positioning_error_max_mm"], errors.max(), places=6)
        # the flange really went there: 20 mm above the board, spread over its 200 x 140 mm of corners
        reached = np.array([c["reached_m"] for c in corners])
        targets = np.array([c["target_m"] for c in corners])
        self.assertLess(np.abs(reached - targets).max(), 1e-4)
        self.assertGreater(np.ptp(reached[:, 0]) + np.ptp(reached[:, 1]), 0.33)
        # and came back out of the camera's view
        state = rospy.wait_for_message("/joint_states", JointState, 5.0)
        np.testing.assert_allclose(_positions(state), OUT_OF_VIEW, atol=1e-3)

    def _place(self, positions):
        set_state = rospy.ServiceProxy("/ur_driver_sim/set_joint_state", SetJointState)
        placed = set_state(positions=list(positions), named_state="")
        self.assertTrue(placed.success, placed.message)
        deadline = rospy.Time.now() + rospy.Duration(10.0)
        while rospy.Time.now() < deadline:
            state = rospy.wait_for_message("/joint_states", JointState, 5.0)
            if np.allclose(_positions(state), positions, atol=1e-3):
                break
        rospy.sleep(0.5)  # tf of the new pose reaches the camera

    def test_5_manual_flag_points_samples_save_and_load(self):
        from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
        from agiprobot_measurement.calibration.registration import read_data_file, read_flag_points
        from agiprobot_measurement.motion.ik import make_ik_solver
        from agiprobot_measurement.motion.kinematics import KinematicModel
        from agiprobot_measurement.station import Station

        station = Station.load()
        model = KinematicModel.from_station(station, tip_frame="tool0", base_frame="base")
        ik = make_ik_solver(model, station.robot)
        config = load_calibration_config()
        self.assertTrue(_service("/calibration/clear")().success)
        add_flag = _service("/calibration/add_flag_point")
        seed = np.array([0.0, -1.5707, 1.5707, -1.5707, -1.5707, 0.0])
        for p in read_flag_points(config["flag_points_file"]):
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = tool_rotation(config["tool_z_towards_m"], p), p
            q, ok = ik.solve_nearest(pose, seed)
            self.assertTrue(bool(np.all(ok)))
            self._place(np.asarray(q).reshape(-1))
            response = add_flag()
            self.assertTrue(response.success, response.message)
        self.assertIn("4 flag samples stored", response.message)
        response = _service("/calibration/compute_coarse")()
        self.assertTrue(response.success, response.message)
        data_file = self.output_dir / "calibration_data.txt"
        self.assertEqual(len(read_data_file(data_file).samples), 4)  # written as the samples came
        self.assertTrue(_service("/calibration/take_sample")().success)  # at the last flag point: accepted
        self.assertEqual(len(read_data_file(data_file).samples), 5)
        self.assertTrue(_service("/calibration/remove_sample")().success)
        self.assertEqual(len(read_data_file(data_file).samples), 4)
        self.assertTrue(_service("/calibration/save_samples")().success)
        response = _service("/calibration/load_samples")()
        self.assertTrue(response.success, response.message)
        self.assertIn("4 samples", response.message)

    def test_6_operator_judges_each_detection_when_auto_judge_is_off(self):
        import threading

        from geometry_msgs.msg import PointStamped
        from std_srvs.srv import SetBool

        judge = rospy.ServiceProxy("/calibration/judge", SetBool)
        self.assertFalse(judge(True).success, "nothing to judge before a run")
        rospy.set_param("/calibration/mode", "cal_coarse")
        rospy.set_param("/calibration/use_auto_judge", False)
        outcome = {}
        runner = threading.Thread(target=lambda: outcome.update(response=self.run_collection()))
        try:
            runner.start()
            questions = []
            deadline = rospy.Time.now() + rospy.Duration(180.0)
            while runner.is_alive() and rospy.Time.now() < deadline:
                answer = judge(True)
                if answer.success:
                    questions.append(answer.message)
                    detection = rospy.wait_for_message("/calibration/flange_detection", PointStamped, 5.0)
                    self.assertEqual(detection.header.frame_id, CAMERA_FRAME)
                else:
                    rospy.sleep(0.2)
            runner.join(10.0)
        finally:
            rospy.set_param("/calibration/mode", "cal_fine")
            rospy.set_param("/calibration/use_auto_judge", True)
        response = outcome["response"]
        self.assertTrue(response.success, response.message)
        self.assertIn("coarse: 4 flag points", response.message)
        self.assertEqual(len(questions), 4, questions)  # one question per flag point
        self.assertTrue(all(q.startswith("accepted: flag point") for q in questions), questions)

    def test_7_cheap_service_under_load(self):
        # 200 calls from 1 and from 4 concurrent clients, zero failures, the rate printed
        for clients in (1, 4):
            counts = [[0, 0] for _ in range(clients)]

            def client(index, counts=counts):
                proxy = rospy.ServiceProxy("/calibration/list_samples", Trigger)
                for _ in range(200):
                    try:
                        counts[index][0 if proxy().success else 1] += 1
                    except rospy.ServiceException:
                        counts[index][1] += 1

            threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
            start = time.monotonic()
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            seconds = time.monotonic() - start
            ok, failed = sum(c[0] for c in counts), sum(c[1] for c in counts)
            print(f"/calibration/list_samples {clients} client(s): {ok / seconds:.1f} calls/s, {failed} failed")
            self.assertEqual((ok, failed), (200 * clients, 0))

    def test_8_load_of_a_huge_bad_data_file_gives_a_short_reply(self):
        data_file = self.output_dir / "calibration_data.txt"
        with open(data_file, "wb") as f:  # 63 MB of NUL bytes: under the size cap, one line
            f.truncate(63 * 1024 * 1024)
        try:
            start = time.monotonic()
            response = _service("/calibration/load_samples")()
            seconds = time.monotonic() - start
        finally:
            data_file.unlink()
        print(f"load_samples of 63 MB of NUL bytes: {seconds:.1f} s, reply of {len(response.message)} chars")
        self.assertFalse(response.success)
        self.assertLess(len(response.message), 500)
        self.assertIn("unexpected line", response.message)
        self.assertTrue(self.list_samples().success, "the node keeps serving")


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "calibration_node", CalibrationNodeTest)
