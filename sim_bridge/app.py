"""The simulator-bridge process: integrates a plant and talks MAVLink to the flight controller.

Each control tick it sends the vehicle state as one datagram holding ``ATTITUDE`` and
``LOCAL_POSITION_NED`` (NED/FRD, ``time_boot_ms`` = simulated time) and applies the motor
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

import json
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.faults import SEVERITY_REJECTED, SimFaults
from sim_bridge.plants.base import Plant
from smcpilot.errors import DivergenceError, WatchdogError
from smcpilot.fastcodec import encode_attitude, encode_local_position_ned
from smcpilot.faults import SIM_PARAM_INDEX, SIM_PARAMS, FaultError
from smcpilot.link import MavlinkUdp
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.wire import wire_of_paper

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


class SimBridgeApp:
    def __init__(
        self,
        plant: Plant,
        *,
        fc_url: str,
        timing: BridgeTiming,
        system_id: int = 1,
        out: TextIO = sys.stdout,
        monotonic: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.plant = plant
        self.timing = timing
        self.out = out
        self._mono = monotonic
        self._sleep = sleep
        self._t_us = 0
        self.link = MavlinkUdp(
            fc_url, source_system=system_id, source_component=SIM_COMPONENT, accept_system=system_id,
            clock_us=lambda: self._t_us,
        )  # fmt: skip
        self.link.report_peer_errors()
        #: the FC's address: motor commands and parameters are taken from it only.
        self._fc_addr = self.link.peers[0]
        self.system_id = system_id
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
        #: lockstep: running mean round trip state -> answer, wall s.
        self.rtt_s = 0.0
        self._last_state: tuple[bytes, ...] = ()
        self._stop = False
        self._exit = EXIT_OK
        self._wall_start = 0.0

    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    # -- wire ------------------------------------------------------------------------------------
    def _send_state(self) -> None:
        obs = self.plant.observe()
        link = self.link
        sysid, comp = link.source
        t_ms = (self._t_us // 1000) & 0xFFFFFFFF
        (phi, theta, psi), (pf, qf, rf), (xw, yw, zw), (vxw, vyw, vzw) = obs.euler_rad, obs.body_rates_radps, obs.position_m, obs.velocity_mps
        roll, pitch, yaw, p, q, r, x, y, z, vx, vy, vz = wire_of_paper(phi, theta, psi, pf, qf, rf, xw, yw, zw, vxw, vyw, vzw)
        # The per-tick pair, encoded straight to bytes (smcpilot.fastcodec; the same bytes as pymavlink).
        packets = (
            encode_attitude(link.take_seq(), sysid, comp, t_ms, roll, pitch, yaw, p, q, r),
            encode_local_position_ned(link.take_seq(), sysid, comp, t_ms, x, y, z, vx, vy, vz),
        )
        link.send_packets(packets)
        self._last_state = packets
        faults = self.faults
        if faults is not None and faults.events:
            self._announce()

    def _say_goodbye(self) -> None:
        """A clean end: HEARTBEAT with MAV_STATE_POWEROFF (a few copies: the link may lose some), so
        the FC stops cleanly instead of taking the closed port for a dead simulator."""
        mav = self.link.mav
        hb = mav.heartbeat_encode(mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_POWEROFF)
        for _ in range(GOODBYE_COPIES):  # one datagram each (sending never raises)
            self.link.send(hb)

    def _announce(self) -> None:
        """Every fault start/stop (and refusal) since the last call, as STATUSTEXT to the FC."""
        assert self.faults is not None
        mav = self.link.mav
        for ev in self.faults.take_events():
            self.link.send(mav.statustext_encode(ev.severity, ev.text[:50].encode("ascii", "replace")))

    # -- live simulator parameters ------------------------------------------------------------------
    def _for_me(self, msg: mavlink.MAVLink_message) -> bool:
        return msg.target_system in (0, self.system_id) and msg.target_component in (0, SIM_COMPONENT)

    def _param_value(self, name: str) -> mavlink.MAVLink_message:
        assert self.faults is not None
        return self.link.mav.param_value_encode(
            name.encode("ascii"), self.faults.param_value(name), _REAL32, len(SIM_PARAMS), SIM_PARAM_INDEX[name]
        )

    def _on_param(self, msg: mavlink.MAVLink_message) -> None:
        """PARAM_SET / PARAM_REQUEST_READ / PARAM_REQUEST_LIST addressed to the simulator."""
        if not self._for_me(msg):
            return
        faults = self.faults
        t_s = self._t_us * 1e-6
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
                self._announce()
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
        self._announce()

    def _apply(self, msg: mavlink.MAVLink_hil_actuator_controls_message) -> None:
        c = msg.controls
        c0, c1, c2, c3 = c[0], c[1], c[2], c[3]
        if not (_isfinite(c0) and _isfinite(c1) and _isfinite(c2) and _isfinite(c3)):
            self.nonfinite_actuator_msgs += 1  # counted; the motor holds its last command
            old = self.commands
            c0, c1, c2, c3 = (new if _isfinite(new) else prev for new, prev in zip((c0, c1, c2, c3), old))
        self.commands = (c0, c1, c2, c3)
        self.armed = bool(msg.mode & _ARMED)
        self.actuator_msgs += 1

    def _integrate(self, n_steps: int) -> None:
        dt = 1.0 / self.timing.physics_hz
        step = self.plant.step
        cmds = self.commands
        armed = self.armed
        for _ in range(n_steps):
            step(self._t_us * 1e-6, dt, cmds, armed)
            self._t_us += int(round(dt * 1e6))

    # -- loops -----------------------------------------------------------------------------------
    def run(self) -> int:
        tm = self.timing
        self.say(
            f"SIM_READY fc={self.link.endpoint.url} local={self.link.local_address[0]}:{self.link.local_address[1]}"
            f" lockstep={tm.lockstep} physics_hz={tm.physics_hz:g} rate_hz={tm.rate_hz:g} pid={os.getpid()}"
        )
        self._wall_start = self._mono()
        try:
            if tm.lockstep:
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
            summary = {
                "sim_time_s": self._t_us * 1e-6,
                "wall_s": wall,
                "speed": (self._t_us * 1e-6 / wall) if wall > 0 else None,
                "actuator_msgs": self.actuator_msgs,
                "stale_actuator_msgs": self.stale_actuator_msgs,
                "resends": self.resends,
                "foreign_msgs": self.foreign_msgs,
                "nonfinite_actuator_msgs": self.nonfinite_actuator_msgs,
                "rtt_mean_s": self.rtt_s,
                "params_set": self.params_set,
                "params_rejected": self.params_rejected,
                "faults_started": self.faults.started if self.faults is not None else 0,
                "faults_stopped": self.faults.stopped if self.faults is not None else 0,
                "link": self.link.counters.as_dict(),
            }
            if self._exit == EXIT_OK:
                self._say_goodbye()
            self.link.close()
            self.say("SIM_SUMMARY " + json.dumps(summary, sort_keys=True))
        return self._exit

    def _run_lockstep(self) -> None:
        """State out, wait for the answer stamped with its time, integrate, repeat.

        Busy-polls for ``spin_s`` after sending (the answer usually comes within tens of
        microseconds; waking a blocked process costs as much again), then blocks.
        """
        tm = self.timing
        substeps = tm.substeps
        duration_us = None if tm.duration_s is None else int(round(tm.duration_s * 1e6))
        mono = self._mono
        recv = self.link.recv
        spin_s = tm.spin_s
        fc_addr = self._fc_addr
        link = self.link
        self._send_state()
        sent_at = first_sent = last_answer = mono()
        resend_after = tm.resend_s
        answered = False
        final = False  # the last state (at the duration) is out: its answer ends the run
        while not self._stop:
            now = mono()
            msgs = recv(0.0 if now - sent_at < spin_s else min(0.05, resend_after))
            if link.peer_refused:
                if final:
                    return  # a timed FC stops on the last state: its answer was lost, it is gone
                raise WatchdogError("the flight controller's port is closed (the FC process has died); stopping")
            advanced = False
            for msg, addr in msgs:  # in arrival order: a PARAM_SET before the answer acts on this period
                if addr != fc_addr:
                    self.foreign_msgs += 1
                    continue
                mid = msg.id
                if mid != _ACTUATORS:
                    if mid == _PARAM_SET or mid == _PARAM_READ or mid == _PARAM_LIST:
                        self._on_param(msg)
                    continue
                if advanced:
                    continue  # a duplicate answer in the same batch
                if msg.time_usec != self._t_us:
                    self.stale_actuator_msgs += 1
                    continue
                if final:
                    return
                self._apply(msg)
                answered = True
                if sent_at == first_sent:  # a clean round trip (no re-send): the running mean
                    rtt = mono() - first_sent
                    self.rtt_s += 0.05 * (rtt - self.rtt_s) if self.rtt_s else rtt
                self._integrate(substeps)
                if duration_us is not None and self._t_us >= duration_us:
                    # The final state: a lockstep FC with the same duration stops on it. Re-sent like
                    # any other until it is answered (or the timed FC has gone), so a loss cannot cut it.
                    final = True
                if tm.speed is not None and not final:
                    ahead = self._t_us * 1e-6 / tm.speed - (mono() - self._wall_start)
                    if ahead > 0.0:
                        self._sleep(ahead)
                self._send_state()
                sent_at = first_sent = last_answer = mono()
                resend_after = min(tm.resend_s, max(tm.resend_min_s, 4.0 * self.rtt_s))
                advanced = True
                # the rest of the batch came after this answer: it acts from the state just sent
            if advanced:
                continue
            if now - sent_at < spin_s:
                _yield()  # let the FC have this core if the machine is oversubscribed
                continue
            now = mono()
            limit = tm.watchdog_s if answered else tm.startup_timeout_s
            if now - last_answer > limit:
                what = "never answered" if not answered else f"has been silent for {now - last_answer:.1f} s"
                raise WatchdogError(f"flight controller {what} (lockstep watchdog {limit:g} s); stopping")
            if now - sent_at > resend_after:
                self.resends += 1
                # The same bytes again (a lost state or a lost answer): a copy cannot change the FC's log.
                self.link.send_packets(self._last_state)
                sent_at = now
                resend_after = min(tm.resend_s, 2.0 * resend_after)

    def _run_realtime(self) -> None:
        tm = self.timing
        speed = tm.speed or 1.0
        dt_wall = 1.0 / (tm.physics_hz * speed)
        substeps = tm.substeps
        duration_us = None if tm.duration_s is None else int(round(tm.duration_s * 1e6))
        mono = self._mono
        recv = self.link.recv
        last_answer = mono()
        answered = False
        deadline = mono()
        k = 0
        fc_addr = self._fc_addr
        link = self.link
        while not self._stop:
            now = mono()
            wait = deadline - now
            if wait > 0.0:
                for msg, addr in recv(wait):
                    if addr != fc_addr:
                        self.foreign_msgs += 1
                        continue
                    mid = msg.id
                    if mid == _ACTUATORS:
                        self._apply(msg)
                        answered = True
                        last_answer = mono()
                    elif mid == _PARAM_SET or mid == _PARAM_READ or mid == _PARAM_LIST:
                        self._on_param(msg)
                if link.peer_refused:
                    raise WatchdogError("the flight controller's port is closed (the FC process has died); stopping")
                continue
            if k % substeps == 0:
                self._send_state()
            self._integrate(1)
            k += 1
            deadline += dt_wall
            if now - deadline > 1.0:  # hopelessly behind (machine stalled): do not try to catch up
                deadline = now
            if duration_us is not None and self._t_us >= duration_us:
                return
            limit = tm.watchdog_s if answered else tm.startup_timeout_s
            if now - last_answer > limit:
                what = "never answered" if not answered else f"has been silent for {now - last_answer:.1f} s"
                raise WatchdogError(f"flight controller {what} (real-time watchdog {limit:g} s); stopping")


def install_signal_handlers(app: SimBridgeApp) -> None:
    signal.signal(signal.SIGTERM, app.request_stop)
    signal.signal(signal.SIGINT, app.request_stop)
