"""The scanner's systematic uncertainty in an inspection (``config/inspection/instruments.yaml``).

A scanner's random noise averages out in a patch or a fit; its per-device systematic errors (calibration,
fixed pattern, speckle, hand-eye: docs/sensor-errors.md) do not. What is left of them after the best fit enters
every decision's uncertainty as a fully correlated term: ``surface_mm`` (1 sigma) on a patch's mean deviation,
``form_mm`` on a flatness value, ``length_rel`` (relative, 1 sigma) on a size and, times the distance from the
registration's centre, on a hole's position. The values per error model and scanner are an uncertainty
evaluation with calibrated parts (ISO 15530-3 style): the null parts of the development seeds scanned with that
error model (see the file's comments). An unknown scanner or error model is an error; ``None`` is no term.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import non_negative, read_yaml
from agiprobot_measurement.inspection.errors import InspectionInputError

__all__ = ["INSTRUMENTS_FILE", "InstrumentUncertainty", "load_instrument"]

INSTRUMENTS_FILE = CONFIG_DIR / "inspection" / "instruments.yaml"
_KEYS = ("surface_mm", "form_mm", "length_rel")


@dataclass(frozen=True)
class InstrumentUncertainty:
    """1-sigma systematic terms of one scanner under one error model (see the module docstring)."""

    surface_mm: float = 0.0
    form_mm: float = 0.0
    length_rel: float = 0.0


def load_instrument(error_model: str, scanner: str, path: str | Path = INSTRUMENTS_FILE) -> InstrumentUncertainty:
    """The terms of ``scanner`` (e.g. ``phoxi_S``, ``laser_line``) under the named ``error_model``."""
    data = read_yaml(path)
    where = f"{path}"
    if not isinstance(data, dict) or error_model not in data:
        known = sorted(data) if isinstance(data, dict) else []
        raise InspectionInputError(f"{where}: no error model {error_model!r} (known: {known})")
    scanners = data[error_model]
    if not isinstance(scanners, dict) or scanner not in scanners:
        known = sorted(scanners) if isinstance(scanners, dict) else []
        raise InspectionInputError(f"{where}: {error_model}: no scanner {scanner!r} (known: {known})")
    entry = scanners[scanner]
    unknown = sorted(set(entry) - set(_KEYS)) if isinstance(entry, dict) else ["(not a mapping)"]
    if unknown:
        raise InspectionInputError(f"{where}: {error_model}.{scanner}: unknown keys {unknown} (known: {list(_KEYS)})")
    return InstrumentUncertainty(
        **{k: non_negative(entry.get(k, 0.0), f"{where}: {error_model}.{scanner}.{k}") for k in _KEYS}
    )
