"""Candidate views of the 3D next-best-view loop and their filter chain.

Sources (all at the PhoXi's sweet-spot distance from their target, sensor frame z = viewing direction):

- **frontier**: the planning grid's candidate voxels (unknown, next to an empty and a growth voxel: the report's S0
  candidates in 3D) are clustered (26-connected components, large ones split by k-means, at most ``max_targets``);
  per cluster the predicted surface gives a target point and normal ``n``; directions lie on cones of 0/20/40 deg
  around ``n`` at rolls 0/90 deg (the projector baseline's orientation changes the shadows). A **sphere of
  visibility** per target (``visibility_directions`` Fibonacci directions within ``visibility_max_angle`` of ``n``)
  keeps the directions whose camera ray is clear of full voxels; a blocked cone direction is replaced by the
  nearest clear one, and a pose whose projector ray to the target is blocked is dropped.
- **sphere**: a global view sphere of Fibonacci directions around the ROI centre (the opening game).
- **hemisphere**: a fixed set of ``n`` directions, elevations 15-75 deg (a baseline).

Filter chain (:meth:`CandidateGenerator.filter`), each rejected pose keeps its reason (:data:`REJECTION_REASONS`):
sensor inside the ROI or below the table; tabu (a visited or failed pose); no closed-form IK solution within the
joint limits (the solution nearest the current joints is kept); FCL collision of robot and housing with the scene;
collision with the not-yet-known-free region (the planning grid's full and unknown voxels, marching-cubed to a
mesh); line of sight from the sensor to the target. IK and collision run batched. Metres, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.settings import CandidateSettings

__all__ = [
    "REJECTION_REASONS",
    "CandidateConfig",
    "CandidateGenerator",
    "Candidates",
    "Targets",
    "fibonacci_sphere",
    "poses_from_directions",
    "segments_clear",
    "unknown_region_mesh",
]

REJECTION_REASONS = (
    "camera_occluded",
    "projector_occluded",
    "inside_roi",
    "below_table",
    "tabu",
    "ik",
    "collision_scene",
    "collision_unknown",
    "line_of_sight",
)

UNKNOWN_OBSTACLE = "not_known_free"


@dataclass(frozen=True)
class CandidateConfig:
    """Candidate generation parameters (``candidates`` of config/nbv.yaml); lengths m, angles rad."""

    standoff_m: float = 0.442
    baseline_m: float = 0.230
    cone_angles_rad: tuple = (0.0, math.radians(20.0), math.radians(40.0))
    cone_azimuths: int = 6
    rolls_rad: tuple = (0.0, math.pi / 2.0)
    max_targets: int = 30
    min_cluster_voxels: int = 2
    visibility_directions: int = 2000
    visibility_max_angle_rad: float = math.radians(60.0)
    sphere_directions: int = 96
    sphere_min_elevation_rad: float = math.radians(-10.0)
    roi_clearance_m: float = 0.03
    table_clearance_m: float = 0.05
    unknown_obstacle: bool = True
    unknown_obstacle_pool: int = 1  # the unknown obstacle on blocks of this many planning voxels per axis
    tabu_distance_m: float = 0.03
    tabu_angle_rad: float = math.radians(10.0)
    towards_unseen: bool = True  # add directions tilted from the normal towards the frontier's unseen side

    @classmethod
    def from_settings(cls, settings: CandidateSettings, scanner_model=None) -> CandidateConfig:
        """The configuration of ``candidates`` of config/nbv.yaml, the standoff and baseline of ``scanner_model``."""
        kwargs = {}
        if scanner_model is not None:
            kwargs["standoff_m"] = scanner_model.sweet_spot_mm / 1000.0
            kwargs["baseline_m"] = scanner_model.baseline_mm / 1000.0
        kwargs.update(settings.given())
        return cls(**kwargs)


@dataclass
class Targets:
    """Frontier targets: points (T, 3) m, unit normals (T, 3) pointing into observed-free space, voxel counts."""

    points_m: np.ndarray
    normals: np.ndarray
    sizes: np.ndarray
    tangents: np.ndarray | None = None  # (T, 3) from the seen surface towards the unseen side

    def __post_init__(self):
        if self.tangents is None:
            self.tangents = np.zeros_like(np.asarray(self.normals, dtype=float))

    def __len__(self) -> int:
        return len(self.points_m)


@dataclass
class Candidates:
    """Candidate poses (world <- sensor) with their target, source, IK joints and filter outcome."""

    poses: np.ndarray  # (N, 4, 4)
    targets_m: np.ndarray  # (N, 3) the point each pose aims at
    target_index: np.ndarray  # (N,) index into Targets, -1 for sphere / hemisphere poses
    source: np.ndarray  # (N,) str: frontier | sphere | hemisphere
    joints: np.ndarray = None  # (N, 6) rad, NaN where no IK
    feasible: np.ndarray = None  # (N,) bool
    reason: np.ndarray = None  # (N,) object: "" when feasible
    pre_rejections: dict = field(default_factory=dict)  # rejections before the poses were made (occlusion)

    def __post_init__(self):
        n = len(self.poses)
        if self.joints is None:
            self.joints = np.full((n, 6), np.nan)
        if self.feasible is None:
            self.feasible = np.ones(n, dtype=bool)
        if self.reason is None:
            self.reason = np.full(n, "", dtype=object)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def total(self) -> int:
        return len(self) + int(sum(self.pre_rejections.values()))

    def reject(self, mask: np.ndarray, reason: str) -> None:
        mask = np.asarray(mask, dtype=bool) & self.feasible
        self.feasible[mask] = False
        self.reason[mask] = reason

    def rejections(self) -> dict:
        counts = dict(self.pre_rejections)
        for reason in self.reason[~self.feasible]:
            counts[reason] = counts.get(reason, 0) + 1
        return counts

    def subset(self, mask) -> Candidates:
        mask = np.asarray(mask)
        return Candidates(
            self.poses[mask],
            self.targets_m[mask],
            self.target_index[mask],
            self.source[mask],
            self.joints[mask],
            self.feasible[mask],
            self.reason[mask],
        )

    @staticmethod
    def concatenate(parts: list[Candidates]) -> Candidates:
        parts = [p for p in parts if p is not None]
        if not parts:
            return Candidates(np.zeros((0, 4, 4)), np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, dtype=object))
        out = Candidates(
            np.concatenate([p.poses for p in parts]),
            np.concatenate([p.targets_m for p in parts]),
            np.concatenate([p.target_index for p in parts]),
            np.concatenate([p.source for p in parts]),
            np.concatenate([p.joints for p in parts]),
            np.concatenate([p.feasible for p in parts]),
            np.concatenate([p.reason for p in parts]),
        )
        for p in parts:
            for key, value in p.pre_rejections.items():
                out.pre_rejections[key] = out.pre_rejections.get(key, 0) + value
        return out


# ------------------------------------------------------------------------------------------- geometry
def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n, 3) on the sphere (golden-angle spiral)."""
    if n < 1:
        raise InputError(f"fibonacci_sphere: need at least one direction, got {n}")
    i = np.arange(n, dtype=float) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _orthonormal(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per unit vector (N, 3) an x (N, 3) perpendicular to it, horizontal where possible, and y = z x x."""
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), z.shape).copy()
    x = np.cross(z, up)
    small = np.linalg.norm(x, axis=1) < 1e-6
    x[small] = np.cross(z[small], np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x, np.cross(z, x)


def poses_from_directions(targets_m: np.ndarray, directions: np.ndarray, distance_m: float, rolls_rad) -> np.ndarray:
    """Sensor poses (N * R, 4, 4) at ``targets + distance * direction`` looking back at the targets, one per roll
    (rad, about the optical axis; roll 0 = image x horizontal), ordered pose-major."""
    targets_m = np.asarray(targets_m, dtype=float).reshape(-1, 3)
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    z = -d
    x0, y0 = _orthonormal(z)
    rolls = np.asarray(rolls_rad, dtype=float).reshape(-1)
    c, s = np.cos(rolls)[None, :, None], np.sin(rolls)[None, :, None]
    x = c * x0[:, None, :] + s * y0[:, None, :]
    y = -s * x0[:, None, :] + c * y0[:, None, :]
    n, r = len(d), len(rolls)
    poses = np.zeros((n, r, 4, 4))
    poses[..., :3, 0] = x
    poses[..., :3, 1] = y
    poses[..., :3, 2] = np.broadcast_to(z[:, None, :], (n, r, 3))
    poses[..., :3, 3] = np.broadcast_to((targets_m + distance_m * d)[:, None, :], (n, r, 3))
    poses[..., 3, 3] = 1.0
    return poses.reshape(n * r, 4, 4)


@numba.njit(cache=True)
def _segments_clear_kernel(blocked, origin, res, starts, ends, out):
    nx, ny, nz = blocked.shape
    step = 0.5 * res
    for i in range(starts.shape[0]):
        dx = ends[i, 0] - starts[i, 0]
        dy = ends[i, 1] - starts[i, 1]
        dz = ends[i, 2] - starts[i, 2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        n = int(length / step) + 1
        clear = True
        for s in range(n + 1):
            f = s / n
            ix = math.floor((starts[i, 0] + dx * f - origin[0]) / res)
            iy = math.floor((starts[i, 1] + dy * f - origin[1]) / res)
            iz = math.floor((starts[i, 2] + dz * f - origin[2]) / res)
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz and blocked[ix, iy, iz]:
                clear = False
                break
        out[i] = clear


def segments_clear(blocked: np.ndarray, origin_m, resolution_m: float, starts_m, ends_m) -> np.ndarray:
    """Whether each segment (N,) misses every ``blocked`` voxel (x, y, z grid at ``origin_m``, ``resolution_m``),
    sampled at half-voxel steps (compiled)."""
    starts = np.ascontiguousarray(np.asarray(starts_m, dtype=np.float64).reshape(-1, 3))
    ends = np.ascontiguousarray(np.broadcast_to(np.asarray(ends_m, dtype=np.float64), starts.shape))
    out = np.ones(len(starts), dtype=np.bool_)
    if len(starts):
        _segments_clear_kernel(
            np.ascontiguousarray(blocked, dtype=np.bool_),
            np.asarray(origin_m, dtype=np.float64),
            float(resolution_m),
            starts,
            ends,
            out,
        )
    return out


def unknown_region_mesh(grid, pool: int = 1):
    """The not-yet-known-free region of a (planning) grid as a closed Trimesh (world frame): its full and unknown
    voxels except the static ones (the scene checker has those), marching-cubed; None when nothing is left. With
    ``pool`` > 1 the region is taken on blocks of ``pool``^3 voxels (a block is in it when any of its voxels is): a
    superset with about ``pool``^2 times fewer faces (the collision tree is built afresh whenever the map changed)."""
    import trimesh
    from skimage.measure import marching_cubes

    labels = grid.labels()
    mask = (labels >= 0) & ~grid.static
    if not mask.any():
        return None
    if pool > 1:
        blocks = -(-np.asarray(mask.shape) // pool)
        full = np.zeros(blocks * pool, dtype=bool)
        full[: mask.shape[0], : mask.shape[1], : mask.shape[2]] = mask
        mask = full.reshape(blocks[0], pool, blocks[1], pool, blocks[2], pool).any(axis=(1, 3, 5))
    padded = np.pad(mask.astype(np.float32), 1)
    vertices, faces, _, _ = marching_cubes(padded, 0.5)
    # cell (i, j, k) of the padded volume is block (i - 1, ...) of the grid; its centre lies at (i + 0.5) * size
    vertices = (vertices - 1.0 + 0.5) * (pool * grid.resolution_m) + grid.origin_m
    return trimesh.Trimesh(vertices, faces[:, ::-1], process=False)


# ------------------------------------------------------------------------------------------- generator
class CandidateGenerator:
    """Builds and filters candidate views for one station (an :class:`~.station3d.NBVStation` or any object with
    ``ik``, ``collision_checker()``, ``table_top_m``)."""

    def __init__(self, station, config: CandidateConfig, seed: int = 0):
        self.station = station
        self.config = config
        self.rng = np.random.default_rng(seed)
        self.ik = station.ik
        #: the scene and the not-yet-known-free region (the motion router plans with it)
        self.checker = station.collision_checker()
        #: the scene alone (the first collision stage), so the region's tree in :attr:`checker` can stay while the
        #: map has not changed (a second pool in the same view, e.g. ours' coverage fallback, reuses it)
        self.scene_checker = station.collision_checker()
        self._visibility_dirs = fibonacci_sphere(int(config.visibility_directions))
        self._has_unknown = False
        self._unknown_key = None  # (the grid, its version) the region in ``checker`` was built from

    # ----------------------------------------------------------------------------------- targets
    def targets(self, grid, banned_m: np.ndarray | None = None) -> Targets:
        """Frontier targets of a planning grid: clustered candidate voxels, each with its predicted surface.

        Candidate voxels next to static geometry (where the part stands on the fixture: never measurable, its
        points are dropped within the static margin) and within ``tabu_distance_m`` of a ``banned_m`` point (an
        unmeasurable target of an earlier iteration) are left out. ``Targets.tangents`` points from the seen
        surface towards the unseen side (perpendicular to the normal; zero when undefined).
        """
        from scipy import ndimage

        cfg = self.config
        empty = Targets(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int))
        mask = grid.candidate_mask() & ~ndimage.binary_dilation(grid.static, np.ones((3, 3, 3), bool), iterations=2)
        if banned_m is not None and len(banned_m):
            idx = np.argwhere(mask)
            if len(idx):
                from scipy.spatial import cKDTree

                d, _ = cKDTree(np.asarray(banned_m).reshape(-1, 3)).query(grid.index_to_world(idx))
                far = d >= cfg.tabu_distance_m
                mask = np.zeros_like(mask)
                mask[tuple(idx[far].T)] = True
        if not mask.any():
            return empty
        labels, count = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
        voxels = np.argwhere(labels > 0)
        comp = labels[tuple(voxels.T)] - 1
        sizes = np.bincount(comp, minlength=count)
        keep = sizes >= cfg.min_cluster_voxels
        if not keep.any():
            return empty
        total = sizes[keep].sum()
        centroids, normals = grid.predicted_surface(voxels)
        # orient every normal like the scanner's normals of the points around it (they face the sensors that saw
        # them, so they point out of the part): the empty-neighbour rule can flip at an edge
        fused = np.stack(
            [ndimage.uniform_filter(grid.normal_sum[..., a], size=3, mode="constant") for a in range(3)], axis=-1
        )[tuple(voxels.T)]
        flip = np.einsum("ij,ij->i", normals, fused) < 0
        normals[flip] *= -1.0
        outward = grid.index_to_world(voxels) - centroids
        points, dirs, tangents, counts = [], [], [], []
        for c in np.argsort(-sizes):
            if not keep[c]:
                continue
            members = np.nonzero(comp == c)[0]
            k = int(
                min(len(members) // max(cfg.min_cluster_voxels, 1), max(1, round(cfg.max_targets * sizes[c] / total)))
            )
            groups = [members] if k <= 1 else self._split(centroids[members], members, k)
            for g in groups:
                n = normals[g].sum(axis=0)
                norm = np.linalg.norm(n)
                if norm < 1e-9:
                    continue
                n = n / norm
                t = outward[g].mean(axis=0)
                t = t - n * float(t @ n)
                t_norm = np.linalg.norm(t)
                points.append(centroids[g].mean(axis=0))
                dirs.append(n)
                tangents.append(t / t_norm if t_norm > 1e-6 else np.zeros(3))
                counts.append(len(g))
        if not points:
            return empty
        order = np.argsort(-np.asarray(counts))[: cfg.max_targets]
        return Targets(
            np.asarray(points)[order], np.asarray(dirs)[order], np.asarray(counts)[order], np.asarray(tangents)[order]
        )

    def _split(self, xyz: np.ndarray, members: np.ndarray, k: int) -> list:
        from scipy.cluster.vq import kmeans2

        _, assign = kmeans2(xyz, k, minit="++", seed=self.rng)
        return [members[assign == j] for j in range(k) if np.any(assign == j)]

    # ----------------------------------------------------------------------------------- sources
    def frontier(self, grid, targets: Targets) -> Candidates:
        """Cone directions around each target's normal, made clear by the sphere of visibility, at every roll."""
        cfg = self.config
        t = len(targets)
        if t == 0:
            return Candidates.concatenate([])
        blocked = grid.labels() == 1
        res = grid.resolution_m
        skip = 1.5 * math.sqrt(3.0) * res  # leave the target's own neighbourhood (the surface it lies on)
        sphere = self._visibility_dirs
        cos_max = math.cos(cfg.visibility_max_angle_rad)
        # the sphere of visibility: (T, D) directions near the normal whose camera ray is clear
        near = targets.normals @ sphere.T >= cos_max
        ti, di = np.nonzero(near)
        starts = targets.points_m[ti] + skip * sphere[di]
        ends = targets.points_m[ti] + cfg.standoff_m * sphere[di]
        clear = np.zeros(near.shape, dtype=bool)
        clear[ti, di] = segments_clear(blocked, grid.origin_m, res, starts, ends)
        # the ideal directions: cones around each normal
        # the ideal directions: cones around each normal, and the direction halfway towards the unseen side
        # (a frontier at an edge continues round the corner: the normal alone looks at what is already seen)
        ideal, owner = [], []
        for i in range(t):
            n = targets.normals[i]
            x, y = _orthonormal(n[None])
            for angle in cfg.cone_angles_rad:
                m = 1 if angle == 0.0 else cfg.cone_azimuths
                for a in np.arange(m) * (2.0 * math.pi / m):
                    ideal.append(math.cos(angle) * n + math.sin(angle) * (math.cos(a) * x[0] + math.sin(a) * y[0]))
                    owner.append(i)
            tangent = targets.tangents[i]
            if cfg.towards_unseen and np.linalg.norm(tangent) > 0.5:
                for angle in (math.radians(45.0), math.radians(70.0)):
                    ideal.append(math.cos(angle) * n + math.sin(angle) * tangent)
                    owner.append(i)
        ideal = np.asarray(ideal)
        owner = np.asarray(owner)
        # the nearest sphere direction stands for the ideal one; blocked ones move to the nearest clear direction
        cosines = ideal @ sphere.T  # (C, D)
        nearest = np.argmax(cosines, axis=1)
        ok = clear[owner, nearest]
        chosen = ideal.copy()
        masked = np.where(clear[owner], cosines, -2.0)
        best = np.argmax(masked, axis=1)
        substitute = ~ok & (masked[np.arange(len(best)), best] > math.cos(math.radians(30.0)))
        chosen[substitute] = sphere[best[substitute]]
        usable = ok | substitute
        pre = {"camera_occluded": int((~usable).sum()) * len(cfg.rolls_rad)}
        chosen, owner = chosen[usable], owner[usable]
        # nearby targets may produce the same direction twice: keep one
        key = np.round(np.concatenate([targets.points_m[owner] * 100.0, chosen * 20.0], axis=1))
        _, unique = np.unique(key, axis=0, return_index=True)
        unique = np.sort(unique)
        chosen, owner = chosen[unique], owner[unique]
        poses = poses_from_directions(targets.points_m[owner], chosen, cfg.standoff_m, cfg.rolls_rad)
        r = len(cfg.rolls_rad)
        owner = np.repeat(owner, r)
        aim = targets.points_m[owner]
        # the projector ray from the target must be clear too (the structured-light shadow)
        projector = poses[:, :3, 3] + cfg.baseline_m * poses[:, :3, 0]
        to_projector = projector - aim
        to_projector /= np.linalg.norm(to_projector, axis=1, keepdims=True)
        lit = segments_clear(blocked, grid.origin_m, res, aim + skip * to_projector, projector)
        pre["projector_occluded"] = int((~lit).sum())
        out = Candidates(poses[lit], aim[lit], owner[lit], np.full(int(lit.sum()), "frontier", dtype=object))
        out.pre_rejections = pre
        return out

    def sphere(self, center_m, n: int | None = None) -> Candidates:
        """The global view sphere around ``center_m`` at the sweet spot, down to ``sphere_min_elevation``."""
        cfg = self.config
        n = int(n or cfg.sphere_directions)
        # spread n directions over the usable cap only
        cap = (1.0 - math.sin(cfg.sphere_min_elevation_rad)) / 2.0
        dirs = fibonacci_sphere(max(n, math.ceil(n / max(cap, 1e-3))))
        dirs = dirs[dirs[:, 2] >= math.sin(cfg.sphere_min_elevation_rad)][:n]
        return self._around(center_m, dirs, "sphere")

    @staticmethod
    def object_center(grid, roi_min_m, roi_max_m) -> np.ndarray:
        """Where the global sphere looks: the centre of the bounding box of the object seen so far (its full and
        candidate voxels), else the ROI's centre. A flat part lies far below the ROI's centre, out of the scanning
        range of views aimed there."""
        if grid is not None:
            idx = np.argwhere(grid.full_mask() | grid.candidate_mask())
            if len(idx):
                pts = grid.index_to_world(idx)
                return 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        return 0.5 * (np.asarray(roi_min_m, dtype=float) + np.asarray(roi_max_m, dtype=float))

    def hemisphere(self, center_m, n: int) -> Candidates:
        """A fixed hemisphere of ``n`` directions (rings at elevations 15-75 deg), roll 0."""
        if n < 1:
            raise InputError(f"hemisphere: need at least one view, got {n}")
        rings = 3 if n >= 12 else 2
        elevations = np.radians(np.linspace(15.0, 75.0, rings))
        per = np.full(rings, n // rings)
        per[: n - per.sum()] += 1
        dirs = []
        for e, m in zip(elevations, per, strict=True):
            for k in range(m):
                a = 2.0 * math.pi * (k + 0.5 * (e == elevations[1] if rings > 1 else 0)) / m
                dirs.append([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        return self._around(center_m, np.asarray(dirs), "hemisphere", rolls=(0.0,))

    def _around(self, center_m, dirs, source: str, rolls=None) -> Candidates:
        cfg = self.config
        rolls = cfg.rolls_rad if rolls is None else rolls
        center = np.asarray(center_m, dtype=float).reshape(1, 3)
        poses = poses_from_directions(np.repeat(center, len(dirs), axis=0), dirs, cfg.standoff_m, rolls)
        n = len(poses)
        return Candidates(poses, np.repeat(center, n, axis=0), np.full(n, -1), np.full(n, source, dtype=object))

    # ----------------------------------------------------------------------------------- filters
    def update_unknown_obstacle(self, grid) -> None:
        """Give the collision checker the grid's not-yet-known-free region (replacing the previous one; kept as it
        is while the same grid has not changed since)."""
        key = (id(grid), grid.version) if self.config.unknown_obstacle and grid is not None else None
        if key is not None and key == self._unknown_key:
            return
        if self._has_unknown:
            self.checker.remove_object(UNKNOWN_OBSTACLE)
            self._has_unknown = False
        self._unknown_key = key
        if key is None:
            return
        mesh = unknown_region_mesh(grid, self.config.unknown_obstacle_pool)
        if mesh is not None and len(mesh.faces):
            self.checker.add_mesh(UNKNOWN_OBSTACLE, mesh.vertices, mesh.faces, np.eye(4))
            self._has_unknown = True

    def filter(self, cands: Candidates, grid, roi_min_m, roi_max_m, current_q, tabu=()) -> Candidates:
        """Run the filter chain in place (each stage only on what survived the previous); returns ``cands``."""
        cfg = self.config
        if len(cands) == 0:
            return cands
        pos = cands.poses[:, :3, 3]
        lo = np.asarray(roi_min_m) - cfg.roi_clearance_m
        hi = np.asarray(roi_max_m) + cfg.roi_clearance_m
        cands.reject(np.all((pos > lo) & (pos < hi), axis=1), "inside_roi")
        cands.reject(pos[:, 2] < self.station.table_top_m + cfg.table_clearance_m, "below_table")
        if len(tabu):
            cands.reject(self._in_tabu(cands.poses, list(tabu)), "tabu")
        alive = np.nonzero(cands.feasible)[0]
        if len(alive):
            q, ok = self.ik.solve_nearest(cands.poses[alive], np.asarray(current_q, dtype=float))
            q = np.atleast_2d(q)
            ok = np.atleast_1d(ok)
            cands.joints[alive[ok]] = q[ok]
            bad = np.zeros(len(cands), dtype=bool)
            bad[alive[~ok]] = True
            cands.reject(bad, "ik")
        self._collision_stage(cands, grid)
        alive = np.nonzero(cands.feasible & (cands.source == "frontier"))[0]
        if len(alive) and grid is not None:
            blocked = grid.labels() == 1
            aim = cands.targets_m[alive]
            pos = cands.poses[alive, :3, 3]
            direction = pos - aim
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            skip = 1.5 * math.sqrt(3.0) * grid.resolution_m
            clear = segments_clear(blocked, grid.origin_m, grid.resolution_m, aim + skip * direction, pos)
            bad = np.zeros(len(cands), dtype=bool)
            bad[alive[~clear]] = True
            cands.reject(bad, "line_of_sight")
        return cands

    def _collision_stage(self, cands: Candidates, grid) -> None:
        alive = np.nonzero(cands.feasible)[0]
        if not len(alive):
            return
        q = cands.joints[alive]
        free = self.scene_checker.check_states(q)
        bad = np.zeros(len(cands), dtype=bool)
        bad[alive[~free]] = True
        cands.reject(bad, "collision_scene")
        self.update_unknown_obstacle(grid)
        if self._has_unknown:
            alive = np.nonzero(cands.feasible)[0]
            if len(alive):
                free = self.checker.check_states(cands.joints[alive])
                bad = np.zeros(len(cands), dtype=bool)
                bad[alive[~free]] = True
                cands.reject(bad, "collision_unknown")

    def _in_tabu(self, poses: np.ndarray, tabu) -> np.ndarray:
        """Poses (N,) near a tabu entry: a visited or failed pose (``tabu_distance_m``, ``tabu_angle_rad``, same
        roll within 30 deg: turned by 90 deg about its axis it is another view), or ``(pose, distance_m,
        angle_rad)`` for a wider region regardless of roll (views that saw far less than promised)."""
        cfg = self.config
        plain = [np.asarray(t) for t in tabu if not isinstance(t, tuple)]
        wide = [t for t in tabu if isinstance(t, tuple)]
        out = np.zeros(len(poses), dtype=bool)
        if plain:
            t = np.asarray(plain)
            d = np.linalg.norm(poses[:, None, :3, 3] - t[None, :, :3, 3], axis=2)
            c = np.einsum("ni,ti->nt", poses[:, :3, 2], t[:, :3, 2])
            r = np.einsum("ni,ti->nt", poses[:, :3, 0], t[:, :3, 0])
            out |= (
                (d < cfg.tabu_distance_m) & (c > math.cos(cfg.tabu_angle_rad)) & (r > math.cos(math.radians(30.0)))
            ).any(axis=1)
        if wide:
            t = np.asarray([np.asarray(w[0]) for w in wide])
            dist = np.asarray([float(w[1]) for w in wide])
            cos = np.cos(np.asarray([float(w[2]) for w in wide]))
            d = np.linalg.norm(poses[:, None, :3, 3] - t[None, :, :3, 3], axis=2)
            c = np.einsum("ni,ti->nt", poses[:, :3, 2], t[:, :3, 2])
            out |= ((d < dist[None, :]) & (c > cos[None, :])).any(axis=1)
        return out

    def generate(self, grid, roi_min_m, roi_max_m, current_q, sources: str = "frontier+sphere", tabu=(),
                 targets: Targets | None = None) -> tuple[Candidates, Targets]:  # fmt: skip
        """Raw candidates of ``sources`` ("frontier", "sphere", "frontier+sphere") through the filter chain."""
        parts = []
        names = set(sources.split("+"))
        unknown = names - {"frontier", "sphere"}
        if unknown or not names:
            raise InputError(
                f"candidates: unknown source(s) {sorted(unknown)}; use frontier, sphere or frontier+sphere"
            )
        if targets is None:
            targets = (
                self.targets(grid)
                if "frontier" in names
                else Targets(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int))
            )
        if "frontier" in names:
            parts.append(self.frontier(grid, targets))
        if "sphere" in names:
            parts.append(self.sphere(self.object_center(grid, roi_min_m, roi_max_m)))
        cands = Candidates.concatenate(parts)
        return self.filter(cands, grid, roi_min_m, roi_max_m, current_q, tabu), targets
