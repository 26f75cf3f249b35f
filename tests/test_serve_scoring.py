"""Scoring another autopilot's flight on our plant: ``smcpilot sim --serve`` writes the served
flight's ``.tlog`` and ``smcpilot log summary`` scores it with our metrics.

The autopilots are the protocol-level clients of ``test_serve_external`` (ArduPilot's JSON
interface, PX4's simulator API) with a small hover controller of their own, which keeps its own
log of its set-points the way an autopilot's ground station does (``POSITION_TARGET_LOCAL_NED``
and ``ATTITUDE_TARGET``, stamped with its ``time_boot_ms``: the physics' time it was given).

Oracle: the metrics computed again here, independently, from the same two logs read with
pymavlink (``mavutil``) and plain Python loops: the true state of every served step, the motor
commands held from the step they fly, the set-points held for at most a second, trapezoids.
"""

from __future__ import annotations

import io
import json
import math
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from test_serve_external import HOVER, ArduPilotClient, Px4Client, Running

from ground.logs import load_log, summarize
from ground.logs.load import SERVED_PREFIX as READ_PREFIX
from lab.cli import main as smcpilot
from sim_bridge.serve import ServeOptions
from sim_bridge.serve_ardupilot import ROTOR_CHANNELS, ArduPilotJsonServer
from sim_bridge.serve_log import SERVED_PREFIX
from sim_bridge.serve_px4 import Px4Server
from smcpilot.faults import FaultSpec
from smcpilot.frames import quat_from_euler
from smcpilot.geo import Home, global_to_ned
from smcpilot.scenario import Scenario
from smcpilot.tlog import TlogWriter

ROOT = Path(__file__).resolve().parents[1]
FLIGHT_S = 4.0
FAULT_S = 3.0
#: the set-points the pilot flies: (from time s, north, east, altitude m).
SETPOINTS = ((0.3, 0.0, 0.0, 1.0), (2.0, 0.3, -0.2, 1.2))
SCENARIO = Scenario(name="served", faults=(FaultSpec(kind="motor", start_s=FAULT_S, motor=1, efficiency=0.85),))


def _euler(q: Any) -> tuple[float, float, float]:
    w, x, y, z = q
    return (math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)), math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))),
            math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))  # fmt: skip


class HoverPilot:
    """A small autopilot: disarmed until the first set-point, then altitude PD with an integral,
    a position loop giving roll and pitch references, attitude PD; our rotors 1..4 (right, front,
    left, rear) in [0, 1]. It logs its set-points at 10 Hz as an autopilot's ground station would."""

    def __init__(self, log: Path) -> None:
        self.tlog = TlogWriter(log)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.i_alt = 0.0
        self.next_log_s = 0.0
        self.wall0_us = int(time.time() * 1e6)

    def setpoint(self, t_s: float) -> tuple[float, float, float] | None:
        sp = None
        for t0, n, e, alt in SETPOINTS:
            if t_s >= t0:
                sp = (n, e, alt)
        return sp

    def __call__(self, t_s: float, ned: Any, vel: Any, q: Any, rates: Any, dt_s: float) -> tuple[list[float], bool]:
        sp = self.setpoint(t_s)
        if sp is None:
            return [0.0] * 4, False
        (n, e, d), (vn, ve, vd) = ned, vel
        roll, pitch, yaw = _euler(q)
        p, qr, r = rates
        alt, vup = -d, -vd
        self.i_alt += (sp[2] - alt) * dt_s
        c = HOVER + 0.3 * (sp[2] - alt) - 0.3 * vup + 0.3 * self.i_alt
        pitch_ref = max(-0.3, min(0.3, -0.25 * (sp[0] - n) + 0.3 * vn))
        roll_ref = max(-0.3, min(0.3, 0.25 * (sp[1] - e) - 0.3 * ve))
        dr = 0.4 * (roll_ref - roll) - 0.08 * p
        dp = 0.4 * (pitch_ref - pitch) - 0.08 * qr
        dy = 0.3 * (0.0 - yaw) - 0.1 * r
        if t_s >= self.next_log_s - 1e-9:  # the autopilot's telemetry, stamped with its clock
            self.next_log_s += 0.1
            t_ms = int(round(t_s * 1000))
            stamp = self.wall0_us + int(t_s * 1e6)  # a ground station stamps with the wall clock
            mav = self.mav
            self.tlog.write(stamp, mav.position_target_local_ned_encode(t_ms, 1, 0b0000_1101_1111_1000, sp[0], sp[1], -sp[2],
                                                                        0, 0, 0, 0, 0, 0, 0.0, 0.0).pack(mav))  # fmt: skip
            w, x, y, z = quat_from_euler(roll_ref, pitch_ref, 0.0)  # (FRD-in-NED: the same formula)
            self.tlog.write(stamp, mav.attitude_target_encode(t_ms, 0b0000_0111, [w, x, y, z], 0, 0, 0, c).pack(mav))
        rot = [c - dr - dy, c + dp + dy, c + dr - dy, c - dp + dy]
        return [min(1.0, max(0.0, v)) for v in rot], True

    def close(self) -> None:
        self.tlog.close()


def _serve(kind: str, tlog: Path | None, **opts: Any) -> Running:
    out = io.StringIO()
    options = ServeOptions(kind=kind, port=0, tlog=tlog, **opts)
    cls = ArduPilotJsonServer if kind == "ardupilot-json" else Px4Server
    return Running(cls(SCENARIO, options, out=out), out)


def fly_ardupilot(tmp: Path) -> tuple[Path, Path, Running, dict[str, Any]]:
    served, sp = tmp / "served-ap.tlog", tmp / "ardupilot.tlog"
    run = _serve("ardupilot-json", served)
    client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
    pilot = HoverPilot(sp)
    state = client.step([1000] * 4, rate=1000)
    while state["timestamp"] < FLIGHT_S - 1e-9:
        cmd, armed = pilot(state["timestamp"], state["position"], state["velocity"], state["quaternion"], state["imu"]["gyro"], 0.001)
        pwm = [1000] * 4
        if armed:
            for i, ch in enumerate(ROTOR_CHANNELS):
                pwm[ch] = int(round(1000 + 1000 * cmd[i])) if cmd[i] > 0 else 1001
        state = client.step(pwm, rate=1000)
    client.close()
    pilot.close()
    assert run.stop() == 0
    return served, sp, run, state


def fly_px4(tmp: Path) -> tuple[Path, Path, Running, Any]:
    served, sp = tmp / "served-px4.tlog", tmp / "px4.tlog"
    run = _serve("px4", served, watchdog_s=5.0)
    client = Px4Client(run.server.address)  # type: ignore[attr-defined]
    pilot = HoverPilot(sp)
    home = Home()
    state = client.recv("HIL_STATE_QUATERNION")
    client.actuators([0.0] * 4, armed=False)  # PX4's first answer: lockstep from here
    while (m := client.recv("HIL_STATE_QUATERNION", 0.3)) is not None:
        state = m  # (the states sent at real time before it)
    while state.time_usec < FLIGHT_S * 1e6 - 1:
        t_s = state.time_usec * 1e-6
        ned = global_to_ned(home, state.lat * 1e-7, state.lon * 1e-7, state.alt * 1e-3)
        vel = (state.vx * 0.01, state.vy * 0.01, state.vz * 0.01)
        cmd, armed = pilot(t_s, ned, vel, state.attitude_quaternion, (state.rollspeed, state.pitchspeed, state.yawspeed), 0.004)
        client.actuators(cmd, armed=armed)
        state = client.recv("HIL_STATE_QUATERNION")
        assert state is not None
    pilot.close()
    assert run.stop() == 0  # (before the connection closes: PX4 closing it ends the server with an error)
    client.close()
    return served, sp, run, state


# -- the oracle -------------------------------------------------------------------------------------
def oracle(served: Path, setpoints: Path | None) -> dict[str, Any]:
    """The truth metrics again, from the logs through pymavlink, in plain loops."""
    truth, act, starts = [], [], []
    conn = mavutil.mavlink_connection(str(served))
    while (m := conn.recv_match()) is not None:
        kind = m.get_type()
        if kind == "ODOMETRY":
            roll, pitch, yaw = _euler(m.q)
            truth.append((m.time_usec * 1e-6, m.x, m.y, -m.z, roll, pitch, yaw))
        elif kind == "HIL_ACTUATOR_CONTROLS":
            act.append((m.time_usec * 1e-6, list(m.controls[:4]), bool(m.mode & 128)))
        elif kind == "STATUSTEXT" and m.text.startswith("SIM:") and m.severity == 4:
            starts.append(m.text)
    conn.close()
    pos_sp, att_sp = [], []
    if setpoints is not None:
        conn = mavutil.mavlink_connection(str(setpoints))
        while (m := conn.recv_match()) is not None:
            if m.get_type() == "POSITION_TARGET_LOCAL_NED":
                pos_sp.append((m.time_boot_ms * 1e-3, m.x, m.y, -m.z))
            elif m.get_type() == "ATTITUDE_TARGET":
                att_sp.append((m.time_boot_ms * 1e-3, *_euler(m.q)))
        conn.close()

    def latest(rows: list, t: float, max_age: float | None = None) -> Any:
        best = None
        for r in rows:
            if r[0] <= t + 1e-6:
                best = r
        if best is None or (max_age is not None and t - best[0] > max_age):
            return None
        return best

    samples = []
    for t, n, e, alt, roll, pitch, yaw in truth:
        a = latest(act, t)
        motors, armed = (a[1], a[2]) if a is not None else ([math.nan] * 4, False)
        sp = latest(pos_sp, t, 1.0)
        ref = latest(att_sp, t, 1.0)
        err_p = math.dist((n, e, alt), sp[1:]) if sp is not None else math.nan
        if ref is not None:
            dyaw = (yaw - ref[3] + math.pi) % (2 * math.pi) - math.pi
            err_a = math.sqrt((roll - ref[1]) ** 2 + (pitch - ref[2]) ** 2 + dyaw**2)
        else:
            err_a = math.nan
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch)))))
        samples.append((t, armed, motors, err_p, err_a, tilt))
    iae_p = ise_p = iae_a = effort = tv = flight = 0.0
    for (t0, a0, m0, p0, q0, _), (t1, a1, m1, p1, q1, _) in zip(samples, samples[1:]):
        if a0 and a1:
            dt = t1 - t0
            flight += dt
            effort += 0.5 * (sum(c * c for c in m0) + sum(c * c for c in m1)) * dt
            tv += sum(abs(c1 - c0) for c0, c1 in zip(m0, m1))
            if math.isfinite(p0) and math.isfinite(p1):
                iae_p += 0.5 * (p0 + p1) * dt
                ise_p += 0.5 * (p0 * p0 + p1 * p1) * dt
            if math.isfinite(q0) and math.isfinite(q1):
                iae_a += 0.5 * (q0 + q1) * dt
    errs = [s[3] for s in samples if s[1] and math.isfinite(s[3])]
    return {
        "samples": len(samples), "flight_time_s": flight, "effort_u2_s": effort, "motor_tv": tv,
        "max_tilt_deg": max(s[5] for s in samples if s[1]), "iae_pos_m_s": iae_p if pos_sp else None,
        "ise_pos_m2_s": ise_p if pos_sp else None, "iae_att_rad_s": iae_a if att_sp else None,
        "max_pos_err_m": max(errs) if errs else None, "fault_start_s": len(starts),
    }  # fmt: skip


def _check(served: Path, sp: Path) -> dict[str, Any]:
    """log summary with and without the set-points against the oracle; the scored summary."""
    bare = summarize(load_log(served))
    scored = _summary(served, sp)
    assert bare["served"] == scored["served"]
    for s, setpoints in ((bare, None), (scored, sp)):
        want = oracle(served, setpoints)
        got = s["truth_metrics"]
        assert got["samples"] == want["samples"] and got["crashed"] is False
        for key in ("flight_time_s", "effort_u2_s", "motor_tv", "max_tilt_deg", "iae_pos_m_s", "ise_pos_m2_s", "iae_att_rad_s", "max_pos_err_m"):
            if want[key] is None:
                assert got[key] is None, key
            else:
                assert got[key] == pytest.approx(want[key], rel=1e-9, abs=1e-12), key
        assert got["fault_start_s"] == pytest.approx(FAULT_S, abs=0.002) and want["fault_start_s"] == 1
    # without set-points nothing that needs one is scored, and the summary says so
    assert bare["truth_metrics"]["itae_pos_m_s2"] is None and bare["truth_metrics"]["recovered"] is None
    assert bare["metrics_sources"]["setpoints"].startswith("no set-points")
    assert scored["metrics_sources"]["setpoints"].startswith("the autopilot's set-points in")
    assert isinstance(scored["truth_metrics"]["recovered"], bool) and scored["truth_metrics"]["itae_pos_m_s2"] > 0
    return scored


def _summary(served: Path, sp: Path | None = None) -> dict[str, Any]:
    argv = ["log", "summary", str(served), "--json", "-"] + (["--setpoints", str(sp)] if sp is not None else [])
    out = io.StringIO()
    old = sys.stdout
    sys.stdout = out
    try:
        assert smcpilot(argv) == 0
    finally:
        sys.stdout = old
    return json.loads(out.getvalue())


# -- the tests ----------------------------------------------------------------------------------------
def test_an_ardupilot_flight_is_scored_with_our_metrics(tmp_path: Path) -> None:
    served, sp, run, last = fly_ardupilot(tmp_path)
    s = _check(served, sp)
    assert s["served"] == "ardupilot-json" and s["lockstep"] is True
    m = s["truth_metrics"]
    assert 3.5 < m["flight_time_s"] < 3.8 and m["max_tilt_deg"] < 20.0  # armed from 0.3 s, flew to the end
    assert m["max_pos_err_m"] == pytest.approx(1.0, abs=0.05)  # the first set-point, 1 m up from the ground
    # the log holds what was served: the last JSON state is the last logged sensed state
    log = load_log(served)
    assert log.pos_t_s[-1] == pytest.approx(last["timestamp"], abs=1e-9)
    assert [log.north_m[-1], log.east_m[-1], -log.alt_m[-1]] == pytest.approx(last["position"], rel=1e-6, abs=1e-6)
    summary = run.summary()
    assert summary["tlog"] == str(served) and summary["frames"] == log.message_counts["HIL_ACTUATOR_CONTROLS"]
    assert log.message_counts["ODOMETRY"] == log.message_counts["HIGHRES_IMU"] == summary["frames"]  # a state after every step
    text = io.StringIO()
    old = sys.stdout
    sys.stdout = text
    try:
        assert smcpilot(["log", "summary", str(served), "--setpoints", str(sp)]) == 0
    finally:
        sys.stdout = old
    printed = text.getvalue()
    assert "Served" in printed and "scored against      the autopilot's set-points in ardupilot.tlog" in printed
    assert "Truth metrics" in printed and "IAE n/a" not in printed


def test_a_px4_flight_is_scored_with_our_metrics(tmp_path: Path) -> None:
    served, sp, run, _ = fly_px4(tmp_path)
    s = _check(served, sp)
    assert s["served"] == "px4"
    m = s["truth_metrics"]
    assert 3.5 < m["flight_time_s"] < 3.8 and m["max_tilt_deg"] < 20.0
    log = load_log(served)
    boot = run.summary()["bootstrap_steps"]
    assert log.message_counts["ODOMETRY"] == boot + run.summary()["actuator_msgs"] + 1  # at rest, then after every step
    assert log.lockstep is True and not log.armed[:boot].any()  # the boot steps: rotors stopped


def test_the_served_log_reads_as_our_logs_do(tmp_path: Path) -> None:
    """pymavlink reads every record; the reader and the writer agree on the served log's mark;
    the truth at rest is the origin, level; a restart continues the log's time."""
    served = tmp_path / "restart.tlog"
    run = _serve("ardupilot-json", served)
    client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
    client.fly([1500] * 4, 300)
    client.frame = 0  # ArduPilot restarted
    client.fly([1000] * 4, 10)
    client.close()
    assert run.stop() == 0
    assert SERVED_PREFIX == READ_PREFIX
    conn = mavutil.mavlink_connection(str(served))
    kinds = []
    while (m := conn.recv_match()) is not None:
        kinds.append(m.get_type())
    conn.close()
    log = load_log(served)
    assert len(kinds) == log.records and log.served_to == "ardupilot-json"
    assert log.message_counts["HIL_ACTUATOR_CONTROLS"] == 310 and log.message_counts["ODOMETRY"] == 310
    assert all(b > a for a, b in zip(log.truth_t_s, log.truth_t_s[1:]))  # time goes on across the restart
    k = int(log.truth_t_s.searchsorted(0.300 + 1e-9))
    assert log.truth_t_s[k] == pytest.approx(0.302) and log.truth_alt_m[k] == pytest.approx(0.0, abs=1e-4)  # the fresh vehicle
    assert any(e.text.startswith("ArduPilot restarted") and e.severity == "WARNING" for e in log.events)
    assert summarize(log)["truth_metrics"]["fault_start_s"] is None  # a restart is no fault


# -- bad input: one line, exit 2 --------------------------------------------------------------------
def _error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert smcpilot(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("smcpilot log: error: "), err
    return err


def test_bad_and_empty_logs_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    assert "is empty" in _error(["log", "summary", str(empty)], capsys)
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(b"time,x\n0,1\n" * 20)
    assert "is not a MAVLink telemetry log" in _error(["log", "summary", str(junk)], capsys)
    assert "no such log file" in _error(["log", "summary", str(tmp_path / "missing.tlog")], capsys)
    # a server stopped before any frame: the mark, no state
    idle = tmp_path / "idle.tlog"
    run = _serve("ardupilot-json", idle)
    assert run.stop() == 0
    assert "never stepped the physics" in _error(["log", "summary", str(idle)], capsys)
    # set-points: none in the file, junk, empty, another flight's, for our own FC's log
    served, sp, _, _ = fly_ardupilot(tmp_path)
    assert "no set-points to score against" in _error(["log", "summary", str(served), "--setpoints", str(served)], capsys)
    assert "is not a MAVLink telemetry log" in _error(["log", "summary", str(served), "--setpoints", str(junk)], capsys)
    assert "is empty: no set-points" in _error(["log", "summary", str(served), "--setpoints", str(empty)], capsys)
    late = tmp_path / "late.tlog"
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    with TlogWriter(late) as w:
        w.write(1, mav.position_target_local_ned_encode(900_000, 1, 0, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav))
    assert "outside the served flight" in _error(["log", "summary", str(served), "--setpoints", str(late)], capsys)
    from lab.run import fly_in_process

    ours = fly_in_process(Scenario.from_toml(ROOT / "examples" / "scenarios" / "hover.toml").with_changes(duration_s=1.0), tmp_path / "fc.tlog")
    assert "is for a served flight's log" in _error(["log", "summary", str(ours.tlog), "--setpoints", str(sp)], capsys)


def test_smcpilot_sim_serve_writes_its_log_and_the_scenario_beside_it(tmp_path: Path) -> None:
    """The command line: the default log name under logs/, the scenario beside it, the log's path
    in the summary line; ``--tlog`` a directory is a one-line error."""
    proc = subprocess.Popen([sys.executable, "-m", "lab.cli", "sim", "--serve", "ardupilot-json:0", "--duration", "0.05"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline()
        port = int(ready.split("udp=127.0.0.1:")[1].split()[0])
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client = ArduPilotClient(("127.0.0.1", port))
        client.fly([1000] * 4, 50)
        client.close()
        sock.close()
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    (log,) = (tmp_path / "logs").glob("serve-ardupilot-json-*.tlog")
    assert log.with_name(log.stem + ".scenario.toml").is_file()
    summary = json.loads(out.strip().splitlines()[-1].split(" ", 1)[1])
    assert summary["tlog"] == str(Path("logs") / log.name)
    assert f"smcpilot log summary {Path('logs') / log.name}" in out
    assert load_log(log).message_counts["ODOMETRY"] == 50
    r = subprocess.run([sys.executable, "-m", "lab.cli", "sim", "--serve", "px4:0", "--tlog", str(tmp_path)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "a directory, not a file" in r.stderr


def test_log_compare_puts_a_served_flight_beside_ours(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lab.run import fly_in_process

    served, sp, _, _ = fly_ardupilot(tmp_path)
    ours = fly_in_process(SCENARIO.with_changes(duration_s=FLIGHT_S), tmp_path / "fc.tlog").tlog
    capsys.readouterr()
    assert smcpilot(["log", "compare", str(served), str(ours), "--setpoints", f"{served}={sp}", "--json", "-"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["log"] for r in rows] == [str(served), str(ours)]
    # each column is what `log summary` scores for that log alone (the truth, against the right set-points)
    assert rows[0]["metrics"] == _summary(served, sp)["truth_metrics"]
    assert rows[1]["metrics"] == _summary(ours)["truth_metrics"]
    assert rows[0]["scored"] == rows[1]["scored"] == "true state"
    assert "ardupilot.tlog" in rows[0]["scored_against"] and rows[1]["scored_against"] is None
    capsys.readouterr()
    assert smcpilot(["log", "compare", str(served), str(ours), "--setpoints", f"{served}={sp}"]) == 0
    table = capsys.readouterr().out
    iae = f"{rows[0]['metrics']['iae_pos_m_s']:.3f}"
    assert "IAE position, m s" in table and iae in table and f"{ours.name}: true state, against its own set-points" in table
    assert "wants LOG=AUTOPILOT.tlog" in _error(["log", "compare", str(served), "--setpoints", str(sp)], capsys)
    assert "is not one of the logs compared" in _error(["log", "compare", str(ours), "--setpoints", f"{served}={sp}"], capsys)
    assert "is for a served flight's log" in _error(["log", "compare", str(ours), "--setpoints", f"{ours}={sp}"], capsys)
