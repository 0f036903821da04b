"""Straight-line Cartesian paths of the tip frame, like MoveIt's ``compute_cartesian_path``.

The tip moves from its pose at ``start_q`` through the given waypoint poses (4x4, metres, in the IK model's
base frame): position linearly, orientation by slerp, in steps of at most ``step_mm`` (and
``max_rotation_step_rad``). Every interpolated pose is solved at once (closed-form IK in one vectorised
call when the solver offers ``solve_all``), then the solution nearest the previous joint state is followed
from the start. The path stops before the first pose that is unreachable, needs a joint jump above
``jump_threshold_rad``, would leave the joint limits, or that ``validity_checker`` rejects; ``fraction`` is
the share of the interpolation steps achieved.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from agiprobot_measurement.motion.cartesian_kernels import follow_branches
from agiprobot_measurement.motion.errors import MotionInputError
from agiprobot_measurement.motion.ik import IKSolver, check_joint_states, check_poses

__all__ = [
    "STOP_COMPLETE",
    "STOP_INVALID_STATE",
    "STOP_JOINT_JUMP",
    "STOP_JOINT_LIMITS",
    "STOP_UNREACHABLE",
    "CartesianPathResult",
    "compute_cartesian_path",
    "interpolate_poses",
]

STOP_COMPLETE = "complete"
STOP_UNREACHABLE = "unreachable"
STOP_JOINT_JUMP = "joint_jump"
STOP_JOINT_LIMITS = "joint_limits"
STOP_INVALID_STATE = "invalid_state"


@dataclass(frozen=True)
class CartesianPathResult:
    """Outcome of :func:`compute_cartesian_path`.

    ``fraction``: achieved interpolation steps / requested steps (1.0 = the whole path).
    ``joint_path`` (K, dof) rad: the joint states, starting with ``start_q`` (empty if the start state is
    invalid). ``poses`` (K, 4, 4) metres: the interpolated tip poses they reach. ``stop_reason``: one of
    ``complete``, ``unreachable``, ``joint_jump``, ``joint_limits``, ``invalid_state``.
    """

    fraction: float
    joint_path: np.ndarray
    poses: np.ndarray
    stop_reason: str


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.mod(angle + np.pi, 2.0 * np.pi) - np.pi


def _axis_angle_matrices(rotvec: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Rotation matrices (K, 3, 3) of the rotation vector ``rotvec`` (rad) scaled by each of ``fractions``."""
    angle = float(np.linalg.norm(rotvec))
    out = np.broadcast_to(np.eye(3), (len(fractions), 3, 3)).copy()
    if angle < 1e-15:
        return out
    x, y, z = rotvec / angle
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    theta = angle * np.asarray(fractions, dtype=float)
    out += np.sin(theta)[:, None, None] * k + (1.0 - np.cos(theta))[:, None, None] * (k @ k)
    return out


def interpolate_poses(
    start: np.ndarray, waypoints: np.ndarray, step_m: float, max_rotation_step_rad: float
) -> np.ndarray:
    """Poses (K, 4, 4) from ``start`` (included) through ``waypoints`` (M, 4, 4), metres and rad.

    Each segment is split into the fewest equal steps that keep the translation per step <= ``step_m`` and
    the rotation per step <= ``max_rotation_step_rad``.
    """
    out = [start[None]]
    previous = start
    for target in waypoints:
        distance = float(np.linalg.norm(target[:3, 3] - previous[:3, 3]))
        # slerp as R0 exp(s log(R0^T R1)) with Rodrigues' formula: the same rotations as scipy's Slerp, without
        # its per-call set-up (scan lines keep their orientation, so this is called for thousands of short lines)
        rotvec = Rotation.from_matrix(previous[:3, :3].T @ target[:3, :3]).as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        # the small slack keeps 0.2 m / 0.002 m at 100 steps despite rounding
        steps = max(1, math.ceil(distance / step_m - 1e-9), math.ceil(angle / max_rotation_step_rad - 1e-9))
        s = np.linspace(0.0, 1.0, steps + 1)[1:]
        segment = np.zeros((steps, 4, 4))
        segment[:, :3, :3] = previous[:3, :3] @ _axis_angle_matrices(rotvec, s)
        segment[:, :3, 3] = previous[:3, 3] + s[:, None] * (target[:3, 3] - previous[:3, 3])
        segment[:, 3, 3] = 1.0
        segment[-1] = target  # end exactly on the waypoint
        out.append(segment)
        previous = target
    return np.concatenate(out)


#: the compiled walk (numba, loaded by cartesian_kernels on first use) takes over after this many paths in a process: loading it
#: costs about 0.6 s, it saves about 0.35 ms per path
COMPILED_AFTER_PATHS = 1500
_paths_followed = 0


def _follow_all_solutions(ik, start_q: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, int]:
    """Branch-following over every closed-form solution: (chosen raw angles (M, dof), count reachable)."""
    global _paths_followed
    solutions, valid = ik.solve_all(poses, start_q)
    solutions = np.where(valid[..., None], solutions, 0.0)
    _paths_followed += 1
    if _paths_followed > COMPILED_AFTER_PATHS:
        chosen, count = follow_branches(
            np.ascontiguousarray(solutions), np.ascontiguousarray(valid), np.asarray(start_q, dtype=np.float64)
        )
        return solutions[np.arange(count), chosen[:count]], int(count)
    # pairwise joint-space distances between consecutive waypoints' solutions, modulo 2 pi, so the
    # sequential pick below is only index arithmetic
    first = np.where(valid[0], np.linalg.norm(_wrap(solutions[0] - start_q), axis=-1), np.inf)
    steps = np.linalg.norm(_wrap(solutions[1:, None, :, :] - solutions[:-1, :, None, :]), axis=-1)
    steps = np.where(valid[1:, None, :], steps, np.inf)
    chosen = np.empty(len(poses), dtype=int)
    current = int(np.argmin(first))
    if not np.isfinite(first[current]):
        return solutions[:0, 0], 0  # (0, dof): no waypoint reached
    chosen[0] = current
    count = 1
    for k in range(len(poses) - 1):
        row = steps[k, current]
        current = int(np.argmin(row))
        if not np.isfinite(row[current]):
            break
        chosen[k + 1] = current
        count += 1
    return solutions[np.arange(count), chosen[:count]], count


def _follow_sequentially(ik, start_q: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, int]:
    """For solvers without ``solve_all`` (KDL): solve each pose seeded by the previous solution."""
    path = []
    previous = start_q
    for pose in poses:
        q = ik.solve(pose, previous)
        if q is None:
            break
        path.append(q)
        previous = q
    return np.array(path).reshape(len(path), len(start_q)), len(path)


def compute_cartesian_path(
    ik: IKSolver,
    start_q: np.ndarray,
    waypoints: np.ndarray,
    step_mm: float = 2.0,
    jump_threshold_rad: float = 1.5,
    validity_checker: Callable[[np.ndarray], np.ndarray] | None = None,
    max_rotation_step_rad: float = 0.05,
) -> CartesianPathResult:
    """Straight-line tip path from the pose at ``start_q`` through ``waypoints``.

    ``ik``: an IK solver of this package (``URAnalyticIK`` or ``KDLIK``); its model fixes the frames.
    ``start_q`` (dof,) rad, within the joint limits. ``waypoints``: one pose (4, 4) or poses (M, 4, 4) of
    the tip in the model's base frame, metres. ``step_mm``: maximum translation per step, mm.
    ``jump_threshold_rad``: maximum change of any joint between consecutive states, rad.
    ``validity_checker``: called once with the (K, dof) joint states (start included) and returning a
    (K,) bool array, e.g. a collision check. ``max_rotation_step_rad``: maximum rotation per step, rad.
    """
    model = ik.model
    start_q = check_joint_states(start_q, model.dof, model.joint_names, "start_q")
    if start_q.ndim != 1:
        raise MotionInputError(f"start_q: expected one joint state, got shape {start_q.shape}")
    if not model.within_limits(start_q, tolerance=1e-9):
        raise MotionInputError(f"start_q {start_q.tolist()} lies outside the joint limits")
    waypoints, _ = check_poses(waypoints, "waypoints")
    if not (math.isfinite(step_mm) and step_mm > 0.0):
        raise MotionInputError(f"step_mm must be a positive number of millimetres, got {step_mm}")
    if not (math.isfinite(max_rotation_step_rad) and max_rotation_step_rad > 0.0):
        raise MotionInputError(f"max_rotation_step_rad must be positive, got {max_rotation_step_rad}")
    if not jump_threshold_rad > 0.0:
        raise MotionInputError(f"jump_threshold_rad must be positive, got {jump_threshold_rad}")

    poses = interpolate_poses(model.fk(start_q), waypoints, step_mm * 1e-3, max_rotation_step_rad)
    total_steps = len(poses) - 1
    if hasattr(ik, "solve_all"):
        raw, count = _follow_all_solutions(ik, start_q, poses[1:])
    else:
        raw, count = _follow_sequentially(ik, start_q, poses[1:])
    reason = STOP_COMPLETE if count == total_steps else STOP_UNREACHABLE

    # The joints move by the shortest angle between consecutive solutions; accumulating those moves from
    # start_q gives the angles the controller actually reaches (a wide joint may wind past +-pi).
    moves = _wrap(np.diff(np.vstack([start_q, raw]), axis=0))
    jumps = np.flatnonzero(np.max(np.abs(moves), axis=1, initial=0.0) > jump_threshold_rad)
    if jumps.size:
        count, reason = int(jumps[0]), STOP_JOINT_JUMP
    joint_path = start_q + np.vstack([np.zeros((1, model.dof)), np.cumsum(moves[:count], axis=0)])
    outside = np.flatnonzero(~model.within_limits(joint_path, tolerance=1e-9))
    if outside.size:
        count, reason = int(outside[0]) - 1, STOP_JOINT_LIMITS
        joint_path = joint_path[: count + 1]
    joint_path = np.clip(joint_path, model.lower, model.upper)

    if validity_checker is not None:
        ok = np.asarray(validity_checker(joint_path))
        if ok.shape != (len(joint_path),):
            raise MotionInputError(
                f"validity_checker must return one bool per state, shape ({len(joint_path)},), got {ok.shape}"
            )
        invalid = np.flatnonzero(~ok.astype(bool))
        if invalid.size:
            count, reason = int(invalid[0]) - 1, STOP_INVALID_STATE
            joint_path = joint_path[: count + 1]

    fraction = max(count, 0) / total_steps
    return CartesianPathResult(
        fraction=float(fraction),
        joint_path=joint_path,
        poses=poses[: len(joint_path)],
        stop_reason=reason,
    )
