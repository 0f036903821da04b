"""The 3D next-best-view methods on the simulated station.

Per object (the shared parts scaled to a 100-250 mm largest extent, the procedural concave shapes, or any mesh
path) it builds the observable ground truth once, then runs every method on the same station, candidate pool and
filters with the scanner noise on: C(k) (coverage of the observable surface after k views), AUC over 10 views,
views to 90 / 95 %, joint path, motion time, planning time per view (median, p95), Chamfer distance of the fused
cloud, the termination reason. ``random`` runs over --random-seeds seeds (mean). ``oracle`` is the set cover of
the observable truth over the ground truth's feasible poses (the project's set cover; a lower bound on views),
and the coverage over the straight joint path of two planners that know the truth (each view the pose seeing the
most new points, or the most per rad of the move): in the targets, ``*_straight_path_ratio`` compares their
straight joint distance, and ours', with the best volumetric metric's at equal coverage (what exact gains could
save; the executed paths add the detours around obstacles).

examples (python -m benchmarks.nbv3d ...):
  --objects cube cup two_towers --methods ours random hemisphere12 oracle --json /tmp/nbv.json
  --objects all --methods ours occlusion_aware unobserved_voxel rear_side_voxel rear_side_entropy \\
      proximity_count average_entropy area_factor report3d random hemisphere6 hemisphere12 hemisphere24 oracle \\
      --max-views 20 --json nbv_full.json
  --objects all --methods ours --seeds 2 --ours-weight proximity_count=1 --ours-weight report=0.3 \\
      --config-option motion.opening_elevation_deg=90 --json variant.json     # then --merge nbv_full.json variant.json
  --gain-quality --objects all --max-views 10 --compare-weights proximity_count=1,report=0.3

Objects: cube, cylinder, featuretype, fandisk, angle_block, idler_riser, plate_holes (shared parts), u_channel,
cup, two_towers, l_bracket, torus (procedural), or a mesh path (mm); "all" = every named one. ``--set
evaluation|tuning|all`` takes the generated parts of agiprobot_measurement.nbv.simulation.families3d instead (the
evaluation half was never used to tune anything; with ``all`` it is run and reported first), e.g.
  --set evaluation --methods ours ours_tour rear_side_voxel proximity_count random oracle --seeds 3 \
      --random-seeds 3 --max-views 20 --pixel-step 4 --json /tmp/heldout.json

Besides the targets of the original 12 objects, ``comparisons`` holds for ours and ours_tour, against the best
volumetric metric (and ours_tour against ours): the joint path, the motion seconds and the time (planning + motion
+ capture + fusion) until both runs of a pair first reach 0.90, 0.95 and the pair's lower final coverage, as the
ratio, mean over the run pairs, median over the objects; and per method the medians of C(4), AUC(10), N95, the
times to 0.90 / 0.95, planning per view and self-termination.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.nbv.simulation.families3d import FAMILY_SETS, family_parts, is_family_part
from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, auc, simulate, views_to
from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation
from agiprobot_measurement.nbv.volumetric.gain_names import GAIN_NAMES
from agiprobot_measurement.nbv.volumetric.policies.ours import OursPolicy
from agiprobot_measurement.nbv.volumetric.request import METHODS, ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.station3d import load_nbv_config
from benchmarks.harness import ROOT, load_conditions, number_value, parse_key_values, write_json
from benchmarks.nbv_oracles import ORACLE_LOOP_POOLS, GainQuality, TruthLoopPolicy, oracle_views

CONDITIONS = load_conditions("nbv3d_loop")
SHARED = (ROOT / CONDITIONS["parts_dir"]).resolve()
#: name -> (file, unit, largest extent (m) on the fixture or None to keep it)
PARTS = {name: (p["file"], p["unit"], p["extent_m"]) for name, p in CONDITIONS.mapping("parts").items()}
SHAPE_NAMES = tuple(CONDITIONS["shapes"])
DEFAULTS = CONDITIONS.mapping("defaults")
#: the seven volumetric metrics of Isler / Delmerico (every gain but the report's own)
VOLUMETRIC = tuple(name for name in GAIN_NAMES if name != "report")


def resolve_object(name: str):
    """(part argument, units, extent_m) of an object name or mesh path."""
    if name in PARTS:
        file, units, extent = PARTS[name]
        path = SHARED / file
        if not path.is_file():
            raise InputError(f"object {name}: {path} not found")
        return str(path), units, extent
    if name in SHAPE_NAMES or is_family_part(name):
        return name, "mm", None
    path = Path(name)
    if path.is_file():
        return str(path), "mm", None
    raise InputError(f"unknown object {name!r}: one of {', '.join([*PARTS, *SHAPE_NAMES])} or a mesh path")


def percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else math.nan


def aggregate(runs: list[dict], max_views: int) -> dict:
    """Mean over seeds of one method on one object."""
    curves = [r.get("coverage_curve", []) for r in runs]
    padded = [(c + [c[-1] if c else 0.0] * max_views)[:max_views] for c in curves]
    mean_curve = np.mean(padded, axis=0).tolist() if padded else []
    planning = [p for r in runs for p in r["planning_s_per_view"]]

    def mean_of(key):
        values = [r[key] for r in runs if r.get(key) is not None and np.isfinite(r[key])]
        return float(np.mean(values)) if values else None

    def n_to(key):
        values = [r.get(key) for r in runs]
        if any(v is None for v in values):
            return None
        return float(np.mean(values))

    return {
        "runs": len(runs),
        "coverage_curve_mean": mean_curve,
        "c4": mean_curve[3] if len(mean_curve) >= 4 else None,
        "final_coverage": mean_of("coverage"),
        "final_coverage_full_surface": mean_of("coverage_full_surface"),
        "motion_failures": mean_of("motion_failures"),
        "surprises": mean_of("surprises"),
        "auc10": mean_of("auc10"),
        "n90": n_to("n90"),
        "n95": n_to("n95"),
        "views": float(np.mean([r["views"] for r in runs])),
        "joint_path_rad": mean_of("joint_path_rad"),
        "motion_time_s": mean_of("motion_time_s"),
        "planning_median_s": percentile(planning, 50),
        "planning_p95_s": percentile(planning, 95),
        "chamfer_mm": mean_of("chamfer_mm"),
        "accuracy_mm": mean_of("accuracy_mm"),
        "termination": [r["termination_reason"] for r in runs],
        "self_terminated": float(
            np.mean([r["termination_reason"] in ("gain_below_threshold", "frontier_exhausted") for r in runs])
        ),
        "true_collisions": int(sum(r["true_collisions"] for r in runs)),
        "wall_time_s": float(np.sum([r["wall_time_s"] for r in runs])),
    }


def self_terminated(summary: dict) -> dict:
    """The run as it would have ended at its stopping rule: the prefix of a budget run up to the view where the rule
    fired (the views and their measurements are the same up to there; the motions between them may differ, since
    OMPL's random planner is seeded once per process), with the metrics of that prefix. A run whose rule never fired is
    returned as it is."""
    stop = summary.get("stop") or {}
    if "view" not in stop:
        return summary
    k = int(stop["view"])
    out = {key: value for key, value in summary.items() if key != "stop"}
    log = summary["view_log"][:k]
    curve = summary.get("coverage_curve", [])[:k]
    out.update(
        {
            "termination_reason": stop["reason"],
            "views": k,
            "view_log": log,
            "coverage_curve": curve,
            "planning_s_per_view": summary["planning_s_per_view"][: max(k - 1, 0)],
            "joint_path_rad": float(sum(v["joint_path_rad"] for v in log)),
            "motion_time_s": float(sum(v["motion_s"] for v in log)),
            "coverage": stop.get("coverage", curve[-1] if curve else None),
            "coverage_full_surface": stop.get("coverage_full_surface"),
            "auc10": auc(curve, 10),
            "n90": views_to(curve, 0.90),
            "n95": views_to(curve, 0.95),
        }
    )
    for key in ("chamfer_mm", "accuracy_mm", "completeness_mm"):
        if key in stop:
            out[key] = stop[key]
    out["budget_final_coverage"] = summary.get("coverage")
    return out


def path_to(run: dict, level: float) -> tuple[float, bool]:
    """Joint path (rad) of a run until its coverage first reaches ``level``, and whether it did."""
    total = 0.0
    for v in run.get("view_log", []):
        total += float(v["joint_path_rad"])
        if v.get("coverage") is not None and v["coverage"] >= level - 1e-9:
            return total, True
    return total, False


def straight_path_to(run: dict, level: float, home_rad) -> float:
    """Straight joint distance (rad, summed over the joints) from ``home_rad`` through a run's views until its
    coverage first reaches ``level`` (inf if never): its path without the detours around obstacles."""
    total, q = 0.0, np.asarray(home_rad, dtype=float)
    for v in run.get("view_log", []):
        joints = np.asarray(v["joints_rad"], dtype=float)
        total += float(np.abs(joints - q).sum())
        q = joints
        if v.get("coverage") is not None and v["coverage"] >= level - 1e-9:
            return total
    return math.inf


def fmt(v, spec=".3f"):
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--objects", nargs="+", default=None, help=f"default: {' '.join(DEFAULTS['objects'])}")
    parser.add_argument(
        "--set",
        default=None,
        choices=FAMILY_SETS,
        help="the generated parts of this half instead of --objects (evaluation = held out; all = both, held out first)",
    )
    parser.add_argument("--methods", nargs="+", default=list(DEFAULTS["methods"]))
    parser.add_argument("--max-views", type=int, default=DEFAULTS["max_views"])
    parser.add_argument("--random-seeds", type=int, default=DEFAULTS["random_seeds"])
    parser.add_argument("--seed", type=int, default=0, help="scene noise seed, and the first run seed")
    parser.add_argument("--seeds", type=int, default=1, help="run seeds of every method but random (seed, seed+1, ...)")
    parser.add_argument(
        "--no-budget-run",
        action="store_true",
        help="ours stops at its stopping rule (default: it goes on to the budget, the rule's view is "
        "noted, and the self-terminated run is the prefix: 'ours' = that prefix, "
        "'ours@budget' = the whole run)",
    )
    parser.add_argument(
        "--ours-option",
        action="append",
        default=[],
        metavar="FIELD=NUMBER",
        help="a numeric ReconstructionRequest field for 'ours' only (repeatable), e.g. cost_weight=0.15",
    )
    parser.add_argument(
        "--ours-weight",
        action="append",
        default=[],
        metavar="TERM=WEIGHT",
        help="a term of ours' score (repeatable; together they replace config/nbv.yaml "
        "planning.ours_weights for this run), e.g. proximity_count=1 average_entropy=2",
    )
    parser.add_argument(
        "--config-option",
        action="append",
        default=[],
        metavar="SECTION.KEY=NUMBER",
        help="override a numeric entry of config/nbv.yaml for every method of this run (repeatable), "
        "e.g. motion.opening_elevation_deg=55",
    )
    parser.add_argument(
        "--gain-quality",
        action="store_true",
        help="instead of the benchmark: run 'ours' once per object and measure, at each of its first "
        "8 decisions below 97 %% coverage, how much of the truly best candidate's new coverage "
        "each gain's best candidate gets (1 = it picks the truly best view)",
    )
    parser.add_argument(
        "--decisions",
        type=int,
        default=8,
        help="with --gain-quality: how many of ours' decisions are scored (default 8: the opening game; up to "
        "--max-views for the tail too; the JSON keeps every decision's shares)",
    )
    parser.add_argument(
        "--compare-weights",
        action="append",
        default=[],
        metavar="TERM=W,TERM=W",
        help="with --gain-quality: also score this mix of ours' terms on the same decisions "
        "(repeatable), e.g. proximity_count=1,report=0.3",
    )
    parser.add_argument("--pixel-step", type=int, default=DEFAULTS["pixel_step"])
    parser.add_argument(
        "--noise-free", action="store_true", help="the simulated PhoXi without noise (default: config/nbv.yaml's)"
    )
    parser.add_argument(
        "--gt-spacing", type=float, default=DEFAULTS["gt_spacing_m"], help="ground-truth point spacing (m)"
    )
    parser.add_argument("--gt-directions", type=int, default=DEFAULTS["gt_directions"])
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--no-chamfer", action="store_true")
    parser.add_argument("--merge", nargs="+", default=None, help="only merge earlier --json files and print")
    args = parser.parse_args(argv)
    try:
        if args.merge:
            return merge(args)
        if args.gain_quality:
            return gain_quality(args)
        return run(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def ours_overrides(options: list[str]) -> dict:
    """``--ours-option FIELD=NUMBER`` as request overrides; a field that is not a numeric request field, or a value
    that is not a number, is refused with its name (the request validates the range)."""
    numeric = {f.name for f in dataclasses.fields(ReconstructionRequest) if f.type in ("float", "int", float, int)}
    numeric -= {"seed", "max_views"}  # --seed / --seeds and --max-views set them for every method
    return parse_key_values(
        options, "--ours-option", "FIELD=NUMBER", sorted(numeric), lambda _, text: number_value(text)
    )


def ours_weights(options: list[str], flag: str = "--ours-weight") -> dict | None:
    """``--ours-weight TERM=WEIGHT`` (or ``flag``'s items) as ours' score weights (None: the configured ones); an
    unknown term or a weight that is not a finite number >= 0 is refused with its name."""
    if not options:
        return None
    known = (*OursPolicy.own_terms, *GAIN_NAMES)
    out = parse_key_values(options, flag, "TERM=WEIGHT", known, lambda _, text: number_value(text, low=0.0))
    if not any(out.values()):
        raise InputError(f"{flag}: at least one weight must be positive")
    return out


def config_overrides(options: list[str], config: dict) -> dict:
    """``--config-option SECTION.KEY=NUMBER`` as {(section, key): number}; the entry must exist in ``config`` (the
    loaded config/nbv.yaml) and be a number there, the value must be a finite number."""

    def value(path: str, text: str) -> float:
        section, dot, key = path.partition(".")
        if not dot:
            raise InputError("expected SECTION.KEY=NUMBER")
        current = config.get(section, {}).get(key) if isinstance(config.get(section), dict) else None
        if isinstance(current, bool) or not isinstance(current, (int, float)):
            raise InputError(f"config/nbv.yaml has no numeric entry {section}.{key}")
        return number_value(text)

    parsed = parse_key_values(options, "--config-option", "SECTION.KEY=NUMBER", value=value)
    return {tuple(path.partition(".")[::2]): number for path, number in parsed.items()}


def _setup(args):
    """(objects, their specs, the config with the command line's overrides, ours' request overrides)."""
    if args.set is not None and args.objects is not None:
        raise InputError("--set and --objects exclude each other")
    if args.set is not None:
        objects = family_parts("evaluation") + (family_parts("tuning") if args.set == "all" else [])
        if args.set == "tuning":
            objects = family_parts("tuning")
    else:
        objects = args.objects or list(DEFAULTS["objects"])
        objects = [*PARTS, *SHAPE_NAMES] if objects == ["all"] else objects
    ours_options = ours_overrides(args.ours_option)
    weights = ours_weights(args.ours_weight)
    config = load_nbv_config()
    config_options = config_overrides(args.config_option, config)
    for (section, key), value in config_options.items():
        config[section][key] = value
    if weights is not None:
        config.setdefault("planning", {})["ours_weights"] = dict(weights)
    if args.json and not Path(args.json).expanduser().parent.is_dir():
        raise InputError(f"--json: folder {Path(args.json).parent} does not exist")
    specs = [resolve_object(o) for o in objects]
    options = {"ours_weights": weights, "config_options": {f"{a}.{b}": v for (a, b), v in config_options.items()}}
    return objects, specs, config, ours_options, options


def gain_quality(args) -> int:
    """``--gain-quality``: per object one 'ours' run with a ``GainQuality`` hook."""
    objects, specs, config, ours_options, options = _setup(args)
    # the configured score without its motion cost, and the mixes to compare, on the same decisions
    mixes = {"score": dict(config.get("planning", {}).get("ours_weights", {}))}
    for i, text in enumerate(args.compare_weights, start=1):
        mixes[f"mix{i}"] = ours_weights(text.split(","), flag="--compare-weights")
    results = {
        "max_views": args.max_views,
        "pixel_step": args.pixel_step,
        **options,
        "gain_quality": {},
        "mixes": mixes,
    }
    for name, (part, units, extent) in zip(objects, specs, strict=True):
        station = SimulatedNBVStation(part, units, extent, seed=args.seed, pixel_step=args.pixel_step, config=config)
        truth = GroundTruth(station, spacing_m=args.gt_spacing, directions=args.gt_directions)
        hook = GainQuality(truth, max_decisions=args.decisions, mixes=mixes)
        request = ReconstructionRequest.with_config_defaults(
            gain="ours", max_views=args.max_views, seed=args.seed, **ours_options
        )
        simulate(station, request, truth, chamfer=False, on_scored=hook)
        results["gain_quality"][name] = {"decisions": len(hook.decisions), **hook.summary()}
        results.setdefault("gain_quality_decisions", {})[name] = hook.decisions
        print(f"[{name}] {len(hook.decisions)} decisions scored", file=sys.stderr)
    rows = results["gain_quality"]
    names = sorted({k for r in rows.values() for k in r if k != "decisions"})
    medians = {n: float(np.median([r[n] for r in rows.values() if n in r])) for n in names}
    results["gain_quality_median"] = medians
    print(f"{'object':12s} " + " ".join(f"{n[:10]:>10s}" for n in names))
    for obj, r in rows.items():
        print(f"{obj:12s} " + " ".join(f"{fmt(r.get(n)):>10s}" for n in names))
    print(f"{'median':12s} " + " ".join(f"{medians[n]:10.3f}" for n in names))
    if args.json:
        write_json(args.json, results)
    return 0


def run(args) -> int:
    for m in args.methods:
        if m != "oracle" and m not in METHODS and m not in ORACLE_LOOP_POOLS:
            raise InputError(f"unknown method {m!r}; known: {', '.join([*METHODS, 'oracle', *ORACLE_LOOP_POOLS])}")
    objects, specs, config, ours_options, options = _setup(args)
    results = {"max_views": args.max_views, "pixel_step": args.pixel_step, **options, "set": args.set,
               "noise_free": bool(args.noise_free), "objects": {}}  # fmt: skip
    for name, (part, units, extent) in zip(objects, specs, strict=True):
        t = time.perf_counter()
        station = SimulatedNBVStation(part, units, extent, seed=args.seed, pixel_step=args.pixel_step, config=config,
                                      noise=False if args.noise_free else None)  # fmt: skip
        truth = GroundTruth(station, spacing_m=args.gt_spacing, directions=args.gt_directions)
        entry = {
            "extent_mm": float(station.part_mesh.extents.max() * 1000),
            "observable_points": truth.n_observable,
            "surface_points": len(truth.points_m),
            "gt_poses": int(truth.visibility.matrix.shape[1]),
            "methods": {},
        }
        print(
            f"[{name}] {entry['extent_mm']:.0f} mm, observable {truth.n_observable}/{len(truth.points_m)} "
            f"from {entry['gt_poses']} poses ({time.perf_counter() - t:.1f} s)",
            file=sys.stderr,
        )
        for method in args.methods:
            if method == "oracle":
                oracle = oracle_views(truth)
                entry["methods"]["oracle"] = oracle
                print(
                    f"[{name}] oracle: set cover {oracle.get('set_cover_views')} views, n95 {oracle['n95']}",
                    file=sys.stderr,
                )
                continue
            seeds = range(args.random_seeds) if method == "random" else range(args.seed, args.seed + args.seeds)
            runs, budget_runs = [], []
            budget = method in ("ours", "ours_tour") and not args.no_budget_run
            for seed in seeds:
                overrides = {"gain": method, "max_views": args.max_views, "seed": seed}
                if method in VOLUMETRIC:
                    overrides["cost_weight"] = 0.0  # rpg's default
                if method in ("ours", "ours_tour"):
                    overrides.update(ours_options)
                factory = None
                if method in ORACLE_LOOP_POOLS:
                    # the truth-aware greedy inside ours' loop (ours' request, the choice by the true new points)
                    overrides["gain"] = "ours"
                    overrides.update(ours_options)

                    def factory(context, planning, pool=ORACLE_LOOP_POOLS[method], truth=truth):
                        return TruthLoopPolicy(context, planning, truth, pool)

                request = ReconstructionRequest.with_config_defaults(**overrides)
                try:
                    summary = simulate(station, request, truth, chamfer=not args.no_chamfer, budget_run=budget,
                                       policy_factory=factory)  # fmt: skip
                    summary["method"] = method
                except AgiprobotError as exc:  # e.g. a motion the time parameterisation refuses: noted, not fatal
                    entry.setdefault("failed_runs", []).append({"method": method, "seed": seed, "error": str(exc)})
                    print(f"[{name}] {method} seed {seed}: FAILED {exc}", file=sys.stderr)
                    continue
                if budget:
                    budget_runs.append(summary)
                    summary = self_terminated(summary)
                runs.append(summary)
                print(
                    f"[{name}] {method} seed {seed}: {summary['views']} views, coverage "
                    f"{fmt(summary.get('coverage'))}, {summary['termination_reason']}, "
                    f"{summary['wall_time_s']:.0f} s",
                    file=sys.stderr,
                )
            if not runs:
                continue
            entry["methods"][method] = {"summary": aggregate(runs, args.max_views), "runs": runs}
            if budget_runs:
                entry["methods"][method + "@budget"] = {
                    "summary": aggregate(budget_runs, args.max_views),
                    "runs": budget_runs,
                }
        results["objects"][name] = entry
        if args.json:  # after every object, so that a long run cut short keeps what it measured
            finish(results)
            write_json(args.json, results)
    finish(results)
    print_table(results)
    if args.json:
        write_json(args.json, results)
    return 0


def merge(args) -> int:
    """Merge result files (same objects: methods united) and print the table and the targets."""
    results = None
    for name in args.merge:
        path = Path(name).expanduser()
        if not path.is_file():
            raise InputError(f"--merge: {path} not found")
        data = json.loads(path.read_text())
        if results is None:
            results = data
            continue
        for obj, entry in data["objects"].items():
            results["objects"].setdefault(obj, entry)["methods"].update(entry["methods"])
    finish(results)
    print_table(results)
    if args.json:
        write_json(args.json, results)
    return 0


#: the coverage a self-terminated run may lose against the same run continued to the budget (the target's 1 point)
STOP_LOSS_POINT = 0.01
#: the planners compared at fixed coverage levels (each against the best volumetric metric; ours_tour also against ours)
COMPARED = ("ours", "ours_tour")
LEVELS = (0.90, 0.95, "final")


def finish(results: dict) -> None:
    """The targets and the comparisons, over all objects and, for generated parts, per half (held out first)."""
    results["targets"] = targets(results)
    results["comparisons"] = comparisons(results)
    halves = {}
    for half in ("evaluation", "tuning"):
        names = set(family_parts(half))
        part = {**results, "objects": {o: e for o, e in results["objects"].items() if o in names}}
        if part["objects"]:
            halves[half] = {"targets": targets(part), "comparisons": comparisons(part)}
    results["by_set"] = halves


def level_cost(run: dict, level: float) -> dict | None:
    """Joint path (rad), motion (s) and time (planning + motion + capture + fusion, s) of a run until its coverage
    first reaches ``level``; None if it never does."""
    path = motion = total = 0.0
    for v in run.get("view_log", []):
        path += float(v["joint_path_rad"])
        motion += float(v["motion_s"])
        total += sum(float(v.get(k) or 0.0) for k in ("planning_s", "motion_s", "capture_s", "integrate_s"))
        if v.get("coverage") is not None and v["coverage"] >= level - 1e-9:
            return {"path_rad": path, "motion_s": motion, "time_s": total}
    return None


def comparisons(results: dict) -> dict:
    """Ratios at fixed coverage levels and per-method medians (see the module docstring)."""
    objects = {obj: e["methods"] for obj, e in results["objects"].items()}
    tg = targets(results) if objects else {}
    best = tg.get("best_volumetric_auc10_metric")
    out: dict = {"reference": best, "ratios": {}, "methods": {}}
    pairs = [(p, best) for p in COMPARED if best] + [("ours_tour", "ours")]
    for a_name, b_name in pairs:
        key = f"{a_name}/{b_name}"
        per_object = {}
        for obj, m in objects.items():
            if a_name not in m or b_name not in m:
                continue
            a_runs, b_runs = m[a_name]["runs"], m[b_name]["runs"]
            row = {}
            for level in LEVELS:
                ratios = {"path_rad": [], "motion_s": [], "time_s": []}
                for a, b in zip(a_runs, b_runs * len(a_runs), strict=False):
                    lv = min(a.get("coverage") or 0.0, b.get("coverage") or 0.0) if level == "final" else level
                    ca, cb = level_cost(a, lv), level_cost(b, lv)
                    if ca is None or cb is None:
                        continue
                    for k in ratios:
                        if cb[k] > 0:
                            ratios[k].append(ca[k] / cb[k])
                for k, values in ratios.items():
                    if values:
                        row[f"{k}@{level}"] = float(np.mean(values))
            per_object[obj] = row
        keys = sorted({k for r in per_object.values() for k in r})
        out["ratios"][key] = {
            "median": {k: float(np.median([r[k] for r in per_object.values() if k in r])) for k in keys},
            "objects_compared": {k: sum(k in r for r in per_object.values()) for k in keys},
            "per_object": per_object,
        }
    methods = sorted({name for m in objects.values() for name in m if name != "oracle"})
    for name in methods:
        out["methods"][name] = method_medians([m[name] for m in objects.values() if name in m])
    return out


def _median(values):
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def _to_level(rows: list, level: float, key: str):
    """Median over the objects of the mean over runs of ``key`` until ``level`` (a run that never reaches it: inf)."""
    per = []
    for row in rows:
        costs = [level_cost(r, level) for r in row["runs"]]
        per.append(math.inf if any(c is None for c in costs) else float(np.mean([c[key] for c in costs])))
    return float(np.median(per)) if per else None


def method_medians(rows: list) -> dict:
    """One method's medians over the objects (``rows``: its per-object entries with summary and runs)."""
    runs = [r for row in rows for r in row["runs"]]
    losses = [
        (r.get("budget_final_coverage") or 0.0) - (r.get("coverage") or 0.0)
        for r in runs
        if "budget_final_coverage" in r
    ]
    stopped = [r["termination_reason"] in ("gain_below_threshold", "frontier_exhausted") for r in runs]
    # a budget run: its rule fired (the prefix, with the budget run's coverage) or never did (it keeps its "stop")
    budget_known = ["budget_final_coverage" in r or "stop" in r for r in runs]
    # the target's figure: stopped by its own rule before the budget, and within 1 point of the run continued to it
    within = [
        done and (r.get("budget_final_coverage") or 0.0) - (r.get("coverage") or 0.0) <= STOP_LOSS_POINT + 1e-9
        for done, r in zip(stopped, runs, strict=True)
    ]
    return {
        "objects": len(rows),
        "runs": len(runs),
        "c4": _median([row["summary"]["c4"] for row in rows]),
        "auc10": _median([row["summary"]["auc10"] for row in rows]),
        "final": _median([row["summary"]["final_coverage"] for row in rows]),
        "n95": _median([math.inf if row["summary"]["n95"] is None else row["summary"]["n95"] for row in rows]),
        "time_to_090_s": _to_level(rows, 0.90, "time_s"),
        "time_to_095_s": _to_level(rows, 0.95, "time_s"),
        "motion_to_095_s": _to_level(rows, 0.95, "motion_s"),
        "path_to_095_rad": _to_level(rows, 0.95, "path_rad"),
        "planning_median_s": _median([p for r in runs for p in r["planning_s_per_view"]]),
        "self_terminated": float(np.mean(stopped)) if stopped else None,
        "stop_loss_max": max(losses or [0.0]),
        "stop_loss_median": _median(losses or [0.0]),
        # only where the runs were continued to the budget (a method that stopped for real has no loss to measure)
        "stopped_within_1pt": float(np.mean(within)) if within and any(budget_known) else None,
    }


def print_comparisons(title: str, comp: dict) -> None:
    print(f"== {title}: per method, median over the objects (reference metric: {comp.get('reference')})")
    cols = ("c4", "auc10", "final", "n95", "time_to_090_s", "time_to_095_s", "motion_to_095_s", "path_to_095_rad",
            "planning_median_s", "self_terminated", "stop_loss_max", "stopped_within_1pt")  # fmt: skip
    print(f"{'method':<18} " + " ".join(f"{c[:13]:>13}" for c in cols))
    for name, row in comp.get("methods", {}).items():
        print(f"{name:<18} " + " ".join(f"{fmt(row.get(c), '.3f'):>13}" for c in cols))
    for key, r in comp.get("ratios", {}).items():
        med = r["median"]
        n = r["objects_compared"]
        print(f"   {key}: " + ", ".join(f"{k} {v:.3f} ({n[k]} obj)" for k, v in med.items()))


def targets(results: dict) -> dict:
    """The targets' figures, per object and as the median over objects (where the methods were run).

    "The best volumetric metric" is the one of the seven with the best median over the objects (of C(4), resp.
    AUC(10)), so one metric for all objects as a user would pick it; ``*_per_object_max`` is the stricter bound
    of the best metric picked per object afterwards. The joint path is compared at equal coverage: per object and
    run pair, the path each needed to first reach the lower of the two final coverages."""
    objects = {obj: e["methods"] for obj, e in results["objects"].items() if "ours" in e["methods"]}

    def med(values):
        values = [v for v in values if v is not None]
        return float(np.median(values)) if values else None

    metrics = [k for k in VOLUMETRIC if objects and all(k in m for m in objects.values())]
    by_metric = {
        k: {key: med([m[k]["summary"][key] for m in objects.values()]) for key in ("c4", "auc10", "joint_path_rad")}
        for k in metrics
    }
    best_c4 = max(metrics, key=lambda k: by_metric[k]["c4"] or 0.0) if metrics else None
    best_auc = max(metrics, key=lambda k: by_metric[k]["auc10"] or 0.0) if metrics else None
    per = {}
    for obj, m in objects.items():
        ours = m["ours"]["summary"]
        row = {
            "ours_c4": ours["c4"],
            "ours_auc10": ours["auc10"],
            "ours_n95": ours["n95"],
            "ours_planning_median_s": ours["planning_median_s"],
            "ours_self_terminated": ours["self_terminated"],
            "ours_views": ours["views"],
            "ours_chamfer_mm": ours["chamfer_mm"],
            "ours_accuracy_mm": ours["accuracy_mm"],
            "ours_joint_path_rad": ours["joint_path_rad"],
            "ours_final": ours["final_coverage"],
        }
        if "ours@budget" in m:
            # a run whose rule never fired is its budget run: it lost nothing
            losses = [
                (r["budget_final_coverage"] or 0.0) - (r.get("coverage") or 0.0)
                if "budget_final_coverage" in r
                else 0.0
                for r in m["ours"]["runs"]
            ]
            row["ours_budget_final"] = m["ours@budget"]["summary"]["final_coverage"]
            row["ours_stop_loss_max"] = float(max(losses))
            row["ours_stopped_before_budget"] = float(
                np.mean(
                    [
                        r["views"] < results["max_views"] and r["termination_reason"] != "max_views"
                        for r in m["ours"]["runs"]
                    ]
                )
            )
        vol = {k: v["summary"] for k, v in m.items() if k in VOLUMETRIC}
        if vol:
            k4 = max(vol, key=lambda k: vol[k]["c4"] or 0.0)
            ka = max(vol, key=lambda k: vol[k]["auc10"] or 0.0)
            row.update(
                {
                    "best_volumetric_c4_per_object_max": vol[k4]["c4"],
                    "best_volumetric_c4_per_object": k4,
                    "best_volumetric_auc10_per_object_max": vol[ka]["auc10"],
                    "best_volumetric_auc10_per_object": ka,
                }
            )
        if best_auc in m:
            row["best_volumetric_c4"] = m[best_c4]["summary"]["c4"]
            row["best_volumetric_auc10"] = m[best_auc]["summary"]["auc10"]
            row["best_volumetric_joint_path_rad"] = m[best_auc]["summary"]["joint_path_rad"]
            row["best_volumetric_final"] = m[best_auc]["summary"]["final_coverage"]
            ratios, ours_paths, vol_paths = [], [], []
            # the same comparison on straight joint distances, for ours and the truth-aware planners (the oracle's
            # path curves): what a planner that knew the part could save (gains exact, moves straight)
            oracle = m.get("oracle", {})
            curves = oracle.get("path_curves", {})
            straight = {"ours": []} | {f"oracle_{name}": [] for name in curves}
            for a, b in zip(m["ours"]["runs"], m[best_auc]["runs"] * len(m["ours"]["runs"]), strict=False):
                level = min(a.get("coverage") or 0.0, b.get("coverage") or 0.0)
                pa, _ = path_to(a, level)
                pb, _ = path_to(b, level)
                ours_paths.append(pa)
                vol_paths.append(pb)
                ratios.append(pa / pb if pb > 0 else math.inf)
                if not curves:
                    continue
                sb = straight_path_to(b, level, oracle["home_rad"])
                if not (sb > 0 and math.isfinite(sb)):
                    continue
                straight["ours"].append(straight_path_to(a, level, oracle["home_rad"]) / sb)
                for name, curve in curves.items():
                    reached = [path for coverage, path in curve if coverage >= level - 1e-9]
                    straight[f"oracle_{name}"].append((reached[0] if reached else math.inf) / sb)
            row["ours_path_at_equal_coverage_rad"] = float(np.mean(ours_paths))
            row["best_volumetric_path_at_equal_coverage_rad"] = float(np.mean(vol_paths))
            row["path_ratio_at_equal_coverage"] = float(np.mean(ratios))
            for key, values in straight.items():
                if values:
                    row[f"{key}_straight_path_ratio"] = float(np.mean(values))
        if "random" in m:
            rnd = m["random"]["summary"]
            row.update({"random_c4": rnd["c4"], "random_auc10": rnd["auc10"], "random_n95": rnd["n95"]})
        if "oracle" in m:
            row["oracle_n95"] = m["oracle"].get("n95")
            row["oracle_set_cover"] = m["oracle"].get("set_cover_views")
        per[obj] = row

    def median(key):
        if key.endswith(("_n90", "_n95")):
            # views to a level: an object where it was not reached (in some run) counts as never, not as absent
            values = [math.inf if r[key] is None else r[key] for r in per.values() if key in r]
        else:
            values = [r[key] for r in per.values() if r.get(key) is not None]
        return float(np.median(values)) if values else None

    keys = sorted({k for r in per.values() for k, v in r.items() if isinstance(v, (int, float)) or k.endswith("_n95")})
    all_runs = [r for m in objects.values() for r in m["ours"]["runs"]]
    summary = {k: median(k) for k in keys}
    if all_runs:
        summary["ours_runs_stopped_before_budget"] = float(
            np.mean([r["views"] < results["max_views"] and r["termination_reason"] != "max_views" for r in all_runs])
        )
    return {
        "per_object": per,
        "median": summary,
        "volumetric_medians": by_metric,
        "best_volumetric_c4_metric": best_c4,
        "best_volumetric_auc10_metric": best_auc,
    }


def print_table(results: dict) -> None:
    head = (
        f"{'object':<12} {'method':<18} {'C(1)':>5} {'C(4)':>5} {'C(8)':>5} {'final':>5} {'AUC10':>5} {'N90':>4} "
        f"{'N95':>4} {'views':>5} {'path':>6} {'motion':>6} {'plan50':>6} {'plan95':>6} {'cham':>5} term"
    )
    print(head)
    for name, entry in results["objects"].items():
        for method, data in entry["methods"].items():
            if method == "oracle":
                print(
                    f"{name:<12} {'oracle':<18} set cover {data.get('set_cover_views')} views, greedy N90 "
                    f"{data.get('n90')} N95 {data.get('n95')}"
                )
                continue
            s = data["summary"]
            c = s["coverage_curve_mean"]

            def at(k, c=c):
                return fmt(c[k - 1], ".2f") if len(c) >= k else "-"

            terms = sorted(set(s["termination"]))
            print(
                f"{name:<12} {method:<18} {at(1):>5} {at(4):>5} {at(8):>5} {fmt(s['final_coverage'], '.2f'):>5} "
                f"{fmt(s['auc10'], '.3f'):>5} {fmt(s['n90'], '.1f'):>4} {fmt(s['n95'], '.1f'):>4} "
                f"{s['views']:>5.1f} {fmt(s['joint_path_rad'], '.1f'):>6} {fmt(s['motion_time_s'], '.1f'):>6} "
                f"{fmt(s['planning_median_s'], '.2f'):>6} {fmt(s['planning_p95_s'], '.2f'):>6} "
                f"{fmt(s['chamfer_mm'], '.2f'):>5} {','.join(terms)}"
            )
    tg = results.get("targets", {})
    if tg.get("volumetric_medians"):
        print(
            "volumetric metrics, median over the objects: "
            + ", ".join(
                f"{k} C4 {fmt(v['c4'], '.3f')} AUC10 {fmt(v['auc10'], '.3f')}"
                for k, v in tg["volumetric_medians"].items()
            )
        )
        print(
            f"best volumetric metric (median): C(4) {tg['best_volumetric_c4_metric']}, "
            f"AUC(10) {tg['best_volumetric_auc10_metric']}"
        )
    medians = tg.get("median", {})
    if medians:
        print("median over objects: " + ", ".join(f"{k} {v:.3f}" for k, v in medians.items() if v is not None))
    halves = results.get("by_set") or {}
    for half in ("evaluation", "tuning"):
        if half in halves:
            label = "held-out (evaluation) parts" if half == "evaluation" else "tuning parts (not the targets)"
            print_comparisons(label, halves[half]["comparisons"])
    if not halves and results.get("comparisons"):
        print_comparisons("all objects", results["comparisons"])


if __name__ == "__main__":
    raise SystemExit(main())
