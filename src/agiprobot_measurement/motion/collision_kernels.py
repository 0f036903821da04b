"""The collision checker's broad-phase geometry: segment distances, and its first stages compiled for large batches.

Like :mod:`agiprobot_measurement.motion.kinematics_kernels`, this module owns the laziness of numba (compiled or
loaded from its cache at the first call). :func:`sphere_candidates` gives the same candidates as the numpy code
of :meth:`CollisionChecker._broad_phase <agiprobot_measurement.motion.collision.CollisionChecker>`'s first
stage, without its (states x shapes x obstacles x 3) temporaries.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["centres_inside_meshes", "second_stage", "segment_distances", "sphere_candidates", "sphere_candidates_numpy"]

#: segment lengths (squared, m^2) are floored at this, so degenerate segments work as points
_EPS = 1e-12


def centres_inside_meshes(centres: np.ndarray, obstacles: np.ndarray, objects) -> np.ndarray:
    """(K,) bool: whether each point ``centres`` (K, 3) m (world) lies inside the closed mesh of the obstacle
    ``objects[obstacles[k]]`` (False for an obstacle without a mesh): its oriented bounding box first, then the
    mesh's own test (rays through Embree) for all points in the box of one obstacle at once."""
    inside = np.zeros(len(centres), dtype=bool)
    for o in np.unique(obstacles).tolist():
        obj = objects[o]
        if obj.mesh is None:
            continue
        rows = np.flatnonzero(obstacles == o)
        rotation, translation = obj.pose[:3, :3], obj.pose[:3, 3]
        local = (centres[rows] - translation) @ rotation  # R^T (c - t) per row
        box_local = rotation.T @ (obj.box_center - translation)
        in_box = np.all(np.abs(local - box_local) <= obj.box_half, axis=1)
        if in_box.any():
            inside[rows[in_box]] = np.asarray(obj.mesh.contains(local[in_box]), dtype=bool)
    return inside


def sphere_candidates(centers, box_axes, box_center, box_half, bound, env_checked, pair_i, pair_j, reach2):
    """(env (K, 3) rows [state, shape, obstacle], pairs (L, 2) rows [state, self-pair]), both in row-major order:
    the robot shapes whose bounding sphere (``centers`` (N, S, 3) m, radii ``bound`` (S,)) meets an obstacle's box
    (axes as rows ``box_axes`` (3 O, 3), centre coordinates along them ``box_center`` (3 O,), half extents
    ``box_half`` (3 O,)) where ``env_checked`` (S, O) asks for it, and the self pairs (``pair_i``, ``pair_j`` (P,))
    whose centres are closer than sqrt(``reach2`` (P,))."""
    return _compiled()(
        np.ascontiguousarray(centers, dtype=np.float64),
        np.ascontiguousarray(box_axes, dtype=np.float64),
        np.ascontiguousarray(box_center, dtype=np.float64),
        np.ascontiguousarray(box_half, dtype=np.float64),
        np.ascontiguousarray(bound, dtype=np.float64),
        np.ascontiguousarray(env_checked, dtype=np.bool_),
        np.ascontiguousarray(pair_i, dtype=np.int64),
        np.ascontiguousarray(pair_j, dtype=np.int64),
        np.ascontiguousarray(reach2, dtype=np.float64),
    )


def sphere_candidates_numpy(centers, box_axes, box_center, box_half, bound, env_checked, pair_i, pair_j, reach2):
    """:func:`sphere_candidates` in numpy (no compilation: as fast for small batches)."""
    n, n_obj = centers.shape[0], env_checked.shape[1]
    env = np.zeros((0, 3), dtype=np.int64)
    if n_obj:
        offset = centers @ box_axes.T - box_center  # centres in box coordinates (N, S, 3 O)
        apart = np.abs(offset) > box_half + bound[:, None]
        env = np.argwhere(~apart.reshape(n, -1, n_obj, 3).any(axis=-1) & env_checked)
    gap = centers[:, pair_i] - centers[:, pair_j]
    pairs = np.argwhere(np.einsum("npi,npi->np", gap, gap) < reach2)
    return env, pairs


def segment_distances(p0, p1, q0, q1) -> np.ndarray:
    """Distances between segments p0-p1 and q0-q1 (arrays (..., 3)); Ericson, Real-Time Collision Detection 5.1.9.

    Degenerate segments (spheres) work as points: their squared lengths are floored at a tiny value, which
    makes the general formulas reduce to the point cases.
    """
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.maximum((d1 * d1).sum(-1), _EPS)
    e = np.maximum((d2 * d2).sum(-1), _EPS)
    b, c, f = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
    denom = a * e - b * b
    # parallel segments: any s works, 0 as in Ericson
    s = np.where(denom > 1e-9 * a * e, (b * f - c * e) / np.maximum(denom, _EPS * _EPS), 0.0)
    s = np.minimum(np.maximum(s, 0.0), 1.0)
    t = (b * s + f) / e
    clamped = np.minimum(np.maximum(t, 0.0), 1.0)
    s = np.where(t != clamped, np.minimum(np.maximum((b * clamped - c) / a, 0.0), 1.0), s)
    gap = r + d1 * s[..., None] - d2 * clamped[..., None]
    return np.sqrt((gap * gap).sum(-1))


def second_stage(found, close_rows, poses, world, boxes, pairs):
    """The broad phase's second stage, compiled (the numpy code of ``CollisionChecker._broad_phase`` for large
    batches): (sure (N,) bool: states certainly in collision, env_near (K,) bool per row of ``found``, pair_near
    (L,) bool per row of ``close_rows``), the rows of sure states cleared.

    ``found`` (K, 3) [state, shape, obstacle] and ``close_rows`` (L, 2) [state, self pair]: the first stage's
    candidates; ``poses`` (N, S, 4, 4) the shapes' poses; ``world``: the shapes' (axis index (S,), half extents
    (S, 3), ball (S,), disc (S,), extent along the axis (S,), half length (S,)) for the world; ``boxes``: the
    obstacles' (axes as rows (3 O, 3), centre coordinates along them (3 O,), half extents (O, 3), rotation
    (O, 3, 3), solid (O,)); ``pairs``: the self pairs' (i (P,), j (P,), own half lengths (S,), reach (P,))."""
    axis, extents, ball, disc, axis_extent, half_length = world
    box_axes, box_center, box_half, box_rotation, solid = boxes
    pair_i, pair_j, own_half, reach = pairs
    f64 = functools.partial(np.ascontiguousarray, dtype=np.float64)
    i64 = functools.partial(np.ascontiguousarray, dtype=np.int64)
    return _compiled_second()(
        i64(found), i64(close_rows), f64(poses), i64(axis), f64(extents), f64(ball), f64(disc), f64(axis_extent),
        f64(half_length), f64(box_axes), f64(box_center), f64(box_half), f64(box_rotation),
        np.ascontiguousarray(solid, dtype=np.bool_), i64(pair_i), i64(pair_j), f64(own_half), f64(reach),
    )  # fmt: skip


@functools.cache
def _compiled():
    import numba  # lazily, see the module docstring

    return numba.njit(cache=True)(_sphere_candidates)


@functools.cache
def _compiled_second():
    import numba  # lazily, see the module docstring
    from numba.extending import register_jitable

    register_jitable(_segment_distance)
    return numba.njit(cache=True)(_second_stage)


def _second_stage(
    found, close_rows, poses, axis, extents, ball, disc, axis_extent, half_length, box_axes, box_center, box_half,
    box_rotation, solid, pair_i, pair_j, own_half, reach,
):  # pragma: no cover - compiled  # fmt: skip
    n = poses.shape[0]
    sure = np.zeros(n, dtype=np.bool_)
    env_near = np.zeros(found.shape[0], dtype=np.bool_)
    local = np.zeros(3)
    along = np.zeros(3)
    for row in range(found.shape[0]):
        state, shape, o = found[row, 0], found[row, 1], found[row, 2]
        for a in range(3):
            r = 3 * o + a
            local[a] = (
                poses[state, shape, 0, 3] * box_axes[r, 0]
                + poses[state, shape, 1, 3] * box_axes[r, 1]
                + poses[state, shape, 2, 3] * box_axes[r, 2]
                - box_center[r]
            )
        # separating axes with exact supports: the box's axes, then the shape's axis
        apart = False
        for i in range(3):
            extent = ball[shape]
            for k in range(3):
                cosine = (
                    box_rotation[o, 0, i] * poses[state, shape, 0, k]
                    + box_rotation[o, 1, i] * poses[state, shape, 1, k]
                    + box_rotation[o, 2, i] * poses[state, shape, 2, k]
                )
                extent += abs(cosine) * extents[shape, k]
                if k == axis[shape]:
                    along[i] = cosine
            extent += disc[shape] * np.sqrt(max(1.0 - along[i] * along[i], 0.0))
            if abs(local[i]) > extent + box_half[o, i]:
                apart = True
        box_extent = 0.0
        projected = 0.0
        for i in range(3):
            box_extent += abs(along[i]) * box_half[o, i]
            projected += along[i] * local[i]
        if apart or abs(projected) > axis_extent[shape] + box_extent:
            continue
        env_near[row] = True
        if solid[o]:  # an end of the shape's axis inside a solid box: the shape reaches into it for certain
            plus, minus = True, True
            for i in range(3):
                reach_i = along[i] * half_length[shape]
                plus = plus and abs(local[i] - reach_i) < box_half[o, i]
                minus = minus and abs(local[i] + reach_i) < box_half[o, i]
            if plus or minus:
                sure[state] = True
    for row in range(found.shape[0]):
        if sure[found[row, 0]]:
            env_near[row] = False
    pair_near = np.zeros(close_rows.shape[0], dtype=np.bool_)
    p0 = np.zeros(3)
    p1 = np.zeros(3)
    q0 = np.zeros(3)
    q1 = np.zeros(3)
    for row in range(close_rows.shape[0]):
        state, pair = close_rows[row, 0], close_rows[row, 1]
        if sure[state]:
            continue
        a, b = pair_i[pair], pair_j[pair]
        for m in range(3):
            da = poses[state, a, m, axis[a]] * own_half[a]
            db = poses[state, b, m, axis[b]] * own_half[b]
            p0[m], p1[m] = poses[state, a, m, 3] - da, poses[state, a, m, 3] + da
            q0[m], q1[m] = poses[state, b, m, 3] - db, poses[state, b, m, 3] + db
        pair_near[row] = _segment_distance(p0, p1, q0, q1) < reach[pair]
    return sure, env_near, pair_near


def _segment_distance(p0, p1, q0, q1):  # pragma: no cover - compiled
    """:func:`segment_distances` of one pair of segments, in scalars."""
    a = e = b = c = f = 0.0
    for m in range(3):
        d1, d2, r = p1[m] - p0[m], q1[m] - q0[m], p0[m] - q0[m]
        a += d1 * d1
        e += d2 * d2
        b += d1 * d2
        c += d1 * r
        f += d2 * r
    a, e = max(a, _EPS), max(e, _EPS)
    denom = a * e - b * b
    s = (b * f - c * e) / max(denom, _EPS * _EPS) if denom > 1e-9 * a * e else 0.0
    s = min(max(s, 0.0), 1.0)
    t = (b * s + f) / e
    clamped = min(max(t, 0.0), 1.0)
    if t != clamped:
        s = min(max((b * clamped - c) / a, 0.0), 1.0)
    total = 0.0
    for m in range(3):
        gap = (p0[m] - q0[m]) + (p1[m] - p0[m]) * s - (q1[m] - q0[m]) * clamped
        total += gap * gap
    return np.sqrt(total)


def _sphere_candidates(
    centers, box_axes, box_center, box_half, bound, env_checked, pair_i, pair_j, reach2
):  # pragma: no cover - compiled
    n, n_shapes, _ = centers.shape
    n_obj = env_checked.shape[1]
    n_pairs = pair_i.shape[0]
    env = np.empty((max(n * 4, 16), 3), dtype=np.int64)
    k = 0
    pairs = np.empty((max(n * 4, 16), 2), dtype=np.int64)
    p = 0
    for state in range(n):
        for s in range(n_shapes):
            cx, cy, cz = centers[state, s, 0], centers[state, s, 1], centers[state, s, 2]
            for o in range(n_obj):
                if not env_checked[s, o]:
                    continue
                apart = False
                for a in range(3):
                    row = 3 * o + a
                    local = cx * box_axes[row, 0] + cy * box_axes[row, 1] + cz * box_axes[row, 2] - box_center[row]
                    if abs(local) > box_half[row] + bound[s]:
                        apart = True
                        break
                if apart:
                    continue
                if k == env.shape[0]:
                    grown = np.empty((2 * k, 3), dtype=np.int64)
                    grown[:k] = env
                    env = grown
                env[k, 0], env[k, 1], env[k, 2] = state, s, o
                k += 1
        for q in range(n_pairs):
            a, b = pair_i[q], pair_j[q]
            dx = centers[state, a, 0] - centers[state, b, 0]
            dy = centers[state, a, 1] - centers[state, b, 1]
            dz = centers[state, a, 2] - centers[state, b, 2]
            if dx * dx + dy * dy + dz * dz < reach2[q]:
                if p == pairs.shape[0]:
                    grown2 = np.empty((2 * p, 2), dtype=np.int64)
                    grown2[:p] = pairs
                    pairs = grown2
                pairs[p, 0], pairs[p, 1] = state, q
                p += 1
    return env[:k].copy(), pairs[:p].copy()
