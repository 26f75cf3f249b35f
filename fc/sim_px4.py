"""The flight controller on PX4's simulator MAVLink API (``python -m fc --sim px4:tcp:HOST:PORT``).

Gazebo, jMAVSim, AirSim, rotorpy and Pegasus serve an autopilot through PX4's simulator API: the
simulator listens on TCP (4560 by convention) and the autopilot connects to it. With this link the
FC is that autopilot, in PX4's place:

- it **connects** to ``HOST:PORT`` (default ``127.0.0.1:4560``), retrying every
  :data:`CONNECT_RETRY_S` with one message while the simulator is not up, for at most the
  start-up timeout (``--startup-timeout-s``), and sends a ``HEARTBEAT`` on connecting and every
  wall second (rotorpy waits for one);
- **lockstep on the simulator's clock**, as PX4: each ``HIL_STATE_QUATERNION`` is one control tick
  at its ``time_usec`` and is answered with one ``HIL_ACTUATOR_CONTROLS`` stamped with it, the
  lockstep flag (bit 0 of ``flags``) set; the simulator steps its physics on the answer. The
  state's ``time_usec`` must advance by the FC's period (``--rate-hz``, within
  :data:`STEP_TOLERANCE_US`: a simulator that accumulates its clock in floats is off by a
  microsecond now and then);
- the state: attitude quaternion (FRD body in NED), body rates (rad/s, FRD), position
  (lat/lon 1e-7 deg, altitude mm AMSL) and velocity (cm/s, NED) of ``HIL_STATE_QUATERNION``; the
  local frame's origin and the FC's home are where the vehicle is at the first state (PX4's
  estimator takes its origin at the first fix likewise), so ``--home`` does not apply;
- ``HIL_SENSOR`` and ``HIL_GPS`` are logged and counted, not flown on;
- the answer: ``controls[0..3]`` in PX4's motor order and normalisation (:func:`px4_controls`),
  ``controls[4..15]`` 0, ``mode`` MAV_MODE_FLAG_CUSTOM_MODE_ENABLED plus SAFETY_ARMED while armed;
  disarmed, every control is 0 (PX4 does the same).

Motor order (``--px4-frame``): ``quad-x`` (default), PX4's quadrotor X: controls[0] front right
(counter-clockwise seen from above), [1] rear left (CCW), [2] front left (clockwise), [3] rear
right (CW), each rotor ``arm_length_m`` from the centre on the diagonals; ``plus``: our own layout,
controls[0..3] our rotors 1..4 (right CW, front CCW, left CW, rear CCW), as ``smcpilot sim
--serve px4`` reads them. The FC's mixer allocates for its plus layout; for the X the same wrench
(total thrust, roll, pitch and yaw torque) is allocated again on the X (:func:`plus_to_quad_x`), and
a rotor the X cannot give its share is clipped to its range (counted: ``px4_clipped_ticks``).

Normalisation (``--px4-motor``): a control in [0, 1] sets the rotor **speed**, omega = c *
``rotor_speed_max_radps`` (``speed``, default: Gazebo's motor model and rotorpy; PX4's
``THR_MDL_FAC`` 1), or the **thrust** above idle as our plant reads it (``thrust``:
omega^2 = omega_idle^2 + c (omega_max^2 - omega_idle^2); PX4's ``THR_MDL_FAC`` 0).

Bad input, counted by kind (``FC_SUMMARY``'s ``px4``), never flown on, with one rate-limited
message naming it (:class:`smcpilot.complaints.Complaints`): bytes that are not MAVLink
(``mavlink``); a state stamped at or before the last one (``duplicate`` / ``out_of_order``) or not
one period after it (``wrong_step``; on the second state this is a simulator at another rate:
exit 2 naming ``--rate-hz``); a state with a non-finite quaternion or rate, or a quaternion that is
not a rotation (all zero: a message that lacks it) is flown as "not measured" (``nonfinite`` /
``no_attitude``): the estimate's state-loss failsafe flies, as for our simulator's NaN states;
``HIL_SENSOR`` with no field updated (``sensor_empty``) or a non-finite updated value
(``sensor_nonfinite``), ``HIL_GPS`` without a fix (``gps_no_fix``). A simulator silent for
``FS_WATCHDOG`` s ends the FC (exit 3); one that closes the connection ends it too: cleanly when no
``--duration`` was asked for or it has been flown, else exit 3.

``SIM_*`` parameters from ground stations (faults) are forwarded as ``PARAM_SET`` to the
simulator as over our own link; a simulator that does not answer (PX4's do not) gets the usual
one warning per parameter ("no answer from the simulator").
"""

from __future__ import annotations

import math
import re
import select
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, cast

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.app import FlightControllerApp
from fc.core import TickOutput
from fc.flight import VehicleState
from fc.mixer import MixerParams, mixer_params
from smcpilot.complaints import Complaints
from smcpilot.errors import EndpointError, RateMismatchError, WatchdogError
from smcpilot.fastcodec import encode_attitude, encode_hil_actuator_controls, encode_local_position_ned
from smcpilot.frames import euler_from_quat
from smcpilot.geo import Home, global_to_ned
from smcpilot.impair import LinkImpairment
from smcpilot.link import LinkCounters, MavlinkUdp, PacketSink
from smcpilot.protocol import ACTUATOR_FLAG_LOCKSTEP, FC_COMPONENT_ID, SIM_COMPONENT_ID
from smcpilot.wire import paper_of_wire

#: the port PX4's simulators listen on.
DEFAULT_PX4_PORT = 4560
#: motor orders (``--px4-frame``) and normalisations (``--px4-motor``).
PX4_FRAMES = ("quad-x", "plus")
PX4_MOTOR_MODELS = ("speed", "thrust")
#: while the simulator refuses the connection, try again this often (wall s).
CONNECT_RETRY_S = 0.5
#: a state's time_usec may differ from one period after the last by this much.
STEP_TOLERANCE_US = 10
#: a quaternion whose norm is outside this range is not a rotation (a message that lacks one).
QUAT_NORM_RANGE = (0.9, 1.1)
#: HEARTBEAT to the simulator this often (wall s).
HEARTBEAT_S = 1.0
_MODE_CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_ZEROS12 = [0.0] * 12
_ZEROS4 = [0.0] * 4
_SQRT2 = math.sqrt(2.0)
_ID_STATE = mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
_ID_SENSOR = mavlink.MAVLINK_MSG_ID_HIL_SENSOR
_ID_GPS = mavlink.MAVLINK_MSG_ID_HIL_GPS
_ID_PARAM_VALUE = mavlink.MAVLINK_MSG_ID_PARAM_VALUE
_ID_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_URL = re.compile(r"^px4(?::tcp:(?P<host>[A-Za-z0-9.-]+)(?::(?P<port>\d{1,5}))?)?$")
_URL_FORMS = "px4, px4:tcp:HOST or px4:tcp:HOST:PORT"


def is_px4_url(url: str) -> bool:
    """Does ``--sim URL`` name PX4's simulator API (``px4...``)?"""
    return url == "px4" or url.startswith("px4:")


def parse_px4_url(url: str) -> tuple[str, int]:
    """``px4[:tcp:HOST[:PORT]]`` -> (host, port); the default 127.0.0.1:4560."""
    m = _URL.match(url)
    if m is None:
        raise EndpointError(f"--sim: expected {_URL_FORMS} (PX4's simulator API over TCP), got {url!r}")
    host = m.group("host") or "127.0.0.1"
    port = int(m.group("port")) if m.group("port") else DEFAULT_PX4_PORT
    if not 1 <= port <= 65535:
        raise EndpointError(f"--sim {url}: the port must be in [1, 65535], got {port}")
    return host, port


class SimulatorGoneError(WatchdogError):
    """The connection to the simulator broke (closed or reset) while the FC wrote to it."""


@dataclass(frozen=True)
class Px4Output:
    """How the FC's motor commands go on PX4's wire: motor order and normalisation."""

    frame: str = "quad-x"
    motor: str = "speed"

    def __post_init__(self) -> None:
        if self.frame not in PX4_FRAMES:
            raise EndpointError(f"--px4-frame must be one of {', '.join(PX4_FRAMES)}, got {self.frame!r}")
        if self.motor not in PX4_MOTOR_MODELS:
            raise EndpointError(f"--px4-motor must be one of {', '.join(PX4_MOTOR_MODELS)}, got {self.motor!r}")


# -- pure conversions ------------------------------------------------------------------------------
class Px4State(NamedTuple):
    """The 12 wire values of a HIL_STATE_QUATERNION (as :mod:`smcpilot.wire` takes them), and what
    was wrong with it: 0 fine, else :data:`STATE_NONFINITE` / :data:`STATE_NO_ATTITUDE` bits."""

    wire: tuple[float, float, float, float, float, float, float, float, float, float, float, float]
    problems: int


STATE_NONFINITE = 1
STATE_NO_ATTITUDE = 2


def wire_of_hil_state(
    quat_wxyz: tuple[float, float, float, float], rates_frd_radps: tuple[float, float, float],
    lat_e7: int, lon_e7: int, alt_mm: int, vel_ned_cmps: tuple[int, int, int], origin: Home,
) -> Px4State:  # fmt: skip
    """HIL_STATE_QUATERNION's fields -> (roll, pitch, yaw, p, q, r, north, east, down, vn, ve, vd)
    in MAVLink's frames (rad, rad/s FRD, m and m/s NED from ``origin``). A quaternion that is not
    finite or not a rotation makes the angles NaN, a non-finite rate that rate NaN ("not
    measured": the estimate decides)."""
    nan = math.nan
    problems = 0
    if all(math.isfinite(v) for v in quat_wxyz):
        n = math.sqrt(sum(v * v for v in quat_wxyz))
        if QUAT_NORM_RANGE[0] <= n <= QUAT_NORM_RANGE[1]:
            roll, pitch, yaw = euler_from_quat(quat_wxyz)
        else:
            roll = pitch = yaw = nan
            problems |= STATE_NO_ATTITUDE
    else:
        roll = pitch = yaw = nan
        problems |= STATE_NONFINITE
    rates = tuple(v if math.isfinite(v) else nan for v in rates_frd_radps)
    if any(r != r for r in rates):
        problems |= STATE_NONFINITE
    north, east, down = global_to_ned(origin, lat_e7 * 1e-7, lon_e7 * 1e-7, alt_mm * 1e-3)
    vn, ve, vd = (v * 0.01 for v in vel_ned_cmps)
    return Px4State((roll, pitch, yaw, rates[0], rates[1], rates[2], north, east, down, vn, ve, vd), problems)


def plus_to_quad_x(w2_plus: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Rotor speeds squared of our plus layout (rotors 1 right, 2 front, 3 left, 4 rear) -> those
    of PX4's quad X (1 front right, 2 rear left, 3 front left, 4 rear right) giving the same total
    thrust and body torques, both with their rotors at the same distance d from the centre (the
    X's at d / sqrt(2) along each axis), 1 and 3 of the plus and 3 and 4 of the X clockwise.

    With F_i proportional to w_i^2 and torques per unit of it: the plus gives roll d (w3 - w1),
    pitch d (w4 - w2), yaw k (w1 + w3 - w2 - w4); the X roll (d/sqrt2)(-W1 + W2 + W3 - W4), pitch
    (d/sqrt2)(-W1 + W2 - W3 + W4), yaw k (-W1 - W2 + W3 + W4); solved for W."""
    w1, w2, w3, w4 = w2_plus
    total = w1 + w2 + w3 + w4
    roll = _SQRT2 * (w3 - w1)
    pitch = _SQRT2 * (w4 - w2)
    yaw = w1 + w3 - w2 - w4
    return (
        0.25 * (total - roll - pitch - yaw),
        0.25 * (total + roll + pitch - yaw),
        0.25 * (total + roll - pitch + yaw),
        0.25 * (total - roll + pitch + yaw),
    )


def px4_controls(
    motors: tuple[float, float, float, float], mp: MixerParams, output: Px4Output
) -> tuple[tuple[float, float, float, float], bool]:
    """(controls[0..3] in [0, 1] in PX4's order and normalisation, clipped) of the FC's motor
    commands (our rotors 1..4, thrust-linear above idle: w^2 = lo + c span). ``clipped``: a rotor
    of the X needed more (or less) than its range and was clipped."""
    lo, span = mp.lo, mp.span
    w2 = (lo + motors[0] * span, lo + motors[1] * span, lo + motors[2] * span, lo + motors[3] * span)
    clipped = False
    if output.frame == "quad-x":
        hi = mp.hi
        out = []
        for w in plus_to_quad_x(w2):
            if w < lo or w > hi:
                clipped = clipped or abs(w - min(max(w, lo), hi)) > 1e-9 * hi
                w = min(max(w, lo), hi)
            out.append(w)
        w2 = (out[0], out[1], out[2], out[3])
    if output.motor == "speed":
        w_max = math.sqrt(mp.hi)
        c = tuple(min(1.0, math.sqrt(w) / w_max) for w in w2)
    else:
        c = tuple(min(1.0, max(0.0, (w - lo) / span)) for w in w2)
    return (c[0], c[1], c[2], c[3]), clipped


# -- the link --------------------------------------------------------------------------------------
class Px4Link:
    """MAVLink 2 over one TCP connection to a simulator, the FC as the client (as PX4 is)."""

    def __init__(self, host: str, port: int, *, source_system: int, source_component: int = FC_COMPONENT_ID) -> None:
        self.host = host
        self.port = port
        self.counters = LinkCounters()
        self._sink = PacketSink()
        self.mav = mavlink.MAVLink(self._sink, srcSystem=source_system, srcComponent=source_component)
        self.mav.robust_parsing = True
        self._parser = mavlink.MAVLink(None, srcSystem=source_system, srcComponent=source_component)
        self._parser.robust_parsing = True
        self.sock: socket.socket | None = None
        self.send_timeout_s = 5.0

    @property
    def url(self) -> str:
        return f"px4:tcp:{self.host}:{self.port}"

    @property
    def local_address(self) -> tuple[str, int]:
        """Where the link goes, as ``FC_LISTENING sim=`` shows it (``px4:tcp:HOST:PORT``)."""
        return f"px4:tcp:{self.host}", self.port

    @property
    def impair_counters(self) -> None:
        return None

    @property
    def connected(self) -> bool:
        return self.sock is not None

    def try_connect(self) -> OSError | None:
        """One connection attempt; None when connected, else the error (refused, unreachable)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.settimeout(2.0)
        try:
            sock.connect((self.host, self.port))
        except OSError as exc:
            sock.close()
            return exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(self.send_timeout_s)
        self.sock = sock
        return None

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else -1

    def take_seq(self) -> int:
        seq = self.mav.seq
        self.mav.seq = (seq + 1) & 0xFF
        self.counters.tx_messages += 1
        return seq

    @property
    def source(self) -> tuple[int, int]:
        return self.mav.srcSystem, self.mav.srcComponent

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        self.mav.send(msg)
        self.counters.tx_messages += 1
        return self._sink.take()

    def send_bytes(self, data: bytes) -> None:
        """Everything or an error: a simulator that reads nothing for ``send_timeout_s`` (its
        buffer full) or has gone is a :class:`WatchdogError`."""
        if self.sock is None:
            return
        try:
            self.sock.sendall(data)
        except TimeoutError:
            raise WatchdogError(f"the simulator has read nothing for {self.send_timeout_s:g} s; stopping") from None
        except OSError as exc:
            raise SimulatorGoneError(f"the connection to the simulator broke ({exc.strerror or exc}); stopping") from None
        self.counters.tx_datagrams += 1

    def recv(self) -> list[Any] | None:
        """The messages that wait on the socket (BAD_DATA included); None when the simulator has
        closed the connection."""
        assert self.sock is not None
        try:
            data = self.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            data = b""
        if not data:
            return None
        self.counters.rx_datagrams += 1
        msgs = self._parser.parse_buffer(data) or []
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                self.counters.rx_bad += 1
            else:
                self.counters.rx_messages += 1
        return msgs

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


# -- the app ---------------------------------------------------------------------------------------
@dataclass
class Px4Counts:
    """What came over the link (``FC_SUMMARY``'s ``px4``)."""

    states: int = 0
    hil_sensors: int = 0
    hil_gps: int = 0
    heartbeats: int = 0
    other_msgs: int = 0
    clipped_ticks: int = 0
    connect_attempts: int = 0


class Px4FlightControllerApp(FlightControllerApp):
    """:class:`fc.app.FlightControllerApp` on PX4's simulator API: the sim link is :class:`Px4Link`;
    the ground link, parameters, log, core and summary are the app's own. Always lockstep."""

    def __init__(self, *args: Any, sim_url: str, px4_output: Px4Output = Px4Output(), **kw: Any) -> None:
        self.px4_host, self.px4_port = parse_px4_url(sim_url)
        self.px4_output = px4_output
        self.px4_counts = Px4Counts()
        kw["lockstep"] = True
        super().__init__(*args, sim_url=sim_url, **kw)
        self.complaints = Complaints(self.say, "fc px4", self._mono)
        self._mixer = mixer_params(self.vehicle)
        self._origin: Home | None = None
        self._last_tick_us = -1
        self._last_heartbeat = -math.inf

    def _open_sim(
        self, url: str, sysid: int, clock_us: Callable[[], int], impairment: LinkImpairment | None, impair_seed: int
    ) -> MavlinkUdp:
        if impairment is not None and impairment.active:
            raise EndpointError("--sim-link (impairment) works on our simulator's UDP link only, not on PX4's TCP link")
        self.px4 = Px4Link(self.px4_host, self.px4_port, source_system=sysid)
        # The app's shared code uses only what both links have (counters, impair_counters,
        # local_address, fileno, close); everything that is UDP's own is overridden below.
        return cast(MavlinkUdp, self.px4)

    # -- connect ---------------------------------------------------------------------------------
    def _connect(self) -> None:
        link = self.px4
        mono = self._mono
        start = mono()
        said_at = -math.inf
        limit = self.startup_timeout_s
        while not self._stop:
            self.px4_counts.connect_attempts += 1
            err = link.try_connect()
            if err is None:
                self.say(f"fc px4: connected to the simulator at tcp:{link.host}:{link.port}")
                link.send_timeout_s = max(1.0, self.cfg.watchdog_s)
                self._heartbeat(mono())
                return
            now = mono()
            if now - said_at >= 10.0:
                said_at = now
                self.say(f"fc px4: waiting for the simulator at tcp:{link.host}:{link.port} ({err.strerror or err});"
                         f" retrying every {CONNECT_RETRY_S:g} s for up to {limit:g} s (--startup-timeout-s)")  # fmt: skip
            if now - start > limit:
                raise WatchdogError(f"no simulator accepted a connection at tcp:{link.host}:{link.port} within {limit:g} s; stopping")
            wait_until = now + CONNECT_RETRY_S
            while not self._stop and mono() < wait_until:  # ground stations are served meanwhile
                fds = [self.gcs.fileno()] if self.gcs is not None else []
                readable, _, _ = select.select(fds, (), (), max(0.0, min(0.1, wait_until - mono())))
                if readable:
                    self._poll_ground()
                if self.gcs is not None:
                    self.gcs_handler.send_durable_acks()

    def _heartbeat(self, now: float) -> None:
        self._last_heartbeat = now
        link = self.px4
        link.send_bytes(link.encode(link.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, _MODE_CUSTOM | (_ARMED if self.core.flight.armed else 0),
            0, mavlink.MAV_STATE_ACTIVE,
        )))  # fmt: skip

    # -- the loop --------------------------------------------------------------------------------
    def _run_lockstep(self) -> None:
        self._connect()
        if self._stop:
            return
        mono = self._mono
        link = self.px4
        last_rx = mono()
        while not self._stop:
            fds = [link.fileno()] + ([self.gcs.fileno()] if self.gcs is not None else [])
            readable, _, _ = select.select(fds, (), (), 0.1)
            now = mono()
            if link.fileno() in readable:
                if self._poll_sim():
                    last_rx = now
                if self._stop:
                    break
            if self.gcs is not None and self.gcs.fileno() in readable:
                self._poll_ground()
            if self.gcs is not None:
                self.gcs_handler.send_durable_acks()
            if now - self._last_heartbeat >= HEARTBEAT_S:
                self._heartbeat(now)
            if self._sim_pending:
                self._check_sim_answers(now)
            limit = self.cfg.watchdog_s if self.core.ticks else self.startup_timeout_s
            if now - last_rx > limit:
                what = "sent no state" if not self.core.ticks else f"has sent no state for {now - last_rx:.1f} s"
                raise WatchdogError(f"the simulator {what} (lockstep watchdog {limit:g} s); stopping")

    def _poll_sim(self, max_datagrams: int = 256) -> bool:
        """Everything that waits on the connection (a stream: ``max_datagrams`` does not apply);
        True if a state was flown."""
        msgs = self.px4.recv()
        flown = False
        for msg in msgs or ():
            if self._stop:
                break
            mid = msg.get_msgId()
            if mid == _ID_STATE:
                flown = self._on_state(msg) or flown
            elif mid == _ID_SENSOR:
                self._on_sensor(msg)
            elif mid == _ID_GPS:
                self.px4_counts.hil_gps += 1
                self._log_sim(msg)
                if msg.fix_type < 2:
                    self.complaints.bad("gps_no_fix", f"HIL_GPS without a fix (fix_type {msg.fix_type}) at {msg.time_usec} us")
            elif msg.get_type() == "BAD_DATA":
                self.complaints.bad("mavlink", f"{len(msg.get_msgbuf())} bytes that are not a MAVLink message")
            elif msg.get_type() == "STATUSTEXT":
                self._log_sim(msg)
                self._relay_sim_text(msg)
            elif mid == _ID_PARAM_VALUE:
                self._log_sim(msg)
                self._sim_param_value(msg)
            elif mid == _ID_HEARTBEAT:
                self.px4_counts.heartbeats += 1
            else:
                self.px4_counts.other_msgs += 1
        if msgs is None and not self._stop:
            self._closed_by_simulator()
        return flown

    def _closed_by_simulator(self) -> None:
        t_s = self.clock.now_s()
        if self.duration_s is not None and t_s < self.duration_s:
            raise WatchdogError(f"the simulator closed the connection at t = {t_s:.3f} s, before --duration {self.duration_s:g} s; stopping")
        if not self.core.ticks:
            raise WatchdogError("the simulator closed the connection before its first state; stopping")
        self.say(f"fc px4: the simulator closed the connection at t = {t_s:.3f} s; stopping")
        self._stop = True

    def _stamp_ok_us(self, t_us: int) -> bool:
        """Is a state stamped ``t_us`` the next one (one period after the last tick's)?"""
        last = self._last_tick_us
        if last < 0:
            return True
        stats = self.stats
        period = self.cfg.period_us
        step = t_us - last
        if abs(step - period) <= STEP_TOLERANCE_US:
            return True
        if step == 0:
            stats.duplicate_states += 1
            self.complaints.bad("duplicate", f"HIL_STATE_QUATERNION stamped {t_us} us again")
        elif step < 0:
            stats.out_of_order_states += 1
            self.complaints.bad("out_of_order", f"HIL_STATE_QUATERNION stamped {t_us} us, before the last one ({last} us)")
        else:
            if self.core.ticks == 1:
                raise RateMismatchError(
                    f"the simulator steps {step} us per state but this FC runs at {self.cfg.rate_hz:g} Hz ({period} us):"
                    f" give the FC the simulator's rate (--rate-hz {1e6 / step:g})"
                )
            stats.wrong_step_states += 1
            self.complaints.bad("wrong_step", f"HIL_STATE_QUATERNION stamped {t_us} us, {step} us after the last one (the period is {period} us)")
        return False

    def _on_state(self, msg: Any) -> bool:
        t_us = int(msg.time_usec)
        if not self._stamp_ok_us(t_us):
            return False
        if self._origin is None:
            self._adopt_origin(msg)
        assert self._origin is not None
        st = wire_of_hil_state(
            tuple(msg.attitude_quaternion), (msg.rollspeed, msg.pitchspeed, msg.yawspeed),
            msg.lat, msg.lon, msg.alt, (msg.vx, msg.vy, msg.vz), self._origin,
        )  # fmt: skip
        if st.problems:
            self.stats.states_missing_fields += 1
            if st.problems & STATE_NONFINITE:
                self.stats.rx_invalid_state += 1
                self.complaints.bad("nonfinite", f"a non-finite attitude or rate in HIL_STATE_QUATERNION at {t_us} us (flown as not measured)")
            if st.problems & STATE_NO_ATTITUDE:
                self.complaints.bad("no_attitude", f"HIL_STATE_QUATERNION without a rotation quaternion {list(msg.attitude_quaternion)} at {t_us} us"
                                    " (flown as not measured)")  # fmt: skip
        self.px4_counts.states += 1
        w = st.wire
        self.clock.set_us(t_us)  # type: ignore[union-attr]
        if self.tlog is not None:  # the state as received, and as our log readers read a state
            lm = self._logmav
            t_ms = (t_us // 1000) & 0xFFFFFFFF
            a = encode_attitude(lm.seq, lm.srcSystem, SIM_COMPONENT_ID, t_ms, *w[:6])
            b = encode_local_position_ned((lm.seq + 1) & 0xFF, lm.srcSystem, SIM_COMPONENT_ID, t_ms, *w[6:])
            lm.seq = (lm.seq + 2) & 0xFF
            self.tlog.write_many(t_us, (msg.get_msgbuf(), a, b))
        s = paper_of_wire(*w)  # smcpilot.wire: the one wire <-> paper-frame conversion
        rates = (s[12], s[13], s[14])
        self.state = VehicleState(*s[:12])
        if all(math.isfinite(v) for v in rates):
            self.body_rates = rates
        self._state_wall_s = self._mono()
        self._last_tick_us = t_us
        self._tick(t_us, stale=False)
        if self.duration_s is not None and t_us * 1e-6 >= self.duration_s:
            self._stop = True
        return True

    def _adopt_origin(self, msg: Any) -> None:
        """The first state's position is the local origin and the FC's home."""
        origin = Home(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
        self._origin = origin
        self.home = self.core.home = self.core.commander.home = origin
        self.say(f"fc px4: home (the local origin) is the vehicle's first position {origin.lat_deg:.7f},{origin.lon_deg:.7f},{origin.alt_m:.3f}")

    def _on_sensor(self, msg: Any) -> None:
        self.px4_counts.hil_sensors += 1
        self._log_sim(msg)
        fields = int(msg.fields_updated)
        if fields == 0:
            self.complaints.bad("sensor_empty", f"HIL_SENSOR with no field updated at {msg.time_usec} us")
            return
        values = (msg.xacc, msg.yacc, msg.zacc, msg.xgyro, msg.ygyro, msg.zgyro, msg.xmag, msg.ymag, msg.zmag,
                  msg.abs_pressure, msg.diff_pressure, msg.pressure_alt, msg.temperature)  # fmt: skip
        if any(fields >> i & 1 and not math.isfinite(v) for i, v in enumerate(values)):
            self.complaints.bad("sensor_nonfinite", f"HIL_SENSOR with a non-finite updated value at {msg.time_usec} us")

    # -- out -------------------------------------------------------------------------------------
    def _actuator_packet(self, t_us: int, out: TickOutput) -> bytes:
        if out.armed:
            c, clipped = px4_controls(out.motors, self._mixer, self.px4_output)
            if clipped:
                self.px4_counts.clipped_ticks += 1
            controls = [c[0], c[1], c[2], c[3]]
            mode = _MODE_CUSTOM | _ARMED
        else:
            controls, mode = _ZEROS4, _MODE_CUSTOM
        link = self.px4
        return encode_hil_actuator_controls(link.take_seq(), *link.source, t_us, controls + _ZEROS12, mode, ACTUATOR_FLAG_LOCKSTEP)

    def _answer_sim(self, packets: tuple[bytes, ...]) -> None:
        try:
            self.px4.send_bytes(b"".join(packets))
        except SimulatorGoneError:
            t_s = self.clock.now_s()
            if self.duration_s is None or t_s < self.duration_s:
                raise
            # The answer to the state at --duration: a simulator that flies the same duration may
            # close (or reset) the connection with that state, before it reads the answer. The
            # flight is flown: the clean end, as a close after the answer is (the log goes on whole).
            self.say(f"fc px4: the simulator closed the connection with its last state (t = {t_s:.3f} s); stopping")
            self._stop = True

    def forward_sim_param(self, name: str, value: float) -> None:
        link = self.px4
        msg = link.mav.param_set_encode(self._sim_sysid, SIM_COMPONENT_ID, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32)
        link.send_bytes(link.encode(msg))
        self._log_sim(msg)
        self.stats.sim_param_forwards += 1
        self._sim_pending[name] = self._mono()

    def _summary_extra(self) -> dict[str, Any]:
        c = self.px4_counts
        return {"px4": {"url": self.px4.url, "frame": self.px4_output.frame, "motor": self.px4_output.motor, "states": c.states,
                "hil_sensors": c.hil_sensors, "hil_gps": c.hil_gps, "heartbeats": c.heartbeats, "other_msgs": c.other_msgs,
                "clipped_ticks": c.clipped_ticks, "connect_attempts": c.connect_attempts, "bad": dict(self.complaints.counts)}}  # fmt: skip
