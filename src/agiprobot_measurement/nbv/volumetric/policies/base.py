"""What every view-selection policy shares: the narrow :class:`PolicyContext` it reads, the candidate pool, the
ranked choice with its fallbacks, and the estimated motion time.

A policy never sees the reconstructor: the loop hands it a :class:`PolicyContext` (the candidate generator, the
planning map, the region of interest, the tabu list, the random stream, the request's sources and motion weight,
the joint limits) and a callback that records each scored pool. :meth:`Policy.choose` returns the next view (with
fallbacks for a failed motion) or the reason there is none.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.nbv.volumetric.gains import evaluate_views

__all__ = [
    "FALLBACKS",
    "Policy",
    "PolicyContext",
    "ViewChoice",
    "limit_evaluated",
    "motion_time_s",
    "weighted_score",
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


@dataclass
class PolicyContext:
    """What a policy may read of the running loop. ``tabu`` is the loop's own list (it grows as the loop visits
    poses); ``banned_targets()`` the frontier targets found unmeasurable so far; ``on_pool(candidates, utilities)``
    records each pool (utilities of the feasible candidates in their order, or None when unscored)."""

    generator: object  # candidates.CandidateGenerator
    planning_map: object  # voxel_map.VoxelMap
    view_model: object  # gains.ViewModel
    limits: object  # the station's joint limits
    sensor_pose: Callable[[np.ndarray], np.ndarray]
    roi_min_m: np.ndarray
    roi_max_m: np.ndarray
    roi_center_m: np.ndarray
    tabu: list
    rng: np.random.Generator
    max_evaluated: int
    sources: str
    cost_weight: float
    velocity_scaling: float
    banned_targets: Callable[[], np.ndarray]
    on_pool: Callable[[object, np.ndarray | None], None]

    def evaluate(self, cands, gain_name: str):
        """Gains of the feasible candidates on the planning map: (ViewGains, feasible indices)."""
        idx = np.nonzero(cands.feasible)[0]
        return evaluate_views(self.planning_map, cands.poses[idx], self.view_model, gain=gain_name), idx

    def motion_cost(self, q: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Estimated joint-move times (s) from ``q`` to each of ``joints``."""
        return motion_time_s(q, joints, self.limits, self.velocity_scaling)


def weighted_score(terms: dict, weights: dict, n: int) -> np.ndarray:
    """Ours' score of ``n`` candidates: the sum of ``weight x term / the term's best candidate's`` over ``weights``
    ({term name: weight}), each term an (n,) array of ``terms``."""
    score = np.zeros(n)
    for name, weight in weights.items():
        values = np.asarray(terms[name], dtype=float)
        score += float(weight) * values / max(float(values.max()), 1e-12)
    return score


def _choice(cands, i: int, gain: float, utility: float, new_area: float) -> ViewChoice:
    target = cands.targets_m[i] if cands.source[i] == "frontier" else None
    return ViewChoice(cands.poses[i], cands.joints[i], float(gain), float(utility), float(new_area), str(cands.source[i]),
                      np.zeros(0, int), int(i), target)  # fmt: skip


class Policy(ABC):
    """Base: the candidate pool and the bookkeeping every policy shares. A subclass implements :meth:`choose`."""

    name = "policy"
    uses_stopping_rule = True

    def __init__(self, context: PolicyContext):
        self.context = context

    @abstractmethod
    def choose(self, q: np.ndarray) -> tuple[ViewChoice | None, str, dict]:
        """(the next view or None, the reason when None, stats: total / feasible / rejections / fallbacks)."""

    def pool(self, q: np.ndarray, sources: str | None = None):
        c = self.context
        sources = sources or c.sources
        targets = c.generator.targets(c.planning_map, c.banned_targets()) if "frontier" in sources else None
        cands, targets = c.generator.generate(
            c.planning_map, c.roi_min_m, c.roi_max_m, q, sources, c.tabu, targets=targets
        )
        limit_evaluated(cands, targets, c.max_evaluated, c.rng)
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
        self.context.on_pool(cands, utilities_feasible)

    def ranked(self, cands, idx, gains, utilities, new_area, first: int | None = None) -> tuple:
        """(the choice, the fallbacks) by utility, ``first`` (an index into ``idx``) taken first when given."""
        order = np.argsort(-utilities, kind="stable")
        if first is not None:
            order = np.concatenate([[first], order[order != first]])
        best = order[0]
        choice = _choice(cands, idx[best], gains[best], utilities[best], new_area[best])
        fallbacks = [_choice(cands, idx[j], gains[j], utilities[j], new_area[j]) for j in order[1 : 1 + FALLBACKS]]
        return choice, fallbacks


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
