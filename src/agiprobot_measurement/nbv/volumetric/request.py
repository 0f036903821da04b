"""The request of one 3D reconstruction: every field validated at construction (an InputError naming the field),
its defaults from config/nbv.yaml ``request`` and then this class's. Lengths m, angles rad."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import ConfigError, non_negative, number, vector, whole
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.volumetric.settings import NBVSettings
from agiprobot_measurement.nbv.volumetric.station3d import load_nbv_config

__all__ = ["CANDIDATE_SOURCES", "MAX_ROI_EDGE_M", "MAX_VIEWS", "METHODS", "ReconstructionRequest"]

#: the selection methods (``ReconstructionRequest.gain``), each a policy of the registry
METHODS = (
    "ours",
    "ours_tour",
    *GAIN_NAMES,
    "random",
    "hemisphere",
    "hemisphere6",
    "hemisphere12",
    "hemisphere24",
    "report3d",
)
#: candidate sources; "random" and "hemisphere_fixed" (the action's names) select those baselines
CANDIDATE_SOURCES = ("frontier+sphere", "frontier", "sphere", "random", "hemisphere_fixed")
#: the largest ROI edge the loop accepts (m): the UR10e's reach around a part on the fixture
MAX_ROI_EDGE_M = 1.0
MAX_VIEWS = 1000


def _defaults() -> dict:
    """config/nbv.yaml's ``request`` entries (none when the file cannot be read); a ConfigError names a bad entry."""
    try:
        config = load_nbv_config()
    except InputError:
        return {}
    values = NBVSettings.from_config(config).request
    known = sorted(f.name for f in fields(ReconstructionRequest))
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(f"request.{unknown[0]}: unknown key; known: {', '.join(known)}")
    return values


def _optional_vector(value, where: str, positive: bool = False) -> np.ndarray | None:
    if value is None:
        return None
    try:
        value = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        pass  # the validator names it
    v = vector(value, 3, where)
    if positive and np.any(v <= 0):
        raise InputError(f"{where} must be positive in every axis (an empty region of interest), got {v.tolist()}")
    return v


def _budget(value, where: str) -> float:
    """A positive budget; infinite means none."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    return number(value, where, 0.0, low_inclusive=False)


@dataclass
class ReconstructionRequest:
    """One reconstruction; every field is validated here (InputError naming the field). Lengths m, angles rad."""

    roi_center_m: np.ndarray | None = None  # None = above the fixture, where the scene's part sits
    roi_size_m: np.ndarray | None = None  # None = config/nbv.yaml roi.max_object_size_m + margins
    resolution_m: float = 0.002
    planning_resolution_m: float = 0.005
    gain: str = "ours"  # "ours" | GAIN_NAMES | "random" | "hemisphere[6|12|24]" | "report3d"
    candidates: str = "frontier+sphere"
    cost_weight: float = 0.3  # ours: lambda in 1/s of G exp(-lambda C); metrics: rpg's w
    max_views: int = 20
    max_time_s: float = 600.0
    max_joint_path_rad: float = math.inf
    min_gain_area_mm2: float = 100.0
    min_relative_gain: float = 0.02
    execute: bool = True  # False = plan-only: next_best_view() without moving
    output_dir: str | None = None
    seed: int = 0

    def __post_init__(self):
        self.roi_center_m = _optional_vector(self.roi_center_m, "roi_center_m")
        self.roi_size_m = _optional_vector(self.roi_size_m, "roi_size_m", positive=True)
        if self.roi_size_m is not None and np.any(self.roi_size_m > MAX_ROI_EDGE_M):
            raise InputError(
                f"roi_size_m {self.roi_size_m.tolist()} is too large: every edge must be <= {MAX_ROI_EDGE_M} m"
            )
        self.resolution_m = number(self.resolution_m, "resolution_m", 0.0, 0.05, low_inclusive=False)
        if self.resolution_m < 0.0005:
            raise InputError(f"resolution_m must be >= 0.0005 m, got {self.resolution_m}")
        self.planning_resolution_m = number(
            self.planning_resolution_m, "planning_resolution_m", 0.0, 0.1, low_inclusive=False
        )
        if self.planning_resolution_m < self.resolution_m:
            raise InputError(
                f"planning_resolution_m ({self.planning_resolution_m}) must not be finer than resolution_m "
                f"({self.resolution_m})"
            )
        if not isinstance(self.gain, str) or self.gain not in METHODS:
            raise InputError(f"gain: unknown method {self.gain!r}; known: {', '.join(METHODS)}")
        if not isinstance(self.candidates, str) or self.candidates not in CANDIDATE_SOURCES:
            raise InputError(f"candidates: unknown source {self.candidates!r}; known: {', '.join(CANDIDATE_SOURCES)}")
        self.cost_weight = non_negative(self.cost_weight, "cost_weight")
        self.max_views = whole(self.max_views, "max_views", 1, MAX_VIEWS)
        self.max_time_s = _budget(self.max_time_s, "max_time_s")
        self.max_joint_path_rad = _budget(self.max_joint_path_rad, "max_joint_path_rad")
        self.min_gain_area_mm2 = non_negative(self.min_gain_area_mm2, "min_gain_area_mm2")
        self.min_relative_gain = number(self.min_relative_gain, "min_relative_gain", 0.0, 1.0)
        self.execute = bool(self.execute)
        self.seed = int(number(self.seed, "seed", 0.0))
        if self.output_dir is not None and not isinstance(self.output_dir, (str, Path)):
            raise InputError(f"output_dir must be a path, got {self.output_dir!r}")
        if self.output_dir in ("",):
            self.output_dir = None

    @property
    def method(self) -> str:
        """The selection method, the ``candidates`` aliases applied."""
        if self.candidates == "random":
            return "random"
        if self.candidates == "hemisphere_fixed":
            return "hemisphere12"
        return "hemisphere12" if self.gain == "hemisphere" else self.gain

    @property
    def sources(self) -> str:
        return self.candidates if self.candidates in ("frontier+sphere", "frontier", "sphere") else "frontier+sphere"

    @classmethod
    def from_mapping(cls, values: dict) -> ReconstructionRequest:
        """A request from a mapping (an action goal, a JSON file): zero, empty or missing fields take the defaults
        (config/nbv.yaml ``request``, then this class's); ``max_joint_path_rad`` 0 means unlimited."""
        if not isinstance(values, dict):
            raise InputError(f"a request must be a mapping, got {type(values).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InputError(f"unknown request field(s): {', '.join(unknown)}")
        kwargs = dict(_defaults())
        for key, value in values.items():
            if value is None or (isinstance(value, str) and value == ""):
                continue
            if key in ("roi_center_m", "roi_size_m"):
                try:
                    arr = np.asarray(value, dtype=float).reshape(-1)
                except (TypeError, ValueError):
                    raise InputError(f"{key} must be three numbers (m), got {value!r}") from None
                if arr.size == 0 or (arr.size == 3 and np.all(arr == 0)):
                    continue
            elif key not in ("execute", "seed", "min_gain_area_mm2") and not isinstance(value, str):
                try:
                    if float(value) == 0.0:
                        continue
                except (TypeError, ValueError):
                    pass
            kwargs[key] = value
        return cls(**kwargs)

    @classmethod
    def with_config_defaults(cls, **overrides) -> ReconstructionRequest:
        """config/nbv.yaml's ``request`` defaults with ``overrides`` (not treated as unset when zero)."""
        kwargs = dict(_defaults())
        kwargs.update(overrides)
        return cls(**kwargs)
