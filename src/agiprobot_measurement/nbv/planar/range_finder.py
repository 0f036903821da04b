"""The report's 2D range finder: geometry (``rfconfig``), poses, ``rangef2d`` / ``rangef2d_`` and ``bkrangef2d``.

Geometry (report, ``rfconfig``; angles in radians, lengths in cells):

- ``rf_length_cells`` (RFlength): distance from the laser (light source) to the camera's focal point;
- ``rf_alpha_rad`` (RFalpha): angle between the laser line and the laser-camera baseline;
- ``rf_beta_rad`` (RFbeta): angle between the camera's central line and the baseline;
- ``fr_gamma_rad`` (FRgamma, the report's spelling): the camera's field of view in the plane.

Documented choice: the rig is rigid and the camera's central line crosses the laser at the standoff
``|S - P| = RFlength sin(beta) / sin(alpha + beta)`` (sine rule), like a laser line scanner whose optical axes cross
at its sweet spot. The default geometry is the station's laser line scanner (``config/laser_scanner.yaml``, 1 cell
= 1 mm): RFlength = tan(alpha) x optimal standoff (76 mm), RFalpha = 90 deg, RFbeta = 90 deg - alpha (67.3 deg,
standoff 181.8 cells) and FRgamma = the span of camera angles between the minimum and maximum standoff (12.4 deg).

A pose ``pos`` is the report's 3 x 2 matrix ``[source; sensor (camera); aim]``; the laser runs from the source
through the aim point and on to the border of the (bounded) scene. ``NO_VIEW`` (all -1) is the planners' "no view is
possible"; ``NO_RETURN`` ([-1, -1]) is ``rangef2d``'s "nothing came back".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.limits import LIMITS
from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL
from agiprobot_measurement.nbv.planar.traversal import first_blocking, line8_cells, segment_box_entry, supercover_cells

__all__ = [
    "NO_RETURN",
    "NO_VIEW",
    "RangeFinder2D",
    "Reading",
    "apply_measurement",
    "assign_noisy_cell",
    "bkrangef2d",
    "bkrangef2d_",
    "default_laser_scanner_config_path",
    "noisy_return_margin_cells",
    "rangef2d",
    "rangef2d_",
    "scan",
]

NO_VIEW = np.full((3, 2), -1.0)
NO_RETURN = np.array([-1.0, -1.0])

# Nudge (cells) that moves the end of the laser's free part off the hit cell's boundary, so that cells touching the
# hit only at that point are not carved empty. Larger than traversal.TOUCH_EPS.
_END_NUDGE = 1e-7


def default_laser_scanner_config_path() -> Path:
    """Path of the station's ``config/laser_scanner.yaml`` (kept in one function so it can be redirected later)."""
    return CONFIG_DIR / "laser_scanner.yaml"


#: the longest laser-camera distance (cells): a ray's traversal buffer grows with it
MAX_RF_LENGTH_CELLS = 5 * math.isqrt(LIMITS.image_pixels)


def _check_finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise NbvInputError(f"{name} must be a finite number, got {value!r}")
    return v


def _check_length(length: float) -> None:
    if not 0 < length <= MAX_RF_LENGTH_CELLS:
        raise NbvInputError(
            f"rf_length_cells (RFlength) must be > 0 and <= {MAX_RF_LENGTH_CELLS:,} cells (5 times the side of the "
            f"largest object grid read), got {length:g}"
        )


@dataclass(frozen=True)
class RangeFinder2D:
    """The triangulating range finder of the report (lengths in cells, angles in radians)."""

    rf_length_cells: float
    rf_alpha_rad: float
    rf_beta_rad: float
    fr_gamma_rad: float

    def __post_init__(self) -> None:
        length = _check_finite("rf_length_cells (RFlength)", self.rf_length_cells)
        alpha = _check_finite("rf_alpha_rad (RFalpha)", self.rf_alpha_rad)
        beta = _check_finite("rf_beta_rad (RFbeta)", self.rf_beta_rad)
        gamma = _check_finite("fr_gamma_rad (FRgamma)", self.fr_gamma_rad)
        _check_length(length)
        if not (0 < alpha < math.pi and 0 < beta < math.pi and alpha + beta < math.pi):
            raise NbvInputError(
                f"RFalpha and RFbeta must lie in (0, pi) with RFalpha + RFbeta < pi so that the laser and the camera "
                f"axis cross, got {alpha} rad and {beta} rad"
            )
        if not 0 < gamma < math.pi:
            raise NbvInputError(f"fr_gamma_rad (FRgamma) must lie in (0, pi) rad, got {gamma}")

    @property
    def standoff_cells(self) -> float:
        """Distance from the source to the point where the camera axis crosses the laser (sine rule)."""
        return self.rf_length_cells * math.sin(self.rf_beta_rad) / math.sin(self.rf_alpha_rad + self.rf_beta_rad)

    @property
    def triangulation_angle_rad(self) -> float:
        """Angle between laser and camera central line at the standoff point (pi - alpha - beta)."""
        return math.pi - self.rf_alpha_rad - self.rf_beta_rad

    @classmethod
    def from_config(cls, path: Path | str | None = None, cell_size_mm: float = 1.0) -> RangeFinder2D:
        """The station's laser line scanner mapped onto the report's parameters (see the module docstring)."""
        cell = _check_finite("cell_size_mm", cell_size_mm)
        if cell <= 0:
            raise NbvInputError(f"cell_size_mm must be > 0, got {cell}")
        path = Path(path) if path is not None else default_laser_scanner_config_path()
        try:
            cfg = yaml.safe_load(path.read_text())["sensor_model"]
            optimal = float(cfg["optimal_standoff_mm"]) / cell
            near = float(cfg["minimum_standoff_mm"]) / cell
            far = float(cfg["maximum_standoff_mm"]) / cell
            tilt = float(cfg["alpha_rad"])
        except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
            raise NbvInputError(f"cannot read the laser scanner geometry from {path}: {exc}") from exc
        length = math.tan(tilt) * optimal
        # camera angle from the baseline to a point at depth z on the laser (laser perpendicular to the baseline)
        gamma = math.atan2(far, length) - math.atan2(near, length)
        return cls(length, math.pi / 2, math.atan2(optimal, length), gamma)

    def with_length(self, rf_length_cells: float) -> RangeFinder2D:
        """The same rig with another laser-camera distance, keeping the standoff (the camera re-aims: beta changes).

        Keeping the standoff makes a longer rod a larger laser-camera angle at the target, the quantity the
        report's section 7.1 names.
        """
        length = _check_finite("rf_length_cells (RFlength)", rf_length_cells)
        _check_length(length)
        s = self.standoff_cells
        a = self.rf_alpha_rad
        beta = math.atan2(s * math.sin(a), length - s * math.cos(a))
        return replace(self, rf_length_cells=length, rf_beta_rad=beta)

    def poses(self, aim_xy, source_dir_rad, side) -> np.ndarray:
        """Poses (n x 3 x 2) with the standoff point at ``aim_xy`` and the source in direction ``source_dir_rad``.

        ``source_dir_rad`` is the direction from the aim to the source (a sector of the circle of visibility);
        ``side`` (+1 / -1) puts the camera on the left / right of the laser as seen from the source.
        """
        phi = np.atleast_1d(np.asarray(source_dir_rad, dtype=float))
        sd = np.broadcast_to(np.asarray(side, dtype=float), phi.shape)
        aim = np.asarray(aim_xy, dtype=float).reshape(-1, 2)
        aim = np.broadcast_to(aim, (phi.shape[0], 2))
        u = np.column_stack([np.cos(phi), np.sin(phi)])
        src = aim + self.standoff_cells * u
        # baseline: the laser direction (-u) turned by RFalpha towards the camera's side
        ang = phi + np.pi + sd * self.rf_alpha_rad
        cam = src + self.rf_length_cells * np.column_stack([np.cos(ang), np.sin(ang)])
        return np.stack([src, cam, aim], axis=1)

    def pose_through(self, source_xy, through_xy, side: int) -> np.ndarray:
        """A pose with the source at ``source_xy`` and the laser through ``through_xy`` (any depth); 3 x 2."""
        s = np.asarray(source_xy, dtype=float)
        t = np.asarray(through_xy, dtype=float)
        v = t - s
        dist = float(np.hypot(*v))
        if dist == 0:
            raise NbvInputError("pose_through: the source and the aim point coincide")
        d = v / dist
        ang = math.atan2(d[1], d[0]) + side * self.rf_alpha_rad
        cam = s + self.rf_length_cells * np.array([math.cos(ang), math.sin(ang)])
        return np.stack([s, cam, t])

    def depth_window_cells(self) -> tuple[float, float]:
        """Depths along the laser (from the source) that the camera's field of view covers."""
        a, b, g, length = self.rf_alpha_rad, self.rf_beta_rad, self.fr_gamma_rad, self.rf_length_cells
        lo_b, hi_b = b - g / 2, b + g / 2
        # sine rule for a camera ray at angle b' from the baseline; b' + a >= pi never meets the laser
        near = length * math.sin(lo_b) / math.sin(a + lo_b)
        far = length * math.sin(hi_b) / math.sin(a + hi_b) if a + hi_b < math.pi else math.inf
        return near, far


@dataclass(frozen=True)
class Reading:
    """One return: the point where the laser entered the hit cell (cells, sub-cell) and that cell."""

    point: np.ndarray
    cell: tuple[int, int]


def _check_pose(pos) -> np.ndarray:
    p = np.asarray(pos, dtype=float)
    if p.shape != (3, 2):
        raise NbvInputError(f"a pose is a 3 x 2 matrix [source; sensor; aim], got shape {p.shape}")
    if not np.isfinite(p).all():
        raise NbvInputError("the pose contains NaN or infinite values")
    if np.hypot(*(p[2] - p[0])) == 0:
        raise NbvInputError("the pose's source and aim point coincide: the laser has no direction")
    return p


def _far_end(src: np.ndarray, d: np.ndarray, shape) -> np.ndarray:
    # far enough to leave any cell of the grid: the scene is bounded and cells outside it are free
    reach = float(np.hypot(*src)) + shape[0] + shape[1] + 2.0
    return src + reach * d


def scan(truth: np.ndarray, pos, rf: RangeFinder2D, eight_connected: bool = False) -> Reading | None:
    """One measurement on the ground truth: the hit and its cell, or ``None`` (miss, blocked return, out of view).

    A return exists only when the laser hits a full cell, the hit lies within the camera's field of view
    (+- FRgamma / 2 about its central line) and the segment hit -> camera touches no full cell other than the hit.
    """
    p = _check_pose(pos)
    src, cam, aim = p
    d = (aim - src) / np.hypot(*(aim - src))
    far = _far_end(src, d, truth.shape)
    full = np.asarray(truth) == FULL
    hi, hj = first_blocking(full, src, far, eight_connected=eight_connected)
    if hi < 0:
        return None
    t = segment_box_entry(src, far, (hi, hj))
    if t < 0:
        # an 8-connected line may pick a cell the segment never touches: use the foot of the cell centre
        t = float(np.dot(np.array([hi, hj], dtype=float) - src, far - src) / np.dot(far - src, far - src))
    hit = src + t * (far - src)
    axis_point = src + rf.standoff_cells * d
    v_hit = hit - cam
    v_axis = axis_point - cam
    cosang = float(np.dot(v_hit, v_axis) / (np.hypot(*v_hit) * np.hypot(*v_axis) + 1e-300))
    if math.acos(max(-1.0, min(1.0, cosang))) > rf.fr_gamma_rad / 2:
        return None
    bi, _ = first_blocking(full, hit, cam, skip=(hi, hj), eight_connected=eight_connected)
    if bi >= 0:
        return None
    return Reading(hit, (hi, hj))


def rangef2d(truth: np.ndarray, pos, rf: RangeFinder2D) -> np.ndarray:
    """The report's ``[X] = rangef2d(M, pos)`` with supercover traversal: the hit point, or ``NO_RETURN``."""
    r = scan(truth, pos, rf, eight_connected=False)
    return NO_RETURN.copy() if r is None else r.point.copy()


def rangef2d_(truth: np.ndarray, pos, rf: RangeFinder2D) -> np.ndarray:
    """The report's ``rangef2d_``: as :func:`rangef2d` with the 8-connected line (kept for parity)."""
    r = scan(truth, pos, rf, eight_connected=True)
    return NO_RETURN.copy() if r is None else r.point.copy()


def cell_of_point(point_xy, laser_dir) -> tuple[int, int]:
    """The cell a measured point falls in; a point on an edge belongs to the cell the laser enters there."""
    q = np.asarray(point_xy, dtype=float) + _END_NUDGE * np.asarray(laser_dir, dtype=float)
    return math.floor(q[0] + 0.5), math.floor(q[1] + 0.5)


def assign_noisy_cell(model: np.ndarray, pos, point_xy, window_cells: float):
    """The cell a noisy return is filed under, given the model: ``(cell, snapped)``.

    Documented choices (the report names noise as its main failure and gives no rule):

    - A surface point lies on the entry edge of its cell, so with depth noise the best single guess of that cell is
      the one half a cell deeper than the measured point (right for an error below half a cell either way).
    - If that cell is already known empty, the laser has passed it before: the return is filed under the first cell
      further along the laser, within ``window_cells`` (k noise sigmas) of the measured point, that is not known
      empty (``snapped`` is True). If every such cell is known empty the guess stands: the return contradicts the
      model and the report's fusion turns the cell unknown (a conflict), so that it can be measured again.
    """
    p = _check_pose(pos)
    src = p[0]
    x = np.asarray(point_xy, dtype=float)
    d = (p[2] - src) / np.hypot(*(p[2] - src))
    guess = cell_of_point(x + 0.5 * d, d)
    m = np.asarray(model)
    inside = 0 <= guess[0] < m.shape[0] and 0 <= guess[1] < m.shape[1]
    if not inside or m[guess] != EMPTY:
        return guess, False
    ahead = supercover_cells(x + 0.5 * d, x + max(window_cells, 0.5) * d + 0.5 * d, m.shape)
    if len(ahead):
        keep = m[ahead[:, 0], ahead[:, 1]] != EMPTY
        if keep.any():
            k = int(np.flatnonzero(keep)[0])
            return (int(ahead[k, 0]), int(ahead[k, 1])), True
    return guess, False


def noisy_return_margin_cells(pos, point_xy, depth_margin_cells: float) -> float:
    """How much of the return path next to a noisy point to leave uncarved (cells).

    Documented choice: a point measured ``e`` too deep lies ``e`` under the surface, and its return path, at angle
    ``theta`` to the laser, leaves the body only after about ``e / cos(theta)`` (a surface facing the laser). With
    ``e = depth_margin_cells`` (k sigma) plus the half cell of the cell guess, that stretch is not carved empty.
    With a long laser-camera distance ``theta`` is large (54 deg at RFlength 250) and a fixed margin of half a cell
    let the return of every too deep point erase the surface cell just measured. ``cos(theta)`` is floored at 0.2.
    """
    p = _check_pose(pos)
    d = (p[2] - p[0]) / np.hypot(*(p[2] - p[0]))
    r = p[1] - np.asarray(point_xy, dtype=float)
    cos_t = max(float(-(r @ d)) / (float(np.hypot(*r)) + 1e-300), 0.2)
    return 0.5 + float(depth_margin_cells) / cos_t


def measurement_cells(
    model_shape,
    pos,
    point_xy,
    cell=None,
    eight_connected: bool = False,
    laser_margin_cells: float = 0.0,
    return_margin_cells: float = 0.0,
):
    """Cells a return proves free (laser before the point, point -> camera) and the cell proven full.

    ``laser_margin_cells`` leaves that much of the laser before the point uncarved (a noisy point may lie in front
    of the surface); ``return_margin_cells`` leaves that much of the return path next to the point uncarved (a
    point measured too deep lies inside the body, and the first stretch of its return path crosses body cells). Returns ``(free_cells k x 2, full_cell)``; ``full_cell`` is ``None`` outside the grid.
    """
    p = _check_pose(pos)
    src, cam, aim = p
    x = np.asarray(point_xy, dtype=float)
    if not np.isfinite(x).all():
        raise NbvInputError("bkrangef2d: the measured point contains NaN")
    d = (aim - src) / np.hypot(*(aim - src))
    if cell is None:
        cell = cell_of_point(x, d)
    inside = 0 <= cell[0] < model_shape[0] and 0 <= cell[1] < model_shape[1]
    trace = line8_cells if eight_connected else supercover_cells
    laser = trace(src, x - max(_END_NUDGE, laser_margin_cells) * d, model_shape)
    to_cam = cam - x
    dist_cam = float(np.hypot(*to_cam))
    if return_margin_cells > 0 and dist_cam > return_margin_cells:
        back = trace(x + return_margin_cells * to_cam / dist_cam, cam, model_shape)
    else:
        back = trace(x, cam, model_shape)
    free = np.concatenate([laser, back]) if len(back) else laser
    if inside and len(free):
        free = free[~((free[:, 0] == cell[0]) & (free[:, 1] == cell[1]))]
    return free, (cell if inside else None)


def apply_measurement(
    model: np.ndarray,
    pos,
    point_xy,
    cell=None,
    eight_connected: bool = False,
    laser_margin_cells: float = 0.0,
    return_margin_cells: float = 0.0,
):
    """Fuse one return into ``model`` in place (``sgn(M + U)`` on the cells the return touches).

    Returns ``(free_cells, full_cell)`` as :func:`measurement_cells`.
    """
    free, full_cell = measurement_cells(
        model.shape, pos, point_xy, cell, eight_connected, laser_margin_cells, return_margin_cells
    )
    if len(free):
        fi, fj = free[:, 0], free[:, 1]
        model[fi, fj] = np.sign(model[fi, fj] + EMPTY)
    if full_cell is not None:
        model[full_cell] = np.sign(model[full_cell] + FULL)
    return free, full_cell


def bkrangef2d(model: np.ndarray, pos, point_xy, cell=None) -> np.ndarray:
    """The report's ``[M] = bkrangef2d(M, pos, X)``: the model updated with the return ``X`` (a new array).

    Documented rule (the report leaves it unstated): the cells on the laser before ``X`` and on ``X -> camera``
    become empty, the cell of ``X`` becomes full, all through the fusion ``sgn(M + U)``. ``X = NO_RETURN`` changes
    nothing. ``model`` must be the planner's model, never the ground truth: it is copied, not modified.
    """
    out = np.array(model, dtype=float, copy=True)
    x = np.asarray(point_xy, dtype=float)
    if x.shape == (2,) and np.all(x == NO_RETURN):
        return out
    apply_measurement(out, pos, x, cell)
    return out


def bkrangef2d_(model: np.ndarray, pos, point_xy, cell=None) -> np.ndarray:
    """The report's ``bkrangef2d_``: :func:`bkrangef2d` with the 8-connected line."""
    out = np.array(model, dtype=float, copy=True)
    x = np.asarray(point_xy, dtype=float)
    if x.shape == (2,) and np.all(x == NO_RETURN):
        return out
    apply_measurement(out, pos, x, cell, eight_connected=True)
    return out
