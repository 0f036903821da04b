"""One inspection as a request (:class:`InspectionRequest`): the cloud (a file, or points in hand), the nominal mesh
file, the spec file, the planned placement, the cloud's unit and the report folder; :func:`run_inspection` reads,
checks, inspects and writes the report. The command line (``cli``) and the ROS action both go through it. Every bad
input is an :class:`InspectionInputError` raised before the report folder is touched.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty
from agiprobot_measurement.inspection.pipeline import InspectionResult, inspect_cloud
from agiprobot_measurement.inspection.report import write_report
from agiprobot_measurement.inspection.spec import UNITS, load_spec
from agiprobot_measurement.sensors.errors import PointCloudFormatError
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

__all__ = ["InspectionRequest", "placement_from_values", "read_cloud", "read_nominal", "read_placement",
           "run_inspection"]  # fmt: skip


def read_cloud(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) points and (N,) noise sigma (or None) from a PLY, .npy or text file."""
    path = Path(path)
    if not path.is_file():
        raise InspectionInputError(f"cloud file not found: {path}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".ply":
            data = read_ply(path)
            if not {"x", "y", "z"} <= set(data):
                raise InspectionInputError(f"{path}: the PLY has no x y z vertex properties")
            points = np.stack([data["x"], data["y"], data["z"]], axis=1).astype(float)
            return points, np.asarray(data["sigma"], float) if "sigma" in data else None
        table = (
            np.load(path)
            if suffix == ".npy"
            else np.loadtxt(path, delimiter="," if suffix == ".csv" else None, ndmin=2)
        )
    except (OSError, ValueError, PointCloudFormatError, UnicodeDecodeError) as exc:
        raise InspectionInputError(f"{path}: cannot read a point cloud ({exc})") from exc
    table = np.asarray(table, dtype=float)
    if table.ndim != 2 or table.shape[1] not in (3, 4):
        raise InspectionInputError(f"{path}: expected N x 3 (or N x 4 with sigma) numbers, got shape {table.shape}")
    return table[:, :3], table[:, 3] if table.shape[1] == 4 else None


def read_nominal(path: str | Path) -> trimesh.Trimesh:
    path = Path(path)
    if not path.is_file():
        raise InspectionInputError(f"nominal model not found: {path}")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:
        raise InspectionInputError(f"{path}: cannot read a mesh ({exc})") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) < 4:
        raise InspectionInputError(f"{path}: not a triangle mesh with at least 4 faces")
    return mesh


def read_placement(text: str | None) -> np.ndarray:
    """The planned world <- part pose: None (identity), 'x,y,z' or a YAML/JSON file holding a 4x4 matrix."""
    if text is None:
        return np.eye(4)
    if Path(text).is_file():
        try:
            data = read_yaml(text)
        except ConfigError as exc:
            raise InspectionInputError(str(exc)) from exc
        matrix = np.asarray(data.get("placement", data) if isinstance(data, dict) else data, dtype=float)
        if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
            raise InspectionInputError(f"{text}: the placement must be a finite 4x4 matrix")
        return matrix
    try:
        xyz = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise InspectionInputError(f"--placement {text!r}: neither a file nor 'x,y,z'") from exc
    if len(xyz) != 3:
        raise InspectionInputError(f"--placement {text!r}: give three numbers x,y,z")
    pose = np.eye(4)
    pose[:3, 3] = xyz
    return pose


def placement_from_values(values) -> np.ndarray:
    """The placement from a flat list: empty (identity), 3 values (a translation) or 16 (a row-major 4x4)."""
    values = np.asarray(list(values), dtype=float)
    if not np.all(np.isfinite(values)):
        raise InspectionInputError("placement: values must be finite")
    if values.size == 0:
        return np.eye(4)
    if values.size == 3:
        pose = np.eye(4)
        pose[:3, 3] = values
        return pose
    if values.size == 16:
        pose = values.reshape(4, 4)
        if not np.allclose(pose[3], (0.0, 0.0, 0.0, 1.0)):
            raise InspectionInputError("placement: the last row of the 4x4 matrix must be 0 0 0 1")
        return pose
    raise InspectionInputError(f"placement: give 0, 3 or 16 values, not {values.size}")


@dataclass(frozen=True)
class InspectionRequest:
    """What to inspect: ``points`` (N, 3) with optional ``sigma`` (N,) in hand, else ``cloud_file``; the cloud's unit
    ``cloud_units`` ('' = the spec's); ``placement`` the planned world <- part pose (spec unit); ``meta`` goes into
    the report; ``instrument`` the scanner's systematic uncertainty terms (:mod:`.instrument`)."""

    nominal_file: str | Path
    spec_file: str | Path
    out_dir: str | Path
    cloud_file: str | Path = ""
    points: np.ndarray | None = None
    sigma: np.ndarray | None = None
    placement: np.ndarray | None = None
    cloud_units: str = ""
    overwrite: bool = False
    meta: dict | None = None
    instrument: InstrumentUncertainty | None = None  # the scanner's systematic terms (None: noise only)


def run_inspection(
    request: InspectionRequest, progress: Callable[[str, float], None] | None = None
) -> tuple[InspectionResult, Path]:
    """(the result, the report folder) of ``request``; the folder is checked before any work starts. ``progress``
    gets the pipeline's stages (:data:`~.pipeline.STAGES`), then ``report`` while the report is written."""
    out = Path(request.out_dir).absolute()
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not request.overwrite)):
        raise InspectionInputError(f"output folder {out} exists and is not empty (overwrite replaces it)")
    if request.cloud_units and request.cloud_units not in UNITS:
        raise InspectionInputError(f"cloud units {request.cloud_units!r}: use one of {', '.join(UNITS)}")
    spec = load_spec(request.spec_file)
    nominal = read_nominal(request.nominal_file)
    if request.points is not None:
        points = np.asarray(request.points, dtype=float)
        sigma = None if request.sigma is None else np.asarray(request.sigma, dtype=float)
    else:
        points, sigma = read_cloud(request.cloud_file)
    if request.cloud_units:
        factor = UNITS[request.cloud_units] / spec.unit_scale_to_mm
        points = points * factor
        sigma = None if sigma is None else sigma * factor
    placement = np.eye(4) if request.placement is None else np.asarray(request.placement, dtype=float)
    result = inspect_cloud(points, nominal, spec, placement, sigma, progress, request.instrument)
    if progress is not None:
        progress("report", 0.0)
    meta = dict(request.meta or {}, nominal=str(request.nominal_file), spec=str(request.spec_file))
    return result, write_report(result, out, meta, overwrite=request.overwrite)
