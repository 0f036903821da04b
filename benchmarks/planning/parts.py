"""Every real part planned on the fixture and executed on the simulated scanner, without ROS.

The parts are those of ``parts/`` and ``../shared/parts`` (beside the checkout), each in its own unit as the
folders' README tables give it (STEP files carry theirs). Each part runs in a fresh process (so the peak memory
is its own): loaded, placed on the fixture (``placement='fixture'``: lowest point on the fixture's top, centred),
planned with TrajectoryManager (0.03 points/mm^2, 12 orientations, IP_basic by default), and the plan's
measurement segments are replayed through the simulated laser line scanner (profiles at 100 Hz from the
laser_emitter_frame's pose along each measurement trajectory). Per part it prints: samples, candidates, time
per stage, peak memory, views, the three coverage numbers (metrologically coverable, coverable by executable
views, covered), the measured coverage and the predicted-vs-measured gap (percentage points, both shares of the
points coverable by executable views). A part the planner refuses (bad mesh, nothing measurable) gets its
error in the table instead. ``--json FILE`` writes everything for comparison across commits.

    python -m benchmarks.planning.parts                       # tilt none, every part
    python -m benchmarks.planning.parts --tilt full --json full.json
    python -m benchmarks.planning.parts --parts featuretype.STL plate_holes.STL
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.sensors.laser_line.simulator import (
    LaserLineScannerSimulator,
    StitchedCloud,
    measured_samples,
)
from benchmarks.harness import (
    ROOT,
    ChildFailed,
    Target,
    child_command,
    format_targets,
    load_conditions,
    peak_rss_mb,
    run_json,
    write_json,
)

CONDITIONS = load_conditions("planning_parts")
PART_DIRS = tuple((ROOT / folder).resolve() for folder in CONDITIONS["part_dirs"])
DENSITY = CONDITIONS.number("density_points_per_mm2", low=0.0)
ORIENTATIONS = CONDITIONS.whole("orientations", low=1)
THRESHOLD_MM = CONDITIONS.number("threshold_mm", low=0.0)
PROFILE_RATE_HZ = CONDITIONS.number("profile_rate_hz", low=0.0)
MEASURED_RADIUS_MM = CONDITIONS.number("measured_radius_mm", low=0.0)
DEFAULTS = CONDITIONS.mapping("defaults")
TARGETS = CONDITIONS.mapping("targets")
#: the README tables' words for a unit that are not a unit name
UNIT_WORDS = {"none": "dm", "-": "mm", "inch": "inch", "in": "inch"}
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".step", ".stp")


def readme_units(folder: Path) -> dict[str, str]:
    """{file name: unit} from the folder's README table (a `| \\`file\\` | ... |` row; the unit is the column
    headed 'unit'); parts not listed are mm."""
    readme = folder / "README.md"
    if not readme.is_file():
        return {}
    units, column = {}, None
    for line in readme.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if column is None and "unit" in cells:
            column = cells.index("unit")
            continue
        if column is None or len(cells) <= column or not cells[0].startswith("`"):
            continue
        word = cells[column].split()[0].lower() if cells[column] else "-"
        unit = UNIT_WORDS.get(word, word)
        for name in re.findall(r"`([^`]+)`", cells[0]):
            units[name] = unit
        extra = re.search(r"\(\+ `?(\.[A-Za-z]+)`?\)", cells[0])
        if extra:  # "`featuretype.STL` (+ `.STEP`)": the STEP carries its own unit
            stem = Path(re.findall(r"`([^`]+)`", cells[0])[0]).stem
            units[stem + extra.group(1)] = "mm"
    return units


def discover(names: list[str] | None) -> list[tuple[Path, str]]:
    """(path, unit) of every part, the first folder winning for a name that is in both."""
    found: dict[str, tuple[Path, str]] = {}
    for folder in PART_DIRS:
        if not folder.is_dir():
            continue
        units = readme_units(folder)
        for path in sorted(folder.iterdir()):
            if path.suffix.lower() in MESH_SUFFIXES and path.name not in found:
                found[path.name] = (path, units.get(path.name, "mm"))
    if names:
        missing = [n for n in names if n not in found]
        if missing:
            raise SystemExit(f"error: unknown part(s) {', '.join(missing)}; known: {', '.join(found)}")
        return [found[n] for n in names]
    return list(found.values())


def measure_plan(manager, ordered) -> dict:
    """Replay the plan's measurement segments through the simulated scanner; measured vs predicted coverage."""
    scanner = LaserLineScannerSimulator(manager.sensor_model, seed=manager.seed)
    scanner.set_target(manager.part.mesh)
    cloud = StitchedCloud()
    for view in ordered:
        trajectory = view.get_trajectory_for_measurement()
        times = np.arange(0.0, trajectory.duration, 1.0 / PROFILE_RATE_HZ)
        positions, _, _ = trajectory.sample(np.append(times, trajectory.duration))
        poses = manager.kinematics.fk_batch(positions)
        poses[:, :3, 3] *= 1000.0  # m -> mm
        for start in range(0, len(poses), 200):
            cloud.add(scanner.profiles(poses[start : start + 200]))
    samples = manager.samples.points
    measured = measured_samples(samples, cloud.points(), MEASURED_RADIUS_MM)
    executable = manager.coverable_mask()
    predicted = np.isfinite(manager.point_uncertainties())
    n = int(executable.sum())
    predicted_share = float(predicted[executable].mean()) if n else 0.0
    measured_share = float(measured[executable].mean()) if n else 0.0
    return {
        "measured_points": len(cloud.points()),
        "profiles": int(cloud.profiles),
        "measured_samples": int(measured.sum()),
        "predicted_coverage": predicted_share,
        "measured_coverage": measured_share,
        "predicted_minus_measured_points": round(100.0 * (predicted_share - measured_share), 3),
    }


def run_one(path: str, unit: str, tilt: str, solver: str, time_limit_s: float, seed: int) -> dict:
    warnings.simplefilter("ignore")
    out: dict = {"part": Path(path).name, "unit": unit, "tilt": tilt, "solver": solver}
    t0 = time.perf_counter()
    try:
        manager = TrajectoryManager(seed=seed)
        manager.load_target_mesh(path, units=unit, placement="fixture")
        ordered = manager.plan(
            DENSITY,
            THRESHOLD_MM,
            ORIENTATIONS,
            tilt,
            solver,
            time_limit_s=time_limit_s,
            started_s=t0,  # the limit counts from the part's loading, as on the command line
            min_planning_time=CONDITIONS["min_planning_time_s"],
        )
    except AgiprobotError as exc:
        out.update(error=f"{type(exc).__name__}: {exc}", total_s=round(time.perf_counter() - t0, 2))
        out["peak_mb"] = round(peak_rss_mb(), 1)
        return out
    total = time.perf_counter() - t0
    report = manager.coverage_report()
    t = manager.timings_s
    out.update(
        samples=report.n_samples,
        candidates=report.n_candidates,
        valid_viewpoints=report.n_valid_candidates,
        reachable_share=report.reachable_share,
        views=report.n_views,
        unconnected_views=report.unconnected_views,
        coverable_metrology=report.n_coverable_metrology,
        coverable_executable=report.n_coverable,
        covered=report.n_covered,
        unverified=report.n_unverified,
        verified_share=round(report.verified_share, 6),
        views_lower_bound=report.views_lower_bound,
        dropped_views=len(report.dropped_views),
        covered_of_executable=round(report.coverage_of_coverable, 5),
        solver_gap=report.solver_gap,
        time_limit_hit=report.time_limit_hit,
        candidates_evaluated_share=round(report.candidates_evaluated_share, 4),
        tilt_choice=manager.parameters.get("tilt_choice", tilt),
        estimated_execution_s=round(report.estimated_execution_time_s, 2),
        scan_lines_verified=t.get("scan_lines_verified", 0),
        dropped_dominated=0 if manager.last_stream_stats is None else manager.last_stream_stats.dropped_views,
        revived_views=manager.revived_views,
        set_cover_rounds=t.get("set_cover_rounds", 0),
        time_s={
            "placement_check": round(t.get("placement_check", 0.0), 3),
            "sampling": round(t.get("sampling", 0.0), 3),
            "metrology": round(t.get("anchor_reachability", 0.0) + t.get("metrology", 0.0), 3),
            "mechanics": round(t.get("mechanics", 0.0), 3),
            "set_cover": round(t.get("set_cover", 0.0), 3),
            "connection": round(t.get("connection", 0.0), 3),
            "total": round(total, 3),
        },
        warnings=list(report.warnings),
    )
    t1 = time.perf_counter()
    out.update(measure_plan(manager, ordered))
    out["time_s"]["simulated_execution"] = round(time.perf_counter() - t1, 3)
    out["peak_mb"] = round(peak_rss_mb(), 1)
    return out


def row(r: dict) -> str:
    if "error" in r:
        return f"{r['part']:<22} {r['unit']:<5} refused in {r['total_s']:.1f} s: {r['error'][:150]}"
    t = r["time_s"]
    return (
        f"{r['part']:<22} {r['unit']:<5} {r['samples']:>6} {r['candidates']:>7} {t['metrology']:>6.1f} "
        f"{t['mechanics']:>6.1f} {t['set_cover']:>6.1f} {t['connection']:>5.1f} {t['total']:>6.1f} "
        f"{r['peak_mb']:>6.0f} {r['views']:>5} {r['coverable_metrology']:>6} {r['coverable_executable']:>6} "
        f"{r['covered']:>6} {100 * r['covered_of_executable']:>6.1f} {100 * r['measured_coverage']:>6.1f} "
        f"{r['predicted_minus_measured_points']:>+6.1f}"
    )


HEADER = (
    f"{'part':<22} {'unit':<5} {'samp':>6} {'cands':>7} {'metro':>6} {'mech':>6} {'cover':>6} {'conn':>5} "
    f"{'total':>6} {'MB':>6} {'views':>5} {'meas':>6} {'exec':>6} {'cov':>6} {'cov%':>6} {'msd%':>6} {'gap':>6}"
)


def target_checks(results: list[dict], tilt: str) -> list[Target]:
    """Per target the parts that missed it (all planned parts are held to it; refused parts are not counted)."""
    limit, peak = TARGETS["total_s"][tilt], TARGETS["peak_mb"]
    share, gap = TARGETS["covered_of_executable"], TARGETS["predicted_minus_measured_points"]
    planned = [r for r in results if "error" not in r]
    checks = (
        ("total time", f"<= {limit:g} s", lambda r: r["time_s"]["total"] <= limit),
        ("peak memory", f"<= {peak:g} MB", lambda r: r["peak_mb"] <= peak),
        ("covered of executable", f">= {100 * share:g} %", lambda r: r["covered_of_executable"] >= share),
        ("|predicted - measured|", f"<= {gap:g} points", lambda r: abs(r["predicted_minus_measured_points"]) <= gap),
    )
    targets = []
    for name, bound, holds in checks:
        missed = [r["part"] for r in planned if not holds(r)]
        measured = "missed by " + ", ".join(missed) if missed else f"all {len(planned)} planned parts"
        targets.append(Target(name, measured, bound, not missed))
    return targets


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tilt", default=DEFAULTS["tilt"], choices=("none", "limited", "full", "auto"))
    parser.add_argument("--solver", default=DEFAULTS["solver"])
    parser.add_argument(
        "--time-limit", type=float, default=DEFAULTS["time_limit_s"], help="whole-plan time limit per part (s)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="*", help="file names to run (default: all)")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--one", nargs=2, metavar=("PATH", "UNIT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        result = run_one(args.one[0], args.one[1], args.tilt, args.solver, args.time_limit, args.seed)
        print(json.dumps(result))
        return 0
    parts = discover(args.parts)
    print(
        f"{len(parts)} parts at {DENSITY} points/mm^2, {ORIENTATIONS} orientations, tilt {args.tilt}, {args.solver}, "
        f"placed on the fixture; times in s (metro = reachability + metrology), peak memory MB; meas / exec / cov = "
        "metrologically coverable / coverable by executable views / covered samples; cov% = covered of exec; "
        "msd% = measured of exec (simulated scanner); gap = predicted - measured (points)"
    )
    print(HEADER, flush=True)
    results = []
    for path, unit in parts:
        command = child_command(__spec__.name, "--one", path, unit, "--tilt", args.tilt, "--solver", args.solver)
        command += ["--time-limit", str(args.time_limit), "--seed", str(args.seed)]
        try:
            result = run_json(command)
        except ChildFailed as exc:
            result = {"part": path.name, "unit": unit, "error": f"crashed: {exc}", "total_s": 0.0}
        results.append(result)
        print(row(result), flush=True)
    print("targets:")
    print(format_targets(target_checks(results, args.tilt)))
    if args.json:
        write_json(args.json, {"settings": vars(args), "results": results})
        print(f"written: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
