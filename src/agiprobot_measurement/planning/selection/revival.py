"""Revival of dominated candidates: a candidate the evaluation dropped because another view measures all its
points is evaluated again when that dominator's scan line fails (or is shortened), and joins the problem when
one of its points is left without a view that may still be executable."""

from __future__ import annotations

import logging
import time

import numba
import numpy as np

from agiprobot_measurement.planning.candidates.generation import attach_unverified
from agiprobot_measurement.planning.candidates.mechanics import estimate_scan_duration, scan_line_extents
from agiprobot_measurement.planning.candidates.streaming import chunk_block
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint, build_viewpoints
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools

__all__ = ["revive_dominated", "revive_in"]

LOG = logging.getLogger(__name__)


def revive_dominated(run: PlanningRun, tools: PlanningTools) -> list[ViewPoint]:
    """Evaluate again the dropped candidates of dominators the mechanics rejected or shortened, and return
    the new (unverified) views of those that measure a point no other view measures any more.

    A dominated candidate measures a subset of its dominator's points, so it adds nothing while the
    dominator is executable; when the dominator's scan line cannot be driven (or only part of it), the
    dominated one may be. It is needed only for points left without a view that may still be executable (a
    view not yet verified counts until it fails): the dominated candidates of a failed dominator are
    evaluated once one of its points is left so, and those of them that measure only points measured
    elsewhere wait on a shelf until they are needed. The new views are not columns of the store (their
    arrays are their own), and are added to :attr:`last_viewpoints`.
    """
    views, reserve = run.generation_views, run.reserve
    if not reserve.candidates.size or not views or run.measurability is None:
        return []
    store = run.measurability
    newly = np.flatnonzero(~reserve.checked)
    if newly.size:
        newly = newly[[views[j].mechanics_verified is True for j in newly.tolist()]]
    if newly.size:
        # rejected, or shortened (a shortened view keeps only the points it still sweeps)
        failed = [not views[j].mechanics_valid or views[j].measurable_indices.size < store.indptr[j + 1] - store.indptr[j]
                  for j in newly.tolist()]  # fmt: skip
        reserve.failed_dominator[newly[np.asarray(failed, dtype=bool)]] = True
        reserve.checked[newly] = True
    waiting = ~reserve.revived & reserve.failed_dominator[reserve.dominator_column]
    if not waiting.any() and not reserve.shelf:
        return []
    started = time.perf_counter()
    measured = _measured_counts(run)
    if waiting.any():
        dominators = np.unique(reserve.dominator_column[waiting])
        needy = dominators[_has_open_points(run, dominators, measured)]
        pick = np.flatnonzero(waiting & np.isin(reserve.dominator_column, needy))
        if pick.size:
            reserve.revived[pick] = True
            reserve.shelf.extend(_evaluate_again(run, tools, reserve.candidates[pick]))
    revived, shelf = [], []
    for view in reserve.shelf:
        (revived if np.any(measured[view.measurable_indices] == 0) else shelf).append(view)
    reserve.shelf = shelf
    run.last_viewpoints.extend(revived)
    run.revived_views += len(revived)
    run.add_time("revival", time.perf_counter() - started)
    if revived:
        LOG.debug("revived %d dominated candidates (%d wait)", len(revived), len(shelf))
    return revived


def revive_in(run: PlanningRun, tools: PlanningTools, views: list[ViewPoint], provided: set) -> np.ndarray:
    """Append to ``views`` (and to the ids in ``provided``) the dominated candidates revived for the views
    the mechanics failed (:func:`revive_dominated`); returns their columns. They are not added to the
    candidate pool as they come: thousands of unverified views there (most fail like their dominators)
    would be picked a few per round for many rounds."""
    revived = revive_dominated(run, tools)
    start = len(views)
    views.extend(revived)
    provided.update(id(v) for v in revived)
    return np.arange(start, len(views), dtype=np.int64)


def _evaluate_again(run: PlanningRun, tools: PlanningTools, candidates: np.ndarray) -> list[ViewPoint]:
    """The views (unverified, not store columns) of dropped candidates that measure something."""
    threshold, deflection = run.evaluation_limits
    block, columns, _ = chunk_block(tools.sensor_model, run.candidates.poses[candidates], threshold, deflection)
    views = build_viewpoints(
        run.candidates,
        run.samples.points,
        run.samples.normals,
        int(run.parameters["orientations_around_boresight"]),
        run.parameters["viewpoint_tilt_mode"],
        tools.sensor_model,
        selection=candidates[columns],
    )
    lo, hi = scan_line_extents(
        block.t0_min,
        block.t0_max,
        run.mechanics["minimum_required_overmeasure"],
        run.mechanics["minimum_trajectory_length"],
    )
    durations = [estimate_scan_duration((a, b), tools.scan_speed_mm_s) for a, b in zip(lo, hi, strict=True)]
    attach_unverified(views, block, lo, hi, durations, store_columns=False)
    return views


def _measured_counts(run: PlanningRun) -> np.ndarray:
    """Per point, how many views that may still be executable measure it: live store entries and revived
    views not rejected."""
    store = run.measurability
    measured = np.zeros(store.n_points, dtype=np.int64)
    _count_alive(np.asarray(store.point_indices), run.entry_alive, measured)
    revived = [v.measurable_indices for v in run.last_viewpoints[len(run.generation_views) :] if v.mechanics_valid]
    if revived:
        measured += np.bincount(np.concatenate(revived).astype(np.int64), minlength=store.n_points)
    return measured


@numba.njit(cache=True)
def _count_alive(point_indices, alive, counts):  # pragma: no cover - compiled
    """``counts[p] += 1`` for every live entry of point p: one pass over the store, no gathered copy."""
    for e in range(point_indices.size):
        if alive[e]:
            counts[point_indices[e]] += 1


def _has_open_points(run: PlanningRun, columns: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """For store columns, whether one of their points (as evaluated, before any shortening) has
    ``measured == 0``."""
    store = run.measurability
    starts, ends = store.indptr[columns], store.indptr[columns + 1]
    lengths = ends - starts
    owner = np.repeat(np.arange(columns.size), lengths)
    entries = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(int(lengths.sum()))
    open_entry = measured[store.point_indices[entries]] == 0
    return np.bincount(owner[open_entry], minlength=columns.size) > 0
