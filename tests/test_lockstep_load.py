"""Lockstep is bit for bit under CPU load.

Busy-loop processes (one per core, at least three) keep the machine oversubscribed while three
lockstep SITL runs with the same seed fly concurrently. Preempted processes answer late, the
simulator re-sends states, the FC answers the copies again, but a copy is never logged: the three
logs must be identical byte for byte, and a different seed must give a different log.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from sitl_helpers import sitl_options

from ground.sitl import Sitl, SitlOptions

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

DURATION_S = 2.0
_BUSY = "import time\nend = time.monotonic() + 300\nwhile time.monotonic() < end:\n    pass\n"


@pytest.fixture()
def busy_loops() -> Iterator[int]:
    n = max(3, os.cpu_count() or 1)
    procs = [subprocess.Popen([sys.executable, "-c", _BUSY]) for _ in range(n)]
    try:
        yield n
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(timeout=10)


def _run_all(options: list[SitlOptions]) -> list[Sitl]:
    results: list[Sitl | BaseException] = [RuntimeError("not run")] * len(options)

    def one(i: int) -> None:
        try:
            with Sitl(options[i]) as sitl:
                sitl.wait(timeout_s=300.0)
            results[i] = sitl
        except BaseException as exc:  # reported below
            results[i] = exc

    threads = [threading.Thread(target=one, args=(i,)) for i in range(len(options))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return results  # type: ignore[return-value]


def test_lockstep_logs_identical_under_cpu_load(tmp_path: Path, busy_loops: int) -> None:
    same = [sitl_options(tmp_path, f"run{i}", duration_s=DURATION_S, noise=True, seed=7) for i in range(3)]
    other = sitl_options(tmp_path, "seed8", duration_s=DURATION_S, noise=True, seed=8)
    runs = _run_all(same + [other])
    logs = [o.tlog.read_bytes() for o in same + [other]]  # type: ignore[union-attr]
    resends = [(r.sim_summary or {}).get("resends", 0) for r in runs]
    dups = [(r.fc_summary or {}).get("duplicate_states", 0) for r in runs]
    print(f"\n{busy_loops} busy loops, 4 concurrent lockstep runs of {DURATION_S:g} s: simulator re-sends {resends},"
          f" duplicate states answered again {dups}")
    assert len(logs[0]) > 100_000
    assert logs[0] == logs[1] == logs[2], "same seed under CPU load: the lockstep logs differ"
    assert logs[3] != logs[0], "another seed gave the same log"
