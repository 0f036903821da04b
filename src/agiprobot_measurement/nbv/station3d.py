"""The station of the 3D next-best-view loop without ROS: the UR10e with a PhoXi on its flange and an unknown part.

:class:`SimulatedNBVStation` holds what the loop may know (the scene file's table, fixture and pedestal, the robot of
``urdf/station.urdf.xacro tool:=phoxi``, closed-form IK of the sensor frame, an FCL collision checker WITHOUT the
part) and the hidden truth (the part's mesh, placed on the fixture), which only the renderer, the ground truth and
the safety check of :class:`SimulatedRobot` see. :class:`SimulatedRobot` and :class:`SimulatedPhoXiCamera` implement
:class:`~agiprobot_measurement.nbv.interfaces.NBVRobot` and :class:`~.interfaces.NBVCamera` over it, the latter
with the structured-light renderer of :mod:`agiprobot_measurement.sensors.phoxi.renderer` (model S by default, noise
on). ``pixel_step`` renders every n-th pixel in both directions (a camera of 1/n the resolution with the same field
of view), the low-resolution option for CI. World frame, metres, rad.
"""

from __future__ import annotations

import dataclasses
import math
import time
from functools import cached_property
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR, PACKAGE_ROOT, URDF_DIR
from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.interfaces import CapturedView, MotionError
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_HIGH, RESOLUTION_LOW

__all__ = [
    "SENSOR_FRAME",
    "NBVStation",
    "SimulatedNBVStation",
    "SimulatedPhoXiCamera",
    "SimulatedRobot",
    "load_nbv_config",
    "load_part_mesh",
    "phoxi_station_urdf",
]

SENSOR_FRAME = "PhoXi3Dscanner_sensor"
HOUSING_LINK = "PhoXi3Dscanner"
#: largest mesh file the loader reads (bytes): a bound on memory for a user-given path
MAX_MESH_BYTES = 200 * 1024 * 1024


def load_nbv_config(path: str | Path | None = None) -> dict:
    """``config/nbv.yaml`` (or ``path``) as a mapping."""
    config = read_yaml(Path(path) if path else CONFIG_DIR / "nbv.yaml")
    if not isinstance(config, dict):
        raise InputError(f"{path or CONFIG_DIR / 'nbv.yaml'}: expected a mapping")
    return config


def phoxi_station_urdf(scene: str | Path | None = None, model: str = "", nbv: str | Path | None = None) -> str:
    """The station URDF with ``tool:=phoxi`` (xacro in-process); ``model``: S | M | L, empty = config/nbv.yaml's."""
    import xacro  # lazily: xacro pulls in the ROS xml tooling

    mappings = {"tool": "phoxi", "phoxi_model": str(model or "")}
    if scene:
        mappings["scene"] = str(Path(scene).resolve())
    if nbv:
        mappings["nbv"] = str(Path(nbv).resolve())
    try:
        return xacro.process_file(str(URDF_DIR / "station.urdf.xacro"), mappings=mappings).toprettyxml()
    except Exception as exc:  # xacro raises its own and Python errors for bad arguments and YAML
        raise InputError(f"station URDF with tool:=phoxi: {exc}") from exc


def load_part_mesh(part, units: str = "mm", largest_extent_m: float | None = None):
    """A part as a ``trimesh.Trimesh`` in metres: a mesh path (STL, OBJ, PLY, OFF...) in ``units``, a Trimesh
    (already in ``units``) or the name of a procedural shape of :mod:`.objects3d` (mm); ``largest_extent_m`` rescales it so that its largest bounding-box edge has that length.

    Raises :class:`InputError` for a missing, oversized, empty or non-finite mesh or an unknown unit.
    """
    import trimesh

    from agiprobot_measurement.common.units import UNIT_SCALES_TO_M

    if units not in UNIT_SCALES_TO_M:
        raise InputError(f"units: unknown unit {units!r}; one of {', '.join(sorted(UNIT_SCALES_TO_M))}")
    from agiprobot_measurement.nbv.objects3d import SHAPES, make_shape

    if isinstance(part, trimesh.Trimesh):
        mesh = part.copy()
    elif isinstance(part, str) and part in SHAPES:
        mesh = make_shape(part)  # mm
        units = "mm"
    else:
        path = Path(part)
        if not path.is_absolute() and not path.exists():
            shared = PACKAGE_ROOT / path
            path = shared if shared.exists() else path
        if not path.is_file():
            raise InputError(f"part: mesh file {part} does not exist")
        if path.stat().st_size > MAX_MESH_BYTES:
            raise InputError(f"part: mesh file {part} is larger than {MAX_MESH_BYTES // 2**20} MB")
        try:
            mesh = trimesh.load(str(path), force="mesh")
        except Exception as exc:  # trimesh raises many kinds for unreadable files
            raise InputError(f"part: cannot read mesh {part}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"part: {part} holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError(f"part: {part} has non-finite vertices")
    mesh.apply_scale(UNIT_SCALES_TO_M[units])
    extent = float(np.max(mesh.extents))
    if not extent > 0:
        raise InputError(f"part: {part} is degenerate (zero extent)")
    if largest_extent_m is not None:
        if not (math.isfinite(largest_extent_m) and largest_extent_m > 0):
            raise InputError(f"largest_extent_m must be a positive length, got {largest_extent_m}")
        mesh.apply_scale(float(largest_extent_m) / extent)
    return mesh


def _place_on_fixture(mesh, scene, fixture: str) -> np.ndarray:
    """world <- part (4x4): lowest point on the fixture's top, bounding-box centre over the fixture's centre."""
    from agiprobot_measurement.station.placement import fixture_placement

    placement_mm = fixture_placement(np.asarray(mesh.vertices) * 1000.0, np.eye(3), scene, fixture)
    pose = placement_mm.copy()
    pose[:3, 3] /= 1000.0
    return pose


class NBVStation:
    """What the loop may know of the station: the scene file's obstacles (no part), the robot of
    ``tool:=phoxi`` with closed-form IK of the sensor frame, collision checkers and the PhoXi model.

    ``model``: PhoXi model (default config/nbv.yaml's, S); ``pixel_step`` and ``resolution`` ("high" / "low")
    describe the frames the camera delivers (the simulation renders them so; a real camera ignores them).
    """

    def __init__(
        self,
        model: str | None = None,
        scene_path: str | Path | None = None,
        config: dict | None = None,
        pixel_step: int | None = None,
        resolution: str | None = None,
    ):
        from agiprobot_measurement.motion.ik import make_ik_solver
        from agiprobot_measurement.motion.kinematics import KinematicModel
        from agiprobot_measurement.sensors.phoxi.renderer import load_scanner_model
        from agiprobot_measurement.station import Station
        from agiprobot_measurement.station.urdf_model import UrdfModel

        self.config = config if config is not None else load_nbv_config()
        sim = self.config.get("simulation", {})
        self.model_name = str(model or self.config["phoxi_tool"]["model"])
        self.pixel_step = int(sim.get("pixel_step", 1) if pixel_step is None else pixel_step)
        if self.pixel_step < 1:
            raise InputError(f"pixel_step must be a positive integer, got {self.pixel_step}")
        resolution = str(sim.get("resolution", "low") if resolution is None else resolution)
        if resolution not in ("high", "low"):
            raise InputError(f"resolution must be 'high' or 'low', got {resolution!r}")
        self.resolution = RESOLUTION_HIGH if resolution == "high" else RESOLUTION_LOW
        base = Station.load(scene=scene_path)
        self.urdf_xml = phoxi_station_urdf(scene_path, self.model_name)
        self.station = dataclasses.replace(base, urdf_xml=self.urdf_xml)
        self.scene = self.station.scene.without_part()
        self.limits = self.station.limits
        self.urdf = UrdfModel(self.urdf_xml)
        self.kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame="world")
        self.sensor_kinematics = KinematicModel.from_station(self.station, tip_frame=SENSOR_FRAME, base_frame="world")
        self.ik = make_ik_solver(self.sensor_kinematics, self.station.robot)
        self.tool0_from_sensor = self.urdf.fixed_transform("tool0", SENSOR_FRAME)
        fixture = str(self.config.get("roi", {}).get("fixture", "fixture"))
        self.fixture_name = fixture
        self.fixture_top_m, self.fixture_center_xy_m = self._fixture_top(fixture)
        scanner = load_scanner_model(self.model_name)
        if self.pixel_step > 1:
            sizes = {
                k: (max(8, w // self.pixel_step), max(8, h // self.pixel_step))
                for k, (w, h) in scanner.resolutions.items()
            }
            scanner = dataclasses.replace(scanner, resolutions=sizes)
        self.scanner_model = scanner
        motion = self.config.get("motion", {})
        self.home_rad = np.asarray(motion.get("home_rad", self.station.named_states["home"]), dtype=float)

    # ------------------------------------------------------------------------------------ geometry
    def _fixture_top(self, fixture: str) -> tuple[float, np.ndarray]:
        from agiprobot_measurement.station.placement import scene_object_top_m

        for obj in self.scene.objects:
            if obj.name == fixture:
                return scene_object_top_m(obj)
        raise InputError(f"the scene has no fixture object '{fixture}'")

    @cached_property
    def table_top_m(self) -> float:
        """World z (m) of the highest box top under the fixture (the table)."""
        from agiprobot_measurement.station.placement import scene_object_top_m

        tops = [scene_object_top_m(o)[0] for o in self.scene.objects if o.type == "box" and o.group is None]
        below = [t for t in tops if t <= self.fixture_top_m - 1e-6]
        return max(below) if below else self.fixture_top_m

    def default_roi(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, size) m of the a-priori ROI: ``roi.max_object_size_m`` above the fixture plus ``margin_m``."""
        roi = self.config.get("roi", {})
        size = np.asarray(roi.get("max_object_size_m", [0.26, 0.26, 0.26]), dtype=float)
        margin = float(roi.get("margin_m", 0.01))
        center = np.array([*self.fixture_center_xy_m, self.fixture_top_m + size[2] / 2.0])
        return center, size + 2.0 * margin

    @cached_property
    def static_geometry(self):
        """The scene's obstacles as the renderer's SceneGeometry (world frame, the mirrors left out)."""
        from agiprobot_measurement.sensors.phoxi.renderer import scene_geometry

        return scene_geometry(self.scene, exclude_groups=("wbk_mirrors",))

    def static_mesh(self):
        """The scene's static geometry (table, fixture, pedestal) as one triangle soup (world frame).

        Deliberately not merged into one closed surface: the boxes touch (the fixture stands on the table), and
        an inside test on their union is ill-defined; the map needs their surfaces, which stop every ray.
        """
        import trimesh

        tri = np.asarray(self.static_geometry.triangles)
        return trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)

    def collision_checker(self, with_part: bool = False):
        """An FCL checker of the robot with the PhoXi against the scene; ``with_part``: also the true part (the
        simulation's safety check; the loop never gets it)."""
        from agiprobot_measurement.motion.collision import CollisionChecker

        checker = CollisionChecker(self.kinematics, self.scene)
        checker.allow_collision("wrist_3_link", HOUSING_LINK, "Adjacent")
        if with_part:
            if getattr(self, "part_mesh", None) is None:
                raise InputError("collision_checker(with_part=True) needs the simulated station's part")
            checker.set_part(self.part_mesh, name="part")
        return checker

    def sensor_pose(self, q: np.ndarray) -> np.ndarray:
        """world <- sensor (4x4) at joints ``q`` (rad), or (N, 4, 4) for (N, 6)."""
        q = np.asarray(q, dtype=float)
        return (
            self.kinematics.fk_batch(np.atleast_2d(q))[0] @ self.tool0_from_sensor
            if q.ndim == 1
            else (self.kinematics.fk_batch(q) @ self.tool0_from_sensor)
        )

    def link_poses(self, q: np.ndarray) -> dict:
        poses = self.kinematics.link_poses_batch(np.atleast_2d(np.asarray(q, dtype=float)))
        return {name: value[0] for name, value in poses.items()}


class SimulatedNBVStation(NBVStation):
    """:class:`NBVStation` plus the hidden truth and the renderer.

    ``part``: mesh path or Trimesh in ``units`` (None: the scene file's part); ``largest_extent_m`` rescales it;
    it is placed on the scene object ``roi.fixture`` of config/nbv.yaml. ``noise``/``seed``: the renderer's.
    """

    def __init__(
        self,
        part=None,
        units: str = "mm",
        largest_extent_m: float | None = None,
        model: str | None = None,
        scene_path: str | Path | None = None,
        noise: bool | None = None,
        seed: int | None = None,
        pixel_step: int | None = None,
        resolution: str | None = None,
        config: dict | None = None,
    ):
        from agiprobot_measurement.sensors.phoxi.renderer import (
            RobotGeometry,
            SceneGeometry,
            StructuredLightScanner,
        )

        super().__init__(model, scene_path, config, pixel_step, resolution)
        sim = self.config.get("simulation", {})
        self.noise = bool(sim.get("noise", True) if noise is None else noise)
        self.seed = int(sim.get("seed", 0) if seed is None else seed)
        if part is None:
            if self.station.scene.part is None:
                raise InputError("no part given and the scene file has none")
            part_file = self.station.scene.part
            mesh = load_part_mesh(part_file.mesh, part_file.units, largest_extent_m)
        else:
            mesh = load_part_mesh(part, units, largest_extent_m)
        self.part_pose = _place_on_fixture(mesh, self.station.scene, self.fixture_name)
        self.part_mesh = mesh.copy()
        self.part_mesh.apply_transform(self.part_pose)  # world frame
        self.scanner = StructuredLightScanner(self.scanner_model, workers=2)
        self.part_geometry = SceneGeometry.from_trimesh(self.part_mesh, "part", 0.6)
        # the housing does not see itself: its front face holds the camera and projector
        self.robot_geometry = RobotGeometry(self.urdf)
        self.robot_geometry.links.pop(HOUSING_LINK, None)
        self._scene_geometry_cls = SceneGeometry

    # ------------------------------------------------------------------------------------ camera
    def render(self, q: np.ndarray, frame_index: int = 0, with_robot: bool = True):
        """One renderer Frame with the robot at ``q`` (rad)."""
        from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings

        parts = [self.static_geometry, self.part_geometry]
        if with_robot:
            parts.append(self.robot_geometry.posed(self.link_poses(q)))
        geometry = self._scene_geometry_cls.concatenate(parts)
        settings = ScanSettings(resolution=self.resolution, noise=self.noise, seed=self.seed)
        return self.scanner.capture(geometry, self.sensor_pose(q), settings, frame_index=frame_index)

    def captured_view(self, frame) -> CapturedView:
        """A renderer Frame as the loop's CapturedView: valid pixels in the world frame."""
        pose = np.asarray(frame.camera_pose, dtype=float)
        valid = frame.valid.reshape(-1)
        points = frame.points_m().reshape(-1, 3)[valid].astype(np.float64)
        normals = frame.normals.reshape(-1, 3)[valid].astype(np.float64)
        rotation = pose[:3, :3]
        return CapturedView(
            points_m=points @ rotation.T + pose[:3, 3],
            normals=normals @ rotation.T,
            sigma_mm=frame.confidence.reshape(-1)[valid].astype(np.float64),
            camera_pose=pose,
            depth_m=(frame.depth_mm / 1000.0).astype(np.float32),
            intrinsics=frame.intrinsics,
            stamp_s=time.time(),
        )


class SimulatedRobot:
    """:class:`~.interfaces.NBVRobot` of the simulation: the robot is where the last trajectory ended.

    Every trajectory is checked against the TRUE scene (with the part) at 2 cm steps; ``true_collisions`` counts
    the ones that would have hit it (the loop never sees the part, so this measures its safety). ``strict``:
    raise :class:`MotionError` on such a trajectory instead of counting it.
    """

    def __init__(self, station: SimulatedNBVStation, joints_rad: np.ndarray | None = None, strict: bool = False):
        self.station = station
        self.joints_rad = np.array(station.home_rad if joints_rad is None else joints_rad, dtype=float)
        self.trajectories: list = []
        self.true_collisions = 0
        self.strict = strict
        self._truth = None

    def current_joints(self) -> np.ndarray:
        return self.joints_rad.copy()

    def execute(self, trajectory) -> None:
        if np.abs(np.asarray(trajectory.start) - self.joints_rad).max() > 1e-6:
            raise MotionError("robot motion failed: the trajectory does not start at the current joint state")
        if self._truth is None:
            self._truth = self.station.collision_checker(with_part=True)
        samples = trajectory.positions
        if len(samples) >= 2:
            steps = np.maximum(1, np.ceil(np.abs(np.diff(samples, axis=0)).max(axis=1) / 0.02).astype(int))
            segment = np.repeat(np.arange(len(steps)), steps)
            fraction = (np.concatenate([np.arange(1, n + 1) for n in steps]) / np.repeat(steps, steps))[:, None]
            samples = np.vstack([samples[:1], samples[segment] + (samples[segment + 1] - samples[segment]) * fraction])
        if not self._truth.check_states(samples).all():
            if self.strict:
                raise MotionError("robot motion failed: the trajectory collides with the part or the scene")
            self.true_collisions += 1
        self.trajectories.append(trajectory)
        self.joints_rad = np.array(trajectory.end, dtype=float)


class SimulatedPhoXiCamera:
    """:class:`~.interfaces.NBVCamera` of the simulation: a rendered frame from where ``robot`` has the sensor."""

    def __init__(self, station: SimulatedNBVStation, robot: SimulatedRobot, first_frame_index: int = 0):
        self.station = station
        self.robot = robot
        self.frame_index = first_frame_index
        self.render_s: list[float] = []

    def capture(self) -> CapturedView:
        start = time.perf_counter()
        frame = self.station.render(self.robot.current_joints(), self.frame_index)
        self.frame_index += 1
        view = self.station.captured_view(frame)
        self.render_s.append(time.perf_counter() - start)
        return view
