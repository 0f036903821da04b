"""The inspection facade: a measured cloud, the nominal CAD and a spec in; registration, signed deviations,
surface regions, features and ISO 14253-1 decisions out (:class:`InspectionResult`). Stages report progress
through a callback ``progress(stage, fraction)`` (:data:`STAGES`). Lengths in mm; the cloud in the world frame,
brought into the CAD frame by the planned placement and the registration.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import trimesh

from agiprobot_measurement.inspection.decision import CONFORM, COVERAGE_FACTOR, INDETERMINATE, NOT_CONFORM
from agiprobot_measurement.inspection.deviation import closest_points, edge_distance, edge_mask, no_data_mask, patches
from agiprobot_measurement.inspection.errors import InspectionInputError, RegistrationError
from agiprobot_measurement.inspection.features import FeatureContext, FeatureResult, evaluate_feature
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty
from agiprobot_measurement.inspection.registration import (
    Registration,
    apply,
    datum_frame,
    icp,
    prealign,
    rps_alignment,
)
from agiprobot_measurement.inspection.spec import InspectionSpec

__all__ = ["MIN_POINTS", "STAGES", "InspectionResult", "SurfaceRegion", "inspect_cloud"]

STAGES = ("check", "register", "deviations", "regions", "features", "done")
#: fewer measured points than this is not an inspection
MIN_POINTS = 500
#: a registration whose robust residual exceeds this many times the scatter the scanner explains (the points' noise
#: with its systematic surface and view-stitching terms, in quadrature) is a wrong part
MAX_RESIDUAL_OVER_NOISE = 6.0


@dataclass
class SurfaceRegion:
    """A connected region of patches outside the tolerance (or indeterminate): its verdict, extreme deviation
    (mm, small-patch mean), where that lies (CAD, mm), its area (mm^2) and the U (mm) at the extreme."""

    verdict: str
    extreme_mm: float
    location_mm: list
    area_mm2: float
    uncertainty_mm: float
    patches: int

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class InspectionResult:
    """Everything an inspection found; arrays per measured point are in the CAD frame."""

    spec: InspectionSpec
    points_cad: np.ndarray
    signed_mm: np.ndarray
    sigma_mm: np.ndarray
    face_of_point: np.ndarray
    edge: np.ndarray
    outlier: np.ndarray
    registration: Registration
    transform: np.ndarray  # CAD <- world
    regions: list[SurfaceRegion]
    face_stats: dict
    features: list[FeatureResult]
    coverage: dict
    surface_uncertainty_mm: float
    smoothed_mm: np.ndarray  # per point: the mean deviation of its patch (NaN where masked)
    timings_s: dict = field(default_factory=dict)
    instrument: InstrumentUncertainty = field(default_factory=InstrumentUncertainty)
    region_of_point: np.ndarray | None = None  # per point: its index in ``regions`` (-1: in none, i.e. conform)

    @property
    def flags(self) -> int:
        """Surface regions that do not conform."""
        return sum(r.verdict == NOT_CONFORM for r in self.regions)

    @property
    def verdict(self) -> str:
        verdicts = [r.verdict for r in self.regions] + [f.verdict for f in self.features]
        return NOT_CONFORM if NOT_CONFORM in verdicts else INDETERMINATE if INDETERMINATE in verdicts else CONFORM


def _check(points: np.ndarray, mesh: trimesh.Trimesh, spec: InspectionSpec, sigma) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) < 4:
        raise InspectionInputError("the nominal model must be a triangle mesh with at least 4 faces")
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InspectionInputError(f"the cloud must be N x 3 points, got shape {points.shape}")
    finite = np.all(np.isfinite(points), axis=1)
    points = points[finite]
    if len(points) < MIN_POINTS:
        raise InspectionInputError(
            f"the cloud has {len(points)} finite points; an inspection needs at least {MIN_POINTS}"
        )
    if sigma is None:
        return points, np.full(len(points), np.nan)
    sigma = np.asarray(sigma, dtype=float).reshape(-1)
    if len(sigma) != len(finite):
        raise InspectionInputError(f"{len(sigma)} noise values for {len(finite)} points")
    return points, sigma[finite]


def _unit_check(points_cad: np.ndarray, mesh: trimesh.Trimesh) -> None:
    """Refuse a cloud whose size is off the model's by a unit factor (the cloud may cover part of the model)."""
    cloud = float(np.linalg.norm(np.ptp(points_cad, axis=0)))
    model = float(np.linalg.norm(mesh.extents))
    ratio = cloud / model
    if ratio > 3.0 or ratio < 0.02:
        hints = [name for name, f in (("m vs mm", 1000.0), ("in vs mm", 25.4), ("cm vs mm", 10.0))
                 if abs(np.log(ratio * f)) < 0.7 or abs(np.log(ratio / f)) < 0.7]  # fmt: skip
        raise InspectionInputError(
            f"the cloud spans {cloud:.4g} and the nominal model {model:.4g} (in the spec's unit): a unit mismatch"
            + (f" ({hints[0]}?)" if hints else " or another part")
        )


def _register(points, mesh, spec, placement, progress) -> tuple[Registration, np.ndarray]:
    initial = prealign(points, placement)
    _unit_check(apply(initial, points), mesh)
    reg = icp(points, mesh, spec.icp, initial=initial)
    progress("register", 0.7)
    if spec.alignment == "datum_321":
        moved = apply(reg.transform, points)
        cp = closest_points(mesh, moved)
        sets, planes = [], []
        for name in spec.datums:
            on = spec.on_face(mesh, name, cp.face) & (np.abs(cp.signed_mm) < spec.icp.max_distance_mm)
            on &= ~edge_mask(mesh, cp.closest_mm, spec.surface.edge_margin_mm)
            sets.append(moved[on])
            face = spec.faces[name]
            planes.append((face.point, face.normal))
        correction = datum_frame(sets, planes)
        reg.transform = correction @ reg.transform
        reg.method = "datum_321"
    elif spec.alignment == "rps":
        result = rps_alignment(apply(reg.transform, points), spec.rps_points, spec.rps_radius_mm,
                               lock=spec.icp.lock)  # fmt: skip
        reg.transform = result.correction @ reg.transform
        reg.method, reg.rps = "rps", result
    return reg, reg.transform


def inspect_cloud(points_world_mm, nominal: trimesh.Trimesh, spec: InspectionSpec, nominal_placement=None,
                  sigma_mm=None, progress=None, instrument: InstrumentUncertainty | None = None) -> InspectionResult:  # fmt: skip
    """Inspect a measured cloud (world, in the spec's unit) against the nominal mesh (CAD frame, same unit).
    ``instrument``: the scanner's systematic terms (mm) entering every uncertainty (None: noise only)."""
    instrument = instrument or InstrumentUncertainty()
    report = progress or (lambda stage, fraction: None)
    timings, t0 = {}, time.perf_counter()
    report("check", 0.0)
    points, sigma = _check(points_world_mm, nominal, spec, sigma_mm)
    scale = spec.unit_scale_to_mm
    if scale != 1.0:
        points, sigma = points * scale, sigma * scale
        nominal = nominal.copy()
        nominal.apply_scale(scale)
    spec.check_against(nominal)
    placement = np.eye(4) if nominal_placement is None else np.asarray(nominal_placement, float).copy()
    placement[:3, 3] *= scale
    timings["check"] = time.perf_counter() - t0
    report("register", 0.0)
    t = time.perf_counter()
    reg, transform = _register(points, nominal, spec, placement, report)
    timings["register"] = time.perf_counter() - t
    report("deviations", 0.0)
    t = time.perf_counter()
    cad = apply(transform, points)
    cp = closest_points(nominal, cad)
    s = spec.surface
    outlier = np.abs(cp.signed_mm) > s.max_distance_mm
    if outlier.mean() > 0.5:
        raise RegistrationError(f"{100 * outlier.mean():.0f} % of the points lie farther than {s.max_distance_mm} mm "
                                "from the nominal surface after registration: a cloud of another part?")  # fmt: skip
    to_edge = edge_distance(nominal, cp.closest_mm, s.edge_margin_mm)
    edge = np.isfinite(to_edge)
    use = ~outlier & ~edge
    if np.isnan(sigma).any():  # no noise model given: the points' scatter about their voxel's mean
        local = patches(cp.closest_mm, cp.signed_mm, np.zeros(len(cad)), use, s.voxel_mm, 0.5 * s.voxel_mm)
        scatter = cp.signed_mm[use] - local.mean_mm[local.voxel_of_point[use]]
        sigma = np.where(np.isnan(sigma), 1.4826 * float(np.median(np.abs(scatter))), sigma)
    # views stitched with a relative pose error (stitching_mm) disagree by about that much where they meet the fit
    scatter = float(np.hypot(np.median(sigma[use]), np.hypot(instrument.surface_mm, instrument.stitching_mm)))
    if reg.residual_mm > MAX_RESIDUAL_OVER_NOISE * max(scatter, 1e-3):
        raise RegistrationError(f"the registration's residual ({reg.residual_mm:.3g} mm) is far above the noise and "
                                f"the scanner's systematic terms ({scatter:.3g} mm): a cloud of another part?")  # fmt: skip
    timings["deviations"] = time.perf_counter() - t
    report("regions", 0.0)
    t = time.perf_counter()
    regions, u_surface, smoothed, region_of_point = _regions(nominal, cp, sigma, use, reg, s, instrument.surface_mm)
    face_of_point, face_stats, face_points, edge_points = _faces(nominal, spec, cp, use, ~outlier & edge,
                                                                 s.tolerance_mm)  # fmt: skip
    coverage = _coverage(nominal, spec, cp.closest_mm[use], s.no_data_radius_mm)
    timings["regions"] = time.perf_counter() - t
    report("features", 0.0)
    t = time.perf_counter()
    ctx = FeatureContext(cad, sigma, ~outlier, face_points, {n: (f.point, f.normal) for n, f in spec.faces.items()},
                         reg.displacement_sigma, instrument, reg.centre_mm, edge_points, to_edge)  # fmt: skip
    results = [evaluate_feature(feature, ctx) for feature in spec.features]
    timings["features"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    report("done", 1.0)
    return InspectionResult(spec, cad, cp.signed_mm, sigma, face_of_point, edge, outlier, reg, transform, regions,
                            face_stats, results, coverage, u_surface, smoothed, timings, instrument,
                            region_of_point)  # fmt: skip


def _regions(mesh, cp, sigma, use, reg, s, systematic_mm=0.0) -> tuple[list[SurfaceRegion], float, np.ndarray,
                                                                       np.ndarray]:  # fmt: skip
    """The regions outside the tolerance or indeterminate (worst first), the median U, each point's patch mean and
    each point's region (index, -1: none)."""
    pat = patches(cp.closest_mm, cp.signed_mm, sigma, use, s.voxel_mm, s.patch_radius_mm)
    smoothed = np.full(len(cp.signed_mm), np.nan)
    region_of_point = np.full(len(cp.signed_mm), -1, dtype=np.int32)
    if not len(pat.mean_mm):
        return [], float("nan"), smoothed, region_of_point
    smoothed[use] = pat.mean_mm[pat.voxel_of_point[use]]
    normals = mesh.face_normals[cp.face[use]]
    voxel = pat.voxel_of_point[use]
    n_sum = np.stack([np.bincount(voxel, weights=normals[:, k], minlength=len(pat.count)) for k in range(3)], axis=1)
    n_sum /= np.maximum(np.linalg.norm(n_sum, axis=1, keepdims=True), 1e-12)
    u_reg = reg.displacement_sigma(pat.centre_mm, n_sum)
    uncertainty = COVERAGE_FACTOR * np.sqrt(pat.sigma_mm**2 + u_reg**2 + systematic_mm**2)
    magnitude = np.abs(pat.mean_mm)
    t = s.tolerance_mm
    flagged = magnitude >= t - uncertainty
    found = []
    for members in pat.regions(flagged):
        worst = members[np.argmax(magnitude[members])]
        extreme, location = _peak(cp, use, pat, members, worst, s)
        not_conform = np.any(magnitude[members] >= t + uncertainty[members])
        found.append((SurfaceRegion(NOT_CONFORM if not_conform else INDETERMINATE, extreme, location.tolist(),
                                    float(len(members) * s.voxel_mm**2), float(uncertainty[worst]), len(members)),
                      members))  # fmt: skip
    found.sort(key=lambda item: -abs(item[0].extreme_mm))
    region_of_patch = np.full(len(pat.mean_mm), -1, dtype=np.int32)
    for index, (_, members) in enumerate(found):
        region_of_patch[members] = index
    region_of_point[use] = region_of_patch[pat.voxel_of_point[use]]
    return [region for region, _ in found], float(np.median(uncertainty)), smoothed, region_of_point


def _peak(cp, use, pat, members, worst, s) -> tuple[float, np.ndarray]:
    """A region's extreme deviation: a paraboloid fitted (LS) to the deviations within ``depth_radius_mm`` + 1.5 mm
    of its worst patch, evaluated at its vertex (kept within a patch radius); the worst patch's mean when too few
    points."""
    centre = pat.centre_mm[worst]
    idx = np.flatnonzero(use)
    member = np.zeros(len(pat.mean_mm), dtype=bool)
    member[members] = True
    idx = idx[member[pat.voxel_of_point[idx]]]
    rel = cp.closest_mm[idx] - centre
    window = s.depth_radius_mm + 1.5
    near = np.einsum("ij,ij->i", rel, rel) <= window**2
    if near.sum() < 30:
        return float(pat.mean_mm[worst]), centre
    rel, dev = rel[near], cp.signed_mm[idx[near]]
    _, _, vt = np.linalg.svd(rel - rel.mean(axis=0), full_matrices=False)
    x, y = rel @ vt[0], rel @ vt[1]
    design = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)
    a, b, c, d, e, f = np.linalg.lstsq(design, dev, rcond=None)[0]
    hessian = np.array([[2 * d, e], [e, 2 * f]])
    vertex = np.zeros(2)
    if abs(np.linalg.det(hessian)) > 1e-12:
        vertex = np.linalg.solve(hessian, -np.array([b, c]))
        if np.linalg.norm(vertex) > s.patch_radius_mm:
            vertex = np.zeros(2)
    value = a + b * vertex[0] + c * vertex[1] + d * vertex[0] ** 2 + e * vertex[0] * vertex[1] + f * vertex[1] ** 2
    return float(value), centre + vertex[0] * vt[0] + vertex[1] * vt[1]


def _stats(values: np.ndarray, tolerance: float) -> dict:
    if not len(values):
        return {"points": 0}
    p = np.percentile(values, [0.15, 50, 99.85])
    return {"points": len(values), "mean_mm": float(values.mean()), "std_mm": float(values.std()),
            "min_mm": float(values.min()), "max_mm": float(values.max()), "p0_15_mm": float(p[0]),
            "median_mm": float(p[1]), "p99_85_mm": float(p[2]),
            "in_tolerance_percent": float(100 * np.mean(np.abs(values) <= tolerance))}  # fmt: skip


def _faces(mesh, spec, cp, use, edge_band, tolerance):
    """Per named face: the points' face names, statistics, the face's points (masks applied) and its points in the
    edge band (masked only for being near an edge)."""
    face_of_point = np.full(len(cp.face), "", dtype=object)
    stats, members, near_edge = {"all": _stats(cp.signed_mm[use], tolerance)}, {}, {}
    for name in spec.faces:
        face = spec.on_face(mesh, name, cp.face)
        on = face & use
        face_of_point[on] = name
        members[name] = np.flatnonzero(on)
        near_edge[name] = np.flatnonzero(face & edge_band)
        stats[name] = _stats(cp.signed_mm[on], tolerance)
    return face_of_point, stats, members, near_edge


def _coverage(mesh, spec, closest_used, radius) -> dict:
    count = int(np.clip(mesh.area / radius**2, 1000, 200000))
    samples, face = trimesh.sample.sample_surface(mesh, count, seed=0)
    empty = no_data_mask(samples, closest_used, radius)
    result = {"all_percent": float(100 * (1 - empty.mean())), "samples": len(samples)}
    for name in spec.faces:
        on = spec.on_face(mesh, name, face)
        result[f"{name}_percent"] = float(100 * (1 - empty[on].mean())) if on.any() else 0.0
    return result
