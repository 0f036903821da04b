"""The volumetric metrics of Isler / Delmerico as policies, with rpg's utility ``G / sum G - w C / sum C``."""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.nbv.volumetric.gains import utility
from agiprobot_measurement.nbv.volumetric.policies.base import Policy, PolicyContext

__all__ = ["MetricPolicy"]


class MetricPolicy(Policy):
    """One volumetric metric (a name of :data:`~agiprobot_measurement.nbv.volumetric.gain_names.GAIN_NAMES`) with
    rpg's utility; the benchmark runs them with ``w = 0`` (rpg's default)."""

    def __init__(self, context: PolicyContext, gain: str):
        super().__init__(context)
        self.name = gain

    def choose(self, q):
        c = self.context
        cands, stats = self.feasible_pool(q)
        if cands is None:
            return None, "frontier_exhausted", stats
        g, idx = c.evaluate(cands, self.name)
        cost = c.motion_cost(q, cands.joints[idx])
        utilities = utility(g.gain, cost, "rpg", c.cost_weight)
        self.remember(cands, utilities)
        if not np.any(g.gain > 0):
            return None, "frontier_exhausted", stats
        choice, fallbacks = self.ranked(cands, idx, g.gain, utilities, g.new_surface_area_m2)
        stats["fallbacks"] = fallbacks
        return choice, "", stats
