"""One error hierarchy; the config validators name the place of the bad value."""

import itertools

import numpy as np
import pytest

from agiprobot_measurement import errors
from agiprobot_measurement.common import config


def test_every_package_error_is_under_the_one_base():
    from agiprobot_measurement.calibration.registration import CalibrationError
    from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError
    from agiprobot_measurement.motion.trajectory import TrajectoryError
    from agiprobot_measurement.planning.cover.solve import SetCoverError
    from agiprobot_measurement.planning.part_loading import PartLoadError
    from agiprobot_measurement.planning.plan.plan_io import PlanError, PlanFileNotFoundError
    from agiprobot_measurement.planning.trajectory_manager import ExecutionError, PlanningError
    from agiprobot_measurement.sensors.laser_line.model import ProcessingContextError
    from agiprobot_measurement.sensors.phoxi.device import PhoxiError
    from agiprobot_measurement.sensors.phoxi.point_cloud_io import OutputPathError

    user_errors = (CalibrationError, TimeParameterizationError, TrajectoryError, PartLoadError, PlanError,
                   PlanFileNotFoundError, SetCoverError, OutputPathError, config.ConfigError)  # fmt: skip
    for error in user_errors:
        assert issubclass(error, errors.InputError) and issubclass(error, ValueError), error
        assert errors.is_input_error(error("x"))
    for error in (ExecutionError, PlanningError, ProcessingContextError, PhoxiError):
        assert issubclass(error, errors.AgiprobotError), error
    assert issubclass(PlanFileNotFoundError, FileNotFoundError)
    assert not errors.is_input_error(errors.InternalError("x"))
    assert issubclass(errors.InternalError, RuntimeError)


def test_validators_name_the_place(tmp_path):
    assert np.allclose(config.vector([1, 2, 3], 3, "f: k"), [1, 2, 3])
    with pytest.raises(config.ConfigError, match="f: k: expected 3 numbers"):
        config.vector([1, 2], 3, "f: k")
    with pytest.raises(config.ConfigError, match="finite"):
        config.vector([1, np.nan, 3], 3, "f: k")
    with pytest.raises(config.ConfigError, match="positive"):
        config.positive(-1, "f: k")
    with pytest.raises(config.ConfigError, match="missing key 'a'"):
        config.require({}, "a", "f")
    with pytest.raises(config.ConfigError, match="file not found"):
        config.read_yaml(tmp_path / "none.yaml")
    (tmp_path / "bad.yaml").write_text("a: [1, 2\n")
    with pytest.raises(config.ConfigError, match="malformed YAML"):
        config.read_yaml(tmp_path / "bad.yaml")


def alias_bomb(levels: int = 9, fan_out: int = 10) -> str:
    names = [f"l{i}" for i in range(levels + 1)]
    lines = [f"{names[0]}: &{names[0]} [" + ", ".join(["x"] * fan_out) + "]"]
    for prev, name in itertools.pairwise(names):
        lines.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * fan_out) + "]")
    return "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_fast_and_small_aliases_load():
    import time

    start = time.perf_counter()
    with pytest.raises(config.ConfigError, match=r"bomb\.yaml: YAML expands to more than"):
        config.load_yaml_text(alias_bomb(), "bomb.yaml")
    assert time.perf_counter() - start < 5.0  # refused before anything is expanded
    assert config.load_yaml_text("a: &x [1, 2]\nb: *x\n") == {"a": [1, 2], "b": [1, 2]}
    # the bound is the expanded size: 3 levels of 10 = 1,111 nodes pass a 2,000 limit, 4 levels do not
    assert config.load_yaml_text(alias_bomb(2), max_expanded_nodes=2000)
    with pytest.raises(config.ConfigError, match="expands"):
        config.load_yaml_text(alias_bomb(3), max_expanded_nodes=2000)


@pytest.mark.parametrize(
    "text",
    ["a: &a [*a]\n", "a: &a {k: *a}\n", "a: &a [1, [2, *a]]\n", "&r [x, {y: *r}]\n"],
    ids=["list", "mapping", "nested", "root"],
)
def test_a_yaml_alias_that_contains_itself_is_refused(tmp_path, text):
    # read_yaml of such a file used to run until memory ran out
    (tmp_path / "cycle.yaml").write_text(text)
    with pytest.raises(config.ConfigError, match=r"cycle\.yaml: a YAML alias refers to a node that contains it"):
        config.read_yaml(tmp_path / "cycle.yaml")
    # the same anchor used twice side by side is not a cycle
    assert config.load_yaml_text("a: &a [1]\nb: [*a, *a]\n") == {"a": [1], "b": [[1], [1]]}


def test_yaml_bounds_size_depth_and_encoding(tmp_path):
    with pytest.raises(config.ConfigError, match="nested deeper than 64"):
        config.load_yaml_text("[" * 100 + "]" * 100)
    with pytest.raises(config.ConfigError, match="more than the limit"):
        config.load_yaml_text("a: 1\n" * 100, max_bytes=50)
    (tmp_path / "binary.yaml").write_bytes(b"\x80\x81 binary")
    with pytest.raises(config.ConfigError, match=r"binary\.yaml: not a UTF-8 text file"):
        config.read_yaml(tmp_path / "binary.yaml")
    with pytest.raises(config.ConfigError, match="is a directory"):
        config.read_yaml(tmp_path)
    assert config.load_yaml_text("") is None


def test_number_whole_and_lists_refuse_by_name():
    assert config.number("2.5", "k", low=0) == 2.5
    assert config.whole(3.0, "k", low=1) == 3
    assert config.number_list([1, 2], "k", low=0) == [1.0, 2.0]
    np.testing.assert_array_equal(config.vector([1, 2, 3], 3, "k", positive=True), [1.0, 2.0, 3.0])
    bad = [
        (lambda: config.number(True, "a.b"), "a.b: expected a number"),
        (lambda: config.number(float("nan"), "a.b"), "a.b: must be a finite"),
        (lambda: config.number("1e999", "a.b"), "a.b: must be a finite"),
        (lambda: config.number(0, "a.b", low=0, low_inclusive=False), "a.b: must be > 0"),
        (lambda: config.number(5, "a.b", high=4), "a.b: must be <= 4"),
        (lambda: config.whole(2.5, "a.b"), "a.b: must be a whole number"),
        (lambda: config.number_list("abc", "a.b"), "a.b: expected a list"),
        (lambda: config.number_list([], "a.b"), "a.b: expected at least 1"),
        (lambda: config.number_list([1, "x"], "a.b"), r"a.b\[1\]: expected a number"),
        (lambda: config.vector([1, -1, 1], 3, "a.b", positive=True), "a.b: values must be positive"),
        (lambda: config.positive(float("inf"), "a.b"), "a.b: must be a finite"),
    ]
    for call, message in bad:
        with pytest.raises(config.ConfigError, match=message):
            call()


def test_a_hostile_value_is_quoted_short():
    with pytest.raises(config.ConfigError) as info:
        config.number("x" * 100_000, "k")
    assert len(str(info.value)) < 120
