"""The report's predicates and helpers on the planner's working grid ``W`` (section "Terminologie", appendix).

- growth point (*růstový bod*): a full cell with unknown cells nearby;
- scanning candidate (*kandidát na snímání*): an unknown cell 8-adjacent to a full cell; ``getcandidates2d`` is
  stricter: the candidate must be unknown and 8-adjacent to *both* an empty cell and the growth point ``X``;
- predicted point (*predikovaný bod*): the candidate next to the growth point that lies closest to the contour
  line fitted (least squares) through the growth point and its full neighbours (``ComputeDirection`` over the
  points of ``TraceContour``).

Documented choice: the growth points that drive the run (``getpoints2d``, ``verifypoint2d``, ``GetNearestPP``) are
the full cells that still have a ``getcandidates2d`` candidate, so that "a growth point whose candidates are
exhausted stops being a growth point" holds literally. The looser report definition is :func:`general_growth_mask`.
Only ``W == 0`` counts as unknown: cells marked +-0.1 by the planner are never candidates again.

Documented choice (contour ends): ``getcandidates2d``'s rule needs an empty cell next to the candidate. At an acute
apex the space beyond the apex is often still unknown (no ray has passed there), so the strict rule finds no
candidate and the contour would stop at the apex although the report's growth point ("a full point with unknown
region nearby") is still there. A *contour end* is a full cell whose full 8-neighbours all lie within 45 degrees of their mean
direction (the end of a straight or staircase run, or an acute apex; a right-angle corner and an isolated cell are
not ends). A contour end
without a strict candidate takes the report's general candidates instead: its unknown 8-neighbours. Each such
candidate is still a candidate at most once, so termination is unaffected.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN, dilate8

__all__ = [
    "candidate_mask",
    "compute_direction",
    "contour_end_mask",
    "driving_candidate_mask",
    "general_growth_mask",
    "get_distance_vc",
    "get_nearest_pp",
    "getcandidates2d",
    "getpoints2d",
    "growth_mask",
    "outward_normal",
    "predicted_point",
    "strict_candidate_mask",
    "trace_contour",
    "verifypoint2d",
]

_NEIGHBOURS = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)], dtype=int)
_NEIGHBOUR_NORM = np.hypot(_NEIGHBOURS[:, 0], _NEIGHBOURS[:, 1]).astype(float)
# a contour end: every full neighbour within 45 degrees of their mean direction (a 90-degree corner is not an end)
_END_COS = math.cos(math.radians(45.0)) + 1e-9
NONE_CELL = (-1, -1)


def _check_grid(w: np.ndarray) -> np.ndarray:
    arr = np.asarray(w, dtype=float)
    if arr.ndim != 2 or arr.size == 0:
        raise NbvInputError(f"the model must be a non-empty 2D grid, got shape {arr.shape}")
    return arr


def _inside(w: np.ndarray, cell) -> bool:
    return 0 <= cell[0] < w.shape[0] and 0 <= cell[1] < w.shape[1]


def candidate_mask(w: np.ndarray) -> np.ndarray:
    """Scanning candidates, general rule: unknown cells 8-adjacent to a full cell."""
    w = _check_grid(w)
    return (w == UNKNOWN) & dilate8(w == FULL)


def strict_candidate_mask(w: np.ndarray) -> np.ndarray:
    """Cells that are a ``getcandidates2d`` candidate of some full cell: unknown, next to empty and to full."""
    w = _check_grid(w)
    return (w == UNKNOWN) & dilate8(w == EMPTY) & dilate8(w == FULL)


def contour_end_mask(w: np.ndarray) -> np.ndarray:
    """Full cells at the end of a measured contour: all full 8-neighbours on one side (see the module docstring)."""
    w = _check_grid(w)
    full = w == FULL
    padded = np.zeros((w.shape[0] + 2, w.shape[1] + 2), dtype=bool)
    padded[1:-1, 1:-1] = full
    cells = np.argwhere(full)
    out = np.zeros_like(full)
    if len(cells) == 0:
        return out
    nb = padded[cells[:, :1] + 1 + _NEIGHBOURS[:, 0], cells[:, 1:] + 1 + _NEIGHBOURS[:, 1]]  # k x 8
    s = (nb.astype(np.int64) @ _NEIGHBOURS).astype(float)  # k x 2: sum of the full neighbours' offsets
    cos = (s @ _NEIGHBOURS.T) / (np.hypot(*s.T)[:, None] * _NEIGHBOUR_NORM[None, :] + 1e-300)  # k x 8
    end = nb.any(axis=1) & (~nb | (cos > _END_COS)).all(axis=1)
    out[cells[end, 0], cells[end, 1]] = True
    return out


def driving_candidate_mask(w: np.ndarray) -> np.ndarray:
    """Every cell that is a candidate of some driving growth point: the ``getcandidates2d`` candidates of all full
    cells, plus the unknown 8-neighbours of the contour ends that have no such candidate."""
    w = _check_grid(w)
    unknown = w == UNKNOWN
    strict = unknown & dilate8(w == EMPTY)
    full = w == FULL
    has_strict = full & dilate8(strict)
    bare_ends = contour_end_mask(w) & ~has_strict
    return (strict & dilate8(full)) | (unknown & dilate8(bare_ends))


def general_growth_mask(w: np.ndarray) -> np.ndarray:
    """The report's literal growth points: full cells with an unknown 8-neighbour."""
    w = _check_grid(w)
    return (w == FULL) & dilate8(w == UNKNOWN)


def growth_mask(w: np.ndarray) -> np.ndarray:
    """Growth points that drive the run: full cells with at least one ``getcandidates2d`` candidate (contour ends
    included, see the module docstring)."""
    w = _check_grid(w)
    unknown = w == UNKNOWN
    strict = (w == FULL) & dilate8(unknown & dilate8(w == EMPTY))
    return strict | (contour_end_mask(w) & dilate8(unknown))


def _is_contour_end(w: np.ndarray, x) -> bool:
    if not _inside(w, x) or w[x] != FULL:
        return False
    offs = [
        (int(di), int(dj))
        for di, dj in _NEIGHBOURS
        if _inside(w, (x[0] + di, x[1] + dj)) and w[x[0] + di, x[1] + dj] == FULL
    ]
    if not offs:
        return False
    sx, sy = sum(o[0] for o in offs), sum(o[1] for o in offs)
    ns = float(np.hypot(sx, sy))
    return ns > 0 and all((o[0] * sx + o[1] * sy) / (ns * float(np.hypot(*o))) > _END_COS for o in offs)


def getcandidates2d(w: np.ndarray, x) -> np.ndarray:
    """Candidates of the growth point ``x`` (k x 2, neighbour order E, NE, N, NW, W, SW, S, SE); may be empty.

    The report's rule (unknown, 8-adjacent to an empty cell and to ``x``); at a contour end with no such candidate,
    the unknown 8-neighbours of ``x`` (see the module docstring).
    """
    w = _check_grid(w)
    x = (int(x[0]), int(x[1]))
    out = _strict_candidates(w, x)
    if len(out) == 0 and _is_contour_end(w, x):
        out = [
            (x[0] + int(di), x[1] + int(dj))
            for di, dj in _NEIGHBOURS
            if _inside(w, (x[0] + di, x[1] + dj)) and w[x[0] + di, x[1] + dj] == UNKNOWN
        ]
    return np.asarray(out, dtype=int).reshape(-1, 2)


def _strict_candidates(w: np.ndarray, x) -> list:
    out = []
    for di, dj in _NEIGHBOURS:
        c = (x[0] + di, x[1] + dj)
        if not _inside(w, c) or w[c] != UNKNOWN:
            continue
        i0, i1 = max(c[0] - 1, 0), min(c[0] + 2, w.shape[0])
        j0, j1 = max(c[1] - 1, 0), min(c[1] + 2, w.shape[1])
        if (w[i0:i1, j0:j1] == EMPTY).any():
            out.append(c)
    return out


def verifypoint2d(w: np.ndarray, p) -> int:
    """1 if ``p`` is (still) a growth point, else 0 (report's return convention)."""
    w = _check_grid(w)
    p = (int(p[0]), int(p[1]))
    if not _inside(w, p) or w[p] != FULL:
        return 0
    return int(len(getcandidates2d(w, p)) > 0)


def getpoints2d(w: np.ndarray) -> np.ndarray:
    """All growth points (k x 2), or ``[[-1, -1]]`` when there is none (report's convention)."""
    pts = np.argwhere(growth_mask(w))
    return pts if len(pts) else np.array([NONE_CELL], dtype=int)


def get_nearest_pp(w: np.ndarray, p: np.ndarray | None, pp_old) -> tuple[int, int]:
    """``GetNearestPP``: the growth point nearest to ``pp_old`` that :func:`verifypoint2d` confirms.

    ``p`` is the list of growth points (k x 2); ``None`` recomputes it from ``w``. Ties go to the first in ``p``
    (row-major order for a recomputed list). Returns ``(-1, -1)`` when none remains.
    """
    w = _check_grid(w)
    pts = np.argwhere(growth_mask(w)) if p is None else np.asarray(p, dtype=int).reshape(-1, 2)
    if len(pts) == 0 or (len(pts) == 1 and tuple(pts[0]) == NONE_CELL):
        return NONE_CELL
    d2 = ((pts - np.asarray(pp_old, dtype=float)) ** 2).sum(axis=1)
    for k in np.argsort(d2, kind="stable"):
        cand = (int(pts[k, 0]), int(pts[k, 1]))
        if verifypoint2d(w, cand):
            return cand
    return NONE_CELL


def trace_contour(w: np.ndarray, x, count: int) -> np.ndarray:
    """``TraceContour``: up to ``count`` full contour cells reached from ``x`` along 8-connected full cells.

    Breadth-first, so the cells nearest (in steps) to ``x`` come first; ``x`` itself is the first row. A contour
    cell is a full cell with a non-full 8-neighbour (in a measured model nearly every full cell is one).
    """
    w = _check_grid(w)
    if count < 1:
        raise NbvInputError(f"trace_contour: count must be >= 1, got {count}")
    x = (int(x[0]), int(x[1]))
    if not _inside(w, x) or w[x] != FULL:
        return np.zeros((0, 2), dtype=int)
    seen = {x}
    order = [x]
    queue = deque([x])
    while queue and len(order) < count:
        c = queue.popleft()
        for di, dj in _NEIGHBOURS:
            n = (c[0] + di, c[1] + dj)
            if n in seen or not _inside(w, n) or w[n] != FULL:
                continue
            i0, i1 = max(n[0] - 1, 0), min(n[0] + 2, w.shape[0])
            j0, j1 = max(n[1] - 1, 0), min(n[1] + 2, w.shape[1])
            if not (w[i0:i1, j0:j1] != FULL).any():
                continue
            seen.add(n)
            order.append(n)
            queue.append(n)
            if len(order) >= count:
                break
    return np.asarray(order, dtype=int)


def compute_direction(w: np.ndarray, x, count: int) -> np.ndarray | None:
    """``ComputeDirection``: unit direction of the least-squares (total least squares) line through at most
    ``count`` contour points from ``x``; ``None`` when fewer than two points exist.

    The sign is chosen to point from the traced contour's centroid towards ``x``, i.e. where the contour continues.
    """
    pts = trace_contour(w, x, count).astype(float)
    if len(pts) < 2:
        return None
    centred = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    direction = vt[0]
    ahead = np.asarray(x, dtype=float) - pts.mean(axis=0)
    if np.dot(direction, ahead) < 0:
        direction = -direction
    return direction / np.linalg.norm(direction)


def get_distance_vc(x1, x2, p) -> float:
    """``GetDistanceVC``: distance of ``p`` from the line through ``x1`` and ``x2``."""
    a = np.asarray(x1, dtype=float)
    b = np.asarray(x2, dtype=float)
    q = np.asarray(p, dtype=float)
    v = b - a
    n = np.hypot(*v)
    if n == 0:
        raise NbvInputError("get_distance_vc: the two line points coincide")
    return float(abs(v[0] * (q[1] - a[1]) - v[1] * (q[0] - a[0])) / n)


def outward_normal(w: np.ndarray, x, direction: np.ndarray | None, radius_cells: int = 2) -> np.ndarray | None:
    """Unit normal of the contour at ``x`` pointing to the empty side (``None`` if no empty cell is near).

    With a ``direction`` the normal is perpendicular to it, oriented towards the empty cells within
    ``radius_cells``; without one it is the mean direction to those empty cells.
    """
    w = _check_grid(w)
    i0, i1 = max(x[0] - radius_cells, 0), min(x[0] + radius_cells + 1, w.shape[0])
    j0, j1 = max(x[1] - radius_cells, 0), min(x[1] + radius_cells + 1, w.shape[1])
    empties = np.argwhere(w[i0:i1, j0:j1] == EMPTY) + np.array([i0, j0])
    if len(empties) == 0:
        return None
    towards = (empties - np.asarray(x, dtype=float)).sum(axis=0)
    if direction is None:
        n = np.hypot(*towards)
        return None if n == 0 else towards / n
    normal = np.array([-direction[1], direction[0]])
    if np.dot(normal, towards) < 0:
        normal = -normal
    return normal


def predicted_point(w: np.ndarray, x, count: int = 7) -> tuple[int, int] | None:
    """The predicted point among ``getcandidates2d(w, x)``: the candidate nearest the contour line through ``x``.

    Ties (and the case without a line) go to the candidate furthest ahead along the contour direction, then to the
    neighbour order of :func:`getcandidates2d`. ``None`` when ``x`` has no candidate.
    """
    cands = getcandidates2d(w, x)
    if len(cands) == 0:
        return None
    direction = compute_direction(w, x, count)
    if direction is None:
        return int(cands[0, 0]), int(cands[0, 1])
    xf = np.asarray(x, dtype=float)
    rel = cands - xf
    dist = np.abs(rel[:, 0] * direction[1] - rel[:, 1] * direction[0])
    ahead = rel @ direction
    order = np.lexsort((-ahead, np.round(dist, 9)))
    k = order[0]
    return int(cands[k, 0]), int(cands[k, 1])
