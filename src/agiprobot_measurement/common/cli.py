"""The one way a command-line tool of this package ends: its exit status and its error line.

``sys.exit(run_main(main))`` runs ``main()`` and maps what escapes it: an :class:`InputError` (the user's to fix)
prints ``error: <message>`` and exits with :data:`EXIT_USAGE`; any other :class:`AgiprobotError` prints
``error: internal error: <message>`` and exits with :data:`EXIT_INTERNAL`; an ``OSError`` (a folder that cannot be
written, a full disk) prints ``error: <message>`` and exits with :data:`EXIT_USAGE`; Ctrl-C exits with
:data:`EXIT_INTERRUPTED`. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from agiprobot_measurement.errors import AgiprobotError, is_input_error

__all__ = [
    "EXIT_INTERNAL",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_USAGE",
    "process_started_s",
    "run_main",
    "start_process_group",
    "stop_process_group",
]

EXIT_OK = 0
#: a failure that is not the user's input (a solver, a device)
EXIT_INTERNAL = 1
#: bad input: a file, an option, an existing output without --overwrite
EXIT_USAGE = 2
#: interrupted with Ctrl-C
EXIT_INTERRUPTED = 130


def process_started_s() -> float:
    """When this process started, as a ``time.perf_counter()`` value (the interpreter's start-up and the imports
    included), so that a command's time limit counts from when the user started it. Linux's ``/proc`` gives the
    start; elsewhere it is the moment of this call."""
    try:
        stat = Path("/proc/self/stat").read_text()
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
        # the fields after the command name (which may hold spaces) in brackets; starttime is field 22
        start_ticks = int(stat.rsplit(")", 1)[1].split()[19])
        age_s = uptime_s - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return time.perf_counter()
    return time.perf_counter() - max(age_s, 0.0)


def _interruptible() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_process_group(command: list[str], **popen_kwargs) -> subprocess.Popen:
    """Start ``command`` (roslaunch, rviz) in a process group of its own, so that :func:`stop_process_group` ends it
    and everything it started. Ctrl-C is restored in the child: a command started as a background job of a
    non-interactive shell (as CI and ``nohup ... &`` do) inherits an ignored SIGINT, and roslaunch would then only
    end with SIGKILL, leaving its nodes unshut."""
    return subprocess.Popen(command, start_new_session=True, preexec_fn=_interruptible, **popen_kwargs)


def stop_process_group(process: subprocess.Popen, timeout_s: float = 30.0) -> None:
    """End a child started with :func:`start_process_group` (roslaunch, rviz) as Ctrl-C would: SIGINT to its whole
    process group, and SIGKILL when it has not ended after ``timeout_s`` (s); children that outlived it are killed
    too. Nothing when it has ended already."""
    if process.poll() is not None:
        return
    try:
        os.killpg(process.pid, signal.SIGINT)
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        pass
    except ProcessLookupError:  # ended between the poll and the signal
        pass
    try:
        os.killpg(process.pid, signal.SIGKILL)  # the leader if it is still there, and any child that outlived it
    except ProcessLookupError:
        pass
    process.wait()


def run_main(main: Callable[[], int | None], prog: str = "") -> int:
    """``main()``'s exit status (None counts as :data:`EXIT_OK`), or the status of the package error that ended
    it, after one ``[prog: ]error: ...`` line on stderr."""
    prefix = f"{prog}: " if prog else ""
    try:
        status = main()
    except AgiprobotError as exc:
        if is_input_error(exc):
            print(f"{prefix}error: {exc}", file=sys.stderr, flush=True)
            return EXIT_USAGE
        print(f"{prefix}error: internal error: {exc}", file=sys.stderr, flush=True)
        return EXIT_INTERNAL
    except OSError as exc:  # the user's file system: permissions, a full disk
        print(f"{prefix}error: {exc}", file=sys.stderr, flush=True)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prefix}interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    return EXIT_OK if status is None else int(status)
