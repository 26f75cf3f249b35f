"""Scripted missions: a TOML file of mission items, SITL settings and expectations, and the
runner behind ``smcpilot mission run FILE``.

A mission file says what to fly (``[[item]]``), where (``[sitl]``, used only when the runner
launches SITL itself) and what must hold afterwards (``[[expect]]``)::

    name = "hop"                       # optional: name and description (strings)
    description = "take off, fly 5 m north, land"

    [sitl]                             # optional; every key optional
    controller = "adaptive_pid_smc"    # adaptive_pid_smc | pid_smc | cascade_pid
    vehicle = "../vehicles/heavy-quad.toml"   # vehicle TOML, relative to this file
    seed = 0                           # seed of sensor noise and gusts (integer >= 0)
    plant = "rigid-body"               # rigid-body | paper
    noise = false                      # sensor noise on the simulated state
    noise_scale = 1.0                  # multiplies the noise levels (>= 0)
    wind_force_ned_n = [0.4, -0.3, 0.0]   # constant wind force, newtons, NED
    gust_std_n = 0.3                   # horizontal gust force std, newtons (>= 0)
    home = [-35.363261, 149.165230, 584.0]  # lat deg, lon deg, alt m AMSL (default: the FC's)
    max_duration_s = 600.0             # simulated seconds of flight before the runner gives up

    [[item]]
    type = "takeoff"
    alt_m = 3.0

    [[item]]
    type = "waypoint"
    north_m = 5.0
    east_m = 0.0
    alt_m = 3.0

    [[item]]
    type = "land"

    [[expect]]
    kind = "reach"
    item = 2
    within_m = 0.3
    by_s = 15.0

    [[expect]]
    kind = "landed"

Items (``[[item]]``, flown in file order; item N is the vehicle's mission sequence number N,
home being item 0, inserted by :meth:`ground.client.Vehicle.upload_mission`)
----------------------------------------------------------------------------------------------
Positions are either ``north_m``/``east_m`` (metres north/east of the vehicle's home, MAVLink
local NED frame; converted to latitude/longitude through the vehicle's ``HOME_POSITION`` with
:func:`smcpilot.geo.ned_to_global`) or ``lat_deg``/``lon_deg`` (WGS-84 degrees), never both.
Altitudes ``alt_m`` are metres above home (``MAV_FRAME_GLOBAL_RELATIVE_ALT``).

============  ===================================================  =============================
type          keys                                                 MAVLink item
============  ===================================================  =============================
takeoff       ``alt_m`` (0.5-500): climb over the current point    NAV_TAKEOFF
waypoint      position, ``alt_m`` (0-500); optional ``hold_s``     NAV_WAYPOINT
              (0-3600 s, default 0), ``yaw_deg`` (heading: 0 north,
              90 east; default: keep), ``radius_m`` (acceptance
              radius, 0-100 m; 0 or absent = the FC's WP_RADIUS_M)
loiter_time   ``hold_s``; optional position (default: here) and     NAV_LOITER_TIME
              ``alt_m`` (default: the current altitude; required
              with a position)
land          optional position (default: here)                    NAV_LAND
rtl           —                                                    NAV_RETURN_TO_LAUNCH
speed         ``speed_mps`` (0 < v <= 50): horizontal speed from    DO_CHANGE_SPEED
              here on
============  ===================================================  =============================

The FC moves on when the vehicle is within the acceptance radius (3-D) of a point, then holds
``hold_s``; a ``land`` without a point lands where the vehicle is when the land item begins.
TOML note: top-level keys (``name``, ``description``) go before the first table; a key written
after ``[[item]]`` belongs to that item.

Expectations (``[[expect]]``, each with ``kind``)
-------------------------------------------------
Times are **mission time**: simulated seconds since the mission started (the FC's ``Mode AUTO``
event after ``MISSION_START``; the vehicle armed on the ground a moment before). Positions are
north/east/altitude-up metres relative to home. Only armed flight counts where it says so.

``reach``: ``item`` (an item number), ``within_m`` (> 0), ``by_s`` (>= 0)
    While flying the item or later, and by ``by_s``, the vehicle came within ``within_m`` of
    the item's target: the window runs from the moment the item became the current one (the
    FC's ``MISSION_ITEM_REACHED`` for the item before it; item 1 at 0) to ``by_s``, so a point
    merely passed earlier (home on the way up) does not count. The target is, for a waypoint
    and for a loiter_time with a position, its 3-D point (3-D distance); for a land with a
    position, its north/east point (horizontal distance); for a takeoff, its altitude
    (vertical distance). Other items have no target to reach: a parse error. Measured: the
    closest approach in the window and when the vehicle first came within the limit.
``max_tilt``: ``max_deg`` (0-90)
    The tilt (angle between the body z axis and the vertical, acos(cos roll · cos pitch)) stays
    at or below ``max_deg`` throughout the armed flight. Measured: the largest tilt and when.
``chi_hat``: ``max``; optional ``min`` (<= ``max``), ``channels`` (subset of
    ``["phi", "theta", "psi", "z"]``, default all)
    Every adaptive gain χ̂ of the chosen channels stays within [``min``, ``max``] throughout the
    armed flight. Fails when the log has no χ̂ (a controller without adaptive gains).
    Measured: each channel's range.
``final_position``: ``north_m``, ``east_m``, ``within_m`` (> 0); optional ``alt_m``
    The last recorded position is within ``within_m`` of (``north_m``, ``east_m``):
    horizontal distance, or 3-D distance when ``alt_m`` is given.
``landed``: optional ``by_s``
    At the end the vehicle is disarmed and on the ground (altitude < 0.3 m); with ``by_s``, it
    also disarmed at mission time <= ``by_s``. Measured: when it disarmed and its altitude.
``max_error_after``: ``t_s`` (>= 0), ``max_m`` (> 0); optional ``until_s`` (> ``t_s``)
    A hold: during armed flight from mission time ``t_s`` (to ``until_s``, default the end),
    the horizontal distance from the vehicle to its current position set-point stays below
    ``max_m``. The set-point is the FC's target (a step to each new item's point, not the
    smoothed reference), so choose a window in which the set-point does not jump. Measured:
    the largest error and when.

The runner
----------
:func:`run_mission` (``smcpilot mission run FILE``): launch lockstep SITL with ``[sitl]`` (or,
with ``--connect URL``, talk to a running vehicle), upload the items through the MAVLink
mission protocol (home inserted as item 0), switch to GUIDED if needed, arm, ``MISSION_START``
from item 1, then wait in simulated time until the vehicle disarms or ``max_duration_s``
(``[sitl]``, honoured with ``--connect`` too) has passed, printing a progress line every 5
simulated seconds; stop SITL, evaluate, print the report (each expectation PASS/FAIL, measured
value vs limit, and how it was measured), write the plots and optionally JSON. Exit codes of the
command: 0 every expectation held, 1 one failed or the mission could not be flown, 2 a broken
file or bad usage.

Where expectations are evaluated
--------------------------------
When the runner launches SITL, from the FC's ``.tlog``: the simulator's state at every control
tick (500 Hz), the actuator armed flag, and the controller's per-tick record (χ̂ and the
position set-point). With ``--connect`` (a vehicle that is already running) there is no FC log:
the runner records the telemetry it receives (10 Hz ``LOCAL_POSITION_NED``, ``ATTITUDE``,
``CHI_*``; armed from the 1 Hz ``HEARTBEAT``), writes it to a ``.tlog`` for the plots, and uses
it instead; ``max_error_after`` then compares with the set-point the FC streams
(``POSITION_TARGET_LOCAL_NED``, 4 Hz), or, from a vehicle that does not stream it, with the
*planned* set-point (the current item's point, taken from ``MISSION_ITEM_REACHED`` /
``MISSION_CURRENT``; for an item without a point, where the vehicle was when the item began;
home during RTL). The report says which source each expectation used.

Errors
------
:class:`MissionFileError` (a :class:`~smcpilot.errors.ConfigError`): the file is unreadable or
invalid; the message names the file, the section (``item N``, ``expect N``, ``[sitl]``) and the
key, e.g. ``box.toml: item 3 (waypoint): unknown key 'nort_m' (did you mean 'north_m'?)``.
:class:`MissionRunError`: the flight could not be flown (a SITL child died, the log is missing).
Vehicle refusals and timeouts are :class:`ground.client.VehicleError`.

API
---
:func:`load_mission` (``path -> Mission``), :func:`parse_mission` (a parsed TOML dict),
:meth:`Mission.to_items` (``home -> list[ground.client.MissionItem]``), :func:`items_to_toml`
(downloaded items back to this format), :func:`run_mission` (fly and evaluate -> a
:class:`MissionReport`), and the CLI pieces :func:`add_arguments` / :func:`main` of
``smcpilot mission``.
"""

from __future__ import annotations

import argparse
import difflib
import json
import math
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TextIO

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.client import HomePosition, MissionItem, Vehicle, VehicleError
from ground.sitl import Sitl, SitlError, SitlOptions
from smcpilot.errors import ConfigError, LinkError, SmcpilotError, TlogError
from smcpilot.geo import Home, global_to_ned, ned_to_global
from smcpilot.protocol import CHI_NAMES, FC_CONTROLLERS
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

__all__ = [
    "CHANNELS",
    "DEFAULT_MAX_DURATION_S",
    "EXPECTATION_KINDS",
    "ITEM_TYPES",
    "ChiHat",
    "Expectation",
    "ExpectationResult",
    "FinalPosition",
    "FlightRecord",
    "ItemSpec",
    "Landed",
    "MaxErrorAfter",
    "MaxTilt",
    "Mission",
    "MissionFileError",
    "MissionReport",
    "MissionRunError",
    "Reach",
    "SitlSettings",
    "TelemetryRecorder",
    "add_arguments",
    "evaluate",
    "items_to_toml",
    "load_mission",
    "main",
    "parse_mission",
    "print_report",
    "record_from_log",
    "run_mission",
]

#: Simulated seconds the runner waits for the mission to end (landed and disarmed) by default.
DEFAULT_MAX_DURATION_S = 600.0
#: A progress line every this many simulated seconds while flying.
PROGRESS_EVERY_SIM_S = 5.0
#: "On the ground" for the ``landed`` expectation: altitude below this, m.
LANDED_MAX_ALT_M = 0.3
#: Channel names of χ̂, in the controller's order.
CHANNELS: tuple[str, ...] = ("phi", "theta", "psi", "z")
ITEM_TYPES: tuple[str, ...] = ("takeoff", "waypoint", "loiter_time", "land", "rtl", "speed")

_LOCAL_KEYS = ("north_m", "east_m")
_GLOBAL_KEYS = ("lat_deg", "lon_deg")
_POSITION_KEYS = frozenset(_LOCAL_KEYS + _GLOBAL_KEYS)
#: type -> (required keys, optional keys), besides "type".
_ITEM_KEYS: dict[str, tuple[frozenset[str], frozenset[str]]] = {
    "takeoff": (frozenset({"alt_m"}), frozenset()),
    "waypoint": (frozenset({"alt_m"}), frozenset({"hold_s", "yaw_deg", "radius_m"}) | _POSITION_KEYS),
    "loiter_time": (frozenset({"hold_s"}), frozenset({"alt_m"}) | _POSITION_KEYS),
    "land": (frozenset(), _POSITION_KEYS),
    "rtl": (frozenset(), frozenset()),
    "speed": (frozenset({"speed_mps"}), frozenset()),
}
#: key -> (low, high) inclusive bounds of item numbers.
_ITEM_RANGES: dict[str, tuple[float, float]] = {
    "alt_m": (0.0, 500.0),
    "hold_s": (0.0, 3600.0),
    "yaw_deg": (-360.0, 360.0),
    "radius_m": (0.0, 100.0),
    "north_m": (-10_000.0, 10_000.0),
    "east_m": (-10_000.0, 10_000.0),
    "lat_deg": (-90.0, 90.0),
    "lon_deg": (-180.0, 180.0),
}
_SITL_KEYS = frozenset(
    {"controller", "vehicle", "seed", "plant", "noise", "noise_scale", "wind_force_ned_n", "gust_std_n", "home", "max_duration_s"}
)
_PLANTS = ("rigid-body", "paper")
_TOP_KEYS = frozenset({"name", "description", "sitl", "item", "expect"})
#: Messages whose time_boot_ms is the vehicle's simulated clock (as in ground.client).
_TIMED_MESSAGES = frozenset(
    {"SYSTEM_TIME", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "NAMED_VALUE_FLOAT", "NAMED_VALUE_INT", "POSITION_TARGET_LOCAL_NED"}
)


# ------------------------------------------------------------------------------------------ errors
class MissionFileError(ConfigError):
    """A mission file is unreadable or invalid.

    The message names the file, the section and the key; the parts are also attributes:
    ``path`` (the file, or the source name), ``section`` (``"item"``, ``"expect"``, ``"sitl"`` or
    None for the top level), ``number`` (1-based item/expectation number, None otherwise) and
    ``key`` (the offending key, None when the problem is not one key's).
    """

    def __init__(self, message: str, *, path: str, section: str | None = None, number: int | None = None, key: str | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.section = section
        self.number = number
        self.key = key


class MissionRunError(SmcpilotError):
    """The mission could not be flown or assessed (SITL died, no log, no home position)."""


class _Where:
    """Builds :class:`MissionFileError` messages for one place in a file."""

    def __init__(self, source: str, section: str | None = None, number: int | None = None, label: str | None = None) -> None:
        self.source = source
        self.section = section
        self.number = number
        if section is None:
            self.text = source
        elif number is None:
            self.text = f"{source}: [{section}]"
        else:
            self.text = f"{source}: {section} {number}" + (f" ({label})" if label else "")

    def error(self, message: str, key: str | None = None) -> MissionFileError:
        prefix = f"key {key!r}: " if key is not None and not message.startswith(("unknown key", "missing key")) else ""
        return MissionFileError(f"{self.text}: {prefix}{message}", path=self.source, section=self.section, number=self.number, key=key)

    def labelled(self, label: str) -> _Where:
        return _Where(self.source, self.section, self.number, label)


def _suggest(key: str, allowed: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, sorted(allowed), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_keys(where: _Where, table: Mapping[str, Any], required: Iterable[str], optional: Iterable[str], what: str) -> None:
    required = set(required)
    allowed = required | set(optional)
    for key in table:
        if key not in allowed:
            listing = ", ".join(sorted(allowed)) or "none"
            raise where.error(f"unknown key {key!r}{_suggest(key, allowed)}; {what} takes: {listing}", key)
    for key in sorted(required):
        if key not in table:
            raise where.error(f"missing key {key!r} ({what} needs: {', '.join(sorted(required))})", key)


def _number(where: _Where, table: Mapping[str, Any], key: str, lo: float | None = None, hi: float | None = None, *,
            lo_open: bool = False) -> float:  # fmt: skip
    """``table[key]`` as a finite float within [lo, hi] (``lo_open``: > lo)."""
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise where.error(f"must be a number, got {v!r} ({type(v).__name__})", key)
    v = float(v)
    if not math.isfinite(v):
        raise where.error(f"must be a finite number, got {v}", key)
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise where.error(f"must be {'>' if lo_open else '>='} {lo:g}" + (f" and <= {hi:g}" if hi is not None else "") + f", got {v:g}", key)
    if hi is not None and v > hi:
        raise where.error(f"must be <= {hi:g}" + (f" and {'>' if lo_open else '>='} {lo:g}" if lo is not None else "") + f", got {v:g}", key)
    return v


def _table(where: _Where, value: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(value, dict):
        raise where.error(f"must be a table ({what}), got {type(value).__name__}")
    return value


# ------------------------------------------------------------------------------------------- items
def _geo_home(home: Home | HomePosition) -> Home:
    if isinstance(home, Home):
        return home
    return Home(home.lat_deg, home.lon_deg, home.alt_amsl_m)


@dataclass(frozen=True)
class ItemSpec:
    """One ``[[item]]`` of a mission file (see the module docstring).

    ``number`` is its 1-based place in the file (= the vehicle's sequence number). Positions:
    ``north_m``/``east_m`` metres from home (local NED) or ``lat_deg``/``lon_deg`` degrees, or
    neither; ``alt_m`` metres above home; ``hold_s`` seconds; ``yaw_deg`` compass heading
    (None = keep); ``radius_m`` acceptance radius (0 = the FC's WP_RADIUS_M); ``speed_mps``
    horizontal speed for ``speed`` items.
    """

    number: int
    type: str
    north_m: float | None = None
    east_m: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    hold_s: float = 0.0
    yaw_deg: float | None = None
    radius_m: float = 0.0
    speed_mps: float | None = None

    @property
    def has_position(self) -> bool:
        """True when the item names a north/east or latitude/longitude point."""
        return self.north_m is not None or self.lat_deg is not None

    def local_ne(self, home: Home | HomePosition | None) -> tuple[float, float] | None:
        """The item's point as (north, east) metres from home; None without a point.
        ``home`` is needed only for latitude/longitude items."""
        if self.north_m is not None and self.east_m is not None:
            return (self.north_m, self.east_m)
        if self.lat_deg is not None and self.lon_deg is not None:
            if home is None:
                raise MissionRunError(f"item {self.number}: lat_deg/lon_deg need the vehicle's home to compare positions")
            g = _geo_home(home)
            n, e, _ = global_to_ned(g, self.lat_deg, self.lon_deg, g.alt_m)
            return (n, e)
        return None

    def latlon(self, home: Home | HomePosition | None) -> tuple[float, float] | None:
        """The item's point as (latitude, longitude) degrees; None without a point.
        North/east items are converted through ``home`` with :func:`smcpilot.geo.ned_to_global`."""
        if self.lat_deg is not None and self.lon_deg is not None:
            return (self.lat_deg, self.lon_deg)
        if self.north_m is not None and self.east_m is not None:
            if home is None:
                raise MissionRunError(f"item {self.number} ({self.type}): north_m/east_m need the vehicle's home (HOME_POSITION)")
            lat, lon, _ = ned_to_global(_geo_home(home), self.north_m, self.east_m, 0.0)
            return (lat, lon)
        return None

    def to_item(self, home: Home | HomePosition | None) -> MissionItem:
        """This item as a :class:`ground.client.MissionItem` (altitudes relative to home).

        Loiter and land items without a point are sent with latitude/longitude 0, 0 ("here", as
        MAVLink has it); a point at exactly 0°, 0° would read the same way."""
        ll = self.latlon(home)
        lat, lon = ll if ll is not None else (0.0, 0.0)
        if self.type == "takeoff":
            assert self.alt_m is not None
            return MissionItem.takeoff(self.alt_m)
        if self.type == "waypoint":
            assert self.alt_m is not None and ll is not None
            return MissionItem.waypoint(lat, lon, self.alt_m, hold_s=self.hold_s, acceptance_radius_m=self.radius_m, yaw_deg=self.yaw_deg)
        if self.type == "loiter_time":
            return MissionItem.loiter_time(self.hold_s, lat, lon, self.alt_m if self.alt_m is not None else 0.0)
        if self.type == "land":
            return MissionItem.land(lat, lon)
        if self.type == "rtl":
            return MissionItem.rtl()
        if self.type == "speed":
            assert self.speed_mps is not None
            return MissionItem.change_speed(self.speed_mps)
        raise AssertionError(self.type)  # pragma: no cover - parse_mission checked the type

    def describe(self) -> str:
        """A short human description, e.g. ``waypoint N 8 E 0 alt 3 m, yaw 90°``."""
        parts = [self.type]
        if self.north_m is not None:
            parts.append(f"N {self.north_m:g} E {self.east_m:g}")
        elif self.lat_deg is not None:
            parts.append(f"lat {self.lat_deg:.7f} lon {self.lon_deg:.7f}")
        if self.alt_m is not None:
            parts.append(f"alt {self.alt_m:g} m")
        if self.type in ("waypoint", "loiter_time") and self.hold_s:
            parts.append(f"hold {self.hold_s:g} s")
        if self.yaw_deg is not None:
            parts.append(f"yaw {self.yaw_deg:g}°")
        if self.speed_mps is not None:
            parts.append(f"{self.speed_mps:g} m/s")
        return " ".join(parts)

    def to_toml_entry(self) -> dict[str, Any]:
        """The keys of this item as they appear in a mission file (absent values left out)."""
        e: dict[str, Any] = {"type": self.type}
        for key in ("north_m", "east_m", "lat_deg", "lon_deg", "alt_m"):
            v = getattr(self, key)
            if v is not None:
                e[key] = v
        if self.type == "loiter_time" or (self.type == "waypoint" and self.hold_s):
            e["hold_s"] = self.hold_s
        if self.yaw_deg is not None:
            e["yaw_deg"] = self.yaw_deg
        if self.radius_m:
            e["radius_m"] = self.radius_m
        if self.speed_mps is not None:
            e["speed_mps"] = self.speed_mps
        return e

    @classmethod
    def from_mission_item(cls, item: MissionItem, number: int, home: Home | HomePosition | None = None) -> ItemSpec:
        """A downloaded :class:`ground.client.MissionItem` in this format: north/east metres when
        ``home`` is given, else latitude/longitude. Raises :class:`MissionFileError` for a
        command this format has no type for."""
        cmd = item.command
        kind = {
            mavlink.MAV_CMD_NAV_TAKEOFF: "takeoff",
            mavlink.MAV_CMD_NAV_WAYPOINT: "waypoint",
            mavlink.MAV_CMD_NAV_LOITER_TIME: "loiter_time",
            mavlink.MAV_CMD_NAV_LAND: "land",
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "rtl",
            mavlink.MAV_CMD_DO_CHANGE_SPEED: "speed",
        }.get(cmd)
        if kind is None:
            raise MissionFileError(f"item {number}: {item.command_name} has no mission-file type", path="<vehicle>", section="item", number=number)
        pos: dict[str, float] = {}
        # lat/lon 0, 0 means "here" for loiter and land (MAVLink's convention); a waypoint always has a point.
        if kind == "waypoint" or (kind in ("loiter_time", "land") and (item.lat_deg != 0.0 or item.lon_deg != 0.0)):
            if home is not None:
                g = _geo_home(home)
                n, e, _ = global_to_ned(g, item.lat_deg, item.lon_deg, g.alt_m)
                pos = {"north_m": round(n, 3), "east_m": round(e, 3)}
            else:
                pos = {"lat_deg": round(item.lat_deg, 7), "lon_deg": round(item.lon_deg, 7)}
        if kind == "takeoff":
            return cls(number, kind, alt_m=item.alt_m)
        if kind == "waypoint":
            yaw = item.param4 if math.isfinite(item.param4) else None
            return cls(number, kind, alt_m=item.alt_m, hold_s=item.param1, yaw_deg=yaw, radius_m=item.param2, **pos)
        if kind == "loiter_time":
            return cls(number, kind, alt_m=item.alt_m if (pos or item.alt_m > 0) else None, hold_s=item.param1, **pos)
        if kind == "land":
            return cls(number, kind, **pos)
        if kind == "speed":
            return cls(number, kind, speed_mps=item.param2)
        return cls(number, kind)


def _parse_item(where: _Where, raw: Any) -> ItemSpec:
    table = _table(where, raw, "[[item]] with a type")
    kind = table.get("type")
    if "type" not in table:
        raise where.error(f"missing key 'type' (one of {', '.join(ITEM_TYPES)})", "type")
    if kind not in ITEM_TYPES:
        hint = _suggest(kind, ITEM_TYPES) if isinstance(kind, str) else ""
        raise where.error(f"unknown item type {kind!r}{hint}; types: {', '.join(ITEM_TYPES)}", "type")
    w = where.labelled(kind)
    required, optional = _ITEM_KEYS[kind]
    _check_keys(w, {k: v for k, v in table.items() if k != "type"}, required, optional, f"a {kind} item")
    vals: dict[str, float] = {}
    for key in table:
        if key == "type":
            continue
        lo, hi = _ITEM_RANGES.get(key, (None, None))
        if key == "alt_m" and kind == "takeoff":
            lo, hi = 0.5, 500.0
        if key == "speed_mps":
            vals[key] = _number(w, table, key, 0.0, 50.0, lo_open=True)
        else:
            vals[key] = _number(w, table, key, lo, hi)
    has_local = [k for k in _LOCAL_KEYS if k in vals]
    has_global = [k for k in _GLOBAL_KEYS if k in vals]
    if has_local and has_global:
        raise w.error(f"give north_m/east_m or lat_deg/lon_deg, not both ({has_local[0]} and {has_global[0]})", has_global[0])
    for pair in (_LOCAL_KEYS, _GLOBAL_KEYS):
        present = [k for k in pair if k in vals]
        if len(present) == 1:
            other = pair[1] if present[0] == pair[0] else pair[0]
            raise w.error(f"missing key {other!r} ({present[0]} and {other} go together)", other)
    positioned = bool(has_local or has_global)
    if kind == "waypoint" and not positioned:
        raise w.error("missing key 'north_m' (a waypoint needs north_m/east_m or lat_deg/lon_deg)", "north_m")
    if kind == "loiter_time" and positioned and "alt_m" not in vals:
        raise w.error("missing key 'alt_m' (a loiter_time with a position needs its altitude)", "alt_m")
    return ItemSpec(number=where.number or 0, type=kind, **vals)


# ------------------------------------------------------------------------------------ expectations
@dataclass(frozen=True)
class ExpectationResult:
    """The verdict on one expectation.

    ``measured`` / ``limit`` are the headline numbers in ``unit`` (None when there is nothing to
    measure), ``detail`` says what was measured and when, ``source`` where the data came from
    (``"log"``: the FC's .tlog; ``"telemetry"``: what the ground link received).
    """

    number: int
    kind: str
    description: str
    passed: bool
    measured: float | None
    limit: float | None
    unit: str
    detail: str
    source: str
    extra: dict[str, Any] = field(default_factory=dict)
    #: the measured value as printed, e.g. ``"23.27°"``, ``"range [0.500, 0.566]"``.
    measured_text: str = "n/a"
    #: the limit as printed, e.g. ``"<= 30°"``, ``"within 0.3 m by 15 s"``.
    limit_text: str = ""
    #: what was measured, e.g. ``"item 3"`` (may be empty).
    subject: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "number": self.number,
            "kind": self.kind,
            "description": self.description,
            "passed": self.passed,
            "measured": _json_num(self.measured),
            "limit": _json_num(self.limit),
            "unit": self.unit,
            "measured_text": self.measured_text,
            "limit_text": self.limit_text,
            "detail": self.detail,
            "source": self.source,
            **{k: _json_value(v) for k, v in self.extra.items()},
        }


@dataclass(frozen=True)
class Expectation:
    """Base of the ``[[expect]]`` kinds; ``number`` is the 1-based place in the file."""

    number: int
    kind: ClassVar[str] = ""
    #: (required keys, optional keys) besides "kind".
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset(), frozenset())

    def describe(self) -> str:  # pragma: no cover - every kind overrides it
        return self.kind

    def limit_text(self) -> str:  # pragma: no cover - every kind overrides it
        return ""

    def subject(self) -> str:
        """What is measured, for the report line (empty when the kind says it all)."""
        return ""

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:  # pragma: no cover
        raise NotImplementedError

    def _result(self, rec: FlightRecord, passed: bool, measured: float | None, limit: float | None, unit: str, detail: str,
                *, measured_text: str | None = None, **extra: Any) -> ExpectationResult:  # fmt: skip
        if measured_text is None:
            measured_text = "n/a" if measured is None else _with_unit(measured, unit)
        return ExpectationResult(self.number, self.kind, self.describe(), passed, measured, limit, unit, detail, rec.source, extra,
                                 measured_text, self.limit_text(), self.subject())  # fmt: skip


def _with_unit(v: float, unit: str) -> str:
    if unit == "deg":
        return f"{v:.2f}°"
    if unit == "s":
        return f"{v:.2f} s"
    return f"{v:.3f}" + (f" {unit}" if unit else "")


@dataclass(frozen=True)
class Reach(Expectation):
    """Came within ``within_m`` of item ``item``'s target by mission time ``by_s``."""

    item: int = 0
    within_m: float = 0.0
    by_s: float = 0.0
    kind: ClassVar[str] = "reach"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"item", "within_m", "by_s"}), frozenset())

    def describe(self) -> str:
        return f"reach item {self.item} within {self.within_m:g} m by {self.by_s:g} s"

    def limit_text(self) -> str:
        return f"within {self.within_m:g} m by {self.by_s:g} s"

    def subject(self) -> str:
        return f"item {self.item}"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        it = mission.items[self.item - 1]
        t, n, e, alt = rec.pos_t, rec.north, rec.east, rec.alt
        ne = it.local_ne(home)
        if it.type == "takeoff":
            assert it.alt_m is not None
            dist, what = np.abs(alt - it.alt_m), f"altitude {it.alt_m:g} m (vertical distance)"
        elif it.type == "land":
            assert ne is not None
            dist, what = np.hypot(n - ne[0], e - ne[1]), f"N {ne[0]:.2f} E {ne[1]:.2f} (horizontal distance)"
        else:
            assert ne is not None and it.alt_m is not None
            dist = np.sqrt((n - ne[0]) ** 2 + (e - ne[1]) ** 2 + (alt - it.alt_m) ** 2)
            what = f"N {ne[0]:.2f} E {ne[1]:.2f} alt {it.alt_m:g} m (3-D distance)"
        start = rec.item_start_s.get(self.item)
        since = f"item current from {start:.2f} s" if start is not None else "item never became current: from mission start"
        t_from = start if start is not None else 0.0
        window = (t >= t_from) & (t <= self.by_s)
        if not window.any():
            return self._result(rec, False, None, self.within_m, "m", f"no position samples in [{t_from:.2f}, {self.by_s:g}] s ({since})",
                                item_start_s=start)  # fmt: skip
        k = int(np.argmin(np.where(window, dist, np.inf)))
        closest = float(dist[k])
        inside = np.flatnonzero(window & (dist <= self.within_m))
        after = np.flatnonzero((t >= t_from) & (dist <= self.within_m))
        if inside.size:
            first = float(t[inside[0]])
            detail = f"first within {self.within_m:g} m of {what} at {first:.2f} s ({since}); closest {closest:.3f} m at {t[k]:.2f} s"
        elif after.size:
            first = float(t[after[0]])
            detail = f"closest by {self.by_s:g} s was {closest:.3f} m at {t[k]:.2f} s; within {self.within_m:g} m only at {first:.2f} s ({since})"
        else:
            first = None
            detail = f"closest by {self.by_s:g} s was {closest:.3f} m at {t[k]:.2f} s (target {what}; {since}); never within {self.within_m:g} m"
        if inside.size:
            when = f", within at {first:.2f} s"
        elif first is not None:
            when = f" by {self.by_s:g} s (within only at {first:.2f} s)"
        else:
            when = ""
        return self._result(rec, bool(inside.size), closest, self.within_m, "m", detail, first_within_s=first, closest_at_s=float(t[k]),
                            item_start_s=start, measured_text=f"closest {closest:.3f} m{when}")  # fmt: skip


@dataclass(frozen=True)
class MaxTilt(Expectation):
    """The tilt stays at or below ``max_deg`` during armed flight."""

    max_deg: float = 0.0
    kind: ClassVar[str] = "max_tilt"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"max_deg"}), frozenset())

    def describe(self) -> str:
        return f"tilt <= {self.max_deg:g}°"

    def limit_text(self) -> str:
        return f"<= {self.max_deg:g}°"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        armed = rec.armed_at(rec.tilt_t)
        tilt = np.where(armed & np.isfinite(rec.tilt_deg), rec.tilt_deg, -np.inf)
        if not np.isfinite(tilt).any():
            return self._result(rec, False, None, self.max_deg, "deg", "no attitude samples during armed flight")
        k = int(np.argmax(tilt))
        worst = float(tilt[k])
        return self._result(rec, worst <= self.max_deg, worst, self.max_deg, "deg", f"largest tilt {worst:.2f}° at {rec.tilt_t[k]:.2f} s",
                            at_s=float(rec.tilt_t[k]))  # fmt: skip


@dataclass(frozen=True)
class ChiHat(Expectation):
    """Every χ̂ of ``channels`` stays within [``min``, ``max``] during armed flight."""

    max: float = 0.0
    min: float | None = None
    channels: tuple[str, ...] = CHANNELS
    kind: ClassVar[str] = "chi_hat"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"max"}), frozenset({"min", "channels"}))

    def describe(self) -> str:
        lo = f"{self.min:g} <= " if self.min is not None else ""
        which = "" if self.channels == CHANNELS else f" ({', '.join(self.channels)})"
        return f"{lo}χ̂ <= {self.max:g}{which}"

    def limit_text(self) -> str:
        return f"within [{self.min:g}, {self.max:g}]" if self.min is not None else f"<= {self.max:g}"

    def subject(self) -> str:
        return "" if self.channels == CHANNELS else ", ".join(self.channels)

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        armed = rec.armed_at(rec.chi_t)
        ranges: dict[str, list[float]] = {}
        for c in self.channels:
            col = rec.chi[:, CHANNELS.index(c)] if rec.chi.size else np.zeros(0)
            v = col[armed & np.isfinite(col)] if col.size else col
            if v.size:
                ranges[c] = [float(v.min()), float(v.max())]
        if not ranges:
            return self._result(rec, False, None, self.max, "", "no χ̂ in the record (a controller without adaptive gains?)")
        hi = max(r[1] for r in ranges.values())
        lo = min(r[0] for r in ranges.values())
        ok = hi <= self.max and (self.min is None or lo >= self.min)
        missing = [c for c in self.channels if c not in ranges]
        detail = ", ".join(f"{c} [{r[0]:.3f}, {r[1]:.3f}]" for c, r in ranges.items())
        if missing:
            ok = False
            detail += f"; no χ̂ for {', '.join(missing)}"
        return self._result(rec, ok, hi, self.max, "", f"range per channel: {detail}", min_measured=lo, ranges=ranges,
                            measured_text=f"range [{lo:.3f}, {hi:.3f}]")  # fmt: skip


@dataclass(frozen=True)
class FinalPosition(Expectation):
    """The last position is within ``within_m`` of (north, east[, alt])."""

    north_m: float = 0.0
    east_m: float = 0.0
    within_m: float = 0.0
    alt_m: float | None = None
    kind: ClassVar[str] = "final_position"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"north_m", "east_m", "within_m"}), frozenset({"alt_m"}))

    def describe(self) -> str:
        alt = f" alt {self.alt_m:g}" if self.alt_m is not None else ""
        return f"end within {self.within_m:g} m of N {self.north_m:g} E {self.east_m:g}{alt}"

    def limit_text(self) -> str:
        return f"<= {self.within_m:g} m"

    def subject(self) -> str:
        return f"from N {self.north_m:g} E {self.east_m:g}" + (f" alt {self.alt_m:g}" if self.alt_m is not None else "")

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        if not rec.pos_t.size:
            return self._result(rec, False, None, self.within_m, "m", "no position samples")
        n, e, a = float(rec.north[-1]), float(rec.east[-1]), float(rec.alt[-1])
        d = math.hypot(n - self.north_m, e - self.east_m)
        if self.alt_m is not None:
            d = math.hypot(d, a - self.alt_m)
        kind = "3-D" if self.alt_m is not None else "horizontal"
        return self._result(rec, d <= self.within_m, d, self.within_m, "m",
                            f"ended at N {n:.3f} E {e:.3f} alt {a:.3f} m ({rec.pos_t[-1]:.2f} s): {kind} distance {d:.3f} m",
                            final_ned_alt=[n, e, a])  # fmt: skip


@dataclass(frozen=True)
class Landed(Expectation):
    """Disarmed on the ground at the end (by mission time ``by_s`` if given)."""

    by_s: float | None = None
    kind: ClassVar[str] = "landed"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset(), frozenset({"by_s"}))

    def describe(self) -> str:
        return "landed and disarmed" + (f" by {self.by_s:g} s" if self.by_s is not None else "")

    def limit_text(self) -> str:
        return f"disarmed on the ground by {self.by_s:g} s" if self.by_s is not None else "disarmed on the ground at the end"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        if not rec.armed_t.size or not rec.pos_t.size:
            return self._result(rec, False, None, self.by_s, "s", "no armed/position record")
        alt = float(rec.alt[-1])
        disarmed = not bool(rec.armed[-1])
        armed_idx = np.flatnonzero(rec.armed)
        t_disarm = None
        if disarmed and armed_idx.size and armed_idx[-1] + 1 < rec.armed_t.size:
            t_disarm = float(rec.armed_t[armed_idx[-1] + 1])
        ok = disarmed and alt < LANDED_MAX_ALT_M
        if not disarmed:
            detail = f"still armed at the end ({rec.armed_t[-1]:.2f} s), altitude {alt:.2f} m"
        else:
            when = f"disarmed at {t_disarm:.2f} s" if t_disarm is not None else "never armed"
            detail = f"{when}, final altitude {alt:.3f} m" + ("" if alt < LANDED_MAX_ALT_M else f" (not < {LANDED_MAX_ALT_M:g} m)")
            if t_disarm is None:
                ok = False
        if ok and self.by_s is not None and (t_disarm is None or t_disarm > self.by_s):
            ok = False
            detail += f"; later than {self.by_s:g} s"
        measured = ("still armed" if not disarmed else f"disarmed at {t_disarm:.2f} s" if t_disarm is not None else "never armed")
        return self._result(rec, ok, t_disarm, self.by_s, "s", detail, final_alt_m=alt, measured_text=f"{measured}, altitude {alt:.2f} m")


@dataclass(frozen=True)
class MaxErrorAfter(Expectation):
    """Horizontal error to the set-point stays below ``max_m`` from ``t_s`` (to ``until_s``)."""

    t_s: float = 0.0
    max_m: float = 0.0
    until_s: float | None = None
    kind: ClassVar[str] = "max_error_after"
    keys: ClassVar[tuple[frozenset[str], frozenset[str]]] = (frozenset({"t_s", "max_m"}), frozenset({"until_s"}))

    def describe(self) -> str:
        until = f" to {self.until_s:g} s" if self.until_s is not None else ""
        return f"horizontal error < {self.max_m:g} m from {self.t_s:g} s{until}"

    def limit_text(self) -> str:
        return f"< {self.max_m:g} m"

    def subject(self) -> str:
        return f"{self.t_s:g}-{self.until_s:g} s" if self.until_s is not None else f"from {self.t_s:g} s"

    def evaluate(self, rec: FlightRecord, mission: Mission, home: Home | None) -> ExpectationResult:
        t = rec.sp_t
        end = self.until_s if self.until_s is not None else math.inf
        if not t.size:
            return self._result(rec, False, None, self.max_m, "m", "no position set-point in the record")
        n = _hold(rec.pos_t, rec.north, t)
        e = _hold(rec.pos_t, rec.east, t)
        err = np.hypot(n - rec.sp_north, e - rec.sp_east)
        mask = (t >= self.t_s) & (t <= end) & rec.armed_at(t) & np.isfinite(err)
        if not mask.any():
            return self._result(rec, False, None, self.max_m, "m", f"no armed flight with a set-point in [{self.t_s:g}, {end:g}] s")
        k = int(np.argmax(np.where(mask, err, -np.inf)))
        worst = float(err[k])
        rms = float(np.sqrt(np.mean(err[mask] ** 2)))
        span = f"{t[mask][0]:.2f}-{t[mask][-1]:.2f} s"
        return self._result(rec, worst < self.max_m, worst, self.max_m, "m",
                            f"largest {worst:.3f} m at {t[k]:.2f} s, RMS {rms:.3f} m over {span} (set-point: {rec.sp_source})",
                            rms_m=rms, at_s=float(t[k]))  # fmt: skip


_EXPECTATIONS: dict[str, type[Expectation]] = {
    cls.kind: cls for cls in (Reach, MaxTilt, ChiHat, FinalPosition, Landed, MaxErrorAfter)
}
EXPECTATION_KINDS: tuple[str, ...] = tuple(_EXPECTATIONS)
#: key -> (low, high, lo_open) of expectation numbers.
_EXPECT_RANGES: dict[str, tuple[float | None, float | None, bool]] = {
    "within_m": (0.0, None, True),
    "by_s": (0.0, None, False),
    "max_deg": (0.0, 90.0, True),
    "max": (None, None, False),
    "min": (None, None, False),
    "north_m": (-10_000.0, 10_000.0, False),
    "east_m": (-10_000.0, 10_000.0, False),
    "alt_m": (0.0, 500.0, False),
    "t_s": (0.0, None, False),
    "until_s": (0.0, None, True),
    "max_m": (0.0, None, True),
}


def _parse_expectation(where: _Where, raw: Any, items: Sequence[ItemSpec]) -> Expectation:
    table = _table(where, raw, "[[expect]] with a kind")
    if "kind" not in table:
        raise where.error(f"missing key 'kind' (one of {', '.join(EXPECTATION_KINDS)})", "kind")
    kind = table["kind"]
    if kind not in _EXPECTATIONS:
        hint = _suggest(kind, EXPECTATION_KINDS) if isinstance(kind, str) else ""
        raise where.error(f"unknown expectation kind {kind!r}{hint}; kinds: {', '.join(EXPECTATION_KINDS)}", "kind")
    cls = _EXPECTATIONS[kind]
    w = where.labelled(kind)
    required, optional = cls.keys
    body = {k: v for k, v in table.items() if k != "kind"}
    _check_keys(w, body, required, optional, f"a {kind} expectation")
    vals: dict[str, Any] = {}
    for key, value in body.items():
        if key == "item":
            if isinstance(value, bool) or not isinstance(value, int):
                raise w.error(f"must be an item number (integer), got {value!r}", key)
            if not 1 <= value <= len(items):
                raise w.error(f"item {value} does not exist (the mission has items 1..{len(items)})", key)
            it = items[value - 1]
            if it.type in ("rtl", "speed") or (it.type in ("loiter_time", "land") and not it.has_position):
                raise w.error(f"item {value} ({it.type}) has no position to reach (use a waypoint, a takeoff, or a loiter_time/land with a position)", key)
            vals[key] = value
        elif key == "channels":
            if not isinstance(value, list) or not value or not all(isinstance(c, str) for c in value):
                raise w.error(f"must be a non-empty list of channel names ({', '.join(CHANNELS)}), got {value!r}", key)
            bad = [c for c in value if c not in CHANNELS]
            if bad:
                raise w.error(f"unknown channel {bad[0]!r}{_suggest(bad[0], CHANNELS)}; channels: {', '.join(CHANNELS)}", key)
            vals[key] = tuple(c for c in CHANNELS if c in value)
        else:
            lo, hi, lo_open = _EXPECT_RANGES[key]
            vals[key] = _number(w, body, key, lo, hi, lo_open=lo_open)
    if kind == "chi_hat" and "min" in vals and vals["min"] > vals["max"]:
        raise w.error(f"must be <= max ({vals['max']:g}), got {vals['min']:g}", "min")
    if kind == "max_error_after" and "until_s" in vals and vals["until_s"] <= vals["t_s"]:
        raise w.error(f"must be > t_s ({vals['t_s']:g}), got {vals['until_s']:g}", "until_s")
    return cls(number=where.number or 0, **vals)


# ------------------------------------------------------------------------------------------ sitl
@dataclass(frozen=True)
class SitlSettings:
    """The ``[sitl]`` table: how the runner launches SITL (ignored with ``--connect``, except
    ``max_duration_s``). Units: newtons (wind, gusts, NED), simulated seconds."""

    controller: str = "adaptive_pid_smc"
    #: vehicle TOML, resolved against the mission file's directory.
    vehicle: Path | None = None
    seed: int = 0
    plant: str = "rigid-body"
    noise: bool = False
    noise_scale: float = 1.0
    wind_force_ned_n: tuple[float, float, float] | None = None
    gust_std_n: float = 0.0
    #: home of the local frame (default: the FC's).
    home: Home | None = None
    #: simulated seconds of flight after the mission start before the runner stops waiting.
    max_duration_s: float = DEFAULT_MAX_DURATION_S

    def scenario(self, name: str = "mission") -> Scenario:
        """The flight these settings describe (no plan: the mission is uploaded and started)."""
        return Scenario(
            name=name,
            vehicle=VehicleParams.from_toml(self.vehicle) if self.vehicle is not None else DEFAULT_VEHICLE,
            vehicle_file=self.vehicle,
            controller=self.controller,
            seed=self.seed,
            plant=self.plant,
            home=None if self.home is None else (self.home.lat_deg, self.home.lon_deg, self.home.alt_m),
            environment=EnvironmentSpec(
                noise=self.noise, noise_scale=self.noise_scale,
                wind_force_ned_n=self.wind_force_ned_n if self.wind_force_ned_n is not None else (0.0, 0.0, 0.0),
                gust_std_n=self.gust_std_n,
            ),  # fmt: skip
        )

    def options(self, *, gcs: str, log_dir: Path, tlog: Path, param_file: Path, name: str = "mission") -> SitlOptions:
        """Lockstep :class:`ground.sitl.SitlOptions` for these settings."""
        return SitlOptions(scenario=self.scenario(name), lockstep=True, gcs=gcs, log_dir=log_dir, tlog=tlog, param_file=param_file)

    def describe(self) -> str:
        parts = [f"controller {self.controller}", f"plant {self.plant}", f"seed {self.seed}"]
        if self.vehicle is not None:
            parts.append(f"vehicle {self.vehicle.name}")
        if self.noise:
            parts.append(f"noise ×{self.noise_scale:g}")
        if self.wind_force_ned_n is not None:
            parts.append("wind NED [" + ", ".join(f"{v:g}" for v in self.wind_force_ned_n) + "] N")
        if self.gust_std_n:
            parts.append(f"gusts σ {self.gust_std_n:g} N")
        return ", ".join(parts)


def _parse_sitl(where: _Where, raw: Any, base_dir: Path | None) -> SitlSettings:
    table = _table(where, raw, "[sitl]")
    _check_keys(where, table, (), _SITL_KEYS, "[sitl]")
    kw: dict[str, Any] = {}
    for key, v in table.items():
        if key == "controller":
            if v not in FC_CONTROLLERS:
                raise where.error(f"must be one of {', '.join(FC_CONTROLLERS)}, got {v!r}", key)
            kw[key] = v
        elif key == "plant":
            if v not in _PLANTS:
                raise where.error(f"must be one of {', '.join(_PLANTS)}, got {v!r}", key)
            kw[key] = v
        elif key == "vehicle":
            if not isinstance(v, str) or not v.strip():
                raise where.error(f"must be a path (string), got {v!r}", key)
            p = Path(v).expanduser()
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if not p.is_file():
                raise where.error(f"vehicle file not found: {p}", key)
            kw[key] = p
        elif key == "seed":
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 2**32:
                raise where.error(f"must be an integer in [0, 2^32), got {v!r}", key)
            kw[key] = v
        elif key == "noise":
            if not isinstance(v, bool):
                raise where.error(f"must be true or false, got {v!r}", key)
            kw[key] = v
        elif key in ("noise_scale", "gust_std_n"):
            kw[key] = _number(where, table, key, 0.0, 1000.0)
        elif key == "max_duration_s":
            kw[key] = _number(where, table, key, 0.0, 86_400.0, lo_open=True)
        elif key in ("wind_force_ned_n", "home"):
            if not isinstance(v, list) or len(v) != 3:
                what = "[north, east, down] newtons" if key == "wind_force_ned_n" else "[lat_deg, lon_deg, alt_m_amsl]"
                raise where.error(f"must be a list of three numbers {what}, got {v!r}", key)
            nums = []
            for k, x in enumerate(v):
                if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                    raise where.error(f"element {k + 1} must be a finite number, got {x!r}", key)
                nums.append(float(x))
            if key == "home":
                try:
                    kw[key] = Home(*nums)
                except ConfigError as exc:
                    raise where.error(str(exc), key) from None
            else:
                kw[key] = tuple(nums)
    return SitlSettings(**kw)


# ----------------------------------------------------------------------------------------- mission
@dataclass(frozen=True)
class Mission:
    """A parsed mission file: the items to fly, the SITL settings and the expectations."""

    items: tuple[ItemSpec, ...]
    expectations: tuple[Expectation, ...] = ()
    sitl: SitlSettings = field(default_factory=SitlSettings)
    name: str = "mission"
    description: str = ""
    #: the file it came from (None when parsed from a dict).
    path: Path | None = None

    def to_items(self, home: Home | HomePosition | None) -> list[MissionItem]:
        """The items to upload, as :class:`ground.client.MissionItem` (home, item 0, not
        included: :meth:`ground.client.Vehicle.upload_mission` adds it). ``home`` — the vehicle's
        ``HOME_POSITION`` (:class:`ground.client.HomePosition`) or a :class:`smcpilot.geo.Home` —
        converts north/east items to latitude/longitude; it may be None when no item uses
        north/east (else :class:`MissionRunError`)."""
        return [it.to_item(home) for it in self.items]

    @property
    def uses_local_positions(self) -> bool:
        """True when some item gives north_m/east_m (the vehicle's home is needed)."""
        return any(it.north_m is not None for it in self.items)

    @property
    def ends_on_ground(self) -> bool:
        """True when the last navigation item lands (land or rtl)."""
        nav = [it for it in self.items if it.type != "speed"]
        return bool(nav) and nav[-1].type in ("land", "rtl")


def parse_mission(doc: Mapping[str, Any], *, source: str = "<mission>", base_dir: Path | None = None, path: Path | None = None) -> Mission:
    """A :class:`Mission` from a parsed TOML document. ``source`` names it in errors;
    ``base_dir`` resolves a relative ``[sitl]`` vehicle path. Raises :class:`MissionFileError`."""
    top = _Where(source)
    for key in doc:
        if key not in _TOP_KEYS:
            raise top.error(f"unknown key {key!r} at the top level{_suggest(key, _TOP_KEYS)}; a mission has: name,"
                            " description, [sitl], [[item]], [[expect]]", key)  # fmt: skip
    for key in ("name", "description"):
        if key in doc and not isinstance(doc[key], str):
            raise top.error(f"must be a string, got {doc[key]!r}", key)
    raw_items = doc.get("item")
    if raw_items is None:
        raise top.error("no [[item]] tables: a mission needs at least one item", "item")
    if not isinstance(raw_items, list):
        raise top.error("must be an array of tables: write [[item]], not [item]", "item")
    if not raw_items:
        raise top.error("no [[item]] tables: a mission needs at least one item", "item")
    items = tuple(_parse_item(_Where(source, "item", i), raw) for i, raw in enumerate(raw_items, start=1))
    raw_expect = doc.get("expect", [])
    if not isinstance(raw_expect, list):
        raise top.error("must be an array of tables: write [[expect]], not [expect]", "expect")
    expectations = tuple(_parse_expectation(_Where(source, "expect", i), raw, items) for i, raw in enumerate(raw_expect, start=1))
    sitl = _parse_sitl(_Where(source, "sitl"), doc["sitl"], base_dir) if "sitl" in doc else SitlSettings()
    name = doc.get("name") or (path.stem if path is not None else "mission")
    return Mission(items, expectations, sitl, name, doc.get("description", ""), path)


def load_mission(path: str | Path) -> Mission:
    """Read and check a mission file (see the module docstring). Raises
    :class:`MissionFileError` naming the file, the item/expectation number and the key."""
    p = Path(path)
    src = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MissionFileError(f"{src}: mission file not found", path=src) from None
    except IsADirectoryError:
        raise MissionFileError(f"{src}: is a directory, not a mission file", path=src) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionFileError(f"{src}: cannot read: {getattr(exc, 'strerror', None) or exc}", path=src) from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionFileError(f"{src}: not valid TOML: {exc}", path=src) from None
    return parse_mission(doc, source=src, base_dir=p.parent, path=p)


def items_to_toml(items: Sequence[MissionItem], home: Home | HomePosition | None = None, *, header: str | None = None) -> str:
    """Mission-file TOML (``[[item]]`` tables) of items downloaded from a vehicle (home, item 0,
    excluded). With ``home``, points are written as north_m/east_m from it, else as
    lat_deg/lon_deg. Items this format has no type for become comments."""
    lines = [f"# {header}", ""] if header else []
    for k, item in enumerate(items, start=1):
        try:
            entry = ItemSpec.from_mission_item(item, k, home).to_toml_entry()
        except MissionFileError:
            comment = (
                f"# item {k}: {item.command_name} (frame {item.frame}) has no mission-file type: "
                f"params {item.param1:g} {item.param2:g} {item.param3:g} {item.param4:g}, "
                f"lat {item.lat_deg:.7f} lon {item.lon_deg:.7f} alt {item.alt_m:g}"
            )
            lines += [comment, ""]
            continue
        lines.append("[[item]]")
        for key, value in entry.items():
            lines.append(f"{key} = {json.dumps(value) if isinstance(value, str) else repr(float(value))}")
        lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- flight record
def _hold(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Zero-order hold: the latest sample at or before each query time (NaN before the first)."""
    idx = np.searchsorted(t_src, t_query, side="right") - 1
    out = np.full(t_query.shape, np.nan)
    ok = idx >= 0
    if t_src.size:
        out[ok] = values[idx[ok]]
    return out


@dataclass
class FlightRecord:
    """What the expectations are evaluated on. Times are mission time (s since the mission
    started, see the module docstring); positions north/east/altitude-up metres from home."""

    #: "log" (the FC's .tlog) or "telemetry" (what the ground link received).
    source: str
    #: a sentence for the report.
    description: str
    #: mission start in the source's own time base (sim seconds since the log's first record).
    t0_s: float
    pos_t: np.ndarray
    north: np.ndarray
    east: np.ndarray
    alt: np.ndarray
    tilt_t: np.ndarray
    tilt_deg: np.ndarray
    #: χ̂ per channel (phi, theta, psi, z), shape (n, 4).
    chi_t: np.ndarray
    chi: np.ndarray
    armed_t: np.ndarray
    armed: np.ndarray
    #: horizontal position set-point.
    sp_t: np.ndarray
    sp_north: np.ndarray
    sp_east: np.ndarray
    sp_source: str
    events: list[tuple[float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: item number -> mission time at which it became the current item (the previous item's
    #: MISSION_ITEM_REACHED, else the first MISSION_CURRENT naming it; item 1 at 0).
    item_start_s: dict[int, float] = field(default_factory=dict)

    def armed_at(self, t: np.ndarray) -> np.ndarray:
        """Armed flag held onto times ``t`` (False before the first armed sample)."""
        if not self.armed_t.size:
            return np.zeros(t.shape, dtype=bool)
        v = _hold(self.armed_t, self.armed.astype(float), t)
        return np.nan_to_num(v, nan=0.0) > 0.5

    @property
    def end_s(self) -> float:
        """Mission time of the last position sample."""
        return float(self.pos_t[-1]) if self.pos_t.size else 0.0


def _mission_start_in_log(log: Any) -> tuple[float, str]:
    """(log time of the mission start, how it was found)."""
    armed_t = log.act_t_s[log.armed] if log.act_t_s.size else np.zeros(0)
    first_armed = float(armed_t[0]) if armed_t.size else None
    for ev in log.events:
        if ev.text.strip() == "Mode AUTO" and (first_armed is None or ev.t_s >= first_armed - 1.0):
            return ev.t_s, "the FC's 'Mode AUTO' event"
    if first_armed is not None:
        return first_armed, "arming (no 'Mode AUTO' event in the log)"
    return 0.0, "the start of the log (never armed, no 'Mode AUTO' event)"


def _item_starts(changes: Iterable[tuple[float, str, int]], t0_s: float) -> dict[int, float]:
    """Item number -> mission time it became current, from ``(time, message type, seq)`` of
    MISSION_ITEM_REACHED (item seq done: seq + 1 starts) and MISSION_CURRENT (seq is current),
    times in the same base as ``t0_s``; only those after the mission start count."""
    starts: dict[int, float] = {1: 0.0}
    for t, mtype, seq in sorted(changes):
        if t < t0_s - 0.05:
            continue
        item = seq + 1 if mtype == "MISSION_ITEM_REACHED" else seq
        if item >= 1 and item not in starts:
            starts[item] = max(0.0, t - t0_s)
    return starts


def _mission_messages_in_tlog(path: Path, t0_us: int) -> list[tuple[float, str, int]]:
    """``(log time, type, seq)`` of every MISSION_ITEM_REACHED / MISSION_CURRENT the FC sent."""
    from smcpilot.tlog import read_tlog

    out: list[tuple[float, str, int]] = []
    try:
        for time_us, msg in read_tlog(path):
            mtype = msg.get_type()
            if mtype in ("MISSION_ITEM_REACHED", "MISSION_CURRENT"):
                out.append(((time_us - t0_us) * 1e-6, mtype, int(msg.seq)))
    except TlogError:
        pass  # a cut-short log: keep what was read (load_log reported it)
    return out


def record_from_log(log: Any) -> FlightRecord:
    """A :class:`FlightRecord` from a :class:`ground.logtools.FlightLog` of the FC's ``.tlog``
    (the file is read once more for the mission messages the FC sent)."""
    t0, how = _mission_start_in_log(log)
    changes = _mission_messages_in_tlog(log.path, log.t0_us) if log.t0_us is not None else []
    sp_t = log.smc_t_s - t0 if log.has_smc else np.zeros(0)
    return FlightRecord(
        source="log",
        description=f"FC log {log.path} (state from the {log.state_source or 'n/a'}, χ̂ and set-points from"
        f" {log.ctrl_source or 'n/a'}); mission time 0 = {how}, at {t0:.3f} s of the log",
        t0_s=t0,
        pos_t=log.pos_t_s - t0,
        north=log.north_m,
        east=log.east_m,
        alt=log.alt_m,
        tilt_t=log.att_t_s - t0,
        tilt_deg=log.tilt_deg,
        chi_t=log.ctrl_t_s - t0,
        chi=log.chi_hat,
        armed_t=log.act_t_s - t0,
        armed=log.armed,
        sp_t=sp_t,
        sp_north=log.target_north_m if log.has_smc else np.zeros(0),
        sp_east=log.target_east_m if log.has_smc else np.zeros(0),
        sp_source="the FC's position target (per tick)",
        events=[(e.t_s - t0, e.text) for e in log.events],
        notes=list(log.warnings),
        item_start_s=_item_starts(changes, t0),
    )


class TelemetryRecorder:
    """Records the telemetry of a :class:`~ground.client.Vehicle` (on its receiver thread) for
    expectations and plots when there is no FC log. Times are the vehicle's simulated seconds
    (``time_boot_ms``; for messages without it, the latest one). Optionally writes every message
    to a ``.tlog`` stamped with simulated time, for :func:`ground.logtools.plot_log`."""

    def __init__(self, vehicle: Vehicle, tlog_path: Path | None = None) -> None:
        self.vehicle = vehicle
        self.pos: list[tuple[float, float, float, float]] = []
        self.att: list[tuple[float, float, float]] = []
        self.chi: dict[float, list[float]] = {}
        self.armed: list[tuple[float, bool]] = []
        self.current: list[tuple[float, str, int]] = []
        self.targets: list[tuple[float, float, float]] = []
        self.events: list[tuple[float, str]] = []
        self._last_t = 0.0
        self._writer = None
        self._sub = None
        self._lock = threading.Lock()
        if tlog_path is not None:
            from smcpilot.tlog import TlogWriter

            self._writer = TlogWriter(tlog_path)

    def start(self) -> TelemetryRecorder:
        self._sub = self.vehicle.subscribe(None, self._on_message)
        return self

    def stop(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        with self._lock:
            if self._writer is not None:
                self._writer.close()

    def _on_message(self, msg: mavlink.MAVLink_message) -> None:
        mtype = msg.get_type()
        if mtype in _TIMED_MESSAGES:
            t = float(msg.time_boot_ms) * 1e-3
            self._last_t = max(self._last_t, t)
        else:
            t = self._last_t
        with self._lock:
            if self._writer is not None and not self._writer.closed:
                try:
                    self._writer.write(round(t * 1e6), msg.get_msgbuf())
                except TlogError:
                    pass
        if mtype == "LOCAL_POSITION_NED":
            self.pos.append((t, msg.x, msg.y, -msg.z))
        elif mtype == "ATTITUDE":
            self.att.append((t, msg.roll, msg.pitch))
        elif mtype == "POSITION_TARGET_LOCAL_NED":
            self.targets.append((t, msg.x, msg.y))
        elif mtype == "NAMED_VALUE_FLOAT":
            name = msg.name if isinstance(msg.name, str) else msg.name.decode("ascii", "replace")
            name = name.split("\0", 1)[0]
            if name in CHI_NAMES:
                self.chi.setdefault(t, [math.nan] * 4)[CHI_NAMES.index(name)] = float(msg.value)
        elif mtype == "HEARTBEAT":
            if msg.type != mavlink.MAV_TYPE_GCS and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
                self.armed.append((t, bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)))
        elif mtype in ("MISSION_ITEM_REACHED", "MISSION_CURRENT"):
            self.current.append((t, mtype, int(msg.seq)))
        elif mtype == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("utf-8", "replace")
            self.events.append((t, text.split("\0", 1)[0]))

    def record(self, t0_s: float, mission: Mission, home: Home | None) -> FlightRecord:
        """The recorded telemetry as a :class:`FlightRecord` with mission time 0 at ``t0_s``."""
        p = np.asarray(sorted(self.pos), dtype=float).reshape(-1, 4)
        a = np.asarray(sorted(self.att), dtype=float).reshape(-1, 3)
        tilt = np.degrees(np.arccos(np.clip(np.cos(a[:, 1]) * np.cos(a[:, 2]), -1.0, 1.0)))
        chi_t = np.asarray(sorted(self.chi), dtype=float)
        chi = np.asarray([self.chi[t] for t in sorted(self.chi)], dtype=float).reshape(-1, 4)
        arm = sorted(self.armed, key=lambda r: r[0])
        rec = FlightRecord(
            source="telemetry",
            description="telemetry received over the ground link (10 Hz position/attitude/χ̂, armed from the 1 Hz"
            f" HEARTBEAT); mission time 0 = the vehicle's start of AUTO at {t0_s:.2f} s simulated",
            t0_s=t0_s,
            pos_t=p[:, 0] - t0_s,
            north=p[:, 1],
            east=p[:, 2],
            alt=p[:, 3],
            tilt_t=a[:, 0] - t0_s,
            tilt_deg=tilt,
            chi_t=chi_t - t0_s,
            chi=chi,
            armed_t=np.asarray([r[0] for r in arm], dtype=float) - t0_s,
            armed=np.asarray([r[1] for r in arm], dtype=bool),
            sp_t=np.zeros(0),
            sp_north=np.zeros(0),
            sp_east=np.zeros(0),
            sp_source="planned: the current item's point (telemetry has no set-point)",
            events=[(t - t0_s, text) for t, text in self.events],
            item_start_s=_item_starts(self.current, t0_s),
        )
        targets = np.asarray(sorted(self.targets), dtype=float).reshape(-1, 3)
        if np.count_nonzero(targets[:, 0] >= t0_s) >= 2:
            rec.sp_t, rec.sp_north, rec.sp_east = targets[:, 0] - t0_s, targets[:, 1], targets[:, 2]
            rec.sp_source = "the FC's set-point from POSITION_TARGET_LOCAL_NED (4 Hz telemetry)"
        else:
            self._planned_setpoints(rec, mission, home)
        return rec

    def _planned_setpoints(self, rec: FlightRecord, mission: Mission, home: Home | None) -> None:
        """Set ``rec.sp_*`` at the position samples after the mission start: the current item's
        point (see the module docstring)."""
        changes = sorted((t, item) for item, t in rec.item_start_s.items())
        t = rec.pos_t
        sel = np.flatnonzero(t >= 0.0)
        if not sel.size:
            return
        sp_n = np.full(sel.size, np.nan)
        sp_e = np.full(sel.size, np.nan)
        seq = 1
        started = 0.0
        anchor: tuple[float, float] | None = None
        ci = 0
        for j, k in enumerate(sel):
            tk = t[k]
            while ci < len(changes) and changes[ci][0] <= tk:
                if changes[ci][1] != seq:
                    seq, started, anchor = changes[ci][1], changes[ci][0], None
                ci += 1
            if not 1 <= seq <= len(mission.items):
                seq_item = mission.items[-1]
            else:
                seq_item = mission.items[seq - 1]
            point = None
            if seq_item.type == "rtl":
                point = (0.0, 0.0)
            elif seq_item.has_position:
                try:
                    point = seq_item.local_ne(home)
                except MissionRunError:
                    point = None
            if point is None:
                if anchor is None:
                    i0 = min(int(np.searchsorted(t, started)), t.size - 1)
                    anchor = (float(rec.north[i0]), float(rec.east[i0]))
                point = anchor
            sp_n[j], sp_e[j] = point
        rec.sp_t = t[sel]
        rec.sp_north = sp_n
        rec.sp_east = sp_e


def evaluate(mission: Mission, rec: FlightRecord, home: Home | None) -> list[ExpectationResult]:
    """Every expectation of ``mission`` on ``rec`` (``home`` converts lat/lon items)."""
    return [exp.evaluate(rec, mission, home) for exp in mission.expectations]


# ------------------------------------------------------------------------------------------ report
def _json_num(v: Any) -> Any:
    if v is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return f if math.isfinite(f) else None


def _json_value(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _json_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    if isinstance(v, (str, type(None))):
        return v
    return _json_num(v)


@dataclass
class MissionReport:
    """The outcome of :func:`run_mission`: the verdicts and what was flown."""

    mission: Mission
    results: list[ExpectationResult]
    #: "log" or "telemetry".
    source: str
    source_description: str
    #: True when the vehicle disarmed before ``max_duration_s``.
    finished: bool
    #: mission time at which the runner stopped waiting, s.
    flight_time_s: float
    #: "lockstep SITL (...)" or "connected to URL".
    flown_with: str
    tlog: Path | None = None
    plots: list[Path] = field(default_factory=list)
    json_path: Path | None = None
    wall_time_s: float = 0.0
    events: list[tuple[float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every expectation held."""
        return all(r.passed for r in self.results)

    @property
    def failed(self) -> list[ExpectationResult]:
        return [r for r in self.results if not r.passed]

    def as_dict(self) -> dict[str, Any]:
        m = self.mission
        return {
            "mission": m.name,
            "file": str(m.path) if m.path is not None else None,
            "description": m.description,
            "passed": self.passed,
            "expectations_passed": sum(r.passed for r in self.results),
            "expectations_total": len(self.results),
            "flown_with": self.flown_with,
            "source": self.source,
            "source_description": self.source_description,
            "finished": self.finished,
            "flight_time_s": _json_num(self.flight_time_s),
            "wall_time_s": _json_num(self.wall_time_s),
            "tlog": str(self.tlog) if self.tlog is not None else None,
            "plots": [str(p) for p in self.plots],
            "items": [it.to_toml_entry() for it in m.items],
            "expectations": [r.as_dict() for r in self.results],
            "events": [{"t_s": round(t, 3), "text": text} for t, text in self.events],
            "notes": list(self.notes),
        }


def print_report(report: MissionReport, file: TextIO | None = None) -> None:
    """The readable report: each expectation PASS/FAIL with the measured value and the limit."""
    f = file if file is not None else sys.stdout
    m = report.mission
    print(file=f)
    print(f"Mission {m.name!r}" + (f" ({m.path})" if m.path else "") + f": {len(m.items)} items, flown with {report.flown_with}", file=f)
    state = "landed and disarmed" if report.finished else "did NOT land and disarm"
    print(f"  {state}; {report.flight_time_s:.1f} s of mission time in {report.wall_time_s:.1f} s wall", file=f)
    print(f"  evaluated from {report.source_description}", file=f)
    for note in report.notes:
        print(f"  note: {note}", file=f)
    if not report.results:
        print("  no expectations in the file", file=f)
    for r in report.results:
        verdict = "PASS" if r.passed else "FAIL"
        subject = f" {r.subject}" if r.subject else ""
        print(f"  {verdict}  expect {r.number} {r.kind}{subject}: {r.measured_text} vs limit {r.limit_text}", file=f)
        print(f"        {r.detail}" + ("  [from telemetry]" if r.source == "telemetry" else ""), file=f)
    n_ok = sum(r.passed for r in report.results)
    print(f"Result: {n_ok}/{len(report.results)} expectations held -> {'PASS' if report.passed else 'FAIL'}", file=f)
    if report.failed:
        print("  failed: " + "; ".join(f"expect {r.number} {r.kind} ({r.description})" for r in report.failed), file=f)
    if report.tlog is not None:
        print(f"log: {report.tlog}", file=f)
    if report.plots:
        print(f"plots: {len(report.plots)} PNG files in {report.plots[0].parent}/", file=f)
    if report.json_path is not None:
        print(f"json: {report.json_path}", file=f)
    f.flush()


# ------------------------------------------------------------------------------------------ runner
def _stamp(vehicle: Vehicle) -> float:
    return vehicle.sim_time_s if vehicle.sim_time_s is not None else 0.0


@dataclass
class _Flight:
    home: Home | None
    start_sim_s: float
    end_sim_s: float
    finished: bool
    notes: list[str]


def _fly(vehicle: Vehicle, mission: Mission, progress: Callable[[str], None], alive: Callable[[], str | None]) -> _Flight:
    """Upload, arm, MISSION_START, and wait (simulated time) until disarmed or max_duration_s."""
    notes: list[str] = []
    home_pos: HomePosition | None
    try:
        home_pos = vehicle.get_home(timeout_s=10.0)
    except VehicleError:
        home_pos = None
    if home_pos is None and mission.uses_local_positions:
        raise MissionRunError("the vehicle sent no HOME_POSITION: north_m/east_m items cannot be converted")
    home = _geo_home(home_pos) if home_pos is not None else None
    items = mission.to_items(home)
    progress(f"uploading {len(items)} items (+ home as item 0) through the mission protocol")
    vehicle.upload_mission(items)
    if not vehicle.armed:
        if vehicle.mode != "GUIDED":
            # e.g. AUTO or LAND left over from an earlier flight: arm where nothing starts by itself
            progress(f"mode {vehicle.mode} -> GUIDED before arming")
            vehicle.set_mode("GUIDED")
        progress("arming")
        vehicle.arm()
    progress("MISSION_START (AUTO from item 1)")
    vehicle.start_mission(1)
    start = _stamp(vehicle)
    limit = mission.sitl.max_duration_s
    deadline = start + limit
    next_progress = start + PROGRESS_EVERY_SIM_S
    n_items = len(mission.items)
    dead: list[str] = []

    def done(s: Any) -> bool:
        why = alive()
        if why is not None:
            dead.append(why)
            return True
        now = s.sim_time_s if s.sim_time_s is not None else start
        return (not s.armed) or now >= min(next_progress, deadline)

    finished = False
    while True:
        st = vehicle.wait_for(done, PROGRESS_EVERY_SIM_S + 10.0, what="the mission to progress",
                              value=lambda s: f"armed={s.armed}, mode {s.mode_name}")  # fmt: skip
        if dead:
            raise MissionRunError(dead[0])
        now = st.sim_time_s if st.sim_time_s is not None else start
        if not st.armed:
            finished = True
            progress(f"t={now - start:7.1f} s  disarmed ({st.landed_state_name or 'landed'}) — mission over")
            break
        if now >= deadline:
            notes.append(f"the vehicle was still armed after max_duration_s = {limit:g} s of mission time; the runner stopped waiting")
            progress(f"t={now - start:7.1f} s  max_duration_s reached ({limit:g} s): stop waiting")
            break
        cur = st.mission_current
        if cur is not None and 1 <= cur <= n_items:
            item = mission.items[cur - 1].type
        elif cur is not None and cur > n_items:
            item, cur = "(complete)", n_items
        else:
            item = "-"
        pos = st.position_ned_m
        where = f"N {pos[0]:+7.2f} E {pos[1]:+7.2f} alt {-pos[2]:6.2f} m" if pos is not None else "position unknown"
        progress(f"t={now - start:7.1f} s  item {cur if cur is not None else '-'}/{n_items} {item:<11} {where}  {st.mode_name}")
        while next_progress <= now:
            next_progress += PROGRESS_EVERY_SIM_S
    return _Flight(home, start, _stamp(vehicle), finished, notes)


def _mission_start_from_texts(vehicle: Vehicle, fallback: float) -> float:
    for s in vehicle.statustexts:
        if s.text.strip() == "Mode AUTO" and s.sim_time_s is not None and s.sim_time_s >= fallback - 2.0:
            return s.sim_time_s
    return fallback


def run_mission(
    mission: Mission,
    connect_url: str | None = None,
    *,
    out_dir: Path,
    json_path: Path | None = None,
    progress: Callable[[str], None] | None = None,
    plots: bool = True,
    report_file: TextIO | None = None,
) -> MissionReport:
    """Fly ``mission`` and evaluate its expectations.

    Without ``connect_url``: launch lockstep SITL with the ``[sitl]`` settings (log and FC
    parameter file in ``out_dir``; the FC's ground link points at a free port our
    :class:`~ground.client.Vehicle` listens on), upload the mission through the mission protocol,
    arm, MISSION_START, wait in simulated time until the vehicle disarms or ``max_duration_s``
    passes, stop SITL, and evaluate every expectation on the FC's ``.tlog``. With
    ``connect_url`` (a :mod:`smcpilot.link` URL of a running vehicle): the same flight, evaluated
    on the telemetry received (also written to ``out_dir/<name>-telemetry.tlog``).

    Then prints the report (:func:`print_report`, to ``report_file``, default stdout), writes the
    plots (:func:`ground.logtools.plot_log`, into ``out_dir/plots``) and, with ``json_path``,
    the report as JSON. ``progress`` receives the progress lines (default: print them).
    Raises :class:`MissionRunError`, :class:`ground.sitl.SitlError` or
    :class:`ground.client.VehicleError` when the mission cannot be flown.
    """
    from ground import logtools

    say = progress if progress is not None else (lambda line: print(line, flush=True))
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MissionRunError(f"cannot create the output directory {out_dir}: {exc.strerror or exc}") from None
    stem = mission.path.stem if mission.path is not None else mission.name
    wall0 = time.monotonic()
    notes: list[str] = []
    log = None
    if connect_url is None:
        tlog = out_dir / f"{stem}.tlog"
        param_file = out_dir / f"{stem}-fc.parm"
        if param_file.exists():
            param_file.unlink()  # our own file from an earlier run: start from the FC's defaults
        vehicle = Vehicle("udpin:127.0.0.1:0", connect_timeout_s=30.0)
        vehicle.open()
        flown_with = f"lockstep SITL ({mission.sitl.describe()})"
        say(f"mission {mission.name}: {len(mission.items)} items, {len(mission.expectations)} expectations; {flown_with}")
        try:
            opts = mission.sitl.options(gcs=f"udp:127.0.0.1:{vehicle.local_address[1]}", log_dir=out_dir, tlog=tlog, param_file=param_file)
            sitl = Sitl(opts, echo=lambda line: say(f"  {line}"))

            def alive() -> str | None:
                fc_rc, sim_rc = sitl.poll()
                if fc_rc is not None or sim_rc is not None:
                    who = "the flight controller" if fc_rc is not None else "the simulator"
                    return f"{who} exited during the flight (code {fc_rc if fc_rc is not None else sim_rc}); log {tlog}"
                return None

            with sitl:
                vehicle.wait_heartbeat()
                flight = _fly(vehicle, mission, say, alive)
        finally:
            vehicle.close()
        fcs = sitl.fc_summary or {}
        if fcs.get("overruns"):
            notes.append(f"the FC reported {fcs['overruns']} control overruns")
        try:
            log = logtools.load_log(tlog)
        except logtools.LogError as exc:
            raise MissionRunError(f"cannot read the FC log: {exc}") from None
        rec = record_from_log(log)
        report_tlog: Path | None = tlog
    else:
        telemetry_tlog = out_dir / f"{stem}-telemetry.tlog"
        flown_with = f"the vehicle at {connect_url}"
        say(f"mission {mission.name}: {len(mission.items)} items, {len(mission.expectations)} expectations; connecting to {connect_url}")
        vehicle = Vehicle(connect_url)
        recorder = TelemetryRecorder(vehicle, telemetry_tlog)
        try:
            vehicle.open()
            recorder.start()
            vehicle.wait_heartbeat()
            flight = _fly(vehicle, mission, say, lambda: None)
            # Let the last telemetry of the landing arrive.
            try:
                vehicle.sleep_sim(1.0)
            except VehicleError:
                pass
        finally:
            recorder.stop()
            vehicle.close()
        t0 = _mission_start_from_texts(vehicle, flight.start_sim_s)
        rec = recorder.record(t0, mission, flight.home)
        notes.append("no FC log over the ground link: expectations use the telemetry received (10 Hz; armed state at 1 Hz)")
        report_tlog = telemetry_tlog
        try:
            log = logtools.load_log(telemetry_tlog)
        except logtools.LogError:
            log = None
    notes.extend(flight.notes)
    notes.extend(rec.notes)
    results = evaluate(mission, rec, flight.home)
    report = MissionReport(
        mission=mission,
        results=results,
        source=rec.source,
        source_description=rec.description,
        finished=flight.finished,
        flight_time_s=flight.end_sim_s - flight.start_sim_s,
        flown_with=flown_with,
        tlog=report_tlog,
        wall_time_s=time.monotonic() - wall0,
        events=[(t, text) for t, text in rec.events if t >= -5.0],
        notes=notes,
    )
    if plots and log is not None:
        try:
            report.plots = logtools.plot_log(log, out_dir / "plots")
        except (logtools.LogError, OSError) as exc:
            report.notes.append(f"plots not written: {exc}")
    if json_path is not None:
        report.json_path = Path(json_path)
        try:
            report.json_path.parent.mkdir(parents=True, exist_ok=True)
            report.json_path.write_text(json.dumps(report.as_dict(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        except OSError as exc:
            raise MissionRunError(f"cannot write {json_path}: {exc.strerror or exc}") from None
    print_report(report, report_file)
    return report


# --------------------------------------------------------------------------------------------- cli
EXIT_PASSED = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Subcommands of ``smcpilot mission``: ``run FILE [--connect URL] [--json PATH] [--out DIR]``."""
    sub = p.add_subparsers(dest="mission_command", metavar="SUBCOMMAND")
    sub.required = True
    r = sub.add_parser(
        "run",
        help="fly a scripted mission (TOML) and check its expectations",
        description="Fly FILE's [[item]] list as a real mission (upload, arm, MISSION_START) in lockstep SITL"
        " launched with its [sitl] settings, or on a running vehicle (--connect), then check its [[expect]]"
        " entries on the FC's log. Exit 0 when every expectation held, 1 when one failed or the flight"
        " could not be flown, 2 for a broken file or bad usage. The file format is in ground/missions.py.",
    )
    r.add_argument("file", type=Path, metavar="FILE", help="mission TOML file")
    r.add_argument("--connect", metavar="URL", default=None,
                   help="fly the already-running vehicle at URL (udpin:HOST:PORT or udpout:HOST:PORT) instead of launching"
                   " SITL; expectations then use the telemetry received")  # fmt: skip
    r.add_argument("--json", type=Path, metavar="PATH", default=None, help="also write the report as JSON")
    r.add_argument("--out", type=Path, metavar="DIR", default=None,
                   help="directory for the log and plots (default out/missions/<file stem>)")  # fmt: skip
    r.add_argument("--no-plots", action="store_true", help="skip the plots")
    r.set_defaults(mission_handler=_run_main)


def main(args: argparse.Namespace) -> int:
    """``smcpilot mission SUBCOMMAND``."""
    handler: Callable[[argparse.Namespace], int] = args.mission_handler
    return handler(args)


class _Terminated(Exception):
    pass


def _raise_terminated(*_: object) -> None:
    raise _Terminated()


def _run_main(args: argparse.Namespace) -> int:
    mission = load_mission(args.file)  # MissionFileError -> exit 2 (lab.cli)
    out = args.out if args.out is not None else Path("out") / "missions" / args.file.stem
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        report = run_mission(mission, args.connect, out_dir=out, json_path=args.json, plots=not args.no_plots)
    except (_Terminated, KeyboardInterrupt):
        print("smcpilot mission run: stopped", file=sys.stderr)
        return 130
    except ConfigError:
        raise  # usage/configuration: exit 2
    except (VehicleError, SitlError, MissionRunError, LinkError, TlogError) as exc:
        print(f"smcpilot mission run: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return EXIT_PASSED if report.passed else EXIT_FAILED
