"""The loop's gain-based stopping rule (the budgets and cancel are the loop's own)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["StoppingRule"]


@dataclass
class StoppingRule:
    """Fires when the best view promises less than ``min_gain_area_mm2`` two iterations running, or when the views
    taken brought less than that ``realised_streak`` times running (the prediction counts unknown space the scanner
    may not reach from there), or when the best gain falls below ``min_relative_gain`` of the first iteration's."""

    min_gain_area_mm2: float  # the report's "maximum size of an ignored detail", as an area
    min_relative_gain: float  # share of the first iteration's gain
    realised_streak: int  # views running that brought too little
    #: the run's state: the gain of the first counted iteration and the two streaks so far
    first_gain: float | None = None
    low_gain_streak: int = 0
    low_real_streak: int = 0

    def update(self, gain: float, expected_new_area_m2: float, last_realised_m2: float) -> bool:
        """Count one iteration (the best view's gain and expected new surface, the surface the last view added);
        whether the rule fires."""
        if self.first_gain is None:
            self.first_gain = max(gain, 1e-12)
        relative = gain / self.first_gain
        threshold = self.min_gain_area_mm2
        self.low_gain_streak = self.low_gain_streak + 1 if expected_new_area_m2 * 1e6 < threshold else 0
        self.low_real_streak = self.low_real_streak + 1 if last_realised_m2 * 1e6 < threshold else 0
        return (
            self.low_gain_streak >= 2
            or self.low_real_streak >= self.realised_streak
            or relative < self.min_relative_gain
        )
