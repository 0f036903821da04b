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
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.set_cover import SOLVER_TYPES
from agiprobot_measurement.planning.viewpoint import TILT_MODES

__all__ = [
    "DEFAULTS_FILE",
    "PlanRequest",
    "PlanRequestError",
    "check_choice",
    "check_positive",
    "load_planning_defaults",
]

#: the file holding the defaults of every request field (section ``planning``)
DEFAULTS_FILE = CONFIG_DIR / "trajectory_manager.yaml"


class PlanRequestError(InputError):
    """A planning request field is invalid; ``field`` names it, the message says why."""

    def __init__(self, field_name: str, message: str):
        super().__init__(message)
        self.field = field_name


def check_positive(value, field_name: str, label: str | None = None) -> float:
    """``value`` as a finite positive float, else :class:`PlanRequestError` naming ``label`` (default: the field)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (math.isfinite(number) and number > 0):
        raise PlanRequestError(field_name, f"{label or field_name} must be a positive number, got {value}")
    return number


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


def load_planning_defaults(path: str | Path | None = None) -> dict:
    """The ``planning`` section of ``config/trajectory_manager.yaml`` (or of ``path``)."""
    path = Path(path) if path is not None else DEFAULTS_FILE
    data = read_yaml(path)
    section = data.get("planning", {}) if isinstance(data, dict) else None
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: 'planning' must be a mapping")
    return dict(section)


@dataclass
class PlanRequest:
    """One planning run. Field names are those of the configuration file and the PlanMeasurement goal.

    ``part_transform_mm``: 4x4 placement of the part's CAD frame relative to the scene file's part pose
    (translation mm). ``plan_file``: where to store the plan ('' = not stored).
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
                raise TypeError(f"PlanRequest has no field {key!r}")
            if value is None or (not isinstance(value, np.ndarray) and not value and value is not False):
                continue
            values[key] = value
        return cls(**values)

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
        if not part.exists():
            raise PlanRequestError("part_file", f"part file not found: {part}")
        if not part.is_file():
            raise PlanRequestError("part_file", f"part is not a file: {part}")
        units = check_choice(self.units, tuple(UNIT_SCALES_TO_M), "units", label("units"))
        tilt = check_choice(self.viewpoint_tilt_mode, TILT_MODES, "viewpoint_tilt_mode", label("viewpoint_tilt_mode"))
        solver = check_choice(self.solver_type, SOLVER_TYPES, "solver_type", label("solver_type"))
        positives = {
            name: check_positive(getattr(self, name), name, label(name))
            for name in (
                "sampling_density",
                "uncertainty_threshold_mm",
                "scan_speed_mm_s",
                "set_cover_time_limit_s",
                "min_planning_time_s",
                "minimum_trajectory_length_mm",
                "trajectory_sample_step_mm",
                "joint_jump_threshold_rad",
            )
        }
        overmeasure = float(self.minimum_required_overmeasure_mm)
        if not (math.isfinite(overmeasure) and overmeasure >= 0):
            raise PlanRequestError(
                "minimum_required_overmeasure_mm",
                f"{label('minimum_required_overmeasure_mm')} must be a number >= 0, got {self.minimum_required_overmeasure_mm}",
            )
        orientations = self.orientations_around_boresight
        if isinstance(orientations, float) and orientations.is_integer():
            orientations = int(orientations)
        if not isinstance(orientations, int | np.integer) or isinstance(orientations, bool) or orientations < 1:
            raise PlanRequestError(
                "orientations_around_boresight",
                f"{label('orientations_around_boresight')} must be at least 1, got {self.orientations_around_boresight}",
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
            solver_type=solver,
            orientations_around_boresight=int(orientations),
            minimum_required_overmeasure_mm=overmeasure,
            add_wbk_mirrors=bool(self.add_wbk_mirrors),
            seed=int(self.seed),
            part_transform_mm=transform,
            plan_file=str(self.plan_file or ""),
            **positives,
        )
