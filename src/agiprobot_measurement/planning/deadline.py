"""The planning time limit, counted from the request (the part's loading included) and checked between the chunks
of the stages before the set cover; the set cover and the connection end in time by themselves."""

from __future__ import annotations

import time
from dataclasses import dataclass

from agiprobot_measurement.planning.errors import PlanningTimeLimit

__all__ = ["TIME_CHECKED_STAGES", "StageClock"]

#: the stages that check the time limit at their progress reports
TIME_CHECKED_STAGES = ("sampling", "metrology")


@dataclass(frozen=True)
class StageClock:
    """A running time limit: ``started_s`` (``time.perf_counter()``) and ``limit_s`` (s)."""

    started_s: float
    limit_s: float

    def check(self, stage: str) -> None:
        """Raise :class:`PlanningTimeLimit` when the limit ran out and ``stage`` is one that checks it."""
        if stage not in TIME_CHECKED_STAGES:
            return
        elapsed = time.perf_counter() - self.started_s
        if elapsed > self.limit_s:
            raise PlanningTimeLimit(
                f"the time limit of {self.limit_s:g} s ran out during {stage} ({elapsed:.1f} s, before the set "
                "cover): no plan; allow more time, or lower the sampling density or the orientations (a finely "
                "meshed or large part takes long to load and sample)"
            )
