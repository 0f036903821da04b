"""The state of one planning run, and the tools its stages work with.

:class:`PlanningRun` holds everything a run produces and its stages share (samples, candidates, the coverage
store, the views and their verification, the cover, the order, timings, warnings); :class:`Reserve` holds the
dominated candidates the evaluation dropped and their revival. :class:`PlanningTools` names the collaborators a
stage uses (kinematics, IK, collision world, sensor model, the connection planner, the progress report).
:class:`RunField` lets the facade expose a run attribute under its documented name. Points are mm, joints rad,
times s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.planning.deadline import StageClock
from agiprobot_measurement.planning.errors import PlanningInputError

__all__ = ["DEFAULT_MECHANICS", "PlanningRun", "PlanningTools", "Reserve", "RunField", "joint_state"]

#: the scan-line settings of the lazy verification before a generation sets its own
DEFAULT_MECHANICS = {
    "minimum_required_overmeasure": 5.0,
    "trajectory_sample_step": 2.0,
    "joint_jump_threshold": 1.5,
    "minimum_trajectory_length": 25.0,
    "plan_path_to_check_reachability": False,
}


def _no_entries() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


def _no_flags() -> np.ndarray:
    return np.zeros(0, dtype=bool)


@dataclass
class Reserve:
    """Dominated candidates the evaluation dropped, each with the store column of its dominator.

    ``candidates``: candidate indices; ``dominator_column``: each one's dominator; ``revived``: evaluated again;
    ``checked``: store columns already looked at for revival; ``failed_dominator``: those rejected or shortened;
    ``shelf``: views evaluated again but not needed yet (every point they measure has another view).
    """

    candidates: np.ndarray = field(default_factory=_no_entries)
    dominator_column: np.ndarray = field(default_factory=_no_entries)
    revived: np.ndarray = field(default_factory=_no_flags)
    checked: np.ndarray = field(default_factory=_no_flags)
    failed_dominator: np.ndarray = field(default_factory=_no_flags)
    shelf: list = field(default_factory=list)


@dataclass
class PlanningRun:
    """What one planning run holds between its stages (the facade's documented attributes among them)."""

    part: object = None
    target_mesh: object = None
    #: while a plan runs: its time limit (checked between the chunks of the stages before the set cover)
    clock: StageClock | None = None
    samples: object = None
    sampled_surface_points: list = field(default_factory=list)
    candidates: object = None
    #: the coverage store: the measurability of the kept candidates (points x views, sparse)
    measurability: object = None
    last_set_cover: object = None
    last_viewpoints: list = field(default_factory=list)
    last_ordered: list = field(default_factory=list)
    unconnected_views: list = field(default_factory=list)
    #: the views left out of the plan and why: [{"view": label, "reason": text}] (a failed move, never an error)
    dropped_views: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)
    parameters: dict = field(default_factory=dict)
    mechanics_checked: int = 0
    #: doubts about the run the caller should hear of (low reachability, time limit hit, ...)
    warnings: list = field(default_factory=list)
    #: share of samples with at least one reachable candidate anchor (after sampling)
    reachable_share: float | None = None
    time_limit_hit: bool = False
    #: the share of the reachable candidates the metrology evaluated (below 1: the time limit cut it)
    candidates_evaluated_share: float = 1.0
    revived_views: int = 0
    #: what the last candidate evaluation did (candidates, kept pairs, chunks, projection, times)
    last_stream_stats: object = None
    last_work_estimate: object = None
    last_plan_path: object = None
    loaded_plan: object = None
    #: the scan-line settings of the lazy verification (set by the generation)
    mechanics: dict = field(default_factory=lambda: dict(DEFAULT_MECHANICS))
    #: the generation's views, the store's columns in order (revived views join ``last_viewpoints`` only)
    generation_views: list | None = None
    #: per store entry: still measurable by a view that may be executable
    entry_alive: np.ndarray | None = None
    #: per sample: some reachable candidate measures it (metrologically)
    metrology_coverable: np.ndarray | None = None
    #: per store column: duration (s; verified or estimated), the first estimate, whether verified
    durations: np.ndarray | None = None
    durations_estimate: np.ndarray | None = None
    duration_verified: np.ndarray | None = None
    #: estimates are scaled by this (the worst verified / estimated ratio) so they are not optimistic
    duration_bias: float = 1.0
    #: (uncertainty threshold mm, maximum deflection) of the evaluation, for evaluating dropped candidates again
    evaluation_limits: tuple = (0.0, 0.0)
    #: id(view) -> (view, joint path rad) of checked scan lines whose trajectory is not computed yet
    pending_scan_paths: dict = field(default_factory=dict)
    reserve: Reserve = field(default_factory=Reserve)

    def snapshot(self) -> PlanningRun:
        """A copy whose timings, parameters and warnings are its own (the rest is replaced, not changed, by a
        later generation)."""
        copy = PlanningRun(**self.__dict__)
        copy.timings_s, copy.parameters, copy.warnings = (
            dict(self.timings_s),
            dict(self.parameters),
            list(self.warnings),
        )
        return copy

    def add_time(self, key: str, seconds: float) -> None:
        """Add ``seconds`` to the timing ``key``."""
        self.timings_s[key] = self.timings_s.get(key, 0.0) + seconds

    def warn(self, message: str, log) -> None:
        """Log ``message`` as a warning and keep it in :attr:`warnings`."""
        log.warning("%s", message)
        self.warnings.append(message)


@dataclass
class PlanningTools:
    """The collaborators of a run's stages: the robot (``kinematics``, ``ik``, ``limits``, ``collision``), the
    ``sensor_model``, the states (rad) a scan line prefers and starts from, the scan speed (mm/s), ``connect``
    (``(q_from, q_to, planning_time_s) -> trajectory | None``) and ``report`` (``(stage, fraction, message)``)."""

    kinematics: object
    ik: object
    limits: object
    collision: object
    sensor_model: object
    preferred_state: np.ndarray
    current_state: np.ndarray
    scan_speed_mm_s: float
    connect: Callable
    report: Callable[[str, float, str], None]


class RunField:
    """A facade attribute that reads and writes the same-named (or ``name``) attribute of its ``run``."""

    def __init__(self, name: str | None = None):
        self.name = name

    def __set_name__(self, owner, name: str) -> None:
        self.name = self.name or name

    def __get__(self, obj, owner=None):
        return self if obj is None else getattr(obj.run, self.name)

    def __set__(self, obj, value) -> None:
        setattr(obj.run, self.name, value)


def joint_state(named_states: dict, dof: int, value) -> np.ndarray:
    """A joint state (rad): one of the station's ``named_states`` by name, or ``dof`` finite values."""
    if isinstance(value, str):
        if value not in named_states:
            raise ConfigError(f"unknown named state '{value}'; known: {', '.join(named_states)}")
        return named_states[value].copy()
    state = np.asarray(value, dtype=float)
    if state.shape != (dof,) or not np.all(np.isfinite(state)):
        raise PlanningInputError(f"a joint state needs {dof} finite values")
    return state
