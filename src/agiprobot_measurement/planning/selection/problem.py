"""The set cover's problem from the run's views: which points each view may still measure, its worst
uncertainty and its duration.

The columns of the coverage store are read without copying their values (the store holds tens of millions of
entries at tilt full); views that are not store columns (revived or foreign ones) bring their own measurements.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse

from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.run import PlanningRun

__all__ = ["coverage_problem", "executable_columns", "gather_rows", "measurable_structure"]


def measurable_structure(matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, row indices, column sizes) of the measurable (non-zero) entries of a points x views matrix,
    without copying its values: the planner's matrices hold tens of millions of entries at tilt full."""
    csc = matrix if scipy.sparse.issparse(matrix) and matrix.format == "csc" else scipy.sparse.csc_matrix(matrix)
    alive = csc.data != 0
    if alive.all():
        return csc.indptr, csc.indices, np.diff(csc.indptr)
    col_of_entry = np.repeat(np.arange(csc.shape[1], dtype=np.int32), np.diff(csc.indptr))
    sizes = np.bincount(col_of_entry[alive], minlength=csc.shape[1])
    indptr = np.zeros(csc.shape[1] + 1, dtype=np.int64)
    np.cumsum(sizes, out=indptr[1:])
    return indptr, csc.indices[alive], sizes


def _segment_max(values: np.ndarray, indptr: np.ndarray) -> np.ndarray:
    """Per segment of a CSC ``indptr``: the largest finite value (0 for an empty segment), float64."""
    out = np.zeros(indptr.size - 1)
    nonempty = np.flatnonzero(np.diff(indptr) > 0)
    if nonempty.size:
        finite = np.where(np.isfinite(values), values, 0.0) if not np.all(np.isfinite(values)) else values
        out[nonempty] = np.maximum.reduceat(finite, indptr[nonempty])
    return np.maximum(out, 0.0)


def gather_rows(indptr: np.ndarray, indices: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The row indices of ``columns`` (in that order), concatenated."""
    starts = np.asarray(indptr)[columns]
    lengths = np.asarray(indptr)[columns + 1] - starts
    offsets = np.zeros(columns.size, dtype=np.int64)
    np.cumsum(lengths[:-1], out=offsets[1:])
    return indices[np.repeat(starts - offsets, lengths) + np.arange(int(lengths.sum()))]


def executable_columns(views: list[ViewPoint]) -> np.ndarray:
    """Indices of the views verified executable."""
    return np.flatnonzero([v.mechanics_verified is True and v.mechanics_valid for v in views])


def _views_problem(views: list[ViewPoint], n_points: int, only_verified: bool):
    """The coverage problem (points x views boolean CSC matrix, worst uncertainty, duration s) of views that are
    not columns of the store, from their own measurements."""
    usable = [v.mechanics_valid and not (only_verified and v.mechanics_verified is False) for v in views]
    indices = [v.measurable_indices if ok else np.zeros(0, np.int64) for v, ok in zip(views, usable, strict=True)]
    values = [v.measurable_uncertainties if ok else np.zeros(0) for v, ok in zip(views, usable, strict=True)]
    indptr = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([len(i) for i in indices], out=indptr[1:])
    rows = np.concatenate(indices) if indices else np.zeros(0, dtype=np.int64)
    matrix = scipy.sparse.csc_matrix((np.ones(rows.size, dtype=bool), rows, indptr), shape=(n_points, len(views)))
    worst = _segment_max(np.concatenate(values) if values else np.zeros(0), indptr)
    durations = np.array([1.0 if v.estimated_duration_s is None else v.estimated_duration_s for v in views])
    return matrix, worst, durations


def coverage_problem(run: PlanningRun, views: list[ViewPoint], n_points: int, only_verified: bool = False):
    """(points x views boolean CSC matrix of the measurable entries, per-view worst uncertainty, per-view
    durations in s) for the set cover. Rejected views have empty columns, shortened ones only their
    remaining points; with ``only_verified`` the unverified views are empty too.

    The matrix holds only the live entries and no values: the solvers need per-view figures only (the
    worst uncertainty is the greedy tie-break and the cost of IP_uncertainty), and at tilt full the store
    has tens of millions of entries, so a float64 copy of them (plus its temporaries) was the largest
    allocation of the whole plan.
    """
    store = run.measurability
    generation = run.generation_views
    in_store = np.array(
        [
            store is not None
            and v.coverage_column is not None
            and v.coverage_column < store.n_views
            and generation[v.coverage_column] is v
            for v in views
        ],
        dtype=bool,
    )
    if store is not None and in_store.all():
        matrix, worst, durations = _store_problem(run, views, only_verified)
    elif not in_store.any():
        matrix, worst, durations = _views_problem(views, n_points, only_verified)
    else:
        # the store's columns and the revived (or foreign) views, then back in the order of ``views``
        inside, outside = np.flatnonzero(in_store), np.flatnonzero(~in_store)
        m_in, w_in, d_in = _store_problem(run, [views[j] for j in inside], only_verified)
        m_out, w_out, d_out = _views_problem([views[j] for j in outside], m_in.shape[0], only_verified)
        matrix = scipy.sparse.hstack([m_in, m_out], format="csc")
        worst, durations = np.concatenate([w_in, w_out]), np.concatenate([d_in, d_out])
        order = np.argsort(np.concatenate([inside, outside]), kind="stable")
        if np.any(order != np.arange(order.size)):  # revived views come last in the set cover's list
            matrix, worst, durations = matrix[:, order], worst[order], durations[order]
    matrix.sort_indices()
    return matrix, worst, durations


@numba.njit(cache=True)
def _compact_store(indptr, point_indices, uncertainties, alive, keep_view):
    """The live entries of the store's columns in one pass: (indptr, point rows, per-column largest finite
    uncertainty, 0 for an empty column) of the entries ``alive`` holds in the columns ``keep_view`` holds."""
    n_views = indptr.size - 1
    out_ptr = np.zeros(n_views + 1, dtype=np.int64)
    worst = np.zeros(n_views)
    for j in range(n_views):
        count = 0
        if keep_view[j]:
            for e in range(indptr[j], indptr[j + 1]):
                if alive[e]:
                    count += 1
                    u = float(uncertainties[e])
                    if np.isfinite(u) and u > worst[j]:
                        worst[j] = u
        out_ptr[j + 1] = out_ptr[j] + count
    rows = np.empty(out_ptr[n_views], dtype=point_indices.dtype)
    for j in range(n_views):
        if keep_view[j] and out_ptr[j + 1] > out_ptr[j]:
            k = out_ptr[j]
            for e in range(indptr[j], indptr[j + 1]):
                if alive[e]:
                    rows[k] = point_indices[e]
                    k += 1
    return out_ptr, rows, worst


def _store_problem(run: PlanningRun, views: list[ViewPoint], only_verified: bool):
    """:func:`coverage_problem` of views that are all columns of the store."""
    store = run.measurability
    columns = np.asarray([v.coverage_column for v in views], dtype=np.int64)
    keep_view = np.ones(store.n_views, dtype=bool)
    if only_verified:
        keep_view[:] = False
        keep_view[columns[[v.mechanics_verified is not False for v in views]]] = True
    indptr, rows, worst = _compact_store(
        np.asarray(store.indptr, dtype=np.int64),
        np.asarray(store.point_indices),
        np.asarray(store.uncertainties),
        run.entry_alive,
        keep_view,
    )
    matrix = scipy.sparse.csc_matrix(
        (np.ones(rows.size, dtype=bool), rows, indptr), shape=(store.n_points, store.n_views)
    )
    if len(columns) != store.n_views or np.any(columns != np.arange(store.n_views)):
        matrix, worst = matrix[:, columns], worst[columns]
    durations = np.where(run.duration_verified, run.durations, run.durations * run.duration_bias)[columns]
    return matrix, worst, durations


# ----------------------------------------------------------------------------------- connection
