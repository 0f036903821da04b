"""A simulated structured-light 3D scanner (PhoXi 3D Scanner S / M / L): what one frame of the scene looks like.

Everything here is ROS-free; the node ``nodes/phoxi_camera`` only feeds in the scene and the robot's link poses
and turns a :class:`Frame` into messages.

Geometry
    The camera frame is the scanner's sensor frame (``PhoXi3Dscanner_sensor``): an optical frame, x right,
    y down, z forward, metres. The projector sits ``baseline`` to the right of the camera (+x) and is turned
    about the camera's y axis so that both optical axes cross at the sweet spot. Pixel (u, v) looks along
    ``((u - cx) / fx, (v - cy) / fy, 1)`` (pinhole, square pixels, no distortion); ``fx`` makes the image as wide
    as the maker's scanning area at the sweet spot. Low resolution is 2x2 binning of high resolution.

Validity of a pixel
    The camera ray hits the scene (one triangle mesh: scene objects, the part and the robot's links), the depth
    lies within the scanning range, the point lies inside the projector's field of view, faces the projector and
    no surface occludes the segment from the projector to it (the shadows the baseline produces), and its
    estimated inaccuracy does not exceed the ``confidence`` setting (mm; <= 0 keeps every point).

Noise model (seeded by ``ScanSettings.seed`` and the frame index)
    Depth noise is Gaussian along the camera ray (the point stays on its pixel's ray) with standard deviation::

        sigma_z = temporal_noise * (z / sweet_spot)^2 / sqrt(max(cos(theta_p), min_cos_incidence) * gain)
        gain    = (albedo / reference_albedo) * scan_multiplier * shutter_multiplier * exposure / reference_exposure

    z is the depth along the camera axis, theta_p the angle between the surface normal and the direction to the
    projector. The square law is triangulation's (a fixed disparity error costs z^2 / (f * baseline) in depth);
    the square root is shot noise (less light on a tilted or dark surface, more with longer or repeated exposure).
    The confidence map is this sigma_z in mm, so it follows the noise point by point.

Texture
    Lambertian shading of the projector light: ``full_scale * exposure_gain * albedo * (cos(theta_p) *
    (sweet_spot / r_p)^2 [lit] + ambient * cos(theta_c))``, clipped at the camera's saturation; pixels whose
    ray hits nothing are 0. ``rgb_texture`` is the driver's 8-bit view of it (min-max normalised, histogram
    equalised, grey to RGB). Normals are the hit triangles' normals, turned towards the camera.

Units: metres for poses and points, mm for depth, range, noise and the confidence map (as the driver uses them).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import positive, require, vector
from agiprobot_measurement.station import (
    CONFIG_DIR,
    ConfigError,
    Scene,
    read_yaml,
)
from agiprobot_measurement.station.scene import chessboard_board_size, chessboard_dark_squares

__all__ = [
    "AMBIENT_SUPPRESSION_SHUTTER_MULTIPLIER",
    "BLACK_ALBEDO",
    "CHUNK_PIXELS",
    "DEFAULT_ALBEDO",
    "PHOXI_MODELS_FILE",
    "RESOLUTION_HIGH",
    "RESOLUTION_LOW",
    "ROBOT_ALBEDO",
    "SINGLE_PATTERN_EXPOSURES_MS",
    "WHITE_ALBEDO",
    "CameraIntrinsics",
    "Frame",
    "NoiseModel",
    "RayCaster",
    "RobotGeometry",
    "ScanSettings",
    "ScannerModel",
    "SceneGeometry",
    "StructuredLightScanner",
    "albedo_of",
    "chessboard_geometry",
    "depth_sigma_mm",
    "load_scanner_model",
    "load_scanner_models",
    "primitive_mesh",
    "rgb_texture",
    "scene_chessboard_geometry",
    "scene_geometry",
    "transform_points",
]

PHOXI_MODELS_FILE = CONFIG_DIR / "phoxi_models.yaml"

RESOLUTION_LOW = 0
RESOLUTION_HIGH = 1
#: PhoXi ``single_pattern_exposure`` index -> exposure of one pattern (ms), as PhoXi Control offers them
SINGLE_PATTERN_EXPOSURES_MS = (
    10.24,
    14.336,
    20.48,
    24.576,
    30.72,
    34.816,
    40.96,
    49.152,
    75.776,
    79.872,
    90.112,
    100.352,
)
#: shutter multiplier PhoXi Control fixes while ambient light suppression is on
AMBIENT_SUPPRESSION_SHUTTER_MULTIPLIER = 2
DEFAULT_ALBEDO = 0.6
ROBOT_ALBEDO = 0.55


# ----------------------------------------------------------------------------------------------- models
@dataclass(frozen=True)
class NoiseModel:
    """Constants of the noise and texture model (see the module docstring)."""

    min_cos_incidence: float = 0.05
    reference_albedo: float = 0.8
    reference_exposure_ms: float = 20.48
    texture_full_scale: float = 1000.0
    texture_saturation: float = 4095.0
    ambient_fraction: float = 0.05
    camera_only_ambient_fraction: float = 0.6
    shadow_epsilon_m: float = 0.001


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels of one resolution (no distortion)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def pixel_rays(self) -> np.ndarray:
        """(H * W, 3) float32 ray of every pixel, row-major, scaled to z = 1 (so ray * depth = point)."""
        return _pixel_rays(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def project(self, points_m: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) (u, v) of camera-frame points (N, 3)."""
        points_m = np.asarray(points_m, dtype=float)
        return np.stack(
            [
                self.fx * points_m[:, 0] / points_m[:, 2] + self.cx,
                self.fy * points_m[:, 1] / points_m[:, 2] + self.cy,
            ],
            axis=1,
        )


@lru_cache(maxsize=4)
def _pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    u = (np.arange(width, dtype=np.float64) - cx) / fx
    v = (np.arange(height, dtype=np.float64) - cy) / fy
    rays = np.empty((height, width, 3), dtype=np.float32)
    rays[:, :, 0] = u[None, :]
    rays[:, :, 1] = v[:, None]
    rays[:, :, 2] = 1.0
    rays = rays.reshape(-1, 3)
    rays.setflags(write=False)
    return rays


@dataclass(frozen=True)
class ScannerModel:
    """One PhoXi model: the maker's figures (mm, deg) and the simulator's noise constants."""

    name: str
    scanning_range_mm: tuple[float, float]
    sweet_spot_mm: float
    scan_area_mm: tuple[float, float]
    baseline_mm: float
    projector_fov_deg: tuple[float, float]
    temporal_noise_mm: float
    resolutions: dict = field(default_factory=lambda: {RESOLUTION_HIGH: (2064, 1544), RESOLUTION_LOW: (1032, 772)})
    noise: NoiseModel = field(default_factory=NoiseModel)

    def intrinsics(self, resolution: int = RESOLUTION_HIGH) -> CameraIntrinsics:
        if resolution not in self.resolutions:
            raise ValueError(f"unknown resolution {resolution!r}: 1 = High, 0 = Low")
        width, height = self.resolutions[resolution]
        # the image spans the scanning area's width at the sweet spot; pixels are square
        f = width * self.sweet_spot_mm / self.scan_area_mm[0]
        return CameraIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    def projector_pose(self) -> np.ndarray:
        """Camera -> projector frame (4x4, metres): ``baseline`` along +x, z axis through the sweet spot."""
        b = self.baseline_mm / 1000.0
        d = self.sweet_spot_mm / 1000.0
        z = np.array([-b, 0.0, d]) / math.hypot(b, d)
        y = np.array([0.0, 1.0, 0.0])
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([np.cross(y, z), y, z])
        pose[:3, 3] = [b, 0.0, 0.0]
        return pose

    def supported_resolutions(self) -> list[tuple[int, int]]:
        return [self.resolutions[k] for k in sorted(self.resolutions, reverse=True)]


def load_scanner_models(path: str | Path | None = None) -> dict[str, ScannerModel]:
    """Read ``config/phoxi_models.yaml`` (or ``path``); errors name the file and the bad key."""
    path = Path(path) if path else PHOXI_MODELS_FILE
    data = read_yaml(path)
    where = str(path)
    resolutions = require(data, "resolutions", where)
    res = {}
    for key, code in (("high", RESOLUTION_HIGH), ("low", RESOLUTION_LOW)):
        size = vector(require(resolutions, key, f"{where}: resolutions"), 2, f"{where}: resolutions.{key}")
        if np.any(size < 1) or np.any(size != np.round(size)):
            raise ConfigError(f"{where}: resolutions.{key} must be two positive integers")
        res[code] = (int(size[0]), int(size[1]))
    noise_entry = data.get("noise_model") or {}
    if not isinstance(noise_entry, dict):
        raise ConfigError(f"{where}: noise_model must be a mapping")
    unknown = set(noise_entry) - set(NoiseModel.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"{where}: noise_model: unknown key(s) {sorted(unknown)}")
    noise = NoiseModel(**{k: positive(v, f"{where}: noise_model.{k}") for k, v in noise_entry.items()})
    models_entry = require(data, "models", where)
    if not isinstance(models_entry, dict) or not models_entry:
        raise ConfigError(f"{where}: models must be a non-empty mapping of name -> figures")
    models = {}
    for name, entry in models_entry.items():
        here = f"{where}: models.{name}"
        rng = vector(require(entry, "scanning_range_mm", here), 2, f"{here}.scanning_range_mm")
        sweet = positive(require(entry, "sweet_spot_mm", here), f"{here}.sweet_spot_mm")
        if not 0 < rng[0] < sweet < rng[1]:
            raise ConfigError(f"{here}: need 0 < scanning_range_mm[0] < sweet_spot_mm < scanning_range_mm[1]")
        area = vector(require(entry, "scan_area_mm", here), 2, f"{here}.scan_area_mm")
        fov = vector(require(entry, "projector_fov_deg", here), 2, f"{here}.projector_fov_deg")
        if np.any(area <= 0) or np.any(fov <= 0) or np.any(fov >= 180):
            raise ConfigError(f"{here}: scan_area_mm must be positive and projector_fov_deg within (0, 180)")
        models[str(name)] = ScannerModel(
            name=str(name),
            scanning_range_mm=(float(rng[0]), float(rng[1])),
            sweet_spot_mm=sweet,
            scan_area_mm=(float(area[0]), float(area[1])),
            baseline_mm=positive(require(entry, "baseline_mm", here), f"{here}.baseline_mm"),
            projector_fov_deg=(float(fov[0]), float(fov[1])),
            temporal_noise_mm=positive(require(entry, "temporal_noise_mm", here), f"{here}.temporal_noise_mm"),
            resolutions=res,
            noise=noise,
        )
    return models


def load_scanner_model(name: str, path: str | Path | None = None) -> ScannerModel:
    models = load_scanner_models(path)
    if name not in models:
        raise ConfigError(f"unknown PhoXi model {name!r}; models in {path or PHOXI_MODELS_FILE}: {', '.join(models)}")
    return models[name]


# -------------------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class SceneGeometry:
    """Triangles of the scene in one frame (metres) with an outward unit normal, albedo and owner per face."""

    triangles: np.ndarray  # (F, 3, 3)
    normals: np.ndarray  # (F, 3)
    albedo: np.ndarray  # (F,)
    owner: np.ndarray  # (F,) index into names
    names: tuple[str, ...]

    @classmethod
    def empty(cls) -> SceneGeometry:
        return cls(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int32), ())

    @classmethod
    def from_trimesh(cls, mesh, name: str, albedo: float) -> SceneGeometry:
        triangles = np.asarray(mesh.triangles, dtype=float)
        normals = np.asarray(mesh.face_normals, dtype=float)
        n = len(triangles)
        return cls(triangles, normals, np.full(n, float(albedo)), np.zeros(n, dtype=np.int32), (name,))

    def __len__(self) -> int:
        return len(self.triangles)

    def transformed(self, pose: np.ndarray) -> SceneGeometry:
        rotation, translation = pose[:3, :3], pose[:3, 3]
        return SceneGeometry(
            self.triangles @ rotation.T + translation, self.normals @ rotation.T, self.albedo, self.owner, self.names
        )

    @staticmethod
    def concatenate(parts: list[SceneGeometry]) -> SceneGeometry:
        parts = [p for p in parts if len(p)]
        if not parts:
            return SceneGeometry.empty()
        names, owners, offset = [], [], 0
        for part in parts:
            owners.append(part.owner + offset)
            names.extend(part.names)
            offset += len(part.names)
        return SceneGeometry(
            np.concatenate([p.triangles for p in parts]),
            np.concatenate([p.normals for p in parts]),
            np.concatenate([p.albedo for p in parts]),
            np.concatenate(owners).astype(np.int32),
            tuple(names),
        )

    def owner_names(self, faces: np.ndarray) -> np.ndarray:
        """Owner name per face index (-1 -> '')."""
        lookup = np.array([*self.names, ""], dtype=object)
        faces = np.asarray(faces)
        return lookup[np.where(faces >= 0, self.owner[np.clip(faces, 0, None)], len(self.names))]


def primitive_mesh(kind: str, size=None, radius: float | None = None, length: float | None = None, sections: int = 48):
    """A box (size), cylinder (radius, length along z) or sphere centred at the origin, as URDF and the scene define them."""
    import trimesh

    if kind == "box":
        return trimesh.creation.box(extents=np.asarray(size, dtype=float))
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=float(radius), height=float(length), sections=sections)
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=3, radius=float(radius))
    raise ConfigError(f"unsupported primitive {kind!r} (box, cylinder, sphere)")


def albedo_of(color_rgba) -> float:
    """Diffuse albedo from a display colour: its luminance (Rec. 709), kept within [0.05, 1]."""
    r, g, b = (float(c) for c in color_rgba[:3])
    return float(np.clip(0.2126 * r + 0.7152 * g + 0.0722 * b, 0.05, 1.0))


def _load_mesh(path: Path, scale: float):
    import trimesh

    mesh = trimesh.load(str(path), force="mesh")
    mesh.apply_scale(scale)
    return mesh


def scene_geometry(scene: Scene, exclude_groups: tuple[str, ...] = ()) -> SceneGeometry:
    """The scene file's objects and the part as triangles in the scene frame (albedo from their colours)."""
    parts = []
    for obj in scene.objects:
        if obj.group is not None and obj.group in exclude_groups:
            continue
        if obj.type == "chessboard":
            parts.append(scene_chessboard_geometry(obj))
            continue
        if obj.type == "mesh":
            mesh = _load_mesh(obj.mesh, obj.mesh_scale)
        else:
            mesh = primitive_mesh(obj.type, obj.size_m, obj.radius_m, obj.length_m)
        parts.append(SceneGeometry.from_trimesh(mesh, obj.name, albedo_of(obj.color_rgba)).transformed(obj.pose))
    if scene.part is not None:
        mesh = _load_mesh(scene.part.mesh, scene.part.scale_to_m)
        parts.append(
            SceneGeometry.from_trimesh(mesh, scene.part.name, albedo_of(scene.part.color_rgba)).transformed(
                scene.part.pose
            )
        )
    return SceneGeometry.concatenate(parts)


class RobotGeometry:
    """The robot's link shapes from its URDF (visual elements by default) in link frames, posed per frame.

    ``mesh_resolver`` maps a URDF mesh filename (``package://...``, ``file://...``) to a local path; meshes it
    cannot resolve are left out and listed in :attr:`skipped`.
    """

    def __init__(self, urdf, elements: str = "visual", albedo: float = ROBOT_ALBEDO, mesh_resolver=None):
        table = urdf.visual if elements == "visual" else urdf.collision
        self.links: dict[str, SceneGeometry] = {}
        self.skipped: list[str] = []
        for link, geometries in table.items():
            parts = []
            for geometry in geometries:
                if geometry.type == "mesh":
                    path = _resolve_mesh(geometry.mesh, mesh_resolver)
                    if path is None:
                        self.skipped.append(f"{link}: {geometry.mesh}")
                        continue
                    mesh = _load_mesh(path, 1.0)
                    mesh.apply_scale(np.asarray(geometry.scale, dtype=float))
                else:
                    mesh = primitive_mesh(geometry.type, geometry.size, geometry.radius, geometry.length)
                parts.append(SceneGeometry.from_trimesh(mesh, link, albedo).transformed(geometry.origin))
            if parts:
                merged = SceneGeometry.concatenate(parts)
                self.links[link] = SceneGeometry(
                    merged.triangles, merged.normals, merged.albedo, np.zeros(len(merged), np.int32), (link,)
                )

    @property
    def link_names(self) -> list[str]:
        return list(self.links)

    def posed(self, link_poses: dict) -> SceneGeometry:
        """Triangles of the links whose pose (4x4, scene frame) is given; other links are left out."""
        return SceneGeometry.concatenate(
            [
                geometry.transformed(np.asarray(link_poses[link]))
                for link, geometry in self.links.items()
                if link in link_poses
            ]
        )


def _resolve_mesh(filename: str | None, resolver) -> Path | None:
    if not filename:
        return None
    if resolver is not None:
        resolved = resolver(filename)
        return Path(resolved) if resolved else None
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    path = Path(filename)
    return path if path.is_absolute() and path.is_file() else None


# ------------------------------------------------------------------------------------------ ray casting
class RayCaster:
    """Embree (embreex, the backend of ``trimesh.ray.ray_pyembree``) over one triangle soup; all rays at once.

    embreex is called directly because it returns the hit distance with the triangle, which trimesh's wrapper
    would recompute per ray. Directions need not be unit: distances are in units of the direction's length.
    """

    def __init__(self, geometry: SceneGeometry):
        from embreex import mesh_construction, rtcore_scene

        self.size = len(geometry)
        self.scene = rtcore_scene.EmbreeScene()
        if self.size:
            mesh_construction.TriangleMesh(self.scene, np.ascontiguousarray(geometry.triangles, dtype=np.float32))

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance (N,) float32, face index (N,) int32, -1 where the ray hits nothing)."""
        n = len(directions)
        if self.size == 0 or n == 0:
            return np.full(n, np.inf, dtype=np.float32), np.full(n, -1, dtype=np.int32)
        result = self.scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            output=1,
        )
        return result["tfar"], result["primID"]

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """Whether something lies on each ray between 0 and ``t_max`` (N,) bool."""
        n = len(directions)
        if self.size == 0 or n == 0:
            return np.zeros(n, dtype=bool)
        result = self.scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            dists=np.ascontiguousarray(t_max, dtype=np.float32),
            query="OCCLUDED",
        )
        return result == 0  # embreex: 0 = occluded, -1 = free


# --------------------------------------------------------------------------------------------- capture
@dataclass(frozen=True)
class ScanSettings:
    """The capturing settings the simulation uses (names and ranges of the driver's parameters)."""

    resolution: int = RESOLUTION_HIGH
    scan_multiplier: int = 1
    shutter_multiplier: int = 1
    single_pattern_exposure: int = 2
    confidence: float = 3.0  # max estimated inaccuracy (mm) of a kept point; <= 0 keeps all
    ambient_light_suppression: bool = False
    camera_only_mode: bool = False
    noise: bool = True
    seed: int = 0

    def exposure_ms(self) -> float:
        if not 0 <= self.single_pattern_exposure < len(SINGLE_PATTERN_EXPOSURES_MS):
            raise ValueError(f"single_pattern_exposure must be an index 0..{len(SINGLE_PATTERN_EXPOSURES_MS) - 1}")
        return SINGLE_PATTERN_EXPOSURES_MS[self.single_pattern_exposure]

    def effective_shutter_multiplier(self) -> int:
        return AMBIENT_SUPPRESSION_SHUTTER_MULTIPLIER if self.ambient_light_suppression else self.shutter_multiplier


@dataclass
class Frame:
    """One captured frame, organised H x W, in the camera frame. Invalid pixels have depth 0 (and zero normal).

    ``depth_mm`` is the depth along the camera's z axis (mm), ``normals`` unit normals (camera frame),
    ``confidence`` the estimated inaccuracy sigma_z (mm), ``texture`` the intensity (camera counts).
    """

    index: int
    intrinsics: CameraIntrinsics
    depth_mm: np.ndarray  # (H, W) float32
    normals: np.ndarray  # (H, W, 3) float32
    confidence: np.ndarray  # (H, W) float32
    texture: np.ndarray  # (H, W) float32
    camera_pose: np.ndarray  # world <- camera (4x4) the frame was taken from
    model: str = ""
    stats: dict = field(default_factory=dict)
    #: the PhoXi coordinate space the frame was captured in, and its transform of camera-frame points (p' = T p)
    coordinate_space: int = 1
    output_transform: np.ndarray = field(default_factory=lambda: np.eye(4))

    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    @property
    def valid(self) -> np.ndarray:
        return self.depth_mm > 0.0

    def points_m(self) -> np.ndarray:
        """(H, W, 3) float32 camera-frame points in metres, zeros where invalid (exactly depth_mm / 1000 in z)."""
        rays = self.intrinsics.pixel_rays().reshape(self.height, self.width, 3)
        return rays * (self.depth_mm / np.float32(1000.0))[:, :, None]

    def rgb_texture(self) -> np.ndarray:
        return rgb_texture(self.texture)


def depth_sigma_mm(model: ScannerModel, settings: ScanSettings, depth_mm, cos_projector, albedo) -> np.ndarray:
    """The noise model's sigma_z (mm) for depths (mm), cosines of the projector incidence and albedos."""
    noise = model.noise
    depth_mm = np.asarray(depth_mm)
    dtype = np.result_type(depth_mm.dtype, np.float32)
    exposure = settings.scan_multiplier * settings.effective_shutter_multiplier() * settings.exposure_ms()
    gain = np.asarray(albedo, dtype=dtype) * dtype.type(
        exposure / (noise.reference_albedo * noise.reference_exposure_ms)
    )
    cos_p = np.maximum(np.asarray(cos_projector, dtype=dtype), dtype.type(noise.min_cos_incidence))
    ratio = depth_mm.astype(dtype, copy=False) / dtype.type(model.sweet_spot_mm)
    return dtype.type(model.temporal_noise_mm) * ratio * ratio / np.sqrt(cos_p * gain)


#: pixels rendered per chunk: temporaries of a few MB stay in cache, and chunks spread over the CPU cores
CHUNK_PIXELS = 1 << 17


@dataclass
class _FrameJob:
    """What every chunk of one frame shares: inputs (camera frame unless noted) and the output images."""

    caster: RayCaster
    settings: ScanSettings
    frame_index: int
    rays: np.ndarray  # (N, 3) float32, z = 1
    inverse_ray_norms: np.ndarray  # (N,) float32
    rotation: np.ndarray  # world <- camera, float32
    origin: np.ndarray  # camera position (world), float32
    projector_world: np.ndarray  # float32
    normals: np.ndarray  # (F, 3) face normals in the camera frame, float32
    albedo: np.ndarray  # (F,) float32
    depth_mm: np.ndarray
    normals_out: np.ndarray
    confidence: np.ndarray
    texture: np.ndarray


class StructuredLightScanner:
    """Renders frames of one :class:`ScannerModel`; :meth:`capture` takes the scene as one triangle soup.

    The image is rendered in chunks of :data:`CHUNK_PIXELS` pixels on ``workers`` threads (Embree and numpy
    release the GIL). The noise of a chunk is seeded by (seed, frame index, first pixel), so a frame does not
    depend on the number of threads.
    """

    def __init__(self, model: ScannerModel, workers: int | None = None):
        self.model = model
        self.projector = model.projector_pose()
        half_h, half_v = (math.radians(a) / 2.0 for a in model.projector_fov_deg)
        self._tan_projector = (math.tan(half_h), math.tan(half_v))
        self.workers = max(1, int(workers if workers is not None else min(4, os.cpu_count() or 1)))
        self._pool = None

    def capture(
        self,
        geometry: SceneGeometry,
        camera_pose: np.ndarray,
        settings: ScanSettings | None = None,
        frame_index: int = 0,
        caster: RayCaster | None = None,
    ) -> Frame:
        """One frame of ``geometry`` (scene frame) seen from ``camera_pose`` (scene <- camera, 4x4, metres)."""
        settings = settings or ScanSettings()
        settings.exposure_ms()  # refuses an exposure index out of range before any work
        intrinsics = self.model.intrinsics(settings.resolution)
        pose = np.asarray(camera_pose, dtype=float)
        rotation = pose[:3, :3]
        rays = intrinsics.pixel_rays()
        n = len(rays)
        job = _FrameJob(
            caster=caster or RayCaster(geometry),
            settings=settings,
            frame_index=int(frame_index),
            rays=rays,
            inverse_ray_norms=_inverse_norms(
                intrinsics.width, intrinsics.height, intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
            ),
            rotation=rotation.astype(np.float32),
            origin=pose[:3, 3].astype(np.float32),
            projector_world=(pose @ np.append(self.projector[:3, 3], 1.0))[:3].astype(np.float32),
            normals=(np.asarray(geometry.normals, dtype=float) @ rotation).astype(np.float32).reshape(-1, 3),
            albedo=np.asarray(geometry.albedo, dtype=np.float32),
            depth_mm=np.empty(n, dtype=np.float32),
            normals_out=np.empty((n, 3), dtype=np.float32),
            confidence=np.empty(n, dtype=np.float32),
            texture=np.empty(n, dtype=np.float32),
        )
        chunks = [slice(start, min(start + CHUNK_PIXELS, n)) for start in range(0, n, CHUNK_PIXELS)]
        if self.workers > 1 and len(chunks) > 1:
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="structured_light")
            counts = list(self._pool.map(lambda chunk: self._render_chunk(job, chunk), chunks))
        else:
            counts = [self._render_chunk(job, chunk) for chunk in chunks]
        hits, lit, valid = (int(v) for v in np.sum(counts, axis=0))
        h, w = intrinsics.height, intrinsics.width
        return Frame(
            index=int(frame_index),
            intrinsics=intrinsics,
            depth_mm=job.depth_mm.reshape(h, w),
            normals=job.normals_out.reshape(h, w, 3),
            confidence=job.confidence.reshape(h, w),
            texture=job.texture.reshape(h, w),
            camera_pose=pose.copy(),
            model=self.model.name,
            stats={"pixels": n, "hits": hits, "lit": lit, "valid": valid},
        )

    def _render_chunk(self, job: _FrameJob, chunk: slice) -> tuple[int, int, int]:
        model, noise, settings = self.model, self.model.noise, job.settings
        rays = job.rays[chunk]
        directions = _rotate(rays, job.rotation)
        origins = np.empty_like(directions)
        origins[:] = job.origin
        distance, faces = job.caster.first_hit(origins, directions)
        hit = faces >= 0
        face = np.maximum(faces, 0)
        depth = np.where(hit, distance, np.float32(0.0))  # rays have z = 1: the distance along them is the depth (m)
        point = rays * depth[:, None]

        normal = job.normals[face]
        cos_camera = -np.einsum("ij,ij->i", normal, rays) * job.inverse_ray_norms[chunk]
        # thin or open surfaces seen from behind show their other side
        side = np.where(cos_camera < 0.0, np.float32(-1.0), np.float32(1.0))
        normal *= side[:, None]
        cos_camera *= side

        proj_rotation = self.projector[:3, :3].astype(np.float32)
        to_projector = self.projector[:3, 3].astype(np.float32) - point
        projector_distance = np.sqrt(np.einsum("ij,ij->i", to_projector, to_projector))
        cos_projector = np.einsum("ij,ij->i", normal, to_projector) / projector_distance
        in_projector = _rotate(to_projector, -proj_rotation.T)
        tan_h, tan_v = self._tan_projector
        candidate = (
            hit
            & (cos_projector > 0.0)
            & (in_projector[:, 2] > 0.0)
            & (np.abs(in_projector[:, 0]) <= tan_h * in_projector[:, 2])
            & (np.abs(in_projector[:, 1]) <= tan_v * in_projector[:, 2])
        )
        # shadow rays from the projector to every point; non-candidates get a negative length, which Embree skips
        shadow_dirs = directions * depth[:, None]
        shadow_dirs += job.origin - job.projector_world
        origins[:] = job.projector_world
        t_max = np.where(candidate, 1.0 - noise.shadow_epsilon_m / projector_distance, np.float32(-1.0))
        lit = candidate & ~job.caster.occluded(origins, shadow_dirs, t_max)

        albedo = job.albedo[face]
        depth_mm = depth * np.float32(1000.0)
        sigma = depth_sigma_mm(model, settings, depth_mm, cos_projector, albedo)
        low, high = model.scanning_range_mm
        valid = lit & (depth_mm >= low) & (depth_mm <= high)
        if settings.confidence > 0.0:
            valid &= sigma <= settings.confidence
        if settings.camera_only_mode:
            valid[:] = False

        ambient = noise.camera_only_ambient_fraction if settings.camera_only_mode else noise.ambient_fraction
        light = np.float32(ambient) * cos_camera
        if not settings.camera_only_mode:
            ratio = np.float32(model.sweet_spot_mm / 1000.0) / projector_distance
            light += np.where(lit, cos_projector * ratio * ratio, np.float32(0.0))
        exposure_gain = settings.effective_shutter_multiplier() * settings.exposure_ms() / noise.reference_exposure_ms
        texture = np.float32(noise.texture_full_scale * exposure_gain) * albedo * light
        np.minimum(texture, np.float32(noise.texture_saturation), out=texture)
        texture[~hit] = 0.0

        sigma = np.where(valid, sigma, np.float32(0.0))
        measured = np.where(valid, depth_mm, np.float32(0.0))
        if settings.noise:
            rng = np.random.default_rng([int(settings.seed), job.frame_index, chunk.start])
            measured += rng.standard_normal(len(rays), dtype=np.float32) * sigma
        normal *= valid[:, None]
        job.depth_mm[chunk] = measured
        job.normals_out[chunk] = normal
        job.confidence[chunk] = sigma
        job.texture[chunk] = texture
        return int(hit.sum()), int(lit.sum()), int(valid.sum())


@lru_cache(maxsize=4)
def _inverse_norms(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    rays = _pixel_rays(width, height, fx, fy, cx, cy)
    inverse = (1.0 / np.sqrt(np.einsum("ij,ij->i", rays.astype(np.float64), rays))).astype(np.float32)
    inverse.setflags(write=False)
    return inverse


def _rotate(vectors: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``vectors @ rotation.T`` for (N, 3) arrays, by einsum: BLAS matmul threads cost far more than they bring for
    (N, 3) x (3, 3), especially when the other core is busy."""
    return np.einsum("ij,kj->ik", vectors, rotation)


# ---------------------------------------------------------------------------------------------- output
def rgb_texture(texture: np.ndarray) -> np.ndarray:
    """The driver's rgb_texture: min-max normalised to 0..255, 8 bit, histogram-equalised, grey to RGB."""
    import cv2

    grey = cv2.normalize(np.asarray(texture, dtype=np.float32), None, 0.0, 255.0, cv2.NORM_MINMAX)
    grey = cv2.equalizeHist(grey.astype(np.uint8))
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)


def transform_points(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, transform: np.ndarray):
    """Points and normals (H, W, 3) mapped by ``transform`` (4x4: p' = R p + t); invalid pixels stay zero."""
    rotation = np.asarray(transform[:3, :3], dtype=np.float32)
    translation = np.asarray(transform[:3, 3], dtype=np.float32)
    points_out = np.einsum("...j,kj->...k", points, rotation) + translation
    normals_out = np.einsum("...j,kj->...k", normals, rotation)
    points_out[~valid] = 0.0
    normals_out[~valid] = 0.0
    return points_out, normals_out


# --------------------------------------------------------------------------------------- chessboards
WHITE_ALBEDO = 0.9
BLACK_ALBEDO = 0.08


def chessboard_geometry(board_pose: np.ndarray, inner_corners=(8, 11), square_m: float = 0.03, thickness_m=0.003):
    """SceneGeometry (frame of ``board_pose``'s parent) of a chessboard: (rows+1) x (cols+1) squares of alternating
    albedo, printed (0.1 mm) on a white backing board with a one-square margin (the quiet zone OpenCV needs)."""
    backing = np.eye(4)
    backing[2, 3] = -thickness_m / 2.0  # its face at z = 0: the corners' plane
    size = chessboard_board_size(inner_corners, square_m, thickness_m)
    parts = [SceneGeometry.from_trimesh(primitive_mesh("box", size=size), "board", WHITE_ALBEDO).transformed(backing)]
    printed = SceneGeometry.from_trimesh(
        primitive_mesh("box", size=(square_m, square_m, 0.0002)), "square", BLACK_ALBEDO
    )
    for x, y in chessboard_dark_squares(inner_corners, square_m):
        square = np.eye(4)
        square[:2, 3] = [x, y]  # printed: 0.1 mm proud of the face
        parts.append(printed.transformed(square))
    return SceneGeometry.concatenate(parts).transformed(np.asarray(board_pose, dtype=float))


def scene_chessboard_geometry(board) -> object:
    """SceneGeometry of a scene file's chessboard object (station.SceneObject of type chessboard)."""
    return chessboard_geometry(board.pose, board.inner_corners, board.square_m, board.thickness_m)
