"""The command line's work (``scripts/inspect_cloud.py``): an :class:`~.request.InspectionRequest` from the
arguments (or a simulated demo case), inspected and reported. Every bad input is an :class:`InspectionInputError`
raised before the report folder is touched. The readers are :mod:`.request`'s (named here too)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.inspection.cases import build_case
from agiprobot_measurement.inspection.errors import InspectionInputError
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


def _demo(text: str, sensor: str):
    fields = text.split(":")
    try:
        magnitude = float(fields[1]) if len(fields) > 1 else 0.0
        seed = int(fields[2]) if len(fields) > 2 else 0
    except ValueError as exc:
        raise InspectionInputError(f"--demo {text!r}: use CASE[:MAGNITUDE[:SEED]]") from exc
    case = build_case(fields[0], magnitude, seed, sensor)
    meta = {"demo": fields[0], "magnitude": magnitude, "seed": seed, "sensor": sensor, "truth": case.truth}
    return case.points_mm, case.sigma_mm, case.nominal, case.spec, case.part.nominal_placement, meta


def inspect_command(args, progress=None):
    """(InspectionResult, report folder) for the parsed command line ``args``."""
    out = Path(args.out).absolute()
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not args.overwrite)):
        raise InspectionInputError(f"--out {out} exists and is not empty (--overwrite replaces it)")
    if args.demo:
        points, sigma, nominal, spec, placement, meta = _demo(args.demo, args.sensor)
        result = inspect_cloud(points, nominal, spec, placement, sigma, progress)
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
    )
    return run_inspection(request, progress)
