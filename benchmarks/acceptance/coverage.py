"""Planning under real errors: the planner's predicted coverage against the coverage measured with the realistic
error models, per part.

Each part is planned as ``benchmarks.planning.parts`` plans it (its conditions: tilt none, IP_basic), then its measurement
segments are replayed twice on the simulated laser scanner: with the ``ideal`` model (the parts benchmark's replay)
and with the ``realistic`` one, cast from the true robot (``TrueKinematics`` at the error model's residual scale,
the head's hand-eye error, per-profile jitter) and reported through the nominal kinematics read ``latency_s``
late. A sample counts as measured when a reported point lies within the parts benchmark's radius. The gap is
predicted minus measured, in points of the samples coverable by executable views.

  python -m benchmarks.acceptance.coverage                         # every part
  python -m benchmarks.acceptance.coverage --parts objectA_wuerfel.stl busted.STL
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.motion.kinematics import TrueKinematics, load_kinematics_correction
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.sensors.error_models import LaserErrors, load_error_model
from agiprobot_measurement.sensors.laser_line.simulator import (
    LaserLineScannerSimulator,
    StitchedCloud,
    measured_samples,
    pose_chain_poses,
)
from benchmarks.planning.parts import (
    CONDITIONS,
    DEFAULTS,
    DENSITY,
    MEASURED_RADIUS_MM,
    ORIENTATIONS,
    PROFILE_RATE_HZ,
    THRESHOLD_MM,
    discover,
)


def replay(manager, ordered, error_model_name: str) -> tuple[float, int]:
    """(measured share of the executable-coverable samples, measured points) of the plan under an error model."""
    sensor = manager.sensor_model
    errors = LaserErrors.create(sensor, load_error_model(error_model_name))
    scanner = LaserLineScannerSimulator(sensor, seed=manager.seed, errors=errors)
    scanner.set_target(manager.part.mesh)
    chain = errors.pose_chain if errors is not None else None
    true_kin = None
    if chain and chain["robot_residual_scale"] > 0.0:
        _, arm, _ = load_kinematics_correction()
        true_kin = TrueKinematics(manager.kinematics, arm, chain["robot_residual_scale"])
    latency = chain["latency_s"] if chain else 0.0
    rng = np.random.default_rng(manager.seed)
    cloud = StitchedCloud()
    for view in ordered:
        trajectory = view.get_trajectory_for_measurement()
        times = np.append(np.arange(0.0, trajectory.duration, 1.0 / PROFILE_RATE_HZ), trajectory.duration)
        q, _, _ = trajectory.sample(times)
        nominal = manager.kinematics.fk_batch(q)
        if errors is None:
            true, reported = nominal, None
        else:
            q_late, _, _ = trajectory.sample(np.minimum(times + latency, trajectory.duration))
            true = true_kin.fk(q) if true_kin is not None else nominal.copy()
            reported = manager.kinematics.fk_batch(q_late)
            for poses in (true, reported):
                poses[:, :3, 3] *= 1000.0
            true, reported = pose_chain_poses(errors, true, reported, np.eye(4), None, rng)
        if reported is None:
            true = true.copy()
            true[:, :3, 3] *= 1000.0
        for start in range(0, len(true), 200):
            part = None if reported is None else reported[start : start + 200]
            cloud.add(scanner.profiles(true[start : start + 200], part))
    measured = measured_samples(manager.samples.points, cloud.points(), MEASURED_RADIUS_MM)
    executable = manager.coverable_mask()
    return (float(measured[executable].mean()) if executable.any() else 0.0), len(cloud.points())


def run_part(path, unit: str, seed: int = 0) -> dict:
    warnings.simplefilter("ignore")
    start = time.perf_counter()
    manager = TrajectoryManager(seed=seed)
    manager.load_target_mesh(str(path), units=unit, placement="fixture")
    ordered = manager.plan(
        DENSITY,
        THRESHOLD_MM,
        ORIENTATIONS,
        DEFAULTS["tilt"],
        DEFAULTS["solver"],
        time_limit_s=float(DEFAULTS["time_limit_s"]),
        min_planning_time=CONDITIONS["min_planning_time_s"],
    )
    executable = manager.coverable_mask()
    predicted = float(np.isfinite(manager.point_uncertainties())[executable].mean()) if executable.any() else 0.0
    row = {"part": path.name, "views": len(ordered), "predicted": predicted}
    for name in ("ideal", "realistic"):
        row[name], row[f"{name}_points"] = replay(manager, ordered, name)
        row[f"gap_{name}"] = round(100.0 * (predicted - row[name]), 3)
    row["seconds"] = round(time.perf_counter() - start, 1)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.acceptance.coverage", description=__doc__)
    parser.add_argument("--parts", nargs="*", default=None)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    rows = []
    print(
        "| part | views | predicted % | measured ideal % | gap ideal (points) | measured realistic % | gap realistic | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for path, unit in discover(args.parts):
        try:
            row = run_part(path, unit)
        except AgiprobotError as exc:  # a part the planner refuses is a row, not the end of the run
            row = {"part": path.name, "error": f"{type(exc).__name__}: {exc}"[:160]}
            print(f"| {path.name} | refused: {row['error']} |")
            rows.append(row)
            continue
        rows.append(row)
        print(
            f"| {row['part']} | {row['views']} | {100 * row['predicted']:.2f} | {100 * row['ideal']:.2f} | "
            f"{row['gap_ideal']:.2f} | {100 * row['realistic']:.2f} | {row['gap_realistic']:.2f} | {row['seconds']} |",
            flush=True,
        )
    worst = max((abs(r["gap_realistic"]) for r in rows if "gap_realistic" in r), default=float("nan"))
    print(f"\nlargest |predicted - measured| with the realistic models: {worst:.2f} points (target <= 2)")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as stream:
            json.dump(rows, stream, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
