"""The command line's work (``scripts/inspect_cloud.py``): read the cloud, nominal, spec and placement, or build a
simulated demo case; inspect; write the report. Every bad input is an :class:`InspectionInputError` raised
before the report folder is touched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.inspection.cases import build_case
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.pipeline import inspect_cloud
from agiprobot_measurement.inspection.report import write_report
from agiprobot_measurement.inspection.spec import UNITS, load_spec
from agiprobot_measurement.sensors.errors import PointCloudFormatError
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

__all__ = ["inspect_command", "read_cloud", "read_nominal", "read_placement"]


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


def _demo(text: str, sensor: str):
    fields = text.split(":")
    try:
        magnitude = float(fields[1]) if len(fields) > 1 else 0.0
        seed = int(fields[2]) if len(fields) > 2 else 0
    except ValueError as exc:
        raise InspectionInputError(f"--demo {text!r}: use CASE[:MAGNITUDE[:SEED]]") from exc
    case = build_case(fields[0], magnitude, seed, sensor)
    meta = {"demo": fields[0], "magnitude": magnitude, "seed": seed, "sensor": sensor, "truth": case.truth}
    return case.points_mm, case.sigma_mm, case.nominal, case.spec, case.part.nominal_placement, meta


def inspect_command(args, progress=None):
    """(InspectionResult, report folder) for the parsed command line ``args``."""
    out = Path(args.out).absolute()
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not args.overwrite)):
        raise InspectionInputError(f"--out {out} exists and is not empty (--overwrite replaces it)")
    if args.demo:
        points, sigma, nominal, spec, placement, meta = _demo(args.demo, args.sensor)
    else:
        if not (args.cloud and args.nominal and args.spec):
            raise InspectionInputError("give CLOUD, --nominal and --spec (or --demo CASE)")
        spec = load_spec(args.spec)
        points, sigma = read_cloud(args.cloud)
        nominal = read_nominal(args.nominal)
        placement = read_placement(args.placement)
        if args.sigma is not None:
            sigma = np.full(len(points), float(args.sigma))
        if args.cloud_units:
            factor = UNITS[args.cloud_units] / spec.unit_scale_to_mm
            points = points * factor
            sigma = None if sigma is None else sigma * factor
        meta = {"cloud": str(args.cloud), "nominal": str(args.nominal), "spec": str(args.spec)}
    result = inspect_cloud(points, nominal, spec, placement, sigma, progress)
    return result, write_report(result, out, meta, overwrite=args.overwrite)
