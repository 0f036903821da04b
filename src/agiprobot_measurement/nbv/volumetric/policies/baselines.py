"""The comparison policies: random views, a fixed hemisphere, and the report's 2D strategy carried to 3D.

- :class:`RandomPolicy` (``random``): uniform over the feasible candidates, seeded; stops only on budgets.
- :class:`HemispherePolicy` (``hemisphere6/12/24``): a fixed hemisphere at the sweet spot, elevations 15-75 deg,
  visited nearest-first, infeasible views dropped; done when the list is (``frontier_exhausted``).
- :class:`Report3DPolicy` (``report3d``): the frontier target nearest the sensor (GetNearestPP), views
  perpendicular to its predicted surface, scored V x K x P (the report gain, i.e. visible candidates x Kolmost,
  times a motion factor); ends when no target can be measured.

The set-cover oracle (the lower bound on views) is the benchmark's, offline.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from agiprobot_measurement.nbv.volumetric.policies.base import FALLBACKS, Policy, PolicyContext

__all__ = ["HemispherePolicy", "RandomPolicy", "Report3DPolicy"]


class RandomPolicy(Policy):
    name = "random"
    uses_stopping_rule = False

    def choose(self, q):
        c = self.context
        cands, _ = self.pool(q)
        stats = self.stats(cands)
        idx = np.nonzero(cands.feasible)[0]
        self.remember(cands, None)
        if not len(idx):
            return None, "frontier_exhausted", stats
        picks = c.rng.permutation(idx)[: 1 + FALLBACKS]
        zeros = np.zeros(len(picks))
        choice, fallbacks = self.ranked(cands, picks, zeros, -np.arange(len(picks), dtype=float), zeros)
        stats["fallbacks"] = fallbacks
        return choice, "", stats


class HemispherePolicy(Policy):
    uses_stopping_rule = False

    def __init__(self, context: PolicyContext, n: int):
        super().__init__(context)
        self.name = f"hemisphere{n}"
        self.plan = context.generator.hemisphere(context.roi_center_m, n)
        self.done = np.zeros(len(self.plan), dtype=bool)

    def choose(self, q):
        c = self.context
        plan = self.plan.subset(~self.done)
        plan.feasible[:] = True
        plan.reason[:] = ""
        c.generator.filter(plan, c.planning_map, c.roi_min_m, c.roi_max_m, q, c.tabu)
        stats = self.stats(plan)
        self.remember(plan, None)
        idx = np.nonzero(plan.feasible)[0]
        if not len(idx):
            return None, "frontier_exhausted", stats
        cost = c.motion_cost(q, plan.joints[idx])
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
        c = self.context
        gen = c.generator
        targets = gen.targets(c.planning_map, c.banned_targets())
        sensor = c.sensor_pose(q)[:3, 3]
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
                gen.config = dataclasses.replace(saved, cone_angles_rad=(0.0, math.radians(20.0)), towards_unseen=False)
                cands = gen.frontier(c.planning_map, one)
            finally:
                gen.config = saved
            gen.filter(cands, c.planning_map, c.roi_min_m, c.roi_max_m, q, c.tabu)
            total += cands.total
            for k, v in cands.rejections().items():
                rejections[k] = rejections.get(k, 0) + v
            if not cands.feasible.any():
                continue
            g, idx = c.evaluate(cands, "report")
            if not np.any(g.gain > 0):
                continue
            cost = c.motion_cost(q, cands.joints[idx])
            utilities = g.gain * np.exp(-cost / self.motion_scale_s)
            self.remember(cands, utilities)
            choice, fallbacks = self.ranked(cands, idx, g.gain, utilities, g.new_surface_area_m2)
            stats = {"total": total, "feasible": int(cands.feasible.sum()), "rejections": rejections}
            stats["fallbacks"] = fallbacks
            return choice, "", stats
        return None, "frontier_exhausted", {"total": total, "feasible": 0, "rejections": rejections}
