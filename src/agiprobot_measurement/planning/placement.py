"""Where the part stands: its placement on the fixture and the check of a placement against the scene.

:func:`fixture_placement` turns a part (its CAD frame, optionally rotated) so that its lowest point sits on the
top face of the scene's fixture and its footprint is centred on the fixture. :func:`check_placement` tests the
placed part against every scene object (table, fixture, pedestal, mirrors, ...) and the robot at its start
state; an overlap raises :class:`PlacementError` naming the object, how deep the part reaches into it (the
shortest axis-aligned shift that frees the part from it) and the lift along world +z that clears every object,
checked with FCL before it is reported.

The part's mesh is in mm in the world frame (as :class:`~agiprobot_measurement.planning.part_loading.LoadedPart`
holds it); scene objects are in metres (the scene file's unit). Offsets in messages are mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import fcl
import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = [
    "FIXTURE_NAME",
    "PLACEMENTS",
    "Overlap",
    "PlacementError",
    "check_placement",
    "clearing_shift_mm",
    "find_overlaps",
    "fixture_placement",
    "scene_object_top_m",
]

#: the scene object a part is put on by ``placement='fixture'``
FIXTURE_NAME = "fixture"
#: ``scene``: at the scene file's part pose times the caller's transform; ``fixture``: on the fixture, centred
PLACEMENTS = ("scene", "fixture")
#: a part resting on a surface touches it; shifts below this (mm) are contact, not overlap
CONTACT_TOLERANCE_MM = 0.05
#: shifts are searched up to this far (mm); beyond it the part is hopelessly inside something
MAX_SHIFT_MM = 5000.0


class PlacementError(InputError):
    """The placed part overlaps a scene object or the robot; the message names it, the depth and a clearing
    offset. ``overlaps`` lists them, ``lift_mm`` is the lift along world +z that clears all (None if none)."""

    def __init__(self, message: str, overlaps: list[Overlap], lift_mm: float | None):
        super().__init__(message)
        self.overlaps = overlaps
        self.lift_mm = lift_mm


@dataclass(frozen=True)
class Overlap:
    """The part overlaps ``name``: ``depth_mm`` is the shortest axis-aligned shift that frees the part from it
    (along ``direction``, world frame), ``lift_mm`` the shift along world +z that does."""

    name: str
    depth_mm: float
    direction: tuple[float, float, float]
    lift_mm: float


def _part_object(mesh_mm) -> fcl.CollisionObject:
    vertices = np.asarray(mesh_mm.vertices, dtype=float) * 1e-3
    model = fcl.BVHModel()
    model.beginModel(len(mesh_mm.faces), len(vertices))
    model.addSubModel(vertices, np.asarray(mesh_mm.faces, dtype=np.int64))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def _scene_object(obstacle) -> fcl.CollisionObject | None:
    """An FCL object of a scene object (metres), None for types the check does not know."""
    if obstacle.type in ("box", "chessboard"):
        size, pose = obstacle.solid_box()
        geometry = fcl.Box(*np.asarray(size, dtype=float))
    elif obstacle.type == "cylinder":
        pose, geometry = obstacle.pose, fcl.Cylinder(float(obstacle.radius_m), float(obstacle.length_m))
    elif obstacle.type == "sphere":
        pose, geometry = obstacle.pose, fcl.Sphere(float(obstacle.radius_m))
    elif obstacle.type == "mesh" and obstacle.mesh is not None:
        import trimesh

        mesh = trimesh.load(str(obstacle.mesh), force="mesh")
        vertices = np.asarray(mesh.vertices, dtype=float) * float(obstacle.mesh_scale)
        geometry = fcl.BVHModel()
        geometry.beginModel(len(mesh.faces), len(vertices))
        geometry.addSubModel(vertices, np.asarray(mesh.faces, dtype=np.int64))
        geometry.endModel()
        pose = obstacle.pose
    else:
        return None
    return fcl.CollisionObject(geometry, fcl.Transform(pose[:3, :3], pose[:3, 3]))


def _collides(part: fcl.CollisionObject, other: fcl.CollisionObject, shift_mm: np.ndarray) -> bool:
    part.setTransform(fcl.Transform(np.eye(3), np.asarray(shift_mm, dtype=float) * 1e-3))
    return fcl.collide(part, other, fcl.CollisionRequest(), fcl.CollisionResult()) > 0


def clearing_shift_mm(
    part: fcl.CollisionObject, others: list[fcl.CollisionObject], direction, resolution_mm: float = 0.1
) -> float:
    """The smallest shift (mm) along the unit ``direction`` after which the part touches none of ``others``
    (searched by doubling, then bisection to ``resolution_mm``; the returned shift is free); inf when none
    within :data:`MAX_SHIFT_MM`."""
    direction = np.asarray(direction, dtype=float)

    def hit(s: float) -> bool:
        return any(_collides(part, other, s * direction) for other in others)

    if not hit(CONTACT_TOLERANCE_MM):
        return 0.0  # free, or only touching
    high = 1.0
    while hit(high):
        high *= 2.0
        if high > MAX_SHIFT_MM:
            return math.inf
    low = high / 2.0 if high > 1.0 else 0.0
    while high - low > resolution_mm:
        middle = 0.5 * (low + high)
        if hit(middle):
            low = middle
        else:
            high = middle
    return high


_AXES = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))


def find_overlaps(mesh_mm, scene, skip: tuple[str, ...] = ()) -> tuple[list[Overlap], float | None]:
    """The scene objects the part (mesh in world mm) overlaps by more than contact, and the lift along world
    +z (mm) that clears all of them together (None when nothing overlaps)."""
    part = _part_object(mesh_mm)
    overlaps = []
    for obstacle in scene.objects:
        if obstacle.name in skip:
            continue
        other = _scene_object(obstacle)
        if other is None or not _collides(part, other, np.zeros(3)):
            continue
        shifts = [clearing_shift_mm(part, [other], axis) for axis in _AXES]
        best = int(np.argmin(shifts))
        lift = shifts[4]
        if shifts[best] <= CONTACT_TOLERANCE_MM:
            continue  # resting on it
        overlaps.append(Overlap(obstacle.name, float(shifts[best]), _AXES[best], float(lift)))
    if not overlaps:
        return [], None
    # the lift must clear the overlapped objects without running into another one
    everything = [obj for obj in (_scene_object(o) for o in scene.objects if o.name not in skip) if obj is not None]
    lift = clearing_shift_mm(part, everything, (0.0, 0.0, 1.0))
    return overlaps, float(lift)


def check_placement(mesh_mm, scene, collision=None, start_state=None, where: str = "part") -> None:
    """Raise :class:`PlacementError` when the placed part (mesh in world mm) overlaps a scene object, or the
    robot at ``start_state`` (rad; with ``collision``, a CollisionChecker that holds the part). Resting on a
    surface (contact within :data:`CONTACT_TOLERANCE_MM`) is fine."""
    overlaps, lift = find_overlaps(mesh_mm, scene)
    robot_hits = []
    if collision is not None and start_state is not None and collision.part_name is not None:
        robot_hits = sorted(
            {link for pair in collision.colliding_pairs(start_state) if collision.part_name in pair for link in pair}
            - {collision.part_name}
        )
    if not overlaps and not robot_hits:
        return
    lines = []
    for overlap in overlaps:
        axis = "xyz"[int(np.argmax(np.abs(overlap.direction)))]
        sign = "+" if max(overlap.direction) > 0 else "-"
        lines.append(
            f"the {where} overlaps scene object '{overlap.name}' by {overlap.depth_mm:.1f} mm (shift along "
            f"{sign}{axis} to clear it; lifting by {overlap.lift_mm:.1f} mm along +z clears it too)"
        )
    if robot_hits:
        lines.append(f"the {where} overlaps the robot at its start state ({', '.join(robot_hits)})")
    if lift is not None and math.isfinite(lift):
        advice = (
            f"offset that clears it: lift the part by {lift:.1f} mm along world +z (add it to the z of the "
            "transform / part pose), or place it on the fixture (--place fixture, placement='fixture')"
        )
    else:
        advice = "no lift along +z clears it: move the part (transform / part pose) or place it on the fixture"
    raise PlacementError("; ".join(lines) + "; " + advice, overlaps, lift)


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
