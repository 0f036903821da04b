"""The robot_sim node maps the controller's outcomes to action results and service replies (no roscore)."""

import numpy as np
import pytest
import rospy
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg
from trajectory_msgs.msg import JointTrajectoryPoint

from agiprobot_measurement.motion.controller_sim import SimulatedController
from agiprobot_measurement.msg import ExecuteJointTrajectoryGoal
from agiprobot_measurement.ros.nodes import robot_sim
from agiprobot_measurement.srv import SetJointStateRequest
from agiprobot_measurement.station import load_joint_limits, load_named_states

LIMITS = load_joint_limits()
NAMED = load_named_states()
JOINTS = list(LIMITS.names)


class _Clock:
    def __init__(self):
        self.t, self.shutdown = 0.0, False

    def now_s(self):
        return self.t

    def is_shutdown(self):
        return self.shutdown

    def rate(self, rate_hz):
        clock = self

        class _Rate:
            def sleep(self):
                clock.t += 1.0 / rate_hz

        return _Rate()


class _Publisher:
    def publish_joint_state(self, joint_names, positions_rad, velocities_rad_s):
        pass


class _Server:
    def __init__(self, preempt=False):
        self.preempt = preempt
        self.calls = []
        self.feedback = []

    def is_preempt_requested(self):
        return self.preempt

    def publish_feedback(self, feedback):
        self.feedback.append((feedback.progress, feedback.time_from_start))

    def set_aborted(self, result, text):
        self.calls.append(("aborted", result.success, result.error, text))

    def set_preempted(self, result, text):
        self.calls.append(("preempted", result.success, result.error, text))

    def set_succeeded(self, result):
        self.calls.append(("succeeded", result.success, result.error))


def _node(server):
    node = object.__new__(robot_sim.RobotSimNode)
    node.controller = SimulatedController(JOINTS, LIMITS, NAMED, NAMED["home"], _Clock(), _Publisher(), 100.0)
    node.server = server
    return node


def _goal(delta_rad, duration_s, names=None, ragged=False):
    msg = JointTrajectoryMsg(joint_names=list(names or JOINTS))
    for t, q in ((0.0, NAMED["home"]), (duration_s, NAMED["home"] + np.asarray(delta_rad))):
        positions = list(q)[:-1] if ragged and t > 0 else list(q)
        msg.points.append(
            JointTrajectoryPoint(positions=positions, velocities=[0.0] * 6, time_from_start=rospy.Duration(t))
        )
    return ExecuteJointTrajectoryGoal(trajectory=msg)


@pytest.fixture(autouse=True)
def _quiet_logging(monkeypatch):
    for name in ("loginfo", "logwarn"):
        monkeypatch.setattr(robot_sim.rospy, name, lambda *args, **kwargs: None)
    monkeypatch.setattr(robot_sim.rospy, "is_shutdown", lambda: False)


def test_success_sets_succeeded_after_full_feedback():
    server = _Server()
    _node(server).execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0))
    assert server.calls == [("succeeded", True, "")]
    assert server.feedback[0] == (0.0, 0.0) and server.feedback[-1] == (1.0, 1.0)


def test_rejection_and_malformed_goals_abort_with_the_reason():
    server = _Server()
    node = _node(server)
    node.execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0, names=["gripper_joint", *JOINTS[1:]]))
    node.execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0, ragged=True))
    (first, second) = server.calls
    assert first[:2] == ("aborted", False) and first[2] == first[3] and "wrong joint names" in first[2]
    assert second[:2] == ("aborted", False) and second[2].startswith("malformed trajectory: ")
    assert server.feedback == []


def test_cancel_sets_preempted_with_the_stop_report():
    server = _Server(preempt=True)
    _node(server).execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0))
    ((status, success, error, text),) = server.calls
    assert (status, success) == ("preempted", False)
    assert error == text and text.startswith("cancelled after 0.00 s of 1.00 s; stopped at [")


def test_shutdown_while_following_aborts_quietly(monkeypatch):
    server = _Server()
    node = _node(server)
    node.controller.clock.shutdown = True
    node.execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0))
    assert server.calls == [
        ("aborted", False, "robot_sim shut down during the trajectory", "robot_sim shut down during the trajectory")
    ]

    def closed(result, text):
        raise rospy.ROSException("publish() to a closed topic")

    server = _Server()
    server.set_aborted = closed
    node = _node(server)
    node.controller.clock.shutdown = True
    node.execute(_goal([0.1, 0, 0, 0, 0, 0], 1.0))  # no traceback when the result topic is gone


def test_set_joint_state_replies():
    node = _node(_Server())
    reply = node.set_joint_state(SetJointStateRequest(positions=[], named_state="up"))
    assert reply.success and reply.message == f"robot placed at {np.round(NAMED['up'], 4).tolist()}"
    reply = node.set_joint_state(SetJointStateRequest(positions=[0.0] * 5, named_state=""))
    assert not reply.success and reply.message == "expected 6 positions, got 5"


def test_publish_after_shutdown_is_quiet(monkeypatch):
    # the timer firing while shutdown closes the topic printed a traceback
    node = _node(_Server())

    def closed():
        raise rospy.ROSException("publish() to a closed topic")

    def other():
        raise rospy.ROSException("some other failure")

    monkeypatch.setattr(robot_sim.rospy.core, "is_shutdown_requested", lambda: False)
    node.controller.publish_state = closed
    node.publish()  # the topic closes before is_shutdown() turns true: quiet
    node.controller.publish_state = other
    with pytest.raises(rospy.ROSException, match="other failure"):
        node.publish()  # anything else while running is still an error
    monkeypatch.setattr(robot_sim.rospy, "is_shutdown", lambda: True)
    node.publish()
