"""Loading the part to measure and sampling its surface.

The planner works in mm: :func:`load_part` scales the file's unit to mm, merges unmerged vertices, applies a
rigid placement (translation in mm) and marks the downward faces (held by the fixture, not measurable).
:func:`sample_surface` spreads ``round(area * density)`` points evenly over the measurable faces (weighted
sample elimination, Yuksel 2015), seeded and reproducible.

Problems with the file raise :class:`PartLoadError` naming it; doubtful geometry (open mesh, triangle soup,
implausible size for the station) is reported with a :class:`PartWarning` and kept in
:attr:`LoadedPart.warnings`, because such parts can still be planned for.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import re
import sys
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from agiprobot_measurement.common import config
from agiprobot_measurement.common.limits import LIMITS, check_count, check_file_size, excerpt
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.errors import validated
from agiprobot_measurement.station import UNIT_SCALES_TO_M
from agiprobot_measurement.station.placement import fixture_placement

__all__ = [
    "MAX_COORDINATE",
    "MAX_PLACEMENT_MM",
    "MESH_SUFFIXES",
    "PLAUSIBLE_SIZE_MM",
    "STEP_SUFFIXES",
    "UNIT_SCALES_TO_MM",
    "LoadedPart",
    "PartLoadError",
    "PartWarning",
    "SurfaceSamples",
    "downward_faces",
    "load_part",
    "part_parameters",
    "place_part",
    "sample_surface",
    "validate_rigid_transform",
]

#: Millimetres per unit for the ``units`` argument of :func:`load_part`.
UNIT_SCALES_TO_MM = {unit: scale * 1000.0 for unit, scale in UNIT_SCALES_TO_M.items()}

#: Largest extent (mm) of a part the UR10e station can plausibly measure; outside it a warning suggests units.
PLAUSIBLE_SIZE_MM = (10.0, 2000.0)
#: vertex coordinates beyond this (file units) are refused: no part is that large, and squares of them overflow
MAX_COORDINATE = 1e12
#: a part placed farther than this from the world origin (mm) is refused: the station is a few metres across
MAX_PLACEMENT_MM = 1e5

MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
STEP_SUFFIXES = (".step", ".stp")
#: CAD exchange formats trimesh's own loader cannot tessellate (cascadio handles STEP only there)
UNREAD_CAD_SUFFIXES = (".iges", ".igs")
#: STEP geometry comes out of OpenCASCADE (through cascadio and GLB) in metres, whatever unit the file declares
STEP_SCALE_TO_MM = 1000.0


class PartLoadError(InputError):
    """The part file is missing, unreadable, of an unsupported format or holds no triangles."""


class PartWarning(UserWarning):
    """The part loaded but looks doubtful (open mesh, triangle soup, implausible size, ...)."""


@dataclass(frozen=True)
class SurfaceSamples:
    """Sampled surface points (N, 3) in mm, the index of the mesh face each lies on, and its unit normal."""

    points: np.ndarray
    face_ids: np.ndarray
    normals: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __iter__(self):
        return iter((self.points, self.face_ids, self.normals))


@dataclass
class LoadedPart:
    """A part placed in the world, in mm.

    ``mesh`` is the whole part (for collision checks and occlusion); ``measurable_faces`` the indices of its
    faces that are not facing downwards (what is sampled). ``scale_to_mm`` is the factor applied to the
    file's coordinates, ``transform`` the rigid placement applied after scaling.
    """

    path: Path
    mesh: trimesh.Trimesh
    measurable_faces: np.ndarray
    scale_to_mm: float
    transform: np.ndarray
    warnings: list[str] = field(default_factory=list)

    @property
    def measurable_mesh(self) -> trimesh.Trimesh:
        """The part without its downward faces (a copy)."""
        return self.mesh.submesh([self.measurable_faces], append=True, repair=False)

    @property
    def measurable_area(self) -> float:
        """Area (mm^2) of the measurable faces."""
        return float(self.mesh.area_faces[self.measurable_faces].sum())

    def sample(self, density: float, seed: int | None = 0, oversampling: int = 5) -> SurfaceSamples:
        """Sample the measurable faces with ``density`` points/mm^2 (see :func:`sample_surface`)."""
        return sample_surface(self.mesh, density, faces=self.measurable_faces, seed=seed, oversampling=oversampling)


def _warn(messages: list[str], text: str) -> None:
    messages.append(text)
    warnings.warn(text, PartWarning, stacklevel=3)


def validate_rigid_transform(transform, tolerance: float = 1e-6) -> np.ndarray:
    """Check a 4x4 homogeneous rigid transform (rotation + translation in mm); returns it as float array."""
    matrix = np.asarray(transform, dtype=float)
    if matrix.shape != (4, 4):
        raise PartLoadError(f"part transform must be a 4x4 matrix, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise PartLoadError("part transform contains NaN or infinite values")
    distance = float(np.max(np.abs(matrix[:3, 3])))
    if distance > MAX_PLACEMENT_MM:
        raise PartLoadError(
            f"part transform shifts the part by {distance:.3g} mm along an axis, more than "
            f"{MAX_PLACEMENT_MM:g} mm: the translation is in mm and the station is a few metres across"
        )
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=tolerance):
        raise PartLoadError(f"part transform's last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=tolerance) or np.linalg.det(rotation) < 0:
        raise PartLoadError(
            "part transform is not rigid: its 3x3 block must be a rotation (orthonormal, det +1); "
            "give the unit with the units/scale argument instead of scaling in the transform"
        )
    return matrix


def downward_faces(mesh: trimesh.Trimesh, remove_threshold_angle_deg: float = 20.0) -> np.ndarray:
    """Boolean mask of the faces whose normal lies within ``remove_threshold_angle_deg`` of world -z."""
    message = f"remove_threshold_angle_deg must lie in [0, 90] degrees, got {remove_threshold_angle_deg}"
    check = lambda: config.number(remove_threshold_angle_deg, "remove_threshold_angle_deg", 0.0, 90.0)  # noqa: E731
    threshold = validated(check, PartLoadError, message)
    normals = np.asarray(mesh.face_normals)
    # a small slack so that exactly downward faces count at a threshold of 0
    return -normals[:, 2] >= math.cos(math.radians(threshold)) - 1e-9


def _scale_from(units: str | None, scale: float | None, path: Path) -> float:
    if scale is not None:
        message = f"{path}: scale must be a positive number (mm per file unit), got {scale}"
        return validated(lambda: config.positive(scale, "scale"), PartLoadError, message)
    if units not in UNIT_SCALES_TO_MM:
        raise PartLoadError(f"{path}: unknown unit {units!r}; valid units: {', '.join(UNIT_SCALES_TO_MM)}")
    return UNIT_SCALES_TO_MM[units]


def _read_mesh(path: Path, tessellation_tolerance_mm: float = 0.0) -> trimesh.Trimesh:
    if not path.exists():
        raise PartLoadError(f"{path}: part file not found")
    if not path.is_file():
        raise PartLoadError(f"{path}: not a file")
    suffix = path.suffix.lower()
    options = {}
    if suffix in STEP_SUFFIXES:
        if importlib.util.find_spec("cascadio") is None:
            raise PartLoadError(
                f"{path}: STEP needs a converter and none is installed (trimesh reads STEP through the "
                "'cascadio' package: pip install cascadio); or export the part as STL, OBJ or PLY from CAD"
            )
        if tessellation_tolerance_mm and tessellation_tolerance_mm > 0:
            # OpenCASCADE tessellates in its working unit, mm: the linear deflection is a distance in mm
            options["tol_linear"] = float(tessellation_tolerance_mm)
        with path.open("rb") as handle:
            head = handle.read(64)
        if b"ISO-10303" not in head:
            raise PartLoadError(f"{path}: not a STEP file (no ISO-10303 header)")
        check_file_size(path, LIMITS.step_file_bytes, "STEP file")
    elif suffix in UNREAD_CAD_SUFFIXES:
        raise PartLoadError(
            f"{path}: IGES is not read here (trimesh's loader tessellates STEP through cascadio, not IGES); "
            "export the part as STEP, STL, OBJ or PLY"
        )
    elif suffix not in MESH_SUFFIXES:
        raise PartLoadError(
            f"{path}: unsupported part format {suffix or '(no suffix)'!r}; "
            f"supported: {', '.join(MESH_SUFFIXES + STEP_SUFFIXES)}"
        )
    else:
        check_file_size(path, LIMITS.mesh_file_bytes, "mesh file")
    console: list[str] = []
    try:
        with _native_console_captured(console) if suffix in STEP_SUFFIXES else contextlib.nullcontext():
            loaded = trimesh.load(str(path), force="mesh", process=False, **options)
    except Exception as exc:  # trimesh raises anything from ValueError to ModuleNotFoundError on bad files
        said = next((line.strip() for line in "".join(console).splitlines() if "ERR" in line), "")
        detail = f"; it says {excerpt(said, 120)}" if said else ""
        raise PartLoadError(f"{path}: {_read_failure(suffix, exc)}{detail}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise PartLoadError(f"{path}: the file holds no triangles")
    check_count(len(loaded.faces), LIMITS.mesh_faces, f"{path}: triangles of the part's mesh")
    with np.errstate(all="ignore"):
        finite = np.all(np.isfinite(loaded.vertices)) and np.all(np.abs(loaded.vertices) < MAX_COORDINATE)
    if not finite:
        raise PartLoadError(
            f"{path}: the mesh has NaN, infinite or absurd vertex coordinates (beyond {MAX_COORDINATE:g} file units)"
        )
    return loaded


#: terminal colour codes (OpenCASCADE colours its console messages)
_ANSI_CODES = re.compile(r"\x1b\[[0-9;]*m")
#: bytes of a converter's console output kept for an error message
_CONSOLE_KEPT_BYTES = 4096


@contextlib.contextmanager
def _native_console_captured(into: list[str]):
    """Capture what native code writes to file descriptors 1 and 2 (OpenCASCADE prints its STEP parse errors
    there, in colour, bypassing Python) into ``into`` (colour codes removed, at most :data:`_CONSOLE_KEPT_BYTES`),
    so that a user sees one clear error instead of the converter's console."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    with tempfile.TemporaryFile() as sink:
        for fd in saved:
            os.dup2(sink.fileno(), fd)
        try:
            yield into
        finally:
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            sink.seek(0)
            into.append(_ANSI_CODES.sub("", sink.read(_CONSOLE_KEPT_BYTES).decode("utf-8", "replace")))


def _read_failure(suffix: str, error: Exception) -> str:
    """What went wrong reading a part file, in words: the readers' own errors on a corrupt file name a missing
    text-decoding module (a binary STL or OBJ that is not one) or a converter's missing output (a STEP file
    OpenCASCADE could not parse)."""
    if suffix in STEP_SUFFIXES and isinstance(error, FileNotFoundError | OSError):
        return "cannot read the STEP file: OpenCASCADE could not parse it (corrupt, truncated or not AP203/AP214)"
    if isinstance(error, ImportError):
        return (
            f"cannot read the part: the file is not a valid {suffix.lstrip('.').upper()} file (corrupt or truncated?)"
        )
    return f"cannot read the part: {type(error).__name__}: {excerpt(str(error), 200)}"


def _check_geometry(mesh: trimesh.Trimesh, path: Path, messages: list[str], merged: bool) -> None:
    bodies = int(mesh.body_count)
    if bodies > max(1, len(mesh.faces) // 4):
        hint = "" if merged else " (unmerged vertices? load with merge_vertices=True)"
        _warn(
            messages,
            f"{path}: looks like a triangle soup ({len(mesh.faces)} faces in {bodies} disconnected pieces"
            f"{hint}): occlusion and collision checks may be unreliable",
        )
    elif not mesh.is_watertight:
        _warn(messages, f"{path}: the mesh is open (not watertight) even after merging vertices")
    if mesh.is_watertight:
        if not mesh.is_winding_consistent:
            trimesh.repair.fix_winding(mesh)
        if mesh.volume < 0:
            # an inside-out mesh would make every outward normal point into the part
            mesh.invert()
            _warn(messages, f"{path}: the mesh was inside out (negative volume); its faces were flipped")


def _check_size(mesh: trimesh.Trimesh, scale_to_mm: float, path: Path, messages: list[str]) -> None:
    size = float(np.max(mesh.extents))
    low, high = PLAUSIBLE_SIZE_MM
    if low <= size <= high:
        return
    raw = size / scale_to_mm
    fits = [unit for unit, mm in UNIT_SCALES_TO_MM.items() if unit != "in" and low <= raw * mm <= high]
    hint = f" did you mean {' or '.join(fits)}?" if fits else ""
    _warn(
        messages,
        f"{path}: the part is {size:.4g} mm across after scaling by {scale_to_mm:g} mm per unit, implausible "
        f"for the station ({low:g} to {high:g} mm);{hint}",
    )


def load_part(
    path,
    units: str | None = "mm",
    *,
    scale: float | None = None,
    transform=None,
    merge_vertices: bool = True,
    remove_downside: bool = True,
    remove_threshold_angle_deg: float = 20.0,
    tessellation_tolerance_mm: float = 0.0,
    checkpoint: Callable[[], None] | None = None,
) -> LoadedPart:
    """Load a part (STL, OBJ, PLY, OFF, glTF; STEP only with a STEP reader installed) into the world in mm.

    ``units``: the file's unit (one of :data:`UNIT_SCALES_TO_MM`: mm, cm, dm, m, inch/in, ft); or ``scale``:
    mm per file unit, which overrides ``units``. ``transform``: 4x4 rigid placement of the part in the world
    (translation in mm), applied after scaling; default identity. ``merge_vertices`` merges the duplicated
    vertices of STL files and drops degenerate and duplicate faces. ``remove_downside``: faces whose normal
    (in the world, after the transform) lies within ``remove_threshold_angle_deg`` degrees of -z are not
    measurable (the fixture holds the part from below); they stay in :attr:`LoadedPart.mesh`.
    STEP files (with ``cascadio`` installed) carry their unit: ``units`` and ``scale`` do not apply to them;
    ``tessellation_tolerance_mm`` is the linear deflection of their tessellation (0 = the reader's default).
    ``checkpoint()`` is called between the steps (a time limit's check may raise there).
    """
    checkpoint = checkpoint or (lambda: None)
    path = Path(path).expanduser()
    scale_to_mm = _scale_from(units, scale, path)
    placement = np.eye(4) if transform is None else validate_rigid_transform(transform)
    mesh = _read_mesh(path, tessellation_tolerance_mm)
    checkpoint()
    messages: list[str] = []
    if path.suffix.lower() in STEP_SUFFIXES:
        if scale is not None or units not in (None, "mm"):
            _warn(messages, f"{path}: a STEP file declares its own unit; the given unit/scale is not used")
        scale_to_mm = STEP_SCALE_TO_MM
    if merge_vertices:
        mesh.merge_vertices()
        mesh.update_faces(mesh.nondegenerate_faces())
        mesh.update_faces(mesh.unique_faces())
        mesh.remove_unreferenced_vertices()
        if len(mesh.faces) == 0:
            raise PartLoadError(f"{path}: every triangle of the mesh is degenerate")
        checkpoint()
    _check_geometry(mesh, path, messages, merge_vertices)
    checkpoint()
    mesh.apply_scale(scale_to_mm)
    _check_size(mesh, scale_to_mm, path, messages)
    mesh.apply_transform(placement)
    if remove_downside:
        measurable = np.flatnonzero(~downward_faces(mesh, remove_threshold_angle_deg))
    else:
        measurable = np.arange(len(mesh.faces))
    if measurable.size == 0:
        _warn(messages, f"{path}: every face faces downwards: nothing is left to measure")
    return LoadedPart(path, mesh, measurable, scale_to_mm, placement, messages)


def _random_points(mesh: trimesh.Trimesh, faces: np.ndarray, count: int, rng) -> tuple[np.ndarray, np.ndarray]:
    areas = mesh.area_faces[faces]
    chosen = faces[rng.choice(faces.size, size=count, p=areas / areas.sum())]
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    tri = mesh.triangles[chosen]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    return points, chosen


def _eliminate(points: np.ndarray, normals: np.ndarray, count: int, area: float) -> np.ndarray:
    """Indices of ``count`` of ``points`` chosen by weighted sample elimination (Yuksel 2015)."""
    total = points.shape[0]
    if count >= total:
        return np.arange(total)
    r_max = math.sqrt(area / (2.0 * math.sqrt(3.0) * count))
    pairs = cKDTree(points).query_pairs(2.0 * r_max, output_type="ndarray")
    first, second = pairs[:, 0], pairs[:, 1]
    # points on opposite sides of a thin wall are not neighbours on the surface
    same_side = np.einsum("ij,ij->i", normals[first], normals[second]) > -0.5
    first, second = first[same_side], second[same_side]
    distance = np.linalg.norm(points[first] - points[second], axis=1)
    weight = (1.0 - distance / (2.0 * r_max)) ** 8
    weights = np.bincount(first, weight, total) + np.bincount(second, weight, total)
    rows = np.concatenate([first, second])
    cols = np.concatenate([second, first])
    both = np.concatenate([weight, weight])
    order = np.argsort(rows, kind="stable")
    rows, cols, both = rows[order], cols[order], both[order]
    indptr = np.zeros(total + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=total), out=indptr[1:])

    # Yuksel removes the most crowded point, one at a time. Removing, in rounds, points more crowded than
    # all their remaining neighbours (ties broken by index) makes the same kind of choices but vectorises.
    alive = np.ones(total, dtype=bool)
    remaining = total
    empty_row = indptr[:-1] == indptr[1:]
    rank = np.empty(total, dtype=np.int64)
    while remaining > count:
        rank[np.lexsort((np.arange(total), weights))] = np.arange(total)
        neighbour_rank = np.where(alive[cols], rank[cols], -1)
        crowding = np.maximum.reduceat(np.append(neighbour_rank, -1), indptr[:-1])
        crowding[empty_row] = -1
        removed = np.flatnonzero(alive & (rank > crowding))
        # at most a quarter of the excess per round, most crowded first: close to the one-at-a-time
        # quality (nearest-neighbour distances within 2 %) at a fraction of its cost
        limit = max(1, (remaining - count) // 4)
        if removed.size > limit:
            removed = removed[np.argsort(-rank[removed])[:limit]]
        alive[removed] = False
        remaining -= removed.size
        dead = np.zeros(total, dtype=bool)
        dead[removed] = True
        edges = dead[rows]
        weights -= np.bincount(cols[edges], both[edges], minlength=total)
    return np.flatnonzero(alive)


def sample_surface(
    mesh: trimesh.Trimesh, density: float, *, faces=None, seed: int | None = 0, oversampling: int = 5
) -> SurfaceSamples:
    """Evenly spread ``round(area * density)`` points over ``faces`` of ``mesh`` (default: all faces).

    ``density`` in points/mm^2 (mesh in mm). Draws ``oversampling`` times as many uniform random points and
    eliminates the most crowded ones until the count is reached, so the points keep a near-constant spacing
    (Poisson-disk like). ``seed`` makes the result reproducible. Returns points (N, 3) mm, the face index of
    each point in ``mesh`` and the face's unit normal.
    """
    message = f"sampling density must be a positive number of points/mm^2, got {density}"
    density = validated(lambda: config.positive(density, "density"), PartLoadError, message)
    if int(oversampling) < 1:
        raise PartLoadError("oversampling must be >= 1")
    face_index = np.arange(len(mesh.faces)) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    face_index = face_index[mesh.area_faces[face_index] > 0.0]
    area = float(mesh.area_faces[face_index].sum())
    count = round(area * density)
    if count == 0:
        return SurfaceSamples(np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    rng = np.random.default_rng(seed)
    candidates, candidate_faces = _random_points(mesh, face_index, count * int(oversampling), rng)
    normals = np.asarray(mesh.face_normals)[candidate_faces]
    keep = _eliminate(candidates, normals, count, area)
    return SurfaceSamples(candidates[keep], candidate_faces[keep], normals[keep])


def place_part(
    file_name,
    scene,
    transform: np.ndarray,
    placement: str = "scene",
    units: str = "mm",
    remove_downside: bool = True,
    remove_threshold_angle_deg: float = 20.0,
    tessellation_tolerance_mm: float = 0.0,
    checkpoint: Callable[[], None] | None = None,
) -> LoadedPart:
    """Load a part and place it on the station: at ``scene``'s part pose times ``transform`` (4x4, translation
    mm), or (``placement='fixture'``) turned by that pose's rotation, its lowest point on the fixture's top and its
    bounding box centred over the fixture, then shifted by ``transform``'s translation. The mesh is in world mm."""
    transform = np.asarray(transform, dtype=float)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise PartLoadError(f"transform must be a finite 4x4 matrix, got shape {transform.shape}")
    placement_mm = np.eye(4)
    if scene.part is not None:
        placement_mm = scene.part.pose.copy()
        placement_mm[:3, 3] *= 1000.0
    world = placement_mm @ transform
    if placement == "fixture":
        turned = np.eye(4)
        turned[:3, :3] = world[:3, :3]
        world = turned
    part = load_part(
        file_name,
        units=units,
        transform=world,
        remove_downside=remove_downside,
        remove_threshold_angle_deg=remove_threshold_angle_deg,
        tessellation_tolerance_mm=tessellation_tolerance_mm,
        checkpoint=checkpoint,
    )
    if placement == "fixture":
        centred = fixture_placement(part.mesh.vertices, np.eye(3), scene)
        shift = centred[:3, 3] + placement_mm[:3, :3] @ transform[:3, 3]
        part.mesh.apply_translation(shift)
        moved = np.eye(4)
        moved[:3, 3] = shift
        part.transform = moved @ part.transform
    return part


def part_parameters(
    part: LoadedPart, file_name, units: str, add_wbk_mirrors, remove_downside, angle_deg, placement, seed: int
) -> dict:
    """The parameters a stored plan names its placed ``part`` by (``part_transform_mm``: file coordinates -> world
    mm, scale included) and the run's ``seed``."""
    return dict(
        part_file=str(Path(file_name).resolve()),
        units=units,
        add_wbk_mirrors=bool(add_wbk_mirrors),
        remove_downside=bool(remove_downside),
        remove_threshold_angle_deg=float(angle_deg),
        placement=placement,
        part_transform_mm=(part.transform @ np.diag([part.scale_to_mm] * 3 + [1.0])).reshape(-1).tolist(),
        seed=seed,
    )
