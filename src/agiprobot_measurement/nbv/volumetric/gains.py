"""Information gain of candidate PhoXi views on a :class:`~.voxel_map.VoxelMap`: the seven volumetric metrics of
Isler et al. / Delmerico et al. (``uzh-rpg/rpg_ig_active_reconstruction``) and the report's own, all PhoXi-aware.

Every candidate pose casts a ray bundle (``rays_h x rays_v`` rays over the camera's field of view); all poses are
evaluated in one compiled, parallel call (:func:`.raycast3d.evaluate_bundle`). A ray starts at the camera, is
clipped to the ROI and ends at the first full voxel (its end voxel) or at the maximum scanning depth. A voxel
**counts** only when the structured-light scanner could measure it from that pose: its depth lies in the scanning
range, the projector lights it (it is not behind the projector's shadow map, a second bundle cast from the
projector centre, which is the 3D form of the report's two-ray visibility), and, where the voxel has a normal (fused
or predicted), the incidence at camera and projector is below ``max_incidence_rad``. Voxels are counted once per
view in the sum metrics.

Metrics (``p`` occupancy probability, ``H(p) = -p ln p - (1 - p) ln(1 - p)``, ``v`` visibility: the product of
``1 - p`` over the ray's voxels before this one, as in the paper; ``rpg_compat=True`` uses the rpg code's
``v *= p`` instead, as discussed on that project's issue tracker):

- ``occlusion_aware``: sum of ``v H(p)`` over every counted voxel;
- ``unobserved_voxel``: sum of ``v H(p)`` over counted unknown voxels;
- ``rear_side_voxel``: count of counted full voxels reached directly after an unknown voxel;
- ``rear_side_entropy``: per ray ending in a full voxel, ``v H`` of the unknown run right before it plus its end;
- ``proximity_count``: over counted never-observed voxels, ``max_dist - d`` where ``d`` is the distance to the
  nearest full voxel (``0 < d < max_dist``; ``max_dist`` defaults to 10 grid voxels);
- ``average_entropy``: total entropy / voxel count over the rays that end in a full voxel;
- ``area_factor``: Vasquez-Gomez's area factor of the fractions of rays whose first registered voxel is full
  (desired 0.2) and occlusion plane (desired 0.8);
- ``report``: the report's gain in 3D: growth-neighbour / candidate voxels seen, each weighted by Kolmost
  ``w cos(a) + 1 - w`` (``a`` the angle between the predicted surface normal and the view ray, ``w = 0.5``).

Not reproduced: rpg's "void ray" term (a ray hitting nothing adds the geometric series of unknown entropy); the ROI
bounds the object, so space outside it carries no information here. ``new_surface_area_m2`` is the counted
growth-neighbour voxels (unknown voxels next to the seen surface's open border, where it continues unseen) x
resolution^2: the expected newly seen surface the stopping rule compares with the "maximum size of an ignored
detail". Evaluate on the coarse planning grid (:meth:`VoxelMap.coarse`) for speed.
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass, field
from functools import lru_cache

import numba
import numpy as np
from scipy import ndimage

from agiprobot_measurement.common.config import number, positive
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric import raycast3d as rc
from agiprobot_measurement.nbv.volumetric.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.volumetric.voxel_map import EMPTY, FULL, UNKNOWN, VoxelMap
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW

__all__ = [
    "GAIN_NAMES",
    "UTILITY_METHODS",
    "ExpectedSurfaceModel",
    "ViewGains",
    "ViewModel",
    "camera_ray_directions",
    "evaluate_views",
    "expected_surface",
    "expected_surface_fields",
    "open_faces",
    "predicted_normals",
    "undersampled_surface",
    "utility",
]

UTILITY_METHODS = ("rpg", "exp")
#: Vasquez-Gomez's desired fractions of occupied and occlusion-plane voxels (rpg's defaults)
AREA_FACTOR_OCCUPIED_DESIRED = 0.2
AREA_FACTOR_OCCPLANE_DESIRED = 0.8
#: the angle (deg) within which a measured normal marks a voxel's face seen (:func:`open_faces`; the running per-map
#: evidence is kept at this angle)
FACE_SEEN_ANGLE_DEG = 30.0
#: most rays of one bundle (a full low-resolution PhoXi frame)
MAX_BUNDLE_RAYS = 1032 * 772


@dataclass(frozen=True, eq=False)
class ViewModel:
    """What a view sees: camera field of view (rad, full angles), scanning range (m, depth along the optical axis),
    projector origin in the camera frame (m) and the ray bundle (rays_h x rays_v); incidence limit (rad).

    ``projector_rotation`` (3x3, camera <- projector; default identity), ``projector_fov_h/v_rad`` (default the
    camera's) and ``projector_rays_h/v`` (default the camera bundle's) describe the projector's shadow map.
    """

    fov_h_rad: float
    fov_v_rad: float
    range_min_m: float
    range_max_m: float
    projector_offset_m: np.ndarray
    rays_h: int = 64
    rays_v: int = 48
    max_incidence_rad: float = math.radians(75)
    projector_rotation: np.ndarray | None = None
    projector_fov_h_rad: float | None = None
    projector_fov_v_rad: float | None = None
    projector_rays_h: int | None = None
    projector_rays_v: int | None = None

    def __post_init__(self):
        number(self.fov_h_rad, "fov_h_rad", 0.0, math.pi, low_inclusive=False, high_inclusive=False)
        number(self.fov_v_rad, "fov_v_rad", 0.0, math.pi, low_inclusive=False, high_inclusive=False)
        positive(self.range_min_m, "range_min_m")
        positive(self.range_max_m, "range_max_m")
        if not self.range_min_m < self.range_max_m:
            raise InputError(f"range_min_m {self.range_min_m} must be below range_max_m {self.range_max_m}")
        number(
            self.max_incidence_rad,
            "max_incidence_rad",
            0.0,
            math.pi / 2 + 1e-12,
            low_inclusive=False,
            high_inclusive=False,
        )
        offset = np.asarray(self.projector_offset_m, dtype=float).reshape(-1)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise InputError(f"projector_offset_m must be three finite numbers (m), got {self.projector_offset_m!r}")
        object.__setattr__(self, "projector_offset_m", offset)
        rot = np.eye(3) if self.projector_rotation is None else np.asarray(self.projector_rotation, dtype=float)
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
            raise InputError("projector_rotation must be a 3x3 rotation matrix")
        object.__setattr__(self, "projector_rotation", rot)
        for name, default in (("projector_fov_h_rad", self.fov_h_rad), ("projector_fov_v_rad", self.fov_v_rad)):
            value = default if getattr(self, name) is None else getattr(self, name)
            object.__setattr__(self, name, number(value, name, 0.0, math.pi, low_inclusive=False, high_inclusive=False))
        for name, default in (("projector_rays_h", self.rays_h), ("projector_rays_v", self.rays_v)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)
        for name in ("rays_h", "rays_v", "projector_rays_h", "projector_rays_v"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        if (
            self.rays_h * self.rays_v > MAX_BUNDLE_RAYS
            or self.projector_rays_h * self.projector_rays_v > MAX_BUNDLE_RAYS
        ):
            raise InputError(f"a ray bundle may have at most {MAX_BUNDLE_RAYS} rays")

    @classmethod
    def from_scanner_model(cls, model, rays_h: int = 64, rays_v: int = 48, **overrides) -> ViewModel:
        """The view of a PhoXi :class:`~agiprobot_measurement.sensors.phoxi.models.ScannerModel`: field of view of
        its pinhole intrinsics, scanning range, projector pose (baseline along +x, turned to the sweet spot) and
        projection angles."""
        intr = model.intrinsics(RESOLUTION_LOW)
        proj = model.projector_pose()
        values = {
            "fov_h_rad": 2.0 * math.atan(0.5 * intr.width / intr.fx),
            "fov_v_rad": 2.0 * math.atan(0.5 * intr.height / intr.fy),
            "range_min_m": model.scanning_range_mm[0] / 1000.0,
            "range_max_m": model.scanning_range_mm[1] / 1000.0,
            "projector_offset_m": proj[:3, 3].copy(),
            "rays_h": int(rays_h),
            "rays_v": int(rays_v),
            "projector_rotation": proj[:3, :3].copy(),
            "projector_fov_h_rad": math.radians(model.projector_fov_deg[0]),
            "projector_fov_v_rad": math.radians(model.projector_fov_deg[1]),
        }
        values.update(overrides)
        return cls(**values)


@lru_cache(maxsize=16)
def _pinhole_dirs(fov_h_rad: float, fov_v_rad: float, n_h: int, n_v: int) -> np.ndarray:
    th = math.tan(0.5 * fov_h_rad)
    tv = math.tan(0.5 * fov_v_rad)
    u = ((np.arange(n_h) + 0.5) / n_h * 2.0 - 1.0) * th
    v = ((np.arange(n_v) + 0.5) / n_v * 2.0 - 1.0) * tv
    dirs = np.empty((n_v, n_h, 3))
    dirs[:, :, 0] = u[None, :]
    dirs[:, :, 1] = v[:, None]
    dirs[:, :, 2] = 1.0
    dirs = dirs.reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs.setflags(write=False)
    return dirs


def camera_ray_directions(view: ViewModel) -> np.ndarray:
    """(rays_v * rays_h, 3) unit ray directions in the camera frame (row-major pinhole grid over the fov)."""
    return _pinhole_dirs(view.fov_h_rad, view.fov_v_rad, view.rays_h, view.rays_v)


def _sensor_arguments(poses: np.ndarray, view: ViewModel) -> tuple:
    """The kernels' leading arguments: camera poses (V, 4, 4), camera ray directions, and the projector (offset,
    rotation, shadow-map ray directions, their grid size and half-angle tangents)."""
    return (
        np.ascontiguousarray(poses),
        np.ascontiguousarray(camera_ray_directions(view)),
        view.projector_offset_m,
        np.ascontiguousarray(view.projector_rotation),
        np.ascontiguousarray(
            _pinhole_dirs(
                view.projector_fov_h_rad, view.projector_fov_v_rad, view.projector_rays_h, view.projector_rays_v
            )
        ),
        int(view.projector_rays_h),
        int(view.projector_rays_v),
        math.tan(0.5 * view.projector_fov_h_rad),
        math.tan(0.5 * view.projector_fov_v_rad),
    )


@dataclass
class ViewGains:
    """Gains of V views: ``gain`` (V,) the chosen metric, ``new_surface_area_m2`` (V,) expected newly seen surface
    (m^2), ``visible_voxels`` (V,) counted voxels; ``all_gains`` every metric by name; ``seconds`` wall time."""

    gain: np.ndarray
    new_surface_area_m2: np.ndarray
    visible_voxels: np.ndarray
    all_gains: dict = field(default_factory=dict)
    seconds: float = 0.0


def _gain_fields(grid: VoxelMap, max_dist_m: float):
    """Flat per-voxel inputs of the bundle kernel (cached on the map until it changes)."""

    def compute():
        labels = grid.labels()
        state = np.full(grid.shape, rc.S_UNKNOWN, dtype=np.int8)
        state[labels == EMPTY] = rc.S_EMPTY
        state[(labels == UNKNOWN) & ~grid.observed] = rc.S_UNOBSERVED
        state[labels == FULL] = rc.S_FULL
        blocked = (state == rc.S_FULL).astype(np.uint8)
        flags = np.zeros(grid.shape, dtype=np.uint8)
        flags[grid.occlusion_plane_mask()] |= rc.F_OCCPLANE
        flags[grid.growth_neighbour_mask()] |= rc.F_GROWTH_NEIGHBOUR
        flags[grid.candidate_mask()] |= rc.F_CANDIDATE
        growth = grid.growth_mask()
        flags[growth] |= rc.F_GROWTH
        # normals: fused (sensor-facing) on full voxels, the PCA plane on growth voxels, and on growth neighbours the
        # mean predicted normal of the adjacent growth voxels (where the surface is expected to continue)
        nsum = grid.normal_sum.astype(np.float64)
        length = np.linalg.norm(nsum, axis=-1, keepdims=True)
        normals = np.where(length > 1e-9, nsum / np.maximum(length, 1e-12), 0.0)
        normals[~grid.full_mask()] = 0.0
        gidx = np.argwhere(growth)
        if len(gidx):
            _, gnormals = grid.predicted_surface(gidx)
            field_g = np.zeros((*grid.shape, 3))
            field_g[gidx[:, 0], gidx[:, 1], gidx[:, 2]] = gnormals
            normals[gidx[:, 0], gidx[:, 1], gidx[:, 2]] = gnormals
            spread = np.stack(
                [ndimage.uniform_filter(field_g[..., a], size=3, mode="constant") for a in range(3)], axis=-1
            )
            nb = grid.growth_neighbour_mask()
            slen = np.linalg.norm(spread, axis=-1, keepdims=True)
            spread = np.where(slen > 1e-12, spread / np.maximum(slen, 1e-12), 0.0)
            normals[nb] = spread[nb]
        full = grid.full_mask()
        pc_value = np.zeros(grid.shape, dtype=np.float64)
        if full.any():
            dist = ndimage.distance_transform_edt(~full) * grid.resolution_m
            ok = (state == rc.S_UNOBSERVED) & (dist > 0) & (dist < max_dist_m)
            pc_value[ok] = max_dist_m - dist[ok]
        prob = grid.probability().astype(np.float64).reshape(-1)
        return (
            state.reshape(-1),
            blocked.reshape(-1),
            prob,
            rc.entropy(prob),
            flags.reshape(-1),
            np.ascontiguousarray(normals.reshape(-1, 3)),
            pc_value.reshape(-1),
        )

    return grid._cached(("gain_fields", float(max_dist_m)), compute)


def predicted_normals(grid: VoxelMap) -> np.ndarray:
    """(n_voxels, 3) per flat voxel index: the fused normal on full voxels, the predicted surface's on growth voxels
    and their unknown neighbours, zero elsewhere (the gain kernel's own input, cached on the map)."""
    return _gain_fields(grid, 10.0 * grid.resolution_m)[5]


def evaluate_views(
    grid: VoxelMap,
    camera_poses: np.ndarray,
    view: ViewModel,
    gain: str = "occlusion_aware",
    rpg_compat: bool = False,
    kolmost_weight: float = 0.5,
    proximity_max_dist_m: float | None = None,
) -> ViewGains:
    """Gains of camera poses (V, 4, 4) world <- camera (z = optical axis, m) on ``grid`` (see the module docstring).

    ``gain`` is one of :data:`GAIN_NAMES`; all metrics come back in ``all_gains`` anyway (one traversal computes
    them all). ``kolmost_weight`` is the report's ``w`` in ``w cos(a) + 1 - w``.
    """
    start = time.perf_counter()
    if gain not in GAIN_NAMES:
        raise InputError(f"unknown gain {gain!r}; known: {', '.join(GAIN_NAMES)}")
    if not isinstance(grid, VoxelMap):
        raise InputError(f"grid must be a VoxelMap, got {type(grid).__name__}")
    if not isinstance(view, ViewModel):
        raise InputError(f"view must be a ViewModel, got {type(view).__name__}")
    try:
        poses = np.asarray(camera_poses, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("camera_poses must be a (V, 4, 4) array") from None
    if poses.ndim == 2 and poses.shape == (4, 4):
        poses = poses[None]
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise InputError(f"camera_poses must be (V, 4, 4), got shape {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError("camera_poses contain NaN or infinite values")
    w = float(kolmost_weight)
    if not 0.0 <= w <= 1.0:
        raise InputError(f"kolmost_weight must be in [0, 1], got {kolmost_weight!r}")
    max_dist = 10.0 * grid.resolution_m if proximity_max_dist_m is None else float(proximity_max_dist_m)
    positive(max_dist, "proximity_max_dist_m")
    n_views = len(poses)
    if n_views == 0:
        empty = np.zeros(0)
        return ViewGains(empty, empty.copy(), np.zeros(0, dtype=np.int64), {name: empty.copy() for name in GAIN_NAMES})
    state, blocked, prob, ent, flags, normals, pc_value = _gain_fields(grid, max_dist)
    nx, ny, nz = grid.shape
    parallel = rc.parallel_allowed()
    n_chunks = max(1, min(numba.get_num_threads(), n_views)) if parallel else 1
    kernel = rc.evaluate_bundle if parallel else rc.evaluate_bundle_serial
    gains, new_vox, visible = kernel(
        n_chunks,
        *_sensor_arguments(poses, view),
        state,
        blocked,
        prob,
        ent,
        flags,
        normals,
        pc_value,
        grid.origin_m.astype(np.float64),
        float(grid.resolution_m),
        nx,
        ny,
        nz,
        float(view.range_min_m),
        float(view.range_max_m),
        math.cos(view.max_incidence_rad),
        bool(rpg_compat),
        w,
        AREA_FACTOR_OCCUPIED_DESIRED,
        AREA_FACTOR_OCCPLANE_DESIRED,
    )
    all_gains = {name: gains[:, i].copy() for i, name in enumerate(GAIN_NAMES)}
    return ViewGains(
        gain=all_gains[gain],
        new_surface_area_m2=new_vox.astype(np.float64) * grid.resolution_m**2,
        visible_voxels=visible,
        all_gains=all_gains,
        seconds=time.perf_counter() - start,
    )


def utility(gain, cost_s, method: str = "rpg", cost_weight: float = 0.0) -> np.ndarray:
    """Utility of V views from gains (V,) and motion costs (V,) in s.

    ``"rpg"``: ``G / sum(G) - w C / sum(C)`` (rpg's weighted linear utility; a zero sum makes its share 0);
    ``"exp"``: ``G exp(-w C)`` (mav_active_3d_planning's exponential discount, ``w`` in 1/s).
    """
    if method not in UTILITY_METHODS:
        raise InputError(f"unknown utility method {method!r}; known: {', '.join(UTILITY_METHODS)}")
    g = np.asarray(gain, dtype=float).reshape(-1)
    c = np.asarray(cost_s, dtype=float).reshape(-1)
    if g.shape != c.shape:
        raise InputError(f"gain ({g.shape[0]}) and cost_s ({c.shape[0]}) need one value per view")
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(c))):
        raise InputError("gain and cost_s must be finite")
    if np.any(c < 0):
        raise InputError("cost_s must be >= 0")
    w = float(cost_weight)
    if not math.isfinite(w) or w < 0:
        raise InputError(f"cost_weight must be >= 0, got {cost_weight!r}")
    if method == "exp":
        return g * np.exp(-w * c)
    g_sum = g.sum()
    c_sum = c.sum()
    share_g = g / g_sum if g_sum != 0 else np.zeros_like(g)
    share_c = c / c_sum if c_sum != 0 else np.zeros_like(c)
    return share_g - w * share_c


@dataclass(frozen=True)
class ExpectedSurfaceModel:
    """Where the unseen surface is expected (the predicted-surface model of :func:`expected_surface`).

    ``plane_radius_vox``: how far (grid voxels, Chebyshev) the PCA plane of a growth voxel is extrapolated into
    unknown space; ``occlusion_max_dist_m``: occlusion-plane voxels (unknown next to observed-free space) within this
    distance of the observed surface are expected surface too, with a weight falling linearly from
    ``occlusion_weight`` at the surface to 0 at that distance; ``kolmost_weight``: the report's ``w``; voxels with a
    measured point within ``seen_radius_fraction`` x resolution of their centre expect nothing (already seen).
    ``open_face_angle_deg``: a full voxel's face towards observed-free space, turned away from its seen surface, is
    an **open face** (seen surface whose side there was never measured: the rim of a plate thinner than a voxel, a
    sharp edge's second face) while no point measured in the voxel has its normal within this angle of the face's
    direction (:func:`open_faces`; 0: no open faces).
    """

    plane_radius_vox: int = 2
    occlusion_max_dist_m: float = 0.03
    occlusion_weight: float = 0.5
    kolmost_weight: float = 0.5
    seen_radius_fraction: float = 0.6
    open_face_angle_deg: float = FACE_SEEN_ANGLE_DEG

    def __post_init__(self):
        if not isinstance(self.plane_radius_vox, (int, np.integer)) or not 0 <= self.plane_radius_vox <= 5:
            raise InputError(f"plane_radius_vox must be an integer in [0, 5], got {self.plane_radius_vox!r}")
        if not math.isfinite(float(self.occlusion_max_dist_m)) or self.occlusion_max_dist_m < 0:
            raise InputError(f"occlusion_max_dist_m must be >= 0 (m), got {self.occlusion_max_dist_m!r}")
        if not 0.0 <= float(self.occlusion_weight) <= 1.0:
            raise InputError(f"occlusion_weight must be in [0, 1], got {self.occlusion_weight!r}")
        if not 0.0 <= float(self.kolmost_weight) <= 1.0:
            raise InputError(f"kolmost_weight must be in [0, 1], got {self.kolmost_weight!r}")
        if not 0.0 <= float(self.seen_radius_fraction) <= 2.0:
            raise InputError(f"seen_radius_fraction must be in [0, 2], got {self.seen_radius_fraction!r}")
        if not 0.0 <= float(self.open_face_angle_deg) <= 45.0:
            raise InputError(f"open_face_angle_deg must be in [0, 45], got {self.open_face_angle_deg!r}")

    @classmethod
    def from_config(cls, values: dict | None) -> ExpectedSurfaceModel:
        values = dict(values or {})
        known = {
            "plane_radius_vox",
            "occlusion_max_dist_m",
            "occlusion_weight",
            "kolmost_weight",
            "seen_radius_fraction",
            "open_face_angle_deg",
        }
        unknown = sorted(set(values) - known)
        if unknown:
            raise InputError(f"expected_surface: unknown key(s) {unknown}; known: {sorted(known)}")
        if "plane_radius_vox" in values:
            values["plane_radius_vox"] = int(values["plane_radius_vox"])
        return cls(**values)


def _dilate_static(static: np.ndarray) -> np.ndarray:
    return ndimage.binary_dilation(static, np.ones((3, 3, 3), dtype=bool)) if static.any() else static


def _seen_near(grid: VoxelMap, mask: np.ndarray, radius_m: float) -> np.ndarray:
    """Voxels of ``mask`` with a raw point within ``radius_m`` of their centre."""
    from scipy.spatial import cKDTree

    out = np.zeros(grid.shape, dtype=bool)
    xyz = grid.raw.xyz_m
    if radius_m <= 0 or not len(xyz) or not mask.any():
        return out
    # one point per 1 mm cell is enough for a radius of millimetres
    cells = np.unique(np.floor(xyz / 0.001).astype(np.int64), axis=0)
    tree = cKDTree((cells + 0.5) * 0.001)
    idx = np.argwhere(mask)
    dist, _ = tree.query(grid.index_to_world(idx), k=1, distance_upper_bound=radius_m + 0.001)
    seen = idx[np.isfinite(dist) & (dist <= radius_m)]
    out[tuple(seen.T)] = True
    return out


#: a voxel's face more than this far from the voxel's mean measured normal may be an unseen side (:func:`open_faces`)
OPEN_FACE_SURFACE_ANGLE_DEG = 60.0
#: per map: (raw points taken in, seen flags (6 x voxels), summed normals (voxels, 3)), updated with new points only
_FACE_EVIDENCE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: the six axis directions of a voxel's faces
FACE_DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.int64)


def _face_points(grid: VoxelMap, xyz: np.ndarray, normal: np.ndarray, angle_deg: float):
    """(flat voxel index, face index into :data:`FACE_DIRECTIONS`) of the points whose normal lies within
    ``angle_deg`` (<= 45: at most one face) of a face's direction, each in its voxel and in the voxel half a voxel
    behind it (a face on a voxel boundary); and (flat index, normal) of every point inside the grid."""
    axis = np.argmax(np.abs(normal), axis=1)
    component = normal[np.arange(len(normal)), axis]
    face = 2 * axis + (component < 0)
    facing = np.abs(component) >= math.cos(math.radians(min(angle_deg, 45.0)))
    out = []
    for shift in (0.0, 0.5 * grid.resolution_m):
        idx = grid.world_to_index(xyz[facing] - shift * normal[facing])
        ok = grid.in_grid(idx)
        out.append((grid.flat_index(idx[ok]), face[facing][ok]))
    idx = grid.world_to_index(xyz)
    ok = grid.in_grid(idx)
    return out, (grid.flat_index(idx[ok]), normal[ok])


def _face_evidence(grid: VoxelMap) -> tuple[np.ndarray, np.ndarray]:
    """(seen flags (6 x voxels) at :data:`FACE_SEEN_ANGLE_DEG`, summed normals (voxels, 3)) of the map's raw points,
    kept per map and updated with the points added since (the raw points only grow)."""
    n_vox = grid.n_voxels
    done, seen, total = _FACE_EVIDENCE.get(grid, (0, None, None))
    if seen is None or len(grid.raw) < done or len(seen) != 6 * n_vox:
        done, seen, total = 0, np.zeros(6 * n_vox, dtype=bool), np.zeros((n_vox, 3))
    if len(grid.raw) > done:
        xyz = np.asarray(grid.raw.xyz_m[done:], dtype=np.float64)
        normal = np.asarray(grid.raw.normal[done:], dtype=np.float64)
        facing, (flat, n) = _face_points(grid, xyz, normal, FACE_SEEN_ANGLE_DEG)
        for f, face in facing:
            seen[face * n_vox + f] = True
        for a in range(3):
            total[:, a] += np.bincount(flat, weights=n[:, a], minlength=n_vox)
        done = len(grid.raw)
    _FACE_EVIDENCE[grid] = (done, seen, total)
    return seen, total


def _seen_faces(grid: VoxelMap, angle_deg: float) -> np.ndarray:
    """Seen flags (6, *grid shape) at another angle than the running evidence's, from all raw points."""
    xyz = np.asarray(grid.raw.xyz_m, dtype=np.float64)
    facing, _ = _face_points(grid, xyz, np.asarray(grid.raw.normal, dtype=np.float64), angle_deg)
    seen = np.zeros(6 * grid.n_voxels, dtype=bool)
    for f, face in facing:
        seen[face * grid.n_voxels + f] = True
    return seen.reshape(6, *grid.shape)


def open_faces(
    grid: VoxelMap, seen_angle_deg: float, surface_angle_deg: float = OPEN_FACE_SURFACE_ANGLE_DEG
) -> tuple[np.ndarray, np.ndarray]:
    """Open faces of the seen surface: (count per voxel (grid shape, float64), their mean outward direction
    (grid shape + (3,))). A face of a full voxel with measured points is open when

    - its 6-neighbour is observed free (not the static scene), or unknown right above the static scene with the
      face turned sideways (within ``surface_angle_deg`` of the perpendicular to the mean normal),
    - the face turns away from the voxel's seen surface: its direction is more than ``surface_angle_deg`` from the
      voxel's mean measured normal (a staircase face of a sloped surface is not a new side), and
    - no point measured in the voxel (or half a voxel behind it along its normal, for a face on a voxel boundary)
      has its normal within ``seen_angle_deg`` (at most 45) of the face's direction.

    That is the seen surface turning to a side no view has measured: the rim of a plate thinner than a voxel, which
    no frontier voxel marks (the space around it is already known to be free), or a sharp edge's second face."""
    shape = grid.shape
    count = np.zeros(shape, dtype=np.float64)
    direction = np.zeros((*shape, 3), dtype=np.float64)
    xyz = grid.raw.xyz_m
    if seen_angle_deg <= 0 or not len(xyz):
        return count, direction
    seen, mean = _face_evidence(grid)
    length = np.linalg.norm(mean, axis=1)
    with_points = (length > 1e-9).reshape(shape)
    mean = (mean / np.maximum(length, 1e-12)[:, None]).reshape(*shape, 3)
    seen = seen.reshape(6, *shape) if seen_angle_deg == FACE_SEEN_ANGLE_DEG else _seen_faces(grid, seen_angle_deg)
    full = grid.full_mask() & with_points
    free = grid.empty_mask() & ~grid.static
    # the air right above the static scene stays unknown however often it is seen (its points are masked out): a
    # face there counts when it turns sideways (not into the part, as a face of its unseen inside would)
    above_static = grid.unknown_mask() & _dilate_static(grid.static)
    cos_surface = math.cos(math.radians(surface_angle_deg))
    for k, d in enumerate(FACE_DIRECTIONS):
        a = int(np.flatnonzero(d)[0])
        src = tuple(slice(max(0, -j), shape[i] - max(0, j)) for i, j in enumerate(d))
        dst = tuple(slice(max(0, j), shape[i] - max(0, -j)) for i, j in enumerate(d))
        neighbour_free = np.zeros(shape, dtype=bool)
        neighbour_free[src] = free[dst]
        neighbour_static = np.zeros(shape, dtype=bool)
        neighbour_static[src] = above_static[dst]
        towards = mean[..., a] * d[a]
        is_open = neighbour_free | (neighbour_static & (towards > -cos_surface))
        is_open &= full & ~seen[k] & (towards < cos_surface)
        count[is_open] += 1.0
        direction[is_open, a] += d[a]
    length = np.linalg.norm(direction, axis=-1, keepdims=True)
    direction = np.where(length > 1e-9, direction / np.maximum(length, 1e-12), 0.0)
    return count, direction


def expected_surface_fields(grid: VoxelMap, model: ExpectedSurfaceModel = ExpectedSurfaceModel()):
    """Per-voxel expected-surface weight (flat float64, 0 = none) and predicted outward normal (flat, 3).

    The unseen surface is expected where the seen one continues, never in the unknown interior behind it:

    - frontier (candidate) voxels -- unknown, next to observed-free space and to a growth voxel -- weight 1, normal
      the mean PCA normal of the adjacent growth voxels;
    - unknown voxels the PCA plane of a growth voxel crosses within ``plane_radius_vox`` of it (the predicted
      surface extrapolated over the open border), weight 1, that plane's normal;
    - occlusion-plane voxels (unknown next to observed-free space) within ``occlusion_max_dist_m`` of the observed
      surface, weight ``occlusion_weight x (1 - d / max)``, normal towards the free space (the gradient of the
      smoothed free-space indicator).

    - full voxels with open faces (:func:`open_faces`), weight the number of open faces, normal their mean
      direction; the expected-surface ray cast counts such a voxel where its ray ends.

    Unknown voxels with no free neighbour and off every predicted plane (a part's inside) weigh 0.
    """

    def compute():
        shape = grid.shape
        unknown = grid.unknown_mask()
        empty = grid.empty_mask()
        full = grid.full_mask()
        weight = np.zeros(shape, dtype=np.float64)
        normals = np.zeros((*shape, 3), dtype=np.float64)
        occplane = grid.occlusion_plane_mask()
        # next to the static scene (the fixture's top) nothing is expected: its points are masked out of the map,
        # so the air right above it stays unknown however often it is seen
        near_static = _dilate_static(grid.static)
        # occlusion plane near the observed surface: the surface is likely behind the free space's border
        free_grad = np.stack(np.gradient(ndimage.gaussian_filter(empty.astype(np.float64), 1.0)), axis=-1)
        glen = np.linalg.norm(free_grad, axis=-1, keepdims=True)
        free_normal = np.where(glen > 1e-9, free_grad / np.maximum(glen, 1e-12), 0.0)
        if full.any() and model.occlusion_max_dist_m > 0 and model.occlusion_weight > 0:
            occ = occplane
            dist = ndimage.distance_transform_edt(~full) * grid.resolution_m
            near = occ & (dist < model.occlusion_max_dist_m)
            weight[near] = model.occlusion_weight * (1.0 - dist[near] / model.occlusion_max_dist_m)
            normals[near] = free_normal[near]
        gidx = grid.growth_voxels()
        if len(gidx):
            centroids, gnormals = grid.predicted_surface(gidx)
            # frontier voxels: the mean predicted normal of the adjacent growth voxels
            field_g = np.zeros((*shape, 3))
            field_g[tuple(gidx.T)] = gnormals
            spread = np.stack(
                [ndimage.uniform_filter(field_g[..., a], size=3, mode="constant") for a in range(3)], axis=-1
            )
            slen = np.linalg.norm(spread, axis=-1, keepdims=True)
            spread = np.where(slen > 1e-12, spread / np.maximum(slen, 1e-12), free_normal)
            cand = grid.candidate_mask()
            weight[cand] = 1.0
            normals[cand] = spread[cand]
            # the PCA planes extrapolated over the open border into unknown space
            r = int(model.plane_radius_vox)
            ok_n = np.linalg.norm(gnormals, axis=1) > 0.5
            if r > 0 and ok_n.any():
                g, c, n = gidx[ok_n], centroids[ok_n], gnormals[ok_n]
                ax = np.arange(-r, r + 1)
                offsets = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
                vox = g[:, None, :] + offsets[None, :, :]  # (K, O, 3)
                inside = np.all((vox >= 0) & (vox < np.asarray(shape)), axis=-1)
                vox_c = np.where(inside[..., None], vox, 0)
                is_unknown = unknown[vox_c[..., 0], vox_c[..., 1], vox_c[..., 2]] & inside
                centres = grid.origin_m + (vox_c + 0.5) * grid.resolution_m
                off_plane = np.abs(np.einsum("koj,kj->ko", centres - c[:, None, :], n))
                half = 0.5 * grid.resolution_m * np.abs(n).sum(axis=1)
                hit = is_unknown & (off_plane <= half[:, None])
                # only on the free space's border: a plane through a voxel layer's boundary also crosses the layer
                # behind the seen face (the part's inside), which no view can measure
                hit &= occplane[vox_c[..., 0], vox_c[..., 1], vox_c[..., 2]]
                k, o = np.nonzero(hit)
                if len(k):
                    cells = vox[k, o]
                    flat = np.ravel_multi_index(tuple(cells.T), shape)
                    acc = np.zeros((int(np.prod(shape)), 3))
                    np.add.at(acc, flat, n[k])
                    uniq = np.unique(flat)
                    acc_u = acc[uniq]
                    alen = np.linalg.norm(acc_u, axis=1, keepdims=True)
                    good = alen[:, 0] > 1e-9
                    uniq, acc_u = uniq[good], acc_u[good] / alen[good]
                    wflat = weight.reshape(-1)
                    nflat = normals.reshape(-1, 3)
                    plane_only = wflat[uniq] < 1.0
                    wflat[uniq] = 1.0
                    nflat[uniq[plane_only]] = acc_u[plane_only]
        weight[near_static] = 0.0
        # where points were already measured the surface is seen, whatever the voxel's label says (a hit followed
        # by a grazing miss leaves a surface voxel unknown, and a face on a voxel-layer boundary leaves holes of
        # unknown voxels under free ones): nothing new is expected there
        weight[_seen_near(grid, weight > 0, model.seen_radius_fraction * grid.resolution_m)] = 0.0
        faces, face_normals = open_faces(grid, float(model.open_face_angle_deg))
        has_faces = faces > 0
        weight[has_faces] = faces[has_faces]
        normals[has_faces] = face_normals[has_faces]
        return weight.reshape(-1), np.ascontiguousarray(normals.reshape(-1, 3))

    key = ("expected_fields", model)
    return grid._cached(key, compute)


def _finite_poses(camera_poses) -> np.ndarray:
    """Camera poses as a finite float (V, 4, 4) array (one (4, 4) pose becomes V = 1); InputError otherwise."""
    poses = np.asarray(camera_poses, dtype=np.float64)
    if poses.shape == (4, 4):
        poses = poses[None]
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.all(np.isfinite(poses)):
        raise InputError(f"camera_poses must be a finite (V, 4, 4) array, got shape {poses.shape}")
    return poses


def expected_surface(
    grid: VoxelMap, camera_poses: np.ndarray, view: ViewModel, model: ExpectedSurfaceModel = ExpectedSurfaceModel()
) -> tuple[np.ndarray, np.ndarray]:
    """Expected newly seen surface of camera poses (V, 4, 4) world <- camera: ``(gain (V,), area_m2 (V,))``.

    The predicted-surface model (:func:`expected_surface_fields`): each camera ray ends at the first full or
    expected-surface voxel; an expected-surface voxel counts once per view when the structured-light scanner could
    measure it there (depth in range, camera and projector on its front side within ``max_incidence_rad``, lit by
    the projector). ``area_m2`` is the sum of the weights of the counted voxels x resolution^2; ``gain`` weighs each
    by Kolmost ``w cos a + 1 - w`` as well.
    """
    if not isinstance(grid, VoxelMap):
        raise InputError(f"grid must be a VoxelMap, got {type(grid).__name__}")
    if not isinstance(view, ViewModel):
        raise InputError(f"view must be a ViewModel, got {type(view).__name__}")
    poses = _finite_poses(camera_poses)
    if len(poses) == 0:
        return np.zeros(0), np.zeros(0)
    weight, normals = expected_surface_fields(grid, model)
    return _surface_bundle(grid, poses, view, weight, normals, float(model.kolmost_weight), 0.0, 0.0)


def undersampled_surface(
    grid: VoxelMap,
    camera_poses: np.ndarray,
    view: ViewModel,
    weight: np.ndarray,
    pitch_rad: float,
    radius_m: float,
    normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Expected newly *densely* measured seen surface of camera poses (V, 4, 4): ``(gain (V,), area_m2 (V,))``,
    both the sum over the full voxels a view measures (the ray's first full voxel, in range, lit, both incidences
    within ``max_incidence_rad`` of the fused normal) of ``weight x min(1, pi radius_m^2 / s^2)``: ``weight`` (flat,
    per planning voxel) the share of its surface no fused point lies within ``radius_m`` of (see
    :mod:`.sampling`), ``s = pitch_rad x distance / cos(incidence)`` the view's sample spacing there (m).
    ``normals`` (flat, 3): the directions the incidence is taken to (None: the fused normals)."""
    poses = _finite_poses(camera_poses)
    weight = np.ascontiguousarray(weight, dtype=np.float64).reshape(-1)
    if weight.shape != (grid.n_voxels,):
        raise InputError(f"weight must have one value per planning voxel ({grid.n_voxels}), got {weight.shape}")
    if len(poses) == 0 or not pitch_rad > 0 or not np.any(weight > 0):
        return np.zeros(len(poses)), np.zeros(len(poses))
    normals = predicted_normals(grid) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    return _surface_bundle(grid, poses, view, weight, normals, 0.0, float(pitch_rad), float(radius_m))


def _surface_bundle(grid, poses, view, weight, normals, kolmost_weight, pitch_rad, radius_m):
    """The predicted-surface ray cast (:func:`.raycast3d.expected_surface_bundle`) of ``poses`` over per-voxel
    ``weight`` and ``normals``: (gain (V,), area (V,) m^2)."""
    blocked = (grid.labels() == FULL).reshape(-1).astype(np.uint8)
    nx, ny, nz = grid.shape
    parallel = rc.parallel_allowed()
    n_chunks = max(1, min(numba.get_num_threads(), len(poses))) if parallel else 1
    kernel = rc.expected_surface_bundle if parallel else rc.expected_surface_bundle_serial
    gain, vox = kernel(
        n_chunks,
        *_sensor_arguments(poses, view),
        blocked,
        weight,
        normals,
        grid.origin_m.astype(np.float64),
        float(grid.resolution_m),
        nx,
        ny,
        nz,
        float(view.range_min_m),
        float(view.range_max_m),
        math.cos(view.max_incidence_rad),
        float(kolmost_weight),
        float(pitch_rad),
        float(radius_m),
    )
    return gain, vox * grid.resolution_m**2
