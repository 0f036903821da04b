"""Inverse kinematics: closed form (URAnalyticIK), KDL (KDLIK) and the solver choice."""

import dataclasses

import numpy as np
import pytest

from agiprobot_measurement.motion.ik import (
    KDLIK,
    ORIENTATION_TOLERANCE_RAD,
    POSITION_TOLERANCE_M,
    URAnalyticIK,
    ik_for_station,
    make_ik_solver,
    nearest_representative,
    pose_errors,
)
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.station import ConfigError, JointLimits, Station
from agiprobot_measurement.station.urdf_model import UrdfModel


@pytest.fixture(scope="module")
def ik(kinematic_model, station):
    return URAnalyticIK(kinematic_model, station.robot)


@pytest.fixture(scope="module")
def random_states(kinematic_model):
    return np.random.default_rng(42).uniform(kinematic_model.lower, kinematic_model.upper, (1000, 6))


def dh_matrix(theta, d, a, alpha):
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def independent_fk(station, q):
    """world -> laser_emitter_frame from the DH table, the scene's robot base (base_link; the DH base frame is it
    turned by pi about z, ur_description's base_link -> base) and the scanner mount."""
    robot = station.robot
    pose = station.scene.robot_base_pose @ np.diag([-1.0, -1.0, 1.0, 1.0])
    for i in range(6):
        pose = pose @ dh_matrix(q[i], robot.d_m[i], robot.a_m[i], robot.alpha_rad[i])
    return pose @ station.scanner.mount_pose


def assert_reaches(model, q, poses):
    position, angle = pose_errors(model.fk_batch(np.atleast_2d(q)), np.reshape(poses, (-1, 4, 4)))
    assert position.max() <= POSITION_TOLERANCE_M
    assert angle.max() <= ORIENTATION_TOLERANCE_RAD


def wide_limit_model(station, lower=-2 * np.pi, upper=2 * np.pi):
    limits = station.limits
    wide = JointLimits(
        limits.names,
        np.full(6, lower),
        np.full(6, upper),
        limits.max_velocity,
        limits.max_acceleration,
    )
    return KinematicModel(UrdfModel(station.urdf_xml), "world", "laser_emitter_frame", wide)


# ---------------------------------------------------------------------------------------------- FK
def test_fk_matches_independent_dh_product(station, kinematic_model, ik):
    states = [*station.named_states.values(), *np.random.default_rng(1).uniform(-3, 3, (10, 6))]
    for q in states:
        expected = independent_fk(station, q)
        for reached in (kinematic_model.fk(q), ik.fk(q), kinematic_model.fk_kdl(q)):
            position, angle = pose_errors(reached, expected)
            assert position < 1e-6
            assert angle < 1e-6


def test_the_compiled_fk_of_large_batches_matches_the_numpy_fk(kinematic_model):
    from agiprobot_measurement.motion.kinematics_kernels import COMPILED_FROM_STATES, chain_frames

    states = np.random.default_rng(2).uniform(-3, 3, (COMPILED_FROM_STATES, 6))
    pre, axes, tip = kinematic_model.fk_segments
    frames, tips = chain_frames(states, pre, axes, tip)
    small = kinematic_model.fk_batch(states[:10])  # below the compiled size: the numpy product
    np.testing.assert_allclose(tips[:10], small, atol=1e-12)
    np.testing.assert_allclose(frames[:10, -1] @ tip, small, atol=1e-12)
    np.testing.assert_allclose(tips[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(states), 4)))


# ------------------------------------------------------------------------------------ closed form
def test_round_trip_on_1000_reachable_poses(kinematic_model, ik, random_states):
    poses = kinematic_model.fk_batch(random_states)
    seeds = np.random.default_rng(7).uniform(kinematic_model.lower, kinematic_model.upper, (1000, 6))
    q, ok = ik.solve_nearest(poses, seeds)
    assert ok.all()
    assert_reaches(kinematic_model, q, poses)
    assert kinematic_model.within_limits(q).all()


def test_every_solution_is_valid_and_the_generating_state_is_among_them(kinematic_model, ik, random_states):
    poses = kinematic_model.fk_batch(random_states)
    solutions, valid = ik.solve_all(poses)
    assert solutions.shape == (1000, 8, 6) and valid.shape == (1000, 8)
    assert np.isnan(solutions[~valid]).all()
    good = solutions[valid]
    assert kinematic_model.within_limits(good).all()
    rows = np.nonzero(valid)[0]
    assert_reaches(kinematic_model, good, poses[rows])
    # completeness: the state the pose came from is one of the branches (modulo 2 pi per joint)
    difference = np.angle(np.exp(1j * (solutions - random_states[:, None, :])))
    found = np.where(valid, np.max(np.abs(np.nan_to_num(difference, nan=1.0)), axis=-1), np.inf) < 1e-5
    assert found.any(axis=1).all()


def test_eight_distinct_solutions_without_limit_restrictions(station):
    model = wide_limit_model(station)
    solver = URAnalyticIK(model, station.robot)
    pose = model.fk(np.array([0.4, -1.1, 1.3, -0.7, 0.9, 0.3]))
    solutions, valid = solver.solve_all(pose)
    assert valid.all()
    assert_reaches(model, solutions, np.repeat(pose[None], 8, axis=0))
    wrapped = np.round(np.angle(np.exp(1j * solutions)), 6)
    assert len({tuple(row) for row in wrapped}) == 8


def test_solutions_respect_narrow_joint_limits(station):
    model = wide_limit_model(station, lower=-1.0, upper=1.0)
    solver = URAnalyticIK(model, station.robot)
    states = np.random.default_rng(3).uniform(-1.0, 1.0, (300, 6))
    poses = model.fk_batch(states)
    solutions, valid = solver.solve_all(poses)
    assert valid.any(axis=1).all()
    assert (np.abs(solutions[valid]) <= 1.0).all()
    # the same poses solved with wide limits have branches that the narrow limits must have excluded
    _, valid_wide = URAnalyticIK(wide_limit_model(station), station.robot).solve_all(poses)
    assert valid_wide.sum() > valid.sum()


def test_unreachable_poses_have_no_solution(kinematic_model, ik):
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 1.0]
    solutions, valid = ik.solve_all(far)
    assert not valid.any() and np.isnan(solutions).all()
    assert ik.solve(far) is None
    q, ok = ik.solve_nearest(np.stack([far, kinematic_model.fk(np.array([0.3, -1.0, -1.2, 0.5, 1.0, 0.7]))]))
    assert ok.tolist() == [False, True]
    assert np.isnan(q[0]).all() and np.isfinite(q[1]).all()


def test_singular_and_limit_states_are_solved(station, kinematic_model, ik):
    states = [
        *station.named_states.values(),  # home: wrist singular (q5 = 0) and stretched elbow
        kinematic_model.upper.copy(),
        kinematic_model.lower.copy(),
    ]
    for q in states:
        pose = kinematic_model.fk(q)
        solution = ik.solve(pose, q)
        assert solution is not None
        assert_reaches(kinematic_model, solution, pose)
        assert kinematic_model.within_limits(solution)


def test_nearest_to_seed(kinematic_model, ik, random_states):
    poses = kinematic_model.fk_batch(random_states[:200])
    seeds = random_states[:200] + np.random.default_rng(5).normal(0.0, 1e-3, (200, 6))
    q, ok = ik.solve_nearest(poses, seeds)
    assert ok.all()
    np.testing.assert_allclose(q, random_states[:200], atol=1e-5)
    # among all solutions the returned one is the nearest in joint space
    solutions, valid = ik.solve_all(poses, seeds)
    distances = np.where(valid, np.linalg.norm(np.nan_to_num(solutions) - seeds[:, None], axis=-1), np.inf)
    np.testing.assert_allclose(np.linalg.norm(q - seeds, axis=1), distances.min(axis=1), atol=1e-9)


def test_wide_joints_take_the_2pi_representative_nearest_the_seed(kinematic_model, ik):
    q = np.array([2.5, -1.0, -1.2, 0.5, 1.0, -2.0])
    pose = kinematic_model.fk(q)
    seed = q.copy()
    seed[0], seed[5] = 5.0, 5.0  # 2.5 is nearer than 2.5 + 2 pi; -2 + 2 pi = 4.28 is nearer than -2
    np.testing.assert_allclose(ik.solve(pose, seed), [2.5, -1.0, -1.2, 0.5, 1.0, -2.0 + 2 * np.pi], atol=1e-6)
    seed[0], seed[5] = -5.0, -5.0
    np.testing.assert_allclose(ik.solve(pose, seed), [2.5 - 2 * np.pi, -1.0, -1.2, 0.5, 1.0, -2.0], atol=1e-6)


def test_nearest_representative_reports_joints_without_a_value_in_limits():
    lower, upper = np.array([-0.5, -6.283]), np.array([0.5, 6.283])
    shifted, ok = nearest_representative(np.array([[0.2, 3.0], [2.0, 0.0]]), np.array([0.0, -3.0]), lower, upper)
    assert ok.tolist() == [True, False]
    np.testing.assert_allclose(shifted[0], [0.2, 3.0 - 2 * np.pi])


def test_scanner_offset_and_robot_mounting_come_from_configuration(tmp_path, station):
    import yaml

    from agiprobot_measurement.station import CONFIG_DIR, PACKAGE_ROOT

    scanner = yaml.safe_load((CONFIG_DIR / "laser_scanner.yaml").read_text())
    scanner["mount"] = {"xyz_m": [0.03, -0.02, 0.2], "rpy_rad": [0.3, -0.2, 1.0]}
    scene = yaml.safe_load((CONFIG_DIR / "scene.yaml").read_text())
    scene["robot"] = {"base_xyz_m": [0.1, 0.2, 0.9], "base_rpy_rad": [0.0, 0.0, 0.7]}
    scene["part"]["mesh"] = str(PACKAGE_ROOT / scene["part"]["mesh"])
    (tmp_path / "laser_scanner.yaml").write_text(yaml.safe_dump(scanner))
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(scene))
    moved = Station.load(scanner=tmp_path / "laser_scanner.yaml", scene=tmp_path / "scene.yaml")
    solver = ik_for_station(moved)
    assert isinstance(solver, URAnalyticIK)
    states = np.random.default_rng(11).uniform(solver.model.lower, solver.model.upper, (200, 6))
    poses = solver.model.fk_batch(states)
    np.testing.assert_allclose(poses[0], independent_fk(moved, states[0]), atol=1e-9)
    q, ok = solver.solve_nearest(poses, states)
    assert ok.all()
    assert_reaches(solver.model, q, poses)


# -------------------------------------------------------------------------------------------- KDL
def test_kdl_success_rate_on_reachable_poses(kinematic_model, random_states):
    solver = KDLIK(kinematic_model, rng=0)
    poses = kinematic_model.fk_batch(random_states[:300])
    seeds = np.random.default_rng(8).uniform(kinematic_model.lower, kinematic_model.upper, (300, 6))
    q, ok = solver.solve_batch(poses, seeds)
    assert ok.mean() >= 0.99
    assert_reaches(kinematic_model, q[ok], poses[ok])
    assert kinematic_model.within_limits(q[ok]).all()


def test_kdl_from_a_near_seed_returns_that_branch(kinematic_model, random_states):
    solver = KDLIK(kinematic_model, max_restarts=0)
    q = solver.solve(kinematic_model.fk(random_states[0]), random_states[0] + 0.02)
    np.testing.assert_allclose(q, random_states[0], atol=1e-5)


def test_kdl_gives_up_on_unreachable_poses(kinematic_model):
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 1.0]
    solver = KDLIK(kinematic_model, max_restarts=3, rng=1)
    assert solver.solve(far) is None
    q, ok = solver.solve_batch(far[None])
    assert not ok[0] and np.isnan(q).all()


# ------------------------------------------------------------------------------------ solver choice
def test_factory_uses_closed_form_for_the_ur_chain_and_kdl_otherwise(station, kinematic_model):
    assert isinstance(make_ik_solver(kinematic_model, station.robot), URAnalyticIK)
    assert isinstance(ik_for_station(station, tip_frame="wrist_3_link"), URAnalyticIK)
    five_axis = ik_for_station(station, tip_frame="wrist_2_link", rng=0)
    assert isinstance(five_axis, KDLIK)
    q = np.array([0.3, -1.0, -1.2, 0.5, 1.0])
    pose = five_axis.model.fk(q)
    assert_reaches(five_axis.model, five_axis.solve(pose, q + 0.05), pose)


def test_dh_parameters_that_disagree_with_the_urdf_are_rejected(station, kinematic_model):
    # 3 cm: beyond what a calibrated arm may deviate (CALIBRATION_MAX_DEVIATION_M), so not a calibration
    wrong = dataclasses.replace(station.robot, d_m=station.robot.d_m + np.array([0, 0, 0, 0.03, 0, 0]))
    with pytest.raises(ConfigError, match="disagree with the URDF"):
        URAnalyticIK(kinematic_model, wrong)
    assert isinstance(make_ik_solver(kinematic_model, wrong), KDLIK)


# -------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("make_solver", [lambda m: URAnalyticIK(m), lambda m: KDLIK(m, max_restarts=0)])
def test_bad_input_gives_clear_errors(kinematic_model, make_solver):
    solver = make_solver(kinematic_model)
    pose = kinematic_model.fk(np.array([0.3, -1.0, -1.2, 0.5, 1.0, 0.7]))
    with pytest.raises(ValueError, match="expected 6 joint values"):
        solver.solve(pose, np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        solver.solve(pose, np.full(6, np.nan))
    nan_pose = pose.copy()
    nan_pose[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        solver.solve(nan_pose)
    with pytest.raises(ValueError, match="shape"):
        solver.solve(np.eye(3))
    with pytest.raises(ValueError, match="not rigid"):
        solver.solve(2.0 * pose)
    with pytest.raises(ValueError, match="3 seed states for 2 poses"):
        solver.solve_nearest(np.stack([pose, pose]), np.zeros((3, 6)))


def test_unknown_frame_is_named(station):
    with pytest.raises(ConfigError, match="unknown frame 'scanner_tip'"):
        ik_for_station(station, tip_frame="scanner_tip")


# ------------------------------------------------------------------------------ calibrated arm (kinematics file)
@pytest.fixture(scope="module")
def calibrated_ik():
    from agiprobot_measurement.station import CONFIG_DIR

    station = Station.load(kinematics=CONFIG_DIR / "my_robot_calibration.yaml")
    return ik_for_station(station)


def test_calibrated_arm_round_trip_to_sub_micrometre(calibrated_ik):
    solver = calibrated_ik
    assert isinstance(solver, URAnalyticIK)
    assert 1e-3 < solver.calibration_deviation[0] < 8e-3  # millimetres from the DH: not the nominal arm
    model = solver.model
    states = np.random.default_rng(21).uniform(model.lower, model.upper, (1000, 6))
    poses = model.fk_batch(states)
    q, ok = solver.solve_nearest(poses, states)
    assert ok.mean() > 0.995  # a few next to singular wrists and joint limits
    position, angle = pose_errors(model.fk_batch(q[ok]), poses[ok])
    assert position.max() < 1e-7 and angle.max() < 1e-7  # sub-micrometre on the calibrated chain
    assert np.median(position) < 1e-11
    assert model.within_limits(q[ok]).all()
    assert np.mean(np.abs(q[ok] - states[ok]).max(axis=1) < 1e-5) > 0.99  # the same state (not a self-motion twin)
    # the closed form alone (the nominal DH) would miss by millimetres: the refinement did the work
    nominal_position, _ = pose_errors(solver.nominal_fk(q[ok]), poses[ok])
    assert np.median(nominal_position) > 5e-4


def test_calibrated_arm_every_branch_is_exact(calibrated_ik):
    model = calibrated_ik.model
    pose = model.fk(np.array([0.4, -1.1, 1.3, -0.7, 0.9, 0.3]))
    solutions, valid = calibrated_ik.solve_all(pose)
    assert valid.sum() >= 2
    position, angle = pose_errors(model.fk_batch(solutions[valid]), pose[None])
    assert position.max() < 1e-9 and angle.max() < 1e-9


def test_calibrated_arm_single_solve_and_unreachable(calibrated_ik):
    model = calibrated_ik.model
    q0 = np.array([0.3, -1.0, -1.2, 0.5, 1.0, 0.7])
    q = calibrated_ik.solve(model.fk(q0), q0 + 0.01)
    assert q is not None and np.abs(q - q0).max() < 1e-6
    far = np.eye(4)
    far[:3, 3] = [5.0, 0.0, 1.0]
    assert calibrated_ik.solve(far) is None
