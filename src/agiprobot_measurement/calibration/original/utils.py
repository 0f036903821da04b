"""The original calibration's ``utils.py`` (its documented Code API): point pairs, the data file, random draws.

Same names, inputs and outputs as documented; the data file is this project's reader and writer
(:func:`~agiprobot_measurement.calibration.registration.read_data_file` reads the original's layout and the
project's; :func:`write_data` writes the original's blocks), the determinant check is
:func:`~agiprobot_measurement.calibration.registration.direct_linear`'s. Matrices are ``numpy.matrix`` as in the
original (``H.I``, ``*`` products keep working), points in metres.

Where the documentation and the original code disagree, the documentation is followed and the difference is named
in the function's docstring (``read_data`` outputs, ``get_rand_list``'s ``num_points``).
"""

from __future__ import annotations

import random
import warnings
from pathlib import Path

import numpy as np

from agiprobot_measurement.calibration.registration import (
    CalibrationError,
    direct_linear,
    homogeneous,
    original_block,
    original_matrix_rows,
    original_pair_block,
    parse_data_text,
    read_data_file,
    read_flag_points,
)
from agiprobot_measurement.common.files import atomic_write_text, read_text_file
from agiprobot_measurement.common.geometry import matrix_to_rpy
from agiprobot_measurement.common.limits import excerpt

__all__ = [
    "DATA_TYPES",
    "H2trans_rot",
    "PointPair",
    "as_matrix",
    "get_point_pair_list",
    "get_rand_list",
    "point_valid_check",
    "pp2mat",
    "print_point_list",
    "print_point_pair_list",
    "read_data",
    "write_data",
]

#: the ``type`` values of :func:`write_data` (``mat`` = ``H``, ``vec`` = ``criteria``) and :func:`read_data`
DATA_TYPES = ("point_pair", "H", "mat", "vec", "criteria", "target")

#: the design note's spelling of "point_pair", accepted too
_TYPE_ALIASES = {"piont_pair": "point_pair"}

#: draws of :func:`get_rand_list` that may fail the determinant check before it gives up (the original's 10)
MAX_FAILED_DRAWS = 10


def as_matrix(values) -> np.matrix:
    """``numpy.matrix`` of ``values`` (the original's type), without numpy's pending-deprecation warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        return np.asmatrix(np.asarray(values, dtype=float))


class PointPair:
    """Corresponding 3-DoF flange positions: ``p_robot`` (robot base frame) and ``p_camera`` (camera frame),
    metres, and an ``index`` (999 when not given, as the original)."""

    def __init__(self, p_robot, p_camera, index=999):
        self.p_robot = p_robot
        self.p_camera = p_camera
        self.index = index

    def __repr__(self) -> str:
        return f"PointPair(p_robot={list(self.p_robot)}, p_camera={list(self.p_camera)}, index={self.index!r})"


def pp2mat(point_pair_list) -> tuple[np.matrix, np.matrix]:
    """(p_camera_mat, p_robot_mat): 4 x N matrices whose columns are the pairs' homogeneous points."""
    if not len(point_pair_list):
        raise CalibrationError("pp2mat: the point pair list is empty")
    p_camera = homogeneous([np.asarray(pp.p_camera, dtype=float)[:3] for pp in point_pair_list]).T
    p_robot = homogeneous([np.asarray(pp.p_robot, dtype=float)[:3] for pp in point_pair_list]).T
    return as_matrix(p_camera), as_matrix(p_robot)


def _point_text(values) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=float).reshape(-1)]


def write_data(data_path, data, title=None, type="mat"):
    """Append one block to the data file, laid out as the original writer does (a blank line and a line holding one
    space after it); the file is rewritten atomically, so a reader never sees half a block.

    ``type``:
      - ``"point_pair"`` (also the note's ``"piont_pair"``): ``data`` = [p_robot, p_camera], ``title`` = the index;
        p_robot: 3 values (position) or 7 (x, y, z, qx, qy, qz, qw, written as ``p_robot 6-DoF``), p_camera: 3.
      - ``"H"`` / ``"mat"``: a matrix, one ``[a, b, c, d, ]`` line per row, under ``title`` (default ``H``).
      - ``"criteria"`` / ``"vec"``: ``title`` (``criteria:plane`` / ``criteria:line``, or the seed's
        ``circle:plane`` / ``circle:line``) and ``data`` on the next line (criteria: an integer point count).

    A block the reader would refuse (a NaN or infinite value, an index or title with spaces or line breaks, a title
    the reader does not know) is refused with a :class:`CalibrationError` before anything is written, so the file
    stays readable: one bad sample cannot make the earlier ones unreadable.
    """
    path = Path(data_path)
    type = _TYPE_ALIASES.get(type, type)
    if type == "point_pair":
        try:
            p_robot, p_camera = data
        except (TypeError, ValueError) as exc:
            raise CalibrationError("write_data(type='point_pair') needs data = [p_robot, p_camera]") from exc
        p_robot, p_camera = _point_text(p_robot), _point_text(p_camera)
        if len(p_robot) not in (3, 7) or len(p_camera) != 3:
            raise CalibrationError(
                f"write_data: p_robot needs 3 or 7 values, p_camera 3 (got {len(p_robot)} and {len(p_camera)})"
            )
        if title is None:
            raise CalibrationError("write_data(type='point_pair') needs the index as title")
        block = original_pair_block(str(title), p_robot, p_camera)
    elif type in ("H", "mat"):
        matrix = np.asarray(data, dtype=float)
        if matrix.ndim != 2:
            raise CalibrationError(f"write_data(type={excerpt(type)}) needs a matrix, got shape {matrix.shape}")
        block = original_block(title or "H", original_matrix_rows(matrix))
    elif type in ("criteria", "vec"):
        if not title:
            raise CalibrationError(f"write_data(type={excerpt(type)}) needs a title, e.g. 'criteria:plane'")
        if type == "criteria":
            value = str(int(data))
        elif np.ndim(data):
            value = "[" + ", ".join(repr(v) for v in _point_text(data)) + "]"
        else:
            value = repr(data)
        block = original_block(str(title), [value])
    else:
        raise CalibrationError(f"write_data: type must be one of {', '.join(DATA_TYPES[:-1])}, got {excerpt(type)}")
    try:
        parse_data_text(block, f"write_data({excerpt(type)}, title {excerpt(title)})")
    except CalibrationError as exc:
        raise CalibrationError(f"{exc}; nothing written to {path}") from exc
    existing = read_text_file(path, "data file") if path.is_file() else ""
    return atomic_write_text(path, existing + block, make_parents=True)


def read_data(data_path, type):
    """Read one kind of data from a data file (the original's layout or the project's).

    ``type``:
      - ``"point_pair"``: [p_robot_list, p_camera_list] (3-DoF positions, as documented; the original code returned
        (index_list, p_camera_list, p_robot_list), :func:`get_point_pair_list` gives the indices);
      - ``"H"``: the first H of the file as a 4x4 ``numpy.matrix`` (H_coarse, else H_final / H);
      - ``"target"``: the flag points of a target file, a list of [x, y, z] (at least 4, not coplanar);
      - ``"criteria"``: [criteria_plane, criteria_line] (as documented; the smallest of the flag points'), None
        when the file holds none.
    """
    type = _TYPE_ALIASES.get(type, type)
    if type == "target":
        return read_flag_points(data_path).tolist()
    data = read_data_file(data_path)
    if type == "point_pair":
        return [[s.p_robot_m.copy() for s in data.samples], [s.p_camera_m.copy() for s in data.samples]]
    if type == "H":
        matrix = data.h_coarse if data.h_coarse is not None else data.h_final
        if matrix is None:
            raise CalibrationError(f"{data_path}: no H_coarse, H_final or H block")
        return as_matrix(matrix)
    if type == "criteria":
        if data.criteria_plane is None or data.criteria_line is None:
            return None
        return [data.criteria_plane, data.criteria_line]
    raise CalibrationError(f"read_data: type must be point_pair, H, target or criteria, got {excerpt(type)}")


def get_point_pair_list(data_path) -> list[PointPair]:
    """The data file's pairs as :class:`PointPair` s, indexed 0, 1, ... in file order (as the original)."""
    data = read_data_file(data_path)
    return [PointPair(s.p_robot_m.copy(), s.p_camera_m.copy(), i) for i, s in enumerate(data.samples)]


def print_point_pair_list(point_pair_list) -> None:
    """Print every pair: ``r:<p_robot> c:<p_camera> i:<index>``."""
    for pp in point_pair_list:
        print(
            f"r:{list(np.asarray(pp.p_robot, dtype=float))} c:{list(np.asarray(pp.p_camera, dtype=float))} i:{pp.index}"
        )


#: the original code's name of :func:`print_point_pair_list`
print_point_list = print_point_pair_list


def point_valid_check(point_pair_list, num_list=None):
    """(p_camera, p_robot) homogeneous 4 x N matrices of the pairs (those at ``num_list`` when given), or False
    when exactly 4 are chosen and they are (nearly) coplanar: |det(p_camera)| <= 1e-6, the check of
    :func:`~agiprobot_measurement.calibration.registration.direct_linear`."""
    chosen = [point_pair_list[k] for k in num_list] if num_list else list(point_pair_list)
    p_camera, p_robot = pp2mat(chosen)
    if len(chosen) == 4 and direct_linear(p_camera[:3].T, p_robot[:3].T) is None:
        return False
    return p_camera, p_robot


def get_rand_list(point_pair_list, num_points=4, exact_list=None, num_point=None):
    """(p_camera, p_robot) of ``num_points`` distinct pairs drawn at random (``exact_list``: those indices first),
    checked by :func:`point_valid_check`; a failed check draws again, False after more than 10 failures.

    ``num_point`` is the original code's spelling of ``num_points`` (the documentation's).
    """
    count = int(num_point if num_point is not None else num_points)
    if count < 4:
        raise CalibrationError(f"get_rand_list: at least 4 points are needed, got {count}")
    if count > len(point_pair_list):
        raise CalibrationError(f"get_rand_list: {count} points asked for, the list has {len(point_pair_list)}")
    failures = 0
    draw = list(exact_list) if exact_list else None
    while True:
        if draw is None:
            draw = random.sample(range(len(point_pair_list)), count)
        result = point_valid_check(point_pair_list, num_list=draw)
        if result:
            return result
        failures += 1
        if failures > MAX_FAILED_DRAWS:
            return False
        draw = None


def H2trans_rot(H):
    """(trans, rot) of H: the translation [x, y, z] (metres) and the rotation as static x-y-z Euler angles
    (roll, pitch, yaw, rad; tf's ``sxyz``)."""
    h = np.asarray(H, dtype=float)
    return [float(v) for v in h[:3, 3]], tuple(float(v) for v in matrix_to_rpy(h[:3, :3]))
