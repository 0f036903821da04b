"""The circle of visibility (*kružnice viditelnosti*): ``MakeCircleOfVisibility`` and ``UpdateCirc``.

A 360-vector around a reference point ``xs``; sector ``k`` covers the directions ``[k, k + 1)`` degrees,
counter-clockwise from +x (the report's MATLAB entry 360 is our entry 0). ``circ[k] == 0`` iff an opaque cell's
closed square intersects the sector's wedge, else 1. A ray leaving ``xs`` inside a free sector therefore touches no
opaque cell, which is what the planners rely on.

Opaque means full by default. The report's main text says "every non-empty cell" leaves a trace, the appendix and
the Viditelnost definition say full; ``block_unknown=True`` also blocks on unknown cells (the candidate's own cell,
which contains ``xs``, is never blocking).
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import FULL, UNKNOWN

__all__ = ["cell_sector_spans", "make_circle_of_visibility", "sector_of", "update_circ"]

N_SECTORS = 360
_CORNERS = np.array([(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)])
# angular tolerance (degrees): a cell whose span ends within this of a sector boundary blocks that sector too
_SECTOR_EPS_DEG = 1e-7


def sector_of(angle_rad) -> np.ndarray:
    """Sector index (0..359) of directions given in radians."""
    deg = np.degrees(np.asarray(angle_rad, dtype=float))
    return np.floor(np.mod(deg, 360.0)).astype(int) % N_SECTORS


def cell_sector_spans(xs, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last sector (may be < 0 or >= 360; wrap with mod 360) blocked by each cell, as seen from ``xs``.

    A cell containing ``xs`` in its interior blocks all sectors (returned as 0 .. 359).
    """
    xs = np.asarray(xs, dtype=float)
    c = np.asarray(cells, dtype=float).reshape(-1, 2)
    rel = c - xs
    interior = (np.abs(rel[:, 0]) < 0.5 - 1e-12) & (np.abs(rel[:, 1]) < 0.5 - 1e-12)
    centre_ang = np.arctan2(rel[:, 1], rel[:, 0])
    v = c[:, None, :] + _CORNERS[None, :, :] - xs
    ang = np.arctan2(v[..., 1], v[..., 0])
    d = np.mod(ang - centre_ang[:, None] + np.pi, 2 * np.pi) - np.pi
    # a corner at xs itself has no direction; it cannot widen the span
    d = np.where(np.hypot(v[..., 0], v[..., 1]) < 1e-12, 0.0, d)
    lo = np.degrees(centre_ang + d.min(axis=1))
    hi = np.degrees(centre_ang + d.max(axis=1))
    k_lo = np.floor(lo - _SECTOR_EPS_DEG).astype(int)
    k_hi = np.floor(hi + _SECTOR_EPS_DEG).astype(int)
    k_lo = np.where(interior, 0, k_lo)
    k_hi = np.where(interior, N_SECTORS - 1, k_hi)
    return k_lo, k_hi


def _block(circ: np.ndarray, k_lo: np.ndarray, k_hi: np.ndarray) -> None:
    if len(k_lo) == 0:
        return
    # difference array over [-360, 720) so that spans crossing 0 deg need no special case
    diff = np.zeros(3 * N_SECTORS + 1, dtype=np.int64)
    np.add.at(diff, k_lo + N_SECTORS, 1)
    np.add.at(diff, k_hi + N_SECTORS + 1, -1)
    covered = np.cumsum(diff[:-1]).reshape(3, N_SECTORS).any(axis=0)
    circ[covered] = 0


def make_circle_of_visibility(
    w: np.ndarray, xs, block_unknown: bool = False, max_distance_cells: float | None = None
) -> np.ndarray:
    """``MakeCircleOfVisibility(M, Xs)``: the circle of ``xs`` built by a pass over the whole grid.

    ``max_distance_cells`` limits the opaque cells to those whose centre is within that distance of ``xs`` (used by
    strategy 1 to find *nearby* full cells); ``None`` uses the whole grid as the report does.
    """
    w = np.asarray(w, dtype=float)
    if w.ndim != 2 or w.size == 0:
        raise NbvInputError(f"the model must be a non-empty 2D grid, got shape {w.shape}")
    xs = np.asarray(xs, dtype=float)
    if xs.shape != (2,) or not np.isfinite(xs).all():
        raise NbvInputError(f"the reference point must be a finite (x, y), got {xs!r}")
    opaque = w == FULL
    if block_unknown:
        unknown = w == UNKNOWN
        # the candidate's own cell (any cell whose closed square holds xs) never hides xs from itself
        for i in range(math.ceil(xs[0] - 0.5 - 1e-9), math.floor(xs[0] + 0.5 + 1e-9) + 1):
            for j in range(math.ceil(xs[1] - 0.5 - 1e-9), math.floor(xs[1] + 0.5 + 1e-9) + 1):
                if 0 <= i < w.shape[0] and 0 <= j < w.shape[1]:
                    unknown[i, j] = False
        opaque = opaque | unknown
    cells = np.argwhere(opaque)
    if max_distance_cells is not None and len(cells):
        cells = cells[np.hypot(*(cells - xs).T) <= max_distance_cells]
    circ = np.ones(N_SECTORS, dtype=np.uint8)
    k_lo, k_hi = cell_sector_spans(xs, cells)
    _block(circ, k_lo, k_hi)
    return circ


def update_circ(circ: np.ndarray, xs, cells, in_place: bool = False) -> np.ndarray:
    """``UpdateCirc(circ, Xs, X)``: zero the sectors touched by the newly opaque cell(s) ``cells`` (k x 2 or (i, j))."""
    c = np.asarray(circ)
    if c.shape != (N_SECTORS,):
        raise NbvInputError(f"a circle of visibility has {N_SECTORS} sectors, got shape {c.shape}")
    out = c if in_place else c.copy()
    cells = np.asarray(cells, dtype=int).reshape(-1, 2)
    k_lo, k_hi = cell_sector_spans(xs, cells)
    _block(out, k_lo, k_hi)
    return out
