"""Least-squares geometric elements and minimum-zone flatness (mm).

Plane (SVD), circle in a plane (algebraic start, then geometric Gauss-Newton), sphere (same), cylinder with a
free axis (Gauss-Newton from a nominal axis); each returns its parameters, the residual RMS and the parameters'
1-sigma uncertainties from the fit (residual variance times the inverse normal matrix). Minimum-zone flatness is
the narrowest pair of parallel planes around the points (a linear programme in the plane's slopes, HiGHS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, linprog

from agiprobot_measurement.inspection.errors import InspectionInputError, InspectionInternalError

__all__ = [
    "CircleFit",
    "CylinderFit",
    "PlaneFit",
    "SphereFit",
    "fit_circle",
    "fit_cylinder",
    "fit_plane",
    "fit_sphere",
    "min_zone_flatness",
    "plane_basis",
]


def _need(points: np.ndarray, count: int, what: str) -> np.ndarray:
    points = np.asarray(points, float)
    if len(points) < count:
        raise InspectionInputError(f"{what}: {len(points)} points, a fit needs at least {count}")
    return points


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane perpendicular to ``normal``."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


@dataclass
class PlaneFit:
    centroid: np.ndarray
    normal: np.ndarray
    rms_mm: float
    offset_sigma_mm: float
    count: int

    def heights(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, float) - self.centroid) @ self.normal


def fit_plane(points, normal_hint=None) -> PlaneFit:
    """LS plane; the normal turned towards ``normal_hint`` when given."""
    points = _need(points, 3, "plane")
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid, full_matrices=False)[2][-1]
    if normal_hint is not None and normal @ np.asarray(normal_hint, float) < 0:
        normal = -normal
    h = (points - centroid) @ normal
    rms = float(np.sqrt(np.mean(h**2)))
    return PlaneFit(centroid, normal, rms, rms / np.sqrt(len(points)), len(points))


@dataclass
class CircleFit:
    """Centre (3D, in the plane), radius, residual RMS and 1-sigma of centre (in-plane, 2) and radius (mm)."""

    centre: np.ndarray
    radius: float
    rms_mm: float
    centre_sigma_mm: np.ndarray
    radius_sigma_mm: float
    count: int


def _gauss_newton(residual, jacobian, x0, iterations=30):
    x = np.asarray(x0, float)
    for _ in range(iterations):
        r, jac = residual(x), jacobian(x)
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        x = x + step
        if np.linalg.norm(step) < 1e-12:
            break
    r, jac = residual(x), jacobian(x)
    dof = max(len(r) - len(x), 1)
    variance = float(r @ r) / dof
    try:
        covariance = variance * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError as exc:
        raise InspectionInternalError("a geometric fit is singular (points on too small an arc?)") from exc
    return x, np.sqrt(variance), covariance


def fit_circle(points, origin, normal) -> CircleFit:
    """LS circle of points projected into the plane through ``origin`` with ``normal``."""
    points = _need(points, 3, "circle")
    origin, normal = np.asarray(origin, float), np.asarray(normal, float) / np.linalg.norm(normal)
    u, v = plane_basis(normal)
    xy = np.stack([(points - origin) @ u, (points - origin) @ v], axis=1)
    a = np.c_[2 * xy, np.ones(len(xy))]
    sol = np.linalg.lstsq(a, (xy**2).sum(axis=1), rcond=None)[0]
    x0 = [sol[0], sol[1], np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1e-12))]

    def residual(x):
        return np.hypot(xy[:, 0] - x[0], xy[:, 1] - x[1]) - x[2]

    def jacobian(x):
        d = np.maximum(np.hypot(xy[:, 0] - x[0], xy[:, 1] - x[1]), 1e-12)
        return np.stack([-(xy[:, 0] - x[0]) / d, -(xy[:, 1] - x[1]) / d, -np.ones(len(xy))], axis=1)

    x, rms, cov = _gauss_newton(residual, jacobian, x0)
    sig = np.sqrt(np.diag(cov))
    return CircleFit(origin + x[0] * u + x[1] * v, float(x[2]), float(rms), sig[:2], float(sig[2]), len(points))


class SphereFit(CircleFit):
    """Centre (3D), radius, residual RMS and 1-sigma of the centre (3) and the radius (mm)."""


def fit_sphere(points) -> SphereFit:
    points = _need(points, 4, "sphere")
    a = np.c_[2 * points, np.ones(len(points))]
    sol = np.linalg.lstsq(a, (points**2).sum(axis=1), rcond=None)[0]
    x0 = [*sol[:3], np.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-12))]

    def residual(x):
        return np.linalg.norm(points - x[:3], axis=1) - x[3]

    def jacobian(x):
        d = points - x[:3]
        n = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        return np.c_[-d / n[:, None], -np.ones(len(points))]

    x, rms, cov = _gauss_newton(residual, jacobian, x0)
    sig = np.sqrt(np.diag(cov))
    return SphereFit(x[:3], float(x[3]), float(rms), sig[:3], float(sig[3]), len(points))


@dataclass
class CylinderFit:
    point: np.ndarray
    axis: np.ndarray
    radius: float
    rms_mm: float
    point_sigma_mm: np.ndarray
    radius_sigma_mm: float
    count: int


def fit_cylinder(points, point0, axis0, radius0) -> CylinderFit:
    """LS cylinder from a nominal axis (point, direction) and radius; the axis point stays in the plane
    perpendicular to ``axis0`` through ``point0``."""
    points = _need(points, 5, "cylinder")
    p0, a0 = np.asarray(point0, float), np.asarray(axis0, float) / np.linalg.norm(axis0)
    u, v = plane_basis(a0)

    def unpack(x):
        axis = a0 + x[2] * u + x[3] * v
        return p0 + x[0] * u + x[1] * v, axis / np.linalg.norm(axis), x[4]

    def residual(x):
        p, axis, r = unpack(x)
        d = points - p
        return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1) - r

    result = least_squares(residual, [0.0, 0.0, 0.0, 0.0, float(radius0)], method="lm")
    p, axis, r = unpack(result.x)
    res = residual(result.x)
    dof = max(len(res) - 5, 1)
    variance = float(res @ res) / dof
    cov = variance * np.linalg.pinv(result.jac.T @ result.jac)
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return CylinderFit(p, axis, float(r), float(np.sqrt(variance)), sig[:2], float(sig[4]), len(points))


#: minimum zone: points this far (mm) outside the zone count as inside (the LP solver's feasibility tolerance)
MIN_ZONE_TOLERANCE_MM = 1e-7


def min_zone_flatness(points, normal) -> float:
    """Width (mm) of the narrowest pair of parallel planes containing ``points``, near-perpendicular to ``normal``.

    Minimises ``w`` subject to ``0 <= h_i - (a x_i + b y_i + c) <= w`` (x, y, h in the plane's frame)."""
    points = _need(points, 3, "flatness")
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    u, v = plane_basis(normal)
    centred = points - points.mean(axis=0)
    x, y, h = centred @ u, centred @ v, centred @ normal
    scale = max(float(np.abs(np.c_[x, y]).max()), 1.0)
    x, y = x / scale, y / scale
    # constraint generation: the zone is set by a few extreme points; start from the LS extremes, add violators
    k = min(len(h), 400)
    active = np.unique(np.concatenate([np.argsort(h)[:k], np.argsort(h)[-k:]]))
    for _ in range(50):
        a, b, c, w = _zone(x[active], y[active], h[active])
        r = h - (a * x + b * y + c)
        violation = np.maximum(r - w, -r)
        worst = np.argsort(violation)[-k:]
        worst = worst[violation[worst] > MIN_ZONE_TOLERANCE_MM]
        if not len(worst):
            return float(w)
        if np.isin(worst, active).all():  # only the LP's own tolerance left: the zone widened to hold every point
            return float(w + 2.0 * violation.max())
        active = np.union1d(active, worst)
    raise InspectionInternalError("minimum-zone flatness: the constraint generation did not converge")


def _zone(x: np.ndarray, y: np.ndarray, h: np.ndarray) -> tuple[float, float, float, float]:
    n = len(h)
    ones = np.ones(n)
    # variables a, b, c, w; rows: h - (a x + b y + c) <= w  and  -(h - (a x + b y + c)) <= 0
    upper = np.c_[-x, -y, -ones, -ones]
    lower = np.c_[x, y, ones, np.zeros(n)]
    result = linprog(
        c=[0, 0, 0, 1],
        A_ub=np.vstack([upper, lower]),
        b_ub=np.concatenate([-h, h]),
        bounds=[(None, None)] * 3 + [(0, None)],
        method="highs",
    )
    if result.status != 0:
        raise InspectionInternalError(f"minimum-zone flatness: the linear programme failed ({result.message})")
    return tuple(float(v) for v in result.x)
