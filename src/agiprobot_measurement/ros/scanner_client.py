"""The scanner as the plan executor sees it: the laser_scanner node's target, stitching and measured cloud.

:class:`ScannerClient` talks to the laser_scanner node (target, stitching, the measured cloud) and collects the
profiles it publishes. Points are mm in the core and m on the wire.
"""

from __future__ import annotations

import threading

import numpy as np
import rospy
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Empty, Trigger

from agiprobot_measurement.planning.plan.execution import ExecutionError, PlanPart
from agiprobot_measurement.ros.conversions import cloud_xyz
from agiprobot_measurement.srv import SetScanTarget, SetStitching

__all__ = ["PROFILE_QUEUE", "ScannerClient", "ScannerError"]

#: a node starved of CPU must not drop profiles: the queue holds a minute of them
PROFILE_QUEUE = 6000


class ScannerError(ExecutionError):
    """The scanner refused a request (no target, an unreadable mesh)."""


class ScannerClient:
    """The laser_scanner node's services and topics under ``namespace`` (e.g. /laser_scanner)."""

    def __init__(self, namespace: str, service_timeout_s: float = 5.0):
        self.namespace = namespace.rstrip("/")
        self.service_timeout_s = service_timeout_s
        self.lock = threading.Lock()
        self.collecting = False
        self.profiles_received = 0
        self.chunks_mm: list[np.ndarray] = []
        self.measured_cloud: PointCloud2 | None = None
        rospy.Subscriber(
            f"{self.namespace}/profile", PointCloud2, self._on_profile, queue_size=PROFILE_QUEUE, buff_size=2**24
        )
        rospy.Subscriber(
            f"{self.namespace}/measured_cloud", PointCloud2, self._on_measured_cloud, queue_size=1, buff_size=2**26
        )

    def _call(self, name: str, service_type, *args):
        rospy.wait_for_service(f"{self.namespace}/{name}", timeout=self.service_timeout_s)
        return rospy.ServiceProxy(f"{self.namespace}/{name}", service_type)(*args)

    def _on_profile(self, msg):
        if self.collecting:
            self.profiles_received += 1
            points = cloud_xyz(msg) * 1000.0
            if len(points):
                self.chunks_mm.append(points)

    def _on_measured_cloud(self, msg):
        if not self.collecting:
            self.measured_cloud = msg

    def set_target(self, part: PlanPart) -> None:
        """Scan ``part`` from now on and forget what was measured before."""
        reply = self._call(
            "set_target", SetScanTarget, part.mesh_file, part.units, part.file_units_placement.reshape(-1).tolist()
        )
        if not reply.success:
            raise ScannerError(f"scanner: {reply.message}")
        self._call("clear", Empty)

    def set_stitching(self, on: bool) -> int:
        """Switch stitching; returns the scanner's profile count since its last clear."""
        return int(self._call("set_stitching", SetStitching, on).profiles)

    def start_collecting(self) -> None:
        self.chunks_mm = []
        self.profiles_received = 0
        self.collecting = True

    def finish_collecting(self, profile_wait_s: float = 5.0, cloud_wait_s: float = 10.0) -> np.ndarray:
        """Stop stitching and return every point measured since :meth:`start_collecting` (mm): the scanner's
        whole measured cloud (one message, which a bag records as well), else the profiles received."""
        expected = None
        try:
            expected = self.set_stitching(False)
        except rospy.ROSException:
            pass
        # the last profiles are still in flight: wait for them (bounded)
        deadline = rospy.Time.now() + rospy.Duration(profile_wait_s)
        while expected is not None and self.profiles_received < expected and rospy.Time.now() < deadline:
            rospy.sleep(0.05)
        self.collecting = False
        self.measured_cloud = None
        try:
            self._call("publish_measured_cloud", Trigger)
            deadline = rospy.Time.now() + rospy.Duration(cloud_wait_s)
            while self.measured_cloud is None and rospy.Time.now() < deadline:
                rospy.sleep(0.05)
        except rospy.ROSException:
            pass
        if self.measured_cloud is not None:
            return cloud_xyz(self.measured_cloud) * 1000.0
        return np.vstack(self.chunks_mm) if self.chunks_mm else np.zeros((0, 3))
