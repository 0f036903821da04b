"""Point-cloud files (PLY, PTX, TIFF); which paths may be written: test_device.py (the file policy)."""

import os

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.sensors.phoxi.point_cloud_io import (
    format_fixed_rows,
    read_ply,
    read_point_tiff,
    write_ply,
    write_point_tiff,
    write_ptx,
)


@pytest.fixture()
def out(tmp_path):
    root = tmp_path / "frames"
    root.mkdir()
    return root


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


def test_fixed_point_rows_equal_printf_formatting():
    """The vectorised PTX formatter writes exactly what np.savetxt("%.6f ... %.4f") writes: signs, -0, rounding,
    leading zeros, large values, and its printf fallback for non-finite or huge values."""
    import io

    rng = np.random.default_rng(3)
    table = np.concatenate([rng.normal(scale=s, size=(2000, 4)) for s in (1e-7, 1e-3, 1.0, 100.0, 1e4, 1e9)])
    table = table.astype(np.float32).astype(np.float64)  # the frames' points are float32
    table[:5] = 0.0
    table[5:10] = -0.0
    table[10, 0], table[11, 0], table[12, 3] = -4e-7, 0.9999999, 0.99995
    for rows in (table, np.array([[np.nan, np.inf, -np.inf, 1e15]])):
        expected = io.BytesIO()
        np.savetxt(expected, rows, fmt="%.6f %.6f %.6f %.4f")
        assert format_fixed_rows(rows, (6, 6, 6, 4)) == expected.getvalue()
    assert format_fixed_rows(np.empty((0, 2)), (1, 1)) == b""
    assert format_fixed_rows(np.array([[12.34, -5.0]]), (0, 2)) == b"12 -5.00\n"
    with pytest.raises(ValueError, match="2 columns"):
        format_fixed_rows(np.zeros((3, 3)), (6, 6))


def test_ptx_of_a_large_frame_is_fast_and_reloads(out):
    import time

    rng = np.random.default_rng(4)
    points = rng.normal(size=(772, 1032, 3)).astype(np.float32)  # a quarter of a high-resolution frame
    points[::7] = 0.0
    intensity = rng.uniform(size=(772, 1032))
    start = time.perf_counter()
    path = write_ptx(out / "big.ptx", points, intensity)
    elapsed = time.perf_counter() - start
    table = np.loadtxt(path, skiprows=10)
    np.testing.assert_allclose(table[:, :3], points.transpose(1, 0, 2).reshape(-1, 3), atol=5e-7)
    np.testing.assert_allclose(table[:, 3], intensity.T.reshape(-1), atol=5e-5)
    assert elapsed < 2.0, f"PTX of 0.8 M points took {elapsed:.2f} s"


def test_tiff_round_trip_keeps_x_y_z_order(out):
    points = np.random.default_rng(2).normal(size=(6, 7, 3)).astype(np.float32)
    path = write_point_tiff(out / "a.tif", points)
    np.testing.assert_array_equal(read_point_tiff(path), points)
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # OpenCV reads the samples back in BGR order
    np.testing.assert_array_equal(raw[:, :, 2], points[:, :, 0])
