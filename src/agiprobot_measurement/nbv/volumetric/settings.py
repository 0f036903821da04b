"""``config/nbv.yaml`` read once into typed, validated settings of the 3D loop.

:meth:`NBVSettings.from_config` checks every section the loop reads (``roi``, ``request``, ``candidates``,
``planning``, ``motion``, ``simulation``; ``phoxi_tool`` is the URDF's and is passed on as it is) with the validators
of :mod:`agiprobot_measurement.common.config`: a bad value or an unknown key raises a
:class:`~agiprobot_measurement.common.config.ConfigError` naming ``section.key``. A missing key takes the default
written here. Lengths m, angles in the unit the key names (converted to rad where the field says ``_rad``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from agiprobot_measurement.common.config import (
    ConfigError,
    non_negative,
    number,
    number_list,
    positive,
    vector,
    whole,
)

__all__ = [
    "COST_SCHEDULES",
    "CandidateSettings",
    "MotionSettings",
    "NBVSettings",
    "PlanningSettings",
    "RoiSettings",
    "SimulationSettings",
    "TourSettings",
]

#: how ours applies its motion weight lambda over a run (``planning.cost_schedule``)
COST_SCHEDULES = ("constant", "remaining_surface", "map_growth")
#: the sections of config/nbv.yaml
SECTIONS = ("phoxi_tool", "roi", "request", "candidates", "planning", "motion", "simulation")


def _section(config: dict, name: str) -> dict:
    values = config.get(name) if isinstance(config, dict) else None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise ConfigError(f"{name}: expected a mapping, got {type(values).__name__}")
    return values


def _check_keys(values: dict, known, where: str) -> None:
    unknown = sorted(str(k) for k in set(values) - set(known))
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown key; known: {', '.join(sorted(known))}")


def _parse(values: dict, section: str, rules: dict) -> dict:
    """Keyword arguments of a settings class from a section: ``rules`` maps each known key to (field name,
    ``convert(value, where)``); an unknown key raises a ConfigError naming it."""
    _check_keys(values, rules, section)
    kwargs = {}
    for key, value in values.items():
        name, convert = rules[key]
        kwargs[name] = convert(value, f"{section}.{key}")
    return kwargs


def _numbers(low: float, high: float):
    """A list of numbers in [low, high]; a single number is a list of one, an empty list is allowed."""

    def convert(value, where: str) -> tuple[float, ...]:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value]
        return tuple(number_list(value, where, low, high, min_length=0))

    return convert


def _degrees_list(value, where: str) -> tuple[float, ...]:
    return tuple(math.radians(a) for a in _numbers(-360.0, 360.0)(value, where))


def _degrees(value, where: str) -> float:
    return math.radians(number(value, where))


def _whole(low: int | None = None, high: int | None = None):
    return lambda value, where: whole(value, where, low, high)


def _vector(length: int):
    return lambda value, where: tuple(float(v) for v in vector(value, length, where))


def _text(value, where: str) -> str:
    return str(value)


def _switch(value, where: str) -> bool:
    return bool(value)


def _one_of(*names: str):
    def convert(value, where: str) -> str:
        if str(value) not in names:
            raise ConfigError(f"{where}: unknown {str(value)!r}; known: {', '.join(names)}")
        return str(value)

    return convert


def _weights(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
    return {str(k): number(v, f"{where}.{k}") for k, v in value.items()}


def _mapping(value, where: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
    return dict(value)


def _ray_bundle(value, where: str) -> tuple[int, int]:
    rays = number_list(value, where, 1, min_length=2, max_length=2)
    return whole(rays[0], f"{where}[0]"), whole(rays[1], f"{where}[1]")


@dataclass(frozen=True)
class RoiSettings:
    """``roi``: the a-priori object box above the fixture (m) and the fixture's scene object."""

    max_object_size_m: tuple[float, float, float] = (0.26, 0.26, 0.26)
    margin_m: float = 0.01
    fixture: str = "fixture"

    @classmethod
    def from_mapping(cls, values: dict) -> RoiSettings:
        rules = {"max_object_size_m": ("max_object_size_m", _vector(3)), "margin_m": ("margin_m", number),
                 "fixture": ("fixture", _text)}  # fmt: skip
        return cls(**_parse(values, "roi", rules))


@dataclass(frozen=True)
class CandidateSettings:
    """``candidates``: the entries given (None = the candidate generator's own default); angles in rad."""

    cone_angles_rad: tuple[float, ...] | None = None
    cone_azimuths: int | None = None
    rolls_rad: tuple[float, ...] | None = None
    max_targets: int | None = None
    visibility_directions: int | None = None
    visibility_max_angle_rad: float | None = None
    sphere_directions: int | None = None
    sphere_min_elevation_rad: float | None = None
    roi_clearance_m: float | None = None
    table_clearance_m: float | None = None
    tabu_distance_m: float | None = None
    unknown_obstacle: bool | None = None
    unknown_obstacle_pool: int | None = None

    @classmethod
    def from_mapping(cls, values: dict) -> CandidateSettings:
        rules = {
            "cone_angles_deg": ("cone_angles_rad", _degrees_list),
            "rolls_deg": ("rolls_rad", _degrees_list),
            "visibility_max_angle_deg": ("visibility_max_angle_rad", _degrees),
            "sphere_min_elevation_deg": ("sphere_min_elevation_rad", _degrees),
            "unknown_obstacle": ("unknown_obstacle", _switch),
        }
        rules.update({k: (k, _whole(0)) for k in ("max_targets", "visibility_directions", "sphere_directions",
                                                  "cone_azimuths")})  # fmt: skip
        rules["unknown_obstacle_pool"] = ("unknown_obstacle_pool", _whole(1, 8))
        rules.update({k: (k, number) for k in ("roi_clearance_m", "table_clearance_m", "tabu_distance_m")})
        return cls(**_parse(values, "candidates", rules))

    def given(self) -> dict:
        """The entries the configuration set, as keyword arguments of the candidate generator's configuration."""
        return {k: v for k, v in self.__dict__.items() if v is not None}


@dataclass(frozen=True)
class TourSettings:
    """``planning.tour``: ours_tour's receding-horizon plan (see :mod:`.policies.touring`): greedy views first, the
    plan's size and covered share, the share of its planned gain a view must keep to stay in the plan, the smallest
    marginal value (share of the first pick's) worth a stop, the IK branches per view, and ``greedy_share``: when ours'
    best view alone promises at least this share of the plan's predicted new surface, it is visited first (the gain
    is concentrated there: a tour that leaves it for later loses coverage; 1: never), ``undersampled_min_share``: a
    full planning voxel whose missed share (:meth:`.sampling.SamplingState.fields`) is at least this is also to be
    covered (1, the default: the plan covers the predicted unseen surface only)."""

    min_greedy_views: int = 3
    max_plan_views: int = 8
    cover_share: float = 0.9
    keep_share: float = 0.5
    min_marginal_share: float = 0.3
    max_branches: int = 4
    greedy_share: float = 0.5
    undersampled_min_share: float = 1.0

    @classmethod
    def from_mapping(cls, values: dict) -> TourSettings:
        def share(value, where):
            return number(value, where, 0.0, 1.0)

        rules = {
            "min_greedy_views": ("min_greedy_views", _whole(0, 64)),
            "max_plan_views": ("max_plan_views", _whole(1, 64)),
            "cover_share": ("cover_share", share),
            "keep_share": ("keep_share", share),
            "min_marginal_share": ("min_marginal_share", share),
            "max_branches": ("max_branches", _whole(1, 8)),
            "greedy_share": ("greedy_share", share),
            "undersampled_min_share": ("undersampled_min_share", share),
        }
        return cls(**_parse(values, "planning.tour", rules))


@dataclass(frozen=True)
class PlanningSettings:
    """``planning``: ours' score and motion weight (``cost_schedule_power``: (1 - A / A1)^power, a higher power lets
    the motion count later in the run; ``cost_joint_path_s_per_rad``: seconds of motion cost per rad of straight
    joint path, added to the move time), the gain ray bundle, the surprise rule and the realised stop."""

    ours_weights: dict | None = None  # None: ours' own default
    cost_schedule: str = "constant"
    cost_schedule_power: float = 1.0
    cost_joint_path_s_per_rad: float = 0.0
    expected_surface: dict = field(default_factory=dict)
    gain_rays: tuple[int, int] = (32, 24)
    max_evaluated: int = 160
    #: ours: the gain terms of every evaluated candidate come from a bundle with ``coarse_ray_divisor`` times fewer
    #: rays per axis, and only the ``exact_evaluated`` best by that score are scored with ``gain_rays`` (0: all)
    exact_evaluated: int = 0
    coarse_ray_divisor: int = 2
    surprise_ratio: float = 0.2
    surprise_distance_m: float = 0.15
    surprise_angle_rad: float = math.radians(25.0)
    realised_streak: int = 3
    #: stop also when the rest of the view budget, at the mean growth of the map's surface over the last
    #: ``growth_window`` views, would add less than this share of the observed surface (0: off)
    budget_growth_share: float = 0.0
    growth_window: int = 3
    #: ours: below this best predicted new surface (mm^2), and whenever the frontier predicts none, the view of the
    #: global sphere that sees the most never-observed space next to the seen surface is weighed too (0: only when
    #: the frontier predicts none)
    coverage_fallback_below_mm2: float = 100.0
    coverage_fallback_reach_vox: int = 3  # "next to": within this many planning voxels of a full voxel
    #: ours' ``undersampled_surface`` term (:mod:`.sampling`): a surface point counts as measured within
    #: ``coverage_radius_m`` of a sample; a point's sample spacing is its ``sample_neighbours``-th neighbour's
    #: distance; the surface beyond the open borders of the fused points counts ``open_border_weight`` x (0: not)
    coverage_radius_m: float = 0.002
    sample_neighbours: int = 4
    open_border_weight: float = 0.0
    #: the term's weight x (its best area / (that + the most unseen surface expected)) ^ this power
    undersampled_fade_power: float = 1.0
    #: ours: among the candidates whose utility is within this share of the best one's, the one whose move takes
    #: least time is taken (views that promise almost the same are told apart by their motion; 0: the best)
    near_best_share: float = 0.0
    tour: TourSettings = field(default_factory=TourSettings)

    @classmethod
    def from_mapping(cls, values: dict) -> PlanningSettings:
        rules = {
            "ours_weights": ("ours_weights", _weights),
            "cost_schedule": ("cost_schedule", _one_of(*COST_SCHEDULES)),
            "cost_schedule_power": ("cost_schedule_power", positive),
            "cost_joint_path_s_per_rad": ("cost_joint_path_s_per_rad", non_negative),
            "expected_surface": ("expected_surface", _mapping),
            "gain_rays": ("gain_rays", _ray_bundle),
            "max_evaluated": ("max_evaluated", _whole()),
            "exact_evaluated": ("exact_evaluated", _whole()),
            "coarse_ray_divisor": ("coarse_ray_divisor", _whole(1, 8)),
            "surprise_ratio": ("surprise_ratio", number),
            "surprise_distance_m": ("surprise_distance_m", number),
            "surprise_angle_deg": ("surprise_angle_rad", _degrees),
            "realised_streak": ("realised_streak", _whole()),
            "budget_growth_share": ("budget_growth_share", lambda value, where: number(value, where, 0.0, 1.0)),
            "growth_window": ("growth_window", _whole(1, 20)),
            "coverage_fallback_below_mm2": ("coverage_fallback_below_mm2", non_negative),
            "coverage_fallback_reach_vox": ("coverage_fallback_reach_vox", _whole(1, 20)),
            "coverage_radius_m": ("coverage_radius_m", positive),
            "sample_neighbours": ("sample_neighbours", _whole(1, 16)),
            "open_border_weight": ("open_border_weight", non_negative),
            "undersampled_fade_power": ("undersampled_fade_power", non_negative),
            "near_best_share": ("near_best_share", lambda value, where: number(value, where, 0.0, 1.0)),
            "tour": ("tour", lambda value, where: TourSettings.from_mapping(_mapping(value, where))),
        }
        return cls(**_parse(values, "planning", rules))


@dataclass(frozen=True)
class MotionSettings:
    """``motion``: the home pose, the joint-move speed, OMPL's budget, the routes around blocked moves, the search
    and the opening view."""

    home_rad: tuple[float, ...] | None = None  # None: the station's named state ``home``
    velocity_scaling: float = 0.5
    planning_time_s: float = 0.5
    simplify_time_s: float = 0.5
    ompl_best_of: int = 4
    via_poses: int = 8
    orbit_retract_m: tuple[float, ...] = (0.1, 0.2, 0.3)
    orbit_radius_extra_m: tuple[float, ...] = (0.05, 0.15, 0.3)
    orbit_lift_deg: tuple[float, ...] = (25.0, 50.0)
    search_views: int = 4
    opening_height: float = 0.25
    opening_elevation_deg: float = 90.0

    @classmethod
    def from_mapping(cls, values: dict) -> MotionSettings:
        rules = {
            "home_rad": ("home_rad", _vector(6)),
            "ompl_best_of": ("ompl_best_of", _whole(1, 50)),
            "orbit_retract_m": ("orbit_retract_m", _numbers(0.0, 1.0)),
            "orbit_radius_extra_m": ("orbit_radius_extra_m", _numbers(0.0, 1.0)),
            "orbit_lift_deg": ("orbit_lift_deg", _numbers(0.0, 90.0)),
            "opening_elevation_deg": ("opening_elevation_deg", lambda v, where: number(v, where, 0.0, 90.0)),
        }
        rules.update({k: (k, number) for k in ("velocity_scaling", "planning_time_s", "simplify_time_s",
                                               "opening_height")})  # fmt: skip
        rules.update({k: (k, _whole()) for k in ("search_views", "via_poses")})
        return cls(**_parse(values, "motion", rules))


@dataclass(frozen=True)
class SimulationSettings:
    """``simulation``: the renderer's noise and seed, the pixel step and the PhoXi resolution."""

    noise: bool = True
    seed: int = 0
    pixel_step: int = 1
    resolution: str = "low"

    @classmethod
    def from_mapping(cls, values: dict) -> SimulationSettings:
        rules = {"noise": ("noise", _switch), "seed": ("seed", _whole()), "pixel_step": ("pixel_step", _whole()),
                 "resolution": ("resolution", _text)}  # fmt: skip
        return cls(**_parse(values, "simulation", rules))


@dataclass(frozen=True)
class NBVSettings:
    """The whole of config/nbv.yaml, typed. ``request`` holds the loop's request defaults as given (the request
    validates them); ``phoxi_tool`` the URDF's section as given."""

    phoxi_tool: dict = field(default_factory=dict)
    roi: RoiSettings = field(default_factory=RoiSettings)
    request: dict = field(default_factory=dict)
    candidates: CandidateSettings = field(default_factory=CandidateSettings)
    planning: PlanningSettings = field(default_factory=PlanningSettings)
    motion: MotionSettings = field(default_factory=MotionSettings)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)

    @classmethod
    def from_config(cls, config: dict) -> NBVSettings:
        """Settings of a config/nbv.yaml mapping; ConfigError naming ``section.key`` for a bad or unknown entry."""
        if not isinstance(config, dict):
            raise ConfigError(f"nbv configuration: expected a mapping, got {type(config).__name__}")
        _check_keys(config, SECTIONS, "nbv")
        return cls(
            phoxi_tool=dict(_section(config, "phoxi_tool")),
            roi=RoiSettings.from_mapping(_section(config, "roi")),
            request=dict(_section(config, "request")),
            candidates=CandidateSettings.from_mapping(_section(config, "candidates")),
            planning=PlanningSettings.from_mapping(_section(config, "planning")),
            motion=MotionSettings.from_mapping(_section(config, "motion")),
            simulation=SimulationSettings.from_mapping(_section(config, "simulation")),
        )
