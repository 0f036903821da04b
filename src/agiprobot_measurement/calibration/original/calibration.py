"""The original calibration's ``calibration.py`` (its documented Code API): circle fitting on saved point clouds, the
acceptance criteria, the RANSAC calibration of a data file.

Same names, inputs and outputs as documented, on this project's implementation: the flange centre is
:func:`~agiprobot_measurement.calibration.flange_detection.detect_flange` (crop, outlier removal, plane
segmentation, clustering, RANSAC circle of the flange's radius) on the PLY the camera saved, read with
:mod:`~agiprobot_measurement.sensors.phoxi.point_cloud_io`; the criteria are
:class:`~agiprobot_measurement.calibration.session.CalibrationSession`'s (0.75 x plane points, 0.5 x circle inliers
of the smallest flag point); the calibration is
:func:`~agiprobot_measurement.calibration.registration.calibrate` (4-pair direct linear draws, all C(n, 4) up to 495,
then Umeyama with a proper rotation and a robust refinement over the inliers). What the original left unfinished
("least square and SVD remained to be finished") is the SVD solution here. As in the original, the utils names are
importable from this module too. Metres throughout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.calibration.config import load_calibration_config
from agiprobot_measurement.calibration.flange_detection import FlangeDetection, FlangeDetectorConfig, detect_flange
from agiprobot_measurement.calibration.original.utils import (
    PointPair,
    as_matrix,
    get_point_pair_list,
    get_rand_list,
    point_valid_check,
    pp2mat,
    print_point_pair_list,
    read_data,
    write_data,
)
from agiprobot_measurement.calibration.registration import (
    CalibrationData,
    CalibrationError,
    direct_linear,
    umeyama,
)
from agiprobot_measurement.calibration.registration import (
    calibrate as register,
)
from agiprobot_measurement.calibration.session import CalibrationSession, detector_config
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

__all__ = [
    "DATA_FILE_NAME",
    "PointPair",
    "calibrate",
    "circle_feasibility_exam",
    "circle_fitting",
    "detector",
    "fit_flange",
    "get_calibrate",
    "get_point_pair_list",
    "get_rand_list",
    "judge_fit",
    "load_point_cloud",
    "point_valid_check",
    "pose_diff",
    "pp2mat",
    "print_point_pair_list",
    "ransac",
    "read_data",
    "write_data",
]

#: the data file circle_fitting reads and writes the criteria in when none is given: next to the point clouds
DATA_FILE_NAME = "data.txt"

#: every draw of the direct linear solution takes 4 pairs
DRAW_SIZE = 4

#: all C(n, 4) draws are tried up to this many (n <= 12), random ones beyond
ENUMERATE_DRAWS_UP_TO = 495

_detector: FlangeDetectorConfig | None = None


def detector() -> FlangeDetectorConfig:
    """The flange detector's settings: the ``flange`` section of config/calibration.yaml (read once)."""
    global _detector
    if _detector is None:
        _detector = detector_config(load_calibration_config())
    return _detector


def _acceptance() -> dict:
    return load_calibration_config().get("acceptance", {}) or {}


def circle_feasibility_exam(data_path, index, circle_plane=None, circle_line=None) -> bool:
    """Write or check the acceptance criteria (point counts of a circle fit).

    A flag point (``"flag"`` in ``index``) with both counts writes them to the data file (``criteria:plane`` /
    ``criteria:line``); any other index is checked against the file's criteria (the smallest flag point's):
    False when ``circle_plane`` < 0.75 x the plane criterion or ``circle_line`` < 0.5 x the circle criterion (the
    fractions of config/calibration.yaml ``acceptance``). A count of None is not checked. CalibrationError when the
    file holds no criteria yet (fit the flag points first).
    """
    if "flag" in str(index) and circle_plane and circle_line:
        write_data(data_path, int(circle_plane), "criteria:plane", type="criteria")
        write_data(data_path, int(circle_line), "criteria:line", type="criteria")
        return True
    criteria = read_data(data_path, "criteria") if Path(data_path).is_file() else None
    if criteria is None:
        raise CalibrationError(
            f"{data_path}: no criteria yet; fit the flag points first (an index containing 'flag' writes them)"
        )
    plane, line = criteria
    acceptance = _acceptance()
    session = CalibrationSession(
        plane_fraction=float(acceptance.get("plane_fraction", 0.75)),
        circle_fraction=float(acceptance.get("circle_fraction", 0.5)),
        data=CalibrationData(criteria_plane=plane, criteria_line=line),
    )
    counts = FlangeDetection(
        True,
        plane_points=int(circle_plane) if circle_plane is not None else plane,
        circle_inliers=int(circle_line) if circle_line is not None else line,
    )
    reason = session.judge(counts)
    if reason:
        print(f"Error: {reason}")
    return not reason


def _cloud_file(point_cloud_path) -> Path:
    path = Path(str(point_cloud_path))
    if path.suffix.lower() == ".ply" and path.is_file():
        return path
    ply = Path(str(point_cloud_path) + ".ply")
    if ply.is_file():
        return ply
    raise CalibrationError(f"{ply}: point cloud not found (circle_fitting takes the path without '.ply')")


def load_point_cloud(point_cloud_path) -> np.ndarray:
    """(N, 3) points (metres) of ``<point_cloud_path>.ply`` (a ``units: millimetres`` comment is honoured)."""
    path = _cloud_file(point_cloud_path)
    try:
        vertices = read_ply(path)
        points = np.column_stack([vertices["x"], vertices["y"], vertices["z"]]).astype(np.float64)
    except (OSError, ValueError, KeyError) as exc:
        raise CalibrationError(f"{path}: not a readable PLY point cloud with x, y, z ({exc})") from exc
    units = " ".join(c.lower() for c in vertices.get("comments", []) if "units" in c.lower())
    if "millimet" in units or "units: mm" in units:
        points *= 0.001
    return points


def fit_flange(pointCloud_path) -> FlangeDetection:
    """The flange detection in ``<pointCloud_path>.ply`` (centre, counts or the reason why not), without the
    criteria: the part of :func:`circle_fitting` that may run on another process (``use_mp``)."""
    return detect_flange(load_point_cloud(pointCloud_path), detector())


def judge_fit(detection: FlangeDetection, pointCloud_path, index=999, need_judge=True, data_path=None):
    """:func:`circle_fitting`'s answer for a detection: the centre [x, y, z] or False (no flange, or refused by the
    criteria; a flag point writes them). Runs where the data file is written (one writer)."""
    if not detection.ok:
        print(f"circle_fitting {pointCloud_path}: {detection.reason}")
        return False
    if need_judge or "flag" in str(index):
        data_file = Path(data_path) if data_path else _cloud_file(pointCloud_path).parent / DATA_FILE_NAME
        if not circle_feasibility_exam(data_file, index, detection.plane_points, detection.circle_inliers):
            return False
    return [float(v) for v in detection.centre_m]


def circle_fitting(pointCloud_path, index=999, need_judge=True, data_path=None):
    """The flange centre [x, y, z] (camera frame, metres) in the point cloud ``<pointCloud_path>.ply``, or False.

    ``index``: the shot's index; one containing ``"flag"`` is a flag point, whose counts become the criteria.
    ``need_judge``: check the counts against the criteria (always for flag points, which write them).
    ``data_path``: the data file of the criteria (default ``data.txt`` next to the point cloud).
    False when no flange is found (the reason is printed) or the criteria refuse the fit.
    """
    return judge_fit(fit_flange(pointCloud_path), pointCloud_path, index, need_judge, data_path)


def pose_diff(H1, H2):
    """H1 * H2^-1 (``numpy.matrix``): the identity when the two transforms agree."""
    return as_matrix(np.asarray(H1, dtype=float) @ np.linalg.inv(np.asarray(H2, dtype=float)))


def get_calibrate(num_point):
    """The solver for ``num_point`` pairs, ``solve(p_robot_mat, p_camera_mat) -> H`` (4 x N homogeneous columns,
    as :func:`pp2mat` gives): 4 pairs the direct linear H = P_robot P_camera^-1, more pairs the least-squares rigid
    transform (SVD / Umeyama, proper rotation); False for fewer than 4 (as the original)."""
    num_point = int(num_point)
    if num_point < DRAW_SIZE:
        return False

    def points(mat) -> np.ndarray:
        return np.asarray(mat, dtype=float)[:3].T

    def calibrate_dlm(p_robot_mat, p_camera_mat):
        h = direct_linear(points(p_camera_mat), points(p_robot_mat))
        if h is None:
            raise CalibrationError("the 4 camera points are (nearly) coplanar: |det| <= 1e-6")
        return as_matrix(h)

    def calibrate_svd(p_robot_mat, p_camera_mat):
        return as_matrix(umeyama(points(p_camera_mat), points(p_robot_mat)))

    return calibrate_dlm if num_point == DRAW_SIZE else calibrate_svd


def ransac(point_pair_list, num_point=4, max_iteration=10000):
    """(H, error): the calibration of the pairs and its reprojection error.

    H (``numpy.matrix`` 4x4, p_robot = H p_camera) from RANSAC over draws of 4 pairs (at most ``max_iteration``
    draws: all C(n, 4) when there are at most 495 of them and ``max_iteration`` allows, else random ones; near
    coplanar draws skipped), then the SVD solution over the inliers, refined. ``error``: the RMS distance (metres)
    |H p_camera - p_robot| over all pairs, outliers included (the original summed signed residuals instead).
    """
    if int(num_point) != DRAW_SIZE:
        raise CalibrationError(
            f"ransac: num_point={num_point}: the draws take {DRAW_SIZE} pairs (the direct linear solution); every "
            "inlier is used in the refinement"
        )
    if int(max_iteration) < 1:
        raise CalibrationError(f"ransac: max_iteration must be at least 1, got {max_iteration}")
    p_camera, p_robot = pp2mat(point_pair_list)
    result = register(
        np.asarray(p_camera, dtype=float)[:3].T,
        np.asarray(p_robot, dtype=float)[:3].T,
        max_draws=int(max_iteration),
        enumerate_up_to=min(ENUMERATE_DRAWS_UP_TO, int(max_iteration)),
        sample_ids=[str(pp.index) for pp in point_pair_list],
    )
    error = float(np.sqrt(np.mean(result.residuals_m**2)))
    return as_matrix(result.transform), error


def calibrate(data_path, num_point=4, max_iteration=10000):
    """(H, error) of a data file's pairs (:func:`ransac`); the data file may be the original's or the project's."""
    return ransac(get_point_pair_list(data_path), num_point=num_point, max_iteration=max_iteration)
