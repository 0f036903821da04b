"""The benchmarks' harness: KEY=VALUE options, conditions files, target tables, JSON and tables, the child process
runner (timeouts, failures, its JSON line) and peak memory; and the benchmarks stay out of the installed product."""

from __future__ import annotations

import importlib
import json
import sys

import numpy as np
import pytest

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.errors import InputError
from benchmarks import harness
from benchmarks.harness import (
    ROOT,
    ChildFailed,
    OptionError,
    Target,
    format_table,
    format_targets,
    load_conditions,
    number_value,
    parse_key_values,
    peak_rss_mb,
    run_json,
    run_process,
    switch_value,
    targets_json,
    timed,
    write_json,
)

MODULES = (
    "benchmarks.planning.pipeline",
    "benchmarks.planning.parts",
    "benchmarks.planning.scale",
    "benchmarks.planning.set_cover",
    "benchmarks.planning.metrology",
    "benchmarks.motion.core",
    "benchmarks.motion.collision",
    "benchmarks.nbv3d.loop",
    "benchmarks.nbv3d.map",
    "benchmarks.nbv2d",
    "benchmarks.mild",
    "benchmarks.calibration",
    "benchmarks.phoxi",
    "benchmarks.reliability.run",
)


# ------------------------------------------------------------------------------------------------------ options
def test_key_values_are_parsed_and_converted():
    got = parse_key_values(["a=1", "b=x=y"], "--opt")
    assert got == {"a": "1", "b": "x=y"}  # the first '=' splits
    numbers = parse_key_values(["w=0.5", "v=2"], "--opt", "KEY=NUMBER", value=lambda _, t: number_value(t))
    assert numbers == {"w": 0.5, "v": 2.0}
    assert parse_key_values([], "--opt") == {}


@pytest.mark.parametrize("item", ["novalue", "=3", "unknown=1"])
def test_a_bad_item_names_the_option_the_item_and_the_known_keys(item):
    with pytest.raises(OptionError) as error:
        parse_key_values([item], "--opt", "NAME=VALUE", names=("alpha", "beta"))
    message = str(error.value)
    assert message.startswith(f"--opt {item!r}: expected NAME=VALUE, NAME one of alpha, beta")


def test_a_converters_error_is_prefixed_with_the_item():
    with pytest.raises(OptionError, match=r"^--opt 'w=lots': value: expected a number, got 'lots'$"):
        parse_key_values(["w=lots"], "--opt", value=lambda _, t: number_value(t))
    with pytest.raises(OptionError, match="must be >= 0"):
        parse_key_values(["w=-1"], "--opt", value=lambda _, t: number_value(t, low=0.0))
    assert issubclass(OptionError, InputError)


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "", "1,5"])
def test_number_values_are_finite_numbers(text):
    with pytest.raises(InputError):
        number_value(text)


def test_number_values_read_plain_numbers():
    assert number_value(" 2.5 ") == 2.5
    assert number_value("0", low=0.0) == 0.0


@pytest.mark.parametrize(("text", "expected"), [("true", True), ("FALSE", False), ("1", True), ("0", False)])
def test_switches(text, expected):
    assert switch_value(text) is expected


@pytest.mark.parametrize("text", ["yes", "False!", "2", ""])
def test_a_switch_refuses_anything_else(text):
    with pytest.raises(OptionError, match="is a switch"):
        switch_value(text)


# --------------------------------------------------------------------------------------------------- conditions
def test_conditions_are_read_and_checked(tmp_path):
    (tmp_path / "demo.yaml").write_text("density: 0.03\ncount: 12\nlimits: {none: 20}\nname: cube\nbad: -1\n")
    conditions = load_conditions("demo", tmp_path)
    assert conditions.number("density", low=0.0) == 0.03
    assert conditions.whole("count", low=1) == 12
    assert conditions.mapping("limits") == {"none": 20}
    assert conditions["name"] == "cube" and conditions.get("absent", 7) == 7
    with pytest.raises(ConfigError, match=r"demo\.yaml: missing key 'absent'"):
        conditions["absent"]
    with pytest.raises(ConfigError, match=r"demo\.yaml: bad: must be >= 0"):
        conditions.number("bad", low=0.0)
    with pytest.raises(ConfigError, match="must be a whole number"):
        conditions.whole("density")
    with pytest.raises(ConfigError, match="name: expected a mapping"):
        conditions.mapping("name")


def test_a_conditions_file_must_hold_a_mapping(tmp_path):
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping of conditions"):
        load_conditions("list", tmp_path)
    with pytest.raises(ConfigError, match="file not found"):
        load_conditions("absent", tmp_path)


def test_every_shipped_conditions_file_is_used_by_a_benchmark():
    files = sorted(p.stem for p in harness.CONDITIONS_DIR.glob("*.yaml"))
    assert files
    sources = "".join(p.read_text() for p in (ROOT / "benchmarks").rglob("*.py"))
    for name in files:
        assert isinstance(load_conditions(name).values, dict)
        assert f'load_conditions("{name}")' in sources, f"conditions/{name}.yaml is read by no benchmark"


# ------------------------------------------------------------------------------------------------------ targets
def test_targets_table_states_each_verdict():
    targets = [
        Target("set cover", "0.73 s", "<= 10 s", True),
        Target("peak memory", "5,000 MB", "<= 4,096 MB", False),
    ]
    lines = format_targets(targets).splitlines()
    assert [cell.strip() for cell in lines[0].split("|")] == ["ok", "target", "measured", "bound"]
    assert lines[2].startswith("met ") and "set cover" in lines[2] and "0.73 s" in lines[2] and "<= 10 s" in lines[2]
    assert lines[3].startswith("MISSED") and "peak memory" in lines[3]
    # every row's columns line up under the header's
    assert len({line.index("|") for line in lines if "|" in line}) == 1
    assert targets_json(targets) == [
        {"name": "set cover", "measured": "0.73 s", "target": "<= 10 s", "ok": True},
        {"name": "peak memory", "measured": "5,000 MB", "target": "<= 4,096 MB", "ok": False},
    ]
    assert targets_json([Target("x", "1", "2", np.bool_(True))])[0]["ok"] is True  # JSON-able, not numpy's bool


# ------------------------------------------------------------------------------------------------- tables, JSON
def test_tables_pad_columns_align_right_where_asked_and_accept_short_rows():
    text = format_table(["name", "value"], [["a", "1.0"], ["longer", "12,345.6"], ["short"]], right=(1,), sep="  ")
    header, rule, *rows = text.splitlines()
    assert header == "name" + " " * 7 + "value"  # "name" padded to "longer", "value" right-aligned to "12,345.6"
    assert rule == "------  --------"
    assert rows == ["a" + " " * 12 + "1.0", "longer  12,345.6", "short"]
    piped = format_table(["a", "b"], [["x", "y"]]).splitlines()
    assert piped[1] == "--|--" and piped[2] == "x | y"


def test_json_is_written_atomically_with_folders_and_numpy_numbers(tmp_path):
    path = tmp_path / "new" / "folder" / "r.json"
    written = write_json(path, {"value": np.float64(1.5), "count": np.int64(3), "rows": [1, 2]})
    assert written == path
    assert json.loads(path.read_text()) == {"value": 1.5, "count": 3.0, "rows": [1, 2]}
    write_json(path, [1])  # replaces
    assert json.loads(path.read_text()) == [1]
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # no temporary file left


# ---------------------------------------------------------------------------------------------------- processes
def python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_a_process_past_its_timeout_is_a_timed_out_result():
    done = run_process(python("import time; print('started', flush=True); time.sleep(30)"), timeout_s=1.0)
    assert done.timed_out and done.returncode is None
    assert 0.9 <= done.seconds < 15
    assert "started" in done.stdout


def test_a_finished_process_gives_its_code_and_output():
    done = run_process(python("import sys; print('out'); print('err', file=sys.stderr); sys.exit(3)"), timeout_s=60)
    assert not done.timed_out and done.returncode == 3
    assert done.stdout == "out\n" and done.stderr == "err\n"


def test_a_child_returns_its_last_json_line():
    code = "import json; print('noise'); print(json.dumps({'a': 1})); print('more noise'); print(json.dumps({'a': 2}))"
    assert run_json(python(code), timeout_s=60) == {"a": 2}


@pytest.mark.parametrize(
    ("code", "message"),
    [
        ("import sys; print('{\"a\": 1}'); sys.exit('boom')", r"^exit 1: boom$"),
        ("print('no json here')", r"^exit 0: no output$"),
        ("import time; time.sleep(30)", r"^timed out after 1 s$"),
    ],
)
def test_a_failed_child_is_named(code, message):
    with pytest.raises(ChildFailed, match=message):
        run_json(python(code), timeout_s=1.0)


def test_children_run_from_the_checkout_and_find_the_benchmarks():
    command = harness.child_command("benchmarks.planning.set_cover", "--help")
    assert command[:3] == [sys.executable, "-m", "benchmarks.planning.set_cover"]
    done = run_process(command, timeout_s=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "set cover" in done.stdout


# --------------------------------------------------------------------------------------------- memory and time
def test_peak_memory_grows_with_what_a_process_touches():
    code = (
        "from benchmarks.harness import peak_rss_mb; before = peak_rss_mb(); "
        "block = b'x' * (300 * 2**20); "
        "print(before, peak_rss_mb())"
    )
    done = run_process(python(code), timeout_s=300)
    assert done.returncode == 0, done.stderr[-2000:]
    before, after = (float(v) for v in done.stdout.split())
    # MB, not KiB or bytes; a child's peak starts at its parent's resident memory at the fork (Linux), so only the
    # block's size is a lower bound
    assert 300 <= after <= max(before, 100) + 400
    assert before <= after
    assert 0 < peak_rss_mb() < 1e6


def test_timed_counts_its_calls_and_keeps_the_last_result():
    calls = []
    timing = timed(lambda: calls.append(1) or len(calls), repeats=3, warmup=True)
    assert len(calls) == 4 and timing.result == 4
    assert 0 <= timing.min_s <= timing.median_s <= timing.max_s
    assert timing.cpu_median_s >= 0
    assert len(calls) == 4
    timed(lambda: calls.append(1), repeats=0)  # at least one call
    assert len(calls) == 5


# ---------------------------------------------------------------------------------------------- the benchmarks
@pytest.mark.parametrize("module", MODULES)
def test_every_benchmark_reads_its_conditions_and_options(module, capsys):
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_the_benchmarks_are_not_in_the_product():
    assert not list((ROOT / "scripts").glob("bench_*")), "benchmarks belong in benchmarks/, not scripts/"
    assert not (ROOT / "src" / "benchmarks").exists()
    for build_file in ("CMakeLists.txt", "setup.py"):
        assert "benchmarks" not in (ROOT / build_file).read_text(), f"{build_file} installs the benchmarks"
