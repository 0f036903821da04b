"""Simulated laser line scanner: one profile = the laser fan cast against the part from the emitter pose.

The same geometry and rules as the sensor model (:mod:`agiprobot_measurement.sensors.laser_line.model`): the fan spans the
emitter frame's y-z plane with the sensor's fan angle, z is the boresight and x the scan direction; the
detector sits ``tan(alpha) * optimal_standoff`` behind the emitter along -x. A fan ray's first hit on the part
is measured when the detector sees it too, it faces the emitter, ``z``, ``psi`` and ``theta`` lie within the
sensor's limits, and it then gets the model's uncertainty ``u(z, psi) * |s . n|``; the measured point is
displaced along the laser ray by Gaussian noise of that standard deviation (seeded).

With an error model (``errors``: :class:`~agiprobot_measurement.sensors.error_models.LaserErrors`) the measured
point is instead reconstructed with the nominal triangulation geometry from what the true head saw (calibration
error), displaced along the ray by the measurement noise (static speckle + temporal, growing with depth and
incidence; with a ``noise`` block its sigma along the ray is the reported uncertainty, not the planning ``u``),
dropped when the signal is too weak or saturated (material), mixed at depth jumps along the line (edges), and
reported through the nominal pose when the caller passes one (pose chain: :func:`pose_chain_poses`). See ``docs/sensor-errors.md``.

Everything here is in mm and in the world frame; the ROS node converts to metres.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from agiprobot_measurement.sensors.error_models import LaserErrors, value_noise
from agiprobot_measurement.sensors.errors import SensorInputError, SensorStateError
from agiprobot_measurement.sensors.laser_line.model import SensorModel

__all__ = [
    "LaserLineScannerSimulator",
    "Profile",
    "StitchedCloud",
    "measured_samples",
    "pose_chain_poses",
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
        errors: LaserErrors | None = None,
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
        #: the head's realised error models (None: the planning model's noise only, ``noise_scale``)
        self.errors = errors
        #: the target's material (albedo, specular_share) overriding the error model's, or None
        self.material: dict | None = None

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

    def set_target(self, mesh_mm: trimesh.Trimesh, material: dict | None = None) -> None:
        """The surface to scan (mm, world). Normals must point outwards (as loaded parts' do). ``material``:
        ``albedo`` and/or ``specular_share`` of this part (else the error model's)."""
        self.material = dict(material) if material else None
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

    def profiles(self, emitter_poses_mm: np.ndarray, reported_poses_mm: np.ndarray | None = None) -> list[Profile]:
        """Profiles for many emitter poses (K, 4, 4) at once: all rays of all profiles in one batch.

        ``reported_poses_mm`` (K, 4, 4): where the station believes the emitter was (the nominal tf); the points,
        measured from the true ``emitter_poses_mm``, are then reported through it (the pose-chain error)."""
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
        if self.errors is None:
            noise = self.rng.normal(0.0, 1.0, len(hits)) * uncertainty * self.noise_scale
            measured = hits + noise[:, None] * ray_dirs
        else:
            normals_v = normals[visible]
            keep, measured = self._measure_with_errors(
                poses, which, hits, normals_v, ray_dirs, z, ray_in_profile, detector[visible]
            )
            if self.errors.noise is not None:  # the error model's noise along the ray, not the planning u
                cos_inc = -np.einsum("ij,ij->i", ray_dirs, normals_v)
                uncertainty = self.errors.sigma_mm(z, cos_inc, sensor.optimal_standoff)
            hits, uncertainty, which, ray_in_profile, measured = (
                a[keep] for a in (hits, uncertainty, which, ray_in_profile, measured)
            )
        if reported_poses_mm is not None and len(hits):
            reported = np.asarray(reported_poses_mm, dtype=float).reshape(k, 4, 4)
            change = reported @ np.linalg.inv(poses)  # true emitter -> reported emitter, per profile
            measured = np.einsum("kij,kj->ki", change[which, :3, :3], measured) + change[which, :3, 3]
        order = np.argsort(which, kind="stable")
        bounds = np.searchsorted(which[order], np.arange(k + 1))
        return [
            Profile(measured[order[a:b]], uncertainty[order[a:b]], hits[order[a:b]], ray_in_profile[order[a:b]])
            for a, b in itertools.pairwise(bounds)
        ]

    def _measure_with_errors(self, poses, which, hits, normals, ray_dirs, z, ray_index, detector):
        """(kept mask, measured points) of the visible hits under the error model (see the module docstring)."""
        errors, sensor = self.errors, self.sensor
        emitters = poses[which, :3, 3]
        ranges = np.linalg.norm(hits - emitters, axis=1)
        cos_inc = -np.einsum("ij,ij->i", ray_dirs, normals)
        keep = np.ones(len(hits), dtype=bool)
        material = errors.material
        if material is not None and len(hits):
            part = {**material, **(self.material or {})}
            share = float(part["specular_share"])
            to_det = detector - hits
            to_det /= np.maximum(np.linalg.norm(to_det, axis=1), 1e-12)[:, None]
            mirror = ray_dirs - 2.0 * np.einsum("ij,ij->i", ray_dirs, normals)[:, None] * normals
            lobe = np.maximum(np.einsum("ij,ij->i", mirror, to_det), 0.0) ** material["specular_exponent"]
            ratio = sensor.optimal_standoff / z
            signal = part["albedo"] * (1.0 - share) * np.maximum(cos_inc, 0.0) * ratio * ratio
            signal += share * material["specular_peak"] * lobe
            keep &= (signal >= material["min_signal"]) & (signal <= material["saturation"])
        fan = self.fan_angles_rad[ray_index]
        if errors.calibration is not None:
            baseline = np.tan(sensor.alpha) * sensor.optimal_standoff
            ranges, fan = errors.calibration.reconstruct(ranges, fan, baseline, sensor.alpha)
        if errors.noise is not None and len(hits):
            temporal, speckle = errors.noise_parts_mm(z, cos_inc, sensor.optimal_standoff)
            field = value_noise(hits, errors.noise["speckle_correlation_mm"], errors.speckle_seed)
            ranges = ranges + speckle * field + temporal * self.rng.normal(0.0, 1.0, len(hits))
        if errors.edges is not None and len(hits):
            ranges = _mix_line_edges(
                ranges, which, ray_index, errors.edges["jump_mm"], errors.edges["probability"], self.rng
            )
        local = np.stack([np.zeros_like(fan), np.sin(fan), np.cos(fan)], axis=1) * ranges[:, None]
        measured = np.einsum("kij,kj->ki", poses[which, :3, :3], local) + emitters
        return keep, measured


def pose_chain_poses(
    errors: LaserErrors | None,
    true_flange_mm: np.ndarray,
    nominal_flange_mm: np.ndarray,
    mount_mm: np.ndarray,
    velocity_mm_s: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(true, reported) emitter poses (K, 4, 4) of a robot-carried head: the true flange (the true robot's forward
    kinematics, e.g. ``TrueKinematics.fk``) with the true mount (``mount_mm`` times the head's hand-eye error) and
    per-move jitter (repeatability), against the nominal flange (the model's kinematics, the tf) with the nominal
    mount, read ``latency_s`` later (``velocity_mm_s``: (3,) or (K, 3) world velocity of the flange). All mm."""
    true_flange = np.asarray(true_flange_mm, dtype=float).reshape(-1, 4, 4)
    nominal = np.asarray(nominal_flange_mm, dtype=float).reshape(-1, 4, 4)
    mount = np.asarray(mount_mm, dtype=float)
    reported = nominal @ mount
    chain = errors.pose_chain if errors is not None else None
    if chain is None:
        return true_flange @ mount, reported
    true = true_flange @ mount @ errors.hand_eye_error
    if chain["repeatability_mm"] > 0.0:
        rng = rng or np.random.default_rng(0)
        true = true.copy()
        true[:, :3, 3] += rng.normal(0.0, chain["repeatability_mm"], (len(true), 3))
    if velocity_mm_s is not None and chain["latency_s"] > 0.0:
        reported = reported.copy()
        reported[:, :3, 3] += np.asarray(velocity_mm_s, dtype=float) * chain["latency_s"]
    return true, reported


def measured_samples(samples_mm: np.ndarray, measured_points_mm: np.ndarray, radius_mm: float = 1.0) -> np.ndarray:
    """Boolean per sample point: a measured point lies within ``radius_mm`` of it."""
    samples = np.asarray(samples_mm, dtype=float).reshape(-1, 3)
    measured = np.asarray(measured_points_mm, dtype=float).reshape(-1, 3)
    if len(samples) == 0 or len(measured) == 0:
        return np.zeros(len(samples), dtype=bool)
    distance, _ = cKDTree(measured).query(samples, k=1, distance_upper_bound=radius_mm)
    return np.isfinite(distance)


def _mix_line_edges(ranges, which, rays, jump_mm, probability, rng):
    """Mixed points along the line: a point whose neighbouring fan ray (same profile) lies more than ``jump_mm``
    away in range sees both surfaces; with ``probability`` its range becomes a uniform mix of the two."""
    order = np.lexsort((rays, which))
    r, w, q = ranges[order], which[order], rays[order]
    neighbour = (w[1:] == w[:-1]) & (q[1:] == q[:-1] + 1)
    step = r[1:] - r[:-1]
    edge = neighbour & (np.abs(step) > jump_mm) & (rng.random(len(step)) < probability)
    mixed = r.copy()
    mixed[:-1] = np.where(edge, r[:-1] + rng.random(len(step)) * step, r[:-1])
    out = np.empty_like(ranges)
    out[order] = mixed
    return out


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
