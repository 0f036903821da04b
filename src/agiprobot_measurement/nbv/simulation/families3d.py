"""Generated 3D parts to generalise over: six families at random parameters, fixed seeds, a tuning and a held-out
evaluation half.

Each part is an occupancy test on a regular grid turned into a closed mesh by marching cubes (as :mod:`.objects3d`,
no boolean backend needed), in millimetres, lowest point at z = 0, centred in x and y, its largest extent drawn
uniformly from 80-250 mm. The families:

===========  ========================================================================================================
``shape``    the procedural shapes of :mod:`.objects3d` (U channel, cup, towers, L bracket, torus) at random
             proportions
``boolean``  a block or cylinder minus 1-3 pockets and 1-3 bores (blind or through), plus an overhanging ledge
``plate``    a thin flat plate 3-6 mm thick, rectangular or round, sometimes with holes (the part that made the
             frontier rule quit early)
``blob``     a free-form body: the 0.5 level set of a sum of 3-6 Gaussian kernels
``mech``     mechanical parts: a flange with bolt holes and a boss, a stepped shaft lying down, a gear-like star
             extrusion with a bore, an angle bracket with ribs
===========  ========================================================================================================

Names are ``<family>_<k>``, k = 0..7 (40 parts); the parameters of a name come from ``numpy.random.default_rng((SEED,
family, k))``. Even k is the tuning half, odd k the evaluation half (every family in both halves).
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["FAMILIES", "FAMILY_SETS", "SEED", "family_parts", "is_family_part", "make_family_part"]

#: the generator's seed: changing it changes every part (and invalidates every figure measured on the family)
SEED = 20261207
FAMILIES = ("shape", "boolean", "plate", "blob", "mech")
PER_FAMILY = 8
FAMILY_SETS = ("tuning", "evaluation", "all")
EXTENT_MM = (80.0, 250.0)


def family_parts(which: str = "evaluation") -> list[str]:
    """The names of one half (``tuning``: even k, ``evaluation``: odd k) or ``all``."""
    if which not in FAMILY_SETS:
        raise InputError(f"unknown part set {which!r}; one of {', '.join(FAMILY_SETS)}")
    keep = {"tuning": (0,), "evaluation": (1,), "all": (0, 1)}[which]
    return [f"{f}_{k}" for f in FAMILIES for k in range(PER_FAMILY) if k % 2 in keep]


def is_family_part(name) -> bool:
    if not isinstance(name, str):
        return False
    family, _, index = name.rpartition("_")
    return family in FAMILIES and index.isdigit() and int(index) < PER_FAMILY


def _box(x, y, z, lo, hi):
    return (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]) & (z >= lo[2]) & (z <= hi[2])


# Each maker returns (occupancy function of (x, y, z) in mm, bounds lo, hi in mm, voxel mm); the part is scaled to its
# drawn extent afterwards, so the makers work at a nominal size of about 150 mm.


def _shape(rng):
    kind = int(rng.integers(5))
    if kind == 0:  # U channel
        w, d, h = rng.uniform(120, 170), rng.uniform(60, 110), rng.uniform(50, 100)
        t, slot = rng.uniform(8, 18), rng.uniform(6, 14)

        def occ(x, y, z):
            base = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, d / 2, t))
            walls = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, -d / 2 + t, h)) | _box(
                x, y, z, (-w / 2, d / 2 - t, 0), (w / 2, d / 2, h)
            )
            return (base | walls) & ~_box(x, y, z, (-w / 4, -slot / 2, -1), (w / 4, slot / 2, t + 1))

        return occ, (-w / 2 - 5, -d / 2 - 5, -5), (w / 2 + 5, d / 2 + 5, h + 5), 2.0
    if kind == 1:  # cup
        r, h, wall = rng.uniform(35, 70), rng.uniform(60, 130), rng.uniform(5, 12)

        def occ(x, y, z):
            q = np.hypot(x, y)
            return (q <= r) & (z >= 0) & (z <= h) & ~((q < r - wall) & (z > wall))

        return occ, (-r - 5, -r - 5, -5), (r + 5, r + 5, h + 5), 2.0
    if kind == 2:  # towers
        n = int(rng.integers(2, 4))
        side, gap, h = rng.uniform(25, 45), rng.uniform(12, 30), rng.uniform(70, 140)
        span = n * side + (n - 1) * gap

        def occ(x, y, z):
            out = _box(x, y, z, (-span / 2 - 5, -side / 2 - 10, 0), (span / 2 + 5, side / 2 + 10, 10))
            for i in range(n):
                x0 = -span / 2 + i * (side + gap)
                out |= _box(x, y, z, (x0, -side / 2, 0), (x0 + side, side / 2, h * (0.6 + 0.4 * (i % 2))))
            return out

        return occ, (-span / 2 - 10, -side / 2 - 15, -5), (span / 2 + 10, side / 2 + 15, h + 5), 2.0
    if kind == 3:  # L bracket with a hole
        w, d, t, h, hole = (rng.uniform(90, 150), rng.uniform(60, 100), rng.uniform(8, 16), rng.uniform(60, 120),
                            rng.uniform(10, 20))  # fmt: skip

        def occ(x, y, z):
            plate = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, d / 2, t))
            upright = _box(x, y, z, (-w / 2, -d / 2, 0), (-w / 2 + t, d / 2, h))
            return (plate | upright) & ~((np.hypot(x - w / 8, y) < hole) & (z < t + 1))

        return occ, (-w / 2 - 5, -d / 2 - 5, -5), (w / 2 + 5, d / 2 + 5, h + 5), 2.0
    big, small = rng.uniform(35, 60), rng.uniform(10, 22)  # torus

    def occ(x, y, z):
        q = np.hypot(x, y) - big
        return q * q + (z - small) ** 2 <= small**2

    e = big + small + 5
    return occ, (-e, -e, -5), (e, e, 2 * small + 5), 2.0


def _boolean(rng):
    w, d, h = rng.uniform(90, 150), rng.uniform(60, 130), rng.uniform(40, 90)
    round_base = rng.random() < 0.3
    pockets = [
        (
            rng.uniform(-w / 3, w / 3),
            rng.uniform(-d / 3, d / 3),
            rng.uniform(15, 40),
            rng.uniform(15, 40),
            rng.uniform(0.3, 0.8) * h,
        )
        for _ in range(int(rng.integers(1, 4)))
    ]
    bores = [
        (
            rng.uniform(-w / 3, w / 3),
            rng.uniform(-d / 3, d / 3),
            rng.uniform(4, 12),
            rng.random() < 0.5,
            int(rng.integers(3)),
        )
        for _ in range(int(rng.integers(1, 4)))
    ]
    ledge = rng.uniform(20, 45), rng.uniform(8, 15)  # overhang length, thickness

    def occ(x, y, z):
        if round_base:
            body = (np.hypot(x / (w / 2), y / (d / 2)) <= 1) & (z >= 0) & (z <= h)
        else:
            body = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, d / 2, h))
        for px, py, sx, sy, depth in pockets:
            body &= ~_box(x, y, z, (px - sx / 2, py - sy / 2, h - depth), (px + sx / 2, py + sy / 2, h + 1))
        for bx, by, r, through, axis in bores:
            if axis == 0:  # vertical
                body &= ~((np.hypot(x - bx, y - by) < r) & (z > (-1 if through else h / 2)))
            elif axis == 1:  # along x, from the side
                body &= ~((np.hypot(y - by, z - h / 2) < r) & (x > (-w if through else w / 4)))
            else:  # along y
                body &= ~((np.hypot(x - bx, z - h / 2) < r) & (y > (-d if through else d / 4)))
        # an overhanging ledge at the top of one side: a surface seen only from below
        body |= _box(x, y, z, (w / 2 - 1, -d / 4, h - ledge[1]), (w / 2 + ledge[0], d / 4, h))
        return body

    return occ, (-w / 2 - 5, -d / 2 - 5, -5), (w / 2 + ledge[0] + 5, d / 2 + 5, h + 5), 2.0


def _plate(rng):
    w, d, t = rng.uniform(110, 160), rng.uniform(60, 150), rng.uniform(3.0, 6.0)
    round_plate = rng.random() < 0.3
    holes = [(rng.uniform(-w / 3, w / 3), rng.uniform(-d / 3, d / 3), rng.uniform(4, 12))
             for _ in range(int(rng.integers(0, 4)))]  # fmt: skip

    def occ(x, y, z):
        if round_plate:
            body = (np.hypot(x / (w / 2), y / (d / 2)) <= 1) & (z >= 0) & (z <= t)
        else:
            body = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, d / 2, t))
        for hx, hy, r in holes:
            body &= ~(np.hypot(x - hx, y - hy) < r)
        return body

    voxel = min(2.0, t / 3.0)
    return occ, (-w / 2 - 3, -d / 2 - 3, -2), (w / 2 + 3, d / 2 + 3, t + 2), voxel


def _blob(rng):
    k = int(rng.integers(3, 7))
    centres = rng.uniform([-45, -45, 25], [45, 45, 75], (k, 3))
    sig = rng.uniform(18, 32, k)

    def occ(x, y, z):
        f = np.zeros(x.shape)
        for c, s in zip(centres, sig, strict=True):
            f += np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / (2 * s * s))
        return (f > 0.5) & (z >= 0)

    return occ, (-110, -110, -5), (110, 110, 140), 2.5


def _mech(rng):
    kind = int(rng.integers(4))
    if kind == 0:  # flange: disc, boss, bore, bolt circle
        r, t = rng.uniform(55, 75), rng.uniform(8, 16)
        boss_r, boss_h, bore = rng.uniform(18, 30), rng.uniform(25, 60), rng.uniform(6, 14)
        n_bolts, bolt_r = int(rng.integers(4, 9)), rng.uniform(3, 6)
        bolt_c = (r + boss_r) / 2
        bolts = [(bolt_c * math.cos(a), bolt_c * math.sin(a)) for a in np.arange(n_bolts) * 2 * math.pi / n_bolts]

        def occ(x, y, z):
            q = np.hypot(x, y)
            body = ((q <= r) & (z >= 0) & (z <= t)) | ((q <= boss_r) & (z >= 0) & (z <= t + boss_h))
            body &= ~(q < bore)
            for bx, by in bolts:
                body &= ~(np.hypot(x - bx, y - by) < bolt_r)
            return body

        return occ, (-r - 5, -r - 5, -5), (r + 5, r + 5, t + boss_h + 5), 2.0
    if kind == 1:  # stepped shaft lying along x, on a small cradle
        steps = int(rng.integers(2, 5))
        lengths = rng.uniform(25, 55, steps)
        radii = np.sort(rng.uniform(10, 30, steps))[::-1]
        total = float(lengths.sum())
        rmax = float(radii[0])

        def occ(x, y, z):
            body = np.zeros(x.shape, bool)
            x0 = -total / 2
            for length, r in zip(lengths, radii, strict=True):
                body |= (x >= x0) & (x <= x0 + length) & (np.hypot(y, z - rmax) <= r)
                x0 += length
            return body & (z >= 0)

        return occ, (-total / 2 - 5, -rmax - 5, -5), (total / 2 + 5, rmax + 5, 2 * rmax + 5), 2.0
    if kind == 2:  # gear-like star extrusion with a bore
        teeth, r_out, h = int(rng.integers(6, 13)), rng.uniform(50, 75), rng.uniform(15, 45)
        depth, bore = rng.uniform(6, 14), rng.uniform(8, 20)

        def occ(x, y, z):
            a = np.arctan2(y, x)
            edge = r_out - depth * (0.5 + 0.5 * np.sign(np.sin(teeth * a)))
            q = np.hypot(x, y)
            return (q <= edge) & (q >= bore) & (z >= 0) & (z <= h)

        return occ, (-r_out - 5, -r_out - 5, -5), (r_out + 5, r_out + 5, h + 5), 2.0
    w, d, t, h = rng.uniform(80, 140), rng.uniform(50, 90), rng.uniform(6, 12), rng.uniform(50, 110)  # ribbed angle
    ribs = int(rng.integers(1, 4))

    def occ(x, y, z):
        base = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, d / 2, t))
        wall = _box(x, y, z, (-w / 2, -d / 2, 0), (w / 2, -d / 2 + t, h))
        body = base | wall
        for i in range(ribs):
            rx = -w / 2 + (i + 1) * w / (ribs + 1)
            along = y + d / 2 - t  # distance in front of the wall
            body |= (np.abs(x - rx) <= t / 2) & (along >= 0) & (z >= 0) & (z <= h - along * h / (d - t))
        return body

    return occ, (-w / 2 - 5, -d / 2 - 5, -5), (w / 2 + 5, d / 2 + 5, h + 5), 2.0


_MAKERS = {"shape": _shape, "boolean": _boolean, "plate": _plate, "blob": _blob, "mech": _mech}


def make_family_part(name: str):
    """The generated part ``name`` as a closed ``trimesh.Trimesh`` in mm (largest extent in 80-250 mm, lowest point
    at z = 0, centred in x and y)."""
    import trimesh
    from skimage.measure import marching_cubes

    if not is_family_part(name):
        raise InputError(f"unknown generated part {name!r}; one of {', '.join(family_parts('all'))}")
    family, _, index = name.rpartition("_")
    rng = np.random.default_rng((SEED, FAMILIES.index(family), int(index)))
    occ, lo, hi, voxel = _MAKERS[family](rng)
    extent_mm = rng.uniform(*EXTENT_MM)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    # a thin plate keeps its thickness: it is scaled in x and y only (the thickness is what makes it hard)
    axes = [np.arange(lo[a], hi[a] + voxel, voxel) for a in range(3)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    volume = np.pad(occ(x, y, z).astype(np.float32), 1)
    if volume.max() < 0.5:
        raise InputError(f"generated part {name}: empty occupancy")
    vertices, faces, _, _ = marching_cubes(volume, 0.5, spacing=(voxel,) * 3)
    mesh = trimesh.Trimesh(vertices - voxel + lo, faces[:, ::-1], process=True)
    if mesh.volume < 0:
        mesh.invert()
    if family == "plate":
        scale = extent_mm / float(max(mesh.extents[:2]))
        mesh.apply_transform(np.diag([scale, scale, 1.0, 1.0]))
    else:
        mesh.apply_scale(extent_mm / float(mesh.extents.max()))
    b = mesh.bounds
    mesh.apply_translation([-(b[0][0] + b[1][0]) / 2, -(b[0][1] + b[1][1]) / 2, -b[0][2]])
    return mesh
