"""scancontrol_driver node: the simulated laser line scanner as the Micro-Epsilon scanCONTROL driver
(micro_epsilon_scancontrol_driver, ROS 1) offers it.

Profiles stream continuously at the sensor's profile rate (exposure + idle time), one sensor_msgs/PointCloud2 per
profile on ``topic_name`` (public: /scancontrol_pointcloud), in the sensor frame ``~frame_id`` (x along the laser
line, y = 0, z = distance, m; fields x, y, z, intensity float32; height 1, width = resolution; no return = +Inf).
Each profile is the laser fan cast against the part
(:class:`~agiprobot_measurement.sensors.laser_line.simulator.LaserLineScannerSimulator`) from the
``~emitter_frame`` pose tf had at the exposure instant; the stamp is that instant plus ``~stamp_latency_s`` (a real
driver stamps at host receive time, a few ms after the exposure; 0 = exposure time).

Services (the driver's; micro_epsilon_scancontrol_msgs): ~get_feature, ~set_feature, ~get_resolution,
~set_resolution, ~get_available_resolutions, ~invert_x, ~invert_z (std_srvs/SetBool). Return codes as the SDK's
(1 = success; see :mod:`agiprobot_measurement.sensors.laser_line.scancontrol`).
Simulation only: ~set_target (agiprobot_measurement/SetScanTarget: the part's mesh file, unit and placement;
without a target every point is a no-return).
Parameters (the driver's): ~resolution (-1 = highest), ~serial, ~frame_id (scancontrol), ~topic_name
(scancontrol_pointcloud), ~partial_profile_start_point (0), ~partial_profile_start_point_data (4),
~partial_profile_point_count (-1), ~partial_profile_data_width (4: the last ceil(16 / width) points carry the
sensor's timestamp and are +Inf).
Parameters (the simulator's): ~scanner (config/laser_scanner.yaml), ~world_frame (world), ~emitter_frame
(laser_emitter_frame), ~profile_rate_hz (the scanner config's), ~stamp_latency_s (0.0), ~noise_scale (1.0),
~seed (0), ~error_model (realistic: config/error_models/<name>.yaml; ideal = the planning model's noise only,
scaled by ~noise_scale). With an error model the head's calibration error, measurement noise, material and edge
effects apply, and its hand-eye error: profiles are cast from the tf pose times that error and reported at the tf
pose (docs/sensor-errors.md).
"""

from __future__ import annotations

import threading

import numpy as np
import rospy
import tf2_ros
from micro_epsilon_scancontrol_msgs.srv import (
    GetAvailableResolutions,
    GetAvailableResolutionsResponse,
    GetFeature,
    GetFeatureResponse,
    GetResolution,
    GetResolutionResponse,
    SetFeature,
    SetFeatureResponse,
    SetResolution,
    SetResolutionResponse,
)
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from std_srvs.srv import SetBool, SetBoolResponse

from agiprobot_measurement.common.config import number, whole
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.planning.part_loading import PartLoadError, load_part
from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, param, read_params, text
from agiprobot_measurement.sensors.error_models import DEFAULT_ERROR_MODEL, LaserErrors, load_error_model
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.scancontrol import (
    GENERAL_FUNCTION_OK,
    INVERT_X_BIT,
    INVERT_Z_BIT,
    POINT_FIELDS,
    ScanControlDevice,
    sensor_frame_profile,
)
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator
from agiprobot_measurement.srv import SetScanTarget, SetScanTargetResponse
from agiprobot_measurement.station import load_scanner_config

__all__ = ["ScanControlDriverSim", "main", "profile_cloud"]

_TF_ERRORS = (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException)
_FIELDS = [PointField(name, 4 * i, PointField.FLOAT32, 1) for i, name in enumerate(POINT_FIELDS)]
#: how often (s) the node produces the profiles due since its last tick
TICK_S = 0.02
#: a gap in tf longer than this (s) is a stall: the profile clock restarts at the newest pose instead of catching up
MAX_CATCH_UP_S = 8.0
#: profiles a stalled subscriber may fall behind by before the oldest are dropped (a catch-up publishes many at once)
PUBLISH_QUEUE = 2000


def profile_cloud(points: np.ndarray, header: Header) -> PointCloud2:
    """The driver's message of one profile: (N, 4) float32 x, y, z, intensity (m), height 1, width N."""
    data = np.ascontiguousarray(points, dtype=np.float32)
    msg = PointCloud2(header=header, height=1, width=len(data), fields=_FIELDS, is_bigendian=False)
    msg.point_step = 4 * len(POINT_FIELDS)
    msg.row_step = msg.point_step * len(data)
    msg.is_dense = bool(np.all(np.isfinite(data)))
    msg.data = data.tobytes()
    return msg


class ScanControlDriverSim:
    def __init__(self):
        scanner = load_scanner_config(param("~scanner", None) or None)
        params = scanner.sensor_parameters
        settings = read_params(
            (
                Param("~resolution", -1, whole),
                Param("~serial", "", text),
                Param("~frame_id", "scancontrol", text),
                Param("~topic_name", "scancontrol_pointcloud", text),
                Param("~partial_profile_start_point", 0, whole),
                Param("~partial_profile_start_point_data", 4, whole),
                Param("~partial_profile_point_count", -1, whole),
                Param("~partial_profile_data_width", 4, whole),
                Param("~world_frame", "world", text),
                Param("~emitter_frame", "laser_emitter_frame", text),
                Param("~profile_rate_hz", params.get("profile_rate_hz", 100.0), number),
                Param("~stamp_latency_s", 0.0, number),
                Param("~noise_scale", 1.0, number),
                Param("~seed", 0, whole),
                Param("~error_model", DEFAULT_ERROR_MODEL, text),
            )
        )
        self.frame_id = settings.frame_id
        self.world_frame = settings.world_frame
        self.emitter_frame = settings.emitter_frame
        self.latency = rospy.Duration.from_sec(settings.stamp_latency_s)
        model = SensorModel(params)
        self.device = ScanControlDevice(
            int(params.get("points_per_profile", 640)),
            settings.profile_rate_hz,
            data_width=settings.partial_profile_data_width,
            measuring_range_m=(model.minimum_standoff / 1000.0, model.maximum_standoff / 1000.0),
        )
        self.device.select_resolution(settings.resolution)
        errors = LaserErrors.create(model, load_error_model(settings.error_model), settings.serial or None)
        self.simulator = LaserLineScannerSimulator(
            model,
            points_per_profile=self.device.resolution,
            seed=settings.seed,
            noise_scale=settings.noise_scale,
            errors=errors,
        )
        self.hand_eye_error = errors.hand_eye_error if errors is not None else None
        self.has_target = False
        self.lock = threading.Lock()
        self.next_exposure: rospy.Time | None = None
        self.emitter_to_sensor: np.ndarray | None = None
        self.tf_buffer = tf2_ros.Buffer(rospy.Duration(2.0 * MAX_CATCH_UP_S))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.publisher = rospy.Publisher(settings.topic_name, PointCloud2, queue_size=PUBLISH_QUEUE)
        rospy.Service("~get_feature", GetFeature, self.get_feature)
        rospy.Service("~set_feature", SetFeature, self.set_feature)
        rospy.Service("~get_resolution", GetResolution, self.get_resolution)
        rospy.Service("~set_resolution", SetResolution, self.set_resolution)
        rospy.Service("~get_available_resolutions", GetAvailableResolutions, self.get_available_resolutions)
        rospy.Service("~invert_x", SetBool, lambda request: self.invert(INVERT_X_BIT, "x", request))
        rospy.Service("~invert_z", SetBool, lambda request: self.invert(INVERT_Z_BIT, "z", request))
        rospy.Service("~set_target", SetScanTarget, self.set_target)
        rospy.Timer(rospy.Duration(TICK_S), self.tick)
        rospy.loginfo(
            "scancontrol_driver: simulated scanCONTROL%s, %d points per profile, %.0f profiles/s in %s on %s",
            f" {settings.serial}" if settings.serial else "",
            self.device.resolution,
            1.0 / self.device.profile_period_s,
            self.frame_id,
            self.publisher.resolved_name,
        )

    # --- services ----------------------------------------------------------------------------------------------

    def get_feature(self, request):
        with self.lock:
            code, value = self.device.get_feature(request.setting)
        return GetFeatureResponse(value=value, return_code=code)

    def set_feature(self, request):
        with self.lock:
            return SetFeatureResponse(return_code=self.device.set_feature(request.setting, request.value))

    def get_resolution(self, _request):
        with self.lock:
            code, resolution = self.device.get_resolution()
        return GetResolutionResponse(resolution=resolution, return_code=code)

    def set_resolution(self, request):
        with self.lock:
            code = self.device.set_resolution(request.resolution)
            if code >= GENERAL_FUNCTION_OK:
                self.simulator.set_points_per_profile(self.device.resolution)
        return SetResolutionResponse(return_code=code)

    def get_available_resolutions(self, _request):
        with self.lock:
            code, resolutions = self.device.available_resolutions()
        return GetAvailableResolutionsResponse(resolutions=resolutions, return_code=code)

    def invert(self, bit: int, axis: str, request):
        with self.lock:
            code = self.device.set_inversion(bit, bool(request.data))
        if code < GENERAL_FUNCTION_OK:
            return SetBoolResponse(False, f"Failed to set 'Profile Data Processing' feature. Error code: {code}")
        return SetBoolResponse(True, "")

    def set_target(self, request):
        transform = np.asarray(request.transform_mm, dtype=float).reshape(4, 4)
        try:
            if not np.all(np.isfinite(transform)):
                raise PartLoadError("transform_mm contains NaN or infinite values")
            part = load_part(request.mesh_file, units=request.units or "mm", transform=transform, remove_downside=False)
            with self.lock:
                self.simulator.set_target(part.mesh)
                self.has_target = True
        except (AgiprobotError, ValueError) as exc:
            return SetScanTargetResponse(False, str(exc))
        return SetScanTargetResponse(True, f"scanning {request.mesh_file} ({len(part.mesh.faces)} faces)")

    # --- profiles ----------------------------------------------------------------------------------------------

    def _sensor_in_emitter(self) -> np.ndarray | None:
        """The sensor frame's pose in the emitter frame (4x4, mm; fixed, looked up once)."""
        if self.emitter_to_sensor is None:
            try:
                transform = self.tf_buffer.lookup_transform(self.emitter_frame, self.frame_id, rospy.Time(0))
            except _TF_ERRORS as exc:
                rospy.logwarn_throttle(5.0, "scancontrol_driver: no frame %s: %s", self.frame_id, exc)
                return None
            matrix = transform_to_matrix(transform)
            matrix[:3, 3] *= 1000.0
            self.emitter_to_sensor = matrix
        return self.emitter_to_sensor

    def tick(self, _event) -> None:
        """Every profile whose exposure instant tf has reached since the last tick, one per profile period, each
        from the emitter pose at that instant (interpolated by tf), so compute jitter never thins the stream."""
        try:
            latest = self.tf_buffer.lookup_transform(self.world_frame, self.emitter_frame, rospy.Time(0)).header.stamp
        except _TF_ERRORS as exc:
            rospy.logwarn_throttle(5.0, "scancontrol_driver: no emitter pose: %s", exc)
            return
        sensor_in_emitter = self._sensor_in_emitter()
        if sensor_in_emitter is None:
            return
        with self.lock:
            period = rospy.Duration.from_sec(self.device.profile_period_s)
            if self.next_exposure is None or (latest - self.next_exposure).to_sec() > MAX_CATCH_UP_S:
                self.next_exposure = latest
            exposures, poses = [], []
            while self.next_exposure <= latest:
                try:
                    transform = self.tf_buffer.lookup_transform(
                        self.world_frame, self.emitter_frame, self.next_exposure
                    )
                    pose = transform_to_matrix(transform)
                    pose[:3, 3] *= 1000.0
                    exposures.append(self.next_exposure)
                    poses.append(pose)
                except _TF_ERRORS:
                    pass
                self.next_exposure += period
            if not poses or self.publisher.get_num_connections() == 0:
                return  # nobody listens: the sensor runs on, nothing to compute
            profiles = self._profiles(np.array(poses)) if self.has_target else [None] * len(poses)
            clouds = [
                sensor_frame_profile(profile, pose @ sensor_in_emitter, self.device)
                for profile, pose in zip(profiles, poses, strict=True)
            ]
        for exposure, cloud in zip(exposures, clouds, strict=True):
            self.publisher.publish(profile_cloud(cloud, Header(stamp=exposure + self.latency, frame_id=self.frame_id)))

    def _profiles(self, poses: np.ndarray):
        """Profiles at the tf poses; with a hand-eye error cast from where the head really is, reported at tf."""
        if self.hand_eye_error is None:
            return self.simulator.profiles(poses)
        return self.simulator.profiles(poses @ self.hand_eye_error, poses)


def main():
    run_node("scancontrol_driver", ScanControlDriverSim, label="scancontrol_driver")
