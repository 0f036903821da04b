"""What every benchmark shares: conditions, options, one run per fresh process, peak memory, timing, tables, JSON
and target checks.

- :func:`load_conditions` reads ``benchmarks/conditions/<name>.yaml`` (the default parameter sets and targets) with
  the package's YAML reader; :class:`Conditions` hands out its entries checked by ``common.config``'s validators.
- :func:`parse_key_values` reads repeatable ``KEY=VALUE`` options; :func:`number_value` and :func:`switch_value`
  convert their values. Errors are :class:`OptionError` naming the option and the item.
- :func:`run_process` runs a command with a timeout; :func:`run_json` runs a benchmark's child (``python -m
  <module> ...``, see :func:`child_command`) in a fresh process, so that its peak memory is its own, and returns the
  last JSON line it printed; :class:`ChildFailed` says why there is none.
- :func:`peak_rss_mb` is this process's peak resident memory; :func:`timed` the median of repeated calls.
- :func:`format_table` lays out rows under a header; :func:`write_json` writes results atomically.
- :class:`Target` (name, measured, target, ok) with :func:`format_targets` and :func:`targets_json`: the one way a
  benchmark states whether a figure meets its target.

The import bootstrap (a checkout without the catkin environment finds the package in ``src/``) is
``benchmarks/__init__.py``'s: it runs once, before any benchmark module.
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from agiprobot_measurement.common.config import ConfigError, number, read_yaml, require, whole
from agiprobot_measurement.common.files import atomic_write_text
from agiprobot_measurement.errors import InputError, InternalError

from . import ROOT

__all__ = [
    "CONDITIONS_DIR",
    "RESULTS_DIR",
    "ROOT",
    "ChildFailed",
    "Conditions",
    "OptionError",
    "ProcessResult",
    "Target",
    "Timing",
    "child_command",
    "format_table",
    "format_targets",
    "load_conditions",
    "number_value",
    "parse_key_values",
    "peak_rss_mb",
    "run_json",
    "run_process",
    "switch_value",
    "targets_json",
    "timed",
    "write_json",
]

CONDITIONS_DIR = ROOT / "benchmarks" / "conditions"
#: where ``make bench-<domain>`` writes its JSON (ignored by git)
RESULTS_DIR = ROOT / "bench_results"


class OptionError(InputError):
    """A benchmark option the user must fix; the message names the option and the item."""


class ChildFailed(InternalError):
    """A benchmark's child process timed out, failed or printed no JSON; the message says which."""


# --------------------------------------------------------------------------------------------------- conditions
@dataclass(frozen=True)
class Conditions:
    """The entries of one conditions file; each read is checked and a bad or missing entry names the file and key."""

    path: Path
    values: dict

    def __getitem__(self, key: str) -> object:
        return require(self.values, key, str(self.path))

    def get(self, key: str, default: object = None) -> object:
        return self.values.get(key, default)

    def number(self, key: str, low: float | None = None, high: float | None = None) -> float:
        return number(self[key], f"{self.path}: {key}", low, high)

    def whole(self, key: str, low: int | None = None, high: int | None = None) -> int:
        return whole(self[key], f"{self.path}: {key}", low, high)

    def mapping(self, key: str) -> dict:
        value = self[key]
        if not isinstance(value, dict):
            raise ConfigError(f"{self.path}: {key}: expected a mapping, got {type(value).__name__}")
        return value


def load_conditions(name: str, folder: Path = CONDITIONS_DIR) -> Conditions:
    """``<folder>/<name>.yaml`` read with the package's bounded YAML reader; it must hold a mapping."""
    path = Path(folder) / f"{name}.yaml"
    values = read_yaml(path)
    if not isinstance(values, dict):
        raise ConfigError(f"{path}: expected a mapping of conditions, got {type(values).__name__}")
    return Conditions(path, values)


# ------------------------------------------------------------------------------------------------------ options
def parse_key_values(
    items: Iterable[str],
    flag: str,
    metavar: str = "KEY=VALUE",
    names: Sequence[str] | None = None,
    value: Callable[[str, str], object] = lambda key, text: text,
) -> dict[str, object]:
    """``KEY=VALUE`` items (a repeatable option's values) as ``{KEY: value(KEY, VALUE)}``.

    An item without ``=`` or with a key outside ``names`` (when given) is refused naming the expected form and the
    known keys; an ``InputError`` from ``value`` (an :class:`OptionError`, a ``ConfigError``) is refused prefixed with
    the option and the item.
    """
    key_word = metavar.partition("=")[0]
    out: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key or (names is not None and key not in names):
            known = f", {key_word} one of {', '.join(names)}" if names is not None else ""
            raise OptionError(f"{flag} {item!r}: expected {metavar}{known}")
        try:
            out[key] = value(key, text)
        except InputError as exc:
            raise OptionError(f"{flag} {item!r}: {exc}") from None
    return out


def number_value(text: str, low: float | None = None) -> float:
    """A finite number (``>= low`` when given), read by ``common.config.number``."""
    return number(text.strip(), "value", low)


def switch_value(text: str) -> bool:
    """``true``/``false`` (any case) or ``1``/``0``; anything else is refused ("False" as text would be true)."""
    flag = {"true": True, "1": True, "false": False, "0": False}.get(text.strip().lower())
    if flag is None:
        raise OptionError("is a switch, give true or false")
    return flag


# ---------------------------------------------------------------------------------------------------- processes
@dataclass(frozen=True)
class ProcessResult:
    returncode: int | None  # None: killed at the timeout
    stdout: str
    stderr: str
    seconds: float

    @property
    def timed_out(self) -> bool:
        return self.returncode is None


def run_process(
    command: Sequence[str], timeout_s: float | None = None, env: dict | None = None, cwd: Path | None = ROOT
) -> ProcessResult:
    """Run ``command`` (its output captured) for at most ``timeout_s`` seconds; a timeout is a result, not an
    exception (``returncode`` None)."""
    started = time.perf_counter()
    try:
        done = subprocess.run(
            list(command), capture_output=True, text=True, timeout=timeout_s, env=env, cwd=cwd, check=False
        )
    except subprocess.TimeoutExpired as exc:
        text = [x.decode(errors="replace") if isinstance(x, bytes) else (x or "") for x in (exc.stdout, exc.stderr)]
        return ProcessResult(None, text[0], text[1], time.perf_counter() - started)
    return ProcessResult(done.returncode, done.stdout, done.stderr, time.perf_counter() - started)


def child_command(module: str, *args: object) -> list[str]:
    """``python -m <module> args...`` with this interpreter (run from the checkout's root)."""
    return [sys.executable, "-m", module, *(str(a) for a in args)]


def run_json(command: Sequence[str], timeout_s: float | None = None, env: dict | None = None) -> dict:
    """Run a child that prints its figures as one JSON line last and return that object; :class:`ChildFailed`
    names the timeout, or the exit code with the last line of the child's error output."""
    done = run_process(command, timeout_s, env)
    if done.timed_out:
        raise ChildFailed(f"timed out after {timeout_s:.0f} s")
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise ChildFailed(f"exit {done.returncode}: {tail}")
    return json.loads(lines[-1])


# --------------------------------------------------------------------------------------------- memory and time
def peak_rss_mb() -> float:
    """This process's peak resident memory in MB (``ru_maxrss``, KiB on Linux). In a child process it starts at the
    parent's resident memory at the fork, so a benchmark's parent stays small."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass(frozen=True)
class Timing:
    median_s: float
    min_s: float
    max_s: float
    cpu_median_s: float  # CPU seconds of the process (all threads): wall time on a shared machine includes waiting
    result: object


def timed(function: Callable[[], object], repeats: int, warmup: bool = False) -> Timing:
    """Wall and CPU seconds of ``repeats`` calls (after one untimed call when ``warmup``) and the last result."""
    if warmup:
        function()
    wall, cpu, result = [], [], None
    for _ in range(max(1, repeats)):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = function()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return Timing(statistics.median(wall), min(wall), max(wall), statistics.median(cpu), result)


# ------------------------------------------------------------------------------------------------ tables, JSON
def format_table(
    header: Sequence[str], rows: Iterable[Sequence[str]], right: Iterable[int] = (), sep: str = " | "
) -> str:
    """``header`` and ``rows`` in columns as wide as their widest cell, a rule under the header; the columns in
    ``right`` are right-aligned. A row may be shorter than the header."""
    rows = [[str(c) for c in row] for row in rows]
    right = set(right)
    widths = [max([len(header[i])] + [len(r[i]) for r in rows if i < len(r)]) for i in range(len(header))]

    def line(cells):
        padded = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=False))]
        return sep.join(padded).rstrip()

    rule = sep.replace(" ", "-") if sep.strip() else sep
    return "\n".join([line(header), rule.join("-" * w for w in widths), *(line(r) for r in rows)])


def write_json(path: str | Path, data: object, indent: int = 1) -> Path:
    """``data`` as JSON at ``path`` (``~`` expanded, folders made), written atomically; numpy numbers as floats."""
    return atomic_write_text(
        Path(path).expanduser(), json.dumps(data, indent=indent, default=float) + "\n", make_parents=True
    )


# ------------------------------------------------------------------------------------------------------ targets
@dataclass(frozen=True)
class Target:
    """One target: what was measured, the bound it is held to (as text, e.g. ``<= 20 s``), and whether it held."""

    name: str
    measured: str
    target: str
    ok: bool


def format_targets(targets: Iterable[Target]) -> str:
    """The targets as a table: verdict (``met`` / ``MISSED``), name, measured, target."""
    rows = [["met" if t.ok else "MISSED", t.name, t.measured, t.target] for t in targets]
    return format_table(["ok", "target", "measured", "bound"], rows)


def targets_json(targets: Iterable[Target]) -> list[dict]:
    return [asdict(t) | {"ok": bool(t.ok)} for t in targets]
