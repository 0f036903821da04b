"""Geometric queries of the laser line sensor model: occlusion rays against the part's mesh (:class:`RayCaster`)
and the grid of sample cells (:func:`build_cells`) over which :func:`cull_pairs` keeps the (view, point) pairs that
may pass the exact tests. Millimetres throughout."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.spatial
import trimesh

__all__ = ["CELL_POINTS", "SEED_DIRECTIONS", "Cells", "RayCaster", "build_cells", "cull_pairs", "support_test"]

#: samples per cell of that grid, on average
CELL_POINTS = 48


class RayCaster:
    """Occlusion queries ``segment origin -> origin + distance * direction`` against one mesh.

    Uses Embree (through embreex, as trimesh's intersector does) when available, and trimesh's pure
    Python intersector otherwise.
    """

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        # Embree works in float32: shifting the geometry to the origin keeps the rounding of a part placed
        # a metre away from the robot base at the level of its own size.
        self.offset = np.asarray(mesh.bounds.mean(axis=0), dtype=float)
        self.scene = None
        if trimesh.ray.has_embree:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            self.scene = rtcore_scene.EmbreeScene()
            TriangleMesh(
                scene=self.scene,
                vertices=(np.asarray(mesh.vertices) - self.offset).astype(np.float32),
                indices=np.asarray(mesh.faces).astype(np.int32),
            )

    def occluded(self, origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """Boolean per ray: does any face intersect the ray between 0 and ``distances`` (mm)?"""
        count = origins.shape[0]
        if count == 0:
            return np.zeros(0, dtype=bool)
        if self.scene is not None:
            hit = self.scene.run(
                (origins - self.offset).astype(np.float32),
                directions.astype(np.float32),
                dists=np.maximum(distances, 0.0).astype(np.float32),
                query="OCCLUDED",
            )
            # embreex reports 0 for an occluded ray and -1 for a free one
            return np.asarray(hit) != -1
        _, ray, loc = self.mesh.ray.intersects_id(origins, directions, multiple_hits=False, return_locations=True)
        result = np.zeros(count, dtype=bool)
        if len(ray):
            hit_distance = np.einsum("ij,ij->i", loc - origins[ray], directions[ray])
            result[ray] = hit_distance < distances[ray]
        return result


@numba.njit(cache=True, nogil=True)
def cull_pairs(
    rot,
    anchor,
    center,
    radius,
    start,
    order,
    point_data,
    min_standoff,
    max_standoff,
    tan_half,
    deflection,
    tan_psi,
    margin,
):  # pragma: no cover - compiled
    """(view, point) pairs that may pass the exact tests: cells whose bounding sphere (``radius`` with its
    margin) meets a view's frustum, then per point the psi limit and the frustum with ``margin`` (mm).
    ``rot`` (V, 3, 3) columns t, l, s; ``anchor`` (V, 3) mm. View-major; within a view by cell."""
    n_views, n_cells = rot.shape[0], center.shape[0]
    reach = np.zeros((n_views, n_cells), np.bool_)
    bound = 0
    for v in range(n_views):
        for c in range(n_cells):
            dx, dy, dz = center[c, 0] - anchor[v, 0], center[c, 1] - anchor[v, 1], center[c, 2] - anchor[v, 2]
            qx = rot[v, 0, 0] * dx + rot[v, 1, 0] * dy + rot[v, 2, 0] * dz
            qy = rot[v, 0, 1] * dx + rot[v, 1, 1] * dy + rot[v, 2, 1] * dz
            qz = rot[v, 0, 2] * dx + rot[v, 1, 2] * dy + rot[v, 2, 2] * dz
            r = radius[c]
            if (
                abs(qx) <= deflection + r
                and qz > min_standoff - r
                and qz < max_standoff + r
                and abs(qy) <= qz * tan_half + r * (1.0 + tan_half)
            ):
                reach[v, c] = True
                bound += start[c + 1] - start[c]
    views = np.empty(bound, np.int64)
    points = np.empty(bound, np.int64)
    n = 0
    for v in range(n_views):
        tx, ty, tz = rot[v, 0, 0], rot[v, 1, 0], rot[v, 2, 0]
        lx, ly, lz = rot[v, 0, 1], rot[v, 1, 1], rot[v, 2, 1]
        sx, sy, sz = rot[v, 0, 2], rot[v, 1, 2], rot[v, 2, 2]
        ax, ay, az = anchor[v, 0], anchor[v, 1], anchor[v, 2]
        for c in range(n_cells):
            if not reach[v, c]:
                continue
            for k in range(start[c], start[c + 1]):
                p = order[k]
                nx, ny, nz = point_data[3, p], point_data[4, p], point_data[5, p]
                ns = nx * sx + ny * sy + nz * sz
                if not abs(nx * tx + ny * ty + nz * tz) < -ns * tan_psi + 1e-9:
                    continue
                dx, dy, dz = point_data[0, p] - ax, point_data[1, p] - ay, point_data[2, p] - az
                pz = dx * sx + dy * sy + dz * sz
                if not (pz > min_standoff - margin and pz < max_standoff + margin):
                    continue
                if not abs(dx * lx + dy * ly + dz * lz) <= pz * tan_half + margin:
                    continue
                if not abs(dx * tx + dy * ty + dz * tz) <= deflection + margin:
                    continue
                views[n] = v
                points[n] = p
                n += 1
    return views[:n], points[:n]


@dataclass(frozen=True)
class Cells:
    """Samples grouped by grid cell: ``order[start[c]:start[c+1]]`` are cell ``c``'s sample ids (ascending);
    every one lies within ``radius[c]`` mm of ``center[c]``."""

    order: np.ndarray  # (P,) int64
    start: np.ndarray  # (C + 1,) int64
    center: np.ndarray  # (C, 3) mm
    radius: np.ndarray  # (C,) mm

    @property
    def sizes(self) -> np.ndarray:
        return np.diff(self.start)


def build_cells(points: np.ndarray, area_mm2: float) -> Cells:
    """A grid of cubic cells holding :data:`CELL_POINTS` samples on average (edge from the surface density)."""
    edge = math.sqrt(CELL_POINTS * max(float(area_mm2), 1e-9) / max(len(points), 1))
    keys = np.floor((points - points.min(axis=0)) / edge).astype(np.int64)
    _, cell = np.unique(keys, axis=0, return_inverse=True)
    cell = cell.reshape(-1)
    order = np.argsort(cell, kind="stable")
    start = np.zeros(int(cell.max()) + 2, dtype=np.int64)
    np.cumsum(np.bincount(cell, minlength=start.size - 1), out=start[1:])
    sorted_points = points[order]
    low = np.minimum.reduceat(sorted_points, start[:-1], axis=0)
    high = np.maximum.reduceat(sorted_points, start[:-1], axis=0)
    center = 0.5 * (low + high)
    distance = np.linalg.norm(sorted_points - np.repeat(center, np.diff(start), axis=0), axis=1)
    radius = np.maximum.reduceat(distance, start[:-1]) + 1e-6 * edge
    return Cells(order.astype(np.int64), start, center, radius)


# ------------------------------------------------------------------------------------------- supporting faces
#: directions whose extreme hull vertices seed the search of every face (besides the hull vertex next to it)
SEED_DIRECTIONS = 32


@numba.njit(cache=True, nogil=True)
def _support_walk(normals, thresholds, starts, hull_vertices, indptr, neighbours, result):
    """Per face: is no hull vertex above its threshold? Hill climbing on the hull's vertex graph: a vertex whose
    neighbours are all lower is the maximum of a linear function over a convex polytope. Stops early at the first
    vertex above the threshold, so a face costs the degrees of a few vertices."""
    for f in range(normals.shape[0]):
        nx, ny, nz = normals[f, 0], normals[f, 1], normals[f, 2]
        threshold = thresholds[f]
        v = starts[f]
        value = nx * hull_vertices[v, 0] + ny * hull_vertices[v, 1] + nz * hull_vertices[v, 2]
        supporting = value <= threshold
        while supporting:
            best, best_vertex = value, -1
            for k in range(indptr[v], indptr[v + 1]):
                u = neighbours[k]
                x = nx * hull_vertices[u, 0] + ny * hull_vertices[u, 1] + nz * hull_vertices[u, 2]
                if x > threshold:
                    supporting = False
                    break
                if x > best:
                    best, best_vertex = x, u
            if best_vertex < 0:
                break
            v, value = best_vertex, best
        result[f] = supporting


def support_test(hull: trimesh.Trimesh, normals: np.ndarray, thresholds: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Boolean per plane ``normals[i] . x <= thresholds[i]``: does it hold for every vertex of the convex ``hull``?

    Exact for a convex hull and near-linear in the number of planes: each search starts at the better of the hull
    vertex nearest to ``near[i]`` (a point on the plane) and the extreme vertices in :data:`SEED_DIRECTIONS`
    directions, then climbs the hull's vertex graph.
    """
    vertices = np.ascontiguousarray(hull.vertices, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    edges = np.asarray(hull.edges_unique, dtype=np.int64)
    both = np.concatenate([edges, edges[:, ::-1]])
    order = np.argsort(both[:, 0], kind="stable")
    neighbours = np.ascontiguousarray(both[order, 1])
    indptr = np.zeros(len(vertices) + 1, dtype=np.int64)
    np.cumsum(np.bincount(both[:, 0], minlength=len(vertices)), out=indptr[1:])
    # seeds: the nearest hull vertex, or the extreme vertex of the best of a few fixed directions
    start = scipy.spatial.cKDTree(vertices).query(np.asarray(near, dtype=np.float64))[1].astype(np.int64)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    z = np.linspace(1.0 - 1.0 / SEED_DIRECTIONS, -1.0 + 1.0 / SEED_DIRECTIONS, SEED_DIRECTIONS)
    radius = np.sqrt(1.0 - z * z)
    angle = golden * np.arange(SEED_DIRECTIONS)
    directions = np.stack([radius * np.cos(angle), radius * np.sin(angle), z], axis=1)
    extremes = np.argmax(vertices @ directions.T, axis=0)
    seed_values = normals @ vertices[extremes].T  # (F, SEED_DIRECTIONS)
    best_seed = np.argmax(seed_values, axis=1)
    near_values = np.einsum("ij,ij->i", normals, vertices[start])
    start = np.where(seed_values[np.arange(len(normals)), best_seed] > near_values, extremes[best_seed], start)
    result = np.zeros(len(normals), dtype=np.bool_)
    _support_walk(
        normals, np.ascontiguousarray(thresholds, dtype=np.float64), start, vertices, indptr, neighbours, result
    )
    return result
