"""ArduPilot's JSON physics interface, served by our plant (``smcpilot sim --serve ardupilot-json``).

ArduPilot SITL started with ``--model JSON`` sends, every physics frame, a binary servo packet by
UDP to port 9002 of the physics host, and waits for the state in JSON; the physics answers to the
address the packet came from (ArduPilot's ``libraries/SITL/SIM_JSON.cpp`` and
``libraries/SITL/examples/JSON/readme.md``).

Servo packet, little-endian: ``uint16 magic, uint16 frame_rate, uint32 frame_count, uint16 pwm[N]``,
magic 18458 with 16 channels, 29569 with 32 (``SERVO_32_ENABLE``). Reply: one JSON object between
two newlines (ArduPilot parses the text between the last two it holds), compact (its parser expects
``"key":[`` with no space), numbers never NaN::

    {"timestamp":T,"imu":{"gyro":[p,q,r],"accel_body":[ax,ay,az]},"position":[n,e,d],
     "velocity":[vn,ve,vd],"quaternion":[w,x,y,z]}

timestamp in s of physics time; gyro rad/s and the specific force m/s^2 in body FRD ((0, 0, -9.81)
level at rest); position m and velocity m/s in NED from where the vehicle started; the attitude
quaternion of the FRD body in NED (:mod:`smcpilot.frames`).

Lockstep on the frame counter:

- a new frame (its count above the last) steps the plant by ``1 / frame_rate`` with its motor
  commands and is answered once; a gap in the counter is counted (``missed_frames``), one step;
- a re-sent frame (the same count: ArduPilot re-sends after a second without an answer) does not
  step the plant: the last answer is sent again, byte for byte (``resent_frames``);
- a smaller count means ArduPilot restarted: a fresh vehicle from the scenario (``restarts``).

Motors: ArduCopter with ``FRAME_CLASS`` 1 (quad) and ``FRAME_TYPE`` 6 (PLUSREV: plus with reversed
motor directions) numbers its motors 1 right (CW), 2 left (CW), 3 front (CCW), 4 rear (CCW), which
are our rotors 1, 3, 2, 4 (our rotors 1 right and 3 left spin clockwise seen from above, 2 front and
4 rear counter-clockwise: :mod:`sim_bridge.plants.rigid_body`). Channel ``ROTOR_CHANNELS[i]``
(0-based) drives our rotor i + 1. A PWM maps to our motor command (thrust-linear above idle) as
``c = (pwm - pwm_min) / (pwm_max - pwm_min)``, clamped to [0, 1]; the rotors stop (our disarmed
state) while every motor channel is at or below ``pwm_min``, which is ArduCopter's disarmed output.

Bad input, counted and dropped with a rate-limited message naming it (:class:`sim_bridge.serve.Complaints`):
a packet shorter than its header or than its magic's length (``short``), an unknown magic
(``magic``), a frame rate of 0 (``frame_rate``), a motor channel outside
``[pwm_min - PWM_MARGIN, pwm_max + PWM_MARGIN]`` other than 0 (``pwm``; 0 is a channel not yet
output, a stopped motor). A dropped frame is not answered (ArduPilot re-sends it).

A sensor the faults drop out (NaN) cannot be sent (the protocol has no "not measured"): its last
value is sent again (counted in ``held_values``).
"""

from __future__ import annotations

import math
import select
import socket
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

from sim_bridge.sensors import imu_frd
from sim_bridge.serve import ServeOptions, ServerBase
from smcpilot.frames import nwu_to_ned, quat_nwu_flu_to_ned_frd
from smcpilot.scenario import Scenario

MAGIC_16 = 18458
MAGIC_32 = 29569
HEADER = struct.Struct("<HHI")
#: channels of each magic.
CHANNELS = {MAGIC_16: 16, MAGIC_32: 32}
#: 0-based servo channel driving our rotors 1..4 (ArduCopter PLUSREV motors 1 right, 3 front, 2 left, 4 rear).
ROTOR_CHANNELS = (0, 2, 1, 3)
#: ArduCopter's frame parameters for our rotor layout.
ARDUCOPTER_FRAME = {"FRAME_CLASS": 1, "FRAME_TYPE": 6}
#: how far beyond [pwm_min, pwm_max] a motor channel may be before the packet is refused, us.
PWM_MARGIN = 100


class BadPacket(Exception):
    """A servo packet that cannot be flown: ``kind`` (a counter's name) and what was wrong."""

    def __init__(self, kind: str, text: str) -> None:
        super().__init__(text)
        self.kind = kind
        self.text = text


class ServoFrame(NamedTuple):
    magic: int
    frame_rate: int
    frame_count: int
    pwm: tuple[int, ...]


def parse_servo_packet(data: bytes) -> ServoFrame:
    """A servo packet's fields; raises :class:`BadPacket` for a short one or an unknown magic."""
    if len(data) < HEADER.size:
        raise BadPacket("short", f"a servo packet of {len(data)} bytes (shorter than its {HEADER.size}-byte header)")
    magic, frame_rate, frame_count = HEADER.unpack_from(data)
    n = CHANNELS.get(magic)
    if n is None:
        raise BadPacket("magic", f"a packet with the unknown magic {magic} (servo packets have {MAGIC_16} or {MAGIC_32})")
    size = HEADER.size + 2 * n
    if len(data) < size:
        raise BadPacket("short", f"a servo packet of {len(data)} bytes (magic {magic} has {n} channels: {size} bytes)")
    if frame_rate == 0:
        raise BadPacket("frame_rate", f"servo frame {frame_count} with a frame rate of 0 Hz")
    return ServoFrame(magic, frame_rate, frame_count, struct.unpack_from(f"<{n}H", data, HEADER.size))


def motor_commands(pwm: Sequence[int], pwm_min: int, pwm_max: int) -> tuple[tuple[float, float, float, float], bool]:
    """Our rotors' commands in [0, 1] and whether they spin, from the servo channels; raises
    :class:`BadPacket` for a motor channel out of range."""
    lo, hi = pwm_min - PWM_MARGIN, pwm_max + PWM_MARGIN
    span = float(pwm_max - pwm_min)
    out = []
    spinning = False
    for rotor, ch in enumerate(ROTOR_CHANNELS):
        v = pwm[ch]
        if v != 0 and not lo <= v <= hi:
            raise BadPacket("pwm", f"PWM {v} us on channel {ch + 1} (rotor {rotor + 1}), outside [{lo}, {hi}]")
        spinning = spinning or v > pwm_min
        out.append(min(max((v - pwm_min) / span, 0.0), 1.0))
    return (out[0], out[1], out[2], out[3]), spinning


def _num(v: float) -> str:
    return f"{v + 0.0:.9g}"  # (no "-0")


def _vec(v: Sequence[float]) -> str:
    return "[" + ",".join(_num(x) for x in v) + "]"


def state_json(t_s: float, gyro: Sequence[float], accel: Sequence[float], pos: Sequence[float], vel: Sequence[float], quat: Sequence[float]) -> bytes:
    """The reply ArduPilot parses (finite numbers only), between a leading and a trailing newline."""
    text = (f'\n{{"timestamp":{t_s:.9f},"imu":{{"gyro":{_vec(gyro)},"accel_body":{_vec(accel)}}},'
            f'"position":{_vec(pos)},"velocity":{_vec(vel)},"quaternion":{_vec(quat)}}}\n')  # fmt: skip
    return text.encode("ascii")


class ArduPilotJsonServer(ServerBase):
    """Listens on UDP ``options.host:options.port``; :meth:`run` serves until stopped."""

    name = "sim ardupilot-json"

    def __init__(self, scenario: Scenario, options: ServeOptions, **kw: Any) -> None:
        super().__init__(scenario, options, **kw)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((options.host, options.port))
        except OSError:
            self.sock.close()
            raise
        self.address: tuple[str, int] = self.sock.getsockname()
        self.peer: tuple[str, int] | None = None
        self.frames = 0
        self.resent_frames = 0
        self.missed_frames = 0
        self.peer_changes = 0
        self._last_count: int | None = None
        self._last_reply = b""
        self._held: dict[str, tuple[float, ...]] = {}

    def counters(self) -> dict[str, Any]:
        return {"frames": self.frames, "resent_frames": self.resent_frames, "missed_frames": self.missed_frames, "peer_changes": self.peer_changes}

    def close(self) -> None:
        self.sock.close()

    # -- the state sent --------------------------------------------------------------------------
    def _finite(self, key: str, v: tuple[float, ...]) -> tuple[float, ...]:
        """``v``, or its last finite value when a dropout made it NaN (0 before there was one)."""
        if all(math.isfinite(x) for x in v):
            self._held[key] = v
            return v
        self.held_values += 1
        return self._held.get(key, tuple(0.0 if k or key != "quaternion" else 1.0 for k in range(len(v))))

    def reply(self) -> bytes:
        plant = self.plant
        obs = plant.observe()
        gyro, accel = imu_frd(obs, plant.truth(), self.gravity)
        f = self._finite
        return state_json(
            plant.t_s, f("gyro", gyro), f("accel", accel), f("position", nwu_to_ned(obs.position_m)),
            f("velocity", nwu_to_ned(obs.velocity_mps)), f("quaternion", quat_nwu_flu_to_ned_frd(obs.quaternion)),
        )  # fmt: skip

    # -- one packet ------------------------------------------------------------------------------
    def handle(self, data: bytes, addr: tuple[str, int]) -> bytes | None:
        """The answer to one datagram (None: dropped, counted)."""
        opts = self.options
        try:
            frame = parse_servo_packet(data)
            commands, spinning = motor_commands(frame.pwm, opts.pwm_min, opts.pwm_max)
        except BadPacket as exc:
            self.complaints.bad(exc.kind, f"{exc.text} from {addr[0]}:{addr[1]}")
            return None
        if addr != self.peer:
            if self.peer is not None:
                self.peer_changes += 1
                self.say(f"{self.name}: servo packets now come from {addr[0]}:{addr[1]} (were from {self.peer[0]}:{self.peer[1]})")
            else:
                self.say(f"{self.name}: ArduPilot connected from {addr[0]}:{addr[1]} ({len(frame.pwm)} channels, {frame.frame_rate} Hz)")
            self.peer = addr
        last = self._last_count
        if last is not None:
            if frame.frame_count == last:
                self.resent_frames += 1
                return self._last_reply
            if frame.frame_count < last:
                self.restart_plant(f"ArduPilot restarted (frame {frame.frame_count} after {last})", 1.0 / frame.frame_rate)
                self._held.clear()
                self.say(f"{self.name}: frame {frame.frame_count} after {last}: ArduPilot restarted; the vehicle starts again at rest")
            elif frame.frame_count > last + 1:
                self.missed_frames += frame.frame_count - last - 1
        self.step_plant(self.plant.t_s, 1.0 / frame.frame_rate, commands, spinning, True)
        self.frames += 1
        self._last_count = frame.frame_count
        self._last_reply = self.reply()
        self.announce_faults()
        return self._last_reply

    def _serve(self) -> None:
        opts = self.options
        frame = ", ".join(f"{k} {v}" for k, v in ARDUCOPTER_FRAME.items())
        self.say(f"SIM_READY serve=ardupilot-json udp={self.address[0]}:{self.address[1]} plant={self.scenario.plant}"
                 f" ArduCopter: {frame}, MOT_PWM_MIN {opts.pwm_min}, MOT_PWM_MAX {opts.pwm_max}, MOT_THST_EXPO 0")  # fmt: skip
        sock = self.sock
        last_heard: float | None = None
        while not self._stop:
            ready, _, _ = select.select([sock], [], [], 0.1)
            if not ready:
                self.check_silence(last_heard, "servo packet from ArduPilot")
                continue
            try:
                data, addr = sock.recvfrom(4096)
            except OSError:  # e.g. ICMP port unreachable from an ArduPilot that has gone
                continue
            answer = self.handle(data, addr)
            if answer is None:
                self.check_silence(last_heard, "servo packet from ArduPilot")
                continue
            last_heard = self._mono()
            try:
                sock.sendto(answer, addr)
            except OSError:
                pass  # the next frame (or the watchdog) tells
            if self.duration_reached():
                return
