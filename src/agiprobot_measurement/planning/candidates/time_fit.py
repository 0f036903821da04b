"""A candidate evaluation under a deadline: how many candidates fit, as a fixed random spread over all of them.

:func:`~agiprobot_measurement.planning.candidates.streaming.evaluate_streaming` projects its time from its pilot;
when the candidates do not fit before the deadline, it evaluates the spread :func:`fitting_subset` gives (over the
whole part, not its first samples), and stops with :class:`DeadlineReached` should the deadline come anyway.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["FIT_TIME_SHARE", "MIN_FITTING_VIEWS", "DeadlineReached", "fitting_subset"]

#: the share of the time left before the deadline that a time-limited evaluation plans to use: the pilot's
#: projection is rough (the machine's load changes), and a spread that fits is worth more than a stop part-way
#: (whose chunks cover the part's first samples only)
FIT_TIME_SHARE = 0.85
#: a time-limited evaluation evaluates at least this many candidates (as many as the pilot evaluates at least),
#: and is not stopped part-way when it evaluates no more
MIN_FITTING_VIEWS = 200


class DeadlineReached(Exception):  # control flow inside the evaluation, never raised out of it
    """The evaluation's deadline came before its last chunk."""


def fitting_subset(n: int, seconds_per_view: float, deadline_s: float | None) -> np.ndarray | None:
    """A fixed random spread of ``n`` candidates (ascending indices) that the projection ``seconds_per_view``
    (wall s) fits before ``deadline_s`` (a ``time.perf_counter()`` value); None when all fit or there is no
    deadline. A random spread, not a stride: a stride would alias with the orientation / tilt pattern."""
    if deadline_s is None:
        return None
    left = deadline_s - time.perf_counter()
    fitting = int(FIT_TIME_SHARE * max(left, 0.0) / max(seconds_per_view, 1e-12))
    if fitting >= n:
        return None
    m = min(n, max(fitting, MIN_FITTING_VIEWS))
    return np.sort(np.random.default_rng(1).choice(n, m, replace=False))
