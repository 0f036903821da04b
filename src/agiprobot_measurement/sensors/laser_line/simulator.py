"""Simulated laser line scanner: one profile = the laser fan cast against the part from the emitter pose.

The same geometry and rules as the sensor model (:mod:`agiprobot_measurement.sensors.laser_line.model`): the fan spans the
emitter frame's y-z plane with the sensor's fan angle, z is the boresight and x the scan direction; the
detector sits ``tan(alpha) * optimal_standoff`` behind the emitter along -x. A fan ray's first hit on the part
is measured when the detector sees it too, it faces the emitter, ``z``, ``psi`` and ``theta`` lie within the
sensor's limits, and it then gets the model's uncertainty ``u(z, psi) * |s . n|``; the measured point is
displaced along the laser ray by Gaussian noise of that standard deviation (seeded).

Everything here is in mm and in the world frame; the ROS node converts to metres.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from agiprobot_measurement.sensors.errors import SensorInputError, SensorStateError
from agiprobot_measurement.sensors.laser_line.model import SensorModel

__all__ = [
    "LaserLineScannerSimulator",
    "Profile",
    "StitchedCloud",
    "measured_samples",
    "voxel_thin",
]


@dataclass(frozen=True)
class Profile:
    """Measured points of one profile (mm, world), their uncertainties (mm) and the true surface points;
    ``ray_indices``: which fan ray (0 .. points_per_profile - 1, from the fan's -y edge to its +y edge) measured
    each point (None when unknown)."""

    points_mm: np.ndarray
    uncertainties_mm: np.ndarray
    true_points_mm: np.ndarray
    ray_indices: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points_mm.shape[0])


class LaserLineScannerSimulator:
    """Casts laser fans against a target mesh (mm, world) and applies the sensor model's visibility rules."""

    def __init__(
        self,
        sensor_model: SensorModel,
        points_per_profile: int = 640,
        seed: int | None = 0,
        noise_scale: float = 1.0,
        occlusion_tolerance_mm: float = 0.05,
    ):
        if not (np.isfinite(noise_scale) and noise_scale >= 0):
            raise SensorInputError(f"noise_scale must be >= 0, got {noise_scale}")
        self.sensor = sensor_model
        self.noise_scale = float(noise_scale)
        self.occlusion_tolerance_mm = float(occlusion_tolerance_mm)
        self.rng = np.random.default_rng(seed)
        self.set_points_per_profile(points_per_profile)
        self.detector_offset_mm = np.tan(sensor_model.alpha) * sensor_model.optimal_standoff
        self.mesh: trimesh.Trimesh | None = None

    def set_points_per_profile(self, points_per_profile: int) -> None:
        """The number of fan rays (the profile's resolution), spread evenly over the fan angle."""
        if int(points_per_profile) < 2:
            raise SensorInputError(f"points_per_profile must be >= 2, got {points_per_profile}")
        self.points_per_profile = int(points_per_profile)
        half = 0.5 * self.sensor.fan_angle
        #: the fan rays' angles from the boresight towards +y of the emitter frame (rad)
        self.fan_angles_rad = np.linspace(-half, half, self.points_per_profile)
        # fan directions in the emitter frame: in its y-z plane, around the boresight z
        angles = self.fan_angles_rad
        self._fan = np.stack([np.zeros_like(angles), np.sin(angles), np.cos(angles)], axis=1)

    def set_target(self, mesh_mm: trimesh.Trimesh) -> None:
        """The surface to scan (mm, world). Normals must point outwards (as loaded parts' do)."""
        if not isinstance(mesh_mm, trimesh.Trimesh) or len(mesh_mm.faces) == 0:
            raise SensorInputError("the scan target must be a non-empty trimesh.Trimesh")
        self.mesh = mesh_mm
        # the Embree intersector works in float32: shift the part near the origin for its precision
        self._offset = np.asarray(mesh_mm.bounds.mean(axis=0))
        shifted = trimesh.Trimesh(np.asarray(mesh_mm.vertices) - self._offset, np.asarray(mesh_mm.faces), process=False)
        self._intersector = shifted.ray
        self._normals = np.asarray(mesh_mm.face_normals)

    def _first_hits(self, origins: np.ndarray, directions: np.ndarray):
        faces, rays, locations = self._intersector.intersects_id(
            origins - self._offset, directions, multiple_hits=False, return_locations=True
        )
        return np.asarray(faces), np.asarray(rays), np.asarray(locations) + self._offset

    def profile(self, emitter_pose_mm: np.ndarray) -> Profile:
        """The profile measured with the laser_emitter_frame at ``emitter_pose_mm`` (4x4, world, mm)."""
        return self.profiles(np.asarray(emitter_pose_mm, dtype=float)[None])[0]

    def profiles(self, emitter_poses_mm: np.ndarray) -> list[Profile]:
        """Profiles for many emitter poses (K, 4, 4) at once: all rays of all profiles in one batch."""
        if self.mesh is None:
            raise SensorStateError("no scan target: call set_target(mesh) first")
        poses = np.asarray(emitter_poses_mm, dtype=float).reshape(-1, 4, 4)
        if not np.all(np.isfinite(poses)):
            raise SensorInputError("emitter poses must be finite 4x4 matrices")
        k, n = poses.shape[0], self.points_per_profile
        rotations, emitters = poses[:, :3, :3], poses[:, :3, 3]
        directions = np.einsum("kij,nj->kni", rotations, self._fan).reshape(-1, 3)
        origins = np.repeat(emitters, n, axis=0)
        profile_of_ray = np.repeat(np.arange(k), n)
        faces, rays, hits = self._first_hits(np.ascontiguousarray(origins), np.ascontiguousarray(directions))
        which = profile_of_ray[rays]
        normals = self._normals[faces]
        ray_dirs = directions[rays]
        t_axis, l_axis, s_axis = (rotations[which][:, :, axis] for axis in range(3))
        emitter = emitters[which]
        offset = hits - emitter
        z = np.einsum("ij,ij->i", offset, s_axis)
        facing = np.einsum("ij,ij->i", ray_dirs, normals) < 0.0
        s_dot_n = np.einsum("ij,ij->i", normals, s_axis)
        psi = np.arctan2(np.einsum("ij,ij->i", normals, t_axis), -s_dot_n)
        v1 = np.stack([np.einsum("ij,ij->i", offset, l_axis), z], axis=1)
        v2 = np.stack([np.einsum("ij,ij->i", normals, l_axis), s_dot_n], axis=1)
        cos_theta = -np.einsum("ij,ij->i", v1, v2) / np.maximum(
            np.linalg.norm(v1, axis=1) * np.linalg.norm(v2, axis=1), 1e-12
        )
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
        sensor = self.sensor
        ok = (
            facing
            & (z > sensor.minimum_standoff)
            & (z < sensor.maximum_standoff)
            & (np.abs(psi) < sensor.psi_max)
            & (theta < sensor.theta_max)
        )
        hits, normals, psi, z, s_dot_n, ray_dirs, which, t_axis = (
            a[ok] for a in (hits, normals, psi, z, s_dot_n, ray_dirs, which, t_axis)
        )
        # the detector must see the lit point: nothing on the segment detector -> point
        detector = emitters[which] - self.detector_offset_mm * t_axis
        to_point = hits - detector
        distance = np.linalg.norm(to_point, axis=1)
        visible = np.zeros(len(hits), dtype=bool)
        if len(hits):
            det_dirs = to_point / distance[:, None]
            _, rays_d, hits_d = self._first_hits(np.ascontiguousarray(detector), det_dirs)
            first = np.full(len(hits), np.inf)
            if len(rays_d):
                first[rays_d] = np.linalg.norm(hits_d - detector[rays_d], axis=1)
            visible = (first >= distance - self.occlusion_tolerance_mm) & (np.einsum("ij,ij->i", det_dirs, normals) < 0)
        ray_in_profile = (rays % n)[ok][visible]
        hits, psi, z, s_dot_n, ray_dirs, which = (a[visible] for a in (hits, psi, z, s_dot_n, ray_dirs, which))
        uncertainty = sensor.evaluate_uncertainty(z, psi) * np.abs(s_dot_n) if len(hits) else np.zeros(0)
        noise = self.rng.normal(0.0, 1.0, len(hits)) * uncertainty * self.noise_scale
        measured = hits + noise[:, None] * ray_dirs
        order = np.argsort(which, kind="stable")
        bounds = np.searchsorted(which[order], np.arange(k + 1))
        return [
            Profile(measured[order[a:b]], uncertainty[order[a:b]], hits[order[a:b]], ray_in_profile[order[a:b]])
            for a, b in itertools.pairwise(bounds)
        ]


def measured_samples(samples_mm: np.ndarray, measured_points_mm: np.ndarray, radius_mm: float = 1.0) -> np.ndarray:
    """Boolean per sample point: a measured point lies within ``radius_mm`` of it."""
    samples = np.asarray(samples_mm, dtype=float).reshape(-1, 3)
    measured = np.asarray(measured_points_mm, dtype=float).reshape(-1, 3)
    if len(samples) == 0 or len(measured) == 0:
        return np.zeros(len(samples), dtype=bool)
    distance, _ = cKDTree(measured).query(samples, k=1, distance_upper_bound=radius_mm)
    return np.isfinite(distance)


def voxel_thin(points_mm: np.ndarray, voxel_mm: float) -> np.ndarray:
    """The first point of each ``voxel_mm`` cube, in the points' order (for display: a dense cloud thinned to
    about one point per voxel); all points when ``voxel_mm`` <= 0."""
    points = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    if not len(points) or voxel_mm <= 0:
        return points
    keys = np.floor(points / voxel_mm).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


class StitchedCloud:
    """The profiles stitched since the last :meth:`clear`: their count and their measured points (mm)."""

    def __init__(self):
        self.chunks: list[np.ndarray] = []
        self.profiles = 0

    def clear(self) -> None:
        self.chunks = []
        self.profiles = 0

    def add(self, profiles) -> None:
        """Add :class:`Profile` s; empty ones count but add no points."""
        for profile in profiles:
            if len(profile):
                self.chunks.append(profile.points_mm)
        self.profiles += len(profiles)

    def points(self) -> np.ndarray:
        """(N, 3) every measured point, mm."""
        return np.vstack(self.chunks) if self.chunks else np.zeros((0, 3))
