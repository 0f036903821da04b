"""The station of the 3D next-best-view loop as the loop may know it: the UR10e with a PhoXi on its flange.

:class:`NBVStation` holds the scene file's table, fixture and pedestal (no part), the robot of
``urdf/station.urdf.xacro tool:=phoxi``, closed-form IK of the sensor frame, FCL collision checkers and the PhoXi
model; ``pixel_step`` describes frames of every n-th pixel in both directions (a camera of 1/n the resolution with the
same field of view). The simulated station with the hidden part lives in
:mod:`agiprobot_measurement.nbv.simulation.station3d`. World frame, metres, rad.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import CONFIG_DIR, URDF_DIR
from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.nbv.volumetric.settings import NBVSettings
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_HIGH, RESOLUTION_LOW
from agiprobot_measurement.sensors.phoxi.renderer import load_scanner_model, scene_geometry
from agiprobot_measurement.station import Station
from agiprobot_measurement.station.placement import scene_object_top_m
from agiprobot_measurement.station.urdf_model import UrdfModel

__all__ = ["HOUSING_LINK", "SENSOR_FRAME", "NBVStation", "load_nbv_config", "phoxi_station_urdf"]

SENSOR_FRAME = "PhoXi3Dscanner_sensor"
HOUSING_LINK = "PhoXi3Dscanner"


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
        self.config = config if config is not None else load_nbv_config()
        self.settings = NBVSettings.from_config(self.config)
        sim = self.settings.simulation
        self.model_name = str(model or self.settings.phoxi_tool["model"])
        self.pixel_step = int(sim.pixel_step if pixel_step is None else pixel_step)
        if self.pixel_step < 1:
            raise InputError(f"pixel_step must be a positive integer, got {self.pixel_step}")
        resolution = str(sim.resolution if resolution is None else resolution)
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
        fixture = self.settings.roi.fixture
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
        home = self.settings.motion.home_rad
        self.home_rad = np.asarray(self.station.named_states["home"] if home is None else home, dtype=float)

    # ------------------------------------------------------------------------------------ geometry
    def _fixture_top(self, fixture: str) -> tuple[float, np.ndarray]:
        for obj in self.scene.objects:
            if obj.name == fixture:
                return scene_object_top_m(obj)
        raise InputError(f"the scene has no fixture object '{fixture}'")

    @cached_property
    def table_top_m(self) -> float:
        """World z (m) of the highest box top under the fixture (the table)."""
        tops = [scene_object_top_m(o)[0] for o in self.scene.objects if o.type == "box" and o.group is None]
        below = [t for t in tops if t <= self.fixture_top_m - 1e-6]
        return max(below) if below else self.fixture_top_m

    def default_roi(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, size) m of the a-priori ROI: ``roi.max_object_size_m`` above the fixture plus ``margin_m``."""
        roi = self.settings.roi
        size = np.asarray(roi.max_object_size_m, dtype=float)
        margin = roi.margin_m
        center = np.array([*self.fixture_center_xy_m, self.fixture_top_m + size[2] / 2.0])
        return center, size + 2.0 * margin

    @cached_property
    def static_geometry(self):
        """The scene's obstacles as the renderer's SceneGeometry (world frame, the mirrors left out)."""
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
