"""The reliability replay's judging: fake children (tiny Python one-liners) and fabricated outcomes, no real tool."""

from __future__ import annotations

import sys

import pytest

from benchmarks.harness import OptionError, ProcessResult
from benchmarks.reliability import inputs
from benchmarks.reliability.judge import Expectation, Outcome, judge, run_watched
from benchmarks.reliability.probes import CLI_PROBES
from benchmarks.reliability.run import CONDITIONS, expectation, main, select

REFUSE = Expectation("refuse", seconds=5.0, memory_mb=500.0, message="not found")
FORBID = ("ModuleNotFoundError",)


def _child(code: str, timeout_s: float = 20.0, cap_mb: float = 2000.0) -> Outcome:
    return run_watched([sys.executable, "-c", code], timeout_s, cap_mb)


def _outcome(code, stderr="", seconds=0.5, peak=100.0, stdout="", killed="", longest=None) -> Outcome:
    longest = max((len(x) for x in stderr.splitlines()), default=0) if longest is None else longest
    return Outcome(ProcessResult(code, stdout, stderr, seconds), peak, killed, longest)


def test_a_child_that_prints_a_traceback_is_a_defect():
    outcome = _child("raise ValueError('Maximum allowed dimension exceeded')")
    verdict = judge(outcome, REFUSE, FORBID)
    assert not verdict.holds and verdict.label == "DEFECT"
    assert verdict.reason.startswith("traceback: ValueError: Maximum allowed dimension exceeded")


def test_exit_2_with_one_error_line_holds():
    outcome = _child("import sys; print('error: part file not found: x.stl', file=sys.stderr); sys.exit(2)")
    assert outcome.result.returncode == 2 and outcome.peak_mb > 0 and not outcome.killed
    verdict = judge(outcome, REFUSE, FORBID)
    assert verdict.holds and verdict.label == "holds"
    assert verdict.reason == "error: part file not found: x.stl"


def test_over_time_is_a_defect():
    verdict = judge(_outcome(2, "error: part file not found", seconds=7.2), REFUSE, FORBID)
    assert not verdict.holds and "took 7.2 s (bound 5 s" in verdict.reason


def test_a_child_killed_at_the_timeout_is_a_defect():
    outcome = _child("import time; time.sleep(30)", timeout_s=0.5)
    assert outcome.killed == "time" and outcome.result.returncode is None and outcome.result.seconds < 10
    assert judge(outcome, REFUSE).reason.startswith("killed after")


def test_a_child_killed_above_the_memory_cap_is_a_defect():
    outcome = _child("import time; x = bytearray(400 * 2**20); x[::4096] = b'1' * len(x[::4096]); time.sleep(30)",
                     cap_mb=200)  # fmt: skip
    assert outcome.killed == "memory" and outcome.peak_mb > 200
    assert judge(outcome, REFUSE).reason.startswith("killed at")


@pytest.mark.parametrize(
    ("outcome", "reason"),
    [
        (_outcome(0), "exit 0: accepted where a refusal was expected"),
        (_outcome(1, "error: internal"), "exit 1: error: internal"),
        (_outcome(2, "some warning"), "no one-line error: some warning"),
        (_outcome(2, "error: " + "\\x00" * 1000), "error line of 4,007 characters"),
        (_outcome(2, "error: cannot read: ModuleNotFoundError: x"), "unclear output: error: cannot read: Module"),
        (_outcome(2, "error: something else"), "unclear error: error: something else"),
        (_outcome(2, "error: file not found", peak=900.0), "peak 900 MB (bound 500 MB)"),
    ],
)
def test_refusal_defects(outcome, reason):
    verdict = judge(outcome, REFUSE, FORBID)
    assert not verdict.holds and verdict.reason.startswith(reason)


def test_success_expectations():
    succeed = Expectation("succeed", 11.0, 2000.0, forbid=(r"Chamfer inf",))
    assert judge(_outcome(0, seconds=10.5), succeed).holds
    assert judge(_outcome(0, seconds=12.0), succeed).reason.startswith("took 12.0 s")
    assert judge(_outcome(0, stdout="done, Chamfer inf mm"), succeed).reason.startswith("unclear output")
    assert judge(_outcome(2, "error: x"), succeed).reason.startswith("exit 2 where success was expected")
    either = Expectation("either", 11.0, 2000.0)
    assert judge(_outcome(0), either).holds and judge(_outcome(2, "error: too large"), either).holds


def test_planning_bound_is_the_time_limit_and_its_slack():
    probe = next(p for p in CLI_PROBES if p.id == "P24")
    limit = CONDITIONS.number("time_limit_s")
    assert expectation(probe).seconds == pytest.approx(limit * 1.1)
    assert "{T}" in probe.args


def test_catalogue_ids_are_unique_and_inputs_known():
    ids = [p.id for p in select(None, "all")]
    assert len(ids) == len(set(ids))
    for probe in CLI_PROBES:
        assert set(probe.inputs) <= set(inputs.GENERATORS), probe.id
        assert probe.ends in ("refuse", "succeed", "either") and probe.bound in CONDITIONS.mapping("bounds")


def test_the_command_lists_its_probes_and_refuses_unknown_ids(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0 and "usage:" in capsys.readouterr().out
    assert main(["--list", "--only", "P4", "K22", "N19"]) == 0
    listed = capsys.readouterr().out
    assert "random bytes" in listed and "load_samples" in listed and "ReconstructObject" in listed
    with pytest.raises(OptionError, match="unknown probe P999"):
        main(["--list", "--only", "P999"])
