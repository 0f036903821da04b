"""The viewpoint-selection set cover on synthetic cube instances.

The presets mirror the original's cube benchmark (1,500 samples; 3, 6 and 12 orientations around the
boresight, without and with the 9 tilts; conditions/planning_set_cover.yaml). Example:

    python -m benchmarks.planning.set_cover                   # o3 o6 o12 o12-all, every solver
    python -m benchmarks.planning.set_cover --presets full --solvers greedy IP_basic
    python -m benchmarks.planning.set_cover --points 3000 --orientations 12 --valid-fraction 0.5
"""

from __future__ import annotations

import argparse
import sys
import time

from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES, solve_set_cover
from agiprobot_measurement.testing.set_cover_instances import cube_instance
from benchmarks.harness import load_conditions

CONDITIONS = load_conditions("planning_set_cover")
PRESETS = CONDITIONS.mapping("presets")
DEFAULT_PRESETS = list(CONDITIONS["default_presets"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", nargs="+", choices=sorted(PRESETS), help="instance presets")
    parser.add_argument("--points", type=int, help="custom instance: number of sample points")
    parser.add_argument("--orientations", type=int, default=12, help="custom instance: orientations")
    parser.add_argument("--tilts", type=int, choices=(1, 9), default=1, help="custom instance: tilts")
    parser.add_argument("--valid-fraction", type=float, default=0.5, help="custom instance: share kept")
    parser.add_argument("--solvers", nargs="+", choices=SOLVER_TYPES, default=list(SOLVER_TYPES))
    parser.add_argument("--backend", choices=("highs", "cbc"), default="highs")
    parser.add_argument("--time-limit", type=float, default=60.0, help="per IP solve, s")
    parser.add_argument("--mip-gap", type=float, default=0.0, help="relative gap at which an IP may stop (0)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=1, help="solve each case this often, report the fastest")
    args = parser.parse_args(argv)

    cases: list[tuple[str, dict]] = []
    if args.points is not None:
        cases.append(
            (
                "custom",
                {
                    "n_points": args.points,
                    "n_orientations": args.orientations,
                    "n_tilts": args.tilts,
                    "valid_fraction": args.valid_fraction,
                },
            )
        )
    for name in args.presets or ([] if cases else DEFAULT_PRESETS):
        cases.append((name, PRESETS[name]))

    header = (
        f"{'instance':<9} {'points':>6} {'views':>7} {'nnz':>10} {'solver':<20} {'chosen':>6} "
        f"{'coverage':>11} {'objective':>10} {'time s':>7} {'gap':>8} {'optimal':>7}  reduced to"
    )
    print(header)
    print("-" * len(header))
    for name, params in cases:
        t0 = time.perf_counter()
        inst = cube_instance(seed=args.seed, **params)
        gen_s = time.perf_counter() - t0
        for solver in args.solvers:
            best = None
            for _ in range(max(1, args.repeat)):
                result = solve_set_cover(
                    inst.matrix,
                    solver,
                    durations_s=inst.durations_s,
                    time_limit_s=args.time_limit,
                    backend=args.backend,
                    mip_gap=args.mip_gap,
                )
                if best is None or result.solve_time_s < best.solve_time_s:
                    best = result
            r = best
            coverage = f"{int(r.covered.sum())}/{r.n_coverable}"
            gap = "-" if r.gap is None else f"{100.0 * r.gap:.2f}%"
            shape = r.stats.get("mip_shape")
            reduced = "-" if shape is None else ("none left" if shape == (0, 0) else f"{shape[0]}x{shape[1]}")
            print(
                f"{name:<9} {inst.n_points:>6} {inst.n_views:>7} {inst.matrix.nnz:>10} {r.solver:<20} "
                f"{r.n_selected:>6} {coverage:>11} {r.objective:>10.4g} {r.solve_time_s:>7.2f} {gap:>8} "
                f"{'yes' if r.proven_optimal else 'no':>7}  {reduced}",
                flush=True,
            )
        print(f"  ({name}: instance generated in {gen_s:.1f} s; {inst.description})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
