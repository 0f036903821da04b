"""The scene as the PhoXi renderer sees it: one triangle soup with an outward normal, an albedo and an owner per face.

:func:`scene_geometry` builds it from a scene file (objects, chessboards, the part), :class:`RobotGeometry` from a
robot's URDF (posed per frame from its link poses), :func:`chessboard_geometry` from a board's layout. Albedos come
from the display colours (:func:`albedo_of`). Metres throughout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.station import Scene
from agiprobot_measurement.station.scene import chessboard_board_size, chessboard_dark_squares

__all__ = [
    "BLACK_ALBEDO",
    "DEFAULT_ALBEDO",
    "ROBOT_ALBEDO",
    "WHITE_ALBEDO",
    "RobotGeometry",
    "SceneGeometry",
    "albedo_of",
    "chessboard_geometry",
    "primitive_mesh",
    "scene_chessboard_geometry",
    "scene_geometry",
]

DEFAULT_ALBEDO = 0.6
ROBOT_ALBEDO = 0.55
WHITE_ALBEDO = 0.9
BLACK_ALBEDO = 0.08


@dataclass(frozen=True)
class SceneGeometry:
    """Triangles of the scene in one frame (metres) with an outward unit normal, albedo and owner per face."""

    triangles: np.ndarray  # (F, 3, 3)
    normals: np.ndarray  # (F, 3)
    albedo: np.ndarray  # (F,)
    owner: np.ndarray  # (F,) index into names
    names: tuple[str, ...]

    @classmethod
    def empty(cls) -> SceneGeometry:
        return cls(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int32), ())

    @classmethod
    def from_trimesh(cls, mesh, name: str, albedo: float) -> SceneGeometry:
        triangles = np.asarray(mesh.triangles, dtype=float)
        normals = np.asarray(mesh.face_normals, dtype=float)
        n = len(triangles)
        return cls(triangles, normals, np.full(n, float(albedo)), np.zeros(n, dtype=np.int32), (name,))

    def __len__(self) -> int:
        return len(self.triangles)

    def transformed(self, pose: np.ndarray) -> SceneGeometry:
        """The scene under the 4x4 ``pose`` (rigid, or with a scale, e.g. mm -> m): normals transform with the
        inverse transpose and stay unit length."""
        linear, translation = pose[:3, :3], pose[:3, 3]
        normals = self.normals @ np.linalg.inv(linear)  # (L^-T n^T)^T
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        return SceneGeometry(self.triangles @ linear.T + translation, normals, self.albedo, self.owner, self.names)

    @staticmethod
    def concatenate(parts: list[SceneGeometry]) -> SceneGeometry:
        parts = [p for p in parts if len(p)]
        if not parts:
            return SceneGeometry.empty()
        names, owners, offset = [], [], 0
        for part in parts:
            owners.append(part.owner + offset)
            names.extend(part.names)
            offset += len(part.names)
        return SceneGeometry(
            np.concatenate([p.triangles for p in parts]),
            np.concatenate([p.normals for p in parts]),
            np.concatenate([p.albedo for p in parts]),
            np.concatenate(owners).astype(np.int32),
            tuple(names),
        )


def primitive_mesh(kind: str, size=None, radius: float | None = None, length: float | None = None, sections: int = 48):
    """A box (size), cylinder (radius, length along z) or sphere centred at the origin, as URDF and the scene define them."""
    import trimesh

    if kind == "box":
        return trimesh.creation.box(extents=np.asarray(size, dtype=float))
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=float(radius), height=float(length), sections=sections)
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=3, radius=float(radius))
    raise ConfigError(f"unsupported primitive {kind!r} (box, cylinder, sphere)")


def albedo_of(color_rgba) -> float:
    """Diffuse albedo from a display colour: its luminance (Rec. 709), kept within [0.05, 1]."""
    r, g, b = (float(c) for c in color_rgba[:3])
    return float(np.clip(0.2126 * r + 0.7152 * g + 0.0722 * b, 0.05, 1.0))


def _load_mesh(path: Path, scale: float):
    import trimesh

    mesh = trimesh.load(str(path), force="mesh")
    mesh.apply_scale(scale)
    return mesh


def scene_geometry(scene: Scene, exclude_groups: tuple[str, ...] = ()) -> SceneGeometry:
    """The scene file's objects and the part as triangles in the scene frame (albedo from their colours)."""
    parts = []
    for obj in scene.objects:
        if obj.group is not None and obj.group in exclude_groups:
            continue
        if obj.type == "chessboard":
            parts.append(scene_chessboard_geometry(obj))
            continue
        if obj.type == "mesh":
            mesh = _load_mesh(obj.mesh, obj.mesh_scale)
        else:
            mesh = primitive_mesh(obj.type, obj.size_m, obj.radius_m, obj.length_m)
        parts.append(SceneGeometry.from_trimesh(mesh, obj.name, albedo_of(obj.color_rgba)).transformed(obj.pose))
    if scene.part is not None:
        mesh = _load_mesh(scene.part.mesh, scene.part.scale_to_m)
        parts.append(
            SceneGeometry.from_trimesh(mesh, scene.part.name, albedo_of(scene.part.color_rgba)).transformed(
                scene.part.pose
            )
        )
    return SceneGeometry.concatenate(parts)


class RobotGeometry:
    """The robot's link shapes from its URDF (visual elements by default) in link frames, posed per frame.

    ``mesh_resolver`` maps a URDF mesh filename (``package://...``, ``file://...``) to a local path; meshes it
    cannot resolve are left out and listed in :attr:`skipped`.
    """

    def __init__(self, urdf, elements: str = "visual", albedo: float = ROBOT_ALBEDO, mesh_resolver=None):
        table = urdf.visual if elements == "visual" else urdf.collision
        self.links: dict[str, SceneGeometry] = {}
        self.skipped: list[str] = []
        for link, geometries in table.items():
            parts = []
            for geometry in geometries:
                if geometry.type == "mesh":
                    path = _resolve_mesh(geometry.mesh, mesh_resolver)
                    if path is None:
                        self.skipped.append(f"{link}: {geometry.mesh}")
                        continue
                    mesh = _load_mesh(path, 1.0)
                    mesh.apply_scale(np.asarray(geometry.scale, dtype=float))
                else:
                    mesh = primitive_mesh(geometry.type, geometry.size, geometry.radius, geometry.length)
                parts.append(SceneGeometry.from_trimesh(mesh, link, albedo).transformed(geometry.origin))
            if parts:
                merged = SceneGeometry.concatenate(parts)
                self.links[link] = SceneGeometry(
                    merged.triangles, merged.normals, merged.albedo, np.zeros(len(merged), np.int32), (link,)
                )

    @property
    def link_names(self) -> list[str]:
        return list(self.links)

    def posed(self, link_poses: dict) -> SceneGeometry:
        """Triangles of the links whose pose (4x4, scene frame) is given; other links are left out."""
        return SceneGeometry.concatenate(
            [
                geometry.transformed(np.asarray(link_poses[link]))
                for link, geometry in self.links.items()
                if link in link_poses
            ]
        )


def _resolve_mesh(filename: str | None, resolver) -> Path | None:
    if not filename:
        return None
    if resolver is not None:
        resolved = resolver(filename)
        return Path(resolved) if resolved else None
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    path = Path(filename)
    return path if path.is_absolute() and path.is_file() else None


def chessboard_geometry(board_pose: np.ndarray, inner_corners=(8, 11), square_m: float = 0.03, thickness_m=0.003):
    """SceneGeometry (frame of ``board_pose``'s parent) of a chessboard: (rows+1) x (cols+1) squares of alternating
    albedo, printed (0.1 mm) on a white backing board with a one-square margin (the quiet zone OpenCV needs)."""
    backing = np.eye(4)
    backing[2, 3] = -thickness_m / 2.0  # its face at z = 0: the corners' plane
    size = chessboard_board_size(inner_corners, square_m, thickness_m)
    parts = [SceneGeometry.from_trimesh(primitive_mesh("box", size=size), "board", WHITE_ALBEDO).transformed(backing)]
    printed = SceneGeometry.from_trimesh(
        primitive_mesh("box", size=(square_m, square_m, 0.0002)), "square", BLACK_ALBEDO
    )
    for x, y in chessboard_dark_squares(inner_corners, square_m):
        square = np.eye(4)
        square[:2, 3] = [x, y]  # printed: 0.1 mm proud of the face
        parts.append(printed.transformed(square))
    return SceneGeometry.concatenate(parts).transformed(np.asarray(board_pose, dtype=float))


def scene_chessboard_geometry(board) -> object:
    """SceneGeometry of a scene file's chessboard object (station.SceneObject of type chessboard)."""
    return chessboard_geometry(board.pose, board.inner_corners, board.square_m, board.thickness_m)
