"""The simulated UR10e node maps the controller's outcomes to actionlib states and results (no roscore)."""

import threading

import numpy as np
import pytest
import rospy
from control_msgs.msg import FollowJointTrajectoryGoal, JointTolerance
from trajectory_msgs.msg import JointTrajectory as JointTrajectoryMsg
from trajectory_msgs.msg import JointTrajectoryPoint

from agiprobot_measurement.motion.jtc import ErrorCode, JointTrajectoryController
from agiprobot_measurement.motion.trajectory import CheckTolerances
from agiprobot_measurement.msg import ExecuteJointTrajectoryGoal
from agiprobot_measurement.ros.nodes import ur_driver_sim
from agiprobot_measurement.station import load_joint_limits, load_named_states

LIMITS = load_joint_limits()
NAMED = load_named_states()
JOINTS = list(LIMITS.names)
CLOCK = {"t": 100.0}


class _Handle:
    def __init__(self, goal):
        self.goal = goal
        self.calls = []
        self.feedback = []

    def get_goal(self):
        return self.goal

    def set_accepted(self):
        self.calls.append(("accepted",))

    def set_rejected(self, result, text=""):
        self.calls.append(("rejected", result, text))

    def set_aborted(self, result, text=""):
        self.calls.append(("aborted", result, text))

    def set_canceled(self, result, text=""):
        self.calls.append(("canceled", result, text))

    def set_succeeded(self, result, text=""):
        self.calls.append(("succeeded", result, text))

    def publish_feedback(self, feedback):
        self.feedback.append(feedback)


class _Topic:
    def __init__(self):
        self.messages = []

    def publish(self, msg):
        self.messages.append(msg)


@pytest.fixture(autouse=True)
def _fake_ros(monkeypatch):
    CLOCK["t"] = 100.0
    monkeypatch.setattr(ur_driver_sim.rospy.Time, "now", staticmethod(lambda: rospy.Time.from_sec(CLOCK["t"])))
    for name in ("loginfo", "logwarn"):
        monkeypatch.setattr(ur_driver_sim.rospy, name, lambda *args, **kwargs: None)


def _node():
    node = object.__new__(ur_driver_sim.UrDriverSimNode)
    node.joint_names = JOINTS
    node.limits = LIMITS
    node.named_states = NAMED
    node.check_tolerances = CheckTolerances()
    node.per_joint_tolerances = {name: (0.2, 0.1) for name in JOINTS}
    node.lock = ur_driver_sim.threading.RLock()
    node.outbox = []
    node.controller = JointTrajectoryController(NAMED["home"], joint_names=JOINTS, now_s=CLOCK["t"])
    node.handles, node.aliases = {}, {}
    node.alphabetical = sorted(range(6), key=lambda i: JOINTS[i])
    node.joint_states, node.scaling, node.state_topic = _Topic(), _Topic(), _Topic()
    return node


def _run(node, seconds, dt=0.01):
    for _ in range(round(seconds / dt)):
        CLOCK["t"] += dt
        with node.lock:
            node.finish(node.controller.update(CLOCK["t"]))
            node.send_feedback(node.controller.snapshot(), rospy.Time.from_sec(CLOCK["t"]))
        node.deliver()  # as the control loop: results and feedback go out with no lock held


def _fjt(values, times, names=None, **fields):
    goal = FollowJointTrajectoryGoal(**fields)
    goal.trajectory = JointTrajectoryMsg(joint_names=list(names or JOINTS))
    for v, t in zip(values, times, strict=True):
        goal.trajectory.points.append(JointTrajectoryPoint(positions=[v] * 6, time_from_start=rospy.Duration(t)))
    return goal


def test_a_goal_succeeds_with_feedback():
    node = _node()
    handle = _Handle(_fjt([0.2], [1.0]))
    node.on_goal(handle)
    assert handle.calls == [("accepted",)]
    _run(node, 2.0)
    kind, result, _ = handle.calls[-1]
    assert (kind, result.error_code) == ("succeeded", 0)
    assert len(handle.feedback) > 10
    last = handle.feedback[-1]
    assert last.joint_names == JOINTS
    assert last.actual.time_from_start.to_sec() == pytest.approx(last.desired.time_from_start.to_sec())
    np.testing.assert_allclose(last.error.positions, np.subtract(last.desired.positions, last.actual.positions))


class _LockCheckingHandle(_Handle):
    """Records, for every result and feedback, whether another thread could take the node's lock at that moment."""

    def __init__(self, goal, lock):
        super().__init__(goal)
        self.lock, self.lock_free = lock, []

    def _check(self):
        got = []

        def probe():
            got.append(self.lock.acquire(timeout=1.0))
            if got[0]:
                self.lock.release()

        thread = threading.Thread(target=probe)
        thread.start()
        thread.join()
        self.lock_free.append(got[0])

    def set_canceled(self, result, text=""):
        self._check()
        super().set_canceled(result, text)

    def set_succeeded(self, result, text=""):
        self._check()
        super().set_succeeded(result, text)

    def publish_feedback(self, feedback):
        self._check()
        super().publish_feedback(feedback)


def test_results_and_feedback_go_out_with_the_node_lock_free():
    # actionlib calls the goal and cancel callbacks holding its server's lock, and they take the node's lock: a result
    # or feedback sent while the node's lock is held (it takes the server's lock) closes a deadlock cycle
    node = _node()
    first = _LockCheckingHandle(_fjt([0.2], [0.5]), node.lock)
    node.on_goal(first)
    _run(node, 1.0, dt=0.05)
    second = _LockCheckingHandle(_fjt([0.0], [3.0]), node.lock)
    node.on_goal(second)
    _run(node, 0.2, dt=0.05)
    node.on_cancel(second)
    _run(node, 0.1, dt=0.05)
    assert [c[0] for c in first.calls] == ["accepted", "succeeded"]
    assert [c[0] for c in second.calls] == ["accepted", "canceled"]
    assert first.lock_free and second.lock_free and all(first.lock_free + second.lock_free)


@pytest.mark.parametrize(
    ("goal", "code"),
    [
        (_fjt([0.2], [1.0], names=[*JOINTS[:5], "gripper"]), ErrorCode.INVALID_JOINTS),
        (_fjt([0.2, 0.3], [2.0, 1.0]), ErrorCode.INVALID_GOAL),
        (_fjt([], []), ErrorCode.INVALID_GOAL),
    ],
)
def test_bad_goals_are_rejected_with_the_code(goal, code):
    node = _node()
    handle = _Handle(goal)
    node.on_goal(handle)
    kind, result, text = handle.calls[-1]
    assert (kind, result.error_code) == ("rejected", code)
    assert result.error_string == text != ""


def test_a_new_goal_preempts_and_cancel_preempts():
    node = _node()
    first, second = _Handle(_fjt([0.5], [3.0])), _Handle(_fjt([0.0], [3.0]))
    node.on_goal(first)
    _run(node, 0.5)
    node.on_goal(second)
    node.deliver()  # the control loop's next tick
    assert first.calls[-1][0] == "canceled"
    node.on_cancel(second)
    node.deliver()
    assert second.calls[-1][0] == "canceled"
    assert second.calls[-1][1].error_code == 0


def test_controller_tolerances_fill_the_goal_defaults():
    node = _node()
    node.per_joint_tolerances[JOINTS[0]] = (0.01, 0.1)  # a strict path tolerance on shoulder_pan
    handle = _Handle(_fjt([0.0, -1.0], [0.1, 0.6]))
    node.on_goal(handle)
    _run(node, 2.0)
    kind, result, _ = handle.calls[-1]
    assert (kind, result.error_code) == ("aborted", ErrorCode.PATH_TOLERANCE_VIOLATED)
    assert result.error_string.startswith(f"{JOINTS[0]} path error ")
    # erased in the goal: the same motion passes
    node = _node()
    node.per_joint_tolerances[JOINTS[0]] = (0.01, 0.1)
    erased = [JointTolerance(name=JOINTS[0], position=-1.0)]
    handle = _Handle(_fjt([0.0, -1.0], [0.1, 0.6], path_tolerance=erased))
    node.on_goal(handle)
    _run(node, 2.0)
    assert handle.calls[-1][0] == "succeeded"


def test_joint_states_are_alphabetical():
    node = _node()
    node.publish(node.controller.snapshot(), 1.0, rospy.Time.from_sec(CLOCK["t"]), True)
    msg = node.joint_states.messages[-1]
    assert msg.name == sorted(JOINTS)
    by_name = dict(zip(msg.name, msg.position, strict=True))
    np.testing.assert_allclose([by_name[n] for n in JOINTS], NAMED["home"])
    assert node.scaling.messages[-1].data == 1.0
    assert node.state_topic.messages[-1].joint_names == JOINTS


def _alias_goal(target, duration_s, start=None):
    msg = JointTrajectoryMsg(joint_names=JOINTS)
    first = NAMED["home"] if start is None else start
    for t, q in ((0.0, first), (duration_s, target)):
        msg.points.append(
            JointTrajectoryPoint(positions=list(q), velocities=[0.0] * 6, time_from_start=rospy.Duration(t))
        )
    return ExecuteJointTrajectoryGoal(trajectory=msg)


def test_alias_keeps_the_strict_checks_and_replies():
    node = _node()
    handle = _Handle(_alias_goal(NAMED["home"] + 0.1, 2.0, start=NAMED["home"] + 0.3))
    node.on_alias_goal(handle)
    kind, result, _text = handle.calls[-1]
    assert kind == "aborted" and not result.success
    assert "does not start at the current state" in result.error
    handle = _Handle(_alias_goal(NAMED["home"] + 0.1, 2.0))
    node.on_alias_goal(handle)
    _run(node, 3.0)
    kind, result, _ = handle.calls[-1]
    assert kind == "succeeded" and result.success
    np.testing.assert_allclose(node.controller.positions(), NAMED["home"] + 0.1, atol=2e-4)
    assert 0.0 < handle.feedback[0].progress <= handle.feedback[-1].progress <= 1.0


def test_alias_cancel_stops_where_the_robot_is():
    node = _node()
    handle = _Handle(_alias_goal(NAMED["home"] - 0.5, 4.0))
    node.on_alias_goal(handle)
    _run(node, 1.0)
    assert handle.calls == [("accepted",)]
    node.on_alias_cancel(handle)
    node.deliver()
    kind, _result, text = handle.calls[-1]
    assert kind == "canceled" and text.startswith("cancelled after")
    stopped = node.controller.positions()
    _run(node, 1.0)
    np.testing.assert_allclose(node.controller.positions(), stopped, atol=1e-9)


def test_alias_single_point_at_the_current_state_succeeds_at_once():
    node = _node()
    msg = JointTrajectoryMsg(joint_names=JOINTS)
    msg.points.append(JointTrajectoryPoint(positions=list(NAMED["home"] + 0.005), time_from_start=rospy.Duration(0)))
    handle = _Handle(ExecuteJointTrajectoryGoal(trajectory=msg))
    node.on_alias_goal(handle)
    assert [c[0] for c in handle.calls] == ["accepted", "succeeded"]
    np.testing.assert_array_equal(node.controller.positions(), NAMED["home"] + 0.005)


def test_alias_success_is_exactly_at_the_end():
    node = _node()
    handle = _Handle(_alias_goal(NAMED["home"] - 0.3, 3.0))
    node.on_alias_goal(handle)
    assert handle.calls == [("accepted",)]
    _run(node, 4.0, dt=0.002)
    assert handle.calls[-1][0] == "succeeded"
    np.testing.assert_array_equal(node.controller.positions(), NAMED["home"] - 0.3)
