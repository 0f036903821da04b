"""The station as configuration: URDF, joint limits, named states, scene and scanner files."""

import numpy as np
import pytest
import yaml

from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.station import (
    CONFIG_DIR,
    ConfigError,
    Station,
    load_joint_limits,
    load_scene,
    read_yaml,
)
from agiprobot_measurement.station.urdf_model import UrdfModel, build_station_urdf

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


def dh_forward(q, d, a, alpha):
    """Independent standard-DH product (base frame -> flange), written out from the textbook definition."""
    pose = np.eye(4)
    for qi, di, ai, al in zip(q, d, a, alpha, strict=True):
        ct, st, ca, sa = np.cos(qi), np.sin(qi), np.cos(al), np.sin(al)
        pose = pose @ np.array(
            [[ct, -st * ca, st * sa, ai * ct], [st, ct * ca, -ct * sa, ai * st], [0, sa, ca, di], [0, 0, 0, 1]]
        )
    return pose


def test_urdf_parses_with_every_link_and_joint(station):
    model = UrdfModel(station.urdf_xml)
    for frame in ("world", "base_link", "tool0", "laser_emitter_frame", "wrist_3_link"):
        assert frame in model.links
    assert model.movable_joint_names("world", "laser_emitter_frame") == JOINTS
    # every moving link has collision geometry that follows it
    for link in ("base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link"):
        assert model.collision[link], f"{link} has no collision geometry"
    assert model.collision["laser_scanner_link"][0].type == "box"


def test_joint_limits_equal_the_config(station):
    raw = read_yaml(CONFIG_DIR / "joint_limits.yaml")["joint_limits"]
    model = UrdfModel(station.urdf_xml)
    for i, name in enumerate(JOINTS):
        assert station.limits.lower[i] == raw[name]["min_position"]
        assert station.limits.upper[i] == raw[name]["max_position"]
        assert station.limits.max_velocity[i] == raw[name]["max_velocity"]
        assert station.limits.max_acceleration[i] == raw[name]["max_acceleration"]
        joint = model.joints[name]
        assert (joint.lower, joint.upper, joint.velocity) == (
            raw[name]["min_position"],
            raw[name]["max_position"],
            raw[name]["max_velocity"],
        )
    # the original's values (reference): shoulder_lift [-3.14, 0.52], elbow [-2.9, 0.1]
    assert tuple(station.limits.lower[1:3]) == (-3.14, -2.9)
    assert tuple(station.limits.upper[1:3]) == (0.52, 0.1)


def test_fk_from_urdf_equals_independent_dh(station):
    # `base` is the DH base frame (ur_description's, base_link turned by pi about z); the default kinematics file
    # is ur_description's nominal one, equal to config/ur10e.yaml's DH
    model = KinematicModel.from_station(station, tip_frame="tool0", base_frame="base")
    robot = station.robot
    states = np.vstack([np.zeros(6), np.random.default_rng(7).uniform(-3, 3, size=(20, 6))])
    for q in states:
        expected = dh_forward(q, robot.d_m, robot.a_m, robot.alpha_rad)
        np.testing.assert_allclose(model.fk(q), expected, atol=1e-9)
        np.testing.assert_allclose(model.fk_kdl(q), expected, atol=1e-6)


def test_named_states_are_within_limits(station):
    assert set(station.named_states) >= {"home", "up"}
    for state in station.named_states.values():
        assert station.limits.within_position_limits(state)


def _write(tmp_path, name, data):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _scene_dict():
    return read_yaml(CONFIG_DIR / "scene.yaml")


@pytest.mark.parametrize(
    "mutate, expected",
    [
        (lambda s: s["robot"].pop("base_xyz_m"), "base_xyz_m"),
        (lambda s: s["objects"][0].pop("size_m"), "size_m"),
        (lambda s: s["objects"][1].update(type="pyramid"), "unknown type 'pyramid'"),
        (lambda s: s["objects"][2].update(xyz_m=[1.0, 2.0]), "xyz_m"),
        (lambda s: s["objects"][0].update(size_m=[1.0, -1.0, 1.0]), "size_m"),
        (lambda s: s["part"].update(units="furlong"), "unknown unit 'furlong'"),
        (lambda s: s["part"].update(mesh="missing_part.stl"), "part.mesh"),
        (lambda s: s.update(obstacles=[]), "unknown key(s) ['obstacles']"),
        (lambda s: s["objects"][3].update(name="table"), "duplicate object name"),
    ],
)
def test_malformed_scene_names_the_bad_key(tmp_path, mutate, expected):
    scene = _scene_dict()
    scene["part"]["mesh"] = str(CONFIG_DIR.parent / scene["part"]["mesh"])
    mutate(scene)
    with pytest.raises(ConfigError, match=None) as info:
        load_scene(_write(tmp_path, "scene.yaml", scene))
    assert expected in str(info.value)


def test_malformed_yaml_and_missing_file(tmp_path):
    bad = tmp_path / "scene.yaml"
    bad.write_text("robot: {base_xyz_m: [0, 0\n")
    with pytest.raises(ConfigError, match="malformed YAML"):
        load_scene(bad)
    with pytest.raises(ConfigError, match="file not found"):
        load_scene(tmp_path / "nope.yaml")


def test_missing_joint_limit_names_the_joint(tmp_path):
    raw = read_yaml(CONFIG_DIR / "joint_limits.yaml")
    del raw["joint_limits"]["elbow_joint"]["max_acceleration"]
    with pytest.raises(ConfigError, match=r"elbow_joint.*max_acceleration"):
        load_joint_limits(_write(tmp_path, "limits.yaml", raw))


def test_scanner_offset_and_robot_mount_are_configuration(tmp_path):
    scanner = read_yaml(CONFIG_DIR / "laser_scanner.yaml")
    scanner["mount"]["xyz_m"] = [0.01, 0.02, 0.2]
    scanner_path = _write(tmp_path, "scanner.yaml", scanner)
    scene = _scene_dict()
    scene["part"]["mesh"] = str(CONFIG_DIR.parent / scene["part"]["mesh"])
    scene["robot"]["base_xyz_m"] = [0.1, 0.2, 0.8]
    scene_path = _write(tmp_path, "scene.yaml", scene)
    station = Station.load(scanner=scanner_path, scene=scene_path)
    model = UrdfModel(station.urdf_xml)
    np.testing.assert_allclose(model.fixed_transform("tool0", "laser_emitter_frame")[:3, 3], [0.01, 0.02, 0.2])
    np.testing.assert_allclose(model.fixed_transform("world", "base_link")[:3, 3], [0.1, 0.2, 0.8])
    default = UrdfModel(build_station_urdf())
    np.testing.assert_allclose(default.fixed_transform("tool0", "laser_emitter_frame")[:3, 3], [0.0, 0.0, 0.15])


def test_calibration_scene_is_the_station_plus_its_chessboard():
    station_scene = read_yaml(CONFIG_DIR / "scene.yaml")
    calibration_scene = read_yaml(CONFIG_DIR / "calibration_scene.yaml")
    boards = [o for o in calibration_scene["objects"] if o["type"] == "chessboard"]
    assert [b["name"] for b in boards] == ["calibration_chessboard"]
    calibration_scene["objects"] = [o for o in calibration_scene["objects"] if o["type"] != "chessboard"]
    assert calibration_scene == station_scene  # the same station: only the test mode's board is added


def test_chessboard_object_loads_with_its_backing_board():
    scene = load_scene(CONFIG_DIR / "calibration_scene.yaml")
    board = next(o for o in scene.objects if o.type == "chessboard")
    assert board.inner_corners == (8, 11) and board.square_m == pytest.approx(0.02)
    size, centre = board.solid_box()
    # 12 x 9 squares plus a one-square white margin on every side, 3 mm thick, lying below the printed face
    np.testing.assert_allclose(size, [14 * 0.02, 11 * 0.02, 0.003])
    np.testing.assert_allclose(centre[:3, 3], board.pose[:3, 3] - [0.0, 0.0, 0.0015])
    table = next(o for o in scene.objects if o.name == "table")
    table_top = table.pose[2, 3] + table.size_m[2] / 2.0
    assert centre[2, 3] - size[2] / 2.0 == pytest.approx(table_top)  # it lies on the table


@pytest.mark.parametrize(
    "change, expected",
    [
        ({"inner_corners": [8]}, "inner_corners: expected [rows, columns]"),
        ({"inner_corners": [8, 1]}, "inner_corners: expected [rows, columns]"),
        ({"inner_corners": [8.5, 11]}, "inner_corners: expected [rows, columns]"),
        ({"square_m": 30}, "the unit is metres"),
        ({"square_m": -0.03}, "square_m: must be a positive number"),
        ({"thickness_m": "thin"}, "thickness_m: expected a number"),
    ],
)
def test_malformed_chessboard_names_the_bad_key(tmp_path, change, expected):
    scene = read_yaml(CONFIG_DIR / "calibration_scene.yaml")
    scene["part"]["mesh"] = str(CONFIG_DIR.parent / scene["part"]["mesh"])
    board = next(o for o in scene["objects"] if o["type"] == "chessboard")
    board.update(change)
    with pytest.raises(ConfigError) as info:
        load_scene(_write(tmp_path, "scene.yaml", scene))
    assert expected in str(info.value)
    assert "calibration_chessboard" in str(info.value)
    board.pop("square_m")
    with pytest.raises(ConfigError, match="square_m"):
        load_scene(_write(tmp_path, "scene.yaml", scene))


def test_scene_without_part_keeps_the_obstacles():
    scene = load_scene()
    assert scene.part is not None
    bare = scene.without_part()
    assert bare.part is None
    assert bare.objects == scene.objects and bare.frame_id == scene.frame_id and bare.source == scene.source
    np.testing.assert_array_equal(bare.robot_base_pose, scene.robot_base_pose)
    assert scene.part is not None  # the original is unchanged
