"""True kinematics of the simulated robot: the model's chain with another kinematics file's joint origins (the
original station's real UR10e, config/my_robot_calibration.yaml), scaled deviations, the simulation's config file."""

import numpy as np
import pytest

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.motion.kinematics import (
    KinematicModel,
    TrueKinematics,
    load_kinematics_correction,
    ur_arm_frames,
)
from agiprobot_measurement.station import CONFIG_DIR, Station, load_ur_kinematics


@pytest.fixture(scope="module")
def nominal():
    return KinematicModel.from_station(Station.load(), tip_frame="tool0", base_frame="base_link")


@pytest.fixture(scope="module")
def real_arm():
    return load_ur_kinematics(CONFIG_DIR / "my_robot_calibration.yaml")


def test_the_nominal_file_is_the_nominal_model(nominal):
    true = TrueKinematics(nominal, load_ur_kinematics(CONFIG_DIR / "ur10e_default_kinematics.yaml"))
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (20, 6))
    np.testing.assert_allclose(true.fk(q), nominal.fk(q), atol=1e-12)


def test_the_true_robot_is_the_files_chain(nominal, real_arm):
    true = TrueKinematics(nominal, real_arm)
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (50, 6))
    np.testing.assert_allclose(true.fk(q), ur_arm_frames(real_arm, q)["tool0"], atol=1e-12)
    shift = np.linalg.norm(true.fk(q)[:, :3, 3] - nominal.fk(q)[:, :3, 3], axis=1)
    assert 5e-4 < shift.mean() < 5e-3  # millimetres, as the reference says (1.76 mm mean)


def test_links_fixed_to_the_flange_move_with_it():
    station = Station.load()
    world = KinematicModel.from_station(station, tip_frame="laser_emitter_frame")
    true = TrueKinematics(world, load_ur_kinematics(CONFIG_DIR / "my_robot_calibration.yaml"))
    q = np.array([[0.2, -1.0, 1.1, -1.5, -1.4, 0.3]])
    poses, nominal_poses = true.link_poses_batch(q), world.link_poses_batch(q)
    relative = np.linalg.inv(poses["tool0"][0]) @ poses["laser_emitter_frame"][0]
    nominal_relative = np.linalg.inv(nominal_poses["tool0"][0]) @ nominal_poses["laser_emitter_frame"][0]
    np.testing.assert_allclose(relative, nominal_relative, atol=1e-12)
    assert np.linalg.norm(poses["tool0"][0][:3, 3] - nominal_poses["tool0"][0][:3, 3]) > 1e-4
    # the robot's mounting does not move
    np.testing.assert_allclose(poses["base_link"], nominal_poses["base_link"], atol=0)


def test_solve_near_reaches_the_pose_with_the_true_robot(nominal, real_arm):
    true = TrueKinematics(nominal, real_arm)
    q0 = np.array([0.3, -1.2, 1.5, -1.8, -1.5, 0.2])
    target = nominal.fk(q0)
    q = true.solve_near(target, q0)
    assert q is not None
    np.testing.assert_allclose(true.fk(q), target, atol=1e-9)
    assert np.abs(q - q0).max() > 1e-5  # a different joint state: the robot is not the nominal one


def test_published_true_robot_file(tmp_path, real_arm):
    enabled, arm, scale = load_kinematics_correction()
    assert enabled is False and scale == 1.0  # off for the demo
    assert arm.hash == real_arm.hash == "calib_1811142273362460997"
    (tmp_path / "arm.yaml").write_text((CONFIG_DIR / "ur10e_default_kinematics.yaml").read_text())
    text = tmp_path / "c.yaml"
    text.write_text("true_kinematics: true\nscale: 2.0\nkinematics_config: arm.yaml\n")
    enabled, arm, scale = load_kinematics_correction(text)
    assert enabled is True and scale == 2.0 and arm.hash == "calib_5119701370761913513"


def test_bad_true_robot_file_names_the_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("true_kinematics: true\n")
    with pytest.raises(ConfigError, match="kinematics_config"):
        load_kinematics_correction(path)
    path.write_text("true_kinematics: yes please\nkinematics_config: x.yaml\n")
    with pytest.raises(ConfigError, match="true_kinematics"):
        load_kinematics_correction(path)
    path.write_text("true_kinematics: true\nkinematics_config: missing.yaml\n")
    with pytest.raises(ConfigError, match=r"missing\.yaml"):
        load_kinematics_correction(path)
    path.write_text("true_kinematics: true\nscale: -1\nkinematics_config: x.yaml\n")
    with pytest.raises(ConfigError, match="scale"):
        load_kinematics_correction(path)


def test_deviation_scale_grows_the_flange_error_linearly(nominal, real_arm):
    q = np.random.default_rng(5).uniform(-np.pi, np.pi, (200, 6))
    offsets = {
        s: np.linalg.norm(TrueKinematics(nominal, real_arm, s).fk(q)[:, :3, 3] - nominal.fk(q)[:, :3, 3], axis=1)
        for s in (0.0, 0.5, 1.0, 2.0)
    }
    assert offsets[0.0].max() < 1e-12
    assert offsets[1.0].mean() > 1e-3  # the real robot: millimetres at the flange
    np.testing.assert_allclose(offsets[0.5], 0.5 * offsets[1.0], rtol=0.02, atol=2e-6)
    np.testing.assert_allclose(offsets[2.0], 2.0 * offsets[1.0], rtol=0.05, atol=2e-6)


def test_station_option_from_the_config(tmp_path):
    from agiprobot_measurement.calibration.simulation import true_kinematics_from_config

    assert true_kinematics_from_config() == {}  # the shipped file: off
    path = tmp_path / "on.yaml"
    path.write_text(
        f"true_kinematics: true\nscale: 0.5\nkinematics_config: {CONFIG_DIR / 'my_robot_calibration.yaml'}\n"
    )
    options = true_kinematics_from_config(path)
    assert options["deviation_scale"] == 0.5 and options["true_kinematics"].hash == "calib_1811142273362460997"


def test_a_station_that_knows_its_robot_reports_the_true_flange(real_arm):
    """SimulatedStation: the true robot = the real UR10e's file; with the same file as the planner's model the
    reported flange is the true one, with the nominal model it is millimetres off."""
    from agiprobot_measurement.calibration.simulation import SimulatedStation, nominal_camera_pose

    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [-0.6, 0.3, 0.4]
    offsets = {}
    for planner in (None, CONFIG_DIR / "my_robot_calibration.yaml"):
        sim = SimulatedStation(nominal_camera_pose(), true_kinematics=real_arm, planner_kinematics=planner)
        q = sim.joints_for(pose[:3, 3], pose[:3, :3])
        assert q is not None
        offsets[planner is None] = np.linalg.norm(sim.true_flange_pose(q)[:3, 3] - pose[:3, 3])
        np.testing.assert_allclose(sim.reported_flange_pose(q), pose, atol=1e-9)
    assert offsets[True] > 5e-4 and offsets[False] < 1e-9
