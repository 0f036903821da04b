"""Command line of the simulated acceptance test (see :mod:`benchmarks.acceptance`)."""

from __future__ import annotations

import argparse
import json
import math
import time

from agiprobot_measurement.sensors.acceptance import load_acceptance_specs
from agiprobot_measurement.sensors.error_models import DEFAULT_ERROR_MODEL, load_error_model
from benchmarks.acceptance import run_scanner
from benchmarks.acceptance.multi_sweep import run_multi_sweep

COLUMNS = ("artefact", "position", "z", "tilt", "PF", "PS", "SD", "F", "sigma", "expected_sigma", "rms_vs_true")


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4f}"
    return str(value)


def table(rows: list[dict]) -> str:
    used = [c for c in COLUMNS if any(c in r for r in rows)]
    lines = ["| " + " | ".join(used) + " |", "|" + "---|" * len(used)]
    for row in rows:
        lines.append("| " + " | ".join(_cell(_number(row.get(c))) for c in used) + " |")
    return "\n".join(lines)


def _number(value):
    return float(value) if hasattr(value, "dtype") else value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.acceptance", description=__doc__)
    specs = load_acceptance_specs()
    parser.add_argument("--scanners", nargs="+", default=list(specs), choices=list(specs))
    parser.add_argument("--positions", type=int, default=None, help="positions per artefact (default: all)")
    parser.add_argument("--error-model", default=DEFAULT_ERROR_MODEL, help="config/error_models/<name>.yaml")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-multi-sweep", action="store_true", help="skip the laser's multi-sweep length test")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args(argv)
    error_model = load_error_model(args.error_model)
    results, failed = [], 0
    print(f"error model: {error_model.name} ({error_model.source})")
    for name in args.scanners:
        spec = specs[name]
        result = run_scanner(spec, error_model, args.positions, args.seed)
        if spec.multi_sweep and not args.no_multi_sweep:
            start = time.perf_counter()
            multi = run_multi_sweep(spec, error_model, args.positions and max(args.positions, 3), args.seed)
            result["rows"] += multi["rows"]
            result["summary"].update({f"multi_{k}": v for k, v in multi["summary"].items()})
            result["checks"] += multi["checks"]
            result["multi_sweep_seconds"] = time.perf_counter() - start
        results.append(result)
        print(f"\n## {name} ({spec.kind}), {result['seconds']:.1f} s wall, {result['cpu_seconds']:.1f} s CPU", end="")
        if "multi_sweep_seconds" in result:
            print(f" + multi-sweep {result['multi_sweep_seconds']:.1f} s wall", end="")
        print("\n")
        print(table(result["rows"]))
        print("\nsummary: " + ", ".join(f"{k} {v:.4f}" for k, v in result["summary"].items()))
        for check in result["checks"]:
            failed += not check["holds"]
            verdict = "holds" if check["holds"] else "MISSES"
            print(f"  {verdict:6s}  {check['name']}: {check['value']:.3f} in [{check['low']}, {check['high']}]")
    total = sum(len(r["checks"]) for r in results)
    print(f"\n{total - failed} of {total} checks hold")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as stream:
            json.dump(results, stream, indent=1, default=_number)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
