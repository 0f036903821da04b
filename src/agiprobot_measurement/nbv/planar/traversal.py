"""Ray traversal on the grid: the report's supercover line (``rangef2d``) and its 8-connected line (``rangef2d_``).

Cell ``(i, j)`` is the closed square ``[i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]``. The *supercover* of a segment is
every cell whose closed square the segment touches at all ("sebemenší část trasované úsečky"), corners included;
cells are listed in the order the segment reaches them. The *8-connected* line samples the segment once per unit
step of its major axis and rounds, as MATLAB line rasterisers do. Both are clipped to the grid (the report's
``TraceLine2D`` ``Bound``). Kernels are numba-compiled because the brute-force measurability and the planners trace
millions of short rays.
"""

# ruff: noqa: RUF046 -- explicit int() keeps numba's integer typing of math.floor / math.ceil unambiguous
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "first_blocking",
    "line8_cells",
    "segment_box_entry",
    "supercover_cells",
]

# Touch tolerance in cells: a segment passing within this distance of a cell edge or corner counts as touching it,
# so that floating-point round-off never lets a ray slip between two cells that share a corner.
TOUCH_EPS = 1e-9


@numba.njit(cache=True)
def _column_span(x0, y0, x1, y1, nx):
    """The segment's columns: (first, last) column index in grid order, clipped to ``nx`` columns."""
    k_lo = max(int(math.ceil(min(x0, x1) - 0.5 - TOUCH_EPS)), 0)
    k_hi = min(int(math.floor(max(x0, x1) + 0.5 + TOUCH_EPS)), nx - 1)
    return k_lo, k_hi


@numba.njit(cache=True)
def _column_rows(k, x0, y0, x1, y1, ny):
    """The rows (first, last; clipped to ``ny`` rows) of the cells of column ``k`` that the segment touches."""
    dx = x1 - x0
    dy = y1 - y0
    if abs(dx) > 1e-15:
        ta = (k - 0.5 - x0) / dx
        tb = (k + 0.5 - x0) / dx
        t_lo = max(0.0, min(ta, tb))
        t_hi = min(1.0, max(ta, tb))
        if t_lo > t_hi:
            # the column is touched only within the tolerance: take the nearer segment end
            t_lo = t_hi = 0.0 if abs(x0 - k) < abs(x1 - k) else 1.0
        ya = y0 + dy * t_lo
        yb = y0 + dy * t_hi
    else:
        ya = y0
        yb = y1
    j_lo = max(int(math.ceil(min(ya, yb) - 0.5 - TOUCH_EPS)), 0)
    j_hi = min(int(math.floor(max(ya, yb) + 0.5 + TOUCH_EPS)), ny - 1)
    return j_lo, j_hi


@numba.njit(cache=True)
def _supercover_into(x0, y0, x1, y1, nx, ny, out):
    """Fill ``out`` (k x 2 int) with the supercover cells of the segment, in order; returns k."""
    k_lo, k_hi = _column_span(x0, y0, x1, y1, nx)
    n = 0
    for c in range(k_hi - k_lo + 1):
        k = k_lo + c if x1 >= x0 else k_hi - c
        j_lo, j_hi = _column_rows(k, x0, y0, x1, y1, ny)
        for r in range(j_hi - j_lo + 1):
            j = j_lo + r if y1 >= y0 else j_hi - r
            if n < out.shape[0]:
                out[n, 0] = k
                out[n, 1] = j
                n += 1
    return n


@numba.njit(cache=True)
def _line8_into(x0, y0, x1, y1, nx, ny, out):
    """Fill ``out`` with the 8-connected rasterisation of the segment (rounded samples), in order; returns k."""
    dx = x1 - x0
    dy = y1 - y0
    steps = int(math.ceil(max(abs(dx), abs(dy))))
    if steps < 1:
        steps = 1
    n = 0
    last_i = -(10**9)
    last_j = -(10**9)
    for s in range(steps + 1):
        t = s / steps
        i = int(math.floor(x0 + dx * t + 0.5))
        j = int(math.floor(y0 + dy * t + 0.5))
        if i == last_i and j == last_j:
            continue
        last_i = i
        last_j = j
        if 0 <= i < nx and 0 <= j < ny and n < out.shape[0]:
            out[n, 0] = i
            out[n, 1] = j
            n += 1
    return n


def _buffer(x0, y0, x1, y1) -> np.ndarray:
    span = int(abs(x1 - x0) + abs(y1 - y0)) + 8
    return np.empty((2 * span, 2), dtype=np.int64)


def supercover_cells(p0, p1, shape) -> np.ndarray:
    """Supercover cells (k x 2, ordered from ``p0`` to ``p1``) of the segment, clipped to a grid of ``shape``."""
    x0, y0 = float(p0[0]), float(p0[1])
    x1, y1 = float(p1[0]), float(p1[1])
    buf = _buffer(x0, y0, x1, y1)
    n = _supercover_into(x0, y0, x1, y1, int(shape[0]), int(shape[1]), buf)
    return buf[:n].copy()


def line8_cells(p0, p1, shape) -> np.ndarray:
    """8-connected cells (k x 2, ordered) of the segment, clipped to a grid of ``shape``."""
    x0, y0 = float(p0[0]), float(p0[1])
    x1, y1 = float(p1[0]), float(p1[1])
    buf = _buffer(x0, y0, x1, y1)
    n = _line8_into(x0, y0, x1, y1, int(shape[0]), int(shape[1]), buf)
    return buf[:n].copy()


@numba.njit(cache=True)
def _supercover_first(blocking, x0, y0, x1, y1, skip_i, skip_j):
    """First supercover cell with ``blocking`` true, other than (skip_i, skip_j); (-1, -1) if none.

    The same walk as :func:`_supercover_into` without a buffer, for the hot loops (planner checks, brute force).
    """
    nx, ny = blocking.shape
    k_lo, k_hi = _column_span(x0, y0, x1, y1, nx)
    for c in range(k_hi - k_lo + 1):
        k = k_lo + c if x1 >= x0 else k_hi - c
        j_lo, j_hi = _column_rows(k, x0, y0, x1, y1, ny)
        for r in range(j_hi - j_lo + 1):
            j = j_lo + r if y1 >= y0 else j_hi - r
            if blocking[k, j] and not (k == skip_i and j == skip_j):
                return k, j
    return -1, -1


@numba.njit(cache=True)
def _first_blocking(blocking, x0, y0, x1, y1, skip_i, skip_j, eight):
    """First cell of the traversal with ``blocking`` true, other than (skip_i, skip_j); (-1, -1) if none."""
    if not eight:
        return _supercover_first(blocking, x0, y0, x1, y1, skip_i, skip_j)
    span = int(abs(x1 - x0) + abs(y1 - y0)) + 8
    buf = np.empty((2 * span, 2), dtype=np.int64)
    nx, ny = blocking.shape
    n = _line8_into(x0, y0, x1, y1, nx, ny, buf)
    for q in range(n):
        i = buf[q, 0]
        j = buf[q, 1]
        if i == skip_i and j == skip_j:
            continue
        if blocking[i, j]:
            return i, j
    return -1, -1


def first_blocking(blocking: np.ndarray, p0, p1, skip=(-1, -1), eight_connected: bool = False) -> tuple[int, int]:
    """First cell along ``p0 -> p1`` where ``blocking`` is true (``skip`` ignored), or ``(-1, -1)``."""
    i, j = _first_blocking(
        np.ascontiguousarray(blocking, dtype=np.bool_),
        float(p0[0]),
        float(p0[1]),
        float(p1[0]),
        float(p1[1]),
        int(skip[0]),
        int(skip[1]),
        bool(eight_connected),
    )
    return int(i), int(j)


@numba.njit(cache=True)
def _segment_box_entry(x0, y0, x1, y1, ci, cj):
    """Parameter t in [0, 1] where the segment first touches the closed square of cell (ci, cj); -1 if never."""
    t_enter = 0.0
    t_exit = 1.0
    d = (x1 - x0, y1 - y0)
    o = (x0, y0)
    c = (ci, cj)
    for a in range(2):
        lo = c[a] - 0.5
        hi = c[a] + 0.5
        if abs(d[a]) < 1e-15:
            if o[a] < lo - TOUCH_EPS or o[a] > hi + TOUCH_EPS:
                return -1.0
        else:
            ta = (lo - o[a]) / d[a]
            tb = (hi - o[a]) / d[a]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t_enter:
                t_enter = ta
            if tb < t_exit:
                t_exit = tb
    if t_enter > t_exit + TOUCH_EPS:
        return -1.0
    return t_enter


def segment_box_entry(p0, p1, cell) -> float:
    """Where (parameter ``t`` of ``p0 + t (p1 - p0)``) the segment enters the square of ``cell``; -1 if it misses."""
    return float(_segment_box_entry(float(p0[0]), float(p0[1]), float(p1[0]), float(p1[1]), int(cell[0]), int(cell[1])))
