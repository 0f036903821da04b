"""TrajectoryManager: plan, store, load and execute measurement trajectories for a laser line scanner.

The documented API of the original package (names, parameters, defaults, mm and points/mm^2), rebuilt on the
package's ROS-free core: the station comes from configuration (``config/*.yaml``), MoveIt's jobs are done by
KDL / closed-form IK, FCL and OMPL, and every stage works in batch.

Pipeline (``generate_samples_and_viewpoints`` -> ``solve_scp`` -> ``connect_viewpoints`` ->
``convert_viewpointlist_to_execution_plan`` -> ``store_execution_plan`` / ``execute``):

1. the part is loaded in mm, placed at the scene file's part pose times the caller's transform, downward faces
   are not sampled;
2. samples are spread evenly by density; candidate viewpoints are anchored at the optimal standoff;
3. the anchors of all candidates are checked for reachability with the batched closed-form IK, the reachable
   ones are evaluated metrologically in one batch (sparse points x viewpoints matrix);
4. mechanics without waste: the full scan line (Cartesian path, joint jumps, collisions, partial acceptance)
   is computed for the views the set cover picks and, in the same round, for the views it is likely to pick
   next (the greedy cover's, the LP's favourites, the views sharing most points with each pick, views of every
   point no verified view measures yet); one batched IK + collision pass over the batch's scan-line ends rejects
   the views that cannot start first, and the time parameterisation waits for the views the final cover keeps;
   failed or shortened columns are corrected and the cover solved again, over a candidate pool after the
   first round, until the chosen views are all verified or the whole-plan time limit comes (then: the best
   cover of verified views, with its gap);
5. the chosen views are ordered greedily by connection time from the current state (either scan direction),
   improved by 2-opt, and connected with collision-free, time-parameterised paths.

Units: the API takes and returns mm (positions, lengths) and rad; kinematics and collision work in metres; the
conversion happens here, at the edge.

This module is the facade; the work lives beside it: ``request`` (a planning request's defaults and validation,
:meth:`TrajectoryManager.plan_request`), ``mechanics`` (reachability, chunked metrology, scan lines and their
mechanical check), ``ordering`` (move times, view order, unwrapping), ``report`` (coverage report, per-sample
uncertainties, the coverable mask), ``execution`` (the executor interface and the segment loop) and
``progress`` (the stages).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import scipy.sparse

import agiprobot_measurement
from agiprobot_measurement.errors import InternalError
from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.trajectory import JointTrajectory, check_trajectory
from agiprobot_measurement.planning import plan_io
from agiprobot_measurement.planning.execution import (
    EXECUTOR_CHOICES,
    ExecutionCancelled,
    ExecutionError,
    PlanPart,
    SimulatedExecutor,
    execute_segments,
    ros_station_executor,
    segment_triples,
)
from agiprobot_measurement.planning.mechanics import (
    check_scan_line,
    estimate_scan_duration,
    reachable_anchors,
    scan_line_extents,
    scan_line_starts_free,
    set_scan_trajectory,
)
from agiprobot_measurement.planning.ordering import order_views, p2p_durations, unwrapped_towards
from agiprobot_measurement.planning.part_loading import LoadedPart, PartLoadError, SurfaceSamples, load_part
from agiprobot_measurement.planning.placement import check_placement, fixture_placement
from agiprobot_measurement.planning.plan_io import PlanSegment
from agiprobot_measurement.planning.progress import STAGES
from agiprobot_measurement.planning.report import CoverageReport, coverable_mask, point_uncertainties
from agiprobot_measurement.planning.request import (
    PLACEMENTS,
    REQUEST_TILT_MODES,
    PlanRequest,
    WorkBudget,
    WorkEstimate,
    check_choice,
    check_positive,
    estimate_work,
)
from agiprobot_measurement.planning.set_cover import SOLVER_TYPES, SetCoverResult, solve_set_cover
from agiprobot_measurement.planning.streaming import EvaluationSettings, StreamStats, chunk_block, evaluate_streaming
from agiprobot_measurement.planning.viewpoint import (
    TILT_MODES,
    ViewPoint,
    ViewpointCandidates,
    build_viewpoints,
    generate_viewpoint_poses,
    select_limited_tilt,
)
from agiprobot_measurement.sensors.laser_line.model import MeasurabilityResult, SensorModel
from agiprobot_measurement.station import ConfigError, Station

__all__ = [
    "LOG",
    "STAGES",
    "CoverageReport",
    "ExecutionError",
    "PlanRequest",
    "PlanningCancelled",
    "PlanningError",
    "ProgressCallback",
    "SimulatedExecutor",
    "TrajectoryManager",
    "p2p_durations",
]

LOG = logging.getLogger(__name__)

#: tilt auto tries tilt full when tilt none covers less than this share of the metrologically coverable points
AUTO_COVERAGE_SHARE = 0.98
#: ... or needs more views than this
AUTO_VIEWS = 10
#: ... and at least this share of the time limit is left
AUTO_MIN_TIME_SHARE = 0.4
#: coverages within this share of the samples count as the same
AUTO_SAME_COVERAGE = 0.005

#: an IP solve of one verification round stops after this long (s): its cover only names what to verify next
ROUND_IP_TIME_S = 2.0
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
#: each verification round takes up to this many unverified views of every point no verified view measures yet
POINT_VIEWS_PER_ROUND = 24
#: ... but no more than this many in one round (the next round's cover may settle the rest)
MAX_POINT_VIEWS_PER_ROUND = 2000
#: each verification round also takes this many unverified views sharing the most points with each picked one
SUBSTITUTES_PER_VIEW = 20
#: the candidate pool takes at most this many of a solve's most likely columns (or four times the batch)
POOL_LIKELY_COLUMNS = 6000


def _measurable_structure(matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, row indices, column sizes) of the measurable (non-zero) entries of a points x views matrix,
    without copying its values: the planner's matrices hold tens of millions of entries at tilt full."""
    csc = matrix if scipy.sparse.issparse(matrix) and matrix.format == "csc" else scipy.sparse.csc_matrix(matrix)
    alive = csc.data != 0
    if alive.all():
        return csc.indptr, csc.indices, np.diff(csc.indptr)
    col_of_entry = np.repeat(np.arange(csc.shape[1], dtype=np.int32), np.diff(csc.indptr))
    sizes = np.bincount(col_of_entry[alive], minlength=csc.shape[1])
    indptr = np.zeros(csc.shape[1] + 1, dtype=np.int64)
    np.cumsum(sizes, out=indptr[1:])
    return indptr, csc.indices[alive], sizes


#: columns gathered at once when looking for the open points' views (bounds the temporary memory)
OPEN_POINT_CHUNK_ENTRIES = 2_000_000


def open_point_views(matrix, views: list[ViewPoint], per_point: int) -> np.ndarray:
    """Columns to verify for the rows (points) of ``matrix`` (points x views, CSC, non-zero = measurable) that
    no verified view measures yet: up to ``per_point`` unverified columns each, the largest columns first
    (equal sizes: the lower column first).

    The columns are visited largest first in chunks, and the visit stops once every open row has its
    ``per_point`` columns: the largest columns cover most rows, so the first round (every row open) touches a
    few chunks of the matrix, not all of its entries.
    """
    verified = np.array([v.mechanics_verified is True for v in views], dtype=bool)
    unverified = np.array([v.mechanics_verified is False for v in views], dtype=bool)
    indptr, indices, sizes = _measurable_structure(matrix)
    n_rows = matrix.shape[0]
    open_rows = np.zeros(n_rows, dtype=bool)
    open_rows[indices] = True
    if verified.any():
        done_cols = np.flatnonzero(verified & (sizes > 0))
        if done_cols.size:
            open_rows[_gather_rows(indptr, indices, done_cols)] = False
    if not open_rows.any() or per_point <= 0:
        return np.zeros(0, dtype=np.int64)
    # only unverified columns holding an open row can be picked; largest first, then the lower index
    candidates = np.flatnonzero(unverified & (sizes > 0))
    candidates = candidates[np.lexsort((candidates, -sizes[candidates]))]
    need = np.where(open_rows, per_point, 0).astype(np.int64)
    picked_cols, picked_rows = [], []
    position = 0
    while position < candidates.size and need.any():
        cum = np.cumsum(sizes[candidates[position:]])
        stop = position + max(1, int(np.searchsorted(cum, OPEN_POINT_CHUNK_ENTRIES, side="right")))
        chunk = candidates[position:stop]
        position = stop
        lengths = sizes[chunk]
        rows = _gather_rows(indptr, indices, chunk)
        cols = np.repeat(chunk, lengths)
        wanted = need[rows] > 0
        rows, cols = rows[wanted], cols[wanted]
        if rows.size == 0:
            continue
        # rank of each entry among its row's entries in this chunk, in column order (stable sort by row)
        order = np.argsort(rows, kind="stable")
        rows, cols = rows[order], cols[order]
        rank = np.arange(rows.size) - np.searchsorted(rows, rows, side="left")
        take = rank < need[rows]
        picked_rows.append(rows[take])
        picked_cols.append(cols[take])
        need -= np.bincount(rows[take], minlength=n_rows)
    if not picked_cols:
        return np.zeros(0, dtype=np.int64)
    picked = np.concatenate(picked_cols)
    # most-shared columns first: one view that settles many open points is worth more than many that settle one
    unique, counts = np.unique(picked, return_counts=True)
    return unique[np.lexsort((-sizes[unique], -counts))].astype(np.int64)


def _segment_counts(mask: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per segment (column) of a CSC ``indptr``: how many entries of ``mask`` hold."""
    counts = np.zeros(indptr.size - 1, dtype=np.int64)
    nonempty = np.flatnonzero(np.diff(indptr) > 0)
    if nonempty.size:
        # reduceat runs from one start to the next; empty segments in between hold no entries
        counts[nonempty] = np.add.reduceat(mask, indptr[nonempty], dtype=np.int64)
    return counts


def _segment_max(values: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per segment of a CSC ``indptr``: the largest finite value (0 for an empty segment), float64."""
    out = np.zeros(indptr.size - 1)
    nonempty = np.flatnonzero(np.diff(indptr) > 0)
    if nonempty.size:
        finite = np.where(np.isfinite(values), values, 0.0) if not np.all(np.isfinite(values)) else values
        out[nonempty] = np.maximum.reduceat(finite, indptr[nonempty])
    return np.maximum(out, 0.0)


def _gather_rows(indptr: np.ndarray, indices: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The row indices of ``columns`` (in that order), concatenated."""
    starts = np.asarray(indptr)[columns]
    lengths = np.asarray(indptr)[columns + 1] - starts
    offsets = np.zeros(columns.size, dtype=np.int64)
    np.cumsum(lengths[:-1], out=offsets[1:])
    return indices[np.repeat(starts - offsets, lengths) + np.arange(int(lengths.sum()))]


def _select_columns(result: MeasurabilityResult, columns: np.ndarray) -> MeasurabilityResult:
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


def _executable_columns(views: list[ViewPoint]) -> np.ndarray:
    """Indices of the views verified executable."""
    return np.flatnonzero([v.mechanics_verified is True and v.mechanics_valid for v in views])


def substitute_views(matrix, views: list[ViewPoint], columns: np.ndarray, per_view: int) -> np.ndarray:
    """The unverified columns sharing the most points with each of ``columns`` (points x views matrix, CSC,
    non-zero = measurable), up to ``per_view`` each, the largest overlaps first.

    When a picked view fails or is shortened, the next cover takes the views that measure the same points,
    which a reduction had hidden as dominated: verifying them in the same round spares the rounds that would
    uncover them one by one.
    """
    columns = np.asarray(columns, dtype=np.int64)
    if columns.size == 0 or per_view <= 0:
        return np.zeros(0, dtype=np.int64)
    measurable = (scipy.sparse.csc_matrix(matrix) != 0).astype(np.float32)
    overlap = (measurable[:, columns].T.tocsr() @ measurable).tocoo()  # len(columns) x views
    unverified = np.array([v.mechanics_verified is False for v in views], dtype=bool)
    keep = unverified[overlap.col] & (overlap.col != columns[overlap.row])
    r, c, w = overlap.row[keep], overlap.col[keep], overlap.data[keep]
    if r.size == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((-w, r))
    r, c, w = r[order], c[order], w[order]
    rank = np.arange(r.size) - np.searchsorted(r, r, side="left")
    chosen = rank < per_view
    # best overlaps first across all picked views, each column once
    c, w = c[chosen], w[chosen]
    c = c[np.argsort(-w, kind="stable")]
    _, first = np.unique(c, return_index=True)
    return c[np.sort(first)]


def _views_problem(views: list[ViewPoint], n_points: int, only_verified: bool):
    """The coverage problem (points x views boolean CSC matrix, worst uncertainty, duration s) of views that are
    not columns of the store, from their own measurements."""
    usable = [v.mechanics_valid and not (only_verified and v.mechanics_verified is False) for v in views]
    indices = [v.measurable_indices if ok else np.zeros(0, np.int64) for v, ok in zip(views, usable, strict=True)]
    values = [v.measurable_uncertainties if ok else np.zeros(0) for v, ok in zip(views, usable, strict=True)]
    indptr = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([len(i) for i in indices], out=indptr[1:])
    rows = np.concatenate(indices) if indices else np.zeros(0, dtype=np.int64)
    matrix = scipy.sparse.csc_matrix((np.ones(rows.size, dtype=bool), rows, indptr), shape=(n_points, len(views)))
    worst = _segment_max(np.concatenate(values) if values else np.zeros(0), indptr)
    durations = np.array([1.0 if v.estimated_duration_s is None else v.estimated_duration_s for v in views])
    return matrix, worst, durations


def _attach_unverified(views: list[ViewPoint], arrays, lo, hi, durations_s, store_columns: bool) -> None:
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


#: progress callback: (stage, fraction done 0..1, message)
ProgressCallback = Callable[[str, float, str], None]


class PlanningError(InternalError):
    """The planning pipeline cannot go on (nothing reachable, nothing measurable, no part loaded...)."""


class PlanningCancelled(RuntimeError):
    """The caller cancelled planning (the progress callback raised it)."""


class TrajectoryManager:
    """Completely integrated system for high-coverage, uncertainty-minimal scanning of a part with a laser line
    scanner on the station's robot. Everything station-specific comes from configuration.

    :param station: the station (default: ``Station.load()`` from ``config/``).
    :param scan_speed_mm_s: tip speed during measurement segments.
    :param planner_name: OMPL planner for connections.
    :param progress: optional callback ``(stage, fraction, message)``; raising :class:`PlanningCancelled` in it
        cancels planning.
    :param seed: seeds sampling and planning, so plans are reproducible.
    :param workers: evaluate the candidates on a local Dask cluster of this many worker processes (0 = in this
        process); :param scheduler: ... or on the existing Dask cluster at this address (``tcp://host:8786``);
        :param max_memory_bytes: the memory budget of the evaluation's store (None = 80 % of the memory
        available); work whose projected store does not fit is refused before the evaluation. The plan does
        not depend on where the candidates are evaluated. :meth:`close` ends a local cluster.
    """

    def __init__(
        self,
        station: Station | None = None,
        scan_speed_mm_s: float = 50.0,
        planner_name: str = "RRTConnect",
        progress: ProgressCallback | None = None,
        seed: int = 0,
        start_state: np.ndarray | str = "home",
        preferred_state: np.ndarray | str = "up",
        work_budget: WorkBudget | None = None,
        workers: int = 0,
        scheduler: str = "",
        max_memory_bytes: float | None = None,
    ):
        self.evaluation = EvaluationSettings(int(workers or 0), str(scheduler or ""), max_memory_bytes)
        self._evaluator = None
        #: what the last candidate evaluation did (candidates, kept pairs, chunks, projection, times)
        self.last_stream_stats: StreamStats | None = None
        self.station = station or Station.load()
        self.work_budget = work_budget if work_budget is not None else WorkBudget()
        self.last_work_estimate: WorkEstimate | None = None
        if not (math.isfinite(scan_speed_mm_s) and scan_speed_mm_s > 0):
            raise ValueError(f"scan_speed_mm_s must be a positive number, got {scan_speed_mm_s}")
        self.scan_speed_mm_s = float(scan_speed_mm_s)
        self.kinematics = KinematicModel.from_station(self.station)
        self.ik = make_ik_solver(self.kinematics)
        self.limits = self.station.limits
        self.sensor_model = SensorModel(self.station.scanner.sensor_parameters)
        self._base_scene = self.station.scene
        self.collision = CollisionChecker.from_station(self.station, model=self.kinematics, load_part=False)
        self.planner_name = planner_name
        self._planner = None
        self.progress = progress
        self.seed = int(seed)
        self.current_state = self._state(start_state)
        self.preferred_state = self._state(preferred_state)
        self.part: LoadedPart | None = None
        self.target_mesh = None
        self.samples: SurfaceSamples | None = None
        self.sampled_surface_points: list[np.ndarray] = []
        self.candidates: ViewpointCandidates | None = None
        self.measurability: MeasurabilityResult | None = None
        self.last_set_cover: SetCoverResult | None = None
        self.last_viewpoints: list[ViewPoint] = []
        self.last_ordered: list[ViewPoint] = []
        self.unconnected_views: list[ViewPoint] = []
        self.timings_s: dict[str, float] = {}
        self.parameters: dict = {}
        self.mechanics_checked = 0
        #: id(view) -> (view, joint path rad) of checked scan lines whose trajectory is not computed yet
        self._pending_scan_paths: dict[int, tuple[ViewPoint, np.ndarray]] = {}
        self.measurability = None
        #: doubts about the run the caller should hear of (low reachability, time limit hit, ...)
        self.warnings: list[str] = []
        #: share of samples with at least one reachable candidate anchor (after sampling)
        self.reachable_share: float | None = None
        self._metrology_coverable: np.ndarray | None = None
        self.time_limit_hit = False
        self._generation_views: list[ViewPoint] | None = None
        self._duration_bias = 1.0
        # dropped (dominated) candidates: candidate indices, the store column of each one's dominator, whether each
        # was evaluated again; which store columns were looked at for revival, and which of them failed
        self._reserve_candidates = np.zeros(0, dtype=np.int64)
        self._reserve_dominator_column = np.zeros(0, dtype=np.int64)
        self._reserve_revived = np.zeros(0, dtype=bool)
        self._revival_checked = np.zeros(0, dtype=bool)
        self._failed_dominator = np.zeros(0, dtype=bool)
        # dropped candidates evaluated again but not needed yet: every point they measure has another view
        self._revival_shelf: list[ViewPoint] = []
        self._evaluation_limits: tuple[float, float] = (0.0, 0.0)
        self.revived_views = 0
        # mechanics settings used by the lazy verification (set by generate_samples_and_viewpoints)
        self._mechanics = {
            "minimum_required_overmeasure": 5.0,
            "trajectory_sample_step": 2.0,
            "joint_jump_threshold": 1.5,
            "minimum_trajectory_length": 25.0,
            "plan_path_to_check_reachability": False,
        }

    # ----------------------------------------------------------------------------------------- helpers
    def _state(self, value) -> np.ndarray:
        if isinstance(value, str):
            if value not in self.station.named_states:
                raise ConfigError(f"unknown named state '{value}'; known: {', '.join(self.station.named_states)}")
            return self.station.named_states[value].copy()
        state = np.asarray(value, dtype=float)
        if state.shape != (self.kinematics.dof,) or not np.all(np.isfinite(state)):
            raise ValueError(f"a joint state needs {self.kinematics.dof} finite values")
        return state

    def _report(self, stage: str, fraction: float, message: str = "") -> None:
        if self.progress is not None:
            self.progress(stage, float(min(max(fraction, 0.0), 1.0)), message)

    def evaluator(self):
        """The Dask evaluator of this manager's settings (made on first use), or None to evaluate here."""
        if self._evaluator is None and self.evaluation.distributed:
            from agiprobot_measurement.planning.distributed import DaskEvaluator

            self._evaluator = DaskEvaluator(self.evaluation.workers, self.evaluation.scheduler)
        return self._evaluator

    def close(self) -> None:
        """End the Dask client (and a local cluster) of the evaluation, if one was started."""
        if self._evaluator is not None:
            self._evaluator.close()
            self._evaluator = None

    @property
    def planner(self):
        if self._planner is None:
            from agiprobot_measurement.motion.motion_planning import MotionPlanner

            # OMPL refuses the seed 0 (and says so on every call): seeds count from 1 there
            self._planner = MotionPlanner(self.collision, planner=self.planner_name, seed=self.seed + 1)
        return self._planner

    # ------------------------------------------------------------------------------------------- load
    def load_target_mesh(
        self,
        file_name,
        transform=np.eye(4),  # noqa: B008 (read only)
        add_wbk_mirrors=True,
        remove_downside=True,
        remove_threshold_angle_deg=20,
        units="mm",
        placement="scene",
        check_scene_overlap=True,
        tessellation_tolerance_mm=0.0,
    ) -> bool:
        """Load the part to measure and put it into the collision world.

        ``transform``: 4x4 placement of the CAD frame (translation in mm) relative to the scene file's part
        pose (the station's part offset, ``config/scene.yaml``); identity puts the part where the scene says.
        ``add_wbk_mirrors``: keep the scene objects of group ``wbk_mirrors`` (the original station's two mirrors).
        ``units``: the file's length unit (mm, cm, dm, m, inch, ft; STEP files carry their own).
        ``placement``: 'scene' (as above) or 'fixture': the part turned by the rotation of scene pose x
        ``transform``, its lowest point on the fixture's top and its bounding box centred over the fixture, then
        shifted by ``transform``'s translation. ``check_scene_overlap``: refuse a part that overlaps a scene object
        or the robot at its start state (:class:`~agiprobot_measurement.planning.placement.PlacementError`, naming
        the object, the depth and the lift that clears it). ``tessellation_tolerance_mm``: linear deflection of
        the STEP tessellation (0 = the reader's default). Raises
        :class:`~agiprobot_measurement.planning.part_loading.PartLoadError` with the reason for unreadable, empty or
        implausible input; returns True when everything was loaded.
        """
        check_choice(placement, PLACEMENTS, "placement")
        transform = np.asarray(transform, dtype=float)
        if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
            raise PartLoadError(f"transform must be a finite 4x4 matrix, got shape {transform.shape}")
        scene_part = self.station.scene.part
        placement_mm = np.eye(4)
        if scene_part is not None:
            placement_mm = scene_part.pose.copy()
            placement_mm[:3, 3] *= 1000.0
        world = placement_mm @ transform
        if placement == "fixture":
            turned = np.eye(4)
            turned[:3, :3] = world[:3, :3]
            world = turned
        part = load_part(
            file_name,
            units=units,
            transform=world,
            remove_downside=remove_downside,
            remove_threshold_angle_deg=remove_threshold_angle_deg,
            tessellation_tolerance_mm=tessellation_tolerance_mm,
        )
        scene = self._base_scene if add_wbk_mirrors else self._base_scene.without_group("wbk_mirrors")
        if placement == "fixture":
            centred = fixture_placement(part.mesh.vertices, np.eye(3), scene)
            shift = centred[:3, 3] + placement_mm[:3, :3] @ transform[:3, 3]
            part.mesh.apply_translation(shift)
            moved = np.eye(4)
            moved[:3, 3] = shift
            part.transform = moved @ part.transform
        for message in part.warnings:
            LOG.warning("%s", message)
        self.collision = CollisionChecker(self.kinematics, scene, self.collision.config, load_part=False)
        self.collision.set_part(part.mesh, pose=np.eye(4), name="part", scale_to_m=1e-3)
        if check_scene_overlap:
            started = time.perf_counter()
            check_placement(part.mesh, scene, self.collision, self.current_state)
            self.timings_s["placement_check"] = time.perf_counter() - started
        self.warnings = list(part.warnings)
        self._planner = None
        self.part = part
        self.target_mesh = part.mesh
        self.samples = None
        self.parameters.update(
            part_file=str(Path(file_name).resolve()),
            units=units,
            add_wbk_mirrors=bool(add_wbk_mirrors),
            remove_downside=bool(remove_downside),
            remove_threshold_angle_deg=float(remove_threshold_angle_deg),
            placement=placement,
            # file coordinates -> world mm (scale included), so a stored plan names its part's placement
            part_transform_mm=(part.transform @ np.diag([part.scale_to_mm] * 3 + [1.0])).reshape(-1).tolist(),
            seed=self.seed,
        )
        return True

    def _require_part(self) -> LoadedPart:
        if self.part is None:
            raise PlanningError("no part loaded: call load_target_mesh(file_name, ...) first")
        return self.part

    # -------------------------------------------------------------------------- samples + viewpoints
    def generate_samples_and_viewpoints(
        self,
        sampling_density,
        uncertainty_threshold,
        orientations_around_boresight,
        viewpoint_tilt_mode="full",
        plan_path_to_check_reachability=False,
        minimum_trajectory_length=25,
        trajectory_sample_step=2,
        minimum_required_overmeasure=5,
        joint_jump_threshold=1.5,
        maximum_deflection=500.0,
        min_reachable_share=0.3,
    ):
        """Sample the part (``sampling_density`` points/mm^2), generate candidate viewpoints and evaluate them.

        Returns ``(sampled surface points (list of (3,) mm), viewpoints)``: the viewpoints whose anchor pose is
        reachable and which measure at least one sample within ``uncertainty_threshold`` (mm). Their scan
        lines are checked mechanically (Cartesian path, joint jumps, collisions) lazily, when ``solve_scp``
        picks them, or at once with :meth:`process_viewpoint`. After the (cheap) anchor reachability the share
        of samples with at least one reachable anchor is in ``reachable_share``; below ``min_reachable_share`` a
        warning (logged and in ``warnings``) names it and suggests another placement or tilts.
        """
        part = self._require_part()
        density = check_positive(sampling_density, "sampling_density", "sampling_density (points/mm^2)")
        threshold = check_positive(uncertainty_threshold, "uncertainty_threshold", "uncertainty_threshold (mm)")
        check_choice(viewpoint_tilt_mode, TILT_MODES, "viewpoint_tilt_mode")
        for name, value in (
            ("minimum_trajectory_length", minimum_trajectory_length),
            ("trajectory_sample_step", trajectory_sample_step),
            ("joint_jump_threshold", joint_jump_threshold),
        ):
            check_positive(value, name)
        self._mechanics = {
            "minimum_required_overmeasure": float(minimum_required_overmeasure),
            "trajectory_sample_step": float(trajectory_sample_step),
            "joint_jump_threshold": float(joint_jump_threshold),
            "minimum_trajectory_length": float(minimum_trajectory_length),
            "plan_path_to_check_reachability": bool(plan_path_to_check_reachability),
        }
        self.parameters.update(
            sampling_density=density,
            uncertainty_threshold=threshold,
            orientations_around_boresight=int(orientations_around_boresight),
            viewpoint_tilt_mode=viewpoint_tilt_mode,
            **self._mechanics,
        )
        timings = self.timings_s
        t0 = time.perf_counter()
        # the largest work of this run, refused beyond the budget before anything is allocated
        self.last_work_estimate = self.work_budget.check(
            estimate_work(part.measurable_area, density, int(orientations_around_boresight), viewpoint_tilt_mode)
        )
        self._report("sampling", 0.0, f"sampling at {density} points/mm^2")
        samples = part.sample(density, seed=self.seed)
        if len(samples) == 0:
            raise PlanningError(
                f"sampling at {density} points/mm^2 gives no points on {part.measurable_area:.1f} mm^2: "
                "raise the density (or check the part's unit)"
            )
        self.samples = samples
        self.sampled_surface_points = [p for p in samples.points]
        self.sensor_model.set_processing_context(part.mesh, samples.points, samples.face_ids)
        candidates = generate_viewpoint_poses(
            samples.points, samples.normals, orientations_around_boresight, viewpoint_tilt_mode, self.sensor_model
        )
        self.candidates = candidates
        timings["sampling"] = time.perf_counter() - t0
        self._report("sampling", 1.0, f"{len(samples)} samples, {len(candidates.poses)} candidate viewpoints")

        # anchors: reachability for all candidates at once (closed-form IK); metrology only where reachable
        t1 = time.perf_counter()
        reachable = reachable_anchors(self.ik, candidates.poses)
        timings["anchor_reachability"] = time.perf_counter() - t1
        sample_reachable = np.zeros(len(samples), dtype=bool)
        sample_reachable[candidates.sample_index[reachable]] = True
        self.reachable_share = float(sample_reachable.mean())
        if self.reachable_share < float(min_reachable_share):
            message = (
                f"only {100 * self.reachable_share:.1f} % of the {len(samples)} samples have a reachable anchor "
                f"(threshold {100 * float(min_reachable_share):.0f} %): move the part closer to the robot or place it "
                "on the fixture (placement 'fixture'), or allow tilts (tilt mode limited/full/auto)"
            )
            LOG.warning("%s", message)
            self.warnings.append(message)
        self._report("metrology", 0.0, f"{int(reachable.sum())} of {len(reachable)} anchors reachable")
        t2 = time.perf_counter()
        index = np.flatnonzero(reachable)
        stats = StreamStats()
        # what this process holds beside the store: the samples and every candidate's pose and indices
        fixed = samples.points.nbytes * 4 + candidates.poses.nbytes * 2 + len(candidates.poses) * 40
        result, useful_index = evaluate_streaming(
            self.sensor_model,
            candidates.poses[index],
            threshold,
            maximum_deflection,
            self._report,
            settings=self.evaluation,
            executor=self.evaluator(),
            fixed_bytes=fixed,
            stats=stats,
        )
        self.last_stream_stats = stats
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
                result = _select_columns(result, chosen)
                useful_index = useful_index[chosen]
        timings["metrology"] = time.perf_counter() - t2
        kept = index[useful_index]
        self._keep_reserve(stats, index, useful_index, allowed)
        self._evaluation_limits = (float(threshold), float(maximum_deflection))
        self.revived_views = 0
        self._report("metrology", 1.0, f"{kept.size} viewpoints measure something")
        t3 = time.perf_counter()
        # the views hold slices of the store's arrays (no per-view copies); the set cover's matrix is built from
        # them directly
        self.measurability = result
        del result
        store = self.measurability
        self._entry_alive = np.ones(store.nnz, dtype=bool)
        self._metrology_coverable = np.zeros(len(samples), dtype=bool)
        self._metrology_coverable[store.point_indices] = True
        views = build_viewpoints(
            candidates,
            samples.points,
            samples.normals,
            orientations_around_boresight,
            viewpoint_tilt_mode,
            self.sensor_model,
            selection=kept,
        )
        overmeasure = self._mechanics["minimum_required_overmeasure"]
        min_length = self._mechanics["minimum_trajectory_length"]
        lo, hi = scan_line_extents(store.t0_min, store.t0_max, overmeasure, min_length)
        self._durations = np.array(
            [estimate_scan_duration((a, b), self.scan_speed_mm_s) for a, b in zip(lo, hi, strict=True)]
        )
        self._durations_estimate = self._durations.copy()
        self._duration_verified = np.zeros(len(self._durations), dtype=bool)
        self._duration_bias = 1.0
        _attach_unverified(views, store, lo, hi, self._durations, store_columns=True)
        # a copy: revived views join last_viewpoints, not the store's columns
        self._generation_views = list(views)
        self._revival_checked = np.zeros(len(views), dtype=bool)
        self._failed_dominator = np.zeros(len(views), dtype=bool)
        self._revival_shelf = []
        timings["viewpoint_objects"] = time.perf_counter() - t3
        self.last_viewpoints = views
        if not views:
            raise PlanningError(
                "no viewpoint can measure the part: no reachable anchor sees a sample within the uncertainty "
                "threshold (is the part within reach of the robot and the threshold sensible?)"
            )
        return list(self.sampled_surface_points), views

    # ------------------------------------------------------------------------------------ mechanics
    def process_viewpoint(
        self,
        viewpoint,
        ik_service=None,
        uncertainty_threshold=None,
        minimum_required_overmeasure=5,
        trajectory_sample_step=2,
        joint_jump_threshold=1.5,
        minimum_trajectory_length=50,
    ) -> bool:
        """Process one viewpoint entirely: anchor reachability, metrology, the measurement trajectory (straight
        Cartesian line, joint jumps, collisions, partial acceptance) and its timing. On success the results are
        stored in the viewpoint and True is returned.

        ``ik_service`` is accepted for compatibility and ignored (the package's own IK is used);
        ``uncertainty_threshold`` (mm) defaults to the one of the last generation.
        """
        if self.samples is None:
            raise PlanningError("no samples: call generate_samples_and_viewpoints(...) first")
        threshold = uncertainty_threshold or self.parameters.get("uncertainty_threshold")
        if threshold is None:
            raise ValueError("uncertainty_threshold is required")
        anchor = viewpoint.get_anchor_pose()
        if not reachable_anchors(self.ik, anchor[None])[0]:
            return False
        points, uncertainties, t0s = self.sensor_model.process_viewpoint_metrologically(viewpoint, float(threshold))
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
            plan_path_to_check_reachability=self._mechanics["plan_path_to_check_reachability"],
        )
        return self._verify_mechanics(viewpoint, settings)

    def _keep_reserve(self, stats: StreamStats, index: np.ndarray, useful_index: np.ndarray, allowed) -> None:
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
        self._reserve_candidates = candidates[found]
        self._reserve_dominator_column = column[found].astype(np.int64)
        self._reserve_revived = np.zeros(self._reserve_candidates.size, dtype=bool)

    def _revive_dominated(self) -> list[ViewPoint]:
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
        views = self._generation_views
        if not self._reserve_candidates.size or not views or self.measurability is None:
            return []
        store = self.measurability
        newly = np.flatnonzero(~self._revival_checked)
        if newly.size:
            newly = newly[[views[j].mechanics_verified is True for j in newly.tolist()]]
        if newly.size:
            # rejected, or shortened (a shortened view keeps only the points it still sweeps)
            failed = [not views[j].mechanics_valid or views[j].measurable_indices.size < store.indptr[j + 1] - store.indptr[j]
                      for j in newly.tolist()]  # fmt: skip
            self._failed_dominator[newly[np.asarray(failed, dtype=bool)]] = True
            self._revival_checked[newly] = True
        waiting = ~self._reserve_revived & self._failed_dominator[self._reserve_dominator_column]
        if not waiting.any() and not self._revival_shelf:
            return []
        started = time.perf_counter()
        measured = self._measured_counts()
        if waiting.any():
            dominators = np.unique(self._reserve_dominator_column[waiting])
            needy = dominators[self._has_open_points(dominators, measured)]
            pick = np.flatnonzero(waiting & np.isin(self._reserve_dominator_column, needy))
            if pick.size:
                self._reserve_revived[pick] = True
                self._revival_shelf.extend(self._evaluate_again(self._reserve_candidates[pick]))
        revived, shelf = [], []
        for view in self._revival_shelf:
            (revived if np.any(measured[view.measurable_indices] == 0) else shelf).append(view)
        self._revival_shelf = shelf
        self.last_viewpoints.extend(revived)
        self.revived_views += len(revived)
        self.timings_s["revival"] = self.timings_s.get("revival", 0.0) + time.perf_counter() - started
        if revived:
            LOG.debug("revived %d dominated candidates (%d wait)", len(revived), len(shelf))
        return revived

    def _evaluate_again(self, candidates: np.ndarray) -> list[ViewPoint]:
        """The views (unverified, not store columns) of dropped candidates that measure something."""
        threshold, deflection = self._evaluation_limits
        block, columns, _ = chunk_block(self.sensor_model, self.candidates.poses[candidates], threshold, deflection)
        views = build_viewpoints(
            self.candidates,
            self.samples.points,
            self.samples.normals,
            int(self.parameters["orientations_around_boresight"]),
            self.parameters["viewpoint_tilt_mode"],
            self.sensor_model,
            selection=candidates[columns],
        )
        lo, hi = scan_line_extents(
            block.t0_min,
            block.t0_max,
            self._mechanics["minimum_required_overmeasure"],
            self._mechanics["minimum_trajectory_length"],
        )
        durations = [estimate_scan_duration((a, b), self.scan_speed_mm_s) for a, b in zip(lo, hi, strict=True)]
        _attach_unverified(views, block, lo, hi, durations, store_columns=False)
        return views

    def _measured_counts(self) -> np.ndarray:
        """Per point, how many views that may still be executable measure it: live store entries and revived
        views not rejected."""
        store = self.measurability
        measured = np.bincount(store.point_indices[self._entry_alive], minlength=store.n_points)
        for view in self.last_viewpoints[len(self._generation_views) :]:
            if view.mechanics_valid:
                measured[np.asarray(view.measurable_indices, dtype=np.int64)] += 1
        return measured

    def _has_open_points(self, columns: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """For store columns, whether one of their points (as evaluated, before any shortening) has
        ``measured == 0``."""
        store = self.measurability
        starts, ends = store.indptr[columns], store.indptr[columns + 1]
        lengths = ends - starts
        owner = np.repeat(np.arange(columns.size), lengths)
        entries = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(int(lengths.sum()))
        open_entry = measured[store.point_indices[entries]] == 0
        return np.bincount(owner[open_entry], minlength=columns.size) > 0

    def _column_range(self, view: ViewPoint):
        """The view's entry range in the generation's coverage store, or None for a foreign view."""
        j = view.coverage_column
        views = self._generation_views
        if j is None or views is None or j >= len(views) or views[j] is not view:
            return None
        return int(self.measurability.indptr[j]), int(self.measurability.indptr[j + 1])

    def _verify_mechanics(self, view: ViewPoint, settings: dict | None = None, time_parameterize: bool = True) -> bool:
        """Compute the view's measurement trajectory; shorten the view to what is executable or reject it.

        With ``time_parameterize=False`` only the scan line's path is checked (the view is verified, valid or
        not, its duration an estimate); the trajectory is computed later by :meth:`_finish_scan_trajectories`
        for the views a cover keeps (the time parameterisation costs twice the check).
        """
        started = time.perf_counter()
        path = None
        try:
            path = check_scan_line(
                view,
                settings or self._mechanics,
                ik=self.ik,
                collision=self.collision,
                preferred_state=self.preferred_state,
                scan_speed_mm_s=self.scan_speed_mm_s,
                connect_from_current=lambda q: self.connect(self.current_state, q, planning_time_s=1.0),
            )
            if path is not None:
                if time_parameterize:
                    self._set_scan_trajectory(view, path)
                else:
                    view.set_trajectory_for_measurement(None)
                    self._pending_scan_paths[id(view)] = (view, path)
        finally:
            self.timings_s["mechanics"] = self.timings_s.get("mechanics", 0.0) + time.perf_counter() - started
            self.mechanics_checked += 1
        valid = path is not None
        span = self._column_range(view)
        if span is not None:
            a, b = span
            if not valid:
                self._entry_alive[a:b] = False
            else:
                if view.measurable_indices.size < b - a:  # shortened: only the points it still sweeps
                    kept = np.isin(self.measurability.point_indices[a:b], view.measurable_indices)
                    self._entry_alive[a:b] &= kept
                if time_parameterize:
                    self._record_duration(view)
        return valid

    def _set_scan_trajectory(self, view: ViewPoint, path: np.ndarray) -> None:
        self._pending_scan_paths.pop(id(view), None)
        set_scan_trajectory(
            view, path, kinematics=self.kinematics, limits=self.limits, scan_speed_mm_s=self.scan_speed_mm_s
        )

    def _record_duration(self, view: ViewPoint) -> None:
        """A verified view's trajectory duration (s) replaces its estimate in the set cover's durations."""
        if self._column_range(view) is None:
            return
        j = view.coverage_column
        # estimates must not be optimistic, or IP_time keeps preferring views not yet verified
        ratio = view.estimated_duration_s / max(self._durations_estimate[j], 1e-9)
        self._duration_bias = max(self._duration_bias, ratio)
        self._durations[j] = view.estimated_duration_s
        self._duration_verified[j] = True

    def _finish_scan_trajectories(self, views) -> None:
        """Time-parameterise the checked scan lines of ``views`` whose trajectory was deferred."""
        started = time.perf_counter()
        try:
            for view in views:
                pending = self._pending_scan_paths.get(id(view))
                if pending is not None and pending[0] is view and view.get_trajectory_for_measurement() is None:
                    self._set_scan_trajectory(view, pending[1])
                    self._record_duration(view)
        finally:
            self.timings_s["mechanics"] = self.timings_s.get("mechanics", 0.0) + time.perf_counter() - started

    def _screen_scan_lines(self, views) -> int:
        """Reject, in one batched pass, the unverified views whose scan line has no collision-free IK branch
        at either end (:func:`scan_line_starts_free`): the full check would reject them too. Returns how many
        it rejected."""
        todo = [v for v in views if v.mechanics_verified is False]
        if not todo:
            return 0
        started = time.perf_counter()
        free = scan_line_starts_free(todo, self.ik, self.collision, self.preferred_state)
        rejected = 0
        for view, ok in zip(todo, free.tolist(), strict=True):
            if ok:
                continue
            view.mechanics_verified = True
            view.mechanics_valid = False
            span = self._column_range(view)
            if span is not None:
                self._entry_alive[span[0] : span[1]] = False
            rejected += 1
        self.mechanics_checked += rejected
        self.timings_s["mechanics"] = self.timings_s.get("mechanics", 0.0) + time.perf_counter() - started
        return rejected

    # ------------------------------------------------------------------------------------ set cover
    def solve_scp(
        self,
        provided_viewpoints,
        solver_type="greedy",
        time_limit_s=60.0,
        max_rounds=30,
        mip_gap=0.02,
        deadline_s=None,
        verification_batch=None,
    ):
        """Choose viewpoints that together measure every point any provided viewpoint measures.

        ``solver_type``: 'greedy', 'IP_basic', 'IP_uncertainty' or 'IP_time' (an unknown name raises
        ValueError listing these). Views picked but not yet verified mechanically are verified (and corrected
        or dropped) and the problem is solved again until every chosen view is executable. Each round verifies
        a batch: the picked views, the greedy cover's and the views the LP relaxation likes best (most likely
        picked first), at least ``verification_batch`` (default: four times the cover) views, so the loop ends
        in a few rounds. ``time_limit_s`` bounds one IP solve, ``mip_gap`` is the relative gap at which it may
        stop (0 = prove optimality); ``deadline_s`` (a ``time.perf_counter()`` value) bounds the whole loop: when
        it comes, or after ``max_rounds``, the cover is solved once more over verified views only, so the result
        is always executable (``time_limit_hit`` says so, the gap is in ``last_set_cover``). Returns the chosen
        views as a set (documented type).
        """
        if solver_type not in SOLVER_TYPES:
            raise ValueError(f"unknown solver_type {solver_type!r}; valid names: {', '.join(SOLVER_TYPES)}")
        views = list(provided_viewpoints)
        if not views:
            raise PlanningError("solve_scp needs at least one viewpoint")
        n_points = len(self.sampled_surface_points) or 1 + max(int(v.measurable_indices.max(initial=0)) for v in views)
        t0 = time.perf_counter()
        # only IP_time needs the verified views' real durations while solving; the others time-parameterise
        # the scan lines of the chosen views only
        defer_trajectories = solver_type != "IP_time"
        provided = {id(v) for v in views}
        self._pending_scan_paths = {k: p for k, p in self._pending_scan_paths.items() if k in provided}
        deadline = math.inf if deadline_s is None else float(deadline_s)
        mechanics_before = self.timings_s.get("mechanics", 0.0)
        set_cover_time = 0.0
        verified_count = 0
        only_verified = False
        self.time_limit_hit = False
        result = None
        rounds_used = 0
        # Rounds after the first solve a restricted problem: the columns the first (full) solve's reductions kept,
        # plus every column verified since. The full matrix's reductions cost seconds on parts whose views see
        # hundreds of points; the pool's cost milliseconds. When a restricted cover is fully verified, the full
        # problem is solved once more (if time allows) to prove the cover is optimal over all views.
        pool: np.ndarray | None = None
        full_checked = False
        full_solve_s = 0.0
        best_verified: SetCoverResult | None = None
        # a round's cover whose picks all verified as executable with their points: the next round takes it as
        # its (verified) cover instead of solving again, which could pick other, equally good unverified views
        settled: SetCoverResult | None = None
        full_solves = 0
        for round_index in range(max_rounds + 1):
            rounds_used = round_index + 1
            now = time.perf_counter()
            # the first round always solves and verifies its picks: a plan comes out however short the time
            if round_index == max_rounds or (now >= deadline and round_index > 0):
                only_verified = True  # the fallback: no more verification, a cover of verified views
                self.time_limit_hit = now >= deadline
                message = (
                    f"set cover: {'the time limit came' if self.time_limit_hit else f'{max_rounds} rounds'} after "
                    f"{verified_count} scan lines verified; solving over verified views only"
                )
                LOG.warning("%s", message)
                self.warnings.append(message)
            matrix, worst, durations = self._coverage_problem(views, n_points, only_verified)
            self._report("set cover", min(0.9, round_index / max(max_rounds, 1)), f"round {round_index + 1}")
            # an IP solve never takes all the time left: verification and the last solve need some
            # a round's cover only decides what to verify next (its columns change after that): a short solve is
            # enough; the last cover gets the time left (below)
            remaining = deadline - time.perf_counter()
            columns = np.arange(len(views)) if pool is None or only_verified else pool
            if only_verified:
                # the unverified columns are empty here: leaving them out is the same programme, much smaller
                executable = _executable_columns(views)
                columns = executable if executable.size else columns
            # a solve over all views names the pool the next rounds choose from: its reductions must finish
            n_candidates = max(len(views), 0 if self.candidates is None else len(self.candidates.poses))
            round_s = LARGE_ROUND_IP_TIME_S if n_candidates >= LARGE_PROBLEM_VIEWS else ROUND_IP_TIME_S
            limit = min(time_limit_s, FULL_ROUND_IP_TIME_S if columns.size == len(views) else round_s)
            if math.isfinite(remaining):
                limit = max(1.0, min(limit, 0.5 * remaining))
            sub = matrix if columns.size == len(views) else matrix[:, columns]
            if settled is not None and not only_verified:
                result, settled = settled, None
            else:
                result = solve_set_cover(
                    sub,
                    solver_type,
                    uncertainties=worst[columns],
                    durations_s=durations[columns] if solver_type == "IP_time" else None,
                    time_limit_s=limit,
                    mip_gap=mip_gap,
                )
                set_cover_time += result.solve_time_s
                if columns.size == len(views):
                    full_solve_s = result.solve_time_s
                    full_solves += 1
                result = dataclasses.replace(result, selected=columns[result.selected])
            chosen = [views[j] for j in result.selected.tolist()]
            pending = [v for v in chosen if v.mechanics_verified is False]
            if only_verified:
                break
            if not pending and columns.size < len(views):
                best_verified = result
            if pending and columns.size == len(views) and best_verified is not None:
                # unverified views count as executable in the full problem, so its bound is a bound on every
                # executable cover: a verified cover within the gap of it is good enough
                bound = result.lower_bound
                same_points = int(best_verified.covered.sum()) >= result.n_coverable
                if same_points and bound is not None and best_verified.objective > 0:
                    gap = max(0.0, (best_verified.objective - bound) / best_verified.objective)
                    if gap <= max(mip_gap, 1e-9):
                        result = dataclasses.replace(
                            best_verified, gap=gap, lower_bound=bound, proven_optimal=gap <= 1e-9
                        )
                        chosen = [views[j] for j in result.selected.tolist()]
                        full_checked = True
                        break
            if not pending:
                if columns.size == len(views):
                    full_checked = True
                    break
                # a verified cover of the pool: worth proving over all views only if that fits in the time, and a
                # few times at most (each full solve may name new candidates, each costs the full reductions)
                if full_solves < MAX_FULL_SOLVES and time.perf_counter() + 1.5 * full_solve_s < deadline:
                    pool = None
                    continue
                # points that only unverified views outside the pool measure: verify their views (no solve) while
                # time and rounds allow, then solve the pool again with them, so such points are settled
                per_point = POINT_VIEWS_PER_ROUND * 2 ** min(round_index, 10)
                open_columns = open_point_views(matrix, views, per_point)[:MAX_POINT_VIEWS_PER_ROUND]
                if open_columns.size and time.perf_counter() < deadline and round_index + 1 < max_rounds:
                    verified_count += self._screen_scan_lines([views[j] for j in open_columns.tolist()])
                    for j in open_columns.tolist():
                        if time.perf_counter() >= deadline:
                            break
                        if views[j].mechanics_verified is False:
                            self._verify_mechanics(views[j], time_parameterize=not defer_trajectories)
                            verified_count += 1
                    # revived views join the problem, not the pool: they come into it verified, as the open
                    # points' views (above) or through a solve over all views
                    self._revive_in(views, provided)
                    pool = np.union1d(columns, open_columns)
                    continue
                message = (
                    f"set cover: the gap holds for a candidate pool of {columns.size} of {len(views)} views (no "
                    "more time or rounds to solve over all views again)"
                )
                LOG.warning("%s", message)
                self.warnings.append(message)
                break
            batch = list(pending)
            greedy_pending = []
            if solver_type != "greedy" and columns.size < len(views):
                # the greedy cover of the pool costs little and names views the next solve may want (a solve over
                # all views already started from its own greedy cover, and a greedy pass over all is not cheap)
                extra = solve_set_cover(sub, "greedy", uncertainties=worst[columns], time_limit_s=limit)
                set_cover_time += extra.solve_time_s
                greedy_pending = [
                    views[j] for j in columns[extra.selected].tolist() if views[j].mechanics_verified is False
                ]
            size = max(int(verification_batch or 0), 4 * len(chosen), len(pending) + len(greedy_pending))
            batch += greedy_pending
            likely = result.stats.get("likely_columns")
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
            batch += [views[j] for j in open_point_views(matrix, views, per_point)][:MAX_POINT_VIEWS_PER_ROUND]
            pending_columns = [v.coverage_column if v.coverage_column is not None else -1 for v in pending]
            if all(views[j] is v for j, v in zip(pending_columns, pending, strict=True) if 0 <= j < len(views)):
                picked_columns = np.array([j for j in pending_columns if 0 <= j < len(views)], dtype=np.int64)
            else:
                index_of = {id(v): j for j, v in enumerate(views)}
                picked_columns = np.array([index_of[id(v)] for v in pending], dtype=np.int64)
            batch += [views[j] for j in substitute_views(matrix, views, picked_columns, SUBSTITUTES_PER_VIEW)]
            if columns.size < len(views) and n_candidates >= LARGE_PROBLEM_VIEWS:
                batch += [views[j] for j in columns.tolist() if views[j].mechanics_verified is False][:POOL_VERIFY_MAX]
            batch = list(dict.fromkeys(batch))
            LOG.debug(
                "set cover round %d: %d of %d columns, %d chosen, %d pending, %d to verify (%s)",
                round_index + 1, columns.size, len(views), len(chosen), len(pending), len(batch), result.message,
            )  # fmt: skip
            # views without a free start at either end of their line are settled for the whole batch at once
            verified_count += self._screen_scan_lines(batch)
            for k, view in enumerate(batch):
                if view.mechanics_verified is not False:
                    continue
                if k >= len(pending) and time.perf_counter() >= deadline:
                    break  # the picked views first; the likely ones only while there is time
                self._verify_mechanics(view, time_parameterize=not defer_trajectories)
                verified_count += 1
                if verified_count % 25 == 0 or k == len(batch) - 1:
                    self._report(
                        "mechanics",
                        min(1.0, verified_count / (verified_count + 10)),
                        f"verified {verified_count} scan lines",
                    )
            if all(v.mechanics_verified is True and v.mechanics_valid for v in chosen):
                still = np.zeros(result.covered.size, dtype=bool)
                for view in chosen:
                    still[np.asarray(view.measurable_indices, dtype=np.int64)] = True
                if still[result.covered].all():
                    settled = result
            self._revive_in(views, provided)  # into the problem, not the pool (see above)
            verified_columns = np.flatnonzero([v.mechanics_verified is True and v.mechanics_valid for v in views])
            previous = np.zeros(0, dtype=np.int64) if pool is None else pool
            extra_columns = [result.selected, verified_columns, previous]
            if likely is not None:
                # the most likely only: without a finished reduction (tilt full, a loaded machine) the list is
                # every column, and a pool of all columns makes every round a full solve
                extra_columns.append(likely[: max(POOL_LIKELY_COLUMNS, 4 * size)])
            pool = np.unique(np.concatenate([np.asarray(c, dtype=np.int64) for c in extra_columns]))
        self.timings_s["set_cover_full_problem_checked"] = bool(full_checked)
        if chosen and (result.gap is None or result.gap > mip_gap) and solver_type != "greedy":
            # the rounds' short solves may leave a gap: spend what is left on the programme over the verified
            # views (every cover of it is executable); the gap is then the one over verified views
            left = deadline - time.perf_counter()
            if not math.isfinite(left):
                left = time_limit_s
            if left > 2.0:
                matrix, worst, durations = self._coverage_problem(views, n_points, only_verified=True)
                executable = _executable_columns(views)
                if executable.size == 0:
                    executable = np.arange(len(views))
                polished = solve_set_cover(
                    matrix[:, executable],
                    solver_type,
                    uncertainties=worst[executable],
                    durations_s=durations[executable] if solver_type == "IP_time" else None,
                    time_limit_s=max(1.0, min(time_limit_s, 0.8 * left, POLISH_IP_TIME_S)),
                    mip_gap=mip_gap,
                )
                polished = dataclasses.replace(polished, selected=executable[polished.selected])
                set_cover_time += polished.solve_time_s
                polished_views = [views[j] for j in polished.selected.tolist()]
                if (
                    polished.covered.sum() >= result.covered.sum()
                    and polished.objective <= result.objective
                    and polished.gap is not None
                    and all(v.mechanics_verified for v in polished_views)
                ):
                    result = dataclasses.replace(polished, message=polished.message + " (over verified views)")
                    chosen = polished_views
        if not chosen:
            raise PlanningError("no viewpoint is executable: every candidate failed the mechanical checks")
        self._finish_scan_trajectories(chosen)
        self.timings_s["set_cover_and_mechanics"] = time.perf_counter() - t0
        self.timings_s["set_cover"] = set_cover_time
        self.timings_s["set_cover_last_solve"] = result.solve_time_s
        self.timings_s["set_cover_rounds"] = rounds_used
        self.timings_s["scan_lines_verified"] = verified_count
        self.timings_s["mechanics_in_set_cover"] = self.timings_s.get("mechanics", 0.0) - mechanics_before
        self.last_set_cover = result
        self.parameters["solver_type"] = solver_type
        self.parameters["set_cover_mip_gap"] = float(mip_gap)
        self._report("set cover", 1.0, f"{len(chosen)} views cover {int(result.covered.sum())} points")
        return set(chosen)

    def _revive_in(self, views: list[ViewPoint], provided: set) -> np.ndarray:
        """Append to ``views`` (and to the ids in ``provided``) the dominated candidates revived for the views
        the mechanics failed (:meth:`_revive_dominated`); returns their columns. They are not added to the
        candidate pool as they come: thousands of unverified views there (most fail like their dominators)
        would be picked a few per round for many rounds."""
        revived = self._revive_dominated()
        start = len(views)
        views.extend(revived)
        provided.update(id(v) for v in revived)
        return np.arange(start, len(views), dtype=np.int64)

    def _coverage_problem(self, views: list[ViewPoint], n_points: int, only_verified: bool = False):
        """(points x views boolean CSC matrix of the measurable entries, per-view worst uncertainty, per-view
        durations in s) for the set cover. Rejected views have empty columns, shortened ones only their
        remaining points; with ``only_verified`` the unverified views are empty too.

        The matrix holds only the live entries and no values: the solvers need per-view figures only (the
        worst uncertainty is the greedy tie-break and the cost of IP_uncertainty), and at tilt full the store
        has tens of millions of entries, so a float64 copy of them (plus its temporaries) was the largest
        allocation of the whole plan.
        """
        store = self.measurability
        generation = self._generation_views
        in_store = np.array(
            [
                store is not None
                and v.coverage_column is not None
                and v.coverage_column < store.n_views
                and generation[v.coverage_column] is v
                for v in views
            ],
            dtype=bool,
        )
        if store is not None and in_store.all():
            matrix, worst, durations = self._store_problem(views, only_verified)
        elif not in_store.any():
            matrix, worst, durations = _views_problem(views, n_points, only_verified)
        else:
            # the store's columns and the revived (or foreign) views, then back in the order of ``views``
            inside, outside = np.flatnonzero(in_store), np.flatnonzero(~in_store)
            m_in, w_in, d_in = self._store_problem([views[j] for j in inside], only_verified)
            m_out, w_out, d_out = _views_problem([views[j] for j in outside], m_in.shape[0], only_verified)
            matrix = scipy.sparse.hstack([m_in, m_out], format="csc")
            worst, durations = np.concatenate([w_in, w_out]), np.concatenate([d_in, d_out])
            order = np.argsort(np.concatenate([inside, outside]), kind="stable")
            if np.any(order != np.arange(order.size)):  # revived views come last in the set cover's list
                matrix, worst, durations = matrix[:, order], worst[order], durations[order]
        matrix.sort_indices()
        return matrix, worst, durations

    def _store_problem(self, views: list[ViewPoint], only_verified: bool):
        """:meth:`_coverage_problem` of views that are all columns of the store."""
        store = self.measurability
        columns = np.asarray([v.coverage_column for v in views], dtype=np.int64)
        alive = self._entry_alive
        if only_verified:
            verified_store = np.zeros(store.n_views, dtype=bool)
            verified_store[columns[[v.mechanics_verified is not False for v in views]]] = True
            alive = alive & np.repeat(verified_store, np.diff(store.indptr))
        counts = _segment_counts(alive, store.indptr)
        indptr = np.zeros(store.n_views + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        matrix = scipy.sparse.csc_matrix(
            (np.ones(int(indptr[-1]), dtype=bool), store.point_indices[alive], indptr),
            shape=(store.n_points, store.n_views),
        )
        worst = _segment_max(store.uncertainties[alive], indptr)
        if len(columns) != store.n_views or np.any(columns != np.arange(store.n_views)):
            matrix, worst = matrix[:, columns], worst[columns]
        durations = np.where(self._duration_verified, self._durations, self._durations * self._duration_bias)[columns]
        return matrix, worst, durations

    # ----------------------------------------------------------------------------------- connection
    def connect(self, start: np.ndarray, goal: np.ndarray, planning_time_s: float = 0.2, attempts: int = 3):
        """Collision-free, time-parameterised joint trajectory from ``start`` to ``goal``, or None.

        The straight joint move when it is free (exactly time-optimal), else OMPL with a bounded number of
        attempts, each with twice the previous time budget.
        """
        from agiprobot_measurement.motion.motion_planning import collision_free_trajectory

        return collision_free_trajectory(
            start,
            goal,
            self.limits,
            self.collision,
            lambda: self.planner,  # OMPL is set up only when a straight move is blocked
            planning_time_s=planning_time_s,
            attempts=attempts,
        )

    def connect_viewpoints(self, unordered_viewpoints, min_planning_time=0.2):
        """Order the views for a fast execution and connect them (greedy by connection time from the current
        state, either scan direction, then 2-opt). Each view stores its connecting trajectory
        (``get_trajectory_to_view``). Views that cannot be connected are left out and listed in
        ``unconnected_views``. Returns the ordered list."""
        views = [v for v in unordered_viewpoints]
        t0 = time.perf_counter()
        self._finish_scan_trajectories(views)
        for view in views:
            if not view.mechanics_verified or view.get_trajectory_for_measurement() is None:
                if not self._verify_mechanics(view):
                    raise PlanningError(f"{view} has no executable measurement trajectory")
        if not views:
            return []
        starts = np.array([v.get_trajectory_for_measurement().start for v in views])
        ends = np.array([v.get_trajectory_for_measurement().end for v in views])
        order, flips = order_views(self.current_state, starts, ends, self.limits)
        ordered, unconnected = [], []
        state = self.current_state.copy()
        for k, (i, flip) in enumerate(zip(order, flips, strict=True)):
            view = views[i]
            if flip != view.reversed:
                view.reverse_trajectory_for_measurement()
            view.set_trajectory_for_measurement(
                unwrapped_towards(view.get_trajectory_for_measurement(), state, self.limits)
            )
            entry = view.get_trajectory_for_measurement().start
            self._report("connection", k / len(order), f"connecting view {k + 1} of {len(order)}")
            connection = self.connect(state, entry, planning_time_s=min_planning_time)
            if connection is None:
                LOG.warning("view %d cannot be connected from the previous state: left out", i)
                unconnected.append(view)
                continue
            view.set_trajectory_to_view(connection)
            ordered.append(view)
            state = view.get_trajectory_for_measurement().end.copy()
        self.unconnected_views = unconnected
        self.last_ordered = ordered
        self.timings_s["connection"] = time.perf_counter() - t0
        self._report("connection", 1.0, f"{len(ordered)} views connected, {len(unconnected)} left out")
        return ordered

    # ----------------------------------------------------------------------------------- plans
    def convert_viewpointlist_to_execution_plan(self, viewpointlist) -> list[PlanSegment]:
        """Two segments per view: the connection to it ('connect') and its measurement ('measure')."""
        segments = []
        for view in viewpointlist:
            connection = view.get_trajectory_to_view()
            measurement = view.get_trajectory_for_measurement()
            if connection is None or measurement is None:
                raise PlanningError(f"{view} lacks its trajectories: connect_viewpoints first")
            segments.append(PlanSegment("connect", connection))
            segments.append(PlanSegment("measure", measurement))
        return segments

    def store_execution_plan(self, file_path, execution_plan, metadata={}):  # noqa: B006 (documented default)
        """Store the plan as YAML at exactly ``file_path`` (the original's format; atomic write).
        Returns True (documented); the path written is in ``last_plan_path``."""
        info = {
            "Timestamp": time.strftime("%a %b %d %H:%M:%S %Y"),
            "robot": self.station.robot.name,
            "joint_names": list(self.limits.names),
            "planner": "agiprobot_measurement",
        }
        info.update(self.plan_metadata())
        info.update(dict(metadata))
        self.last_plan_path = plan_io.store_execution_plan(file_path, execution_plan, info)
        return True

    def plan_metadata(self) -> dict:
        """Parameters, coverage and timings of the last planning run (for the plan file)."""
        meta = {"parameters": {k: v for k, v in self.parameters.items()}, "version": agiprobot_measurement.__version__}
        if self.last_set_cover is not None and self.samples is not None:
            report = self.coverage_report()
            meta["coverage"] = {
                "samples": report.n_samples,
                "coverable_metrology": report.n_coverable_metrology,
                "coverable": report.n_coverable,
                "coverable_executable": report.n_coverable,
                "covered": report.n_covered,
                "unverified": report.n_unverified,
                "reachable_share": None if report.reachable_share is None else round(report.reachable_share, 4),
                "time_limit_hit": report.time_limit_hit,
                "views": report.n_views,
                "estimated_execution_time_s": round(report.estimated_execution_time_s, 3),
                "mean_uncertainty_mm": round(report.mean_uncertainty_mm, 6),
                "max_uncertainty_mm": round(report.max_uncertainty_mm, 6),
                "solver_gap": report.solver_gap,
            }
            stats = self.last_stream_stats
            # dominated candidates dropped at the evaluation, and those evaluated again for failed dominators
            meta["candidates"] = {
                "total": report.n_candidates,
                "measuring": report.n_valid_candidates,
                "dropped_dominated": 0 if stats is None else int(stats.dropped_views),
                "revived": int(self.revived_views),
            }
            meta["planning_time_s"] = {k: round(v, 3) for k, v in self.timings_s.items()}
        return meta

    def load_execution_plan(self, file_path, adapt_to_current_start_pose=True):
        """Load a stored plan (validated against this robot's joints and limits). With
        ``adapt_to_current_start_pose`` a planned motion from the current state to the plan's first point is
        merged into the first connection. Returns the list of segments (connect, measure, ...)."""
        plan = plan_io.load_execution_plan(file_path)
        verdict = plan_io.validate_execution_plan(plan, self.limits, list(self.limits.names))
        if not verdict.ok:
            raise PlanningError(f"{file_path}: {verdict.reason}")
        if adapt_to_current_start_pose:
            plan = self.adapt_start(plan, self.current_state)
        self.loaded_plan = plan
        return list(plan.segments)

    def adapt_start(self, plan: plan_io.ExecutionPlan, state: np.ndarray) -> plan_io.ExecutionPlan:
        """``plan`` starting at ``state`` (rad): a collision-free motion to its first point is merged into the
        first connection when it starts elsewhere. Raises PlanningError when there is no such motion."""

        def planner_fn(start, goal):
            trajectory = self.connect(np.asarray(start), np.asarray(goal), planning_time_s=1.0)
            if trajectory is None:
                raise PlanningError("no collision-free motion from the current state to the plan's start")
            return trajectory

        return plan_io.adapt_to_current_start_pose(plan, state, planner_fn)

    def set_collision_part(self, part: PlanPart) -> None:
        """Put a stored plan's part into the collision world (as placed in the plan; downward faces kept), so
        that motions planned to the plan's start avoid it."""
        loaded = load_part(part.mesh_file, units=part.units, transform=part.file_units_placement, remove_downside=False)
        self.collision.set_part(loaded.mesh, name="part", scale_to_m=1e-3)

    def postprocess_trajectory(self, trajectory) -> bool:
        """Whether a trajectory meets the joint limits (positions, velocities, accelerations) and its time is
        strictly increasing (the documented check)."""
        if isinstance(trajectory, JointTrajectory):
            pass
        elif isinstance(trajectory, PlanSegment):
            trajectory = trajectory.trajectory
        elif isinstance(trajectory, dict):
            trajectory = JointTrajectory.from_dict(trajectory.get("joint_trajectory", trajectory))
        elif hasattr(trajectory, "joint_trajectory"):
            trajectory = JointTrajectory.from_msg(trajectory.joint_trajectory)
        else:
            trajectory = JointTrajectory.from_msg(trajectory)
        verdict = check_trajectory(trajectory, self.limits)
        if not verdict.ok:
            LOG.warning("trajectory rejected: %s", verdict.reason)
        return verdict.ok

    # ------------------------------------------------------------------------------------ execution
    def execute(self, execution_list, surface_points=None, executor=None, on_segment=None):
        """Execute segments, ``moveit_msgs/RobotTrajectory``-shaped items or ViewPoints one after the other.

        ``executor``: ``None``/``"auto"`` drives the running station's controller when this is a ROS process
        (``rospy.init_node`` called) and a controller answers, as the original drove the robot through MoveIt,
        else an instant simulated robot; ``"simulated"`` always the instant one; ``"station"`` the station or an
        :class:`ExecutionError`; or any
        :class:`~agiprobot_measurement.planning.execution.SegmentExecutor`. On the station, with
        ``surface_points`` (the sampled points, mm) and views given, the points each view measures are published
        on ``/currently_measured_points`` while it runs (as the original did). A failing segment stops execution
        and raises :class:`ExecutionError`; a cancel raises
        :class:`~agiprobot_measurement.planning.execution.ExecutionCancelled`. ``on_segment(feedback)`` hears of
        each segment before it starts."""
        outcome = self.execute_with_outcome(execution_list, executor, on_segment, surface_points)
        if outcome.status == "cancelled":
            raise ExecutionCancelled(outcome.describe())
        if not outcome.ok:
            raise ExecutionError(outcome.error)
        return True

    def execute_with_outcome(self, execution_list, executor=None, on_segment=None, surface_points=None):
        """Like :meth:`execute`, but a failure or cancel is returned as the :class:`ExecutionOutcome` (how many
        segments ran, why it stopped) instead of raised."""
        triples = segment_triples(execution_list)  # malformed input is refused before anything moves
        executor = self._executor(executor, surface_points)
        outcome = execute_segments(triples, executor, on_segment)
        self.current_state = executor.current_state()
        return outcome

    def _executor(self, choice, surface_points):
        if choice is not None and not isinstance(choice, str):
            return choice
        choice = "auto" if choice is None else choice
        if choice not in EXECUTOR_CHOICES:
            raise PlanningError(f"executor must be one of {EXECUTOR_CHOICES} or a SegmentExecutor, got {choice!r}")
        if choice != "simulated":
            params = self.parameters
            part = None
            if "part_file" in params and "part_transform_mm" in params:
                placement = np.asarray(params["part_transform_mm"], dtype=float).reshape(4, 4)
                part = PlanPart(str(params["part_file"]), str(params.get("units", "mm")), placement)
            station = ros_station_executor(list(self.limits.names), surface_points, part)
            if station is not None:
                return station
            if choice == "station":
                raise ExecutionError("executor='station': this is not a ROS process or no robot controller answers")
        return SimulatedExecutor(self.current_state, self.limits)

    # ------------------------------------------------------------------------------------ reports
    def coverable_mask(self) -> np.ndarray:
        """(n_samples,) bool: the samples some view verified executable measures, or the plan covers."""
        if self.samples is None:
            raise PlanningError("nothing planned yet")
        covered = np.isfinite(self.point_uncertainties())
        return coverable_mask(self.last_viewpoints, len(self.samples), covered)

    def metrology_coverable_mask(self) -> np.ndarray:
        """(n_samples,) bool: the samples some candidate view with a reachable anchor measures (the sensor model
        says so), whether or not its scan line can be driven."""
        if self.samples is None:
            raise PlanningError("nothing planned yet")
        n = len(self.samples)
        mask = coverable_mask(self.last_viewpoints, n, np.isfinite(self.point_uncertainties()), verified_only=False)
        if self._metrology_coverable is not None and len(self._metrology_coverable) == n:
            mask |= self._metrology_coverable
        return mask

    def coverage_report(self, views: Iterable[ViewPoint] | None = None) -> CoverageReport:
        """Coverage, view count, execution time and uncertainties of the chosen (or given) views."""
        if self.samples is None:
            raise PlanningError("nothing planned yet")
        chosen = list(views) if views is not None else (self.last_ordered or [])
        n = len(self.samples)
        best_u = point_uncertainties(chosen, n)
        covered = np.isfinite(best_u)
        coverable = coverable_mask(self.last_viewpoints, n, covered)
        metrology = coverable_mask(self.last_viewpoints, n, covered, verified_only=False)
        if self._metrology_coverable is not None and len(self._metrology_coverable) == n:
            metrology |= self._metrology_coverable
        # points that only views never verified measure: neither known executable nor known not to be
        open_views = [v for v in self.last_viewpoints if v.mechanics_valid and not v.mechanics_verified]
        unverified = coverable_mask(open_views, n, None, verified_only=False) & ~coverable
        measure = sum(v.get_trajectory_for_measurement().duration for v in chosen if v.get_trajectory_for_measurement())
        connect = sum(v.get_trajectory_to_view().duration for v in chosen if v.get_trajectory_to_view())
        result = self.last_set_cover
        return CoverageReport(
            n_samples=n,
            n_coverable=int(coverable.sum()),
            n_covered=int(covered.sum()),
            n_views=len(chosen),
            n_candidates=0 if self.candidates is None else len(self.candidates.poses),
            n_valid_candidates=len(self.last_viewpoints),
            estimated_execution_time_s=float(measure + connect),
            measurement_time_s=float(measure),
            connection_time_s=float(connect),
            mean_uncertainty_mm=float(best_u[covered].mean()) if covered.any() else float("nan"),
            max_uncertainty_mm=float(best_u[covered].max()) if covered.any() else float("nan"),
            solver=self.parameters.get("solver_type", ""),
            solver_gap=None if result is None else result.gap,
            timings_s=dict(self.timings_s),
            unconnected_views=len(self.unconnected_views),
            n_coverable_metrology=int(metrology.sum()),
            n_unverified=int(unverified.sum()),
            reachable_share=self.reachable_share,
            time_limit_hit=bool(self.time_limit_hit),
            tilt_mode=str(self.parameters.get("viewpoint_tilt_mode", "")),
            warnings=list(self.warnings),
        )

    def point_uncertainties(self, views: Iterable[ViewPoint] | None = None) -> np.ndarray:
        """Best predicted uncertainty (mm) per sample over the given views (default: the plan); inf = unmeasured."""
        chosen = list(views) if views is not None else (self.last_ordered or [])
        return point_uncertainties(chosen, len(self.samples))

    def scan_lines_mm(self, views: Iterable[ViewPoint] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """(start, end) positions (mm) of the laser_emitter_frame's scan lines of the given views (default: plan)."""
        chosen = list(views) if views is not None else (self.last_ordered or [])
        lines = []
        for view in chosen:
            trajectory = view.get_trajectory_for_measurement()
            if trajectory is not None:
                ends = self.kinematics.fk_batch(np.vstack([trajectory.start, trajectory.end]))[:, :3, 3] * 1000.0
                lines.append((ends[0], ends[1]))
        return lines

    # ------------------------------------------------------------------------------------ everything
    @classmethod
    def for_request(
        cls,
        request: PlanRequest,
        station: Station | None = None,
        progress: ProgressCallback | None = None,
        start_state: np.ndarray | str = "home",
        work_budget: WorkBudget | None = None,
    ) -> TrajectoryManager:
        """A manager with the request's scan speed and seed (``request`` validated already) and ``work_budget``
        (default: :class:`~agiprobot_measurement.planning.request.WorkBudget`'s)."""
        return cls(
            station,
            scan_speed_mm_s=request.scan_speed_mm_s,
            progress=progress,
            seed=request.seed,
            start_state=start_state,
            work_budget=work_budget,
            workers=request.workers,
            scheduler=request.scheduler,
            max_memory_bytes=request.max_memory_gb * 1e9 if request.max_memory_gb else None,
        )

    def plan_request(self, request: PlanRequest) -> list[ViewPoint]:
        """Load the request's part and run the whole pipeline with its settings (``request`` validated with
        :meth:`PlanRequest.validate`; the manager made by :meth:`for_request`). Returns the ordered views."""
        self._report("sampling", 0.0, f"loading {request.part_file}")
        self.load_target_mesh(
            request.part_file,
            transform=request.part_transform_mm,
            add_wbk_mirrors=request.add_wbk_mirrors,
            units=request.units,
            placement=request.placement,
            tessellation_tolerance_mm=request.tessellation_tolerance_mm,
        )
        return self.plan(
            request.sampling_density,
            request.uncertainty_threshold_mm,
            request.orientations_around_boresight,
            request.viewpoint_tilt_mode,
            request.solver_type,
            set_cover_time_limit_s=request.set_cover_time_limit_s,
            min_planning_time=request.min_planning_time_s,
            minimum_trajectory_length=request.minimum_trajectory_length_mm,
            trajectory_sample_step=request.trajectory_sample_step_mm,
            minimum_required_overmeasure=request.minimum_required_overmeasure_mm,
            joint_jump_threshold=request.joint_jump_threshold_rad,
            time_limit_s=request.time_limit_s,
            mip_gap=request.set_cover_mip_gap,
            min_reachable_share=request.min_reachable_share,
        )

    def plan(
        self,
        sampling_density=0.03,
        uncertainty_threshold=0.1,
        orientations_around_boresight=12,
        viewpoint_tilt_mode="none",
        solver_type="IP_basic",
        set_cover_time_limit_s=60.0,
        min_planning_time=0.2,
        time_limit_s=300.0,
        mip_gap=0.02,
        **generation,
    ) -> list[ViewPoint]:
        """The whole pipeline on the loaded part: generate, solve the set cover, connect. Returns the ordered
        views (also in ``last_ordered``). The defaults are :class:`PlanRequest`'s.

        ``time_limit_s`` bounds the whole plan: the set cover / verification loop ends in time for the connection
        and the best verified plan is returned with its optimality gap (``time_limit_hit`` says whether the limit
        cut it short). ``viewpoint_tilt_mode='auto'`` plans with tilt none first and, when the cover is large or
        leaves metrologically coverable points uncovered and time is left, with tilt full; the plan with fewer
        views at the same coverage (or clearly more coverage) is kept and the choice is in
        ``parameters['tilt_choice']``.
        """
        check_choice(solver_type, SOLVER_TYPES, "solver_type")
        check_choice(viewpoint_tilt_mode, REQUEST_TILT_MODES, "viewpoint_tilt_mode")
        limit = check_positive(time_limit_s, "time_limit_s", "time_limit_s (s)")
        t0 = time.perf_counter()
        deadline = t0 + limit
        settings = dict(
            sampling_density=sampling_density,
            uncertainty_threshold=uncertainty_threshold,
            orientations_around_boresight=orientations_around_boresight,
            solver_type=solver_type,
            set_cover_time_limit_s=set_cover_time_limit_s,
            min_planning_time=min_planning_time,
            mip_gap=mip_gap,
            generation=generation,
        )
        if viewpoint_tilt_mode != "auto":
            ordered = self._plan_once(viewpoint_tilt_mode, deadline, **settings)
        else:
            ordered = self._plan_auto(t0, deadline, settings)
        self.timings_s["total"] = time.perf_counter() - t0
        self.parameters["time_limit_s"] = limit
        return ordered

    def _plan_once(
        self,
        tilt_mode,
        deadline,
        *,
        sampling_density,
        uncertainty_threshold,
        orientations_around_boresight,
        solver_type,
        set_cover_time_limit_s,
        min_planning_time,
        mip_gap,
        generation,
    ) -> list[ViewPoint]:
        _, views = self.generate_samples_and_viewpoints(
            sampling_density, uncertainty_threshold, orientations_around_boresight, tilt_mode, **generation
        )
        # the connection needs its share of the time: about a second per view in the worst case, bounded
        left = deadline - time.perf_counter()
        reserve = min(0.25 * left, max(0.1 * left, 20.0))
        chosen = self.solve_scp(
            views, solver_type, time_limit_s=set_cover_time_limit_s, mip_gap=mip_gap, deadline_s=deadline - reserve
        )
        return self.connect_viewpoints(chosen, min_planning_time=min_planning_time)

    def _snapshot(self) -> dict:
        state = dict(self.__dict__)
        state["timings_s"] = dict(self.timings_s)
        state["parameters"] = dict(self.parameters)
        state["warnings"] = list(self.warnings)
        return state

    def _plan_auto(self, t0: float, deadline: float, settings: dict) -> list[ViewPoint]:
        """Tilt none, then (when its cover is large or short and time is left) tilt full, and tilt full's
        verified views solved again for the points tilt none covered. Among the plans that cover at least what
        tilt none covers (within :data:`AUTO_SAME_COVERAGE` of the samples), the one with the fewest views wins,
        then the one covering more; the choice and the figures of every plan are in ``parameters['tilt_choice']``.
        Tilt full covering more points with more views is reported, not chosen: the same coverage with fewer
        views is what tilts are tried for."""
        base_warnings = list(self.warnings)
        ordered = self._plan_once("none", deadline, **settings)
        first = self.coverage_report()
        first_state = self._snapshot()
        first_points = np.isfinite(point_uncertainties(ordered, len(self.samples)))
        short = first.n_covered < AUTO_COVERAGE_SHARE * first.n_coverable_metrology
        large = first.n_views > AUTO_VIEWS
        left = deadline - time.perf_counter()
        if not (short or large):
            choice = f"none (cover of {first.n_views} views, {first.n_covered} covered: tilts not needed)"
        elif left < AUTO_MIN_TIME_SHARE * (deadline - t0):
            choice = f"none (no time left to try tilt full: {left:.0f} s)"
        else:
            self.warnings = list(base_warnings)
            self.timings_s = {}
            try:
                self._plan_once("full", deadline, **settings)
                second = self.coverage_report()
            except PlanningError as exc:
                second, reason = None, str(exc)
            tolerance = AUTO_SAME_COVERAGE * first.n_samples
            enough = second is not None and second.n_covered >= first.n_covered - tolerance
            third = None
            if second is not None and not (enough and second.n_views < first.n_views):
                # tilt full's cover may buy extra points with extra views: its verified views, solved for the
                # points tilt none covered, give the same coverage with (possibly) fewer views
                full_timings = dict(self.timings_s)
                third = self._cover_points_with_verified(first_points, settings, deadline)
                if third is not None:
                    self.timings_s = {**full_timings, **self.timings_s}
            third_enough = third is not None and third.n_covered >= first.n_covered - tolerance
            full_detail = (
                f"tilt full: {second.n_views} views, {second.n_covered} covered"
                if second is not None
                else f"tilt full failed: {reason}"
            )
            if enough and second.n_views < first.n_views:
                ordered = list(self.last_ordered)
                choice = (
                    f"full ({second.n_views} views, {second.n_covered} covered; tilt none: {first.n_views} views, "
                    f"{first.n_covered} covered)"
                )
                self.timings_s["tilt_none_total"] = first.timings_s.get("total", 0.0)
            elif third_enough and third.n_views < first.n_views:
                ordered = list(self.last_ordered)
                choice = (
                    f"full, for tilt none's points ({third.n_views} views, {third.n_covered} covered; tilt none: "
                    f"{first.n_views} views, {first.n_covered} covered; {full_detail})"
                )
                self.timings_s["tilt_none_total"] = first.timings_s.get("total", 0.0)
            else:
                restricted = (
                    f"; for tilt none's points: {third.n_views} views, {third.n_covered} covered"
                    if third is not None
                    else ""
                )
                choice = f"none ({first.n_views} views, {first.n_covered} covered; {full_detail}{restricted})"
                full_time = time.perf_counter() - t0
                self.__dict__.update(first_state)
                self.timings_s["tilt_full_total"] = full_time
        self.parameters["viewpoint_tilt_mode_requested"] = "auto"
        self.parameters["tilt_choice"] = choice
        LOG.info("tilt auto: %s", choice)
        return ordered

    def _cover_points_with_verified(self, points: np.ndarray, settings: dict, deadline: float) -> CoverageReport | None:
        """Cover the points of the mask ``points`` with the current generation's verified executable views
        (no new verification: every cover is executable), connect the cover and report it; None when there is
        no time, no such view or the samples differ."""
        views = list(self.last_viewpoints or [])
        left = deadline - time.perf_counter()
        if not views or points.size != len(self.samples) or not points.any() or left < 5.0:
            return None
        started = time.perf_counter()
        matrix, worst, durations = self._coverage_problem(views, len(self.samples), only_verified=True)
        executable = _executable_columns(views)
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
        self.last_set_cover = dataclasses.replace(result, selected=executable[result.selected])
        self.timings_s["set_cover_restricted"] = time.perf_counter() - started
        self._finish_scan_trajectories(chosen)
        self.connect_viewpoints(chosen, min_planning_time=settings["min_planning_time"])
        return self.coverage_report()
