"""The calibration on the simulated station without ROS: robot with the bare flange disc, scene, PhoXi renderer.

:class:`SimulatedStation` poses the robot by closed-form IK at each target (flange centre in the robot base frame,
tool orientation from the config) and renders one scanner frame with
:mod:`agiprobot_measurement.sensors.phoxi.renderer` from a camera pose kept from the calibration (the hidden
truth). :class:`SimulatedJointDriver` and :class:`SimulatedCamera` are the ROS node's robot and camera over it, so
that :mod:`~agiprobot_measurement.calibration.procedure` runs in pytest; ``python -m benchmarks.calibration`` uses the
station directly. Metres and rad throughout.

Options of the station (off by default): ``true_kinematics`` (a
:class:`~agiprobot_measurement.station.UrKinematics`, the true robot's kinematics file, e.g. the one
``config/ur10e_kinematics_correction.yaml`` names: the original station's real UR10e): the links are rendered where
that robot puts them, while IK and everything the robot reports follow the station's model, as on a real station;
``planner_kinematics``: the kinematics file of that model (default config/ur10e.yaml's ``kinematics_config``, the
nominal arm; the true robot's file = a station whose planner and calibration know the robot); ``board`` (a
:class:`~agiprobot_measurement.calibration.hand_eye.FlangeBoard`): a chessboard plate on the flange, the target of
the OpenCV hand-eye peers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.calibration.config import flange_station_urdf
from agiprobot_measurement.calibration.flange_motion import PlannedFlangeRobot, flange_collision_checker
from agiprobot_measurement.calibration.interfaces import CameraFrame, StepError
from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import (
    KinematicModel,
    TrueKinematics,
    load_kinematics_correction,
)
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.sensors.phoxi.renderer import (
    RobotGeometry,
    ScanSettings,
    SceneGeometry,
    StructuredLightScanner,
    load_scanner_model,
    scene_geometry,
)
from agiprobot_measurement.station import Station, UrKinematics, load_joint_limits
from agiprobot_measurement.station.urdf_model import UrdfModel

__all__ = [
    "BASE_FRAME",
    "SimulatedCamera",
    "SimulatedJointDriver",
    "SimulatedStation",
    "nominal_camera_pose",
    "perturbed_pose",
    "simulated_robot_and_camera",
    "true_kinematics_from_config",
]


#: the robot base frame of the calibration (hand-eye ``base``): the DH base, ur_description's ``base``
BASE_FRAME = "base"


@dataclass
class SimulatedStation:
    """Robot (bare flange), scene and a PhoXi model at a camera pose (world <- camera) kept from the calibration."""

    camera_pose_world: np.ndarray
    model_name: str = "L"
    noise_seed: int = 0
    scene_path: str | Path | None = None  # None: config/scene.yaml
    true_kinematics: UrKinematics | None = None  # None: the robot is the station's model
    deviation_scale: float = 1.0  # TrueKinematics.deviation_scale of the true robot
    board: object | None = None  # hand_eye.FlangeBoard on the flange, or None (the bare flange disc)
    planner_kinematics: str | Path | None = None  # the model's kinematics file (None: config/ur10e.yaml's)

    def __post_init__(self):
        self.station = Station.load(scene=self.scene_path, kinematics=self.planner_kinematics)
        # the robot base frame of the calibration: `base`, the DH base (the controller's Base)
        self.kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame=BASE_FRAME)
        self.world_kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame="world")
        self.ik = make_ik_solver(self.kinematics, self.station.robot)
        self.urdf = UrdfModel(flange_station_urdf(self.scene_path, self.planner_kinematics))
        self.robot = RobotGeometry(self.urdf)
        self.scene = scene_geometry(self.station.scene, exclude_groups=("wbk_mirrors",))
        self.scanner = StructuredLightScanner(load_scanner_model(self.model_name))
        self.world_from_base = self.urdf.fixed_transform("world", BASE_FRAME)
        self.limits = load_joint_limits()
        self.seed_q = np.array([0.0, -1.5707, 1.5707, -1.5707, -1.5707, 0.0])
        self.true_world_kinematics = None
        if self.true_kinematics is not None:
            self.true_world_kinematics = TrueKinematics(
                self.world_kinematics, self.true_kinematics, self.deviation_scale
            )
            self.true_base_kinematics = TrueKinematics(self.kinematics, self.true_kinematics, self.deviation_scale)
        self._board_geometry = None if self.board is None else self.board.geometry()

    @property
    def camera_in_base(self) -> np.ndarray:
        """The hidden truth: base <- camera (4x4)."""
        return np.linalg.inv(self.world_from_base) @ self.camera_pose_world

    def joints_for(self, position_base_m: np.ndarray, rotation: np.ndarray) -> np.ndarray | None:
        pose = np.eye(4)
        pose[:3, :3] = rotation
        pose[:3, 3] = position_base_m
        q, ok = self.ik.solve_nearest(pose, self.seed_q)
        return np.asarray(q) if ok else None

    def reported_flange_pose(self, q: np.ndarray) -> np.ndarray:
        """base <- tool0 as the robot reports it at ``q``: the station's model, whatever the true kinematics."""
        return self.kinematics.fk(np.asarray(q, dtype=float))

    def true_flange_pose(self, q: np.ndarray) -> np.ndarray:
        """base <- tool0 where the flange really is at ``q``."""
        if self.true_world_kinematics is None:
            return self.reported_flange_pose(q)
        return self.true_base_kinematics.fk(np.asarray(q, dtype=float))

    def joints_placing(self, flange_pose_base: np.ndarray) -> np.ndarray | None:
        """The joint state at which the TRUE flange is at ``flange_pose_base`` (base <- tool0): the model's IK, then
        Gauss-Newton on the true kinematics; None without an IK solution."""
        q, ok = self.ik.solve_nearest(np.asarray(flange_pose_base, dtype=float), self.seed_q)
        if not ok:
            return None
        if self.true_world_kinematics is None:
            return np.asarray(q)
        return self.true_base_kinematics.solve_near(np.asarray(flange_pose_base, dtype=float), np.asarray(q))

    def link_poses(self, q: np.ndarray) -> dict:
        model = self.world_kinematics if self.true_world_kinematics is None else self.true_world_kinematics
        poses = model.link_poses_batch(np.atleast_2d(q))
        out = {name: value[0] for name, value in poses.items()}
        out["flange_disc_link"] = out["tool0"] @ self.urdf.fixed_transform("tool0", "flange_disc_link")
        return out

    def capture(self, q: np.ndarray, frame_index: int, extra=None):
        """One frame (renderer.Frame) with the robot at ``q``; ``extra``: more SceneGeometry (world)."""
        links = self.link_poses(q)
        parts = [self.scene, self.robot.posed(links)]
        if self._board_geometry is not None:
            parts.append(self._board_geometry.transformed(links["tool0"]))
        if extra is not None:
            parts.append(extra)
        geometry = SceneGeometry.concatenate(parts)
        settings = ScanSettings(seed=self.noise_seed)
        return self.scanner.capture(geometry, self.camera_pose_world, settings, frame_index=frame_index)


def true_kinematics_from_config(path=None) -> dict:
    """The :class:`SimulatedStation` keyword arguments of a kinematics correction file (default
    ``config/ur10e_kinematics_correction.yaml``): ``true_kinematics`` and ``deviation_scale`` when the file's
    ``true_kinematics`` is true, else none (the nominal robot)."""
    enabled, correction, scale = load_kinematics_correction(path)
    return {"true_kinematics": correction, "deviation_scale": scale} if enabled else {}


def perturbed_pose(pose: np.ndarray, rng, translation_m: float = 0.05, rotation_rad: float = 0.05) -> np.ndarray:
    """``pose`` moved by a uniform random offset (per axis) and turned by a random small rotation."""
    from scipy.spatial.transform import Rotation  # lazily: scipy.spatial takes a quarter of a second to load

    out = np.array(pose, dtype=float)
    out[:3, 3] += rng.uniform(-translation_m, translation_m, 3)
    out[:3, :3] = Rotation.from_rotvec(rng.uniform(-rotation_rad, rotation_rad, 3)).as_matrix() @ out[:3, :3]
    return out


def nominal_camera_pose() -> np.ndarray:
    """world <- camera from config/phoxi_camera.yaml (xyz_m + look_at_m)."""
    cfg = read_yaml(CONFIG_DIR / "phoxi_camera.yaml")
    return look_at(cfg["pose"]["xyz_m"], cfg["pose"]["look_at_m"])


class SimulatedJointDriver:
    """The :class:`~agiprobot_measurement.calibration.interfaces.JointDriver` of the simulation: the robot is where
    the last trajectory ended (no dynamics, no waiting); ``trajectories`` keeps every one it ran."""

    def __init__(self, joints_rad: np.ndarray):
        self.joints_rad = np.array(joints_rad, dtype=float)
        self.trajectories: list[JointTrajectory] = []

    def current_joints(self) -> np.ndarray:
        return self.joints_rad.copy()

    def execute(self, trajectory: JointTrajectory, settle_s: float) -> None:
        if np.abs(trajectory.start - self.joints_rad).max() > 1e-6:
            raise StepError("robot motion failed: the trajectory does not start at the current joint state")
        self.trajectories.append(trajectory)
        self.joints_rad = np.array(trajectory.end, dtype=float)


class SimulatedCamera:
    """The :class:`~agiprobot_measurement.calibration.interfaces.Camera` of the simulation: a frame of ``station``
    rendered with the robot where ``driver`` has it; frame indices (the noise draws) count up from
    ``first_frame_index``."""

    def __init__(self, station: SimulatedStation, driver: SimulatedJointDriver, first_frame_index: int = 0):
        self.station = station
        self.driver = driver
        self.frame_index = first_frame_index

    def capture(self, texture: bool = False) -> CameraFrame:
        frame = self.station.capture(self.driver.current_joints(), self.frame_index)
        self.frame_index += 1
        points = frame.points_m()
        if not texture:
            return CameraFrame(points)
        return CameraFrame(points, organized_m=points, texture=frame.texture)


def simulated_robot_and_camera(
    station: SimulatedStation,
    tool_z_towards_m,
    start_rad: np.ndarray | None = None,
    check_collisions: bool = False,
    velocity_scaling: float = 1.0,
) -> tuple[PlannedFlangeRobot, SimulatedCamera]:
    """The node's robot and camera over ``station``: a :class:`PlannedFlangeRobot` on a
    :class:`SimulatedJointDriver` starting at ``start_rad`` (default the named state ``home``, as robot_sim), and a
    :class:`SimulatedCamera` rendering where that robot is. ``check_collisions``: with the flange station's
    collision checker (straight moves checked, blocked ones planned), as the node does by default."""
    driver = SimulatedJointDriver(station.station.named_states["home"] if start_rad is None else start_rad)
    collision = None
    if check_collisions:
        collision = flange_collision_checker(
            dataclasses.replace(
                station.station, urdf_xml=flange_station_urdf(station.scene_path, station.planner_kinematics)
            )
        )
    robot = PlannedFlangeRobot(
        driver,
        station.kinematics,
        station.ik,
        station.limits,
        tool_z_towards_m,
        collision=collision,
        velocity_scaling=velocity_scaling,
    )
    return robot, SimulatedCamera(station, driver)
