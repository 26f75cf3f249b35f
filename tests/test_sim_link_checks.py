"""The simulator link's checks, with the test playing the other side over real UDP.

FC side (``python -m fc``, the test is the simulator): states only from the simulator's address;
in lockstep a stamp must be exactly one period after the last tick's (a +10 s or a +3 ms stamp is
counted and dropped, never adopted: the next good state is answered as if nothing had come); in
real time a stale replay and an implausible future stamp are counted and dropped.
Simulator side (``python -m sim_bridge``, the test is the FC): motor commands only from the FC's
address; a NaN motor value is counted and that motor keeps its last command.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import TAKEOFF_3M, FakeSim, FcProcess, parse_datagram, udp_socket, write_plan

from smcpilot.tlog import read_tlog

PERIOD_MS = 2  # 500 Hz


@pytest.fixture()
def lockstep_fc(tmp_path: Path) -> Iterator[tuple[FcProcess, FakeSim]]:
    plan = write_plan(tmp_path / "plan.toml", TAKEOFF_3M)
    fc = FcProcess(
        ["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--plan", str(plan),
         "--tlog", str(tmp_path / "fc.tlog"), "--watchdog-s", "30"], cwd=tmp_path,
    )  # fmt: skip
    sim = None
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)), timeout_s=5.0)
        yield fc, sim
    finally:
        if sim is not None:
            sim.close()
        fc.kill()


def _answers(sim: FakeSim, wait_s: float) -> list[int]:
    """Stamps (ms) of every actuator answer arriving within ``wait_s``."""
    out: list[int] = []
    end = time.monotonic() + wait_s
    while (left := end - time.monotonic()) > 0:
        sim.sock.settimeout(left)
        try:
            data, _ = sim.sock.recvfrom(65535)
        except TimeoutError:
            break
        out += [m.time_usec // 1000 for m in parse_datagram(data) if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
    sim.sock.settimeout(5.0)
    return out


def _no_answer(sim: FakeSim, t_ms: int, wait_s: float = 0.15) -> bool:
    """No answer stamped ``t_ms`` (the FC's re-sends of its last answer, while it waits, are allowed)."""
    return t_ms not in _answers(sim, wait_s)


def _exchange(sim: FakeSim, t_ms: int) -> mavlink.MAVLink_message:
    """Send a state, return the answer stamped with its time (skipping re-sends of older answers)."""
    sim.send_state(t_ms)
    end = time.monotonic() + 5.0
    while time.monotonic() < end:
        for m in sim.recv_actuators():
            if m.time_usec == t_ms * 1000:
                return m
            assert m.time_usec < t_ms * 1000, f"answer stamped {m.time_usec} µs to a state of {t_ms} ms"
    raise AssertionError(f"no answer to the state of {t_ms} ms")


def test_lockstep_wrong_stamps_are_counted_and_dropped_never_adopted(lockstep_fc, tmp_path: Path) -> None:
    fc, sim = lockstep_fc
    t = 0
    for _ in range(20):
        assert _exchange(sim, t).time_usec == t * 1000
        t += PERIOD_MS
    last = t - PERIOD_MS
    # +10 s, then +3 ms, then +1 ms, then an old one: none is answered (the FC's clock stays put).
    for bad in (last + 10_000, last + 3, last + 1, last - 4):
        sim.send_state(bad)
        assert _no_answer(sim, bad), f"a state stamped {bad} ms was answered after {last} ms"
    # The next good state is answered, stamped as it is: nothing was adopted.
    for _ in range(20):
        assert _exchange(sim, t).time_usec == t * 1000
        t += PERIOD_MS
    assert fc.stop() == 0
    s = fc.summary()
    assert s["wrong_step_states"] == 3, s
    assert s["out_of_order_states"] == 1, s
    assert s["ticks"] == 40
    assert abs(s["sim_time_s"] - (t - PERIOD_MS) / 1000) < 1e-9
    # Dropped states are not in the log: its simulator states are exactly the 40 flown.
    stamps = [m.time_boot_ms for _, m in read_tlog(tmp_path / "fc.tlog") if m.get_type() == "LOCAL_POSITION_NED"]
    assert stamps == list(range(0, t, PERIOD_MS))


def test_lockstep_a_resent_state_is_answered_again_and_not_logged(lockstep_fc, tmp_path: Path) -> None:
    fc, sim = lockstep_fc
    for t in range(0, 20, PERIOD_MS):
        first = _exchange(sim, t)
        again = _exchange(sim, t)  # the simulator re-sends (our answer "was lost")
        assert again.get_msgbuf() == first.get_msgbuf(), "a re-sent state must get the very same answer"
    assert fc.stop() == 0
    s = fc.summary()
    assert s["duplicate_states"] == 10 and s["ticks"] == 10, s
    log = [m for _, m in read_tlog(tmp_path / "fc.tlog")]
    assert sum(m.get_type() == "LOCAL_POSITION_NED" for m in log) == 10
    assert sum(m.get_type() == "HIL_ACTUATOR_CONTROLS" for m in log) == 10


def test_states_from_another_address_are_dropped(lockstep_fc) -> None:
    fc, sim = lockstep_fc
    for t in range(0, 10, PERIOD_MS):
        _exchange(sim, t)
    intruder = FakeSim(sim.addr, timeout_s=0.3)
    try:
        intruder.send_state(10, ned=(50.0, 0.0, -40.0))
        assert _no_answer(intruder, 10) and _no_answer(sim, 10)
    finally:
        intruder.close()
    assert _exchange(sim, 10).time_usec == 10_000  # the real simulator's state of that time is flown
    assert fc.stop() == 0
    assert fc.summary()["foreign_states"] == 1


def test_a_simulator_at_another_rate_is_told_at_once(tmp_path: Path) -> None:
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--tlog", str(tmp_path / "x.tlog")], cwd=tmp_path)
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)))
        _exchange(sim, 0)
        sim.send_state(4)  # a 250 Hz simulator
        assert fc.wait(10.0) == 2
        assert any("steps 4 ms per state" in ln for ln in fc.all_lines), fc.all_lines
        sim.close()
    finally:
        fc.kill()


def test_real_time_stale_and_future_states_are_counted_and_dropped(tmp_path: Path) -> None:
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--tlog", str(tmp_path / "rt.tlog"), "--watchdog-s", "30"],
                   cwd=tmp_path)  # fmt: skip
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)), timeout_s=2.0)
        t0 = time.monotonic()
        t_ms = 1000
        sent_bad = 0
        while time.monotonic() - t0 < 1.0:
            t_ms += 10
            sim.send_state(t_ms)
            if t_ms % 100 == 0:
                sim.send_state(t_ms - 500)  # a stale replay
                sim.send_state(t_ms + 10_000)  # a forged future stamp
                sent_bad += 1
            time.sleep(0.01)
        assert fc.stop() == 0
    finally:
        fc.kill()
    s = fc.summary()
    assert s["stale_states"] == sent_bad and s["future_states"] == sent_bad, s
    stamps = [m.time_boot_ms for _, m in read_tlog(tmp_path / "rt.tlog") if m.get_type() == "LOCAL_POSITION_NED"]
    assert stamps == sorted(stamps) and max(stamps) <= t_ms, "a stale or future state was taken"


# -- the simulator's side -------------------------------------------------------------------------
def _bridge(fc_port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sim_bridge", "--fc", f"udp:127.0.0.1:{fc_port}", "--lockstep", "--watchdog-s", "10", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )  # fmt: skip


def test_bridge_counts_nan_motor_values_and_takes_commands_from_the_fc_only() -> None:
    fc_sock = udp_socket(5.0)
    other = udp_socket(5.0)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    proc = _bridge(fc_sock.getsockname()[1], "--duration", "0.02")
    try:
        armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        answered = 0
        fc_sock.settimeout(0.2)
        deadline = time.monotonic() + 20.0
        while proc.poll() is None and time.monotonic() < deadline:  # answer every state, the final one too
            try:
                data, addr = fc_sock.recvfrom(65535)
            except TimeoutError:
                continue
            lpn = [m for m in parse_datagram(data) if m.get_type() == "LOCAL_POSITION_NED"]
            if not lpn:
                continue
            t_us = lpn[0].time_boot_ms * 1000
            if t_us < answered * 2000:
                continue  # a re-send of a state already answered (the bridge re-sends quickly)
            c = [0.6, math.nan, 0.6, 0.6] if answered % 2 else [0.6] * 4
            if answered == 3:  # an answer from elsewhere first: ignored (the real one follows)
                other.sendto(mav.hil_actuator_controls_encode(t_us, [1.0] * 16, armed, 1).pack(mav), addr)
                time.sleep(0.02)
            fc_sock.sendto(mav.hil_actuator_controls_encode(t_us, c + [0.0] * 12, armed, 1).pack(mav), addr)
            answered += 1
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        fc_sock.close()
        other.close()
    assert proc.returncode == 0, out
    import json

    summary = json.loads(next(ln for ln in out.splitlines() if ln.startswith("SIM_SUMMARY ")).split(" ", 1)[1])
    assert summary["nonfinite_actuator_msgs"] == 5, summary
    assert summary["foreign_msgs"] == 1, summary
    assert summary["actuator_msgs"] == 10, summary
