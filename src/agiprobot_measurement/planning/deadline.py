"""The planning time limit, counted from the request (the part's loading included; a command-line run counts it
from the command's start) and checked between the chunks of the stages before the set cover; a single long step
that cannot check it itself (reading and merging a huge mesh) runs under :meth:`StageClock.call`, which gives up
on it when the limit runs out. The set cover and the connection end in time by themselves."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from agiprobot_measurement.planning.errors import PlanningTimeLimit

__all__ = ["METROLOGY_TIME_SHARE", "TIME_CHECKED_STAGES", "StageClock"]

T = TypeVar("T")

#: the stages that check the time limit at their progress reports
TIME_CHECKED_STAGES = ("sampling", "metrology")
#: the share of the time left after the sampling that the metrology may take: the rest is the set cover's, the
#: scan-line verification's and the connection's. When its candidates do not fit, the metrology evaluates a random
#: spread of them that does (the plan then says the time limit stopped it). Tuned on the tuning half of the
#: generated part family (400 mm parts, 60 s): 0.3 instead of 0.5 verified 99.7-100 % instead of 89.5-98 % of the
#: measurable points (a tenth of the candidates already measures nearly every sample; the set cover's rounds need
#: the time)
METROLOGY_TIME_SHARE = 0.3


@dataclass(frozen=True)
class StageClock:
    """A running time limit: ``started_s`` (``time.perf_counter()``) and ``limit_s`` (s)."""

    started_s: float
    limit_s: float

    def elapsed_s(self) -> float:
        return time.perf_counter() - self.started_s

    def check(self, stage: str) -> None:
        """Raise :class:`PlanningTimeLimit` when the limit ran out and ``stage`` is one that checks it."""
        if stage not in TIME_CHECKED_STAGES:
            return
        elapsed = self.elapsed_s()
        if elapsed > self.limit_s:
            raise self._expired(stage, elapsed)

    def share_deadline(self, share: float) -> float:
        """The ``time.perf_counter()`` value at ``share`` of the time left from now to the limit."""
        now = time.perf_counter()
        return now + share * max(self.started_s + self.limit_s - now, 0.0)

    def call(self, stage: str, work: Callable[[], T]) -> T:
        """``work()``'s result, or :class:`PlanningTimeLimit` as soon as the limit runs out while it runs.

        For one long step that cannot check the time itself: it runs in a daemon thread, and when the limit runs
        out first, that thread is left to finish on its own (its result is dropped) and the caller goes on with
        the error. ``work`` must therefore change no shared state (it returns what it made); its own errors are
        raised here."""
        outcome: dict[str, object] = {}

        def run() -> None:
            try:
                outcome["result"] = work()
            except BaseException as exc:  # handed to the caller below, whatever it is
                outcome["error"] = exc

        worker = threading.Thread(target=run, name=f"planning {stage}", daemon=True)
        worker.start()
        worker.join(max(self.limit_s - self.elapsed_s(), 0.0))
        if worker.is_alive():
            raise self._expired(stage, self.elapsed_s())
        if "error" in outcome:
            raise outcome["error"]
        return outcome["result"]

    def _expired(self, stage: str, elapsed_s: float) -> PlanningTimeLimit:
        return PlanningTimeLimit(
            f"the time limit of {self.limit_s:g} s ran out during {stage} ({elapsed_s:.1f} s, before the set "
            "cover): no plan; allow more time, or lower the sampling density or the orientations (a finely "
            "meshed or large part takes long to load and sample)"
        )
