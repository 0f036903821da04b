"""Errors of the NBV subpackage."""

from __future__ import annotations

__all__ = ["NbvInputError"]


class NbvInputError(ValueError):
    """Bad user input to the NBV code (an empty grid, a body touching the border, a NaN parameter, ...).

    The message names the offending input. It stays a ``ValueError`` so that callers catching that keep working.
    """
