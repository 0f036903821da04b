"""The simulated PhoXi device behind ``nodes/phoxi_camera``: connection, acquisition, frames, spaces, files.

ROS-free: the node turns service requests into calls here and :class:`PhoxiError` into ``success: false`` with its
message. The semantics follow the real driver (``phoxi_camera`` 1.8.0, ROS 1: RosInterface.cpp and
PhoXiInterface.cpp): the device lists the configured scanners (:class:`~.models.SimulatedScanner`) and connects only
to one of them by its hardware identification ("" is not a scanner); connecting sets the software trigger and
starts acquisition; triggering a frame (``trigger`` or a frame id < 0) switches to the software trigger and starts
acquisition when it is stopped; frames are numbered from 0 in the order they are taken; an id the device does not
hold is an error. Frames keep the coordinate space they were captured in (the scanner applies the space while it
computes the cloud).

Coordinate spaces 1 CameraSpace (the sensor frame), 2 MountingSpace, 3 MarkerSpace, 4 RobotSpace and 5 CustomSpace
(p' = A p + t with the space's transformation, identity until one is set; the simulated scanner has no marker
calibration, so MountingSpace and MarkerSpace stay identity); 0 (NoValue) is accepted and leaves the space as it
is. ``set_transformation`` stores the transformation of RobotSpace or CustomSpace and switches to that space
whatever ``set_space`` says (PhoXiInterface.cpp sets the space in both cases). The transformation is taken from a
translation and a quaternion as the driver's Eigen conversion does (unnormalised: a zero quaternion is the
identity, as ``geometry_msgs/Transform()`` gives it); it must be finite, its translation at most
:data:`MAX_TRANSLATION_M` long and its linear part at most :data:`MAX_LINEAR_ENTRY` per entry, so that every later
frame stays finite; a refused one changes nothing.

Files follow the package's one file policy (:class:`~agiprobot_measurement.common.files.FileRoot`, see
:class:`PhoxiDevice`); reconfigured numbers that are not finite are put back (:meth:`PhoxiDevice.reconfigure`).
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from agiprobot_measurement.common.config import require, vector
from agiprobot_measurement.common.files import FileRoot, PathPolicyError
from agiprobot_measurement.common.geometry import look_at, matrix_to_rpy
from agiprobot_measurement.common.limits import excerpt
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.sensors.error_models import ErrorModel, PhoxiErrors
from agiprobot_measurement.sensors.phoxi import reconfigure as phoxi_config
from agiprobot_measurement.sensors.phoxi.models import SIMULATED_SCANNER_ID, ScannerModel, SimulatedScanner
from agiprobot_measurement.sensors.phoxi.point_cloud_io import (
    write_ply,
    write_point_tiff,
    write_ptx,
)
from agiprobot_measurement.sensors.phoxi.renderer import (
    Frame,
    RayCaster,
    ScanSettings,
    StructuredLightScanner,
    transform_points,
)
from agiprobot_measurement.sensors.phoxi.scene_geometry import RobotGeometry, SceneGeometry
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
    "MAX_LINEAR_ENTRY",
    "MAX_TRANSLATION_M",
    "NOT_CONNECTED",
    "NO_VALUE_SPACE",
    "OK",
    "RAW_EXTENSIONS",
    "SAVE_LAST_FRAME_EXTENSIONS",
    "SETTING_NAMES",
    "TRIGGER_FREERUN",
    "TRIGGER_SOFTWARE",
    "WRITTEN_EXTENSIONS",
    "CameraConfig",
    "PhoxiDevice",
    "PhoxiError",
    "ScenePoses",
    "check_reconfigure_changes",
    "check_transformation",
    "default_allowed_save_dirs",
    "default_output_dir",
    "frame_output",
    "load_camera_config",
    "overridden_pose",
    "pose_from_entry",
    "transform_from_quaternion",
]

OK = "Ok"
#: what the driver answers when no scanner is connected (PhoXiInterface::isOk)
NOT_CONNECTED = "No scanner connected"
NO_VALUE_SPACE, CAMERA_SPACE, MOUNTING_SPACE, MARKER_SPACE, ROBOT_SPACE, CUSTOM_SPACE = 0, 1, 2, 3, 4, 5
COORDINATE_SPACES = {1: "CameraSpace", 2: "MountingSpace", 3: "MarkerSpace", 4: "RobotSpace", 5: "CustomSpace"}
#: pho::api::PhoXiTriggerMode values the simulator runs (Hardware 2 needs a trigger cable)
TRIGGER_FREERUN, TRIGGER_SOFTWARE = 0, 1
TRIGGER_MODE_NAMES = {0: "Freerun", 1: "Software", 2: "Hardware", 3: "NoValue"}
#: extensions V2/save_last_frame accepts (as the driver); the simulator writes ply, ptx and tif
SAVE_LAST_FRAME_EXTENSIONS = ("praw", "ply", "ptx", "tif", "prawf")
WRITTEN_EXTENSIONS = ("ply", "ptx", "tif")
#: PhoXi Control's raw formats: the real scanner writes them, the simulated one cannot
RAW_EXTENSIONS = ("praw", "prawf")
#: largest accepted translation of a coordinate-space transformation: a station is metres across, and beyond this
#: every point of a frame loses its millimetres (1e308 made every point inf)
MAX_TRANSLATION_M = 1e3
#: largest accepted entry of a transformation's linear part (a rotation's are at most 1; the driver passes a
#: non-unit quaternion's matrix on unnormalised, which scales the cloud by the quaternion's squared norm)
MAX_LINEAR_ENTRY = 1e3
API_VERSION = "1.2.35-sim"
CAMERA_CONFIG_FILE = CONFIG_DIR / "phoxi_camera.yaml"
#: the reconfigurable parameters that are capturing settings (ScanSettings' fields)
SETTING_NAMES = (
    "resolution",
    "scan_multiplier",
    "shutter_multiplier",
    "single_pattern_exposure",
    "confidence",
    "ambient_light_suppression",
    "camera_only_mode",
)

_DOUBLE_PARAMETERS = tuple(entry[0] for entry in phoxi_config.PARAMETERS if entry[1] == "double")


class PhoxiError(InputError):
    """A request the device refuses (a bad argument, or one the device's state does not allow: the client must
    change it); the message is what the service answers."""


def _typed_value(name: str, kind: str, value):
    """``value`` as parameter ``name`` of type ``kind`` holds it, or PhoxiError. dynamic_reconfigure's message has a
    list per type and takes a name from any of them: an int parameter accepts an integral number (not a bool), a
    double any real number, a bool a bool or the int 0 / 1; a string is no value of any of them."""
    if kind == "bool":
        if isinstance(value, bool):
            return value
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        expected = "a bool (true / false)"
    elif kind == "int":
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and math.isfinite(value) and value == int(value):
            return int(value)
        expected = "an integer"
    elif kind == "double":
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        expected = "a number"
    else:
        return value
    raise PhoxiError(f"parameter {name} is {kind}: got {type(value).__name__} {excerpt(value)}, expected {expected}")


def check_reconfigure_changes(changes: Mapping) -> dict:
    """The changes of a set_parameters request with every known parameter converted to its type, or PhoxiError
    naming each value of the wrong type (the request is refused whole and changes nothing). Names the driver does
    not know pass through unchanged, as dynamic_reconfigure ignores them."""
    checked = dict(changes)
    refusals = []
    for name, value in changes.items():
        kind = phoxi_config.type.get(name) if isinstance(name, str) else None
        if kind is None:
            continue
        try:
            checked[name] = _typed_value(name, kind, value)
        except PhoxiError as exc:
            refusals.append(str(exc))
    if refusals:
        raise PhoxiError("set_parameters refused, nothing changed: " + "; ".join(refusals))
    return checked


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
    """4x4 from a translation (m) and a quaternion (x, y, z, w) as the driver builds it (``tf::transformMsgToEigen``:
    Eigen's quaternion-to-matrix formula, not normalised, so a zero quaternion gives the identity and a unit one its
    rotation); refused (:class:`PhoxiError`) when not finite or beyond the bounds of :func:`check_transformation`."""
    translation = np.asarray(translation, dtype=float)
    quaternion = np.asarray(quaternion_xyzw, dtype=float)
    if translation.shape != (3,) or quaternion.shape != (4,):
        raise PhoxiError("transformation needs a translation (x, y, z) and a quaternion (x, y, z, w)")
    if not (np.all(np.isfinite(quaternion)) and np.all(np.isfinite(translation))):
        raise PhoxiError(
            f"transformation must be finite, got translation {translation.tolist()}, rotation {quaternion.tolist()}"
        )
    x, y, z, w = quaternion
    with np.errstate(over="ignore", invalid="ignore"):
        linear = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    matrix[:3, 3] = translation
    return check_transformation(matrix)


def check_transformation(matrix) -> np.ndarray:
    """``matrix`` as a 4x4 float array if the scanner can apply it to every later frame: finite, last row 0 0 0 1,
    translation at most :data:`MAX_TRANSLATION_M` long, linear entries at most :data:`MAX_LINEAR_ENTRY`; else
    :class:`PhoxiError` naming the bad part. (The driver checks nothing; these bounds only keep frames finite.)"""
    matrix = np.asarray(matrix, dtype=float)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise PhoxiError("transformation must be a finite 4x4 matrix (a quaternion too large gives infinite entries)")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise PhoxiError(f"transformation's last row must be 0 0 0 1, got {matrix[3].tolist()}")
    largest = float(np.abs(matrix[:3, :3]).max())
    if largest > MAX_LINEAR_ENTRY:
        raise PhoxiError(
            f"transformation's rotation part has an entry of {largest:.3g}, beyond {MAX_LINEAR_ENTRY:g} "
            "(a unit quaternion gives a rotation, whose entries are at most 1)"
        )
    length = math.hypot(*matrix[:3, 3])
    if length > MAX_TRANSLATION_M:
        raise PhoxiError(
            f"transformation's translation {matrix[:3, 3].tolist()} m is {length:.3g} m long, beyond the "
            f"{MAX_TRANSLATION_M:g} m a coordinate space may be shifted"
        )
    return matrix


def overridden_pose(pose: np.ndarray, xyz_m: np.ndarray | None = None, rpy_rad: np.ndarray | None = None) -> np.ndarray:
    """``pose`` (4x4) with its position and/or its roll, pitch, yaw replaced (None keeps the pose's own)."""
    if xyz_m is None and rpy_rad is None:
        return np.array(pose, dtype=float)
    return pose_matrix(
        pose[:3, 3] if xyz_m is None else xyz_m, matrix_to_rpy(pose[:3, :3]) if rpy_rad is None else rpy_rad
    )


def _ros_home(environ: Mapping[str, str]) -> Path:
    return Path(environ.get("ROS_HOME") or str(Path("~/.ros").expanduser()))


def default_output_dir(environ: Mapping[str, str] | None = None) -> Path:
    """``$ROS_HOME/phoxi_frames`` (ROS_HOME defaults to ~/.ros): a folder for frames that scripts and tools save (the
    node itself resolves relative names under its working directory, as the driver)."""
    return _ros_home(os.environ if environ is None else environ) / "phoxi_frames"


def default_allowed_save_dirs(environ: Mapping[str, str] | None = None, cwd: str | Path | None = None) -> list[Path]:
    """Where absolute save paths may point unless ``~allowed_save_dirs`` says otherwise: the working directory,
    ROS_HOME and /tmp (the real driver writes anywhere; the simulator only where a ROS user's files go)."""
    environ = os.environ if environ is None else environ
    return [Path(cwd or os.getcwd()), _ros_home(environ), Path("/tmp")]


class ScenePoses(Protocol):
    """Where the camera and the robot's links are when a frame is taken (scene frame, 4x4, metres)."""

    def camera_pose(self) -> np.ndarray:
        """scene frame <- sensor frame."""

    def link_poses(self, link_names: list[str]) -> dict[str, np.ndarray]:
        """Poses of those links that are known; unknown links are left out."""


# --------------------------------------------------------------------------------------------- device
class PhoxiDevice:
    """The simulated PhoXi Control with its scanners: state, frame store and file output. Not thread-safe: the node
    serialises calls, except the writers that :meth:`frame_writer` and :meth:`last_frame_writer` return: they touch
    only the frame they were given, so the node runs them outside its lock.

    ``scanners`` is the device list (default: one scanner :data:`~.models.SIMULATED_SCANNER_ID`, or
    ``hardware_identification``, of ``model``); the device starts disconnected. Capturing settings belong to the
    device and are kept across connections.

    Files: requested names resolve under ``output_dir`` (the node's working directory, as the driver's paths); a
    leading ``~`` is the home folder (as the driver replaces it with ``$HOME``); absolute names may also point into
    ``allowed_dirs``; ``..`` and anything else (symlinks resolved) are refused with a message naming the allowed
    folders (:class:`~agiprobot_measurement.common.files.FileRoot`). An existing file is replaced, as the driver does
    (its API has no overwrite flag), atomically.
    """

    def __init__(
        self,
        model: ScannerModel,
        scene: SceneGeometry,
        output_dir: str | Path,
        robot: RobotGeometry | None = None,
        hardware_identification: str | None = None,
        frame_buffer_size: int = 3,
        settings: ScanSettings | None = None,
        allowed_dirs: Iterable[str | Path] = (),
        scanners: Iterable[SimulatedScanner] | None = None,
        environ: Mapping[str, str] | None = None,
        error_model: ErrorModel | None = None,
    ):
        if frame_buffer_size < 1:
            raise ConfigError("frame_buffer_size must be at least 1")
        self.scanners = list(scanners or [SimulatedScanner(hardware_identification or SIMULATED_SCANNER_ID, model)])
        if not self.scanners:
            raise ConfigError("the simulated PhoXi Control needs at least one scanner")
        self.default_model = model
        self.scene = scene
        self.robot = robot
        self.files = FileRoot(Path(output_dir), tuple(Path(d) for d in allowed_dirs), purpose="PhoXi frame file")
        self.output_dir = self.files.root
        self.environ = os.environ if environ is None else environ
        self.frame_buffer_size = int(frame_buffer_size)
        self.settings = settings or ScanSettings()
        self.current: SimulatedScanner | None = None
        self._scanner_optics: dict[str, StructuredLightScanner] = {}
        #: the error model each scanner's errors are drawn from (per hw_identification); None = noise model only
        self.error_model = error_model
        self.acquiring = False
        self.trigger_mode = TRIGGER_SOFTWARE
        self.coordinate_space = CAMERA_SPACE
        self.transformations = {space: np.eye(4) for space in COORDINATE_SPACES if space != CAMERA_SPACE}
        self.frames: OrderedDict[int, Frame] = OrderedDict()
        self.next_index = 0
        self.last_frame: Frame | None = None

    # -------------------------------------------------------------------------- connection, acquisition
    @property
    def connected(self) -> bool:
        return self.current is not None

    @property
    def model(self) -> ScannerModel:
        """The connected scanner's model (the default model while disconnected)."""
        return self.current.model if self.current is not None else self.default_model

    @property
    def hardware_identification(self) -> str:
        """The connected scanner's id, else the first listed one (what a script would connect to)."""
        return (self.current or self.scanners[0]).hw_identification

    def device_list(self) -> list[SimulatedScanner]:
        return list(self.scanners)

    def connect(self, name: str) -> None:
        """The driver's connectCamera: connect to the listed scanner ``name`` (its hardware identification), with the
        software trigger and acquisition started; connecting again to the connected one only does the latter."""
        name = str(name)
        if self.current is not None and self.current.hw_identification == name:
            self.set_trigger_mode(TRIGGER_SOFTWARE, True)
            return
        scanner = next((s for s in self.scanners if s.hw_identification == name), None)
        if scanner is None:
            listed = ", ".join(s.hw_identification for s in self.scanners)
            raise PhoxiError(f"Scanner not found: '{name}' (the simulated PhoXi Control lists {listed})")
        self.disconnect()
        self.current = scanner
        self.trigger_mode = TRIGGER_SOFTWARE
        self.acquiring = True

    def disconnect(self) -> None:
        """Disconnect (nothing happens when not connected); the frames of the connection are gone."""
        self.current = None
        self.acquiring = False
        self.frames.clear()
        self.last_frame = None

    def _require_connected(self) -> None:
        if not self.connected:
            raise PhoxiError(NOT_CONNECTED)

    def start_acquisition(self) -> None:
        self._require_connected()
        self.acquiring = True

    def stop_acquisition(self) -> None:
        self._require_connected()
        self.acquiring = False

    def set_trigger_mode(self, mode: int, start_acquisition: bool) -> None:
        """The driver's setTriggerMode: the trigger mode (0 free run, 1 software), then acquisition started or
        stopped as ``start_acquisition`` says."""
        mode = int(mode)
        if mode not in (TRIGGER_FREERUN, TRIGGER_SOFTWARE):
            raise PhoxiError(
                f"Invalid trigger mode {mode}: the simulated scanner runs 0 Freerun and 1 Software (a hardware "
                "trigger needs the cable)"
            )
        self._require_connected()
        self.trigger_mode = mode
        self.acquiring = bool(start_acquisition)

    def status(self) -> tuple[str, str]:
        """(level, message) of the driver's diagnostics: OK Ready / WARN Acquisition not started / ERROR Not connected."""
        if not self.connected:
            return "ERROR", "Not connected"
        if not self.acquiring:
            return "WARN", "Acquisition not started"
        return "OK", "Ready"

    def diagnostic_values(self) -> list[tuple[str, str]]:
        """The driver's diagnostics key/values: HardwareIdentification and Trigger mode while connected, else none."""
        if not self.connected:
            return []
        return [
            ("HardwareIdentification", self.current.hw_identification),
            ("Trigger mode", TRIGGER_MODE_NAMES.get(self.trigger_mode, "Undefined")),
        ]

    # ------------------------------------------------------------------------------------------ frames
    def trigger(self, camera_pose: np.ndarray, link_poses: dict | None = None) -> Frame:
        """The driver's triggerImage: switch to the software trigger, start acquisition, take a new frame of the scene
        (and the robot at ``link_poses``) from ``camera_pose`` (world <- sensor)."""
        self.set_trigger_mode(TRIGGER_SOFTWARE, True)
        return self._take(camera_pose, link_poses)

    def free_run_frame(self, camera_pose: np.ndarray, link_poses: dict | None = None) -> Frame:
        """A frame the scanner takes by itself in free-run mode (the trigger mode stays)."""
        self._require_connected()
        if not self.free_running():
            raise PhoxiError("the scanner is not in free run with acquisition started")
        return self._take(camera_pose, link_poses)

    def _take(self, camera_pose: np.ndarray, link_poses: dict | None) -> Frame:
        parts = [self.scene]
        if self.robot is not None and link_poses:
            parts.append(self.robot.posed(link_poses))
        geometry = SceneGeometry.concatenate(parts)
        index = self.next_index
        key = self.current.hw_identification
        optics = self._scanner_optics.get(key)
        if optics is None or optics.model is not self.model:
            errors = PhoxiErrors.create(self.model, key, self.error_model)
            optics = self._scanner_optics[key] = StructuredLightScanner(self.model, errors=errors)
        frame = optics.capture(geometry, camera_pose, self.settings, index, RayCaster(geometry))
        frame.coordinate_space = self.coordinate_space
        frame.output_transform = self.output_transform().copy()
        frame.outputs = self.current.frame_outputs
        self.next_index += 1
        self.frames[index] = frame
        while len(self.frames) > self.frame_buffer_size:
            self.frames.popitem(last=False)
        self.last_frame = frame
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

    def capture(self, index: int, poses: ScenePoses) -> Frame:
        """:meth:`get_frame` with the poses asked of ``poses`` only when a new frame is taken."""
        if index >= 0:
            return self.frame(index)
        self._require_connected()
        return self.trigger(poses.camera_pose(), self._link_poses(poses))

    def capture_free_run(self, poses: ScenePoses) -> Frame:
        """:meth:`free_run_frame` with the poses asked of ``poses``."""
        self._require_connected()
        return self.free_run_frame(poses.camera_pose(), self._link_poses(poses))

    def _link_poses(self, poses: ScenePoses) -> dict:
        return poses.link_poses(self.robot.link_names) if self.robot is not None else {}

    def save_captured_frame(self, index: int, requested: str, poses: ScenePoses, organized: bool = True):
        """The driver's saveFrame: frame ``index`` (a new one for < 0) as PLY; a bad path is refused before rendering.

        Returns (frame, path written)."""
        frame, write = self.capture_for_saving(index, requested, poses, organized)
        return frame, write()

    def capture_for_saving(self, index: int, requested: str, poses: ScenePoses, organized: bool = True):
        """The part of :meth:`save_captured_frame` that needs the device: (frame, writer); the writer writes the file."""
        self.output_path(requested, ply_only=True)
        frame = self.capture(index, poses)
        return frame, self.frame_writer(frame, requested, organized)

    # ---------------------------------------------------------------------------------------- information
    def require_connected(self) -> None:
        """PhoxiError unless connected: what hardware identification and capturing modes need."""
        self._require_connected()

    def supported_capturing_modes(self) -> list[tuple[int, int]]:
        """(width, height) pixels of every resolution, highest first; needs a connection."""
        self._require_connected()
        return self.model.supported_resolutions()

    def free_running(self) -> bool:
        """Whether the scanner takes frames one after the other (free-run trigger while acquiring)."""
        return self.connected and self.acquiring and self.trigger_mode == TRIGGER_FREERUN

    # ----------------------------------------------------------------------------------------- settings
    def update_settings(self, **changes) -> None:
        self.settings = replace(self.settings, **changes)

    def reconfigure(self, config: dict, level: int = -1, previous: Mapping | None = None) -> str:
        """The driver's dynamic_reconfigure callback: apply what ``level``'s bits name (-1: everything) and change
        ``config`` in place to what holds afterwards. Not connected: ``config`` becomes ``previous`` (the driver
        refuses to reconfigure without a scanner). A number that is not finite is put back to its ``previous`` value
        (dynamic_reconfigure clamps to the ranges, but NaN passes its comparisons), and so is a value of the wrong type
        (:func:`check_reconfigure_changes`: a double for an int parameter); a refused trigger mode or space
        is put back to the device's. Returns why something was refused, or ''."""
        previous = dict(phoxi_config.defaults if previous is None else previous)
        if not self.connected:
            config.clear()
            config.update(previous)
            return "Node is not connected to scanner"
        refusals = []
        for name, kind in phoxi_config.type.items():  # a value of the wrong type (a double for an int) is refused
            try:
                config[name] = _typed_value(name, kind, config[name])
            except PhoxiError as exc:
                refusals.append(f"{exc} (kept {previous[name]})")
                config[name] = previous[name]
        for name in _DOUBLE_PARAMETERS:
            if not math.isfinite(float(config[name])):
                refusals.append(f"{name} {config[name]} refused: not a finite number (kept {previous[name]})")
                config[name] = previous[name]
        if level & phoxi_config.LEVEL_TRIGGER:
            try:
                self.set_trigger_mode(config["trigger_mode"], config["start_acquisition"])
            except PhoxiError as exc:
                refusals.append(f"trigger_mode {config['trigger_mode']} refused: {exc}")
        config["trigger_mode"], config["start_acquisition"] = self.trigger_mode, self.acquiring
        if level & phoxi_config.LEVEL_COORDINATE_SPACE and config["coordinate_space"] != self.coordinate_space:
            try:
                self.set_coordinate_space(config["coordinate_space"])
            except PhoxiError as exc:
                refusals.append(f"coordinate_space {config['coordinate_space']} refused: {exc}")
        config["coordinate_space"] = self.coordinate_space
        changes = {name: config[name] for name in SETTING_NAMES if level & phoxi_config.level[name]}
        self.update_settings(**changes)
        for name in SETTING_NAMES:  # what the scanner holds, also for the levels not applied
            config[name] = getattr(self.settings, name)
        return "; ".join(refusals)

    # -------------------------------------------------------------------------------- coordinate spaces
    def output_transform(self, space: int | None = None) -> np.ndarray:
        space = self.coordinate_space if space is None else space
        return np.eye(4) if space == CAMERA_SPACE else self.transformations[space]

    def set_coordinate_space(self, space: int) -> None:
        """Spaces 1-5 switch (2 and 3 are identity: no marker calibration); 0 NoValue is accepted and changes
        nothing; anything else is refused."""
        space = int(space)
        self._require_connected()
        if space == NO_VALUE_SPACE:
            return
        if space not in COORDINATE_SPACES:
            known = ", ".join(f"{k} {v}" for k, v in COORDINATE_SPACES.items())
            raise PhoxiError(f"Unknown coordinate space {space} (known: 0 NoValue, {known})")
        self.coordinate_space = space

    def set_transformation(self, matrix: np.ndarray, space: int, set_space: bool, save_settings: bool) -> None:
        """Store the transformation of RobotSpace or CustomSpace and switch to that space. ``set_space`` makes no
        difference, as in the driver (PhoXiInterface.cpp switches in both cases).

        ``save_settings`` is accepted: the real scanner persists the transformation in PhoXi Control, the simulated
        one keeps it for the node's lifetime either way.
        """
        self._require_connected()
        space = int(space)
        if space not in (ROBOT_SPACE, CUSTOM_SPACE):
            name = COORDINATE_SPACES.get(space, f"unknown space {space}")
            raise PhoxiError(
                f"Coordinate space is not supported: a transformation is set for 4 RobotSpace and 5 CustomSpace "
                f"only, not {name}"
            )
        matrix = check_transformation(matrix)
        self.transformations[space] = matrix.copy()
        self.coordinate_space = space

    # -------------------------------------------------------------------------------------------- files
    def output_path(self, requested: str, ply_only: bool = False) -> Path:
        """The confined path of a requested file (see the class); ``ply_only``: save_frame's request, which writes
        PLY whatever the extension (as the driver) but cannot write PhoXi Control's raw formats."""
        extension = Path(str(requested)).suffix.lower().lstrip(".")
        if ply_only and extension in RAW_EXTENSIONS:
            raise PhoxiError(self._raw_refusal(extension))
        requested = self._expand_home(str(requested))
        try:
            return self.files.for_writing(requested, overwrite=True)
        except PathPolicyError as exc:
            raise PhoxiError(str(exc)) from exc

    def _expand_home(self, requested: str) -> str:
        """A leading ``~`` is the home folder, as the driver replaces it with ``$HOME`` (and refuses without one)."""
        if requested == "~" or requested.startswith("~/"):
            home = self.environ.get("HOME")
            if not home:
                raise PhoxiError(
                    "'~' found in 'path' parameter but environment variable 'HOME' not found: pass an absolute path"
                )
            return home + requested[1:]
        return requested

    @staticmethod
    def _raw_refusal(extension: str) -> str:
        """The refusal of a raw format, worded as the driver's failed save ("Unsuccessful save.") so that a script's
        handling of a failed save applies; the simulator writes no stand-in that PhoXi Control could not open."""
        written = ", ".join("." + e for e in WRITTEN_EXTENSIONS)
        return (
            f"Unsuccessful save: extension .{extension} (PhoXi Control's raw format) is not supported by the "
            f"simulator, which has no raw pattern images to write; it writes {written}"
        )

    def save_frame(self, frame: Frame, requested: str, organized: bool = True) -> Path:
        """The frame as binary PLY at ``requested`` (inside the output directory), whatever its extension (as the driver)."""
        return self.frame_writer(frame, requested, organized)()

    def frame_writer(self, frame: Frame, requested: str, organized: bool = True) -> Callable[[], Path]:
        """A writer of ``frame`` as PLY at ``requested``, the path checked now; the writer returns the path."""
        path = self.output_path(requested, ply_only=True)
        return lambda: self._write_ply(frame, path, organized)

    def save_last_frame(self, requested: str, organized: bool = True) -> Path:
        """The last triggered frame (as the driver's SaveLastOutput) in the format its extension names (ply, ptx, tif)."""
        return self.last_frame_writer(requested, organized)()

    def last_frame_writer(self, requested: str, organized: bool = True) -> Callable[[], Path]:
        """A writer of the last triggered frame in the format its extension names (ply, ptx, tif); extension, frame
        and path are checked now, so the writer, which needs no device state, can run outside the node's lock."""
        extension = Path(str(requested)).suffix.lower().lstrip(".")
        if extension not in SAVE_LAST_FRAME_EXTENSIONS:
            raise PhoxiError("Wrong extension.")
        if extension not in WRITTEN_EXTENSIONS:
            raise PhoxiError(self._raw_refusal(extension))
        if self.last_frame is None:
            raise PhoxiError(
                "Unsuccessful save: no frame triggered since the scanner was connected (trigger_image or get_frame -1)"
            )
        path = self.output_path(requested)
        frame = self.last_frame
        if extension == "ply":
            return lambda: self._write_ply(frame, path, organized)
        if extension == "ptx":
            return lambda: _write_frame_ptx(frame, path)
        return lambda: write_point_tiff(path, frame_output(frame)[0])

    def _write_ply(self, frame: Frame, path: Path, organized: bool) -> Path:
        points, normals = frame_output(frame)
        parts = {"intensity": ("texture", frame.texture), "confidence": ("confidence_map", frame.confidence)}
        scalars = {name: values for name, (part, values) in parts.items() if part in frame.outputs}
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


def _write_frame_ptx(frame: Frame, path: Path) -> Path:
    points, _ = frame_output(frame)
    scale = max(float(frame.texture.max()), 1.0)
    return write_ptx(path, points, frame.texture / scale)


def frame_output(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Points (m) and normals (H, W, 3) float32 of a frame in the coordinate space it was captured in."""
    points = frame.points_m()
    if np.array_equal(frame.output_transform, np.eye(4)):
        return points, frame.normals
    return transform_points(points, frame.normals, frame.valid, frame.output_transform)
