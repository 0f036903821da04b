"""The scanner's systematic uncertainty in an inspection (``config/inspection/instruments.yaml``).

A scanner's random noise averages out in a patch or a fit; its per-device systematic errors (calibration,
fixed pattern, speckle, hand-eye: docs/sensor-errors.md) do not. What is left of them after the best fit enters
every decision's uncertainty as a fully correlated term: ``surface_mm`` (1 sigma) on a patch's mean deviation,
``form_mm`` on a flatness value, ``length_rel`` (relative, 1 sigma) on a size and, times the distance from the
registration's centre, on a hole's position; ``size_mm`` (1 sigma) on a size between two opposite faces, which a
scanner that sees them in opposite head orientations and at one standoff moves apart or together by its
linearity and hand-eye errors whatever the size; ``centre_mm`` (1 sigma per in-plane axis) on a fitted hole's centre
against its datums: what the device's calibration error moves the hole's points by against the datum faces'
points (they lie elsewhere in the field of view, and the hole is seen by other views than some datums). The values
per error model and scanner are an uncertainty evaluation with calibrated parts (ISO 15530-3 style): the null parts of
the development seeds scanned with that error model (see the file's comments); ``centre_mm`` of the PhoXi and the
laser's ``surface_mm`` and ``size_mm`` are propagated from the error model by Monte Carlo
(``python -m benchmarks.inspection.derive``: devices of the model's draws, noise-free scans, the inspection's own
fits). An unknown scanner or error model is an error; ``None`` is no term.

``stitching_mm`` (1 sigma, per axis) is the relative shift of two views taken in different head orientations,
which a feature seen in one view suffers against datums (or the rest of the cloud) seen in others: it enters a
hole's position. ``stitching_mm: pose_chain`` derives it from the error model's laser ``pose_chain`` block
(:func:`pose_chain_stitching_mm`), not from measured clouds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import non_negative, read_yaml
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.sensors.error_models import load_error_model
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.station.config import load_scanner_config

__all__ = [
    "INSTRUMENTS_FILE",
    "InstrumentUncertainty",
    "known_error_models",
    "load_instrument",
    "pose_chain_stitching_mm",
]

INSTRUMENTS_FILE = CONFIG_DIR / "inspection" / "instruments.yaml"
_KEYS = ("surface_mm", "form_mm", "length_rel", "centre_mm", "size_mm", "stitching_mm")
#: ``stitching_mm`` value that derives the term from the error model's laser pose chain
FROM_POSE_CHAIN = "pose_chain"


@dataclass(frozen=True)
class InstrumentUncertainty:
    """1-sigma systematic terms of one scanner under one error model (see the module docstring)."""

    surface_mm: float = 0.0
    form_mm: float = 0.0
    length_rel: float = 0.0
    centre_mm: float = 0.0
    size_mm: float = 0.0
    stitching_mm: float = 0.0


def pose_chain_stitching_mm(pose_chain: dict | None, standoff_mm: float) -> float:
    """1-sigma per-axis shift (mm) of one view against another taken in a different head orientation, implied by
    a laser ``pose_chain`` block (config/error_models/): the head's hand-eye error (translation t per axis,
    rotation theta per axis, the latter moving a point at the ``standoff_mm`` by theta x standoff) is fixed in the
    head's frame, so two orientations about 90 deg apart see it differently: their difference (I - R) e has
    sqrt(2) times its per-axis sigma; one repeatability draw (r per axis) per view adds sqrt(2) r. The kinematic
    residual and latency of a robot-carried head are not in it (straight ideal sweeps). None/disabled: 0."""
    if not pose_chain or not pose_chain.get("enabled", True):
        return 0.0
    rotation_mm = math.radians(float(pose_chain.get("hand_eye_rotation_deg", 0.0))) * standoff_mm
    per_view = math.hypot(float(pose_chain.get("hand_eye_translation_mm", 0.0)), rotation_mm,
                          float(pose_chain.get("repeatability_mm", 0.0)))  # fmt: skip
    return math.sqrt(2.0) * per_view


def _stitching(value, error_model: str, where: str) -> float:
    if value != FROM_POSE_CHAIN:
        return non_negative(value, where)
    standoff = SensorModel(load_scanner_config().sensor_parameters).optimal_standoff
    return pose_chain_stitching_mm(load_error_model(error_model).laser.get("pose_chain"), standoff)


def known_error_models(path: str | Path = INSTRUMENTS_FILE) -> list[str]:
    """The error models the instruments file states terms for (sorted)."""
    data = read_yaml(path)
    return sorted(data) if isinstance(data, dict) else []


def load_instrument(error_model: str, scanner: str, path: str | Path = INSTRUMENTS_FILE) -> InstrumentUncertainty:
    """The terms of ``scanner`` (e.g. ``phoxi_S``, ``laser_line``) under the named ``error_model``."""
    data = read_yaml(path)
    where = f"{path}"
    if not isinstance(data, dict) or error_model not in data:
        raise InspectionInputError(f"{where}: no error model {error_model!r} (known: {known_error_models(path)})")
    scanners = data[error_model]
    if not isinstance(scanners, dict) or scanner not in scanners:
        known = sorted(scanners) if isinstance(scanners, dict) else []
        raise InspectionInputError(f"{where}: {error_model}: no scanner {scanner!r} (known: {known})")
    entry = scanners[scanner]
    unknown = sorted(set(entry) - set(_KEYS)) if isinstance(entry, dict) else ["(not a mapping)"]
    if unknown:
        raise InspectionInputError(f"{where}: {error_model}.{scanner}: unknown keys {unknown} (known: {list(_KEYS)})")
    values = {k: non_negative(entry.get(k, 0.0), f"{where}: {error_model}.{scanner}.{k}") for k in _KEYS[:-1]}
    stitching = _stitching(
        entry.get("stitching_mm", 0.0), error_model, f"{where}: {error_model}.{scanner}.stitching_mm"
    )
    return InstrumentUncertainty(**values, stitching_mm=stitching)
