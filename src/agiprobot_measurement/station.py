"""The measurement station as configuration: robot, joint limits, named states, scanner and scene.

Everything station-specific is read from ``config/*.yaml`` (or files the caller names); this module turns the
files into checked, typed objects and fails with a :class:`ConfigError` that names the file and the bad key.
Units: metres and radians in the scene, robot and limits; the sensor model keeps the documented mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

PACKAGE_ROOT = Path(__file__).resolve().parents[2]
CONFIG_DIR = PACKAGE_ROOT / "config"
URDF_DIR = PACKAGE_ROOT / "urdf"

UNIT_SCALES_TO_M = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "in": 0.0254, "ft": 0.3048}


class ConfigError(ValueError):
    """A configuration file is missing, malformed, or has a bad or missing key."""


def read_yaml(path: str | Path) -> object:
    """Read a YAML file with ``safe_load``; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: file not found")
    try:
        with path.open() as stream:
            return yaml.safe_load(stream)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: malformed YAML: {exc}") from exc


def _require(mapping: object, key: str, where: str) -> object:
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise ConfigError(f"{where}: missing key '{key}'")
    return mapping[key]


def _vector(value: object, length: int, where: str) -> np.ndarray:
    try:
        vec = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}") from exc
    if vec.shape != (length,):
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}")
    if not np.all(np.isfinite(vec)):
        raise ConfigError(f"{where}: values must be finite, got {value!r}")
    return vec


def _positive(value: object, where: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected a number, got {value!r}") from exc
    if not math.isfinite(number) or number <= 0.0:
        raise ConfigError(f"{where}: must be a positive number, got {value!r}")
    return number


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z) to a 3x3 rotation matrix."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def pose_matrix(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 transform from a translation and URDF roll-pitch-yaw."""
    pose = np.eye(4)
    pose[:3, :3] = rpy_to_matrix(np.asarray(rpy, dtype=float))
    pose[:3, 3] = xyz
    return pose


# ----------------------------------------------------------------------------------------------- robot
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


def load_robot_config(path: str | Path | None = None) -> RobotConfig:
    path = Path(path) if path else CONFIG_DIR / "ur10e.yaml"
    data = read_yaml(path)
    where = str(path)
    names = _require(data, "joint_names", where)
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise ConfigError(f"{where}: 'joint_names' must be a list of distinct names")
    dh = _require(data, "dh", where)
    n = len(names)
    return RobotConfig(
        name=str(data.get("robot_name", "robot")),
        joint_names=tuple(names),
        d_m=_vector(_require(dh, "d_m", f"{where}: dh"), n, f"{where}: dh.d_m"),
        a_m=_vector(_require(dh, "a_m", f"{where}: dh"), n, f"{where}: dh.a_m"),
        alpha_rad=_vector(_require(dh, "alpha_rad", f"{where}: dh"), n, f"{where}: dh.alpha_rad"),
        base_frame=str(data.get("base_frame", "base_link")),
        flange_frame=str(data.get("flange_frame", "tool0")),
        planning_frame=str(data.get("planning_frame", "world")),
        default_tip_frame=str(data.get("default_tip_frame", "tool0")),
    )


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
    table = _require(data, "joint_limits", where)
    lower, upper, vel, acc = [], [], [], []
    for name in joint_names:
        entry = _require(table, name, f"{where}: joint_limits")
        here = f"{where}: joint_limits.{name}"
        for flag in ("has_position_limits", "has_velocity_limits", "has_acceleration_limits"):
            if not _require(entry, flag, here):
                raise ConfigError(f"{here}: '{flag}' must be true: the station needs every limit")
        lo = float(_require(entry, "min_position", here))
        hi = float(_require(entry, "max_position", here))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(f"{here}: need finite min_position < max_position, got {lo}, {hi}")
        lower.append(lo)
        upper.append(hi)
        vel.append(_positive(_require(entry, "max_velocity", here), f"{here}.max_velocity"))
        acc.append(_positive(_require(entry, "max_acceleration", here), f"{here}.max_acceleration"))
    return JointLimits(tuple(joint_names), np.array(lower), np.array(upper), np.array(vel), np.array(acc))


def load_named_states(path: str | Path | None = None, joint_count: int = 6) -> dict[str, np.ndarray]:
    path = Path(path) if path else CONFIG_DIR / "named_states.yaml"
    data = read_yaml(path)
    table = _require(data, "named_states", str(path))
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{path}: 'named_states' must be a non-empty mapping of name -> joint values")
    return {str(k): _vector(v, joint_count, f"{path}: named_states.{k}") for k, v in table.items()}


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
    model = _require(data, "sensor_model", where)
    params = {}
    for key in SENSOR_PARAMETER_KEYS:
        params[key] = _positive(_require(model, key, f"{where}: sensor_model"), f"{where}: sensor_model.{key}")
    for key, value in model.items():
        if key not in params:
            params[key] = value
    if not params["minimum_standoff_mm"] < params["optimal_standoff_mm"] < params["maximum_standoff_mm"]:
        raise ConfigError(f"{where}: sensor_model needs minimum < optimal < maximum standoff")
    mount = _require(data, "mount", where)
    housing = _require(data, "housing", where)
    return ScannerConfig(
        sensor_parameters=params,
        mount_pose=pose_matrix(
            _vector(_require(mount, "xyz_m", f"{where}: mount"), 3, f"{where}: mount.xyz_m"),
            _vector(_require(mount, "rpy_rad", f"{where}: mount"), 3, f"{where}: mount.rpy_rad"),
        ),
        housing_size_m=_vector(_require(housing, "size_m", f"{where}: housing"), 3, f"{where}: housing.size_m"),
        housing_center_m=_vector(
            _require(housing, "center_xyz_m", f"{where}: housing"), 3, f"{where}: housing.center_xyz_m"
        ),
    )


# -------------------------------------------------------------------------------------------------- scene
SCENE_OBJECT_TYPES = {
    "box": ("size_m",),
    "cylinder": ("radius_m", "length_m"),
    "sphere": ("radius_m",),
    "mesh": (),
    # a printed calibration chessboard on a flat backing board: pose = centre of the printed face, z out of it
    "chessboard": ("inner_corners", "square_m"),
}
CHESSBOARD_MARGIN_SQUARES = 1  # white border around the squares (the quiet zone OpenCV's detector needs)


def chessboard_board_size(inner_corners: tuple[int, int], square_m: float, thickness_m: float) -> np.ndarray:
    """Edge lengths (m) of a chessboard's backing board: (rows+1) x (cols+1) squares and the white margin."""
    rows, cols = inner_corners
    border = 2 * (CHESSBOARD_MARGIN_SQUARES + 1)  # the outer squares plus the margin on each side
    return np.array([(cols - 1 + border) * square_m, (rows - 1 + border) * square_m, thickness_m])


def chessboard_dark_squares(inner_corners: tuple[int, int], square_m: float) -> np.ndarray:
    """Centres (N, 2) of a chessboard's dark squares in its board frame (origin at the centre of the corners)."""
    rows, cols = inner_corners
    i, j = np.nonzero((np.add.outer(np.arange(rows + 1), np.arange(cols + 1)) % 2) == 0)
    return np.column_stack([(j - cols / 2.0) * square_m, (i - rows / 2.0) * square_m])


@dataclass(frozen=True)
class SceneObject:
    """A static obstacle. ``pose`` is 4x4 in the scene frame (metres); ``mesh`` is a path for type mesh."""

    name: str
    type: str
    pose: np.ndarray
    size_m: np.ndarray | None = None
    radius_m: float | None = None
    length_m: float | None = None
    mesh: Path | None = None
    mesh_scale: float = 1.0
    color_rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)
    #: optional group name, so a set of obstacles can be switched off together (e.g. ``wbk_mirrors``)
    group: str | None = None
    #: chessboard: inner corners (rows, columns), square edge (m), backing board thickness (m)
    inner_corners: tuple[int, int] | None = None
    square_m: float | None = None
    thickness_m: float | None = None

    def solid_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Edge lengths (m) and centre pose (4x4) of the solid of a box or a chessboard's backing board (its
        printed face is the chessboard's pose, the board lies behind it)."""
        if self.type == "box":
            return np.asarray(self.size_m, dtype=float), self.pose
        if self.type == "chessboard":
            behind = np.eye(4)
            behind[2, 3] = -self.thickness_m / 2.0
            return np.asarray(self.size_m, dtype=float), self.pose @ behind
        raise ValueError(f"scene object '{self.name}' ({self.type}) is not box-shaped")


@dataclass(frozen=True)
class PartPlacement:
    """The part to measure: mesh file, its unit (scale to metres) and pose in the scene frame."""

    name: str
    mesh: Path
    units: str
    scale_to_m: float
    pose: np.ndarray
    color_rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.2, 1.0)


@dataclass(frozen=True)
class Scene:
    frame_id: str
    robot_base_pose: np.ndarray  # world -> base_link, 4x4, metres
    objects: tuple[SceneObject, ...] = field(default_factory=tuple)
    part: PartPlacement | None = None
    source: Path | None = None

    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    def without_group(self, group: str) -> Scene:
        """The same scene without the objects of ``group``."""
        from dataclasses import replace

        return replace(self, objects=tuple(o for o in self.objects if o.group != group))


def _resolve_path(value: object, where: str, relative_to: Path) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: expected a file path, got {value!r}")
    path = Path(value).expanduser()
    if not path.is_absolute():
        # relative paths: first next to the scene file, then relative to the package root
        candidates = [relative_to / path, PACKAGE_ROOT / path]
        path = next((c for c in candidates if c.exists()), candidates[-1])
    if not path.is_file():
        raise ConfigError(f"{where}: file not found: {path}")
    return path


def _units(value: object, where: str) -> float:
    if value not in UNIT_SCALES_TO_M:
        raise ConfigError(f"{where}: unknown unit {value!r}; valid units: {', '.join(UNIT_SCALES_TO_M)}")
    return UNIT_SCALES_TO_M[value]


def _color(value: object, where: str, default: tuple) -> tuple:
    if value is None:
        return default
    vec = _vector(value, 4, where)
    if np.any(vec < 0) or np.any(vec > 1):
        raise ConfigError(f"{where}: colour components must lie in [0, 1]")
    return tuple(float(v) for v in vec)


def _pose_of(entry: dict, where: str) -> np.ndarray:
    xyz = _vector(_require(entry, "xyz_m", where), 3, f"{where}.xyz_m")
    rpy = _vector(entry.get("rpy_rad", [0.0, 0.0, 0.0]), 3, f"{where}.rpy_rad")
    return pose_matrix(xyz, rpy)


def _chessboard(entry: dict, where: str) -> dict:
    corners = entry["inner_corners"]
    if (
        not isinstance(corners, list)
        or len(corners) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 2 for v in corners)
    ):
        raise ConfigError(f"{where}.inner_corners: expected [rows, columns], integers >= 2, got {corners!r}")
    square = _positive(entry["square_m"], f"{where}.square_m")
    if square > 0.5:
        raise ConfigError(f"{where}.square_m: {square} m per square; the unit is metres (0.03 = 30 mm)")
    thickness = _positive(entry.get("thickness_m", 0.003), f"{where}.thickness_m")
    return {
        "inner_corners": tuple(corners),
        "square_m": square,
        "thickness_m": thickness,
        "size_m": chessboard_board_size(tuple(corners), square, thickness),
    }


def load_scene(path: str | Path | None = None) -> Scene:
    """Read a scene file (see ``config/scene.yaml``). Errors name the file and the bad key."""
    path = Path(path) if path else CONFIG_DIR / "scene.yaml"
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: a scene file must be a mapping")
    known = {"frame_id", "robot", "objects", "part"}
    unknown = set(data) - known
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; valid keys: {sorted(known)}")
    robot = _require(data, "robot", where)
    base_pose = pose_matrix(
        _vector(_require(robot, "base_xyz_m", f"{where}: robot"), 3, f"{where}: robot.base_xyz_m"),
        _vector(robot.get("base_rpy_rad", [0.0, 0.0, 0.0]), 3, f"{where}: robot.base_rpy_rad"),
    )
    objects = []
    raw_objects = data.get("objects") or []
    if not isinstance(raw_objects, list):
        raise ConfigError(f"{where}: 'objects' must be a list")
    seen = set()
    for i, entry in enumerate(raw_objects):
        here = f"{where}: objects[{i}]"
        name = _require(entry, "name", here)
        here = f"{where}: objects[{i}] ({name})"
        if name in seen:
            raise ConfigError(f"{here}: duplicate object name '{name}'")
        seen.add(name)
        kind = _require(entry, "type", here)
        if kind not in SCENE_OBJECT_TYPES:
            raise ConfigError(f"{here}: unknown type {kind!r}; valid types: {', '.join(SCENE_OBJECT_TYPES)}")
        for key in SCENE_OBJECT_TYPES[kind]:
            _require(entry, key, here)
        kwargs = {}
        if kind == "box":
            size = _vector(entry["size_m"], 3, f"{here}.size_m")
            if np.any(size <= 0):
                raise ConfigError(f"{here}.size_m: sizes must be positive")
            kwargs["size_m"] = size
        if kind in ("cylinder", "sphere"):
            kwargs["radius_m"] = _positive(entry["radius_m"], f"{here}.radius_m")
        if kind == "cylinder":
            kwargs["length_m"] = _positive(entry["length_m"], f"{here}.length_m")
        if kind == "mesh":
            kwargs["mesh"] = _resolve_path(_require(entry, "mesh", here), f"{here}.mesh", path.parent)
            kwargs["mesh_scale"] = _units(entry.get("units", "m"), f"{here}.units")
        if kind == "chessboard":
            kwargs.update(_chessboard(entry, here))
        objects.append(
            SceneObject(
                name=str(name),
                type=kind,
                pose=_pose_of(entry, here),
                color_rgba=_color(entry.get("color_rgba"), f"{here}.color_rgba", (0.6, 0.6, 0.6, 1.0)),
                group=None if entry.get("group") is None else str(entry["group"]),
                **kwargs,
            )
        )
    part = None
    if data.get("part") is not None:
        entry = data["part"]
        here = f"{where}: part"
        units = _require(entry, "units", here)
        part = PartPlacement(
            name=str(entry.get("name", "part")),
            mesh=_resolve_path(_require(entry, "mesh", here), f"{here}.mesh", path.parent),
            units=str(units),
            scale_to_m=_units(units, f"{here}.units"),
            pose=_pose_of(entry, here),
            color_rgba=_color(entry.get("color_rgba"), f"{here}.color_rgba", (0.8, 0.8, 0.2, 1.0)),
        )
    return Scene(
        frame_id=str(data.get("frame_id", "world")),
        robot_base_pose=base_pose,
        objects=tuple(objects),
        part=part,
        source=path,
    )


# ------------------------------------------------------------------------------------------------ station
@dataclass(frozen=True)
class Station:
    """Everything that defines the station, loaded from configuration files."""

    robot: RobotConfig
    limits: JointLimits
    named_states: dict
    scanner: ScannerConfig
    scene: Scene
    urdf_xml: str

    @classmethod
    def load(
        cls,
        robot: str | Path | None = None,
        joint_limits: str | Path | None = None,
        named_states: str | Path | None = None,
        scanner: str | Path | None = None,
        scene: str | Path | None = None,
    ) -> Station:
        from agiprobot_measurement.urdf_model import build_station_urdf

        robot_cfg = load_robot_config(robot)
        return cls(
            robot=robot_cfg,
            limits=load_joint_limits(joint_limits, robot_cfg.joint_names),
            named_states=load_named_states(named_states, len(robot_cfg.joint_names)),
            scanner=load_scanner_config(scanner),
            scene=load_scene(scene),
            urdf_xml=build_station_urdf(robot=robot, joint_limits=joint_limits, scanner=scanner, scene=scene),
        )
