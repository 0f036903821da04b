"""The scanner simulator's stitched cloud and its display thinning (the stitcher node keeps its own cloud; benchmarks use this one)."""

import numpy as np

from agiprobot_measurement.sensors.laser_line.simulator import Profile, StitchedCloud, voxel_thin


def _profile(points):
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return Profile(points, np.zeros(len(points)), points.copy())


def test_voxel_thin_keeps_the_first_point_per_voxel_in_order():
    points = np.array([[0.1, 0.1, 0.1], [5.0, 0, 0], [0.4, 0.2, 0.9], [5.5, 0.5, 0.5], [-0.5, 0, 0]])
    np.testing.assert_array_equal(voxel_thin(points, 1.0), points[[0, 1, 4]])
    np.testing.assert_array_equal(voxel_thin(points, 0.0), points)
    assert voxel_thin(np.zeros((0, 3)), 1.0).shape == (0, 3)


def test_stitched_cloud_counts_every_profile_and_keeps_the_points():
    cloud = StitchedCloud()
    assert cloud.points().shape == (0, 3) and cloud.profiles == 0
    cloud.add([_profile([[0, 0, 0], [1, 0, 0]]), _profile(np.zeros((0, 3)))])
    cloud.add([_profile([[2, 0, 0]])])
    assert cloud.profiles == 3  # the empty profile counts: a client waits for every published profile
    np.testing.assert_array_equal(cloud.points()[:, 0], [0, 1, 2])
    cloud.clear()
    assert cloud.profiles == 0 and len(cloud.points()) == 0
