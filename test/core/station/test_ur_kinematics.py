"""The arm's kinematics file (ur_calibration's output, ur_description's format): the reader on the carried files and
on hostile ones, the FK of its chain against the reference numbers, and the URDF's frames."""

import copy
import math

import numpy as np
import pytest
import yaml

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.kinematics import KinematicModel, ur_arm_frames
from agiprobot_measurement.station import CONFIG_DIR, ConfigError, KinematicsFileError, Station, load_ur_kinematics
from agiprobot_measurement.station.config import load_robot_config
from agiprobot_measurement.station.ur_kinematics import (
    MAX_ANGLE_RAD,
    MAX_OFFSET_M,
    UR_KINEMATICS_LINKS,
    parse_ur_kinematics,
)
from agiprobot_measurement.station.urdf_model import UrdfModel, build_station_urdf

NOMINAL = CONFIG_DIR / "ur10e_default_kinematics.yaml"
REAL = CONFIG_DIR / "my_robot_calibration.yaml"


@pytest.fixture(scope="module")
def nominal():
    return load_ur_kinematics(NOMINAL)


@pytest.fixture(scope="module")
def real():
    return load_ur_kinematics(REAL)


def _document(path=NOMINAL) -> dict:
    return yaml.safe_load(path.read_text())


# ------------------------------------------------------------------------------------------------ the files
def test_carried_files_read_as_published(nominal, real):
    assert nominal.hash == "calib_5119701370761913513"
    np.testing.assert_array_equal(nominal.xyz_m[0], [0, 0, 0.1807])
    np.testing.assert_array_equal(nominal.xyz_m[2], [-0.6127, 0, 0])
    np.testing.assert_array_equal(nominal.rpy_rad[5], [1.570796326589793, 3.141592653589793, 3.141592653589793])
    assert real.hash == "calib_1811142273362460997"
    assert real.xyz_m[0, 2] == 0.1809285554189298 and real.xyz_m[2, 0] == -0.6122170645291438
    np.testing.assert_array_equal(real.xyz_m[3], [-0.5710532962649695, 0.0004321871976029597, 0.174635709173292])
    np.testing.assert_array_equal(real.rpy_rad[3], [3.139117865831163, 3.141438522722451, 3.14158831533744])
    # written back, the content is the same
    assert parse_ur_kinematics(real.as_yaml_mapping()).hash == real.hash
    np.testing.assert_array_equal(parse_ur_kinematics(real.as_yaml_mapping()).xyz_m, real.xyz_m)


def test_the_default_robot_is_nominal_and_configured_in_one_place():
    robot = load_robot_config()
    assert robot.kinematics_config == NOMINAL.resolve()
    assert Station.load().kinematics.hash == "calib_5119701370761913513"


def test_the_nominal_file_is_the_dh_of_the_robot_file(nominal):
    """ur_description's nominal file and config/ur10e.yaml's DH give the same tool0 (base frame `base`)."""
    robot = load_robot_config()
    q = np.random.default_rng(2).uniform(-np.pi, np.pi, (200, 6))
    frames = ur_arm_frames(nominal, q)
    tool0_in_base = np.linalg.inv(frames["base"]) @ frames["tool0"]
    pose = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    for i in range(6):
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        ca, sa = math.cos(robot.alpha_rad[i]), math.sin(robot.alpha_rad[i])
        link = np.zeros((len(q), 4, 4))
        link[:, 0] = np.stack([ct, -st * ca, st * sa, robot.a_m[i] * ct], 1)
        link[:, 1] = np.stack([st, ct * ca, -ct * sa, robot.a_m[i] * st], 1)
        link[:, 2, 1:] = [sa, ca, robot.d_m[i]]
        link[:, 3, 3] = 1.0
        pose = pose @ link
    np.testing.assert_allclose(tool0_in_base, pose, atol=1e-9)


# --------------------------------------------------------------------------------------------- hostile input
def _mutated(change):
    data = copy.deepcopy(_document())
    change(data)
    return data


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda d: d["kinematics"].pop("wrist_2"), "lacks.*wrist_2"),
        (lambda d: d["kinematics"].pop("hash"), "lacks.*hash"),
        (lambda d: d["kinematics"].__setitem__("wrist3", d["kinematics"]["wrist_3"]), "unknown key.*wrist3"),
        (lambda d: d["kinematics"]["forearm"].pop("x"), r"forearm.*missing \['x'\]"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("rol", 0.0), r"forearm.*unknown \['rol'\]"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", float("nan")), "forearm.x.*finite"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", float("inf")), "forearm.x.*finite"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", 1e300), "forearm.x.*implausible"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", -(MAX_OFFSET_M + 0.1)), "forearm.x.*implausible"),
        (lambda d: d["kinematics"]["wrist_1"].__setitem__("yaw", MAX_ANGLE_RAD + 0.1), "wrist_1.yaw.*implausible"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", "-0.6"), "forearm.x.*number.*str"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", True), "forearm.x.*number.*bool"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", [1, 2]), "forearm.x.*number.*list"),
        (lambda d: d["kinematics"]["forearm"].__setitem__("x", None), "forearm.x.*number"),
        (lambda d: d["kinematics"].__setitem__("shoulder", [0, 0, 0.18]), "shoulder.*mapping"),
        (lambda d: d["kinematics"].__setitem__("hash", 5119701370761913513), "hash.*calib_"),
        (lambda d: d["kinematics"].__setitem__("hash", "calib_x; rm -rf /"), "hash.*calib_"),
        (lambda d: d.__setitem__("kinematics", [1, 2, 3]), "'kinematics' must be a mapping"),
        (lambda d: d.pop("kinematics"), "key 'kinematics'"),
    ],
)
def test_hostile_content_is_refused_naming_the_key(change, match):
    with pytest.raises(KinematicsFileError, match=match) as raised:
        parse_ur_kinematics(_mutated(change), "k.yaml")
    assert isinstance(raised.value, ConfigError) and isinstance(raised.value, InputError)
    assert "k.yaml" in str(raised.value)


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "'kinematics'"),
        ("kinematics: [", "k.yaml"),
        ("- 1\n- 2\n", "'kinematics'"),
        ("kinematics: !!python/object/apply:os.system ['true']\n", "k.yaml"),
    ],
)
def test_broken_files_are_refused(tmp_path, text, match):
    path = tmp_path / "k.yaml"
    path.write_text(text)
    with pytest.raises(KinematicsFileError, match=match):
        load_ur_kinematics(path)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(KinematicsFileError, match="not found"):
        load_ur_kinematics(tmp_path / "none.yaml")
    with pytest.raises(KinematicsFileError, match="directory"):
        load_ur_kinematics(tmp_path)


def test_a_bad_configured_file_stops_the_station(tmp_path):
    robot = yaml.safe_load((CONFIG_DIR / "ur10e.yaml").read_text())
    robot["kinematics_config"] = "broken.yaml"
    (tmp_path / "ur10e.yaml").write_text(yaml.safe_dump(robot))
    (tmp_path / "broken.yaml").write_text(yaml.safe_dump(_mutated(lambda d: d["kinematics"].pop("forearm"))))
    with pytest.raises(KinematicsFileError, match="forearm"):
        Station.load(robot=tmp_path / "ur10e.yaml")
    robot["kinematics_config"] = 3
    (tmp_path / "ur10e.yaml").write_text(yaml.safe_dump(robot))
    with pytest.raises(ConfigError, match="kinematics_config"):
        load_robot_config(tmp_path / "ur10e.yaml")


# -------------------------------------------------------------------------------------- FK: reference numbers
def test_fk_nominal_vs_real_robot_matches_the_reference(nominal, real):
    """The reference: tool0 over 5,000 uniform random joint states, 1.76 mm mean / 1.65 median / 4.72 max,
    0.17 deg mean / 0.33 deg max."""
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (5000, 6))
    a, b = ur_arm_frames(nominal, q)["tool0"], ur_arm_frames(real, q)["tool0"]
    mm = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1) * 1000.0
    cos = np.clip((np.einsum("nij,nij->n", a[:, :3, :3], b[:, :3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    deg = np.degrees(np.arccos(cos))
    assert mm.mean() == pytest.approx(1.76, abs=0.03)
    assert np.median(mm) == pytest.approx(1.65, abs=0.05)
    assert mm.max() == pytest.approx(4.72, abs=0.25)
    assert deg.mean() == pytest.approx(0.17, abs=0.01) and deg.max() == pytest.approx(0.33, abs=0.02)


def test_fk_frames_follow_ur_description(nominal):
    frames = ur_arm_frames(nominal, np.zeros((1, 6)))
    np.testing.assert_allclose(frames["base"][0], np.diag([-1.0, -1.0, 1.0, 1.0]), atol=1e-15)
    np.testing.assert_allclose(frames["base_link_inertia"][0], frames["base"][0], atol=0)
    np.testing.assert_allclose(frames["tool0"][0], frames["wrist_3_link"][0], atol=1e-15)  # flange . tool0 = I
    # zero pose: the arm stretched along base's -x = base_link's +x: tool0 at a2 + a3 out, d4 + d6 aside,
    # d1 - d5 up
    np.testing.assert_allclose(frames["tool0"][0][:3, 3], [1.18425, 0.2907, 0.06085], atol=1e-9)


# --------------------------------------------------------------------------------------------- URDF frames
@pytest.mark.parametrize("path", [NOMINAL, REAL])
def test_urdf_chain_equals_the_core_fk(path):
    arm = load_ur_kinematics(path)
    urdf = UrdfModel(build_station_urdf(kinematics=path))
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (50, 6))
    expected = ur_arm_frames(arm, q)
    for frame in ("base_link_inertia", "base", "shoulder_link", "wrist_2_link", "wrist_3_link", "flange", "tool0"):
        model = KinematicModel(urdf, "base_link", frame) if frame not in ("base", "base_link_inertia") else None
        got = model.fk(q[:, : model.dof]) if model else urdf.fixed_transform("base_link", frame)
        np.testing.assert_allclose(got, expected[frame] if model else expected[frame][0], atol=1e-12, err_msg=frame)
    # the joints carry the file's origins
    for name, origin in zip(arm.joint_names, arm.joint_origins(), strict=True):
        np.testing.assert_allclose(urdf.joints[name].origin, origin, atol=1e-15)
    assert urdf.joints["shoulder_pan_joint"].parent == "base_link_inertia"


def test_the_station_does_not_move_with_the_frame_change():
    """world -> base (the DH base) is where world -> base_link was before base_link became REP-103: the pedestal
    at z = 1 m, turned by pi; base_link is the scene's mount."""
    station = Station.load()
    urdf = UrdfModel(station.urdf_xml)
    expected = np.diag([-1.0, -1.0, 1.0, 1.0])
    expected[2, 3] = 1.0
    np.testing.assert_allclose(urdf.fixed_transform("world", "base"), expected, atol=1e-12)
    np.testing.assert_allclose(station.scene.robot_dh_base_pose, expected, atol=1e-12)
    np.testing.assert_allclose(urdf.fixed_transform("world", "base_link"), station.scene.robot_base_pose, atol=0)


def test_xacro_kinematics_argument_overrides_the_robot_file():
    real = UrdfModel(build_station_urdf(kinematics=REAL))
    default = UrdfModel(build_station_urdf())
    assert real.joints["elbow_joint"].origin[0, 3] == -0.6122170645291438
    assert default.joints["elbow_joint"].origin[0, 3] == -0.6127
    for link in UR_KINEMATICS_LINKS:
        assert link  # every link key has a joint: checked by test_urdf_chain_equals_the_core_fk
