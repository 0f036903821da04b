#!/usr/bin/env python3
"""Accuracy of the flange-based calibration against the hidden true camera pose, over seeds, without ROS.

Per seed: the scanner's pose is the configured one moved by up to +-5 cm and turned by up to +-3 deg (the truth,
kept from the calibration); the robot (bare flange disc) is posed by IK at the flag points and the zig-zag path,
each frame rendered by the ROS-free PhoXi simulation (structured_light.py, its noise model) and the flange
detected in it. Flag points: up to 3 disc candidates per frame, the combination whose distances agree with the
robot's (select_consistent_flags); coarse = flag points only. Fine = flag points + zig-zag path, once with clean
frames and once with a fraction of the path frames spoiled (a plate occludes part of the flange and a decoy disc
of the flange's size sits 8 cm beside it: a wrong cluster); the clean frames are shared by both runs.

    scripts/bench_calibration.py                          # 20 seeds, 20 % spoiled, 2 workers
    scripts/bench_calibration.py --seeds 3 --workers 4 --fractions 0.5

The station is that of launch/calibration.launch (config/calibration_scene.yaml: the chessboard lies on the table in
every frame). Test mode (--no-chessboard skips it): the chessboard's 8 x 11 inner corners found in the texture image
(OpenCV) with the robot out of view, taken to 3D through the organised cloud and transformed with the fine
calibration; the positioning error per corner against the true corners (the simulated robot reaches any target
exactly, so this is the error of moving the tip to the corner).

Prints one row per seed (translation error mm, rotation error deg, test-mode max / RMS over the corners in mm) and
the mean / max over the seeds.
"""

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def _spoiler(sim, p, rotation):
    """Decoy disc 8 cm beside the flange and a plate over a third of the flange, 2 cm in front (world frame)."""
    from agiprobot_measurement.sensors.phoxi.renderer import SceneGeometry, primitive_mesh

    world = sim.world_from_base
    decoy = np.eye(4)
    decoy[:3, :3] = rotation
    decoy[:3, 3] = p + rotation[:, 0] * 0.08
    plate = decoy.copy()
    plate[:3, 3] = p + rotation[:, 0] * 0.04 + rotation[:, 2] * 0.02
    return SceneGeometry.concatenate(
        [
            SceneGeometry.from_trimesh(primitive_mesh("cylinder", radius=0.0315, length=0.004), "d", 0.6).transformed(
                world @ decoy
            ),
            SceneGeometry.from_trimesh(primitive_mesh("box", size=(0.05, 0.08, 0.002)), "p", 0.6).transformed(
                world @ plate
            ),
        ]
    )


def chessboard_test(sim, h_base_camera, cfg):
    """Test mode: the chessboard of config/calibration_scene.yaml (on the table, 1.6 m from the camera) seen with the
    robot out of view, its corners found in the texture, taken to 3D and transformed with the calibration; the
    positioning error per corner (mm) against the true corners."""
    from agiprobot_measurement.calibration.chessboard_test import (
        corner_points,
        detect_corners,
        positioning_errors_mm,
        scene_chessboard_corners,
        scene_chessboards,
    )
    from agiprobot_measurement.common.geometry import transform_points

    (board,) = scene_chessboards(sim.station.scene)
    frame = sim.capture(sim.station.named_states["up"], 999)
    points = corner_points(frame.points_m(), detect_corners(frame.texture, board.inner_corners))
    truth = transform_points(np.linalg.inv(sim.world_from_base), scene_chessboard_corners(board))
    return positioning_errors_mm(h_base_camera, points, truth)


def run_seed(args):
    seed, spoil_fraction, fractions, chessboard = args
    from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
    from agiprobot_measurement.calibration.flange_detection import detect_flange, detect_flange_candidates
    from agiprobot_measurement.calibration.registration import (
        CalibrationError,
        pose_error,
        read_flag_points,
        zigzag_path,
    )
    from agiprobot_measurement.calibration.session import CalibrationSession, detector_config
    from agiprobot_measurement.calibration.simulation import SimulatedStation, nominal_camera_pose, perturbed_pose
    from agiprobot_measurement.station import CONFIG_DIR

    started = time.monotonic()
    rng = np.random.default_rng(1000 + seed)
    sim = SimulatedStation(
        perturbed_pose(nominal_camera_pose(), rng, 0.05, np.radians(3.0)),
        noise_seed=seed,
        scene_path=CONFIG_DIR / "calibration_scene.yaml",
    )
    sim.scanner.workers = 1
    cfg = load_calibration_config()
    detector = detector_config(cfg)
    detector.seed = seed
    flags = read_flag_points(cfg["flag_points_file"])
    clean = CalibrationSession.from_config(cfg, None)
    candidates = []
    for i, p in enumerate(flags):
        q = sim.joints_for(p, tool_rotation(cfg["tool_z_towards_m"], p))
        found, reason = detect_flange_candidates(sim.capture(q, i).points_m(), detector, max_results=3)
        if not found:
            return seed, None, f"flag point {i}: {reason}"
        candidates.append(found)
    try:
        clean.add_flags(flags, candidates)
        coarse = clean.compute("cal_coarse")
    except CalibrationError as exc:
        return seed, None, str(exc)
    spoilt = CalibrationSession.from_config(cfg, None)
    spoilt.data.samples = list(clean.data.samples)
    spoilt.data.h_coarse = clean.data.h_coarse
    spoilt.data.criteria_plane, spoilt.data.criteria_line = clean.data.criteria_plane, clean.data.criteria_line
    zz = cfg["zigzag"]
    path = zigzag_path(flags, seed=seed, jitter_m=zz["jitter_m"], fractions=tuple(fractions or zz["fractions"]))
    spoiled = set(rng.choice(len(path), round(spoil_fraction * len(path)), replace=False).tolist())
    for k, p in enumerate(path):
        rotation = tool_rotation(cfg["tool_z_towards_m"], p)
        q = sim.joints_for(p, rotation)
        if q is None:
            clean.rejections.append((f"path {k}", "no IK"))
            spoilt.rejections.append((f"path {k}", "no IK"))
            continue
        expected = clean.expected_camera_point(p)
        det = detect_flange(sim.capture(q, 100 + k).points_m(), detector, expected)
        clean.add_sample(p, det, f"path {k}")
        if k in spoiled:
            det = detect_flange(sim.capture(q, 100 + k, _spoiler(sim, p, rotation)).points_m(), detector, expected)
        spoilt.add_sample(p, det, f"path {k}")
    fine, fine_spoilt = clean.compute("cal_fine"), spoilt.compute("cal_fine")
    truth = sim.camera_in_base
    try:
        test_mm = chessboard_test(sim, fine.transform, cfg) if chessboard else np.array([np.nan])
    except CalibrationError as exc:  # reported as a failed test mode, the calibration rows still count
        print(f"seed {seed}: test mode failed: {exc}", flush=True)
        test_mm = np.array([np.inf])
    return (
        seed,
        {
            "coarse": pose_error(coarse.transform, truth),
            "fine": pose_error(fine.transform, truth),
            "spoilt": pose_error(fine_spoilt.transform, truth),
            "samples": (len(fine.inliers), len(fine_spoilt.inliers)),
            "rejected": (len(clean.rejections), len(spoilt.rejections)),
            "outliers": (len(fine.rejected), len(fine_spoilt.rejected)),
            "test_mm": (float(np.nanmax(test_mm)), float(np.sqrt(np.nanmean(test_mm**2)))),
            "seconds": time.monotonic() - started,
        },
        "",
    )


def _pair(values) -> str:
    return f"{values[0]}/{values[1]}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--spoil", type=float, default=0.2, help="fraction of spoiled path frames (default 0.2)")
    parser.add_argument("--fractions", type=float, nargs="+", help="zig-zag fractions (default: the config's)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-chessboard", action="store_true", help="skip the test mode (chessboard corners)")
    args = parser.parse_args(argv)
    spoil = f"{args.spoil:.0%}"
    print(
        f"{'seed':>4} | {'coarse t_mm':>11} {'r_deg':>7} | {'fine t_mm':>9} {'r_deg':>7} | "
        f"{spoil + ' spoilt t_mm':>16} {'r_deg':>7} | {'test max/rms mm':>15} | {'samples':>7} {'rejected':>8} "
        f"{'outliers':>8} {'s':>4}"
    )
    rows, failed = [], 0
    with ProcessPoolExecutor(args.workers) as pool:
        for seed, row, error in pool.map(
            run_seed, [(s, args.spoil, args.fractions, not args.no_chessboard) for s in range(args.seeds)]
        ):
            if row is None:
                failed += 1
                print(f"{seed:4d} | failed: {error}", flush=True)
                continue
            rows.append(row)
            (ct, cr), (ft, fr), (st, sr) = row["coarse"], row["fine"], row["spoilt"]
            print(
                f"{seed:4d} | {ct:11.3f} {cr:7.4f} | {ft:9.3f} {fr:7.4f} | {st:16.3f} {sr:7.4f} | "
                f"{row['test_mm'][0]:7.3f}/{row['test_mm'][1]:7.3f} | "
                f"{_pair(row['samples']):>7} {_pair(row['rejected']):>8} {_pair(row['outliers']):>8} "
                f"{row['seconds']:4.0f}",
                flush=True,
            )
    if rows:
        print(f"\nsummary over {len(rows)} seeds ({failed} failed): mean / max")
        for key, label in (("coarse", "coarse (flag points)"), ("fine", "fine, clean"), ("spoilt", f"fine, {spoil}")):
            t = np.array([r[key][0] for r in rows])
            r = np.array([r[key][1] for r in rows])
            print(
                f"  {label:22} translation {t.mean():7.3f} / {t.max():7.3f} mm   rotation {r.mean():.4f} / "
                f"{r.max():.4f} deg"
            )
        test = np.array([r["test_mm"] for r in rows])
        found = np.isfinite(test[:, 0])
        if found.any():
            print(
                f"  {'test mode (88 corners)':22} positioning error per corner: max over seeds "
                f"{test[found, 0].max():.3f} mm, mean of the per-seed RMS {test[found, 1].mean():.3f} mm"
            )
        if np.isinf(test[:, 0]).any():
            failed += int(np.isinf(test[:, 0]).sum())
            print(f"  test mode failed for {int(np.isinf(test[:, 0]).sum())} seeds (no chessboard found)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
