"""The flight-controller process against bad input, with the test playing the simulator.

The FC runs for real (``python -m fc``, lockstep unless stated) on ``udpin:127.0.0.1:0``; the test
sends ATTITUDE + LOCAL_POSITION_NED datagrams from system 1, component 200 (pymavlink) and reads
the HIL_ACTUATOR_CONTROLS answers. Lockstep: one answer per state, stamped with the state's time,
so "the FC dropped X and answered the next good state" is checked by the first answer after X
being the one stamped with the good state's time. Counters come from the FC_SUMMARY line.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from sitl_helpers import TAKEOFF_3M, FakeSim, FcProcess, load_flight, parse_datagram, udp_socket, write_plan

from fc.config import FcConfig
from fc.mixer import Mixer
from smcpilot.vehicle import DEFAULT_VEHICLE

_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


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
        sim = FakeSim((host, int(port)))
        yield fc, sim
    finally:
        if sim is not None:
            sim.close()
        fc.kill()


def _assert_normal_answer(msg: mavlink.MAVLink_message, t_ms: int) -> None:
    assert msg.time_usec == t_ms * 1000, f"answer stamped {msg.time_usec} µs, expected {t_ms * 1000}"
    assert msg.flags & 1, "lockstep flag missing"
    assert msg.mode & _ARMED, "the take-off plan should have armed the FC"
    assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in msg.controls[:4]), msg.controls


def _sim_counters(summary: dict) -> dict:
    return {k: summary["links"]["sim"][k] for k in ("rx_bad", "rx_foreign_system", "rx_unknown")} | {
        "rx_invalid_state": summary["rx_invalid_state"],
        "duplicate_states": summary["duplicate_states"],
    }


def _bad_garbage(sim: FakeSim, t_ms: int) -> bytes:
    return b"\x00\x01 this is not MAVLink \x7f" * 3


def _bad_truncated(sim: FakeSim, t_ms: int) -> bytes:
    att, pos = sim.state_packets(t_ms, ned=(0.0, 0.0, -1.0))
    return att + pos[: len(pos) // 2]


def _bad_crc(sim: FakeSim, t_ms: int) -> bytes:
    att, pos = sim.state_packets(t_ms, ned=(0.0, 0.0, -1.0))
    return att + pos[:-1] + bytes([pos[-1] ^ 0x5A])


def _bad_nan_position(sim: FakeSim, t_ms: int) -> bytes:
    att, pos = sim.state_packets(t_ms, ned=(float("nan"), 0.0, 0.0))
    return att + pos


def _bad_inf_attitude(sim: FakeSim, t_ms: int) -> bytes:
    att, pos = sim.state_packets(t_ms, rpy=(0.0, float("inf"), 0.0))
    return att + pos


def _bad_foreign_system(sim: FakeSim, t_ms: int) -> bytes:
    att, pos = sim.state_packets(t_ms, ned=(5.0, 5.0, -5.0), sysid=2)
    return att + pos


BAD_INPUTS = {
    "malformed": (_bad_garbage, {"rx_bad": 1}),
    "truncated": (_bad_truncated, {"rx_bad": 1}),
    "bad_crc": (_bad_crc, {"rx_bad": 1}),
    "foreign_system": (_bad_foreign_system, {"rx_foreign_system": 2}),  # ATTITUDE and LOCAL_POSITION_NED
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_state_is_dropped_counted_and_the_next_good_state_answered(lockstep_fc, case: str) -> None:
    fc, sim = lockstep_fc
    make, expected = BAD_INPUTS[case]
    _assert_normal_answer(sim.exchange(0), 0)
    _assert_normal_answer(sim.exchange(2), 2)
    sim.send_raw(make(sim, 4))
    # The bad datagram is dropped unanswered; the simulator re-sends the state it stands for, and
    # the first answer after it is that state's (an answer to the bad bytes would arrive first).
    _assert_normal_answer(sim.exchange(4), 4)
    _assert_normal_answer(sim.exchange(6), 6)
    assert fc.stop() == 0
    summary = fc.summary()
    want = {"rx_bad": 0, "rx_foreign_system": 0, "rx_unknown": 0, "rx_invalid_state": 0, "duplicate_states": 0} | expected
    assert _sim_counters(summary) == want
    assert summary["ticks"] == 4


def test_state_with_fields_not_measured_is_ticked_on_the_estimate(lockstep_fc) -> None:
    """A NaN field is a sensor dropout (the simulator keeps the lockstep going): the FC answers
    that very state, from its estimate — a missing position is dead-reckoned, an attitude that is
    missing (or garbage: infinite) puts it in the state-loss failsafe — never with a NaN motor."""
    fc, sim = lockstep_fc
    _assert_normal_answer(sim.exchange(0), 0)
    _assert_normal_answer(sim.exchange(2), 2)
    sim.send_raw(_bad_nan_position(sim, 4))
    (answer,) = sim.recv_actuators()
    _assert_normal_answer(answer, 4)  # dead reckoning: still flying, closed loop
    sim.send_raw(_bad_inf_attitude(sim, 6))
    (answer,) = sim.recv_actuators()
    _assert_normal_answer(answer, 6)  # attitude lost: open-loop failsafe, still armed
    failsafe = Mixer(DEFAULT_VEHICLE).mix(0.0, 0.0, 0.0, FcConfig().failsafe_thrust_fraction * DEFAULT_VEHICLE.weight_n)[0]
    assert list(answer.controls[:4]) == pytest.approx(list(failsafe), abs=1e-6)
    _assert_normal_answer(sim.exchange(8), 8)
    assert fc.stop() == 0
    summary = fc.summary()
    assert summary["ticks"] == 5
    assert summary["states_missing_fields"] == 2 and summary["rx_invalid_state"] == 1  # the infinite one
    assert summary["failsafe_events"] == 1
    texts = [line for line in fc.all_lines if line.startswith("fc: ")]
    assert "fc: position lost: dead reckoning" in texts
    assert "fc: FAILSAFE: attitude lost, level and descend" in texts
    assert "fc: State back: failsafe landing" in texts


def test_duplicate_state_gets_the_same_answer_again(lockstep_fc) -> None:
    fc, sim = lockstep_fc
    sim.exchange(0)
    first = sim.exchange(2, ned=(0.0, 0.0, -0.5), vel=(0.0, 0.0, -0.3))
    again = sim.exchange(2, ned=(0.0, 0.0, -0.5), vel=(0.0, 0.0, -0.3))  # the simulator re-sent
    assert again.time_usec == first.time_usec == 2000
    assert list(again.controls) == list(first.controls)
    assert (again.mode, again.flags) == (first.mode, first.flags)
    # A state from the past is dropped without an answer; the next new state is answered.
    sim.send_state(0)
    _assert_normal_answer(sim.exchange(4), 4)
    assert fc.stop() == 0
    summary = fc.summary()
    assert summary["ticks"] == 3, "a duplicate must not run another control tick"
    assert summary["duplicate_states"] == 1  # the re-sent state
    assert summary["out_of_order_states"] == 1  # the state from the past
    assert summary["links"]["sim"]["rx_bad"] == 0


# -- configuration errors: exit 2, one line naming the problem --------------------------------
CONFIG_ERRORS = {
    "vehicle_unknown_key": ("vehicle.toml", "[vehicle]\nmass_kgg = 1.0\n", "--vehicle", "unknown vehicle key 'mass_kgg'"),
    "vehicle_bad_value": ("vehicle.toml", "[vehicle]\nmass_kg = -0.5\n", "--vehicle", "'mass_kg' must be > 0"),
    "vehicle_not_toml": ("vehicle.toml", "[vehicle\nmass_kg = 1\n", "--vehicle", "not valid TOML"),
    "plan_missing_key": (
        "plan.toml",
        '[[step]]\nt_s = 0.0\naction = "takeoff"\nalt_m = 3.0\n\n[[step]]\nt_s = 5.0\naction = "goto"\nnorth_m = 1.0\nalt_m = 3.0\n',
        "--plan",
        "step 2 (goto): missing key 'east_m'",
    ),
    "plan_unknown_key": ("plan.toml", '[[step]]\nt_s = 0.0\naction = "land"\nspeed = 2.0\n', "--plan", "step 1 (land): unknown key 'speed'"),
    "plan_not_toml": ("plan.toml", "[[step]\n", "--plan", "not valid TOML"),
}


def _run_fc_expect_config_error(args: list[str], tmp_path: Path, needle: str) -> str:
    fc = FcProcess(args + ["--lockstep", "--tlog", str(tmp_path / "x.tlog")], cwd=tmp_path)
    try:
        rc = fc.wait(timeout_s=60.0)
    finally:
        fc.kill()
    lines = [ln for ln in fc.all_lines if ln.strip()]
    assert rc == 2, (rc, lines)
    assert len(lines) == 1, lines
    assert lines[0].startswith("fc: error: "), lines
    assert needle in lines[0], lines
    assert "Traceback" not in lines[0]
    return lines[0]


@pytest.mark.parametrize("case", list(CONFIG_ERRORS))
def test_broken_file_exits_2_naming_the_problem(tmp_path: Path, case: str) -> None:
    name, text, flag, needle = CONFIG_ERRORS[case]
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    line = _run_fc_expect_config_error([flag, str(path)], tmp_path, needle)
    assert str(path) in line, f"the message does not name the file: {line}"


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--sim", "udp:127.0.0.1"], "missing ':PORT'"),
        (["--sim", "tcp:127.0.0.1:5760"], "unknown form"),
        (["--gcs", "udpin:127.0.0.1:70000"], "port 70000 is outside"),
        (["--plan", "/nonexistent/plan.toml"], "cannot read plan"),
    ],
)
def test_bad_url_or_missing_file_exits_2(tmp_path: Path, args: list[str], needle: str) -> None:
    _run_fc_expect_config_error(args, tmp_path, needle)


def test_bad_url_leaves_no_empty_log(tmp_path: Path) -> None:
    _run_fc_expect_config_error(["--sim", "udp:127.0.0.1"], tmp_path, "missing ':PORT'")
    assert not (tmp_path / "x.tlog").exists(), "an empty .tlog was left behind by a configuration error"


# -- real-time failsafe -------------------------------------------------------------------------
FEED_S = 0.5
FEED_PERIOD_S = 0.002


def test_realtime_state_loss_failsafe_then_watchdog(tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "plan.toml", TAKEOFF_3M)
    gcs = udp_socket(timeout_s=0.2)
    tlog = tmp_path / "rt.tlog"
    fc = FcProcess(
        ["--sim", "udpin:127.0.0.1:0", "--gcs", f"udp:127.0.0.1:{gcs.getsockname()[1]}", "--plan", str(plan),
         "--tlog", str(tlog), "--watchdog-s", "1"], cwd=tmp_path,
    )  # fmt: skip
    sim = None
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)), timeout_s=0.2)
        # ~500 Hz of states (on the ground, level) for ~0.5 s, on absolute deadlines.
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < FEED_S:
            sim.send_state(2 * k)
            k += 1
            delay = start + k * FEED_PERIOD_S - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        stopped_at = time.monotonic()
        # Then silence: the GCS hears FAILSAFE soon (state timeout 0.1 s).
        failsafe_text = None
        while failsafe_text is None and time.monotonic() - stopped_at < 5.0:
            try:
                data, _ = gcs.recvfrom(65535)
            except TimeoutError:
                continue
            for m in parse_datagram(data):
                if m.get_type() == "STATUSTEXT" and "FAILSAFE" in m.text:
                    failsafe_text = m.text
        assert failsafe_text is not None, f"no FAILSAFE STATUSTEXT; fc output: {fc.all_lines}"
        rc = fc.wait(timeout_s=30.0)
    finally:
        if sim is not None:
            sim.close()
        gcs.close()
        fc.kill()
    assert rc == 3, (rc, fc.all_lines)
    out = "\n".join(fc.all_lines)
    assert "simulator has been silent" in out and "real-time watchdog" in out, out
    summary = fc.summary()
    assert summary["failsafe_events"] >= 1
    # From the log: every actuator command after the (last) FAILSAFE is level thrust.
    from smcpilot.tlog import read_tlog

    records = [(t, m) for t, m in read_tlog(tlog)]
    idx = max(i for i, (_, m) in enumerate(records) if m.get_type() == "STATUSTEXT" and "FAILSAFE" in m.text)
    after = [m for _, m in records[idx + 1 :] if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
    assert len(after) >= 10, f"only {len(after)} actuator messages after the failsafe"
    cfg = FcConfig()
    level = Mixer(DEFAULT_VEHICLE).mix(0.0, 0.0, 0.0, cfg.failsafe_thrust_fraction * DEFAULT_VEHICLE.weight_n)[0]
    assert len(set(level)) == 1
    for m in after:
        c = list(m.controls[:4])
        assert c[0] == c[1] == c[2] == c[3], f"failsafe motors not level: {c}"
        assert c[0] == pytest.approx(level[0], abs=1e-6)
        assert m.mode & _ARMED
        assert not m.flags & 1, "real-time FC must not set the lockstep flag"
    f = load_flight(tlog)
    assert len(f.t) > 50, "the fed states are not in the log"


def test_lockstep_rate_mismatch_is_a_clear_error(lockstep_fc) -> None:
    """A simulator stepping 4 ms per state against a 500 Hz FC would fly the law with the wrong dt.
    One odd stamp is dropped unanswered and costs nothing; a simulator that insists on it (re-sends
    the state the FC does not answer) is at another rate: exit 2 with the reason."""
    fc, sim = lockstep_fc
    for t in (0, 2, 4):
        _assert_normal_answer(sim.exchange(t), t)
    sim.send_state(8)  # one odd step: dropped, not adopted
    _assert_normal_answer(sim.exchange(6), 6)  # the right next state is still answered
    for _ in range(3):  # a 250 Hz simulator insists on its 4 ms step
        sim.send_state(10)
        time.sleep(0.05)
    assert fc.wait(timeout_s=30.0) == 2
    assert any("steps 4 ms per state" in ln and "500 Hz" in ln for ln in fc.all_lines), fc.all_lines


def test_command_line_beats_the_parameter_file(tmp_path: Path) -> None:
    """A stored FC_CONTROLLER/FC_RATE_HZ must not silently override what the command line asks for."""
    pf = tmp_path / "p.parm"
    pf.write_text("FC_CONTROLLER 2\nFC_RATE_HZ 250\n")  # cascade_pid at 250 Hz stored
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--param-file", str(pf),
                    "--controller", "pid_smc", "--rate-hz", "500", "--tlog", str(tmp_path / "x.tlog")], cwd=tmp_path)  # fmt: skip
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)))
        try:
            for t in (0, 2, 4, 6):
                assert sim.exchange(t).time_usec == t * 1000  # 2 ms steps answered: 500 Hz in force
        finally:
            sim.close()
        ready = [fc.await_line("FC_READY", 10.0)]  # the reader thread may not have the line yet
        assert ready and "controller=pid_smc" in ready[0], fc.all_lines
    finally:
        fc.kill()
    # Without the flags, the file's values are used.
    fc = FcProcess(["--sim", "udpin:127.0.0.1:0", "--gcs", "none", "--lockstep", "--param-file", str(pf),
                    "--tlog", str(tmp_path / "y.tlog")], cwd=tmp_path)  # fmt: skip
    try:
        host, port = fc.listening()["sim"].rsplit(":", 1)
        sim = FakeSim((host, int(port)))
        try:
            for t in (0, 4, 8, 12):
                assert sim.exchange(t).time_usec == t * 1000  # 4 ms steps answered: 250 Hz from the file
        finally:
            sim.close()
        ready = [fc.await_line("FC_READY", 10.0)]  # the reader thread may not have the line yet
        assert ready and "controller=cascade_pid" in ready[0], fc.all_lines
    finally:
        fc.kill()
