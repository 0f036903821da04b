"""The planning pipeline's errors."""

from __future__ import annotations

from collections.abc import Callable

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.errors import InputError, InternalError

__all__ = [
    "PlanningCancelled",
    "PlanningError",
    "PlanningInputError",
    "PlanningTimeLimit",
    "PlanningTypeError",
    "validated",
]


class PlanningError(InternalError):
    """The planning pipeline cannot go on (nothing reachable, nothing measurable, no part loaded...)."""


class PlanningInputError(InputError):
    """A planning call's argument is wrong (an unknown solver, a joint state of the wrong size...)."""


class PlanningTimeLimit(PlanningInputError):
    """The time limit ran out before the set cover could start (loading, sampling or the metrology of a part too
    large for it): there is no plan to return, and more time or less work is the remedy."""


class PlanningTypeError(PlanningInputError, TypeError):
    """A planning call's argument has the wrong type (a ``TypeError`` too, as the builtin checks raise)."""


class PlanningCancelled(RuntimeError):
    """The caller cancelled planning (the progress callback raised it). Deliberately not an error of the package:
    a cancel is the caller's wish, and the edges that report errors let it through."""


def validated(check: Callable[[], object], error: Callable[[str], Exception], message: str):
    """``check()`` (a call of a :mod:`~agiprobot_measurement.common.config` validator), its ``ConfigError``
    raised again as ``error(message)`` (the caller's error class and wording)."""
    try:
        return check()
    except ConfigError as exc:
        raise error(message) from exc
