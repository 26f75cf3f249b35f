"""A MAVLink ground-station client for smcpilot (and any ArduCopter-like vehicle).

:class:`Vehicle` is what tests, scripts and ``smcpilot gcs`` use to fly the flight controller
through its ground link (docs/gcs-protocol.md)::

    with Vehicle("udpin:127.0.0.1:14550") as v:        # where the FC sends its telemetry
        v.arm()
        v.takeoff(3.0)
        v.wait_altitude(3.0, tol_m=0.3, timeout_sim_s=20)
        v.goto_ned(4.0, -3.0, -3.0, yaw_deg=90)
        v.wait_position_ned(4.0, -3.0, -3.0, tol_m=0.5, timeout_sim_s=30)
        v.land()
        v.wait_disarmed(timeout_sim_s=30)

Connection URLs are :mod:`smcpilot.link`'s: ``udpin:HOST:PORT`` listens where the FC sends
telemetry (the FC's ``--gcs udp:HOST:PORT``); ``udpout:HOST:PORT`` writes to the FC's own ground
port (the ``gcs=`` address it prints, :attr:`ground.sitl.Sitl.gcs_address`). We are system 255,
component 190 (MAV_COMP_ID_MISSIONPLANNER), and send a GCS ``HEARTBEAT`` at 1 Hz wall clock from a
background thread.

Threads: exactly one thread (the receiver) reads the link; it keeps the latest telemetry
(:class:`Telemetry`, read with :attr:`Vehicle.telemetry`), feeds subscribers
(:meth:`Vehicle.subscribe`) and wakes waiters. Every send goes through one lock (the link is not
thread-safe). Public methods may be called from any thread.

Two clocks:

- **simulated time** (``time_boot_ms`` of SYSTEM_TIME, ATTITUDE, LOCAL_POSITION_NED, ... — the FC
  stamps them with the simulator's clock in lockstep): every ``wait_*`` timeout is in simulated
  seconds (``timeout_sim_s``), so a test means the same thing at 1x and at 20x real time. Each wait
  also has a wall-clock safety limit (``wall_margin_s + wall_per_sim_s * timeout_sim_s``) and fails
  early when no telemetry arrives for ``stall_timeout_s`` wall seconds, so nothing hangs when the
  simulator stops.
- **wall clock**: protocol retries (a ground station lives in real time, as the FC's protocol
  timeouts do). Commands: ``COMMAND_LONG`` re-sent with ``confirmation`` + 1 when no
  ``COMMAND_ACK`` came within ``ack_timeout_s`` (1 s), up to ``command_tries`` (5) sends;
  ``MAV_RESULT_IN_PROGRESS`` extends the wait. Parameters: the request (or ``PARAM_SET``) re-sent
  after 1 s, up to 5 times; a list fetch re-requests missing indices one by one. Missions: the
  GCS side of the upload/download transactions (below).

Missions follow ArduPilot: **item 0 is home**. :meth:`Vehicle.upload_mission` takes the items to
fly and inserts the home item itself (from the vehicle's ``HOME_POSITION``), so ``items[0]``
becomes sequence number 1; :meth:`Vehicle.download_mission` strips item 0 again. Sequence numbers
given to or reported by the vehicle (:meth:`Vehicle.set_current_item`,
:attr:`Telemetry.mission_current`, ``MISSION_ITEM_REACHED``) are the vehicle's, i.e. user item
``k`` (0-based) is sequence number ``k + 1``.

Errors (all :class:`~smcpilot.errors.SmcpilotError`): :class:`VehicleTimeout` (what was awaited,
the last value, the simulated time), :class:`CommandDenied` (the MAV_RESULT name and the FC's
STATUSTEXT reason), :class:`ParamRejected`, :class:`MissionError`, :class:`UnknownModeError`.
"""

from __future__ import annotations

import collections
import logging
import math
import queue
import re
import threading
import time
from dataclasses import dataclass, field, replace
from types import TracebackType
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence, TypeVar

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.errors import ConfigError, LinkClosedError, SmcpilotError
from smcpilot.link import Address, MavlinkUdp
from smcpilot.protocol import COPTER_MODE_NAMES, COPTER_MODES, FORCE_ARM_MAGIC

__all__ = [
    "COPTER_MODES",
    "CommandDenied",
    "CommandTimeout",
    "ConnectTimeout",
    "HomePosition",
    "MissionError",
    "MissionItem",
    "ParamError",
    "ParamRejected",
    "StatusText",
    "Subscription",
    "Telemetry",
    "UnknownModeError",
    "Vehicle",
    "VehicleError",
    "VehicleTimeout",
    "mode_number",
    "mode_name",
    "result_name",
]

log = logging.getLogger(__name__)

#: Our MAVLink identity: a ground station (MAV_COMP_ID_MISSIONPLANNER).
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER  # 190

_NAN = float("nan")
_T = TypeVar("_T")

# Messages whose time_boot_ms is the vehicle's (simulated) clock.
_TIMED_MESSAGES = frozenset(
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
_INT_PARAM_TYPES = frozenset(
    {
        mavlink.MAV_PARAM_TYPE_UINT8,
        mavlink.MAV_PARAM_TYPE_INT8,
        mavlink.MAV_PARAM_TYPE_UINT16,
        mavlink.MAV_PARAM_TYPE_INT16,
        mavlink.MAV_PARAM_TYPE_UINT32,
        mavlink.MAV_PARAM_TYPE_INT32,
    }
)


# ------------------------------------------------------------------------------------------ errors
class VehicleError(SmcpilotError):
    """Something the vehicle did (or did not do) over the link; the CLI exits 1 on these."""


class VehicleTimeout(VehicleError, TimeoutError):
    """A wait or a protocol exchange ran out of time.

    ``what`` is what was awaited, ``last_value`` the last value seen (None if none),
    ``sim_time_s`` the vehicle's simulated time when we gave up (None if it never reported one).
    """

    def __init__(self, message: str, *, what: str, last_value: object = None, sim_time_s: float | None = None) -> None:
        super().__init__(message)
        self.what = what
        self.last_value = last_value
        self.sim_time_s = sim_time_s


class ConnectTimeout(VehicleTimeout):
    """No vehicle HEARTBEAT arrived in time."""


class CommandTimeout(VehicleTimeout):
    """No COMMAND_ACK arrived for a command after every retry."""


class CommandDenied(VehicleError):
    """The vehicle answered a command with a result other than MAV_RESULT_ACCEPTED.

    ``command`` is the MAV_CMD number, ``command_name`` its name, ``result`` the MAV_RESULT number,
    ``result_name`` its name (e.g. ``"MAV_RESULT_DENIED"``), ``reason`` the vehicle's STATUSTEXT
    that came with the refusal (None if none came).
    """

    def __init__(self, command: int, result: int, reason: str | None) -> None:
        self.command = command
        self.command_name = command_name(command)
        self.result = result
        self.result_name = result_name(result)
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"{self.command_name} refused with {self.result_name}{why}")


class UnknownModeError(ConfigError):
    """A flight-mode name is not an ArduCopter mode (the message lists the valid names)."""


class ParamError(VehicleError):
    """A parameter exchange failed (unknown name, incomplete list)."""


class ParamRejected(ParamError):
    """The vehicle kept another value than the one set (out of range, not finite, read-only).

    ``name``, ``requested`` and ``value`` (now in force) are attributes; ``reason`` is the
    vehicle's STATUSTEXT, if one came.
    """

    def __init__(self, name: str, requested: float, value: float, reason: str | None) -> None:
        self.name = name
        self.requested = requested
        self.value = value
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"parameter {name}: {requested:g} refused, value stays {value:g}{why}")


class MissionError(VehicleError):
    """A mission transaction failed; ``result_name`` is the MAV_MISSION_RESULT name when the
    vehicle sent one (None on a timeout), ``reason`` its STATUSTEXT if any."""

    def __init__(self, message: str, *, result: int | None = None, reason: str | None = None) -> None:
        self.result = result
        self.result_name = mission_result_name(result) if result is not None else None
        self.reason = reason
        super().__init__(message + (f": {reason}" if reason else ""))


# ------------------------------------------------------------------------------------ name helpers
def _enum_name(enum: str, value: int) -> str:
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum}({value})"


def result_name(result: int) -> str:
    """``MAV_RESULT`` number -> name, e.g. 2 -> ``"MAV_RESULT_DENIED"``."""
    return _enum_name("MAV_RESULT", result)


def command_name(command: int) -> str:
    """``MAV_CMD`` number -> name, e.g. 22 -> ``"MAV_CMD_NAV_TAKEOFF"``."""
    return _enum_name("MAV_CMD", command)


def mission_result_name(result: int) -> str:
    """``MAV_MISSION_RESULT`` number -> name."""
    return _enum_name("MAV_MISSION_RESULT", result)


def mode_number(name: str | int) -> int:
    """ArduCopter custom-mode number of a mode name (case-insensitive) or number.

    Raises :class:`UnknownModeError` listing the valid names.
    """
    if isinstance(name, int) and not isinstance(name, bool):
        if name < 0:
            raise UnknownModeError(f"mode number must be >= 0, got {name}")
        return name
    key = str(name).strip().upper()
    if key.isdigit():
        return int(key)
    try:
        return COPTER_MODES[key]
    except KeyError:
        valid = ", ".join(COPTER_MODES)
        raise UnknownModeError(f"unknown flight mode {name!r}; ArduCopter modes: {valid}") from None


def mode_name(number: int | None) -> str | None:
    """ArduCopter mode name of a custom-mode number (``"MODE_<n>"`` if unknown, None for None)."""
    if number is None:
        return None
    return COPTER_MODE_NAMES.get(number, f"MODE_{number}")


# ------------------------------------------------------------------------------------- telemetry
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
        return _enum_name("MAV_SEVERITY", self.severity)


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


# ----------------------------------------------------------------------------------- mission items
def _finite_or_nan(v: float | None) -> float:
    return _NAN if v is None else float(v)


@dataclass(frozen=True)
class MissionItem:
    """One mission item as the MISSION_ITEM_INT protocol carries it.

    ``command`` is the MAV_CMD number, ``frame`` the MAV_FRAME (default
    ``MAV_FRAME_GLOBAL_RELATIVE_ALT``: altitude above home), ``param1``–``param4`` as the command
    defines them, ``lat_deg``/``lon_deg`` in degrees (sent as ×1e7 integers, so 1e-7° ≈ 1 cm
    resolution; 0, 0 means "here" for take-off, loiter and land), ``alt_m`` in metres in the
    frame's reference. Build items with the class methods.
    """

    command: int
    frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_m: float = 0.0
    autocontinue: bool = True

    @classmethod
    def takeoff(cls, alt_m: float) -> "MissionItem":
        """NAV_TAKEOFF to ``alt_m`` above home, over the current position."""
        return cls(mavlink.MAV_CMD_NAV_TAKEOFF, alt_m=float(alt_m))

    @classmethod
    def waypoint(
        cls,
        lat_deg: float,
        lon_deg: float,
        alt_m: float,
        *,
        hold_s: float = 0.0,
        acceptance_radius_m: float = 0.0,
        yaw_deg: float | None = None,
    ) -> "MissionItem":
        """NAV_WAYPOINT at ``alt_m`` above home; hold ``hold_s`` s there; radius 0 = WP_RADIUS;
        ``yaw_deg`` None (NaN on the wire) keeps the heading."""
        return cls(
            mavlink.MAV_CMD_NAV_WAYPOINT,
            param1=float(hold_s),
            param2=float(acceptance_radius_m),
            param4=_finite_or_nan(yaw_deg),
            lat_deg=float(lat_deg),
            lon_deg=float(lon_deg),
            alt_m=float(alt_m),
        )

    @classmethod
    def loiter_time(
        cls, hold_s: float, lat_deg: float = 0.0, lon_deg: float = 0.0, alt_m: float = 0.0
    ) -> "MissionItem":
        """NAV_LOITER_TIME: hold ``hold_s`` s at the position (0, 0 = here) and ``alt_m`` above home."""
        return cls(
            mavlink.MAV_CMD_NAV_LOITER_TIME, param1=float(hold_s), lat_deg=float(lat_deg), lon_deg=float(lon_deg), alt_m=float(alt_m)
        )

    @classmethod
    def land(cls, lat_deg: float = 0.0, lon_deg: float = 0.0) -> "MissionItem":
        """NAV_LAND at the position (0, 0 = where the vehicle is)."""
        return cls(mavlink.MAV_CMD_NAV_LAND, lat_deg=float(lat_deg), lon_deg=float(lon_deg))

    @classmethod
    def rtl(cls) -> "MissionItem":
        """NAV_RETURN_TO_LAUNCH."""
        return cls(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    @classmethod
    def change_speed(cls, speed_mps: float) -> "MissionItem":
        """DO_CHANGE_SPEED: horizontal speed ``speed_mps`` (ground speed; -1 = no change)."""
        return cls(
            mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=1.0, param2=float(speed_mps), param3=-1.0
        )

    @classmethod
    def home(cls, home: HomePosition | None) -> "MissionItem":
        """Item 0 (home): a NAV_WAYPOINT in MAV_FRAME_GLOBAL (altitude AMSL); zeros if unknown."""
        if home is None:
            return cls(mavlink.MAV_CMD_NAV_WAYPOINT, frame=mavlink.MAV_FRAME_GLOBAL)
        return cls(
            mavlink.MAV_CMD_NAV_WAYPOINT,
            frame=mavlink.MAV_FRAME_GLOBAL,
            lat_deg=home.lat_deg,
            lon_deg=home.lon_deg,
            alt_m=home.alt_amsl_m,
        )

    @property
    def command_name(self) -> str:
        return command_name(self.command)

    def to_message(self, mav: mavlink.MAVLink, seq: int, target_system: int, target_component: int) -> mavlink.MAVLink_message:
        """The MISSION_ITEM_INT for sequence number ``seq``."""
        return mav.mission_item_int_encode(
            target_system,
            target_component,
            seq,
            self.frame,
            self.command,
            0,
            1 if self.autocontinue else 0,
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            int(round(self.lat_deg * 1e7)),
            int(round(self.lon_deg * 1e7)),
            float(self.alt_m),
            mavlink.MAV_MISSION_TYPE_MISSION,
        )

    @classmethod
    def from_message(cls, msg: mavlink.MAVLink_message) -> "MissionItem":
        """From MISSION_ITEM_INT (lat/lon ×1e7) or MISSION_ITEM (float degrees)."""
        if msg.get_type() == "MISSION_ITEM_INT":
            lat, lon = msg.x * 1e-7, msg.y * 1e-7
        else:
            lat, lon = float(msg.x), float(msg.y)
        return cls(
            command=msg.command,
            frame=msg.frame,
            param1=float(msg.param1),
            param2=float(msg.param2),
            param3=float(msg.param3),
            param4=float(msg.param4),
            lat_deg=lat,
            lon_deg=lon,
            alt_m=float(msg.z),
            autocontinue=bool(msg.autocontinue),
        )

    def close_to(self, other: "MissionItem", *, pos_tol_deg: float = 2e-7, tol: float = 1e-4) -> bool:
        """Same command, frame and autocontinue, and numbers equal within the wire's resolution
        (lat/lon to ``pos_tol_deg``, the rest to ``tol`` relative; NaN equals NaN)."""

        def same(a: float, b: float, t: float) -> bool:
            if math.isnan(a) or math.isnan(b):
                return math.isnan(a) and math.isnan(b)
            return abs(a - b) <= t * max(1.0, abs(a), abs(b))

        return (
            self.command == other.command
            and _same_frame(self.frame, other.frame)
            and self.autocontinue == other.autocontinue
            and all(same(getattr(self, f), getattr(other, f), tol) for f in ("param1", "param2", "param3", "param4", "alt_m"))
            and abs(self.lat_deg - other.lat_deg) <= pos_tol_deg
            and abs(self.lon_deg - other.lon_deg) <= pos_tol_deg
        )


_INT_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}


def _same_frame(a: int, b: int) -> bool:
    """Frames equal, counting ``*_INT`` frames as their plain twins (the same meaning)."""
    return _INT_FRAMES.get(a, a) == _INT_FRAMES.get(b, b)


# ----------------------------------------------------------------------------------- subscriptions
class Subscription:
    """Messages of some types, as they arrive: into a queue (:meth:`get`) or to a callback.

    Callbacks run on the receiver thread: keep them short and never call blocking
    :class:`Vehicle` methods from them. A full queue drops its oldest message (``dropped``
    counts them). Use as a context manager, or :meth:`close`.
    """

    def __init__(
        self,
        vehicle: "Vehicle",
        types: frozenset[str] | None,
        callback: Callable[[mavlink.MAVLink_message], None] | None,
        maxsize: int,
    ) -> None:
        self._vehicle = vehicle
        self.types = types
        self.callback = callback
        self.queue: "queue.Queue[mavlink.MAVLink_message]" = queue.Queue(maxsize=maxsize)
        self.dropped = 0

    def wants(self, msg_type: str) -> bool:
        return self.types is None or msg_type in self.types

    def _deliver(self, msg: mavlink.MAVLink_message) -> None:
        if self.callback is not None:
            try:
                self.callback(msg)
            except Exception:  # a user's callback must not kill the receiver
                log.exception("subscription callback failed on %s", msg.get_type())
            return
        while True:
            try:
                self.queue.put_nowait(msg)
                return
            except queue.Full:
                try:
                    self.queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout_s: float | None = None) -> mavlink.MAVLink_message | None:
        """The next message, waiting up to ``timeout_s`` wall seconds (None: forever); None on timeout."""
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def __iter__(self) -> Iterator[mavlink.MAVLink_message]:
        """Messages already queued, without waiting."""
        while True:
            try:
                yield self.queue.get_nowait()
            except queue.Empty:
                return

    def close(self) -> None:
        self._vehicle._unsubscribe(self)

    def __enter__(self) -> "Subscription":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------- vehicle
class Vehicle:
    """A connection to one vehicle; see the module docstring. Use as a context manager.

    ``url``: ``udpin:HOST:PORT`` (listen where the FC sends telemetry; ``udpin:127.0.0.1:0`` binds
    a free port, see :attr:`local_address`) or ``udpout:HOST:PORT`` (write to the FC's port).
    ``system_id``: talk to this vehicle only (default: the first vehicle heard).
    ``connect_timeout_s``: wall seconds to wait for the vehicle's HEARTBEAT in :meth:`connect`.
    Protocol retries: ``ack_timeout_s``/``command_tries`` (commands), ``param_timeout_s``/
    ``param_tries``, ``mission_timeout_s``/``mission_tries`` (all wall clock).
    Waits: ``wall_margin_s``, ``wall_per_sim_s`` (wall safety limit of a wait of T simulated
    seconds = margin + per_sim × T) and ``stall_timeout_s`` (give up when the vehicle has been
    silent this many wall seconds).
    """

    def __init__(
        self,
        url: str,
        *,
        system_id: int | None = None,
        connect_timeout_s: float = 15.0,
        ack_timeout_s: float = 1.0,
        command_tries: int = 5,
        param_timeout_s: float = 1.0,
        param_tries: int = 5,
        mission_timeout_s: float = 1.5,
        mission_tries: int = 5,
        wall_margin_s: float = 30.0,
        wall_per_sim_s: float = 3.0,
        stall_timeout_s: float = 10.0,
        statustext_history: int = 100,
        heartbeat_period_s: float = 1.0,
    ) -> None:
        for name, value in (
            ("connect_timeout_s", connect_timeout_s),
            ("ack_timeout_s", ack_timeout_s),
            ("param_timeout_s", param_timeout_s),
            ("mission_timeout_s", mission_timeout_s),
            ("wall_margin_s", wall_margin_s),
            ("stall_timeout_s", stall_timeout_s),
            ("heartbeat_period_s", heartbeat_period_s),
        ):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"Vehicle {name} must be a finite number > 0, got {value!r}")
        for name, count in (("command_tries", command_tries), ("param_tries", param_tries), ("mission_tries", mission_tries)):
            if not isinstance(count, int) or count < 1:
                raise ConfigError(f"Vehicle {name} must be an integer >= 1, got {count!r}")
        if system_id is not None and not 1 <= system_id <= 254:
            raise ConfigError(f"system_id must lie in 1..254, got {system_id}")
        self.url = url
        self.connect_timeout_s = float(connect_timeout_s)
        self.ack_timeout_s = float(ack_timeout_s)
        self.command_tries = command_tries
        self.param_timeout_s = float(param_timeout_s)
        self.param_tries = param_tries
        self.mission_timeout_s = float(mission_timeout_s)
        self.mission_tries = mission_tries
        self.wall_margin_s = float(wall_margin_s)
        self.wall_per_sim_s = float(wall_per_sim_s)
        self.stall_timeout_s = float(stall_timeout_s)
        self.heartbeat_period_s = float(heartbeat_period_s)
        self._wanted_system = system_id

        self._link: MavlinkUdp | None = None
        self._tx_lock = threading.Lock()
        self._cond = threading.Condition()
        self._state = Telemetry()
        self._texts: collections.deque[StatusText] = collections.deque(maxlen=statustext_history)
        self._chi: dict[str, float] = {}
        self._sigma: dict[str, float] = {}
        self._subs: tuple[Subscription, ...] = ()
        self._subs_lock = threading.Lock()
        self._params: dict[str, tuple[float, int]] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._vehicle_address: Address | None = None
        self._t0_wall = time.monotonic()
        self._rx_error: BaseException | None = None

    # -------------------------------------------------------------------------------- lifecycle
    def open(self) -> "Vehicle":
        """Open the link and start the receiver and heartbeat threads (does not wait for the vehicle)."""
        if self._link is not None:
            return self
        self._link = MavlinkUdp(self.url, source_system=GCS_SYSTEM_ID, source_component=GCS_COMPONENT_ID)
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._rx_loop, name=f"vehicle-rx {self.url}", daemon=True),
            threading.Thread(target=self._heartbeat_loop, name=f"vehicle-hb {self.url}", daemon=True),
        ]
        for t in self._threads:
            t.start()
        return self

    def wait_heartbeat(self, timeout_s: float | None = None) -> "Vehicle":
        """Wait up to ``timeout_s`` wall seconds (default ``connect_timeout_s``) for the vehicle's
        HEARTBEAT; raise :class:`ConnectTimeout` saying where we listened."""
        timeout = self.connect_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._state.heartbeats == 0:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.2))
            got = self._state.heartbeats > 0
        if not got:
            link = self._require_link()
            where = (
                f"listening on {link.local_address[0]}:{link.local_address[1]}"
                if link.endpoint.mode == "in"
                else f"writing to {link.endpoint.host}:{link.endpoint.port}"
            )
            hint = " (is the FC running with --gcs udp:HOST:PORT pointing here?)" if link.endpoint.mode == "in" else ""
            raise ConnectTimeout(
                f"no HEARTBEAT from a vehicle within {timeout:g} s wall, {where}{hint}", what="vehicle HEARTBEAT"
            )
        return self

    def connect(self, timeout_s: float | None = None) -> "Vehicle":
        """:meth:`open`, then :meth:`wait_heartbeat`; closes again on failure."""
        self.open()
        try:
            return self.wait_heartbeat(timeout_s)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop the threads and close the link (idempotent)."""
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        link, self._link = self._link, None
        if link is not None:
            with self._tx_lock:
                link.close()

    def __enter__(self) -> "Vehicle":
        return self.connect()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    @property
    def local_address(self) -> Address:
        """``(host, port)`` our socket is bound to (after :meth:`open`)."""
        return self._require_link().local_address

    @property
    def target_system(self) -> int:
        """The vehicle's system id (from its HEARTBEAT; the wanted one, or 1, before that)."""
        s = self._state.system_id
        return s if s is not None else (self._wanted_system or 1)

    @property
    def target_component(self) -> int:
        c = self._state.component_id
        return c if c is not None else mavlink.MAV_COMP_ID_AUTOPILOT1

    def _require_link(self) -> MavlinkUdp:
        link = self._link
        if link is None:
            raise LinkClosedError(f"vehicle connection {self.url} is not open")
        return link

    @property
    def mav(self) -> mavlink.MAVLink:
        """pymavlink encoder for building messages to :meth:`send` (``vehicle.mav.xxx_encode(...)``)."""
        return self._require_link().mav

    # -------------------------------------------------------------------------------- sending
    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Send one message (thread-safe)."""
        link = self._require_link()
        with self._tx_lock:
            link.send(msg)

    def _heartbeat_loop(self) -> None:
        while not self._stop.is_set():
            link = self._link
            if link is None:
                return
            try:
                msg = link.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
                )
                with self._tx_lock:
                    if link.closed:
                        return
                    link.send(msg)
            except LinkClosedError:
                return
            self._stop.wait(self.heartbeat_period_s)

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._t0_wall) * 1000.0) & 0xFFFFFFFF

    # -------------------------------------------------------------------------------- receiving
    def _rx_loop(self) -> None:
        link = self._link
        assert link is not None
        while not self._stop.is_set():
            try:
                batch = link.recv(0.1)
            except LinkClosedError:
                return
            except Exception as exc:  # pragma: no cover - defensive: keep the reason for waiters
                self._rx_error = exc
                log.exception("vehicle receiver failed")
                return
            if not batch:
                continue
            accepted: list[mavlink.MAVLink_message] = []
            with self._cond:
                for msg, addr in batch:
                    if self._ingest(msg, addr):
                        accepted.append(msg)
                self._cond.notify_all()
            subs = self._subs
            if subs and accepted:
                for msg in accepted:
                    t = msg.get_type()
                    for sub in subs:
                        if sub.wants(t):
                            sub._deliver(msg)

    def _ingest(self, msg: mavlink.MAVLink_message, addr: Address) -> bool:
        """Update the state from one message (lock held); False if it is not from our vehicle."""
        st = self._state
        src = msg.get_srcSystem()
        t = msg.get_type()
        if st.system_id is None:
            if t != "HEARTBEAT" or msg.type == mavlink.MAV_TYPE_GCS or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                return False
            if self._wanted_system is not None and src != self._wanted_system:
                return False
            st = replace(st, system_id=src, component_id=msg.get_srcComponent())
            self._vehicle_address = addr
        elif src != st.system_id:
            return False
        upd: dict[str, Any] = {"last_message_wall_s": time.monotonic()}
        if t in _TIMED_MESSAGES:
            upd["sim_time_s"] = msg.time_boot_ms * 1e-3
        if t == "HEARTBEAT":
            if msg.get_srcComponent() != st.component_id or msg.type == mavlink.MAV_TYPE_GCS:
                self._state = replace(st, **upd)
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
        elif t == "MISSION_CURRENT":
            upd["mission_current"] = msg.seq
            total = getattr(msg, "total", 0)
            if total and total != 0xFFFF:
                upd["mission_total"] = total
        elif t == "MISSION_ITEM_REACHED":
            upd["mission_reached"] = msg.seq
        elif t == "NAMED_VALUE_FLOAT":
            name = _text(msg.name)
            if name.startswith("CHI_"):
                self._chi[name[4:]] = msg.value
                upd["chi"] = dict(self._chi)
            elif name.startswith("SIG_"):
                self._sigma[name[4:]] = msg.value
                upd["sigma"] = dict(self._sigma)
        elif t == "NAMED_VALUE_INT":
            if _text(msg.name) == "OVERRUN":
                upd["overruns"] = msg.value
        elif t == "POSITION_TARGET_LOCAL_NED":
            upd["setpoint_ned_m"] = (msg.x, msg.y, msg.z)
        elif t == "STATUSTEXT":
            self._texts.append(StatusText(msg.severity, _text(msg.text), upd.get("sim_time_s", st.sim_time_s), time.time()))
            upd["statustexts"] = tuple(self._texts)
        elif t == "PARAM_VALUE":
            self._params[_text(msg.param_id)] = (msg.param_value, msg.param_type)
        self._state = replace(st, **upd)
        return True

    # ----------------------------------------------------------------------------- subscriptions
    def subscribe(
        self,
        types: str | Iterable[str] | None = None,
        callback: Callable[[mavlink.MAVLink_message], None] | None = None,
        *,
        maxsize: int = 10000,
    ) -> Subscription:
        """Receive messages of ``types`` (names like ``"STATUSTEXT"``; None = all) from the vehicle,
        from now on: into the subscription's queue, or to ``callback`` (on the receiver thread)."""
        type_set = None if types is None else frozenset([types] if isinstance(types, str) else types)
        sub = Subscription(self, type_set, callback, maxsize)
        with self._subs_lock:
            self._subs = self._subs + (sub,)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._subs_lock:
            self._subs = tuple(s for s in self._subs if s is not sub)

    # -------------------------------------------------------------------------------- telemetry
    @property
    def telemetry(self) -> Telemetry:
        """The latest telemetry (an immutable snapshot)."""
        return self._state

    @property
    def sim_time_s(self) -> float | None:
        return self._state.sim_time_s

    @property
    def armed(self) -> bool:
        return self._state.armed

    @property
    def mode(self) -> str | None:
        """Current flight-mode name (from the last HEARTBEAT)."""
        return self._state.mode_name

    @property
    def position_ned_m(self) -> tuple[float, float, float] | None:
        return self._state.position_ned_m

    @property
    def altitude_m(self) -> float | None:
        return self._state.altitude_m

    @property
    def statustexts(self) -> tuple[StatusText, ...]:
        return self._state.statustexts

    # ------------------------------------------------------------------------------------ waits
    def wait_for(
        self,
        predicate: Callable[[Telemetry], bool],
        timeout_sim_s: float,
        *,
        what: str,
        value: Callable[[Telemetry], object] | None = None,
    ) -> Telemetry:
        """Wait until ``predicate(telemetry)`` holds; return that telemetry.

        ``timeout_sim_s`` counts simulated seconds from the vehicle's time now. Also gives up when
        the wall clock passes ``wall_margin_s + wall_per_sim_s * timeout_sim_s``, or when nothing
        has come from the vehicle for ``stall_timeout_s`` wall seconds (simulator stopped, link
        down). Raises :class:`VehicleTimeout` naming ``what``, the last ``value(telemetry)`` and
        the simulated time.
        """
        if not (math.isfinite(timeout_sim_s) and timeout_sim_s >= 0):
            raise ConfigError(f"timeout_sim_s must be a finite number >= 0, got {timeout_sim_s!r}")
        self._require_link()
        wall_start = time.monotonic()
        wall_deadline = wall_start + self.wall_margin_s + self.wall_per_sim_s * timeout_sim_s
        with self._cond:
            st = self._state
            sim_start = st.sim_time_s
            while True:
                st = self._state
                if predicate(st):
                    return st
                now = time.monotonic()
                if sim_start is None and st.sim_time_s is not None:
                    sim_start = st.sim_time_s
                why = None
                if sim_start is not None and st.sim_time_s is not None and st.sim_time_s - sim_start >= timeout_sim_s:
                    why = f"timed out after {timeout_sim_s:g} s simulated"
                elif now >= wall_deadline:
                    why = f"gave up after {now - wall_start:.1f} s wall (safety limit; simulated time advanced too slowly)"
                else:
                    last_rx = st.last_message_wall_s if st.last_message_wall_s is not None else wall_start
                    silent = now - max(last_rx, wall_start)
                    if silent >= self.stall_timeout_s:
                        why = f"gave up: nothing from the vehicle for {silent:.1f} s wall (simulator stopped or link down)"
                    elif self._rx_error is not None or self._link is None:
                        why = "gave up: the connection closed"
                if why is not None:
                    last = value(st) if value is not None else None
                    t_txt = "unknown" if st.sim_time_s is None else f"{st.sim_time_s:.2f} s"
                    raise VehicleTimeout(
                        f"{why} waiting for {what}; last value {_fmt(last)}; sim time {t_txt}",
                        what=what,
                        last_value=last,
                        sim_time_s=st.sim_time_s,
                    )
                self._cond.wait(0.1)

    def wait_armed(self, timeout_sim_s: float = 5.0) -> Telemetry:
        return self.wait_for(lambda s: s.armed, timeout_sim_s, what="armed", value=lambda s: "armed" if s.armed else "disarmed")

    def wait_disarmed(self, timeout_sim_s: float = 60.0) -> Telemetry:
        return self.wait_for(
            lambda s: not s.armed and s.heartbeats > 0,
            timeout_sim_s,
            what="disarmed",
            value=lambda s: f"{'armed' if s.armed else 'disarmed'}, altitude {_fmt(s.altitude_m)} m",
        )

    def wait_mode(self, name: str | int, timeout_sim_s: float = 5.0) -> Telemetry:
        number = mode_number(name)
        return self.wait_for(
            lambda s: s.mode_number == number, timeout_sim_s, what=f"mode {mode_name(number)}", value=lambda s: s.mode_name
        )

    def wait_altitude(self, alt_m: float, tol_m: float = 0.3, timeout_sim_s: float = 30.0) -> Telemetry:
        """Wait until the height above home is within ``tol_m`` of ``alt_m`` (metres, up)."""
        return self.wait_for(
            lambda s: s.altitude_m is not None and abs(s.altitude_m - alt_m) <= tol_m,
            timeout_sim_s,
            what=f"altitude {alt_m:g} ± {tol_m:g} m",
            value=lambda s: None if s.altitude_m is None else f"{s.altitude_m:.2f} m",
        )

    def wait_position_ned(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        tol_m: float = 0.5,
        timeout_sim_s: float = 30.0,
        *,
        max_speed_mps: float | None = None,
    ) -> Telemetry:
        """Wait until the vehicle is within ``tol_m`` (3-D distance) of the NED point, and slower
        than ``max_speed_mps`` if given."""
        target = (north_m, east_m, down_m)

        def ok(s: Telemetry) -> bool:
            if s.position_ned_m is None or math.dist(s.position_ned_m, target) > tol_m:
                return False
            return max_speed_mps is None or (s.velocity_ned_mps is not None and math.hypot(*s.velocity_ned_mps) <= max_speed_mps)

        def val(s: Telemetry) -> object:
            if s.position_ned_m is None:
                return None
            n, e, d = s.position_ned_m
            return f"NED ({n:.2f}, {e:.2f}, {d:.2f}) m, {math.dist(s.position_ned_m, target):.2f} m away"

        return self.wait_for(
            ok, timeout_sim_s, what=f"position NED ({north_m:g}, {east_m:g}, {down_m:g}) ± {tol_m:g} m", value=val
        )

    def wait_landed_state(self, state: str, timeout_sim_s: float = 30.0) -> Telemetry:
        """Wait for EXTENDED_SYS_STATE landed_state ``"ON_GROUND"``, ``"IN_AIR"``, ..."""
        want = state.upper()
        return self.wait_for(
            lambda s: s.landed_state_name == want, timeout_sim_s, what=f"landed state {want}", value=lambda s: s.landed_state_name
        )

    def wait_statustext(self, contains: str, timeout_sim_s: float = 10.0, *, since: int = 0) -> StatusText:
        """Wait for a STATUSTEXT containing ``contains`` (case-insensitive) among the history
        entries from index ``since`` on (``len(vehicle.statustexts)`` before the action)."""
        needle = contains.lower()

        def find(s: Telemetry) -> StatusText | None:
            return next((x for x in s.statustexts[since:] if needle in x.text.lower()), None)

        st = self.wait_for(
            lambda s: find(s) is not None,
            timeout_sim_s,
            what=f"STATUSTEXT containing {contains!r}",
            value=lambda s: s.last_statustext.text if s.last_statustext else None,
        )
        found = find(st)
        assert found is not None
        return found

    def wait_sim_time(self, sim_time_s: float) -> Telemetry:
        """Wait until the vehicle's simulated clock reaches ``sim_time_s``."""
        now = self._state.sim_time_s or 0.0
        return self.wait_for(
            lambda s: s.sim_time_s is not None and s.sim_time_s >= sim_time_s,
            max(0.0, sim_time_s - now) + 1.0,
            what=f"sim time {sim_time_s:g} s",
            value=lambda s: s.sim_time_s,
        )

    def sleep_sim(self, duration_s: float) -> Telemetry:
        """Let ``duration_s`` simulated seconds pass."""
        start = self._state.sim_time_s
        if start is None:
            st = self.wait_for(lambda s: s.sim_time_s is not None, 5.0, what="simulated time")
            start = st.sim_time_s
        assert start is not None
        return self.wait_sim_time(start + duration_s)

    # ------------------------------------------------------------------------------ commands
    def command_long(
        self,
        command: int,
        param1: float = 0.0,
        param2: float = 0.0,
        param3: float = 0.0,
        param4: float = 0.0,
        param5: float = 0.0,
        param6: float = 0.0,
        param7: float = 0.0,
        *,
        check: bool = False,
        tries: int | None = None,
    ) -> int:
        """Send COMMAND_LONG and return the MAV_RESULT of its COMMAND_ACK.

        No ACK within ``ack_timeout_s`` wall: re-sent with ``confirmation`` + 1, up to ``tries``
        (default ``command_tries``) sends, then :class:`CommandTimeout`. With ``check``, a result
        other than ACCEPTED raises :class:`CommandDenied` with the vehicle's STATUSTEXT reason.
        """
        link = self._require_link()
        params = (param1, param2, param3, param4, param5, param6, param7)

        def build(attempt: int) -> mavlink.MAVLink_message:
            return link.mav.command_long_encode(self.target_system, self.target_component, command, min(attempt, 255), *params)

        return self._command(command, build, check=check, tries=tries)

    def command_int(
        self,
        command: int,
        *,
        frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        param1: float = 0.0,
        param2: float = 0.0,
        param3: float = 0.0,
        param4: float = 0.0,
        x: int = 0,
        y: int = 0,
        z: float = 0.0,
        check: bool = False,
        tries: int | None = None,
    ) -> int:
        """Send COMMAND_INT (``x``/``y`` = lat/lon × 1e7 in global frames) and return the MAV_RESULT;
        retried like :meth:`command_long` (COMMAND_INT has no confirmation field: same message)."""
        link = self._require_link()

        def build(attempt: int) -> mavlink.MAVLink_message:
            return link.mav.command_int_encode(
                self.target_system, self.target_component, frame, command, 0, 0, param1, param2, param3, param4, x, y, z
            )

        return self._command(command, build, check=check, tries=tries)

    def _command(
        self, command: int, build: Callable[[int], mavlink.MAVLink_message], *, check: bool, tries: int | None
    ) -> int:
        n_tries = self.command_tries if tries is None else tries
        texts: list[StatusText] = []
        result: int | None = None
        with self.subscribe(("COMMAND_ACK", "STATUSTEXT")) as sub:
            for attempt in range(n_tries):
                self.send(build(attempt))
                deadline = time.monotonic() + self.ack_timeout_s
                while result is None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    msg = sub.get(remaining)
                    if msg is None:
                        break
                    if msg.get_type() == "STATUSTEXT":
                        texts.append(StatusText(msg.severity, _text(msg.text), self._state.sim_time_s, time.time()))
                        continue
                    if msg.command != command:
                        continue
                    if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
                        deadline = time.monotonic() + self.ack_timeout_s
                        continue
                    result = msg.result
                if result is not None:
                    break
            if result is None:
                raise CommandTimeout(
                    f"no COMMAND_ACK for {command_name(command)} after {n_tries} tries ({n_tries * self.ack_timeout_s:g} s wall)",
                    what=f"COMMAND_ACK for {command_name(command)}",
                    sim_time_s=self._state.sim_time_s,
                )
            if check and result != mavlink.MAV_RESULT_ACCEPTED:
                reason = self._reason(sub, texts)
                raise CommandDenied(command, result, reason)
        return result

    def _reason(self, sub: Subscription, texts: list[StatusText], grace_s: float = 0.3) -> str | None:
        """The vehicle's explanation of a refusal: the most severe recent STATUSTEXT that came
        with it (waiting ``grace_s`` wall seconds for one if none has come yet)."""
        deadline = time.monotonic() + grace_s
        while not texts:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            msg = sub.get(remaining)
            if msg is not None and msg.get_type() == "STATUSTEXT":
                texts.append(StatusText(msg.severity, _text(msg.text), self._state.sim_time_s, time.time()))
        if not texts:
            return None
        serious = [t for t in texts if t.severity <= mavlink.MAV_SEVERITY_WARNING]
        return (serious or texts)[-1].text

    # ------------------------------------------------------------------------- flight commands
    def arm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """COMPONENT_ARM_DISARM arm (``force``: skip the pre-arm checks); then wait for the
        armed HEARTBEAT. Raises :class:`CommandDenied` with the reason."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, FORCE_ARM_MAGIC if force else 0.0, check=True)
        if wait:
            self.wait_armed(timeout_sim_s)

    def disarm(self, force: bool = False, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """COMPONENT_ARM_DISARM disarm (``force`` is needed in the air); then wait for disarmed."""
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_ARM_MAGIC if force else 0.0, check=True)
        if wait:
            self.wait_disarmed(timeout_sim_s)

    def set_mode(self, name: str | int, *, wait: bool = True, timeout_sim_s: float = 5.0) -> None:
        """MAV_CMD_DO_SET_MODE (param1 CUSTOM_MODE_ENABLED, param2 the ArduCopter mode number);
        then wait until the HEARTBEAT shows it. Raises :class:`UnknownModeError` for a bad name,
        :class:`CommandDenied` when the vehicle refuses."""
        number = mode_number(name)
        self.command_long(
            mavlink.MAV_CMD_DO_SET_MODE, float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(number), check=True
        )
        if wait:
            self.wait_mode(number, timeout_sim_s)

    def takeoff(self, alt_m: float) -> None:
        """MAV_CMD_NAV_TAKEOFF to ``alt_m`` metres above home (vehicle armed, in GUIDED).
        Returns once accepted; :meth:`wait_altitude` waits for the climb."""
        self.command_long(mavlink.MAV_CMD_NAV_TAKEOFF, param7=float(alt_m), check=True)

    def goto_ned(self, north_m: float, east_m: float, down_m: float, yaw_deg: float | None = None) -> None:
        """Fly to a local NED point (metres from home; down negative = up) with
        SET_POSITION_TARGET_LOCAL_NED; yaw in degrees (0 north, 90 east), None keeps the heading.

        The vehicle only follows set-points in GUIDED: if it is in another mode, this switches to
        GUIDED first. The message has no acknowledgement; use :meth:`wait_position_ned`.
        """
        for name, v in (("north_m", north_m), ("east_m", east_m), ("down_m", down_m)):
            if not math.isfinite(v):
                raise ConfigError(f"goto_ned {name} must be finite, got {v!r}")
        if yaw_deg is not None and not math.isfinite(yaw_deg):
            raise ConfigError(f"goto_ned yaw_deg must be finite or None, got {yaw_deg!r}")
        if self._state.mode_number != COPTER_MODES["GUIDED"]:
            self.set_mode("GUIDED")
        mask = (
            mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        )
        yaw_rad = 0.0
        if yaw_deg is None:
            mask |= mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
        else:
            yaw_rad = math.radians(yaw_deg)
        msg = self.mav.set_position_target_local_ned_encode(
            self._boot_ms(), self.target_system, self.target_component, mavlink.MAV_FRAME_LOCAL_NED, mask,
            float(north_m), float(east_m), float(down_m), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw_rad, 0.0,
        )  # fmt: skip
        self.send(msg)

    def goto_global(self, lat_deg: float, lon_deg: float, alt_rel_m: float, yaw_deg: float | None = None) -> None:
        """Fly to a global point (altitude ``alt_rel_m`` above home) with COMMAND_INT
        MAV_CMD_DO_REPOSITION (the vehicle switches to GUIDED); yaw None keeps the heading."""
        for name, v in (("lat_deg", lat_deg), ("lon_deg", lon_deg), ("alt_rel_m", alt_rel_m)):
            if not math.isfinite(v):
                raise ConfigError(f"goto_global {name} must be finite, got {v!r}")
        self.command_int(
            mavlink.MAV_CMD_DO_REPOSITION,
            frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            param1=-1.0,
            param2=float(mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
            param4=_NAN if yaw_deg is None else float(yaw_deg),
            x=int(round(lat_deg * 1e7)),
            y=int(round(lon_deg * 1e7)),
            z=float(alt_rel_m),
            check=True,
        )

    def land(self) -> None:
        """MAV_CMD_NAV_LAND (unused parameters NaN, as MAVSDK sends them): descend here, disarm on touchdown."""
        self.command_long(mavlink.MAV_CMD_NAV_LAND, 0.0, 0.0, 0.0, _NAN, _NAN, _NAN, 0.0, check=True)

    def rtl(self) -> None:
        """MAV_CMD_NAV_RETURN_TO_LAUNCH."""
        self.command_long(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, check=True)

    def start_mission(self, first_seq: int = 0) -> None:
        """MAV_CMD_MISSION_START (switches to AUTO; 0 = from the current item)."""
        self.command_long(mavlink.MAV_CMD_MISSION_START, float(first_seq), 0.0, check=True)

    def set_current_item(self, seq: int) -> None:
        """MAV_CMD_DO_SET_MISSION_CURRENT: continue the mission at vehicle sequence number
        ``seq`` (1 = the first item after home)."""
        if seq < 0:
            raise ConfigError(f"mission sequence number must be >= 0, got {seq}")
        self.command_long(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, float(seq), check=True)

    def request_message(self, message_id: int) -> int:
        """MAV_CMD_REQUEST_MESSAGE: have the vehicle send one message once; returns the MAV_RESULT."""
        return self.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, float(message_id))

    def get_home(self, timeout_s: float = 5.0) -> HomePosition:
        """The vehicle's home: the last HOME_POSITION, or asked for (MAV_CMD_GET_HOME_POSITION,
        re-asked every ``ack_timeout_s``) for up to ``timeout_s`` wall seconds."""
        home = self._state.home
        if home is not None:
            return home
        deadline = time.monotonic() + timeout_s
        link = self._require_link()
        with self.subscribe("HOME_POSITION") as sub:
            while True:
                self.send(
                    link.mav.command_long_encode(
                        self.target_system, self.target_component, mavlink.MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0, 0, 0
                    )
                )
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                if sub.get(min(remaining, self.ack_timeout_s)) is not None:
                    home = self._state.home
                    assert home is not None
                    return home
        raise VehicleTimeout(
            f"no HOME_POSITION from the vehicle within {timeout_s:g} s wall",
            what="HOME_POSITION",
            sim_time_s=self._state.sim_time_s,
        )

    # ----------------------------------------------------------------------------- parameters
    def get_param(self, name: str) -> float:
        """PARAM_REQUEST_READ by name (re-requested every ``param_timeout_s``, ``param_tries``
        times); returns the value (an ``int`` for integer parameters). Raises :class:`ParamError`
        when the vehicle never answers (unknown name)."""
        value, _ = self._read_param(name)
        return value

    def _read_param(self, name: str) -> tuple[float, int]:
        """(value, MAV_PARAM_TYPE). Stops re-requesting early when the vehicle sent a STATUSTEXT
        naming the parameter instead of a value (e.g. "unknown SMC_FOO"): that is its answer."""
        pid = _param_id(name)
        link = self._require_link()
        said: list[str] = []

        def match(m: mavlink.MAVLink_message) -> bool:
            if m.get_type() == "STATUSTEXT":
                text = _text(m.text)
                if re.search(rf"\b{re.escape(pid)}\b", text.upper()):
                    said.append(text)
                    return True
                return False
            return _text(m.param_id) == pid

        tries = 0
        with self.subscribe(("PARAM_VALUE", "STATUSTEXT")) as sub:
            while tries < self.param_tries and not said:
                tries += 1
                self.send(link.mav.param_request_read_encode(self.target_system, self.target_component, pid.encode(), -1))
                msg = _await(sub, match, self.param_timeout_s)
                if msg is not None and msg.get_type() == "PARAM_VALUE":
                    return _param_value(msg), msg.param_type
        if said:
            raise ParamError(f"no value for parameter {pid}: {said[-1]}")
        raise ParamError(
            f"no PARAM_VALUE for {pid!r} after {tries} requests {self.param_timeout_s:g} s apart"
            " (unknown parameter, or the vehicle is not answering)"
        )

    def set_param(self, name: str, value: float) -> float:
        """PARAM_SET (re-sent every ``param_timeout_s`` until the PARAM_VALUE echo, ``param_tries``
        times); returns the value now in force. Raises :class:`ParamRejected` (with the
        STATUSTEXT reason) when the vehicle kept another value."""
        pid = _param_id(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"parameter {pid}: value must be a number, got {value!r}")
        cached = self._params.get(pid)
        ptype = cached[1] if cached is not None else self._read_param(pid)[1]
        link = self._require_link()
        texts: list[StatusText] = []
        with self.subscribe(("PARAM_VALUE", "STATUSTEXT")) as sub:
            for _ in range(self.param_tries):
                self.send(link.mav.param_set_encode(self.target_system, self.target_component, pid.encode(), float(value), ptype))
                deadline = time.monotonic() + self.param_timeout_s
                while (remaining := deadline - time.monotonic()) > 0:
                    msg = sub.get(remaining)
                    if msg is None:
                        break
                    if msg.get_type() == "STATUSTEXT":
                        texts.append(StatusText(msg.severity, _text(msg.text), self._state.sim_time_s, time.time()))
                        continue
                    if _text(msg.param_id) != pid:
                        continue
                    got = _param_value(msg)
                    if not _float32_equal(float(got), float(value)):
                        raise ParamRejected(pid, float(value), float(got), self._reason(sub, texts))
                    return got
        raise ParamError(f"no PARAM_VALUE echo for PARAM_SET {pid} after {self.param_tries} tries {self.param_timeout_s:g} s apart")

    def list_params(self) -> dict[str, float]:
        """Every parameter (PARAM_REQUEST_LIST), in index order: name -> value (``int`` for
        integer parameters). Indices still missing when the stream pauses for
        ``param_timeout_s`` are re-requested one by one (PARAM_REQUEST_READ by index), up to
        ``param_tries`` rounds; then :class:`ParamError` lists what is missing."""
        link = self._require_link()
        by_index: dict[int, tuple[str, float]] = {}
        count: int | None = None
        with self.subscribe("PARAM_VALUE") as sub:
            self.send(link.mav.param_request_list_encode(self.target_system, self.target_component))
            rounds = 0
            while count is None or len(by_index) < count:
                msg = sub.get(self.param_timeout_s)
                if msg is not None:
                    count = msg.param_count
                    if 0 <= msg.param_index < msg.param_count:
                        by_index[msg.param_index] = (_text(msg.param_id), _param_value(msg))
                    continue
                rounds += 1
                if rounds >= self.param_tries:
                    missing = "all" if count is None else f"{count - len(by_index)} of {count}"
                    raise ParamError(f"parameter list incomplete after {rounds} retries: {missing} missing")
                if count is None:
                    self.send(link.mav.param_request_list_encode(self.target_system, self.target_component))
                else:
                    for index in range(count):
                        if index not in by_index:
                            self.send(link.mav.param_request_read_encode(self.target_system, self.target_component, b"", index))
        return {name: value for _, (name, value) in sorted(by_index.items())}

    # -------------------------------------------------------------------------------- missions
    def upload_mission(self, items: Sequence[MissionItem]) -> None:
        """Upload ``items`` (the items to fly; home is inserted as item 0 from the vehicle's
        HOME_POSITION): MISSION_COUNT -> MISSION_REQUEST_INT/MISSION_REQUEST -> MISSION_ITEM_INT
        ... -> MISSION_ACK.

        Retries: while the vehicle has requested nothing, MISSION_COUNT is re-sent every
        ``mission_timeout_s`` (``mission_tries`` times); after that the vehicle drives the
        transaction (it re-requests what it misses) and we answer every request, giving up after
        ``mission_tries`` × ``mission_timeout_s`` of silence. Raises :class:`MissionError` with the
        MAV_MISSION_RESULT name when the vehicle refuses an item.
        """
        for i, item in enumerate(items):
            if not isinstance(item, MissionItem):
                raise ConfigError(f"mission item {i} must be a MissionItem, got {type(item).__name__}")
        try:
            home = self.get_home(timeout_s=max(2.0, 2 * self.mission_timeout_s))
        except VehicleTimeout:
            home = None  # ArduPilot replaces item 0 with its home anyway
        full = [MissionItem.home(home), *items]
        link = self._require_link()
        ts, tc = self.target_system, self.target_component
        count_msg = link.mav.mission_count_encode(ts, tc, len(full), mavlink.MAV_MISSION_TYPE_MISSION)
        texts: list[StatusText] = []
        requested = False
        silent_rounds = 0
        with self.subscribe(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK", "STATUSTEXT")) as sub:
            self.send(count_msg)
            while True:
                msg = sub.get(self.mission_timeout_s)
                if msg is None:
                    silent_rounds += 1
                    if silent_rounds >= self.mission_tries:
                        raise MissionError(
                            f"mission upload ({len(full)} items incl. home) timed out: the vehicle went silent for"
                            f" {silent_rounds * self.mission_timeout_s:g} s wall"
                            + ("" if requested else " without requesting any item")
                        )
                    if not requested:
                        self.send(count_msg)
                    continue
                t = msg.get_type()
                if t == "STATUSTEXT":
                    texts.append(StatusText(msg.severity, _text(msg.text), self._state.sim_time_s, time.time()))
                    continue
                if getattr(msg, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
                    continue
                silent_rounds = 0
                if t == "MISSION_ACK":
                    if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                        if requested or len(full) == 0:
                            return
                        continue  # a stale ACK from an earlier transaction
                    raise MissionError(
                        f"mission upload refused with {mission_result_name(msg.type)}",
                        result=msg.type,
                        reason=self._reason(sub, texts, grace_s=0.2),
                    )
                seq = msg.seq
                if not 0 <= seq < len(full):
                    raise MissionError(f"the vehicle requested item {seq} of a {len(full)}-item mission")
                requested = True
                self.send(full[seq].to_message(link.mav, seq, ts, tc))

    def download_mission(self, *, include_home: bool = False) -> list[MissionItem]:
        """Download the mission: MISSION_REQUEST_LIST -> MISSION_COUNT -> MISSION_REQUEST_INT
        (each item) -> MISSION_ACK. Each request is re-sent every ``mission_timeout_s`` up to
        ``mission_tries`` times. Returns the items to fly: **item 0 (home) is stripped** unless
        ``include_home`` (then the list is exactly the vehicle's, sequence number = index)."""
        link = self._require_link()
        ts, tc = self.target_system, self.target_component
        mtype = mavlink.MAV_MISSION_TYPE_MISSION
        with self.subscribe(("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK")) as sub:
            count_reply = self._exchange(
                sub,
                link.mav.mission_request_list_encode(ts, tc, mtype),
                lambda m: m.get_type() == "MISSION_COUNT" and getattr(m, "mission_type", 0) == mtype,
                "MISSION_COUNT",
            )
            count = count_reply.count
            items: list[MissionItem] = []
            for seq in range(count):
                reply = self._exchange(
                    sub,
                    link.mav.mission_request_int_encode(ts, tc, seq, mtype),
                    lambda m, s=seq: m.get_type() in ("MISSION_ITEM_INT", "MISSION_ITEM")
                    and m.seq == s
                    and getattr(m, "mission_type", 0) == mtype,
                    f"mission item {seq}",
                )
                items.append(MissionItem.from_message(reply))
            self.send(link.mav.mission_ack_encode(ts, tc, mavlink.MAV_MISSION_ACCEPTED, mtype))
        return items if include_home else items[1:]

    def clear_mission(self) -> None:
        """MISSION_CLEAR_ALL, re-sent until the MISSION_ACK; raises :class:`MissionError` if refused."""
        link = self._require_link()
        ts, tc = self.target_system, self.target_component
        with self.subscribe("MISSION_ACK") as sub:
            ack = self._exchange(
                sub,
                link.mav.mission_clear_all_encode(ts, tc, mavlink.MAV_MISSION_TYPE_MISSION),
                lambda m: getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION,
                "MISSION_ACK for MISSION_CLEAR_ALL",
            )
        if ack.type != mavlink.MAV_MISSION_ACCEPTED:
            raise MissionError(f"mission clear refused with {mission_result_name(ack.type)}", result=ack.type)

    def _exchange(
        self,
        sub: Subscription,
        request: mavlink.MAVLink_message,
        match: Callable[[mavlink.MAVLink_message], bool],
        what: str,
    ) -> mavlink.MAVLink_message:
        """Send ``request`` until a matching reply comes (``mission_tries`` × ``mission_timeout_s``);
        a MISSION_ACK that is not the awaited reply is an error from the vehicle."""
        for _ in range(self.mission_tries):
            self.send(request)
            deadline = time.monotonic() + self.mission_timeout_s
            while (remaining := deadline - time.monotonic()) > 0:
                msg = sub.get(remaining)
                if msg is None:
                    break
                if match(msg):
                    return msg
                if msg.get_type() == "MISSION_ACK" and getattr(msg, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION:
                    raise MissionError(f"waiting for {what}, the vehicle ended the transaction with {mission_result_name(msg.type)}", result=msg.type)
        raise MissionError(f"no {what} after {self.mission_tries} requests {self.mission_timeout_s:g} s apart")

    def __repr__(self) -> str:
        st = self._state
        return f"Vehicle({self.url!r}, system={st.system_id}, mode={st.mode_name}, armed={st.armed})"


# ----------------------------------------------------------------------------------------- helpers
def _text(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    return raw.split("\0", 1)[0]


def _param_id(name: str) -> str:
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"parameter name must be a non-empty string, got {name!r}")
    pid = name.strip().upper()
    if len(pid) > 16:
        raise ConfigError(f"parameter name {pid!r} is longer than MAVLink's 16 characters")
    return pid


def _param_value(msg: mavlink.MAVLink_message) -> float:
    v = float(msg.param_value)
    if msg.param_type in _INT_PARAM_TYPES and math.isfinite(v):
        return int(round(v))
    return v


def _float32_equal(a: float, b: float) -> bool:
    """Equal as MAVLink's float32 carries them."""
    if math.isnan(a) or math.isnan(b):
        return False
    return a == b or abs(a - b) <= 1e-6 * max(abs(a), abs(b))


def _await(sub: Subscription, match: Callable[[mavlink.MAVLink_message], bool], timeout_s: float) -> mavlink.MAVLink_message | None:
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        msg = sub.get(remaining)
        if msg is None:
            return None
        if match(msg):
            return msg
    return None


def _fmt(value: object) -> str:
    if value is None:
        return "none"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)
