"""Flange-based robot-camera calibration (eye-to-hand), ROS-free.

The robot's tool flange is the target: its centre is found in the fixed camera's point cloud
(:mod:`agiprobot_measurement.calibration.flange_detection`) and paired with the flange position the robot reports. With 3D
point pairs only this is point registration (absolute orientation): find H (camera -> robot base, 4x4, metres)
with ``p_robot = H p_camera``.

Here: flag points (file, checks), the zig-zag path, RANSAC over 4-pair draws (determinant check, direct linear
solution), the SVD / Umeyama solution with a proper rotation, the robust refinement over the inliers, the data
file (the project's layout and the original calibration's, both read and written, atomically), the result YAML and
accuracy metrics.

Units: metres for points and transforms, mm only where a name says so (``*_mm``), degrees where it says ``*_deg``.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.common.config import ConfigError, load_yaml_text
from agiprobot_measurement.common.files import FileReadError, atomic_write_text, read_text_file
from agiprobot_measurement.common.geometry import matrix_to_quaternion, matrix_to_rpy, transform_points
from agiprobot_measurement.common.limits import LIMITS, check_count, excerpt
from agiprobot_measurement.errors import InputError

__all__ = [
    "COPLANAR_TOLERANCE_M",
    "DATA_FORMATS",
    "MIN_FLAG_POINTS",
    "ORIGINAL_BLOCK_END",
    "CalibrationData",
    "CalibrationError",
    "CalibrationResult",
    "CircleFit",
    "Sample",
    "calibrate",
    "calibrate_data",
    "check_flag_points",
    "circle_from_three",
    "direct_linear",
    "fit_circle_lsq",
    "fit_circle_ransac",
    "format_data_file",
    "format_flag_points",
    "format_original_data_file",
    "homogeneous",
    "original_block",
    "original_matrix_rows",
    "original_pair_block",
    "original_transform_blocks",
    "parse_data_text",
    "parse_vector",
    "plane_basis",
    "pose_error",
    "read_data_file",
    "read_flag_points",
    "read_result_yaml",
    "residuals_m",
    "result_dict",
    "rotation_angle_deg",
    "select_consistent_flags",
    "umeyama",
    "write_data_file",
    "write_flag_points",
    "write_result_yaml",
    "zigzag_path",
]


class CalibrationError(InputError):
    """Bad input to the calibration (flag points, data file, too few samples); the message says what to fix."""


# ------------------------------------------------------------------------------------------------ flag points
MIN_FLAG_POINTS = 4
#: flag points whose RMS distance from their best-fit plane is below this are refused as coplanar (metres)
COPLANAR_TOLERANCE_M = 0.01

_VECTOR_RE = re.compile(r"^\s*\[([^\]]*)\]\s*$")


def parse_vector(text: str, length: int | None, where: str, quote: bool = True) -> np.ndarray:
    """``[a, b, c]`` (or the original writer's ``[a, b, c, ]``) -> array of ``length`` values (None: any number);
    CalibrationError naming ``where`` otherwise, quoting an excerpt of ``text`` (nothing of it when not ``quote``)."""
    match = _VECTOR_RE.match(text)
    if not match:
        raise CalibrationError(f"{where}: expected '[x, y, z]'{_got(text, quote)}")
    too_many = length is not None and match.group(1).count(",") > length  # before a huge line is split
    items = [] if too_many else match.group(1).split(",")
    if len(items) > 1 and not items[-1].strip():  # the original writes a separator after every value
        items = items[:-1]
    try:
        values = [float(v) for v in items]
    except ValueError as exc:
        raise CalibrationError(f"{where}: not a list of numbers{_got(text, quote)}") from exc
    if length is None:
        length = len(values)
    if len(values) != length or not all(map(math.isfinite, values)):
        raise CalibrationError(f"{where}: expected {length} finite numbers{_got(text, quote)}")
    return np.array(values)


def _got(text: str, quote: bool) -> str:
    return f", got {excerpt(text.strip())}" if quote else ""


def check_flag_points(points_m: np.ndarray, where: str = "flag points", tolerance_m: float = COPLANAR_TOLERANCE_M):
    """Refuse fewer than 4 points or (nearly) coplanar ones with a message that says how to fix it."""
    points = np.asarray(points_m, dtype=float).reshape(-1, 3)
    if len(points) < MIN_FLAG_POINTS:
        raise CalibrationError(
            f"{where}: {len(points)} flag point(s), at least {MIN_FLAG_POINTS} non-coplanar ones are needed"
        )
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    rms_off_plane_m = singular[-1] / math.sqrt(len(points))
    if rms_off_plane_m < tolerance_m:
        raise CalibrationError(
            f"{where}: the {len(points)} flag points are coplanar (RMS distance from their best-fit plane "
            f"{rms_off_plane_m * 1000.0:.2f} mm < {tolerance_m * 1000.0:.1f} mm); move at least one point out of "
            "the plane (e.g. change its height by 10 cm or more)"
        )
    return points


def read_flag_points(path: str | Path) -> np.ndarray:
    """Flag points (N, 3) in metres, robot base frame, from a text file: one ``[x, y, z]`` per line.

    Blank lines and lines starting with ``#`` are skipped. Raises CalibrationError for a missing file, a bad line,
    fewer than 4 points or coplanar points. A bad line is named by its number, never quoted: the file may be one
    a client named, and its content is not the client's to see.
    """
    path = Path(path)
    if not path.is_file() and not path.is_dir():
        raise CalibrationError(f"{path}: flag point file not found (one '[x, y, z]' per line, metres, robot base)")
    lines = _read_text(path, "flag point file").splitlines()
    check_count(len(lines), LIMITS.data_file_lines, f"{path}: lines of the flag point file")
    points = []
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        points.append(parse_vector(line, 3, f"{path}:{number} (one '[x, y, z]' per line, metres)", quote=False))
    return check_flag_points(np.array(points).reshape(-1, 3), where=str(path))


def zigzag_path(
    flag_points_m: np.ndarray,
    seed: int | None = 0,
    jitter_m: float = 0.03,
    fractions: tuple[float, ...] = (0.25, 0.5, 0.75),
) -> np.ndarray:
    """The fine calibration's path: for every pair of flag points, points at ``fractions`` of the segment, each
    coordinate shifted by a uniform random offset in [-jitter_m, +jitter_m] (seeded). Flag points not included.

    Returns (C(N, 2) * len(fractions), 3) metres.
    """
    points = np.asarray(flag_points_m, dtype=float).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    path = []
    for i, j in itertools.combinations(range(len(points)), 2):
        for f in fractions:
            path.append(points[i] + f * (points[j] - points[i]) + rng.uniform(-jitter_m, jitter_m, 3))
    return np.array(path).reshape(-1, 3)


def select_consistent_flags(
    p_robot_m: np.ndarray, candidates_camera_m: list[list[np.ndarray]], tolerance_m: float = 0.005
) -> list[int]:
    """Pick one flange candidate per flag point so that the flag points' pairwise distances agree.

    A rigid transform keeps distances, so |c_i - c_j| (camera) must equal |p_i - p_j| (robot) for the true flange
    centres; a wrong cluster at one flag point shows up as a mismatch. Every combination is tried (a few candidates
    per flag point). Returns the chosen index per flag point; CalibrationError naming the flag point when one has no
    candidate or the best combination still disagrees by more than ``tolerance_m``.
    """
    robot = np.asarray(p_robot_m, dtype=float).reshape(-1, 3)
    if len(candidates_camera_m) != len(robot):
        raise CalibrationError(f"{len(robot)} flag points but {len(candidates_camera_m)} candidate lists")
    for i, options in enumerate(candidates_camera_m):
        if not len(options):
            raise CalibrationError(f"flag point {i} {robot[i].tolist()}: no flange found in its frame")
    d_robot = np.linalg.norm(robot[:, None] - robot[None], axis=2)
    best, best_choice, best_mismatch = math.inf, None, None
    for choice in itertools.product(*[range(len(o)) for o in candidates_camera_m]):
        cam = np.array([candidates_camera_m[i][k] for i, k in enumerate(choice)])
        mismatch = np.abs(np.linalg.norm(cam[:, None] - cam[None], axis=2) - d_robot)
        score = float(mismatch.max())
        if score < best:
            best, best_choice, best_mismatch = score, list(choice), mismatch
    if best > tolerance_m:
        worst = int(np.argmax(best_mismatch.sum(axis=1)))  # the point in most of the bad pairs
        raise CalibrationError(
            f"the flange positions found at the flag points disagree with the robot's by up to {best * 1000:.1f} mm "
            f"(> {tolerance_m * 1000:.1f} mm), worst at flag point {worst} {robot[worst].tolist()}: a wrong cluster "
            "or a flange not fully in view; move that flag point"
        )
    return best_choice


# ------------------------------------------------------------------------------------------- geometry fits


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3): two unit vectors spanning the plane with the given normal."""
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


def circle_from_three(points_2d: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Circle through 3 points (2D): (centre, radius), None when collinear."""
    (ax, ay), (bx, by), (cx, cy) = points_2d
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-15:
        return None
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return np.array([ux, uy]), math.hypot(ax - ux, ay - uy)


def fit_circle_lsq(points_2d: np.ndarray, iterations: int = 10) -> tuple[np.ndarray, float]:
    """Geometric least-squares circle (2D): algebraic (Kasa) start, then Gauss-Newton on the distances."""
    p = np.asarray(points_2d, dtype=float)
    a = np.column_stack([2.0 * p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(a, (p**2).sum(axis=1), rcond=None)
    centre = sol[:2]
    radius = math.sqrt(max(sol[2] + centre @ centre, 1e-18))
    for _ in range(iterations):
        diff = p - centre
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        residual = dist - radius
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(p))])
        step, *_ = np.linalg.lstsq(jac, -residual, rcond=None)
        centre = centre + step[:2]
        radius += step[2]
        if np.linalg.norm(step) < 1e-10:
            break
    return centre, float(radius)


@dataclass
class CircleFit:
    """A circle fitted in 2D: centre (2,), radius (m) and the inlier mask of the input points."""

    centre: np.ndarray
    radius_m: float
    inliers: np.ndarray

    @property
    def inlier_count(self) -> int:
        return int(self.inliers.sum())


def fit_circle_ransac(
    points_2d: np.ndarray,
    radius_m: float | None = None,
    band_m: float = 0.0008,
    radius_tolerance: float = 0.15,
    iterations: int = 300,
    seed: int | None = 0,
) -> CircleFit | None:
    """RANSAC circle: 3-point circles (radius within ``radius_tolerance`` of ``radius_m`` when given), inliers
    within ``band_m`` of the circle, then a geometric least-squares refit over the inliers (twice). None when no
    circle with at least 3 inliers is found.
    """
    p = np.asarray(points_2d, dtype=float)
    if len(p) < 3:
        return None
    rng = np.random.default_rng(seed)
    best_count, best = 0, None
    for _ in range(iterations):
        circle = circle_from_three(p[rng.choice(len(p), 3, replace=False)])
        if circle is None:
            continue
        centre, radius = circle
        if radius_m is not None and abs(radius - radius_m) > radius_tolerance * radius_m:
            continue
        count = int((np.abs(np.linalg.norm(p - centre, axis=1) - radius) <= band_m).sum())
        if count > best_count:
            best_count, best = count, (centre, radius)
    if best is None or best_count < 3:
        return None
    centre, radius = best
    inliers = np.abs(np.linalg.norm(p - centre, axis=1) - radius) <= band_m
    for _ in range(2):
        if inliers.sum() < 3:
            break
        centre, radius = fit_circle_lsq(p[inliers])
        inliers = np.abs(np.linalg.norm(p - centre, axis=1) - radius) <= band_m
    return CircleFit(np.asarray(centre), float(radius), inliers)


# ------------------------------------------------------------------------------------------- registration
def homogeneous(points_m: np.ndarray) -> np.ndarray:
    points = np.asarray(points_m, dtype=float).reshape(-1, 3)
    return np.column_stack([points, np.ones(len(points))])


def direct_linear(p_camera_m: np.ndarray, p_robot_m: np.ndarray, det_threshold: float = 1e-6) -> np.ndarray | None:
    """The original's direct linear solution from exactly 4 pairs: H = P_robot * P_camera^-1 (4x4, affine).

    Columns of P are homogeneous points. None when |det(P_camera)| <= ``det_threshold`` (near-coplanar draw).
    """
    pc = homogeneous(p_camera_m).T
    pr = homogeneous(p_robot_m).T
    if pc.shape != (4, 4) or abs(np.linalg.det(pc)) <= det_threshold:
        return None
    return pr @ np.linalg.inv(pc)


def umeyama(p_camera_m: np.ndarray, p_robot_m: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Rigid transform (4x4, proper rotation, no scale) minimising sum w |R p_camera + t - p_robot|^2 (SVD).

    The sign correction diag(1, 1, det(U V^T)) keeps det(R) = +1 (no reflection) for any point configuration.
    """
    src = np.asarray(p_camera_m, dtype=float).reshape(-1, 3)
    dst = np.asarray(p_robot_m, dtype=float).reshape(-1, 3)
    if len(src) < 3:
        raise CalibrationError(f"umeyama: {len(src)} pairs, at least 3 are needed")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    cov = (dst - mu_d).T @ ((src - mu_s) * w[:, None])
    u, _, vt = np.linalg.svd(cov)
    correction = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ correction @ vt
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = mu_d - rotation @ mu_s
    return transform


def residuals_m(transform: np.ndarray, p_camera_m: np.ndarray, p_robot_m: np.ndarray) -> np.ndarray:
    """|H p_camera - p_robot| per pair (metres)."""
    return np.linalg.norm(transform_points(transform, p_camera_m) - np.asarray(p_robot_m, dtype=float), axis=1)


@dataclass
class CalibrationResult:
    """H (camera -> robot base, 4x4, metres: p_robot = H p_camera) and what the fit says about the samples."""

    transform: np.ndarray
    residuals_m: np.ndarray  # per sample, also the rejected ones
    inliers: np.ndarray  # bool per sample
    method: str = "ransac+umeyama"
    draws: int = 0
    sample_ids: list[str] = field(default_factory=list)

    @property
    def rejected(self) -> list[int]:
        return [int(i) for i in np.flatnonzero(~self.inliers)]

    @property
    def rms_mm(self) -> float:
        """RMS residual over the inliers (mm)."""
        r = self.residuals_m[self.inliers]
        return float(np.sqrt(np.mean(r**2)) * 1000.0) if len(r) else float("nan")

    @property
    def max_mm(self) -> float:
        r = self.residuals_m[self.inliers]
        return float(r.max() * 1000.0) if len(r) else float("nan")

    def report(self) -> str:
        """Residual per sample and in total (mm), the rejected samples named."""
        lines = [f"{'sample':>28} {'residual_mm':>12}  status"]
        for i, r in enumerate(self.residuals_m):
            name = self.sample_ids[i] if i < len(self.sample_ids) else str(i)
            lines.append(f"{name:>28} {r * 1000.0:12.3f}  {'ok' if self.inliers[i] else 'REJECTED (outlier)'}")
        lines.append(
            f"inliers {int(self.inliers.sum())}/{len(self.inliers)}, RMS {self.rms_mm:.3f} mm, max {self.max_mm:.3f} mm"
        )
        if self.rejected:
            names = [self.sample_ids[i] if i < len(self.sample_ids) else str(i) for i in self.rejected]
            lines.append("rejected samples: " + ", ".join(names))
        return "\n".join(lines)


def calibrate(
    p_camera_m: np.ndarray,
    p_robot_m: np.ndarray,
    threshold_m: float = 0.003,
    det_threshold: float = 1e-6,
    max_draws: int = 2000,
    enumerate_up_to: int = 495,
    refine_iterations: int = 10,
    min_threshold_m: float = 0.0005,
    seed: int | None = 0,
    sample_ids: list[str] | None = None,
) -> CalibrationResult:
    """RANSAC over 4-pair draws + Umeyama + robust refinement.

    Draws: all C(n, 4) when there are at most ``enumerate_up_to`` (n <= 12; with n = 4 the single draw), else
    ``max_draws`` random ones. A draw whose 4x4 homogeneous camera matrix has |det| <= ``det_threshold`` is skipped
    (near coplanar). The draw's direct linear H scores every pair: most pairs within ``threshold_m``, ties by the
    sum of squared residuals. Its inliers seed the refinement: Umeyama over the inliers, then the inlier set is
    re-selected with the threshold max(``min_threshold_m``, 3 x 1.4826 x MAD of the inlier residuals), capped at
    ``threshold_m``, until it does not change. With exactly 4 pairs no outlier can be told apart: all are kept.
    """
    pc = np.asarray(p_camera_m, dtype=float).reshape(-1, 3)
    pr = np.asarray(p_robot_m, dtype=float).reshape(-1, 3)
    n = len(pc)
    if n != len(pr):
        raise CalibrationError(f"{n} camera points but {len(pr)} robot points")
    if n < MIN_FLAG_POINTS:
        raise CalibrationError(f"{n} sample(s): at least {MIN_FLAG_POINTS} non-coplanar samples are needed")
    rng = np.random.default_rng(seed)
    if math.comb(n, 4) <= enumerate_up_to:
        draws = itertools.combinations(range(n), 4)
    else:
        draws = (tuple(rng.choice(n, 4, replace=False)) for _ in range(max_draws))
    best_key, best_inliers, used = None, None, 0
    for draw in draws:
        idx = list(draw)
        h = direct_linear(pc[idx], pr[idx], det_threshold)
        if h is None:
            continue
        used += 1
        r = residuals_m(h, pc, pr)
        inliers = r <= threshold_m
        key = (int(inliers.sum()), -float(np.sum(np.minimum(r, threshold_m) ** 2)))
        if best_key is None or key > best_key:
            best_key, best_inliers = key, inliers
    if best_inliers is None or best_inliers.sum() < 3:
        raise CalibrationError(
            f"no usable draw of 4 samples among {n}: the camera points are (nearly) coplanar "
            f"(|det| <= {det_threshold:g} for every draw) or disagree with the robot points by more than "
            f"{threshold_m * 1000.0:.1f} mm; check the flag points and the flange detection"
        )
    inliers = best_inliers.copy() if n > 4 else np.ones(n, bool)
    transform = umeyama(pc[inliers], pr[inliers])
    for _ in range(refine_iterations):
        r = residuals_m(transform, pc, pr)
        if n <= 4:
            break
        mad = np.median(np.abs(r[inliers] - np.median(r[inliers])))
        limit = min(threshold_m, max(min_threshold_m, np.median(r[inliers]) + 3.0 * 1.4826 * mad))
        new_inliers = r <= limit
        if new_inliers.sum() < MIN_FLAG_POINTS:
            break
        transform = umeyama(pc[new_inliers], pr[new_inliers])
        if np.array_equal(new_inliers, inliers):
            break
        inliers = new_inliers
    r = residuals_m(transform, pc, pr)
    return CalibrationResult(transform, r, inliers, draws=used, sample_ids=list(sample_ids or []))


# ------------------------------------------------------------------------------------------------ metrics
def rotation_angle_deg(rotation: np.ndarray) -> float:
    cos = (np.trace(rotation) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation error mm, rotation error deg) of two 4x4 poses of the same frame."""
    estimate, truth = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    translation_mm = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) * 1000.0)
    return translation_mm, rotation_angle_deg(estimate[:3, :3].T @ truth[:3, :3])


# ---------------------------------------------------------------------------------------------- data file
#: the data file layouts :func:`write_data_file` writes; :func:`read_data_file` reads both
DATA_FORMATS = ("project", "original")


@dataclass
class Sample:
    """One pair: flange centre in the robot base frame and in the camera frame (metres); index = timestamp id."""

    index: str
    p_robot_m: np.ndarray
    p_camera_m: np.ndarray
    flag: bool = False


@dataclass
class CalibrationData:
    """The content of a data file: samples, H_coarse and H_final (or None) and the acceptance criteria (point
    counts: the smallest of the flag points')."""

    samples: list[Sample] = field(default_factory=list)
    h_coarse: np.ndarray | None = None
    criteria_plane: int | None = None
    criteria_line: int | None = None
    h_final: np.ndarray | None = None

    def arrays(self, flag_only: bool = False) -> tuple[np.ndarray, np.ndarray, list[str]]:
        chosen = [s for s in self.samples if s.flag or not flag_only]
        pc = np.array([s.p_camera_m for s in chosen]).reshape(-1, 3)
        pr = np.array([s.p_robot_m for s in chosen]).reshape(-1, 3)
        return pc, pr, [s.index for s in chosen]


def _vector_text(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def _check_format(format: str) -> str:
    if format not in DATA_FORMATS:
        raise CalibrationError(f"data file format must be one of {', '.join(DATA_FORMATS)}, got {excerpt(format)}")
    return format


def format_data_file(data: CalibrationData, format: str = "project") -> str:
    """The data file's text.

    ``project``: the documented blocks (``p_robot 3-DoF index:<id>`` + ``[x, y, z]``, ``p_camera ...``), flag samples
    in an extra ``flag_points`` block of indices, 3-row ``H_coarse`` / ``H_final``, ``criteria:plane`` / ``line``.
    ``original``: what the original calibration's reader (``utils.read_data``) parses, laid out as its writer lays it
    out: criteria, the flag pairs (index prefixed ``flag<i>_``), ``H_coarse`` with 4 rows ``[a, b, c, d, ]`` followed
    by ``Trans_coarse`` / ``Rot_coarse``, the other pairs, ``H_final``; every block followed by an empty line and a
    line holding one space (the original's separator); 3-DoF pairs.
    """
    if _check_format(format) == "original":
        return format_original_data_file(data)
    lines = []
    for s in data.samples:
        lines += [f"p_robot 3-DoF index:{s.index}", _vector_text(s.p_robot_m)]
        lines += [f"p_camera 3-DoF index:{s.index}", _vector_text(s.p_camera_m)]
    lines.append("")
    flags = [s.index for s in data.samples if s.flag]
    if flags:
        lines += ["flag_points", "[" + ", ".join(flags) + "]", ""]
    for title, matrix in (("H_coarse", data.h_coarse), ("H_final", data.h_final)):
        if matrix is not None:
            lines.append(title)
            lines += [_vector_text(row) for row in np.asarray(matrix)[:3]]
            lines.append("")
    if data.criteria_plane is not None:
        lines += ["criteria:plane", str(int(data.criteria_plane))]
    if data.criteria_line is not None:
        lines += ["criteria:line", str(int(data.criteria_line))]
    return "\n".join(lines) + "\n"


#: what the original writer puts after every block: a newline and a line holding one space
ORIGINAL_BLOCK_END = "\n \n"


def original_block(title: str, value_lines: list[str]) -> str:
    """One block as the original writer lays it out: title, value lines, :data:`ORIGINAL_BLOCK_END`."""
    return "".join(line + "\n" for line in [title, *value_lines]) + ORIGINAL_BLOCK_END


def original_matrix_rows(matrix) -> list[str]:
    """The original's matrix rows: every value followed by ``", "`` inside the brackets (``[a, b, c, d, ]``)."""
    return ["[" + "".join(f"{float(v)!r}, " for v in row) + "]" for row in np.asarray(matrix, dtype=float)]


def original_pair_block(index: str, p_robot, p_camera) -> str:
    """A point pair as the original writes it; the robot header says 6-DoF for a 7-value pose (x, y, z, quaternion
    xyzw), as the original's, and 3-DoF for a position."""
    p_robot = np.asarray(p_robot, dtype=float).reshape(-1)
    dof = "6-DoF" if len(p_robot) in (6, 7) else "3-DoF"
    lines = [
        f"p_robot {dof} index:{index}",
        _vector_text(p_robot),
        f"p_camera 3-DoF index:{index}",
        _vector_text(np.asarray(p_camera, dtype=float).reshape(-1)),
    ]
    return "".join(line + "\n" for line in lines) + ORIGINAL_BLOCK_END


def original_transform_blocks(matrix, suffix: str) -> str:
    """``Trans<suffix>`` ``[x, y, z]`` and ``Rot<suffix>`` ``(roll, pitch, yaw)`` (rad, static x-y-z axes) of H."""
    h = np.asarray(matrix, dtype=float)
    rpy = matrix_to_rpy(h[:3, :3])
    rot = "(" + ", ".join(repr(float(v)) for v in rpy) + ")"
    return original_block(f"Trans{suffix}", [_vector_text(h[:3, 3])]) + original_block(f"Rot{suffix}", [rot])


def format_original_data_file(data: CalibrationData) -> str:
    """The original layout (see :func:`format_data_file`)."""
    parts = []
    if data.criteria_plane is not None and data.criteria_line is not None:
        parts.append(original_block("criteria:plane", [str(int(data.criteria_plane))]))
        parts.append(original_block("criteria:line", [str(int(data.criteria_line))]))
    flags = [s for s in data.samples if s.flag]
    for i, s in enumerate(flags):
        index = s.index if s.index.startswith("flag") else f"flag{i}_{s.index}"
        parts.append(original_pair_block(index, s.p_robot_m, s.p_camera_m))
    if data.h_coarse is not None:
        parts.append(original_block("H_coarse", original_matrix_rows(data.h_coarse)))
        parts.append(original_transform_blocks(data.h_coarse, "_coarse"))
    for s in data.samples:
        if not s.flag:
            parts.append(original_pair_block(s.index, s.p_robot_m, s.p_camera_m))
    if data.h_final is not None:
        parts.append(original_block("H_final", original_matrix_rows(data.h_final)))
        parts.append(original_transform_blocks(data.h_final, ""))
    return "".join(parts)


def write_data_file(path: str | Path, data: CalibrationData, format: str = "project") -> Path:
    """The data file (:func:`format_data_file` in ``format``), written atomically."""
    return atomic_write_text(path, format_data_file(data, format), make_parents=True)


def format_flag_points(points_m, format: str = "project") -> str:
    """A flag point (target) file: one ``[x, y, z]`` per line (metres, robot base). ``project`` starts with a ``#``
    comment; ``original`` has nothing but the point lines (the original's target reader parses every line)."""
    lines = [_vector_text(p) for p in np.asarray(points_m, dtype=float).reshape(-1, 3)]
    if _check_format(format) == "project":
        lines.insert(0, "# flag points: flange centre (tool0 origin), [x, y, z] metres, robot base frame")
    return "\n".join(lines) + "\n"


def write_flag_points(path: str | Path, points_m, format: str = "project") -> Path:
    """Write a flag point file (:func:`format_flag_points`) atomically."""
    return atomic_write_text(path, format_flag_points(points_m, format), make_parents=True)


def _read_text(path: Path, what: str) -> str:
    try:
        return read_text_file(path, what)
    except FileReadError as exc:
        raise CalibrationError(str(exc)) from exc


_PAIR_HEADER_RE = re.compile(r"^p_(robot|camera) ([36])-DoF index:(\S+)$")
_MATRIX_TITLES = {"H_coarse": "h_coarse", "H_final": "h_final", "H": "h_final"}
_TRANSFORM_TITLE_RE = re.compile(r"^(Trans|Rot)(_\w+)?$")
_CRITERIA_RE = re.compile(r"^(?:criteria|circle):(plane|line)$")


def _pair_vector(text: str, dof: str, where: str) -> np.ndarray:
    """The position of a pair line: 3 values (3-DoF), or 7 (x, y, z, quaternion; 6 with roll-pitch-yaw) of a 6-DoF
    pose, of which the position is kept."""
    if dof == "3":
        return parse_vector(text, 3, where)
    values = parse_vector(text, None, where)
    if len(values) not in (6, 7):
        raise CalibrationError(
            f"{where}: a 6-DoF pose needs 7 values [x, y, z, qx, qy, qz, qw], got {excerpt(text.strip())}"
        )
    return values[:3]


def read_data_file(path: str | Path) -> CalibrationData:
    """Parse a data file, the project's or the original calibration's layout; CalibrationError with file and line
    for anything malformed.

    Accepted besides the project's blocks: ``p_robot 6-DoF index:<id>`` with 7 values (the position is used),
    4-row ``H_coarse`` / ``H_final`` / ``H`` (rows may end ``, ]``), ``Trans*`` / ``Rot*`` blocks (derived from H,
    skipped), criteria blocks separated by blank or blank-looking lines, repeated criteria (the smallest counts,
    as the original reads them). Without a ``flag_points`` block, samples whose index starts with ``flag`` (the
    original's flag points) are the flag samples.
    """
    path = Path(path)
    return parse_data_text(_read_text(path, "data file"), path)


def parse_data_text(text: str, path: str | Path = "<data>", max_lines: int | None = None) -> CalibrationData:
    """:func:`read_data_file` of the text ``text`` (``path`` names it in messages); refused unparsed when it has more
    than ``max_lines`` lines (default :attr:`InputLimits.data_file_lines`). Linear in the number of lines."""
    limit = LIMITS.data_file_lines if max_lines is None else max_lines
    newlines = text.count("\n")  # before splitting: a file of line breaks must not become a list of millions
    check_count(newlines + (not text.endswith("\n")), limit, f"{path}: lines of the data file")
    lines = text.splitlines()
    check_count(len(lines), limit, f"{path}: lines of the data file")
    path = str(path)  # formatted into a location per line: once
    data = CalibrationData()
    robot: dict[str, np.ndarray] = {}
    camera: dict[str, np.ndarray] = {}
    order: dict[str, None] = {}  # the indices in file order (a dict: membership in constant time)
    flags: set[str] | None = None
    criteria: dict[str, list[int]] = {"plane": [], "line": []}
    i = 0

    def next_line(what: str) -> str:
        if i + 1 >= len(lines):
            raise CalibrationError(f"{path}:{i + 1}: '{what}' without a value")
        return lines[i + 1]

    while i < len(lines):
        line = lines[i].strip()
        where = f"{path}:{i + 2}"
        header = _PAIR_HEADER_RE.match(line)
        criterion = None if header else _CRITERIA_RE.match(line)
        if header:
            kind, dof, index = header.groups()
            vector = _pair_vector(next_line(line), dof, where)
            (robot if kind == "robot" else camera)[index] = vector
            order.setdefault(index)
            i += 2
        elif line in _MATRIX_TITLES:
            rows = []
            while len(rows) < 4 and i + 1 + len(rows) < len(lines):
                row_line = lines[i + 1 + len(rows)]
                if not row_line.strip().startswith("["):
                    break
                rows.append(parse_vector(row_line, 4, f"{path}:{i + 2 + len(rows)}"))
            if len(rows) < 3:
                raise CalibrationError(f"{path}:{i + 1}: {line} needs 3 or 4 rows '[a, b, c, d]'")
            consumed = len(rows)
            if consumed == 3:  # the project's layout: the affine row is implied
                rows.append(np.array([0.0, 0.0, 0.0, 1.0]))
            setattr(data, _MATRIX_TITLES[line], np.vstack(rows))
            i += 1 + consumed
        elif _TRANSFORM_TITLE_RE.match(line):
            if not next_line(line).strip():
                raise CalibrationError(f"{where}: {line} without a value")
            i += 2
        elif criterion:
            try:
                value = int(next_line(line).strip())
            except ValueError as exc:
                raise CalibrationError(f"{where}: {line} needs an integer") from exc
            criteria[criterion.group(1)].append(value)
            i += 2
        elif line == "flag_points":
            text = next_line(line).strip()
            if not (text.startswith("[") and text.endswith("]")):
                raise CalibrationError(f"{where}: flag_points needs '[index, ...]'")
            flags = {v.strip() for v in text[1:-1].split(",") if v.strip()}
            i += 2
        elif not line or line.startswith("#"):
            i += 1
        else:
            raise CalibrationError(f"{path}:{i + 1}: unexpected line {excerpt(line)}")
    for index in order:
        if index not in robot or index not in camera:
            missing = "p_camera" if index not in camera else "p_robot"
            raise CalibrationError(f"{path}: sample {excerpt(index)} has no {missing}")
        flag = index.startswith("flag") if flags is None else index in flags
        data.samples.append(Sample(index, robot[index], camera[index], flag))
    data.criteria_plane = min(criteria["plane"]) if criteria["plane"] else None
    data.criteria_line = min(criteria["line"]) if criteria["line"] else None
    return data


def calibrate_data(data: CalibrationData, mode: str = "cal_fine", **options) -> CalibrationResult:
    """Coarse (flag samples only; all samples when none is marked) or fine (all samples) calibration."""
    if mode not in ("cal_fine", "cal_coarse"):
        raise CalibrationError(f"mode must be cal_fine or cal_coarse, got {excerpt(mode)}")
    flag_only = mode == "cal_coarse" and any(s.flag for s in data.samples)
    pc, pr, ids = data.arrays(flag_only=flag_only)
    if mode == "cal_coarse" or len(pc) == MIN_FLAG_POINTS:
        check_flag_points(pr, where=f"{mode} robot points")
    result = calibrate(pc, pr, sample_ids=ids, **options)
    result.method = f"{mode}: ransac (4-pair direct linear) + umeyama + robust refinement"
    return result


# ----------------------------------------------------------------------------------------------- result


def result_dict(result: CalibrationResult, parent_frame: str, child_frame: str, mode: str) -> dict:
    """The result YAML's content: the transform parent (robot base) <- child (camera) and its residuals (mm)."""
    h = result.transform
    return {
        "parent_frame": parent_frame,
        "child_frame": child_frame,
        "mode": mode,
        "method": result.method,
        "translation_m": [float(v) for v in h[:3, 3]],
        "rotation_quaternion_xyzw": [float(v) for v in matrix_to_quaternion(h[:3, :3])],
        "matrix": [[float(v) for v in row] for row in h],
        "samples": len(result.inliers),
        "inliers": int(result.inliers.sum()),
        "rejected_samples": [result.sample_ids[i] if i < len(result.sample_ids) else i for i in result.rejected],
        "residual_rms_mm": result.rms_mm,
        "residual_max_mm": result.max_mm,
        "residuals_mm": [float(v * 1000.0) for v in result.residuals_m],
    }


def write_result_yaml(path: str | Path, result: CalibrationResult, parent_frame: str, child_frame: str, mode: str):
    text = yaml.safe_dump(result_dict(result, parent_frame, child_frame, mode), sort_keys=False)
    return atomic_write_text(
        path, "# robot-camera calibration (p_parent = matrix * p_child, metres)\n" + text, make_parents=True
    )


def read_result_yaml(path: str | Path) -> np.ndarray:
    """The 4x4 matrix of a result YAML (safe_load)."""
    path = Path(path)
    try:
        content = load_yaml_text(_read_text(path, "calibration result"), str(path))
    except ConfigError as exc:
        raise CalibrationError(str(exc)) from exc
    try:
        matrix = np.array(content["matrix"], dtype=float)
    except (TypeError, KeyError, ValueError) as exc:
        raise CalibrationError(f"{path}: no 4x4 'matrix'") from exc
    if matrix.shape != (4, 4):
        raise CalibrationError(f"{path}: 'matrix' is not 4x4")
    return matrix
