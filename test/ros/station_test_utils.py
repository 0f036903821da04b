"""Helpers shared by the rostest nodes of the station."""

import numpy as np
import rospy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from agiprobot_measurement.msg import ExecuteJointTrajectoryAction, ExecuteJointTrajectoryGoal, PlanMeasurementGoal
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.srv import SetJointState
from agiprobot_measurement.station import PACKAGE_ROOT, load_joint_limits, load_named_states

ACTION = "/robot_sim/execute_trajectory"
LIMITS = load_joint_limits()
NAMED = load_named_states()
JOINTS = list(LIMITS.names)
CUBE = str(PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl")


def quick_goal(solver_type: str = "IP_basic", **overrides) -> PlanMeasurementGoal:
    """A plan goal for the demo cube that plans in seconds (coarse sampling, 6 orientations, no tilts)."""
    goal = PlanMeasurementGoal(
        part_file=CUBE,
        units="mm",
        sampling_density=0.01,
        orientations_around_boresight=6,
        viewpoint_tilt_mode="none",
        solver_type=solver_type,
        uncertainty_threshold_mm=0.1,
    )
    for key, value in overrides.items():
        setattr(goal, key, value)
    return goal


def current_positions(timeout_s=20.0):  # a new subscriber may need seconds to connect on a loaded machine
    msg = rospy.wait_for_message("/joint_states", JointState, timeout=timeout_s)
    by_name = dict(zip(msg.name, msg.position, strict=True))
    return np.array([by_name[n] for n in JOINTS])


def place_robot(named_state="home"):
    rospy.wait_for_service("/ur_driver_sim/set_joint_state", timeout=20)
    reply = rospy.ServiceProxy("/ur_driver_sim/set_joint_state", SetJointState)(positions=[], named_state=named_state)
    assert reply.success, reply.message
    rospy.sleep(0.1)


def action_client():
    client = ActionClient(ACTION, ExecuteJointTrajectoryAction)
    assert client.wait_for_server(rospy.Duration(20.0)), f"no action server at {ACTION}"
    return client


def make_trajectory(points, times, velocities=None, accelerations=None, names=None):
    msg = JointTrajectory()
    msg.joint_names = list(names or JOINTS)
    for i, (q, t) in enumerate(zip(points, times, strict=True)):
        point = JointTrajectoryPoint()
        point.positions = list(q)
        point.velocities = list(velocities[i]) if velocities is not None else [0.0] * len(q)
        if accelerations is not None:
            point.accelerations = list(accelerations[i])
        point.time_from_start = rospy.Duration.from_sec(t)
        msg.points.append(point)
    return ExecuteJointTrajectoryGoal(trajectory=msg)
