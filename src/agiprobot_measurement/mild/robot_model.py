"""Kinematic model of the MILD mobile robot (asr_robot_model_services' algorithms), ROS-free.

The MILD: a planar base (x, y in metres, rotation in radians about the map's z) carrying a pan-tilt unit (PTU: pan
about a vertical axis, tilt about a horizontal axis, positive tilt raises the view) with a stereo camera pair. A
robot state is (pan, tilt, rotation, x, y) in that order (RobotStateMessage's field order); a camera pose is the pose
of the camera mount frame in the map frame, the camera looking along its +x axis. The view centre of a camera pose is
``position + view * (ncp + fcp) / 2``.

What is here (the reference's section asr_robot_model_services, see ../shared/reference/interfaces.md), built on
:mod:`~agiprobot_measurement.mild.state` (RobotState, angles), :mod:`~agiprobot_measurement.mild.config` (frames,
kinematics, settings), :mod:`~agiprobot_measurement.mild.lp` (the turn-splitting LP) and
:mod:`~agiprobot_measurement.mild.ratings` (the heuristics):

- forward kinematics: :meth:`MildRobotModel.frame_poses`, :meth:`MildRobotModel.camera_poses` (vectorised);
- inverse kinematics with base movement, exact geometric (``robotModelId: 1``, :meth:`MildRobotModel.exact_ik_batch`):
  closed-form tilt from the tilt axis' constant height and the camera offset so that the camera faces the requested
  view centre from the viewing distance with the least angle deviation (the view azimuth is matched exactly; the
  elevation is whatever the heights force), then the pan sampled over its limits, refined by halving the window
  around the best sample until the ratings change by less than ``inverseKinematicIterationAccuracy``, each sample
  rated by a heuristic on the base pose it implies (SIMPLE, ANGLE_APPROXIMATION, NAVIGATION_PATH; 0 where the map
  does not allow the base); no solution when the view centre is too far above or below the camera's reach;
- approximated inverse kinematics (``robotModelId: 2``, :meth:`MildRobotModel.approximated_ik`): the original's linear
  programme splitting the remaining azimuth turn between pan and base rotation at least weighted cost
  (:func:`solve_turn_lp`: GLPK through swiglpk as the original, HiGHS, or its closed form); tilt = elevation of the
  view axis, base (x, y) = the requested camera position;
- PTU-only pose correction (:meth:`MildRobotModel.camera_pose_correction`): closed-form pan and tilt that aim the
  camera's view axis through the requested view centre without moving the base, clamped to the limits;
- movement costs with the omega weights and sigma; GetDistance and IsPositionAllowed on an
  :class:`~agiprobot_measurement.mild.occupancy_map.OccupancyMap`.

Deliberate differences from the original, each because the original's behaviour was a defect: CalculateCameraPose
is implemented (it returned zeros); the approximated IK clamps the tilt to its limits and splits the turn from the
clamped current pan (so pan + rotation always equals the requested azimuth); ANGLE_APPROXIMATION rates a turn in
place (same position) as the turn itself instead of against a heading of 0; pan samples include the window's ends
and the refinement also continues while the window's samples still differ by more than the accuracy (the original
stopped when two samples straddling the optimum rated alike).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.mild.config import (
    APPROXIMATED_IK,
    MildKinematics,
    RobotModelSettings,
    load_kinematics,
    load_map,
    load_settings,
)
from agiprobot_measurement.mild.lp import solve_turn_lp, turn_split_closed_form
from agiprobot_measurement.mild.occupancy_map import OccupancyMap, polyline_length
from agiprobot_measurement.mild.ratings import (
    rating_angle_approximation,
    rating_angle_approximation_offsets,
    rating_navigation_path,
    rating_simple,
)
from agiprobot_measurement.mild.state import (
    TWO_PI,
    RobotState,
    angle_between,
    check_pose,
    check_position,
    state_problem,
    view_directions,
    wrap_to_2pi,
)

__all__ = ["IKBatch", "IKSolution", "MildRobotModel", "MovementCosts", "PoseCorrection"]


@dataclass(frozen=True)
class IKSolution:
    """Result of an inverse kinematics request. ``state`` is None when there is no solution (``reason`` says why)."""

    state: RobotState | None
    reason: str
    requested_view_centre_m: np.ndarray
    achieved_view_centre_m: np.ndarray | None = None
    camera_pose: np.ndarray | None = None  # 4x4 of the solution's camera mount frame in the map frame
    angle_deviation_rad: float = math.nan  # between the requested and the achieved view axis
    tilt_clamped: bool = False
    base_position_allowed: bool | None = None  # None without a map
    samples: np.ndarray | None = None  # (k, 5) pan, x, y, rotation, rating of every pan sample (visualisation)

    @property
    def ok(self) -> bool:
        return self.state is not None


@dataclass(frozen=True)
class IKBatch:
    """Vectorised IK results: states (n, 5) as (pan, tilt, rotation, x, y), NaN rows where there is no solution."""

    states: np.ndarray
    ok: np.ndarray
    angle_deviation_rad: np.ndarray
    tilt_clamped: np.ndarray
    view_centres_m: np.ndarray  # requested
    achieved_view_centres_m: np.ndarray


@dataclass(frozen=True)
class PoseCorrection:
    """PTU angles (rad) aiming the camera at a view centre without moving the base."""

    pan: float
    tilt: float
    pan_clamped: bool
    tilt_clamped: bool
    view_centre_m: np.ndarray
    reason: str = ""


@dataclass(frozen=True)
class MovementCosts:
    """Movement costs in [0, 1], 1 = no movement (the original's convention), and their omega-weighted mean."""

    base_translation: float
    pan: float
    tilt: float
    rotation: float
    weighted: float


# --------------------------------------------------------------------------------------------------- the model
_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # x right, y down, z along the view


class MildRobotModel:
    """The MILD's kinematics with the settings of asr_robot_model_services and, optionally, a map."""

    def __init__(
        self,
        kinematics: MildKinematics | None = None,
        settings: RobotModelSettings | None = None,
        occupancy_map: OccupancyMap | None = None,
    ):
        self.kinematics = kinematics or load_kinematics()
        self.settings = settings or load_settings()
        self.map = occupancy_map
        k = self.kinematics
        self._bp = k.base_to_pan_m
        self._t = k.pan_to_tilt_m
        self._m = k.tilt_to_mount_m
        self._h = k.tilt_axis_height_m

    @classmethod
    def load(
        cls,
        settings: str | Path | RobotModelSettings | None = None,
        kinematics: str | Path | None = None,
        frames: str | Path | None = None,
        map_file: str | Path | bool | None = None,
    ) -> MildRobotModel:
        """From files (package defaults when None); ``map_file=False`` for a model without a map."""
        if not isinstance(settings, RobotModelSettings):
            settings = load_settings(settings)
        kin = load_kinematics(kinematics, frames)
        occupancy = None if map_file is False else load_map(map_file, settings)
        return cls(kin, settings, occupancy)

    # ----------------------------------------------------------------------------------------- forward kinematics
    @property
    def pan_limits(self) -> tuple[float, float]:
        return self.settings.pan_limits_rad

    @property
    def tilt_limits(self) -> tuple[float, float]:
        return self.settings.tilt_limits_rad

    def frame_poses(self, state: RobotState) -> dict[str, np.ndarray]:
        """4x4 pose in the map frame of every frame of the chain, keyed by tf frame name."""
        k, f = self.kinematics, self.kinematics.frames

        def translation(v):
            m = np.eye(4)
            m[:3, 3] = v
            return m

        def rot_z(a):
            m = np.eye(4)
            m[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
            return m

        def tilt_rotation(a):  # about -y: positive tilt raises the +x axis
            m = np.eye(4)
            m[0, 0], m[0, 2], m[2, 0], m[2, 2] = math.cos(a), -math.sin(a), math.sin(a), math.cos(a)
            return m

        poses = {f.map_frame: np.eye(4)}
        base = translation([state.x, state.y, 0.0]) @ rot_z(state.rotation)
        poses[f.base_frame] = base
        poses[f.ptu_base_frame] = base @ translation(k.base_to_ptu_base_m)
        poses[f.ptu_pan_frame] = poses[f.ptu_base_frame] @ translation(k.ptu_base_to_pan_m)
        poses[f.ptu_pan_frame_rotated] = poses[f.ptu_pan_frame] @ rot_z(state.pan)
        poses[f.ptu_tilt_frame] = poses[f.ptu_pan_frame_rotated] @ translation(k.pan_to_tilt_m)
        poses[f.ptu_tilt_frame_rotated] = poses[f.ptu_tilt_frame] @ tilt_rotation(state.tilt)
        mount = poses[f.ptu_tilt_frame_rotated] @ translation(k.tilt_to_mount_m)
        poses[f.camera_mount_frame] = mount
        optical = np.eye(4)
        optical[:3, :3] = _OPTICAL
        half = 0.5 * k.camera_baseline_m
        poses[f.camera_left_frame] = mount @ translation([0.0, half, 0.0]) @ optical
        poses[f.camera_right_frame] = mount @ translation([0.0, -half, 0.0]) @ optical
        return poses

    def camera_poses(self, states: np.ndarray) -> np.ndarray:
        """Camera mount poses (n, 4, 4) in the map frame of states (n, 5), vectorised."""
        s = np.atleast_2d(np.asarray(states, dtype=float))
        pan, tilt, rotation, x, y = s.T
        heading = rotation + pan
        cr, sr, ch, sh, ct, st = (np.cos(rotation), np.sin(rotation), np.cos(heading), np.sin(heading),
                                  np.cos(tilt), np.sin(tilt))  # fmt: skip
        bp, t, m = self._bp, self._t, self._m
        forward = t[0] + m[0] * ct - m[2] * st  # in the pan-rotated frame
        lateral = t[1] + m[1]
        out = np.zeros((len(s), 4, 4))
        out[:, 0, 3] = x + bp[0] * cr - bp[1] * sr + forward * ch - lateral * sh
        out[:, 1, 3] = y + bp[0] * sr + bp[1] * cr + forward * sh + lateral * ch
        out[:, 2, 3] = self._h + m[0] * st + m[2] * ct
        out[:, :3, 0] = np.stack([ct * ch, ct * sh, st], -1)
        out[:, :3, 1] = np.stack([-sh, ch, np.zeros_like(sh)], -1)
        out[:, :3, 2] = np.stack([-st * ch, -st * sh, ct], -1)
        out[:, 3, 3] = 1.0
        return out

    def camera_pose(self, state: RobotState) -> np.ndarray:
        """Camera mount pose (4x4, map frame) of a robot state (unchecked: see :meth:`calculate_camera_pose`)."""
        return self.camera_poses(state.as_array()[None])[0]

    def check_state(self, state: RobotState, what: str = "robot state") -> RobotState:
        """``state`` if the MILD can take it: finite, pan and tilt within the settings' PTU limits, rotation and
        position within sane bounds; else InputError naming the value and the limit (as mild_sim/set_state)."""
        problem = state_problem(state, self.pan_limits, self.tilt_limits, what)
        if problem:
            raise InputError(problem)
        return state

    def calculate_camera_pose(self, state: RobotState) -> np.ndarray:
        """CalculateCameraPose: the camera mount pose (4x4, map frame) of a checked state (:meth:`check_state`)."""
        return self.camera_pose(self.check_state(state, "sourceRobotState"))

    def view_centre(self, camera_pose: np.ndarray) -> np.ndarray:
        return camera_pose[:3, 3] + self.settings.view_distance_m * camera_pose[:3, 0]

    def view_centre_height_range_m(self) -> tuple[float, float]:
        """Heights of view centres the camera can face from the viewing distance at all (before tilt limits)."""
        d = self.settings.view_distance_m
        reach = math.hypot(self._m[0] + d, self._m[2])
        return self._h - reach, self._h + reach

    # ----------------------------------------------------------------------------------------- ratings
    def rate_base_poses(self, source: RobotState, xy_m: np.ndarray, rotations_rad: np.ndarray) -> np.ndarray:
        """Heuristic rating (``IKAngleRating``) of candidate base poses (..., 2) / (...) reached from ``source``;
        0 where the map does not allow the base position (when the model has a map)."""
        xy = np.asarray(xy_m, dtype=float)
        return self._rate(source, xy[..., 0], xy[..., 1], np.asarray(rotations_rad, dtype=float))

    def _rate(self, source: RobotState, x: np.ndarray, y: np.ndarray, rotations: np.ndarray) -> np.ndarray:
        name = self.settings.ik_angle_rating
        if name == "NAVIGATION_PATH" and self.map is not None:
            ratings = self._rate_navigation_path(source, np.stack([x, y], -1), rotations)
        elif name in ("ANGLE_APPROXIMATION", "NAVIGATION_PATH"):  # NAVIGATION_PATH without a map: straight line
            ratings = rating_angle_approximation_offsets(x - source.x, y - source.y, source.rotation, rotations)
        else:
            ratings = rating_simple(source.rotation, rotations)
        if self.map is not None:
            ratings = np.where(self.map.is_allowed_xy(x, y, self.settings.col_thresh), ratings, 0.0)
        return ratings

    def _rate_navigation_path(self, source: RobotState, xy: np.ndarray, rotations: np.ndarray) -> np.ndarray:
        planner = self.map.planner(self.settings.col_thresh)
        start = np.array([source.x, source.y])
        if planner.snap(start, self.settings.tolerance_m) is None:
            # the robot stands where the planner cannot start: rate the straight line instead of everything 0
            return rating_angle_approximation(start, xy, source.rotation, rotations)
        flat_xy, flat_rot = xy.reshape(-1, 2), rotations.reshape(-1)
        paths = planner.plan_many(start, flat_xy, self.settings.tolerance_m)
        ratings = np.array(
            [rating_navigation_path(p, source.rotation, r) for p, r in zip(paths, flat_rot, strict=True)]
        )
        return ratings.reshape(rotations.shape)

    # ----------------------------------------------------------------------------------------- exact IK
    def _exact_geometry(self, positions: np.ndarray, views: np.ndarray):
        """Tilt, camera heading and the pan-rotated frame's position for every request (vectorised)."""
        d = self.settings.view_distance_m
        tmin, tmax = self.tilt_limits
        m = self._m
        centres = positions + d * views
        heading = np.arctan2(views[:, 1], views[:, 0])
        # The camera at distance d looking at the centre puts the centre at height
        # h + (m_x + d) sin(tilt) + m_z cos(tilt) = h + reach sin(tilt + beta): one tilt for every pan and base pose.
        lever = m[0] + d
        reach = math.hypot(lever, m[2])
        beta = math.atan2(m[2], lever)
        sine = (centres[:, 2] - self._h) / reach
        reachable = np.abs(sine) <= 1.0
        tilt = np.arcsin(np.clip(sine, -1.0, 1.0)) - beta
        tilt_c = np.clip(tilt, tmin, tmax)
        clamped = np.abs(tilt_c - tilt) > 1e-12
        # clamped: face the point above/below the requested centre instead, at the same distance
        achieved = centres.copy()
        achieved[:, 2] = self._h + lever * np.sin(tilt_c) + m[2] * np.cos(tilt_c)
        ct, st, ch, sh = np.cos(tilt_c), np.sin(tilt_c), np.cos(heading), np.sin(heading)
        view = np.stack([ct * ch, ct * sh, st], -1)
        camera = achieved - d * view
        forward = m[0] * ct - m[2] * st
        tilt_axis_xy = camera[:, :2] - np.stack([forward * ch - m[1] * sh, forward * sh + m[1] * ch], -1)
        t = self._t
        pan_xy = tilt_axis_xy - np.stack([t[0] * ch - t[1] * sh, t[0] * sh + t[1] * ch], -1)
        return heading, tilt_c, pan_xy, reachable, clamped, centres, achieved, view

    def _base_poses(self, heading: np.ndarray, pan_xy: np.ndarray, pans: np.ndarray):
        """Base positions x, y (n, k) and rotations (n, k) putting the pan axis at ``pan_xy`` (n, 2) for pans (n, k)."""
        rotation = heading[:, None] - pans
        c, s = np.cos(rotation), np.sin(rotation)
        bx = pan_xy[:, 0, None] - (self._bp[0] * c - self._bp[1] * s)
        by = pan_xy[:, 1, None] - (self._bp[0] * s + self._bp[1] * c)
        return bx, by, rotation

    def _sample_pan(self, source: RobotState, heading, pan_xy, record: bool = False):
        """The original's pan sampling: ``panAngleSamplingStepsPerIteration`` samples spread evenly across a window
        that starts as the whole pan range and then halves around the best sample so far (kept inside the limits).

        Refinement stops after ``panAngleSamplingMaxIterations`` or once the best rating improved by at most
        ``inverseKinematicIterationAccuracy`` and the window's samples rate within that accuracy of each other. (The
        original stopped on the improvement alone, which ends too early when two samples straddle the optimum.)
        """
        lo, hi = self.pan_limits
        n = len(heading)
        offsets = np.linspace(-0.5, 0.5, self.settings.pan_sampling_steps)
        accuracy = self.settings.ik_iteration_accuracy
        centre = np.full(n, 0.5 * (lo + hi))
        width = np.full(n, hi - lo)
        best_pan = centre.copy()
        best_rating = np.full(n, -1.0)
        active = np.ones(n, dtype=bool)
        rows = np.arange(n)
        trace = []
        for _ in range(self.settings.pan_sampling_max_iterations):
            centre = np.clip(centre, lo + 0.5 * width, hi - 0.5 * width)
            pans = centre[:, None] + width[:, None] * offsets
            bx, by, rotation = self._base_poses(heading, pan_xy, pans)
            ratings = self._rate(source, bx, by, rotation)
            if record:
                trace.append(np.stack([pans, bx, by, rotation, ratings], -1))
            best = np.argmax(ratings, axis=1)
            rating = ratings[rows, best]
            improved = active & (rating > best_rating)
            gain = np.where(improved, rating - np.maximum(best_rating, 0.0), 0.0)
            best_pan = np.where(improved, pans[rows, best], best_pan)
            best_rating = np.where(improved, rating, best_rating)
            centre = np.where(active, best_pan, centre)
            width = np.where(active, 0.5 * width, width)
            spread = ratings.max(axis=1) - ratings.min(axis=1)
            active &= (gain > accuracy) | (spread > accuracy)
            if not active.any():
                break
        samples = np.concatenate([t.reshape(n, -1, 5) for t in trace], axis=1) if record else None
        return best_pan, best_rating, samples

    def exact_ik_batch(self, source: RobotState, positions: np.ndarray, orientations: np.ndarray) -> IKBatch:
        """Exact geometric IK with base movement for many requested camera poses (positions (n, 3) in m,
        orientations (n, 4) as unit quaternions x, y, z, w) from one source state."""
        return self._exact(source, positions, orientations)[0]

    def _exact(self, source: RobotState, positions, orientations, record: bool = False):
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        views = view_directions(np.atleast_2d(np.asarray(orientations, dtype=float)))
        views /= np.linalg.norm(views, axis=1, keepdims=True)
        heading, tilt, pan_xy, reachable, clamped, centres, achieved, view = self._exact_geometry(positions, views)
        n = len(positions)
        states = np.full((n, 5), np.nan)
        samples = None
        if reachable.any():
            idx = np.flatnonzero(reachable)
            pan, _, samples = self._sample_pan(source, heading[idx], pan_xy[idx], record)
            bx, by, rotation = self._base_poses(heading[idx], pan_xy[idx], pan[:, None])
            states[idx] = np.stack([pan, tilt[idx], wrap_to_2pi(rotation[:, 0]), bx[:, 0], by[:, 0]], -1)
        deviation = np.where(reachable, angle_between(view, views), np.nan)
        batch = IKBatch(
            states, reachable, deviation, clamped & reachable, centres, np.where(reachable[:, None], achieved, np.nan)
        )
        return batch, samples

    # ----------------------------------------------------------------------------------------- approximated IK
    def approximated_ik_batch(self, source: RobotState, positions, orientations) -> IKBatch:
        """Approximated IK (the LP in its closed form, vectorised) for many requested camera poses."""
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        views = view_directions(np.atleast_2d(np.asarray(orientations, dtype=float)))
        views /= np.linalg.norm(views, axis=1, keepdims=True)
        alpha, up, down, current_pan, elevation = self._approximated_setup(source, views)
        s = self.settings
        pan_change, rot_change = turn_split_closed_form(alpha, up, down, s.omega_pan, s.omega_rot)
        return self._approximated_result(source, positions, views, current_pan + pan_change, rot_change, elevation)

    def _approximated_setup(self, source: RobotState, views: np.ndarray):
        lo, hi = self.pan_limits
        azimuth = wrap_to_2pi(np.arctan2(views[:, 1], views[:, 0]))
        elevation = np.arcsin(np.clip(views[:, 2], -1.0, 1.0))
        current_pan = min(max(source.pan, lo), hi)  # a pan outside the limits counts as at the limit
        alpha = wrap_to_pi(azimuth - current_pan - source.rotation)
        return (
            alpha,
            np.full_like(alpha, hi - current_pan),
            np.full_like(alpha, current_pan - lo),
            current_pan,
            elevation,
        )

    def _approximated_result(self, source, positions, views, pan, rot_change, elevation) -> IKBatch:
        tmin, tmax = self.tilt_limits
        tilt = np.clip(elevation, tmin, tmax)
        lo, hi = self.pan_limits
        pan = np.clip(pan, lo, hi)
        rotation = wrap_to_2pi(source.rotation + rot_change)
        states = np.stack([pan, tilt, rotation, positions[:, 0], positions[:, 1]], -1)
        poses = self.camera_poses(states)
        achieved_view = poses[:, :3, 0]
        deviation = angle_between(achieved_view, views)
        d = self.settings.view_distance_m
        n = len(states)
        return IKBatch(
            states,
            np.ones(n, dtype=bool),
            deviation,
            np.abs(tilt - elevation) > 1e-12,
            positions + d * views,
            poses[:, :3, 3] + d * achieved_view,
        )

    def approximated_ik(self, source: RobotState, position, orientation_xyzw) -> IKSolution:
        """Approximated IK for one pose, the LP solved by ``lpSolver`` (GLPK by default, as the original)."""
        source = self.check_state(source, "sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        views = view_directions(q[None])
        alpha, up, down, current_pan, elevation = self._approximated_setup(source, views)
        s = self.settings
        pan_change, rot_change = solve_turn_lp(alpha[0], up[0], down[0], s.omega_pan, s.omega_rot, s.lp_solver)
        batch = self._approximated_result(
            source, p[None], views, np.array([current_pan + pan_change]), np.array([rot_change]), elevation
        )
        return self._solution(batch, 0, None)

    # ----------------------------------------------------------------------------------------- IK entry point
    def calculate_robot_state(
        self, source: RobotState, position, orientation_xyzw, record_samples: bool = False
    ) -> IKSolution:
        """Inverse kinematics with base movement by ``robotModelId`` (1 exact, 2 approximated).

        ``position`` (m, map) and ``orientation_xyzw`` are the requested camera pose, the camera looking along +x.
        Raises InputError (a ValueError) for a state the MILD cannot take (:meth:`check_state`), a non-finite or
        absurd pose or a zero quaternion.
        """
        if self.settings.robot_model_id == APPROXIMATED_IK:
            return self.approximated_ik(source, position, orientation_xyzw)
        source = self.check_state(source, "sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        batch, samples = self._exact(source, p[None], q[None], record_samples)
        return self._solution(batch, 0, None if samples is None else samples[0] if len(samples) else None)

    def _solution(self, batch: IKBatch, i: int, samples) -> IKSolution:
        centre = batch.view_centres_m[i]
        if not batch.ok[i]:
            low, high = self.view_centre_height_range_m()
            where = "above" if centre[2] > high else "below"
            return IKSolution(
                None,
                f"no solution: the view centre ({centre[0]:.3f}, {centre[1]:.3f}, {centre[2]:.3f}) m is too far "
                f"{where} the robot; the camera faces view centres at {low:.3f} .. {high:.3f} m height from "
                f"{self.settings.view_distance_m:.3f} m",
                centre,
            )
        state = RobotState.from_array(batch.states[i])
        pose = self.camera_pose(state)
        achieved = self.view_centre(pose)
        reason = ""
        if batch.tilt_clamped[i]:
            lo, hi = np.degrees(self.tilt_limits)
            reason = (
                f"tilt clamped to [{lo:.1f}, {hi:.1f}] deg: the view centre is approximated "
                f"{np.linalg.norm(achieved - centre):.3f} m away"
            )
        allowed = None
        if self.map is not None:
            allowed = bool(self.map.is_allowed(np.array([state.x, state.y]), self.settings.col_thresh))
            if not allowed:
                reason = (reason + "; " if reason else "") + "the base position is not allowed on the map"
        return IKSolution(
            state,
            reason,
            centre,
            achieved,
            pose,
            float(batch.angle_deviation_rad[i]),
            bool(batch.tilt_clamped[i]),
            allowed,
            samples,
        )

    # ----------------------------------------------------------------------------------------- PTU pose correction
    def camera_pose_correction(self, state: RobotState, position, orientation_xyzw) -> PoseCorrection:
        """Pan and tilt (rad) that make the camera's view axis pass through the requested view centre without moving
        the base (the distance to it is whatever results), clamped to the PTU limits; ``state`` must be one the MILD
        can take (:meth:`check_state`)."""
        state = self.check_state(state, "sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        centre = p + self.settings.view_distance_m * view_directions(q)
        c, s = math.cos(state.rotation), math.sin(state.rotation)
        bp, t, m = self._bp, self._t, self._m
        pan_axis = np.array([state.x + bp[0] * c - bp[1] * s, state.y + bp[0] * s + bp[1] * c])
        w = centre[:2] - pan_axis
        a = math.hypot(w[0], w[1])
        bearing = math.atan2(w[1], w[0])
        lateral = t[1] + m[1]  # the view axis runs in the vertical plane this far left of the pan axis
        notes = []
        if a > abs(lateral) + 1e-9:
            offset = math.asin(lateral / a)
            heading = bearing - offset
            ahead = a * math.cos(offset)
        else:
            heading, ahead = bearing, a
            notes.append("the view centre lies on the pan axis: pan kept on its bearing")
        forward, up = ahead - t[0], centre[2] - self._h
        radius = math.hypot(forward, up)
        elevation = math.atan2(up, forward)
        tilt = elevation - math.asin(m[2] / radius) if radius > abs(m[2]) else elevation
        pan, pan_clamped = self._pan_within_limits(heading - state.rotation, state.pan)
        tmin, tmax = self.tilt_limits
        tilt_c = min(max(tilt, tmin), tmax)
        tilt_clamped = tilt_c != tilt
        if pan_clamped:
            notes.append(f"pan {math.degrees(wrap_to_pi(heading - state.rotation)):.1f} deg clamped to the limits")
        if tilt_clamped:
            notes.append(f"tilt {math.degrees(tilt):.1f} deg clamped to the limits")
        return PoseCorrection(pan, tilt_c, pan_clamped, tilt_clamped, centre, "; ".join(notes))

    def _pan_within_limits(self, pan_rad: float, current_pan_rad: float) -> tuple[float, bool]:
        """The representation pan + 2 pi k within the limits closest to the current pan, else the nearest limit."""
        lo, hi = self.pan_limits
        candidates = float(wrap_to_pi(pan_rad)) + TWO_PI * np.arange(-2, 3)
        inside = candidates[(candidates >= lo - 1e-12) & (candidates <= hi + 1e-12)]
        if len(inside):
            return float(inside[np.argmin(np.abs(inside - current_pan_rad))]), False
        clamped = np.clip(candidates, lo, hi)
        return float(clamped[np.argmin(np.abs(clamped - candidates))]), True

    # ----------------------------------------------------------------------------------------- costs and map
    def get_distance(self, source_position_m, target_position_m) -> float:
        """GetDistance: 2-D Euclidean distance (m), or with ``useGlobalPlanner`` the planned path's length on the map;
        -1 when there is no path."""
        a = np.asarray(source_position_m, dtype=float).reshape(-1)[:2]
        b = np.asarray(target_position_m, dtype=float).reshape(-1)[:2]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise InputError(f"positions must be finite, got {a.tolist()} and {b.tolist()}")
        a, b = check_position(a, "sourcePosition"), check_position(b, "targetPosition")
        if not self.settings.use_global_planner:
            return float(np.hypot(*(b - a)))
        if self.map is None:
            raise InternalError("useGlobalPlanner is set but the model has no map")
        path = self.map.planner(self.settings.col_thresh).plan(a, b, self.settings.tolerance_m)
        return -1.0 if path is None else polyline_length(path)

    def navigation_path(self, source_position_m, target_position_m) -> np.ndarray | None:
        """The planned path (k, 2) in metres on the map, None when there is none."""
        if self.map is None:
            raise InternalError("the model has no map")
        a = np.asarray(source_position_m, dtype=float).reshape(-1)[:2]
        b = np.asarray(target_position_m, dtype=float).reshape(-1)[:2]
        return self.map.planner(self.settings.col_thresh).plan(a, b, self.settings.tolerance_m)

    def is_position_allowed(self, position_m) -> bool:
        """IsPositionAllowed: the inflated map's occupancy at the point lies within [0, colThresh]; unknown cells
        and points outside the map are not allowed."""
        p = np.asarray(position_m, dtype=float).reshape(-1)[:2]
        if not np.all(np.isfinite(p)):
            raise InputError(f"position {p.tolist()} is not finite")
        p = check_position(p, "targetPosition")
        if self.map is None:
            raise InternalError("the model has no map")
        return bool(self.map.is_allowed(p, self.settings.col_thresh))

    def movement_costs(self, source: RobotState, target: RobotState) -> MovementCosts:
        """The original's movement costs (1 = no movement): base translation exp(-d^2 / (2 mSigma^2)) with d from
        GetDistance (a missing path costs everything), pan 1 - |d pan| / pan span, tilt 1 - |d tilt| / tilt span,
        rotation 1 - (turn onto the line between the positions + turn from it to the target heading, or the turn
        in place) / 2 pi; ``weighted`` is their mean weighted by mOmegaBase, mOmegaPan, mOmegaTilt, mOmegaRot."""
        s = self.settings
        distance = self.get_distance([source.x, source.y], [target.x, target.y])
        base = 0.0 if distance < 0 else math.exp(-(distance**2) / (2.0 * s.sigma_m**2))
        pan_span = s.pan_limits_rad[1] - s.pan_limits_rad[0]
        tilt_span = s.tilt_limits_rad[1] - s.tilt_limits_rad[0]
        pan = 1.0 - abs(target.pan - source.pan) / pan_span
        tilt = 1.0 - abs(target.tilt - source.tilt) / tilt_span
        dx, dy = target.x - source.x, target.y - source.y
        if abs(dx) < 1e-5 and abs(dy) < 1e-5:
            turn = abs(float(wrap_to_pi(target.rotation - source.rotation)))
        else:
            line = math.atan2(dy, dx)
            turn = abs(float(wrap_to_pi(source.rotation - line))) + abs(float(wrap_to_pi(target.rotation - line)))
        rotation = 1.0 - turn / TWO_PI
        weights = np.array([s.omega_base, s.omega_pan, s.omega_tilt, s.omega_rot])
        values = np.array([base, pan, tilt, rotation])
        weighted = float(weights @ values / weights.sum()) if weights.sum() > 0 else float(values.mean())
        return MovementCosts(base, pan, tilt, rotation, weighted)

    # ----------------------------------------------------------------------------------------- visualisation
    def frustum_corners(self, camera_pose: np.ndarray) -> np.ndarray:
        """The 8 corners (m, map frame) of the camera's view frustum: near plane then far plane, each
        top-left, top-right, bottom-right, bottom-left as seen from the camera."""
        s = self.settings
        corners = []
        for distance in (s.ncp_m, s.fcp_m):
            half_w = distance * math.tan(0.5 * s.fovx_rad)
            half_h = distance * math.tan(0.5 * s.fovy_rad)
            for lateral, vertical in ((half_w, half_h), (-half_w, half_h), (-half_w, -half_h), (half_w, -half_h)):
                corners.append([distance, lateral, vertical])
        local = np.array(corners)
        return local @ camera_pose[:3, :3].T + camera_pose[:3, 3]
