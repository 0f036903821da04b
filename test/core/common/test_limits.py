import math

import pytest

from agiprobot_measurement.common.limits import (
    EXCERPT_CHARS,
    LIMITS,
    InputTooLarge,
    check_count,
    check_file_size,
    excerpt,
    local_worker_limit,
)
from agiprobot_measurement.errors import InputError


def test_an_excerpt_of_a_huge_line_is_short_and_says_how_long_the_line_was():
    text = "\x00" * 10_000_000
    quoted = excerpt(text)
    assert len(quoted) < 4 * EXCERPT_CHARS + 40
    assert "10,000,000 characters" in quoted


def test_a_short_value_is_quoted_whole():
    assert excerpt("p_robot 3-DoF") == "'p_robot 3-DoF'"
    assert excerpt(b"abc") == "b'abc'"
    assert excerpt(12.5) == "'12.5'"


def test_bytes_are_cut_and_counted_as_bytes():
    quoted = excerpt(b"x" * 1000, max_chars=10)
    assert quoted.startswith("b'xxxxxxxxxx'") and "1,000 bytes" in quoted


def test_a_file_over_its_limit_is_refused_with_its_size(tmp_path):
    path = tmp_path / "big.txt"
    path.write_bytes(b"0" * 2000)
    assert check_file_size(path, 2000) == 2000
    with pytest.raises(InputTooLarge, match="2,000 bytes, more than the limit of 1,999") as info:
        check_file_size(path, 1999, "calibration data file")
    assert "calibration data file" in str(info.value)
    assert isinstance(info.value, InputError)


def test_counts_over_the_limit_and_not_finite_are_refused():
    assert check_count(10, 10, "faces") == 10
    with pytest.raises(InputTooLarge, match="faces: 11 is more than the limit of 10"):
        check_count(11, 10, "faces")
    with pytest.raises(InputTooLarge):
        check_count(math.nan, 10, "pixels")
    with pytest.raises(InputTooLarge):
        check_count(math.inf, 10, "pixels")


def test_the_local_worker_limit_follows_the_cores():
    assert local_worker_limit(2) == 2 * LIMITS.workers_per_core
    assert local_worker_limit(0) == LIMITS.workers_per_core
