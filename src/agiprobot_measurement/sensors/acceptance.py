"""A VDI/VDE 2634 Part 2 acceptance test of the simulated scanners: artefacts, positions and the evaluation.

Quantities (each from one view: one PhoXi frame or one straight laser sweep):

* ``PF`` probing error, form: range of the radial residuals to the least-squares sphere with free radius;
* ``PS`` probing error, size: fitted minus calibrated diameter (same fit, same measurements);
* ``SD`` sphere-spacing error: fitted minus calibrated centre distance of a dumbbell's two spheres;
* ``F`` flatness measurement error: range of the signed residuals to the least-squares plane.

Up to :data:`OUTLIER_SHARE` (0.3 %) of the points with the largest absolute residuals are discarded before the
range is taken (the guideline's allowance). The calibrated diameter and distance are those of the artefact mesh
itself (a least-squares fit to dense samples of its surface), so faceting does not count as scanner error.

Positions follow the guideline's pattern inside a box-shaped measuring volume (:class:`Volume`): the sphere at
corners and centre of the near, middle and far layers; the dumbbell along the four space diagonals and three face
diagonals; the plane at three depths, fronto-parallel and tilted. The number of positions per artefact can be
reduced (the CI-sized test takes 3). Units: mm; poses 4x4 in the scanner's frame (z = viewing direction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.common.config import ConfigError, positive, read_yaml, require
from agiprobot_measurement.sensors.error_models import ERROR_MODELS_DIR
from agiprobot_measurement.sensors.errors import SensorInputError

__all__ = [
    "ACCEPTANCE_FILE",
    "OUTLIER_SHARE",
    "AcceptanceSpec",
    "Artefacts",
    "Volume",
    "dumbbell_positions",
    "evaluate_dumbbell",
    "evaluate_plane",
    "evaluate_sphere",
    "fit_plane",
    "fit_sphere",
    "load_acceptance_specs",
    "plane_positions",
    "sphere_positions",
]

#: the per-scanner artefacts, volumes and expectations
ACCEPTANCE_FILE = ERROR_MODELS_DIR / "acceptance.yaml"
#: share of the points the guideline lets the evaluation discard as outliers
OUTLIER_SHARE = 0.003


# ----------------------------------------------------------------------------------------------- fits
def fit_sphere(points_mm: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares (Gaussian) sphere with free radius: (centre (3,), radius, radial residuals (N,))."""
    p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    if len(p) < 4:
        raise SensorInputError(f"a sphere fit needs at least 4 points, got {len(p)}")
    # algebraic start: |p|^2 = 2 c . p + (r^2 - |c|^2)
    a = np.column_stack([2.0 * p, np.ones(len(p))])
    sol = np.linalg.lstsq(a, np.einsum("ij,ij->i", p, p), rcond=None)[0]
    centre = sol[:3]
    radius = math.sqrt(max(sol[3] + centre @ centre, 1e-12))
    for _ in range(iterations):  # Gauss-Newton on the geometric residuals
        d = p - centre
        dist = np.linalg.norm(d, axis=1)
        residual = dist - radius
        jac = np.column_stack([-d / dist[:, None], -np.ones(len(p))])
        step = np.linalg.lstsq(jac, -residual, rcond=None)[0]
        centre, radius = centre + step[:3], radius + step[3]
        if np.abs(step).max() < 1e-10:
            break
    return centre, float(radius), np.linalg.norm(p - centre, axis=1) - radius


def fit_plane(points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane: (point on it (3,), unit normal (3,), signed residuals (N,))."""
    p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    if len(p) < 3:
        raise SensorInputError(f"a plane fit needs at least 3 points, got {len(p)}")
    centroid = p.mean(axis=0)
    normal = np.linalg.svd(p - centroid, full_matrices=False)[2][2]
    return centroid, normal, (p - centroid) @ normal


def _trimmed(points: np.ndarray, fit, residual_of) -> tuple[tuple, np.ndarray]:
    """Fit, drop the OUTLIER_SHARE largest |residuals|, refit: (fit result, residuals of the kept points)."""
    first = fit(points)
    residual = residual_of(first)
    drop = math.floor(OUTLIER_SHARE * len(points))
    if drop:
        keep = np.argsort(np.abs(residual))[: len(points) - drop]
        points = points[keep]
    result = fit(points)
    return result, residual_of(result)


def evaluate_sphere(points_mm: np.ndarray, calibrated_diameter_mm: float) -> dict:
    """PF and PS of one sphere measurement (mm), with the fit's centre, diameter and point count."""
    (centre, radius, _), residual = _trimmed(np.asarray(points_mm, dtype=float), fit_sphere, lambda r: r[2])
    return {
        "PF": float(residual.max() - residual.min()),
        "PS": float(2.0 * radius - calibrated_diameter_mm),
        "centre": centre,
        "diameter": 2.0 * radius,
        "sigma": float(residual.std()),
        "points": len(points_mm),
    }


def evaluate_dumbbell(points_a, points_b, calibrated_distance_mm: float) -> dict:
    """SD of one dumbbell measurement (mm): the two spheres fitted apart (free radius)."""
    a = evaluate_sphere(points_a, 0.0)
    b = evaluate_sphere(points_b, 0.0)
    distance = float(np.linalg.norm(a["centre"] - b["centre"]))
    return {"SD": distance - calibrated_distance_mm, "distance": distance, "points": a["points"] + b["points"]}


def evaluate_plane(points_mm: np.ndarray) -> dict:
    """F of one plane measurement (mm) and the residual standard deviation."""
    _, residual = _trimmed(np.asarray(points_mm, dtype=float), fit_plane, lambda r: r[2])
    return {"F": float(residual.max() - residual.min()), "sigma": float(residual.std()), "points": len(points_mm)}


# ------------------------------------------------------------------------------------- volume, positions
@dataclass(frozen=True)
class Volume:
    """A box-shaped measuring volume in the scanner frame (mm): depth ``z_range`` along the viewing axis, the
    half-widths ``half_xy`` (x, y) usable at every depth of it."""

    z_range: tuple[float, float]
    half_xy: tuple[float, float]

    @property
    def centre(self) -> np.ndarray:
        return np.array([0.0, 0.0, 0.5 * sum(self.z_range)])

    @property
    def half(self) -> np.ndarray:
        return np.array([self.half_xy[0], self.half_xy[1], 0.5 * (self.z_range[1] - self.z_range[0])])


def _translation(p) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = p
    return pose


def sphere_positions(volume: Volume, radius_mm: float, count: int = 10) -> list[np.ndarray]:
    """Sphere centres: middle-layer centre, then the four corners of the near and far layers, then the near
    centre (10); the first ``count`` of them, the artefact kept inside the volume."""
    c, h = volume.centre, np.maximum(volume.half - radius_mm, 0.0)
    near, far = c[2] - h[2], c[2] + h[2]
    corners = [(sx * 0.6 * h[0], sy * 0.6 * h[1]) for sx, sy in ((-1, -1), (1, 1), (1, -1), (-1, 1))]
    centres = [c.copy()]
    for x, y in corners:
        centres += [np.array([x, y, near]), np.array([-x, -y, far])]
    centres.append(np.array([0.0, 0.0, near]))
    return [_translation(p) for p in centres[:count]]


def dumbbell_positions(volume: Volume, length_mm: float, count: int = 7) -> list[np.ndarray]:
    """Dumbbell poses (centre, x axis along the bar): the four space diagonals, then the face diagonals x-y, x-z
    and y-z of the volume, centred in it; the first ``count``."""
    h = volume.half
    directions = [
        (1, 1, 1),
        (1, -1, 1),
        (-1, 1, 1),
        (-1, -1, 1),
        (1, 1, 0),
        (1, 0, 1),
        (0, 1, 1),
    ]
    poses = []
    for d in directions[:count]:
        axis = np.asarray(d, dtype=float) * h
        axis /= np.linalg.norm(axis)
        pose = _translation(volume.centre)
        pose[:3, :3] = _frame_with_x(axis)
        poses.append(pose)
    return poses


def plane_positions(volume: Volume, tilt_deg: float, count: int = 6) -> list[np.ndarray]:
    """Plane poses (the artefact's +z, its front normal, turned towards the scanner): near, middle and far
    fronto-parallel and the same depths tilted by ``tilt_deg`` about the plane's long (x) axis, interleaved
    (plain near, tilted near, plain middle, ...); the first ``count``."""
    c, h = volume.centre, volume.half
    poses = []
    for tilt in (0.0, tilt_deg):
        for z in (c[2] - 0.5 * h[2], c[2], c[2] + 0.5 * h[2]):
            a = math.radians(tilt)
            pose = _translation([0.0, 0.0, z])
            # normal towards the scanner (-z), turned about x by the tilt
            pose[:3, :3] = np.array([[1, 0, 0], [0, -math.cos(a), math.sin(a)], [0, -math.sin(a), -math.cos(a)]])
            poses.append(pose)
    order = [0, 3, 1, 4, 2, 5]
    return [poses[i] for i in order[:count]]


def _frame_with_x(axis: np.ndarray) -> np.ndarray:
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = np.cross(helper, axis)
    y /= np.linalg.norm(y)
    return np.column_stack([axis, y, np.cross(axis, y)])


# ------------------------------------------------------------------------------------------- artefacts
@dataclass(frozen=True)
class Artefacts:
    """Sizes of one scanner's artefacts (mm): sphere diameter, dumbbell sphere diameter and centre distance,
    plane length, width and tilt (deg); icosphere subdivision for sagitta below a twentieth of the noise."""

    sphere_diameter: float
    dumbbell_diameter: float
    dumbbell_length: float
    plane_size: tuple[float, float]
    plane_tilt_deg: float = 20.0
    subdivisions: int = 6

    def sphere_mesh(self, diameter: float):
        import trimesh

        return trimesh.creation.icosphere(subdivisions=self.subdivisions, radius=0.5 * diameter)

    def calibrated_diameter(self, diameter: float) -> float:
        """The LS diameter of the faceted artefact (dense surface samples): what a calibration would certify."""
        import trimesh

        mesh = self.sphere_mesh(diameter)
        samples, _ = trimesh.sample.sample_surface_even(mesh, 20000, seed=1)
        return 2.0 * fit_sphere(samples)[1]

    def plane_mesh(self):
        import trimesh

        box = trimesh.creation.box([self.plane_size[0], self.plane_size[1], 10.0])
        box.apply_translation([0.0, 0.0, -5.0])  # front face at z = 0 of the artefact frame, normal +z
        return box


@dataclass(frozen=True)
class AcceptanceSpec:
    """One scanner's test: artefacts, measuring volume, expectations (``expect`` as in the config file)."""

    name: str
    kind: str  # "phoxi" or "laser"
    model: str
    artefacts: Artefacts
    volume: Volume
    settings: dict = field(default_factory=dict)
    expect: dict = field(default_factory=dict)
    multi_sweep: dict = field(default_factory=dict)  # the laser's robot-registered length test, if any


def load_acceptance_specs(path=None) -> dict[str, AcceptanceSpec]:
    """The scanners of ``config/error_models/acceptance.yaml`` (or ``path``)."""
    path = path or ACCEPTANCE_FILE
    data = read_yaml(path)
    where = str(path)
    scanners = require(data, "scanners", where)
    if not isinstance(scanners, dict) or not scanners:
        raise ConfigError(f"{where}: scanners must be a non-empty mapping")
    specs = {}
    for name, entry in scanners.items():
        here = f"{where}: scanners.{name}"
        kind = str(require(entry, "kind", here))
        if kind not in ("phoxi", "laser"):
            raise ConfigError(f"{here}.kind must be phoxi or laser, got {kind!r}")
        art = require(entry, "artefacts", here)
        vol = require(entry, "volume", here)
        z = [positive(v, f"{here}.volume.z_range_mm") for v in require(vol, "z_range_mm", f"{here}.volume")]
        xy = [positive(v, f"{here}.volume.half_xy_mm") for v in require(vol, "half_xy_mm", f"{here}.volume")]
        if len(z) != 2 or len(xy) != 2 or not z[0] < z[1]:
            raise ConfigError(f"{here}.volume: z_range_mm needs near < far, half_xy_mm two numbers")
        size = require(art, "plane_size_mm", f"{here}.artefacts")
        specs[str(name)] = AcceptanceSpec(
            name=str(name),
            kind=kind,
            model=str(entry.get("model", name)),
            artefacts=Artefacts(
                sphere_diameter=positive(require(art, "sphere_diameter_mm", here), f"{here}.sphere_diameter_mm"),
                dumbbell_diameter=positive(require(art, "dumbbell_diameter_mm", here), f"{here}.dumbbell_diameter_mm"),
                dumbbell_length=positive(require(art, "dumbbell_length_mm", here), f"{here}.dumbbell_length_mm"),
                plane_size=(positive(size[0], f"{here}.plane_size_mm"), positive(size[1], f"{here}.plane_size_mm")),
                plane_tilt_deg=float(art.get("plane_tilt_deg", 20.0)),
                subdivisions=int(art.get("subdivisions", 6)),
            ),
            volume=Volume((z[0], z[1]), (xy[0], xy[1])),
            settings=dict(entry.get("settings") or {}),
            expect=dict(entry.get("expect") or {}),
            multi_sweep=dict(entry.get("multi_sweep") or {}),
        )
    return specs
