"""Time parameterisation of joint paths: time-optimal (TOPP-RA) and constant Cartesian speed for scan lines.

A joint path is a (K, n) array of waypoints in rad. It is interpolated by a cubic spline (scipy, not-a-knot)
over a path parameter ``s`` and re-timed with toppra's TOPP-RA under per-joint velocity (rad/s) and
acceleration (rad/s^2) limits; the result is sampled into a :class:`~agiprobot_measurement.motion.trajectory.
JointTrajectory` with positions, velocities and accelerations, starting and ending at rest.

Guarantee: the produced trajectory's peak |velocity| and |acceleration|, measured the way
:func:`~agiprobot_measurement.motion.trajectory.check_trajectory` judges them (cubic Hermite interpolation through
the knots for velocities, listed knot values for accelerations), and the peak acceleration of the underlying
continuous motion at every toppra grid point, are within the (scaled) limits. TOPP-RA enforces its
constraints only at its grid points, so its output can overshoot slightly between them; the trajectory is then
slowed down uniformly (time scaling by ``k``: velocities / k, accelerations / k^2) until the measured peaks
fit.

The spline passes through every waypoint but not along the straight segments between sparse waypoints; pass
``max_waypoint_step_rad`` to densify such paths (e.g. a planner's collision-checked polyline) first.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint
from scipy.interpolate import CubicSpline

from agiprobot_measurement.common.config import ConfigError, number
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.trajectory import JointTrajectory, motion_peaks
from agiprobot_measurement.station import JointLimits

__all__ = [
    "CRUISE_ACCELERATION_SHARE",
    "CRUISE_SPEED_TOLERANCE",
    "CRUISE_VELOCITY_SHARE",
    "DUPLICATE_WAYPOINT_RAD",
    "GRID_MAX_ERROR",
    "LIMIT_MARGIN",
    "MAX_INTERVALS_PER_WAYPOINT",
    "MAX_RETIMING_ROUNDS",
    "MIN_GRID_INTERVALS",
    "TOPPRA_SHARE",
    "UNBOUNDED_PATH_ACCELERATION_MM_S2",
    "ScanTrajectory",
    "TimeParameterizationError",
    "constant_speed_scan_trajectory",
    "time_optimal_trajectory",
]

# Consecutive waypoints closer than this (rad, max-norm) are one waypoint: a zero-length spline interval would
# make the path parameter non-increasing.
DUPLICATE_WAYPOINT_RAD = 1e-9
# toppra grid refinement: maximum estimated interpolation error of a grid interval (path units).
GRID_MAX_ERROR = 1e-4
MIN_GRID_INTERVALS = 100
MAX_INTERVALS_PER_WAYPOINT = 64
# Peaks are compared against limit * (1 - this) so floating-point noise never lands on the wrong side.
LIMIT_MARGIN = 1e-9
# toppra gets the limits times this: its solutions sit exactly on the limits it is given, and a hair below
# ours they pass the check without a needless retiming round.
TOPPRA_SHARE = 1.0 - 1e-6
MAX_RETIMING_ROUNDS = 8
# Share of the joint acceleration a scan's cruise may use for the path curvature term q_ss * s_dot^2; the
# rest stays available to hold the speed.
CRUISE_ACCELERATION_SHARE = 0.9
# Share of the joint velocity limit a scan's cruise may use: toppra's velocity constraint (see TOPPRA_SHARE) must
# not bind before the speed cap, or the cruise would not be exactly constant.
CRUISE_VELOCITY_SHARE = 1.0 - 1e-4
# Cruise detection: path speed within this relative distance of the cruise speed.
CRUISE_SPEED_TOLERANCE = 1e-6
# Path acceleration bound (mm/s^2) of a scan's virtual "path joint" when the caller sets none: effectively
# unbounded, the joint acceleration limits bind first.
UNBOUNDED_PATH_ACCELERATION_MM_S2 = 1e7


class TimeParameterizationError(InputError):
    """A joint path cannot be time-parameterised (bad input, or toppra found no solution)."""


# ------------------------------------------------------------------------------------------- helpers
def _limits_in_order(limits: JointLimits, joint_names) -> tuple[list[str], JointLimits]:
    if joint_names is None:
        return list(limits.names), limits
    joint_names = [str(n) for n in joint_names]
    if sorted(joint_names) != sorted(limits.names) or len(set(joint_names)) != len(joint_names):
        raise TimeParameterizationError(
            f"joint names {joint_names} do not match the limits' joints {list(limits.names)}"
        )
    order = [limits.names.index(n) for n in joint_names]
    return joint_names, JointLimits(
        tuple(joint_names),
        limits.lower[order],
        limits.upper[order],
        limits.max_velocity[order],
        limits.max_acceleration[order],
    )


def _scaling(value: float, name: str) -> float:
    """A scaling factor in (0, 1], checked by :func:`common.config.number`."""
    try:
        return number(value, name, low=0.0, high=1.0, low_inclusive=False)
    except ConfigError as exc:
        raise TimeParameterizationError(str(exc)) from exc


def _waypoints(waypoints_rad, limits: JointLimits, names: list[str]) -> np.ndarray:
    try:
        q = np.array(waypoints_rad, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TimeParameterizationError(f"waypoints must be numbers (rad): {exc}") from exc
    n = len(names)
    if q.ndim == 1 and q.shape[0] == n:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != n:
        raise TimeParameterizationError(
            f"waypoints must have shape (K, {n}) for joints {', '.join(names)}; got shape {q.shape}"
        )
    if q.shape[0] == 0:
        raise TimeParameterizationError("the path has no waypoints")
    bad = ~np.all(np.isfinite(q), axis=1)
    if np.any(bad):
        raise TimeParameterizationError(f"waypoint {int(np.argmax(bad))} contains NaN or infinite values")
    outside = (q < limits.lower) | (q > limits.upper)
    if np.any(outside):
        i, j = (int(x) for x in np.argwhere(outside)[0])
        raise TimeParameterizationError(
            f"waypoint {i}: {names[j]} = {q[i, j]:.6f} rad lies outside its position limits "
            f"[{limits.lower[j]}, {limits.upper[j]}]"
        )
    return q


def _densify(q: np.ndarray, max_step_rad: float) -> np.ndarray:
    rows = [q[:1]]
    for a, b in itertools.pairwise(q):
        count = max(1, int(np.ceil(np.max(np.abs(b - a)) / max_step_rad)))
        piece = a + np.outer(np.arange(1, count + 1) / count, b - a)
        piece[-1] = b  # the original waypoint exactly, not up to round-off
        rows.append(piece)
    return np.vstack(rows)


def _rest_trajectory(q: np.ndarray, names: list[str], frame_id: str) -> JointTrajectory:
    n = len(names)
    return JointTrajectory(names, [0.0], q[None, :], np.zeros((1, n)), np.zeros((1, n)), frame_id)


@dataclass
class _Timing:
    """A TOPP-RA solution: path spline, grid points ``ss``, path speeds ``sd`` and the grid times."""

    spline: CubicSpline
    ss: np.ndarray
    sd: np.ndarray
    ts: np.ndarray
    us: np.ndarray  # constant path acceleration on each grid interval

    @classmethod
    def solve(
        cls,
        spline: CubicSpline,
        s_waypoints: np.ndarray,
        max_velocity: np.ndarray,
        max_acceleration: np.ndarray,
    ) -> _Timing:
        # toppra's solver works with absolute tolerances and fails on path speeds of 1e3 (a scan line in mm):
        # it gets the path over u = (s - s0) / length in [0, 1]. A not-a-knot spline over affinely mapped knots
        # is the same curve, so the toppra path and ``spline`` agree. The grid holds every waypoint, so their
        # times are exact.
        s0, length = float(s_waypoints[0]), float(s_waypoints[-1] - s_waypoints[0])
        path = toppra.SplineInterpolator((s_waypoints - s0) / length, spline(s_waypoints))
        ss = _grid(spline, s_waypoints)
        constraints = [
            toppra.constraint.JointVelocityConstraint(TOPPRA_SHARE * np.column_stack([-max_velocity, max_velocity])),
            toppra.constraint.JointAccelerationConstraint(
                TOPPRA_SHARE * np.column_stack([-max_acceleration, max_acceleration]),
                discretization_scheme=toppra.constraint.DiscretizationType.Interpolation,
            ),
        ]
        instance = toppra.algorithm.TOPPRA(
            constraints, path, gridpoints=(ss - s0) / length, parametrizer="ParametrizeConstAccel"
        )
        _, ud, _, _ = instance.compute_parameterization(0.0, 0.0, return_data=True)
        code = instance.problem_data.return_code
        if ud is None or code != toppra.algorithm.ParameterizationReturnCode.Ok:
            raise TimeParameterizationError(f"toppra found no time parameterisation: {code.value}")
        sd = np.maximum(np.asarray(ud, dtype=float), 0.0) * length
        sd[0] = sd[-1] = 0.0  # start and end at rest exactly, not at solver round-off
        mean = sd[:-1] + sd[1:]
        if np.any(mean <= 0.0):
            i = int(np.argmax(mean <= 0.0))
            raise TimeParameterizationError(f"toppra stopped the path at s = {ss[i]:.6g} (zero path speed)")
        ds = np.diff(ss)
        ts = np.concatenate([[0.0], np.cumsum(2.0 * ds / mean)])
        us = 0.5 * (sd[1:] ** 2 - sd[:-1] ** 2) / ds
        return cls(spline, ss, sd, ts, us)

    def evaluate(self, times: np.ndarray) -> tuple[np.ndarray, ...]:
        """Path position, speed, acceleration and joint q, qd, qdd at ``times`` (s)."""
        i = np.clip(np.searchsorted(self.ts, times, side="right") - 1, 0, len(self.us) - 1)
        dt = times - self.ts[i]
        s = np.clip(self.ss[i] + self.sd[i] * dt + 0.5 * self.us[i] * dt**2, self.ss[0], self.ss[-1])
        sdot = np.maximum(self.sd[i] + self.us[i] * dt, 0.0)
        sddot = self.us[i]
        q_s, q_ss = self.spline(s, 1), self.spline(s, 2)
        q = self.spline(s)
        qd = q_s * sdot[:, None]
        qdd = q_ss * sdot[:, None] ** 2 + q_s * sddot[:, None]
        return s, sdot, sddot, q, qd, qdd

    def grid_acceleration_peak(self) -> np.ndarray:
        """Peak |joint acceleration| (rad/s^2) of the continuous motion on both sides of every grid point."""
        q_s, q_ss = self.spline(self.ss, 1), self.spline(self.ss, 2)
        centripetal = q_ss * self.sd[:, None] ** 2
        left = centripetal[1:] + q_s[1:] * self.us[:, None]
        right = centripetal[:-1] + q_s[:-1] * self.us[:, None]
        return np.maximum(np.abs(left).max(axis=0), np.abs(right).max(axis=0))


def _grid(spline: CubicSpline, s_waypoints: np.ndarray) -> np.ndarray:
    """TOPP-RA grid: the waypoints, each interval split so 0.5 |q''| ds^2 <= GRID_MAX_ERROR.

    A cubic's second derivative is linear on each interval, so its largest magnitude is at an end: this is
    toppra's ``propose_gridpoints`` criterion, evaluated exactly and vectorised (toppra's loop is slow).
    """
    curvature = np.abs(spline(s_waypoints, 2)).max(axis=1)
    peak = np.maximum(curvature[:-1], curvature[1:])
    lengths = np.diff(s_waypoints)
    with np.errstate(divide="ignore"):
        by_error = np.ceil(lengths / np.sqrt(2.0 * GRID_MAX_ERROR / np.maximum(peak, 1e-300)))
    # At least MIN_GRID_INTERVALS over the whole path; at most MAX_INTERVALS_PER_WAYPOINT per interval.
    # (less a hair, so equally spaced waypoints with round-off all get the same count)
    by_length = np.ceil(lengths / (s_waypoints[-1] - s_waypoints[0]) * MIN_GRID_INTERVALS - 1e-6)
    counts = np.clip(np.maximum(by_error, by_length), 1, MAX_INTERVALS_PER_WAYPOINT).astype(int)
    pieces = [
        np.linspace(a, b, c, endpoint=False) for a, b, c in zip(s_waypoints[:-1], s_waypoints[1:], counts, strict=True)
    ]
    return np.concatenate([*pieces, s_waypoints[-1:]])


def _sample_times(knot_times: np.ndarray, duration_s: float, sample_step_s: float | None) -> np.ndarray:
    if sample_step_s is None:
        return knot_times
    grid = np.arange(0.0, duration_s, sample_step_s)
    # Grid samples too close to a waypoint knot would make tiny Hermite intervals; the waypoint knots stay.
    nearest = np.min(np.abs(grid[:, None] - knot_times[None, :]), axis=1) if len(grid) else grid
    return np.union1d(knot_times, grid[nearest >= 0.25 * sample_step_s])


def _build(
    timing: _Timing,
    s_knots: np.ndarray,
    q_knots: np.ndarray,
    names: list[str],
    limits: JointLimits,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    sample_step_s: float | None,
    frame_id: str,
    joints: slice = slice(None),
    limit_hint: str = "",
) -> tuple[JointTrajectory, float]:
    """Sample the timing into a trajectory, slowed down by the returned factor k >= 1 until peaks fit.
    ``limit_hint``: what the caller's caller can do when the spline leaves the position limits (the error adds it)."""
    knot_times = timing.ts[np.searchsorted(timing.ss, s_knots)]
    times = _sample_times(knot_times, float(timing.ts[-1]), sample_step_s)
    _, _, _, q, qd, qdd = timing.evaluate(times)
    q, qd, qdd = q[:, joints], qd[:, joints], qdd[:, joints]
    qd[0] = qd[-1] = 0.0
    # The knots at the waypoints get the waypoints' own values, not the spline's (equal up to round-off).
    q[np.searchsorted(times, knot_times)] = q_knots
    trajectory = JointTrajectory(names, times, q, qd, qdd, frame_id)

    grid_acc = timing.grid_acceleration_peak()[joints]
    factor = 1.0
    for _ in range(MAX_RETIMING_ROUNDS):
        vel_peak, acc_peak = motion_peaks(trajectory)
        acc_peak = np.maximum(acc_peak, grid_acc / factor**2)
        ratio = max(
            float(np.max(vel_peak / (max_velocity * (1.0 - LIMIT_MARGIN)))),
            float(np.sqrt(np.max(acc_peak / (max_acceleration * (1.0 - LIMIT_MARGIN))))),
        )
        if ratio <= 1.0:
            break
        # Dense re-sampling after scaling can move the measured velocity peak by round-off: overshoot a bit.
        step = ratio * (1.0 + 1e-6)
        trajectory = trajectory.time_scaled(step)
        factor *= step
    else:
        raise TimeParameterizationError("could not bring the trajectory within the limits by time scaling")

    pos, _, _ = trajectory.sample(trajectory.dense_times())
    outside = (pos < limits.lower - 1e-6) | (pos > limits.upper + 1e-6)
    if np.any(outside):
        j = int(np.argmax(np.any(outside, axis=0)))
        raise TimeParameterizationError(
            f"the spline through the waypoints leaves the position limits of {names[j]} "
            f"([{limits.lower[j]}, {limits.upper[j]}] rad){limit_hint}"
        )
    return trajectory, factor


# ----------------------------------------------------------------------------------------- public API
def time_optimal_trajectory(
    waypoints_rad,
    limits: JointLimits,
    joint_names=None,
    velocity_scaling_factor: float = 1.0,
    acceleration_scaling_factor: float = 1.0,
    sample_step_s: float | None = 0.02,
    max_waypoint_step_rad: float | None = None,
    frame_id: str = "world",
) -> JointTrajectory:
    """Time-optimal trajectory through the joint waypoints, at rest at both ends.

    Args:
        waypoints_rad: (K, n) joint waypoints in rad, columns in the order of ``joint_names``.
        limits: per-joint position (rad), velocity (rad/s) and acceleration (rad/s^2) limits.
        joint_names: column order of ``waypoints_rad`` (same set as ``limits.names``); default the limits'.
        velocity_scaling_factor, acceleration_scaling_factor: in (0, 1], scale the velocity and acceleration
            limits (as MoveIt's scaling factors do).
        sample_step_s: time step (s) of the output knots, added to the knots at the waypoints (which the
            output always passes through); None for knots at the waypoints only (useful for dense paths).
        max_waypoint_step_rad: when set, straight-line points are inserted so consecutive waypoints differ by
            at most this (rad, per joint), keeping the spline close to the polyline between sparse waypoints.
        frame_id: header frame of the result.

    Returns:
        A :class:`JointTrajectory` with positions (rad), velocities (rad/s) and accelerations (rad/s^2);
        a single point at rest when the path does not move.

    Raises:
        TimeParameterizationError: bad input (shape, joint count, NaN, out of limits, bad factor) or no
            solution.
    """
    names, limits = _limits_in_order(limits, joint_names)
    vel_scale = _scaling(velocity_scaling_factor, "velocity_scaling_factor")
    acc_scale = _scaling(acceleration_scaling_factor, "acceleration_scaling_factor")
    if sample_step_s is not None and not (np.isfinite(sample_step_s) and sample_step_s > 0):
        raise TimeParameterizationError(f"sample_step_s must be positive or None, got {sample_step_s}")
    q = _waypoints(waypoints_rad, limits, names)
    keep = np.concatenate([[True], np.max(np.abs(np.diff(q, axis=0)), axis=1) > DUPLICATE_WAYPOINT_RAD])
    q = q[keep]
    if len(q) == 1:
        return _rest_trajectory(q[0], names, frame_id)
    if max_waypoint_step_rad is not None:
        if not (np.isfinite(max_waypoint_step_rad) and max_waypoint_step_rad > 0):
            raise TimeParameterizationError(
                f"max_waypoint_step_rad must be positive or None, got {max_waypoint_step_rad}"
            )
        q = _densify(q, float(max_waypoint_step_rad))
    # Chord-length parameter (rad): overshoots less between unevenly spaced waypoints than a uniform one.
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    spline = CubicSpline(s, q, bc_type="not-a-knot")
    max_velocity = limits.max_velocity * vel_scale
    max_acceleration = limits.max_acceleration * acc_scale
    timing = _Timing.solve(spline, s, max_velocity, max_acceleration)
    hint = "; pass max_waypoint_step_rad to keep it close to the straight segments between the waypoints"
    if max_waypoint_step_rad is not None:
        hint = f" (waypoints {max_waypoint_step_rad:g} rad apart)"
    trajectory, _ = _build(
        timing, s, q, names, limits, max_velocity, max_acceleration, sample_step_s, frame_id, limit_hint=hint
    )
    return trajectory


@dataclass(frozen=True)
class ScanTrajectory:
    """A scan line's trajectory and what speed it achieves.

    ``scan_speed_mm_s`` is the constant tip speed (mm/s) held between ``cruise_start_s`` and ``cruise_end_s``
    (over ``cruise_length_mm``); it is below ``requested_scan_speed_mm_s`` when the joint limits demanded it,
    and ``speed_limited_by`` then says why. When the line is too short to reach the speed,
    ``reached_scan_speed`` is False and ``scan_speed_mm_s`` is the peak tip speed.
    """

    trajectory: JointTrajectory
    scan_speed_mm_s: float
    requested_scan_speed_mm_s: float
    speed_limited_by: str
    reached_scan_speed: bool
    cruise_start_s: float
    cruise_end_s: float
    cruise_length_mm: float
    line_length_mm: float

    @property
    def speed_reduced(self) -> bool:
        return self.scan_speed_mm_s < self.requested_scan_speed_mm_s * (1.0 - CRUISE_SPEED_TOLERANCE)


def constant_speed_scan_trajectory(
    waypoints_rad,
    limits: JointLimits,
    scan_speed_mm_s: float,
    spacing_mm: float | None = None,
    tip_positions_m=None,
    joint_names=None,
    velocity_scaling_factor: float = 1.0,
    acceleration_scaling_factor: float = 1.0,
    ramp_acceleration_mm_s2: float | None = None,
    sample_step_s: float | None = 0.02,
    frame_id: str = "world",
) -> ScanTrajectory:
    """Trajectory that moves the tip along a scan line at constant speed, with ramps at both ends.

    The joint waypoints are poses of the tip along the line: either equally spaced by ``spacing_mm`` (mm) or
    at the given ``tip_positions_m`` ((K, 3), metres); the tip's path length (mm) is the path parameter. The
    tip moves at ``scan_speed_mm_s`` in the middle. It ramps up from rest and down to rest time-optimally
    within the joint acceleration limits (and within ``ramp_acceleration_mm_s2`` along the line when given).
    When the joint velocity limits, or the joint accelerations the line's curvature in joint space needs at
    that speed, do not allow the requested speed anywhere along the line, the whole line is scanned at the
    highest constant speed that fits, and the result says so.

    Returns:
        :class:`ScanTrajectory`; its trajectory is at rest at both ends and passes through every waypoint.

    Raises:
        TimeParameterizationError: bad input (shapes, NaN, out of limits, neither or both of ``spacing_mm``
            and ``tip_positions_m``, non-positive speed) or no solution.
    """
    names, limits = _limits_in_order(limits, joint_names)
    vel_scale = _scaling(velocity_scaling_factor, "velocity_scaling_factor")
    acc_scale = _scaling(acceleration_scaling_factor, "acceleration_scaling_factor")
    try:
        requested = float(scan_speed_mm_s)
    except (TypeError, ValueError) as exc:
        raise TimeParameterizationError(f"scan_speed_mm_s must be a number, got {scan_speed_mm_s!r}") from exc
    if not (np.isfinite(requested) and requested > 0):
        raise TimeParameterizationError(f"scan_speed_mm_s must be positive, got {scan_speed_mm_s}")
    if sample_step_s is not None and not (np.isfinite(sample_step_s) and sample_step_s > 0):
        raise TimeParameterizationError(f"sample_step_s must be positive or None, got {sample_step_s}")
    q = _waypoints(waypoints_rad, limits, names)
    if len(q) < 2:
        raise TimeParameterizationError("a scan line needs at least 2 waypoints")
    if (spacing_mm is None) == (tip_positions_m is None):
        raise TimeParameterizationError("give exactly one of spacing_mm and tip_positions_m")
    if spacing_mm is not None:
        if not (np.isfinite(spacing_mm) and spacing_mm > 0):
            raise TimeParameterizationError(f"spacing_mm must be positive, got {spacing_mm}")
        s = np.arange(len(q)) * float(spacing_mm)
    else:
        tips = np.asarray(tip_positions_m, dtype=float)
        if tips.shape != (len(q), 3) or not np.all(np.isfinite(tips)):
            raise TimeParameterizationError(
                f"tip_positions_m must be finite with shape ({len(q)}, 3) (metres), got {tips.shape}"
            )
        steps_mm = np.linalg.norm(np.diff(tips, axis=0), axis=1) * 1000.0
        if np.any(steps_mm <= 1e-9):
            i = int(np.argmax(steps_mm <= 1e-9))
            raise TimeParameterizationError(f"tip positions {i} and {i + 1} coincide: the line must advance")
        s = np.concatenate([[0.0], np.cumsum(steps_mm)])
    ramp = UNBOUNDED_PATH_ACCELERATION_MM_S2
    if ramp_acceleration_mm_s2 is not None:
        if not (np.isfinite(ramp_acceleration_mm_s2) and ramp_acceleration_mm_s2 > 0):
            raise TimeParameterizationError(
                f"ramp_acceleration_mm_s2 must be positive or None, got {ramp_acceleration_mm_s2}"
            )
        ramp = float(ramp_acceleration_mm_s2)

    spline = CubicSpline(s, q, bc_type="not-a-knot")
    max_velocity = limits.max_velocity * vel_scale
    max_acceleration = limits.max_acceleration * acc_scale

    # Highest constant speed the whole line allows: |q_s| * v <= v_max and |q_ss| * v^2 <= share * a_max,
    # judged on the waypoints and three points inside every interval.
    s_fine = np.unique(np.concatenate([s, *(s[:-1] + f * np.diff(s) for f in (0.25, 0.5, 0.75))]))
    with np.errstate(divide="ignore"):
        v_by_velocity = CRUISE_VELOCITY_SHARE * float(np.min(max_velocity / np.abs(spline(s_fine, 1))))
        v_by_curvature = float(
            np.min(np.sqrt(CRUISE_ACCELERATION_SHARE * max_acceleration / np.abs(spline(s_fine, 2))))
        )
    cruise = min(requested, v_by_velocity, v_by_curvature)
    reasons = []
    if cruise < requested:
        reasons.append(
            f"joint velocity limits allow at most {v_by_velocity:.6g} mm/s along this line"
            if v_by_velocity <= v_by_curvature
            else f"joint acceleration limits allow at most {v_by_curvature:.6g} mm/s along this line's curvature "
            "in joint space"
        )

    # The path speed cap is a virtual joint q_{n+1}(s) = s with velocity limit = cruise speed (mm/s).
    augmented = CubicSpline(s, np.column_stack([q, s]), bc_type="not-a-knot")
    # toppra shrinks every limit by TOPPRA_SHARE; the cap is a target, not a limit, so undo that for it.
    timing = _Timing.solve(
        augmented, s, np.append(max_velocity, cruise / TOPPRA_SHARE), np.append(max_acceleration, ramp)
    )
    trajectory, factor = _build(
        timing,
        s,
        q,
        names,
        limits,
        max_velocity,
        max_acceleration,
        sample_step_s,
        frame_id,
        joints=slice(0, len(names)),
    )
    if factor > 1.0:
        reasons.append(f"slowed by a factor {factor:.6g} to keep toppra's output within the joint limits")

    sd = timing.sd / factor
    ts = timing.ts * factor
    # The cruise is the longest run of grid points at the capped speed (one run unless toppra misbehaves).
    at_cruise = np.concatenate([[False], timing.sd >= cruise * (1.0 - CRUISE_SPEED_TOLERANCE), [False]])
    edges = np.flatnonzero(np.diff(at_cruise.astype(int)))
    runs = edges.reshape(-1, 2)  # [first, last + 1] of each run
    if len(runs):
        first, stop = runs[int(np.argmax(runs[:, 1] - runs[:, 0]))]
        last = int(stop) - 1
        reached = True
        achieved = float(np.mean(sd[first : last + 1]))
        cruise_start, cruise_end = float(ts[first]), float(ts[last])
        cruise_length = float(timing.ss[last] - timing.ss[first])
    else:
        reached = False
        achieved = float(sd.max())
        cruise_start = cruise_end = float(ts[int(np.argmax(sd))])
        cruise_length = 0.0
        reasons.append(
            f"the {s[-1]:.6g} mm line is too short to reach {cruise / factor:.6g} mm/s within the acceleration "
            "limits (the speed given is the peak)"
        )
    limited_by = "; ".join(reasons)
    return ScanTrajectory(
        trajectory=trajectory,
        scan_speed_mm_s=float(achieved),
        requested_scan_speed_mm_s=requested,
        speed_limited_by=limited_by,
        reached_scan_speed=reached,
        cruise_start_s=cruise_start,
        cruise_end_s=cruise_end,
        cruise_length_mm=cruise_length,
        line_length_mm=float(s[-1]),
    )
