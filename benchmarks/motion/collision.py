"""Collision checking and joint-space planning on the station scene (with the part).

Prints full-robot collision checks per second (batch, random and valid states; single calls) and, for N
seeded pairs of random valid states, the planner's success rate and planning times (median, mean, p90, max).
By default the planner is RRTConnect with the straight-line shortcut off, so every pair is planned by OMPL.

    python -m benchmarks.motion.collision                      # 100 pairs, RRTConnect
    python -m benchmarks.motion.collision --pairs 20 --planner PRM --direct
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.motion_planning import MotionPlanner, available_planners
from agiprobot_measurement.station import Station
from benchmarks.harness import load_conditions

DEFAULTS = load_conditions("motion_collision").mapping("defaults")


def random_valid_states(checker: CollisionChecker, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` valid joint states (rad), uniform within the joint limits."""
    model = checker.model
    found = []
    while sum(len(f) for f in found) < count:
        q = rng.uniform(model.lower, model.upper, size=(4 * count, model.dof))
        found.append(q[checker.check_states(q)])
    return np.concatenate(found)[:count]


def bench_collision(checker: CollisionChecker, states: int = 20000, seed: int = 0) -> dict:
    """Checks per second: batch on random and on valid states, and single ``is_state_valid`` calls."""
    rng = np.random.default_rng(seed)
    model = checker.model
    random_q = rng.uniform(model.lower, model.upper, size=(states, model.dof))
    checker.check_states(random_q[:100])  # warm-up
    started = time.perf_counter()
    valid = checker.check_states(random_q)
    random_rate = states / (time.perf_counter() - started)
    valid_q = random_valid_states(checker, states, rng)
    started = time.perf_counter()
    checker.check_states(valid_q)
    valid_rate = states / (time.perf_counter() - started)
    singles = valid_q[: min(2000, states)]
    started = time.perf_counter()
    for q in singles:
        checker.is_state_valid(q)
    single_us = (time.perf_counter() - started) / len(singles) * 1e6
    return {
        "states": states,
        "valid_fraction_random": float(valid.mean()),
        "batch_random_states_per_s": random_rate,
        "batch_valid_states_per_s": valid_rate,
        "single_valid_state_us": single_us,
    }


def bench_planning(planner: MotionPlanner, pairs: int = 100, seed: int = 1, planner_name: str | None = None) -> dict:
    """Plan between ``pairs`` seeded pairs of random valid states; times in s."""
    rng = np.random.default_rng(seed)
    states = random_valid_states(planner.checker, 2 * pairs, rng)
    times, successes, failures, used = [], 0, [], {}
    for k in range(pairs):
        result = planner.plan(states[2 * k], states[2 * k + 1], planner=planner_name)
        times.append(result.planning_time)
        used[result.planner] = used.get(result.planner, 0) + 1
        if result.success:
            successes += 1
            if planner.check_path(result.path) >= 0:
                failures.append(f"pair {k}: returned path failed the dense check")
        else:
            failures.append(f"pair {k}: {result.reason}")
    times = np.array(times)
    return {
        "pairs": pairs,
        "planner": planner_name or planner.planner_name,
        "try_direct": planner.try_direct,
        "success_rate": successes / pairs,
        "median_s": float(np.median(times)),
        "mean_s": float(np.mean(times)),
        "p90_s": float(np.percentile(times, 90)),
        "max_s": float(np.max(times)),
        "solved_by": used,
        "failures": failures,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--states", type=int, default=DEFAULTS["states"], help="states for the collision benchmark")
    parser.add_argument("--pairs", type=int, default=DEFAULTS["pairs"], help="state pairs for the planning benchmark")
    parser.add_argument("--planner", default=DEFAULTS["planner"], choices=available_planners())
    parser.add_argument("--direct", action="store_true", help="take the straight line when it is free")
    parser.add_argument("--budget", type=float, default=DEFAULTS["budget_s"], help="time budget per plan (s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)

    station = Station.load()
    checker = CollisionChecker.from_station(station)
    collision = bench_collision(checker, args.states, args.seed) if args.states > 0 else {}
    planner = MotionPlanner(
        checker, planner=args.planner, try_direct=args.direct, time_budget_s=args.budget, seed=args.seed + 1
    )
    planning = bench_planning(planner, args.pairs, args.seed + 1) if args.pairs > 0 else {}
    if args.json:
        print(json.dumps({"collision": collision, "planning": planning}, indent=2))
        return 0
    objects = ", ".join(checker.object_names())
    print(f"scene: {objects}; padding {checker.padding_m} m, self padding {checker.self_padding_m} m")
    if collision:
        print(
            f"collision checks ({collision['states']} states): "
            f"batch random {collision['batch_random_states_per_s']:.0f} states/s "
            f"({100 * collision['valid_fraction_random']:.0f} % valid), "
            f"batch valid {collision['batch_valid_states_per_s']:.0f} states/s, "
            f"single valid {collision['single_valid_state_us']:.0f} us/state"
        )
    if planning:
        print(
            f"{planning['planner']} ({'straight line first' if planning['try_direct'] else 'always OMPL'}), "
            f"{planning['pairs']} random valid pairs: success {100 * planning['success_rate']:.0f} %, "
            f"median {planning['median_s']:.3f} s, mean {planning['mean_s']:.3f} s, "
            f"p90 {planning['p90_s']:.3f} s, max {planning['max_s']:.3f} s; solved by {planning['solved_by']}"
        )
        for failure in planning["failures"]:
            print(f"  {failure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
