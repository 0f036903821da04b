#!/usr/bin/env python3
"""Reconstruct a part on the simulated station by next-best-view planning (no roscore needed).

The part (a mesh file in --units, a STEP file in the unit it declares, a procedural shape: u_channel, cup,
two_towers, l_bracket, torus, or a generated part: shape_k, boolean_k, plate_k, blob_k, mech_k with k = 0..7; read and checked as plan_measurement.py reads parts, 10 mm to 2 m across) is placed on
the fixture, hidden from the planner, and scanned by the simulated PhoXi (model S, noise on) on the UR10e's flange,
view after view, by the same loop as the ROS node (src/agiprobot_measurement/nbv/reconstruction.py).

examples:
  reconstruct.py ../shared/parts/objectA_wuerfel.stl --units mm --out /tmp/cube
  reconstruct.py cup --method random --max-views 8 --out /tmp/cup --summary /tmp/cup.json --pixel-step 4
  reconstruct.py plate_1 --method ours_tour --max-views 12 --out /tmp/plate --pixel-step 4
  reconstruct.py ../shared/parts/fandisk.obj --units m --extent 0.2 --method hemisphere12 --out /tmp/fan

outputs in --out: cloud.ply (fused points, world frame), map.npz (+ map.bt with an OctoMap binding), mesh.ply
(TSDF), views.yaml (poses, joints, gains, timings, termination reason). --summary FILE.json: the views, the
coverage of the observable surface after each view, the planning time per view, the termination reason and the
Chamfer distance. Progress goes to stderr. Files go where they are named (absolute, or relative to the working
directory); a non-empty --out or an existing --summary is refused unless --overwrite.

exit status: 0 done; 2 bad input (one 'error: ...' line); 1 internal error or outputs not written (the folder
keeps its previous files); 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
try:
    import agiprobot_measurement  # noqa: F401
except ImportError:  # run from a checkout without the catkin environment
    sys.path.insert(0, str(ROOT / "src"))

from agiprobot_measurement.common.cli import run_main  # noqa: E402
from agiprobot_measurement.common.files import output_path, write_output  # noqa: E402
from agiprobot_measurement.common.limits import excerpt  # noqa: E402
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M  # noqa: E402
from agiprobot_measurement.errors import InputError  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    from agiprobot_measurement.nbv.volumetric.request import METHODS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 2)[2],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("part", help="mesh file or procedural shape name")
    parser.add_argument("--units", default="mm", choices=sorted(UNIT_SCALES_TO_M), help="unit of the mesh file")
    parser.add_argument("--extent", type=float, default=None, help="rescale the part to this largest extent (m)")
    parser.add_argument("--method", default="ours", choices=METHODS)
    parser.add_argument("--max-views", type=int, default=20)
    parser.add_argument("--max-time", type=float, default=600.0, help="time budget (s)")
    parser.add_argument("--min-gain-area", type=float, default=None, help="ignored detail (mm^2), stopping rule")
    parser.add_argument("--cost-weight", type=float, default=None)
    parser.add_argument("--resolution", type=float, default=0.002, help="output grid (m)")
    parser.add_argument("--planning-resolution", type=float, default=0.005, help="planning grid (m)")
    parser.add_argument("--model", default=None, choices=("S", "M", "L"), help="PhoXi model (default S)")
    parser.add_argument("--pixel-step", type=int, default=2, help="render every n-th pixel (n x n)")
    parser.add_argument("--no-noise", action="store_true", help="switch the scanner noise off")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument(
        "--overwrite",
        "--force",
        dest="overwrite",
        action="store_true",
        help="write into a non-empty --out, replace an existing --summary",
    )
    parser.add_argument("--summary", default=None, help="write a JSON summary here")
    parser.add_argument("--no-ground-truth", action="store_true", help="skip the coverage ground truth (faster)")
    parser.add_argument("-v", "--verbose", action="store_true")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main(lambda: run(args))


def run(args) -> int:
    out = Path(args.out).expanduser()
    summary_path = output_path(args.summary, args.overwrite, what="--summary") if args.summary else None
    try:  # an unusable --out fails here, before any work
        if out.exists() and not out.is_dir():
            raise InputError(f"--out {excerpt(str(out))} exists and is not a folder")
        if out.is_dir() and any(out.iterdir()) and not args.overwrite:
            raise InputError(f"--out {excerpt(str(out))} is not empty (use --overwrite to write into it)")
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out: cannot create the folder {excerpt(str(out))}: {exc.strerror}") from exc
    from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest

    overrides = {
        "gain": args.method,
        "max_views": args.max_views,
        "max_time_s": args.max_time,
        "resolution_m": args.resolution,
        "planning_resolution_m": args.planning_resolution,
        "seed": args.seed,
        "output_dir": str(out),
    }
    if args.min_gain_area is not None:
        overrides["min_gain_area_mm2"] = args.min_gain_area
    if args.cost_weight is not None:
        overrides["cost_weight"] = args.cost_weight
    request = ReconstructionRequest.with_config_defaults(**overrides)  # validates before the heavy imports
    from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation, load_part_mesh

    t0 = time.perf_counter()
    part_mesh_m = load_part_mesh(args.part, args.units, args.extent)  # checked before the heavy imports and work
    from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, simulate

    station = SimulatedNBVStation(
        part_mesh_m, "m", None, args.model, noise=not args.no_noise, seed=args.seed, pixel_step=args.pixel_step,
    )  # fmt: skip
    print(f"part: {args.part}, extent {station.part_mesh.extents.max() * 1000:.0f} mm, on the fixture", file=sys.stderr)
    truth = None
    if not args.no_ground_truth:
        truth = GroundTruth(station)
        print(
            f"ground truth: {truth.n_observable} of {len(truth.points_m)} surface points observable from "
            f"{truth.visibility.matrix.shape[1]} reachable poses ({truth.seconds:.1f} s)",
            file=sys.stderr,
        )

    def progress(p):
        if p.phase in ("capture", "finish") or args.verbose:
            cov = "" if p.coverage is None else f" coverage {100 * p.coverage:.1f} %"
            print(
                f"  view {p.view:2d} {p.phase:<11} observed {p.observed_area_m2 * 1e4:.1f} cm^2{cov}", file=sys.stderr
            )

    summary = simulate(station, request, truth, on_progress=progress)
    summary["part"] = str(args.part)
    summary["wall_time_total_s"] = time.perf_counter() - t0
    print(
        f"done: {summary['termination_reason']} after {summary['views']} views"
        + (f", coverage {100 * summary['coverage']:.1f} %" if summary.get("coverage") is not None else "")
        + (f", Chamfer {summary['chamfer_mm']:.3f} mm" if "chamfer_mm" in summary else "")
        + f"; files in {out}",
        file=sys.stderr,
    )
    if summary_path is not None:
        write_output(summary_path, json.dumps(summary, indent=1, default=float))
    if summary["termination_reason"] == "error":
        print(f"error: {summary['error']}", file=sys.stderr)
        return 1
    if summary.get("outputs_error"):
        print(f"error: {summary['outputs_error']} (in {out})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
