"""Oracles of the 3D NBV benchmark: what planners that know the truth reach, and how well each gain ranks views.

:func:`oracle_views` solves the set cover of the observable points of a
:class:`~agiprobot_measurement.nbv.simulation.ground_truth.GroundTruth` over its feasible poses with the project's
:func:`~agiprobot_measurement.planning.cover.solve.solve_set_cover` (the lower bound on views) and gives the greedy
max-coverage order for the 90 / 95 % counts; :func:`oracle_path_curve` the coverage over the straight joint path of
a greedy planner that knows the truth, :func:`oracle_tour_curve` that of a set cover visited in the shortest tour; :class:`GainQuality` scores each gain's choice against the truly best view. :class:`TruthLoopPolicy` is the truth-aware greedy *inside* the loop (ours' pool, noise, fusion and
reachability; the choice by the true new observable points): the benchmark's ``oracle_loop`` methods.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, views_to
from agiprobot_measurement.nbv.volumetric.candidates import Candidates
from agiprobot_measurement.nbv.volumetric.gains import ExpectedSurfaceModel, expected_surface
from agiprobot_measurement.nbv.volumetric.policies.base import weighted_score
from agiprobot_measurement.nbv.volumetric.policies.ours import OursPolicy
from agiprobot_measurement.nbv.volumetric.tour import greedy_cover, order_tour
from agiprobot_measurement.planning.cover.solve import solve_set_cover
from agiprobot_measurement.sensors.phoxi.renderer import RayCaster, SceneGeometry

__all__ = [
    "ORACLE_LOOP_POOLS",
    "ORACLE_PATH_PLANNERS",
    "GainQuality",
    "TruthLoopPolicy",
    "oracle_path_curve",
    "oracle_tour_curve",
    "oracle_views",
]


def oracle_views(truth: GroundTruth, time_limit_s: float = 20.0) -> dict:
    """The set-cover oracle on the known truth: the project's set cover of the observable points over the feasible
    poses (``greedy`` and, within ``time_limit_s``, ``IP_basic``), and the greedy max-coverage curve (C(k) of the
    best k poses chosen greedily) for N90 / N95."""
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
    out["path_curves"]["tour"] = oracle_tour_curve(truth)
    return out


def _observable_matrix(truth: GroundTruth):
    """The visibility matrix (observable points x poses, CSC), or None when either is empty."""
    matrix = truth.visibility.matrix.tocsc()[truth.observable].tocsc()
    return None if matrix.shape[0] == 0 or matrix.shape[1] == 0 else matrix


#: coverage levels the truth-aware tour oracle plans for
TOUR_LEVELS = (0.90, 0.95, 0.98, 1.0)


def oracle_tour_curve(truth: GroundTruth, levels=TOUR_LEVELS, max_views: int = 14) -> list:
    """The truth-aware tour bound: per level, the greedy partial set cover of the observable points until the
    level (at most ``max_views`` poses; 1.0: all of them, or what that many poses reach), visited in the shortest
    open tour from the home pose over the poses' collision-free IK branches (straight L1 joint distance; exact for small plans,
    :func:`~agiprobot_measurement.nbv.volumetric.tour.order_tour`). Returns [(coverage reached, path rad), ...]
    sorted by coverage, each path the shortest of the tours reaching at least that coverage (the same shape as
    :func:`oracle_path_curve`'s, so a level is looked up the same way). A bound at these levels only: between
    them the next level's tour counts."""
    matrix = _observable_matrix(truth)
    if matrix is None:
        return []
    st, vis = truth.station, truth.visibility
    dense = np.asarray(matrix.todense(), dtype=bool).T  # (poses, points)
    home = np.asarray(st.home_rad, dtype=float)
    checker = st.collision_checker(with_part=True)
    points = []
    for level in levels:
        picked = greedy_cover(dense, dense.sum(axis=1).astype(float), cover_share=level, max_views=max_views)
        if not picked:
            continue
        solutions, valid = st.ik.solve_all(vis.poses[picked], home)
        branches = []
        for k, pose_index in enumerate(picked):
            mine = solutions[k][valid[k]]
            mine = mine[checker.check_states(mine)] if len(mine) else mine
            branches.append(mine if len(mine) else vis.joints[pose_index][None])
        path, _, _ = order_tour(home, branches, lambda q, qs: np.abs(np.atleast_2d(qs) - q).sum(axis=1))
        points.append((float(dense[picked].any(axis=0).mean()), float(path)))
    points.sort()
    return [(c, min(p for c2, p in points if c2 >= c)) for c, _ in points]


#: the truth-aware path planners of :func:`oracle_path_curve`: name -> per_rad_offset_rad (None: coverage first)
ORACLE_PATH_PLANNERS = {"coverage_first": None, "per_rad": 2.0}


def oracle_path_curve(truth: GroundTruth, per_rad_offset_rad: float | None = None, max_views: int = 30) -> list:
    """The coverage a planner that knows the truth reaches over the straight joint path (rad, summed over the
    joints) from the home pose: each step it takes the feasible ground-truth pose that newly covers the most
    observable points (``per_rad_offset_rad`` None; ties to the shorter move), or the most per rad of the move
    plus that offset. Poses are solved nearest the joints of the step before (the ground truth's own solution where
    that one collides). A bound, not a plan: the moves are straight (no detour around obstacles) and the gains
    exact. Returns [(coverage, path rad), ...] per view."""
    matrix = _observable_matrix(truth)
    if matrix is None:
        return []
    st, vis = truth.station, truth.visibility
    n = matrix.shape[0]
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
    """How well each gain ranks a run's candidates against the truth (a reconstructor's ``on_scored`` hook).

    At each scored pool -- the first ``max_decisions`` while the coverage is below ``max_coverage`` -- every
    feasible candidate's *true gain* is the share of the observable points it would newly measure (seen validly
    from its pose, not yet covered). Per gain (the policy's own utility, every metric of :data:`~agiprobot_measurement.nbv.volumetric.gain_names.GAIN_NAMES`
    on the planning map and the predicted-surface gain) the decision scores the true gain of that gain's best
    candidate over the best true gain of the pool: 1 when it would pick the truly best view. ``mixes`` ({name:
    {gain: weight}}) are scored on the same pools too, each as ours' score (the sum of the weighted gains, each
    divided by its best candidate's, without the motion cost), so that mixes compare on the same decisions.
    ``summary()`` is the mean over the decisions."""

    def __init__(
        self, truth: GroundTruth, max_decisions: int = 8, max_coverage: float = 0.97, mixes: dict | None = None
    ):
        self.truth = truth
        self.max_decisions = int(max_decisions)
        self.max_coverage = float(max_coverage)
        st = truth.station
        self._caster = RayCaster(SceneGeometry.concatenate([st.static_geometry, st.part_geometry]))
        self.mixes = {str(k): dict(v) for k, v in (mixes or {}).items()}
        self.decisions: list[dict[str, float]] = []

    def __call__(self, recon, cands, utilities: np.ndarray) -> None:
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


#: the benchmark's in-loop oracles: method name -> the pool its truth-aware choice is made from
ORACLE_LOOP_POOLS = {"oracle_loop": "ours", "oracle_loop_all": "all", "oracle_loop_gt": "gt"}


class TruthLoopPolicy(OursPolicy):
    """The truth-aware greedy inside ours' loop: the same opening view, sensor noise, fusion, filters
    (reachability, collision with the scene and the not-yet-known-free region, tabu) and motion as ours, but each
    view the feasible candidate that measures the most observable ground-truth points not yet covered (exact
    visibility from its pose, :meth:`GroundTruth.visible_from`). It runs to the budget (no stopping rule).

    ``pool``: ``ours`` -- ours' pool as ours scores it (frontier + sphere after the evaluation limit of
    ``planning.max_evaluated``); ``all`` -- every feasible candidate of ours' generator (no limit); ``gt`` -- the
    ground truth's dense pose set (the offline oracle's, three standoffs, aimed at the part's centre) through the
    same filter chain. Splits the gap between the offline truth-aware greedy and ours into pool, noise / fusion /
    reachability, and scoring."""

    name = "oracle_loop"
    uses_stopping_rule = False

    def __init__(self, context, planning, truth: GroundTruth, pool: str = "ours"):
        if pool not in ORACLE_LOOP_POOLS.values():
            raise InputError(f"unknown oracle pool {pool!r}; one of {', '.join(ORACLE_LOOP_POOLS.values())}")
        super().__init__(context, planning)
        self.truth = truth
        self.pool_kind = pool
        st = truth.station
        self._caster = RayCaster(SceneGeometry.concatenate([st.static_geometry, st.part_geometry]))

    def true_gain(self, poses: np.ndarray) -> np.ndarray:
        """Observable ground-truth points not yet covered that each pose (n, 4, 4) measures validly."""
        todo = self.truth.observable & ~self.truth.covered
        return np.array([np.count_nonzero(self.truth.visible_from(p, self._caster) & todo) for p in poses], float)

    def _candidates(self, q):
        c = self.context
        if self.pool_kind == "ours":
            cands, _ = self.pool(q)
            return cands
        if self.pool_kind == "all":
            cands, _ = c.generator.generate(c.planning_map, c.roi_min_m, c.roi_max_m, q, c.sources, c.tabu)
            return cands
        poses = self.truth.visibility.poses
        aim = np.broadcast_to(self.truth.station.part_mesh.bounding_box.centroid, (len(poses), 3)).copy()
        cands = Candidates(poses.copy(), aim, np.full(len(poses), -1), np.full(len(poses), "sphere", dtype=object))
        return c.generator.filter(cands, c.planning_map, c.roi_min_m, c.roi_max_m, q, c.tabu)

    def choose(self, q):
        cands = self._candidates(q)
        stats = self.stats(cands)
        idx = np.nonzero(cands.feasible)[0]
        if not len(idx):
            self.remember(cands, None)
            return None, "frontier_exhausted", stats
        gain = self.true_gain(cands.poses[idx])
        self.remember(cands, gain)
        if not np.any(gain > 0):
            return None, "frontier_exhausted", stats
        # no expected area: the oracle's views are never "surprises" (it knows what they see)
        choice, fallbacks = self.ranked(cands, idx, gain, gain, np.zeros(len(idx)))
        stats["fallbacks"] = fallbacks
        return choice, "", stats
