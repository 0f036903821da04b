"""Ground truth and metrics of the 3D NBV loop in simulation.

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
observable points to the fused cloud; Chamfer = their mean). The benchmark's oracles live in
``benchmarks/nbv_oracles.py``.
Metres in, mm in the metric names that say so.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.station3d import SimulatedPhoXiCamera, SimulatedRobot
from agiprobot_measurement.nbv.volumetric.candidates import fibonacci_sphere, poses_from_directions
from agiprobot_measurement.nbv.volumetric.reconstruction import Reconstructor
from agiprobot_measurement.sensors.phoxi.renderer import RayCaster, SceneGeometry

__all__ = ["GroundTruth", "auc", "simulate", "views_to"]


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


def simulate(
    station,
    request,
    ground_truth=None,
    on_progress=None,
    should_cancel=None,
    chamfer: bool = True,
    budget_run: bool = False,
    on_scored=None,
    policy_factory=None,
) -> dict:
    """One reconstruction on the simulated station (a fresh robot at the home pose and camera; the ground truth's
    coverage is reset): the result plus the benchmark's metrics as a JSON-ready summary. ``on_scored``: the
    reconstructor's hook called with every scored candidate pool (e.g. a :class:`GainQuality`); ``policy_factory``:
    the reconstructor's (None: the request's method)."""
    robot = SimulatedRobot(station)
    camera = SimulatedPhoXiCamera(station, robot, first_frame_index=1000 * int(request.seed))
    if ground_truth is not None:
        ground_truth.reset()
    recon = Reconstructor(
        robot, camera, request, station=station, ground_truth=ground_truth, policy_factory=policy_factory
    )
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
        summary["stop_history"] = list(recon.stopping.history)
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
