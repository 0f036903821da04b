"""The MILD's kinematic model: configuration, forward kinematics, both inverse kinematics, the PTU pose correction,
heuristics, movement costs and the map services (agiprobot_measurement.mild.robot_model)."""

import itertools
import math

import numpy as np
import pytest
import xacro
from scipy.spatial.transform import Rotation

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.config import (
    DEFAULTS,
    MildKinematics,
    RobotModelSettings,
    load_kinematics,
    load_settings,
    settings_from_mapping,
)
from agiprobot_measurement.mild.lp import solve_turn_lp, turn_split_closed_form
from agiprobot_measurement.mild.ratings import (
    RATING_BASE,
    path_heading_change,
    rating_angle_approximation,
    rating_navigation_path,
    rating_simple,
)
from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState, view_directions
from agiprobot_measurement.station import CONFIG_DIR, URDF_DIR, ConfigError, read_yaml
from agiprobot_measurement.station.urdf_model import UrdfModel

REAL = CONFIG_DIR / "mild_robot_model_services_real.yaml"
SIM = CONFIG_DIR / "mild_robot_model_services_sim.yaml"
UPSTREAM_PARAM = PACKAGE_ROOT / "packages" / "asr_robot_model_services" / "param"


def wide_pan_settings():
    """The simulation settings with the pan range widened to +-200 deg (what a user passes as settings:= for a PTU
    that turns further): the pose-correction tests need every direction reachable by the pan alone."""
    data = read_yaml(SIM)
    data.update(panMin=-200, panMax=200)
    return settings_from_mapping(data, "sim settings, pan +-200 deg")


@pytest.fixture(scope="module")
def real():
    return MildRobotModel.load(REAL)


@pytest.fixture(scope="module")
def sim():
    return MildRobotModel.load(SIM)


@pytest.fixture(scope="module")
def wide():
    return MildRobotModel.load(wide_pan_settings())


def _lateral_model(settings_path=REAL):
    """A MILD with lateral and forward offsets everywhere, so no formula may rely on a symmetric chain."""
    kin = load_kinematics()
    odd = MildKinematics(
        base_to_ptu_base_m=np.array([0.12, -0.05, 1.1]),
        ptu_base_to_pan_m=np.array([0.01, 0.02, 0.05]),
        pan_to_tilt_m=np.array([0.03, 0.04, 0.07]),
        tilt_to_mount_m=np.array([0.05, -0.03, 0.09]),
        camera_baseline_m=0.1,
        frames=kin.frames,
    )
    settings = settings_path if isinstance(settings_path, RobotModelSettings) else load_settings(settings_path)
    return MildRobotModel(odd, settings, None)


def random_states(model, n, rng, area=((0.5, 4.0), (0.5, 4.0))):
    lo, hi = model.pan_limits
    tlo, thi = model.tilt_limits
    return np.stack(
        [
            rng.uniform(lo, hi, n),
            rng.uniform(tlo, thi, n),
            rng.uniform(0.0, 2.0 * np.pi, n),
            rng.uniform(*area[0], n),
            rng.uniform(*area[1], n),
        ],
        -1,
    )


def poses_of(model, states):
    poses = model.camera_poses(states)
    return poses[:, :3, 3], Rotation.from_matrix(poses[:, :3, :3]).as_quat()


def view_centres(model, states):
    poses = model.camera_poses(states)
    return poses[:, :3, 3] + model.settings.view_distance_m * poses[:, :3, 0]


# ------------------------------------------------------------------------------------------------ configuration
def test_real_settings_are_the_reference_parameter_set():
    s = load_settings(REAL)
    assert s.robot_model_id == 1
    np.testing.assert_allclose(np.degrees(s.pan_limits_rad), [-20, 20])
    np.testing.assert_allclose(np.degrees(s.tilt_limits_rad), [-45, 25])
    assert (s.sigma_m, s.col_thresh, s.omega_pan, s.omega_tilt, s.omega_rot, s.omega_base) == (2.0, 40, 1, 1, 10, 135)
    assert (s.tolerance_m, s.pan_sampling_steps, s.ik_iteration_accuracy) == (0.00003, 3, 0.01)
    assert (s.ik_angle_rating, s.visualize_ik, s.use_global_planner) == ("ANGLE_APPROXIMATION", False, False)
    assert (s.ncp_m, s.fcp_m, s.view_distance_m) == (0.4, 1.5, 0.95)
    assert s.warnings == ()


def test_sim_settings_are_the_originals_simulation_set():
    s = load_settings(SIM)
    np.testing.assert_allclose(np.degrees(s.pan_limits_rad), [-20, 20])
    np.testing.assert_allclose(np.degrees(s.tilt_limits_rad), [-45, 25])
    assert (s.pan_sampling_steps, s.ik_iteration_accuracy, s.visualize_ik) == (20, 0.005, True)
    assert s.debug_levels == frozenset()


def _upstream_node_params(kind: str) -> dict:
    """What the original's RobotModelService<kind>.launch loads into the node: settings, topics, frames, costmap."""
    params = {}
    for name in (f"robot_model_services_settings_{kind}.yaml", "TopicsConfig.yaml", "robot_model_frames.yaml",
                 "costmap_params.yaml"):  # fmt: skip
        params.update(read_yaml(UPSTREAM_PARAM / name))
    return params


@pytest.mark.parametrize(("kind", "config"), [("sim", SIM), ("real", REAL)])
def test_config_files_agree_with_the_upstream_param_files(kind, config):
    """config/mild_robot_model_services_<kind>.yaml and the asr_robot_model_services param/ files the launch files
    load give the same settings (one definition, two file layouts)."""
    ours = load_settings(config)
    theirs = settings_from_mapping(_upstream_node_params(kind), f"param/ ({kind})")
    assert theirs.warnings == ()
    assert theirs.defaulted == ()
    for field in ("robot_model_id", "pan_limits_rad", "tilt_limits_rad", "sigma_m", "col_thresh", "omega_pan",
                  "omega_tilt", "omega_rot", "omega_base", "tolerance_m", "use_global_planner", "ncp_m", "fcp_m",
                  "visualize_ik", "ik_angle_rating", "pan_sampling_steps", "ik_iteration_accuracy", "debug_levels",
                  "inscribed_radius_m", "inflation_radius_m", "cost_scaling_per_m",
                  "ik_visualization_topic"):  # fmt: skip
        assert (
            getattr(ours, field) == pytest.approx(getattr(theirs, field))
            if isinstance(getattr(ours, field), float)
            else getattr(ours, field) == getattr(theirs, field)
        ), field
    assert theirs.inflation_radius_m == 0.65  # costmap_params.yaml
    assert (theirs.inscribed_radius_m, theirs.cost_scaling_per_m) == (0.46, 10.0)  # costmap_2d's defaults


def test_no_parameters_give_the_originals_defaults():
    s = settings_from_mapping({}, "no parameters")
    assert s.robot_model_id == 1
    np.testing.assert_allclose(np.degrees(s.pan_limits_rad), [-60, 60])
    np.testing.assert_allclose(np.degrees(s.tilt_limits_rad), [-45, 45])
    assert s.col_thresh == 40
    assert s.debug_levels == frozenset({"PARAMETERS", "RATING", "ROBOT_MODEL", "MAP", "IK_RATING"})  # none = ALL
    assert s.ik_angle_rating == "SIMPLE"  # the original's fallback for a name it does not know, "" included
    assert len(s.warnings) == 1 and "IKAngleRating is not set" in s.warnings[0]
    assert set(s.defaulted) == set(DEFAULTS)
    # the keys the original reads without a default take its real settings file's values
    real = settings_from_mapping(read_yaml(UPSTREAM_PARAM / "robot_model_services_settings_real.yaml"), "real")
    for field in ("sigma_m", "omega_pan", "omega_tilt", "omega_rot", "omega_base", "tolerance_m", "ncp_m", "fcp_m",
                  "use_global_planner", "visualize_ik", "pan_sampling_steps", "ik_iteration_accuracy"):  # fmt: skip
        assert getattr(s, field) == getattr(real, field), field
    assert (s.inscribed_radius_m, s.inflation_radius_m, s.cost_scaling_per_m) == (0.46, 0.55, 10.0)
    model = MildRobotModel(load_kinematics(), s, None)  # and it works
    assert model.camera_pose(RobotState(math.radians(59.0)))[1, 0] > 0.8


def test_absent_keys_default_one_by_one_and_present_keys_are_kept():
    data = read_yaml(REAL)
    del data["panMax"], data["mSigma"]
    s = settings_from_mapping(data, "partial")
    assert s.defaulted == ("panMax", "mSigma")
    assert math.degrees(s.pan_limits_rad[1]) == pytest.approx(60.0)  # the original's default, not the file's 20
    assert math.degrees(s.pan_limits_rad[0]) == pytest.approx(-20.0)
    assert s.sigma_m == 2.0


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"debugLevels": ["PARAMETERS", "LOUD"]}, ["invalid debug level 'LOUD'", "debugLevels"]),
        ({"debugLevels": 3}, ["debugLevels", "list"]),
        ({"speedFactorPTU": 0}, ["speedFactorPTU", "positive"]),
        ({"speedFactorBaseRot": "fast"}, ["speedFactorBaseRot", "number"]),
        ({"global_costmap": {"inflation_layer": {"inflation_radius": "wide"}}}, ["inflation_radius", "number"]),
        ({"global_costmap": {"robot_radius": 0.9}}, ["inscribed radius", "inflation radius"]),
        ({"global_costmap": [1, 2]}, ["global_costmap", "mapping"]),
        ({"IKVisualization": 5}, ["IKVisualization"]),
        ({"robotModelId": "1"}, ["robotModelId"]),
        ({"panMin": "left"}, ["'panMin'", "number"]),
    ],
)
def test_present_but_wrong_values_are_still_errors(changes, words):
    data = {}  # on top of nothing: absent keys default, the given one must be right
    data.update(changes)
    with pytest.raises(ConfigError) as info:
        settings_from_mapping(data, "the node's parameters")
    assert "the node's parameters" in str(info.value)
    for word in words:
        assert word in str(info.value)


def test_debug_levels_and_speed_factors_are_read_as_the_original_does():
    assert settings_from_mapping({"debugLevels": ["NONE"]}, "x").debug_levels == frozenset()
    assert settings_from_mapping({"debugLevels": ["ALL"]}, "x").debug("MAP")
    assert settings_from_mapping({"debugLevels": []}, "x").debug("RATING")  # empty = ALL
    some = settings_from_mapping({"debugLevels": ["MAP", "RATING"]}, "x")
    assert some.debug("MAP") and some.debug("RATING") and not some.debug("PARAMETERS")
    assert settings_from_mapping({"debugLevels": "[map, ik_rating]"}, "x").debug_levels == {"MAP", "IK_RATING"}
    s = settings_from_mapping({"speedFactorPTU": 2.0, "speedFactorBaseMove": 0.5}, "x")
    assert s.speed_factors == (2.0, 0.5, None)
    # the original uses the speed factors in no answer: movement costs are the same with and without them
    plain = MildRobotModel(load_kinematics(), settings_from_mapping({}, "x"), None)
    scaled = MildRobotModel(load_kinematics(), s, None)
    a, b = RobotState(0.1, 0.2, 0.3, 1.0, 1.0), RobotState(-0.4, 0.1, 2.0, 3.0, 2.0)
    assert plain.movement_costs(a, b) == scaled.movement_costs(a, b)


def test_costmap_parameters_of_the_original_set_the_inflation():
    s = settings_from_mapping(
        {
            "global_costmap": {
                "robot_radius": 0.3,
                "inflation_layer": {"inflation_radius": 0.8, "cost_scaling_factor": 4},
            }
        },
        "costmap",
    )
    assert (s.inscribed_radius_m, s.inflation_radius_m, s.cost_scaling_per_m) == (0.3, 0.8, 4.0)
    old_style = settings_from_mapping({"global_costmap": {"inflation_radius": 0.7}}, "costmap")
    assert old_style.inflation_radius_m == 0.7
    # the package's own keys (units in the name) win over the costmap's
    both = settings_from_mapping({"inflationRadius_m": 0.9, "global_costmap": {"inflation_radius": 0.7}}, "both")
    assert both.inflation_radius_m == 0.9


def test_unknown_rating_warns_and_falls_back_to_simple():
    data = read_yaml(REAL)
    data["IKAngleRating"] = "SHORTEST_DETOUR"
    s = settings_from_mapping(data, "test")
    assert s.ik_angle_rating == "SIMPLE"
    assert len(s.warnings) == 1 and "SHORTEST_DETOUR" in s.warnings[0] and "SIMPLE" in s.warnings[0]


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("robotModelId", 3, ["robotModelId", "not a valid robot model id"]),
        ("panMin", 30, ["panMin", "panMax"]),
        ("ncp", "near", ["'ncp'", "number"]),
        ("useGlobalPlanner", "sometimes", ["useGlobalPlanner"]),
        ("colThresh", 140, ["colThresh"]),
    ],
)
def test_bad_settings_name_the_source_and_key(key, value, words):
    data = read_yaml(REAL)
    data[key] = value
    with pytest.raises(ConfigError) as info:
        settings_from_mapping(data, "my_settings.yaml")
    assert "my_settings.yaml" in str(info.value)
    for word in words:
        assert word in str(info.value)


def test_settings_file_error_names_the_file_and_key(tmp_path):
    data = read_yaml(REAL)
    data["mSigma"] = "wide"
    path = tmp_path / "settings.yaml"
    path.write_text("\n".join(f"{k}: {v}" for k, v in data.items()))
    with pytest.raises(ConfigError, match=r"settings\.yaml: 'mSigma': expected a number"):
        load_settings(path)


def test_kinematics_file_error_names_the_key(tmp_path):
    path = tmp_path / "kin.yaml"
    path.write_text((CONFIG_DIR / "mild_kinematics.yaml").read_text().replace("pan_to_tilt_xyz_m", "pan_to_tilt"))
    with pytest.raises(ConfigError, match=r"kin\.yaml: missing key 'pan_to_tilt_xyz_m'"):
        load_kinematics(path)


# ------------------------------------------------------------------------------------------------ forward kinematics
def test_frames_have_the_reference_names(real):
    names = set(real.frame_poses(RobotState()))
    assert names == {
        "map",
        "base_link",
        "ptu_base_link",
        "ptu_pan_link",
        "ptu_pan_link_rotated",
        "ptu_tilt_link",
        "ptu_tilted_link",
        "ptu_mount_link",
        "camera_left_frame",
        "camera_right_frame",
    }


def test_urdf_matches_the_kinematic_model(real):
    """The tf tree (URDF from the xacro) and the core's FK agree for random joint values."""
    urdf = UrdfModel(xacro.process_file(str(URDF_DIR / "mild.urdf.xacro")).toprettyxml())
    rng = np.random.default_rng(3)
    for values in random_states(real, 5, rng):
        state = RobotState.from_array(values)
        joints = {real.kinematics.pan_joint: state.pan, real.kinematics.tilt_joint: state.tilt}
        expected = real.frame_poses(state)
        for frame in ("ptu_tilted_link", "ptu_mount_link", "camera_left_frame", "camera_right_frame"):
            pose = expected["base_link"].copy()
            for joint in urdf.chain("base_link", frame):
                pose = pose @ joint.origin
                if joint.type == "revolute":
                    rotation = np.eye(4)
                    rotation[:3, :3] = Rotation.from_rotvec(joint.axis * joints[joint.name]).as_matrix()
                    pose = pose @ rotation
            np.testing.assert_allclose(pose, expected[frame], atol=1e-9, err_msg=frame)


def test_vectorised_fk_matches_the_frame_chain():
    model = _lateral_model()
    states = random_states(model, 50, np.random.default_rng(4))
    batch = model.camera_poses(states)
    for values, pose in zip(states, batch, strict=True):
        np.testing.assert_allclose(pose, model.frame_poses(RobotState.from_array(values))["ptu_mount_link"], atol=1e-12)


def test_joint_directions(real):
    zero = real.camera_pose(RobotState())
    np.testing.assert_allclose(zero[:3, 0], [1, 0, 0], atol=1e-12)
    assert real.camera_pose(RobotState(tilt=0.3))[2, 0] > 0.29, "positive tilt must raise the view"
    assert real.camera_pose(RobotState(pan=0.3))[1, 0] > 0.29, "positive pan must turn the view left"
    left = real.frame_poses(RobotState())["camera_left_frame"]
    right = real.frame_poses(RobotState())["camera_right_frame"]
    np.testing.assert_allclose(left[:3, 2], [1, 0, 0], atol=1e-12)  # optical z along the view
    np.testing.assert_allclose(left[:3, 3] - right[:3, 3], [0, real.kinematics.camera_baseline_m, 0], atol=1e-12)


# ------------------------------------------------------------------------------------------------ exact IK
@pytest.mark.parametrize("settings", [REAL, SIM])
def test_exact_ik_round_trip(settings):
    """Camera poses of random states within the limits: the IK state's camera faces the same view centre from the
    same distance along the same view axis (they are reachable, so no deviation)."""
    for model in (MildRobotModel.load(settings), _lateral_model(settings)):
        rng = np.random.default_rng(5)
        states = random_states(model, 400, rng)
        positions, quaternions = poses_of(model, states)
        source = RobotState(0.05, 0.0, 1.0, 2.0, 2.0)
        batch = model.exact_ik_batch(source, positions, quaternions)
        assert batch.ok.all()
        assert not batch.tilt_clamped.any()
        assert np.degrees(batch.angle_deviation_rad).max() < 0.5
        achieved = model.camera_poses(batch.states)
        np.testing.assert_allclose(view_centres(model, batch.states), view_centres(model, states), atol=1e-9)
        distance = np.linalg.norm(view_centres(model, states) - achieved[:, :3, 3], axis=1)
        np.testing.assert_allclose(distance, model.settings.view_distance_m, atol=1e-9)
        np.testing.assert_allclose(achieved[:, :3, 0], model.camera_poses(states)[:, :3, 0], atol=1e-6)
        lo, hi = model.pan_limits
        assert np.all((batch.states[:, 0] >= lo) & (batch.states[:, 0] <= hi))


def test_exact_ik_single_equals_batch_and_reports_the_solution(real):
    rng = np.random.default_rng(6)
    states = random_states(real, 20, rng)
    positions, quaternions = poses_of(real, states)
    source = RobotState(0.0, 0.0, 0.3, 1.0, 1.0)
    batch = real.exact_ik_batch(source, positions, quaternions)
    for i in range(20):
        solution = real.calculate_robot_state(source, positions[i], quaternions[i])
        assert solution.ok, solution.reason
        np.testing.assert_allclose(solution.state.as_array(), batch.states[i], atol=1e-12)
        np.testing.assert_allclose(solution.camera_pose, real.camera_pose(solution.state), atol=1e-12)
        np.testing.assert_allclose(solution.achieved_view_centre_m, solution.requested_view_centre_m, atol=1e-9)
        assert 0.0 <= solution.state.rotation < 2 * np.pi


def test_unreachable_requests_still_face_the_centre_with_least_deviation(real):
    """Random requested views (not from FK): the IK matches the view's azimuth exactly and faces the centre from the
    viewing distance; the deviation is only in elevation, forced by the tilt axis' height."""
    rng = np.random.default_rng(7)
    n = 300
    positions = np.column_stack([rng.uniform(0, 4, n), rng.uniform(0, 4, n), rng.uniform(0.8, 1.8, n)])
    quaternions = Rotation.from_euler("zyx", np.column_stack([rng.uniform(-np.pi, np.pi, n),
                                                              rng.uniform(-0.6, 0.4, n), np.zeros(n)])).as_quat()  # fmt: skip
    batch = real.exact_ik_batch(RobotState(), positions, quaternions)
    views = view_directions(quaternions)
    achieved = real.camera_poses(batch.states[batch.ok])[:, :3, 0]
    np.testing.assert_allclose(
        wrap_to_pi(np.arctan2(achieved[:, 1], achieved[:, 0]) - np.arctan2(views[batch.ok, 1], views[batch.ok, 0])),
        0.0,
        atol=1e-9,
    )
    np.testing.assert_allclose(
        batch.angle_deviation_rad[batch.ok],
        np.abs(np.arcsin(achieved[:, 2]) - np.arcsin(views[batch.ok, 2])),
        atol=1e-9,
    )
    free = batch.ok & ~batch.tilt_clamped
    assert free.sum() > 100
    np.testing.assert_allclose(view_centres(real, batch.states[free]), batch.view_centres_m[free], atol=1e-9)


@pytest.mark.parametrize("height", [3.5, -1.0])
def test_view_centre_too_far_above_or_below_has_no_solution(real, height):
    low, high = real.view_centre_height_range_m()
    assert not low < height < high
    d = real.settings.view_distance_m
    position = np.array([2.0 - d, 2.0, height])  # looking along +x: the centre is at (2, 2, height)
    solution = real.calculate_robot_state(RobotState(), position, [0, 0, 0, 1])
    assert not solution.ok and solution.state is None
    assert ("above" if height > high else "below") in solution.reason
    assert not real.exact_ik_batch(RobotState(), position[None], np.array([[0, 0, 0, 1.0]])).ok[0]


def test_tilt_beyond_its_limit_is_clamped_and_faces_the_point_above(real):
    _, high = real.view_centre_height_range_m()
    centre = np.array([2.0, 2.0, high - 0.05])  # reachable in height, but only with a tilt far above 25 deg
    position = centre - np.array([real.settings.view_distance_m, 0, 0])
    solution = real.calculate_robot_state(RobotState(), position, [0, 0, 0, 1])
    assert solution.ok and solution.tilt_clamped
    assert solution.state.tilt == pytest.approx(real.tilt_limits[1])
    np.testing.assert_allclose(solution.achieved_view_centre_m[:2], centre[:2], atol=1e-9)
    assert solution.achieved_view_centre_m[2] < centre[2]
    assert "clamped" in solution.reason


def _dense_best_rating(model, source, position, quaternion):
    """Best heuristic rating over 4001 pans: what the sampling should come close to."""
    views = view_directions(np.asarray(quaternion)[None])
    heading, _, pan_xy, *_ = model._exact_geometry(np.asarray(position)[None], views)
    pans = np.linspace(*model.pan_limits, 4001)[None]
    bx, by, rotation = model._base_poses(heading, pan_xy, pans)
    return model.rate_base_poses(source, np.stack([bx, by], -1), rotation).max()


@pytest.mark.parametrize("rating", ["SIMPLE", "ANGLE_APPROXIMATION"])
@pytest.mark.parametrize("settings", [REAL, SIM])
def test_pan_sampling_finds_the_best_rated_base_pose(rating, settings):
    model = MildRobotModel(load_kinematics(), load_settings(settings).with_changes(ik_angle_rating=rating), None)
    rng = np.random.default_rng(8)
    states = random_states(model, 40, rng)
    positions, quaternions = poses_of(model, states)
    source = RobotState(0.0, 0.0, 0.7, 2.0, 2.0)
    gaps = []
    for p, q in zip(positions, quaternions, strict=True):
        solution = model.calculate_robot_state(source, p, q)
        got = model.rate_base_poses(source, np.array([solution.state.x, solution.state.y]), solution.state.rotation)
        gaps.append(_dense_best_rating(model, source, p, q) - got)
    # the refinement stops once the best rating changes by less than the accuracy; a few of those steps remain
    assert max(gaps) < 4 * model.settings.ik_iteration_accuracy, max(gaps)
    assert np.median(gaps) < model.settings.ik_iteration_accuracy


def test_simple_rating_prefers_the_pan_that_saves_base_rotation(real):
    """With SIMPLE the base keeps its heading when the pan can absorb the turn (|turn| <= pan limit)."""
    model = MildRobotModel(load_kinematics(), real.settings.with_changes(ik_angle_rating="SIMPLE"), None)
    source = RobotState(0.0, 0.0, 0.0, 0.0, 0.0)
    for azimuth_deg in (-15.0, 10.0):
        q = Rotation.from_euler("z", azimuth_deg, degrees=True).as_quat()
        solution = model.calculate_robot_state(source, [2.0, 1.0, 1.3], q)
        assert abs(wrap_to_pi(solution.state.rotation)) < math.radians(1.5)
        assert solution.state.pan == pytest.approx(math.radians(azimuth_deg), abs=math.radians(1.5))


# ------------------------------------------------------------------------------------------------ approximated IK
@pytest.mark.parametrize("weights", [(1.0, 10.0), (10.0, 1.0), (3.0, 3.0)])
def test_turn_lp_solvers_agree_on_the_optimum(weights):
    rng = np.random.default_rng(9)
    w_pan, w_rot = weights
    for _ in range(60):
        alpha = rng.uniform(-np.pi, np.pi)
        up, down = rng.uniform(0, 1.5, 2)
        splits = {s: solve_turn_lp(alpha, up, down, w_pan, w_rot, s) for s in ("glpk", "highs", "closed_form")}
        costs = {s: w_pan * abs(p) + w_rot * abs(r) for s, (p, r) in splits.items()}
        for solver, (pan, rot) in splits.items():
            assert pan + rot == pytest.approx(alpha, abs=1e-9), solver
            assert -down - 1e-9 <= pan <= up + 1e-9, solver
            assert abs(rot) <= np.pi + 1e-9, solver
            assert costs[solver] == pytest.approx(costs["glpk"], abs=1e-9), solver


def test_turn_lp_uses_the_cheaper_pan_first():
    pan, rot = solve_turn_lp(1.0, 0.3, 0.4, 1.0, 10.0)  # pan can turn 0.3 up, the rest is rotation
    assert (pan, rot) == pytest.approx((0.3, 0.7))
    pan, rot = solve_turn_lp(-0.2, 0.3, 0.4, 1.0, 10.0)  # within the pan's room: no rotation
    assert (pan, rot) == pytest.approx((-0.2, 0.0))
    pan, rot = solve_turn_lp(1.0, 0.3, 0.4, 10.0, 1.0)  # rotation cheaper: pan stays
    assert (pan, rot) == pytest.approx((0.0, 1.0))


@pytest.mark.parametrize("solver", ["glpk", "highs", "closed_form"])
def test_approximated_ik_follows_the_lp(real, solver):
    model = MildRobotModel(real.kinematics, real.settings.with_changes(robot_model_id=2, lp_solver=solver), None)
    rng = np.random.default_rng(10)
    lo, hi = model.pan_limits
    for _ in range(50):
        source = RobotState(rng.uniform(lo, hi), 0.0, rng.uniform(0, 2 * np.pi), 1.0, 1.0)
        azimuth, elevation = rng.uniform(-np.pi, np.pi), rng.uniform(-0.7, 0.4)
        q = Rotation.from_euler("ZY", [azimuth, -elevation]).as_quat()
        position = rng.uniform(0, 4, 3)
        state = model.calculate_robot_state(source, position, q).state
        assert wrap_to_pi(state.pan + state.rotation - azimuth) == pytest.approx(0.0, abs=1e-9)
        assert state.tilt == pytest.approx(np.clip(elevation, *model.tilt_limits), abs=1e-9)
        assert (state.x, state.y) == pytest.approx((position[0], position[1]))
        alpha = wrap_to_pi(azimuth - source.pan - source.rotation)
        expected_pan, _ = turn_split_closed_form(alpha, hi - source.pan, source.pan - lo, 1.0, 10.0)
        assert state.pan - source.pan == pytest.approx(float(expected_pan), abs=1e-9)
        batch = model.approximated_ik_batch(source, position[None], q[None])
        np.testing.assert_allclose(batch.states[0], state.as_array(), atol=1e-9)


# ------------------------------------------------------------------------------------------------ heuristics
def test_simple_rating_ranks_by_the_heading_change():
    targets = np.radians([0.0, 30.0, -60.0, 179.0, 181.0])
    ratings = rating_simple(0.0, targets)
    np.testing.assert_allclose(ratings, RATING_BASE ** np.abs(np.radians([0, 30, 60, 179, 179])))
    assert ratings[0] > ratings[1] > ratings[2] > ratings[3]
    assert ratings[3] == pytest.approx(ratings[4])  # 179 deg either way round


def test_angle_approximation_counts_the_turns_via_the_straight_line():
    source_xy, source_rot = np.array([0.0, 0.0]), 0.0
    ahead = rating_angle_approximation(source_xy, [2.0, 0.0], source_rot, 0.0)  # drive straight on
    aside_same = rating_angle_approximation(source_xy, [0.0, 2.0], source_rot, 0.0)  # left, then back: 90 + 90
    aside_facing = rating_angle_approximation(source_xy, [0.0, 2.0], source_rot, np.pi / 2)  # left: 90
    in_place = rating_angle_approximation(source_xy, [0.0, 0.0], source_rot, np.pi / 2)
    assert ahead == pytest.approx(1.0)
    assert aside_same == pytest.approx(RATING_BASE**np.pi)
    assert aside_facing == pytest.approx(RATING_BASE ** (np.pi / 2))
    assert in_place == pytest.approx(RATING_BASE ** (np.pi / 2))
    assert ahead > aside_facing > aside_same


def test_navigation_path_sums_the_heading_changes():
    straight = np.array([[0.0, 0.0], [2.0, 0.0]])
    detour = np.array([[0.0, 0.0], [0.0, 1.0], [2.0, 1.0], [2.0, 0.0]])
    assert path_heading_change(straight, 0.0, 0.0) == pytest.approx(0.0)
    assert path_heading_change(detour, 0.0, 0.0) == pytest.approx(2 * np.pi)  # 90 + 90 + 90 + 90
    assert rating_navigation_path(straight, 0.0, 0.0) > rating_navigation_path(detour, 0.0, 0.0)
    assert rating_navigation_path(None, 0.0, 0.0) == 0.0
    # a straight path rates as ANGLE_APPROXIMATION does
    assert rating_navigation_path(straight, 0.4, -0.3) == pytest.approx(
        rating_angle_approximation([0, 0], [2, 0], 0.4, -0.3)
    )


def test_navigation_path_rating_on_the_map(real):
    model = MildRobotModel(real.kinematics, real.settings.with_changes(ik_angle_rating="NAVIGATION_PATH"), real.map)
    source = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    free = model.rate_base_poses(source, np.array([[3.0, 1.0]]), np.array([0.0]))[0]
    behind_wall = model.rate_base_poses(source, np.array([[7.0, 1.0]]), np.array([0.0]))[0]
    enclosed = model.rate_base_poses(source, np.array([[8.0, 3.0]]), np.array([0.0]))[0]
    occupied = model.rate_base_poses(source, np.array([[2.5, 4.5]]), np.array([0.0]))[0]
    assert free == pytest.approx(1.0, abs=1e-6)
    assert 0.0 < behind_wall < 0.5 * free
    assert enclosed == 0.0 and occupied == 0.0
    # the exact IK with this heuristic still solves
    q = Rotation.from_euler("z", 0.5).as_quat()
    assert model.calculate_robot_state(source, [2.5, 2.0, 1.4], q).ok


# ------------------------------------------------------------------------------------------------ pose correction
def _aim_error_deg(model, state, centre):
    pose = model.camera_pose(state)
    to_centre = centre - pose[:3, 3]
    return math.degrees(math.acos(np.clip(pose[:3, 0] @ to_centre / np.linalg.norm(to_centre), -1, 1)))


@pytest.mark.parametrize("lateral", [False, True])
def test_pose_correction_aims_at_the_centre_within_the_limits(real, lateral):
    wide = wide_pan_settings()
    model = _lateral_model(wide) if lateral else MildRobotModel.load(wide, map_file=False)
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(300):
        base = RobotState(0.0, 0.0, rng.uniform(0, 2 * np.pi), rng.uniform(0, 4), rng.uniform(0, 4))
        centre = np.array([*(np.array([base.x, base.y]) + rng.uniform(-3, 3, 2)), rng.uniform(0.5, 2.0)])
        position = centre - np.array([model.settings.view_distance_m, 0, 0])
        correction = model.camera_pose_correction(base, position, [0, 0, 0, 1])
        np.testing.assert_allclose(correction.view_centre_m, centre)
        if correction.pan_clamped or correction.tilt_clamped or np.linalg.norm(centre[:2] - [base.x, base.y]) < 0.6:
            continue
        state = RobotState(correction.pan, correction.tilt, base.rotation, base.x, base.y)
        assert _aim_error_deg(model, state, centre) < 0.1
        checked += 1
    assert checked > 150


def test_pose_correction_clamps_to_the_limits(real):
    base = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    d = real.settings.view_distance_m
    behind = real.camera_pose_correction(base, [-2.0 - d, 1.0, 1.3], [0, 0, 0, 1])  # centre behind the robot
    assert behind.pan_clamped and min(abs(behind.pan - limit) for limit in real.pan_limits) < 1e-12
    above = real.camera_pose_correction(base, [2.5 - d, 1.0, 6.0], [0, 0, 0, 1])  # centre far above
    assert above.tilt_clamped and above.tilt == pytest.approx(real.tilt_limits[1])
    below = real.camera_pose_correction(base, [1.6 - d, 1.0, -1.0], [0, 0, 0, 1])  # centre steeply below
    assert below.tilt_clamped and below.tilt == pytest.approx(real.tilt_limits[0])
    assert "clamped" in above.reason and "clamped" in behind.reason


def test_pose_correction_takes_the_pan_closest_to_the_current_one(wide):
    """With +-200 deg the pan has two representations near 180 deg: keep the one nearer the current pan."""
    d = wide.settings.view_distance_m
    behind = [-2.0 - d, 1.0, 1.3]
    from_left = wide.camera_pose_correction(RobotState(pan=3.0, x=1.0, y=1.0), behind, [0, 0, 0, 1])
    from_right = wide.camera_pose_correction(RobotState(pan=-3.0, x=1.0, y=1.0), behind, [0, 0, 0, 1])
    assert from_left.pan > 0 > from_right.pan
    assert wrap_to_pi(from_left.pan - from_right.pan) == pytest.approx(0.0, abs=1e-9)


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("position", "orientation", "words"),
    [
        ([np.nan, 0, 1], [0, 0, 0, 1], ["position", "not finite"]),
        ([0, 0, 1], [0, 0, 0, 0], ["zero quaternion"]),
        ([0, 0, 1], [0, np.inf, 0, 1], ["orientation", "not finite"]),
    ],
)
def test_bad_requests_raise_clear_errors(real, position, orientation, words):
    for call in (
        lambda: real.calculate_robot_state(RobotState(), position, orientation),
        lambda: real.camera_pose_correction(RobotState(), position, orientation),
    ):
        with pytest.raises(ValueError) as info:
            call()
        for word in words:
            assert word in str(info.value)
    with pytest.raises(ValueError, match="tilt"):
        real.calculate_robot_state(RobotState(tilt=np.nan), [0, 0, 1], [0, 0, 0, 1])


@pytest.mark.parametrize(
    ("state", "words"),
    [
        (RobotState(1e12, 0.0, 0.0, 1.0, 1.0), ["sourceRobotState: pan", "deg outside [-20.0, 20.0] deg", "1e+12 rad"]),
        (RobotState(math.radians(20.5), 0.0, 0.0, 1.0, 1.0), ["pan 20.50 deg outside [-20.0, 20.0] deg"]),
        (RobotState(0.0, math.radians(-46), 0.0, 1.0, 1.0), ["tilt -46.00 deg outside [-45.0, 25.0] deg"]),
        (RobotState(0.0, np.nan, 0.0, 1.0, 1.0), ["tilt = nan is not finite"]),
        (RobotState(0.0, 0.0, -np.inf, 1.0, 1.0), ["rotation = -inf is not finite"]),
        (RobotState(0.0, 0.0, 1e12, 1.0, 1.0), ["rotation = 1e+12 rad lies beyond"]),
        (RobotState(0.0, 0.0, 0.0, 1.0, -1e300), ["y = -1e+300 m lies beyond"]),
    ],
)
def test_states_the_mild_cannot_take_are_refused_by_every_service(real, state, words):
    """As mild_sim/set_state: pan and tilt outside the settings' PTU limits, non-finite and absurd values."""
    for model_id in (1, 2):
        model = MildRobotModel(real.kinematics, real.settings.with_changes(robot_model_id=model_id), real.map)
        for call in (
            lambda m=model: m.calculate_camera_pose(state),
            lambda m=model: m.camera_pose_correction(state, [2, 2, 1.3], [0, 0, 0, 1]),
            lambda m=model: m.calculate_robot_state(state, [2, 2, 1.3], [0, 0, 0, 1]),
        ):
            with pytest.raises(InputError) as info:
                call()
            for word in words:
                assert word in str(info.value)


def test_states_at_the_limits_are_taken(real):
    (plo, phi), (tlo, thi) = real.pan_limits, real.tilt_limits
    for state in (RobotState(plo, tlo, -math.pi, 1.0, 1.0), RobotState(phi + 1e-10, thi, 7.0, 1.0, 1.0)):
        assert real.check_state(state) is state
        np.testing.assert_allclose(real.calculate_camera_pose(state), real.camera_pose(state))
        assert real.calculate_robot_state(state, [2, 2, 1.3], [0, 0, 0, 1]).ok


@pytest.mark.parametrize(
    ("position", "orientation", "words"),
    [
        ([1e12, 0, 1], [0, 0, 0, 1], ["position", "beyond +-10000 m"]),
        ([0, -1e300, 1], [0, 0, 0, 1], ["position", "beyond"]),
        ([0, 0, 1], [1e308, 1e308, 1e308, 1e308], ["orientation", "too large to normalise"]),
    ],
)
def test_absurd_requested_poses_are_refused(real, position, orientation, words):
    for call in (
        lambda: real.calculate_robot_state(RobotState(), position, orientation),
        lambda: real.camera_pose_correction(RobotState(), position, orientation),
    ):
        with pytest.raises(InputError) as info:
            call()
        for word in words:
            assert word in str(info.value)


def test_absurd_positions_are_refused_by_get_distance_and_is_position_allowed(real):
    with pytest.raises(InputError, match=r"targetPosition.*beyond"):
        real.get_distance([0, 0], [1e300, 0])
    with pytest.raises(InputError, match=r"sourcePosition.*beyond"):
        real.get_distance([-1e5, 0], [1, 1])
    with pytest.raises(InputError, match="beyond"):
        real.is_position_allowed([0.0, 1e12, 0.0])


def test_huge_quaternion_components_are_only_normalised(real):
    a = real.calculate_robot_state(RobotState(), [1, 1, 1.2], [0, 0, 3e300, 9e300])
    b = real.calculate_robot_state(RobotState(), [1, 1, 1.2], [0, 0, 0.3, 0.9])
    np.testing.assert_allclose(a.state.as_array(), b.state.as_array())


def test_unnormalised_quaternion_is_accepted(real):
    a = real.calculate_robot_state(RobotState(), [1, 1, 1.2], [0, 0, 0.3, 0.9])
    b = real.calculate_robot_state(RobotState(), [1, 1, 1.2], np.array([0, 0, 0.3, 0.9]) / np.hypot(0.3, 0.9))
    np.testing.assert_allclose(a.state.as_array(), b.state.as_array())


# ------------------------------------------------------------------------------------------------ costs and map
def test_movement_costs(real):
    s = real.settings
    here = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    still = real.movement_costs(here, here)
    assert (still.base_translation, still.pan, still.tilt, still.rotation, still.weighted) == (1, 1, 1, 1, 1)
    moved = real.movement_costs(here, RobotState(s.pan_limits_rad[1], 0.0, 0.0, 1.0 + s.sigma_m, 1.0))
    assert moved.base_translation == pytest.approx(math.exp(-0.5))
    assert moved.pan == pytest.approx(0.5)
    assert moved.rotation == pytest.approx(1.0)  # driving straight on: no turn
    turned = real.movement_costs(here, RobotState(0.0, s.tilt_limits_rad[0], np.pi, 1.0, 1.0))
    assert turned.rotation == pytest.approx(0.5) and turned.tilt == pytest.approx(1 - 45 / 70)
    weights = np.array([s.omega_base, s.omega_pan, s.omega_tilt, s.omega_rot])
    values = np.array([turned.base_translation, turned.pan, turned.tilt, turned.rotation])
    assert turned.weighted == pytest.approx(weights @ values / weights.sum())


def test_get_distance_euclidean_without_the_planner(real):
    assert not real.settings.use_global_planner
    assert real.get_distance([0, 0, 5], [3, 4, -2]) == pytest.approx(5.0)
    assert real.get_distance([3.0, 2.0, 0], [7.0, 1.0, 0]) == pytest.approx(math.hypot(4, 1))


def test_get_distance_with_the_planner(real):
    model = MildRobotModel(real.kinematics, real.settings.with_changes(use_global_planner=True), real.map)
    open_floor = model.get_distance([1.0, 1.0, 0], [4.0, 3.0, 0])
    assert math.hypot(3, 2) <= open_floor < math.hypot(3, 2) + 0.05
    around = model.get_distance([3.0, 2.0, 0], [7.0, 1.0, 0])
    assert around > math.hypot(4, 1) + 3.0  # the inner wall ends at y = 5: up and down again
    path = model.navigation_path([3.0, 2.0], [7.0, 1.0])
    assert path[:, 1].max() > 5.0, "the path must go around the end of the wall"
    planner = model.map.planner(model.settings.col_thresh)
    for a, b in itertools.pairwise(path):  # straight over allowed cells, or a single step of the grid search
        assert planner.line_is_clear(a, b) or np.linalg.norm(b - a) < 1.5 * model.map.resolution_m
    assert model.get_distance([1.0, 1.0, 0], [8.0, 3.0, 0]) == -1.0  # inside the closed box room
    assert model.get_distance([1.0, 1.0, 0], [2.5, 4.5, 0]) == -1.0  # on the table


def test_is_position_allowed_on_free_occupied_inflated_and_unknown_cells(real):
    assert real.is_position_allowed([1.0, 1.0, 0.0])  # free
    assert not real.is_position_allowed([2.5, 4.5, 0.0])  # table
    assert not real.is_position_allowed([5.0, 2.0, 0.0])  # wall
    assert not real.is_position_allowed([5.3, 2.0, 0.0])  # 0.25 m from the wall: inscribed (99)
    assert real.map.values_at(np.array([5.55, 2.0])) > 0  # 0.5 m: inflated cost, but below colThresh 40
    assert real.is_position_allowed([5.55, 2.0, 0.0])
    assert not real.is_position_allowed([5.45, 2.0, 0.0])  # 0.4 m: inflated above colThresh
    assert not real.is_position_allowed([9.8, 0.3, 0.0])  # unknown corner
    assert not real.is_position_allowed([-3.0, 0.0, 0.0])  # outside the map
    with pytest.raises(ValueError):
        real.is_position_allowed([np.nan, 0.0, 0.0])


def test_frustum_corners(real):
    pose = real.camera_pose(RobotState())
    corners = real.frustum_corners(pose)
    s = real.settings
    local = (corners - pose[:3, 3]) @ pose[:3, :3]
    np.testing.assert_allclose(local[:4, 0], s.ncp_m)
    np.testing.assert_allclose(local[4:, 0], s.fcp_m)
    np.testing.assert_allclose(np.abs(local[4:, 1]), s.fcp_m * math.tan(s.fovx_rad / 2))
    np.testing.assert_allclose(np.abs(local[4:, 2]), s.fcp_m * math.tan(s.fovy_rad / 2))
