"""Our simulator as another autopilot's physics back-end (``smcpilot sim --serve``), driven over real
sockets on 127.0.0.1 by protocol-level clients written from the published specifications:

- ArduPilot's JSON interface (``libraries/SITL/SIM_JSON.cpp``, ``libraries/SITL/examples/JSON/readme.md``):
  servo packets ``<HHI16H`` (magic 18458) or ``<HHI32H`` (magic 29569) by UDP, the state in JSON;
- PX4's simulator MAVLink API: the simulator listens on TCP, sends HIL_SENSOR, HIL_GPS and
  HIL_STATE_QUATERNION, takes HIL_ACTUATOR_CONTROLS, lockstep.

Oracles: known physics (at rest the accelerometer reads -g along body z in FRD, full throttle
climbs, stopped rotors fall), smcpilot.frames, and ArduCopter's PLUSREV motor geometry (motor 1
right CW, 2 left CW, 3 front CCW, 4 rear CCW).
"""

from __future__ import annotations

import io
import json
import math
import signal
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.sensors import specific_force_frd
from sim_bridge.serve import ServeOptions, ServerBase
from sim_bridge.serve_ardupilot import ROTOR_CHANNELS, ArduPilotJsonServer
from sim_bridge.serve_px4 import ACCEL_BITS, BARO_BITS, GYRO_BITS, MAG_BITS, Px4Server
from smcpilot.actuators import hover_command
from smcpilot.faults import FaultSpec
from smcpilot.frames import quat_from_euler
from smcpilot.geo import Home
from smcpilot.scenario import Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE

ROOT = Path(__file__).resolve().parents[1]
G = DEFAULT_VEHICLE.gravity_mps2
HOVER = hover_command(DEFAULT_VEHICLE)
QUIET_S = 0.3  # how long "no answer" is waited for (a socket wait with this timeout)


class Running:
    """A server serving in a thread; ``stop()`` ends it and gives its exit code and output."""

    def __init__(self, server: ServerBase, out: io.StringIO) -> None:
        self.server = server
        self.out = out
        self.code: int | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.code = self.server.run()

    def join(self, timeout: float = 10.0) -> int:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "the server did not stop"
        assert self.code is not None
        return self.code

    def stop(self) -> int:
        self.server.request_stop()
        return self.join()

    def lines(self) -> list[str]:
        return self.out.getvalue().splitlines()

    def summary(self) -> dict[str, Any]:
        (line,) = [ln for ln in self.lines() if ln.startswith("SIM_SUMMARY ")]
        return json.loads(line.split(" ", 1)[1])


def _serve(kind: str, scenario: Scenario | None = None, **opts: Any) -> Running:
    out = io.StringIO()
    options = ServeOptions(kind=kind, port=0, **opts)
    cls = ArduPilotJsonServer if kind == "ardupilot-json" else Px4Server
    return Running(cls(scenario or Scenario(), options, out=out), out)


def _motor_fault(motor: int, efficiency: float) -> Scenario:
    return Scenario(faults=(FaultSpec(kind="motor", start_s=0.0, motor=motor, efficiency=efficiency),))


# == ArduPilot JSON =================================================================================
class ArduPilotClient:
    """What ArduPilot SITL's JSON back-end does on the wire: a servo packet, then wait for the state."""

    def __init__(self, address: tuple[str, int]) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.frame = 0

    def packet(self, pwm: Sequence[int], *, frame: int, rate: int = 1000, channels: int = 16) -> bytes:
        magic = 18458 if channels == 16 else 29569
        values = list(pwm) + [0] * (channels - len(pwm))
        return struct.pack(f"<HHI{channels}H", magic, rate, frame, *values)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.address)

    def reply(self, timeout: float = 5.0) -> bytes | None:
        self.sock.settimeout(timeout)
        try:
            data, _ = self.sock.recvfrom(65536)
        except TimeoutError:
            return None
        return data

    def step(self, pwm: Sequence[int], *, frame: int | None = None, **kw: Any) -> dict[str, Any]:
        """Send one frame (the next one unless given) and parse its one answer."""
        if frame is None:
            frame = self.frame
            self.frame += 1
        self.send_raw(self.packet(pwm, frame=frame, **kw))
        data = self.reply()
        assert data is not None, f"no answer to frame {frame}"
        return json.loads(data)

    def fly(self, pwm: Sequence[int], frames: int, **kw: Any) -> dict[str, Any]:
        state: dict[str, Any] = {}
        for _ in range(frames):
            state = self.step(pwm, **kw)
        return state

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def ardupilot() -> Iterator[tuple[Running, ArduPilotClient]]:
    run = _serve("ardupilot-json")
    client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
    yield run, client
    client.close()
    run.stop()


def _pwm(c: float) -> int:
    return int(round(1000 + 1000 * c))


def test_the_json_state_at_rest_is_what_ardupilot_parses(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    run, client = ardupilot
    client.send_raw(client.packet([1000] * 4, frame=0, rate=400))
    raw = client.reply()
    assert raw is not None
    text = raw.decode("ascii")
    assert text.startswith("\n{") and text.endswith("}\n") and text.count("\n") == 2  # between two newlines
    assert ": " not in text and ", " not in text and "nan" not in text.lower()  # compact, finite: SIM_JSON's parser
    state = json.loads(text)
    assert state["timestamp"] == pytest.approx(1 / 400)
    assert state["imu"]["accel_body"] == pytest.approx([0.0, 0.0, -G], abs=1e-9)  # specific force, body FRD, at rest
    assert state["imu"]["gyro"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)
    assert state["position"] == pytest.approx([0.0, 0.0, 0.0]) and state["velocity"] == pytest.approx([0.0, 0.0, 0.0])
    assert state["quaternion"] == pytest.approx([1.0, 0.0, 0.0, 0.0])
    assert any("ArduPilot connected" in ln for ln in run.lines())


def test_lockstep_one_answer_per_new_frame_and_a_resent_frame_does_not_step(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    run, client = ardupilot
    stamps = [client.step([_pwm(HOVER + 0.05)] * 4)["timestamp"] for _ in range(10)]
    assert stamps == pytest.approx([0.001 * (k + 1) for k in range(10)])
    assert client.reply(QUIET_S) is None  # one answer per frame, no more
    client.send_raw(client.packet([_pwm(HOVER + 0.05)] * 4, frame=9))  # ArduPilot re-sends a frame it got no answer to
    again = client.reply()
    assert again is not None and json.loads(again)["timestamp"] == pytest.approx(0.010)  # the same state: no step
    assert client.reply(QUIET_S) is None
    assert client.step([_pwm(HOVER + 0.05)] * 4)["timestamp"] == pytest.approx(0.011)
    client.send_raw(client.packet([1000] * 4, frame=15))  # frames 11..14 lost
    assert json.loads(client.reply() or b"{}")["timestamp"] == pytest.approx(0.012)  # one step per frame received
    assert run.stop() == 0
    s = run.summary()
    assert (s["frames"], s["resent_frames"], s["missed_frames"]) == (12, 1, 4)


def test_the_32_channel_magic_flies_the_same(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    _, client = ardupilot
    s16 = client.fly([2000] * 4, 200)
    run32 = _serve("ardupilot-json")
    try:
        c32 = ArduPilotClient(run32.server.address)  # type: ignore[attr-defined]
        s32 = c32.fly([2000] * 4 + [1500] * 20, 200, channels=32)
        c32.close()
    finally:
        run32.stop()
    assert s32 == s16 and s32["position"][2] < -0.1


def test_full_throttle_climbs_and_stopped_rotors_fall(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    _, client = ardupilot
    up = client.fly([2000] * 4, 500)  # 0.5 s at full thrust
    assert up["position"][2] < -0.5 and up["velocity"][2] < -2.0  # NED: up is negative
    assert up["imu"]["accel_body"][2] < -G  # more than 1 g of thrust along body -z (FRD)
    down = client.fly([1000] * 4, 600)  # every motor at MOT_PWM_MIN: the rotors stop
    assert down["velocity"][2] > 0.5  # falling
    rest = _serve("ardupilot-json")
    try:
        c = ArduPilotClient(rest.server.address)  # type: ignore[attr-defined]
        still = c.fly([1000] * 4, 300)
        c.close()
    finally:
        rest.stop()
    assert still["position"] == pytest.approx([0.0, 0.0, 0.0]) and still["imu"]["accel_body"][2] == pytest.approx(-G)


#: ArduCopter PLUSREV: motor (channel) -> the body rate (FRD) that more thrust on it gives, and its sign.
MOTOR_RESPONSE = [
    ((0,), 0, -1.0),  # motor 1, right: rolls left
    ((1,), 0, +1.0),  # motor 2, left: rolls right
    ((2,), 1, +1.0),  # motor 3, front: nose up
    ((3,), 1, -1.0),  # motor 4, rear: nose down
    ((0, 1), 2, -1.0),  # motors 1 and 2 spin clockwise: their drag yaws the body counter-clockwise (negative in NED)
    ((2, 3), 2, +1.0),  # motors 3 and 4 spin counter-clockwise: yaw clockwise
]


@pytest.mark.parametrize(("channels", "axis", "sign"), MOTOR_RESPONSE, ids=["m1-right", "m2-left", "m3-front", "m4-rear", "m12-cw", "m34-ccw"])
def test_the_motor_order_is_arducopters_plusrev(channels: tuple[int, ...], axis: int, sign: float) -> None:
    run = _serve("ardupilot-json")
    try:
        client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
        client.fly([_pwm(HOVER + 0.1)] * 4, 150)  # off the ground
        pwm = [_pwm(HOVER + 0.1)] * 4
        for ch in channels:
            pwm[ch] += 60
        gyro = client.fly(pwm, 40)["imu"]["gyro"]
        client.close()
    finally:
        run.stop()
    assert sign * gyro[axis] > 0.005, gyro  # (yaw authority is small: drag torque)
    others = [abs(gyro[k]) for k in range(3) if k != axis]
    assert max(others) < 0.2 * abs(gyro[axis]), gyro
    assert ROTOR_CHANNELS == (0, 2, 1, 3)


def test_a_motor_fault_of_the_scenario_acts_as_in_our_simulator() -> None:
    gyros = []
    for scenario in (Scenario(), _motor_fault(1, 0.5)):
        run = _serve("ardupilot-json", scenario)
        try:
            client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
            gyros.append(client.fly([_pwm(HOVER + 0.1)] * 4, 200)["imu"]["gyro"])
            client.close()
        finally:
            run.stop()
        if scenario.faults:
            assert any("SIM: motor 1 at 50%" in ln for ln in run.lines()), run.lines()
            assert run.summary()["faults_started"] == 1
    healthy, faulty = gyros
    assert max(abs(v) for v in healthy) < 1e-6
    assert faulty[0] > 0.1  # our rotor 1 (right, ArduCopter motor 1) weak: the right side drops, roll right (FRD p > 0)


def test_a_restarted_ardupilot_gets_a_fresh_vehicle(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    run, client = ardupilot
    assert client.fly([2000] * 4, 300)["position"][2] < -0.1
    client.frame = 0  # ArduPilot restarted: its counter starts again
    state = client.step([1000] * 4)
    assert state["timestamp"] == pytest.approx(0.001) and state["position"] == pytest.approx([0.0, 0.0, 0.0])
    assert any("ArduPilot restarted" in ln for ln in run.lines())
    run.stop()
    assert run.summary()["restarts"] == 1


def test_bad_servo_packets_are_counted_and_dropped_with_one_message_each(ardupilot: tuple[Running, ArduPilotClient]) -> None:
    run, client = ardupilot
    good = client.packet([1000] * 4, frame=0)
    bad = {
        "magic": struct.pack("<HHI16H", 12345, 1000, 0, *([1000] * 16)),
        "short": good[:20],
        "pwm": client.packet([1000, 2600, 1000, 1000], frame=0),
        "frame_rate": client.packet([1000] * 4, frame=0, rate=0),
    }
    for data in bad.values():
        for _ in range(5):
            client.send_raw(data)
    client.send_raw(client.packet([1000] * 4, frame=0, channels=32)[:30])  # 32-channel magic, 16-channel length
    assert client.reply(QUIET_S) is None  # none answered
    assert client.step([1000] * 4)["timestamp"] == pytest.approx(0.001)  # the server is alive, nothing was stepped
    run.stop()
    assert run.summary()["bad_input"] == {"magic": 5, "short": 6, "pwm": 5, "frame_rate": 5}
    said = [ln for ln in run.lines() if "dropped" in ln]
    assert len(said) == 4, said  # one message per kind: the rest counted within the rate limit
    assert any("unknown magic 12345" in ln for ln in said) and any("PWM 2600 us on channel 2" in ln for ln in said)
    assert any("20 bytes" in ln for ln in said) and any("frame rate of 0" in ln for ln in said)


def test_an_ardupilot_that_stops_ends_the_server_with_a_clear_message() -> None:
    run = _serve("ardupilot-json", watchdog_s=0.3)
    client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
    client.fly([1000] * 4, 3)
    client.close()
    assert run.join(5.0) == 3
    assert any("no servo packet from ArduPilot for" in ln and "watchdog 0.3 s" in ln for ln in run.lines()), run.lines()
    assert run.summary()["frames"] == 3


def test_smcpilot_sim_serves_until_sigint_and_prints_a_summary(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "lab.cli", "sim", "--serve", "ardupilot-json:0", "--no-tlog"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline()
        assert ready.startswith("SIM_READY serve=ardupilot-json udp=127.0.0.1:"), ready
        assert "FRAME_CLASS 1, FRAME_TYPE 6" in ready
        port = int(ready.split("udp=127.0.0.1:")[1].split()[0])
        client = ArduPilotClient(("127.0.0.1", port))
        assert client.fly([1000] * 4, 5)["timestamp"] == pytest.approx(0.005)
        client.close()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1].split(" ", 1)[1])
    assert summary["frames"] == 5 and summary["serve"] == "ardupilot-json" and err == ""


# == PX4 ===========================================================================================
class Px4Client:
    """What PX4 SITL's simulator_mavlink does on the wire: connect, read sensors, answer with actuators."""

    def __init__(self, address: tuple[str, int]) -> None:
        self.sock = socket.create_connection(address, timeout=5.0)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.parts: list[bytes] = []
        self.tx = mavlink.MAVLink(self, srcSystem=1, srcComponent=1)
        self.pending: list[Any] = []

    def write(self, data: bytes) -> None:  # pymavlink's file
        self.parts.append(bytes(data))

    def recv(self, kind: str, timeout: float = 5.0) -> Any | None:
        """The next message of this type (None if none came within ``timeout``)."""
        self.sock.settimeout(timeout)
        while True:
            while self.pending:
                m = self.pending.pop(0)
                if m.get_type() == kind:
                    return m
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                return None
            if not data:
                return None
            self.pending.extend(self.rx.parse_buffer(data) or ())

    def actuators(self, controls: Sequence[float], *, armed: bool = True, flags: int = 1) -> None:
        self.tx.send(self.tx.hil_actuator_controls_encode(0, [*controls, *([0.0] * (16 - len(controls)))], 128 if armed else 0, flags))
        self.sock.sendall(b"".join(self.parts))
        self.parts.clear()

    def fly(self, controls: Sequence[float], steps: int) -> tuple[Any, Any]:
        """Answer ``steps`` sensor messages; the last HIL_SENSOR and HIL_STATE_QUATERNION."""
        sensor = state = None
        for _ in range(steps):
            self.actuators(controls)
            sensor = self.recv("HIL_SENSOR")
            state = self.recv("HIL_STATE_QUATERNION")
            assert sensor is not None and state is not None
        return sensor, state

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def px4() -> Iterator[tuple[Running, Px4Client]]:
    run = _serve("px4", watchdog_s=5.0)
    client = Px4Client(run.server.address)  # type: ignore[attr-defined]
    yield run, client
    client.close()
    run.stop()


def test_px4_gets_its_sensors_at_rest(px4: tuple[Running, Px4Client]) -> None:
    _, client = px4
    sensor = client.recv("HIL_SENSOR")
    state = client.recv("HIL_STATE_QUATERNION")
    gps = client.recv("HIL_GPS")
    assert sensor is not None and state is not None and gps is not None
    assert sensor.id == 0 and sensor.fields_updated == ACCEL_BITS | GYRO_BITS | MAG_BITS | BARO_BITS
    assert (sensor.xacc, sensor.yacc, sensor.zacc) == pytest.approx((0.0, 0.0, -G), abs=1e-5)  # specific force, FRD
    assert (sensor.xgyro, sensor.ygyro, sensor.zgyro) == pytest.approx((0.0, 0.0, 0.0))
    assert sensor.pressure_alt == pytest.approx(Home().alt_m) and 900.0 < sensor.abs_pressure < 1013.25
    assert state.attitude_quaternion == pytest.approx([1.0, 0.0, 0.0, 0.0]) and state.zacc == -1000  # -1 g in mG
    assert (gps.fix_type, gps.lat, gps.lon) == (3, round(Home().lat_deg * 1e7), round(Home().lon_deg * 1e7))


def test_px4_lockstep_physics_advances_only_on_actuator_messages(px4: tuple[Running, Px4Client]) -> None:
    run, client = px4
    first = client.recv("HIL_SENSOR")
    assert first is not None and first.time_usec == 0
    client.actuators([0.0] * 4, armed=False)  # PX4's first answer: lockstep from here
    # before it, time ran at real time (PX4 boots on it): drain to the sensor message that answers it
    t = None
    while True:
        m = client.recv("HIL_SENSOR", QUIET_S)
        if m is None:
            break
        t = m.time_usec
    assert t is not None and run.server.lockstep  # type: ignore[attr-defined]
    for k in range(1, 6):
        client.actuators([HOVER] * 4)
        m = client.recv("HIL_SENSOR")
        assert m is not None and m.time_usec == t + 4000 * k  # one period (250 Hz) per answer
        assert client.recv("HIL_SENSOR", 0.05) is None  # and one message
    assert client.recv("HIL_SENSOR", QUIET_S) is None  # silence: nothing advances
    assert run.server.plant.t_s == pytest.approx((t + 5 * 4000) * 1e-6)  # type: ignore[attr-defined]


def test_px4_full_throttle_climbs_and_zero_falls(px4: tuple[Running, Px4Client]) -> None:
    _, client = px4
    sensor, state = client.fly([1.0] * 4, 125)  # 0.5 s
    assert state.vz < -200 and state.alt > Home().alt_m * 1000 + 500  # up, cm/s NED and mm AMSL
    assert sensor.zacc < -G and sensor.pressure_alt > Home().alt_m + 0.5
    _, state = client.fly([0.0] * 4, 150)  # armed at zero: idle thrust, far below weight
    assert state.vz > 50


def test_px4_motor_order_is_ours_and_a_scenario_fault_acts() -> None:
    rates = []
    for scenario, controls in ((Scenario(), [HOVER + 0.1] * 4), (Scenario(), [HOVER + 0.1, HOVER + 0.2, HOVER + 0.1, HOVER + 0.1]),
                               (_motor_fault(1, 0.5), [HOVER + 0.1] * 4)):  # fmt: skip
        run = _serve("px4", scenario)
        try:
            client = Px4Client(run.server.address)  # type: ignore[attr-defined]
            client.fly([HOVER + 0.1] * 4, 40)
            sensor, _ = client.fly(controls, 15)
            rates.append((sensor.xgyro, sensor.ygyro, sensor.zgyro))
            client.close()
        finally:
            run.stop()
    healthy, front_up, fault = rates
    assert max(abs(v) for v in healthy) < 1e-6
    assert front_up[1] > 0.05  # controls[1] is our rotor 2, front: nose up (FRD q > 0)
    assert fault[0] > 0.05  # controls[0]'s rotor 1 (right) at 50 %: roll right


def test_px4_bad_input_is_counted_and_dropped_with_one_message_each(px4: tuple[Running, Px4Client]) -> None:
    run, client = px4
    assert client.recv("HIL_SENSOR") is not None
    client.actuators([0.0] * 4, armed=False)
    while client.recv("HIL_SENSOR", QUIET_S) is not None:
        pass  # lockstep now; drained
    t0 = run.server.plant.t_s  # type: ignore[attr-defined]
    for _ in range(3):
        client.actuators([math.nan, 0.5, 0.5, 0.5])
        client.actuators([0.5, 1.7, 0.5, 0.5])
    client.sock.sendall(b"\x00" * 40)
    assert client.recv("HIL_SENSOR", QUIET_S) is None  # nothing stepped
    assert run.server.plant.t_s == t0  # type: ignore[attr-defined]
    client.actuators([0.0] * 4)
    assert client.recv("HIL_SENSOR") is not None  # alive
    run.stop()
    bad = run.summary()["bad_input"]
    assert bad["nonfinite"] == 3 and bad["range"] == 3 and bad["mavlink"] >= 1
    said = [ln for ln in run.lines() if "dropped" in ln]
    assert len(said) == 3, said
    assert any("controls[1] = 1.7" in ln for ln in said) and any("non-finite" in ln for ln in said)


def test_px4_that_closes_or_goes_silent_ends_the_server_with_a_clear_message() -> None:
    run = _serve("px4", watchdog_s=5.0)
    client = Px4Client(run.server.address)  # type: ignore[attr-defined]
    client.fly([0.0] * 4, 2)
    client.close()
    assert run.join(5.0) == 3
    assert any("PX4 closed the connection" in ln for ln in run.lines()), run.lines()
    run = _serve("px4", watchdog_s=0.3)
    client = Px4Client(run.server.address)  # type: ignore[attr-defined]
    client.fly([0.0] * 4, 2)
    assert run.join(5.0) == 3
    client.close()
    assert any("no HIL_ACTUATOR_CONTROLS from PX4 for" in ln for ln in run.lines()), run.lines()


# == shared ========================================================================================
@pytest.mark.parametrize("roll_deg", [0.0, 30.0, -75.0])
def test_the_specific_force_at_rest_is_minus_g_along_body_up(roll_deg: float) -> None:
    phi = math.radians(roll_deg)
    f = specific_force_frd((0.0, 0.0, 0.0), quat_from_euler(phi, 0.0, 0.0), G)  # FLU roll = FRD roll
    assert f == pytest.approx((0.0, -G * math.sin(phi), -G * math.cos(phi)))


def test_the_servers_leave_the_port_free_when_they_stop() -> None:
    run = _serve("px4")
    port = run.server.address[1]  # type: ignore[attr-defined]
    assert run.stop() == 0
    again = Px4Server(Scenario(), ServeOptions(kind="px4", port=port), out=io.StringIO())
    again.close()


def _dropout(sensor: str, start_s: float) -> Scenario:
    return Scenario(faults=(FaultSpec(kind="sensor", start_s=start_s, sensor=sensor, mode="dropout"),))


def test_a_sensor_dropout_holds_the_last_json_value_and_clears_px4s_bits() -> None:
    run = _serve("ardupilot-json", _dropout("position", 0.3))
    try:
        client = ArduPilotClient(run.server.address)  # type: ignore[attr-defined]
        before = client.fly([2000] * 4, 299)["position"]
        after = client.fly([2000] * 4, 50)  # climbing on, position dropped out: the last value again, finite
        client.close()
    finally:
        run.stop()
    assert after["position"] == before and before[2] < -0.1 and after["velocity"][2] < -1.0
    assert run.summary()["held_values"] == 50
    run = _serve("px4", _dropout("gyro", 0.02))
    try:
        px = Px4Client(run.server.address)  # type: ignore[attr-defined]
        early, _ = px.fly([0.0] * 4, 1)
        late, _ = px.fly([0.0] * 4, 10)
        px.close()
    finally:
        run.stop()
    assert early.fields_updated & GYRO_BITS == GYRO_BITS and late.fields_updated & GYRO_BITS == 0
    assert late.fields_updated & ACCEL_BITS == ACCEL_BITS
