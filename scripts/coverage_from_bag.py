#!/usr/bin/env python3
"""Recompute the measured coverage of a recorded measurement from the bag alone.

scripts/coverage_from_bag.py demo_output/measurement_demo.bag [--radius-mm 1.0]
"""

import argparse
import sys

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.ros.bag_coverage import coverage_from_bag
from agiprobot_measurement.ros.errors import BagReadError


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag")
    parser.add_argument("--radius-mm", type=float, default=1.0, help="a sample counts as measured within this")
    parser.add_argument("--execution", type=int, default=-1, help="which recorded execution (0 = first, -1 = last)")
    args = parser.parse_args()
    try:
        result = coverage_from_bag(args.bag, args.radius_mm, args.execution)
    except (AgiprobotError, OSError):
        raise
    except Exception as exc:  # rosbag raises its own types for unreadable bags
        raise BagReadError(f"cannot read {args.bag}: {exc}") from exc
    print(
        f"measured coverage {100 * result.measured_coverage:.2f} % ({result.measured} of {result.coverable} coverable "
        f"samples; {result.profiles} profiles, {result.measured_points} measured points)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
