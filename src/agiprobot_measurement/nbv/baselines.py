"""View selection policies of the 3D NBV loop: ours, the volumetric metrics and the baselines (issue 17, 4.4).

Every policy works on the same candidate pool and filter chain (:mod:`.candidates`) and the same planning map;
:meth:`Policy.choose` returns the next view (with fallbacks for a failed motion) or the reason there is none.

- :class:`OursPolicy` (``ours``): frontier + sphere candidates; a weighted sum of PhoXi-aware gains, each normalised
  by its best candidate (``planning.ours_weights`` of config/nbv.yaml: the report gain -- frontier voxels seen,
  weighted by perpendicularity -- plus the rear-side-voxel and proximity-count metrics), all from one ray traversal;
  utility ``G exp(-lambda C)`` with C the estimated joint-move time (s).
- :class:`MetricPolicy` (one of :data:`~.gains.GAIN_NAMES`): rpg's utility ``G / sum G - w C / sum C``; the
  benchmark runs them with ``w = 0`` (rpg's default).
- :class:`RandomPolicy` (``random``): uniform over the feasible candidates, seeded; stops only on budgets.
- :class:`HemispherePolicy` (``hemisphere6/12/24``): a fixed hemisphere at the sweet spot, elevations 15-75 deg,
  visited nearest-first, infeasible views dropped; done when the list is (``frontier_exhausted``).
- :class:`Report3DPolicy` (``report3d``): the report's strategy in 3D: the frontier target nearest the sensor
  (GetNearestPP), views perpendicular to its predicted surface, scored V x K x P (the report gain, i.e. visible
  candidates x Kolmost, times a motion factor); ends when no target can be measured.

The set-cover oracle (the lower bound on views) is offline: :func:`~.ground_truth.oracle_views`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = [
    "HemispherePolicy",
    "MetricPolicy",
    "OursPolicy",
    "Policy",
    "RandomPolicy",
    "Report3DPolicy",
    "ViewChoice",
    "make_policy",
    "motion_time_s",
]

#: how many next-best alternatives a choice carries for a failed motion
FALLBACKS = 4


def motion_time_s(q_from: np.ndarray, q_to: np.ndarray, limits, velocity_scaling: float = 1.0) -> np.ndarray:
    """Estimated duration (s) of synchronised joint moves from ``q_from`` (6,) to each of ``q_to`` (N, 6): the
    slowest joint's trapezoidal profile at the scaled velocity and acceleration limits."""
    dq = np.abs(np.atleast_2d(q_to) - np.asarray(q_from)[None, :])
    v = np.asarray(limits.max_velocity, dtype=float) * velocity_scaling
    a = np.asarray(limits.max_acceleration, dtype=float) * velocity_scaling
    cruise = dq > v * v / a
    t = np.where(cruise, dq / v + v / a, 2.0 * np.sqrt(dq / a))
    return t.max(axis=1)


@dataclass
class ViewChoice:
    """A chosen view: sensor pose (world), joints (rad), its gain / utility / expected new area (m^2)."""

    pose: np.ndarray
    joints: np.ndarray
    gain: float
    utility: float
    new_area_m2: float
    source: str
    order: np.ndarray  # fallbacks: indices into the feasible candidates, best first
    index: int
    target_m: np.ndarray | None = None  # the frontier target it aims at (None: sphere, hemisphere, search)
    #: what the stopping rule compares (None: this view's gain / new area): the best expected new surface (m^2)
    #: and gain over all evaluated candidates, i.e. the predicted surface still to be seen from anywhere
    remaining_area_m2: float | None = None
    remaining_gain: float | None = None


def _choice(recon, cands, i: int, gain: float, utility: float, new_area: float):
    target = cands.targets_m[i] if cands.source[i] == "frontier" else None
    return ViewChoice(cands.poses[i], cands.joints[i], float(gain), float(utility), float(new_area), str(cands.source[i]),
                   np.zeros(0, int), int(i), target)  # fmt: skip


def weighted_score(terms: dict, weights: dict, n: int) -> np.ndarray:
    """Ours' score of ``n`` candidates: the sum of ``weight x term / the term's best candidate's`` over ``weights``
    ({term name: weight}), each term an (n,) array of ``terms``."""
    score = np.zeros(n)
    for name, weight in weights.items():
        values = np.asarray(terms[name], dtype=float)
        score += float(weight) * values / max(float(values.max()), 1e-12)
    return score


#: how ours applies its motion weight lambda over a run (config/nbv.yaml planning.cost_schedule)
COST_SCHEDULES = ("constant", "remaining_surface")


class Policy:
    """Base: the candidate pool and the bookkeeping every policy shares."""

    name = "policy"
    uses_stopping_rule = True

    def __init__(self, recon):
        self.recon = recon

    def pool(self, q: np.ndarray, sources: str | None = None):
        r = self.recon
        sources = sources or r.request.sources
        targets = r.generator.targets(r.planning_map, r.banned_targets()) if "frontier" in sources else None
        cands, targets = r.generator.generate(
            r.planning_map, r.roi_min_m, r.roi_max_m, q, sources, r.tabu, targets=targets
        )
        limit_evaluated(cands, targets, r.max_evaluated, r.rng)
        return cands, targets

    def feasible_pool(self, q: np.ndarray):
        """(candidates, stats) of the pool at joints ``q``; the candidates are None (and the pool remembered
        without utilities) when none is feasible."""
        cands, _ = self.pool(q)
        stats = self.stats(cands)
        if not cands.feasible.any():
            self.remember(cands, None)
            return None, stats
        return cands, stats

    def stats(self, cands) -> dict:
        return {"total": cands.total, "feasible": int(cands.feasible.sum()), "rejections": cands.rejections()}

    def remember(self, cands, utilities_feasible: np.ndarray | None) -> None:
        utilities = np.full(len(cands), np.nan)
        if utilities_feasible is not None:
            utilities[cands.feasible] = utilities_feasible
            if self.recon.on_scored is not None:
                self.recon.on_scored(self.recon, cands, np.asarray(utilities_feasible, dtype=float))
        self.recon.candidates_last = [cands.poses, utilities, cands.reason.copy()]

    def ranked(self, cands, idx, gains, utilities, new_area) -> tuple:
        order = np.argsort(-utilities, kind="stable")
        best = order[0]
        choice = _choice(self.recon, cands, idx[best], gains[best], utilities[best], new_area[best])
        fallbacks = [
            _choice(self.recon, cands, idx[j], gains[j], utilities[j], new_area[j]) for j in order[1 : 1 + FALLBACKS]
        ]
        return choice, fallbacks

    def choose(self, q: np.ndarray):
        raise NotImplementedError


class OursPolicy(Policy):
    """The report's method in 3D: frontier targets (growth / candidate voxels with the PCA predicted surface),
    candidate views perpendicular to it filtered by the sphere of visibility, scored by the weighted terms of
    config/nbv.yaml ``planning.ours_weights`` (each normalised by its best candidate; the default mixes rpg's
    proximity count, average entropy and rear side voxel, the mix whose best candidate came closest to the truly
    best view, ``bench_nbv.py --gain-quality``), times the motion factor Pohyb ``exp(-lambda C)`` (lambda scaled by
    :meth:`cost_factor`, config ``planning.cost_schedule``). The expected newly
    seen surface of the predicted-surface model (:func:`~.gains.expected_surface`: camera and projector rays clear
    and in range, perpendicularity) ranks the fallbacks and drives the stopping rule; it is a score term only when
    the weights name it (as the only term it chose worse views on the benchmark objects)."""

    name = "ours"
    #: the score: each term normalised by its best candidate (config/nbv.yaml planning.ours_weights); the name
    #: ``expected_surface`` is the predicted-surface gain, the others are :data:`~.gains.GAIN_NAMES`
    default_weights = (("expected_surface", 1.0),)

    def __init__(self, recon):
        super().__init__(recon)
        from agiprobot_measurement.common.config import non_negative, positive
        from agiprobot_measurement.nbv.gains import GAIN_NAMES, ExpectedSurfaceModel

        planning = recon.station.config.get("planning", {})
        self.weights = dict(planning.get("ours_weights", dict(self.default_weights)))
        unknown = sorted(set(self.weights) - {*GAIN_NAMES, "expected_surface"})
        if unknown:
            raise InputError(
                f"planning.ours_weights: unknown gain(s) {unknown}; known: expected_surface, {', '.join(GAIN_NAMES)}"
            )
        self.model = ExpectedSurfaceModel.from_config(planning.get("expected_surface"))
        self.cost_schedule = str(planning.get("cost_schedule", "constant"))
        if self.cost_schedule not in COST_SCHEDULES:
            raise InputError(
                f"planning.cost_schedule: unknown {self.cost_schedule!r}; known: {', '.join(COST_SCHEDULES)}"
            )
        # (1 - A / A1)^power: a higher power lets the motion count later in the run
        self.cost_schedule_power = positive(planning.get("cost_schedule_power", 1.0), "planning.cost_schedule_power")
        # seconds of motion cost per rad of straight joint path (summed over the joints), added to the move time
        self.cost_s_per_rad = non_negative(
            planning.get("cost_joint_path_s_per_rad", 0.0), "planning.cost_joint_path_s_per_rad"
        )
        self.first_expected_area_m2 = None

    def cost_factor(self, expected_area_m2: float) -> float:
        """The share of lambda applied now. ``constant``: 1. ``remaining_surface``: 1 - A / A1, with A the most
        new surface any candidate is expected to see and A1 that at the first planned view (clipped to [0, 1]):
        while most of the part is still unseen, the view that sees most is worth its motion; the motion counts
        fully once little is left to gain."""
        if self.cost_schedule == "constant":
            return 1.0
        if self.first_expected_area_m2 is None:
            self.first_expected_area_m2 = expected_area_m2
        if self.first_expected_area_m2 <= 0:
            return 1.0
        share_seen = float(np.clip(1.0 - expected_area_m2 / self.first_expected_area_m2, 0.0, 1.0))
        return share_seen**self.cost_schedule_power

    def choose(self, q):
        from agiprobot_measurement.nbv.gains import expected_surface

        r = self.recon
        cands, stats = self.feasible_pool(q)
        if cands is None:
            return None, "frontier_exhausted", stats
        idx = np.nonzero(cands.feasible)[0]
        exp_gain, exp_area = expected_surface(r.planning_map, cands.poses[idx], r.view_model, self.model)
        terms = {"expected_surface": exp_gain}
        if set(self.weights) - {"expected_surface"}:
            g, _ = r.evaluate(cands, "report")
            terms.update(g.all_gains)
        score = weighted_score(terms, self.weights, len(idx))
        cost = _motion_cost(r, q, cands.joints[idx])
        if self.cost_s_per_rad > 0:
            cost = cost + self.cost_s_per_rad * np.abs(cands.joints[idx] - q).sum(axis=1)
        factor = self.cost_factor(float(exp_area.max()))
        utilities = score * np.exp(-r.request.cost_weight * factor * cost)
        self.remember(cands, utilities)
        if not np.any(exp_area > 0):
            return None, "frontier_exhausted", stats
        choice, fallbacks = self.ranked(cands, idx, exp_gain, utilities, exp_area)
        # the stopping rule looks at the predicted surface left for any candidate, not at the chosen view only
        for c in (choice, *fallbacks):
            c.remaining_area_m2 = float(exp_area.max())
            c.remaining_gain = float(exp_gain.max())
        stats["fallbacks"] = fallbacks
        return choice, "", stats


class MetricPolicy(Policy):
    """One volumetric metric with rpg's utility."""

    def __init__(self, recon, gain: str):
        super().__init__(recon)
        self.name = gain

    def choose(self, q):
        from agiprobot_measurement.nbv.gains import utility

        r = self.recon
        cands, stats = self.feasible_pool(q)
        if cands is None:
            return None, "frontier_exhausted", stats
        g, idx = r.evaluate(cands, self.name)
        cost = _motion_cost(r, q, cands.joints[idx])
        utilities = utility(g.gain, cost, "rpg", r.request.cost_weight)
        self.remember(cands, utilities)
        if not np.any(g.gain > 0):
            return None, "frontier_exhausted", stats
        choice, fallbacks = self.ranked(cands, idx, g.gain, utilities, g.new_surface_area_m2)
        stats["fallbacks"] = fallbacks
        return choice, "", stats


class RandomPolicy(Policy):
    name = "random"
    uses_stopping_rule = False

    def choose(self, q):
        r = self.recon
        cands, _ = self.pool(q)
        stats = self.stats(cands)
        idx = np.nonzero(cands.feasible)[0]
        self.remember(cands, None)
        if not len(idx):
            return None, "frontier_exhausted", stats
        picks = r.rng.permutation(idx)[: 1 + FALLBACKS]
        zeros = np.zeros(len(picks))
        choice, fallbacks = self.ranked(cands, picks, zeros, -np.arange(len(picks), dtype=float), zeros)
        stats["fallbacks"] = fallbacks
        return choice, "", stats


class HemispherePolicy(Policy):
    uses_stopping_rule = False

    def __init__(self, recon, n: int):
        super().__init__(recon)
        self.name = f"hemisphere{n}"
        self.plan = recon.generator.hemisphere(recon.roi_center_m, n)
        self.done = np.zeros(len(self.plan), dtype=bool)

    def choose(self, q):
        r = self.recon
        plan = self.plan.subset(~self.done)
        plan.feasible[:] = True
        plan.reason[:] = ""
        r.generator.filter(plan, r.planning_map, r.roi_min_m, r.roi_max_m, q, r.tabu)
        stats = self.stats(plan)
        self.remember(plan, None)
        idx = np.nonzero(plan.feasible)[0]
        if not len(idx):
            return None, "frontier_exhausted", stats
        cost = _motion_cost(r, q, plan.joints[idx])
        zeros = np.zeros(len(idx))
        choice, _ = self.ranked(plan, idx, zeros, -cost, zeros)
        # the plan's views are visited once, whether their motion succeeds or not
        remaining = np.nonzero(~self.done)[0]
        self.done[remaining[choice.index]] = True
        stats["fallbacks"] = []
        return choice, "", stats


class Report3DPolicy(Policy):
    name = "report3d"
    uses_stopping_rule = False
    motion_scale_s = 10.0  # P = exp(-C / motion_scale_s)

    def choose(self, q):
        r = self.recon
        gen = r.generator
        targets = gen.targets(r.planning_map, r.banned_targets())
        sensor = r.station.sensor_pose(q)[:3, 3]
        if len(targets) == 0:
            return None, "frontier_exhausted", {"total": 0, "feasible": 0, "rejections": {}}
        order = np.argsort(np.linalg.norm(targets.points_m - sensor, axis=1))
        total, rejections = 0, {}
        for t in order:
            one = type(targets)(
                targets.points_m[t : t + 1],
                targets.normals[t : t + 1],
                targets.sizes[t : t + 1],
                targets.tangents[t : t + 1],
            )
            saved = gen.config
            try:
                # perpendicular to the predicted surface, or nearly (the report's Kolmost tolerates obliquity)
                gen.config = _replace(saved, cone_angles_rad=(0.0, math.radians(20.0)), towards_unseen=False)
                cands = gen.frontier(r.planning_map, one)
            finally:
                gen.config = saved
            gen.filter(cands, r.planning_map, r.roi_min_m, r.roi_max_m, q, r.tabu)
            total += cands.total
            for k, v in cands.rejections().items():
                rejections[k] = rejections.get(k, 0) + v
            if not cands.feasible.any():
                continue
            g, idx = r.evaluate(cands, "report")
            if not np.any(g.gain > 0):
                continue
            cost = _motion_cost(r, q, cands.joints[idx])
            utilities = g.gain * np.exp(-cost / self.motion_scale_s)
            self.remember(cands, utilities)
            choice, fallbacks = self.ranked(cands, idx, g.gain, utilities, g.new_surface_area_m2)
            stats = {"total": total, "feasible": int(cands.feasible.sum()), "rejections": rejections}
            stats["fallbacks"] = fallbacks
            return choice, "", stats
        return None, "frontier_exhausted", {"total": total, "feasible": 0, "rejections": rejections}


def limit_evaluated(cands, targets, max_n: int, rng) -> None:
    """Keep at most ``max_n`` feasible candidates for the (costly) gain evaluation, the others marked
    ``not_evaluated``: frontier candidates by a cheap prior (their target's size x how squarely they face it), the
    global sphere's spread at random over a quarter of the slots, so the opening game stays in the pool."""
    idx = np.nonzero(cands.feasible)[0]
    if max_n <= 0 or len(idx) <= max_n:
        return
    frontier = idx[cands.source[idx] == "frontier"]
    other = idx[cands.source[idx] != "frontier"]
    n_other = min(len(other), max(max_n // 4, max_n - len(frontier)))
    keep_other = rng.choice(other, n_other, replace=False) if n_other < len(other) else other
    n_front = max_n - len(keep_other)
    if len(frontier) > n_front:
        t = cands.target_index[frontier]
        view = cands.poses[frontier, :3, 2]
        facing = -np.einsum("ij,ij->i", view, targets.normals[t])
        prior = targets.sizes[t] * np.maximum(facing, 0.0) + rng.uniform(0.0, 1e-6, len(frontier))
        frontier = frontier[np.argsort(-prior)[:n_front]]
    drop = np.ones(len(cands), dtype=bool)
    drop[frontier] = False
    drop[keep_other] = False
    cands.reject(drop, "not_evaluated")


def _replace(config, **changes):
    import dataclasses

    return dataclasses.replace(config, **changes)


def _motion_cost(recon, q, joints) -> np.ndarray:
    return motion_time_s(q, joints, recon.station.limits, recon.velocity_scaling)


def make_policy(method: str, recon) -> Policy:
    """The policy of a request's method name."""
    from agiprobot_measurement.nbv.gains import GAIN_NAMES

    if method == "ours":
        return OursPolicy(recon)
    if method in GAIN_NAMES:
        return MetricPolicy(recon, method)
    if method == "random":
        return RandomPolicy(recon)
    if method.startswith("hemisphere"):
        n = int(method[len("hemisphere") :] or 12)
        return HemispherePolicy(recon, n)
    if method == "report3d":
        return Report3DPolicy(recon)
    raise InputError(f"unknown method {method!r}")
