"""The simulated PhoXi device behind ``nodes/phoxi_camera``: connection, acquisition, frames, spaces, files.

ROS-free: the node turns service requests into calls here and :class:`PhoxiError` into ``success: false`` with its
message. The semantics follow the real driver (``phoxi_camera``, ROS 1): frames are numbered from 0 in the order
they are triggered; a frame id < 0 means "trigger a new frame"; an id the device does not hold is an error.
Frames keep the coordinate space they were captured in (the scanner applies the space while it computes the cloud).

Coordinate spaces: 1 CameraSpace (the sensor frame), 4 RobotSpace and 5 CustomSpace (p' = R p + t with the
transformation set by ``set_transformation``; CustomSpace starts as identity, RobotSpace needs a transformation
first). 2 MountingSpace and 3 MarkerSpace need a marker calibration the simulated scanner does not have.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import require, vector
from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.errors import InternalError
from agiprobot_measurement.sensors.phoxi.point_cloud_io import (
    OutputPathError,
    resolve_output_path,
    write_ply,
    write_point_tiff,
    write_ptx,
)
from agiprobot_measurement.sensors.phoxi.renderer import (
    Frame,
    RayCaster,
    RobotGeometry,
    ScannerModel,
    ScanSettings,
    SceneGeometry,
    StructuredLightScanner,
    transform_points,
)
from agiprobot_measurement.station import (
    CONFIG_DIR,
    ConfigError,
    pose_matrix,
    read_yaml,
)

__all__ = [
    "API_VERSION",
    "CAMERA_CONFIG_FILE",
    "COORDINATE_SPACES",
    "FIRMWARE_VERSION",
    "OK",
    "SAVE_LAST_FRAME_EXTENSIONS",
    "WRITTEN_EXTENSIONS",
    "CameraConfig",
    "PhoxiDevice",
    "PhoxiError",
    "frame_output",
    "load_camera_config",
    "pose_from_entry",
    "transform_from_quaternion",
]

OK = "Ok"
CAMERA_SPACE, MOUNTING_SPACE, MARKER_SPACE, ROBOT_SPACE, CUSTOM_SPACE = 1, 2, 3, 4, 5
COORDINATE_SPACES = {1: "CameraSpace", 2: "MountingSpace", 3: "MarkerSpace", 4: "RobotSpace", 5: "CustomSpace"}
#: extensions V2/save_last_frame accepts (as the driver); the simulator writes ply, ptx and tif
SAVE_LAST_FRAME_EXTENSIONS = ("praw", "ply", "ptx", "tif", "prawf")
WRITTEN_EXTENSIONS = ("ply", "ptx", "tif")
API_VERSION = "1.2.35-sim"
FIRMWARE_VERSION = "1.2.35-sim"
CAMERA_CONFIG_FILE = CONFIG_DIR / "phoxi_camera.yaml"


class PhoxiError(InternalError):
    """A request the device refuses; the message is what the service answers."""


# --------------------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class CameraConfig:
    """Model and mounting of the simulated scanner (pose: parent_frame <- sensor frame, 4x4, metres)."""

    model: str
    parent_frame: str
    pose: np.ndarray
    source: Path | None = None


def pose_from_entry(entry: object, where: str) -> np.ndarray:
    """A pose from ``xyz_m`` and either ``rpy_rad`` or ``look_at_m`` (optical frame towards that point)."""
    xyz = vector(require(entry, "xyz_m", where), 3, f"{where}.xyz_m")
    has_rpy, has_target = "rpy_rad" in entry, "look_at_m" in entry
    if has_rpy == has_target:
        raise ConfigError(f"{where}: give exactly one of rpy_rad and look_at_m")
    if has_rpy:
        return pose_matrix(xyz, vector(entry["rpy_rad"], 3, f"{where}.rpy_rad"))
    target = vector(entry["look_at_m"], 3, f"{where}.look_at_m")
    try:
        return look_at(xyz, target)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def load_camera_config(path: str | Path | None = None) -> CameraConfig:
    path = Path(path) if path else CAMERA_CONFIG_FILE
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    return CameraConfig(
        model=str(require(data, "model", where)),
        parent_frame=str(data.get("parent_frame", "world")),
        pose=pose_from_entry(require(data, "pose", where), f"{where}: pose"),
        source=path,
    )


def transform_from_quaternion(translation, quaternion_xyzw) -> np.ndarray:
    """4x4 from a translation and a quaternion (x, y, z, w); the quaternion is normalised, a zero one refused."""
    q = np.asarray(quaternion_xyzw, dtype=float)
    t = np.asarray(translation, dtype=float)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
        raise PhoxiError("transformation must be finite")
    norm = np.linalg.norm(q)
    if norm < 1e-6:
        raise PhoxiError("transformation has a zero quaternion (rotation.w = 1 is the identity)")
    x, y, z, w = q / norm
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    pose[:3, 3] = t
    return pose


# --------------------------------------------------------------------------------------------- device
class PhoxiDevice:
    """One simulated scanner: state, frame store and file output. Not thread-safe: the node serialises calls."""

    def __init__(
        self,
        model: ScannerModel,
        scene: SceneGeometry,
        output_dir: str | Path,
        robot: RobotGeometry | None = None,
        hardware_identification: str | None = None,
        frame_buffer_size: int = 3,
        settings: ScanSettings | None = None,
    ):
        if frame_buffer_size < 1:
            raise ValueError("frame_buffer_size must be at least 1")
        self.model = model
        self.scanner = StructuredLightScanner(model)
        self.scene = scene
        self.robot = robot
        self.output_dir = Path(output_dir).expanduser().resolve()
        self.hardware_identification = hardware_identification or f"PhoXi3DScanner-{model.name}-sim"
        self.frame_buffer_size = int(frame_buffer_size)
        self.settings = settings or ScanSettings()
        self.connected = False
        self.acquiring = False
        self.coordinate_space = CAMERA_SPACE
        self.transformations = {CUSTOM_SPACE: np.eye(4)}
        self.frames: OrderedDict[int, Frame] = OrderedDict()
        self.next_index = 0
        self.last_frame: Frame | None = None

    # -------------------------------------------------------------------------- connection, acquisition
    def connect(self, name: str = "") -> None:
        """Connect to this scanner: ``name`` is its hardware identification, or empty for the default."""
        if name not in ("", self.hardware_identification):
            raise PhoxiError(f"Scanner not found: '{name}' (available: {self.hardware_identification})")
        self.connected = True
        self.acquiring = True

    def disconnect(self) -> None:
        self.connected = False
        self.acquiring = False

    def _require_connected(self) -> None:
        if not self.connected:
            raise PhoxiError("Scanner is not connected (call connect_camera)")

    def start_acquisition(self) -> None:
        self._require_connected()
        self.acquiring = True

    def stop_acquisition(self) -> None:
        self._require_connected()
        self.acquiring = False

    def status(self) -> tuple[str, str]:
        """(level, message) of the driver's diagnostics: OK Ready / WARN Acquisition not started / ERROR Not connected."""
        if not self.connected:
            return "ERROR", "Not connected"
        if not self.acquiring:
            return "WARN", "Acquisition not started"
        return "OK", "Ready"

    # ------------------------------------------------------------------------------------------ frames
    def trigger(self, camera_pose: np.ndarray, link_poses: dict | None = None) -> Frame:
        """Take a new frame of the scene (and the robot at ``link_poses``) from ``camera_pose`` (world <- sensor)."""
        self._require_connected()
        if not self.acquiring:
            raise PhoxiError("Acquisition not started (call start_acquisition)")
        parts = [self.scene]
        if self.robot is not None and link_poses:
            parts.append(self.robot.posed(link_poses))
        geometry = SceneGeometry.concatenate(parts)
        index = self.next_index
        frame = self.scanner.capture(geometry, camera_pose, self.settings, index, RayCaster(geometry))
        frame.coordinate_space = self.coordinate_space
        frame.output_transform = self.output_transform().copy()
        self.next_index += 1
        self.frames[index] = frame
        while len(self.frames) > self.frame_buffer_size:
            self.frames.popitem(last=False)
        return frame

    def frame(self, index: int) -> Frame:
        """A frame this device still holds (the last ``frame_buffer_size`` ones)."""
        self._require_connected()
        if index not in self.frames:
            held = ", ".join(str(i) for i in self.frames) or "none"
            raise PhoxiError(f"Frame {index} is not available (frames held: {held}; an id < 0 takes a new frame)")
        return self.frames[index]

    def get_frame(self, index: int, camera_pose: np.ndarray, link_poses: dict | None = None) -> Frame:
        """The driver's getPFrame: a new frame for ``index < 0``, else the stored one."""
        return self.trigger(camera_pose, link_poses) if index < 0 else self.frame(index)

    def mark_published(self, frame: Frame) -> None:
        self.last_frame = frame

    # ----------------------------------------------------------------------------------------- settings
    def update_settings(self, **changes) -> None:
        self.settings = replace(self.settings, **changes)

    # -------------------------------------------------------------------------------- coordinate spaces
    def output_transform(self, space: int | None = None) -> np.ndarray:
        space = self.coordinate_space if space is None else space
        return np.eye(4) if space == CAMERA_SPACE else self.transformations[space]

    def check_space(self, space: int) -> None:
        if space not in COORDINATE_SPACES:
            known = ", ".join(f"{k} {v}" for k, v in COORDINATE_SPACES.items())
            raise PhoxiError(f"Unknown coordinate space {space} (known: {known})")
        if space in (MOUNTING_SPACE, MARKER_SPACE):
            raise PhoxiError(
                f"{COORDINATE_SPACES[space]} needs a marker calibration that the simulated scanner does not have "
                "(use 1 CameraSpace, or 5 CustomSpace with V2/set_transformation)"
            )
        if space != CAMERA_SPACE and space not in self.transformations:
            raise PhoxiError(
                f"{COORDINATE_SPACES[space]} has no transformation yet: set one with V2/set_transformation"
            )

    def set_coordinate_space(self, space: int) -> None:
        self.check_space(int(space))
        self.coordinate_space = int(space)

    def set_transformation(self, matrix: np.ndarray, space: int, set_space: bool, save_settings: bool) -> None:
        """Store the transformation of RobotSpace or CustomSpace; ``set_space`` also switches to that space.

        ``save_settings`` is accepted: the real scanner persists the transformation in PhoXi Control, the simulated
        one keeps it for the node's lifetime either way.
        """
        space = int(space)
        if space not in (ROBOT_SPACE, CUSTOM_SPACE):
            name = COORDINATE_SPACES.get(space, f"unknown space {space}")
            raise PhoxiError(f"A transformation can be set for 4 RobotSpace and 5 CustomSpace only, not {name}")
        matrix = np.asarray(matrix, dtype=float)
        if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
            raise PhoxiError("transformation must be a finite 4x4 matrix")
        rotation = matrix[:3, :3]
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            raise PhoxiError("transformation's rotation is not a proper rotation")
        self.transformations[space] = matrix.copy()
        if set_space:
            self.coordinate_space = space

    # -------------------------------------------------------------------------------------------- files
    def output_path(self, requested: str) -> Path:
        try:
            return resolve_output_path(self.output_dir, requested)
        except OutputPathError as exc:
            raise PhoxiError(str(exc)) from exc

    def save_frame(self, frame: Frame, requested: str, organized: bool = True) -> Path:
        """The frame as binary PLY at ``requested`` (inside the output directory), whatever its extension (as the driver)."""
        path = self.output_path(requested)
        return self._write_ply(frame, path, organized)

    def save_last_frame(self, requested: str, organized: bool = True) -> Path:
        """The last published frame in the format its extension names (ply, ptx, tif)."""
        extension = Path(str(requested)).suffix.lower().lstrip(".")
        if extension not in SAVE_LAST_FRAME_EXTENSIONS:
            raise PhoxiError("Wrong extension.")
        if extension not in WRITTEN_EXTENSIONS:
            raise PhoxiError(
                f"Extension .{extension} is the PhoXi Control raw format, which the simulated scanner does not write "
                f"(it writes {', '.join('.' + e for e in WRITTEN_EXTENSIONS)})"
            )
        if self.last_frame is None:
            raise PhoxiError("There is no frame to save: trigger or get a frame first")
        path = self.output_path(requested)
        frame = self.last_frame
        if extension == "ply":
            return self._write_ply(frame, path, organized)
        points, _ = frame_output(frame)
        if extension == "ptx":
            scale = max(float(frame.texture.max()), 1.0)
            return write_ptx(path, points, frame.texture / scale)
        return write_point_tiff(path, points)

    def _write_ply(self, frame: Frame, path: Path, organized: bool) -> Path:
        points, normals = frame_output(frame)
        scalars = {"intensity": frame.texture, "confidence": frame.confidence}
        comments = [
            f"PhoXi 3D scanner {frame.model} (simulated), frame {frame.index}",
            "units: metres",
            f"coordinate space: {COORDINATE_SPACES[frame.coordinate_space]}",
        ]
        if organized:
            comments.append(f"organized: width {frame.width} height {frame.height} (invalid points are 0 0 0)")
            return write_ply(path, points, normals, scalars, tuple(comments))
        keep = frame.valid.reshape(-1)
        return write_ply(
            path,
            points.reshape(-1, 3)[keep],
            normals.reshape(-1, 3)[keep],
            {k: v.reshape(-1)[keep] for k, v in scalars.items()},
            tuple(comments),
        )


def frame_output(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Points (m) and normals (H, W, 3) float32 of a frame in the coordinate space it was captured in."""
    points = frame.points_m()
    if np.array_equal(frame.output_transform, np.eye(4)):
        return points, frame.normals
    return transform_points(points, frame.normals, frame.valid, frame.output_transform)
