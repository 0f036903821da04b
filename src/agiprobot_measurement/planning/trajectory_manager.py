"""TrajectoryManager: plan, store, load and execute measurement trajectories for a laser line scanner.

The documented API of the original package (names, parameters, defaults, mm and points/mm^2), rebuilt on the
package's ROS-free core: the station comes from configuration (``config/*.yaml``), MoveIt's jobs are done by
KDL / closed-form IK, FCL and OMPL, and every stage works in batch.

Pipeline: ``generate_samples_and_viewpoints`` -> ``solve_scp`` -> ``connect_viewpoints`` ->
``convert_viewpointlist_to_execution_plan`` -> ``store_execution_plan`` / ``execute``. This is the facade: the
run's state is a :class:`~agiprobot_measurement.planning.run.PlanningRun` (its documented attributes are read and
written here under their names) and each method calls a stage (see :mod:`agiprobot_measurement.planning`).
The API takes and returns mm (positions, lengths) and rad; kinematics and collision work in metres.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable

import numpy as np

import agiprobot_measurement
from agiprobot_measurement.motion.trajectory import check_trajectory
from agiprobot_measurement.planning import pipeline
from agiprobot_measurement.planning.candidates import generation
from agiprobot_measurement.planning.candidates.distributed import DaskEvaluator  # Dask itself loads on first use
from agiprobot_measurement.planning.candidates.streaming import EvaluationSettings
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.connection import ConnectionPlanner, add_plan_part, station_robot
from agiprobot_measurement.planning.deadline import StageClock
from agiprobot_measurement.planning.errors import PlanningCancelled, PlanningError
from agiprobot_measurement.planning.ordering import connect_views, p2p_durations
from agiprobot_measurement.planning.plan import execution, plan_io
from agiprobot_measurement.planning.plan.execution import (
    ExecutionCancelled,
    ExecutionError,
    PlanPart,
    SimulatedExecutor,
)
from agiprobot_measurement.planning.plan.plan_io import PlanSegment
from agiprobot_measurement.planning.report import report
from agiprobot_measurement.planning.report.progress import STAGES
from agiprobot_measurement.planning.report.report import CoverageReport
from agiprobot_measurement.planning.request import PLACEMENTS, PlanRequest, WorkBudget, check_choice, check_positive
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools, RunField, joint_state
from agiprobot_measurement.planning.selection import loop
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.station import Station

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

#: progress callback: (stage, fraction done 0..1, message)
ProgressCallback = Callable[[str, float, str], None]


def _arguments(arguments: dict) -> dict:
    """A method's arguments (its ``locals()`` on entry) without ``self``, to hand them on to its stage."""
    return {k: v for k, v in arguments.items() if k != "self"}


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
        self.station = station or Station.load()
        self.work_budget = work_budget if work_budget is not None else WorkBudget()
        self.scan_speed_mm_s = check_positive(scan_speed_mm_s, "scan_speed_mm_s", "scan_speed_mm_s (mm/s)")
        self.kinematics, self.ik, self.collision = station_robot(self.station)
        self.limits, self._base_scene = self.station.limits, self.station.scene
        self.sensor_model = SensorModel(self.station.scanner.sensor_parameters)
        self.planner_name = planner_name
        self.progress = progress
        self.seed = int(seed)
        self.connection = ConnectionPlanner(self.collision, self.limits, planner_name, self.seed)
        self.current_state = joint_state(self.station.named_states, self.kinematics.dof, start_state)
        self.preferred_state = joint_state(self.station.named_states, self.kinematics.dof, preferred_state)
        #: the state of the planning run (samples, candidates, views, cover, order, timings, warnings, ...)
        self.run = PlanningRun()

    def check_time(self, stage: str) -> None:
        """Raise when the running plan's time limit ran out in ``stage`` (see :mod:`.deadline`)."""
        if self.run.clock is not None:
            self.run.clock.check(stage)

    def _report(self, stage: str, fraction: float, message: str = "") -> None:
        self.check_time(stage)
        if self.progress is not None:
            self.progress(stage, float(min(max(fraction, 0.0), 1.0)), message)

    def tools(self) -> PlanningTools:
        """The collaborators the run's stages use, with the current states."""
        robot = (self.kinematics, self.ik, self.limits, self.collision, self.sensor_model)
        states = (self.preferred_state, self.current_state, self.scan_speed_mm_s)
        return PlanningTools(*robot, *states, self.connect, self._report)

    def evaluator(self):
        """The Dask evaluator of this manager's settings (made on first use), or None to evaluate here."""
        if self._evaluator is None and self.evaluation.distributed:
            self._evaluator = DaskEvaluator(self.evaluation.workers, self.evaluation.scheduler)
        return self._evaluator

    def close(self) -> None:
        """End the Dask client (and a local cluster) of the evaluation, if one was started."""
        if self._evaluator is not None:
            self._evaluator.close()
            self._evaluator = None

    @property
    def planner(self):
        """The OMPL planner of connection moves (set up on first use)."""
        return self.connection.planner

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
        or the robot at its start state (:class:`~agiprobot_measurement.motion.placement_check.PlacementError`, naming
        the object, the depth and the lift that clears it). ``tessellation_tolerance_mm``: linear deflection of
        the STEP tessellation (0 = the reader's default). Raises
        :class:`~agiprobot_measurement.planning.part_loading.PartLoadError` with the reason for unreadable, empty or
        implausible input; returns True when everything was loaded.
        """
        check_choice(placement, PLACEMENTS, "placement")
        return pipeline.load_target(self, **_arguments(locals()))

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
        args = _arguments(locals())
        budget = generation.EvaluationBudget(self.evaluation, self.evaluator(), self.work_budget, self.seed)
        return generation.generate_samples_and_viewpoints(self.run, self.tools(), budget, **args)

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
        return generation.process_viewpoint(self.run, self.tools(), **_arguments(locals()))

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
        return loop.solve_scp(self.run, self.tools(), **_arguments(locals()))

    def connect(self, start: np.ndarray, goal: np.ndarray, planning_time_s: float = 0.2, attempts: int = 3):
        """Collision-free, time-parameterised joint trajectory from ``start`` to ``goal``, or None: the straight joint
        move when it is free (exactly time-optimal), else OMPL with ``attempts``, each with twice the time of the last."""
        return self.connection.connect(start, goal, planning_time_s=planning_time_s, attempts=attempts)

    def connect_viewpoints(self, unordered_viewpoints, min_planning_time=0.2):
        """Order the views for a fast execution and connect them (greedy by connection time from the current
        state, either scan direction, then 2-opt). Each view stores its connecting trajectory
        (``get_trajectory_to_view``). Views that cannot be connected are left out and listed in
        ``unconnected_views``. Returns the ordered list."""
        return connect_views(self.run, self.tools(), unordered_viewpoints, min_planning_time)

    def convert_viewpointlist_to_execution_plan(self, viewpointlist) -> list[PlanSegment]:
        """Two segments per view: the connection to it ('connect') and its measurement ('measure')."""
        return execution.view_segments(viewpointlist, error=PlanningError)

    def store_execution_plan(self, file_path, execution_plan, metadata={}):  # noqa: B006 (documented default)
        """Store the plan as YAML at exactly ``file_path`` (the original's format; atomic write).
        Returns True (documented); the path written is in ``last_plan_path``."""
        info = {**execution.plan_info(self.station.robot.name, self.limits.names), **self.plan_metadata()}
        info.update(dict(metadata))
        self.last_plan_path = plan_io.store_execution_plan(file_path, execution_plan, info)
        return True

    def plan_metadata(self) -> dict:
        """Parameters, coverage and timings of the last planning run (for the plan file)."""
        return report.run_metadata(self.run, agiprobot_measurement.__version__)

    def load_execution_plan(self, file_path, adapt_to_current_start_pose=True):
        """Load a stored plan (validated against this robot's joints and limits). With
        ``adapt_to_current_start_pose`` a planned motion from the current state to the plan's first point is
        merged into the first connection. Returns the list of segments (connect, measure, ...)."""
        try:
            plan = execution.load_plan(file_path, self.limits, self.limits.names).plan
        except execution.PlanRejected as exc:
            raise PlanningError(str(exc)) from exc
        if adapt_to_current_start_pose:
            plan = self.adapt_start(plan, self.current_state)
        self.loaded_plan = plan
        return list(plan.segments)

    def adapt_start(self, plan: plan_io.ExecutionPlan, state: np.ndarray) -> plan_io.ExecutionPlan:
        """``plan`` starting at ``state`` (rad): a collision-free motion to its first point is merged into the
        first connection when it starts elsewhere. Raises PlanningError when there is no such motion."""
        connect = lambda start, goal: self.connect(start, goal, planning_time_s=1.0)  # noqa: E731
        return execution.adapt_plan_start(plan, state, connect, error=PlanningError)

    def set_collision_part(self, part: PlanPart) -> None:
        """Put a stored plan's part into the collision world (as placed in the plan; downward faces kept), so
        that motions planned to the plan's start avoid it."""
        add_plan_part(self.collision, part)

    def postprocess_trajectory(self, trajectory) -> bool:
        """Whether a trajectory meets the joint limits (positions, velocities, accelerations) and its time is
        strictly increasing (the documented check)."""
        verdict = check_trajectory(execution.as_joint_trajectory(trajectory), self.limits)
        if not verdict.ok:
            LOG.warning("trajectory rejected: %s", verdict.reason)
        return verdict.ok

    def execute(self, execution_list, surface_points=None, executor=None, on_segment=None):
        """Execute segments, ``moveit_msgs/RobotTrajectory``-shaped items or ViewPoints one after the other.

        ``executor``: ``None``/``"auto"`` drives the running station's controller when a station executor is
        registered (:mod:`~agiprobot_measurement.planning.plan.executors`; the ROS layer registers one that answers
        in a ROS process) and a controller answers, as the original drove the robot through MoveIt, else an instant
        simulated robot; ``"simulated"`` always the instant one; ``"station"`` the station or an
        :class:`ExecutionError`; or any
        :class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor`. On the station, with
        ``surface_points`` (the sampled points, mm) and views given, the points each view measures are published
        on ``/currently_measured_points`` while it runs (as the original did). A failing segment stops execution
        and raises :class:`ExecutionError`; a cancel raises
        :class:`~agiprobot_measurement.planning.plan.execution.ExecutionCancelled`. ``on_segment(feedback)`` hears of
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
        triples = execution.segment_triples(execution_list)  # malformed input is refused before anything moves
        names, params = self.limits.names, self.parameters
        executor = execution.choose_executor(
            executor, names, params, self.current_state, self.limits, surface_points, PlanningError
        )
        outcome = execution.execute_segments(triples, executor, on_segment)
        self.current_state = executor.current_state()
        return outcome

    def _chosen(self, views) -> list[ViewPoint]:
        return list(views) if views is not None else (self.last_ordered or [])

    def _planned(self) -> PlanningRun:
        if self.samples is None:
            raise PlanningError("nothing planned yet")
        return self.run

    def coverable_mask(self) -> np.ndarray:
        """(n_samples,) bool: the samples some view verified executable measures, or the plan covers."""
        covered = np.isfinite(self.point_uncertainties())
        return report.coverable_mask(self._planned().last_viewpoints, len(self.samples), covered)

    def metrology_coverable_mask(self) -> np.ndarray:
        """(n_samples,) bool: the samples some candidate view with a reachable anchor measures (the sensor model
        says so), whether or not its scan line can be driven."""
        return report.metrology_mask(self._planned())

    def coverage_report(self, views: Iterable[ViewPoint] | None = None) -> CoverageReport:
        """Coverage, view count, execution time and uncertainties of the chosen (or given) views."""
        return report.run_report(self._planned(), views)

    def point_uncertainties(self, views: Iterable[ViewPoint] | None = None) -> np.ndarray:
        """Best predicted uncertainty (mm) per sample over the given views (default: the plan); inf = unmeasured."""
        return report.point_uncertainties(self._chosen(views), len(self.samples))

    def scan_lines_mm(self, views: Iterable[ViewPoint] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """(start, end) positions (mm) of the laser_emitter_frame's scan lines of the given views (default: plan)."""
        return report.scan_lines(self.kinematics, self._chosen(views))

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
        settings = request.manager_settings()
        return cls(station, progress=progress, start_state=start_state, work_budget=work_budget, **settings)

    def plan_request(self, request: PlanRequest, started_s: float | None = None) -> list[ViewPoint]:
        """Load the request's part and run the whole pipeline with its settings (``request`` validated with
        :meth:`PlanRequest.validate`; the manager made by :meth:`for_request`). Returns the ordered views.
        ``started_s``: the ``time.perf_counter()`` value the time limit counts from (default: now; a command
        passes its own start, so that its start-up counts too)."""
        started = time.perf_counter() if started_s is None else float(started_s)
        self._report("sampling", 0.0, f"loading {request.part_file}")
        self.run.clock = StageClock(started, float(request.time_limit_s))
        try:
            self.load_target_mesh(request.part_file, **request.part_arguments())
            self._report("sampling", 0.0, f"loaded {request.part_file}")
        finally:
            self.run.clock = None
        return self.plan(**request.plan_arguments(), started_s=started)

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
        started_s=None,
        **generation,
    ) -> list[ViewPoint]:
        """The whole pipeline on the loaded part: generate, solve the set cover, connect. Returns the ordered
        views (also in ``last_ordered``). The defaults are :class:`PlanRequest`'s.

        ``time_limit_s`` bounds the whole plan: the set cover / verification loop ends in time for the connection
        and the best verified plan is returned with its optimality gap (``time_limit_hit`` says whether the limit
        cut it short). ``viewpoint_tilt_mode='auto'`` plans with tilt none first and, when the cover is large or
        leaves metrologically coverable points uncovered and time is left, with tilt full; the plan with fewer
        views at the same coverage (or clearly more coverage) is kept and the choice is in
        ``parameters['tilt_choice']``. ``started_s``: the ``time.perf_counter()`` value the time limit counts
        from (default: now). The stages before the set cover check the limit between their chunks and raise
        :class:`~agiprobot_measurement.planning.errors.PlanningTimeLimit` when it ran out (no plan to return).
        """
        return pipeline.plan(self, **_arguments(locals()))


#: the run's attributes the facade exposes under their documented names (read and written through to ``run``)
RUN_ATTRIBUTES = (
    "part target_mesh samples sampled_surface_points candidates measurability last_set_cover last_viewpoints "
    "last_ordered unconnected_views dropped_views timings_s parameters mechanics_checked warnings reachable_share time_limit_hit "
    "revived_views last_stream_stats last_work_estimate last_plan_path loaded_plan"
).split()
for _name in RUN_ATTRIBUTES:
    setattr(TrajectoryManager, _name, RunField(_name))
