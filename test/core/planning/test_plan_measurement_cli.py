"""scripts/plan_measurement.py as a user runs it: a subprocess, its exit status, its output and its files."""

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from agiprobot_measurement.planning.plan.plan_io import load_execution_plan
from agiprobot_measurement.station import PACKAGE_ROOT

SCRIPT = PACKAGE_ROOT / "scripts" / "plan_measurement.py"
CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"
FAST = ["--density", "0.005", "--orientations", "4", "--tilt", "none", "--solver", "greedy"]


def run_cli(args, cwd, timeout=120):
    return subprocess.run(
        [sys.executable, str(SCRIPT), *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["missing.stl"], "part file not found: missing.stl"),
        ([CUBE, "--units", "furlong"], "unknown unit 'furlong'"),
        ([CUBE, "--solver", "IP_uncert"], "did you mean 'IP_uncertainty'"),
        ([CUBE, "--tilt", "sideways"], "unknown tilt mode 'sideways'"),
        ([CUBE, "--density", "0"], "--density"),
        ([CUBE, "--threshold", "nan"], "--threshold"),
        ([CUBE, "--transform", "0", "0", "nan", "0", "0", "0"], "--transform"),
        ([CUBE, "--orientations", "many"], "invalid int value: 'many'"),
        ([CUBE, "-o", "no_such_dir/plan.yaml"], "output directory does not exist: no_such_dir"),
        ([CUBE, "--report", "no_such_dir/report.png"], "output directory does not exist: no_such_dir"),
        ([CUBE, "--report", "report.jpg"], "must end in .png"),
        ([CUBE, "--scene", "no_scene.yaml"], "scene file not found: no_scene.yaml"),
        # a command-line user's files go where they are named: only what cannot be written is refused
        ([CUBE, "-o", "/no_such_dir/plan"], "output directory does not exist: /no_such_dir"),
        ([CUBE, "--report", "../no_such_dir/report.png"], "output directory does not exist: ../no_such_dir"),
        ([CUBE, "--summary", "/no_such_dir/summary.txt"], "output directory does not exist: /no_such_dir"),
        ([CUBE, "-o", "~/no_such_dir_of_plans/plan"], "output directory does not exist: ~/no_such_dir_of_plans"),
        ([CUBE, "--output-dir", "no_such_dir", "-o", "plan"], "--output-dir no_such_dir is not a directory"),
    ],
)
def test_bad_input_gives_one_error_line_and_exit_status_2(tmp_path, args, expected):
    result = run_cli(args, tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in result.stdout + result.stderr
    assert not any(tmp_path.iterdir()), "nothing may be written on bad input"


def test_unreadable_part_is_reported_without_traceback(tmp_path):
    broken = tmp_path / "broken.stl"
    broken.write_text("solid nothing\nendsolid nothing\n")
    result = run_cli([broken, *FAST], tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].startswith("error: ")
    assert "broken.stl" in result.stderr and "Traceback" not in result.stderr


def test_place_fixture_and_an_overlap_error(tmp_path):
    # the cube sunk 30 mm into the fixture: refused quickly, before any planning, with the lift that clears it
    started = time.monotonic()
    result = run_cli([CUBE, *FAST, "--transform", "0", "0", "-30", "0", "0", "0"], tmp_path)
    assert result.returncode == 2
    assert time.monotonic() - started < 30.0  # the process start (imports) included
    last = result.stderr.strip().splitlines()[-1]
    assert "'fixture'" in last and "lift the part by 30" in last and "Traceback" not in result.stderr
    # --place fixture puts it back on the fixture, whatever its frame
    result = run_cli([CUBE, *FAST, "--place", "fixture", "--summary", "s.yaml"], tmp_path)
    assert result.returncode == 0, result.stderr
    summary = yaml.safe_load((tmp_path / "s.yaml").read_text())
    assert summary["parameters"]["placement"] == "fixture" and summary["covered"] > 0


def test_plans_the_cube_and_writes_only_what_was_asked(tmp_path):
    result = run_cli(
        [CUBE, *FAST, "-o", "cube_plan", "--report", "cube.png", "--summary", "summary.yaml", "--seed", "1"], tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    # the plan gets its .yaml suffix once; nothing but the requested files is left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.png", "cube_plan.yaml", "summary.yaml"]
    plan = load_execution_plan(tmp_path / "cube_plan.yaml")
    assert len(plan.measurements()) >= 5 and len(plan.connections()) == len(plan.measurements())
    assert (tmp_path / "cube.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = yaml.safe_load((tmp_path / "summary.yaml").read_text())
    assert summary["views"] == len(plan.measurements())
    assert summary["samples"] == 250 and summary["candidates"] == 1000
    assert 0.9 <= summary["coverage_of_samples"] <= 1.0
    assert summary["estimated_execution_time_s"] > 0
    assert set(summary["time_s"]) >= {"sampling", "metrology", "mechanics", "set cover", "connection", "total"}
    labels = ("samples", "valid viewpoints", "views chosen", "measurable (metrology)", "measurable, executable")
    for label in (*labels, "covered", "placement", "est. execution time"):
        assert label in result.stdout
    # the three numbers: covered <= coverable by executable views <= metrologically coverable <= samples
    assert summary["covered"] <= summary["coverable_executable"] <= summary["coverable_metrology"] <= 250
    assert summary["reachable_share"] == pytest.approx(1.0)
    assert "cube_plan.yaml" in result.stdout


@pytest.mark.skipif(os.name != "posix", reason="needs SIGINT")
def test_ctrl_c_exits_cleanly(tmp_path):
    # a larger problem, so that planning is still running when the signal arrives
    process = subprocess.Popen(
        [sys.executable, str(SCRIPT), CUBE, "--density", "0.03", "--tilt", "full", "-o", "plan.yaml"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a test run started in the background inherits SIGINT ignored, and Python keeps it so: give the CLI the
        # terminal's default, as a user's shell does
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 60
    line = ""
    while "sampling:" not in line and time.monotonic() < deadline:
        line = process.stderr.readline()
        if not line and process.poll() is not None:
            break
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    assert not any(tmp_path.iterdir()), "an interrupted run writes no plan"


def test_existing_outputs_are_kept_unless_overwrite(tmp_path):
    existing = tmp_path / "plan.yaml"
    existing.write_text("keep me")
    result = run_cli([CUBE, *FAST, "-o", "plan"], tmp_path)
    assert result.returncode == 2 and "exists" in result.stderr and "--overwrite" in result.stderr, result.stderr
    assert existing.read_text() == "keep me"
    out = tmp_path / "out"
    out.mkdir()
    result = run_cli([CUBE, *FAST, "--output-dir", out, "-o", "plan", "--overwrite", "-q"], tmp_path)
    assert result.returncode == 0, result.stderr
    assert load_execution_plan(out / "plan.yaml").segments
    assert existing.read_text() == "keep me"


def test_outputs_go_where_the_user_names_them(tmp_path):
    # absolute (outside the working directory), and '..' relative to it: both written, atomically, as named
    work = tmp_path / "work"
    work.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = run_cli([CUBE, *FAST, "-o", elsewhere / "plan.yaml", "--summary", "../summary.txt", "-q"], work)
    assert result.returncode == 0, result.stderr
    assert load_execution_plan(elsewhere / "plan.yaml").segments
    assert (tmp_path / "summary.txt").is_file() and not any(work.iterdir())
    assert not [p for p in elsewhere.iterdir() if p.name.startswith(".")], "no temporary file is left"
    result = run_cli([CUBE, *FAST, "-o", elsewhere / "plan.yaml", "-q"], work)
    assert result.returncode == 2 and "exists" in result.stderr and "--overwrite" in result.stderr, result.stderr


def test_a_huge_density_is_refused_before_any_work(tmp_path):
    started = time.monotonic()
    result = run_cli([CUBE, "--density", "1000", "-q"], tmp_path)
    assert result.returncode == 2, result.stderr
    assert "max_samples" in result.stderr and "samples" in result.stderr
    assert "Traceback" not in result.stderr and time.monotonic() - started < 60


def load_script():
    spec = importlib.util.spec_from_file_location("plan_measurement_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(os.name != "posix", reason="needs SIGTERM")
def test_sigterm_while_writing_leaves_no_half_file_and_names_what_was_written(tmp_path, monkeypatch, capsys):
    script = load_script()
    real_write = script.write_output

    def write_then_terminated(path, data, suffix=""):
        def half(temporary):
            Path(temporary).write_text("half")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)  # the handler raises here

        return real_write(path, half, suffix=".txt")

    monkeypatch.setattr(script, "write_output", write_then_terminated)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        status = script.main(
            [str(CUBE), *FAST, "-q", "--output-dir", str(tmp_path), "-o", "plan.yaml", "--summary", "s.txt"]
        )
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert status == script.EXIT_TERMINATED
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.yaml"]
    assert "terminated: written before: plan" in capsys.readouterr().err


def test_a_failed_write_names_the_file_and_what_was_written(tmp_path, monkeypatch, capsys):
    script = load_script()

    def full_disk(path, data, suffix=""):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(script, "write_output", full_disk)
    status = script.main(
        [str(CUBE), *FAST, "-q", "--output-dir", str(tmp_path), "-o", "plan.yaml", "--summary", "s.txt"]
    )
    assert status == 2
    err = capsys.readouterr().err
    assert "s.txt: cannot write the summary: No space left on device; written before: plan" in err
