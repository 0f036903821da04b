"""A family of generated parts nobody tuned on: the planner judged on its tail, evaluation half first.

Ten kinds of part made by code (trimesh primitives and manifold3d booleans; fixed seed): trays with pockets of
several depths, plates with pockets and holes, brackets (L angles with holes), housings with a bore and slots,
ribbed panels, thin plates with holes, cylinders with holes, free-form (height-field) surfaces, stepped blocks and
plates with bosses; each at three sizes (about 80, 200 and 400 mm): 30 parts. Each part's dimensions are drawn
from a generator seeded by the family seed and the part's name, so a part does not change when others are added.
The parts are split into a tuning half and an evaluation half (alternating over kind and size, so both halves have
every kind and every size); tune on the first only. The benchmark plans each part in a fresh process (placed on
the fixture, tilt none, IP_basic, 0.03 points/mm^2, 12 orientations: ``benchmarks.planning.parts``' child) and
replays the plan on the simulated scanner, then reports per half the median and the worst of: plan time, peak
memory, verified share of the measurable points, covered share of the executable points, views minus the set
cover's lower bound, and the predicted-vs-measured coverage gap; the evaluation half first.

    python -m benchmarks.planning.part_family                           # both halves, evaluation first
    python -m benchmarks.planning.part_family --half evaluation --json family.json
    python -m benchmarks.planning.part_family --list                    # the parts, their sizes and halves
    python -m benchmarks.planning.part_family --tilt full --time-limit 180 --parts tray_80 bracket_200
    python -m benchmarks.planning.part_family --write DIR               # only write the STL files
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from benchmarks.harness import RESULTS_DIR, ChildFailed, child_command, format_table, run_json, write_json

SEED = 0
SIZES_MM = (80.0, 200.0, 400.0)
HALVES = ("evaluation", "tuning")
#: the whole-plan time limit per part (s): the family's target is every part within it
TIME_LIMIT_S = 60.0


@dataclass(frozen=True)
class FamilyPart:
    """One generated part: ``name`` (kind_size), its kind, its nominal size (mm) and its half."""

    name: str
    kind: str
    size_mm: float
    half: str
    build: Callable[[np.random.Generator, float], trimesh.Trimesh]

    def mesh(self, seed: int = SEED) -> trimesh.Trimesh:
        """The part's mesh (mm, z up, bottom at z = 0), the same for the same seed."""
        digest = hashlib.sha256(f"{seed}:{self.name}".encode()).digest()
        rng = np.random.default_rng(int.from_bytes(digest[:8], "little"))
        mesh = self.build(rng, self.size_mm)
        mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
        return mesh


# ------------------------------------------------------------------------------------------------- primitives
def _box(extents, center) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(center))


def _cylinder(radius, height, center, axis="z") -> trimesh.Trimesh:
    rotate = {"z": np.eye(4), "x": trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]),
              "y": trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])}[axis]  # fmt: skip
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=48, transform=rotate)
    mesh.apply_translation(center)
    return mesh


def _minus(body, *cutters) -> trimesh.Trimesh:
    return trimesh.boolean.difference([body, *cutters], engine="manifold") if cutters else body


def _plus(*bodies) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(bodies), engine="manifold")


def _pockets(rng, length, width, top, count, depth_range, round_share=0.3) -> list:
    """Pockets in a grid over the top face at z = ``top``: rectangular or round, each of its own depth (mm)."""
    cols = int(np.ceil(np.sqrt(count * length / width)))
    rows = int(np.ceil(count / cols))
    cell_x, cell_y = length / cols, width / rows
    cutters = []
    for k in range(count):
        cx = -length / 2 + (k % cols + 0.5) * cell_x
        cy = -width / 2 + (k // cols + 0.5) * cell_y
        depth = rng.uniform(*depth_range)
        sx, sy = cell_x * rng.uniform(0.45, 0.75), cell_y * rng.uniform(0.45, 0.75)
        if rng.random() < round_share:
            cutters.append(_cylinder(0.5 * min(sx, sy), 2 * depth, (cx, cy, top)))
        else:
            cutters.append(_box((sx, sy, 2 * depth), (cx, cy, top)))
    return cutters


# ------------------------------------------------------------------------------------------------------ kinds
def tray(rng, size):
    length, width = size, size * rng.uniform(0.6, 0.9)
    height = np.clip(0.15 * size, 15.0, 60.0)
    body = _box((length, width, height), (0, 0, height / 2))
    pockets = _pockets(rng, 0.85 * length, 0.85 * width, height, int(rng.integers(2, 7)), (0.25 * height, 0.8 * height))
    return _minus(body, *pockets)


def pocket_plate(rng, size):
    length, width = size, size * rng.uniform(0.5, 0.8)
    t = np.clip(0.08 * size, 8.0, 30.0)
    body = _box((length, width, t), (0, 0, t / 2))
    cutters = _pockets(rng, 0.8 * length, 0.8 * width, t, int(rng.integers(3, 9)), (0.2 * t, 0.6 * t), 0.5)
    for _ in range(int(rng.integers(2, 5))):  # through holes near the edges
        x, y = rng.uniform(-0.45, 0.45) * length, rng.choice([-1, 1]) * 0.44 * width
        cutters.append(_cylinder(rng.uniform(0.015, 0.03) * size, 3 * t, (x, y, t / 2)))
    return _minus(body, *cutters)


def bracket(rng, size):
    t = np.clip(0.06 * size, 5.0, 20.0)
    depth = size * rng.uniform(0.3, 0.5)
    rise = size * rng.uniform(0.35, 0.6)
    base = _box((size, depth, t), (0, 0, t / 2))
    wall = _box((size, t, rise), (0, -depth / 2 + t / 2, rise / 2))
    holes = [_cylinder(0.04 * size, 3 * t, (x, 0.1 * depth, t / 2)) for x in (-0.3 * size, 0.3 * size)]
    holes += [
        _cylinder(0.04 * size, 3 * t, (x, -depth / 2 + t / 2, 0.6 * rise), axis="y")
        for x in (-0.25 * size, 0.25 * size)
    ]
    return _minus(_plus(base, wall), *holes)


def housing(rng, size):
    length, width, height = size, size * rng.uniform(0.5, 0.8), size * rng.uniform(0.3, 0.5)
    t = np.clip(0.05 * size, 4.0, 15.0)
    body = _box((length, width, height), (0, 0, height / 2))
    cavity = _box((length - 2 * t, width - 2 * t, height - t), (0, 0, (height - t) / 2 - 1e-3))  # open at the bottom
    bore = _cylinder(rng.uniform(0.12, 0.2) * min(width, height), 2 * length, (0, 0, 0.55 * height), axis="x")
    slots = [
        _box((0.5 * length, rng.uniform(0.03, 0.06) * width, 3 * t), (0, y, height))
        for y in (-0.25 * width, 0.25 * width)
    ]
    return _minus(body, cavity, bore, *slots)


def ribbed_panel(rng, size):
    length, width = size, size * rng.uniform(0.5, 0.8)
    t = np.clip(0.04 * size, 4.0, 15.0)
    ribs = int(rng.integers(3, 7))
    rib_t, rib_h = max(0.4 * t, 2.5), size * rng.uniform(0.06, 0.12)
    parts = [_box((length, width, t), (0, 0, t / 2))]
    for x in np.linspace(-0.4 * length, 0.4 * length, ribs):
        parts.append(_box((rib_t, 0.9 * width, rib_h), (x, 0, t + rib_h / 2 - 1e-3)))
    return _plus(*parts)


def thin_plate(rng, size):
    length, width, t = size, size * rng.uniform(0.4, 0.7), float(rng.uniform(2.0, 4.0))
    body = _box((length, width, t), (0, 0, t / 2))
    holes = []
    for _ in range(int(rng.integers(3, 8))):
        x, y = rng.uniform(-0.4, 0.4) * length, rng.uniform(-0.35, 0.35) * width
        holes.append(_cylinder(rng.uniform(0.02, 0.05) * size, 4 * t, (x, y, t / 2)))
    return _minus(body, *holes)


def cylinder_holes(rng, size):
    radius, height = 0.3 * size, size * rng.uniform(0.3, 0.6)
    body = _cylinder(radius, height, (0, 0, height / 2))
    bore = _cylinder(radius * rng.uniform(0.25, 0.45), 3 * height, (0, 0, height / 2))
    holes = []
    for angle in np.linspace(0, np.pi, int(rng.integers(1, 4)), endpoint=False):
        hole = _cylinder(0.08 * radius, 3 * radius, (0, 0, 0), axis="x")
        hole.apply_transform(trimesh.transformations.rotation_matrix(angle, [0, 0, 1]))
        hole.apply_translation((0, 0, height * rng.uniform(0.35, 0.65)))
        holes.append(hole)
    return _minus(body, bore, *holes)


def freeform(rng, size):
    """A height field z = base + bumps (a few Gaussians and a wave) over size x 0.8 size, closed below."""
    length, width = size, 0.8 * size
    n = 41
    x, y = np.meshgrid(np.linspace(-length / 2, length / 2, n), np.linspace(-width / 2, width / 2, n), indexing="ij")
    z = np.full_like(x, 0.1 * size)
    for _ in range(int(rng.integers(2, 5))):
        cx, cy = rng.uniform(-0.35, 0.35) * length, rng.uniform(-0.35, 0.35) * width
        z += (
            rng.uniform(-0.05, 0.12)
            * size
            * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * (rng.uniform(0.1, 0.25) * size) ** 2))
        )
    z += 0.02 * size * np.sin(2 * np.pi * x / (rng.uniform(0.4, 0.8) * size))
    z = np.maximum(z, 0.03 * size)
    return _height_field(x, y, z)


def _height_field(x, y, z) -> trimesh.Trimesh:
    """A closed solid: the surface z(x, y) on top of a grid, flat bottom at z = 0, vertical sides."""
    n, m = x.shape
    top = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    bottom = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    vertices = np.vstack([top, bottom])
    index = np.arange(n * m).reshape(n, m)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = [np.column_stack([a, b, c]), np.column_stack([a, c, d])]
    off = n * m
    faces += [np.column_stack([a + off, c + off, b + off]), np.column_stack([a + off, d + off, c + off])]
    for ring in (index[:, 0], index[-1, :], index[::-1, -1], index[0, ::-1]):
        p, q = ring[:-1], ring[1:]
        faces += [np.column_stack([p, p + off, q]), np.column_stack([q, p + off, q + off])]
    mesh = trimesh.Trimesh(vertices, np.vstack(faces), process=True)
    mesh.fix_normals()
    return mesh


def stepped_block(rng, size):
    width = size * rng.uniform(0.4, 0.7)
    steps = int(rng.integers(2, 5))
    heights = np.sort(rng.uniform(0.1, 0.5, steps))[::-1] * size
    edges = np.linspace(-size / 2, size / 2, steps + 1)
    blocks = [_box((edges[k + 1] - edges[k] + (1e-3 if k < steps - 1 else 0.0), width, h),
                   ((edges[k] + edges[k + 1]) / 2, 0, h / 2)) for k, h in enumerate(heights)]  # fmt: skip
    return _plus(*blocks)


def boss_plate(rng, size):
    length, width = size, size * rng.uniform(0.5, 0.8)
    t = np.clip(0.05 * size, 5.0, 20.0)
    parts = [_box((length, width, t), (0, 0, t / 2))]
    for _ in range(int(rng.integers(2, 6))):
        r, h = rng.uniform(0.04, 0.09) * size, rng.uniform(0.08, 0.2) * size
        x, y = rng.uniform(-0.4, 0.4) * length, rng.uniform(-0.3, 0.3) * width
        parts.append(_cylinder(r, h, (x, y, t + h / 2 - 1e-3)))
    return _plus(*parts)


KINDS = {
    "tray": tray, "pocket_plate": pocket_plate, "bracket": bracket, "housing": housing,
    "ribbed_panel": ribbed_panel, "thin_plate": thin_plate, "cylinder_holes": cylinder_holes,
    "freeform": freeform, "stepped_block": stepped_block, "boss_plate": boss_plate,
}  # fmt: skip


def family() -> list[FamilyPart]:
    """Every part: each kind at each size; halves alternate over (kind, size) so both have every kind and size."""
    parts = []
    for k, (kind, build) in enumerate(KINDS.items()):
        for s, size in enumerate(SIZES_MM):
            half = HALVES[(k + s) % 2]
            parts.append(FamilyPart(f"{kind}_{size:.0f}", kind, size, half, build))
    return parts


def write_parts(folder: Path, parts=None, seed: int = SEED) -> dict[str, Path]:
    """The parts' STL files (mm) in ``folder`` (written when missing or when their content changed)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for part in parts or family():
        path = folder / f"{part.name}.stl"
        data = part.mesh(seed).export(file_type="stl")
        if not path.exists() or path.read_bytes() != data:
            path.write_bytes(data)
        paths[part.name] = path
    return paths


# -------------------------------------------------------------------------------------------------- reporting
def summary_rows(results: list[dict]) -> list[list[str]]:
    """Median and worst per figure over one half's results (a part that failed counts in the failures only)."""
    planned = [r for r in results if "error" not in r]

    def figure(name, values, worst, fmt):
        if not values:
            return [name, "-", "-"]
        return [name, fmt(statistics.median(values)), fmt(worst(values))]

    times = [r["time_s"]["total"] for r in planned]
    return [
        ["parts", str(len(results)), f"{len(results) - len(planned)} failed"],
        figure("plan time s", times, max, lambda v: f"{v:.1f}"),
        figure("peak memory MB", [r["peak_mb"] for r in planned], max, lambda v: f"{v:.0f}"),
        figure("verified share %", [100 * r["verified_share"] for r in planned], min, lambda v: f"{v:.1f}"),
        figure("covered of executable %", [100 * r["covered_of_executable"] for r in planned], min, lambda v: f"{v:.1f}"),
        figure("views - lower bound", [r["views"] - r["views_lower_bound"] for r in planned if r.get("views_lower_bound") is not None],
               max, lambda v: f"{v:.0f}"),
        figure("|predicted - measured| points", [abs(r["predicted_minus_measured_points"]) for r in planned], max,
               lambda v: f"{v:.1f}"),
        figure("candidates evaluated %", [100 * r.get("candidates_evaluated_share", 1.0) for r in planned], min,
               lambda v: f"{v:.0f}"),
        ["time limit hit", str(sum(bool(r.get("time_limit_hit")) for r in planned)), ""],
        ["views dropped", str(sum(int(r.get("dropped_views", 0)) for r in planned)), ""],
    ]  # fmt: skip


def part_row(r: dict) -> list[str]:
    if "error" in r:
        return [r["part"], "FAILED", r["error"][:100]] + [""] * 8
    bound = r.get("views_lower_bound")
    return [
        r["part"], f"{r['samples']}", f"{r['time_s']['total']:.1f}", f"{r['peak_mb']:.0f}",
        f"{100 * r['verified_share']:.1f}", f"{100 * r['covered_of_executable']:.1f}",
        f"{r['views']} / {'-' if bound is None else int(np.ceil(bound - 1e-6))}",
        f"{r['predicted_minus_measured_points']:+.1f}", "yes" if r.get("time_limit_hit") else "",
        f"{100 * r.get('candidates_evaluated_share', 1.0):.0f}", str(r.get("dropped_views", 0)),
    ]  # fmt: skip


PART_HEADER = ["part", "samples", "time s", "MB", "verified %", "cov/exec %", "views / bound", "pred-msd",
               "time limit", "evaluated %", "dropped"]  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--half", choices=("both", *HALVES), default="both")
    parser.add_argument("--parts", nargs="*", help="part names to run (default: the half's)")
    parser.add_argument("--time-limit", type=float, default=TIME_LIMIT_S, help="whole-plan time limit per part (s)")
    parser.add_argument(
        "--tilt",
        default="none",
        choices=("none", "limited", "full", "auto"),
        help="tilt mode (the family's targets: none within --time-limit 60, full within 180)",
    )
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--dir", type=Path, default=RESULTS_DIR / "part_family", help="where the STL files go")
    parser.add_argument("--list", action="store_true", help="list the parts and exit")
    parser.add_argument("--write", type=Path, help="write the STL files here and exit")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    parts = family()
    if args.list:
        rows = []
        for p in parts:
            extents = p.mesh(args.seed).extents
            rows.append([p.name, p.kind, f"{p.size_mm:.0f}", p.half, " x ".join(f"{e:.0f}" for e in extents)])
        print(format_table(["part", "kind", "size mm", "half", "extents mm"], rows))
        return 0
    if args.write:
        write_parts(args.write, parts, args.seed)
        return 0
    halves = HALVES if args.half == "both" else (args.half,)
    selected = [p for p in parts if p.half in halves and (not args.parts or p.name in args.parts)]
    paths = write_parts(args.dir, selected, args.seed)
    results = {half: [] for half in halves}
    for half in halves:  # the evaluation half first
        print(f"{half} half (tilt {args.tilt}, IP_basic, time limit {args.time_limit:g} s per part):", flush=True)
        for part in [p for p in selected if p.half == half]:
            command = child_command("benchmarks.planning.parts", "--one", paths[part.name], "mm", "--time-limit",
                                    args.time_limit, "--seed", args.seed, "--tilt", args.tilt)  # fmt: skip
            try:
                result = run_json(command)
            except ChildFailed as exc:
                result = {"part": f"{part.name}.stl", "error": f"crashed: {exc}"}
            result["part"] = part.name
            results[half].append(result)
            print(format_table(PART_HEADER, [part_row(result)]).splitlines()[-1], flush=True)
    for half in halves:
        print(f"\n{half} half: median and worst")
        print(format_table(["figure", "median", "worst"], summary_rows(results[half])))
    if args.json:
        meta = {"seed": args.seed, "time_limit_s": args.time_limit, "tilt": args.tilt}
        write_json(args.json, {**meta, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
