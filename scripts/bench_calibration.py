#!/usr/bin/env python3
"""Accuracy of the flange-based calibration against the hidden true camera pose, over seeds, without ROS.

Per seed: the scanner's pose is the configured one moved by up to +-5 cm and turned by up to +-3 deg (the truth,
kept from the calibration); the robot (bare flange disc) is posed by IK at the flag points and the zig-zag path,
each frame rendered by the ROS-free PhoXi simulation (structured_light.py, its noise model) and the flange
detected in it; coarse (flag points only) and fine calibration are compared with the truth. With --spoil 0.2 a
fifth of the zig-zag frames are spoiled (a plate occludes part of the flange and a decoy disc of the flange's
size sits beside it: a wrong cluster).

    scripts/bench_calibration.py                 # 20 seeds, clean and 20 % spoiled
    scripts/bench_calibration.py --seeds 3 --workers 4
"""

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def run_seed(args):
    seed, spoil_fraction = args
    from agiprobot_measurement.calibration import (
        CalibrationData,
        Sample,
        calibrate_data,
        pose_error,
        read_flag_points,
        transform_points,
        zigzag_path,
    )
    from agiprobot_measurement.calibration_sim import (
        SimulatedStation,
        load_calibration_config,
        nominal_camera_pose,
        perturbed_pose,
        tool_rotation,
    )
    from agiprobot_measurement.flange_detection import FlangeDetectorConfig, detect_flange
    from agiprobot_measurement.structured_light import SceneGeometry, primitive_mesh

    rng = np.random.default_rng(1000 + seed)
    sim = SimulatedStation(perturbed_pose(nominal_camera_pose(), rng, 0.05, np.radians(3.0)), noise_seed=seed)
    sim.scanner.workers = 1
    cfg = load_calibration_config()
    flange = FlangeDetectorConfig(radius_m=cfg["flange"]["radius_m"], seed=seed)
    flags = read_flag_points(cfg["flag_points_file"])
    data = CalibrationData()
    rejected = 0
    for i, p in enumerate(flags):
        q = sim.joints_for(p, tool_rotation(cfg["tool_z_towards_m"], p))
        det = detect_flange(sim.capture(q, i).points_m(), flange)
        if not det.ok:
            return seed, None, f"flag point {i}: {det.reason}"
        data.samples.append(Sample(f"{seed}_{i:06d}", p, det.centre_m, True))
        data.criteria_plane = min(data.criteria_plane or det.plane_points, det.plane_points)
        data.criteria_line = min(data.criteria_line or det.circle_inliers, det.circle_inliers)
    coarse = calibrate_data(data, "cal_coarse")
    h_coarse_inv = np.linalg.inv(coarse.transform)
    zz = cfg["zigzag"]
    path = zigzag_path(flags, seed=seed, jitter_m=zz["jitter_m"], fractions=tuple(zz["fractions"]))
    spoiled = set(rng.choice(len(path), round(spoil_fraction * len(path)), replace=False).tolist())
    acc = cfg["acceptance"]
    for k, p in enumerate(path):
        rotation = tool_rotation(cfg["tool_z_towards_m"], p)
        q = sim.joints_for(p, rotation)
        if q is None:
            rejected += 1
            continue
        extra = None
        if k in spoiled:  # decoy disc 8 cm beside the flange, plate over a third of the flange, 2 cm in front
            world = sim.world_from_base
            decoy = np.eye(4)
            decoy[:3, :3] = rotation
            decoy[:3, 3] = p + rotation[:, 0] * 0.08
            plate = decoy.copy()
            plate[:3, 3] = p + rotation[:, 0] * 0.04 + rotation[:, 2] * 0.02
            extra = SceneGeometry.concatenate(
                [
                    SceneGeometry.from_trimesh(
                        primitive_mesh("cylinder", radius=0.0315, length=0.004), "d", 0.6
                    ).transformed(world @ decoy),
                    SceneGeometry.from_trimesh(primitive_mesh("box", size=(0.05, 0.08, 0.002)), "p", 0.6).transformed(
                        world @ plate
                    ),
                ]
            )
        expected = transform_points(h_coarse_inv, p[None])[0]
        det = detect_flange(sim.capture(q, 100 + k, extra).points_m(), flange, expected)
        if (
            not det.ok
            or det.plane_points < acc["plane_fraction"] * data.criteria_plane
            or det.circle_inliers < acc["circle_fraction"] * data.criteria_line
        ):
            rejected += 1
            continue
        data.samples.append(Sample(f"{seed}_{100 + k:06d}", p, det.centre_m))
    fine = calibrate_data(data, "cal_fine")
    truth = sim.camera_in_base
    return (
        seed,
        {
            "coarse": pose_error(coarse.transform, truth),
            "fine": pose_error(fine.transform, truth),
            "samples": len(data.samples),
            "rejected_frames": rejected,
            "outliers": len(fine.rejected),
            "rms_mm": fine.rms_mm,
        },
        "",
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--spoil", type=float, nargs="+", default=[0.0, 0.2], help="fractions of spoiled frames")
    parser.add_argument("--workers", type=int, default=4)
    args = parser.parse_args(argv)
    print(
        f"{'spoiled':>7} {'seed':>4} {'coarse_t_mm':>11} {'coarse_r_deg':>12} {'fine_t_mm':>9} {'fine_r_deg':>10} "
        f"{'samples':>7} {'rej_frames':>10} {'outliers':>8} {'rms_mm':>7}"
    )
    summary = []
    with ProcessPoolExecutor(args.workers) as pool:
        for spoil in args.spoil:
            rows = []
            for seed, row, error in pool.map(run_seed, [(s, spoil) for s in range(args.seeds)]):
                if row is None:
                    print(f"{spoil:7.0%} {seed:4d} failed: {error}")
                    continue
                rows.append(row)
                print(
                    f"{spoil:7.0%} {seed:4d} {row['coarse'][0]:11.3f} {row['coarse'][1]:12.4f} {row['fine'][0]:9.3f} "
                    f"{row['fine'][1]:10.4f} {row['samples']:7d} {row['rejected_frames']:10d} {row['outliers']:8d} "
                    f"{row['rms_mm']:7.3f}",
                    flush=True,
                )
            summary.append((spoil, rows))
    print("\nsummary over seeds (max / mean): translation error mm, rotation error deg")
    print(f"{'spoiled':>7} {'runs':>4} {'coarse t':>15} {'coarse r':>15} {'fine t':>15} {'fine r':>15}")
    for spoil, rows in summary:
        if not rows:
            continue
        cols = [np.array([r[k][j] for r in rows]) for k in ("coarse", "fine") for j in (0, 1)]
        cells = " ".join(f"{c.max():7.3f}/{c.mean():7.3f}" for c in cols)
        print(f"{spoil:7.0%} {len(rows):4d} {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
