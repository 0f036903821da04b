"""The command line's work (``scripts/inspect_cloud.py``): an :class:`~.request.InspectionRequest` from the
arguments (or a simulated demo case), inspected and reported. Every bad input is an :class:`InspectionInputError`
raised before the report folder is touched. The readers are :mod:`.request`'s (named here too)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.inspection.cases import build_case
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.instrument import load_instrument
from agiprobot_measurement.inspection.pipeline import inspect_cloud
from agiprobot_measurement.inspection.report import write_report
from agiprobot_measurement.inspection.request import (
    InspectionRequest,
    read_cloud,
    read_nominal,
    read_placement,
    run_inspection,
)

__all__ = ["inspect_command", "read_cloud", "read_nominal", "read_placement"]


#: the scanner (config/inspection/instruments.yaml) of each demo sensor
DEMO_SCANNERS = {"phoxi": "phoxi_S", "phoxi_low": "phoxi_S", "laser": "laser_line"}


def _instrument(text: str | None):
    """``MODEL:SCANNER`` (e.g. ``realistic:phoxi_S``) -> the systematic terms; None -> None."""
    if not text:
        return None
    model, _, scanner = text.partition(":")
    if not scanner:
        raise InspectionInputError(f"--instrument {text!r}: use ERROR_MODEL:SCANNER, e.g. realistic:phoxi_S")
    return load_instrument(model, scanner)


def _demo(text: str, sensor: str, error_model: str = "ideal"):
    fields = text.split(":")
    try:
        magnitude = float(fields[1]) if len(fields) > 1 else 0.0
        seed = int(fields[2]) if len(fields) > 2 else 0
    except ValueError as exc:
        raise InspectionInputError(f"--demo {text!r}: use CASE[:MAGNITUDE[:SEED]]") from exc
    case = build_case(fields[0], magnitude, seed, sensor, error_model)
    meta = {"demo": fields[0], "magnitude": magnitude, "seed": seed, "sensor": sensor, "error_model": error_model,
            "truth": case.truth}  # fmt: skip
    return case.points_mm, case.sigma_mm, case.nominal, case.spec, case.part.nominal_placement, meta


def inspect_command(args, progress=None):
    """(InspectionResult, report folder) for the parsed command line ``args``."""
    out = Path(args.out).absolute()
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not args.overwrite)):
        raise InspectionInputError(f"--out {out} exists and is not empty (--overwrite replaces it)")
    if args.demo:
        error_model = getattr(args, "error_model", "ideal")
        points, sigma, nominal, spec, placement, meta = _demo(args.demo, args.sensor, error_model)
        instrument = _instrument(getattr(args, "instrument", None)) or load_instrument(
            error_model, DEMO_SCANNERS[args.sensor]
        )
        result = inspect_cloud(points, nominal, spec, placement, sigma, progress, instrument)
        return result, write_report(result, out, meta, overwrite=args.overwrite)
    if not (args.cloud and args.nominal and args.spec):
        raise InspectionInputError("give CLOUD, --nominal and --spec (or --demo CASE)")
    points, sigma = read_cloud(args.cloud)
    if args.sigma is not None:
        sigma = np.full(len(points), float(args.sigma))
    request = InspectionRequest(
        nominal_file=args.nominal,
        spec_file=args.spec,
        out_dir=out,
        points=points,
        sigma=sigma,
        placement=read_placement(args.placement),
        cloud_units=args.cloud_units or "",
        overwrite=args.overwrite,
        meta={"cloud": str(args.cloud)},
        instrument=_instrument(getattr(args, "instrument", None)),
    )
    return run_inspection(request, progress)
