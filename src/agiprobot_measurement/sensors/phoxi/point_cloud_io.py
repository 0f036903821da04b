"""Point-cloud files (binary PLY, PTX, float TIFF) written atomically.

Writers take organised (H, W, 3) or flat (N, 3) arrays in metres and write to a temporary file beside the target,
then rename it (:func:`agiprobot_measurement.common.files.atomic_write`), so a reader never sees half a file. Which
paths a client may name is the file policy's business (:class:`agiprobot_measurement.common.files.FileRoot`, used by
:mod:`agiprobot_measurement.sensors.phoxi.device`), not the writers'.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.files import PathPolicyError, atomic_write
from agiprobot_measurement.sensors.errors import PointCloudFormatError, PointCloudWriteError

__all__ = [
    "OutputPathError",
    "format_fixed_rows",
    "read_ply",
    "read_point_tiff",
    "write_ply",
    "write_point_tiff",
    "write_ptx",
]

#: the file policy's refusal; the old name stays importable for code that catches it
OutputPathError = PathPolicyError


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
            raise PointCloudFormatError(f"PLY property {name}: {len(values)} values for {len(points)} points")
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
        raise PointCloudFormatError(f"{path}: not a PLY file")
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
                raise PointCloudFormatError(f"{path}: list properties are not supported")
            elements[-1][2].append((words[2], _PLY_DTYPES[words[1]]))
    if not elements or elements[0][0] != "vertex":
        raise PointCloudFormatError(f"{path}: the first element must be 'vertex'")
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
#: rows formatted per block: bounds the formatter's scratch memory (about 100 bytes a row) whatever the frame size
_ROWS_PER_BLOCK = 1 << 18
#: beyond this magnitude the fixed-point formatter's int64 would overflow; such tables use printf formatting
_FIXED_POINT_LIMIT = 1e11
_ZERO, _MINUS, _DOT, _SPACE, _NEWLINE = (ord(c) for c in "0-. \n")


def format_fixed_rows(table: np.ndarray, decimals: Sequence[int]) -> bytes:
    """Rows of ``table`` (N, C) as text, column c with ``decimals[c]`` decimals, space-separated, one line a row:
    the bytes ``np.savetxt(fmt="%.{d}f ...")`` writes, formatted with array operations instead of per-row printf.

    Each column becomes fixed-width digit fields (sign, integer digits, point, decimals) built digit by digit for all
    rows at once; leading zeros and the sign of positive numbers are then dropped with one mask. Values are rounded
    half to even on their binary value times 10**d (exact for float32 data and d <= 6, hence printf's result).
    """
    table = np.asarray(table, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] != len(decimals):
        raise PointCloudFormatError(f"expected a table with {len(decimals)} columns, got shape {table.shape}")
    if len(table) == 0:
        return b""
    if not np.all(np.isfinite(table)) or np.abs(table).max() >= _FIXED_POINT_LIMIT:
        fmt = " ".join(f"%.{d}f" for d in decimals) + "\n"
        return "".join(fmt % tuple(row) for row in table.tolist()).encode("ascii")
    chars, keep = [], []
    rows = len(table)
    for column, d in enumerate(decimals):
        values = table[:, column]
        scaled = np.rint(np.abs(values) * 10.0**d).astype(np.int64)
        integer, fraction = np.divmod(scaled, 10**d)
        digits = len(str(int(integer.max())))
        width = 1 + digits + (1 + d if d else 0)
        field = np.empty((rows, width), dtype=np.uint8)
        shown = np.ones((rows, width), dtype=bool)
        field[:, 0] = _MINUS
        shown[:, 0] = np.signbit(values)  # printf shows the sign of -0.0 and of negatives rounded to zero
        significant = np.zeros(rows, dtype=bool)
        for j in range(digits):
            digit = (integer // 10 ** (digits - 1 - j)) % 10
            field[:, 1 + j] = _ZERO + digit
            if j < digits - 1:  # the last integer digit shows even when 0
                significant |= digit != 0
                shown[:, 1 + j] = significant
        if d:
            field[:, 1 + digits] = _DOT
            for j in range(d):
                field[:, 2 + digits + j] = _ZERO + (fraction // 10 ** (d - 1 - j)) % 10
        separator = np.full((rows, 1), _NEWLINE if column == len(decimals) - 1 else _SPACE, dtype=np.uint8)
        chars += [field, separator]
        keep += [shown, np.ones((rows, 1), dtype=bool)]
    return np.concatenate(chars, axis=1)[np.concatenate(keep, axis=1)].tobytes()


def write_ptx(path: str | Path, points: np.ndarray, intensity: np.ndarray, scanner_pose: np.ndarray | None = None):
    """Leica PTX (ASCII) of an organised cloud (H, W, 3) in metres with intensities in [0, 1], written atomically.

    PTX lists points column by column; missing points are ``0 0 0 0``. The header holds the scanner's position,
    axes and a 4x4 transform (``scanner_pose``, identity when points are already in the scanner frame). Points are
    written with 6 decimals (micrometres), intensities with 4, formatted block by block with
    :func:`format_fixed_rows` (a 2064 x 1544 frame in well under 2 s; per-row printf took 5 to 13 s).
    """
    points = np.asarray(points)
    if points.ndim != 3 or points.shape[2] != 3:
        raise PointCloudFormatError("PTX needs an organised cloud (H, W, 3)")
    height, width = points.shape[:2]
    pose = np.eye(4) if scanner_pose is None else np.asarray(scanner_pose, dtype=float)
    intensity = np.asarray(intensity)
    if intensity.shape != (height, width):
        raise PointCloudFormatError(f"PTX intensity must be ({height}, {width}), got {intensity.shape}")
    header = [str(width), str(height), " ".join(f"{v:.6f}" for v in pose[:3, 3])]
    header += [" ".join(f"{v:.6f}" for v in pose[:3, i]) for i in range(3)]
    header += [" ".join(f"{v:.6f}" for v in row) for row in pose.T]
    # column by column: transposing the (H, W) grid lists each image column's points top to bottom
    by_column = points.transpose(1, 0, 2).reshape(-1, 3)
    intensity_by_column = intensity.T.reshape(-1)

    def write(tmp: Path) -> None:
        with tmp.open("wb") as stream:
            stream.write(("\n".join(header) + "\n").encode("ascii"))
            for start in range(0, len(by_column), _ROWS_PER_BLOCK):
                block = np.empty((min(_ROWS_PER_BLOCK, len(by_column) - start), 4))
                block[:, :3] = by_column[start : start + len(block)]
                block[:, 3] = intensity_by_column[start : start + len(block)]
                stream.write(format_fixed_rows(block, (6, 6, 6, 4)))

    return atomic_write(path, write, make_parents=True)


# ------------------------------------------------------------------------------------------------ TIFF
def write_point_tiff(path: str | Path, points: np.ndarray) -> Path:
    """Organised cloud (H, W, 3) as a 3-sample 32-bit float TIFF, samples in the order x, y, z (metres)."""
    import cv2

    points = np.asarray(points, dtype=np.float32)
    if points.ndim != 3 or points.shape[2] != 3:
        raise PointCloudFormatError("TIFF needs an organised cloud (H, W, 3)")

    def write(tmp: Path) -> None:
        # OpenCV stores 3-channel images as RGB from its BGR order: reverse so the file holds x, y, z. LZW is
        # named explicitly: OpenCV 4's default for 3-channel float is the lossy SGI LogLuv coding.
        lossless = [cv2.IMWRITE_TIFF_COMPRESSION, 5]
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(points[:, :, ::-1]), lossless):
            raise PointCloudWriteError(f"OpenCV could not write {tmp}")

    return atomic_write(path, write, suffix=Path(path).suffix, make_parents=True)


def read_point_tiff(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 x, y, z from :func:`write_point_tiff`."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise PointCloudFormatError(f"{path}: not a readable TIFF")
    return image[:, :, ::-1]
