"""The machine's own stalls: a bare fixed-rate loop that does nothing but wait for its deadlines.

``python -m lab.timer_floor SECONDS [--rate-hz 500] [--stall-ms 1]`` waits for each deadline as the
FC's real-time loop does (``select`` on a UDP socket with the time left as its timeout) and prints
one JSON line: ticks, missed deadlines, lateness p50/p99/max, and its stalls (ticks ``--stall-ms``
or more late) with their ``time.monotonic`` times. Run beside a real-time flight (``smcpilot bench
sitl --realtime-s``), its stalls are the floor the machine sets: a stall of the FC at the same
moment as one of this loop, which computes nothing, is the machine's (the scheduler, the VM's
host), not the FC's code.
"""

from __future__ import annotations

import argparse
import json
import select
import socket
import time
from collections.abc import Callable, Sequence

__all__ = ["bare_loop", "coincident", "main"]

#: at most this many stalls are kept with their times
STALLS_KEPT = 1000


def bare_loop(seconds: float, period_s: float = 0.002, stall_s: float = 0.001,
              mono: Callable[[], float] = time.monotonic, wait_s: Callable[[float], object] | None = None) -> dict:  # fmt: skip
    """Wait for ``seconds`` worth of deadlines every ``period_s``; the summary (see the module).
    ``wait_s(s)`` waits (default: ``select`` on a UDP socket of its own, as the FC's loop waits)."""
    late_all: list[float] = []
    stalls: list[tuple[float, float]] = []
    stall_count = missed = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        fds = [sock.fileno()]
        if wait_s is None:
            def wait_s(s: float) -> object:
                return select.select(fds, (), (), s)
        start = mono()
        end = start + seconds
        deadline = start + period_s
        while True:
            now = mono()
            wait = deadline - now
            if wait > 0.0:
                wait_s(wait)
                continue
            late = -wait
            late_all.append(late)
            if late >= stall_s:
                stall_count += 1
                if len(stalls) < STALLS_KEPT:
                    stalls.append((now, late))
            if late >= period_s:
                n = int(late / period_s)
                missed += n
                deadline += n * period_s
            deadline += period_s
            if now >= end:
                break
    late_all.sort()
    n = len(late_all)
    return {
        "ticks": n, "missed": missed, "period_s": period_s,
        "lateness_p50_s": late_all[n // 2] if n else None,
        "lateness_p99_s": late_all[min(n - 1, int(0.99 * (n - 1) + 0.5))] if n else None,
        "lateness_max_s": late_all[-1] if n else None,
        "stalls": {"count": stall_count, "threshold_s": stall_s, "at_s": [round(t, 6) for t, _ in stalls],
                   "late_s": [round(d, 6) for _, d in stalls]},
    }  # fmt: skip


def coincident(a_at: Sequence[float], a_late: Sequence[float], b_at: Sequence[float], b_late: Sequence[float],
               slack_s: float = 0.0005) -> int:  # fmt: skip
    """How many of stalls ``a`` overlap one of stalls ``b`` in time (each stall spans from when its
    tick was due, ``at - late``, to when it ran, ``at``; ``slack_s`` widens each side)."""
    spans = sorted((t - d - slack_s, t + slack_s) for t, d in zip(b_at, b_late))
    count = 0
    for t, d in zip(a_at, a_late):
        lo, hi = t - d, t
        for start, end in spans:
            if start > hi:
                break
            if end >= lo:
                count += 1
                break
    return count


def _cpu_times() -> tuple[int, int] | None:
    """(steal, total) jiffies of the whole machine from /proc/stat, or None where there is none."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    values = [int(x) for x in fields[1:9]]  # user nice system idle iowait irq softirq steal
    return values[7], sum(values)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.timer_floor", description=__doc__.split("\n\n")[0])
    ap.add_argument("seconds", type=float, help="how long to run, wall seconds")
    ap.add_argument("--rate-hz", type=float, default=500.0, help="deadlines per second (default 500)")
    ap.add_argument("--stall-ms", type=float, default=1.0, help="a tick this late or later is a stall (default 1 ms)")
    args = ap.parse_args(argv)
    if not args.seconds > 0 or not args.rate_hz > 0 or not args.stall_ms > 0:
        ap.error("SECONDS, --rate-hz and --stall-ms must be > 0")
    cpu0 = _cpu_times()
    out = bare_loop(args.seconds, 1.0 / args.rate_hz, args.stall_ms * 1e-3)
    cpu1 = _cpu_times()
    out["steal_share"] = (cpu1[0] - cpu0[0]) / (cpu1[1] - cpu0[1]) if cpu0 and cpu1 and cpu1[1] > cpu0[1] else None
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
