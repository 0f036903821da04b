"""The original calibration's data file, both directions.

Original -> project: fixtures laid out as the original writer (``utils.write_data``) lays a file out: every block is
its title line, its value lines (``str()`` of a Python list, matrix rows ``[v, v, v, v, ]``) and then ``"\\n \\n"``;
point pairs ``p_robot 6-DoF index:<id>`` with 7 values (x, y, z, quaternion) and ``p_camera 3-DoF index:<id>``;
criteria written once per flag point; ``H_coarse`` (4 rows) followed by ``Trans_coarse`` (``str(list(H[0:3, 3]))`` of
a numpy matrix) and ``Rot_coarse`` (a tuple); the fine pairs after them; ``H_final``.

Project (original mode) -> original: :class:`OriginalReader` parses as the original reader (``utils.read_data``)
does: a vector is the text between the first ``[`` and the next ``]`` split at commas, a last item of one space
dropped; pairs at every line containing ``p_robot`` (next line the robot values, of which the first 3, one line
skipped, then the camera values); H = the 4 lines after the first line containing ``H``; criteria = at every line
containing ``plane`` the integer on the next line and the one 4 lines further, returned as [smallest circle count,
smallest plane count]; a target file = every line a vector.
"""

import subprocess
import sys

import numpy as np
import pytest

from agiprobot_measurement.calibration.registration import (
    CalibrationData,
    CalibrationError,
    Sample,
    calibrate_data,
    format_data_file,
    read_data_file,
    read_flag_points,
    read_result_yaml,
    write_data_file,
    write_flag_points,
)
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.station import PACKAGE_ROOT

CLI = PACKAGE_ROOT / "scripts" / "calibrate.py"


# ------------------------------------------------------------------- the original's parsing rules (facts), small
class OriginalReader:
    def __init__(self, text: str):
        self.lines = text.splitlines(keepends=True)

    @staticmethod
    def vector(line: str) -> np.ndarray:
        items = line.split("[")[1].split("]")[0].split(",")
        if items[-1] == " ":
            items = items[:-1]
        return np.array(items, dtype=np.double)

    def point_pairs(self):
        robot, camera, k = [], [], 0
        while k < len(self.lines):
            if "p_robot" in self.lines[k]:
                robot.append(self.vector(self.lines[k + 1])[:3])
                camera.append(self.vector(self.lines[k + 3]))
                k += 4
            else:
                k += 1
        return robot, camera

    def h(self) -> np.ndarray:
        first = next(k for k, line in enumerate(self.lines) if "H" in line)  # StopIteration: the original hangs
        return np.array([self.vector(self.lines[first + 1 + r]) for r in range(4)])

    def criteria(self):
        planes, circles = [], []
        for k, line in enumerate(self.lines):
            if "plane" in line:
                planes.append(int(self.lines[k + 1]))
                circles.append(int(self.lines[k + 5]))
        return [min(circles), min(planes)] if circles and circles[-1] > 0 else None

    def targets(self):
        return [list(self.vector(line)) for line in self.lines]


# -------------------------------------------------------------------- the original writer's layout (facts)
def block(title: str, *values: str) -> str:
    return "".join(f"{line}\n" for line in (title, *values)) + "\n \n"


def matrix_rows(h) -> list[str]:
    return ["[" + "".join(f"{v}, " for v in row) + "]" for row in np.asarray(h).tolist()]


def pair_block(index: str, p_robot7, p_camera) -> str:
    return f"p_robot 6-DoF index:{index}\n{list(p_robot7)}\np_camera 3-DoF index:{index}\n{list(p_camera)}\n" + "\n \n"


def truth_transform() -> np.ndarray:
    h = np.eye(4)
    angle = np.radians(30.0)
    h[:3, :3] = [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    h[:3, 3] = [0.5, -0.2, 1.1]
    return h


@pytest.fixture
def pairs():
    rng = np.random.default_rng(4)
    p_camera = rng.uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (9, 3))
    p_robot = transform_points(truth_transform(), p_camera)
    return p_robot, p_camera


def original_file_text(p_robot, p_camera, flag_count=4) -> str:
    """A data file as the original cal_main writes it (use_mp: flag indices prefixed flag<i>_)."""
    quaternion = [0.0, 0.70710678, 0.0, 0.70710678]
    text = ""
    counts = [(14562, 407), (8379, 324), (14861, 456), (13376, 393)]
    indices = [f"15446271{k:02d}0_603512048721" for k in range(len(p_robot))]
    for k in range(flag_count):
        text += block("criteria:plane", str(counts[k][0])) + block("criteria:line", str(counts[k][1]))
        text += pair_block(f"flag{k}_{indices[k]}", [*p_robot[k].tolist(), *quaternion], p_camera[k].tolist())
    h = truth_transform()
    text += block("H_coarse", *matrix_rows(h))
    text += block("Trans_coarse", f"[matrix([[{h[0, 3]}]]), matrix([[{h[1, 3]}]]), matrix([[{h[2, 3]}]])]")
    text += block("Rot_coarse", str((0.0, 0.0, float(np.radians(30.0)))))
    for k in range(flag_count, len(p_robot)):
        text += pair_block(indices[k], [*p_robot[k].tolist(), *quaternion], p_camera[k].tolist())
    text += block("H_final", *matrix_rows(h))
    return text


# --------------------------------------------------------------------------------------- original -> project
def test_the_original_layout_is_read(tmp_path, pairs):
    p_robot, p_camera = pairs
    path = tmp_path / "data.txt"
    path.write_text(original_file_text(p_robot, p_camera))
    data = read_data_file(path)
    assert len(data.samples) == 9
    np.testing.assert_allclose(np.array([s.p_robot_m for s in data.samples]), p_robot, atol=1e-12)
    np.testing.assert_allclose(np.array([s.p_camera_m for s in data.samples]), p_camera, atol=1e-12)
    assert [s.flag for s in data.samples] == [True] * 4 + [False] * 5
    assert data.samples[0].index == "flag0_15446271000_603512048721"
    np.testing.assert_allclose(data.h_coarse, truth_transform(), atol=1e-12)
    np.testing.assert_allclose(data.h_final, truth_transform(), atol=1e-12)
    assert (data.criteria_plane, data.criteria_line) == (8379, 324)  # the smallest, as the original reads them
    coarse = calibrate_data(data, "cal_coarse")
    fine = calibrate_data(data, "cal_fine")
    assert len(coarse.inliers) == 4 and len(fine.inliers) == 9
    np.testing.assert_allclose(fine.transform, truth_transform(), atol=1e-9)


def test_original_layout_errors_name_the_line(tmp_path, pairs):
    p_robot, p_camera = pairs
    text = original_file_text(p_robot, p_camera)
    bad_pose = tmp_path / "bad_pose.txt"
    bad_pose.write_text(text.replace(", 0.0, 0.70710678, 0.0, 0.70710678]", ", 0.70710678]", 1))
    with pytest.raises(CalibrationError, match=r"bad_pose.txt:\d+: a 6-DoF pose needs 7 values"):
        read_data_file(bad_pose)
    short_h = tmp_path / "short_h.txt"
    rows = matrix_rows(truth_transform())
    short_h.write_text(block("H_coarse", *rows[:2]))
    with pytest.raises(CalibrationError, match="H_coarse needs 3 or 4 rows"):
        read_data_file(short_h)
    bad_row = tmp_path / "bad_row.txt"
    bad_row.write_text(block("H_coarse", *rows[:3], "[1.0, x, ]"))
    with pytest.raises(CalibrationError, match=r"bad_row\.txt:5: not a list of numbers"):
        read_data_file(bad_row)


def test_an_original_target_file_is_read(tmp_path):
    path = tmp_path / "target.txt"
    points = [[-0.30, 0.73, 0.39], [-0.52, 0.20, 0.17], [-0.74, 0.58, 0.29], [-0.37, 0.82, 0.23]]
    path.write_text("".join(f"{p}\n" for p in points))
    np.testing.assert_allclose(read_flag_points(path), points)


def _cli(*args):
    return subprocess.run([sys.executable, str(CLI), *map(str, args)], capture_output=True, text=True, timeout=60)


def test_cli_gives_the_same_result_for_both_formats(tmp_path, pairs):
    p_robot, p_camera = pairs
    p_camera = p_camera + np.random.default_rng(5).normal(0.0, 0.0002, p_camera.shape)  # measured, not exact
    original = tmp_path / "original.txt"
    original.write_text(original_file_text(p_robot, p_camera))
    samples = [Sample(f"{k}_0", p_robot[k], p_camera[k], k < 4) for k in range(len(p_robot))]
    project = write_data_file(
        tmp_path / "project.txt", CalibrationData(samples, criteria_plane=8379, criteria_line=324)
    )
    for mode in ("cal_fine", "cal_coarse"):
        results = []
        for name, path in (("original", original), ("project", project)):
            out = _cli(path, "--mode", mode, "-o", tmp_path / f"{name}_{mode}.yaml")
            assert out.returncode == 0, out.stderr
            results.append(read_result_yaml(tmp_path / f"{name}_{mode}.yaml"))
        np.testing.assert_allclose(results[0], results[1], atol=1e-12)
        assert np.linalg.norm(results[0][:3, 3] - truth_transform()[:3, 3]) < 0.002


def test_cli_converts_a_project_file_for_the_original(tmp_path, pairs):
    p_robot, p_camera = pairs
    samples = [Sample(f"{k}_0", p_robot[k], p_camera[k], k < 4) for k in range(len(p_robot))]
    project = write_data_file(tmp_path / "project.txt", CalibrationData(samples, criteria_plane=900, criteria_line=80))
    converted = tmp_path / "for_original.txt"
    targets = tmp_path / "target.txt"
    out = _cli(project, "--write-data", converted, "--write-targets", targets, "--write-format", "original")
    assert out.returncode == 0, out.stderr
    reader = OriginalReader(converted.read_text())
    robot, camera = reader.point_pairs()
    np.testing.assert_allclose(np.array(robot), p_robot, atol=1e-12)
    np.testing.assert_allclose(np.array(camera), p_camera, atol=1e-12)
    np.testing.assert_allclose(reader.h(), truth_transform(), atol=1e-9)  # the fine result as H_final
    assert reader.criteria() == [80, 900]
    np.testing.assert_allclose(OriginalReader(targets.read_text()).targets(), p_robot[:4], atol=1e-12)
    back = read_data_file(converted)
    assert [s.flag for s in back.samples] == [True] * 4 + [False] * 5
    out = _cli(project, "--write-data", converted, "--write-format", "nonsense")
    assert out.returncode == 2 and "error" in out.stderr


# --------------------------------------------------------------------------------------- project -> original
def test_original_mode_is_what_the_original_reader_reads(tmp_path, pairs):
    p_robot, p_camera = pairs
    h_coarse = truth_transform()
    h_coarse[:3, 3] += 0.001
    samples = [Sample(f"1733_{k:06d}_{k:04d}", p_robot[k], p_camera[k], k < 4) for k in range(len(p_robot))]
    data = CalibrationData(
        samples, h_coarse=h_coarse, criteria_plane=3634, criteria_line=179, h_final=truth_transform()
    )
    path = write_data_file(tmp_path / "data.txt", data, format="original")
    text = path.read_text()
    reader = OriginalReader(text)
    robot, camera = reader.point_pairs()
    order = [s for s in samples if s.flag] + [s for s in samples if not s.flag]
    np.testing.assert_allclose(np.array(robot), [s.p_robot_m for s in order], atol=1e-15)
    np.testing.assert_allclose(np.array(camera), [s.p_camera_m for s in order], atol=1e-15)
    np.testing.assert_allclose(reader.h(), h_coarse, atol=1e-15)  # 4 rows, the first H block
    assert reader.criteria() == [179, 3634]
    assert "p_robot 3-DoF index:flag0_1733_000000_0000\n" in text
    assert "criteria:plane\n3634\n\n \ncriteria:line\n179\n\n \n" in text
    assert text.count(", ]\n") == 8  # H_coarse and H_final, 4 rows each
    # and back: the same content
    back = read_data_file(path)
    assert [s.flag for s in back.samples] == [s.flag for s in order]
    np.testing.assert_allclose([s.p_robot_m for s in back.samples], [s.p_robot_m for s in order], atol=0)
    np.testing.assert_allclose(back.h_coarse, h_coarse, atol=0)
    np.testing.assert_allclose(back.h_final, truth_transform(), atol=0)
    assert (back.criteria_plane, back.criteria_line) == (3634, 179)


def test_the_project_layout_is_not_what_the_original_reads(tmp_path, pairs):
    """Why the original mode exists: the original's reader fails on the project's H_coarse and criteria."""
    p_robot, p_camera = pairs
    samples = [Sample(f"{k}_0", p_robot[k], p_camera[k], k < 4) for k in range(len(p_robot))]
    data = CalibrationData(samples, h_coarse=truth_transform(), criteria_plane=10, criteria_line=5)
    reader = OriginalReader(format_data_file(data))
    with pytest.raises((IndexError, ValueError)):
        reader.h()
    with pytest.raises((IndexError, ValueError)):
        reader.criteria()


def test_flag_point_files_in_both_formats(tmp_path):
    points = np.array([[-0.30, 0.73, 0.39], [-0.52, 0.20, 0.17], [-0.74, 0.58, 0.29], [-0.37, 0.82, 0.23]])
    original = write_flag_points(tmp_path / "target.txt", points, format="original")
    assert not any(line.startswith("#") or not line.strip() for line in original.read_text().splitlines())
    np.testing.assert_allclose(OriginalReader(original.read_text()).targets(), points)
    project = write_flag_points(tmp_path / "flags.txt", points)
    assert project.read_text().startswith("#")
    with pytest.raises(ValueError):
        OriginalReader(project.read_text()).targets()
    np.testing.assert_allclose(read_flag_points(project), points)
    np.testing.assert_allclose(read_flag_points(original), points)
    with pytest.raises(CalibrationError, match="format must be one of project, original"):
        write_flag_points(tmp_path / "x.txt", points, format="yaml")
