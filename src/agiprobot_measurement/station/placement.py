"""Where the part stands on the station: the fixture placement (pure geometry over the scene).

:func:`fixture_placement` turns a part (its CAD frame, optionally rotated) so that its lowest point sits on the
top face of the scene's fixture and its footprint is centred on the fixture; :func:`scene_object_top_m` gives a
box-shaped scene object's top and footprint centre. Part vertices are mm, scene objects metres (the scene file's
unit). The check of a placement against the scene (FCL) is :mod:`agiprobot_measurement.motion.placement_check`.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["FIXTURE_NAME", "PLACEMENTS", "fixture_placement", "scene_object_top_m"]

#: the scene object a part is put on by ``placement='fixture'``
FIXTURE_NAME = "fixture"
#: ``scene``: at the scene file's part pose times the caller's transform; ``fixture``: on the fixture, centred
PLACEMENTS = ("scene", "fixture")


def scene_object_top_m(obstacle) -> tuple[float, np.ndarray]:
    """World z (m) of a box-shaped scene object's top and the (x, y) centre (m) of its footprint."""
    size, pose = obstacle.solid_box()
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = (signs * (np.asarray(size) / 2.0)) @ pose[:3, :3].T + pose[:3, 3]
    return float(corners[:, 2].max()), 0.5 * (corners[:, :2].min(axis=0) + corners[:, :2].max(axis=0))


def fixture_placement(vertices_mm: np.ndarray, rotation: np.ndarray, scene, fixture: str = FIXTURE_NAME) -> np.ndarray:
    """The 4x4 world placement (translation mm) of a part with CAD-frame vertices ``vertices_mm`` (already in
    mm) turned by ``rotation`` (3x3, world frame): its lowest point on the top of scene object ``fixture`` and
    the centre of its bounding box over the fixture's centre. Raises InputError without such a box."""
    found = [o for o in scene.objects if o.name == fixture]
    if not found or found[0].type not in ("box", "chessboard"):
        names = ", ".join(o.name for o in scene.objects) or "none"
        raise InputError(f"placement 'fixture' needs a box scene object named '{fixture}'; the scene has: {names}")
    top_m, centre_m = scene_object_top_m(found[0])
    rotated = np.asarray(vertices_mm, dtype=float) @ np.asarray(rotation, dtype=float).T
    lo, hi = rotated.min(axis=0), rotated.max(axis=0)
    placement = np.eye(4)
    placement[:3, :3] = rotation
    placement[:2, 3] = centre_m * 1000.0 - 0.5 * (lo[:2] + hi[:2])
    placement[2, 3] = top_m * 1000.0 - lo[2]
    return placement
