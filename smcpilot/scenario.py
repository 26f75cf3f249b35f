"""One scenario: everything that decides a flight, frozen, validated, loaded from and saved to TOML.

A :class:`Scenario` is what ``smcpilot run`` flies (in-process on the flight core, or as the two
SITL processes), what ``smcpilot sitl`` launches, what a mission file's ``[sitl]`` table and the
pytest plugin's ``sitl_options`` marker describe, and what the lab's campaigns vary. Launch
details that do not change the flight (ports, log paths, lockstep pacing) are not part of it.

TOML (every table and key optional; units in the names; positions in the MAVLink local frame:
north, east, altitude up)::

    name = "step-yaw"
    description = "step to (4, -3, 3) m with a heading change across ±180°"
    duration_s = 25.0          # simulated seconds
    seed = 0                   # seeds the noise and gust streams

    [vehicle]
    file = "../vehicles/heavy-quad.toml"   # relative to this file; or the vehicle keys inline
    plant = "rigid-body"                   # or "paper" (the corrected eq. 10 model)

    [environment]
    noise = false              # sensor noise (0.002 rad, 0.01 rad/s, 0.01 m, 0.02 m/s 1-sigma)
    noise_scale = 1.0
    wind_force_ned_n = [0.0, 0.0, 0.0]
    gust_std_n = 0.0           # horizontal gust force std, N
    gust_tau_s = 1.0           # gust correlation time, s
    paper_disturbance = false  # the paper's fs1..fs4

    [fc]
    controller = "adaptive_pid_smc"        # pid_smc, cascade_pid, sign_smc, a plug-in, or path/to/law.py:NAME
    rate_hz = 500.0
    home = [-35.363261, 149.16523, 584.0]  # lat_deg, lon_deg, alt_m (default: ArduPilot's SITL field)
    params = { SMC_CHI_DZ = 0.3 }          # FC parameters by name, as PARAM_SET would set them

    [sim]
    physics_hz = 1000.0

    [link]                     # impaired links (smcpilot.impair): a string or a table
    sim = "loss=0.2,delay_ms=4"           # the simulator <-> FC link, both directions
    gcs = { loss = 0.3 }                  # the FC's ground link, both directions

    [[step]]                   # the timed plan (see smcpilot.plan); or plan = "file.toml"
    t_s = 0.0
    action = "takeoff"
    alt_m = 3.0

    [[fault]]                  # timed faults in the simulator (see smcpilot.faults); any number
    kind = "motor"             # motor, sensor, force, torque, gust, paper_disturbance
    start_s = 10.0             # simulated s; stop_s omitted: until the end
    motor = 1                  # 1 right, 2 front, 3 left, 4 rear
    efficiency = 0.7           # thrust factor 0..1 (0 = off)

    [[fault]]
    kind = "sensor"
    start_s = 12.0
    stop_s = 12.5
    sensor = "position"        # gyro, accel, attitude, position, velocity
    mode = "dropout"           # stuck, bias, noise, dropout, delay (value: bias/std per axis, or delay s)

    [[fault]]
    kind = "torque"            # also "force" (force_ned_n, N) and "gust" (force_std_n, torque_std_n_m, tau_s)
    start_s = 15.0
    torque_frd_n_m = [0.0, 0.0, 0.05]

    [swarm]                    # many vehicles in one flight (smcpilot.swarm): count, spawn grid, per-vehicle tables
    count = 4

Errors name the file and the key (:class:`ScenarioError`; a fault's errors name it as
``fault[N] (kind)``, counting from 1).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from smcpilot.errors import ConfigError, ScenarioError
from smcpilot.faults import FaultSpec
from smcpilot.geo import Home
from smcpilot.impair import ImpairmentError, LinkImpairment
from smcpilot.lawref import law_reference_problem, normalise_reference
from smcpilot.plan import PlanError, PlanStep, load_plan, parse_plan
from smcpilot.swarm import SEED_STEP, SwarmSpec, spawn_point
from smcpilot.tomlfile import read_toml
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

PLANTS = ("rigid-body", "paper")
#: ``--noise``: a small IMU/estimator-grade noise level (1-sigma per axis): attitude rad,
#: body rate rad/s, position m, velocity m/s.
DEFAULT_NOISE_STD = (0.002, 0.01, 0.01, 0.02)

__all__ = ["PLANTS", "DEFAULT_NOISE_STD", "ScenarioError", "EnvironmentSpec", "Scenario", "FleetVehicle", "dumps_toml", "toml_string"]


@dataclass(frozen=True)
class EnvironmentSpec:
    """Sensor noise, wind, gusts and the paper's disturbances (NED forces in newtons)."""

    noise: bool = False
    noise_scale: float = 1.0
    wind_force_ned_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_n: float = 0.0
    gust_tau_s: float = 1.0
    paper_disturbance: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.noise_scale) and self.noise_scale >= 0.0):
            raise ScenarioError(f"environment.noise_scale must be >= 0, got {self.noise_scale!r}")
        if len(self.wind_force_ned_n) != 3 or not all(math.isfinite(v) for v in self.wind_force_ned_n):
            raise ScenarioError(f"environment.wind_force_ned_n must be three finite numbers N, E, D, got {self.wind_force_ned_n!r}")
        if not (math.isfinite(self.gust_std_n) and self.gust_std_n >= 0.0):
            raise ScenarioError(f"environment.gust_std_n must be >= 0 N, got {self.gust_std_n!r}")
        if not (math.isfinite(self.gust_tau_s) and self.gust_tau_s > 0.0):
            raise ScenarioError(f"environment.gust_tau_s must be > 0 s, got {self.gust_tau_s!r}")

    @property
    def noise_std(self) -> tuple[float, float, float, float]:
        """1-sigma noise (attitude rad, body rate rad/s, position m, velocity m/s); zeros without noise."""
        if not self.noise:
            return (0.0, 0.0, 0.0, 0.0)
        k = self.noise_scale
        a, b, c, d = DEFAULT_NOISE_STD
        return (a * k, b * k, c * k, d * k)


@dataclass(frozen=True)
class Scenario:
    """Everything that decides a flight (see the module docstring for the TOML form)."""

    name: str = "scenario"
    description: str = ""
    #: simulated seconds to fly.
    duration_s: float = 30.0
    #: seed of the simulator's noise and gust streams.
    seed: int = 0
    #: the vehicle's parameters.
    vehicle: VehicleParams = DEFAULT_VEHICLE
    #: where the vehicle came from (a TOML file), None for the defaults or inline keys.
    vehicle_file: Path | None = None
    #: simulated vehicle: "rigid-body" (6-DOF, motor lag, limits, drag) or "paper".
    plant: str = "rigid-body"
    environment: EnvironmentSpec = field(default_factory=EnvironmentSpec)
    #: control law: adaptive_pid_smc, pid_smc or cascade_pid.
    controller: str = "adaptive_pid_smc"
    #: FC control rate, Hz (= the simulator's state rate).
    rate_hz: float = 500.0
    #: physics rate, Hz (a whole multiple of ``rate_hz``).
    physics_hz: float = 1000.0
    #: home (lat_deg, lon_deg, alt_m) of the local frame; None: the FC's default.
    home: tuple[float, float, float] | None = None
    #: FC parameter values by name (applied over the defaults, as PARAM_SET would).
    params: tuple[tuple[str, float], ...] = ()
    #: the timed plan, executed by the FC in simulated time.
    plan: tuple[PlanStep, ...] = ()
    #: timed faults, acted out by the simulator in simulated time (``[[fault]]`` tables).
    faults: tuple[FaultSpec, ...] = ()
    #: impairment of the simulator <-> FC link (``[link] sim``), seeded from ``seed`` unless it has its own.
    sim_link: LinkImpairment = field(default_factory=LinkImpairment)
    #: impairment of the FC's ground link (``[link] gcs``).
    gcs_link: LinkImpairment = field(default_factory=LinkImpairment)
    #: many vehicles (``[swarm]``, :mod:`smcpilot.swarm`); None: one vehicle.
    swarm: SwarmSpec | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ScenarioError(f"name must be a non-empty string, got {self.name!r}")
        if not (isinstance(self.duration_s, (int, float)) and math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ScenarioError(f"duration_s must be > 0 simulated seconds, got {self.duration_s!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ScenarioError(f"seed must be a whole number >= 0, got {self.seed!r}")
        if self.plant not in PLANTS:
            raise ScenarioError(f"vehicle.plant must be one of {', '.join(PLANTS)}, got {self.plant!r}")
        problem = law_reference_problem(self.controller)
        if problem:
            raise ScenarioError(f"fc.controller: {problem}")
        # a law file named relative to the working directory: absolute, so that the FC process and
        # campaign workers (other directories) find it too (a scenario file's are made relative to it)
        object.__setattr__(self, "controller", normalise_reference(self.controller))
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 1000):
            raise ScenarioError(f"fc.rate_hz must lie in (0, 1000] Hz, got {self.rate_hz!r}")
        ratio = self.physics_hz / self.rate_hz if math.isfinite(self.physics_hz) and self.physics_hz > 0 else 0.0
        if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
            raise ScenarioError(
                f"sim.physics_hz ({self.physics_hz!r}) must be a whole multiple of fc.rate_hz ({self.rate_hz!r})"
            )
        if self.home is not None:
            if len(self.home) != 3 or not all(math.isfinite(v) for v in self.home):
                raise ScenarioError(f"fc.home must be [lat_deg, lon_deg, alt_m], got {self.home!r}")
            if not (-90.0 <= self.home[0] <= 90.0 and -180.0 <= self.home[1] <= 180.0):
                raise ScenarioError(f"fc.home latitude/longitude out of range: {self.home!r}")
        for name, value in self.params:
            if not isinstance(name, str) or not name:
                raise ScenarioError(f"fc.params: parameter names must be strings, got {name!r}")
            if not math.isfinite(value):
                raise ScenarioError(f"fc.params.{name} must be a finite number, got {value!r}")
        if not isinstance(self.faults, tuple):
            raise ScenarioError(f"faults must be a tuple of FaultSpec, got {type(self.faults).__name__}")
        for i, f in enumerate(self.faults):
            if not isinstance(f, FaultSpec):
                raise ScenarioError(f"fault[{i + 1}] must be a FaultSpec, got {f!r}")

    # -- derived ----------------------------------------------------------------------------------
    @property
    def n_ticks(self) -> int:
        """Control ticks of a full flight: t = 0, one period, ..., ``duration_s`` (both ends)."""
        return int(round(self.duration_s * self.rate_hz)) + 1

    @property
    def count(self) -> int:
        """How many vehicles fly this scenario (1 without a ``[swarm]`` table)."""
        return self.swarm.count if self.swarm is not None else 1

    def fleet(self) -> tuple[FleetVehicle, ...]:
        """Every vehicle's own flight: its system id, spawn and one-vehicle scenario (no ``swarm``).

        Without a ``[swarm]`` table, the one vehicle is this scenario itself (system id 1).
        Raises :class:`ScenarioError` naming the vehicle table and key that cannot fly.
        """
        if self.swarm is None:
            return (FleetVehicle(0, 1, (0.0, 0.0), self),)
        spec = self.swarm
        try:
            sysids = spec.sysids()
            swarm_home = Home(*self.home) if self.home is not None else Home()
            out = []
            for i, sid in enumerate(sysids):
                table = spec.vehicles[i] if i < len(spec.vehicles) else {}
                spawn = spawn_point(swarm_home, i, spec, table)
                changes: dict[str, Any] = {"swarm": None, "name": f"{self.name}-v{sid}", "seed": self.seed + SEED_STEP * i}
                if spawn.offset_ne_m != (0.0, 0.0) or "home" in table:
                    changes["home"] = (spawn.home.lat_deg, spawn.home.lon_deg, spawn.home.alt_m)
                changes.update(_vehicle_changes(self, i, table))
                out.append(FleetVehicle(i, sid, spawn.offset_ne_m, replace(self, **changes)))
        except ConfigError as exc:
            raise ScenarioError(str(exc)) from None
        return tuple(out)

    def with_changes(self, **changes: Any) -> Scenario:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)

    # -- TOML -------------------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path: str | Path) -> Scenario:
        p = Path(path)
        return cls.from_mapping(read_toml(p, ScenarioError, "scenario"), source=str(p), base_dir=p.parent)

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], *, source: str = "scenario", base_dir: Path | None = None) -> Scenario:
        """Build from a parsed TOML document; relative paths resolve against ``base_dir``."""
        try:
            return _parse(doc, source, base_dir)
        except ConfigError as exc:  # also a vehicle file's or a plan's own error
            msg = str(exc)
            raise ScenarioError(msg if msg.startswith(source) else f"{source}: {msg}") from None

    def to_mapping(self) -> dict[str, Any]:
        """The TOML document (as a dict) that :meth:`from_mapping` reads back to an equal scenario."""
        env = self.environment
        vehicle: dict[str, Any] = {"plant": self.plant}
        if self.vehicle != DEFAULT_VEHICLE:
            vehicle.update(self.vehicle.to_dict())
        fc: dict[str, Any] = {"controller": self.controller, "rate_hz": self.rate_hz}
        if self.home is not None:
            fc["home"] = list(self.home)
        if self.params:
            fc["params"] = dict(self.params)
        doc: dict[str, Any] = {
            "name": self.name,
            "description": self.description,
            "duration_s": self.duration_s,
            "seed": self.seed,
            "vehicle": vehicle,
            "environment": {
                "noise": env.noise,
                "noise_scale": env.noise_scale,
                "wind_force_ned_n": list(env.wind_force_ned_n),
                "gust_std_n": env.gust_std_n,
                "gust_tau_s": env.gust_tau_s,
                "paper_disturbance": env.paper_disturbance,
            },
            "fc": fc,
            "sim": {"physics_hz": self.physics_hz},
        }
        if self.plan:
            doc["step"] = [
                {k: v for k, v in (("t_s", s.t_s), ("action", s.action), ("north_m", s.north_m), ("east_m", s.east_m),
                                   ("alt_m", s.alt_m), ("yaw_deg", s.yaw_deg)) if v is not None}  # fmt: skip
                for s in self.plan
            ]
        links = {k: v.to_mapping() for k, v in (("sim", self.sim_link), ("gcs", self.gcs_link)) if v != LinkImpairment()}
        if links:
            doc["link"] = links
        if self.faults:
            doc["fault"] = [f.to_mapping() for f in self.faults]
        if self.swarm is not None:
            doc["swarm"] = self.swarm.to_mapping()
        return doc

    def to_toml(self) -> str:
        """TOML text that :meth:`from_toml` reads back to an equal scenario (vehicle inline)."""
        return dumps_toml(self.to_mapping())

    def save(self, path: str | Path) -> Path:
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(self.to_toml(), encoding="utf-8")
        return p


# -- parsing ---------------------------------------------------------------------------------------
_TOP = {"name", "description", "duration_s", "seed", "vehicle", "environment", "fc", "sim", "step", "plan", "fault", "link",
        "swarm"}  # fmt: skip
_ENV_KEYS = {f.name for f in fields(EnvironmentSpec)}
_FC_KEYS = {"controller", "rate_hz", "home", "params"}
_SIM_KEYS = {"physics_hz"}


def _table(doc: Mapping[str, Any], key: str) -> dict[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise ScenarioError(f"[{key}] must be a table, got {value!r}")
    return value


def _check(table: Mapping[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise ScenarioError(f"unknown key {where}{unknown[0]!r} (known: {', '.join(sorted(known))})")


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{key} must be a number, got {value!r}")
    return float(value)


def _numbers(value: Any, n: int, key: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise ScenarioError(f"{key} must be a list of {n} numbers, got {value!r}")
    return tuple(_number(v, key) for v in value)


def _bool(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise ScenarioError(f"{key} must be true or false, got {value!r}")
    return value


def _parse(doc: Mapping[str, Any], source: str, base_dir: Path | None) -> Scenario:
    _check(doc, _TOP, "")
    kw: dict[str, Any] = {}
    if "name" in doc:
        kw["name"] = doc["name"]
    elif source != "scenario":
        kw["name"] = Path(source).stem
    if "description" in doc:
        if not isinstance(doc["description"], str):
            raise ScenarioError(f"description must be a string, got {doc['description']!r}")
        kw["description"] = doc["description"]
    if "duration_s" in doc:
        kw["duration_s"] = _number(doc["duration_s"], "duration_s")
    if "seed" in doc:
        kw["seed"] = doc["seed"]

    veh = _table(doc, "vehicle")
    vkeys = dict(veh)
    if "plant" in vkeys:
        kw["plant"] = vkeys.pop("plant")
    vfile = vkeys.pop("file", None)
    if vfile is not None:
        if not isinstance(vfile, str):
            raise ScenarioError(f"vehicle.file must be a path string, got {vfile!r}")
        vpath = Path(vfile)
        if base_dir is not None and not vpath.is_absolute():
            vpath = base_dir / vpath
        vehicle = VehicleParams.from_toml(vpath)
        kw["vehicle_file"] = vpath
    else:
        vehicle = DEFAULT_VEHICLE
    if vkeys:
        vehicle = VehicleParams.from_mapping({**vehicle.to_dict(), **vkeys}, source="[vehicle]")
        kw["vehicle_file"] = None
    kw["vehicle"] = vehicle

    env = _table(doc, "environment")
    _check(env, _ENV_KEYS, "environment.")
    ekw: dict[str, Any] = {}
    for key, value in env.items():
        where = f"environment.{key}"
        if key in ("noise", "paper_disturbance"):
            ekw[key] = _bool(value, where)
        elif key == "wind_force_ned_n":
            ekw[key] = _numbers(value, 3, where)
        else:
            ekw[key] = _number(value, where)
    kw["environment"] = EnvironmentSpec(**ekw)

    fc = _table(doc, "fc")
    _check(fc, _FC_KEYS, "fc.")
    if "controller" in fc:
        kw["controller"] = fc["controller"]
        if isinstance(fc["controller"], str) and base_dir is not None:
            kw["controller"] = normalise_reference(fc["controller"], base_dir)  # a law file beside the scenario
    if "rate_hz" in fc:
        kw["rate_hz"] = _number(fc["rate_hz"], "fc.rate_hz")
    if "home" in fc:
        kw["home"] = _numbers(fc["home"], 3, "fc.home")
    if "params" in fc:
        params = fc["params"]
        if not isinstance(params, dict):
            raise ScenarioError(f"fc.params must be a table of NAME = value, got {params!r}")
        kw["params"] = tuple((str(k), _number(v, f"fc.params.{k}")) for k, v in params.items())

    sim = _table(doc, "sim")
    _check(sim, _SIM_KEYS, "sim.")
    if "physics_hz" in sim:
        kw["physics_hz"] = _number(sim["physics_hz"], "sim.physics_hz")

    link = _table(doc, "link")
    _check(link, {"sim", "gcs"}, "link.")
    try:
        for key in ("sim", "gcs"):
            if key in link:
                kw[f"{key}_link"] = LinkImpairment.from_mapping(link[key], f"link.{key}")
    except ImpairmentError as exc:
        raise ScenarioError(str(exc)) from None

    if "plan" in doc and "step" in doc:
        raise ScenarioError("give either plan = \"FILE\" or [[step]] tables, not both")
    try:
        if "step" in doc:
            kw["plan"] = parse_plan({"step": doc["step"]}, "[[step]]")
        elif "plan" in doc:
            ppath = doc["plan"]
            if not isinstance(ppath, str):
                raise ScenarioError(f"plan must be a path string, got {ppath!r}")
            pp = Path(ppath)
            kw["plan"] = load_plan(base_dir / pp if base_dir is not None and not pp.is_absolute() else pp)
    except PlanError as exc:
        raise ScenarioError(str(exc)) from None
    if "fault" in doc:
        tables = doc["fault"]
        if not isinstance(tables, list):
            raise ScenarioError(f"fault must be [[fault]] tables, got {tables!r}")
        kw["faults"] = tuple(FaultSpec.from_mapping(t, f"fault[{i + 1}]") for i, t in enumerate(tables))
    if "swarm" in doc:
        swarm = SwarmSpec.from_mapping(doc["swarm"])
        kw["swarm"] = replace(swarm, vehicles=tuple(_resolve_paths(t, base_dir) for t in swarm.vehicles))
    scenario = Scenario(**kw)
    scenario.fleet()  # every vehicle's flight checked now (its key named), not when it is launched
    return scenario


@dataclass(frozen=True)
class FleetVehicle:
    """One vehicle of a scenario: its index (0-based), system id, spawn offset from the swarm's
    home (north, east, m) and its own one-vehicle :class:`Scenario`."""

    index: int
    sysid: int
    offset_ne_m: tuple[float, float]
    scenario: Scenario


def _resolve_paths(table: Mapping[str, Any], base_dir: Path | None) -> dict[str, Any]:
    """A [[swarm.vehicle]] table with its file names (plan, vehicle, a law file) made absolute."""
    out = dict(table)
    if base_dir is None:
        return out
    for key in ("plan", "vehicle"):
        v = out.get(key)
        if isinstance(v, str) and not Path(v).is_absolute():
            out[key] = str(base_dir / v)
    if isinstance(out.get("controller"), str):
        out["controller"] = normalise_reference(out["controller"], base_dir)
    return out


def _vehicle_changes(base: Scenario, i: int, table: Mapping[str, Any]) -> dict[str, Any]:
    """The fields a [[swarm.vehicle]] table changes in the scenario's flight."""
    where = f"swarm.vehicle[{i + 1}]"
    kw: dict[str, Any] = {}
    if "seed" in table:
        seed = table["seed"]
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ScenarioError(f"{where}.seed must be a whole number >= 0, got {seed!r}")
        kw["seed"] = seed
    if "controller" in table:
        kw["controller"] = table["controller"]
    if "params" in table:
        params = table["params"]
        if not isinstance(params, dict):
            raise ScenarioError(f"{where}.params must be a table of NAME = value, got {params!r}")
        merged = dict(base.params)
        merged.update((str(k), _number(v, f"{where}.params.{k}")) for k, v in params.items())
        kw["params"] = tuple(merged.items())
    if "vehicle" in table:
        vfile = table["vehicle"]
        if not isinstance(vfile, str):
            raise ScenarioError(f"{where}.vehicle must be a vehicle TOML file, got {vfile!r}")
        kw["vehicle"] = VehicleParams.from_toml(vfile)
        kw["vehicle_file"] = Path(vfile)
    if "plan" in table and "step" in table:
        raise ScenarioError(f"{where}: give either plan = \"FILE\" or [[swarm.vehicle.step]] tables, not both")
    try:
        if "step" in table:
            kw["plan"] = parse_plan({"step": table["step"]}, f"{where}.step")
        elif "plan" in table:
            if not isinstance(table["plan"], str):
                raise ScenarioError(f"{where}.plan must be a path string, got {table['plan']!r}")
            kw["plan"] = load_plan(Path(table["plan"]))
    except PlanError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    if "fault" in table:
        tables = table["fault"]
        if not isinstance(tables, list):
            raise ScenarioError(f"{where}.fault must be [[swarm.vehicle.fault]] tables, got {tables!r}")
        kw["faults"] = base.faults + tuple(FaultSpec.from_mapping(t, f"{where}.fault[{k + 1}]") for k, t in enumerate(tables))
    return kw


# -- a small TOML writer for the documents above ----------------------------------------------------
def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def toml_string(text: str) -> str:
    """A TOML basic string (JSON's escapes, plus DEL, which TOML forbids raw)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _key(k: str) -> str:
    return k if k.isascii() and k.replace("_", "").replace("-", "").isalnum() else toml_string(k)


def dumps_toml(doc: Mapping[str, Any]) -> str:
    """TOML text of a document of scalars, lists, inline tables, tables and arrays of tables."""
    lines: list[str] = []
    tables: list[tuple[str, Mapping[str, Any]]] = []
    arrays: list[tuple[str, list[Mapping[str, Any]]]] = []
    for k, v in doc.items():
        if isinstance(v, dict) and k != "params":
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            arrays.append((k, v))
        else:
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, t in tables:
        lines += ["", f"[{_key(k)}]"] + [f"{_key(a)} = {_value(b)}" for a, b in t.items()]
    for k, items in arrays:
        for t in items:
            lines += ["", f"[[{_key(k)}]]"] + [f"{_key(a)} = {_value(b)}" for a, b in t.items()]
    return "\n".join(lines) + "\n"
