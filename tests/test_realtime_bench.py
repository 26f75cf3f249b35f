"""The real-time comparison bench reads `smcpilot bench sitl`'s real-time line (the format both
sides print), and names a revision git does not know in one line."""

from __future__ import annotations

import argparse
import math

import pytest

from lab.realtime_bench import RealtimeRun, bench_realtime, parse_run
from smcpilot.errors import ConfigError


def test_parse_run_reads_the_real_time_line() -> None:
    out = ("lockstep over UDP, two processes: 12.0× real time\n\nreal time, 60 s at 500 Hz (takes 60 s) ...\n"
           "  29981 ticks, 76 missed deadlines (0.25 %), loop lateness p50 74 µs, p99 412 µs, max 5210 µs (period 2000 µs)\n")  # fmt: skip
    assert parse_run(out) == RealtimeRun(29981, 76, 74.0, 412.0, 5210.0)
    assert parse_run(out).missed_pct == pytest.approx(100 * 76 / 29981)  # type: ignore[union-attr]
    na = parse_run("  0 ticks, 0 missed deadlines (0.00 %), loop lateness p50 n/a, p99 n/a, max n/a (period 2000 µs)")
    assert na is not None and math.isnan(na.p99_us)
    assert parse_run("no such line") is None


def test_an_unknown_revision_is_a_clear_error() -> None:
    args = argparse.Namespace(against="no-such-revision-xyz", pairs=1, seconds=1.0)
    with pytest.raises(ConfigError, match="--against no-such-revision-xyz: not a revision"):
        bench_realtime(args)
