"""Occupancy grid: map_server loading, inflation, position checks and grid paths (agiprobot_measurement.mild.occupancy_map)."""

import itertools
import math

import numpy as np
import pytest

from agiprobot_measurement.mild.occupancy_map import (
    INSCRIBED,
    LETHAL,
    UNKNOWN,
    OccupancyMap,
    inflate,
    occupancy_from_image,
    polyline_length,
    read_pgm,
)
from agiprobot_measurement.station import CONFIG_DIR, ConfigError

LAB = CONFIG_DIR / "maps" / "mild_lab.yaml"


def write_map(tmp_path, image, origin="[0.0, 0.0, 0.0]", resolution=0.1, extra="", binary=True):
    pgm = tmp_path / "m.pgm"
    header = f"P5\n# comment\n{image.shape[1]} {image.shape[0]}\n255\n" if binary else None
    if binary:
        pgm.write_bytes(header.encode() + image.astype(np.uint8).tobytes())
    else:
        body = "\n".join(" ".join(str(v) for v in row) for row in image)
        pgm.write_text(f"P2\n{image.shape[1]} {image.shape[0]}\n255\n{body}\n")
    yaml_path = tmp_path / "m.yaml"
    yaml_path.write_text(
        f"image: m.pgm\nresolution: {resolution}\norigin: {origin}\nnegate: 0\n"
        f"occupied_thresh: 0.65\nfree_thresh: 0.196\n{extra}"
    )
    return yaml_path


def test_pgm_binary_and_ascii_read_alike(tmp_path):
    image = np.array([[0, 205, 254], [254, 254, 0]], dtype=np.uint8)
    write_map(tmp_path, image)
    binary = read_pgm(tmp_path / "m.pgm")
    write_map(tmp_path, image, binary=False)
    ascii_ = read_pgm(tmp_path / "m.pgm")
    np.testing.assert_array_equal(binary, image)
    np.testing.assert_array_equal(ascii_, image)


def test_map_server_trinary_interpretation_and_row_order():
    image = np.array([[0, 205], [254, 100]], dtype=np.uint8)  # row 0 = top of the picture
    grid = occupancy_from_image(image, negate=False, occupied_thresh=0.65, free_thresh=0.196)
    # bottom image row first; 100 grey: p = 0.61 -> unknown; 205: p = 0.196 -> unknown
    np.testing.assert_array_equal(grid, [[0, UNKNOWN], [LETHAL, UNKNOWN]])
    negated = occupancy_from_image(255 - image, negate=True, occupied_thresh=0.65, free_thresh=0.196)
    np.testing.assert_array_equal(negated, grid)


def test_world_to_cell_uses_the_origin_and_yaw(tmp_path):
    image = np.full((20, 30), 254, dtype=np.uint8)
    grid = OccupancyMap.load(write_map(tmp_path, image, origin="[1.0, 2.0, 0.0]"))
    rows, cols, inside = grid.world_to_cell(np.array([[1.05, 2.05], [3.95, 3.95], [0.9, 2.5], [4.1, 2.5]]))
    assert inside.tolist() == [True, True, False, False]
    assert (rows[0], cols[0], rows[1], cols[1]) == (0, 0, 19, 29)
    turned = OccupancyMap(grid.occupancy, 0.1, np.array([1.0, 2.0]), math.pi / 2)
    rows, cols, inside = turned.world_to_cell(np.array([[0.95, 2.05]]))  # map x axis points along world y
    assert inside[0] and (rows[0], cols[0]) == (0, 0)
    centre = turned.cell_to_world(np.array([3]), np.array([7]))
    rows, cols, _ = turned.world_to_cell(centre)
    assert (rows[0], cols[0]) == (3, 7)


def test_inflation_costs():
    occupancy = np.zeros((1, 40), dtype=np.int8)
    occupancy[0, 0] = LETHAL
    occupancy[0, 39] = UNKNOWN
    cost = inflate(occupancy, resolution_m=0.05, inscribed_radius_m=0.3, inflation_radius_m=0.6, cost_scaling_per_m=5)
    distance = np.arange(40) * 0.05
    assert cost[0, 0] == LETHAL
    assert np.all(cost[0, (distance > 0) & (distance <= 0.3)] == INSCRIBED)
    ring = cost[0, (distance > 0.3) & (distance <= 0.6)]
    assert np.all(np.diff(ring.astype(int)) <= 0) and 0 < ring[-1] < ring[0] < INSCRIBED
    assert np.all(cost[0, (distance > 0.6) & (distance < 1.9)] == 0)
    assert cost[0, 39] == UNKNOWN
    # costmap_2d's curve on MapHelper's 0..100 scale, e.g. 0.45 m: 252 exp(-5 * 0.15) = 119 -> 1 + 97 * 118 // 251
    assert cost[0, 9] == 1 + (97 * (math.floor(252 * math.exp(-5 * 0.15)) - 1)) // 251


def test_positions_allowed_under_the_threshold(tmp_path):
    image = np.full((20, 40), 254, dtype=np.uint8)
    image[:, 20] = 0  # a wall at x = 2.0 .. 2.1 (resolution 0.1)
    image[:5, :5] = 205  # unknown top-left corner
    grid = OccupancyMap.load(write_map(tmp_path, image), inscribed_radius_m=0.2, inflation_radius_m=0.5)
    points = np.array([[1.0, 1.0], [2.05, 1.0], [1.85, 1.0], [1.65, 1.0], [0.2, 1.9], [-0.5, 1.0]])
    values = grid.values_at(points)
    assert values[0] == 0 and values[1] == LETHAL and values[2] == INSCRIBED and 0 < values[3] < INSCRIBED
    assert values[4] == UNKNOWN and values[5] == UNKNOWN
    assert grid.is_allowed(points, 40).tolist() == [True, False, False, values[3] <= 40, False, False]
    assert grid.is_allowed(points[3], 100) and not grid.is_allowed(points[3], values[3] - 1)
    assert not grid.is_allowed(np.array([np.nan, 1.0]), 40)
    # the IK's fast path agrees with the checked one, also outside the map
    np.testing.assert_array_equal(grid.is_allowed_xy(points[:, 0], points[:, 1], 40), grid.is_allowed(points, 40))


def test_planner_goes_around_a_wall_and_reports_blocked_goals(tmp_path):
    image = np.full((40, 60), 254, dtype=np.uint8)
    image[10:, 30] = 0  # wall at x = 3.0 from y = 0 up to y = 3.0 (image rows run top-down: row 10 = y 3.0)
    image[0, :] = image[-1, :] = image[:, 0] = image[:, -1] = 0
    grid = OccupancyMap.load(write_map(tmp_path, image), inscribed_radius_m=0.1, inflation_radius_m=0.2)
    planner = grid.planner(40)
    start, goal = np.array([1.0, 1.0]), np.array([5.0, 1.0])
    path = planner.plan(start, goal)
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], goal)
    assert path[:, 1].max() > 3.0  # over the wall's end
    assert polyline_length(path) > 2 * math.hypot(2.0, 2.0)  # at least start -> wall end -> goal
    for a, b in itertools.pairwise(path):
        assert planner.line_is_clear(a, b) or np.linalg.norm(b - a) < 1.5 * grid.resolution_m
    assert planner.plan(start, [3.05, 1.0]) is None  # on the wall
    assert planner.plan(start, [9.0, 1.0]) is None  # outside the map
    free = planner.plan(start, [2.0, 2.5])
    assert len(free) == 2 and polyline_length(free) == pytest.approx(math.hypot(1.0, 1.5))


def test_planner_tolerance_snaps_to_the_nearest_allowed_cell(tmp_path):
    image = np.full((20, 20), 254, dtype=np.uint8)
    image[10, 10] = 0
    grid = OccupancyMap.load(write_map(tmp_path, image), inscribed_radius_m=0.0, inflation_radius_m=0.0)
    planner = grid.planner(40)
    blocked = [1.05, 0.95]  # the occupied cell (image row 10 = y 0.9 .. 1.0)
    assert planner.plan([0.3, 0.3], blocked) is None
    assert planner.plan([0.3, 0.3], blocked, tolerance_m=0.15) is not None


def test_plan_many_equals_single_plans():
    grid = OccupancyMap.load(LAB)
    planner = grid.planner(40)
    goals = np.array([[4.0, 3.0], [7.0, 1.0], [8.0, 3.0], [6.0, 6.5]])
    many = planner.plan_many([1.0, 1.0], goals)
    for goal, path in zip(goals, many, strict=True):
        single = planner.plan([1.0, 1.0], goal)
        assert (path is None) == (single is None)
        if path is not None:
            np.testing.assert_allclose(path, single)
    assert many[2] is None  # inside the closed box room


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("resolution: 0.1\norigin: [0, 0, 0]\n", ["missing key 'image'"]),
        ("image: nothere.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", ["nothere.pgm", "not found"]),
        ("image: m.pgm\nresolution: 0.1\norigin: [0, 0]\n", ["origin"]),
        ("image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\n", ["bad number"]),
    ],
)
def test_bad_map_files_name_the_problem(tmp_path, text, words):
    write_map(tmp_path, np.full((3, 3), 254, dtype=np.uint8))
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        OccupancyMap.load(path)
    for word in words:
        assert word in str(info.value)


def test_the_shipped_lab_map():
    grid = OccupancyMap.load(LAB)
    assert grid.shape == (180, 240) and grid.resolution_m == pytest.approx(0.05)
    assert set(np.unique(grid.occupancy)) == {UNKNOWN, 0, LETHAL}
    assert grid.values_at(np.array([1.0, 1.0])) == 0
