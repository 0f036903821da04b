"""The files of a 3D reconstruction, written as one set into one folder: ``cloud.ply`` (fused raw points),
``map.npz`` (+ ``map.bt`` with an OctoMap binding), ``mesh.ply`` (TSDF + marching cubes) and ``views.yaml``
(method, request, ROI, per-view poses, joints, gains and timings, the result).

The set is written into a hidden staging folder inside the output folder first and moved into place only when every
file was written, so a failure (a full disk) leaves the previous set untouched and no mixture of old and new files;
a file of an earlier set that the new set lacks (no points, no mesh) is removed when the new set is moved in."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.common.files import atomic_write, atomic_write_text

__all__ = ["OUTPUT_NAMES", "attach_outputs", "save_outputs"]

#: the files of one output set, by kind
OUTPUT_NAMES = {
    "cloud": "cloud.ply",
    "map": "map.npz",
    "octomap": "map.bt",
    "mesh": "mesh.ply",
    "log": "views.yaml",
}


def save_outputs(output_dir, voxel_map, tsdf, request, roi_min_m, roi_max_m, views, termination_reason: str = "",
                 result=None) -> dict[str, str]:  # fmt: skip
    """Write the files into ``output_dir`` (created); returns {kind: path}. ``tsdf``: the TSDF volume or None;
    ``views``: the view records; ``result``: the ReconstructionResult when there is one."""
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".outputs.", suffix=".tmp", dir=out))
    try:
        staged = _write_set(staging, voxel_map, tsdf, request, roi_min_m, roi_max_m, views, termination_reason, result)
        files = {}
        for kind, name in OUTPUT_NAMES.items():  # renames in one folder: they need no space
            if kind in staged:
                os.replace(staged[kind], out / name)
                files[kind] = str(out / name)
            else:
                (out / name).unlink(missing_ok=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return files


def _write_set(out: Path, voxel_map, tsdf, request, roi_min_m, roi_max_m, views, termination_reason, result) -> dict:
    """The files of the set written into ``out`` (the staging folder); {kind: path}."""
    files = {}
    cloud = out / "cloud.ply"
    if voxel_map.export_cloud_ply(cloud) > 0:
        files["cloud"] = str(cloud)
    files["map"] = str(voxel_map.save_npz(out / "map.npz"))
    if voxel_map.save_bt(out / "map.bt"):
        files["octomap"] = str(out / "map.bt")
    if tsdf is not None:
        mesh = tsdf.mesh()
        if mesh is not None and len(mesh.faces):
            atomic_write(out / "mesh.ply", lambda tmp: mesh.export(str(tmp), file_type="ply"), suffix=".ply")
            files["mesh"] = str(out / "mesh.ply")
    log = {
        "method": request.method,
        "termination_reason": termination_reason or (result.termination_reason if result else ""),
        "request": {
            k: (v.tolist() if isinstance(v, np.ndarray) else v)
            for k, v in request.__dict__.items()
            if k != "output_dir"
        },
        "roi_min_m": np.asarray(roi_min_m).tolist(),
        "roi_max_m": np.asarray(roi_max_m).tolist(),
        "views": [v.as_dict() for v in views],
    }
    if result is not None:
        log["result"] = {k: v for k, v in result.summary().items() if not k.endswith("_file")}
    log_path = out / "views.yaml"
    atomic_write_text(log_path, yaml.safe_dump(log, sort_keys=False, default_flow_style=None))
    files["log"] = str(log_path)
    return files


def attach_outputs(result, write: Callable[[], dict]) -> None:
    """Write the outputs with ``write()`` and name the files in ``result``; a failed write sets the result's
    ``outputs_error`` and is added to its error instead of raising (the run's measurements stay in the result;
    callers report the run as failed)."""
    try:
        files = write()
    except OSError as exc:
        result.outputs_error = f"writing the outputs failed (the folder keeps its previous files): {exc}"
        result.error = (result.error + "; " if result.error else "") + result.outputs_error
        files = {}
    result.cloud_file = files.get("cloud", "")
    result.mesh_file = files.get("mesh", "")
    result.map_file = files.get("map", "")
    result.log_file = files.get("log", "")
