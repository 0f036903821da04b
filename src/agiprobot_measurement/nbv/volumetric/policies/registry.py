"""The policies by method name (``ReconstructionRequest.gain`` after its aliases): :func:`make_policy`."""

from __future__ import annotations

from collections.abc import Callable

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.volumetric.policies.base import Policy, PolicyContext
from agiprobot_measurement.nbv.volumetric.policies.baselines import HemispherePolicy, RandomPolicy, Report3DPolicy
from agiprobot_measurement.nbv.volumetric.policies.metrics import MetricPolicy
from agiprobot_measurement.nbv.volumetric.policies.ours import OursPolicy
from agiprobot_measurement.nbv.volumetric.policies.touring import TourPolicy
from agiprobot_measurement.nbv.volumetric.settings import PlanningSettings

__all__ = ["POLICIES", "make_policy"]

#: method name -> factory(context, planning settings)
POLICIES: dict[str, Callable[[PolicyContext, PlanningSettings], Policy]] = {
    "ours": OursPolicy,
    "ours_tour": TourPolicy,
    **{name: (lambda context, planning, name=name: MetricPolicy(context, name)) for name in GAIN_NAMES},
    "random": lambda context, planning: RandomPolicy(context),
    "hemisphere": lambda context, planning: HemispherePolicy(context, 12),
    **{f"hemisphere{n}": (lambda context, planning, n=n: HemispherePolicy(context, n)) for n in (6, 12, 24)},
    "report3d": lambda context, planning: Report3DPolicy(context),
}


def make_policy(method: str, context: PolicyContext, planning: PlanningSettings) -> Policy:
    """The policy of a method name; InputError listing the known names for an unknown one."""
    factory = POLICIES.get(method)
    if factory is None:
        raise InputError(f"unknown method {method!r}; known: {', '.join(POLICIES)}")
    return factory(context, planning)
