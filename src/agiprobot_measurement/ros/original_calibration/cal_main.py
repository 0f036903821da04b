"""The original calibration's ``cal_main.py`` (its documented Code API): paths of poses, robot motion, shots, test mode.

Same names, inputs and outputs as documented, against the running station (``calibration.launch``, or
``station.launch tool:=flange_disc`` + ``phoxi_camera.launch``) through the calls the calibration node makes:
motions are IK (nearest to the current joint state) + a collision-checked joint motion (planned around obstacles
when the straight one is blocked) run through the motion client (FollowJointTrajectory on
``/scaled_pos_joint_traj_controller/follow_joint_trajectory``, or MoveIt's ``/execute_trajectory``); shots are ``/phoxi_camera/get_frame``
(``in_ = -1``: a new frame) and the next ``/phoxi_camera/pointcloud``, saved as PLY (metres) for
:func:`~agiprobot_measurement.calibration.original.calibration.circle_fitting`. Poses are ``geometry_msgs/Pose`` of
tool0 in the robot base frame ``base`` (the DH base, in which the flag points are given), metres.

The original's module globals are kept: ``mode`` (cal_fine | cal_coarse | test), ``use_mp`` (circle fitting on
worker processes), ``use_auto_judge`` (False: every shot waits for the operator's Enter / 'd' / 'q' / 'auto'),
``data_path`` (the folder of the shots and ``data.txt``) and ``killing_flag``. The defaults are the project's
(cal_fine, False, True); the original file set test, True, False. :func:`main` is the original's main program.
A ROS node is started on first use if the script has not started one (``rospy.init_node``).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import rospy
from geometry_msgs.msg import Pose

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.calibration.chessboard_test import corner_points, detect_corners
from agiprobot_measurement.calibration.config import MODES, flange_station, load_calibration_config
from agiprobot_measurement.calibration.flange_detection import valid_points
from agiprobot_measurement.calibration.flange_motion import (
    PlannedFlangeRobot,
    flange_collision_checker,
    nearest_solution,
)
from agiprobot_measurement.calibration.interfaces import STEP_FAILURES
from agiprobot_measurement.calibration.original.calibration import calibrate, circle_fitting, fit_flange, judge_fit
from agiprobot_measurement.calibration.original.utils import H2trans_rot, read_data, write_data
from agiprobot_measurement.calibration.registration import CalibrationError, zigzag_path
from agiprobot_measurement.common.geometry import fit_plane, transform_points
from agiprobot_measurement.common.limits import excerpt
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.ros.conversions import matrix_to_pose, pose_to_matrix
from agiprobot_measurement.ros.nodes.calibration import RosCamera, RosJointDriver
from agiprobot_measurement.ros.robot_client import MotionSettings
from agiprobot_measurement.sensors.phoxi.point_cloud_io import write_ply
from agiprobot_measurement.station import load_joint_limits

__all__ = [
    "RUN_MODES",
    "StationHandles",
    "configure",
    "connect_camera",
    "copy_pose",
    "get_current_pose",
    "get_fix_path",
    "get_image",
    "get_path_zigzag",
    "get_target",
    "main",
    "move_shoot",
    "plan_execute",
    "station",
]

#: the calibration modes of the Code API and the original's "debug" (print the current pose)
RUN_MODES = (*MODES, "debug")

#: the original's floor for a target's height (metres, base frame): lower ones are raised to it
MIN_TARGET_Z_M = 0.1

#: the turbulence of get_fix_path: a uniform shift in [-this, +this] per coordinate (metres)
TURBULENCE_M = 0.03

# ---------------------------------------------------------------------------- the original's module globals
mode = "cal_fine"
use_mp = False
use_auto_judge = True
killing_flag = False
data_path = str(Path(os.environ.get("ROS_HOME", "~/.ros")).expanduser() / "calibration_images") + os.sep
#: seed of the turbulence (None: new random shifts every call, as the original)
random_seed = None


@dataclass
class StationHandles:
    """The robot (tool0 in base) and the camera the functions act on."""

    robot: PlannedFlangeRobot
    camera: RosCamera
    settle_s: float
    inner_corners: tuple
    named_states: dict


_station: StationHandles | None = None


def _ensure_node() -> None:
    if not rospy.core.is_initialized():
        rospy.init_node("original_calibration", anonymous=True)


def configure(
    scene: str | Path | None = None,
    camera_ns: str = "/phoxi_camera",
    controller_action: str = "",
    velocity_scaling: float = 0.5,
    check_collisions: bool = True,
    settle_s: float = 0.3,
    frame_timeout_s: float = 60.0,
    config: str | Path | None = None,
    executor: str = "follow_joint_trajectory",
) -> StationHandles:
    """Connect to the station (replaces an earlier connection): ``scene`` the station's scene file for the
    collision checks (default config/calibration_scene.yaml, calibration.launch's), ``camera_ns`` the PhoXi driver,
    ``executor`` follow_joint_trajectory (the UR driver's or the simulator's action) or moveit (move_group's
    ExecuteTrajectory), ``controller_action`` its action name ('' = the executor's), ``velocity_scaling`` of the joint limits,
    ``settle_s`` the wait after a motion before a shot, ``config`` the calibration config (tool orientation,
    chessboard)."""
    global _station
    _ensure_node()
    settings = load_calibration_config(config)
    flange = flange_station(scene or CONFIG_DIR / "calibration_scene.yaml")
    kinematics = KinematicModel.from_station(flange, tip_frame="tool0", base_frame="base")
    limits = load_joint_limits()
    robot = PlannedFlangeRobot(
        RosJointDriver(limits, MotionSettings(executor, controller_action)),
        kinematics,
        make_ik_solver(kinematics, flange.robot),
        limits,
        settings["tool_z_towards_m"],
        collision=flange_collision_checker(flange) if check_collisions else None,
        velocity_scaling=velocity_scaling,
    )
    inner = tuple(int(v) for v in (settings.get("chessboard", {}) or {}).get("inner_corners", (8, 11)))
    camera = RosCamera(camera_ns, frame_timeout_s)
    _station = StationHandles(robot, camera, float(settle_s), inner, dict(flange.named_states))
    return _station


def connect_camera(scanner_id: str | None = None, timeout_s: float = 30.0) -> str:
    """Connect the PhoXi driver to ``scanner_id`` (None: the first of ``get_device_list``), as a script does before
    its first shot when the driver starts disconnected; returns the id. The service types are looked up from the
    running driver, whichever package defines them. CalibrationError when the driver refuses."""
    import rosservice  # lazily: only scripts that connect need it

    _ensure_node()
    ns = station().camera.camera_ns
    names = {name: f"{ns}/{name}" for name in ("get_device_list", "connect_camera")}
    for service in names.values():
        rospy.wait_for_service(service, timeout_s)
    if scanner_id is None:
        listing = rospy.ServiceProxy(
            names["get_device_list"], rosservice.get_service_class_by_name(names["get_device_list"])
        )()
        if not listing.out:
            raise CalibrationError(f"{names['get_device_list']}: no scanner listed")
        scanner_id = listing.out[0]
    connect = rospy.ServiceProxy(names["connect_camera"], rosservice.get_service_class_by_name(names["connect_camera"]))
    response = connect(name=scanner_id)
    if not response.success:
        raise CalibrationError(f"connect_camera {scanner_id}: {response.message}")
    return scanner_id


def station() -> StationHandles:
    """The station connection (:func:`configure` with its defaults on first use)."""
    return _station if _station is not None else configure()


def _check_mode(value) -> str:
    if value not in RUN_MODES:
        raise CalibrationError(f"mode must be one of {', '.join(RUN_MODES)}, got {excerpt(value)}")
    return value


# ----------------------------------------------------------------------------------------------- poses
def copy_pose(original_pose: Pose) -> Pose:
    """A deep copy of a geometry_msgs/Pose."""
    return copy.deepcopy(original_pose)


def get_current_pose() -> Pose:
    """tool0's pose in base now (forward kinematics of /joint_states)."""
    robot = station().robot
    return matrix_to_pose(np.asarray(robot.kinematics.fk(robot.current_joints()), dtype=float))


def _rng():
    return np.random.default_rng(random_seed)


def get_fix_path(data_path=None, object_points=None, need_Turbulance=False, needTurbulance=None, rng=None):
    """(path, object_points): a Pose per object point (position = the point, orientation = tool0's now).

    ``data_path``: a target file (one ``[x, y, z]`` per line, base frame, metres) read as the object points when
    given; ``object_points``: the points otherwise. ``need_Turbulance`` (the original code's ``needTurbulance``):
    shift every coordinate by a uniform random amount in [-3 cm, +3 cm]. Heights below 0.1 m are raised to 0.1 m
    (the original's floor).
    """
    if data_path:
        object_points = read_data(data_path, "target")
    if object_points is None:
        raise CalibrationError("get_fix_path: give a target file (data_path) or object_points")
    turbulence = need_Turbulance if needTurbulance is None else needTurbulance
    points = np.asarray(object_points, dtype=float).reshape(-1, 3)
    if turbulence:
        points = points + (rng or _rng()).uniform(-TURBULENCE_M, TURBULENCE_M, points.shape)
    points[:, 2] = np.maximum(points[:, 2], MIN_TARGET_Z_M)
    current = get_current_pose()
    path = []
    for x, y, z in points:
        pose = copy_pose(current)
        pose.position.x, pose.position.y, pose.position.z = float(x), float(y), float(z)
        path.append(pose)
    return path, object_points


def get_path_zigzag(path_, object_points):
    """The fine calibration's path: for every pair of object points the points at 0.25, 0.5 and 0.75 of their
    segment, each coordinate shifted by a uniform random amount in [-3 cm, +3 cm]; the object points themselves are
    not included. Poses with the orientation of ``path_``'s first pose (tool0's now when ``path_`` is empty)."""
    positions = zigzag_path(np.asarray(object_points, dtype=float), seed=random_seed, jitter_m=TURBULENCE_M)
    positions[:, 2] = np.maximum(positions[:, 2], MIN_TARGET_Z_M)
    template = path_[0] if len(path_) else get_current_pose()
    zig_zag_path = []
    for x, y, z in positions:
        pose = copy_pose(template)
        pose.position.x, pose.position.y, pose.position.z = float(x), float(y), float(z)
        zig_zag_path.append(pose)
    return zig_zag_path


# ------------------------------------------------------------------------------------ robot and camera
def plan_execute(target: Pose, mode, index=None) -> bool:
    """Move tool0 to ``target`` (its position and orientation): the IK solution nearest the current joint state
    that is free of collisions, reached by a collision-checked motion. False (with the reason logged) when the pose
    is unreachable or the motion fails ("Fail to get any plan"), True when the robot is there."""
    _check_mode(mode)
    handles = station()
    robot = handles.robot
    goal = pose_to_matrix(target)
    what = f"target {np.round(goal[:3, 3], 4).tolist()}" + (f" ({index})" if index else "")
    try:
        q = nearest_solution(robot.ik, goal[None], robot.current_joints(), robot.collision, what)
        robot.move_to_joints(q, what, handles.settle_s)
    except STEP_FAILURES as exc:
        rospy.logwarn("Fail to get any plan: %s", exc)
        return False
    return True


def get_image(im_name) -> Path:
    """Take a frame now (``get_frame`` -1, then the next ``pointcloud``) and save its valid points as binary PLY
    (metres, camera frame) at ``<im_name>.ply``; returns that path. StepError when the camera fails."""
    name = str(im_name)
    path = Path(name if name.lower().endswith(".ply") else name + ".ply")
    points = valid_points(station().camera.capture().points_m)  # the driver's invalid points are 0 0 0
    return write_ply(path, points, comments=("PhoXi frame (get_frame -1, pointcloud)", "units: metres"))


def _frame_index(now: float) -> str:
    """The original's shot index: the whole seconds followed by the fraction, its point written '_'."""
    seconds = int(now)
    return f"{seconds}{now - seconds:.9f}".replace(".", "_")


def move_shoot(target: Pose, mode):
    """Move to ``target`` and take a shot named after the current time.

    Returns (im_name, index, p_robot): the point cloud's path without '.ply' (``data_path + "im" + index``), the
    index, and the pose reached [x, y, z, qx, qy, qz, qw] (tool0 in base). False when the target cannot be
    reached or, with ``use_auto_judge`` False, the operator deletes the shot ('d') or quits ('q', sets
    ``killing_flag``); 'auto' switches to automatic judging.
    """
    global use_auto_judge, killing_flag
    index = _frame_index(time.time())
    if not plan_execute(target, mode, index):
        return False
    im_name = str(data_path) + "im" + index
    get_image(im_name)
    if not use_auto_judge:
        answer = input("Press 'Enter' to continue (input 'd' to delete current shoot or 'q' to quit calibration)")
        if answer.strip() == "auto":
            use_auto_judge = True
        elif answer.strip() in ("d", "q"):
            Path(im_name + ".ply").unlink(missing_ok=True)
            killing_flag = answer.strip() == "q"
            return False
    pose = get_current_pose()
    p_robot = [pose.position.x, pose.position.y, pose.position.z]
    p_robot += [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
    return im_name, index, p_robot


def get_target():
    """A frame now, the chessboard's inner corners (config/calibration.yaml ``chessboard.inner_corners``, 8 x 11) in
    its texture, each taken to 3D through the organised cloud: a list of [x, y, z] (camera frame, metres), corners
    without depth left out. CalibrationError when no chessboard is found."""
    handles = station()
    frame = handles.camera.capture(texture=True)
    pixels = detect_corners(frame.texture, handles.inner_corners)
    points = corner_points(frame.organized_m, pixels)
    return [[float(v) for v in p] for p in points if np.isfinite(p).all()]


# ------------------------------------------------------------------------------------------ main program
def _pool():
    # forkserver: the workers come from a clean server process, not from this one with rospy's threads (fork), and
    # do not import the calling script (spawn would, and a rostest or a script under rosrun may not import cleanly)
    context = get_context("forkserver")
    context.set_forkserver_preload(["agiprobot_measurement.calibration.original.calibration"])
    return ProcessPoolExecutor(max_workers=2, mp_context=context)


def _collect(path, data_file: Path, flag: bool, calibrate_each: bool = False, best=None):
    """Shots along ``path``, their circles fitted (on worker processes with ``use_mp``), the accepted pairs written;
    with ``calibrate_each`` the data file is calibrated after every pair and the (H, error) with the lowest error
    is returned (the fine calibration's rule), starting from ``best``."""

    def record(p_camera, shot_index, p_robot):
        nonlocal best
        if not p_camera:
            return
        write_data(data_file, [p_robot, p_camera], shot_index, type="point_pair")
        if calibrate_each:
            h, error = calibrate(data_file)
            if best is None or error < best[1]:
                best = (h, error)
                rospy.loginfo("New H (error %.6f m):\n%s", error, h)

    pending = []
    pool = _pool() if use_mp else None
    try:
        for i, target in enumerate(path):
            if killing_flag:
                break
            rospy.loginfo("##### Target: %d/%d #####", i + 1, len(path))
            shot = move_shoot(target, mode)
            if not shot:
                continue
            im_name, index, p_robot = shot
            shot_index = f"flag{i}_{index}" if flag else index
            need_judge = not flag and use_auto_judge
            if pool is None:
                record(circle_fitting(im_name, shot_index, need_judge, data_file), shot_index, p_robot)
            else:
                pending.append((pool.submit(fit_flange, im_name), im_name, shot_index, need_judge, p_robot))
        for future, im_name, shot_index, need_judge, p_robot in pending:  # in shot order: one writer
            record(judge_fit(future.result(), im_name, shot_index, need_judge, data_file), shot_index, p_robot)
    finally:
        if pool is not None:
            pool.shutdown()
    return best


def main(run_mode=None, target_file=None, velocity_scaling=None, max_targets=None) -> tuple | None:
    """The original main program in ``run_mode`` (default the module's ``mode``), files in ``data_path``.

    cal_coarse / cal_fine: the flag points of ``target_file`` (default ``data_path + "target.txt"``) are shot and
    fitted (their counts become the criteria), ``H_coarse`` = calibrate(data.txt) is written with ``Trans_coarse`` /
    ``Rot_coarse``; cal_fine goes on along the zig-zag path (each accepted pair written, calibrated again, the lowest
    error kept) and writes ``H_final``, ``Trans``, ``Rot``. Returns (H, error). test: with the flange out of view
    (``chessboard.capture_state``), the chessboard's corners (:func:`get_target`) are taken to the base frame with
    calibrate(data.txt) (written as ``H``) and the flange is moved 2 cm above each (``chessboard.approach_offset_m``,
    along the board's normal; the first ``max_targets`` corners only when given); returns (H, the flange positions
    reached). debug: prints the current pose.
    """
    run_mode = _check_mode(run_mode or mode)
    if velocity_scaling is not None:
        station().robot.velocity_scaling = float(velocity_scaling)
    folder = Path(str(data_path))
    folder.mkdir(parents=True, exist_ok=True)
    data_file = folder / "data.txt"
    if run_mode == "debug":
        print(get_current_pose())
        return None
    if run_mode == "test":
        return _test_mode(data_file, max_targets)
    path, object_points = get_fix_path(data_path=str(target_file or folder / "target.txt"))
    zig_zag_path = get_path_zigzag(path, object_points) if run_mode == "cal_fine" else []
    _collect(path, data_file, flag=True)
    h_coarse, error = calibrate(data_file)
    rospy.loginfo("Coarse Calibrate Finished (error %.6f m):\n%s", error, h_coarse)
    write_data(data_file, h_coarse, "H_coarse", type="mat")
    trans, rot = H2trans_rot(h_coarse)
    write_data(data_file, trans, "Trans_coarse", type="vec")
    write_data(data_file, rot, "Rot_coarse", type="vec")
    if run_mode == "cal_coarse":
        return h_coarse, error
    h_final, error = _collect(zig_zag_path, data_file, flag=False, calibrate_each=True, best=(h_coarse, error))
    write_data(data_file, h_final, "H_final", type="mat")
    trans, rot = H2trans_rot(h_final)
    write_data(data_file, trans, "Trans", type="vec")
    write_data(data_file, rot, "Rot", type="vec")
    return h_final, error


def _test_mode(data_file: Path, max_targets: int | None = None):
    handles = station()
    board = load_calibration_config().get("chessboard", {}) or {}
    offset = float(board.get("approach_offset_m", 0.02))
    capture_state = board.get("capture_state", "up")
    robot = handles.robot
    if capture_state:  # the flange out of the camera's view while the board is shot
        robot.move_to_joints(handles.named_states[capture_state], f"named state {capture_state}")
    target_cam = np.asarray(get_target(), dtype=float)
    if len(target_cam) < 3:
        raise CalibrationError(f"test mode: only {len(target_cam)} chessboard corners have a 3D point")
    h, _error = calibrate(data_file)
    write_data(data_file, h, "H", type="mat")
    h = np.asarray(h)
    targets = transform_points(h, target_cam)
    _, normal = fit_plane(targets)
    if normal @ (h[:3, 3] - targets.mean(axis=0)) < 0.0:  # the board's side the camera sees
        normal = -normal
    reached = []
    for target in targets[:max_targets]:
        goal = target + offset * normal
        try:
            robot.move_to(goal, z_towards_m=goal - normal, settle_s=handles.settle_s, free_yaw=True)
        except STEP_FAILURES as exc:
            rospy.logwarn("corner %s: %s", np.round(target, 4).tolist(), exc)
            continue
        reached.append(goal)
    return h, reached


def _parse(argv):
    parser = argparse.ArgumentParser(description="The original calibration's main program on the running station.")
    parser.add_argument("--mode", choices=RUN_MODES, default=mode)
    parser.add_argument("--use-mp", action="store_true", default=use_mp)
    parser.add_argument("--operator", action="store_true", help="use_auto_judge False: confirm every shot")
    parser.add_argument("--data-path", default=data_path, help="folder of the shots, data.txt and target.txt")
    parser.add_argument("--target-file", help="flag points (default <data-path>/target.txt)")
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = _parse(rospy.myargv(sys.argv)[1:])
    mode, use_mp, use_auto_judge = args.mode, args.use_mp, not args.operator
    data_path = str(Path(args.data_path)) + os.sep
    print(main(target_file=args.target_file))
