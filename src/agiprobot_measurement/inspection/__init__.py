"""Inspection: a measured cloud against the nominal CAD -- registration, signed deviations, features, ISO 14253-1
decisions and a report; plus actual parts with analytic truth and their simulated scans for testing it.

Modules: ``spec`` (the spec file: faces, features, alignment), ``registration`` (prealignment, robust ICP with
locked DOFs, 3-2-1 datums), ``deviation`` (closest points, signed distances, masks, patch statistics),
``fitting`` (LS plane/circle/sphere/cylinder, minimum-zone flatness), ``features`` (the spec's features
evaluated), ``decision`` (ISO 14253-1 rules), ``pipeline`` (the facade :func:`inspect_cloud`), ``request`` (one
inspection from files or points to its report: :func:`run_inspection`, used by the CLI and the ROS action),
``cli`` (the command line's work), ``report`` (JSON,
HTML, PNG, coloured PLY, written atomically), ``actual`` (deviated parts with truth), ``simulate`` (scanning
them with the PhoXi and laser simulators under a named sensor error model), ``instrument`` (the scanner's
systematic uncertainty terms per error model), ``errors``.
"""

from agiprobot_measurement.inspection.actual import ActualPart
from agiprobot_measurement.inspection.decision import CONFORM, INDETERMINATE, NOT_CONFORM, Decision, decide
from agiprobot_measurement.inspection.errors import (
    InspectionInputError,
    InspectionInternalError,
    RegistrationError,
    SpecError,
)
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty, load_instrument
from agiprobot_measurement.inspection.pipeline import STAGES, InspectionResult, inspect_cloud
from agiprobot_measurement.inspection.registration import IcpSettings, Registration, icp
from agiprobot_measurement.inspection.request import InspectionRequest, run_inspection
from agiprobot_measurement.inspection.spec import InspectionSpec, load_spec, parse_spec

__all__ = [
    "CONFORM",
    "INDETERMINATE",
    "NOT_CONFORM",
    "STAGES",
    "ActualPart",
    "Decision",
    "IcpSettings",
    "InspectionInputError",
    "InspectionInternalError",
    "InspectionRequest",
    "InspectionResult",
    "InspectionSpec",
    "InstrumentUncertainty",
    "Registration",
    "RegistrationError",
    "SpecError",
    "decide",
    "icp",
    "inspect_cloud",
    "load_instrument",
    "load_spec",
    "parse_spec",
    "run_inspection",
]
