"""The files of the interface package phoxi_camera that users of the real driver load by name: the URDF macros with
the driver's macro, link and joint names, the parameter file's schema and defaults, the launch files.

Facts from photoneo/phoxi_camera 1.8.0 (urdf/PhoXi3Dscanner_*.xacro, config/phoxi_camera.yaml, launch/).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.common.geometry import rpy_to_matrix

xacro = pytest.importorskip("xacro")

PHOXI = PACKAGE_ROOT / "packages" / "phoxi_camera"

#: the driver's config/phoxi_camera.yaml: every key, in its order, with its default
DRIVER_PARAMETERS = {
    "scanner_id": "",
    "frame_id": "PhoXi3Dscanner_sensor",
    "latch_topics": False,
    "topic_queue_size": 1,
    "init_from_config": False,
    "organized_cloud": True,
    "resolution": 1,
    "scan_multiplier": 1,
    "confidence": 3.0,
    "send_confidence_map": True,
    "send_depth_map": True,
    "send_normal_map": True,
    "send_point_cloud": True,
    "send_texture": True,
    "shutter_multiplier": 1,
    "timeout": -3,
    "trigger_mode": 1,
    "coordinate_space": 1,
    "ambient_light_suppression": False,
    "single_pattern_exposure": 2,
    "camera_only_mode": False,
}

#: the driver's default sensor origins per model (xyz m, rpy rad) of urdf/PhoXi3Dscanner_values.xacro
SENSOR_ORIGINS = {
    "XS_old": ((0.1, 0.025, 0.035), (0.0, -15.45 / 180 * math.pi, math.pi)),
    "XS": ((0.090, 0.0299, 0.03595), (0.0, 0.0, math.pi)),
    "S": ((-0.1173845315, 0.0299, 0.005287752939), (0.0, -15.45 / 180 * math.pi, math.pi)),
    "M": ((-0.176277236938477, 0.0299, 0.002164826095), (0.0, -11.75 / 180 * math.pi, math.pi)),
    "L": ((-0.274213, 0.0299, 0.0090044), (0.0, -9.45 / 180 * math.pi, math.pi)),
    "XL": ((-0.4349977156, 0.0299, 0.02086702926), (0.0, -7.5 / 180 * math.pi, math.pi)),
}


def expand(path) -> ET.Element:
    return ET.fromstring(xacro.process_file(str(path)).toxml())


def origin_of(joint: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    origin = joint.find("origin")
    return (
        np.array([float(v) for v in origin.get("xyz").split()]),
        np.array([float(v) for v in origin.get("rpy").split()]),
    )


def test_the_example_description_has_the_driver_frames():
    robot = expand(PHOXI / "urdf" / "PhoXi3Dscanner.xacro")
    assert {link.get("name") for link in robot.iter("link")} == {"base_link", "PhoXi3Dscanner", "PhoXi3Dscanner_sensor"}
    joints = {j.get("name"): j for j in robot.iter("joint")}
    assert set(joints) == {"base_link_to_PhoXi3Dscanner_joint", "PhoXi3Dscanner_to_PhoXi3Dscanner_sensor_joint"}
    sensor = joints["PhoXi3Dscanner_to_PhoXi3Dscanner_sensor_joint"]
    assert (sensor.find("parent").get("link"), sensor.find("child").get("link")) == (
        "PhoXi3Dscanner",
        "PhoXi3Dscanner_sensor",
    )
    xyz, rpy = origin_of(sensor)
    np.testing.assert_allclose(xyz, SENSOR_ORIGINS["M"][0])
    np.testing.assert_allclose(rpy, SENSOR_ORIGINS["M"][1])


@pytest.mark.parametrize("model", sorted(SENSOR_ORIGINS))
def test_every_model_macro_gives_the_driver_origin_and_a_housing(tmp_path, model):
    # a user's URDF as the driver's README writes one: own parent and names, the model's two macros
    (tmp_path / "robot.xacro").write_text(
        f"""<?xml version="1.0"?>
<robot name="cell" xmlns:xacro="http://ros.org/wiki/xacro">
  <xacro:include filename="{PHOXI}/urdf/PhoXi3Dscanner_values.xacro"/>
  <xacro:include filename="{PHOXI}/urdf/PhoXi3Dscanner_macro.xacro"/>
  <link name="tool0"/>
  <xacro:PhoXi3Dscanner scanner_parent="tool0" scanner_name="scanner" sensor_parent="scanner"
                        sensor_name="scanner_optical">
    <origin xyz="0.1 0 0.2" rpy="0 0 0.5"/>
    <xacro:PhoXi3Dscanner{model}_default_sensor_origin/>
    <xacro:PhoXi3Dscanner{model}_meshes/>
  </xacro:PhoXi3Dscanner>
</robot>
"""
    )
    robot = expand(tmp_path / "robot.xacro")
    joints = {j.get("name"): j for j in robot.iter("joint")}
    np.testing.assert_allclose(origin_of(joints["tool0_to_scanner_joint"])[0], [0.1, 0.0, 0.2])
    xyz, rpy = origin_of(joints["scanner_to_scanner_optical_joint"])
    np.testing.assert_allclose(xyz, SENSOR_ORIGINS[model][0])
    np.testing.assert_allclose(rpy, SENSOR_ORIGINS[model][1], atol=1e-12)
    housing = next(link for link in robot.iter("link") if link.get("name") == "scanner")
    boxes = [np.array([float(v) for v in b.get("size").split()]) for b in housing.iter("box")]
    assert len(boxes) == 2, "a visual and a collision box"
    # the housing's long side lies along the baseline, between projector and camera (the sensor sits inside it)
    visual = housing.find("visual")
    turn = rpy_to_matrix([float(v) for v in visual.find("origin").get("rpy").split()])
    extent = np.abs(turn @ boxes[0])
    assert np.argmax(extent) == 0 and extent[0] / 2 >= abs(SENSOR_ORIGINS[model][0][0])


def test_the_parameter_file_has_the_driver_schema():
    data = read_yaml(PHOXI / "config" / "phoxi_camera.yaml")
    assert list(data) == list(DRIVER_PARAMETERS)
    assert data == DRIVER_PARAMETERS
    assert all(type(data[k]) is type(v) for k, v in DRIVER_PARAMETERS.items())


def test_the_driver_launch_files_exist_and_start_the_node_type_phoxi_camera():
    names = {p.name for p in (PHOXI / "launch").glob("*.launch")}
    assert {"phoxi_camera.launch", "phoxi_camera_test.launch", "display_urdf.launch", "load_urdf.launch"} <= names
    launch = ET.parse(PHOXI / "launch" / "phoxi_camera.launch").getroot()
    (node,) = launch.findall("node")
    assert (node.get("pkg"), node.get("type"), node.get("name")) == ("phoxi_camera", "phoxi_camera", "phoxi_camera")
    assert node.find("rosparam").get("command") == "load"
    # every simulator argument has a default: the driver's `roslaunch phoxi_camera phoxi_camera.launch` needs none
    assert all(arg.get("default") is not None for arg in launch.findall("arg"))
    assert (PHOXI / "nodes" / "phoxi_camera").is_file()
    urdf_launch = ET.parse(PHOXI / "launch" / "load_urdf.launch").getroot()
    assert urdf_launch.find("param").get("name") == "robot_description"


def test_the_test_launch_scene_is_in_front_of_the_example_scanner():
    from agiprobot_measurement.station import load_scene

    scene = load_scene(PHOXI / "config" / "phoxi_camera_test_scene.yaml")
    assert scene.frame_id == "base_link"  # the example description's root: the scanner's pose comes from its tf
    xyz, rpy = SENSOR_ORIGINS["M"]
    view = rpy_to_matrix(rpy)[:, 2]
    board = next(o for o in scene.objects if o.name == "board")
    to_board = board.pose[:3, 3] - np.asarray(xyz)
    distance_m = float(np.linalg.norm(to_board))
    off_axis_deg = math.degrees(math.acos(float(to_board @ view) / distance_m))
    assert off_axis_deg < 5.0
    assert 0.458 < distance_m < 1.118  # the M's scanning range
