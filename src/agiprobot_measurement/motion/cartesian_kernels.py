"""Compiled branch following for :mod:`agiprobot_measurement.motion.cartesian`.

This module owns the laziness of numba: it is imported (about 0.6 s with the cached kernel) at the first call of
:func:`follow_branches`, so only processes that check enough scan lines for the compiled walk to pay off load it.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["follow_branches", "follow_paths"]


def follow_branches(solutions, valid, start_q):
    """(chosen branch per waypoint (M,), number of waypoints followed) for closed-form solutions (M, B, dof) rad
    with validity (M, B), compiled at the first call; see :func:`_follow_branches`."""
    return _compiled()(solutions, valid, start_q)


def follow_paths(solutions, valid, offsets, starts, jump_threshold, lower, upper):
    """Many paths' branch walks with their joint-jump and joint-limit checks, compiled at the first call; see
    :func:`_follow_paths`."""
    return _compiled_paths()(solutions, valid, offsets, starts, jump_threshold, lower, upper)


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
