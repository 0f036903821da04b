"""True (calibrated) kinematics of the simulated robot: the nominal model plus a UR-controller-style DH correction."""

import numpy as np
import pytest

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.motion.kinematics import (
    DhCorrection,
    KinematicModel,
    TrueKinematics,
    load_kinematics_correction,
)
from agiprobot_measurement.station import Station
from agiprobot_measurement.station.config import load_robot_config


@pytest.fixture(scope="module")
def nominal():
    return KinematicModel.from_station(Station.load(), tip_frame="tool0", base_frame="base_link")


@pytest.fixture(scope="module")
def robot():
    return load_robot_config()


def _correction(**deltas):
    values = {k: np.zeros(6) for k in ("delta_a_m", "delta_d_m", "delta_alpha_rad", "delta_theta_rad")}
    for key, (joint, value) in deltas.items():
        values[key][joint] = value
    return DhCorrection(**values)


def test_zero_correction_is_the_nominal_model(nominal, robot):
    true = TrueKinematics(nominal, robot, DhCorrection.zero())
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, (50, 6))
    np.testing.assert_allclose(true.fk(q), nominal.fk(q), atol=1e-12)
    for link, pose in true.link_poses_batch(q).items():
        np.testing.assert_allclose(pose, nominal.link_poses_batch(q)[link], atol=1e-12, err_msg=link)


def test_shoulder_height_correction_lifts_everything_after_the_base(nominal, robot):
    true = TrueKinematics(nominal, robot, _correction(delta_d_m=(0, 0.001)))
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (20, 6))
    shift = true.fk(q)[:, :3, 3] - nominal.fk(q)[:, :3, 3]
    np.testing.assert_allclose(shift, np.tile([0.0, 0.0, 0.001], (20, 1)), atol=1e-12)
    # the rotation is untouched; the base link itself does not move
    np.testing.assert_allclose(true.fk(q)[:, :3, :3], nominal.fk(q)[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(true.link_poses_batch(q)["base_link"], nominal.link_poses_batch(q)["base_link"])


def test_upper_arm_length_correction_by_hand(nominal, robot):
    # a2 lies along DH x2, which at q1 = q2 = 0 is the base x axis and at q1 = pi/2 the base y axis: a 1 mm longer
    # upper arm moves the flange by 1 mm along that axis, whatever the wrist does
    true = TrueKinematics(nominal, robot, _correction(delta_a_m=(1, 0.001)))
    for q1, axis in ((0.0, [1.0, 0.0, 0.0]), (np.pi / 2, [0.0, 1.0, 0.0])):
        q = np.array([q1, 0.0, 0.7, -0.4, 1.1, 0.3])
        np.testing.assert_allclose(true.fk(q)[:3, 3] - nominal.fk(q)[:3, 3], 0.001 * np.array(axis), atol=1e-12)


def test_shoulder_offset_correction_turns_the_arm_about_the_base_axis(nominal, robot):
    eps = np.radians(0.1)
    true = TrueKinematics(nominal, robot, _correction(delta_theta_rad=(0, eps)))
    q = np.array([0.2, -1.2, 1.4, -1.7, -1.5, 0.4])
    turn = np.array([[np.cos(eps), -np.sin(eps), 0.0], [np.sin(eps), np.cos(eps), 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(true.fk(q)[:3, 3], turn @ nominal.fk(q)[:3, 3], atol=1e-12)
    reach = np.linalg.norm(nominal.fk(q)[:2, 3])
    assert np.linalg.norm(true.fk(q)[:3, 3] - nominal.fk(q)[:3, 3]) == pytest.approx(reach * eps, rel=1e-6)


def test_links_fixed_to_the_flange_follow_it(nominal, robot):
    model = KinematicModel.from_station(Station.load(), tip_frame="laser_emitter_frame", base_frame="world")
    true = TrueKinematics(model, robot, _correction(delta_alpha_rad=(2, 0.002), delta_theta_rad=(3, -0.003)))
    q = np.array([0.3, -1.0, 1.2, -1.4, -1.6, 0.1])
    poses, nominal_poses = true.link_poses_batch(q), model.link_poses_batch(q)
    relative = np.linalg.inv(poses["tool0"][0]) @ poses["laser_emitter_frame"][0]
    nominal_relative = np.linalg.inv(nominal_poses["tool0"][0]) @ nominal_poses["laser_emitter_frame"][0]
    np.testing.assert_allclose(relative, nominal_relative, atol=1e-12)
    assert np.linalg.norm(poses["tool0"][0][:3, 3] - nominal_poses["tool0"][0][:3, 3]) > 1e-4


def test_solve_near_reaches_the_pose_with_the_true_robot(nominal, robot):
    _, correction, _ = load_kinematics_correction()
    true = TrueKinematics(nominal, robot, correction)
    q0 = np.array([0.3, -1.2, 1.5, -1.8, -1.5, 0.2])
    target = nominal.fk(q0)
    q = true.solve_near(target, q0)
    assert q is not None
    np.testing.assert_allclose(true.fk(q), target, atol=1e-9)
    assert np.abs(q - q0).max() > 1e-4  # a different joint state: the robot is not the nominal one


def test_published_correction_file(tmp_path):
    enabled, correction, scale = load_kinematics_correction()
    assert enabled is False and scale == 1.0  # off for the demo
    assert correction.delta_d_m[1] == pytest.approx(1.4442162376284788)
    assert not correction.is_zero and correction.scaled(0.0).is_zero
    text = tmp_path / "c.yaml"
    text.write_text(
        "true_kinematics: true\nscale: 2.0\ndh_delta:\n  delta_a_m: [0.001, 0, 0, 0, 0, 0]\n"
        "  delta_d_m: [0, 0, 0, 0, 0, 0]\n  delta_alpha_rad: [0, 0, 0, 0, 0, 0]\n"
        "  delta_theta_rad: [0, 0, 0, 0, 0, 0]\n"
    )
    enabled, correction, scale = load_kinematics_correction(text)
    assert enabled is True and scale == 2.0 and correction.delta_a_m[0] == pytest.approx(0.001)


def test_bad_correction_file_names_the_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(
        "true_kinematics: true\ndh_delta:\n  delta_a_m: [0, 0, 0]\n  delta_d_m: [0, 0, 0, 0, 0, 0]\n"
        "  delta_alpha_rad: [0, 0, 0, 0, 0, 0]\n  delta_theta_rad: [0, 0, 0, 0, 0, 0]\n"
    )
    with pytest.raises(ConfigError, match="delta_a_m"):
        load_kinematics_correction(path)
    path.write_text("true_kinematics: yes please\n")
    with pytest.raises(ConfigError, match="true_kinematics"):
        load_kinematics_correction(path)


def test_deviation_scale_grows_the_flange_error_linearly(nominal, robot):
    _, correction, _ = load_kinematics_correction()
    q = np.random.default_rng(5).uniform(-np.pi, np.pi, (200, 6))
    offsets = {
        s: np.linalg.norm(
            TrueKinematics(nominal, robot, correction, s).fk(q)[:, :3, 3] - nominal.fk(q)[:, :3, 3], axis=1
        )
        for s in (0.0, 0.5, 1.0, 2.0)
    }
    assert offsets[0.0].max() < 1e-12
    assert offsets[1.0].mean() > 1e-3  # the published correction: millimetres at the flange
    np.testing.assert_allclose(offsets[0.5], 0.5 * offsets[1.0], rtol=0.02)
    np.testing.assert_allclose(offsets[2.0], 2.0 * offsets[1.0], rtol=0.05)
    # multiplying the controller's deltas instead does not scale the error (they compensate each other)
    halved = TrueKinematics(nominal, robot, correction.scaled(0.5)).fk(q)[:, :3, 3] - nominal.fk(q)[:, :3, 3]
    assert np.linalg.norm(halved, axis=1).mean() > 1.5 * offsets[1.0].mean()


def test_station_option_from_the_config(tmp_path):
    from agiprobot_measurement.calibration.simulation import true_kinematics_from_config

    assert true_kinematics_from_config() == {}  # the shipped file: off
    path = tmp_path / "on.yaml"
    path.write_text(
        "true_kinematics: true\nscale: 0.5\ndh_delta:\n  delta_a_m: [0, 0, 0, 0, 0, 0]\n"
        "  delta_d_m: [0.001, 0, 0, 0, 0, 0]\n  delta_alpha_rad: [0, 0, 0, 0, 0, 0]\n"
        "  delta_theta_rad: [0, 0, 0, 0, 0, 0]\n"
    )
    options = true_kinematics_from_config(path)
    assert options["deviation_scale"] == 0.5 and options["true_kinematics"].delta_d_m[0] == 0.001
