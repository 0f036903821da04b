"""``ours_tour``: ours' coverage-first opening, then a receding-horizon tour over the predicted surface.

While much of the part is unknown a tour opens with the nearest views, not the biggest, and loses early coverage; in
the tail a greedy planner shuttles between the sides of the part. So:

1. **Greedy phase**: ours' choice (:class:`~.ours.OursPolicy`) for the first ``min_greedy_views`` planned views (3:
   with the opening view, C(4) is ours'). A switch on the share of the first view's predicted surface left (the
   reference design's ``A / A1 < 0.2``) never fired on the generated tuning parts (the predicted surface includes
   unknown space no view reaches), so the count alone decides.
2. **Tour phase**, every view: the predicted surface still unseen (the planning map's growth-neighbour voxels: unknown
   voxels where the seen surface continues) is the set to cover, with ``undersampled_min_share`` < 1 also the full
   voxels whose seen surface was sampled too sparsely (:mod:`..sampling`); a candidate covers the elements inside its
   frustum and scanning range (occlusion left out; its predicted new area, plus the undersampled area it would
   sample densely, is its weight). The last plan's views
   that are still in the pool and still promise ``keep_share`` of the gain they were planned for are kept, the cover
   is topped up greedily (:func:`~agiprobot_measurement.nbv.volumetric.tour.greedy_cover`; ours' best view by its
   utility is always in the plan) to ``cover_share`` of the
   union or ``max_plan_views``; the views are ordered by the estimated joint-move time over up to ``max_branches``
   collision-free IK branches each, from the current joints (open tour, exact for small plans:
   :func:`~agiprobot_measurement.nbv.volumetric.tour.order_tour`; views whose marginal value is below
   ``min_marginal_share`` of the first pick's are left out of the plan); the first stop is executed (the other stops and
   then ours' ranking are its fallbacks), the map fused, and the plan re-made. When ours' best view alone promises
   ``greedy_share`` of the plan's predicted new surface, it is the first stop and the tour goes on from it (a plan of
   nearby small views first left the tail's big view for later and lost coverage).
3. Where the predicted surface runs out, ours' coverage fallback and stopping rule apply unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.nbv.volumetric.gains import predicted_normals
from agiprobot_measurement.nbv.volumetric.policies.base import FALLBACKS, ViewChoice
from agiprobot_measurement.nbv.volumetric.policies.ours import OursPolicy
from agiprobot_measurement.nbv.volumetric.tour import TourPlan, greedy_cover, order_tour

__all__ = ["TourPolicy", "coverage_sets"]

#: at most this many predicted-surface elements per plan (a random subset beyond)
MAX_ELEMENTS = 4000


def coverage_sets(poses: np.ndarray, elements_m: np.ndarray, normals: np.ndarray, view_model) -> np.ndarray:
    """(V, M) bool: element m lies inside view v's frustum (camera z forward) within the scanning range, and its
    predicted normal (where it has one; (M, 3), zero where not) faces the camera within the incidence limit."""
    if len(elements_m) == 0 or len(poses) == 0:
        return np.zeros((len(poses), len(elements_m)), dtype=bool)
    rot = poses[:, :3, :3]
    rel = elements_m[None, :, :] - poses[:, None, :3, 3]
    local = np.einsum("vji,vmj->vmi", rot, rel)  # R^T (p - t)
    z = local[..., 2]
    tan_h = math.tan(0.5 * view_model.fov_h_rad)
    tan_v = math.tan(0.5 * view_model.fov_v_rad)
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (np.abs(local[..., 0]) <= tan_h * z) & (np.abs(local[..., 1]) <= tan_v * z)
    seen = inside & (z >= view_model.range_min_m) & (z <= view_model.range_max_m)
    to_camera = -rel / np.maximum(np.linalg.norm(rel, axis=2, keepdims=True), 1e-12)
    facing = np.einsum("vmi,mi->vm", to_camera, normals)
    has_normal = np.linalg.norm(normals, axis=1) > 0.5
    return seen & ((facing >= math.cos(view_model.max_incidence_rad)) | ~has_normal[None, :])


class TourPolicy(OursPolicy):
    """Ours with a receding-horizon tour in the tail (see the module docstring)."""

    name = "ours_tour"

    def __init__(self, context, planning):
        super().__init__(context, planning)
        self.tour = planning.tour
        self.plan = TourPlan()
        self.planned_views = 0
        self.last_phase = "greedy"

    def choose(self, q):
        scored = self.scored_pool(q)
        self.planned_views += 1
        cands, stats, idx, exp_gain, exp_area, utilities = scored
        greedy = (
            cands is None
            or not np.any(exp_area > 0)
            or self.planned_views <= self.tour.min_greedy_views
            or float(exp_area.max()) * 1e6 < self.fallback_below_mm2
        )
        if greedy:
            self.last_phase = "greedy"
            self.plan = TourPlan()
            return self.choose_from(q, *scored)
        self.last_phase = "tour"
        return self._tour_choice(q, cands, stats, idx, exp_gain, exp_area, utilities)

    @property
    def covers_undersampled(self) -> bool:
        """The plan covers the seen surface sampled too sparsely too (``undersampled_min_share`` < 1 and the term in
        ours' score)."""
        return self.tour.undersampled_min_share < 1.0 and "undersampled_surface" in self.weights

    def _elements(self) -> tuple[np.ndarray, np.ndarray]:
        """(centres (M, 3) m, normals (M, 3), zero where none) of the surface still to be covered: the predicted
        unseen surface (growth-neighbour voxels, predicted normals) and the seen surface sampled too sparsely (full
        voxels whose missed share is at least ``undersampled_min_share``, the directions of ours' undersampled term),
        each at most :data:`MAX_ELEMENTS` / 2 (a random subset beyond)."""
        grid = self.context.planning_map
        parts = [(np.argwhere(grid.growth_neighbour_mask()), predicted_normals(grid))]
        if self.covers_undersampled:
            missed, normals, _ = self.sampling.fields(grid, self.open_border_weight)
            parts.append((np.argwhere((missed >= self.tour.undersampled_min_share).reshape(grid.shape)), normals))
        centres, directions = [], []
        for cells, normals in parts:
            if len(cells) > MAX_ELEMENTS // 2:
                cells = cells[self.context.rng.choice(len(cells), MAX_ELEMENTS // 2, replace=False)]
            centres.append(grid.index_to_world(cells))
            directions.append(normals[grid.flat_index(cells)] if normals is not None else np.zeros((len(cells), 3)))
        return np.vstack(centres), np.vstack(directions)

    def _branches(self, q, cands, picked_idx) -> list[np.ndarray]:
        """Per picked candidate: the filter's joints first, then up to ``max_branches - 1`` more collision-free IK
        branches nearest ``q``."""
        gen = self.context.generator
        poses = cands.poses[picked_idx]
        out = [cands.joints[i][None].copy() for i in picked_idx]
        if self.tour.max_branches <= 1:
            return out
        solutions, valid = gen.ik.solve_all(poses, np.asarray(q, dtype=float))
        rows, cols = np.nonzero(valid)
        if not len(rows):
            return out
        states = solutions[rows, cols]
        free = gen.checker.check_states(states)
        for k in range(len(picked_idx)):
            mine = states[(rows == k) & free]
            if not len(mine):
                continue
            mine = mine[np.abs(mine - out[k][0]).max(axis=1) > 1e-3]  # not the filter's own branch again
            mine = mine[np.argsort(np.abs(mine - q).sum(axis=1))][: self.tour.max_branches - 1]
            out[k] = np.vstack([out[k], mine])
        return out

    def _tour_choice(self, q, cands, stats, idx, exp_gain, exp_area, utilities):
        c = self.context
        poses = cands.poses[idx]
        # a view's weight: the predicted unseen surface, and the undersampled surface it would measure when the plan
        # covers that too
        weight = exp_area + self.scores.undersampled_area_m2 if self.covers_undersampled else exp_area
        sets = coverage_sets(poses, *self._elements(), c.view_model) & (weight > 0)[:, None]
        kept = self.plan.kept(poses, weight, self.tour.keep_share)
        # ours' own best view is always in the plan (the tour may visit it later, on the way): the plan keeps the
        # greedy's gain, the order saves the shuttling
        best = int(np.argmax(utilities))
        first = [best, *(k for k in kept if k != best)]
        picked = greedy_cover(sets, weight, self.tour.cover_share, self.tour.max_plan_views, first=first,
                              min_marginal_share=self.tour.min_marginal_share)  # fmt: skip
        if not picked:
            return self.choose_from(q, cands, stats, idx, exp_gain, exp_area, utilities)
        branches = self._branches(q, cands, idx[picked])
        stops = []
        if len(picked) > 1 and weight[best] >= self.tour.greedy_share * float(weight[picked].sum()):
            # the gain is concentrated in ours' best view: it goes first, the tour goes on from there
            stops = [(best, cands.joints[idx[best]])]
            rest = [k for k, p in enumerate(picked) if p != best]
            picked, branches = [picked[k] for k in rest], [branches[k] for k in rest]
        _, order, choice = order_tour(stops[0][1] if stops else q, branches, c.motion_cost)
        stops += [(picked[v], branches[v][b]) for v, b in zip(order, choice, strict=True)]
        self.plan = TourPlan(poses[[p for p, _ in stops]], weight[[p for p, _ in stops]])
        options = [self._option(cands, idx, j, joints, exp_gain, utilities, exp_area) for j, joints in stops]
        ranked = [j for j in np.argsort(-utilities, kind="stable") if j not in {p for p, _ in stops}]
        options += [self._option(cands, idx, j, cands.joints[idx[j]], exp_gain, utilities, exp_area) for j in ranked]
        options = options[: 1 + FALLBACKS]
        for option in options:
            option.remaining_area_m2 = float(exp_area.max())
            option.remaining_gain = float(exp_gain.max())
        stats["fallbacks"] = options[1:]
        stats["tour_views"] = len(stops)
        stats["tour_kept"] = len(kept)
        return options[0], "", stats

    @staticmethod
    def _option(cands, idx, j, joints, exp_gain, utilities, exp_area) -> ViewChoice:
        i = int(idx[j])
        target = cands.targets_m[i] if cands.source[i] == "frontier" else None
        return ViewChoice(cands.poses[i], np.asarray(joints, dtype=float), float(exp_gain[j]), float(utilities[j]),
                          float(exp_area[j]), str(cands.source[i]), np.zeros(0, int), i, target)  # fmt: skip
