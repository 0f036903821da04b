"""point_cloud_stitcher node: stitches a line scanner's profiles (sensor frame) into one cloud in the world frame,
with the names of the original station's stitcher.

Every profile of ``~cloud_topic`` (/scancontrol_pointcloud, sensor_msgs/PointCloud2 in the sensor frame, as the
scanCONTROL driver publishes them) is queued (none dropped) and, when its stamp minus ``~latency_compensation_s``
lies in a window in which stitching was on, transformed into ``~world_frame`` with tf at that instant (waiting up to
``~tf_timeout_s`` for tf to get there) and added to the stitched cloud.

Services (the original's names, in the node's namespace): switch_stitch_mode (std_srvs/SetBool: true opens a
stitching window at the call's instant, reply "activated stitching"; false closes it at the call's instant t_off and
replies "deactivated stitching" once every profile stamped up to t_off is stitched, when the profiles stop for
1 s, or after ``~switch_off_timeout_s``; a profile stamped up to t_off that comes later is still stitched),
clear_stitched_point_cloud (std_srvs/Trigger: forget the stitched cloud).
Extras: ~publish_measured_cloud (std_srvs/Trigger: publish the whole stitched cloud once on ~measured_cloud).
Topics: stitched_point_cloud (sensor_msgs/PointCloud, world, latched, the original's type: the stitched cloud
thinned to ``~stitched_cloud_voxel_mm``, at 1 Hz while stitching, at switch-off and on clear), ~profile
(sensor_msgs/PointCloud2: each stitched profile in the world frame, m), ~measured_cloud (PointCloud2, world, latched,
every stitched point, on request), ~measured_cloud_display (PointCloud2, the cloud thinned to
``~measured_cloud_voxel_mm``, 1 Hz while stitching, latched), ~stitching (std_msgs/Bool, latched).
Parameters: ~cloud_topic (/scancontrol_pointcloud), ~world_frame (world), ~latency_compensation_s (0.0: subtracted
from each profile's stamp before the tf lookup), ~tf_timeout_s (1.0), ~tf_cache_s (120: the tf history kept, longer
than a scan line), ~switch_off_timeout_s (30.0), ~stitched_cloud_voxel_mm (1.0), ~measured_cloud_voxel_mm (1.0).
"""

from __future__ import annotations

import collections
import threading

import numpy as np
import rospy
import tf2_ros
from sensor_msgs.msg import PointCloud, PointCloud2
from std_msgs.msg import Bool, Header
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse

from agiprobot_measurement.common.config import number, positive
from agiprobot_measurement.ros.conversions import cloud_xyz, transform_to_matrix, xyz_cloud, xyz_point_cloud
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, read_params, text
from agiprobot_measurement.sensors.laser_line.scancontrol import StitchWindows, stitch_profile
from agiprobot_measurement.sensors.laser_line.simulator import voxel_thin

__all__ = ["PointCloudStitcher", "main"]

_TF_ERRORS = (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException)
#: the subscriber's queue: a minute of profiles at 100 Hz, so a busy stitcher drops none
PROFILE_QUEUE = 6000
#: while switching off, no new profile for this long (s) means the scanner stopped: stop waiting for more
PROFILE_STALL_S = 1.0
#: the wait loop's poll period (s)
POLL_S = 0.005


class PointCloudStitcher:
    def __init__(self):
        settings = read_params(
            (
                Param("~cloud_topic", "/scancontrol_pointcloud", text),
                Param("~world_frame", "world", text),
                Param("~latency_compensation_s", 0.0, number),
                Param("~tf_timeout_s", 1.0, positive),
                Param("~tf_cache_s", 120.0, positive),
                Param("~switch_off_timeout_s", 30.0, positive),
                Param("~stitched_cloud_voxel_mm", 1.0, number),
                Param("~measured_cloud_voxel_mm", 1.0, number),
            )
        )
        self.settings = settings
        self.world_frame = settings.world_frame
        self.compensation = rospy.Duration.from_sec(settings.latency_compensation_s)
        self.tf_timeout = rospy.Duration.from_sec(settings.tf_timeout_s)
        self.tf_buffer = tf2_ros.Buffer(rospy.Duration.from_sec(settings.tf_cache_s))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        # the stitched cloud, its profile count, the stitching windows, the newest processed (corrected) stamp
        self.lock = threading.Lock()
        self.processed = threading.Condition(self.lock)
        self.windows = StitchWindows()
        self.chunks: list[np.ndarray] = []
        self.profiles = 0
        self.dropped = 0
        self.latest_stamp: rospy.Time | None = None
        self.latest_arrival = rospy.Time(0)
        self.queue: collections.deque = collections.deque()
        self.queued = threading.Condition()
        self.publish_request = threading.Event()
        self.profile_pub = rospy.Publisher("~profile", PointCloud2, queue_size=PROFILE_QUEUE)
        self.cloud_pub = rospy.Publisher("~measured_cloud", PointCloud2, queue_size=1, latch=True)
        self.display_pub = rospy.Publisher("~measured_cloud_display", PointCloud2, queue_size=1, latch=True)
        self.stitched_pub = rospy.Publisher("stitched_point_cloud", PointCloud, queue_size=1, latch=True)
        self.state_pub = rospy.Publisher("~stitching", Bool, queue_size=1, latch=True)
        self.state_pub.publish(Bool(False))
        self.publish_clouds()
        rospy.Service("switch_stitch_mode", SetBool, self.switch_stitch_mode)
        rospy.Service("clear_stitched_point_cloud", Trigger, self.clear)
        rospy.Service("~publish_measured_cloud", Trigger, self.publish_full_cloud)
        threading.Thread(target=self._work, name="stitcher", daemon=True).start()
        threading.Thread(target=self._publish_loop, name="thinned clouds", daemon=True).start()
        rospy.Subscriber(settings.cloud_topic, PointCloud2, self._on_profile, queue_size=PROFILE_QUEUE, buff_size=2**26)
        rospy.Timer(rospy.Duration(1.0), lambda _e: self._publish_clouds_later() if self.windows.active else None)
        rospy.loginfo(
            "point_cloud_stitcher: profiles of %s into %s (latency compensation %.4f s)",
            settings.cloud_topic,
            self.world_frame,
            settings.latency_compensation_s,
        )

    # --- profiles ----------------------------------------------------------------------------------------------

    def _on_profile(self, msg: PointCloud2) -> None:
        with self.queued:
            self.queue.append(msg)
            self.queued.notify()

    def _work(self) -> None:
        while not rospy.is_shutdown():
            with self.queued:
                while not self.queue and not rospy.is_shutdown():
                    self.queued.wait(0.1)
                if not self.queue:
                    continue
                msg = self.queue.popleft()
            try:
                self._stitch(msg)
            except Exception as exc:  # one malformed profile must not end stitching
                rospy.logerr_throttle(5.0, "point_cloud_stitcher: profile skipped: %s", exc)

    def _stitch(self, msg: PointCloud2) -> None:
        stamp = msg.header.stamp - self.compensation
        with self.lock:
            wanted = self.windows.contains(stamp.to_sec())
        world = None
        if wanted:
            try:
                transform = self.tf_buffer.lookup_transform(
                    self.world_frame, msg.header.frame_id, stamp, self.tf_timeout
                )
                world = stitch_profile(cloud_xyz(msg), transform_to_matrix(transform))
            except _TF_ERRORS as exc:
                rospy.logwarn_throttle(5.0, "point_cloud_stitcher: profile at %.3f s dropped: %s", stamp.to_sec(), exc)
        with self.processed:
            if world is not None:
                if len(world):
                    self.chunks.append(world)
                self.profiles += 1
            elif wanted:
                self.dropped += 1
            self.latest_stamp = stamp
            self.latest_arrival = rospy.Time.now()
            self.windows.forget_before(stamp.to_sec())
            self.processed.notify_all()
        if world is not None:
            self.profile_pub.publish(xyz_cloud(world, Header(stamp=stamp, frame_id=self.world_frame)))

    # --- services ----------------------------------------------------------------------------------------------

    def switch_stitch_mode(self, request):
        now = rospy.Time.now()
        if request.data:
            with self.lock:
                self.windows.switch_on(now.to_sec())
            self.state_pub.publish(Bool(True))
            return SetBoolResponse(True, "activated stitching")
        with self.lock:
            was_on = self.windows.active
            self.windows.switch_off(now.to_sec())
        if was_on:
            self._wait_for_profiles_until(now)
        self.state_pub.publish(Bool(False))
        self._publish_clouds_later()
        return SetBoolResponse(True, "deactivated stitching")

    def _wait_for_profiles_until(self, t_off: rospy.Time) -> None:
        """Until a profile stamped after ``t_off`` is processed (so every earlier one is: they come in order), the
        profiles stop arriving for :data:`PROFILE_STALL_S`, or ``~switch_off_timeout_s`` passed."""
        deadline = rospy.Time.now() + rospy.Duration.from_sec(self.settings.switch_off_timeout_s)
        with self.processed:
            while not rospy.is_shutdown():
                if self.latest_stamp is not None and self.latest_stamp > t_off:
                    return
                now = rospy.Time.now()
                stalled = (now - max(self.latest_arrival, t_off)).to_sec() > PROFILE_STALL_S
                if now > deadline or (stalled and not self.queue):
                    rospy.logwarn(
                        "point_cloud_stitcher: switched off without the profiles up to %.3f s (newest %s)",
                        t_off.to_sec(),
                        "none" if self.latest_stamp is None else f"{self.latest_stamp.to_sec():.3f} s",
                    )
                    return
                self.processed.wait(POLL_S * 10)

    def clear(self, _request):
        with self.lock:
            self.chunks = []
            self.profiles = 0
            self.dropped = 0
        self._publish_clouds_later()
        return TriggerResponse(True, "cleared the stitched point cloud")

    def _accumulated(self) -> tuple[np.ndarray, int]:
        with self.lock:
            points = np.vstack(self.chunks) if self.chunks else np.zeros((0, 3))
            return points, self.profiles

    def _publish_clouds_later(self) -> None:
        """Have the publishing thread publish the thinned clouds: thinning a large cloud takes a while, and the
        service replies must not wait for it."""
        self.publish_request.set()

    def _publish_loop(self) -> None:
        while not rospy.is_shutdown():
            if self.publish_request.wait(0.5):
                self.publish_request.clear()
                self.publish_clouds()

    def publish_clouds(self) -> None:
        """The thinned clouds: stitched_point_cloud (PointCloud) and ~measured_cloud_display (PointCloud2)."""
        points, _ = self._accumulated()
        header = Header(stamp=rospy.Time.now(), frame_id=self.world_frame)
        thinned_mm = voxel_thin(points * 1000.0, self.settings.stitched_cloud_voxel_mm)
        self.stitched_pub.publish(xyz_point_cloud(thinned_mm / 1000.0, header))
        display_mm = voxel_thin(points * 1000.0, self.settings.measured_cloud_voxel_mm)
        self.display_pub.publish(xyz_cloud(display_mm / 1000.0, header))

    def publish_full_cloud(self, _request):
        points, profiles = self._accumulated()
        header = Header(stamp=rospy.Time.now(), frame_id=self.world_frame)
        self.cloud_pub.publish(xyz_cloud(points, header))
        return TriggerResponse(True, f"{len(points)} points from {profiles} profiles")


def main():
    run_node("point_cloud_stitcher", PointCloudStitcher, label="point_cloud_stitcher")
