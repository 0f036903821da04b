"""Robot, joint limits, named states and scanner: the station's configuration files as typed objects.

Units: metres and radians; the sensor model keeps the documented mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, positive, read_yaml, require, vector
from agiprobot_measurement.common.geometry import pose_matrix

__all__ = [
    "SENSOR_PARAMETER_KEYS",
    "JointLimits",
    "RobotConfig",
    "ScannerConfig",
    "load_joint_limits",
    "load_named_states",
    "load_robot_config",
    "load_scanner_config",
]


@dataclass(frozen=True)
class RobotConfig:
    """Kinematic description of a 6-axis arm from standard DH parameters (metres, radians)."""

    name: str
    joint_names: tuple[str, ...]
    d_m: np.ndarray
    a_m: np.ndarray
    alpha_rad: np.ndarray
    base_frame: str
    flange_frame: str
    planning_frame: str
    default_tip_frame: str
    #: the arm's kinematics file (ur_calibration's output, ur_description's format), resolved; the URDF's joint
    #: origins and so every model built from the station come from it
    kinematics_config: Path | None = None


def load_robot_config(path: str | Path | None = None) -> RobotConfig:
    path = Path(path) if path else CONFIG_DIR / "ur10e.yaml"
    data = read_yaml(path)
    where = str(path)
    names = require(data, "joint_names", where)
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise ConfigError(f"{where}: 'joint_names' must be a list of distinct names")
    dh = require(data, "dh", where)
    n = len(names)
    return RobotConfig(
        name=str(data.get("robot_name", "robot")),
        joint_names=tuple(names),
        d_m=vector(require(dh, "d_m", f"{where}: dh"), n, f"{where}: dh.d_m"),
        a_m=vector(require(dh, "a_m", f"{where}: dh"), n, f"{where}: dh.a_m"),
        alpha_rad=vector(require(dh, "alpha_rad", f"{where}: dh"), n, f"{where}: dh.alpha_rad"),
        base_frame=str(data.get("base_frame", "base_link")),
        flange_frame=str(data.get("flange_frame", "tool0")),
        planning_frame=str(data.get("planning_frame", "world")),
        default_tip_frame=str(data.get("default_tip_frame", "tool0")),
        kinematics_config=_kinematics_path(data, path),
    )


def _kinematics_path(data: dict, path: Path) -> Path | None:
    """``kinematics_config`` of a robot file, relative to the file's folder unless absolute; None when absent."""
    value = data.get("kinematics_config")
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{path}: 'kinematics_config' must be a file name, got {value!r}")
    kinematics = Path(value)
    return kinematics if kinematics.is_absolute() else (path.parent / kinematics).resolve()


# ------------------------------------------------------------------------------------------ joint limits
@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, arrays in the order of ``names`` (rad, rad/s, rad/s^2)."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    max_velocity: np.ndarray
    max_acceleration: np.ndarray

    def __len__(self) -> int:
        return len(self.names)

    def within_position_limits(self, q: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
        """Boolean per state (last axis = joints) whether every joint lies within its limits."""
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.lower - tolerance) & (q <= self.upper + tolerance), axis=-1)


def load_joint_limits(path: str | Path | None = None, joint_names: tuple[str, ...] | None = None) -> JointLimits:
    """Read a MoveIt-style ``joint_limits.yaml``; ``joint_names`` fixes the order (default: the robot's)."""
    path = Path(path) if path else CONFIG_DIR / "joint_limits.yaml"
    if joint_names is None:
        joint_names = load_robot_config().joint_names
    data = read_yaml(path)
    where = str(path)
    table = require(data, "joint_limits", where)
    lower, upper, vel, acc = [], [], [], []
    for name in joint_names:
        entry = require(table, name, f"{where}: joint_limits")
        here = f"{where}: joint_limits.{name}"
        for flag in ("has_position_limits", "has_velocity_limits", "has_acceleration_limits"):
            if not require(entry, flag, here):
                raise ConfigError(f"{here}: '{flag}' must be true: the station needs every limit")
        lo = float(require(entry, "min_position", here))
        hi = float(require(entry, "max_position", here))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(f"{here}: need finite min_position < max_position, got {lo}, {hi}")
        lower.append(lo)
        upper.append(hi)
        vel.append(positive(require(entry, "max_velocity", here), f"{here}.max_velocity"))
        acc.append(positive(require(entry, "max_acceleration", here), f"{here}.max_acceleration"))
    return JointLimits(tuple(joint_names), np.array(lower), np.array(upper), np.array(vel), np.array(acc))


def load_named_states(path: str | Path | None = None, joint_count: int = 6) -> dict[str, np.ndarray]:
    path = Path(path) if path else CONFIG_DIR / "named_states.yaml"
    data = read_yaml(path)
    table = require(data, "named_states", str(path))
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{path}: 'named_states' must be a non-empty mapping of name -> joint values")
    return {str(k): vector(v, joint_count, f"{path}: named_states.{k}") for k, v in table.items()}


# ------------------------------------------------------------------------------------------------ scanner
@dataclass(frozen=True)
class ScannerConfig:
    """Laser line scanner: sensor-model parameters (mm, rad) and the tool0 -> laser_emitter_frame mount."""

    sensor_parameters: dict
    mount_pose: np.ndarray  # 4x4, metres
    housing_size_m: np.ndarray
    housing_center_m: np.ndarray


SENSOR_PARAMETER_KEYS = (
    "optimal_standoff_mm",
    "minimum_standoff_mm",
    "maximum_standoff_mm",
    "theta_max_rad",
    "psi_max_rad",
    "K_u",
    "alpha_rad",
    "fan_angle_rad",
)


def load_scanner_config(path: str | Path | None = None) -> ScannerConfig:
    path = Path(path) if path else CONFIG_DIR / "laser_scanner.yaml"
    data = read_yaml(path)
    where = str(path)
    model = require(data, "sensor_model", where)
    params = {}
    for key in SENSOR_PARAMETER_KEYS:
        params[key] = positive(require(model, key, f"{where}: sensor_model"), f"{where}: sensor_model.{key}")
    for key, value in model.items():
        if key not in params:
            params[key] = value
    if not params["minimum_standoff_mm"] < params["optimal_standoff_mm"] < params["maximum_standoff_mm"]:
        raise ConfigError(f"{where}: sensor_model needs minimum < optimal < maximum standoff")
    mount = require(data, "mount", where)
    housing = require(data, "housing", where)
    return ScannerConfig(
        sensor_parameters=params,
        mount_pose=pose_matrix(
            vector(require(mount, "xyz_m", f"{where}: mount"), 3, f"{where}: mount.xyz_m"),
            vector(require(mount, "rpy_rad", f"{where}: mount"), 3, f"{where}: mount.rpy_rad"),
        ),
        housing_size_m=vector(require(housing, "size_m", f"{where}: housing"), 3, f"{where}: housing.size_m"),
        housing_center_m=vector(
            require(housing, "center_xyz_m", f"{where}: housing"), 3, f"{where}: housing.center_xyz_m"
        ),
    )
