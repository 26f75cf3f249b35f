"""Dying and stalling peers, real processes, real UDP on 127.0.0.1.

SIGKILL of the simulator or the FC, in lockstep and in real time: the survivor ends by itself,
non-zero, within 2 wall seconds, with a one-line reason; the launcher names the dead child; the
FC's tlog reads to its last record. SIGSTOP of the simulator for 3 s then SIGCONT: in real time the
FC goes into its state-loss failsafe and takes the state back; in lockstep the run resumes and its
log is bit for bit the log of a run that was never stopped.

The time to exit is printed per case (``-s`` shows it).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sitl_helpers import children_of, cmdline, sitl_options

from ground.sitl import Sitl, SitlError
from smcpilot.tlog import read_tlog

#: end-to-end: the quick tier (`pytest -m "not slow"`) leaves this module to the full suite.
pytestmark = pytest.mark.slow

#: The survivor must be gone this soon after the kill (wall seconds; the target).
EXIT_WITHIN_S = 2.0


def _wait_exit(proc: subprocess.Popen, timeout_s: float = 15.0) -> tuple[int, float]:
    t0 = time.monotonic()
    rc = proc.wait(timeout=timeout_s)
    return rc, time.monotonic() - t0


def _reason(tail: list[str], who: str) -> str:
    lines = [ln for ln in tail if ln.startswith(f"{who}: error:")]
    assert len(lines) == 1, tail
    return lines[0]


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "realtime"])
@pytest.mark.parametrize("victim", ["sim", "fc"])
def test_killed_peer_survivor_exits_fast_with_a_reason(tmp_path: Path, victim: str, lockstep: bool) -> None:
    # watchdog 5 s (the default): the survivor must not need it.
    opts = sitl_options(tmp_path, f"kill-{victim}", duration_s=600.0, lockstep=lockstep, speed=1.0 if lockstep else None)
    with Sitl(opts) as sitl:
        assert sitl.fc is not None and sitl.sim is not None
        time.sleep(1.0)  # flying
        dead, survivor = (sitl.sim, sitl.fc) if victim == "sim" else (sitl.fc, sitl.sim)
        t_kill = time.monotonic()
        os.kill(dead.proc.pid, signal.SIGKILL)
        rc = survivor.proc.wait(timeout=15.0)
        exit_s = time.monotonic() - t_kill
        print(f"\n{victim} SIGKILLed ({'lockstep' if lockstep else 'real time'}): {survivor.name} exited {rc} after {exit_s:.3f} s")
        with pytest.raises(SitlError, match=rf"^{victim} was killed by SIGKILL"):
            sitl.wait(timeout_s=15.0)
        survivor_name = "fc" if victim == "sim" else "sim_bridge"
        reason = _reason(survivor.tail, survivor_name)
    assert rc != 0, f"{survivor.name} exited 0 after its peer died"
    assert exit_s < EXIT_WITHIN_S, f"{survivor.name} needed {exit_s:.2f} s to notice ({reason})"
    assert "died" in reason, reason
    assert sitl.tlog is not None
    records = list(read_tlog(sitl.tlog))  # readable to its last record (raises on a torn one)
    assert len(records) > 500, len(records)
    if victim == "fc" and lockstep:  # the killed FC's log keeps all but the last moments (flushed every 0.25 s)
        sim_s = (sitl.sim_summary or {})["sim_time_s"]
        lost_s = sim_s - records[-1][0] * 1e-6
        print(f"  the killed FC's log ends {lost_s:.3f} simulated s before the simulator's last state")
        assert 0.0 <= lost_s < 0.3, (sim_s, records[-1][0])


def test_sitl_command_names_the_dead_child(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "lab.cli", "sitl", "--lockstep", "--speed", "1", "--duration", "600", "--gcs", "none",
         "--log-dir", str(tmp_path / "logs")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30.0
        sim_pid = None
        while sim_pid is None and time.monotonic() < deadline:
            sim_pid = next((p for p in children_of(proc.pid) if "sim_bridge" in cmdline(p)), None)
            time.sleep(0.1)
        assert sim_pid is not None, "no simulator child"
        time.sleep(2.0)
        t0 = time.monotonic()
        os.kill(sim_pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=30.0)
        exit_s = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    print(f"\nsmcpilot sitl exited {proc.returncode} {exit_s:.2f} s after the simulator's SIGKILL")
    assert proc.returncode == 1
    first = err.strip().splitlines()[0]
    assert first.startswith("smcpilot sitl: error: sim was killed by SIGKILL"), err
    tlogs = list((tmp_path / "logs").glob("*.tlog"))
    assert len(tlogs) == 1 and sum(1 for _ in read_tlog(tlogs[0])) > 500


def _stall_sim(sitl: Sitl, stop_s: float) -> None:
    assert sitl.sim is not None
    os.kill(sitl.sim.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(stop_s)
    finally:
        os.kill(sitl.sim.proc.pid, signal.SIGCONT)


def test_stalled_simulator_real_time_failsafe_then_state_back(tmp_path: Path) -> None:
    opts = sitl_options(tmp_path, "stop-rt", duration_s=600.0, lockstep=False)
    with Sitl(opts) as sitl:
        time.sleep(2.0)
        _stall_sim(sitl, 3.0)
        time.sleep(1.5)
        assert sitl.poll() == (None, None), "a 3 s stall must not end either process"
        assert sitl.fc is not None
    text = "\n".join(sitl.fc.tail)
    assert "FAILSAFE: state lost" in text and "State back" in text, text


def test_stalled_simulator_lockstep_resumes_bit_for_bit(tmp_path: Path) -> None:
    plan = [{"t_s": 0.0, "action": "takeoff", "alt_m": 3.0}, {"t_s": 2.5, "action": "goto", "north_m": 1.0, "east_m": 0.0, "alt_m": 3.0}]
    logs = []
    for name, stall in (("clean", False), ("stalled", True)):
        opts = sitl_options(tmp_path, name, plan=plan, duration_s=4.0, lockstep=True, speed=1.0, noise=True, seed=3)
        with Sitl(opts) as sitl:
            if stall:
                time.sleep(1.0)
                _stall_sim(sitl, 3.0)
            sitl.wait(timeout_s=60.0)
        assert sitl.tlog is not None
        logs.append(sitl.tlog.read_bytes())
    assert len(logs[0]) > 100_000
    assert logs[0] == logs[1], "a 3 s stall changed the lockstep log"
