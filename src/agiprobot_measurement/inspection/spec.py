"""The inspection spec (``config/inspection/*.yaml``): alignment, surface-deviation settings, named faces and the
features to evaluate, read once into dataclasses and resolved against the nominal mesh.

A face is named by its outward ``normal`` and a ``point`` of its plane (CAD frame, mm); it resolves to the
nominal triangles on that plane facing that way -- a name the mesh does not have is an error before any work.
Feature types: ``flatness`` (face, tolerance_mm), ``size`` (two parallel faces, nominal_mm, tolerance_mm),
``hole`` (face it opens on, centre, axis, diameter_mm, position_tolerance_mm, diameter_tolerance_mm), ``plane``
(face; reports its form), ``sphere`` (centre, radius_mm, tolerance_mm on the radius), ``cylinder`` (point, axis,
diameter_mm, tolerance_mm on the diameter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.inspection.errors import SpecError
from agiprobot_measurement.inspection.registration import DOF_NAMES, IcpSettings, RpsPoint

__all__ = ["FEATURE_TYPES", "Face", "Feature", "InspectionSpec", "SurfaceSettings", "load_spec", "parse_spec"]

FEATURE_TYPES = ("flatness", "size", "hole", "plane", "sphere", "cylinder")
#: alignment methods: robust best fit; best fit then 3-2-1 datum planes; best fit then reference points (RPS)
ALIGNMENTS = ("best_fit", "datum_321", "rps")
#: a nominal triangle belongs to a named face when its normal is within this angle (deg) of the face's
FACE_ANGLE_DEG = 2.0


@dataclass(frozen=True)
class Face:
    name: str
    normal: np.ndarray
    point: np.ndarray


@dataclass(frozen=True)
class Feature:
    """One feature to evaluate; ``params`` holds its type's keys (vectors as arrays, lengths in mm)."""

    name: str
    type: str
    faces: tuple[str, ...]
    params: dict


@dataclass(frozen=True)
class SurfaceSettings:
    """Surface comparison: profile tolerance +-``tolerance_mm``; points farther than ``max_distance_mm`` are not
    the part's; ``edge_margin_mm`` around sharp edges masked; patches of ``voxel_mm`` voxels averaged within
    ``patch_radius_mm`` (flags) and ``depth_radius_mm`` (extreme values); ``no_data_radius_mm`` for coverage."""

    tolerance_mm: float = 0.1
    max_distance_mm: float = 3.0
    edge_margin_mm: float = 1.0
    voxel_mm: float = 1.0
    patch_radius_mm: float = 2.0
    depth_radius_mm: float = 1.0
    no_data_radius_mm: float = 1.5


@dataclass(frozen=True)
class InspectionSpec:
    part: str
    unit_scale_to_mm: float
    alignment: str
    icp: IcpSettings
    datums: tuple[str, ...]
    surface: SurfaceSettings
    faces: dict[str, Face] = field(default_factory=dict)
    features: tuple[Feature, ...] = ()
    rps_points: tuple[RpsPoint, ...] = ()
    rps_radius_mm: float = 3.0

    def face_triangles(self, mesh: trimesh.Trimesh, name: str) -> np.ndarray:
        """Indices of the nominal triangles of the named face (a :class:`SpecError` for an unknown name or a face
        the mesh does not have)."""
        if name not in self.faces:
            raise SpecError(f"spec {self.part}: unknown face {name!r} (named faces: {sorted(self.faces)})")
        face = self.faces[name]
        normals = np.asarray(mesh.face_normals)
        centroids = np.asarray(mesh.triangles_center)
        tol = 1e-4 * max(float(mesh.scale), 1.0)
        hit = (normals @ face.normal > np.cos(np.radians(FACE_ANGLE_DEG))) & (
            np.abs((centroids - face.point) @ face.normal) < tol
        )
        if not hit.any():
            raise SpecError(
                f"spec {self.part}: face {name!r} (normal {face.normal.round(3).tolist()}, point "
                f"{face.point.round(3).tolist()} mm) matches no triangle of the nominal model"
            )
        return np.flatnonzero(hit)

    def on_face(self, mesh: trimesh.Trimesh, name: str, triangle_of_point: np.ndarray) -> np.ndarray:
        """Per point: its (closest) triangle belongs to the named face (a lookup table, not a set search)."""
        member = np.zeros(len(mesh.faces), dtype=bool)
        member[self.face_triangles(mesh, name)] = True
        return member[np.asarray(triangle_of_point, dtype=np.int64)]

    def check_against(self, mesh: trimesh.Trimesh) -> None:
        """Every face a feature or datum names exists on ``mesh``."""
        for name in {*self.datums, *(f for feat in self.features for f in feat.faces)}:
            self.face_triangles(mesh, name)


UNITS = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "in": 25.4, "inch": 25.4}
_FEATURE_KEYS = {
    "flatness": ({"face", "tolerance_mm"}, set()),
    "size": ({"faces", "nominal_mm", "tolerance_mm"}, set()),
    "hole": ({"face", "centre", "axis", "diameter_mm", "position_tolerance_mm"}, {"diameter_tolerance_mm"}),
    "plane": ({"face"}, {"tolerance_mm"}),
    "sphere": ({"centre", "radius_mm", "tolerance_mm"}, set()),
    "cylinder": ({"point", "axis", "diameter_mm", "tolerance_mm"}, {"length_mm"}),
}
_VECTORS = ("centre", "axis", "point")


def _vec(value, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{where}: expected 3 numbers, got {value!r}") from exc
    if not np.all(np.isfinite(v)):
        raise SpecError(f"{where}: not finite")
    return v


def _positive(value, where: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{where}: expected a number, got {value!r}") from exc
    if not (np.isfinite(v) and v > 0):
        raise SpecError(f"{where}: must be > 0, got {value!r}")
    return v


def _feature(entry, index: int, where: str) -> Feature:
    if not isinstance(entry, dict) or "name" not in entry or "type" not in entry:
        raise SpecError(f"{where}: features[{index}] needs a name and a type")
    name, kind = str(entry["name"]), str(entry["type"])
    if kind not in _FEATURE_KEYS:
        raise SpecError(f"{where}: feature {name!r}: unknown type {kind!r} (known: {list(FEATURE_TYPES)})")
    required, optional = _FEATURE_KEYS[kind]
    keys = set(entry) - {"name", "type"}
    if missing := required - keys:
        raise SpecError(f"{where}: feature {name!r} ({kind}) lacks {sorted(missing)}")
    if extra := keys - required - optional:
        raise SpecError(f"{where}: feature {name!r} ({kind}): unknown keys {sorted(extra)}")
    params = {}
    for key in keys - {"face", "faces"}:
        label = f"{where}: feature {name!r} {key}"
        params[key] = _vec(entry[key], label) if key in _VECTORS else _positive(entry[key], label)
    if "axis" in params:
        params["axis"] = params["axis"] / np.linalg.norm(params["axis"])
    faces = (str(entry["face"]),) if "face" in entry else tuple(str(f) for f in entry.get("faces", ()))
    if kind == "size" and len(faces) != 2:
        raise SpecError(f"{where}: feature {name!r} (size) needs exactly two faces")
    return Feature(name, kind, faces, params)


def parse_spec(data, where: str = "spec") -> InspectionSpec:
    """An :class:`InspectionSpec` from the YAML mapping ``data``."""
    if not isinstance(data, dict):
        raise SpecError(f"{where}: expected a mapping at the top")
    unit = str(data.get("units", "mm"))
    if unit not in UNITS:
        raise SpecError(f"{where}: units {unit!r} unknown (known: {sorted(UNITS)})")
    align = data.get("alignment") or {}
    method = str(align.get("method", "best_fit"))
    if method not in ALIGNMENTS:
        raise SpecError(f"{where}: alignment method {method!r}: use one of {list(ALIGNMENTS)}")
    lock = tuple(str(x) for x in align.get("lock", ()) or ())
    if bad := sorted(set(lock) - set(DOF_NAMES)):
        raise SpecError(f"{where}: alignment lock {bad}: known degrees of freedom {list(DOF_NAMES)}")
    icp_keys = {"robust", "trim", "max_distance_mm", "sample", "max_iterations"}
    icp = IcpSettings(lock=lock, **{k: v for k, v in align.items() if k in icp_keys})
    datums = tuple(str(x) for x in align.get("datums", ()) or ())
    if method == "datum_321" and len(datums) != 3:
        raise SpecError(f"{where}: datum_321 alignment needs three datum faces (A, B, C), got {list(datums)}")
    surface_data = data.get("deviation") or {}
    fields = set(SurfaceSettings.__dataclass_fields__)
    if extra := sorted(set(surface_data) - fields):
        raise SpecError(f"{where}: deviation: unknown keys {extra} (known: {sorted(fields)})")
    surface = SurfaceSettings(**{k: _positive(v, f"{where}: deviation {k}") for k, v in surface_data.items()})
    faces = {}
    for name, face in (data.get("faces") or {}).items():
        if not isinstance(face, dict) or {"normal", "point"} - set(face):
            raise SpecError(f"{where}: face {name!r} needs a normal and a point")
        normal = _vec(face["normal"], f"{where}: face {name!r} normal")
        if np.linalg.norm(normal) < 1e-9:
            raise SpecError(f"{where}: face {name!r}: zero normal")
        faces[str(name)] = Face(
            str(name), normal / np.linalg.norm(normal), _vec(face["point"], f"{where}: face {name!r} point")
        )
    features = tuple(_feature(e, i, where) for i, e in enumerate(data.get("features") or ()))
    names = [f.name for f in features]
    if len(set(names)) != len(names):
        raise SpecError(f"{where}: feature names repeat: {names}")
    for name in {*datums, *(f for feat in features for f in feat.faces)}:
        if name not in faces:
            raise SpecError(f"{where}: unknown face {name!r} (named faces: {sorted(faces)})")
    rps_points, rps_radius = _rps(align.get("rps"), method, where)
    return InspectionSpec(
        str(data.get("part", Path(where).stem)),
        UNITS[unit],
        method,
        icp,
        datums,
        surface,
        faces,
        features,
        rps_points,
        rps_radius,
    )


def _rps(entry, method: str, where: str) -> tuple[tuple[RpsPoint, ...], float]:
    """The RPS points of ``alignment.rps`` ({radius_mm, points: [{name, point, direction}]})."""
    if method != "rps":
        if entry:
            raise SpecError(f"{where}: alignment rps given but the method is {method!r} (use method: rps)")
        return (), 3.0
    if not isinstance(entry, dict) or not entry.get("points"):
        raise SpecError(f"{where}: rps alignment needs alignment.rps.points: [{{name, point, direction}}, ...]")
    if extra := sorted(set(entry) - {"radius_mm", "points"}):
        raise SpecError(f"{where}: alignment.rps: unknown keys {extra} (known: ['points', 'radius_mm'])")
    radius = _positive(entry.get("radius_mm", 3.0), f"{where}: alignment.rps.radius_mm")
    points = []
    for k, p in enumerate(entry["points"]):
        if not isinstance(p, dict) or {"point", "direction"} - set(p) or set(p) - {"name", "point", "direction"}:
            raise SpecError(f"{where}: alignment.rps.points[{k}]: needs point and direction (and a name)")
        name = str(p.get("name", f"P{k + 1}"))
        direction = _vec(p["direction"], f"{where}: RPS point {name!r} direction")
        if np.linalg.norm(direction) < 1e-9:
            raise SpecError(f"{where}: RPS point {name!r}: zero direction")
        points.append(RpsPoint(name, _vec(p["point"], f"{where}: RPS point {name!r} point"),
                               direction / np.linalg.norm(direction)))  # fmt: skip
    names = [p.name for p in points]
    if len(set(names)) != len(names):
        raise SpecError(f"{where}: RPS point names repeat: {names}")
    return tuple(points), radius


def load_spec(path: str | Path) -> InspectionSpec:
    """Read and check an inspection spec file."""
    try:
        data = read_yaml(path)
    except ConfigError as exc:
        raise SpecError(str(exc)) from exc
    return parse_spec(data, str(path))
