"""The measurement loop of the report (Fig. 3, Fig. 5) and its three scripts ``circpix``, ``fullpix``, ``stratpix``.

One run: the range finder starts in the home pose and follows the a-priori search trajectory until it measures
something (abort when nothing is found), takes small sideways steps until the growth point has a full neighbour,
then expands growth points: ``GetNearestPP`` picks the growth point ``pp`` nearest to the previous one, its
predicted point becomes the candidate ``cc``, and the strategies (:mod:`.strategies`) plan and classify measurements
until ``cc`` is resolved. The run ends when the growth points are exhausted (the report's rule), or earlier on an
optional budget (measurements, time) or when ``Possible_Improvement`` falls below a threshold.

Documented choices where the report is silent:

- Home pose and search trajectory: the source runs along a line below the scene, laser pointing +y, placed so that
  the far edge of the camera's depth window lies on the scene's middle row (a body in the scene's lower half is
  seen), from ``x = 0`` to ``x = nx - 1`` in steps of ``search_step_cells``; the sideways steps continue along it
  by ``side_step_cells``. When that line measures nothing (the part of the body in the depth window is shadowed
  by a nearer part, or lies nearer than the window), the line is moved away from the scene in steps of 0.8 of the
  window's depth until the window's near edge has passed the scene's edge, then the same from the other three
  sides (a rotated comb whose teeth hide its bar was never found from one line).
- ``Possible_Improvement(W)`` is the number of remaining scanning candidates (``getcandidates2d`` cells of all
  growth points): it is what the implemented stop drives to zero.
- Every cell that was ``cc`` once and is still unknown is marked in the working copy (+0.1 unmeasurable, -0.1
  otherwise), so it is never a candidate again.
- With depth noise (the report's main real-data failure, no rule given): the return is filed under the cell half a
  cell deeper than the measured point; if that cell is known empty, under the first cell further along the laser,
  within ``noise_window_sigmas`` sigma, that is not known empty (:func:`.range_finder.assign_noisy_cell`; if all
  are known empty, the report's fusion makes the conflicting cell unknown so it can be measured again). The
  laser's free part stops half a cell before the point; the return path's free part starts only where a point
  measured ``noise_return_margin_sigmas`` sigma too deep would have left the body, ``0.5 + k sigma / cos(theta)``
  with ``theta`` the laser-camera angle at the point (:func:`.range_finder.noisy_return_margin_cells`). With a
  fixed half cell, at RFlength 250 (theta = 54 deg) the returns of too deep points erased the surface just
  measured (disc, fullpix, long, sigma 0.3: coverage 0.614 -> 0.95 with k = 2).
- With depth noise the report's "no point is a candidate twice" is relaxed once the growth points are exhausted:
  a noisy return can get a candidate marked (unmeasurable, or resolved without a measurement of it) and break the
  contour-following chain, so the contour beyond is never reached (U-shape, edge midpoints, short baseline: 75 of
  the slot's right-wall cells never became candidates). The marks of the cells still unknown are then cleared,
  with the forbidden configurations, and the expansion runs again, while a pass adds full cells, at most
  ``noise_reopen_passes`` (8) times (that U-shape run: coverage 0.804 -> 0.912). Noise-free runs keep one pass.
- Contour fits and predicted points use the model's cells as in the noise-free case; the raw (noisy) points are
  kept per cell for the export.
- The camera-in-front rule of :mod:`.scoring` applies to ``getcandidates2d`` candidates only, not to the general
  candidates of a contour end (beyond an apex the outer side of the continuation is not known yet).
- A candidate is unmeasurable only once every planning strategy has failed to plan it. In ``fullpix`` (recovery
  S0 <-> S1 only) a strategy that planned before may plan again when the other finds no view, its failed
  configurations being forbidden (``retry_planned_strategies``); in ``stratpix`` a strategy is not re-entered
  after it found no view, but strategy 0 re-plans when strategy 1 has no view for an orbit (below).
- ``stratpix`` switches E0 -> S2 and D1 -> S2 (``fullpix``: E0 -> S1, D1 -> S0). Strategy 2 cannot tell an
  unmeasurable candidate (the report), strategy 1's circle of visibility can: before an orbit starts, strategy 1's
  planner is asked, without measuring, for a look-through view; if it has none, the candidate is unmeasurable and
  no orbit is flown (``s2_feasibility_check``; U-shape short path 30102 -> 10876 cells).
- ``stratpix``'s orbit budget (``s2_orbit_budget``; the report claims a smoother path for S2, not a shorter one,
  and gives no rule): the same probe's planned look-through view is strategy 1's alternative. ``"s1_view"``
  (default), a path-aware strategy switch: the probe is asked before every orbit, also after a failed jump (D1,
  that configuration forbidden), and an orbit step is flown only if it brings the source nearer to the source of
  strategy 1's planned view, i.e. while the orbit lies on the way to that jump and each of its short moves replaces
  part of it; the first step that does not (the lead-in to the orbit's start included) is not flown and strategy 1
  jumps from where the sensor is. With no switch left for the candidate, that step ends it as unmeasurable instead
  of flying the rest of the turn. ``"s1_jump"``: the orbit's accumulated source motion, lead-in included, may reach
  ``s2_orbit_budget_factor`` times strategy 1's jump from the sensor (the motion that the Pohyb term scores); the
  step that would exceed it is not flown and strategy 1 takes over; should that jump fail too (D1), strategy 2
  flies its full orbit unprobed and unbudgeted. ``"predicted"``: decided once before the orbit, by the motion until
  the orbit's laser aims at ``cc`` (:func:`.strategies.orbit_motion_to`). ``"none"``: the full turn. Measured
  (noise-free, centre aim, stratpix paths <= fullpix over the six objects, short / long baseline): none 3/6 and 2/6;
  predicted 4/6 and 2/6; s1_jump factor 1 5/6 and 4/6 (but the long-baseline triangle's coverage fell 0.988 ->
  0.842), factor 2 5/6 and 2/6, factor 3 5/6 and 3/6; s1_view 6/6 and 6/6, every coverage >= 0.95 (the
  long-baseline disc 1.000 -> 0.982, the lowest). Without the "no switch left" end, s1_view gives 5/6 short (the
  triangle's orbits after D1, flown unchecked once the switches are used up, lead in from across the body and
  return a seen cell) and stratpix's short-baseline transfers exceed its long-baseline ones.
- ``s2_no_s1_view_back_to_s0`` (on): when the probe before an orbit finds no look-through view and strategy 0
  planned the candidate before, strategy 0 re-plans it (its failed configurations forbidden, a switch counted)
  instead of the candidate being marked unmeasurable, the recovery ``fullpix`` has by S1 -> S0. Leaving orbits
  early makes this matter: with s1_view and the option off, the long-baseline triangle's hypotenuse chain breaks at
  two E0 candidates that strategy 1 cannot plan and the coverage falls to 0.842; on, it is 0.990.
- Strategy 2 flies its orbit blind, as in the report. Option ``s2_skip_predicted_d2`` (off): an orbit step whose
  laser can only return an already seen cell (its first cell not known empty is known full) is passed over without
  measuring, so the source goes straight to the next step that may teach something. Measured: noise-free it
  shortens the long-baseline triangle's path 7931 -> 6996 cells (D2 outcomes 60 -> 37) and flips no path target;
  with depth noise a spurious full cell makes it pass over steps that would have measured, and the U-shape's
  noisy long-baseline coverage falls 0.940 -> 0.884.
- ``circpix``: the source moves on the circle around the scene centre through the first hit at the standoff, in
  steps of ``circ_step_deg`` counter-clockwise and never back. At each stop it measures, one after the other, the
  candidates it can see (laser and camera path free of known full cells, depth within the camera's field, no known
  full cell on the laser behind the candidate before the first cell not known empty, nor within 5 cells of it, nor
  one with a free return behind at most ``circ_d0_max_unknown_cells`` unknown cells: each would make an empty
  candidate answer with an already seen cell), the one nearest the standoff first. "Never turning back" is kept
  literally: the source keeps going round in the same sense, for up to ``circ_max_laps`` laps, and stops after a
  lap that could measure nothing. The candidates still left then cannot be planned from the circle: they are marked
  unmeasurable (the report's rule for a candidate without a plannable view), which exhausts the growth points.

- Re-acquisition once the growth points are exhausted: sweeps round the known body (``reacquire_sweeps``, see
  :func:`.reacquisition.reacquire_sweep`), then views onto the model's frontier next to the known body
  (``reacquire_frontier``, :mod:`.reacquisition`); each hit that leaves growth points starts a new expansion. With
  edge-midpoint aiming a candidate that ends unmeasurable is planned once more onto its centre
  (``aim_fallback_centre``).

Termination: each candidate is chosen once, and for one candidate every failed measurement forbids its configuration
(at most 2 x 360 per aim point and strategy), strategy 2 stops after a full turn, and strategy switches are capped;
so the number of measurements is finite on any finite grid (and ``max_measurements_per_candidate`` caps it further);
with noise the expansion runs at most ``1 + noise_reopen_passes`` times; a candidate falls back to the centre aim
once, and the frontier pass tries each cell once and takes at most ``reacquire_frontier_max_views`` views.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from agiprobot_measurement.nbv.planar.grid import (
    EMPTY,
    FULL,
    PROBABLY_EMPTY,
    PROBABLY_FULL,
    UNKNOWN,
    MeasuredPoints,
    validate_truth,
)
from agiprobot_measurement.nbv.planar.predicates import (
    compute_direction,
    driving_candidate_mask,
    growth_mask,
    outward_normal,
    predicted_point,
)
from agiprobot_measurement.nbv.planar.range_finder import (
    RangeFinder2D,
    apply_measurement,
    assign_noisy_cell,
    cell_of_point,
    noisy_return_margin_cells,
    scan,
)
from agiprobot_measurement.nbv.planar.reacquisition import reacquire_frontier, reacquire_sweep
from agiprobot_measurement.nbv.planar.run_config import RunConfig
from agiprobot_measurement.nbv.planar.scoring import aim_points
from agiprobot_measurement.nbv.planar.strategies import (
    TRANSITIONS,
    Action,
    NoView,
    Strategy,
    classify,
    is_strict_candidate,
    label_of,
    orbit_motion_to,
    plan_s0,
    plan_s1,
    plan_s2,
    predicted_return_free,
    start_orbit,
)
from agiprobot_measurement.nbv.planar.traversal import first_blocking, supercover_cells
from agiprobot_measurement.nbv.planar.visibility import N_SECTORS, make_circle_of_visibility, update_circ

__all__ = ["TERMINATION_REASONS", "MeasurementRecord", "RunResult", "run"]

TERMINATION_REASONS = (
    "growth_points_exhausted",
    "nothing_found",
    "measurement_budget",
    "time_budget",
    "possible_improvement_below_threshold",
    "circle_completed",
)


@dataclass
class MeasurementRecord:
    """One measurement: the pose, what came back and how it was classified."""

    pos: np.ndarray
    point: np.ndarray | None
    cell: tuple[int, int] | None
    label: str
    target: tuple[int, int] | None


@dataclass
class RunResult:
    """Everything a run produced."""

    truth: np.ndarray
    model: np.ndarray  # fused measurements, {-1, 0, 1}
    working: np.ndarray  # the planner's copy with the +-0.1 marks
    records: list
    points: MeasuredPoints
    unmeasurable: list
    outcomes: Counter
    termination: str
    run_time_s: float
    rf: RangeFinder2D
    config: RunConfig

    @property
    def sources(self) -> np.ndarray:
        return np.array([r.pos[0] for r in self.records]).reshape(-1, 2)

    @property
    def cameras(self) -> np.ndarray:
        return np.array([r.pos[1] for r in self.records]).reshape(-1, 2)

    @property
    def d0_count(self) -> int:
        return int(self.outcomes.get("D0", 0))


class _BudgetExceeded(Exception):
    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class _Engine:
    def __init__(self, truth: np.ndarray, rf: RangeFinder2D, cfg: RunConfig):
        self.truth = truth
        self.rf = rf
        self.cfg = cfg
        self.shape = truth.shape
        self.m = np.zeros(self.shape)
        self.w = np.zeros(self.shape)
        self.marks = np.zeros(self.shape)
        self.points = MeasuredPoints()
        self.records: list[MeasurementRecord] = []
        self.unmeasurable: list[tuple[int, int]] = []
        self.outcomes: Counter = Counter()
        self.rng = np.random.default_rng(cfg.seed)
        self.t0 = time.perf_counter()
        self.current_source: np.ndarray | None = None
        self.circles: dict[tuple[float, float], np.ndarray] = {}
        self.forbidden: dict[tuple[int, int, int], np.ndarray] = {}
        self.bbox = None  # (i0, i1, j0, j1) of the known cells, to keep the predicates local
        self.full_lost = False

    # --- measuring -------------------------------------------------------------------------------------------
    def _check_budget(self) -> None:
        cfg = self.cfg
        if cfg.max_measurements is not None and len(self.records) >= cfg.max_measurements:
            raise _BudgetExceeded("measurement_budget")
        if cfg.max_time_s is not None and time.perf_counter() - self.t0 > cfg.max_time_s:
            raise _BudgetExceeded("time_budget")

    def measure(self, pos: np.ndarray, target, strategy: Strategy | None, untargeted_label: str = "search"):
        """Measure on the ground truth, classify against the model before the update, fuse the return."""
        self._check_budget()
        reading = scan(self.truth, pos, self.rf, self.cfg.eight_connected)
        point = cell = None
        if reading is not None:
            d = (pos[2] - pos[0]) / np.hypot(*(pos[2] - pos[0]))
            sigma = self.cfg.noise_sigma_cells
            if sigma > 0:
                # depth noise along the laser, the report's real-data failure mode
                point = reading.point + self.rng.normal(0.0, sigma) * d
                if self.cfg.noise_window_sigmas > 0:
                    cell, snapped = assign_noisy_cell(self.m, pos, point, self.cfg.noise_window_sigmas * sigma)
                else:
                    cell, snapped = cell_of_point(point + 0.5 * d, d), False
                if snapped:
                    self.outcomes["noise: snapped past known empty"] += 1
            else:
                point, cell = reading.point, reading.cell
            if not (0 <= cell[0] < self.shape[0] and 0 <= cell[1] < self.shape[1]):
                point = cell = None
        kind = classify(cell, target, self.m, self.w, strategy == Strategy.S2 and self.cfg.s2_general_candidates)
        label = label_of(strategy, kind) if strategy is not None else untargeted_label
        self.outcomes[label] += 1
        self.records.append(MeasurementRecord(np.array(pos, dtype=float), point, cell, label, target))
        self.current_source = np.array(pos[0], dtype=float)
        if point is not None:
            self._fuse(pos, point, cell)
        return kind, cell, label

    def _fuse(self, pos, point, cell) -> None:
        """Fuse a return (free rays, the full cell) and file the measured point under ``cell``."""
        was_full = self.m == FULL  # a full copy is cheap next to the traversal and keeps the bookkeeping exact
        sigma = self.cfg.noise_sigma_cells
        # the half cell of the cell guess (range_finder.assign_noisy_cell), plus an optional k sigma: a point
        # measured e too deep lies e inside the body, and a laser carved up to half a cell before it erases the
        # surface cells it entered (see RunConfig.noise_laser_margin_sigmas)
        margin = 0.5 + self.cfg.noise_laser_margin_sigmas * sigma if sigma > 0 else 0.0
        back_margin = 0.0
        if sigma > 0:
            back_margin = noisy_return_margin_cells(pos, point, self.cfg.noise_return_margin_sigmas * sigma)
        free, full_cell = apply_measurement(self.m, pos, point, cell, self.cfg.eight_connected, margin, back_margin)
        touched = free if full_cell is None else np.vstack([free, np.array([full_cell])])
        if len(touched) == 0:
            return
        ti, tj = touched[:, 0], touched[:, 1]
        mv = self.m[ti, tj]
        self.w[ti, tj] = np.where(mv != UNKNOWN, mv, self.marks[ti, tj])
        if full_cell is not None:
            self.points.add(point, full_cell, len(self.records) - 1)
        newly_full = touched[(self.m[ti, tj] == FULL) & ~was_full[ti, tj]]
        if (was_full[ti, tj] & (self.m[ti, tj] != FULL)).any():
            self.full_lost = True
        self._grow_bbox(touched)
        self._update_circles(newly_full)

    def _grow_bbox(self, cells: np.ndarray) -> None:
        i0, j0 = cells.min(axis=0)
        i1, j1 = cells.max(axis=0) + 1
        if self.bbox is None:
            self.bbox = [i0, i1, j0, j1]
        else:
            b = self.bbox
            self.bbox = [min(b[0], i0), max(b[1], i1), min(b[2], j0), max(b[3], j1)]

    def _update_circles(self, newly_full: np.ndarray) -> None:
        if not self.circles:
            return
        if self.full_lost or self.cfg.block_unknown:
            # a cell stopped being opaque (noise conflict, or unknown -> empty): zeroing cannot undo that, rebuild
            for xs in list(self.circles):
                self.circles[xs] = make_circle_of_visibility(self.w, np.array(xs), self.cfg.block_unknown)
            self.full_lost = False
        elif len(newly_full):
            for xs, circ in self.circles.items():
                update_circ(circ, np.array(xs), newly_full, in_place=True)

    # --- planner state --------------------------------------------------------------------------------------
    def window(self, margin: int = 2):
        i0, i1, j0, j1 = self.bbox
        return (
            max(i0 - margin, 0),
            min(i1 + margin, self.shape[0]),
            max(j0 - margin, 0),
            min(j1 + margin, self.shape[1]),
        )

    def growth_points(self) -> np.ndarray:
        if self.bbox is None:
            return np.zeros((0, 2), dtype=int)
        i0, i1, j0, j1 = self.window()
        return np.argwhere(growth_mask(self.w[i0:i1, j0:j1])) + np.array([i0, j0])

    def possible_improvement(self) -> int:
        if self.bbox is None:
            return 0
        i0, i1, j0, j1 = self.window()
        return int(driving_candidate_mask(self.w[i0:i1, j0:j1]).sum())

    def nearest_growth_point(self, pp_old):
        pts = self.growth_points()
        if len(pts) == 0:
            return None
        d2 = ((pts - np.asarray(pp_old, dtype=float)) ** 2).sum(axis=1)
        k = int(np.argmin(d2))
        return int(pts[k, 0]), int(pts[k, 1])

    def mark(self, cell, value: float) -> None:
        if self.m[cell] == UNKNOWN:
            self.marks[cell] = value
            self.w[cell] = value

    def circles_for(self, aims: np.ndarray) -> np.ndarray:
        out = np.empty((len(aims), N_SECTORS), dtype=np.uint8)
        for a, xs in enumerate(aims):
            key = (float(xs[0]), float(xs[1]))
            if key not in self.circles:
                self.circles[key] = make_circle_of_visibility(self.w, xs, self.cfg.block_unknown)
            out[a] = self.circles[key]
        return out

    def forbid_array(self, strategy: Strategy, cc, n_aims: int) -> np.ndarray:
        key = (int(strategy), int(cc[0]), int(cc[1]), int(n_aims))
        if key not in self.forbidden:
            self.forbidden[key] = np.zeros((n_aims, N_SECTORS, 2), dtype=bool)
        return self.forbidden[key]

    # --- the report's loop ------------------------------------------------------------------------------------
    def initial_search(self):
        """The a-priori search: the growth point to start from (a measured cell with a full neighbour), or None.

        The report's line first (see the module docstring); when it measures nothing (the part of the body in the
        depth window is shadowed, or lies nearer than the window), the same line further from the scene in steps
        of 0.8 of the window's depth until the window's near edge has passed the scene's edge, then the same from
        the other three sides of the scene (the line turned about the scene centre by 90, 180, 270 degrees)."""
        rf = self.rf
        nx, ny = self.shape
        near, far = rf.depth_window_cells()
        # the far edge of the camera's depth window on the scene's middle row: the search sees the body's lower half
        y_line = (ny - 1) / 2 - min(far, 2 * rf.standoff_cells) + 1.0
        band = 0.8 * (min(far, 2 * rf.standoff_cells) - near)
        step = self.cfg.search_step_cells
        centre = np.array([(nx - 1) / 2, (ny - 1) / 2])
        for turn in range(4):
            along, across = (nx, ny) if turn % 2 == 0 else (ny, nx)
            c, s = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[turn]
            rot = np.array([[c, -s], [s, c]])
            offset = y_line - centre[1]  # the line's signed distance from the centre (negative: below)
            shifts = 0 if band <= 0 else max(0, math.ceil((offset + near + (across - 1) / 2) / band))
            for k in range(shifts + 1):
                line = (rot, offset - k * band, (along - 1) / 2)
                hit, t_hit = None, None
                for t in np.arange(0.0, along - 1 + 1e-9, step):
                    _, cell, _ = self.measure(self._search_pose(centre, line, t), None, None)
                    if cell is not None:
                        hit, t_hit = cell, t
                        break
                if hit is not None:
                    return self._side_steps(centre, line, hit, t_hit)
        return None

    def _search_pose(self, centre, line, t):
        """The pose at ``t`` (cells from the line's start) of a search line (rotation, offset from the centre,
        half length): the source on the line, the laser across it towards the scene."""
        rot, offset, half = line
        source = centre + rot @ np.array([t - half, offset])
        return self.rf.pose_through(source, source + rot @ np.array([0.0, self.rf.standoff_cells]), 1)

    def _side_steps(self, centre, line, hit, t):
        """Small sideways steps along the search line until the growth point has a full neighbour (planning
        needs a contour direction); the growth point."""
        step = self.cfg.search_step_cells
        for _ in range(int(4 * step / self.cfg.side_step_cells) + 8):
            i0, i1 = max(hit[0] - 1, 0), hit[0] + 2
            j0, j1 = max(hit[1] - 1, 0), hit[1] + 2
            if (self.m[i0:i1, j0:j1] == FULL).sum() >= 2:
                break
            t += self.cfg.side_step_cells
            _, cell, _ = self.measure(self._search_pose(centre, line, t), None, None)
            if cell is not None:
                hit = cell
        return hit

    def resolve(self, cc, pp, transitions) -> tuple[int, int]:
        """Run the strategy state machine on ``cc``; returns the growth point to continue from. With edge-midpoint
        aiming and ``aim_fallback_centre``, a candidate that ends unmeasurable is planned once more with centre aim
        (its mark lifted): a narrow spike's cell can lack a view onto any edge midpoint and still have one onto its
        centre."""
        n_before = len(self.unmeasurable)
        out = self._resolve(cc, pp, transitions, self.cfg.aim)
        if self.cfg.aim == "centre" or not self.cfg.aim_fallback_centre or len(self.unmeasurable) <= n_before:
            return out
        last = self.unmeasurable[-1]
        if self.m[last] != UNKNOWN:
            return out
        self.unmeasurable.pop()
        self.marks[last] = 0.0
        self.w[last] = UNKNOWN
        self.outcomes["aim fallback: centre"] += 1
        return self._resolve(last, pp, transitions, "centre")

    def _resolve(self, cc, pp, transitions, aim: str) -> tuple[int, int]:
        cfg = self.cfg
        strategy = Strategy.S0
        switches = 0
        spent = 0
        orbit = None
        orbit_budget, orbit_spent = math.inf, 0.0  # strategy 2's motion budget (s2_orbit_budget) and its use
        orbit_left = False  # an orbit of this candidate was left for strategy 1's jump
        orbit_goal = None  # s1_view: the source position of strategy 1's planned view, which the orbit must approach
        tried: set[Strategy] = set()
        planned: set[Strategy] = set()
        self.circles = {}
        while True:
            if self.m[cc] != UNKNOWN:
                # another measurement of this candidate's cycle already decided it
                self.outcomes["resolved on the way"] += 1
                return cc if self.m[cc] == FULL else pp
            aims = aim_points(cc, aim)
            direction = compute_direction(self.w, pp, cfg.contour_points)
            normal = outward_normal(self.w, pp, direction)
            # a contour end's general candidate lies where the outer side is not known yet (beyond an apex): the
            # camera-in-front rule, made for the side the contour shows, would exclude the views round the apex
            score_cfg = cfg.score if is_strict_candidate(self.w, cc) else replace(cfg.score, camera_front=False)
            if strategy == Strategy.S0:
                plan = plan_s0(
                    self.m, self.rf, cc, aims, self.circles_for(aims), normal, self.current_source, score_cfg,
                    self.forbid_array(strategy, cc, len(aims)), loose=cfg.s0_loose_d0_check,
                    return_check=cfg.predicted_return_check, continuation_check=cfg.s0_continuation_return_check,
                )  # fmt: skip
            elif strategy == Strategy.S1:
                plan = plan_s1(
                    self.m, self.w, self.rf, cc, aims, self.circles_for(aims), normal, self.current_source, cfg.score,
                    self.forbid_array(strategy, cc, len(aims)), cfg.s1_reach_cells,
                )  # fmt: skip
            else:
                # s1_view: strategy 1's planner is asked before every orbit (after a failed jump too, that
                # configuration forbidden), and the orbit is steered by it. The other budgets: once an orbit of this
                # candidate was left for strategy 1's jump and that jump failed too, strategy 2 runs its full orbit
                # unprobed: strategy 1 was tried for real, and orbiting is what remains
                s1_view = cfg.s2_orbit_budget == "s1_view"
                mode = "none" if not s1_view and (orbit_left or Strategy.S1 in tried) else cfg.s2_orbit_budget
                probe = None
                if orbit is None and (s1_view or not orbit_left) and (cfg.s2_feasibility_check or mode != "none"):
                    # strategy 2 cannot tell an unmeasurable candidate (the report): strategy 1's circle-of-visibility
                    # test, which can, is asked first, without measuring; no look-through view -> unmeasurable (or,
                    # with s2_no_s1_view_back_to_s0, strategy 0 re-plans a candidate it planned before)
                    probe = plan_s1(
                        self.m, self.w, self.rf, cc, aims, self.circles_for(aims), normal, self.current_source,
                        cfg.score, self.forbid_array(Strategy.S1, cc, len(aims)), cfg.s1_reach_cells,
                    )  # fmt: skip
                    if isinstance(probe, NoView) and cfg.s2_feasibility_check:
                        if (
                            cfg.s2_no_s1_view_back_to_s0
                            and Strategy.S0 in planned
                            and switches < cfg.max_switches_per_candidate
                        ):
                            # strategy 0 planned cc before: it re-plans, its failed configurations forbidden
                            self.outcomes["S2 not started: S1 finds no view, back to S0"] += 1
                            strategy, switches = Strategy.S0, switches + 1
                            continue
                        self.outcomes["S2 not started: S1 finds no view"] += 1
                        return self._unmeasurable(cc, pp)
                    orbit_budget, orbit_spent, orbit_goal = math.inf, 0.0, None
                    if mode != "none" and not isinstance(probe, NoView) and self.current_source is not None:
                        if s1_view:
                            orbit_goal = np.array(probe.pos[0], dtype=float)
                        else:
                            # the orbit's motion budget: the source motion of strategy 1's planned jump
                            orbit_budget = cfg.s2_orbit_budget_factor * float(
                                np.hypot(*(probe.pos[0] - self.current_source))
                            )
                if orbit is None:
                    orbit = start_orbit(
                        pp, normal, direction, cc, self.current_source, cfg.s2_step_deg, cfg.s2_start,
                        cfg.s2_max_turn_deg, cfg.s2_camera,
                    )  # fmt: skip
                    if (
                        mode == "predicted"
                        and math.isfinite(orbit_budget)
                        and switches < cfg.max_switches_per_candidate
                    ):
                        predicted = orbit_motion_to(self.rf, orbit, cc, self.current_source)
                        if predicted > orbit_budget:
                            # reaching a view of cc on the orbit would cost more motion than strategy 1's jump
                            self.outcomes["S2 not started: S1's jump is shorter"] += 1
                            strategy, switches, orbit, orbit_left = Strategy.S1, switches + 1, None, True
                            continue
                        orbit_budget = math.inf
                plan = plan_s2(self.rf, orbit, self.m if cfg.s2_skip_predicted_d2 else None)
                if not isinstance(plan, NoView) and orbit_goal is not None:
                    # s1_view: the step is flown only if it brings the source nearer to strategy 1's planned view,
                    # i.e. while the orbit is on the way to that jump; else strategy 1 jumps from here
                    d_now = float(np.hypot(*(self.current_source - orbit_goal)))
                    if float(np.hypot(*(plan.pos[0] - orbit_goal))) >= d_now:
                        if switches >= cfg.max_switches_per_candidate:
                            # no switch left for the jump: the candidate ends here instead of flying the rest of the
                            # turn away from the only other view
                            self.outcomes["S2 orbit ended: leads away from S1's view, no switch left"] += 1
                            return self._unmeasurable(cc, pp)
                        self.outcomes["S2 orbit left for S1: step leads away from S1's view"] += 1
                        strategy, switches, orbit, orbit_left, orbit_goal = Strategy.S1, switches + 1, None, True, None
                        continue
                if not isinstance(plan, NoView) and mode == "s1_jump":
                    step = float(np.hypot(*(plan.pos[0] - self.current_source)))
                    if orbit_spent + step > orbit_budget and switches < cfg.max_switches_per_candidate:
                        # the orbit would now cost more motion than strategy 1's single jump: take the jump
                        self.outcomes["S2 orbit left for S1: longer than S1's jump"] += 1
                        strategy, switches, orbit, orbit_left = Strategy.S1, switches + 1, None, True
                        continue
                    orbit_spent += step
            if isinstance(plan, NoView):
                # a candidate is unmeasurable only once every planning strategy has failed to plan it. In fullpix,
                # whose only recovery is S0 <-> S1, a strategy that planned before (its failed configurations now
                # forbidden) may plan again; in stratpix strategy 2 is the recovery and a strategy that planned
                # once is not re-entered (the report: strategy 2 fails after a full turn)
                tried.add(strategy)
                if cfg.script != "fullpix" or not cfg.retry_planned_strategies:
                    tried |= planned
                untried = [s for s in (Strategy.S0, Strategy.S1) if s not in tried]
                if untried and switches < cfg.max_switches_per_candidate:
                    self.outcomes[f"no view {strategy.name}->{untried[0].name}"] += 1
                    strategy, switches = untried[0], switches + 1
                    continue
                return self._unmeasurable(cc, pp)
            planned.add(strategy)
            if spent >= cfg.max_measurements_per_candidate:
                return self._unmeasurable(cc, pp)
            _, cell, label = self.measure(plan.pos, cc, strategy)
            spent += 1
            action, nxt = transitions[label]
            if action in (Action.REPLAN, Action.SWITCH) and plan.key is not None:
                self.forbid_array(strategy, cc, len(aims))[plan.key] = True
            if action == Action.SUCCESS:
                self.mark(cc, PROBABLY_EMPTY)
                return cell if cell is not None and self.m[cell] == FULL else pp
            if action == Action.RETARGET:
                self.mark(cc, PROBABLY_EMPTY)
                return cell if self.m[cell] == FULL else pp
            if action == Action.REPLAN or action == Action.NEXT_ANGLE:
                continue
            if action == Action.SWITCH:
                switches += 1
                if switches > cfg.max_switches_per_candidate:
                    return self._unmeasurable(cc, pp)
                strategy = nxt
                orbit = None
                continue
            if action == Action.NEXT_CANDIDATE:
                self.mark(cc, PROBABLY_EMPTY)
                nxt_cc = predicted_point(self.w, pp, cfg.contour_points) if self.w[pp] == FULL else None
                if nxt_cc is None:
                    return pp
                cc, strategy, switches, spent, orbit, tried, planned = nxt_cc, nxt, 0, 0, None, set(), set()
                orbit_left = False
                self.circles = {}
                continue
            return self._unmeasurable(cc, pp)

    def _unmeasurable(self, cc, pp):
        self.unmeasurable.append((int(cc[0]), int(cc[1])))
        self.mark(cc, PROBABLY_FULL)
        return pp

    def expand(self, first_hit) -> str:
        """Expand growth points until they are exhausted; with depth noise, then reopen the marked candidates and
        expand again, while a pass adds full cells (``noise_reopen_passes``); then, while full cells border unknown
        ones, sweep round the body for a new hit and expand from it (``reacquire_sweeps``); then views onto the
        frontier (``reacquire_frontier``)."""
        reason = self.expand_with_reopening(first_hit)
        for _ in range(self.cfg.reacquire_sweeps):
            if reason != "growth_points_exhausted":
                break
            full_before = int(np.count_nonzero(self.m == FULL))
            reason = reacquire_sweep(self)
            if int(np.count_nonzero(self.m == FULL)) <= full_before:
                break
        if reason == "growth_points_exhausted" and self.cfg.reacquire_frontier:
            reason = reacquire_frontier(self)
        return reason

    def expand_with_reopening(self, first_hit) -> str:
        reason = self._expand_pass(first_hit)
        if self.cfg.noise_sigma_cells <= 0:
            return reason
        for _ in range(self.cfg.noise_reopen_passes):
            reopened = (self.marks != 0) & (self.m == UNKNOWN)
            if reason != "growth_points_exhausted" or not reopened.any():
                break
            full_before = int(np.count_nonzero(self.m == FULL))
            self.marks[reopened] = 0.0
            self.w[reopened] = UNKNOWN
            self.forbidden.clear()
            self.unmeasurable = [c for c in self.unmeasurable if not reopened[c]]
            self.outcomes["noise: reopening pass"] += 1
            self.outcomes["noise: candidates reopened"] += int(np.count_nonzero(reopened))
            reason = self._expand_pass(first_hit)
            if int(np.count_nonzero(self.m == FULL)) <= full_before:
                break
        return reason

    def _expand_pass(self, first_hit) -> str:
        cfg = self.cfg
        transitions = TRANSITIONS[cfg.script]
        pp = first_hit
        while True:
            self._check_budget()
            if cfg.min_possible_improvement > 0 and self.possible_improvement() < cfg.min_possible_improvement:
                return "possible_improvement_below_threshold"
            pp = self.nearest_growth_point(pp)
            if pp is None:
                return "growth_points_exhausted"
            cc = predicted_point(self.w, pp, cfg.contour_points)
            if cc is None:  # cannot happen for a verified growth point; guards the loop anyway
                return "growth_points_exhausted"
            pp = self.resolve(cc, pp, transitions)

    def circle_sweep(self, first_hit) -> str:
        rf, cfg = self.rf, self.cfg
        centre = (np.array(self.shape, dtype=float) - 1) / 2
        rel = np.asarray(first_hit, dtype=float) - centre
        radius = float(np.hypot(*rel)) + rf.standoff_cells
        psi0 = math.atan2(rel[1], rel[0])
        near, far = rf.depth_window_cells()
        steps_per_lap = math.ceil(360.0 / cfg.circ_step_deg)
        k = 0
        for _lap in range(cfg.circ_max_laps):
            measured_in_lap = 0
            for _ in range(steps_per_lap):
                k += 1
                psi = psi0 + math.radians(k * cfg.circ_step_deg)
                src = centre + radius * np.array([math.cos(psi), math.sin(psi)])
                while True:
                    self._check_budget()
                    if len(self.growth_points()) == 0:
                        return "growth_points_exhausted"
                    plan = self._circ_plan(src, near, far)
                    if plan is None:
                        break
                    pos, cc = plan
                    self.measure(pos, cc, Strategy.S0)
                    self.mark(cc, PROBABLY_EMPTY)
                    measured_in_lap += 1
            if measured_in_lap == 0:
                break
        # a whole lap planned no view of the candidates left: from the circle they cannot be planned, which is the
        # report's "unmeasurable"; marking them exhausts the growth points
        i0, i1, j0, j1 = self.window()
        while True:  # marking the candidates of a contour end may expose the end's other unknown neighbours
            left = np.argwhere(driving_candidate_mask(self.w[i0:i1, j0:j1])) + np.array([i0, j0])
            if len(left) == 0:
                break
            for c in left:
                self._unmeasurable((int(c[0]), int(c[1])), None)
        return "growth_points_exhausted" if len(self.growth_points()) == 0 else "circle_completed"

    def _circ_plan(self, src, near, far):
        i0, i1, j0, j1 = self.window()
        cands = np.argwhere(driving_candidate_mask(self.w[i0:i1, j0:j1])) + np.array([i0, j0])
        if len(cands) == 0:
            return None
        depth = np.hypot(*(cands - src).T)
        ok = (depth > near) & (depth < far)
        cands, depth = cands[ok], depth[ok]
        full = self.m == FULL
        reach = min(far, float(self.shape[0] + self.shape[1])) + 2.0
        cfg_near = 5.0  # as strategy 0's near_cells
        for k in np.argsort(np.abs(depth - self.rf.standoff_cells), kind="stable")[:30]:
            cc = (int(cands[k, 0]), int(cands[k, 1]))
            if first_blocking(full, src, cc, skip=cc)[0] >= 0:
                continue
            # should cc be empty the laser goes on: a known full cell behind cc, before any cell that is not known
            # empty or within the near stretch, would answer with an already seen cell (a D0); not planned
            d = (np.asarray(cc, dtype=float) - src) / depth[k]
            # the first known full cell on the laser behind cc within the camera's depth window: should cc and
            # the unknown cells before it be empty, it answers (a D0) unless its return is blocked
            bi, bj = first_blocking(full, cc, src + (reach + 2.0) * d, skip=cc)
            behind = None if bi < 0 else (bi, bj)
            if behind is not None and not self.cfg.circ_strict_d0_check:
                between = supercover_cells(np.asarray(cc, dtype=float), np.asarray(behind, dtype=float), self.shape)
                n_unknown = int(np.count_nonzero(self.m[between[1:-1, 0], between[1:-1, 1]] == UNKNOWN))
                if n_unknown > self.cfg.circ_d0_max_unknown_cells:
                    behind = None
            bi, bj = first_blocking(self.m != EMPTY, cc, src + reach * d, skip=cc)
            if bi >= 0 and full[bi, bj]:
                continue
            if first_blocking(full, cc, np.asarray(cc, dtype=float) + cfg_near * d, skip=cc)[0] >= 0:
                continue
            for side in (1, -1):
                pos = self.rf.pose_through(src, cc, side)
                if behind is not None and predicted_return_free(full, pos, behind):
                    continue
                # the return is checked from the centre of cc: a view whose return from the laser's entry point
                # is blocked still measures an empty cc (measured: checking from the entry point here, as strategy
                # 0 does, cut the long-baseline rotated rectangle from 0.411 to 0.174 coverage)
                if first_blocking(full, cc, pos[1], skip=cc)[0] < 0:
                    return pos, cc
        return None


def run(truth: np.ndarray, rf: RangeFinder2D | None = None, config: RunConfig | None = None) -> RunResult:
    """Reconstruct ``truth`` (FULL / EMPTY grid or boolean mask) with one script; see the module docstring."""
    cfg = config or RunConfig()
    truth = validate_truth(truth)
    rf = rf or RangeFinder2D.from_config()
    eng = _Engine(truth, rf, cfg)
    try:
        first = eng.initial_search()
        if first is None:
            reason = "nothing_found"
        elif cfg.script == "circpix":
            reason = eng.circle_sweep(first)
        else:
            reason = eng.expand(first)
    except _BudgetExceeded as exc:
        reason = exc.reason
    return RunResult(
        truth=truth,
        model=eng.m,
        working=eng.w,
        records=eng.records,
        points=eng.points,
        unmeasurable=eng.unmeasurable,
        outcomes=eng.outcomes,
        termination=reason,
        run_time_s=time.perf_counter() - eng.t0,
        rf=rf,
        config=cfg,
    )
