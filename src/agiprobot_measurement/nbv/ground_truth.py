"""Ground truth and metrics of the 3D NBV benchmark (issue 17, brief section 4.4); simulation only.

:class:`GroundTruth` samples the true part surface (about one point per ``spacing_m`` squared) and finds the
*observable* points: those the PhoXi measures validly from at least one pose of a dense pose set that is reachable
(closed-form IK within the joint limits) and collision-free against the TRUE scene (part included). A point counts
as measured from a pose when, as in the renderer's validity rules, it lies in the camera image and the scanning
range, in the projector's field of view, faces camera and projector, and neither the camera ray nor the projector
ray is blocked by the scene or the part (the robot itself is not modelled as an occluder here). The pose set:
Fibonacci directions around the part's centre at three standoffs within the scanning range, two rolls.

Metrics: coverage C (share of observable points with a fused point within ``tau_m``, default 2 mm) after each view,
its AUC over the first 10 views (PC-NBV: the mean of C(1..10), the last value carried forward), views to 90 / 95 %,
and the Chamfer distance of the fused cloud to the truth (accuracy: fused points to the true surface; completeness:
observable points to the fused cloud; Chamfer = their mean). :func:`oracle_views` solves the set cover of the
observable points over the feasible poses with the project's :func:`~agiprobot_measurement.planning.cover.solve.
solve_set_cover` (the lower bound on views) and gives the greedy max-coverage order for the 90 / 95 % counts.
Metres in, mm in the metric names that say so.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["GainQuality", "GroundTruth", "auc", "oracle_path_curve", "oracle_views", "simulate", "views_to"]


@dataclass
class _Visibility:
    poses: np.ndarray  # (P, 4, 4) feasible sensor poses
    joints: np.ndarray  # (P, 6)
    matrix: object  # scipy.sparse csc (points x poses) bool


class GroundTruth:
    """Observable ground truth of a :class:`~.station3d.SimulatedNBVStation`'s part (see the module docstring)."""

    def __init__(
        self,
        station,
        spacing_m: float = 0.002,
        directions: int = 200,
        standoffs: int = 3,
        rolls: int = 2,
        tau_m: float = 0.002,
        seed: int = 0,
        min_cos: float = 0.05,
    ):
        import trimesh

        if not (math.isfinite(spacing_m) and spacing_m > 0):
            raise InputError(f"spacing_m must be positive, got {spacing_m}")
        if not (math.isfinite(tau_m) and tau_m > 0):
            raise InputError(f"tau_m must be positive, got {tau_m}")
        self.station = station
        self.tau_m = float(tau_m)
        mesh = station.part_mesh
        count = int(min(400_000, max(1000, mesh.area / spacing_m**2)))
        points, faces = trimesh.sample.sample_surface_even(mesh, count, seed=seed)
        self.points_m = np.asarray(points, dtype=float)
        self.normals = np.asarray(mesh.face_normals[faces], dtype=float)
        self.min_cos = float(min_cos)
        start = time.perf_counter()
        self.visibility = self._visibility(directions, standoffs, rolls)
        self.seconds = time.perf_counter() - start
        seen = np.asarray(self.visibility.matrix.sum(axis=1)).reshape(-1) > 0
        self.observable = seen
        self.covered = np.zeros(len(self.points_m), dtype=bool)
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.points_m)

    # ------------------------------------------------------------------------------ visibility
    def _pose_set(self, directions: int, standoffs: int, rolls: int) -> np.ndarray:
        from agiprobot_measurement.nbv.candidates import fibonacci_sphere, poses_from_directions

        model = self.station.scanner_model
        lo, hi = (v / 1000.0 for v in model.scanning_range_mm)
        center = self.station.part_mesh.bounding_box.centroid
        dirs = fibonacci_sphere(directions)
        dirs = dirs[dirs[:, 2] > -0.3]
        margin = 0.2 * (hi - lo)
        distances = np.linspace(lo + margin, hi - margin, standoffs) if standoffs > 1 else [model.sweet_spot_mm / 1e3]
        roll_values = np.arange(rolls) * (math.pi / 2.0)
        targets = np.repeat(center[None], len(dirs), axis=0)
        return np.concatenate([poses_from_directions(targets, dirs, d, roll_values) for d in distances])

    def _visibility(self, directions: int, standoffs: int, rolls: int) -> _Visibility:
        from scipy import sparse

        from agiprobot_measurement.sensors.phoxi.renderer import RayCaster, SceneGeometry

        st = self.station
        poses = self._pose_set(directions, standoffs, rolls)
        q, ok = st.ik.solve_nearest(poses, st.home_rad)
        q, ok = np.atleast_2d(q), np.atleast_1d(ok)
        table = poses[:, 2, 3] > st.table_top_m + 0.05
        ok &= table
        idx = np.nonzero(ok)[0]
        if len(idx):
            free = st.collision_checker(with_part=True).check_states(q[idx])
            idx = idx[free]
        poses, q = poses[idx], q[idx]
        caster = RayCaster(SceneGeometry.concatenate([st.static_geometry, st.part_geometry]))
        rows, cols = [], []
        for j, pose in enumerate(poses):
            seen = self.visible_from(pose, caster)
            hit = np.nonzero(seen)[0]
            rows.append(hit)
            cols.append(np.full(len(hit), j))
        n = len(self.points_m)
        if rows:
            r, c = np.concatenate(rows), np.concatenate(cols)
        else:
            r, c = np.zeros(0, int), np.zeros(0, int)
        matrix = sparse.csc_matrix((np.ones(len(r), dtype=bool), (r, c)), shape=(n, len(poses)))
        return _Visibility(poses, q, matrix)

    def visible_from(self, pose: np.ndarray, caster) -> np.ndarray:
        """Which ground-truth points (N,) bool the scanner measures validly from sensor pose ``pose`` (world)."""
        model = self.station.scanner_model
        intr = model.intrinsics(self.station.resolution)
        rotation, origin = pose[:3, :3], pose[:3, 3]
        local = (self.points_m - origin) @ rotation
        z = local[:, 2]
        lo, hi = (v / 1000.0 for v in model.scanning_range_mm)
        ok = (z >= lo) & (z <= hi)
        u = intr.fx * local[:, 0] / np.maximum(z, 1e-9) + intr.cx
        v = intr.fy * local[:, 1] / np.maximum(z, 1e-9) + intr.cy
        ok &= (u >= -0.5) & (u <= intr.width - 0.5) & (v >= -0.5) & (v <= intr.height - 0.5)
        to_camera = origin - self.points_m
        dist_c = np.linalg.norm(to_camera, axis=1)
        ok &= np.einsum("ij,ij->i", self.normals, to_camera) > self.min_cos * dist_c
        projector = model.projector_pose()
        proj_world = pose @ projector
        p_origin = proj_world[:3, 3]
        to_proj = p_origin - self.points_m
        dist_p = np.linalg.norm(to_proj, axis=1)
        ok &= np.einsum("ij,ij->i", self.normals, to_proj) > self.min_cos * dist_p
        in_proj = (self.points_m - p_origin) @ proj_world[:3, :3]
        th, tv = (math.tan(math.radians(a) / 2.0) for a in model.projector_fov_deg)
        ok &= (in_proj[:, 2] > 0) & (np.abs(in_proj[:, 0]) <= th * in_proj[:, 2])
        ok &= np.abs(in_proj[:, 1]) <= tv * in_proj[:, 2]
        idx = np.nonzero(ok)[0]
        if not len(idx):
            return ok
        eps = 0.001  # a point does not occlude itself
        pts = self.points_m[idx]
        m = len(idx)
        starts = np.concatenate([np.broadcast_to(origin, (m, 3)), np.broadcast_to(p_origin, (m, 3))])
        dirs = np.concatenate([pts - origin, pts - p_origin])
        t_max = np.concatenate([1.0 - eps / dist_c[idx], 1.0 - eps / dist_p[idx]])
        blocked = caster.occluded(starts, dirs, t_max)
        ok[idx[blocked[:m] | blocked[m:]]] = False
        return ok

    # ------------------------------------------------------------------------------ coverage
    @property
    def n_observable(self) -> int:
        return int(self.observable.sum())

    def reset(self) -> None:
        self.covered[:] = False

    def add_points(self, points_m: np.ndarray) -> float:
        """Mark the ground-truth points within ``tau_m`` of the new fused points; returns the coverage."""
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        if len(points):
            from scipy.spatial import cKDTree

            todo = np.nonzero(~self.covered)[0]
            if len(todo):
                tree = cKDTree(points)
                d, _ = tree.query(self.points_m[todo], distance_upper_bound=self.tau_m)
                self.covered[todo[np.isfinite(d)]] = True
        return self.coverage()

    def coverage(self) -> float:
        """Share of the observable points covered."""
        n = self.n_observable
        return float((self.covered & self.observable).sum() / n) if n else 0.0

    def coverage_full(self) -> float:
        """Share of ALL surface points covered."""
        return float(self.covered.mean()) if len(self.covered) else 0.0

    def chamfer_mm(self, cloud_m: np.ndarray, max_points: int = 50_000, seed: int = 0) -> dict:
        """Accuracy (fused -> true surface), completeness (observable -> fused) and their mean, in mm."""
        import trimesh
        from scipy.spatial import cKDTree

        cloud = np.asarray(cloud_m, dtype=float).reshape(-1, 3)
        if not len(cloud):
            return {"accuracy_mm": math.inf, "completeness_mm": math.inf, "chamfer_mm": math.inf}
        rng = np.random.default_rng(seed)
        sample = cloud if len(cloud) <= max_points else cloud[rng.choice(len(cloud), max_points, replace=False)]
        _, dist, _ = trimesh.proximity.closest_point(self.station.part_mesh, sample)
        accuracy = float(np.mean(dist))
        obs = self.points_m[self.observable]
        d, _ = cKDTree(cloud).query(obs) if len(obs) else (np.zeros(0), None)
        completeness = float(np.mean(d)) if len(d) else 0.0
        return {
            "accuracy_mm": 1000.0 * accuracy,
            "completeness_mm": 1000.0 * completeness,
            "chamfer_mm": 500.0 * (accuracy + completeness),
        }


def auc(curve, k: int = 10) -> float:
    """Mean of C(1..k) with the last value carried forward (0 without views)."""
    c = list(curve)
    if not c:
        return 0.0
    c = (c + [c[-1]] * k)[:k]
    return float(np.mean(c))


def views_to(curve, level: float) -> int | None:
    """The first k (1-based) with C(k) >= level, or None."""
    for i, value in enumerate(curve):
        if value >= level:
            return i + 1
    return None


def oracle_views(truth: GroundTruth, time_limit_s: float = 20.0) -> dict:
    """The set-cover oracle on the known truth: the project's set cover of the observable points over the feasible
    poses (``greedy`` and, within ``time_limit_s``, ``IP_basic``), and the greedy max-coverage curve (C(k) of the
    best k poses chosen greedily) for N90 / N95."""
    from agiprobot_measurement.planning.cover.solve import solve_set_cover

    matrix = truth.visibility.matrix.tocsr()[truth.observable].tocsc()
    n = matrix.shape[0]
    out = {"poses": int(matrix.shape[1]), "observable_points": int(n)}
    if n == 0 or matrix.shape[1] == 0:
        out.update({"set_cover_views": None, "curve": [], "n90": None, "n95": None})
        return out
    greedy = solve_set_cover(matrix, "greedy")
    out["set_cover_views_greedy"] = int(greedy.n_selected)
    try:
        exact = solve_set_cover(matrix, "IP_basic", time_limit_s=time_limit_s)
        out["set_cover_views"] = int(exact.n_selected)
        out["set_cover_optimal"] = bool(exact.proven_optimal)
    except Exception as exc:  # the IP is a bound only; a solver failure leaves the greedy figure
        out["set_cover_views"] = int(greedy.n_selected)
        out["set_cover_error"] = str(exc)
    # greedy max coverage: each step the pose that covers most not-yet-covered points
    covered = np.zeros(n, dtype=bool)
    curve = []
    csr = matrix.tocsr()
    for _ in range(min(40, matrix.shape[1])):
        gain = np.asarray(matrix[~covered].sum(axis=0)).reshape(-1) if (~covered).any() else np.zeros(1)
        j = int(np.argmax(gain))
        if gain[j] <= 0:
            break
        covered |= np.asarray(csr[:, j].todense()).reshape(-1) > 0
        curve.append(float(covered.mean()))
        if covered.all():
            break
    out["curve"] = curve
    out["n90"] = views_to(curve, 0.90)
    out["n95"] = views_to(curve, 0.95)
    out["home_rad"] = [float(v) for v in truth.station.home_rad]
    out["path_curves"] = {
        name: oracle_path_curve(truth, per_rad_offset_rad=offset) for name, offset in ORACLE_PATH_PLANNERS.items()
    }
    return out


#: the truth-aware path planners of :func:`oracle_path_curve`: name -> per_rad_offset_rad (None: coverage first)
ORACLE_PATH_PLANNERS = {"coverage_first": None, "per_rad": 2.0}


def oracle_path_curve(truth: GroundTruth, per_rad_offset_rad: float | None = None, max_views: int = 30) -> list:
    """The coverage a planner that knows the truth reaches over the straight joint path (rad, summed over the
    joints) from the home pose: each step it takes the feasible ground-truth pose that newly covers the most
    observable points (``per_rad_offset_rad`` None; ties to the shorter move), or the most per rad of the move
    plus that offset. Poses are solved nearest the joints of the step before (the ground truth's own solution where
    that one collides). A bound, not a plan: the moves are straight (no detour around obstacles) and the gains
    exact. Returns [(coverage, path rad), ...] per view."""
    st = truth.station
    vis = truth.visibility
    matrix = vis.matrix.tocsc()[truth.observable].tocsc()
    n = matrix.shape[0]
    if n == 0 or matrix.shape[1] == 0:
        return []
    rows = matrix.tocsr()
    covered = np.zeros(n, dtype=bool)
    q = np.asarray(st.home_rad, dtype=float)
    path = 0.0
    curve = []
    checker = st.collision_checker(with_part=True)
    for _ in range(int(max_views)):
        joints, ok = st.ik.solve_nearest(vis.poses, np.broadcast_to(q, (len(vis.poses), 6)))
        ok[ok] = checker.check_states(joints[ok])
        # where the solution nearest q collides, the pose's own (checked) solution
        joints = np.where(ok[:, None], joints, vis.joints)
        move = np.abs(joints - q).sum(axis=1)
        gain = np.asarray(rows[~covered].sum(axis=0), dtype=float).reshape(-1)
        if gain.max() <= 0:
            break
        if per_rad_offset_rad is None:
            best = int(np.lexsort((move, -gain))[0])
        else:
            best = int(np.argmax(gain / (move + float(per_rad_offset_rad))))
        path += float(move[best])
        q = joints[best]
        covered[matrix[:, best].indices] = True
        curve.append((float(covered.mean()), path))
        if covered.all():
            break
    return curve


class GainQuality:
    """How well each gain ranks a run's candidates against the truth (a :meth:`Reconstructor.on_scored` hook).

    At each scored pool -- the first ``max_decisions`` while the coverage is below ``max_coverage`` -- every
    feasible candidate's *true gain* is the share of the observable points it would newly measure (seen validly
    from its pose, not yet covered). Per gain (the policy's own utility, every metric of :data:`.gains.GAIN_NAMES`
    on the planning map and the predicted-surface gain) the decision scores the true gain of that gain's best
    candidate over the best true gain of the pool: 1 when it would pick the truly best view. ``mixes`` ({name:
    {gain: weight}}) are scored on the same pools too, each as ours' score (the sum of the weighted gains, each
    divided by its best candidate's, without the motion cost), so that mixes compare on the same decisions.
    ``summary()`` is the mean over the decisions."""

    def __init__(
        self, truth: GroundTruth, max_decisions: int = 8, max_coverage: float = 0.97, mixes: dict | None = None
    ):
        from agiprobot_measurement.sensors.phoxi.renderer import RayCaster, SceneGeometry

        self.truth = truth
        self.max_decisions = int(max_decisions)
        self.max_coverage = float(max_coverage)
        st = truth.station
        self._caster = RayCaster(SceneGeometry.concatenate([st.static_geometry, st.part_geometry]))
        self.mixes = {str(k): dict(v) for k, v in (mixes or {}).items()}
        self.decisions: list[dict[str, float]] = []

    def __call__(self, recon, cands, utilities: np.ndarray) -> None:
        from agiprobot_measurement.nbv.baselines import weighted_score
        from agiprobot_measurement.nbv.gains import ExpectedSurfaceModel, expected_surface

        truth = self.truth
        if len(self.decisions) >= self.max_decisions or truth.coverage() >= self.max_coverage:
            return
        idx = np.nonzero(cands.feasible)[0]
        todo = truth.observable & ~truth.covered
        true_gain = np.array([(truth.visible_from(cands.poses[i], self._caster) & todo).sum() for i in idx], float)
        best = float(true_gain.max()) if len(true_gain) else 0.0
        if best <= 0:
            return
        gains, _ = recon.evaluate(cands, "report")
        model = getattr(recon.policy, "model", None) or ExpectedSurfaceModel()
        scores = {"utility": utilities, **gains.all_gains}
        scores["expected_surface"], _ = expected_surface(recon.planning_map, cands.poses[idx], recon.view_model, model)
        for name, weights in self.mixes.items():
            scores[name] = weighted_score(scores, weights, len(idx))
        self.decisions.append(
            {name: float(true_gain[int(np.argmax(values))]) / best for name, values in scores.items()}
        )

    def summary(self) -> dict[str, float]:
        """Mean share of the best true gain per gain over the decisions (empty without decisions)."""
        if not self.decisions:
            return {}
        return {name: float(np.mean([d[name] for d in self.decisions])) for name in self.decisions[0]}


def simulate(
    station,
    request,
    ground_truth=None,
    on_progress=None,
    should_cancel=None,
    chamfer: bool = True,
    budget_run: bool = False,
    on_scored=None,
) -> dict:
    """One reconstruction on the simulated station (a fresh robot at the home pose and camera; the ground truth's
    coverage is reset): the result plus the benchmark's metrics as a JSON-ready summary. ``on_scored``: the
    reconstructor's hook called with every scored candidate pool (e.g. a :class:`GainQuality`)."""
    from agiprobot_measurement.nbv.reconstruction import Reconstructor
    from agiprobot_measurement.nbv.station3d import SimulatedPhoXiCamera, SimulatedRobot

    robot = SimulatedRobot(station)
    camera = SimulatedPhoXiCamera(station, robot, first_frame_index=1000 * int(request.seed))
    if ground_truth is not None:
        ground_truth.reset()
    recon = Reconstructor(robot, camera, request, station=station, ground_truth=ground_truth)
    recon.on_scored = on_scored
    stop = {}
    if budget_run:
        # the stopping rule only notes where it fired (the self-terminated run is the prefix up to there)
        def on_stop(rec, reason):
            stop.update({"view": len(rec.views), "reason": reason})
            if ground_truth is not None:
                stop["coverage"] = float(ground_truth.coverage())
                stop["coverage_full_surface"] = float(ground_truth.coverage_full())
                if chamfer:
                    stop.update(ground_truth.chamfer_mm(rec.map.raw.xyz_m))

        recon.on_stop = on_stop
    result = recon.run(on_progress=on_progress, should_cancel=should_cancel)
    summary = result.summary()
    summary["method"] = request.method
    summary["view_log"] = [v.as_dict() for v in result.views]
    summary["planning_s_per_view"] = [float(v.planning_s) for v in result.views[1:]]
    summary["motion_time_s"] = float(sum(v.motion_s for v in result.views))
    summary["true_collisions"] = int(robot.true_collisions)
    summary["surprises"] = int(recon.surprises)
    summary["render_s"] = [round(float(s), 4) for s in camera.render_s]
    if budget_run:
        summary["stop"] = stop  # empty: the rule never fired before the budget (or another reason ended the run)
    if ground_truth is not None:
        curve = [float(v.coverage) for v in result.views]
        summary["coverage_curve"] = curve
        summary["auc10"] = auc(curve, 10)
        summary["n90"] = views_to(curve, 0.90)
        summary["n95"] = views_to(curve, 0.95)
        summary["coverage_full_surface"] = ground_truth.coverage_full()
        summary["observable_points"] = ground_truth.n_observable
        if chamfer:
            summary.update(ground_truth.chamfer_mm(recon.map.raw.xyz_m))
    return summary
