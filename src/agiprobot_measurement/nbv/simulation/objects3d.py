"""Procedural concave test parts for the 3D NBV benchmark.

Each shape is a union / difference of simple solids written as an occupancy test on a regular grid and turned into
a closed triangle mesh by marching cubes (no boolean backend needed), then given in millimetres with its lowest
point at z = 0. The concavities are what makes next-best-view planning hard: a slot, a cup's inside, the gap between
two towers, an inside corner, a torus's hole.

- ``u_channel``: a U profile 150 x 90 x 80 mm (base 15 mm, walls 15 mm) with a 10 mm slot through the base;
- ``cup``: outer radius 55 mm, height 100 mm, wall 8 mm, bottom 10 mm;
- ``two_towers``: two 40 x 40 x 120 mm towers 20 mm apart on a 100 x 60 x 10 mm plate;
- ``l_bracket``: 120 x 80 x 12 mm plate with a 12 mm upright 100 mm high and a 30 mm hole;
- ``torus``: major radius 50 mm, minor radius 18 mm, lying flat.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["SHAPES", "make_shape"]

SHAPES = ("u_channel", "cup", "two_towers", "l_bracket", "torus")


def _box(x, y, z, lo, hi):
    return (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]) & (z >= lo[2]) & (z <= hi[2])


def _occupancy(name: str, x, y, z):
    if name == "u_channel":
        base = _box(x, y, z, (-75, -45, 0), (75, 45, 15))
        walls = _box(x, y, z, (-75, -45, 0), (75, -30, 80)) | _box(x, y, z, (-75, 30, 0), (75, 45, 80))
        slot = _box(x, y, z, (-40, -5, -1), (40, 5, 16))
        return (base | walls) & ~slot
    if name == "cup":
        r = np.hypot(x, y)
        return (r <= 55) & (z >= 0) & (z <= 100) & ~((r < 47) & (z > 10))
    if name == "two_towers":
        plate = _box(x, y, z, (-50, -30, 0), (50, 30, 10))
        left = _box(x, y, z, (-50, -20, 0), (-10, 20, 120))
        right = _box(x, y, z, (10, -20, 0), (50, 20, 120))
        return plate | left | right
    if name == "l_bracket":
        plate = _box(x, y, z, (-60, -40, 0), (60, 40, 12))
        upright = _box(x, y, z, (-60, -40, 0), (-48, 40, 100))
        hole = (np.hypot(x - 15, y) < 15) & (z < 13)
        return (plate | upright) & ~hole
    if name == "torus":
        q = np.hypot(x, y) - 50
        return q * q + (z - 18) ** 2 <= 18**2
    raise InputError(f"unknown shape {name!r}; known: {', '.join(SHAPES)}")


_BOUNDS = {
    "u_channel": ((-80, -50, -5), (80, 50, 85)),
    "cup": ((-60, -60, -5), (60, 60, 105)),
    "two_towers": ((-55, -35, -5), (55, 35, 125)),
    "l_bracket": ((-65, -45, -5), (65, 45, 105)),
    "torus": ((-73, -73, -5), (73, 73, 41)),
}


def make_shape(name: str, voxel_mm: float = 2.0):
    """The shape ``name`` as a closed ``trimesh.Trimesh`` in mm (lowest point at z = 0, centred in x and y)."""
    import trimesh
    from skimage.measure import marching_cubes

    if name not in SHAPES:
        raise InputError(f"unknown shape {name!r}; known: {', '.join(SHAPES)}")
    if not (np.isfinite(voxel_mm) and 0.2 <= voxel_mm <= 10.0):
        raise InputError(f"voxel_mm must be in [0.2, 10], got {voxel_mm}")
    lo, hi = (np.asarray(b, dtype=float) for b in _BOUNDS[name])
    axes = [np.arange(lo[a], hi[a] + voxel_mm, voxel_mm) for a in range(3)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    occupied = _occupancy(name, x, y, z)
    volume = np.pad(occupied.astype(np.float32), 1)
    vertices, faces, _, _ = marching_cubes(volume, 0.5, spacing=(voxel_mm,) * 3)
    vertices = vertices - voxel_mm + lo  # undo the padding
    mesh = trimesh.Trimesh(vertices, faces[:, ::-1], process=True)
    if mesh.volume < 0:
        mesh.invert()
    bounds = mesh.bounds
    mesh.apply_translation([-(bounds[0][0] + bounds[1][0]) / 2, -(bounds[0][1] + bounds[1][1]) / 2, -bounds[0][2]])
    return mesh
