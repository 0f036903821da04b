"""Viewpoints: one straight measurement trajectory of the laser_emitter_frame and what it measures.

Construction (lengths in mm, angles in rad): for a surface point ``p`` with unit normal ``n`` the untilted
boresight is ``s0 = -n``. The reference trajectory direction ``x0`` is the world x axis projected onto the
plane normal to ``s0`` (the world y axis when ``s0`` is parallel to world x), ``y0 = s0 x x0``. The
orientation of the laser_emitter_frame is

    R = [x0 y0 s0] @ Rz(angle_around_boresight) @ Rx(tilt_theta) @ Ry(tilt_psi)

so ``tilt_psi`` is exactly the ``psi`` of ``p`` seen from the anchor and ``tilt_theta`` tilts the boresight
within the laser fan (it equals ``theta`` when ``tilt_psi`` is 0). The anchor is ``p - standoff * z`` (z the
boresight of ``R``): the boresight always passes through ``p``.

:func:`generate_viewpoint_poses` builds the anchor poses of all candidates at once, ordered sample-major,
then orientation, then tilt. Tilt indices (see :data:`TILT_STEPS`) are ordered for the 'limited' mode: index 0
is the optimal (untilted) pose, 1-4 single-axis deviations, 5-8 combined ones; 'limited' tries them in this
order and keeps the first that is valid (:func:`select_limited_tilt`).
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np

from agiprobot_measurement.common import config
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.errors import PlanningInputError, PlanningTypeError, validated

__all__ = [
    "TILT_MODES",
    "TILT_STEPS",
    "ViewPoint",
    "ViewpointCandidates",
    "anchor_poses",
    "base_frames",
    "build_viewpoints",
    "generate_viewpoint_poses",
    "orientation_angles",
    "reverse_trajectory",
    "select_limited_tilt",
    "tilt_angles",
]

#: Tilt modes of ``generate_samples_and_viewpoints(viewpoint_tilt_mode=...)``.
TILT_MODES = ("none", "limited", "full")

#: (theta, psi) deviations in units of the sensor's median deviation angle, in the order 'limited' tries.
TILT_STEPS = np.array([(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)], dtype=float)


class ViewpointCandidates(NamedTuple):
    """Anchor poses of candidate viewpoints and where they come from (unpacks as a 4-tuple)."""

    poses: np.ndarray  # (V, 4, 4) laser_emitter_frame at the anchor, mm
    sample_index: np.ndarray  # (V,) index of the surface point the view is built on
    orientation_index: np.ndarray  # (V,) k: angle around the boresight 2*pi*k/K
    tilt_index: np.ndarray  # (V,) row of TILT_STEPS


def orientation_angles(orientations_around_boresight: int) -> np.ndarray:
    """Angles (rad) around the boresight for ``K`` orientations: ``2*pi*k/K``.

    The full circle, because a trajectory and its opposite direction put the detector (behind the emitter
    along -x) on opposite sides, which changes what is occluded.
    """
    message = f"orientations_around_boresight must be a positive integer, got {orientations_around_boresight}"
    check = lambda: config.whole(orientations_around_boresight, "orientations_around_boresight", low=1)  # noqa: E731
    count = validated(check, PlanningInputError, message)
    return 2.0 * np.pi * np.arange(count) / count


def tilt_angles(tilt_mode: str, sensor_model) -> np.ndarray:
    """(T, 2) tilt angles (theta, psi) in rad of a tilt mode: 1 row for 'none', 9 for 'limited'/'full'."""
    if tilt_mode not in TILT_MODES:
        raise PlanningInputError(f"unknown viewpoint tilt mode {tilt_mode!r}; valid modes: {', '.join(TILT_MODES)}")
    if tilt_mode == "none":
        return np.zeros((1, 2))
    return TILT_STEPS * sensor_model.get_median_deviation_angle()


def _unit_rows(vectors: np.ndarray, what: str) -> np.ndarray:
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    if not np.all(np.isfinite(vectors)) or np.any(norm < 1e-12):
        raise PlanningInputError(f"{what} must be finite and non-zero")
    return vectors / norm


def base_frames(normals: np.ndarray) -> np.ndarray:
    """(P, 3, 3) untilted frames ``[x0 y0 s0]`` (columns) for unit normals (P, 3); ``s0 = -n``."""
    s0 = -_unit_rows(np.asarray(normals, dtype=float).reshape(-1, 3), "surface normals")
    ref = np.zeros_like(s0)
    # world x as reference; world y where the boresight is (nearly) parallel to world x
    parallel = np.abs(s0[:, 0]) > 1.0 - 1e-9
    ref[~parallel, 0] = 1.0
    ref[parallel, 1] = 1.0
    x0 = ref - np.sum(ref * s0, axis=1, keepdims=True) * s0
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    y0 = np.cross(s0, x0)
    return np.stack([x0, y0, s0], axis=2)


def _rot(axis: int, angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    out = np.zeros((*np.shape(angles), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def anchor_poses(points, normals, angles, tilts, standoff: float) -> np.ndarray:
    """(P, K, T, 4, 4) anchor poses for P points/normals, K angles around the boresight and T (theta, psi)
    tilts, the anchor ``standoff`` mm from the point along the boresight."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    frames = base_frames(normals)
    if frames.shape[0] != points.shape[0]:
        raise PlanningInputError(f"{points.shape[0]} points but {frames.shape[0]} normals")
    if not np.all(np.isfinite(points)):
        raise PlanningInputError("surface points must be finite")
    angles = np.asarray(angles, dtype=float).reshape(-1)
    tilts = np.asarray(tilts, dtype=float).reshape(-1, 2)
    local = _rot(2, angles)[:, None] @ _rot(0, tilts[:, 0]) @ _rot(1, tilts[:, 1])  # (K, T, 3, 3)
    rot = np.einsum("pij,ktjl->pktil", frames, local)
    poses = np.zeros((*rot.shape[:3], 4, 4))
    poses[..., :3, :3] = rot
    poses[..., :3, 3] = points[:, None, None, :] - float(standoff) * rot[..., :, 2]
    poses[..., 3, 3] = 1.0
    return poses


def generate_viewpoint_poses(
    points, normals, orientations_around_boresight: int, tilt_mode: str, sensor_model
) -> ViewpointCandidates:
    """Anchor poses of every candidate viewpoint, vectorised.

    ``points`` (P, 3) mm and unit ``normals`` (P, 3); ``orientations_around_boresight`` K; ``tilt_mode`` one
    of :data:`TILT_MODES` ('none': 1 pose per orientation; 'limited' and 'full': the 9 of :data:`TILT_STEPS`,
    0 and +-median deviation angle on theta and psi; for 'limited' the caller evaluates tilt index 0 first and
    the deviations only where it failed, see :func:`select_limited_tilt`). The anchor lies at the sensor's
    optimal standoff. Returns ``(poses (V, 4, 4), sample_index, orientation_index, tilt_index)`` with
    ``V = P * K * T``, ordered sample-major, then orientation, then tilt.
    """
    tilts = tilt_angles(tilt_mode, sensor_model)
    angles = orientation_angles(orientations_around_boresight)
    poses = anchor_poses(points, normals, angles, tilts, sensor_model.get_optimal_standoff())
    n_points, n_angles, n_tilts = poses.shape[:3]
    sample, orientation, tilt = np.meshgrid(np.arange(n_points), np.arange(n_angles), np.arange(n_tilts), indexing="ij")
    return ViewpointCandidates(poses.reshape(-1, 4, 4), sample.reshape(-1), orientation.reshape(-1), tilt.reshape(-1))


def select_limited_tilt(valid, sample_index, orientation_index, tilt_index) -> np.ndarray:
    """Boolean mask of the candidates the 'limited' tilt mode keeps.

    Per (sample, orientation): the untilted candidate (tilt index 0) if it is valid, otherwise the valid one
    with the lowest tilt index, otherwise none. ``valid`` is a boolean per candidate from whatever stage the
    caller has reached (metrology, reachability, ...).
    """
    valid = np.asarray(valid, dtype=bool)
    sample_index = np.asarray(sample_index)
    orientation_index = np.asarray(orientation_index)
    tilt_index = np.asarray(tilt_index)
    keep = np.zeros(valid.shape, dtype=bool)
    candidates = np.flatnonzero(valid)
    if candidates.size == 0:
        return keep
    n_orient = int(orientation_index.max()) + 1
    group = sample_index[candidates].astype(np.int64) * n_orient + orientation_index[candidates]
    order = np.lexsort((tilt_index[candidates], group))
    first = np.ones(order.size, dtype=bool)
    first[1:] = group[order][1:] != group[order][:-1]
    keep[candidates[order[first]]] = True
    return keep


def reverse_trajectory(trajectory):
    """The same joint trajectory run backwards in the same time (start and end swapped).

    Accepts a :class:`~agiprobot_measurement.motion.trajectory.JointTrajectory` or a ``moveit_msgs/RobotTrajectory``
    (or ``trajectory_msgs/JointTrajectory``) message; velocities change sign, accelerations do not.
    """
    if trajectory is None:
        return None
    if isinstance(trajectory, JointTrajectory):
        times = trajectory.time_from_start
        return JointTrajectory(
            trajectory.joint_names,
            (times[-1] - times[::-1]) if len(times) else times,
            trajectory.positions[::-1],
            None if trajectory.velocities is None else -trajectory.velocities[::-1],
            None if trajectory.accelerations is None else trajectory.accelerations[::-1],
            trajectory.frame_id,
        )
    msg = copy.deepcopy(trajectory)
    joint_trajectory = getattr(msg, "joint_trajectory", msg)
    points = getattr(joint_trajectory, "points", None)
    if points is None:
        raise PlanningTypeError(f"cannot reverse a {type(trajectory).__name__}: expected a JointTrajectory")
    if points:
        total = points[-1].time_from_start
        originals = [p.time_from_start for p in points]
        points.reverse()
        for point, stamp in zip(points, reversed(originals), strict=True):
            point.time_from_start = total - stamp
            point.velocities = [-v for v in point.velocities]
    return msg


_NO_INDICES = np.zeros(0, dtype=np.int64)
_NO_INDICES.flags.writeable = False
_NO_VALUES = np.zeros(0)
_NO_VALUES.flags.writeable = False


class ViewPoint:
    """One viewpoint: the geometry of a straight measurement trajectory plus its metrological and
    kinematic results.

    ``surface_point`` (3,) mm and ``surface_normal`` (3,) of the sample the view is built on;
    ``angle_around_boresight`` rad; ``standoff_distance`` mm from the surface point to the anchor along the
    boresight; ``tilt_theta`` and ``tilt_psi`` rad (see the module docstring).
    """

    # Planning state the TrajectoryManager keeps per view. Class-level defaults: the batch path builds
    # hundreds of thousands of views and sets these only for the few it verifies.
    #: column of the view in its generation's coverage store, None for a view built elsewhere
    coverage_column: int | None = None
    #: True once the scan line was checked mechanically, False while pending, None for a view built elsewhere
    mechanics_verified: bool | None = None
    #: False when the mechanical check rejected the view
    mechanics_valid: bool = True
    #: estimated (before verification) or exact duration of the measurement trajectory, s
    estimated_duration_s: float | None = None
    #: the tip speed of the measurement trajectory, mm/s (set by the mechanical check)
    scan_speed_mm_s: float | None = None

    def __init__(
        self,
        surface_point,
        surface_normal,
        angle_around_boresight: float,
        standoff_distance: float,
        tilt_theta: float = 0,
        tilt_psi: float = 0,
    ):
        message = f"standoff_distance must be a positive number of mm, got {standoff_distance}"
        standoff_distance = validated(
            lambda: config.positive(standoff_distance, "standoff"), PlanningInputError, message
        )
        for name, value in (
            ("angle_around_boresight", angle_around_boresight),
            ("tilt_theta", tilt_theta),
            ("tilt_psi", tilt_psi),
        ):
            validated(lambda: config.number(value, name), PlanningInputError, f"{name} must be finite, got {value}")  # noqa: B023
        self._surface_point = np.asarray(surface_point, dtype=float).reshape(3)
        self._surface_normal = _unit_rows(np.asarray(surface_normal, dtype=float).reshape(1, 3), "surface_normal")[0]
        self.angle_around_boresight = float(angle_around_boresight)
        self.standoff_distance = standoff_distance
        self.tilt_theta = float(tilt_theta)
        self.tilt_psi = float(tilt_psi)
        self._anchor_pose = anchor_poses(
            self._surface_point[None],
            self._surface_normal[None],
            [self.angle_around_boresight],
            [(self.tilt_theta, self.tilt_psi)],
            standoff_distance,
        )[0, 0, 0]
        self._measurable_indices = np.zeros(0, dtype=np.int64)
        self._uncertainties = np.zeros(0)
        self._trajectory_distances = np.zeros(0)
        self._trajectory_for_measurement = None
        self._trajectory_to_view = None
        #: (start, end) of the measurement line as distances (mm) from the anchor along the frame's x axis.
        self.scan_line: tuple[float, float] | None = None
        self.reversed = False
        #: free-form provenance (sample / orientation / tilt index) set by whoever builds the view
        self.metadata: dict = {}

    @classmethod
    def from_anchor_pose(
        cls,
        surface_point: np.ndarray,
        surface_normal: np.ndarray,
        angle_around_boresight: float,
        standoff_distance: float,
        tilt_theta: float,
        tilt_psi: float,
        anchor_pose: np.ndarray,
    ) -> ViewPoint:
        """A view whose anchor pose was already computed by :func:`anchor_poses` for exactly these values
        (the batch path: skips recomputing the pose and re-validating the inputs)."""
        view = cls.__new__(cls)
        view._surface_point = surface_point
        view._surface_normal = surface_normal
        view.angle_around_boresight = float(angle_around_boresight)
        view.standoff_distance = float(standoff_distance)
        view.tilt_theta = float(tilt_theta)
        view.tilt_psi = float(tilt_psi)
        view._anchor_pose = anchor_pose
        # shared empty arrays (never written): a batch builds hundreds of thousands of views
        view._measurable_indices = _NO_INDICES
        view._uncertainties = _NO_VALUES
        view._trajectory_distances = _NO_VALUES
        view._trajectory_for_measurement = None
        view._trajectory_to_view = None
        view.scan_line = None
        view.reversed = False
        view.metadata = {}
        return view

    def attach_measurements(self, indices: np.ndarray, uncertainties: np.ndarray, trajectory_distances) -> None:
        """Like :meth:`set_measurable_surface_point_indices_and_uncertainties` without copying or checking:
        for arrays (e.g. slices of a batch result) the caller guarantees to be consistent."""
        self._measurable_indices = indices
        self._uncertainties = uncertainties
        self._trajectory_distances = trajectory_distances

    # ------------------------------------------------------------------------------------ geometry
    def get_anchor_pose(self) -> np.ndarray:
        """4x4 pose (mm) of the laser_emitter_frame at the anchor."""
        return self._anchor_pose.copy()

    def get_anchor_position(self, as_matrix: bool = False) -> np.ndarray:
        """The anchor position (mm): the laser_emitter_frame position whose z axis hits the surface point.

        ``as_matrix``: a homogeneous 4x4 translation matrix instead of the (3,) vector.
        """
        return self._position(self._anchor_pose[:3, 3], as_matrix)

    def get_surface_point(self, as_matrix: bool = False) -> np.ndarray:
        """The surface point (mm) the view is built on, as (3,) vector or 4x4 translation matrix."""
        return self._position(self._surface_point, as_matrix)

    def get_surface_normal(self) -> np.ndarray:
        """The unit surface normal (3,) at the view's surface point (a copy)."""
        return self._surface_normal.copy()

    def get_orientation_matrix(self) -> np.ndarray:
        """3x3 orientation of the laser_emitter_frame (constant along the measurement trajectory)."""
        return self._anchor_pose[:3, :3].copy()

    @staticmethod
    def _position(vector: np.ndarray, as_matrix: bool) -> np.ndarray:
        if not as_matrix:
            return vector.copy()
        matrix = np.eye(4)
        matrix[:3, 3] = vector
        return matrix

    def get_scan_line_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """4x4 start and end poses (mm) of the laser_emitter_frame on the measurement line, in execution
        order. Requires :attr:`scan_line` to be set."""
        if self.scan_line is None:
            raise PlanningInputError("the scan line of this viewpoint has not been set")
        poses = []
        for distance in self.scan_line:
            pose = self._anchor_pose.copy()
            pose[:3, 3] += distance * pose[:3, 0]
            poses.append(pose)
        return poses[0], poses[1]

    # --------------------------------------------------------------------------------- metrology
    def set_measurable_surface_point_indices_and_uncertainties(
        self, measurable_point_indices, uncertainties, trajectory_distances=None
    ) -> None:
        """Indices of the measurable surface points (into an external list), their uncertainties (mm) and,
        optionally, where along the trajectory (t0, mm from the anchor along x) each is measured."""
        indices = np.asarray(measurable_point_indices, dtype=np.int64).reshape(-1)
        values = np.asarray(uncertainties, dtype=float).reshape(-1)
        if indices.shape != values.shape:
            raise PlanningInputError(
                f"{indices.size} indices but {values.size} uncertainties: both lists must have the same length"
            )
        if trajectory_distances is None:
            distances = np.full(indices.shape, np.nan)
        else:
            distances = np.asarray(trajectory_distances, dtype=float).reshape(-1)
            if distances.shape != indices.shape:
                raise PlanningInputError("trajectory_distances must have the same length as the indices")
        self._measurable_indices = indices
        self._uncertainties = values
        self._trajectory_distances = distances

    @property
    def measurable_indices(self) -> np.ndarray:
        """The measurable surface-point indices as a read-only int64 array (no list copy: for batch work)."""
        view = self._measurable_indices.view()
        view.flags.writeable = False
        return view

    @property
    def measurable_uncertainties(self) -> np.ndarray:
        """The uncertainties (mm) of :attr:`measurable_indices`, read-only."""
        view = self._uncertainties.view()
        view.flags.writeable = False
        return view

    def get_measurable_surface_point_indices(self) -> list[int]:
        return self._measurable_indices.tolist()

    def get_measurable_surface_point_uncertainties(self) -> list[float]:
        return self._uncertainties.tolist()

    def get_measurable_surface_point_trajectory_distances(self) -> list[float]:
        return self._trajectory_distances.tolist()

    # ------------------------------------------------------------------------------- trajectories
    def get_trajectory_for_measurement(self):
        """The straight measurement trajectory (JointTrajectory or moveit_msgs/RobotTrajectory)."""
        return self._trajectory_for_measurement

    def set_trajectory_for_measurement(self, trajectory_for_measurement) -> None:
        self._trajectory_for_measurement = trajectory_for_measurement

    def get_trajectory_to_view(self):
        """The stored trajectory from a former state to the start of the measurement trajectory."""
        return self._trajectory_to_view

    def set_trajectory_to_view(self, trajectory_to_view) -> None:
        self._trajectory_to_view = trajectory_to_view

    # The original's source names these two ``..._to_viewpoint``; its documentation ``..._to_view``. Both work.
    get_trajectory_to_viewpoint = get_trajectory_to_view
    set_trajectory_to_viewpoint = set_trajectory_to_view

    def reverse_trajectory_for_measurement(self) -> None:
        """Flip the measurement trajectory: start and end swap, the duration stays the same.

        The laser_emitter_frame's orientation is unchanged, so what is measured (and where) is unchanged.
        """
        self._trajectory_for_measurement = reverse_trajectory(self._trajectory_for_measurement)
        if self.scan_line is not None:
            self.scan_line = (self.scan_line[1], self.scan_line[0])
        self.reversed = not self.reversed

    def __repr__(self) -> str:
        return (
            f"ViewPoint(surface_point={self._surface_point.round(3).tolist()}, "
            f"angle_around_boresight={self.angle_around_boresight:.4f}, tilt=({self.tilt_theta:.4f}, "
            f"{self.tilt_psi:.4f}), measurable={self._measurable_indices.size})"
        )


def build_viewpoints(
    candidates: ViewpointCandidates,
    points,
    normals,
    orientations_around_boresight: int,
    tilt_mode: str,
    sensor_model,
    selection=None,
) -> list[ViewPoint]:
    """:class:`ViewPoint` objects for (a selection of) the candidates of :func:`generate_viewpoint_poses`,
    called with the same points, normals, orientations, tilt mode and sensor model.

    ``selection``: indices or boolean mask into the candidates (default: all). The views' anchor poses equal
    ``candidates.poses`` (up to rounding).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    normals = np.asarray(normals, dtype=float).reshape(-1, 3)
    angles = orientation_angles(orientations_around_boresight)
    tilts = tilt_angles(tilt_mode, sensor_model)
    chosen = np.arange(len(candidates.poses)) if selection is None else np.asarray(selection)
    if chosen.dtype == bool:
        chosen = np.flatnonzero(chosen)
    standoff = sensor_model.get_optimal_standoff()
    unit_normals = _unit_rows(normals, "surface normals")
    samples = candidates.sample_index[chosen]
    orientations = candidates.orientation_index[chosen]
    tilt_rows = candidates.tilt_index[chosen]
    views = []
    for index, sample, orientation, tilt in zip(
        chosen.tolist(), samples.tolist(), orientations.tolist(), tilt_rows.tolist(), strict=True
    ):
        view = ViewPoint.from_anchor_pose(
            points[sample],
            unit_normals[sample],
            angles[orientation],
            standoff,
            tilts[tilt, 0],
            tilts[tilt, 1],
            candidates.poses[index],
        )
        view.metadata = {"candidate": index, "sample": sample, "orientation": orientation, "tilt": tilt}
        views.append(view)
    return views
