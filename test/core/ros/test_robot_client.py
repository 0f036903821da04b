"""The robot motion client: outcome mapping, the checks before sending, the program watch and the wait loop
(no roscore: a scripted action client stands for actionlib)."""

import threading
import time

import numpy as np
import pytest
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import FollowJointTrajectoryFeedback, FollowJointTrajectoryResult
from moveit_msgs.msg import ExecuteTrajectoryGoal, MoveItErrorCodes
from moveit_msgs.msg import ExecuteTrajectoryResult as MoveItResult

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.plan.execution import ControllerLost, ExecutionCancelled, ExecutionError
from agiprobot_measurement.ros import robot_client
from agiprobot_measurement.ros.robot_client import (
    FJT_ACTION,
    MOVEIT_ACTION,
    FollowJointTrajectoryClient,
    GoalOutcome,
    MotionSettings,
    MoveItExecuteClient,
    RobotProgramWatch,
    RobotStopped,
    TrajectoryRefused,
    code_names,
    describe_outcome,
    executor_kind,
)
from agiprobot_measurement.station import load_joint_limits, load_named_states

LIMITS = load_joint_limits()
NAMED = load_named_states()
FJT_NAMES = code_names(FollowJointTrajectoryResult)


def test_code_names_are_the_messages_constants():
    assert (
        FJT_NAMES[-1] == "INVALID_GOAL" and FJT_NAMES[-4] == "PATH_TOLERANCE_VIOLATED" and FJT_NAMES[0] == "SUCCESSFUL"
    )
    moveit = code_names(MoveItErrorCodes)
    assert moveit[1] == "SUCCESS" and moveit[-4] == "CONTROL_FAILED" and moveit[-7] == "PREEMPTED"


@pytest.mark.parametrize(
    ("outcome", "expected", "words"),
    [
        (GoalOutcome(GoalStatus.SUCCEEDED, 0), None, []),
        (GoalOutcome(GoalStatus.SUCCEEDED, -5), ExecutionError, ["GOAL_TOLERANCE_VIOLATED (-5)"]),
        (GoalOutcome(GoalStatus.REJECTED, -2, "names"), ExecutionError, ["REJECTED", "INVALID_JOINTS (-2)", "names"]),
        (
            GoalOutcome(GoalStatus.ABORTED, -4, "elbow_joint path error 0.3"),
            ExecutionError,
            ["ABORTED", "PATH_TOLERANCE_VIOLATED (-4)", "elbow_joint path error 0.3"],
        ),
        (GoalOutcome(GoalStatus.PREEMPTED, 0, cancel_sent=True), ExecutionCancelled, ["cancelled"]),
        (GoalOutcome(GoalStatus.PREEMPTED, 0), RobotStopped, ["preempted", "not asked by this client"]),
        (
            GoalOutcome(GoalStatus.PREEMPTED, 0, stop_reason="the robot program stopped"),
            RobotStopped,
            ["preempted", "the robot program stopped"],
        ),
        (
            GoalOutcome(GoalStatus.REJECTED, -1, stop_reason="the robot program stopped"),
            ExecutionError,
            ["INVALID_GOAL (-1)", "the robot program stopped"],
        ),
    ],
)
def test_follow_joint_trajectory_outcomes(outcome, expected, words):
    error = describe_outcome(FJT_ACTION, outcome, 0, FJT_NAMES, FollowJointTrajectoryClient.hints)
    if expected is None:
        assert error is None
        return
    assert type(error) is expected
    for word in words:
        assert word in str(error)


def test_a_preempted_result_is_never_a_success_although_its_code_is_zero():
    # the JTC answers a cancel or a stopped controller with PREEMPTED and error_code 0 (SUCCESSFUL)
    error = describe_outcome(FJT_ACTION, GoalOutcome(GoalStatus.PREEMPTED, 0), 0, FJT_NAMES)
    assert error is not None


def test_moveit_outcomes_use_its_success_code():
    names, hints = MoveItExecuteClient.names, MoveItExecuteClient.hints
    assert describe_outcome(MOVEIT_ACTION, GoalOutcome(GoalStatus.SUCCEEDED, 1), 1, names) is None
    failed = describe_outcome(MOVEIT_ACTION, GoalOutcome(GoalStatus.ABORTED, -4), 1, names, hints)
    assert "CONTROL_FAILED (-4)" in str(failed)
    timed_out = describe_outcome(MOVEIT_ACTION, GoalOutcome(GoalStatus.ABORTED, -6), 1, names, hints)
    assert "TIMED_OUT" in str(timed_out) and "allowed_execution_duration_scaling" in str(timed_out)
    # SUCCEEDED with FollowJointTrajectory's success code 0 is no MoveIt success
    assert describe_outcome(MOVEIT_ACTION, GoalOutcome(GoalStatus.SUCCEEDED, 0), 1, names) is not None


def test_executor_parameter():
    assert executor_kind("moveit", "~executor") == "moveit"
    with pytest.raises(ConfigError, match="~executor"):
        executor_kind("movit", "~executor")
    assert MotionSettings().action == FJT_ACTION
    assert MotionSettings("moveit").action == MOVEIT_ACTION
    assert MotionSettings("moveit", "/my/execute").action == "/my/execute"


def _watch(running, safety=None):
    watch = RobotProgramWatch.__new__(RobotProgramWatch)
    watch.program_topic = robot_client.PROGRAM_RUNNING_TOPIC
    watch._lock = threading.Lock()
    watch._running, watch._safety = running, safety
    return watch


def test_program_watch_says_why_the_robot_stands():
    assert _watch(None).stop_reason() == ""  # a controller without the UR driver's topics
    assert _watch(True).stop_reason() == ""
    reason = _watch(False).stop_reason()
    assert "robot program stopped" in reason and robot_client.PROGRAM_RUNNING_TOPIC in reason


class _ScriptedAction:
    """Stands for the actionlib client: the goal ends after ``steps`` polls with ``state`` and ``result``;
    ``on_poll(i)`` runs at each poll."""

    def __init__(self, state, result, steps=3, on_poll=None, feedback=None):
        self.state, self.result, self.steps, self.on_poll = state, result, steps, on_poll
        self.feedback = feedback or []
        self.goals, self.cancels, self.polls = [], 0, 0

    def send_goal(self, goal, feedback_cb=None):
        self.goals.append(goal)
        for message in self.feedback:
            feedback_cb(message)

    def wait_for_result(self, timeout=None):
        if self.cancels:
            self.state = GoalStatus.PREEMPTED
            return True
        self.polls += 1
        if self.on_poll is not None:
            self.on_poll(self.polls)
        return self.polls > self.steps

    def get_state(self):
        return self.state

    def get_result(self):
        return self.result

    def cancel_goal(self):
        self.cancels += 1


def _client(cls, action, state, program=None):
    client = cls.__new__(cls)
    client.action = FJT_ACTION if cls is FollowJointTrajectoryClient else MOVEIT_ACTION
    client.limits = LIMITS
    client.current_state = lambda: state
    client.program = program
    client.tolerances = robot_client.DEFAULT_TOLERANCES
    client.poll_s = 0.001
    client.client = action
    client._progress_lock = threading.Lock()
    client._progress, client._duration_s, client._cancel_sent = 0.0, 0.0, False
    return client


def _move(start=NAMED["home"], goal=NAMED["up"]) -> JointTrajectory:
    return point_to_point(np.asarray(start), np.asarray(goal), LIMITS, 0.5, 0.5)


def test_the_client_refuses_a_start_away_from_the_robot_before_sending():
    action = _ScriptedAction(GoalStatus.SUCCEEDED, FollowJointTrajectoryResult(error_code=0))
    client = _client(FollowJointTrajectoryClient, action, np.asarray(NAMED["home"]) + 0.02)
    with pytest.raises(TrajectoryRefused, match="does not start at the current state"):
        client.execute(_move())
    assert action.goals == []
    within = _client(FollowJointTrajectoryClient, action, np.asarray(NAMED["home"]) + 0.005)
    within.execute(_move())  # MoveIt's allowed_start_tolerance is 0.01 rad
    assert len(action.goals) == 1


def test_the_client_refuses_a_limit_violation_and_an_unknown_state():
    action = _ScriptedAction(GoalStatus.SUCCEEDED, FollowJointTrajectoryResult(error_code=0))
    fast = _move()
    fast = JointTrajectory(fast.joint_names, fast.time_from_start / 10.0, fast.positions)
    with pytest.raises(TrajectoryRefused, match="limit violated"):
        _client(FollowJointTrajectoryClient, action, NAMED["home"]).execute(fast)
    with pytest.raises(TrajectoryRefused, match="joint_states"):
        _client(FollowJointTrajectoryClient, action, None).execute(_move())
    assert action.goals == []


def test_the_joint_order_of_the_trajectory_is_free():
    action = _ScriptedAction(GoalStatus.SUCCEEDED, FollowJointTrajectoryResult(error_code=0))
    move = _move()
    alphabetical = sorted(move.joint_names)
    _client(FollowJointTrajectoryClient, action, NAMED["home"]).execute(move.reordered(alphabetical))
    assert list(action.goals[0].trajectory.joint_names) == alphabetical


def test_fjt_success_sends_the_trajectory_and_reports_progress():
    move = _move()
    feedback = FollowJointTrajectoryFeedback()
    feedback.actual.time_from_start.secs = int(move.duration / 2)
    feedback.actual.time_from_start.nsecs = int((move.duration / 2 % 1) * 1e9)
    seen = []
    action = _ScriptedAction(GoalStatus.SUCCEEDED, FollowJointTrajectoryResult(error_code=0), feedback=[feedback])
    client = _client(FollowJointTrajectoryClient, action, NAMED["home"])
    action.on_poll = lambda i: seen.append(client.progress)
    client.execute(move)
    sent = action.goals[0].trajectory
    assert len(sent.points) == len(move) and np.allclose(sent.points[-1].positions, move.end)
    assert seen[0] == pytest.approx(0.5, abs=0.01) and client.progress == 1.0


def test_fjt_aborted_names_the_code_and_text():
    result = FollowJointTrajectoryResult(error_code=-4, error_string="wrist_1_joint path error 0.25")
    action = _ScriptedAction(GoalStatus.ABORTED, result)
    with pytest.raises(ExecutionError, match=r"PATH_TOLERANCE_VIOLATED \(-4\): wrist_1_joint path error 0.25"):
        _client(FollowJointTrajectoryClient, action, NAMED["home"]).execute(_move())


def test_a_program_that_stops_ends_the_wait_at_once_and_cancels():
    watch = _watch(True)

    def stop(poll):
        if poll == 2:
            watch._running = False

    action = _ScriptedAction(GoalStatus.ACTIVE, None, steps=10**6, on_poll=stop)
    with pytest.raises(RobotStopped, match="robot program stopped"):
        _client(FollowJointTrajectoryClient, action, NAMED["home"], watch).execute(_move())
    assert action.cancels == 1 and action.polls == 2


def test_a_protective_stop_names_both_topics_whichever_arrives_first():
    # a protective stop changes the program and the safety topic; under load the program topic may come well before
    # the safety one: the reason waits for the second (but returns as soon as both tell)
    pytest.importorskip("ur_dashboard_msgs.msg")
    for first, second in ((("_running", False), ("_safety", 3)), (("_safety", 3), ("_running", False))):
        watch = _watch(True, 1)

        def stop(poll, watch=watch, first=first, second=second):
            if poll == 2:
                setattr(watch, *first)
                threading.Timer(0.25, lambda: setattr(watch, *second)).start()

        # the topic seen while the goal runs, or the controller's PREEMPTED first and the topic with the result
        for state, steps in ((GoalStatus.ACTIVE, 10**6), (GoalStatus.PREEMPTED, 1)):
            watch._running, watch._safety = True, 1
            action = _ScriptedAction(state, FollowJointTrajectoryResult(error_code=0), steps=steps, on_poll=stop)
            started = time.monotonic()
            with pytest.raises(RobotStopped, match=r"PROTECTIVE_STOP.*robot program stopped"):
                _client(FollowJointTrajectoryClient, action, NAMED["home"], watch).execute(_move())
            assert time.monotonic() - started < robot_client.SECOND_TOPIC_WAIT_S + 0.2


def test_a_stopped_program_refuses_before_sending():
    action = _ScriptedAction(GoalStatus.SUCCEEDED, FollowJointTrajectoryResult(error_code=0))
    with pytest.raises(RobotStopped, match="not sent"):
        _client(FollowJointTrajectoryClient, action, NAMED["home"], _watch(False)).execute(_move())
    assert action.goals == []


def test_cancel_and_a_lost_controller_cancel_the_goal():
    action = _ScriptedAction(GoalStatus.ACTIVE, None, steps=10**6)
    client = _client(FollowJointTrajectoryClient, action, NAMED["home"])
    with pytest.raises(ExecutionCancelled):
        client.execute(_move(), cancel_requested=lambda: action.polls >= 3)
    assert action.cancels == 1
    action = _ScriptedAction(GoalStatus.ACTIVE, None, steps=10**6)
    client = _client(FollowJointTrajectoryClient, action, NAMED["home"])
    with pytest.raises(ControllerLost, match="gone"):
        client.execute(_move(), controller_problem=lambda: "gone" if action.polls >= 2 else "")
    assert action.cancels == 1


def test_moveit_goal_carries_the_trajectory_and_maps_its_codes():
    move = _move()
    ok = _ScriptedAction(GoalStatus.SUCCEEDED, MoveItResult(error_code=MoveItErrorCodes(val=1)))
    _client(MoveItExecuteClient, ok, NAMED["home"]).execute(move)
    goal = ok.goals[0]
    assert isinstance(goal, ExecuteTrajectoryGoal)
    assert np.allclose(goal.trajectory.joint_trajectory.points[-1].positions, move.end)
    failed = _ScriptedAction(GoalStatus.ABORTED, MoveItResult(error_code=MoveItErrorCodes(val=-4)))
    with pytest.raises(ExecutionError, match="CONTROL_FAILED"):
        _client(MoveItExecuteClient, failed, NAMED["home"]).execute(move)


def test_an_unasked_preemption_waits_briefly_for_the_program_topic_to_say_why():
    # the controller's PREEMPTED can arrive before the latched program topic: the client waits for the reason
    watch = _watch(True)
    result = FollowJointTrajectoryResult(error_code=0)
    action = _ScriptedAction(GoalStatus.PREEMPTED, result, steps=1)
    client = _client(FollowJointTrajectoryClient, action, NAMED["home"], watch)
    real_wait = action.wait_for_result

    def finished(timeout=None):
        done = real_wait(timeout)
        if done:
            threading.Timer(0.1, lambda: setattr(watch, "_running", False)).start()
        return done

    action.wait_for_result = finished
    with pytest.raises(RobotStopped, match="robot program stopped"):
        client.execute(_move())
    # without a watch the preemption is reported as unexplained, at once
    bare = _client(FollowJointTrajectoryClient, _ScriptedAction(GoalStatus.PREEMPTED, result, steps=1), NAMED["home"])
    with pytest.raises(RobotStopped, match="not asked by this client"):
        bare.execute(_move())


def test_a_cancel_returns_once_the_robot_stands():
    # a joint trajectory controller ends a cancelled goal at once and brakes for 0.5 s afterwards
    import time

    cancelled_at = {}
    start = np.asarray(NAMED["home"], dtype=float)

    def braking():
        if "t" not in cancelled_at:
            return start
        left = max(0.0, 0.3 - (time.monotonic() - cancelled_at["t"]))
        return start + left  # moving until 0.3 s after the cancel

    action = _ScriptedAction(GoalStatus.ACTIVE, None, steps=10**6)
    client = _client(FollowJointTrajectoryClient, action, NAMED["home"])
    client.current_state = braking
    real_cancel = action.cancel_goal

    def cancel_goal():
        cancelled_at["t"] = time.monotonic()
        real_cancel()

    action.cancel_goal = cancel_goal
    client.check = lambda trajectory: None
    with pytest.raises(ExecutionCancelled):
        client.execute(_move(), cancel_requested=lambda: action.polls >= 2)
    assert time.monotonic() - cancelled_at["t"] >= 0.3
    assert np.allclose(braking(), start)


def test_a_one_point_trajectory_at_the_robot_is_not_sent():
    # a joint trajectory controller refuses a goal whose only point lies at time 0
    action = _ScriptedAction(GoalStatus.REJECTED, FollowJointTrajectoryResult(error_code=-1))
    here = point_to_point(np.asarray(NAMED["home"]), np.asarray(NAMED["home"]), LIMITS)
    assert len(here) == 1
    _client(FollowJointTrajectoryClient, action, NAMED["home"]).execute(here)
    assert action.goals == []
    with pytest.raises(TrajectoryRefused):  # still checked: one point away from the robot is refused
        _client(FollowJointTrajectoryClient, action, np.asarray(NAMED["home"]) + 0.1).execute(here)
