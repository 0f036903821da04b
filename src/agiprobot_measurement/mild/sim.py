"""The simulated MILD's motion: its state, the PTU limits it refuses to leave, and the drive to a commanded state.

Every axis moves at most at its speed limit and all axes finish together (the base turns the shorter way round); a
new command replaces the old one. Time is passed in (seconds on any monotonic clock), so the motion runs without
ROS; the node ``mild_sim`` publishes what :meth:`MildMotion.state_at` returns. Thread-safe.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.state import RobotState, state_problem

__all__ = ["MildMotion", "MotionRefused"]


class MotionRefused(InputError):
    """A state the simulated MILD cannot take: not finite, or pan or tilt outside the PTU limits."""


@dataclass(frozen=True)
class _Drive:
    start: np.ndarray  # (pan, tilt, rotation, x, y) where the drive began
    delta: np.ndarray  # what it adds by its end (rotation: the shorter way round)
    started_s: float
    duration_s: float


class MildMotion:
    """State and drive of the simulated MILD.

    ``max_velocity``: pan, tilt, base rotation (rad/s) and base translation (m/s, one limit for the distance
    driven), as :attr:`agiprobot_measurement.mild.config.MildKinematics.max_velocity`.
    """

    def __init__(
        self,
        initial: RobotState,
        pan_limits_rad: tuple[float, float],
        tilt_limits_rad: tuple[float, float],
        max_velocity: tuple[float, float, float, float],
    ):
        self.pan_limits_rad = tuple(pan_limits_rad)
        self.tilt_limits_rad = tuple(tilt_limits_rad)
        self.max_velocity = np.asarray(max_velocity, dtype=float)
        self._lock = threading.Lock()
        self.check(initial)
        self._state = initial.as_array()
        self._drive: _Drive | None = None

    def problem(self, state: RobotState) -> str:
        """Why the MILD cannot take ``state`` ('' when it can): the same check as the robot model services'."""
        return state_problem(state, self.pan_limits_rad, self.tilt_limits_rad, "state")

    def check(self, state: RobotState) -> None:
        """:class:`MotionRefused` with :meth:`problem`'s reason unless the MILD can take ``state``."""
        problem = self.problem(state)
        if problem:
            raise MotionRefused(problem)

    @property
    def moving(self) -> bool:
        with self._lock:
            return self._drive is not None

    def place(self, state: RobotState) -> None:
        """Put the MILD at ``state`` at once (simulation only); stops any drive."""
        self.check(state)
        with self._lock:
            self._state, self._drive = state.as_array(), None

    def command(self, target: RobotState, now_s: float) -> float:
        """Start driving to ``target`` from the state last returned by :meth:`state_at` (what was last published);
        returns the drive's duration (s)."""
        self.check(target)
        with self._lock:
            start = self._state.copy()
            delta = target.as_array() - start
            delta[2] = wrap_to_pi(delta[2])  # the shorter way round
            distance = math.hypot(delta[3], delta[4])
            duration = max(np.abs(delta[:3] / self.max_velocity[:3]).max(), distance / self.max_velocity[3])
            self._drive = _Drive(start, delta, float(now_s), float(duration))
        return float(duration)

    def state_at(self, now_s: float) -> RobotState:
        """The state at ``now_s`` (the drive advanced to then; at its end the rotation is wrapped to [-pi, pi))."""
        with self._lock:
            return RobotState.from_array(self._advance(now_s))

    def _advance(self, now_s: float) -> np.ndarray:
        drive = self._drive
        if drive is not None:
            fraction = 1.0 if drive.duration_s <= 0 else min(1.0, (now_s - drive.started_s) / drive.duration_s)
            self._state = drive.start + fraction * drive.delta
            if fraction >= 1.0:
                self._state[2] = float(wrap_to_pi(self._state[2]))
                self._drive = None
        return self._state
