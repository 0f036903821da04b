"""The simulated UR10e as ur_robot_driver v2.4.1 presents it (``motion.jtc`` on ROS).

Started as node ``ur_hardware_interface`` by ``roslaunch ur_robot_driver ur10e_bringup.launch robot_ip:=<any>``
(packages/ur_robot_driver). The driver's names:

* action ``scaled_pos_joint_traj_controller/follow_joint_trajectory`` (control_msgs/FollowJointTrajectory) with the
  joint trajectory controller's semantics (``motion.jtc``), feedback at ``action_monitor_rate`` (20 Hz);
* ``joint_states`` (sensor_msgs/JointState, joints in alphabetical order as the driver's joint_state_controller
  publishes them) and ``speed_scaling_factor`` (std_msgs/Float64) at the loop rate
  (``/hardware_control_loop/loop_hz``, 500 Hz), ``scaled_pos_joint_traj_controller/state``
  (control_msgs/JointTrajectoryControllerState) at the controller's ``state_publish_rate``;
* ``~robot_program_running`` (std_msgs/Bool), ``~robot_mode`` (ur_dashboard_msgs/RobotMode: POWER_OFF, IDLE or
  RUNNING, the robot powered with its brakes released, at the start) and ``~safety_mode`` (ur_dashboard_msgs/SafetyMode: NORMAL, PROTECTIVE_STOP),
  latched, published on change; ``~set_speed_slider`` (ur_msgs/SetSpeedSliderFraction);
* ``~hand_back_control`` and, with ``~headless_mode``, ``~resend_robot_program`` (std_srvs/Trigger: the External
  Control program ends / starts again, as after a power cycle);
* ``~set_mode`` (ur_dashboard_msgs/SetMode; the real driver's ``ur_robot_state_helper``): power off, power on,
  unlock a protective stop, release the brakes until the target robot mode, then play the program if asked;
* the dashboard client's Trigger services ``~dashboard/power_on``, ``~dashboard/power_off``,
  ``~dashboard/brake_release``, ``~dashboard/play``, ``~dashboard/stop``,
  ``~dashboard/unlock_protective_stop`` and its queries ``~dashboard/program_running`` (IsProgramRunning),
  ``~dashboard/program_state`` (GetProgramState), ``~dashboard/get_robot_mode`` (GetRobotMode),
  ``~dashboard/get_safety_mode`` (GetSafetyMode), answering with the dashboard server's texts.

The controller's tolerances, stop trajectory duration and rates come from the controller configuration the bringup
loads (``scaled_pos_joint_traj_controller/constraints`` ...), as on the real driver.

Simulation only (``ur_driver_sim/``): ``set_program_running`` (std_srvs/SetBool: the External Control program
runs / stops), ``protective_stop`` and ``unlock_protective_stop`` (std_srvs/Trigger), ``set_joint_state``
(agiprobot_measurement/SetJointState: place the robot at once).

Deprecated alias (until every client uses FollowJointTrajectory): action ``robot_sim/execute_trajectory``
(agiprobot_measurement/ExecuteJointTrajectory) and service ``robot_sim/set_joint_state``, served by the same
controller. The alias keeps the old strict checks (joint names, finite values, strictly increasing time, start at
the current state, position / velocity / acceleration limits of the interpolated motion) and the old replies;
its cancel stops the robot where it is.

Private parameters: ~robot_config, ~joint_limits, ~named_states (project configuration files; "" = the package's),
~initial_state (a named state or six values, "home"), ~servoj_lookahead_time (0.03 s: the simulated robot's
position lag), ~start_tolerance_rad
(0.01), ~velocity_tolerance_fraction (0.01), ~acceleration_tolerance_fraction (0.05), and the driver's own
(robot_ip, ports, kinematics/... as the bringup sets them; the simulator does not use them), and ~joints (the
controller configuration's joint list, checked against ~robot_config's joints).
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable

import actionlib
import numpy as np
import rospy
from control_msgs.msg import (
    FollowJointTrajectoryAction,
    FollowJointTrajectoryFeedback,
    FollowJointTrajectoryResult,
    JointTrajectoryControllerState,
)
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_dashboard_msgs.msg import (
    ProgramState,
    RobotMode,
    SafetyMode,
    SetModeAction,
    SetModeFeedback,
    SetModeResult,
)
from ur_dashboard_msgs.srv import (
    GetProgramState,
    GetProgramStateResponse,
    GetRobotMode,
    GetRobotModeResponse,
    GetSafetyMode,
    GetSafetyModeResponse,
    IsProgramRunning,
    IsProgramRunningResponse,
)
from ur_msgs.srv import SetSpeedSliderFraction, SetSpeedSliderFractionResponse

from agiprobot_measurement.common.config import ConfigError, number, positive
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.jtc import (
    DEFAULT_CONSTRAINTS,
    SETTLED_RAD,
    STOP_TRAJECTORY_DURATION_S,
    Constraints,
    ControllerState,
    ErrorCode,
    GoalEnd,
    GoalOutcome,
    GoalRejected,
    JointTolerance,
    JointTrajectoryController,
    TrajectoryGoal,
    TrajectoryPoint,
    resolve_initial_state,
)
from agiprobot_measurement.motion.trajectory import CheckTolerances, JointTrajectory, TrajectoryError, check_trajectory
from agiprobot_measurement.motion.ur_modes import MAX_SET_MODE_STEPS, UrModes, set_mode_step
from agiprobot_measurement.msg import (
    ExecuteJointTrajectoryAction,
    ExecuteJointTrajectoryFeedback,
    ExecuteJointTrajectoryResult,
)
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, flag, param, read_params
from agiprobot_measurement.srv import SetJointState, SetJointStateResponse
from agiprobot_measurement.station import load_joint_limits, load_named_states, load_robot_config

__all__ = ["CONTROLLER", "UrDriverSimNode", "main"]

#: the driver's trajectory controller (its namespace holds the action, the state topic and its configuration)
CONTROLLER = "scaled_pos_joint_traj_controller"
#: the driver's control loop rate (Hz) when the controller configuration does not set one
DEFAULT_LOOP_HZ = 500.0
#: the program the External Control URCap runs, as the dashboard names it
EXTERNAL_CONTROL_PROGRAM = "external_control.urp"
#: the JTC's action_monitor_rate default (Hz)
DEFAULT_ACTION_MONITOR_HZ = 20.0
#: the alias's goal position tolerance (rad): its SUCCEEDED means "exactly at the trajectory's end", as robot_sim's did
ALIAS_GOAL_TOLERANCE_RAD = SETTLED_RAD

PARAMETERS = (
    Param("~robot_config", None),
    Param("~joint_limits", None),
    Param("~named_states", None),
    Param("~initial_state", "home"),
    Param("~servoj_lookahead_time", 0.03, number),
    Param("~start_tolerance_rad", 0.01, number),
    Param("~velocity_tolerance_fraction", 0.01, number),
    Param("~acceleration_tolerance_fraction", 0.05, number),
)


def read_constraints(joint_names: list[str]) -> tuple[Constraints, dict[str, tuple[float, float]]]:
    """The controller's ``constraints`` (defaults: ur10e_controllers.yaml's values) and per-joint (trajectory,
    goal) tolerances (rad)."""
    root = f"{CONTROLLER}/constraints"
    defaults = DEFAULT_CONSTRAINTS
    constraints = Constraints(
        path_rad=defaults.path_rad,
        goal_rad=defaults.goal_rad,
        goal_time_s=param(f"{root}/goal_time", defaults.goal_time_s, number),
        stopped_velocity_rad_s=param(f"{root}/stopped_velocity_tolerance", defaults.stopped_velocity_rad_s, number),
    )
    per_joint = {
        name: (
            param(f"{root}/{name}/trajectory", defaults.path_rad, number),
            param(f"{root}/{name}/goal", defaults.goal_rad, number),
        )
        for name in joint_names
    }
    return constraints, per_joint


def _point(positions, velocities, accelerations, time_s: float) -> JointTrajectoryPoint:
    point = JointTrajectoryPoint()
    point.positions = list(positions)
    point.velocities = list(velocities)
    if accelerations is not None:
        point.accelerations = list(accelerations)
    point.time_from_start = rospy.Duration.from_sec(time_s)
    return point


def _goal_from_msg(msg) -> TrajectoryGoal:
    trajectory = msg.trajectory
    return TrajectoryGoal(
        joint_names=list(trajectory.joint_names),
        points=[
            TrajectoryPoint(list(p.positions), p.time_from_start.to_sec(), list(p.velocities), list(p.accelerations))
            for p in trajectory.points
        ],
        start_s=trajectory.header.stamp.to_sec(),
        path_tolerance=[JointTolerance(t.name, t.position, t.velocity) for t in msg.path_tolerance],
        goal_tolerance=[JointTolerance(t.name, t.position, t.velocity) for t in msg.goal_tolerance],
        goal_time_tolerance_s=msg.goal_time_tolerance.to_sec(),
    )


class _Alias:
    """One goal of the deprecated ExecuteJointTrajectory alias: its handle and duration (s)."""

    def __init__(self, handle, duration_s: float):
        self.handle = handle
        self.duration_s = duration_s
        self.started_s = rospy.Time.now().to_sec()


class UrDriverSimNode:
    def __init__(self):
        settings = read_params(PARAMETERS)
        robot = load_robot_config(settings.robot_config)
        self.joint_names = list(robot.joint_names)
        driver_joints = param("~joints", self.joint_names)
        if not isinstance(driver_joints, list) or sorted(map(str, driver_joints)) != sorted(self.joint_names):
            raise ConfigError(f"~joints {driver_joints} are not the robot's joints {self.joint_names}")
        self.limits = load_joint_limits(settings.joint_limits, robot.joint_names)
        self.named_states = load_named_states(settings.named_states, len(self.joint_names))
        self.check_tolerances = CheckTolerances(
            start_rad=settings.start_tolerance_rad,
            velocity_fraction=settings.velocity_tolerance_fraction,
            acceleration_fraction=settings.acceleration_tolerance_fraction,
        )
        initial = resolve_initial_state(settings.initial_state, self.named_states, len(self.joint_names))
        constraints, per_joint = read_constraints(self.joint_names)
        self.per_joint_tolerances = per_joint
        self.loop_hz = param("/hardware_control_loop/loop_hz", DEFAULT_LOOP_HZ, positive)
        self.state_hz = param(f"{CONTROLLER}/state_publish_rate", self.loop_hz, positive)
        self.monitor_hz = param(f"{CONTROLLER}/action_monitor_rate", DEFAULT_ACTION_MONITOR_HZ, positive)
        stop_s = param(f"{CONTROLLER}/stop_trajectory_duration", STOP_TRAJECTORY_DURATION_S, number)
        if settings.servoj_lookahead_time < 0:
            raise ConfigError("~servoj_lookahead_time must not be negative")
        self.lock = threading.RLock()
        #: goal results and feedback to send once no lock is held (see :meth:`deliver`)
        self.outbox: list[Callable[[], None]] = []
        self.controller = JointTrajectoryController(
            initial,
            joint_names=self.joint_names,
            constraints=constraints,
            stop_trajectory_duration_s=stop_s,
            tracking_time_constant_s=settings.servoj_lookahead_time,
            now_s=rospy.Time.now().to_sec(),
        )
        self.handles: dict[int, object] = {}  # FollowJointTrajectory goals by controller goal id
        self.aliases: dict[int, _Alias] = {}  # ExecuteJointTrajectory goals by controller goal id
        self.alphabetical = sorted(range(len(self.joint_names)), key=lambda i: self.joint_names[i])

        self.joint_states = rospy.Publisher("joint_states", JointState, queue_size=10)
        self.scaling = rospy.Publisher("speed_scaling_factor", Float64, queue_size=10)
        self.state_topic = rospy.Publisher(f"{CONTROLLER}/state", JointTrajectoryControllerState, queue_size=10)
        self.program_topic = rospy.Publisher("~robot_program_running", Bool, queue_size=1, latch=True)
        self.robot_mode_topic = rospy.Publisher("~robot_mode", RobotMode, queue_size=1, latch=True)
        self.safety_mode_topic = rospy.Publisher("~safety_mode", SafetyMode, queue_size=1, latch=True)
        self.modes = UrModes()
        self.publish_modes()

        self.server = actionlib.ActionServer(
            f"{CONTROLLER}/follow_joint_trajectory",
            FollowJointTrajectoryAction,
            goal_cb=self.on_goal,
            cancel_cb=self.on_cancel,
            auto_start=False,
        )
        self.alias_server = actionlib.ActionServer(
            "robot_sim/execute_trajectory",
            ExecuteJointTrajectoryAction,
            goal_cb=self.on_alias_goal,
            cancel_cb=self.on_alias_cancel,
            auto_start=False,
        )
        rospy.Service("~set_speed_slider", SetSpeedSliderFraction, self.set_speed_slider)
        rospy.Service("~dashboard/play", Trigger, self.dashboard_play)
        rospy.Service("~dashboard/stop", Trigger, self.dashboard_stop)
        rospy.Service("~dashboard/unlock_protective_stop", Trigger, self.unlock_protective_stop)
        rospy.Service("~dashboard/power_on", Trigger, lambda _request: TriggerResponse(*self.dashboard("power_on")))
        rospy.Service("~dashboard/power_off", Trigger, lambda _request: TriggerResponse(*self.dashboard("power_off")))
        rospy.Service(
            "~dashboard/brake_release", Trigger, lambda _request: TriggerResponse(*self.dashboard("brake_release"))
        )
        rospy.Service("~hand_back_control", Trigger, self.hand_back_control)
        if param("~headless_mode", False, flag):
            rospy.Service("~resend_robot_program", Trigger, self.resend_robot_program)
        rospy.Service("~dashboard/program_running", IsProgramRunning, self.dashboard_program_running)
        rospy.Service("~dashboard/program_state", GetProgramState, self.dashboard_program_state)
        rospy.Service("~dashboard/get_robot_mode", GetRobotMode, self.dashboard_robot_mode)
        rospy.Service("~dashboard/get_safety_mode", GetSafetyMode, self.dashboard_safety_mode)
        rospy.Service("ur_driver_sim/set_program_running", SetBool, self.set_program_running)
        rospy.Service("ur_driver_sim/protective_stop", Trigger, self.protective_stop)
        rospy.Service("ur_driver_sim/unlock_protective_stop", Trigger, self.unlock_protective_stop)
        rospy.Service("ur_driver_sim/set_joint_state", SetJointState, self.set_joint_state)
        rospy.Service("robot_sim/set_joint_state", SetJointState, self.set_joint_state)
        self.set_mode_server = actionlib.SimpleActionServer("~set_mode", SetModeAction, self.set_mode, False)
        self.server.start()
        self.alias_server.start()
        self.set_mode_server.start()
        self.thread = threading.Thread(target=self.loop, name="control_loop", daemon=True)
        self.thread.start()
        rospy.loginfo(
            "ur_driver_sim: UR10e at %s, control loop %.0f Hz, action %s/follow_joint_trajectory",
            np.round(initial, 4).tolist(),
            self.loop_hz,
            CONTROLLER,
        )

    # ------------------------------------------------------------------------------------ control loop
    def loop(self) -> None:
        rate = rospy.Rate(self.loop_hz)
        state_every = max(1, round(self.loop_hz / self.state_hz))
        monitor_every = max(1, round(self.loop_hz / self.monitor_hz))
        tick = 0
        while not rospy.is_shutdown():
            try:
                now = rospy.Time.now()
                with self.lock:
                    ended = self.controller.update(now.to_sec())
                    self.finish(ended)
                    snapshot = self.controller.snapshot()
                    scaling = self.controller.speed_scaling
                    if tick % monitor_every == 0:
                        self.send_feedback(snapshot, now)
                self.deliver()
                self.publish(snapshot, scaling, now, tick % state_every == 0)
                tick += 1
                rate.sleep()
            except rospy.ROSInterruptException:
                break
            except rospy.ROSException:
                if rospy.is_shutdown() or rospy.core.is_shutdown_requested():
                    break  # the topics close while shutting down
                raise

    def publish(self, snapshot: ControllerState, scaling: float, now: rospy.Time, with_state: bool) -> None:
        msg = JointState()
        msg.header.stamp = now
        order = self.alphabetical
        msg.name = [self.joint_names[i] for i in order]
        msg.position = snapshot.actual_positions[order].tolist()
        msg.velocity = snapshot.actual_velocities[order].tolist()
        msg.effort = [0.0] * len(order)
        self.joint_states.publish(msg)
        self.scaling.publish(Float64(scaling))
        if with_state:
            state = JointTrajectoryControllerState()
            state.header.stamp = now
            state.joint_names = list(snapshot.joint_names)
            state.desired, state.actual, state.error = self._points(snapshot)
            self.state_topic.publish(state)

    @staticmethod
    def _points(snapshot: ControllerState):
        t = snapshot.time_from_start_s
        desired = _point(snapshot.desired_positions, snapshot.desired_velocities, snapshot.desired_accelerations, t)
        actual = _point(snapshot.actual_positions, snapshot.actual_velocities, None, t)
        error = _point(snapshot.error_positions, snapshot.error_velocities, None, t)
        return desired, actual, error

    def send_feedback(self, snapshot: ControllerState, now: rospy.Time) -> None:
        """Queues the active goal's feedback (called with the lock held; :meth:`deliver` sends it)."""
        goal_id = snapshot.goal_id
        if goal_id in self.handles:
            feedback = FollowJointTrajectoryFeedback()
            feedback.header.stamp = now
            feedback.joint_names = list(snapshot.joint_names)
            feedback.desired, feedback.actual, feedback.error = self._points(snapshot)
            self.outbox.append(functools.partial(self.handles[goal_id].publish_feedback, feedback))
        elif goal_id in self.aliases:
            alias = self.aliases[goal_id]
            progress = snapshot.time_from_start_s / alias.duration_s if alias.duration_s > 0 else 1.0
            feedback = ExecuteJointTrajectoryFeedback(
                progress=float(min(progress, 1.0)), time_from_start=snapshot.time_from_start_s
            )
            self.outbox.append(functools.partial(alias.handle.publish_feedback, feedback))

    def finish(self, ended: list[GoalOutcome]) -> None:
        """Queues the results of the goals that ended (called with the lock held; :meth:`deliver` sends them)."""
        for outcome in ended:
            if outcome.goal_id in self.handles:
                handle = self.handles.pop(outcome.goal_id)
                result = FollowJointTrajectoryResult(error_code=int(outcome.code), error_string=outcome.text)
                if outcome.end is GoalEnd.SUCCEEDED:
                    self.outbox.append(functools.partial(handle.set_succeeded, result))
                elif outcome.end is GoalEnd.ABORTED:
                    rospy.logwarn("ur_driver_sim: goal aborted: %s", outcome.text)
                    self.outbox.append(functools.partial(handle.set_aborted, result, outcome.text))
                else:
                    self.outbox.append(functools.partial(handle.set_canceled, result))
            elif outcome.goal_id in self.aliases:
                self._finish_alias(self.aliases.pop(outcome.goal_id), outcome)

    def _finish_alias(self, alias: _Alias, outcome: GoalOutcome) -> None:
        if outcome.end is GoalEnd.SUCCEEDED:
            self.outbox.append(
                functools.partial(alias.handle.set_succeeded, ExecuteJointTrajectoryResult(success=True, error=""))
            )
            return
        if outcome.end is GoalEnd.ABORTED:
            text = f"trajectory aborted: {outcome.text}"
            send = alias.handle.set_aborted
        else:
            elapsed = rospy.Time.now().to_sec() - alias.started_s
            stopped_at = np.round(self.controller.positions(), 4).tolist()
            text = f"cancelled after {elapsed:.2f} s of {alias.duration_s:.2f} s; stopped at {stopped_at}"
            send = alias.handle.set_canceled
        self.outbox.append(functools.partial(send, ExecuteJointTrajectoryResult(success=False, error=text), text))

    def deliver(self) -> None:
        """Sends the queued results and feedback, holding no lock of this node: actionlib calls the goal and cancel
        callbacks with its server's lock held, and they take this node's lock; sending a result takes the server's
        lock, so with this node's lock held it would close the cycle (a deadlock that froze the control loop)."""
        with self.lock:
            pending, self.outbox = self.outbox, []
        for send in pending:
            send()

    # ------------------------------------------------------------------------------------ FollowJointTrajectory
    def on_goal(self, handle) -> None:
        now = rospy.Time.now().to_sec()
        try:
            goal = _goal_from_msg(handle.get_goal())
        except (TypeError, ValueError) as exc:
            self._reject(handle, GoalRejected(ErrorCode.INVALID_GOAL, f"malformed goal: {exc}"))
            return
        goal = self._with_controller_tolerances(goal)
        with self.lock:
            try:
                goal_id, ended = self.controller.accept(goal, now)
            except GoalRejected as rejected:
                self._reject(handle, rejected)
                return
            handle.set_accepted()
            self.handles[goal_id] = handle
            self.finish(ended)

    def _with_controller_tolerances(self, goal: TrajectoryGoal) -> TrajectoryGoal:
        """The goal with the controller's per-joint defaults under the goal's own tolerances (0 = default)."""

        def merged(overrides, index):
            given = {t.name: t for t in overrides}
            out = []
            for name in self.joint_names:
                default = self.per_joint_tolerances[name][index]
                mine = given.get(name, JointTolerance(name))
                position = mine.position if mine.position != 0.0 else default
                out.append(JointTolerance(name, position if position > 0 else -1.0, mine.velocity))
            return out

        return TrajectoryGoal(
            goal.joint_names,
            goal.points,
            goal.start_s,
            merged(goal.path_tolerance, 0),
            merged(goal.goal_tolerance, 1),
            goal.goal_time_tolerance_s,
        )

    @staticmethod
    def _reject(handle, rejected: GoalRejected) -> None:
        rospy.logwarn("ur_driver_sim: goal rejected: %s", rejected.reason)
        handle.set_rejected(
            FollowJointTrajectoryResult(error_code=int(rejected.code), error_string=rejected.reason), rejected.reason
        )

    def on_cancel(self, handle) -> None:
        with self.lock:
            for goal_id, known in list(self.handles.items()):
                if known == handle:
                    self.finish(self.controller.cancel(goal_id, rospy.Time.now().to_sec()))

    # ------------------------------------------------------------------------------------ deprecated alias
    def on_alias_goal(self, handle) -> None:
        def refuse(reason: str) -> None:
            rospy.logwarn("ur_driver_sim: trajectory rejected: %s", reason)
            handle.set_accepted()  # robot_sim's reply: ABORTED with the reason
            handle.set_aborted(ExecuteJointTrajectoryResult(success=False, error=reason), reason)

        try:
            trajectory = JointTrajectory.from_msg(handle.get_goal().trajectory)
        except (TrajectoryError, ValueError) as exc:
            refuse(f"malformed trajectory: {exc}")
            return
        with self.lock:
            current = self.controller.positions()
            verdict = check_trajectory(trajectory, self.limits, current, self.check_tolerances)
            if not verdict.ok:
                refuse(verdict.reason)
                return
            ordered = trajectory.reordered(self.joint_names)
            if ordered.duration <= 0.0:  # one point, where the robot is: robot_sim put it there at once
                active = self.controller.active_goal_id
                if active is not None:
                    self.finish(self.controller.halt(active, rospy.Time.now().to_sec()))
                self.controller.place(ordered.end)
                handle.set_accepted()
                handle.set_succeeded(ExecuteJointTrajectoryResult(success=True, error=""))
                return
            velocities = ordered.knot_velocities()
            goal = TrajectoryGoal(
                self.joint_names,
                [
                    TrajectoryPoint(list(q), float(t), list(v))
                    for q, t, v in zip(ordered.positions, ordered.time_from_start, velocities, strict=True)
                ],
                goal_tolerance=[JointTolerance(name, ALIAS_GOAL_TOLERANCE_RAD) for name in self.joint_names],
            )
            try:
                goal_id, ended = self.controller.accept(goal, rospy.Time.now().to_sec())
            except GoalRejected as rejected:
                refuse(rejected.reason)
                return
            handle.set_accepted()
            self.aliases[goal_id] = _Alias(handle, ordered.duration)
            self.finish(ended)

    def on_alias_cancel(self, handle) -> None:
        with self.lock:
            for goal_id, alias in list(self.aliases.items()):
                if alias.handle == handle:
                    self.finish(self.controller.halt(goal_id, rospy.Time.now().to_sec()))

    # ------------------------------------------------------------------------------------ services
    def set_speed_slider(self, request):
        with self.lock:
            ok = self.controller.set_speed_slider(request.speed_slider_fraction)
        if not ok:
            rospy.logwarn("ur_driver_sim: speed slider fraction must be in [0.01, 1]")
        return SetSpeedSliderFractionResponse(success=ok)

    def _set_running(self, running: bool) -> tuple[bool, str]:
        with self.lock:
            if running and not self.modes.can_play:
                return False, f"the robot is in mode {self.modes.robot.name}: power it on and release the brakes"
            try:
                self.finish(self.controller.set_program_running(running, rospy.Time.now().to_sec()))
            except InputError as exc:
                return False, str(exc)
            state = self.controller.program_running
        self.publish_modes()
        return True, "program running" if state else "program stopped"

    def _safety_mode(self) -> int:
        return SafetyMode.PROTECTIVE_STOP if self.controller.protective_stopped else SafetyMode.NORMAL

    def publish_modes(self) -> None:
        """The latched robot mode, safety mode and program topics from the controller's state."""
        with self.lock:
            robot, safety, running = int(self.modes.robot), self._safety_mode(), self.controller.program_running
        self.robot_mode_topic.publish(RobotMode(robot))
        self.safety_mode_topic.publish(SafetyMode(safety))
        self.program_topic.publish(Bool(running))

    def dashboard(self, command: str) -> tuple[bool, str]:
        """A dashboard command that changes the robot mode or the safety system: (success, the server's answer)."""
        with self.lock:
            now_s = rospy.Time.now().to_sec()
            if command in ("power_off", "restart_safety"):
                # the program stops with the power; restarting the safety system powers the arm off
                self.finish(self.controller.set_program_running(False, now_s))
                answer = self.modes.power_off() if command == "power_off" else (True, "Restarting safety")
                self.modes.power_off()
            elif command == "unlock_protective_stop":
                was = self.controller.unlock_protective_stop()
                answer = (True, "Protective stop releasing" if was else "no protective stop to unlock")
            else:
                answer = getattr(self.modes, command)()
        self.publish_modes()
        return answer

    def set_mode(self, goal) -> None:
        """ur_robot_driver's set_mode action (robot_state_helper): dashboard commands until the robot is in the target
        mode, feedback after each; ``stop_program`` first, ``play_program`` at the end (target RUNNING)."""
        target, first = int(goal.target_robot_mode.mode), True
        for _ in range(MAX_SET_MODE_STEPS):
            with self.lock:
                robot, safety = int(self.modes.robot), self._safety_mode()
            step = set_mode_step(target, robot, safety, first)
            if first and step.command and goal.stop_program:
                self._set_running(False)
            first = False
            if step.done:
                break
            if not step.command:
                self.set_mode_server.set_aborted(
                    SetModeResult(False, f"the simulated robot cannot leave robot mode {robot} by itself")
                )
                return
            ok, answer = self.dashboard(step.command)
            if not ok:
                message = (
                    "An error occurred while switching the robot mode. The respective dashboard service returned "
                    f"non-success: {answer}"
                )
                self.set_mode_server.set_aborted(SetModeResult(False, message))
                return
            with self.lock:
                self.set_mode_server.publish_feedback(SetModeFeedback(int(self.modes.robot), self._safety_mode()))
        else:
            self.set_mode_server.set_aborted(SetModeResult(False, f"no robot mode {target} after dashboard commands"))
            return
        if not step.success:
            self.set_mode_server.set_aborted(SetModeResult(False, step.message))
            return
        if target == RobotMode.RUNNING and goal.play_program:
            self._set_running(True)
        self.set_mode_server.set_succeeded(SetModeResult(True, step.message))

    def hand_back_control(self, _request):
        with self.lock:
            running = self.controller.program_running
        if not running:
            return TriggerResponse(True, "No control active. Nothing to do.")
        self._set_running(False)
        return TriggerResponse(True, "Deactivated control")

    def resend_robot_program(self, _request):
        ok, _message = self._set_running(True)
        return TriggerResponse(ok, "Successfully resent robot program" if ok else "Could not resend robot program")

    def dashboard_program_running(self, _request):
        with self.lock:
            running = self.controller.program_running
        return IsProgramRunningResponse(
            answer=f"Program running: {str(running).lower()}", program_running=running, success=True
        )

    def dashboard_program_state(self, _request):
        with self.lock:
            state = ProgramState.PLAYING if self.controller.program_running else ProgramState.STOPPED
        return GetProgramStateResponse(
            state=ProgramState(state),
            program_name=EXTERNAL_CONTROL_PROGRAM,
            answer=f"{state} {EXTERNAL_CONTROL_PROGRAM}",
            success=True,
        )

    def dashboard_robot_mode(self, _request):
        with self.lock:
            mode = self.modes.robot
        return GetRobotModeResponse(robot_mode=RobotMode(int(mode)), answer=f"Robotmode: {mode.name}", success=True)

    def dashboard_safety_mode(self, _request):
        with self.lock:
            stopped = self.controller.protective_stopped
        name = "PROTECTIVE_STOP" if stopped else "NORMAL"
        return GetSafetyModeResponse(
            safety_mode=SafetyMode(getattr(SafetyMode, name)), answer=f"Safetymode: {name}", success=True
        )

    def set_program_running(self, request):
        return SetBoolResponse(*self._set_running(bool(request.data)))

    def dashboard_play(self, _request):
        ok, message = self._set_running(True)
        return TriggerResponse(ok, "Starting program" if ok else f"Failed to execute: play ({message})")

    def dashboard_stop(self, _request):
        ok, message = self._set_running(False)
        return TriggerResponse(ok, "Stopped" if ok else message)

    def protective_stop(self, _request):
        with self.lock:
            self.finish(self.controller.protective_stop(rospy.Time.now().to_sec()))
        self.publish_modes()
        return TriggerResponse(True, "protective stop: robot halted, program stopped")

    def unlock_protective_stop(self, _request):
        return TriggerResponse(*self.dashboard("unlock_protective_stop"))

    def set_joint_state(self, request):
        try:
            if request.named_state:
                if request.named_state not in self.named_states:
                    raise InputError(f"unknown named state '{request.named_state}' (known: {list(self.named_states)})")
                positions = np.array(self.named_states[request.named_state], dtype=float)
            else:
                positions = np.asarray(list(request.positions), dtype=float)
                if positions.shape == (len(self.joint_names),) and np.all(np.isfinite(positions)):
                    if not self.limits.within_position_limits(positions):
                        raise InputError("positions outside the joint limits")
            with self.lock:
                state = self.controller.place(positions)
        except InputError as exc:
            return SetJointStateResponse(False, str(exc))
        return SetJointStateResponse(True, f"robot placed at {np.round(state, 4).tolist()}")


def main():
    run_node("ur_hardware_interface", UrDriverSimNode, label="ur_driver_sim")
