"""Many vehicles in one flight: the ``[swarm]`` table of a scenario, its vehicles, ports and spawn grid.

A scenario with a ``[swarm]`` table flies ``count`` vehicles in one simulator: one flight-controller
process each (system ids ``sysid_base``, ``sysid_base + 1``, ...), one simulator stepping every
plant on one clock. Every vehicle flies the scenario's flight (vehicle, environment, controller,
parameters, plan, faults) unless a ``[[swarm.vehicle]]`` table (the i-th table is the i-th vehicle)
changes it::

    [swarm]
    count = 3
    spacing_m = 4.0          # the spawn grid: rows and columns this far apart (north, east)
    separation_m = 2.0       # an event when two vehicles come closer than this (centres, m)
    contact_m = 0.5          # two vehicles closer than this touch: both crash (default 2 x arm length)
    lost = "stop"            # real time, a vehicle whose FC died: "stop" its motors, "hold" them, "remove" it

    [[swarm.vehicle]]        # vehicle 1 (system id 1)
    seed = 7                 # default: the scenario's seed + 1000 x (index)
    params = { SMC_CHI_DZ = 0.2 }      # over the scenario's [fc] params
    [[swarm.vehicle.fault]]  # added to the scenario's faults
    kind = "motor"
    start_s = 8.0
    motor = 2
    efficiency = 0.7

    [[swarm.vehicle]]        # vehicle 2
    offset_m = [0.0, 10.0]   # spawn north, east of the swarm's home (default: the grid)
    controller = "cascade_pid"
    plan = "v2-plan.toml"    # or [[swarm.vehicle.step]] tables: replaces the scenario's plan

Per vehicle: ``sysid``, ``seed``, ``controller``, ``params``, ``home`` (its own origin, lat/lon/alt:
then its spawn offset is where that home lies from the swarm's), ``offset_m``, ``plan`` or ``step``,
``fault``, ``vehicle`` (a vehicle TOML file). Anything else is an error naming the key.

Each vehicle's local frame has its origin where it spawns (its ``home``, shifted by its offset
from the scenario's home), as ArduPilot's multi-vehicle SITL does: a ground station sees the swarm
spread over the field, and each FC flies its own plan in its own frame.

Ports (:func:`fc_ground_port`): instance ``i`` (0-based) answers ground stations on
``FC_GROUND_PORT + 10 (i + 1)``, ArduPilot's ``+10 x instance`` convention; the ground router
answers on ``FC_GROUND_PORT`` itself, as a single vehicle does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from smcpilot.errors import ConfigError
from smcpilot.geo import Home, global_to_ned, ned_to_global
from smcpilot.protocol import FC_GROUND_PORT

#: the most vehicles one swarm may hold (one FC process each; the simulator steps them all).
MAX_VEHICLES = 64
#: the port step between instances (ArduPilot's convention).
PORT_STEP = 10
DEFAULT_SPACING_M = 4.0
DEFAULT_SEPARATION_M = 2.0
#: default seed of vehicle i: the scenario's seed + SEED_STEP x i (vehicle 0 keeps the scenario's).
SEED_STEP = 1000

#: keys of a [[swarm.vehicle]] table.
VEHICLE_KEYS = frozenset({"sysid", "seed", "controller", "params", "home", "offset_m", "plan", "step", "fault", "vehicle"})
#: keys of the [swarm] table.
SWARM_KEYS = frozenset({"count", "sysid_base", "spacing_m", "separation_m", "contact_m", "lost", "vehicle"})
#: real time, what the simulator does with a vehicle whose FC is gone: "stop" its motors (it falls,
#: as a vehicle does whose ESCs lose their signal), "hold" its last motor commands, or "remove" it
#: from the world (no more physics, no separation checks).
LOST_POLICIES = ("stop", "hold", "remove")


class SwarmError(ConfigError):
    """A swarm that cannot fly as described (its count, system ids, ports or a vehicle table)."""


def fc_ground_port(index: int, base: int = FC_GROUND_PORT) -> int:
    """The ground port instance ``index`` (0-based) of a swarm answers on."""
    return base + PORT_STEP * (index + 1)


def fc_groups(count: int, processes: int) -> list[list[int]]:
    """Vehicles ``0..count-1`` in ``processes`` groups of consecutive vehicles, as even as can be
    (the first groups one larger): which flight controllers share a process (:mod:`fc.group`)."""
    if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
        raise SwarmError(f"the number of flight-controller processes must be a whole number >= 1, got {processes!r}")
    n = min(processes, count)
    size, extra = divmod(count, n)
    groups, start = [], 0
    for g in range(n):
        end = start + size + (1 if g < extra else 0)
        groups.append(list(range(start, end)))
        start = end
    return groups


def check_count(count: int, *, base_port: int = FC_GROUND_PORT) -> None:
    """Raise :class:`SwarmError` unless ``count`` vehicles fit (the maximum and the port range)."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise SwarmError(f"the vehicle count must be a whole number >= 1, got {count!r}")
    if count > MAX_VEHICLES:
        raise SwarmError(f"at most {MAX_VEHICLES} vehicles fly in one swarm, got {count}")
    if fc_ground_port(count - 1, base_port) > 65535:
        raise SwarmError(f"{count} vehicles need ground ports up to {fc_ground_port(count - 1, base_port)}, beyond 65535")


def grid_offset(index: int, count: int, spacing_m: float) -> tuple[float, float]:
    """Spawn (north, east) m of vehicle ``index`` on a square grid, row by row."""
    cols = max(1, math.ceil(math.sqrt(count)))
    return (float(index // cols) * spacing_m, float(index % cols) * spacing_m)


@dataclass(frozen=True)
class SwarmSpec:
    """The ``[swarm]`` table: how many vehicles, their ids and spawn grid, separation and contact."""

    count: int = 1
    #: the first vehicle's system id; the others count up from it (unless their table says).
    sysid_base: int = 1
    spacing_m: float = DEFAULT_SPACING_M
    #: two vehicles closer than this (centre to centre, m) is an event (``SIM: vehicles 1 and 2 within 1.8 m``).
    separation_m: float = DEFAULT_SEPARATION_M
    #: two vehicles closer than this touch: both crash (their motors stop). None: 2 x the arm length.
    contact_m: float | None = None
    #: real time: a vehicle whose FC is gone (:data:`LOST_POLICIES`); lockstep ends the run instead.
    lost: str = "stop"
    #: the [[swarm.vehicle]] tables as read (validated; turned into flights by the scenario).
    vehicles: tuple[Mapping[str, Any], ...] = ()

    def __post_init__(self) -> None:
        check_count(self.count)
        if isinstance(self.sysid_base, bool) or not isinstance(self.sysid_base, int) or not 1 <= self.sysid_base <= 255:
            raise SwarmError(f"swarm.sysid_base must be a system id in 1..255, got {self.sysid_base!r}")
        for name in ("spacing_m", "separation_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SwarmError(f"swarm.{name} must be a finite number >= 0 m, got {v!r}")
        if self.contact_m is not None and not (math.isfinite(self.contact_m) and self.contact_m >= 0):
            raise SwarmError(f"swarm.contact_m must be a finite number >= 0 m, got {self.contact_m!r}")
        if self.lost not in LOST_POLICIES:
            raise SwarmError(f"swarm.lost must be one of {', '.join(LOST_POLICIES)}, got {self.lost!r}")
        if len(self.vehicles) > self.count:
            raise SwarmError(f"{len(self.vehicles)} [[swarm.vehicle]] tables for a swarm of {self.count}")
        for i, table in enumerate(self.vehicles):
            unknown = sorted(set(table) - VEHICLE_KEYS)
            if unknown:
                raise SwarmError(f"unknown key swarm.vehicle[{i + 1}].{unknown[0]} (known: {', '.join(sorted(VEHICLE_KEYS))})")

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any]) -> SwarmSpec:
        if not isinstance(table, Mapping):
            raise SwarmError(f"[swarm] must be a table, got {table!r}")
        unknown = sorted(set(table) - SWARM_KEYS)
        if unknown:
            raise SwarmError(f"unknown key swarm.{unknown[0]} (known: {', '.join(sorted(SWARM_KEYS))})")
        kw: dict[str, Any] = {}
        for key in ("count", "sysid_base"):
            if key in table:
                v = table[key]
                if isinstance(v, bool) or not isinstance(v, int):
                    raise SwarmError(f"swarm.{key} must be a whole number, got {v!r}")
                kw[key] = v
        if "lost" in table:
            kw["lost"] = table["lost"]
        for key in ("spacing_m", "separation_m", "contact_m"):
            if key in table:
                v = table[key]
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise SwarmError(f"swarm.{key} must be a number of metres, got {v!r}")
                kw[key] = float(v)
        tables = table.get("vehicle", [])
        if not isinstance(tables, list) or not all(isinstance(t, Mapping) for t in tables):
            raise SwarmError(f"swarm.vehicle must be [[swarm.vehicle]] tables, got {tables!r}")
        kw["vehicles"] = tuple(dict(t) for t in tables)
        return cls(**kw)

    def to_mapping(self) -> dict[str, Any]:
        out: dict[str, Any] = {"count": self.count, "sysid_base": self.sysid_base, "spacing_m": self.spacing_m,
                               "separation_m": self.separation_m}  # fmt: skip
        if self.contact_m is not None:
            out["contact_m"] = self.contact_m
        if self.lost != "stop":
            out["lost"] = self.lost
        if self.vehicles:
            out["vehicle"] = [dict(t) for t in self.vehicles]
        return out

    def sysids(self) -> tuple[int, ...]:
        """Every vehicle's system id (checked: each in 1..255, no two alike)."""
        ids = []
        for i in range(self.count):
            table = self.vehicles[i] if i < len(self.vehicles) else {}
            sid = table.get("sysid", self.sysid_base + i)
            if isinstance(sid, bool) or not isinstance(sid, int) or not 1 <= sid <= 255:
                raise SwarmError(f"swarm.vehicle[{i + 1}].sysid must be a system id in 1..255, got {sid!r}")
            ids.append(sid)
        seen: dict[int, int] = {}
        for i, sid in enumerate(ids):
            if sid in seen:
                raise SwarmError(f"vehicles {seen[sid] + 1} and {i + 1} both have system id {sid}: every vehicle needs its own")
            seen[sid] = i
        return tuple(ids)


@dataclass(frozen=True)
class SpawnPoint:
    """Where one vehicle of a swarm starts: its home (its local frame's origin) and where that lies
    from the swarm's home (north, east, m)."""

    home: Home
    offset_ne_m: tuple[float, float]


def spawn_point(swarm_home: Home, index: int, spec: SwarmSpec, table: Mapping[str, Any]) -> SpawnPoint:
    """Vehicle ``index``'s spawn: its table's ``home`` (offset derived), or ``offset_m``, or the grid."""
    where = f"swarm.vehicle[{index + 1}]"
    if "home" in table and "offset_m" in table:
        raise SwarmError(f"{where}: give home or offset_m, not both")
    if "home" in table:
        h = table["home"]
        if not isinstance(h, list) or len(h) != 3:
            raise SwarmError(f"{where}.home must be [lat_deg, lon_deg, alt_m], got {h!r}")
        home = Home(*(float(v) for v in h))
        n, e, _ = global_to_ned(swarm_home, home.lat_deg, home.lon_deg, home.alt_m)
        return SpawnPoint(home, (n, e))
    if "offset_m" in table:
        o = table["offset_m"]
        if (not isinstance(o, list) or len(o) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in o)):  # fmt: skip
            raise SwarmError(f"{where}.offset_m must be [north_m, east_m], got {o!r}")
        n, e = float(o[0]), float(o[1])
    else:
        n, e = grid_offset(index, spec.count, spec.spacing_m)
    lat, lon, alt = ned_to_global(swarm_home, n, e, 0.0)
    return SpawnPoint(Home(lat, lon, alt), (n, e))
