"""``smcpilot bench realtime``: the real-time loop's lateness, this tree against an earlier revision.

Each pair runs ``smcpilot bench sitl --realtime-s S`` twice, back to back: once in this tree and
once in ``--against REV`` (checked out into a temporary git worktree and run from there with the
same Python and installed packages), the order alternating from pair to pair so that a machine
that speeds up or slows down does not favour one side. Printed per run: control ticks, missed
deadlines (ticks that overran their 2 ms period), and the loop's lateness p50, p99 and max, and
(where the tree prints it) the missed deadlines of a bare loop run beside the flight and how many of
the FC's stalls fell at the same moments as its (the machine's, not the FC's code); then
the median of each side over the pairs and this tree's ratio to the other. Figures, never
pass/fail; a machine shared with other work shows in both sides (``--pairs`` more, and read the
ratio).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from smcpilot.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
_LINE = re.compile(
    r"(?P<ticks>\d+) ticks, (?P<missed>\d+) missed deadlines \((?P<pct>[\d.]+) %\), loop lateness"
    r" p50 (?P<p50>[\d.]+|n/a)(?: µs)?, p99 (?P<p99>[\d.]+|n/a)(?: µs)?, max (?P<max>[\d.]+|n/a)"
)

_FLOOR = re.compile(
    r"stalls \(ticks ≥ [\d.]+ ms late\): the FC (?P<stalls>\d+);.*?"
    r"a bare [\d.]+ Hz loop beside it, computing nothing: (?P<fstalls>\d+) stalls, (?P<fmissed>\d+) missed of (?P<fticks>\d+)"
    r".*?of the FC's (?P<kept>\d+) stalls with times, (?P<same>\d+) at the same moments",
    re.S,
)


def add_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("realtime", help="real-time lateness at 500 Hz: this tree against --against REV, paired runs")
    c.add_argument("--against", metavar="REV", default=None,
                   help="a git revision to compare with (a tag, a commit, HEAD~20); default: only this tree")  # fmt: skip
    c.add_argument("--pairs", type=int, default=3, metavar="N", help="runs per side, alternating (default 3)")
    c.add_argument("--seconds", type=float, default=60.0, metavar="S", help="wall seconds per run (default 60)")
    c.set_defaults(bench=bench_realtime)


@dataclass(frozen=True)
class RealtimeRun:
    ticks: int
    missed: int
    p50_us: float
    p99_us: float
    max_us: float
    #: the FC's stalls (ticks 1 ms late or more); a bare loop's beside it (missed deadlines of its
    #: ticks), and how many of the FC's stalls (of those kept with times) fell at the same moments
    stalls: int | None = None
    floor_missed: int | None = None
    floor_ticks: int | None = None
    stalls_kept: int | None = None
    stalls_same: int | None = None

    @property
    def missed_pct(self) -> float:
        return 100.0 * self.missed / self.ticks if self.ticks else float("nan")


def parse_run(output: str) -> RealtimeRun | None:
    """The real-time line of ``smcpilot bench sitl``'s output, or None."""
    m = _LINE.search(output)
    if m is None:
        return None

    def us(text: str) -> float:
        return float(text) if text != "n/a" else float("nan")

    f = _FLOOR.search(output)
    if f is None:  # (an earlier revision prints no floor)
        return RealtimeRun(int(m["ticks"]), int(m["missed"]), us(m["p50"]), us(m["p99"]), us(m["max"]))
    return RealtimeRun(int(m["ticks"]), int(m["missed"]), us(m["p50"]), us(m["p99"]), us(m["max"]), int(f["stalls"]),
                       int(f["fmissed"]), int(f["fticks"]), int(f["kept"]), int(f["same"]))  # fmt: skip


def _run(tree: Path, seconds: float) -> RealtimeRun:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, "-m", "lab.cli", "bench", "sitl", "--duration", "1", "--realtime-s", f"{seconds:g}"]
    r = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=seconds + 300, check=False)
    run = parse_run(r.stdout)
    if r.returncode != 0 or run is None:
        tail = "\n  ".join((r.stdout + r.stderr).strip().splitlines()[-6:])
        raise ConfigError(f"the run in {tree} failed (exit {r.returncode}):\n  {tail}")
    return run


def _worktree(rev: str, into: Path) -> Path:
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", f"{rev}^{{commit}}"], capture_output=True,
                                text=True, check=True).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        raise ConfigError(f"--against {rev}: not a revision of the git repository at {ROOT}") from None
    path = into / f"against-{commit[:12]}"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(path), commit], check=True,
                   capture_output=True)  # fmt: skip
    return path


def _row(name: str, r: RealtimeRun) -> str:
    row = f"  {name:<10} {r.ticks:>7} ticks  {r.missed:>5} missed ({r.missed_pct:5.2f} %)  p50 {r.p50_us:6.0f} µs  p99 {r.p99_us:6.0f} µs  max {r.max_us:7.0f} µs"
    if r.floor_ticks:
        row += (f"  | bare loop {r.floor_missed} missed ({100.0 * (r.floor_missed or 0) / r.floor_ticks:.2f} %);"
                f" stalls {r.stalls}, {r.stalls_same} of {r.stalls_kept} with the bare loop's")  # fmt: skip
    return row


def _median(rs: list[RealtimeRun]) -> RealtimeRun:
    """Each figure's median over the runs (the bare loop's only where every run has one)."""

    def m(get: Callable[[RealtimeRun], float | int | None]) -> float:
        return statistics.median(float(get(r) or 0) for r in rs)

    floor = all(r.floor_ticks for r in rs)
    return RealtimeRun(int(m(lambda r: r.ticks)), int(m(lambda r: r.missed)), m(lambda r: r.p50_us), m(lambda r: r.p99_us),
                       m(lambda r: r.max_us),
                       *((int(m(lambda r: r.stalls)), int(m(lambda r: r.floor_missed)), int(m(lambda r: r.floor_ticks)),
                          int(m(lambda r: r.stalls_kept)), int(m(lambda r: r.stalls_same))) if floor else ()))  # fmt: skip


def bench_realtime(args: argparse.Namespace) -> int:
    if args.pairs < 1 or not args.seconds > 0:
        raise ConfigError("--pairs must be >= 1 and --seconds > 0")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"smcpilot bench realtime — 500 Hz real time, {args.seconds:g} s per run, {args.pairs} pair(s);"
          f" machine load {load:.2f} on {os.cpu_count()} cores")  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="smcpilot-bench-rt-") as tmp:
        sides: dict[str, Path] = {"this tree": ROOT}
        other = None
        if args.against is not None:
            other = _worktree(args.against, Path(tmp))
            sides[args.against] = other
        runs: dict[str, list[RealtimeRun]] = {name: [] for name in sides}
        try:
            for k in range(args.pairs):
                order = list(sides.items()) if k % 2 == 0 else list(reversed(sides.items()))
                for name, tree in order:
                    r = _run(tree, args.seconds)
                    runs[name].append(r)
                    print(_row(name, r), flush=True)
        finally:
            if other is not None:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(other)], capture_output=True, check=False)
    print("median over the runs:")
    med: dict[str, RealtimeRun] = {}
    for name, rs in runs.items():
        med[name] = _median(rs)
        print(_row(name, med[name]))
    if args.against is not None:
        a, b = med["this tree"], med[args.against]
        print(f"this tree / {args.against}: missed deadlines {a.missed_pct / b.missed_pct if b.missed_pct else float('nan'):.2f}×,"
              f" p99 lateness {a.p99_us / b.p99_us if b.p99_us else float('nan'):.2f}×")  # fmt: skip
    return 0
