"""coverage_figure.plot_coverage: a PNG of the predicted coverage, written atomically, fast, without a display."""

import time

import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

from agiprobot_measurement.planning.report.coverage_figure import NOT_MEASURABLE_COLOR, UNCERTAINTY_CMAP, plot_coverage

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def cube_samples(count: int, seed: int = 1):
    mesh = trimesh.creation.box((100.0, 100.0, 100.0))
    mesh.apply_translation((450.0, -550.0, 1050.0))
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return mesh, points


def scan_lines():
    return [
        (np.array([400.0, -550.0, 1281.8]), np.array([500.0, -550.0, 1281.8])),
        (np.array([268.2, -600.0, 1050.0]), np.array([268.2, -500.0, 1050.0])),
    ]


def test_writes_a_png_with_the_seed_colours(tmp_path):
    mesh, points = cube_samples(2000)
    # top face not measured (red), the rest graded by x: green at x=400 -> blue at x=500
    uncertainties = 0.04 + 0.14 * (points[:, 0] - 400.0) / 100.0
    uncertainties[points[:, 2] > 1099.9] = np.inf
    path = plot_coverage(
        tmp_path / "coverage.png", points, uncertainties, scan_lines(), 0.04, 0.18, title="cube", mesh=mesh
    )
    assert path == tmp_path / "coverage.png"
    assert path.read_bytes()[:8] == PNG_MAGIC
    image = imread(path)[..., :3]
    assert image.shape[0] > 300 and image.shape[1] > 600

    def present(rgb, tolerance=0.06):
        return bool((np.abs(image - np.asarray(rgb)).max(axis=2) < tolerance).any())

    red = tuple(int(NOT_MEASURABLE_COLOR[i : i + 2], 16) / 255 for i in (1, 3, 5))
    assert present(red), "not measured points must be drawn red"
    assert present(UNCERTAINTY_CMAP(0.0)[:3]), "low uncertainty must be drawn green"
    assert present(UNCERTAINTY_CMAP(1.0)[:3]), "high uncertainty must be drawn blue"
    # nothing but the target is left in the directory (the temporary file was renamed)
    assert [p.name for p in tmp_path.iterdir()] == ["coverage.png"]


def test_ten_thousand_points_in_under_three_seconds(tmp_path):
    mesh, points = cube_samples(10_000)
    rng = np.random.default_rng(7)
    uncertainties = rng.uniform(0.04, 0.18, len(points))
    uncertainties[rng.random(len(points)) < 0.1] = np.inf
    start = time.perf_counter()
    plot_coverage(tmp_path / "big.png", points, uncertainties, scan_lines() * 8, 0.04, 0.18, mesh=mesh)
    assert time.perf_counter() - start < 3.0


def test_replaces_an_existing_file_and_handles_edge_cases(tmp_path):
    target = tmp_path / "again.png"
    target.write_bytes(b"old")
    _, points = cube_samples(50)
    # nothing measured, no scan lines, no colour range given
    plot_coverage(target, points, np.full(len(points), np.inf), [])
    assert target.read_bytes()[:8] == PNG_MAGIC
    # all points alike: the colour range is widened instead of failing
    plot_coverage(target, points, np.full(len(points), 0.08), [], 0.08, 0.08)
    plot_coverage(target, np.zeros((0, 3)), np.zeros(0), [])
    assert target.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize(
    ("points", "uncertainties", "lines", "match"),
    [
        (np.zeros((5, 2)), np.zeros(5), [], "shape"),
        (np.zeros((5, 3)), np.zeros(4), [], "4 uncertainties for 5 points"),
        (np.full((2, 3), np.nan), np.zeros(2), [], "NaN"),
        (np.zeros((2, 3)), np.zeros(2), [(np.zeros(3),)], "scan line 1"),
        (np.zeros((2, 3)), np.zeros(2), [(np.zeros(3), np.full(3, np.inf))], "scan line 1"),
    ],
)
def test_bad_input_raises_value_error(tmp_path, points, uncertainties, lines, match):
    with pytest.raises(ValueError, match=match):
        plot_coverage(tmp_path / "bad.png", points, uncertainties, lines, 0.0, 1.0)
    assert not any(tmp_path.iterdir())


def test_reversed_range_and_missing_directory(tmp_path):
    _, points = cube_samples(20)
    with pytest.raises(ValueError, match="u_max"):
        plot_coverage(tmp_path / "x.png", points, np.zeros(20), [], 0.2, 0.1)
    with pytest.raises(FileNotFoundError):
        plot_coverage(tmp_path / "missing" / "x.png", points, np.zeros(20), [], 0.0, 0.1)
