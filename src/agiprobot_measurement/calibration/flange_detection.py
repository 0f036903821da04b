"""The robot's tool flange in a camera point cloud, ROS-free: its centre (camera frame, metres) for calibration.

Pipeline (per frame): crop (a sphere around the expected centre, or a camera-frame box), locate on a voxel-grid
copy (statistical outlier removal, repeated RANSAC plane segmentation, Euclidean clustering of each plane's
points, the first cluster of the flange's size), then refine at full resolution around it (plane RANSAC,
Euclidean clustering, least-squares plane, boundary points of the disc, RANSAC circle fit with the flange radius
and a least-squares refit). The two counts the acceptance criteria use are returned: ``plane_points`` (points of
the flange cluster on the plane) and ``circle_inliers`` (boundary points on the fitted circle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from agiprobot_measurement.calibration.registration import fit_circle_ransac, plane_basis
from agiprobot_measurement.common.geometry import fit_plane

__all__ = [
    "UR10E_FLANGE_RADIUS_M",
    "FlangeDetection",
    "FlangeDetectorConfig",
    "boundary_mask",
    "detect_flange",
    "detect_flange_candidates",
    "detect_flanges",
    "estimate_normals",
    "euclidean_clusters",
    "flange_candidates",
    "planar_segments",
    "ransac_plane",
    "refine_flange",
    "statistical_outlier_removal",
    "valid_points",
    "voxel_downsample",
]

#: UR10e tool flange (ISO 9409-1-50-4-M6): outer diameter 63 mm
UR10E_FLANGE_RADIUS_M = 0.0315


@dataclass
class FlangeDetectorConfig:
    """Parameters of the detection (metres unless noted)."""

    radius_m: float = UR10E_FLANGE_RADIUS_M
    crop_radius_m: float = 0.12  # sphere around the expected centre
    crop_box_m: tuple = ((-2.0, -2.0, 0.1), (2.0, 2.0, 4.0))  # camera-frame box when no centre is expected
    voxel_m: float = 0.004
    sor_neighbours: int = 8
    sor_std_ratio: float = 2.5
    plane_band_m: float = 0.002
    cluster_tolerance_m: float = 0.004
    circle_band_m: float = 0.0005
    boundary_gap_deg: float = 100.0
    ransac_iterations: int = 200
    min_plane_points: int = 200
    min_arc_deg: float = 180.0  # the fitted circle's outline points must cover at least this much of it
    max_outside_fraction: float = 0.05  # of the cluster's points beyond the circle (radius + 3 bands)
    max_candidates: int = 8  # approximate centres refined per frame at most
    max_offset_m: float = 0.02  # with an expected centre: farther discs are refused
    seed: int = 0


@dataclass
class FlangeDetection:
    """The result: ``ok`` with centre/normal (camera frame, m) and counts, or ``reason`` why not."""

    ok: bool
    centre_m: np.ndarray | None = None
    normal: np.ndarray | None = None
    radius_m: float = float("nan")
    plane_points: int = 0
    circle_inliers: int = 0
    reason: str = ""
    stats: dict = field(default_factory=dict)


def valid_points(cloud_m: np.ndarray) -> np.ndarray:
    """(N, 3) finite, non-zero points of an organised (H, W, 3) or flat cloud."""
    p = np.asarray(cloud_m, dtype=np.float64).reshape(-1, 3)
    keep = np.isfinite(p).all(axis=1) & (np.abs(p).sum(axis=1) > 0.0)
    return p[keep]


def voxel_downsample(points_m: np.ndarray, voxel_m: float) -> np.ndarray:
    """Centroid of the points of every occupied voxel."""
    keys = np.floor(points_m / voxel_m).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.column_stack([np.bincount(inverse, weights=points_m[:, k], minlength=len(counts)) for k in range(3)])
    return sums / counts[:, None]


def estimate_normals(points_m: np.ndarray, neighbours: int = 10) -> np.ndarray:
    """Unit normals (N, 3) by PCA over the k nearest neighbours."""
    _, idx = cKDTree(points_m).query(points_m, k=min(neighbours, len(points_m)))
    local = points_m[idx] - points_m[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", local, local)
    _, vectors = np.linalg.eigh(cov)
    return vectors[:, :, 0]


def planar_segments(points_m: np.ndarray, tolerance_m: float, max_angle_deg: float = 8.0) -> list[np.ndarray]:
    """Region growing: neighbours within ``tolerance_m`` whose normals agree and lie on each other's plane."""
    normals = estimate_normals(points_m)
    pairs = cKDTree(points_m).query_pairs(tolerance_m, output_type="ndarray")
    if len(pairs) == 0:
        return []
    a, b = pairs[:, 0], pairs[:, 1]
    agree = np.abs(np.einsum("ij,ij->i", normals[a], normals[b])) >= math.cos(math.radians(max_angle_deg))
    offset = np.abs(np.einsum("ij,ij->i", points_m[b] - points_m[a], normals[a])) <= 0.25 * tolerance_m
    keep = agree & offset
    graph = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(len(points_m),) * 2)
    count, labels = connected_components(graph, directed=False)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(count + 1))
    return [order[bounds[k] : bounds[k + 1]] for k in range(count) if bounds[k + 1] - bounds[k] > 1]


def statistical_outlier_removal(points_m: np.ndarray, neighbours: int, std_ratio: float) -> np.ndarray:
    """Keep points whose mean distance to their k neighbours is within mean + std_ratio * std of all."""
    if len(points_m) <= neighbours:
        return points_m
    dist, _ = cKDTree(points_m).query(points_m, k=neighbours + 1)
    mean = dist[:, 1:].mean(axis=1)
    return points_m[mean <= mean.mean() + std_ratio * mean.std()]


def ransac_plane(points_m: np.ndarray, band_m: float, iterations: int, rng) -> np.ndarray:
    """Inlier mask of the plane with most points within ``band_m`` (3-point RANSAC)."""
    n = len(points_m)
    best = np.zeros(n, bool)
    if n < 3:
        return best
    for _ in range(iterations):
        a, b, c = points_m[rng.choice(n, 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-12:
            continue
        inliers = np.abs((points_m - a) @ (normal / norm)) <= band_m
        if inliers.sum() > best.sum():
            best = inliers
    return best


def euclidean_clusters(points_m: np.ndarray, tolerance_m: float) -> list[np.ndarray]:
    """Index arrays of the connected components (neighbours within ``tolerance_m``), largest first."""
    if len(points_m) == 0:
        return []
    pairs = cKDTree(points_m).query_pairs(tolerance_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points_m),) * 2)
    count, labels = connected_components(graph, directed=False)
    clusters = [np.flatnonzero(labels == k) for k in range(count)]
    return sorted(clusters, key=len, reverse=True)


def boundary_mask(points_2d: np.ndarray, radius_m: float, min_gap_deg: float) -> np.ndarray:
    """Points on the outline of a 2D point set: the directions to their neighbours leave a gap > ``min_gap_deg``."""
    tree = cKDTree(points_2d)
    k = min(16, len(points_2d))
    dist, idx = tree.query(points_2d, k=k)
    vectors = points_2d[idx[:, 1:]] - points_2d[:, None, :]
    angles = np.sort(np.arctan2(vectors[..., 1], vectors[..., 0]), axis=1)
    near = dist[:, 1:] <= radius_m
    angles = np.where(near, angles, np.nan)
    angles = np.sort(angles, axis=1)  # NaN last
    counts = near.sum(axis=1)
    gaps = np.diff(angles, axis=1)
    wrap = np.full(len(points_2d), 2.0 * math.pi)
    has = counts > 0
    first = angles[has, 0]
    last = angles[has, np.maximum(counts[has] - 1, 0)]
    wrap[has] = first + 2.0 * math.pi - last
    max_gap = np.fmax(np.nanmax(np.where(np.isnan(gaps), -1.0, gaps), axis=1, initial=-1.0), wrap)
    return (max_gap > math.radians(min_gap_deg)) | (counts < 3)


def _disc_score(points_m: np.ndarray, radius_m: float) -> float | None:
    """How disc-like a planar cluster is (smaller = better), None when not of the flange's size and shape."""
    centre = points_m.mean(axis=0)
    singular = np.linalg.svd(points_m - centre, compute_uv=False)
    if singular[1] < 0.7 * singular[0] or singular[2] > 0.3 * singular[1]:
        return None  # elongated (a strip of a cylinder) or not flat
    extent = np.percentile(np.linalg.norm(points_m - centre, axis=1), 98)
    if not 0.7 * radius_m <= extent <= 1.3 * radius_m:
        return None
    return abs(extent - radius_m) / radius_m


def flange_candidates(points_m: np.ndarray, config: FlangeDetectorConfig) -> list[np.ndarray]:
    """Approximate flange centres (metres) on a voxel-grid copy, most likely first.

    Planar segments by region growing: first the disc-like ones of the flange's size (best score first), then
    fragments no larger than the flange (noise can split the disc into strips; each fragment seeds a full-resolution
    refinement around it), largest first.
    """
    voxels = voxel_downsample(points_m, config.voxel_m)
    voxels = statistical_outlier_removal(voxels, config.sor_neighbours, config.sor_std_ratio)
    disc_voxels = math.pi * config.radius_m**2 / config.voxel_m**2
    min_voxels = max(10, int(0.4 * disc_voxels))
    discs, fragments = [], []
    for segment in planar_segments(voxels, 1.8 * config.voxel_m):
        if len(segment) < max(8, int(0.1 * disc_voxels)):
            continue
        points = voxels[segment]
        centre = points.mean(axis=0)
        score = _disc_score(points, config.radius_m) if len(segment) >= min_voxels else None
        if score is not None:
            discs.append((score, centre))
        elif np.percentile(np.linalg.norm(points - centre, axis=1), 98) <= 1.3 * config.radius_m:
            fragments.append((-len(segment), centre))
    ordered = [c for _, c in sorted(discs, key=lambda c: c[0])] + [c for _, c in sorted(fragments, key=lambda c: c[0])]
    unique: list[np.ndarray] = []
    for centre in ordered:  # one seed per flange-sized neighbourhood
        if all(np.linalg.norm(centre - u) > 0.5 * config.radius_m for u in unique):
            unique.append(centre)
    return unique


def _angular_coverage_deg(points_2d: np.ndarray, centre: np.ndarray, bins: int = 36) -> float:
    """How much of the circle around ``centre`` the points cover (deg, in 360 / ``bins`` steps)."""
    angles = np.arctan2(points_2d[:, 1] - centre[1], points_2d[:, 0] - centre[0])
    occupied = np.unique(np.floor((angles + math.pi) / (2.0 * math.pi) * bins).astype(int) % bins)
    return 360.0 * len(occupied) / bins


def refine_flange(points_m: np.ndarray, guess_m: np.ndarray, config: FlangeDetectorConfig, rng) -> FlangeDetection:
    """Full-resolution fit around an approximate centre; ``ok`` only for a disc of the flange's radius.

    Accepted: a planar cluster of at least ``min_plane_points``, a circle of the flange's radius (within 15 %) with
    at least 8 outline points on it covering at least ``min_arc_deg`` of the circle, and at most
    ``max_outside_fraction`` of the cluster's points beyond the circle (a plate or strip is not a disc).
    """
    local = points_m[np.linalg.norm(points_m - guess_m, axis=1) <= 1.6 * config.radius_m]
    local = statistical_outlier_removal(local, config.sor_neighbours, config.sor_std_ratio)
    inliers = ransac_plane(local, config.plane_band_m, config.ransac_iterations, rng)
    if inliers.sum() < config.min_plane_points:
        return FlangeDetection(False, reason=f"flange plane has only {int(inliers.sum())} points")
    on_plane = local[inliers]
    clusters = euclidean_clusters(on_plane, config.cluster_tolerance_m)
    cluster = min(clusters[:3], key=lambda c: np.linalg.norm(on_plane[c].mean(axis=0) - guess_m))
    disc = on_plane[cluster]
    if len(disc) < config.min_plane_points:
        return FlangeDetection(False, reason=f"flange cluster has only {len(disc)} points")
    centroid, normal = fit_plane(disc)
    basis = plane_basis(normal)
    flat = (disc - centroid) @ basis.T
    # outline radius from the point spacing: nearest and 4th-nearest neighbour (grid and jittered sampling)
    dist = cKDTree(flat).query(flat, k=5)[0]
    spacing = float(np.median(dist[:, 1]))
    edge = boundary_mask(flat, max(2.5 * spacing, 2.0 * float(np.median(dist[:, 4]))), config.boundary_gap_deg)
    band = max(config.circle_band_m, 0.5 * spacing)
    circle = fit_circle_ransac(flat[edge], config.radius_m, band, iterations=config.ransac_iterations, seed=config.seed)
    if circle is None or circle.inlier_count < 8:
        return FlangeDetection(False, reason="no circle of the flange's radius on the cluster's outline")
    if abs(circle.radius_m - config.radius_m) > 0.15 * config.radius_m:
        return FlangeDetection(False, reason=f"circle radius {circle.radius_m * 1000:.1f} mm is not the flange's")
    arc_deg = _angular_coverage_deg(flat[edge][circle.inliers], circle.centre)
    if arc_deg < config.min_arc_deg:
        return FlangeDetection(False, reason=f"the circle's outline covers only {arc_deg:.0f} deg: not a disc")
    outside = float(np.mean(np.linalg.norm(flat - circle.centre, axis=1) > circle.radius_m + 3.0 * band))
    if outside > config.max_outside_fraction:
        return FlangeDetection(False, reason=f"{outside:.0%} of the cluster lies beyond the circle: not a disc")
    centre = centroid + circle.centre @ basis
    if normal @ centre > 0.0:  # the normal towards the camera
        normal = -normal
    return FlangeDetection(
        True,
        centre_m=centre,
        normal=normal,
        radius_m=circle.radius_m,
        plane_points=len(disc),
        circle_inliers=circle.inlier_count,
        stats={"edge_points": int(edge.sum()), "spacing_m": spacing, "arc_deg": arc_deg, "outside": outside},
    )


def _crop(cloud_m, config: FlangeDetectorConfig, expected_centre_m) -> np.ndarray:
    points = valid_points(cloud_m)
    if expected_centre_m is not None:
        return points[np.linalg.norm(points - np.asarray(expected_centre_m), axis=1) <= config.crop_radius_m]
    low, high = (np.asarray(v) for v in config.crop_box_m)
    return points[((points >= low) & (points <= high)).all(axis=1)]


def detect_flange_candidates(
    cloud_m: np.ndarray,
    config: FlangeDetectorConfig | None = None,
    expected_centre_m: np.ndarray | None = None,
    max_results: int = 1,
) -> tuple[list[FlangeDetection], str]:
    """Up to ``max_results`` accepted detections (distinct discs), most likely first, and the reason when none.

    Candidates (:func:`flange_candidates`; nearest ``expected_centre_m`` first when given) are refined one after
    the other, at most ``max_candidates``; with an expected centre a disc farther than ``max_offset_m`` is refused.
    """
    config = config or FlangeDetectorConfig()
    rng = np.random.default_rng(config.seed)
    points = _crop(cloud_m, config, expected_centre_m)
    if len(points) < config.min_plane_points:
        return [], f"only {len(points)} points in the crop region: no flange in view"
    candidates = flange_candidates(points, config)
    if expected_centre_m is not None:
        expected = np.asarray(expected_centre_m, dtype=float)
        candidates.sort(key=lambda c: float(np.linalg.norm(c - expected)))
    if not candidates:
        return [], "no disc-shaped planar cluster of the flange's size found"
    found: list[FlangeDetection] = []
    reasons: list[str] = []
    for guess in candidates[: config.max_candidates]:
        det = refine_flange(points, guess, config, rng)
        if det.ok and expected_centre_m is not None:
            offset = float(np.linalg.norm(det.centre_m - expected))
            if offset > config.max_offset_m:
                det = FlangeDetection(
                    False,
                    reason=f"disc {offset * 1000:.0f} mm from the expected centre (> {config.max_offset_m * 1000:.0f})",
                )
        if not det.ok:
            reasons.append(det.reason)
            continue
        if any(np.linalg.norm(det.centre_m - f.centre_m) < config.radius_m for f in found):
            continue
        det.stats["candidate"] = len(reasons) + len(found)
        found.append(det)
        if len(found) >= max_results:
            break
    if found:
        return found, ""
    return [], f"no flange among {len(reasons)} candidate(s): " + "; ".join(dict.fromkeys(reasons))


def detect_flange(
    cloud_m: np.ndarray,
    config: FlangeDetectorConfig | None = None,
    expected_centre_m: np.ndarray | None = None,
) -> FlangeDetection:
    """The flange centre in a camera-frame cloud ((H, W, 3) or (N, 3), metres; zeros = invalid)."""
    found, reason = detect_flange_candidates(cloud_m, config, expected_centre_m, max_results=1)
    return found[0] if found else FlangeDetection(False, reason=reason)


def _detect_job(args):
    cloud, config, expected, max_results = args
    if max_results is None:
        return detect_flange(cloud, config, expected)
    return detect_flange_candidates(cloud, config, expected, max_results)


def detect_flanges(clouds, config=None, expected_centres=None, workers: int = 1, max_results: int | None = None):
    """:func:`detect_flange` over several clouds, on ``workers`` processes when > 1 (the original's use_mp).

    With ``max_results``: :func:`detect_flange_candidates` instead, a (detections, reason) pair per cloud.
    """
    expected_centres = expected_centres if expected_centres is not None else [None] * len(clouds)
    jobs = [(c, config, e, max_results) for c, e in zip(clouds, expected_centres, strict=True)]
    if workers <= 1 or len(jobs) <= 1:
        return [_detect_job(j) for j in jobs]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(min(workers, len(jobs))) as pool:
        return list(pool.map(_detect_job, jobs))
