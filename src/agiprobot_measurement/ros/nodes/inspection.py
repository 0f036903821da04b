"""inspection: a measured cloud against the nominal CAD model as a ROS action (``inspection.request`` on ROS).

Action ``~inspect_cloud`` (agiprobot_measurement/InspectCloud): the cloud from a file or the next message on a
cloud topic (sensor_msgs/PointCloud2 or PointCloud, world frame, metres: by default ``/stitched_point_cloud``, the
laser measurement's stitched cloud after an execution), the nominal mesh and the spec from files; feedback per stage
(check, register, deviations, regions, features, report, done); the result names the verdict, the surface regions
out of tolerance, each feature's verdict and the report folder. Topic ``~deviations`` (visualization_msgs/MarkerArray,
latched): the inspected points in the world frame coloured by their signed deviation (the report's colour map).

Files: reports go under ``~root`` (default ``$ROS_HOME/inspection``); input names resolve under it, absolute names
only inside it or one of ``~allowed_input_dirs`` (default: the package's ``config/inspection``, ROS_HOME, /tmp).
Parameters: ~root, ~allowed_input_dirs, ~cloud_topic (``/stitched_point_cloud``), ~cloud_timeout_s (30 s),
~frame_id (``world``: the frame the cloud must be in and the markers are drawn in).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import actionlib
import numpy as np
import rospy
from sensor_msgs.msg import PointCloud, PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.config import positive
from agiprobot_measurement.common.files import FileRoot
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.registration import apply
from agiprobot_measurement.inspection.report import deviation_colours
from agiprobot_measurement.inspection.request import InspectionRequest, placement_from_values, run_inspection
from agiprobot_measurement.msg import InspectCloudAction, InspectCloudFeedback, InspectCloudResult
from agiprobot_measurement.ros.conversions import cloud_xyz
from agiprobot_measurement.ros.markers import deviation_markers
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, read_params

__all__ = ["InspectionNode", "main"]

PARAMETERS = (
    Param("~root", ""),
    Param("~allowed_input_dirs", []),
    Param("~cloud_topic", "/stitched_point_cloud"),
    Param("~cloud_timeout_s", 30.0, positive),
    Param("~frame_id", "world"),
)
CLOUD_TYPES = {"sensor_msgs/PointCloud2": PointCloud2, "sensor_msgs/PointCloud": PointCloud}


def _ros_home() -> Path:
    return Path(os.environ.get("ROS_HOME") or "~/.ros").expanduser()


class InspectionNode:
    def __init__(self):
        self.settings = read_params(PARAMETERS)
        root = Path(self.settings.root or _ros_home() / "inspection").expanduser()
        root.mkdir(parents=True, exist_ok=True)
        allowed = self.settings.allowed_input_dirs or [PACKAGE_ROOT / "config" / "inspection", _ros_home(), "/tmp"]
        if isinstance(allowed, str):
            allowed = allowed.split()
        self.reports = FileRoot(root, purpose="inspection report folder")
        self.inputs = FileRoot(root, extra_roots=tuple(Path(d) for d in allowed), purpose="inspection input")
        self.markers = rospy.Publisher("~deviations", MarkerArray, queue_size=1, latch=True)
        self.server = actionlib.SimpleActionServer(
            "~inspect_cloud", InspectCloudAction, execute_cb=self.on_goal, auto_start=False
        )
        self.server.start()
        rospy.loginfo("inspection: ready (reports under %s)", self.reports.root)

    # ----------------------------------------------------------------------------------------------- goal
    def _topic_cloud(self, topic: str) -> np.ndarray:
        kind = dict(rospy.get_published_topics()).get(topic)
        if kind not in CLOUD_TYPES:
            found = "nobody publishes it" if kind is None else f"it carries {kind}"
            raise InspectionInputError(
                f"cloud topic {topic}: {found}; a sensor_msgs/PointCloud2 or PointCloud is needed"
            )
        try:
            msg = rospy.wait_for_message(topic, CLOUD_TYPES[kind], timeout=self.settings.cloud_timeout_s)
        except rospy.ROSException as exc:
            raise InspectionInputError(f"no cloud on {topic} within {self.settings.cloud_timeout_s:g} s") from exc
        if msg.header.frame_id.lstrip("/") != self.settings.frame_id:
            raise InspectionInputError(
                f"the cloud on {topic} is in frame '{msg.header.frame_id}'; the inspection needs '{self.settings.frame_id}'"
            )
        if kind == "sensor_msgs/PointCloud2":
            return cloud_xyz(msg)
        points = np.array([(p.x, p.y, p.z) for p in msg.points], dtype=float).reshape(-1, 3)
        return points[np.all(np.isfinite(points), axis=1)]

    def _request(self, goal) -> InspectionRequest:
        nominal = self.inputs.for_reading(goal.nominal_file)
        spec = self.inputs.for_reading(goal.spec_file)
        placement = placement_from_values(goal.placement)
        name = goal.output_dir or time.strftime("report_%Y%m%d_%H%M%S")
        out = self.reports.resolve(name)
        if goal.cloud_file:
            cloud = self.inputs.for_reading(goal.cloud_file)
            return InspectionRequest(nominal, spec, out, cloud_file=cloud, placement=placement,
                                     cloud_units=goal.cloud_units, overwrite=goal.overwrite)  # fmt: skip
        topic = goal.cloud_topic or self.settings.cloud_topic
        points = self._topic_cloud(topic)
        return InspectionRequest(nominal, spec, out, points=points, placement=placement,
                                 cloud_units=goal.cloud_units or "m", overwrite=goal.overwrite,
                                 meta={"cloud_topic": topic})  # fmt: skip

    def on_goal(self, goal) -> None:
        result = InspectCloudResult()

        def progress(stage: str, fraction: float) -> None:
            if stage != "done":  # "done" follows the report
                self.server.publish_feedback(InspectCloudFeedback(stage=stage, fraction=float(fraction)))

        try:
            progress("check", 0.0)
            request = self._request(goal)
            inspected, folder = run_inspection(request, progress)
        except AgiprobotError as exc:
            result.error = str(exc)
            rospy.logwarn("inspection: %s", result.error)
            self.server.set_aborted(result, result.error)
            return
        self.server.publish_feedback(InspectCloudFeedback(stage="done", fraction=1.0))
        self._publish_markers(inspected)
        result.success = True
        result.verdict = inspected.verdict
        result.surface_flags = int(inspected.flags)
        result.points = len(inspected.points_cad)
        result.registration_residual_mm = float(inspected.registration.residual_mm)
        result.report_dir = str(folder)
        result.features = [f"{feature.name}: {feature.verdict}" for feature in inspected.features]
        rospy.loginfo("inspection: %s, %d surface regions out of tolerance; report in %s",
                      result.verdict, result.surface_flags, folder)  # fmt: skip
        self.server.set_succeeded(result)

    def _publish_markers(self, inspected) -> None:
        """The inspected points back in the world frame (m), coloured by their patch's signed deviation."""
        world_mm = apply(np.linalg.inv(inspected.transform), inspected.points_cad)
        masked = inspected.edge | inspected.outlier
        rgb = deviation_colours(np.nan_to_num(inspected.smoothed_mm), inspected.spec.surface.tolerance_mm, masked)
        header = Header(frame_id=self.settings.frame_id, stamp=rospy.Time.now())
        self.markers.publish(deviation_markers(world_mm / 1000.0, rgb, header))


def main():
    run_node("inspection", InspectionNode)
