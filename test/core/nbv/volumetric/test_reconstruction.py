"""The 3D NBV loop: request validation, the stopping rules and budgets, plan-only, outputs, the simulated station."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.routing import Router
from agiprobot_measurement.nbv.volumetric.policies.base import motion_time_s
from agiprobot_measurement.nbv.volumetric.policies.ours import OursPolicy
from agiprobot_measurement.nbv.volumetric.reconstruction import Reconstructor
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.results import TERMINATION_REASONS
from agiprobot_measurement.nbv.volumetric.settings import PlanningSettings


@pytest.fixture(scope="module")
def station():
    from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation

    return SimulatedNBVStation(pixel_step=8)  # the 100 mm cube of config/scene.yaml


def make(station, **fields):
    from agiprobot_measurement.nbv.simulation.station3d import SimulatedPhoXiCamera, SimulatedRobot

    robot = SimulatedRobot(station, strict=True)
    camera = SimulatedPhoXiCamera(station, robot)
    request = ReconstructionRequest.with_config_defaults(**fields)
    return Reconstructor(robot, camera, request, station=station), robot


# --------------------------------------------------------------------------------------------- requests
@pytest.mark.parametrize(
    ("fields", "name"),
    [
        ({"roi_size_m": [0.2, 0.0, 0.2]}, "roi_size_m"),
        ({"roi_size_m": [5.0, 5.0, 5.0]}, "roi_size_m"),
        ({"roi_center_m": [0.4, math.nan, 1.0]}, "roi_center_m"),
        ({"resolution_m": 0.0}, "resolution_m"),
        ({"resolution_m": math.nan}, "resolution_m"),
        ({"planning_resolution_m": 0.001}, "planning_resolution_m"),
        ({"gain": "magic"}, "gain"),
        ({"candidates": "everywhere"}, "candidates"),
        ({"max_views": 0}, "max_views"),
        ({"max_views": 2.5}, "max_views"),
        ({"cost_weight": -1.0}, "cost_weight"),
        ({"min_gain_area_mm2": math.inf}, "min_gain_area_mm2"),
        ({"min_relative_gain": 2.0}, "min_relative_gain"),
        ({"max_time_s": 0.0}, "max_time_s"),
    ],
)
def test_bad_requests_name_the_field(fields, name):
    with pytest.raises(InputError, match=name):
        ReconstructionRequest(**fields)


def test_from_mapping_takes_defaults_for_zero_and_empty_fields():
    request = ReconstructionRequest.from_mapping(
        {"roi_center_m": [0, 0, 0], "roi_size_m": [], "resolution_m": 0.0, "gain": "", "max_views": 0,
         "max_joint_path_rad": 0.0, "execute": False}
    )  # fmt: skip
    assert request.roi_center_m is None and request.roi_size_m is None
    assert request.resolution_m == 0.002 and request.gain == "ours" and request.max_views == 20
    assert request.max_joint_path_rad == math.inf and request.execute is False
    with pytest.raises(InputError, match="bogus"):
        ReconstructionRequest.from_mapping({"bogus": 1})
    with pytest.raises(InputError, match="roi_size_m"):
        ReconstructionRequest.from_mapping({"roi_size_m": [0.1, -0.1, 0.1]})


def test_motion_time_is_the_slowest_joints_trapezoid(station):
    limits = station.limits
    q0 = np.zeros(6)
    far = np.zeros((1, 6))
    far[0, 0] = 4.0  # v 1.8 rad/s, a 1.0 rad/s^2: cruise (4 > 1.8^2 / 1)
    np.testing.assert_allclose(motion_time_s(q0, far, limits), 4.0 / 1.8 + 1.8)
    near = np.zeros((1, 6))
    near[0, 1] = 0.25
    np.testing.assert_allclose(motion_time_s(q0, near, limits), 2.0 * math.sqrt(0.25))
    assert motion_time_s(q0, np.zeros((1, 6)), limits)[0] == 0.0


# --------------------------------------------------------------------------------------------- loop
def test_view_budget_stops_the_loop_and_the_outputs_are_written(station, tmp_path):
    recon, robot = make(station, max_views=2, output_dir=str(tmp_path / "out"))
    phases = []
    result = recon.run(on_progress=lambda p: phases.append(p.phase))
    assert result.termination_reason == "max_views"
    assert len(result.views) == 2 and len(robot.trajectories) >= 2
    assert robot.true_collisions == 0
    assert {"search", "capture", "integrate", "candidates", "plan_motion", "move", "finish"} <= set(phases)
    assert result.views[1].candidates_feasible > 0 and result.views[1].rejections
    assert result.observed_surface_area_m2 > 0.005  # two faces of the cube at least
    assert result.joint_path_rad > 0 and result.tcp_path_m > 0
    for name in ("cloud_file", "mesh_file", "map_file", "log_file"):
        assert getattr(result, name), name
    log = yaml.safe_load(open(result.log_file))
    assert log["termination_reason"] == "max_views" and len(log["views"]) == 2
    assert np.asarray(log["views"][1]["camera_pose"]).shape == (4, 4)
    from agiprobot_measurement.nbv.volumetric.voxel_map import VoxelMap

    assert VoxelMap.load_npz(result.map_file).shape == recon.map.shape


def test_a_move_that_cannot_be_timed_skips_that_view_and_the_loop_goes_on(station):
    from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError

    recon, _ = make(station, max_views=3)
    route = recon.router.route
    calls = []

    def route_failing_once(q_from, q_to, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:  # the move to the first planned view: a spline leaving the wrist's limits
            raise TimeParameterizationError("wrist_3_joint leaves its limits")
        return route(q_from, q_to, *args, **kwargs)

    recon.router.route = route_failing_once
    result = recon.run()
    assert result.error == "" and result.termination_reason == "max_views"
    assert len(result.views) == 3 and result.motion_failures == 1
    assert len(calls) >= 4


def test_gain_threshold_and_cancel_and_budgets(station):
    recon, _ = make(station, max_views=5, min_gain_area_mm2=1e9)
    assert recon.run().termination_reason == "gain_below_threshold"
    assert len(recon.views) == 2  # below the threshold for two iterations: one more view, then the stop

    recon, _ = make(station, max_views=5)
    calls = []
    result = recon.run(should_cancel=lambda: len(calls.append(1) or calls) > 1)
    assert result.termination_reason == "cancelled" and len(result.views) == 1

    recon, _ = make(station, max_views=5, max_joint_path_rad=0.01)
    assert recon.run().termination_reason == "max_path"

    recon, _ = make(station, max_views=5, max_time_s=1e-6)
    assert recon.run().termination_reason == "max_time"
    assert set(TERMINATION_REASONS) >= {"gain_below_threshold", "cancelled", "max_path", "max_time", "max_views"}


def test_the_stopping_rule_sees_the_maps_growth_and_the_views_left(station):
    # budget_growth_share 0: the saturation rule stays off, the loop runs to its budget and hands it every iteration
    recon, _ = make(station, max_views=4)
    recon.stopping.budget_growth_share = 0.0
    seen = []
    update = recon.stopping.update

    def spy(*args):
        seen.append((args[4], args[5], len(recon.views), recon.map.observed_surface_area_m2()))
        return update(*args)

    recon.stopping.update = spy
    result = recon.run()
    assert result.termination_reason == "max_views" and len(seen) == 3
    assert [left for _, left, _, _ in seen] == [4 - views for _, _, views, _ in seen] == [3, 2, 1]
    growth = [g for g, _, _, _ in seen]
    # after the opening view the map's growth is all it observed; later views add newly full voxels only
    assert growth[0] == pytest.approx(result.views[0].observed_area_m2)
    assert all(g >= 0 for g in growth) and sum(growth) >= seen[-1][3] - 1e-12


def test_empty_roi_ends_with_nothing_found_after_the_search(station):
    center, _ = station.default_roi()
    beside = center + np.array([0.0, 0.3, 0.0])  # over the bare table next to the fixture
    recon, _ = make(station, max_views=10, roi_center_m=beside, roi_size_m=[0.2, 0.2, 0.2])
    result = recon.run()
    assert result.termination_reason == "nothing_found"
    assert 1 < len(result.views) <= 1 + recon.settings.motion.search_views
    assert {v.source for v in result.views[1:]} == {"search"}


def test_plan_only_returns_the_next_view_without_moving(station):
    recon, robot = make(station, execute=False)
    result = recon.run()
    assert result.termination_reason == "plan_only" and not robot.trajectories
    pose, joints = result.next_view_pose, result.next_view_joints
    assert pose.shape == (4, 4) and joints.shape == (6,)
    np.testing.assert_allclose(station.sensor_pose(joints), pose, atol=1e-6)


def test_integrate_refuses_what_is_not_a_frame(station):
    recon, _ = make(station)
    with pytest.raises(InputError):
        recon.integrate({"points": []})


def test_reconstruct_cli_refuses_bad_input_before_any_work(tmp_path, capsys, load_script):
    cli = load_script("reconstruct")
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "old.txt").write_text("x")
    assert cli.main(["cup", "--out", str(busy)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert cli.main(["no_such_part.stl", "--out", str(tmp_path / "new")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli.main(["cup", "--resolution", "0", "--out", str(tmp_path / "new2")]) == 2
    assert "resolution_m" in capsys.readouterr().err


def test_reconstruct_cli_refuses_unusable_outputs_before_any_work(tmp_path, capsys, load_script):
    cli = load_script("reconstruct")
    assert cli.main(["cup", "--out", "/proc/no_such_folder"]) == 2
    assert "--out: cannot create the folder" in capsys.readouterr().err
    assert cli.main(["cup", "--out", str(tmp_path / ("a" * 300))]) == 2
    assert "--out: cannot create the folder" in capsys.readouterr().err
    assert cli.main(["cup", "--out", str(tmp_path / "new"), "--summary", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_ours_scores_coarse_first_and_chooses_among_the_best_scored_with_the_full_bundle(station):
    from agiprobot_measurement.nbv.volumetric.policies.ours import coarse_view

    recon, _ = make(station, max_views=1)
    recon.run()
    policy, q = recon.policy, recon.current_joints()

    def scored(exact):
        policy.exact_evaluated = exact
        policy.context.rng = np.random.default_rng(3)  # the same pool each time
        recon.generator.rng = np.random.default_rng(4)
        policy.first_expected_area_m2 = None
        cands, _, idx, _, _, utilities = policy.scored_pool(q)
        return cands.poses[idx], utilities

    poses, full = scored(0)
    assert len(full) > 12
    np.testing.assert_array_equal(scored(len(full))[1], full)  # as many exact slots as candidates: all exact
    poses_k, mixed = scored(8)
    np.testing.assert_array_equal(poses_k, poses)
    order = np.argsort(-mixed)
    assert mixed[order[7]] > mixed[order[8]]  # the 8 rescored rank above every coarse-only one
    assert full[order[0]] >= 0.7 * full.max()  # the choice is (near) the full bundle's best
    coarse = coarse_view(recon.context.view_model, 2)
    assert coarse.rays_h * coarse.rays_v * 4 == recon.context.view_model.rays_h * recon.context.view_model.rays_v


# --------------------------------------------------------------------------------------------- ours' motion weight
def ours_policy(**planning):
    return OursPolicy(None, PlanningSettings.from_mapping(planning))


def test_ours_counts_motion_fully_by_default_and_as_the_surface_runs_out_with_the_schedule():
    constant = ours_policy()
    assert [constant.cost_factor(a) for a in (0.02, 0.01, 0.0)] == [1.0, 1.0, 1.0]
    ramp = ours_policy(cost_schedule="remaining_surface")
    assert ramp.cost_factor(0.02) == 0.0  # the first planned view: the most to gain, motion does not count
    assert ramp.cost_factor(0.03) == 0.0  # more surface expected than at first: clipped
    assert ramp.cost_factor(0.005) == pytest.approx(0.75)
    assert ramp.cost_factor(0.0) == 1.0


def test_a_higher_schedule_power_lets_motion_count_later():
    squared = ours_policy(cost_schedule="remaining_surface", cost_schedule_power=2.0)
    assert squared.cost_factor(0.02) == 0.0
    assert squared.cost_factor(0.005) == pytest.approx(0.75**2)
    assert squared.cost_factor(0.0) == 1.0


def test_the_map_growth_schedule_lets_motion_count_as_the_maps_growth_falls_off():
    from types import SimpleNamespace

    from agiprobot_measurement.nbv.volumetric.policies.ours import GrowthTrack

    class Grid:  # what the schedule reads of the planning map: its version and observed surface
        def __init__(self):
            self.version, self.area = 0, 0.0

        def observed_surface_area_m2(self):
            return self.area

    grid = Grid()
    policy = ours_policy(cost_schedule="map_growth")
    policy.context = SimpleNamespace(planning_map=grid)
    factors = []
    for area in (0.01, 0.03, 0.06, 0.07, 0.075, 0.076):
        grid.version += 1
        grid.area = area
        factors.append(policy.cost_factor(1.0))
        assert policy.cost_factor(1.0) == factors[-1]  # the same map (version): the same factor
    # two-view gains: 0.05, 0.04, 0.015, 0.006 against the best 0.05
    assert factors[:3] == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(factors[3:], [1 - 0.04 / 0.05, 1 - 0.015 / 0.05, 1 - 0.006 / 0.05])
    assert GrowthTrack().saturation(grid) == 0.0


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("cost_schedule_power", 0.0),
        ("cost_schedule_power", math.nan),
        ("cost_schedule_power", "steep"),
        ("cost_joint_path_s_per_rad", -1.0),
        ("cost_joint_path_s_per_rad", math.inf),
        ("cost_joint_path_s_per_rad", None),
    ],
)
def test_bad_motion_weight_settings_are_named(key, value):
    with pytest.raises(InputError, match=rf"planning\.{key}"):
        ours_policy(cost_schedule="remaining_surface", **{key: value})


def test_an_unknown_cost_schedule_is_named():
    with pytest.raises(InputError, match=r"planning\.cost_schedule: unknown 'sometimes'"):
        ours_policy(cost_schedule="sometimes")


# --------------------------------------------------------------------------------------------- via-pose motions
class _BandChecker:
    """Joint-space obstacle: joint 0 within ``home0 + [0.4, 0.6]`` and joint 1 within ``home1 +- 0.1`` collide."""

    def __init__(self, home):
        self.home = np.asarray(home, dtype=float)
        self.calls = 0

    def check_states(self, states):
        self.calls += 1
        d = np.atleast_2d(states) - self.home
        return ~((d[:, 0] > 0.4) & (d[:, 0] < 0.6) & (np.abs(d[:, 1]) < 0.1))


class _Seen:
    def __init__(self, joints):
        self.joints = np.asarray(joints, dtype=float)


def _via_setup(station, via_offset):
    recon, _ = make(station)
    home = recon.home_rad

    def no_ompl():
        raise AssertionError("OMPL must not be asked when a short via move is free")

    # only the earlier poses are vias here (no moves around the ROI)
    settings = dataclasses.replace(recon.router.settings, orbit_retract_m=(), orbit_radius_extra_m=())
    recon.router = Router(_BandChecker(home), station.limits, no_ompl, settings, arm=station)
    recon.views.append(_Seen(home + np.asarray(via_offset)))
    return recon, home


def test_a_blocked_straight_move_goes_through_an_earlier_view_pose(station):
    recon, home = _via_setup(station, [0.5, 0.2, 0, 0, 0, 0])
    goal = home + np.array([1.0, 0, 0, 0, 0, 0])
    trajectory = recon.plan_motion(home, goal)
    positions = np.asarray(trajectory.positions)
    assert np.allclose(positions[0], home) and np.allclose(positions[-1], goal)
    assert recon.router.checker.check_states(positions).all()
    # through the view pose: joint 1 rises to it and comes back, the path is the two segments' (1.4 rad)
    assert positions[:, 1].max() == pytest.approx(home[1] + 0.2, abs=0.01)
    assert np.abs(np.diff(positions, axis=0)).sum() == pytest.approx(1.4, abs=0.02)


def test_no_via_move_when_switched_off_or_every_via_is_blocked(station):
    recon, home = _via_setup(station, [0.5, 0.2, 0, 0, 0, 0])
    goal = home + np.array([1.0, 0, 0, 0, 0, 0])
    vias = [home, *(v.joints for v in recon.views)]
    recon.router.settings = dataclasses.replace(recon.router.settings, via_poses=0)
    assert recon.router.via_path(home, goal, vias) is None
    recon, home = _via_setup(station, [0.5, 0.05, 0, 0, 0, 0])  # the view pose itself lies in the band
    assert recon.router.via_path(home, goal, [home, *(v.joints for v in recon.views)]) is None


# --------------------------------------------------------------------------------------------- moves around the ROI
def _opposite_views(recon, station):
    """Joints of two reachable views of the ROI centre from opposite sides (azimuths 180 deg apart), 55 deg up."""
    from agiprobot_measurement.nbv.volumetric.candidates import poses_from_directions

    centre = 0.5 * (recon.roi_min_m + recon.roi_max_m)
    elevation = math.radians(55.0)
    for azimuth in np.radians(np.arange(0.0, 180.0, 15.0)):
        directions = [[math.cos(elevation) * math.cos(a), math.cos(elevation) * math.sin(a), math.sin(elevation)]
                      for a in (azimuth, azimuth + math.pi)]  # fmt: skip
        poses = poses_from_directions(centre, np.asarray(directions), 0.5, [0.0])
        q, ok = station.ik.solve_nearest(poses, np.broadcast_to(recon.home_rad, (2, 6)))
        if np.all(ok) and recon.generator.checker.check_states(q).all():
            return q[0], q[1], centre
    raise AssertionError("no pair of opposite views is reachable")


def test_orbit_waypoints_retract_along_the_optical_axis_or_pass_the_great_circle(station):
    recon, _ = make(station)
    q_from, q_to, centre = _opposite_views(recon, station)
    router = recon.router
    routes = router.orbit_waypoints(q_from, q_to, centre)
    n_retract = len(router.settings.orbit_retract_m)
    retracts, arcs = routes[:n_retract], routes[n_retract:]
    assert all(len(w) == 4 for w in retracts)
    assert {len(w) for w in arcs} == {3, 4}  # through the middle, and through the thirds
    for w in routes:
        assert np.allclose(w[0], q_from) and np.allclose(w[-1], q_to)
    start, end = station.sensor_pose(np.asarray([q_from, q_to]))
    for d, w in zip(router.settings.orbit_retract_m, retracts, strict=True):
        back = station.sensor_pose(w[1])
        assert np.allclose(back[:3, 3], start[:3, 3] - d * start[:3, 2], atol=1e-6)
        assert np.allclose(back[:3, :3], start[:3, :3], atol=1e-6)
        assert np.allclose(station.sensor_pose(w[2])[:3, 3], end[:3, 3] - d * end[:3, 2], atol=1e-6)
    radius = max(np.linalg.norm(start[:3, 3] - centre), np.linalg.norm(end[:3, 3] - centre))
    for via in station.sensor_pose(np.concatenate([w[1:-1] for w in arcs])):
        offset = via[:3, 3] - centre
        assert np.linalg.norm(offset) >= radius + min(router.settings.orbit_radius_extra_m) - 1e-6
        assert np.dot(via[:3, 2], -offset / np.linalg.norm(offset)) == pytest.approx(1.0, abs=1e-6)  # looks at it
    router.settings = dataclasses.replace(router.settings, orbit_retract_m=(), orbit_radius_extra_m=())
    assert router.orbit_waypoints(q_from, q_to, centre) == []


def test_a_move_across_the_unknown_roi_goes_around_it(station):
    from agiprobot_measurement.motion.motion_planning import interpolate_path

    recon, _ = make(station)
    recon.generator.update_unknown_obstacle(recon.planning_map)  # before any view: the whole ROI is unknown
    q_from, q_to, _ = _opposite_views(recon, station)
    checker = recon.generator.checker
    assert not checker.check_states(interpolate_path(np.asarray([q_from, q_to]), 0.02)).all()

    def no_ompl():
        raise AssertionError("the move around the ROI is short enough: OMPL is not asked")

    recon.router.planner_factory = no_ompl
    trajectory = recon.plan_motion(q_from, q_to)
    positions = np.asarray(trajectory.positions)
    assert np.allclose(positions[0], q_from) and np.allclose(positions[-1], q_to)
    assert checker.check_states(positions).all()
    straight = np.abs(q_to - q_from).sum()
    assert np.abs(np.diff(positions, axis=0)).sum() <= 1.5 * straight


# --------------------------------------------------------------------------------------------- the opening view
def _opening_elevation_deg(station, elevation_deg):
    motion = station.config.setdefault("motion", {})
    saved = motion.get("opening_elevation_deg")
    motion["opening_elevation_deg"] = elevation_deg
    try:
        recon, _ = make(station)
        choice = recon._opening_choice(recon.home_rad)
    finally:
        if saved is None:
            motion.pop("opening_elevation_deg")
        else:
            motion["opening_elevation_deg"] = saved
    return math.degrees(math.asin(-choice.pose[2, 2]))


def test_the_opening_view_comes_from_the_configured_elevation(station):
    top = _opening_elevation_deg(station, 90.0)
    oblique = _opening_elevation_deg(station, 50.0)
    assert top > 80.0
    assert abs(oblique - 50.0) < 15.0


@pytest.mark.parametrize("value", [120.0, -5.0, math.nan])
def test_a_bad_opening_elevation_is_named(station, value):
    with pytest.raises(InputError, match="opening_elevation_deg"):
        _opening_elevation_deg(station, value)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("ompl_best_of", 0),
        ("ompl_best_of", 2.5),
        ("ompl_best_of", "many"),
        ("orbit_retract_m", [0.1, math.nan]),
        ("orbit_radius_extra_m", "far"),
        ("orbit_lift_deg", [120.0]),
    ],
)
def test_bad_motion_settings_are_named(station, key, value):
    motion = station.config.setdefault("motion", {})
    saved = motion.get(key)
    motion[key] = value
    try:
        with pytest.raises(InputError, match=rf"motion\.{key}"):
            make(station)
    finally:
        if saved is None:
            motion.pop(key)
        else:
            motion[key] = saved


def test_a_roi_out_of_reach_ends_with_nothing_found(station):
    recon, _ = make(station, max_views=3, roi_center_m=[1e6, 1e6, 1e6], roi_size_m=[0.2, 0.2, 0.2])
    result = recon.run()
    assert result.termination_reason == "nothing_found"
    assert result.observed_surface_area_m2 == 0.0


def test_ours_undersampled_term_counts_by_its_share_of_the_surface_still_to_be_had(station):
    from agiprobot_measurement.nbv.volumetric.gains import undersampled_surface

    recon, _ = make(station, max_views=2)
    recon.run()
    policy, q = recon.policy, recon.current_joints()
    cands, _, idx, exp_gain, _, _ = policy.scored_pool(q)
    poses, view = cands.poses[idx], recon.context.view_model
    grid = recon.context.planning_map
    missed, normals, pitch = policy.sampling.fields(grid, policy.open_border_weight)
    us_gain, us_area = undersampled_surface(grid, poses, view, missed, pitch, 0.002, normals)
    assert us_gain.max() > 0.0  # every 8th pixel of the opening views leaves sparse surface
    policy.weights = {"proximity_count": 1.0, "undersampled_surface": 2.0}
    policy.undersampled_fade_power = 1.0
    alone, area = policy._score(poses, exp_gain, view, 1e9)  # the unseen surface dwarfs it: the term fades out
    np.testing.assert_allclose(area, us_area)  # the area each would sample is handed on (the tour weighs it)
    policy.weights = {"proximity_count": 1.0}
    np.testing.assert_allclose(alone, policy._score(poses, exp_gain, view, 0.0)[0], atol=1e-6)
    policy.weights = {"proximity_count": 1.0, "undersampled_surface": 2.0}
    share = us_area.max() / (us_area.max() + 0.01)
    with_term = policy._score(poses, exp_gain, view, 0.01)[0]
    np.testing.assert_allclose(with_term - alone, 2.0 * share * us_gain / us_gain.max(), atol=1e-9)


def test_the_tour_covers_the_undersampled_surface_too_and_runs_the_loop(station):
    recon, _ = make(station, max_views=4, gain="ours_tour")
    policy = recon.policy
    policy.tour = dataclasses.replace(policy.tour, min_greedy_views=1, undersampled_min_share=0.25)
    phases = []
    choose = policy.choose

    def spy(q):
        out = choose(q)
        phases.append(policy.last_phase)
        return out

    policy.choose = spy
    result = recon.run()
    assert result.error == "" and len(result.views) >= 3
    assert "tour" in phases  # after the greedy opening the plan takes over
    grid = recon.context.planning_map
    predicted = int(grid.growth_neighbour_mask().sum())
    centres, normals = policy._elements()
    assert len(centres) > min(predicted, 2000)  # the undersampled full voxels are elements beside the predicted ones
    lengths = np.linalg.norm(normals, axis=1)
    assert np.all((np.abs(lengths - 1.0) < 1e-6) | (lengths == 0.0))  # unit directions, or none
    assert len(policy.scores.undersampled_area_m2) > 0
    assert policy.covers_undersampled
    policy.tour = dataclasses.replace(policy.tour, undersampled_min_share=1.0)  # off: the predicted surface only
    assert not policy.covers_undersampled  # ... and the views weighed by their predicted unseen surface alone
    assert len(policy._elements()[0]) == min(predicted, 2000)
