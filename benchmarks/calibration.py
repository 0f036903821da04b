"""Accuracy of the flange-based calibration against the hidden true camera pose, over seeds, without ROS.

Per seed: the scanner's pose is the configured one moved by up to +-5 cm and turned by up to +-3 deg (the truth,
kept from the calibration); the robot (bare flange disc) is posed by IK at the flag points and the zig-zag path,
each frame rendered by the ROS-free PhoXi simulation (structured_light.py, its noise model) and the flange
detected in it. Flag points: up to 3 disc candidates per frame, the combination whose distances agree with the
robot's (select_consistent_flags); coarse = flag points only. Fine = flag points + zig-zag path, once with clean
frames and once with a fraction of the path frames spoiled (a plate occludes part of the flange and a decoy disc
of the flange's size sits 8 cm beside it: a wrong cluster); the clean frames are shared by both runs.

    python -m benchmarks.calibration                          # 20 seeds, 20 % spoiled, 2 workers
    python -m benchmarks.calibration --seeds 3 --workers 4 --fractions 0.5

The station is that of launch/calibration.launch (config/calibration_scene.yaml: the chessboard lies on the table in
every frame). Test mode (--no-chessboard skips it): the chessboard's 8 x 11 inner corners found in the texture image
(OpenCV) with the robot out of view, taken to 3D through the organised cloud and transformed with the fine
calibration; the positioning error per corner against the true corners (the simulated robot reaches any target
exactly, so this is the error of moving the tip to the corner).

Prints one row per seed (translation error mm, rotation error deg, test-mode max / RMS over the corners in mm) and
the mean / max over the seeds.

--compare: the flange method against its peers, OpenCV's eye-to-hand AX = XB solvers (calibrateHandEye: TSAI, PARK,
HORAUD, ANDREFF, DANIILIDIS; calibrateRobotWorldHandEye: SHAH, LI) with a 6 x 9 chessboard plate (25 mm squares) on
the flange, on the same robot poses and frame budgets (--frames, default 8 15 30), noise on, for a robot whose true
kinematics deviate from the planner's model by each --scales factor times the deviation of the true robot's
kinematics file (config/ur10e_kinematics_correction.yaml names it: the original station's real UR10e,
config/my_robot_calibration.yaml) from that model (0 = the perfect robot, 1 = that robot). The planner's model (IK,
what the robot reports, the calibration's flange poses) is config/ur10e.yaml's kinematics_config (the nominal arm),
or --planner-kinematics FILE (e.g. config/my_robot_calibration.yaml: a station that knows its robot's calibration).
See compare_seed for how the poses are chosen and frames spoiled.

    python -m benchmarks.calibration --compare --workers 2 --json compare.json --plot compare.png      # 20 seeds
    python -m benchmarks.calibration --compare --seeds 5 --workers 2
    python -m benchmarks.calibration --compare --seeds 5 --scales 1 --planner-kinematics config/my_robot_calibration.yaml
"""

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.spatial.transform import Rotation

from agiprobot_measurement.calibration import hand_eye
from agiprobot_measurement.calibration.chessboard_test import (
    corner_points,
    detect_corners,
    match_to_truth,
    positioning_errors_mm,
    scene_chessboard_corners,
    scene_chessboards,
)
from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
from agiprobot_measurement.calibration.flange_detection import detect_flange, detect_flange_candidates
from agiprobot_measurement.calibration.registration import CalibrationError, pose_error, read_flag_points, zigzag_path
from agiprobot_measurement.calibration.session import CalibrationSession, detector_config
from agiprobot_measurement.calibration.simulation import SimulatedStation, nominal_camera_pose, perturbed_pose
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.motion.kinematics import TrueKinematics, load_kinematics_correction
from agiprobot_measurement.sensors.phoxi.renderer import SceneGeometry, primitive_mesh
from agiprobot_measurement.station import CONFIG_DIR
from benchmarks.harness import load_conditions, write_json

DEFAULTS = load_conditions("calibration").mapping("defaults")


def _spoiler(sim, p, rotation):
    """Decoy disc 8 cm beside the flange and a plate over a third of the flange, 2 cm in front (world frame)."""

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

    (board,) = scene_chessboards(sim.station.scene)
    frame = sim.capture(sim.station.named_states["up"], 999)
    points = corner_points(frame.points_m(), detect_corners(frame.texture, board.inner_corners))
    truth = transform_points(np.linalg.inv(sim.world_from_base), scene_chessboard_corners(board))
    return positioning_errors_mm(h_base_camera, points, truth)


def run_seed(args):
    seed, spoil_fraction, fractions, chessboard = args

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


# ------------------------------------------------------------------------------------------------ --compare
def _compare_poses(cfg, flags, rng, count, tilt_deg):
    """Flange poses (base_link <- tool0): the 4 flag points, then zig-zag points between them (fractions 1/8 .. 7/8 of
    every pair, jittered as the config says) in random order. Orientation: tool z towards the config's
    tool_z_towards_m (the flange and the board face the camera), then tilted about a random horizontal axis of the tool
    by 10 deg .. tilt_deg and rolled about its z by up to +-tilt_deg, so that the AX = XB solvers get the rotation
    diversity they need (their accuracy grows with the angles between stations; Tsai & Lenz)."""

    path = zigzag_path(
        flags,
        seed=int(rng.integers(1 << 30)),
        jitter_m=cfg["zigzag"]["jitter_m"],
        fractions=tuple(np.arange(1, 8) / 8.0),
    )
    positions = np.vstack([flags, path[rng.permutation(len(path))]])
    poses = []
    for p in positions[: count + 12]:  # spares for poses without IK or board
        heading = rng.uniform(0.0, 2.0 * np.pi)
        tilt = np.radians(rng.uniform(10.0, tilt_deg))
        turn = Rotation.from_rotvec([tilt * np.cos(heading), tilt * np.sin(heading), 0.0])
        roll = Rotation.from_rotvec([0.0, 0.0, np.radians(rng.uniform(-tilt_deg, tilt_deg))])
        pose = np.eye(4)
        pose[:3, :3] = tool_rotation(cfg["tool_z_towards_m"], p) @ (turn * roll).as_matrix()
        pose[:3, 3] = p
        poses.append(pose)
    return poses


def _test_errors_mm(sim, true_kin, h_base_camera, corners_camera, truth, normal, offset_m):
    """Test mode on an imperfect robot: the tool0 target `offset_m` above each corner estimate (flange facing the
    board), joints by the NOMINAL IK, the point `offset_m` in front of the TRUE flange against the true corner (mm)."""

    targets = transform_points(h_base_camera, corners_camera)
    ok = np.isfinite(targets).all(axis=1)
    z = -normal / np.linalg.norm(normal)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    poses = np.broadcast_to(np.eye(4), (int(ok.sum()), 4, 4)).copy()
    poses[:, :3, :3] = np.column_stack([x, np.cross(z, x), z])
    poses[:, :3, 3] = targets[ok] - z * offset_m
    q, solved = sim.ik.solve_nearest(poses, sim.seed_q)
    # an estimate off the reachable space has no IK solution (NaN joints): it counts as a missed corner (NaN error)
    good = np.asarray(solved, dtype=bool) & np.isfinite(np.asarray(q)).all(axis=1)
    errors = np.full(len(targets), np.nan)
    if not good.any():
        return errors
    q_good = np.asarray(q)[good]
    reached = true_kin.fk(q_good) if true_kin is not None else sim.kinematics.fk(q_good)
    tips = reached[:, :3, 3] + reached[:, :3, 2] * offset_m
    idx = np.flatnonzero(ok)[good]

    errors[idx] = np.linalg.norm(tips - truth[match_to_truth(targets[idx], truth)], axis=1) * 1000.0
    return errors


def _flange_variant(sim, frames_points, physical, cfg, detector):
    """Flange detections of one pose set: flag candidates (frames 0-3) and path detections (cropped around the
    perfect robot's coarse prediction); (candidates, path detections) or a failure reason (str)."""

    candidates = []
    for i in range(4):
        found, reason = detect_flange_candidates(frames_points[i], detector, max_results=3)
        if not found:
            return f"flag point {i}: {reason}"
        candidates.append(found)
    perfect = CalibrationSession.from_config(cfg, None)
    try:
        perfect.add_flags(physical[:4, :3, 3], candidates)
        perfect.compute("cal_coarse")
    except CalibrationError as exc:
        return f"flag points: {exc}"
    path = [None] * 4 + [
        detect_flange(frames_points[k], detector, perfect.expected_camera_point(physical[k, :3, 3]))
        for k in range(4, len(frames_points))
    ]
    return candidates, path


def _flange_estimates(cfg, reported, candidates, path, n, label, where):
    """({label coarse, label fine}: base <- camera of the flange method from the robot's reported flange positions,
    whether the flag check's tolerance had to be raised). When the flag points' camera and robot distances disagree
    by more than the configured flag_tolerance_m (the robot's own error can do that), the procedure refuses; the
    benchmark then retries with 20 mm to show what the method would give, and says so."""

    out, raised = {}, False
    session = CalibrationSession.from_config(cfg, None)
    try:
        try:
            session.add_flags(reported[:4, :3, 3], candidates)
        except CalibrationError as exc:
            if "disagree" not in str(exc):
                raise
            print(f"{where}: {label}: flag check refused ({exc}); retried with flag_tolerance_m 0.02", flush=True)
            session.flag_tolerance_m, raised = 0.02, True
            session.add_flags(reported[:4, :3, 3], candidates)
        out[f"{label} coarse"] = session.compute("cal_coarse").transform
        for k in range(4, n):
            session.add_sample(reported[k, :3, 3], path[k], f"path {k}")
        out[f"{label} fine"] = session.compute("cal_fine").transform
    except CalibrationError as exc:
        print(f"{where}: {label} method failed: {exc}", flush=True)
    return out, raised


def compare_seed(args):
    """One seed of --compare. The truth: the scanner's pose moved by up to 5 cm / 3 deg from the configured one.

    Poses: the same positions (:func:`_compare_poses`) and frame budget for every method, each method with the
    orientations its procedure prescribes: the flange faces the camera (tool z towards tool_z_towards_m, as
    calibration.procedure does: an oblique disc is found less accurately, 0.1-0.2 mm instead of 0.02 mm per frame at
    15-25 deg); the board is tilted by 10..tilt_deg and rolled (what AX = XB needs). ``flange_tilted``: the flange
    method once more on the board's tilted poses (the shared-poses comparison; 50 % more rendering).

    Each pose is rendered once per target, the flange / board where the pose says and the arm's links by the true
    kinematics (the correction at scale 1) at the joints that put it there; for every scale the robot's joints are
    those at which that scale's true robot reaches the pose, and the robot reports the NOMINAL forward kinematics of
    them (what a driver without the calibration file reports). Spoiled frames: a robot pose reading glitch on
    round(spoil x frames) of the non-flag frames of a budget (one random joint's reading off by 1-3 deg, either sign),
    the same frames and glitches for every method. Path frames' flange detection crops around the perfect robot's
    coarse prediction (on a real station a large kinematic error also moves the crop: at scale 2 this favours the
    flange method)."""
    seed, frames, scales, spoil, tilt_deg, chessboard, flange_tilted, planner_kinematics = args

    started = time.monotonic()
    rng = np.random.default_rng(5000 + seed)
    camera = perturbed_pose(nominal_camera_pose(), rng, 0.05, np.radians(3.0))
    _, correction, _ = load_kinematics_correction()
    scene = CONFIG_DIR / "calibration_scene.yaml"
    sim = SimulatedStation(
        camera, noise_seed=seed, scene_path=scene, true_kinematics=correction, planner_kinematics=planner_kinematics
    )
    board_sim = SimulatedStation(
        camera,
        noise_seed=seed,
        scene_path=scene,
        true_kinematics=correction,
        board=hand_eye.FlangeBoard(),
        planner_kinematics=planner_kinematics,
    )
    sim.scanner.workers = board_sim.scanner.workers = 1
    true_models = {s: TrueKinematics(sim.kinematics, correction, s) for s in scales}
    cfg = load_calibration_config()
    detector = detector_config(cfg)
    detector.seed = seed
    flags = read_flag_points(cfg["flag_points_file"])
    budget = max(frames)
    truth = sim.camera_in_base

    # ---- the shared positions; per pose set and scale the joints that reach them
    sets = ("facing", "tilted")
    used = {name: [] for name in sets}
    joints = {(name, s): [] for name in sets for s in scales}
    renders = {"flange": [], "board": [], "flange_tilted": []}
    for k, tilted in enumerate(_compare_poses(cfg, flags, rng, budget, tilt_deg)):
        if len(used["tilted"]) == budget:
            break
        facing = tilted.copy()
        facing[:3, :3] = tool_rotation(cfg["tool_z_towards_m"], tilted[:3, 3])
        poses = {"facing": facing, "tilted": tilted}
        render_q = {name: sim.joints_placing(pose) for name, pose in poses.items()}
        per_scale = {
            (name, s): (None if render_q[name] is None else true_models[s].solve_near(poses[name], render_q[name]))
            for name in sets
            for s in scales
        }
        if any(v is None for v in per_scale.values()):
            if k < 4:
                return seed, None, f"flag point {k}: no joint solution"
            continue
        for name in sets:
            used[name].append(poses[name])
        for key, q in per_scale.items():
            joints[key].append(q)
        renders["flange"].append(sim.capture(render_q["facing"], k).points_m())
        if flange_tilted:
            renders["flange_tilted"].append(sim.capture(render_q["tilted"], 400 + k).points_m())
        frame = board_sim.capture(render_q["tilted"], 200 + k)
        try:
            renders["board"].append(
                hand_eye.detect_board_pose(frame.texture, frame.intrinsics.matrix(), board_sim.board)
            )
        except CalibrationError:
            renders["board"].append(None)
    if len(used["tilted"]) < budget:
        return seed, None, f"only {len(used['tilted'])} of {budget} poses reachable"
    physical = {name: np.array(used[name]) for name in sets}
    deviation_mm = {
        s: float(
            np.mean(
                [
                    np.linalg.norm(
                        sim.kinematics.fk(np.array(joints[name, s]))[:, :3, 3] - physical[name][:, :3, 3], axis=1
                    )
                    for name in sets
                ]
            )
            * 1000
        )
        for s in scales
    }

    # ---- flange detections (once: they depend on the frames, not on what the robot reports)
    variants = {"flange": ("facing", renders["flange"])}
    if flange_tilted:
        variants["flange tilted"] = ("tilted", renders["flange_tilted"])
    detections = {}
    for label, (name, points) in variants.items():
        found = _flange_variant(sim, points, physical[name], cfg, detector)
        if isinstance(found, str):
            return seed, None, f"{label}: {found}"
        detections[label] = found

    # ---- glitches: the same frames and joint errors for every method and scale
    glitches = {}
    for n in frames:
        count = min(round(spoil * n), n - 4)
        chosen = rng.choice(np.arange(4, n), count, replace=False) if count else []
        glitches[n] = {
            int(k): (int(rng.integers(6)), float(np.radians(rng.uniform(1.0, 3.0)) * rng.choice([-1, 1])))
            for k in chosen
        }

    # ---- test mode: the table's chessboard, robot out of view
    test = None
    if chessboard:
        (board,) = scene_chessboards(sim.station.scene)
        frame = sim.capture(sim.station.named_states["up"], 999)
        try:
            corners = corner_points(frame.points_m(), detect_corners(frame.texture, board.inner_corners))
            base_from_world = np.linalg.inv(sim.world_from_base)
            test = (
                corners,
                transform_points(base_from_world, scene_chessboard_corners(board)),
                base_from_world[:3, :3] @ board.pose[:3, :3][:, 2],
            )
        except CalibrationError as exc:
            print(f"seed {seed}: test mode failed: {exc}", flush=True)

    def reported(name, s, n, spoilt):
        q = np.array(joints[name, s][:n])
        if spoilt:
            for k, (j, delta) in glitches[n].items():
                q[k, j] += delta
        return sim.kinematics.fk(q)

    cases, problems = [], []
    for s in scales:
        for n in frames:
            for spoilt in (False, True) if spoil > 0 else (False,):
                where = f"seed {seed} scale {s} frames {n}{' spoilt' if spoilt else ''}"
                estimates, raised = {}, set()
                for label, (name, _) in variants.items():
                    candidates, path = detections[label]
                    found, tolerance_raised = _flange_estimates(
                        cfg, reported(name, s, n, spoilt), candidates, path, n, label, where
                    )
                    estimates.update(found)
                    if tolerance_raised:
                        raised.update(found)
                seen = [k for k in range(n) if renders["board"][k] is not None]
                robot = reported("tilted", s, n, spoilt)
                problems.append((robot[seen], np.array([renders["board"][k].camera_from_board for k in seen])))
                cases.append(((s, n, spoilt), estimates, raised))
    for (_, estimates, _), solved in zip(cases, hand_eye.solve_many(problems), strict=True):
        estimates.update(solved)

    results = []
    offset = float(cfg["chessboard"]["approach_offset_m"])
    for (s, n, spoilt), estimates, raised in cases:
        for method, h in estimates.items():
            t_mm, r_deg = pose_error(h, truth)
            row = {
                "seed": seed,
                "scale": s,
                "frames": n,
                "spoilt": spoilt,
                "method": method,
                "translation_mm": t_mm,
                "rotation_deg": r_deg,
                "flag_tolerance_raised": method in raised,
            }
            if test is not None:
                errors = _test_errors_mm(sim, true_models[s], h, test[0], test[1], test[2], offset)
                row["test_rms_mm"] = float(np.sqrt(np.nanmean(errors**2)))
                row["test_max_mm"] = float(np.nanmax(errors))
            results.append(row)
    boards = [b for b in renders["board"] if b is not None]
    info = {
        "seed": seed,
        "seconds": time.monotonic() - started,
        "flange_deviation_mm": deviation_mm,
        "boards_found": len(boards),
        "board_reprojection_rms_px": float(np.mean([b.reprojection_rms_px for b in boards])) if boards else None,
    }
    return seed, {"rows": results, "info": info}, ""


def _compare_summary(rows, key, **where):
    values = [r[key] for r in rows if all(r[k] == v for k, v in where.items()) and key in r]
    return (float(np.mean(values)), float(np.max(values)), len(values)) if values else (np.nan, np.nan, 0)


def _compare_plot(rows, frames, scales, path):
    """Mean translation error against the truth (top) and test-mode RMS (bottom) vs frames, one column per robot."""
    import matplotlib  # only for --plot: the plotting backend is chosen before pyplot loads

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(r["method"] for r in rows))
    colours = plt.get_cmap("tab20")(np.linspace(0.0, 1.0, 20))[: len(methods)]
    keys = [("translation_mm", "mean translation error (mm)"), ("test_rms_mm", "test-mode RMS (mm)")]
    fig, axes = plt.subplots(2, len(scales), figsize=(4.2 * len(scales) + 2.0, 8), squeeze=False)
    for column, s in enumerate(scales):
        for row, (key, label) in enumerate(keys):
            ax = axes[row][column]
            for method, colour in zip(methods, colours, strict=True):
                means = [_compare_summary(rows, key, scale=s, frames=n, spoilt=False, method=method)[0] for n in frames]
                style = "-o" if method.startswith("flange") else "--s"
                ax.plot(frames, means, style, color=colour, label=method)
            ax.set_yscale("log")
            ax.set_xlabel("frames")
            ax.set_ylabel(label)
            ax.set_title("perfect robot" if s == 0 else f"kinematic error x {s:g}")
            ax.grid(True, which="both", alpha=0.3)
            ax.set_xticks(list(frames))
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=8)
    fig.tight_layout(rect=(0.0, 0.0, 0.86, 1.0))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def compare_main(args) -> int:

    frames, scales = sorted(args.frames), list(dict.fromkeys(args.scales))
    if min(frames) < 5:
        print("--frames: every budget needs the 4 flag frames and at least one more", file=sys.stderr)
        return 2
    started = time.monotonic()
    rows, infos, failed = [], [], 0
    print(f"planner's model: {args.planner_kinematics or 'config/ur10e.yaml kinematics_config'}", flush=True)
    jobs = [
        (
            s,
            frames,
            scales,
            args.spoil,
            args.tilt_deg,
            not args.no_chessboard,
            args.flange_tilted,
            args.planner_kinematics,
        )
        for s in range(args.seeds)
    ]
    with ProcessPoolExecutor(args.workers) as pool:
        for seed, out, error in pool.map(compare_seed, jobs):
            if out is None:
                failed += 1
                print(f"seed {seed}: failed: {error}", flush=True)
                continue
            rows += out["rows"]
            infos.append(out["info"])
            dev = ", ".join(f"x{s:g}: {v:.2f}" for s, v in out["info"]["flange_deviation_mm"].items())
            print(
                f"seed {seed}: {out['info']['seconds']:.0f} s, boards found {out['info']['boards_found']}/"
                f"{max(frames)}, flange deviation mean (mm) {dev}",
                flush=True,
            )
    if not rows:
        return 1
    methods = list(dict.fromkeys(r["method"] for r in rows))
    print(
        f"\n{len(infos)} seeds ({failed} failed), {time.monotonic() - started:.0f} s; translation error mean / max (mm),"
        " rotation error mean (deg), test-mode RMS over the table chessboard's corners, mean over seeds (mm)"
    )
    header = f"{'robot':>12} {'frames':>6} {'method':>20} | {'clean t_mm':>15} {'r_deg':>6} {'test':>6} |"
    if args.spoil > 0:
        header += f" {f'{args.spoil:.0%} spoilt t_mm':>17} {'r_deg':>6} {'test':>6}"
    print(header)
    for s in scales:
        robot = "perfect" if s == 0 else f"corr x{s:g}"
        for n in frames:
            for method in methods:
                raised = any(
                    r["flag_tolerance_raised"] for r in rows if (r["scale"], r["frames"], r["method"]) == (s, n, method)
                )
                line = f"{robot:>11}{'*' if raised else ' '} {n:6d} {method:>20} |"
                for spoilt in (False, True) if args.spoil > 0 else (False,):
                    t = _compare_summary(rows, "translation_mm", scale=s, frames=n, spoilt=spoilt, method=method)
                    r = _compare_summary(rows, "rotation_deg", scale=s, frames=n, spoilt=spoilt, method=method)
                    e = _compare_summary(rows, "test_rms_mm", scale=s, frames=n, spoilt=spoilt, method=method)
                    line += f" {t[0]:7.3f} /{t[1]:7.3f} {r[0]:6.3f} {e[0]:6.2f} |"
                print(line)
    if any(r["flag_tolerance_raised"] for r in rows):
        print(
            "* the flange method's flag check refused (camera and robot distances between the flag points disagree "
            "by more than flag_tolerance_m: the robot's own error) for some seeds; those rows retried with 20 mm"
        )
    deviation = {s: float(np.mean([i["flange_deviation_mm"][s] for i in infos])) for s in scales}
    print(
        "\nflange position the robot reports vs where it is, mean over poses and seeds (mm): "
        + ", ".join(f"correction x{s:g}: {v:.2f}" for s, v in deviation.items())
    )
    n_mid = frames[len(frames) // 2]
    print(f"cost of the robot's kinematic error at {n_mid} frames (clean): mean translation error / test-mode RMS (mm)")
    for method in methods:
        cells = []
        for s in scales:
            t = _compare_summary(rows, "translation_mm", scale=s, frames=n_mid, spoilt=False, method=method)[0]
            e = _compare_summary(rows, "test_rms_mm", scale=s, frames=n_mid, spoilt=False, method=method)[0]
            cells.append(f"x{s:g}: {t:7.3f} / {e:6.2f}")
        print(f"  {method:>20}  " + "   ".join(cells))
    peers = [m for m in methods if not m.startswith("flange")]
    if peers and "flange fine" in methods:
        print("flange fine against the best OpenCV method (mean translation error / test-mode RMS, mm):")
        for s in scales:
            for n in frames:
                cells = []
                for spoilt in (False, True) if args.spoil > 0 else (False,):
                    for key in ("translation_mm", "test_rms_mm"):
                        own = _compare_summary(rows, key, scale=s, frames=n, spoilt=spoilt, method="flange fine")[0]
                        best = min(
                            peers,
                            key=lambda m, k=key, sp=spoilt, s=s, n=n: _compare_summary(
                                rows, k, scale=s, frames=n, spoilt=sp, method=m
                            )[0],
                        )
                        other = _compare_summary(rows, key, scale=s, frames=n, spoilt=spoilt, method=best)[0]
                        verdict = "leads" if own < other else "BEHIND"
                        cells.append(
                            f"{'spoilt ' if spoilt else ''}{key.split('_')[0]} {own:.3f} vs {best} "
                            f"{other:.3f} {verdict}"
                        )
                print(f"  x{s:g} {n:3d} frames: " + "; ".join(cells))
    if args.json:
        write_json(
            args.json,
            {
                "frames": frames,
                "scales": scales,
                "spoil": args.spoil,
                "tilt_deg": args.tilt_deg,
                "seeds": infos,
                "rows": rows,
            },
        )
        print(f"json: {args.json}")
    if args.plot:
        _compare_plot(rows, frames, scales, args.plot)
        print(f"plot: {args.plot}")
    return 1 if failed else 0


def _pair(values) -> str:
    return f"{values[0]}/{values[1]}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=DEFAULTS["seeds"])
    parser.add_argument(
        "--spoil", type=float, default=DEFAULTS["spoil"], help="fraction of spoiled path frames (%(default)g)"
    )
    parser.add_argument("--fractions", type=float, nargs="+", help="zig-zag fractions (default: the config's)")
    parser.add_argument("--workers", type=int, default=DEFAULTS["workers"])
    parser.add_argument("--no-chessboard", action="store_true", help="skip the test mode (chessboard corners)")
    parser.add_argument("--compare", action="store_true", help="the flange method against OpenCV's AX = XB solvers")
    parser.add_argument(
        "--frames", type=int, nargs="+", default=list(DEFAULTS["frames"]), help="--compare: frame budgets"
    )
    parser.add_argument(
        "--scales",
        type=float,
        nargs="+",
        default=list(DEFAULTS["scales"]),
        help="--compare: factors on the true robot's deviation from the planner's model (0 = perfect)",
    )
    parser.add_argument(
        "--planner-kinematics",
        help="--compare: the kinematics file of the planner's model (default config/ur10e.yaml's kinematics_config)",
    )
    parser.add_argument(
        "--tilt-deg", type=float, default=DEFAULTS["tilt_deg"], help="--compare: largest tilt / roll of the poses"
    )
    parser.add_argument(
        "--flange-tilted", action="store_true", help="--compare: also the flange method on the board's tilted poses"
    )
    parser.add_argument("--json", help="--compare: write every result row to this JSON file")
    parser.add_argument("--plot", help="--compare: error vs frames plot (PNG)")
    args = parser.parse_args(argv)
    if args.compare:
        return compare_main(args)
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
    raise SystemExit(main())
