"""Compiled branch following for :mod:`agiprobot_measurement.motion.cartesian`.

This module owns the laziness of numba: it is imported (about 0.6 s with the cached kernel) at the first call of
:func:`follow_branches`, so only processes that check enough scan lines for the compiled walk to pay off load it.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["follow_branches"]


def follow_branches(solutions, valid, start_q):
    """(chosen branch per waypoint (M,), number of waypoints followed) for closed-form solutions (M, B, dof) rad
    with validity (M, B), compiled at the first call; see :func:`_follow_branches`."""
    return _compiled()(solutions, valid, start_q)


@functools.cache
def _compiled():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_follow_branches)


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
