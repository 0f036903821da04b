"""Executing a plan: the executor interface, the segment loop, loading a stored plan and adapting its start.

An executor drives the robot through one segment at a time (:class:`SegmentExecutor`). The package has two:
:class:`SimulatedExecutor` (instant, on a kinematic state; pytest, and the API's default outside ROS) and
``agiprobot_measurement.ros.executor.RosSegmentExecutor`` (the robot controller's action, the scanner's stitching;
the API's default inside a ROS process with the station running, see :func:`ros_station_executor`).
:func:`execute_segments` runs the loop: feedback before each segment, stop at the first failure or cancel, and an
:class:`ExecutionOutcome` that says how far it got. Joint values are rad, times s, lengths mm.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.motion.trajectory import JointTrajectory, check_trajectory
from agiprobot_measurement.planning import plan_io
from agiprobot_measurement.planning.plan_io import ExecutionPlan
from agiprobot_measurement.planning.viewpoint import ViewPoint

__all__ = [
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
    "execute_segments",
    "load_plan",
    "plan_part",
    "plan_segments",
    "segment_triples",
]

#: a start this close (rad, every joint) to the current state needs no adaptation
START_TOLERANCE_RAD = 1e-3


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


def execute_segments(
    segments: Sequence[tuple[str, JointTrajectory, object]],
    executor: SegmentExecutor,
    on_segment: Callable[[SegmentFeedback], None] | None = None,
) -> ExecutionOutcome:
    """Run ``(kind, trajectory, viewpoint or None)`` segments one after the other through ``executor``;
    stop at the first failure or cancel. ``on_segment`` hears of each segment before it starts."""
    total_time = sum(trajectory.duration for _, trajectory, _ in segments if trajectory is not None) or 1.0
    done_time = 0.0
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
            return ExecutionOutcome("failed", index, len(segments), str(exc))
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
    :class:`~agiprobot_measurement.planning.plan_io.PlanError` naming the plan file and the key."""
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
    not fit; :class:`~agiprobot_measurement.planning.plan_io.PlanError` if it cannot be read)."""
    path = Path(path)
    plan = plan_io.load_execution_plan(path)
    verdict = plan_io.validate_execution_plan(plan, limits, list(joint_names))
    if not verdict.ok:
        raise PlanRejected(f"{path}: not a plan for this robot: {verdict.reason}")
    return LoadedPlan(path, plan, plan_part(plan))


def adapt_plan_start(
    plan: ExecutionPlan,
    state: np.ndarray,
    connect: Callable[[np.ndarray, np.ndarray], JointTrajectory | None],
) -> ExecutionPlan:
    """``plan`` starting at the current ``state``: unchanged when it already starts there, else with a motion
    from ``connect(start, goal)`` (a collision-free trajectory or None) merged into the first connection."""
    if np.abs(plan.segments[0].trajectory.start - state).max() <= START_TOLERANCE_RAD:
        return plan

    def planner_fn(start, goal):
        trajectory = connect(np.asarray(start), np.asarray(goal))
        if trajectory is None:
            raise PlanRejected("no collision-free motion from the current state to the plan's start")
        return trajectory

    return plan_io.adapt_to_current_start_pose(plan, state, planner_fn)


def segment_triples(items: Sequence) -> list[tuple[str, JointTrajectory, object]]:
    """``(kind, trajectory, view)`` of what ``TrajectoryManager.execute`` accepts: views (each its connection and
    its measurement), or an execution plan's segments in C-M-C-M-... order: plan segments, bare trajectories,
    ``moveit_msgs/RobotTrajectory`` messages or anything shaped like one (``joint_trajectory``), or their
    expanded mappings. Raises :class:`~agiprobot_measurement.planning.plan_io.PlanError` naming the segment
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


def in_ros_process() -> bool:
    """Whether this process is a ROS node (``rospy.init_node`` was called); imports nothing from ROS."""
    rospy = sys.modules.get("rospy")
    core = getattr(rospy, "core", None)
    return bool(core is not None and core.is_initialized())


def ros_station_executor(joint_names: Sequence[str], surface_points_mm=None, part: PlanPart | None = None):
    """The running station's executor (``agiprobot_measurement.ros.library_executor.station_executor``), or None
    when this is not a ROS process or no controller answers.

    The core never imports the ROS layer at module level: this looks it up by name, and only in a process where
    ``rospy`` is already initialised, so ``TrajectoryManager.execute`` drives the real (or simulated) controller
    for scripts written against the original, and stays instant and ROS-free everywhere else.
    """
    if not in_ros_process():
        return None
    module = importlib.import_module("agiprobot_measurement.ros.library_executor")
    return module.station_executor(joint_names, surface_points_mm=surface_points_mm, part=part)
