"""The ground-station protocol of the flight controller (docs/gcs-protocol.md).

:class:`GcsHandler` dispatches every message from the ground link — commands, modes, set-points,
parameters, missions, stream requests — to the commander, the parameter store and the mission
protocol, answers the sender, and sends the telemetry the stream scheduler says is due (built by
:func:`fc.telemetry.build` from one :class:`fc.telemetry.TelemetrySnapshot`). It is given its
collaborators explicitly and knows nothing of the process that runs it (:mod:`fc.app`).
The commander's refusals (:class:`fc.modes.Refusal`) become ``COMMAND_ACK`` results and
``STATUSTEXT`` here, and only here. Bad input never raises: it is refused with the protocol's code (``COMMAND_ACK`` result,
``MISSION_ACK`` error, unchanged ``PARAM_VALUE``) and a ``STATUSTEXT``, or dropped and counted.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import inbound, inject, telemetry
from fc.config import FcConfig
from fc.control.law import LawError
from fc.core import EventSink, FlightCore
from fc.mission import GLOBAL_FRAMES, RELATIVE_FRAMES, MissionItem, MissionProtocol
from fc.modes import Refusal
from fc.params import ParamError, ParamStore, is_sim_param, param_table
from fc.streams import StreamScheduler, interval_refusal
from fc.telemetry import CAPABILITIES, IGNORE_POS, IGNORE_YAW, TelemetrySnapshot
from smcpilot.faults import SIM_PARAM_INDEX, SIM_PARAMS
from smcpilot.link import LinkCounters
from smcpilot.protocol import FORCE_ARM_MAGIC, Mode
from smcpilot.signing import Signing

M = mavlink
Address = tuple[str, int]

_FTP_NAK = 129
_FTP_FILE_NOT_FOUND = 10
#: a command we do not implement: MAV_RESULT_UNSUPPORTED, no STATUSTEXT.
_UNSUPPORTED = Refusal("", M.MAV_RESULT_UNSUPPORTED)
#: Refusal STATUSTEXTs: at most one per REFUSAL_TEXT_PERIOD_S per reason (whoever asked), and in
#: all a bucket of REFUSAL_TEXT_BURST texts refilled at REFUSAL_TEXT_RATE_HZ (a flood of distinct
#: reasons gets 20 texts, then 5 a second).
REFUSAL_TEXT_PERIOD_S = 1.0
REFUSAL_TEXT_BURST = 20
REFUSAL_TEXT_RATE_HZ = 5.0
#: Messages whose sender is a station that matters: it keeps its place in the peer table.
_PIN_MSG_IDS = frozenset({
    M.MAVLINK_MSG_ID_COMMAND_LONG, M.MAVLINK_MSG_ID_COMMAND_INT, M.MAVLINK_MSG_ID_SET_MODE, M.MAVLINK_MSG_ID_PARAM_SET,
    M.MAVLINK_MSG_ID_MISSION_COUNT, M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
    M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT, M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
})  # fmt: skip
#: streamed telemetry goes to the configured destination and every station that matters (pinned:
#: it commanded, or signed), and to this many of the other peers per batch, in turn: a table full
#: of strangers (a heartbeat flood) costs a bounded number of sends.
TELEMETRY_OTHER_PEERS = 4
#: PARAM_REQUEST_LIST: values sent per control tick for each list under way (the table of ~180
#: goes out in 8 ticks, 16 ms at 500 Hz), and the lists under way at once (one per station).
PARAM_LIST_CHUNK = 24
PARAM_LISTS_AT_ONCE = 4
_GLOBAL_FRAMES = (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)


class GroundLink(Protocol):
    """The ground link as the handler uses it (:class:`smcpilot.link.MavlinkUdp`)."""

    @property
    def mav(self) -> mavlink.MAVLink: ...

    def send(self, msg: mavlink.MAVLink_message) -> None: ...

    def send_many(self, msgs: Iterable[mavlink.MAVLink_message], *, others_limit: int | None = None) -> int: ...

    def send_to(self, msg: mavlink.MAVLink_message, addr: Address) -> None: ...

    def send_many_to(self, msgs: Iterable[mavlink.MAVLink_message], addr: Address) -> None: ...


class GcsHandler:
    """Dispatches ground-link messages to explicit collaborators.

    - ``core``: the flight core (its commander carries out commands; home; the GCS heartbeat);
    - ``mission``: the mission protocol (uploads, downloads, set-current);
    - ``params``: the parameter store; ``apply_config``: the one listener every accepted
      parameter change goes to (it reaches the core and the streams);
    - ``streams``: the telemetry scheduler; ``snapshot``: the telemetry snapshot provider
      (:func:`fc.telemetry.snapshot`), called once per batch of due messages or per request;
    - ``link``: the ground link (None: none; then only :meth:`on_tick` is called);
    - ``event``: the event sink (``STATUSTEXT`` to ground stations, a line on stdout);
      ``log``: a line on stdout only;
    - ``wall_s``: the real-time clock for protocol timeouts and the GCS-loss failsafe;
    - ``forward_sim``: sends one ``SIM_*`` parameter value to the simulator (``PARAM_SET`` over
      the sim link; None: no simulator link, and SIM_* changes are refused);
    - ``signing``: the ground link's signing state, which ``SETUP_SIGNING`` changes (None: the
      message is ignored); ``trusted``: the ground link is declared trusted (``SETUP_SIGNING``
      accepted from it even while a key is set, unsigned).
    """

    def __init__(
        self,
        *,
        core: FlightCore,
        mission: MissionProtocol,
        params: ParamStore,
        streams: StreamScheduler,
        link: GroundLink | None,
        event: EventSink,
        log: Callable[[str], None],
        snapshot: Callable[[], TelemetrySnapshot],
        apply_config: Callable[[FcConfig], None],
        wall_s: Callable[[], float] = time.monotonic,
        forward_sim: Callable[[str, float], None] | None = None,
        signing: Signing | None = None,
        trusted: bool = False,
    ) -> None:
        self.core = core
        self.commander = core.commander
        self.mission = mission
        self.params = params
        self.streams = streams
        self.link = link
        self.mav: mavlink.MAVLink = link.mav if link is not None else mavlink.MAVLink(None)
        self._event = event
        self._log = log
        self.snapshot = snapshot
        self._apply_config = apply_config
        self.wall_s = wall_s
        self._forward_sim = forward_sim
        #: reason -> count of dropped or refused messages
        self.rejected: Counter[str] = Counter()
        mission.on_reject = lambda reason, text: self._refuse(reason, text)
        self.gcs_heartbeats = 0
        self._last_reject_text_s: dict[str, float] = {}
        #: the refusal-text bucket: (tokens, wall time of the last update).
        self._text_bucket: tuple[float, float] = (float(REFUSAL_TEXT_BURST), -math.inf)
        #: refusal STATUSTEXTs not sent because of the rate limit.
        self.texts_suppressed = 0
        #: streamed telemetry batches not sent to a peer (beyond TELEMETRY_OTHER_PEERS).
        self.telemetry_peers_skipped = 0
        #: streamed messages deferred to the next tick (real time: the budget ran out), and the
        #: ids deferred last time (they go first next time).
        self.telemetry_deferred = 0
        self._late_streams: set[int] = set()
        self.signing = signing
        self.trusted = trusted
        #: drop-rate window: (wall start, rejected, good) at its start; the last window's rate.
        self._drop_window: tuple[float, int, int] = (-math.inf, 0, 0)
        self._drop_rate = 0
        self._refusal_counted = False
        #: parameter lists under way: station -> the next index to send (oldest request first).
        self._param_lists: dict[Address, int] = {}
        self._handlers: dict[int, Callable[[mavlink.MAVLink_message, Address], None]] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            M.MAVLINK_MSG_ID_COMMAND_LONG: self._command_long,
            M.MAVLINK_MSG_ID_COMMAND_INT: self._command_int,
            M.MAVLINK_MSG_ID_SET_MODE: self._set_mode_msg,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: self._target_local,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: self._target_global,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self._param_list,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self._param_read,
            M.MAVLINK_MSG_ID_PARAM_SET: self._param_set,
            M.MAVLINK_MSG_ID_MISSION_COUNT: lambda m, a: mission.on_count(m, a, self.wall_s()),
            M.MAVLINK_MSG_ID_MISSION_ITEM_INT: self._mission_item,
            M.MAVLINK_MSG_ID_MISSION_ITEM: self._mission_item,
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: lambda m, a: mission.on_request_list(m, a),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_INT: lambda m, a: mission.on_request(m, a, True),
            M.MAVLINK_MSG_ID_MISSION_REQUEST: lambda m, a: mission.on_request(m, a, False),
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: lambda m, a: mission.on_clear(m, a),
            M.MAVLINK_MSG_ID_MISSION_SET_CURRENT: self._mission_set_current,
            M.MAVLINK_MSG_ID_MISSION_ACK: lambda m, a: None,
            M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self._request_data_stream,
            M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self._ftp,
            M.MAVLINK_MSG_ID_SETUP_SIGNING: self._setup_signing,
        }

    # -- plumbing -------------------------------------------------------------------------------
    def _send_to(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        if self.link is not None:
            self.link.send_to(msg, addr)

    def _broadcast(self, msg: mavlink.MAVLink_message) -> None:
        if self.link is not None:
            self.link.send(msg)

    def _for_us(self, target_system: int, target_component: int | None = None) -> bool:
        if target_system not in (0, self.core.config.system_id):
            self.rejected["other_system"] += 1
            return False
        if target_component is not None and target_component not in (0, 1):
            self.rejected["other_component"] += 1
            return False
        return True

    def _refuse(self, reason: str, text: str, addr: Address | None = None) -> None:
        """Count a refused message and say why (rate-limited: :meth:`_refusal_text`)."""
        self.rejected[reason] += 1
        self._refusal_text(reason, text)

    def _refusal_text(self, key: str, text: str, severity: int = M.MAV_SEVERITY_WARNING) -> None:
        """A refusal's STATUSTEXT (and stdout line): at most one per ``REFUSAL_TEXT_PERIOD_S``
        per ``key`` whoever asked, and in all no more than the bucket allows
        (``REFUSAL_TEXT_BURST``, refilled at ``REFUSAL_TEXT_RATE_HZ``), so a flood of bad
        requests from any number of stations cannot flood the ground link or the console."""
        now = self.wall_s()
        if now - self._last_reject_text_s.get(key, -math.inf) < REFUSAL_TEXT_PERIOD_S:
            self.texts_suppressed += 1
            return
        tokens, then = self._text_bucket
        tokens = min(float(REFUSAL_TEXT_BURST), tokens + max(0.0, now - then) * REFUSAL_TEXT_RATE_HZ)
        if tokens < 1.0:
            self._text_bucket = (tokens, now)
            self.texts_suppressed += 1
            return
        self._text_bucket = (tokens - 1.0, now)
        if len(self._last_reject_text_s) > 256:
            self._last_reject_text_s.clear()
        self._last_reject_text_s[key] = now
        self._event(severity, text)

    def comm_errors(self, sim: LinkCounters | None = None) -> tuple[int, int, int, int, int, int]:
        """SYS_STATUS's communication counters, totals since start (uint16 on the wire):

        - ``errors_comm``: every packet rejected on the ground link (bad bytes, unknown ids,
          foreign systems, signing) plus every message this handler dropped or refused;
        - ``drop_rate_comm``: the ground link's rejected share of the packets of the last wall
          second or so, in c% (0..10000);
        - ``errors_count1``: ground-link bad frames (garbage, truncated, bad CRC, unknown id,
          foreign system); ``errors_count2``: ground-link signing rejections (unsigned, bad
          signature, old timestamp, stream out of window); ``errors_count3``: protocol
          refusals and drops of this handler; ``errors_count4``: sim-link packets rejected.
        """
        c: LinkCounters | None = getattr(self.link, "counters", None)
        protocol = self.rejected_total
        if c is None:
            bad = signing = 0
            rejected = good = 0
        else:
            signing = c.rx_signing_rejected
            rejected = c.rx_rejected
            bad = rejected - signing
            good = c.rx_messages
        now = self.wall_s()
        w = self._drop_window
        if now - w[0] >= 1.0:
            # a new window: the rate of the one that just ended
            d_rej, d_all = rejected - w[1], (rejected - w[1]) + (good - w[2])
            self._drop_rate = int(round(10000 * d_rej / d_all)) if d_all > 0 else 0
            self._drop_window = (now, rejected, good)
        sim_rejected = sim.rx_rejected if sim is not None else 0
        return (rejected + protocol, self._drop_rate, bad, signing, protocol, sim_rejected)

    @property
    def rejected_total(self) -> int:
        """Every message this handler dropped or refused (the mission protocol's included)."""
        return sum(self.rejected.values()) + self.mission.refused + self.mission.ignored

    def handle(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        # get_msgId(), not .id: STATUSTEXT has a field named "id" that hides the message id
        # (a ground station's STATUSTEXT with id 0 would reach the HEARTBEAT handler)
        mid = msg.get_msgId()
        handler = self._handlers.get(mid)
        if handler is None:
            return
        ts = getattr(msg, "target_system", None)
        if ts is not None and mid != M.MAVLINK_MSG_ID_HEARTBEAT and not self._for_us(ts):
            return
        if mid in _PIN_MSG_IDS:
            pin = getattr(self.link, "pin_peer", None)
            if pin is not None:
                pin(addr)
        try:
            handler(msg, addr)
        except Exception as exc:  # a hostile packet must never stop the loop
            self.rejected["handler_error"] += 1
            self._log(f"fc: ignored {msg.get_type()} from {addr[0]}:{addr[1]}: {type(exc).__name__}: {exc}")

    # -- messages -------------------------------------------------------------------------------
    def _heartbeat(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if m.type == M.MAV_TYPE_GCS:
            self.gcs_heartbeats += 1
            self.core.on_gcs_heartbeat(self.wall_s())

    def _ack(self, addr: Address, m: mavlink.MAVLink_message, command: int, refusal: Refusal | None) -> None:
        """``COMMAND_ACK`` to the sender: ACCEPTED, or the refusal's code with a ``STATUSTEXT``
        saying why (the one place a refusal becomes protocol)."""
        if refusal is None:
            code = M.MAV_RESULT_ACCEPTED
        else:
            code = refusal.code
            if refusal is not _UNSUPPORTED and not self._refusal_counted:  # (those are counted where they arise)
                self.rejected["command_refused"] += 1
            self._refusal_counted = False
            if refusal.reason:
                self._refusal_text(refusal.reason, refusal.reason)
        self._send_to(self.mav.command_ack_encode(command, code, 0, 0, m.get_srcSystem(), m.get_srcComponent()), addr)

    def _command_long(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        self._ack(addr, m, m.command, self._command(m.command, p, None, addr, m))

    def _command_int(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        p = (m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z)
        self._ack(addr, m, m.command, self._command(m.command, p, m.frame, addr, m))

    def _command(self, cmd: int, p: tuple[float, ...], frame: int | None, addr: Address, m) -> Refusal | None:
        c = self.commander
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = p[1] == FORCE_ARM_MAGIC
            if p[0] == 1.0:
                return c.arm(force)
            if p[0] == 0.0:
                return c.disarm(force)
            return Refusal(f"Arm/disarm: param1 must be 0 or 1, got {p[0]!r}")
        if cmd == M.MAV_CMD_NAV_TAKEOFF:
            return c.takeoff(p[6])
        if cmd == M.MAV_CMD_NAV_LAND:
            return c.land()
        if cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return c.rtl()
        if cmd == M.MAV_CMD_MISSION_START:
            first = int(p[0]) if math.isfinite(p[0]) and p[0] >= 0 else 0
            return c.mission_start(first)
        if cmd == M.MAV_CMD_DO_SET_MODE:
            if not math.isfinite(p[0]) or not int(p[0]) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return Refusal("Set mode: only custom modes (base mode bit 1) are supported")
            if not math.isfinite(p[1]):
                return Refusal("Set mode: mode number is not a number")
            return c.set_mode(int(p[1]))
        if cmd == M.MAV_CMD_DO_REPOSITION:
            if frame is None:  # COMMAND_LONG: lat/lon degrees in param5/6, altitude above home in param7
                return c.reposition(p[4], p[5], p[6], True, p[3])
            if frame not in _GLOBAL_FRAMES:
                return Refusal(f"Reposition: frame {frame} not supported")
            return c.reposition(p[4] * 1e-7, p[5] * 1e-7, p[6], frame in RELATIVE_FRAMES, p[3])
        if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not (math.isfinite(p[0]) and math.isfinite(p[1])):
                return Refusal("Message interval: non-finite parameter")
            why = interval_refusal(int(p[0]), p[1])
            if why is not None:
                self.rejected["bad_interval"] += 1
                self._refusal_counted = True
                return Refusal(why)
            self.streams.set_interval(int(p[0]), p[1])
            return None
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            if not math.isfinite(p[0]):
                return Refusal("Request message: id is not a number")
            msgs = self.build(int(p[0]))
            if not msgs:
                self.rejected["unsupported_message"] += 1
                return _UNSUPPORTED
            for msg in msgs:
                self._send_to(msg, addr)
            return None
        if cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._send_to(self.build(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)[0], addr)
            return None
        if cmd == M.MAV_CMD_GET_HOME_POSITION:
            self._send_to(self.build(M.MAVLINK_MSG_ID_HOME_POSITION)[0], addr)
            return None
        if cmd == M.MAV_CMD_RUN_PREARM_CHECKS:  # ArduPilot's answer: ACCEPTED, the failure said
            why = c.prearm_failure()
            self._event(M.MAV_SEVERITY_WARNING if why else M.MAV_SEVERITY_INFO, why or "PreArm: checks pass")
            return None
        if cmd == M.MAV_CMD_INJECT_FAILURE:
            return self._inject_failure(p)
        if cmd == M.MAV_CMD_DO_SET_MISSION_CURRENT:
            if not math.isfinite(p[0]) or not self.mission.set_current(int(p[0])):
                return Refusal(f"Set current: no mission item {p[0]!r}")
            self._broadcast(self.build(M.MAVLINK_MSG_ID_MISSION_CURRENT)[0])
            return None
        self.rejected["unsupported_command"] += 1
        return _UNSUPPORTED

    def _set_mode_msg(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not m.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            refusal: Refusal | None = Refusal("Set mode: only custom modes are supported")
        else:
            refusal = self.commander.set_mode(m.custom_mode)
        self._ack(addr, m, M.MAVLINK_MSG_ID_SET_MODE, refusal)

    def _target_component_ok(self, m: mavlink.MAVLink_message, addr: Address) -> bool:
        """A set-point addressed to another component of this system is not flown (counted,
        and the sender told once a second)."""
        if m.target_component in (0, 1):
            return True
        self._refuse("other_component", f"Set-point for component {m.target_component} not flown (this FC is component 1)", addr)
        return False

    def _target_local(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._target_component_ok(m, addr):
            return
        if m.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
            self._refuse("unsupported_frame", f"Set-point: frame {m.coordinate_frame} not supported (use LOCAL_NED)", addr)
            return
        if m.type_mask & IGNORE_POS:
            self._refuse("no_position", "Set-point: only position targets are supported", addr)
            return
        yaw = None if m.type_mask & IGNORE_YAW else m.yaw
        if yaw is not None and not math.isfinite(yaw):
            self._refuse("non_finite", "Set-point: yaw is not a number", addr)
            return
        refusal = self.commander.goto(inbound.local_ned_target(m.x, m.y, m.z, yaw))
        if refusal is not None:
            self._refuse("setpoint_refused", refusal.reason or "Set-point refused", addr)

    def _target_global(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._target_component_ok(m, addr):
            return
        if not (-90 * 10**7 <= m.lat_int <= 90 * 10**7 and -180 * 10**7 <= m.lon_int <= 180 * 10**7):
            self._refuse("setpoint_refused", "Set-point refused: latitude/longitude out of range", addr)
            return
        if m.coordinate_frame not in _GLOBAL_FRAMES:
            self._refuse("unsupported_frame", f"Set-point: frame {m.coordinate_frame} not supported", addr)
            return
        if m.type_mask & IGNORE_POS:
            self._refuse("no_position", "Set-point: only position targets are supported", addr)
            return
        if not math.isfinite(m.alt):
            self._refuse("non_finite", "Set-point: altitude is not a number", addr)
            return
        yaw = None if m.type_mask & IGNORE_YAW else m.yaw
        target = inbound.global_target(
            self.core.home, m.lat_int * 1e-7, m.lon_int * 1e-7, m.alt, m.coordinate_frame in RELATIVE_FRAMES, yaw
        )
        refusal = self.commander.goto(target)
        if refusal is not None:
            self._refuse("setpoint_refused", refusal.reason or "Set-point refused", addr)

    # -- parameters -----------------------------------------------------------------------------
    # Indices 0..len(PARAMS)-1 are the FC's parameters, then the simulator's SIM_* (volatile,
    # forwarded to the simulator on a change): param_table().count in all.
    def _param_msg(self, index: int, value: float | None = None) -> mavlink.MAVLink_message:
        """PARAM_VALUE of parameter ``index``: ``value``, or the value in force."""
        if index >= param_table().sim_offset:
            sp = SIM_PARAMS[index - param_table().sim_offset]
            name, is_int = sp.name, sp.is_int
            value = self.params.sim[sp.name] if value is None else value
        else:
            p = param_table().specs[index]
            name, is_int = p.name, p.is_int
            value = self.params.value(p.name) if value is None else value
        ptype = M.MAV_PARAM_TYPE_INT32 if is_int else M.MAV_PARAM_TYPE_REAL32
        return self.mav.param_value_encode(name.encode(), float(value), ptype, param_table().count, index)

    @staticmethod
    def _param_index(name: str) -> int | None:
        index = param_table().index.get(name)
        if index is None and name in SIM_PARAM_INDEX:
            index = param_table().sim_offset + SIM_PARAM_INDEX[name]
        return index

    def announce_param(self, name: str) -> None:
        """``PARAM_VALUE`` of ``name`` to every ground station (a value changed without a
        ``PARAM_SET`` from them, e.g. the simulator answered another value)."""
        index = self._param_index(name)
        if index is not None:
            self._broadcast(self._param_msg(index))

    def _param_list(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        """The whole table, sent :data:`PARAM_LIST_CHUNK` values a tick (from :meth:`on_tick`), as
        ArduPilot streams it: a request costs the loop a few values a tick, never the whole table at
        once. A repeated request from the same station starts its list again; past
        :data:`PARAM_LISTS_AT_ONCE` stations the oldest list is dropped (counted; a station asks
        for what it misses by index)."""
        if not self._for_us(m.target_system, m.target_component):
            return
        jobs = self._param_lists
        jobs.pop(addr, None)
        jobs[addr] = 0
        if len(jobs) > PARAM_LISTS_AT_ONCE:
            del jobs[next(iter(jobs))]
            self.rejected["param_list_dropped"] += 1

    def send_param_lists(self, *, all_now: bool = False) -> None:
        """One chunk of every parameter list under way (:meth:`_param_list`), or with ``all_now``
        the rest of each (between ticks, when no deadline waits: lockstep with the simulator
        silent, real time before the first state)."""
        jobs = self._param_lists
        if not jobs or self.link is None:
            return
        count = param_table().count
        for addr in list(jobs):
            start = jobs[addr]
            end = count if all_now else min(count, start + PARAM_LIST_CHUNK)
            self.link.send_many_to([self._param_msg(i) for i in range(start, end)], addr)
            if end >= count:
                del jobs[addr]
            else:
                jobs[addr] = end

    def _param_read(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        name = _param_name(m.param_id)
        if m.param_index >= 0:
            index = m.param_index if m.param_index < param_table().count else -1
        else:
            found = self._param_index(name)
            index = -1 if found is None else found
        if index < 0:
            self._refuse("unknown_param", f"Param read: unknown {name or m.param_index}", addr)
            return
        self._send_to(self._param_msg(index), addr)

    def _param_set(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        name = _param_name(m.param_id)
        if is_sim_param(name):
            self._sim_param_set(name, float(m.param_value), addr)
            return
        index = param_table().index.get(name)
        if index is None:
            self._refuse("unknown_param", f"Param set: unknown {name}", addr)
            return
        old = self.params.value(name)
        try:
            cfg = self.params.set(name, float(m.param_value), persist=False)
            self._apply_config(cfg)  # the flying law flattens its constants: it may still refuse
        except (ParamError, LawError) as exc:
            if isinstance(exc, LawError):
                self.params.set(name, old, persist=False)  # undone: the law refused the value
            self.rejected["param_refused"] += 1
            self._refusal_text(str(exc), str(exc))
            self._send_to(self._param_msg(index), addr)  # the value in force, unchanged
            return
        try:
            if self.params.path is not None:
                self.params.save(token=(name, index))
        except OSError as exc:
            self._event(M.MAV_SEVERITY_ERROR, f"Param file not written: {exc.strerror or exc}")
        if param_table().specs[index].restart:
            self._event(M.MAV_SEVERITY_INFO, f"{name} takes effect at the next start")
        if not self.params.acks_wait_for_disk:
            self._broadcast(self._param_msg(index))
        # else: acknowledged by on_tick once the parameter file holding it is on disk

    def send_durable_acks(self) -> None:
        """PARAM_VALUE for every change now on disk (the value as written); a change that could not
        be saved is undone, said so, and the value in force echoed."""
        for (name, index), value, exc in self.params.durable_acks():
            if exc is not None:
                self._apply_config(self.params.config)
                self._event(M.MAV_SEVERITY_ERROR, f"{name} not saved ({exc.strerror or exc}): kept {value:g}")
            self._broadcast(self._param_msg(index, value))

    def _sim_param_set(self, name: str, value: float, addr: Address) -> None:
        """A simulator parameter: validated here (the pair of a sensor fault too), recorded,
        forwarded to the simulator and echoed at once (as ArduPilot answers); a refusal gets the
        value in force back and a STATUSTEXT with the reason."""
        index = param_table().sim_offset + SIM_PARAM_INDEX[name]
        try:
            if self._forward_sim is None:
                raise ParamError(f"{name}: no simulator link to forward it to")
            v = self.params.check_sim(name, value)
        except ParamError as exc:
            self.rejected["param_refused"] += 1
            self._refusal_text(str(exc), str(exc))
            self._send_to(self._param_msg(index), addr)
            return
        self._set_sim(name, v)

    def _set_sim(self, name: str, value: float) -> None:
        """Record, forward to the simulator and announce to the ground one checked SIM_* value."""
        assert self._forward_sim is not None
        self.params.set_sim(name, value)
        self._forward_sim(name, value)
        self.announce_param(name)

    # -- failure injection ----------------------------------------------------------------------
    def _inject_failure(self, p: tuple[float, ...]) -> Refusal | None:
        """MAV_CMD_INJECT_FAILURE: the SIM_* changes of :func:`fc.inject.injection`, each
        forwarded like a PARAM_SET; refused unless SYS_FAILURE_EN is 1."""
        if not self.params.options.failure_enabled:
            return Refusal("failure injection disabled (SYS_FAILURE_EN=0)")
        result = inject.injection(p[0], p[1], p[2], self.params.sim)
        if isinstance(result, Refusal):
            self.rejected["inject_refused"] += 1
            self._refusal_counted = True
            return result
        if self._forward_sim is None:
            return Refusal("Inject: no simulator link", M.MAV_RESULT_UNSUPPORTED)
        try:
            for name, value in result.changes:  # valid one by one: fc.inject orders them so
                self.params.check_sim(name, value)
                self._set_sim(name, value)
        except ParamError as exc:  # pragma: no cover - fc.inject gives valid changes only
            return Refusal(f"Inject: {exc}")
        self._event(M.MAV_SEVERITY_WARNING if result.failure else M.MAV_SEVERITY_INFO, result.text)
        return None

    # -- missions, streams, FTP -----------------------------------------------------------------
    def _mission_item(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        """``MISSION_ITEM(_INT)``: ``current`` 2 is ArduPilot's guided-mode waypoint (fly there
        now), 3 an altitude change only; both answered with ``MISSION_ACK``. Anything else is an
        upload's item (:meth:`fc.mission.MissionProtocol.on_item`)."""
        if m.current in (2, 3) and getattr(m, "mission_type", 0) == M.MAV_MISSION_TYPE_MISSION:
            if m.get_type() == "MISSION_ITEM":
                self.mission.note_legacy(addr)
            refusal = self._guided_item(m)
            if refusal is None:
                result = M.MAV_MISSION_ACCEPTED
            else:
                result = refusal.code
                self._refuse("guided_item_refused", refusal.reason, addr)
            ack = self.mav.mission_ack_encode(m.get_srcSystem(), m.get_srcComponent(), result, M.MAV_MISSION_TYPE_MISSION)
            self._send_to(ack, addr)
            return
        self.mission.on_item(m, addr, self.wall_s())

    def _guided_item(self, m: mavlink.MAVLink_message) -> Refusal | None:
        """The target of a guided-mode mission item (``current`` 2: position, 3: altitude only),
        validated like every other target source; a refusal carries a ``MAV_MISSION_*`` code."""
        item = MissionItem.from_msg(m)
        if item.frame not in GLOBAL_FRAMES:
            return Refusal(f"Guided item: frame {m.frame} not supported", M.MAV_MISSION_UNSUPPORTED_FRAME)
        if not math.isfinite(item.z):
            return Refusal("Guided item: altitude is not a number", M.MAV_MISSION_INVALID_PARAM7)
        if self.commander.mode != Mode.GUIDED:
            return Refusal(f"Guided item: needs GUIDED, in {self.commander.mode.name}", M.MAV_MISSION_ERROR)
        home = self.core.home
        if m.current == 3:
            x, y, _z = self.core.flight.target
            z = inbound.altitude_above_home(home, item.z, item.frame in RELATIVE_FRAMES)
            target = inbound.Target(x, y, z, None)
        else:
            if not (-90 * 10**7 <= item.x <= 90 * 10**7):
                return Refusal("Guided item: latitude out of range", M.MAV_MISSION_INVALID_PARAM5_X)
            if not (-180 * 10**7 <= item.y <= 180 * 10**7):
                return Refusal("Guided item: longitude out of range", M.MAV_MISSION_INVALID_PARAM6_Y)
            target = inbound.global_target(home, item.lat_deg, item.lon_deg, item.z, item.frame in RELATIVE_FRAMES, None)
        refusal = self.commander.goto(target)
        if refusal is not None:
            return Refusal(refusal.reason or "Guided item refused", M.MAV_MISSION_ERROR)
        return None

    def _mission_set_current(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self.mission.set_current(m.seq):
            self._refuse("bad_mission_seq", f"Mission: no item {m.seq}", addr)
        self._broadcast(self.build(M.MAVLINK_MSG_ID_MISSION_CURRENT)[0])

    def _request_data_stream(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        refusal = self.streams.request_stream(m.req_stream_id, m.req_message_rate, bool(m.start_stop))
        if refusal is not None:
            self._refuse("bad_stream_request", refusal, addr)

    def _setup_signing(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        """``SETUP_SIGNING``: a new key (all zeros: signing off), accepted from a trusted link,
        while no key is set, or signed with the current key; refused while armed. The key is
        never printed or logged (the link zeroes it in the tlog)."""
        signing = self.signing
        if signing is None or not self._for_us(m.target_system, m.target_component):
            return
        if signing.enabled and not self.trusted and not getattr(m, "_signed", False):
            self._refuse("signing_untrusted", "Signing: SETUP_SIGNING refused (not signed, link not trusted)", addr)
            return
        if self.core.flight.armed:
            self._refuse("signing_armed", "Signing: SETUP_SIGNING refused while armed", addr)
            return
        key = bytes(m.secret_key)
        signing.set_key(key, int(m.initial_timestamp))
        self._event(M.MAV_SEVERITY_INFO, "Signing enabled" if signing.enabled else "Signing disabled")

    def _ftp(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        """NAK every MAVLink-FTP request (FileNotFound): MAVProxy then uses the parameter protocol."""
        payload = bytes(m.payload)
        seq = (payload[0] | payload[1] << 8) if len(payload) >= 2 else 0
        session = payload[2] if len(payload) > 2 else 0
        opcode = payload[3] if len(payload) > 3 else 0
        reply = bytearray(251)
        reply[0:2] = ((seq + 1) & 0xFFFF).to_bytes(2, "little")
        reply[2] = session
        reply[3] = _FTP_NAK
        reply[4] = 1
        reply[5] = opcode
        reply[12] = _FTP_FILE_NOT_FOUND
        self._send_to(self.mav.file_transfer_protocol_encode(0, m.get_srcSystem(), m.get_srcComponent(), list(reply)), addr)

    # -- telemetry ------------------------------------------------------------------------------
    def stream(self, t_us: int, until: float | None = None) -> None:
        """Send what the scheduler says is due (one batch per peer, from one snapshot; beyond the
        stations that matter, to :data:`TELEMETRY_OTHER_PEERS` others at a time). With ``until``
        (a wall time: real time's budget), the heartbeat and then the messages deferred last time
        go first, and what is not built by then is deferred to the next tick (counted)."""
        link = self.link
        if link is None:
            return
        due = self.streams.due(t_us)
        if not due:
            return
        snap = self.snapshot()
        mav = self.mav
        msgs: list[mavlink.MAVLink_message] = []
        if until is None:
            for mid in due:
                msgs.extend(telemetry.build(mid, snap, mav))
        else:
            late = self._late_streams
            due.sort(key=lambda mid: (mid != M.MAVLINK_MSG_ID_HEARTBEAT, mid not in late))
            wall_s = self.wall_s
            for k, mid in enumerate(due):
                if k and mid != M.MAVLINK_MSG_ID_HEARTBEAT and wall_s() >= until:
                    rest = due[k:]
                    self.streams.defer(rest, t_us + 1)
                    self.telemetry_deferred += len(rest)
                    self._late_streams = set(rest)
                    break
                msgs.extend(telemetry.build(mid, snap, mav))
            else:
                self._late_streams = set()
        if msgs:
            self.telemetry_peers_skipped += link.send_many(msgs, others_limit=TELEMETRY_OTHER_PEERS)

    def build(self, msg_id: int) -> list[mavlink.MAVLink_message]:
        """The message(s) of this id now; [] when there is nothing to say."""
        return telemetry.build(msg_id, self.snapshot(), self.mav)

    def on_tick(self, t_us: int, until: float | None = None) -> None:
        """Per control tick: mission-protocol timeouts (wall clock) and the telemetry streams
        (within ``until``, a wall time, if given: :meth:`stream`)."""
        now = self.wall_s()
        self.mission.tick(now)
        self.send_durable_acks()
        self.send_param_lists()
        if self.params.write_errors:  # the writer thread could not save the parameter file
            exc = self.params.write_errors.pop()
            self.params.write_errors.clear()
            self._event(M.MAV_SEVERITY_ERROR, f"Param file not written: {exc.strerror or exc}")
        self.stream(t_us, until)


def _param_name(raw: object) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0].strip()


__all__ = ["GcsHandler", "GroundLink", "CAPABILITIES", "Mode"]
