"""The VDI/VDE 2634 Part 2 acceptance test in simulation: PhoXi S, M, L and the laser line scanner.

Each scanner measures the guideline's artefacts at their positions (sphere: PF, PS; dumbbell: SD; plane: F; one
view each) with the configured error model, then the results are judged against the per-scanner expectations of
``config/error_models/acceptance.yaml``; the laser adds a robot-registered multi-sweep length test
(:mod:`benchmarks.acceptance.multi_sweep`). ``positions`` limits the positions per artefact (the CI-sized test
takes 3).

  python -m benchmarks.acceptance                           # all scanners, realistic error model
  python -m benchmarks.acceptance --scanners S laser --positions 3 --error-model ideal
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from agiprobot_measurement.sensors.acceptance import (
    AcceptanceSpec,
    dumbbell_positions,
    evaluate_dumbbell,
    evaluate_plane,
    evaluate_sphere,
    plane_positions,
    sphere_positions,
)
from agiprobot_measurement.sensors.error_models import ErrorModel, LaserErrors, PhoxiErrors, load_error_model
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator
from agiprobot_measurement.sensors.phoxi.models import load_scanner_model
from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, StructuredLightScanner
from agiprobot_measurement.sensors.phoxi.scene_geometry import SceneGeometry
from agiprobot_measurement.station import load_scanner_config

__all__ = ["judge", "run_laser", "run_phoxi", "run_scanner"]

#: albedo of the artefacts (the guideline's optically cooperative, diffuse matt surface)
ARTEFACT_ALBEDO = 0.8


def _transformed(mesh, pose):
    out = mesh.copy()
    out.apply_transform(pose)
    return out


def _dumbbell_meshes(spec: AcceptanceSpec, pose: np.ndarray, diameter: float, length: float):
    art = spec.artefacts
    meshes, centres = [], []
    for sign in (-0.5, 0.5):
        local = np.eye(4)
        local[0, 3] = sign * length
        world = pose @ local
        meshes.append(_transformed(art.sphere_mesh(diameter), world))
        centres.append(world[:3, 3])
    return meshes, np.array(centres)


def _split(points: np.ndarray, centres: np.ndarray, radius: float, screen: float, mask: bool = False):
    """Points of each sphere (or their masks): nearest centre, within ``screen`` of its nominal surface."""
    d = np.linalg.norm(points[:, None, :] - centres[None], axis=2)
    nearest = np.argmin(d, axis=1)
    near = np.abs(d[np.arange(len(points)), nearest] - radius) < screen
    masks = [(nearest == i) & near for i in range(len(centres))]
    return masks if mask else [points[m] for m in masks]


def _plane_points(points: np.ndarray, pose: np.ndarray, size, screen: float, border: float):
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    inside = (np.abs(local[:, 0]) < 0.5 * size[0] - border) & (np.abs(local[:, 1]) < 0.5 * size[1] - border)
    return points[inside & (np.abs(local[:, 2]) < screen)], inside & (np.abs(local[:, 2]) < screen)


# ------------------------------------------------------------------------------------------------- PhoXi
class _PhoxiRig:
    def __init__(self, spec: AcceptanceSpec, error_model: ErrorModel, seed: int):
        self.spec = spec
        self.model = load_scanner_model(spec.model)
        serial = str(spec.settings.get("serial", "PhoXi3DScanner-sim"))
        self.scanner = StructuredLightScanner(self.model, errors=PhoxiErrors.create(self.model, serial, error_model))
        self.settings = ScanSettings(resolution=int(spec.settings.get("resolution", 1)), seed=seed)
        self.frame_index = 0
        self.screen = max(2.0, 20.0 * self.model.temporal_noise_mm)
        # leave the plane's rim (mixed pixels at its edges) out: 12 high-resolution point spacings
        self.plane_border = 12.0 * self.model.scan_area_mm[0] / self.model.resolutions[1][0]

    def measure(self, meshes_mm):
        """(points (N, 3) mm, configured sigma along the surface normal (N,) mm) of one frame of the meshes."""
        points, sigma, _ = self.capture(meshes_mm)
        return points, sigma

    def capture(self, meshes_mm, settings=None):
        parts = []
        for mesh in meshes_mm:
            metres = mesh.copy()
            metres.apply_scale(0.001)
            parts.append(SceneGeometry.from_trimesh(metres, "artefact", ARTEFACT_ALBEDO))
        frame = self.scanner.capture(SceneGeometry.concatenate(parts), np.eye(4), settings or self.settings,
                                     self.frame_index)  # fmt: skip
        self.frame_index += 1
        valid = frame.valid
        points = frame.points_m()[valid].astype(float) * 1000.0
        # the configured noise is along the pixel ray; the residuals are taken along the surface normal
        cos = np.abs(np.einsum("ij,ij->i", frame.normals[valid], points)) / np.linalg.norm(points, axis=1)
        return points, frame.confidence[valid].astype(float) * cos, frame


def _average_plane(rig: _PhoxiRig, frames: int) -> dict:
    """Mean of ``frames`` frames of a wall at each of 5 depths over the scanning range (the maker's definition of the
    calibration accuracy: planes at several distances): RMS deviation of the means from the true walls, and the
    residual sigma to the LS planes. The camera has 4x fewer pixels per side (same field, same device errors): the
    floor is a property of the device, not of the pixel count, and 80 frames stay cheap."""
    import trimesh

    model = rig.model
    width, height = model.resolutions[1]
    camera = replace(model, resolutions={1: (width // 4, height // 4), 0: (width // 8, height // 8)})
    scanner = StructuredLightScanner(camera, errors=rig.scanner.errors)
    low, high = model.scanning_range_mm
    margin = 0.05 * (high - low)
    deviations, sigmas, count = [], [], 0
    for depth in np.linspace(low + margin, high - margin, 5):
        wall = trimesh.creation.box([4.0 * depth, 4.0 * depth, 10.0])
        wall.apply_translation([0.0, 0.0, depth + 5.0])
        wall.apply_scale(0.001)
        geometry = SceneGeometry.from_trimesh(wall, "wall", ARTEFACT_ALBEDO)
        settings = replace(rig.settings, resolution=1)
        stack = np.array([scanner.capture(geometry, np.eye(4), settings, i).depth_mm for i in range(frames)])
        valid = np.all(stack > 0.0, axis=0)
        mean = stack.mean(axis=0)[valid]
        rays = camera.intrinsics(1).pixel_rays().reshape(stack.shape[1], stack.shape[2], 3)[valid]
        deviations.append(mean - depth)
        sigmas.append(evaluate_plane(rays * mean[:, None])["sigma"])
        count += int(valid.sum())
    return {
        "artefact": "average",
        "position": 0,
        "z": float(np.mean([low, high])),
        "frames": frames,
        "rms_vs_true": float(np.sqrt(np.mean(np.square(np.concatenate(deviations))))),
        "sigma": float(np.sqrt(np.mean(np.square(sigmas)))),
        "points": count,
    }


def _tilt(pose: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(-pose[2, 2], -1.0, 1.0))))


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")


def _plain(result: dict) -> dict:
    return {k: v for k, v in result.items() if not isinstance(v, np.ndarray)}


# ------------------------------------------------------------------------------------------------- laser
class _LaserRig:
    def __init__(self, spec: AcceptanceSpec, error_model: ErrorModel, seed: int):
        config = load_scanner_config()
        self.sensor = SensorModel(config.sensor_parameters)
        self.errors = LaserErrors.create(self.sensor, error_model)
        self.sim = LaserLineScannerSimulator(
            self.sensor,
            points_per_profile=int(spec.settings.get("points_per_profile", 640)),
            seed=seed,
            errors=self.errors,
        )
        self.pitch = float(spec.settings.get("pitch_mm", 0.2))
        self.screen = 2.0
        self.plane_border = 1.0

    def measure(self, meshes_mm):
        return self.sweep(meshes_mm), None

    def sweep(self, meshes_mm) -> np.ndarray:
        """One straight sweep along x (emitter looking along +z, identity orientation) over the meshes."""
        import trimesh

        mesh = trimesh.util.concatenate(meshes_mm)
        self.sim.set_target(mesh)
        x0, x1 = mesh.bounds[0, 0] - 2.0, mesh.bounds[1, 0] + 2.0
        xs = np.arange(x0, x1, self.pitch)
        poses = np.repeat(np.eye(4)[None], len(xs), axis=0)
        poses[:, 0, 3] = xs
        profiles = self.sim.profiles(poses)
        chunks = [p.points_mm for p in profiles if len(p)]
        return np.vstack(chunks) if chunks else np.zeros((0, 3))


def _run(spec: AcceptanceSpec, rig, positions: int | None) -> list[dict]:
    """The artefacts at their positions, one view each: rows of PF/PS, SD and F."""
    art, volume = spec.artefacts, spec.volume
    rows = []
    d_cal = art.calibrated_diameter(art.sphere_diameter)
    for i, pose in enumerate(sphere_positions(volume, 0.5 * art.sphere_diameter, positions or 10)):
        points, sigma = rig.measure([_transformed(art.sphere_mesh(art.sphere_diameter), pose)])
        centre = pose[:3, 3][None]
        near = _split(points, centre, 0.5 * art.sphere_diameter, rig.screen, mask=True)[0]
        row = dict(artefact="sphere", position=i, z=pose[2, 3], **_plain(evaluate_sphere(points[near], d_cal)))
        rows.append(row | ({"expected_sigma": _rms(sigma[near])} if sigma is not None else {}))
    for i, pose in enumerate(dumbbell_positions(volume, art.dumbbell_length, positions or 7)):
        meshes, centres = _dumbbell_meshes(spec, pose, art.dumbbell_diameter, art.dumbbell_length)
        points, _ = rig.measure(meshes)
        a, b = _split(points, centres, 0.5 * art.dumbbell_diameter, rig.screen)
        # the spheres' centres are exact (the meshes are centred on them): the calibrated length is the nominal one
        result = evaluate_dumbbell(a, b, art.dumbbell_length)
        rows.append(dict(artefact="dumbbell", position=i, z=pose[2, 3], **_plain(result)))
    for i, pose in enumerate(plane_positions(volume, art.plane_tilt_deg, positions or 6)):
        points, sigma = rig.measure([_transformed(art.plane_mesh(), pose)])
        selected, mask = _plane_points(points, pose, art.plane_size, rig.screen, rig.plane_border)
        row = dict(artefact="plane", position=i, z=pose[2, 3], tilt=_tilt(pose), **_plain(evaluate_plane(selected)))
        rows.append(row | ({"expected_sigma": _rms(sigma[mask])} if sigma is not None else {}))
    return rows


def run_phoxi(spec: AcceptanceSpec, error_model: ErrorModel, positions: int | None = None, seed: int = 0) -> dict:
    """Rows of one PhoXi's test, with the averaged-plane row (see :func:`judge`)."""
    rig = _PhoxiRig(spec, error_model, seed)
    rows = _run(spec, rig, positions)
    frames = int(spec.settings.get("average_frames", 16))
    if frames > 0:
        rows.append(_average_plane(rig, frames))
    return {"scanner": spec.name, "rows": rows}


def run_laser(spec: AcceptanceSpec, error_model: ErrorModel, positions: int | None = None, seed: int = 0) -> dict:
    """Rows of the laser's single-sweep test (the multi-sweep test is :mod:`benchmarks.acceptance.multi_sweep`)."""
    return {"scanner": spec.name, "rows": _run(spec, _LaserRig(spec, error_model, seed), positions)}


def run_scanner(spec: AcceptanceSpec, error_model: ErrorModel | str = "realistic", positions=None, seed=0) -> dict:
    """One scanner's test: rows, summary and verdicts, with its run time (s)."""
    if not isinstance(error_model, ErrorModel):
        error_model = load_error_model(error_model)
    start, cpu = time.perf_counter(), time.process_time()
    run = run_phoxi if spec.kind == "phoxi" else run_laser
    result = run(spec, error_model, positions, seed)
    # wall time, and the CPU time of all the process's threads (what a busy, shared machine does not inflate)
    result["seconds"] = time.perf_counter() - start
    result["cpu_seconds"] = time.process_time() - cpu
    result["error_model"] = error_model.name
    result["summary"], result["checks"] = judge(spec, result["rows"])
    return result


def judge(spec: AcceptanceSpec, rows: list[dict]) -> tuple[dict, list[dict]]:
    """Summary figures (max |PF|, F, spreads of PS and SD, ...) and the checks against ``spec.expect``: each check
    a dict (name, value, low, high, holds)."""
    by = {}
    for row in rows:
        by.setdefault(row["artefact"], []).append(row)
    spheres, bells, planes = by.get("sphere", []), by.get("dumbbell", []), by.get("plane", [])
    ps = np.array([r["PS"] for r in spheres])
    sd = np.array([r["SD"] for r in bells])
    summary = {
        "PF_max": max((r["PF"] for r in spheres), default=float("nan")),
        "F_max": max((r["F"] for r in planes), default=float("nan")),
        "PS_mean": float(ps.mean()) if len(ps) else float("nan"),
        "PS_std": float(ps.std(ddof=1)) if len(ps) > 1 else float("nan"),
        "PS_maxabs": float(np.abs(ps).max()) if len(ps) else float("nan"),
        "SD_mean": float(sd.mean()) if len(sd) else float("nan"),
        "SD_std": float(sd.std(ddof=1)) if len(sd) > 1 else float("nan"),
        "SD_maxabs": float(np.abs(sd).max()) if len(sd) else float("nan"),
    }
    expect = spec.expect
    checks = []

    def check(name, value, low, high):
        checks.append({"name": name, "value": float(value), "low": low, "high": high,
                       "holds": bool(low <= value <= high)})  # fmt: skip

    if spec.kind == "phoxi":
        factor, tol = expect["form_factor"], expect["form_tolerance"]
        for row in spheres:
            ratio = row["PF"] / (factor * row["expected_sigma"])
            check(f"PF/expected sphere {row['position']}", ratio, 1.0 - tol, 1.0 + tol)
        for row in planes:
            ratio = row["F"] / (factor * row["expected_sigma"])
            check(f"F/expected plane {row['position']}", ratio, 1.0 - tol, 1.0 + tol)
        acc = expect["calibration_accuracy_mm"]
        low, high = expect["spread_range"]
        if len(ps) > 1:
            check("std(PS)/calibration accuracy", summary["PS_std"] / acc, low, high)
        if len(sd) > 1:
            check("std(SD)/calibration accuracy", summary["SD_std"] / acc, low, high)
        for row in by.get("average", []):
            summary["average_rms_vs_true"] = row["rms_vs_true"]
            check("averaged plane RMS/calibration accuracy", row["rms_vs_true"] / acc,
                  expect["average_floor_factor"], float("inf"))  # fmt: skip
    else:
        low, high = expect["form_range_mm"]
        for row in spheres:
            check(f"PF sphere {row['position']} (mm)", row["PF"], low, high)
        for row in planes:
            check(f"F plane {row['position']} (mm)", row["F"], low, high)
        for row in bells:
            check(f"|SD| dumbbell {row['position']} (mm)", abs(row["SD"]), 0.0, expect["linearity_mm"])
    return summary, checks
