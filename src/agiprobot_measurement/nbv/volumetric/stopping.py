"""The loop's gain-based stopping rule (the budgets and cancel are the loop's own)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["StoppingRule"]


@dataclass
class StoppingRule:
    """Fires when the best view promises less than ``min_gain_area_mm2`` two iterations running, or when the views
    taken brought less than that ``realised_streak`` times running (the prediction counts unknown space the scanner
    may not reach from there), or when the rest of the view budget, at the rate the map's surface grew over the last
    ``growth_window`` views, would add less than ``budget_growth_share`` of the surface observed so far (the
    reconstruction has saturated: the prediction keeps counting space no view measures, while what the views add to
    the map has become small against what the remaining views could still buy), or when the best gain falls below
    ``min_relative_gain`` of the first iteration's."""

    min_gain_area_mm2: float  # the report's "maximum size of an ignored detail", as an area
    min_relative_gain: float  # share of the first iteration's gain
    realised_streak: int  # views running that brought too little
    budget_growth_share: float = 0.0  # share of the observed surface the rest of the budget must promise (0: off)
    growth_window: int = 3  # views whose mean growth of the map's surface is the rate
    #: the run's state: the gain of the first counted iteration, the two streaks so far, the map's growth per view (m^2)
    first_gain: float | None = None
    low_gain_streak: int = 0
    low_real_streak: int = 0
    growth_m2: list = field(default_factory=list)
    #: per iteration what the rule saw: views left, the map's growth and observed surface (m^2), and whether a rule
    #: other than the saturation against the budget fired (a replay of other shares needs no re-run)
    history: list = field(default_factory=list)

    def projected_growth_m2(self, views_left: int) -> float:
        """The surface (m^2) the rest of the budget (``views_left`` views) adds at the mean growth of the last
        ``growth_window`` views; inf before that many views were counted."""
        recent = self.growth_m2[-self.growth_window :]
        if len(recent) < self.growth_window:
            return math.inf
        return max(0, int(views_left)) * sum(recent) / len(recent)

    def update(
        self,
        gain: float,
        expected_new_area_m2: float,
        last_realised_m2: float,
        observed_area_m2: float = math.inf,
        last_growth_m2: float = math.inf,
        views_left: int | None = None,
    ) -> bool:
        """Count one iteration (the best view's gain and expected new surface, the surface the last view added, the
        surface observed so far, the surface the last view added to the map, the views left in the budget); whether
        the rule fires."""
        if self.first_gain is None:
            self.first_gain = max(gain, 1e-12)
        relative = gain / self.first_gain
        threshold = self.min_gain_area_mm2
        self.low_gain_streak = self.low_gain_streak + 1 if expected_new_area_m2 * 1e6 < threshold else 0
        self.low_real_streak = self.low_real_streak + 1 if last_realised_m2 * 1e6 < threshold else 0
        self.growth_m2.append(last_growth_m2)
        saturated = (
            self.budget_growth_share > 0
            and views_left is not None
            and self.projected_growth_m2(views_left) < self.budget_growth_share * observed_area_m2
        )
        other = (
            self.low_gain_streak >= 2
            or self.low_real_streak >= self.realised_streak
            or relative < self.min_relative_gain
        )
        seen = {"views_left": views_left, "growth_m2": float(last_growth_m2), "observed_m2": float(observed_area_m2)}
        streaks = {"low_gain_streak": self.low_gain_streak, "low_real_streak": self.low_real_streak}
        fired = {"other_rule": bool(other), "saturated": bool(saturated), "relative_gain": float(relative)}
        self.history.append({**seen, **streaks, **fired})
        return other or saturated
