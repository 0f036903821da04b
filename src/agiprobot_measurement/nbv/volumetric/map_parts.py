"""Parts of the voxel map that stand on their own: the store of kept raw points and the surface samples of the static
scene inside the map's box."""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["RawPoints", "surface_samples_in_box"]


class RawPoints:
    """Every kept raw point of every fused frame: ``xyz_m`` (N, 3) float32 world, ``normal`` (N, 3) float32 unit
    (zero where the sensor gave none; oriented towards the sensor), ``view`` (N,) int32, ``sigma_mm`` (N,) float32
    (NaN where unknown). Frames are stored as chunks and concatenated on first access. ``origins`` maps a view id
    to its sensor origin (3,) world (m) where the fusion knew it."""

    def __init__(self):
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._cache = None
        self.origins: dict[int, np.ndarray] = {}

    def append(self, xyz_m, normal, view_id, sigma_mm) -> None:
        """Add points: ``view_id`` one int for all or one per point."""
        xyz = np.ascontiguousarray(xyz_m, dtype=np.float32).reshape(-1, 3)
        n = len(xyz)
        if n == 0:
            return
        views = np.broadcast_to(np.asarray(view_id, dtype=np.int32), (n,)).copy()
        self._chunks.append(
            (
                xyz,
                np.ascontiguousarray(normal, dtype=np.float32).reshape(n, 3),
                views,
                np.ascontiguousarray(sigma_mm, dtype=np.float32).reshape(n),
            )
        )
        self._cache = None

    def origin_arrays(self) -> dict[str, np.ndarray]:
        """The origins as arrays for a map file: ``raw_origin_view`` (k,) int64, ``raw_origin_m`` (k, 3)."""
        views = sorted(self.origins)
        return {
            "raw_origin_view": np.array(views, dtype=np.int64),
            "raw_origin_m": np.array([self.origins[v] for v in views], dtype=float).reshape(-1, 3),
        }

    def set_origins(self, views: np.ndarray, origins_m: np.ndarray, where: str) -> None:
        """The origins from a map file's arrays (:meth:`origin_arrays`); damaged ones are an InputError naming
        ``where``."""
        origins_m = np.asarray(origins_m)
        if origins_m.shape != (len(views), 3) or not np.all(np.isfinite(origins_m)):
            raise InputError(f"{where}: raw_origin_m does not give a finite origin per view")
        self.origins = {int(v): o.astype(float) for v, o in zip(views, origins_m, strict=True)}

    def _arrays(self):
        if self._cache is None:
            if not self._chunks:
                self._cache = (
                    np.zeros((0, 3), np.float32),
                    np.zeros((0, 3), np.float32),
                    np.zeros(0, np.int32),
                    np.zeros(0, np.float32),
                )
            else:
                self._cache = tuple(np.concatenate([c[i] for c in self._chunks]) for i in range(4))
                self._chunks = [self._cache]
        return self._cache

    @property
    def xyz_m(self) -> np.ndarray:
        return self._arrays()[0]

    @property
    def normal(self) -> np.ndarray:
        return self._arrays()[1]

    @property
    def view(self) -> np.ndarray:
        return self._arrays()[2]

    @property
    def sigma_mm(self) -> np.ndarray:
        return self._arrays()[3]

    def __len__(self) -> int:
        return sum(len(c[0]) for c in self._chunks)


def _clip_polygon_to_box(poly: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon (k, 3) to an axis-aligned box; (0, 3) when nothing is left."""
    for axis in range(3):
        for sign, bound in ((1.0, lo[axis]), (-1.0, hi[axis])):
            if len(poly) == 0:
                return poly
            dist = sign * (poly[:, axis] - bound)
            out = []
            for i in range(len(poly)):
                a, b = poly[i], poly[(i + 1) % len(poly)]
                da, db = dist[i], dist[(i + 1) % len(poly)]
                if da >= 0:
                    out.append(a)
                if (da >= 0) != (db >= 0):
                    out.append(a + (b - a) * (da / (da - db)))
            poly = np.array(out).reshape(-1, 3)
    return poly


def surface_samples_in_box(triangles: np.ndarray, lo, hi, spacing_m: float, inset_m: float = 0.0) -> np.ndarray:
    """Points no farther than ``spacing_m`` apart on the parts of triangles (T, 3, 3) inside the box (m), moved
    ``inset_m`` against each triangle's normal (into a body whose faces wind outwards)."""
    tri_lo = triangles.min(axis=1)
    tri_hi = triangles.max(axis=1)
    near = np.all((tri_hi >= lo) & (tri_lo <= hi), axis=1)
    chunks = []
    for tri in triangles[near]:
        tri = np.asarray(tri, dtype=float)
        normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])  # of the triangle: a clipped sliver's is unreliable
        length = float(np.linalg.norm(normal))
        inset = normal * (inset_m / length) if length > 0 else np.zeros(3)
        poly = _clip_polygon_to_box(tri, lo, hi)
        for k in range(1, len(poly) - 1):
            a, b, c = poly[0], poly[k], poly[k + 1]
            n = max(1, math.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)) / spacing_m))
            i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
            keep = (i + j) <= n
            u = i[keep, None] / n
            v = j[keep, None] / n
            chunks.append(a + (b - a) * u + (c - a) * v - inset)
    return np.vstack(chunks) if chunks else np.zeros((0, 3))
