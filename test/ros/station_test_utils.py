"""Helpers shared by the rostest nodes of the station."""

import threading

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


class _JointStates:
    """One subscriber to /joint_states for the whole test process: a subscriber per call had to connect anew each
    time, which took more than 20 s once on a loaded machine."""

    def __init__(self):
        self.condition = threading.Condition()
        self.received = 0
        self.latest = None
        self.subscriber = rospy.Subscriber("/joint_states", JointState, self._on_message, queue_size=1)

    def _on_message(self, msg):
        with self.condition:
            self.latest, self.received = msg, self.received + 1
            self.condition.notify_all()

    def next_message(self, timeout_s):
        """The first message received after this call."""
        with self.condition:
            seen = self.received
            if not self.condition.wait_for(lambda: self.received > seen, timeout=timeout_s):
                raise rospy.ROSException(f"no message on /joint_states within {timeout_s} s")
            return self.latest


_JOINT_STATES = []


def current_positions(timeout_s=20.0):
    """The joint positions (rad, JOINTS order) of the next /joint_states message."""
    if not _JOINT_STATES:
        _JOINT_STATES.append(_JointStates())
    msg = _JOINT_STATES[0].next_message(timeout_s)
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
