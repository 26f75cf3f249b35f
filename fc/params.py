"""The parameter table: every tunable of the flight controller, by MAVLink parameter name.

Each :class:`ParamSpec` says the name (at most 16 characters), unit, range, default, whether it
needs a restart, and how it reads from and writes into :class:`fc.config.FcConfig` — the one place
the values live. :class:`ParamStore` applies a change by building a new (validated) config, and
persists accepted changes atomically to a ``.parm`` file (``NAME VALUE`` per line, the format
Mission Planner and MAVProxy read and write).

Two groups beside :class:`fc.config.FcConfig` (the block "Fault injection and the estimator"
below): :class:`FcOptions`, FC parameters of their own (``SYS_FAILURE_EN``, ``FS_POS_TMO``)
that persist like the others; and the simulator's ``SIM_*`` parameters
(:data:`smcpilot.faults.SIM_PARAMS`), listed after the FC's and forwarded to the simulator,
*volatile*: never written to the file nor loaded from it, at their defaults at every start.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from dataclasses import field as _field
from pathlib import Path
from typing import Any

from fc.config import FcConfig
from fc.control import registry
from fc.control.builtin import BUILTIN_LAWS
from fc.control.law import Law, LawParam
from fc.control.pid_smc import DISTURBANCE_ESTIMATES
from fc.estimate import EstimatorConfig
from fc.param_store import BackgroundWriter, atomic_write_text, clean_leftovers
from smcpilot.errors import ConfigError, InvalidGainError, ParamError
from smcpilot.faults import (
    MAX_DELAY_S,
    SENSOR_FAULT_PARAM,
    SIM_PARAM_INDEX,
    SIM_PARAMS,
    FaultError,
    check_sim_param,
    sensor_fault_from_params,
)
from smcpilot.limits import FENCE_ALT_MAX_RANGE_M, FENCE_RADIUS_RANGE_M
from smcpilot.protocol import FC_CONTROLLERS
from smcpilot.scenario import Scenario, ScenarioError


@dataclass(frozen=True)
class ParamSpec:
    name: str
    unit: str
    lo: float
    hi: float
    doc: str
    #: read from / write into :class:`fc.config.FcConfig` (or :class:`FcOptions` if ``options``).
    get: Callable[[Any], float]
    set: Callable[[Any, float], Any]
    is_int: bool = False
    restart: bool = False
    #: the value lives in :class:`FcOptions`, not in FcConfig.
    options: bool = False
    #: the control laws the parameter belongs to (none: the FC's own).
    laws: tuple[str, ...] = ()


_CHANNEL_TAGS = ("R", "P", "Y", "Z")
_CHANNEL_NAMES = ("roll φ", "pitch θ", "yaw ψ", "altitude z")
#: (param suffix, ChannelGains field, lo, hi, unit, description)
_GAIN_PARAMS = (
    ("C1", "c1", 0.0, 100.0, "1/s", "S = c1 e + c2 e': weight of the error"),
    ("C2", "c2", 0.01, 100.0, "", "S = c1 e + c2 e': weight of the error rate"),
    ("KP", "kp", 0.0, 100.0, "", "sigma = kp S + ki int S + kd S': proportional weight"),
    ("KI", "ki", 0.0, 100.0, "1/s", "sigma: integral weight"),
    ("KD", "kd", 0.01, 100.0, "s", "sigma: derivative weight"),
    ("KAPPA", "kappa", 0.0, 1000.0, "", "reaching term kappa sign(sigma)|sigma|^delta"),
    ("DELTA", "delta", 0.05, 0.95, "", "exponent of the reaching term, in (0, 1)"),
    ("NU", "nu", 0.0, 100.0, "1/s", "linear reaching term nu sigma"),
    ("CHI", "chi", 0.0, 100.0, "", "known disturbance bound chi (pid_smc controller)"),
    ("THETA", "adapt_rate", 0.0, 10.0, "", "adaptation rate Theta: d chi_hat/dt = Theta |sigma|"),
)


def _gain_get(i: int, field: str) -> Callable[[FcConfig], float]:
    return lambda c: float(getattr(c.gains[i], field))


def _gain_set(i: int, field: str) -> Callable[[FcConfig, float], FcConfig]:
    def setter(c: FcConfig, v: float) -> FcConfig:
        g = list(c.gains)
        g[i] = replace(g[i], **{field: v})
        return replace(c, gains=tuple(g))  # type: ignore[arg-type]

    return setter


def _attr(path: str, scale: float = 1.0, cast: Callable[[float], object] = float):
    """Getter/setter for ``field`` or ``sub.field`` of FcConfig, with a unit scale (param = value*scale)."""
    parts = path.split(".")

    def get(c: FcConfig) -> float:
        obj: object = c
        for p in parts:
            obj = getattr(obj, p)
        return float(obj) * scale  # type: ignore[arg-type]

    def set_(c: FcConfig, v: float) -> FcConfig:
        val: Any = cast(v / scale)
        if len(parts) == 1:
            return replace(c, **{parts[0]: val})
        sub = getattr(c, parts[0])
        return replace(c, **{parts[0]: replace(sub, **{parts[1]: val})})

    return get, set_


def _cascade_get(field: str, i: int) -> Callable[[FcConfig], float]:
    return lambda c: float(getattr(c.cascade, field)[i])


def _cascade_set(field: str, i: int) -> Callable[[FcConfig, float], FcConfig]:
    def setter(c: FcConfig, v: float) -> FcConfig:
        vals = list(getattr(c.cascade, field))
        vals[i] = v
        return replace(c, cascade=replace(c.cascade, **{field: tuple(vals)}))  # type: ignore[arg-type]

    return setter


def _dob_get(c: FcConfig) -> float:
    return -1.0 if c.disturbance_estimate == "auto" else float(DISTURBANCE_ESTIMATES.index(c.disturbance_estimate))


def _dob_set(c: FcConfig, v: float) -> FcConfig:
    return replace(c, disturbance_estimate="auto" if int(v) < 0 else DISTURBANCE_ESTIMATES[int(v)])


def _law_names() -> tuple[str, ...]:
    """The FC's law table: the built-ins, then the plug-ins loaded in this process."""
    return tuple(law.name for law in registry.flight_laws())


def _controller_get(c: FcConfig) -> float:
    names = _law_names()
    name = c.controller if c.controller in names else registry.resolve(c.controller).name
    return float(names.index(name))


def _controller_set(c: FcConfig, v: float) -> FcConfig:
    return replace(c, controller=_law_names()[int(v)])


def _controller_spec(names: tuple[str, ...]) -> ParamSpec:
    return ParamSpec("FC_CONTROLLER", "", 0.0, float(len(names) - 1),
                     "control law: " + ", ".join(f"{i} {n}" for i, n in enumerate(names)),
                     _controller_get, _controller_set, is_int=True, restart=True)  # fmt: skip


def _law_value_get(law: Law, lp: LawParam, name: str) -> Callable[[FcConfig], float]:
    default = law.param_value(law.default_params(), lp)

    def get(c: FcConfig) -> float:
        for n, v in c.law_values:
            if n == name:
                return float(v)
        return default

    return get


def _law_value_set(law: Law, lp: LawParam, name: str) -> Callable[[FcConfig, float], FcConfig]:
    default = law.param_value(law.default_params(), lp)

    def set_(c: FcConfig, v: float) -> FcConfig:
        values = dict(c.law_values)
        values[name] = float(v)
        if float(v) == default:
            del values[name]  # only values that differ are kept: a default set is the default config
        law.params_from_values(values)  # the law's own validation (LawError, a ConfigError, names it)
        return replace(c, law_values=tuple(sorted(values.items())))

    return set_


def law_param_specs(law: Law) -> tuple[ParamSpec, ...]:
    """The parameters of a law that keeps its values as MAVLink values (a plug-in, sign_smc)."""
    if law.params_of is not None:
        return ()
    return tuple(
        ParamSpec(name, lp.unit, lp.lo, lp.hi, lp.doc if lp.doc.startswith(law.name) else f"{law.name}: {lp.doc}", _law_value_get(law, lp, name), _law_value_set(law, lp, name),
                  is_int=lp.is_int, laws=(law.name,))  # fmt: skip
        for lp, name in zip(law.param_list(), law.param_names())
    )


def _build() -> tuple[ParamSpec, ...]:
    specs: list[ParamSpec] = []
    for i, (tag, cname) in enumerate(zip(_CHANNEL_TAGS, _CHANNEL_NAMES)):
        for suffix, field, lo, hi, unit, doc in _GAIN_PARAMS:
            specs.append(ParamSpec(f"SMC_{tag}_{suffix}", unit, lo, hi, f"{cname}: {doc}", _gain_get(i, field), _gain_set(i, field)))

    def add(name: str, path: str, lo: float, hi: float, unit: str, doc: str, scale: float = 1.0, *, is_int: bool = False,
            restart: bool = False, cast: Callable[[float], object] = float, laws: tuple[str, ...] = ()) -> None:  # fmt: skip
        get, set_ = _attr(path, scale, cast)
        specs.append(ParamSpec(name, unit, lo, hi, doc, get, set_, is_int=is_int, restart=restart, laws=laws))

    add("SMC_CHI0", "chi_hat0", 0.0, 100.0, "", "adaptive chi_hat(0) on every channel (applies at the next arming)")
    add("SMC_CHI_MIN", "adaptation.chi_hat_min", 0.0, 100.0, "", "chi_hat projection: lower bound")
    add("SMC_CHI_MAX", "adaptation.chi_hat_max", 0.0, 1000.0, "", "chi_hat projection: upper bound")
    add("SMC_CHI_DZ", "adaptation.dead_zone", 0.0, 10.0, "", "chi_hat grows only while |sigma| exceeds this dead zone")
    add("SMC_CHI_LEAK", "adaptation.leakage_per_s", 0.0, 10.0, "1/s", "sigma-modification pulling chi_hat back to chi_hat(0)")
    specs[:] = [replace(sp, laws=("adaptive_pid_smc", "pid_smc")) if sp.name.startswith("SMC_") else sp for sp in specs]
    # -- the disturbance observer, in front of any law ------------------------------------------------
    specs.append(
        ParamSpec("DOB_MODE", "", -1.0, float(len(DISTURBANCE_ESTIMATES) - 1),
                  "disturbance observer: -1 auto, " + ", ".join(f"{i} {n}" for i, n in enumerate(DISTURBANCE_ESTIMATES))
                  + " (auto: the law's default, input for the PID-SMC, none for the others; sigma and lumped hand the"
                  " estimate to the law, input cancels it at the law's output)",
                  _dob_get, _dob_set, is_int=True)
    )  # fmt: skip
    add("DOB_W", "dob_bandwidth_att_radps", 1.0, 200.0, "rad/s", "disturbance observer bandwidth, roll and pitch")
    add("DOB_WY", "dob_bandwidth_yaw_radps", 1.0, 200.0, "rad/s", "disturbance observer bandwidth, yaw")
    add("DOB_WZ", "dob_bandwidth_z_radps", 1.0, 100.0, "rad/s", "disturbance observer bandwidth, altitude")
    add("DOB_LAG", "dob_motor_lag", 0.0, 1.0, "", "1: the observer models the motors' lag (vehicle time constant)", is_int=True, cast=bool)

    # -- the cascaded PID (controller cascade_pid): ArduCopter's names, this project's units -------------
    for i, (tag, cname) in enumerate(zip(("RLL", "PIT", "YAW"), _CHANNEL_NAMES)):
        for pname, fname, hi, unit, doc in (
            (f"ATC_ANG_{tag}_P", "k_outer", 50.0, "1/s", "angle error -> rate command"),
            (f"ATC_RAT_{tag}_P", "k_inner", 500.0, "1/s", "rate error -> angular acceleration"),
            (f"ATC_RAT_{tag}_I", "ki_inner", 500.0, "1/s^2", "integral of the rate error -> angular acceleration"),
            (f"ATC_RAT_{tag}_D", "kd_rate", 10.0, "", "D on the low-passed measured rate (angular acceleration per angular acceleration)"),
            (f"ATC_RAT_{tag}_IMAX", "i_max", 1000.0, "rad/s^2", "largest |I term| (integrator clamp)"),
        ):
            specs.append(ParamSpec(pname, unit, 0.0, hi, f"cascade_pid {cname}: {doc}", _cascade_get(fname, i), _cascade_set(fname, i), laws=("cascade_pid",)))
    for pname, fname, hi, unit, doc in (
        ("PSC_POSZ_P", "k_outer", 50.0, "1/s", "altitude error -> climb-rate command"),
        ("PSC_VELZ_P", "k_inner", 200.0, "1/s", "climb-rate error -> vertical acceleration"),
        ("PSC_VELZ_I", "ki_inner", 200.0, "1/s^2", "integral of the climb-rate error -> vertical acceleration"),
        ("PSC_VELZ_IMAX", "i_max", 20.0, "m/s^2", "largest |I term| of the climb-rate loop (integrator clamp)"),
    ):
        specs.append(ParamSpec(pname, unit, 0.0, hi, f"cascade_pid altitude z: {doc}", _cascade_get(fname, 3), _cascade_set(fname, 3), laws=("cascade_pid",)))
    add("ATC_RAT_FLTD", "cascade.d_filter_hz", 0.0, 500.0, "Hz", "cascade_pid: low-pass of the rate D terms (0 off)", laws=("cascade_pid",))
    add("INS_GYRO_FILTER", "cascade.gyro_filter_hz", 0.0, 500.0, "Hz", "cascade_pid: low-pass of the rates its rate loops use (0 off)", laws=("cascade_pid",))
    # -------------------------------------------------------------------------------------------------------
    add("PSC_POS_KP", "position.kp_1ps2", 0.0, 20.0, "1/s^2", "position loop: gain on position error")
    add("PSC_VEL_KD", "position.kd_1ps", 0.0, 20.0, "1/s", "position loop: gain on velocity error")
    add("PSC_POS_KI", "position.ki_1ps3", 0.0, 5.0, "1/s^3", "position loop: integral gain")
    add("PSC_INT_MAX", "position.int_limit_mps2", 0.0, 10.0, "m/s^2", "position loop: largest integral contribution (the authority min(PSC_ACC_MAX, g tan PSC_TILT_MAX) if smaller)")
    add("PSC_ACC_MAX", "position.accel_max_mps2", 0.5, 20.0, "m/s^2", "position loop: largest horizontal acceleration demand")
    add("PSC_TILT_MAX", "position.tilt_max_rad", 5.0, 70.0, "deg", "largest commanded roll or pitch", scale=180.0 / math.pi)
    add("PSC_FILT_W", "pos_filter_omega_radps", 0.2, 10.0, "rad/s", "bandwidth of the position/altitude reference prefilters")
    add("PSC_SPD_XY", "speed_max_xy_mps", 0.1, 20.0, "m/s", "largest horizontal reference speed (DO_CHANGE_SPEED sets it too)")
    add("PSC_SPD_Z", "speed_max_z_mps", 0.1, 10.0, "m/s", "largest climb/descent reference speed")
    add("PSC_ACC_REF", "accel_ref_max_mps2", 0.1, 20.0, "m/s^2", "largest reference acceleration")
    add("ATT_FILT_W", "att_filter_omega_radps", 1.0, 100.0, "rad/s", "bandwidth of the roll/pitch reference prefilters")
    add("YAW_FILT_W", "yaw_filter_omega_radps", 0.1, 20.0, "rad/s", "bandwidth of the yaw reference prefilter")
    add("YAW_RATE_MAX", "yaw_rate_max_radps", 5.0, 360.0, "deg/s", "largest yaw reference rate", scale=180.0 / math.pi)
    add("LAND_SPD", "land_speed_mps", 0.1, 5.0, "m/s", "descent speed when landing")
    add("RTL_ALT_M", "rtl_alt_m", 0.5, 100.0, "m", "RTL climbs to at least this altitude above home first")
    add("WP_RADIUS_M", "wp_radius_m", 0.05, 20.0, "m", "waypoint acceptance radius")
    add("DISARM_DELAY", "disarm_delay_s", 0.0, 127.0, "s", "disarm after this long armed on the ground without take-off (0 off)")
    add("ARMING_CHECK", "arming_check", 0.0, 1.0, "", "1: pre-arm checks on; 0: skipped", is_int=True, cast=bool)
    add("FS_STATE_TMO", "failsafe_state_timeout_s", 0.02, 2.0, "s", "state older than this -> state-loss failsafe (real time)")
    add("FS_THR_FRAC", "failsafe_thrust_fraction", 0.5, 0.99, "", "open-loop thrust in a state-loss failsafe, x hover")
    add("FS_GCS_ENABLE", "fs_gcs_enable", 0.0, 2.0, "", "GCS-loss failsafe: 0 off, 1 RTL, 2 LAND", is_int=True, cast=int)
    add("FS_GCS_TIMEOUT", "fs_gcs_timeout_s", 1.0, 120.0, "s", "GCS-loss failsafe after this long without a GCS heartbeat (wall)")
    add("FS_WATCHDOG", "watchdog_s", 1.0, 600.0, "s", "stop when the simulator is silent this long (wall)")
    add("TELEM_RATE_HZ", "telemetry_rate_hz", 1.0, 50.0, "Hz", "rate of ATTITUDE, position and CHI/SIG telemetry")
    add("FC_RATE_HZ", "rate_hz", 50.0, 1000.0, "Hz", "control loop rate (must match the simulator's)", restart=True)
    specs.append(_controller_spec(FC_CONTROLLERS))
    add("FENCE_ENABLE", "fence_enable", 0.0, 1.0, "", "1: targets outside the geofence (FENCE_RADIUS, FENCE_ALT_MAX) are refused;"
        " 0: only the absolute limits hold (10 km, 500 m)", is_int=True, cast=bool)  # fmt: skip
    add("FENCE_RADIUS", "fence_radius_m", *FENCE_RADIUS_RANGE_M, "m", "geofence: largest horizontal distance of a target from home")
    add("FENCE_ALT_MAX", "fence_alt_max_m", *FENCE_ALT_MAX_RANGE_M, "m", "geofence: largest target altitude above home (take-off too)")
    add("SYSID_THISMAV", "system_id", 1.0, 255.0, "", "MAVLink system id", is_int=True, restart=True, cast=int)
    for law in BUILTIN_LAWS:
        specs.extend(law_param_specs(law))
    names = [s.name for s in specs]
    assert len(set(names)) == len(names) and all(len(n) <= 16 for n in names), names
    return tuple(specs)


# == Fault injection and the estimator ============================================================
# FC settings kept beside FcConfig (FcOptions), and the simulator's volatile SIM_* parameters.


@dataclass(frozen=True)
class FcOptions:
    """FC parameters outside :class:`fc.config.FcConfig`: failure injection and the estimator."""

    #: MAV_CMD_INJECT_FAILURE is carried out (True) or refused with DENIED (``SYS_FAILURE_EN``).
    failure_enabled: bool = False
    #: dead reckoning and the hold-point filter (``FS_POS_TMO`` is ``estimator.pos_timeout_s``).
    estimator: EstimatorConfig = _field(default_factory=EstimatorConfig)


def _failure_set(o: FcOptions, v: float) -> FcOptions:
    return replace(o, failure_enabled=bool(int(v)))


def _pos_tmo_set(o: FcOptions, v: float) -> FcOptions:
    return replace(o, estimator=replace(o.estimator, pos_timeout_s=float(v)))


_OPTION_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("SYS_FAILURE_EN", "", 0.0, 1.0, "1: MAV_CMD_INJECT_FAILURE is carried out; 0: refused (DENIED)",
              lambda o: float(o.failure_enabled), _failure_set, is_int=True, options=True),  # fmt: skip
    ParamSpec("FS_POS_TMO", "s", 0.0, 10.0, "position/velocity not measured: dead reckoning this long, then the state-loss failsafe",
              lambda o: float(o.estimator.pos_timeout_s), _pos_tmo_set, options=True),  # fmt: skip
)

#: the built-in parameter table (what ``docs/parameters.md`` and ``apm.pdef.xml`` list): the FC's own,
#: the built-in laws', the observer's; plug-in laws' parameters join it at run time (:func:`param_table`).
PARAMS: tuple[ParamSpec, ...] = _build() + _OPTION_PARAMS
PARAM_INDEX: dict[str, int] = {p.name: i for i, p in enumerate(PARAMS)}
assert len(PARAM_INDEX) == len(PARAMS) and not set(PARAM_INDEX) & set(SIM_PARAM_INDEX)


@dataclass(frozen=True)
class ParamTable:
    """Every FC parameter a ground station sees, in index order, then the simulator's ``SIM_*``."""

    specs: tuple[ParamSpec, ...]
    index: dict[str, int]

    @property
    def sim_offset(self) -> int:
        """Index of the first ``SIM_*`` parameter (they follow the FC's)."""
        return len(self.specs)

    @property
    def count(self) -> int:
        """Every parameter: the FC's, then the simulator's."""
        return len(self.specs) + len(SIM_PARAMS)


_TABLES: dict[tuple[str, ...], ParamTable] = {}


def param_table() -> ParamTable:
    """The parameter table of this process: the built-in one with ``FC_CONTROLLER`` ranging over the
    laws loaded so far, then each loaded plug-in law's parameters (in load order)."""
    plugins = registry.plugin_laws()
    key = tuple(law.name for law in plugins)
    table = _TABLES.get(key)
    if table is None:
        names = FC_CONTROLLERS + key
        specs = [(_controller_spec(names) if p.name == "FC_CONTROLLER" else p) for p in PARAMS]
        for law in plugins:
            for sp in law_param_specs(law):
                if sp.name in PARAM_INDEX or sp.name in SIM_PARAM_INDEX or any(q.name == sp.name for q in specs):
                    raise ParamError(f"law {law.name!r}: parameter {sp.name} is already taken; choose another prefix than {law.prefix}")
                specs.append(sp)
        table = ParamTable(tuple(specs), {p.name: i for i, p in enumerate(specs)})
        _TABLES[key] = table
    return table


#: the simulator's parameters follow the FC's in the parameter protocol (built-in table; with
#: plug-in laws loaded see :func:`param_table`).
SIM_PARAM_OFFSET = len(PARAMS)
#: every parameter a ground station sees: the FC's, then the simulator's (built-in table).
PARAM_COUNT = len(PARAMS) + len(SIM_PARAMS)


def is_sim_param(name: str) -> bool:
    """``name`` is one of the simulator's live ``SIM_*`` parameters."""
    return name in SIM_PARAM_INDEX


def spec(name: str) -> ParamSpec:
    table = param_table()
    try:
        return table.specs[table.index[name]]
    except KeyError:
        if name in SIM_PARAM_INDEX:
            raise ParamError(
                f"{name} is a live simulator parameter: set it with PARAM_SET while flying, or use a [[fault]] in a scenario"
            ) from None
        raise ParamError(f"unknown parameter {name!r}") from None


class ParamStore:
    """The live configuration and its parameter view; persists to ``path`` if given.

    ``config`` is what the FC runs; ``pending`` is what a restart would run (it differs only in
    parameters marked restart).
    """

    def __init__(self, config: FcConfig, path: Path | None = None, options: FcOptions | None = None) -> None:
        self.config = config
        self.pending = config
        self.path = path
        #: the FC parameters kept beside FcConfig (SYS_FAILURE_EN, FS_POS_TMO).
        self.options = options if options is not None else FcOptions()
        #: the simulator's SIM_* values as the FC last set or heard them (volatile: defaults at start).
        self.sim: dict[str, float] = {p.name: p.default for p in SIM_PARAMS}
        #: writes the file off the control loop once :meth:`start_writer` ran (None: synchronous).
        self.writer: BackgroundWriter | None = None
        #: a background write failed (the FC says so once; cleared by a later good write).
        self.write_errors: list[OSError] = []
        #: (pending config, options) as last written to disk (with the writer running).
        self._durable: tuple[FcConfig, FcOptions] = (config, self.options)

    def start_writer(self) -> None:
        """From now on, :meth:`set` applies at once and the file is written on a thread of its own
        (coalesced, atomic): the control loop never waits for the disk, and a change is acknowledged
        only once it is durable (:meth:`durable_acks`). :meth:`close` flushes."""
        if self.path is not None and self.writer is None:
            self._durable = (self.pending, self.options)
            self.writer = BackgroundWriter(self.path, _render_pair, self.write_errors.append)

    @property
    def acks_wait_for_disk(self) -> bool:
        """A change's acknowledgement waits until the file holding it is on disk (the writer runs)."""
        return self.writer is not None

    def durable_acks(self) -> list[tuple[Any, float, OSError | None]]:
        """The changes whose fate was decided since the last call, in order: ``(token, value, None)``
        when the file holding it is on disk (``value`` as written: a newer change may be in memory
        already), ``(token, value in force, error)`` when it could not be made durable: the change is
        then undone (back to the value last on disk). ``token`` is what :meth:`set` was given; its
        first item is the parameter's name."""
        if self.writer is None:
            return []
        out: list[tuple[Any, float, OSError | None]] = []
        for content, tokens, exc in self.writer.completed():
            if exc is None:
                assert isinstance(content, tuple)
                self._durable = content
                cfg, opts = content
                for tok in tokens:
                    p = spec(tok[0])  # type: ignore[index]
                    out.append((tok, float(p.get(opts if p.options else cfg)), None))
                continue
            dcfg, dopts = self._durable
            for tok in tokens:
                p = spec(tok[0])  # type: ignore[index]
                v = float(p.get(dopts if p.options else dcfg))
                if p.options:
                    self.options = p.set(self.options, v)
                else:
                    self.pending = p.set(self.pending, v)
                    if not p.restart:
                        self.config = p.set(self.config, v)
                out.append((tok, v, exc))
        return out

    def close(self) -> None:
        """Write what is pending and stop the writer thread (idempotent)."""
        if self.writer is not None:
            self.writer.close()

    def clean_leftovers(self) -> list[Path]:
        """Remove temporary files of interrupted writes of the parameter file; return them."""
        return clean_leftovers(self.path) if self.path is not None else []

    def differences(self) -> list[tuple[str, float, float]]:
        """(name, value, default) of every FC parameter that differs from its default, as the next
        start would run them (``pending``)."""
        d, o = FcConfig(), FcOptions()
        out = []
        for p in param_table().specs:
            v = p.get(self.options if p.options else self.pending)
            dv = p.get(o if p.options else d)
            if v != dv:
                out.append((p.name, v, dv))
        return out

    def value(self, name: str) -> float:
        """Current value (for restart parameters: the value the next start will use)."""
        p = spec(name)
        if p.options:
            return p.get(self.options)
        return p.get(self.pending if p.restart else self.config)

    def check_sim(self, name: str, value: float) -> float:
        """A SIM_* value validated (whole-number parameters rounded) with the others in force: a
        sensor fault's mode and value must make a valid fault together. ParamError with the reason."""
        try:
            v = check_sim_param(name, value)
        except FaultError as exc:
            raise ParamError(str(exc)) from None
        for sensor, mode_name in SENSOR_FAULT_PARAM.items():
            if name in (mode_name, mode_name + "_V"):
                mode = int(v if name == mode_name else self.sim[mode_name])
                val = v if name != mode_name else self.sim[mode_name + "_V"]
                try:
                    sensor_fault_from_params(sensor, mode, val)
                except FaultError:  # short reasons: one STATUSTEXT holds 50 characters
                    value_name = mode_name + "_V"
                    if mode == 3:
                        why = "noise std must be >= 0" if name == value_name else f"noise needs {value_name} >= 0"
                    elif mode == 5:
                        lim = f"[0, {MAX_DELAY_S:g}] s"
                        why = f"delay must lie in {lim}" if name == value_name else f"needs {value_name} in {lim}"
                    else:
                        why = f"not a valid {sensor} fault"
                    raise ParamError(f"{name} {v:g}: {why}") from None
        return v

    def set_sim(self, name: str, value: float) -> float:
        """Validate (:meth:`check_sim`) and record a SIM_* value; returns it (never persisted)."""
        v = self.check_sim(name, value)
        self.sim[name] = v
        return v

    def check(self, name: str, value: float) -> ParamSpec:
        p = spec(name)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ParamError(f"{name}: value must be a finite number, got {value!r}")
        if not p.lo <= value <= p.hi:
            raise ParamError(f"{name} out of range [{p.lo:g}, {p.hi:g}]: {value:g}")
        if p.is_int and value != int(value):
            raise ParamError(f"{name} must be a whole number, got {value:g}")
        return p

    def set(self, name: str, value: float, *, persist: bool = True, token: Any = None) -> FcConfig:
        """Validate and apply; return the new live config (unchanged for restart params). With the
        writer running, ``token`` (a tuple, the name first) comes back from :meth:`durable_acks`."""
        p = self.check(name, value)
        try:
            if p.options:
                self.options = p.set(self.options, float(value))
            elif p.restart:
                self.pending = p.set(self.pending, float(value))
            else:
                self.config = p.set(self.config, float(value))
                self.pending = p.set(self.pending, float(value))
        except (ConfigError, InvalidGainError, ValueError, IndexError) as exc:
            raise ParamError(f"{name} = {value:g} refused: {exc}") from None
        if persist and self.path is not None:
            self.save(token)
        return self.config

    def save(self, token: Any = None) -> None:
        """Write every parameter to the file atomically (temporary file, fsync, rename): handed
        to the writer thread if :meth:`start_writer` ran (returns at once), else here."""
        assert self.path is not None
        if self.writer is not None:
            self.writer.submit((self.pending, self.options), token)  # frozen values: safe to share
            return
        atomic_write_text(self.path, render_param_file(self.pending, self.options))

    def load(self) -> list[str]:
        """Apply the file's values (no save); return warnings (unknown names). Errors name the line."""
        assert self.path is not None
        warnings: list[str] = []
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return warnings
        except OSError as exc:
            raise ParamError(f"cannot read parameter file {self.path}: {exc.strerror or exc}") from None
        for lineno, raw in enumerate(text.splitlines(), start=1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.replace(",", " ").split()
            if len(parts) != 2:
                raise ParamError(f"{self.path}:{lineno}: expected 'NAME VALUE', got {raw!r}")
            name, text_value = parts
            try:
                value = float(text_value)
            except ValueError:
                raise ParamError(f"{self.path}:{lineno}: {name}: not a number: {text_value!r}") from None
            if name in SIM_PARAM_INDEX:
                warnings.append(f"{self.path}:{lineno}: {name} is a live simulator parameter, not loaded (volatile)")
                continue
            if name not in param_table().index:
                warnings.append(f"{self.path}:{lineno}: unknown parameter {name} ignored")
                continue
            try:
                self.set(name, value, persist=False)
            except ParamError as exc:
                raise ParamError(f"{self.path}:{lineno}: {exc}") from None
        # Restart parameters from the file apply now: this is the start.
        self.config = self.pending
        return warnings


def render_param_file(config: FcConfig, options: FcOptions) -> str:
    """The ``.parm`` text of ``config`` and ``options`` (``NAME VALUE`` per line; the simulator's
    SIM_* are volatile and never written)."""
    lines = ["# smcpilot flight-controller parameters (NAME VALUE); written by the FC on every change"]
    for p in param_table().specs:
        v = p.get(options if p.options else config)
        lines.append(f"{p.name} {int(v) if p.is_int else repr(float(v))}")
    return "\n".join(lines) + "\n"


def _render_pair(content: object) -> str:
    """The writer thread's renderer: ``content`` is the (config, options) pair :meth:`ParamStore.save` hands over."""
    assert isinstance(content, tuple) and len(content) == 2
    config: FcConfig = content[0]
    options: FcOptions = content[1]
    return render_param_file(config, options)


def defaults_table() -> list[dict[str, object]]:
    """Every FC parameter with its default, range, unit and description (docs, ``param list``)."""
    d = FcConfig()
    o = FcOptions()
    return [
        {"name": p.name, "default": p.get(o if p.options else d), "min": p.lo, "max": p.hi, "unit": p.unit,
         "restart": p.restart, "type": "int" if p.is_int else "float", "description": p.doc}  # fmt: skip
        for p in PARAMS
    ]



def apply_scenario(store: ParamStore, scenario: Scenario) -> FcConfig:
    """Start-up: the scenario's controller, rate and parameter values over what ``store`` holds
    (defaults, or a loaded parameter file); restart parameters apply at once. Errors name the key."""
    try:
        registry.resolve(scenario.controller)  # a plug-in's parameters join the table before they are set
    except ConfigError as exc:
        raise ScenarioError(f"fc.controller: {exc}") from None
    base: dict[str, Any] = {"controller": scenario.controller, "rate_hz": scenario.rate_hz}
    store.config = replace(store.config, **base)
    store.pending = replace(store.pending, **base)
    for name, value in scenario.params:
        if name in SIM_PARAM_INDEX:
            raise ScenarioError(f"fc.params.{name}: a live simulator parameter; give a scenario's faults as [[fault]] tables")
        try:
            store.set(name, value, persist=False)
        except ParamError as exc:
            raise ScenarioError(f"fc.params.{name}: {exc}") from None
    store.config = store.pending
    return store.config


def settings_for(scenario: Scenario) -> tuple[FcConfig, FcOptions]:
    """The FC configuration and options a scenario flies (defaults, then the scenario's settings),
    from one pass over them (:func:`config_for` and :func:`options_for` each make one)."""
    store = ParamStore(FcConfig())
    return apply_scenario(store, scenario), store.options


def config_for(scenario: Scenario) -> FcConfig:
    """The FC configuration a scenario flies (defaults, then the scenario's settings)."""
    return settings_for(scenario)[0]


def options_for(scenario: Scenario) -> FcOptions:
    """The :class:`FcOptions` a scenario flies (``SYS_FAILURE_EN``, ``FS_POS_TMO`` from its parameters)."""
    return settings_for(scenario)[1]


def param_messages(mav: Any, config: FcConfig, options: FcOptions | None = None) -> list[Any]:
    """``PARAM_VALUE`` of every parameter as ``config`` and ``options`` hold them, then the
    simulator's at their defaults (as every start has them): the FC logs them once at start,
    so a log says what configuration flew it (as ArduPilot's logs carry PARM records)."""
    opts = options if options is not None else FcOptions()
    out = []
    table = param_table()
    n = table.count
    for i, p in enumerate(table.specs):
        ptype = 6 if p.is_int else 9  # MAV_PARAM_TYPE_INT32 / REAL32
        out.append(mav.param_value_encode(p.name.encode(), float(p.get(opts if p.options else config)), ptype, n, i))
    for j, sp in enumerate(SIM_PARAMS):
        out.append(mav.param_value_encode(sp.name.encode(), float(sp.default), 6 if sp.is_int else 9, n, table.sim_offset + j))
    return out
