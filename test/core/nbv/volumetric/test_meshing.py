"""Projective TSDF + marching cubes: a plane and a sphere seen in analytic depth images come back within a voxel."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.meshing import TSDFVolume
from agiprobot_measurement.sensors.phoxi.models import CameraIntrinsics

INTR = CameraIntrinsics(width=200, height=150, fx=300.0, fy=300.0, cx=99.5, cy=74.5)


def camera_rays_world(pose):
    u, v = np.meshgrid(np.arange(INTR.width), np.arange(INTR.height))
    rays = np.stack([(u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy, np.ones_like(u, dtype=float)], axis=-1)
    return rays, rays @ pose[:3, :3].T  # camera-frame rays (z = 1) and their world directions


def sphere_depth(pose, centre, radius):
    """z-depth image of a sphere (0 where the ray misses it)."""
    rays_cam, rays_world = camera_rays_world(pose)
    o = pose[:3, 3] - centre
    a = np.einsum("hwi,hwi->hw", rays_world, rays_world)
    b = 2 * np.einsum("hwi,i->hw", rays_world, o)
    c = o @ o - radius**2
    disc = b * b - 4 * a * c
    t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)
    return np.where(disc >= 0, t * rays_cam[..., 2], 0.0).astype(np.float32)


def test_a_plane_comes_back_within_a_voxel():
    volume = TSDFVolume([-0.05, -0.05, -0.03], [0.05, 0.05, 0.03], voxel_m=0.002, truncation_m=0.006)
    pose = look_at([0.0, 0.0, 0.45], [0.0, 0.0, 0.0], up=(0, 1, 0))
    # the plane z = 0 seen straight down: z-depth 0.45 everywhere
    depth = np.full((INTR.height, INTR.width), 0.45, dtype=np.float32)
    depth[:, :20] = 0.0  # invalid pixels update nothing
    assert volume.integrate(depth, INTR, pose) > 0
    mesh = volume.mesh()
    assert len(mesh.faces) > 100
    assert np.abs(mesh.vertices[:, 2]).max() < 0.002
    # normals face the camera side (free space)
    assert mesh.face_normals[:, 2].mean() > 0.99


def test_a_sphere_seen_from_four_sides_comes_back_within_a_voxel():
    centre = np.array([0.0, 0.0, 0.0])
    radius = 0.04
    volume = TSDFVolume([-0.06] * 3, [0.06] * 3, voxel_m=0.002, truncation_m=0.006)
    for eye in ([0.45, 0, 0.05], [-0.45, 0, 0.05], [0, 0.45, 0.05], [0, -0.45, 0.05], [0.0, 0.05, 0.45]):
        pose = look_at(eye, centre)
        volume.integrate(sphere_depth(pose, centre, radius), INTR, pose)
    mesh = volume.mesh()
    r = np.linalg.norm(mesh.vertices - centre, axis=1)
    assert len(mesh.faces) > 1000
    assert np.abs(r - radius).max() < 0.002
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - centre)
    assert (outward > 0).mean() > 0.99


def test_nothing_seen_gives_an_empty_mesh_and_bad_input_is_refused():
    volume = TSDFVolume([0, 0, 0], [0.02, 0.02, 0.02])
    assert len(volume.mesh().faces) == 0
    with pytest.raises(InputError, match="intrinsics"):
        volume.integrate(np.zeros((10, 10)), INTR, np.eye(4))
    with pytest.raises(InputError, match="4x4"):
        volume.integrate(np.zeros((INTR.height, INTR.width)), INTR, np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="empty or inverted ROI"):
        TSDFVolume([0, 0, 0], [0, 1, 1])
    with pytest.raises(InputError, match="voxel_m"):
        TSDFVolume([0, 0, 0], [1, 1, 1], voxel_m=0.0)
    with pytest.raises(InputError, match="voxels"):
        TSDFVolume([0, 0, 0], [10, 10, 10], voxel_m=0.001)


def test_the_serial_kernel_of_forked_children_gives_the_same_tsdf(monkeypatch):
    from agiprobot_measurement.nbv.volumetric import raycast3d

    pose = look_at([0.02, 0.01, 0.45], [0.0, 0.0, 0.0])
    depth = sphere_depth(pose, np.zeros(3), 0.04)
    threaded = TSDFVolume([-0.05] * 3, [0.05] * 3, voxel_m=0.004, truncation_m=0.012)
    threaded.integrate(depth, INTR, pose)
    monkeypatch.setattr(raycast3d, "_FORKED", True)
    serial = TSDFVolume([-0.05] * 3, [0.05] * 3, voxel_m=0.004, truncation_m=0.012)
    serial.integrate(depth, INTR, pose)
    assert np.array_equal(threaded.tsdf, serial.tsdf) and np.array_equal(threaded.weight, serial.weight)
