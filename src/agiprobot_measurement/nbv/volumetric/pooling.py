"""Pooling of a fine voxel grid onto a coarser one sharing its origin (numba kernels of the map's coarse copy)."""
# ruff: noqa: RUF046 -- explicit int() keeps numba's integer typing of math.floor unambiguous

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["pool_max", "pool_sum"]


@numba.njit(cache=True)
def pool_max(values, shape, factor_num, factor_den, out_shape, fill):
    """Max-pool a fine (nx, ny, nz) float32 array onto a coarse grid sharing its origin.

    Fine voxel ``i`` (centre ``(i + 0.5) * fine``) falls into coarse voxel ``floor((i + 0.5) * fine / coarse)``;
    ``factor_num / factor_den`` is ``fine / coarse``. Coarse voxels receiving no fine voxel keep ``fill``.
    """
    nx, ny, nz = shape
    cx, cy, cz = out_shape
    out = np.full((cx, cy, cz), -np.inf, dtype=np.float32)
    ratio = factor_num / factor_den
    mapx = np.empty(nx, dtype=np.int64)
    mapy = np.empty(ny, dtype=np.int64)
    mapz = np.empty(nz, dtype=np.int64)
    for i in range(nx):
        mapx[i] = min(int(math.floor((i + 0.5) * ratio)), cx - 1)
    for j in range(ny):
        mapy[j] = min(int(math.floor((j + 0.5) * ratio)), cy - 1)
    for k in range(nz):
        mapz[k] = min(int(math.floor((k + 0.5) * ratio)), cz - 1)
    for i in range(nx):
        a = mapx[i]
        for j in range(ny):
            b = mapy[j]
            for k in range(nz):
                c = mapz[k]
                v = values[i, j, k]
                if v > out[a, b, c]:
                    out[a, b, c] = v
    for a in range(cx):
        for b in range(cy):
            for c in range(cz):
                if out[a, b, c] == -np.inf:
                    out[a, b, c] = fill
    return out


@numba.njit(cache=True)
def pool_sum(values, factor_num, factor_den, out_shape):
    """Sum-pool a fine (nx, ny, nz, c) float32 array onto the coarse grid of :func:`pool_max` (float64 out)."""
    nx, ny, nz, nc = values.shape
    cx, cy, cz = out_shape
    out = np.zeros((cx, cy, cz, nc), dtype=np.float64)
    ratio = factor_num / factor_den
    for i in range(nx):
        a = min(int(math.floor((i + 0.5) * ratio)), cx - 1)
        for j in range(ny):
            b = min(int(math.floor((j + 0.5) * ratio)), cy - 1)
            for k in range(nz):
                c = min(int(math.floor((k + 0.5) * ratio)), cz - 1)
                for q in range(nc):
                    out[a, b, c, q] += values[i, j, k, q]
    return out
