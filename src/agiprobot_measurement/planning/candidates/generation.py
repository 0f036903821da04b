"""Candidate generation: samples on the part, candidate viewpoints, anchor reachability, the streamed metrology
and the views of the candidates that measure something (their scan lines not yet verified).

:func:`generate_samples_and_viewpoints` fills a :class:`~agiprobot_measurement.planning.run.PlanningRun`;
:func:`process_viewpoint` processes one viewpoint entirely. Points are mm, densities points/mm^2.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.planning.candidates.mechanics import (
    estimate_scan_duration,
    reachable_anchors,
    scan_line_extents,
)
from agiprobot_measurement.planning.candidates.streaming import EvaluationSettings, StreamStats, evaluate_streaming
from agiprobot_measurement.planning.candidates.viewpoint import (
    TILT_MODES,
    ViewPoint,
    build_viewpoints,
    generate_viewpoint_poses,
    select_limited_tilt,
)
from agiprobot_measurement.planning.deadline import METROLOGY_TIME_SHARE
from agiprobot_measurement.planning.errors import PlanningError, PlanningInputError
from agiprobot_measurement.planning.request import WorkBudget, check_choice, check_positive, estimate_work
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools, Reserve
from agiprobot_measurement.planning.selection.verify import verify_mechanics
from agiprobot_measurement.sensors.laser_line.model import MeasurabilityResult

__all__ = [
    "EvaluationBudget",
    "attach_unverified",
    "generate_samples_and_viewpoints",
    "keep_reserve",
    "process_viewpoint",
    "select_columns",
]

LOG = logging.getLogger(__name__)


@dataclass
class EvaluationBudget:
    """Where and within what the candidates are evaluated: the evaluation settings, the Dask evaluator (None =
    in this process), the work budget and the sampling seed."""

    evaluation: EvaluationSettings
    evaluator: object
    work_budget: WorkBudget
    seed: int


def generate_samples_and_viewpoints(
    run: PlanningRun,
    tools: PlanningTools,
    budget: EvaluationBudget,
    *,
    sampling_density,
    uncertainty_threshold,
    orientations_around_boresight,
    viewpoint_tilt_mode,
    plan_path_to_check_reachability,
    minimum_trajectory_length,
    trajectory_sample_step,
    minimum_required_overmeasure,
    joint_jump_threshold,
    maximum_deflection,
    min_reachable_share,
):
    """The facade's ``generate_samples_and_viewpoints`` (see there) over ``run``: samples, candidates, their
    reachability and metrology, and the views of those that measure something (not verified yet)."""
    part = run.part
    if part is None:
        raise PlanningError("no part loaded: call load_target_mesh(file_name, ...) first")
    density = check_positive(sampling_density, "sampling_density", "sampling_density (points/mm^2)")
    threshold = check_positive(uncertainty_threshold, "uncertainty_threshold", "uncertainty_threshold (mm)")
    check_choice(viewpoint_tilt_mode, TILT_MODES, "viewpoint_tilt_mode")
    for name, value in (
        ("minimum_trajectory_length", minimum_trajectory_length),
        ("trajectory_sample_step", trajectory_sample_step),
        ("joint_jump_threshold", joint_jump_threshold),
    ):
        check_positive(value, name)
    run.mechanics = {
        "minimum_required_overmeasure": float(minimum_required_overmeasure),
        "trajectory_sample_step": float(trajectory_sample_step),
        "joint_jump_threshold": float(joint_jump_threshold),
        "minimum_trajectory_length": float(minimum_trajectory_length),
        "plan_path_to_check_reachability": bool(plan_path_to_check_reachability),
    }
    run.parameters.update(
        sampling_density=density,
        uncertainty_threshold=threshold,
        orientations_around_boresight=int(orientations_around_boresight),
        viewpoint_tilt_mode=viewpoint_tilt_mode,
        **run.mechanics,
    )
    timings = run.timings_s
    t0 = time.perf_counter()
    # the largest work of this run, refused beyond the budget before anything is allocated
    run.last_work_estimate = budget.work_budget.check(
        estimate_work(part.measurable_area, density, int(orientations_around_boresight), viewpoint_tilt_mode)
    )
    tools.report("sampling", 0.0, f"sampling at {density} points/mm^2")
    samples = part.sample(density, seed=budget.seed)
    if len(samples) == 0:
        raise PlanningError(
            f"sampling at {density} points/mm^2 gives no points on {part.measurable_area:.1f} mm^2: "
            "raise the density (or check the part's unit)"
        )
    run.samples = samples
    run.sampled_surface_points = [p for p in samples.points]
    tools.report("sampling", 0.3, f"{len(samples)} samples")
    tools.sensor_model.set_processing_context(part.mesh, samples.points, samples.face_ids)
    tools.report("sampling", 0.6, "occlusion context ready")
    candidates = generate_viewpoint_poses(
        samples.points, samples.normals, orientations_around_boresight, viewpoint_tilt_mode, tools.sensor_model
    )
    run.candidates = candidates
    timings["sampling"] = time.perf_counter() - t0
    tools.report("sampling", 1.0, f"{len(samples)} samples, {len(candidates.poses)} candidate viewpoints")

    # anchors: reachability for all candidates at once (closed-form IK); metrology only where reachable
    t1 = time.perf_counter()
    reachable = reachable_anchors(tools.ik, candidates.poses)
    timings["anchor_reachability"] = time.perf_counter() - t1
    sample_reachable = np.zeros(len(samples), dtype=bool)
    sample_reachable[candidates.sample_index[reachable]] = True
    run.reachable_share = float(sample_reachable.mean())
    if run.reachable_share < float(min_reachable_share):
        message = (
            f"only {100 * run.reachable_share:.1f} % of the {len(samples)} samples have a reachable anchor "
            f"(threshold {100 * float(min_reachable_share):.0f} %): move the part closer to the robot or place it "
            "on the fixture (placement 'fixture'), or allow tilts (tilt mode limited/full/auto)"
        )
        LOG.warning("%s", message)
        run.warnings.append(message)
    tools.report("metrology", 0.0, f"{int(reachable.sum())} of {len(reachable)} anchors reachable")
    t2 = time.perf_counter()
    index = np.flatnonzero(reachable)
    stats = StreamStats()
    # what this process holds beside the store: the samples and every candidate's pose and indices
    fixed = samples.points.nbytes * 4 + candidates.poses.nbytes * 2 + len(candidates.poses) * 40
    result, useful_index = evaluate_streaming(
        tools.sensor_model,
        candidates.poses[index],
        threshold,
        maximum_deflection,
        tools.report,
        settings=budget.evaluation,
        executor=budget.evaluator,
        fixed_bytes=fixed,
        stats=stats,
        deadline_s=None if run.clock is None else run.clock.share_deadline(METROLOGY_TIME_SHARE),
    )
    run.last_stream_stats = stats
    run.candidates_evaluated_share = stats.evaluated / max(stats.candidates, 1)
    if stats.time_limited:
        message = (
            f"the time limit left the metrology time for {stats.evaluated:,} of the {stats.candidates:,} reachable "
            f"candidate viewpoints ({100 * run.candidates_evaluated_share:.0f} %"
            + (", a random spread over the part)" if stats.time_limited == "projected" else ", the first ones)")
            + ": the plan covers what they measure; allow more time for a complete plan"
        )
        LOG.warning("%s", message)
        run.warnings.append(message)
    allowed = None
    if viewpoint_tilt_mode == "limited":
        valid_all = np.zeros(len(candidates.poses), dtype=bool)
        valid_all[index[useful_index]] = True
        keep_all = select_limited_tilt(
            valid_all, candidates.sample_index, candidates.orientation_index, candidates.tilt_index
        )
        allowed = keep_all
        chosen = np.flatnonzero(keep_all[index[useful_index]])
        if chosen.size < result.n_views:
            result = select_columns(result, chosen)
            useful_index = useful_index[chosen]
    timings["metrology"] = time.perf_counter() - t2
    kept = index[useful_index]
    run.reserve = keep_reserve(stats, index, useful_index, allowed)
    run.evaluation_limits = (float(threshold), float(maximum_deflection))
    run.revived_views = 0
    tools.report("metrology", 1.0, f"{kept.size} viewpoints measure something")
    t3 = time.perf_counter()
    # the views hold slices of the store's arrays (no per-view copies); the set cover's matrix is built from
    # them directly
    run.measurability = result
    del result
    store = run.measurability
    run.entry_alive = np.ones(store.nnz, dtype=bool)
    run.metrology_coverable = np.zeros(len(samples), dtype=bool)
    run.metrology_coverable[store.point_indices] = True
    views = build_viewpoints(
        candidates,
        samples.points,
        samples.normals,
        orientations_around_boresight,
        viewpoint_tilt_mode,
        tools.sensor_model,
        selection=kept,
    )
    overmeasure = run.mechanics["minimum_required_overmeasure"]
    min_length = run.mechanics["minimum_trajectory_length"]
    lo, hi = scan_line_extents(store.t0_min, store.t0_max, overmeasure, min_length)
    run.durations = np.array(
        [estimate_scan_duration((a, b), tools.scan_speed_mm_s) for a, b in zip(lo, hi, strict=True)]
    )
    run.durations_estimate = run.durations.copy()
    run.duration_verified = np.zeros(len(run.durations), dtype=bool)
    run.duration_bias = 1.0
    attach_unverified(views, store, lo, hi, run.durations, store_columns=True)
    # a copy: revived views join last_viewpoints, not the store's columns
    run.generation_views = list(views)
    run.reserve.checked = np.zeros(len(views), dtype=bool)
    run.reserve.failed_dominator = np.zeros(len(views), dtype=bool)
    run.reserve.shelf = []
    timings["viewpoint_objects"] = time.perf_counter() - t3
    run.last_viewpoints = views
    if not views:
        raise PlanningError(
            "no viewpoint can measure the part: no reachable anchor sees a sample within the uncertainty "
            "threshold (is the part within reach of the robot and the threshold sensible?)"
        )
    return list(run.sampled_surface_points), views


def process_viewpoint(
    run: PlanningRun,
    tools: PlanningTools,
    *,
    viewpoint,
    ik_service,
    uncertainty_threshold,
    minimum_required_overmeasure,
    trajectory_sample_step,
    joint_jump_threshold,
    minimum_trajectory_length,
) -> bool:
    """The facade's ``process_viewpoint`` (see there) over ``run``: True when ``viewpoint`` is executable."""
    if run.samples is None:
        raise PlanningError("no samples: call generate_samples_and_viewpoints(...) first")
    threshold = uncertainty_threshold or run.parameters.get("uncertainty_threshold")
    if threshold is None:
        raise PlanningInputError("uncertainty_threshold is required")
    anchor = viewpoint.get_anchor_pose()
    if not reachable_anchors(tools.ik, anchor[None])[0]:
        return False
    points, uncertainties, t0s = tools.sensor_model.process_viewpoint_metrologically(viewpoint, float(threshold))
    if points.size == 0:
        return False
    viewpoint.set_measurable_surface_point_indices_and_uncertainties(points, uncertainties, t0s)
    lo, hi = scan_line_extents(
        [np.min(t0s)], [np.max(t0s)], float(minimum_required_overmeasure), float(minimum_trajectory_length)
    )
    viewpoint.scan_line = (float(lo[0]), float(hi[0]))
    viewpoint.mechanics_verified = False
    viewpoint.mechanics_valid = True
    settings = dict(
        minimum_required_overmeasure=float(minimum_required_overmeasure),
        trajectory_sample_step=float(trajectory_sample_step),
        joint_jump_threshold=float(joint_jump_threshold),
        minimum_trajectory_length=float(minimum_trajectory_length),
        plan_path_to_check_reachability=run.mechanics["plan_path_to_check_reachability"],
    )
    return verify_mechanics(run, tools, viewpoint, settings)


def select_columns(result: MeasurabilityResult, columns: np.ndarray) -> MeasurabilityResult:
    """The columns ``columns`` (ascending) of ``result``, entries gathered once."""
    starts = result.indptr[columns]
    lengths = result.indptr[columns + 1] - starts
    indptr = np.zeros(len(columns) + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    gather = np.repeat(starts - indptr[:-1], lengths) + np.arange(indptr[-1])
    return MeasurabilityResult(
        result.n_points,
        len(columns),
        indptr,
        result.point_indices[gather],
        result.uncertainties[gather],
        result.trajectory_distances[gather],
        None if result.extent_min is None else result.extent_min[columns],
        None if result.extent_max is None else result.extent_max[columns],
    )


def attach_unverified(views: list[ViewPoint], arrays, lo, hi, durations_s, store_columns: bool) -> None:
    """Give each view its slice of ``arrays`` (the store or an evaluated block: ``indptr``, ``point_indices``,
    ``uncertainties``, ``trajectory_distances``), its scan line ``(lo, hi)`` (mm) and estimated duration (s), not
    yet verified; ``store_columns``: the views are the store's columns in order (else they have none)."""
    indptr = arrays.indptr
    for j, view in enumerate(views):
        a, b = indptr[j], indptr[j + 1]
        view.attach_measurements(arrays.point_indices[a:b], arrays.uncertainties[a:b], arrays.trajectory_distances[a:b])
        view.coverage_column = j if store_columns else None
        view.scan_line = (float(lo[j]), float(hi[j]))
        view.mechanics_verified = False
        view.mechanics_valid = True
        view.estimated_duration_s = float(durations_s[j])


def keep_reserve(stats: StreamStats, index: np.ndarray, useful_index: np.ndarray, allowed) -> Reserve:
    """Remember the dominated candidates the evaluation dropped, each with its dominator's store column.

    ``index``: the candidate index of each evaluated pose; ``useful_index``: the evaluated poses kept as store
    columns (ascending); ``allowed``: a mask of the candidates the tilt mode may use (None = all). The
    redundancy cover's drops (no dominator) are not revived: they exist only when the budget requires them.
    """
    dropped = np.zeros(0, dtype=np.int64) if stats.reserve_index is None else stats.reserve_index
    by = np.zeros(0, dtype=np.int64) if stats.reserve_dominator is None else stats.reserve_dominator
    column = np.searchsorted(useful_index, np.maximum(by, 0))
    found = (by >= 0) & (column < useful_index.size)
    found[found] &= useful_index[column[found]] == by[found]
    candidates = index[dropped] if dropped.size else dropped
    if allowed is not None and candidates.size:
        found &= allowed[candidates]
    return Reserve(candidates[found], column[found].astype(np.int64), np.zeros(int(found.sum()), dtype=bool))
