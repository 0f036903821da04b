"""The MILD's state and the angle helpers every part of its robot model uses.

A robot state is (pan, tilt, rotation, x, y) in that order (RobotStateMessage's field order): pan and tilt of the
pan-tilt unit (rad), the base's rotation about the map's z (rad) and its position (m, map frame). A camera looks
along the +x axis of its orientation (quaternions are (x, y, z, w), geometry_msgs' order).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = [
    "LIMIT_SLACK_RAD",
    "MAX_ABS_ANGLE_RAD",
    "MAX_ABS_POSITION_M",
    "TWO_PI",
    "RobotState",
    "angle_between",
    "check_pose",
    "check_position",
    "state_problem",
    "view_directions",
    "wrap_to_2pi",
]

TWO_PI = 2.0 * math.pi
#: largest position (m) a request may name: a map of the robot's world is tens of metres; beyond this a value is a
#: mistake (1e12 gave meaningless poses) and the millimetres are lost
MAX_ABS_POSITION_M = 1e4
#: largest angle (rad) a state may hold: a few hundred turns; beyond, float64 angles lose their micro-radians
MAX_ABS_ANGLE_RAD = 1e3
#: slack on the PTU limits (rad): states computed at a limit must not be refused for rounding
LIMIT_SLACK_RAD = 1e-9
_FIELDS = ("pan", "tilt", "rotation", "x", "y")


def wrap_to_2pi(angle_rad):
    """Angles mapped to [0, 2 pi) (the original's convention for the base rotation)."""
    return np.asarray(angle_rad) % TWO_PI


def view_directions(q_xyzw: np.ndarray) -> np.ndarray:
    """The +x axes (..., 3) of orientations (..., 4): where a camera with that orientation looks."""
    x, y, z, w = np.moveaxis(np.asarray(q_xyzw, dtype=float), -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], -1)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) between unit vectors (..., 3); atan2 keeps them accurate near 0 where arccos is not."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def check_position(position, what: str = "position", size: int | None = None) -> np.ndarray:
    """``position`` (m) as a flat float array if finite and within :data:`MAX_ABS_POSITION_M`, else InputError;
    ``size``: the number of coordinates it must have."""
    p = np.asarray(position, dtype=float).reshape(-1)
    if size is not None and p.shape != (size,):
        raise InputError(f"{what}: expected {size} coordinates, got {p.tolist()}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{what}: position {p.tolist()} is not finite")
    if np.abs(p).max(initial=0.0) > MAX_ABS_POSITION_M:
        raise InputError(
            f"{what}: position {p.tolist()} m lies beyond +-{MAX_ABS_POSITION_M:g} m (no map of the robot's world "
            "is that large)"
        )
    return p


def check_pose(position, orientation_xyzw, what: str = "pose") -> tuple[np.ndarray, np.ndarray]:
    """A finite position within :data:`MAX_ABS_POSITION_M` and a normalised quaternion, or InputError saying what is
    wrong."""
    p = np.asarray(position, dtype=float).reshape(-1)
    q = np.asarray(orientation_xyzw, dtype=float).reshape(-1)
    if p.shape != (3,) or q.shape != (4,):
        raise InputError(f"{what}: expected a position (x, y, z) and a quaternion (x, y, z, w)")
    p = check_position(p, what)
    if not np.all(np.isfinite(q)):
        raise InputError(f"{what}: orientation {q.tolist()} is not finite")
    norm = math.hypot(*q)  # no overflow for huge components, where the sum of squares would give inf
    if not math.isfinite(norm):
        raise InputError(f"{what}: orientation {q.tolist()} is too large to normalise")
    if norm < 1e-9:
        raise InputError(
            f"{what}: orientation {q.tolist()} is a zero quaternion; expected a unit quaternion (x, y, z, w)"
        )
    return p, q / norm


@dataclass(frozen=True)
class RobotState:
    """A MILD configuration: pan and tilt of the PTU (rad), base rotation (rad) and base position x, y (m, map)."""

    pan: float = 0.0
    tilt: float = 0.0
    rotation: float = 0.0
    x: float = 0.0
    y: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.pan, self.tilt, self.rotation, self.x, self.y])

    @classmethod
    def from_array(cls, values) -> RobotState:
        v = np.asarray(values, dtype=float).reshape(5)
        return cls(*(float(a) for a in v))

    def checked(self, what: str = "robot state") -> RobotState:
        """This state if every value is finite, angles within :data:`MAX_ABS_ANGLE_RAD` and x, y within
        :data:`MAX_ABS_POSITION_M`; else InputError naming the value and the bound (PTU limits: :func:`state_problem`)."""
        for name in _FIELDS:
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"{what}: {name} = {getattr(self, name)} is not finite")
        for name in ("pan", "tilt", "rotation"):
            if abs(getattr(self, name)) > MAX_ABS_ANGLE_RAD:
                raise InputError(
                    f"{what}: {name} = {getattr(self, name):.6g} rad lies beyond +-{MAX_ABS_ANGLE_RAD:g} rad"
                )
        for name in ("x", "y"):
            if abs(getattr(self, name)) > MAX_ABS_POSITION_M:
                raise InputError(
                    f"{what}: {name} = {getattr(self, name):.6g} m lies beyond +-{MAX_ABS_POSITION_M:g} m (no map of "
                    "the robot's world is that large)"
                )
        return self


def state_problem(
    state: RobotState, pan_limits_rad: tuple[float, float], tilt_limits_rad: tuple[float, float], what: str = "state"
) -> str:
    """Why the MILD cannot take ``state`` ('' when it can): a value that is not finite, pan or tilt outside the PTU
    limits (named in degrees, with :data:`LIMIT_SLACK_RAD` for rounding), or what :meth:`RobotState.checked` refuses."""
    for name in _FIELDS:
        if not math.isfinite(getattr(state, name)):
            return f"{what}: {name} = {getattr(state, name)} is not finite"
    for name, (low, high) in (("pan", pan_limits_rad), ("tilt", tilt_limits_rad)):
        value = getattr(state, name)
        if not low - LIMIT_SLACK_RAD <= value <= high + LIMIT_SLACK_RAD:
            return (
                f"{what}: {name} {math.degrees(value):.2f} deg outside [{math.degrees(low):.1f}, "
                f"{math.degrees(high):.1f}] deg, the PTU's {name} limits ({name} = {value:.6g} rad)"
            )
    try:
        state.checked(what)
    except InputError as exc:
        return str(exc)
    return ""
