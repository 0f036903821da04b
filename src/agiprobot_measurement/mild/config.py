"""Configuration of the MILD's robot model: tf frame names, the kinematic chain's offsets and speed limits, and
asr_robot_model_services' parameters (config/mild_*.yaml, or the node's private parameters), checked and converted
to SI units (degrees in the files become radians here, metres stay metres). Errors are ConfigError naming the file
or parameter namespace and the key.

Absent parameters take the original node's defaults (RobotModel_Service.cpp: panMin -60, panMax 60, tiltMin -45,
tiltMax 45 deg, robotModelId 1; MILDRobotModel.cpp: colThresh 40; DebugHelper: no debugLevels = ALL). The original
reads the other keys without a default (an unset C++ variable); here they take the values of the original's
param/robot_model_services_settings_real.yaml, and an absent IKAngleRating is, as there, an unknown rating name: a
warning and SIMPLE. The frame names default to the original's param/robot_model_frames.yaml. The costmap's
inflation is read from the original's ``global_costmap`` parameters (costmap_params.yaml) when the package's own
keys are absent, with costmap_2d's defaults for what that file leaves out.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, non_negative, number, positive, read_yaml, vector
from agiprobot_measurement.mild.occupancy_map import OccupancyMap

__all__ = [
    "APPROXIMATED_IK",
    "DEBUG_LEVELS",
    "DEFAULTS",
    "EXACT_IK",
    "FRAME_KEYS",
    "LP_SOLVERS",
    "RATING_NAMES",
    "FrameNames",
    "MildKinematics",
    "RobotModelSettings",
    "load_frame_names",
    "load_kinematics",
    "load_map",
    "load_settings",
    "settings_from_mapping",
]

RATING_NAMES = ("SIMPLE", "ANGLE_APPROXIMATION", "NAVIGATION_PATH")
#: DebugHelper's categories; ``[ALL]``, ``[NONE]`` or a list of categories (an empty list means ALL)
DEBUG_LEVELS = ("PARAMETERS", "RATING", "ROBOT_MODEL", "MAP", "IK_RATING")
LP_SOLVERS = ("glpk", "highs", "closed_form")
#: robotModelId values: MILDRobotModelWithExactIK, MILDRobotModelWithApproximatedIK
EXACT_IK, APPROXIMATED_IK = 1, 2


FRAME_KEYS = (
    "map_frame",
    "base_frame",
    "ptu_base_frame",
    "ptu_pan_frame",
    "ptu_pan_frame_rotated",
    "ptu_tilt_frame",
    "ptu_tilt_frame_rotated",
    "camera_mount_frame",
    "camera_left_frame",
    "camera_right_frame",
)


@dataclass(frozen=True)
class FrameNames:
    """The chain's tf frame names, keyed by the original's parameter names (robot_model_frames.yaml)."""

    map_frame: str = "map"
    base_frame: str = "base_link"
    ptu_base_frame: str = "ptu_base_link"
    ptu_pan_frame: str = "ptu_pan_link"
    ptu_pan_frame_rotated: str = "ptu_pan_link_rotated"
    ptu_tilt_frame: str = "ptu_tilt_link"
    ptu_tilt_frame_rotated: str = "ptu_tilted_link"
    camera_mount_frame: str = "ptu_mount_link"
    camera_left_frame: str = "camera_left_frame"
    camera_right_frame: str = "camera_right_frame"

    @classmethod
    def from_mapping(cls, mapping: object, where: str, require_all: bool = True) -> FrameNames:
        """``require_all=False``: absent keys take the original's names (the node's parameters may omit them)."""
        if not isinstance(mapping, dict):
            raise ConfigError(f"{where}: expected a mapping of frame names")
        values = {}
        for key in FRAME_KEYS:
            if key not in mapping:
                if require_all:
                    raise ConfigError(f"{where}: missing key '{key}'")
                values[key] = getattr(cls, key)
                continue
            name = mapping[key]
            if not isinstance(name, str) or not name.strip("/"):
                raise ConfigError(f"{where}: '{key}' must be a frame name, got {name!r}")
            values[key] = name.strip("/")  # tf2 frame ids carry no leading slash (the original's had one)
        if len(set(values.values())) != len(values):
            raise ConfigError(f"{where}: frame names must be distinct")
        return cls(**values)


def load_frame_names(path: str | Path | None = None) -> FrameNames:
    path = Path(path) if path else CONFIG_DIR / "mild_robot_model_frames.yaml"
    return FrameNames.from_mapping(read_yaml(path), str(path))


@dataclass(frozen=True)
class MildKinematics:
    """The MILD's fixed offsets (m) between the frames of its chain; see config/mild_kinematics.yaml."""

    base_to_ptu_base_m: np.ndarray
    ptu_base_to_pan_m: np.ndarray
    pan_to_tilt_m: np.ndarray
    tilt_to_mount_m: np.ndarray
    camera_baseline_m: float
    pan_joint: str = "ptu_pan_joint"
    tilt_joint: str = "ptu_tilt_joint"
    frames: FrameNames = field(default_factory=FrameNames)
    # speed limits: pan and tilt (rad/s), base rotation (rad/s) and base translation (m/s)
    max_velocity: tuple[float, float, float, float] = (1.0, 1.0, 0.8, 0.5)

    @property
    def base_to_pan_m(self) -> np.ndarray:
        return self.base_to_ptu_base_m + self.ptu_base_to_pan_m

    @property
    def tilt_axis_height_m(self) -> float:
        """Height of the tilt axis above the floor: constant, whatever the base pose and pan (the IK relies on it)."""
        return float(self.base_to_pan_m[2] + self.pan_to_tilt_m[2])


def load_kinematics(path: str | Path | None = None, frames: FrameNames | str | Path | None = None) -> MildKinematics:
    path = Path(path) if path else CONFIG_DIR / "mild_kinematics.yaml"
    where = str(path)
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")

    def vec(key: str) -> np.ndarray:
        if key not in data:
            raise ConfigError(f"{where}: missing key '{key}'")
        return vector(data[key], 3, f"{where}: {key}")

    if "camera_baseline_m" not in data:
        raise ConfigError(f"{where}: missing key 'camera_baseline_m'")
    baseline = non_negative(data["camera_baseline_m"], f"{where}: camera_baseline_m")
    joints = data.get("joint_names", {}) or {}
    if not isinstance(joints, dict):
        raise ConfigError(f"{where}: joint_names must be a mapping with 'pan' and 'tilt'")
    if not isinstance(frames, FrameNames):
        frames = load_frame_names(frames)
    speeds = data.get("max_velocity", {}) or {}
    if not isinstance(speeds, dict):
        raise ConfigError(f"{where}: max_velocity must be a mapping")
    max_velocity = tuple(
        _number(speeds, key, f"{where}: max_velocity", default=default, strictly_positive=True)
        for key, default in (
            ("pan_rad_s", 1.0),
            ("tilt_rad_s", 1.0),
            ("base_angular_rad_s", 0.8),
            ("base_linear_m_s", 0.5),
        )
    )
    return MildKinematics(
        base_to_ptu_base_m=vec("base_to_ptu_base_xyz_m"),
        ptu_base_to_pan_m=vec("ptu_base_to_pan_xyz_m"),
        pan_to_tilt_m=vec("pan_to_tilt_xyz_m"),
        tilt_to_mount_m=vec("tilt_to_camera_mount_xyz_m"),
        camera_baseline_m=baseline,
        pan_joint=str(joints.get("pan", "ptu_pan_joint")),
        tilt_joint=str(joints.get("tilt", "ptu_tilt_joint")),
        frames=frames,
        max_velocity=max_velocity,
    )


@dataclass(frozen=True)
class RobotModelSettings:
    """asr_robot_model_services' parameters, converted to SI units (radians, metres); names as in the YAML files."""

    robot_model_id: int
    pan_limits_rad: tuple[float, float]
    tilt_limits_rad: tuple[float, float]
    sigma_m: float
    col_thresh: float
    omega_pan: float
    omega_tilt: float
    omega_rot: float
    omega_base: float
    tolerance_m: float
    use_global_planner: bool
    ncp_m: float
    fcp_m: float
    visualize_ik: bool
    ik_angle_rating: str
    pan_sampling_steps: int
    ik_iteration_accuracy: float
    pan_sampling_max_iterations: int = 6
    lp_solver: str = "glpk"
    fovx_rad: float = math.radians(30.0)
    fovy_rad: float = math.radians(20.0)
    inscribed_radius_m: float = 0.30
    inflation_radius_m: float = 0.60
    cost_scaling_per_m: float = 5.0
    ik_visualization_topic: str = "/asr_robot_model_services/IK_Visualization"
    debug_levels: frozenset[str] = frozenset(DEBUG_LEVELS)
    # speedFactorPTU, speedFactorBaseMove, speedFactorBaseRot (dimensionless; None = not set): read and logged as
    # the original does, which uses them in no answer
    speed_factors: tuple[float | None, float | None, float | None] = (None, None, None)
    defaulted: tuple[str, ...] = ()  # the keys that were absent and took their default
    warnings: tuple[str, ...] = ()

    def debug(self, level: str) -> bool:
        """Whether DebugHelper's category ``level`` (PARAMETERS, RATING, ROBOT_MODEL, MAP, IK_RATING) is on."""
        return level in self.debug_levels

    @property
    def view_distance_m(self) -> float:
        """Distance from the camera to the view centre: the middle of the clipping planes."""
        return 0.5 * (self.ncp_m + self.fcp_m)

    def with_changes(self, **changes) -> RobotModelSettings:
        return replace(self, **changes)


_REQUIRED = object()

#: What an absent key becomes (the original's units: degrees, metres). The first six are the original code's own
#: defaults; the rest are param/robot_model_services_settings_real.yaml's values (the original has no default).
DEFAULTS = {
    "robotModelId": EXACT_IK,
    "panMin": -60.0,
    "panMax": 60.0,
    "tiltMin": -45.0,
    "tiltMax": 45.0,
    "colThresh": 40.0,
    "mSigma": 2.0,
    "mOmegaPan": 1.0,
    "mOmegaTilt": 1.0,
    "mOmegaRot": 10.0,
    "mOmegaBase": 135.0,
    "tolerance": 0.00003,
    "useGlobalPlanner": False,
    "ncp": 0.4,
    "fcp": 1.5,
    "visualizeIK": False,
    "panAngleSamplingStepsPerIteration": 3,
    "inverseKinematicIterationAccuracy": 0.01,
}
# costmap_2d's defaults (Costmap2D.cfg robot_radius, InflationLayer inflation_radius and cost_scaling_factor)
COSTMAP_ROBOT_RADIUS_M, COSTMAP_INFLATION_RADIUS_M, COSTMAP_COST_SCALING_PER_M = 0.46, 0.55, 10.0


def _debug_levels(value: object, where: str) -> frozenset[str]:
    """DebugHelper::parseLevels: nothing or [] = ALL, [ALL], [NONE], or a list of categories; a string
    "[PARAMETERS, MAP]" is split as DebugHelper::setLevels(string) does."""
    if value is None:
        return frozenset(DEBUG_LEVELS)
    if isinstance(value, str):
        value = [part for part in re.split(r"[\s,]+", value.strip("\"',[]{} ")) if part]
        value = [part.strip("\"',[]{} ").upper() for part in value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where}: 'debugLevels' must be a list of names, got {value!r}")
    if not value or value == ["ALL"]:
        return frozenset(DEBUG_LEVELS)
    if value == ["NONE"]:
        return frozenset()
    for name in value:
        if name not in DEBUG_LEVELS:
            raise ConfigError(
                f"{where}: invalid debug level {name!r} in 'debugLevels' ([ALL], [NONE] or a list of "
                f"{', '.join(DEBUG_LEVELS)})"
            )
    return frozenset(value)


def _costmap_radii(mapping: dict, where: str) -> tuple[float, float, float]:
    """(inscribed radius m, inflation radius m, cost scaling 1/m): the package's keys, else the original's
    ``global_costmap`` (robot_radius; inflation_layer/inflation_radius, cost_scaling_factor, or the old-style keys
    directly under global_costmap), else costmap_2d's defaults."""
    costmap = mapping.get("global_costmap", {})
    if costmap is None:
        costmap = {}
    if not isinstance(costmap, dict):
        raise ConfigError(f"{where}: 'global_costmap' must be a mapping (costmap_2d parameters)")
    layer = costmap.get("inflation_layer", {}) or {}
    if not isinstance(layer, dict):
        raise ConfigError(f"{where}: 'global_costmap/inflation_layer' must be a mapping")
    inner = f"{where} (global_costmap)"

    def from_costmap(key: str, default: float) -> float:
        if key in layer:
            return _number(layer, key, f"{inner}/inflation_layer", minimum=0)
        return _number(costmap, key, inner, default=default, minimum=0)

    inscribed = _number(
        mapping,
        "inscribedRadius_m",
        where,
        default=_number(costmap, "robot_radius", inner, default=COSTMAP_ROBOT_RADIUS_M, minimum=0),
        minimum=0,
    )
    inflation = _number(
        mapping,
        "inflationRadius_m",
        where,
        default=from_costmap("inflation_radius", COSTMAP_INFLATION_RADIUS_M),
        minimum=0,
    )
    scaling = _number(
        mapping,
        "costScalingFactor_per_m",
        where,
        default=from_costmap("cost_scaling_factor", COSTMAP_COST_SCALING_PER_M),
        minimum=0,
    )
    return inscribed, inflation, scaling


def _number(mapping: dict, key: str, where: str, default=_REQUIRED, minimum=None, strictly_positive=False) -> float:
    """``mapping[key]`` checked by :func:`common.config.number` (``default`` when absent, unless required)."""
    if key not in mapping:
        if default is _REQUIRED:
            raise ConfigError(f"{where}: missing key '{key}'")
        return default
    if strictly_positive:
        return number(positive(mapping[key], f"{where}: '{key}'"), f"{where}: '{key}'", low=minimum)
    return number(mapping[key], f"{where}: '{key}'", low=minimum)


def _flag(mapping: dict, key: str, where: str, default=_REQUIRED) -> bool:
    if key not in mapping:
        if default is _REQUIRED:
            raise ConfigError(f"{where}: missing key '{key}'")
        return default
    value = mapping[key]
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise ConfigError(f"{where}: '{key}' must be true or false, got {value!r}")


def settings_from_mapping(mapping: object, where: str) -> RobotModelSettings:
    """Check and convert the parameters (a YAML file's or the node's private rosparams); errors name ``where``.
    Absent keys take :data:`DEFAULTS` (listed in ``defaulted``); present keys of a wrong type or value are errors."""
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping of parameters")
    warnings: list[str] = []
    defaulted = tuple(key for key in DEFAULTS if key not in mapping)

    def number(key: str, **checks) -> float:
        return _number(mapping, key, where, default=float(DEFAULTS[key]), **checks)

    def flag(key: str) -> bool:
        return _flag(mapping, key, where, default=DEFAULTS[key])

    model_id = mapping.get("robotModelId", DEFAULTS["robotModelId"])
    if isinstance(model_id, bool) or model_id not in (EXACT_IK, APPROXIMATED_IK):
        raise ConfigError(
            f"{where}: robotModelId {model_id!r} is not a valid robot model id "
            f"(1 = MILDRobotModelWithExactIK, 2 = MILDRobotModelWithApproximatedIK)"
        )
    limits = {key: number(key) for key in ("panMin", "panMax", "tiltMin", "tiltMax")}
    for low, high in (("panMin", "panMax"), ("tiltMin", "tiltMax")):
        if limits[low] >= limits[high]:
            raise ConfigError(f"{where}: need {low} < {high} (degrees), got {limits[low]} and {limits[high]}")
    if limits["tiltMin"] <= -90 or limits["tiltMax"] >= 90:
        raise ConfigError(f"{where}: tilt limits must lie within (-90, 90) degrees")
    ncp = number("ncp", strictly_positive=True)
    fcp = number("fcp", strictly_positive=True)
    if ncp >= fcp:
        raise ConfigError(f"{where}: need ncp < fcp (metres), got {ncp} and {fcp}")
    rating = mapping.get("IKAngleRating", "")
    if "IKAngleRating" not in mapping:
        warnings.append("IKAngleRating is not set; using SIMPLE (the original's choice for a name it does not know)")
        rating = "SIMPLE"
    elif rating not in RATING_NAMES:
        warnings.append(
            f"'{rating}' is not a valid IK rating algorithm (IKAngleRating: one of {', '.join(RATING_NAMES)}); "
            "using SIMPLE instead"
        )
        rating = "SIMPLE"
    steps = number("panAngleSamplingStepsPerIteration", minimum=2)
    iterations = _number(mapping, "panAngleSamplingMaxIterations", where, default=6, minimum=1)
    if steps != int(steps) or iterations != int(iterations):
        raise ConfigError(f"{where}: panAngleSamplingStepsPerIteration and panAngleSamplingMaxIterations are integers")
    solver = str(mapping.get("lpSolver", "glpk"))
    if solver not in LP_SOLVERS:
        raise ConfigError(f"{where}: lpSolver must be one of {', '.join(LP_SOLVERS)}, got {solver!r}")
    fovx = _number(mapping, "fovx_deg", where, default=30.0, strictly_positive=True)
    fovy = _number(mapping, "fovy_deg", where, default=20.0, strictly_positive=True)
    if fovx >= 180 or fovy >= 180:
        raise ConfigError(f"{where}: fovx_deg and fovy_deg must be below 180")
    col_thresh = number("colThresh", minimum=0)
    if col_thresh > 100:
        raise ConfigError(f"{where}: colThresh is an occupancy value in [0, 100], got {col_thresh}")
    inscribed, inflation, scaling = _costmap_radii(mapping, where)
    if inscribed > inflation:
        raise ConfigError(
            f"{where}: need inscribed radius <= inflation radius (inscribedRadius_m or global_costmap/robot_radius, "
            f"inflationRadius_m or global_costmap inflation_radius), got {inscribed} m and {inflation} m"
        )
    speed_factors = tuple(
        None if key not in mapping else _number(mapping, key, where, strictly_positive=True)
        for key in ("speedFactorPTU", "speedFactorBaseMove", "speedFactorBaseRot")
    )
    topic = mapping.get("IKVisualization", "/asr_robot_model_services/IK_Visualization")
    if not isinstance(topic, str) or not topic.strip("/"):
        raise ConfigError(f"{where}: 'IKVisualization' must be a topic name, got {topic!r}")
    return RobotModelSettings(
        robot_model_id=int(model_id),
        pan_limits_rad=(math.radians(limits["panMin"]), math.radians(limits["panMax"])),
        tilt_limits_rad=(math.radians(limits["tiltMin"]), math.radians(limits["tiltMax"])),
        sigma_m=number("mSigma", strictly_positive=True),
        col_thresh=col_thresh,
        omega_pan=number("mOmegaPan", minimum=0),
        omega_tilt=number("mOmegaTilt", minimum=0),
        omega_rot=number("mOmegaRot", minimum=0),
        omega_base=number("mOmegaBase", minimum=0),
        tolerance_m=number("tolerance", minimum=0),
        use_global_planner=flag("useGlobalPlanner"),
        ncp_m=ncp,
        fcp_m=fcp,
        visualize_ik=flag("visualizeIK"),
        ik_angle_rating=str(rating),
        pan_sampling_steps=int(steps),
        ik_iteration_accuracy=number("inverseKinematicIterationAccuracy", strictly_positive=True),
        pan_sampling_max_iterations=int(iterations),
        lp_solver=solver,
        fovx_rad=math.radians(fovx),
        fovy_rad=math.radians(fovy),
        inscribed_radius_m=inscribed,
        inflation_radius_m=inflation,
        cost_scaling_per_m=scaling,
        ik_visualization_topic=topic,
        debug_levels=_debug_levels(mapping.get("debugLevels"), where),
        speed_factors=speed_factors,
        defaulted=defaulted,
        warnings=tuple(warnings),
    )


def load_settings(path: str | Path | None = None) -> RobotModelSettings:
    """Settings file (default: config/mild_robot_model_services_real.yaml)."""
    path = Path(path) if path else CONFIG_DIR / "mild_robot_model_services_real.yaml"
    return settings_from_mapping(read_yaml(path), str(path))


def load_map(path: str | Path | None, settings: RobotModelSettings) -> OccupancyMap:
    """A map_server map inflated with the settings' radii (default: config/maps/mild_lab.yaml)."""
    path = Path(path) if path else CONFIG_DIR / "maps" / "mild_lab.yaml"
    return OccupancyMap.load(
        path, settings.inscribed_radius_m, settings.inflation_radius_m, settings.cost_scaling_per_m
    )
