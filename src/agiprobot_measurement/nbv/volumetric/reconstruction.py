"""The 3D next-best-view loop on the station: an unknown part reconstructed by the PhoXi on the flange.

:class:`Reconstructor` runs, with any :class:`~.interfaces.NBVRobot` and :class:`~.interfaces.NBVCamera` (the
simulation of :mod:`agiprobot_measurement.nbv.simulation.station3d` or the ROS node's):

1. the home pose (config/nbv.yaml ``motion.home_rad``); the opening view: the feasible pose of the global view
   sphere around the ROI nearest ``motion.opening_elevation_deg`` (90: the most top-down one); if the ROI is still
   empty, an a-priori search of ``motion.search_views`` hemisphere views; if still nothing (or no view of the ROI
   can be reached, or the candidates run out before any surface was seen), the result is ``nothing_found``;
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
normalised by its best candidate, discounted by the motion time (G exp(-lambda C)), with the surprise rule below; any of :data:`~.gain_names.GAIN_NAMES` with rpg's utility G/sum G - w C/sum C; the baselines of
:mod:`.policies.baselines` (``random``, ``hemisphere6/12/24``, ``report3d``), each chosen by name from
:mod:`.policies.registry`. Outputs: :mod:`.outputs`, atomically into ``output_dir``.

The collaborators are handed in or built from the station: the settings (:class:`~.settings.NBVSettings`, read once
from the station's configuration), the motion :class:`~agiprobot_measurement.motion.routing.Router` (straight, via
poses, around the ROI, OMPL) and the policy, which sees only a :class:`~.policies.base.PolicyContext`.
World frame, metres, rad; areas in m^2 except the request's ``min_gain_area_mm2``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np

from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.motion.motion_planning import MotionPlanner
from agiprobot_measurement.motion.routing import Router, RouteSettings, path_length_rad
from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError
from agiprobot_measurement.motion.trajectory import TrajectoryError
from agiprobot_measurement.nbv.volumetric.candidates import CandidateConfig, CandidateGenerator, poses_from_directions
from agiprobot_measurement.nbv.volumetric.gains import ViewModel
from agiprobot_measurement.nbv.volumetric.interfaces import CapturedView, NBVCamera, NBVRobot
from agiprobot_measurement.nbv.volumetric.meshing import TSDFVolume
from agiprobot_measurement.nbv.volumetric.novelty import NoveltyTracker
from agiprobot_measurement.nbv.volumetric.outputs import attach_outputs, save_outputs
from agiprobot_measurement.nbv.volumetric.policies.base import PolicyContext, ViewChoice, motion_time_s
from agiprobot_measurement.nbv.volumetric.policies.registry import make_policy
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.results import Progress, ReconstructionResult, ViewRecord
from agiprobot_measurement.nbv.volumetric.settings import MotionSettings, NBVSettings
from agiprobot_measurement.nbv.volumetric.station3d import NBVStation
from agiprobot_measurement.nbv.volumetric.stopping import StoppingRule
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

__all__ = ["Reconstructor", "policy_context", "region_of_interest", "station_maps", "station_router"]

LOG = logging.getLogger(__name__)
#: rolls (rad) of the poses looking at the ROI centre that the moves around it pass
ORBIT_ROLLS_RAD = np.arange(4) * (math.pi / 2.0)


def station_router(station, checker, motion: MotionSettings, seed: int) -> Router:
    """The loop's router on ``station``: ``checker`` (the candidate generator's, with the not-yet-known-free
    region), OMPL set up only when a move needs it (best of ``motion.ompl_best_of``, seeded), the via and orbit
    moves of ``motion``."""

    def planner():
        return MotionPlanner(
            checker,
            time_budget_s=max(motion.planning_time_s, 0.2),
            simplify_time_s=motion.simplify_time_s,
            seed=seed + 1,
            try_direct=False,  # the router asks OMPL only once the straight move is found blocked
            best_of=motion.ompl_best_of,
            max_attempts=motion.ompl_best_of + 2,
        )

    def look_poses(centre, direction, radius_m):
        return poses_from_directions(centre, direction[None], radius_m, ORBIT_ROLLS_RAD)

    settings = RouteSettings(
        velocity_scaling=motion.velocity_scaling,
        planning_time_s=motion.planning_time_s,
        via_poses=motion.via_poses,
        orbit_retract_m=motion.orbit_retract_m,
        orbit_radius_extra_m=motion.orbit_radius_extra_m,
        orbit_lift_deg=motion.orbit_lift_deg,
    )
    return Router(checker, station.limits, planner, settings, arm=station, look_poses=look_poses)


def region_of_interest(station, request: ReconstructionRequest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(min, max, centre) m of the request's ROI, the station's default where the request leaves it open."""
    center, size = station.default_roi()
    if request.roi_center_m is not None:
        center = request.roi_center_m
    if request.roi_size_m is not None:
        size = request.roi_size_m
    center, half = np.asarray(center, dtype=float), np.asarray(size, dtype=float) / 2.0
    return center - half, center + half, center


def station_maps(station, request: ReconstructionRequest, roi_min_m, roi_max_m) -> tuple[VoxelMap, VoxelMap]:
    """(output map, planning map) over the ROI at the request's resolutions, the station's static scene set."""
    maps = [
        VoxelMap(roi_min_m, roi_max_m, MapConfig(resolution_m=res, planning_resolution_m=request.planning_resolution_m))
        for res in (request.resolution_m, request.planning_resolution_m)
    ]
    static = station.static_mesh()
    for grid in maps:
        grid.set_static(static)
    return maps[0], maps[1]


def policy_context(recon: Reconstructor, motion: MotionSettings) -> PolicyContext:
    """What the policies of ``recon`` may read of it."""
    shared = ("generator", "planning_map", "view_model", "roi_min_m", "roi_max_m", "roi_center_m", "tabu", "rng",
              "max_evaluated", "banned_targets")  # fmt: skip
    return PolicyContext(
        **{name: getattr(recon, name) for name in shared},
        limits=recon.station.limits,
        sensor_pose=recon.station.sensor_pose,
        sources=recon.request.sources,
        cost_weight=recon.request.cost_weight,
        velocity_scaling=motion.velocity_scaling,
        on_pool=recon.remember_pool,
    )


class Reconstructor:
    """The loop (see the module docstring). ``station``: an :class:`~.station3d.NBVStation` (None: built from the
    configuration); ``ground_truth``: the simulation's ground truth, for coverage per view. ``settings`` (None: read
    from the station's configuration), ``router`` and ``policy_factory(context, planning)`` (None: the request's
    method from the registry) are the collaborators a caller may hand in."""

    def __init__(self, robot: NBVRobot, camera: NBVCamera, request: ReconstructionRequest, station=None,
                 ground_truth=None, gain_rays: tuple[int, int] | None = None, max_evaluated: int | None = None,
                 settings: NBVSettings | None = None, router: Router | None = None,
                 policy_factory: Callable | None = None):  # fmt: skip
        if not isinstance(request, ReconstructionRequest):
            raise InputError(f"request must be a ReconstructionRequest, got {type(request).__name__}")
        self.robot = robot
        self.camera = camera
        self.request = request
        self.station = station if station is not None else NBVStation()
        self.ground_truth = ground_truth
        self.settings = settings if settings is not None else NBVSettings.from_config(self.station.config)
        planning, motion = self.settings.planning, self.settings.motion
        self.roi_min_m, self.roi_max_m, self.roi_center_m = region_of_interest(self.station, request)
        self.map, self.planning_map = station_maps(self.station, request, self.roi_min_m, self.roi_max_m)
        self.candidate_config = CandidateConfig.from_settings(self.settings.candidates, self.station.scanner_model)
        self.generator = CandidateGenerator(self.station, self.candidate_config, seed=request.seed)
        rays = gain_rays or planning.gain_rays
        self.view_model = ViewModel.from_scanner_model(self.station.scanner_model, int(rays[0]), int(rays[1]))
        self.max_evaluated = int(planning.max_evaluated if max_evaluated is None else max_evaluated)
        self.router = router or station_router(self.station, self.generator.checker, motion, request.seed)
        self.home_rad = np.asarray(self.station.home_rad, dtype=float)
        self.rng = np.random.default_rng(request.seed)
        self.candidates_last: list = []  # (poses (N,4,4), utilities (N,), reasons (N,)) of the last evaluation
        self.views: list[ViewRecord] = []
        self.tabu: list = []  # poses (4, 4), or (pose, distance_m, angle_rad) regions
        self.context = policy_context(self, motion)
        self.policy = (policy_factory or (lambda c, p: make_policy(request.method, c, p)))(self.context, planning)
        self._captures: list[CapturedView] = []
        self._tsdf = None
        self.stopping = StoppingRule(request.min_gain_area_mm2, request.min_relative_gain, planning.realised_streak,
                                     planning.budget_growth_share, planning.growth_window)  # fmt: skip
        fx = self.station.scanner_model.intrinsics(self.station.resolution).fx
        self.novelty = NoveltyTracker(self.roi_min_m, self.roi_max_m, self.map, fx)
        self._banned: list[np.ndarray] = []  # targets that turned out unmeasurable (the report's extra state)
        self.surprises = 0
        self._last_novel_m2 = math.inf
        self._last_growth_m2 = math.inf  # surface the last frame added to the output map (newly full voxels, m^2)
        self._full_before: np.ndarray | None = None
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

    def remember_pool(self, cands, utilities_feasible: np.ndarray | None) -> None:
        """The policy's pool: kept as ``candidates_last`` (the node publishes it) and passed to ``on_scored``."""
        utilities = np.full(len(cands), np.nan)
        if utilities_feasible is not None:
            utilities[cands.feasible] = utilities_feasible
            if self.on_scored is not None:
                self.on_scored(self, cands, np.asarray(utilities_feasible, dtype=float))
        self.candidates_last = [cands.poses, utilities, cands.reason.copy()]

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
        self._last_novel_m2 = self.novelty.add(view)
        full = self.map.full_mask()
        before = self._full_before
        added = int(full.sum()) if before is None else int(np.count_nonzero(full & ~before))
        self._last_growth_m2 = added * self.map.resolution_m**2
        self._full_before = full.copy()
        if view.depth_m is not None and view.intrinsics is not None:
            tsdf = self._tsdf_volume()
            if tsdf is not None:
                tsdf.integrate(np.asarray(view.depth_m, dtype=np.float32), view.intrinsics, pose)
        if self.ground_truth is not None:
            self.ground_truth.add_points(view.points_m)

    def _tsdf_volume(self):
        if self._tsdf is None:
            self._tsdf = TSDFVolume(self.roi_min_m, self.roi_max_m, voxel_m=self.request.resolution_m)
        return self._tsdf

    def banned_targets(self) -> np.ndarray:
        """Frontier targets found unmeasurable so far (K, 3) m: a view aimed at them saw far less than promised."""
        return np.asarray(self._banned).reshape(-1, 3)

    def object_seen(self) -> bool:
        return bool(self.map.full_mask().any())

    def _unless_nothing_seen(self, reason: str) -> str:
        """``reason``, or ``nothing_found`` when it is ``frontier_exhausted`` and the ROI never held a surface."""
        return "nothing_found" if reason == "frontier_exhausted" and not self.object_seen() else reason

    # ------------------------------------------------------------------------------------ planning
    def current_joints(self) -> np.ndarray:
        q = np.asarray(self.robot.current_joints(), dtype=float).reshape(-1)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise InternalError(f"the robot reports an invalid joint state {q.tolist()}")
        return q

    def evaluate(self, cands, gain_name: str):
        """Gains of the feasible candidates on the planning map: (ViewGains, feasible indices)."""
        return self.context.evaluate(cands, gain_name)

    def _choose(self, q_now: np.ndarray) -> tuple[ViewChoice | None, str, dict]:
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
                return None, None, 0.0, "frontier_exhausted" if self.object_seen() else "nothing_found"
            return choice.pose, choice.joints, 0.0, ""
        choice, reason, _ = self._choose(q)
        if choice is None:
            return None, None, 0.0, self._unless_nothing_seen(reason)
        return choice.pose, choice.joints, float(choice.gain), ""

    def _opening_choice(self, q: np.ndarray, source: str = "sphere") -> ViewChoice | None:
        """The feasible pose of the view sphere whose elevation is nearest ``motion.opening_elevation_deg``, the
        cheapest move among equals (the report's a-priori opening view), aimed at ``motion.opening_height`` of the
        ROI's height. An oblique opening view sees the top and the sides facing it; the scanning range spans the
        ROI's lower part, where most parts are; taller ones are found by the search aimed higher."""
        motion = self.settings.motion
        aim = self.roi_center_m.copy()
        aim[2] = self.roi_min_m[2] + motion.opening_height * (self.roi_max_m[2] - self.roi_min_m[2])
        cands = self.generator.sphere(aim)
        self.generator.filter(cands, self.planning_map, self.roi_min_m, self.roi_max_m, q, self.tabu)
        idx = np.nonzero(cands.feasible)[0]
        if not len(idx):
            return None
        # camera z . (-world z) = sin(elevation of the viewing direction below the horizon); within 0.01 of the
        # best, the cheaper move wins
        down = -cands.poses[idx, 2, 2]
        off = np.round(np.abs(down - math.sin(math.radians(motion.opening_elevation_deg))), 2)
        cost = motion_time_s(q, cands.joints[idx], self.station.limits, motion.velocity_scaling)
        order = np.lexsort((cost, off))
        i = idx[order[0]]
        return ViewChoice(cands.poses[i], cands.joints[i], 0.0, 0.0, 0.0, source, idx[order], int(order[0]))

    def plan_motion(self, q_from: np.ndarray, q_to: np.ndarray):
        """A collision-free trajectory against the scene and the not-yet-known-free region, or None: the router's
        route with the poses the robot has already been at (the home pose and the views so far; the known-free
        region only grows, so they stay free) as vias and the moves around the ROI."""
        vias = [self.home_rad, *(v.joints for v in self.views)]
        try:
            return self.router.route(q_from, q_to, vias, centre=0.5 * (self.roi_min_m + self.roi_max_m))
        except (TimeParameterizationError, TrajectoryError) as exc:
            # one move whose spline cannot be timed within the limits (e.g. a wrist near its limit) must not end
            # the run: the view counts as unreachable (the caller bans it and tries the next one)
            LOG.warning("no timed motion to %s: %s", np.round(np.asarray(q_to, dtype=float), 3).tolist(), exc)
            return None

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
        if opening is None or not self._visit(opening, planning_s=0.0, stats={}):
            # no view of the ROI can be reached (a ROI out of the robot's reach): nothing_found unless seen before
            return self._unless_nothing_seen("frontier_exhausted")
        if not self.object_seen():
            reason = self._search()
            if reason:
                return reason
        while True:
            reason = self._budget_reason()
            if reason:
                return reason
            self._progress("candidates")
            q = self.current_joints()
            choice, reason, stats = self._choose(q)
            if choice is None:
                return self._unless_nothing_seen(reason)
            area = choice.new_area_m2 if choice.remaining_area_m2 is None else choice.remaining_area_m2
            gain = choice.gain if choice.remaining_gain is None else choice.remaining_gain
            if self.policy.uses_stopping_rule:
                fires = self.stopping.update(
                    gain,
                    area,
                    self._last_novel_m2,
                    self.map.observed_surface_area_m2(),
                    self._last_growth_m2,
                    self.request.max_views - len(self.views),
                )
                if self.stop_view is None and fires:
                    if self.on_stop is None:
                        return "gain_below_threshold"
                    # the benchmark's budget run: note where the rule fired and go on to the budget
                    self.stop_view = len(self.views)
                    self.on_stop(self, "gain_below_threshold")
            if not self._visit(choice, stats.get("planning_s", 0.0), stats):
                return "frontier_exhausted"

    def _search(self) -> str:
        """The a-priori search while the ROI stays empty; the reason to stop, or "" once the object is seen."""
        searched = 0
        # the a-priori search: hemisphere views aimed alternately at the lower and the upper part of the ROI,
        # since the scanning range (136 mm for model S) is shorter than the ROI is high
        height = self.roi_max_m[2] - self.roi_min_m[2]
        aims = []
        for fraction in (0.25, 0.75):
            aim = self.roi_center_m.copy()
            aim[2] = self.roi_min_m[2] + fraction * height
            aims.append(self.generator.hemisphere(aim, 8))
        while not self.object_seen() and searched < self.settings.motion.search_views:
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
            choice = ViewChoice(search.poses[i], search.joints[i], 0.0, 0.0, 0.0, "search", idx, 0)
            search.feasible[i] = False
            search.reason[i] = "visited"
            self._visit(choice, 0.0, {})
        return "" if self.object_seen() else "nothing_found"

    def _visit(self, choice: ViewChoice, planning_s: float, stats: dict) -> bool:
        """Plan the motion to ``choice`` (falling back on the next candidates when it fails), move, capture, fuse.
        False when no candidate could be reached."""
        start = time.perf_counter()
        self._progress(
            "plan_motion",
            best_gain=float(choice.gain),
            relative_gain=float(choice.gain / first) if (first := self.stopping.first_gain) else 1.0,
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
        planning = self.settings.planning
        if gained < planning.surprise_ratio * chosen.new_area_m2:
            # a surprise: the view saw far less than predicted (the unknown space it counted is out of the scanner's
            # reach from there); its target and the views around it are not tried again
            if chosen.target_m is not None:
                self._banned.append(np.asarray(chosen.target_m, dtype=float))
            self.tabu.append((np.asarray(chosen.pose), planning.surprise_distance_m, planning.surprise_angle_rad))
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
            self._joint_path += path_length_rad(trajectory)
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
            attach_outputs(result, lambda: self.save_outputs(self.request.output_dir, result))
        return result

    def save_outputs(self, output_dir, result: ReconstructionResult | None = None) -> dict[str, str]:
        """Write the outputs of :mod:`.outputs` into ``output_dir`` (created), each atomically; returns {kind:
        path}."""
        return save_outputs(output_dir, self.map, self._tsdf, self.request, self.roi_min_m, self.roi_max_m,
                            self.views, self.termination_reason, result)  # fmt: skip
