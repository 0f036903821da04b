"""Ours: the report's method in 3D, scored by a weighted sum of PhoXi-aware gains and discounted by the motion."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.volumetric.gains import (
    ExpectedSurfaceModel,
    ViewModel,
    evaluate_views,
    expected_surface,
    undersampled_surface,
)
from agiprobot_measurement.nbv.volumetric.policies.base import Policy, PolicyContext, weighted_score
from agiprobot_measurement.nbv.volumetric.sampling import SamplingModel, SamplingState
from agiprobot_measurement.nbv.volumetric.settings import PlanningSettings

__all__ = ["OursPolicy"]


class OursPolicy(Policy):
    """The report's method in 3D: frontier targets (growth / candidate voxels with the PCA predicted surface),
    candidate views perpendicular to it filtered by the sphere of visibility, scored by the weighted terms of
    config/nbv.yaml ``planning.ours_weights`` (each normalised by its best candidate; the default mixes rpg's
    proximity count, average entropy and rear side voxel, the mix whose best candidate came closest to the truly
    best view in the benchmark's gain-quality check), times the motion factor Pohyb ``exp(-lambda C)`` (lambda
    scaled by :meth:`cost_factor`, config ``planning.cost_schedule``). The expected newly seen surface of the
    predicted-surface model (:func:`~agiprobot_measurement.nbv.volumetric.gains.expected_surface`: camera and
    projector rays clear and in range, perpendicularity) ranks the fallbacks and drives the stopping rule; it is a
    score term only when the weights name it."""

    name = "ours"
    #: the score when the configuration names none: the name ``expected_surface`` is the predicted-surface gain,
    #: ``undersampled_surface`` the seen surface sampled too sparsely (:func:`.gains.undersampled_surface`), the
    #: others are :data:`~agiprobot_measurement.nbv.volumetric.gain_names.GAIN_NAMES`
    default_weights = (("expected_surface", 1.0),)
    own_terms = ("expected_surface", "undersampled_surface")

    def __init__(self, context: PolicyContext, planning: PlanningSettings):
        super().__init__(context)
        weights = planning.ours_weights
        self.weights = dict(weights if weights is not None else dict(self.default_weights))
        unknown = sorted(set(self.weights) - {*GAIN_NAMES, *self.own_terms})
        if unknown:
            raise InputError(
                f"planning.ours_weights: unknown gain(s) {unknown}; known: {', '.join([*self.own_terms, *GAIN_NAMES])}"
            )
        self.open_border_weight = planning.open_border_weight
        self.undersampled_fade_power = planning.undersampled_fade_power
        self.sampling = SamplingState(SamplingModel(planning.coverage_radius_m, planning.sample_neighbours))
        self.model = ExpectedSurfaceModel.from_config(planning.expected_surface)
        self.cost_schedule = planning.cost_schedule
        self.cost_schedule_power = planning.cost_schedule_power
        self.cost_s_per_rad = planning.cost_joint_path_s_per_rad
        self.first_expected_area_m2 = None
        self.growth = GrowthTrack()
        self.fallback_below_mm2 = planning.coverage_fallback_below_mm2
        self.fallback_reach_vox = planning.coverage_fallback_reach_vox
        self.exact_evaluated = planning.exact_evaluated
        self.coarse_ray_divisor = planning.coarse_ray_divisor
        self.near_best_share = planning.near_best_share
        self.scores = PoolScores(np.zeros(0), np.zeros(0))

    def cost_factor(self, expected_area_m2: float) -> float:
        """The share of lambda applied now. ``constant``: 1. ``remaining_surface``: 1 - A / A1, with A the most
        new surface any candidate is expected to see and A1 that at the first planned view (clipped to [0, 1]):
        while most of the part is still unseen, the view that sees most is worth its motion; the motion counts
        fully once little is left to gain. ``map_growth``: 1 - g / g_max, with g the planning map's surface growth
        (full voxels x resolution^2) over the last two views and g_max the largest such growth so far (the
        predicted surface A hardly falls over a run: it counts unknown space no view measures). Either to the
        power ``planning.cost_schedule_power``."""
        if self.cost_schedule == "constant":
            return 1.0
        if self.cost_schedule == "map_growth":
            return self.growth.saturation(self.context.planning_map) ** self.cost_schedule_power
        if self.first_expected_area_m2 is None:
            self.first_expected_area_m2 = expected_area_m2
        if self.first_expected_area_m2 <= 0:
            return 1.0
        share_seen = float(np.clip(1.0 - expected_area_m2 / self.first_expected_area_m2, 0.0, 1.0))
        return share_seen**self.cost_schedule_power

    def scored_pool(self, q):
        """(candidates, stats, feasible indices, expected gain, expected new area (m^2), utilities) of the pool at
        joints ``q``, the pool remembered with its utilities; the candidates are None when none is feasible."""
        c = self.context
        cands, stats = self.feasible_pool(q)
        if cands is None:
            return None, stats, None, None, None, None
        idx = np.nonzero(cands.feasible)[0]
        exp_gain, exp_area = expected_surface(c.planning_map, cands.poses[idx], c.view_model, self.model)
        cost = c.motion_cost(q, cands.joints[idx])
        if self.cost_s_per_rad > 0:
            cost = cost + self.cost_s_per_rad * np.abs(cands.joints[idx] - q).sum(axis=1)
        discount = np.exp(-c.cost_weight * self.cost_factor(float(exp_area.max())) * cost)
        exact = len(idx) <= self.exact_evaluated or self.exact_evaluated <= 0
        view_model = c.view_model if exact else coarse_view(c.view_model, self.coarse_ray_divisor)
        utilities, undersampled = self._score(cands.poses[idx], exp_gain, view_model, float(exp_area.max()))
        utilities *= discount
        if not exact:
            # coarse to fine: the best by the coarse bundle are scored with the full one (each term normalised
            # within them) and the choice is among them; the others keep their coarse utility, ranked below
            top = np.argsort(-utilities, kind="stable")[: self.exact_evaluated]
            fine, undersampled[top] = self._score(cands.poses[idx[top]], exp_gain[top], c.view_model,
                                                  float(exp_area.max()))  # fmt: skip
            fine *= discount[top]
            rest = np.ones(len(idx), dtype=bool)
            rest[top] = False
            if rest.any():
                floor = float(fine.min())
                utilities[rest] = floor * utilities[rest] / max(float(utilities[rest].max()), 1e-12) * (1 - 1e-6)
            utilities[top] = fine
        self.remember(cands, utilities)
        self.scores = PoolScores(undersampled, cost)
        return cands, stats, idx, exp_gain, exp_area, utilities

    def _score(
        self, poses: np.ndarray, exp_gain: np.ndarray, view_model: ViewModel, exp_area_max_m2: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(Ours' weighted score (before the motion discount), the undersampled surface each would sample densely
        (m^2; zero when the term is not in the score)) of camera poses (n, 4, 4) with their expected gains.
        The ``undersampled_surface`` term's weight is scaled by its share of the new surface to be had: its best
        candidate's area over that plus ``exp_area_max_m2``, the most unseen surface any candidate is expected to
        see (early on little, in the tail most), to the power ``planning.undersampled_fade_power``."""
        grid = self.context.planning_map
        terms = {"expected_surface": exp_gain}
        weights = dict(self.weights)
        area = np.zeros(len(poses))
        if "undersampled_surface" in weights:
            missed, normals, pitch = self.sampling.fields(grid, self.open_border_weight)
            radius = self.sampling.model.coverage_radius_m
            gain, area = undersampled_surface(grid, poses, view_model, missed, pitch, radius, normals)
            terms["undersampled_surface"] = gain
            best = float(area.max()) if len(area) else 0.0
            share = best / max(best + exp_area_max_m2, 1e-12)
            weights["undersampled_surface"] *= share**self.undersampled_fade_power
        if set(weights) - set(self.own_terms):
            g = evaluate_views(grid, poses, view_model, gain="report")
            terms.update(g.all_gains)
        return weighted_score(terms, weights, len(poses)), np.asarray(area, dtype=float)

    def choose(self, q):
        return self.choose_from(q, *self.scored_pool(q))

    def choose_from(self, q, cands, stats, idx, exp_gain, exp_area, utilities):
        """Ours' choice from a scored pool (:meth:`scored_pool`), the coverage fallback where the predicted surface
        runs out."""
        if cands is None or not np.any(exp_area > 0):
            return self.coverage_fallback(q, stats)
        if float(exp_area.max()) * 1e6 < self.fallback_below_mm2:
            # little predicted surface left: a view that sees never-observed space next to the surface may see more
            other = self.coverage_fallback(q, dict(stats))
            if other[0] is not None and other[0].remaining_area_m2 > float(exp_area.max()):
                return other
        choice, fallbacks = self.ranked(
            cands, idx, exp_gain, utilities, exp_area, first=self.scores.near_best(utilities, self.near_best_share)
        )
        # the stopping rule looks at the predicted surface left for any candidate, not at the chosen view only
        for option in (choice, *fallbacks):
            option.remaining_area_m2 = float(exp_area.max())
            option.remaining_gain = float(exp_gain.max())
        stats["fallbacks"] = fallbacks
        return choice, "", stats

    def coverage_fallback(self, q, stats: dict):
        """The view of the global sphere that sees the most never-observed space next to the seen surface (rpg's
        proximity count within ``planning.coverage_fallback_reach_vox`` voxels of a full voxel, discounted by the
        motion as the score), or (None, "frontier_exhausted", stats) when no reachable view sees any. A thin or
        flat part has no predicted surface along its rim (thinner than a planning voxel) although views from low
        elevations would still see it. Its expected new area is the counted voxels x resolution^2 (weights
        ``reach - d`` average about half the reach), so the stopping rule (too little expected or realised new
        surface, surprises made tabu) still ends the run."""
        c = self.context
        cands, _ = self.pool(q, sources="sphere")
        stats = {**stats, **self.stats(cands)}
        if not cands.feasible.any():
            self.remember(cands, None)
            return None, "frontier_exhausted", stats
        idx = np.nonzero(cands.feasible)[0]
        res = float(c.planning_map.resolution_m)
        reach = self.fallback_reach_vox * res
        gains = evaluate_views(c.planning_map, cands.poses[idx], c.view_model, gain="proximity_count",
                               proximity_max_dist_m=reach)  # fmt: skip
        proximity = np.asarray(gains.gain, dtype=float)
        area = proximity / (0.5 * reach) * res * res
        utilities = proximity * np.exp(-c.cost_weight * c.motion_cost(q, cands.joints[idx]))
        self.remember(cands, utilities)
        if not np.any(area > 0):
            return None, "frontier_exhausted", stats
        choice, fallbacks = self.ranked(cands, idx, proximity, utilities, area)
        for option in (choice, *fallbacks):
            option.source = "coverage_fallback"
            option.remaining_area_m2 = float(area.max())
            option.remaining_gain = math.inf  # not comparable with the predicted-surface gain of the first view
        stats["fallbacks"] = fallbacks
        return choice, "", stats


@dataclass
class PoolScores:
    """What the last :meth:`OursPolicy.scored_pool` measured beside the utilities, per feasible candidate."""

    #: the undersampled surface each would sample densely (m^2; the coarse bundle's below the finely scored best)
    undersampled_area_m2: np.ndarray
    #: its motion cost from the current joints (s, the joint path's share included)
    motion_cost_s: np.ndarray

    def near_best(self, utilities: np.ndarray, share: float) -> int | None:
        """The candidate with the cheapest motion among those whose utility is at least (1 - ``share``) x the
        best's; None when ``share`` is 0 or the costs are not those of ``utilities``."""
        if share <= 0 or len(self.motion_cost_s) != len(utilities) or not len(utilities):
            return None
        near = np.nonzero(utilities >= (1.0 - share) * float(utilities.max()))[0]
        return int(near[np.argmin(self.motion_cost_s[near])])


@dataclass
class GrowthTrack:
    """The planning map's observed surface (m^2) at each choice (by map version), for the ``map_growth`` schedule."""

    areas_m2: list = field(default_factory=list)
    versions: list = field(default_factory=list)

    def saturation(self, grid, window: int = 2) -> float:
        """1 - (the surface the map gained over the last ``window`` choices) / (the most it gained over any
        ``window`` running), in [0, 1]; 0 until ``window`` gains are known."""
        if not self.versions or self.versions[-1] != grid.version:
            self.versions.append(grid.version)
            self.areas_m2.append(grid.observed_surface_area_m2())
        areas = np.asarray(self.areas_m2)
        if len(areas) <= window:
            return 0.0
        gains = areas[window:] - areas[:-window]
        best = float(gains.max())
        return float(np.clip(1.0 - gains[-1] / best, 0.0, 1.0)) if best > 0 else 1.0


def coarse_view(view: ViewModel, divisor: int) -> ViewModel:
    """``view`` with ``divisor`` times fewer rays per axis in the camera and the projector bundle (at least one)."""
    return dataclasses.replace(
        view,
        rays_h=max(1, view.rays_h // divisor),
        rays_v=max(1, view.rays_v // divisor),
        projector_rays_h=max(1, view.projector_rays_h // divisor),
        projector_rays_v=max(1, view.projector_rays_v // divisor),
    )
