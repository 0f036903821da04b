"""The 2D range-finder planner (Fojtík & Pajdla): six objects x three scripts, noise-free and with
depth noise, a short and a long laser-camera distance, and the report's section 7.1 remedy (edge-midpoint aiming).

Prints a table and the targets (met or not), and writes every run's summary to a JSON file. Coverage and
D0 are judged separately for the centre-aim runs (the report's planner, the whole matrix) and the edge-midpoint runs
(the report's section 7.1 remedy, fullpix and stratpix, noise-free and noisy), so that neither aim hides the other;
the D0, path and section 7.1 targets use the noise-free runs:

    python -m benchmarks.nbv2d                                   # the full matrix, 2 processes
    python -m benchmarks.nbv2d --objects disc triangle --scripts fullpix --jobs 1
    python -m benchmarks.nbv2d --objects u_shape --baselines long --aims centre --noisy off   # a subset
    python -m benchmarks.nbv2d --short 40 --long 250 --noise 0.3 --json /tmp/nbv2d.json --table /tmp/nbv2d.txt
    python -m benchmarks.nbv2d --scripts fullpix stratpix --s2-orbit-budget none --json /tmp/b.json   # full orbit
    python -m benchmarks.nbv2d --set evaluation --scripts fullpix stratpix --baselines long   # generated bodies
    python -m benchmarks.nbv2d --objects star5 --scripts fullpix stratpix --baselines long --noisy off

``--set tuning|evaluation|all`` runs the generated bodies of :mod:`agiprobot_measurement.nbv.planar.families` (stars,
combs, spirals, random polygons, blobs; the evaluation half was never used to tune the planner) instead of the six
substitutes; with ``--set all`` the held-out (evaluation) figures are printed first. The targets that compare scripts
object by object (path, section 7.1) are defined on the six substitutes only.

Lengths in cells (1 cell = 1 mm); ``--short`` / ``--long`` are RFlength values, the standoff is kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from agiprobot_measurement.common.files import atomic_write_text
from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.evaluation import coverage, measurable_boundary, plannable_boundary, summarize
from agiprobot_measurement.nbv.planar.families import FAMILY_SETS, family_bodies, make_body
from agiprobot_measurement.nbv.planar.loop import run
from agiprobot_measurement.nbv.planar.objects import OBJECT_NAMES
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D
from agiprobot_measurement.nbv.planar.run_config import RunConfig
from agiprobot_measurement.nbv.planar.strategies import SCRIPTS
from benchmarks.harness import (
    OptionError,
    Target,
    format_targets,
    load_conditions,
    parse_key_values,
    switch_value,
    targets_json,
    write_json,
)

CONDITIONS = load_conditions("nbv2d")
DEFAULTS = CONDITIONS.mapping("defaults")
TARGETS = CONDITIONS.mapping("targets")


def _one(job):
    obj, script, length, aim, noise, seed, baseline, extra = job
    rf = RangeFinder2D.from_config().with_length(length)
    truth = make_body(obj)
    result = run(truth, rf, RunConfig(script=script, aim=aim, noise_sigma_cells=noise, seed=seed, **extra))
    # the denominator: the boundary cells that a view planned onto the cell with this aim can see (the report's
    # section 7.1: cells beyond that are reached by no planned view); the any-ray figure is kept next to it
    plannable = plannable_boundary(truth, rf, aim)
    s = summarize(result, plannable, obj)
    s["baseline"] = baseline
    meas = measurable_boundary(truth, rf)
    s["measurable_any_ray_cells"] = int(meas.sum())
    s["coverage_any_ray"] = coverage(result.model, meas)
    # the share of the measurable cells that a view planned onto them can see at all
    s["plannable_share"] = float((plannable & meas).sum() / max(int(meas.sum()), 1))
    return s


def target_checks(rows) -> list[Target]:
    """The targets over the runs: coverage and D0 are judged separately for the centre-aim runs and the
    edge-midpoint runs; the D0, path and section 7.1 targets use the noise-free runs."""
    out = []

    def sel(**kw):
        return [r for r in rows if all(r[k] == v for k, v in kw.items())]

    all_runs_nf = [r for r in rows if r["noise_sigma_cells"] == 0]
    nf = [r for r in all_runs_nf if r["aim"] == "centre"]
    bad = [r for r in all_runs_nf if r["termination"] != "growth_points_exhausted"]
    budget = [r for r in rows if r["termination"] in ("measurement_budget", "time_budget")]
    others = ", ".join(f"{r['object']}/{r['script']}/{r['baseline']}={r['termination']}" for r in bad) or "none"
    out.append(
        Target(
            "every noise-free run ends by exhausting growth points",
            f"{len(all_runs_nf) - len(bad)}/{len(all_runs_nf)}; others: {others}",
            "all",
            not bad,
        )
    )
    out.append(Target("runs ending on a budget", f"{len(budget)} of {len(rows)}", "none", not budget))
    # coverage: the matrix runs aim at cell centres (the report's planner); the edge-midpoint runs (the report's
    # section 7.1 remedy, noise-free and noisy) are judged separately, so that neither aim hides the other
    for aim, noise_free, limit in (
        ("centre", True, TARGETS["coverage_noise_free"]),
        ("edge_midpoints", True, TARGETS["coverage_noise_free"]),
        ("centre", False, TARGETS["coverage_noisy"]),
        ("edge_midpoints", False, TARGETS["coverage_noisy"]),
    ):
        group = [r for r in rows if r["aim"] == aim and r["script"] in ("fullpix", "stratpix")]
        group = [r for r in group if (r["noise_sigma_cells"] == 0) == noise_free]
        if not group:
            continue
        worst = min(group, key=lambda r: r["coverage"])
        fails = [
            f"{r['object']}/{r['script']}/{r['baseline']}={r['coverage']:.3f} (any ray {r['coverage_any_ray']:.3f})"
            for r in group
            if r["coverage"] < limit
        ]
        out.append(
            Target(
                f"coverage with fullpix/stratpix ({'noise-free' if noise_free else 'noise'}, aim {aim})",
                f"min {worst['coverage']:.3f}; below: {', '.join(fails) or 'none'}",
                f">= {limit:.0%}",
                not fails,
            )
        )
    for aim in ("centre", "edge_midpoints"):
        group = [r for r in all_runs_nf if r["aim"] == aim]
        d0 = [r for r in group if r["d0_count"] > 0]
        if group:
            measured = ", ".join(f"{r['object']}/{r['script']}/{r['baseline']}={r['d0_count']}" for r in d0)
            out.append(Target(f"D0 noise-free (aim {aim}, all scripts)", measured or "all 0", "= 0", not d0))
    wins_needed = TARGETS["stratpix_shorter_on"]
    for baseline in sorted({r["baseline"] for r in nf}):
        wins = []
        for obj in OBJECT_NAMES:
            f = sel(object=obj, script="fullpix", baseline=baseline, aim="centre", noise_sigma_cells=0.0)
            s = sel(object=obj, script="stratpix", baseline=baseline, aim="centre", noise_sigma_cells=0.0)
            if f and s:
                wins.append(s[0]["path_length_cells"] <= f[0]["path_length_cells"])
        if wins:
            out.append(
                Target(
                    f"objects where stratpix path <= fullpix path ({baseline})",
                    f"{sum(wins)}/{len(wins)}",
                    f">= {wins_needed} of {len(OBJECT_NAMES)}",
                    sum(wins) >= wins_needed,
                )
            )
    for script in ("fullpix", "stratpix"):
        agg = {}
        for key in (("short", "centre"), ("long", "centre"), ("long", "edge_midpoints")):
            g = sel(script=script, baseline=key[0], aim=key[1], noise_sigma_cells=0.0)
            if g:
                agg[key] = (sum(r["unmeasurable_candidates"] for r in g), sum(r["transfer_length_cells"] for r in g))
        if len(agg) == 3:
            sc, lc, le = agg[("short", "centre")], agg[("long", "centre")], agg[("long", "edge_midpoints")]
            out.append(
                Target(
                    f"7.1 {script}: unmeasurable and transfer length, long baseline against short",
                    f"unmeasurable {sc[0]} -> {lc[0]}, transfer length {sc[1]:.0f} -> {lc[1]:.0f}",
                    "both larger",
                    lc[0] > sc[0] and lc[1] > sc[1],
                )
            )
            out.append(
                Target(
                    f"7.1 {script}: edge midpoints against centre at the long baseline",
                    f"unmeasurable {lc[0]} -> {le[0]}, transfer length {lc[1]:.0f} -> {le[1]:.0f}",
                    "both smaller",
                    le[0] < lc[0] and le[1] < lc[1],
                )
            )
    slow = max(rows, key=lambda r: r["run_time_s"])
    limit_s = TARGETS["run_time_s"]
    out.append(
        Target(
            "time per 400 x 400 run",
            f"slowest {slow['run_time_s']:.1f} s",
            f"<= {limit_s:g} s",
            slow["run_time_s"] <= limit_s,
        )
    )
    return out


def run_option_value(name: str, text: str) -> object:
    """A RunConfig field's value: a switch takes true/false (any case) or 1/0, others JSON or else text."""
    if RunConfig.__dataclass_fields__[name].type in ("bool", bool):
        return switch_value(text)
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def run_options(items) -> dict:
    """``NAME=VALUE`` texts -> RunConfig overrides for every run; :class:`OptionError` names a bad item (an unknown
    field, or a switch given anything but true/false: "False" read as text would be a true value)."""
    fields = sorted(set(RunConfig.__dataclass_fields__) - {"script", "aim", "noise_sigma_cells", "seed", "score"})
    return parse_key_values(items, "--run-option", "NAME=VALUE", fields, run_option_value)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--objects",
        nargs="+",
        default=None,
        choices=[*OBJECT_NAMES, "star5", *family_bodies("all")],
        help="the six substitutes by default",
    )
    p.add_argument(
        "--set",
        default=None,
        choices=FAMILY_SETS,
        help="the generated bodies of this half instead of --objects (evaluation = held out)",
    )
    p.add_argument("--scripts", nargs="+", default=list(SCRIPTS), choices=SCRIPTS)
    p.add_argument("--short", type=float, default=DEFAULTS["short"], help="short RFlength in cells (%(default)g)")
    p.add_argument("--long", type=float, default=DEFAULTS["long"], help="long RFlength in cells (%(default)g)")
    p.add_argument(
        "--noise", type=float, default=DEFAULTS["noise"], help="depth noise sigma in cells for the noisy runs"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--baselines", nargs="+", default=["short", "long"], choices=["short", "long"])
    p.add_argument("--aims", nargs="+", default=["centre", "edge_midpoints"], choices=["centre", "edge_midpoints"])
    p.add_argument("--noisy", default="both", choices=["both", "off", "only"], help="noise-free and/or noisy runs")
    p.add_argument("--jobs", type=int, default=DEFAULTS["jobs"])
    p.add_argument("--json", type=Path, default=Path(DEFAULTS["json"]), help="where to write the summaries")
    p.add_argument("--table", type=Path, default=None, help="also write the printed table and targets to this file")
    p.add_argument(
        "--s2-orbit-budget", default=None, help="stratpix orbit budget: s1_view (default), s1_jump, predicted or none"
    )
    p.add_argument("--s2-orbit-budget-factor", type=float, default=None, help="s1_jump orbit budget in S1 jumps")
    p.add_argument(
        "--run-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="any RunConfig field for every run, e.g. noise_laser_margin_sigmas=1 (value read as JSON, else text)",
    )
    args = p.parse_args(argv)
    try:
        extra = run_options(args.run_option)
    except OptionError as exc:
        p.error(str(exc))
    if args.s2_orbit_budget is not None:
        extra["s2_orbit_budget"] = args.s2_orbit_budget
    if args.s2_orbit_budget_factor is not None:
        extra["s2_orbit_budget_factor"] = args.s2_orbit_budget_factor
    try:  # the run's own check, reported before any run starts
        RunConfig(script="stratpix", **extra)
    except NbvInputError as exc:
        p.error(str(exc))

    if args.set is not None and args.objects is not None:
        p.error("--set and --objects exclude each other")
    if args.set is not None:
        # the held-out half first
        args.objects = family_bodies("evaluation") + (family_bodies("tuning") if args.set == "all" else [])
        if args.set == "tuning":
            args.objects = family_bodies("tuning")
    elif args.objects is None:
        args.objects = list(OBJECT_NAMES)
    jobs = []
    noises = {"both": (0.0, args.noise), "off": (0.0,), "only": (args.noise,)}[args.noisy]
    for baseline, length in (("short", args.short), ("long", args.long)):
        if baseline not in args.baselines:
            continue
        for aim in [a for a in ("centre", "edge_midpoints") if a in args.aims]:
            # circpix (the report's circle script) is run with the report's centre aim only
            scripts = [s for s in args.scripts if aim == "centre" or s != "circpix"]
            for noise in noises:
                for obj in args.objects:
                    for script in scripts:
                        jobs.append((obj, script, length, aim, noise, args.seed, baseline, extra))
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(_one, jobs))
    else:
        rows = [_one(j) for j in jobs]
    wall = time.perf_counter() - t0

    head = (
        f"{'object':12s} {'script':8s} {'base':5s} {'aim':6s} {'noise':>5s} {'cover':>6s} {'meas.':>5s} {'any':>6s} "
        f"{'n':>4s} {'path':>7s} {'trans':>5s} {'tr.len':>7s} {'D0':>3s} {'unm':>4s} {'time':>5s}  termination"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['object']:12s} {r['script']:8s} {r['baseline']:5s} {r['aim'][:6]:6s} {r['noise_sigma_cells']:5.2f} "
            f"{r['coverage']:6.3f} {r['measurable_cells']:5d} {r['coverage_any_ray']:6.3f} {r['measurements']:4d} {r['path_length_cells']:7.0f} "
            f"{r['transfers']:5d} {r['transfer_length_cells']:7.0f} {r['d0_count']:3d} {r['unmeasurable_candidates']:4d} "
            f"{r['run_time_s']:5.1f}  {r['termination']}"
        )
    lines.append(f"\n{len(rows)} runs in {wall:.0f} s wall ({args.jobs} processes)\n")
    if args.set is None:
        checks = target_checks(rows)
        lines.append(format_targets(checks))
    else:  # the held-out half first; the tuning half's figures beside them, not the targets
        checks = []
        for half in ("evaluation", "tuning"):
            names = set(family_bodies(half))
            group = [r for r in rows if r["object"] in names]
            if group:
                lines.append(f"targets on the {half} bodies ({'held out' if half == 'evaluation' else 'tuning'}):")
                half_checks = target_checks(group)
                lines.append(format_targets(half_checks))
                checks += [dataclasses.replace(c, name=f"[{half}] {c.name}") for c in half_checks]
    print("\n".join(lines))
    if args.table is not None:
        atomic_write_text(args.table, "\n".join(lines) + "\n", make_parents=True)
    write_json(args.json, {"runs": rows, "targets": targets_json(checks)}, indent=2)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
