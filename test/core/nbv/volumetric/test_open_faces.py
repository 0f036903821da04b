"""Open faces: a plate thinner than a voxel, seen from above only, has a rim no frontier voxel marks (the space
around it is already known free); its edge voxels' sideways faces are open until a point with a sideways normal is
measured there, and the expected-surface gain counts them for a view that faces them, not for one from above."""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.nbv.volumetric.gains import ExpectedSurfaceModel, ViewModel, expected_surface, open_faces
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

RES = 0.01  # m: 10^3 voxels over a 0.1 m cube
PLATE_Z = 0.035  # the plate's top, in voxel layer 3
PLATE_LO, PLATE_HI = 0.03, 0.07  # its extent in x and y (voxel columns 3..6)


def plate_seen_from_above() -> VoxelMap:
    grid = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))
    ax = np.arange(0.0025, 0.1, 0.005)
    x, y = np.meshgrid(ax, ax, indexing="ij")
    on_plate = (x > PLATE_LO) & (x < PLATE_HI) & (y > PLATE_LO) & (y < PLATE_HI)
    # the plate's top and a floor around it, both seen from straight above (the rays beside the plate carve the
    # space at its height free)
    z = np.where(on_plate, PLATE_Z, 0.005)
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    up = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    for dx in (-0.002, 0.002):  # two views, so the free space is observed well
        grid.integrate([0.05 + dx, 0.05, 0.6], points, up)
    return grid


def face_count(grid: VoxelMap, index) -> float:
    return float(open_faces(grid, 30.0)[0][tuple(index)])


def test_the_rim_of_a_plate_seen_from_above_is_open_and_closes_when_measured():
    grid = plate_seen_from_above()
    count, direction = open_faces(grid, 30.0)
    assert grid.full_mask()[3, 4, 3] and grid.empty_mask()[2, 4, 3]  # a rim voxel, free space beside it
    assert count[3, 4, 3] == 1.0
    np.testing.assert_allclose(direction[3, 4, 3], [-1.0, 0.0, 0.0])
    assert count[4, 4, 3] == 0.0  # inside the plate: its top is seen, its sides are plate
    assert count[3, 3, 3] == 2.0  # a corner: two sideways faces
    assert not count[:, :, 0].any()  # the floor: seen from above, nothing free beside it turns away
    # a point on the rim with a sideways normal closes that face (and only that one)
    grid.integrate([-0.3, 0.045, PLATE_Z], [[0.0302, 0.045, PLATE_Z - 0.001]], [[-1.0, 0.0, 0.0]])
    assert face_count(grid, (3, 4, 3)) == 0.0
    assert face_count(grid, (3, 3, 3)) == 2.0


def test_a_staircase_face_of_a_sloped_surface_is_not_open():
    grid = plate_seen_from_above()
    # the same plate, its top measured with normals tilted 50 deg towards -x: the -x face lies within 60 deg of
    # the voxel's mean normal, it is the seen surface's own continuation, not a new side
    tilted = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))
    xyz = grid.raw.xyz_m
    normal = np.tile([-np.sin(np.radians(50.0)), 0.0, np.cos(np.radians(50.0))], (len(xyz), 1))
    for dx in (-0.002, 0.002):
        tilted.integrate([0.05 + dx, 0.05, 0.6], xyz, normal)
    assert face_count(grid, (3, 4, 3)) == 1.0
    assert face_count(tilted, (3, 4, 3)) == 0.0
    assert face_count(tilted, (6, 4, 3)) == 1.0  # the +x side turns away from it by 140 deg: open


def test_the_expected_surface_counts_open_faces_for_a_view_that_faces_them():
    grid = plate_seen_from_above()
    view = ViewModel(fov_h_rad=np.radians(30.0), fov_v_rad=np.radians(30.0), range_min_m=0.05, range_max_m=1.0,
                     projector_offset_m=np.zeros(3), rays_h=32, rays_v=32, max_incidence_rad=np.radians(75.0))  # fmt: skip
    rim = np.array([PLATE_LO, 0.05, PLATE_Z - 0.005])
    side = look_at(rim + np.array([-0.3, 0.0, 0.05]), rim)
    above = look_at(rim + np.array([0.0, 0.0, 0.3]), rim, up=[1.0, 0.0, 0.0])
    _, area = expected_surface(grid, np.stack([side, above]), view, ExpectedSurfaceModel())
    assert area[0] > 0.0 and area[1] == 0.0
    _, without = expected_surface(grid, side[None], view, ExpectedSurfaceModel(open_face_angle_deg=0.0))
    assert without[0] < area[0]


def test_the_running_evidence_equals_a_recount_from_all_points():
    grid = plate_seen_from_above()
    before = open_faces(grid, 30.0)[0]  # the evidence of the two views so far, kept for the map
    grid.integrate([-0.3, 0.045, PLATE_Z], [[0.0302, 0.045, PLATE_Z - 0.001]], [[-1.0, 0.0, 0.0]])
    running = open_faces(grid, 30.0)[0]  # updated with the new point only
    recount = open_faces(grid, 29.9)[0]  # another angle: counted from all the points again
    np.testing.assert_array_equal(running, recount)
    assert running.sum() == before.sum() - 1
