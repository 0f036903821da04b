#!/usr/bin/env python3
"""Reconstruct a 2D body with the range-finder planner of Fojtík & Pajdla (circpix / fullpix / stratpix).

Per run it writes a picture like the report's ``paintRF`` (model, sensor path, transfers, measured points,
unmeasurable candidates), the measured points of the full cells (CSV and PLY, millimetres at 1 cell = 1 mm) and
prints a summary line; ``--summary`` collects every run's summary in one JSON file. Examples:

    scripts/nbv2d.py --object disc --script stratpix --out /tmp/nbv
    scripts/nbv2d.py --object all --script fullpix --rf-length 250 --aim edge_midpoints --out /tmp/nbv
    scripts/nbv2d.py --object-image body.png --script fullpix --noise 0.3 --seed 1 --out /tmp/nbv --summary s.json

Lengths are in cells (1 cell = 1 mm by default), noise is the standard deviation of the depth along the laser.
Files go where they are named (absolute, or relative to the working directory); a run whose picture, points or
summary file exists is refused before any work unless --overwrite.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from functools import partial
from pathlib import Path

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.common.files import output_path, write_output
from agiprobot_measurement.nbv.planar.errors import NbvInputError


def _parse(argv):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--object",
        help="rectangle, disc, rotated_rect, triangle, l_shape, u_shape, all, star5, or a generated body "
        "(star_0 .. star_5, comb_k, spiral_k, poly_k, blob_k)",
    )
    src.add_argument("--object-image", type=Path, help="a body as an image (dark = body) or a .npy mask")
    p.add_argument("--script", required=True, help="circpix, fullpix or stratpix")
    p.add_argument("--rf-length", type=float, default=None, help="laser-camera distance RFlength in cells "
                   "(default: the station's laser scanner, 76; the standoff is kept)")  # fmt: skip
    p.add_argument("--aim", default="centre", help="centre or edge_midpoints (default centre)")
    p.add_argument("--noise", type=float, default=0.0, help="depth noise sigma in cells (default 0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--motion", default="angular", help="Pohyb model: angular, distance or none")
    p.add_argument("--kolmost-weight", type=float, default=0.5, help="w of Kolmost = w cos a + 1 - w, in (0, 1)")
    p.add_argument("--block-unknown", action="store_true", help="unknown cells also block the circle of visibility")
    p.add_argument("--max-measurements", type=int, default=None, help="measurement budget (default none)")
    p.add_argument("--max-time", type=float, default=None, help="time budget in seconds (default none)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--summary", type=Path, default=None, help="write all summaries to this JSON file")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return p.parse_args(argv)


def _outputs(out: Path, stem: str, overwrite: bool) -> dict[str, Path]:
    """The checked paths of one run's picture and points (see :func:`output_path`)."""
    names = {"picture": f"{stem}.png", "points_csv": f"{stem}_points.csv", "points_ply": f"{stem}_points.ply"}
    return {
        key: output_path(name, overwrite, what="output file", base=out, make_parents=True)
        for key, name in names.items()
    }


def main(argv=None) -> int:
    return run_main(lambda: _main(argv), prog="nbv2d")


def _main(argv=None) -> int:
    args = _parse(argv)
    summary_path = (
        output_path(args.summary, args.overwrite, what="--summary", make_parents=True) if args.summary else None
    )
    try:
        from agiprobot_measurement.nbv.planar.evaluation import (
            coverage,
            measurable_boundary,
            plannable_boundary,
            summarize,
        )
        from agiprobot_measurement.nbv.planar.families import make_body
        from agiprobot_measurement.nbv.planar.loop import run
        from agiprobot_measurement.nbv.planar.objects import OBJECT_NAMES, load_object_file, make_object
        from agiprobot_measurement.nbv.planar.painting import paint_rf
        from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D
        from agiprobot_measurement.nbv.planar.run_config import RunConfig
        from agiprobot_measurement.nbv.planar.scoring import ScoreConfig

        for name, value in (("--noise", args.noise), ("--rf-length", args.rf_length), ("--max-time", args.max_time)):
            if value is not None and not math.isfinite(value):
                raise NbvInputError(f"{name} must be a finite number, got {value}")
        cfg = RunConfig(
            script=args.script,
            aim=args.aim,
            noise_sigma_cells=args.noise,
            seed=args.seed,
            score=ScoreConfig(kolmost_weight=args.kolmost_weight, motion=args.motion),
            block_unknown=args.block_unknown,
            max_measurements=args.max_measurements,
            max_time_s=args.max_time,
        )
        rf = RangeFinder2D.from_config()
        if args.rf_length is not None:
            rf = rf.with_length(args.rf_length)
        if args.object_image is not None:
            bodies = [(args.object_image.stem, load_object_file(args.object_image))]
        elif args.object == "all":
            bodies = [(n, make_object(n)) for n in OBJECT_NAMES]
        else:
            bodies = [(args.object, make_body(args.object))]
        stem_of = {
            name: f"{name}_{cfg.script}_{cfg.aim}_L{rf.rf_length_cells:.0f}_n{cfg.noise_sigma_cells:g}_s{cfg.seed}"
            for name, _ in bodies
        }
        outputs = {name: _outputs(args.out, stem, args.overwrite) for name, stem in stem_of.items()}
        args.out.mkdir(parents=True, exist_ok=True)
        summaries = []
        for name, truth in bodies:
            result = run(truth, rf, cfg)
            # coverage of the cells a view planned onto them (with this aim) can see; the any-ray figure beside it
            measurable = plannable_boundary(truth, rf, cfg.aim)
            summary = summarize(result, measurable, name)
            summary["coverage_any_ray"] = coverage(result.model, measurable_boundary(truth, rf))
            title = (
                f"{name} / {cfg.script} / aim {cfg.aim} / RFlength {rf.rf_length_cells:.0f} / noise "
                f"{cfg.noise_sigma_cells:g}: coverage {summary['coverage']:.1%}, {summary['measurements']} "
                f"measurements, path {summary['path_length_cells']:.0f}, {summary['transfers']} transfers"
            )
            files = outputs[name]
            writers = {
                "picture": partial(paint_rf, result, title=title, measurable=measurable),
                "points_csv": partial(result.points.export_csv, model=result.model),
                "points_ply": partial(result.points.export_ply, model=result.model),
            }
            for key, write in writers.items():
                summary[key] = str(write_output(files[key], write, suffix=files[key].suffix))
            summaries.append(summary)
            print(
                f"{name:14s} {cfg.script:8s} coverage {summary['coverage']:6.1%} of {summary['measurable_cells']} "
                f"measurable | {summary['measurements']:4d} meas | path {summary['path_length_cells']:7.0f} | "
                f"transfers {summary['transfers']:3d} | D0 {summary['d0_count']} | unmeasurable "
                f"{summary['unmeasurable_candidates']:3d} | {summary['termination']} | {summary['run_time_s']:.1f} s"
            )
        if summary_path is not None:
            write_output(summary_path, json.dumps(summaries, indent=2))
    except NbvInputError as exc:
        print(f"nbv2d: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
