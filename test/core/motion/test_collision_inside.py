"""The batched inside-a-closed-mesh test of the collision checker's candidates: one call for all points gives
what the point-by-point test gives (box first, then the mesh), for posed obstacles with and without a mesh."""

from types import SimpleNamespace

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from agiprobot_measurement.motion.collision_kernels import centres_inside_meshes


def _obstacle(mesh, rng):
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    pose[:3, 3] = rng.normal(0.0, 0.3, size=3)
    lo, hi = mesh.bounds if mesh is not None else (np.full(3, -0.1), np.full(3, 0.1))
    box_center = pose[:3, :3] @ ((lo + hi) / 2) + pose[:3, 3]
    return SimpleNamespace(mesh=mesh, pose=pose, box_center=box_center, box_half=(hi - lo) / 2)


def _one_point(point, obj) -> bool:
    """The definition for one point: inside the oriented box, then inside the mesh (object frame)."""
    if obj.mesh is None:
        return False
    rotation, translation = obj.pose[:3, :3], obj.pose[:3, 3]
    local = rotation.T @ (point - translation)
    if np.any(np.abs(local - rotation.T @ (obj.box_center - translation)) > obj.box_half):
        return False
    return bool(obj.mesh.contains(local[None])[0])


def test_batched_inside_test_equals_the_point_by_point_one():
    rng = np.random.default_rng(3)
    objects = [
        _obstacle(trimesh.creation.icosphere(subdivisions=2, radius=0.2), rng),
        _obstacle(None, rng),
        _obstacle(trimesh.creation.annulus(r_min=0.05, r_max=0.15, height=0.1), rng),
    ]
    which = rng.integers(0, len(objects), size=3000)
    centres = np.stack([objects[o].pose[:3, 3] for o in which]) + rng.normal(0.0, 0.15, size=(len(which), 3))
    batched = centres_inside_meshes(centres, which, objects)
    reference = np.array([_one_point(c, objects[o]) for c, o in zip(centres, which, strict=True)])
    np.testing.assert_array_equal(batched, reference)
    # not vacuous: points inside both meshes and outside them, and none for the object without a mesh
    assert batched[which == 0].any() and batched[which == 2].any() and not batched[which == 1].any()
    assert (~batched[which == 0]).any() and (~batched[which == 2]).any()
