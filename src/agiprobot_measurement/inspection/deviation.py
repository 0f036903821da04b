"""Signed deviations of measured points from the nominal surface, masks and patch statistics.

Distances are exact closest points on the nominal triangles (point-cloud-utils, loaded at the first call); the
sign is that of the closest face's outward normal (positive = material excess). Points within ``edge_margin_mm``
of a sharp CAD edge (dihedral angle above ``SHARP_EDGE_DEG``) are masked: there a closest point slides from one
face to the next and a best fit would read slip as deviation. Points farther than ``max_distance_mm`` are
outliers (not on the part). Patch statistics average the deviations over voxels of ``patch_mm``, each voxel with
its neighbours within ``patch_radius_mm``: the noise averages out, a dent does not.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "SHARP_EDGE_DEG",
    "ClosestPoints",
    "Patches",
    "closest_points",
    "edge_distance",
    "edge_mask",
    "no_data_mask",
    "patches",
    "sharp_edge_samples",
]

#: CAD edges whose faces meet at more than this angle (deg) are sharp (edge mask, no-data regions)
SHARP_EDGE_DEG = 20.0
#: closest-point queries of at least this many points are split over up to this many threads
PARALLEL_MIN_POINTS = 200_000
PARALLEL_CHUNKS = 2
#: patch voxels are indexed through a dense occupancy table when the grid has at most this many cells per point
DENSE_GRID_FACTOR = 8


@dataclass
class ClosestPoints:
    """Per point: signed distance (mm), closest face index and closest point (mm) on the nominal mesh."""

    signed_mm: np.ndarray
    face: np.ndarray
    closest_mm: np.ndarray


def _pcu():
    import point_cloud_utils  # heavy compiled extension: loaded at the first distance query

    return point_cloud_utils


def _query(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    distance, face, bary = _pcu().closest_points_on_mesh(points, vertices, faces)
    return np.asarray(distance, float), np.asarray(face, dtype=np.int64), np.asarray(bary, float)


def closest_points(mesh: trimesh.Trimesh, points_mm: np.ndarray) -> ClosestPoints:
    """Exact closest points of ``points_mm`` (N, 3) on ``mesh``; sign from the closest face's outward normal.
    Large queries run in ``PARALLEL_CHUNKS`` threads (the query releases the GIL; each builds its own tree)."""
    points = np.ascontiguousarray(points_mm, dtype=np.float64)
    if not len(points):
        return ClosestPoints(np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    workers = min(PARALLEL_CHUNKS, os.cpu_count() or 1)
    if len(points) >= PARALLEL_MIN_POINTS and workers > 1:
        chunks = [np.ascontiguousarray(c) for c in np.array_split(points, workers)]
        with ThreadPoolExecutor(workers) as pool:
            parts = list(pool.map(lambda chunk: _query(chunk, vertices, faces), chunks))
        distance, face, bary = (np.concatenate([p[k] for p in parts]) for k in range(3))
    else:
        distance, face, bary = _query(points, vertices, faces)
    closest = np.einsum("ni,nij->nj", bary, vertices[faces[face]])
    sign = np.sign(np.einsum("ij,ij->i", points - closest, mesh.face_normals[face]))
    sign[sign == 0] = 1.0
    return ClosestPoints(sign * distance, face, closest)


def sharp_edge_samples(mesh: trimesh.Trimesh, spacing_mm: float) -> np.ndarray:
    """Points every ``spacing_mm`` along the mesh's sharp edges and its open (boundary) edges (M, 3, mm)."""
    angles = np.degrees(mesh.face_adjacency_angles)
    edges = [mesh.face_adjacency_edges[angles > SHARP_EDGE_DEG]]
    counts = np.bincount(mesh.edges_unique_inverse, minlength=len(mesh.edges_unique))  # cached by the mesh
    edges.append(mesh.edges_unique[counts == 1])
    edges = np.concatenate(edges)
    if not len(edges):
        return np.zeros((0, 3))
    a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    count = np.maximum(2, np.ceil(length / spacing_mm).astype(int) + 1)
    which = np.repeat(np.arange(len(edges)), count)
    start = np.repeat(np.cumsum(count) - count, count)
    t = (np.arange(count.sum()) - start) / (count[which] - 1)
    return a[which] + t[:, None] * (b - a)[which]


def edge_distance(mesh: trimesh.Trimesh, closest_mm: np.ndarray, margin_mm: float) -> np.ndarray:
    """Distance (mm) of each point's closest nominal point to the nearest sharp or open CAD edge, inf beyond
    ``margin_mm`` (the edge sampled every margin / 4: within about margin / 30 of the exact distance there)."""
    if margin_mm <= 0 or not len(closest_mm):
        return np.full(len(closest_mm), np.inf)
    samples = sharp_edge_samples(mesh, margin_mm / 4)
    if not len(samples):
        return np.full(len(closest_mm), np.inf)
    distance, _ = cKDTree(samples).query(closest_mm, k=1, distance_upper_bound=margin_mm)
    return distance


def edge_mask(mesh: trimesh.Trimesh, closest_mm: np.ndarray, margin_mm: float) -> np.ndarray:
    """True where a point's closest nominal point lies within ``margin_mm`` of a sharp or open CAD edge."""
    return np.isfinite(edge_distance(mesh, closest_mm, margin_mm))


def no_data_mask(surface_samples_mm: np.ndarray, closest_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """True for nominal surface samples with no measured point's closest point within ``radius_mm``."""
    if not len(closest_mm):
        return np.ones(len(surface_samples_mm), dtype=bool)
    tree = cKDTree(closest_mm, balanced_tree=False, compact_nodes=False)  # builds about twice as fast, same answers
    distance, _ = tree.query(surface_samples_mm, k=1, distance_upper_bound=radius_mm)
    return ~np.isfinite(distance)


@dataclass
class Patches:
    """Voxel patches: centre (mean closest point, mm), mean signed deviation (mm), point count, the points' voxel
    (-1 for points left out) and the connected groups of flagged patches."""

    centre_mm: np.ndarray
    mean_mm: np.ndarray
    patch_centre_mm: np.ndarray  # mean position of the patch's points (the point its mean deviation belongs to)
    count: np.ndarray
    sigma_mm: np.ndarray
    voxel_of_point: np.ndarray
    neighbours: coo_matrix

    def regions(self, flagged: np.ndarray) -> list[np.ndarray]:
        """Connected groups (patch indices) of ``flagged`` patches, adjacency = neighbouring voxels."""
        idx = np.flatnonzero(flagged)
        if not len(idx):
            return []
        sub = self.neighbours.tocsr()[idx][:, idx]
        n, labels = connected_components(sub, directed=False)
        return [idx[labels == k] for k in range(n)]


def patches(closest_mm: np.ndarray, signed_mm: np.ndarray, sigma_mm: np.ndarray, use: np.ndarray, voxel_mm: float,
            radius_mm: float) -> Patches:  # fmt: skip
    """Patch means of ``signed_mm`` over the ``use``d points: per voxel (edge ``voxel_mm``, keyed on the closest
    nominal point), the points of every voxel whose centre lies within ``radius_mm``; ``sigma_mm`` of a patch is
    the propagated noise of its mean, sqrt(sum sigma^2) / n."""
    voxel_of_point = np.full(len(closest_mm), -1, dtype=np.int64)
    idx = np.flatnonzero(use)
    if not len(idx):
        empty = np.zeros(0)
        return Patches(np.zeros((0, 3)), empty, np.zeros((0, 3)), empty, empty, voxel_of_point, coo_matrix((0, 0)))
    keys = np.floor(closest_mm[idx] / voxel_mm).astype(np.int64)
    low = keys.min(axis=0)
    span = keys.max(axis=0) - low + 1
    linear_keys = np.ravel_multi_index((keys - low).T, span)
    cells = int(np.prod(span))
    if cells <= DENSE_GRID_FACTOR * len(idx):  # occupancy table instead of a sort (same order as np.unique)
        occupied = np.bincount(linear_keys, minlength=cells) > 0
        inverse = (np.cumsum(occupied) - 1)[linear_keys]
        unique = np.stack(np.unravel_index(np.flatnonzero(occupied), span), axis=1) + low
    else:
        _, first, inverse = np.unique(linear_keys, return_index=True, return_inverse=True)
        unique = keys[first]
        inverse = inverse.reshape(-1)
    voxel_of_point[idx] = inverse
    m = len(unique)
    count = np.bincount(inverse, minlength=m).astype(float)
    sums = np.bincount(inverse, weights=signed_mm[idx], minlength=m)
    var = np.bincount(inverse, weights=sigma_mm[idx] ** 2, minlength=m)
    centre = np.stack([np.bincount(inverse, weights=closest_mm[idx, k], minlength=m) for k in range(3)], axis=1)
    centre_sums = centre
    centre = centre / count[:, None]
    reach = int(np.ceil(radius_mm / voxel_mm))
    grid = np.arange(-reach, reach + 1)
    offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), axis=-1).reshape(-1, 3)
    offsets = offsets[np.linalg.norm(offsets, axis=1) * voxel_mm <= radius_mm + 1e-9]
    base = unique - unique.min(axis=0) + reach
    dims = base.max(axis=0) + reach + 1
    linear = np.ravel_multi_index(base.T, dims)
    order = np.argsort(linear)
    sorted_linear = linear[order]
    rows, cols = [], []
    for offset in offsets:
        target = np.ravel_multi_index((base + offset).T, dims)
        pos = np.clip(np.searchsorted(sorted_linear, target), 0, m - 1)
        hit = sorted_linear[pos] == target
        rows.append(np.flatnonzero(hit))
        cols.append(order[pos[hit]])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m)).tocsr()
    n_patch = adjacency @ count
    mean = (adjacency @ sums) / n_patch
    patch_centre = (adjacency @ centre_sums) / n_patch[:, None]
    sigma = np.sqrt(adjacency @ var) / n_patch
    return Patches(centre, mean, patch_centre, n_patch, sigma, voxel_of_point, adjacency.tocoo())
