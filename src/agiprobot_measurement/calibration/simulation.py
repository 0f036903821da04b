"""The calibration on the simulated station without ROS: robot with the bare flange disc, scene, PhoXi renderer.

Used by ``tools/bench_calibration.py`` and the tests: poses the robot by closed-form IK at each target
(flange centre in the robot base frame, tool orientation from the config), renders one scanner frame with
:mod:`agiprobot_measurement.sensors.phoxi.renderer` and detects the flange in it. Metres and rad throughout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement.station import CONFIG_DIR, read_yaml

__all__ = [
    "CALIBRATION_CONFIG",
    "SimulatedStation",
    "flange_station_urdf",
    "load_calibration_config",
    "nominal_camera_pose",
    "perturbed_pose",
    "tool_rotation",
]

CALIBRATION_CONFIG = CONFIG_DIR / "calibration.yaml"


def load_calibration_config(path: str | Path | None = None) -> dict:
    """``config/calibration.yaml`` (safe_load) with the flag point file resolved to an absolute path."""
    path = Path(path or CALIBRATION_CONFIG)
    config = read_yaml(path) or {}
    flag = Path(config.get("flag_points_file", "calibration_flag_points.txt"))
    config["flag_points_file"] = str(flag if flag.is_absolute() else path.parent / flag)
    return config


def tool_rotation(z_towards_m: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """Rotation (3x3) whose z axis points from ``position_m`` towards ``z_towards_m`` (x kept horizontal; for a
    vertical z, x is the frame's x axis)."""
    z = np.asarray(z_towards_m, dtype=float) - np.asarray(position_m, dtype=float)
    length = np.linalg.norm(z)
    if not length > 1e-9:
        raise ValueError("tool_rotation: the point to face coincides with the position")
    z /= length
    x = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(x) < 1e-6:  # straight up or down: no horizontal direction is singled out
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def flange_station_urdf(scene: str | Path | None = None) -> str:
    """The station URDF with ``tool:=flange_disc`` (xacro in-process); ``scene``: a scene file (default
    config/scene.yaml) for the robot's mounting."""
    import xacro

    from agiprobot_measurement.station import URDF_DIR

    mappings = {"tool": "flange_disc"}
    if scene:
        mappings["scene"] = str(Path(scene).resolve())
    return xacro.process_file(str(URDF_DIR / "station.urdf.xacro"), mappings=mappings).toprettyxml()


@dataclass
class SimulatedStation:
    """Robot (bare flange), scene and a PhoXi model at a camera pose (world <- camera) kept from the calibration."""

    camera_pose_world: np.ndarray
    model_name: str = "L"
    noise_seed: int = 0
    scene_path: str | Path | None = None  # None: config/scene.yaml

    def __post_init__(self):
        from agiprobot_measurement.motion.ik import make_ik_solver
        from agiprobot_measurement.motion.kinematics import KinematicModel
        from agiprobot_measurement.sensors.phoxi.renderer import (
            RobotGeometry,
            StructuredLightScanner,
            load_scanner_model,
            scene_geometry,
        )
        from agiprobot_measurement.station import Station
        from agiprobot_measurement.station.urdf_model import UrdfModel

        self.station = Station.load(scene=self.scene_path)
        self.kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame="base_link")
        self.world_kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame="world")
        self.ik = make_ik_solver(self.kinematics, self.station.robot)
        self.urdf = UrdfModel(flange_station_urdf(self.scene_path))
        self.robot = RobotGeometry(self.urdf)
        self.scene = scene_geometry(self.station.scene, exclude_groups=("wbk_mirrors",))
        self.scanner = StructuredLightScanner(load_scanner_model(self.model_name))
        self.world_from_base = self.urdf.fixed_transform("world", "base_link")
        self.seed_q = np.array([0.0, -1.5707, 1.5707, -1.5707, -1.5707, 0.0])

    @property
    def camera_in_base(self) -> np.ndarray:
        """The hidden truth: base_link <- camera (4x4)."""
        return np.linalg.inv(self.world_from_base) @ self.camera_pose_world

    def joints_for(self, position_base_m: np.ndarray, rotation: np.ndarray) -> np.ndarray | None:
        pose = np.eye(4)
        pose[:3, :3] = rotation
        pose[:3, 3] = position_base_m
        q, ok = self.ik.solve_nearest(pose, self.seed_q)
        return np.asarray(q) if ok else None

    def link_poses(self, q: np.ndarray) -> dict:
        poses = self.world_kinematics.link_poses_batch(np.atleast_2d(q))
        out = {name: value[0] for name, value in poses.items()}
        out["flange_disc_link"] = out["tool0"] @ self.urdf.fixed_transform("tool0", "flange_disc_link")
        return out

    def capture(self, q: np.ndarray, frame_index: int, extra=None):
        """One frame (structured_light.Frame) with the robot at ``q``; ``extra``: more SceneGeometry (world)."""
        from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, SceneGeometry

        parts = [self.scene, self.robot.posed(self.link_poses(q))]
        if extra is not None:
            parts.append(extra)
        geometry = SceneGeometry.concatenate(parts)
        settings = ScanSettings(seed=self.noise_seed)
        return self.scanner.capture(geometry, self.camera_pose_world, settings, frame_index=frame_index)


def perturbed_pose(pose: np.ndarray, rng, translation_m: float = 0.05, rotation_rad: float = 0.05) -> np.ndarray:
    """``pose`` moved by a uniform random offset (per axis) and turned by a random small rotation."""
    from scipy.spatial.transform import Rotation

    out = np.array(pose, dtype=float)
    out[:3, 3] += rng.uniform(-translation_m, translation_m, 3)
    out[:3, :3] = Rotation.from_rotvec(rng.uniform(-rotation_rad, rotation_rad, 3)).as_matrix() @ out[:3, :3]
    return out


def nominal_camera_pose() -> np.ndarray:
    """world <- camera from config/phoxi_camera.yaml (xyz_m + look_at_m)."""
    from agiprobot_measurement.common.geometry import look_at

    cfg = read_yaml(CONFIG_DIR / "phoxi_camera.yaml")
    return look_at(cfg["pose"]["xyz_m"], cfg["pose"]["look_at_m"])
