"""PhoXi scanner models: the maker's figures per model (config/phoxi_models.yaml), the camera's pinhole intrinsics
per resolution, the projector's pose and the noise model's constants.

The camera frame is the scanner's sensor frame (optical: x right, y down, z forward, metres); the projector sits
``baseline`` to the right of the camera (+x), turned so that both optical axes cross at the sweet spot. Low
resolution is 2x2 binning of high resolution. Units: mm and degrees as the maker gives them, metres for poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, positive, read_yaml, require, vector
from agiprobot_measurement.errors import InputError

__all__ = [
    "FRAME_OUTPUTS",
    "PHOXI_MODELS_FILE",
    "RESOLUTION_HIGH",
    "RESOLUTION_LOW",
    "SIMULATED_SCANNER_ID",
    "CameraIntrinsics",
    "NoiseModel",
    "ScannerModel",
    "SimulatedScanner",
    "load_scanner_model",
    "load_scanner_models",
    "load_simulated_scanners",
    "simulated_scanners_from_entries",
]

PHOXI_MODELS_FILE = CONFIG_DIR / "phoxi_models.yaml"

RESOLUTION_LOW = 0
RESOLUTION_HIGH = 1
#: the hardware identification of the one scanner listed when the configuration lists none
SIMULATED_SCANNER_ID = "PhoXi3DScanner-sim"
#: the parts a PhoXi frame can hold (pho::api::Frame: PointCloud, DepthMap, NormalMap, ConfidenceMap, Texture), named
#: as the driver's send_<part> parameters; a scanner's frames hold every part it is told to send, a file camera's
#: only what its recording holds
FRAME_OUTPUTS = ("point_cloud", "depth_map", "normal_map", "confidence_map", "texture")


@dataclass(frozen=True)
class NoiseModel:
    """Constants of the noise and texture model (see the module docstring)."""

    min_cos_incidence: float = 0.05
    reference_albedo: float = 0.8
    reference_exposure_ms: float = 20.48
    texture_full_scale: float = 1000.0
    texture_saturation: float = 4095.0
    ambient_fraction: float = 0.05
    camera_only_ambient_fraction: float = 0.6
    shadow_epsilon_m: float = 0.001


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels of one resolution (no distortion)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def pixel_rays(self) -> np.ndarray:
        """(H * W, 3) float32 ray of every pixel, row-major, scaled to z = 1 (so ray * depth = point)."""
        return _pixel_rays(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def project(self, points_m: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) (u, v) of camera-frame points (N, 3)."""
        points_m = np.asarray(points_m, dtype=float)
        return np.stack(
            [
                self.fx * points_m[:, 0] / points_m[:, 2] + self.cx,
                self.fy * points_m[:, 1] / points_m[:, 2] + self.cy,
            ],
            axis=1,
        )


@lru_cache(maxsize=4)
def _pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    u = (np.arange(width, dtype=np.float64) - cx) / fx
    v = (np.arange(height, dtype=np.float64) - cy) / fy
    rays = np.empty((height, width, 3), dtype=np.float32)
    rays[:, :, 0] = u[None, :]
    rays[:, :, 1] = v[:, None]
    rays[:, :, 2] = 1.0
    rays = rays.reshape(-1, 3)
    rays.setflags(write=False)
    return rays


@dataclass(frozen=True)
class ScannerModel:
    """One PhoXi model: the maker's figures (mm, deg) and the simulator's noise constants."""

    name: str
    scanning_range_mm: tuple[float, float]
    sweet_spot_mm: float
    scan_area_mm: tuple[float, float]
    baseline_mm: float
    projector_fov_deg: tuple[float, float]
    temporal_noise_mm: float
    resolutions: dict = field(default_factory=lambda: {RESOLUTION_HIGH: (2064, 1544), RESOLUTION_LOW: (1032, 772)})
    noise: NoiseModel = field(default_factory=NoiseModel)

    def intrinsics(self, resolution: int = RESOLUTION_HIGH) -> CameraIntrinsics:
        if resolution not in self.resolutions:
            raise InputError(f"unknown resolution {resolution!r}: 1 = High, 0 = Low")
        width, height = self.resolutions[resolution]
        # the image spans the scanning area's width at the sweet spot; pixels are square
        f = width * self.sweet_spot_mm / self.scan_area_mm[0]
        return CameraIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    def projector_pose(self) -> np.ndarray:
        """Camera -> projector frame (4x4, metres): ``baseline`` along +x, z axis through the sweet spot."""
        b = self.baseline_mm / 1000.0
        d = self.sweet_spot_mm / 1000.0
        z = np.array([-b, 0.0, d]) / math.hypot(b, d)
        y = np.array([0.0, 1.0, 0.0])
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([np.cross(y, z), y, z])
        pose[:3, 3] = [b, 0.0, 0.0]
        return pose

    def supported_resolutions(self) -> list[tuple[int, int]]:
        return [self.resolutions[k] for k in sorted(self.resolutions, reverse=True)]


def load_scanner_models(path: str | Path | None = None) -> dict[str, ScannerModel]:
    """Read ``config/phoxi_models.yaml`` (or ``path``); errors name the file and the bad key."""
    path = Path(path) if path else PHOXI_MODELS_FILE
    data = read_yaml(path)
    where = str(path)
    resolutions = require(data, "resolutions", where)
    res = {}
    for key, code in (("high", RESOLUTION_HIGH), ("low", RESOLUTION_LOW)):
        size = vector(require(resolutions, key, f"{where}: resolutions"), 2, f"{where}: resolutions.{key}")
        if np.any(size < 1) or np.any(size != np.round(size)):
            raise ConfigError(f"{where}: resolutions.{key} must be two positive integers")
        res[code] = (int(size[0]), int(size[1]))
    noise_entry = data.get("noise_model") or {}
    if not isinstance(noise_entry, dict):
        raise ConfigError(f"{where}: noise_model must be a mapping")
    unknown = set(noise_entry) - set(NoiseModel.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"{where}: noise_model: unknown key(s) {sorted(unknown)}")
    noise = NoiseModel(**{k: positive(v, f"{where}: noise_model.{k}") for k, v in noise_entry.items()})
    models_entry = require(data, "models", where)
    if not isinstance(models_entry, dict) or not models_entry:
        raise ConfigError(f"{where}: models must be a non-empty mapping of name -> figures")
    models = {}
    for name, entry in models_entry.items():
        here = f"{where}: models.{name}"
        rng = vector(require(entry, "scanning_range_mm", here), 2, f"{here}.scanning_range_mm")
        sweet = positive(require(entry, "sweet_spot_mm", here), f"{here}.sweet_spot_mm")
        if not 0 < rng[0] < sweet < rng[1]:
            raise ConfigError(f"{here}: need 0 < scanning_range_mm[0] < sweet_spot_mm < scanning_range_mm[1]")
        area = vector(require(entry, "scan_area_mm", here), 2, f"{here}.scan_area_mm")
        fov = vector(require(entry, "projector_fov_deg", here), 2, f"{here}.projector_fov_deg")
        if np.any(area <= 0) or np.any(fov <= 0) or np.any(fov >= 180):
            raise ConfigError(f"{here}: scan_area_mm must be positive and projector_fov_deg within (0, 180)")
        models[str(name)] = ScannerModel(
            name=str(name),
            scanning_range_mm=(float(rng[0]), float(rng[1])),
            sweet_spot_mm=sweet,
            scan_area_mm=(float(area[0]), float(area[1])),
            baseline_mm=positive(require(entry, "baseline_mm", here), f"{here}.baseline_mm"),
            projector_fov_deg=(float(fov[0]), float(fov[1])),
            temporal_noise_mm=positive(require(entry, "temporal_noise_mm", here), f"{here}.temporal_noise_mm"),
            resolutions=res,
            noise=noise,
        )
    return models


def load_scanner_model(name: str, path: str | Path | None = None) -> ScannerModel:
    models = load_scanner_models(path)
    if name not in models:
        raise ConfigError(f"unknown PhoXi model {name!r}; models in {path or PHOXI_MODELS_FILE}: {', '.join(models)}")
    return models[name]


@dataclass(frozen=True)
class SimulatedScanner:
    """One scanner the simulated PhoXi Control lists (get_device_list) and connects to: its hardware identification
    (what a real scanner reports, e.g. ``2019-04-011-LC3``), its model and the device information it reports.

    ``frame_outputs``: the parts its frames can hold (:data:`FRAME_OUTPUTS`; default all). A scanner computes every
    part; PhoXi Control's file cameras (e.g. its installed example ``InstalledExamples-basic-example``, which the
    driver's own tests connect to) replay a recording and hold only what was recorded: the driver then publishes no
    message for a missing part (RosInterface.cpp ``publishFrame``: "Empty confidence map!")."""

    hw_identification: str
    model: ScannerModel
    name: str = ""
    firmware_version: str = "1.2.35"
    variant: str = ""
    ip_address: str = "127.0.0.1"
    is_alpha: bool = False
    frame_outputs: tuple[str, ...] = FRAME_OUTPUTS

    def __post_init__(self):
        if not self.hw_identification.strip():
            raise ConfigError("a simulated scanner needs a non-empty hw_identification")
        unknown = [part for part in self.frame_outputs if part not in FRAME_OUTPUTS]
        if unknown:
            raise ConfigError(
                f"scanner {self.hw_identification}: unknown frame output(s) {unknown} (known: {', '.join(FRAME_OUTPUTS)})"
            )
        object.__setattr__(self, "frame_outputs", tuple(self.frame_outputs))
        if not self.name:
            object.__setattr__(self, "name", f"PhoXi3DScanner {self.model.name} (simulated)")
        if not self.variant:
            object.__setattr__(self, "variant", self.model.name)


_SCANNER_KEYS = {
    "hw_identification",
    "model",
    "name",
    "firmware_version",
    "variant",
    "ip_address",
    "is_alpha",
    "frame_outputs",
}


def simulated_scanners_from_entries(
    entries, models: dict[str, ScannerModel], default_model: str, where: str
) -> list[SimulatedScanner]:
    """The scanner list of ``devices`` entries (mappings with the :class:`SimulatedScanner` keys; ``model`` empty or
    missing = ``default_model``); an empty list gives one scanner :data:`SIMULATED_SCANNER_ID` of the default model."""
    if default_model not in models:
        raise ConfigError(f"{where}: unknown PhoXi model {default_model!r} (models: {', '.join(models)})")
    if not entries:
        return [SimulatedScanner(SIMULATED_SCANNER_ID, models[default_model])]
    if not isinstance(entries, list):
        raise ConfigError(f"{where}: devices must be a list of scanners, got {type(entries).__name__}")
    scanners, seen = [], set()
    for i, entry in enumerate(entries):
        here = f"{where}: devices[{i}]"
        if not isinstance(entry, dict):
            raise ConfigError(f"{here}: expected a mapping with hw_identification, model, ...")
        unknown = set(entry) - _SCANNER_KEYS
        if unknown:
            raise ConfigError(f"{here}: unknown key(s) {sorted(unknown)} (known: {', '.join(sorted(_SCANNER_KEYS))})")
        hw_id = str(require(entry, "hw_identification", here)).strip()
        if not hw_id or hw_id in seen:
            raise ConfigError(f"{here}: hw_identification {hw_id!r} is empty or listed twice")
        seen.add(hw_id)
        model_name = str(entry.get("model") or default_model)
        if model_name not in models:
            raise ConfigError(f"{here}: unknown PhoXi model {model_name!r} (models: {', '.join(models)})")
        is_alpha = entry.get("is_alpha", False)
        if not isinstance(is_alpha, bool):
            raise ConfigError(f"{here}: is_alpha must be true or false")
        outputs = entry.get("frame_outputs", list(FRAME_OUTPUTS))
        if not isinstance(outputs, list) or not all(
            isinstance(part, str) and part in FRAME_OUTPUTS for part in outputs
        ):
            raise ConfigError(f"{here}: frame_outputs must be a list of {', '.join(FRAME_OUTPUTS)}, got {outputs!r}")
        scanners.append(
            SimulatedScanner(
                hw_identification=hw_id,
                model=models[model_name],
                name=str(entry.get("name") or ""),
                firmware_version=str(entry.get("firmware_version", "1.2.35")),
                variant=str(entry.get("variant") or ""),
                ip_address=str(entry.get("ip_address", "127.0.0.1")),
                is_alpha=is_alpha,
                frame_outputs=tuple(outputs),
            )
        )
    return scanners


def load_simulated_scanners(default_model: str, path: str | Path | None = None, entries=None) -> list[SimulatedScanner]:
    """The scanners of ``entries`` (e.g. the node's ``~devices``) or else of the models file's ``devices`` list."""
    path = Path(path) if path else PHOXI_MODELS_FILE
    models = load_scanner_models(path)
    if entries is None:
        data = read_yaml(path)
        return simulated_scanners_from_entries(data.get("devices"), models, default_model, str(path))
    return simulated_scanners_from_entries(entries, models, default_model, "~devices")
