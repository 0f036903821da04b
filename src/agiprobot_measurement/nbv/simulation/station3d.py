"""The simulated station of the 3D next-best-view loop: :class:`SimulatedNBVStation` adds the hidden truth to
:class:`~agiprobot_measurement.nbv.volumetric.station3d.NBVStation`.

The truth is the part's mesh, placed on the fixture, which only the renderer, the ground truth and the safety check of
:class:`SimulatedRobot` see. :class:`SimulatedRobot` and :class:`SimulatedPhoXiCamera` implement
:class:`~agiprobot_measurement.nbv.volumetric.interfaces.NBVRobot` and
:class:`~agiprobot_measurement.nbv.volumetric.interfaces.NBVCamera` over it, the latter with the structured-light
renderer of :mod:`agiprobot_measurement.sensors.phoxi.renderer` (model S by default, noise on). World frame, metres,
rad.
"""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import trimesh

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.limits import LIMITS, check_count, check_file_size, excerpt
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.families3d import is_family_part, make_family_part
from agiprobot_measurement.nbv.simulation.objects3d import SHAPES, make_shape
from agiprobot_measurement.nbv.volumetric.interfaces import CapturedView, MotionError
from agiprobot_measurement.nbv.volumetric.station3d import HOUSING_LINK, NBVStation
from agiprobot_measurement.planning.part_loading import PLAUSIBLE_SIZE_MM, STEP_SUFFIXES, PartWarning, load_part
from agiprobot_measurement.sensors.phoxi.renderer import (
    RobotGeometry,
    ScanSettings,
    SceneGeometry,
    StructuredLightScanner,
)
from agiprobot_measurement.station.placement import fixture_placement

__all__ = ["SimulatedNBVStation", "SimulatedPhoXiCamera", "SimulatedRobot", "load_part_mesh"]


def load_part_mesh(part, units: str = "mm", largest_extent_m: float | None = None):
    """A part as a ``trimesh.Trimesh`` in metres: a mesh path (STL, OBJ, PLY, OFF...) in ``units`` or a STEP file
    (in the unit it declares), a Trimesh (already in ``units``) or the name of a procedural shape of
    :mod:`.objects3d` or a generated part of :mod:`.families3d` (mm); ``largest_extent_m`` rescales it so that its largest bounding-box edge has that length.

    Files are read by the planner's :func:`~agiprobot_measurement.planning.part_loading.load_part`, so the two tools
    accept and refuse the same files. Raises :class:`InputError` for a missing, oversized, empty, degenerate or
    non-finite mesh, an unknown unit, or a part whose largest extent lies outside
    :data:`~agiprobot_measurement.planning.part_loading.PLAUSIBLE_SIZE_MM` (the station cannot scan it).
    """
    if units not in UNIT_SCALES_TO_M:
        raise InputError(f"units: unknown unit {units!r}; one of {', '.join(sorted(UNIT_SCALES_TO_M))}")

    if isinstance(part, trimesh.Trimesh):
        mesh = part.copy()
        mesh.apply_scale(UNIT_SCALES_TO_M[units])
    elif isinstance(part, str) and part in SHAPES:
        mesh = make_shape(part)  # mm
        mesh.apply_scale(UNIT_SCALES_TO_M["mm"])
    elif is_family_part(part):
        mesh = make_family_part(part)  # mm
        mesh.apply_scale(UNIT_SCALES_TO_M["mm"])
    else:
        mesh = _read_part_file(part, units)
    if len(mesh.faces) == 0:
        raise InputError(f"part: {excerpt(str(part))} holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError(f"part: {excerpt(str(part))} has non-finite vertices")
    extent = float(np.max(mesh.extents))
    if not extent > 0:
        raise InputError(f"part: {excerpt(str(part))} is degenerate (zero extent)")
    if largest_extent_m is not None:
        if not (math.isfinite(largest_extent_m) and largest_extent_m > 0):
            raise InputError(f"largest_extent_m must be a positive length, got {largest_extent_m}")
        mesh.apply_scale(float(largest_extent_m) / extent)
        extent = float(np.max(mesh.extents))
    low, high = PLAUSIBLE_SIZE_MM
    if not low <= extent * 1000.0 <= high:
        raise InputError(
            f"part: {excerpt(str(part))} is {extent * 1000.0:.4g} mm across, outside what the station scans "
            f"({low:g} to {high:g} mm): check the unit (--units) or rescale it (--extent)"
        )
    return mesh


def _read_part_file(part, units: str):
    """The mesh of a part file in metres, read and checked as the planner reads it."""
    path = Path(part)
    if not path.is_absolute() and not path.exists():
        shared = PACKAGE_ROOT / path
        path = shared if shared.exists() else path
    if not path.is_file():
        raise InputError(f"part: mesh file {excerpt(str(part))} does not exist or is not a regular file")
    is_step = path.suffix.lower() in STEP_SUFFIXES
    if is_step:
        check_file_size(path, LIMITS.step_file_bytes, "part: STEP file")
    else:
        check_file_size(path, LIMITS.mesh_file_bytes, "part: mesh file")
    with warnings.catch_warnings():
        # the planner's doubts (open mesh, size before --extent) are not refusals; the size is checked after
        warnings.simplefilter("ignore", PartWarning)
        loaded = load_part(path, "mm" if is_step else units, remove_downside=False)  # STEP carries its unit
    check_count(len(loaded.mesh.faces), LIMITS.mesh_faces, f"part: faces of {excerpt(str(part))}")
    mesh = loaded.mesh
    mesh.apply_scale(1e-3)  # mm -> m
    return mesh


def _place_on_fixture(mesh, scene, fixture: str) -> np.ndarray:
    """world <- part (4x4): lowest point on the fixture's top, bounding-box centre over the fixture's centre."""
    placement_mm = fixture_placement(np.asarray(mesh.vertices) * 1000.0, np.eye(3), scene, fixture)
    pose = placement_mm.copy()
    pose[:3, 3] /= 1000.0
    return pose


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
        super().__init__(model, scene_path, config, pixel_step, resolution)
        sim = self.settings.simulation
        self.noise = bool(sim.noise if noise is None else noise)
        self.seed = int(sim.seed if seed is None else seed)
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
