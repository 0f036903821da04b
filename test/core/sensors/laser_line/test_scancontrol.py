"""The simulated scanCONTROL sensor: profiles in the sensor frame as the driver publishes them (geometry, +Inf
no-returns, the timestamp's lost points), its resolutions and features, and the stitching math."""

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.sensors.errors import SensorInputError
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.scancontrol import (
    ERROR_SETGETFUNCTIONS_NOT_SUPPORTED_RESOLUTION,
    ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS,
    FEATURE_FUNCTION_IDLETIME,
    FEATURE_FUNCTION_LASERPOWER,
    FEATURE_FUNCTION_PROCESSING_PROFILEDATA,
    FEATURE_FUNCTION_SHUTTERTIME,
    GENERAL_FUNCTION_OK,
    INVERT_X_BIT,
    INVERT_Z_BIT,
    ScanControlDevice,
    StitchWindows,
    sensor_frame_profile,
    stitch_profile,
)
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator
from agiprobot_measurement.station import load_scanner_config

#: the plate's lower face, facing the emitter (mm along the boresight)
PLATE_Z_MM = 180.0
#: the sensor frame in the emitter frame: turned 90 degrees about z (config/laser_scanner.yaml sensor_frame)
SENSOR_IN_EMITTER = pose_matrix(np.zeros(3), np.array([0.0, 0.0, np.pi / 2]))


def _model() -> SensorModel:
    return SensorModel(load_scanner_config().sensor_parameters)


def _plate(half_width_y_mm: float) -> trimesh.Trimesh:
    """A plate whose lower face lies at z = PLATE_Z_MM, ``half_width_y_mm`` to each side of the fan's centre."""
    plate = trimesh.creation.box(extents=[200.0, 2 * half_width_y_mm, 10.0])
    plate.apply_translation([0.0, 0.0, PLATE_Z_MM + 5.0])
    return plate


def _device(resolution=640, data_width=4) -> ScanControlDevice:
    return ScanControlDevice(resolution, 100.0, data_width=data_width, measuring_range_m=(0.127, 0.227))


def _scan(plate, emitter_pose_mm, device, sensor_in_emitter=SENSOR_IN_EMITTER):
    simulator = LaserLineScannerSimulator(_model(), points_per_profile=device.resolution, noise_scale=0.0)
    simulator.set_target(plate)
    profile = simulator.profile(emitter_pose_mm)
    sensor_pose_mm = emitter_pose_mm @ sensor_in_emitter
    return simulator, profile, sensor_frame_profile(profile, sensor_pose_mm, device)


def test_a_profile_lies_along_x_with_y_zero_and_z_the_distance():
    device = _device()
    pose = pose_matrix(np.array([30.0, -20.0, 5.0]), np.zeros(3))
    simulator, _, points = _scan(_plate(300.0), pose, device)
    assert points.shape == (640, 4) and points.dtype == np.float32
    finite = np.isfinite(points[:, 2])
    # the whole fan hits the plate but the timestamp's last ceil(16 / 4) = 4 points
    assert finite.sum() == 640 - 4 and not finite[-4:].any()
    x, y, z = (points[finite, i].astype(float) for i in range(3))
    assert np.all(y == 0.0)
    np.testing.assert_allclose(z, (PLATE_Z_MM - 5.0) / 1000.0, atol=1e-6)
    # point i comes from fan ray i: x = z tan(angle of ray i), increasing along the line
    np.testing.assert_allclose(x, z * np.tan(simulator.fan_angles_rad[finite]), atol=1e-6)
    assert np.all(np.diff(x) > 0)
    np.testing.assert_array_equal(points[:, 3], 1.0)


def test_rays_without_a_return_are_plus_infinity():
    device = _device()
    _, profile, points = _scan(_plate(20.0), np.eye(4), device)
    finite = np.isfinite(points[:, 2])
    assert 0 < finite.sum() < 640 - 4
    assert np.all(np.isposinf(points[~finite, 2]))
    # the returns are the middle of the fan, where the narrow plate is
    assert np.all(np.abs(points[finite, 0]) <= 0.0201)
    assert finite.sum() == len(profile)
    # no target, or the laser off: no return at all
    assert np.all(np.isposinf(sensor_frame_profile(None, np.eye(4), device)[:, 2]))
    assert device.set_feature(FEATURE_FUNCTION_LASERPOWER, 0) == GENERAL_FUNCTION_OK
    assert np.all(np.isposinf(sensor_frame_profile(profile, np.eye(4) @ SENSOR_IN_EMITTER, device)[:, 2]))


def test_the_timestamp_overwrites_ceil_16_over_the_data_width_points():
    for width, lost in ((4, 4), (2, 8), (3, 6), (16, 1), (32, 1)):
        device = _device(data_width=width)
        assert device.lost_points == lost
        points = sensor_frame_profile(None, np.eye(4), device)
        assert np.all(np.isposinf(points[-lost:, 2]))


def test_the_inversion_bits_mirror_x_and_z():
    device = _device()
    pose = np.eye(4)
    _, profile, normal = _scan(_plate(300.0), pose, device)
    assert device.invert_x and device.invert_z  # the factory setting: the geometry above
    assert device.set_inversion(INVERT_X_BIT, False) == GENERAL_FUNCTION_OK
    mirrored_x = sensor_frame_profile(profile, pose @ SENSOR_IN_EMITTER, device)
    finite = np.isfinite(normal[:, 2])
    np.testing.assert_allclose(mirrored_x[finite, 0], -normal[finite, 0], atol=1e-7)
    assert device.set_inversion(INVERT_Z_BIT, False) == GENERAL_FUNCTION_OK
    mirrored_z = sensor_frame_profile(profile, pose @ SENSOR_IN_EMITTER, device)
    np.testing.assert_allclose(mirrored_z[finite, 2], 0.127 + 0.227 - normal[finite, 2], atol=1e-6)
    code, value = device.get_feature(FEATURE_FUNCTION_PROCESSING_PROFILEDATA)
    assert code == GENERAL_FUNCTION_OK and value & (INVERT_X_BIT | INVERT_Z_BIT) == 0


def test_resolutions_are_the_highest_and_its_halvings():
    device = _device(640)
    assert device.available_resolutions() == (3, [640, 320, 160])
    assert ScanControlDevice(1280, 100.0).available_resolutions()[1] == [1280, 640, 320, 160]
    assert device.select_resolution(-1) == 640
    assert device.select_resolution(320) == 320
    assert device.select_resolution(500) == 640  # not available: the driver falls back to the first
    assert device.set_resolution(500) == ERROR_SETGETFUNCTIONS_NOT_SUPPORTED_RESOLUTION
    assert device.get_resolution() == (GENERAL_FUNCTION_OK, 640)
    assert device.set_resolution(160) == GENERAL_FUNCTION_OK
    assert device.get_resolution() == (GENERAL_FUNCTION_OK, 160)
    assert sensor_frame_profile(None, np.eye(4), device).shape == (160, 4)
    # the simulator follows: a profile of the new resolution, point i from ray i
    _, _, points = _scan(_plate(300.0), np.eye(4), device)
    assert points.shape == (160, 4) and np.isfinite(points[:-4, 2]).all()
    # a profile of more rays than the resolution has points is refused
    _, wide, _ = _scan(_plate(300.0), np.eye(4), _device(640))
    with pytest.raises(SensorInputError):
        sensor_frame_profile(wide, np.eye(4), device)


def test_shutter_and_idle_time_set_the_profile_period():
    device = _device()
    assert device.profile_period_s == pytest.approx(0.01)
    assert device.set_feature(FEATURE_FUNCTION_IDLETIME, 400) == GENERAL_FUNCTION_OK
    assert device.profile_period_s == pytest.approx((100 + 400) * 1e-5)
    assert device.get_feature(FEATURE_FUNCTION_SHUTTERTIME) == (GENERAL_FUNCTION_OK, 100)
    assert device.set_feature(FEATURE_FUNCTION_SHUTTERTIME, 0) == ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS
    assert device.get_feature(0x12345678) == (ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS, 0)
    assert device.set_feature(0x12345678, 1) == ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS
    assert device.set_feature(FEATURE_FUNCTION_IDLETIME, 2**32) == ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS


def test_stitching_with_the_sensor_pose_gives_the_world_points_back():
    device = _device()
    pose = pose_matrix(np.array([12.0, -40.0, 3.0]), np.array([0.1, -0.2, 0.3]))
    plate = _plate(300.0)
    plate.apply_transform(pose)
    _, profile, points = _scan(plate, pose, device)
    sensor_to_world_m = pose @ SENSOR_IN_EMITTER
    sensor_to_world_m[:3, 3] /= 1000.0
    world_m = stitch_profile(points[:, :3], sensor_to_world_m)
    assert len(profile) == 640 and len(world_m) == 640 - 4  # the timestamp's +Inf points are dropped
    np.testing.assert_allclose(world_m * 1000.0, profile.points_mm[:-4], atol=1e-3)
    # a given transform: a pure translation moves every point by it
    shifted = np.eye(4)
    shifted[:3, 3] = [1.0, 2.0, 3.0]
    raw = np.array([[0.01, 0.0, 0.2], [0.0, 0.0, np.inf]])
    np.testing.assert_allclose(stitch_profile(raw, shifted), [[1.01, 2.0, 3.2]])
    with pytest.raises(SensorInputError):
        stitch_profile(raw, np.full((4, 4), np.nan))


def test_stitch_windows_hold_the_stamps_between_switch_on_and_off():
    windows = StitchWindows()
    assert not windows.active and not windows.contains(1.0)
    windows.switch_on(10.0)
    assert windows.active and windows.contains(10.0) and windows.contains(1e9) and not windows.contains(9.99)
    windows.switch_off(12.0)
    assert not windows.active and windows.contains(12.0) and not windows.contains(12.01)
    windows.switch_on(20.0)
    windows.switch_off(21.0)
    assert windows.contains(11.0) and windows.contains(20.5) and not windows.contains(15.0)
    windows.forget_before(13.0)
    assert list(windows) == [(20.0, 21.0)]
