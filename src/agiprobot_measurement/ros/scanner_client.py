"""The scanner as the plan executor sees it: a line scanner's profiles stitched by the stitcher node.

:class:`ScannerClient` drives the names a real cell has: the stitcher's ``/switch_stitch_mode`` (std_srvs/SetBool)
and ``/clear_stitched_point_cloud`` (std_srvs/Trigger), as the original station's stitcher offered them; the
stitcher's extras under ``namespace`` (``<namespace>/profile``: each stitched profile in the world frame,
``<namespace>/publish_measured_cloud`` + ``<namespace>/measured_cloud``: the whole stitched cloud on request); and,
in simulation only, the simulated sensor's ``/scancontrol_driver/set_target`` (the part to scan; a real scanner sees
the real part, so the client goes on without it when no such service exists). Switching stitching off returns once
the stitcher has stitched every profile stamped up to that instant. Points are mm in the core and m on the wire.
"""

from __future__ import annotations

import threading

import numpy as np
import rospy
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import SetBool, Trigger

from agiprobot_measurement.planning.plan.execution import ExecutionError, PlanPart
from agiprobot_measurement.ros.conversions import cloud_xyz
from agiprobot_measurement.srv import SetScanTarget

__all__ = [
    "CLEAR_SERVICE",
    "PROFILE_QUEUE",
    "SWITCH_SERVICE",
    "TARGET_SERVICE",
    "ScannerClient",
    "ScannerError",
]

#: a node starved of CPU must not drop profiles: the queue holds a minute of them
PROFILE_QUEUE = 6000
#: the stitcher's switch and clear services (the original station's names)
SWITCH_SERVICE = "/switch_stitch_mode"
CLEAR_SERVICE = "/clear_stitched_point_cloud"
#: the simulated sensor's service for the part to scan (simulation only)
TARGET_SERVICE = "/scancontrol_driver/set_target"


class ScannerError(ExecutionError):
    """The scanner refused a request (no target, an unreadable mesh, stitching not switched)."""


class ScannerClient:
    """The stitcher's services and topics; ``namespace`` holds its extras (e.g. /laser_scanner)."""

    def __init__(
        self,
        namespace: str,
        service_timeout_s: float = 5.0,
        switch_service: str = SWITCH_SERVICE,
        clear_service: str = CLEAR_SERVICE,
        target_service: str = TARGET_SERVICE,
    ):
        self.namespace = namespace.rstrip("/")
        self.service_timeout_s = service_timeout_s
        self.switch_service = switch_service
        self.clear_service = clear_service
        self.target_service = target_service
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
        rospy.wait_for_service(name, timeout=self.service_timeout_s)
        return rospy.ServiceProxy(name, service_type)(*args)

    def _on_profile(self, msg):
        if self.collecting:
            points = cloud_xyz(msg) * 1000.0
            with self.lock:
                self.profiles_received += 1
                if len(points):
                    self.chunks_mm.append(points)

    def _on_measured_cloud(self, msg):
        self.measured_cloud = msg

    def wait_for_stitcher(self, timeout_s: float) -> None:
        """Raise ``rospy.ROSException`` unless the stitcher's switch service appears within ``timeout_s``."""
        rospy.wait_for_service(self.switch_service, timeout=timeout_s)

    def set_target(self, part: PlanPart) -> None:
        """Scan ``part`` from now on (simulation: the simulated sensor's target) and forget what was stitched."""
        try:
            rospy.wait_for_service(self.target_service, timeout=self.service_timeout_s)
        except rospy.ROSException:
            rospy.logwarn("scanner: no %s: a real scanner, scanning the real part", self.target_service)
        else:
            reply = rospy.ServiceProxy(self.target_service, SetScanTarget)(
                part.mesh_file, part.units, part.file_units_placement.reshape(-1).tolist()
            )
            if not reply.success:
                raise ScannerError(f"scanner: {reply.message}")
        reply = self._call(self.clear_service, Trigger)
        if not reply.success:
            raise ScannerError(f"scanner: cannot clear the stitched cloud: {reply.message}")

    def set_stitching(self, on: bool) -> None:
        """Switch stitching; switching off returns once every profile up to now is stitched."""
        reply = self._call(self.switch_service, SetBool, on)
        if not reply.success:
            raise ScannerError(f"scanner: stitching not switched {'on' if on else 'off'}: {reply.message}")

    def start_collecting(self) -> None:
        with self.lock:
            self.chunks_mm = []
            self.profiles_received = 0
        self.collecting = True

    def finish_collecting(self, profile_wait_s: float = 5.0, cloud_wait_s: float = 10.0) -> np.ndarray:
        """Stop stitching and return every point stitched since the last clear (mm): the stitcher's whole cloud
        (one message, which a bag records as well), else the stitched profiles received since
        :meth:`start_collecting` (after at most ``profile_wait_s`` for those in flight)."""
        try:
            self.set_stitching(False)
        except (rospy.ROSException, rospy.ServiceException, ScannerError) as exc:
            rospy.logwarn("scanner: %s", exc)
        self.measured_cloud = None
        try:
            self._call(f"{self.namespace}/publish_measured_cloud", Trigger)
            deadline = rospy.Time.now() + rospy.Duration(cloud_wait_s)
            while self.measured_cloud is None and rospy.Time.now() < deadline:
                rospy.sleep(0.05)
        except (rospy.ROSException, rospy.ServiceException):
            pass
        if self.measured_cloud is not None:
            self.collecting = False
            return cloud_xyz(self.measured_cloud) * 1000.0
        # no whole cloud: the profiles in flight may still come
        rospy.sleep(min(profile_wait_s, 1.0))
        self.collecting = False
        with self.lock:
            return np.vstack(self.chunks_mm) if self.chunks_mm else np.zeros((0, 3))
