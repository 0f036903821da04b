"""Actual parts with analytic truth: the nominal CAD and a deviated copy of it (dent, shifted hole, warp, scale)
placed with a placement error, for scanning with the simulators while inspection sees only the nominal.

All lengths in mm, in the part's CAD frame; a placement is a 4x4 world <- part transform (mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from agiprobot_measurement.inspection.errors import InspectionInputError

__all__ = [
    "ActualPart",
    "cube",
    "dented",
    "holed_plate",
    "placement_error",
    "scaled",
    "subdivide_near",
    "warped",
]


@dataclass
class ActualPart:
    """A nominal CAD mesh, the actual (deviated) mesh in the same frame and the truth of the deviation.

    ``truth``: what an inspection should find (e.g. ``dent_depth_mm``, ``hole_shift_mm``, ``flatness_mm``,
    ``scale``); ``nominal_placement`` the planned world <- part pose, ``actual_placement`` the real one (mm)."""

    name: str
    nominal: trimesh.Trimesh
    actual: trimesh.Trimesh
    truth: dict = field(default_factory=dict)
    nominal_placement: np.ndarray = field(default_factory=lambda: np.eye(4))
    actual_placement: np.ndarray = field(default_factory=lambda: np.eye(4))

    def placed_actual(self) -> trimesh.Trimesh:
        """The actual mesh in the world (mm)."""
        mesh = self.actual.copy()
        mesh.apply_transform(self.actual_placement)
        return mesh

    def with_placement(self, nominal_placement: np.ndarray, error: np.ndarray | None = None) -> ActualPart:
        """The same part planned at ``nominal_placement`` and really placed at ``nominal_placement @ error``."""
        planned = np.asarray(nominal_placement, dtype=float)
        err = np.eye(4) if error is None else np.asarray(error, dtype=float)
        return ActualPart(self.name, self.nominal, self.actual, dict(self.truth), planned, planned @ err)


def cube(size_mm: float = 100.0) -> trimesh.Trimesh:
    """A cube of ``size_mm`` centred at the origin (12 faces)."""
    return trimesh.creation.box(extents=(size_mm,) * 3)


def subdivide_near(mesh: trimesh.Trimesh, centre_mm, radius_mm: float, max_edge_mm: float) -> trimesh.Trimesh:
    """``mesh`` with the faces within ``radius_mm`` of ``centre_mm`` split until their edges are <= ``max_edge_mm``
    (the split faces' neighbours keep their edges: T-junctions, no gaps)."""
    vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    centre = np.asarray(centre_mm, float)
    for _ in range(40):
        tri = vertices[faces]
        closest = trimesh.triangles.closest_point(tri, np.repeat(centre[None], len(faces), axis=0))
        near = np.linalg.norm(closest - centre, axis=1) <= radius_mm
        edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        split = np.flatnonzero(near & (edges > max_edge_mm))
        if not len(split):
            break
        vertices, faces = trimesh.remesh.subdivide(vertices, faces, face_index=split)
    return trimesh.Trimesh(vertices, faces, process=False)


def dented(nominal: trimesh.Trimesh, centre_mm, normal, depth_mm: float, radius_mm: float = 5.0) -> ActualPart:
    """A dent: points within ``radius_mm`` of ``centre_mm`` (on a face with outward ``normal``) pushed inwards by
    ``depth_mm * (1 - (d / radius)^2)^2`` (d: distance from the centre in the face)."""
    if depth_mm < 0 or radius_mm <= 0:
        raise InspectionInputError("a dent needs depth_mm >= 0 and radius_mm > 0")
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    centre = np.asarray(centre_mm, float)
    mesh = subdivide_near(nominal, centre, radius_mm + 1.0, min(0.5, radius_mm / 10))
    v = np.asarray(mesh.vertices, float).copy()
    rel = v - centre
    along = rel @ n
    d = np.linalg.norm(rel - along[:, None] * n, axis=1)
    inside = (d < radius_mm) & (np.abs(along) < 1e-6 * max(1.0, float(np.abs(v).max())))
    v[inside] -= (depth_mm * (1.0 - (d[inside] / radius_mm) ** 2) ** 2)[:, None] * n
    actual = trimesh.Trimesh(v, np.asarray(mesh.faces), process=False)
    truth = {"case": "dent", "dent_depth_mm": float(depth_mm), "dent_radius_mm": float(radius_mm),
             "dent_centre_mm": centre.tolist()}  # fmt: skip
    return ActualPart("dent", nominal, actual, truth)


def warped(length_mm=200.0, width_mm=100.0, thickness_mm=5.0, bow_mm=0.0, max_edge_mm=5.0) -> ActualPart:
    """A plate (top face at z = thickness/2) bent by ``z += bow * (1 - (2x / length)^2)``: the top face's flatness
    is ``bow_mm``."""
    nominal = trimesh.creation.box(extents=(length_mm, width_mm, thickness_mm))
    v, f = trimesh.remesh.subdivide_to_size(nominal.vertices, nominal.faces, max_edge=max_edge_mm)
    v = np.asarray(v, float).copy()
    v[:, 2] += bow_mm * (1.0 - (2.0 * v[:, 0] / length_mm) ** 2)
    actual = trimesh.Trimesh(v, f, process=False)
    return ActualPart("warp", nominal, actual, {"case": "warp", "flatness_mm": float(abs(bow_mm))})


def scaled(nominal: trimesh.Trimesh, scale: float) -> ActualPart:
    """The part scaled uniformly by ``1 + scale`` about its bounding-box centre: every size grows by that factor."""
    centre = nominal.bounds.mean(axis=0)
    v = (np.asarray(nominal.vertices, float) - centre) * (1.0 + scale) + centre
    actual = trimesh.Trimesh(v, np.asarray(nominal.faces), process=False)
    sizes = (nominal.extents * (1.0 + scale)).tolist()
    return ActualPart("scale", nominal, actual, {"case": "scale", "scale": float(scale), "sizes_mm": sizes})


def _annulus_strip(centre, radius, half, sections, z, up):
    """Triangles between a circle of ``radius`` and the square of half-size ``half`` around ``centre`` at ``z``
    (``sections`` a multiple of 8, so the square's corners are among its points)."""
    angles = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    circle = np.stack([centre[0] + radius * c, centre[1] + radius * s, np.full(sections, z)], axis=1)
    scale = half / np.maximum(np.abs(c), np.abs(s))
    square = np.stack([centre[0] + scale * c, centre[1] + scale * s, np.full(sections, z)], axis=1)
    tris = []
    for i in range(sections):
        j = (i + 1) % sections
        a, b, cc, d = circle[i], circle[j], square[j], square[i]
        tris += [[a, d, cc], [a, cc, b]] if up else [[a, cc, d], [a, b, cc]]
    return np.asarray(tris)


def _rect(x0, x1, y0, y1, z, up):
    p = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
    return (
        np.array([[p[0], p[1], p[2]], [p[0], p[2], p[3]]]) if up else np.array([[p[0], p[2], p[1]], [p[0], p[3], p[2]]])
    )


def _plate_with_hole(length, width, thickness, centre, radius, sections=256) -> trimesh.Trimesh:
    """A plate centred at the origin (z from -t/2 to t/2) with one through-hole at ``centre`` (x, y)."""
    half = 2.0 * radius
    cx, cy = centre
    x0, x1, y0, y1 = -length / 2, length / 2, -width / 2, width / 2
    if not (x0 < cx - half and cx + half < x1 and y0 < cy - half and cy + half < y1):
        raise InspectionInputError("the hole must lie at least one diameter inside the plate")
    tris = []
    for z, up in ((thickness / 2, True), (-thickness / 2, False)):
        tris.append(_annulus_strip(centre, radius, half, sections, z, up))
        tris += [_rect(x0, x1, y0, cy - half, z, up), _rect(x0, x1, cy + half, y1, z, up),
                 _rect(x0, cx - half, cy - half, cy + half, z, up), _rect(cx + half, x1, cy - half, cy + half, z, up)]  # fmt: skip
    box = trimesh.creation.box(extents=(length, width, thickness))
    side = np.abs(box.face_normals[:, 2]) < 0.5
    tris.append(np.asarray(box.triangles)[side])
    angles = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = np.stack([cx + radius * np.cos(angles), cy + radius * np.sin(angles)], axis=1)
    top, bottom = np.c_[ring, np.full(sections, thickness / 2)], np.c_[ring, np.full(sections, -thickness / 2)]
    wall = []
    for i in range(sections):
        j = (i + 1) % sections
        wall += [[top[i], bottom[j], bottom[i]], [top[i], top[j], bottom[j]]]  # normals towards the hole's axis
    tris.append(np.asarray(wall))
    triangles = np.concatenate(tris)
    return trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(len(triangles) * 3).reshape(-1, 3), process=True)


def holed_plate(shift_mm=(0.0, 0.0), length_mm=120.0, width_mm=80.0, thickness_mm=10.0, hole_centre_mm=(20.0, 10.0),
                hole_diameter_mm=10.0) -> ActualPart:  # fmt: skip
    """A plate with one through-hole; the actual hole is moved by ``shift_mm`` (x, y) in the plate."""
    centre = np.asarray(hole_centre_mm, float)
    radius = hole_diameter_mm / 2
    nominal = _plate_with_hole(length_mm, width_mm, thickness_mm, centre, radius)
    actual = _plate_with_hole(length_mm, width_mm, thickness_mm, centre + np.asarray(shift_mm, float), radius)
    shift = float(np.linalg.norm(shift_mm))
    truth = {"case": "hole", "hole_shift_mm": shift, "hole_position_deviation_mm": 2.0 * shift,
             "hole_centre_mm": (centre + np.asarray(shift_mm, float)).tolist(), "hole_diameter_mm": hole_diameter_mm}  # fmt: skip
    return ActualPart("hole", nominal, actual, truth)


def placement_error(rng: np.random.Generator, translation_mm: float = 2.0, rotation_deg: float = 1.0,
                    centre_mm=(0.0, 0.0, 0.0)) -> np.ndarray:  # fmt: skip
    """A rigid error (4x4, part frame): rotation of ``rotation_deg`` about a random axis through ``centre_mm`` and a
    translation of ``translation_mm`` in a random direction."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(np.radians(rotation_deg) * axis).as_matrix()
    c = np.asarray(centre_mm, float)
    pose[:3, 3] = c - pose[:3, :3] @ c + translation_mm * direction
    return pose
