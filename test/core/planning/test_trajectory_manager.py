"""TrajectoryManager: the documented API and the pipeline end to end (no ROS)."""

import inspect
import warnings

import numpy as np
import pytest

from agiprobot_measurement.motion.trajectory import check_continuity, check_trajectory
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.part_loading import PartLoadError
from agiprobot_measurement.planning.plan.plan_io import load_execution_plan, validate_execution_plan
from agiprobot_measurement.planning.trajectory_manager import (
    ExecutionError,
    PlanningError,
    SimulatedExecutor,
    TrajectoryManager,
)
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def cube_plan():
    """The cube planned once at a low density (shared by the end-to-end tests)."""
    manager = TrajectoryManager()
    assert manager.load_target_mesh(str(CUBE)) is True
    points, views = manager.generate_samples_and_viewpoints(0.01, 0.1, 6, "none")
    chosen = manager.solve_scp(views, "IP_basic")
    ordered = manager.connect_viewpoints(chosen)
    return manager, points, views, chosen, ordered


def test_documented_api_names_and_defaults():
    expected = {
        "load_target_mesh": {
            "add_wbk_mirrors": True,
            "remove_downside": True,
            "remove_threshold_angle_deg": 20,
        },
        "generate_samples_and_viewpoints": {
            "viewpoint_tilt_mode": "full",
            "plan_path_to_check_reachability": False,
            "minimum_trajectory_length": 25,
            "trajectory_sample_step": 2,
        },
        "process_viewpoint": {
            "minimum_required_overmeasure": 5,
            "trajectory_sample_step": 2,
            "joint_jump_threshold": 1.5,
            "minimum_trajectory_length": 50,
        },
        "solve_scp": {"solver_type": "greedy"},
        "connect_viewpoints": {"min_planning_time": 0.2},
        "load_execution_plan": {"adapt_to_current_start_pose": True},
        "store_execution_plan": {"metadata": {}},
        "execute": {"surface_points": None},
        "convert_viewpointlist_to_execution_plan": {},
        "postprocess_trajectory": {},
    }
    for method, defaults in expected.items():
        signature = inspect.signature(getattr(TrajectoryManager, method))
        for name, value in defaults.items():
            assert signature.parameters[name].default == value, f"{method}({name}=...)"
    transform_default = inspect.signature(TrajectoryManager.load_target_mesh).parameters["transform"].default
    np.testing.assert_array_equal(transform_default, np.eye(4))
    for name in (
        "get_anchor_position",
        "get_measurable_surface_point_indices",
        "get_measurable_surface_point_uncertainties",
        "get_orientation_matrix",
        "get_surface_point",
        "get_trajectory_for_measurement",
        "get_trajectory_to_view",
        "reverse_trajectory_for_measurement",
        "set_measurable_surface_point_indices_and_uncertainties",
        "set_trajectory_for_measurement",
        "set_trajectory_to_view",
    ):
        assert callable(getattr(ViewPoint, name))


def test_cube_plan_covers_every_coverable_point(cube_plan):
    manager, points, _views, chosen, ordered = cube_plan
    report = manager.coverage_report()
    assert report.n_samples == len(points) > 0
    assert report.n_views == len(ordered) == len(chosen)
    assert report.unconnected_views == 0
    assert report.coverage_of_coverable >= 0.99
    # the cube on its fixture: every sample of the five upper faces is measurable
    assert report.n_coverable == report.n_samples
    assert 0 < report.mean_uncertainty_mm <= report.max_uncertainty_mm <= 0.1
    assert report.estimated_execution_time_s > 0


def test_cube_plan_is_executable_and_checked(cube_plan, station):
    manager, _, _, _, ordered = cube_plan
    segments = manager.convert_viewpointlist_to_execution_plan(ordered)
    assert [s.kind for s in segments] == ["connect", "measure"] * len(ordered)
    previous = None
    state = manager.current_state
    for segment in segments:
        assert manager.postprocess_trajectory(segment.trajectory)
        assert check_trajectory(segment.trajectory, station.limits, state).ok
        if previous is not None:
            assert check_continuity(previous, segment.trajectory).ok
        previous, state = segment.trajectory, segment.trajectory.end
        # every state of the motion is collision-free (densely interpolated)
        positions, _, _ = segment.trajectory.sample(segment.trajectory.dense_times(step_s=0.05, per_segment=5))
        assert manager.collision.check_states(positions).all()
    executor = SimulatedExecutor(manager.current_state, station.limits)
    assert manager.execute(segments, executor=executor)
    assert [kind for kind, _ in executor.log] == ["connect", "measure"] * len(ordered)


def test_measurement_segments_are_straight_lines_of_the_scanner(cube_plan):
    manager, _, _, _, ordered = cube_plan
    for view in ordered:
        trajectory = view.get_trajectory_for_measurement()
        tips = manager.kinematics.fk_batch(trajectory.positions)
        direction = tips[-1, :3, 3] - tips[0, :3, 3]
        assert np.linalg.norm(direction) * 1000 >= 25 - 1e-6  # minimum_trajectory_length (mm)
        direction /= np.linalg.norm(direction)
        offsets = tips[:, :3, 3] - tips[0, :3, 3]
        lateral = offsets - np.outer(offsets @ direction, direction)
        assert np.abs(lateral).max() < 1e-4  # metres: a straight line
        # constant orientation, and the line runs along the laser_emitter_frame's x axis
        np.testing.assert_allclose(tips[:, :3, :3], np.broadcast_to(tips[0, :3, :3], tips[:, :3, :3].shape), atol=1e-5)
        assert abs(abs(direction @ tips[0, :3, 0]) - 1.0) < 1e-4


def test_plan_round_trips_through_yaml(cube_plan, tmp_path, station):
    manager, _, _, _, ordered = cube_plan
    segments = manager.convert_viewpointlist_to_execution_plan(ordered)
    # the original's store_execution_plan writes exactly the path it is given, with or without a suffix
    assert manager.store_execution_plan(str(tmp_path / "cube_plan"), segments, {"operator": "test"}) is True
    written = tmp_path / "cube_plan"
    assert manager.last_plan_path == written and written.exists()
    assert not list(tmp_path.glob("*.yaml"))
    plan = load_execution_plan(written)
    assert plan.metadata["operator"] == "test"
    assert plan.metadata["coverage"]["covered"] == manager.coverage_report().n_covered
    assert plan.metadata["parameters"]["solver_type"] == "IP_basic"
    assert validate_execution_plan(plan, station.limits).ok
    for original, loaded in zip(segments, plan.segments, strict=True):
        np.testing.assert_allclose(loaded.trajectory.positions, original.trajectory.positions, atol=1e-12)
        np.testing.assert_allclose(loaded.trajectory.time_from_start, original.trajectory.time_from_start, atol=1e-9)
    reloaded = manager.load_execution_plan(str(written), adapt_to_current_start_pose=False)
    assert len(reloaded) == len(segments)


def test_every_solver_covers_the_coverable_points(cube_plan):
    manager, _, views, _, _ = cube_plan
    coverable = set()
    for view in views:
        if view.mechanics_valid:
            coverable.update(view.get_measurable_surface_point_indices())
    for solver in ("greedy", "IP_basic", "IP_uncertainty", "IP_time"):
        chosen = manager.solve_scp(views, solver)
        covered = set().union(*(v.get_measurable_surface_point_indices() for v in chosen))
        valid_coverable = set()
        for view in views:
            if view.mechanics_valid:
                valid_coverable.update(view.get_measurable_surface_point_indices())
        assert covered == valid_coverable, solver
        assert all(v.mechanics_verified and v.mechanics_valid for v in chosen)
    with pytest.raises(ValueError, match="IP_basic"):
        manager.solve_scp(views, "IP_uncert")


def test_real_part_in_inches(shared_dir):
    manager = TrajectoryManager()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a sensible part in its own unit loads without warnings
        manager.load_target_mesh(str(shared_dir / "parts" / "featuretype.STL"), units="inch")
    extents = manager.target_mesh.extents
    np.testing.assert_allclose(sorted(extents), sorted([127.0, 63.5, 35.6]), rtol=0.02)
    _, views = manager.generate_samples_and_viewpoints(0.004, 0.12, 6, "none")
    ordered = manager.connect_viewpoints(manager.solve_scp(views, "greedy"))
    report = manager.coverage_report()
    assert report.coverage_of_coverable >= 0.99
    assert report.n_coverable >= 0.6 * report.n_samples  # pockets and holes hide some samples
    for segment in manager.convert_viewpointlist_to_execution_plan(ordered):
        assert manager.postprocess_trajectory(segment.trajectory)


def test_shared_plan_loads_validates_and_adapts(shared_dir, station):
    manager = TrajectoryManager()
    path = shared_dir / "plans" / "zylinder_low_sampling.yaml"
    plain = manager.load_execution_plan(str(path), adapt_to_current_start_pose=False)
    assert len(plain) == 8
    assert all(manager.postprocess_trajectory(s) for s in plain)
    adapted = manager.load_execution_plan(str(path), adapt_to_current_start_pose=True)
    np.testing.assert_allclose(adapted[0].trajectory.start, manager.current_state, atol=1e-9)
    np.testing.assert_allclose(adapted[0].trajectory.end, plain[0].trajectory.end, atol=1e-9)
    executor = SimulatedExecutor(manager.current_state, station.limits)
    manager.execute(adapted, executor=executor)
    np.testing.assert_allclose(manager.current_state, plain[-1].trajectory.end, atol=1e-9)


def test_execution_stops_on_a_bad_segment(cube_plan, station):
    manager, _, _, _, ordered = cube_plan
    segments = manager.convert_viewpointlist_to_execution_plan(ordered)
    executor = SimulatedExecutor(station.named_states["up"] + 0.3, station.limits)  # not where the plan starts
    with pytest.raises(ExecutionError, match="does not start at the current state"):
        manager.execute(segments, executor=executor)


# ------------------------------------------------------------------------------------------ bad input
def test_bad_input(tmp_path, shared_dir):
    manager = TrajectoryManager()
    with pytest.raises(PlanningError, match="no part loaded"):
        manager.generate_samples_and_viewpoints(0.01, 0.1, 4, "none")
    with pytest.raises(PartLoadError, match=r"nope\.stl"):
        manager.load_target_mesh(str(tmp_path / "nope.stl"))
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 not a mesh at all")
    with pytest.raises(PartLoadError):
        manager.load_target_mesh(str(garbage))
    empty = tmp_path / "empty.stl"
    empty.write_text("solid empty\nendsolid empty\n")
    with pytest.raises(PartLoadError):
        manager.load_target_mesh(str(empty))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(PartLoadError, match="finite"):
        manager.load_target_mesh(str(CUBE), transform=bad)
    # a 5 mm 'part': the unit is almost certainly wrong; warned, still loaded
    with pytest.warns(UserWarning, match="inch"):
        manager.load_target_mesh(str(shared_dir / "parts" / "angle_block.STL"), units="mm", placement="fixture")
    # a triangle soup is no solid, but still a measurable surface: warned, not a crash
    with pytest.warns(UserWarning):
        manager.load_target_mesh(str(shared_dir / "parts" / "soup.stl"), units="dm", placement="fixture")
    manager.load_target_mesh(str(CUBE))
    with pytest.raises(ValueError, match="none, limited, full"):
        manager.generate_samples_and_viewpoints(0.01, 0.1, 4, "sideways")
    with pytest.raises(ValueError, match="sampling_density"):
        manager.generate_samples_and_viewpoints(0.0, 0.1, 4, "none")
    with pytest.raises(ValueError, match="uncertainty_threshold"):
        manager.generate_samples_and_viewpoints(0.01, float("nan"), 4, "none")


def test_part_out_of_reach_is_a_clear_error():
    manager = TrajectoryManager()
    far = np.eye(4)
    far[:3, 3] = [3000.0, 0.0, 0.0]  # 3 m beyond the station's part position
    manager.load_target_mesh(str(CUBE), transform=far)
    with pytest.raises(PlanningError, match="reach"):
        manager.generate_samples_and_viewpoints(0.005, 0.1, 4, "none")
