"""Running one probe's child under a wall-clock and memory watch, and judging how it ended.

:func:`run_watched` runs a command in its own process group, its output to files; every 0.1 s it sums the resident
memory of the whole process tree (Dask workers included) and kills the group above a memory cap or after a time cap.
The peak is the larger of that sampled sum and the child's own ``ru_maxrss`` (exact, reported by a small trampoline
process the child is forked from).

:func:`judge` holds an :class:`Outcome` to its :class:`Expectation`: ``holds`` when the child ended with a clear
error (exit 2, one ``error: ...`` line of bounded length naming the problem, no traceback, no leaked warnings or
escape codes) or succeeded as expected, within the time and memory bound; otherwise ``DEFECT`` with the reason.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import psutil

from benchmarks.harness import ProcessResult

__all__ = ["Expectation", "Outcome", "Verdict", "error_line", "judge", "run_watched"]

#: how much of each output stream is kept (the rest is counted, not read)
KEEP_CHARS = 200_000
TRACEBACK = "Traceback (most recent call last)"


@dataclass(frozen=True)
class Outcome:
    """How a child ended: ``result`` (returncode None = killed), peak memory, why it was killed, and the full
    length in characters of its error output's longest line (it may have been cut to :data:`KEEP_CHARS`)."""

    result: ProcessResult
    peak_mb: float
    killed: str = ""  # "" | "time" | "memory"
    longest_stderr_line: int = 0
    cpu_s: float | None = None  # user + system seconds of the child and the children it waited for


@dataclass(frozen=True)
class Expectation:
    """What a probe holds its child to.

    ``ends``: ``refuse`` (exit 2 with a clear error), ``succeed`` (exit 0) or ``either``. ``message``: a regular
    expression the error line must match (it names the problem). ``forbid``: expressions that must not occur in the
    output (e.g. a leaked ``ModuleNotFoundError``, ``Chamfer inf``). ``seconds`` / ``memory_mb``: the bound.
    """

    ends: str
    seconds: float
    memory_mb: float
    message: str = ""
    forbid: Sequence[str] = ()
    max_message_chars: int = 500


@dataclass(frozen=True)
class Verdict:
    holds: bool
    reason: str = ""

    @property
    def label(self) -> str:
        return "holds" if self.holds else "DEFECT"


# ----------------------------------------------------------------------------------------------------- running
def _tree_rss_mb(pid: int) -> float:
    try:
        parent = psutil.Process(pid)
        procs = [parent, *parent.children(recursive=True)]
    except psutil.Error:
        return 0.0
    total = 0
    for proc in procs:
        try:
            total += proc.memory_info().rss
        except psutil.Error:
            pass
    return total / 2**20


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _read(path: Path) -> tuple[str, int]:
    """The first :data:`KEEP_CHARS` characters of a file and the length of its longest line (counted in chunks)."""
    longest = current = 0
    with open(path, "rb") as f:
        head = f.read(KEEP_CHARS)
        f.seek(0)
        while chunk := f.read(1 << 20):
            parts = chunk.split(b"\n")
            current += len(parts[0])
            if len(parts) > 1:
                longest = max(longest, current, *(len(p) for p in parts[1:-1]))
                current = len(parts[-1])
        longest = max(longest, current)
    return head.decode(errors="replace"), longest


# A small trampoline between this process and the child: a child forked from this (large) process starts with our
# resident memory as its ru_maxrss, and exec keeps it; forked from the trampoline it starts small. The trampoline
# changes to the folder, runs the command, writes its ru_maxrss (KiB) and CPU seconds, and ends as the command did.
_TRAMPOLINE = """
import os, resource, signal, sys
folder, report, command = sys.argv[1], sys.argv[2], sys.argv[3:]
pid = os.fork()
if pid == 0:
    os.chdir(folder)
    os.execvp(command[0], command)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as f:
    f.write(f"{usage.ru_maxrss} {usage.ru_utime + usage.ru_stime}")
if os.WIFSIGNALED(status):
    signal.signal(os.WTERMSIG(status), signal.SIG_DFL)
    os.kill(os.getpid(), os.WTERMSIG(status))
sys.exit(os.WEXITSTATUS(status))
"""


def _spawn(command: Sequence[str], folder: Path, cwd: Path | None, env: dict | None) -> int:
    """Start ``command`` through the trampoline in a new session (its own process group), its output to files."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
    actions = [
        (os.POSIX_SPAWN_OPEN, 0, os.devnull, os.O_RDONLY, 0),
        (os.POSIX_SPAWN_OPEN, 1, str(folder / "stdout"), flags, 0o600),
        (os.POSIX_SPAWN_OPEN, 2, str(folder / "stderr"), flags, 0o600),
    ]
    argv = [sys.executable, "-I", "-c", _TRAMPOLINE, str(cwd or os.getcwd()), str(folder / "usage"), *command]
    return os.posix_spawn(argv[0], argv, os.environ if env is None else env, file_actions=actions, setsid=True)


def run_watched(
    command: Sequence[str],
    timeout_s: float,
    memory_cap_mb: float,
    cwd: Path | None = None,
    env: dict | None = None,
    poll_s: float = 0.1,
) -> Outcome:
    """Run ``command`` until it ends, or kill its process group after ``timeout_s`` or above ``memory_cap_mb``
    (the process tree's resident memory); nothing of the group is left running afterwards."""
    command = [str(c) for c in command]
    with tempfile.TemporaryDirectory(prefix="fuzz-out-") as folder:
        folder = Path(folder)
        started = time.perf_counter()
        pid = _spawn(command, folder, cwd, env)
        peak, killed, status = 0.0, "", 0
        while True:
            done, status, _ = os.wait4(pid, os.WNOHANG)
            if done:
                break
            peak = max(peak, _tree_rss_mb(pid))
            if peak > memory_cap_mb:
                killed = "memory"
            elif time.perf_counter() - started > timeout_s:
                killed = "time"
            if killed:
                _kill_group(pid)
                _, status, _ = os.wait4(pid, 0)
                break
            time.sleep(poll_s)
        seconds = time.perf_counter() - started
        _kill_group(pid)  # leftovers of the run (Dask workers)
        stdout, _ = _read(folder / "stdout")
        stderr, longest = _read(folder / "stderr")
        usage = (folder / "usage").read_text().split() if (folder / "usage").exists() else None
    peak = max(peak, float(usage[0]) / 1024.0 if usage else 0.0)
    cpu = float(usage[1]) if usage else None
    code = None if killed else os.waitstatus_to_exitcode(status)
    return Outcome(ProcessResult(code, stdout, stderr, seconds), peak, killed, longest, cpu)


# ----------------------------------------------------------------------------------------------------- judging
def error_line(stderr: str) -> str:
    """The last non-empty line of the error output (where a tool's ``error: ...`` line is)."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    return lines[-1].strip() if lines else ""


def _short(text: str, n: int = 90) -> str:
    text = text.replace("\n", " ")
    return text if len(text) <= n else text[: n - 3] + "..."


def judge(outcome: Outcome, expect: Expectation, forbid: Sequence[str] = ()) -> Verdict:
    """``outcome`` against ``expect``; ``forbid`` are expressions forbidden in every probe's output."""
    result = outcome.result
    if outcome.killed == "time":
        return Verdict(False, f"killed after {result.seconds:.0f} s (bound {expect.seconds:g} s)")
    if outcome.killed == "memory":
        return Verdict(False, f"killed at {outcome.peak_mb:.0f} MB (bound {expect.memory_mb:g} MB)")
    output = result.stdout + "\n" + result.stderr
    if TRACEBACK in output:
        return Verdict(False, f"traceback: {_short(error_line(result.stderr))}")
    for pattern in (*forbid, *expect.forbid):
        found = re.search(pattern, output)
        if found:
            line = next((x for x in output.splitlines() if found.group(0) in x), found.group(0))
            return Verdict(False, f"unclear output: {_short(line)}")
    code, line = result.returncode, error_line(result.stderr)
    if expect.ends == "succeed" and code != 0:
        return Verdict(False, f"exit {code} where success was expected: {_short(line)}")
    if expect.ends == "refuse" and code == 0:
        return Verdict(False, "exit 0: accepted where a refusal was expected")
    if code not in (0, 2):
        return Verdict(False, f"exit {code}: {_short(line)}")
    if code == 2:
        if outcome.longest_stderr_line > expect.max_message_chars:
            return Verdict(False, f"error line of {outcome.longest_stderr_line:,} characters")
        if not line.startswith("error:") and ": error:" not in line:
            return Verdict(False, f"no one-line error: {_short(line) or 'nothing on stderr'}")
        if expect.message and not re.search(expect.message, line, re.IGNORECASE):
            return Verdict(False, f"unclear error: {_short(line)}")
    if result.seconds > expect.seconds:
        cpu = f"; {outcome.cpu_s:.1f} s CPU" if outcome.cpu_s is not None else ""
        return Verdict(False, f"took {result.seconds:.1f} s (bound {expect.seconds:g} s{cpu})")
    if outcome.peak_mb > expect.memory_mb:
        return Verdict(False, f"peak {outcome.peak_mb:.0f} MB (bound {expect.memory_mb:g} MB)")
    return Verdict(True, _short(line) if code == 2 else "exit 0")
