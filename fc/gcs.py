"""The ground-station protocol of the flight controller (docs/gcs-protocol.md).

:class:`GcsHandler` dispatches every message from the ground link — commands, modes, set-points,
parameters, missions, stream requests — to the commander, the parameter store and the mission
protocol, answers the sender, and builds the telemetry the stream scheduler says is due.
Bad input never raises: it is refused with the protocol's code (``COMMAND_ACK`` result,
``MISSION_ACK`` error, unchanged ``PARAM_VALUE``) and a ``STATUSTEXT``, or dropped and counted.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from typing import TYPE_CHECKING, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import telemetry
from fc.commander import Result
from fc.mission import RELATIVE_FRAMES
from fc.params import PARAM_INDEX, PARAMS, ParamError
from smcpilot import __version__
from smcpilot.frames import euler_flu_to_frd, euler_frd_to_flu, ned_to_nwu, nwu_to_ned
from smcpilot.geo import ned_to_global
from smcpilot.protocol import FORCE_ARM_MAGIC, OVERRUN_NAME, Mode

if TYPE_CHECKING:  # pragma: no cover
    from fc.app import FlightControllerApp

M = mavlink
Address = tuple[str, int]

# POSITION_TARGET_TYPEMASK bits
_IGNORE_POS = 0x7
_IGNORE_YAW = 0x400
_FTP_NAK = 129
_FTP_FILE_NOT_FOUND = 10

CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
)
_VERSION = tuple(int(p) for p in __version__.split(".")[:3])
FLIGHT_SW_VERSION = (_VERSION[0] << 24) | (_VERSION[1] << 16) | (_VERSION[2] << 8) | 0xFF  # FIRMWARE_VERSION_TYPE_OFFICIAL


class GcsHandler:
    """Dispatches ground-link messages; ``wall_s`` is the real-time clock for protocol timeouts."""

    def __init__(self, app: "FlightControllerApp", wall_s: Callable[[], float] = time.monotonic) -> None:
        self.app = app
        self.wall_s = wall_s
        #: reason -> count of dropped or refused messages
        self.rejected: Counter[str] = Counter()
        self.gcs_heartbeats = 0
        self._last_reject_text_s: dict[tuple[str, Address | None], float] = {}
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
            M.MAVLINK_MSG_ID_MISSION_COUNT: lambda m, a: self.app.mission.on_count(m, a, self.wall_s()),
            M.MAVLINK_MSG_ID_MISSION_ITEM_INT: lambda m, a: self.app.mission.on_item(m, a, self.wall_s()),
            M.MAVLINK_MSG_ID_MISSION_ITEM: lambda m, a: self.app.mission.on_item(m, a, self.wall_s()),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: lambda m, a: self.app.mission.on_request_list(m, a),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_INT: lambda m, a: self.app.mission.on_request(m, a, True),
            M.MAVLINK_MSG_ID_MISSION_REQUEST: lambda m, a: self.app.mission.on_request(m, a, False),
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: lambda m, a: self.app.mission.on_clear(m, a),
            M.MAVLINK_MSG_ID_MISSION_SET_CURRENT: self._mission_set_current,
            M.MAVLINK_MSG_ID_MISSION_ACK: lambda m, a: None,
            M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self._request_data_stream,
            M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self._ftp,
        }

    # -- plumbing -------------------------------------------------------------------------------
    @property
    def mav(self) -> mavlink.MAVLink:
        return self.app.gcs.mav  # type: ignore[union-attr]

    def _send_to(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        if self.app.gcs is not None:
            self.app.gcs.send_to(msg, addr)

    def _broadcast(self, msg: mavlink.MAVLink_message) -> None:
        if self.app.gcs is not None:
            self.app.gcs.send(msg)

    def _for_us(self, target_system: int, target_component: int | None = None) -> bool:
        if target_system not in (0, self.app.cfg.system_id):
            self.rejected["other_system"] += 1
            return False
        if target_component is not None and target_component not in (0, 1):
            self.rejected["other_component"] += 1
            return False
        return True

    def _refuse(self, reason: str, text: str, addr: Address | None = None) -> None:
        """Count a refused message and say why (at most one STATUSTEXT a second per reason and
        requester, so a flood of bad set-points cannot flood the ground link)."""
        self.rejected[reason] += 1
        now = self.wall_s()
        key = (reason, addr)
        if now - self._last_reject_text_s.get(key, -math.inf) >= 1.0:
            if len(self._last_reject_text_s) > 256:
                self._last_reject_text_s.clear()
            self._last_reject_text_s[key] = now
            self.app.event(M.MAV_SEVERITY_WARNING, text)

    def handle(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        handler = self._handlers.get(msg.id)
        if handler is None:
            return
        ts = getattr(msg, "target_system", None)
        if ts is not None and msg.id != M.MAVLINK_MSG_ID_HEARTBEAT and not self._for_us(ts):
            return
        try:
            handler(msg, addr)
        except Exception as exc:  # a hostile packet must never stop the loop
            self.rejected["handler_error"] += 1
            self.app.say(f"fc: ignored {msg.get_type()} from {addr[0]}:{addr[1]}: {type(exc).__name__}: {exc}")

    # -- messages -------------------------------------------------------------------------------
    def _heartbeat(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if m.type == M.MAV_TYPE_GCS:
            self.gcs_heartbeats += 1
            self.app.core.on_gcs_heartbeat(self.wall_s())

    def _ack(self, addr: Address, m: mavlink.MAVLink_message, command: int, result: Result) -> None:
        code, reason = result
        if reason and code != M.MAV_RESULT_ACCEPTED:
            self.app.event(M.MAV_SEVERITY_WARNING, reason)
        self._send_to(
            self.mav.command_ack_encode(command, code, 0, 0, m.get_srcSystem(), m.get_srcComponent()), addr
        )

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

    def _command(self, cmd: int, p: tuple[float, ...], frame: int | None, addr: Address, m) -> Result:
        c = self.app.commander
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = p[1] == FORCE_ARM_MAGIC
            if p[0] == 1.0:
                return c.arm(force)
            if p[0] == 0.0:
                return c.disarm(force)
            return (M.MAV_RESULT_DENIED, f"Arm/disarm: param1 must be 0 or 1, got {p[0]!r}")
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
                return (M.MAV_RESULT_DENIED, "Set mode: only custom modes (base mode bit 1) are supported")
            if not math.isfinite(p[1]):
                return (M.MAV_RESULT_DENIED, "Set mode: mode number is not a number")
            return c.set_mode(int(p[1]))
        if cmd == M.MAV_CMD_DO_REPOSITION:
            if frame is None:  # COMMAND_LONG: lat/lon degrees in param5/6, altitude above home in param7
                return c.reposition(p[4], p[5], p[6], True, p[3])
            if frame not in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                             M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):  # fmt: skip
                return (M.MAV_RESULT_DENIED, f"Reposition: frame {frame} not supported")
            return c.reposition(p[4] * 1e-7, p[5] * 1e-7, p[6], frame in RELATIVE_FRAMES, p[3])
        if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not (math.isfinite(p[0]) and math.isfinite(p[1])):
                return (M.MAV_RESULT_DENIED, "Message interval: non-finite parameter")
            ok = self.app.streams.set_interval(int(p[0]), p[1])
            return (M.MAV_RESULT_ACCEPTED, None) if ok else (M.MAV_RESULT_DENIED, f"Message interval: message {int(p[0])} not streamed")
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            if not math.isfinite(p[0]):
                return (M.MAV_RESULT_DENIED, "Request message: id is not a number")
            msgs = self.build(int(p[0]))
            if not msgs:
                return (M.MAV_RESULT_UNSUPPORTED, None)
            for msg in msgs:
                self._send_to(msg, addr)
            return (M.MAV_RESULT_ACCEPTED, None)
        if cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._send_to(self.build(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)[0], addr)
            return (M.MAV_RESULT_ACCEPTED, None)
        if cmd == M.MAV_CMD_GET_HOME_POSITION:
            self._send_to(self.build(M.MAVLINK_MSG_ID_HOME_POSITION)[0], addr)
            return (M.MAV_RESULT_ACCEPTED, None)
        if cmd == M.MAV_CMD_DO_SET_MISSION_CURRENT:
            if not math.isfinite(p[0]) or not self.app.mission.set_current(int(p[0])):
                return (M.MAV_RESULT_DENIED, f"Set current: no mission item {p[0]!r}")
            self._broadcast(self.build(M.MAVLINK_MSG_ID_MISSION_CURRENT)[0])
            return (M.MAV_RESULT_ACCEPTED, None)
        self.rejected["unsupported_command"] += 1
        return (M.MAV_RESULT_UNSUPPORTED, None)

    def _set_mode_msg(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not m.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result: Result = (M.MAV_RESULT_DENIED, "Set mode: only custom modes are supported")
        else:
            result = self.app.commander.set_mode(m.custom_mode)
        self._ack(addr, m, M.MAVLINK_MSG_ID_SET_MODE, result)

    def _target_local(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if m.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
            self._refuse("unsupported_frame", f"Set-point: frame {m.coordinate_frame} not supported (use LOCAL_NED)", addr)
            return
        if m.type_mask & _IGNORE_POS:
            self._refuse("no_position", "Set-point: only position targets are supported", addr)
            return
        yaw = None if m.type_mask & _IGNORE_YAW else m.yaw
        if yaw is not None and not math.isfinite(yaw):
            self._refuse("non_finite", "Set-point: yaw is not a number", addr)
            return
        x, y, z = ned_to_nwu((m.x, m.y, m.z))
        code, reason = self.app.commander.goto_local(
            x, y, z, euler_frd_to_flu(0.0, 0.0, yaw)[2] if yaw is not None else None
        )
        if code != M.MAV_RESULT_ACCEPTED:
            self._refuse("setpoint_refused", reason or "Set-point refused", addr)

    def _target_global(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if m.coordinate_frame not in (M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL,
                                      M.MAV_FRAME_GLOBAL_RELATIVE_ALT):  # fmt: skip
            self._refuse("unsupported_frame", f"Set-point: frame {m.coordinate_frame} not supported", addr)
            return
        if m.type_mask & _IGNORE_POS:
            self._refuse("no_position", "Set-point: only position targets are supported", addr)
            return
        if not math.isfinite(m.alt):
            self._refuse("non_finite", "Set-point: altitude is not a number", addr)
            return
        c = self.app.commander
        x, y, z = c.local_of_global(m.lat_int * 1e-7, m.lon_int * 1e-7, m.alt, m.coordinate_frame in RELATIVE_FRAMES)
        yaw = None if m.type_mask & _IGNORE_YAW or not math.isfinite(m.yaw) else euler_frd_to_flu(0.0, 0.0, m.yaw)[2]
        code, reason = c.goto_local(x, y, z, yaw)
        if code != M.MAV_RESULT_ACCEPTED:
            self._refuse("setpoint_refused", reason or "Set-point refused", addr)

    # -- parameters -----------------------------------------------------------------------------
    def _param_msg(self, index: int) -> mavlink.MAVLink_message:
        p = PARAMS[index]
        value = self.app.params.value(p.name)
        ptype = M.MAV_PARAM_TYPE_INT32 if p.is_int else M.MAV_PARAM_TYPE_REAL32
        return self.mav.param_value_encode(p.name.encode(), float(value), ptype, len(PARAMS), index)

    def _param_list(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        self.app.gcs.send_many_to([self._param_msg(i) for i in range(len(PARAMS))], addr)  # type: ignore[union-attr]

    def _param_read(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        name = _param_name(m.param_id)
        if m.param_index >= 0:
            index = m.param_index if m.param_index < len(PARAMS) else -1
        else:
            index = PARAM_INDEX.get(name, -1)
        if index < 0:
            self._refuse("unknown_param", f"Param read: unknown {name or m.param_index}", addr)
            return
        self._send_to(self._param_msg(index), addr)

    def _param_set(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self._for_us(m.target_system, m.target_component):
            return
        name = _param_name(m.param_id)
        index = PARAM_INDEX.get(name)
        if index is None:
            self._refuse("unknown_param", f"Param set: unknown {name}", addr)
            return
        try:
            cfg = self.app.params.set(name, float(m.param_value))
        except ParamError as exc:
            self.rejected["param_refused"] += 1
            self.app.event(M.MAV_SEVERITY_WARNING, str(exc))
            self._send_to(self._param_msg(index), addr)  # the value in force, unchanged
            return
        except OSError as exc:
            self.app.event(M.MAV_SEVERITY_ERROR, f"Param file not written: {exc.strerror or exc}")
            cfg = self.app.params.config
        self.app.apply_config(cfg)
        if PARAMS[index].restart:
            self.app.event(M.MAV_SEVERITY_INFO, f"{name} takes effect at the next start")
        self._broadcast(self._param_msg(index))

    # -- missions, streams, FTP -----------------------------------------------------------------
    def _mission_set_current(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if not self.app.mission.set_current(m.seq):
            self._refuse("bad_mission_seq", f"Mission: no item {m.seq}", addr)
        self._broadcast(self.build(M.MAVLINK_MSG_ID_MISSION_CURRENT)[0])

    def _request_data_stream(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        self.app.streams.request_stream(m.req_stream_id, m.req_message_rate, bool(m.start_stop))

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
    def stream(self, t_us: int) -> None:
        """Send what the scheduler says is due (one batch per peer)."""
        gcs = self.app.gcs
        if gcs is None:
            return
        msgs: list[mavlink.MAVLink_message] = []
        for mid in self.app.streams.due(t_us):
            msgs.extend(self.build(mid))
        if msgs:
            gcs.send_many(msgs)

    def build(self, msg_id: int) -> list[mavlink.MAVLink_message]:
        """The message(s) of this id for the current state; [] when there is nothing to say."""
        app = self.app
        mav = self.mav
        st = app.state
        t_ms = (app.clock.now_us() // 1000) & 0xFFFFFFFF
        c = app.commander
        f = app.flight
        if msg_id == M.MAVLINK_MSG_ID_HEARTBEAT:
            status = M.MAV_STATE_CRITICAL if app.failsafe else M.MAV_STATE_ACTIVE if f.armed else M.MAV_STATE_STANDBY
            return [telemetry.heartbeat(mav, f.armed, int(c.mode), status)]
        if msg_id == M.MAVLINK_MSG_ID_SYS_STATUS:
            healthy = not app.failsafe and st is not None
            prearm_ok = f.armed or c.prearm_failure() is None
            return [telemetry.sys_status(mav, 0, healthy, prearm_ok)]
        if msg_id == M.MAVLINK_MSG_ID_SYSTEM_TIME:
            return [mav.system_time_encode(0, t_ms)]
        if msg_id == M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return [mav.extended_sys_state_encode(M.MAV_VTOL_STATE_UNDEFINED, c.landed_state())]
        if msg_id == M.MAVLINK_MSG_ID_MISSION_CURRENT:
            n_items = len(app.mission.items)
            return [mav.mission_current_encode(app.mission.current, n_items - 1 if n_items else 0xFFFF)]
        if msg_id == M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
            if not f.armed:
                return []
            tn, te, td = nwu_to_ned(f.target)
            yaw_ned = euler_flu_to_frd(0.0, 0.0, f.yaw_target_rad)[2]
            mask = 0xFFF & ~(_IGNORE_POS | _IGNORE_YAW)  # position and yaw are the set-point
            return [mav.position_target_local_ned_encode(t_ms, M.MAV_FRAME_LOCAL_NED, mask, tn, te, td, 0, 0, 0, 0, 0, 0, yaw_ned, 0)]
        if msg_id == M.MAVLINK_MSG_ID_NAMED_VALUE_INT:
            return [mav.named_value_int_encode(t_ms, OVERRUN_NAME.encode(), app.stats.overruns)]
        if msg_id == M.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT:
            return telemetry.named_values(mav, t_ms, app.last_out.pipeline if app.last_out is not None else None)
        if msg_id == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return [
                mav.autopilot_version_encode(
                    CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0x1209, 0x5350,
                    0x534D435049000000 | app.cfg.system_id,
                )  # fmt: skip
            ]
        if msg_id == M.MAVLINK_MSG_ID_HOME_POSITION:
            h = app.home
            return [
                mav.home_position_encode(
                    int(round(h.lat_deg * 1e7)), int(round(h.lon_deg * 1e7)), int(round(h.alt_m * 1000)),
                    0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
                )  # fmt: skip
            ]
        if st is None:
            return []
        if msg_id == M.MAVLINK_MSG_ID_ATTITUDE:
            return [telemetry.attitude(mav, t_ms, st, app.body_rates)]
        if msg_id == M.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return [telemetry.local_position(mav, t_ms, st)]
        n, e, d = nwu_to_ned((st.x_m, st.y_m, st.z_m))
        vn, ve, vd = nwu_to_ned((st.vx_mps, st.vy_mps, st.vz_mps))
        lat, lon, alt = ned_to_global(app.home, n, e, d)
        heading_deg = math.degrees(euler_frd_to_flu(0.0, 0.0, st.psi_rad)[2]) % 360.0
        if msg_id == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return [
                mav.global_position_int_encode(
                    t_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)), int(round(-d * 1000)),
                    _i16(vn * 100), _i16(ve * 100), _i16(vd * 100), int(round(heading_deg * 100)) % 36000,
                )  # fmt: skip
            ]
        ground_speed = math.hypot(vn, ve)
        if msg_id == M.MAVLINK_MSG_ID_GPS_RAW_INT:
            cog = int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100)) % 36000 if ground_speed > 0.2 else 65535
            return [
                mav.gps_raw_int_encode(
                    app.clock.now_us(), M.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
                    int(round(alt * 1000)), 80, 120, min(65534, int(round(ground_speed * 100))), cog, 12,
                )  # fmt: skip
            ]
        if msg_id == M.MAVLINK_MSG_ID_VFR_HUD:
            out = app.last_out
            throttle = int(round(100 * sum(out.motors) / 4)) if out is not None else 0
            return [mav.vfr_hud_encode(ground_speed, ground_speed, int(round(heading_deg)) % 360, throttle, -d, -vd)]
        return []

    def on_tick(self, t_us: int) -> None:
        """Per control tick: mission-protocol timeouts (wall clock) and the telemetry streams."""
        now = self.wall_s()
        self.app.mission.tick(now)
        self.stream(t_us)


def _param_name(raw: object) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0].strip()


def _i16(v: float) -> int:
    return max(-32768, min(32767, int(round(v))))


__all__ = ["GcsHandler", "CAPABILITIES", "Mode"]
