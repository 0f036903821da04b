"""The robot side of viewpoints: anchor reachability, chunked metrology, scan-line extents and the mechanical
check of a scan line (Cartesian path, joint jumps, collisions, partial acceptance, timing).

Poses in the planning API are 4x4 mm; kinematics and IK work in metres (:func:`tip_pose_m` converts). Scan-line
extents are mm from the view's anchor along the laser_emitter_frame's x axis; joint values rad, speeds mm/s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from agiprobot_measurement.motion.cartesian import compute_cartesian_path
from agiprobot_measurement.motion.cartesian_batch import compute_cartesian_paths
from agiprobot_measurement.motion.time_parameterization import constant_speed_scan_trajectory

# the chunked metrology moved to the streaming module; re-exported here for its callers
from agiprobot_measurement.planning.candidates.streaming import evaluate_in_chunks

__all__ = [
    "SCAN_ACCELERATION_MM_S2",
    "check_scan_line",
    "check_scan_lines",
    "estimate_scan_duration",
    "evaluate_in_chunks",
    "reachable_anchors",
    "scan_line_extents",
    "scan_line_starts_free",
    "scan_path",
    "set_scan_trajectory",
    "tip_pose_m",
    "verify_scan_line",
]

#: ramps at the joints' pace are short; a constant tip acceleration of this much is a fair estimate
SCAN_ACCELERATION_MM_S2 = 500.0


def tip_pose_m(pose_mm: np.ndarray) -> np.ndarray:
    """A copy of 4x4 pose(s) with the translation in metres."""
    pose = np.array(pose_mm, dtype=float)
    pose[..., :3, 3] *= 1e-3
    return pose


def reachable_anchors(ik, anchor_poses_mm: np.ndarray, chunk: int = 20000) -> np.ndarray:
    """Whether each anchor pose of the laser_emitter_frame has an IK solution within the joint limits."""
    out = np.zeros(len(anchor_poses_mm), dtype=bool)
    for start in range(0, len(anchor_poses_mm), chunk):
        poses = tip_pose_m(anchor_poses_mm[start : start + chunk])
        _, valid = ik.solve_all(poses)
        out[start : start + chunk] = valid.any(axis=1)
    return out


def scan_line_extents(t0_min, t0_max, overmeasure_mm: float, min_length_mm: float):
    """Scan-line extents (lo, hi arrays, mm from the anchor along x) for arrays of the measured points' t0
    ranges: the range plus the overmeasure at both ends, widened symmetrically to ``min_length_mm``."""
    lo = np.asarray(t0_min, dtype=float) - overmeasure_mm
    hi = np.asarray(t0_max, dtype=float) + overmeasure_mm
    short = hi - lo < min_length_mm
    middle = 0.5 * (lo + hi)
    lo = np.where(short, middle - 0.5 * min_length_mm, lo)
    hi = np.where(short, middle + 0.5 * min_length_mm, hi)
    return lo, hi


def estimate_scan_duration(scan_line: tuple[float, float], scan_speed_mm_s: float) -> float:
    """Estimated duration (s) of a scan line's measurement trajectory before its mechanics are checked."""
    length = abs(scan_line[1] - scan_line[0])
    return length / scan_speed_mm_s + scan_speed_mm_s / SCAN_ACCELERATION_MM_S2


def scan_path(view, line: tuple[float, float], step_mm: float, jump_rad: float, ik, collision, preferred_state):
    """Cartesian path along the view's line from ``line[0]`` to ``line[1]`` (mm from the anchor along x).

    Tries every collision-free IK branch of the start pose, nearest ``preferred_state`` first, and returns
    the best ``(fraction, joint path, line)`` or None.
    """
    anchor = view.get_anchor_pose()
    x_axis = anchor[:3, 0]
    start_pose = anchor.copy()
    start_pose[:3, 3] += line[0] * x_axis
    end_pose = anchor.copy()
    end_pose[:3, 3] += line[1] * x_axis
    start_m, end_m = tip_pose_m(start_pose), tip_pose_m(end_pose)
    solutions, valid = ik.solve_all(start_m[None], seeds=preferred_state[None])
    branches = solutions[0][valid[0]]
    if len(branches) == 0:
        return None
    branches = branches[collision.check_states(branches)]
    if len(branches) == 0:
        return None
    order = np.argsort(np.abs(branches - preferred_state).max(axis=1))
    best = None
    for q_start in branches[order]:
        result = compute_cartesian_path(
            ik,
            q_start,
            end_m,
            step_mm=step_mm,
            jump_threshold_rad=jump_rad,
            validity_checker=collision.check_states,
        )
        if len(result.joint_path) >= 2 and (best is None or result.fraction > best[0]):
            best = (result.fraction, result.joint_path, line)
        if best is not None and best[0] >= 1.0:
            break
    return best


def scan_line_starts_free(views, ik, collision, preferred_state: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Whether each view's scan line has a collision-free IK branch at one of its two ends, for many views in
    one vectorised pass (closed-form IK of all end poses at once, one batched collision check).

    A view without one is rejected by :func:`verify_scan_line` for certain (both scan directions start at an
    end, with the same IK seed and the same collision check), so the batch settles such views cheaply; a
    view with one still needs the full check along its line.
    """
    out = np.zeros(len(views), dtype=bool)
    for begin in range(0, len(views), chunk):
        part = views[begin : begin + chunk]
        anchors = np.stack([v.get_anchor_pose() for v in part])
        lines = np.array([v.scan_line for v in part], dtype=float)
        ends = np.concatenate([anchors, anchors])
        x_axis = anchors[:, :3, 0]
        ends[: len(part), :3, 3] += lines[:, 0, None] * x_axis
        ends[len(part) :, :3, 3] += lines[:, 1, None] * x_axis
        solutions, valid = ik.solve_all(tip_pose_m(ends), seeds=preferred_state)
        rows, branches = np.nonzero(valid)
        free = np.zeros(valid.shape, dtype=bool)
        if rows.size:
            free[rows, branches] = collision.check_states(solutions[rows, branches])
        any_end = free.any(axis=1)
        out[begin : begin + len(part)] = any_end[: len(part)] | any_end[len(part) :]
    return out


def verify_scan_line(
    view,
    settings: dict,
    *,
    ik,
    collision,
    kinematics,
    limits,
    preferred_state: np.ndarray,
    scan_speed_mm_s: float,
    connect_from_current: Callable[[np.ndarray], object] | None = None,
) -> bool:
    """Compute the view's measurement trajectory; shorten the view to what is executable or reject it.

    ``settings``: trajectory_sample_step, minimum_required_overmeasure, joint_jump_threshold,
    minimum_trajectory_length, plan_path_to_check_reachability (the generation's mechanics settings, mm / rad).
    ``connect_from_current(q)`` plans a motion from the current state to ``q`` (None if there is none); it is
    used when ``plan_path_to_check_reachability`` is set. Sets the view's mechanics fields; returns validity.
    """
    path = check_scan_line(
        view,
        settings,
        ik=ik,
        collision=collision,
        preferred_state=preferred_state,
        scan_speed_mm_s=scan_speed_mm_s,
        connect_from_current=connect_from_current,
    )
    if path is None:
        return False
    set_scan_trajectory(view, path, kinematics=kinematics, limits=limits, scan_speed_mm_s=scan_speed_mm_s)
    return True


def check_scan_line(
    view,
    settings: dict,
    *,
    ik,
    collision,
    preferred_state: np.ndarray,
    scan_speed_mm_s: float,
    connect_from_current: Callable[[np.ndarray], object] | None = None,
) -> np.ndarray | None:
    """The geometric part of :func:`verify_scan_line`: the joint path (K, dof) rad of the view's executable
    scan line, or None (the view is rejected). Shortens the view like :func:`verify_scan_line` and sets
    ``mechanics_verified``, ``mechanics_valid``, ``scan_line`` and an estimated duration (s), but not the
    measurement trajectory: :func:`set_scan_trajectory` time-parameterises the path (about twice the cost of
    this check), so a set cover that verifies many views needs it only for the views it keeps.
    """
    view.mechanics_verified = True
    step = settings["trajectory_sample_step"]
    lo, hi = view.scan_line if not view.reversed else view.scan_line[::-1]
    best = None
    for direction in ((lo, hi), (hi, lo)):
        attempt = scan_path(view, direction, step, settings["joint_jump_threshold"], ik, collision, preferred_state)
        if attempt is not None and (best is None or attempt[0] > best[0]):
            best = attempt
        if best is not None and best[0] >= 1.0:
            break
    return _accept_scan_line(view, best, settings, scan_speed_mm_s, connect_from_current)


def _accept_scan_line(view, best, settings: dict, scan_speed_mm_s: float, connect_from_current) -> np.ndarray | None:
    """The end of :func:`check_scan_line` for the best ``(fraction, joint path, line)`` attempt (or None): reject,
    shorten (partial acceptance) or accept the view; returns the joint path or None."""
    overmeasure = settings["minimum_required_overmeasure"]
    if best is None:
        view.mechanics_valid = False
        return None
    fraction, path, line = best
    start_t, end_t = line
    achieved_end = start_t + fraction * (end_t - start_t)
    achieved_lo, achieved_hi = sorted((start_t, achieved_end))
    if achieved_hi - achieved_lo < settings["minimum_trajectory_length"] - 1e-6:
        view.mechanics_valid = False
        return None
    if fraction < 1.0:
        # partial acceptance: keep the points the laser line still sweeps, with the overmeasure margin
        indices = np.asarray(view.get_measurable_surface_point_indices())
        uncert = np.asarray(view.get_measurable_surface_point_uncertainties())
        t0s = np.asarray(view.get_measurable_surface_point_trajectory_distances())
        keep = (t0s >= achieved_lo + overmeasure - 1e-9) & (t0s <= achieved_hi - overmeasure + 1e-9)
        if not keep.any():
            view.mechanics_valid = False
            return None
        view.set_measurable_surface_point_indices_and_uncertainties(indices[keep], uncert[keep], t0s[keep])
    if settings.get("plan_path_to_check_reachability") and connect_from_current is not None:
        if connect_from_current(path[0]) is None:
            view.mechanics_valid = False
            return None
    view.scan_line = (start_t, achieved_end)
    view.reversed = False
    view.estimated_duration_s = estimate_scan_duration(view.scan_line, scan_speed_mm_s)
    view.mechanics_valid = True
    return path


def check_scan_lines(
    views,
    settings: dict,
    *,
    ik,
    collision,
    preferred_state: np.ndarray,
    scan_speed_mm_s: float,
    connect_from_current: Callable[[np.ndarray], object] | None = None,
    chunk: int = 1024,
) -> list:
    """:func:`check_scan_line` for many views at once: the same joint paths (or None), the same changes to the
    views, in a few batched steps per ``chunk`` views instead of a dozen small numpy calls per view.

    Each view tries its line's start branches (collision-free closed-form IK solutions, nearest
    ``preferred_state`` first) in the first scan direction, then in the other, until one attempt runs the whole
    line; the best attempt is the first one that goes furthest. Attempt k of every view still looking is computed
    for all of them at once (:func:`~agiprobot_measurement.motion.cartesian_batch.compute_cartesian_paths`: one
    IK call, one compiled walk with the jump and limit checks, one collision check of all states); most views
    are settled by their first attempt. Solvers without ``solve_all`` (KDL) are checked one view at a time.
    """
    views = list(views)
    if not hasattr(ik, "solve_all"):
        return [
            check_scan_line(
                v,
                settings,
                ik=ik,
                collision=collision,
                preferred_state=preferred_state,
                scan_speed_mm_s=scan_speed_mm_s,
                connect_from_current=connect_from_current,
            )
            for v in views
        ]
    out = []
    for begin in range(0, len(views), chunk):
        part = views[begin : begin + chunk]
        bests = _best_attempts(part, settings, ik, collision, preferred_state)
        out += [
            _accept_scan_line(v, b, settings, scan_speed_mm_s, connect_from_current)
            for v, b in zip(part, bests, strict=True)
        ]
    return out


def _best_attempts(views, settings: dict, ik, collision, preferred_state: np.ndarray) -> list:
    """Each view's best ``(fraction, joint path, line)`` attempt as :func:`check_scan_line` finds it, or None."""
    n = len(views)
    for view in views:
        view.mechanics_verified = True
    lines = np.array([v.scan_line if not v.reversed else v.scan_line[::-1] for v in views], dtype=float).reshape(n, 2)
    anchors = np.stack([v.get_anchor_pose() for v in views]) if n else np.zeros((0, 4, 4))
    # ends of both directions: row d * n + i is view i's direction d (0: lo -> hi, 1: hi -> lo)
    start_t = np.concatenate([lines[:, 0], lines[:, 1]])
    end_t = np.concatenate([lines[:, 1], lines[:, 0]])
    both = np.concatenate([anchors, anchors])
    starts, ends = both.copy(), both.copy()
    starts[:, :3, 3] += start_t[:, None] * both[:, :3, 0]
    ends[:, :3, 3] += end_t[:, None] * both[:, :3, 0]
    starts_m, ends_m = tip_pose_m(starts), tip_pose_m(ends)
    solutions, valid = ik.solve_all(starts_m, seeds=preferred_state)
    rows, branches = np.nonzero(valid)
    free = np.zeros(valid.shape, dtype=bool)
    if rows.size:
        free[rows, branches] = collision.check_states(solutions[rows, branches])
    # every view's attempts in order: the free branches of direction 0 nearest the preferred state first, then
    # those of direction 1
    distance = np.abs(np.nan_to_num(solutions) - preferred_state).max(axis=2)
    attempts = [[] for _ in range(n)]
    for r in range(2 * n):
        branch = np.flatnonzero(free[r])
        if branch.size:
            attempts[r % n] += [(r, int(b)) for b in branch[np.argsort(distance[r, branch], kind="stable")]]
    best = [None] * n
    active = [i for i in range(n) if attempts[i]]
    stage = 0
    step = settings["trajectory_sample_step"]
    while active:
        todo = [i for i in active if stage < len(attempts[i])]
        if not todo:
            break
        picked = [attempts[i][stage] for i in todo]
        rows_ = np.array([r for r, _ in picked], dtype=np.int64)
        branches_ = np.array([b for _, b in picked], dtype=np.int64)
        paths = compute_cartesian_paths(
            ik,
            solutions[rows_, branches_],
            ends_m[rows_],
            step_mm=step,
            jump_threshold_rad=settings["joint_jump_threshold"],
            validity_checker=collision.check_states,
        )
        still = []
        for k, i in enumerate(todo):
            path = paths.joint_path(k)
            fraction = float(paths.fractions[k])
            if len(path) >= 2 and (best[i] is None or fraction > best[i][0]):
                r = int(rows_[k])
                best[i] = (fraction, path, (float(start_t[r]), float(end_t[r])))
            if best[i] is None or best[i][0] < 1.0:
                still.append(i)
        active = still
        stage += 1
    return best


def set_scan_trajectory(view, path: np.ndarray, *, kinematics, limits, scan_speed_mm_s: float) -> None:
    """Time-parameterise a checked scan line's joint path (rad) at constant tip speed (mm/s): sets the view's
    measurement trajectory, its scan speed and its duration (s)."""
    scan = constant_speed_scan_trajectory(
        path, limits, scan_speed_mm_s, spacing_mm=None, tip_positions_m=kinematics.fk_batch(path)[:, :3, 3]
    )
    view.set_trajectory_for_measurement(scan.trajectory)
    view.scan_speed_mm_s = scan.scan_speed_mm_s
    view.estimated_duration_s = scan.trajectory.duration
