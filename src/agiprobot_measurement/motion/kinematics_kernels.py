"""Compiled forward kinematics of a serial chain for large batches of joint states.

Like :mod:`agiprobot_measurement.motion.cartesian_kernels`, this module owns the laziness of numba: the kernel is
compiled (or loaded from numba's cache, about 0.6 s) at the first call, so only processes that pose many states at
once (the IK's refinement and the collision checks of batched scan-line verification) pay for it. Below
:data:`COMPILED_FROM_STATES` states the numpy code of the callers is as fast.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["COMPILED_FROM_STATES", "attached_frames", "chain_frames", "joint_frame", "register_helpers", "tip_frame"]

#: batches of at least this many joint states go through the compiled kernel
COMPILED_FROM_STATES = 512


def chain_frames(q, pre, axes, tip):
    """(frames (N, dof, 4, 4): each joint's frame after its rotation, tips (N, 4, 4): the last frame times ``tip``)
    for joint states ``q`` (N, dof) rad, the fixed transforms ``pre`` (dof, 4, 4) from the previous moving frame to
    each joint's frame, the joints' unit ``axes`` (dof, 3) and the last moving frame -> tip transform (4, 4)."""
    return _compiled()(
        np.ascontiguousarray(q, dtype=np.float64),
        np.ascontiguousarray(pre, dtype=np.float64),
        np.ascontiguousarray(axes, dtype=np.float64),
        np.ascontiguousarray(tip, dtype=np.float64),
    )


def attached_frames(frames, anchors, offsets):
    """(N, S, 4, 4): ``frames[:, anchors[s]] @ offsets[s]`` for each attached frame s, ``offsets[s]`` itself where
    ``anchors[s]`` < 0 (fixed to the base); ``frames`` (N, dof, 4, 4) rigid, ``anchors`` (S,), ``offsets``
    (S, 4, 4)."""
    return _compiled_attached()(
        np.ascontiguousarray(frames, dtype=np.float64),
        np.ascontiguousarray(anchors, dtype=np.int64),
        np.ascontiguousarray(offsets, dtype=np.float64),
    )


@functools.cache
def _compiled_attached():
    import numba  # lazily, see the module docstring

    register_helpers()
    return numba.njit(cache=True)(_attached_frames)


def _attached_frames(frames, anchors, offsets):  # pragma: no cover - compiled
    n, n_attached = frames.shape[0], anchors.shape[0]
    out = np.zeros((n, n_attached, 4, 4))
    for i in range(n):
        for s in range(n_attached):
            if anchors[s] < 0:
                out[i, s] = offsets[s]
            else:
                tip_frame(frames[i, anchors[s]], offsets[s], out[i, s])
    return out


@functools.cache
def register_helpers() -> None:
    """Make :func:`joint_frame` and :func:`tip_frame` callable from compiled kernels (this module's and
    :mod:`~agiprobot_measurement.motion.cartesian_kernels`'), once; they stay plain Python functions too."""
    from numba.extending import register_jitable  # lazily, see the module docstring

    register_jitable(joint_frame)
    register_jitable(tip_frame)


@functools.cache
def _compiled():
    import numba  # lazily, see the module docstring

    register_helpers()
    return numba.njit(cache=True)(_chain_frames)


def joint_frame(cur, nxt, rot, pre_k, axis, angle):  # pragma: no cover - compiled
    """``cur`` <- ``cur`` @ ``pre_k`` @ [R(axis, angle) 0; 0 1] in place (4 x 4 frames; ``nxt`` (4, 4) and ``rot``
    (3, 3) are scratch): one joint of the chain, its rotation by Rodrigues' formula I + s K + (1 - c) K^2 with K
    the unit ``axis``' skew matrix, ``angle`` rad."""
    x, y, z = axis[0], axis[1], axis[2]
    s, c1 = np.sin(angle), 1.0 - np.cos(angle)
    rot[0, 0] = 1.0 - c1 * (y * y + z * z)
    rot[0, 1] = -s * z + c1 * x * y
    rot[0, 2] = s * y + c1 * x * z
    rot[1, 0] = s * z + c1 * x * y
    rot[1, 1] = 1.0 - c1 * (x * x + z * z)
    rot[1, 2] = -s * x + c1 * y * z
    rot[2, 0] = -s * y + c1 * x * z
    rot[2, 1] = s * x + c1 * y * z
    rot[2, 2] = 1.0 - c1 * (x * x + y * y)
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for m in range(3):
                pm = 0.0
                for j in range(3):
                    pm += pre_k[m, j] * rot[j, c]
                acc += cur[r, m] * pm
            nxt[r, c] = acc
        t = cur[r, 3]
        for m in range(3):
            t += cur[r, m] * pre_k[m, 3]
        nxt[r, 3] = t
    for r in range(3):
        for c in range(4):
            cur[r, c] = nxt[r, c]
    cur[3, 0], cur[3, 1], cur[3, 2], cur[3, 3] = 0.0, 0.0, 0.0, 1.0


def tip_frame(cur, tip, out):  # pragma: no cover - compiled
    """``out`` <- ``cur`` @ ``tip`` (4 x 4 rigid frames)."""
    for r in range(3):
        for c in range(4):
            acc = cur[r, 3] if c == 3 else 0.0
            for m in range(3):
                acc += cur[r, m] * tip[m, c]
            out[r, c] = acc
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


def _chain_frames(q, pre, axes, tip):  # pragma: no cover - compiled
    n, dof = q.shape
    frames = np.zeros((n, dof, 4, 4))
    tips = np.zeros((n, 4, 4))
    rot = np.zeros((3, 3))
    cur = np.zeros((4, 4))
    nxt = np.zeros((4, 4))
    for i in range(n):
        for r in range(4):
            for c in range(4):
                cur[r, c] = 1.0 if r == c else 0.0
        for k in range(dof):
            joint_frame(cur, nxt, rot, pre[k], axes[k], q[i, k])
            frames[i, k] = cur
        tip_frame(cur, tip, tips[i])
    return frames, tips
