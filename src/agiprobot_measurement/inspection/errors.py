"""The errors of the inspection subpackage, under the package's one root (:mod:`agiprobot_measurement.errors`)."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError, InternalError

__all__ = ["InspectionInputError", "InspectionInternalError", "RegistrationError", "SpecError"]


class InspectionInputError(InputError):
    """A cloud, nominal model or option the inspection cannot work with (empty, tiny, wrong part, wrong unit)."""


class SpecError(InspectionInputError):
    """An inspection spec file is malformed or names a face or feature the nominal model does not have."""


class InspectionInternalError(InternalError):
    """A stage of the inspection failed on valid input (a fit or solver that did not converge)."""


class RegistrationError(InspectionInputError):
    """The cloud does not register to the nominal model: too few overlapping points or a residual far above noise
    (a cloud of another part, a unit mismatch or a wrong placement)."""
