"""Many straight-line Cartesian paths at once: :func:`compute_cartesian_paths` gives, for P (start state, target
pose) pairs, the same paths as P calls of :func:`~agiprobot_measurement.motion.cartesian.compute_cartesian_path`
with one target each, in a few vectorised steps instead of P rounds of small numpy calls.

The interpolated poses of every path are solved in one closed-form IK call (each seeded with its path's start
state), the branches are followed, and joint jumps and joint limits checked, in one compiled pass over all paths
(:func:`~agiprobot_measurement.motion.cartesian_kernels.follow_paths`), and the states of every path go through
the validity checker (a collision check) in one call. Poses 4x4 in metres, joints rad, steps mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from agiprobot_measurement.motion.cartesian import (
    STOP_COMPLETE,
    STOP_INVALID_STATE,
    STOP_JOINT_JUMP,
    STOP_JOINT_LIMITS,
    STOP_UNREACHABLE,
)
from agiprobot_measurement.motion.cartesian_kernels import TRACK_EXACT, fill_line_poses, follow_paths, track_paths
from agiprobot_measurement.motion.errors import MotionInputError

__all__ = ["CartesianPaths", "compute_cartesian_paths", "line_poses"]

#: the kernel's stop codes, in the order of :data:`STOP_NAMES`
STOP_NAMES = (STOP_COMPLETE, STOP_UNREACHABLE, STOP_JOINT_JUMP, STOP_JOINT_LIMITS, STOP_INVALID_STATE)
_INVALID = 4
#: a path is tracked by continuation only where every other IK branch lies this much (rad) beyond twice the
#: tracked move onto each waypoint (see cartesian_kernels.track_paths)
TRACK_MARGIN_RAD = 0.3
#: the collision check of a batch of paths looks at every this-many-th state first (see compute_cartesian_paths)
COARSE_STRIDE = 8


@dataclass(frozen=True)
class CartesianPaths:
    """Outcome of :func:`compute_cartesian_paths` for P paths.

    ``fractions`` (P,): achieved steps / requested steps. ``states`` (S, dof) rad: every path's joint states one
    after the other (start included); path i owns ``states[offsets[i]:offsets[i + 1]]`` (empty when its start
    state is invalid). ``stop_codes`` (P,): indices into :data:`STOP_NAMES`.
    """

    fractions: np.ndarray
    states: np.ndarray
    offsets: np.ndarray
    stop_codes: np.ndarray

    def joint_path(self, i: int) -> np.ndarray:
        """Path ``i``'s joint states (K, dof) rad."""
        return self.states[self.offsets[i] : self.offsets[i + 1]]

    def stop_reason(self, i: int) -> str:
        """Why path ``i`` stopped (see :mod:`agiprobot_measurement.motion.cartesian`)."""
        return STOP_NAMES[int(self.stop_codes[i])]


def line_poses(
    starts: np.ndarray, targets: np.ndarray, step_m: float, max_rotation_step_rad: float
) -> tuple[np.ndarray, np.ndarray]:
    """The interpolated poses of P one-segment lines, start excluded: (poses (M, 4, 4), offsets (P + 1,)).

    Line i runs from ``starts[i]`` to ``targets[i]`` (4x4, metres) in the fewest equal steps that keep the
    translation per step <= ``step_m`` and the rotation per step <= ``max_rotation_step_rad`` (position linear,
    orientation by slerp, the last pose exactly the target), as
    :func:`~agiprobot_measurement.motion.cartesian.interpolate_poses` does for one line.
    """
    distance = np.linalg.norm(targets[:, :3, 3] - starts[:, :3, 3], axis=1)
    relative = np.einsum("pji,pjk->pik", starts[:, :3, :3], targets[:, :3, :3])
    rotvec = Rotation.from_matrix(relative).as_rotvec() if len(starts) else np.zeros((0, 3))
    angle = np.linalg.norm(rotvec, axis=1)
    steps = np.maximum.reduce(
        [
            np.ones(len(starts), dtype=np.int64),
            np.ceil(distance / step_m - 1e-9).astype(np.int64),
            np.ceil(angle / max_rotation_step_rad - 1e-9).astype(np.int64),
        ]
    )
    offsets = np.concatenate([[0], np.cumsum(steps)])
    # Rodrigues' formula of each line's rotation vector scaled by s (the slerp of interpolate_poses): the start's
    # rotation S times I + sin(t) K + (1 - cos(t)) K^2 is S + sin(t) (S K) + (1 - cos(t)) (S K^2)
    axis = np.where(angle[:, None] > 1e-15, rotvec / np.maximum(angle, 1e-300)[:, None], 0.0)
    x, y, z = axis.T
    k = np.zeros((len(starts), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 0], k[:, 1, 2], k[:, 2, 0], k[:, 2, 1] = -z, y, z, -x, -y, x
    start_k = starts[:, :3, :3] @ k
    poses = fill_line_poses(
        np.ascontiguousarray(starts, dtype=np.float64),
        np.ascontiguousarray(targets, dtype=np.float64),
        np.ascontiguousarray(start_k),
        np.ascontiguousarray(start_k @ k),
        np.ascontiguousarray(angle, dtype=np.float64),
        offsets.astype(np.int64),
    )
    return poses, offsets


def compute_cartesian_paths(
    ik,
    start_q: np.ndarray,
    targets: np.ndarray,
    step_mm: float = 2.0,
    jump_threshold_rad: float = 1.5,
    validity_checker: Callable[[np.ndarray], np.ndarray] | None = None,
    max_rotation_step_rad: float = 0.05,
) -> CartesianPaths:
    """Straight tip lines from the poses at ``start_q`` (P, dof) rad to ``targets`` (P, 4, 4) metres.

    Path i is the one ``compute_cartesian_path(ik, start_q[i], targets[i], ...)`` gives (same parameters); ``ik``
    must offer ``solve_all`` (the closed-form solver). ``validity_checker`` is called with the paths' states in two
    batches: every :data:`COARSE_STRIDE`-th state of each path (and its last), then the states before each path's
    first invalid one of those (the result is that of one call with every state).
    """
    model = ik.model
    start_q = np.asarray(start_q, dtype=float).reshape(-1, model.dof)
    targets = np.asarray(targets, dtype=float).reshape(-1, 4, 4)
    if len(start_q) != len(targets):
        raise MotionInputError(f"got {len(start_q)} start states for {len(targets)} targets")
    if not hasattr(ik, "solve_all"):
        raise MotionInputError("compute_cartesian_paths needs a closed-form IK solver (one with solve_all)")
    if not np.all(model.within_limits(start_q, tolerance=1e-9)):
        raise MotionInputError("a start state lies outside the joint limits")
    if not (math.isfinite(step_mm) and step_mm > 0.0) or not jump_threshold_rad > 0.0:
        raise MotionInputError(f"step_mm and jump_threshold_rad must be positive, got {step_mm}, {jump_threshold_rad}")
    n_paths = len(start_q)
    if n_paths == 0:
        empty = np.zeros(0)
        return CartesianPaths(empty, np.zeros((0, model.dof)), np.zeros(1, dtype=np.int64), empty.astype(np.int64))
    poses, pose_offsets = line_poses(model.fk(start_q), targets, step_mm * 1e-3, max_rotation_step_rad)
    states, counts, codes = _walk(ik, poses, pose_offsets, start_q, float(jump_threshold_rad))
    # states: every path's (count + 1) states in the rows pose_offsets[i] + i ... (one more row per path)
    lengths = counts + 1
    base = pose_offsets[:-1] + np.arange(n_paths)
    if validity_checker is not None:
        ranks = _ranks(lengths)
        rows = np.repeat(base, lengths) + ranks
        heads = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        # every COARSE_STRIDE-th state and each path's last first: a path cut there needs no check of the states
        # after its first invalid coarse one (the cut is at or before it); the others are checked next, so the
        # first invalid state found is the one a check of every state finds
        coarse = (ranks % COARSE_STRIDE == COARSE_STRIDE - 1) | (ranks == np.repeat(lengths, lengths) - 1)
        ok = np.ones(len(rows), dtype=bool)
        ok[coarse] = _checked(validity_checker, states[rows[coarse]])
        coarse_bad = np.minimum.reduceat(np.where(ok, np.iinfo(np.int64).max, ranks), heads)
        fine = ~coarse & (ranks < np.repeat(coarse_bad, lengths))
        ok[fine] = _checked(validity_checker, states[rows[fine]])
        bad_rank = np.where(ok, np.iinfo(np.int64).max, ranks)
        first_bad = np.minimum.reduceat(bad_rank, heads)
        cut = first_bad < lengths
        lengths = np.where(cut, first_bad, lengths)
        counts = np.where(cut, first_bad - 1, counts)
        codes = np.where(cut, _INVALID, codes)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    kept = np.repeat(base, lengths) + _ranks(lengths)
    fractions = np.maximum(counts, 0) / np.diff(pose_offsets)
    return CartesianPaths(fractions.astype(float), states[kept], offsets, codes.astype(np.int64))


def _walk(ik, poses, pose_offsets, start_q, jump):
    """(states, counts, codes) as :func:`~agiprobot_measurement.motion.cartesian_kernels.follow_paths` gives
    them: the continuation (:func:`~agiprobot_measurement.motion.cartesian_kernels.track_paths`, a UR arm's
    closed-form solver) settles each path up to the first waypoint where it cannot show the walk's choice, and the
    walk over every closed-form branch goes on from there: first over that one waypoint (most such paths stop
    there: a joint limit, a jump, the workspace's edge), then over the rest of the paths that go on."""
    model = ik.model
    lower, upper = np.asarray(model.lower, dtype=np.float64), np.asarray(model.upper, dtype=np.float64)
    n_paths = len(start_q)
    sizes = np.diff(pose_offsets)
    if hasattr(ik, "shoulder_gaps"):
        pre, axes, tip = model.fk_segments
        states, counts, codes = track_paths(
            np.ascontiguousarray(poses),
            pose_offsets.astype(np.int64),
            np.ascontiguousarray(start_q),
            ik.shoulder_gaps(poses),
            pre,
            axes,
            tip,
            lower,
            upper,
            jump,
            TRACK_MARGIN_RAD,
            ik.elbow_links(),
        )
        exact = np.flatnonzero(codes >= TRACK_EXACT)
        resume = states[pose_offsets[exact] + exact + counts[exact]]
    else:
        states = np.zeros((len(poses) + n_paths, model.dof))
        counts, codes = np.zeros(n_paths, dtype=np.int64), np.zeros(n_paths, dtype=np.int64)
        exact = np.arange(n_paths)
        resume = start_q
    for window in (1, None):  # the first waypoint left, then the rest where the walk goes on
        if exact.size == 0:
            break
        left = sizes[exact] - counts[exact]
        take = left if window is None else np.minimum(left, window)
        walked, sub_counts, sub_codes = _walk_every_branch(
            ik, poses, pose_offsets[exact] + counts[exact], take, resume, start_q[exact], jump, lower, upper
        )
        lengths = sub_counts + 1  # the resumed state is written again (unchanged)
        target = np.repeat(pose_offsets[exact] + exact + counts[exact], lengths) + _ranks(lengths)
        source = np.repeat(np.concatenate([[0], np.cumsum(take)])[:-1] + np.arange(exact.size), lengths)
        states[target] = walked[source + _ranks(lengths)]
        counts[exact] += sub_counts
        codes[exact] = sub_codes
        going = (sub_codes == 0) & (sub_counts < left)
        resume = walked[source[np.cumsum(lengths) - 1] + sub_counts][going] if going.any() else resume[:0]
        exact = exact[going]
    return states, counts, codes


def _walk_every_branch(ik, poses, firsts, sizes, starts, seeds, jump, lower, upper):
    """The walk over every closed-form branch (:func:`follow_paths`) of the waypoints ``poses[firsts[i]:firsts[i] +
    sizes[i]]`` from the states ``starts[i]`` rad, the closed form seeded with ``seeds[i]`` (the path's start: it
    picks a singular wrist's q6): (states (sum(sizes) + len(sizes), dof), counts, codes)."""
    rows = np.repeat(firsts, sizes) + _ranks(sizes)
    sub_offsets = np.concatenate([[0], np.cumsum(sizes)])
    sub_poses = poses[rows]
    solutions, valid = ik.solve_all(sub_poses, np.repeat(seeds, sizes, axis=0))
    solutions = np.where(valid[..., None], solutions, 0.0)
    return follow_paths(
        np.ascontiguousarray(solutions),
        np.ascontiguousarray(valid),
        sub_offsets.astype(np.int64),
        np.ascontiguousarray(starts, dtype=np.float64),
        jump,
        lower,
        upper,
    )


def _checked(validity_checker, states: np.ndarray) -> np.ndarray:
    """The checker's verdicts (bool, one per state) on ``states`` (none asked for an empty batch)."""
    if len(states) == 0:
        return np.zeros(0, dtype=bool)
    ok = np.asarray(validity_checker(states), dtype=bool)
    if ok.shape != (len(states),):
        raise MotionInputError(f"validity_checker must return one bool per state, shape ({len(states)},)")
    return ok


def _ranks(lengths: np.ndarray) -> np.ndarray:
    """0, 1, ..., n_i - 1 for every n_i of ``lengths``, concatenated."""
    total = int(lengths.sum())
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    return np.arange(total) - np.repeat(starts, lengths)
