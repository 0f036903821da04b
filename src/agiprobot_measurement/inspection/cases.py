"""Test cases with analytic truth: an actual part, its simulated scan and the spec to inspect it with.

``build_case(case, magnitude, seed, sensor)`` returns a :class:`Case`: the nominal CAD, the planned placement, the
measured cloud (world, mm) with its noise sigma, the spec and the truth. The part is placed with a placement error
of 2 mm / 1 deg (random direction, seeded); defect positions are seeded too. Sensors: ``phoxi`` (PhoXi S, high
resolution), ``phoxi_low`` (low resolution, for quick tests) and ``laser`` (laser line sweeps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.inspection import actual, simulate
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.spec import InspectionSpec, load_spec
from agiprobot_measurement.sensors.error_models import ErrorModel

__all__ = ["CASES", "SENSORS", "Case", "build_case", "device_serial", "spec_path"]

CASES = ("null", "dent", "hole", "warp", "scale")
SENSORS = ("phoxi", "phoxi_low", "laser")
#: placement error of every case: translation (mm) and rotation (deg)
PLACEMENT_ERROR = (2.0, 1.0)
#: where the parts stand in the world (mm): the planned placement is a translation to here
PART_ORIGIN_MM = np.array([600.0, 0.0, 100.0])


@dataclass
class Case:
    name: str
    magnitude: float
    seed: int
    sensor: str
    error_model: str | None
    part: actual.ActualPart
    points_mm: np.ndarray
    sigma_mm: np.ndarray
    spec: InspectionSpec

    @property
    def nominal(self) -> trimesh.Trimesh:
        return self.part.nominal

    @property
    def truth(self) -> dict:
        return self.part.truth


def spec_path(name: str):
    return CONFIG_DIR / "inspection" / f"{name}.yaml"


def _part(case: str, magnitude: float, rng: np.random.Generator, dent_centre=None) -> tuple[actual.ActualPart, str]:
    if case in ("null", "dent"):
        centre = np.r_[rng.uniform(-30.0, 30.0, 2), 50.0] if dent_centre is None else dent_centre
        return actual.dented(
            actual.cube(), centre, (0, 0, 1), magnitude if case == "dent" else 0.0, DENT_RADIUS_MM
        ), "cube_100"
    if case == "hole":
        angle = rng.uniform(0, 2 * np.pi)
        return actual.holed_plate(magnitude * np.array([np.cos(angle), np.sin(angle)])), "plate_hole"
    if case == "warp":
        return actual.warped(bow_mm=magnitude), "plate_warp"
    if case == "scale":
        return actual.scaled(actual.cube(), magnitude), "cube_100"
    raise InspectionInputError(f"unknown case {case!r} (known: {list(CASES)})")


#: view directions (part -> sensor) per case: enough faces for a determined fit and for the case's features
_VIEWS = {
    "null": [(1, 1, 1.5), (-1, -1, 1.5)],
    "dent": [(1, 1, 1.5)],
    "hole": [(-1, -1, 1.5), (1, 1, 1.5)],
    "warp": [(0.2, 0.1, 1.0)],
    "scale": [(1, 1, 1.5), (-1, -1, 1.5)],
}


_TOP, _PX, _NX, _PY, _NY = (0.15, 0.1, 1.0), (1.0, 0.1, 0.3), (-1.0, -0.1, 0.3), (0.1, 1.0, 0.3), (-0.1, -1.0, 0.3)
#: laser sweeps per case, (view direction, sweep direction): the laser sees faces within about 45 deg of its
#: boresight, so each face group gets its own sweep
_LASER_SWEEPS = {
    "null": [(_TOP, (1, 0, 0)), (_PX, (0, 1, 0)), (_NX, (0, 1, 0)), (_PY, (1, 0, 0)), (_NY, (1, 0, 0))],
    "dent": [(_TOP, (1, 0, 0)), (_PX, (0, 1, 0)), (_PY, (1, 0, 0))],
    "hole": [((0.4, 0.4, 1.0), (1, -1, 0)), ((-0.4, -0.4, 1.0), (1, -1, 0)), (_NX, (0, 1, 0)), (_NY, (1, 0, 0))],
    "warp": [((0.1, 0.15, 1.0), (1, 0, 0))],
    "scale": [(_TOP, (1, 0, 0)), (_PX, (0, 1, 0)), (_NX, (0, 1, 0)), (_PY, (1, 0, 0)), (_NY, (1, 0, 0))],
}
#: laser sweep step between profiles (mm); the coarser step of the noise-free prescan that places the dent
LASER_STEP_MM = 0.2
PRESCAN_STEP_MM = 1.0
#: the dent (radius, mm) and the measured margin around it; a 1 mm grid cell is covered when a prescan point lies
#: within DENT_COVER_RADIUS_MM of it
DENT_RADIUS_MM = 5.0
DENT_MARGIN_MM = 2.0
DENT_COVER_RADIUS_MM = 1.0


def _scan(mesh_world, origin, case: str, sensor: str, seed: int, error_model, prescan=False,
          noise=True) -> simulate.ScannedCloud:  # fmt: skip
    """The case's scan; ``prescan``: noise-free and coarse (PhoXi low resolution, laser at PRESCAN_STEP_MM);
    ``noise`` False: without the random noise (the error model's systematic errors stay)."""
    views = _VIEWS[case]
    noise = noise and not prescan
    if sensor in ("phoxi", "phoxi_low"):
        return simulate.scan_phoxi(mesh_world, views, origin, "S", sensor == "phoxi" and not prescan, seed,
                                   noise, error_model, device_serial(seed))  # fmt: skip
    if sensor != "laser":
        raise InspectionInputError(f"unknown sensor {sensor!r} (known: {list(SENSORS)})")
    clouds = []
    for k, (view, sweep) in enumerate(_LASER_SWEEPS[case]):
        v = np.asarray(view, float)
        unit = v / np.linalg.norm(v)
        length = 1.2 * float(np.max(mesh_world.extents))
        # the visible half of the part (depth 0 .. nearest point along the view) centred in the standoff range
        depth = (np.asarray(mesh_world.vertices) - origin) @ unit
        offset = 0.5 * depth.max() * unit
        step = PRESCAN_STEP_MM if prescan else LASER_STEP_MM
        clouds.append(simulate.scan_laser(mesh_world, v, sweep, length, origin, step, seed + 1000 * k, float(noise),
                                          offset, error_model, device_serial(seed)))  # fmt: skip
    return simulate.ScannedCloud(np.vstack([c.points_mm for c in clouds]), np.concatenate([c.sigma_mm for c in clouds]),
                                 "laser_line")  # fmt: skip


def device_serial(seed: int) -> str:
    """The simulated scanner of a run, PhoXi or laser head: each seed scans with another device (its own
    per-device errors: calibration, fixed pattern, speckle, hand-eye), so the seeds sample the error model's
    spread of devices, not one draw."""
    return f"inspection-sim-{int(seed):04d}"


def _measured_dent_centre(planned, error, sensor: str, seed: int, rng: np.random.Generator) -> np.ndarray:
    """A dent centre (CAD, mm) drawn uniformly from the top face's points whose whole disc of the dent's radius
    plus ``DENT_MARGIN_MM`` the case's scan covers: a noise-free, ideal prescan of the undented part as placed
    (PhoXi at low resolution, laser sweeps at a coarse step) marks the covered cells of a 1 mm grid of the face."""
    part = actual.cube()
    placed = part.copy()
    placed.apply_transform(planned @ error)
    cloud = _scan(placed, PART_ORIGIN_MM, "dent", sensor, seed, None, prescan=True)
    cad = np.linalg.inv(planned @ error)
    points = cloud.points_mm @ cad[:3, :3].T + cad[:3, 3]
    top = points[np.abs(points[:, 2] - 50.0) < 0.5][:, :2]
    grid = np.stack(np.meshgrid(*(np.arange(-49.5, 50.0, 1.0),) * 2, indexing="ij"), axis=-1).reshape(-1, 2)
    covered = np.isfinite(cKDTree(top).query(grid, distance_upper_bound=DENT_COVER_RADIUS_MM)[0]) if len(top) else \
        np.zeros(len(grid), bool)  # fmt: skip
    reach = DENT_RADIUS_MM + DENT_MARGIN_MM
    gaps = grid[~covered]
    far_from_gaps = np.isinf(cKDTree(gaps).query(grid, distance_upper_bound=reach)[0]) if len(gaps) else \
        np.ones(len(grid), bool)  # fmt: skip
    inside = covered & far_from_gaps & np.all(np.abs(grid) <= 50.0 - reach, axis=1)
    if not inside.any():
        raise InspectionInputError(f"the {sensor} scan of the dent case covers no disc of {reach} mm on the top face")
    centre = grid[rng.choice(np.flatnonzero(inside))] + rng.uniform(-0.5, 0.5, 2)
    return np.r_[centre, 50.0]


def build_case(case: str, magnitude: float = 0.0, seed: int = 0, sensor: str = "phoxi",
               error_model: str | ErrorModel | None = "ideal", noise: bool = True) -> Case:  # fmt: skip
    """The case's actual part placed with the placement error, scanned with the named error model (``ideal``:
    noise only; ``realistic``: docs/sensor-errors.md; or an :class:`ErrorModel`); the inspection sees nominal +
    cloud. The dent is drawn where the case's scan measures the whole dent (:func:`_measured_dent_centre`): a miss
    is a detection miss. ``noise`` False scans without the random noise (the per-device systematic errors only)."""
    rng = np.random.default_rng(seed)
    planned = np.eye(4)
    planned[:3, 3] = PART_ORIGIN_MM
    if case == "dent":
        error = actual.placement_error(rng, *PLACEMENT_ERROR)
        part, spec_name = _part(case, magnitude, rng, _measured_dent_centre(planned, error, sensor, seed, rng))
    else:
        part, spec_name = _part(case, magnitude, rng)
        error = actual.placement_error(rng, *PLACEMENT_ERROR)
    part = part.with_placement(planned, error)
    cloud = _scan(part.placed_actual(), PART_ORIGIN_MM, case, sensor, seed, error_model, noise=noise)
    name = error_model.name if isinstance(error_model, ErrorModel) else error_model
    return Case(case, float(magnitude), int(seed), sensor, name, part, cloud.points_mm, cloud.sigma_mm,
                load_spec(spec_path(spec_name)))  # fmt: skip
