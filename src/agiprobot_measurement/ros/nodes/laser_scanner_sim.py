"""laser_scanner_sim node: the simulated laser line scanner on the robot, profiles of the part from the real
laser_emitter_frame pose (tf).

While stitching is on (the original switched it on for measurement segments only), it casts the laser fan
against the part at the profile rate (:class:`~agiprobot_measurement.sensors.laser_line.simulator.LaserLineScannerSimulator`),
publishes each profile and accumulates the measured cloud.

Services: ~set_target (agiprobot_measurement/SetScanTarget: the part's mesh file, unit and placement),
~set_stitching (agiprobot_measurement/SetStitching: the reply carries the profile count since ~clear), ~clear
(std_srvs/Empty: forget the accumulated cloud), ~publish_measured_cloud (std_srvs/Trigger: publish the whole
accumulated cloud once on ~measured_cloud).
Topics: ~profile (sensor_msgs/PointCloud2, world frame, m), ~measured_cloud (PointCloud2, every measured point
since ~clear, on request, latched), ~measured_cloud_display (the same thinned to ~measured_cloud_voxel_mm, 1 Hz
while stitching, latched), ~stitching (std_msgs/Bool, latched).
Parameters: ~scanner (config/laser_scanner.yaml), ~world_frame (world), ~emitter_frame (laser_emitter_frame),
~profile_rate_hz (the scanner config's), ~points_per_profile (the scanner config's), ~noise_scale (1.0),
~seed (0), ~measured_cloud_voxel_mm (1.0).
"""

from __future__ import annotations

import threading

import numpy as np
import rospy
import tf2_ros
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Bool, Header
from std_srvs.srv import Empty, EmptyResponse, Trigger, TriggerResponse

from agiprobot_measurement.common.config import number, whole
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.planning.part_loading import PartLoadError, load_part
from agiprobot_measurement.ros.conversions import transform_to_matrix, xyz_cloud
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, param, read_params
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator, StitchedCloud, voxel_thin
from agiprobot_measurement.srv import SetScanTarget, SetScanTargetResponse, SetStitching, SetStitchingResponse
from agiprobot_measurement.station import load_scanner_config

__all__ = ["LaserScannerSim", "main"]

_TF_ERRORS = (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException)


#: tf older than this (s) when stitching is switched off means the robot stopped publishing: no wait for it
TF_STALL_S = 1.0


class LaserScannerSim:
    def __init__(self):
        scanner = load_scanner_config(param("~scanner", None) or None)
        params = scanner.sensor_parameters
        # the node's parameters (name, default, validator), read once; two defaults come from the scanner file
        settings = read_params(
            (
                Param("~world_frame", "world"),
                Param("~emitter_frame", "laser_emitter_frame"),
                Param("~profile_rate_hz", params.get("profile_rate_hz", 100.0), number),
                Param("~measured_cloud_voxel_mm", 1.0, number),
                Param("~points_per_profile", params.get("points_per_profile", 640), whole),
                Param("~seed", 0, whole),
                Param("~noise_scale", 1.0, number),
            )
        )
        self.world_frame = settings.world_frame
        self.emitter_frame = settings.emitter_frame
        self.rate_hz = settings.profile_rate_hz
        self.voxel_mm = settings.measured_cloud_voxel_mm
        self.simulator = LaserLineScannerSimulator(
            SensorModel(params),
            points_per_profile=settings.points_per_profile,
            seed=settings.seed,
            noise_scale=settings.noise_scale,
        )
        self.lock = threading.Lock()
        # the timer's scan and a stitching switch must not interleave: a switch resets the profile clock that a
        # running scan advances
        self.scan_lock = threading.Lock()
        self.stitching = False
        self.has_target = False
        self.cloud = StitchedCloud()
        self.next_profile_time = None
        self.tf_buffer = tf2_ros.Buffer(rospy.Duration(10.0))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        # a catch-up after a stall publishes many profiles at once: none may be dropped
        self.profile_pub = rospy.Publisher("~profile", PointCloud2, queue_size=5000)
        self.cloud_pub = rospy.Publisher("~measured_cloud", PointCloud2, queue_size=1, latch=True)
        self.display_pub = rospy.Publisher("~measured_cloud_display", PointCloud2, queue_size=1, latch=True)
        self.state_pub = rospy.Publisher("~stitching", Bool, queue_size=1, latch=True)
        self.state_pub.publish(Bool(False))
        rospy.Service("~set_target", SetScanTarget, self.set_target)
        rospy.Service("~set_stitching", SetStitching, self.set_stitching)
        rospy.Service("~clear", Empty, self.clear)
        rospy.Service("~publish_measured_cloud", Trigger, self.publish_full_cloud)
        # ticks at 25 Hz; each produces every profile due since the last (see scan())
        rospy.Timer(rospy.Duration(0.04), self.scan)
        rospy.Timer(rospy.Duration(1.0), lambda _e: self.publish_cloud() if self.stitching else None)
        rospy.loginfo(
            "laser_scanner_sim: %.0f profiles/s, %d points per profile", self.rate_hz, self.simulator.points_per_profile
        )

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

    def set_stitching(self, request):
        if request.data and not self.has_target:
            return SetStitchingResponse(False, "no scan target: call ~set_target first", self.cloud.profiles)
        stop = None
        if not request.data and self.stitching:
            # the measurement lasts until now: wait for tf to reach this instant (a busy machine delivers it
            # late), then scan the profiles still due before switching off
            stop = rospy.Time.now()
            self._wait_for_tf(stop, timeout_s=5.0)
        with self.scan_lock:
            if stop is not None:
                self._scan(until=stop)
            with self.lock:
                self.stitching = bool(request.data)
                self.next_profile_time = None
        self.state_pub.publish(Bool(self.stitching))
        if not self.stitching:
            self.publish_cloud()
        # the profile count lets a client wait until it has received every profile
        profiles = self.cloud.profiles
        return SetStitchingResponse(
            True, f"stitching {'on' if self.stitching else 'off'}; {profiles} profiles", profiles
        )

    def _wait_for_tf(self, stamp: rospy.Time, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the emitter's tf at ``stamp``, but only while tf keeps arriving: a robot
        whose controller died publishes none for ``TF_STALL_S``, and switching off must not wait for it."""
        deadline = rospy.Time.now() + rospy.Duration(timeout_s)
        while not rospy.is_shutdown() and rospy.Time.now() < deadline:
            if self.tf_buffer.can_transform(self.world_frame, self.emitter_frame, stamp, rospy.Duration(0.05)):
                return True
            try:
                latest = self.tf_buffer.lookup_transform(self.world_frame, self.emitter_frame, rospy.Time(0))
            except tf2_ros.TransformException:
                return False
            if (rospy.Time.now() - latest.header.stamp).to_sec() > TF_STALL_S:
                return False
        return False

    def clear(self, _request):
        with self.lock:
            self.cloud.clear()
        self.publish_cloud()
        return EmptyResponse()

    def scan(self, _event, until=None):
        """Profiles at the scanner's fixed rate: one per profile period since the last tick, each at the
        emitter pose tf had at that instant (interpolated), so compute jitter never thins the scan."""
        with self.scan_lock:
            self._scan(until)

    def _scan(self, until=None):
        if not self.stitching:
            return
        try:
            latest = self.tf_buffer.lookup_transform(self.world_frame, self.emitter_frame, rospy.Time(0)).header.stamp
        except _TF_ERRORS as exc:
            rospy.logwarn_throttle(5.0, "laser_scanner_sim: no emitter pose: %s", exc)
            return
        if until is not None and until < latest:
            latest = until
        period = rospy.Duration(1.0 / self.rate_hz)
        # catch up after a stall as far as the tf history reaches (a starved process must not thin the scan)
        if self.next_profile_time is None or latest - self.next_profile_time > rospy.Duration(8.0):
            self.next_profile_time = latest
        stamps, poses = [], []
        while self.next_profile_time <= latest:
            try:
                transform = self.tf_buffer.lookup_transform(
                    self.world_frame, self.emitter_frame, self.next_profile_time
                )
            except _TF_ERRORS:
                transform = None
            if transform is not None:
                pose_mm = transform_to_matrix(transform)
                pose_mm[:3, 3] *= 1000.0
                stamps.append(self.next_profile_time)
                poses.append(pose_mm)
            self.next_profile_time += period
        if not poses:
            return
        with self.lock:
            profiles = self.simulator.profiles(np.array(poses))
            self.cloud.add(profiles)
        for stamp, profile in zip(stamps, profiles, strict=True):
            header = Header(stamp=stamp, frame_id=self.world_frame)
            self.profile_pub.publish(xyz_cloud(profile.points_mm / 1000.0, header))

    def _accumulated(self) -> np.ndarray:
        with self.lock:
            return self.cloud.points()

    def publish_cloud(self):
        """The thinned cloud for display."""
        points = voxel_thin(self._accumulated(), self.voxel_mm)
        header = Header(stamp=rospy.Time.now(), frame_id=self.world_frame)
        self.display_pub.publish(xyz_cloud(points / 1000.0, header))

    def publish_full_cloud(self, _request):
        points = self._accumulated()
        header = Header(stamp=rospy.Time.now(), frame_id=self.world_frame)
        self.cloud_pub.publish(xyz_cloud(points / 1000.0, header))
        return TriggerResponse(True, f"{len(points)} points from {self.cloud.profiles} profiles")


def main():
    run_node("laser_scanner", LaserScannerSim, label="laser_scanner_sim")
