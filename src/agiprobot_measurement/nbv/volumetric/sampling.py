"""Where the seen surface is sampled too sparsely to count as measured.

A structured-light frame samples a surface every ``pitch x distance / cos(incidence)`` along the tilt; a surface seen
from far or obliquely is full in the voxel map and yet has holes wider than the distance within which a point counts
as measured. Late in a reconstruction most of what is missing lies there, next to fused points, not in unknown space.

Per fused view, from its own points only: the spacing of its samples (the distance to each point's ``neighbours``-th
nearest neighbour in the same frame, the wider of the two grid directions), averaged per planning voxel, and the
view's angular pitch (the median of ``spacing x cos(incidence) / distance`` over its points; needs the view's sensor
origin, :attr:`.map_parts.RawPoints.origins`). A view of spacing ``s`` measures the share ``min(1, pi r^2 / s^2)`` of
a voxel's surface densely enough (``r`` = ``coverage_radius_m``); views are taken as independent, so the share a
voxel still misses is the product of ``1 -`` those shares. The surface just beyond the fused points' open borders
(:func:`open_edges`: grazing incidence, shadows) is expected too (:meth:`SamplingState.open_border`).
:func:`.gains.undersampled_surface` scores a candidate view by the missed share it would measure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from agiprobot_measurement.common.config import positive
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gains import predicted_normals
from agiprobot_measurement.nbv.volumetric.voxel_map import FULL

__all__ = ["SamplingModel", "SamplingState", "ViewSampling", "covered_share", "open_edges"]


@dataclass(frozen=True)
class SamplingModel:
    """``coverage_radius_m``: a surface point counts as measured within this distance of a sample (m);
    ``neighbours``: the neighbour whose distance is a point's sample spacing (4: the wider grid direction)."""

    coverage_radius_m: float = 0.002
    neighbours: int = 4

    def __post_init__(self):
        positive(self.coverage_radius_m, "coverage_radius_m")
        if not isinstance(self.neighbours, int) or not 1 <= self.neighbours <= 16:
            raise InputError(f"neighbours must be a whole number in [1, 16], got {self.neighbours!r}")


def covered_share(spacing_m: np.ndarray, radius_m: float) -> np.ndarray:
    """The share of a surface within ``radius_m`` of samples ``spacing_m`` apart: ``min(1, pi r^2 / s^2)``."""
    s = np.maximum(np.asarray(spacing_m, dtype=float), 1e-9)
    return np.minimum(1.0, math.pi * radius_m * radius_m / (s * s))


@dataclass
class ViewSampling:
    """One fused view on the planning grid: ``flat`` the voxels holding its points, ``spacing_m`` its mean sample
    spacing there, ``pitch_rad`` its angular pitch (NaN where its origin is unknown)."""

    flat: np.ndarray
    spacing_m: np.ndarray
    pitch_rad: float


@dataclass
class SamplingState:
    """The views summarised so far (by view id) on one planning grid; :meth:`missed_share` brings it up to date."""

    model: SamplingModel = field(default_factory=SamplingModel)
    views: dict = field(default_factory=dict)
    #: (map version, border weight) -> :meth:`fields`' result, the last one only
    last: tuple = ()

    def fields(self, grid, border_weight: float) -> tuple[np.ndarray, np.ndarray | None, float]:
        """(per planning voxel (flat) the surface a view may still measure there, as a share of resolution^2: the
        missed share (:meth:`missed_share`) plus ``border_weight`` x the open border's (:meth:`open_border`); the
        directions the incidence is taken to (flat, 3; None: the fused normals); the angular pitch (rad))."""
        key = (grid.version, float(border_weight))
        if self.last and self.last[0] == key:
            return self.last[1]
        missed, pitch = self.missed_share(grid)
        normals = None
        if border_weight > 0:
            border, direction = self.open_border(grid)
            fused = predicted_normals(grid)
            normals = fused * missed[:, None] + direction
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            normals = np.where(length > 1e-9, normals / np.maximum(length, 1e-12), fused)
            missed = missed + border_weight * border
        self.last = (key, (missed, normals, pitch))
        return missed, normals, pitch

    def update(self, grid) -> None:
        """Summarise the views of ``grid.raw`` not seen yet."""
        raw = grid.raw
        if len(raw) == 0:
            return
        ids = raw.view
        new = [int(v) for v in np.unique(ids) if int(v) not in self.views]
        if not new:
            return
        xyz_all = raw.xyz_m
        normal_all = raw.normal
        k = self.model.neighbours
        for v in new:
            mask = ids == v
            xyz = xyz_all[mask].astype(np.float64)
            if len(xyz) <= k:
                self.views[v] = ViewSampling(np.zeros(0, np.int64), np.zeros(0), math.nan)
                continue
            dist, _ = cKDTree(xyz).query(xyz, k=k + 1)
            spacing = dist[:, k]
            idx = np.floor((xyz - grid.origin_m) / grid.resolution_m).astype(np.int64)
            inside = grid.in_grid(idx)
            flat = grid.flat_index(idx[inside])
            uniq, inverse = np.unique(flat, return_inverse=True)
            mean = np.bincount(inverse, spacing[inside]) / np.bincount(inverse)
            pitch = math.nan
            origin = raw.origins.get(v)
            if origin is not None:
                to_sensor = origin[None, :] - xyz
                distance = np.linalg.norm(to_sensor, axis=1)
                cos_inc = np.abs(np.einsum("ij,ij->i", normal_all[mask], to_sensor)) / np.maximum(distance, 1e-9)
                ok = cos_inc > 0.2
                if ok.any():
                    pitch = float(np.median(spacing[ok] * cos_inc[ok] / distance[ok]))
            self.views[v] = ViewSampling(uniq, mean, pitch)

    def missed_share(self, grid) -> tuple[np.ndarray, float]:
        """(per planning voxel (flat) the share of its surface no view has measured densely enough, on the full
        voxels with measured points off the static scene, 0 elsewhere; the views' median angular pitch (rad), NaN
        when none is known)."""
        self.update(grid)
        full_flat = ((grid.labels() == FULL) & (grid.hits > 0) & ~grid.static).reshape(-1)
        missed = np.ones(grid.n_voxels)
        radius = self.model.coverage_radius_m
        for view in self.views.values():
            if len(view.flat):
                missed[view.flat] *= 1.0 - covered_share(view.spacing_m, radius)
        missed[~full_flat] = 0.0
        pitches = [v.pitch_rad for v in self.views.values() if np.isfinite(v.pitch_rad)]
        return missed, float(np.median(pitches)) if pitches else math.nan

    def open_border(self, grid) -> tuple[np.ndarray, np.ndarray]:
        """(per planning voxel (flat) the surface expected just beyond the open borders of the fused points in it,
        as a share of ``resolution^2``: per border point its views' mean sample spacing x twice the coverage
        radius; the direction (flat, 3) the surface is expected to face there: the fused normal turned 45 degrees
        outwards, summed). Borders whose outward side lies on the static scene (the fixture) are left out."""
        self.update(grid)
        weight = np.zeros(grid.n_voxels)
        direction = np.zeros((grid.n_voxels, 3))
        raw = grid.raw
        if len(raw) == 0:
            return weight, direction
        cell = self.model.coverage_radius_m / 2.0
        keys = np.floor(raw.xyz_m / cell).astype(np.int64)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        counts = np.bincount(inverse)
        xyz = np.stack([np.bincount(inverse, raw.xyz_m[:, a]) for a in range(3)], axis=1) / counts[:, None]
        nrm = np.stack([np.bincount(inverse, raw.normal[:, a]) for a in range(3)], axis=1)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        ok = length[:, 0] > 1e-9
        xyz, nrm = xyz[ok], nrm[ok] / length[ok]
        border, outward = open_edges(xyz, nrm, 2.0 * self.model.coverage_radius_m)
        border &= np.linalg.norm(outward, axis=1) > 0.5
        beyond = xyz + outward * self.model.coverage_radius_m
        border[border] &= ~grid.on_static_scene(beyond[border])
        if not border.any():
            return weight, direction
        spacing = [np.median(v.spacing_m) for v in self.views.values() if len(v.spacing_m)]
        area = (float(np.mean(spacing)) if spacing else cell) * 2.0 * self.model.coverage_radius_m
        idx = np.floor((xyz[border] - grid.origin_m) / grid.resolution_m).astype(np.int64)
        inside = grid.in_grid(idx)
        flat = grid.flat_index(idx[inside])
        np.add.at(weight, flat, area / grid.resolution_m**2)
        turned = nrm[border][inside] + outward[border][inside]
        np.add.at(direction, flat, turned / np.linalg.norm(turned, axis=1, keepdims=True))
        return weight, direction


def open_edges(xyz_m: np.ndarray, normals: np.ndarray, radius_m: float, neighbours: int = 16,
               min_gap_rad: float = 0.6 * math.pi, crease_rad: float = math.pi / 4) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The fused points on an open border of the seen surface: (mask (N,), outward direction (N, 3) in the
    tangent plane). A point is on the border when its neighbours within ``radius_m``, projected on its tangent plane
    (normal ``normals``), leave an angular gap wider than ``min_gap_rad`` (or when fewer than 3 are that near);
    the outward direction bisects the widest gap. A fold seen from both sides is no border: a point with a
    neighbour whose normal turns more than ``crease_rad`` away from its own is never one."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    n = len(xyz)
    if n == 0:
        return np.zeros(0, bool), np.zeros((0, 3))
    k = min(neighbours, n - 1)
    if k < 1:
        return np.ones(n, bool), np.zeros((n, 3))
    dist, idx = cKDTree(xyz).query(xyz, k=k + 1, distance_upper_bound=radius_m)
    dist, idx = dist[:, 1:], idx[:, 1:]
    near = np.isfinite(dist)
    nrm = np.asarray(normals, dtype=np.float64)
    # a tangent basis per point
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = np.cross(nrm, helper)
    b1 /= np.maximum(np.linalg.norm(b1, axis=1, keepdims=True), 1e-12)
    b2 = np.cross(nrm, b1)
    offsets = xyz[np.where(near, idx, 0)] - xyz[:, None, :]
    angle = np.arctan2(np.einsum("nkj,nj->nk", offsets, b2), np.einsum("nkj,nj->nk", offsets, b1))
    angle = np.sort(np.where(near, angle, np.inf), axis=1)
    count = near.sum(axis=1)
    first = angle[:, 0]
    last = np.take_along_axis(angle, np.maximum(count - 1, 0)[:, None], axis=1)[:, 0]
    gaps = np.diff(np.where(np.isfinite(angle), angle, np.nan), axis=1)
    gaps = np.where(np.isnan(gaps), -1.0, gaps)
    inner = gaps.max(axis=1) if gaps.shape[1] else np.full(n, -1.0)
    with np.errstate(invalid="ignore"):  # no neighbour at all: inf - inf (such a point is a border anyway)
        wrap = first + 2 * math.pi - last
    widest = np.maximum(inner, wrap)
    # a neighbour facing another way (a fold of the surface, both faces seen): the surface goes on there
    crease = (near & (np.einsum("nkj,nj->nk", nrm[np.where(near, idx, 0)], nrm) < math.cos(crease_rad))).any(axis=1)
    border = ((count < 3) | (widest > min_gap_rad)) & ~crease
    # the bisector of the widest gap
    j = np.argmax(gaps, axis=1) if gaps.shape[1] else np.zeros(n, int)
    lo = np.take_along_axis(angle, j[:, None], axis=1)[:, 0]
    mid = np.where(wrap >= inner, last + 0.5 * wrap, lo + 0.5 * np.maximum(inner, 0.0))
    mid = np.where(np.isfinite(mid), mid, 0.0)
    out = np.cos(mid)[:, None] * b1 + np.sin(mid)[:, None] * b2
    out[count < 3] = 0.0
    return border, out
