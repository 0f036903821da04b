"""ISO 14253-1 decision rules: conformance is proven only inside the tolerance zone shrunk by the expanded
uncertainty U (k = 2), non-conformance only outside the zone widened by U; between the two the result is
indeterminate. The detection limit of a characteristic is where non-conformance becomes certain, T + U."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["CONFORM", "COVERAGE_FACTOR", "INDETERMINATE", "NOT_CONFORM", "Decision", "decide", "expanded"]

CONFORM, NOT_CONFORM, INDETERMINATE = "conform", "not conform", "indeterminate"
#: coverage factor of the expanded uncertainty (about 95 %)
COVERAGE_FACTOR = 2.0


def expanded(*standard_uncertainties: float) -> float:
    """U = k * sqrt(sum u^2) (mm)."""
    return float(COVERAGE_FACTOR * np.sqrt(np.sum(np.square(standard_uncertainties))))


@dataclass
class Decision:
    """A characteristic's measured value against its zone [lower, upper] (mm) with expanded uncertainty U (mm)."""

    characteristic: str
    value_mm: float
    lower_mm: float | None
    upper_mm: float | None
    uncertainty_mm: float
    verdict: str
    detection_limit_mm: float | None

    def as_dict(self) -> dict:
        return asdict(self)


def decide(
    characteristic: str, value: float, upper: float | None, uncertainty: float, lower: float | None = None
) -> Decision:
    """The ISO 14253-1 verdict of ``value`` against ``lower`` <= value <= ``upper`` (None: unbounded side)."""
    u = float(uncertainty)
    inside = (upper is None or value <= upper - u) and (lower is None or value >= lower + u)
    outside = (upper is not None and value >= upper + u) or (lower is not None and value <= lower - u)
    verdict = CONFORM if inside else NOT_CONFORM if outside else INDETERMINATE
    limit = None if upper is None else float(upper + u)
    return Decision(characteristic, float(value), lower, upper, u, verdict, limit)
