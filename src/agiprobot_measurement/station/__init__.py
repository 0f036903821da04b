"""The measurement station as configuration: robot, joint limits, named states, scanner and scene.

Everything station-specific is read from ``config/*.yaml`` (or files the caller names); this module turns the
files into checked, typed objects and fails with a :class:`ConfigError` that names the file and the bad key.
Units: metres and radians in the scene, robot and limits; the sensor model keeps the documented mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from agiprobot_measurement._paths import CONFIG_DIR, PACKAGE_ROOT, URDF_DIR
from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.common.geometry import pose_matrix, rpy_to_matrix
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M
from agiprobot_measurement.station.config import (
    SENSOR_PARAMETER_KEYS,
    JointLimits,
    RobotConfig,
    ScannerConfig,
    load_joint_limits,
    load_named_states,
    load_robot_config,
    load_scanner_config,
)
from agiprobot_measurement.station.scene import (
    CHESSBOARD_MARGIN_SQUARES,
    SCENE_OBJECT_TYPES,
    PartPlacement,
    Scene,
    SceneObject,
    chessboard_board_size,
    chessboard_dark_squares,
    load_scene,
)
from agiprobot_measurement.station.ur_kinematics import KinematicsFileError, UrKinematics, load_ur_kinematics
from agiprobot_measurement.station.urdf_model import build_station_urdf

__all__ = [
    "CHESSBOARD_MARGIN_SQUARES",
    "CONFIG_DIR",
    "PACKAGE_ROOT",
    "SCENE_OBJECT_TYPES",
    "SENSOR_PARAMETER_KEYS",
    "UNIT_SCALES_TO_M",
    "URDF_DIR",
    "ConfigError",
    "JointLimits",
    "KinematicsFileError",
    "PartPlacement",
    "RobotConfig",
    "ScannerConfig",
    "Scene",
    "SceneObject",
    "Station",
    "UrKinematics",
    "chessboard_board_size",
    "chessboard_dark_squares",
    "load_joint_limits",
    "load_named_states",
    "load_robot_config",
    "load_scanner_config",
    "load_scene",
    "load_ur_kinematics",
    "pose_matrix",
    "read_yaml",
    "rpy_to_matrix",
]


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
    #: the arm's kinematics file the URDF's joint origins come from (None: a station built by hand)
    kinematics: UrKinematics | None = None

    @classmethod
    def load(
        cls,
        robot: str | Path | None = None,
        joint_limits: str | Path | None = None,
        named_states: str | Path | None = None,
        scanner: str | Path | None = None,
        scene: str | Path | None = None,
        kinematics: str | Path | None = None,
    ) -> Station:
        """``kinematics``: the arm's kinematics file (ur_calibration's format); default the robot file's
        ``kinematics_config``."""
        robot_cfg = load_robot_config(robot)
        kinematics_path = kinematics if kinematics is not None else robot_cfg.kinematics_config
        if kinematics_path is None:
            raise ConfigError(f"robot '{robot_cfg.name}': no kinematics_config in the robot file and none given")
        arm = load_ur_kinematics(kinematics_path)
        return cls(
            robot=robot_cfg,
            limits=load_joint_limits(joint_limits, robot_cfg.joint_names),
            named_states=load_named_states(named_states, len(robot_cfg.joint_names)),
            scanner=load_scanner_config(scanner),
            scene=load_scene(scene),
            urdf_xml=build_station_urdf(
                robot=robot, joint_limits=joint_limits, scanner=scanner, scene=scene, kinematics=kinematics_path
            ),
            kinematics=arm,
        )
