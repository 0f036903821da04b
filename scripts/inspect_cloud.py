#!/usr/bin/env python3
"""Inspect a measured point cloud against the nominal CAD model: register, colour the signed deviations, evaluate
the spec's features and decide per ISO 14253-1 (conform / not conform / indeterminate), then write a report.

CLOUD: a PLY (x y z, optional per-point noise property 'sigma' in the cloud's unit), .npy (N x 3, or N x 4 with
sigma) or text file (.xyz/.txt/.csv, 3 or 4 columns), in the world frame. --nominal: the CAD mesh (STL/PLY/OBJ) in
its own frame; --placement: the planned world <- part pose (a YAML/JSON 4x4 matrix or 'x,y,z' translation),
identity by default. Units: the spec's (`units:`), unless --cloud-units says the cloud is in another one.

--demo CASE[:MAGNITUDE[:SEED]] builds a deviated part with known truth (null, dent, hole, warp, scale), scans it
with the simulated PhoXi S and inspects it against the nominal (CLOUD, --nominal and --spec are then not needed);
the truth goes into the report's meta.

examples:
  inspect_cloud.py --demo dent:0.3 --out /tmp/dent_report
  inspect_cloud.py cloud.ply --nominal part.stl --spec config/inspection/cube_100.yaml --placement pose.yaml --out /tmp/r

outputs in --out (written into a temporary folder and renamed at the end): report.json, report.html,
deviation_map.png, histogram.png, deviations.ply. A non-empty --out is refused unless --overwrite.

(Named inspect_cloud.py, not inspect.py: a script called inspect.py would shadow Python's own ``inspect`` module
for every script in this folder.)

exit status: 0 conform; 3 not conform or indeterminate; 2 bad input (one 'error: ...' line); 1 internal error;
130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
try:
    import agiprobot_measurement  # noqa: F401
except ImportError:  # run from a checkout without the catkin environment
    sys.path.insert(0, str(ROOT / "src"))


from agiprobot_measurement.common.cli import run_main  # noqa: E402
from agiprobot_measurement.inspection.cli import inspect_command  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("cloud", nargs="?", help="measured cloud file (world frame)")
    parser.add_argument("--nominal", help="nominal CAD mesh (its own frame)")
    parser.add_argument("--spec", help="inspection spec (config/inspection/*.yaml)")
    parser.add_argument("--out", required=True, help="report folder")
    parser.add_argument("--placement", default=None, help="planned world <- part pose: YAML/JSON 4x4 file or 'x,y,z'")
    parser.add_argument("--cloud-units", default=None, choices=("mm", "m", "cm", "in"), help="the cloud's unit")
    parser.add_argument("--sigma", type=float, default=None, help="noise sigma of every point (cloud unit)")
    parser.add_argument("--demo", default=None, help="CASE[:MAGNITUDE[:SEED]] simulated part with truth")
    parser.add_argument("--sensor", default="phoxi", choices=("phoxi", "phoxi_low", "laser"), help="for --demo")
    parser.add_argument(
        "--error-model", default="ideal", help="for --demo: the scanners' error model (ideal, realistic)"
    )
    parser.add_argument(
        "--instrument",
        default=None,
        help="the scanner's systematic uncertainty terms: ERROR_MODEL:SCANNER, e.g. realistic:phoxi_S "
        "(config/inspection/instruments.yaml; --demo takes its error model's by default)",
    )
    parser.add_argument("--overwrite", action="store_true")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    result, folder = inspect_command(args, progress=lambda stage, f: print(f"[{stage}]", file=sys.stderr, flush=True))
    summary = json.loads((folder / "report.json").read_text())
    print(f"{summary['part']}: {summary['verdict']}; {summary['surface_flags']} surface regions out of tolerance; "
          f"report in {folder}")  # fmt: skip
    for feature in summary["features"]:
        values = ", ".join(f"{d['characteristic']} {d['value_mm']:.4f} (U {d['uncertainty_mm']:.4f})"
                           for d in feature["decisions"])  # fmt: skip
        print(f"  {feature['name']}: {feature['verdict']} {values}")
    return 0 if result.verdict == "conform" else 3


if __name__ == "__main__":
    sys.exit(run_main(main, prog="inspect_cloud.py"))
