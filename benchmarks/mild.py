"""The MILD robot model: exact and approximated inverse kinematics, solves/s and success rate.

Usage (after ``source tools/env.sh``, from the checkout's root)::

    python -m benchmarks.mild                      # real robot's settings, 2000 poses
    python -m benchmarks.mild --settings config/mild_robot_model_services_sim.yaml --poses 5000

Requested camera poses are reachable by construction: the camera poses of random robot states within the PTU limits
whose base stands on an allowed cell of the map. An exact IK solve succeeds when it returns a state whose camera faces
the requested view centre from the viewing distance with less than 0.5 deg deviation; an approximated solve when its
pan + rotation equals the requested azimuth and its tilt the requested elevation (1e-6 rad). Single-call rates are
what a service request costs (the node's path); batch rates are one vectorised call for all poses.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.mild.config import load_settings
from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState, view_directions
from benchmarks.harness import load_conditions

DEFAULTS = load_conditions("mild").mapping("defaults")


def reachable_poses(model: MildRobotModel, count: int, rng: np.random.Generator):
    lo, hi = model.pan_limits
    tlo, thi = model.tilt_limits
    chunks, found = [], 0
    while found < count:
        xy = rng.uniform([-0.5, -0.5], [10.5, 7.5], (count, 2))
        xy = xy[model.map.is_allowed(xy, model.settings.col_thresh)]
        n = len(xy)
        chunks.append(
            np.column_stack([rng.uniform(lo, hi, n), rng.uniform(tlo, thi, n), rng.uniform(0, 2 * np.pi, n), xy])
        )
        found += n
    states = np.vstack(chunks)[:count]
    poses = model.camera_poses(states)
    return states, poses[:, :3, 3], Rotation.from_matrix(poses[:, :3, :3]).as_quat()


def exact_success(model, batch_states, ok, positions, quaternions) -> np.ndarray:
    d = model.settings.view_distance_m
    views = view_directions(quaternions)
    success = ok.copy()
    achieved = model.camera_poses(np.nan_to_num(batch_states))
    centre_error = np.linalg.norm(achieved[:, :3, 3] + d * achieved[:, :3, 0] - (positions + d * views), axis=1)
    deviation = np.degrees(np.arccos(np.clip(np.sum(achieved[:, :3, 0] * views, axis=1), -1, 1)))
    return success & (centre_error < 1e-6) & (deviation < 0.5)


def approximated_success(states, quaternions) -> np.ndarray:
    views = view_directions(quaternions)
    azimuth = np.arctan2(views[:, 1], views[:, 0])
    elevation = np.arcsin(np.clip(views[:, 2], -1, 1))
    return (np.abs(wrap_to_pi(states[:, 0] + states[:, 2] - azimuth)) < 1e-6) & (
        np.abs(states[:, 1] - elevation) < 1e-6
    )


def single_calls(model, source, positions, quaternions):
    start = time.perf_counter()
    solutions = [model.calculate_robot_state(source, p, q) for p, q in zip(positions, quaternions, strict=True)]
    seconds = time.perf_counter() - start
    states = np.array([s.state.as_array() if s.ok else np.full(5, np.nan) for s in solutions])
    return len(positions) / seconds, states, np.array([s.ok for s in solutions])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--settings", default=None, help="settings YAML (default: the real robot's)")
    parser.add_argument("--poses", type=int, default=DEFAULTS["poses"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    settings = load_settings(args.settings)
    model = MildRobotModel.load(settings)
    rng = np.random.default_rng(args.seed)
    _, positions, quaternions = reachable_poses(model, args.poses, rng)
    source = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    print(
        f"settings: {args.settings or 'config/mild_robot_model_services_real.yaml'}; {args.poses} reachable camera poses"
    )
    print(
        f"pan [{math.degrees(model.pan_limits[0]):.0f}, {math.degrees(model.pan_limits[1]):.0f}] deg, "
        f"{settings.pan_sampling_steps} pan samples per iteration, accuracy {settings.ik_iteration_accuracy}"
    )
    model.calculate_robot_state(source, positions[0], quaternions[0])  # warm-up (lazy imports)

    rows = []
    for rating in ("SIMPLE", "ANGLE_APPROXIMATION", "NAVIGATION_PATH"):
        rated = MildRobotModel(model.kinematics, settings.with_changes(ik_angle_rating=rating), model.map)
        count = args.poses if rating != "NAVIGATION_PATH" else min(args.poses, 200)
        rate, states, ok = single_calls(rated, source, positions[:count], quaternions[:count])
        success = exact_success(rated, states, ok, positions[:count], quaternions[:count]).mean()
        rows.append((f"exact IK, {rating}, single calls", rate, success, count))
        if rating != "NAVIGATION_PATH":
            start = time.perf_counter()
            batch = rated.exact_ik_batch(source, positions, quaternions)
            rate = args.poses / (time.perf_counter() - start)
            success = exact_success(rated, batch.states, batch.ok, positions, quaternions).mean()
            rows.append((f"exact IK, {rating}, one batch", rate, success, args.poses))

    for solver in ("glpk", "highs"):
        approximated = MildRobotModel(
            model.kinematics, settings.with_changes(robot_model_id=2, lp_solver=solver), model.map
        )
        approximated.calculate_robot_state(source, positions[0], quaternions[0])
        rate, states, _ = single_calls(approximated, source, positions, quaternions)
        rows.append(
            (
                f"approximated IK, LP by {solver}, single calls",
                rate,
                approximated_success(states, quaternions).mean(),
                args.poses,
            )
        )
    start = time.perf_counter()
    batch = approximated.approximated_ik_batch(source, positions, quaternions)
    rate = args.poses / (time.perf_counter() - start)
    rows.append(
        (
            "approximated IK, closed-form LP, one batch",
            rate,
            approximated_success(batch.states, quaternions).mean(),
            args.poses,
        )
    )

    print(f"{'':48s} {'solves/s':>12s} {'success':>9s} {'poses':>7s}")
    for name, rate, success, count in rows:
        print(f"{name:48s} {rate:12,.0f} {100 * success:8.1f}% {count:7d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
