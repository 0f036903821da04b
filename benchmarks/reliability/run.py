"""``python -m benchmarks.reliability``: build the inputs, run the selected probes one by one, print the table.

Each row: probe id, entry point, input, what was expected, ``holds`` / ``DEFECT``, wall time, peak memory of the
process tree, and the error line or the reason of the defect. ``--json FILE`` writes the rows; the exit status is 1
when any row is a DEFECT.
"""

from __future__ import annotations

import argparse
import http.server
import os
import socket
import sys
import tempfile
import threading
from pathlib import Path
from typing import ClassVar

from benchmarks.harness import ROOT, OptionError, format_table, load_conditions, write_json

from . import inputs
from .judge import Expectation, judge, run_watched
from .nodes import NODE_PROBES, NodeProbe
from .probes import CLI_PROBES, Probe

__all__ = ["expectation", "main", "run_probe"]

CONDITIONS = load_conditions("reliability")


def expectation(probe: Probe, conditions=CONDITIONS) -> Expectation:
    """The bound and checks of ``probe`` from the conditions."""
    bounds = conditions.mapping("bounds")
    bound = bounds[probe.bound]
    if probe.bound == "planning":
        seconds = conditions.number("time_limit_s", 0) * (1.0 + float(bound["slack"]))
    else:
        seconds = float(bound["seconds"])
    return Expectation(
        probe.ends, seconds, float(bound["memory_mb"]), probe.message, probe.forbid,
        conditions.whole("max_message_chars", 1),
    )  # fmt: skip


# -------------------------------------------------------------------------------------------- fake schedulers
class _Quiet(http.server.BaseHTTPRequestHandler):
    """Answers every request with 501 (it serves no files), silently."""

    def log_message(self, *args):
        pass


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _http_server() -> int:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server.server_address[1]


def _silent_listener() -> int:
    """A listener that accepts connections and never answers (they stay open until this process ends)."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(16)
    held = []

    def accept():
        while True:
            held.append(listener.accept()[0])

    threading.Thread(target=accept, daemon=True).start()
    return listener.getsockname()[1]


class Ports(dict):
    """Template values made on first use: a fake scheduler is started only when a selected probe needs it."""

    makers: ClassVar[dict] = {"http_port": _http_server, "silent_port": _silent_listener, "closed_port": _free_port}

    def __missing__(self, key):
        if key not in self.makers:
            raise KeyError(key)
        self[key] = self.makers[key]()
        return self[key]


# ------------------------------------------------------------------------------------------------------ running
def run_probe(probe: Probe, folder: Path, values: dict, timeout_s: float, conditions=CONDITIONS) -> dict:
    """Build ``probe``'s inputs in ``folder``/in, run it, judge it; the table row as a dict."""
    expect = expectation(probe, conditions)
    in_dir, out_dir = folder / "in", folder / "out" / probe.id
    in_dir.mkdir(parents=True, exist_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in probe.inputs:
        inputs.make(in_dir, name)
    values.update(
        {"in": in_dir, "out": out_dir, "root": ROOT, "T": conditions.number("time_limit_s", 0)}
    )  # the ports stay made on first use
    args = [a.format_map(values) for a in probe.args]
    env = dict(os.environ, ROS_HOME=str(folder / "roshome"))
    env.update({k: v.format_map(values) for k, v in probe.env})
    kept = (in_dir / probe.unchanged).read_bytes() if probe.unchanged else None
    kill_after = min(timeout_s, conditions.number("kill_factor", 1) * expect.seconds + 5.0)
    outcome = run_watched(
        [sys.executable, str(ROOT / "scripts" / probe.tool), *args], kill_after,
        conditions.number("memory_cap_mb", 1), cwd=out_dir, env=env,
    )  # fmt: skip
    verdict = judge(outcome, expect, conditions.get("forbid") or ())
    if verdict.holds and kept is not None and (in_dir / probe.unchanged).read_bytes() != kept:
        verdict = type(verdict)(False, f"replaced the existing {probe.unchanged}")
    return {
        "id": probe.id,
        "entry": probe.tool,
        "input": probe.what,
        "expected": f"{probe.ends} <= {expect.seconds:g} s, {expect.memory_mb:g} MB",
        "result": verdict.label,
        "seconds": round(outcome.result.seconds, 2),
        "cpu_s": None if outcome.cpu_s is None else round(outcome.cpu_s, 2),
        "peak_mb": round(outcome.peak_mb),
        "exit": outcome.result.returncode,
        "reason": verdict.reason,
    }


def format_rows(rows: list[dict]) -> str:
    header = ["id", "entry point", "input", "expected", "result", "time s", "peak MB", "exit", "message / reason"]
    table = [
        [r["id"], r["entry"], r["input"], r["expected"], r["result"], f"{r['seconds']:.1f}", str(r["peak_mb"]),
         "killed" if r["exit"] is None else str(r["exit"]), r["reason"]]
        for r in rows
    ]  # fmt: skip
    return format_table(header, table, right=(5, 6, 7))


def select(only: list[str] | None, group: str, conditions=CONDITIONS) -> list[Probe]:
    catalogue = {"cli": list(CLI_PROBES), "nodes": list(NODE_PROBES), "all": [*CLI_PROBES, *NODE_PROBES]}[group]
    if only:
        known = {p.id: p for p in [*CLI_PROBES, *NODE_PROBES]}
        unknown = [i for i in only if i not in known]
        if unknown:
            raise OptionError(f"--only: unknown probe {', '.join(unknown)}; known: {', '.join(known)}")
        return [known[i] for i in only]
    skip = set(conditions.get("skip") or ())
    return [p for p in catalogue if p.id not in skip]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reliability", description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="ID", help="run only these probes (e.g. P4 C9 K8)")
    parser.add_argument("--group", choices=("cli", "nodes", "all"), default="all", help="which probes (all)")
    parser.add_argument("--json", metavar="FILE", help="write the rows as JSON")
    parser.add_argument("--timeout", type=float, default=CONDITIONS.number("timeout_s", 1), metavar="S",
                        help="kill any child after S seconds at most (default %(default)g)")  # fmt: skip
    parser.add_argument("--keep", metavar="DIR", help="build the inputs and outputs in DIR and keep them")
    parser.add_argument("--list", action="store_true", help="list the probes and exit")
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        raise OptionError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    probes = select(args.only, args.group)
    if args.list:
        print(
            format_table(["id", "entry point", "input", "expected"], [[p.id, p.tool, p.what, p.ends] for p in probes])
        )
        return 0
    with tempfile.TemporaryDirectory(prefix="fuzz-") as scratch:
        folder = Path(args.keep).resolve() if args.keep else Path(scratch)
        rows, values = [], Ports()
        for probe in probes:
            print(f"{probe.id} {probe.tool} {probe.what} ...", file=sys.stderr, flush=True)
            if isinstance(probe, NodeProbe):
                rows.append(probe.run(folder, args.timeout, expectation(probe), CONDITIONS))
            else:
                rows.append(run_probe(probe, folder, values, args.timeout))
    print(format_rows(rows))
    defects = sum(r["result"] != "holds" for r in rows)
    print(f"\n{len(rows) - defects} holds, {defects} DEFECT, {len(rows)} probes")
    if args.json:
        write_json(args.json, {"conditions": CONDITIONS.values, "rows": rows})
    return 1 if defects else 0
