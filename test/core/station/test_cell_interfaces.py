"""The cell check's core: the bundled interface list, its checks, and what is missing from a master's report."""

import pytest
import yaml

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.station.cell_interfaces import (
    CELL_INTERFACES_FILE,
    MasterSnapshot,
    load_cell_interfaces,
    missing_interfaces,
    parse_roles,
)

FJT = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"
#: what a running ur10e_bringup.launch, scanCONTROL driver and stitcher show on the master (types as upstream)
CELL_TOPICS = {
    f"{FJT}/status": "actionlib_msgs/GoalStatusArray",
    f"{FJT}/feedback": "control_msgs/FollowJointTrajectoryActionFeedback",
    f"{FJT}/result": "control_msgs/FollowJointTrajectoryActionResult",
    "/joint_states": "sensor_msgs/JointState",
    "/ur_hardware_interface/robot_program_running": "std_msgs/Bool",
    "/speed_scaling_factor": "std_msgs/Float64",
    "/scancontrol_pointcloud": "sensor_msgs/PointCloud2",
    "/rosout": "rosgraph_msgs/Log",
}
CELL_SERVICES = {"/switch_stitch_mode": "std_srvs/SetBool", "/clear_stitched_point_cloud": "std_srvs/Trigger"}
CELL_PARAMS = frozenset({"/robot_description", "/run_id"})
ROLES = ["robot", "scanner", "stitcher"]


@pytest.fixture(scope="module")
def cell():
    return load_cell_interfaces()


def _texts(cell, master, roles=ROLES):
    return [m.text for m in missing_interfaces(cell, roles, master)]


def test_the_bundled_file_has_the_upstream_names(cell):
    assert list(cell.roles) == ["robot", "scanner", "stitcher", "phoxi"]
    robot = {(i.kind, i.name, i.type) for i in cell.roles["robot"].interfaces}
    assert robot == {
        ("action", FJT, "control_msgs/FollowJointTrajectory"),
        ("topic", "/joint_states", "sensor_msgs/JointState"),
        ("topic", "/ur_hardware_interface/robot_program_running", "std_msgs/Bool"),
        ("topic", "/speed_scaling_factor", "std_msgs/Float64"),
        ("param", "/robot_description", ""),
    }
    assert cell.wanted(["scanner"], "topic") == ["/scancontrol_pointcloud"]
    assert cell.wanted(["stitcher"], "service") == list(CELL_SERVICES)
    assert cell.source == CELL_INTERFACES_FILE


def test_a_complete_cell_misses_nothing(cell):
    master = MasterSnapshot(CELL_TOPICS, CELL_SERVICES, CELL_PARAMS)
    assert missing_interfaces(cell, ROLES, master) == []
    # a service whose type could not be read is not held against it
    assert _texts(cell, MasterSnapshot(CELL_TOPICS, dict.fromkeys(CELL_SERVICES, ""), CELL_PARAMS)) == []


def test_an_empty_master_names_every_interface_and_its_provider(cell):
    texts = _texts(cell, MasterSnapshot())
    assert texts == [
        f"robot: no action server {FJT} (control_msgs/FollowJointTrajectory) — is ur_robot_driver's "
        "ur10e_bringup.launch running?",
        "robot: no publisher of topic /joint_states (sensor_msgs/JointState) — is ur_robot_driver's "
        "ur10e_bringup.launch running?",
        "robot: no publisher of topic /ur_hardware_interface/robot_program_running (std_msgs/Bool) — is "
        "ur_robot_driver's ur10e_bringup.launch running?",
        "robot: no publisher of topic /speed_scaling_factor (std_msgs/Float64) — is ur_robot_driver's "
        "ur10e_bringup.launch running?",
        "robot: no parameter /robot_description — is ur_robot_driver's ur10e_bringup.launch running?",
        "scanner: no publisher of topic /scancontrol_pointcloud (sensor_msgs/PointCloud2) — is "
        "micro_epsilon_scancontrol_driver's load_driver.launch running?",
        "stitcher: no service /switch_stitch_mode (std_srvs/SetBool) — is the point-cloud stitcher running?",
        "stitcher: no service /clear_stitched_point_cloud (std_srvs/Trigger) — is the point-cloud stitcher running?",
    ]


@pytest.mark.parametrize("dropped", sorted(CELL_TOPICS))
def test_each_missing_topic_is_named(cell, dropped):
    topics = {k: v for k, v in CELL_TOPICS.items() if k != dropped}
    texts = _texts(cell, MasterSnapshot(topics, CELL_SERVICES, CELL_PARAMS))
    if dropped == "/rosout":
        assert texts == []
    elif dropped.startswith(FJT):  # any of the action server's topics missing: no action server
        assert texts == [texts[0]] and texts[0].startswith(f"robot: no action server {FJT} ")
    else:
        assert len(texts) == 1 and f"no publisher of topic {dropped} (" in texts[0]


def test_a_missing_service_and_parameter_are_named(cell):
    services = {"/switch_stitch_mode": "std_srvs/SetBool"}
    texts = _texts(cell, MasterSnapshot(CELL_TOPICS, services, frozenset()))
    assert texts == [
        "robot: no parameter /robot_description — is ur_robot_driver's ur10e_bringup.launch running?",
        "stitcher: no service /clear_stitched_point_cloud (std_srvs/Trigger) — is the point-cloud stitcher running?",
    ]


def test_a_wrong_type_is_named_with_both_types(cell):
    topics = dict(CELL_TOPICS)
    topics["/joint_states"] = "std_msgs/String"
    topics[f"{FJT}/result"] = "control_msgs/JointTrajectoryActionResult"  # the older action under the same name
    services = dict(CELL_SERVICES, **{"/switch_stitch_mode": "agiprobot_measurement/SetStitching"})
    texts = _texts(cell, MasterSnapshot(topics, services, CELL_PARAMS))
    assert texts == [
        f"robot: action server {FJT} is control_msgs/JointTrajectory, expected control_msgs/FollowJointTrajectory — "
        "is it ur_robot_driver's ur10e_bringup.launch that offers it?",
        "robot: topic /joint_states is std_msgs/String, expected sensor_msgs/JointState — is it ur_robot_driver's "
        "ur10e_bringup.launch that offers it?",
        "stitcher: service /switch_stitch_mode is agiprobot_measurement/SetStitching, expected std_srvs/SetBool — "
        "is it the point-cloud stitcher that offers it?",
    ]


def test_only_the_chosen_roles_are_checked(cell):
    assert _texts(cell, MasterSnapshot(), ["stitcher"]) == _texts(cell, MasterSnapshot())[-2:]
    phoxi = _texts(cell, MasterSnapshot(CELL_TOPICS, CELL_SERVICES, CELL_PARAMS), ["phoxi", "robot", "phoxi"])
    assert len(phoxi) == 3 and all(t.startswith("phoxi: ") for t in phoxi)
    with pytest.raises(ConfigError, match=r"unknown role\(s\) 'gripper'; the cell has robot, scanner, stitcher, phoxi"):
        missing_interfaces(cell, ["robot", "gripper"], MasterSnapshot())
    with pytest.raises(ConfigError, match="no role chosen"):
        missing_interfaces(cell, [], MasterSnapshot())


def test_roles_from_a_launch_argument_or_a_list():
    assert parse_roles("robot scanner,stitcher", "~roles") == ["robot", "scanner", "stitcher"]
    assert parse_roles(["robot"], "~roles") == ["robot"]
    for bad in (3, ["robot", ""], [None], {"robot": 1}):
        with pytest.raises(ConfigError, match="~roles: expected a list of role names"):
            parse_roles(bad, "~roles")


def _write(tmp_path, roles):
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({"roles": roles}))
    return path


ROBOT = {"provider": "p.launch", "interfaces": [{"kind": "topic", "name": "/a", "type": "std_msgs/Bool"}]}


@pytest.mark.parametrize(
    ("roles", "words"),
    [
        ({}, "roles must be a non-empty mapping"),
        ({"Robot": ROBOT}, "role name 'Robot' must be lower-case"),
        ({"robot": {"interfaces": ROBOT["interfaces"]}}, "missing key 'provider'"),
        ({"robot": dict(ROBOT, provider=" ")}, "robot.provider: expected the launch file"),
        ({"robot": dict(ROBOT, colour=1)}, "unknown key(s) ['colour']"),
        ({"robot": dict(ROBOT, interfaces=[])}, "robot.interfaces: expected a non-empty list"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "node", "name": "/a", "type": "a/B"}])}, "kind 'node' is not"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "topic", "name": "a", "type": "a/B"}])}, "resolved ROS name"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "topic", "name": "/a", "type": "Bool"}])}, "must be package/Name"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "topic", "name": "/a"}])}, "missing key 'type'"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "param", "name": "/a", "type": "a/B"}])}, "a param has no type"),
        ({"robot": dict(ROBOT, interfaces=[{"kind": "topic", "name": "/a", "type": "a/B", "rate": 1}])}, "['rate']"),
        ({"robot": dict(ROBOT, interfaces=ROBOT["interfaces"] * 2)}, "topic /a is listed twice"),
    ],
)
def test_a_bad_file_is_refused_naming_the_key(tmp_path, roles, words):
    with pytest.raises(ConfigError) as info:
        load_cell_interfaces(_write(tmp_path, roles))
    assert words in str(info.value) and "cell.yaml" in str(info.value)


def test_a_file_of_ones_own_roles(tmp_path):
    cell = load_cell_interfaces(_write(tmp_path, {"gripper": ROBOT}))
    assert _texts(cell, MasterSnapshot(), ["gripper"]) == [
        "gripper: no publisher of topic /a (std_msgs/Bool) — is p.launch running?"
    ]
    assert _texts(cell, MasterSnapshot({"/a": "std_msgs/Bool"}), ["gripper"]) == []
    with pytest.raises(ConfigError, match="file not found"):
        load_cell_interfaces(tmp_path / "absent.yaml")
