"""Scan-line verification speed: milliseconds per scan line, one at a time and batched.

For each part of the conditions (placed on the fixture) it generates the candidate views (tilt none), draws
random ones (fixed seed) and checks their scan lines' mechanics (Cartesian path along the line, joint jumps and
limits, collisions, partial acceptance) twice from fresh copies: one view at a time (``check_scan_line``, the
reference) and all at once (``check_scan_lines``). It prints ms per line for both, the speed-up, and whether
the two agree (same verdicts, same accepted scan-line ranges, same kept points). The machine's load (1-minute
average) is printed beside the figures: on a shared machine they are pessimistic.

    python -m benchmarks.planning.scan_lines
    python -m benchmarks.planning.scan_lines --lines 3000 --sequential-lines 300 --json scan_lines.json
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

import numpy as np

from agiprobot_measurement.planning.candidates.mechanics import check_scan_line, check_scan_lines
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from benchmarks.harness import ROOT, Target, format_table, format_targets, load_conditions, targets_json, write_json

CONDITIONS = load_conditions("planning_scan_lines")


def _copies(views, indices):
    return [copy.deepcopy(views[i]) for i in indices]


def agree(reference, batched, ref_paths, batch_paths) -> bool:
    """Same verdict, same accepted range (mm), same kept points and (within 1e-6 rad) the same joint path."""
    for a, b, p, q in zip(reference, batched, ref_paths, batch_paths, strict=True):
        if (p is None) != (q is None) or a.mechanics_valid != b.mechanics_valid:
            return False
        if p is None:
            continue
        if not np.allclose(a.scan_line, b.scan_line, atol=1e-6):
            return False
        if not np.array_equal(a.measurable_indices, b.measurable_indices):
            return False
        if p.shape != q.shape or not np.allclose(p, q, atol=1e-6):
            return False
    return True


def measure(part: dict, lines: int, sequential_lines: int, density: float, orientations: int, seed: int) -> dict:
    path = Path(part["file"])
    path = path if path.is_absolute() else ROOT / path
    manager = TrajectoryManager(seed=seed)
    manager.load_target_mesh(str(path), units=part.get("units", "mm"), placement="fixture")
    _, views = manager.generate_samples_and_viewpoints(density, 0.1, orientations, "none")
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(views), size=min(lines, len(views)), replace=False)
    settings = manager.run.mechanics
    kw = dict(ik=manager.ik, collision=manager.collision, preferred_state=manager.preferred_state, scan_speed_mm_s=50.0)
    check_scan_lines(_copies(views, chosen[:4]), settings, **kw)  # compiles (or loads) the kernels
    batch = _copies(views, chosen)
    started = time.perf_counter()
    batch_paths = check_scan_lines(batch, settings, **kw)
    batched_s = time.perf_counter() - started
    n_seq = min(sequential_lines, len(chosen))
    reference = _copies(views, chosen[:n_seq])
    started = time.perf_counter()
    ref_paths = [check_scan_line(v, settings, **kw) for v in reference]
    sequential_s = time.perf_counter() - started
    batched_ms = 1e3 * batched_s / max(len(batch), 1)
    sequential_ms = 1e3 * sequential_s / max(n_seq, 1)
    return {
        "part": path.name,
        "candidates": len(views),
        "lines": len(batch),
        "valid": int(sum(p is not None for p in batch_paths)),
        "mean_line_mm": float(np.mean([abs(v.scan_line[1] - v.scan_line[0]) for v in _copies(views, chosen)])),
        "batched_ms_per_line": batched_ms,
        "sequential_lines": n_seq,
        "sequential_ms_per_line": sequential_ms,
        "speedup": sequential_ms / max(batched_ms, 1e-9),
        "agree": agree(reference, batch[:n_seq], ref_paths, batch_paths[:n_seq]),
        "load_1min": os.getloadavg()[0],
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=CONDITIONS.whole("lines", low=1))
    parser.add_argument("--sequential-lines", type=int, default=CONDITIONS.whole("sequential_lines", low=1))
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    density = CONDITIONS.number("density_points_per_mm2", low=0.0)
    orientations = CONDITIONS.whole("orientations", low=1)
    seed = CONDITIONS.whole("seed", low=0)
    targets_cfg = CONDITIONS.mapping("targets")
    rows, results = [], []
    for part in CONDITIONS["parts"]:
        r = measure(part, args.lines, args.sequential_lines, density, orientations, seed)
        results.append(r)
        rows.append(
            [
                r["part"], r["candidates"], r["lines"], r["valid"], f"{r['mean_line_mm']:.0f}",
                f"{r['sequential_ms_per_line']:.2f}", f"{r['batched_ms_per_line']:.3f}", f"{r['speedup']:.1f}x",
                "yes" if r["agree"] else "NO", f"{r['load_1min']:.1f}",
            ]
        )  # fmt: skip
        print(format_table(["part", "candidates", "lines", "valid", "line mm", "one by one ms", "batched ms",
                            "speed-up", "agree", "load"], rows[-1:]), flush=True)  # fmt: skip
    worst_ms = max(r["batched_ms_per_line"] for r in results)
    least = min(r["speedup"] for r in results)
    targets = [
        Target("batched ms per line (worst part)", f"{worst_ms:.3f}", f"<= {targets_cfg['batched_ms_per_line']}",
               worst_ms <= float(targets_cfg["batched_ms_per_line"])),
        Target("speed-up over one at a time (least)", f"{least:.1f}x", f">= {targets_cfg['speedup']}x",
               least >= float(targets_cfg["speedup"])),
        Target("batched agrees with one at a time", str(all(r["agree"] for r in results)), "True",
               all(r["agree"] for r in results)),
    ]  # fmt: skip
    print()
    print(format_table(["part", "candidates", "lines", "valid", "line mm", "one by one ms", "batched ms",
                        "speed-up", "agree", "load"], rows))  # fmt: skip
    print(format_targets(targets))
    if args.json:
        write_json(args.json, {"results": results, "targets": targets_json(targets)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
