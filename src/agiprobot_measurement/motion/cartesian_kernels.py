"""Compiled branch following for :mod:`agiprobot_measurement.motion.cartesian`.

This module owns the laziness of numba: it is imported (about 0.6 s with the cached kernel) at the first call of
:func:`follow_branches`, so only processes that check enough scan lines for the compiled walk to pay off load it.
"""

from __future__ import annotations

import functools

import numpy as np

from agiprobot_measurement.motion.kinematics_kernels import joint_frame, register_helpers, tip_frame

__all__ = ["TRACK_EXACT", "follow_branches", "follow_paths", "kernels_loaded", "track_paths"]

#: the stop code of :func:`track_paths` for a path it cannot settle: the caller checks it with every IK branch
TRACK_EXACT = 5


def follow_branches(solutions, valid, start_q):
    """(chosen branch per waypoint (M,), number of waypoints followed) for closed-form solutions (M, B, dof) rad
    with validity (M, B), compiled at the first call; see :func:`_follow_branches`."""
    return _compiled()(solutions, valid, start_q)


def follow_paths(solutions, valid, offsets, starts, jump_threshold, lower, upper):
    """Many paths' branch walks with their joint-jump and joint-limit checks, compiled at the first call; see
    :func:`_follow_paths`."""
    return _compiled_paths()(solutions, valid, offsets, starts, jump_threshold, lower, upper)


def track_paths(poses, offsets, starts, shoulder_gap, pre, axes, tip, lower, upper, jump_threshold, margin):
    """Many paths followed by Newton steps from state to state; see :func:`_track_paths`."""
    return _compiled_track()(poses, offsets, starts, shoulder_gap, pre, axes, tip, lower, upper, jump_threshold, margin)


def kernels_loaded() -> bool:
    """Whether the batched path kernels (:func:`track_paths`, :func:`follow_paths`) are compiled or loaded from
    numba's cache in this process: their first call costs seconds, which a caller near a deadline may not have."""
    return all(factory.cache_info().currsize and factory().signatures for factory in (_compiled_track, _compiled_paths))


@functools.cache
def _compiled_track():
    import numba  # lazily, see the module docstring

    register_helpers()
    return numba.njit(cache=True)(_track_paths)


@functools.cache
def _compiled():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_follow_branches)


@functools.cache
def _compiled_paths():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_follow_paths)


def _follow_branches(solutions, valid, start_q):  # pragma: no cover - compiled
    """(chosen branch per waypoint (M,), number of waypoints followed) for closed-form solutions (M, B, dof) rad
    with validity (M, B): at each waypoint the valid solution nearest the previous choice (norm of the joint
    differences wrapped to [-pi, pi)), starting from ``start_q``; stops at the first waypoint with none."""
    m, n_branches, dof = solutions.shape
    chosen = np.zeros(m, dtype=np.int64)
    two_pi = 2.0 * np.pi
    previous = start_q.copy()
    for k in range(m):
        best, best_j = np.inf, -1
        for j in range(n_branches):
            if not valid[k, j]:
                continue
            total = 0.0
            for d in range(dof):
                x = solutions[k, j, d] - previous[d] + np.pi
                x = x - two_pi * np.floor(x / two_pi) - np.pi
                total += x * x
            if total < best:
                best, best_j = total, j
        if best_j < 0:
            return chosen, k
        chosen[k] = best_j
        previous = solutions[k, best_j].copy()
    return chosen, m


def _follow_paths(solutions, valid, offsets, starts, jump_threshold, lower, upper):  # pragma: no cover - compiled
    """The joint states of P Cartesian paths (as ``compute_cartesian_path`` walks one) in one pass.

    Path i's waypoints are rows ``offsets[i]:offsets[i + 1]`` of the closed-form ``solutions`` (M, B, dof) rad with
    ``valid`` (M, B); it starts at ``starts[i]``. The walk takes the valid solution nearest the previous one
    (:func:`_follow_branches`) until a waypoint has none; the joints move by the wrapped differences, accumulated
    from the start; the path stops before the first move above ``jump_threshold`` (rad) on any joint and before
    the first state outside [lower, upper] (1e-9 rad slack), and is clipped into the limits.

    Returns (states (M + P, dof): path i's states (start included) in rows offsets[i] + i onwards, counts (P,):
    the waypoints reached (states - 1), codes (P,): 0 complete, 1 unreachable, 2 joint jump, 3 joint limits).
    """
    m, n_branches, dof = solutions.shape
    n_paths = starts.shape[0]
    states = np.zeros((m + n_paths, dof))
    counts = np.zeros(n_paths, dtype=np.int64)
    codes = np.zeros(n_paths, dtype=np.int64)
    two_pi = 2.0 * np.pi
    previous = np.zeros(dof)
    move = np.zeros(dof)
    total = np.zeros(dof)
    for i in range(n_paths):
        first, last = offsets[i], offsets[i + 1]
        row = first + i
        for d in range(dof):
            previous[d] = starts[i, d]
            total[d] = 0.0
            states[row, d] = min(max(starts[i, d], lower[d]), upper[d])
        count = last - first
        code = 0
        for k in range(first, last):
            best, best_j = np.inf, -1
            for j in range(n_branches):
                if not valid[k, j]:
                    continue
                norm = 0.0
                for d in range(dof):
                    x = solutions[k, j, d] - previous[d] + np.pi
                    x = x - two_pi * np.floor(x / two_pi) - np.pi
                    norm += x * x
                if norm < best:
                    best, best_j = norm, j
            if best_j < 0:
                count, code = k - first, 1
                break
            jump = False
            for d in range(dof):
                x = solutions[k, best_j, d] - previous[d] + np.pi
                move[d] = x - two_pi * np.floor(x / two_pi) - np.pi
                if abs(move[d]) > jump_threshold:
                    jump = True
            if jump:
                count, code = k - first, 2
                break
            outside = False
            for d in range(dof):
                total[d] += move[d]
                q = starts[i, d] + total[d]
                if q < lower[d] - 1e-9 or q > upper[d] + 1e-9:
                    outside = True
                states[row + k - first + 1, d] = min(max(q, lower[d]), upper[d])
                previous[d] = solutions[k, best_j, d]
            if outside:
                count, code = k - first, 3
                break
        counts[i] = count
        codes[i] = code
    return states, counts, codes


#: a tracked state must reach its pose this closely (the pose error vector, m and rad), as the IK's refinement does
TRACK_GOAL = 1e-9
TRACK_ITERATIONS = 12
#: a tracked move larger than this on any joint (rad) leaves the path to the exact check (next to a singularity)
TRACK_MAX_MOVE_RAD = 0.1
#: the elbow's mirror solution counts as within the elbow's limits up to this far beyond them (rad): the closed
#: form's limit slack (0.02) and a calibrated arm's deviation from the nominal DH (0.05)
MIRROR_LIMIT_SLACK_RAD = 0.07
#: ... and so does a state whose |sin(wrist_2)| falls below this (the wrist singularity)
TRACK_MIN_WRIST_SINE = 0.02


def _track_paths(
    poses, offsets, starts, shoulder_gap, pre, axes, tip, lower, upper, jump_threshold, margin
):  # pragma: no cover - compiled
    """The joint states of P Cartesian paths by continuation: each waypoint's state is found by damped Newton
    steps on the model's kinematics from the previous one, and the path stops as :func:`_follow_paths` stops it.

    This is the walk of :func:`_follow_paths` over the closed-form solutions whenever the continued state is the
    closed-form solution nearest the previous one and every other one lies beyond the jump threshold: the path is
    given the code :data:`TRACK_EXACT` (to be checked with every branch) unless, at each of its waypoints, Newton
    converges, no joint moves more than TRACK_MAX_MOVE_RAD (or the jump threshold, if smaller), |sin(q5)| >=
    TRACK_MIN_WRIST_SINE, and the other branches are at least ``2 sqrt(dof) max_move + margin`` away (then farther
    from the previous state than the tracked one, which the walk therefore keeps): the wrist flip (pi on joint 6), the elbow's mirror
    (2 |q3| on joint 3, unless -q3 lies outside the elbow's limits) and the other shoulder (``shoulder_gap`` (M,) on joint 1, rad, from the caller's closed
    form). UR joint order (shoulder pan, lift, elbow, wrist 1, 2, 3) assumed. Chain as :func:`chain_frames`.
    """
    m = poses.shape[0]
    n_paths, dof = starts.shape
    states = np.zeros((m + n_paths, dof))
    counts = np.zeros(n_paths, dtype=np.int64)
    codes = np.zeros(n_paths, dtype=np.int64)
    two_pi = 2.0 * np.pi
    # the walk takes the closed-form solution nearest the previous state (L2 over wrapped differences): the tracked
    # one moves at most sqrt(dof) * max_move, so another branch at least twice that (plus the margin) from the
    # tracked state is farther from the previous state than the tracked one (triangle inequality), and the walk
    # keeps the tracked branch
    max_move = min(TRACK_MAX_MOVE_RAD, jump_threshold)
    need = 2.0 * np.sqrt(dof) * max_move + margin
    q = np.zeros(dof)
    jac = np.zeros((6, dof))
    err = np.zeros(6)
    cur = np.zeros((4, 4))
    nxt = np.zeros((4, 4))
    rot = np.zeros((3, 3))
    origins = np.zeros((dof, 3))
    zaxes = np.zeros((dof, 3))
    gram = np.zeros((6, 6))
    rhs = np.zeros(6)
    velocity = np.zeros(dof)
    for i in range(n_paths):
        first, last = offsets[i], offsets[i + 1]
        row = first + i
        for d in range(dof):
            q[d] = min(max(starts[i, d], lower[d]), upper[d])
            states[row, d] = q[d]
        count = last - first
        code = 0
        if need >= np.pi:
            count, code = 0, 5
        for k in range(first, last):
            if code >= 5:
                break
            converged = False
            start_q = q.copy()
            if k > first:
                for d in range(dof):
                    q[d] += velocity[d]  # the last move as the predictor: one Newton step is then enough
            for _ in range(TRACK_ITERATIONS):
                # forward kinematics with every joint's origin and axis
                for r in range(4):
                    for c in range(4):
                        cur[r, c] = 1.0 if r == c else 0.0
                for j in range(dof):
                    joint_frame(cur, nxt, rot, pre[j], axes[j], q[j])
                    x, y, z = axes[j, 0], axes[j, 1], axes[j, 2]
                    for r in range(3):
                        origins[j, r] = cur[r, 3]
                        zaxes[j, r] = cur[r, 0] * x + cur[r, 1] * y + cur[r, 2] * z
                tip_frame(cur, tip, nxt)
                # pose error: target - reached, rotation target R^T as sin(angle) axis
                for r in range(3):
                    err[r] = poses[k, r, 3] - nxt[r, 3]
                # R = Rt Rr^T; skew parts
                r21 = 0.0
                r12 = 0.0
                r02 = 0.0
                r20 = 0.0
                r10 = 0.0
                r01 = 0.0
                for mm in range(3):
                    r21 += poses[k, 2, mm] * nxt[1, mm]
                    r12 += poses[k, 1, mm] * nxt[2, mm]
                    r02 += poses[k, 0, mm] * nxt[2, mm]
                    r20 += poses[k, 2, mm] * nxt[0, mm]
                    r10 += poses[k, 1, mm] * nxt[0, mm]
                    r01 += poses[k, 0, mm] * nxt[1, mm]
                err[3] = 0.5 * (r21 - r12)
                err[4] = 0.5 * (r02 - r20)
                err[5] = 0.5 * (r10 - r01)
                worst = 0.0
                for r in range(6):
                    worst = max(worst, abs(err[r]))
                if worst <= TRACK_GOAL:
                    converged = True
                    break
                for j in range(dof):
                    lx = nxt[0, 3] - origins[j, 0]
                    ly = nxt[1, 3] - origins[j, 1]
                    lz = nxt[2, 3] - origins[j, 2]
                    ax, ay, az = zaxes[j, 0], zaxes[j, 1], zaxes[j, 2]
                    jac[0, j] = ay * lz - az * ly
                    jac[1, j] = az * lx - ax * lz
                    jac[2, j] = ax * ly - ay * lx
                    jac[3, j], jac[4, j], jac[5, j] = ax, ay, az
                # J dq = err by Gaussian elimination with partial pivoting (J is 6x6 for the UR arm; a near-singular
                # J gives a large move, which leaves the path to the exact check)
                for r in range(6):
                    for c in range(dof):
                        gram[r, c] = jac[r, c]
                    rhs[r] = err[r]
                singular = False
                for c in range(6):
                    pivot = c
                    for r in range(c + 1, 6):
                        if abs(gram[r, c]) > abs(gram[pivot, c]):
                            pivot = r
                    if abs(gram[pivot, c]) < 1e-12:
                        singular = True
                        break
                    if pivot != c:
                        for cc in range(6):
                            gram[c, cc], gram[pivot, cc] = gram[pivot, cc], gram[c, cc]
                        rhs[c], rhs[pivot] = rhs[pivot], rhs[c]
                    for r in range(c + 1, 6):
                        f = gram[r, c] / gram[c, c]
                        for cc in range(c, 6):
                            gram[r, cc] -= f * gram[c, cc]
                        rhs[r] -= f * rhs[c]
                if singular:
                    break
                for r in range(5, -1, -1):
                    acc = rhs[r]
                    for cc in range(r + 1, 6):
                        acc -= gram[r, cc] * rhs[cc]
                    rhs[r] = acc / gram[r, r]
                for j in range(dof):
                    q[j] += rhs[j]
            if not converged:
                count, code = 0, 6
                break
            large = False
            for d in range(dof):
                velocity[d] = q[d] - start_q[d]
                if abs(velocity[d]) > min(TRACK_MAX_MOVE_RAD, jump_threshold):
                    large = True
            x = 2.0 * abs(q[2] + np.pi - two_pi * np.floor((q[2] + np.pi) / two_pi) - np.pi)
            elbow_gap = min(x, two_pi - x)
            # the elbow's mirror (-q3) outside the elbow's limits (any turn, with the closed form's slack and a
            # calibrated arm's deviation) is no solution at all
            mirror = -q[2]
            lo, hi = lower[2] - MIRROR_LIMIT_SLACK_RAD, upper[2] + MIRROR_LIMIT_SLACK_RAD
            if np.ceil((lo - mirror) / two_pi) > np.floor((hi - mirror) / two_pi):
                elbow_gap = np.inf
            if large:
                count, code = 0, 7
                break
            if abs(np.sin(q[4])) < TRACK_MIN_WRIST_SINE:
                count, code = 0, 8
                break
            if elbow_gap < need:
                count, code = 0, 9
                break
            if shoulder_gap[k] < need:
                count, code = 0, 10
                break
            outside = False
            for d in range(dof):
                if q[d] < lower[d] - 1e-9 or q[d] > upper[d] + 1e-9:
                    outside = True
                    if q[d] > lower[d] - 1e-4 and q[d] < upper[d] + 1e-4:
                        code = 5  # the closed form clips within 1e-4 rad of a limit: the exact walk decides
                states[row + k - first + 1, d] = min(max(q[d], lower[d]), upper[d])
            if code == 5:
                count = 0
                break
            if outside:
                count, code = k - first, 3
                break
        counts[i] = count
        codes[i] = code
    return states, counts, codes
