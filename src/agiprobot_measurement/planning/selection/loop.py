"""The verify-and-resolve loop of the set cover: solve, verify what the cover picked (and what the next covers
will likely pick), correct the problem, solve again, until the chosen views are all executable.

Each round is three steps over a :class:`CoverLoop`: :meth:`~CoverLoop.solve_round` (the cover of this round's
columns: all views, or the candidate pool after the first solve), :meth:`~CoverLoop.settle` (is the cover
verified and good enough, or are open points left to verify) and :meth:`~CoverLoop.verify_round` (the batch of
views to verify, and the pool of the next round). :meth:`~CoverLoop.polish` spends the time left on the programme
over verified views. :func:`cover_points_with_verified` covers a given point set with verified views only.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from agiprobot_measurement.motion.cartesian_kernels import kernels_loaded
from agiprobot_measurement.planning.cover.pricing import full_bound, price_pool
from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES, SetCoverResult, solve_set_cover
from agiprobot_measurement.planning.errors import PlanningError, PlanningInputError
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools
from agiprobot_measurement.planning.selection.open_points import open_point_views, substitute_views
from agiprobot_measurement.planning.selection.problem import coverage_problem, executable_columns
from agiprobot_measurement.planning.selection.revival import revive_in
from agiprobot_measurement.planning.selection.verify import (
    finish_scan_trajectories,
    screen_scan_lines,
    verify_mechanics_batch,
)

__all__ = ["CoverLoop", "cover_points_with_verified", "solve_scp"]

LOG = logging.getLogger(__name__)

#: an IP solve of one verification round stops after this long (s): its cover only names what to verify next
ROUND_IP_TIME_S = 2.0
#: ... and may stop at this relative gap (or the requested one, if larger)
ROUND_MIP_GAP = 0.04
#: ... and this long on problems of at least LARGE_PROBLEM_VIEWS candidates (tilt full; counted before dominated
#: ones were dropped): there the pool's programmes have a ~40 % integrality gap, so a round's solve always runs to
#: its limit; 1 s gave the same covers as 2 s on the cylinder and idler_riser and saved ~25 s on the cylinder
LARGE_ROUND_IP_TIME_S = 1.0
LARGE_PROBLEM_VIEWS = 100_000
#: a round over the candidate pool of a large problem verifies up to this many of the pool's unverified views at
#: once: the next solves choose from the pool, so they are final sooner than when a few new picks are verified per
#: round (cylinder at tilt full: 22 rounds instead of 28; at tilt none it costs more than the rounds it saves)
POOL_VERIFY_MAX = 3000
#: the last solve over the verified views, when the rounds left a gap, stops after this long (s): at tilt full its
#: programme has tens of thousands of verified views (cylinder: 22 views proven optimal after 40 s; 23 views and an
#: 8.7 % gap, reported, after 15 s)
POLISH_IP_TIME_S = 15.0
#: ... and one over all views after this long (s): its reductions name the candidate pool of the next rounds
FULL_ROUND_IP_TIME_S = 8.0
#: the set cover loop solves the problem over all views at most this often (the rest over the candidate pool)
MAX_FULL_SOLVES = 3
#: a verified cover of the pool is priced over all views at most this often (each time the views of negative
#: reduced cost join the pool), up to this many views each time, most negative first
MAX_PRICING_ROUNDS = 3
PRICING_POOL_COLS = 2000
#: each verification round takes up to this many unverified views of every point no verified view measures yet
POINT_VIEWS_PER_ROUND = 24
#: ... but no more than this many in one round (the next round's cover may settle the rest)
MAX_POINT_VIEWS_PER_ROUND = 2000
#: each verification round also takes this many unverified views sharing the most points with each picked one
SUBSTITUTES_PER_VIEW = 20
#: scan lines verified in one batched call (:func:`verify_mechanics_batch`); the deadline is checked between them
VERIFY_CHUNK = 256
#: what loading the compiled path kernels may cost in a process (s): a verification batch that would load them is
#: not started with less time left
KERNEL_LOAD_S = 3.0
#: near the deadline, each open point gets this many of its unverified views verified per pass (then 4x as many)
CLOSE_OUT_VIEWS_PER_POINT = 4
#: the IP time limit (s) of the fallback solve over verified views when the deadline has passed
LATE_IP_TIME_S = 0.3
#: ... but the fallback's cover is the plan's: its solve gets at least this long (s), past the deadline if need be
#: (the connection's reserve follows it), so that its LP gives the lower bound the report states beside the view
#: count (a 0.3 s solve of a 6,000-point cover on a loaded machine may end before its LP)
FALLBACK_MIN_IP_TIME_S = 2.0
#: before the deadline, a batch holds only the lines the time left allows at the measured time per line (at least
#: this many; the first batch this many, to measure it): a batch that starts just before the deadline ends soon after
MIN_VERIFY_CHUNK = 16
#: the candidate pool takes at most this many of a solve's most likely columns (or four times the batch)
POOL_LIKELY_COLUMNS = 6000


@dataclass
class _Round:
    """One round's problem and cover: the columns solved over, the matrix and per-view figures of all views,
    the (sub)matrix solved, the IP time limit, the chosen views and those of them not yet verified."""

    columns: np.ndarray
    matrix: object
    worst: np.ndarray
    durations: np.ndarray
    sub: object
    limit: float
    chosen: list
    pending: list
    solved: bool = True  # False when the round took a settled cover of an earlier round (its bound is that pool's)
    started_s: float = 0.0  # when the round began (perf_counter s)


@dataclass
class CoverLoop:
    """The state of one verify-and-resolve loop over ``views`` (the facade's ``solve_scp`` arguments)."""

    run: PlanningRun
    tools: PlanningTools
    views: list
    solver_type: str
    time_limit_s: float
    max_rounds: int
    mip_gap: float
    deadline: float
    verification_batch: int | None
    n_points: int = 0
    provided: set = field(default_factory=set)
    set_cover_time: float = 0.0
    verified_count: int = 0
    line_s: float | None = None  # measured verification time per scan line (s), None before the first batch
    longest_round_s: float = 0.0  # the longest round so far (s): what the close-out's test expects the next to take
    only_verified: bool = False
    # the points no verified view measures had their views verified before the deadline (:meth:`close_out`): the
    # next round is the fallback over verified views
    closed_out: bool = False
    result: SetCoverResult | None = None
    chosen: list = field(default_factory=list)
    rounds_used: int = 0
    # Rounds after the first solve a restricted problem: the columns the first (full) solve's reductions kept,
    # plus every column verified since. The full matrix's reductions cost seconds on parts whose views see
    # hundreds of points; the pool's cost milliseconds. When a restricted cover is fully verified, the full
    # problem is solved once more (if time allows) to prove the cover is optimal over all views.
    pool: np.ndarray | None = None
    full_checked: bool = False
    full_solve_s: float = 0.0
    full_solves: int = 0
    pricing_rounds: int = 0
    pricing_added: bool = True  # whether the last pricing named views (the first is always run)
    best_verified: SetCoverResult | None = None
    # a round's cover whose picks all verified as executable with their points: the next round takes it as
    # its (verified) cover instead of solving again, which could pick other, equally good unverified views
    settled: SetCoverResult | None = None

    @property
    def defer_trajectories(self) -> bool:
        """Only IP_time needs the verified views' real durations while solving; the others time-parameterise the
        scan lines of the chosen views only."""
        return self.solver_type != "IP_time"

    @property
    def n_candidates(self) -> int:
        candidates = self.run.candidates
        return max(len(self.views), 0 if candidates is None else len(candidates.poses))

    def _verify(self, views: list, *, until_deadline: bool = True) -> None:
        """Verify the unverified ``views`` in batches of up to :data:`VERIFY_CHUNK`; with ``until_deadline`` only
        while the deadline has not come, in batches that fit the time left (the batch started before it is
        finished)."""
        todo = [v for v in dict.fromkeys(views) if v.mechanics_verified is False]
        begin = 0
        while begin < len(todo):
            size = VERIFY_CHUNK
            if until_deadline and math.isfinite(self.deadline):
                left_s = self.deadline - time.perf_counter()
                if left_s <= 0.0:
                    break
                if left_s < KERNEL_LOAD_S and not kernels_loaded():
                    break  # the compiled path kernels would load first: seconds this verification does not have
                fits = MIN_VERIFY_CHUNK if self.line_s is None else int(left_s / max(self.line_s, 1e-6))
                size = min(VERIFY_CHUNK, max(MIN_VERIFY_CHUNK, fits))
            part = todo[begin : begin + size]
            begin += len(part)
            started = time.perf_counter()
            deadline = self.deadline if until_deadline and math.isfinite(self.deadline) else None
            verify_mechanics_batch(
                self.run, self.tools, part, time_parameterize=not self.defer_trajectories, deadline=deadline
            )
            per_line = (time.perf_counter() - started) / len(part)
            self.line_s = per_line if self.line_s is None else 0.5 * (self.line_s + per_line)
            self.verified_count += len(part)
            done = min(1.0, self.verified_count / (self.verified_count + 10))
            self.tools.report("mechanics", done, f"verified {self.verified_count} scan lines")

    def _screen_and_verify(self, views: list) -> None:
        """Settle the views without a free start at either end at once, then verify the others (until the deadline)."""
        self.verified_count += screen_scan_lines(self.run, self.tools, views)
        self._verify(views)

    def solve_round(self, round_index: int) -> _Round:
        """This round's cover: over all views, the pool, or (the fallback, after the last round or at the
        deadline) the verified views only."""
        views, run = self.views, self.run
        now = started = time.perf_counter()
        # the first round always solves and verifies its picks: a plan comes out however short the time
        if round_index == self.max_rounds or (now >= self.deadline and round_index > 0) or self.closed_out:
            self.only_verified = True  # the fallback: no more verification, a cover of verified views
            run.time_limit_hit = now >= self.deadline or self.closed_out
            cause = "the time limit came" if run.time_limit_hit else f"{self.max_rounds} rounds"
            if self.closed_out and now < self.deadline:
                cause = "the time limit drew near (the open points' views verified first)"
            run.warn(
                f"set cover: {cause} after {self.verified_count} scan lines verified; solving over verified views only",
                LOG,
            )
        matrix, worst, durations = coverage_problem(run, views, self.n_points, self.only_verified)
        self.tools.report("set cover", min(0.9, round_index / max(self.max_rounds, 1)), f"round {round_index + 1}")
        # an IP solve never takes all the time left: verification and the last solve need some
        # a round's cover only decides what to verify next (its columns change after that): a short solve is
        # enough; the last cover gets the time left (below)
        remaining = self.deadline - time.perf_counter()
        columns = np.arange(len(views)) if self.pool is None or self.only_verified else self.pool
        if self.only_verified:
            # the unverified columns are empty here: leaving them out is the same programme, much smaller
            executable = executable_columns(views)
            columns = executable if executable.size else columns
        # a solve over all views names the pool the next rounds choose from: its reductions must finish
        round_s = LARGE_ROUND_IP_TIME_S if self.n_candidates >= LARGE_PROBLEM_VIEWS else ROUND_IP_TIME_S
        limit = min(self.time_limit_s, FULL_ROUND_IP_TIME_S if columns.size == len(views) else round_s)
        if math.isfinite(remaining):
            # past the deadline the fallback's cover of verified views (a small programme) gets a short solve
            limit = max(min(1.0, max(remaining, LATE_IP_TIME_S)), min(limit, 0.5 * remaining))
            if self.only_verified:
                limit = max(limit, min(self.time_limit_s, FALLBACK_MIN_IP_TIME_S))
        sub = matrix if columns.size == len(views) else matrix[:, columns]
        solved = self.settled is None or self.only_verified
        if not solved:
            result, self.settled = self.settled, None
        else:
            result = solve_set_cover(
                sub,
                self.solver_type,
                uncertainties=worst[columns],
                durations_s=durations[columns] if self.solver_type == "IP_time" else None,
                time_limit_s=limit,
                # a round's cover only names what to verify next: it need not close the last view of an
                # integrality gap (the search for it ran each round to its time limit); the fallback and the polish
                # over verified views solve to the requested gap
                mip_gap=self.mip_gap if self.only_verified else max(self.mip_gap, ROUND_MIP_GAP),
            )
            self.set_cover_time += result.solve_time_s
            if columns.size == len(views):
                self.full_solve_s = result.solve_time_s
                self.full_solves += 1
            result = dataclasses.replace(result, selected=columns[result.selected])
        self.result = result
        self.chosen = [views[j] for j in result.selected.tolist()]
        pending = [v for v in self.chosen if v.mechanics_verified is False]
        return _Round(columns, matrix, worst, durations, sub, limit, self.chosen, pending, solved, started)

    def settle(self, step: _Round, round_index: int) -> str | None:
        """What the round's cover settles: ``'done'`` (the cover is final), ``'again'`` (solve again without a
        verification batch), or None (verify a batch)."""
        views, columns, result = self.views, step.columns, self.result
        if not step.pending and columns.size < len(views):
            self.best_verified = result
        if step.pending and columns.size == len(views) and self.best_verified is not None:
            # unverified views count as executable in the full problem, so its bound is a bound on every
            # executable cover: a verified cover within the gap of it is good enough
            best, bound = self.best_verified, result.lower_bound
            same_points = int(best.covered.sum()) >= result.n_coverable
            if same_points and bound is not None and best.objective > 0:
                gap = max(0.0, (best.objective - bound) / best.objective)
                if gap <= max(self.mip_gap, 1e-9):
                    self.result = dataclasses.replace(best, gap=gap, lower_bound=bound, proven_optimal=gap <= 1e-9)
                    self.chosen = [views[j] for j in self.result.selected.tolist()]
                    self.full_checked = True
                    return "done"
        if step.pending:
            return None
        if columns.size == len(views):
            self.full_checked = True
            return "done"
        # a verified cover of the pool: the pool LP's duals priced over all views prove it or name the views
        # outside the pool that improve the LP (milliseconds, where a solve over all views costs seconds and, on an
        # integrality gap, runs to its time limit without closing it); a solve over all views only when the LP did
        # not solve
        priced = None
        if self.pricing_rounds < MAX_PRICING_ROUNDS:
            # priced before without a gain, and the pool's bound leaves a gap: no pricing closes it
            priced = self._price(step) if self._worth_pricing(step) else ("again", np.zeros(0, dtype=np.int64))
        if priced is not None:
            verdict, added = priced
            if verdict == "done":
                self.full_checked = True
                return "done"
            self.pricing_added = bool(added.size)
            if added.size:
                self.pricing_rounds += 1
                self.pool = np.union1d(columns, added)
                return "again"
        elif self.full_solves < MAX_FULL_SOLVES and time.perf_counter() + 1.5 * self.full_solve_s < self.deadline:
            self.pool = None
            return "again"
        # points that only unverified views outside the pool measure: verify their views (no solve) while
        # time and rounds allow, then solve the pool again with them, so such points are settled
        per_point = POINT_VIEWS_PER_ROUND * 2 ** min(round_index, 10)
        open_columns = open_point_views(step.matrix, views, per_point)[:MAX_POINT_VIEWS_PER_ROUND]
        if open_columns.size and time.perf_counter() < self.deadline and round_index + 1 < self.max_rounds:
            self._screen_and_verify([views[j] for j in open_columns.tolist()])
            # revived views join the problem, not the pool: they come into it verified, as the open
            # points' views (above) or through a solve over all views
            revive_in(self.run, self.tools, views, self.provided)
            self.pool = np.union1d(columns, open_columns)
            return "again"
        self.run.warn(
            f"set cover: the gap holds for a candidate pool of {columns.size} of {len(views)} views (its LP priced "
            "over all views, or no more time or rounds to solve over all views again)",
            LOG,
        )
        return "done"

    def _worth_pricing(self, step: _Round) -> bool:
        """Whether pricing the pool's verified cover may settle anything: it can prove the cover only when the pool's
        own bound (of this round's solve) is within the gap, and after a pricing that named no views only that."""
        if self.pricing_added or not step.solved or self.result.lower_bound is None:
            return True
        objective = self.result.objective
        return objective <= 0 or (objective - self.result.lower_bound) / objective <= max(self.mip_gap, 1e-9)

    def _price(self, step: _Round) -> tuple[str, np.ndarray] | None:
        """The pool's verified cover priced over all views (:func:`price_pool`): ``('done', ...)`` when no cover
        over all views (unverified ones counted as executable) beats it by more than the gap (the result then
        carries that bound), else ``('again', columns)`` with the outside views of negative reduced cost (none: the
        pool's LP is the LP over all views, the gap left is the programme's own); None when the pool LP did not
        solve in time."""
        result, columns, views = self.result, step.columns, self.views
        if self.solver_type == "IP_uncertainty":
            raw = step.worst
        elif self.solver_type == "IP_time":
            raw = step.durations
        else:
            raw = np.ones(len(views))
        scale = float(raw.max()) if raw.size and raw.max() > 0 else 1.0
        left = self.deadline - time.perf_counter()
        limit = min(step.limit, 0.5 * left) if math.isfinite(left) else step.limit
        started = time.perf_counter()
        pricing = price_pool(step.matrix, columns, raw / scale, max(limit, 0.05))
        self.set_cover_time += time.perf_counter() - started
        if pricing is None:
            return None
        integral = self.solver_type == "IP_basic"
        objective = result.objective / scale
        pool_bound = result.lower_bound / scale if step.solved and result.lower_bound is not None else None
        bound = full_bound(pricing, pool_bound, integral)
        gap = max(0.0, (objective - bound) / objective) if objective > 0 else 0.0
        if int(result.covered.sum()) >= pricing.n_coverable and gap <= max(self.mip_gap, 1e-9):
            proven = gap <= 1e-9
            self.result = dataclasses.replace(
                result, gap=0.0 if proven else gap, lower_bound=objective * scale if proven else bound * scale,
                proven_optimal=proven,
            )  # fmt: skip
            return "done", np.zeros(0, dtype=np.int64)
        return "again", pricing.improving()[:PRICING_POOL_COLS]

    def _batch(self, step: _Round, round_index: int) -> tuple[list, int, np.ndarray | None]:
        """The views to verify this round (the picks first), the batch size aimed at, the likely columns."""
        views, columns, pending = self.views, step.columns, step.pending
        batch = list(pending)
        greedy_pending = []
        if self.solver_type != "greedy" and columns.size < len(views):
            # the greedy cover of the pool costs little and names views the next solve may want (a solve over
            # all views already started from its own greedy cover, and a greedy pass over all is not cheap)
            extra = solve_set_cover(step.sub, "greedy", uncertainties=step.worst[columns], time_limit_s=step.limit)
            self.set_cover_time += extra.solve_time_s
            greedy_pending = [
                views[j] for j in columns[extra.selected].tolist() if views[j].mechanics_verified is False
            ]
        size = max(int(self.verification_batch or 0), 4 * len(step.chosen), len(pending) + len(greedy_pending))
        batch += greedy_pending
        likely = self.result.stats.get("likely_columns")
        likely = None if likely is None else columns[np.asarray(likely, dtype=np.int64)]
        if likely is not None and len(batch) < size:
            # the columns the reduced programme kept, most likely first: the next covers choose from them
            unverified = [views[j] for j in likely.tolist() if views[j].mechanics_verified is False]
            batch += unverified[: 2 * size]
        # points no verified view measures yet: a few of their unverified views each, largest first, so that a
        # point whose views keep failing is settled in one pass instead of one view per round
        # (twice as many each round: a point all of whose views fail is known to be so after a few rounds)
        per_point = POINT_VIEWS_PER_ROUND * 2 ** min(round_index, 10)
        batch = list(dict.fromkeys(batch))[:size]
        batch += [views[j] for j in open_point_views(step.matrix, views, per_point)][:MAX_POINT_VIEWS_PER_ROUND]
        pending_columns = [v.coverage_column if v.coverage_column is not None else -1 for v in pending]
        if all(views[j] is v for j, v in zip(pending_columns, pending, strict=True) if 0 <= j < len(views)):
            picked_columns = np.array([j for j in pending_columns if 0 <= j < len(views)], dtype=np.int64)
        else:
            index_of = {id(v): j for j, v in enumerate(views)}
            picked_columns = np.array([index_of[id(v)] for v in pending], dtype=np.int64)
        batch += [views[j] for j in substitute_views(step.matrix, views, picked_columns, SUBSTITUTES_PER_VIEW)]
        if columns.size < len(views):
            unverified = [views[j] for j in columns.tolist() if views[j].mechanics_verified is False]
            round_s = time.perf_counter() - step.started_s
            if self.n_candidates >= LARGE_PROBLEM_VIEWS:
                batch += unverified[:POOL_VERIFY_MAX]
            elif self.line_s is not None and len(unverified) * self.line_s <= round_s:
                # the whole pool verified costs no more than this round did: the next solves choose among
                # verified views, where each round of picking one unverified view at a time costs a round
                # (a rent-or-buy rule: at worst twice the rounds' time)
                batch += unverified
        return list(dict.fromkeys(batch)), size, likely

    def verify_round(self, step: _Round, round_index: int) -> None:
        """Verify this round's batch, remember a cover that verified as it is, revive dominated candidates of the
        failed views and name the next round's pool."""
        views, result, chosen, pending = self.views, self.result, step.chosen, step.pending
        batch, size, likely = self._batch(step, round_index)
        LOG.debug(
            "set cover round %d: %d of %d columns, %d chosen, %d pending, %d to verify (%s)",
            round_index + 1, step.columns.size, len(views), len(chosen), len(pending), len(batch), result.message,
        )  # fmt: skip
        # views without a free start at either end of their line are settled for the whole batch at once (after
        # the first round only while there is time: screening a round's batch costs up to seconds)
        if round_index > 0 and time.perf_counter() >= self.deadline:
            return
        self.verified_count += screen_scan_lines(self.run, self.tools, batch)
        # the picked views first, whatever the time in the first round (a plan comes out however short the time);
        # later rounds' picks and the likely ones only while there is time
        self._verify(batch[: len(pending)], until_deadline=round_index > 0)
        self._verify(batch[len(pending) :])
        if all(v.mechanics_verified is True and v.mechanics_valid for v in chosen):
            still = np.zeros(result.covered.size, dtype=bool)
            for view in chosen:
                still[np.asarray(view.measurable_indices, dtype=np.int64)] = True
            if still[result.covered].all():
                self.settled = result
        revive_in(self.run, self.tools, views, self.provided)  # into the problem, not the pool (see settle)
        verified_columns = np.flatnonzero([v.mechanics_verified is True and v.mechanics_valid for v in views])
        previous = np.zeros(0, dtype=np.int64) if self.pool is None else self.pool
        extra_columns = [result.selected, verified_columns, previous]
        if likely is not None:
            # the most likely only: without a finished reduction (tilt full, a loaded machine) the list is
            # every column, and a pool of all columns makes every round a full solve
            extra_columns.append(likely[: max(POOL_LIKELY_COLUMNS, 4 * size)])
        self.pool = np.unique(np.concatenate([np.asarray(c, dtype=np.int64) for c in extra_columns]))

    def _close_out_due(self, step: _Round) -> bool:
        """Whether another round as long as the longest so far (this one included) would leave too little time to
        verify every unverified view of the points no verified view measures (:meth:`close_out`'s most, when all
        their views fail), at the measured time per line."""
        if not math.isfinite(self.deadline) or self.line_s is None:
            return False
        now = time.perf_counter()
        # the next round may take as long as the longest so far (a solve over all views; a loaded machine)
        self.longest_round_s = max(self.longest_round_s, now - step.started_s)
        spare_s = self.deadline - now - self.longest_round_s - LATE_IP_TIME_S
        if sum(v.mechanics_verified is False for v in self.views) * self.line_s < spare_s:
            return False  # even every unverified view would fit: no need to find the open points' ones
        # the problem as the round's verification left it: the views it revived are often the open points' only ones
        matrix, _, _ = coverage_problem(self.run, self.views, self.n_points)
        open_columns = open_point_views(matrix, self.views, len(self.views))
        close_out_s = open_columns.size * self.line_s
        return open_columns.size > 0 and close_out_s >= spare_s

    def close_out(self, round_s: float = math.inf) -> None:
        """Verify the unverified views of the points no verified view measures, a few per point (most shared
        first), again (with the views revived for the failed ones) for the points still open, until none is open
        or the deadline comes: every measurable point then has a view known to be executable or none left
        unverified. When the time left would not hold another round of ``round_s`` seconds, the rounds end with
        the fallback over verified views."""
        views, per_point = self.views, CLOSE_OUT_VIEWS_PER_POINT
        while time.perf_counter() < self.deadline:
            matrix, _, _ = coverage_problem(self.run, views, self.n_points)
            open_columns = open_point_views(matrix, views, per_point)
            if open_columns.size == 0:
                break
            todo = [views[j] for j in open_columns.tolist()]
            LOG.debug(
                "set cover close-out: %d views of the open points, %d per point, %.1f s left",
                len(todo), per_point, self.deadline - time.perf_counter(),
            )  # fmt: skip
            self._screen_and_verify(todo)
            revive_in(self.run, self.tools, views, self.provided)
            per_point *= 4  # points whose first views failed: more of theirs at once
        self.closed_out = time.perf_counter() + round_s + LATE_IP_TIME_S >= self.deadline

    def polish(self) -> None:
        """The rounds' short solves may leave a gap: spend what is left on the programme over the verified views
        (every cover of it is executable); the gap is then the one over verified views."""
        result, views = self.result, self.views
        if not self.chosen or (result.gap is not None and result.gap <= self.mip_gap) or self.solver_type == "greedy":
            return
        left = self.deadline - time.perf_counter()
        if not math.isfinite(left):
            left = self.time_limit_s
        if left <= 2.0:
            return
        matrix, worst, durations = coverage_problem(self.run, views, self.n_points, only_verified=True)
        executable = executable_columns(views)
        if executable.size == 0:
            executable = np.arange(len(views))
        polished = solve_set_cover(
            matrix[:, executable],
            self.solver_type,
            uncertainties=worst[executable],
            durations_s=durations[executable] if self.solver_type == "IP_time" else None,
            time_limit_s=max(1.0, min(self.time_limit_s, 0.8 * left, POLISH_IP_TIME_S)),
            mip_gap=self.mip_gap,
        )
        polished = dataclasses.replace(polished, selected=executable[polished.selected])
        self.set_cover_time += polished.solve_time_s
        polished_views = [views[j] for j in polished.selected.tolist()]
        if (
            polished.covered.sum() >= result.covered.sum()
            and polished.objective <= result.objective
            and polished.gap is not None
            and all(v.mechanics_verified for v in polished_views)
        ):
            self.result = dataclasses.replace(polished, message=polished.message + " (over verified views)")
            self.chosen = polished_views

    def rounds(self) -> None:
        """Solve, settle and verify until the cover is final or the fallback (verified views only) solved."""
        for round_index in range(self.max_rounds + 1):
            self.rounds_used = round_index + 1
            step = self.solve_round(round_index)
            if self.only_verified:
                break
            verdict = self.settle(step, round_index)
            if verdict == "done":
                break
            if verdict == "again":
                continue
            self.verify_round(step, round_index)
            if self._close_out_due(step):
                self.close_out(round_s=self.longest_round_s)


def solve_scp(
    run: PlanningRun,
    tools: PlanningTools,
    *,
    provided_viewpoints,
    solver_type,
    time_limit_s,
    max_rounds,
    mip_gap,
    deadline_s,
    verification_batch,
) -> set:
    """The facade's ``solve_scp`` (see there) over ``run``: the chosen views as a set."""
    if solver_type not in SOLVER_TYPES:
        raise PlanningInputError(f"unknown solver_type {solver_type!r}; valid names: {', '.join(SOLVER_TYPES)}")
    views = list(provided_viewpoints)
    if not views:
        raise PlanningError("solve_scp needs at least one viewpoint")
    n_points = len(run.sampled_surface_points) or 1 + max(int(v.measurable_indices.max(initial=0)) for v in views)
    t0 = time.perf_counter()
    provided = {id(v) for v in views}
    run.pending_scan_paths = {k: p for k, p in run.pending_scan_paths.items() if k in provided}
    mechanics_before = run.timings_s.get("mechanics", 0.0)
    run.time_limit_hit = False
    loop = CoverLoop(
        run,
        tools,
        views,
        solver_type,
        time_limit_s,
        max_rounds,
        mip_gap,
        math.inf if deadline_s is None else float(deadline_s),
        verification_batch,
        n_points=n_points,
        provided=provided,
    )
    loop.rounds()
    run.timings_s["set_cover_full_problem_checked"] = bool(loop.full_checked)
    loop.polish()
    chosen, result = loop.chosen, loop.result
    if not chosen:
        raise PlanningError("no viewpoint is executable: every candidate failed the mechanical checks")
    finish_scan_trajectories(run, tools, chosen)
    run.timings_s["set_cover_and_mechanics"] = time.perf_counter() - t0
    run.timings_s["set_cover"] = loop.set_cover_time
    run.timings_s["set_cover_last_solve"] = result.solve_time_s
    run.timings_s["set_cover_rounds"] = loop.rounds_used
    run.timings_s["scan_lines_verified"] = loop.verified_count
    run.timings_s["mechanics_in_set_cover"] = run.timings_s.get("mechanics", 0.0) - mechanics_before
    run.last_set_cover = result
    run.parameters["solver_type"] = solver_type
    run.parameters["set_cover_mip_gap"] = float(mip_gap)
    tools.report("set cover", 1.0, f"{len(chosen)} views cover {int(result.covered.sum())} points")
    return set(chosen)


def cover_points_with_verified(
    run: PlanningRun, tools: PlanningTools, points: np.ndarray, settings: dict, deadline: float
):
    """Cover the points of the mask ``points`` with the run's verified executable views (no new verification:
    every cover is executable); returns the chosen views (their trajectories finished), or None when there is no
    time, no such view or the samples differ. The cover is the run's ``last_set_cover``."""
    views = list(run.last_viewpoints or [])
    left = deadline - time.perf_counter()
    if not views or points.size != len(run.samples) or not points.any() or left < 5.0:
        return None
    started = time.perf_counter()
    matrix, worst, durations = coverage_problem(run, views, len(run.samples), only_verified=True)
    executable = executable_columns(views)
    if executable.size == 0:
        return None
    solver_type = settings["solver_type"]
    sub = scipy.sparse.csr_matrix(matrix)[np.flatnonzero(points)].tocsc()[:, executable]
    result = solve_set_cover(
        sub,
        solver_type,
        uncertainties=worst[executable],
        durations_s=durations[executable] if solver_type == "IP_time" else None,
        time_limit_s=max(1.0, min(settings["set_cover_time_limit_s"], 0.5 * left)),
        mip_gap=settings["mip_gap"],
    )
    chosen = [views[j] for j in executable[result.selected].tolist()]
    if not chosen:
        return None
    run.last_set_cover = dataclasses.replace(result, selected=executable[result.selected])
    run.timings_s["set_cover_restricted"] = time.perf_counter() - started
    finish_scan_trajectories(run, tools, chosen)
    return chosen
