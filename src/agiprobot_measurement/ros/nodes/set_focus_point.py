"""The node ``set_focus_point`` (launched by nodes/set_focus_point): make the (simulated) MILD look at a 3-D focus
point (the procedure: :func:`agiprobot_measurement.mild.focus.focus_on`).

The point comes from ~point ("x y z", metres in the map frame: looked at once at start-up) and from /clicked_point
(geometry_msgs/PointStamped, rviz' "Publish Point" tool). For each point: the current state from /joint_states
(pan, tilt) and GetRobotPose (base), the PTU angles from CalculateCameraPoseCorrection (the camera's view axis
through the point, base fixed); when the PTU limits keep the camera from facing the point (checked with
CalculateCameraPose), the base turns in place towards the point first and the PTU is corrected again. The resulting
state goes to the simulated MILD's ~command_topic (/mild_sim/command).

Parameters: ~point (""), ~command_topic (/mild_sim/command), ~service_namespace (/asr_robot_model_services),
~facing_tolerance_deg (0.5).
"""

import math

import numpy as np
import rospy
from asr_robot_model_services.msg import RobotStateMessage
from asr_robot_model_services.srv import CalculateCameraPose, CalculateCameraPoseCorrection, GetPose
from geometry_msgs.msg import Point, PointStamped, Quaternion, Vector3
from sensor_msgs.msg import JointState

from agiprobot_measurement.common.config import ConfigError, number
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.mild.config import load_kinematics
from agiprobot_measurement.mild.focus import focus_on
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.conversions import pose_to_matrix
from agiprobot_measurement.ros.mild_messages import state_to_msg, yaw_of
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import param, text

__all__ = ["RobotModelServiceClient", "SetFocusPoint", "main"]


class RobotModelServiceClient:
    """:class:`agiprobot_measurement.mild.focus.FocusServices` answered by asr_robot_model_services."""

    def __init__(self, namespace: str):
        for name in ("GetRobotPose", "CalculateCameraPoseCorrection", "CalculateCameraPose"):
            rospy.wait_for_service(f"{namespace}/{name}", timeout=30.0)
        self.get_robot_pose = rospy.ServiceProxy(f"{namespace}/GetRobotPose", GetPose)
        self.correct = rospy.ServiceProxy(f"{namespace}/CalculateCameraPoseCorrection", CalculateCameraPoseCorrection)
        self.calculate_camera_pose = rospy.ServiceProxy(f"{namespace}/CalculateCameraPose", CalculateCameraPose)

    def camera_pose(self, state: RobotState) -> np.ndarray:
        return pose_to_matrix(self.calculate_camera_pose(state_to_msg(state)).cameraFrame)

    def pose_correction(self, state, orientation_xyzw, position_m):
        reply = self.correct(state_to_msg(state), Quaternion(*orientation_xyzw), Vector3(*position_m))
        return reply.pan, reply.tilt


class SetFocusPoint:
    def __init__(self):
        ns = param("~service_namespace", "/asr_robot_model_services").rstrip("/")
        self.kinematics = load_kinematics()
        self.tolerance_rad = math.radians(param("~facing_tolerance_deg", 0.5, number))
        self.services = RobotModelServiceClient(ns)
        self.view_distance_m = 0.5 * (param(f"{ns}/ncp", 0.4) + param(f"{ns}/fcp", 1.5))
        self.command = rospy.Publisher(param("~command_topic", "/mild_sim/command"), RobotStateMessage,
                                       queue_size=1, latch=True)  # fmt: skip
        rospy.Subscriber("/clicked_point", PointStamped, lambda msg: self.look_at(msg.point), queue_size=1)

    def current_state(self) -> RobotState:
        joints = rospy.wait_for_message("/joint_states", JointState, timeout=5.0)
        by_name = dict(zip(joints.name, joints.position, strict=True))
        pose = self.services.get_robot_pose().pose
        return RobotState(
            by_name[self.kinematics.pan_joint],
            by_name[self.kinematics.tilt_joint],
            yaw_of(pose.orientation),
            pose.position.x,
            pose.position.y,
        )

    def look_at(self, point_msg) -> None:
        point = np.array([point_msg.x, point_msg.y, point_msg.z], dtype=float)
        rospy.loginfo("set_focus_point: focus point (%.3f, %.3f, %.3f) m", *point)
        try:
            result = focus_on(self.services, self.current_state(), point, self.view_distance_m, self.tolerance_rad)
        except (rospy.ServiceException, rospy.ROSException, KeyError, AgiprobotError) as exc:
            rospy.logwarn("set_focus_point: cannot look at the point: %s", exc)
            return
        target = result.state
        if result.miss_rad > self.tolerance_rad:
            rospy.logwarn(
                "set_focus_point: the PTU limits leave the camera %.1f deg off the point (too high or too low)",
                math.degrees(result.miss_rad),
            )
        rospy.loginfo(
            "set_focus_point: moving to pan %.1f deg, tilt %.1f deg, rotation %.1f deg",
            math.degrees(target.pan),
            math.degrees(target.tilt),
            math.degrees(target.rotation),
        )
        self.command.publish(state_to_msg(target))


def _start() -> SetFocusPoint:
    tool = SetFocusPoint()
    point = param("~point", "", text).strip()
    if point:
        try:
            x, y, z = (float(v) for v in point.replace(",", " ").split())
        except ValueError:
            raise ConfigError(f"~point must be 'x y z' in metres, got {point!r}") from None
        rospy.sleep(0.5)  # let /joint_states arrive
        tool.look_at(Point(x, y, z))
    return tool


def main():
    run_node("set_focus_point", _start)
