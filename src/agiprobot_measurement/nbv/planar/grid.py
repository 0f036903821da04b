"""The report's grid model: values, fusion, neighbourhood masks and the measured points of every full cell.

Values (report, appendix "M matice obsazenosti plochy"):

- ``UNKNOWN = 0`` nothing is known about the cell;
- ``FULL = 1`` the cell belongs to the body;
- ``EMPTY = -1`` the cell is free;
- ``PROBABLY_FULL = 0.1`` and ``PROBABLY_EMPTY = -0.1`` "used by the algorithm itself".

Documented choice (the report does not reconcile ``sgn`` with the +-0.1 values): the fused measurement grid ``M``
holds only {-1, 0, 1}; the +-0.1 marks live only in the planner's working copy ``W``, where they record the
"extra state" of the report's section on cycles: a cell that was a scanning candidate once and is still unknown
gets +0.1 when it was unmeasurable (it borders the surface and could not be seen, so it may be body) and -0.1
otherwise. Because predicates test ``W == UNKNOWN``, a marked cell is never a candidate again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.files import atomic_write, atomic_write_text
from agiprobot_measurement.nbv.planar.errors import NbvInputError

__all__ = [
    "EMPTY",
    "FULL",
    "PROBABLY_EMPTY",
    "PROBABLY_FULL",
    "UNKNOWN",
    "MeasuredPoints",
    "dilate8",
    "fuse",
    "validate_truth",
]

UNKNOWN = 0.0
FULL = 1.0
EMPTY = -1.0
PROBABLY_FULL = 0.1
PROBABLY_EMPTY = -0.1


def fuse(m1: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """The report's fusion of two measurement grids, ``M = sgn(M1 + M2)``.

    A conflict (1 with -1) becomes unknown, agreement is idempotent and unknown is neutral. Inputs must have the same
    shape and be finite; +-0.1 would snap to +-1, which is why only {-1, 0, 1} grids should be fused.
    """
    a = np.asarray(m1, dtype=float)
    b = np.asarray(m2, dtype=float)
    if a.shape != b.shape:
        raise NbvInputError(f"fuse: grids of different shapes {a.shape} and {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise NbvInputError("fuse: grids contain NaN or infinite values")
    return np.sign(a + b)


def dilate8(mask: np.ndarray) -> np.ndarray:
    """Cells with at least one true 8-neighbour (the cell itself excluded); outside the grid counts as false."""
    m = np.asarray(mask, dtype=bool)
    padded = np.zeros((m.shape[0] + 2, m.shape[1] + 2), dtype=bool)
    padded[1:-1, 1:-1] = m
    out = np.zeros_like(m)
    nx, ny = m.shape
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            out |= padded[1 + di : 1 + di + nx, 1 + dj : 1 + dj + ny]
    return out


def dilate4(mask: np.ndarray) -> np.ndarray:
    """Cells with at least one true 4-neighbour (the cell itself excluded)."""
    m = np.asarray(mask, dtype=bool)
    out = np.zeros_like(m)
    out[1:, :] |= m[:-1, :]
    out[:-1, :] |= m[1:, :]
    out[:, 1:] |= m[:, :-1]
    out[:, :-1] |= m[:, 1:]
    return out


def validate_truth(truth: np.ndarray, name: str = "object") -> np.ndarray:
    """Check a ground-truth body and return it as a float grid with FULL (1) and EMPTY (-1).

    Accepts a boolean mask or a numeric grid where values > 0 are body. Raises :class:`NbvInputError` when the
    grid is not 2D, is smaller than 3 x 3, holds NaN, has no body cell, or when the body touches the border (the
    report's scene is bounded with the object wholly inside, so a free ring around it is required).
    """
    arr = np.asarray(truth)
    if arr.ndim != 2:
        raise NbvInputError(f"{name}: the grid must be 2D, got shape {arr.shape}")
    if arr.shape[0] < 3 or arr.shape[1] < 3:
        raise NbvInputError(f"{name}: the grid must be at least 3 x 3 cells, got {arr.shape}")
    if arr.dtype != bool:
        arr = arr.astype(float)
        if not np.isfinite(arr).all():
            raise NbvInputError(f"{name}: the grid contains NaN or infinite values")
        body = arr > 0
    else:
        body = arr
    if not body.any():
        raise NbvInputError(f"{name}: the grid holds no body cell (empty grid)")
    if body[0, :].any() or body[-1, :].any() or body[:, 0].any() or body[:, -1].any():
        raise NbvInputError(f"{name}: the body touches the grid border; leave at least one free cell around it")
    return np.where(body, FULL, EMPTY)


@dataclass
class MeasuredPoints:
    """Every measured point (grid units, sub-cell), kept per cell: the report's remedy for the grid's imprecision.

    ``xy`` are the measured points, ``cells`` the cell each fell into, ``index`` the measurement number. The export
    keeps only points whose cell is full in the given model, i.e. "the list of measured points of every full cell".
    """

    xy: list = field(default_factory=list)
    cells: list = field(default_factory=list)
    index: list = field(default_factory=list)

    def add(self, point_xy: np.ndarray, cell: tuple[int, int], measurement: int) -> None:
        self.xy.append((float(point_xy[0]), float(point_xy[1])))
        self.cells.append((int(cell[0]), int(cell[1])))
        self.index.append(int(measurement))

    def __len__(self) -> int:
        return len(self.xy)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            np.asarray(self.xy, dtype=float).reshape(-1, 2),
            np.asarray(self.cells, dtype=int).reshape(-1, 2),
            np.asarray(self.index, dtype=int),
        )

    def of_full_cells(self, model: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points, cells and measurement numbers of the points whose cell is FULL in ``model``."""
        xy, cells, idx = self.arrays()
        if len(xy) == 0:
            return xy, cells, idx
        keep = np.asarray(model)[cells[:, 0], cells[:, 1]] == FULL
        return xy[keep], cells[keep], idx[keep]

    def points_of_cell(self, cell: tuple[int, int]) -> np.ndarray:
        xy, cells, _ = self.arrays()
        if len(xy) == 0:
            return xy
        return xy[(cells[:, 0] == cell[0]) & (cells[:, 1] == cell[1])]

    def export_csv(self, path: Path | str, model: np.ndarray, cell_size_mm: float = 1.0) -> Path:
        """Write ``x_mm,y_mm,cell_i,cell_j,measurement`` for the points of full cells (atomically); returns the
        path."""
        xy, cells, idx = self.of_full_cells(model)
        path = Path(path)
        data = np.column_stack([xy * cell_size_mm, cells, idx]) if len(xy) else np.zeros((0, 5))

        def write(tmp: Path) -> None:
            np.savetxt(
                tmp,
                data,
                delimiter=",",
                header="x_mm,y_mm,cell_i,cell_j,measurement",
                comments="",
                fmt=["%.6f", "%.6f", "%d", "%d", "%d"],
            )

        atomic_write(path, write)
        return path

    def export_ply(self, path: Path | str, model: np.ndarray, cell_size_mm: float = 1.0) -> Path:
        """Write an ASCII PLY point cloud (z = 0, millimetres) of the points of full cells (atomically); returns the
        path."""
        xy, _, _ = self.of_full_cells(model)
        path = Path(path)
        lines = [
            "ply",
            "format ascii 1.0",
            "comment nbv2d measured points (mm), one slice z = 0",
            f"element vertex {len(xy)}",
            "property float x",
            "property float y",
            "property float z",
            "end_header",
        ]
        lines += [f"{x * cell_size_mm:.6f} {y * cell_size_mm:.6f} 0.0" for x, y in xy]
        atomic_write_text(path, "\n".join(lines) + "\n")
        return path
