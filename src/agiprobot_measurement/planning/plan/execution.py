"""Executing a plan: the executor interface, the segment loop, loading a stored plan and adapting its start.

An executor drives the robot through one segment at a time (:class:`SegmentExecutor`). The core has
:class:`SimulatedExecutor` (instant, on a kinematic state; pytest, and the API's default without a station); the
layers above register the station's executor in :mod:`~agiprobot_measurement.planning.plan.executors`.
:func:`execute_segments` runs the loop: feedback before each segment, stop at the first failure or cancel, and an
:class:`ExecutionOutcome` that says how far it got. Joint values are rad, times s, lengths mm.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from agiprobot_measurement.errors import AgiprobotError, InputError, InternalError
from agiprobot_measurement.motion.trajectory import JointTrajectory, check_trajectory
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.plan import executors, plan_io
from agiprobot_measurement.planning.plan.plan_io import START_TOLERANCE_RAD, ExecutionPlan

__all__ = [
    "JUMP_TOLERANCE_RAD",
    "MAX_PART_LINEAR_ENTRY",
    "MAX_PART_OFFSET_MM",
    "ControllerLost",
    "ExecutionCancelled",
    "ExecutionError",
    "ExecutionOutcome",
    "LoadedPlan",
    "PlanPart",
    "PlanRejected",
    "SegmentExecutor",
    "SegmentFeedback",
    "SimulatedExecutor",
    "adapt_plan_start",
    "as_joint_trajectory",
    "choose_executor",
    "execute_segments",
    "load_plan",
    "plan_info",
    "plan_part",
    "plan_segments",
    "segment_triples",
    "starts_at",
    "state_jump",
    "view_segments",
]


class ExecutionError(InternalError):
    """Executing a trajectory failed; the robot has been stopped."""


class ControllerLost(ExecutionError):
    """The robot controller stopped answering during a segment (no joint states, its action server gone); the
    execution is aborted at once instead of waiting for a result that never comes."""


class ExecutionCancelled(RuntimeError):
    """The caller cancelled execution (an executor raises it); the robot has been stopped."""


class PlanRejected(InputError):
    """A plan cannot run here: not for this robot, or no motion to its start."""


class SegmentExecutor(Protocol):
    """Drives the robot through one segment at a time."""

    def current_state(self) -> np.ndarray:
        """(n,) joint positions, rad."""

    def execute_segment(self, trajectory: JointTrajectory, kind: str, viewpoint=None) -> None:
        """Run one segment ('connect' or 'measure'; ``viewpoint`` the view it measures, if known) to its end.
        Raises :class:`ExecutionError` on failure, :class:`ExecutionCancelled` when cancelled."""


class SimulatedExecutor:
    """Executes trajectories instantly on a kinematic state (no ROS): the default executor.

    Each segment must start at the current state and meet the joint limits (else :class:`ExecutionError`);
    ``on_measure(viewpoint)`` is called after each measurement segment that names its view.
    """

    def __init__(self, start_state: np.ndarray, limits, on_measure: Callable | None = None):
        self.state = np.asarray(start_state, dtype=float).copy()
        self.limits = limits
        self.on_measure = on_measure
        self.log: list[tuple[str, float]] = []

    def current_state(self) -> np.ndarray:
        return self.state.copy()

    def execute_segment(self, trajectory: JointTrajectory, kind: str, viewpoint=None) -> None:
        verdict = check_trajectory(trajectory, self.limits, self.state)
        if not verdict.ok:
            raise ExecutionError(f"{kind} segment rejected: {verdict.reason}")
        self.state = trajectory.end.copy()
        self.log.append((kind, trajectory.duration))
        if kind == "measure" and self.on_measure is not None and viewpoint is not None:
            self.on_measure(viewpoint)


@dataclass(frozen=True)
class SegmentFeedback:
    """Before a segment starts: its number (1-based), the count, its kind, the share of the plan's time done."""

    number: int
    total: int
    kind: str
    done_fraction: float


@dataclass
class ExecutionOutcome:
    """How an execution ended: ``status`` 'ok', 'cancelled', 'failed' or 'controller_lost' (``error`` says why)."""

    status: str
    segments_executed: int
    total: int
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def describe(self) -> str:
        """One line for a result or a log ('' when everything ran)."""
        if self.status == "cancelled":
            return f"cancelled during segment {self.segments_executed + 1} of {self.total}; robot stopped"
        if self.status == "failed":
            return f"segment {self.segments_executed + 1} of {self.total} failed: {self.error}; robot stopped"
        if self.status == "controller_lost":
            return (
                f"controller lost during segment {self.segments_executed + 1} of {self.total}: {self.error}; "
                "scanning stopped, the plan is kept"
            )
        return ""


#: a robot this far (rad, any joint) from where its last segment ended has moved without a command: its controller
#: was restarted or lost between moves (a controller's tracking error is far smaller)
JUMP_TOLERANCE_RAD = 0.05


def state_jump(state, expected: np.ndarray | None, where: str) -> str:
    """Why the robot's joint ``state`` (rad) is not at ``expected``, where ``where`` (e.g. 'segment 2') ended, or ''
    (nothing expected, the state unknown or of another shape, or within :data:`JUMP_TOLERANCE_RAD`)."""
    if expected is None or state is None:
        return ""
    state = np.asarray(state, dtype=float)
    if state.shape != np.shape(expected):
        return ""
    offsets = np.abs(state - expected)
    joint = int(np.argmax(offsets))
    if not offsets[joint] > JUMP_TOLERANCE_RAD:
        return ""
    return (
        f"the robot's joint {joint + 1} is {offsets[joint]:.3f} rad from where {where} ended without a command: "
        "the controller was restarted or lost between moves"
    )


def _jump_since(executor: SegmentExecutor, previous_end: np.ndarray | None, index: int) -> str:
    """:func:`state_jump` of ``executor``'s state since segment ``index`` (0-based) - 1 ended."""
    if previous_end is None:
        return ""
    try:
        state = executor.current_state()
    except (AgiprobotError, ValueError, RuntimeError):
        return ""
    return state_jump(state, previous_end, f"segment {index}")


def execute_segments(
    segments: Sequence[tuple[str, JointTrajectory, object]],
    executor: SegmentExecutor,
    on_segment: Callable[[SegmentFeedback], None] | None = None,
) -> ExecutionOutcome:
    """Run ``(kind, trajectory, viewpoint or None)`` segments one after the other through ``executor``;
    stop at the first failure or cancel. ``on_segment`` hears of each segment before it starts."""
    total_time = sum(trajectory.duration for _, trajectory, _ in segments if trajectory is not None) or 1.0
    done_time = 0.0
    previous_end = None
    for index, (kind, trajectory, view) in enumerate(segments):
        if on_segment is not None:
            on_segment(SegmentFeedback(index + 1, len(segments), kind, done_time / total_time))
        if trajectory is None:
            return ExecutionOutcome("failed", index, len(segments), f"a {kind} segment has no trajectory")
        try:
            executor.execute_segment(trajectory, kind, view)
        except ExecutionCancelled:
            return ExecutionOutcome("cancelled", index, len(segments))
        except ControllerLost as exc:
            return ExecutionOutcome("controller_lost", index, len(segments), str(exc))
        except ExecutionError as exc:
            jump = _jump_since(executor, previous_end, index)
            if jump:  # a controller restarted between moves refuses the next one as not starting at its state
                return ExecutionOutcome("controller_lost", index, len(segments), f"{jump}; the segment failed: {exc}")
            return ExecutionOutcome("failed", index, len(segments), str(exc))
        previous_end = trajectory.end
        done_time += trajectory.duration
    return ExecutionOutcome("ok", len(segments), len(segments))


def plan_segments(plan_or_segments, views: Sequence | None = None) -> list[tuple[str, JointTrajectory, object]]:
    """``(kind, trajectory, view)`` triples of a plan's segments; ``views`` name the measured view of each
    connect+measure pair when they match the plan (2 segments per view), else views are None."""
    segments = plan_or_segments.segments if isinstance(plan_or_segments, ExecutionPlan) else list(plan_or_segments)
    by_measure = {}
    if views and len(views) * 2 == len(segments):
        by_measure = {2 * i + 1: view for i, view in enumerate(views)}
    return [(s.kind, s.trajectory, by_measure.get(i)) for i, s in enumerate(segments)]


#: a stored plan's part lies at most this far (mm, any axis) from the world origin: a station is metres across, and a
#: part beyond it executed "successfully" with nothing to measure
MAX_PART_OFFSET_MM = 1e5
#: largest entry of a part placement's linear part: a rotation times the file unit's scale (1000 for metres)
MAX_PART_LINEAR_ENTRY = 1e4


@dataclass(frozen=True)
class PlanPart:
    """The part a plan measures: its mesh file, the file's unit, and ``placement_mm``, the 4x4 map from file
    coordinates to world mm (the unit's scale included)."""

    mesh_file: str
    units: str
    placement_mm: np.ndarray

    @property
    def scale_to_mm(self) -> float:
        return float(np.linalg.norm(self.placement_mm[:3, 0]))

    @property
    def file_units_placement(self) -> np.ndarray:
        """The placement with the unit's scale taken out: file coordinates in the file's unit -> world mm."""
        return self.placement_mm @ np.diag([1.0 / self.scale_to_mm] * 3 + [1.0])


def plan_part(plan: ExecutionPlan) -> PlanPart | None:
    """The part named in a stored plan's parameters, or None. A malformed entry raises
    :class:`~agiprobot_measurement.planning.plan.plan_io.PlanError` naming the plan file and the key."""
    where = f"{plan.source}: " if plan.source is not None else ""
    params = plan.metadata.get("parameters", {}) if isinstance(plan.metadata, dict) else {}
    if not isinstance(params, dict):
        raise plan_io.PlanError(f"{where}metadata 'parameters' must be a mapping, got {type(params).__name__}")
    if "part_file" not in params or "part_transform_mm" not in params:
        return None
    key = "parameters.part_transform_mm"
    try:
        placement = np.asarray(params["part_transform_mm"], dtype=float)
    except (TypeError, ValueError) as exc:
        raise plan_io.PlanError(f"{where}{key} must be 16 numbers (a 4x4 matrix, mm): {exc}") from exc
    if placement.size != 16 or placement.ndim not in (1, 2) or (placement.ndim == 2 and placement.shape != (4, 4)):
        raise plan_io.PlanError(f"{where}{key} must be 16 numbers (a 4x4 matrix, mm), got shape {placement.shape}")
    if not np.all(np.isfinite(placement)):
        raise plan_io.PlanError(f"{where}{key} holds NaN or infinite values")
    placement = placement.reshape(4, 4)
    offset_mm = float(np.abs(placement[:3, 3]).max())
    if offset_mm > MAX_PART_OFFSET_MM:
        raise plan_io.PlanError(
            f"{where}{key} places the part {offset_mm:.3g} mm from the world origin: beyond the "
            f"{MAX_PART_OFFSET_MM:,.0f} mm a station spans"
        )
    if float(np.abs(placement[:3, :3]).max()) > MAX_PART_LINEAR_ENTRY or not np.allclose(
        placement[3], [0.0, 0.0, 0.0, 1.0]
    ):
        raise plan_io.PlanError(
            f"{where}{key} must be a rotation and a unit scale (entries of at most {MAX_PART_LINEAR_ENTRY:g}) "
            "and end in the row 0 0 0 1"
        )
    part_file = params["part_file"]
    if not isinstance(part_file, str) or not part_file:
        raise plan_io.PlanError(f"{where}parameters.part_file must be a file name, got {part_file!r}")
    return PlanPart(part_file, str(params.get("units", "mm")), placement.reshape(4, 4))


@dataclass
class LoadedPlan:
    """A stored plan read and checked for this robot."""

    path: Path
    plan: ExecutionPlan
    part: PlanPart | None


def load_plan(path: str | Path, limits, joint_names: Sequence[str]) -> LoadedPlan:
    """Read a stored plan and check it against the robot's joints and limits (:class:`PlanRejected` if it does
    not fit; :class:`~agiprobot_measurement.planning.plan.plan_io.PlanError` if it cannot be read)."""
    path = Path(path)
    plan = plan_io.load_execution_plan(path)
    verdict = plan_io.validate_execution_plan(plan, limits, list(joint_names))
    if not verdict.ok:
        raise PlanRejected(f"{path}: not a plan for this robot: {verdict.reason}")
    return LoadedPlan(path, plan, plan_part(plan))


def starts_at(plan: ExecutionPlan, state: np.ndarray) -> bool:
    """Whether ``plan`` starts at ``state`` (rad) within :data:`START_TOLERANCE_RAD` on every joint."""
    return bool(np.abs(plan.segments[0].trajectory.start - state).max() <= START_TOLERANCE_RAD)


def adapt_plan_start(
    plan: ExecutionPlan,
    state: np.ndarray,
    connect: Callable[[np.ndarray, np.ndarray], JointTrajectory | None],
    error: type[Exception] = PlanRejected,
) -> ExecutionPlan:
    """``plan`` starting at the current ``state``: unchanged when it already starts there (:func:`starts_at`),
    else with a motion from ``connect(start, goal)`` (a collision-free trajectory or None) merged into the first
    connection; ``error`` (default :class:`PlanRejected`) is raised when ``connect`` finds no motion."""
    if starts_at(plan, state):
        return plan

    def planner_fn(start, goal):
        trajectory = connect(np.asarray(start), np.asarray(goal))
        if trajectory is None:
            raise error("no collision-free motion from the current state to the plan's start")
        return trajectory

    return plan_io.adapt_to_current_start_pose(plan, state, planner_fn)


def segment_triples(items: Sequence) -> list[tuple[str, JointTrajectory, object]]:
    """``(kind, trajectory, view)`` of what ``TrajectoryManager.execute`` accepts: views (each its connection and
    its measurement), or an execution plan's segments in C-M-C-M-... order: plan segments, bare trajectories,
    ``moveit_msgs/RobotTrajectory`` messages or anything shaped like one (``joint_trajectory``), or their
    expanded mappings. Raises :class:`~agiprobot_measurement.planning.plan.plan_io.PlanError` naming the segment
    that is none of these."""
    if isinstance(items, ExecutionPlan):
        items = items.segments
    items = list(items)
    if items and all(isinstance(item, ViewPoint) for item in items):
        out = []
        for view in items:
            out.append(("connect", view.get_trajectory_to_view(), view))
            out.append(("measure", view.get_trajectory_for_measurement(), view))
        return out
    return [(segment.kind, segment.trajectory, None) for segment in plan_io.as_segments(items)]


EXECUTOR_CHOICES = ("auto", "simulated", "station")


def as_joint_trajectory(item) -> JointTrajectory:
    """The joint trajectory of ``item``: a :class:`JointTrajectory`, a plan segment, an expanded mapping, or a
    ``moveit_msgs/RobotTrajectory``-shaped object (``joint_trajectory``) or ``trajectory_msgs/JointTrajectory``."""
    if isinstance(item, JointTrajectory):
        return item
    if isinstance(item, plan_io.PlanSegment):
        return item.trajectory
    if isinstance(item, dict):
        return JointTrajectory.from_dict(item.get("joint_trajectory", item))
    if hasattr(item, "joint_trajectory"):
        return JointTrajectory.from_msg(item.joint_trajectory)
    return JointTrajectory.from_msg(item)


def choose_executor(
    choice, joint_names: Sequence[str], parameters: dict, current_state, limits, surface_points=None, error=InputError
):
    """The executor of ``TrajectoryManager.execute``'s ``executor`` argument: a
    :class:`SegmentExecutor` as given; ``'station'`` / ``'auto'`` the registered station executor
    (:data:`~agiprobot_measurement.planning.plan.executors.STATION`) when one answers, with the part named by
    the planning ``parameters``; ``'station'`` raises :class:`ExecutionError` when none does; else (and for
    ``'simulated'``) an instant :class:`SimulatedExecutor` at ``current_state`` (rad). An unknown name raises
    ``error``."""
    if choice is not None and not isinstance(choice, str):
        return choice
    choice = "auto" if choice is None else choice
    if choice not in EXECUTOR_CHOICES:
        raise error(f"executor must be one of {EXECUTOR_CHOICES} or a SegmentExecutor, got {choice!r}")
    if choice != "simulated":
        part = None
        if "part_file" in parameters and "part_transform_mm" in parameters:
            placement = np.asarray(parameters["part_transform_mm"], dtype=float).reshape(4, 4)
            part = PlanPart(str(parameters["part_file"]), str(parameters.get("units", "mm")), placement)
        station = None
        if executors.registered(executors.STATION):
            station = executors.get(executors.STATION)(list(joint_names), surface_points, part)
        if station is not None:
            return station
        if choice == "station":
            raise ExecutionError(
                "executor='station': no station executor is registered (the ROS layer registers its own), "
                "this is not a ROS process or no robot controller answers"
            )
    return SimulatedExecutor(current_state, limits)


def view_segments(views, error: type[Exception] = InputError) -> list[plan_io.PlanSegment]:
    """Two plan segments per view: the connection to it ('connect') and its measurement ('measure'); ``error`` is
    raised for a view that lacks one of them."""
    segments = []
    for view in views:
        connection, measurement = view.get_trajectory_to_view(), view.get_trajectory_for_measurement()
        if connection is None or measurement is None:
            raise error(f"{view} lacks its trajectories: connect_viewpoints first")
        segments += [
            plan_io.PlanSegment(plan_io.CONNECT, connection),
            plan_io.PlanSegment(plan_io.MEASURE, measurement),
        ]
    return segments


def plan_info(robot_name: str, joint_names: Sequence[str]) -> dict:
    """The header of a plan file planned by this package for ``robot_name``'s ``joint_names``."""
    return {
        "Timestamp": time.strftime("%a %b %d %H:%M:%S %Y"),
        "robot": robot_name,
        "joint_names": list(joint_names),
        "planner": "agiprobot_measurement",
    }
