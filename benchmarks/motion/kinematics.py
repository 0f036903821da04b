"""The robot's own kinematics: what planning with the nominal arm costs on the original's real UR10e, and what the
calibrated model (its ur_calibration file, config/my_robot_calibration.yaml) gives back.

    python -m benchmarks.motion.kinematics                 # 5,000 random states + the demo plan's poses
    python -m benchmarks.motion.kinematics --no-plan       # random states only (seconds)
    python -m benchmarks.motion.kinematics --json out.json

The true robot is the file's chain (ur_description's, the joint origins of the file). Two sets of tool0 target
poses (the robot base frame):

* random FK: ``--states`` joint states uniform in [-pi, pi] (seed ``--seed``): the file's tool0 vs the nominal
  file's (the reference's statistic);
* random in limits: as many states uniform within the joint limits (and [-pi, pi]), targets = their nominal FK;
* demo plan: the measurement (scan-line) joint states of the demo's plan (the 100 mm cube at 0.03 points/mm^2,
  12 orientations, tilt none, greedy set cover, connected), targets = their nominal FK (what the planner meant).

For each set: "nominal model" = the joints the nominal model's IK gives (the planner without the file), tool0
where the true robot puts it at them vs the target; "file" = the joints the calibrated model's IK gives (closed
form on the nominal DH refined on the file's chain), likewise. Position error mm (mean, median, max), orientation
deg (mean, max), unreachable targets, the largest joint change from the planned state, and the IK time per
pose (batch; the nominal model's is the closed form alone). The reference
(/work/shared/reference/real_cell_interfaces.md) gives 1.76 mm mean / 1.65 median / 4.72 max, 0.17 / 0.33 deg for
the FK difference over 5,000 random states.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from agiprobot_measurement.motion.ik import URAnalyticIK, pose_errors
from agiprobot_measurement.motion.kinematics import KinematicModel, ur_arm_frames
from agiprobot_measurement.station import CONFIG_DIR, Station, load_ur_kinematics
from benchmarks.harness import ROOT, format_table, load_conditions, write_json

CONDITIONS = load_conditions("motion_kinematics")
DEFAULTS = CONDITIONS.mapping("defaults")
CALIBRATION_FILE = CONFIG_DIR / str(CONDITIONS["calibration_file"])
PLAN = CONDITIONS.mapping("demo_plan")


def _stats(reached: np.ndarray, targets: np.ndarray, ok: np.ndarray) -> dict:
    position, angle = pose_errors(reached[ok], targets[ok])
    mm, deg = position * 1000.0, np.degrees(angle)
    return {
        "poses": len(targets),
        "unreachable": int((~ok).sum()),
        "position_mean_mm": float(mm.mean()),
        "position_median_mm": float(np.median(mm)),
        "position_max_mm": float(mm.max()),
        "orientation_mean_deg": float(deg.mean()),
        "orientation_max_deg": float(deg.max()),
    }


def evaluate(name: str, states: np.ndarray, nominal: URAnalyticIK, calibrated: URAnalyticIK, true_arm) -> list[dict]:
    """Both models' IK for the nominal FK of ``states`` (base frame, tool0), judged by the true robot's FK."""
    targets = nominal.model.fk_batch(states)
    rows = []
    for label, solver in (("nominal model", nominal), ("file", calibrated)):
        started = time.perf_counter()
        q, ok = solver.solve_nearest(targets, states)
        seconds = time.perf_counter() - started
        reached = np.full_like(targets, np.nan)
        reached[ok] = ur_arm_frames(true_arm, q[ok])["tool0"]
        # ur_arm_frames is in base_link; the solvers' chain starts at `base` (the DH base)
        base_from_base_link = np.linalg.inv(ur_arm_frames(true_arm, np.zeros((1, 6)))["base"][0])
        reached[ok] = base_from_base_link @ reached[ok]
        row = {"set": name, "model": label, **_stats(reached, targets, ok)}
        row["joint_change_max_deg"] = float(np.degrees(np.abs(q[ok] - states[ok]).max()))
        row["ik_us_per_pose"] = seconds / len(targets) * 1e6
        rows.append(row)
    return rows


def fk_difference(states: np.ndarray, nominal_arm, true_arm) -> dict:
    """tool0 of the file's chain vs the nominal file's chain (ur_description's FK, base_link)."""
    a, b = ur_arm_frames(nominal_arm, states)["tool0"], ur_arm_frames(true_arm, states)["tool0"]
    return {"set": "random FK", "model": "file vs nominal", **_stats(b, a, np.ones(len(states), bool))}


def demo_plan_states(seed: int) -> np.ndarray:
    """The measurement joint states of the demo's plan (core planner, the nominal station)."""
    from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager

    manager = TrajectoryManager(seed=seed)
    manager.load_target_mesh(str(ROOT / PLAN["part"]), units="mm", remove_downside=True)
    _, views = manager.generate_samples_and_viewpoints(
        float(PLAN["density_points_per_mm2"]), float(PLAN["threshold_mm"]), int(PLAN["orientations"]), PLAN["tilt"]
    )
    chosen = manager.solve_scp(views, PLAN["solver"])
    ordered = manager.connect_viewpoints(chosen)
    segments = manager.convert_viewpointlist_to_execution_plan(ordered)
    states = [np.asarray(s.trajectory.positions) for s in segments if s.kind == "measure"]
    return np.vstack(states)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--states", type=int, default=DEFAULTS["states"], help="random joint states")
    parser.add_argument("--seed", type=int, default=DEFAULTS["seed"])
    parser.add_argument("--no-plan", action="store_true", help="skip the demo plan (planning takes a minute)")
    parser.add_argument("--kinematics", default=str(CALIBRATION_FILE), help="the true robot's kinematics file")
    parser.add_argument("--json", help="write the rows to this JSON file")
    args = parser.parse_args(argv)

    true_arm = load_ur_kinematics(args.kinematics)
    nominal_station = Station.load()
    calibrated_station = Station.load(kinematics=args.kinematics)
    solvers = {}
    for name, station in (("nominal", nominal_station), ("file", calibrated_station)):
        model = KinematicModel.from_station(station, tip_frame="tool0", base_frame="base")
        solvers[name] = URAnalyticIK(model, station.robot)
    rng = np.random.default_rng(args.seed)
    states = rng.uniform(-np.pi, np.pi, (args.states, 6))
    rows = [fk_difference(states, nominal_station.kinematics, true_arm)]
    model = solvers["nominal"].model
    reachable = rng.uniform(np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi), (args.states, 6))
    rows += evaluate("random in limits", reachable, solvers["nominal"], solvers["file"], true_arm)
    if not args.no_plan:
        started = time.perf_counter()
        plan = demo_plan_states(args.seed)
        print(f"demo plan: {len(plan)} measurement joint states ({time.perf_counter() - started:.0f} s to plan)")
        rows += evaluate("demo plan", plan, solvers["nominal"], solvers["file"], true_arm)
    columns = [
        ("set", "set", "{}"),
        ("model", "planner's model", "{}"),
        ("poses", "poses", "{}"),
        ("unreachable", "unreach.", "{}"),
        ("position_mean_mm", "mean mm", "{:.3g}"),
        ("position_median_mm", "median mm", "{:.3g}"),
        ("position_max_mm", "max mm", "{:.3g}"),
        ("orientation_mean_deg", "mean deg", "{:.3g}"),
        ("orientation_max_deg", "max deg", "{:.3g}"),
        ("joint_change_max_deg", "max dq deg", "{:.3g}"),
        ("ik_us_per_pose", "IK us/pose", "{:.1f}"),
    ]
    print(f"true robot: {args.kinematics} ({true_arm.hash}); tool0 error where the true robot puts it")
    print(
        format_table(
            [label for _, label, _ in columns],
            [[fmt.format(r[key]) if key in r else "-" for key, _, fmt in columns] for r in rows],
        )
    )
    if args.json:
        write_json(args.json, {"kinematics": args.kinematics, "hash": true_arm.hash, "rows": rows})
        print(f"json: {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
