"""``python -m benchmarks.reliability.real_cell``: the faults of a real UR cell, measured on the simulated UR driver.

Runs ``test/ros/test_real_cell_faults.test`` (trajectory_manager + the simulated station; the program stopped and a
protective stop during a measurement segment, the speed slider at 0.3) and prints its figures: how long after the
fault the robot stood still and the execute_plan result arrived, the error the user reads, the plan's duration and
measured coverage at 100 % and 30 % speed. ``--yaml FILE`` keeps the figures; the exit status is the test's.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--yaml", default="", help="write the figures to this file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        figures_file = Path(args.yaml).resolve() if args.yaml else Path(tmp) / "figures.yaml"
        done = subprocess.run(
            [
                "rostest",
                "agiprobot_measurement",
                "test_real_cell_faults.test",
                f"figures_file:={figures_file}",
                "speed_slider:=0.3",
            ],
            check=False,
        )
        if not figures_file.is_file():
            print("no figures: the test did not get to write them", file=sys.stderr)
            return done.returncode or 1
        figures = yaml.safe_load(figures_file.read_text()) or {}
    print("\nreal cell faults (simulated UR driver):")
    for name in ("program_stopped", "protective_stop"):
        row = figures.get(name)
        if row:
            print(
                f"  {name:16s} robot stood {row['robot_stood_after_s']:.3f} s after the fault, execute_plan result "
                f"after {row['result_after_s']:.3f} s (segment {row['segment']}); next execution "
                f"{row.get('next_execution_s', '-')} s\n    error: {row['error']}"
            )
    for speed in ("speed_1.0", "speed_0.3"):
        row = figures.get(speed)
        if row:
            phases = ", ".join(f"{k} {v:.2f} s" for k, v in (row.get("phases_s") or {}).items())
            print(
                f"  {speed:16s} {row['duration_s']:.2f} s ({phases}), measured coverage {row['measured_coverage']:.4f}"
            )
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
