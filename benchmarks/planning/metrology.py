"""Sampling, viewpoint generation and metrological evaluation (no mechanics).

Defaults reproduce the original's benchmark work: the 100 mm cube at 0.03 points/mm^2 (1,500 samples),
12 orientations around the boresight, tilt modes 'none' (18,000 candidates) and 'full' (162,000). The
original needed about 0.1 s per candidate including its mechanics (1,065 s for 12 orientations, tilt none).
"""

from __future__ import annotations

import argparse
import sys
import time

from agiprobot_measurement.planning.candidates.viewpoint import TILT_MODES, generate_viewpoint_poses
from agiprobot_measurement.planning.part_loading import load_part
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from benchmarks.harness import ROOT, load_conditions, peak_rss_mb

CONDITIONS = load_conditions("planning_metrology")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", default=str(ROOT / CONDITIONS["part"]), help="mesh file")
    parser.add_argument("--units", default=CONDITIONS["units"], help="unit of the mesh file (mm, inch, m, ...)")
    parser.add_argument(
        "--density", type=float, default=CONDITIONS["density_points_per_mm2"], help="samples per mm^2 (%(default)g)"
    )
    parser.add_argument(
        "--orientations", type=int, default=CONDITIONS["orientations"], help="orientations around the boresight"
    )
    parser.add_argument(
        "--tilt", nargs="+", default=list(CONDITIONS["tilts"]), choices=TILT_MODES, help="tilt modes to run"
    )
    parser.add_argument(
        "--threshold", type=float, default=None, help="uncertainty threshold in mm (default: the sensor's max)"
    )
    parser.add_argument(
        "--deflection", type=float, default=CONDITIONS["max_deflection_mm"], help="maximum deflection in mm"
    )
    parser.add_argument("--seed", type=int, default=0, help="sampling seed")
    parser.add_argument(
        "--cast-all-rays",
        action="store_true",
        help="cast rays for every pair, also on faces no ray can be blocked from (convex hull faces)",
    )
    args = parser.parse_args(argv)

    start = time.perf_counter()
    part = load_part(args.part, units=args.units)
    samples = part.sample(args.density, seed=args.seed)
    sampling_s = time.perf_counter() - start
    sensor = SensorModel.from_config()
    threshold = sensor.get_max_uncertainty() if args.threshold is None else args.threshold
    start = time.perf_counter()
    sensor.set_processing_context(
        part.mesh, samples.points, samples.face_ids, cull_supporting_faces=not args.cast_all_rays
    )
    context_s = time.perf_counter() - start
    print(f"part {args.part} ({args.units}): {len(part.mesh.faces)} faces, {part.measurable_area:.0f} mm^2")
    print(
        f"samples {len(samples)} at {args.density} /mm^2 in {sampling_s:.2f} s; context {context_s:.2f} s; "
        f"threshold {threshold:.4f} mm; rays {'all pairs' if args.cast_all_rays else 'culled on hull faces'}"
    )
    print(
        f"{'tilt':8} {'candidates':>10} {'generate s':>10} {'metrology s':>11} {'total s':>8} "
        f"{'nonzeros':>11} {'views>0':>8} {'peak MB':>8}"
    )
    for mode in args.tilt:
        start = time.perf_counter()
        candidates = generate_viewpoint_poses(samples.points, samples.normals, args.orientations, mode, sensor)
        generated = time.perf_counter()
        result = sensor.evaluate_viewpoints_batch(candidates.poses, threshold, args.deflection)
        done = time.perf_counter()
        print(
            f"{mode:8} {len(candidates.poses):>10} {generated - start:>10.2f} {done - generated:>11.2f} "
            f"{done - start:>8.2f} {result.nnz:>11} {(result.counts > 0).sum():>8} {peak_rss_mb():>8.0f}",
            flush=True,
        )
        del candidates, result
    return 0


if __name__ == "__main__":
    sys.exit(main())
