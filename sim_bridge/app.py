"""The simulator-bridge process: integrates a plant and talks MAVLink to the flight controller.

Each control tick it sends the vehicle state as one datagram holding ``ATTITUDE``, ``HIGHRES_IMU``,
``ODOMETRY`` and ``LOCAL_POSITION_NED`` (in that order, all stamped with simulated time):

- ``ATTITUDE`` + ``LOCAL_POSITION_NED`` (NED/FRD, ``time_boot_ms``): the sensed state the FC flies on;
- ``HIGHRES_IMU`` (``time_usec``): the sensed IMU, body FRD: specific force ``xacc``..``zacc``
  (m/s^2, about (0, 0, -9.81) level at rest) and the gyro ``xgyro``..``zgyro`` (rad/s, the
  rates of ``ATTITUDE``), with the environment's sensor noise and the accelerometer and gyro
  faults (a dropout is NaN in that sensor's fields); ``fields_updated``
  :data:`smcpilot.protocol.IMU_FIELDS_UPDATED` (:func:`sim_bridge.sensors.imu_frd` converts);
- ``ODOMETRY`` (``time_usec``): the plant's true state, for the log and for scoring only (the FC
  never flies on it): position and velocity NED (m, m/s, the local frame of the state), the
  attitude quaternion (FRD body in NED), body rates FRD (rad/s); covariances unknown (NaN),
  ``estimator_type`` MOCAP.

It applies the motor
commands of ``HIL_ACTUATOR_CONTROLS``: controls[0..3] in [0, 1] are rotors 1..4 (1 right,
2 front, 3 left, 4 rear), thrust-linear above idle (``w^2 = w_idle^2 + c (w_max^2 - w_idle^2)``,
:mod:`smcpilot.actuators`); ``mode`` with MAV_MODE_FLAG_SAFETY_ARMED spins the rotors, without it
they stop; ``flags`` bit 0 marks a lockstep FC.

- **lockstep**: send the state at t, wait for the actuator message stamped t (re-sending the same
  bytes if it does not come: after 4x the running mean round trip, at least ``resend_min_s``,
  doubling up to ``resend_s``), integrate one control period, repeat. As fast as possible, or at
  most ``speed`` times real time. A flight controller silent for ``watchdog_s`` wall seconds
  ends the bridge with an error (exit 3).
- **real time**: physics at ``physics_hz`` on the wall clock (times ``speed``), state out at
  ``rate_hz``, the latest motor commands held between messages.

Motor commands and parameters are taken from the FC's address only (others counted in
``foreign_msgs``); a NaN or infinite motor value is counted (``nonfinite_actuator_msgs``) and that
motor keeps its last command. A dead FC (its port closed, reported by the OS) ends the bridge at
once (exit 3); a clean end sends ``HEARTBEAT`` with ``MAV_STATE_POWEROFF`` so the FC stops too.

Faults (:mod:`sim_bridge.faults`, the plant's ``faults``): the state sent is the faulty sensors'
(a dropped-out sensor's fields are NaN: gyro -> rollspeed/pitchspeed/yawspeed, attitude ->
roll/pitch/yaw, position -> x/y/z, velocity -> vx/vy/vz); every fault start and stop goes to the FC
as ``STATUSTEXT`` (WARNING for a start, INFO for a stop, ``SIM: motor 1 at 70%``). Live ``SIM_*``
parameters (:data:`smcpilot.faults.SIM_PARAMS`): a ``PARAM_SET`` addressed to this component is
applied at the simulated time of the state last sent (lockstep: before integrating the next
period; messages are handled in arrival order, also those that come while the bridge waits for
the actuator message) and answered with ``PARAM_VALUE`` (the value in force; param_count =
len(SIM_PARAMS), param_index = its position); a refused value is answered with the old value and a
``STATUSTEXT`` (ERROR) giving the reason. ``PARAM_REQUEST_READ`` and ``PARAM_REQUEST_LIST`` for
this component are answered with ``PARAM_VALUE`` too.
"""

from __future__ import annotations

import gc
import json
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TextIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.faults import SEVERITY_REJECTED, SimFaults
from sim_bridge.plants.base import Plant
from sim_bridge.proximity import Proximity
from sim_bridge.sensors import specific_force_frd
from sim_bridge.state_encoder import DATAGRAM_MAX_BYTES
from smcpilot.errors import DivergenceError, WatchdogError
from smcpilot.fastcodec import TickRecords, decode_actuator_datagram
from smcpilot.faults import SIM_PARAM_INDEX, SIM_PARAMS, FaultError
from smcpilot.frames import quat_nwu_flu_to_ned_frd
from smcpilot.jit import AUTO_MIN_LOCKSTEP_S, compile_in_background
from smcpilot.link import MavlinkUdp
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.udplink.readiness import Readiness
from smcpilot.wire import wire_of_paper

if TYPE_CHECKING:
    from sim_bridge.plants.compiled_physics import CompiledPhysics

#: Component id the bridge sends from (a sensor-ish component of the vehicle's system).
SIM_COMPONENT = SIM_COMPONENT_ID
EXIT_OK = 0
EXIT_WATCHDOG = 3
EXIT_DIVERGED = 4
#: copies of the closing HEARTBEAT (MAV_STATE_POWEROFF) sent at a clean end.
GOODBYE_COPIES = 4
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_ACTUATORS = mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
_PARAM_SET = mavlink.MAVLINK_MSG_ID_PARAM_SET
_PARAM_READ = mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ
_PARAM_LIST = mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST
_REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
_yield = getattr(os, "sched_yield", lambda: None)
_isfinite = math.isfinite
#: ODOMETRY's covariances: unknown (NaN in the first element, as MAVLink says).


class _Answer:
    """A flight controller's answer (HIL_ACTUATOR_CONTROLS) decoded straight to the values the
    bridge reads (:func:`smcpilot.fastcodec.decode_actuator_datagram`), in place of pymavlink's message."""

    __slots__ = ("time_usec", "controls", "mode")
    id = mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS

    def __init__(self, time_usec: int, controls: tuple[float, ...], mode: int) -> None:
        self.time_usec = time_usec
        self.controls = controls
        self.mode = mode


@dataclass(frozen=True)
class BridgeTiming:
    """Rates and limits of the bridge."""

    physics_hz: float = 1000.0
    rate_hz: float = 500.0
    lockstep: bool = False
    #: at most this many times real time (lockstep), or the real-time clock's speed; None = unlimited (lockstep).
    speed: float | None = None
    duration_s: float | None = None
    watchdog_s: float = 5.0
    startup_timeout_s: float = 30.0
    #: lockstep: re-send the state if no answer came for this long (wall seconds): at most this
    #: long, at least ``resend_min_s``; in between 4 times the running mean round trip, doubled
    #: on each further re-send of the same state.
    resend_s: float = 0.25
    resend_min_s: float = 0.001
    #: lockstep: busy-poll this long for the FC's answer before blocking, s (0: always block).
    spin_s: float = 0.002

    @property
    def substeps(self) -> int:
        return int(round(self.physics_hz / self.rate_hz))

    @property
    def period_us(self) -> int:
        return int(round(1e6 / self.rate_hz))


class SimVehicle:
    """One simulated vehicle of the bridge: its plant, its link to its own flight controller, its
    motor commands and its counters. The bridge steps every vehicle on one clock."""

    def __init__(self, plant: Plant, *, fc_url: str, system_id: int, clock_us: Callable[[], int],
                 offset_ne_m: tuple[float, float] = (0.0, 0.0)) -> None:  # fmt: skip
        self.plant = plant
        self.system_id = system_id
        #: where this vehicle's local frame lies from the swarm's home (north, east, m).
        self.offset_ne_m = offset_ne_m
        self.link = MavlinkUdp(
            fc_url, source_system=system_id, source_component=SIM_COMPONENT, accept_system=system_id,
            clock_us=clock_us,
        )  # fmt: skip
        self.link.report_peer_errors()
        self._clock_us = clock_us
        self._records = TickRecords(system_id)
        self._gravity = float(plant.vehicle.gravity_mps2)  # type: ignore[attr-defined]
        self._truth = plant.truth  # type: ignore[attr-defined]
        #: the FC's address: motor commands and parameters are taken from it only.
        self.fc_addr = self.link.peers[0]
        #: the FC's answers decoded straight to values (:meth:`receive`)
        self._fast_answers = self.link.signing is None and self.link.impair_counters is None
        self.faults: SimFaults | None = getattr(plant, "faults", None)
        self.commands = (0.0, 0.0, 0.0, 0.0)
        self.armed = False
        self.resends = 0
        self.params_set = 0
        self.params_rejected = 0
        self.actuator_msgs = 0
        self.stale_actuator_msgs = 0
        #: messages from another address than the FC's, dropped.
        self.foreign_msgs = 0
        #: actuator messages with a NaN or infinite motor value (that motor keeps its last command).
        self.nonfinite_actuator_msgs = 0
        self.last_state: tuple[bytes, ...] = ()
        #: the state datagram's compiled encoder (:mod:`sim_bridge.state_encoder`; None: CPython makes it).
        self.encoder: Any = None
        #: lockstep: when the state was last sent (wall s), when first sent, the re-send interval;
        #: ``last_answer``: its last answer, or the last new state sent to it (the watchdog counts from it).
        self.sent_at = 0.0
        self.first_sent = 0.0
        self.resend_after = 0.0
        self.last_answer = 0.0
        self.answered = False
        #: in a swarm: the vehicle crashed into another (its motors stopped for good).
        self.crashed = False
        #: lockstep: messages that came after this vehicle's answer, acted on from the next state.
        self.deferred: list = []
        #: lockstep, a swarm: the simulated time of the state last sent to this vehicle (µs), and its
        #: answer to it with what came after, held while other vehicles are a step behind.
        self.t_us = 0
        self.held: list = []

    @property
    def name(self) -> str:
        return f"vehicle {self.system_id}"

    def receive(self) -> list:
        """What waits on this vehicle's link, as (message, address) in arrival order, without
        waiting. The FC's answers are decoded straight to values (:class:`_Answer`; an unsigned,
        unimpaired link); anything else goes through the link's full parse, counted and checked."""
        link = self.link
        if not self._fast_answers:
            return link.recv(0.0)
        out: list = []
        fc_addr, sysid = self.fc_addr, self.system_id
        for data, addr in link.recv_datagrams():
            if addr == fc_addr:
                values = decode_actuator_datagram(data, sysid)
                if values is not None:
                    link.heard(addr, 1)
                    out.append((_Answer(values[0], values[2], values[3]), addr))
                    continue
            out.extend(link.parse(data, addr))
        return out

    # -- wire ------------------------------------------------------------------------------------
    def send_state(self) -> None:
        """The state now to this vehicle's FC (:meth:`make_state`, then sent; the faults' news after it)."""
        self.make_state()
        self.send_made()

    def fast_states_ok(self) -> bool:
        """The link sends a state's four packets as one datagram, unchanged (unsigned, unimpaired,
        not logged): the compiled encoder may make that datagram itself."""
        link = self.link
        return self._fast_answers and not link.logged and link.max_datagram_bytes >= DATAGRAM_MAX_BYTES

    def send_made(self) -> None:
        """The state :meth:`make_state` made, to the FC, then the faults' news (STATUSTEXT)."""
        self.link.send_packets(self.last_state)
        faults = self.faults
        if faults is not None and faults.events:
            self.announce()

    def make_state(self) -> None:
        """Encode the state now (``last_state``: ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED),
        not yet sent: in real time a swarm's simulator makes every vehicle's first, then sends them
        in one burst (a sleeping FC process is woken once for several, not once each). In lockstep
        each goes out as soon as it is made (:meth:`send_state`): its FC, busy-polling on the other
        core, works while the next is made (measured faster, docs/swarms.md)."""
        obs = self.plant.observe()
        tru = self._truth()
        link = self.link
        t_us = self._clock_us()
        enc = self.encoder
        if enc is not None and obs.accel_mps2 is not None:  # compiled: the same bytes in one call
            enc.vin[:] = (*obs.euler_rad, *obs.body_rates_radps, *obs.position_m, *obs.velocity_mps, *obs.accel_mps2,
                          *tru.quaternion, *tru.euler_rad, *tru.body_rates_radps, *tru.position_m, *tru.velocity_mps,
                          self._gravity)  # fmt: skip
            data = enc.encode(t_us, link.peek_seq())
            if data is not None:  # (else a NaN or a value beyond float32: made below, as always)
                for _ in range(4):
                    link.take_seq()
                self.last_state = (data,)
                return
        t_ms = (t_us // 1000) & 0xFFFFFFFF
        (phi, theta, psi), (pf, qf, rf), (xw, yw, zw), (vxw, vyw, vzw) = obs.euler_rad, obs.body_rates_radps, obs.position_m, obs.velocity_mps
        roll, pitch, yaw, p, q, r, x, y, z, vx, vy, vz = wire_of_paper(phi, theta, psi, pf, qf, rf, xw, yw, zw, vxw, vyw, vzw)
        fx, fy, fz = specific_force_frd(obs.accel_mps2, tru.quaternion, self._gravity)
        (phi, theta, psi), (pf, qf, rf), (xw, yw, zw), (vxw, vyw, vzw) = tru.euler_rad, tru.body_rates_radps, tru.position_m, tru.velocity_mps
        _, _, _, tp, tq, tr, tx, ty, tz, tvx, tvy, tvz = wire_of_paper(phi, theta, psi, pf, qf, rf, xw, yw, zw, vxw, vyw, vzw)
        # The per-tick messages, encoded straight to bytes (smcpilot.fastcodec.TickRecords: the same
        # bytes as pymavlink); the state's pair last, so the FC has the IMU when the state ticks it.
        rec = self._records
        qw, qx, qy, qz = quat_nwu_flu_to_ned_frd(tru.quaternion)
        packets = (
            rec.attitude(link.take_seq(), t_ms, roll, pitch, yaw, p, q, r),
            rec.highres_imu(link.take_seq(), t_us, fx, fy, fz, p, q, r),
            rec.odometry(link.take_seq(), t_us, tx, ty, tz, qw, qx, qy, qz, tvx, tvy, tvz, tp, tq, tr),
            rec.local_position_ned(link.take_seq(), t_ms, x, y, z, vx, vy, vz),
        )
        self.last_state = packets

    def fly_and_make(self, phys: CompiledPhysics, t_us0: int, dt_us: int, dt_s: float, n_steps: int) -> bool:
        """Fly the plant ``n_steps`` physics steps of ``dt_s`` s from ``t_us0`` µs (``dt_us`` apart) and
        make its state (stamped with the clock, which already reads the end of the span) in one
        compiled call (:meth:`CompiledPhysics.fly_state`): what ``phys.fly`` then :meth:`make_state`
        leave, the same bytes. False: not flown (nothing changed; fly and make it as before).
        Raises :class:`DivergenceError` as ``phys.fly``."""
        enc = self.encoder
        if enc is None:
            return False
        link = self.link
        got = phys.fly_state(self.plant, self.commands, self.armed, t_us0, dt_us, dt_s, n_steps, enc, self._gravity, self._clock_us(),
                             link.peek_seq())  # fmt: skip
        if got is None:  # flown and observed; the datagram is CPython's to make (a sensor fault, float32)
            self.make_state()
        elif got.__class__ is str:
            return False
        else:
            for _ in range(4):
                link.take_seq()
            self.last_state = (got,)  # type: ignore[assignment]
        return True

    def say_goodbye(self) -> None:
        """A clean end: HEARTBEAT with MAV_STATE_POWEROFF (a few copies: the link may lose some), so
        the FC stops cleanly instead of taking the closed port for a dead simulator."""
        mav = self.link.mav
        hb = mav.heartbeat_encode(mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_POWEROFF)
        for _ in range(GOODBYE_COPIES):  # one datagram each (sending never raises)
            self.link.send(hb)

    def announce(self) -> None:
        """Every fault start/stop (and refusal) since the last call, as STATUSTEXT to the FC."""
        assert self.faults is not None
        for ev in self.faults.take_events():
            self.say(ev.severity, ev.text)

    def say(self, severity: int, text: str) -> None:
        """One STATUSTEXT to this vehicle's FC (which relays it to its ground stations)."""
        self.link.send(self.link.mav.statustext_encode(severity, text[:50].encode("ascii", "replace")))

    # -- live simulator parameters ------------------------------------------------------------------
    def _for_me(self, msg: mavlink.MAVLink_message) -> bool:
        return msg.target_system in (0, self.system_id) and msg.target_component in (0, SIM_COMPONENT)

    def _param_value(self, name: str) -> mavlink.MAVLink_message:
        assert self.faults is not None
        return self.link.mav.param_value_encode(
            name.encode("ascii"), self.faults.param_value(name), _REAL32, len(SIM_PARAMS), SIM_PARAM_INDEX[name]
        )

    def on_param(self, msg: mavlink.MAVLink_message) -> None:
        """PARAM_SET / PARAM_REQUEST_READ / PARAM_REQUEST_LIST addressed to the simulator."""
        if not self._for_me(msg):
            return
        faults = self.faults
        t_s = self._clock_us() * 1e-6
        mid = msg.id
        if faults is None:
            if mid == _PARAM_SET:
                self.params_rejected += 1
                self.link.send(self.link.mav.statustext_encode(SEVERITY_REJECTED, b"SIM: this plant takes no live parameters"))
            return
        if mid == _PARAM_LIST:
            self.link.send_many(self._param_value(p.name) for p in SIM_PARAMS)
            return
        if mid == _PARAM_READ:
            idx = msg.param_index
            name = SIM_PARAMS[idx].name if 0 <= idx < len(SIM_PARAMS) else msg.param_id
            if name in SIM_PARAM_INDEX:
                self.link.send(self._param_value(name))
            else:
                faults.reject(t_s, f"unknown parameter {name}")
                self.announce()
            return
        name = msg.param_id
        try:
            faults.set_param(name, msg.param_value, t_s)
        except FaultError as exc:
            self.params_rejected += 1
            faults.reject(t_s, str(exc).split(" (known:")[0].replace("unknown simulator parameter", "unknown parameter"))
        else:
            self.params_set += 1
        if name in SIM_PARAM_INDEX:
            self.link.send(self._param_value(name))
        self.announce()

    def apply(self, msg: mavlink.MAVLink_hil_actuator_controls_message) -> None:
        c = msg.controls
        c0, c1, c2, c3 = c[0], c[1], c[2], c[3]
        if not (_isfinite(c0) and _isfinite(c1) and _isfinite(c2) and _isfinite(c3)):
            self.nonfinite_actuator_msgs += 1  # counted; the motor holds its last command
            old = self.commands
            c0, c1, c2, c3 = (new if _isfinite(new) else prev for new, prev in zip((c0, c1, c2, c3), old))
        self.commands = (c0, c1, c2, c3)
        self.armed = bool(msg.mode & _ARMED)
        self.actuator_msgs += 1

    def crash(self, t_s: float, other: SimVehicle, distance_m: float) -> None:
        """Contact with ``other``: every motor of this vehicle stops for good (SIM_MOT_OFF = 15,
        announced as the fault it is), and the FC hears why."""
        if self.crashed:
            return
        self.crashed = True
        self.say(mavlink.MAV_SEVERITY_CRITICAL, f"SIM: contact with vehicle {other.system_id} ({distance_m:.2f} m)")
        if self.faults is not None:
            self.faults.set_param("SIM_MOT_OFF", 15.0, t_s)
            self.announce()

    def position_ned_m(self) -> tuple[float, float, float]:
        """The true position in the swarm's frame: NED, m, from the swarm's home."""
        x, y, z = self._truth().position_m
        return (x + self.offset_ne_m[0], -y + self.offset_ne_m[1], -z)

    def summary(self) -> dict:
        return {
            "system_id": self.system_id,
            "actuator_msgs": self.actuator_msgs,
            "stale_actuator_msgs": self.stale_actuator_msgs,
            "resends": self.resends,
            "foreign_msgs": self.foreign_msgs,
            "nonfinite_actuator_msgs": self.nonfinite_actuator_msgs,
            "params_set": self.params_set,
            "params_rejected": self.params_rejected,
            "faults_started": self.faults.started if self.faults is not None else 0,
            "faults_stopped": self.faults.stopped if self.faults is not None else 0,
            "crashed": self.crashed,
            "link": self.link.counters.as_dict(),
        }


class SimBridgeApp:
    """The simulator process: one or more vehicles (a swarm) stepped on one clock.

    In lockstep the world advances one control period only when every vehicle's FC has answered
    the state stamped with the current time, so a swarm is as deterministic as one vehicle and no
    vehicle's clock runs ahead of another's; in real time every plant integrates on the same
    physics clock. A vehicle's FC that dies or falls silent ends a lockstep run with a message
    naming the vehicle; in real time the others fly on, and that vehicle's plant is dealt with as
    ``lost`` says (:data:`smcpilot.swarm.LOST_POLICIES`: its motors stop, by default, as they do
    when the ESCs lose their signal; or they hold their last commands; or the plant is removed).
    """

    def __init__(
        self,
        plant: Plant | None = None,
        *,
        fc_url: str | None = None,
        timing: BridgeTiming,
        system_id: int = 1,
        vehicles: Sequence[tuple[Plant, str, int, tuple[float, float]]] = (),
        proximity: Proximity | None = None,
        lost: str = "stop",
        jit: str = "off",
        freeze_gc: bool = False,
        out: TextIO = sys.stdout,
        monotonic: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        """One vehicle (``plant``, ``fc_url``, ``system_id``) or many (``vehicles``: (plant, FC
        URL, system id, spawn offset north/east m) each, with ``proximity`` checking their separation).
        ``jit``: the physics compiled (:mod:`sim_bridge.plants.compiled_physics`) as ``--jit`` says
        (:data:`smcpilot.jit.JIT_POLICIES`; ``off``, the default here: stepped in Python).
        ``freeze_gc``: once started, move every object made so far out of the garbage collector's
        sight (``gc.freeze``; the process's entry point does: the collector then need not scan
        numba's and pymavlink's objects again and again during the flight)."""
        self.timing = timing
        self.out = out
        self._mono = monotonic
        self._sleep = sleep
        self._t_us = 0
        specs = list(vehicles)
        if plant is not None:
            if fc_url is None:
                raise ValueError("a plant needs its fc_url")
            specs.insert(0, (plant, fc_url, system_id, (0.0, 0.0)))
        if not specs:
            raise ValueError("no vehicle to simulate")
        self.vehicles: list[SimVehicle] = []
        clock = self._clock_us
        try:
            for p, url, sid, offset in specs:
                self.vehicles.append(SimVehicle(p, fc_url=url, system_id=sid, clock_us=clock, offset_ne_m=offset))
        except BaseException:
            for v in self.vehicles:
                v.link.close()
            raise
        self.proximity = proximity if len(self.vehicles) > 1 else None
        #: real time, a swarm: what happens to a vehicle whose FC is gone (smcpilot.swarm.LOST_POLICIES).
        self.lost = lost
        #: vehicles taken out of the world ("remove"): no physics, no separation checks.
        self._removed: set[SimVehicle] = set()
        #: every vehicle's link's file descriptor, in the vehicles' order (made at the first receive)
        self._fds: list[int] = []
        self._vehicle_of_fd: dict[int, SimVehicle] = {}
        #: the vehicles' links polled (epoll where there is one: :class:`smcpilot.udplink.readiness.Readiness`).
        self._readiness = Readiness()
        #: lockstep: running mean round trip state -> answer (the slowest vehicle's), wall s.
        self.rtt_s = 0.0
        #: real time, a swarm: wall seconds from the first vehicle's state to the last one's, each period.
        self._fanout_s: list[float] = []
        self._stop = False
        self._exit = EXIT_OK
        self._wall_start = 0.0
        self.jit = jit
        self._freeze_gc = freeze_gc
        #: the compiled physics once loaded (:meth:`_attach_physics`), why not, and the physics steps
        #: it handed back to Python (something drawn or timed acted on the physics).
        self.physics: CompiledPhysics | None = None
        self.physics_why: str | None = "not started"
        self.physics_python_steps = 0
        #: lockstep swarm: the states made with their physics span in one call (:mod:`sim_bridge.fused_state`).
        self.states_fused = 0
        #: lockstep, a swarm sent states ahead (:meth:`_run_lockstep_swarm`): the states sent while
        #: another vehicle was a period behind, and the answers held until it caught up.
        self.ahead_counts: dict[str, int] | None = None

    def _clock_us(self) -> int:
        return self._t_us

    # The single vehicle's parts, by their names of a one-vehicle bridge.
    @property
    def plant(self) -> Plant:
        return self.vehicles[0].plant

    @property
    def link(self) -> MavlinkUdp:
        return self.vehicles[0].link

    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def _attach_physics(self) -> None:
        """The physics compiled as ``--jit`` says (the FC's rule: under ``auto``, when cached and
        not in a short lockstep flight; not cached, compiled in the background for later runs)."""
        tm = self.timing
        if self.jit == "off":
            self.physics_why = "--jit off"
            return
        # (a swarm's physics is one call for every vehicle: what it saves grows with their number)
        if self.jit == "auto" and tm.lockstep and tm.duration_s is not None and tm.duration_s * len(self.vehicles) < AUTO_MIN_LOCKSTEP_S:
            self.physics_why = (f"--jit auto: a lockstep flight shorter than {AUTO_MIN_LOCKSTEP_S:g} vehicle-seconds"
                                " (loading costs more than it saves)")  # fmt: skip
            return
        from sim_bridge.plants import compiled_physics

        self.physics, why = compiled_physics.load([v.plant for v in self.vehicles], compile_new=self.jit == "wait")
        self.physics_why = why
        if why is None:
            from sim_bridge.state_encoder import compiled_encoder

            for v in self.vehicles:
                if v.fast_states_ok():
                    v.encoder = compiled_encoder(v.system_id, compile_new=self.jit == "wait")
            missing = any(v.encoder is None for v in self.vehicles if v.fast_states_ok())
            if self.physics is not None and tm.lockstep and tm.spin_s > 0.0 and len(self.vehicles) > 1 and any(v.encoder is not None for v in self.vehicles):
                # (a lockstep swarm flies each vehicle and makes its state in one call: the same bytes)
                from sim_bridge.fused_state import compiled_fused

                self.physics.fused = compiled_fused(compile_new=self.jit == "wait")
                missing = missing or self.physics.fused is None
            if self.proximity is not None:  # (the separation check's distances, compiled: the same values)
                from sim_bridge.proximity import compiled_pair_distances

                self.proximity.kernel = compiled_pair_distances(compile_new=self.jit == "wait")
                missing = missing or self.proximity.kernel is None
            if self.jit == "auto" and missing:
                compile_in_background("sim_bridge.plants.compiled_physics")  # (it caches the encoder and the distances too)
        if why is None or why == "no rigid-body plant":
            return
        note = f"sim: the physics is stepped in Python: {why}"
        if self.jit == "auto" and why.endswith("not cached yet"):
            pid = compile_in_background("sim_bridge.plants.compiled_physics")
            if pid is not None:
                note += f"; compiling it in the background (pid {pid}) for the next runs"
        self.say(note)

    def _integrate(self, n_steps: int) -> None:
        dt = 1.0 / self.timing.physics_hz
        dt_us = int(round(dt * 1e6))
        vehicles = [v for v in self.vehicles if v not in self._removed] if self._removed else self.vehicles
        phys = self.physics
        if phys is not None:
            try:
                why = phys.fly([v.plant for v in vehicles], [v.commands for v in vehicles], [v.armed for v in vehicles],
                               self._t_us, dt_us, dt, n_steps)  # fmt: skip
            except DivergenceError as exc:  # as the Python steps leave it: the clock at the failing step
                self._t_us += exc.steps_done * dt_us  # type: ignore[attr-defined]
                raise
            if why is None:
                self._t_us += n_steps * dt_us
                return
            self.physics_python_steps += n_steps
        if len(vehicles) == 1:
            v = vehicles[0]
            step, cmds, armed = v.plant.step, v.commands, v.armed
            for _ in range(n_steps):
                step(self._t_us * 1e-6, dt, cmds, armed)
                self._t_us += dt_us
            return
        for _ in range(n_steps):
            t_s = self._t_us * 1e-6
            for v in vehicles:
                v.plant.step(t_s, dt, v.commands, v.armed)
            self._t_us += dt_us

    def _check_proximity(self) -> None:
        prox = self.proximity
        if prox is None:
            return
        vehicles = self.vehicles
        t_s = self._t_us * 1e-6
        far = (1e9, 1e9, 1e9)  # a removed vehicle: out of everyone's way
        positions = [far if v in self._removed else v.position_ned_m() for v in vehicles]
        for kind, i, j, dist in prox.check(t_s, positions):
            a, b = vehicles[i], vehicles[j]
            if kind == "contact":
                self.say(f"sim: vehicles {a.system_id} and {b.system_id} touched at t = {t_s:.3f} s ({dist:.2f} m apart): both crash")
                a.crash(t_s, b, dist)
                b.crash(t_s, a, dist)
            else:
                text = f"SIM: vehicles {a.system_id} and {b.system_id} within {dist:.1f} m"
                a.say(mavlink.MAV_SEVERITY_WARNING, text)
                b.say(mavlink.MAV_SEVERITY_WARNING, text)

    def _recv(self, timeout_s: float) -> list[tuple[SimVehicle, list]]:
        """Messages from every vehicle's link (waiting at most ``timeout_s`` for the first)."""
        vehicles = self.vehicles
        if len(vehicles) == 1 and not vehicles[0]._fast_answers:
            v = vehicles[0]
            return [(v, v.link.recv(timeout_s))]
        fds = self._fds
        if len(fds) != len(vehicles):
            fds = self._fds = [v.link.fileno() for v in vehicles]
            self._vehicle_of_fd = {fd: v for fd, v in zip(fds, vehicles)}
            self._readiness.watch(fds)
        try:
            ready = self._readiness.wait(timeout_s)
        except (OSError, ValueError):
            ready = fds
        if not ready:
            return []
        of = self._vehicle_of_fd
        if len(ready) == 1:
            v = of[ready[0]]
            return [(v, v.receive())]
        ready_set = set(ready)  # (in the vehicles' order)
        return [(v, v.receive()) for v, fd in zip(vehicles, fds) if fd in ready_set]

    # -- loops -----------------------------------------------------------------------------------
    def run(self) -> int:
        tm = self.timing
        v0 = self.vehicles[0]
        fcs = " ".join(f"fc={v.link.endpoint.url}" for v in self.vehicles)
        local = " ".join("local={}:{}".format(*v.link.local_address) for v in self.vehicles)
        count = f" vehicles={len(self.vehicles)}" if len(self.vehicles) > 1 else ""
        self._attach_physics()
        if self._freeze_gc:
            gc.collect()
            gc.freeze()
        self.say(f"SIM_READY {fcs} {local} lockstep={tm.lockstep} physics_hz={tm.physics_hz:g} rate_hz={tm.rate_hz:g}{count}"
                 f" pid={os.getpid()}")  # fmt: skip
        self._wall_start = self._mono()
        cpu_start = time.process_time()
        try:
            if tm.lockstep and len(self.vehicles) > 1 and tm.spin_s > 0.0:
                self._run_lockstep_swarm()
            elif tm.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        except WatchdogError as exc:
            self.say(f"sim_bridge: error: {exc}")
            self._exit = EXIT_WATCHDOG
        except (ArithmeticError, DivergenceError) as exc:
            self.say(f"sim_bridge: error: the simulation diverged at t = {self._t_us * 1e-6:.3f} s: {exc}")
            self._exit = EXIT_DIVERGED
        finally:
            wall = self._mono() - self._wall_start
            summary: dict = {"sim_time_s": self._t_us * 1e-6, "wall_s": wall, "speed": (self._t_us * 1e-6 / wall) if wall > 0 else None,
                             "rtt_mean_s": self.rtt_s, "cpu_s": round(time.process_time(), 3),
                             "cpu_start_s": round(cpu_start, 3),
                             "cpu_sys_s": round(os.times().system, 3),
                             "physics": {"compiled": self.physics is not None, "compiled_steps": self.physics.steps if self.physics else 0,
                                         "python_steps": self.physics_python_steps, "why_not": self.physics_why,
                                         "states_encoded_compiled": sum(v.encoder.made for v in self.vehicles if v.encoder is not None),
                                         "states_fused": self.states_fused}}  # fmt: skip
            if len(self.vehicles) == 1:
                summary.update(v0.summary())
                del summary["system_id"], summary["crashed"]
            else:
                per = [v.summary() for v in self.vehicles]
                summary["vehicles"] = per
                for key in ("actuator_msgs", "stale_actuator_msgs", "resends", "foreign_msgs", "nonfinite_actuator_msgs",
                            "params_set", "params_rejected", "faults_started", "faults_stopped"):  # fmt: skip
                    summary[key] = sum(p[key] for p in per)
                if self.proximity is not None:
                    summary["proximity"] = self.proximity.summary([v.system_id for v in self.vehicles])
                if self.ahead_counts is not None:  # lockstep, states sent ahead of the slowest vehicle
                    summary["ahead"] = dict(self.ahead_counts)
                if self._fanout_s:  # real time: how far apart in wall time the vehicles got the same state
                    f = sorted(self._fanout_s)
                    summary["fanout_skew_s"] = {"p50": f[len(f) // 2], "p99": f[min(len(f) - 1, int(0.99 * len(f)))], "max": f[-1]}
            self._readiness.close()
            for v in self.vehicles:
                if self._exit == EXIT_OK:
                    v.say_goodbye()
                v.link.close()
            self.say("SIM_SUMMARY " + json.dumps(summary, sort_keys=True))
        return self._exit

    def _run_lockstep(self) -> None:
        """States out, wait for every answer stamped with their time, integrate, repeat.

        Busy-polls for ``spin_s`` after sending (the answer usually comes within tens of
        microseconds; waking a blocked process costs as much again), then blocks.
        """
        tm = self.timing
        substeps = tm.substeps
        duration_us = None if tm.duration_s is None else int(round(tm.duration_s * 1e6))
        mono = self._mono
        spin_s = tm.spin_s
        vehicles = self.vehicles
        pending: set[SimVehicle] = set()

        def send_all() -> None:
            resend_after = min(tm.resend_s, max(tm.resend_min_s, 4.0 * self.rtt_s)) if self.rtt_s else tm.resend_s
            for v in vehicles:  # each state out as soon as it is made: its FC works while the next one is made
                v.send_state()
            now = mono()
            for v in vehicles:  # the watchdog counts from here (a vehicle that answered early is not blamed for a slow one)
                v.sent_at = v.first_sent = v.last_answer = now
                v.resend_after = resend_after
            pending.update(vehicles)

        send_all()
        final = False  # the last state (at the duration) is out: its answers end the run
        while not self._stop:
            now = mono()
            oldest = min(v.sent_at for v in pending) if pending else now
            wait = 0.0 if now - oldest < spin_s else min(0.05, min(v.resend_after for v in pending) if pending else 0.05)
            batches = self._recv(wait)
            for v in vehicles:
                if v.link.peer_refused:
                    if final:
                        pending.discard(v)  # a timed FC stops on the last state: its answer was lost, it is gone
                        continue
                    who = "the flight controller's port is closed" if len(vehicles) == 1 else f"the flight controller of {v.name} has closed its port"
                    raise WatchdogError(f"{who} (the FC process has died); stopping")
            for v, msgs in batches:
                v.deferred.extend(self._take_answer(v, msgs, pending, final))
            if not pending:
                if final:
                    return
                self._integrate(substeps)
                self._check_proximity()
                if duration_us is not None and self._t_us >= duration_us:
                    # The final state: a lockstep FC with the same duration stops on it. Re-sent like
                    # any other until it is answered (or the timed FC has gone), so a loss cannot cut it.
                    final = True
                if tm.speed is not None and not final:
                    ahead = self._t_us * 1e-6 / tm.speed - (mono() - self._wall_start)
                    if ahead > 0.0:
                        self._sleep(ahead)
                send_all()
                for v in vehicles:  # what came after a vehicle's answer acts from the state just sent
                    if v.deferred:
                        rest, v.deferred = v.deferred, []
                        v.deferred.extend(self._take_answer(v, rest, pending, final))
                continue
            now = mono()
            if now - oldest < spin_s:
                _yield()  # let the FCs have the cores if the machine is oversubscribed
                continue
            for v in list(pending):
                limit = tm.watchdog_s if v.answered else tm.startup_timeout_s
                if now - v.last_answer > limit:
                    what = "never answered" if not v.answered else f"has been silent for {now - v.last_answer:.1f} s"
                    who = "flight controller" if len(vehicles) == 1 else f"the flight controller of {v.name}"
                    raise WatchdogError(f"{who} {what} (lockstep watchdog {limit:g} s); stopping")
                if now - v.sent_at > v.resend_after:
                    v.resends += 1
                    # The same bytes again (a lost state or a lost answer): a copy cannot change the FC's log.
                    v.link.send_packets(v.last_state)
                    v.sent_at = now
                    v.resend_after = min(tm.resend_s, 2.0 * v.resend_after)

    def _run_lockstep_swarm(self) -> None:
        """Lockstep for several vehicles: each vehicle's next state goes out as soon as its FC has
        answered, while the others are still flying theirs.

        Every plant is at the barrier ``B`` (its FC has not yet answered the state of ``B``) or one
        control period ahead (its state of ``B + period`` sent). A vehicle whose FC answers the
        state of ``B`` is integrated one period and sent its next state at once: its FC works while
        the simulator waits for the slowest one (measured: docs/swarms.md). An answer that comes
        from a vehicle already ahead is held, with whatever came after it, until every vehicle is
        ahead: then the barrier moves a period, the vehicles' separation is checked there (a contact
        stops both vehicles' motors before either flies on), and the held answers fly. So every
        plant flies what it flies when all advance together, each vehicle's messages act from the
        same state of its own, and the logs do not depend on the order the answers came in. (The
        separation's STATUSTEXTs reach an FC after the state they were checked at, not before.)

        Flown when the simulator busy-polls (``--spin-s`` > 0). Blocking, each state sent alone
        wakes an FC's process once more, and the barrier loop (:meth:`_run_lockstep`) was the
        faster (docs/swarms.md).
        """
        tm = self.timing
        substeps = tm.substeps
        dt_s = 1.0 / tm.physics_hz
        dt_us = int(round(dt_s * 1e6))
        duration_us = None if tm.duration_s is None else int(round(tm.duration_s * 1e6))
        mono = self._mono
        spin_s = tm.spin_s
        vehicles = self.vehicles
        barrier = self._t_us
        for v in vehicles:
            v.t_us = barrier
        behind: set[SimVehicle] = set(vehicles)  # at the barrier, their FC's answer to it not yet in
        pending: set[SimVehicle] = set()  # the answer to the last state sent not yet in
        done: set[SimVehicle] = set()  # answered the final state (at the duration)
        # the physics steps of the current period: flown compiled / in Python (by any vehicle)
        flew = [False, False]

        def final(v: SimVehicle) -> bool:
            return duration_us is not None and v.t_us >= duration_us

        # [the re-send interval (from the running round trip: renewed as the barrier moves), the
        # last send (wall s): the loop busy-polls for spin_s after it]
        resend = [tm.resend_s, mono()]

        def send(v: SimVehicle, made: bool = False) -> None:
            self._t_us = v.t_us
            if made:
                v.send_made()
            else:
                v.send_state()
            v.sent_at = v.first_sent = v.last_answer = resend[1] = mono()
            v.resend_after = resend[0]
            pending.add(v)

        def integrate(v: SimVehicle) -> None:
            t_us = v.t_us
            phys = self.physics
            if phys is not None:
                try:
                    why = phys.fly([v.plant], [v.commands], [v.armed], t_us, dt_us, dt_s, substeps, count=False)
                except DivergenceError as exc:
                    self._t_us = t_us + exc.steps_done * dt_us  # type: ignore[attr-defined]
                    raise
                if why is None:
                    v.t_us = t_us + substeps * dt_us
                    flew[0] = True
                    return
            flew[1] = True
            step, cmds, armed = v.plant.step, v.commands, v.armed
            for _ in range(substeps):
                self._t_us = t_us  # (a divergence is said at the step that failed)
                step(t_us * 1e-6, dt_s, cmds, armed)
                t_us += dt_us
            v.t_us = t_us

        def fly_and_send(v: SimVehicle) -> bool:
            """:func:`integrate` and :func:`send` in one compiled call (:meth:`SimVehicle.fly_and_make`);
            False: not flown, nothing done."""
            phys = self.physics
            if phys is None or phys.fused is None or v.encoder is None:
                return False
            t_us = v.t_us
            t_end = t_us + substeps * dt_us
            self._t_us = t_end  # (the state's stamp)
            try:
                flown = v.fly_and_make(phys, t_us, dt_us, dt_s, substeps)
            except DivergenceError as exc:
                self._t_us = t_us + exc.steps_done * dt_us  # type: ignore[attr-defined]
                raise
            if not flown:
                return False
            v.t_us = t_end
            flew[0] = True
            self.states_fused += 1
            send(v, made=True)
            return True

        counts = self.ahead_counts = {"states": 0, "held": 0}

        def fly_on(v: SimVehicle, msgs: list) -> None:
            """``v``'s messages from its answer to the state at the barrier on: the answer flies it
            a period and its next state goes out; the rest act from that state."""
            self._t_us = v.t_us
            pending.add(v)  # (a held answer: its vehicle waits for it again, a moment)
            rest = self._take_answer(v, msgs, pending, final(v))
            if v in pending:  # (no answer in msgs: a stale or foreign one only)
                return
            behind.discard(v)
            if final(v):
                done.add(v)
                return
            if not fly_and_send(v):
                integrate(v)
                send(v)
            if behind:
                counts["states"] += 1
            if rest:
                take(v, rest)

        def take(v: SimVehicle, msgs: list) -> None:
            """What came from ``v``'s link, by where ``v`` is."""
            if v.held:  # ahead and answered: all of it waits for the barrier
                v.held.extend(msgs)
                return
            if v in behind:
                fly_on(v, msgs)
                return
            if v in done:
                return
            # ahead: what comes before its answer acts now; the answer and what follows wait
            self._t_us = v.t_us
            fc_addr = v.fc_addr
            for k, (msg, addr) in enumerate(msgs):
                if addr != fc_addr:
                    v.foreign_msgs += 1
                    continue
                mid = msg.id
                if mid != _ACTUATORS:
                    if mid == _PARAM_SET or mid == _PARAM_READ or mid == _PARAM_LIST:
                        v.on_param(msg)
                    continue
                if msg.time_usec != v.t_us:
                    v.stale_actuator_msgs += 1
                    continue
                if final(v):
                    self._take_answer(v, msgs[k:], pending, True)
                    done.add(v)
                    return
                v.held = msgs[k:]
                counts["held"] += 1
                v.last_answer = mono()  # (answered: the watchdog is not its)
                pending.discard(v)
                return

        for v in vehicles:
            send(v)
        while not self._stop:
            now = mono()
            spinning = now - resend[1] < spin_s
            wait = 0.0 if spinning else min(0.05, min(v.resend_after for v in pending) if pending else 0.05)
            batches = self._recv(wait)
            if batches or wait > 0.0:
                for v in vehicles:
                    if v.link.peer_refused and v not in done:
                        if final(v) and v in pending:
                            pending.discard(v)  # a timed FC stops on the last state: its answer was lost, it is gone
                            behind.discard(v)
                            done.add(v)
                            continue
                        who = f"the flight controller of {v.name} has closed its port"
                        raise WatchdogError(f"{who} (the FC process has died); stopping")
            for v, msgs in batches:
                take(v, msgs)
            if len(done) == len(vehicles):
                self._t_us = max(v.t_us for v in vehicles)
                return
            if not behind:  # every vehicle a period ahead: the barrier moves
                barrier += substeps * dt_us
                self._t_us = barrier
                phys = self.physics
                if phys is not None and flew[0]:
                    phys.steps += substeps
                if flew[1]:
                    self.physics_python_steps += substeps
                flew[0] = flew[1] = False
                if self.rtt_s:
                    resend[0] = min(tm.resend_s, max(tm.resend_min_s, 4.0 * self.rtt_s))
                self._check_proximity()
                if tm.speed is not None and (duration_us is None or barrier < duration_us):
                    ahead = barrier * 1e-6 / tm.speed - (mono() - self._wall_start)
                    if ahead > 0.0:
                        self._sleep(ahead)
                behind = {v for v in vehicles if v not in done}
                for v in vehicles:
                    if v.held:
                        msgs, v.held = v.held, []
                        fly_on(v, msgs)
                continue
            now = mono()
            if now - resend[1] < spin_s:
                _yield()  # let the FCs have the cores if the machine is oversubscribed
                continue
            for v in list(pending):
                limit = tm.watchdog_s if v.answered else tm.startup_timeout_s
                if now - v.last_answer > limit:
                    what = "never answered" if not v.answered else f"has been silent for {now - v.last_answer:.1f} s"
                    raise WatchdogError(f"the flight controller of {v.name} {what} (lockstep watchdog {limit:g} s); stopping")
                if now - v.sent_at > v.resend_after:
                    v.resends += 1
                    # The same bytes again (a lost state or a lost answer): a copy cannot change the FC's log.
                    v.link.send_packets(v.last_state)
                    v.sent_at = now
                    v.resend_after = min(tm.resend_s, 2.0 * v.resend_after)

    def _take_answer(self, v: SimVehicle, msgs: list, pending: set[SimVehicle], final: bool) -> list:
        """Lockstep: handle ``v``'s messages in arrival order up to its answer to the state stamped
        now; return the ones after it (they act from the next state: the log cannot depend on how
        datagrams were batched)."""
        fc_addr = v.fc_addr
        for k, (msg, addr) in enumerate(msgs):
            if addr != fc_addr:
                v.foreign_msgs += 1
                continue
            mid = msg.id
            if mid != _ACTUATORS:
                if mid == _PARAM_SET or mid == _PARAM_READ or mid == _PARAM_LIST:
                    v.on_param(msg)
                continue
            if v not in pending:
                continue  # a duplicate answer
            if msg.time_usec != self._t_us:
                v.stale_actuator_msgs += 1
                continue
            pending.discard(v)
            if final:
                return []
            v.apply(msg)
            v.answered = True
            t_now = self._mono()
            v.last_answer = t_now
            if v.sent_at == v.first_sent:  # a clean round trip (no re-send): the running mean
                rtt = t_now - v.first_sent
                self.rtt_s += 0.05 * (rtt - self.rtt_s) if self.rtt_s else rtt
            return msgs[k + 1:]
        return []

    def _run_realtime(self) -> None:
        tm = self.timing
        speed = tm.speed or 1.0
        dt_wall = 1.0 / (tm.physics_hz * speed)
        substeps = tm.substeps
        duration_us = None if tm.duration_s is None else int(round(tm.duration_s * 1e6))
        mono = self._mono
        vehicles = self.vehicles
        alive = list(vehicles)
        start = mono()
        for v in vehicles:
            v.last_answer = start
        deadline = mono()
        k = 0
        while not self._stop:
            now = mono()
            wait = deadline - now
            if wait > 0.0:
                for v, msgs in self._recv(wait):
                    fc_addr = v.fc_addr
                    for msg, addr in msgs:
                        if addr != fc_addr:
                            v.foreign_msgs += 1
                            continue
                        mid = msg.id
                        if mid == _ACTUATORS:
                            v.apply(msg)
                            v.answered = True
                            v.last_answer = mono()
                        elif mid == _PARAM_SET or mid == _PARAM_READ or mid == _PARAM_LIST:
                            v.on_param(msg)
                for v in alive:
                    if v.link.peer_refused:
                        self._lost(v, alive, "has closed its port (the FC process has died)")
                        break
                continue
            if k % substeps == 0:
                for v in alive:
                    v.make_state()
                first = mono()
                for v in alive:
                    v.send_made()
                if len(alive) > 1:
                    self._fanout_s.append(mono() - first)
                self._check_proximity()
            self._integrate(1)
            k += 1
            deadline += dt_wall
            if now - deadline > 1.0:  # hopelessly behind (machine stalled): do not try to catch up
                deadline = now
            if duration_us is not None and self._t_us >= duration_us:
                return
            for v in alive:
                limit = tm.watchdog_s if v.answered else tm.startup_timeout_s
                if now - v.last_answer > limit:
                    what = "never answered" if not v.answered else f"has been silent for {now - v.last_answer:.1f} s"
                    self._lost(v, alive, f"{what} (real-time watchdog {limit:g} s)")
                    break

    def _lost(self, v: SimVehicle, alive: list[SimVehicle], why: str) -> None:
        """Real time: a vehicle's FC is gone. One vehicle: the run ends (WatchdogError). In a swarm
        the others fly on; that plant keeps its last commands, is said once, and is no longer sent to."""
        if len(self.vehicles) == 1:
            raise WatchdogError(f"flight controller {why}; stopping")
        alive.remove(v)
        if self.lost == "stop":
            v.commands, v.armed = (0.0, 0.0, 0.0, 0.0), False  # its ESCs lose their signal: the rotors stop
            fate = "its motors stop"
        elif self.lost == "remove":
            self._removed.add(v)
            fate = "its plant leaves the world"
        else:
            fate = "its plant holds its last motor commands"
        self.say(f"sim_bridge: warning: the flight controller of {v.name} {why}; {fate},"
                 f" the other {len(alive)} vehicle{'s' if len(alive) != 1 else ''} fly on")  # fmt: skip
        if not alive:
            raise WatchdogError("every flight controller is gone; stopping")


def install_signal_handlers(app: SimBridgeApp) -> None:
    signal.signal(signal.SIGTERM, app.request_stop)
    signal.signal(signal.SIGINT, app.request_stop)
