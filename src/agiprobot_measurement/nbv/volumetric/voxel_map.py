"""Probabilistic dense voxel map over the object's region of interest (ROI), fused from PhoXi frames.

The map is OctoMap's sensor model on a dense grid: per voxel a clamped log-odds ``L``; a frame adds ``logit(prob_hit)``
to the voxel of every valid point and ``logit(prob_miss)`` to every voxel a valid point's ray crosses before it,
each voxel at most once per frame with hits winning (OctoMap's ``computeUpdate``), clamped to
``[logit(clamp_min), logit(clamp_max)]``. Rays are clipped to the ROI (the a-priori box the object lies in) and are
traversed by a compiled Amanatides-Woo DDA (:mod:`.raycast3d`). Only valid pixels are fused, so nothing is carved
along a pixel the scanner did not measure: a missing PhoXi pixel may be a projector shadow on real surface.

Static scene geometry (table, fixture: the a-priori known scene) is rasterised once (:meth:`VoxelMap.set_static`);
its voxels are full and never updated, and points within ``static_margin_m`` of it are dropped.

Labels (the report's values): -1 empty (``p < free_below``), 1 full (``p > occupied_above``, static included), 0
unknown otherwise (never observed voxels have ``p = 0.5``). With the OctoMap sensor model (hit 0.7, miss 0.4) one
frame moves a voxel to ``p = 0.7`` or ``0.4``; the default band ``[0.45, 0.65]`` (SCVP's) therefore labels a voxel
after one consistent observation. rpg's band ``[0.2, 0.8]`` needs two hits or four misses; it is a configuration.

The report's terms in 3D (26-neighbourhoods): *growth* voxels are full (not static) voxels with an unknown
neighbour; *candidates* are unknown voxels next to an empty and a growth voxel; the *occlusion plane* is the unknown
voxels next to an empty one; the *predicted surface* at a voxel is the PCA plane of the raw points around it.

Every kept raw point is stored with its view id, normal and inaccuracy sigma (:class:`~.map_parts.RawPoints`), the report's
per-cell point lists: output accuracy does not depend on the voxel size. Arrays are indexed ``(x, y, z)``; voxel
``(i, j, k)`` spans ``origin_m + [i, i + 1) * resolution_m`` (and likewise in y, z). Units: metres, mm where named.
"""

from __future__ import annotations

import io
import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numba
import numpy as np
from scipy import ndimage

from agiprobot_measurement.common.config import positive, vector
from agiprobot_measurement.common.files import atomic_write, atomic_write_bytes
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.errors import MapWriteError
from agiprobot_measurement.nbv.volumetric.map_parts import RawPoints, surface_samples_in_box
from agiprobot_measurement.nbv.volumetric.pooling import pool_max, pool_sum
from agiprobot_measurement.nbv.volumetric.raycast3d import (
    fuse_frame,
    fuse_frame_serial,
    parallel_allowed,
)
from agiprobot_measurement.sensors.phoxi.point_cloud_io import write_ply

__all__ = [
    "EMPTY",
    "FULL",
    "MAP_FORMAT_VERSION",
    "UNKNOWN",
    "MapConfig",
    "VoxelMap",
    "logit",
]

EMPTY = -1
UNKNOWN = 0
FULL = 1
MAP_FORMAT_VERSION = 1
#: bytes of memory one voxel costs (log-odds 4, observed 1, static 1, near-static 1, hit count 4, normal sum 12, scratch 1)
BYTES_PER_VOXEL = 24

_NEIGHBOURS_26 = np.array(
    [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], dtype=np.int64
)

_NEIGHBOURS_27 = np.vstack([np.zeros((1, 3), dtype=np.int64), _NEIGHBOURS_26])


def logit(p: float) -> float:
    """Log-odds ``ln(p / (1 - p))`` of a probability in (0, 1)."""
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class MapConfig:
    """Voxel map parameters: resolutions (m), OctoMap sensor model and clamping (probabilities), label band.

    ``resolution_m`` is the output / coverage grid, ``planning_resolution_m`` the coarse grid :meth:`VoxelMap.coarse`
    returns for candidates and gains. ``free_below`` / ``occupied_above`` bound the unknown band (see the module
    docstring for why the default is SCVP's ``[0.45, 0.65]`` and not rpg's ``[0.2, 0.8]``). Points closer than
    ``static_margin_m`` to static geometry are dropped: a point in a static voxel, or in the band of
    ``ceil(margin / resolution)`` voxels (Chebyshev) around them whose distance to the static mesh along one of
    the six axis directions is below the margin (so a part thinner than a voxel that lies on the fixture keeps its
    points: a 4 mm plate vanished into the 5 mm planning map's band, and the frontier rule then quit after the
    first view). ``max_voxels`` bounds memory (about :data:`BYTES_PER_VOXEL` bytes per voxel).
    """

    resolution_m: float = 0.002
    planning_resolution_m: float = 0.005
    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    free_below: float = 0.45
    occupied_above: float = 0.65
    static_margin_m: float = 0.002
    max_voxels: int = 32_000_000

    def __post_init__(self):
        positive(self.resolution_m, "resolution_m")
        positive(self.planning_resolution_m, "planning_resolution_m")
        for name in ("prob_hit", "prob_miss", "clamp_min", "clamp_max", "free_below", "occupied_above"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not 0.0 < float(value) < 1.0:
                raise InputError(f"{name} must be a probability in (0, 1), got {value!r}")
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise InputError(f"need prob_miss < 0.5 < prob_hit, got {self.prob_miss} / {self.prob_hit}")
        if not self.clamp_min < 0.5 < self.clamp_max:
            raise InputError(f"need clamp_min < 0.5 < clamp_max, got {self.clamp_min} / {self.clamp_max}")
        if not self.free_below < 0.5 < self.occupied_above:
            raise InputError(f"need free_below < 0.5 < occupied_above, got {self.free_below} / {self.occupied_above}")
        if not math.isfinite(self.static_margin_m) or self.static_margin_m < 0:
            raise InputError(f"static_margin_m must be >= 0, got {self.static_margin_m!r}")
        if not 1 <= int(self.max_voxels) < 2**31:
            raise InputError(f"max_voxels must be in [1, 2^31), got {self.max_voxels!r}")
        if self.planning_resolution_m < self.resolution_m:
            raise InputError(
                f"planning_resolution_m ({self.planning_resolution_m}) must not be finer than resolution_m "
                f"({self.resolution_m})"
            )


def _dilate(mask: np.ndarray, radius: int = 1) -> np.ndarray:
    """Cube (Chebyshev) dilation; outside the grid counts as not set."""
    if radius <= 0:
        return mask.copy()
    return ndimage.maximum_filter(mask.view(np.uint8), size=2 * radius + 1, mode="constant", cval=0).astype(bool)


@numba.njit(cache=True)
def _neighbourhood_moments(points, starts, ends, n_query, n_nb):
    """Per query: point count, coordinate sums (3) and second-moment sums (6: xx xy xz yy yz zz) over its
    ``n_nb`` neighbour voxels' point ranges ``[starts, ends)`` of the voxel-sorted ``points``."""
    out = np.zeros((n_query, 10), dtype=np.float64)
    for q in range(n_query):
        for s in range(n_nb):
            a = starts[q * n_nb + s]
            b = ends[q * n_nb + s]
            for p in range(a, b):
                x = points[p, 0]
                y = points[p, 1]
                z = points[p, 2]
                out[q, 0] += 1.0
                out[q, 1] += x
                out[q, 2] += y
                out[q, 3] += z
                out[q, 4] += x * x
                out[q, 5] += x * y
                out[q, 6] += x * z
                out[q, 7] += y * y
                out[q, 8] += y * z
                out[q, 9] += z * z
    return out


def _near_mesh(mesh, margin_m: float, points: np.ndarray) -> np.ndarray:
    """(N,) whether ``mesh`` (trimesh or None) lies within ``margin_m`` of each point along one of the six axis
    directions (Embree ray casts through trimesh)."""
    near = np.zeros(len(points), dtype=bool)
    if mesh is None or not len(points) or margin_m <= 0:
        return near
    for axis in range(3):
        for sign in (1.0, -1.0):
            d = np.zeros(3)
            d[axis] = sign
            left = np.flatnonzero(~near)
            if not len(left):
                return near
            loc, ray, _ = mesh.ray.intersects_location(points[left], np.tile(d, (len(left), 1)), multiple_hits=False)
            if len(ray):
                dist = np.linalg.norm(loc - points[left][ray], axis=1)
                near[left[ray[dist < margin_m]]] = True
    return near


class VoxelMap:
    """Dense probabilistic voxel map over an axis-aligned ROI (see the module docstring).

    Arrays (``(nx, ny, nz)``, x/y/z index order): ``log_odds`` float32, ``observed`` bool (updated at least once),
    ``static`` bool (a-priori scene geometry), ``hits`` int32 (points fused into the voxel), ``normal_sum`` float32
    (..., 3) (sum of those points' unit normals). ``raw`` holds every kept point (:class:`~.map_parts.RawPoints`).
    """

    def __init__(self, roi_min_m, roi_max_m, config: MapConfig = MapConfig()):
        if not isinstance(config, MapConfig):
            raise InputError(f"config must be a MapConfig, got {type(config).__name__}")
        lo = vector(roi_min_m, 3, "roi_min_m")
        hi = vector(roi_max_m, 3, "roi_max_m")
        if np.any(hi <= lo):
            raise InputError(f"empty or inverted ROI: roi_min_m {lo.tolist()} must be below roi_max_m {hi.tolist()}")
        res = positive(config.resolution_m, "resolution_m")
        shape = tuple(int(n) for n in np.maximum(np.ceil((hi - lo) / res - 1e-9), 1))
        n_vox = math.prod(shape)
        if n_vox > int(config.max_voxels):
            raise InputError(
                f"ROI {np.round(hi - lo, 4).tolist()} m at {res * 1000:g} mm needs {shape[0]}x{shape[1]}x{shape[2]} = "
                f"{n_vox:,} voxels (about {n_vox * BYTES_PER_VOXEL / 2**20:,.0f} MiB), above the budget of "
                f"{int(config.max_voxels):,} voxels: shrink the ROI or coarsen the resolution"
            )
        self.config = config
        self.roi_min_m = lo
        self.roi_max_m = hi
        self.origin_m = lo.copy()
        self.resolution_m = res
        self.shape = shape
        self.log_odds = np.zeros(shape, dtype=np.float32)
        self.observed = np.zeros(shape, dtype=bool)
        self.static = np.zeros(shape, dtype=bool)
        self.hits = np.zeros(shape, dtype=np.int32)
        self.normal_sum = np.zeros((*shape, 3), dtype=np.float32)
        self.raw = RawPoints()
        self._static_near = np.zeros(shape, dtype=bool)
        self._static_mesh = None  # the a-priori scene (trimesh), for the exact margin test
        self._mark = np.zeros(n_vox, dtype=np.uint8)
        self._version = 0
        self._cache: dict = {}
        self.views_integrated = 0

    # ------------------------------------------------------------------ sensor model
    @property
    def l_hit(self) -> float:
        return logit(self.config.prob_hit)

    @property
    def l_miss(self) -> float:
        return logit(self.config.prob_miss)

    @property
    def l_min(self) -> float:
        return logit(self.config.clamp_min)

    @property
    def l_max(self) -> float:
        return logit(self.config.clamp_max)

    def _changed(self) -> None:
        self._version += 1
        self._cache.clear()

    @property
    def version(self) -> int:
        """Counts the changes of the map (fusion, static geometry, edits made known by :meth:`invalidate`)."""
        return self._version

    def invalidate(self) -> None:
        """Drop derived data (labels, masks, planning grid) after editing the arrays directly."""
        self._changed()

    def _cached(self, key, compute):
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    # ------------------------------------------------------------------ coordinates
    def index_to_world(self, idx) -> np.ndarray:
        """Centres (m, world) of voxel indices (..., 3)."""
        return self.origin_m + (np.asarray(idx, dtype=float) + 0.5) * self.resolution_m

    def world_to_index(self, p) -> np.ndarray:
        """Voxel indices (int64, ..., 3) of world points (m); points outside the ROI give indices outside the shape."""
        return np.floor((np.asarray(p, dtype=float) - self.origin_m) / self.resolution_m).astype(np.int64)

    def in_grid(self, idx) -> np.ndarray:
        """Whether voxel indices (..., 3) lie inside the grid."""
        idx = np.asarray(idx)
        return np.all((idx >= 0) & (idx < np.asarray(self.shape)), axis=-1)

    def flat_index(self, idx) -> np.ndarray:
        idx = np.asarray(idx, dtype=np.int64)
        return (idx[..., 0] * self.shape[1] + idx[..., 1]) * self.shape[2] + idx[..., 2]

    @property
    def n_voxels(self) -> int:
        return math.prod(self.shape)

    # ------------------------------------------------------------------ static geometry
    def set_static(self, mesh_world) -> None:
        """Rasterise a-priori scene geometry (a trimesh in the world frame, m): voxels on its surface, and inside each
        of its watertight connected bodies, become static (full, never updated); the margin band drops points."""
        import trimesh

        if not isinstance(mesh_world, trimesh.Trimesh):
            raise InputError(f"set_static needs a trimesh.Trimesh, got {type(mesh_world).__name__}")
        res = self.resolution_m
        static = np.zeros(self.shape, dtype=bool)
        if len(mesh_world.faces):
            lo = self.origin_m - res
            hi = self.origin_m + np.asarray(self.shape) * res + res
            # samples moved a micrometre into the body: a face on a voxel boundary (the fixture's top, on the ROI's
            # grid) marks the voxel below it, not the free one above
            samples = surface_samples_in_box(mesh_world.vertices[mesh_world.faces], lo, hi, 0.5 * res, inset_m=1e-6)
            if len(samples):
                idx = self.world_to_index(samples)
                idx = idx[self.in_grid(idx)]
                static[idx[:, 0], idx[:, 1], idx[:, 2]] = True
            # parity fill per connected body: touching or overlapping bodies (a fixture on a table) share
            # coincident faces whose crossings a ray reports once, which would flip the parity above them
            bodies = mesh_world.split(only_watertight=False) if len(mesh_world.faces) < 200_000 else [mesh_world]
            for body in bodies:
                if body.is_watertight:
                    static |= self._inside_by_columns(body)
        self._static_mesh = mesh_world if len(mesh_world.faces) else None
        self._apply_static(static)

    def on_static_scene(self, points_m: np.ndarray) -> np.ndarray:
        """(N,) whether world points (m) inside the grid lie on the static scene as fusion judges it (in a static
        voxel, or in the margin band with the static mesh within ``static_margin_m``): fusion drops them."""
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        idx = self.world_to_index(points)
        out = np.zeros(len(points), dtype=bool)
        inside = self.in_grid(idx)
        out[inside] = self._on_static_scene(points[inside], self.flat_index(idx[inside]))
        return out

    def _on_static_scene(self, points: np.ndarray, flat: np.ndarray) -> np.ndarray:
        on = self.static.reshape(-1)[flat].copy()
        band = self._static_near.reshape(-1)[flat] & ~on
        if band.any():
            on[band] = _near_mesh(self._static_mesh, self.config.static_margin_m, points[band])
        return on

    def _inside_by_columns(self, mesh) -> np.ndarray:
        """Voxels whose centre is inside a watertight mesh: one +z ray per (x, y) column, parity of the crossings
        below each centre (Embree through trimesh)."""
        inside = np.zeros(self.shape, dtype=bool)
        lo = np.maximum(self.world_to_index(mesh.bounds[0]), 0)
        hi = np.minimum(self.world_to_index(mesh.bounds[1]) + 1, np.asarray(self.shape))
        if np.any(hi <= lo):
            return inside
        ii, jj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
        ii, jj = ii.reshape(-1), jj.reshape(-1)
        centres = self.index_to_world(np.column_stack([ii, jj, np.zeros_like(ii)]))
        origins = centres.copy()
        origins[:, 2] = mesh.bounds[0, 2] - 0.01
        directions = np.tile([0.0, 0.0, 1.0], (len(origins), 1))
        locations, ray_index, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
        if len(ray_index) == 0:
            return inside
        z_centres = self.index_to_world(
            np.column_stack([np.zeros(self.shape[2]), np.zeros(self.shape[2]), np.arange(self.shape[2])])
        )[:, 2]
        order = np.lexsort((locations[:, 2], ray_index))
        ray_sorted = ray_index[order]
        z_sorted = locations[order, 2]
        bounds = np.searchsorted(ray_sorted, np.arange(len(origins) + 1))
        for r in np.flatnonzero(np.diff(bounds) >= 2):
            crossings = np.searchsorted(z_sorted[bounds[r] : bounds[r + 1]], z_centres)
            inside[ii[r], jj[r], :] = (crossings % 2) == 1
        return inside

    def _apply_static(self, static: np.ndarray) -> None:
        self.static = static
        self.log_odds[static] = np.float32(self.l_max)
        self.observed[static] = True
        radius = math.ceil(self.config.static_margin_m / self.resolution_m - 1e-9)
        self._static_near = _dilate(static, radius)
        self._changed()

    # ------------------------------------------------------------------ fusion
    def integrate(self, sensor_origin_m, points_m, normals=None, sigma_mm=None, view_id: int = 0) -> dict:
        """Fuse one frame: ``points_m`` (N, 3) world (m), ONLY the frame's valid pixels, seen from
        ``sensor_origin_m`` (the camera centre, m). ``normals`` (N, 3) optional (oriented towards the sensor here),
        ``sigma_mm`` (N,) optional per-point inaccuracy. Rows with a non-finite coordinate are dropped and counted.

        Returns ``{"points", "points_nan", "points_outside", "points_static", "points_kept", "free_updates",
        "hit_updates", "seconds"}``: input rows, dropped NaN rows, points outside the ROI (their rays still carve
        inside it), points dropped near static geometry, kept points, voxels updated free / hit, wall time (s).
        """
        start = time.perf_counter()
        origin = vector(sensor_origin_m, 3, "sensor_origin_m")
        try:
            points = np.asarray(points_m, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("points_m must be an (N, 3) array of numbers") from None
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"points_m must be (N, 3), got shape {points.shape}")
        n_in = len(points)
        if normals is None:
            normals = np.zeros((n_in, 3), dtype=np.float32)
        else:
            normals = np.asarray(normals, dtype=np.float32)
            if normals.shape != (n_in, 3):
                raise InputError(f"normals must be (N, 3) like points_m ({n_in}), got shape {normals.shape}")
        if sigma_mm is None:
            sigma = np.full(n_in, np.nan, dtype=np.float32)
        else:
            sigma = np.asarray(sigma_mm, dtype=np.float32).reshape(-1)
            if sigma.shape != (n_in,):
                raise InputError(f"sigma_mm must have one value per point ({n_in}), got {sigma.shape}")
        finite = np.all(np.isfinite(points), axis=1)
        n_nan = int(n_in - finite.sum())
        if n_nan:
            points, normals, sigma = points[finite], normals[finite], sigma[finite]
        normals = np.where(np.all(np.isfinite(normals), axis=1, keepdims=True), normals, 0.0).astype(np.float32)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 1e-9, normals / np.maximum(length, 1e-12), 0.0).astype(np.float32)
        # a PhoXi normal's sign is arbitrary for us: orient it towards the sensor (the surface's seen side)
        flip = np.einsum("ij,ij->i", normals, origin - points) < 0
        normals[flip] *= -1.0

        res = self.resolution_m
        points_g = (points - self.origin_m) / res
        origin_g = (origin - self.origin_m) / res
        idx = np.floor(points_g).astype(np.int64)
        inside = self.in_grid(idx)
        end_flat = np.full(len(points), -1, dtype=np.int64)
        end_flat[inside] = self.flat_index(idx[inside])
        near_static = np.zeros(len(points), dtype=bool)
        near_static[inside] = self._on_static_scene(points[inside], end_flat[inside])
        kept = inside & ~near_static
        nx, ny, nz = self.shape
        args = (
            self.log_odds.reshape(-1),
            self.observed.reshape(-1),
            self.hits.reshape(-1),
            self.normal_sum.reshape(-1, 3),
            self.static.reshape(-1),
            self._mark,
            origin_g,
            np.ascontiguousarray(points_g),
            normals,
            kept,
            end_flat,
            nx,
            ny,
            nz,
            self.l_hit,
            self.l_miss,
            self.l_min,
            self.l_max,
        )
        if parallel_allowed():
            n_free, n_hit = fuse_frame(*args, numba.get_num_threads())
        else:
            n_free, n_hit = fuse_frame_serial(*args, 1)
        self.raw.append(points[kept], normals[kept], view_id, sigma[kept])
        if np.ndim(view_id) == 0:
            self.raw.origins[int(view_id)] = origin.copy()
        self.views_integrated += 1
        self._changed()
        return {
            "points": int(n_in),
            "points_nan": n_nan,
            "points_outside": int((~inside).sum()),
            "points_static": int(near_static.sum()),
            "points_kept": int(kept.sum()),
            "free_updates": int(n_free),
            "hit_updates": int(n_hit),
            "seconds": time.perf_counter() - start,
        }

    def integrate_organised(
        self, depth_m, intrinsics, camera_pose_world, normals_cam=None, sigma_mm=None, view_id: int = 0
    ) -> dict:
        """Fuse an organised frame: z-depth image (H, W) in m with 0 / NaN for invalid pixels, pinhole
        ``intrinsics`` (``sensors.phoxi`` CameraIntrinsics), pose world <- camera (4x4); optional camera-frame
        normals (H, W, 3) and sigma (H, W) mm. Only valid pixels are fused (see :meth:`integrate`)."""
        depth = np.asarray(depth_m, dtype=np.float64)
        if depth.shape != (intrinsics.height, intrinsics.width):
            raise InputError(f"depth_m is {depth.shape}, the intrinsics need ({intrinsics.height}, {intrinsics.width})")
        pose = np.asarray(camera_pose_world, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InputError("camera_pose_world must be a finite 4x4 matrix")
        valid = (np.isfinite(depth) & (depth > 0)).reshape(-1)
        rays = intrinsics.pixel_rays()[valid].astype(np.float64)
        points = (rays * depth.reshape(-1)[valid, None]) @ pose[:3, :3].T + pose[:3, 3]
        normals = None
        if normals_cam is not None:
            normals = np.asarray(normals_cam, dtype=np.float64).reshape(-1, 3)[valid] @ pose[:3, :3].T
        sigma = None if sigma_mm is None else np.asarray(sigma_mm, dtype=np.float32).reshape(-1)[valid]
        return self.integrate(pose[:3, 3], points, normals, sigma, view_id)

    # ------------------------------------------------------------------ labels
    def probability(self) -> np.ndarray:
        """Occupancy probability per voxel (float32; 0.5 where never observed)."""
        return (1.0 / (1.0 + np.exp(-self.log_odds))).astype(np.float32)

    def labels(self) -> np.ndarray:
        """int8 per voxel: -1 empty, 0 unknown, 1 full (static geometry is full)."""

        def compute():
            out = np.zeros(self.shape, dtype=np.int8)
            out[self.log_odds < logit(self.config.free_below)] = EMPTY
            out[self.log_odds > logit(self.config.occupied_above)] = FULL
            out[self.static] = FULL
            out.setflags(write=False)
            return out

        return self._cached("labels", compute)

    def unknown_mask(self) -> np.ndarray:
        return self._cached("unknown", lambda: self.labels() == UNKNOWN)

    def empty_mask(self) -> np.ndarray:
        return self._cached("empty", lambda: self.labels() == EMPTY)

    def full_mask(self) -> np.ndarray:
        """Full voxels of the object (static geometry excluded)."""
        return self._cached("full", lambda: (self.labels() == FULL) & ~self.static)

    def growth_mask(self) -> np.ndarray:
        """Full (non-static) voxels with an unknown 26-neighbour."""
        return self._cached("growth", lambda: self.full_mask() & _dilate(self.unknown_mask()))

    def candidate_mask(self) -> np.ndarray:
        """Unknown voxels 26-adjacent to an empty and to a growth voxel."""
        return self._cached(
            "candidate", lambda: self.unknown_mask() & _dilate(self.empty_mask()) & _dilate(self.growth_mask())
        )

    def occlusion_plane_mask(self) -> np.ndarray:
        """Unknown voxels 26-adjacent to an empty voxel (Massios & Fisher's occlusion plane)."""
        return self._cached("occplane", lambda: self.unknown_mask() & _dilate(self.empty_mask()))

    def growth_neighbour_mask(self) -> np.ndarray:
        """Unknown voxels 26-adjacent to a growth voxel (where the seen surface continues unseen)."""
        return self._cached("growth_nb", lambda: self.unknown_mask() & _dilate(self.growth_mask()))

    def growth_voxels(self) -> np.ndarray:
        """(K, 3) int64 indices of the growth voxels."""
        return np.argwhere(self.growth_mask())

    def candidate_voxels(self) -> np.ndarray:
        """(K, 3) int64 indices of the candidate voxels."""
        return np.argwhere(self.candidate_mask())

    def occlusion_plane(self) -> np.ndarray:
        """(K, 3) int64 indices of the occlusion-plane voxels."""
        return np.argwhere(self.occlusion_plane_mask())

    def observed_surface_area_m2(self) -> float:
        """Observed surface estimate (m^2): full object voxels x resolution^2.

        A surface crossing the grid occupies about one voxel layer, so this is its area to within the voxel
        staircase: exact for axis-aligned faces, up to ~1.7x for a face at 45 deg to all axes (more voxels per
        area), and it counts thin parts once per face seen.
        """
        return float(self.full_mask().sum()) * self.resolution_m**2

    def frontier_area_m2(self) -> float:
        """Remaining frontier estimate (m^2): candidate voxels x resolution^2 (same staircase caveat)."""
        return float(self.candidate_mask().sum()) * self.resolution_m**2

    # ------------------------------------------------------------------ predicted surface
    def _sorted_raw(self):
        def compute():
            xyz = self.raw.xyz_m
            idx = self.world_to_index(xyz)
            ok = self.in_grid(idx)
            flat = self.flat_index(idx[ok])
            order = np.argsort(flat, kind="stable")
            return flat[order], np.ascontiguousarray(xyz[ok][order], dtype=np.float64)

        return self._cached(("raw_sorted", len(self.raw)), compute)

    def predicted_surface(self, voxel_indices) -> tuple[np.ndarray, np.ndarray]:
        """Predicted surface at voxels (K, 3): (centroids (K, 3) m, unit normals (K, 3)).

        The PCA plane of the raw points in each voxel's 3x3x3 neighbourhood: centroid = their mean, normal = the
        covariance's least eigenvector, oriented towards the neighbourhood's empty voxels (observed-free space),
        else along the fused sensor-facing normals. With fewer than 3 points the centroid is the voxel centre and the
        normal the mean fused normal (zero if none).
        """
        idx = np.asarray(voxel_indices, dtype=np.int64).reshape(-1, 3)
        k = len(idx)
        if k == 0:
            return np.zeros((0, 3)), np.zeros((0, 3))
        if not np.all(self.in_grid(idx)):
            raise InputError("predicted_surface: voxel indices outside the grid")
        nb = idx[:, None, :] + _NEIGHBOURS_27[None, :, :]
        ok = self.in_grid(nb)
        flat_nb = np.where(ok, self.flat_index(np.where(ok[..., None], nb, 0)), -1)
        sorted_flat, sorted_xyz = self._sorted_raw()
        starts = np.searchsorted(sorted_flat, flat_nb.reshape(-1), side="left")
        ends = np.searchsorted(sorted_flat, flat_nb.reshape(-1), side="right")
        ends = np.where(flat_nb.reshape(-1) < 0, starts, ends)
        mom = _neighbourhood_moments(sorted_xyz, starts, ends, k, 27)
        count = mom[:, 0]
        safe = np.maximum(count, 1.0)[:, None]
        mean = mom[:, 1:4] / safe
        second = mom[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]].reshape(k, 3, 3) / safe[:, :, None]
        cov = second - mean[:, :, None] * mean[:, None, :]
        _, vectors = np.linalg.eigh(cov)
        normals = vectors[:, :, 0]
        flat_safe = np.where(ok, flat_nb, 0)
        nsum = (self.normal_sum.reshape(-1, 3)[flat_safe] * ok[..., None]).sum(axis=1)
        empty = self.empty_mask().reshape(-1)[flat_safe] & ok
        empty_dir = (empty[..., None] * _NEIGHBOURS_27[None, :, :]).sum(axis=1).astype(float)
        reference = np.where(np.linalg.norm(empty_dir, axis=1, keepdims=True) > 0, empty_dir, nsum)
        few = count < 3
        centres = self.index_to_world(idx)
        nsum_len = np.linalg.norm(nsum, axis=1, keepdims=True)
        fallback = np.where(nsum_len > 1e-9, nsum / np.maximum(nsum_len, 1e-12), 0.0)
        normals = np.where(few[:, None], fallback, normals)
        flip = np.einsum("ij,ij->i", normals, reference) < 0
        normals[flip] *= -1.0
        centroids = np.where(few[:, None], centres, mean)
        return centroids, normals

    # ------------------------------------------------------------------ planning grid
    def coarse(self) -> VoxelMap:
        """The planning grid at ``planning_resolution_m`` over the same ROI (shares :attr:`raw`).

        Log-odds are max-pooled, so a coarse voxel is full if any fine voxel in it is full, empty only if all are
        empty, unknown otherwise; ``observed``/``static`` are or-pooled, ``hits``/``normal_sum`` summed. Fine
        voxel centres decide membership, so the two resolutions need not divide each other.
        """
        return self._cached("coarse", self._make_coarse)

    def _make_coarse(self) -> VoxelMap:
        res_c = float(self.config.planning_resolution_m)
        config = replace(self.config, resolution_m=res_c)
        out = VoxelMap(self.roi_min_m, self.roi_max_m, config)
        out.raw = self.raw
        out._static_mesh = self._static_mesh
        if abs(res_c - self.resolution_m) < 1e-12 and out.shape == self.shape:
            out.log_odds[...] = self.log_odds
            out.observed[...] = self.observed
            out.hits[...] = self.hits
            out.normal_sum[...] = self.normal_sum
            out.static = self.static.copy()
            out._static_near = self._static_near.copy()
            out._changed()
            return out
        num, den = self.resolution_m, res_c
        out.log_odds[...] = pool_max(self.log_odds, self.shape, num, den, out.shape, 0.0)
        out.observed[...] = pool_max(self.observed.astype(np.float32), self.shape, num, den, out.shape, 0.0) > 0
        static = pool_max(self.static.astype(np.float32), self.shape, num, den, out.shape, 0.0) > 0
        extra = pool_sum(
            np.concatenate([self.hits[..., None].astype(np.float32), self.normal_sum], axis=-1), num, den, out.shape
        )
        out.hits[...] = np.minimum(extra[..., 0], np.iinfo(np.int32).max).astype(np.int32)
        out.normal_sum[...] = extra[..., 1:4]
        out.static = static
        radius = math.ceil(self.config.static_margin_m / res_c - 1e-9)
        out._static_near = _dilate(static, radius)
        out.views_integrated = self.views_integrated
        out._changed()
        return out

    # ------------------------------------------------------------------ persistence
    def save_npz(self, path) -> Path:
        """Write the map (grids, config, raw points with each view's sensor origin) to a compressed ``.npz``,
        atomically."""
        raw = self.raw
        buffer = io.BytesIO()
        np.savez_compressed(
            buffer,
            format_version=np.array(MAP_FORMAT_VERSION),
            config=np.array(json.dumps(asdict(self.config))),
            roi_min_m=self.roi_min_m,
            roi_max_m=self.roi_max_m,
            log_odds=self.log_odds,
            observed=self.observed,
            static=self.static,
            hits=self.hits,
            normal_sum=self.normal_sum,
            raw_xyz_m=raw.xyz_m,
            raw_normal=raw.normal,
            raw_view=raw.view,
            raw_sigma_mm=raw.sigma_mm,
            **raw.origin_arrays(),
            views_integrated=np.array(self.views_integrated),
        )
        return atomic_write_bytes(path, buffer.getvalue())

    @classmethod
    def load_npz(cls, path) -> VoxelMap:
        """Read a map written by :meth:`save_npz`; a missing, foreign or damaged file is an InputError naming it."""
        path = Path(path)
        keys = ("log_odds", "observed", "static", "hits", "normal_sum", "raw_xyz_m", "raw_normal", "raw_view")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [k for k in ("format_version", "config", "roi_min_m", "roi_max_m", *keys) if k not in data]
                if missing:
                    raise InputError(f"{path}: not a voxel map file (missing {', '.join(missing)})")
                if int(data["format_version"]) != MAP_FORMAT_VERSION:
                    raise InputError(f"{path}: map format {int(data['format_version'])}, expected {MAP_FORMAT_VERSION}")
                config = MapConfig(**json.loads(str(data["config"])))
                out = cls(data["roi_min_m"], data["roi_max_m"], config)
                for name in ("log_odds", "observed", "static", "hits", "normal_sum"):
                    value = data[name]
                    target = getattr(out, name)
                    if value.shape != target.shape:
                        raise InputError(f"{path}: {name} has shape {value.shape}, the ROI needs {target.shape}")
                    target[...] = value
                out.raw.append(data["raw_xyz_m"], data["raw_normal"], data["raw_view"], data["raw_sigma_mm"])
                if "raw_origin_view" in data:  # the sensor origin per view (maps written before had none)
                    out.raw.set_origins(data["raw_origin_view"], data["raw_origin_m"], str(path))
                out.views_integrated = int(data["views_integrated"]) if "views_integrated" in data else 0
        except FileNotFoundError:
            raise InputError(f"{path}: no such map file") from None
        except (OSError, ValueError, KeyError, TypeError) as error:
            if isinstance(error, InputError):
                raise
            raise InputError(f"{path}: cannot read the voxel map ({error})") from None
        out._apply_static(out.static)
        return out

    def save_bt(self, path) -> bool:
        """Write an OctoMap ``.bt`` of the observed voxels when the OctoMap binding ``octomap-python`` is importable;
        returns False, writing nothing, when it is not.

        The tree gets this map's sensor model, clamping and each observed voxel's log-odds; ``.bt`` is OctoMap's
        max-likelihood format, so a reader sees every node as free or occupied (OctoMap's threshold 0.5) at the
        clamping bounds. Never-observed voxels stay absent (OctoMap's unknown)."""
        try:
            import octomap
        except ImportError:
            return False
        tree = octomap.OcTree(self.resolution_m)
        tree.setProbHit(self.config.prob_hit)
        tree.setProbMiss(self.config.prob_miss)
        tree.setClampingThresMin(self.config.clamp_min)
        tree.setClampingThresMax(self.config.clamp_max)
        observed = np.flatnonzero(self.observed.reshape(-1))
        values = self.log_odds.reshape(-1)[observed]
        # fused log-odds are sums of two constants (clamped): few distinct values, one batched call each
        levels, inverse = np.unique(values, return_inverse=True)
        centres = self.index_to_world(np.column_stack(np.unravel_index(observed, self.shape)))
        for level_index, level in enumerate(levels):
            if level != 0.0:
                tree.updateNodes(np.ascontiguousarray(centres[inverse == level_index]), float(level), True)
        tree.updateInnerOccupancy()

        def write(tmp: Path) -> None:
            if not tree.writeBinary(str(tmp).encode()):
                raise MapWriteError(f"octomap could not write {tmp}")

        atomic_write(path, write, suffix=".bt")
        return True

    def export_cloud_ply(self, path, voxel_m: float = 0.001) -> int:
        """Write the fused raw cloud as a binary PLY (world frame, m), downsampled to one point per ``voxel_m`` cell.

        Per output point: the mean position and normal of the cell's points, ``view`` = the view of its most precise
        point (smallest sigma), ``sigma_mm`` = the mean sigma, ``count`` = the points merged. Returns the count.
        """
        voxel_m = positive(voxel_m, "voxel_m")
        xyz = self.raw.xyz_m.astype(np.float64)
        if len(xyz) == 0:
            write_ply(path, np.zeros((0, 3)), np.zeros((0, 3)), {"view": [], "sigma_mm": [], "count": []})
            return 0
        cells = np.floor((xyz - self.origin_m) / voxel_m).astype(np.int64)
        cells -= cells.min(axis=0)
        dims = cells.max(axis=0) + 1
        key = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        sigma = self.raw.sigma_mm.astype(np.float64)
        order = np.lexsort((np.where(np.isfinite(sigma), sigma, np.inf), key))
        key_sorted = key[order]
        first = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
        group = np.cumsum(np.r_[True, key_sorted[1:] != key_sorted[:-1]]) - 1
        count = np.diff(np.r_[first, len(key_sorted)]).astype(np.float64)
        m = len(first)
        mean = np.stack([np.bincount(group, xyz[order, a], m) for a in range(3)], axis=1) / count[:, None]
        nrm = self.raw.normal[order].astype(np.float64)
        nsum = np.stack([np.bincount(group, nrm[:, a], m) for a in range(3)], axis=1)
        nlen = np.linalg.norm(nsum, axis=1, keepdims=True)
        normals = np.where(nlen > 1e-9, nsum / np.maximum(nlen, 1e-12), 0.0)
        s = sigma[order]
        finite = np.isfinite(s)
        s_count = np.bincount(group, finite.astype(float), m)
        s_sum = np.bincount(group, np.where(finite, s, 0.0), m)
        sigma_mean = np.where(s_count > 0, s_sum / np.maximum(s_count, 1), np.nan)
        views = self.raw.view[order][first]
        write_ply(
            path,
            mean,
            normals,
            {"view": views, "sigma_mm": sigma_mean, "count": count},
            comments=("frame world", f"fused NBV cloud, {voxel_m * 1000:g} mm cells"),
        )
        return int(m)
