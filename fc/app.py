"""The flight-controller process: MAVLink in, control law, MAVLink out, at a fixed rate.

Two links:

- the **simulator link** (``--sim``, normally ``udpin:127.0.0.1:PORT``): state in as
  ``ATTITUDE`` + ``LOCAL_POSITION_NED`` (NED/FRD, one datagram per tick, stamped with simulated
  time), with the sensed IMU (``HIGHRES_IMU``: its accelerometer reaches a law that measures
  acceleration) and the plant's true state (``ODOMETRY``: logged, never flown on) in the same
  datagram; motor commands out as ``HIL_ACTUATOR_CONTROLS`` (controls[0..3] in [0, 1]; mode has
  SAFETY_ARMED when armed; flags bit 0 = lockstep);
- the **ground link** (``--gcs``): telemetry out (:mod:`fc.telemetry`), set-points and commands in
  (:mod:`fc.gcs`).

The simulator link also carries the simulator's live parameters: a ``SIM_*`` change from a
ground station (or ``MAV_CMD_INJECT_FAILURE``) goes out as ``PARAM_SET`` to component
``SIM_COMPONENT_ID``; the simulator answers ``PARAM_VALUE`` (counted; a forward unanswered for
1 wall second gets one ``STATUSTEXT`` warning) and announces fault starts and stops with
``STATUSTEXT``, which the FC relays to its ground stations. A state with NaN fields (a sensor
dropout) is ticked like any other: the core's estimate (:mod:`fc.estimate`) handles it.

Timing:

- **lockstep**: every state message is one tick of simulated time; the FC answers each with one
  actuator message and the simulator advances only then. The clock is the simulator's. A
  simulator silent for ``watchdog_s`` wall seconds ends the FC with an error (exit 3).
- **real time**: a fixed-rate loop on the wall clock with absolute deadlines; each tick uses the
  latest state. Late ticks are counted (overruns) and their lateness recorded. State older than
  ``failsafe_state_timeout_s`` puts the FC in failsafe (level, descend, ``STATUSTEXT``).

Everything the FC sends and receives is logged to a ``.tlog`` (simulated-time stamps in
lockstep, so the log is reproducible bit for bit), plus the law's internals every tick. On the sim
link the app logs, not the link: each state when it is flown and each answer when it is made, never
a re-sent or duplicated copy. The log is handed to the OS every ``TLOG_FLUSH_S`` of ticks.

The sim link's checks (docs/links.md): states only from the simulator's address (the first that
sent one); lockstep stamps exactly one period apart, real-time stamps newer than the last and not
implausibly far ahead; every rejected state counted in :class:`FcStats` and dropped. The IMU and
the truth are taken only with the state they came with (same address, same stamp); a stale one,
one without the accelerometer or with an infinite value is counted and dropped with one
rate-limited message naming what was wrong; NaN accelerometer fields are a dropout (counted). A dead
simulator (its port closed, reported by the OS) ends the FC at once (exit 3); a clean simulator end
(``HEARTBEAT`` with ``MAV_STATE_POWEROFF``) stops it cleanly. ``sim_impairment`` /
``gcs_impairment`` (:mod:`smcpilot.impair`) degrade both directions of a link.
"""

from __future__ import annotations

import gc
import ipaddress
import json
import math
import os
import select
import signal
import struct
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import telemetry
from fc.compiled_pipeline import IO_OUT as _IO_OUT
from fc.compiled_pipeline import IO_TOUCHDOWN as _IO_TOUCHDOWN
from fc.config import FcConfig
from fc.core import FlightCore, TickOutput
from fc.flight import VehicleState
from fc.gcs import GcsHandler
from fc.intake import OTHER, Intake, classify
from fc.lockstep_kernel import KI_LENGTHS, KI_REC_BYTES, KI_T_MS
from fc.mission import MissionProtocol
from fc.params import ParamStore, param_messages
from fc.streams import StreamScheduler
from smcpilot.clock import SimClock, WallClock
from smcpilot.complaints import Complaints
from smcpilot.errors import LinkError, RateMismatchError, TlogError, WatchdogError
from smcpilot.fastcodec import TickRecords, decode_state_datagram
from smcpilot.faults import SIM_PARAM_INDEX
from smcpilot.gc_pauses import GcPauses
from smcpilot.geo import Home
from smcpilot.impair import LinkImpairment
from smcpilot.jit import AUTO_MIN_LOCKSTEP_S
from smcpilot.link import Address, MavlinkUdp
from smcpilot.plan import PlanStep
from smcpilot.protocol import (
    ACTUATOR_FLAG_LOCKSTEP,
    FC_COMPONENT_ID,
    IMU_ACCEL_BITS,
    OVERRUN_NAME,
    SIM_COMPONENT_ID,
)
from smcpilot.signing import Signing
from smcpilot.tlog import TlogWriter
from smcpilot.vehicle import VehicleParams
from smcpilot.wire import paper_of_wire

if TYPE_CHECKING:
    from fc.lockstep_kernel import PlainLockstep

FC_COMPONENT = FC_COMPONENT_ID

EXIT_OK = 0
EXIT_CONFIG = 2
EXIT_WATCHDOG = 3

_isfinite = math.isfinite
_NAN = math.nan
_F32 = struct.Struct("<f")
_STATUSTEXT = mavlink.MAVLink_statustext_message
_ATTITUDE_ID = mavlink.MAVLINK_MSG_ID_ATTITUDE
_LPN_ID = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
#: HIGHRES_IMU has a field "id" (the IMU's) that hides the message id: tell it by its class.
_IMU_MSG = mavlink.MAVLink_highres_imu_message
_TRUTH_ID = mavlink.MAVLINK_MSG_ID_ODOMETRY
_HEARTBEAT_ID = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_POWEROFF = mavlink.MAV_STATE_POWEROFF


def _f32(v: float) -> float:
    """``v`` rounded to float32, as PARAM_VALUE carries it."""
    return _F32.unpack(_F32.pack(v))[0]
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_yield = getattr(os, "sched_yield", lambda: None)
#: real time, the loop first: ground-link work (handling datagrams, streaming telemetry) draws on
#: a budget refilled by this share of the control period each tick and holding at most that much;
#: work that overdraws it (one long request) is paid back from the next periods' shares.
GCS_BUDGET_SHARE = 0.15
#: real time: streamed telemetry is built for at most this share of the period per tick (the
#: heartbeat always); what is not built by then goes first at the next tick.
TELEMETRY_SHARE = 0.075
#: real time: no queued datagram is started this close to a deadline (share of the period).
GCS_GUARD_SHARE = 0.2
#: datagrams taken off the ground socket at a time (unparsed, queued in the intake by class).
GCS_DRAIN = 64
#: a SIM_* forward unanswered this long (wall seconds) gets one STATUSTEXT warning.
SIM_PARAM_ANSWER_S = 1.0
#: the link id the ground link's signed packets carry.
GCS_LINK_ID = 0


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


#: lockstep: while the simulator is silent, the last answer is re-sent this often (wall s): it
#: recovers a lost answer, and a dead simulator's closed port is reported on the next receive.
LOCKSTEP_PROBE_S = 0.2
#: real time: this many more ticks that took longer than the period than ticks that did not -> the law is failed
#: (too slow for the control rate; the failsafe flies; fc.core.FlightCore.law_failure).
LAW_OVERRUN_TICKS = 25
#: the tlog is handed to the OS at least this often (simulated s of ticks).
TLOG_FLUSH_S = 0.25
#: real time: a tick this late or later is a stall, kept with its time (FcStats.stalls), at most
#: STALLS_KEPT of them.
STALL_S = 0.001
STALLS_KEPT = 200
#: real time: a state may be stamped at most this much (plus 4x the wall time since the last
#: one) after the last one; later stamps are taken for forged or garbled and dropped.
FUTURE_STATE_S = 0.5


@dataclass
class FcStats:
    """Counters reported at exit (and summarised from the log by ``smcpilot log summary``)."""

    overruns: int = 0
    lateness_s: list[float] = field(default_factory=list)
    #: states with an infinite value (garbage: flown as "not measured", like NaN).
    rx_invalid_state: int = 0
    #: states with fields not measured (NaN or infinite: a sensor dropout), ticked on the estimate.
    states_missing_fields: int = 0
    duplicate_states: int = 0
    out_of_order_states: int = 0
    #: states from another address than the simulator's (the first that sent one), dropped.
    foreign_states: int = 0
    #: lockstep: states whose stamp is not exactly one period after the last tick's, dropped.
    wrong_step_states: int = 0
    #: real time: states not newer than the last one used (replays, late copies), dropped.
    stale_states: int = 0
    #: real time: states stamped implausibly far ahead of the last one (more than 0.5 s plus four
    #: times the wall time since it), dropped: a forged stamp is never adopted.
    future_states: int = 0
    #: SIM_* values forwarded to the simulator, PARAM_VALUE answers heard, forwards unanswered.
    sim_param_forwards: int = 0
    sim_param_answers: int = 0
    sim_param_unanswered: int = 0
    #: STATUSTEXT from the simulator (fault starts/stops), relayed to the ground.
    sim_statustexts: int = 0
    #: real time: periods whose ground-link budget ran out with datagrams still queued, and the
    #: wall seconds of ground-link work (intake and telemetry) in all.
    gcs_budget_spent_periods: int = 0
    gcs_work_s: float = 0.0
    #: HIGHRES_IMU taken with a state (and logged); of those, with NaN accelerometer fields (a
    #: dropout: not measured); states that came without one (the law that measures acceleration
    #: then differences); HIGHRES_IMU / ODOMETRY from another address than the simulator's.
    imu_msgs: int = 0
    imu_accel_missing: int = 0
    states_without_imu: int = 0
    foreign_imu: int = 0
    #: ODOMETRY (the plant's true state) taken with a state and logged.
    truth_msgs: int = 0
    #: real time: the ticks STALL_S or more late, as (monotonic wall s when the tick ran, lateness
    #: s), the first STALLS_KEPT of them: to line up with the garbage collector's passes and with
    #: other processes' stalls (``smcpilot bench sitl``).
    stalls: list[tuple[float, float]] = field(default_factory=list)
    stall_count: int = 0

    def summary(self) -> dict:
        late = sorted(self.lateness_s)

        def pct(p: float) -> float | None:
            if not late:
                return None
            return late[min(len(late) - 1, int(p * (len(late) - 1) + 0.5))]

        return {
            "overruns": self.overruns,
            "lateness_p50_s": pct(0.5),
            "lateness_p99_s": pct(0.99),
            "lateness_max_s": late[-1] if late else None,
            "rx_invalid_state": self.rx_invalid_state,
            "states_missing_fields": self.states_missing_fields,
            "duplicate_states": self.duplicate_states,
            "out_of_order_states": self.out_of_order_states,
            "foreign_states": self.foreign_states,
            "wrong_step_states": self.wrong_step_states,
            "stale_states": self.stale_states,
            "future_states": self.future_states,
            "sim_param_forwards": self.sim_param_forwards,
            "sim_param_answers": self.sim_param_answers,
            "sim_param_unanswered": self.sim_param_unanswered,
            "sim_statustexts": self.sim_statustexts,
            "imu_msgs": self.imu_msgs,
            "imu_accel_missing": self.imu_accel_missing,
            "states_without_imu": self.states_without_imu,
            "foreign_imu": self.foreign_imu,
            "truth_msgs": self.truth_msgs,
            "stalls": {"count": self.stall_count, "threshold_s": STALL_S, "at_s": [round(t, 6) for t, _ in self.stalls],
                       "late_s": [round(d, 6) for _, d in self.stalls]},
        }

    def budget_summary(self) -> dict[str, object]:
        return {"periods_out_of_budget": self.gcs_budget_spent_periods, "work_s": round(self.gcs_work_s, 3)}


def state_from_mavlink(att: mavlink.MAVLink_attitude_message, pos: mavlink.MAVLink_local_position_ned_message):
    """:func:`state_from_wire` of the two wire messages."""
    return state_from_wire((att.roll, att.pitch, att.yaw, att.rollspeed, att.pitchspeed, att.yawspeed,
                            pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz))  # fmt: skip


_tuple_new = tuple.__new__
#: not empty once this process has started compiling the state decoder in the background.
_DECODER_COMPILE_STARTED: list[bool] = []


def state_from_wire(vals: tuple[float, ...]):  # type: ignore[no-untyped-def]
    """(VehicleState in the paper frame, body rates FLU, missing) from the 12 wire values
    (:data:`smcpilot.wire.WIRE_FIELDS`: ATTITUDE's angles and rates, LOCAL_POSITION_NED's position
    and velocity).

    A field the simulator did not measure is NaN on the wire (a sensor dropout: gyro -> the
    rates, attitude -> the angles, position -> x/y/z, velocity -> vx/vy/vz) and stays NaN here,
    for the flight core's estimate (:mod:`fc.estimate`) to handle; an infinite value (garbage)
    becomes NaN too. ``missing`` is 0 when every field is finite, 1 if some are NaN, 2 if some
    were infinite."""
    missing = 0
    for v in vals:
        if not _isfinite(v):
            missing = max(missing, 1 if v != v else 2)
    if missing:
        vals = tuple(v if _isfinite(v) else _NAN for v in vals)
    s = paper_of_wire(*vals)  # smcpilot.wire: the one wire <-> paper-frame conversion
    return VehicleState(*s[:12]), (s[12], s[13], s[14]), missing


class FlightControllerApp:
    """One flight-controller process. Build, then :meth:`run` (returns the exit code)."""

    def __init__(
        self,
        config: FcConfig,
        vehicle: VehicleParams,
        *,
        sim_url: str,
        gcs_url: str | None,
        lockstep: bool,
        tlog_path: Path | None,
        plan: tuple[PlanStep, ...] = (),
        params: ParamStore | None = None,
        home: Home = Home(),
        duration_s: float | None = None,
        startup_timeout_s: float = 30.0,
        spin_s: float = 0.002,
        sim_system_id: int | None = None,
        sim_impairment: LinkImpairment | None = None,
        gcs_impairment: LinkImpairment | None = None,
        impair_seed: int = 0,
        out: TextIO = sys.stdout,
        monotonic: Callable[[], float] = time.monotonic,
        gcs_port: int = 0,
        signing: Signing | None = None,
        gcs_trusted: bool = False,
        jit: str = "auto",
        tick_phase: float | None = None,
    ) -> None:
        #: MAVLink 2 signing of the ground link (key None: off until a SETUP_SIGNING sets one).
        self.signing = signing if signing is not None else Signing(None)
        self.params = params if params is not None else ParamStore(config)
        config = self.params.config
        self.cfg = config
        self.vehicle = vehicle
        self.home = home
        self.lockstep = lockstep
        self.duration_s = duration_s
        self.startup_timeout_s = startup_timeout_s
        #: lockstep: busy-poll this long after each tick before blocking (0: always block).
        self.spin_s = spin_s
        #: real time: the ticks fall this fraction of a period (0 <= phase < 1) after the beat of
        #: one period from the first state; a swarm's FCs each their own, spread over the period
        #: (None: 0, and in :mod:`fc.group` the FC's place among the group's).
        self.tick_phase = tick_phase
        #: the compiled pipeline: ``auto``, ``wait`` or ``off`` (:data:`smcpilot.jit.JIT_POLICIES`).
        self.jit = jit
        #: why the pipeline flies in CPython (None: compiled).
        self.jit_why: str | None = "not started"
        self.out = out
        self._mono = monotonic
        self.stats = FcStats()
        self.clock: SimClock | WallClock = SimClock() if lockstep else WallClock(1.0, monotonic)
        self.tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        clock_us = self.clock.now_us
        sysid = config.system_id
        # The simulator link keeps the system id the two processes were launched with; a
        # SYSID_THISMAV change (restart) renames the vehicle to ground stations only.
        sim_sysid = sysid if sim_system_id is None else sim_system_id
        self._sim_sysid = sim_sysid
        #: SIM_* forwards awaiting the simulator's PARAM_VALUE: name -> wall time sent.
        self._sim_pending: dict[str, float] = {}
        try:
            # The sim link logs nothing itself: this app logs each state it flies and each answer
            # once, so a re-sent or duplicated datagram never changes the log (lockstep: bit for bit).
            self.sim = self._open_sim(sim_url, sim_sysid, clock_us, sim_impairment, impair_seed)
            self.gcs = self._open_gcs(gcs_url, gcs_port, sysid, clock_us, gcs_trusted, gcs_impairment, impair_seed + 1) if gcs_url else None
        except Exception:
            if self.tlog is not None:  # a configuration error must not leave an empty log behind
                self.tlog.close()
                if self.tlog.records_written == 0:
                    self.tlog.path.unlink(missing_ok=True)
            raise
        # Log-only messages have their own sequence numbers: the links' numbering stays gap-free.
        self._logmav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=FC_COMPONENT)
        #: the tick's log record and its answer to the simulator (the simulator's system id), encoded
        #: (the in-process runner writes the same records)
        self._records = TickRecords(sysid)
        self._sim_records = TickRecords(sim_sysid)
        #: decode the simulator's per-tick datagram straight to values (else every datagram goes
        #: through the link's full parse into message objects; the same result, slower)
        self._fast_states = isinstance(self.sim, MavlinkUdp) and self.sim.signing is None
        #: the state datagram's compiled decoder and the tick's answer's and record's compiled encoder
        #: (:mod:`fc.state_kernel`; None: CPython's), loaded with the compiled pipeline.
        self._state_decoder: Any = None
        self._answer_encoder: Any = None
        #: lockstep: plain ticks flown in one compiled call (fc.lockstep_kernel; None: every tick the ordinary way);
        #: ``_plain_ready``: the kernel's inputs are as the last plain tick left them (nothing else has run since).
        self._plain: PlainLockstep | None = None
        self._plain_ready = False
        gcs = self.gcs
        #: the flight core: the one control tick (plan, modes, failsafes, pipeline, events).
        self.core = FlightCore(
            config, vehicle, home=home, plan=plan, event=self.event, item_reached=self._item_reached,
            estimator=self.params.options.estimator,
        )  # fmt: skip
        #: the mission protocol with ground stations, over the commander's stored mission.
        self.mission = MissionProtocol(
            self.core.commander.mission, gcs.mav if gcs is not None else mavlink.MAVLink(None),
            gcs.send_to if gcs is not None else (lambda m, a: None),
            home=lambda: self.core.commander.home, fence=lambda: self.core.config.fence,
        )  # fmt: skip
        self.streams = StreamScheduler(config.telemetry_rate_hz)
        #: the ground protocol, with its collaborators (no back-reference to this app).
        self.gcs_handler = GcsHandler(
            core=self.core, mission=self.mission, params=self.params, streams=self.streams,
            link=gcs, event=self.event, log=self.say, snapshot=self.telemetry_snapshot,
            apply_config=self.apply_config, wall_s=monotonic, forward_sim=self.forward_sim_param,
            signing=self.signing, trusted=gcs_trusted,
        )  # fmt: skip
        if self.gcs is not None and not self.signing.enabled and not _is_loopback(self.gcs.local_address[0]):
            self.say(
                f"fc: warning: the ground link listens on {self.gcs.local_address[0]}:{self.gcs.local_address[1]}"
                " (not loopback) without signing: anyone who can reach it can command the vehicle (--signing-key)"
            )
        self._att: mavlink.MAVLink_attitude_message | None = None
        #: the IMU and the truth of the datagram being read, with the address each came from.
        self._imu: tuple[mavlink.MAVLink_message, Address] | None = None
        self._truth: tuple[mavlink.MAVLink_message, Address] | None = None
        #: the accelerometer's specific force with the latest state (body FRD, m/s^2; None: none).
        self.accel_frd: tuple[float, float, float] | None = None
        #: bad IMU and truth messages from the simulator, by kind, with rate-limited messages.
        self.sim_complaints = Complaints(self.say, "fc", monotonic)
        self.state: VehicleState | None = None
        self.body_rates: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._state_ms = -1
        self._state_wall_s = -math.inf
        self._last_tick_ms = -1
        self._last_actuator: bytes | None = None
        #: the simulator's address: the first to send a state; states from elsewhere are dropped.
        self._sim_peer: tuple[str, int] | None = None
        #: lockstep: a rejected stamp and how often in a row it came (the simulator insisting).
        self._rejected_ms = -1
        self._rejected_repeats = 0
        self._impaired = self.sim.impair_counters is not None or (self.gcs is not None and self.gcs.impair_counters is not None)
        #: the tlog is handed to the OS every this many ticks (a killed FC loses at most ~0.25 s).
        self._flush_ticks = max(1, int(config.rate_hz * TLOG_FLUSH_S))
        self._unflushed_ticks = 0
        #: received datagrams waiting to be handled, by class (fc.intake): the ground link's, and
        #: the simulator link's from other addresses than the simulator's (class "other").
        self.intake: Intake[tuple[MavlinkUdp, bytes, Address]] = Intake()
        #: control periods (ticks) so far: the intake counts a datagram handled in a later one deferred.
        self._period_no = 0
        #: wall seconds the last tick spent on the ground link (telemetry, acknowledgements).
        self._gcs_tick_s = 0.0
        self._stop = False
        self._exit_code = EXIT_OK
        self._cpu_at_first_tick_s = 0.0
        #: real time: the garbage collector's passes during the loop
        self._gc_pauses = GcPauses(monotonic)
        #: lockstep: when the last state was flown and the last probe sent (wall s), states flown.
        self._ls_last_rx = self._ls_last_probe = 0.0
        self._ls_states = 0

    def _open_sim(
        self, url: str, sysid: int, clock_us: Callable[[], int], impairment: LinkImpairment | None, impair_seed: int
    ) -> MavlinkUdp:
        """The simulator link (our simulator's UDP; :mod:`fc.sim_px4` opens PX4's TCP instead)."""
        link = MavlinkUdp(
            url, source_system=sysid, source_component=FC_COMPONENT, accept_system=sysid,
            tlog=None, clock_us=clock_us, monotonic_s=self._mono, impairment=impairment, impair_seed=impair_seed,
        )  # fmt: skip
        link.report_peer_errors()
        return link

    def _open_gcs(
        self, url: str, port: int, sysid: int, clock_us: Callable[[], int], trusted: bool,
        impairment: LinkImpairment | None, impair_seed: int,
    ) -> MavlinkUdp:  # fmt: skip
        """The ground link; with ``port``, sending from that port of ours (a second ground
        station writes to it while the first listens where we send); a port already taken
        (another FC) falls back to a free one, said on stdout."""
        unsigned_ok = self.signing.accept_unsigned | {mavlink.MAVLINK_MSG_ID_SETUP_SIGNING} if trusted else None

        def open_link(bind_port: int) -> MavlinkUdp:
            return MavlinkUdp(url, source_system=sysid, source_component=FC_COMPONENT, tlog=self.tlog, clock_us=clock_us,
                              bind_port=bind_port, signing=self.signing, link_id=GCS_LINK_ID, accept_unsigned=unsigned_ok,
                              impairment=impairment, impair_seed=impair_seed)  # fmt: skip

        try:
            return open_link(port)
        except LinkError as exc:
            if not port:
                raise
            self.say(f"fc: ground port {port} not available ({exc}); using a free port (see FC_LISTENING gcs=)")
        return open_link(0)

    def telemetry_snapshot(self) -> telemetry.TelemetrySnapshot:
        """What ground-station telemetry reads, now (the GCS handler's snapshot provider)."""
        return telemetry.snapshot(  # the core's estimate: never a NaN of a sensor dropout
            self.core, time_us=self.clock.now_us(), state=self.core.state, body_rates=self.body_rates, overruns=self.stats.overruns,
            comm_errors=self.gcs_handler.comm_errors(self.sim.counters),
        )

    # -- lifecycle -----------------------------------------------------------------------------
    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def close(self) -> None:
        self.signing.close()
        for link in (self.sim, self.gcs):
            if link is not None:
                link.close()
        if self.tlog is not None:
            self.tlog.close()
        self.params.close()  # the last parameter change on disk before we exit

    #: ``--jit auto`` loads the compiled pipeline for lockstep flights at least this long (or open-ended),
    #: counted over every flight of the process (:mod:`fc.group`: they share the one load).
    JIT_AUTO_MIN_LOCKSTEP_S = AUTO_MIN_LOCKSTEP_S
    #: flight controllers flying in this process (:mod:`fc.group` sets it before :meth:`start`).
    flights_per_process = 1

    def _attach_compiled(self) -> None:
        """The pipeline compiled (:mod:`fc.compiled_pipeline`) as ``--jit`` says; one line says
        when it flies in CPython and why (except for a short lockstep flight under ``auto``)."""
        if self.jit == "off":
            self.jit_why = "--jit off"
            return
        flown_s = None if self.duration_s is None else self.duration_s * self.flights_per_process
        if self.jit == "auto" and self.lockstep and flown_s is not None and flown_s < self.JIT_AUTO_MIN_LOCKSTEP_S:
            what = "a lockstep flight" if self.flights_per_process == 1 else f"{self.flights_per_process} lockstep flights in one process"
            self.jit_why = f"--jit auto: {what} shorter than {self.JIT_AUTO_MIN_LOCKSTEP_S:g} s (loading costs more than it saves)"
            return
        from fc.compiled_pipeline import attach_compiled, compile_in_background

        why = self.jit_why = attach_compiled(self.core.flight, compile_new=self.jit == "wait")
        if why is None and self._fast_states:
            from fc.state_kernel import compiled_answer_encoder, compiled_decoder

            wait = self.jit == "wait"
            self._state_decoder = compiled_decoder(compile_new=wait)
            flight = self.core.flight
            self._answer_encoder = compiled_answer_encoder(
                self._sim_records.sysid, self._records.sysid, ACTUATOR_FLAG_LOCKSTEP if self.lockstep else 0, flight.diag_mask,
                compile_new=wait,
            )  # fmt: skip
            missing = self._state_decoder is None or self._answer_encoder is None
            if self.lockstep and not missing and os.environ.get("SMCPILOT_LOCKSTEP_KERNEL", "1") != "0":
                from fc.compiled_pipeline import plain_entry

                self._plain = plain_entry(flight, self.core._est, self.core._est_params, compile_new=wait)
                missing = self._plain is None
            if missing and self.jit == "auto" and not _DECODER_COMPILE_STARTED:
                _DECODER_COMPILE_STARTED.append(True)  # (once a process: a group's FCs all come here)
                compile_in_background(self.cfg.controller)  # (it caches the decoder with the pipeline)
        if why is None or "not in the pure style" in why:  # (that one fc.cli says already)
            return
        note = f"fc: the pipeline flies in CPython: {why}"
        if self.jit == "auto" and why.endswith("not cached yet"):
            pid = compile_in_background(self.cfg.controller)
            if pid is not None:
                note += f"; compiling it in the background (pid {pid}) for the next runs"
        self.say(note)

    def run(self) -> int:
        """Fly until the end (the duration, a stop, the simulator's goodbye or a watchdog); the
        exit code: :meth:`start`, then :meth:`fly`. :mod:`fc.group` flies several apps in one process
        through the same parts (in lockstep one loop calling the loop's steps, then :meth:`finish`)."""
        self.start()
        return self.fly()

    def fly(self) -> int:
        """After :meth:`start`: the loop (lockstep or real time) until the end, then :meth:`finish`;
        the exit code."""
        try:
            if self.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        except (WatchdogError, RateMismatchError) as exc:
            self.ended_by(exc)
        finally:  # whatever ended the loop: the log closed, the summary said
            self.finish()
        return self._exit_code

    def start(self, *, freeze_gc: bool = True) -> None:
        """Before the first state: the compiled pipeline (as ``--jit`` says), ``FC_LISTENING``,
        the configuration into the log."""
        sim_addr = "{}:{}".format(*self.sim.local_address)
        gcs_addr = "{}:{}".format(*self.gcs.local_address) if self.gcs else "-"
        self._attach_compiled()
        if freeze_gc:
            # Start-up made every object the loop will ever need (numba alone brings ~10^5): the
            # collector need not scan them again and again during the flight.
            gc.collect()
            gc.freeze()
        self.say(f"FC_LISTENING sim={sim_addr} gcs={gcs_addr} pid={os.getpid()}")
        if self.tlog is not None:  # the configuration this flight flies, for the log's readers
            lm = self._logmav
            self.tlog.write_many(self.clock.now_us(), [m.pack(lm) for m in param_messages(lm, self.cfg, self.params.options)])

    def ended_by(self, exc: WatchdogError | RateMismatchError) -> None:
        """The flight ends on ``exc`` (a watchdog: exit 3; a rate mismatch: exit 2), said in one line."""
        self.say(f"fc: error: {exc}")
        self._exit_code = EXIT_WATCHDOG if isinstance(exc, WatchdogError) else EXIT_CONFIG
        self._stop = True

    def finish(self) -> int:
        """After the loop: the last records into the log, the log and links closed, ``FC_SUMMARY``;
        the exit code."""
        summary = self.stats.summary()
        summary["ticks"] = self.core.ticks
        summary["failsafe_events"] = self.core.failsafe_events
        summary["sim_time_s"] = self.clock.now_s()
        sim_drops = getattr(self.sim, "kernel_drops", lambda: None)()  # (a TCP simulator link has none)
        summary["links"] = {"sim": {**self.sim.counters.as_dict(), "kernel_drops": sim_drops},
                            "gcs": {**self.gcs.counters.as_dict(), "kernel_drops": self.gcs.kernel_drops()} if self.gcs else None}
        summary["impairment"] = {"sim": self.sim.impair_counters, "gcs": self.gcs.impair_counters if self.gcs else None}
        summary["gcs_rejected"] = dict(self.gcs_handler.rejected)
        summary["gcs_budget"] = {**self.intake.counters.as_dict(), "left": len(self.intake), **self.stats.budget_summary(),
                                                  "telemetry_peers_skipped": self.gcs_handler.telemetry_peers_skipped,
                                 "telemetry_deferred": self.gcs_handler.telemetry_deferred}  # fmt: skip
        summary["cpu_s"] = round(time.process_time(), 3)
        #: CPU seconds before the first tick (imports, start-up): cpu_s minus it is the flight's.
        summary["cpu_start_s"] = round(self._cpu_at_first_tick_s, 3)
        t = os.times()  # the kernel's share (system calls, wake-ups) beside our own code's
        summary["cpu_user_s"], summary["cpu_sys_s"] = round(t.user, 3), round(t.system, 3)
        summary["rx_rejected"] = self.rejected_summary()
        summary["gc"] = self._gc_pauses.summary()
        flight = self.core.flight
        dec, enc = self._state_decoder, self._answer_encoder
        summary["pipeline"] = {"compiled": flight.compiled, "compiled_ticks": flight.compiled_ticks, "why_not": self.jit_why,
                               "states_decoded_compiled": 0 if dec is None else dec.decoded,
                               "answers_encoded_compiled": 0 if enc is None else enc.made,
                               "lockstep_kernel_ticks": 0 if self._plain is None else self._plain.flown}  # fmt: skip
        summary["sim_bad"] = dict(self.sim_complaints.counts)
        summary["tlog"] = str(self.tlog.path) if self.tlog is not None else None
        summary.update(self._summary_extra())
        if self.tlog is not None and not self.tlog.closed:  # the run's own overrun count, for the log's readers
            lm, now_us = self._logmav, self.clock.now_us()
            count = lm.named_value_int_encode((now_us // 1000) & 0xFFFFFFFF, OVERRUN_NAME.encode(), self.stats.overruns)
            try:
                self.tlog.write(now_us, count.pack(lm))
            except TlogError as exc:  # the log must still be closed below
                self.say(f"fc: warning: {exc}")
        if self.tlog is not None:  # the final counters, for `smcpilot log summary` (with or without a GCS)
            lm = self._logmav
            try:
                final = telemetry.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS, self.telemetry_snapshot(), lm)
                self.tlog.write_many(self.clock.now_us(), [m.pack(lm) for m in final])
            except Exception as exc:  # never hide the error that ended the run, never lose the log
                self.say(f"fc: warning: final SYS_STATUS not logged: {type(exc).__name__}: {exc}")
        self.close()  # flushes the parameter writer: its figures are final below
        w = self.params.writer
        summary["param_file"] = None if self.params.path is None else {
            "path": str(self.params.path), "changes": w.submissions if w else 0, "writes": w.writes if w else 0,
            "write_errors": w.errors if w else 0,
        }  # fmt: skip
        self.say("FC_SUMMARY " + json.dumps(summary, sort_keys=True))
        return self._exit_code

    def _summary_extra(self) -> dict[str, Any]:
        """More of FC_SUMMARY (a link's own counters: :mod:`fc.sim_px4`)."""
        return {}

    def rejected_summary(self) -> dict[str, int]:
        """Every rejected packet by reason (the links' counters and the ground protocol's), 0s left out."""
        out: dict[str, int] = {}
        for name, link in (("sim", self.sim), ("gcs", self.gcs)):
            if link is None:
                continue
            c = link.counters
            for field_name in ("rx_bad", "rx_unknown", "rx_foreign_system", "rx_unsigned", "rx_bad_signature",
                               "rx_old_timestamp", "rx_stream_window"):  # fmt: skip
                v = getattr(c, field_name)
                if v:
                    out[f"{name}.{field_name}"] = v
        for reason, v in self.gcs_handler.rejected.items():
            if v:
                out[f"gcs.{reason}"] = v
        mission = self.mission
        for reason, v in (("mission_refused", mission.refused), ("mission_ignored", mission.ignored)):
            if v:
                out[f"gcs.{reason}"] = v
        out["total"] = sum(out.values())
        return out

    # -- loops ---------------------------------------------------------------------------------
    def _fds(self) -> list[int]:
        return [self.sim.fileno()] + ([self.gcs.fileno()] if self.gcs else [])

    def _run_lockstep(self) -> None:
        """Answer each state as soon as it arrives.

        The simulator's next state comes a few tens of microseconds after our answer; waking a
        blocked process costs about as much again, so the loop busy-polls for ``spin_s`` after
        each tick before it falls back to a blocking ``select``. The steps (:meth:`lockstep_begin`,
        :meth:`lockstep_take`, :meth:`lockstep_between`) are the ones :mod:`fc.group` calls for
        several apps in one loop.
        """
        fds = self._fds()
        mono = self._mono
        spin_s = self.spin_s
        self.lockstep_begin()
        take = self.lockstep_take
        spin_until = self._ls_last_rx + spin_s
        while not self._stop:
            if take():
                spin_until = self._ls_last_rx + spin_s
                continue
            if mono() < spin_until:
                _yield()  # let the simulator have this core if the machine is oversubscribed
                continue
            readable, _, _ = select.select(fds, (), (), self.lockstep_wait_s())
            self.lockstep_between(bool(readable))

    def lockstep_begin(self) -> None:
        """Lockstep: the watchdog and the probe count from now."""
        self._ls_last_rx = self._ls_last_probe = self._mono()
        self._ls_states = 0

    def lockstep_take(self, max_datagrams: int = 256) -> bool:
        """Lockstep: fly what waits on the simulator link, at most ``max_datagrams`` datagrams
        (True: a state was flown); the ground link is looked at every 8 states. (A caller that
        ``select``s before each call takes one: the rest makes the socket readable again, and no
        empty read is paid for.)"""
        if not self._poll_sim(max_datagrams):
            return False
        self._ls_last_rx = self._mono()
        self._ls_states += 1
        if self._ls_states % 8 == 0:
            self._poll_ground()
        return True

    def lockstep_wait_s(self) -> float:
        """Lockstep: how long to block at most before :meth:`lockstep_between` is due again."""
        if self._impaired:
            gcs = self.gcs
            return min(0.1, self.sim.impair_wait_s(), gcs.impair_wait_s() if gcs is not None else 0.1)
        return 0.1

    def lockstep_between(self, readable: bool) -> None:
        """Lockstep, between states: the ground link (``readable``: a socket of this app has
        something), acknowledgements and parameter lists; with nothing readable, the probe of a
        silent simulator (our last answer again), unanswered simulator parameters and the
        watchdog (raises :class:`WatchdogError`)."""
        gcs = self.gcs
        self._plain_ready = False
        if readable:
            self._poll_ground()
        if gcs is not None:
            self.gcs_handler.send_durable_acks()  # between ticks too (before the first state)
            self.gcs_handler.send_param_lists(all_now=True)  # the simulator is silent: no deadline waits
        if readable:
            return
        now = self._mono()
        last_rx = self._ls_last_rx
        if self._last_actuator is not None and now - max(last_rx, self._ls_last_probe) > LOCKSTEP_PROBE_S:
            self._ls_last_probe = now
            self._answer_sim((self._last_actuator,))  # not logged (the sim link logs nothing)
            self._poll_sim()  # a closed port (dead simulator) is reported here
        if self._sim_pending:
            self._check_sim_answers(now)
        limit = self.cfg.watchdog_s if self.core.ticks else self.startup_timeout_s
        if now - last_rx > limit:
            what = "sent nothing" if not self.core.ticks else f"has been silent for {now - last_rx:.1f} s"
            raise WatchdogError(f"simulator {what} (lockstep watchdog {limit:g} s); stopping")

    def _run_realtime(self) -> None:
        """The fixed-rate loop, with the garbage collector's passes timed (FC_SUMMARY's ``gc``)."""
        with self._gc_pauses:
            self._realtime_loop()

    def _realtime_loop(self) -> None:
        """The fixed-rate loop of one FC, from its steps (:meth:`realtime_wait_first`,
        :meth:`realtime_begin`, :meth:`realtime_work`, :meth:`realtime_fds`, :meth:`realtime_readable`,
        :meth:`realtime_due`), which :mod:`fc.group` calls for several FCs in one loop."""
        fds = self._fds()
        mono = self._mono
        start = mono()
        # Wait for the first state before starting the fixed-rate loop.
        while not self._stop and self.state is None:
            readable, _, _ = select.select(fds, (), (), 0.1)
            self.realtime_wait_first(readable, mono() - start)
        now = mono()
        self.realtime_begin(now, now + (1.0 + (self.tick_phase or 0.0)) * self.cfg.period_s)
        while not self._stop:
            now = mono()
            wait = self.rt_deadline - now
            if wait > 0.0:
                if self.realtime_work(now):
                    continue
                readable, _, _ = select.select(self.realtime_fds(), (), (), wait)
                if readable:
                    self.realtime_readable(readable)
                continue
            if self.realtime_due(now):
                break

    def realtime_wait_first(self, readable: Sequence[int], waited_s: float) -> None:
        """Real time, before the first state: what came (``readable``: this app's ready sockets),
        the ground's acknowledgements and lists; the start-up watchdog after ``waited_s``."""
        if self.sim.fileno() in readable:
            self._poll_sim()
        self._poll_ground()
        if self.gcs is not None:
            self.gcs_handler.send_durable_acks()
            self.gcs_handler.send_param_lists(all_now=True)
        if waited_s > self.startup_timeout_s:
            raise WatchdogError(f"simulator sent nothing within {self.startup_timeout_s:g} s; stopping")

    def realtime_begin(self, now: float, first_deadline: float | None = None) -> None:
        """Real time, the first state in: the fixed-rate loop's state; its first deadline one
        period from ``now`` (or ``first_deadline``: a group's FCs share their deadlines)."""
        period = self.cfg.period_s
        self._rt_period = period
        self.rt_deadline = now + period if first_deadline is None else first_deadline
        self._rt_slow_ticks = 0
        # The loop first: ground-link work draws on a budget of GCS_BUDGET_SHARE of each period
        # (fc.intake: most important and oldest first) and never starts within the guard before a
        # deadline; the ground socket is watched only while the budget lasts.
        self._rt_budget = GCS_BUDGET_SHARE * period
        self._rt_guard = GCS_GUARD_SHARE * period
        self._rt_credit = self._rt_budget
        self._rt_worked = False
        self._rt_can_work = True
        fds = self._fds()
        self._rt_all_fds = fds
        self._rt_sim_only = [fds[0]]
        self._rt_sim_fd = fds[0]
        self._rt_gcs_fd = self.gcs.fileno() if self.gcs is not None else -1

    def realtime_work(self, now: float) -> bool:
        """Real time, before the deadline: ground-link work from the intake, within the period's
        budget and never inside the guard before the deadline (True: some was done, look again);
        at least one datagram a period (the most important waiting), whatever the credit."""
        wait = self.rt_deadline - now
        can_work = self._rt_can_work = (self._rt_credit > 0.0 or not self._rt_worked) and wait > self._rt_guard
        if not (can_work and self.intake):
            return False
        spent = self._work_intake(min(self.rt_deadline - self._rt_guard, now + self._rt_credit))
        self._rt_worked = True
        self._rt_credit -= spent
        stats = self.stats
        stats.gcs_work_s += spent
        if self._rt_credit <= 0.0 and self.intake:
            stats.gcs_budget_spent_periods += 1
        return True

    def realtime_fds(self) -> list[int]:
        """Real time, before the deadline: the sockets to wait on (the ground's only while the
        period's budget lasts, as :meth:`realtime_work` found)."""
        return self._rt_all_fds if self._rt_can_work else self._rt_sim_only

    def realtime_readable(self, readable: Sequence[int]) -> None:
        """Real time, before the deadline: what came on this app's sockets in ``readable``."""
        if self._rt_sim_fd in readable:
            self._poll_sim()
        if self._rt_gcs_fd in readable:
            self._take_gcs()

    def realtime_due(self, now: float) -> bool:
        """Real time, the deadline passed (``now``): the lateness, the watchdog, the tick, the
        ground link's share; True when the flight's duration is flown (the loop ends)."""
        stats = self.stats
        period = self._rt_period
        late = now - self.rt_deadline
        stats.lateness_s.append(late)
        if late >= STALL_S:
            stats.stall_count += 1
            if len(stats.stalls) < STALLS_KEPT:
                stats.stalls.append((now, late))
        if late >= period:
            missed = int(late / period)
            stats.overruns += missed
            self.rt_deadline += missed * period
        self.rt_deadline += period
        if self._impaired:  # release held datagrams on time
            self._poll_sim()
            if self.gcs is not None:
                self.gcs.pump()
        age = now - self._state_wall_s
        if age > self.cfg.watchdog_s:
            raise WatchdogError(f"simulator has been silent for {age:.1f} s (real-time watchdog); stopping")
        mono = self._mono
        t_start = mono()
        self._tick(self.clock.now_us(), stale=age > self.cfg.failsafe_state_timeout_s)
        t_end = mono()
        spent = t_end - t_start
        # the period's new share, less the ground work of the tick (telemetry) and of taking
        # what waits on the ground socket off it (counted and queued by class, or dropped)
        self._take_gcs()
        ground = self._gcs_tick_s + mono() - t_end
        stats.gcs_work_s += ground
        self._rt_credit = min(self._rt_budget, self._rt_credit + self._rt_budget) - ground
        self._rt_worked = False
        if spent > period and self.core.flight.armed and not self.core.law_failed:
            # Ticks that cannot keep the rate, again and again, are a law too slow for it: the
            # failsafe (open loop, cheap) flies instead of a loop that falls ever later. A fast
            # tick takes one back (the state-loss failsafe a starved loop falls into is fast).
            self._rt_slow_ticks += 1
            if self._rt_slow_ticks >= LAW_OVERRUN_TICKS:
                self.core.law_failure(f"overran its tick {LAW_OVERRUN_TICKS} times ({spent * 1e3:.1f} ms of {period * 1e3:.1f} ms)")
        elif self._rt_slow_ticks:
            self._rt_slow_ticks -= 1
        return self.duration_s is not None and self.clock.now_s() >= self.duration_s

    # -- input ---------------------------------------------------------------------------------
    def _poll_sim(self, max_datagrams: int = 256) -> bool:
        """Handle simulator traffic; True if a state was flown (lockstep) or taken (real time).

        Checks, each counted in :class:`FcStats` and dropped (never adopted): a state from another
        address than the simulator's; in lockstep a stamp that is not exactly one period after the
        last tick's (a re-sent copy of the last one is answered again, unlogged); in real time a
        stamp not newer than the last one (stale) or implausibly far ahead (future)."""
        got = False
        sim = self.sim
        fast = self._fast_states
        dec = self._state_decoder
        for data, addr in sim.recv_datagrams(max_datagrams):
            peer = self._sim_peer
            if peer is not None and addr != peer:
                # not the simulator: parsed (and counted) as ground work, least important
                self._plain_ready = False
                self.intake.put(OTHER, (sim, data, addr), self._period_no)
                continue
            if fast and peer is not None:
                # a plain tick, flown in one compiled call (fc.lockstep_kernel)
                if self._plain is not None and self._fly_plain(self._plain, data, addr):
                    got = True
                    continue
                self._plain_ready = False
                # the simulator's per-tick datagram, decoded straight to values (anything else:
                # the link's full parse below, which counts and checks it the same way)
                taken = None
                if dec is not None:  # compiled: decoded and converted in one call (fc.state_kernel)
                    if dec.decode(data, self._sim_sysid):
                        fo = dec.fo.tolist()
                        io = dec.io.tolist()
                        e0, e1, e2, e3 = io[5], io[6], io[7], io[8]
                        taken = (
                            io[0], (_tuple_new(VehicleState, fo[0:12]), (fo[12], fo[13], fo[14]), io[1]),
                            (io[2], io[3], fo[15], fo[16], fo[17], data[e0:e1], addr), (io[4], data[e1:e2], addr),
                            data[:e0], data[e2:e3], addr,
                        )  # fmt: skip
                else:
                    d = decode_state_datagram(data, self._sim_sysid)
                    if d is not None and d[0][0] == d[3][0]:  # (stamps that differ: the full parse says so)
                        att, imu, odo, lpn, (p_att, p_imu, p_odo, p_lpn) = d
                        taken = (
                            lpn[0], state_from_wire((*att[1:7], *lpn[1:7])), (imu[0], imu[14], imu[1], imu[2], imu[3], p_imu, addr),
                            (odo[0], p_odo, addr), p_att, p_lpn, addr,
                        )  # fmt: skip
                if taken is not None:
                    sim.heard(addr, 4)
                    self._att = None
                    self._imu = self._truth = None
                    if self._take_state(*taken):
                        got = True
                    continue
            for msg, src in sim.parse(data, addr):
                if self._on_sim_message(msg, src):
                    got = True
        if sim.peer_refused and not self._stop:
            silent_s = max(0.0, self._mono() - self._state_wall_s) if self._state_wall_s > -math.inf else 0.0
            raise WatchdogError(f"simulator has been silent for {silent_s:.1f} s and its port is closed"
                                " (the simulator process has died); stopping")  # fmt: skip
        return got

    def _on_sim_message(self, msg: mavlink.MAVLink_message, addr: Address) -> bool:
        """One message of the simulator's traffic (parsed by the link); True if a state was
        flown (lockstep) or taken (real time)."""
        peer = self._sim_peer
        if peer is not None and addr != peer:
            if type(msg) is _IMU_MSG or msg.id == _TRUTH_ID:
                self.stats.foreign_imu += 1
            elif msg.id == _LPN_ID:  # one per state (ATTITUDE + LOCAL_POSITION_NED)
                self.stats.foreign_states += 1
            return False
        if type(msg) is _IMU_MSG:
            self._imu = (msg, addr)
            return False
        mid = msg.id
        if mid == _ATTITUDE_ID:
            self._att = msg
        elif mid == _TRUTH_ID:
            self._truth = (msg, addr)
        elif mid == _LPN_ID:
            att = self._att
            imu, truth = self._imu, self._truth
            self._imu = self._truth = None
            if att is None or att.time_boot_ms != msg.time_boot_ms:
                return False
            self._att = None
            if imu is not None:
                m, src = imu
                imu_v = (m.time_usec, m.fields_updated, m.xacc, m.yacc, m.zacc, m.get_msgbuf(), src)
            if truth is not None:
                m, src = truth
                truth_v = (m.time_usec, m.get_msgbuf(), src)
            return self._take_state(
                msg.time_boot_ms, state_from_wire((att.roll, att.pitch, att.yaw, att.rollspeed, att.pitchspeed, att.yawspeed,
                                                   msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)),
                imu_v if imu is not None else None, truth_v if truth is not None else None, att.get_msgbuf(), msg.get_msgbuf(), addr,
            )  # fmt: skip
        elif type(msg) is _STATUSTEXT:  # its field "id" (the chunk id) hides the message id
            self._log_sim(msg)
            self._relay_sim_text(msg)
        elif mid == mavlink.MAVLINK_MSG_ID_PARAM_VALUE:
            self._log_sim(msg)
            self._sim_param_value(msg)
        elif mid == _HEARTBEAT_ID and msg.system_status == _POWEROFF and not self._stop:
            # The simulator's clean end (not logged: in lockstep it may come after the last tick or not).
            self.say("fc: the simulator has ended; stopping")
            self._stop = True
        return False

    def _fly_plain(self, plain: PlainLockstep, data: bytes, addr: Address) -> bool:
        """Lockstep: fly the simulator's datagram ``data`` in one compiled call when its tick is
        plain (:mod:`fc.lockstep_kernel`), then bring everything up to date as :meth:`_take_state`
        and :meth:`_tick` would have; False when it is not (nothing changed: fly it the ordinary way)."""
        core = self.core
        c = core.commander
        kf = plain.kf
        ki = plain.ki
        ready = self._plain_ready
        if not ready:  # the inputs that change only when Python does something else
            watch = core.plain_watch()
            if watch is None:
                return False
            f = core.flight
            enc = self._answer_encoder
            if enc is None or f.diag_mask != enc.mask or self._last_tick_ms < 0:
                return False
            cfg = core.config
            kf[:] = (self._last_tick_ms, self.cfg.period_us, cfg.period_s, core.t0_us, core.plan.next_t_s, cfg.disarm_delay_s, c.ground_armed_s,
                     *watch, f.yaw_target_rad)  # fmt: skip
            f._held.io[12:20] = f.pipeline_inputs()  # type: ignore[union-attr]
            plain.flags = core.flags()
            plain.mode = int(c.current.number)
            ki[2:5] = (_ARMED, plain.flags, plain.mode)
        else:
            kf[0] = self._last_tick_ms
        if self._sim_pending or (self.gcs is not None and c.gcs_loss_may_act(self._mono())):
            # (a simulator parameter awaiting its answer may log a complaint between the state and the answer)
            self._plain_ready = False
            return False
        ki[0] = self.sim.peek_seq()
        ki[1] = self._logmav.seq
        ki[5] = self.clock.now_us()
        held = core.flight._held
        enc = self._answer_encoder
        dec = self._state_decoder
        flown, est = plain.call(data, self._sim_sysid, held, core._est, core._est_params, dec.fo, enc)  # type: ignore[union-attr]
        if not flown:
            self._plain_ready = False
            return False
        # the state as _take_state takes it
        plain.flown += 1
        dec.decoded += 1  # type: ignore[union-attr]
        fo = dec.fo.tolist()  # type: ignore[union-attr]
        t_ms = int(ki[KI_T_MS])
        sim = self.sim
        sim.heard(addr, 4)
        self._att = None
        self._imu = self._truth = None
        self._rejected_ms, self._rejected_repeats = -1, 0
        stats = self.stats
        stats.imu_msgs += 1
        stats.truth_msgs += 1
        self.accel_frd = (fo[15], fo[16], fo[17])
        state = _tuple_new(VehicleState, fo[0:12])
        self.state = state
        self.body_rates = (fo[12], fo[13], fo[14])
        self._state_ms = t_ms
        self._state_wall_s = self._mono()
        t_us = t_ms * 1000
        self.clock.set_us(t_us)  # type: ignore[union-attr]
        # the tick as core.tick and _tick do it
        core.flown_plain(t_us, state, est, float(kf[6]), held.io[_IO_OUT:_IO_TOUCHDOWN + 1].tolist(), plain.flags, plain.mode,  # type: ignore[union-attr]
                         again=ready)  # fmt: skip
        n1 = int(ki[KI_LENGTHS]) & 0xFFFF
        act = enc.out[:n1].tobytes()
        enc.made += 1
        sim.take_seq()
        sim.send_datagram_to(act, self._sim_peer)  # type: ignore[arg-type]
        self._answered(t_us, None, act, None, plain.rec[: int(ki[KI_REC_BYTES])].tobytes())
        # Nothing but this path changes the kernel's inputs until Python does something else: the
        # next plain tick keeps them (_poll_ground, lockstep_between and any other datagram say so)
        self._plain_ready = True
        if self.duration_s is not None and t_ms * 1e-3 >= self.duration_s:
            self._stop = True
        return True

    def _take_state(self, t_ms: int, taken: tuple[VehicleState, tuple[float, float, float], int], imu: tuple | None,
                    truth: tuple | None, att_packet: bytes, lpn_packet: bytes, addr: Address) -> bool:  # fmt: skip
        """A state from the simulator (``taken``: :func:`state_from_wire` of the 12 wire values
        stamped ``t_ms``, with the IMU and the truth that came with it and the two packets, logged
        as they came); flies the tick in lockstep. False when its stamp is not the next one's (counted)."""
        if self._sim_peer is None:
            self._sim_peer = addr
        if not self._stamp_ok(t_ms):
            return False
        state, rates, missing = taken
        if missing:
            self.stats.states_missing_fields += 1
            if missing == 2:
                self.stats.rx_invalid_state += 1
        self.accel_frd, extra = self._take_imu_truth(imu, truth, addr, t_ms)
        if self.tlog is not None:  # stamped as the link stamped it: before the clock moves
            self.tlog.write_many(self.clock.now_us(), (att_packet, lpn_packet, *extra))
        self.state = state
        if not missing or (_isfinite(rates[0]) and _isfinite(rates[1]) and _isfinite(rates[2])):
            self.body_rates = rates
        self._state_ms = t_ms
        self._state_wall_s = self._mono()
        if self.lockstep:
            self.clock.set_us(t_ms * 1000)  # type: ignore[union-attr]
            self._tick(t_ms * 1000, stale=False)
            if self.duration_s is not None and t_ms * 1e-3 >= self.duration_s:
                self._stop = True
        return True

    def _take_imu_truth(self, imu: tuple | None, truth: tuple | None, addr: Address, t_ms: int,
                        ) -> tuple[tuple[float, float, float] | None, tuple[bytes, ...]]:  # fmt: skip
        """The IMU ((time_usec, fields_updated, xacc, yacc, zacc, packet, sender) of HIGHRES_IMU)
        and the truth ((time_usec, packet, sender) of ODOMETRY) that came with the state stamped
        ``t_ms`` from ``addr``: (the accelerometer's specific force for the law, or None; the
        packets to log with the state).
        Only the state's own (same address, same stamp) are taken; a bad one is counted and
        dropped with a rate-limited message. The truth is logged, never flown on."""
        stats = self.stats
        bad = self.sim_complaints.bad
        logged: list[bytes] = []
        accel = None
        if imu is None:
            stats.states_without_imu += 1
        else:
            time_usec, fields_updated, xacc, yacc, zacc, packet, src = imu
            if src != addr:
                stats.foreign_imu += 1
                stats.states_without_imu += 1
            elif time_usec // 1000 != t_ms:
                stats.states_without_imu += 1
                bad("imu_stamp", f"HIGHRES_IMU stamped {time_usec * 1e-6:.6f} s with the state of {t_ms * 1e-3:.3f} s (stale or garbled)")
            elif fields_updated & IMU_ACCEL_BITS != IMU_ACCEL_BITS:
                stats.states_without_imu += 1
                bad("imu_no_accel", f"HIGHRES_IMU without the accelerometer (fields_updated 0x{fields_updated:x})")
            else:
                a = (xacc, yacc, zacc)
                if _isfinite(a[0]) and _isfinite(a[1]) and _isfinite(a[2]):
                    accel = a
                else:  # NaN: the accelerometer dropped out; infinite: garbage, said; both "not measured"
                    stats.imu_accel_missing += 1
                    if any(v == v for v in a if not _isfinite(v)):
                        bad("imu_nonfinite", f"HIGHRES_IMU with an infinite accelerometer value {a} (taken as not measured)")
                logged.append(packet)  # as it came, like a state with NaN fields
                stats.imu_msgs += 1
        if truth is not None:
            time_usec, packet, src = truth
            if src != addr:
                stats.foreign_imu += 1
            elif time_usec // 1000 != t_ms:
                bad("truth_stamp", f"ODOMETRY stamped {time_usec * 1e-6:.6f} s with the state of {t_ms * 1e-3:.3f} s (stale or garbled)")
            else:
                logged.append(packet)
                stats.truth_msgs += 1
        return accel, tuple(logged)

    def _answer_sim(self, packets: tuple[bytes, ...]) -> None:
        """To the simulator only (not to whoever else wrote to the sim port)."""
        peer = self._sim_peer
        if peer is not None:
            self.sim.send_packets_to(packets, peer)
        else:
            self.sim.send_packets(packets)

    def _log_sim(self, msg: mavlink.MAVLink_message) -> None:
        if self.tlog is not None:
            self.tlog.write(self.clock.now_us(), msg.get_msgbuf())

    def _stamp_ok(self, t_ms: int) -> bool:
        """Is a state stamped ``t_ms`` (from the simulator's address) the next one to use?"""
        stats = self.stats
        if self.lockstep:
            last = self._last_tick_ms
            if last < 0:
                return True
            if t_ms == last:
                if self._last_actuator is not None:
                    stats.duplicate_states += 1  # the simulator re-sent (our answer was lost): answer again
                    self._answer_sim((self._last_actuator,))
                return False
            if abs((t_ms - last) * 1000 - self.cfg.period_us) < 1000:  # one period (stamps are whole ms)
                self._rejected_ms, self._rejected_repeats = -1, 0
                return True
            if t_ms < last:
                stats.out_of_order_states += 1
            else:
                stats.wrong_step_states += 1
            if t_ms == self._rejected_ms:
                self._rejected_repeats += 1
            else:
                self._rejected_ms, self._rejected_repeats = t_ms, 1
            # A simulator at another rate shows it on its second state, and then insists (re-sends
            # the state we do not answer); one odd stamp is dropped and costs nothing.
            if t_ms > last and (self.core.ticks == 1 or self._rejected_repeats >= 3):
                raise RateMismatchError(
                    f"the simulator steps {t_ms - last} ms per state but this FC runs at {self.cfg.rate_hz:g} Hz"
                    f" ({self.cfg.period_us / 1000:g} ms): give both the same rate (--rate-hz; FC_RATE_HZ)"
                )
            return False
        last = self._state_ms
        if last < 0:
            return True
        if t_ms <= last:
            if t_ms == last:
                stats.duplicate_states += 1
            else:
                stats.stale_states += 1
            return False
        if (t_ms - last) * 1e-3 > FUTURE_STATE_S + 4.0 * (self._mono() - self._state_wall_s):
            stats.future_states += 1
            return False
        return True

    # -- the simulator's parameters and announcements --------------------------------------------
    def forward_sim_param(self, name: str, value: float) -> None:
        """``PARAM_SET`` of a (checked) SIM_* value to the simulator over the sim link (logged in
        the tlog with the rest of the link); its answer is awaited for 1 wall second."""
        msg = self.sim.mav.param_set_encode(
            self._sim_sysid, SIM_COMPONENT_ID, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32
        )
        peer = self._sim_peer
        if peer is not None:
            self.sim.send_to(msg, peer)
        else:
            self.sim.send(msg)
        self._log_sim(msg)
        self.stats.sim_param_forwards += 1
        self._sim_pending[name] = self._mono()

    def _sim_param_value(self, msg: mavlink.MAVLink_message) -> None:
        """The simulator's PARAM_VALUE: the answer to a forward; a value other than the one we
        set (it refused it) is taken over and told to the ground stations."""
        if msg.get_srcComponent() != SIM_COMPONENT_ID:
            return
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("ascii", "replace")
        name = name.split("\x00", 1)[0]
        if name not in SIM_PARAM_INDEX:
            return
        self.stats.sim_param_answers += 1
        self._sim_pending.pop(name, None)
        value = float(msg.param_value)
        if not _isfinite(value):
            return
        sim = self.params.sim
        if _f32(sim[name]) != value:
            sim[name] = value
            self.gcs_handler.announce_param(name)

    def _check_sim_answers(self, now: float) -> None:
        """One STATUSTEXT warning per forward the simulator has not answered within 1 s."""
        late = [n for n, t in self._sim_pending.items() if now - t > SIM_PARAM_ANSWER_S]
        for name in late:
            del self._sim_pending[name]
            self.stats.sim_param_unanswered += 1
            self.event(mavlink.MAV_SEVERITY_WARNING, f"{name}: no answer from the simulator")

    def _relay_sim_text(self, msg: mavlink.MAVLink_message) -> None:
        """A STATUSTEXT of the simulator (a fault's start or stop): to the ground stations as the
        FC's own (the sim link has logged it already), and a line on stdout."""
        if msg.get_srcComponent() != SIM_COMPONENT_ID:
            return
        text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
        text = text.split("\x00", 1)[0]
        self.stats.sim_statustexts += 1
        self.say(f"fc: {text}")
        if self.gcs is not None:
            self.gcs.send_many(telemetry.statustexts(self.gcs.mav, int(msg.severity), text))

    def _take_gcs(self) -> None:
        """Take what waits on the ground socket off it, unparsed, into the intake by class."""
        gcs = self.gcs
        if gcs is None:
            return
        put, period = self.intake.put, self._period_no
        for data, addr in gcs.recv_datagrams(GCS_DRAIN):
            put(classify(data), (gcs, data, addr), period)

    def _work_intake(self, until: float | None) -> float:
        """Parse and handle queued datagrams, most important and oldest first, until the queue is
        empty or the clock passes ``until`` (None: no limit; at least one is handled). Returns
        the wall seconds it took."""
        mono = self._mono
        t0 = mono()
        intake, period = self.intake, self._period_no
        handle = self.gcs_handler.handle
        while intake:
            item = intake.pop(period)
            assert item is not None
            link, data, addr = item
            if link is self.gcs:
                for msg, src in link.parse(data, addr):
                    handle(msg, src)
            else:  # the simulator link, from another address than the simulator's
                for msg, _ in link.parse(data, addr):
                    if type(msg) is _IMU_MSG or msg.id == _TRUTH_ID:
                        self.stats.foreign_imu += 1
                    elif msg.id == _LPN_ID:
                        self.stats.foreign_states += 1
            if until is not None and mono() >= until:
                break
        return mono() - t0

    def _poll_ground(self) -> None:
        """What waits on the ground socket (up to GCS_DRAIN datagrams) and everything queued,
        handled now (lockstep, and before the first state)."""
        self._plain_ready = False  # (a command may change what the lockstep kernel reads)
        self._take_gcs()
        if self.intake:
            self._work_intake(None)

    # -- the tick ------------------------------------------------------------------------------
    def apply_config(self, cfg: FcConfig) -> None:
        """Live parameter change, the one listener every change goes to: the core (from its next
        tick), the telemetry rates, and this process's loops."""
        self.core.reconfigure(cfg)  # first: a law that refuses the settings (LawError) changes nothing
        self.cfg = cfg
        self.streams.set_telemetry_rate(cfg.telemetry_rate_hz)
        estimator = self.params.options.estimator
        if estimator != self.core.estimator:
            self.core.reconfigure_estimator(estimator)

    def _tick(self, t_us: int, *, stale: bool) -> None:
        """One tick of the flight core, its answer to the simulator, its log record, telemetry."""
        core = self.core
        if core.ticks == 0:
            self._cpu_at_first_tick_s = time.process_time()
            self.say(f"FC_READY t={t_us * 1e-6:.3f}s controller={self.cfg.controller} lockstep={self.lockstep}")
        out = core.tick(t_us, self.state, fresh=not stale, wall_s=self._mono() if self.gcs is not None else None, accel_frd=self.accel_frd)
        made = None
        enc = self._answer_encoder
        if enc is not None:
            f = core.flight
            if out.pipeline is f.held_out and f.diag_mask == enc.mask:  # (this tick's outputs are the compiled tick's)
                made = enc.encode(f.held_io, t_us, self.sim.peek_seq(), _ARMED if out.armed else 0, self._logmav.seq, out.flags,
                                  out.mode, f.target, f.yaw_target_rad)  # fmt: skip
        if made is not None:  # the same bytes as below, made compiled in one call (fc.state_kernel)
            act, smc = made
            self.sim.take_seq()
        else:
            act = self._actuator_packet(t_us, out)
            smc = None
        self._answer_sim((act,))
        self._answered(t_us, out, act, smc)

    def _answered(self, t_us: int, out: TickOutput | None, act: bytes, smc: bytes | None, records: bytes | None = None) -> None:
        """The rest of the tick at ``t_us`` once its answer ``act`` is sent to the simulator: its
        log records (``smc``, or made here of ``out``; or ``records``: the tick's six, made by the
        lockstep kernel), the ground's telemetry."""
        self._last_actuator = act
        self._last_tick_ms = self._state_ms
        if self._sim_pending:
            self._check_sim_answers(self._mono())
        tlog = self.tlog
        if tlog is not None:
            lm = self._logmav
            if records is not None:
                tlog.write_records(records, 6)
            else:
                tlog.write(self.clock.now_us(), act)
                if smc is None:
                    assert out is not None
                    smc = self._records.smc(lm.seq, t_us, telemetry.smc_record(self.core, out))
                tlog.write(t_us, smc)
            lm.seq = (lm.seq + 1) & 0xFF
            self._unflushed_ticks += 1
            if self._unflushed_ticks >= self._flush_ticks:
                self._unflushed_ticks = 0
                tlog.flush()
        t_ground = self._mono()
        self.gcs_handler.on_tick(t_us, None if self.lockstep else t_ground + TELEMETRY_SHARE * self.cfg.period_s)
        self._gcs_tick_s = self._mono() - t_ground
        self._period_no += 1

    def _actuator_packet(self, t_us: int, out: TickOutput) -> bytes:
        """The tick's answer to the simulator: HIL_ACTUATOR_CONTROLS, controls[0..3] our rotors 1..4."""
        return self._sim_records.actuators(self.sim.take_seq(), t_us, out.motors, _ARMED if out.armed else 0,
                                       ACTUATOR_FLAG_LOCKSTEP if self.lockstep else 0)  # fmt: skip

    def _item_reached(self, seq: int) -> None:
        """``MISSION_ITEM_REACHED`` to every ground station."""
        if self.gcs is not None:
            self.gcs.send(self.gcs.mav.mission_item_reached_encode(seq))

    def event(self, severity: int, text: str) -> None:
        """A STATUSTEXT to ground stations (and the log), and a line on stdout."""
        self.say(f"fc: {text}")
        if self.gcs is not None:
            self.gcs.send_many(telemetry.statustexts(self.gcs.mav, severity, text))
        elif self.tlog is not None:
            lm = self._logmav
            self.tlog.write_many(self.clock.now_us(), [m.pack(lm) for m in telemetry.statustexts(lm, severity, text)])


def install_signal_handlers(app: FlightControllerApp) -> None:
    """SIGTERM and SIGINT end the loop cleanly (the tlog is closed, the summary printed)."""
    signal.signal(signal.SIGTERM, app.request_stop)
    signal.signal(signal.SIGINT, app.request_stop)
