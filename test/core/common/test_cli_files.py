"""Command-line tools own their files (common.files.output_path / write_output) and end through common.cli.run_main;
nodes keep confining what clients ask to their root (FileRoot)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agiprobot_measurement.calibration.registration import CalibrationData, Sample, write_data_file
from agiprobot_measurement.common.cli import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, run_main
from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.common.files import (
    FileRoot,
    FolderNotFoundError,
    OutputExistsError,
    PathPolicyError,
    output_path,
    write_output,
)
from agiprobot_measurement.errors import InternalError
from agiprobot_measurement.station import PACKAGE_ROOT


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    return work


def test_output_path_takes_the_name_as_the_user_gives_it(tmp_path, cwd):
    assert output_path("plan.yaml") == cwd / "plan.yaml"
    assert output_path("../plan.yaml") == tmp_path / "plan.yaml"
    assert output_path(tmp_path / "abs.yaml") == tmp_path / "abs.yaml"
    assert output_path("plan", suffix=".yaml") == cwd / "plan.yaml"
    assert output_path("sub/../plan.yaml", base=tmp_path) == tmp_path / "plan.yaml"
    home = Path("~").expanduser()
    assert output_path("~/x.yaml", overwrite=True) == home / "x.yaml"


def test_output_path_refuses_what_cannot_or_must_not_be_written(tmp_path, cwd):
    (cwd / "plan.yaml").write_text("keep")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        output_path("plan.yaml")
    assert output_path("plan.yaml", overwrite=True) == cwd / "plan.yaml"
    with pytest.raises(FolderNotFoundError, match="output directory does not exist: no_such"):
        output_path("no_such/plan.yaml")
    assert output_path("new/deeper/plan.yaml", make_parents=True) == cwd / "new" / "deeper" / "plan.yaml"
    with pytest.raises(PathPolicyError, match="is a directory"):
        output_path(tmp_path)
    with pytest.raises(PathPolicyError, match="empty"):
        output_path("")
    assert isinstance(OutputExistsError("x"), ValueError)


def test_write_output_is_atomic(tmp_path):
    target = tmp_path / "sub" / "out.txt"
    assert write_output(target, "one") == target and target.read_text() == "one"
    write_output(target, b"two")
    assert target.read_text() == "two"

    def broken(tmp: Path) -> None:
        tmp.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_output(target, broken, suffix=".txt")
    assert target.read_text() == "two"
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"], "no temporary file is left"


def test_nodes_keep_confining_client_names_to_their_root(tmp_path):
    files = FileRoot(tmp_path, purpose="plan")
    for name in ("../x.yaml", "~/x.yaml", "/etc/x.yaml"):
        with pytest.raises(PathPolicyError):
            files.for_writing(name)
    (tmp_path / "x.yaml").write_text("")
    with pytest.raises(PathPolicyError, match="exists"):
        files.for_writing("x.yaml")


@pytest.mark.parametrize(
    ("error", "status", "line"),
    [
        (ConfigError("bad key"), EXIT_USAGE, "tool: error: bad key"),
        (InternalError("solver died"), EXIT_INTERNAL, "tool: error: internal error: solver died"),
        (PermissionError("denied"), EXIT_USAGE, "tool: error: denied"),
        (KeyboardInterrupt(), EXIT_INTERRUPTED, "tool: interrupted"),
    ],
)
def test_run_main_maps_what_escapes_to_one_line_and_a_status(capsys, error, status, line):
    def main():
        raise error

    assert run_main(main, prog="tool") == status
    assert capsys.readouterr().err.strip() == line


def test_run_main_passes_the_status_through():
    assert run_main(lambda: None) == EXIT_OK
    assert run_main(lambda: 3) == 3
    with pytest.raises(ZeroDivisionError):  # a bug keeps its traceback
        run_main(lambda: 1 / 0)


def _script(name: str, *args, cwd: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, str(PACKAGE_ROOT / "scripts" / name), *map(str, args)]
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=120, check=False)


def test_calibrate_writes_where_named_and_refuses_to_replace_without_overwrite(tmp_path, cwd):
    pc = np.random.default_rng(1).uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (6, 3))
    samples = [Sample(f"{i}_0", pc[i] + [0.5, -0.2, 1.1], pc[i], i < 4) for i in range(6)]
    data = write_data_file(tmp_path / "data.txt", CalibrationData(samples))
    done = _script("calibrate.py", data, "-o", "../result.yaml", cwd=cwd)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "result.yaml").is_file()
    before = (tmp_path / "result.yaml").read_text()
    refused = _script("calibrate.py", data, "-o", tmp_path / "result.yaml", "--mode", "cal_coarse", cwd=cwd)
    assert refused.returncode == 2 and "exists" in refused.stderr and "--overwrite" in refused.stderr
    assert (tmp_path / "result.yaml").read_text() == before
    replaced = _script(
        "calibrate.py", data, "-o", tmp_path / "result.yaml", "--mode", "cal_coarse", "--overwrite", cwd=cwd
    )
    assert replaced.returncode == 0, replaced.stderr
    assert "cal_coarse" in (tmp_path / "result.yaml").read_text()


def test_nbv2d_and_reconstruct_refuse_an_existing_summary_before_any_work(tmp_path, cwd):
    summary = tmp_path / "summary.json"
    summary.write_text("keep")
    nbv2d = _script(
        "nbv2d.py", "--object", "disc", "--script", "circpix", "--out", "out", "--summary", summary, cwd=cwd
    )
    assert nbv2d.returncode == 2 and "exists" in nbv2d.stderr and "--overwrite" in nbv2d.stderr, nbv2d.stderr
    recon = _script("reconstruct.py", "cup", "--out", "out", "--summary", "../summary.json", cwd=cwd)
    assert recon.returncode == 2 and "exists" in recon.stderr and "--overwrite" in recon.stderr, recon.stderr
    assert summary.read_text() == "keep" and not any(cwd.iterdir())


def test_stop_process_group_interrupts_then_kills_the_whole_group():
    import signal
    import subprocess
    import sys as _sys
    import time as _time

    from agiprobot_measurement.common.cli import start_process_group, stop_process_group

    # started as from a background job of a non-interactive shell (CI): SIGINT ignored in this process
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        polite = start_process_group([_sys.executable, "-c", "print('ready', flush=True); import time; time.sleep(60)"],
                                     stdout=subprocess.PIPE)  # fmt: skip
    finally:
        signal.signal(signal.SIGINT, previous)
    assert polite.stdout.readline().strip() == b"ready"
    started = _time.monotonic()
    stop_process_group(polite, timeout_s=10.0)
    assert polite.returncode not in (None, 0, -9) and _time.monotonic() - started < 5.0  # ended by the interrupt
    stubborn_code = (
        "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); time.sleep(60)"
    )
    stubborn = subprocess.Popen([_sys.executable, "-c", stubborn_code], start_new_session=True, stdout=subprocess.PIPE)
    assert stubborn.stdout.readline().strip() == b"ready"
    started = _time.monotonic()
    stop_process_group(stubborn, timeout_s=0.5)
    assert stubborn.returncode == -9 and _time.monotonic() - started < 10.0
    stop_process_group(stubborn)  # ended already: nothing happens


def test_stop_process_group_kills_children_that_outlive_the_leader():
    import os
    import subprocess
    import sys as _sys
    import time as _time

    from agiprobot_measurement.common.cli import stop_process_group

    # the leader ends at the interrupt; its child ignores it and would run on in the group
    child_code = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); time.sleep(60)"
    leader_code = (
        f"import subprocess, sys, time; c = subprocess.Popen([sys.executable, '-c', {child_code!r}]); "
        "print(c.pid, flush=True); time.sleep(60)"
    )
    leader = subprocess.Popen([_sys.executable, "-c", leader_code], start_new_session=True, stdout=subprocess.PIPE)
    child_pid = int(leader.stdout.readline())
    stop_process_group(leader, timeout_s=10.0)
    deadline = _time.monotonic() + 5.0
    while _time.monotonic() < deadline:
        try:
            os.kill(child_pid, 0)
        except ProcessLookupError:
            break
        _time.sleep(0.05)
    else:
        raise AssertionError("the child outlived stop_process_group")
