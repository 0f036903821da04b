"""Robot-registered multi-sweep length test of the laser line scanner (VDI/VDE 2634 Part 3-like, by agreement).

A dumbbell longer than the laser line (its spheres in different sweeps) lies at 7 poses in the UR10e's working
area. Each sphere is measured by its own straight sweep; the robot's joint states come from the nominal model's
IK (start and end of the sweep, interpolated in joint space). The profiles are cast from where the TRUE robot
(:class:`~agiprobot_measurement.motion.kinematics.TrueKinematics` with the calibration residual the error model
configures) with the true mount (hand-eye error) really holds the head, and reported through the nominal forward
kinematics read ``latency_s`` late (:func:`~agiprobot_measurement.sensors.laser_line.simulator.pose_chain_poses`).
The sphere-spacing error of the stitched cloud is the stitching residual the configured pose chain implies.
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel, TrueKinematics, load_kinematics_correction
from agiprobot_measurement.sensors.acceptance import AcceptanceSpec, evaluate_sphere
from agiprobot_measurement.sensors.error_models import ErrorModel, LaserErrors
from agiprobot_measurement.sensors.errors import SensorInputError, SensorStateError
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator, pose_chain_poses
from agiprobot_measurement.station import Station, load_scanner_config

__all__ = ["run_multi_sweep"]

#: joint state near which the IK picks its solutions (the calibration simulation's seed: arm over the table)
SEED_Q = np.array([0.0, -1.5707, 1.5707, -1.5707, -1.5707, 0.0])


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def run_multi_sweep(spec: AcceptanceSpec, error_model: ErrorModel, poses: int | None = None, seed: int = 0) -> dict:
    """Rows (one per dumbbell pose: SD of the stitched cloud) and a summary."""
    import trimesh

    settings = spec.settings
    test = spec.multi_sweep
    if not test:
        raise SensorInputError(f"scanner {spec.name}: no multi_sweep test configured")
    station = Station.load()
    kin = KinematicModel.from_station(station, tip_frame="tool0", base_frame="base")
    ik = make_ik_solver(kin, station.robot)
    _, arm, _ = load_kinematics_correction()
    config = load_scanner_config()
    sensor = SensorModel(config.sensor_parameters)
    errors = LaserErrors.create(sensor, error_model)
    chain = errors.pose_chain if errors is not None else None
    residual = chain["robot_residual_scale"] if chain else 0.0
    true_kin = TrueKinematics(kin, arm, residual) if residual > 0.0 else None
    sim = LaserLineScannerSimulator(
        sensor, points_per_profile=int(settings.get("points_per_profile", 640)), seed=seed, errors=errors
    )
    rng = np.random.default_rng(seed)
    mount = config.mount_pose.copy()
    mount[:3, 3] *= 1000.0
    start_flange = kin.fk(SEED_Q)
    start_flange[:3, 3] *= 1000.0
    start_emitter = start_flange @ mount
    standoff = float(test["standoff_mm"])
    length, diameter = float(test["dumbbell_length_mm"]), float(test["dumbbell_diameter_mm"])
    pitch = float(settings.get("pitch_mm", 0.2))
    tilt = float(test.get("tilt_deg", 0.0))
    speed = float(test["sweep_speed_mm_s"])
    art = spec.artefacts
    sphere = trimesh.creation.icosphere(subdivisions=art.subdivisions, radius=0.5 * diameter)
    # the emitter looks straight down at the table (its z = -z of the base), as over the part
    down = np.diag([1.0, -1.0, -1.0])
    base_point = start_emitter[:3, 3] + np.array([0.0, 0.0, -standoff])
    rows = []
    count = int(poses or test["poses"])
    offsets = [(0, 0, 0), (120, 0, 0), (-120, 0, 0), (0, 120, 0), (0, -120, 0), (80, 80, -40), (-80, -80, 40)]
    for i in range(count):
        angle = math.pi * i / count  # the bar turned about the vertical: 7 directions over 180 degrees
        rotation = _rot_z(angle)
        centre = base_point + np.asarray(offsets[i % len(offsets)], dtype=float)
        bar = rotation[:, 0]
        centres = [centre - 0.5 * length * bar, centre + 0.5 * length * bar]
        meshes = []
        for c in centres:
            m = sphere.copy()
            m.apply_translation(c)
            meshes.append(m)
        sim.set_target(trimesh.util.concatenate(meshes))
        clouds = []
        for k, c in enumerate(centres):
            # sweep across the sphere perpendicular to the bar, the line along the bar, each sphere seen from its
            # own side (the head tilted by +-tilt_deg about the sweep direction, as views around a part are)
            orient = rotation @ _rot_z(math.pi / 2) @ down @ _rot_x(math.radians(tilt if k else -tilt))
            xs = np.arange(-0.5 * diameter - 3.0, 0.5 * diameter + 3.0, pitch)
            emit = np.repeat(np.eye(4)[None], len(xs), axis=0)
            emit[:, :3, :3] = orient
            top = c - standoff * orient[:, 2]
            emit[:, :3, 3] = top + xs[:, None] * orient[:, 0]
            ends = np.stack([emit[0], emit[-1]]) @ np.linalg.inv(mount)
            ends[:, :3, 3] /= 1000.0
            q_ends, ok = ik.solve_nearest(ends, np.vstack([SEED_Q, SEED_Q]))
            if not np.all(ok):
                raise SensorStateError(f"multi-sweep pose {i}: no IK solution for a sweep end")
            share = np.linspace(0.0, 1.0, len(xs))[:, None]
            q = q_ends[0] * (1.0 - share) + q_ends[1] * share
            nominal = kin.fk(q)
            true = true_kin.fk(q) if true_kin is not None else nominal.copy()
            nominal[:, :3, 3] *= 1000.0
            true[:, :3, 3] *= 1000.0
            velocity = orient[:, 0] * speed
            true_emit, reported = pose_chain_poses(errors, true, nominal, mount, velocity, rng)
            profiles = sim.profiles(true_emit, reported)
            clouds.append(np.vstack([p.points_mm for p in profiles if len(p)]))
        fits = []
        for c, cloud in zip(centres, clouds, strict=True):
            near = np.abs(np.linalg.norm(cloud - c, axis=1) - 0.5 * diameter) < 3.0
            fits.append(evaluate_sphere(cloud[near], 0.0))
        distance = float(np.linalg.norm(fits[0]["centre"] - fits[1]["centre"]))
        rows.append({"artefact": "multi-sweep dumbbell", "position": i, "SD": distance - length,
                     "distance": distance, "PF_a": fits[0]["PF"], "PF_b": fits[1]["PF"]})  # fmt: skip
    sd = np.array([r["SD"] for r in rows])
    low, high = test["residual_range_mm"]
    summary = {"SD_maxabs": float(np.abs(sd).max()), "SD_rms": float(np.sqrt(np.mean(sd**2)))}
    checks = [{"name": "multi-sweep max |SD| (mm)", "value": summary["SD_maxabs"], "low": low, "high": high,
               "holds": bool(low <= summary["SD_maxabs"] <= high)}]  # fmt: skip
    return {"rows": rows, "summary": summary, "checks": checks}


def main(argv=None) -> int:
    """``python -m benchmarks.acceptance.multi_sweep [--residual-scales S ...]``: the multi-sweep SD against the share of
    the true robot's deviation left after kinematic calibration (the rest of the pose chain as configured)."""
    import argparse

    from agiprobot_measurement.sensors.acceptance import load_acceptance_specs
    from agiprobot_measurement.sensors.error_models import load_error_model

    parser = argparse.ArgumentParser(prog="python -m benchmarks.acceptance.multi_sweep", description=main.__doc__)
    parser.add_argument("--error-model", default="realistic")
    parser.add_argument("--residual-scales", type=float, nargs="*", default=None)
    parser.add_argument("--poses", type=int, default=None)
    args = parser.parse_args(argv)
    spec = load_acceptance_specs()["laser"]
    model = load_error_model(args.error_model)
    chain = model.laser.get("pose_chain")
    scales = args.residual_scales if args.residual_scales and chain else [None]
    print("| robot residual scale | max abs SD (mm) | RMS SD (mm) | SD per pose (mm) |")
    print("|---|---|---|---|")
    for scale in scales:
        varied = (
            model if scale is None else model.with_blocks("laser", pose_chain={**chain, "robot_residual_scale": scale})
        )
        result = run_multi_sweep(spec, varied, args.poses)
        per_pose = " ".join(f"{row['SD']:+.3f}" for row in result["rows"])
        label = "configured" if scale is None else f"{scale:g}"
        print(f"| {label} | {result['summary']['SD_maxabs']:.3f} | {result['summary']['SD_rms']:.3f} | {per_pose} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
