"""The scene file: robot mounting, static obstacles (boxes, cylinders, spheres, meshes, chessboards), the part."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR, PACKAGE_ROOT
from agiprobot_measurement.common.config import ConfigError, positive, read_yaml, require, vector
from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.station.ur_kinematics import BASE_LINK_TO_BASE

__all__ = [
    "CHESSBOARD_MARGIN_SQUARES",
    "SCENE_OBJECT_TYPES",
    "PartPlacement",
    "Scene",
    "SceneObject",
    "SceneObjectError",
    "chessboard_board_size",
    "chessboard_dark_squares",
    "load_scene",
]


SCENE_OBJECT_TYPES = {
    "box": ("size_m",),
    "cylinder": ("radius_m", "length_m"),
    "sphere": ("radius_m",),
    "mesh": (),
    # a printed calibration chessboard on a flat backing board: pose = centre of the printed face, z out of it
    "chessboard": ("inner_corners", "square_m"),
}
CHESSBOARD_MARGIN_SQUARES = 1  # white border around the squares (the quiet zone OpenCV's detector needs)


class SceneObjectError(InputError):
    """A scene object is asked for a shape it does not have."""


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
        raise SceneObjectError(f"scene object '{self.name}' ({self.type}) is not box-shaped")


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
    robot_base_pose: np.ndarray  # world -> base_link (ur_description's REP-103 base frame), 4x4, metres
    objects: tuple[SceneObject, ...] = field(default_factory=tuple)
    part: PartPlacement | None = None
    source: Path | None = None

    @property
    def robot_dh_base_pose(self) -> np.ndarray:
        """world -> base: the robot's DH base frame (the UR controller's Base, ``base_link`` turned by pi about z;
        the robot base frame of the calibration), 4x4, metres."""
        return self.robot_base_pose @ BASE_LINK_TO_BASE

    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    def without_group(self, group: str) -> Scene:
        """The same scene without the objects of ``group``."""
        return replace(self, objects=tuple(o for o in self.objects if o.group != group))

    def without_part(self) -> Scene:
        """The same scene without its part (the obstacles only)."""
        return replace(self, part=None)


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
    vec = vector(value, 4, where)
    if np.any(vec < 0) or np.any(vec > 1):
        raise ConfigError(f"{where}: colour components must lie in [0, 1]")
    return tuple(float(v) for v in vec)


def _pose_of(entry: dict, where: str) -> np.ndarray:
    xyz = vector(require(entry, "xyz_m", where), 3, f"{where}.xyz_m")
    rpy = vector(entry.get("rpy_rad", [0.0, 0.0, 0.0]), 3, f"{where}.rpy_rad")
    return pose_matrix(xyz, rpy)


def _chessboard(entry: dict, where: str) -> dict:
    corners = entry["inner_corners"]
    if (
        not isinstance(corners, list)
        or len(corners) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 2 for v in corners)
    ):
        raise ConfigError(f"{where}.inner_corners: expected [rows, columns], integers >= 2, got {corners!r}")
    square = positive(entry["square_m"], f"{where}.square_m")
    if square > 0.5:
        raise ConfigError(f"{where}.square_m: {square} m per square; the unit is metres (0.03 = 30 mm)")
    thickness = positive(entry.get("thickness_m", 0.003), f"{where}.thickness_m")
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
    robot = require(data, "robot", where)
    base_pose = pose_matrix(
        vector(require(robot, "base_xyz_m", f"{where}: robot"), 3, f"{where}: robot.base_xyz_m"),
        vector(robot.get("base_rpy_rad", [0.0, 0.0, 0.0]), 3, f"{where}: robot.base_rpy_rad"),
    )
    objects = []
    raw_objects = data.get("objects") or []
    if not isinstance(raw_objects, list):
        raise ConfigError(f"{where}: 'objects' must be a list")
    seen = set()
    for i, entry in enumerate(raw_objects):
        here = f"{where}: objects[{i}]"
        name = require(entry, "name", here)
        here = f"{where}: objects[{i}] ({name})"
        if name in seen:
            raise ConfigError(f"{here}: duplicate object name '{name}'")
        seen.add(name)
        kind = require(entry, "type", here)
        if kind not in SCENE_OBJECT_TYPES:
            raise ConfigError(f"{here}: unknown type {kind!r}; valid types: {', '.join(SCENE_OBJECT_TYPES)}")
        for key in SCENE_OBJECT_TYPES[kind]:
            require(entry, key, here)
        kwargs = {}
        if kind == "box":
            size = vector(entry["size_m"], 3, f"{here}.size_m")
            if np.any(size <= 0):
                raise ConfigError(f"{here}.size_m: sizes must be positive")
            kwargs["size_m"] = size
        if kind in ("cylinder", "sphere"):
            kwargs["radius_m"] = positive(entry["radius_m"], f"{here}.radius_m")
        if kind == "cylinder":
            kwargs["length_m"] = positive(entry["length_m"], f"{here}.length_m")
        if kind == "mesh":
            kwargs["mesh"] = _resolve_path(require(entry, "mesh", here), f"{here}.mesh", path.parent)
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
        units = require(entry, "units", here)
        part = PartPlacement(
            name=str(entry.get("name", "part")),
            mesh=_resolve_path(require(entry, "mesh", here), f"{here}.mesh", path.parent),
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
