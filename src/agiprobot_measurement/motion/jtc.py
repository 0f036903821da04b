"""The joint trajectory controller of the simulated UR10e, without ROS.

:class:`JointTrajectoryController` behaves as ur_robot_driver's ``scaled_pos_joint_traj_controller`` (ros_controllers'
JointTrajectoryController 0.21 with the UR's speed scaling) does for a ``FollowJointTrajectory`` goal:

* A goal names the six joints in any order (mapped by name); other names or another count are rejected with
  ``INVALID_JOINTS``. An empty trajectory, ``time_from_start`` not strictly increasing, vectors of the wrong size,
  values that are not finite, or all points in the past are rejected with ``INVALID_GOAL`` and the controller's reason.
  While the robot program is not running (or the robot is protective-stopped) every goal is rejected with
  ``INVALID_GOAL`` (the driver's controller_stopper has stopped the controller then).
* An accepted goal replaces the active one, which ends PREEMPTED. Its trajectory starts at the goal's start time
  (0 = now); a first point at ``time_from_start`` 0 is dropped, and the controller moves from its current *desired*
  state to the first point (the goal need not start where the robot is). Segments are linear (positions only),
  cubic (with velocities) or quintic (with velocities and accelerations), as the JTC's spline segments.
* Trajectory time advances by the control period times the speed scaling (speed slider fraction x the robot's
  target speed fraction); a scaling of 0 holds the trajectory where it is and the goal stays active.
* Tolerances: path position tolerance per joint (``trajectory``, default 0.2 rad) while the segments run, goal
  position tolerance (``goal``, 0.1 rad) and the stopped velocity tolerance (0.05 rad/s) at the end, within the goal
  time tolerance (0.6 s) after the trajectory's end. A goal's own tolerances override them per joint: 0 keeps the
  default, a negative value erases the check; a goal time tolerance > 0 replaces the default, < 0 makes it 0.
  Violations abort with ``PATH_TOLERANCE_VIOLATED`` ("<joint> path error <value>") or ``GOAL_TOLERANCE_VIOLATED``
  ("<joint> goal error <value>"); acceleration tolerances are not checked.
* Cancel ends the goal PREEMPTED at once and brings the robot to a stop along a stop trajectory of
  ``stop_trajectory_duration_s`` (0.5 s). A stopped robot program, or a protective stop, ends the active goal
  PREEMPTED as well (the robot halts); after a protective stop new goals are rejected until it is unlocked *and*
  the program runs again.

The simulated robot follows the controller's desired positions as the UR's servo loop does: a first-order lag
(``tracking_time_constant_s``, the driver's servoj look-ahead time 0.03 s) with the joint speed saturated at the
robot's joint velocity limits (UR10e: 120 deg/s for the two base joints, 180 deg/s for the others), so a too fast
trajectory is followed late (and may violate its tolerances) rather than rejected.

The controller is driven from outside: :meth:`update` with the current time (seconds) advances it and returns the
goals that ended; the ROS layer calls it from its control loop, pytest with a fake clock.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.errors import InputError

__all__ = [
    "DEFAULT_CONSTRAINTS",
    "STOP_TRAJECTORY_DURATION_S",
    "TRACKING_TIME_CONSTANT_S",
    "UR10E_JOINT_NAMES",
    "UR10E_VELOCITY_LIMITS_RAD_S",
    "Constraints",
    "ControllerState",
    "ErrorCode",
    "GoalEnd",
    "GoalOutcome",
    "GoalRejected",
    "JointTolerance",
    "JointTrajectoryController",
    "PlacementRefused",
    "TrajectoryGoal",
    "TrajectoryPoint",
    "resolve_initial_state",
]

#: the UR10e's joints in the controller's (kinematic) order
UR10E_JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
#: the UR10e's joint speed limits (rad/s): ur_description's config/ur10e/joint_limits.yaml, 120 deg/s for the
#: shoulder pan and lift joints, 180 deg/s for the others
UR10E_VELOCITY_LIMITS_RAD_S = {
    "shoulder_pan_joint": math.radians(120.0),
    "shoulder_lift_joint": math.radians(120.0),
    "elbow_joint": math.radians(180.0),
    "wrist_1_joint": math.radians(180.0),
    "wrist_2_joint": math.radians(180.0),
    "wrist_3_joint": math.radians(180.0),
}
#: the time constant (s) of the simulated robot's position tracking (the driver's servoj_lookahead_time)
TRACKING_TIME_CONSTANT_S = 0.03
#: the JTC's stop_trajectory_duration in ur10e_controllers.yaml (s)
STOP_TRAJECTORY_DURATION_S = 0.5
#: the speed slider range the driver accepts (set_speed_slider answers success false outside it)
SPEED_SLIDER_RANGE = (0.01, 1.0)


class ErrorCode(enum.IntEnum):
    """control_msgs/FollowJointTrajectoryResult's error codes."""

    SUCCESSFUL = 0
    INVALID_GOAL = -1
    INVALID_JOINTS = -2
    OLD_HEADER_TIMESTAMP = -3
    PATH_TOLERANCE_VIOLATED = -4
    GOAL_TOLERANCE_VIOLATED = -5


class GoalEnd(enum.Enum):
    """How an accepted goal ended (the actionlib terminal state)."""

    SUCCEEDED = "succeeded"
    ABORTED = "aborted"
    PREEMPTED = "preempted"


class GoalRejected(InputError):
    """A goal the controller does not accept: ``code`` (an :class:`ErrorCode`) and the reason."""

    def __init__(self, code: ErrorCode, reason: str):
        super().__init__(reason)
        self.code = code
        self.reason = reason


class PlacementRefused(InputError):
    """``place`` was refused: unknown named state, wrong positions, or a goal is active."""


@dataclass(frozen=True)
class GoalOutcome:
    """An accepted goal that ended: its id, terminal state, error code and text."""

    goal_id: int
    end: GoalEnd
    code: ErrorCode = ErrorCode.SUCCESSFUL
    text: str = ""


@dataclass(frozen=True)
class TrajectoryPoint:
    """One waypoint: positions (rad), optional velocities (rad/s) and accelerations (rad/s^2), time (s)."""

    positions: Sequence[float]
    time_from_start_s: float
    velocities: Sequence[float] = ()
    accelerations: Sequence[float] = ()


@dataclass(frozen=True)
class JointTolerance:
    """control_msgs/JointTolerance: position (rad) and velocity (rad/s); 0 = default, < 0 = erased."""

    name: str
    position: float = 0.0
    velocity: float = 0.0


@dataclass(frozen=True)
class TrajectoryGoal:
    """A FollowJointTrajectory goal. ``start_s``: the header stamp (s; 0 = now)."""

    joint_names: Sequence[str]
    points: Sequence[TrajectoryPoint]
    start_s: float = 0.0
    path_tolerance: Sequence[JointTolerance] = ()
    goal_tolerance: Sequence[JointTolerance] = ()
    goal_time_tolerance_s: float = 0.0


@dataclass(frozen=True)
class Constraints:
    """The controller's default tolerances (ur10e_controllers.yaml ``constraints``), per joint where named so."""

    path_rad: float = 0.2  # <joint>: {trajectory: 0.2}
    goal_rad: float = 0.1  # <joint>: {goal: 0.1}
    goal_time_s: float = 0.6
    stopped_velocity_rad_s: float = 0.05


DEFAULT_CONSTRAINTS = Constraints()


@dataclass
class ControllerState:
    """A snapshot for feedback and the state topic (controller joint order): desired, actual, error = desired -
    actual, and the time elapsed on the active trajectory (s; 0 without a goal)."""

    joint_names: list[str]
    desired_positions: np.ndarray
    desired_velocities: np.ndarray
    desired_accelerations: np.ndarray
    actual_positions: np.ndarray
    actual_velocities: np.ndarray
    time_from_start_s: float
    goal_id: int | None = None

    @property
    def error_positions(self) -> np.ndarray:
        return self.desired_positions - self.actual_positions

    @property
    def error_velocities(self) -> np.ndarray:
        return self.desired_velocities - self.actual_velocities


@dataclass
class _Segment:
    """A spline segment in trajectory (scaled) time: linear, cubic or quintic between two states."""

    t0: float
    t1: float
    p0: np.ndarray
    p1: np.ndarray
    v0: np.ndarray | None = None
    v1: np.ndarray | None = None
    a0: np.ndarray | None = None
    a1: np.ndarray | None = None
    coefficients: np.ndarray = field(init=False)  # (order + 1, n), in normalised time s in [0, 1] scaled by h

    def __post_init__(self):
        h = self.t1 - self.t0
        p0, p1 = self.p0, self.p1
        if h <= 0.0:
            self.coefficients = np.array([p1])
            return
        if self.v0 is None or self.v1 is None:
            self.coefficients = np.array([p0, (p1 - p0) / h])
            return
        v0, v1 = self.v0, self.v1
        if self.a0 is None or self.a1 is None:
            c2 = (3 * (p1 - p0) / h - 2 * v0 - v1) / h
            c3 = (2 * (p0 - p1) / h + v0 + v1) / h**2
            self.coefficients = np.array([p0, v0, c2, c3])
            return
        a0, a1 = self.a0, self.a1
        h2, h3, h4, h5 = h**2, h**3, h**4, h**5
        c3 = (20 * (p1 - p0) - (8 * v1 + 12 * v0) * h - (3 * a0 - a1) * h2) / (2 * h3)
        c4 = (30 * (p0 - p1) + (14 * v1 + 16 * v0) * h + (3 * a0 - 2 * a1) * h2) / (2 * h4)
        c5 = (12 * (p1 - p0) - 6 * (v1 + v0) * h - (a0 - a1) * h2) / (2 * h5)
        self.coefficients = np.array([p0, v0, a0 / 2, c3, c4, c5])

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = self.coefficients
        n = c.shape[1]
        if t >= self.t1:
            end_v = np.zeros(n) if self.v1 is None or len(c) == 1 else self.v1
            end_a = np.zeros(n) if self.a1 is None or len(c) == 1 else self.a1
            if len(c) == 2:  # linear: the segment's own speed at its end
                end_v = c[1]
            return self.p1.copy(), np.array(end_v, dtype=float), np.array(end_a, dtype=float)
        tau = max(t - self.t0, 0.0)
        pos = np.zeros(n)
        vel = np.zeros(n)
        acc = np.zeros(n)
        for k in range(len(c) - 1, -1, -1):
            pos = pos * tau + c[k]
        for k in range(len(c) - 1, 0, -1):
            vel = vel * tau + k * c[k]
        for k in range(len(c) - 1, 1, -1):
            acc = acc * tau + k * (k - 1) * c[k]
        return pos, vel, acc


@dataclass
class _ActiveGoal:
    goal_id: int
    segments: list[_Segment]
    start_uptime_s: float
    path_rad: np.ndarray  # per joint, 0 = unchecked
    path_velocity_rad_s: np.ndarray
    goal_rad: np.ndarray
    goal_velocity_rad_s: np.ndarray
    goal_time_tolerance_s: float

    @property
    def end_uptime_s(self) -> float:
        return self.segments[-1].t1


def resolve_initial_state(value, named_states: Mapping[str, np.ndarray], dof: int) -> np.ndarray:
    """The initial joint state (rad) from the ``~initial_state`` parameter: a named state or ``dof`` finite values."""
    if isinstance(value, str):
        if value not in named_states:
            raise ConfigError(f"~initial_state: unknown named state '{value}' (known: {list(named_states)})")
        return np.array(named_states[value], dtype=float)
    state = np.asarray(value, dtype=float)
    if state.shape != (dof,) or not np.all(np.isfinite(state)):
        raise ConfigError(f"~initial_state: expected {dof} finite joint values")
    return state


def _finite(values: Sequence[float]) -> bool:
    return all(math.isfinite(float(v)) for v in values)


class JointTrajectoryController:
    """The UR10e's scaled joint trajectory controller and the robot it moves (see the module)."""

    def __init__(
        self,
        initial_positions_rad: Sequence[float],
        *,
        joint_names: Sequence[str] = UR10E_JOINT_NAMES,
        velocity_limits_rad_s: Mapping[str, float] | None = None,
        constraints: Constraints = DEFAULT_CONSTRAINTS,
        stop_trajectory_duration_s: float = STOP_TRAJECTORY_DURATION_S,
        tracking_time_constant_s: float = TRACKING_TIME_CONSTANT_S,
        now_s: float = 0.0,
    ):
        self.joint_names = list(joint_names)
        limits = UR10E_VELOCITY_LIMITS_RAD_S if velocity_limits_rad_s is None else velocity_limits_rad_s
        self.velocity_limits = np.array([float(limits[name]) for name in self.joint_names])
        self.constraints = constraints
        self.stop_duration_s = float(stop_trajectory_duration_s)
        self.tracking_time_constant_s = float(tracking_time_constant_s)
        n = len(self.joint_names)
        positions = np.array(initial_positions_rad, dtype=float)
        if positions.shape != (n,) or not np.all(np.isfinite(positions)):
            raise PlacementRefused(f"expected {n} finite initial positions")
        self._actual = positions
        self._actual_velocity = np.zeros(n)
        self._hold(positions, now_uptime=0.0)
        self._desired = (positions.copy(), np.zeros(n), np.zeros(n))
        self._last_time_s = float(now_s)
        self._uptime_s = 0.0
        self._active: _ActiveGoal | None = None
        self._next_id = 1
        self.speed_slider_fraction = 1.0
        self.target_speed_fraction = 1.0
        self.program_running = True
        self.protective_stopped = False

    # ------------------------------------------------------------------------------------ state
    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def speed_scaling(self) -> float:
        """Speed slider x target speed fraction; 0 while protective-stopped or the program is not running."""
        if self.protective_stopped or not self.program_running:
            return 0.0
        return self.speed_slider_fraction * self.target_speed_fraction

    @property
    def active_goal_id(self) -> int | None:
        return None if self._active is None else self._active.goal_id

    def positions(self) -> np.ndarray:
        """The robot's actual positions (rad), controller joint order."""
        return self._actual.copy()

    def velocities(self) -> np.ndarray:
        """The robot's actual velocities (rad/s), controller joint order."""
        return self._actual_velocity.copy()

    def snapshot(self) -> ControllerState:
        desired_p, desired_v, desired_a = self._desired
        elapsed = 0.0 if self._active is None else max(self._uptime_s - self._active.start_uptime_s, 0.0)
        return ControllerState(
            list(self.joint_names),
            desired_p.copy(),
            desired_v.copy(),
            desired_a.copy(),
            self._actual.copy(),
            self._actual_velocity.copy(),
            elapsed,
            self.active_goal_id,
        )

    # ------------------------------------------------------------------------------------ settings
    def set_speed_slider(self, fraction: float) -> bool:
        """Sets the speed slider (fraction in [0.01, 1]); False (unchanged) outside, as the driver answers."""
        fraction = float(fraction)
        if not (math.isfinite(fraction) and SPEED_SLIDER_RANGE[0] <= fraction <= SPEED_SLIDER_RANGE[1]):
            return False
        self.speed_slider_fraction = fraction
        return True

    def set_program_running(self, running: bool, now_s: float) -> list[GoalOutcome]:
        """Starts or stops the robot program. Stopping halts the robot and preempts the active goal; starting is
        refused (False in the second item) while protective-stopped."""
        ended = self.update(now_s)
        if running:
            if self.protective_stopped:
                raise PlacementRefused("the robot is protective-stopped: unlock the protective stop first")
            if not self.program_running:
                self.program_running = True
                self._hold(self._actual.copy(), self._uptime_s)  # the controller starts: hold where the robot is
            return ended
        if self.program_running:
            self.program_running = False
            ended += self._halt("the robot program stopped")
        return ended

    def protective_stop(self, now_s: float) -> list[GoalOutcome]:
        """A protective stop: the robot halts, the program stops, the active goal ends PREEMPTED."""
        ended = self.update(now_s)
        self.protective_stopped = True
        self.program_running = False
        self._actual_velocity = np.zeros(self.dof)
        ended += self._halt("protective stop")
        return ended

    def unlock_protective_stop(self) -> bool:
        """Clears a protective stop (the program stays stopped); False when there was none."""
        was = self.protective_stopped
        self.protective_stopped = False
        return was

    def place(self, positions_rad: Sequence[float]) -> np.ndarray:
        """Puts the robot at ``positions_rad`` at once (simulation only); refused while a goal is active."""
        if self._active is not None:
            raise PlacementRefused("refused: a trajectory is executing")
        state = np.asarray(list(positions_rad), dtype=float)
        if state.shape != (self.dof,):
            raise PlacementRefused(f"expected {self.dof} positions, got {state.size}")
        if not np.all(np.isfinite(state)):
            raise PlacementRefused("positions must be finite")
        self._actual = state.copy()
        self._actual_velocity = np.zeros(self.dof)
        self._hold(state, self._uptime_s)
        self._desired = (state.copy(), np.zeros(self.dof), np.zeros(self.dof))
        return state

    # ------------------------------------------------------------------------------------ goals
    def accept(self, goal: TrajectoryGoal, now_s: float) -> tuple[int, list[GoalOutcome]]:
        """Checks ``goal`` and makes it the active one; returns its id and the goals that ended meanwhile (the
        preempted previous one among them). Raises :class:`GoalRejected`."""
        ended = self.update(now_s)
        if not self.program_running or self.protective_stopped:
            raise GoalRejected(ErrorCode.INVALID_GOAL, "Can't accept new action goals. Controller is not running.")
        order = self._joint_order(goal.joint_names)
        points = self._checked_points(goal, order)
        start_uptime = self._uptime_s + (goal.start_s - now_s if goal.start_s > 0.0 else 0.0)
        kept = [p for p in points if start_uptime + p[0] > self._uptime_s]
        if not kept:
            raise GoalRejected(
                ErrorCode.INVALID_GOAL,
                f"Dropping all {len(points)} trajectory point(s), as they occur before the current time.",
            )
        if kept[0][0] == 0.0:
            kept = kept[1:]  # "Dropping first trajectory point at time=0"
            if not kept:
                kept = [points[0]]
        segments = []
        p0, v0, a0 = (x.copy() for x in self._desired)
        t0 = self._uptime_s
        first_has_v = kept[0][2] is not None
        first_has_a = kept[0][3] is not None
        for time_s, pos, vel, acc in kept:
            t1 = start_uptime + time_s
            if not segments:
                segments.append(
                    _Segment(
                        t0,
                        t1,
                        p0,
                        pos,
                        v0 if first_has_v else None,
                        vel,
                        a0 if first_has_a else None,
                        acc,
                    )
                )
            else:
                last = segments[-1]
                segments.append(_Segment(last.t1, t1, last.p1, pos, last.v1, vel, last.a1, acc))
        goal_id = self._next_id
        self._next_id += 1
        path_p, path_v = self._tolerances(goal.path_tolerance, self.constraints.path_rad, 0.0, "path")
        goal_p, goal_v = self._tolerances(
            goal.goal_tolerance, self.constraints.goal_rad, self.constraints.stopped_velocity_rad_s, "goal"
        )
        if goal.goal_time_tolerance_s > 0.0:
            goal_time = float(goal.goal_time_tolerance_s)
        elif goal.goal_time_tolerance_s < 0.0:
            goal_time = 0.0
        else:
            goal_time = self.constraints.goal_time_s
        if self._active is not None:
            ended.append(GoalOutcome(self._active.goal_id, GoalEnd.PREEMPTED))
        self._active = _ActiveGoal(goal_id, segments, start_uptime, path_p, path_v, goal_p, goal_v, goal_time)
        return goal_id, ended

    def cancel(self, goal_id: int, now_s: float) -> list[GoalOutcome]:
        """A client's cancel: the goal ends PREEMPTED at once, the robot stops along the stop trajectory."""
        ended = self.update(now_s)
        if self._active is None or self._active.goal_id != goal_id:
            return ended
        ended.append(GoalOutcome(goal_id, GoalEnd.PREEMPTED))
        self._active = None
        p, v, _ = self._desired
        stop_at = p + v * self.stop_duration_s / 2.0  # decelerating evenly to rest
        self._segments = [
            _Segment(self._uptime_s, self._uptime_s + self.stop_duration_s, p, stop_at, v, np.zeros(self.dof))
        ]
        return ended

    def halt(self, goal_id: int, now_s: float) -> list[GoalOutcome]:
        """Ends ``goal_id`` PREEMPTED and stops the robot where it is at once (the deprecated alias's cancel)."""
        ended = self.update(now_s)
        if self._active is None or self._active.goal_id != goal_id:
            return ended
        return ended + self._halt("")

    # ------------------------------------------------------------------------------------ control loop
    def update(self, now_s: float) -> list[GoalOutcome]:
        """Advances the controller and the robot to ``now_s``; returns the goals that ended."""
        dt = float(now_s) - self._last_time_s
        if dt <= 0.0:
            return []
        self._last_time_s = float(now_s)
        self._uptime_s += dt * self.speed_scaling
        if self.protective_stopped:
            return []
        self._desired = self._sample(self._uptime_s)
        self._track(dt)
        return self._check()

    def _sample(self, uptime: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        segments = self._active.segments if self._active is not None else self._segments
        for segment in segments:
            if uptime < segment.t1:
                return segment.sample(uptime)
        last = segments[-1]
        return last.p1.copy(), np.zeros(self.dof), np.zeros(self.dof)

    def _track(self, dt: float) -> None:
        target = self._desired[0]
        if self.tracking_time_constant_s > 0.0:
            step = (target - self._actual) * (1.0 - math.exp(-dt / self.tracking_time_constant_s))
        else:
            step = target - self._actual
        step = np.clip(step, -self.velocity_limits * dt, self.velocity_limits * dt)
        self._actual = self._actual + step
        self._actual_velocity = step / dt

    def _check(self) -> list[GoalOutcome]:
        goal = self._active
        if goal is None:
            return []
        error = self._desired[0] - self._actual
        velocity_error = self._desired[1] - self._actual_velocity
        if self._uptime_s < goal.end_uptime_s:
            joint = self._violation(error, goal.path_rad)
            if joint is None:
                joint = self._violation(velocity_error, goal.path_velocity_rad_s)
            if joint is not None:
                value = error[joint] if abs(error[joint]) > goal.path_rad[joint] > 0 else velocity_error[joint]
                return self._end_aborted(
                    ErrorCode.PATH_TOLERANCE_VIOLATED, f"{self.joint_names[joint]} path error {value:f}"
                )
            return []
        joint = self._violation(error, goal.goal_rad)
        if joint is None:
            joint = self._violation(self._actual_velocity, goal.goal_velocity_rad_s)
        if joint is None:
            self._active = None
            self._hold_end(goal)
            return [GoalOutcome(goal.goal_id, GoalEnd.SUCCEEDED)]
        if self._uptime_s < goal.end_uptime_s + goal.goal_time_tolerance_s:
            return []
        value = error[joint] if abs(error[joint]) > goal.goal_rad[joint] > 0 else self._actual_velocity[joint]
        return self._end_aborted(ErrorCode.GOAL_TOLERANCE_VIOLATED, f"{self.joint_names[joint]} goal error {value:f}")

    @staticmethod
    def _violation(values: np.ndarray, tolerance: np.ndarray) -> int | None:
        bad = np.flatnonzero((tolerance > 0.0) & (np.abs(values) > tolerance))
        return int(bad[0]) if bad.size else None

    def _end_aborted(self, code: ErrorCode, text: str) -> list[GoalOutcome]:
        goal = self._active
        self._active = None
        self._hold(self._actual.copy(), self._uptime_s)  # the JTC holds the current position on an abort
        return [GoalOutcome(goal.goal_id, GoalEnd.ABORTED, code, text)]

    def _hold_end(self, goal: _ActiveGoal) -> None:
        self._segments = [goal.segments[-1]]

    def _hold(self, positions: np.ndarray, now_uptime: float) -> None:
        self._segments = [_Segment(now_uptime, now_uptime, positions.copy(), positions.copy())]

    def _halt(self, _reason: str) -> list[GoalOutcome]:
        ended = []
        if self._active is not None:
            ended.append(GoalOutcome(self._active.goal_id, GoalEnd.PREEMPTED))
            self._active = None
        self._hold(self._actual.copy(), self._uptime_s)
        self._desired = (self._actual.copy(), np.zeros(self.dof), np.zeros(self.dof))
        self._actual_velocity = np.zeros(self.dof)
        return ended

    # ------------------------------------------------------------------------------------ goal checks
    def _joint_order(self, names: Sequence[str]) -> list[int]:
        names = list(names)
        if len(names) != self.dof or sorted(names) != sorted(self.joint_names):
            raise GoalRejected(ErrorCode.INVALID_JOINTS, "Joints on incoming goal don't match the controller joints.")
        return [names.index(name) for name in self.joint_names]

    def _checked_points(self, goal: TrajectoryGoal, order: list[int]) -> list[tuple]:
        if not goal.points:
            raise GoalRejected(ErrorCode.INVALID_GOAL, "Trajectory message contains no waypoints.")
        previous = -math.inf
        points = []
        n = self.dof
        for i, point in enumerate(goal.points):
            t = float(point.time_from_start_s)
            if not math.isfinite(t) or t < 0.0:
                raise GoalRejected(ErrorCode.INVALID_GOAL, f"Trajectory point {i} has an invalid time_from_start.")
            if t <= previous:
                raise GoalRejected(
                    ErrorCode.INVALID_GOAL,
                    "Trajectory message contains waypoints that are not strictly increasing in time.",
                )
            previous = t
            vectors = []
            for label, values, required in (
                ("positions", point.positions, True),
                ("velocities", point.velocities, False),
                ("accelerations", point.accelerations, False),
            ):
                if not required and len(values) == 0:
                    vectors.append(None)
                    continue
                if len(values) != n:
                    raise GoalRejected(
                        ErrorCode.INVALID_GOAL,
                        f"Size mismatch in trajectory point {i} {label}: expected {n}, got {len(values)}.",
                    )
                if not _finite(values):
                    raise GoalRejected(ErrorCode.INVALID_GOAL, f"Trajectory point {i} {label} are not finite.")
                vectors.append(np.array([float(values[j]) for j in order]))
            points.append((t, *vectors))
        return points

    def _tolerances(
        self, overrides: Sequence[JointTolerance], position: float, velocity: float, what: str
    ) -> tuple[np.ndarray, np.ndarray]:
        pos = np.full(self.dof, float(position))
        vel = np.full(self.dof, float(velocity))
        for tolerance in overrides:
            if tolerance.name not in self.joint_names:
                continue  # the JTC ignores tolerances of unknown joints
            j = self.joint_names.index(tolerance.name)
            if not (math.isfinite(tolerance.position) and math.isfinite(tolerance.velocity)):
                raise GoalRejected(ErrorCode.INVALID_GOAL, f"{what} tolerance of {tolerance.name} is not finite.")
            if tolerance.position > 0.0:
                pos[j] = tolerance.position
            elif tolerance.position < 0.0:
                pos[j] = 0.0
            if tolerance.velocity > 0.0:
                vel[j] = tolerance.velocity
            elif tolerance.velocity < 0.0:
                vel[j] = 0.0
        return pos, vel
