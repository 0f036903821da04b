#!/usr/bin/env python3
"""Rebuild the next-best-view map and coverage of a recorded reconstruction from the bag alone.

scripts/nbv_from_bag.py nbv.bag [--run -1] [--no-ground-truth] [--out DIR]

The bag comes from `roslaunch agiprobot_measurement nbv.launch record:=true bag:=nbv.bag`. Prints the views fused,
the observed surface and remaining frontier areas and (simulation) the coverage, next to what the live run reported;
--out writes the rebuilt map's outputs (cloud, mesh, map, log) there.
"""

import argparse
import sys

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.ros.errors import BagReadError


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag")
    parser.add_argument("--run", type=int, default=-1, help="which recorded goal (0 = first, -1 = last)")
    parser.add_argument("--config", default=None, help="config/nbv.yaml of the run (default: the package's)")
    parser.add_argument("--scene", default=None, help="scene file of the run (default: config/scene.yaml)")
    parser.add_argument("--no-ground-truth", action="store_true", help="skip the coverage (simulation only)")
    parser.add_argument("--out", default=None, help="write the rebuilt outputs into this folder")
    args = parser.parse_args()
    try:
        from agiprobot_measurement.ros.nbv_bag import points_summary, reconstruction_from_bag
        from agiprobot_measurement.ros.nbv_setup import nbv_station

        config, station, truth = nbv_station(args.config, args.scene, ground_truth=not args.no_ground_truth)
        rebuilt = reconstruction_from_bag(args.bag, args.run, config, station, truth)
        files = rebuilt.reconstructor.save_outputs(args.out) if args.out else {}
    except (AgiprobotError, OSError):
        raise
    except Exception as exc:  # rosbag raises its own types for unreadable bags
        raise BagReadError(f"cannot rebuild from {args.bag}: {type(exc).__name__}: {exc}") from exc
    coverage = "" if rebuilt.coverage is None else f", coverage {100 * rebuilt.coverage:.2f} %"
    print(
        f"rebuilt from {rebuilt.views} views: observed {rebuilt.observed_surface_area_m2 * 1e4:.1f} cm^2, "
        f"frontier {rebuilt.remaining_frontier_area_m2 * 1e4:.1f} cm^2{coverage} ({points_summary(rebuilt)})"
    )
    if rebuilt.live:
        live = rebuilt.live
        live_coverage = "" if live["coverage"] is None else f", coverage {100 * live['coverage']:.2f} %"
        print(
            f"live run: {live['termination_reason']} after {live['number_of_views']} views, observed "
            f"{live['observed_surface_area_m2'] * 1e4:.1f} cm^2, frontier {live['remaining_frontier_area_m2'] * 1e4:.1f} "
            f"cm^2{live_coverage}"
        )
    for name, path in sorted(files.items()):
        if path:
            print(f"{name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
