"""Synchronised point-to-point joint motion: the fastest straight joint-space move within the limits.

Every joint follows the same normalised trapezoidal (or triangular) velocity profile, scaled so that the
slowest joint just meets its velocity and acceleration limit; the motion is a straight line in joint space.
Used for direct moves between known collision-free states (named states, tests); the planner's paths are
time-parameterised by :mod:`agiprobot_measurement.motion.time_parameterization`.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.motion.errors import MotionInputError
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.station import JointLimits

__all__ = [
    "point_to_point",
]


def point_to_point(
    start: np.ndarray,
    goal: np.ndarray,
    limits: JointLimits,
    velocity_scaling: float = 1.0,
    acceleration_scaling: float = 1.0,
    sample_period_s: float = 0.05,
) -> JointTrajectory:
    """Trajectory (rad, s) from ``start`` to ``goal``, at rest at both ends, sampled every ``sample_period_s``."""
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    n = len(limits.names)
    if start.shape != (n,) or goal.shape != (n,):
        raise MotionInputError(f"expected {n} joint values for start and goal, got {start.shape} and {goal.shape}")
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(goal))):
        raise MotionInputError("start and goal must be finite")
    for name, value in (
        ("velocity_scaling", velocity_scaling),
        ("acceleration_scaling", acceleration_scaling),
    ):
        if not 0.0 < value <= 1.0:
            raise MotionInputError(f"{name} must lie in (0, 1], got {value}")
    for label, state in (("start", start), ("goal", goal)):
        if not limits.within_position_limits(state, 1e-9):
            raise MotionInputError(f"{label} state is outside the joint limits")
    delta = goal - start
    distance = np.abs(delta)
    v_max = limits.max_velocity * velocity_scaling
    a_max = limits.max_acceleration * acceleration_scaling
    if np.all(distance < 1e-12):
        return JointTrajectory(list(limits.names), [0.0], start[None], np.zeros((1, n)), np.zeros((1, n)))
    # per joint: duration of its own fastest trapezoid; the slowest joint sets the common duration
    triangular = distance < v_max**2 / a_max
    own_duration = np.where(triangular, 2.0 * np.sqrt(distance / a_max), distance / v_max + v_max / a_max)
    duration = float(own_duration.max())
    # common normalised profile s(t) in [0, 1]: accelerate for t_a, cruise, decelerate for t_a.
    # Choose the normalised peak speed so every joint stays within both limits.
    # For a trapezoid of duration T with blend t_a: peak s' = 1 / (T - t_a), s'' = s' / t_a.
    # The binding joint j has the smallest ratio; solve for t_a giving v = v_max_j or triangular.
    j = int(np.argmax(own_duration))
    if triangular[j]:
        t_a = duration / 2.0
    else:
        t_a = v_max[j] / a_max[j]
    peak = 1.0 / (duration - t_a)
    # verify against all joints (distance * s' <= v_max, distance * s'' <= a_max); stretch if needed
    scale = max(1.0, float(np.max(distance * peak / v_max)), float(np.sqrt(np.max(distance * peak / t_a / a_max))))
    duration *= scale
    t_a *= scale
    peak = 1.0 / (duration - t_a)
    count = max(2, int(np.ceil(duration / sample_period_s)) + 1)
    t = np.linspace(0.0, duration, count)
    acc_phase = t < t_a
    dec_phase = t > duration - t_a
    s = np.where(
        acc_phase,
        0.5 * peak / t_a * t**2,
        np.where(dec_phase, 1.0 - 0.5 * peak / t_a * (duration - t) ** 2, peak * (t - 0.5 * t_a)),
    )
    ds = np.where(acc_phase, peak / t_a * t, np.where(dec_phase, peak / t_a * (duration - t), peak))
    dds = np.where(acc_phase, peak / t_a, np.where(dec_phase, -peak / t_a, 0.0))
    ds[[0, -1]] = 0.0
    s[-1] = 1.0
    return JointTrajectory(
        list(limits.names),
        t,
        start + s[:, None] * delta,
        ds[:, None] * delta,
        dds[:, None] * delta,
    )
