"""Placement of the part: the overlap check against the scene (object, depth, a clearing offset that clears) and
the fixture placement (lowest point on the fixture's top, centred, optional rotation)."""

import re
import time

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.placement_check import PlacementError, check_placement, find_overlaps
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT, Station
from agiprobot_measurement.station.placement import fixture_placement, scene_object_top_m

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def manager():
    return TrajectoryManager()


@pytest.fixture(scope="module")
def scene():
    return Station.load().scene


def fixture_of(scene):
    return next(o for o in scene.objects if o.name == "fixture")


def test_the_scene_pose_rests_on_the_fixture(manager):
    # the cube's CAD frame has z = 0 at its bottom: at the scene's part pose it touches the fixture, no overlap
    assert manager.load_target_mesh(str(CUBE)) is True
    assert manager.part.mesh.bounds[0, 2] == pytest.approx(1000.0)


def test_a_part_sunk_into_the_fixture_is_refused_with_object_depth_and_offset(manager, scene):
    sunk = pose_matrix([0.0, 0.0, -30.0], [0.0, 0.0, 0.0])
    started = time.perf_counter()
    with pytest.raises(PlacementError) as info:
        manager.load_target_mesh(str(CUBE), transform=sunk)
    assert time.perf_counter() - started < 5.0
    message = str(info.value)
    assert "'fixture'" in message and "lift the part by" in message
    assert re.search(r"by 30\.[01] mm", message), message
    error = info.value
    assert isinstance(error, InputError)
    assert [o.name for o in error.overlaps] == ["fixture"]
    assert error.overlaps[0].depth_mm == pytest.approx(30.0, abs=0.2)
    assert error.lift_mm == pytest.approx(30.0, abs=0.2)
    # the offset it names clears it: the lifted part loads
    lifted = pose_matrix([0.0, 0.0, -30.0 + error.lift_mm], [0.0, 0.0, 0.0])
    assert manager.load_target_mesh(str(CUBE), transform=lifted) is True


def test_a_part_in_the_table_names_the_table_and_the_lift_clears_everything(scene):
    # a 300 x 300 x 10 mm plate half inside the table beside the fixture
    plate = trimesh.creation.box((300.0, 300.0, 10.0))
    table = next(o for o in scene.objects if o.name == "table")
    top_m, _ = scene_object_top_m(table)
    plate.apply_translation([800.0, -200.0, top_m * 1000.0 - 2.0])
    started = time.perf_counter()
    with pytest.raises(PlacementError) as info:
        check_placement(plate, scene)
    assert time.perf_counter() - started < 5.0
    assert "'table'" in str(info.value)
    error = info.value
    table_overlap = next(o for o in error.overlaps if o.name == "table")
    assert table_overlap.depth_mm == pytest.approx(7.0, abs=0.2)  # 5 mm half height + 2 mm below the top
    moved = plate.copy()
    moved.apply_translation([0.0, 0.0, error.lift_mm])
    overlaps, lift = find_overlaps(moved, scene)
    assert overlaps == [] and lift is None


def test_fixture_placement_of_a_part_drawn_in_a_corner_frame(scene):
    # a plate whose CAD frame is one corner (0..203 x 0..305 x 0..12.7 mm), as plate_holes.STL is drawn
    vertices = trimesh.creation.box((203.2, 304.8, 12.7)).vertices + np.array([101.6, 152.4, 6.35])
    top_m, centre_m = scene_object_top_m(fixture_of(scene))
    placement = fixture_placement(vertices, np.eye(3), scene)
    placed = vertices @ placement[:3, :3].T + placement[:3, 3]
    assert placed[:, 2].min() == pytest.approx(top_m * 1000.0)
    assert 0.5 * (placed[:, :2].min(axis=0) + placed[:, :2].max(axis=0)) == pytest.approx(centre_m * 1000.0)
    turned = pose_matrix([0, 0, 0], [0.0, 0.0, np.pi / 2])[:3, :3]
    placement = fixture_placement(vertices, turned, scene)
    placed = vertices @ placement[:3, :3].T + placement[:3, 3]
    extent = placed.max(axis=0) - placed.min(axis=0)
    assert extent[:2] == pytest.approx([304.8, 203.2])  # turned by 90 degrees about z
    assert placed[:, 2].min() == pytest.approx(top_m * 1000.0)
    # the placed part rests on the fixture: no overlap
    assert find_overlaps(trimesh.Trimesh(placed, trimesh.creation.box().faces), scene) == ([], None)


def test_place_fixture_through_the_api_lifts_a_part_below_its_frame(manager, scene):
    # the cube shifted 40 mm down in its own frame would be refused at the scene pose; on the fixture it rests
    down = pose_matrix([0.0, 0.0, -40.0], [0.0, 0.0, 0.0])
    top_m, centre_m = scene_object_top_m(fixture_of(scene))
    yaw = pose_matrix([0.0, 0.0, 0.0], [0.0, 0.0, np.deg2rad(30.0)])
    with pytest.raises(PlacementError):
        manager.load_target_mesh(str(CUBE), transform=down)
    # with placement fixture the transform's rotation turns it; its translation shifts it from the centred
    # position (40 mm down would sink it again), so the request here is the rotation only
    assert manager.load_target_mesh(str(CUBE), transform=yaw, placement="fixture") is True
    bounds = manager.part.mesh.bounds
    assert bounds[0, 2] == pytest.approx(top_m * 1000.0)
    assert 0.5 * (bounds[0, :2] + bounds[1, :2]) == pytest.approx(centre_m * 1000.0)
    assert manager.parameters["placement"] == "fixture"
    # the stored placement (file -> world) reproduces the placed mesh
    stored = np.asarray(manager.parameters["part_transform_mm"]).reshape(4, 4)
    raw = trimesh.load(str(CUBE), force="mesh")
    assert np.allclose(raw.vertices @ stored[:3, :3].T + stored[:3, 3], manager.part.mesh.vertices, atol=1e-6)


def test_unknown_placement_is_refused(manager):
    with pytest.raises(InputError, match="placement"):
        manager.load_target_mesh(str(CUBE), placement="table")
