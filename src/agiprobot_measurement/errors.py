"""The package's one error hierarchy.

Every error the package raises on purpose is an :class:`AgiprobotError`. :class:`InputError` is what the user must
fix (a file, a unit, a request field); its message names the problem. :class:`InternalError` is everything else
(a solver failure, a device fault). Nodes and commands catch :class:`AgiprobotError` once and report input errors
as bad requests, the rest as internal errors. The subclasses keep their builtin bases (``ValueError``,
``RuntimeError``, ``FileNotFoundError``) so that callers written against those keep working.
"""

from __future__ import annotations

__all__ = ["AgiprobotError", "InputError", "InternalError", "is_input_error"]


class AgiprobotError(Exception):
    """Base of every error this package raises on purpose."""


class InputError(AgiprobotError, ValueError):
    """Bad input the user must fix: a missing or malformed file, a wrong unit, a bad request field."""


class InternalError(AgiprobotError, RuntimeError):
    """A failure that is not the user's input: a solver, a device, an unexpected state."""


def is_input_error(error: BaseException) -> bool:
    """Whether ``error`` is the user's to fix (an :class:`InputError`)."""
    return isinstance(error, InputError)
