"""Synthetic but realistic set-cover instances for tests and benchmarks of :mod:`set_cover`.

The instances imitate the original's cube benchmark (``objectA_wuerfel.stl``, 100 mm cube, 0.03 points/mm^2 =
1,500 samples on the five faces that are not on the table): every candidate view is a straight laser-line scan
anchored above one sample point, at one of ``n_orientations`` orientations around the boresight and one of
``n_tilts`` tilts (1 or 9, the original's "none" and "full"). Which points a view measures follows a
simplified version of the original sensor model (frustum between min and max standoff, fan angle, psi/theta
limits, self-occlusion on the convex part, uncertainty threshold); kinematic failures are imitated by
dropping a random share of the candidates. The matrix therefore has the structure that matters to the
solvers (columns are overlapping patches of a few hundred points, many near-duplicates), without needing a
robot model or a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from agiprobot_measurement.errors import InputError

__all__ = [
    "ALPHA_RAD",
    "FAN_ANGLE_RAD",
    "K_U",
    "MAXIMUM_STANDOFF_MM",
    "MINIMUM_STANDOFF_MM",
    "OPTIMAL_STANDOFF_MM",
    "PSI_MAX_RAD",
    "THETA_MAX_RAD",
    "SetCoverInstance",
    "cube_instance",
    "random_instance",
    "sample_cube_points",
]

# The original scanner (reference/measurement_planning.md), lengths in mm, angles in rad.
OPTIMAL_STANDOFF_MM = 181.82
MINIMUM_STANDOFF_MM = 127.27
MAXIMUM_STANDOFF_MM = 227.27
THETA_MAX_RAD = 0.785398
PSI_MAX_RAD = 0.785398
K_U = 2.63e-6
ALPHA_RAD = 0.39602
FAN_ANGLE_RAD = 0.53669


@dataclass(frozen=True)
class SetCoverInstance:
    """A measurability matrix (points x views, stored values = uncertainty in mm) and per-view durations."""

    matrix: sparse.csc_array
    durations_s: np.ndarray
    points_mm: np.ndarray
    normals: np.ndarray
    description: str

    @property
    def n_points(self) -> int:
        return self.matrix.shape[0]

    @property
    def n_views(self) -> int:
        return self.matrix.shape[1]


def _uncertainty_mm(z, psi):
    xi_0 = np.sin(ALPHA_RAD) * OPTIMAL_STANDOFF_MM
    return K_U * np.sqrt(z * z + xi_0 * xi_0 - 2.0 * z * xi_0 * np.sin(ALPHA_RAD)) / np.cos(psi) * z


def sample_cube_points(
    n_points: int, side_mm: float = 100.0, rng: np.random.Generator | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Uniform samples on the five faces of a cube standing on the table (z = 0 is the table)."""
    rng = np.random.default_rng(0) if rng is None else rng
    half = side_mm / 2.0
    face_normals = np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)
    face = rng.integers(0, 5, n_points)
    uv = rng.uniform(-half, half, (n_points, 2))
    normals = face_normals[face]
    points = np.empty((n_points, 3))
    top = face == 0
    points[top] = np.column_stack([uv[top, 0], uv[top, 1], np.full(top.sum(), side_mm)])
    for f, (axis, other) in ((1, (0, 1)), (2, (0, 1)), (3, (1, 0)), (4, (1, 0))):
        m = face == f
        points[m, axis] = face_normals[f, axis] * half
        points[m, other] = uv[m, 0]
        points[m, 2] = uv[m, 1] + half
    return points, normals


def _view_frames(normals_0, phi, tilt_a, tilt_b):
    """Boresight s, trajectory direction t and lateral l (= s x t) per view."""
    # A tangent per face that is never parallel to its normal: x for the top face, z for the sides.
    ref = np.where(np.abs(normals_0[:, 2:3]) > 0.5, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
    u0 = ref - np.sum(ref * normals_0, axis=1, keepdims=True) * normals_0
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    v0 = np.cross(normals_0, u0)
    t = np.cos(phi)[:, None] * u0 + np.sin(phi)[:, None] * v0
    s0 = -normals_0
    l0 = np.cross(s0, t)
    s = s0 + np.tan(tilt_a)[:, None] * t + np.tan(tilt_b)[:, None] * l0
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    t = t - np.sum(t * s, axis=1, keepdims=True) * s
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return s, t, np.cross(s, t)


def _measure_chunk(points, normals, anchors, s, t, l, length, standoff, u_max):
    """Uncertainty (mm) of every point seen by every view of the chunk; inf where not measurable."""
    e0 = anchors - standoff[:, None] * s  # anchor pose: the anchor point on the boresight
    d = points[None, :, :] - e0[:, None, :]  # (views, points, 3)
    t0 = np.einsum("vpk,vk->vp", d, t)
    ok = np.abs(t0) <= 0.5 * length[:, None]
    v = d - t0[:, :, None] * t[:, None, :]  # from the emitter where it sweeps the point
    z = np.einsum("vpk,vk->vp", v, s)
    y = np.einsum("vpk,vk->vp", v, l)
    ok &= (z > MINIMUM_STANDOFF_MM) & (z < MAXIMUM_STANDOFF_MM)
    ok &= np.abs(y) <= z * np.tan(0.5 * FAN_ANGLE_RAD)
    n_s = normals @ s.T  # (points, views)
    n_t = normals @ t.T
    n_l = normals @ l.T
    psi = np.arctan2(n_t.T, -n_s.T)
    ok &= np.abs(psi) < PSI_MAX_RAD
    # theta: the emitter ray against the normal, both projected on the emitter's y-z plane
    dot = y * n_l.T + z * n_s.T
    norm = np.hypot(y, z) * np.hypot(n_l.T, n_s.T)
    cos_theta = -dot / np.maximum(norm, 1e-12)
    ok &= cos_theta > np.cos(THETA_MAX_RAD)
    # The part is convex: a face point is seen exactly when the emitter and the detector (behind the emitter
    # along x) are both in front of its face.
    ok &= np.einsum("vpk,pk->vp", -v, normals) > 0.0
    detector_back = np.tan(ALPHA_RAD) * OPTIMAL_STANDOFF_MM
    ok &= np.einsum("vpk,pk->vp", -v - detector_back * t[:, None, :], normals) > 0.0
    u = _uncertainty_mm(z, np.where(ok, psi, 0.0)) * np.abs(n_s.T)
    ok &= u < u_max
    return np.where(ok, u, np.inf)


def cube_instance(
    n_points: int = 1500,
    n_orientations: int = 12,
    n_tilts: int = 1,
    valid_fraction: float = 0.5,
    side_mm: float = 100.0,
    tilt_rad: float = 0.35,
    uncertainty_threshold_mm: float = 0.12,
    scan_speed_mm_s: float = 25.0,
    length_mm: tuple[float, float] = (40.0, 80.0),
    standoff_mm: tuple[float, float] = (150.0, 210.0),
    seed: int = 0,
) -> SetCoverInstance:
    """Build an instance with about ``n_points * n_orientations * n_tilts * valid_fraction`` views.

    ``n_tilts`` is 1 (boresight along the anchor's normal) or 9 (a 3 x 3 grid of +-``tilt_rad`` about the
    trajectory and the lateral axis). Views that measure no point are dropped, like the original's invalid
    viewpoints. Durations: trajectory length (40-80 mm by default, as if the kinematic check shortened some) at
    ``scan_speed_mm_s`` plus a random approach/settle time.
    """
    if n_tilts not in (1, 9):
        raise InputError(f"n_tilts must be 1 or 9, got {n_tilts}")
    rng = np.random.default_rng(seed)
    points, normals = sample_cube_points(n_points, side_mm, rng)
    tilts = [(0.0, 0.0)] if n_tilts == 1 else [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    n_t = len(tilts)
    anchor = np.repeat(np.arange(n_points), n_orientations * n_t)
    phi = np.tile(np.repeat(2.0 * np.pi * np.arange(n_orientations) / n_orientations, n_t), n_points)
    tilt_idx = np.tile(np.arange(n_t), n_points * n_orientations)
    ta = np.array([a for a, _ in tilts])[tilt_idx] * tilt_rad
    tb = np.array([b for _, b in tilts])[tilt_idx] * tilt_rad
    keep = rng.random(anchor.size) < valid_fraction
    anchor, phi, ta, tb = anchor[keep], phi[keep], ta[keep], tb[keep]
    length = rng.uniform(*length_mm, anchor.size)
    # The kinematic check does not always reach the optimal standoff: the depth (and so the uncertainty)
    # differs between views.
    standoff = rng.uniform(*standoff_mm, anchor.size)
    s, t, l = _view_frames(normals[anchor], phi, ta, tb)

    # psi and theta below 45 deg need -s.n > 1/sqrt(3): faces no view of a chunk looks at that steeply are
    # skipped, and chunks hold views of one anchor face so that this skips most of the points.
    face_normals, point_face = np.unique(normals, axis=0, return_inverse=True)
    point_face = point_face.ravel()
    order = np.argsort(point_face[anchor], kind="stable")
    rows_list, cols_list, vals_list = [], [], []
    chunk = max(1, 4_000_000 // max(n_points, 1))
    for start in range(0, order.size, chunk):
        vi = order[start : start + chunk]
        faces = np.nonzero(np.any(-s[vi] @ face_normals.T > 0.55, axis=0))[0]
        pts = np.nonzero(np.isin(point_face, faces))[0]
        u = _measure_chunk(
            points[pts],
            normals[pts],
            points[anchor[vi]],
            s[vi],
            t[vi],
            l[vi],
            length[vi],
            standoff[vi],
            uncertainty_threshold_mm,
        )
        v_idx, p_idx = np.nonzero(np.isfinite(u))
        rows_list.append(pts[p_idx])
        cols_list.append(vi[v_idx])
        vals_list.append(u[v_idx, p_idx])
    rows = np.concatenate(rows_list) if rows_list else np.zeros(0, int)
    cols = np.concatenate(cols_list) if cols_list else np.zeros(0, int)
    vals = np.concatenate(vals_list) if vals_list else np.zeros(0)
    matrix = sparse.csc_array((vals, (rows, cols)), shape=(n_points, anchor.size))
    nonempty = np.diff(matrix.indptr) > 0
    matrix = matrix[:, nonempty]
    tilt_penalty = 1.0 + np.hypot(ta, tb)[nonempty]
    durations = length[nonempty] / scan_speed_mm_s + rng.uniform(0.5, 2.5, nonempty.sum()) * tilt_penalty
    return SetCoverInstance(
        matrix=sparse.csc_array(matrix),
        durations_s=durations,
        points_mm=points,
        normals=normals,
        description=(
            f"cube {side_mm:g} mm, {n_points} points, {n_orientations} orientations x {n_tilts} tilts, "
            f"valid {valid_fraction:g}"
        ),
    )


def random_instance(
    n_points: int, n_views: int, density: float = 0.3, seed: int = 0, uncoverable: int = 0
) -> SetCoverInstance:
    """Small unstructured instance (for brute-force checks): each entry measurable with ``density``.

    The last ``uncoverable`` points are measured by no view.
    """
    rng = np.random.default_rng(seed)
    mask = rng.random((n_points, n_views)) < density
    if uncoverable:
        mask[n_points - uncoverable :, :] = False
    values = np.where(mask, rng.uniform(0.01, 0.2, mask.shape), 0.0)
    return SetCoverInstance(
        matrix=sparse.csc_array(values),
        durations_s=rng.uniform(1.0, 10.0, n_views),
        points_mm=np.zeros((n_points, 3)),
        normals=np.zeros((n_points, 3)),
        description=f"random {n_points} x {n_views}, density {density:g}",
    )
