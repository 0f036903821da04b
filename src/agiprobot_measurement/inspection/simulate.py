"""Scanning an actual part with the project's simulated scanners (PhoXi structured light, laser line sweeps).

The simulators take the *actual* mesh placed in the world; inspection later sees only the nominal CAD, the
cloud and the planned placement. Views are directions from the part towards the sensor; the sensor stands at
its sweet spot / optimal standoff along that direction and looks at ``target_mm``. Points in mm, world frame;
each point carries its 1-sigma noise (mm) from the simulator's error model, projected on the surface normal
(the simulators displace points along the sensor's ray; a deviation is measured along the normal, so the
stated sigma along the ray times |cos(ray, normal)| is the sigma of the point's signed deviation).

``error_model`` names a configuration of ``config/error_models/`` (``ideal`` = noise only, ``realistic`` = the
scanners' calibration, fixed-pattern, material, edge and -- for the laser head -- hand-eye and repeatability
errors, see docs/sensor-errors.md) or is None (noise only); ``serial`` names the simulated device, whose
per-device errors are drawn from it. The laser head is moved along ideal straight sweeps (no robot): of its pose
chain only the hand-eye error and one repeatability draw per sweep apply. With the realistic laser, the points'
sigma is the error model's noise (depth and incidence dependent) instead of the planning model's ``u``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from agiprobot_measurement.inspection.deviation import closest_points
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.sensors.error_models import ErrorModel, LaserErrors, PhoxiErrors, load_error_model
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator, pose_chain_poses
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_HIGH, RESOLUTION_LOW
from agiprobot_measurement.sensors.phoxi.renderer import (
    ScanSettings,
    SceneGeometry,
    StructuredLightScanner,
    load_scanner_model,
)
from agiprobot_measurement.station.config import load_scanner_config

__all__ = ["ScannedCloud", "look_at", "scan_laser", "scan_phoxi"]


@dataclass
class ScannedCloud:
    """Measured points (N, 3, mm, world) and their 1-sigma noise (N, mm) as the simulator's model states it."""

    points_mm: np.ndarray
    sigma_mm: np.ndarray
    sensor: str

    def __len__(self) -> int:
        return len(self.points_mm)


def look_at(eye_mm, target_mm, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World <- sensor pose (4x4, mm): z from ``eye`` to ``target``, x perpendicular to ``up``."""
    eye, target = np.asarray(eye_mm, float), np.asarray(target_mm, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = eye
    return pose


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ray_cosines(mesh_world_mm, points_mm, origins_mm) -> np.ndarray:
    """|cos| of the angle between each point's ray (from its origin) and the nearest face's normal."""
    if not len(points_mm):
        return np.zeros(0)
    cp = closest_points(mesh_world_mm, points_mm)
    normals = np.asarray(mesh_world_mm.face_normals)[cp.face]
    rays = points_mm - origins_mm
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    return np.abs(np.einsum("ij,ij->i", rays, normals))


def _error_model(error_model):
    """None, an :class:`ErrorModel` or its name / file -> None or the model."""
    return error_model if error_model is None or isinstance(error_model, ErrorModel) else load_error_model(error_model)


def scan_phoxi(mesh_world_mm, view_directions, target_mm=(0.0, 0.0, 0.0), model: str = "S", high_resolution=False,
               seed: int = 0, noise: bool = True, error_model=None, serial: str = "sim-0") -> ScannedCloud:  # fmt: skip
    """One PhoXi frame per view direction at the model's sweet spot, merged; noise along the camera rays.
    The camera is rolled so that its projector lies above or below it (side faces lit alike)."""
    scanner_model = load_scanner_model(model)
    errors = PhoxiErrors.create(scanner_model, serial, _error_model(error_model))
    scanner = StructuredLightScanner(scanner_model, workers=1, errors=errors)
    # metres before building the scene: a scaling ``transformed`` would scale the face normals too (the material
    # block reads them as unit vectors)
    mesh_m = trimesh.Trimesh(np.asarray(mesh_world_mm.vertices) * 1e-3, mesh_world_mm.faces, process=False)
    geometry = SceneGeometry.from_trimesh(mesh_m, "part", 0.8)
    settings = ScanSettings(resolution=RESOLUTION_HIGH if high_resolution else RESOLUTION_LOW, noise=noise, seed=seed,
                            confidence=0.0)  # fmt: skip
    points, sigmas, origins = [], [], []
    for index, direction in enumerate(np.atleast_2d(view_directions)):
        eye = np.asarray(target_mm, float) + scanner_model.sweet_spot_mm * _unit(direction)
        # the camera's x axis (towards the projector) in the vertical plane of the view: side faces lit alike
        horizontal = np.cross(_unit(direction), [0.0, 0.0, 1.0])
        pose_m = look_at(eye, target_mm, up=horizontal if np.linalg.norm(horizontal) > 1e-6 else (0.0, 1.0, 0.0))
        pose_m[:3, 3] *= 1e-3
        frame = scanner.capture(geometry, pose_m, settings, frame_index=index)
        valid = frame.valid
        camera = np.asarray(frame.points_m(), float)[valid]
        points.append((camera @ pose_m[:3, :3].T + pose_m[:3, 3]) * 1e3)
        # the depth noise sigma_z moves a point along its pixel ray (u, v, 1): |ray| sigma_z along the unit ray
        ray_length = np.linalg.norm(frame.intrinsics.pixel_rays().reshape(frame.height, frame.width, 3), axis=2)
        sigmas.append((np.asarray(frame.confidence, float) * ray_length)[valid].reshape(-1))
        origins.append(np.repeat(eye[None], int(valid.sum()), axis=0))
    cloud = np.vstack(points)
    sigma = np.concatenate(sigmas) * _ray_cosines(mesh_world_mm, cloud, np.vstack(origins))
    return ScannedCloud(cloud, sigma, f"phoxi_{model}")


def scan_laser(mesh_world_mm, view_direction, sweep_direction, length_mm: float, target_mm=(0.0, 0.0, 0.0),
               step_mm: float = 0.2, seed: int = 0, noise_scale: float = 1.0, offset_mm=(0.0, 0.0, 0.0), error_model=None,
               serial: str | None = None) -> ScannedCloud:  # fmt: skip
    """One straight laser sweep of ``length_mm`` centred on ``target_mm + offset_mm``: the boresight along
    ``-view_direction`` at the optimal standoff, the emitter moving along ``sweep_direction`` (its x axis)."""
    model = SensorModel(load_scanner_config().sensor_parameters)
    errors = LaserErrors.create(model, _error_model(error_model), serial)
    simulator = LaserLineScannerSimulator(model, seed=seed, noise_scale=noise_scale, errors=errors)
    simulator.set_target(mesh_world_mm)
    z = -_unit(view_direction)
    x = np.asarray(sweep_direction, float) - (np.asarray(sweep_direction, float) @ z) * z
    if np.linalg.norm(x) < 1e-6:
        raise InspectionInputError("the sweep direction must not be parallel to the view direction")
    x /= np.linalg.norm(x)
    rotation = np.column_stack([x, np.cross(z, x), z])
    centre = np.asarray(target_mm, float) + np.asarray(offset_mm, float) - model.optimal_standoff * z
    steps = np.arange(-length_mm / 2, length_mm / 2 + 1e-9, step_mm)
    poses = np.repeat(np.eye(4)[None], len(steps), axis=0)
    poses[:, :3, :3] = rotation
    poses[:, :3, 3] = centre + steps[:, None] * x
    true_poses = poses
    if errors is not None and errors.pose_chain is not None:
        # hand-eye error on every profile, one repeatability draw for the whole (continuous) sweep
        first, _ = pose_chain_poses(errors, poses[:1], poses[:1], np.eye(4), rng=np.random.default_rng(seed))
        true_poses = poses @ errors.hand_eye_error
        true_poses[:, :3, 3] += first[0, :3, 3] - true_poses[0, :3, 3]
    profiles = simulator.profiles(true_poses, poses if true_poses is not poses else None)
    kept = [(k, p) for k, p in enumerate(profiles) if len(p)]
    if not kept:
        return ScannedCloud(np.zeros((0, 3)), np.zeros(0), "laser_line")
    cloud = np.vstack([p.points_mm for _, p in kept])
    origins = np.vstack([np.repeat(poses[k, :3, 3][None], len(p), axis=0) for k, p in kept])
    cosines = _ray_cosines(mesh_world_mm, cloud, origins)
    # sigma along the ray: the error model's noise (depth and incidence dependent, not scaled) or the planning u
    scale = 1.0 if errors is not None and errors.noise is not None else noise_scale
    sigma_ray = np.concatenate([p.uncertainties_mm for _, p in kept]) * scale
    return ScannedCloud(cloud, sigma_ray * cosines, "laser_line")
