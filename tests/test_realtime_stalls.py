"""The FC's real-time loop keeps its stalls with their times, and the collector's passes: a real
FC process, frozen by SIGSTOP for 40 ms mid-flight, reports that stall at that moment, with the
missed deadlines it cost, and every late tick it counted as missed is among its kept stalls."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import pytest

from ground.sitl import Sitl
from tests.sitl_helpers import sitl_options

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="SIGSTOP")

PERIOD_S = 0.002


def test_a_frozen_fc_reports_its_stall_at_that_moment(tmp_path: Path) -> None:
    opts = sitl_options(tmp_path, "rt-stall", duration_s=3.0, lockstep=False)
    with Sitl(opts) as sitl:
        assert sitl.fc is not None
        pid = sitl.fc.proc.pid
        time.sleep(1.5)
        t_stop = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        time.sleep(0.04)
        t_cont = time.monotonic()  # (before the signal: the FC may run its late tick before kill() returns)
        os.kill(pid, signal.SIGCONT)
        assert sitl.wait(timeout_s=60.0) == 0
    f = sitl.fc_summary or {}
    st, gcp = f["stalls"], f["gc"]
    at, late = st["at_s"], st["late_s"]
    assert len(at) == len(late) == min(st["count"], 200)
    assert all(d >= st["threshold_s"] for d in late)
    # the freeze: a tick that ran after SIGCONT was sent, due before SIGSTOP's moment plus a period
    frozen = [(t, d) for t, d in zip(at, late) if t >= t_cont and t - d <= t_stop + PERIOD_S]
    assert frozen, (t_stop, t_cont, list(zip(at, late)))
    assert max(d for _, d in frozen) >= 0.035
    if st["count"] <= 200:  # every overrun is a kept stall's: the counts agree exactly
        assert f["overruns"] == sum(int(d / PERIOD_S) for d in late if d >= PERIOD_S)
    assert len(gcp["collections"]) == 3 and all(c >= 0 for c in gcp["collections"])
    assert gcp["max_s"] >= 0.0 and len(gcp["long_at_s"]) == len(gcp["long_s"])
