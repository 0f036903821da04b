"""Errors of the 2D method."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError

__all__ = ["NbvInputError"]


class NbvInputError(InputError):
    """Bad user input to the 2D method (an empty grid, a body touching the border, a NaN parameter, ...).

    The message names the offending input. As an :class:`~agiprobot_measurement.errors.InputError` it is also a
    ``ValueError``, so callers catching that keep working.
    """
