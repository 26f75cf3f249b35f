"""Telemetry: the :class:`Telemetry` snapshot of what the vehicle last reported, and
:class:`TelemetryParser`, which folds each incoming message into the next snapshot.

Frames and units: positions NED (north, east, down) in metres relative to the local origin
(home); velocities NED m/s; attitude roll/pitch/yaw FRD Euler angles in radians; global positions
WGS-84 degrees and metres AMSL. Times: ``sim_time_s`` is the vehicle's simulated clock (the
``time_boot_ms`` of :data:`TIMED_MESSAGES`), in seconds; wall times are ``time.monotonic()`` or
``time.time()`` seconds, as each field says.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.modes import mode_name
from ground.vehicle.names import enum_name
from smcpilot.link import Address

__all__ = ["TIMED_MESSAGES", "HomePosition", "StatusText", "StatusTextAssembler", "Telemetry", "TelemetryParser", "json_safe",
           "mavlink_text"]

#: Messages whose time_boot_ms is the vehicle's (simulated) clock.
TIMED_MESSAGES = frozenset(
    {
        "SYSTEM_TIME",
        "ATTITUDE",
        "LOCAL_POSITION_NED",
        "GLOBAL_POSITION_INT",
        "NAMED_VALUE_FLOAT",
        "NAMED_VALUE_INT",
        "POSITION_TARGET_LOCAL_NED",
    }
)
_LANDED_STATES = {
    mavlink.MAV_LANDED_STATE_UNDEFINED: "UNDEFINED",
    mavlink.MAV_LANDED_STATE_ON_GROUND: "ON_GROUND",
    mavlink.MAV_LANDED_STATE_IN_AIR: "IN_AIR",
    mavlink.MAV_LANDED_STATE_TAKEOFF: "TAKEOFF",
    mavlink.MAV_LANDED_STATE_LANDING: "LANDING",
}


@dataclass(frozen=True)
class StatusText:
    """One STATUSTEXT from the vehicle: MAV_SEVERITY number, text, and when it came."""

    severity: int
    text: str
    #: the vehicle's simulated time when it arrived (its last time stamp), s; None if unknown.
    sim_time_s: float | None
    #: wall clock (``time.time()``) when it arrived, s since the epoch.
    wall_time_s: float

    @property
    def severity_name(self) -> str:
        """``"MAV_SEVERITY_WARNING"`` etc."""
        return enum_name("MAV_SEVERITY", self.severity)

    @classmethod
    def received(cls, msg: mavlink.MAVLink_message, sim_time_s: float | None) -> StatusText:
        """A STATUSTEXT message that arrived just now, when the vehicle's clock read ``sim_time_s``."""
        return cls(msg.severity, mavlink_text(msg.text), sim_time_s, time.time())


@dataclass(frozen=True)
class HomePosition:
    """The vehicle's home (HOME_POSITION): global position and its local NED coordinates, m."""

    lat_deg: float
    lon_deg: float
    #: altitude above mean sea level, m.
    alt_amsl_m: float
    #: home in the local NED frame, m (0, 0, 0 when the local origin is home).
    north_m: float = 0.0
    east_m: float = 0.0
    down_m: float = 0.0


#: SYS_STATUS fields of :attr:`Telemetry.comm_errors`.
COMM_ERROR_FIELDS = ("errors_comm", "drop_rate_comm", "errors_count1", "errors_count2", "errors_count3", "errors_count4")


@dataclass(frozen=True)
class Telemetry:
    """A snapshot of the latest telemetry. ``None`` means "not received yet".

    Frames: positions NED (north, east, down) in metres relative to the local origin (home);
    velocities NED m/s; attitude roll/pitch/yaw FRD Euler angles in radians.
    """

    #: vehicle simulated time from the last ``time_boot_ms``, s.
    sim_time_s: float | None = None
    #: wall clock (``time.monotonic()``) of the last message from the vehicle, s.
    last_message_wall_s: float | None = None
    system_id: int | None = None
    component_id: int | None = None
    armed: bool = False
    mode_number: int | None = None
    system_status: int | None = None
    heartbeats: int = 0
    #: SYS_STATUS PREARM_CHECK health bit: arming would pass.
    prearm_ok: bool | None = None
    position_ned_m: tuple[float, float, float] | None = None
    velocity_ned_mps: tuple[float, float, float] | None = None
    attitude_rad: tuple[float, float, float] | None = None
    #: GLOBAL_POSITION_INT: latitude/longitude deg, altitude AMSL m, altitude above home m.
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_amsl_m: float | None = None
    relative_alt_m: float | None = None
    home: HomePosition | None = None
    landed_state: int | None = None
    mission_current: int | None = None
    #: MISSION_CURRENT.total (items incl. home) when the vehicle sends it.
    mission_total: int | None = None
    #: last MISSION_ITEM_REACHED sequence number.
    mission_reached: int | None = None
    #: adaptive gains chi_hat by channel ("PHI", "THETA", "PSI", "Z"); NaN without them.
    chi: Mapping[str, float] = field(default_factory=dict)
    #: PID manifolds sigma by channel.
    sigma: Mapping[str, float] = field(default_factory=dict)
    #: NAMED_VALUE_INT OVERRUN: missed control deadlines so far.
    overruns: int | None = None
    #: POSITION_TARGET_LOCAL_NED (if the vehicle streams it), m NED.
    setpoint_ned_m: tuple[float, float, float] | None = None
    #: the last STATUSTEXTs (oldest first).
    statustexts: tuple[StatusText, ...] = ()
    #: SYS_STATUS's communication counters, named as in MAVLink (errors_comm, drop_rate_comm
    #: in c%, errors_count1..4; docs/security.md says what the FC counts in each); empty
    #: before the first SYS_STATUS.
    comm_errors: Mapping[str, int] = field(default_factory=dict)

    @property
    def mode_name(self) -> str | None:
        """ArduCopter mode name, e.g. ``"GUIDED"``."""
        return mode_name(self.mode_number)

    @property
    def altitude_m(self) -> float | None:
        """Height above home, m (up = -down of LOCAL_POSITION_NED; the local origin is home)."""
        return None if self.position_ned_m is None else -self.position_ned_m[2]

    @property
    def landed_state_name(self) -> str | None:
        """``"ON_GROUND"``, ``"IN_AIR"``, ``"TAKEOFF"``, ``"LANDING"`` or ``"UNDEFINED"``."""
        if self.landed_state is None:
            return None
        return _LANDED_STATES.get(self.landed_state, str(self.landed_state))

    @property
    def last_statustext(self) -> StatusText | None:
        return self.statustexts[-1] if self.statustexts else None

    @property
    def yaw_deg(self) -> float | None:
        """Heading, degrees in [0, 360) (0 north, 90 east)."""
        if self.attitude_rad is None:
            return None
        return math.degrees(self.attitude_rad[2]) % 360.0

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: non-finite numbers (χ̂ and σ while disarmed) become None, so strict
        JSON parsers read it."""
        home = self.home
        return json_safe({
            "sim_time_s": self.sim_time_s,
            "system_id": self.system_id,
            "armed": self.armed,
            "mode": self.mode_name,
            "mode_number": self.mode_number,
            "system_status": self.system_status,
            "prearm_ok": self.prearm_ok,
            "landed_state": self.landed_state_name,
            "position_ned_m": list(self.position_ned_m) if self.position_ned_m else None,
            "velocity_ned_mps": list(self.velocity_ned_mps) if self.velocity_ned_mps else None,
            "attitude_deg": [math.degrees(a) for a in self.attitude_rad] if self.attitude_rad else None,
            "altitude_m": self.altitude_m,
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "alt_amsl_m": self.alt_amsl_m,
            "relative_alt_m": self.relative_alt_m,
            "home": None
            if home is None
            else {"lat_deg": home.lat_deg, "lon_deg": home.lon_deg, "alt_amsl_m": home.alt_amsl_m},
            "mission_current": self.mission_current,
            "mission_total": self.mission_total,
            "chi": dict(self.chi),
            "sigma": dict(self.sigma),
            "overruns": self.overruns,
            "setpoint_ned_m": list(self.setpoint_ned_m) if self.setpoint_ned_m else None,
            "last_statustext": self.last_statustext.text if self.last_statustext else None,
            "comm_errors": dict(self.comm_errors),
        })


def json_safe(v: Any) -> Any:
    """``v`` with every non-finite float replaced by None (for strict JSON)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    return v


def mavlink_text(raw: str | bytes) -> str:
    """A MAVLink char[] field as text: decoded (UTF-8, bad bytes replaced), cut at the first NUL."""
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    return raw.split("\0", 1)[0]


class StatusTextAssembler:
    """Joins MAVLink 2 STATUSTEXT chunks (same non-zero ``id``, ``chunk_seq`` 0, 1, ...; the last
    one shorter than 50 characters) into one message with the whole text.

    :meth:`feed` returns the message to deliver: a single STATUSTEXT (``id`` 0) as it is, the
    last chunk of a text carrying the joined text, or None while chunks are outstanding. A chunk
    lost on the way leaves ``[...]`` in its place; a text whose last chunk never comes is
    delivered as it stands after ``timeout_s`` wall seconds (at the next message fed).
    """

    def __init__(self, timeout_s: float = 2.0, clock_s: Any = time.monotonic) -> None:
        self.timeout_s = timeout_s
        self._clock_s = clock_s
        #: (system, component, id) -> (first arrival, {chunk_seq: text}, latest chunk message)
        self._open: dict[tuple[int, int, int], tuple[float, dict[int, str], mavlink.MAVLink_message]] = {}

    def feed(self, msg: mavlink.MAVLink_message) -> list[mavlink.MAVLink_message]:
        """The messages complete now (see the class doc), oldest first."""
        now = self._clock_s()
        out = self._expire(now)
        text_id = int(getattr(msg, "id", 0) or 0)
        if text_id == 0:
            out.append(msg)
            return out
        key = (msg.get_srcSystem(), msg.get_srcComponent(), text_id)
        piece = mavlink_text(msg.text)
        first, chunks, _ = self._open.get(key, (now, {}, msg))
        chunks[int(msg.chunk_seq)] = piece
        if len(piece) < 50:  # the last chunk: the text is complete
            self._open.pop(key, None)
            out.append(self._joined(msg, chunks))
        else:
            if len(self._open) >= 64:  # a flood of unfinished texts: deliver the oldest
                oldest = min(self._open, key=lambda k: self._open[k][0])
                _, c, m = self._open.pop(oldest)
                out.append(self._joined(m, c))
            self._open[key] = (first, chunks, msg)
        return out

    def _expire(self, now: float) -> list[mavlink.MAVLink_message]:
        out = []
        for key in [k for k, (t0, _, _) in self._open.items() if now - t0 > self.timeout_s]:
            _, chunks, msg = self._open.pop(key)
            out.append(self._joined(msg, chunks))
        return out

    @staticmethod
    def _joined(msg: mavlink.MAVLink_message, chunks: dict[int, str]) -> mavlink.MAVLink_message:
        last = max(chunks)
        msg.text = "".join(chunks.get(i, "[...]") for i in range(last + 1))
        return msg


class TelemetryParser:
    """Folds the messages of one vehicle into :class:`Telemetry` snapshots.

    The vehicle is the first one whose HEARTBEAT is heard (an autopilot, not a GCS), or system
    ``wanted_system`` if given; messages from other systems are ignored. ``state`` is the latest
    snapshot (replaced, never mutated, so readers may keep it). Not thread-safe: the
    :class:`~ground.vehicle.link.Link` calls :meth:`ingest` on its receiver thread, lock held.
    """

    def __init__(self, wanted_system: int | None = None, statustext_history: int = 100) -> None:
        self.wanted_system = wanted_system
        self.state = Telemetry()
        #: where the vehicle's first HEARTBEAT came from.
        self.vehicle_address: Address | None = None
        self._texts: collections.deque[StatusText] = collections.deque(maxlen=statustext_history)
        self._chi: dict[str, float] = {}
        self._sigma: dict[str, float] = {}

    def ingest(self, msg: mavlink.MAVLink_message, addr: Address) -> bool:
        """Update :attr:`state` from one message (from ``addr``); False if it is not from our vehicle."""
        st = self.state
        src = msg.get_srcSystem()
        t = msg.get_type()
        if st.system_id is None:
            if t != "HEARTBEAT" or msg.type == mavlink.MAV_TYPE_GCS or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                return False
            if self.wanted_system is not None and src != self.wanted_system:
                return False
            st = replace(st, system_id=src, component_id=msg.get_srcComponent())
            self.vehicle_address = addr
        elif src != st.system_id:
            return False
        upd: dict[str, Any] = {"last_message_wall_s": time.monotonic()}
        if t in TIMED_MESSAGES:
            upd["sim_time_s"] = msg.time_boot_ms * 1e-3
        if t == "HEARTBEAT":
            if msg.get_srcComponent() != st.component_id or msg.type == mavlink.MAV_TYPE_GCS:
                self.state = replace(st, **upd)
                return True
            upd.update(
                armed=bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED),
                mode_number=msg.custom_mode if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None,
                system_status=msg.system_status,
                heartbeats=st.heartbeats + 1,
            )
        elif t == "LOCAL_POSITION_NED":
            upd["position_ned_m"] = (msg.x, msg.y, msg.z)
            upd["velocity_ned_mps"] = (msg.vx, msg.vy, msg.vz)
        elif t == "ATTITUDE":
            upd["attitude_rad"] = (msg.roll, msg.pitch, msg.yaw)
        elif t == "GLOBAL_POSITION_INT":
            upd.update(lat_deg=msg.lat * 1e-7, lon_deg=msg.lon * 1e-7, alt_amsl_m=msg.alt * 1e-3, relative_alt_m=msg.relative_alt * 1e-3)
        elif t == "HOME_POSITION":
            upd["home"] = HomePosition(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3, msg.x, msg.y, msg.z)
        elif t == "EXTENDED_SYS_STATE":
            upd["landed_state"] = msg.landed_state
        elif t == "SYS_STATUS":
            bit = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            if msg.onboard_control_sensors_present & bit:
                upd["prearm_ok"] = bool(msg.onboard_control_sensors_health & bit)
            upd["comm_errors"] = {name: int(getattr(msg, name)) for name in COMM_ERROR_FIELDS}
        elif t == "MISSION_CURRENT":
            upd["mission_current"] = msg.seq
            total = getattr(msg, "total", 0)
            if total and total != 0xFFFF:
                upd["mission_total"] = total
        elif t == "MISSION_ITEM_REACHED":
            upd["mission_reached"] = msg.seq
        elif t == "NAMED_VALUE_FLOAT":
            name = mavlink_text(msg.name)
            if name.startswith("CHI_"):
                self._chi[name[4:]] = msg.value
                upd["chi"] = dict(self._chi)
            elif name.startswith("SIG_"):
                self._sigma[name[4:]] = msg.value
                upd["sigma"] = dict(self._sigma)
        elif t == "NAMED_VALUE_INT":
            if mavlink_text(msg.name) == "OVERRUN":
                upd["overruns"] = msg.value
        elif t == "POSITION_TARGET_LOCAL_NED":
            upd["setpoint_ned_m"] = (msg.x, msg.y, msg.z)
        elif t == "STATUSTEXT":
            self._texts.append(StatusText.received(msg, upd.get("sim_time_s", st.sim_time_s)))
            upd["statustexts"] = tuple(self._texts)
        self.state = replace(st, **upd)
        return True
