"""Point-cloud files (binary PLY, PTX, float TIFF) written atomically, and output paths confined to one directory.

Writers take organised (H, W, 3) or flat (N, 3) arrays in metres and write to a temporary file beside the target,
then rename it, so a reader never sees half a file. :func:`resolve_output_path` is the one gate for requested paths:
``~`` expands to the home directory, relative paths are taken relative to the output directory, and anything that
resolves (symlinks included) outside the output directory is refused with :class:`OutputPathError`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.common.files import atomic_write
from agiprobot_measurement.errors import InputError

__all__ = [
    "OutputPathError",
    "read_ply",
    "read_point_tiff",
    "resolve_output_path",
    "write_ply",
    "write_point_tiff",
    "write_ptx",
]


class OutputPathError(InputError):
    """A requested output path is empty, a directory, or outside the configured output directory."""


def resolve_output_path(output_dir: str | Path, requested: str | Path) -> Path:
    """The absolute file path for ``requested`` if it lies inside ``output_dir``; else :class:`OutputPathError`."""
    if requested is None or not str(requested).strip():
        raise OutputPathError("empty path")
    root = Path(output_dir).expanduser().resolve()
    path = Path(str(requested).strip()).expanduser()
    if not path.is_absolute():
        path = root / path
    resolved = path.resolve()
    if resolved == root or not resolved.is_relative_to(root):
        raise OutputPathError(f"refused: {requested} resolves to {resolved}, outside the output directory {root}")
    if resolved.is_dir():
        raise OutputPathError(f"refused: {resolved} is a directory; give a file name")
    return resolved


# ------------------------------------------------------------------------------------------------- PLY
_PLY_TYPES = {
    "f4": "float",
    "f8": "double",
    "u1": "uchar",
    "i1": "char",
    "u2": "ushort",
    "i2": "short",
    "u4": "uint",
    "i4": "int",
}
_PLY_DTYPES = {
    **{v: k for k, v in _PLY_TYPES.items()},
    "float32": "f4",
    "float64": "f8",
    "uint8": "u1",
    "int8": "i1",
    "uint16": "u2",
    "int16": "i2",
    "uint32": "u4",
    "int32": "i4",
}


def write_ply(
    path: str | Path,
    points: np.ndarray,
    normals: np.ndarray | None = None,
    scalars: dict | None = None,
    comments: tuple[str, ...] = (),
) -> Path:
    """Binary little-endian PLY of vertices x y z [nx ny nz] [scalars...] (float32), written atomically.

    ``points`` (N, 3) or (H, W, 3); ``scalars`` maps a property name to an array of N (or H x W) values.
    """
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    fields = [("x", points[:, 0]), ("y", points[:, 1]), ("z", points[:, 2])]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        fields += [("nx", normals[:, 0]), ("ny", normals[:, 1]), ("nz", normals[:, 2])]
    for name, values in (scalars or {}).items():
        fields.append((name, np.asarray(values, dtype=np.float32).reshape(-1)))
    for name, values in fields:
        if len(values) != len(points):
            raise ValueError(f"PLY property {name}: {len(values)} values for {len(points)} points")
    table = np.empty(len(points), dtype=[(name, "<f4") for name, _ in fields])
    for name, values in fields:
        table[name] = values
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" for c in comments]
    header.append(f"element vertex {len(points)}")
    header += [f"property float {name}" for name, _ in fields]
    header.append("end_header")

    def write(tmp: Path) -> None:
        with tmp.open("wb") as stream:
            stream.write(("\n".join(header) + "\n").encode("ascii"))
            stream.write(table.tobytes())

    return atomic_write(path, write, make_parents=True)


def read_ply(path: str | Path) -> dict:
    """Vertex properties of a PLY file (binary little/big endian or ASCII) as arrays; ``comments`` as a list."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    body_start = data.index(b"\n", end) + 1
    lines = data[:end].decode("ascii").splitlines()
    fmt, comments, elements = None, [], []
    for line in lines[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment":
            comments.append(line[len("comment ") :])
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if words[1] == "list":
                raise ValueError(f"{path}: list properties are not supported")
            elements[-1][2].append((words[2], _PLY_DTYPES[words[1]]))
    if not elements or elements[0][0] != "vertex":
        raise ValueError(f"{path}: the first element must be 'vertex'")
    _, count, props = elements[0]
    if fmt == "ascii":
        values = np.loadtxt(data[body_start:].decode("ascii").splitlines()[:count], ndmin=2)
        result = {name: values[:, i].astype(dtype) for i, (name, dtype) in enumerate(props)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + code) for name, code in props])
        table = np.frombuffer(data, dtype=dtype, count=count, offset=body_start)
        result = {name: table[name].astype(table[name].dtype.newbyteorder("=")) for name, _ in props}
    result["comments"] = comments
    return result


# ------------------------------------------------------------------------------------------------- PTX
def write_ptx(path: str | Path, points: np.ndarray, intensity: np.ndarray, scanner_pose: np.ndarray | None = None):
    """Leica PTX (ASCII) of an organised cloud (H, W, 3) in metres with intensities in [0, 1], written atomically.

    PTX lists points column by column; missing points are ``0 0 0 0``. The header holds the scanner's position,
    axes and a 4x4 transform (``scanner_pose``, identity when points are already in the scanner frame).
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError("PTX needs an organised cloud (H, W, 3)")
    height, width = points.shape[:2]
    pose = np.eye(4) if scanner_pose is None else np.asarray(scanner_pose, dtype=float)
    columns = np.concatenate([points, np.asarray(intensity, dtype=np.float64)[:, :, None]], axis=2)
    table = columns.transpose(1, 0, 2).reshape(-1, 4)
    header = [str(width), str(height), " ".join(f"{v:.6f}" for v in pose[:3, 3])]
    header += [" ".join(f"{v:.6f}" for v in pose[:3, i]) for i in range(3)]
    header += [" ".join(f"{v:.6f}" for v in row) for row in pose.T]

    def write(tmp: Path) -> None:
        with tmp.open("w") as stream:
            stream.write("\n".join(header) + "\n")
            np.savetxt(stream, table, fmt="%.6f %.6f %.6f %.4f")

    return atomic_write(path, write, make_parents=True)


# ------------------------------------------------------------------------------------------------ TIFF
def write_point_tiff(path: str | Path, points: np.ndarray) -> Path:
    """Organised cloud (H, W, 3) as a 3-sample 32-bit float TIFF, samples in the order x, y, z (metres)."""
    import cv2

    points = np.asarray(points, dtype=np.float32)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError("TIFF needs an organised cloud (H, W, 3)")

    def write(tmp: Path) -> None:
        # OpenCV stores 3-channel images as RGB from its BGR order: reverse so the file holds x, y, z
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(points[:, :, ::-1])):
            raise OSError(f"OpenCV could not write {tmp}")

    return atomic_write(path, write, suffix=Path(path).suffix, make_parents=True)


def read_point_tiff(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 x, y, z from :func:`write_point_tiff`."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: not a readable TIFF")
    return image[:, :, ::-1]
