"""The simulated scanCONTROL profile sensor: the device state a Micro-Epsilon scanCONTROL driver sees (resolution,
features, profile period, x/z inversion) and a profile expressed as that driver publishes it.

The driver (micro_epsilon_scancontrol_driver, ROS 1) publishes one profile per message in the sensor frame: **x
along the laser line, y = 0, z = distance** (m), ``resolution`` points, a point without return has z = +Inf, and
the last ``ceil(16 / data width)`` points are +Inf as well (the sensor's 16-byte timestamp overwrites them). The
profile period is the sum of the sensor's shutter (exposure) and idle times, both in 10 us units of the features
FEATURE_FUNCTION_SHUTTERTIME and FEATURE_FUNCTION_IDLETIME. Bit 6 of FEATURE_FUNCTION_PROCESSING_PROFILEDATA
inverts z, bit 7 inverts x; both are set at the factory, and the profile geometry above is the one with both set.
This model mirrors x (x -> -x) when bit 7 is cleared and z about the middle of the measuring range when bit 6 is
cleared; FEATURE_FUNCTION_LASERPOWER 0 switches the laser off (no returns).

Return codes are the scanCONTROL SDK's: ``GENERAL_FUNCTION_OK`` (1) for success, a negative code otherwise;
``get_available_resolutions`` returns the number of resolutions, as the SDK's GetResolutions does.

The stitching helpers (:func:`stitch_profile`, :class:`StitchWindows`) are what a stitcher does with such profiles:
transform each into the world frame with the sensor pose at its stamp, and keep those whose stamps fall into a
window in which stitching was on.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from agiprobot_measurement.sensors.errors import SensorInputError
from agiprobot_measurement.sensors.laser_line.simulator import Profile

__all__ = [
    "ERROR_SETGETFUNCTIONS_NOT_SUPPORTED_RESOLUTION",
    "ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS",
    "FEATURE_FUNCTION_IDLETIME",
    "FEATURE_FUNCTION_LASERPOWER",
    "FEATURE_FUNCTION_MEASURINGFIELD",
    "FEATURE_FUNCTION_PROCESSING_PROFILEDATA",
    "FEATURE_FUNCTION_SHUTTERTIME",
    "FEATURE_FUNCTION_TRIGGER",
    "FEATURE_TIME_UNIT_S",
    "GENERAL_FUNCTION_OK",
    "INVERT_X_BIT",
    "INVERT_Z_BIT",
    "POINT_FIELDS",
    "ScanControlDevice",
    "StitchWindows",
    "sensor_frame_profile",
    "stitch_profile",
]

#: the scanCONTROL SDK's return codes
GENERAL_FUNCTION_OK = 1
ERROR_SETGETFUNCTIONS_NOT_SUPPORTED_RESOLUTION = -153
ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS = -155

#: the scanCONTROL SDK's feature addresses that the simulated sensor knows
FEATURE_FUNCTION_IDLETIME = 0xF0F00800
FEATURE_FUNCTION_PROCESSING_PROFILEDATA = 0xF0F00804
FEATURE_FUNCTION_SHUTTERTIME = 0xF0F0081C
FEATURE_FUNCTION_LASERPOWER = 0xF0F00824
FEATURE_FUNCTION_TRIGGER = 0xF0F00830
FEATURE_FUNCTION_MEASURINGFIELD = 0xF0F00880

#: bits of FEATURE_FUNCTION_PROCESSING_PROFILEDATA (the driver's ~invert_z / ~invert_x set them)
INVERT_Z_BIT = 1 << 6
INVERT_X_BIT = 1 << 7
#: the unit of the shutter and idle time features (s)
FEATURE_TIME_UNIT_S = 1e-5
#: the sensor's timestamp at the end of each profile (bytes); it overwrites the last points
TIMESTAMP_BYTES = 16
#: the laser power feature's low bits: 0 = off, 1 = reduced, 2 = standard
LASER_POWER_MASK = 0x3
#: the fewest points a resolution of the simulated sensor has (the smallest scanCONTROL resolution)
MIN_RESOLUTION = 160
#: the sensor message's fields, in order (float32 each): what the driver's pcl::PointXYZI gives
POINT_FIELDS = ("x", "y", "z", "intensity")
#: the intensity of every point (the driver extracts only x and z and leaves intensity at 1.0)
INTENSITY = 1.0
#: the largest value of a uint32 feature
UINT32_MAX = 2**32 - 1


class ScanControlDevice:
    """The settings of one simulated scanCONTROL sensor, and the profile period they give.

    ``max_resolution``: the highest resolution (points per profile); the available ones are it and its halvings
    down to :data:`MIN_RESOLUTION`. ``profile_rate_hz``: the initial profile frequency (shutter ``shutter_time_s``
    plus idle time). ``data_width``: the partial profile's point data width (bytes), which sets how many points the
    timestamp overwrites. ``measuring_range_m``: (near, far) distance of the measuring range (m), the centre of the
    z mirror when z inversion is switched off.
    """

    def __init__(
        self,
        max_resolution: int,
        profile_rate_hz: float,
        shutter_time_s: float = 0.001,
        data_width: int = 4,
        measuring_range_m: tuple[float, float] = (0.0, 0.0),
    ):
        if int(max_resolution) < 2:
            raise SensorInputError(f"max_resolution must be >= 2, got {max_resolution}")
        if not (math.isfinite(profile_rate_hz) and profile_rate_hz > 0):
            raise SensorInputError(f"profile_rate_hz must be > 0, got {profile_rate_hz}")
        if int(data_width) < 1:
            raise SensorInputError(f"partial profile data width must be >= 1 byte, got {data_width}")
        resolutions = [int(max_resolution)]
        while resolutions[-1] % 2 == 0 and resolutions[-1] // 2 >= MIN_RESOLUTION:
            resolutions.append(resolutions[-1] // 2)
        self.resolutions = resolutions
        self.resolution = resolutions[0]
        self.data_width = int(data_width)
        self.measuring_range_m = (float(measuring_range_m[0]), float(measuring_range_m[1]))
        period_units = max(2, round(1.0 / (profile_rate_hz * FEATURE_TIME_UNIT_S)))
        shutter_units = min(max(1, round(shutter_time_s / FEATURE_TIME_UNIT_S)), period_units - 1)
        self.features = {
            FEATURE_FUNCTION_PROCESSING_PROFILEDATA: INVERT_Z_BIT | INVERT_X_BIT,
            FEATURE_FUNCTION_SHUTTERTIME: shutter_units,
            FEATURE_FUNCTION_IDLETIME: period_units - shutter_units,
            FEATURE_FUNCTION_LASERPOWER: 2,
            FEATURE_FUNCTION_TRIGGER: 0,
            FEATURE_FUNCTION_MEASURINGFIELD: 0,
        }

    # --- the driver's services -----------------------------------------------------------------------------

    def get_feature(self, setting: int) -> tuple[int, int]:
        """(return code, value) of feature ``setting``."""
        if setting not in self.features:
            return ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS, 0
        return GENERAL_FUNCTION_OK, self.features[setting]

    def set_feature(self, setting: int, value: int) -> int:
        """Set feature ``setting`` to ``value``; the return code. Shutter and idle time must leave a period > 0."""
        if setting not in self.features or not 0 <= int(value) <= UINT32_MAX:
            return ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS
        times = {s: self.features[s] for s in (FEATURE_FUNCTION_SHUTTERTIME, FEATURE_FUNCTION_IDLETIME)}
        if setting in times:
            times[setting] = int(value)
            if times[FEATURE_FUNCTION_SHUTTERTIME] < 1 or sum(times.values()) < 1:
                return ERROR_SETGETFUNCTIONS_WRONG_FEATURE_ADRESS
        self.features[setting] = int(value)
        return GENERAL_FUNCTION_OK

    def get_resolution(self) -> tuple[int, int]:
        return GENERAL_FUNCTION_OK, self.resolution

    def set_resolution(self, resolution: int) -> int:
        if int(resolution) not in self.resolutions:
            return ERROR_SETGETFUNCTIONS_NOT_SUPPORTED_RESOLUTION
        self.resolution = int(resolution)
        return GENERAL_FUNCTION_OK

    def available_resolutions(self) -> tuple[int, list[int]]:
        """(number of resolutions, the resolutions), as the SDK's GetResolutions answers."""
        return len(self.resolutions), list(self.resolutions)

    def select_resolution(self, requested: int) -> int:
        """The driver's start-up choice: ``requested`` if available, else (also for -1) the first (highest)."""
        self.resolution = int(requested) if int(requested) in self.resolutions else self.resolutions[0]
        return self.resolution

    def set_inversion(self, bit: int, on: bool) -> int:
        """Set or clear one inversion bit of the profile data processing feature (the ~invert_x/z services)."""
        code, value = self.get_feature(FEATURE_FUNCTION_PROCESSING_PROFILEDATA)
        if code < GENERAL_FUNCTION_OK:
            return code
        return self.set_feature(FEATURE_FUNCTION_PROCESSING_PROFILEDATA, (value & ~bit) | (bit if on else 0))

    # --- what the settings mean --------------------------------------------------------------------------------

    @property
    def profile_period_s(self) -> float:
        """Exposure plus idle time (s): the time between two profiles."""
        units = self.features[FEATURE_FUNCTION_SHUTTERTIME] + self.features[FEATURE_FUNCTION_IDLETIME]
        return units * FEATURE_TIME_UNIT_S

    @property
    def invert_x(self) -> bool:
        return bool(self.features[FEATURE_FUNCTION_PROCESSING_PROFILEDATA] & INVERT_X_BIT)

    @property
    def invert_z(self) -> bool:
        return bool(self.features[FEATURE_FUNCTION_PROCESSING_PROFILEDATA] & INVERT_Z_BIT)

    @property
    def laser_on(self) -> bool:
        return bool(self.features[FEATURE_FUNCTION_LASERPOWER] & LASER_POWER_MASK)

    @property
    def lost_points(self) -> int:
        """How many points at the end of each profile the sensor's timestamp overwrites."""
        return -(-TIMESTAMP_BYTES // self.data_width)


def sensor_frame_profile(profile: Profile | None, sensor_pose_mm: np.ndarray, device: ScanControlDevice) -> np.ndarray:
    """The (resolution, 4) float32 array x, y, z, intensity (m) of one profile as the driver publishes it: point i
    from fan ray i, in the sensor frame whose world pose is ``sensor_pose_mm`` (4x4, mm); y = 0; rays without a
    return, and the last :attr:`ScanControlDevice.lost_points`, have x = 0 and z = +Inf. ``profile`` None (no
    target, laser off) gives a profile without any return. The simulator's resolution must be the device's."""
    n = device.resolution
    out = np.zeros((n, len(POINT_FIELDS)), dtype=np.float32)
    out[:, 2] = np.inf
    out[:, 3] = INTENSITY
    if profile is not None and len(profile) and device.laser_on:
        if profile.ray_indices is None:
            raise SensorInputError("the profile does not say which ray measured each point")
        rays = np.asarray(profile.ray_indices, dtype=int)
        if np.any((rays < 0) | (rays >= n)):
            raise SensorInputError(f"ray indices outside the resolution {n}")
        pose = np.asarray(sensor_pose_mm, dtype=float)
        local_mm = (np.asarray(profile.points_mm, dtype=float) - pose[:3, 3]) @ pose[:3, :3]
        x_m, z_m = local_mm[:, 0] / 1000.0, local_mm[:, 2] / 1000.0
        if not device.invert_x:
            x_m = -x_m
        if not device.invert_z:
            z_m = sum(device.measuring_range_m) - z_m
        out[rays, 0] = x_m
        out[rays, 2] = z_m
    lost = min(device.lost_points, n)
    out[n - lost :, 0] = 0.0
    out[n - lost :, 2] = np.inf
    return out


def stitch_profile(points_sensor_m: np.ndarray, sensor_to_world: np.ndarray) -> np.ndarray:
    """(M, 3) world points (m) of a profile's (N, 3) sensor-frame points: the finite ones (no-returns dropped)
    transformed with the sensor's world pose ``sensor_to_world`` (4x4, m) at the profile's stamp."""
    points = np.asarray(points_sensor_m, dtype=float).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    transform = np.asarray(sensor_to_world, dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise SensorInputError("the sensor pose must be a finite 4x4 matrix")
    return points @ transform[:3, :3].T + transform[:3, 3]


class StitchWindows:
    """The time windows (s, any clock) in which stitching was on: a profile belongs to the stitched cloud when its
    stamp lies in one, ends included. Switching on opens a window, switching off closes it."""

    def __init__(self):
        self.windows: list[list[float | None]] = []

    @property
    def active(self) -> bool:
        return bool(self.windows) and self.windows[-1][1] is None

    def switch_on(self, t: float) -> None:
        if not self.active:
            self.windows.append([float(t), None])

    def switch_off(self, t: float) -> None:
        if self.active:
            self.windows[-1][1] = max(float(t), self.windows[-1][0])

    def contains(self, t: float) -> bool:
        return any(start <= t and (end is None or t <= end) for start, end in self.windows)

    def forget_before(self, t: float) -> None:
        """Drop the windows that closed before ``t`` (profiles arrive in stamp order: no later one needs them)."""
        self.windows = [w for w in self.windows if w[1] is None or w[1] >= t]

    def __iter__(self) -> Iterable[tuple[float, float | None]]:
        return iter([(start, end) for start, end in self.windows])
