"""Views to verify beside a cover's picks: those of the points no verified view measures yet, and those sharing
the most points with a picked view (its substitutes when it fails)."""

from __future__ import annotations

import numpy as np
import scipy.sparse

from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.selection.problem import gather_rows, measurable_structure

__all__ = ["OPEN_POINT_CHUNK_ENTRIES", "open_point_views", "substitute_views"]

#: columns gathered at once when looking for the open points' views (bounds the temporary memory)
OPEN_POINT_CHUNK_ENTRIES = 2_000_000


def open_point_views(matrix, views: list[ViewPoint], per_point: int) -> np.ndarray:
    """Columns to verify for the rows (points) of ``matrix`` (points x views, CSC, non-zero = measurable) that
    no verified view measures yet: up to ``per_point`` unverified columns each, the largest columns first
    (equal sizes: the lower column first).

    The columns are visited largest first in chunks, and the visit stops once every open row has its
    ``per_point`` columns: the largest columns cover most rows, so the first round (every row open) touches a
    few chunks of the matrix, not all of its entries.
    """
    verified = np.array([v.mechanics_verified is True for v in views], dtype=bool)
    unverified = np.array([v.mechanics_verified is False for v in views], dtype=bool)
    indptr, indices, sizes = measurable_structure(matrix)
    n_rows = matrix.shape[0]
    open_rows = np.zeros(n_rows, dtype=bool)
    open_rows[indices] = True
    if verified.any():
        done_cols = np.flatnonzero(verified & (sizes > 0))
        if done_cols.size:
            open_rows[gather_rows(indptr, indices, done_cols)] = False
    if not open_rows.any() or per_point <= 0:
        return np.zeros(0, dtype=np.int64)
    # only unverified columns holding an open row can be picked; largest first, then the lower index
    candidates = np.flatnonzero(unverified & (sizes > 0))
    candidates = candidates[np.lexsort((candidates, -sizes[candidates]))]
    need = np.where(open_rows, per_point, 0).astype(np.int64)
    picked_cols, picked_rows = [], []
    position = 0
    while position < candidates.size and need.any():
        cum = np.cumsum(sizes[candidates[position:]])
        stop = position + max(1, int(np.searchsorted(cum, OPEN_POINT_CHUNK_ENTRIES, side="right")))
        chunk = candidates[position:stop]
        position = stop
        lengths = sizes[chunk]
        rows = gather_rows(indptr, indices, chunk)
        cols = np.repeat(chunk, lengths)
        wanted = need[rows] > 0
        rows, cols = rows[wanted], cols[wanted]
        if rows.size == 0:
            continue
        # rank of each entry among its row's entries in this chunk, in column order (stable sort by row)
        order = np.argsort(rows, kind="stable")
        rows, cols = rows[order], cols[order]
        rank = np.arange(rows.size) - np.searchsorted(rows, rows, side="left")
        take = rank < need[rows]
        picked_rows.append(rows[take])
        picked_cols.append(cols[take])
        need -= np.bincount(rows[take], minlength=n_rows)
    if not picked_cols:
        return np.zeros(0, dtype=np.int64)
    picked = np.concatenate(picked_cols)
    # most-shared columns first: one view that settles many open points is worth more than many that settle one
    unique, counts = np.unique(picked, return_counts=True)
    return unique[np.lexsort((-sizes[unique], -counts))].astype(np.int64)


def substitute_views(matrix, views: list[ViewPoint], columns: np.ndarray, per_view: int) -> np.ndarray:
    """The unverified columns sharing the most points with each of ``columns`` (points x views matrix, CSC,
    non-zero = measurable), up to ``per_view`` each, the largest overlaps first.

    When a picked view fails or is shortened, the next cover takes the views that measure the same points,
    which a reduction had hidden as dominated: verifying them in the same round spares the rounds that would
    uncover them one by one.
    """
    columns = np.asarray(columns, dtype=np.int64)
    if columns.size == 0 or per_view <= 0:
        return np.zeros(0, dtype=np.int64)
    indptr, indices, _ = measurable_structure(matrix)
    n_points, n_views = matrix.shape
    # the transpose of the measurable structure (views x points, CSR) is the CSC's own arrays: no conversion of
    # the whole matrix (tens of millions of entries); only the picked rows are turned round
    ones = np.ones(indices.size, dtype=np.float32)
    by_view = scipy.sparse.csr_matrix((ones, indices, indptr), shape=(n_views, n_points))
    overlap = (by_view @ by_view[columns].T.tocsr()).tocoo()  # views x len(columns): shared points
    unverified = np.array([v.mechanics_verified is False for v in views], dtype=bool)
    keep = unverified[overlap.row] & (overlap.row != columns[overlap.col])
    r, c, w = overlap.col[keep], overlap.row[keep], overlap.data[keep]
    if r.size == 0:
        return np.zeros(0, dtype=np.int64)
    # per picked view: the largest overlaps first (equal overlaps: the lower column first)
    order = np.lexsort((c, -w, r))
    r, c, w = r[order], c[order], w[order]
    rank = np.arange(r.size) - np.searchsorted(r, r, side="left")
    chosen = rank < per_view
    # best overlaps first across all picked views (then the lower column), each column once
    c, w = c[chosen], w[chosen]
    c = c[np.lexsort((c, -w))]
    _, first = np.unique(c, return_index=True)
    return c[np.sort(first)]
