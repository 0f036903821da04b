"""The errors of the motion subpackage, under the package's one root (:mod:`agiprobot_measurement.errors`)."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError

__all__ = ["MotionInputError", "UnknownObjectError"]


class MotionInputError(InputError):
    """A joint state, pose, path or planner setting handed to a motion routine is malformed or out of range."""


class UnknownObjectError(MotionInputError, KeyError):
    """A collision object is addressed by a name the world does not hold (also a ``KeyError``)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""
