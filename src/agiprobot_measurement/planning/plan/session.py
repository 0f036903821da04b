"""A measurement session: the current plan of a station and everything done with it (the trajectory_manager
node's state, without ROS).

:class:`MeasurementSession` plans from a :class:`~agiprobot_measurement.planning.request.PlanRequest`, loads and
stores plan files, adapts a plan's start to the robot's current state, executes it through any
:class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor` and compares what was measured with what was
predicted. Relative part paths are resolved against the package root. Plan files and coverage figures follow
the package's one file policy (:class:`~agiprobot_measurement.common.files.FileRoot`): names resolve under the
plan directory, absolute names only inside it or the allowed directories, ``..`` and ``~`` are refused, and an
existing file is replaced only when the request asks to overwrite (a figure gets a new version name instead).
A plan file is installed as the session's plan only once it passed every check, so a refused request keeps the
current plan. Points are mm, joint values rad.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.files import FileRoot, PathPolicyError
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.connection import ConnectionPlanner
from agiprobot_measurement.planning.plan import plan_io
from agiprobot_measurement.planning.plan.execution import (
    ExecutionOutcome,
    LoadedPlan,
    PlanPart,
    SegmentExecutor,
    SegmentFeedback,
    adapt_plan_start,
    execute_segments,
    load_plan,
    plan_segments,
    starts_at,
)
from agiprobot_measurement.planning.report.coverage import MeasuredCoverage, measured_coverage
from agiprobot_measurement.planning.report.coverage_figure import plot_coverage
from agiprobot_measurement.planning.report.report import CoverageReport
from agiprobot_measurement.planning.request import PlanRequest, WorkBudget
from agiprobot_measurement.planning.trajectory_manager import ProgressCallback, TrajectoryManager

__all__ = ["GoalError", "MeasurementSession", "PlanSummary", "PlanningOutcome"]


class GoalError(InputError):
    """A goal or request the session cannot serve (no plan yet, a missing directory...); the message says why."""


@dataclass
class PlanningOutcome:
    """A finished planning run: its report and the plan file written ('' if not stored)."""

    report: CoverageReport
    plan_file: str
    tilt_choice: str = ""


@dataclass(frozen=True)
class PlanSummary:
    """What a coverage report says about the session's plan: its ``source`` (file or '(planned, not stored)'),
    its own view count and duration, and ``report``, the planning run's coverage report only when the plan is that
    run's (None for a plan loaded from a file: no prediction belongs to it)."""

    source: str
    number_of_views: int
    estimated_execution_time_s: float
    measured_coverage: float
    report: CoverageReport | None

    @property
    def message(self) -> str:
        if self.report is not None:
            return f"plan: {self.source}"
        return f"plan: {self.source} (loaded: no coverage prediction belongs to it; plan it to get one)"

    def as_dict(self) -> dict:
        if self.report is not None:
            data = self.report.as_dict()
        else:
            data = {"number_of_views": self.number_of_views, "predicted_coverage": None}
        data.update(
            plan=self.source,
            estimated_execution_time_s=self.estimated_execution_time_s,
            measured_coverage=self.measured_coverage,
        )
        return data


class MeasurementSession:
    """The station's current plan and what the trajectory_manager does with it.

    ``defaults``: the ``planning`` section of ``config/trajectory_manager.yaml`` (what empty request fields
    take); ``plan_directory``: the root of plan files and figures (relative to the package root unless absolute;
    created on first use); ``allowed_directories``: where absolute plan and figure names may also point;
    ``measured_radius_mm``: a sample counts as measured when a measured point lies this close;
    ``work_budget``: the most work one planning run may cause.
    """

    def __init__(
        self,
        station,
        defaults: Mapping,
        plan_directory: str | Path = "plans",
        measured_radius_mm: float = 1.0,
        package_root: Path = PACKAGE_ROOT,
        allowed_directories: Sequence[str | Path] = (),
        work_budget: WorkBudget | None = None,
    ):
        self.station = station
        self.joint_names = list(station.limits.names)
        self.defaults = dict(defaults)
        self.package_root = Path(package_root)
        self.plan_directory = self.resolve(plan_directory)
        extra = tuple(self.resolve(d) for d in allowed_directories)
        self.plan_files = FileRoot(self.plan_directory, extra, purpose="plan file")
        self.figure_files = FileRoot(self.plan_directory, extra, purpose="coverage figure")
        self.work_budget = work_budget if work_budget is not None else WorkBudget()
        self.measured_radius_mm = float(measured_radius_mm)
        self.lock = threading.Lock()
        self.manager: TrajectoryManager | None = None
        self.views: list[ViewPoint] = []
        self.plan: plan_io.ExecutionPlan | None = None
        self.plan_source = ""
        self.part: PlanPart | None = None
        self.samples_mm: np.ndarray | None = None
        self.coverable_mask: np.ndarray | None = None
        self.predicted_mask: np.ndarray | None = None
        self.last_measured_coverage = -1.0
        self.planned_plan: plan_io.ExecutionPlan | None = None  # the plan of the planning run (self.manager)

    # ------------------------------------------------------------------------------------ paths
    def resolve(self, path_text: str | Path) -> Path:
        """A path relative to the package root unless absolute (configuration, not client input)."""
        path = Path(path_text).expanduser()
        return path if path.is_absolute() else self.package_root / path

    def plan_path(self, name: str, overwrite: bool = False) -> Path:
        """Where to write plan ``name`` (``.yaml`` appended unless it ends in .yaml/.yml), confined to the plan
        directory (created on first use) and the allowed directories; an existing file is refused unless
        ``overwrite``. Raises :class:`~agiprobot_measurement.common.files.PathPolicyError` or :class:`GoalError`."""
        if not str(name or "").strip():
            raise GoalError("plan_file is empty")
        path = self.plan_files.for_writing(plan_io.plan_path(str(name).strip()), overwrite=overwrite)
        if not path.parent.is_dir():
            if path.parent == self.plan_directory:
                path.parent.mkdir(parents=True, exist_ok=True)
            else:
                raise GoalError(f"plan directory does not exist: {path.parent}")
        return path

    def plan_file_to_read(self, name: str) -> Path:
        """The stored plan ``name`` names: the same file :meth:`store` writes for that name (``name`` or
        ``name.yaml``), confined like writing; ``FileNotFoundError`` / ``PathPolicyError`` otherwise."""
        text = str(name or "").strip()
        if not text:
            raise GoalError("plan_file is empty")
        suffixed = plan_io.plan_path(text)
        try:
            return self.plan_files.for_reading(suffixed)
        except FileNotFoundError:
            if str(suffixed) == text:
                raise
            return self.plan_files.for_reading(text)

    # ------------------------------------------------------------------------------------ planning
    def request(self, **fields) -> PlanRequest:
        """A validated request: ``fields`` (empty / zero = the default) over the configured defaults."""
        return PlanRequest.from_defaults(self.defaults, **fields).validate(base_dir=self.package_root)

    def plan_measurement(
        self, request: PlanRequest, start_state: np.ndarray, progress: ProgressCallback | None = None
    ) -> PlanningOutcome:
        """Plan ``request`` (validated) from ``start_state``; store it when it names a plan file; make it the
        session's plan."""
        # a plan file that cannot be written is refused before minutes of planning, and checked again when written
        if request.plan_file:
            self.plan_path(request.plan_file, overwrite=request.overwrite)
        manager = TrajectoryManager.for_request(
            request, self.station, progress=progress, start_state=start_state, work_budget=self.work_budget
        )
        try:
            ordered = manager.plan_request(request)
        finally:
            manager.close()  # ends the evaluation's local Dask cluster, if the request asked for one
        segments = manager.convert_viewpointlist_to_execution_plan(ordered)
        plan = plan_io.ExecutionPlan(manager.plan_metadata(), segments)
        written = ""
        if request.plan_file:
            manager.store_execution_plan(str(self.plan_path(request.plan_file, request.overwrite)), segments)
            written = str(manager.last_plan_path)
        report = manager.coverage_report()
        with self.lock:
            self.manager, self.views, self.plan, self.planned_plan = manager, ordered, plan, plan
            self.plan_source = written or "(planned, not stored)"
            self.part = PlanPart(
                request.part_file,
                request.units,
                manager.part.transform @ np.diag([manager.part.scale_to_mm] * 3 + [1.0]),
            )
            self.samples_mm = manager.samples.points
            self.predicted_mask = np.isfinite(manager.point_uncertainties())
            self.coverable_mask = manager.coverable_mask()
            self.last_measured_coverage = -1.0
        return PlanningOutcome(report, written, str(manager.parameters.get("tilt_choice", "")))

    # ------------------------------------------------------------------------------------ plan files
    def read(self, name: str) -> LoadedPlan:
        """Read and check a stored plan (see :meth:`plan_file_to_read`) without making it the session's plan."""
        try:
            path = self.plan_file_to_read(name)
        except FileNotFoundError as exc:
            raise plan_io.PlanFileNotFoundError(str(exc)) from exc
        return load_plan(path, self.station.limits, self.joint_names)

    def adopt(self, loaded: LoadedPlan) -> LoadedPlan:
        """Make a plan from :meth:`read` the session's plan; its predicted coverage is unknown."""
        with self.lock:
            self.plan, self.plan_source, self.views, self.part = loaded.plan, str(loaded.path), [], loaded.part
            self.samples_mm = self.predicted_mask = self.coverable_mask = None
            self.last_measured_coverage = -1.0
        return loaded

    def load(self, name: str) -> LoadedPlan:
        """Read a stored plan and make it the session's plan (a refused one leaves the current plan)."""
        return self.adopt(self.read(name))

    def store(self, name: str, overwrite: bool = False) -> Path:
        """Write the session's plan to ``name`` (see :meth:`plan_path`); returns the path written."""
        if self.plan is None:
            raise GoalError("no plan to store: plan or load one first")
        return plan_io.store_execution_plan(self.plan_path(name, overwrite), self.plan)

    # ------------------------------------------------------------------------------------ execution
    def connection_planner(self, state: np.ndarray, part: PlanPart | None = None) -> ConnectionPlanner:
        """The planner of motions from ``state``: the planning run's (unless ``part`` names another plan's part),
        else one with the plan's part in the collision world."""
        if self.manager is not None and part is None:
            return self.manager.connection
        return ConnectionPlanner.for_station(self.station, part if part is not None else self.part)

    def prepared_plan(self, state: np.ndarray, candidate: LoadedPlan | None = None) -> plan_io.ExecutionPlan:
        """The session's plan (or ``candidate``, a plan read but not adopted yet) starting at the robot's current
        ``state`` (rad)."""
        plan = candidate.plan if candidate is not None else self.plan
        if plan is None:
            raise GoalError("no plan: plan one, load one, or give plan_file")
        if starts_at(plan, state):
            return plan
        planner = self.connection_planner(state, candidate.part if candidate is not None else None)
        return adapt_plan_start(plan, state, planner.connect)

    def execute(
        self,
        plan: plan_io.ExecutionPlan,
        executor: SegmentExecutor,
        on_segment: Callable[[SegmentFeedback], None] | None = None,
    ) -> ExecutionOutcome:
        """Run ``plan`` (from :meth:`prepared_plan`) through ``executor``; measurement segments name their view
        when the plan is the session's own planning run."""
        return execute_segments(plan_segments(plan, self.views), executor, on_segment)

    def measured(self, measured_points_mm: np.ndarray) -> MeasuredCoverage | None:
        """Compare what was measured with the prediction (None for a loaded plan: no samples to compare)."""
        if self.samples_mm is None:
            return None
        result = measured_coverage(
            self.samples_mm, measured_points_mm, self.measured_radius_mm, self.coverable_mask, self.predicted_mask
        )
        self.last_measured_coverage = result.measured_coverage
        return result

    # ------------------------------------------------------------------------------------ reports
    def _is_planned(self, plan: plan_io.ExecutionPlan) -> bool:
        """Whether ``plan`` is the planning run's plan: that plan, or one loaded from a file whose measurement
        segments are the run's (a plan stored and loaded again; its connections may differ by a start adaptation)."""
        planned = self.planned_plan
        if plan is planned:
            return True
        if planned is None:
            return False
        ours, theirs = ([s for s in p.segments if s.kind == plan_io.MEASURE] for p in (planned, plan))
        return len(ours) == len(theirs) and all(
            a.trajectory.positions.shape == b.trajectory.positions.shape
            and np.allclose(a.trajectory.positions, b.trajectory.positions, rtol=0.0, atol=1e-9)
            for a, b in zip(ours, theirs, strict=True)
        )

    def summary(self) -> PlanSummary:
        """The report of the session's plan: the planning run's coverage report while the plan is that run's,
        else the loaded plan's own view count and duration (the last planning run's numbers describe another
        plan). :class:`GoalError` without a plan."""
        with self.lock:
            plan, source, manager, measured = self.plan, self.plan_source, self.manager, self.last_measured_coverage
            own = manager is not None and plan is not None and self._is_planned(plan)
        if plan is None:
            raise GoalError("nothing planned or loaded yet")
        views = sum(1 for segment in plan.segments if segment.kind == plan_io.MEASURE)
        report = manager.coverage_report() if own else None
        if report is not None:
            return PlanSummary(source, report.n_views, report.estimated_execution_time_s, measured, report)
        return PlanSummary(source, views, float(plan.duration), measured, None)

    def figure_path(self, name: str, overwrite: bool = False) -> Path:
        """Where the figure ``name`` (.png) goes under the file policy; an existing file is kept and the figure
        gets the next free version name (``name_2.png``, ...) unless ``overwrite``."""
        path = self.figure_files.resolve(name)
        if path.suffix.lower() != ".png":
            raise GoalError(f"the figure must be a .png file, got {path.name}")
        if not path.parent.is_dir():
            if path.parent == self.plan_directory:
                path.parent.mkdir(parents=True, exist_ok=True)
            else:
                raise GoalError(f"directory does not exist: {path.parent}")
        if path.is_dir():
            raise PathPolicyError(f"coverage figure: {path} is a directory")
        version = 1
        candidate = path
        while candidate.exists() and not overwrite:
            version += 1
            candidate = path.with_name(f"{path.stem}_{version}{path.suffix}")
        return self.figure_files.for_writing(candidate, overwrite=overwrite)

    def write_figure(self, name: str, overwrite: bool = False) -> Path:
        """The coverage picture of the planning run as a PNG (see :meth:`figure_path`); returns the path written."""
        manager = self.manager
        if manager is None:
            raise GoalError("nothing planned yet")
        if self.plan is None or not self._is_planned(self.plan):
            raise GoalError(
                f"the plan {self.plan_source} was loaded from a file: the figure shows a planning run's prediction, "
                "plan it to get one"
            )
        path = self.figure_path(name, overwrite)
        measured = self.last_measured_coverage
        report = manager.coverage_report()
        title = f"{report.n_views} views, predicted coverage {100 * report.coverage_of_coverable:.1f} %" + (
            f", measured {100 * measured:.1f} %" if measured >= 0 else ""
        )
        return plot_coverage(
            path,
            manager.samples.points,
            manager.point_uncertainties(),
            manager.scan_lines_mm(self.views),
            manager.sensor_model.get_min_uncertainty(),
            manager.sensor_model.get_max_uncertainty(),
            title=title,
            mesh=manager.part.mesh,
            metrology_coverable=manager.metrology_coverable_mask(),
            executable_coverable=manager.coverable_mask(),
        )
