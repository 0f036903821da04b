"""Laser line scanner model: uncertainty equations and metrological evaluation of viewpoints.

Frames and symbols (lengths in mm, angles in rad throughout this module):

* ``laser_emitter_frame``: x = trajectory direction ``t``, z = boresight ``s`` (towards the surface point at
  the anchor pose), y = ``l`` (right-handed). Its orientation is constant along a straight measurement
  trajectory; only the position moves, ``e = anchor + t0 * t``.
* For a sample point ``p`` with face normal ``n``: the laser line sweeps ``p`` when the emitter is at
  ``t0 = (p - anchor) . t``; ``z = s . (p - e)``; ``psi = atan2(t . n, -s . n)``; ``theta`` is the angle
  between the emitter ray ``p - e`` and ``n``, both projected on the emitter frame's y-z plane.
* ``xi_0 = sin(alpha) * optimal_standoff``; the detector sits ``tan(alpha) * optimal_standoff`` behind the
  emitter along **-x** of the laser_emitter_frame (the side ``config/laser_scanner.yaml``'s housing covers).
* ``u(z, psi) = K_u * sqrt(z^2 + xi_0^2 - 2 z xi_0 sin(alpha)) / cos(psi) * z``; a measured point is assigned
  ``u(z, psi) * |s . n|``.

A point is measurable from a straight trajectory when it lies in the scan frustum (fan angle between the
minimum and maximum standoff, swept +-maximum_deflection along x), ``|psi| < psi_max``, ``theta < theta_max``,
``min_standoff < z < max_standoff``, its assigned uncertainty is at most the caller's threshold, and both the
emitter ray and the detector ray reach it unoccluded from the front of its face.

:meth:`SensorModel.evaluate_viewpoints_batch` evaluates many anchor poses at once: the geometric limits are
vector maths over (view x point) chunks, and only the surviving pairs are ray-cast, in large Embree batches.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import scipy.sparse
import trimesh

from agiprobot_measurement.common.config import positive
from agiprobot_measurement.errors import InternalError
from agiprobot_measurement.sensors.errors import SensorInputError, SensorTypeError, ViewIndexError
from agiprobot_measurement.sensors.laser_line.queries import Cells, RayCaster, build_cells, cull_pairs, support_test
from agiprobot_measurement.station import load_scanner_config

__all__ = [
    "BRUTE_FORCE_FACES",
    "CELL_CULL_POINTS",
    "DEFAULT_CHUNK_ELEMENTS",
    "PARAMETER_NAMES",
    "MeasurabilityResult",
    "ProcessingContextError",
    "SensorModel",
    "supporting_faces",
]

#: Canonical parameter names (as in ``config/laser_scanner.yaml``'s ``sensor_model`` section) and the
#: alternative spellings accepted in a ``parameter_map``.
PARAMETER_NAMES = {
    "optimal_standoff_mm": ("optimal_standoff", "optimal_standoff_distance"),
    "minimum_standoff_mm": ("minimum_standoff", "min_standoff"),
    "maximum_standoff_mm": ("maximum_standoff", "max_standoff"),
    "theta_max_rad": ("theta_max", "maximum_deviation_theta", "max_deviation_theta"),
    "psi_max_rad": ("psi_max", "maximum_deviation_psi", "max_deviation_psi"),
    "K_u": ("K", "k_u"),
    "alpha_rad": ("alpha",),
    "fan_angle_rad": ("fan_angle", "laser_fan_angle"),
}

#: Default target size of one dense (views x points) work array in the batch evaluator (elements). Small
#: enough to stay in the CPU cache, large enough that the Python overhead per chunk is negligible.
DEFAULT_CHUNK_ELEMENTS = 1 << 18
#: from this many samples on, a view's candidate points come from a grid of sample cells culled against its
#: frustum instead of a dense (views x points) test: the same result, with work that grows with the pairs in
#: reach rather than with every point (a door-sized panel has 30,000 samples; a view reaches a few thousand)
CELL_CULL_POINTS = 4096


class ProcessingContextError(InternalError):
    """Metrological processing was requested before :meth:`SensorModel.set_processing_context`."""


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # Row-wise dot product written out so that every pair is computed with the same operations whatever
    # the batch size: the per-viewpoint method then reproduces the batch bit for bit.
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


@dataclass(frozen=True)
class MeasurabilityResult:
    """Sparse (point x viewpoint) measurability of a batch of viewpoints.

    Column ``j`` (viewpoint ``j``) holds the entries ``indptr[j]:indptr[j+1]`` of ``point_indices`` (sorted
    ascending), ``uncertainties`` (mm) and ``trajectory_distances`` (``t0`` in mm: where along the
    trajectory direction, from the anchor, the point is swept by the laser line).

    ``extent_min`` / ``extent_max`` (optional, (V,) float64 mm): each column's exact smallest and largest ``t0``.
    A :meth:`compact` result keeps them, so the scan lines derived from :attr:`t0_min` / :attr:`t0_max` do not
    depend on the quantised per-entry values.
    """

    n_points: int
    n_views: int
    indptr: np.ndarray  # (V + 1,) int64
    point_indices: np.ndarray  # (nnz,) int32
    uncertainties: np.ndarray  # (nnz,) float64 (float32 when compact), mm
    trajectory_distances: np.ndarray  # (nnz,) float64, mm
    extent_min: np.ndarray | None = None  # (V,) float64 mm, exact
    extent_max: np.ndarray | None = None  # (V,) float64 mm, exact

    @classmethod
    def concatenate(cls, results: Sequence[MeasurabilityResult]) -> MeasurabilityResult:
        """One result whose viewpoints are those of ``results`` in order (all over the same samples)."""
        if not results:
            raise SensorInputError("concatenate needs at least one result")
        n_points = results[0].n_points
        if any(r.n_points != n_points for r in results):
            raise SensorInputError("results to concatenate must be over the same sample points")
        indptr, offset = [np.zeros(1, dtype=np.int64)], 0
        for result in results:
            indptr.append(result.indptr[1:] + offset)
            offset += result.nnz
        extents = {}
        if all(r.extent_min is not None for r in results):
            extents = dict(
                extent_min=np.concatenate([r.extent_min for r in results]),
                extent_max=np.concatenate([r.extent_max for r in results]),
            )
        return cls(
            n_points,
            sum(r.n_views for r in results),
            np.concatenate(indptr),
            np.concatenate([r.point_indices for r in results]),
            np.concatenate([r.uncertainties for r in results]),
            np.concatenate([r.trajectory_distances for r in results]),
            **extents,
        )

    def compact(self, t0_dtype=np.float64) -> MeasurabilityResult:
        """The same measurability in compact types: point ids int32, uncertainties float32 (mm), ``t0`` as
        ``t0_dtype``, with the exact float64 ``t0`` range of every column kept in ``extent_min`` / ``extent_max``.

        float32 keeps 24 bits: an uncertainty (at most the threshold, ~0.1 mm) to ~6e-9 mm (relative 6e-8), a
        ``t0`` (at most 500 mm) to 3e-5 mm. Both changed plans when the planner used them (measured): a shortened
        scan line's intact end equals its extreme ``t0`` exactly and the partial acceptance compares at 1e-9 mm;
        the set cover breaks ties by the uncertainties. The planner therefore keeps float64 by default
        (:class:`~agiprobot_measurement.planning.candidates.streaming.EvaluationSettings`, ``compact=False``).
        """
        return MeasurabilityResult(
            self.n_points,
            self.n_views,
            self.indptr,
            self.point_indices.astype(np.int32, copy=False),
            self.uncertainties.astype(np.float32, copy=False),
            self.trajectory_distances.astype(t0_dtype, copy=False),
            self.t0_min if self.extent_min is None else self.extent_min,
            self.t0_max if self.extent_max is None else self.extent_max,
        )

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        arrays = (self.indptr, self.point_indices, self.uncertainties, self.trajectory_distances)
        extra = [a for a in (self.extent_min, self.extent_max) if a is not None]
        return int(sum(a.nbytes for a in (*arrays, *extra)))

    @property
    def nnz(self) -> int:
        return int(self.point_indices.shape[0])

    @property
    def counts(self) -> np.ndarray:
        """Number of measurable points per viewpoint, (V,)."""
        return np.diff(self.indptr)

    def _matrix(self, data: np.ndarray) -> scipy.sparse.csc_matrix:
        return scipy.sparse.csc_matrix(
            (data, self.point_indices, self.indptr), shape=(self.n_points, self.n_views), copy=False
        )

    @property
    def uncertainty(self) -> scipy.sparse.csc_matrix:
        """(P, V) CSC matrix of assigned uncertainties in mm (every stored entry is measurable, > 0)."""
        return self._matrix(self.uncertainties)

    @property
    def measurability(self) -> scipy.sparse.csc_matrix:
        """(P, V) boolean CSC matrix: point i measurable by viewpoint j."""
        return self._matrix(np.ones(self.nnz, dtype=bool))

    def _reduce(self, ufunc: np.ufunc, values: np.ndarray) -> np.ndarray:
        out = np.full(self.n_views, np.nan)
        nonempty = np.flatnonzero(self.counts > 0)
        if nonempty.size:
            out[nonempty] = ufunc.reduceat(values, self.indptr[nonempty])
        return out

    @property
    def t0_min(self) -> np.ndarray:
        """(V,) smallest ``t0`` in mm per viewpoint (NaN where nothing is measurable)."""
        if self.extent_min is not None:
            return self.extent_min
        return self._reduce(np.minimum, self.trajectory_distances)

    @property
    def t0_max(self) -> np.ndarray:
        """(V,) largest ``t0`` in mm per viewpoint (NaN where nothing is measurable)."""
        if self.extent_max is not None:
            return self.extent_max
        return self._reduce(np.maximum, self.trajectory_distances)

    @property
    def max_uncertainty(self) -> np.ndarray:
        """(V,) worst assigned uncertainty in mm per viewpoint (NaN where nothing is measurable)."""
        return self._reduce(np.maximum, self.uncertainties)

    def view(self, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(point indices, uncertainties mm, t0 mm) of viewpoint ``j``, as the per-viewpoint API returns."""
        if not -self.n_views <= j < self.n_views:
            raise ViewIndexError(f"viewpoint {j} out of range for {self.n_views} viewpoints")
        j %= self.n_views
        lo, hi = self.indptr[j], self.indptr[j + 1]
        return (
            self.point_indices[lo:hi].astype(np.int64),
            self.uncertainties[lo:hi].astype(float),
            self.trajectory_distances[lo:hi].astype(float),
        )


@dataclass(frozen=True)
class _Context:
    mesh: trimesh.Trimesh
    points: np.ndarray  # (P, 3) mm
    face_ids: np.ndarray  # (P,)
    normals: np.ndarray  # (P, 3)
    point_data: np.ndarray  # (6, P): points and normals as rows
    caster: RayCaster
    unoccludable: np.ndarray  # (P,) bool: the sample's face plane supports the whole mesh
    center: np.ndarray  # (3,)
    cells: Cells | None = None  # for CELL_CULL_POINTS samples or more


#: up to this many faces, :func:`supporting_faces` tests them against every vertex (a few ns per pair) rather than
#: build the convex hull (tens of microseconds per vertex: half a minute for a finely meshed part)
BRUTE_FORCE_FACES = 4096


def supporting_faces(mesh: trimesh.Trimesh, tolerance: float | None = None, faces=None) -> np.ndarray:
    """Boolean per face (of ``faces``, default all): does the face's plane support the mesh (no vertex lies in
    front of it)?

    Every face of a convex mesh does. A segment from a point in front of such a face to a point on it cannot
    meet the mesh anywhere else. ``tolerance`` (mm) defaults to 1e-6 of the mesh's scale. A flat or degenerate
    mesh (no convex hull) gets none. A few faces are tested against every vertex; many, by a climb on the convex
    hull's vertex graph (:func:`~agiprobot_measurement.sensors.laser_line.queries.support_test`): near-linear.
    """
    if tolerance is None:
        tolerance = 1e-6 * float(mesh.scale)
    index = np.arange(len(mesh.faces)) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    normals = np.asarray(mesh.face_normals, dtype=float)[index]
    origins = np.asarray(mesh.triangles[index, 0])
    thresholds = np.einsum("ij,ij->i", normals, origins) + tolerance
    vertices = np.asarray(mesh.vertices, dtype=float)
    centred = vertices - vertices.mean(axis=0) if len(vertices) else np.zeros((0, 3))
    if len(vertices) < 4 or np.linalg.svd(centred, compute_uv=False)[-1] <= 1e-9 * max(float(mesh.scale), 1e-300):
        return np.zeros(len(index), dtype=bool)  # flat: no hull, nothing culled
    if len(index) <= BRUTE_FORCE_FACES:
        result = np.zeros(len(index), dtype=bool)
        block = max(1, (1 << 22) // max(1, len(vertices)))
        for start in range(0, len(index), block):
            height = normals[start : start + block] @ vertices.T
            result[start : start + block] = height.max(axis=1) <= thresholds[start : start + block]
    else:
        try:
            hull = mesh.convex_hull
        except Exception:  # qhull fails on flat or degenerate meshes: then nothing is culled
            return np.zeros(len(index), dtype=bool)
        result = support_test(hull, normals, thresholds, origins)
    # degenerate faces have no normal and so no front side
    result &= np.linalg.norm(normals, axis=1) > 0.5
    return result


class SensorModel:
    """Computational representation of a laser triangulation sensor under the influence of uncertainty.

    ``parameter_map`` holds the keys of ``config/laser_scanner.yaml``'s ``sensor_model`` section (mm, rad):
    ``optimal_standoff_mm``, ``minimum_standoff_mm``, ``maximum_standoff_mm``, ``theta_max_rad``,
    ``psi_max_rad``, ``K_u``, ``alpha_rad``, ``fan_angle_rad`` (full opening angle of the laser fan). The
    spellings in :data:`PARAMETER_NAMES` are accepted as well; further keys (``profile_rate_hz``, ...) are
    kept in :attr:`parameters` and otherwise ignored.

    ``occlusion_tolerance_mm``: an obstacle closer than this to a sample point along a ray does not occlude
    it (absorbs the float32 rounding of the ray tracer; far below the scanner's resolution).
    """

    def __init__(self, parameter_map: Mapping, *, occlusion_tolerance_mm: float = 0.01):
        if not isinstance(parameter_map, Mapping):
            raise SensorTypeError(f"parameter_map must be a mapping, got {type(parameter_map).__name__}")
        values = {}
        for name, aliases in PARAMETER_NAMES.items():
            given = [key for key in (name, *aliases) if key in parameter_map]
            if not given:
                raise SensorInputError(f"sensor parameter_map lacks '{name}' (accepted spellings: {name}, {aliases})")
            if len(given) > 1:
                raise SensorInputError(f"sensor parameter_map gives '{name}' more than once: {given}")
            values[name] = positive(parameter_map[given[0]], f"sensor parameter '{given[0]}'")
        self.parameters = dict(parameter_map)
        self.optimal_standoff = values["optimal_standoff_mm"]
        self.minimum_standoff = values["minimum_standoff_mm"]
        self.maximum_standoff = values["maximum_standoff_mm"]
        self.theta_max = values["theta_max_rad"]
        self.psi_max = values["psi_max_rad"]
        self.K_u = values["K_u"]
        self.alpha = values["alpha_rad"]
        self.fan_angle = values["fan_angle_rad"]
        if not self.minimum_standoff < self.optimal_standoff < self.maximum_standoff:
            raise SensorInputError("sensor parameters need minimum_standoff < optimal_standoff < maximum_standoff")
        for name in ("theta_max", "psi_max", "alpha"):
            if getattr(self, name) >= math.pi / 2:
                raise SensorInputError(f"sensor parameter {name} must be below pi/2 rad")
        if self.fan_angle >= math.pi:
            raise SensorInputError("sensor parameter fan_angle must be below pi rad")
        if not occlusion_tolerance_mm >= 0.0:
            raise SensorInputError("occlusion_tolerance_mm must be >= 0")
        self.occlusion_tolerance = float(occlusion_tolerance_mm)
        self.xi_0 = math.sin(self.alpha) * self.optimal_standoff
        #: Distance emitter -> detector in mm; the detector sits at ``e - distance * x``.
        self.laser_emission_perception_distance = math.tan(self.alpha) * self.optimal_standoff
        self._tan_half_fan = math.tan(self.fan_angle / 2.0)
        self._context: _Context | None = None

    @classmethod
    def from_config(cls, path=None, **kwargs) -> SensorModel:
        """Build from ``config/laser_scanner.yaml`` (or the scanner file at ``path``)."""
        return cls(load_scanner_config(path).sensor_parameters, **kwargs)

    # --------------------------------------------------------------------------------------- equations
    def _u(self, z, psi):
        root = np.sqrt(z * z + self.xi_0**2 - 2.0 * z * self.xi_0 * math.sin(self.alpha))
        return self.K_u * root / np.cos(psi) * z

    def evaluate_uncertainty(self, z, psi):
        """Uncertainty ``u(z, psi)`` in mm of a point at depth ``z`` (mm, laser_emitter_frame) and angle ``psi``
        (rad). NaN where ``z`` lies outside [minimum, maximum standoff] or ``|psi|`` exceeds ``psi_max``.
        Accepts scalars (returns a float) or arrays (broadcast)."""
        z_arr = np.asarray(z, dtype=float)
        psi_arr = np.asarray(psi, dtype=float)
        with np.errstate(invalid="ignore"):
            valid = (
                (z_arr >= self.minimum_standoff) & (z_arr <= self.maximum_standoff) & (np.abs(psi_arr) <= self.psi_max)
            )
            result = np.where(valid, self._u(z_arr, psi_arr), np.nan)
        return float(result) if result.ndim == 0 else result

    def evaluate_score(self, z, psi):
        """Score in [0, 1] (1 = lowest possible uncertainty, 0 = at the rejection limits):
        ``(u_max - u(z, psi)) / (u_max - u_min)``; ``z`` in mm, ``psi`` in rad. NaN where invalid."""
        u_min, u_max = self.get_min_uncertainty(), self.get_max_uncertainty()
        result = (u_max - np.asarray(self.evaluate_uncertainty(z, psi))) / (u_max - u_min)
        return float(result) if np.ndim(result) == 0 else result

    def get_min_uncertainty(self) -> float:
        """Best-case uncertainty in mm: ``u(minimum_standoff, 0)``."""
        return float(self._u(self.minimum_standoff, 0.0))

    def get_max_uncertainty(self) -> float:
        """Worst uncertainty in mm of a point that is not rejected: ``u(maximum_standoff, psi_max)``."""
        return float(self._u(self.maximum_standoff, self.psi_max))

    def get_optimal_standoff(self) -> float:
        """The configured optimal standoff in mm: the z at which viewpoints are placed above their sample.

        The original documents it as the centre between the z-limits; its parameters (181.82 between 127.27
        and 227.27) do not quite match that, and the configured value is what ``xi_0`` uses, so it is returned
        as configured.
        """
        return self.optimal_standoff

    def get_median_deviation_angle(self) -> float:
        """Tilt step in rad: ``min(theta_max, psi_max) / 2``."""
        return min(self.theta_max, self.psi_max) / 2.0

    def get_scanning_frustum(self, half_length: float) -> trimesh.Trimesh:
        """The 'frustum of measurability' (a cut-off Toblerone) in the laser_emitter_frame, mm.

        The fan (full angle ``fan_angle``) in the y-z plane between minimum and maximum standoff, extruded
        ``+-half_length`` mm along x (the trajectory direction).
        """
        half_length = float(half_length)
        if not math.isfinite(half_length) or half_length <= 0.0:
            raise SensorInputError(f"half_length must be a positive number of mm, got {half_length}")
        corners = []
        for x in (-half_length, half_length):
            for z in (self.minimum_standoff, self.maximum_standoff):
                half_width = z * self._tan_half_fan
                corners += [(x, -half_width, z), (x, half_width, z)]
        return trimesh.convex.convex_hull(np.array(corners))

    # ---------------------------------------------------------------------------------------- context
    def set_processing_context(
        self,
        mesh: trimesh.Trimesh,
        sampled_surface_points,
        sampled_face_indices,
        *,
        cull_supporting_faces: bool = True,
    ) -> None:
        """Load the occluding mesh (mm) into the ray tracer and remember the samples to evaluate.

        ``sampled_surface_points``: (P, 3) mm; ``sampled_face_indices``: (P,) face of ``mesh`` each sample
        lies on (its normal is the face normal). Replaces any previous context.

        ``cull_supporting_faces``: no rays are cast for samples on faces whose plane supports the whole mesh
        (the mesh lies behind it, e.g. every face of a convex part): seen from the front, nothing can occlude
        them, so the result is the same. ``False`` casts rays for every pair (for comparisons).
        """
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise SensorInputError("set_processing_context needs a trimesh.Trimesh with faces")
        points = np.asarray(sampled_surface_points, dtype=float).reshape(-1, 3)
        face_ids = np.asarray(sampled_face_indices).reshape(-1)
        if face_ids.shape[0] != points.shape[0]:
            raise SensorInputError(
                f"{points.shape[0]} sample points but {face_ids.shape[0]} face indices: they must match"
            )
        if not np.all(np.isfinite(points)):
            raise SensorInputError("sample points must be finite")
        if face_ids.size and (
            not np.issubdtype(face_ids.dtype, np.integer) or face_ids.min() < 0 or face_ids.max() >= len(mesh.faces)
        ):
            raise SensorInputError(f"face indices must be integers in [0, {len(mesh.faces)})")
        face_ids = face_ids.astype(np.int64)
        normals = np.asarray(mesh.face_normals, dtype=float)[face_ids]
        if cull_supporting_faces:
            unique = np.unique(face_ids)
            unoccludable = supporting_faces(mesh, faces=unique)[np.searchsorted(unique, face_ids)]
        else:
            unoccludable = np.zeros(face_ids.shape, dtype=bool)
        self._context = _Context(
            mesh=mesh,
            points=points,
            face_ids=face_ids,
            normals=normals,
            point_data=np.ascontiguousarray(np.concatenate([points, normals], axis=1).T),
            caster=RayCaster(mesh),
            unoccludable=unoccludable,
            center=points.mean(axis=0) if len(points) else np.zeros(3),
            cells=build_cells(points, mesh.area) if len(points) >= CELL_CULL_POINTS else None,
        )

    def __getstate__(self):
        # the ray tracer's scene lives in native memory: a copy (e.g. on a Dask worker) builds its own
        state = dict(self.__dict__)
        if self._context is not None:
            state["_context"] = dataclasses.replace(self._context, caster=None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self._context is not None and self._context.caster is None:
            self._context = dataclasses.replace(self._context, caster=RayCaster(self._context.mesh))

    @property
    def sampled_surface_points(self) -> np.ndarray:
        return self._require_context().points

    def _require_context(self) -> _Context:
        if self._context is None:
            raise ProcessingContextError("call set_processing_context(mesh, points, face_ids) first")
        return self._context

    # ------------------------------------------------------------------------------------- evaluation
    def process_viewpoint_metrologically(
        self, viewpoint, uncertainty_threshold: float, maximum_deflection: float = 500.0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measurable samples of one viewpoint's straight trajectory.

        ``viewpoint``: a :class:`~agiprobot_measurement.planning.candidates.viewpoint.ViewPoint` (or a 4x4 anchor pose of the
        laser_emitter_frame, mm). ``uncertainty_threshold``: largest permissible assigned uncertainty in mm.
        ``maximum_deflection``: how far (mm) the emitter may travel from the anchor in each direction.

        Returns (indices into the context's samples, their uncertainties in mm, their ``t0`` in mm), the same
        as column 0 of :meth:`evaluate_viewpoints_batch` for this single pose.
        """
        if hasattr(viewpoint, "get_anchor_pose"):
            pose = viewpoint.get_anchor_pose()
        else:
            pose = np.asarray(viewpoint, dtype=float)
        result = self.evaluate_viewpoints_batch(
            np.asarray(pose, dtype=float).reshape(1, 4, 4), uncertainty_threshold, maximum_deflection
        )
        return result.view(0)

    def evaluate_viewpoints_batch(
        self,
        anchor_poses,
        uncertainty_threshold: float,
        maximum_deflection: float = 500.0,
        *,
        chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
        workers: int | None = None,
        progress: Callable[[int, int], None] | None = None,
        spatial_cull: bool | None = None,
    ) -> MeasurabilityResult:
        """Metrological evaluation of many viewpoints against the processing context.

        ``anchor_poses``: (V, 4, 4) poses of the laser_emitter_frame at the anchors (rotation columns x, y, z;
        translation in mm). ``uncertainty_threshold`` and ``maximum_deflection`` in mm as in
        :meth:`process_viewpoint_metrologically`. ``chunk_elements`` bounds the size of the dense work arrays
        (views per chunk = chunk_elements // points), so memory grows with the result, not with V x P.
        ``workers``: threads evaluating chunks concurrently (default: the CPU count, at most 4); the result
        does not depend on it. ``progress(done_views, total_views)`` is called after each chunk, in order.
        ``spatial_cull``: take each view's candidate points from the sample cells its frustum reaches (default:
        from :data:`CELL_CULL_POINTS` samples on); the result is the same either way.
        """
        if workers is None:
            workers = min(4, os.cpu_count() or 1)
        ctx = self._require_context()
        poses = np.asarray(anchor_poses, dtype=float)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise SensorInputError(f"anchor_poses must have shape (V, 4, 4), got {poses.shape}")
        if not np.all(np.isfinite(poses)):
            raise SensorInputError("anchor_poses must be finite")
        rotations = poses[:, :3, :3]
        gram = np.einsum("vji,vjk->vik", rotations, rotations)
        if poses.shape[0] and (np.abs(gram - np.eye(3)).max() > 1e-6 or np.linalg.det(rotations).min() < 0.0):
            raise SensorInputError("anchor_poses must be rigid: rotation blocks orthonormal with det +1")
        threshold = float(uncertainty_threshold)
        deflection = float(maximum_deflection)
        if not threshold > 0.0:
            raise SensorInputError(f"uncertainty_threshold must be a positive number of mm, got {threshold}")
        if not deflection >= 0.0:
            raise SensorInputError(f"maximum_deflection must be >= 0 mm, got {deflection}")
        n_views, n_points = poses.shape[0], ctx.points.shape[0]
        if n_views == 0 or n_points == 0:
            return MeasurabilityResult(
                n_points,
                n_views,
                np.zeros(n_views + 1, dtype=np.int64),
                np.zeros(0, dtype=np.int32),
                np.zeros(0),
                np.zeros(0),
            )

        # float32 copies for the dense prefilter; the centring keeps their rounding at the part's scale
        pts32 = np.ascontiguousarray((ctx.points - ctx.center).T, dtype=np.float32)
        nrm32 = np.ascontiguousarray(ctx.normals.T, dtype=np.float32)
        span = (
            float(np.abs(ctx.points - ctx.center).max())
            + float(np.abs(poses[:, :3, 3] - ctx.center).max())
            + deflection
            + self.maximum_standoff
        )
        # margins make the float32 prefilter a superset of the exact float64 tests
        pos_margin = np.float32(1e-5 * span + 1e-3)
        ang_margin = np.float32(1e-5)

        cells = ctx.cells if spatial_cull is not False else None
        if spatial_cull and cells is None:
            cells = build_cells(ctx.points, ctx.mesh.area)
        per_chunk = max(1, int(chunk_elements) // (n_points if cells is None else len(cells.radius)))

        def process(start: int):
            chunk = poses[start : start + per_chunk]
            view_data = np.concatenate([chunk[:, :3, :3].transpose(0, 2, 1).reshape(-1, 9), chunk[:, :3, 3]], 1)
            view_data = np.ascontiguousarray(view_data.T)
            if cells is None:
                vi, pi = self._prefilter(chunk, ctx, pts32, nrm32, deflection, pos_margin, ang_margin)
                keep, u, t0 = self._evaluate_pairs(view_data, ctx, vi, pi, threshold, deflection)
                counts = np.bincount(vi[keep], minlength=chunk.shape[0])
                return counts, pi[keep].astype(np.int32), u, t0
            parts = [
                (*self._evaluate_pairs(view_data, ctx, vi, pi, threshold, deflection), vi, pi)
                for vi, pi in self._cell_pairs(chunk, view_data, ctx, cells, deflection, int(chunk_elements))
            ]
            if not parts:
                return np.zeros(chunk.shape[0], dtype=np.int64), np.zeros(0, dtype=np.int32), np.zeros(0), np.zeros(0)
            vi = np.concatenate([vi[keep] for keep, _, _, vi, _ in parts])
            pi = np.concatenate([pi[keep] for keep, _, _, _, pi in parts])
            u = np.concatenate([part[1] for part in parts])
            t0 = np.concatenate([part[2] for part in parts])
            # the cells interleave the points: back to view-major, points ascending (the dense test's order)
            order = np.argsort(vi * np.int64(n_points) + pi, kind="stable")
            counts = np.bincount(vi, minlength=chunk.shape[0])
            return counts, pi[order].astype(np.int32), u[order], t0[order]

        starts = range(0, n_views, per_chunk)
        workers = max(1, min(int(workers), len(starts)))
        parts = []
        with ThreadPoolExecutor(workers) if workers > 1 else nullcontext() as pool:
            # numpy and Embree release the GIL for the bulk of a chunk, so threads overlap usefully
            results = map(process, starts) if pool is None else pool.map(process, starts)
            for start, part in zip(starts, results, strict=True):
                parts.append(part)
                if progress is not None:
                    progress(min(start + per_chunk, n_views), n_views)
        indptr = np.zeros(n_views + 1, dtype=np.int64)
        np.cumsum(np.concatenate([part[0] for part in parts]), out=indptr[1:])
        # one column of the chunk results at a time, each freed once merged: the peak stays near the result
        merged = []
        for column in (1, 2, 3):
            merged.append(np.concatenate([part[column] for part in parts]))
            for index, part in enumerate(parts):
                parts[index] = tuple(None if c == column else value for c, value in enumerate(part))
        return MeasurabilityResult(n_points, n_views, indptr, *merged)

    def _prefilter(self, poses, ctx, pts32, nrm32, deflection, pos_margin, ang_margin):
        """Candidate (view, point) pairs of a chunk: a float32 superset of the frustum and psi limits.

        Returns view indices (relative to the chunk) and point indices, view-major and points ascending.
        """
        count, n_points = poses.shape[0], pts32.shape[1]
        rot = poses[:, :3, :3]
        # rows t, l, s of each view stacked: one product serves all three axes. einsum, because BLAS is
        # an order of magnitude slower than numpy's own loop for an inner dimension of 3.
        axes32 = np.ascontiguousarray(rot.transpose(0, 2, 1)).reshape(-1, 3).astype(np.float32)
        offsets = np.einsum("vij,vi->vj", rot, poses[:, :3, 3] - ctx.center).astype(np.float32)

        normal_proj = np.einsum("ij,jk->ik", axes32, nrm32).reshape(count, 3, n_points)  # n.t, n.l, n.s
        # |psi| < psi_max  <=>  |n.t| < tan(psi_max) * (-n.s)  (which also demands -n.s > 0)
        limit = normal_proj[:, 2] * np.float32(-math.tan(self.psi_max))
        limit += ang_margin
        mask = np.abs(normal_proj[:, 0]) < limit

        local = np.einsum("ij,jk->ik", axes32, pts32).reshape(count, 3, n_points)
        local -= offsets[:, :, None]
        qx, qy, qz = local[:, 0], local[:, 1], local[:, 2]
        mask &= qz > np.float32(self.minimum_standoff) - pos_margin
        mask &= qz < np.float32(self.maximum_standoff) + pos_margin
        half_width = qz * np.float32(self._tan_half_fan)
        half_width += pos_margin
        mask &= np.abs(qy) <= half_width
        mask &= np.abs(qx) <= np.float32(deflection) + pos_margin
        return np.divmod(np.flatnonzero(mask), n_points)

    def _cell_pairs(self, poses, view_data, ctx, cells, deflection, max_pairs):
        """Candidate (view, point) pairs of a chunk from the cells each view's frustum may reach, in groups of
        at most ``max_pairs``: a superset of the exact tests (conservative for a cell's bounding sphere, then the
        frustum and psi limits per pair with small margins). Yields (view indices, point indices).

        One compiled pass (:func:`cull_pairs`): the dense (view x cell) and (view x pair) temporaries of an
        array formulation made the evaluation memory-bound, so two workers on one machine slowed each other."""
        del view_data  # the kernel reads the poses directly
        margin = 1e-6 * (self.maximum_standoff + deflection) + 1e-6
        vi, pi = cull_pairs(
            np.ascontiguousarray(poses[:, :3, :3]), np.ascontiguousarray(poses[:, :3, 3]), cells.center,
            cells.radius + (1e-6 * (self.maximum_standoff + deflection) + 1e-3), cells.start, cells.order,
            ctx.point_data, float(self.minimum_standoff), float(self.maximum_standoff), float(self._tan_half_fan),
            float(deflection), math.tan(self.psi_max), margin,
        )  # fmt: skip
        for at in range(0, vi.size, max(int(max_pairs), 1)):
            yield vi[at : at + max_pairs], pi[at : at + max_pairs]

    def _evaluate_pairs(self, view_data, ctx, vi, pi, threshold, deflection):
        """Exact float64 tests and ray casts of candidate pairs. Returns (keep mask, u, t0) of the kept.

        ``view_data`` (12, Vc): rows t, l, s (3 each) and the anchor; gathered as rows so that every
        quantity below is a contiguous 1-D array.
        """
        tx, ty, tz, lx, ly, lz, sx, sy, sz, ax, ay, az = np.take(view_data, vi, axis=1)
        px, py, pz, nx, ny, nz = np.take(ctx.point_data, pi, axis=1)
        dx, dy, dz = px - ax, py - ay, pz - az
        qx = dx * tx + dy * ty + dz * tz
        qy = dx * lx + dy * ly + dz * lz
        qz = dx * sx + dy * sy + dz * sz
        nt = nx * tx + ny * ty + nz * tz
        nl = nx * lx + ny * ly + nz * lz
        ns = nx * sx + ny * sy + nz * sz

        psi = np.arctan2(nt, -ns)
        facing = qy * nl + qz * ns  # (p - e) . n
        with np.errstate(invalid="ignore", divide="ignore"):
            theta = np.arccos(np.clip(-facing / (np.hypot(qy, qz) * np.hypot(nl, ns)), -1.0, 1.0))
        baseline = self.laser_emission_perception_distance
        keep = np.abs(qx) <= deflection
        keep &= qz > self.minimum_standoff
        keep &= qz < self.maximum_standoff
        keep &= np.abs(qy) <= qz * self._tan_half_fan
        keep &= np.abs(psi) < self.psi_max
        keep &= theta < self.theta_max
        # the emitter must see the front of the face (implied by theta < pi/2, stated for clarity), and so
        # must the detector, which sits laser_emission_perception_distance behind the emitter along -x
        keep &= facing < 0.0
        keep &= facing + baseline * nt < 0.0
        u = self._u(qz, psi) * np.abs(ns)
        keep &= u <= threshold

        # points on faces whose plane supports the whole mesh cannot be occluded from their front side
        idx = np.flatnonzero(keep)
        idx = idx[~ctx.unoccludable[pi[idx]]]
        if idx.size:
            p = np.stack([px[idx], py[idx], pz[idx]], axis=1)
            t_ax = np.stack([tx[idx], ty[idx], tz[idx]], axis=1)
            # emitter ray: from e = anchor + t0 * t to p, i.e. along qy * l + qz * s
            ray = qy[idx, None] * np.stack([lx[idx], ly[idx], lz[idx]], axis=1)
            ray += qz[idx, None] * np.stack([sx[idx], sy[idx], sz[idx]], axis=1)
            blocked = self._blocked(ctx, p, ray)
            # detector ray: from e - baseline * t to p
            ray += baseline * t_ax
            blocked[~blocked] = self._blocked(ctx, p[~blocked], ray[~blocked])
            keep[idx[blocked]] = False
        return keep, u[keep], qx[keep]

    def _blocked(self, ctx, points, rays):
        """Occlusion of the segments ``points - rays -> points`` (minus the tolerance at the point)."""
        length = np.sqrt(_dot3(rays, rays))
        return ctx.caster.occluded(points - rays, rays / length[:, None], length - self.occlusion_tolerance)
