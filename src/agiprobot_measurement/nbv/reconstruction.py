"""The 3D next-best-view loop on the station (issue 17): an unknown part reconstructed by the PhoXi on the flange.

:class:`Reconstructor` runs, with any :class:`~.interfaces.NBVRobot` and :class:`~.interfaces.NBVCamera` (the
simulation of :mod:`.station3d` or the ROS node's):

1. the home pose (config/nbv.yaml ``motion.home_rad``); the opening view: the feasible pose of the global view
   sphere around the ROI nearest ``motion.opening_elevation_deg`` (90: the most top-down one); if the ROI is still
   empty, an a-priori search of ``motion.search_views`` hemisphere views; if still nothing, the result is
   ``nothing_found``;
2. per view: capture, fuse into the output map (``resolution_m``) and the planning map (``planning_resolution_m``,
   fused from the same frames so that its free space is carved at its own resolution), update the labels, generate
   and filter candidates (:mod:`.candidates`), score them (:mod:`.gains`), weigh the estimated joint-move time,
   check the stopping rules, plan the motion of the best view with OMPL (a view whose motion fails is tabu-listed
   and the next one is taken) and move;
3. the stopping rules, first one wins and the result names it (:data:`TERMINATION_REASONS`): the expected new
   surface of the best view below ``min_gain_area_mm2`` for two iterations in a row, or its gain below
   ``min_relative_gain`` of the first iteration's (``gain_below_threshold``); no feasible candidate with a
   positive gain left (``frontier_exhausted``); the budgets ``max_views``, ``max_time_s``, ``max_joint_path_rad``;
   cancel. Visited and failed poses are tabu, so the loop cannot cycle.

Methods (``ReconstructionRequest.gain``): ``ours`` -- the frontier + sphere candidates scored by a weighted sum of
PhoXi-aware gains (the report gain: frontier voxels seen with camera and projector rays clear and acceptable
incidence, weighted by the perpendicularity w cos a + 1 - w; plus rear-side voxels and proximity count), each
normalised by its best candidate, discounted by the motion time (G exp(-lambda C)), with the surprise rule below; any of :data:`~.gains.GAIN_NAMES` with rpg's utility G/sum G - w C/sum C; the baselines of
:mod:`.baselines` (``random``, ``hemisphere6/12/24``, ``report3d``). Outputs (:meth:`Reconstructor.save_outputs`,
atomically into ``output_dir``): ``cloud.ply`` (fused raw points), ``map.npz`` (+ ``map.bt`` with an OctoMap
binding), ``mesh.ply`` (TSDF + marching cubes), ``views.yaml`` (poses, joints, gains, timings, reason).
World frame, metres, rad; areas in m^2 except the request's ``min_gain_area_mm2``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.geometry import raise_elevation, slerp_unit
from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.nbv.baselines import ViewChoice as _Choice
from agiprobot_measurement.nbv.baselines import motion_time_s
from agiprobot_measurement.nbv.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.interfaces import CapturedView, NBVCamera, NBVRobot

__all__ = [
    "CANDIDATE_SOURCES",
    "METHODS",
    "TERMINATION_REASONS",
    "Progress",
    "ReconstructionRequest",
    "ReconstructionResult",
    "Reconstructor",
    "ViewRecord",
    "motion_time_s",
]

LOG = logging.getLogger(__name__)

#: a move through a via pose at most this times the straight joint distance is taken without asking OMPL
VIA_ACCEPT_RATIO = 1.5
#: joint step (rad) at which the via moves are collision-checked (as the straight move's)
VIA_CHECK_STEP_RAD = 0.02


def _path_length_rad(trajectory) -> float:
    """Joint path of a trajectory: sum of |dq| over its samples (rad), as the run's ``joint_path_rad``."""
    positions = np.asarray(trajectory.positions, dtype=float)
    return float(np.abs(np.diff(positions, axis=0)).sum()) if len(positions) >= 2 else 0.0


TERMINATION_REASONS = (
    "gain_below_threshold",
    "frontier_exhausted",
    "max_views",
    "max_time",
    "max_path",
    "cancelled",
    "nothing_found",
    "error",
    "plan_only",  # execute=False: the result carries the next best view, nothing moved
)
METHODS = ("ours", *GAIN_NAMES, "random", "hemisphere", "hemisphere6", "hemisphere12", "hemisphere24", "report3d")
#: candidate sources; "random" and "hemisphere_fixed" (the action's names) select those baselines
CANDIDATE_SOURCES = ("frontier+sphere", "frontier", "sphere", "random", "hemisphere_fixed")
#: the largest ROI edge the loop accepts (m): the UR10e's reach around a part on the fixture
MAX_ROI_EDGE_M = 1.0
MAX_VIEWS = 1000


def _defaults() -> dict:
    from agiprobot_measurement.nbv.station3d import load_nbv_config

    try:
        return dict(load_nbv_config().get("request", {}))
    except InputError:
        return {}


def _vector3(value, name: str, positive: bool = False) -> np.ndarray | None:
    if value is None:
        return None
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be three numbers (m), got {value!r}") from None
    if v.shape != (3,):
        raise InputError(f"{name} must be three numbers (m), got {v.size}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} contains NaN or infinite values: {v.tolist()}")
    if positive and np.any(v <= 0):
        raise InputError(f"{name} must be positive in every axis (an empty region of interest), got {v.tolist()}")
    return v


def _number(value, name: str, low: float | None = None, high: float | None = None, allow_inf=False, strict=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise InputError(f"{name} must be finite, got {value!r}")
    if low is not None and (v <= low if strict else v < low):
        raise InputError(f"{name} must be {'>' if strict else '>='} {low:g}, got {value!r}")
    if high is not None and v > high:
        raise InputError(f"{name} must be <= {high:g}, got {value!r}")
    return v


def _number_list(values, name: str, low: float, high: float) -> tuple[float, ...]:
    """A config list of numbers in [low, high] (a single number is a list of one)."""
    if isinstance(values, (int, float)):
        values = [values]
    if not isinstance(values, (list, tuple)):
        raise InputError(f"{name} must be a list of numbers, got {values!r}")
    return tuple(_number(v, name, low, high) for v in values)


@dataclass
class ReconstructionRequest:
    """One reconstruction; every field is validated here (InputError naming the field). Lengths m, angles rad."""

    roi_center_m: np.ndarray | None = None  # None = above the fixture, where the scene's part sits
    roi_size_m: np.ndarray | None = None  # None = config/nbv.yaml roi.max_object_size_m + margins
    resolution_m: float = 0.002
    planning_resolution_m: float = 0.005
    gain: str = "ours"  # "ours" | GAIN_NAMES | "random" | "hemisphere[6|12|24]" | "report3d"
    candidates: str = "frontier+sphere"
    cost_weight: float = 0.3  # ours: lambda in 1/s of G exp(-lambda C); metrics: rpg's w
    max_views: int = 20
    max_time_s: float = 600.0
    max_joint_path_rad: float = math.inf
    min_gain_area_mm2: float = 100.0
    min_relative_gain: float = 0.02
    execute: bool = True  # False = plan-only: next_best_view() without moving
    output_dir: str | None = None
    seed: int = 0

    def __post_init__(self):
        self.roi_center_m = _vector3(self.roi_center_m, "roi_center_m")
        self.roi_size_m = _vector3(self.roi_size_m, "roi_size_m", positive=True)
        if self.roi_size_m is not None and np.any(self.roi_size_m > MAX_ROI_EDGE_M):
            raise InputError(
                f"roi_size_m {self.roi_size_m.tolist()} is too large: every edge must be <= {MAX_ROI_EDGE_M} m"
            )
        self.resolution_m = _number(self.resolution_m, "resolution_m", 0.0, 0.05, strict=True)
        if self.resolution_m < 0.0005:
            raise InputError(f"resolution_m must be >= 0.0005 m, got {self.resolution_m}")
        self.planning_resolution_m = _number(self.planning_resolution_m, "planning_resolution_m", 0.0, 0.1, strict=True)
        if self.planning_resolution_m < self.resolution_m:
            raise InputError(
                f"planning_resolution_m ({self.planning_resolution_m}) must not be finer than resolution_m "
                f"({self.resolution_m})"
            )
        if not isinstance(self.gain, str) or self.gain not in METHODS:
            raise InputError(f"gain: unknown method {self.gain!r}; known: {', '.join(METHODS)}")
        if not isinstance(self.candidates, str) or self.candidates not in CANDIDATE_SOURCES:
            raise InputError(f"candidates: unknown source {self.candidates!r}; known: {', '.join(CANDIDATE_SOURCES)}")
        self.cost_weight = _number(self.cost_weight, "cost_weight", 0.0)
        views = _number(self.max_views, "max_views", 1.0, MAX_VIEWS)
        if views != int(views):
            raise InputError(f"max_views must be an integer, got {self.max_views!r}")
        self.max_views = int(views)
        self.max_time_s = _number(self.max_time_s, "max_time_s", 0.0, allow_inf=True, strict=True)
        self.max_joint_path_rad = _number(
            self.max_joint_path_rad, "max_joint_path_rad", 0.0, allow_inf=True, strict=True
        )
        self.min_gain_area_mm2 = _number(self.min_gain_area_mm2, "min_gain_area_mm2", 0.0)
        self.min_relative_gain = _number(self.min_relative_gain, "min_relative_gain", 0.0, 1.0)
        self.execute = bool(self.execute)
        seed = _number(self.seed, "seed", 0.0)
        self.seed = int(seed)
        if self.output_dir is not None and not isinstance(self.output_dir, (str, Path)):
            raise InputError(f"output_dir must be a path, got {self.output_dir!r}")
        if self.output_dir in ("",):
            self.output_dir = None

    @property
    def method(self) -> str:
        """The selection method, the ``candidates`` aliases applied."""
        if self.candidates == "random":
            return "random"
        if self.candidates == "hemisphere_fixed":
            return "hemisphere12"
        return "hemisphere12" if self.gain == "hemisphere" else self.gain

    @property
    def sources(self) -> str:
        return self.candidates if self.candidates in ("frontier+sphere", "frontier", "sphere") else "frontier+sphere"

    @classmethod
    def from_mapping(cls, values: dict) -> ReconstructionRequest:
        """A request from a mapping (an action goal, a JSON file): zero, empty or missing fields take the defaults
        (config/nbv.yaml ``request``, then this class's); ``max_joint_path_rad`` 0 means unlimited."""
        if not isinstance(values, dict):
            raise InputError(f"a request must be a mapping, got {type(values).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InputError(f"unknown request field(s): {', '.join(unknown)}")
        kwargs = {k: v for k, v in _defaults().items() if k in known}
        for key, value in values.items():
            if value is None or (isinstance(value, str) and value == ""):
                continue
            if key in ("roi_center_m", "roi_size_m"):
                try:
                    arr = np.asarray(value, dtype=float).reshape(-1)
                except (TypeError, ValueError):
                    raise InputError(f"{key} must be three numbers (m), got {value!r}") from None
                if arr.size == 0 or (arr.size == 3 and np.all(arr == 0)):
                    continue
            elif key not in ("execute", "seed", "min_gain_area_mm2") and not isinstance(value, str):
                try:
                    if float(value) == 0.0:
                        continue
                except (TypeError, ValueError):
                    pass
            kwargs[key] = value
        return cls(**kwargs)

    @classmethod
    def with_config_defaults(cls, **overrides) -> ReconstructionRequest:
        """config/nbv.yaml's ``request`` defaults with ``overrides`` (not treated as unset when zero)."""
        known = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in _defaults().items() if k in known}
        kwargs.update(overrides)
        return cls(**kwargs)


@dataclass
class ViewRecord:
    index: int
    camera_pose: np.ndarray  # world <- sensor at capture
    joints: np.ndarray  # rad
    gain: float = 0.0  # of the chosen view, predicted before moving there (0 for the opening view)
    utility: float = 0.0
    candidates_total: int = 0
    candidates_feasible: int = 0
    rejections: dict = field(default_factory=dict)
    planning_s: float = 0.0  # candidates + gains + motion planning before this view
    motion_s: float = 0.0  # duration of the trajectory that brought the robot here
    joint_path_rad: float = 0.0  # sum |dq| of that trajectory
    observed_area_m2: float = 0.0  # after fusing this view
    coverage: float | None = None  # of the observable ground truth after this view (simulation)
    expected_new_area_m2: float = 0.0
    new_area_m2: float = 0.0  # realised: observed surface (output map) added by this view
    source: str = ""
    points: int = 0
    capture_s: float = 0.0
    integrate_s: float = 0.0

    def as_dict(self) -> dict:
        return {
            "index": int(self.index),
            "source": self.source,
            "camera_pose": np.round(self.camera_pose, 6).tolist(),
            "joints_rad": np.round(self.joints, 6).tolist(),
            "gain": float(self.gain),
            "utility": float(self.utility),
            "expected_new_area_m2": float(self.expected_new_area_m2),
            "new_area_m2": float(self.new_area_m2),
            "candidates_total": int(self.candidates_total),
            "candidates_feasible": int(self.candidates_feasible),
            "rejections": {str(k): int(v) for k, v in self.rejections.items()},
            "planning_s": round(float(self.planning_s), 4),
            "motion_s": round(float(self.motion_s), 4),
            "joint_path_rad": round(float(self.joint_path_rad), 5),
            "observed_area_m2": float(self.observed_area_m2),
            "coverage": None if self.coverage is None else float(self.coverage),
            "points": int(self.points),
            "capture_s": round(float(self.capture_s), 4),
            "integrate_s": round(float(self.integrate_s), 4),
        }


@dataclass
class ReconstructionResult:
    termination_reason: str
    views: list = field(default_factory=list)
    joint_path_rad: float = 0.0
    tcp_path_m: float = 0.0
    planning_time_s: float = 0.0
    execution_time_s: float = 0.0
    observed_surface_area_m2: float = 0.0
    remaining_frontier_area_m2: float = 0.0
    coverage: float | None = None
    cloud_file: str = ""
    mesh_file: str = ""
    map_file: str = ""
    log_file: str = ""
    error: str = ""
    motion_failures: int = 0
    wall_time_s: float = 0.0
    next_view_pose: np.ndarray | None = None  # plan-only: the next best view (world <- sensor)
    next_view_joints: np.ndarray | None = None
    next_view_gain: float = 0.0

    def summary(self) -> dict:
        return {
            "termination_reason": self.termination_reason,
            "error": self.error,
            "views": len(self.views),
            "joint_path_rad": float(self.joint_path_rad),
            "tcp_path_m": float(self.tcp_path_m),
            "planning_time_s": float(self.planning_time_s),
            "execution_time_s": float(self.execution_time_s),
            "wall_time_s": float(self.wall_time_s),
            "observed_surface_area_m2": float(self.observed_surface_area_m2),
            "remaining_frontier_area_m2": float(self.remaining_frontier_area_m2),
            "coverage": None if self.coverage is None else float(self.coverage),
            "motion_failures": int(self.motion_failures),
            "cloud_file": self.cloud_file,
            "mesh_file": self.mesh_file,
            "map_file": self.map_file,
            "log_file": self.log_file,
        }


@dataclass
class Progress:
    view: int
    phase: str  # search|capture|integrate|candidates|evaluate|plan_motion|move|finish
    best_gain: float = 0.0
    relative_gain: float = 0.0
    candidates_total: int = 0
    candidates_feasible: int = 0
    observed_area_m2: float = 0.0
    coverage: float | None = None
    progress: float = 0.0
    next_view_pose: np.ndarray | None = None


class Reconstructor:
    """The loop (see the module docstring). ``station``: an :class:`~.station3d.NBVStation` (None: built from the
    configuration); ``ground_truth``: a :class:`~.ground_truth.GroundTruth` (simulation) for coverage per view."""

    def __init__(self, robot: NBVRobot, camera: NBVCamera, request: ReconstructionRequest, station=None,
                 ground_truth=None, gain_rays: tuple[int, int] | None = None,
                 max_evaluated: int | None = None):  # fmt: skip
        from agiprobot_measurement.nbv.baselines import make_policy
        from agiprobot_measurement.nbv.candidates import CandidateConfig, CandidateGenerator
        from agiprobot_measurement.nbv.gains import ViewModel
        from agiprobot_measurement.nbv.station3d import NBVStation
        from agiprobot_measurement.nbv.voxel_map import MapConfig, VoxelMap

        if not isinstance(request, ReconstructionRequest):
            raise InputError(f"request must be a ReconstructionRequest, got {type(request).__name__}")
        self.robot = robot
        self.camera = camera
        self.request = request
        self.station = station if station is not None else NBVStation()
        self.ground_truth = ground_truth
        cfg = self.station.config
        center, size = self.station.default_roi()
        if request.roi_center_m is not None:
            center = request.roi_center_m
        if request.roi_size_m is not None:
            size = request.roi_size_m
        self.roi_min_m = np.asarray(center, dtype=float) - np.asarray(size, dtype=float) / 2.0
        self.roi_max_m = np.asarray(center, dtype=float) + np.asarray(size, dtype=float) / 2.0
        self.roi_center_m = np.asarray(center, dtype=float)
        self.map = VoxelMap(
            self.roi_min_m,
            self.roi_max_m,
            MapConfig(resolution_m=request.resolution_m, planning_resolution_m=request.planning_resolution_m),
        )
        self.planning_map = VoxelMap(
            self.roi_min_m,
            self.roi_max_m,
            MapConfig(resolution_m=request.planning_resolution_m, planning_resolution_m=request.planning_resolution_m),
        )
        static = self.station.static_mesh()
        for grid in (self.map, self.planning_map):
            grid.set_static(static)
        self.candidate_config = CandidateConfig.from_config(cfg.get("candidates", {}), self.station.scanner_model)
        self.generator = CandidateGenerator(self.station, self.candidate_config, seed=request.seed)
        planning = cfg.get("planning", {})
        rays = gain_rays or tuple(planning.get("gain_rays", (32, 24)))
        self.view_model = ViewModel.from_scanner_model(self.station.scanner_model, int(rays[0]), int(rays[1]))
        self.max_evaluated = int(planning.get("max_evaluated", 160) if max_evaluated is None else max_evaluated)
        motion = cfg.get("motion", {})
        self.velocity_scaling = float(motion.get("velocity_scaling", 0.5))
        self.planning_time_s = float(motion.get("planning_time_s", 0.5))
        self.simplify_time_s = float(motion.get("simplify_time_s", 0.5))
        self.search_views = int(motion.get("search_views", 4))
        self.via_poses = int(motion.get("via_poses", 8))
        best_of = _number(motion.get("ompl_best_of", 4), "motion.ompl_best_of", 1.0, 50.0)
        if best_of != int(best_of):
            raise InputError(f"motion.ompl_best_of must be a whole number, got {best_of!r}")
        self.ompl_best_of = int(best_of)
        self.orbit_retract_m = _number_list(
            motion.get("orbit_retract_m", [0.1, 0.2, 0.3]), "motion.orbit_retract_m", 0.0, 1.0
        )
        self.orbit_radius_extra_m = _number_list(
            motion.get("orbit_radius_extra_m", [0.05, 0.15, 0.3]), "motion.orbit_radius_extra_m", 0.0, 1.0
        )
        self.orbit_lift_deg = _number_list(
            motion.get("orbit_lift_deg", [25.0, 50.0]), "motion.orbit_lift_deg", 0.0, 90.0
        )
        self.opening_height = float(motion.get("opening_height", 0.25))
        self.opening_elevation_deg = float(motion.get("opening_elevation_deg", 90.0))
        if not (math.isfinite(self.opening_elevation_deg) and 0.0 <= self.opening_elevation_deg <= 90.0):
            raise InputError(f"motion.opening_elevation_deg must be in [0, 90], got {self.opening_elevation_deg!r}")
        self.home_rad = np.asarray(self.station.home_rad, dtype=float)
        self.rng = np.random.default_rng(request.seed)
        self.policy = make_policy(request.method, self)
        self.candidates_last: list = []  # (poses (N,4,4), utilities (N,), reasons (N,)) of the last evaluation
        self.views: list[ViewRecord] = []
        self.tabu: list = []  # poses (4, 4), or (pose, distance_m, angle_rad) regions
        self._captures: list[CapturedView] = []
        self._tsdf = None
        self._planner = None
        self._first_gain: float | None = None
        self._low_gain_streak = 0
        self._low_real_streak = 0
        self.realised_streak = int(cfg.get("planning", {}).get("realised_streak", 3))
        self._banned: list[np.ndarray] = []  # targets that turned out unmeasurable (the report's extra state)
        #: a view that adds less than this share of the surface it promised bans its target
        self.surprise_ratio = float(cfg.get("planning", {}).get("surprise_ratio", 0.2))
        self.surprise_distance_m = float(cfg.get("planning", {}).get("surprise_distance_m", 0.15))
        self.surprise_angle_rad = math.radians(float(cfg.get("planning", {}).get("surprise_angle_deg", 25.0)))
        self.surprises = 0
        self._last_novel_m2 = math.inf
        self._novel_near = None
        self._joint_path = 0.0
        self._tcp_path = 0.0
        self._planning_s = 0.0
        self._execution_s = 0.0
        self._motion_failures = 0
        self.termination_reason = ""
        #: benchmark hook: when set, a stopping rule that fires calls ``on_stop(self, reason)`` once and the loop goes
        #: on to the budget (so one run gives the self-terminated run as its prefix and the budget run); the view
        #: count at that moment is ``stop_view``
        self.on_stop: Callable | None = None
        #: benchmark hook: when set, every scored candidate pool calls ``on_scored(self, candidates, utilities)``
        #: (utilities of the feasible ones, in their order) before the choice
        self.on_scored: Callable | None = None
        self.stop_view: int | None = None

    # ------------------------------------------------------------------------------------ fusion
    def integrate(self, view: CapturedView) -> None:
        """Fuse one frame into both maps (and the TSDF); a user may feed frames from their own motion."""
        if not isinstance(view, CapturedView):
            raise InputError(f"integrate needs a CapturedView, got {type(view).__name__}")
        pose = np.asarray(view.camera_pose, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InputError("CapturedView.camera_pose must be a finite 4x4 matrix")
        index = len(self._captures)
        origin = pose[:3, 3]
        self.map.integrate(origin, view.points_m, view.normals, view.sigma_mm, view_id=index)
        self.planning_map.integrate(origin, view.points_m, view.normals, view.sigma_mm, view_id=index)
        self._captures.append(view)
        self._last_novel_m2 = self._novel_area_m2(view)
        if view.depth_m is not None and view.intrinsics is not None:
            tsdf = self._tsdf_volume()
            if tsdf is not None:
                tsdf.integrate(np.asarray(view.depth_m, dtype=np.float32), view.intrinsics, pose)
        if self.ground_truth is not None:
            self.ground_truth.add_points(view.points_m)

    def _tsdf_volume(self):
        if self._tsdf is None:
            try:
                from agiprobot_measurement.nbv.meshing import TSDFVolume
            except ImportError:  # the meshing module is optional for the loop itself
                return None
            self._tsdf = TSDFVolume(self.roi_min_m, self.roi_max_m, voxel_m=self.request.resolution_m)
        return self._tsdf

    def _novel_area_m2(self, view: CapturedView) -> float:
        """Surface the frame ``view`` added (m^2): its points with no earlier point within one novelty cell
        (about 1 mm, 26-neighbourhood), each weighted by the surface area a pixel covers there ((depth / f)^2 /
        cos incidence). Noise does not move a point by a cell, and a face first seen grazing still counts when a
        later view samples it densely. Points at the static scene (the fixture's top) do not count."""
        from scipy import ndimage

        if self._novel_near is None:
            extent = float(np.max(self.roi_max_m - self.roi_min_m))
            self._novel_cell_m = max(0.001, extent / 300.0)
            shape = tuple(int(n) for n in np.ceil((self.roi_max_m - self.roi_min_m) / self._novel_cell_m))
            self._novel_near = np.zeros(shape, dtype=bool)
            self._static_band = ndimage.binary_dilation(self.map.static, np.ones((3, 3, 3), dtype=bool), iterations=2)
        pts = np.asarray(view.points_m, dtype=float).reshape(-1, 3)
        if not len(pts):
            return 0.0
        near = self._novel_near
        idx = np.floor((pts - self.roi_min_m) / self._novel_cell_m).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.asarray(near.shape)), axis=1)
        fine = self.map.world_to_index(pts)
        ok &= np.all((fine >= 0) & (fine < np.asarray(self.map.shape)), axis=1)
        ok[ok] &= ~self._static_band[tuple(fine[ok].T)]
        idx, pts = idx[ok], pts[ok]
        normals = np.asarray(view.normals, dtype=float).reshape(-1, 3)[ok]
        novel = ~near[tuple(idx.T)]
        pose = np.asarray(view.camera_pose, dtype=float)
        ray = pts[novel] - pose[:3, 3]
        depth = ray @ pose[:3, 2]
        dist = np.linalg.norm(ray, axis=1)
        cos = np.abs(np.einsum("ij,ij->i", normals[novel], ray)) / np.maximum(dist, 1e-9)
        fx = float(
            getattr(view.intrinsics, "fx", 0.0) or self.station.scanner_model.intrinsics(self.station.resolution).fx
        )
        area = float(np.sum((depth / fx) ** 2 / np.maximum(cos, 0.2)))
        for offset in np.ndindex(3, 3, 3):
            shifted = np.clip(idx + (np.asarray(offset) - 1), 0, np.asarray(near.shape) - 1)
            near[tuple(shifted.T)] = True
        return area

    def banned_targets(self) -> np.ndarray:
        """Frontier targets found unmeasurable so far (K, 3) m: a view aimed at them saw far less than promised."""
        return np.asarray(self._banned).reshape(-1, 3)

    def object_seen(self) -> bool:
        return bool(self.map.full_mask().any())

    # ------------------------------------------------------------------------------------ planning
    def current_joints(self) -> np.ndarray:
        q = np.asarray(self.robot.current_joints(), dtype=float).reshape(-1)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise InternalError(f"the robot reports an invalid joint state {q.tolist()}")
        return q

    def evaluate(self, cands, gain_name: str):
        """Gains of the feasible candidates on the planning map: (ViewGains, feasible indices)."""
        from agiprobot_measurement.nbv.gains import evaluate_views

        idx = np.nonzero(cands.feasible)[0]
        return evaluate_views(self.planning_map, cands.poses[idx], self.view_model, gain=gain_name), idx

    def _choose(self, q_now: np.ndarray) -> tuple[_Choice | None, str, dict]:
        """The best next view, or (None, reason, stats)."""
        start = time.perf_counter()
        choice, reason, stats = self.policy.choose(q_now)
        stats["planning_s"] = time.perf_counter() - start
        return choice, reason, stats

    def next_best_view(self) -> tuple[np.ndarray | None, np.ndarray | None, float, str]:
        """Plan-only: (sensor pose world (4,4), joints (6,) rad, gain, reason) of the next best view from the current
        state, without moving; pose and joints are None when there is none (reason says why)."""
        q = self.current_joints()
        if not self._captures:
            choice = self._opening_choice(q)
            if choice is None:
                return None, None, 0.0, "frontier_exhausted"
            return choice.pose, choice.joints, 0.0, ""
        choice, reason, _ = self._choose(q)
        if choice is None:
            return None, None, 0.0, reason
        return choice.pose, choice.joints, float(choice.gain), ""

    def _opening_choice(self, q: np.ndarray, source: str = "sphere") -> _Choice | None:
        """The feasible pose of the view sphere whose elevation is nearest ``motion.opening_elevation_deg``, the
        cheapest move among equals (the report's a-priori opening view), aimed at ``motion.opening_height`` of the
        ROI's height. At 55 degrees it sees the top and the sides facing it (12 objects: median coverage after the
        first view 0.47, straight down 0.27); the scanning range (136 mm for model S) spans the ROI's lower part,
        where most parts are; taller ones are found by the search aimed higher."""
        aim = self.roi_center_m.copy()
        aim[2] = self.roi_min_m[2] + self.opening_height * (self.roi_max_m[2] - self.roi_min_m[2])
        cands = self.generator.sphere(aim)
        self.generator.filter(cands, self.planning_map, self.roi_min_m, self.roi_max_m, q, self.tabu)
        idx = np.nonzero(cands.feasible)[0]
        if not len(idx):
            return None
        # camera z . (-world z) = sin(elevation of the viewing direction below the horizon); within 0.01 of the
        # best, the cheaper move wins
        down = -cands.poses[idx, 2, 2]
        off = np.round(np.abs(down - math.sin(math.radians(self.opening_elevation_deg))), 2)
        cost = motion_time_s(q, cands.joints[idx], self.station.limits, self.velocity_scaling)
        order = np.lexsort((cost, off))
        i = idx[order[0]]
        return _Choice(cands.poses[i], cands.joints[i], 0.0, 0.0, 0.0, source, idx[order], int(order[0]))

    def _planner_factory(self):
        from agiprobot_measurement.motion.motion_planning import MotionPlanner

        if self._planner is None:
            self._planner = MotionPlanner(
                self.generator.checker,
                time_budget_s=max(self.planning_time_s, 0.2),
                simplify_time_s=self.simplify_time_s,
                seed=self.request.seed + 1,
                try_direct=False,  # plan_motion asks OMPL only once the straight move is found blocked
                best_of=self.ompl_best_of,
                max_attempts=self.ompl_best_of + 2,
            )
        return self._planner

    def plan_motion(self, q_from: np.ndarray, q_to: np.ndarray):
        """A collision-free trajectory against the scene and the not-yet-known-free region, or None: the straight
        joint move when it is free; otherwise the shorter (joint path, rad) of OMPL's simplified path and a straight
        move through a via pose (:meth:`_via_path`). OMPL's paths around the unknown region were twice the straight
        distance on average and up to 9 times (2258 vs 1115 rad, ours' budget runs on 12 objects); with the via
        moves 1.6 times."""
        from agiprobot_measurement.motion.motion_planning import collision_free_trajectory

        limits = self.station.limits
        checker = self.generator.checker
        straight = collision_free_trajectory(q_from, q_to, limits, checker, planner=None,
                                             velocity_scaling=self.velocity_scaling)  # fmt: skip
        if straight is not None:
            return straight
        via = self._via_path(q_from, q_to)
        direct_rad = float(np.abs(np.asarray(q_to) - np.asarray(q_from)).sum())
        if via is not None and via[1] <= VIA_ACCEPT_RATIO * direct_rad:
            return via[0]
        planned = collision_free_trajectory(
            q_from,
            q_to,
            limits,
            checker,
            planner=self._planner_factory,
            velocity_scaling=self.velocity_scaling,
            planning_time_s=self.planning_time_s,
            attempts=2,
            straight_first=False,
        )
        if via is None:
            return planned
        if planned is None:
            return via[0]
        return via[0] if via[1] < _path_length_rad(planned) else planned

    def _via_path(self, q_from: np.ndarray, q_to: np.ndarray):
        """(trajectory, joint path rad) of the shortest free straight move through via poses, or None. The vias are
        the poses the robot has already been at without collision (the home pose and the views so far; the
        known-free region only grows, so they stay free) and the moves around the ROI of :meth:`_orbit_waypoints`;
        the ``motion.via_poses`` shortest of the former and all of the latter are tried, shortest first."""
        from agiprobot_measurement.motion.motion_planning import interpolate_path
        from agiprobot_measurement.motion.time_parameterization import time_optimal_trajectory

        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        vias = np.asarray([self.home_rad, *(v.joints for v in self.views)], dtype=float)
        lengths = np.abs(vias - q_from).sum(axis=1) + np.abs(q_to - vias).sum(axis=1)
        routes = [
            np.asarray([q_from, vias[i], q_to]) for i in np.argsort(lengths, kind="stable")[: max(self.via_poses, 0)]
        ]
        routes += self._orbit_waypoints(q_from, q_to)
        routes.sort(key=lambda w: float(np.abs(np.diff(w, axis=0)).sum()))
        checker = self.generator.checker
        for waypoints in routes:
            if not checker.check_states(interpolate_path(waypoints, VIA_CHECK_STEP_RAD)).all():
                continue
            trajectory = time_optimal_trajectory(
                waypoints,
                self.station.limits,
                velocity_scaling_factor=self.velocity_scaling,
                acceleration_scaling_factor=self.velocity_scaling,
                max_waypoint_step_rad=0.01,
            )
            samples, _, _ = trajectory.sample(trajectory.dense_times(step_s=0.02, per_segment=2))
            if checker.check_states(samples).all():
                return trajectory, _path_length_rad(trajectory)
        return None

    def _orbit_waypoints(self, q_from: np.ndarray, q_to: np.ndarray) -> list[np.ndarray]:
        """Joint waypoints (rad) of moves around the ROI rather than through it, which the straight joint move
        between two views on opposite sides usually crosses:

        - retract the sensor along its optical axis by each of ``motion.orbit_retract_m``, move, approach;
        - pass one pose on the great circle between the two views (directions seen from the ROI centre) at its
          middle, or two at its thirds, at the larger standoff plus each of ``motion.orbit_radius_extra_m``, also
          raised by each of ``motion.orbit_lift_deg``, looking at the centre (the middle pose at each of four
          rolls, the thirds at the roll whose joints are nearest the joint interpolation there).

        IK is taken nearest the move's ends, resp. the joint interpolation at the pose's place on the move;
        unreachable poses are left out."""
        st = self.station
        ends = np.asarray([q_from, q_to], dtype=float)
        pose_a, pose_b = st.sensor_pose(ends)
        routes = []
        for d in self.orbit_retract_m:
            retracted = np.array([pose_a, pose_b])
            retracted[:, :3, 3] -= d * retracted[:, :3, 2]
            q, ok = st.ik.solve_nearest(retracted, ends)
            if np.all(ok):
                routes.append(np.asarray([q_from, q[0], q[1], q_to]))
        centre = 0.5 * (self.roi_min_m + self.roi_max_m)
        offsets = np.array([pose_a[:3, 3] - centre, pose_b[:3, 3] - centre])
        radii = np.linalg.norm(offsets, axis=1)
        if not self.orbit_radius_extra_m or np.any(radii < 1e-6):
            return routes
        u_a, u_b = offsets / radii[:, None]
        for extra in self.orbit_radius_extra_m:
            radius = float(radii.max()) + extra
            for lift in (0.0, *self.orbit_lift_deg):

                def around(t, lift=lift, radius=radius):
                    direction = raise_elevation(slerp_unit(u_a, u_b, t), math.radians(lift))
                    return self._orbit_joints(centre, direction, radius, (1 - t) * ends[0] + t * ends[1])

                routes += [np.asarray([q_from, q, q_to]) for q in around(0.5)]
                first, second = around(1.0 / 3.0), around(2.0 / 3.0)
                if first and second:
                    routes.append(np.asarray([q_from, first[0], second[0], q_to]))
        return routes

    def _orbit_joints(self, centre: np.ndarray, direction: np.ndarray, radius_m: float, seed: np.ndarray) -> list:
        """Joints (rad) of the sensor at ``centre + radius * direction`` looking at the centre, at four rolls, each
        the IK solution nearest ``seed``, nearest first (L1); the unreachable rolls are left out."""
        from agiprobot_measurement.nbv.candidates import poses_from_directions

        poses = poses_from_directions(centre, direction[None], radius_m, np.arange(4) * (math.pi / 2.0))
        q, ok = self.station.ik.solve_nearest(poses, np.broadcast_to(seed, (len(poses), 6)))
        q = q[ok]
        return list(q[np.argsort(np.abs(q - seed).sum(axis=1), kind="stable")])

    # ------------------------------------------------------------------------------------ loop
    def run(
        self,
        on_progress: Callable[[Progress], None] | None = None,
        should_cancel: Callable[[], bool] | None = None,
    ) -> ReconstructionResult:
        """Reconstruct (see the module docstring); never raises for a failed robot or camera: the result's reason
        is ``error`` and ``error`` says why (input errors of the request were raised at construction)."""
        self._t0 = time.perf_counter()
        self._on_progress = on_progress
        self._should_cancel = should_cancel or (lambda: False)
        if not self.request.execute:
            try:
                pose, joints, gain, reason = self.next_best_view()
            except InputError:
                raise
            except Exception as exc:  # as in the loop: a device or planner failure is the result's error
                return self._finish("error", f"{type(exc).__name__}: {exc}")
            result = self._finish("plan_only", reason)
            result.next_view_pose, result.next_view_joints, result.next_view_gain = pose, joints, gain
            return result
        try:
            reason = self._loop()
        except InputError:
            raise
        except Exception as exc:  # a device or planner failure ends the run with what was measured so far
            LOG.exception("reconstruction failed")
            return self._finish("error", f"{type(exc).__name__}: {exc}")
        return self._finish(reason, "")

    def _progress(self, phase: str, **kwargs) -> None:
        if self._on_progress is None:
            return
        view = len(self.views) + (0 if phase in ("finish",) else 1)
        self._on_progress(
            Progress(
                view=min(view, self.request.max_views),
                phase=phase,
                observed_area_m2=self.map.observed_surface_area_m2(),
                coverage=None if self.ground_truth is None else self.ground_truth.coverage(),
                progress=min(1.0, len(self.views) / self.request.max_views),
                **kwargs,
            )
        )

    def _budget_reason(self) -> str:
        if self._should_cancel():
            return "cancelled"
        if len(self.views) >= self.request.max_views:
            return "max_views"
        if time.perf_counter() - self._t0 >= self.request.max_time_s:
            return "max_time"
        if self._joint_path >= self.request.max_joint_path_rad:
            return "max_path"
        return ""

    def _loop(self) -> str:
        if self._should_cancel():
            return "cancelled"
        q = self.current_joints()
        if np.abs(q - self.home_rad).max() > 1e-3:
            self._progress("move")
            trajectory = self.plan_motion(q, self.home_rad)
            if trajectory is not None:
                self._execute(trajectory)
            else:
                LOG.warning("no collision-free motion to the home pose; starting from the current joints")
        # the opening view, then the a-priori search while the ROI stays empty
        self._progress("search")
        opening = self._opening_choice(self.current_joints())
        if opening is None:
            return "frontier_exhausted"
        if not self._visit(opening, planning_s=0.0, stats={}):
            return "frontier_exhausted"
        if not self.object_seen():
            searched = 0
            # the a-priori search: hemisphere views aimed alternately at the lower and the upper part of the ROI,
            # since the scanning range (136 mm for model S) is shorter than the ROI is high
            height = self.roi_max_m[2] - self.roi_min_m[2]
            aims = []
            for fraction in (0.25, 0.75):
                aim = self.roi_center_m.copy()
                aim[2] = self.roi_min_m[2] + fraction * height
                aims.append(self.generator.hemisphere(aim, 8))
            while not self.object_seen() and searched < self.search_views:
                reason = self._budget_reason()
                if reason:
                    return reason
                self._progress("search")
                q = self.current_joints()
                search = aims[searched % 2]
                # filter afresh from the current joints, and from the home pose when no view is reachable from here
                # (IK takes the branch nearest the seed joints: from an oblique opening view that branch can hit the
                # scene where the home pose's does not); views already taken stay out
                for seed in (q, self.home_rad):
                    search.feasible = search.reason != "visited"
                    search.reason[search.feasible] = ""
                    self.generator.filter(search, self.planning_map, self.roi_min_m, self.roi_max_m, seed, self.tabu)
                    idx = np.nonzero(search.feasible)[0]
                    if len(idx):
                        break
                searched += 1
                if not len(idx):
                    continue
                i = idx[np.argmin(motion_time_s(q, search.joints[idx], self.station.limits))]
                choice = _Choice(search.poses[i], search.joints[i], 0.0, 0.0, 0.0, "search", idx, 0)
                search.feasible[i] = False
                search.reason[i] = "visited"
                self._visit(choice, 0.0, {})
            if not self.object_seen():
                return "nothing_found"
        while True:
            reason = self._budget_reason()
            if reason:
                return reason
            self._progress("candidates")
            q = self.current_joints()
            choice, reason, stats = self._choose(q)
            if choice is None:
                return reason
            area = choice.new_area_m2 if choice.remaining_area_m2 is None else choice.remaining_area_m2
            gain = choice.gain if choice.remaining_gain is None else choice.remaining_gain
            new_area_mm2 = area * 1e6
            if self.policy.uses_stopping_rule:
                if self._first_gain is None:
                    self._first_gain = max(gain, 1e-12)
                relative = gain / self._first_gain
                # the rule: the best view promises less than the ignored detail, two iterations running; and, since
                # the prediction counts unknown space the scanner may not reach from there, also when the views taken
                # brought less than that ``realised_streak`` times running (each of those bans its target)
                threshold = self.request.min_gain_area_mm2
                self._low_gain_streak = self._low_gain_streak + 1 if new_area_mm2 < threshold else 0
                self._low_real_streak = self._low_real_streak + 1 if self._last_novel_m2 * 1e6 < threshold else 0
                if self.stop_view is None and (
                    self._low_gain_streak >= 2
                    or self._low_real_streak >= self.realised_streak
                    or relative < self.request.min_relative_gain
                ):
                    if self.on_stop is None:
                        return "gain_below_threshold"
                    # the benchmark's budget run: note where the rule fired and go on to the budget
                    self.stop_view = len(self.views)
                    self.on_stop(self, "gain_below_threshold")
            if not self._visit(choice, stats.get("planning_s", 0.0), stats):
                return "frontier_exhausted"

    def _visit(self, choice: _Choice, planning_s: float, stats: dict) -> bool:
        """Plan the motion to ``choice`` (falling back on the next candidates when it fails), move, capture, fuse.
        False when no candidate could be reached."""
        start = time.perf_counter()
        self._progress(
            "plan_motion",
            best_gain=float(choice.gain),
            relative_gain=float(choice.gain / self._first_gain) if self._first_gain else 1.0,
            candidates_total=int(stats.get("total", 0)),
            candidates_feasible=int(stats.get("feasible", 0)),
            next_view_pose=choice.pose,
        )
        q = self.current_joints()
        fallbacks = stats.get("fallbacks", [])
        options = [choice, *fallbacks]
        trajectory = None
        chosen = None
        for option in options[:5]:
            trajectory = self.plan_motion(q, option.joints)
            if trajectory is not None:
                chosen = option
                break
            self._motion_failures += 1
            self.tabu.append(option.pose)  # the report's "forbid this configuration"
        planning_s += time.perf_counter() - start
        self._planning_s += planning_s
        if chosen is None:
            return False
        self._progress("move", next_view_pose=chosen.pose, best_gain=float(chosen.gain))
        path_before = self._joint_path
        motion_s = self._execute(trajectory)
        self.tabu.append(chosen.pose)
        self._progress("capture")
        t = time.perf_counter()
        view = self.camera.capture()
        capture_s = time.perf_counter() - t
        self._progress("integrate")
        t = time.perf_counter()
        self.integrate(view)
        integrate_s = time.perf_counter() - t
        gained = self._last_novel_m2
        if gained < self.surprise_ratio * chosen.new_area_m2:
            # a surprise: the view saw far less than predicted (the unknown space it counted is out of the scanner's
            # reach from there); its target and the views around it are not tried again
            if chosen.target_m is not None:
                self._banned.append(np.asarray(chosen.target_m, dtype=float))
            self.tabu.append((np.asarray(chosen.pose), self.surprise_distance_m, self.surprise_angle_rad))
            self.surprises += 1
        record = ViewRecord(
            index=len(self.views),
            camera_pose=np.asarray(view.camera_pose, dtype=float),
            joints=self.current_joints(),
            gain=float(chosen.gain),
            utility=float(chosen.utility),
            candidates_total=int(stats.get("total", 0)),
            candidates_feasible=int(stats.get("feasible", 0)),
            rejections=dict(stats.get("rejections", {})),
            planning_s=planning_s,
            motion_s=motion_s,
            joint_path_rad=self._joint_path - path_before,
            observed_area_m2=self.map.observed_surface_area_m2(),
            coverage=None if self.ground_truth is None else self.ground_truth.coverage(),
            expected_new_area_m2=float(chosen.new_area_m2),
            new_area_m2=gained,
            source=chosen.source,
            points=len(view.points_m),
            capture_s=capture_s,
            integrate_s=integrate_s,
        )
        self.views.append(record)
        return True

    def _execute(self, trajectory) -> float:
        positions = np.asarray(trajectory.positions, dtype=float)
        t = time.perf_counter()
        self.robot.execute(trajectory)
        self._execution_s += time.perf_counter() - t
        if len(positions) >= 2:
            self._joint_path += _path_length_rad(trajectory)
            tcp = self.station.sensor_pose(positions)[:, :3, 3]
            self._tcp_path += float(np.linalg.norm(np.diff(tcp, axis=0), axis=1).sum())
        return float(trajectory.duration)

    def _finish(self, reason: str, error: str) -> ReconstructionResult:
        self.termination_reason = reason
        self._progress("finish")
        result = ReconstructionResult(
            termination_reason=reason,
            views=list(self.views),
            joint_path_rad=self._joint_path,
            tcp_path_m=self._tcp_path,
            planning_time_s=self._planning_s,
            execution_time_s=self._execution_s,
            observed_surface_area_m2=self.map.observed_surface_area_m2(),
            remaining_frontier_area_m2=self.map.frontier_area_m2(),
            coverage=None if self.ground_truth is None else self.ground_truth.coverage(),
            error=error,
            motion_failures=self._motion_failures,
            wall_time_s=time.perf_counter() - self._t0,
        )
        if self.request.output_dir and self._captures:
            try:
                files = self.save_outputs(self.request.output_dir, result)
            except OSError as exc:
                result.error = (result.error + "; " if result.error else "") + f"writing the outputs failed: {exc}"
                files = {}
            result.cloud_file = files.get("cloud", "")
            result.mesh_file = files.get("mesh", "")
            result.map_file = files.get("map", "")
            result.log_file = files.get("log", "")
        return result

    # ------------------------------------------------------------------------------------ outputs
    def save_outputs(self, output_dir, result: ReconstructionResult | None = None) -> dict[str, str]:
        """Write cloud.ply, map.npz (+ map.bt), mesh.ply and views.yaml into ``output_dir`` (created), each
        atomically; returns {kind: path}."""
        import yaml

        from agiprobot_measurement.common.files import atomic_write, atomic_write_text

        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files = {}
        cloud = out / "cloud.ply"
        if self.map.export_cloud_ply(cloud) > 0:
            files["cloud"] = str(cloud)
        files["map"] = str(self.map.save_npz(out / "map.npz"))
        if self.map.save_bt(out / "map.bt"):
            files["octomap"] = str(out / "map.bt")
        tsdf = self._tsdf
        if tsdf is not None:
            mesh = tsdf.mesh()
            if mesh is not None and len(mesh.faces):
                atomic_write(out / "mesh.ply", lambda tmp: mesh.export(str(tmp), file_type="ply"), suffix=".ply")
                files["mesh"] = str(out / "mesh.ply")
        log = {
            "method": self.request.method,
            "termination_reason": self.termination_reason or (result.termination_reason if result else ""),
            "request": {
                k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in self.request.__dict__.items()
                if k != "output_dir"
            },
            "roi_min_m": self.roi_min_m.tolist(),
            "roi_max_m": self.roi_max_m.tolist(),
            "views": [v.as_dict() for v in self.views],
        }
        if result is not None:
            log["result"] = {k: v for k, v in result.summary().items() if not k.endswith("_file")}
        log_path = out / "views.yaml"
        atomic_write_text(log_path, yaml.safe_dump(log, sort_keys=False, default_flow_style=None))
        files["log"] = str(log_path)
        return files
