"""Moving the bare flange (ROS-free): the pose solutions, the nearest collision-free IK solution, the straight or
planned motion, the simulated joint driver; and the calibration config around them."""

import numpy as np
import pytest

from agiprobot_measurement.calibration.config import (
    MODES,
    check_mode,
    flange_station,
    load_calibration_config,
    tool_rotation,
)
from agiprobot_measurement.calibration.flange_motion import (
    PlannedFlangeRobot,
    flange_collision_checker,
    flange_pose_solutions,
    joint_motion,
    nearest_solution,
)
from agiprobot_measurement.calibration.interfaces import StepError, UnreachableError
from agiprobot_measurement.calibration.registration import CalibrationError, read_flag_points
from agiprobot_measurement.calibration.simulation import SimulatedJointDriver
from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.station import load_joint_limits


@pytest.fixture(scope="module")
def flange():
    station = flange_station()
    kinematics = KinematicModel.from_station(station, tip_frame="tool0", base_frame="base_link")
    return station, kinematics, make_ik_solver(kinematics, station.robot), load_joint_limits()


@pytest.fixture(scope="module")
def collision(flange):
    return flange_collision_checker(flange[0])


def test_pose_solutions_face_the_point_and_turn_about_the_flange_axis():
    position, towards = np.array([-0.4, 0.5, 0.3]), np.array([-1.0, 1.1, 1.2])
    (single,) = flange_pose_solutions(position, towards)
    np.testing.assert_allclose(single[:3, :3], tool_rotation(towards, position))
    turns = flange_pose_solutions(position, towards, free_yaw=True)
    assert turns.shape == (12, 4, 4)
    axis = (towards - position) / np.linalg.norm(towards - position)
    for pose in turns:
        np.testing.assert_allclose(pose[:3, 3], position)
        np.testing.assert_allclose(pose[:3, 2], axis, atol=1e-12)
    angles = np.degrees(np.arctan2(turns[:, :3, 0] @ single[:3, 1], turns[:, :3, 0] @ single[:3, 0]))
    np.testing.assert_allclose(np.diff(np.unwrap(np.radians(angles))), np.radians(30.0), atol=1e-9)


def test_nearest_solution_reaches_the_pose_or_says_why(flange, collision):
    station, kinematics, ik, _ = flange
    start = station.named_states["home"]
    p = read_flag_points(load_calibration_config()["flag_points_file"])[0]
    poses = flange_pose_solutions(p, np.array([-1.0, 1.1, 1.2]), free_yaw=True)
    q = nearest_solution(ik, poses, start, collision)
    assert collision.check_states(q[None]).all()
    np.testing.assert_allclose(kinematics.fk(q)[:3, 3], p, atol=1e-6)
    with pytest.raises(UnreachableError, match="no IK solution for"):
        nearest_solution(ik, flange_pose_solutions(np.array([5.0, 0.0, 0.0]), np.zeros(3)), start)


def test_planned_robot_moves_straight_and_refuses_colliding_goals(flange, collision):
    station, kinematics, ik, limits = flange
    driver = SimulatedJointDriver(station.named_states["home"])
    robot = PlannedFlangeRobot(driver, kinematics, ik, limits, [-1.0, 1.1, 1.2], collision=collision)
    p = np.array([-0.52, 0.20, 0.17])
    q = robot.move_to(p)
    np.testing.assert_allclose(robot.flange_position(robot.current_joints()), p, atol=1e-6)
    np.testing.assert_allclose(driver.trajectories[-1].start, station.named_states["home"])
    np.testing.assert_allclose(driver.trajectories[-1].end, q)
    into_the_table = np.array([0.0, 0.5, 0.0, 0.0, 0.0, 0.0])  # shoulder down, arm stretched out
    with pytest.raises(UnreachableError, match="named goal: in collision: upper_arm_link - table"):
        joint_motion(q, into_the_table, limits, 1.0, collision, None, "named goal")
    assert "flange_disc_link" in station.urdf_xml
    straight = joint_motion(q, station.named_states["up"], limits, 1.0)
    np.testing.assert_allclose(straight.end, station.named_states["up"])


def test_simulated_driver_refuses_a_trajectory_from_elsewhere(flange):
    station, _, _, limits = flange
    driver = SimulatedJointDriver(station.named_states["up"])
    away = joint_motion(station.named_states["home"], station.named_states["up"], limits, 1.0)
    with pytest.raises(StepError, match="does not start at the current joint state"):
        driver.execute(away, 0.0)


def test_errors_are_the_package_errors():
    assert issubclass(StepError, InternalError) and issubclass(UnreachableError, InputError)
    assert issubclass(CalibrationError, InputError)


def test_modes_and_config():
    assert all(check_mode(m) == m for m in MODES)
    with pytest.raises(CalibrationError, match="~mode must be one of cal_fine, cal_coarse, test, got 'fine'"):
        check_mode("fine")
    config = load_calibration_config()
    assert config["flag_points_file"].endswith("calibration_flag_points.txt")
    assert len(read_flag_points(config["flag_points_file"])) == 4
    with pytest.raises(InputError, match="coincides"):
        tool_rotation(np.ones(3), np.ones(3))
