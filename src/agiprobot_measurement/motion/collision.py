"""Collision checking of the station's robot against itself, the scene and the part, with python-fcl.

Robot geometry is the URDF's collision elements (boxes, cylinders, spheres), inflated by a padding and posed by
forward kinematics of the :class:`~agiprobot_measurement.motion.kinematics.KinematicModel`. The world is the scene's
obstacles (boxes, cylinders, spheres, meshes) and the part to measure (a BVH mesh that can be replaced at run
time). Which pairs are checked is decided by an allowed-collision matrix read from ``config/collision.yaml``
(regenerate it with ``tools/generate_collision_matrix.py``).

Units: metres, radians; poses are 4x4 homogeneous matrices in the planning frame (``world``).

Speed: a batch of states is posed with one vectorised FK, and a numpy broad phase leaves only the few near pairs
to FCL's narrow phase: robot shapes against obstacles by bounding spheres against the obstacles' oriented boxes,
then separating axes with the shapes' exact support; robot shapes against each other by bounding spheres, then
capsule (segment) distances. That makes tens of thousands of full-robot checks per second possible in Python
(prefer :meth:`CollisionChecker.check_states` over many single calls); FCL's own broad-phase managers would call
back into Python for every candidate pair. A checker is not thread-safe (it moves its FCL objects).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import fcl
import numpy as np

from agiprobot_measurement.motion.collision_config import (
    ALLOWED_REASONS,
    AllowedEntry,
    CollisionConfig,
    load_collision_config,
)
from agiprobot_measurement.motion.collision_kernels import (
    centres_inside_meshes,
    second_stage,
    sphere_candidates,
    sphere_candidates_numpy,
)
from agiprobot_measurement.motion.collision_kernels import segment_distances as _segment_distances
from agiprobot_measurement.motion.errors import MotionInputError, UnknownObjectError
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.kinematics_kernels import COMPILED_FROM_STATES, attached_frames, chain_frames
from agiprobot_measurement.station import (
    ConfigError,
    PartPlacement,
    Scene,
    SceneObject,
    Station,
)

__all__ = [
    "Clearance",
    "CollisionChecker",
    "adjacent_link_pairs",
]

_CHUNK = 4096  # states posed at once: bounds the broad phase's temporary arrays to a few tens of MB
#: faces per bounding-volume tree of a mesh obstacle: FCL builds a tree in one native call that holds the
#: interpreter (about 3 us per face), so a finely meshed part is built as several spatially compact trees, and a
#: time limit waiting on the build (``StageClock.call``) gets its turn between them (about 0.2 s)
BVH_PIECE_FACES = 65_536


# --------------------------------------------------------------------------------------------- geometry
def _fcl_transform(pose: np.ndarray) -> fcl.Transform:
    return fcl.Transform(pose[:3, :3], pose[:3, 3])


def _bvh(vertices: np.ndarray, faces: np.ndarray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(faces), len(vertices))
    model.addSubModel(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64))
    model.endModel()
    return model


def _bvh_pieces(vertices: np.ndarray, faces: np.ndarray) -> list[fcl.BVHModel]:
    """The mesh as trees of at most :data:`BVH_PIECE_FACES` faces each, the faces grouped along a Morton curve
    of their centroids so that each piece is spatially compact (its root volume small)."""
    if len(faces) <= BVH_PIECE_FACES:
        return [_bvh(vertices, faces)]
    centroids = vertices[faces].mean(axis=1)
    lo = centroids.min(axis=0)
    span = np.maximum(centroids.max(axis=0) - lo, 1e-12)
    cells = np.minimum((centroids - lo) / span * 1024, 1023).astype(np.uint64)
    code = np.zeros(len(faces), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    order = np.argsort(code, kind="stable")
    pieces = []
    for start in range(0, len(order), BVH_PIECE_FACES):
        used, local = np.unique(faces[order[start : start + BVH_PIECE_FACES]], return_inverse=True)
        pieces.append(_bvh(vertices[used], local.reshape(-1, 3)))
    return pieces


@dataclass
class _Padded:
    """One robot shape inflated by one padding, with its bounding capsule (segment along ``axis``)."""

    obj: fcl.CollisionObject
    half_length: float  # m, half the capsule's segment
    radius: float  # m, capsule radius (padding included)
    # exact support (extent along a unit direction n, m): sum_k |n.u_k| extents_k + disc * sin(n, axis) + ball
    extents: np.ndarray  # half extents along the shape frame's axes (box; cylinder: 0, 0, half length)
    disc: float = 0.0  # cylinder radius
    ball: float = 0.0  # sphere radius


def _padded(geometry, pad: float) -> tuple[_Padded, int]:
    if geometry.type == "box":
        size = np.asarray(geometry.size, dtype=float) + 2.0 * pad
        axis = int(np.argmax(size))
        others = np.delete(size, axis) / 2.0
        capsule_radius = float(np.hypot(*others))
        return _Padded(fcl.CollisionObject(fcl.Box(*size)), size[axis] / 2.0, capsule_radius, size / 2.0), axis
    if geometry.type == "cylinder":
        radius, length = geometry.radius + pad, geometry.length + 2.0 * pad
        extents = np.array([0.0, 0.0, length / 2.0])
        return _Padded(fcl.CollisionObject(fcl.Cylinder(radius, length)), length / 2.0, radius, extents, disc=radius), 2
    if geometry.type == "sphere":
        radius = geometry.radius + pad
        return _Padded(fcl.CollisionObject(fcl.Sphere(radius)), 0.0, radius, np.zeros(3), ball=radius), 2
    raise ConfigError(
        f"link '{geometry.link}': collision geometry '{geometry.type}' is not supported (use box, cylinder, sphere)"
    )


@dataclass
class _RobotShape:
    link: str
    element: int  # index among the link's collision elements (URDF order)
    kind: str
    offset: np.ndarray  # moving frame -> shape frame (4x4)
    anchor: int  # index of the moving frame (-1: fixed to the world)
    axis: int  # shape-frame axis of the bounding capsule's segment
    world: _Padded  # against scene objects and the part
    own: _Padded  # against the robot's other links


@dataclass
class _WorldObject:
    name: str
    kind: str
    pose: np.ndarray
    pieces: tuple[fcl.CollisionObject, ...]  # one, or a finely meshed obstacle's trees (``_bvh_pieces``)
    box_center: np.ndarray  # oriented bounding box: centre (world), rotation, half extents (m)
    box_rotation: np.ndarray
    box_half: np.ndarray
    solid_box: bool  # the bounding box is the object itself
    mesh: object = None  # closed trimesh (object frame) for the inside test FCL's BVH cannot do


def _centre_inside(shape_pose: np.ndarray, obj: _WorldObject) -> bool:
    """Whether a shape's centre (its pose (4, 4), world) lies inside the object's closed mesh."""
    return bool(centres_inside_meshes(shape_pose[None, :3, 3], np.zeros(1, dtype=np.int64), [obj])[0])


class Clearance(NamedTuple):
    """Smallest distance (m, between padded shapes; <= 0 in collision) and the pair it belongs to."""

    distance_m: float
    pair: tuple[str, str]


class _FramePoser:
    """All moving frames of a chain for (N, dof) joint values, with the fixed parts folded into constants.

    Equivalent to :meth:`KinematicModel.link_poses_batch` (the tests compare them) but with a dozen numpy calls
    in all, which matters for the single-state checks a sampling planner makes.
    """

    def __init__(self, model: KinematicModel):
        self.dof = model.dof
        self.pre: list[np.ndarray] = []  # moving frame k-1 -> joint k frame (before its rotation)
        self.axes: list[np.ndarray] = []
        self.frames: dict[str, tuple[int, np.ndarray]] = {}  # link -> (moving frame, offset)
        anchor, acc = -1, np.eye(4)
        self.frames[model.base_frame] = (anchor, acc.copy())
        for joint in model.chain_joints:
            acc = acc @ joint.origin
            if joint.type != "fixed":
                self.pre.append(acc)
                self.axes.append(np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis))
                anchor, acc = len(self.pre) - 1, np.eye(4)
            self.frames[joint.child] = (anchor, acc.copy())
        frontier = list(self.frames)
        while frontier:
            parent = frontier.pop()
            for joint in model.urdf.joints.values():
                if joint.parent == parent and joint.type == "fixed" and joint.child not in self.frames:
                    a, off = self.frames[parent]
                    self.frames[joint.child] = (a, off @ joint.origin)
                    frontier.append(joint.child)
        self._pre = np.array(self.pre).reshape(-1, 4, 4)
        skew = np.array([[[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]] for x, y, z in self.axes]).reshape(-1, 3, 3)
        self._skew, self._skew2 = skew, skew @ skew

    def moving_frames(self, q: np.ndarray) -> np.ndarray:
        """(N, dof, 4, 4): the frame after each joint's rotation (all joints' steps built at once)."""
        n = q.shape[0]
        if n >= COMPILED_FROM_STATES:
            return chain_frames(q, self._pre, np.array(self.axes).reshape(-1, 3), np.eye(4))[0]
        sin, cos = np.sin(q)[..., None, None], np.cos(q)[..., None, None]
        rotation = np.eye(3) + sin * self._skew + (1.0 - cos) * self._skew2  # Rodrigues, (N, dof, 3, 3)
        step = np.zeros((n, self.dof, 4, 4))
        step[..., :3, :3] = self._pre[:, :3, :3] @ rotation
        step[..., :3, 3] = self._pre[:, :3, 3]
        step[..., 3, 3] = 1.0
        for k in range(1, self.dof):
            np.matmul(step[:, k - 1], step[:, k], out=step[:, k])
        return step

    def link_poses(self, q: np.ndarray, links: list[str]) -> dict[str, np.ndarray]:
        moving = self.moving_frames(q)
        poses = {}
        for link in links:
            anchor, offset = self.frames[link]
            poses[link] = np.broadcast_to(offset, (q.shape[0], 4, 4)) if anchor < 0 else moving[:, anchor] @ offset
        return poses


# ----------------------------------------------------------------------------------------------- checker
class CollisionChecker:
    """Validity of joint states: joint limits, self-collision, collision with the scene objects and the part.

    Build it with :meth:`from_station`. Checked pairs: every robot link against every world object, and every
    two robot links, except the pairs of the allowed-collision matrix. A robot shape closer than ``padding_m``
    to an obstacle or the part, or two robot shapes closer than ``2 * self_padding_m``, count as a collision.
    """

    def __init__(
        self,
        model: KinematicModel,
        scene: Scene | None = None,
        config: CollisionConfig | str | Path | None = None,
        load_part: bool = True,
    ):
        self.model = model
        config = config if isinstance(config, CollisionConfig) else load_collision_config(config)
        # a private copy: allow_collision() must not change a configuration other checkers share
        self.config = replace(config, allowed=dict(config.allowed), generation=dict(config.generation))
        self.padding_m = float(self.config.padding_m)
        self.self_padding_m = float(self.config.self_padding_m)
        self._poser = _FramePoser(model)
        self._request = fcl.CollisionRequest()
        self._distance_request = fcl.DistanceRequest(enable_signed_distance=True)
        self.shapes: list[_RobotShape] = []
        for link, (anchor, link_offset) in self._poser.frames.items():
            for element, geometry in enumerate(model.urdf.collision.get(link, [])):
                self.shapes.append(self._make_shape(link, element, anchor, link_offset @ geometry.origin, geometry))
        self.robot_links: list[str] = list(dict.fromkeys(shape.link for shape in self.shapes))
        self._validate_allowed()
        self._shape_anchor = np.array([s.anchor for s in self.shapes])
        self._shape_offset = np.array([s.offset for s in self.shapes])
        self._shape_axis = np.array([s.axis for s in self.shapes], dtype=int)
        self._axis_select = np.eye(3)[self._shape_axis].reshape(-1, 3)
        self._world_half = np.array([s.world.half_length for s in self.shapes])
        self._own_half = np.array([s.own.half_length for s in self.shapes])
        self._own_radius = np.array([s.own.radius for s in self.shapes])
        self._world_extents = np.array([s.world.extents for s in self.shapes]).reshape(-1, 3)
        self._world_disc = np.array([s.world.disc for s in self.shapes])
        self._world_ball = np.array([s.world.ball for s in self.shapes])
        # extent of each shape along its own main axis
        self._world_axis_extent = (self._world_extents * self._axis_select).sum(axis=1) + self._world_ball
        self._world_bound = np.linalg.norm(self._world_extents, axis=1) + self._world_disc + self._world_ball
        self._static = self._shape_anchor < 0
        self._objects: dict[str, _WorldObject] = {}
        self.part_name: str | None = None
        if scene is not None:
            for obstacle in scene.objects:
                self.add_object(obstacle)
            if scene.part is not None and load_part:
                self.set_part_placement(scene.part)
        self._rebuild()

    @classmethod
    def from_station(
        cls,
        station: Station | None = None,
        config: CollisionConfig | str | Path | None = None,
        model: KinematicModel | None = None,
        load_part: bool = True,
    ) -> CollisionChecker:
        """Checker for the station's robot, scene and part (config: ``config/collision.yaml``)."""
        station = station or Station.load()
        model = model or KinematicModel.from_station(station)
        return cls(model, station.scene, config, load_part=load_part)

    # ------------------------------------------------------------------------------------ robot shapes
    def _validate_allowed(self) -> None:
        """Catch typos in the matrix: every entry names a link of the URDF, element indices exist."""
        where = self.config.source or "collision config"
        counts = {link: len(self.model.urdf.collision.get(link, [])) for link in self.model.urdf.links}
        for key, entry in self.config.allowed.items():
            names = sorted(key)
            if not any(name in counts for name in names):
                raise ConfigError(f"{where}: allowed pair {' - '.join(names)} names no robot link")
            for pair in entry.elements or ():
                for name, index in pair:
                    if name in counts and index >= counts[name]:
                        raise ConfigError(
                            f"{where}: allowed pair {' - '.join(names)}: link '{name}' has no collision element"
                            f" {index} (it has {counts[name]})"
                        )

    def _make_shape(self, link, element, anchor, offset, geometry) -> _RobotShape:
        world, axis = _padded(geometry, self.padding_m)
        own, _ = _padded(geometry, self.self_padding_m)
        return _RobotShape(link, element, geometry.type, offset, anchor, axis, world, own)

    # ---------------------------------------------------------------------------------- world objects
    def add_box(self, name: str, size_m, pose: np.ndarray) -> None:
        """Add (or replace) a box obstacle: full edge lengths (m), centre pose (4x4)."""
        size = np.asarray(size_m, dtype=float)
        self._add(name, "box", pose, fcl.Box(*size), np.zeros(3), size / 2.0, True)

    def add_cylinder(self, name: str, radius_m: float, length_m: float, pose: np.ndarray) -> None:
        """Add (or replace) a cylinder obstacle along its z axis, centred at ``pose`` (m)."""
        half = np.array([radius_m, radius_m, length_m / 2.0])
        self._add(name, "cylinder", pose, fcl.Cylinder(radius_m, length_m), np.zeros(3), half, False)

    def add_sphere(self, name: str, radius_m: float, pose: np.ndarray) -> None:
        """Add (or replace) a sphere obstacle (m)."""
        self._add(name, "sphere", pose, fcl.Sphere(radius_m), np.zeros(3), np.full(3, radius_m), False)

    def add_mesh(self, name: str, vertices_m: np.ndarray, faces: np.ndarray, pose: np.ndarray) -> None:
        """Add (or replace) a triangle-mesh obstacle: vertices in metres in the object frame, placed at ``pose``.

        A closed (watertight) mesh is solid: a robot shape wholly inside it collides. An open mesh is only its
        surface, as FCL sees it.
        """
        import trimesh

        vertices = np.asarray(vertices_m, dtype=float)
        faces = np.asarray(faces, dtype=np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise MotionInputError(f"mesh '{name}': need vertices (V, 3) and faces (F, 3)")
        if len(faces) == 0 or not np.all(np.isfinite(vertices)):
            raise MotionInputError(f"mesh '{name}': empty or non-finite mesh")
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        closed = mesh if mesh.is_watertight else None
        half = np.maximum((hi - lo) / 2.0, 1e-9)  # a flat mesh has a flat bounding box
        self._add(name, "mesh", pose, _bvh_pieces(vertices, faces), (lo + hi) / 2.0, half, False, closed)

    def add_trimesh(self, name: str, mesh, pose: np.ndarray, scale_to_m: float = 1.0) -> None:
        """Add a ``trimesh.Trimesh`` obstacle; ``scale_to_m`` converts its units to metres."""
        self.add_mesh(name, np.asarray(mesh.vertices) * scale_to_m, np.asarray(mesh.faces), pose)

    def add_object(self, obstacle: SceneObject) -> None:
        """Add a :class:`~agiprobot_measurement.station.SceneObject` from a scene file."""
        if obstacle.type in ("box", "chessboard"):
            self.add_box(obstacle.name, *obstacle.solid_box())
        elif obstacle.type == "cylinder":
            self.add_cylinder(obstacle.name, obstacle.radius_m, obstacle.length_m, obstacle.pose)
        elif obstacle.type == "sphere":
            self.add_sphere(obstacle.name, obstacle.radius_m, obstacle.pose)
        elif obstacle.type == "mesh":
            self.add_trimesh(obstacle.name, _load_mesh(obstacle.mesh), obstacle.pose, obstacle.mesh_scale)
        else:
            raise ConfigError(f"scene object '{obstacle.name}': unknown type '{obstacle.type}'")

    def set_part(
        self,
        mesh,
        faces: np.ndarray | None = None,
        pose: np.ndarray | None = None,
        name: str = "part",
        scale_to_m: float = 1.0,
    ) -> None:
        """Replace the part: a ``trimesh.Trimesh`` or vertices (V, 3) with ``faces``; ``scale_to_m`` converts
        the vertex unit to metres (0.001 for mm); ``pose`` places it in the world (identity if omitted)."""
        pose = np.eye(4) if pose is None else np.asarray(pose, dtype=float)
        if faces is None:
            vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        else:
            vertices = np.asarray(mesh)
        previous = self.part_name
        self.add_mesh(name, vertices * scale_to_m, faces, pose)  # raises before anything changed
        if previous is not None and previous != name and previous in self._objects:
            del self._objects[previous]
            self._rebuild()
        self.part_name = name

    def part_trees(self) -> tuple[tuple[fcl.CollisionObject, ...], np.ndarray] | None:
        """The part's FCL objects (one per tree, metres) and its pose, None without a part: for a check that shifts
        the part (the placement check) without building its trees again; it must put the pose back."""
        if self.part_name is None or self.part_name not in self._objects:
            return None
        part = self._objects[self.part_name]
        return part.pieces, part.pose

    def set_part_placement(self, part: PartPlacement) -> None:
        """Load the part of a scene file (mesh file, unit, pose)."""
        self.set_part(_load_mesh(part.mesh), pose=part.pose, name=part.name, scale_to_m=part.scale_to_m)

    def remove_part(self) -> None:
        if self.part_name is not None:
            self.remove_object(self.part_name)
            self.part_name = None

    def remove_object(self, name: str) -> None:
        if name not in self._objects:
            raise UnknownObjectError(f"no object '{name}'; objects: {', '.join(self._objects) or 'none'}")
        del self._objects[name]
        if name == self.part_name:
            self.part_name = None
        self._rebuild()

    def object_names(self) -> list[str]:
        return list(self._objects)

    def _add(self, name, kind, pose, geometry, local_center, half, solid_box, mesh=None) -> None:
        """``geometry``: one FCL geometry, or a list of them that together make the object."""
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise MotionInputError(f"object '{name}': pose must be a finite 4x4 matrix")
        if not np.all(np.asarray(half) > 0):
            raise MotionInputError(f"object '{name}': dimensions must be positive")
        if name in self.robot_links:
            raise MotionInputError(f"object '{name}': the name of a robot link")
        geometries = geometry if isinstance(geometry, list) else [geometry]
        pieces = tuple(fcl.CollisionObject(piece, _fcl_transform(pose)) for piece in geometries)
        self._objects[name] = _WorldObject(
            name, kind, pose, pieces, pose[:3, :3] @ local_center + pose[:3, 3], pose[:3, :3].copy(),
            np.asarray(half, dtype=float), solid_box, mesh,
        )  # fmt: skip
        self._rebuild()

    # ------------------------------------------------------------------------------- allowed pairs
    def allow_collision(self, a: str, b: str, reason: str = "User") -> None:
        """Stop checking the pair (a, b) (link or object names)."""
        if reason not in ALLOWED_REASONS:
            raise MotionInputError(f"unknown reason {reason!r}; valid: {', '.join(ALLOWED_REASONS)}")
        self.config.allowed[frozenset((a, b))] = AllowedEntry(reason)
        self._rebuild()

    def disallow_collision(self, a: str, b: str) -> None:
        """Check the pair (a, b) again."""
        self.config.allowed.pop(frozenset((a, b)), None)
        self._rebuild()

    def _rebuild(self) -> None:
        """Recompute the arrays of the broad phase after the world or the allowed pairs changed."""
        objects = list(self._objects.values())
        self._object_list = objects
        n_obj = len(objects)
        self._box_center = np.array([o.box_center for o in objects]).reshape(n_obj, 3)
        self._box_rotation = np.array([o.box_rotation for o in objects]).reshape(n_obj, 3, 3)
        self._box_center_local = np.einsum("oi,oij->oj", self._box_center, self._box_rotation)
        self._box_half = np.array([o.box_half for o in objects]).reshape(n_obj, 3)
        self._solid_box = np.array([o.solid_box for o in objects], dtype=bool)
        # all obstacles' box axes as rows (3 O, 3); flat per-axis centre coordinates and half extents (3 O,)
        self._box_axes = self._box_rotation.transpose(0, 2, 1).reshape(-1, 3)
        self._box_center_flat = self._box_center_local.reshape(-1)
        self._box_half_flat = self._box_half.reshape(-1)
        self._env_screened = None
        self._env_checked = np.array(
            [[not self._allowed(s, o) for o in objects] for s in self.shapes], dtype=bool
        ).reshape(len(self.shapes), n_obj)
        pairs = [
            (i, j)
            for i in range(len(self.shapes))
            for j in range(i + 1, len(self.shapes))
            if self.shapes[i].link != self.shapes[j].link and not self._allowed(self.shapes[i], self.shapes[j])
        ]
        self._self_pairs = np.array(pairs, dtype=int).reshape(-1, 2)
        self._self_reach = self._own_radius[self._self_pairs].sum(axis=1) if pairs else np.zeros(0)
        world = (self._shape_axis, self._world_extents, self._world_ball, self._world_disc)
        world += (self._world_axis_extent, self._world_half)
        boxes = (self._box_axes, self._box_center_flat, self._box_half, self._box_rotation, self._solid_box)
        self_pairs = (self._self_pairs[:, 0], self._self_pairs[:, 1], self._own_half, self._self_reach)
        self._second_stage_arrays = (world, boxes, self_pairs)
        extent = self._own_half + self._own_radius
        self._self_sphere_reach2 = extent[self._self_pairs].sum(axis=1) ** 2 if pairs else np.zeros(0)

    def _allowed(self, shape: _RobotShape, other: _RobotShape | _WorldObject) -> bool:
        if isinstance(other, _RobotShape):
            return self.config.is_allowed(shape.link, other.link, shape.element, other.element)
        return self.config.is_allowed(shape.link, other.name, shape.element, 0)

    # -------------------------------------------------------------------------------------- posing
    def shape_poses(self, q: np.ndarray) -> np.ndarray:
        """World poses (N, S, 4, 4) of the (padded) robot collision shapes for (N, dof) joint values."""
        moving = self._poser.moving_frames(q)
        if len(q) >= COMPILED_FROM_STATES:
            return attached_frames(moving, self._shape_anchor, self._shape_offset)
        anchors = np.where(self._static, 0, self._shape_anchor)
        poses = moving[:, anchors] @ self._shape_offset
        if np.any(self._static):
            poses[:, self._static] = self._shape_offset[self._static]
        return poses

    def _pose_shapes(self, pose: np.ndarray, *padded: _Padded) -> None:
        transform = fcl.Transform(pose[:3, :3], pose[:3, 3])
        for item in padded:
            item.obj.setTransform(transform)

    # ------------------------------------------------------------------------------------- queries
    def _check_q(self, q: np.ndarray) -> np.ndarray:
        return self.model._check_q(np.atleast_2d(np.asarray(q, dtype=float)))

    def is_state_valid(self, q: np.ndarray) -> bool:
        """True when the joint state (rad) is within the joint limits and collision-free (with padding).

        About 0.2 ms per call, mostly numpy overhead: for many states use :meth:`check_states` (tens of
        microseconds per state, less in large batches).
        """
        q = np.asarray(q, dtype=float)
        if q.ndim != 1:
            raise MotionInputError(f"expected one joint state of {self.model.dof} values, got shape {q.shape}")
        return bool(self.check_states(q[None])[0])

    def check_states(self, q: np.ndarray) -> np.ndarray:
        """Validity (N,) bool of (N, dof) joint states (rad): joint limits, self- and world collision."""
        q = self._check_q(q)
        valid = self.model.within_limits(q)
        index = np.nonzero(valid)[0]
        for start in range(0, len(index), _CHUNK):
            chunk = index[start : start + _CHUNK]
            valid[chunk] = self._collision_free(q[chunk])
        return valid

    def _segments(self, poses: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End points (N, S, 3) of the robot shapes' bounding-capsule segments of half lengths ``half`` (m)."""
        axes = np.einsum("nsij,sj->nsi", poses[:, :, :3, :3], self._axis_select) * half[:, None]
        centers = poses[:, :, :3, 3]
        return centers - axes, centers + axes

    def _screened(self, poses: np.ndarray) -> np.ndarray:
        """The checked (shape, obstacle) pairs without those of a static robot shape the broad phase finds apart:
        neither moves, so that holds for every state (computed once per world, from the first state's poses)."""
        if self._env_screened is None:
            static = self._env_checked & self._static[:, None]
            sure, env, _ = self._broad_phase(poses[:1], checked=static)
            screened = self._env_checked & ~self._static[:, None]
            screened[env[:, 1], env[:, 2]] = True
            self._env_screened = screened | static if sure[0] else screened
        return self._env_screened

    def _broad_phase(self, poses: np.ndarray, checked: np.ndarray | None = None):
        """Candidate pairs of the numpy broad phase for (N, S, 4, 4) shape poses (``checked``: the (shape, obstacle)
        pairs to check, default all but the static ones found apart).

        Returns (sure: (N,) states certainly in collision, env: (K, 3) rows [state, shape, object],
        pairs: (K, 2) rows [state, self-pair index]), candidates of the sure states left out.
        """
        n = poses.shape[0]
        centers = poses[:, :, :3, 3]
        sure = np.zeros(n, dtype=bool)
        env = np.zeros((0, 3), dtype=int)
        # stage 1, all (state, shape, obstacle): the shape's bounding sphere against the obstacle's box; and the
        # self pairs' bounding spheres (compiled for large batches, without the (N, S, 3 O) temporaries)
        stage = sphere_candidates if n >= COMPILED_FROM_STATES else sphere_candidates_numpy
        i, j = self._self_pairs[:, 0], self._self_pairs[:, 1]
        found, close_rows = stage(
            centers, self._box_axes, self._box_center_flat, self._box_half_flat, self._world_bound,
            self._screened(poses) if checked is None else checked, i, j, self._self_sphere_reach2,
        )  # fmt: skip
        if n >= COMPILED_FROM_STATES:
            sure, env_near, pair_near = second_stage(found, close_rows, poses, *self._second_stage_arrays)
            return sure, found[env_near], close_rows[pair_near]
        if len(self._object_list):
            state, shape, obstacle = found.T
            rows = 3 * obstacle[:, None] + np.arange(3)
            local = np.einsum("kj,kij->ki", centers[state, shape], self._box_axes[rows]) - self._box_center_flat[rows]
            # stage 2, the few left: separating axes with exact supports (the box's axes, the shape's axis)
            box_rotation = self._box_rotation[obstacle]
            cosines = box_rotation.transpose(0, 2, 1) @ poses[state, shape, :3, :3]  # box axis i . shape axis k
            along = np.take_along_axis(cosines, self._shape_axis[shape, None, None], axis=2)[..., 0]  # (K, 3)
            extent = (np.abs(cosines) @ self._world_extents[shape, :, None])[..., 0] + self._world_ball[shape, None]
            extent += self._world_disc[shape, None] * np.sqrt(np.maximum(1.0 - along * along, 0.0))
            half = self._box_half[obstacle]
            apart = np.any(np.abs(local) > extent + half, axis=1)
            box_extent = (np.abs(along) * half).sum(axis=1)
            apart |= np.abs((along * local).sum(axis=1)) > self._world_axis_extent[shape] + box_extent
            near = ~apart
            # an end of a shape's axis inside a solid box: the shape reaches into the box for certain
            reach = along * self._world_half[shape, None]
            inside = np.all(np.abs(local - reach) < half, axis=1) | np.all(np.abs(local + reach) < half, axis=1)
            inside &= near & self._solid_box[obstacle]
            sure[state[inside]] = True
            near &= ~sure[state]
            env = np.stack([state[near], shape[near], obstacle[near]], axis=1)
        pairs = np.zeros((0, 2), dtype=int)
        if len(self._self_pairs):
            # bounding spheres of the capsules first (above): leaves few pairs for the segment distances
            state, pair = close_rows.T
            keep = ~sure[state]
            state, pair = state[keep], pair[keep]
            if len(state):
                a, b = i[pair], j[pair]
                da = poses[state, a, :3, self._shape_axis[a]] * self._own_half[a, None]
                db = poses[state, b, :3, self._shape_axis[b]] * self._own_half[b, None]
                ca, cb = centers[state, a], centers[state, b]
                distance = _segment_distances(ca - da, ca + da, cb - db, cb + db)
                keep = distance < self._self_reach[pair]
                pairs = np.stack([state[keep], pair[keep]], axis=1)
        return sure, env, pairs

    def _collision_free(self, q: np.ndarray) -> np.ndarray:
        poses = self.shape_poses(q)
        sure, env, pairs = self._broad_phase(poses)
        free = ~sure
        if len(env) == 0 and len(pairs) == 0:
            return free
        # FCL only for the candidates, grouped by state, stopping at a state's first collision
        states = np.union1d(env[:, 0], pairs[:, 0])
        env_lo, env_hi = np.searchsorted(env[:, 0], states), np.searchsorted(env[:, 0], states, side="right")
        pair_lo, pair_hi = np.searchsorted(pairs[:, 0], states), np.searchsorted(pairs[:, 0], states, side="right")
        env_rows, pair_rows = env[:, 1:].tolist(), pairs[:, 1].tolist()
        # a shape wholly inside a closed mesh (which FCL's surface BVH does not report) decides only where FCL found
        # no contact: its centre is then in or out for the whole shape; all candidates' centres in one batch
        inside = centres_inside_meshes(poses[env[:, 0], env[:, 1], :3, 3], env[:, 2], self._object_list).tolist()
        self_pairs = self._self_pairs.tolist()
        objects, shapes, request = self._object_list, self.shapes, self._request
        collide, result = fcl.collide, fcl.CollisionResult
        for k, state in enumerate(states.tolist()):
            state_poses = poses[state]
            posed_world, posed_own = set(), set()
            hit = False
            for row in range(env_lo[k], env_hi[k]):
                s, o = env_rows[row]
                if s not in posed_world:
                    self._pose_shapes(state_poses[s], shapes[s].world)
                    posed_world.add(s)
                mine = shapes[s].world.obj
                if any(collide(mine, piece, request, result()) for piece in objects[o].pieces) or inside[row]:
                    hit = True
                    break
            if not hit:
                for p in pair_rows[pair_lo[k] : pair_hi[k]]:
                    a, b = self_pairs[p]
                    for s in (a, b):
                        if s not in posed_own:
                            self._pose_shapes(state_poses[s], shapes[s].own)
                            posed_own.add(s)
                    if collide(shapes[a].own.obj, shapes[b].own.obj, request, result()):
                        hit = True
                        break
            if hit:
                free[state] = False
        return free

    def _all_pairs(self, include_allowed: bool):
        """(shape index, padded shape, the other's FCL objects, other, names) of every pair for the diagnostic
        queries."""
        for i in range(len(self.shapes)):
            for j in range(i + 1, len(self.shapes)):
                a, b = self.shapes[i], self.shapes[j]
                if a.link != b.link and (include_allowed or not self._allowed(a, b)):
                    yield i, a.own, (b.own.obj,), b, (a.link, b.link)
        for i, shape in enumerate(self.shapes):
            for obj in self._object_list:
                if include_allowed or not self._allowed(shape, obj):
                    yield i, shape.world, obj.pieces, obj, (shape.link, obj.name)

    def _pose_all(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim != 1:
            raise MotionInputError(f"expected one joint state of {self.model.dof} values, got shape {q.shape}")
        poses = self.shape_poses(self._check_q(q))[0]
        for shape, pose in zip(self.shapes, poses, strict=True):
            self._pose_shapes(pose, shape.world, shape.own)
        return poses

    def colliding_pairs(self, q: np.ndarray, include_allowed: bool = False) -> list[tuple[str, str]]:
        """Names of every colliding (link, link) and (link, object) pair at joint state ``q`` (rad).

        Joint limits are not looked at. ``include_allowed`` also reports pairs the matrix allows.
        """
        poses = self._pose_all(q)
        found = []
        for i, mine, others, owner, names in self._all_pairs(include_allowed):
            hit = any(fcl.collide(mine.obj, other, self._request, fcl.CollisionResult()) > 0 for other in others)
            if not hit and isinstance(owner, _WorldObject) and owner.mesh is not None:
                hit = _centre_inside(poses[i], owner)
            if hit and names not in found:
                found.append(names)
        return found

    def min_distance(self, q: np.ndarray) -> Clearance:
        """Smallest distance (m) over the checked pairs at joint state ``q`` (rad), between padded shapes.

        Positive: free, with that much to spare beyond the paddings; <= 0: in collision (negative values are
        penetration depths where FCL computes them, 0 otherwise). Joint limits are not looked at.
        """
        poses = self._pose_all(q)
        best = Clearance(math.inf, ("", ""))
        for i, mine, others, owner, names in self._all_pairs(False):
            distance, touching = math.inf, False
            for other in others:
                gap = fcl.distance(mine.obj, other, self._distance_request, fcl.DistanceResult())
                if fcl.collide(mine.obj, other, self._request, fcl.CollisionResult()):
                    # FCL returns -1 instead of a depth for meshes
                    gap, touching = 0.0 if gap == -1.0 else min(gap, 0.0), True
                distance = min(distance, gap)
            inside = isinstance(owner, _WorldObject) and owner.mesh is not None
            if not touching and inside and _centre_inside(poses[i], owner):
                distance = -abs(distance)
            if distance < best.distance_m:
                best = Clearance(float(distance), names)
        return best

    def element_collision_matrix(
        self, q: np.ndarray
    ) -> tuple[list[tuple[tuple[str, int], tuple[str, int]]], np.ndarray]:
        """Which pairs of collision elements of different robot links collide (with ``self_padding_m``), in each
        of (N, dof) states.

        The allowed-collision matrix is ignored: this is what ``tools/generate_collision_matrix.py`` samples
        to build it. Returns the element pairs ``((link_a, i), (link_b, j))`` and an (N, P) bool matrix.
        """
        q = self._check_q(q)
        shape_pairs = np.array(
            [
                (i, j)
                for i in range(len(self.shapes))
                for j in range(i + 1, len(self.shapes))
                if self.shapes[i].link != self.shapes[j].link
            ],
            dtype=int,
        ).reshape(-1, 2)
        names = [
            ((self.shapes[i].link, self.shapes[i].element), (self.shapes[j].link, self.shapes[j].element))
            for i, j in shape_pairs
        ]
        result = np.zeros((q.shape[0], len(shape_pairs)), dtype=bool)
        reach = self._own_radius[shape_pairs].sum(axis=1)
        i, j = shape_pairs[:, 0], shape_pairs[:, 1]
        for start in range(0, q.shape[0], _CHUNK):
            poses = self.shape_poses(q[start : start + _CHUNK])
            ends0, ends1 = self._segments(poses, self._own_half)
            near = _segment_distances(ends0[:, i], ends1[:, i], ends0[:, j], ends1[:, j]) < reach
            for state, p in np.argwhere(near).tolist():
                a, b = self.shapes[shape_pairs[p, 0]], self.shapes[shape_pairs[p, 1]]
                self._pose_shapes(poses[state, shape_pairs[p, 0]], a.own)
                self._pose_shapes(poses[state, shape_pairs[p, 1]], b.own)
                if fcl.collide(a.own.obj, b.own.obj, self._request, fcl.CollisionResult()):
                    result[start + state, p] = True
        return names, result

    def explain(self, q: np.ndarray) -> str:
        """Why a state is invalid, e.g. 'in collision: forearm_link - table'; '' when it is valid."""
        q = self._check_q(q)[0]
        outside = [
            f"{name} = {value:.4f} rad outside [{lo:.4f}, {hi:.4f}]"
            for name, value, lo, hi in zip(self.model.joint_names, q, self.model.lower, self.model.upper, strict=True)
            if not lo <= value <= hi
        ]
        if outside:
            return "outside joint limits: " + "; ".join(outside)
        pairs = self.colliding_pairs(q)
        if pairs:
            return "in collision: " + ", ".join(f"{a} - {b}" for a, b in pairs)
        return ""


def _load_mesh(path: str | Path):
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ConfigError(f"{path}: cannot read mesh: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ConfigError(f"{path}: no triangles in mesh")
    return mesh


def adjacent_link_pairs(model: KinematicModel, links: list[str]) -> list[tuple[str, str]]:
    """Pairs of links with geometry joined by one joint, or by a run of fixed joints through links without
    geometry (e.g. ``wrist_3_link`` - ``tool0`` - ``laser_scanner_link``): they touch by construction."""
    with_geometry = set(links)
    neighbours: dict[str, set[str]] = {}
    for joint in model.urdf.joints.values():
        neighbours.setdefault(joint.parent, set()).add(joint.child)
        neighbours.setdefault(joint.child, set()).add(joint.parent)
    pairs = set()
    for link in links:
        seen, frontier = {link}, [link]
        while frontier:
            current = frontier.pop()
            for other in neighbours.get(current, ()):
                if other in seen:
                    continue
                seen.add(other)
                if other in with_geometry:
                    pairs.add(tuple(sorted((link, other))))
                else:
                    frontier.append(other)
    return sorted(pairs)
