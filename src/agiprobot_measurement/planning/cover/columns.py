"""Set-cover input: the measurability matrix as column-wise sparse sets, per-view worst uncertainties and
normalised costs (the first step of :func:`~agiprobot_measurement.planning.cover.solve.solve_set_cover`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy import sparse

from agiprobot_measurement.errors import InputError

__all__ = [
    "ColumnSets",
    "SetCoverError",
    "column_max",
    "measurable_columns",
    "normalised_costs",
    "worst_uncertainty",
]


class SetCoverError(InputError):
    """Invalid input to the set-cover solvers."""


@dataclass
class ColumnSets:
    """Column-wise sparse sets: column j holds the rows ``indices[indptr[j]:indptr[j + 1]]`` (sorted)."""

    indptr: np.ndarray
    indices: np.ndarray
    n_rows: int

    @property
    def n_cols(self) -> int:
        return self.indptr.size - 1

    def sizes(self) -> np.ndarray:
        return np.diff(self.indptr)

    def col(self, j: int) -> np.ndarray:
        return self.indices[self.indptr[j] : self.indptr[j + 1]]

    def take(self, which: np.ndarray) -> ColumnSets:
        """The columns ``which`` (same rows), renumbered 0.."""
        sizes = self.indptr[which + 1] - self.indptr[which]
        indptr = np.zeros(which.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=indptr[1:])
        if which.size > 1 and 4 * indptr[-1] > self.indices.size and bool(np.all(which[1:] > which[:-1])):
            # most entries of ascending columns: a boolean mask over the entries (1 byte each) instead of
            # their positions (8 bytes each; tens of millions of entries at tilt full)
            chosen = np.zeros(self.n_cols, dtype=bool)
            chosen[which] = True
            return ColumnSets(indptr, self.indices[np.repeat(chosen, self.sizes())], self.n_rows)
        # Flat positions of all entries of the chosen columns, without a Python loop.
        pos = np.repeat(self.indptr[which] - indptr[:-1], sizes) + np.arange(indptr[-1])
        return ColumnSets(indptr, self.indices[pos], self.n_rows)

    def reduced_costs(self, costs: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``c_j - a_j . y`` for every column (empty columns: their cost), summed in one compiled pass over the
        entries: no matrix of ones (8 bytes per entry, a gigabyte at tilt full) is built for it."""
        return costs - _column_sums(self.indptr, self.indices, np.ascontiguousarray(y, dtype=np.float64))

    def dual_ascent_bound(self, costs: np.ndarray) -> float:
        """A lower bound of every cover's cost (``costs`` (n_cols,) >= 0) without an LP: rows in order of fewest
        columns, each row's dual the least residual cost of its columns, taken off their residuals. The duals are
        >= 0 and no column's residual goes below 0, so their sum bounds every cover's cost (weak LP duality); it is
        weaker than the LP's bound, for when the LP did not solve in time. Rows without columns are skipped."""
        rows = self.transpose()
        order = np.argsort(rows.sizes(), kind="stable")
        return float(_dual_ascent(rows.indptr, rows.indices, order, np.array(costs, dtype=np.float64)))

    def transpose(self) -> ColumnSets:
        """The rows as columns (each row's columns sorted), by a compiled counting sort: one output array, no
        sparse matrix of values and no sort (a scipy conversion took 5 s and 1 GB on 88 M entries, tilt full)."""
        index_type = np.int32 if max(self.indices.size, self.n_cols) < 2**31 else np.int64
        counts = np.bincount(self.indices, minlength=self.n_rows)
        indptr = np.zeros(self.n_rows + 1, dtype=index_type)
        np.cumsum(counts, out=indptr[1:])
        indices = _transpose_entries(self.indptr, self.indices, indptr, np.empty(self.indices.size, dtype=index_type))
        return ColumnSets(indptr, indices, self.n_cols)


@numba.njit(cache=True)
def _column_sums(indptr, indices, y):
    """Per column, the sum of ``y`` over its rows (in entry order, as a sparse product of ones adds them)."""
    out = np.zeros(indptr.size - 1)
    for j in range(indptr.size - 1):
        total = 0.0
        for k in range(indptr[j], indptr[j + 1]):
            total += y[indices[k]]
        out[j] = total
    return out


@numba.njit(cache=True)
def _dual_ascent(row_ptr, row_cols, order, residual):
    """The sum of the duals of :meth:`ColumnSets.dual_ascent_bound` (``residual`` is changed in place)."""
    total = 0.0
    for i in order:
        start, stop = row_ptr[i], row_ptr[i + 1]
        if start == stop:
            continue
        dual = np.inf
        for k in range(start, stop):
            dual = min(dual, residual[row_cols[k]])
        if dual > 0.0:
            for k in range(start, stop):
                residual[row_cols[k]] -= dual
            total += dual
    return total


@numba.njit(cache=True)
def _transpose_entries(indptr, indices, row_start, out):
    """Each entry's column into its row's slice of ``out`` (rows start at ``row_start``), columns in order."""
    fill = row_start[:-1].copy()
    for j in range(indptr.size - 1):
        for k in range(indptr[j], indptr[j + 1]):
            i = indices[k]
            out[fill[i]] = j
            fill[i] += 1
    return out


def measurable_columns(matrix) -> tuple[ColumnSets, np.ndarray | None]:
    """Canonical column sets of the measurable entries and, for numeric input, their values."""
    if sparse.issparse(matrix):
        csc = matrix.tocsc()
        if csc is matrix and not csc.has_canonical_format:
            csc = csc.copy()  # canonicalising works in place: leave the caller's matrix alone
    else:
        dense = np.asarray(matrix)
        if dense.ndim != 2:
            raise SetCoverError(f"matrix must be 2-D (points x views), got shape {dense.shape}")
        csc = sparse.csc_array(dense)
    csc.sum_duplicates()
    csc.sort_indices()
    n_rows, n_cols = csc.shape
    # int32 positions halve the memory traffic of every gather below (nnz stays far below 2**31 here).
    small = csc.nnz < 2**31 - 1
    indptr = csc.indptr.astype(np.int32, copy=False) if small else csc.indptr
    indices = csc.indices.astype(np.int32, copy=False) if small else csc.indices
    data = csc.data
    if data.dtype == bool:
        keep, values = data, None
        all_kept = bool(keep.all())
    elif np.issubdtype(data.dtype, np.number):
        values = data.astype(np.float64, copy=False)
        # Fast path for the usual input (all stored values positive and finite): two passes, no copies.
        positive = values > 0.0
        all_kept = bool(positive.all()) and (values.size == 0 or math.isfinite(float(values.max())))
        if not all_kept:
            if np.any(values < 0.0) or np.any(np.isinf(values)):
                raise SetCoverError("uncertainty values in the matrix must be finite and non-negative")
            keep = positive  # zero and NaN entries are not measurable
    else:
        raise SetCoverError(f"matrix dtype {data.dtype} is neither boolean nor numeric")
    if all_kept:
        return ColumnSets(indptr, indices, n_rows), values
    col_of_entry = np.repeat(np.arange(n_cols), np.diff(indptr))
    counts = np.bincount(col_of_entry[keep], minlength=n_cols)
    new_indptr = np.zeros(n_cols + 1, dtype=indptr.dtype)
    np.cumsum(counts, out=new_indptr[1:])
    return ColumnSets(new_indptr, indices[keep], n_rows), None if values is None else values[keep]


def column_max(cols: ColumnSets, values: np.ndarray) -> np.ndarray:
    """Per-column maximum of ``values`` (aligned with ``cols.indices``); 0 for empty columns."""
    out = np.zeros(cols.n_cols)
    nonempty = np.nonzero(cols.sizes() > 0)[0]
    if nonempty.size:
        # reduceat segments run from one start to the next; empty columns in between hold no entries, so
        # every segment is exactly one non-empty column.
        out[nonempty] = np.maximum.reduceat(values, cols.indptr[nonempty])
    return out


def worst_uncertainty(cols: ColumnSets, values, uncertainties) -> np.ndarray | None:
    """Worst (maximum) uncertainty per view, or None when nothing gives uncertainties."""
    if uncertainties is None:
        return None if values is None else column_max(cols, values)
    if sparse.issparse(uncertainties) or np.ndim(uncertainties) == 2:
        if tuple(uncertainties.shape) != (cols.n_rows, cols.n_cols):
            raise SetCoverError(
                f"uncertainties matrix has shape {tuple(uncertainties.shape)}, expected {(cols.n_rows, cols.n_cols)}"
            )
        u = sparse.csc_array(uncertainties, dtype=np.float64)
        mask = sparse.csc_array(
            (np.ones(cols.indices.size), cols.indices, cols.indptr), shape=(cols.n_rows, cols.n_cols)
        )
        u = sparse.csc_array(u.multiply(mask))  # only the measurable entries count
        u.sum_duplicates()
        if u.data.size and (np.any(u.data < 0.0) or not np.all(np.isfinite(u.data))):
            raise SetCoverError("uncertainties must be finite and non-negative")
        return column_max(ColumnSets(u.indptr, u.indices, cols.n_rows), u.data)
    per_view = np.asarray(uncertainties, dtype=np.float64)
    if per_view.shape != (cols.n_cols,):
        raise SetCoverError(
            f"uncertainties must be one value per view ({cols.n_cols}) or a points x views matrix, "
            f"got shape {per_view.shape}"
        )
    if not np.all(np.isfinite(per_view)) or np.any(per_view < 0.0):
        raise SetCoverError("uncertainties must be finite and non-negative")
    return per_view


def normalised_costs(costs: np.ndarray) -> np.ndarray:
    top = float(costs.max()) if costs.size else 0.0
    return costs / top if top > 0.0 else costs.copy()
