"""Compiled branch following for :mod:`agiprobot_measurement.motion.cartesian`.

This module owns the laziness of numba: it is imported (about 0.6 s with the cached kernel) at the first call of
:func:`follow_branches`, so only processes that check enough scan lines for the compiled walk to pay off load it.
"""

from __future__ import annotations

import functools

import numpy as np

from agiprobot_measurement.motion.kinematics_kernels import joint_frame, register_helpers, tip_frame

__all__ = ["TRACK_EXACT", "fill_line_poses", "follow_branches", "follow_paths", "kernels_loaded", "track_paths"]

#: the least stop code of :func:`track_paths` for a path it cannot settle beyond its count of waypoints: the caller
#: walks on from there with every IK branch
TRACK_EXACT = 5


def follow_branches(solutions, valid, start_q):
    """(chosen branch per waypoint (M,), number of waypoints followed) for closed-form solutions (M, B, dof) rad
    with validity (M, B), compiled at the first call; see :func:`_follow_branches`."""
    return _compiled()(solutions, valid, start_q)


def follow_paths(solutions, valid, offsets, starts, jump_threshold, lower, upper):
    """Many paths' branch walks with their joint-jump and joint-limit checks, compiled at the first call; see
    :func:`_follow_paths`."""
    return _compiled_paths()(solutions, valid, offsets, starts, jump_threshold, lower, upper)


def fill_line_poses(starts, targets, start_k, start_k2, angle, offsets):
    """The interpolated poses (M, 4, 4) of P lines, compiled at the first call; see :func:`_fill_line_poses`."""
    return _compiled_line_poses()(starts, targets, start_k, start_k2, angle, offsets)


def track_paths(
    poses, offsets, starts, shoulder_gap, pre, axes, tip, lower, upper, jump_threshold, margin, elbow_links
):
    """Many paths followed by Newton steps from state to state; see :func:`_track_paths`."""
    return _compiled_track()(
        poses,
        offsets,
        starts,
        shoulder_gap,
        pre,
        axes,
        tip,
        lower,
        upper,
        jump_threshold,
        margin,
        elbow_links,
    )


def kernels_loaded() -> bool:
    """Whether the batched path kernels (:func:`track_paths`, :func:`follow_paths`) are compiled or loaded from
    numba's cache in this process: their first call costs seconds, which a caller near a deadline may not have."""
    factories = (_compiled_track, _compiled_paths, _compiled_line_poses)
    return all(factory.cache_info().currsize and factory().signatures for factory in factories)


@functools.cache
def _compiled_track():
    import numba  # lazily, see the module docstring
    from numba.extending import register_jitable

    register_helpers()
    for helper in (_newton, _track_work, _wrapped_distance, _limit_class):
        register_jitable(helper)
    return numba.njit(cache=True)(_track_paths)


@functools.cache
def _compiled():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_follow_branches)


@functools.cache
def _compiled_line_poses():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_fill_line_poses)


def _fill_line_poses(starts, targets, start_k, start_k2, angle, offsets):  # pragma: no cover - compiled
    """Line i's poses in rows ``offsets[i]:offsets[i + 1]`` (n steps, start excluded, the last exactly
    ``targets[i]``): at s = j / n the position ``(1 - s) p0 + s p1`` (metres) and the rotation ``S + sin(s a) SK +
    (1 - cos(s a)) SK2`` (Rodrigues' formula of the line's rotation vector scaled by s, times the start's rotation
    S; ``start_k`` = S K, ``start_k2`` = S K^2 (P, 3, 3) with K the unit axis' skew matrix, ``angle`` (P,) rad)."""
    n_lines = starts.shape[0]
    poses = np.zeros((offsets[n_lines], 4, 4))
    for i in range(n_lines):
        first, last = offsets[i], offsets[i + 1]
        n = last - first
        for j in range(n - 1):
            s = (j + 1) / n
            sin_t, one_cos = np.sin(angle[i] * s), 1.0 - np.cos(angle[i] * s)
            row = first + j
            for r in range(3):
                for c in range(3):
                    poses[row, r, c] = starts[i, r, c] + sin_t * start_k[i, r, c] + one_cos * start_k2[i, r, c]
                poses[row, r, 3] = starts[i, r, 3] + s * (targets[i, r, 3] - starts[i, r, 3])
            poses[row, 3, 3] = 1.0
        poses[last - 1] = targets[i]  # end exactly on the target
    return poses


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
#: ... and so does a state whose |sin(wrist_2)| falls below this (the wrist singularity)
TRACK_MIN_WRIST_SINE = 0.02


def _newton(q, target, pre, axes, tip, work):  # pragma: no cover - compiled
    """Damped-free Newton steps moving ``q`` (dof,) rad in place until the chain's tip reaches ``target`` (4, 4)
    within TRACK_GOAL (m and rad of the pose error vector); at most TRACK_ITERATIONS steps. ``work`` is the
    scratch of :func:`_track_work`. Returns whether it converged (a near-singular Jacobian stops it: False)."""
    jac, err, cur, nxt, rot, origins, zaxes, gram, rhs = work
    dof = q.shape[0]
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
        # pose error: target - reached, the rotation R = Rt Rr^T as sin(angle) axis from its skew parts
        for r in range(3):
            err[r] = target[r, 3] - nxt[r, 3]
        r21 = 0.0
        r12 = 0.0
        r02 = 0.0
        r20 = 0.0
        r10 = 0.0
        r01 = 0.0
        for mm in range(3):
            r21 += target[2, mm] * nxt[1, mm]
            r12 += target[1, mm] * nxt[2, mm]
            r02 += target[0, mm] * nxt[2, mm]
            r20 += target[2, mm] * nxt[0, mm]
            r10 += target[1, mm] * nxt[0, mm]
            r01 += target[0, mm] * nxt[1, mm]
        err[3] = 0.5 * (r21 - r12)
        err[4] = 0.5 * (r02 - r20)
        err[5] = 0.5 * (r10 - r01)
        worst = 0.0
        for r in range(6):
            worst = max(worst, abs(err[r]))
        if worst <= TRACK_GOAL:
            return True
        for j in range(dof):
            lx = nxt[0, 3] - origins[j, 0]
            ly = nxt[1, 3] - origins[j, 1]
            lz = nxt[2, 3] - origins[j, 2]
            ax, ay, az = zaxes[j, 0], zaxes[j, 1], zaxes[j, 2]
            jac[0, j] = ay * lz - az * ly
            jac[1, j] = az * lx - ax * lz
            jac[2, j] = ax * ly - ay * lx
            jac[3, j], jac[4, j], jac[5, j] = ax, ay, az
        # J dq = err by Gaussian elimination with partial pivoting (J is 6x6 for the UR arm; a near-singular J gives
        # a large move, which leaves the path to the exact check)
        for r in range(6):
            for c in range(dof):
                gram[r, c] = jac[r, c]
            rhs[r] = err[r]
        for c in range(6):
            pivot = c
            for r in range(c + 1, 6):
                if abs(gram[r, c]) > abs(gram[pivot, c]):
                    pivot = r
            if abs(gram[pivot, c]) < 1e-12:
                return False
            if pivot != c:
                for cc in range(6):
                    gram[c, cc], gram[pivot, cc] = gram[pivot, cc], gram[c, cc]
                rhs[c], rhs[pivot] = rhs[pivot], rhs[c]
            for r in range(c + 1, 6):
                f = gram[r, c] / gram[c, c]
                for cc in range(c, 6):
                    gram[r, cc] -= f * gram[c, cc]
                rhs[r] -= f * rhs[c]
        for r in range(5, -1, -1):
            acc = rhs[r]
            for cc in range(r + 1, 6):
                acc -= gram[r, cc] * rhs[cc]
            rhs[r] = acc / gram[r, r]
        for j in range(dof):
            q[j] += rhs[j]
    return False


def _track_work(dof):  # pragma: no cover - compiled
    """Scratch arrays of :func:`_newton`."""
    return (
        np.zeros((6, dof)),
        np.zeros(6),
        np.zeros((4, 4)),
        np.zeros((4, 4)),
        np.zeros((3, 3)),
        np.zeros((dof, 3)),
        np.zeros((dof, 3)),
        np.zeros((6, 6)),
        np.zeros(6),
    )


def _wrapped_distance(a, b):  # pragma: no cover - compiled
    """L2 norm of the joint differences ``a - b`` wrapped to [-pi, pi) (rad), as the branch walk measures it."""
    two_pi = 2.0 * np.pi
    total = 0.0
    for d in range(a.shape[0]):
        x = a[d] - b[d] + np.pi
        x = x - two_pi * np.floor(x / two_pi) - np.pi
        total += x * x
    return np.sqrt(total)


#: :func:`_limit_class`' answers: every joint has a value within its limits; some joint only within the closed
#: form's clipping slack beyond a limit; some joint none even there
LIMITS_INSIDE, LIMITS_NEAR, LIMITS_OUTSIDE = 0, 1, 2
#: the closed form clips a solution this far (rad) beyond a limit into it (the IK's clip slack)
CLIP_SLACK_RAD = 1e-4


def _limit_class(q, lower, upper):  # pragma: no cover - compiled
    """Whether the IK's closed form keeps the solution ``q`` (dof,) rad, some turn of each joint within [lower,
    upper] (1e-9 rad slack): LIMITS_INSIDE, LIMITS_NEAR (some joint only within CLIP_SLACK_RAD beyond a limit,
    where the closed form clips and refines again) or LIMITS_OUTSIDE."""
    two_pi = 2.0 * np.pi
    worst = LIMITS_INSIDE
    for d in range(q.shape[0]):
        if np.ceil((lower[d] - 1e-9 - q[d]) / two_pi) <= np.floor((upper[d] + 1e-9 - q[d]) / two_pi):
            continue
        if np.ceil((lower[d] - CLIP_SLACK_RAD - q[d]) / two_pi) <= np.floor(
            (upper[d] + CLIP_SLACK_RAD - q[d]) / two_pi
        ):
            worst = max(worst, LIMITS_NEAR)
        else:
            worst = LIMITS_OUTSIDE
    return worst


def _track_paths(
    poses, offsets, starts, shoulder_gap, pre, axes, tip, lower, upper, jump_threshold, margin, elbow_links
):  # pragma: no cover - compiled
    """The joint states of P Cartesian paths by continuation: each waypoint's state is found by damped Newton
    steps on the model's kinematics from the previous one, and the path stops as :func:`_follow_paths` stops it.

    This is the walk of :func:`_follow_paths` over the closed-form solutions whenever the state kept is the
    closed-form solution nearest the previous one: the path stops with a code of at least :data:`TRACK_EXACT` at
    its first waypoint where that is not shown (its count the waypoints before it, which are; the caller walks on
    from there over every branch) unless, at each of its waypoints, Newton converges, no joint moves more than
    TRACK_MAX_MOVE_RAD (or the jump threshold, if smaller), |sin(q5)| >= TRACK_MIN_WRIST_SINE, the wrist flip (pi
    on joint 6) and the other shoulder (``shoulder_gap`` (M,) on joint 1, rad, from the caller's closed form) lie
    at least ``2 |move| + margin`` from the kept state, ``|move|`` the length (L2, rad) of the move onto that
    waypoint (then they are farther from the previous state than the kept one, which the walk therefore keeps),
    and the kept state has every joint within its limits (:func:`_limit_class`). The elbow's mirror either lies
    that far too (2 |q3| on joint 3) or is solved for (the planar two-link arm of the DH lengths a2, a3 mirrored,
    then Newton on the model): of the tracked state and the mirror the walk keeps the nearer one within the limits,
    and so does this (``elbow_links``: the DH lengths a2, a3 m of the closed form). UR joint order (shoulder
    pan, lift, elbow, wrist 1, 2, 3) assumed. Chain as :func:`chain_frames`.
    """
    m = poses.shape[0]
    n_paths, dof = starts.shape
    states = np.zeros((m + n_paths, dof))
    counts = np.zeros(n_paths, dtype=np.int64)
    codes = np.zeros(n_paths, dtype=np.int64)
    two_pi = 2.0 * np.pi
    # the walk takes the closed-form solution nearest the previous state (L2 over wrapped differences): another
    # branch at least twice the kept move (plus the margin) from the kept state is farther from the previous
    # state than the kept one (triangle inequality), and the walk keeps that one
    max_move = min(TRACK_MAX_MOVE_RAD, jump_threshold)
    # the wrist flip (pi on joint 6) may lie within reach of the largest move: every path goes to the exact walk
    all_exact = 2.0 * np.sqrt(dof) * max_move + margin >= np.pi
    work = _track_work(dof)
    a2, a3 = elbow_links[0], elbow_links[1]
    q = np.zeros(dof)
    twin = np.zeros(dof)
    start_q = np.zeros(dof)
    velocity = np.zeros(dof)
    for i in range(n_paths):
        first, last = offsets[i], offsets[i + 1]
        row = first + i
        for d in range(dof):
            q[d] = min(max(starts[i, d], lower[d]), upper[d])
            states[row, d] = q[d]
        count = last - first
        code = 0
        if all_exact:
            count, code = 0, 5
        for k in range(first, last):
            if code >= 5:
                break
            start_q[:] = q
            if k > first:
                for d in range(dof):
                    q[d] += velocity[d]  # the last move as the predictor: one Newton step is then enough
            if not _newton(q, poses[k], pre, axes, tip, work):
                count, code = k - first, 6  # the walk over every branch decides (a pose out of reach: it ends)
                break
            moved = _wrapped_distance(q, start_q)
            kept = _limit_class(q, lower, upper)
            x = 2.0 * abs(q[2] + np.pi - two_pi * np.floor((q[2] + np.pi) / two_pi) - np.pi)
            if min(x, two_pi - x) < 2.0 * moved + margin:
                # the elbow's mirror may be nearer the previous state (or the only valid one of the two): solve for
                # it (the mirrored planar arm: q3' = -q3, q2' = q2 + beta(q3) - beta(-q3), q4' keeps q2 + q3 + q4;
                # Newton on the model then) and keep the one the walk keeps
                shift = np.arctan2(a3 * np.sin(q[2]), a2 + a3 * np.cos(q[2])) - np.arctan2(
                    -a3 * np.sin(q[2]), a2 + a3 * np.cos(q[2])
                )
                for d in range(dof):
                    twin[d] = q[d]
                twin[1] = q[1] + shift
                twin[2] = -q[2]
                twin[3] = q[3] - shift + 2.0 * q[2]
                if not _newton(twin, poses[k], pre, axes, tip, work):
                    count, code = k - first, 9
                    break
                mirrored = _limit_class(twin, lower, upper)
                if mirrored == LIMITS_NEAR:
                    count, code = k - first, 5
                    break
                twin_moved = _wrapped_distance(twin, start_q)
                # the nearer valid one (the walk's order of the branches puts the elbow's q3 >= 0 first: the tie)
                nearer = twin_moved < moved or (twin_moved == moved and twin[2] > q[2])
                if mirrored == LIMITS_INSIDE and (kept == LIMITS_OUTSIDE or nearer):
                    for d in range(dof):
                        x = twin[d] - start_q[d] + np.pi
                        q[d] = start_q[d] + x - two_pi * np.floor(x / two_pi) - np.pi
                    moved, kept = twin_moved, mirrored
            if kept != LIMITS_INSIDE:
                # a joint of a narrow range beyond its limit: the walk has no such solution and may take one of the
                # far branches; next to a limit the closed form clips: the exact walk decides either way
                count, code = k - first, 5
                break
            large = False
            for d in range(dof):
                velocity[d] = q[d] - start_q[d]
                if abs(velocity[d]) > max_move:
                    large = True
            # the other branches must lie farther than twice this move (plus the margin) from the kept state
            need = 2.0 * moved + margin
            if large:
                count, code = k - first, 7
                break
            if abs(np.sin(q[4])) < TRACK_MIN_WRIST_SINE:
                count, code = k - first, 8
                break
            if shoulder_gap[k] < need:
                count, code = k - first, 10
                break
            outside = False
            for d in range(dof):
                if q[d] < lower[d] - 1e-9 or q[d] > upper[d] + 1e-9:
                    outside = True
                states[row + k - first + 1, d] = min(max(q[d], lower[d]), upper[d])
            if outside:
                count, code = k - first, 3
                break
        counts[i] = count
        codes[i] = code
    return states, counts, codes
