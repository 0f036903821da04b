"""Registration of a measured cloud to the nominal CAD: prealignment, robust point-to-plane ICP, 3-2-1 datums.

Frames: the cloud comes in the world (mm); the nominal placement (world <- part, the planned pose) prealigns it
into the CAD frame; the ICP then finds the small correction. Every transform here maps cloud points into the CAD
frame (4x4, mm). The ICP is Gauss-Newton on point-to-plane residuals to exact closest points on the nominal
triangles, with Huber weights (scale from the median absolute deviation) and trimming of the largest residuals,
so that a dent or a shifted hole does not pull the fit. Degrees of freedom (``tx ty tz rx ry rz`` in the CAD
frame; rotations about the points' centroid) can be locked.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from agiprobot_measurement.inspection.deviation import closest_points, sharp_edge_samples
from agiprobot_measurement.inspection.errors import InspectionInputError, RegistrationError

__all__ = [
    "DOF_NAMES",
    "IcpSettings",
    "Registration",
    "RpsPoint",
    "RpsResult",
    "apply",
    "datum_frame",
    "icp",
    "prealign",
    "rps_alignment",
    "transform_error",
]

DOF_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
#: Gauss-Newton steps on fixed correspondences between two closest-point queries
INNER_ITERATIONS = 8
#: share of the points that must lie within max_distance_mm of the nominal after prealignment
MIN_OVERLAP = 0.3
#: fewest measured points an RPS point's local plane is fitted to
RPS_MIN_POINTS = 10
#: coarse-to-fine: samples larger than COARSE_FACTOR x COARSE_SAMPLE points are first registered on COARSE_SAMPLE
#: points to these tolerances (rad, mm); the full sample then refines from there (a closest-point query costs
#: about its tree build plus its points: the coarse iterations are a fraction of the fine ones)
COARSE_SAMPLE = 10000
COARSE_FACTOR = 4
COARSE_TOL_RAD = 1e-6
COARSE_TOL_MM = 1e-4


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``transform`` (4x4) applied to points (N, 3) (einsum: a threaded BLAS is slow on thin matrices)."""
    return np.einsum("ij,nj->ni", transform[:3, :3], points) + transform[:3, 3]


def prealign(points_world_mm: np.ndarray, nominal_placement: np.ndarray) -> np.ndarray:
    """CAD <- world from the known (planned) placement world <- part."""
    return np.linalg.inv(np.asarray(nominal_placement, float))


@dataclass(frozen=True)
class IcpSettings:
    """Robust ICP settings: ``robust`` 'huber' or 'none'; ``trim`` share of largest residuals left out;
    ``max_distance_mm`` residual beyond which a point is not the part's; ``sample`` points used per iteration;
    ``lock`` DOF names kept fixed; convergence when an update is below ``tol_rad`` and ``tol_mm``."""

    robust: str = "huber"
    huber_k: float = 1.345
    trim: float = 0.05
    max_distance_mm: float = 5.0
    sample: int = 80000
    max_iterations: int = 60
    lock: tuple[str, ...] = ()
    tol_rad: float = 1e-8
    tol_mm: float = 1e-6
    edge_margin_mm: float = 1.0
    seed: int = 0

    def __post_init__(self):
        unknown = sorted(set(self.lock) - set(DOF_NAMES))
        if unknown:
            raise InspectionInputError(f"unknown degrees of freedom to lock: {unknown} (known: {list(DOF_NAMES)})")
        if self.robust not in ("huber", "none"):
            raise InspectionInputError(f"robust loss must be 'huber' or 'none', got {self.robust!r}")
        if not 0.0 <= self.trim < 0.5:
            raise InspectionInputError(f"trim must lie in [0, 0.5), got {self.trim}")


@dataclass
class Registration:
    """CAD <- cloud transform and the fit's figures: robust residual scale (mm), points used, share of the sample
    within ``max_distance_mm`` (overlap), the 6x6 covariance of (rx ry rz tx ty tz) about ``centre_mm``."""

    transform: np.ndarray
    residual_mm: float
    used: int
    overlap: float
    iterations: int
    converged: bool
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    centre_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    method: str = "best_fit"
    rps: RpsResult | None = None  # the reference-point alignment's figures when the spec asks for one

    def displacement_sigma(self, points_mm: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """1-sigma displacement along ``normals`` of points (CAD frame) due to the fit's parameter uncertainty."""
        arm = points_mm - self.centre_mm
        a = np.concatenate([np.cross(arm, normals), normals], axis=1)
        return np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", a, self.covariance, a), 0.0))


def _huber(residual: np.ndarray, k: float, robust: str) -> tuple[np.ndarray, float]:
    mad = np.median(np.abs(residual - np.median(residual)))
    scale = max(1.4826 * mad, 1e-5)
    if robust == "none":
        return np.ones_like(residual), scale
    a = np.abs(residual)
    return np.where(a <= k * scale, 1.0, k * scale / np.maximum(a, 1e-12)), scale


def icp(points_mm: np.ndarray, mesh: trimesh.Trimesh, settings: IcpSettings = IcpSettings(),
        initial: np.ndarray | None = None) -> Registration:  # fmt: skip
    """Robust point-to-plane ICP of ``points_mm`` onto ``mesh`` starting from ``initial`` (CAD <- cloud)."""
    points = np.asarray(points_mm, float)
    transform = np.eye(4) if initial is None else np.asarray(initial, float).copy()
    rng = np.random.default_rng(settings.seed)
    if len(points) > settings.sample:
        points = points[rng.choice(len(points), settings.sample, replace=False)]
    if len(points) > COARSE_FACTOR * COARSE_SAMPLE:  # coarse to fine: most iterations on a small sample
        coarse = replace(settings, sample=COARSE_SAMPLE, tol_rad=COARSE_TOL_RAD, tol_mm=COARSE_TOL_MM)
        transform = icp(points, mesh, coarse, transform).transform
    free = np.array([name not in settings.lock for name in DOF_NAMES])
    edges = sharp_edge_samples(mesh, max(settings.edge_margin_mm / 4, 0.05)) if settings.edge_margin_mm > 0 else None
    edge_tree = cKDTree(edges) if edges is not None and len(edges) else None
    normals_of_faces = np.asarray(mesh.face_normals)
    converged, iteration, info, scale, used, overlap = False, 0, np.eye(6), 1.0, 0, 0.0
    centre = apply(transform, points).mean(axis=0)
    # outer loop: correspondences (closest face of each point); inner loop: Gauss-Newton on those faces' planes
    for iteration in range(1, settings.max_iterations + 1):
        current = apply(transform, points)
        cp = closest_points(mesh, current)
        normals = normals_of_faces[cp.face]
        near = np.abs(cp.signed_mm) <= settings.max_distance_mm
        overlap = float(near.mean())
        if edge_tree is not None:
            d, _ = edge_tree.query(cp.closest_mm, k=1, distance_upper_bound=settings.edge_margin_mm)
            near &= ~np.isfinite(d)
        if near.sum() < 50 or (iteration == 1 and overlap < MIN_OVERLAP):
            raise RegistrationError(
                f"only {int(near.sum())} of {len(points)} points ({100 * overlap:.0f} %) lie within "
                f"{settings.max_distance_mm} mm of the "
                "nominal surface after prealignment: a cloud of another part, another unit or a wrong placement?"
            )
        anchor = np.einsum("ij,ij->i", cp.closest_mm, normals)
        start = transform.copy()
        for _ in range(INNER_ITERATIONS):
            current = apply(transform, points)
            residual = np.einsum("ij,ij->i", current, normals) - anchor
            keep = np.flatnonzero(near)
            if settings.trim > 0:
                limit = np.quantile(np.abs(residual[keep]), 1.0 - settings.trim)
                keep = keep[np.abs(residual[keep]) <= limit]
            r = residual[keep]
            weights, scale = _huber(r, settings.huber_k, settings.robust)
            centre = current[keep].mean(axis=0)
            jac = np.concatenate([np.cross(current[keep] - centre, normals[keep]), normals[keep]], axis=1)
            info = np.einsum("ni,n,nj->ij", jac, weights, jac)
            gradient = np.einsum("ni,n->i", jac, weights * r)
            step = np.zeros(6)
            sub = info[np.ix_(free, free)]
            step[free] = -np.linalg.solve(sub + 1e-12 * np.eye(int(free.sum())), gradient[free])
            used = len(keep)
            update = np.eye(4)
            update[:3, :3] = Rotation.from_rotvec(step[:3]).as_matrix()
            update[:3, 3] = centre - update[:3, :3] @ centre + step[3:]
            transform = update @ transform
            if np.linalg.norm(step[:3]) < settings.tol_rad and np.linalg.norm(step[3:]) < settings.tol_mm:
                break
        moved = start @ np.linalg.inv(transform)
        rotation = np.linalg.norm(Rotation.from_matrix(moved[:3, :3]).as_rotvec())
        shift = np.linalg.norm(apply(moved, centre[None])[0] - centre)
        if rotation < 10 * settings.tol_rad and shift < 10 * settings.tol_mm:
            converged = True
            break
    covariance = np.zeros((6, 6))
    sub = info[np.ix_(free, free)]
    covariance[np.ix_(free, free)] = scale**2 * np.linalg.inv(sub + 1e-12 * np.eye(int(free.sum())))
    return Registration(transform, float(scale), int(used), overlap, iteration, converged, covariance, centre)


def transform_error(estimated: np.ndarray, truth: np.ndarray, at_mm: np.ndarray) -> tuple[float, float]:
    """(largest displacement over ``at_mm`` (mm), rotation angle (deg)) between two CAD <- cloud transforms."""
    delta = estimated @ np.linalg.inv(truth)
    moved = apply(delta, np.atleast_2d(at_mm))
    angle = float(np.degrees(np.linalg.norm(Rotation.from_matrix(delta[:3, :3]).as_rotvec())))
    return float(np.linalg.norm(moved - np.atleast_2d(at_mm), axis=1).max()), angle


def _plane(points: np.ndarray, normal_hint: np.ndarray, fixed_normal: np.ndarray | None = None,
           perpendicular_to: np.ndarray | None = None):  # fmt: skip
    centroid = points.mean(axis=0)
    if fixed_normal is not None:
        return centroid, fixed_normal
    centred = points - centroid
    if perpendicular_to is None:
        normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    else:  # the normal in the plane perpendicular to that axis: a line fit of the points seen along it
        u = np.cross(perpendicular_to, np.eye(3)[int(np.argmin(np.abs(perpendicular_to)))])
        u /= np.linalg.norm(u)
        v = np.cross(perpendicular_to, u)
        smallest = np.linalg.svd(np.stack([centred @ u, centred @ v], axis=1), full_matrices=False)[2][-1]
        normal = smallest[0] * u + smallest[1] * v
    return centroid, normal if normal @ normal_hint >= 0 else -normal


def _frame(planes) -> np.ndarray:
    (ca, na), (cb, nb), (cc, nc) = planes
    lhs = np.stack([na, nb, nc])
    origin = np.linalg.solve(lhs, [na @ ca, nb @ cb, nc @ cc])
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([na, nb, nc])
    frame[:3, 3] = origin
    return frame


def datum_frame(point_sets, nominal_planes) -> np.ndarray:
    """3-2-1 alignment: datum A a plane (3 DOF), B a plane perpendicular to A (2 DOF), C a plane perpendicular
    to both (1 DOF), each fitted to its measured points (CAD frame after best fit); ``nominal_planes`` the CAD
    planes (centroid, outward normal) of A, B, C. Returns the correction mapping measured datums onto nominal."""
    (pa, pb, pc), (a, b, c) = point_sets, nominal_planes
    for name, pts in zip("ABC", (pa, pb, pc), strict=True):
        if len(pts) < 3:
            raise RegistrationError(f"datum {name}: {len(pts)} measured points, need at least 3")
    ma = _plane(pa, a[1])
    mb = _plane(pb, b[1], perpendicular_to=ma[1])
    nc = np.cross(ma[1], mb[1])
    mc = _plane(pc, c[1], fixed_normal=nc if nc @ c[1] >= 0 else -nc)
    na_, nb_ = a[1], b[1] - (b[1] @ a[1]) * a[1]
    nb_ /= np.linalg.norm(nb_)
    nc_ = np.cross(na_, nb_)
    nominal = _frame([(a[0], na_), (b[0], nb_), (c[0], nc_ if nc_ @ c[1] >= 0 else -nc_)])
    measured = _frame([ma, mb, mc])
    # the measured frame's axes may be a left-handed set when C's normal was flipped: mirror both the same way
    return nominal @ np.linalg.inv(measured)


@dataclass(frozen=True)
class RpsPoint:
    """A reference point (RPS, CAD frame, mm): its nominal ``point`` on the surface and the ``direction`` (unit)
    it fixes the part in: the measured surface is sampled there and the part is moved until it meets the point
    along that direction."""

    name: str
    point: np.ndarray
    direction: np.ndarray


@dataclass
class RpsResult:
    """The RPS correction (4x4, CAD <- CAD), the residual deviation (mm) at each point along its direction
    after the alignment (0 for a determined set), the deviations before it, and the rank of the constraints."""

    correction: np.ndarray
    residual_mm: dict
    deviation_mm: dict
    rank: int


def _rps_measure(points: np.ndarray, rps: RpsPoint, radius_mm: float, reach_mm: float) -> float:
    """Signed distance along ``rps.direction`` from the nominal point to the measured surface: an LS plane through
    the points within ``radius_mm`` of the line through the point (and ``reach_mm`` along it), met by the line."""
    rel = points - rps.point
    along = rel @ rps.direction
    across = np.linalg.norm(rel - np.outer(along, rps.direction), axis=1)
    near = (across <= radius_mm) & (np.abs(along) <= reach_mm)
    if near.sum() < RPS_MIN_POINTS:
        raise RegistrationError(
            f"RPS point {rps.name}: {int(near.sum())} measured points within {radius_mm} mm (need {RPS_MIN_POINTS})"
        )
    local = points[near]
    centroid = local.mean(axis=0)
    normal = np.linalg.svd(local - centroid, full_matrices=False)[2][-1]
    cos = float(normal @ rps.direction)
    if abs(cos) < 0.2:
        raise RegistrationError(f"RPS point {rps.name}: the measured surface runs along its direction")
    return float(normal @ (centroid - rps.point)) / cos


def rps_alignment(points_cad_mm: np.ndarray, rps_points, radius_mm: float = 3.0, reach_mm: float = 3.0,
                  lock: tuple[str, ...] = (), iterations: int = 5) -> RpsResult:  # fmt: skip
    """Reference-point alignment (e.g. 3-2-1: three points along the primary face's normal, two along the
    secondary's, one along the tertiary's): the small rigid correction that brings the measured surface onto every
    RPS point along its direction (least squares when over-determined; minimum norm over the degrees of freedom the
    points leave free, so those keep the prior (best-fit) pose; ``lock``ed DOFs are not moved). Rotations about the
    RPS points' centroid."""
    rps_points = list(rps_points)
    if not rps_points:
        raise InspectionInputError("an RPS alignment needs at least one reference point")
    unknown = sorted(set(lock) - set(DOF_NAMES))
    if unknown:
        raise InspectionInputError(f"unknown degrees of freedom to lock: {unknown} (known: {list(DOF_NAMES)})")
    free = np.array([name not in lock for name in DOF_NAMES])
    points = np.asarray(points_cad_mm, float)
    nominal = np.array([r.point for r in rps_points])
    directions = np.array([r.direction for r in rps_points])
    centre = nominal.mean(axis=0)
    jac = np.concatenate([np.cross(nominal - centre, directions), directions], axis=1)[:, free]
    rank = int(np.linalg.matrix_rank(jac, tol=1e-9 * max(1.0, float(np.abs(jac).max()))))
    correction = np.eye(4)
    first = None
    for _ in range(iterations):
        moved = apply(correction, points)
        deviation = np.array([_rps_measure(moved, r, radius_mm, reach_mm) for r in rps_points])
        first = deviation if first is None else first
        step = np.zeros(6)
        step[free] = np.linalg.lstsq(jac, -deviation, rcond=None)[0]
        update = np.eye(4)
        update[:3, :3] = Rotation.from_rotvec(step[:3]).as_matrix()
        update[:3, 3] = centre - update[:3, :3] @ centre + step[3:]
        correction = update @ correction
        if np.abs(step).max() < 1e-9:
            break
    moved = apply(correction, points)
    residual = [_rps_measure(moved, r, radius_mm, reach_mm) for r in rps_points]
    names = [r.name for r in rps_points]
    return RpsResult(correction, dict(zip(names, map(float, residual), strict=True)),
                     dict(zip(names, map(float, first), strict=True)), rank)  # fmt: skip
