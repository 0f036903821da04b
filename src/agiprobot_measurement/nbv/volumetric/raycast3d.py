"""Compiled 3D ray traversal on a dense voxel grid: Amanatides-Woo DDA, frame fusion and pooling (numba kernels).

Grid units: a point ``p`` (m) is at ``g = (p - origin_m) / resolution_m``; voxel ``(i, j, k)`` is the half-open cube
``[i, i + 1) x [j, j + 1) x [k, k + 1)`` and its flat index is ``(i * ny + j) * nz + k`` (C order of an
``(nx, ny, nz)`` array). Rays are clipped to the grid box ``[0, nx] x [0, ny] x [0, nz]`` before traversal, so
nothing outside the region of interest is ever touched. These kernels are the only compiled loops of the voxel map;
``voxel_map.py`` and ``gains.py`` prepare flat arrays for them.
"""

# ruff: noqa: RUF046 -- explicit int() keeps numba's integer typing of math.floor unambiguous
from __future__ import annotations

import math
import os
import types

import numba
import numpy as np

__all__ = [
    "clip_to_box",
    "entropy",
    "evaluate_bundle",
    "evaluate_bundle_serial",
    "expected_surface_bundle",
    "expected_surface_bundle_serial",
    "fuse_frame",
    "fuse_frame_serial",
    "parallel_allowed",
    "threaded_and_serial",
    "traverse",
]

_INF = np.inf


@numba.njit(cache=True)
def clip_to_box(ox, oy, oz, dx, dy, dz, nx, ny, nz, t0, t1):
    """Parameter interval ``[t0, t1]`` of the ray ``o + t d`` (grid units) inside the box ``[0, n]^3``.

    Returns ``(t0, t1)``; the ray misses the box when ``t0 >= t1``.
    """
    o = (ox, oy, oz)
    d = (dx, dy, dz)
    n = (nx, ny, nz)
    for a in range(3):
        if abs(d[a]) < 1e-15:
            if o[a] < 0.0 or o[a] > n[a]:
                return 1.0, 0.0
        else:
            ta = (0.0 - o[a]) / d[a]
            tb = (n[a] - o[a]) / d[a]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
    return t0, t1


@numba.njit(cache=True)
def traverse(ox, oy, oz, dx, dy, dz, t0, t1, nx, ny, nz, stop, use_stop, out_flat, out_t):
    """Amanatides-Woo traversal of ``o + t d`` for ``t`` in ``[t0, t1)`` (already clipped to the box).

    Fills ``out_flat`` with the flat indices of the voxels in the order the ray enters them and ``out_t`` with the
    entry parameter of each; returns how many. A voxel entered exactly at ``t1`` is not listed (so a segment that
    ends on a face does not reach past its end). With ``use_stop`` the walk ends after the first voxel whose
    ``stop`` flag is set (that voxel is listed).
    """
    px = ox + dx * t0
    py = oy + dy * t0
    pz = oz + dz * t0
    ix = min(max(int(math.floor(px)), 0), nx - 1)
    iy = min(max(int(math.floor(py)), 0), ny - 1)
    iz = min(max(int(math.floor(pz)), 0), nz - 1)
    if dx > 0.0:
        sx, tmx, tdx = 1, t0 + (ix + 1 - px) / dx, 1.0 / dx
    elif dx < 0.0:
        sx, tmx, tdx = -1, t0 + (ix - px) / dx, -1.0 / dx
    else:
        sx, tmx, tdx = 0, _INF, _INF
    if dy > 0.0:
        sy, tmy, tdy = 1, t0 + (iy + 1 - py) / dy, 1.0 / dy
    elif dy < 0.0:
        sy, tmy, tdy = -1, t0 + (iy - py) / dy, -1.0 / dy
    else:
        sy, tmy, tdy = 0, _INF, _INF
    if dz > 0.0:
        sz, tmz, tdz = 1, t0 + (iz + 1 - pz) / dz, 1.0 / dz
    elif dz < 0.0:
        sz, tmz, tdz = -1, t0 + (iz - pz) / dz, -1.0 / dz
    else:
        sz, tmz, tdz = 0, _INF, _INF
    capacity = out_flat.shape[0]
    n = 0
    t_enter = t0
    while n < capacity:
        flat = (ix * ny + iy) * nz + iz
        out_flat[n] = flat
        out_t[n] = t_enter
        n += 1
        if use_stop and stop[flat]:
            break
        if tmx <= tmy and tmx <= tmz:
            if tmx >= t1:
                break
            t_enter = tmx
            ix += sx
            if ix < 0 or ix >= nx:
                break
            tmx += tdx
        elif tmy <= tmz:
            if tmy >= t1:
                break
            t_enter = tmy
            iy += sy
            if iy < 0 or iy >= ny:
                break
            tmy += tdy
        else:
            if tmz >= t1:
                break
            t_enter = tmz
            iz += sz
            if iz < 0 or iz >= nz:
                break
            tmz += tdz
    return n


@numba.njit(cache=True)
def _mark_hits(hits, normal_sum, mark, normals, kept, end_flat):
    for i in range(kept.shape[0]):
        if kept[i]:
            f = end_flat[i]
            hits[f] += 1
            normal_sum[f, 0] += normals[i, 0]
            normal_sum[f, 1] += normals[i, 1]
            normal_sum[f, 2] += normals[i, 2]
            mark[f] = 2


@numba.njit(cache=True)
def _carve_rays(start, stop, static, mark, origin_g, points_g, end_flat, nx, ny, nz):
    """Mark free (1) the unmarked, non-static voxels the rays of points ``start:stop`` cross before their end."""
    cap = nx + ny + nz + 3
    buf_flat = np.empty(cap, dtype=np.int64)
    buf_t = np.empty(cap, dtype=np.float64)
    ox, oy, oz = origin_g[0], origin_g[1], origin_g[2]
    for i in range(start, stop):
        dx = points_g[i, 0] - ox
        dy = points_g[i, 1] - oy
        dz = points_g[i, 2] - oz
        t0, t1 = clip_to_box(ox, oy, oz, dx, dy, dz, nx, ny, nz, 0.0, 1.0)
        if t0 >= t1:
            continue
        m = traverse(ox, oy, oz, dx, dy, dz, t0, t1, nx, ny, nz, mark, False, buf_flat, buf_t)
        end = end_flat[i]
        for s in range(m):
            f = buf_flat[s]
            if f != end and mark[f] == 0 and not static[f]:
                mark[f] = 1


@numba.njit(cache=True)
def _apply_marks(start, stop, log_odds, observed, mark, l_hit, l_miss, l_min, l_max):
    """One clamped update per marked voxel of ``start:stop`` (1 miss, 2 hit), marks cleared; (free, hit) counts."""
    n_free = 0
    n_hit = 0
    for f in range(start, stop):
        mk = mark[f]
        if mk == 1:
            v = log_odds[f] + l_miss
            log_odds[f] = v if v > l_min else l_min
            observed[f] = True
            mark[f] = 0
            n_free += 1
        elif mk == 2:
            v = log_odds[f] + l_hit
            log_odds[f] = v if v < l_max else l_max
            observed[f] = True
            mark[f] = 0
            n_hit += 1
    return n_free, n_hit


def _fuse_frame(
    log_odds,
    observed,
    hits,
    normal_sum,
    static,
    mark,
    origin_g,
    points_g,
    normals,
    kept,
    end_flat,
    nx,
    ny,
    nz,
    l_hit,
    l_miss,
    l_min,
    l_max,
    n_threads,
):
    """Fuse one frame into flat grid arrays (OctoMap's computeUpdate: each voxel at most once, hits win).

    ``points_g`` (N, 3) are the frame's valid points in grid units, ``origin_g`` the sensor centre. Every ray carves
    the voxels between the sensor and its point (clipped to the grid), except static voxels and voxels hit in this
    frame. ``kept[i]`` marks points inside the grid and not near static geometry; their voxel ``end_flat[i]`` gets a
    hit (one log-odds update per voxel however many points fall in it), ``hits`` counts the points and
    ``normal_sum`` accumulates their normals. ``mark`` is a zeroed uint8 scratch array of the grid's size and is
    zero again on return. Returns ``(free_updates, hit_updates)``. ``n_threads``: chunks walked in parallel.

    Three passes: mark the hit voxels (2); walk the rays in parallel, marking crossed unmarked voxels free (1; two
    threads writing the same 1 is harmless); then update every marked voxel once and clear the marks.
    """
    _mark_hits(hits, normal_sum, mark, normals, kept, end_flat)
    n_points = points_g.shape[0]
    n_vox = nx * ny * nz
    per = (n_points + n_threads - 1) // n_threads
    for c in numba.prange(n_threads):
        _carve_rays(c * per, min(n_points, (c + 1) * per), static, mark, origin_g, points_g, end_flat, nx, ny, nz)
    per_vox = (n_vox + n_threads - 1) // n_threads
    n_free = 0
    n_hit = 0
    for c in numba.prange(n_threads):
        a, b = _apply_marks(
            c * per_vox, min(n_vox, (c + 1) * per_vox), log_odds, observed, mark, l_hit, l_miss, l_min, l_max
        )
        n_free += a
        n_hit += b
    return n_free, n_hit


def parallel_allowed() -> bool:
    """Whether this process may run the threaded (GNU OpenMP) kernels: not in a child forked from a process that
    imported this module (OpenMP is not fork-safe; numba would terminate the child), e.g. a fork-started process
    pool worker. Such children run the serial variants."""
    return not _FORKED


_FORKED = False


def _after_fork_in_child() -> None:
    global _FORKED
    _FORKED = True


os.register_at_fork(after_in_child=_after_fork_in_child)


def threaded_and_serial(py_func):
    """Compile ``py_func`` (its loop over chunks written with ``numba.prange``) twice: threaded, and serial for the
    processes :func:`parallel_allowed` refuses (numba runs ``prange`` as ``range`` there). Returns ``(threaded,
    serial)``. The serial copy has a name of its own, so numba's on-disk cache keeps the two compilations apart."""
    serial = types.FunctionType(
        py_func.__code__, py_func.__globals__, py_func.__name__ + "_serial", py_func.__defaults__, py_func.__closure__
    )
    serial.__qualname__ = py_func.__qualname__ + "_serial"
    serial.__module__ = py_func.__module__
    serial.__doc__ = f"The serial compilation of :func:`{py_func.__qualname__}` (for a forked child process)."
    return numba.njit(cache=True, parallel=True)(py_func), numba.njit(cache=True)(serial)


fuse_frame, fuse_frame_serial = threaded_and_serial(_fuse_frame)


# metric columns of evaluate_bundle's output (gains.GAIN_NAMES order)
G_OCCLUSION_AWARE = 0
G_UNOBSERVED_VOXEL = 1
G_REAR_SIDE_VOXEL = 2
G_REAR_SIDE_ENTROPY = 3
G_PROXIMITY_COUNT = 4
G_AVERAGE_ENTROPY = 5
G_AREA_FACTOR = 6
G_REPORT = 7
N_GAINS = 8

# voxel states of evaluate_bundle
S_EMPTY = 0
S_UNKNOWN = 1  # observed, still in the unknown band
S_UNOBSERVED = 2  # never updated (p = prior 0.5)
S_FULL = 3  # occupied or static: ends a ray

# flag bits of evaluate_bundle
F_OCCPLANE = 1
F_GROWTH_NEIGHBOUR = 2
F_CANDIDATE = 4
F_GROWTH = 8


def entropy(p: np.ndarray) -> np.ndarray:
    """Binary entropy ``-p ln p - (1 - p) ln(1 - p)`` (nats), 0 at p = 0 and 1."""
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -p * np.log(p) - (1.0 - p) * np.log1p(-p)
    return np.where((p > 0) & (p < 1), h, 0.0)


@numba.njit(cache=True)
def _area_factor(x, alpha):
    """Vasquez-Gomez's piecewise cubic: 0 at x = 0 and 1, maximum 1 at the desired fraction ``alpha``."""
    if x <= alpha:
        return -(2.0 / alpha**3) * x**3 + (3.0 / alpha**2) * x**2
    a = alpha - 1.0
    a3 = a * a * a
    return -(2.0 / a3) * x**3 + ((3.0 * alpha + 3.0) / a3) * x**2 - (6.0 * alpha / a3) * x + (3.0 * alpha - 1.0) / a3


@numba.njit(cache=True)
def _shadow_map(
    pose, proj_offset, proj_rot, proj_dirs, blocked, origin, res, nx, ny, nz, t_max, buf_flat, buf_t, depth
):
    """Depth (m) along each projector ray to the first full voxel (inf when none) for one camera pose."""
    stop = blocked
    r = pose[:3, :3]
    ow = np.empty(3)
    rw = np.empty((3, 3))
    for a in range(3):
        ow[a] = pose[a, 3] + r[a, 0] * proj_offset[0] + r[a, 1] * proj_offset[1] + r[a, 2] * proj_offset[2]
        for b in range(3):
            rw[a, b] = r[a, 0] * proj_rot[0, b] + r[a, 1] * proj_rot[1, b] + r[a, 2] * proj_rot[2, b]
    ogx = (ow[0] - origin[0]) / res
    ogy = (ow[1] - origin[1]) / res
    ogz = (ow[2] - origin[2]) / res
    for j in range(proj_dirs.shape[0]):
        dx = (rw[0, 0] * proj_dirs[j, 0] + rw[0, 1] * proj_dirs[j, 1] + rw[0, 2] * proj_dirs[j, 2]) / res
        dy = (rw[1, 0] * proj_dirs[j, 0] + rw[1, 1] * proj_dirs[j, 1] + rw[1, 2] * proj_dirs[j, 2]) / res
        dz = (rw[2, 0] * proj_dirs[j, 0] + rw[2, 1] * proj_dirs[j, 1] + rw[2, 2] * proj_dirs[j, 2]) / res
        depth[j] = np.inf
        t0, t1 = clip_to_box(ogx, ogy, ogz, dx, dy, dz, nx, ny, nz, 0.0, t_max)
        if t0 >= t1:
            continue
        m = traverse(ogx, ogy, ogz, dx, dy, dz, t0, t1, nx, ny, nz, stop, True, buf_flat, buf_t)
        if m > 0 and stop[buf_flat[m - 1]]:
            depth[j] = buf_t[m - 1]
    return ow, rw


@numba.njit(cache=True)
def _lit(cx, cy, cz, ow, rw, depth, pw, ph, tan_h, tan_v, bias):
    """Whether the voxel (centre c, size ``bias`` m) is lit by the projector: some part of it in the projector's
    frustum and its centre not behind the shadow map's depth (the deepest of the four nearest shadow-map rays, so
    silhouette edges are not shadowed by discretisation), with ``bias`` of slack."""
    vx = cx - ow[0]
    vy = cy - ow[1]
    vz = cz - ow[2]
    qx = rw[0, 0] * vx + rw[1, 0] * vy + rw[2, 0] * vz
    qy = rw[0, 1] * vx + rw[1, 1] * vy + rw[2, 1] * vz
    qz = rw[0, 2] * vx + rw[1, 2] * vy + rw[2, 2] * vz
    if qz <= 0.0:
        return False
    u = (qx / qz / tan_h + 1.0) * 0.5 * pw - 0.5
    v = (qy / qz / tan_v + 1.0) * 0.5 * ph - 0.5
    # a voxel is in the projector's frustum if any part of it may be: widen the image by its half-diagonal
    half = 0.87 * bias / qz
    mu = half / tan_h * 0.5 * pw
    mv = half / tan_v * 0.5 * ph
    if u < -0.5 - mu or v < -0.5 - mv or u > pw - 0.5 + mu or v > ph - 0.5 + mv:
        return False
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    u0 = min(max(int(math.floor(u)), 0), pw - 1)
    v0 = min(max(int(math.floor(v)), 0), ph - 1)
    u1 = min(u0 + 1, pw - 1)
    v1 = min(v0 + 1, ph - 1)
    d = max(max(depth[v0 * pw + u0], depth[v0 * pw + u1]), max(depth[v1 * pw + u0], depth[v1 * pw + u1]))
    return dist <= d + bias


@numba.njit(cache=True)
def _evaluate_chunk(
    c,
    n_chunks,
    gains,
    new_surface,
    visible,
    poses,
    cam_dirs,
    proj_offset,
    proj_rot,
    proj_dirs,
    proj_w,
    proj_h,
    proj_tan_h,
    proj_tan_v,
    state,
    blocked,
    prob,
    entropy,
    flags,
    normals,
    pc_value,
    origin,
    res,
    nx,
    ny,
    nz,
    range_min,
    range_max,
    cos_max_incidence,
    rpg_compat,
    kolmost_weight,
    af_occupied_des,
    af_occplane_des,
):
    """Views ``c, c + n_chunks, ...`` of :func:`evaluate_bundle` (one thread's share), written into the outputs."""
    n_views = poses.shape[0]
    n_rays = cam_dirs.shape[0]
    n_vox = nx * ny * nz
    cap = nx + ny + nz + 3
    bias = res
    stamp = np.zeros(n_vox, dtype=np.int32)
    vflag = np.zeros(n_vox, dtype=np.uint8)
    buf_flat = np.empty(cap, dtype=np.int64)
    buf_t = np.empty(cap, dtype=np.float64)
    depth = np.empty(proj_dirs.shape[0], dtype=np.float64)
    for v in range(c, n_views, n_chunks):
        tag = v + 1
        pose = poses[v]
        ow, rw = _shadow_map(
            pose,
            proj_offset,
            proj_rot,
            proj_dirs,
            blocked,
            origin,
            res,
            nx,
            ny,
            nz,
            4.0 * range_max,
            buf_flat,
            buf_t,
            depth,
        )
        cam = pose[:3, 3]
        zx = pose[0, 2]
        zy = pose[1, 2]
        zz = pose[2, 2]
        ogx = (cam[0] - origin[0]) / res
        ogy = (cam[1] - origin[1]) / res
        ogz = (cam[2] - origin[2]) / res
        oa = 0.0
        uv = 0.0
        rsv = 0.0
        rse = 0.0
        pc = 0.0
        ae_sum = 0.0
        ae_count = 0.0
        af_occ = 0.0
        af_occp = 0.0
        af_unobs = 0.0
        rep = 0.0
        n_new = 0
        n_vis = 0
        for i in range(n_rays):
            d0 = cam_dirs[i, 0]
            d1 = cam_dirs[i, 1]
            d2 = cam_dirs[i, 2]
            wx = pose[0, 0] * d0 + pose[0, 1] * d1 + pose[0, 2] * d2
            wy = pose[1, 0] * d0 + pose[1, 1] * d1 + pose[1, 2] * d2
            wz = pose[2, 0] * d0 + pose[2, 1] * d1 + pose[2, 2] * d2
            if d2 <= 1e-9:
                continue
            t0, t1 = clip_to_box(ogx, ogy, ogz, wx / res, wy / res, wz / res, nx, ny, nz, 0.0, range_max / d2)
            if t0 >= t1:
                continue
            m = traverse(
                ogx, ogy, ogz, wx / res, wy / res, wz / res, t0, t1, nx, ny, nz, blocked, True, buf_flat, buf_t
            )
            p_vis = 1.0
            prev_unknown = False
            ray_ig = 0.0
            ray_ent = 0.0
            ray_cnt = 0.0
            af_registered = False
            af_prev_free = True
            af_no_known = True
            for s in range(m):
                f = buf_flat[s]
                st = state[f]
                p = prob[f]
                h = entropy[f]
                # validity depends on the voxel and the view only: computed on the first visit, then cached
                new = False
                cos_cam = -1.0
                if stamp[f] == tag:
                    valid = vflag[f] != 0
                else:
                    stamp[f] = tag
                    iz = f % nz
                    iy = (f // nz) % ny
                    ix = f // (ny * nz)
                    cx = origin[0] + (ix + 0.5) * res
                    cy = origin[1] + (iy + 0.5) * res
                    cz = origin[2] + (iz + 0.5) * res
                    ex = cam[0] - cx
                    ey = cam[1] - cy
                    ez = cam[2] - cz
                    dep = -(ex * zx + ey * zy + ez * zz)
                    valid = dep >= range_min and dep <= range_max
                    if valid:
                        nxv = normals[f, 0]
                        nyv = normals[f, 1]
                        nzv = normals[f, 2]
                        nn = nxv * nxv + nyv * nyv + nzv * nzv
                        if nn > 0.0:
                            el = math.sqrt(ex * ex + ey * ey + ez * ez)
                            cos_cam = abs(nxv * ex + nyv * ey + nzv * ez) / (el * math.sqrt(nn))
                            px = ow[0] - cx
                            py = ow[1] - cy
                            pz = ow[2] - cz
                            pl = math.sqrt(px * px + py * py + pz * pz)
                            cos_proj = abs(nxv * px + nyv * py + nzv * pz) / (pl * math.sqrt(nn))
                            if cos_cam < cos_max_incidence or cos_proj < cos_max_incidence:
                                valid = False
                    if valid:
                        valid = _lit(cx, cy, cz, ow, rw, depth, proj_w, proj_h, proj_tan_h, proj_tan_v, bias)
                    vflag[f] = 1 if valid else 0
                    new = valid
                unknown = st == S_UNKNOWN or st == S_UNOBSERVED
                if new:
                    n_vis += 1
                    oa += p_vis * h
                    if unknown:
                        uv += p_vis * h
                    if st == S_UNOBSERVED:
                        pc += pc_value[f]
                    if st == S_FULL and prev_unknown:
                        rsv += 1.0
                    fl = flags[f]
                    if fl & F_GROWTH_NEIGHBOUR:
                        n_new += 1
                    if fl & (F_GROWTH_NEIGHBOUR | F_CANDIDATE):
                        if cos_cam >= 0.0:
                            rep += kolmost_weight * cos_cam + 1.0 - kolmost_weight
                        else:
                            rep += 1.0 - kolmost_weight
                if valid:
                    ray_ent += h
                    ray_cnt += 1.0
                    if st == S_FULL:
                        # rear side entropy: the unknown run right before an occupied end voxel, plus the end
                        ray_ig += p_vis * h
                        rse += ray_ig
                        ae_sum += ray_ent
                        ae_count += ray_cnt
                    elif unknown:
                        ray_ig += p_vis * h
                    else:
                        ray_ig = 0.0
                    if not af_registered:
                        if st == S_UNOBSERVED and not (flags[f] & F_OCCPLANE):
                            af_prev_free = af_no_known
                        elif unknown and (flags[f] & F_OCCPLANE):
                            af_occp += 1.0
                            af_registered = True
                        else:
                            af_no_known = False
                            if st == S_FULL:
                                if af_prev_free:
                                    af_occ += 1.0
                                af_registered = True
                            elif unknown:
                                af_prev_free = False
                            else:
                                af_prev_free = True
                elif not unknown:
                    ray_ig = 0.0
                prev_unknown = unknown
                if rpg_compat:
                    p_vis *= p
                else:
                    p_vis *= 1.0 - p
            if not af_registered:
                af_unobs += 1.0
        gains[v, G_OCCLUSION_AWARE] = oa
        gains[v, G_UNOBSERVED_VOXEL] = uv
        gains[v, G_REAR_SIDE_VOXEL] = rsv
        gains[v, G_REAR_SIDE_ENTROPY] = rse
        gains[v, G_PROXIMITY_COUNT] = pc
        gains[v, G_AVERAGE_ENTROPY] = ae_sum / ae_count if ae_count > 0 else 0.0
        total = af_occ + af_occp + af_unobs
        if total > 0:
            gains[v, G_AREA_FACTOR] = _area_factor(af_occ / total, af_occupied_des) + _area_factor(
                af_occp / total, af_occplane_des
            )
        gains[v, G_REPORT] = rep
        new_surface[v] = n_new
        visible[v] = n_vis


def _evaluate_bundle(n_chunks, *scene):
    """All gains of many camera poses by a ray bundle on a dense grid (flat arrays, see ``gains.py``).

    ``poses`` (V, 4, 4) world <- camera (z optical axis); ``cam_dirs`` (R, 3) unit ray directions in the camera
    frame; the projector sits at ``proj_offset`` with rotation ``proj_rot`` in the camera frame and casts
    ``proj_dirs`` (proj_h * proj_w, 3, row-major pinhole grid with half-angle tangents ``proj_tan_h/v``) for its
    shadow map. Camera rays start at the camera, are clipped to the grid and end at the first full voxel or at
    ``range_max`` depth. A voxel *counts* (is valid) when its centre's depth is within ``[range_min, range_max]``,
    the projector lights it (not behind the shadow map) and, if it has a normal, both incidence cosines are at least
    ``cos_max_incidence``. ``blocked`` (uint8) marks the full voxels (state ``S_FULL``), ``entropy`` is
    ``H(prob)`` per voxel. Each voxel contributes once per view to the sum metrics. Visibility along a ray is
    ``prod(1 - p)`` over the voxels before (the paper) or ``prod(p)`` with ``rpg_compat`` (the rpg code).

    ``scene``: the arguments of :func:`_evaluate_chunk` after its outputs, ``poses`` first; ``n_chunks``: the
    threads' shares of the views. Returns ``(gains (V, N_GAINS), new_surface_voxels (V,), visible_voxels (V,))``.
    """
    n_views = scene[0].shape[0]
    gains = np.zeros((n_views, N_GAINS))
    new_surface = np.zeros(n_views, dtype=np.int64)
    visible = np.zeros(n_views, dtype=np.int64)
    for c in numba.prange(n_chunks):
        _evaluate_chunk(c, n_chunks, gains, new_surface, visible, *scene)
    return gains, new_surface, visible


evaluate_bundle, evaluate_bundle_serial = threaded_and_serial(_evaluate_bundle)


@numba.njit(cache=True)
def _expected_chunk(
    c,
    n_chunks,
    gain,
    area,
    poses,
    cam_dirs,
    proj_offset,
    proj_rot,
    proj_dirs,
    proj_w,
    proj_h,
    proj_tan_h,
    proj_tan_v,
    blocked,
    exp_weight,
    exp_normals,
    origin,
    res,
    nx,
    ny,
    nz,
    range_min,
    range_max,
    cos_max_incidence,
    kolmost_weight,
    pitch_rad,
    radius_m,
):
    """Views ``c, c + n_chunks, ...`` of :func:`expected_surface_bundle`."""
    n_views = poses.shape[0]
    n_rays = cam_dirs.shape[0]
    n_vox = nx * ny * nz
    cap = nx + ny + nz + 3
    stamp = np.zeros(n_vox, dtype=np.int32)
    buf_flat = np.empty(cap, dtype=np.int64)
    buf_t = np.empty(cap, dtype=np.float64)
    depth = np.empty(proj_dirs.shape[0], dtype=np.float64)
    for v in range(c, n_views, n_chunks):
        tag = v + 1
        pose = poses[v]
        ow, rw = _shadow_map(
            pose, proj_offset, proj_rot, proj_dirs, blocked, origin, res, nx, ny, nz, 4.0 * range_max, buf_flat,
            buf_t, depth,
        )  # fmt: skip
        cam = pose[:3, 3]
        ogx = (cam[0] - origin[0]) / res
        ogy = (cam[1] - origin[1]) / res
        ogz = (cam[2] - origin[2]) / res
        g = 0.0
        a = 0.0
        for i in range(n_rays):
            d0 = cam_dirs[i, 0]
            d1 = cam_dirs[i, 1]
            d2 = cam_dirs[i, 2]
            if d2 <= 1e-9:
                continue
            wx = pose[0, 0] * d0 + pose[0, 1] * d1 + pose[0, 2] * d2
            wy = pose[1, 0] * d0 + pose[1, 1] * d1 + pose[1, 2] * d2
            wz = pose[2, 0] * d0 + pose[2, 1] * d1 + pose[2, 2] * d2
            t0, t1 = clip_to_box(ogx, ogy, ogz, wx / res, wy / res, wz / res, nx, ny, nz, 0.0, range_max / d2)
            if t0 >= t1:
                continue
            m = traverse(
                ogx, ogy, ogz, wx / res, wy / res, wz / res, t0, t1, nx, ny, nz, blocked, True, buf_flat, buf_t
            )
            for s in range(m):
                f = buf_flat[s]
                w = exp_weight[f]
                if blocked[f] and w <= 0.0:
                    break
                if w <= 0.0:
                    continue
                # the first expected-surface voxel (a full one: its open faces) ends the ray: the predicted surface hides what lies behind it
                if stamp[f] == tag:
                    break
                stamp[f] = tag
                iz = f % nz
                iy = (f // nz) % ny
                ix = f // (ny * nz)
                cx = origin[0] + (ix + 0.5) * res
                cy = origin[1] + (iy + 0.5) * res
                cz = origin[2] + (iz + 0.5) * res
                ex = cam[0] - cx
                ey = cam[1] - cy
                ez = cam[2] - cz
                dep = -(ex * pose[0, 2] + ey * pose[1, 2] + ez * pose[2, 2])
                if dep < range_min or dep > range_max:
                    break
                nxv = exp_normals[f, 0]
                nyv = exp_normals[f, 1]
                nzv = exp_normals[f, 2]
                nn = math.sqrt(nxv * nxv + nyv * nyv + nzv * nzv)
                cos_cam = 1.0
                if nn > 0.0:
                    el = math.sqrt(ex * ex + ey * ey + ez * ez)
                    # the predicted normal points to observed-free space: a view from behind it sees nothing
                    cos_cam = (nxv * ex + nyv * ey + nzv * ez) / (el * nn)
                    px = ow[0] - cx
                    py = ow[1] - cy
                    pz = ow[2] - cz
                    pl = math.sqrt(px * px + py * py + pz * pz)
                    cos_proj = (nxv * px + nyv * py + nzv * pz) / (pl * nn)
                    if cos_cam < cos_max_incidence or cos_proj < cos_max_incidence:
                        break
                if not _lit(cx, cy, cz, ow, rw, depth, proj_w, proj_h, proj_tan_h, proj_tan_v, res):
                    break
                if pitch_rad > 0.0:
                    # the share of the voxel's surface within radius_m of this view's samples, spaced
                    # pitch x distance / cos(incidence) along the tilt
                    spacing = pitch_rad * math.sqrt(ex * ex + ey * ey + ez * ez) / max(cos_cam, 0.05)
                    share = min(1.0, math.pi * radius_m * radius_m / (spacing * spacing))
                    g += w * share
                    a += w * share
                else:
                    g += w * (kolmost_weight * cos_cam + 1.0 - kolmost_weight)
                    a += w
                break
        gain[v] = g
        area[v] = a


def _expected_surface_bundle(n_chunks, *scene):
    """Expected newly seen surface of many camera poses (the predicted-surface model of ``gains.py``).

    ``exp_weight`` (flat float64) is each voxel's expected-surface weight (0: none; the likelihood that the surface
    passes there), ``exp_normals`` (flat, 3) its predicted outward normal. Each camera ray (clipped to the grid, up
    to ``range_max`` depth) ends at the first full voxel or the first expected-surface voxel (a full voxel may be one:
    its open faces); that voxel counts
    once per view when its depth is in range, both incidence cosines (camera and projector, signed: the front side
    of the predicted surface) are at least ``cos_max_incidence`` and the projector lights it. Returns ``(gain (V,),
    voxels (V,))``: the sum of ``weight x (w cos a + 1 - w)`` (Kolmost) and the sum of weights; with ``pitch_rad``
    > 0 both are the sum of ``weight x min(1, pi radius_m^2 / s^2)``, ``s = pitch_rad x distance / cos a`` the
    view's sample spacing there (the share of the surface it measures densely enough). ``scene``: the
    arguments of :func:`_expected_chunk` after its outputs, ``poses`` first; ``n_chunks``: the threads' shares.
    """
    n_views = scene[0].shape[0]
    gain = np.zeros(n_views)
    area = np.zeros(n_views)
    for c in numba.prange(n_chunks):
        _expected_chunk(c, n_chunks, gain, area, *scene)
    return gain, area


expected_surface_bundle, expected_surface_bundle_serial = threaded_and_serial(_expected_surface_bundle)
