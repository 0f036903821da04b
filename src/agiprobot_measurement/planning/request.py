"""The planning request: one place for its defaults and its validation.

:class:`PlanRequest` holds everything a planning run needs (the part, the sampling, the solver, the mechanics
settings). Its defaults come from ``config/trajectory_manager.yaml`` (section ``planning``); the trajectory_manager
node maps an action goal onto it, ``scripts/plan_measurement.py`` its command line, and
:meth:`TrajectoryManager.plan_request <agiprobot_measurement.planning.trajectory_manager.TrajectoryManager>` runs it.
:meth:`PlanRequest.validate` checks every field before any work starts and raises :class:`PlanRequestError`
(an :class:`~agiprobot_measurement.errors.InputError`) whose message names the field.

This module is light on purpose (numpy and YAML only): bad input is reported before trimesh, FCL and OMPL load.
Lengths are mm, angles rad, times s, densities points/mm^2.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common import config
from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.common.limits import LIMITS, check_file_size, local_worker_limit
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.candidates.viewpoint import TILT_MODES, TILT_STEPS
from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES
from agiprobot_measurement.planning.errors import PlanningTypeError, validated
from agiprobot_measurement.station.placement import PLACEMENTS

__all__ = [
    "DEFAULTS_FILE",
    "PLACEMENTS",
    "REQUEST_TILT_MODES",
    "PlanRequest",
    "PlanRequestError",
    "WorkBudget",
    "WorkEstimate",
    "WorkTooLarge",
    "check_choice",
    "check_positive",
    "estimate_work",
    "load_planning_defaults",
    "load_work_budget",
]

#: the tilt modes of a request: the viewpoint generator's, and ``auto`` (tilt none first, then limited / full
#: when the cover is large or coverage short; the choice is reported)
REQUEST_TILT_MODES = (*TILT_MODES, "auto")

#: the file holding the defaults of every request field (section ``planning``)
DEFAULTS_FILE = CONFIG_DIR / "trajectory_manager.yaml"


class PlanRequestError(InputError):
    """A planning request field is invalid; ``field`` names it, the message says why."""

    def __init__(self, field_name: str, message: str):
        super().__init__(message)
        self.field = field_name


def _validated(check, field_name: str, message: str):
    """``check()`` (a :mod:`~agiprobot_measurement.common.config` validator's call), its ConfigError turned into a
    :class:`PlanRequestError` of ``field_name`` saying ``message``."""
    return validated(check, functools.partial(PlanRequestError, field_name), message)


def check_positive(value, field_name: str, label: str | None = None) -> float:
    """``value`` as a finite positive float, else :class:`PlanRequestError` naming ``label`` (default: the field)."""
    message = f"{label or field_name} must be a positive number, got {value}"
    return _validated(lambda: config.positive(value, field_name), field_name, message)


def check_choice(value, valid: Iterable[str], field_name: str, label: str | None = None) -> str:
    """``value`` if it is one of ``valid``, else :class:`PlanRequestError` listing the valid names (and the
    nearest one)."""
    valid = list(valid)
    if value in valid:
        return value
    hint = difflib.get_close_matches(str(value), valid, n=1)
    suggestion = f"; did you mean {hint[0]!r}?" if hint else ""
    raise PlanRequestError(
        field_name, f"unknown {label or field_name} {value!r}; valid: {', '.join(valid)}{suggestion}"
    )


def _looks_like_address(text: str) -> bool:
    """``[protocol://]host:port`` with a port number (Dask's tcp, tls, ucx, inproc addresses)."""
    rest = text.split("://", 1)[1] if "://" in text else text
    host, _, port = rest.rpartition(":")
    return bool(host) and port.isdigit() and 0 < int(port) < 65536 and not any(c.isspace() for c in rest)


def load_planning_defaults(path: str | Path | None = None) -> dict:
    """The ``planning`` section of ``config/trajectory_manager.yaml`` (or of ``path``)."""
    path = Path(path) if path is not None else DEFAULTS_FILE
    data = read_yaml(path)
    section = data.get("planning", {}) if isinstance(data, dict) else None
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: 'planning' must be a mapping")
    return dict(section)


class WorkTooLarge(PlanRequestError):
    """A request would cause more work than the configured budget allows; the message gives both."""


#: the planner draws this many random points per sample before thinning them (``PartModel.sample``)
SAMPLING_OVERSAMPLING = 5
#: the surface one candidate view can measure at most (mm^2): the laser line's width times a long scan line; the
#: measurability entries of a view are bounded by the samples on it
VIEW_FOOTPRINT_MM2 = 150.0 * 150.0
#: bytes per random point while sampling (point, normal, face), per candidate (4x4 pose and its indices) and per
#: kept measurability entry (point index int32, uncertainty and trajectory distance float64: the streamed store)
BYTES_PER_DRAWN_POINT = 3 * 8 + 3 * 8 + 8
BYTES_PER_CANDIDATE = 16 * 8 + 3 * 8
BYTES_PER_ENTRY = 4 + 8 + 8
#: largest local Dask cluster a request may ask for on any machine (worker processes); the machine's own bound,
#: :func:`~agiprobot_measurement.common.limits.local_worker_limit`, is usually lower
MAX_LOCAL_WORKERS = 256
#: memory of one local Dask worker process before any work (interpreter, numpy, trimesh, the sensor model; measured
#: 95 to 140 MB proportional set size per worker with 8 and 32 workers)
WORKER_PROCESS_BYTES = 150e6


@dataclass(frozen=True)
class WorkEstimate:
    """The largest work a planning run may cause, known before anything is allocated: ``samples`` (area x
    density), ``candidates`` (samples x orientations x tilts), ``measurability_entries`` (an upper bound:
    candidates x the samples one view can see) and ``memory_gb``, the dense arrays of samples and candidates.
    The measurability store is streamed: its size is projected from a pilot of the candidates and checked
    against the run's memory budget (``max_memory_gb``) before the evaluation
    (:func:`~agiprobot_measurement.planning.candidates.streaming.evaluate_streaming`)."""

    area_mm2: float
    samples: float
    candidates: float
    measurability_entries: float
    memory_gb: float

    def describe(self) -> str:
        return (
            f"{_count(self.samples)} samples ({_count(self.area_mm2)} mm^2 x density), {_count(self.candidates)} "
            f"candidate viewpoints, at most {_count(self.measurability_entries)} measurability entries, "
            f"~{_count(self.memory_gb, 2)} GB"
        )


def _count(value: float, decimals: int = 0) -> str:
    """A count for a message: digits grouped up to a trillion, then in exponent notation."""
    return f"{value:,.{decimals}f}" if abs(value) < 1e12 else f"{value:.3g}"


def estimate_work(
    area_mm2: float, sampling_density: float, orientations_around_boresight: int, viewpoint_tilt_mode: str
) -> WorkEstimate:
    """The :class:`WorkEstimate` of sampling ``area_mm2`` at ``sampling_density`` points/mm^2 with that many
    orientations and tilts (floats: a hostile density must not overflow an integer)."""
    samples = float(area_mm2) * float(sampling_density)
    tilts = 1 if viewpoint_tilt_mode == "none" else len(TILT_STEPS)  # auto: at most full
    candidates = samples * float(orientations_around_boresight) * tilts
    per_view = min(samples, float(sampling_density) * VIEW_FOOTPRINT_MM2)
    entries = candidates * per_view
    memory = samples * SAMPLING_OVERSAMPLING * BYTES_PER_DRAWN_POINT + candidates * BYTES_PER_CANDIDATE
    return WorkEstimate(float(area_mm2), samples, candidates, entries, memory / 1e9)


@dataclass(frozen=True)
class WorkBudget:
    """The most work one planning run may cause (section ``budget`` of ``config/trajectory_manager.yaml``)."""

    max_samples: float = 1_000_000
    max_candidates: float = 20_000_000
    max_memory_gb: float = 8.0

    @classmethod
    def from_mapping(cls, data: Mapping | None, where: str = "budget") -> WorkBudget:
        """A budget from a mapping (missing keys keep the defaults); unknown keys or non-positive values raise
        :class:`~agiprobot_measurement.common.config.ConfigError` naming ``where`` and the key."""
        data = dict(data or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; valid: {', '.join(sorted(names))}")
        values = {}
        for key, value in data.items():
            values[key] = config.positive(value, f"{where}.{key}")
        return cls(**values)

    def check(self, estimate: WorkEstimate) -> WorkEstimate:
        """``estimate`` if it fits, else :class:`WorkTooLarge` with the estimate and the exceeded budget."""
        for field_name, value, limit, what in (
            ("sampling_density", estimate.samples, self.max_samples, "max_samples"),
            ("orientations_around_boresight", estimate.candidates, self.max_candidates, "max_candidates"),
            ("sampling_density", estimate.memory_gb, self.max_memory_gb, "max_memory_gb"),
        ):
            if not value <= limit:
                raise WorkTooLarge(
                    field_name,
                    f"request refused before any work: it needs {estimate.describe()}; beyond the budget "
                    f"{what} = {limit:,.10g} (config/trajectory_manager.yaml, section budget); lower "
                    "sampling_density, orientations_around_boresight or the tilt mode",
                )
        return estimate


def load_work_budget(path: str | Path | None = None) -> WorkBudget:
    """The ``budget`` section of ``config/trajectory_manager.yaml`` (or of ``path``)."""
    path = Path(path) if path is not None else DEFAULTS_FILE
    data = read_yaml(path)
    section = data.get("budget", {}) if isinstance(data, dict) else None
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: 'budget' must be a mapping")
    return WorkBudget.from_mapping(section, f"{path}: budget")


#: keyword argument of ``TrajectoryManager`` -> the request field that sets it
MANAGER_ARGUMENTS = {
    "scan_speed_mm_s": "scan_speed_mm_s",
    "seed": "seed",
    "workers": "workers",
    "scheduler": "scheduler",
}
#: keyword argument of ``TrajectoryManager.load_target_mesh`` -> request field
PART_ARGUMENTS = {
    "transform": "part_transform_mm",
    **{name: name for name in ("add_wbk_mirrors", "units", "placement", "tessellation_tolerance_mm")},
}
#: keyword argument of ``TrajectoryManager.plan`` -> request field
PLAN_ARGUMENTS = {
    **{name: name for name in ("sampling_density", "orientations_around_boresight", "viewpoint_tilt_mode")},
    **{name: name for name in ("solver_type", "set_cover_time_limit_s", "time_limit_s", "min_reachable_share")},
    "uncertainty_threshold": "uncertainty_threshold_mm",
    "min_planning_time": "min_planning_time_s",
    "minimum_trajectory_length": "minimum_trajectory_length_mm",
    "trajectory_sample_step": "trajectory_sample_step_mm",
    "minimum_required_overmeasure": "minimum_required_overmeasure_mm",
    "joint_jump_threshold": "joint_jump_threshold_rad",
    "mip_gap": "set_cover_mip_gap",
}


@dataclass
class PlanRequest:
    """One planning run. Field names are those of the configuration file and the PlanMeasurement goal.

    ``part_transform_mm``: 4x4 placement of the part's CAD frame relative to the scene file's part pose
    (translation mm). ``plan_file``: where to store the plan ('' = not stored); ``overwrite``: replace an
    existing plan file of that name (else the request is refused before planning).
    ``time_limit_s``: the whole plan's wall-clock budget (s): the set cover / verification loop stops in time
    and returns the best verified plan with its optimality gap; ``set_cover_time_limit_s`` bounds one IP solve
    inside it. ``set_cover_mip_gap``: the relative optimality gap at which an IP solve may stop.
    ``placement``: one of :data:`PLACEMENTS`. ``min_reachable_share``: below this share of samples with a
    reachable anchor a warning suggests another placement or tilts. ``tessellation_tolerance_mm``: the linear
    deflection of STEP tessellation (0 = the reader's default).
    ``workers``: evaluate the candidates on a local Dask cluster of that many worker processes (0 = in the
    planning process); ``scheduler``: ... or on the existing Dask cluster at this address (``tcp://host:8786``,
    '' = none; it overrides ``workers``); ``max_memory_gb``: the memory budget of the evaluation's store (0 = 80 %
    of the memory available). The plan does not depend on these three.
    """

    part_file: str = ""
    units: str = "mm"
    sampling_density: float = 0.03
    orientations_around_boresight: int = 12
    viewpoint_tilt_mode: str = "none"
    solver_type: str = "IP_basic"
    uncertainty_threshold_mm: float = 0.1
    minimum_trajectory_length_mm: float = 25.0
    trajectory_sample_step_mm: float = 2.0
    minimum_required_overmeasure_mm: float = 5.0
    joint_jump_threshold_rad: float = 1.5
    scan_speed_mm_s: float = 50.0
    min_planning_time_s: float = 0.2
    set_cover_time_limit_s: float = 60.0
    add_wbk_mirrors: bool = True
    seed: int = 0
    part_transform_mm: np.ndarray = field(default_factory=lambda: np.eye(4))
    plan_file: str = ""
    overwrite: bool = False
    time_limit_s: float = 300.0
    set_cover_mip_gap: float = 0.02
    placement: str = "scene"
    min_reachable_share: float = 0.3
    tessellation_tolerance_mm: float = 0.0
    workers: int = 0
    scheduler: str = ""
    max_memory_gb: float = 0.0

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def from_defaults(cls, defaults: Mapping | None = None, **overrides) -> PlanRequest:
        """A request from a defaults mapping (default: the configuration file) with ``overrides`` on top.
        Overrides that are None, '' or 0 mean 'not given' and keep the default, as in an action goal.
        Unknown keys in ``defaults`` are ignored (the node's parameter namespace may hold more)."""
        if defaults is None:
            defaults = load_planning_defaults()
        names = set(cls.field_names())
        values = {k: v for k, v in dict(defaults).items() if k in names}
        for key, value in overrides.items():
            if key not in names:
                raise PlanningTypeError(f"PlanRequest has no field {key!r}")
            if value is None or (not isinstance(value, np.ndarray) and not value and value is not False):
                continue
            values[key] = value
        return cls(**values)

    def work_estimate(self, area_mm2: float) -> WorkEstimate:
        """The largest work this (validated) request causes on a part of ``area_mm2`` measurable mm^2."""
        return estimate_work(
            area_mm2, self.sampling_density, self.orientations_around_boresight, self.viewpoint_tilt_mode
        )

    def manager_settings(self) -> dict:
        """The ``TrajectoryManager`` keyword arguments this (validated) request sets."""
        memory = self.max_memory_gb * 1e9 if self.max_memory_gb else None
        return {**self._arguments(MANAGER_ARGUMENTS), "max_memory_bytes": memory}

    def part_arguments(self) -> dict:
        """The ``TrajectoryManager.load_target_mesh`` keyword arguments of this (validated) request's part."""
        return self._arguments(PART_ARGUMENTS)

    def plan_arguments(self) -> dict:
        """The ``TrajectoryManager.plan`` keyword arguments of this (validated) request."""
        return self._arguments(PLAN_ARGUMENTS)

    def _arguments(self, table: dict[str, str]) -> dict:
        return {argument: getattr(self, field_name) for argument, field_name in table.items()}

    def validate(self, base_dir: str | Path | None = None, labels: Mapping[str, str] | None = None) -> PlanRequest:
        """Check every field; return a copy with typed values and ``part_file`` resolved against ``base_dir``
        (default: the working directory). ``labels`` names fields in messages the caller's way (a CLI's
        option names); by default a message names the field itself. Raises :class:`PlanRequestError`."""
        labels = dict(labels or {})

        def label(name):
            return labels.get(name, name)

        if not self.part_file:
            raise PlanRequestError("part_file", f"no {label('part_file')} given and no default configured")
        part = Path(self.part_file).expanduser()
        if base_dir is not None and not part.is_absolute():
            part = Path(base_dir) / part
        if part.is_dir():
            raise PlanRequestError("part_file", f"{label('part_file')} is a directory, not a mesh file: {part}")
        if not part.exists():
            raise PlanRequestError("part_file", f"part file not found: {part}")
        if not part.is_file():
            raise PlanRequestError("part_file", f"part is not a regular file: {part}")
        # refused before the readers are even imported (the part loader checks it again)
        step = part.suffix.lower() in (".step", ".stp")
        check_file_size(
            part, LIMITS.step_file_bytes if step else LIMITS.mesh_file_bytes, "STEP file" if step else "mesh file"
        )
        units = check_choice(self.units, tuple(UNIT_SCALES_TO_M), "units", label("units"))
        tilt = check_choice(
            self.viewpoint_tilt_mode, REQUEST_TILT_MODES, "viewpoint_tilt_mode", label("viewpoint_tilt_mode")
        )
        placement = check_choice(self.placement, PLACEMENTS, "placement", label("placement"))
        solver = check_choice(self.solver_type, SOLVER_TYPES, "solver_type", label("solver_type"))
        positives = {
            name: check_positive(getattr(self, name), name, label(name))
            for name in (
                "sampling_density",
                "uncertainty_threshold_mm",
                "scan_speed_mm_s",
                "set_cover_time_limit_s",
                "time_limit_s",
                "min_planning_time_s",
                "minimum_trajectory_length_mm",
                "trajectory_sample_step_mm",
                "joint_jump_threshold_rad",
            )
        }
        key, value = "minimum_required_overmeasure_mm", self.minimum_required_overmeasure_mm
        message = f"{label(key)} must be a number >= 0, got {value}"
        overmeasure = _validated(lambda: config.non_negative(value, key), key, message)
        fractions = {}
        for name, low, high in (
            ("set_cover_mip_gap", 0.0, 0.5),
            ("min_reachable_share", 0.0, 1.0),
            ("tessellation_tolerance_mm", 0.0, 1000.0),
        ):
            value = getattr(self, name)
            message = f"{label(name)} must be a number in [{low:g}, {high:g}], got {value}"
            fractions[name] = _validated(lambda: config.number(value, name, low, high), name, message)  # noqa: B023
        orientations = self.orientations_around_boresight
        if isinstance(orientations, float) and orientations.is_integer():
            orientations = int(orientations)
        if not isinstance(orientations, int | np.integer) or isinstance(orientations, bool) or orientations < 1:
            raise PlanRequestError(
                "orientations_around_boresight",
                f"{label('orientations_around_boresight')} must be at least 1, got {self.orientations_around_boresight}",
            )
        workers = self.workers
        if isinstance(workers, float) and workers.is_integer():
            workers = int(workers)
        if (
            not isinstance(workers, int | np.integer)
            or isinstance(workers, bool)
            or not 0 <= workers <= MAX_LOCAL_WORKERS
        ):
            raise PlanRequestError(
                "workers", f"{label('workers')} must be a whole number in [0, {MAX_LOCAL_WORKERS}], got {self.workers}"
            )
        most = local_worker_limit()
        if workers > most and not str(self.scheduler or "").strip():
            raise PlanRequestError(
                "workers",
                f"{label('workers')} {workers} is more than this machine allows: {most} local worker processes "
                f"({LIMITS.workers_per_core} per core, {os.cpu_count() or 1} cores); more processes than cores only "
                "add memory; for more, start a Dask cluster on other machines and give its --scheduler",
            )
        scheduler = str(self.scheduler or "").strip()
        if scheduler and not _looks_like_address(scheduler):
            raise PlanRequestError(
                "scheduler",
                f"{label('scheduler')} must be a Dask scheduler address like tcp://host:8786 (or host:8786), got "
                f"{self.scheduler!r}",
            )
        message = (
            f"{label('max_memory_gb')} must be a number of GB >= 0 (0 = from the machine), got {self.max_memory_gb}"
        )
        max_memory = _validated(
            lambda: config.non_negative(self.max_memory_gb, "max_memory_gb"), "max_memory_gb", message
        )
        if max_memory and not scheduler and workers * WORKER_PROCESS_BYTES >= 0.5 * max_memory * 1e9:
            raise PlanRequestError(
                "workers",
                f"{label('workers')} {workers}: the local worker processes alone take ~{workers * WORKER_PROCESS_BYTES / 1e9:.2f}"
                f" GB, at least half of {label('max_memory_gb')} {max_memory:g}: fewer workers, or more memory",
            )
        transform = np.asarray(self.part_transform_mm, dtype=float)
        if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
            raise PlanRequestError(
                "part_transform_mm",
                f"{label('part_transform_mm')} must be a finite 4x4 matrix (NaN or infinite values, or shape "
                f"{transform.shape})",
            )
        return dataclasses.replace(
            self,
            part_file=str(part),
            units=units,
            viewpoint_tilt_mode=tilt,
            placement=placement,
            solver_type=solver,
            orientations_around_boresight=int(orientations),
            minimum_required_overmeasure_mm=overmeasure,
            add_wbk_mirrors=bool(self.add_wbk_mirrors),
            seed=int(self.seed),
            part_transform_mm=transform,
            plan_file=str(self.plan_file or ""),
            overwrite=bool(self.overwrite),
            workers=int(workers),
            scheduler=scheduler,
            max_memory_gb=max_memory,
            **positives,
            **fractions,
        )
