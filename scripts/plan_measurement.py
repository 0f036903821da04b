#!/usr/bin/env python3
"""Plan a measurement of a part from the command line (no roscore needed).

Runs the TrajectoryManager pipeline (sampling, metrology, mechanics, set cover, connection) with a progress
bar per stage and prints a summary. Writes the execution plan only with -o, the coverage picture only with
--report and a summary file only with --summary.

examples:
  plan_measurement.py parts/objectA_wuerfel.stl -o cube_plan.yaml --report cube.png
  plan_measurement.py parts/featuretype.STL --units inch --tilt full --solver greedy --transform 0 0 0 0 0 90
  plan_measurement.py ../shared/parts/plate_holes.STL --place fixture --tilt auto --time-limit 120

placement: the part's CAD frame goes to the scene's part pose (config/scene.yaml, on the fixture's top) times
--transform; --place fixture instead sets the part's lowest point on the fixture's top, centred, turned by
--transform's rotation and shifted by its translation. A part that overlaps the table, the fixture, another
scene object or the robot is refused with the object, the depth and the lift that clears it.

files: -o, --report and --summary are written where they are named: absolute, or relative to --output-dir (default:
the working directory), '..' and '~' included; every file is written atomically; an existing file is replaced only
with --overwrite. A request beyond the work budget (config/trajectory_manager.yaml, section
budget: samples, candidate viewpoints, memory) is refused before any work, with the estimate.

exit status: 0 planned; 2 bad input or nothing plannable (one 'error: ...' line); 1 internal error;
130 interrupted (Ctrl-C), 143 terminated (SIGTERM): the files written before are named, no half-written file is
left.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
try:
    import agiprobot_measurement  # noqa: F401
except ImportError:  # run from a checkout without the catkin environment
    sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402

from agiprobot_measurement.common.cli import (  # noqa: E402
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    process_started_s,
)
from agiprobot_measurement.common.files import output_path, write_output  # noqa: E402
from agiprobot_measurement.common.geometry import pose_matrix  # noqa: E402
from agiprobot_measurement.common.units import UNIT_SCALES_TO_M  # noqa: E402

# Only light modules here: bad input is reported before trimesh, FCL and OMPL are loaded (about 1 s).
from agiprobot_measurement.errors import InputError  # noqa: E402
from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES  # noqa: E402
from agiprobot_measurement.planning.plan.plan_io import plan_path  # noqa: E402
from agiprobot_measurement.planning.report.progress import STAGES  # noqa: E402
from agiprobot_measurement.planning.request import (  # noqa: E402
    PLACEMENTS,
    REQUEST_TILT_MODES,
    PlanRequest,
    PlanRequestError,
    load_work_budget,
)

#: how the request's fields are named in messages: by their options
OPTION_LABELS = {
    "part_file": "part",
    "units": "unit",
    "viewpoint_tilt_mode": "tilt mode",
    "solver_type": "solver",
    "sampling_density": "--density (points/mm^2)",
    "uncertainty_threshold_mm": "--threshold (mm)",
    "scan_speed_mm_s": "--scan-speed (mm/s)",
    "set_cover_time_limit_s": "--ip-time-limit (s)",
    "time_limit_s": "--time-limit (s)",
    "set_cover_mip_gap": "--mip-gap",
    "placement": "--place",
    "min_reachable_share": "--min-reachable-share",
    "tessellation_tolerance_mm": "--tessellation-tolerance (mm)",
    "orientations_around_boresight": "--orientations",
    "part_transform_mm": "--transform",
    "workers": "--workers",
    "scheduler": "--scheduler",
    "max_memory_gb": "--max-memory (GB)",
}
BAR_FORMAT = "{desc} {percentage:3.0f}%|{bar:30}| "


class UsageError(InputError):
    """Bad command-line input: reported as one 'error: ...' line, exit status 2."""


class OutputWriteError(InputError):
    """An output file could not be written (a full disk, permissions): names the file and what was written."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so that a file being written is removed, not left half."""


#: exit status after SIGTERM (128 + 15, as a shell reports a process ended by it)
EXIT_TERMINATED = 143
#: the output files this run has written so far (kind, path), for the message of an interruption or a failure
WRITTEN: list[tuple[str, Path]] = []


def _terminate(signum, frame):
    raise Terminated()


def _written() -> str:
    if not WRITTEN:
        return "nothing written"
    return "written before: " + ", ".join(f"{kind} {path}" for kind, path in WRITTEN)


def _write(kind: str, path, write):
    """``write()`` (an output's atomic write), its file recorded in :data:`WRITTEN`; an ``OSError`` as
    :class:`OutputWriteError` naming the file."""
    try:
        result = write()
    except OSError as exc:
        raise OutputWriteError(f"{path}: cannot write the {kind}: {exc.strerror or exc}; {_written()}") from exc
    WRITTEN.append((kind, Path(path)))
    return result


class _Parser(argparse.ArgumentParser):
    # argparse prints the whole usage and 'prog: error:'; one plain line is easier to read and to grep
    def error(self, message):
        raise UsageError(f"{message} (see --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="plan_measurement.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    d = PlanRequest.from_defaults()  # config/trajectory_manager.yaml, as for the node
    parser.add_argument("part", help="mesh file of the part (STL, OBJ, PLY, STEP, ...)")
    parser.add_argument("--units", default=d.units, help=f"length unit of the file: {', '.join(UNIT_SCALES_TO_M)}")
    parser.add_argument(
        "--density", type=float, default=d.sampling_density, help=f"samples per mm^2 (default {d.sampling_density:g})"
    )
    parser.add_argument(
        "--orientations",
        type=int,
        default=d.orientations_around_boresight,
        help=f"orientations around the boresight ({d.orientations_around_boresight})",
    )
    parser.add_argument(
        "--tilt",
        default=d.viewpoint_tilt_mode,
        help=f"viewpoint tilt mode: {', '.join(REQUEST_TILT_MODES)} ({d.viewpoint_tilt_mode}); auto tries none, then "
        "full when the cover is large or coverage short, and reports the choice",
    )
    parser.add_argument("--solver", default=d.solver_type, help=f"set cover solver: {', '.join(SOLVER_TYPES)}")
    parser.add_argument(
        "--threshold",
        type=float,
        default=d.uncertainty_threshold_mm,
        help=f"uncertainty threshold in mm ({d.uncertainty_threshold_mm:g})",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=d.time_limit_s,
        help=f"time limit of the whole plan in s ({d.time_limit_s:g}): the best verified plan and its gap then",
    )
    parser.add_argument(
        "--ip-time-limit",
        type=float,
        default=d.set_cover_time_limit_s,
        help=f"time limit of one IP solve in s ({d.set_cover_time_limit_s:g})",
    )
    parser.add_argument(
        "--mip-gap",
        type=float,
        default=d.set_cover_mip_gap,
        help=f"relative optimality gap at which an IP solve may stop ({d.set_cover_mip_gap:g})",
    )
    parser.add_argument(
        "--place",
        default=d.placement,
        help=f"placement of the part: {', '.join(PLACEMENTS)} ({d.placement}); fixture = lowest point on the "
        "fixture's top, centred",
    )
    parser.add_argument(
        "--min-reachable-share",
        type=float,
        default=d.min_reachable_share,
        help=f"warn when fewer samples have a reachable anchor ({d.min_reachable_share:g})",
    )
    parser.add_argument(
        "--tessellation-tolerance",
        type=float,
        default=d.tessellation_tolerance_mm,
        help="linear deflection of STEP tessellation in mm (0 = the reader's default)",
    )
    parser.add_argument(
        "--transform",
        nargs=6,
        type=float,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="placement of the part relative to the scene's part pose: mm and degrees (URDF roll-pitch-yaw)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=d.workers,
        help="evaluate the candidates on a local Dask cluster of N worker processes (0 = in this process)",
    )
    parser.add_argument(
        "--scheduler",
        default=d.scheduler,
        metavar="ADDRESS",
        help="evaluate the candidates on the existing Dask cluster at ADDRESS (tcp://host:8786); the plan is the same",
    )
    parser.add_argument(
        "--max-memory",
        type=float,
        default=d.max_memory_gb,
        metavar="GB",
        help="memory budget of the candidate store in GB (0 = 80 %% of the memory available); larger work is "
        "refused with its estimate",
    )
    parser.add_argument("--scene", help="scene file (default: config/scene.yaml)")
    parser.add_argument("--no-mirrors", action="store_true", help="leave out the scene's wbk_mirrors obstacles")
    parser.add_argument(
        "--scan-speed",
        type=float,
        default=d.scan_speed_mm_s,
        help=f"tip speed while measuring in mm/s ({d.scan_speed_mm_s:g})",
    )
    parser.add_argument("--seed", type=int, default=d.seed, help=f"seed of sampling and planning ({d.seed})")
    parser.add_argument("-o", "--output", help="write the execution plan here (.yaml is appended if missing)")
    parser.add_argument("--report", help="write a coverage picture here (.png)")
    parser.add_argument("--summary", help="write the summary here (.yaml/.yml: YAML, else text)")
    parser.add_argument(
        "--output-dir",
        default=".",
        help="the folder relative -o, --report and --summary names resolve in (working directory)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    return parser


def _output(
    path: str | None, what: str, output_dir: Path, overwrite: bool, suffixes: tuple[str, ...] = ()
) -> Path | None:
    """The path of an output file (see :func:`output_path`), checked before any work starts."""
    if path is None:
        return None
    try:
        target = output_path(path, overwrite, what=what, base=output_dir)
    except InputError as exc:
        raise UsageError(str(exc)) from exc
    if suffixes and target.suffix.lower() not in suffixes:
        raise UsageError(f"{what} {path} must end in {' or '.join(suffixes)}")
    return target


def validate(args: argparse.Namespace) -> PlanRequest:
    """Check every argument before any work starts; returns the planning request (transform in mm)."""
    transform = np.eye(4)
    if args.transform is not None:
        values = np.array(args.transform, dtype=float)
        if not np.all(np.isfinite(values)):
            raise UsageError(
                f"--transform needs 6 finite numbers (x y z in mm, roll pitch yaw in deg), got {args.transform}"
            )
        transform = pose_matrix(values[:3], np.deg2rad(values[3:]))
    # every option has its value (its default is the configured one): 0 is a value here, not 'not given'
    request = dataclasses.replace(
        PlanRequest.from_defaults(),
        part_file=args.part,
        units=args.units,
        sampling_density=args.density,
        orientations_around_boresight=args.orientations,
        viewpoint_tilt_mode=args.tilt,
        solver_type=args.solver,
        uncertainty_threshold_mm=args.threshold,
        set_cover_time_limit_s=args.ip_time_limit,
        time_limit_s=args.time_limit,
        set_cover_mip_gap=args.mip_gap,
        placement=args.place,
        min_reachable_share=args.min_reachable_share,
        tessellation_tolerance_mm=args.tessellation_tolerance,
        workers=args.workers,
        scheduler=args.scheduler,
        max_memory_gb=args.max_memory,
        scan_speed_mm_s=args.scan_speed,
        seed=args.seed,
        add_wbk_mirrors=not args.no_mirrors,
        part_transform_mm=transform,
    )
    try:
        request = request.validate(labels=OPTION_LABELS)
    except PlanRequestError as exc:
        raise UsageError(str(exc)) from exc
    if args.scene is not None and not Path(args.scene).is_file():
        raise UsageError(f"scene file not found: {args.scene}")
    output_dir = Path(args.output_dir).expanduser()
    if not output_dir.is_dir():
        raise UsageError(f"--output-dir {output_dir} is not a directory")
    args.output = _output(
        None if args.output is None else str(plan_path(args.output)), "plan", output_dir, args.overwrite
    )
    args.report = _output(args.report, "report", output_dir, args.overwrite, (".png",))
    args.summary = _output(args.summary, "summary", output_dir, args.overwrite)
    args.work_budget = load_work_budget()
    return request


class StageProgress:
    """The TrajectoryManager progress callback: one tqdm bar per stage on a terminal, plain lines otherwise.

    Set cover and mechanics alternate (each round verifies the views it picked), so every stage keeps its own
    bar at a fixed line instead of one bar replacing the other.
    """

    def __init__(self, enabled: bool, terminal: bool):
        self.enabled = enabled
        self.terminal = terminal
        self.bars: dict = {}
        self.first: dict[str, float] = {}
        self.t0 = time.perf_counter()

    def __call__(self, stage: str, fraction: float, message: str) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not self.terminal:
            if fraction >= 1.0:
                print(f"[{now - self.t0:7.1f} s] {stage}: {message}", file=sys.stderr, flush=True)
            return
        bar = self.bars.get(stage)
        if bar is None:
            from tqdm import tqdm

            bar = tqdm(
                total=1000,
                desc=f"{stage:<10}",
                position=len(self.bars),
                leave=True,
                file=sys.stderr,
                # tqdm's own elapsed time runs on until the bar is closed, i.e. the end of planning: each bar
                # shows the time from the stage's first to its latest report instead
                bar_format=BAR_FORMAT,
                dynamic_ncols=True,
            )
            self.bars[stage] = bar
            self.first[stage] = now
        bar.n = round(1000 * fraction)
        # tqdm puts ', ' before a postfix; the status is written into the format instead (braces escaped)
        status = f"{now - self.first[stage]:6.1f} s  {message}".replace("{", "{{").replace("}", "}}")
        bar.bar_format = BAR_FORMAT + status
        bar.refresh()

    def write(self, text: str) -> None:
        if self.bars:
            from tqdm import tqdm

            tqdm.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
        self.bars.clear()


class _ProgressLogHandler(logging.Handler):
    # log lines printed straight to stderr would tear the progress bars apart
    def __init__(self, progress: StageProgress):
        super().__init__(logging.WARNING)
        self.progress = progress

    def emit(self, record: logging.LogRecord) -> None:
        self.progress.write(f"{record.levelname.lower()}: {record.getMessage()}")


def stage_times(manager, mechanics_s: float) -> dict[str, float]:
    t = manager.timings_s
    set_cover_and_mechanics = t.get("set_cover_and_mechanics", 0.0)
    return {
        "sampling": t.get("sampling", 0.0),
        "metrology": t.get("anchor_reachability", 0.0) + t.get("metrology", 0.0) + t.get("viewpoint_objects", 0.0),
        "mechanics": mechanics_s,
        "set cover": manager.timings_s.get("set_cover", max(0.0, set_cover_and_mechanics - mechanics_s)),
        "connection": t.get("connection", 0.0),
    }


def _unverified_cause(report) -> str:
    """Why some measurable points' views were never verified."""
    return "time limit" if report.time_limit_hit else "the set cover's rounds ended before them"


def _bound_text(report) -> str:
    """The view count's proven lower bound (the set cover's LP-based bound) as the summary states it."""
    if report.solver == "greedy":
        return "greedy gives no lower bound"
    if report.solver != "IP_basic":
        return "no view-count bound (the objective is not the view count)"
    if report.views_lower_bound is None:
        return "lower bound: none known"
    over = " (of covers by verified views)" if report.time_limit_hit else ""
    return f"lower bound {math.ceil(report.views_lower_bound - 1e-6)} views{over}"


def summarise(args, manager, report, times: dict, total_s: float, outputs: dict) -> tuple[list, dict]:
    """(rows for the table, a plain mapping for --summary YAML)."""
    result = manager.last_set_cover
    if report.solver_gap is None:
        gap_text = "none (greedy gives no bound)"
    elif result is not None and result.proven_optimal:
        gap_text = "0 % (proven optimal)"
    else:
        gap_text = f"{100.0 * report.solver_gap:.2f} % (allowed {100 * args.mip_gap:g} %)"
    if report.solver == "IP_basic" and report.views_lower_bound is not None:
        bound = math.ceil(report.views_lower_bound - 1e-6)
        excess_text = f"{report.n_views - bound} ({report.n_views} views, LP bound {bound}; MIP gap {gap_text})"
    elif report.solver_gap is None:
        excess_text = "unknown (the final cover is greedy's: no bound)"
    else:
        excess_text = f"unknown (MIP gap {gap_text})"
    if report.time_limit_hit:
        excess_text += (
            f"; the time limit ({args.time_limit:g} s) stopped the verification: the bound is that of covers by "
            "verified views"
        )
    samples = report.n_samples
    dropped = f", {len(report.dropped_views)} dropped (below)" if report.dropped_views else ""
    rows = []
    if report.time_limit_hit:
        rows.append(
            (
                "STOPPED BY THE TIME LIMIT",
                f"{args.time_limit:g} s: "
                + (
                    f"the metrology evaluated {100.0 * report.candidates_evaluated_share:.0f} % of the candidates, "
                    if report.candidates_evaluated_share < 1.0
                    else ""
                )
                + f"{100.0 * report.verified_share:.1f} % of the measurable points verified; "
                "raise --time-limit for a complete plan",
            )
        )
    rows += [
        ("part", f"{args.part} ({args.units})"),
        ("samples", f"{samples} ({args.density:g} points/mm^2)"),
        ("candidates", f"{report.n_candidates} ({args.orientations} orientations, tilt {args.tilt})"),
        ("valid viewpoints", f"{report.n_valid_candidates}"),
        ("views chosen", f"{report.n_views} ({args.solver}{dropped}); {_bound_text(report)}"),
        ("placement", f"{args.place}, reachable anchors for {_share(report.reachable_share)} of the samples"),
        ("tilt", str(manager.parameters.get("tilt_choice", args.tilt))),
        ("measurable (metrology)", f"{report.n_coverable_metrology} of {samples} samples"),
        (
            "measurable, executable",
            f"{report.n_coverable} of {samples} samples"
            + (
                f" ({report.n_unverified} more not verified: {_unverified_cause(report)})"
                if report.n_unverified
                else ""
            ),
        ),
        (
            "verified",
            f"{100.0 * report.verified_share:.1f} % of the measurable points "
            f"({report.n_coverable_metrology - report.n_unverified} of {report.n_coverable_metrology})",
        ),
        (
            "covered",
            f"{report.n_covered} = {100.0 * report.coverage_of_coverable:.1f} % of executable, "
            f"{100.0 * report.coverage_of_metrology:.1f} % of measurable",
        ),
        ("coverage of all samples", f"{100.0 * report.coverage_of_samples:.1f} % ({report.n_covered} of {samples})"),
        (
            "est. execution time",
            f"{report.estimated_execution_time_s:.1f} s (measuring {report.measurement_time_s:.1f} s, "
            f"connecting {report.connection_time_s:.1f} s)",
        ),
        (
            "predicted uncertainty",
            f"mean {report.mean_uncertainty_mm:.4f} mm, max {report.max_uncertainty_mm:.4f} mm "
            f"(threshold {args.threshold:g} mm)",
        ),
        ("views - lower bound of the final cover", excess_text),
    ]
    for item in report.dropped_views:
        rows.append(("dropped view", f"{item['view']}: {item['reason']}"))
    for text in report.warnings:
        if not text.startswith("view ") or " dropped: " not in text:  # listed above
            rows.append(("warning", text))
    for stage in STAGES:
        rows.append((f"time: {stage}", f"{times[stage]:.2f} s"))
    rows.append(("time: total", f"{total_s:.2f} s"))
    for what, path in outputs.items():
        rows.append((f"output: {what}", str(path)))
    data = {
        "part": str(args.part),
        "units": args.units,
        "parameters": {
            "density_points_per_mm2": args.density,
            "orientations": args.orientations,
            "tilt": args.tilt,
            "placement": args.place,
            "time_limit_s": args.time_limit,
            "mip_gap": args.mip_gap,
            "solver": args.solver,
            "threshold_mm": args.threshold,
            "scan_speed_mm_s": args.scan_speed,
            "seed": args.seed,
            "transform_mm_deg": None if args.transform is None else [float(v) for v in args.transform],
            "mirrors": not args.no_mirrors,
        },
        "samples": samples,
        "candidates": report.n_candidates,
        "valid_viewpoints": report.n_valid_candidates,
        "views": report.n_views,
        "unconnected_views": report.unconnected_views,
        "dropped_views": report.dropped_views,
        "views_lower_bound": report.views_lower_bound,
        "verified_share": round(report.verified_share, 6),
        "coverable_metrology": report.n_coverable_metrology,
        "coverable": report.n_coverable,
        "coverable_executable": report.n_coverable,
        "unverified": report.n_unverified,
        "covered": report.n_covered,
        "reachable_share": report.reachable_share,
        "tilt_choice": manager.parameters.get("tilt_choice", args.tilt),
        "time_limit_hit": report.time_limit_hit,
        "candidates_evaluated_share": round(report.candidates_evaluated_share, 6),
        "warnings": list(report.warnings),
        "coverage_of_coverable": round(report.coverage_of_coverable, 6),
        "coverage_of_samples": round(report.coverage_of_samples, 6),
        "estimated_execution_time_s": round(report.estimated_execution_time_s, 3),
        "mean_uncertainty_mm": _finite_or_none(report.mean_uncertainty_mm),
        "max_uncertainty_mm": _finite_or_none(report.max_uncertainty_mm),
        "solver_gap": report.solver_gap,
        "proven_optimal": bool(result is not None and result.proven_optimal),
        "time_s": {**{k: round(v, 3) for k, v in times.items()}, "total": round(total_s, 3)},
        "outputs": {k: str(v) if isinstance(v, Path) else None for k, v in outputs.items()},
    }
    return rows, data


def _share(value) -> str:
    return "?" if value is None else f"{100.0 * value:.1f} %"


def _finite_or_none(value: float):
    return round(float(value), 6) if math.isfinite(value) else None


def format_table(rows: list[tuple[str, str]]) -> str:
    width = max(len(label) for label, _ in rows)
    rule = "-" * (width + 2 + max(len(value) for _, value in rows))
    return "\n".join([rule, *(f"{label:<{width}}  {value}" for label, value in rows), rule])


def run(args: argparse.Namespace, request: PlanRequest, progress: StageProgress, started_s: float) -> int:
    from agiprobot_measurement.planning.part_loading import PartWarning
    from agiprobot_measurement.planning.trajectory_manager import PlanningError, TrajectoryManager
    from agiprobot_measurement.station import Station

    # the part loader both warns and logs its doubts: show them once, as 'warning: ...' lines (log handler)
    warnings.simplefilter("ignore", PartWarning)

    t0 = time.perf_counter()
    station = Station.load(scene=args.scene)
    manager = TrajectoryManager.for_request(request, station, progress=progress, work_budget=args.work_budget)
    try:
        ordered = manager.plan_request(request, started_s=started_s)
    finally:
        manager.close()  # a local Dask cluster ends with the evaluation's last use
    total_s = time.perf_counter() - t0
    manager.timings_s["total"] = total_s
    progress.close()
    report = manager.coverage_report()
    outputs = {}
    if args.output is not None:
        if not ordered:
            raise PlanningError("no view could be connected: there is no plan to write")
        segments = manager.convert_viewpointlist_to_execution_plan(ordered)
        _write("plan", args.output, lambda: manager.store_execution_plan(args.output, segments))
        outputs["plan"] = manager.last_plan_path
    if args.report is not None:
        from agiprobot_measurement.planning.report.coverage_figure import plot_coverage

        title = (
            f"{Path(args.part).name}: {report.n_views} views ({args.solver}), "
            f"{100.0 * report.coverage_of_samples:.1f} % of samples covered, "
            f"est. {report.estimated_execution_time_s:.0f} s"
        )
        outputs["report"] = _write(
            "figure",
            args.report,
            lambda: plot_coverage(
                args.report,
                manager.samples.points,
                manager.point_uncertainties(),
                manager.scan_lines_mm(),
                manager.sensor_model.get_min_uncertainty(),
                manager.sensor_model.get_max_uncertainty(),
                title=title,
                mesh=manager.target_mesh,
                metrology_coverable=manager.metrology_coverable_mask(),
                executable_coverable=manager.coverable_mask(),
            ),
        )
    if args.summary is not None:
        outputs["summary"] = args.summary
    if args.output is None:
        outputs["plan"] = "not written (give -o FILE)"
    rows, data = summarise(
        args, manager, report, stage_times(manager, manager.timings_s.get("mechanics", 0.0)), total_s, outputs
    )
    table = format_table(rows)
    if args.summary is not None:
        if args.summary.suffix.lower() in (".yaml", ".yml"):
            import yaml

            text = yaml.safe_dump(data, sort_keys=False)
        else:
            text = table + "\n"
        _write("summary", args.summary, lambda: write_output(args.summary, text))
    print(table, flush=True)
    return EXIT_OK


def main(argv=None, started_s: float | None = None) -> int:
    """The command; ``started_s`` (``time.perf_counter()``): what the time limit counts from (default: this call)."""
    started_s = time.perf_counter() if started_s is None else started_s
    progress = None
    debug = False
    WRITTEN.clear()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminate)
    try:
        args = build_parser().parse_args(argv)
        debug = args.debug
        request = validate(args)
        terminal = sys.stderr.isatty()
        progress = StageProgress(enabled=not args.quiet, terminal=terminal)
        logging.getLogger("agiprobot_measurement").addHandler(_ProgressLogHandler(progress))
        logging.getLogger("agiprobot_measurement").propagate = False
        return run(args, request, progress, started_s)
    except UsageError as exc:
        _fail(progress, f"error: {exc}")
        return EXIT_USAGE
    except ValueError as exc:
        # the package's input errors are ValueErrors: PartLoadError, ConfigError, PlanError, SetCoverError
        _fail(progress, f"error: {exc}", debug)
        return EXIT_USAGE
    except Terminated:
        _fail(progress, f"terminated: {_written()}", debug)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        _fail(progress, f"interrupted: {_written()}", debug)
        return EXIT_INTERRUPTED
    except RuntimeError as exc:
        # the module is loaded lazily (OMPL, FCL: slow imports); an error raised before it was loaded is not one
        # of its exceptions
        manager_module = sys.modules.get("agiprobot_measurement.planning.trajectory_manager")
        if manager_module is not None and isinstance(exc, manager_module.PlanningCancelled):
            _fail(progress, f"interrupted: {_written()}", debug)
            return EXIT_INTERRUPTED
        if manager_module is not None and isinstance(exc, manager_module.PlanningError):
            _fail(progress, f"error: planning failed: {exc}", debug)
            return EXIT_USAGE
        return _internal(progress, exc, debug)
    except OSError as exc:
        _fail(progress, f"error: {exc}", debug)
        return EXIT_USAGE
    except Exception as exc:
        return _internal(progress, exc, debug)


def _fail(progress: StageProgress | None, line: str, debug: bool = False) -> None:
    """Close the bars, then one line (after the traceback of the exception being handled, with --debug)."""
    if progress is not None:
        progress.close()
    if debug:
        import traceback

        traceback.print_exc()
    print(line, file=sys.stderr, flush=True)


def _internal(progress, exc: BaseException, debug: bool) -> int:
    hint = "" if debug else " (run with --debug for the traceback)"
    _fail(progress, f"error: internal error: {type(exc).__name__}: {exc}{hint}", debug)
    return EXIT_INTERNAL


if __name__ == "__main__":
    code = main(started_s=process_started_s())  # the time limit counts from the command's start
    sys.stdout.flush()
    sys.stderr.flush()
    # The OMPL bindings (nanobind) report 'leaked instances' at interpreter shutdown; that noise would bury
    # the summary and the error line, and nothing is left to clean up here.
    os._exit(code)
