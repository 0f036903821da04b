"""Features of the spec evaluated on the registered cloud (CAD frame, mm): value, uncertainty, verdict.

Each evaluator receives the points of its face(s) (closest nominal triangle on the face, sharp edges and
outliers masked) or, for holes, spheres and cylinders, the points near the nominal element, and returns a
:class:`FeatureResult` with the ISO 14253-1 decision(s). Standard uncertainties combine the fit's (from the
points' noise) with the registration's at the feature (its covariance propagated); the expanded U = 2 u.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from agiprobot_measurement.inspection.decision import Decision, decide, expanded
from agiprobot_measurement.inspection.deviation import patches
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.fitting import (
    fit_circle,
    fit_cylinder,
    fit_plane,
    fit_sphere,
    min_zone_flatness,
    plane_basis,
)
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty
from agiprobot_measurement.inspection.spec import Feature

__all__ = ["FeatureContext", "FeatureResult", "evaluate_feature"]

#: flatness: the face's heights are averaged within this radius (mm) before the minimum zone (noise filter)
FLATNESS_FILTER_RADIUS_MM = 5.0
#: flatness: of the points the face's edge margin masks, those at least this many point spacings from the CAD edge
#: are kept (the scanners' edge errors -- mixed pixels, mixed line points -- are one point wide): the zone's ends
#: lie at the face's edges
FLATNESS_EDGE_SPACINGS = 2.0
#: points sampled to estimate the face's point spacing (median distance to the nearest other point)
SPACING_SAMPLE = 20_000
#: flatness: points farther than this many robust sigma from the local plane of the face's interior are left out
FLATNESS_OUTLIER_SIGMAS = 4.0
#: hole edge ring: angular bins of the edge points
HOLE_EDGE_BINS = 90
#: hole wall: fewest points and smallest arc (deg, in 10-deg bins holding at least WALL_BIN_POINTS points) for the
#: LS circle through the wall (else the edge ring): a free-radius circle through a shorter arc trades its centre for
#: its radius
MIN_WALL_POINTS = 100
MIN_WALL_ARC_DEG = 180.0
WALL_BIN_POINTS = 3

#: fewest points a feature is evaluated on
MIN_FEATURE_POINTS = 30


@dataclass
class FeatureResult:
    """A feature's measured values (mm), decisions, the points it used and notes (biases, filters)."""

    name: str
    type: str
    values: dict
    decisions: list[Decision]
    points: int
    notes: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        verdicts = {d.verdict for d in self.decisions}
        for v in ("not conform", "indeterminate", "conform"):
            if v in verdicts:
                return v
        return "reported" if self.values else "not evaluated"

    def as_dict(self) -> dict:
        return {"name": self.name, "type": self.type, "verdict": self.verdict, "points": self.points,
                "values": self.values, "decisions": [d.as_dict() for d in self.decisions], "notes": self.notes}  # fmt: skip


@dataclass
class FeatureContext:
    """What the evaluators share: the registered points (CAD, mm), their noise sigma (mm), a mask of points
    usable for fits, the points of each named face, and the registration's displacement sigma function; the
    points of each face that only the edge margin masks and each point's distance to the nearest CAD edge (mm, inf
    beyond the margin)."""

    points: np.ndarray
    sigma: np.ndarray
    usable: np.ndarray
    face_points: dict
    face_planes: dict
    registration_sigma: object  # callable(points (N, 3), normals (N, 3)) -> (N,) mm
    instrument: InstrumentUncertainty = field(default_factory=InstrumentUncertainty)
    registration_centre_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    edge_points: dict = field(default_factory=dict)
    edge_distance_mm: np.ndarray | None = None


def _face(ctx: FeatureContext, name: str, feature: str) -> np.ndarray:
    idx = ctx.face_points.get(name, np.zeros(0, dtype=int))
    if len(idx) < MIN_FEATURE_POINTS:
        raise InspectionInputError(f"feature {feature!r}: face {name!r} has {len(idx)} measured points, too few")
    return idx


def _flatness(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    interior, band, margin = _flatness_points(ctx, feature.faces[0], feature.name)
    plane = fit_plane(ctx.points[interior], ctx.face_planes[feature.faces[0]][1])
    u, v = plane_basis(plane.normal)
    idx = np.concatenate([interior, band])
    pts = ctx.points[idx]
    xy = np.stack([(pts - plane.centroid) @ u, (pts - plane.centroid) @ v], axis=1)
    h = plane.heights(pts)
    keep = _on_local_planes(xy, h, ctx.sigma[idx], np.arange(len(idx)) < len(interior))
    dropped = int(len(idx) - keep.sum())
    idx, pts, xy, h = idx[keep], pts[keep], xy[keep], h[keep]
    voxel = FLATNESS_FILTER_RADIUS_MM / 2
    pat = patches(np.c_[xy, np.zeros(len(xy))], h, ctx.sigma[idx], np.ones(len(idx), dtype=bool), voxel,
                  FLATNESS_FILTER_RADIUS_MM)  # fmt: skip
    at, heights = _local_linear(xy, h, pat)
    filtered = plane.centroid + at[:, :1] * u + at[:, 1:2] * v + heights[:, None] * plane.normal
    value = min_zone_flatness(filtered, plane.normal)
    raw = min_zone_flatness(pts, plane.normal)
    sigma_f = float(np.median(pat.sigma_mm))
    independent = max(len(pat.mean_mm) * voxel**2 / (np.pi * FLATNESS_FILTER_RADIUS_MM**2), 2.0)
    u_f = sigma_f * np.sqrt(2 * np.log(independent))
    tol = feature.params["tolerance_mm"]
    return FeatureResult(
        feature.name, "flatness",
        {"flatness_mm": value, "raw_flatness_mm": raw, "ls_rms_mm": plane.rms_mm, "filter_radius_mm": FLATNESS_FILTER_RADIUS_MM,
         "edge_margin_mm": margin, "dropped_points": dropped},
        [decide("flatness", value, tol, expanded(u_f, ctx.instrument.form_mm))], len(idx),
        [f"minimum zone of the heights filtered by local LS planes within {FLATNESS_FILTER_RADIUS_MM} mm, evaluated "
         "at each patch's centroid and its outermost points; raw (unfiltered) zone includes about 6 sigma of noise; "
         f"points from {margin:.2f} mm of the CAD edges ({FLATNESS_EDGE_SPACINGS:g} point spacings); {dropped} points "
         f"off the face's local planes by more than {FLATNESS_OUTLIER_SIGMAS:g} sigma left out (mixed edge points)"],
    )  # fmt: skip


def _on_local_planes(xy: np.ndarray, h: np.ndarray, sigma: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """True for points whose height lies within ``FLATNESS_OUTLIER_SIGMAS`` robust sigma (1.4826 x the median
    absolute residual of the ``inner`` points) of the local LS plane of the nearest patch of the ``inner`` points
    (the face away from its edges): a scanner's mixed points hover off the face near its measured edge (up to the
    depth jump there), and a CAD edge margin does not hold them out where the registration leaves the part's edge
    off the CAD's (locked in-plane DOFs)."""
    voxel = FLATNESS_FILTER_RADIUS_MM / 2
    n = int(inner.sum())
    pat = patches(np.c_[xy[inner], np.zeros(n)], h[inner], sigma[inner], np.ones(n, dtype=bool), voxel,
                  FLATNESS_FILTER_RADIUS_MM)  # fmt: skip
    coef, ok = _local_planes(xy[inner], h[inner], pat)
    if not ok.any():
        return np.ones(len(h), dtype=bool)
    _, nearest = cKDTree(pat.centre_mm[ok, :2]).query(xy)
    c = coef[ok][nearest]
    residual = h - (c[:, 0] + c[:, 1] * xy[:, 0] + c[:, 2] * xy[:, 1])
    scale = 1.4826 * float(np.median(np.abs(residual[inner])))
    return np.abs(residual) <= FLATNESS_OUTLIER_SIGMAS * max(scale, 1e-6)


def _flatness_points(ctx: FeatureContext, name: str, feature: str) -> tuple[np.ndarray, np.ndarray, float]:
    """The face's points for its flatness: those the surface's masks leave (interior), those of its edge band at
    least ``FLATNESS_EDGE_SPACINGS`` point spacings from the CAD edge, and that margin (mm). The surface's edge
    margin guards the deviation map against closest points sliding over an edge; a flatness needs only the
    scanner's edge errors left out, and a margin of fixed width leaves the zone's ends unmeasured (a bow reads
    short by about 2 x margin / length of itself)."""
    idx = _face(ctx, name, feature)
    face = ctx.points[idx]
    sample = face[np.random.default_rng(0).choice(len(face), min(len(face), SPACING_SAMPLE), replace=False)]
    spacing = float(np.median(cKDTree(face).query(sample, k=2)[0][:, 1]))
    margin = FLATNESS_EDGE_SPACINGS * spacing
    band = ctx.edge_points.get(name, np.zeros(0, dtype=int))
    if ctx.edge_distance_mm is not None and len(band):
        band = band[ctx.edge_distance_mm[band] >= margin]
    return idx, band, margin


def _local_planes(xy: np.ndarray, h: np.ndarray, pat) -> tuple[np.ndarray, np.ndarray]:
    """Per patch the LS plane h = a + b x + c y through the points of the patch and its neighbours (M, 3) and
    whether the points determine it (M,)."""
    x, y = xy[:, 0], xy[:, 1]
    voxel = pat.voxel_of_point
    m = len(pat.mean_mm)
    moments = np.stack([np.bincount(voxel, weights=w, minlength=m)
                        for w in (np.ones_like(x), x, y, x * x, x * y, y * y, h, x * h, y * h)], axis=1)  # fmt: skip
    s = pat.neighbours.tocsr() @ moments
    normal = np.stack([s[:, [0, 1, 2]], s[:, [1, 3, 4]], s[:, [2, 4, 5]]], axis=1)
    ok = np.linalg.cond(normal) < 1e10
    coef = np.full((m, 3), np.nan)
    coef[ok] = np.linalg.solve(normal[ok], s[ok, 6:9][:, :, None])[:, :, 0]
    return coef, ok


def _local_linear(xy: np.ndarray, h: np.ndarray, pat) -> tuple[np.ndarray, np.ndarray]:
    """Positions (M, 2) and heights (M,) of the face filtered by local planes (:func:`_local_planes`, a local
    linear filter) evaluated at each patch's centroid and at the patch's points of smallest and largest x and y,
    so the filtered face reaches as far as the points do. A patch mean at the face's border averages one side only
    and reads a sloped face's height short there, a local plane does not. The patch mean at its centroid where
    the points do not determine a plane."""
    x, y = xy[:, 0], xy[:, 1]
    voxel = pat.voxel_of_point
    coef, ok = _local_planes(xy, h, pat)
    centre = pat.centre_mm[:, :2]
    heights = pat.mean_mm.copy()
    heights[ok] = coef[ok, 0] + coef[ok, 1] * centre[ok, 0] + coef[ok, 2] * centre[ok, 1]
    inside = voxel >= 0
    ends = []
    for key in (x, y):  # each patch's first and last point sorted by x, then by y
        order = np.flatnonzero(inside)[np.lexsort((key[inside], voxel[inside]))]
        starts = np.r_[True, voxel[order][1:] != voxel[order][:-1]]
        ends += [order[starts], order[np.r_[starts[1:], True]]]
    ends = np.unique(np.concatenate(ends))
    ends = ends[ok[voxel[ends]]]
    c = coef[voxel[ends]]
    return np.vstack([centre, xy[ends]]), np.concatenate([heights, c[:, 0] + c[:, 1] * x[ends] + c[:, 2] * y[ends]])


def _size(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    a, b = feature.faces
    pa, pb = (
        fit_plane(ctx.points[_face(ctx, a, feature.name)], ctx.face_planes[a][1]),
        fit_plane(ctx.points[_face(ctx, b, feature.name)], ctx.face_planes[b][1]),
    )
    n = pa.normal - pb.normal
    n /= np.linalg.norm(n)
    value = float((pa.centroid - pb.centroid) @ n)
    nominal, tol = feature.params["nominal_mm"], feature.params["tolerance_mm"]
    u = expanded(pa.offset_sigma_mm, pb.offset_sigma_mm, ctx.instrument.length_rel * nominal, ctx.instrument.size_mm)
    d = decide("size", value, nominal + tol, u, lower=nominal - tol)
    parallel = float(np.degrees(np.arccos(np.clip(-pa.normal @ pb.normal, -1, 1))))
    return FeatureResult(feature.name, "size", {"size_mm": value, "nominal_mm": nominal, "deviation_mm": value - nominal,
                         "parallelism_deg": parallel}, [d], pa.count + pb.count)  # fmt: skip


def _hole(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    p = feature.params
    axis, centre, radius = p["axis"], p["centre"], p["diameter_mm"] / 2
    face_point = ctx.face_planes[feature.faces[0]][0]
    u, v = plane_basis(axis)
    rel = ctx.points - centre
    height = (ctx.points - face_point) @ axis
    band = max(4.0 * float(np.median(ctx.sigma)), 0.3)
    radial = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
    wall = ctx.usable & (height < -band) & (np.abs(radial - radius) < 1.5)
    if wall.sum() >= MIN_WALL_POINTS and _arc_deg(ctx.points[wall] - centre, u, v) >= MIN_WALL_ARC_DEG:
        fit, method = fit_circle(ctx.points[wall], centre, axis), "wall"
        count = int(wall.sum())
        note = "centre and diameter from an LS circle through the hole wall's points (axis along the datum normal)"
    else:
        fit, count = _edge_ring(feature, ctx, centre, axis, radius, height, radial, band, u, v)
        method = "edge ring"
        note = (
            "centre and diameter from the innermost face point (upper half of the face's heights) in each of "
            f"{HOLE_EDGE_BINS} directions (edge ring): the centre is "
            "unbiased, the diameter reads about one point spacing large"
        )
    c = np.array([(fit.centre - centre) @ u, (fit.centre - centre) @ v])
    offset = np.linalg.norm(c)
    direction = c / offset if offset > 1e-9 else np.array([1.0, 0.0])
    u_fit = float(np.hypot(*(fit.centre_sigma_mm * direction)))
    d3 = direction[0] * u + direction[1] * v
    u_reg = float(ctx.registration_sigma(centre[None], d3[None])[0])
    position = 2.0 * offset
    u_scale = ctx.instrument.length_rel * float(np.linalg.norm(centre - ctx.registration_centre_mm))
    # the hole's view against the datums' (or the rest of the cloud's) views: their relative pose error; the
    # device's calibration error at the hole against that at the datum faces
    u_stitch = ctx.instrument.stitching_mm
    u_position = 2.0 * expanded(u_fit, u_reg, u_scale, u_stitch, ctx.instrument.centre_mm)
    decisions = [decide("position", position, p["position_tolerance_mm"], u_position)]
    diameter = 2.0 * fit.radius
    if "diameter_tolerance_mm" in p:
        tol = p["diameter_tolerance_mm"]
        decisions.append(decide("diameter", diameter, p["diameter_mm"] + tol, expanded(2 * fit.radius_sigma_mm),
                                lower=p["diameter_mm"] - tol))  # fmt: skip
    values = {"position_mm": position, "centre_offset_mm": (fit.centre - centre).tolist(), "diameter_mm": diameter,
              "nominal_diameter_mm": p["diameter_mm"], "method": method, "fit_points": fit.count}  # fmt: skip
    return FeatureResult(feature.name, "hole", values, decisions, count, [note])


def _arc_deg(rel: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """Angle (deg) the points cover around the axis: 10 deg per bin holding at least WALL_BIN_POINTS points."""
    angles = np.degrees(np.arctan2(rel @ v, rel @ u)) + 180.0
    counts = np.bincount(np.minimum((angles // 10.0).astype(int), 35), minlength=36)
    return float(10.0 * np.count_nonzero(counts >= WALL_BIN_POINTS))


def _edge_ring(feature, ctx, centre, axis, radius, height, radial, band, u, v):
    # the face's upper half only (heights above the median of the face around the hole): the wall's top, seen from
    # one side, lies at the edge's radius and would read the edge short there; pushed above the face's median by
    # the noise, only its topmost points remain
    face = ctx.usable & (np.abs(height) < band) & (radial > radius + 1.0) & (radial < radius + 3.0)
    level = float(np.median(height[face])) if face.any() else 0.0
    near = ctx.usable & (height > level) & (height < band) & (radial > radius - 1.5) & (radial < radius + 3.0)
    pts = ctx.points[near]
    if len(pts) < MIN_FEATURE_POINTS:
        raise InspectionInputError(f"feature {feature.name!r}: {len(pts)} measured points around the hole, too few")
    xy = np.stack([(pts - centre) @ u, (pts - centre) @ v], axis=1)
    c = np.zeros(2)
    fit = None
    for _ in range(4):
        d = xy - c
        angle = np.arctan2(d[:, 1], d[:, 0])
        r = np.hypot(d[:, 0], d[:, 1])
        bins = np.floor((angle + np.pi) / (2 * np.pi) * HOLE_EDGE_BINS).astype(int) % HOLE_EDGE_BINS
        order = np.lexsort((r, bins))
        first = order[np.r_[True, bins[order][1:] != bins[order][:-1]]]
        if len(first) < HOLE_EDGE_BINS // 2:
            raise InspectionInputError(f"feature {feature.name!r}: the hole's edge is seen in {len(first)} of "
                                       f"{HOLE_EDGE_BINS} directions only")  # fmt: skip
        fit = fit_circle(pts[first], centre, axis)
        c = np.array([(fit.centre - centre) @ u, (fit.centre - centre) @ v])
    return fit, len(pts)


def _plane(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    name = feature.faces[0]
    idx = _face(ctx, name, feature.name)
    point, normal = ctx.face_planes[name]
    plane = fit_plane(ctx.points[idx], normal)
    offset = float((plane.centroid - point) @ normal)
    angle = float(np.degrees(np.arccos(np.clip(plane.normal @ normal, -1, 1))))
    decisions = []
    if "tolerance_mm" in feature.params:
        u_reg = float(ctx.registration_sigma(plane.centroid[None], normal[None])[0])
        t = feature.params["tolerance_mm"]
        decisions.append(decide("location", offset, t, expanded(plane.offset_sigma_mm, u_reg), lower=-t))
    values = {"offset_mm": offset, "angle_deg": angle, "rms_mm": plane.rms_mm, "normal": plane.normal.tolist()}
    return FeatureResult(feature.name, "plane", values, decisions, len(idx))


def _sphere(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    p = feature.params
    band = max(1.0, 3 * p["tolerance_mm"])
    near = ctx.usable & (np.abs(np.linalg.norm(ctx.points - p["centre"], axis=1) - p["radius_mm"]) < band)
    if near.sum() < MIN_FEATURE_POINTS:
        raise InspectionInputError(f"feature {feature.name!r}: {int(near.sum())} points on the sphere, too few")
    fit = fit_sphere(ctx.points[near])
    t = p["tolerance_mm"]
    values = {"radius_mm": fit.radius, "centre_mm": fit.centre.tolist(), "rms_mm": fit.rms_mm,
              "centre_offset_mm": float(np.linalg.norm(fit.centre - p["centre"]))}  # fmt: skip
    d = decide("radius", fit.radius, p["radius_mm"] + t, expanded(fit.radius_sigma_mm), lower=p["radius_mm"] - t)
    return FeatureResult(feature.name, "sphere", values, [d], int(near.sum()))


def _cylinder(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    p = feature.params
    r0 = p["diameter_mm"] / 2
    rel = ctx.points - p["point"]
    radial = np.linalg.norm(rel - np.outer(rel @ p["axis"], p["axis"]), axis=1)
    near = ctx.usable & (np.abs(radial - r0) < max(1.0, 3 * p["tolerance_mm"]))
    if "length_mm" in p:
        near &= np.abs(rel @ p["axis"]) <= p["length_mm"] / 2
    if near.sum() < MIN_FEATURE_POINTS:
        raise InspectionInputError(f"feature {feature.name!r}: {int(near.sum())} points on the cylinder, too few")
    fit = fit_cylinder(ctx.points[near], p["point"], p["axis"], r0)
    t = p["tolerance_mm"]
    diameter = 2 * fit.radius
    values = {"diameter_mm": diameter, "axis": fit.axis.tolist(), "point_mm": fit.point.tolist(), "rms_mm": fit.rms_mm}
    d = decide(
        "diameter", diameter, p["diameter_mm"] + t, expanded(2 * fit.radius_sigma_mm), lower=p["diameter_mm"] - t
    )
    return FeatureResult(feature.name, "cylinder", values, [d], int(near.sum()))


_EVALUATORS = {"flatness": _flatness, "size": _size, "hole": _hole, "plane": _plane, "sphere": _sphere,
               "cylinder": _cylinder}  # fmt: skip


def evaluate_feature(feature: Feature, ctx: FeatureContext) -> FeatureResult:
    """The feature's result; a feature without enough measured points is reported as not evaluated."""
    try:
        return _EVALUATORS[feature.type](feature, ctx)
    except InspectionInputError as exc:
        return FeatureResult(feature.name, feature.type, {}, [], 0, [f"not evaluated: {exc}"])
