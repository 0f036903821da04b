"""Robot motion over ROS: one small client interface the executors use, in front of the robot's trajectory action.

Two clients, chosen by the parameter ``executor`` (read once, :func:`read_motion_settings`):

- :class:`FollowJointTrajectoryClient` (``follow_joint_trajectory``, the default): control_msgs/FollowJointTrajectory,
  the action a UR10e's Universal_Robots_ROS_Driver serves on :data:`FJT_ACTION` (and the simulated controller too).
  Success is SUCCEEDED with ``error_code`` SUCCESSFUL (0); progress is the feedback's ``actual.time_from_start``
  (trajectory time elapsed, slowed by the speed slider) over the last point's time.
- :class:`MoveItExecuteClient` (``moveit``): moveit_msgs/ExecuteTrajectory on :data:`MOVEIT_ACTION`, move_group's
  execute capability (a MoveIt user keeps their move_group and its controller list). Success is SUCCEEDED with
  ``error_code.val`` SUCCESS (1); cancel = cancel the goal.

The real controller checks neither the start state nor the limits (a joint trajectory controller interpolates from
wherever the robot stands, and a UR slows down or protective-stops instead of refusing), so the CLIENT refuses a
trajectory before sending it (:class:`TrajectoryRefused`): its first point must lie within
:data:`START_TOLERANCE_RAD` of ``/joint_states`` (MoveIt's ``allowed_start_tolerance``) and it must meet the
station's position / velocity / acceleration limits (``motion.trajectory.check_trajectory``).

While a goal runs the client watches the UR program (:class:`RobotProgramWatch`: the latched
``/ur_hardware_interface/robot_program_running``, and the safety mode when ur_dashboard_msgs is installed): a program
that stops ends the wait at once with :class:`RobotStopped` saying why, instead of waiting for the controller's
PREEMPTED; a PREEMPTED this client did not ask for is reported with the reason it knows. REJECTED / ABORTED become
:class:`~agiprobot_measurement.planning.plan.execution.ExecutionError` naming the error code and the server's
error_string. Times s, joint values rad.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import rospy
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal, FollowJointTrajectoryResult
from moveit_msgs.msg import ExecuteTrajectoryAction, ExecuteTrajectoryGoal, MoveItErrorCodes, RobotTrajectory
from std_msgs.msg import Bool

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.motion.trajectory import CheckTolerances, JointTrajectory, check_trajectory
from agiprobot_measurement.planning.plan.execution import ControllerLost, ExecutionCancelled, ExecutionError
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.ros.conversions import joint_trajectory_to_msg
from agiprobot_measurement.ros.params import Param, read_params, text
from agiprobot_measurement.station.config import JointLimits

try:  # only for the explanation of a protective stop; the client works without it
    from ur_dashboard_msgs.msg import SafetyMode
except ImportError:  # pragma: no cover - depends on the machine
    SafetyMode = None

__all__ = [
    "DEFAULT_MOTION",
    "EXECUTORS",
    "FJT_ACTION",
    "MOVEIT_ACTION",
    "PROGRAM_RUNNING_TOPIC",
    "START_TOLERANCE_RAD",
    "FollowJointTrajectoryClient",
    "GoalOutcome",
    "MotionSettings",
    "MoveItExecuteClient",
    "RobotMotionClient",
    "RobotProgramWatch",
    "RobotStopped",
    "TrajectoryRefused",
    "code_names",
    "executor_kind",
    "make_motion_client",
    "motion_parameters",
    "read_motion_settings",
]

#: the UR driver's trajectory action (Universal_Robots_ROS_Driver's scaled joint trajectory controller)
FJT_ACTION = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"
#: move_group's execute capability
MOVEIT_ACTION = "/execute_trajectory"
#: the UR driver's latched std_msgs/Bool: true while the External Control program runs
PROGRAM_RUNNING_TOPIC = "/ur_hardware_interface/robot_program_running"
#: the UR driver's latched ur_dashboard_msgs/SafetyMode
SAFETY_MODE_TOPIC = "/ur_hardware_interface/safety_mode"
#: the checks before sending: the first point vs. /joint_states within start_rad 0.01 (MoveIt's
#: allowed_start_tolerance), the joint limits with the simulator's former tolerances
DEFAULT_TOLERANCES = CheckTolerances()
START_TOLERANCE_RAD = DEFAULT_TOLERANCES.start_rad
#: the executor kinds and the action each talks to by default
EXECUTORS = {"follow_joint_trajectory": FJT_ACTION, "moveit": MOVEIT_ACTION}
#: how long an unasked PREEMPTED waits for the program topic to tell why (s)
PREEMPT_REASON_WAIT_S = 0.5
#: once one of the driver's state topics tells why, how long to wait for the other (s): a protective stop changes
#: both, on two connections whose order and delay a loaded machine does not keep; the wait ends as soon as both tell
SECOND_TOPIC_WAIT_S = 0.5
#: how long a cancelled goal may take to end (s): the UR holds within stop_trajectory_duration 0.5 s
CANCEL_WAIT_S = 2.0
#: after a cancel or a stop the robot counts as standing once no joint moved more than STILL_RAD (rad) for
#: STILL_FOR_S (s); the wait ends after CANCEL_WAIT_S anyway (a noisy or silent /joint_states)
STILL_RAD = 1e-5
STILL_FOR_S = 0.1


class TrajectoryRefused(ExecutionError):
    """The client refused a trajectory before sending it (start away from the robot, a limit violated)."""


class RobotStopped(ExecutionError):
    """The robot program stopped or the robot protective-stopped while a trajectory ran (the robot stands)."""


def code_names(result_class) -> dict[int, str]:
    """The names of a result's integer constants by value (``FollowJointTrajectoryResult``: -1 -> INVALID_GOAL)."""
    names: dict[int, str] = {}
    for name in dir(result_class):
        value = getattr(result_class, name)
        if name.isupper() and isinstance(value, int) and not isinstance(value, bool):
            names.setdefault(value, name)
    return names


@dataclass(frozen=True)
class GoalOutcome:
    """How a goal ended: the actionlib state (GoalStatus value), the server's error code and text, whether this
    client had cancelled it, and the robot's stop reason known at the end ('' if none)."""

    state: int
    error_code: int
    error_string: str = ""
    cancel_sent: bool = False
    stop_reason: str = ""


def describe_outcome(
    action: str, outcome: GoalOutcome, success_code: int, names: dict[int, str], hints: dict[int, str] | None = None
) -> Exception | None:
    """None when ``outcome`` is a success (SUCCEEDED and ``success_code``), else the error to raise: cancelled by us
    -> ExecutionCancelled; preempted unasked -> RobotStopped with the reason known; REJECTED / ABORTED (or a
    SUCCEEDED with another code) -> ExecutionError naming the state, the code's name and the server's text."""
    state_name = GoalStatus.to_string(outcome.state) if outcome.state is not None else "NO RESULT"
    if outcome.state == GoalStatus.SUCCEEDED and outcome.error_code == success_code:
        return None
    if outcome.state in (GoalStatus.PREEMPTED, GoalStatus.RECALLED) and outcome.cancel_sent:
        return ExecutionCancelled("cancelled; robot stopped")
    if outcome.state in (GoalStatus.PREEMPTED, GoalStatus.RECALLED):
        why = outcome.stop_reason or (
            "not asked by this client: another goal replaced it, or the controller was stopped (a UR stops its "
            "controller when the robot program stops or pauses)"
        )
        return RobotStopped(f"{action}: the controller preempted the trajectory: {why}")
    code = f"{names.get(outcome.error_code, 'unknown error code')} ({outcome.error_code})"
    text_part = f": {outcome.error_string}" if outcome.error_string else ""
    hint = (hints or {}).get(outcome.error_code, "")
    if outcome.state == GoalStatus.REJECTED and outcome.stop_reason:
        hint = f"{hint}; {outcome.stop_reason}" if hint else outcome.stop_reason
    return ExecutionError(f"{action} {state_name}: {code}{text_part}{f' ({hint})' if hint else ''}")


class RobotProgramWatch:
    """The UR program's state from the driver's latched topics: ``stop_reason()`` is '' while the program runs (or
    nothing is known: a controller without the UR driver's topics), else why the robot does not move."""

    def __init__(self, program_topic: str = PROGRAM_RUNNING_TOPIC, safety_topic: str = SAFETY_MODE_TOPIC):
        self.program_topic = program_topic
        self._lock = threading.Lock()
        self._running: bool | None = None
        self._safety: int | None = None
        self._subscribers = [rospy.Subscriber(program_topic, Bool, self._on_program, queue_size=10)]
        if SafetyMode is not None:
            self._subscribers.append(rospy.Subscriber(safety_topic, SafetyMode, self._on_safety, queue_size=10))

    def _on_program(self, msg: Bool) -> None:
        with self._lock:
            self._running = bool(msg.data)

    def _on_safety(self, msg) -> None:
        with self._lock:
            self._safety = int(msg.mode)

    @property
    def program_running(self) -> bool | None:
        """The last value of the program topic, None before any."""
        with self._lock:
            return self._running

    def wait_stop_reason(self, timeout_s: float) -> str:
        """:meth:`stop_reason`, waiting up to ``timeout_s`` (wall time) for one: the controller's PREEMPTED and the
        latched program topic travel on different connections, the result may come first."""
        deadline = time.monotonic() + timeout_s
        reason = self.stop_reason()
        while not reason and time.monotonic() < deadline:
            time.sleep(0.01)
            reason = self.stop_reason()
        return self.settled_reason(reason)

    def settled_reason(self, reason: str, timeout_s: float = SECOND_TOPIC_WAIT_S) -> str:
        """``reason`` (a :meth:`stop_reason`) once the other state topic had up to ``timeout_s`` to follow: the
        program and the safety topic travel on different connections, and a protective stop changes both. Returns
        as soon as both tell (a safety stop always stops the program; a plain program stop waits the whole time)."""
        if not reason:
            return reason
        deadline = time.monotonic() + timeout_s
        while not self._both_known() and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.stop_reason()

    def _both_known(self) -> bool:
        with self._lock:
            running, safety = self._running, self._safety
        return running is False and self._safety_stopped(safety)

    @staticmethod
    def _safety_stopped(safety: int | None) -> bool:
        return safety is not None and SafetyMode is not None and safety not in (SafetyMode.NORMAL, SafetyMode.REDUCED)

    def stop_reason(self) -> str:
        with self._lock:
            running, safety = self._running, self._safety
        reasons = []
        if self._safety_stopped(safety):
            names = code_names(SafetyMode)
            reasons.append(
                f"the robot is in safety mode {names.get(safety, safety)}"
                + (": unlock the protective stop" if safety == SafetyMode.PROTECTIVE_STOP else "")
            )
        if running is False:
            reasons.append(
                f"the robot program stopped ({self.program_topic} is false): start the External Control program "
                "on the teach pendant (after unlocking a protective stop) and execute again"
            )
        return "; ".join(reasons)


class RobotMotionClient:
    """What the executors use: ``execute(trajectory)`` to its end (or raise), ``wait_for_server``,
    ``server_connected`` (the action server's status topic has a publisher) and ``cancel``.

    ``limits``: the station's joint limits (their names fix the joint order); ``current_state()``: the robot's
    joint positions in that order (rad), None when unknown. ``program``: the UR program watch (None: none).
    """

    kind = ""
    action_spec = None
    success_code = 0
    names: ClassVar[dict[int, str]] = {}
    hints: ClassVar[dict[int, str]] = {}

    def __init__(
        self,
        action: str,
        limits: JointLimits,
        current_state: Callable[[], np.ndarray | None],
        program: RobotProgramWatch | None = None,
        tolerances: CheckTolerances = DEFAULT_TOLERANCES,
        poll_s: float = 0.02,
    ):
        self.action = action
        self.limits = limits
        self.current_state = current_state
        self.program = program
        self.tolerances = tolerances
        self.poll_s = float(poll_s)
        self.client = ActionClient(action, self.action_spec)
        self._progress_lock = threading.Lock()
        self._progress = 0.0
        self._duration_s = 0.0
        self._cancel_sent = False

    # ---------------------------------------------------------------------------- the interface
    def wait_for_server(self, timeout_s: float) -> bool:
        return self.client.wait_for_server(rospy.Duration(timeout_s))

    def server_connected(self) -> bool:
        """Whether the action server's status topic has a publisher (drops as soon as its process dies)."""
        return self.client.action_client.status_sub.get_num_connections() > 0

    def cancel(self) -> None:
        """Cancel the running goal (its end is then reported as cancelled, not as an unasked preemption)."""
        self._cancel_sent = True
        self.client.cancel_goal()

    @property
    def progress(self) -> float:
        """Share (0..1) of the running trajectory's time done, from the server's feedback (0 if it gives none)."""
        with self._progress_lock:
            return self._progress

    def check(self, trajectory: JointTrajectory) -> None:
        """Refuse (TrajectoryRefused) what the real controller would run unchecked: a start away from the robot's
        state, a joint limit violated."""
        current = self.current_state()
        if current is None:
            raise TrajectoryRefused(f"{self.action}: no /joint_states: the robot's state is not known")
        verdict = check_trajectory(trajectory, self.limits, current, self.tolerances)
        if not verdict.ok:
            raise TrajectoryRefused(f"trajectory refused before sending to {self.action}: {verdict.reason}")

    def stop_reason(self) -> str:
        return self.program.stop_reason() if self.program is not None else ""

    def execute(
        self,
        trajectory: JointTrajectory,
        cancel_requested: Callable[[], bool] = lambda: False,
        controller_problem: Callable[[], str] = lambda: "",
    ) -> None:
        """Check, send and wait for ``trajectory``. Raises TrajectoryRefused before sending; ExecutionCancelled when
        ``cancel_requested()`` turned true (the goal is cancelled); ControllerLost when ``controller_problem()``
        names one (the goal is cancelled); RobotStopped when the program stops; ExecutionError on failure."""
        self.check(trajectory)
        if len(trajectory) < 2:
            # one point, at the robot already (checked): nothing to move, and a joint trajectory controller refuses
            # a goal whose only point lies at time 0 ("Dropping all 1 trajectory point(s) ...")
            return
        stopped = self.stop_reason()
        if stopped:
            raise RobotStopped(f"{self.action}: not sent: {stopped}")
        with self._progress_lock:
            self._progress, self._duration_s = 0.0, float(trajectory.duration)
        self._cancel_sent = False
        self.client.send_goal(self.goal(trajectory), feedback_cb=self._on_feedback)
        while not self.client.wait_for_result(rospy.Duration(self.poll_s)):
            if cancel_requested() or rospy.is_shutdown():
                self._cancel_and_wait()
                raise ExecutionCancelled("cancelled; robot stopped")
            problem = controller_problem()
            if problem:
                self.cancel()  # a controller that only stalled must not go on moving
                raise ControllerLost(problem)
            stopped = self.stop_reason()
            if stopped:  # the controller preempts too; the reason is known here, and at once
                stopped = self.program.settled_reason(stopped)
                self._cancel_and_wait()
                raise RobotStopped(f"{self.action}: stopped during the trajectory: {stopped}")
        result, state = self.client.get_result(), self.client.get_state()
        stopped = self.stop_reason()
        if stopped:
            stopped = self.program.settled_reason(stopped)
        elif state == GoalStatus.PREEMPTED and not self._cancel_sent and self.program is not None:
            stopped = self.program.wait_stop_reason(PREEMPT_REASON_WAIT_S)
        outcome = GoalOutcome(
            state=state,
            error_code=self.result_code(result),
            error_string=self.result_text(result),
            cancel_sent=self._cancel_sent,
            stop_reason=stopped,
        )
        error = describe_outcome(self.action, outcome, self.success_code, self.names, self.hints)
        if error is not None:
            self.wait_until_still(CANCEL_WAIT_S)  # the controller brakes after ending a goal early
            raise error
        with self._progress_lock:
            self._progress = 1.0

    def _cancel_and_wait(self) -> None:
        """Cancel, wait for the goal's end and for the robot to stand: a joint trajectory controller ends a
        cancelled goal at once and then brakes along its stop trajectory (0.5 s on a UR)."""
        started = time.monotonic()
        self.cancel()
        self.client.wait_for_result(rospy.Duration(CANCEL_WAIT_S))
        self.wait_until_still(max(0.0, CANCEL_WAIT_S - (time.monotonic() - started)))

    def wait_until_still(self, timeout_s: float) -> bool:
        """Wait (wall time, at most ``timeout_s``) until the joints stay within STILL_RAD for STILL_FOR_S; whether
        they did."""
        deadline = time.monotonic() + timeout_s
        reference, since = self.current_state(), time.monotonic()
        while time.monotonic() < deadline:
            time.sleep(0.01)
            now, state = time.monotonic(), self.current_state()
            if reference is None or state is None or np.abs(state - reference).max() > STILL_RAD:
                reference, since = state, now
            elif now - since >= STILL_FOR_S:
                return True
        return False

    # ---------------------------------------------------------------------------- per action type
    def goal(self, trajectory: JointTrajectory):
        raise NotImplementedError

    def result_code(self, result) -> int:
        raise NotImplementedError

    def result_text(self, result) -> str:
        return ""

    def _on_feedback(self, feedback) -> None:
        pass


class FollowJointTrajectoryClient(RobotMotionClient):
    """control_msgs/FollowJointTrajectory (the UR driver's scaled joint trajectory controller, or the simulator).
    Goals carry no tolerances: the controller's (UR: path 0.2 rad, goal 0.1 rad, goal time 0.6 s) apply."""

    kind = "follow_joint_trajectory"
    action_spec = FollowJointTrajectoryAction
    success_code = FollowJointTrajectoryResult.SUCCESSFUL
    names: ClassVar[dict[int, str]] = code_names(FollowJointTrajectoryResult)

    def goal(self, trajectory: JointTrajectory):
        return FollowJointTrajectoryGoal(trajectory=joint_trajectory_to_msg(trajectory))

    def result_code(self, result) -> int:
        return FollowJointTrajectoryResult.SUCCESSFUL if result is None else int(result.error_code)

    def result_text(self, result) -> str:
        return "" if result is None else str(result.error_string)

    def _on_feedback(self, feedback) -> None:
        elapsed = feedback.actual.time_from_start.to_sec()
        with self._progress_lock:
            if self._duration_s > 0:
                self._progress = min(1.0, max(0.0, elapsed / self._duration_s))


class MoveItExecuteClient(RobotMotionClient):
    """moveit_msgs/ExecuteTrajectory on move_group (``/execute_trajectory``); its feedback is a state name only."""

    kind = "moveit"
    action_spec = ExecuteTrajectoryAction
    success_code = MoveItErrorCodes.SUCCESS
    names: ClassVar[dict[int, str]] = code_names(MoveItErrorCodes)
    hints: ClassVar[dict[int, str]] = {
        MoveItErrorCodes.TIMED_OUT: (
            "move_group's execution duration monitoring: with the speed slider below about 80 % raise "
            "allowed_execution_duration_scaling or turn execution_duration_monitoring off"
        ),
        MoveItErrorCodes.CONTROL_FAILED: "the controller did not follow the trajectory, or execution is disabled",
    }

    def goal(self, trajectory: JointTrajectory):
        return ExecuteTrajectoryGoal(trajectory=RobotTrajectory(joint_trajectory=joint_trajectory_to_msg(trajectory)))

    def result_code(self, result) -> int:
        return 0 if result is None else int(result.error_code.val)


def executor_kind(value: object, where: str) -> str:
    """The ``executor`` parameter: one of :data:`EXECUTORS`."""
    kind = str(value)
    if kind not in EXECUTORS:
        raise ConfigError(f"{where}: {kind!r} is not an executor (one of {', '.join(EXECUTORS)})")
    return kind


@dataclass(frozen=True)
class MotionSettings:
    """The motion parameters of a node: the executor kind and its action name ('' = the kind's default)."""

    executor: str = "follow_joint_trajectory"
    controller_action: str = ""

    @property
    def action(self) -> str:
        return self.controller_action or EXECUTORS[self.executor]


#: the default: FollowJointTrajectory on the UR driver's action
DEFAULT_MOTION = MotionSettings()


def motion_parameters(namespace: str = "~") -> tuple[Param, Param]:
    """The two parameters ``<namespace>executor`` and ``<namespace>controller_action``."""
    return (
        Param(f"{namespace}executor", "follow_joint_trajectory", executor_kind),
        Param(f"{namespace}controller_action", "", text),
    )


def read_motion_settings(namespace: str = "~") -> MotionSettings:
    """The motion settings, read once (``namespace`` '~' for a node's own, or e.g. '/trajectory_manager/')."""
    values = read_params(motion_parameters(namespace))
    return MotionSettings(values.executor, values.controller_action)


def make_motion_client(
    settings: MotionSettings,
    limits: JointLimits,
    current_state: Callable[[], np.ndarray | None],
    program: RobotProgramWatch | None = None,
    **kwargs,
) -> RobotMotionClient:
    """The client ``settings`` name (a new RobotProgramWatch unless ``program`` is given)."""
    kind = executor_kind(settings.executor, "executor")
    cls = MoveItExecuteClient if kind == "moveit" else FollowJointTrajectoryClient
    return cls(settings.action, limits, current_state, program or RobotProgramWatch(), **kwargs)
