"""The motion core: closed-form IK, KDL IK, collision checks, RRTConnect, Cartesian lines.

Usage (after ``source tools/env.sh``, from the checkout's root)::

    python -m benchmarks.motion                       # every benchmark
    python -m benchmarks.motion --only ik_closed_form cartesian --poses 50000

Each benchmark is a function ``(context, args) -> list[Row]`` listed in ``BENCHMARKS``; add collision or
planner benchmarks by writing such a function and registering it there.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from agiprobot_measurement.motion.cartesian import compute_cartesian_path
from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.ik import KDLIK, URAnalyticIK
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.motion_planning import MotionPlanner
from agiprobot_measurement.station import Station
from benchmarks.harness import format_table, load_conditions, timed
from benchmarks.motion.collision import bench_collision, bench_planning

CONDITIONS = load_conditions("motion_core")
LINE_START_XYZ_M = np.array(CONDITIONS["line_start_xyz_m"], dtype=float)
LINE_DIRECTION = np.array(CONDITIONS["line_direction"], dtype=float)
LINE_SEED_Q = np.array(CONDITIONS["line_seed_q"], dtype=float)
DEFAULTS = CONDITIONS.mapping("defaults")


class Row(NamedTuple):
    benchmark: str
    metric: str
    value: float
    unit: str
    note: str = ""


@dataclass
class Context:
    station: Station
    model: KinematicModel
    ik: URAnalyticIK
    rng: np.random.Generator

    def random_states(self, count: int) -> np.ndarray:
        return self.rng.uniform(self.model.lower, self.model.upper, (count, self.model.dof))


def _median_seconds(function, repeats: int) -> float:
    return timed(function, repeats, warmup=True).median_s  # the warm-up call fills caches and lazy imports


# ------------------------------------------------------------------------------------------- benchmarks
def bench_ik_closed_form(ctx: Context, args) -> list[Row]:
    poses = ctx.model.fk_batch(ctx.random_states(args.poses))
    seeds = ctx.random_states(args.poses)
    seconds = _median_seconds(lambda: ctx.ik.solve_nearest(poses, seeds), args.repeats)
    _, ok = ctx.ik.solve_nearest(poses, seeds)
    return [
        Row("closed-form IK", f"poses/s (batch of {args.poses}, nearest of 8)", args.poses / seconds, "1/s"),
        Row("closed-form IK", "success on reachable poses", 100.0 * ok.mean(), "%"),
    ]


def bench_ik_kdl(ctx: Context, args) -> list[Row]:
    solver = KDLIK(ctx.model, rng=args.seed)
    poses = ctx.model.fk_batch(ctx.random_states(args.kdl_poses))
    seeds = ctx.random_states(args.kdl_poses)  # random, not near: the hard case for a local solver
    start = time.perf_counter()
    _, ok = solver.solve_batch(poses, seeds)
    seconds = time.perf_counter() - start
    return [
        Row("KDL IK (LMA + restarts)", f"poses/s ({args.kdl_poses} poses, random seeds)", len(poses) / seconds, "1/s"),
        Row("KDL IK (LMA + restarts)", "success on reachable poses", 100.0 * ok.mean(), "%"),
    ]


def _load_collision_checker(ctx: Context):
    """The collision checker's batch check, or (None, reason) while that module is missing or broken."""
    try:
        checker = CollisionChecker.from_station(ctx.station, model=ctx.model)
        return checker.check_states, "with batched collision check"
    except Exception as exc:  # another helper's module in progress: benchmark without it and say why
        return None, f"no collision check ({type(exc).__name__}: {exc})"


def bench_cartesian(ctx: Context, args) -> list[Row]:
    start_pose = np.eye(4)
    start_pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # boresight (z) pointing down
    start_pose[:3, 3] = LINE_START_XYZ_M
    end_pose = start_pose.copy()
    end_pose[:3, 3] += LINE_DIRECTION * args.line_mm * 1e-3
    checker, note = _load_collision_checker(ctx) if not args.no_collision else (None, "collision off")
    # the start: the IK branch nearest the seed whose whole line is executable (collision-free where checked)
    solutions, valid = ctx.ik.solve_all(start_pose[None], LINE_SEED_Q[None])
    branches = solutions[0][valid[0]]
    branches = branches[np.argsort(np.abs(branches - LINE_SEED_Q).max(axis=1))]
    start_q = None
    for q in branches:
        trial = compute_cartesian_path(ctx.ik, q, end_pose, step_mm=args.step_mm, validity_checker=checker)
        if trial.fraction >= 1.0:
            start_q = q
            break
    if start_q is None:
        raise SystemExit("motion benchmark: no IK branch executes the benchmark's Cartesian line in this station")
    rows = []
    for label, validity in (("IK only", None), (note, checker)):
        if label != "IK only" and validity is None:
            rows.append(Row("Cartesian line", "with collision check", float("nan"), "ms", note))
            continue

        def run(validity=validity):
            return compute_cartesian_path(ctx.ik, start_q, end_pose, step_mm=args.step_mm, validity_checker=validity)

        seconds = _median_seconds(run, args.repeats)
        result = run()
        rows.append(
            Row(
                "Cartesian line",
                f"{args.line_mm:g} mm at {args.step_mm:g} mm, {label}",
                seconds * 1e3,
                "ms",
                f"fraction {result.fraction:.2f}, {len(result.joint_path)} states, {result.stop_reason}",
            )
        )
    return rows


def bench_collision_rate(ctx: Context, args) -> list[Row]:
    checker = CollisionChecker.from_station(ctx.station, model=ctx.model)
    result = bench_collision(checker, args.collision_states, args.seed)
    note = f"scene + cube part, {100 * result['valid_fraction_random']:.0f} % of random states valid"
    return [
        Row(
            "collision check",
            f"states/s (batch of {args.collision_states} random)",
            result["batch_random_states_per_s"],
            "1/s",
            note,
        ),
        Row("collision check", "states/s (batch of valid states)", result["batch_valid_states_per_s"], "1/s"),
        Row("collision check", "single is_state_valid", result["single_valid_state_us"], "us"),
    ]


def bench_rrtconnect(ctx: Context, args) -> list[Row]:
    checker = CollisionChecker.from_station(ctx.station, model=ctx.model)
    planner = MotionPlanner(checker, planner="RRTConnect", try_direct=False, seed=args.seed + 1)
    result = bench_planning(planner, args.pairs, args.seed + 1)
    note = f"{args.pairs} random valid pairs, always OMPL (no straight-line shortcut)"
    return [
        Row("RRTConnect", "median planning time", result["median_s"] * 1e3, "ms", note),
        Row("RRTConnect", "90th percentile", result["p90_s"] * 1e3, "ms"),
        Row("RRTConnect", "success rate", 100.0 * result["success_rate"], "%"),
    ]


BENCHMARKS = {
    "ik_closed_form": bench_ik_closed_form,
    "ik_kdl": bench_ik_kdl,
    "collision": bench_collision_rate,
    "rrtconnect": bench_rrtconnect,
    "cartesian": bench_cartesian,
}


# ------------------------------------------------------------------------------------------------- main
def print_table(rows: list[Row]) -> None:
    header = ("benchmark", "metric", "value", "unit", "note")
    cells = [(r.benchmark, r.metric, "n/a" if np.isnan(r.value) else f"{r.value:,.1f}", r.unit, r.note) for r in rows]
    print(format_table(header, cells, right=(2,), sep="  "))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--only", nargs="+", choices=sorted(BENCHMARKS), help="run only these benchmarks")
    parser.add_argument("--poses", type=int, default=DEFAULTS["poses"], help="closed-form IK batch size (%(default)s)")
    parser.add_argument("--kdl-poses", type=int, default=DEFAULTS["kdl_poses"], help="poses for KDL IK (%(default)s)")
    parser.add_argument(
        "--repeats", type=int, default=DEFAULTS["repeats"], help="repeats for median timings (%(default)s)"
    )
    parser.add_argument(
        "--line-mm", type=float, default=DEFAULTS["line_mm"], help="Cartesian line length, mm (%(default)g)"
    )
    parser.add_argument("--step-mm", type=float, default=DEFAULTS["step_mm"], help="Cartesian step, mm (%(default)g)")
    parser.add_argument("--no-collision", action="store_true", help="Cartesian benchmark without collision check")
    parser.add_argument(
        "--collision-states", type=int, default=DEFAULTS["collision_states"], help="states per collision batch"
    )
    parser.add_argument("--pairs", type=int, default=DEFAULTS["pairs"], help="random valid state pairs for RRTConnect")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    args = parser.parse_args(argv)

    station = Station.load()
    model = KinematicModel.from_station(station)
    ctx = Context(station, model, URAnalyticIK(model, station.robot), np.random.default_rng(args.seed))
    rows = []
    for name in args.only or BENCHMARKS:
        rows.extend(BENCHMARKS[name](ctx, args))
    print_table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
