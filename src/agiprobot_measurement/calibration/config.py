"""The calibration's configuration: ``config/calibration.yaml``, the tool orientation it asks for, the flange station.

Used by the real node (``ros/nodes/calibration.py``) and the simulation alike: the config loader (flag point file
resolved next to the config), the collection modes, the rotation that points the flange at the configured point and
the station with the bare flange disc on tool0 (``station.launch tool:=flange_disc``). Metres and rad throughout.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR, URDF_DIR
from agiprobot_measurement.calibration.registration import CalibrationError
from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.common.limits import excerpt
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.station import Station

__all__ = [
    "CALIBRATION_CONFIG",
    "MODES",
    "check_mode",
    "flange_station",
    "flange_station_urdf",
    "load_calibration_config",
    "tool_rotation",
]

CALIBRATION_CONFIG = CONFIG_DIR / "calibration.yaml"

#: what a run does: flag points + zig-zag path + fine calibration, flag points + coarse only, or the chessboard test
MODES = ("cal_fine", "cal_coarse", "test")


def check_mode(mode: str, where: str = "~mode") -> str:
    """``mode`` if it is one of :data:`MODES`, else a :class:`CalibrationError` naming ``where``."""
    mode = str(mode)
    if mode not in MODES:
        raise CalibrationError(f"{where} must be one of {', '.join(MODES)}, got {excerpt(mode)}")
    return mode


def load_calibration_config(path: str | Path | None = None) -> dict:
    """``config/calibration.yaml`` (safe_load) with the flag point file resolved to an absolute path."""
    path = Path(path or CALIBRATION_CONFIG)
    config = read_yaml(path) or {}
    flag = Path(config.get("flag_points_file", "calibration_flag_points.txt"))
    config["flag_points_file"] = str(flag if flag.is_absolute() else path.parent / flag)
    return config


def tool_rotation(z_towards_m: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """Rotation (3x3) whose z axis points from ``position_m`` towards ``z_towards_m`` (x kept horizontal; for a
    vertical z, x is the frame's x axis). :class:`InputError` (a ValueError) when the two points coincide."""
    z = np.asarray(z_towards_m, dtype=float) - np.asarray(position_m, dtype=float)
    length = np.linalg.norm(z)
    if not length > 1e-9:
        raise InputError("tool_rotation: the point to face coincides with the position")
    z /= length
    x = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(x) < 1e-6:  # straight up or down: no horizontal direction is singled out
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def flange_station_urdf(scene: str | Path | None = None, kinematics: str | Path | None = None) -> str:
    """The station URDF with ``tool:=flange_disc`` (xacro in-process); ``scene``: a scene file (default
    config/scene.yaml) for the robot's mounting; ``kinematics``: the arm's kinematics file (default config/
    ur10e.yaml's kinematics_config)."""
    import xacro  # lazily: xacro pulls in the ROS xml tooling, needed only when a URDF is built

    mappings = {"tool": "flange_disc"}
    if scene:
        mappings["scene"] = str(Path(scene).resolve())
    if kinematics:
        mappings["kinematics"] = str(Path(kinematics).resolve())
    return xacro.process_file(str(URDF_DIR / "station.urdf.xacro"), mappings=mappings).toprettyxml()


def flange_station(scene: str | Path | None = None, kinematics: str | Path | None = None) -> Station:
    """The station of ``scene`` (default config/scene.yaml) with the bare flange disc on tool0, for IK and
    collision checks; ``kinematics``: the arm's kinematics file (default config/ur10e.yaml's)."""
    return dataclasses.replace(
        Station.load(scene=scene, kinematics=kinematics), urdf_xml=flange_station_urdf(scene, kinematics)
    )
