"""Point-cloud files (PLY, PTX, TIFF) and the output-directory gate."""

import os

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.sensors.phoxi.point_cloud_io import (
    OutputPathError,
    read_ply,
    read_point_tiff,
    resolve_output_path,
    write_ply,
    write_point_tiff,
    write_ptx,
)


@pytest.fixture()
def out(tmp_path):
    root = tmp_path / "frames"
    root.mkdir()
    return root


# ----------------------------------------------------------------------------------------------- paths
def test_paths_inside_the_output_directory_are_accepted(out):
    assert resolve_output_path(out, "a.ply") == out / "a.ply"
    assert resolve_output_path(out, "sub/dir/a.ply") == out / "sub" / "dir" / "a.ply"
    assert resolve_output_path(out, str(out / "b.ply")) == out / "b.ply"
    assert resolve_output_path(out, "sub/../c.ply") == out / "c.ply"


@pytest.mark.parametrize("requested", ["../escape.ply", "sub/../../escape.ply", "/tmp/escape.ply", "/etc/passwd"])
def test_paths_that_escape_are_refused(out, requested):
    with pytest.raises(OutputPathError, match="outside the output directory"):
        resolve_output_path(out, requested)


def test_symlink_out_of_the_directory_is_refused(out, tmp_path):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (out / "link").symlink_to(outside, target_is_directory=True)
    with pytest.raises(OutputPathError, match="outside"):
        resolve_output_path(out, "link/x.ply")


def test_home_expands_and_must_still_lie_inside(out, tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(out))
    assert resolve_output_path(out, "~/x.ply") == out / "x.ply"
    monkeypatch.setenv("HOME", str(tmp_path))
    with pytest.raises(OutputPathError, match="outside"):
        resolve_output_path(out, "~/x.ply")


@pytest.mark.parametrize("requested", ["", "   ", "."])
def test_empty_or_directory_paths_are_refused(out, requested):
    with pytest.raises(OutputPathError):
        resolve_output_path(out, requested)
    (out / "d").mkdir()
    with pytest.raises(OutputPathError, match="directory"):
        resolve_output_path(out, "d")


# -------------------------------------------------------------------------------------------------- PLY
def test_binary_ply_round_trip_with_normals_and_scalars(out):
    rng = np.random.default_rng(1)
    points = rng.normal(size=(4, 5, 3)).astype(np.float32)
    normals = rng.normal(size=(4, 5, 3)).astype(np.float32)
    intensity = rng.uniform(size=(4, 5)).astype(np.float32)
    path = write_ply(out / "a.ply", points, normals, {"intensity": intensity}, comments=("units: metres",))
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    data = read_ply(path)
    np.testing.assert_array_equal(np.stack([data["x"], data["y"], data["z"]], 1), points.reshape(-1, 3))
    np.testing.assert_array_equal(np.stack([data["nx"], data["ny"], data["nz"]], 1), normals.reshape(-1, 3))
    np.testing.assert_array_equal(data["intensity"], intensity.reshape(-1))
    assert data["comments"] == ["units: metres"]
    # an independent reader (trimesh) sees the same vertices
    np.testing.assert_array_equal(np.asarray(trimesh.load(path).vertices, dtype=np.float32), points.reshape(-1, 3))
    assert oct(path.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    assert [p.name for p in out.iterdir()] == ["a.ply"], "no temporary file left behind"


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_ply_property_length_mismatch_writes_nothing(out):
    with pytest.raises(ValueError, match="intensity"):
        write_ply(out / "bad.ply", np.zeros((3, 3)), scalars={"intensity": np.zeros(2)})
    assert list(out.iterdir()) == []


def test_ascii_ply_reads_too(out):
    path = out / "ascii.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n1 2 3\n4 5 6\n"
    )
    data = read_ply(path)
    np.testing.assert_array_equal(data["z"], [3, 6])


# ------------------------------------------------------------------------------------------ PTX, TIFF
def test_ptx_lists_points_column_by_column(out):
    points = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3)
    intensity = np.full((2, 3), 0.5)
    path = write_ptx(out / "a.ptx", points, intensity)
    lines = path.read_text().splitlines()
    assert lines[0] == "3" and lines[1] == "2"  # columns, rows
    assert len(lines) == 10 + 6
    first_column = [list(map(float, line.split())) for line in lines[10:12]]
    np.testing.assert_allclose(first_column, [[*points[0, 0], 0.5], [*points[1, 0], 0.5]])


def test_tiff_round_trip_keeps_x_y_z_order(out):
    points = np.random.default_rng(2).normal(size=(6, 7, 3)).astype(np.float32)
    path = write_point_tiff(out / "a.tif", points)
    np.testing.assert_array_equal(read_point_tiff(path), points)
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # OpenCV reads the samples back in BGR order
    np.testing.assert_array_equal(raw[:, :, 2], points[:, :, 0])
