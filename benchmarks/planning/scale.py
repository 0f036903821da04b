"""Candidate evaluation of door-sized panels, streamed, in process and on local Dask clusters.

Generated panels of 0.05, 0.2, 0.5 and 1 m^2 (footprint 1.4 : 1, curved in both directions, a grid of pockets
with steep walls and ribs between them, like a car door's inner panel), placed on the fixture, sampled at 0.03
points/mm^2 with 12 orientations, tilt none and full. Every configuration (in process, 1 and 2 local workers) runs
in its own process, so its peak memory is its own. Printed per panel and tilt: samples, candidates, kept views and
pairs, time per stage (sampling, anchor reachability, evaluation, view objects, greedy cover), peak memory of the
client and of every worker, a digest of the measurability store (equal digests = the same store, so the same
plan), the speed-up of 2 local workers over 1, and a projection of the evaluation time for N workers.

The projection is a model, not a measurement, built from the 1-worker run: the merge (serial, in the client); the
scatter of the sensor model, a fixed part plus a part per worker, fitted through the scatters measured with 1 and
2 workers (from a single run: all of it per worker, as if no two transfers overlapped); the pilot, whose tasks run
on the workers (the random spread split over them, the dominance slices one task each, plus the pilot time not
spent in tasks); and the measured chunk work, split into at least 4 chunks per worker as the evaluation does, each
chunk with the measured per-chunk overhead (the workers' time in the chunk phase not spent computing a chunk).
It assumes workers that do not slow each other, as on separate machines. Efficiency = T(1) / (N T(N)) within the
model. Its 2-worker value is printed next to the measured one. ``--reproject FILE`` recomputes it from a JSON.

Examples::

    python -m benchmarks.planning.scale --areas 0.05 --tilts none          # quick
    nice -n 10 python -m benchmarks.planning.scale --json scale.json        # everything (1 m^2 at tilt full: long)
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import math
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from agiprobot_measurement.planning.candidates.distributed import peak_rss_bytes
from agiprobot_measurement.planning.candidates.mechanics import reachable_anchors
from agiprobot_measurement.planning.candidates.streaming import StreamStats, evaluate_streaming
from agiprobot_measurement.planning.candidates.viewpoint import generate_viewpoint_poses
from agiprobot_measurement.planning.cover.solve import solve_set_cover
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from benchmarks.harness import ChildFailed, child_command, load_conditions, run_json, write_json

CONDITIONS = load_conditions("planning_scale")
DENSITY = CONDITIONS.number("density_points_per_mm2", low=0.0)
ORIENTATIONS = CONDITIONS.whole("orientations", low=1)
THRESHOLD_MM = CONDITIONS.number("threshold_mm", low=0.0)
AREAS_M2 = tuple(CONDITIONS["areas_m2"])
#: grid step of the generated panel's height field (mm)
GRID_MM = CONDITIONS.number("grid_mm", low=0.0)
DEFAULTS = CONDITIONS.mapping("defaults")


def door_panel(area_m2: float):
    """A closed panel mesh (mm) with a top surface of about ``area_m2``: curved (radii 2.5 m across, 4 m along),
    pockets 25 mm deep with steep walls in a grid of ~300 mm cells, ribs 12 mm high and 10 mm wide between them,
    a bottom 28 mm below the curved surface (a shell). Deterministic."""
    width = math.sqrt(area_m2 * 1.4) * 1000.0
    height = width / 1.4
    nx, ny = max(8, round(width / GRID_MM)) + 1, max(8, round(height / GRID_MM)) + 1
    x = np.linspace(-width / 2, width / 2, nx)
    y = np.linspace(-height / 2, height / 2, ny)
    gx, gy = np.meshgrid(x, y, indexing="ij")
    curve = -(gx**2) / (2 * 2500.0) - (gy**2) / (2 * 4000.0)
    z = curve.copy()

    def band(u, lo, hi, ramp):
        # 1 inside [lo, hi], 0 outside, smooth steps of width ramp at both ends
        a = np.clip((u - lo) / ramp, 0, 1)
        b = np.clip((hi - u) / ramp, 0, 1)
        return (a * a * (3 - 2 * a)) * (b * b * (3 - 2 * b))

    cells_x, cells_y = max(1, round(width / 300.0)), max(1, round(height / 300.0))
    pitch_x, pitch_y = width / cells_x, height / cells_y
    pocket = np.zeros_like(z)
    for i in range(cells_x):
        for j in range(cells_y):
            x0, y0 = -width / 2 + i * pitch_x, -height / 2 + j * pitch_y
            pocket = np.maximum(
                pocket,
                band(gx, x0 + 30, x0 + pitch_x - 30, 8.0) * band(gy, y0 + 30, y0 + pitch_y - 30, 8.0),
            )
    z -= 25.0 * pocket
    # ribs across the pockets' middles, one per cell row and column (stiffeners)
    rib = np.zeros_like(z)
    for i in range(cells_x):
        xc = -width / 2 + (i + 0.5) * pitch_x
        rib = np.maximum(rib, band(gx, xc - 5, xc + 5, 5.0))
    for j in range(cells_y):
        yc = -height / 2 + (j + 0.5) * pitch_y
        rib = np.maximum(rib, band(gy, yc - 5, yc + 5, 5.0))
    z += 12.0 * rib * pocket
    bottom = curve - 28.0  # a shell: the bottom follows the curvature, 3 mm below the pockets' floors

    top = np.stack([gx, gy, z], axis=-1).reshape(-1, 3)
    base = np.stack([gx, gy, bottom], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([top, base])
    index = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]
    top_faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    base_faces = top_faces[:, ::-1] + nx * ny
    ring = np.concatenate([index[:, 0], index[-1, 1:], index[::-1, -1][1:], index[0, ::-1][1:-1]])
    nxt = np.roll(ring, -1)
    off = nx * ny
    sides = np.concatenate([np.stack([ring, ring + off, nxt], -1), np.stack([nxt, ring + off, nxt + off], -1)])
    mesh = trimesh.Trimesh(vertices, np.concatenate([top_faces, base_faces, sides]), process=True)
    trimesh.repair.fix_normals(mesh)
    mesh.apply_translation([0, 0, -mesh.bounds[0, 2]])
    return mesh


def minor_faults() -> int:
    """Minor page faults of this process so far (each a page the kernel zeroed and mapped)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_minflt)


def digest(store) -> str:
    h = hashlib.sha256()
    for array in (store.indptr, store.point_indices, store.uncertainties, store.trajectory_distances):
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()[:12]


def evaluation_only(args, manager, out: dict) -> None:
    """The evaluation stage alone (``--evaluation-only``): sampling, candidates, anchor reachability, then the
    streamed evaluation with a store headroom of 1 (no later stage holds copies); ``--share`` evaluates a
    contiguous middle share of the reachable candidates (whole samples' groups of orientations and tilts)."""
    part = manager.part
    started = time.perf_counter()
    samples = part.sample(DENSITY, seed=manager.seed)
    manager.sensor_model.set_processing_context(part.mesh, samples.points, samples.face_ids)
    candidates = generate_viewpoint_poses(
        samples.points, samples.normals, ORIENTATIONS, args.tilt, manager.sensor_model
    )
    sampling_s = time.perf_counter() - started
    started = time.perf_counter()
    reachable = np.flatnonzero(reachable_anchors(manager.ik, candidates.poses))
    reach_s = time.perf_counter() - started
    if args.share < 1.0:
        count = max(1, round(args.share * reachable.size))
        first = (reachable.size - count) // 2
        reachable = reachable[first : first + count]
    settings = dataclasses.replace(manager.evaluation, store_headroom=1.0, redundancy=args.redundancy)
    if args.drop != "auto":
        settings = dataclasses.replace(settings, drop_dominated=args.drop == "always")
    stats = StreamStats()
    cpu_started, faults_started = time.process_time(), minor_faults()
    store, _ = evaluate_streaming(
        manager.sensor_model,
        candidates.poses[reachable],
        THRESHOLD_MM,
        CONDITIONS["max_deflection_mm"],
        settings=settings,
        executor=manager.evaluator(),
        stats=stats,
    )
    out["client_cpu_s"] = time.process_time() - cpu_started
    out["client_minor_faults"] = minor_faults() - faults_started
    out.update(samples=len(samples), candidates=len(candidates.poses), reachable=int(reachable.size))
    out["times"] = {"sampling": sampling_s, "anchor_reachability": reach_s, "viewpoint_objects": 0.0}
    out["digest"] = digest(store)
    out["reachable_share"] = float(np.unique(candidates.sample_index[reachable]).size / len(samples))
    fill_stats(out, stats)


def fill_stats(out: dict, stats) -> None:
    out.update(
        evaluated=stats.candidates,
        kept_views=stats.kept_views,
        kept_pairs=stats.kept_pairs,
        projected_pairs=stats.projected_pairs,
        projected_gb=stats.projected_bytes / 1e9,
        budget_gb=stats.budget_bytes / 1e9,
        compact=stats.compact,
        drop_dominated=stats.drop_dominated,
        redundancy=stats.redundancy,
        dominance_kept_share=stats.dominance_kept_share,
        dropped_views=stats.dropped_views,
        dropped_pairs=stats.dropped_pairs,
        chunks=stats.chunks,
        chunk_views=stats.chunk_views,
        chunk_seconds=stats.chunk_seconds,
        chunk_cpu_seconds=stats.chunk_cpu_seconds,
        pilot_s=stats.pilot_s,
        pilot_spread_seconds=stats.pilot_spread_seconds,
        pilot_dominance_seconds=stats.pilot_dominance_seconds,
        scatter_s=stats.scatter_s,
        merge_s=stats.merge_s,
        evaluation_s=stats.wall_s,
        store_mb=stats.store_bytes / 1e6,
    )


def child(args) -> dict:
    """One configuration in this process; returns its figures."""
    logging.disable(logging.WARNING)
    mesh_file = Path(args.mesh_dir) / f"panel_{args.area:g}.stl"
    manager = TrajectoryManager(workers=args.workers, max_memory_bytes=args.max_memory * 1e9 or None)
    if args.redundancy is not None:
        manager.evaluation = dataclasses.replace(manager.evaluation, redundancy=args.redundancy)
    out = {"area_m2": args.area, "tilt": args.tilt, "workers": args.workers}
    try:
        manager.load_target_mesh(str(mesh_file), placement="fixture", add_wbk_mirrors=args.mirrors)
        if manager.evaluator() is not None:
            manager.evaluator().client  # noqa: B018 (start the cluster before the clock)
        if args.evaluation_only:
            evaluation_only(args, manager, out)
            evaluator = manager.evaluator()
            out["worker_peak_mb"] = (
                sorted(v / 1e6 for v in evaluator.worker_peak_rss_bytes().values()) if evaluator is not None else []
            )
            out["worker_cpu_s"] = (
                sorted(evaluator.client.run(time.process_time).values()) if evaluator is not None else []
            )
            out["worker_minor_faults"] = (
                sorted(evaluator.client.run(minor_faults).values()) if evaluator is not None else []
            )
            return out
        started = time.perf_counter()
        manager.generate_samples_and_viewpoints(DENSITY, THRESHOLD_MM, ORIENTATIONS, args.tilt)
        out["generate_s"] = time.perf_counter() - started
        stats = manager.last_stream_stats
        store = manager.measurability
        fill_stats(out, stats)
        out["generate_peak_mb"] = peak_rss_bytes() / 1e6
        out.update(
            samples=len(manager.samples),
            candidates=len(manager.candidates.poses),
            times={k: manager.timings_s.get(k, 0.0) for k in ("sampling", "anchor_reachability", "viewpoint_objects")},
            digest=digest(store),
            reachable_share=manager.reachable_share,
        )
        started = time.perf_counter()
        cover = solve_set_cover(store.measurability, "greedy")
        out["greedy_s"] = time.perf_counter() - started
        out["greedy_views"] = len(cover.selected)
        out["covered"] = int(cover.covered.sum())
        evaluator = manager.evaluator()
        out["worker_peak_mb"] = (
            sorted(v / 1e6 for v in evaluator.worker_peak_rss_bytes().values()) if evaluator is not None else []
        )
    except Exception as exc:  # reported in the table
        out["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        out["client_peak_mb"] = peak_rss_bytes() / 1e6
        manager.close()
    return out


def scatter_model(runs: list[dict]) -> tuple[float, float]:
    """(fixed s, s per worker) of sending the sensor model: a line through the scatters measured with two
    different worker counts; from one run, all of it per worker (as if no two transfers overlapped)."""
    measured = {max(int(r["workers"]), 1): r["scatter_s"] for r in runs if "scatter_s" in r}
    if len(measured) >= 2:
        (w1, s1), (w2, s2) = sorted(measured.items())[:2]
        per_worker = max((s2 - s1) / (w2 - w1), 0.0)
        return max(s1 - per_worker * w1, 0.0), per_worker
    (w, s1), *_ = measured.items()
    return 0.0, s1 / w


def pilot_model(run: dict, n_workers: int) -> float:
    """Projected pilot time (s) on ``n_workers``: the random spread's work split over the workers, the dominance
    slices one task each (at most one per worker at a time), plus the run's measured pilot time not spent in those
    tasks (round trips, the projection's own arithmetic)."""
    workers = max(int(run["workers"]), 1)
    spread = float(sum(run.get("pilot_spread_seconds") or []))
    slices = np.asarray(run.get("pilot_dominance_seconds") or [], dtype=float)
    mean = float(slices.mean()) if slices.size else 0.0

    def tasks(n):
        return spread / n + math.ceil(slices.size / n) * mean

    overhead = max(run["pilot_s"] - tasks(workers), 0.0)
    return tasks(n_workers) + overhead


def projection(run: dict, n_workers: int, scatter: tuple[float, float] | None = None) -> float:
    """Projected evaluation time (s) on ``n_workers`` from a measured run on W workers (W = run["workers"]): the
    merge (serial, in the client), the scatter of the sensor model (:func:`scatter_model`), the pilot
    (:func:`pilot_model`: its tasks run on the workers), and the run's measured chunk work split as the evaluation
    splits it for ``n_workers`` (at least 4 chunks per worker), each chunk with the measured per-chunk overhead: the
    workers' time in the chunk phase not spent computing a chunk, per chunk (W x (wall - pilot - merge - scatter) -
    sum of the chunks' times)."""
    workers = max(int(run["workers"]), 1)
    fixed, per_worker = scatter if scatter is not None else scatter_model([run])
    chunks = np.asarray(run["chunk_seconds"], dtype=float)
    busy = workers * (run["evaluation_s"] - run["pilot_s"] - run["merge_s"] - run["scatter_s"])
    overhead = max(0.0, busy - chunks.sum()) / max(len(chunks), 1)
    count = max(len(chunks), 4 * n_workers)
    per_chunk = chunks.sum() / count + overhead * len(chunks) / count
    return (
        run["merge_s"]
        + fixed
        + per_worker * n_workers
        + pilot_model(run, n_workers)
        + math.ceil(count / n_workers) * per_chunk
    )


def run_child(area, tilt, workers, mesh_dir, args) -> dict:
    command = child_command(
        __spec__.name,
        "--child",
        "--area",
        area,
        "--tilt",
        tilt,
        "--workers",
        workers,
        "--mesh-dir",
        mesh_dir,
        "--max-memory",
        args.max_memory,
    )
    if args.mirrors:
        command.append("--mirrors")
    if args.evaluation_only:
        command += ["--evaluation-only", "--share", str(args.share), "--drop", args.drop]
    if args.redundancy is not None:
        command += ["--redundancy", str(args.redundancy)]
    try:
        return run_json(command)
    except ChildFailed as exc:
        return {"area_m2": area, "tilt": tilt, "workers": workers, "error": str(exc)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--areas", type=float, nargs="+", default=list(AREAS_M2), help="panel areas in m^2")
    parser.add_argument("--tilts", nargs="+", default=list(DEFAULTS["tilts"]), help="tilt modes")
    parser.add_argument(
        "--configs",
        type=int,
        nargs="+",
        default=list(DEFAULTS["configs"]),
        help="0 = in process, N = N local Dask workers",
    )
    parser.add_argument("--max-memory", type=float, default=0.0, help="memory budget in GB (0 = from the machine)")
    parser.add_argument("--mirrors", action="store_true", help="keep the scene's mirrors (they may block a panel)")
    parser.add_argument(
        "--evaluation-only", action="store_true", help="run the evaluation stage alone (no view objects, no cover)"
    )
    parser.add_argument(
        "--share", type=float, default=1.0, help="with --evaluation-only: evaluate this middle share of the candidates"
    )
    parser.add_argument(
        "--drop", choices=("auto", "always", "never"), default="auto", help="with --evaluation-only: dominated dropping"
    )
    parser.add_argument("--redundancy", type=int, help="force the per-chunk redundancy-fold cover (0 = off)")
    parser.add_argument("--json", help="write all figures here")
    parser.add_argument(
        "--project", type=int, nargs="+", default=list(DEFAULTS["project"]), help="worker counts to project"
    )
    parser.add_argument("--reproject", help="print the projections of a --json file again and exit")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--area", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--tilt", help=argparse.SUPPRESS)
    parser.add_argument("--workers", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--mesh-dir", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args)), flush=True)
        return 0
    if args.reproject:
        runs = {}
        for r in json.loads(Path(args.reproject).read_text()):
            runs.setdefault((r["area_m2"], r["tilt"]), {})[r["workers"]] = r
        for (area, tilt), group in runs.items():
            print(f"{area:g} m^2 tilt {tilt}:")
            report_panel(group, args.project)
        return 0

    print(f"load before the run: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (2 cores: {os.cpu_count()})")
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_scale_") as mesh_dir:
        for area in args.areas:
            door_panel(area).export(Path(mesh_dir) / f"panel_{area:g}.stl")
            for tilt in args.tilts:
                runs = {}
                for workers in args.configs:
                    result = run_child(area, tilt, workers, mesh_dir, args)
                    result["load_1min"] = os.getloadavg()[0]
                    runs[workers] = result
                    results.append(result)
                    report_run(result)
                    if args.json:  # after every run: a long benchmark cut short keeps what it measured
                        write_json(args.json, results)
                report_panel(runs, args.project)
    print("identical stores across configurations:", same_digests(results))
    if args.json:
        write_json(args.json, results)
    return 0


def report_run(r: dict) -> None:
    where = "in-process" if r["workers"] == 0 else f"{r['workers']} local worker(s)"
    if "error" in r:
        print(f"{r['area_m2']:5g} m^2 tilt {r['tilt']:<5} {where:<18} ERROR {r['error']}", flush=True)
        if "kept_pairs" not in r:
            return
    t = r.get("times", {})
    workers = " ".join(f"{m:.0f}" for m in r.get("worker_peak_mb", [])) or "-"
    store = "compact (int32, float32, float32)" if r.get("compact") else "float64"
    dropping = (
        f"dominated dropped {r['dropped_views']:,} views / {r['dropped_pairs']:,} pairs"
        + (f", {r['redundancy']}-fold cover per chunk" if r.get("redundancy") else "")
        if r.get("drop_dominated")
        else "nothing dropped"
    )
    greedy = (
        f", greedy {r['greedy_s']:.1f} s ({r['greedy_views']} views, {r['covered']} covered)" if "greedy_s" in r else ""
    )
    cpu = sum(r.get("chunk_cpu_seconds") or [])
    print(
        f"{r['area_m2']:5g} m^2 tilt {r['tilt']:<5} {where:<18} samples {r.get('samples', 0):>6} candidates "
        f"{r.get('candidates', 0):>8} evaluated {r['evaluated']:>8} kept views {r['kept_views']:>8} pairs "
        f"{r['kept_pairs']:>13,} (projected {r['projected_pairs']:,.0f} before dropping) | store {store}, {dropping} "
        f"| sampling {t.get('sampling', 0):.1f} s, reach {t.get('anchor_reachability', 0):.1f} s, evaluation "
        f"{r['evaluation_s']:.1f} s ({r['chunks']} chunks of {r['chunk_views']}, pilot {r['pilot_s']:.1f} s, chunks "
        f"{sum(r['chunk_seconds']):.1f} s wall / {cpu:.1f} s CPU on the workers), views "
        f"{t.get('viewpoint_objects', 0):.1f} s{greedy} | peak MB client {r['client_peak_mb']:.0f}, workers {workers} "
        f"| store {r['store_mb']:.0f} MB digest {r.get('digest', '-')} | load {r['load_1min']:.1f}",
        flush=True,
    )
    if "client_cpu_s" in r:  # --evaluation-only: where the CPU went during the evaluation
        worker_cpu = " ".join(f"{c:.1f}" for c in r.get("worker_cpu_s", [])) or "-"
        worker_faults = " ".join(f"{f / 1e6:.2f}" for f in r.get("worker_minor_faults", [])) or "-"
        print(
            f"      evaluation CPU s: client {r['client_cpu_s']:.1f}, workers {worker_cpu} | minor page faults "
            f"(millions): client {r.get('client_minor_faults', 0) / 1e6:.2f}, workers {worker_faults}",
            flush=True,
        )


def report_panel(runs: dict, counts) -> None:
    one, two = runs.get(1), runs.get(2)
    measured = [r for r in (one, two) if r and "chunk_seconds" in r and r.get("chunk_seconds")]
    if not measured:
        return
    text = []
    if one and two and "evaluation_s" in one and "evaluation_s" in two:
        speedup = one["evaluation_s"] / two["evaluation_s"]
        cpu = [sum(r.get("chunk_cpu_seconds") or []) for r in (one, two)]
        text.append(
            f"  speed-up of the evaluation, 2 local workers over 1: {speedup:.2f}x (measured; chunk CPU "
            f"{cpu[0]:.1f} s vs {cpu[1]:.1f} s)"
        )
    base_run = measured[0]
    scatter = scatter_model(measured)
    base = projection(base_run, 1, scatter)
    source = "both runs' scatters" if len({r["workers"] for r in measured}) > 1 else "this run's scatter"
    text.append(
        f"  PROJECTION (a model, not a measurement) from the {base_run['workers']}-worker run's chunk and pilot task "
        f"times: {base_run['evaluation_s']:.1f} s measured; the model gives "
        f"{projection(base_run, base_run['workers'], scatter):.1f} s for {base_run['workers']}, {base:.1f} s for 1; "
        f"scatter {scatter[0]:.2f} s + {scatter[1]:.2f} s per worker (from {source})"
    )
    for n in counts:
        t = projection(base_run, n, scatter)
        note = f", measured {two['evaluation_s']:.1f} s" if n == 2 and two and "evaluation_s" in two else ""
        text.append(f"  PROJECTION for {n} workers: {t:.1f} s, efficiency {100 * base / (n * t):.0f} %{note}")
    print("\n".join(text), flush=True)


def same_digests(results) -> str:
    digests = {}
    for r in results:
        if "digest" in r:
            digests.setdefault((r["area_m2"], r["tilt"]), []).append(r["digest"])
    compared = {key: set(d) for key, d in digests.items() if len(d) > 1}
    if not compared:
        return "not compared (fewer than two configurations finished per panel and tilt)"
    return "yes" if all(len(d) == 1 for d in compared.values()) else f"NO: {compared}"


if __name__ == "__main__":
    raise SystemExit(main())
