"""Joint trajectories: representation, the controller's interpolation, and the safety checks.

A :class:`JointTrajectory` holds knots (time in s, positions in rad, optional velocities rad/s and
accelerations rad/s^2). Between knots it is interpolated with cubic Hermite splines through the knot positions
and velocities (given, or estimated when absent). Listed knot accelerations are not used for interpolation:
time-parameterisers such as MoveIt's IPTP list accelerations that do not match their positions and velocities
(the original's stored plans do), and a quintic through them overshoots wildly between knots.

:func:`check_trajectory` judges positions and velocities on the interpolated motion, and accelerations on the
listed knot values when the trajectory lists them (as the documented ``postprocess_trajectory`` does), on the
interpolated motion otherwise.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.common.message_shape import MessageShape, message_shape
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.station import JointLimits

__all__ = [
    "CheckResult",
    "CheckTolerances",
    "JointTrajectory",
    "TrajectoryError",
    "check_continuity",
    "check_trajectory",
    "duration_to_seconds",
    "motion_peaks",
    "seconds_to_duration",
]


class TrajectoryError(InputError):
    """A trajectory is malformed (shapes, names, non-finite values)."""


def duration_to_seconds(value) -> float:
    """Seconds of a duration: a ``{secs, nsecs}`` mapping (stored plans), a message duration or a number."""
    if isinstance(value, dict):
        return float(value.get("secs", 0)) + float(value.get("nsecs", 0)) * 1e-9
    if hasattr(value, "secs") and hasattr(value, "nsecs"):
        # the same arithmetic as for the dict form, so messages and stored plans give identical floats
        return float(value.secs) + float(value.nsecs) * 1e-9
    if hasattr(value, "to_sec"):
        return float(value.to_sec())
    return float(value)


def seconds_to_duration(seconds: float) -> dict:
    """``{secs, nsecs}`` of a duration in seconds, rounded to the nanosecond (not truncated)."""
    secs = int(np.floor(seconds))
    nsecs = round((seconds - secs) * 1e9)
    if nsecs >= 1_000_000_000:
        secs, nsecs = secs + 1, nsecs - 1_000_000_000
    return {"secs": secs, "nsecs": nsecs}


@dataclass
class JointTrajectory:
    joint_names: list[str]
    time_from_start: np.ndarray  # (M,)
    positions: np.ndarray  # (M, n)
    velocities: np.ndarray | None = None  # (M, n)
    accelerations: np.ndarray | None = None  # (M, n)
    frame_id: str = "world"
    effort: list = field(default_factory=list)  # per-point effort rows when listed, else empty

    def __post_init__(self):
        self.joint_names = list(self.joint_names)
        self.time_from_start = np.asarray(self.time_from_start, dtype=float).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=float)
        m = self.time_from_start.shape[0]
        n = len(self.joint_names)
        if self.positions.ndim != 2 or self.positions.shape != (m, n):
            raise TrajectoryError(f"positions must have shape ({m} points, {n} joints), got {self.positions.shape}")
        for name in ("velocities", "accelerations"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=float)
                if value.size == 0:
                    value = None
                elif value.shape != (m, n):
                    raise TrajectoryError(f"{name} must have shape ({m}, {n}), got {value.shape}")
                setattr(self, name, value)

    # ------------------------------------------------------------------------------------- basics
    def __len__(self) -> int:
        return self.time_from_start.shape[0]

    @property
    def duration(self) -> float:
        return float(self.time_from_start[-1]) if len(self) else 0.0

    @property
    def start(self) -> np.ndarray:
        return self.positions[0]

    @property
    def end(self) -> np.ndarray:
        return self.positions[-1]

    def reordered(self, joint_names: list[str]) -> JointTrajectory:
        """The same trajectory with its joints in the order of ``joint_names`` (same set of names)."""
        if sorted(joint_names) != sorted(self.joint_names):
            raise TrajectoryError(f"joint names {self.joint_names} do not match expected {list(joint_names)}")
        order = [self.joint_names.index(n) for n in joint_names]
        return JointTrajectory(
            list(joint_names),
            self.time_from_start,
            self.positions[:, order],
            None if self.velocities is None else self.velocities[:, order],
            None if self.accelerations is None else self.accelerations[:, order],
            self.frame_id,
            [[row[i] for i in order] for row in self.effort] if self.has_effort() else [],
        )

    def has_effort(self) -> bool:
        return len(self.effort) == len(self) > 0 and all(len(r) == len(self.joint_names) for r in self.effort)

    def copy(self) -> JointTrajectory:
        """A deep copy (arrays copied)."""
        return JointTrajectory(
            list(self.joint_names),
            self.time_from_start.copy(),
            self.positions.copy(),
            None if self.velocities is None else self.velocities.copy(),
            None if self.accelerations is None else self.accelerations.copy(),
            self.frame_id,
            [list(r) for r in self.effort],
        )

    def time_scaled(self, factor: float) -> JointTrajectory:
        """The same path ``factor`` times slower (``factor`` > 1) or faster.

        Times (s) are multiplied by ``factor``, velocities divided by it, accelerations by its square. The
        cubic Hermite interpolation scales the same way, so measured peaks scale exactly.
        """
        factor = float(factor)
        if not np.isfinite(factor) or factor <= 0.0:
            raise TrajectoryError(f"time scaling factor must be a positive number, got {factor}")
        return JointTrajectory(
            list(self.joint_names),
            self.time_from_start * factor,
            self.positions.copy(),
            None if self.velocities is None else self.velocities / factor,
            None if self.accelerations is None else self.accelerations / factor**2,
            self.frame_id,
        )

    def concatenated(self, following: JointTrajectory, tolerance_rad: float = 1e-6) -> JointTrajectory:
        """This trajectory followed by ``following``, which must start where this one ends.

        The junction keeps this trajectory's last knot (``following``'s first knot is dropped) and the times
        of ``following`` are shifted to continue from it. Velocities are listed when either part lists them
        (estimated for the other); accelerations only when both list them.
        """
        following = following.reordered(self.joint_names)
        if len(self) == 0:
            return following
        if len(following) == 0:
            return self.copy()
        gap = np.abs(self.end - following.start)
        if np.any(gap > tolerance_rad):
            j = int(np.argmax(gap))
            raise TrajectoryError(
                f"cannot concatenate: {self.joint_names[j]} jumps by {gap[j]:.6f} rad at the junction "
                f"(tolerance {tolerance_rad} rad)"
            )
        shift = self.duration - float(following.time_from_start[0])
        times = np.concatenate([self.time_from_start, following.time_from_start[1:] + shift])
        positions = np.vstack([self.positions, following.positions[1:]])
        velocities = None
        if self.velocities is not None or following.velocities is not None:
            velocities = np.vstack([self.knot_velocities(), following.knot_velocities()[1:]])
        accelerations = None
        if self.accelerations is not None and following.accelerations is not None:
            accelerations = np.vstack([self.accelerations, following.accelerations[1:]])
        return JointTrajectory(list(self.joint_names), times, positions, velocities, accelerations, self.frame_id)

    # -------------------------------------------------------------------------------- conversions
    @classmethod
    def from_msg(cls, msg) -> JointTrajectory:
        """From a ``trajectory_msgs/JointTrajectory`` message or anything shaped like one (``joint_names``,
        ``points`` with positions / velocities / accelerations / time_from_start, ``header.frame_id``); imports
        nothing from ROS. The other direction is ``agiprobot_measurement.ros.conversions.joint_trajectory_to_msg``."""
        points = msg.points

        def stacked(attr):
            rows = [list(getattr(p, attr)) for p in points]
            return np.array(rows, dtype=float) if rows and all(len(r) for r in rows) else None

        return cls(
            joint_names=list(msg.joint_names),
            time_from_start=np.array([duration_to_seconds(p.time_from_start) for p in points]),
            positions=np.array([list(p.positions) for p in points], dtype=float).reshape(
                len(points), len(msg.joint_names)
            )
            if points
            else np.zeros((0, len(msg.joint_names))),
            velocities=stacked("velocities"),
            accelerations=stacked("accelerations"),
            frame_id=msg.header.frame_id,
        )

    @classmethod
    def from_dict(cls, data: dict) -> JointTrajectory:
        """From the expanded ``joint_trajectory`` dict of a stored execution plan."""
        if not isinstance(data, dict):
            raise TrajectoryError(f"joint_trajectory must be a mapping, got {type(data).__name__}")
        try:
            names = list(data["joint_names"])
            points = list(data["points"])
        except (KeyError, TypeError) as exc:
            raise TrajectoryError(f"joint_trajectory lacks {exc}") from exc

        def stacked(key):
            rows = [p.get(key) or [] for p in points]
            return np.array(rows, dtype=float) if rows and all(len(r) for r in rows) else None

        try:
            positions = np.array([p["positions"] for p in points], dtype=float).reshape(len(points), len(names))
            times = np.array([duration_to_seconds(p["time_from_start"]) for p in points])
        except (KeyError, TypeError, ValueError) as exc:
            raise TrajectoryError(f"malformed trajectory point: {exc}") from exc
        header = data.get("header") or {}
        efforts = [list(p.get("effort") or []) for p in points]
        if not (efforts and all(len(e) == len(names) for e in efforts)):
            efforts = []
        return cls(
            names,
            times,
            positions,
            stacked("velocities"),
            stacked("accelerations"),
            header.get("frame_id", ""),
            efforts,
        )

    def to_dict(self, seq: int = 0) -> dict:
        """To the expanded ``joint_trajectory`` dict (the form ``rospy_message_converter`` / genpy write)."""
        points = []
        has_effort = self.has_effort()
        for i, t in enumerate(self.time_from_start):
            points.append(
                {
                    "accelerations": [] if self.accelerations is None else self.accelerations[i].tolist(),
                    "effort": list(self.effort[i]) if has_effort else [],
                    "positions": self.positions[i].tolist(),
                    "time_from_start": seconds_to_duration(float(t)),
                    "velocities": [] if self.velocities is None else self.velocities[i].tolist(),
                }
            )
        return {
            "header": {"frame_id": self.frame_id, "seq": seq, "stamp": {"nsecs": 0, "secs": 0}},
            "joint_names": list(self.joint_names),
            "points": points,
        }

    @property
    def joint_trajectory(self) -> MessageShape:
        """This trajectory as a ``trajectory_msgs/JointTrajectory``-shaped snapshot: the original's views hold
        ``moveit_msgs/RobotTrajectory`` objects, and code written for it reads ``traj.joint_trajectory.points``."""
        return message_shape(self.to_dict())

    @property
    def multi_dof_joint_trajectory(self) -> MessageShape:
        """The empty ``MultiDOFJointTrajectory`` part of the RobotTrajectory shape (a fixed-base arm has none)."""
        return message_shape(
            {"header": {"frame_id": "", "seq": 0, "stamp": {"nsecs": 0, "secs": 0}}, "joint_names": [], "points": []}
        )

    # ------------------------------------------------------------------------------ interpolation
    def knot_velocities(self) -> np.ndarray:
        """Velocities at the knots: given ones, or estimated (zero at the ends, mean slope where monotone)."""
        if self.velocities is not None:
            return self.velocities
        v = np.zeros_like(self.positions)
        if len(self) > 2:
            slopes = np.diff(self.positions, axis=0) / np.diff(self.time_from_start)[:, None]
            before, after = slopes[:-1], slopes[1:]
            same_sign = np.sign(before) == np.sign(after)
            v[1:-1] = np.where(same_sign, 0.5 * (before + after), 0.0)
        return v

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations (each (K, n)) of the interpolated motion at ``times`` (s).

        Before the first knot the trajectory holds its first point; after the last, its last point.
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        t_knots = self.time_from_start
        n = len(self.joint_names)
        if len(self) == 1:
            return (
                np.repeat(self.positions[:1], len(times), axis=0),
                np.zeros((len(times), n)),
                np.zeros((len(times), n)),
            )
        clamped = np.clip(times, t_knots[0], t_knots[-1])
        seg = np.clip(np.searchsorted(t_knots, clamped, side="right") - 1, 0, len(self) - 2)
        h = (t_knots[seg + 1] - t_knots[seg])[:, None]
        s = ((clamped - t_knots[seg])[:, None]) / h
        p0, p1 = self.positions[seg], self.positions[seg + 1]
        v_all = self.knot_velocities()
        v0, v1 = v_all[seg] * h, v_all[seg + 1] * h  # derivatives w.r.t. normalised time s
        c0, c1 = p0, v0
        c2 = 3 * (p1 - p0) - 2 * v0 - v1
        c3 = -2 * (p1 - p0) + v0 + v1
        pos = c0 + s * (c1 + s * (c2 + s * c3))
        vel = c1 + s * (2 * c2 + s * 3 * c3)
        acc = 2 * c2 + s * 6 * c3
        outside = (times < t_knots[0]) | (times > t_knots[-1])
        vel, acc = vel / h, acc / h**2
        vel[outside] = 0.0
        acc[outside] = 0.0
        return pos, vel, acc

    def dense_times(self, step_s: float = 0.002, per_segment: int = 20) -> np.ndarray:
        """Times that sample every segment finely (at least ``per_segment`` samples, and every ``step_s``)."""
        t = self.time_from_start
        if len(t) < 2:
            return t.copy()
        pieces = []
        for t0, t1 in itertools.pairwise(t):
            count = max(per_segment, int(np.ceil((t1 - t0) / step_s)))
            pieces.append(np.linspace(t0, t1, count, endpoint=False))
        pieces.append(t[-1:])
        return np.concatenate(pieces)


@dataclass(frozen=True)
class CheckResult:
    """Verdict of a trajectory check; ``reason`` says what failed, empty when ``ok``."""

    ok: bool
    reason: str = ""

    def __bool__(self) -> bool:
        return self.ok


@dataclass(frozen=True)
class CheckTolerances:
    start_rad: float = 1e-2  # first point vs. current state
    position_rad: float = 1e-6  # beyond the position limits
    velocity_fraction: float = 0.01  # relative excess of a velocity limit
    acceleration_fraction: float = 0.05  # relative excess of an acceleration limit


def motion_peaks(trajectory: JointTrajectory) -> tuple[np.ndarray, np.ndarray]:
    """Peak |velocity| (rad/s) and |acceleration| (rad/s^2) per joint, measured as :func:`check_trajectory`
    judges them: velocity on the densely sampled interpolation, acceleration on the listed knot values when
    listed (on the interpolation otherwise). Joint order is the trajectory's own.
    """
    if len(trajectory) == 0:
        n = len(trajectory.joint_names)
        return np.zeros(n), np.zeros(n)
    _, vel, acc = trajectory.sample(trajectory.dense_times())
    listed = trajectory.accelerations
    return np.abs(vel).max(axis=0), np.abs(acc if listed is None else listed).max(axis=0)


def check_trajectory(
    trajectory: JointTrajectory,
    limits: JointLimits,
    current_positions: np.ndarray | None = None,
    tolerances: CheckTolerances = CheckTolerances(),
) -> CheckResult:
    """Check names, finiteness, time, start state, and position/velocity/acceleration limits.

    Positions and velocities are checked on the interpolated motion (densely sampled), not only at the knots;
    accelerations on the listed knot values when listed, else on the interpolated motion.
    """
    if len(trajectory) == 0:
        return CheckResult(False, "trajectory has no points")
    expected = list(limits.names)
    if sorted(trajectory.joint_names) != sorted(expected) or len(trajectory.joint_names) != len(expected):
        unknown = sorted(set(trajectory.joint_names) - set(expected))
        missing = sorted(set(expected) - set(trajectory.joint_names))
        return CheckResult(
            False, f"wrong joint names: unknown {unknown}, missing {missing} (expected {', '.join(expected)})"
        )
    trajectory = trajectory.reordered(expected)
    arrays = [trajectory.time_from_start, trajectory.positions]
    arrays += [a for a in (trajectory.velocities, trajectory.accelerations) if a is not None]
    if not all(np.all(np.isfinite(a)) for a in arrays):
        return CheckResult(False, "trajectory contains NaN or infinite values")
    t = trajectory.time_from_start
    if t[0] < 0:
        return CheckResult(False, f"time_from_start of the first point is negative ({t[0]:.6f} s)")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0)) + 1
        return CheckResult(
            False, f"time_from_start not strictly increasing at point {i} ({t[i - 1]:.6f} s -> {t[i]:.6f} s)"
        )
    if current_positions is not None:
        deviation = np.abs(trajectory.positions[0] - np.asarray(current_positions, dtype=float))
        if np.any(deviation > tolerances.start_rad):
            j = int(np.argmax(deviation))
            return CheckResult(
                False,
                f"trajectory does not start at the current state: {expected[j]} differs by "
                f"{deviation[j]:.4f} rad "
                f"(tolerance {tolerances.start_rad} rad)",
            )
    times = trajectory.dense_times()
    pos, vel, acc = trajectory.sample(times)
    pos = np.vstack([pos, trajectory.positions])
    low = pos < limits.lower - tolerances.position_rad
    high = pos > limits.upper + tolerances.position_rad
    if np.any(low | high):
        j = int(np.argmax(np.any(low | high, axis=0)))
        value = pos[:, j].min() if np.any(low[:, j]) else pos[:, j].max()
        return CheckResult(
            False,
            f"position limit violated: {expected[j]} reaches {value:.4f} rad, limits "
            f"[{limits.lower[j]}, {limits.upper[j]}]",
        )
    listed_acc = trajectory.accelerations
    for label, values, limit, fraction in (
        ("velocity", vel, limits.max_velocity, tolerances.velocity_fraction),
        (
            "acceleration",
            acc if listed_acc is None else listed_acc,
            limits.max_acceleration,
            tolerances.acceleration_fraction,
        ),
    ):
        peak = np.abs(values).max(axis=0)
        excess = peak > limit * (1.0 + fraction) + 1e-9
        if np.any(excess):
            j = int(np.argmax(excess))
            return CheckResult(
                False,
                f"{label} limit violated: {expected[j]} reaches {peak[j]:.4f}, limit {limit[j]} "
                f"(+{fraction * 100:.0f} % tolerance)",
            )
    return CheckResult(True)


def check_continuity(previous: JointTrajectory, following: JointTrajectory, tolerance_rad: float = 1e-3) -> CheckResult:
    """Whether ``following`` starts where ``previous`` ends (same joints, within ``tolerance_rad``)."""
    if previous.joint_names != following.joint_names:
        following = following.reordered(previous.joint_names)
    gap = np.abs(previous.end - following.start)
    if np.any(gap > tolerance_rad):
        j = int(np.argmax(gap))
        return CheckResult(
            False,
            f"segments are not continuous: {previous.joint_names[j]} jumps by {gap[j]:.4f} rad "
            f"(tolerance {tolerance_rad} rad)",
        )
    return CheckResult(True)
