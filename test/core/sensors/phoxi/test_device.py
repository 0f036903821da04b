"""The simulated PhoXi device: connection, acquisition, frame ids, coordinate spaces, files; messages; reconfigure."""

from dataclasses import replace

import numpy as np
import pytest

from agiprobot_measurement.sensors.phoxi import reconfigure as phoxi_config
from agiprobot_measurement.sensors.phoxi.device import (
    CUSTOM_SPACE,
    ROBOT_SPACE,
    PhoxiDevice,
    PhoxiError,
    frame_output,
    load_camera_config,
    transform_from_quaternion,
)
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply, read_point_tiff
from agiprobot_measurement.sensors.phoxi.renderer import (
    RESOLUTION_HIGH,
    RESOLUTION_LOW,
    SceneGeometry,
    load_scanner_model,
    primitive_mesh,
)


def _wall(depth_m=0.65):
    box = SceneGeometry.from_trimesh(primitive_mesh("box", [3.0, 3.0, 0.01]), "wall", 0.8)
    pose = np.eye(4)
    pose[2, 3] = depth_m + 0.005
    return box.transformed(pose)


@pytest.fixture()
def device(tmp_path):
    # a small sensor keeps the tests fast; the optics are the PhoXi M's
    model = replace(load_scanner_model("M"), resolutions={RESOLUTION_HIGH: (160, 120), RESOLUTION_LOW: (80, 60)})
    dev = PhoxiDevice(model, _wall(), tmp_path / "out", frame_buffer_size=2)
    dev.connect("")
    return dev


CAMERA = np.eye(4)


# ------------------------------------------------------------------------------ connection, frames
def test_connect_by_hardware_id_and_refuse_unknown_scanners(device):
    device.disconnect()
    assert device.status() == ("ERROR", "Not connected")
    with pytest.raises(PhoxiError, match="Scanner not found: 'nope'"):
        device.connect("nope")
    device.connect(device.hardware_identification)
    assert device.connected and device.acquiring and device.status() == ("OK", "Ready")


def test_acquisition_gates_triggering(device):
    device.stop_acquisition()
    assert device.status() == ("WARN", "Acquisition not started")
    with pytest.raises(PhoxiError, match="Acquisition not started"):
        device.trigger(CAMERA)
    device.start_acquisition()
    assert device.trigger(CAMERA).index == 0
    device.disconnect()
    with pytest.raises(PhoxiError, match="not connected"):
        device.trigger(CAMERA)
    with pytest.raises(PhoxiError, match="not connected"):
        device.start_acquisition()


def test_frame_ids_count_up_and_only_held_frames_are_served(device):
    ids = [device.get_frame(-1, CAMERA).index for _ in range(3)]
    assert ids == [0, 1, 2]
    assert device.get_frame(2, None).index == 2
    with pytest.raises(PhoxiError, match=r"Frame 0 is not available \(frames held: 1, 2"):
        device.get_frame(0, None)  # pushed out of the buffer of 2
    with pytest.raises(PhoxiError, match="Frame 17 is not available"):
        device.frame(17)


def test_settings_reach_the_frames(device):
    device.update_settings(resolution=RESOLUTION_LOW)
    frame = device.trigger(CAMERA)
    assert (frame.width, frame.height) == (80, 60)
    assert frame.valid.mean() > 0.9
    np.testing.assert_allclose(frame.depth_mm[frame.valid], 650.0, atol=1.0)


# ---------------------------------------------------------------------------------------- spaces
def test_coordinate_spaces(device):
    with pytest.raises(PhoxiError, match="MarkerSpace needs a marker calibration"):
        device.set_coordinate_space(3)
    with pytest.raises(PhoxiError, match="RobotSpace has no transformation yet"):
        device.set_coordinate_space(ROBOT_SPACE)
    with pytest.raises(PhoxiError, match="Unknown coordinate space 9"):
        device.set_coordinate_space(9)
    device.set_coordinate_space(CUSTOM_SPACE)  # identity until a transformation is set
    with pytest.raises(PhoxiError, match="4 RobotSpace and 5 CustomSpace only"):
        device.set_transformation(np.eye(4), 1, True, False)
    shift = transform_from_quaternion([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0])
    device.set_transformation(shift, CUSTOM_SPACE, set_space=True, save_settings=False)
    custom = device.trigger(CAMERA)
    device.set_coordinate_space(1)
    camera = device.trigger(CAMERA)
    points_custom, _ = frame_output(custom)
    points_camera, _ = frame_output(camera)
    valid = custom.valid
    np.testing.assert_allclose(points_custom[valid][:, 2], custom.depth_mm[valid] / 1000.0 + 1.0, atol=1e-5)
    np.testing.assert_allclose(points_camera[camera.valid][:, 2], camera.depth_mm[camera.valid] / 1000.0, atol=1e-6)
    np.testing.assert_array_equal(points_custom[~valid], 0.0)
    # a frame keeps the space it was captured in
    again, _ = frame_output(device.frame(custom.index))
    np.testing.assert_array_equal(again, points_custom)


def test_transformations_must_be_proper(device):
    with pytest.raises(PhoxiError, match="zero quaternion"):
        transform_from_quaternion([0, 0, 0], [0, 0, 0, 0])
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(PhoxiError, match="not a proper rotation"):
        device.set_transformation(mirror, CUSTOM_SPACE, True, False)
    # a quaternion that is not normalised is normalised (rotation by 90 deg about z)
    np.testing.assert_allclose(transform_from_quaternion([0, 0, 0], [0, 0, 2, 2])[:3, 0], [0, 1, 0], atol=1e-12)


# ----------------------------------------------------------------------------------------- files
def test_save_frame_writes_a_ply_that_reloads_with_the_same_points(device):
    frame = device.trigger(CAMERA)
    path = device.save_frame(frame, "run1/frame.ply", organized=True)
    assert path == device.output_dir / "run1" / "frame.ply"
    data = read_ply(path)
    points, normals = frame_output(frame)
    np.testing.assert_array_equal(np.stack([data["x"], data["y"], data["z"]], 1), points.reshape(-1, 3))
    np.testing.assert_array_equal(np.stack([data["nx"], data["ny"], data["nz"]], 1), normals.reshape(-1, 3))
    assert "units: metres" in data["comments"]
    assert f"organized: width {frame.width} height {frame.height} (invalid points are 0 0 0)" in data["comments"]
    valid_only = read_ply(device.save_frame(frame, "valid.ply", organized=False))
    assert len(valid_only["x"]) == frame.valid.sum()
    np.testing.assert_array_equal(valid_only["z"], points[frame.valid][:, 2])


def test_refused_paths_write_nothing(device, tmp_path):
    frame = device.trigger(CAMERA)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    for requested in ("../escape.ply", str(tmp_path / "escape.ply"), ""):
        with pytest.raises(PhoxiError, match=r"outside the output directory|empty path"):
            device.save_frame(frame, requested)
    device.mark_published(frame)
    with pytest.raises(PhoxiError, match="outside the output directory"):
        device.save_last_frame("../../escape.ply")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_save_last_frame_by_extension(device):
    with pytest.raises(PhoxiError, match="There is no frame to save"):
        device.save_last_frame("a.ply")
    frame = device.trigger(CAMERA)
    device.mark_published(frame)
    for name in ("a.pcd", "a.PLYX", "noextension"):
        with pytest.raises(PhoxiError) as error:
            device.save_last_frame(name)
        assert str(error.value) == "Wrong extension."
    with pytest.raises(PhoxiError, match="raw format"):
        device.save_last_frame("a.praw")
    points, _ = frame_output(frame)
    ply = read_ply(device.save_last_frame("last.PLY"))
    np.testing.assert_array_equal(ply["z"], points[:, :, 2].reshape(-1))
    np.testing.assert_array_equal(read_point_tiff(device.save_last_frame("last.tif")), points)
    ptx = device.save_last_frame("last.ptx").read_text().splitlines()
    assert ptx[:2] == [str(frame.width), str(frame.height)] and len(ptx) == 10 + frame.width * frame.height


# ------------------------------------------------------------------------------------- messages
def test_pointcloud_and_depth_map_agree_pixel_by_pixel(device):
    from std_msgs.msg import Header

    from agiprobot_measurement.ros import phoxi_messages

    device.update_settings(resolution=RESOLUTION_HIGH)
    frame = device.trigger(CAMERA)
    points, normals = frame_output(frame)
    header = Header(frame_id="PhoXi3Dscanner_sensor")
    cloud = phoxi_messages.pointcloud2(points, normals, frame.valid, header, organized=True)
    depth = phoxi_messages.image(frame.depth_mm, "32FC1", header)
    assert (cloud.width, cloud.height, cloud.point_step, cloud.row_step) == (160, 120, 48, 48 * 160)
    assert [(f.name, f.offset) for f in cloud.fields] == list(phoxi_messages.POINT_FIELDS)
    xyz, nrm, curvature = phoxi_messages.pointcloud2_arrays(cloud)
    depth_mm = phoxi_messages.image_array(depth)
    assert depth.encoding == "32FC1" and depth_mm.shape == (120, 160)
    np.testing.assert_allclose(xyz[:, :, 2] * 1000.0, depth_mm, rtol=1e-6)
    np.testing.assert_array_equal(xyz[depth_mm == 0], 0.0)  # zeros kept where the depth map has no value
    intr = frame.intrinsics
    u = np.arange(intr.width)[None, :]
    np.testing.assert_allclose(xyz[:, :, 0], (u - intr.cx) / intr.fx * depth_mm / 1000.0, atol=1e-6)
    np.testing.assert_array_equal(nrm, normals)
    np.testing.assert_array_equal(curvature, 0.0)
    flat = phoxi_messages.pointcloud2(points, normals, frame.valid, header, organized=False)
    assert flat.height == 1 and flat.width == frame.valid.sum()
    normal_map = phoxi_messages.image_array(phoxi_messages.image(normals, "32FC3", header))
    np.testing.assert_array_equal(normal_map, normals)


def test_camera_info_holds_the_intrinsics(device):
    from std_msgs.msg import Header

    from agiprobot_measurement.ros import phoxi_messages

    intr = device.model.intrinsics(RESOLUTION_HIGH)
    info = phoxi_messages.camera_info(intr, Header())
    assert (info.width, info.height) == (160, 120)
    np.testing.assert_allclose(np.reshape(info.K, (3, 3)), intr.matrix())
    np.testing.assert_allclose(np.reshape(info.P, (3, 4))[:, :3], intr.matrix())
    assert info.distortion_model == "plumb_bob" and list(info.D) == [0.0] * 5


# ---------------------------------------------------------------------------------- configuration
REFERENCE_DEFAULTS = {
    "resolution": 1,
    "scan_multiplier": 1,
    "shutter_multiplier": 1,
    "confidence": 3.0,
    "send_confidence_map": True,
    "send_depth_map": True,
    "send_normal_map": True,
    "send_point_cloud": True,
    "send_texture": True,
    "timeout": -3,
    "trigger_mode": 1,
    "coordinate_space": 1,
    "ambient_light_suppression": False,
    "single_pattern_exposure": 2,
    "camera_only_mode": False,
    "organized_cloud": True,
}


def test_reconfigure_description_matches_the_reference():
    for name, default in REFERENCE_DEFAULTS.items():
        assert phoxi_config.defaults[name] == default, name
        assert type(phoxi_config.defaults[name]) is type(default), name
    ranges = {"scan_multiplier": (1, 50), "shutter_multiplier": (1, 20), "confidence": (0.0, 10.0)}
    ranges.update({"single_pattern_exposure": (0, 11), "resolution": (0, 1), "coordinate_space": (1, 5)})
    for name, (low, high) in ranges.items():
        assert (phoxi_config.min[name], phoxi_config.max[name]) == (low, high), name
    assert phoxi_config.STATIC_PARAMETERS == {
        "scanner_id": "",
        "frame_id": "PhoXi3Dscanner_sensor",
        "latch_topics": False,
        "topic_queue_size": 1,
        "init_from_config": False,
    }
    from dynamic_reconfigure.encoding import encode_description, extract_params

    description = encode_description(phoxi_config)
    names = [p.name for group in description.groups for p in group.parameters]
    assert names == [p["name"] for p in extract_params(phoxi_config.config_description)]
    assert len(set(phoxi_config.level.values())) == len(names), "each parameter has its own level bit"


def test_camera_config_errors_name_the_key(tmp_path):
    from agiprobot_measurement.station import ConfigError

    path = tmp_path / "cam.yaml"
    path.write_text("model: L\npose:\n  xyz_m: [1, 2, 3]\n  rpy_rad: [0, 0, 0]\n  look_at_m: [0, 0, 0]\n")
    with pytest.raises(ConfigError, match="exactly one of rpy_rad and look_at_m"):
        load_camera_config(path)
    path.write_text("model: L\npose:\n  xyz_m: [1, 2]\n  rpy_rad: [0, 0, 0]\n")
    with pytest.raises(ConfigError, match=r"pose\.xyz_m: expected 3 numbers"):
        load_camera_config(path)
