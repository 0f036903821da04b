"""The simulated robot controller behind ``robot_sim``, without ROS.

``SimulatedController`` holds the robot's joint state (rad, rad/s), decides whether a trajectory goal is accepted
(``check_trajectory``: names, finite values, strictly increasing time, start at the current state, position /
velocity / acceleration limits of the interpolated motion) and follows an accepted one in the clock's time with
the trajectory's cubic interpolation; a cancel stops the robot where it is. ``place`` puts the robot at a named
state or at given positions at once (simulation only), refused while a trajectory runs.

The ROS layer supplies the small interfaces: a :class:`ControllerClock` (ROS time, so also simulated time), a
:class:`JointStatePublisher` (``/joint_states``) and, per goal, a :class:`GoalChannel` (cancel requests and
feedback of the action server).
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.trajectory import CheckTolerances, JointTrajectory, check_trajectory
from agiprobot_measurement.station import JointLimits

__all__ = [
    "FEEDBACK_PERIOD_S",
    "ControllerClock",
    "ExecutionOutcome",
    "ExecutionStatus",
    "GoalChannel",
    "JointStatePublisher",
    "PlacementRefused",
    "Rate",
    "SimulatedController",
    "resolve_initial_state",
]

FEEDBACK_PERIOD_S = 0.1  # at most this often a goal gets progress feedback, in clock time


class Rate(Protocol):
    """Keeps a loop at a fixed rate (``rospy.Rate``)."""

    def sleep(self) -> None: ...


class ControllerClock(Protocol):
    """The time the controller moves in (ROS time: wall or simulated)."""

    def now_s(self) -> float:
        """The current time, seconds."""

    def is_shutdown(self) -> bool:
        """Whether the process is shutting down (the loop stops following then)."""

    def rate(self, rate_hz: float) -> Rate:
        """A loop rate of ``rate_hz`` Hz."""


class JointStatePublisher(Protocol):
    """Where the controller's state goes (``/joint_states``)."""

    def publish_joint_state(
        self, joint_names: Sequence[str], positions_rad: Sequence[float], velocities_rad_s: Sequence[float]
    ) -> None: ...


class GoalChannel(Protocol):
    """One trajectory goal's link to its client."""

    def is_cancel_requested(self) -> bool: ...

    def publish_feedback(self, progress: float, time_from_start_s: float) -> None:
        """``progress`` in [0, 1] of the trajectory's duration, ``time_from_start_s`` the time followed so far."""


class ExecutionStatus(enum.Enum):
    SUCCEEDED = "succeeded"
    REJECTED = "rejected"  # the trajectory failed the checks; nothing moved
    CANCELLED = "cancelled"  # stopped where the robot was when the cancel came
    SHUTDOWN = "shutdown"  # the process stops; the robot was put at the trajectory's end, no result is due


@dataclass(frozen=True)
class ExecutionOutcome:
    """How a goal ended; ``message`` is the reason of a rejection or the cancel report, empty on success."""

    status: ExecutionStatus
    message: str = ""


class PlacementRefused(InputError):
    """``place`` was refused: unknown named state, wrong positions, or a trajectory is running."""


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


class SimulatedController:
    """A joint-space controller that follows checked trajectories perfectly, at ``rate_hz`` steps per second."""

    def __init__(
        self,
        joint_names: Sequence[str],
        limits: JointLimits,
        named_states: Mapping[str, np.ndarray],
        initial_positions_rad: np.ndarray,
        clock: ControllerClock,
        publisher: JointStatePublisher,
        rate_hz: float = 100.0,
        tolerances: CheckTolerances | None = None,
    ):
        self.joint_names = list(joint_names)
        self.limits = limits
        self.named_states = dict(named_states)
        self.clock = clock
        self.publisher = publisher
        self.rate_hz = float(rate_hz)
        self.tolerances = CheckTolerances() if tolerances is None else tolerances
        self._lock = threading.Lock()
        self._positions = np.array(initial_positions_rad, dtype=float)
        self._velocities = np.zeros(len(self.joint_names))
        self.executing = False

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the positions (rad) and velocities (rad/s), in ``joint_names`` order."""
        with self._lock:
            return self._positions.copy(), self._velocities.copy()

    def publish_state(self) -> None:
        """Sends the current state to the publisher (the node calls it at ``rate_hz``)."""
        with self._lock:
            positions, velocities = self._positions.tolist(), self._velocities.tolist()
        self.publisher.publish_joint_state(self.joint_names, positions, velocities)

    def _set_state(self, positions: np.ndarray, velocities: np.ndarray | None = None) -> None:
        with self._lock:
            self._positions = positions
            self._velocities = np.zeros(self.dof) if velocities is None else velocities

    # ------------------------------------------------------------------------------------ placing
    def place(self, named_state: str = "", positions_rad: Sequence[float] | None = None) -> np.ndarray:
        """Puts the robot at ``named_state`` or else at ``positions_rad`` at once and returns the new state.

        Raises :class:`PlacementRefused` with the reason while a trajectory runs or when the state is unknown,
        of the wrong length, not finite, or outside the position limits (a named state is trusted).
        """
        if self.executing:
            raise PlacementRefused("refused: a trajectory is executing")
        if named_state:
            if named_state not in self.named_states:
                raise PlacementRefused(f"unknown named state '{named_state}' (known: {list(self.named_states)})")
            state = np.array(self.named_states[named_state], dtype=float)
        else:
            given = [] if positions_rad is None else list(positions_rad)
            state = np.asarray(given, dtype=float)
            if state.shape != (self.dof,):
                raise PlacementRefused(f"expected {self.dof} positions, got {len(given)}")
            if not np.all(np.isfinite(state)):
                raise PlacementRefused("positions must be finite")
            if not self.limits.within_position_limits(state):
                raise PlacementRefused("positions outside the joint limits")
        self._set_state(state)
        return state

    # ------------------------------------------------------------------------------------ executing
    def execute(self, trajectory: JointTrajectory, goal: GoalChannel) -> ExecutionOutcome:
        """Checks ``trajectory`` against the limits and the current state, then follows it (see the module)."""
        current, _ = self.state()
        verdict = check_trajectory(trajectory, self.limits, current, self.tolerances)
        if not verdict.ok:
            return ExecutionOutcome(ExecutionStatus.REJECTED, verdict.reason)
        trajectory = trajectory.reordered(self.joint_names)
        self.executing = True
        try:
            return self._follow(trajectory, goal)
        finally:
            self.executing = False

    def _follow(self, trajectory: JointTrajectory, goal: GoalChannel) -> ExecutionOutcome:
        rate = self.clock.rate(self.rate_hz)
        start_s = self.clock.now_s()
        duration = trajectory.duration
        last_feedback = -1.0
        while not self.clock.is_shutdown():
            elapsed = self.clock.now_s() - start_s
            if goal.is_cancel_requested():
                with self._lock:
                    self._velocities = np.zeros(self.dof)
                    stopped_at = self._positions.copy()
                return ExecutionOutcome(
                    ExecutionStatus.CANCELLED,
                    f"cancelled after {elapsed:.2f} s of {duration:.2f} s; stopped at {np.round(stopped_at, 4).tolist()}",
                )
            if elapsed >= duration:
                break
            pos, vel, _ = trajectory.sample(np.array([elapsed]))
            self._set_state(pos[0], vel[0])
            if elapsed - last_feedback >= FEEDBACK_PERIOD_S:
                goal.publish_feedback(float(elapsed / duration) if duration > 0 else 1.0, elapsed)
                last_feedback = elapsed
            rate.sleep()
        self._set_state(trajectory.end.copy())
        if self.clock.is_shutdown():
            return ExecutionOutcome(ExecutionStatus.SHUTDOWN)
        goal.publish_feedback(1.0, duration)
        return ExecutionOutcome(ExecutionStatus.SUCCEEDED)
