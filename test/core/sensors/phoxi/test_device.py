"""The simulated PhoXi device: connection, acquisition, frame ids, coordinate spaces, files; messages; reconfigure."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.sensors.phoxi import reconfigure as phoxi_config
from agiprobot_measurement.sensors.phoxi.device import (
    CUSTOM_SPACE,
    MAX_TRANSLATION_M,
    ROBOT_SPACE,
    PhoxiDevice,
    PhoxiError,
    check_transformation,
    default_allowed_save_dirs,
    default_output_dir,
    frame_output,
    load_camera_config,
    overridden_pose,
    transform_from_quaternion,
)
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_HIGH, RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply, read_point_tiff
from agiprobot_measurement.sensors.phoxi.scene_geometry import SceneGeometry, primitive_mesh


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


@pytest.mark.parametrize(
    "translation, quaternion, words",
    [
        ([1e308, 0, 0], [0, 0, 0, 1], ["translation", "beyond the 1000 m"]),
        ([0, 0, 1001], [0, 0, 0, 1], ["translation", "1e+03 m long"]),
        ([0, np.inf, 0], [0, 0, 0, 1], ["must be finite", "inf"]),
        ([0, 0, 0], [np.nan, 0, 0, 1], ["must be finite", "nan"]),
        ([0, 0, 0], [1e308, 1e308, 1e308, 1e308], ["too large to normalise"]),
        ([0, 0, 0], [0, 0, 0, 1e-300], ["zero quaternion"]),
    ],
)
def test_absurd_transformations_are_refused_and_later_frames_stay_finite(device, translation, quaternion, words):
    good = transform_from_quaternion([0.1, 0.2, 0.3], [0, 0, 0, 1])
    device.set_transformation(good, CUSTOM_SPACE, set_space=True, save_settings=False)
    with pytest.raises(PhoxiError) as info:
        device.set_transformation(transform_from_quaternion(translation, quaternion), CUSTOM_SPACE, True, False)
    for word in words:
        assert word in str(info.value)
    np.testing.assert_array_equal(device.output_transform(), good)  # the refusal changed nothing
    points, normals = frame_output(device.trigger(CAMERA))
    assert np.all(np.isfinite(points)) and np.all(np.isfinite(normals))


def test_check_transformation_refuses_matrices_that_are_not_rigid():
    np.testing.assert_array_equal(check_transformation(np.eye(4)), np.eye(4))
    at_limit = np.eye(4)
    at_limit[0, 3] = MAX_TRANSLATION_M
    check_transformation(at_limit)
    sheared, scaled, bottom = np.eye(4), np.diag([2.0, 2.0, 2.0, 1.0]), np.eye(4)
    sheared[0, 1] = 0.1
    bottom[3, 0] = 1.0
    for matrix, word in ((sheared, "not a proper rotation"), (scaled, "orthonormal"), (bottom, "last row")):
        with pytest.raises(PhoxiError, match=word):
            check_transformation(matrix)
    with pytest.raises(PhoxiError, match="finite 4x4"):
        check_transformation(np.eye(3))
    # huge but finite components are only a quaternion to normalise
    np.testing.assert_allclose(transform_from_quaternion([0, 0, 0], [0, 0, 1e300, 1e300])[:3, 0], [0, 1, 0], atol=1e-12)


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
        with pytest.raises(PhoxiError, match=r"is not allowed in|outside the allowed folder|empty"):
            device.save_frame(frame, requested)
    device.mark_published(frame)
    with pytest.raises(PhoxiError, match=r"'\.\.' is not allowed.*names resolve under"):
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


# ------------------------------------------------------------------------------------- file policy
def _policy_device(tmp_path, allowed=()):
    root = tmp_path / "cwd"
    root.mkdir(exist_ok=True)
    model = replace(load_scanner_model("M"), resolutions={RESOLUTION_HIGH: (40, 30), RESOLUTION_LOW: (20, 15)})
    dev = PhoxiDevice(model, _wall(), root, allowed_dirs=allowed)
    dev.connect("")
    frame = dev.trigger(CAMERA)
    dev.mark_published(frame)
    return dev, frame


def _files(folder):
    return sorted(str(p) for p in folder.rglob("*"))


def test_a_good_relative_name_resolves_under_the_working_directory_and_is_replaced_atomically(tmp_path):
    device, frame = _policy_device(tmp_path)
    path = device.save_frame(frame, "run/frame.ply")
    assert path == tmp_path / "cwd" / "run" / "frame.ply" and path.is_file()
    # the driver overwrites: a second save replaces the file, with no temporary left behind
    second = device.trigger(CAMERA)
    assert device.save_frame(second, "run/frame.ply") == path
    assert f"frame {second.index}" in " ".join(read_ply(path)["comments"])
    assert [p.name for p in path.parent.iterdir()] == ["frame.ply"]
    assert device.save_frame(frame, str(path)) == path  # an absolute name inside the root


@pytest.mark.parametrize(
    "requested, words",
    [
        ("../x.ply", ["'..' is not allowed", "names resolve under", "cwd"]),
        ("run/../../x.ply", ["'..' is not allowed"]),
        ("~/x.ply", ["'~' is not expanded", "names resolve under"]),
        ("/etc/x.ply", ["/etc/x.ply is outside the allowed folder", "cwd"]),
        ("run/.ply", []),  # a hidden file name: allowed, below
        (".", ["is a directory"]),
    ],
)
def test_escaping_names_are_refused_with_the_root_named(tmp_path, requested, words):
    device, frame = _policy_device(tmp_path)
    if not words:
        assert device.save_frame(frame, requested) == tmp_path / "cwd" / requested
        return
    before = _files(tmp_path)
    for save in (device.save_frame, lambda _frame, name: device.save_last_frame(name)):
        with pytest.raises(PhoxiError) as info:
            save(frame, requested if requested != "." else "./")
        if requested != ".":
            for word in words:
                assert word in str(info.value)
    assert _files(tmp_path) == before


@pytest.mark.parametrize("requested", ["", "   "])
def test_empty_names_are_refused(tmp_path, requested):
    device, frame = _policy_device(tmp_path)
    with pytest.raises(PhoxiError, match="empty"):
        device.save_frame(frame, requested)
    assert _files(tmp_path / "cwd") == []


def test_a_symlink_out_of_the_root_is_refused(tmp_path):
    device, frame = _policy_device(tmp_path)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (tmp_path / "cwd" / "link").symlink_to(outside, target_is_directory=True)
    with pytest.raises(PhoxiError, match="outside the allowed folder"):
        device.save_frame(frame, "link/x.ply")
    with pytest.raises(PhoxiError, match="outside the allowed folder"):
        device.save_last_frame("link/x.ptx")
    (tmp_path / "cwd" / "file_link.ply").symlink_to(outside / "target.ply")
    with pytest.raises(PhoxiError, match="outside the allowed folder"):
        device.save_frame(frame, "file_link.ply")
    assert list(outside.iterdir()) == []


def test_absolute_names_may_point_into_the_allowed_folders_only(tmp_path):
    allowed = tmp_path / "ros_home"
    allowed.mkdir()
    device, frame = _policy_device(tmp_path, allowed=[allowed])
    assert device.save_last_frame(str(allowed / "last.ply")) == allowed / "last.ply"
    with pytest.raises(PhoxiError) as info:
        device.save_frame(frame, str(tmp_path / "x.ply"))
    assert str(tmp_path / "cwd") in str(info.value) and str(allowed) in str(info.value)
    assert not (tmp_path / "x.ply").exists()
    defaults = default_allowed_save_dirs({"ROS_HOME": "/rh"}, cwd="/work")
    assert defaults == [Path("/work"), Path("/rh"), Path("/tmp")]


def test_raw_formats_are_not_supported_by_the_simulator(tmp_path):
    device, frame = _policy_device(tmp_path)
    for requested in ("frame.praw", "frame.PRAWF"):
        with pytest.raises(PhoxiError, match="not supported by the simulator"):
            device.save_frame(frame, requested)
        with pytest.raises(PhoxiError, match="not supported by the simulator"):
            device.save_last_frame(requested)
    assert _files(tmp_path / "cwd") == []


def test_writers_check_everything_before_they_run(tmp_path):
    device, frame = _policy_device(tmp_path)
    with pytest.raises(PhoxiError):
        device.last_frame_writer("../x.ptx")
    write = device.last_frame_writer("late.ptx")
    assert not (tmp_path / "cwd" / "late.ptx").exists()  # nothing written until the writer runs (outside the lock)
    device.trigger(CAMERA)  # the device moves on; the writer keeps the frame it was given
    lines = write().read_text().splitlines()
    assert lines[:2] == [str(frame.width), str(frame.height)]


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


# ------------------------------------------------------------------ capture with poses, node logic in the core
class _Poses:
    """ScenePoses double that counts what the device asks."""

    def __init__(self, camera=CAMERA):
        self.camera = camera
        self.camera_calls = 0
        self.link_calls = []

    def camera_pose(self):
        self.camera_calls += 1
        return self.camera

    def link_poses(self, link_names):
        self.link_calls.append(list(link_names))
        return {}


def test_capture_asks_for_poses_only_for_a_new_frame(device):
    poses = _Poses()
    frame = device.capture(-1, poses)
    assert frame.index == 0 and poses.camera_calls == 1
    assert poses.link_calls == []  # no robot: no link poses to ask for
    assert device.capture(0, poses) is frame and poses.camera_calls == 1
    with pytest.raises(PhoxiError, match="Frame 5 is not available"):
        device.capture(5, poses)


def test_save_captured_frame_refuses_a_bad_path_before_rendering(device, tmp_path):
    poses = _Poses()
    with pytest.raises(PhoxiError, match="outside the allowed folder"):
        device.save_captured_frame(-1, str(tmp_path / "elsewhere.ply"), poses)
    assert poses.camera_calls == 0 and device.next_index == 0
    frame, path = device.save_captured_frame(-1, "sub/frame.ply", poses, organized=False)
    assert path == device.output_dir / "sub" / "frame.ply" and path.is_file()
    assert len(read_ply(path)["x"]) == int(frame.valid.sum())


def test_reconfigure_applies_settings_and_puts_back_a_refused_space(device):
    config = dict(phoxi_config.defaults)
    config.update(coordinate_space=ROBOT_SPACE, resolution=RESOLUTION_LOW, confidence=1.5)
    refusal = device.reconfigure(config)
    assert "RobotSpace has no transformation yet" in refusal
    assert config["coordinate_space"] == device.coordinate_space == 1
    assert device.settings.resolution == RESOLUTION_LOW and device.settings.confidence == 1.5
    config["coordinate_space"] = CUSTOM_SPACE
    assert device.reconfigure(config) == "" and device.coordinate_space == CUSTOM_SPACE


def test_reconfigure_puts_back_numbers_that_are_not_finite(device):
    previous = dict(phoxi_config.defaults, confidence=2.0)
    config = dict(previous, confidence=float("nan"), free_run_rate_hz=float("inf"), resolution=RESOLUTION_LOW)
    refusal = device.reconfigure(config, previous=previous)
    assert "confidence nan refused: not a finite number (kept 2.0)" in refusal
    assert "free_run_rate_hz inf refused" in refusal
    assert config["confidence"] == 2.0 and config["free_run_rate_hz"] == phoxi_config.defaults["free_run_rate_hz"]
    assert device.settings.confidence == 2.0 and device.settings.resolution == RESOLUTION_LOW
    frame = device.trigger(CAMERA)
    assert frame.valid.any()


def test_capturing_modes_and_free_run_need_a_connection(device):
    assert device.supported_capturing_modes() == [(160, 120), (80, 60)]
    assert device.free_running(0) and not device.free_running(1)
    device.disconnect()
    assert not device.free_running(0)
    with pytest.raises(PhoxiError, match="not connected"):
        device.supported_capturing_modes()
    with pytest.raises(PhoxiError, match="not connected"):
        device.require_connected()


def test_device_refusals_are_input_errors():
    assert issubclass(PhoxiError, InputError)
    with pytest.raises(InputError, match="transformation must be finite"):
        transform_from_quaternion([0, 0, np.nan], [0, 0, 0, 1])
    np.testing.assert_allclose(transform_from_quaternion([1, 2, 3], [0, 0, 0, 2]), pose_matrix([1, 2, 3], [0, 0, 0]))


def test_overridden_pose_replaces_only_what_is_given():
    pose = pose_matrix([1.0, 2.0, 3.0], [0.1, -0.2, 0.3])
    np.testing.assert_allclose(overridden_pose(pose), pose)
    moved = overridden_pose(pose, xyz_m=np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(moved[:3, :3], pose[:3, :3], atol=1e-12)
    np.testing.assert_allclose(moved[:3, 3], [0.0, 0.5, 1.0])
    turned = overridden_pose(pose, rpy_rad=np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(turned, pose_matrix([1.0, 2.0, 3.0], [0.0, 0.0, 1.0]), atol=1e-12)


def test_default_output_dir_follows_ros_home():
    assert default_output_dir({"ROS_HOME": "/tmp/rh"}) == Path("/tmp/rh/phoxi_frames")
    assert default_output_dir({}) == Path("~/.ros/phoxi_frames").expanduser()
