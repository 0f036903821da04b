"""The check of a part's placement against the scene and the robot (FCL).

:func:`check_placement` tests the placed part against every scene object (table, fixture, pedestal, mirrors, ...)
and the robot at its start state; an overlap raises :class:`PlacementError` naming the object, how deep the part
reaches into it (the shortest axis-aligned shift that frees the part from it) and the lift along world +z that
clears every object, checked with FCL before it is reported. Shapes are built with :mod:`.collision`'s helpers.

The part's mesh is a ``trimesh.Trimesh`` in mm in the world frame (as a loaded part of the planning holds it);
scene objects are in metres (the scene file's unit). Offsets in messages are mm. Where the part is put (the fixture
placement) is :mod:`agiprobot_measurement.station.placement`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import fcl
import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.collision import _bvh, _bvh_pieces, _fcl_transform, _load_mesh

__all__ = ["Overlap", "PlacementError", "check_placement", "clearing_shift_mm", "find_overlaps"]

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


def _part_objects(mesh_mm) -> list[fcl.CollisionObject]:
    vertices_m = np.asarray(mesh_mm.vertices, dtype=float) * 1e-3
    return [fcl.CollisionObject(tree, fcl.Transform()) for tree in _bvh_pieces(vertices_m, np.asarray(mesh_mm.faces))]


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
        mesh = _load_mesh(obstacle.mesh)
        geometry = _bvh(np.asarray(mesh.vertices, dtype=float) * float(obstacle.mesh_scale), mesh.faces)
        pose = obstacle.pose
    else:
        return None
    return fcl.CollisionObject(geometry, _fcl_transform(pose))


def _collides(part: list[fcl.CollisionObject], other: fcl.CollisionObject, shift_mm: np.ndarray) -> bool:
    """Whether the part (its pieces, world m) shifted by ``shift_mm`` touches ``other``."""
    shift = fcl.Transform(np.eye(3), np.asarray(shift_mm, dtype=float) * 1e-3)
    for piece in part:
        piece.setTransform(shift)
    return any(fcl.collide(piece, other, fcl.CollisionRequest(), fcl.CollisionResult()) > 0 for piece in part)


def clearing_shift_mm(
    part: list[fcl.CollisionObject], others: list[fcl.CollisionObject], direction, resolution_mm: float = 0.1
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


def find_overlaps(mesh_mm, scene, skip: tuple[str, ...] = (), part_objects=None) -> tuple[list[Overlap], float | None]:
    """The scene objects the part (mesh in world mm) overlaps by more than contact, and the lift along world
    +z (mm) that clears all of them together (None when nothing overlaps). ``part_objects``: the part's FCL objects
    (world metres, identity pose) when they exist already; they are left shifted."""
    part = list(part_objects) if part_objects is not None else _part_objects(mesh_mm)
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
    robot at ``start_state`` (rad; with ``collision``, a CollisionChecker that holds the part: the same mesh in metres
    at the identity pose, as the planning loads it, whose trees the search then reuses). Resting on a surface
    (contact within :data:`CONTACT_TOLERANCE_MM`) is fine."""
    trees = collision.part_trees() if collision is not None else None
    if trees is not None and np.allclose(trees[1], np.eye(4)):
        # the checker's own trees of the part (the same mesh in metres): shifted by the search, then put back
        try:
            overlaps, lift = find_overlaps(mesh_mm, scene, part_objects=trees[0])
        finally:
            for tree in trees[0]:
                tree.setTransform(fcl.Transform())
    else:
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
