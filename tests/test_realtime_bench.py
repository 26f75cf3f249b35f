"""The real-time comparison bench reads `smcpilot bench sitl`'s real-time line (the format both
sides print), and names a revision git does not know in one line."""

from __future__ import annotations

import argparse
import math

import numpy as np
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


def test_parse_run_reads_the_bare_loop_beside_it() -> None:
    out = ("  2991 ticks, 8 missed deadlines (0.27 %), loop lateness p50 101 µs, p99 846 µs, max 3903 µs (period 2000 µs)\n"
           "  stalls (ticks ≥ 1 ms late): the FC 24; during a garbage collection 0 (collections 0/0/0 by generation, longest 0.00 ms)\n"
           "  a bare 500 Hz loop beside it, computing nothing: 17 stalls, 7 missed of 2493 (0.28 %), p99 694 µs;"
           " of the FC's 24 stalls with times, 8 at the same moments as the bare loop's (the machine's); CPU steal 0.5 %\n")  # fmt: skip
    r = parse_run(out)
    assert r == RealtimeRun(2991, 8, 101.0, 846.0, 3903.0, 24, 7, 2493, 24, 8)


def _coincident_oracle(a: list[tuple[float, float]], b: list[tuple[float, float]], slack: float) -> int:
    return sum(any(t - d <= bt + slack and bt - bd - slack <= t for bt, bd in b) for t, d in a)


def test_coincident_stalls_match_a_pair_by_pair_scan() -> None:
    from lab.timer_floor import coincident

    rng = np.random.default_rng(7)
    for _ in range(300):
        a = [(float(t), float(d)) for t, d in zip(rng.uniform(0, 1, rng.integers(0, 12)), rng.uniform(0, 0.05, 12))]
        b = [(float(t), float(d)) for t, d in zip(rng.uniform(0, 1, rng.integers(0, 12)), rng.uniform(0, 0.05, 12))]
        slack = float(rng.choice([0.0, 0.0005, 0.01]))
        got = coincident([t for t, _ in a], [d for _, d in a], [t for t, _ in b], [d for _, d in b], slack)
        assert got == _coincident_oracle(a, b, slack)


def test_the_bare_loop_counts_a_stall_of_its_clock() -> None:
    """Simulated time: one wait overshoots by 5 ms: one stall of 5 ms and two missed deadlines,
    counted as the FC counts them; every other tick on time."""
    from lab.timer_floor import bare_loop

    now = [0.0]
    waits = [0]

    def wait_s(s: float) -> None:
        waits[0] += 1
        now[0] += s + (0.005 if waits[0] == 5 else 0.0)

    out = bare_loop(0.05, 0.002, 0.001, lambda: now[0], wait_s)
    assert out["stalls"]["count"] == 1 and out["missed"] == 2
    assert out["stalls"]["late_s"][0] == pytest.approx(0.005, abs=1e-9)
    assert out["lateness_p50_s"] == pytest.approx(0.0, abs=1e-12)
    assert out["ticks"] == 23  # 25 deadlines in 50 ms, two of them skipped by the stall
