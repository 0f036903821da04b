"""Helpers shared by the rostest nodes of the MILD robot model services."""

import math

import numpy as np
import rospy
import tf2_ros
from asr_robot_model_services.srv import (
    CalculateCameraPose,
    CalculateCameraPoseCorrection,
    GetDistance,
    GetPose,
    IsPositionAllowed,
)

from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.ros.mild_messages import state_to_msg
from agiprobot_measurement.srv import CalculateRobotState, SetMildState

NS = "/asr_robot_model_services"
SERVICE_TYPES = {
    "CalculateCameraPose": CalculateCameraPose,
    "CalculateCameraPoseCorrection": CalculateCameraPoseCorrection,
    "GetDistance": GetDistance,
    "GetRobotPose": GetPose,
    "GetCameraPose": GetPose,
    "IsPositionAllowed": IsPositionAllowed,
    "CalculateRobotState": CalculateRobotState,
}


def proxies(timeout_s=30.0) -> dict:
    out = {}
    for name, service_type in SERVICE_TYPES.items():
        rospy.wait_for_service(f"{NS}/{name}", timeout=timeout_s)
        out[name] = rospy.ServiceProxy(f"{NS}/{name}", service_type)
    rospy.wait_for_service("/mild_sim/set_state", timeout=timeout_s)
    out["set_state"] = rospy.ServiceProxy("/mild_sim/set_state", SetMildState)
    return out


def place(services, state: RobotState) -> None:
    reply = services["set_state"](state_to_msg(state))
    assert reply.success, reply.message


def wait_for_camera(buffer: tf2_ros.Buffer, expected: np.ndarray, timeout_s=10.0, atol=1e-4) -> np.ndarray:
    """The camera mount pose from tf once it matches ``expected`` (4x4), or the last one seen after the timeout."""
    deadline = rospy.get_time() + timeout_s
    pose = None
    while rospy.get_time() < deadline and not rospy.is_shutdown():
        try:
            pose = transform_to_matrix(buffer.lookup_transform("map", "ptu_mount_link", rospy.Time(0)))
            if np.allclose(pose, expected, atol=atol):
                return pose
        except tf2_ros.TransformException:
            pass
        rospy.sleep(0.05)
    return pose


def facing_error_deg(camera_pose: np.ndarray, point: np.ndarray) -> float:
    to_point = np.asarray(point, dtype=float) - camera_pose[:3, 3]
    cosine = camera_pose[:3, 0] @ to_point / np.linalg.norm(to_point)
    return math.degrees(math.acos(float(np.clip(cosine, -1.0, 1.0))))
