"""Error models of the simulated scanners: named configurations (``config/error_models/<name>.yaml``) and the
per-device errors they imply.

A configuration holds switchable blocks per scanner (see ``config/error_models/realistic.yaml``):

* PhoXi: ``calibration`` (render with the true camera/projector, reconstruct with the nominal ones, plus a local
  residual of the decoded projector column; the two share the maker's calibration accuracy), ``fixed_pattern``
  (a static low-pass noise field per device), ``material`` (dark / saturated points invalid, specular share per
  scene object), ``edges`` (mixed pixels at depth jumps), ``interreflection`` (single bounce off specular surfaces: wrongly decoded points in concave regions);
* laser: ``calibration`` (true vs nominal triangulation angle, baseline, detector and lateral scale, scaled to a
  linearity envelope), ``noise`` (measurement noise apart from the planning ``u``: the datasheet z resolution as
  the temporal part, the speckle law of Dorsch et al. as the static part, both growing with incidence),
  ``material``, ``edges`` and ``pose_chain`` (true robot, hand-eye, latency).

``ideal`` switches everything off (the simulators' former behaviour). Per-device errors are drawn from a seed
derived from the device serial (:func:`device_seed`), so one device keeps its errors across frames and runs.

Units: mm and degrees in the configuration (the key names say which), rad inside the realised models.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, non_negative, read_yaml

__all__ = [
    "DEFAULT_ERROR_MODEL",
    "ERROR_MODELS_DIR",
    "ErrorModel",
    "LaserCalibration",
    "LaserErrors",
    "PhoxiCalibration",
    "PhoxiErrors",
    "ProjectorResidual",
    "device_seed",
    "load_error_model",
    "value_noise",
]

ERROR_MODELS_DIR = CONFIG_DIR / "error_models"
#: the set the simulator nodes and benchmarks use unless told otherwise
DEFAULT_ERROR_MODEL = "realistic"


def device_seed(serial: str, salt: str = "") -> int:
    """A stable 32-bit seed from a device serial (the same on every machine and run)."""
    return zlib.crc32(f"{serial}|{salt}".encode())


def _block(entry: object, where: str, defaults: dict) -> dict | None:
    """The settings of one switchable block (None when missing or ``enabled: false``); unknown keys are refused."""
    if entry is None:
        return None
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping")
    if not entry.get("enabled", True):
        return None
    unknown = set(entry) - set(defaults) - {"enabled"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)} (known: {', '.join(sorted(defaults))})")
    out = dict(defaults)
    for key, value in entry.items():
        if key == "enabled":
            continue
        default = defaults[key]
        if isinstance(default, dict):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}.{key}: expected a mapping")
            out[key] = {str(k): non_negative(v, f"{where}.{key}.{k}") for k, v in value.items()}
        elif isinstance(default, str):
            out[key] = str(value)
        else:
            out[key] = non_negative(value, f"{where}.{key}")
    for key, value in out.items():
        values = value.values() if isinstance(value, dict) else [value]
        if key.endswith(("share", "probability")) and any(v > 1.0 for v in values):
            raise ConfigError(f"{where}.{key}: a share or probability must lie within [0, 1], got {value}")
    return out


_PHOXI_BLOCKS = {
    "calibration": {
        "accuracy_mm": {"S": 0.05, "M": 0.1, "L": 0.2},
        "focal_length_rel": 3.0e-4,
        "principal_point_px": 0.2,
        "radial_k1": 2.0e-4,
        "projector_position_mm": 0.05,
        "projector_angle_deg": 0.005,
        "decoding_share": 0.7,
        "decoding_correlation_deg": 4.0,
    },
    "fixed_pattern": {"share": 0.3, "correlation_px": 10.0},
    "material": {
        "min_signal_counts": 20.0,
        "specular_peak": 30.0,
        "specular_exponent": 40.0,
        "specular_share": {"default": 0.0},
    },
    "edges": {"jump_rel": 0.01, "probability": 0.5},
    "interreflection": {"strength": 1.0},
}
_LASER_BLOCKS = {
    "calibration": {
        "linearity_fso": 0.0016,
        "triangulation_angle_deg": 0.02,
        "baseline_mm": 0.05,
        "detector_scale_rel": 5.0e-4,
        "lateral_scale_rel": 5.0e-4,
    },
    "noise": {
        "sigma_mm": 0.012,
        "depth_exponent": 2.0,
        "incidence_exponent": 1.5,
        "wavelength_nm": 658.0,
        "speckle_contrast": 1.0,
        "aperture_sin": 0.03,
        "speckle_correlation_mm": 0.1,
    },
    "material": {
        "albedo": 0.6,
        "specular_share": 0.0,
        "min_signal": 0.03,
        "saturation": 4.0,
        "specular_peak": 30.0,
        "specular_exponent": 40.0,
    },
    "edges": {"jump_mm": 1.0, "probability": 0.5},
    "pose_chain": {
        "robot_residual_scale": 0.18,
        "repeatability_mm": 0.014,
        "hand_eye_translation_mm": 0.1,
        "hand_eye_rotation_deg": 0.02,
        "latency_s": 0.002,
    },
}


@dataclass(frozen=True)
class ErrorModel:
    """One named error configuration: per scanner, the enabled blocks' settings (None = block off)."""

    name: str
    phoxi: dict = field(default_factory=dict)
    laser: dict = field(default_factory=dict)
    laser_serial: str = "scanCONTROL-sim-0001"
    source: Path | None = None

    @property
    def is_ideal(self) -> bool:
        return not any(self.phoxi.values()) and not any(self.laser.values())

    def with_blocks(self, scanner: str, **blocks) -> ErrorModel:
        """A copy with some blocks of ``scanner`` ('phoxi' or 'laser') replaced (None switches a block off)."""
        if scanner not in ("phoxi", "laser"):
            raise ConfigError(f"with_blocks: scanner must be 'phoxi' or 'laser', got {scanner!r}")
        known = _PHOXI_BLOCKS if scanner == "phoxi" else _LASER_BLOCKS
        unknown = set(blocks) - set(known)
        if unknown:
            raise ConfigError(f"with_blocks: unknown {scanner} block(s) {sorted(unknown)}")
        return replace(self, name=f"{self.name}+", **{scanner: {**getattr(self, scanner), **blocks}})


def load_error_model(name_or_path: str | Path = DEFAULT_ERROR_MODEL) -> ErrorModel:
    """The error model ``config/error_models/<name>.yaml`` (or a YAML file path); errors name the file and key."""
    text = str(name_or_path)
    path = Path(text) if text.endswith((".yaml", ".yml")) else ERROR_MODELS_DIR / f"{text}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in ERROR_MODELS_DIR.glob("*.yaml")))
        raise ConfigError(f"unknown error model {text!r} (no file {path}; known: {known})")
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    unknown = set(data) - {"name", "phoxi", "laser"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}")
    scanners = {}
    serial = _LASER_SERIAL_DEFAULT
    for scanner, blocks in (("phoxi", _PHOXI_BLOCKS), ("laser", _LASER_BLOCKS)):
        entry = data.get(scanner) or {}
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: {scanner} must be a mapping")
        if scanner == "laser":
            serial = str(entry.get("serial", serial))
        extra = set(entry) - set(blocks) - {"serial"}
        if extra:
            raise ConfigError(f"{where}: {scanner}: unknown block(s) {sorted(extra)} (known: {', '.join(blocks)})")
        scanners[scanner] = {key: _block(entry.get(key), f"{where}: {scanner}.{key}", d) for key, d in blocks.items()}
    return ErrorModel(str(data.get("name", path.stem)), scanners["phoxi"], scanners["laser"], serial, path)


_LASER_SERIAL_DEFAULT = "scanCONTROL-sim-0001"


# ---------------------------------------------------------------------------------------------- PhoXi
@dataclass(frozen=True)
class PhoxiCalibration:
    """One device's true optics relative to its nominal calibration: the camera's focal scale and principal point
    offset (high-resolution px), its residual radial distortion, and the true projector pose (camera <- projector,
    4x4 metres). ``scale`` is the factor that brought the draw to the configured accuracy."""

    focal_scale: float
    principal_offset_px: np.ndarray  # (2,)
    radial_k1: float
    projector_pose: np.ndarray  # (4, 4), true
    accuracy_mm: float
    scale: float
    decoding: ProjectorResidual | None = None  # the decoded projector column's local residual

    def reconstruct(self, nominal_rays, true_points, nominal_projector) -> np.ndarray:
        """:func:`reconstruct_depth` with this device's true projector and decoding residual."""
        return reconstruct_depth(nominal_rays, true_points, nominal_projector, self.projector_pose, self.decoding)

    def true_rays(self, intrinsics, nominal_width: int) -> np.ndarray:
        """(N, 3) float32 rays (z = 1) of the true camera for every pixel of ``intrinsics`` (row-major)."""
        binning = nominal_width / intrinsics.width
        w, h = intrinsics.width, intrinsics.height
        f = intrinsics.fx * self.focal_scale
        cx = intrinsics.cx + self.principal_offset_px[0] / binning
        cy = intrinsics.cy + self.principal_offset_px[1] / binning
        xd = ((np.arange(w) - cx) / f)[None, :].repeat(h, 0)
        yd = ((np.arange(h) - cy) / f)[:, None].repeat(w, 1)
        xu, yu = _undistort(xd, yd, self.radial_k1)
        rays = np.stack([xu, yu, np.ones_like(xu)], axis=-1).reshape(-1, 3)
        return np.ascontiguousarray(rays, dtype=np.float32)


@dataclass(frozen=True)
class ProjectorResidual:
    """The local residual of the decoded projector coordinate: what the projector's column -> plane mapping (the
    pattern decoding and the projection optics) does that the low-order calibration model does not capture. A
    smooth random field of the column offset (tan units) over the projector's field, on a regular grid over
    [-half_tan[0], half_tan[0]] x [-half_tan[1], half_tan[1]] (column, row), interpolated bilinearly."""

    grid: np.ndarray  # (rows, columns) column offsets, tan units
    half_tan: tuple[float, float]

    def offset(self, column: np.ndarray, row: np.ndarray) -> np.ndarray:
        rows, cols = self.grid.shape
        x = np.clip((column / self.half_tan[0] + 1.0) * 0.5 * (cols - 1), 0.0, cols - 1.000001)
        y = np.clip((row / self.half_tan[1] + 1.0) * 0.5 * (rows - 1), 0.0, rows - 1.000001)
        i, j = y.astype(np.int64), x.astype(np.int64)
        fy, fx = y - i, x - j
        g = self.grid
        top = g[i, j] * (1.0 - fx) + g[i, j + 1] * fx
        bottom = g[i + 1, j] * (1.0 - fx) + g[i + 1, j + 1] * fx
        return top * (1.0 - fy) + bottom * fy

    def scaled(self, factor: float) -> ProjectorResidual:
        return ProjectorResidual(self.grid * factor, self.half_tan)


def _projector_residual(model, rng, correlation_deg: float, modes: int = 64) -> ProjectorResidual:
    """A unit-RMS (in tan units, before scaling) smooth random field over the projector's field: a sum of random
    Fourier modes with a Gaussian spectrum of correlation length ``correlation_deg``, sampled on a grid a
    quarter of that length apart."""
    half = tuple(math.tan(math.radians(a) / 2.0) for a in model.projector_fov_deg)
    corr = math.tan(math.radians(max(correlation_deg, 1e-3)))
    shape = tuple(max(8, math.ceil(8.0 * h / corr) + 1) for h in (half[1], half[0]))
    rows, cols = np.meshgrid(
        np.linspace(-half[1], half[1], shape[0]), np.linspace(-half[0], half[0], shape[1]), indexing="ij"
    )
    freq = rng.normal(size=(modes, 2)) / corr  # Gaussian spectrum: correlation exp(-d^2 / (2 corr^2))
    phase = rng.uniform(0.0, 2.0 * math.pi, modes)
    grid = np.zeros(shape)
    for k in range(modes):  # a few dozen modes over a small grid: the loop is over modes, not points
        grid += np.cos(freq[k, 0] * cols + freq[k, 1] * rows + phase[k])
    grid *= math.sqrt(2.0 / modes)
    return ProjectorResidual(grid / max(float(np.sqrt(np.mean(grid * grid))), 1e-12), half)


def _undistort(xd: np.ndarray, yd: np.ndarray, k1: float, iterations: int = 3):
    """Invert x_d = x_u (1 + k1 r_u^2) by fixed-point iteration (k1 is tiny)."""
    xu, yu = xd.copy(), yd.copy()
    for _ in range(iterations):
        factor = 1.0 + k1 * (xu * xu + yu * yu)
        xu, yu = xd / factor, yd / factor
    return xu, yu


def reconstruct_depth(nominal_rays, true_points, nominal_projector, true_projector, decoding=None) -> np.ndarray:
    """Structured-light reconstruction: depth (same unit as the points, camera z) at which each nominal pixel ray
    meets the nominal projector's plane of the projector column that the true projector lit ``true_points`` with
    (camera frame; rays z = 1; projector poses camera <- projector, metres or the points' unit); ``decoding``
    (a :class:`ProjectorResidual`) shifts the decoded column."""
    # written out per component: BLAS matmuls of (N, 3) x (3, 3) cost far more than they bring
    rt, tt = true_projector[:3, :3], true_projector[:3, 3]
    px, py, pz = (true_points[:, k] - tt[k] for k in range(3))
    x_p = px * rt[0, 0] + py * rt[1, 0] + pz * rt[2, 0]  # projector-frame coordinates (R^T (p - t))
    z_p = px * rt[0, 2] + py * rt[1, 2] + pz * rt[2, 2]
    column = x_p / z_p
    if decoding is not None:
        y_p = px * rt[0, 1] + py * rt[1, 1] + pz * rt[2, 1]
        column = column + decoding.offset(column, y_p / z_p)
    rn, tn = nominal_projector[:3, :3], nominal_projector[:3, 3]
    rx, ry, rz = (nominal_rays[:, k] for k in range(3))
    ray_x = rx * rn[0, 0] + ry * rn[1, 0] + rz * rn[2, 0]  # R^T r
    ray_z = rx * rn[0, 2] + ry * rn[1, 2] + rz * rn[2, 2]
    origin_p = -(tn @ rn)  # R^T (0 - t)
    # (origin_p + lam ray_p) . (1, 0, -column) = 0
    return -(origin_p[0] - column * origin_p[2]) / (ray_x - column * ray_z)


def _phoxi_calibration(model, serial: str, settings: dict) -> PhoxiCalibration:
    accuracy = float(settings["accuracy_mm"].get(model.name, settings["accuracy_mm"].get("default", 0.0)))
    rng = np.random.default_rng(device_seed(serial, "phoxi-calibration"))
    draw = {
        "focal": rng.normal() * settings["focal_length_rel"],
        "pp": rng.normal(size=2) * settings["principal_point_px"],
        "k1": rng.normal() * settings["radial_k1"],
        "pos": rng.normal(size=3) * settings["projector_position_mm"] / 1000.0,
        "ang": rng.normal(size=3) * math.radians(settings["projector_angle_deg"]),
    }
    share = float(settings["decoding_share"])
    unit_residual = _projector_residual(model, rng, settings["decoding_correlation_deg"]) if share > 0.0 else None
    nominal = model.projector_pose()
    intr = model.intrinsics()

    def build(scale: float, decoding_scale: float = 0.0) -> PhoxiCalibration:
        rot = _rotvec(draw["ang"] * scale)
        true = nominal.copy()
        true[:3, :3] = rot @ nominal[:3, :3]
        true[:3, 3] = nominal[:3, 3] + draw["pos"] * scale
        decoding = unit_residual.scaled(decoding_scale) if unit_residual is not None and decoding_scale else None
        return PhoxiCalibration(
            1.0 + draw["focal"] * scale, draw["pp"] * scale, draw["k1"] * scale, true, accuracy, scale, decoding
        )

    def rms(cal: PhoxiCalibration) -> float:
        # fronto-parallel planes over the scanning range, a grid of pixels over the image
        u = np.linspace(0, intr.width - 1, 65)
        v = np.linspace(0, intr.height - 1, 49)
        uu, vv = np.meshgrid(u, v)
        f = intr.fx * cal.focal_scale
        xd = (uu - intr.cx - cal.principal_offset_px[0]) / f
        yd = (vv - intr.cy - cal.principal_offset_px[1]) / f
        xu, yu = _undistort(xd, yd, cal.radial_k1)
        true_rays = np.stack([xu, yu, np.ones_like(xu)], -1).reshape(-1, 3)
        nominal_rays = np.stack([(uu - intr.cx) / intr.fx, (vv - intr.cy) / intr.fy, np.ones_like(uu)], -1)
        nominal_rays = nominal_rays.reshape(-1, 3)
        errors = []
        for depth in np.linspace(*model.scanning_range_mm, 5) / 1000.0:
            measured = cal.reconstruct(nominal_rays, true_rays * depth, nominal)
            errors.append((measured - depth) * 1000.0)
        return float(np.sqrt(np.mean(np.square(errors))))

    def scaled(make, target: float) -> float:
        scale = 1.0
        for _ in range(3):  # the error is nearly linear in the draw: converges in two steps
            current = rms(make(scale))
            if current <= 0.0:
                break
            scale *= target / current
        return scale

    if accuracy <= 0.0:
        return build(0.0)
    # the accuracy budget (an RMS over planes) split in variance between the low-order optics and the local
    # decoding residual: share^2 of it to the residual, the rest to the optics (the two are uncorrelated)
    global_scale = scaled(build, accuracy * math.sqrt(max(1.0 - share * share, 0.0)))
    if unit_residual is None:
        return build(global_scale)
    decoding_scale = scaled(lambda s: build(0.0, s), accuracy * share)
    return build(global_scale, decoding_scale)


def _rotvec(v: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


class _DeviceErrors:
    """What every device's realised errors hold: its serial, the blocks' settings and the shared blocks."""

    def __init__(self, serial: str, settings: dict):
        self.serial = str(serial)
        self.settings = settings
        self.material = settings.get("material")
        self.edges = settings.get("edges")


class PhoxiErrors(_DeviceErrors):
    """The realised errors of one PhoXi device (model + serial) under an :class:`ErrorModel`'s PhoXi blocks."""

    def __init__(self, model, serial: str, settings: dict):
        super().__init__(serial, settings)
        self.model = model
        cal = settings.get("calibration")
        self.calibration = _phoxi_calibration(model, self.serial, cal) if cal else None
        self.fixed_pattern = settings.get("fixed_pattern")
        self.interreflection = settings.get("interreflection") if self.material else None
        self._fields: dict[tuple[int, int], np.ndarray] = {}
        self._rays: dict[tuple[int, int], np.ndarray] = {}

    @classmethod
    def create(cls, model, serial: str, error_model: ErrorModel | str | None) -> PhoxiErrors | None:
        """The device's errors, or None when the model (or every PhoXi block of it) is off."""
        if error_model is None:
            return None
        if not isinstance(error_model, ErrorModel):
            error_model = load_error_model(error_model)
        if not any(error_model.phoxi.values()):
            return None
        return cls(model, serial, error_model.phoxi)

    def true_rays(self, intrinsics) -> np.ndarray | None:
        if self.calibration is None:
            return None
        key = (intrinsics.width, intrinsics.height)
        if key not in self._rays:
            self._rays[key] = self.calibration.true_rays(intrinsics, self.model.resolutions[1][0])
            self._rays[key].setflags(write=False)
        return self._rays[key]

    def pattern_field(self, width: int, height: int) -> np.ndarray | None:
        """(H * W,) float32 unit-variance low-pass field of this device (None without fixed-pattern noise)."""
        if self.fixed_pattern is None:
            return None
        key = (width, height)
        if key not in self._fields:
            from scipy.ndimage import zoom

            corr = max(self.fixed_pattern["correlation_px"] * width / self.model.resolutions[1][0], 1.0)
            coarse = (max(2, math.ceil(height / corr) + 1), max(2, math.ceil(width / corr) + 1))
            rng = np.random.default_rng(device_seed(self.serial, f"fixed-pattern-{width}"))
            grid = rng.standard_normal(coarse)
            fine = zoom(grid, (height / coarse[0], width / coarse[1]), order=3)[:height, :width]
            fine = (fine - fine.mean()) / max(fine.std(), 1e-12)
            self._fields[key] = np.ascontiguousarray(fine.reshape(-1), dtype=np.float32)
        return self._fields[key]

    def specular_shares(self, names: tuple[str, ...]) -> np.ndarray:
        """Specular share per scene-object name (the ``default`` entry for unnamed ones)."""
        shares = self.material["specular_share"] if self.material else {}
        default = shares.get("default", 0.0)
        return np.array([shares.get(name, default) for name in names] or [default], dtype=np.float32)


def mix_depth_edges(depth: np.ndarray, valid: np.ndarray, jump: np.ndarray, probability: float, rng) -> np.ndarray:
    """Mixed pixels: a valid pixel whose right or lower valid neighbour lies more than ``jump`` (same unit, per
    pixel) away in depth sees both surfaces; with ``probability`` its depth becomes a uniform mix. (H, W) arrays."""
    out = depth.copy()
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        a, b = tuple(a), tuple(b)
        step = depth[b] - depth[a]
        edge = np.flatnonzero(valid[a] & valid[b] & (np.abs(step) > jump[a]))
        pick = edge[rng.random(len(edge)) < probability]
        view = out[a]
        view.flat[pick] = depth[a].flat[pick] + rng.random(len(pick)).astype(depth.dtype) * step.flat[pick]
    return out


# ---------------------------------------------------------------------------------------------- laser
@dataclass(frozen=True)
class LaserCalibration:
    """True minus nominal triangulation geometry of one laser head: triangulation angle (rad), baseline (mm),
    detector scale and lateral (fan) scale (relative); ``envelope_mm`` the max |z error - mean z error| they make
    over the measuring range (the linearity; the mean, an offset, is what a mount calibration absorbs)."""

    d_alpha_rad: float
    d_baseline_mm: float
    detector_scale: float
    lateral_scale: float
    envelope_mm: float
    offset_mm: float = 0.0  # mean range error over the volume, which the mount (hand-eye) calibration absorbs

    def reconstruct(self, ranges_mm, fan_angles_rad, baseline_mm: float, alpha_rad: float):
        """(measured range along the nominal ray, reported fan angle) of points at true ``ranges_mm`` along the
        true fan rays at ``fan_angles_rad``: render with the true head, reconstruct with the nominal one."""
        gamma0 = 0.5 * math.pi - alpha_rad  # detector axis vs baseline, nominal
        b_true = baseline_mm + self.d_baseline_mm
        gamma0_true = gamma0 - self.d_alpha_rad
        gamma = np.arctan2(ranges_mm, b_true)  # the detector sees the point at this angle
        pixel = np.tan(gamma - gamma0_true) * self.detector_scale  # detector coordinate / focal, true head
        measured_gamma = gamma0 + np.arctan(pixel)
        return baseline_mm * np.tan(measured_gamma) - self.offset_mm, np.asarray(fan_angles_rad) * self.lateral_scale


def laser_calibration(sensor, serial: str, settings: dict) -> LaserCalibration:
    """Draw the head's calibration error from its serial and scale its depth part (angle, baseline, detector
    scale) to its linearity envelope; the lateral scale error keeps its 1-sigma draw."""
    rng = np.random.default_rng(device_seed(serial, "laser-calibration"))
    raw = rng.normal(size=4) * [
        math.radians(settings["triangulation_angle_deg"]),
        settings["baseline_mm"],
        settings["detector_scale_rel"],
        settings["lateral_scale_rel"],
    ]
    z_range = sensor.maximum_standoff - sensor.minimum_standoff
    envelope = settings["linearity_fso"] * z_range * rng.uniform(0.5, 1.0)
    baseline = math.tan(sensor.alpha) * sensor.optimal_standoff
    z = np.linspace(sensor.minimum_standoff, sensor.maximum_standoff, 41)
    phi = np.linspace(-0.5 * sensor.fan_angle, 0.5 * sensor.fan_angle, 21)
    zz, pp = np.meshgrid(z, phi)
    ranges = zz / np.cos(pp)

    def build(scale: float, offset: float = 0.0) -> LaserCalibration:
        # the lateral (fan) scale is its own datasheet figure: drawn, not scaled to the z envelope
        args = (raw[0] * scale, raw[1] * scale, 1.0 + raw[2] * scale, 1.0 + raw[3], envelope, offset)
        return LaserCalibration(*args)

    def error(cal: LaserCalibration) -> np.ndarray:
        r, a = cal.reconstruct(ranges, pp, baseline, sensor.alpha)
        return r * np.cos(a) - zz

    # the envelope bounds the error about its mean: a constant offset is what the mount calibration absorbs
    scale = 1.0
    for _ in range(3):
        e = error(build(scale))
        current = float(np.abs(e - e.mean()).max())
        if current <= 0.0:
            break
        scale *= envelope / current
    return build(scale, float(error(build(scale)).mean()))


def value_noise(points_mm: np.ndarray, cell_mm: float, seed: int) -> np.ndarray:
    """A smooth, static, unit-variance random field over space (trilinear value noise on a ``cell_mm`` lattice,
    hashed from ``seed``): the same point always gets the same value."""
    p = np.asarray(points_mm, dtype=float) / cell_mm
    base = np.floor(p)
    frac = p - base
    frac = frac * frac * (3.0 - 2.0 * frac)  # smoothstep
    base = base.astype(np.int64)
    # the seed's hash term within int64 (any serial's seed; below 2^63 / 2654435761 it is the plain product)
    seed_term = np.int64((int(seed) * 2654435761) % (1 << 63))
    out = np.zeros(len(p))
    for corner in range(8):
        offset = np.array([(corner >> k) & 1 for k in range(3)])
        ijk = base + offset
        h = (ijk[:, 0] * 73856093) ^ (ijk[:, 1] * 19349663) ^ (ijk[:, 2] * 83492791) ^ seed_term
        h = (h ^ (h >> 13)) * 1274126177
        h = h ^ (h >> 16)
        value = (h & 0xFFFFFF).astype(float) / float(0xFFFFFF) * 2.0 - 1.0
        weight = np.prod(np.where(offset == 1, frac, 1.0 - frac), axis=1)
        out += weight * value
    # value noise of uniform(-1, 1) corners with smoothstep weights has a standard deviation of 0.37 over space
    # (measured on 200,000 random points; 0.37-0.43 on a plane through lattice nodes): normalise to about 1
    return out / 0.37


class LaserErrors(_DeviceErrors):
    """The realised errors of one laser head (serial) under an :class:`ErrorModel`'s laser blocks."""

    def __init__(self, sensor, serial: str, settings: dict):
        super().__init__(serial, settings)
        cal = settings.get("calibration")
        self.calibration = laser_calibration(sensor, self.serial, cal) if cal else None
        self.noise = settings.get("noise")
        self.pose_chain = settings.get("pose_chain")
        #: emitter -> detector distance (mm), the triangulation baseline of the speckle law
        self.baseline_mm = math.tan(sensor.alpha) * sensor.optimal_standoff
        self.speckle_seed = device_seed(self.serial, "speckle")
        rng = np.random.default_rng(device_seed(self.serial, "hand-eye"))
        self.hand_eye_error = np.eye(4)
        if self.pose_chain:
            self.hand_eye_error[:3, :3] = _rotvec(
                rng.normal(size=3) * math.radians(self.pose_chain["hand_eye_rotation_deg"])
            )
            self.hand_eye_error[:3, 3] = rng.normal(size=3) * self.pose_chain["hand_eye_translation_mm"]

    @classmethod
    def create(cls, sensor, error_model: ErrorModel | str | None, serial: str | None = None) -> LaserErrors | None:
        if error_model is None:
            return None
        if not isinstance(error_model, ErrorModel):
            error_model = load_error_model(error_model)
        if not any(error_model.laser.values()):
            return None
        return cls(sensor, serial or error_model.laser_serial, error_model.laser)

    def noise_parts_mm(
        self, z_mm: np.ndarray, cos_incidence: np.ndarray, optimal_standoff_mm: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(temporal, static speckle) 1-sigma noise along the laser ray (mm) at depths ``z_mm`` and incidence
        cosines. Temporal: the datasheet z resolution ``sigma_mm`` at the optimal standoff, (z / z_opt)^
        depth_exponent (a detector-plane error mapped through the triangulation). Speckle (Dorsch, Haeusler and
        Herrmann 1994): C lambda / (2 pi sin u_obs sin theta) with sin u_obs = a / L and sin theta = b / L (L the
        distance detector -> point, b the baseline, a the aperture radius set by ``aperture_sin`` at the optimal
        standoff): it grows as L^2 = z^2 + b^2, not as z^2. Both grow with incidence as 1 / cos^incidence_exponent."""
        n = self.noise
        z = np.asarray(z_mm, dtype=float)
        cos_i = np.maximum(np.abs(cos_incidence), 0.05) ** n["incidence_exponent"]
        temporal = n["sigma_mm"] * (z / optimal_standoff_mm) ** n["depth_exponent"] / cos_i
        b = self.baseline_mm
        l_opt_sq = optimal_standoff_mm**2 + b * b
        sin_theta_opt = b / math.sqrt(l_opt_sq)
        speckle_opt = n["speckle_contrast"] * n["wavelength_nm"] * 1e-6 / (2.0 * math.pi * n["aperture_sin"])
        speckle_opt /= max(sin_theta_opt, 1e-9)
        speckle = speckle_opt * (z * z + b * b) / l_opt_sq / cos_i
        return temporal, speckle

    def sigma_mm(self, z_mm: np.ndarray, cos_incidence: np.ndarray, optimal_standoff_mm: float) -> np.ndarray:
        """Measurement noise (1 sigma along the laser ray, mm) at depths ``z_mm`` and incidence cosines: the
        root sum of squares of the temporal and the static speckle parts (:meth:`noise_parts_mm`)."""
        temporal, speckle = self.noise_parts_mm(z_mm, cos_incidence, optimal_standoff_mm)
        return np.sqrt(temporal * temporal + speckle * speckle)
