"""How much new surface a captured frame added: the loop's realised gain, which the surprise rule and the stopping
rule compare with what the view promised."""

from __future__ import annotations

import numpy as np

__all__ = ["NoveltyTracker"]


class NoveltyTracker:
    """Surface added per frame (m^2) inside the ROI ``[roi_min_m, roi_max_m]`` of the output map ``voxel_map``.

        A frame's point counts when no earlier point lies within one novelty cell (the ROI's largest edge / 300, at least
        1 mm; 26-neighbourhood), weighted by the surface a pixel covers there ((depth / f)^2 / cos incidence, the
        incidence clipped at cos 0.2). Noise does not move a point by a cell, and a face first seen grazing still counts
        when a later view samples it densely. Points on the static scene (the fixture's top) do not count, judged as fusion
    judges them (:meth:`~.voxel_map.VoxelMap.on_static_scene`: a band of voxels around the static scene dropped all of a
    plate thinner than the band lying on the fixture, so its views added nothing and the run stopped after three). ``default_fx``:
        the focal length (px) of frames without intrinsics."""

    def __init__(self, roi_min_m: np.ndarray, roi_max_m: np.ndarray, voxel_map, default_fx: float):
        self.roi_min_m = np.asarray(roi_min_m, dtype=float)
        self.roi_max_m = np.asarray(roi_max_m, dtype=float)
        self.map = voxel_map
        self.default_fx = float(default_fx)
        self._near = None

    def _start(self) -> None:
        extent = float(np.max(self.roi_max_m - self.roi_min_m))
        self._cell_m = max(0.001, extent / 300.0)
        shape = tuple(int(n) for n in np.ceil((self.roi_max_m - self.roi_min_m) / self._cell_m))
        self._near = np.zeros(shape, dtype=bool)

    def add(self, view) -> float:
        """The surface (m^2) the captured ``view`` added; its points count as seen from now on."""
        if self._near is None:
            self._start()
        pts = np.asarray(view.points_m, dtype=float).reshape(-1, 3)
        if not len(pts):
            return 0.0
        near = self._near
        idx = np.floor((pts - self.roi_min_m) / self._cell_m).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.asarray(near.shape)), axis=1)
        ok &= self.map.in_grid(self.map.world_to_index(pts))
        ok[ok] &= ~self.map.on_static_scene(pts[ok])
        idx, pts = idx[ok], pts[ok]
        normals = np.asarray(view.normals, dtype=float).reshape(-1, 3)[ok]
        novel = ~near[tuple(idx.T)]
        pose = np.asarray(view.camera_pose, dtype=float)
        ray = pts[novel] - pose[:3, 3]
        depth = ray @ pose[:3, 2]
        dist = np.linalg.norm(ray, axis=1)
        cos = np.abs(np.einsum("ij,ij->i", normals[novel], ray)) / np.maximum(dist, 1e-9)
        fx = float(getattr(view.intrinsics, "fx", 0.0) or self.default_fx)
        area = float(np.sum((depth / fx) ** 2 / np.maximum(cos, 0.2)))
        for offset in np.ndindex(3, 3, 3):
            shifted = np.clip(idx + (np.asarray(offset) - 1), 0, np.asarray(near.shape) - 1)
            near[tuple(shifted.T)] = True
        return area
