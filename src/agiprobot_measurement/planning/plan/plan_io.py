"""Execution plans: the original's YAML file format, validation, and adapting a plan to the current state.

File format (as written by the original ``TrajectoryManager.store_execution_plan``): a YAML list whose first
entry is a metadata mapping, followed by "expanded" ``moveit_msgs/RobotTrajectory`` mappings
``{joint_trajectory: {...}, multi_dof_joint_trajectory: {...}}`` alternating connection (C) and measurement
(M) segments, C-M-C-M-...; keys sorted, block style. Times are ``{secs, nsecs}``; positions in rad,
velocities in rad/s, accelerations in rad/s^2.

Loading and storing round-trip exactly: floats are written with ``repr`` precision, times as the integer
``secs``/``nsecs`` they were read as, the header (``seq``, ``stamp``) and the multi-DOF part unchanged.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.common.files import atomic_write_text
from agiprobot_measurement.common.message_shape import MessageShape, MessageTime, message_shape
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.trajectory import (
    CheckResult,
    CheckTolerances,
    JointTrajectory,
    TrajectoryError,
    check_continuity,
    check_trajectory,
)
from agiprobot_measurement.station import JointLimits

__all__ = [
    "CONNECT",
    "MEASURE",
    "PLAN_SUFFIXES",
    "SEGMENT_KINDS",
    "START_TOLERANCE_RAD",
    "ExecutionPlan",
    "MessageShape",
    "MessageTime",
    "PlanError",
    "PlanFileNotFoundError",
    "PlanSegment",
    "adapt_to_current_start_pose",
    "as_segments",
    "dump_execution_plan",
    "empty_multi_dof",
    "kind_at",
    "load_execution_plan",
    "message_shape",
    "message_to_dict",
    "plan_from_dicts",
    "plan_path",
    "plan_to_dicts",
    "segment_from_dict",
    "segment_from_message",
    "segment_to_dict",
    "store_execution_plan",
    "validate_execution_plan",
]

CONNECT = "connect"
MEASURE = "measure"
SEGMENT_KINDS = (CONNECT, MEASURE)
PLAN_SUFFIXES = (".yaml", ".yml")
#: a plan whose start is this close (rad, every joint) to the current state needs no adaptation
START_TOLERANCE_RAD = 1e-3

# libyaml's parser/emitter when present (5x faster on a 260 kB plan); the constructors and representers are
# the same Python classes either way, so the loaded values and written text are identical.
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_Dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


class PlanError(InputError):
    """An execution plan file or object is missing, malformed, or cannot be written."""


class PlanFileNotFoundError(PlanError, FileNotFoundError):
    """The execution plan file does not exist."""


def empty_multi_dof() -> dict:
    """The empty ``trajectory_msgs/MultiDOFJointTrajectory`` mapping the original wrote for every segment."""
    return {
        "header": {"frame_id": "", "seq": 0, "stamp": {"nsecs": 0, "secs": 0}},
        "joint_names": [],
        "points": [],
    }


def _default_header(frame_id: str) -> dict:
    return {"frame_id": frame_id, "seq": 0, "stamp": {"nsecs": 0, "secs": 0}}


@dataclass
class PlanSegment:
    """One segment: ``kind`` is ``'connect'`` (C, moves to a measurement) or ``'measure'`` (M, a scan line).

    ``header`` keeps the stored ``joint_trajectory.header`` (``seq``, ``stamp``); its ``frame_id`` is the
    trajectory's. ``multi_dof`` is the ``multi_dof_joint_trajectory`` mapping, empty in the original's plans.

    A segment also reads as the original's ``moveit_msgs/RobotTrajectory``: ``joint_trajectory`` and
    ``multi_dof_joint_trajectory`` are message-shaped snapshots (``seg.joint_trajectory.points[-1]
    .time_from_start.to_sec()``); inside ROS, the ROS layer's conversions make a ``trajectory_msgs/JointTrajectory``
    message of ``trajectory``.
    """

    kind: str
    trajectory: JointTrajectory
    multi_dof: dict = field(default_factory=empty_multi_dof)
    header: dict | None = None
    _shape_cache: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.kind not in SEGMENT_KINDS:
            raise PlanError(f"segment kind must be one of {SEGMENT_KINDS}, got {self.kind!r}")

    def _shapes(self) -> tuple:
        # Rebuilt when the trajectory object, header or multi-DOF part is replaced (not on in-place edits).
        key = (id(self.trajectory), len(self.trajectory), id(self.header), id(self.multi_dof))
        if self._shape_cache is None or self._shape_cache[0] != key:
            data = segment_to_dict(self)
            shapes = (message_shape(data["joint_trajectory"]), message_shape(data["multi_dof_joint_trajectory"]))
            self._shape_cache = (key, shapes)
        return self._shape_cache[1]

    @property
    def joint_trajectory(self) -> MessageShape:
        """The ``trajectory_msgs/JointTrajectory``-shaped snapshot (header, joint_names, points)."""
        return self._shapes()[0]

    @property
    def multi_dof_joint_trajectory(self) -> MessageShape:
        """The ``trajectory_msgs/MultiDOFJointTrajectory``-shaped snapshot (empty in the original's plans)."""
        return self._shapes()[1]


@dataclass
class ExecutionPlan:
    """Metadata and the segments C-M-C-M-... of a measurement plan."""

    metadata: dict = field(default_factory=dict)
    segments: list[PlanSegment] = field(default_factory=list)
    source: Path | None = None

    def __len__(self) -> int:
        return len(self.segments)

    @property
    def joint_names(self) -> list[str]:
        return list(self.segments[0].trajectory.joint_names) if self.segments else []

    @property
    def duration(self) -> float:
        """Sum of the segments' durations (s)."""
        return float(sum(s.trajectory.duration for s in self.segments))

    @property
    def start(self) -> np.ndarray:
        """Joint positions (rad) of the first point of the first segment."""
        if not self.segments:
            raise PlanError("the plan has no segments")
        return self.segments[0].trajectory.start

    def trajectories(self) -> list[JointTrajectory]:
        return [s.trajectory for s in self.segments]

    def measurements(self) -> list[PlanSegment]:
        return [s for s in self.segments if s.kind == MEASURE]

    def connections(self) -> list[PlanSegment]:
        return [s for s in self.segments if s.kind == CONNECT]


def kind_at(index: int) -> str:
    """Kind of the segment at ``index`` in the alternating C-M-C-M-... order."""
    return CONNECT if index % 2 == 0 else MEASURE


# ---------------------------------------------------------------------------------- dict conversions
def segment_from_dict(data: object, index: int = 0, kind: str | None = None) -> PlanSegment:
    """A segment from an expanded ``moveit_msgs/RobotTrajectory`` mapping; errors name segment ``index``."""
    where = f"segment {index}"
    if not isinstance(data, dict):
        raise PlanError(
            f"{where}: expected a RobotTrajectory mapping with 'joint_trajectory', got {type(data).__name__}"
        )
    if "joint_trajectory" not in data:
        raise PlanError(f"{where}: missing 'joint_trajectory' (keys: {sorted(map(str, data))})")
    joint = data["joint_trajectory"]
    if not isinstance(joint, dict):
        raise PlanError(f"{where}: 'joint_trajectory' must be a mapping, got {type(joint).__name__}")
    for key, kind_of in (("joint_names", list), ("points", list)):
        if not isinstance(joint.get(key), kind_of):
            raise PlanError(f"{where}: joint_trajectory.{key} must be a list, got {joint.get(key)!r:.80}")
    if not all(isinstance(n, str) for n in joint["joint_names"]):
        raise PlanError(f"{where}: joint_trajectory.joint_names must be strings")
    n = len(joint["joint_names"])
    for i, point in enumerate(joint["points"]):
        problem = _point_problem(point, n)
        if problem:
            raise PlanError(f"{where}: point {i}: {problem}")
    try:
        trajectory = JointTrajectory.from_dict(joint)
    except (TrajectoryError, ValueError, TypeError) as exc:
        raise PlanError(f"{where}: {exc}") from exc
    header = joint.get("header")
    if header is not None and not isinstance(header, dict):
        raise PlanError(f"{where}: joint_trajectory.header must be a mapping")
    multi_dof = data.get("multi_dof_joint_trajectory")
    if multi_dof is None:
        multi_dof = empty_multi_dof()
    elif not isinstance(multi_dof, dict):
        raise PlanError(f"{where}: 'multi_dof_joint_trajectory' must be a mapping")
    return PlanSegment(kind or kind_at(index), trajectory, copy.deepcopy(multi_dof), copy.deepcopy(header))


def _point_problem(point: object, n: int) -> str:
    if not isinstance(point, dict):
        return f"expected a mapping, got {type(point).__name__}"
    if "positions" not in point:
        return "missing 'positions'"
    if "time_from_start" not in point:
        return "missing 'time_from_start'"
    for key in ("positions", "velocities", "accelerations", "effort"):
        values = point.get(key)
        if values is None or (key != "positions" and values == []):
            continue
        if not isinstance(values, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in values
        ):
            return f"'{key}' must be a list of numbers, got {values!r:.80}"
        if len(values) != n:
            return f"'{key}' has {len(values)} values for {n} joints"
    stamp = point["time_from_start"]
    if isinstance(stamp, dict):
        if not all(isinstance(stamp.get(k, 0), int) and not isinstance(stamp.get(k, 0), bool) for k in stamp):
            return f"time_from_start must have integer secs and nsecs, got {stamp!r}"
        if set(stamp) - {"secs", "nsecs"} or not stamp:
            return f"time_from_start must be {{secs, nsecs}}, got {stamp!r}"
    elif not isinstance(stamp, int | float) or isinstance(stamp, bool):
        return f"time_from_start must be {{secs, nsecs}} or seconds, got {stamp!r}"
    return ""


def segment_to_dict(segment: PlanSegment | JointTrajectory, seq: int = 0) -> dict:
    """The expanded ``moveit_msgs/RobotTrajectory`` mapping of a segment (or of a bare trajectory)."""
    if isinstance(segment, JointTrajectory):
        segment = PlanSegment(CONNECT, segment)
    joint = segment.trajectory.to_dict(seq=seq)
    header = copy.deepcopy(segment.header) if segment.header else _default_header(segment.trajectory.frame_id)
    header["frame_id"] = segment.trajectory.frame_id
    header.setdefault("seq", seq)
    header.setdefault("stamp", {"nsecs": 0, "secs": 0})
    joint["header"] = header
    return {
        "joint_trajectory": joint,
        "multi_dof_joint_trajectory": copy.deepcopy(segment.multi_dof)
        if segment.multi_dof is not None
        else empty_multi_dof(),
    }


def message_to_dict(message: object) -> object:
    """A genpy ROS message (e.g. ``moveit_msgs/RobotTrajectory``) as the nested mapping rospy writes to YAML.

    Times and durations become ``{secs, nsecs}``; byte arrays and other sequences become lists.
    """
    # Times first: genpy.Time/Duration carry __slots__ too, but their state lives in the base class's slots.
    if hasattr(message, "secs") and hasattr(message, "nsecs"):
        return {"nsecs": int(message.nsecs), "secs": int(message.secs)}
    if hasattr(message, "__slots__") and hasattr(message, "_slot_types"):
        return {name: message_to_dict(getattr(message, name)) for name in message.__slots__}
    if isinstance(message, MessageShape):
        return {name: message_to_dict(value) for name, value in vars(message).items()}
    if isinstance(message, list | tuple):
        return [message_to_dict(v) for v in message]
    if isinstance(message, np.generic):
        return message.item()
    return message


def segment_from_message(message: object, index: int = 0, kind: str | None = None) -> PlanSegment:
    """A segment from a ``moveit_msgs/RobotTrajectory`` message (anything with ``joint_trajectory``)."""
    if not hasattr(message, "joint_trajectory"):
        raise PlanError(f"segment {index}: a RobotTrajectory message needs 'joint_trajectory'")
    multi_dof = getattr(message, "multi_dof_joint_trajectory", None)
    data = {
        "joint_trajectory": message_to_dict(message.joint_trajectory),
        "multi_dof_joint_trajectory": empty_multi_dof() if multi_dof is None else message_to_dict(multi_dof),
    }
    return segment_from_dict(data, index, kind)


def plan_to_dicts(plan: ExecutionPlan) -> list:
    """The plan as the YAML document's list: metadata first, then one RobotTrajectory mapping per segment."""
    return [_plain(plan.metadata, "metadata"), *(segment_to_dict(s) for s in plan.segments)]


def plan_from_dicts(document: object, source: str | Path | None = None) -> ExecutionPlan:
    """A plan from the loaded YAML document (list: metadata mapping, then RobotTrajectory mappings)."""
    where = f"{source}: " if source is not None else ""
    if not isinstance(document, list):
        raise PlanError(
            f"{where}an execution plan must be a YAML list (metadata, then segments), got "
            f"{type(document).__name__ if document is not None else 'an empty document'}"
        )
    if not document:
        raise PlanError(f"{where}the execution plan is an empty list: no metadata entry")
    metadata = document[0]
    if not isinstance(metadata, dict) or "joint_trajectory" in metadata:
        raise PlanError(
            f"{where}the first entry must be the metadata mapping (e.g. {{Timestamp: ...}}), got "
            + ("a segment" if isinstance(metadata, dict) else type(metadata).__name__)
        )
    segments = []
    for index, entry in enumerate(document[1:]):
        try:
            segments.append(segment_from_dict(entry, index))
        except PlanError as exc:
            raise PlanError(f"{where}{exc}") from exc
    return ExecutionPlan(copy.deepcopy(metadata), segments, Path(source) if source is not None else None)


def _plain(value: object, where: str, converted: dict | None = None) -> object:
    """``value`` with numpy scalars/arrays, tuples and paths turned into what ``yaml.safe_dump`` writes.

    A mapping or list met twice (a loaded file's anchors and aliases) is converted once and shared, so the dumper
    writes an anchor and aliases again: metadata is kept as loaded, never expanded (an alias bomb stays small)."""
    converted = {} if converted is None else converted
    if isinstance(value, dict | list | tuple) and id(value) in converted:
        return converted[id(value)][1]
    if isinstance(value, dict):
        out: dict = {}
        converted[id(value)] = (value, out)
        for k, v in value.items():
            out[_plain(k, where, converted)] = _plain(v, f"{where}.{k}", converted)
        return out
    if isinstance(value, list | tuple):
        items: list = []
        converted[id(value)] = (value, items)
        items.extend(_plain(v, f"{where}[{i}]", converted) for i, v in enumerate(value))
        return items
    if isinstance(value, np.ndarray):
        return _plain(value.tolist(), where)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise PlanError(f"{where}: cannot write a {type(value).__name__} to YAML; use numbers, strings, lists, dicts")


def as_segments(plan_or_segments: object) -> list[PlanSegment]:
    if isinstance(plan_or_segments, ExecutionPlan):
        return list(plan_or_segments.segments)
    if isinstance(plan_or_segments, dict | str | bytes) or not isinstance(plan_or_segments, Sequence):
        raise PlanError(
            "expected an ExecutionPlan or a list of segments (PlanSegment, JointTrajectory, RobotTrajectory "
            f"mapping or message), got {type(plan_or_segments).__name__}"
        )
    segments = []
    for index, item in enumerate(plan_or_segments):
        if isinstance(item, PlanSegment):
            segments.append(item)
        elif isinstance(item, JointTrajectory):
            segments.append(PlanSegment(kind_at(index), item))
        elif isinstance(item, dict):
            segments.append(segment_from_dict(item, index))
        elif hasattr(item, "joint_trajectory"):
            segments.append(segment_from_message(item, index))
        else:
            raise PlanError(f"segment {index}: cannot store a {type(item).__name__} as a plan segment")
    return segments


# ---------------------------------------------------------------------------------------------- files
def plan_path(path: str | Path) -> Path:
    """``path`` with the ``.yaml`` suffix added unless it already ends in ``.yaml`` or ``.yml``."""
    path = Path(path)
    if path.suffix.lower() in PLAN_SUFFIXES:
        return path
    return path.with_name(path.name + ".yaml")


def load_execution_plan(path: str | Path) -> ExecutionPlan:
    """Read an execution plan file (``yaml.safe_load`` semantics).

    Raises:
        PlanFileNotFoundError: the file does not exist.
        PlanError: malformed YAML or wrong structure; the message names the file and the segment index.
    """
    path = Path(path)
    if not path.exists():
        raise PlanFileNotFoundError(f"{path}: execution plan file not found")
    if not path.is_file():
        raise PlanError(f"{path}: is a directory, not a plan file" if path.is_dir() else f"{path}: not a file")
    try:
        document = read_yaml(path, loader=_Loader)
    except ConfigError as exc:
        raise PlanError(str(exc)) from exc
    return plan_from_dicts(document, path)


def dump_execution_plan(plan_or_segments: object, metadata: Mapping | None = None) -> str:
    """The YAML text :func:`store_execution_plan` writes (same style as the original: block, sorted keys)."""
    segments = as_segments(plan_or_segments)
    merged = dict(plan_or_segments.metadata) if isinstance(plan_or_segments, ExecutionPlan) else {}
    if metadata is not None:
        if not isinstance(metadata, Mapping):
            raise PlanError(f"metadata must be a mapping, got {type(metadata).__name__}")
        merged.update(metadata)
    document = plan_to_dicts(ExecutionPlan(merged, segments))
    return yaml.dump(document, Dumper=_Dumper, default_flow_style=False, sort_keys=True, allow_unicode=True)


def store_execution_plan(path: str | Path, plan_or_segments: object, metadata: Mapping | None = None) -> Path:
    """Write an execution plan that :func:`load_execution_plan` (and the original) can read.

    Args:
        path: the file written, exactly as given (as the original's ``store_execution_plan``); callers that
            want the ``.yaml`` suffix added apply :func:`plan_path` first (the CLI and the node do).
        plan_or_segments: an :class:`ExecutionPlan`, or a list of segments in C-M-C-M-... order
            (:class:`PlanSegment`, :class:`JointTrajectory`, RobotTrajectory mappings or messages).
        metadata: entries for the metadata mapping, merged over the plan's own.

    Returns:
        The path written.

    The file is replaced atomically: written to a temporary file in the same directory, then renamed, so a
    reader never sees a half-written plan and a failure leaves any previous file untouched.
    """
    target = Path(path)
    directory = target.parent
    if not directory.is_dir():
        raise PlanError(f"{target}: directory {directory} does not exist")
    if target.is_dir():
        raise PlanError(f"{target}: is a directory")
    text = dump_execution_plan(plan_or_segments, metadata)
    try:
        atomic_write_text(target, text)
    except OSError as exc:
        raise PlanError(f"{target}: cannot write: {exc}") from exc
    return target


# ----------------------------------------------------------------------------------------- validation
def validate_execution_plan(
    plan: ExecutionPlan,
    limits: JointLimits,
    joint_names: Sequence[str] | None = None,
    continuity_tolerance_rad: float = 1e-3,
    start_state: np.ndarray | Mapping[str, float] | None = None,
    tolerances: CheckTolerances | None = None,
    rest_tolerance_rad_s: float = 1e-3,
) -> CheckResult:
    """Check that the plan can be executed segment by segment.

    Checks: at least one segment; kinds alternate C-M-C-M-...; every segment has exactly ``joint_names``
    (default: the limits'); no multi-DOF points; every segment passes :func:`check_trajectory` (the first also
    against ``start_state``, rad, when given); every segment starts and ends at rest (|v| <=
    ``rest_tolerance_rad_s``, since each segment is executed as its own goal); consecutive segments are
    continuous within ``continuity_tolerance_rad``. The reason names the failing segment index.
    """
    expected = list(joint_names) if joint_names is not None else list(limits.names)
    tolerances = tolerances or CheckTolerances()
    if sorted(expected) != sorted(limits.names):
        return CheckResult(False, f"joint names {expected} do not match the limits' joints {list(limits.names)}")
    if not isinstance(plan, ExecutionPlan):
        return CheckResult(False, f"expected an ExecutionPlan, got {type(plan).__name__}")
    if not plan.segments:
        return CheckResult(False, "the plan has no segments")
    current = None
    if start_state is not None:
        try:
            current = _state_vector(start_state, list(limits.names))
        except PlanError as exc:
            return CheckResult(False, f"start state: {exc}")
    previous = None
    for index, segment in enumerate(plan.segments):
        label = f"segment {index} ({segment.kind})"
        if segment.kind != kind_at(index):
            return CheckResult(
                False,
                f"{label}: expected a {kind_at(index)} segment here (segments alternate connect-measure-...)",
            )
        trajectory = segment.trajectory
        if sorted(trajectory.joint_names) != sorted(expected) or len(set(trajectory.joint_names)) != len(expected):
            return CheckResult(False, f"{label}: joint names {trajectory.joint_names}, expected {expected}")
        if (segment.multi_dof or {}).get("points"):
            return CheckResult(False, f"{label}: multi-DOF joint trajectories are not supported (it has points)")
        verdict = check_trajectory(trajectory, limits, current if index == 0 else None, tolerances)
        if not verdict:
            return CheckResult(False, f"{label}: {verdict.reason}")
        ordered = trajectory.reordered(list(limits.names))
        velocities = ordered.knot_velocities()
        for where, row in (("start", 0), ("end", -1)):
            speed = np.abs(velocities[row])
            if np.any(speed > rest_tolerance_rad_s):
                j = int(np.argmax(speed))
                return CheckResult(
                    False,
                    f"{label}: does not {where} at rest: {limits.names[j]} moves at {speed[j]:.4f} rad/s "
                    f"(tolerance {rest_tolerance_rad_s} rad/s)",
                )
        if previous is not None:
            verdict = check_continuity(previous, trajectory, continuity_tolerance_rad)
            if not verdict:
                return CheckResult(False, f"between segment {index - 1} and segment {index}: {verdict.reason}")
        previous = trajectory
    return CheckResult(True)


def _state_vector(state: np.ndarray | Mapping[str, float], joint_names: list[str]) -> np.ndarray:
    if isinstance(state, Mapping):
        missing = [n for n in joint_names if n not in state]
        if missing:
            raise PlanError(f"lacks joints {missing}")
        state = [state[n] for n in joint_names]
    try:
        vector = np.asarray(state, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PlanError(f"expected {len(joint_names)} joint values (rad), got {state!r}") from exc
    if vector.shape != (len(joint_names),):
        raise PlanError(f"expected {len(joint_names)} joint values (rad), got shape {vector.shape}")
    if not np.all(np.isfinite(vector)):
        raise PlanError("joint values must be finite")
    return vector


# --------------------------------------------------------------------------------------- adaptation
def adapt_to_current_start_pose(
    plan: ExecutionPlan,
    current_q: np.ndarray | Mapping[str, float],
    planner_fn: Callable[[np.ndarray, np.ndarray], JointTrajectory],
    tolerance_rad: float = START_TOLERANCE_RAD,
    mode: str = "prepend",
) -> ExecutionPlan:
    """A copy of ``plan`` that starts at the current joint state ``current_q`` (rad, plan's joint order, or a
    name -> value mapping).

    ``planner_fn(start_q, goal_q)`` returns a :class:`JointTrajectory` from ``start_q`` to ``goal_q`` (rad,
    in the plan's joint order), at rest at both ends; the lead plugs in the OMPL planner plus time
    parameterisation. Modes:

    - ``'prepend'``: plan a motion from ``current_q`` to the plan's first point and put it in front of the
      first connection segment (merged into it, so the plan stays C-M-C-M-...; the stored connection path is
      kept as it was planned and checked).
    - ``'replace'``: replace the first connection segment by a motion from ``current_q`` straight to where it
      ended (the start of the first measurement).

    When ``current_q`` already equals the start within ``tolerance_rad``, the plan is returned unchanged
    (copied). A plan that starts with a measurement gets a new connection segment in front.

    Raises:
        PlanError: empty plan, bad ``current_q``, or a planned motion that does not start at ``current_q`` /
            end at the goal within ``tolerance_rad``.
    """
    if mode not in ("prepend", "replace"):
        raise PlanError(f"mode must be 'prepend' or 'replace', got {mode!r}")
    if not plan.segments:
        raise PlanError("the plan has no segments to adapt")
    names = plan.joint_names
    current = _state_vector(current_q, names)
    segments = [copy.deepcopy(s) for s in plan.segments]
    adapted = ExecutionPlan(copy.deepcopy(plan.metadata), segments, plan.source)
    first = segments[0]
    first_traj = first.trajectory.reordered(names)
    if first.kind == CONNECT and mode == "replace":
        goal = first_traj.end
        if np.all(np.abs(first_traj.start - current) <= tolerance_rad):
            return adapted
        motion = _planned(planner_fn, current, goal, names, tolerance_rad)
        segments[0] = PlanSegment(CONNECT, motion, copy.deepcopy(first.multi_dof), copy.deepcopy(first.header))
        return adapted
    goal = first_traj.start
    if np.all(np.abs(goal - current) <= tolerance_rad):
        return adapted
    motion = _planned(planner_fn, current, goal, names, tolerance_rad)
    if first.kind == CONNECT:
        try:
            merged = motion.concatenated(first_traj, tolerance_rad=tolerance_rad)
        except TrajectoryError as exc:
            raise PlanError(f"cannot join the planned motion to segment 0: {exc}") from exc
        merged.frame_id = first.trajectory.frame_id
        segments[0] = PlanSegment(CONNECT, merged, copy.deepcopy(first.multi_dof), copy.deepcopy(first.header))
    else:
        motion.frame_id = first.trajectory.frame_id
        segments.insert(0, PlanSegment(CONNECT, motion))
    return adapted


def _planned(planner_fn, start: np.ndarray, goal: np.ndarray, names: list[str], tolerance_rad: float):
    motion = planner_fn(start.copy(), goal.copy())
    if not isinstance(motion, JointTrajectory):
        raise PlanError(f"planner_fn must return a JointTrajectory, got {type(motion).__name__}")
    if len(motion) == 0:
        raise PlanError("planner_fn returned an empty trajectory")
    try:
        motion = motion.reordered(names)
    except TrajectoryError as exc:
        raise PlanError(f"planner_fn returned a trajectory with other joints: {exc}") from exc
    for label, point, wanted in (("start", motion.start, start), ("end", motion.end, goal)):
        gap = np.abs(point - wanted)
        if np.any(gap > tolerance_rad):
            j = int(np.argmax(gap))
            raise PlanError(
                f"planner_fn's motion does not {label} where asked: {names[j]} is off by {gap[j]:.4f} rad "
                f"(tolerance {tolerance_rad} rad)"
            )
    return motion
