"""PX4's simulator MAVLink API, served by our plant (``smcpilot sim --serve px4``).

The simulator listens on TCP (4560 by convention) and PX4 SITL connects to it (PX4's
``simulator_mavlink`` module; ``PX4_SIM_HOSTNAME`` names another host). MAVLink 2 both ways:

- out, each step: ``HIL_SENSOR`` (id 0: gyro rad/s and specific force m/s^2 in body FRD, the
  magnetic field in gauss, barometric pressure hPa, pressure altitude m, temperature; its
  ``fields_updated`` says which), ``HIL_STATE_QUATERNION`` (the true state, which PX4 publishes as
  ground truth) and, every ``1 / GPS_RATE_HZ`` s, ``HIL_GPS``; ``time_usec`` is simulated time;
- in: ``HIL_ACTUATOR_CONTROLS``: ``controls[0..3]`` in [0, 1] are our rotors 1..4 (1 right,
  2 front, 3 left, 4 rear; thrust-linear above idle as for our own flight controller), ``mode``
  with MAV_MODE_FLAG_SAFETY_ARMED (128) spins them, without it they stop.

Lockstep: PX4's clock follows the ``time_usec`` of ``HIL_SENSOR`` and it answers each with
``HIL_ACTUATOR_CONTROLS``. Before its first answer (PX4 boots on our clock) the vehicle rests with
its rotors stopped and simulated time runs at real time; from the first answer on, each valid
``HIL_ACTUATOR_CONTROLS`` steps the plant by one period (``1 / rate_hz``) and is answered with the
next sensors, and nothing else advances time.

Sensor faults: a dropped-out gyro, accelerometer or position clears its bits of
``fields_updated`` (the position: the barometer's) and a dropped-out position or velocity stops
``HIL_GPS``; noise, bias, stuck values and delays are in the values sent. The attitude is PX4's
own estimate (from the IMU and magnetometer): an attitude fault does not reach it.

Not modelled: the magnetic field is a constant :data:`MAG_FIELD_NED_GAUSS` (no declination, no
dependence on place), the barometer follows the ISA with no noise of its own, no airspeed.

Bad input, counted and dropped with a rate-limited message naming it: bytes that are not MAVLink
(``mavlink``), ``HIL_ACTUATOR_CONTROLS`` with a non-finite motor value (``nonfinite``) or one
outside [0, 1] (``range``). A peer that closes the connection or stays silent for the watchdog ends
the server with a clear message (exit 3).
"""

from __future__ import annotations

import math
import select
import socket
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.sensors import imu_frd
from sim_bridge.serve import ServeOptions, ServerBase
from smcpilot.errors import WatchdogError
from smcpilot.frames import flu_to_frd, ned_to_nwu, nwu_to_ned, quat_nwu_flu_to_ned_frd, quat_rotate_inverse, rates_flu_to_frd
from smcpilot.geo import Home, ned_to_global
from smcpilot.link import PacketSink
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.scenario import Scenario

#: HIL_SENSOR fields_updated bits (MAVLink HIL_SENSOR_UPDATED_FLAGS).
ACCEL_BITS = 0x7
GYRO_BITS = 0x38
MAG_BITS = 0x1C0
BARO_BITS = 0x200 | 0x800 | 0x1000  # abs_pressure, pressure_alt, temperature
#: the Earth's field the magnetometer measures, world NED, gauss (no declination).
MAG_FIELD_NED_GAUSS = (0.21, 0.0, 0.42)
GPS_RATE_HZ = 10.0
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_ACTUATORS = mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
#: a motor value this far outside [0, 1] is refused (float rounding on PX4's side is allowed).
RANGE_TOL = 1e-3


def isa_pressure_hpa(alt_amsl_m: float) -> float:
    """The ICAO standard atmosphere's pressure at an altitude, hPa."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


def _i16(v: float) -> int:
    return int(max(-32768, min(32767, round(v))))


class Px4Server(ServerBase):
    """Listens on TCP ``options.host:options.port``; :meth:`run` serves one PX4 until stopped."""

    name = "sim px4"

    def __init__(self, scenario: Scenario, options: ServeOptions, **kw: Any) -> None:
        super().__init__(scenario, options, **kw)
        self.period_us = int(round(1e6 / options.rate_hz))
        self.home = Home(*scenario.home) if scenario.home is not None else Home()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.listener.bind((options.host, options.port))
            self.listener.listen(1)
        except OSError:
            self.listener.close()
            raise
        self.address: tuple[str, int] = self.listener.getsockname()
        self.conn: socket.socket | None = None
        self._sink = PacketSink()
        self.mav = mavlink.MAVLink(self._sink, srcSystem=1, srcComponent=SIM_COMPONENT_ID)
        self.mav.robust_parsing = True
        self.commands = (0.0, 0.0, 0.0, 0.0)
        self.armed = False
        self.lockstep = False
        self.actuator_msgs = 0
        self.bootstrap_steps = 0
        self.sensor_msgs = 0
        self.gps_msgs = 0
        self.other_msgs = 0
        self._said_not_lockstep = False
        #: the lockstep flag of the last HIL_ACTUATOR_CONTROLS (logged with the steps it flies).
        self._lockstep_flag = False
        self._gps_every = max(1, int(round(options.rate_hz / GPS_RATE_HZ)))
        self._steps = 0

    @property
    def t_us(self) -> int:
        return self._steps * self.period_us

    def counters(self) -> dict[str, Any]:
        return {"actuator_msgs": self.actuator_msgs, "bootstrap_steps": self.bootstrap_steps, "sensor_msgs": self.sensor_msgs,
                "gps_msgs": self.gps_msgs, "other_msgs": self.other_msgs, "lockstep": self.lockstep}  # fmt: skip

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.listener.close()

    # -- out ---------------------------------------------------------------------------------------
    def _sensors(self) -> bytes:
        """HIL_SENSOR + HIL_STATE_QUATERNION (+ HIL_GPS when due) of the state now, packed."""
        plant = self.plant
        obs = plant.observe()
        truth = plant.truth()
        mav = self.mav
        t_us = self.t_us
        gyro, accel = imu_frd(obs, truth, self.gravity)
        mag = flu_to_frd(quat_rotate_inverse(truth.quaternion, ned_to_nwu(MAG_FIELD_NED_GAUSS)))
        pos_ned = nwu_to_ned(obs.position_m)
        alt = self.home.alt_m - pos_ned[2]
        fields = MAG_BITS
        if all(math.isfinite(v) for v in gyro):
            fields |= GYRO_BITS
        else:
            gyro = (0.0, 0.0, 0.0)
        if all(math.isfinite(v) for v in accel):
            fields |= ACCEL_BITS
        else:
            accel = (0.0, 0.0, 0.0)
        if math.isfinite(alt):
            fields |= BARO_BITS
            pressure, temp = isa_pressure_hpa(alt), 15.0 - 0.0065 * alt
        else:
            pressure, temp, alt = 0.0, 15.0, 0.0
        mav.send(mav.hil_sensor_encode(t_us, *accel, *gyro, *mag, pressure, 0.0, alt, temp, fields, 0))
        self.sensor_msgs += 1
        # the truth, as PX4 takes it (ground truth topics)
        t_ned = nwu_to_ned(truth.position_m)
        v_ned = nwu_to_ned(truth.velocity_mps)
        lat, lon, alt_t = ned_to_global(self.home, *t_ned)
        f_true = imu_frd(truth, truth, self.gravity)[1]
        speed = math.sqrt(v_ned[0] ** 2 + v_ned[1] ** 2 + v_ned[2] ** 2)
        mav.send(mav.hil_state_quaternion_encode(
            t_us, quat_nwu_flu_to_ned_frd(truth.quaternion), *rates_flu_to_frd(*truth.body_rates_radps),
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt_t * 1000.0)),
            _i16(v_ned[0] * 100.0), _i16(v_ned[1] * 100.0), _i16(v_ned[2] * 100.0),
            min(int(speed * 100.0), 65535), min(int(speed * 100.0), 65535),
            _i16(f_true[0] / 9.80665 * 1000.0), _i16(f_true[1] / 9.80665 * 1000.0), _i16(f_true[2] / 9.80665 * 1000.0),
        ))  # fmt: skip
        if self._steps % self._gps_every == 0:
            vel = nwu_to_ned(obs.velocity_mps)
            if all(math.isfinite(v) for v in (*pos_ned, *vel)):
                lat, lon, alt_g = ned_to_global(self.home, *pos_ned)
                ground = math.hypot(vel[0], vel[1])
                cog = int(round(math.degrees(math.atan2(vel[1], vel[0])) % 360.0 * 100.0)) % 36000 if ground > 0.2 else 65535
                mav.send(mav.hil_gps_encode(
                    t_us, 3, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt_g * 1000.0)), 30, 40,
                    min(int(ground * 100.0), 65535), _i16(vel[0] * 100.0), _i16(vel[1] * 100.0), _i16(vel[2] * 100.0), cog, 10,
                ))  # fmt: skip
                self.gps_msgs += 1
        return self._sink.take()

    def _send_sensors(self) -> None:
        assert self.conn is not None
        try:
            self.conn.sendall(self._sensors())
        except (BrokenPipeError, ConnectionResetError):
            raise WatchdogError("PX4 closed the connection; stopping") from None
        except TimeoutError:
            raise WatchdogError(f"PX4 has read nothing for {self.options.watchdog_s:g} s (its receive buffer is full); stopping") from None
        except OSError as exc:
            raise WatchdogError(f"the connection to PX4 broke ({exc.strerror or exc}); stopping") from None

    def _step(self) -> None:
        self.step_plant(self.t_us * 1e-6, self.period_us * 1e-6, self.commands, self.armed, self._lockstep_flag)
        self._steps += 1

    # -- in ----------------------------------------------------------------------------------------
    def on_message(self, msg: Any) -> bool:
        """Take one message; True when it is a valid HIL_ACTUATOR_CONTROLS (its commands applied)."""
        if msg.get_type() == "BAD_DATA":
            self.complaints.bad("mavlink", f"{len(msg.get_msgbuf())} bytes that are not a MAVLink message ({msg.reason})")
            return False
        if msg.get_msgId() != _ACTUATORS:
            self.other_msgs += 1
            return False
        c = tuple(msg.controls[:4])
        if not all(math.isfinite(v) for v in c):
            self.complaints.bad("nonfinite", f"HIL_ACTUATOR_CONTROLS with a non-finite motor value {list(c)} at {msg.time_usec} us")
            return False
        bad = [(i, v) for i, v in enumerate(c) if not -RANGE_TOL <= v <= 1.0 + RANGE_TOL]
        if bad:
            i, v = bad[0]
            self.complaints.bad("range", f"HIL_ACTUATOR_CONTROLS with controls[{i}] = {v:g}, outside [0, 1] (motors are 0..1)")
            return False
        if not msg.flags & 1 and not self._said_not_lockstep:
            self._said_not_lockstep = True
            self.say(f"{self.name}: PX4's HIL_ACTUATOR_CONTROLS lack the lockstep flag: each still steps the physics one period")
        self.commands = (min(max(c[0], 0.0), 1.0), min(max(c[1], 0.0), 1.0), min(max(c[2], 0.0), 1.0), min(max(c[3], 0.0), 1.0))
        self.armed = bool(msg.mode & _ARMED)
        self._lockstep_flag = bool(msg.flags & 1)
        self.actuator_msgs += 1
        return True

    # -- loop --------------------------------------------------------------------------------------
    def _accept(self) -> socket.socket | None:
        while not self._stop:
            ready, _, _ = select.select([self.listener], [], [], 0.1)
            if ready:
                conn, addr = self.listener.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                conn.settimeout(self.options.watchdog_s or None)
                self.say(f"{self.name}: PX4 connected from {addr[0]}:{addr[1]}")
                return conn
            self.check_silence(None, "connection from PX4")
        return None

    def _serve(self) -> None:
        self.say(f"SIM_READY serve=px4 tcp={self.address[0]}:{self.address[1]} plant={self.scenario.plant}"
                 f" rate_hz={self.options.rate_hz:g} home={self.home.lat_deg:.6f},{self.home.lon_deg:.6f},{self.home.alt_m:g}")  # fmt: skip
        self.conn = conn = self._accept()
        if conn is None:
            return
        period_s = self.period_us * 1e-6
        self.log_state()  # the vehicle at rest (the first sensors PX4 gets)
        self._send_sensors()
        next_wall = self._mono() + period_s
        last_heard: float | None = None
        while not self._stop:
            now = self._mono()
            timeout = 0.1 if self.lockstep else max(0.0, min(0.1, next_wall - now))
            ready, _, _ = select.select([conn], [], [], timeout)
            if ready:
                try:
                    data = conn.recv(65536)
                except ConnectionResetError:
                    data = b""
                except OSError as exc:
                    raise WatchdogError(f"the connection to PX4 broke ({exc.strerror or exc}); stopping") from None
                if not data:
                    raise WatchdogError("PX4 closed the connection; stopping")
                for msg in self.mav.parse_buffer(data) or ():
                    if not self.on_message(msg):
                        continue
                    if not self.lockstep:
                        self.lockstep = True
                        self.say(f"{self.name}: PX4 answered at t = {self.t_us * 1e-6:.3f} s: lockstep from now on")
                    last_heard = self._mono()
                    self._step()
                    self._send_sensors()
                    if self.duration_reached():
                        return
            if self.lockstep:
                self.check_silence(last_heard, "HIL_ACTUATOR_CONTROLS from PX4")
                continue
            self.check_silence(None, "HIL_ACTUATOR_CONTROLS from PX4")
            now = self._mono()
            if now >= next_wall:  # before PX4's first answer: real time, rotors stopped
                self._step()
                self.bootstrap_steps += 1
                self._send_sensors()
                next_wall = max(next_wall + period_s, now - 1.0)
                if self.duration_reached():
                    return
