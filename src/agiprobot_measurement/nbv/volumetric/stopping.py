"""The loop's gain-based stopping rule (the budgets and cancel are the loop's own)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["StoppingRule"]


@dataclass
class StoppingRule:
    """Fires when the best view promises less than ``min_gain_area_mm2`` two iterations running, or when the views
    taken brought less than that ``realised_streak`` times running (the prediction counts unknown space the scanner
    may not reach from there), or when the last ``realised_streak`` views together added less than
    ``min_growth_share`` of the surface observed so far (the reconstruction has saturated: the prediction keeps
    counting space no view measures, while what the views add has become noise-level), or when the best gain falls
    below ``min_relative_gain`` of the first iteration's."""

    min_gain_area_mm2: float  # the report's "maximum size of an ignored detail", as an area
    min_relative_gain: float  # share of the first iteration's gain
    realised_streak: int  # views running that brought too little
    min_growth_share: float = 0.0  # share of the observed surface the last realised_streak views add (0: off)
    #: the run's state: the gain of the first counted iteration, the two streaks so far, the realised areas (m^2)
    first_gain: float | None = None
    low_gain_streak: int = 0
    low_real_streak: int = 0
    realised_m2: list = field(default_factory=list)

    def update(
        self, gain: float, expected_new_area_m2: float, last_realised_m2: float, observed_area_m2: float = math.inf
    ) -> bool:
        """Count one iteration (the best view's gain and expected new surface, the surface the last view added, the
        surface observed so far); whether the rule fires."""
        if self.first_gain is None:
            self.first_gain = max(gain, 1e-12)
        relative = gain / self.first_gain
        threshold = self.min_gain_area_mm2
        self.low_gain_streak = self.low_gain_streak + 1 if expected_new_area_m2 * 1e6 < threshold else 0
        self.low_real_streak = self.low_real_streak + 1 if last_realised_m2 * 1e6 < threshold else 0
        self.realised_m2.append(last_realised_m2)
        recent = self.realised_m2[-self.realised_streak :]
        saturated = (
            self.min_growth_share > 0
            and len(recent) >= self.realised_streak
            and sum(recent) < self.min_growth_share * observed_area_m2
        )
        return (
            self.low_gain_streak >= 2
            or self.low_real_streak >= self.realised_streak
            or saturated
            or relative < self.min_relative_gain
        )
