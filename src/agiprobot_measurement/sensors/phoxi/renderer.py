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

Error models (``errors``: :class:`~agiprobot_measurement.sensors.error_models.PhoxiErrors`, None = none)
    calibration: the rays are cast from the device's true camera (focal scale, principal point, residual
    distortion) and the depth is reconstructed with the nominal camera and projector from the projector column
    the true projector lit; fixed pattern: ``share`` of sigma_z comes from a static per-device field; material:
    points whose projector signal is below ``min_signal_counts`` or saturates (specular glints) are invalid;
    edges: mixed pixels next to depth jumps; interreflection: a pixel seeing light that a specular surface mirrored
    onto its point decodes the mirror point's pattern column (a biased depth). See ``docs/sensor-errors.md``.

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

import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.sensors.error_models import PhoxiErrors, mix_depth_edges, reconstruct_depth

# Scanner models and scene geometry live in their own modules; the names the calibration simulation, its tests and
# tools import from here stay importable (re-exported in __all__).
from agiprobot_measurement.sensors.phoxi.models import (
    FRAME_OUTPUTS,
    RESOLUTION_HIGH,
    CameraIntrinsics,
    ScannerModel,
    load_scanner_model,
)
from agiprobot_measurement.sensors.phoxi.scene_geometry import (
    RobotGeometry,
    SceneGeometry,
    chessboard_geometry,
    primitive_mesh,
    scene_geometry,
)

__all__ = [
    "AMBIENT_SUPPRESSION_SHUTTER_MULTIPLIER",
    "CHUNK_PIXELS",
    "SINGLE_PATTERN_EXPOSURES_MS",
    "Frame",
    "RayCaster",
    "RobotGeometry",
    "ScanSettings",
    "SceneGeometry",
    "StructuredLightScanner",
    "chessboard_geometry",
    "depth_sigma_mm",
    "load_scanner_model",
    "primitive_mesh",
    "rgb_texture",
    "scene_geometry",
    "transform_points",
]

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
            raise InputError(f"single_pattern_exposure must be an index 0..{len(SINGLE_PATTERN_EXPOSURES_MS) - 1}")
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
    #: the parts the scanner delivered (models.FRAME_OUTPUTS; a file camera's recording may lack some)
    outputs: tuple[str, ...] = FRAME_OUTPUTS

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
    cast_rays: np.ndarray | None = None  # (N, 3) the true camera's rays when it differs from the nominal one
    pattern: np.ndarray | None = None  # (N,) the device's fixed-pattern field
    specular: np.ndarray | None = None  # (F,) specular share per face
    bounces: list | None = None  # per chunk (points, mirror directions, shares) of lit specular points


class StructuredLightScanner:
    """Renders frames of one :class:`ScannerModel`; :meth:`capture` takes the scene as one triangle soup.

    The image is rendered in chunks of :data:`CHUNK_PIXELS` pixels on ``workers`` threads (Embree and numpy
    release the GIL). The noise of a chunk is seeded by (seed, frame index, first pixel), so a frame does not
    depend on the number of threads.
    """

    def __init__(self, model: ScannerModel, workers: int | None = None, errors: PhoxiErrors | None = None):
        self.model = model
        #: the device's realised error models (None: the noise model only)
        self.errors = errors
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
            inverse_ray_norms=_inverse_norms(intrinsics),
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
        errors = self.errors
        if errors is not None:
            job.cast_rays = errors.true_rays(intrinsics)
            job.pattern = errors.pattern_field(intrinsics.width, intrinsics.height)
            if errors.material is not None:
                job.specular = errors.specular_shares(geometry.names)[np.asarray(geometry.owner, dtype=np.int64)]
                if errors.interreflection is not None and settings.noise and job.specular.any():
                    job.bounces = []
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
        if errors is not None and errors.edges is not None and settings.noise:
            depth = job.depth_mm.reshape(h, w)
            rng = np.random.default_rng([int(settings.seed), int(frame_index), 1 << 30])
            jump = np.float32(errors.edges["jump_rel"]) * depth
            job.depth_mm = mix_depth_edges(depth, depth > 0.0, jump, errors.edges["probability"], rng).reshape(-1)
        if job.bounces:
            self._interreflect(job, intrinsics)
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
        cast = rays if job.cast_rays is None else job.cast_rays[chunk]
        directions = _rotate(cast, job.rotation)
        origins = np.empty_like(directions)
        origins[:] = job.origin
        distance, faces = job.caster.first_hit(origins, directions)
        hit = faces >= 0
        face = np.maximum(faces, 0)
        depth = np.where(hit, distance, np.float32(0.0))  # rays have z = 1: the distance along them is the depth (m)
        point = cast * depth[:, None]

        normal = job.normals[face]
        cos_camera = -np.einsum("ij,ij->i", normal, cast) * job.inverse_ray_norms[chunk]
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
        errors = self.errors
        if errors is not None and errors.calibration is not None and hit.any():
            # reconstructed with the nominal calibration from what the true camera and projector saw
            measured_depth = errors.calibration.reconstruct(
                rays[hit].astype(float), point[hit].astype(float), self.projector
            )
            depth = depth.copy()
            depth[hit] = measured_depth
        depth_mm = depth * np.float32(1000.0)
        sigma = depth_sigma_mm(model, settings, depth_mm, cos_projector, albedo)
        low, high = model.scanning_range_mm
        valid = lit & (depth_mm >= low) & (depth_mm <= high)
        if errors is not None and errors.material is not None and not settings.camera_only_mode:
            at = np.flatnonzero(valid)
            valid[at] = self._signal_ok(
                job,
                errors.material,
                face[at],
                normal[at],
                point[at],
                to_projector[at],
                projector_distance[at],
                albedo[at],
            )
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
            if job.pattern is None:
                measured += rng.standard_normal(len(rays), dtype=np.float32) * sigma
            else:
                share = np.float32(self.errors.fixed_pattern["share"])
                temporal = rng.standard_normal(len(rays), dtype=np.float32) * np.float32(math.sqrt(1.0 - share**2))
                measured += (temporal + share * job.pattern[chunk]) * sigma
        if job.bounces is not None:
            share = job.specular[face]
            bounce = lit & (share > 0.0)
            if bounce.any():
                incoming = -to_projector[bounce] / projector_distance[bounce, None]
                n_b = normal[bounce]
                mirror = incoming - 2.0 * np.einsum("ij,ij->i", incoming, n_b)[:, None] * n_b
                job.bounces.append((point[bounce], mirror, share[bounce]))
        normal *= valid[:, None]
        job.depth_mm[chunk] = measured
        job.normals_out[chunk] = normal
        job.confidence[chunk] = sigma
        job.texture[chunk] = texture
        return int(hit.sum()), int(lit.sum()), int(valid.sum())

    def _interreflect(self, job: _FrameJob, intrinsics) -> None:
        """Single-bounce interreflection: the projector light that a specular point A mirrors onto a surface point B
        carries A's pattern column; the pixel that sees B then decodes that column (with probability A's specular
        share times ``strength``) and triangulates a wrong depth: its ray against A's projector plane."""
        points = np.concatenate([b[0] for b in job.bounces]).astype(float)
        mirrors = np.concatenate([b[1] for b in job.bounces]).astype(float)
        shares = np.concatenate([b[2] for b in job.bounces]).astype(float)
        rotation = job.rotation.astype(float)
        start = points + 1e-4 * mirrors  # leave A's surface (m)
        distance, faces = job.caster.first_hit(start @ rotation.T + job.origin, mirrors @ rotation.T)
        landed = (faces >= 0) & np.isfinite(distance)
        if not landed.any():
            return
        a, b = points[landed], start[landed] + mirrors[landed] * distance[landed, None].astype(float)
        share = shares[landed]
        in_front = b[:, 2] > 1e-6
        a, b, share = a[in_front], b[in_front], share[in_front]
        pixel = np.rint(intrinsics.project(b)).astype(np.int64)
        inside = (pixel[:, 0] >= 0) & (pixel[:, 0] < intrinsics.width) & (pixel[:, 1] >= 0)
        inside &= pixel[:, 1] < intrinsics.height
        a, b, share, pixel = a[inside], b[inside], share[inside], pixel[inside]
        index = pixel[:, 1] * intrinsics.width + pixel[:, 0]
        depth = job.depth_mm[index]
        # the pixel must see B itself (not something in front of it)
        seen = (depth > 0.0) & (np.abs(depth - 1000.0 * b[:, 2]) < np.maximum(1.0, 10.0 * job.confidence[index]))
        settings = job.settings
        rng = np.random.default_rng([int(settings.seed), job.frame_index, 1 << 29])
        hit = seen & (rng.random(len(seen)) < np.minimum(share * self.errors.interreflection["strength"], 1.0))
        if not hit.any():
            return
        calibration = self.errors.calibration
        if calibration is None:
            wrong = reconstruct_depth(job.rays[index[hit]].astype(float), a[hit], self.projector, self.projector)
        else:
            wrong = calibration.reconstruct(job.rays[index[hit]].astype(float), a[hit], self.projector)
        # a depth outside the scanning range is an inconsistent code: the point is dropped rather than moved
        wrong_mm = 1000.0 * np.where(np.isfinite(wrong), wrong, 0.0)
        low, high = self.model.scanning_range_mm
        job.depth_mm[index[hit]] = np.where((wrong_mm >= low) & (wrong_mm <= high), wrong_mm, 0.0).astype(np.float32)

    def _signal_ok(self, job, material, face, normal, point, to_projector, projector_distance, albedo):
        """Material gate: the projector signal (camera counts) lies between the dark limit and saturation."""
        noise, settings = self.model.noise, job.settings
        share = job.specular[face] if job.specular is not None else np.float32(0.0)
        incoming = -to_projector / projector_distance[:, None]
        mirror = incoming - 2.0 * np.einsum("ij,ij->i", incoming, normal)[:, None] * normal
        to_camera = -point / np.maximum(np.linalg.norm(point, axis=1), 1e-9)[:, None]
        lobe = np.maximum(np.einsum("ij,ij->i", mirror, to_camera), 0.0) ** np.float32(material["specular_exponent"])
        cos_p = np.einsum("ij,ij->i", normal, -incoming)
        ratio = np.float32(self.model.sweet_spot_mm / 1000.0) / projector_distance
        exposure_gain = settings.effective_shutter_multiplier() * settings.exposure_ms() / noise.reference_exposure_ms
        diffuse = albedo * (1.0 - share) * np.maximum(cos_p, 0.0) * ratio * ratio
        signal = noise.texture_full_scale * exposure_gain * (diffuse + share * material["specular_peak"] * lobe)
        return (signal >= material["min_signal_counts"]) & (signal < noise.texture_saturation)


@lru_cache(maxsize=4)
def _inverse_norms(intrinsics: CameraIntrinsics) -> np.ndarray:
    rays = intrinsics.pixel_rays()
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
