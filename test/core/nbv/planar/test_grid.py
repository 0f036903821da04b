"""Grid values, fusion identities, body validation and the export of measured points."""

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN, MeasuredPoints, dilate8, fuse, validate_truth


def test_fusion_identities():
    values = np.array([EMPTY, UNKNOWN, FULL])
    a, b = np.meshgrid(values, values, indexing="ij")
    fused = fuse(a, b)
    assert fuse(np.array([FULL]), np.array([EMPTY]))[0] == UNKNOWN  # conflict -> unknown
    np.testing.assert_array_equal(fuse(np.zeros(3), values), values)  # 0 is neutral
    np.testing.assert_array_equal(fuse(values, values), values)  # idempotent
    np.testing.assert_array_equal(fused, fused.T)  # commutative
    assert set(np.unique(fused)) <= {EMPTY, UNKNOWN, FULL}


def test_fusion_rejects_bad_input():
    with pytest.raises(NbvInputError, match="shapes"):
        fuse(np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(NbvInputError, match="NaN"):
        fuse(np.array([np.nan]), np.array([1.0]))


def test_dilate8_marks_the_ring_only():
    m = np.zeros((5, 5), dtype=bool)
    m[2, 2] = True
    d = dilate8(m)
    assert d.sum() == 8 and not d[2, 2] and d[1, 1] and d[3, 3] and not d[0, 0]


def test_validate_truth_errors():
    with pytest.raises(NbvInputError, match="no body"):
        validate_truth(np.zeros((10, 10)))
    touching = np.zeros((10, 10), dtype=bool)
    touching[0, 4] = True
    with pytest.raises(NbvInputError, match="border"):
        validate_truth(touching)
    with pytest.raises(NbvInputError, match="2D"):
        validate_truth(np.ones(5))
    bad = np.zeros((10, 10))
    bad[3, 3] = np.nan
    with pytest.raises(NbvInputError, match="NaN"):
        validate_truth(bad)
    ok = np.zeros((10, 10), dtype=bool)
    ok[4:6, 4:6] = True
    t = validate_truth(ok)
    assert (t == FULL).sum() == 4 and (t == EMPTY).sum() == 96


def test_points_export_keeps_full_cells_only(tmp_path):
    pts = MeasuredPoints()
    pts.add(np.array([2.2, 3.4]), (2, 3), 0)
    pts.add(np.array([2.4, 3.1]), (2, 3), 1)
    pts.add(np.array([7.0, 7.0]), (7, 7), 2)
    model = np.zeros((10, 10))
    model[2, 3] = FULL  # (7, 7) lost its full state, e.g. by a conflict
    assert len(pts.points_of_cell((2, 3))) == 2
    csv = np.loadtxt(pts.export_csv(tmp_path / "p.csv", model, cell_size_mm=2.0), delimiter=",", skiprows=1)
    assert csv.shape == (2, 5)
    np.testing.assert_allclose(csv[:, :2], [[4.4, 6.8], [4.8, 6.2]])
    ply = (pts.export_ply(tmp_path / "p.ply", model)).read_text().splitlines()
    assert "element vertex 2" in ply and ply[-1].startswith("2.400000 3.100000")
