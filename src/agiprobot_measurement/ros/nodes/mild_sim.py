"""The node ``mild_sim`` (launched by nodes/mild_sim): the simulated MILD's joint states, its base pose on tf
(map -> base_link), and the commands that move it (the motion: :class:`agiprobot_measurement.mild.sim.MildMotion`).

Publishes /joint_states (pan and tilt, rad) and tf map -> base_link at ~publish_rate_hz, and ~state
(agiprobot_measurement/RobotStateMessage, the current state). robot_state_publisher turns the joint states into the
rest of the tf tree (urdf/mild.urdf.xacro).

Commands: topic ~command (RobotStateMessage): drive there, every axis at most at the speed limits of the kinematics
file and all axes finishing together (the base turns the shorter way round); a new command replaces the old one.
Service ~set_state (agiprobot_measurement/SetMildState): place the robot at once (simulation only).
Pan and tilt outside the PTU limits (the settings file, degrees) and non-finite values are refused.

Parameters: ~kinematics (config/mild_kinematics.yaml), ~frames (config/mild_robot_model_frames.yaml), ~settings
(config/mild_robot_model_services_sim.yaml), ~initial_state ([pan rad, tilt rad, rotation rad, x m, y m], default
[0, 0, 0, 1, 1]), ~publish_rate_hz (50).
"""

import numpy as np
import rospy
import tf2_ros
from asr_robot_model_services.msg import RobotStateMessage
from sensor_msgs.msg import JointState

from agiprobot_measurement.common.config import ConfigError, number
from agiprobot_measurement.common.geometry import pose_from_quaternion, yaw_quaternion
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.mild.config import load_kinematics, load_settings
from agiprobot_measurement.mild.sim import MildMotion, MotionRefused
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.conversions import transform_stamped
from agiprobot_measurement.ros.mild_messages import state_from_msg, state_to_msg
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import file_param, param
from agiprobot_measurement.srv import SetMildState, SetMildStateResponse

__all__ = ["MildSim", "main"]


def _base_pose(state: RobotState) -> np.ndarray:
    """map <- base_link (4x4) of a state: the base at (x, y) on the floor, turned by its rotation."""
    return pose_from_quaternion((state.x, state.y, 0.0), yaw_quaternion(state.rotation))


class MildSim:
    def __init__(self):
        self.kinematics = load_kinematics(file_param("~kinematics"), file_param("~frames"))
        settings = load_settings(file_param("~settings"))
        initial = param("~initial_state", [0.0, 0.0, 0.0, 1.0, 1.0])
        try:
            state = RobotState.from_array(initial)
        except ValueError as exc:
            raise ConfigError(f"~initial_state: expected [pan, tilt, rotation, x, y], got {initial!r}") from exc
        try:
            self.motion = MildMotion(
                state, settings.pan_limits_rad, settings.tilt_limits_rad, self.kinematics.max_velocity
            )
        except MotionRefused as exc:
            raise ConfigError(f"~initial_state: {exc}") from exc
        frames = self.kinematics.frames
        self.map_frame, self.base_frame = frames.map_frame, frames.base_frame
        self.joint_publisher = rospy.Publisher("joint_states", JointState, queue_size=10)
        self.state_publisher = rospy.Publisher("~state", RobotStateMessage, queue_size=10)
        self.broadcaster = tf2_ros.TransformBroadcaster()
        rospy.Subscriber("~command", RobotStateMessage, self.on_command, queue_size=1)
        rospy.Service("~set_state", SetMildState, self.set_state)
        self.rate_hz = param("~publish_rate_hz", 50.0, number)
        self.timer = rospy.Timer(rospy.Duration(1.0 / self.rate_hz), self.tick)
        rospy.loginfo("mild_sim: MILD at %s (pan, tilt, rotation, x, y)", np.round(state.as_array(), 4).tolist())

    def set_state(self, request):
        state = state_from_msg(request.state)
        try:
            self.motion.place(state)
        except AgiprobotError as exc:
            return SetMildStateResponse(False, f"refused: {exc}")
        return SetMildStateResponse(True, f"MILD placed at {np.round(state.as_array(), 4).tolist()}")

    def on_command(self, msg):
        target = state_from_msg(msg)
        try:
            duration = self.motion.command(target, rospy.get_time())
        except AgiprobotError as exc:
            rospy.logwarn("mild_sim: command refused: %s", exc)
            return
        rospy.loginfo("mild_sim: moving to %s in %.2f s", np.round(target.as_array(), 4).tolist(), duration)

    def tick(self, _event=None):
        state = self.motion.state_at(rospy.get_time())
        stamp = rospy.Time.now()
        joints = JointState()
        joints.header.stamp = stamp
        joints.name = [self.kinematics.pan_joint, self.kinematics.tilt_joint]
        joints.position = [state.pan, state.tilt]
        self.joint_publisher.publish(joints)
        self.broadcaster.sendTransform(transform_stamped(_base_pose(state), self.map_frame, self.base_frame, stamp))
        self.state_publisher.publish(state_to_msg(state))


def main():
    run_node("mild_sim", MildSim)
