"""Surface mesh of the reconstruction: a projective truncated signed distance field (TSDF) fused from organised
depth images, and marching cubes (``skimage.measure.marching_cubes``) to a world-frame trimesh.

Per voxel the signed distance is the *projective* one: the measured depth at the pixel the voxel centre projects
to, minus the voxel's depth (both along the optical axis), positive in front of the surface. It is truncated to
``[-truncation_m, truncation_m]``, divided by ``truncation_m`` and averaged over frames with unit weights (Curless &
Levoy). Voxels farther than ``truncation_m`` behind the measured surface are not updated (they may be solid or free),
pixels with no depth (0 or non-finite: invalid PhoXi pixels) update nothing, so a projector shadow carves nothing.
Faces with a vertex on a grid edge that touches a never-updated voxel are dropped, so no surface appears at the
border of the observed band. Units: metres.
"""

# ruff: noqa: RUF046 -- explicit int() keeps numba's integer typing of math.floor unambiguous
from __future__ import annotations

import math

import numba
import numpy as np

from agiprobot_measurement.common.config import vector
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.raycast3d import parallel_allowed, threaded_and_serial

__all__ = ["TSDFVolume"]

#: most voxels a TSDF volume may have (8 bytes each)
MAX_TSDF_VOXELS = 64_000_000


@numba.njit(cache=True)
def _integrate_slab(i, tsdf, weight, origin, voxel, depth, fx, fy, cx, cy, rot_wc, trans_wc, truncation):
    """Fuse the voxels of x-slab ``i``; returns how many were updated."""
    ny, nz = tsdf.shape[1], tsdf.shape[2]
    height, width = depth.shape
    wx = origin[0] + (i + 0.5) * voxel
    count = 0
    for j in range(ny):
        wy = origin[1] + (j + 0.5) * voxel
        for k in range(nz):
            wz = origin[2] + (k + 0.5) * voxel
            # camera frame: R^T (p - t)
            dx = wx - trans_wc[0]
            dy = wy - trans_wc[1]
            dz = wz - trans_wc[2]
            pcx = rot_wc[0, 0] * dx + rot_wc[1, 0] * dy + rot_wc[2, 0] * dz
            pcy = rot_wc[0, 1] * dx + rot_wc[1, 1] * dy + rot_wc[2, 1] * dz
            pcz = rot_wc[0, 2] * dx + rot_wc[1, 2] * dy + rot_wc[2, 2] * dz
            if pcz <= 1e-6:
                continue
            u = int(math.floor(fx * pcx / pcz + cx + 0.5))
            v = int(math.floor(fy * pcy / pcz + cy + 0.5))
            if u < 0 or v < 0 or u >= width or v >= height:
                continue
            d = depth[v, u]
            if not (d > 0.0) or not math.isfinite(d):
                continue
            sdf = d - pcz
            if sdf < -truncation:
                continue
            value = min(1.0, sdf / truncation)
            w = weight[i, j, k]
            tsdf[i, j, k] = (tsdf[i, j, k] * w + value) / (w + 1.0)
            weight[i, j, k] = w + 1.0
            count += 1
    return count


def _integrate_projective_slabs(tsdf, weight, origin, voxel, depth, fx, fy, cx, cy, rot_wc, trans_wc, truncation):
    """Fuse one depth image (H, W, z-depth in m, 0 = invalid) seen from camera pose world <- camera (R, t)."""
    nx = tsdf.shape[0]
    updated = np.zeros(nx, dtype=np.int64)
    for i in numba.prange(nx):
        updated[i] = _integrate_slab(
            i, tsdf, weight, origin, voxel, depth, fx, fy, cx, cy, rot_wc, trans_wc, truncation
        )
    return updated.sum()


_integrate_projective, _integrate_projective_serial = threaded_and_serial(_integrate_projective_slabs)


class TSDFVolume:
    """Projective TSDF over the ROI box (m) at ``voxel_m`` with truncation ``truncation_m`` (see the module
    docstring). ``tsdf`` (nx, ny, nz) float32 in [-1, 1] (1 where never updated), ``weight`` float32 frame count."""

    def __init__(self, roi_min_m, roi_max_m, voxel_m: float = 0.002, truncation_m: float = 0.006):
        lo = vector(roi_min_m, 3, "roi_min_m")
        hi = vector(roi_max_m, 3, "roi_max_m")
        if np.any(hi <= lo):
            raise InputError(f"empty or inverted ROI: roi_min_m {lo.tolist()} must be below roi_max_m {hi.tolist()}")
        for name, value in (("voxel_m", voxel_m), ("truncation_m", truncation_m)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise InputError(f"{name} must be a positive finite number, got {value!r}")
        if truncation_m < voxel_m:
            raise InputError(f"truncation_m ({truncation_m}) must be at least one voxel ({voxel_m})")
        shape = tuple(int(n) for n in np.maximum(np.ceil((hi - lo) / voxel_m - 1e-9), 1))
        n_vox = math.prod(shape)
        if n_vox > MAX_TSDF_VOXELS:
            raise InputError(
                f"TSDF over {np.round(hi - lo, 4).tolist()} m at {voxel_m * 1000:g} mm needs {n_vox:,} voxels "
                f"(about {n_vox * 8 / 2**20:,.0f} MiB), above the budget of {MAX_TSDF_VOXELS:,}"
            )
        self.origin_m = lo
        self.voxel_m = float(voxel_m)
        self.truncation_m = float(truncation_m)
        self.shape = shape
        self.tsdf = np.ones(shape, dtype=np.float32)
        self.weight = np.zeros(shape, dtype=np.float32)

    def integrate(self, depth_m: np.ndarray, intrinsics, camera_pose_world: np.ndarray) -> int:
        """Fuse an organised z-depth image (H, W) in m (0 or NaN = invalid pixel) taken with pinhole ``intrinsics``
        (``sensors.phoxi`` CameraIntrinsics: width, height, fx, fy, cx, cy in pixels) from ``camera_pose_world``
        (4x4 world <- camera, z optical axis). Returns the number of voxels updated."""
        depth = np.asarray(depth_m, dtype=np.float32)
        if depth.ndim != 2:
            raise InputError(f"depth_m must be an (H, W) image, got shape {depth.shape}")
        if depth.shape != (intrinsics.height, intrinsics.width):
            raise InputError(
                f"depth_m is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are "
                f"{intrinsics.width}x{intrinsics.height}"
            )
        pose = np.asarray(camera_pose_world, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InputError("camera_pose_world must be a finite 4x4 matrix")
        kernel = _integrate_projective if parallel_allowed() else _integrate_projective_serial
        return int(
            kernel(
                self.tsdf,
                self.weight,
                self.origin_m,
                self.voxel_m,
                np.ascontiguousarray(depth),
                float(intrinsics.fx),
                float(intrinsics.fy),
                float(intrinsics.cx),
                float(intrinsics.cy),
                np.ascontiguousarray(pose[:3, :3]),
                np.ascontiguousarray(pose[:3, 3]),
                self.truncation_m,
            )
        )

    def mesh(self):
        """The zero level set as a trimesh in the world frame (m), faces wound outwards (towards free space); an
        empty mesh when no surface was observed."""
        import trimesh
        from skimage.measure import marching_cubes

        valid = self.weight > 0
        if min(self.shape) < 2 or not valid.any():
            return trimesh.Trimesh()
        values = np.where(valid, self.tsdf, 1.0)
        if values.min() > 0 or values.max() < 0:
            return trimesh.Trimesh()
        try:
            verts, faces, _, _ = marching_cubes(values, level=0.0, gradient_direction="descent")
        except (ValueError, RuntimeError):
            return trimesh.Trimesh()
        # a vertex lies on a grid edge; keep faces whose vertices' edge ends were all observed (no surface at the
        # border between the observed band and never-updated voxels)
        lo = np.clip(np.floor(verts + 1e-6).astype(np.int64), 0, np.asarray(self.shape) - 1)
        hi = np.clip(np.ceil(verts - 1e-6).astype(np.int64), 0, np.asarray(self.shape) - 1)
        vert_ok = valid[lo[:, 0], lo[:, 1], lo[:, 2]] & valid[hi[:, 0], hi[:, 1], hi[:, 2]]
        faces = faces[vert_ok[faces].all(axis=1)]
        if len(faces) == 0:
            return trimesh.Trimesh()
        verts = verts * self.voxel_m + self.origin_m + 0.5 * self.voxel_m
        return trimesh.Trimesh(vertices=verts, faces=faces, process=True)
