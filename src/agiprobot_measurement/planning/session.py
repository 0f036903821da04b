"""A measurement session: the current plan of a station and everything done with it (the trajectory_manager
node's state, without ROS).

:class:`MeasurementSession` plans from a :class:`~agiprobot_measurement.planning.request.PlanRequest`, loads and
stores plan files, adapts a plan's start to the robot's current state, executes it through any
:class:`~agiprobot_measurement.planning.execution.SegmentExecutor` and compares what was measured with what was
predicted. Relative part paths are resolved against the package root, relative plan names against the plan
directory. Points are mm, joint values rad.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning import plan_io
from agiprobot_measurement.planning.coverage import MeasuredCoverage, measured_coverage
from agiprobot_measurement.planning.coverage_figure import plot_coverage
from agiprobot_measurement.planning.execution import (
    ExecutionOutcome,
    LoadedPlan,
    PlanPart,
    SegmentExecutor,
    SegmentFeedback,
    adapt_plan_start,
    execute_segments,
    load_plan,
    plan_segments,
)
from agiprobot_measurement.planning.report import CoverageReport
from agiprobot_measurement.planning.request import PlanRequest
from agiprobot_measurement.planning.trajectory_manager import ProgressCallback, TrajectoryManager
from agiprobot_measurement.planning.viewpoint import ViewPoint

__all__ = ["GoalError", "MeasurementSession", "PlanningOutcome"]


class GoalError(InputError):
    """A goal or request the session cannot serve (no plan yet, a missing directory...); the message says why."""


@dataclass
class PlanningOutcome:
    """A finished planning run: its report and the plan file written ('' if not stored)."""

    report: CoverageReport
    plan_file: str


class MeasurementSession:
    """The station's current plan and what the trajectory_manager does with it.

    ``defaults``: the ``planning`` section of ``config/trajectory_manager.yaml`` (what empty request fields
    take); ``plan_directory``: where plans named without a directory go; ``measured_radius_mm``: a sample counts
    as measured when a measured point lies this close.
    """

    def __init__(
        self,
        station,
        defaults: Mapping,
        plan_directory: str | Path = "plans",
        measured_radius_mm: float = 1.0,
        package_root: Path = PACKAGE_ROOT,
    ):
        self.station = station
        self.joint_names = list(station.limits.names)
        self.defaults = dict(defaults)
        self.package_root = Path(package_root)
        self.plan_directory = self.resolve(plan_directory)
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

    # ------------------------------------------------------------------------------------ paths
    def resolve(self, path_text: str | Path) -> Path:
        """A path relative to the package root unless absolute."""
        path = Path(path_text).expanduser()
        return path if path.is_absolute() else self.package_root / path

    def plan_path(self, name: str) -> Path:
        """Where to write plan ``name``: relative names go to the plan directory (created on first use)."""
        path = Path(name).expanduser()
        if not path.is_absolute():
            path = self.plan_directory / path
        if not path.parent.is_dir():
            if path.parent == self.plan_directory:
                path.parent.mkdir(parents=True, exist_ok=True)
            else:
                raise GoalError(f"plan directory does not exist: {path.parent}")
        return path

    # ------------------------------------------------------------------------------------ planning
    def request(self, **fields) -> PlanRequest:
        """A validated request: ``fields`` (empty / zero = the default) over the configured defaults."""
        return PlanRequest.from_defaults(self.defaults, **fields).validate(base_dir=self.package_root)

    def plan_measurement(
        self, request: PlanRequest, start_state: np.ndarray, progress: ProgressCallback | None = None
    ) -> PlanningOutcome:
        """Plan ``request`` (validated) from ``start_state``; store it when it names a plan file; make it the
        session's plan."""
        manager = TrajectoryManager.for_request(request, self.station, progress=progress, start_state=start_state)
        ordered = manager.plan_request(request)
        segments = manager.convert_viewpointlist_to_execution_plan(ordered)
        plan = plan_io.ExecutionPlan(manager.plan_metadata(), segments)
        written = ""
        if request.plan_file:
            manager.store_execution_plan(str(self.plan_path(request.plan_file)), segments)
            written = str(manager.last_plan_path)
        report = manager.coverage_report()
        with self.lock:
            self.manager, self.views, self.plan = manager, ordered, plan
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
        return PlanningOutcome(report, written)

    # ------------------------------------------------------------------------------------ plan files
    def load(self, name: str) -> LoadedPlan:
        """Read a stored plan (relative to the package root, else to the plan directory) and make it the
        session's plan; its predicted coverage is unknown."""
        path = self.resolve(name) if not Path(name).is_absolute() else Path(name)
        if not path.exists() and not Path(name).is_absolute():
            path = self.plan_directory / name
        loaded = load_plan(path, self.station.limits, self.joint_names)
        with self.lock:
            self.plan, self.plan_source, self.views, self.part = loaded.plan, str(loaded.path), [], loaded.part
            self.samples_mm = self.predicted_mask = self.coverable_mask = None
            self.last_measured_coverage = -1.0
        return loaded

    def store(self, name: str) -> Path:
        """Write the session's plan; returns the path written."""
        if self.plan is None:
            raise GoalError("no plan to store: plan or load one first")
        if not name:
            raise GoalError("plan_file is empty")
        return plan_io.store_execution_plan(self.plan_path(name), self.plan)

    # ------------------------------------------------------------------------------------ execution
    def connection_planner(self, state: np.ndarray) -> TrajectoryManager:
        """The manager that plans motions from ``state``: the planning run's, else one with the plan's part in
        the collision world."""
        if self.manager is not None:
            return self.manager
        manager = TrajectoryManager(self.station, start_state=state)
        if self.part is not None:
            manager.set_collision_part(self.part)
        return manager

    def prepared_plan(self, state: np.ndarray) -> plan_io.ExecutionPlan:
        """The session's plan starting at the robot's current ``state`` (rad)."""
        if self.plan is None:
            raise GoalError("no plan: plan one, load one, or give plan_file")
        plan = self.plan
        if np.abs(plan.segments[0].trajectory.start - state).max() <= 1e-3:
            return plan
        manager = self.connection_planner(state)
        return adapt_plan_start(plan, state, lambda start, goal: manager.connect(start, goal, planning_time_s=1.0))

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
    def write_figure(self, name: str) -> Path:
        """The coverage picture of the planning run as a PNG (relative names go to the plan directory)."""
        path = Path(name).expanduser()
        if not path.is_absolute():
            path = self.plan_directory / path
        if path.suffix.lower() != ".png":
            raise GoalError(f"the figure must be a .png file, got {path.name}")
        if not path.parent.is_dir():
            raise GoalError(f"directory does not exist: {path.parent}")
        manager = self.manager
        if manager is None:
            raise GoalError("nothing planned yet")
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
        )
