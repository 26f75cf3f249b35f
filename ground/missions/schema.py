"""The mission-file format (see :mod:`ground.missions` for the full description): parsing and
checking a TOML document into a :class:`Mission` of :class:`ItemSpec` items, :class:`SitlSettings`
and expectations, and converting items to and from :class:`~ground.vehicle.MissionItem`.

Units: positions metres north/east of home (local NED) or WGS-84 degrees; altitudes metres above
home; times seconds; speeds m/s; headings degrees (0 north, 90 east); forces newtons, NED.
"""

from __future__ import annotations

import difflib
import json
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.missions.errors import MissionFileError, MissionRunError
from ground.missions.expectations import _EXPECTATIONS, CHANNELS, EXPECTATION_KINDS, Expectation
from ground.sitl import SitlOptions
from ground.vehicle import HomePosition, MissionItem
from smcpilot.errors import ConfigError
from smcpilot.faults import FaultSpec
from smcpilot.geo import Home, global_to_ned, ned_to_global
from smcpilot.lawref import law_reference_problem, normalise_reference
from smcpilot.limits import HARD_LIMITS, TAKEOFF_ALT_MIN_M, target_refusal
from smcpilot.scenario import EnvironmentSpec, Scenario
from smcpilot.swarm import DEFAULT_SPACING_M, MAX_VEHICLES, SwarmSpec
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

__all__ = [
    "DEFAULT_MAX_DURATION_S",
    "ITEM_TYPES",
    "ItemSpec",
    "Mission",
    "MissionFileError",
    "SitlSettings",
    "items_to_toml",
    "load_mission",
    "parse_mission",
]

#: Simulated seconds the runner waits for the mission to end (landed and disarmed) by default.
DEFAULT_MAX_DURATION_S = 600.0
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
#: positions and altitudes: the absolute limits every target source shares (smcpilot.limits);
#: the vehicle also applies its own geofence (FENCE_*) and says so if an item lies outside it.
_ITEM_RANGES: dict[str, tuple[float, float]] = {
    "alt_m": (0.0, HARD_LIMITS.alt_max_m),
    "hold_s": (0.0, 3600.0),
    "yaw_deg": (-360.0, 360.0),
    "radius_m": (0.0, 100.0),
    "north_m": (-HARD_LIMITS.radius_m, HARD_LIMITS.radius_m),
    "east_m": (-HARD_LIMITS.radius_m, HARD_LIMITS.radius_m),
    "lat_deg": (-90.0, 90.0),
    "lon_deg": (-180.0, 180.0),
}
_SITL_KEYS = frozenset(
    {"controller", "vehicle", "seed", "plant", "noise", "noise_scale", "wind_force_ned_n", "gust_std_n", "home", "max_duration_s", "fault",
     "count", "spacing_m"}
)  # fmt: skip
_PLANTS = ("rigid-body", "paper")
_TOP_KEYS = frozenset({"name", "description", "sitl", "item", "expect", "vehicle"})
#: keys of a swarm mission's [[vehicle]] table.
_VEHICLE_KEYS = frozenset({"item", "expect"})


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
    """One ``[[item]]`` of a mission file (see :mod:`ground.missions`).

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
        """This item as a :class:`ground.vehicle.MissionItem` (altitudes relative to home).

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
        """A downloaded :class:`ground.vehicle.MissionItem` in this format: north/east metres when
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
            lo, hi = TAKEOFF_ALT_MIN_M, HARD_LIMITS.alt_max_m
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
    if has_local:  # the same rule as the vehicle's, with the absolute limits (it adds its fence)
        why = target_refusal(vals["north_m"], vals["east_m"], vals.get("alt_m", 0.0), HARD_LIMITS)
        if why is not None:
            raise w.error(why, "north_m")
    if kind == "waypoint" and not positioned:
        raise w.error("missing key 'north_m' (a waypoint needs north_m/east_m or lat_deg/lon_deg)", "north_m")
    if kind == "loiter_time" and positioned and "alt_m" not in vals:
        raise w.error("missing key 'alt_m' (a loiter_time with a position needs its altitude)", "alt_m")
    return ItemSpec(number=where.number or 0, type=kind, **vals)



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
    #: timed faults (``[[sitl.fault]]``, the scenario's ``[[fault]]`` tables; times from SITL's start).
    faults: tuple[FaultSpec, ...] = ()
    #: vehicles of a swarm mission (``smcpilot sitl --count``), system ids 1..count, on a grid this far apart.
    count: int = 1
    spacing_m: float = DEFAULT_SPACING_M

    def scenario(self, name: str = "mission") -> Scenario:
        """The flight these settings describe (no plan: the mission is uploaded and started)."""
        return Scenario(
            swarm=SwarmSpec(count=self.count, spacing_m=self.spacing_m) if self.count > 1 else None,
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
            faults=self.faults,
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
        parts.extend(f"fault at {f.start_s:g} s: {f.describe()}" for f in self.faults)
        return ", ".join(parts)


def _parse_sitl(where: _Where, raw: Any, base_dir: Path | None) -> SitlSettings:
    table = _table(where, raw, "[sitl]")
    _check_keys(where, table, (), _SITL_KEYS, "[sitl]")
    kw: dict[str, Any] = {}
    for key, v in table.items():
        if key == "fault":
            if not isinstance(v, list):
                raise where.error("must be an array of tables ([[sitl.fault]]), one per fault", key)
            try:
                kw["faults"] = tuple(FaultSpec.from_mapping(d, f"[[sitl.fault]] {i + 1}") for i, d in enumerate(v))
            except ConfigError as exc:
                raise where.error(str(exc), key) from None
        elif key == "controller":
            problem = law_reference_problem(v)
            if problem:
                raise where.error(problem, key)
            kw[key] = normalise_reference(v, base_dir)  # a law file relative to the mission file
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
        elif key == "count":
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_VEHICLES:
                raise where.error(f"must be a whole number of vehicles in 1..{MAX_VEHICLES}, got {v!r}", key)
            kw[key] = v
        elif key == "spacing_m":
            kw[key] = _number(where, table, key, 0.0, 1000.0)
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
    #: a swarm mission's [[vehicle]] tables, the i-th for vehicle i: its own items (None: the
    #: shared ones) and its expectations (added to the shared ones).
    vehicles: tuple[tuple[tuple[ItemSpec, ...] | None, tuple[Expectation, ...]], ...] = ()
    #: a swarm mission's ``separation`` expectations: the smallest allowed distance between two
    #: vehicles' centres over the flight, m (and no contact).
    separation_min_m: tuple[float, ...] = ()

    @property
    def count(self) -> int:
        """Vehicles that fly it ([sitl] count)."""
        return self.sitl.count

    def for_vehicle(self, index: int) -> Mission:
        """The one-vehicle mission vehicle ``index`` (0-based) flies."""
        items, expect = self.vehicles[index] if index < len(self.vehicles) else (None, ())
        return replace(self, items=items if items is not None else self.items, expectations=self.expectations + expect,
                       vehicles=(), separation_min_m=(), name=f"{self.name} (vehicle {index + 1})")  # fmt: skip

    def to_items(self, home: Home | HomePosition | None) -> list[MissionItem]:
        """The items to upload, as :class:`ground.vehicle.MissionItem` (home, item 0, not
        included: :meth:`ground.vehicle.Vehicle.upload_mission` adds it). ``home`` — the vehicle's
        ``HOME_POSITION`` (:class:`ground.vehicle.HomePosition`) or a :class:`smcpilot.geo.Home` —
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
    sitl = _parse_sitl(_Where(source, "sitl"), doc["sitl"], base_dir) if "sitl" in doc else SitlSettings()
    separation: list[float] = []
    expectations_list = []
    for i, raw in enumerate(raw_expect, start=1):
        where = _Where(source, "expect", i)
        if isinstance(raw, Mapping) and raw.get("kind") == "separation":
            if sitl.count < 2:
                raise where.error("a separation expectation needs a swarm: [sitl] count = 2 or more", "kind")
            _check_keys(where, raw, ("kind", "min_m"), (), "a separation expectation")
            separation.append(_number(where, raw, "min_m", 0.0, 1000.0, lo_open=True))
            continue
        expectations_list.append(_parse_expectation(where, raw, items))
    expectations = tuple(expectations_list)
    vehicles = _parse_vehicles(source, doc.get("vehicle"), sitl.count, items, len(expectations))
    for v, (own, _) in enumerate(vehicles, start=1):  # a shared expectation that names an item must find it in the vehicle's own
        if own is None:
            continue
        for e in expectations:
            n = getattr(e, "item", None)
            if n is not None and not (1 <= n <= len(own) and own[n - 1].type in ("waypoint", "takeoff", "loiter_time", "land")):
                raise _Where(source, "expect", e.number).error(f"names item {n}, which vehicle {v}'s own [[vehicle.item]] list has not"
                                                               " (or it has no position): give that vehicle its own expectation")  # fmt: skip
    name = doc.get("name") or (path.stem if path is not None else "mission")
    return Mission(items, expectations, sitl, name, doc.get("description", ""), path, vehicles, tuple(separation))


def _parse_vehicles(source: str, raw: Any, count: int, shared: tuple[ItemSpec, ...],
                    n_shared: int) -> tuple[tuple[tuple[ItemSpec, ...] | None, tuple[Expectation, ...]], ...]:  # fmt: skip
    """A swarm mission's ``[[vehicle]]`` tables: each vehicle's own items and expectations (numbered
    after the ``n_shared`` shared ones, as the vehicle's report lists them)."""
    if raw is None:
        return ()
    top = _Where(source)
    if not isinstance(raw, list):
        raise top.error("must be an array of tables: write [[vehicle]], not [vehicle]", "vehicle")
    if count < 2:
        raise top.error("[[vehicle]] tables need a swarm: [sitl] count = 2 or more", "vehicle")
    if len(raw) > count:
        raise top.error(f"{len(raw)} [[vehicle]] tables for [sitl] count = {count}", "vehicle")
    out = []
    for v, table in enumerate(raw, start=1):
        where = _Where(source, "vehicle", v)
        table = _table(where, table, "[[vehicle]]")
        _check_keys(where, table, (), _VEHICLE_KEYS, "[[vehicle]]")
        items: tuple[ItemSpec, ...] | None = None
        if "item" in table:
            if not isinstance(table["item"], list) or not table["item"]:
                raise where.error("must be [[vehicle.item]] tables, at least one", "item")
            items = tuple(_parse_item(_Where(source, f"vehicle {v} item", i), r) for i, r in enumerate(table["item"], start=1))
        raw_expect = table.get("expect", [])
        if not isinstance(raw_expect, list):
            raise where.error("must be [[vehicle.expect]] tables", "expect")
        mine = items if items is not None else shared
        expect = tuple(_parse_expectation(_Where(source, f"vehicle {v} expect", i), r, mine) for i, r in enumerate(raw_expect, start=n_shared + 1))
        out.append((items, expect))
    return tuple(out)


def load_mission(path: str | Path) -> Mission:
    """Read and check a mission file (see :mod:`ground.missions`). Raises
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
