"""The parameters of one run of the 2D method, validated at construction (NbvInputError naming the field)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from agiprobot_measurement.common.config import ConfigError, non_negative, positive
from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.scoring import AIM_MODES, ScoreConfig
from agiprobot_measurement.nbv.planar.strategies import SCRIPTS

__all__ = ["S2_ORBIT_BUDGETS", "RunConfig"]

S2_ORBIT_BUDGETS = ("s1_view", "s1_jump", "predicted", "none")


def _positive(name: str, value, allow_none: bool = False, allow_zero: bool = False):
    """A finite number > 0 (>= 0 with ``allow_zero``; None passes with ``allow_none``), checked by
    :mod:`agiprobot_measurement.common.config`; NbvInputError naming ``name``."""
    if value is None and allow_none:
        return None
    try:
        return non_negative(value, name) if allow_zero else positive(value, name)
    except ConfigError as exc:
        raise NbvInputError(str(exc)) from exc


@dataclass(frozen=True)
class RunConfig:
    """Parameters of one run (lengths in cells, angles in degrees, times in seconds)."""

    script: str = "fullpix"
    aim: str = "centre"
    noise_sigma_cells: float = 0.0
    seed: int = 0
    score: ScoreConfig = field(default_factory=ScoreConfig)
    block_unknown: bool = False
    contour_points: int = 7
    s1_reach_cells: float = 3.0
    s2_step_deg: float = 10.0
    circ_step_deg: float = 2.0
    # circpix: laps on the circle (always onward); the sweep also stops after a lap that measured nothing
    circ_max_laps: int = 3
    # circpix plans no view in which a known full cell on the laser behind the candidate, within the depth window,
    # could answer with a free return (an empty candidate would give a D0) when at most
    # ``circ_d0_max_unknown_cells`` unknown cells lie between them: few unknown cells are likely air, which is how
    # the last noise-free D0 came about (rotated rectangle, long baseline: one unknown cell, then known empty ones,
    # then a full cell 10 cells behind). Many unknown cells are likely the body itself. The strict option applies
    # the check whatever lies between; measured, it cuts short-baseline circpix coverage to 0.67-0.85 (rectangle
    # 1.000 -> 0.723), because the far side of the body, already measured, lies within the window. The bound of 2
    # removes that D0 and changes no other noise-free benchmark run's coverage.
    circ_strict_d0_check: bool = False
    circ_d0_max_unknown_cells: int = 2
    max_switches_per_candidate: int = 4
    max_measurements_per_candidate: int = 60
    max_measurements: int | None = None
    max_time_s: float | None = None
    min_possible_improvement: int = 0
    search_step_cells: float = 4.0
    side_step_cells: float = 1.0
    eight_connected: bool = False
    # with noise, a return belongs to the first cell not known empty within this many sigmas of the measured
    # point along the laser (range_finder.assign_noisy_cell)
    noise_window_sigmas: float = 2.0
    # with noise, the return path is left uncarved until it is this many sigmas (of depth along the laser, divided by
    # the cosine of the laser-return angle) out of a body surface that a too deep point lies under
    noise_return_margin_sigmas: float = 2.0
    # with noise, the laser is left uncarved for half a cell plus this many sigmas before the measured point. Off:
    # it stops the slot walls' erasure (U-shape, edge midpoints, short: 33 wall cells carved -> 0) but leaves the
    # air cells before grazed walls unknown; measured over the 48 noisy runs, k = 1 / 2 cut the disc (fullpix,
    # long, edge) to 0.525 and the triangle / U-shape (fullpix, long, edge) to 0.616 / 0.595
    noise_laser_margin_sigmas: float = 0.0
    # with noise, a candidate marked on the way (unmeasurable, or resolved without being measured) may owe its mark
    # to a noisy return, and the contour beyond it is then never reached: once the growth points are exhausted the
    # marks of the cells still unknown are cleared with the forbidden configurations, and the expansion runs again,
    # while a pass adds full cells, at most this many times (0: the report's single pass)
    noise_reopen_passes: int = 8
    # once the growth points are exhausted while full cells still border unknown ones (the contour chain broke at an
    # acute apex, or edge-midpoint aiming lost the contour after one feature), the body is searched again from all
    # round: sources on rings around the known body, the laser through its centre, measured only where the laser's
    # first cell that is not known empty is unknown; a new hit starts a new expansion. At most this many sweeps
    # (0: the report's single expansion), in steps of ``reacquire_step_deg``
    reacquire_sweeps: int = 6
    reacquire_step_deg: float = 5.0
    # after the sweeps, views onto the frontier (unknown cells next to known empty ones) within
    # ``reacquire_frontier_max_distance_cells`` of a known full cell, nearest to the body first, planned on the model
    # (nbv.planar.reacquisition); each hit that leaves growth points starts a new expansion. At most
    # ``reacquire_frontier_max_views`` views per run; ``reacquire_frontier_checks`` frontier cells are tried for a
    # plannable view per view
    reacquire_frontier: bool = True
    # with edge-midpoint aiming, a candidate that ends unmeasurable is planned once more onto its centre
    aim_fallback_centre: bool = True
    reacquire_frontier_max_distance_cells: float = 20.0
    reacquire_frontier_max_views: int = 1500
    reacquire_frontier_checks: int = 50
    # fullpix: after a strategy finds no view, one that planned before may plan again (see ``_Engine.resolve``)
    retry_planned_strategies: bool = True
    # strategy 0 may take a view whose first not-known-empty cell behind cc is not known full when no view has a
    # clear stretch behind cc (see strategies.plan_s0)
    s0_loose_d0_check: bool = True
    # strategy 0 checks the return from the laser's entry point into cc, not only the circle at the aim
    # point (strategies.predicted_return_free)
    predicted_return_check: bool = True
    # strategy 0 prefers views whose return would also be free from the unknown cell the laser reaches should cc be
    # empty (strategies.plan_s0)
    s0_continuation_return_check: bool = False
    # stratpix: before an orbit, strategy 1's planner checks that cc can be looked at at all (see resolve)
    s2_feasibility_check: bool = True
    # strategy 2 passes over orbit steps whose laser can only return an already seen cell (strategies.plan_s2);
    # off, since with depth noise a spurious full cell hides steps that would have measured (module docstring)
    s2_skip_predicted_d2: bool = False
    # strategy 2's camera side: "leading" (ahead of the source in the sense of the turn) or "away" (further from pp)
    s2_camera: str = "leading"
    # where strategy 2's orbit begins: "normal" (the outward normal of pp) or "sensor" (where the sensor is)
    s2_start: str = "normal"
    # strategy 2 counts a hit on any unknown cell next to a full one as its success (A2), the report's general
    # candidate: its candidates are the unit-circle points round the growth point (strategies.classify)
    s2_general_candidates: bool = True
    # how far strategy 2 orbits before it gives up (degrees; the report: a full turn, 360)
    s2_max_turn_deg: float = 360.0
    # stratpix: how strategy 2's orbit is priced against strategy 1's planned jump (see the module docstring).
    # ``"s1_view"`` (default): an orbit step is flown only while it brings the source nearer to strategy 1's planned
    # view, else strategy 1 jumps from there; ``"s1_jump"``: the orbit may cost ``s2_orbit_budget_factor`` times
    # that jump; ``"predicted"``: decided once, by the motion until the orbit aims at cc; ``"none"``: the full turn
    s2_orbit_budget: str = "s1_view"
    # the ``"s1_jump"`` budget is this multiple of strategy 1's jump (measured: 1 cuts the long-baseline triangle to
    # 0.842 coverage, 2 and 3 keep every coverage; 3 gives the most stratpix <= fullpix wins of that mode)
    s2_orbit_budget_factor: float = 3.0
    # stratpix: when strategy 1's planner finds no look-through view before an orbit and strategy 0 planned this
    # candidate before, strategy 0 re-plans it (its failed configurations forbidden), as fullpix's S1 -> S0
    # recovery does, instead of the candidate being marked unmeasurable (see the module docstring)
    s2_no_s1_view_back_to_s0: bool = True

    def __post_init__(self) -> None:
        if self.script not in SCRIPTS:
            raise NbvInputError(f"unknown script {self.script!r}; choose one of {', '.join(SCRIPTS)}")
        if self.aim not in AIM_MODES:
            raise NbvInputError(f"unknown aim {self.aim!r}; choose one of {', '.join(AIM_MODES)}")
        _positive("noise_sigma_cells", self.noise_sigma_cells, allow_zero=True)
        _positive("s1_reach_cells", self.s1_reach_cells)
        _positive("s2_step_deg", self.s2_step_deg)
        _positive("s2_max_turn_deg", self.s2_max_turn_deg)
        _positive("s2_orbit_budget_factor", self.s2_orbit_budget_factor)
        _positive("circ_step_deg", self.circ_step_deg)
        _positive("search_step_cells", self.search_step_cells)
        _positive("side_step_cells", self.side_step_cells)
        _positive("noise_return_margin_sigmas", self.noise_return_margin_sigmas, allow_zero=True)
        _positive("noise_window_sigmas", self.noise_window_sigmas, allow_zero=True)
        _positive("noise_laser_margin_sigmas", self.noise_laser_margin_sigmas, allow_zero=True)
        if self.s2_camera not in ("leading", "away"):
            raise NbvInputError(f"s2_camera must be 'leading' or 'away', got {self.s2_camera!r}")
        if self.s2_orbit_budget not in S2_ORBIT_BUDGETS:
            raise NbvInputError(
                f"s2_orbit_budget must be one of {', '.join(S2_ORBIT_BUDGETS)}, got {self.s2_orbit_budget!r}"
            )
        if self.s2_start not in ("normal", "sensor"):
            raise NbvInputError(f"s2_start must be 'normal' or 'sensor', got {self.s2_start!r}")
        _positive("max_time_s", self.max_time_s, allow_none=True)
        if int(self.circ_d0_max_unknown_cells) < 0:
            raise NbvInputError(f"circ_d0_max_unknown_cells must be >= 0, got {self.circ_d0_max_unknown_cells!r}")
        if int(self.noise_reopen_passes) < 0:
            raise NbvInputError(f"noise_reopen_passes must be >= 0, got {self.noise_reopen_passes!r}")
        if int(self.reacquire_sweeps) < 0:
            raise NbvInputError(f"reacquire_sweeps must be >= 0, got {self.reacquire_sweeps!r}")
        if not (math.isfinite(self.reacquire_step_deg) and 0.5 <= self.reacquire_step_deg <= 90.0):
            raise NbvInputError(f"reacquire_step_deg must be in [0.5, 90], got {self.reacquire_step_deg!r}")
        _positive("reacquire_frontier_max_distance_cells", self.reacquire_frontier_max_distance_cells)
        for name in ("reacquire_frontier_max_views", "reacquire_frontier_checks"):
            if int(getattr(self, name)) < 0:
                raise NbvInputError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("contour_points", "max_switches_per_candidate", "max_measurements_per_candidate", "circ_max_laps"):
            if int(getattr(self, name)) < 1:
                raise NbvInputError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if self.max_measurements is not None and int(self.max_measurements) < 1:
            raise NbvInputError(f"max_measurements must be >= 1 or None, got {self.max_measurements!r}")
        if int(self.min_possible_improvement) < 0:
            raise NbvInputError(f"min_possible_improvement must be >= 0, got {self.min_possible_improvement!r}")
