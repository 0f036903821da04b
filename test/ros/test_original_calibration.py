#!/usr/bin/env python3
"""rostest: a script written in the style of the original calibration (imports from the Code API subpackages only,
plus the station's truth for the check) calibrates the simulated station.

The flow of the original cal_main: flag points from a target file -> get_fix_path -> move_shoot at each ->
circle_fitting (flag indices write the criteria) -> write_data point pairs -> calibrate -> H_coarse written; a
zig-zag point judged by the criteria; calibrate(data_path, num_point, max_iteration) again. The result is compared
with the hidden camera pose; the data file it wrote is the original's layout and this project's reader reads it.
Then the original main program: cal_coarse with use_mp on its own folder, and test mode on its result (the
chessboard's corners found in a frame, the flange moved 2 cm above the first two).
"""

import shutil
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros

# the Code API (calibration.original, ros.original_calibration); the rest for the checks and the first pose only
from agiprobot_measurement.calibration.chessboard_test import chessboard_truth
from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
from agiprobot_measurement.calibration.original.calibration import calibrate, circle_fitting
from agiprobot_measurement.calibration.original.utils import get_point_pair_list, read_data, write_data
from agiprobot_measurement.calibration.registration import (
    pose_error,
    read_data_file,
    read_flag_points,
    write_flag_points,
)
from agiprobot_measurement.calibration.simulation import nominal_camera_pose
from agiprobot_measurement.ros.conversions import matrix_to_pose, transform_to_matrix
from agiprobot_measurement.ros.original_calibration import cal_main
from agiprobot_measurement.ros.original_calibration.cal_main import (
    get_fix_path,
    get_path_zigzag,
    move_shoot,
    plan_execute,
)
from agiprobot_measurement.station import Station


class OriginalCalibrationTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_original_calibration")
        cls.output_dir = Path(rospy.get_param("~output_dir"))
        shutil.rmtree(cls.output_dir, ignore_errors=True)
        cls.output_dir.mkdir(parents=True)
        cal_main.random_seed = 0
        cal_main.configure(scene=rospy.get_param("~scene"), velocity_scaling=1.0, settle_s=0.2)
        cal_main.connect_camera()
        config = load_calibration_config()
        cls.flags = read_flag_points(config["flag_points_file"])
        cls.tool_z_towards_m = config["tool_z_towards_m"]
        tf_buffer = tf2_ros.Buffer()
        tf2_ros.TransformListener(tf_buffer)
        world_from_base = transform_to_matrix(
            tf_buffer.lookup_transform("world", "base", rospy.Time(0), rospy.Duration(20.0))
        )
        cls.truth = np.linalg.inv(world_from_base) @ nominal_camera_pose()

    @classmethod
    def tearDownClass(cls):
        for cloud in cls.output_dir.rglob("*.ply"):  # 7 MB a shot; the data files stay
            cloud.unlink()

    def _face_the_scanner(self):
        """The operator's step before the original's cal_main: the flange at the first flag point, facing the
        scanner (get_fix_path keeps this orientation for every target)."""
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = tool_rotation(self.tool_z_towards_m, self.flags[0]), self.flags[0]
        self.assertTrue(plan_execute(matrix_to_pose(pose), "cal_fine"))

    def _check(self, h, error, what):
        t_mm, r_deg = pose_error(np.asarray(h), self.truth)
        rospy.loginfo("%s: %.3f mm, %.4f deg from the true camera pose, error %.4f mm", what, t_mm, r_deg, error * 1e3)
        # 4 to 5 pairs; the camera origin lies 1.2 m beyond them, which multiplies the detections' 0.1 mm
        self.assertLess(t_mm, 1.0, what)
        self.assertLess(r_deg, 0.1, what)
        self.assertLess(error, 0.0005, what)

    def test_1_original_style_script(self):
        folder = self.output_dir / "script"
        cal_main.data_path = str(folder) + "/"
        data_file = str(folder / "data.txt")
        target_file = write_flag_points(folder / "target.txt", self.flags, format="original")
        self._face_the_scanner()

        # --- the original's coarse calibration
        path, object_points = get_fix_path(data_path=str(target_file))
        self.assertEqual(len(path), 4)
        for i, target in enumerate(path):
            im_name, index, p_robot = move_shoot(target, "cal_coarse")
            self.assertTrue(Path(im_name + ".ply").is_file())
            self.assertEqual(len(p_robot), 7)
            p_camera = circle_fitting(im_name, "flag" + str(i) + "_" + index, need_judge=False)
            self.assertTrue(p_camera, f"no flange at flag point {i}")
            write_data(data_file, [p_robot, p_camera], "flag" + str(i) + "_" + index, type="point_pair")
        criteria = read_data(data_file, "criteria")
        self.assertIsNotNone(criteria)
        self.assertGreater(min(criteria), 50)
        h_coarse, error_coarse = calibrate(data_file, num_point=4, max_iteration=100)
        self._check(h_coarse, error_coarse, "coarse")
        write_data(data_file, h_coarse, "H_coarse", type="mat")

        # --- a point of the fine calibration's zig-zag path, judged by the flag points' criteria
        zig_zag_path = get_path_zigzag(path, object_points)
        self.assertEqual(len(zig_zag_path), 18)
        accepted = 0
        for target in zig_zag_path[:1]:
            result = move_shoot(target, "cal_fine")
            if not result:
                continue
            im_name, index, p_robot = result
            p_camera = circle_fitting(im_name, index, need_judge=True)
            if p_camera:
                write_data(data_file, [p_robot, p_camera], index, type="point_pair")
                accepted += 1
        self.assertEqual(accepted, 1)
        h, error = calibrate(data_file, num_point=4, max_iteration=1000)
        self._check(h, error, "fine")
        np.testing.assert_allclose(np.asarray(read_data(data_file, "H")), np.asarray(h_coarse), atol=1e-9)

        # the file is the original's layout (6-DoF robot poses) and the project's reader takes it
        text = Path(data_file).read_text()
        self.assertIn("p_robot 6-DoF index:flag0_", text)
        self.assertIn(", ]\n", text)
        data = read_data_file(data_file)
        self.assertEqual(len(data.samples), 4 + accepted)
        self.assertEqual(sum(s.flag for s in data.samples), 4)
        self.assertEqual(len(get_point_pair_list(data_file)), 4 + accepted)
        np.testing.assert_allclose(data.samples[0].p_robot_m, self.flags[0], atol=2e-3)

    def test_2_original_main_program_cal_coarse_with_workers(self):
        folder = self.output_dir / "main"
        cal_main.data_path = str(folder) + "/"
        cal_main.use_mp = True
        write_flag_points(folder / "target.txt", self.flags, format="original")
        self._face_the_scanner()
        try:
            h, error = cal_main.main("cal_coarse")
        finally:
            cal_main.use_mp = False
        self._check(h, error, "main cal_coarse")
        data = read_data_file(folder / "data.txt")
        self.assertEqual(sum(s.flag for s in data.samples), 4)
        np.testing.assert_allclose(data.h_coarse, np.asarray(h), atol=1e-9)

    def test_3_original_main_program_test_mode(self):
        """On test 2's data file: the chessboard's corners found, the flange 2 cm above the first two."""
        cal_main.data_path = str(self.output_dir / "main") + "/"
        self.assertTrue((self.output_dir / "main" / "data.txt").is_file(), "test 2 runs first")
        h, reached = cal_main.main("test", max_targets=2)
        self.assertEqual(len(reached), 2)
        np.testing.assert_allclose(read_data_file(self.output_dir / "main" / "data.txt").h_final, h, atol=1e-9)
        truth = chessboard_truth(Station.load(scene=rospy.get_param("~scene")).scene, (8, 11))
        robot = cal_main.station().robot
        flange = robot.flange_position(robot.current_joints())
        np.testing.assert_allclose(flange, reached[-1], atol=1e-4)
        error_mm = np.linalg.norm(flange - (truth.nearest_corner(flange) + 0.02 * truth.normal_base)) * 1000.0
        rospy.loginfo("test mode: flange %.3f mm from 2 cm above the true corner", error_mm)
        self.assertLess(error_mm, 1.0)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "test_original_calibration", OriginalCalibrationTest)
