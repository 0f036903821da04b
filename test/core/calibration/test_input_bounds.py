"""Hostile or careless calibration input is refused in bounded time and memory, with short messages, before anything
is written or moved: data files (size, lines, long lines, linear parse), write_data, flag point files, ~zigzag, and
a session change that could not be saved."""

import os
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest

from agiprobot_measurement.calibration.config import load_calibration_config
from agiprobot_measurement.calibration.flange_detection import FlangeDetection
from agiprobot_measurement.calibration.original import utils
from agiprobot_measurement.calibration.procedure import run_collection
from agiprobot_measurement.calibration.registration import (
    CalibrationData,
    CalibrationError,
    Sample,
    parse_data_text,
    parse_vector,
    read_data_file,
    read_flag_points,
    write_data_file,
)
from agiprobot_measurement.calibration.session import CalibrationSession, check_zigzag
from agiprobot_measurement.common.limits import LIMITS, InputTooLarge
from agiprobot_measurement.station import PACKAGE_ROOT

#: an error message of a bounded input quotes at most an excerpt: path, line number, a short quote
MESSAGE_CHARS = 400


def _samples(n, rng=None):
    rng = rng or np.random.default_rng(0)
    pc = rng.uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (n, 3))
    return [Sample(f"{i}_0", pc[i] + [0.5, -0.2, 1.1], pc[i], i < 4) for i in range(n)]


def _pair_text(n):
    return "".join(
        f"p_robot 3-DoF index:{i}\n[0.{i}, 0.5, 0.25]\np_camera 3-DoF index:{i}\n[0.5, 0.{i}, 1.5]\n" for i in range(n)
    )


# ------------------------------------------------------------------------------------------------ data files
def test_a_file_of_nul_bytes_gives_a_short_message(tmp_path):
    path = tmp_path / "sparse_63M.txt"
    with open(path, "wb") as f:
        f.truncate(63 * 1024 * 1024)  # NUL bytes, under the 64 MiB cap: one 63 MB line
    start = time.monotonic()
    with pytest.raises(CalibrationError) as info:
        read_data_file(path)
    assert time.monotonic() - start < 5.0
    message = str(info.value)
    assert len(message) < MESSAGE_CHARS and str(path) in message and "unexpected line" in message


@pytest.mark.parametrize(
    "text",
    [
        "p_robot 3-DoF index:1\n[" + "1.0, " * 2_000_000 + "]\n",  # a 10 MB vector line
        "p_robot 3-DoF index:1\n" + "[" * 1_000_000 + "\n",
        "p_robot 6-DoF index:1\n[" + "1.0, " * 100_000 + "]\n",
        "p_robot 3-DoF index:1\n[" + "x, " * 100_000 + "]\n",
    ],
)
def test_a_long_bad_line_is_quoted_by_an_excerpt(text):
    with pytest.raises(CalibrationError) as info:
        parse_data_text(text, "long.txt")
    assert len(str(info.value)) < MESSAGE_CHARS and "long.txt:2" in str(info.value)


def test_the_parse_is_linear_in_the_samples():
    text = _pair_text(90_000)  # 360,000 lines: under the line bound; the quadratic parse took ~60 s
    start = time.monotonic()
    data = parse_data_text(text, "n90000.txt")
    assert len(data.samples) == 90_000 and [s.index for s in data.samples[:3]] == ["0", "1", "2"]
    assert time.monotonic() - start < 10.0


def test_more_lines_than_the_bound_are_refused_unparsed():
    text = "# comment\n" * (LIMITS.data_file_lines + 1)
    start = time.monotonic()
    with pytest.raises(InputTooLarge, match="lines of the data file"):
        parse_data_text(text, "many.txt")
    assert time.monotonic() - start < 1.0
    assert len(parse_data_text(_pair_text(3), "few.txt", max_lines=12).samples) == 3
    with pytest.raises(InputTooLarge):
        parse_data_text(_pair_text(3), "few.txt", max_lines=11)


# ------------------------------------------------------------------------------------------------ write_data
@pytest.mark.parametrize(
    "data, title",
    [
        ([[float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0]], "77"),
        ([[1e400, 0.0, 0.0], [0.0, 0.0, 0.0]], "77"),
        ([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0]], "1\nH_final\n[1,2,3,4]"),
        ([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0]], "a b"),
        ([[0.1, 0.2, 0.3], [0.0, 0.0, float("inf")]], "78"),
    ],
)
def test_write_data_refuses_a_sample_the_reader_would_refuse(tmp_path, data, title):
    path = write_data_file(tmp_path / "data.txt", CalibrationData(_samples(12)), "original")
    before = path.read_bytes()
    with pytest.raises(CalibrationError, match="nothing written"):
        utils.write_data(path, data, title, type="point_pair")
    assert path.read_bytes() == before
    assert len(utils.read_data(path, "point_pair")[0]) == 12
    utils.write_data(path, [[0.1, 0.2, 0.3], [0.0, 0.0, 1.0]], "79", type="point_pair")  # a good one still goes
    assert len(utils.read_data(path, "point_pair")[0]) == 13


def test_write_data_refuses_a_bad_matrix_or_title(tmp_path):
    path = tmp_path / "data.txt"
    h = np.eye(4)
    h[0, 0] = np.nan
    with pytest.raises(CalibrationError, match="nothing written"):
        utils.write_data(path, h, "H_final", type="H")
    with pytest.raises(CalibrationError, match="nothing written"):
        utils.write_data(path, np.eye(4), "H_final\nH", type="H")
    with pytest.raises(CalibrationError, match="nothing written"):
        utils.write_data(path, 10, "criteria:plane\n[1]", type="criteria")
    assert not path.exists()


# ---------------------------------------------------------------------------------------------- flag points
def test_a_flag_point_file_is_never_quoted(tmp_path):
    path = tmp_path / "os-release"
    path.write_text('PRETTY_NAME="Secret GNU/Linux 12"\nNAME="Secret"\n')
    with pytest.raises(CalibrationError) as info:
        read_flag_points(path)
    assert "Secret" not in str(info.value) and f"{path}:1" in str(info.value)
    path.write_text("[0.1, 0.2, nan]\n")
    with pytest.raises(CalibrationError) as info:
        read_flag_points(path)
    assert "nan" not in str(info.value) and "3 finite numbers" in str(info.value)


# --------------------------------------------------------------------------------------------------- zigzag
@pytest.mark.parametrize(
    "zigzag, key",
    [
        ("lots", "zigzag must be a mapping"),
        ({"fractions": [1e9, -5], "jitter_m": float("nan"), "seed": -1}, r"zigzag\.fractions\[0\]"),
        ({"fractions": [0.5], "jitter_m": 1e308}, r"zigzag\.jitter_m"),
        ({"fractions": [0.5], "jitter_m": float("nan")}, r"zigzag\.jitter_m"),
        ({"fractions": [0.5], "seed": -1}, r"zigzag\.seed"),
        ({"fractions": [0.5], "seed": "x"}, r"zigzag\.seed"),
        ({"fractions": "0.5"}, r"zigzag\.fractions"),
        ({"fractions": []}, r"zigzag\.fractions"),
        ({"fractions": [0.5] * 1000}, r"zigzag\.fractions"),
        ({"fractions": ["a"]}, r"zigzag\.fractions\[0\]"),
        ({"fraction": [0.5]}, "unknown key 'fraction'"),
    ],
)
def test_bad_zigzag_values_are_named(zigzag, key):
    with pytest.raises(CalibrationError, match=key):
        check_zigzag(zigzag)


def test_good_zigzag_values_pass():
    assert check_zigzag(None)["fractions"] == (0.25, 0.5, 0.75)
    assert check_zigzag({"fractions": [0, 1], "jitter_m": 0, "seed": None}) == {
        "fractions": (0.0, 1.0),
        "jitter_m": 0.0,
        "seed": None,
    }


class _CountingRobot:
    moves = 0

    def move_to(self, *args, **kwargs):
        self.moves += 1
        raise AssertionError("the robot must not move")


def test_a_bad_zigzag_is_refused_before_the_robot_moves():
    config = load_calibration_config()
    config["zigzag"] = "lots"
    robot = _CountingRobot()
    with pytest.raises(CalibrationError, match="zigzag"):
        run_collection(robot, None, CalibrationSession.from_config(config, None), config)
    assert robot.moves == 0


# ------------------------------------------------------------------------------------------ session changes
def _failing_disk(monkeypatch):
    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("agiprobot_measurement.calibration.session.write_data_file", full)


def test_a_removal_that_cannot_be_saved_removes_nothing(tmp_path, monkeypatch):
    session = CalibrationSession.from_config(load_calibration_config(), tmp_path / "data.txt")
    session.data.samples = _samples(12)
    session.save()
    _failing_disk(monkeypatch)
    with pytest.raises(OSError):
        session.remove("last")
    with pytest.raises(OSError):
        session.remove("3_0")
    assert len(session.data.samples) == 12 and len(read_data_file(tmp_path / "data.txt").samples) == 12
    with pytest.raises(OSError):
        session.add_sample(np.zeros(3), FlangeDetection(True, centre_m=np.ones(3), plane_points=9, circle_inliers=9))
    assert len(session.data.samples) == 12
    monkeypatch.undo()
    assert session.remove("last").index == "11_0" and len(read_data_file(tmp_path / "data.txt").samples) == 11


# ---------------------------------------------------------------------------------------------- calibrate.py
def test_calibrate_cli_does_not_replace_an_existing_output(tmp_path):
    data = write_data_file(tmp_path / "data.txt", CalibrationData(_samples(8)))
    cli = [sys.executable, str(PACKAGE_ROOT / "scripts" / "calibrate.py"), str(data)]
    for flag in ("-o", "--write-data", "--write-targets"):
        existing = tmp_path / f"plan{flag}.yaml"
        existing.write_text("plan: keep me\n")
        out = subprocess.run([*cli, flag, str(existing)], capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and "exists" in out.stderr and "--overwrite" in out.stderr, out.stderr
        assert existing.read_text() == "plan: keep me\n"
    out = subprocess.run([*cli, "-o", str(existing), "--overwrite"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "matrix" in existing.read_text() and os.path.getsize(existing) > 100


def test_a_vector_line_of_millions_of_values_is_refused_without_splitting_it():
    line = "[" + "0.5, " * 5_000_000 + "0.5]"
    tracemalloc.start()
    try:
        with pytest.raises(CalibrationError, match="expected 3 finite numbers"):
            parse_vector(line, 3, "line 2")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100e6  # one copy of the 25 MB body at most; split, it would be 5 million strings (> 250 MB)
    assert parse_vector("[1, 2, 3, ]", 3, "line 4").tolist() == [1.0, 2.0, 3.0]
