"""The report's view score ``Pohled = Viditelnost x Kolmost x Pohyb`` over the sectors of the circle of visibility.

- Viditelnost (visibility): 1 when both the laser's and the camera's sector are free in the circle of the aim point
  (the two-ray condition), else 0.
- Kolmost (perpendicularity), eq. (4): ``w cos(a) + 1 - w`` with ``a`` the angle between the contour's outward
  normal and the direction to the source, ``w = 0.5`` by default. Documented choice: the value is clipped to
  [0, 1], which changes nothing for ``w <= 0.5`` and keeps every term in [0, 1] as the report requires.
- Option: a source on the inner side of the contour line (angle to the outward normal > 90 deg) looks through the
  body the contour bounds; ``ScoreConfig.front_only=True`` gives such views Viditelnost 0. Default off: on the
  benchmark it helps the U-shape's slot (fullpix 0.824 -> 0.848) but costs elsewhere (rotated rectangle, stratpix,
  long baseline, edge midpoints: 0.987 -> 0.263), so the report's circle alone decides.
- Documented choice (``ScoreConfig.camera_front``, default on): the camera must lie on the outer side of the contour
  line (its direction from the aim point makes an angle below 90 deg with the outward normal). A surface point is
  seen only from in front of its tangent; the circle of visibility blocks only on full cells, so without this
  the camera was often placed behind the unexplored part of the body and the return never came (E0). It matters
  with a long baseline: with RFlength 250 and depth noise 0.3 cells the disc's coverage went 0.10 -> 0.89. The
  loop leaves it off for a contour end's general candidates (see :mod:`.predicates`), whose outer side is not
  known yet.
- Pohyb (motion): the report gives no formula. ``"angular"`` (default) is ``1 - dtheta / pi`` with ``dtheta`` the
  angle, seen from the aim point, between the candidate source and the current source; ``"distance"`` is
  ``exp(-d / scale)`` of the source displacement ``d`` (``scale`` defaults to the standoff); ``"none"`` is 1.

The best view is the argmax. Tie rule (documented choice): the smaller source displacement, then the lower aim
index, sector and side (+1 before -1) - a deterministic order.

Candidate views are one per sector centre (``k + 0.5`` degrees) and camera side, for each aim point: the cell
centre or, with ``aim="edge_midpoints"``, the four midpoints of the cell's edges planned simultaneously (the
report's proposed remedy in its section 7.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.visibility import N_SECTORS, sector_of

__all__ = ["AIM_MODES", "MOTION_MODES", "ScoreConfig", "ViewSet", "aim_points", "kolmost", "pohyb", "score_views"]

AIM_MODES = ("centre", "edge_midpoints")
MOTION_MODES = ("angular", "distance", "none")
_EDGE_OFFSETS = np.array([(0.5, 0.0), (0.0, 0.5), (-0.5, 0.0), (0.0, -0.5)])


@dataclass(frozen=True)
class ScoreConfig:
    """Weights of the view score (dimensionless) and the Pohyb model."""

    kolmost_weight: float = 0.5
    motion: str = "angular"
    motion_scale_cells: float | None = None
    # option: views from behind the contour line (angle to the outward normal > 90 deg) are invisible
    front_only: bool = False
    # option: the camera must look at the candidate from the outer side of the contour line
    camera_front: bool = True

    def __post_init__(self) -> None:
        w = float(self.kolmost_weight)
        if not math.isfinite(w) or not 0.0 < w < 1.0:
            raise NbvInputError(f"kolmost_weight must lie in (0, 1), got {self.kolmost_weight!r}")
        if self.motion not in MOTION_MODES:
            raise NbvInputError(f"motion must be one of {MOTION_MODES}, got {self.motion!r}")
        if self.motion_scale_cells is not None:
            s = float(self.motion_scale_cells)
            if not math.isfinite(s) or s <= 0:
                raise NbvInputError(f"motion_scale_cells must be > 0 cells, got {self.motion_scale_cells!r}")


def aim_points(cell, aim: str) -> np.ndarray:
    """Aim points of a cell (k x 2): its centre, or the midpoints of its four edges."""
    if aim not in AIM_MODES:
        raise NbvInputError(f"aim must be one of {AIM_MODES}, got {aim!r}")
    c = np.asarray(cell, dtype=float).reshape(1, 2)
    return c.copy() if aim == "centre" else c + _EDGE_OFFSETS


def kolmost(normal, source_dir_rad, weight: float) -> np.ndarray:
    """Eq. (4), clipped to [0, 1]; 1 everywhere when no normal is known."""
    phi = np.asarray(source_dir_rad, dtype=float)
    if normal is None:
        return np.ones_like(phi)
    cos_a = np.cos(phi) * normal[0] + np.sin(phi) * normal[1]
    return np.clip(weight * cos_a + 1.0 - weight, 0.0, 1.0)


def pohyb(sources: np.ndarray, aims: np.ndarray, current_source, cfg: ScoreConfig, standoff_cells: float):
    """Pohyb for candidate sources (n x 2) aimed at ``aims`` (n x 2), from ``current_source`` (None -> 1)."""
    n = len(sources)
    if current_source is None or cfg.motion == "none":
        return np.ones(n)
    cur = np.asarray(current_source, dtype=float)
    if cfg.motion == "distance":
        scale = cfg.motion_scale_cells or standoff_cells
        return np.exp(-np.hypot(*(sources - cur).T) / scale)
    a = sources - aims
    b = cur - aims
    cosang = (a * b).sum(axis=1) / (np.hypot(*a.T) * np.hypot(*b.T) + 1e-300)
    return 1.0 - np.arccos(np.clip(cosang, -1.0, 1.0)) / math.pi


@dataclass
class ViewSet:
    """Candidate views of one target, ranked best first (``order``)."""

    poses: np.ndarray  # n x 3 x 2
    aim_index: np.ndarray
    sector: np.ndarray
    side: np.ndarray
    visibility: np.ndarray
    kolmost: np.ndarray
    pohyb: np.ndarray
    score: np.ndarray
    move_cells: np.ndarray
    order: np.ndarray

    def ranked(self):
        """Indices with a positive score, best first."""
        return self.order[self.score[self.order] > 0]


def score_views(
    rf,
    aims: np.ndarray,
    circles: np.ndarray,
    normal,
    current_source,
    cfg: ScoreConfig,
    forbidden: np.ndarray | None = None,
    term: np.ndarray | None = None,
    camera_circles: np.ndarray | None = None,
) -> ViewSet:
    """Score every (aim, sector, side) view.

    ``circles`` (a x 360) are the circles of visibility of the aims; ``forbidden`` (a x 360 x 2, side +1 at 0) zeroes
    configurations banned after D0/E0; ``term`` (a x 360, optional) replaces Kolmost (strategy 1 uses the
    visibility of nearby full cells through the candidate instead); ``camera_circles`` (a x 360, optional) are
    used for the camera's sector instead of ``circles`` (the frontier re-acquisition blocks the laser on every cell
    that is not known empty, the camera on fewer).
    """
    aims = np.asarray(aims, dtype=float).reshape(-1, 2)
    na = len(aims)
    sectors = np.arange(N_SECTORS)
    phi = np.radians(sectors + 0.5)
    a_idx = np.repeat(np.arange(na), 2 * N_SECTORS)
    sec = np.tile(np.repeat(sectors, 2), na)
    side = np.tile(np.array([1, -1]), na * N_SECTORS)
    phis = phi[sec]
    poses = rf.poses(aims[a_idx], phis, side)
    src, cam = poses[:, 0], poses[:, 1]
    cam_dir = np.arctan2(cam[:, 1] - aims[a_idx, 1], cam[:, 0] - aims[a_idx, 0])
    cam_sec = sector_of(cam_dir)
    cam_circles = circles if camera_circles is None else camera_circles
    vis = (circles[a_idx, sec] > 0) & (cam_circles[a_idx, cam_sec] > 0)
    if forbidden is not None:
        vis &= ~forbidden[a_idx, sec, (1 - side) // 2]
    if term is None and normal is not None and cfg.front_only:
        # a source behind the contour line looks at the candidate through the body that the contour bounds: the
        # circle cannot show that (the body's inside is unknown, not full), so such a view is taken as not visible
        vis &= (np.cos(phis) * normal[0] + np.sin(phis) * normal[1]) >= 0.0
    if term is None and normal is not None and cfg.camera_front:
        vis &= (np.cos(cam_dir) * normal[0] + np.sin(cam_dir) * normal[1]) > 0.0
    k = kolmost(normal, phis, cfg.kolmost_weight) if term is None else term[a_idx, sec]
    p = pohyb(src, aims[a_idx], current_source, cfg, rf.standoff_cells)
    score = vis * k * p
    move = np.zeros(len(src)) if current_source is None else np.hypot(*(src - np.asarray(current_source)).T)
    order = np.lexsort((side == -1, sec, a_idx, np.round(move, 9), -np.round(score, 12)))
    return ViewSet(poses, a_idx, sec, side, vis, k, p, score, move, order)
