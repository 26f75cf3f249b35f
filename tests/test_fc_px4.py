"""The flight controller on PX4's simulator MAVLink API (``python -m fc --sim px4:tcp:HOST:PORT``).

Pure parts against independent oracles (the rotor geometry of PX4's quad X and of our plus written
out as positions and spin directions, smcpilot.frames, smcpilot.geo); the link over real TCP on
127.0.0.1 with the FC as a real process and a protocol-level simulator written here from PX4's
simulator API (it listens, sends HIL_STATE_QUATERNION, reads HIL_ACTUATOR_CONTROLS); and a flight
of two real processes, ``smcpilot sim --serve px4`` and ``python -m fc --sim px4:...``.
"""

from __future__ import annotations

import math
import select
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.mixer import mixer_params
from fc.sim_px4 import (
    STATE_NO_ATTITUDE,
    STATE_NONFINITE,
    Px4Output,
    parse_px4_url,
    plus_to_quad_x,
    px4_controls,
    wire_of_hil_state,
)
from ground.logs import load_log, summarize
from ground.logs.setpoints import load_setpoints
from smcpilot.errors import EndpointError
from smcpilot.frames import quat_from_euler
from smcpilot.geo import Home, ned_to_global
from smcpilot.link import PacketSink
from smcpilot.vehicle import DEFAULT_VEHICLE
from tests.sitl_helpers import FcProcess, load_flight, write_plan

ROOT = Path(__file__).resolve().parents[1]
HOME = Home(47.397742, 8.545594, 488.0)  # PX4's SITL field
PERIOD_US = 4000  # 250 Hz, PX4's simulators' rate
WALL_S = 30.0


# -- pure ------------------------------------------------------------------------------------------
def test_url_forms_and_errors() -> None:
    assert parse_px4_url("px4") == ("127.0.0.1", 4560)
    assert parse_px4_url("px4:tcp:10.0.0.2") == ("10.0.0.2", 4560)
    assert parse_px4_url("px4:tcp:localhost:4561") == ("localhost", 4561)
    for bad in ("px4:udp:1.2.3.4:4560", "px4:tcp:", "px4:tcp:h:0", "px4:tcp:h:99999", "px4x", "px4:tcp:h:12:3"):
        with pytest.raises(EndpointError):
            parse_px4_url(bad)
    with pytest.raises(EndpointError):
        Px4Output("hexa")
    with pytest.raises(EndpointError):
        Px4Output("quad-x", "pwm")


def _wrench(positions_flu: list[tuple[float, float]], ccw: list[bool], f: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Total thrust and body FLU torques of rotors at ``positions`` pushing ``f`` up; a rotor
    turning counter-clockwise seen from above twists the body clockwise (negative about z up)."""
    k = 0.02  # yaw torque per unit of thrust
    tx = sum(y * fi for (x, y), fi in zip(positions_flu, f, strict=True))
    ty = sum(-x * fi for (x, y), fi in zip(positions_flu, f, strict=True))
    tz = sum((-k if c else k) * fi for c, fi in zip(ccw, f, strict=True))
    return sum(f), tx, ty, tz


D = 0.25
A = D / math.sqrt(2.0)
#: our plus: 1 right CW, 2 front CCW, 3 left CW, 4 rear CCW (docs/external-simulators.md).
PLUS = [(0.0, -D), (D, 0.0), (0.0, D), (-D, 0.0)]
PLUS_CCW = [False, True, False, True]
#: PX4's quadrotor X: 1 front right CCW, 2 rear left CCW, 3 front left CW, 4 rear right CW.
QUAD_X = [(A, -A), (-A, A), (A, A), (-A, -A)]
QUAD_X_CCW = [True, True, False, False]


@pytest.mark.parametrize("f", [(1.0, 1.0, 1.0, 1.0), (1.2, 0.9, 0.8, 1.1), (0.5, 1.5, 1.0, 0.7), (2.0, 0.0, 0.3, 1.0)])
def test_plus_to_quad_x_keeps_the_wrench(f: tuple[float, float, float, float]) -> None:
    want = _wrench(PLUS, PLUS_CCW, f)
    got = _wrench(QUAD_X, QUAD_X_CCW, plus_to_quad_x(f))
    assert got == pytest.approx(want, abs=1e-12)


def test_controls_normalisation_and_order() -> None:
    mp = mixer_params(DEFAULT_VEHICLE)
    w_max = DEFAULT_VEHICLE.rotor_speed_max_radps
    # level hover: the same speed on every rotor in any order; "speed" is omega / omega_max
    c_hover = (DEFAULT_VEHICLE.hover_omega_sq - mp.lo) / mp.span
    hover = (c_hover,) * 4
    for frame in ("quad-x", "plus"):
        speed, clipped = px4_controls(hover, mp, Px4Output(frame, "speed"))
        assert not clipped
        assert speed == pytest.approx((math.sqrt(DEFAULT_VEHICLE.hover_omega_sq) / w_max,) * 4, rel=1e-12)
        thrust, _ = px4_controls(hover, mp, Px4Output(frame, "thrust"))
        assert thrust == pytest.approx(hover, rel=1e-12)
    # plus, thrust: our commands unchanged (what smcpilot sim --serve px4 reads)
    cmd = (0.3, 0.6, 0.5, 0.4)
    assert px4_controls(cmd, mp, Px4Output("plus", "thrust"))[0] == pytest.approx(cmd, rel=1e-12)
    # roll right (left rotor 3 up, right rotor 1 down) on the X: the left rotors (2 rear left, 3 front left) up
    x, _ = px4_controls((0.4, 0.5, 0.6, 0.5), mp, Px4Output("quad-x", "thrust"))
    assert x[1] > 0.5 and x[2] > 0.5 and x[0] < 0.5 and x[3] < 0.5
    # a wrench the X cannot give within its range: clipped, said
    _, clipped = px4_controls((0.0, 1.0, 1.0, 0.0), mp, Px4Output("quad-x", "speed"))
    assert clipped


def test_hil_state_to_wire() -> None:
    roll, pitch, yaw = 0.1, -0.2, 2.5
    q = quat_from_euler(roll, pitch, yaw)  # ZYX Euler of the FRD body in NED
    lat, lon, alt = ned_to_global(HOME, 3.0, -4.0, -5.0)
    st = wire_of_hil_state(q, (0.01, 0.02, 0.03), round(lat * 1e7), round(lon * 1e7), round(alt * 1000), (120, -50, -30), HOME)
    assert st.problems == 0
    w = st.wire
    assert w[:6] == pytest.approx((roll, pitch, yaw, 0.01, 0.02, 0.03), abs=1e-9)
    assert w[6:9] == pytest.approx((3.0, -4.0, -5.0), abs=0.012)  # 1e-7 deg is about a centimetre
    assert w[9:] == pytest.approx((1.2, -0.5, -0.3), abs=1e-12)
    nan = wire_of_hil_state((math.nan, 0, 0, 0), (0.0, math.inf, 0.0), 0, 0, 0, (0, 0, 0), Home(0.0, 0.0, 0.0))
    assert nan.problems == STATE_NONFINITE and all(v != v for v in nan.wire[:3]) and nan.wire[4] != nan.wire[4]
    empty = wire_of_hil_state((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 0, 0, (0, 0, 0), Home(0.0, 0.0, 0.0))
    assert empty.problems == STATE_NO_ATTITUDE and all(v != v for v in empty.wire[:3])


# -- a protocol-level simulator ------------------------------------------------------------------
class FakePx4Sim:
    """PX4's simulator side of the API: listens on TCP, sends HIL_STATE_QUATERNION, reads the answers."""

    def __init__(self, port: int = 0) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", port))
        self.listener.listen(1)
        self.port = self.listener.getsockname()[1]
        self.conn: socket.socket | None = None
        self.sink = PacketSink()
        self.mav = mavlink.MAVLink(self.sink, srcSystem=1, srcComponent=200)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[mavlink.MAVLink_message] = []

    def accept(self, timeout_s: float = WALL_S) -> None:
        self.listener.settimeout(timeout_s)
        self.conn, _ = self.listener.accept()
        self.conn.settimeout(timeout_s)

    def send(self, data: bytes) -> None:
        assert self.conn is not None
        self.conn.sendall(data)

    def state(self, t_us: int, *, q: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0), rates: tuple[float, ...] = (0.0, 0.0, 0.0),
              ned: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> bytes:  # fmt: skip
        lat, lon, alt = ned_to_global(HOME, *ned)
        self.mav.send(self.mav.hil_state_quaternion_encode(
            t_us, list(q), *rates, round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0, 0, 0, 0, 0, 0, 0, -1000,
        ))  # fmt: skip
        return self.sink.take()

    def sensor(self, t_us: int, fields: int = 0x3F, accel_z: float = -9.81) -> bytes:
        self.mav.send(self.mav.hil_sensor_encode(t_us, 0, 0, accel_z, 0, 0, 0, 0.2, 0, 0.4, 1013.0, 0, 0, 15, fields, 0))
        return self.sink.take()

    def gps(self, t_us: int, fix: int = 3) -> bytes:
        self.mav.send(self.mav.hil_gps_encode(t_us, fix, 473977420, 85455940, 488000, 30, 40, 0, 0, 0, 0, 65535, 10))
        return self.sink.take()

    def messages(self, timeout_s: float) -> list[mavlink.MAVLink_message]:
        """What arrives within ``timeout_s`` (stops early once something came and the line is quiet)."""
        assert self.conn is not None
        out: list[mavlink.MAVLink_message] = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.conn], [], [], max(0.0, min(0.05, deadline - time.monotonic())))
            if not ready:
                if out:
                    break
                continue
            data = self.conn.recv(65536)
            if not data:
                break
            out.extend(m for m in self.parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")
        self.received.extend(out)
        return out

    def answer(self, timeout_s: float = 10.0) -> mavlink.MAVLink_message:
        """The next HIL_ACTUATOR_CONTROLS."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for m in self.messages(min(1.0, deadline - time.monotonic())):
                if m.get_type() == "HIL_ACTUATOR_CONTROLS":
                    return m
        raise AssertionError("no HIL_ACTUATOR_CONTROLS")

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.listener.close()


def _fc(tmp_path: Path, port: int, *extra: str) -> FcProcess:
    return FcProcess(["--sim", f"px4:tcp:127.0.0.1:{port}", "--rate-hz", "250", "--gcs", "none", "--tlog", str(tmp_path / "fc.tlog"),
                      *extra], tmp_path)  # fmt: skip


@pytest.fixture
def sim() -> FakePx4Sim:
    s = FakePx4Sim()
    yield s
    s.close()


def test_lockstep_answers_heartbeat_and_bad_input(tmp_path: Path, sim: FakePx4Sim) -> None:
    plan = write_plan(tmp_path / "plan.toml", [{"t_s": 0.02, "action": "takeoff", "alt_m": 2.0}])
    fc = _fc(tmp_path, sim.port, "--plan", str(plan), "--watchdog-s", "2")
    try:
        assert fc.listening()["sim"] == f"px4:tcp:127.0.0.1:{sim.port}"
        sim.accept()
        first = sim.messages(5.0)
        assert first and first[0].get_type() == "HEARTBEAT"  # rotorpy waits for it before anything
        # every state is answered once, stamped with its time_usec, the lockstep flag set
        t = 0
        for _ in range(10):
            sim.send(sim.state(t) + sim.sensor(t) + (sim.gps(t) if t % 100_000 == 0 else b""))
            a = sim.answer()
            assert a.time_usec == t and a.flags & 1
            t += PERIOD_US
        assert a.mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED  # the plan's take-off at 0.02 s armed it
        assert all(0.0 < c <= 1.0 for c in a.controls[:4]) and not any(a.controls[4:])
        # bad input: none of it is answered (no tick), all counted
        last = t - PERIOD_US
        sim.send(b"\x00\x01garbage\x02")
        sim.send(sim.state(last))  # duplicate
        sim.send(sim.state(last - PERIOD_US))  # out of order
        sim.send(sim.state(last + 3 * PERIOD_US))  # wrong step
        sim.send(sim.sensor(last, fields=0))  # a HIL_SENSOR that updates nothing
        sim.send(sim.gps(last, fix=0))
        assert not [m for m in sim.messages(0.5) if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
        # a NaN attitude is flown as "not measured": answered (lockstep goes on), the failsafe flies
        sim.send(sim.state(t, q=(math.nan, 0.0, 0.0, 0.0)))
        assert sim.answer().time_usec == t
        t += PERIOD_US
        sim.send(sim.state(t, q=(0.0, 0.0, 0.0, 0.0)))  # a message that lacks its quaternion
        assert sim.answer().time_usec == t
        # the simulator goes silent: the FC's watchdog ends it (exit 3)
        rc = fc.wait(timeout_s=WALL_S)
    finally:
        fc.kill()
    out = "\n".join(fc.all_lines)
    assert rc == 3, out
    assert "has sent no state for" in out
    s = fc.summary()
    assert s["duplicate_states"] == 1 and s["out_of_order_states"] == 1 and s["wrong_step_states"] == 1
    px4 = s["px4"]
    assert px4["bad"] == {"mavlink": 1, "duplicate": 1, "out_of_order": 1, "wrong_step": 1, "sensor_empty": 1, "gps_no_fix": 1,
                          "nonfinite": 1, "no_attitude": 1}  # fmt: skip
    assert px4["states"] == 12 and px4["hil_sensors"] == 11 and px4["hil_gps"] == 2
    assert s["ticks"] == 12 and s["failsafe_events"] >= 1
    # one message per kind the first time (rate-limited after that)
    assert sum("fc px4: dropped" in ln for ln in fc.all_lines) == 8
    assert "state lost" in out.lower() or "failsafe" in out.lower()


def test_waits_for_the_simulator_then_connects(tmp_path: Path) -> None:
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nobody listens there yet
    fc = _fc(tmp_path, port, "--duration", "0.02")
    try:
        fc.await_line("fc px4: waiting for the simulator", timeout_s=WALL_S)
        sim = FakePx4Sim(port)
        try:
            sim.accept()
            for k in range(6):
                sim.send(sim.state(k * PERIOD_US))
                sim.answer()
            rc = fc.wait(timeout_s=WALL_S)
        finally:
            sim.close()
    finally:
        fc.kill()
    assert rc == 0, fc.all_lines
    assert fc.summary()["px4"]["connect_attempts"] >= 2


def test_no_simulator_is_a_clear_error(tmp_path: Path) -> None:
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    fc = _fc(tmp_path, port, "--startup-timeout-s", "1")
    try:
        rc = fc.wait(timeout_s=WALL_S)
    finally:
        fc.kill()
    assert rc == 3
    assert any(f"no simulator accepted a connection at tcp:127.0.0.1:{port} within 1 s" in ln for ln in fc.all_lines)


def test_a_simulator_at_another_rate_is_named(tmp_path: Path, sim: FakePx4Sim) -> None:
    fc = _fc(tmp_path, sim.port)
    try:
        sim.accept()
        sim.send(sim.state(0))
        sim.answer()
        sim.send(sim.state(2000))  # 500 Hz against the FC's 250
        rc = fc.wait(timeout_s=WALL_S)
    finally:
        fc.kill()
    assert rc == 2
    assert any("--rate-hz 500" in ln for ln in fc.all_lines), fc.all_lines


def test_a_closed_connection_before_the_duration_fails(tmp_path: Path, sim: FakePx4Sim) -> None:
    fc = _fc(tmp_path, sim.port, "--duration", "10")
    try:
        sim.accept()
        sim.send(sim.state(0))
        sim.answer()
        sim.close()
        rc = fc.wait(timeout_s=WALL_S)
    finally:
        fc.kill()
    assert rc == 3
    assert any("closed the connection at t = 0.000 s, before --duration 10" in ln for ln in fc.all_lines)


def test_bad_command_line_is_one_line_exit_2(tmp_path: Path) -> None:
    for args, text in ((["--sim", "px4:tcp:"], "--sim: expected px4"),
                       (["--sim", "px4", "--px4-frame", "hexa"], "invalid choice")):  # fmt: skip
        r = subprocess.run([sys.executable, "-m", "fc", *args, "--gcs", "none", "--log-dir", str(tmp_path)],
                           capture_output=True, text=True, timeout=WALL_S, cwd=tmp_path)  # fmt: skip
        assert r.returncode == 2, r
        assert text in r.stderr.strip().splitlines()[-1]  # the error is one line (argparse's usage above it)


# -- two real processes: our simulator serving PX4's API, the FC as the autopilot ----------------------
def test_flies_on_smcpilot_sim_serve_px4(tmp_path: Path) -> None:
    """Take-off, a set-point 2 m north, landing: the FC as PX4 on our plant through PX4's API."""
    duration = 36.0
    sim = subprocess.Popen([sys.executable, "-m", "lab.cli", "sim", "--serve", "px4:0", "--duration", f"{duration:g}"],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        assert sim.stdout is not None
        ready = sim.stdout.readline()
        assert ready.startswith("SIM_READY"), ready
        port = int(ready.split("tcp=")[1].split()[0].rsplit(":", 1)[1])
        plan = write_plan(tmp_path / "plan.toml", [{"t_s": 0.0, "action": "takeoff", "alt_m": 3.0},
                                                   {"t_s": 10.0, "action": "goto", "north_m": 2.0, "east_m": 0.0, "alt_m": 3.0},
                                                   {"t_s": 24.0, "action": "land"}])  # fmt: skip
        fc = _fc(tmp_path, port, "--px4-frame", "plus", "--px4-motor", "thrust", "--plan", str(plan), "--duration", f"{duration:g}")
        try:
            rc = fc.wait(timeout_s=120.0)
        finally:
            fc.kill()
        sim_out, _ = sim.communicate(timeout=WALL_S)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
    assert rc == 0, fc.all_lines
    assert sim.returncode == 0, sim_out
    s = fc.summary()
    assert s["ticks"] == round(duration * 250) + 1 and s["px4"]["bad"] == {} and s["px4"]["clipped_ticks"] == 0
    f = load_flight(tmp_path / "fc.tlog")  # the FC's log reads as with our simulator
    at = lambda t: int(abs(f.t - t).argmin())  # noqa: E731
    i = at(9.5)
    assert f.alt[i] == pytest.approx(3.0, abs=0.05) and abs(f.north[i]) < 0.05
    i = at(23.5)
    assert f.north[i] == pytest.approx(2.0, abs=0.05) and f.alt[i] == pytest.approx(3.0, abs=0.05)
    assert f.alt[-1] < 0.05 and not f.armed[-1]
    assert [text for _, text in f.events][-1].startswith("Landed")
    # the served flight's log, scored against our FC's own set-points, gives the FC's own log's score
    (served,) = (tmp_path / "logs").glob("serve-px4-*.tlog")
    ours = summarize(load_log(tmp_path / "fc.tlog"))["metrics"]  # on the state the FC got: HIL_STATE_QUATERNION
    theirs = summarize(load_log(served), setpoints=load_setpoints(tmp_path / "fc.tlog"))["truth_metrics"]
    assert theirs["scored_against"].startswith("our flight controller's set-points in fc.tlog")
    for key in ("samples", "flight_time_s", "armed_time_s", "effort_u2_s", "motor_tv", "max_pos_err_m", "crashed"):
        assert theirs[key] == pytest.approx(ours[key], rel=1e-12), key  # the same ticks, commands, set-points
    for key in ("iae_att_rad_s", "ise_att_rad2_s", "max_tilt_deg"):
        assert theirs[key] == pytest.approx(ours[key], rel=1e-6), key  # the same float32 quaternion, converted apart
    # HIL_STATE_QUATERNION rounds the position to 1e-7 deg of latitude and longitude and to 1 mm: at most
    # half of that off (a degree of latitude is at most 111.7 km), |e_p| differs by at most 0.79 cm, the IAE by that over the flight time
    lsb_m = math.sqrt(2 * (0.5e-7 * 111_700.0) ** 2 + 0.0005**2)
    assert abs(theirs["iae_pos_m_s"] - ours["iae_pos_m_s"]) <= lsb_m * ours["flight_time_s"]


def test_smcpilot_sitl_flies_on_another_simulator(tmp_path: Path) -> None:
    """``smcpilot sitl --sim px4:...`` starts the FC only; here our simulator serves PX4's API in its place."""
    sim = subprocess.Popen([sys.executable, "-m", "lab.cli", "sim", "--serve", "px4:0", "--rate-hz", "500", "--duration", "6"],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        assert sim.stdout is not None
        ready = sim.stdout.readline()
        port = int(ready.split("tcp=")[1].split()[0].rsplit(":", 1)[1])
        r = subprocess.run([sys.executable, "-m", "lab.cli", "sitl", "--sim", f"px4:tcp:127.0.0.1:{port}", "--px4-frame", "plus",
                            "--px4-motor", "thrust", "--duration", "6", "--gcs", "none", "--plan", str(ROOT / "examples/plans/hover.toml"),
                            "--log-dir", str(tmp_path / "logs"), "--no-progress"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=120)  # fmt: skip
        sim_out, _ = sim.communicate(timeout=WALL_S)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
    assert r.returncode == 0, r.stdout + r.stderr + "\n[the served simulator]\n" + (sim_out or "")
    assert "SITL ended: 6.00 simulated s" in r.stdout and "3001 control ticks" in r.stdout, r.stdout
    assert sim.returncode == 0, sim_out
    bad = subprocess.run([sys.executable, "-m", "lab.cli", "sitl", "--px4-frame", "plus"], capture_output=True, text=True, timeout=WALL_S)
    assert bad.returncode == 2 and "go with --sim px4" in bad.stderr


def test_a_simulator_that_closes_with_the_last_state_ends_cleanly(tmp_path: Path, sim: FakePx4Sim) -> None:
    """A simulator that flies the same duration may close (here: reset) the connection with its last
    state, before it reads the answer: the FC flew its duration, so that is the clean end (exit 0),
    not a broken connection (seen in CI with `smcpilot sim --serve px4` under load)."""
    n = 5
    fc = _fc(tmp_path, sim.port, "--duration", f"{n * PERIOD_US * 1e-6:g}")
    try:
        sim.accept()
        for k in range(n):
            sim.send(sim.state(k * PERIOD_US))
            sim.answer()
        assert sim.conn is not None
        sim.conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close = reset
        sim.send(sim.state(n * PERIOD_US))
        sim.conn.close()
        sim.conn = None
        rc = fc.wait(timeout_s=WALL_S)
    finally:
        fc.kill()
    assert rc == 0, fc.all_lines
    assert fc.summary()["ticks"] == n + 1
