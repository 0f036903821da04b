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
    MAX_LINEAR_ENTRY,
    MAX_TRANSLATION_M,
    NOT_CONNECTED,
    ROBOT_SPACE,
    TRIGGER_FREERUN,
    TRIGGER_SOFTWARE,
    PhoxiDevice,
    PhoxiError,
    check_reconfigure_changes,
    check_transformation,
    default_allowed_save_dirs,
    default_output_dir,
    frame_output,
    load_camera_config,
    overridden_pose,
    transform_from_quaternion,
)
from agiprobot_measurement.sensors.phoxi.models import (
    FRAME_OUTPUTS,
    RESOLUTION_HIGH,
    RESOLUTION_LOW,
    SIMULATED_SCANNER_ID,
    SimulatedScanner,
    load_scanner_model,
)
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
    dev.connect(SIMULATED_SCANNER_ID)
    return dev


CAMERA = np.eye(4)


# ------------------------------------------------------------------------------ connection, frames
def test_connect_by_hardware_id_and_refuse_unknown_scanners(device):
    device.disconnect()
    assert device.status() == ("ERROR", "Not connected") and device.diagnostic_values() == []
    for name in ("nope", ""):  # "" is no scanner, as the driver's cameraList lookup
        with pytest.raises(PhoxiError, match=f"^Scanner not found: '{name}'"):
            device.connect(name)
        assert not device.connected
    device.connect(device.hardware_identification)
    assert device.connected and device.acquiring and device.status() == ("OK", "Ready")
    assert device.diagnostic_values() == [
        ("HardwareIdentification", SIMULATED_SCANNER_ID),
        ("Trigger mode", "Software"),
    ]


def test_a_new_device_starts_disconnected(tmp_path):
    model = load_scanner_model("M")
    device = PhoxiDevice(model, _wall(), tmp_path)
    assert not device.connected and not device.acquiring
    for call in (device.start_acquisition, device.supported_capturing_modes, lambda: device.trigger(CAMERA)):
        with pytest.raises(PhoxiError, match=f"^{NOT_CONNECTED}$"):
            call()


def test_the_device_list_is_configuration_and_a_real_id_can_be_simulated(tmp_path):
    small = replace(load_scanner_model("S"), resolutions={RESOLUTION_HIGH: (40, 30), RESOLUTION_LOW: (20, 15)})
    medium = replace(load_scanner_model("M"), resolutions={RESOLUTION_HIGH: (40, 30), RESOLUTION_LOW: (20, 15)})
    scanners = [SimulatedScanner("2019-04-011-LC3", medium), SimulatedScanner("1711004", small, variant="S-old")]
    device = PhoxiDevice(medium, _wall(), tmp_path, scanners=scanners)
    assert [s.hw_identification for s in device.device_list()] == ["2019-04-011-LC3", "1711004"]
    assert device.device_list()[0].variant == "M" and device.device_list()[1].variant == "S-old"
    with pytest.raises(PhoxiError, match="lists 2019-04-011-LC3, 1711004"):
        device.connect(SIMULATED_SCANNER_ID)
    device.connect("1711004")
    assert device.model is small and device.hardware_identification == "1711004"
    first = device.trigger(CAMERA)
    device.connect("2019-04-011-LC3")  # another scanner: the first one's frames are gone
    assert device.model is medium and device.frames == {}
    assert device.trigger(CAMERA).index == first.index + 1


def test_triggering_switches_to_the_software_trigger_and_starts_acquisition(device):
    device.stop_acquisition()
    assert device.status() == ("WARN", "Acquisition not started")
    assert device.trigger(CAMERA).index == 0  # as PhoXiInterface::triggerImage: software trigger, acquisition on
    assert device.acquiring and device.trigger_mode == TRIGGER_SOFTWARE
    device.set_trigger_mode(TRIGGER_FREERUN, True)
    assert device.free_running()
    assert device.get_frame(-1, CAMERA).index == 1 and device.trigger_mode == TRIGGER_SOFTWARE
    device.set_trigger_mode(TRIGGER_SOFTWARE, False)
    assert not device.acquiring
    with pytest.raises(PhoxiError, match="Invalid trigger mode 2"):
        device.set_trigger_mode(2, True)
    device.disconnect()
    with pytest.raises(PhoxiError, match=NOT_CONNECTED):
        device.trigger(CAMERA)
    with pytest.raises(PhoxiError, match=NOT_CONNECTED):
        device.start_acquisition()


def test_connecting_again_sets_the_software_trigger_and_starts_acquisition(device):
    device.set_trigger_mode(TRIGGER_FREERUN, False)
    frame = device.trigger(CAMERA)
    device.set_trigger_mode(TRIGGER_FREERUN, False)
    device.connect(device.hardware_identification)
    assert (device.trigger_mode, device.acquiring) == (TRIGGER_SOFTWARE, True)
    assert device.frame(frame.index) is frame, "the same connection keeps its frames"


def test_free_run_frames_keep_the_trigger_mode(device):
    with pytest.raises(PhoxiError, match="not in free run"):
        device.free_run_frame(CAMERA)
    device.set_trigger_mode(TRIGGER_FREERUN, True)
    frames = [device.free_run_frame(CAMERA).index for _ in range(2)]
    assert frames == [0, 1] and device.trigger_mode == TRIGGER_FREERUN
    assert device.frame(1).index == 1


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
def test_coordinate_spaces_0_to_5_are_accepted_as_by_the_driver(device):
    for space in (1, 2, 3, 4, 5):
        device.set_coordinate_space(space)
        assert device.coordinate_space == space
        np.testing.assert_array_equal(device.output_transform(), np.eye(4))  # identity until one is set
    device.set_coordinate_space(0)  # NoValue: accepted, the space stays
    assert device.coordinate_space == 5
    with pytest.raises(PhoxiError, match="Unknown coordinate space 9"):
        device.set_coordinate_space(9)
    with pytest.raises(PhoxiError, match=r"^Coordinate space is not supported: .*4 RobotSpace and 5 CustomSpace only"):
        device.set_transformation(np.eye(4), 1, True, False)
    device.disconnect()
    with pytest.raises(PhoxiError, match=NOT_CONNECTED):
        device.set_coordinate_space(1)


def test_custom_space_frames(device):
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


@pytest.mark.parametrize("space", [ROBOT_SPACE, CUSTOM_SPACE])
def test_set_transformation_switches_the_space_even_without_set_space(device, space):
    shift = transform_from_quaternion([0.0, 0.5, 0.0], [0.0, 0.0, 0.0, 1.0])
    device.set_transformation(shift, space, set_space=False, save_settings=False)  # PhoXiInterface.cpp:287/294
    assert device.coordinate_space == space
    np.testing.assert_array_equal(device.output_transform(), shift)
    device.set_coordinate_space(1)
    device.set_coordinate_space(space)  # the transformation stays with its space
    np.testing.assert_array_equal(device.output_transform(), shift)


def test_transformations_are_built_as_the_drivers_eigen_conversion(device):
    # geometry_msgs/Transform() has a zero quaternion: Eigen's formula gives the identity, and the driver accepts it
    np.testing.assert_array_equal(transform_from_quaternion([0, 0, 0], [0, 0, 0, 0]), np.eye(4))
    # a unit quaternion is its rotation (90 deg about z)
    half = np.sqrt(0.5)
    np.testing.assert_allclose(transform_from_quaternion([0, 0, 0], [0, 0, half, half])[:3, 0], [0, 1, 0], atol=1e-12)
    # a non-unit one is not normalised: the driver hands Eigen's matrix on as it is
    scaled = transform_from_quaternion([0, 0, 0], [0, 0, 2, 2])
    np.testing.assert_allclose(scaled[:3, :3], [[-7, -8, 0], [8, -7, 0], [0, 0, 1]], atol=1e-12)
    device.set_transformation(scaled, CUSTOM_SPACE, True, False)
    frame = device.trigger(CAMERA)
    points, _ = frame_output(frame)
    camera_points = frame.points_m()
    np.testing.assert_allclose(points[frame.valid], camera_points[frame.valid] @ scaled[:3, :3].T, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    "translation, quaternion, words",
    [
        ([1e308, 0, 0], [0, 0, 0, 1], ["translation", "beyond the 1000 m"]),
        ([0, 0, 1001], [0, 0, 0, 1], ["translation", "1e+03 m long"]),
        ([0, np.inf, 0], [0, 0, 0, 1], ["must be finite", "inf"]),
        ([0, 0, 0], [np.nan, 0, 0, 1], ["must be finite", "nan"]),
        ([0, 0, 0], [1e308, 1e308, 1e308, 1e308], ["finite 4x4"]),
        ([0, 0, 0], [100, 0, 0, 0], ["entry of 2e+04", "beyond 1000"]),
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


def test_check_transformation_keeps_frames_finite():
    np.testing.assert_array_equal(check_transformation(np.eye(4)), np.eye(4))
    at_limit = np.eye(4)
    at_limit[0, 3] = MAX_TRANSLATION_M
    check_transformation(at_limit)
    sheared, scaled, bottom, huge = np.eye(4), np.diag([2.0, 2.0, 2.0, 1.0]), np.eye(4), np.eye(4)
    sheared[0, 1] = 0.1
    bottom[3, 0] = 1.0
    huge[1, 1] = 2 * MAX_LINEAR_ENTRY
    check_transformation(sheared)  # the driver checks nothing: what stays finite is accepted
    check_transformation(scaled)
    for matrix, word in ((bottom, "last row"), (huge, "rotation part has an entry")):
        with pytest.raises(PhoxiError, match=word):
            check_transformation(matrix)
    with pytest.raises(PhoxiError, match="finite 4x4"):
        check_transformation(np.eye(3))


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
    with pytest.raises(PhoxiError, match=r"'\.\.' is not allowed.*names resolve under"):
        device.save_last_frame("../../escape.ply")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_save_last_frame_by_extension(device):
    with pytest.raises(PhoxiError, match="Unsuccessful save"):
        device.save_last_frame("a.ply")
    frame = device.trigger(CAMERA)
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
    dev = PhoxiDevice(model, _wall(), root, allowed_dirs=allowed, environ={"HOME": str(tmp_path / "home")})
    dev.connect(dev.hardware_identification)
    frame = dev.trigger(CAMERA)
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
        ("~/x.ply", ["home/x.ply is outside the allowed folder", "cwd"]),  # ~ is $HOME, as the driver
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


def test_a_leading_tilde_is_home_as_the_driver_and_home_must_be_allowed(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    device, frame = _policy_device(tmp_path, allowed=[home])
    assert device.save_frame(frame, "~/x.ply") == home / "x.ply" and (home / "x.ply").is_file()
    assert device.save_frame(frame, "a~b.ply") == tmp_path / "cwd" / "a~b.ply"  # only a leading ~ is HOME
    device.environ = {}
    with pytest.raises(PhoxiError, match="environment variable 'HOME' not found"):
        device.save_frame(frame, "~/y.ply")


def test_save_last_frame_saves_the_last_triggered_frame_of_this_connection(tmp_path):
    device, _ = _policy_device(tmp_path)
    second = device.trigger(CAMERA)
    assert f"frame {second.index}" in " ".join(read_ply(device.save_last_frame("last.ply"))["comments"])
    device.disconnect()
    device.connect(device.hardware_identification)
    with pytest.raises(PhoxiError, match="Unsuccessful save"):  # the driver forgets its last frame id
        device.save_last_frame("again.ply")


def test_raw_formats_are_not_supported_by_the_simulator(tmp_path):
    device, frame = _policy_device(tmp_path)
    for requested in ("frame.praw", "frame.PRAWF"):
        with pytest.raises(PhoxiError, match="not supported by the simulator"):
            device.save_frame(frame, requested)
        # worded as the driver's failed save, so a script's handling of "Unsuccessful save." applies
        with pytest.raises(PhoxiError, match=r"^Unsuccessful save: .*not supported by the simulator"):
            device.save_last_frame(requested)
    assert _files(tmp_path / "cwd") == []


def test_a_file_camera_delivers_only_the_recorded_parts(tmp_path):
    """PhoXi Control's file camera (the driver's tests use its installed example) replays a recording: a part the
    recording lacks (here the confidence map) is missing from every frame and from its saved PLY."""
    model = replace(load_scanner_model("M"), resolutions={RESOLUTION_HIGH: (40, 30), RESOLUTION_LOW: (20, 15)})
    recorded = ("point_cloud", "depth_map", "normal_map", "texture")
    scanners = [
        SimulatedScanner(SIMULATED_SCANNER_ID, model),
        SimulatedScanner("InstalledExamples-basic-example", model, frame_outputs=recorded),
    ]
    device = PhoxiDevice(model, _wall(), tmp_path, scanners=scanners)
    device.connect(SIMULATED_SCANNER_ID)
    assert device.trigger(CAMERA).outputs == FRAME_OUTPUTS
    assert "confidence" in read_ply(device.save_last_frame("scanner.ply"))
    device.connect("InstalledExamples-basic-example")
    assert device.trigger(CAMERA).outputs == recorded
    ply = read_ply(device.save_last_frame("file_camera.ply"))
    assert "confidence" not in ply and "intensity" in ply
    with pytest.raises(InputError, match="unknown frame output"):
        SimulatedScanner("x", model, frame_outputs=("colour",))


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
    # the driver divides the cloud's normals by 1000 (PhoXiInterface.cpp); the normal map keeps unit normals
    assert phoxi_messages.CLOUD_NORMAL_SCALE == 1e-3
    np.testing.assert_allclose(nrm, normals * 1e-3, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(nrm[frame.valid], axis=1), 1e-3, rtol=1e-4)
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
#: the driver's cfg/phoxi_camera.cfg (release 1.8.0): name -> (level, default, min, max, enum names), in its order
REFERENCE_CFG = {
    "resolution": (1 << 1, 1, 0, 1, ["Low", "High"]),
    "scan_multiplier": (1 << 2, 1, 1, 50, None),
    "shutter_multiplier": (1 << 3, 1, 1, 20, None),
    "trigger_mode": (1 << 4, 1, 0, 1, ["Freerun", "Software"]),
    "start_acquisition": (1 << 4, True, False, True, None),
    "timeout": (1 << 5, -3, -3, 0, ["ZeroTimeout", "Infinity", "LastStored", "Default"]),
    "confidence": (1 << 6, 3.0, 0.0, 10.0, None),
    "send_point_cloud": (1 << 7, True, False, True, None),
    "send_normal_map": (1 << 8, True, False, True, None),
    "send_confidence_map": (1 << 9, True, False, True, None),
    "send_texture": (1 << 10, True, False, True, None),
    "send_depth_map": (1 << 11, True, False, True, None),
    "coordinate_space": (
        1 << 12,
        1,
        1,
        5,
        ["CameraSpace", "MountingSpace", "MarkerSpace", "RobotSpace", "CustomSpace"],
    ),
    "organized_cloud": (1 << 13, True, False, True, None),
    "ambient_light_suppression": (1 << 14, False, False, True, None),
    "single_pattern_exposure": (
        1 << 15,
        2,
        0,
        11,
        "10_240 14_336 20_480 24_576 30_720 34_816 40_960 49_152 75_776 79_872 90_112 100_352".split(),
    ),
    "camera_only_mode": (1 << 16, False, False, True, None),
}


def test_reconfigure_description_is_the_drivers_cfg():
    import ast

    described = phoxi_config.config_description["parameters"]
    assert [p["name"] for p in described] == list(REFERENCE_CFG), "every parameter of the cfg, in order, no extras"
    for entry in described:
        level, default, low, high, enum = REFERENCE_CFG[entry["name"]]
        got = (entry["level"], entry["default"], entry["min"], entry["max"])
        assert got == (level, default, low, high), entry["name"]
        assert type(entry["default"]) is type(default), entry["name"]
        names = [c["name"] for c in ast.literal_eval(entry["edit_method"])["enum"]] if entry["edit_method"] else None
        assert names == enum, entry["name"]
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


def test_reconfigure_applies_what_the_level_names(device):
    config = dict(phoxi_config.defaults)
    config.update(coordinate_space=ROBOT_SPACE, resolution=RESOLUTION_LOW, confidence=1.5)
    level = phoxi_config.level["resolution"] | phoxi_config.level["confidence"]
    assert device.reconfigure(config, level) == ""
    assert device.settings.resolution == RESOLUTION_LOW and device.settings.confidence == 1.5
    assert config["coordinate_space"] == device.coordinate_space == 1, "a level not named changes nothing"
    config["coordinate_space"] = CUSTOM_SPACE
    assert device.reconfigure(config, phoxi_config.level["coordinate_space"]) == ""
    assert device.coordinate_space == CUSTOM_SPACE
    config.update(trigger_mode=TRIGGER_FREERUN, start_acquisition=False)
    device.reconfigure(config, phoxi_config.level["start_acquisition"])
    assert (device.trigger_mode, device.acquiring) == (TRIGGER_FREERUN, False)
    everything = dict(phoxi_config.defaults)
    device.reconfigure(everything, -1)  # what the server's first call names
    assert (device.trigger_mode, device.acquiring, device.coordinate_space) == (TRIGGER_SOFTWARE, True, 1)


def test_reconfigure_without_a_scanner_puts_everything_back(device):
    device.disconnect()
    previous = dict(phoxi_config.defaults, confidence=2.0)
    config = dict(previous, confidence=4.0, resolution=RESOLUTION_LOW)
    assert device.reconfigure(config, -1, previous) == "Node is not connected to scanner"
    assert config == previous and device.settings.confidence != 4.0


def test_reconfigure_puts_back_numbers_that_are_not_finite(device):
    previous = dict(phoxi_config.defaults, confidence=2.0)
    config = dict(previous, confidence=float("nan"), resolution=RESOLUTION_LOW)
    refusal = device.reconfigure(config, -1, previous=previous)
    assert "confidence nan refused: not a finite number (kept 2.0)" in refusal
    assert config["confidence"] == 2.0
    assert device.settings.confidence == 2.0 and device.settings.resolution == RESOLUTION_LOW
    frame = device.trigger(CAMERA)
    assert frame.valid.any()


def test_reconfigure_puts_back_values_of_the_wrong_type(device):
    """A double for the int resolution was stored and broke every later frame ("unknown resolution 0.5")."""
    previous = dict(phoxi_config.defaults, resolution=RESOLUTION_LOW)
    config = dict(previous, resolution=0.5, organized_cloud="no")
    refusal = device.reconfigure(config, -1, previous=previous)
    assert (
        "parameter resolution is int: got float '0.5', expected an integer (kept 0)" in refusal
        and "organized_cloud" in refusal
    )
    assert config["resolution"] == RESOLUTION_LOW and config["organized_cloud"] is True
    assert device.settings.resolution == RESOLUTION_LOW
    assert device.trigger(CAMERA).valid.any(), "the camera keeps working"


@pytest.mark.parametrize("name", sorted(phoxi_config.type))
def test_set_parameters_refuses_a_wrong_type_for_every_parameter(name):
    kind = phoxi_config.type[name]
    wrong = ["no", "1", None] + {"int": [0.5, float("nan"), True], "bool": [2, 0.0], "double": [False]}[kind]
    for value in wrong:
        with pytest.raises(PhoxiError, match=f"set_parameters refused, nothing changed: parameter {name} is {kind}"):
            check_reconfigure_changes({"groups": {}, name: value})
    default = phoxi_config.defaults[name]
    assert check_reconfigure_changes({name: default}) == {name: default}


def test_set_parameters_converts_values_of_a_compatible_type():
    changes = {"resolution": 0.0, "confidence": 2, "send_texture": 0, "organized_cloud": 1, "unknown": "x"}
    checked = check_reconfigure_changes(changes)
    assert checked == {
        "resolution": 0,
        "confidence": 2.0,
        "send_texture": False,
        "organized_cloud": True,
        "unknown": "x",
    }
    assert type(checked["resolution"]) is int and type(checked["confidence"]) is float
    with pytest.raises(PhoxiError, match="got str") as refused:
        check_reconfigure_changes({"resolution": "x" * 100_000})
    assert len(str(refused.value)) < 1000, "the input is quoted as an excerpt"


def test_capturing_modes_and_free_run_need_a_connection(device):
    assert device.supported_capturing_modes() == [(160, 120), (80, 60)]
    assert not device.free_running()
    device.set_trigger_mode(TRIGGER_FREERUN, True)
    assert device.free_running()
    device.disconnect()
    assert not device.free_running()
    with pytest.raises(PhoxiError, match=NOT_CONNECTED):
        device.supported_capturing_modes()
    with pytest.raises(PhoxiError, match=NOT_CONNECTED):
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


# ------------------------------------------------------------------------------------- device list
def test_the_bundled_device_list_and_its_checks():
    from agiprobot_measurement.sensors.phoxi.models import load_simulated_scanners
    from agiprobot_measurement.station import ConfigError

    bundled = load_simulated_scanners("L")
    assert [(s.hw_identification, s.model.name, s.variant, s.is_alpha) for s in bundled] == [
        (SIMULATED_SCANNER_ID, "L", "L", False)
    ]
    real = load_simulated_scanners("L", entries=[{"hw_identification": "2019-04-011-LC3", "model": "M"}])
    assert real[0].hw_identification == "2019-04-011-LC3" and real[0].model.name == "M"
    assert real[0].frame_outputs == FRAME_OUTPUTS and bundled[0].frame_outputs == FRAME_OUTPUTS
    assert load_simulated_scanners("S", entries=[])[0].hw_identification == SIMULATED_SCANNER_ID
    for entries, words in (
        ([{"hw_identification": "a"}, {"hw_identification": "a"}], "listed twice"),
        ([{"hw_identification": ""}], "empty"),
        ([{"hw_identification": "a", "model": "XXL"}], "unknown PhoXi model 'XXL'"),
        ([{"hw_identification": "a", "colour": "red"}], "unknown key(s) ['colour']"),
        ([{"hw_identification": "a", "is_alpha": "yes"}], "is_alpha must be true or false"),
        ([{"hw_identification": "a", "frame_outputs": ["colour"]}], "frame_outputs must be a list of point_cloud"),
        ([{"hw_identification": "a", "frame_outputs": "texture"}], "frame_outputs must be a list"),
        ({"hw_identification": "a"}, "must be a list"),
    ):
        with pytest.raises(ConfigError) as info:
            load_simulated_scanners("L", entries=entries)
        assert words in str(info.value) and "~devices" in str(info.value)
