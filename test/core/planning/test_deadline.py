"""The planning time limit: checked stages, and one long step that cannot check it itself (StageClock.call)."""

from __future__ import annotations

import threading
import time

import pytest

from agiprobot_measurement.common.cli import process_started_s
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.deadline import StageClock
from agiprobot_measurement.planning.errors import PlanningTimeLimit


def test_only_the_time_checked_stages_raise_once_the_limit_ran_out():
    clock = StageClock(time.perf_counter() - 5.0, 1.0)
    clock.check("connection")  # ends in time by itself
    with pytest.raises(PlanningTimeLimit, match="during sampling"):
        clock.check("sampling")


def test_call_returns_the_result_of_work_that_ends_in_time():
    clock = StageClock(time.perf_counter(), 10.0)
    assert clock.call("loading", lambda: 42) == 42


def test_call_raises_the_works_own_error():
    clock = StageClock(time.perf_counter(), 10.0)

    def broken():
        raise InputError("the part file is broken")

    with pytest.raises(InputError, match="broken"):
        clock.call("loading", broken)


def test_call_gives_up_on_long_work_when_the_limit_runs_out():
    release = threading.Event()
    clock = StageClock(time.perf_counter(), 0.3)
    started = time.perf_counter()
    with pytest.raises(PlanningTimeLimit, match="during loading"):
        clock.call("loading", lambda: release.wait(30.0))
    assert time.perf_counter() - started < 2.0  # not the 30 s the work would take
    release.set()


def test_call_after_the_limit_ran_out_raises_at_once():
    clock = StageClock(time.perf_counter() - 2.0, 1.0)
    with pytest.raises(PlanningTimeLimit):
        clock.call("loading", lambda: time.sleep(5.0))


def test_a_process_started_before_this_test_ran():
    started = process_started_s()
    now = time.perf_counter()
    # pytest started the interpreter and collected the tests before this one ran: the start lies well before now
    assert 0.05 < now - started < 24 * 3600.0


def test_a_share_deadline_lies_at_that_share_of_the_time_left():
    clock = StageClock(time.perf_counter() - 4.0, 10.0)  # 6 s left
    before = time.perf_counter()
    deadline = clock.share_deadline(0.5)
    assert before + 3.0 - 0.1 < deadline < time.perf_counter() + 3.0
    late = StageClock(time.perf_counter() - 20.0, 10.0)  # nothing left: now
    assert late.share_deadline(0.5) <= time.perf_counter()
