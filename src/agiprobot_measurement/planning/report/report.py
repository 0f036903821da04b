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

__all__ = [
    "CoverageReport",
    "coverable_mask",
    "metrology_mask",
    "point_uncertainties",
    "run_metadata",
    "run_report",
    "scan_lines",
]


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
    #: views left out of the plan and why ([{"view", "reason"}]): failed moves, their points covered again
    dropped_views: list = field(default_factory=list)
    #: the set cover's proven lower bound of its objective (IP_basic: views; greedy: None; others: their units)
    views_lower_bound: float | None = None
    #: the share of the reachable candidates the metrology evaluated (below 1: the time limit cut it)
    candidates_evaluated_share: float = 1.0

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

    @property
    def verified_share(self) -> float:
        """The share of the measurable points whose views were verified (1.0 unless the time limit stopped the
        verification): measurable minus those only never-verified views see, over measurable."""
        m = self.n_coverable_metrology
        return (m - self.n_unverified) / m if m else 1.0

    def as_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items()}
        out["coverage_of_coverable"] = self.coverage_of_coverable
        out["coverage_of_samples"] = self.coverage_of_samples
        out["coverage_of_metrology"] = self.coverage_of_metrology
        out["verified_share"] = self.verified_share
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


def run_report(run, views: Iterable | None = None) -> CoverageReport:
    """Coverage, view count, execution time and uncertainties of a run's chosen (or the given) views (the run has
    samples)."""
    chosen = list(views) if views is not None else (run.last_ordered or [])
    n = len(run.samples)
    best_u = point_uncertainties(chosen, n)
    covered = np.isfinite(best_u)
    coverable = coverable_mask(run.last_viewpoints, n, covered)
    metrology = coverable_mask(run.last_viewpoints, n, covered, verified_only=False)
    if run.metrology_coverable is not None and len(run.metrology_coverable) == n:
        metrology |= run.metrology_coverable
    # points that only views never verified measure: neither known executable nor known not to be
    open_views = [v for v in run.last_viewpoints if v.mechanics_valid and not v.mechanics_verified]
    unverified = coverable_mask(open_views, n, None, verified_only=False) & ~coverable
    measure = sum(v.get_trajectory_for_measurement().duration for v in chosen if v.get_trajectory_for_measurement())
    connect = sum(v.get_trajectory_to_view().duration for v in chosen if v.get_trajectory_to_view())
    result = run.last_set_cover
    return CoverageReport(
        n_samples=n,
        n_coverable=int(coverable.sum()),
        n_covered=int(covered.sum()),
        n_views=len(chosen),
        n_candidates=0 if run.candidates is None else len(run.candidates.poses),
        n_valid_candidates=len(run.last_viewpoints),
        estimated_execution_time_s=float(measure + connect),
        measurement_time_s=float(measure),
        connection_time_s=float(connect),
        mean_uncertainty_mm=float(best_u[covered].mean()) if covered.any() else float("nan"),
        max_uncertainty_mm=float(best_u[covered].max()) if covered.any() else float("nan"),
        solver=run.parameters.get("solver_type", ""),
        solver_gap=None if result is None else result.gap,
        timings_s=dict(run.timings_s),
        unconnected_views=len(run.unconnected_views),
        n_coverable_metrology=int(metrology.sum()),
        n_unverified=int(unverified.sum()),
        reachable_share=run.reachable_share,
        time_limit_hit=bool(run.time_limit_hit or run.candidates_evaluated_share < 1.0),
        candidates_evaluated_share=float(run.candidates_evaluated_share),
        tilt_mode=str(run.parameters.get("viewpoint_tilt_mode", "")),
        warnings=list(run.warnings),
        dropped_views=[dict(d) for d in run.dropped_views],
        views_lower_bound=None if result is None or result.lower_bound is None else float(result.lower_bound),
    )


def metrology_mask(run) -> np.ndarray:
    """(n_samples,) bool: the samples some candidate view with a reachable anchor measures (the sensor model
    says so), whether or not its scan line can be driven."""
    n = len(run.samples)
    mask = coverable_mask(
        run.last_viewpoints, n, np.isfinite(point_uncertainties(run.last_ordered or [], n)), verified_only=False
    )
    if run.metrology_coverable is not None and len(run.metrology_coverable) == n:
        mask |= run.metrology_coverable
    return mask


def run_metadata(run, version: str) -> dict:
    """Parameters, coverage and timings of a planning run (for the plan file); ``version``: the package's."""
    meta = {"parameters": {k: v for k, v in run.parameters.items()}, "version": version}
    if run.last_set_cover is not None and run.samples is not None:
        report = run_report(run)
        meta["coverage"] = {
            "samples": report.n_samples,
            "coverable_metrology": report.n_coverable_metrology,
            "coverable": report.n_coverable,
            "coverable_executable": report.n_coverable,
            "covered": report.n_covered,
            "unverified": report.n_unverified,
            "verified_share": round(report.verified_share, 6),
            "reachable_share": None if report.reachable_share is None else round(report.reachable_share, 4),
            "time_limit_hit": report.time_limit_hit,
            "candidates_evaluated_share": round(report.candidates_evaluated_share, 6),
            "views": report.n_views,
            "views_lower_bound": report.views_lower_bound,
            "dropped_views": report.dropped_views,
            "estimated_execution_time_s": round(report.estimated_execution_time_s, 3),
            "mean_uncertainty_mm": round(report.mean_uncertainty_mm, 6),
            "max_uncertainty_mm": round(report.max_uncertainty_mm, 6),
            "solver_gap": report.solver_gap,
        }
        stats = run.last_stream_stats
        # dominated candidates dropped at the evaluation, and those evaluated again for failed dominators
        meta["candidates"] = {
            "total": report.n_candidates,
            "measuring": report.n_valid_candidates,
            "dropped_dominated": 0 if stats is None else int(stats.dropped_views),
            "revived": int(run.revived_views),
        }
        meta["planning_time_s"] = {k: round(v, 3) for k, v in run.timings_s.items()}
    return meta


def scan_lines(kinematics, views: Iterable) -> list[tuple[np.ndarray, np.ndarray]]:
    """(start, end) positions (mm) of the laser_emitter_frame's scan lines of ``views`` (those with a
    measurement trajectory), by the forward kinematics ``kinematics``."""
    lines = []
    for trajectory in (v.get_trajectory_for_measurement() for v in views):
        if trajectory is not None:
            ends = kinematics.fk_batch(np.vstack([trajectory.start, trajectory.end]))[:, :3, 3] * 1000.0
            lines.append((ends[0], ends[1]))
    return lines
