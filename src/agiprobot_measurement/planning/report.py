"""What a plan covers and what it costs: :class:`CoverageReport`, per-sample uncertainties, the coverable mask.

Three numbers per plan, each a count of sample points:

* *metrologically coverable* (``n_coverable_metrology``): some candidate view with a reachable anchor measures
  it (the sensor model says so; whether the view's scan line can be driven is not asked);
* *coverable by executable views* (``n_coverable``): some view whose scan line was verified executable
  (Cartesian path, joint jumps, collisions; shortened views count what they still measure) measures it, or the
  plan covers it;
* *covered* (``n_covered``): a view of the connected plan measures it.

``n_unverified`` counts metrologically coverable points that only views never verified measure (non-zero only
when the time limit stopped the verification). Uncertainties are mm, times s.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CoverageReport", "coverable_mask", "point_uncertainties"]


@dataclass
class CoverageReport:
    """What a plan covers and what it costs (lengths mm, times s)."""

    n_samples: int
    n_coverable: int
    n_covered: int
    n_views: int
    n_candidates: int
    n_valid_candidates: int
    estimated_execution_time_s: float
    measurement_time_s: float
    connection_time_s: float
    mean_uncertainty_mm: float
    max_uncertainty_mm: float
    solver: str
    solver_gap: float | None
    timings_s: dict = field(default_factory=dict)
    unconnected_views: int = 0
    n_coverable_metrology: int = 0
    n_unverified: int = 0
    reachable_share: float | None = None
    time_limit_hit: bool = False
    tilt_mode: str = ""
    warnings: list = field(default_factory=list)

    @property
    def coverage_of_coverable(self) -> float:
        return self.n_covered / self.n_coverable if self.n_coverable else 0.0

    @property
    def coverage_of_samples(self) -> float:
        return self.n_covered / self.n_samples if self.n_samples else 0.0

    @property
    def coverage_of_metrology(self) -> float:
        """covered / metrologically coverable."""
        return self.n_covered / self.n_coverable_metrology if self.n_coverable_metrology else 0.0

    def as_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items()}
        out["coverage_of_coverable"] = self.coverage_of_coverable
        out["coverage_of_samples"] = self.coverage_of_samples
        out["coverage_of_metrology"] = self.coverage_of_metrology
        return out


def point_uncertainties(views: Iterable, n_samples: int) -> np.ndarray:
    """Best predicted uncertainty (mm) per sample over ``views``; inf = no view measures it."""
    best_u = np.full(n_samples, np.inf)
    for view in views:
        np.minimum.at(best_u, view.measurable_indices, view.measurable_uncertainties)
    return best_u


def coverable_mask(
    generated_views: Iterable, n_samples: int, covered: np.ndarray | None = None, verified_only: bool = True
) -> np.ndarray:
    """(n_samples,) bool: measured by some view of the generation whose scan line was verified executable (with
    ``verified_only=False`` also by views not verified yet), or ``covered`` anyway."""
    coverable = np.zeros(n_samples, dtype=bool)
    for view in generated_views:
        if view.mechanics_valid and (view.mechanics_verified or not verified_only):
            coverable[view.measurable_indices] = True
    if covered is not None:
        coverable |= covered
    return coverable
