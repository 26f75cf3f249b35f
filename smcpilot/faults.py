"""Fault specifications and the live simulator parameters (``SIM_*``): the contract both processes share.

A :class:`FaultSpec` is one fault with a start and a stop in simulated time: a motor's thrust
efficiency, a sensor fault (stuck, bias, noise, dropout, delay), a step force or torque, a gust, or
the paper's sensor-failure disturbances. A scenario lists them as ``[[fault]]`` tables
(:mod:`smcpilot.scenario`); the simulator (:mod:`sim_bridge.faults`) evaluates them per physics step.

The same faults can be switched on live through the ``SIM_*`` parameters (:data:`SIM_PARAMS`): the
flight controller lists them with its own and forwards a ``PARAM_SET`` to the simulator's component
(:data:`smcpilot.protocol.SIM_COMPONENT_ID`) over the sim link; the simulator answers ``PARAM_VALUE``.
``SIM_ENGINE_MUL``/``SIM_ENGINE_FAIL`` are ArduPilot's names; the others are smcpilot's own.

Frames: every value given here is in MAVLink's frames (world NED, body FRD), as on the wire; the
simulator converts them with :mod:`smcpilot.frames`. Rotors are numbered as the vehicle's:
1 right, 2 front, 3 left, 4 rear.

TOML (inside a scenario; keys are the :class:`FaultSpec` field names; stop_s omitted = until the end)::

    [[fault]]
    kind = "motor"
    start_s = 10.0
    motor = 1
    efficiency = 0.7          # 0 = motor off

    [[fault]]
    kind = "sensor"
    start_s = 5.0
    stop_s = 5.5
    sensor = "position"       # gyro, accel, attitude, position, velocity
    mode = "dropout"          # stuck, bias, noise, dropout, delay
    # value = [0.1, 0.0, 0.0] # bias / noise std per axis (or one number for all); delay: seconds
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

from smcpilot.errors import ScenarioError

FAULT_KINDS = ("motor", "sensor", "force", "torque", "gust", "paper_disturbance")
SENSORS = ("gyro", "accel", "attitude", "position", "velocity")
SENSOR_MODES = ("stuck", "bias", "noise", "dropout", "delay")
#: Longest sensor delay the simulator keeps observations for, s.
MAX_DELAY_S = 5.0
#: Wire units of each sensor (bias, noise std), for messages.
SENSOR_UNITS = {"gyro": "rad/s", "accel": "m/s^2", "attitude": "rad", "position": "m", "velocity": "m/s"}


class FaultError(ScenarioError):
    """A fault specification or a ``SIM_*`` parameter value is invalid (the message names the item)."""


Vec3 = tuple[float, float, float]
_ZERO3: Vec3 = (0.0, 0.0, 0.0)

#: the fields each kind uses (beyond kind, start_s, stop_s).
KIND_FIELDS: dict[str, tuple[str, ...]] = {
    "motor": ("motor", "efficiency"),
    "sensor": ("sensor", "mode", "value"),
    "force": ("force_ned_n",),
    "torque": ("torque_frd_n_m",),
    "gust": ("force_std_n", "torque_std_n_m", "tau_s"),
    "paper_disturbance": (),
}


def _finite3(v: Any) -> bool:
    return isinstance(v, tuple) and len(v) == 3 and all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)


def _g(x: float) -> str:
    """A short number for messages (up to 3 significant digits)."""
    return f"{x:.3g}"


@dataclass(frozen=True)
class FaultSpec:
    """One fault, active for simulated time ``start_s <= t < stop_s``.

    Values are in MAVLink's wire frames (world NED, body FRD) and SI units named by the field.
    """

    kind: str
    #: simulated seconds from the start of the flight.
    start_s: float = 0.0
    #: simulated seconds; inf = until the end.
    stop_s: float = math.inf
    #: kind "motor": rotor 1..4 (1 right, 2 front, 3 left, 4 rear).
    motor: int = 0
    #: kind "motor": thrust factor 0..1 (0 = motor off); scales the rotor's thrust and its drag torque.
    efficiency: float = 1.0
    #: kind "sensor": one of :data:`SENSORS`.
    sensor: str = ""
    #: kind "sensor": one of :data:`SENSOR_MODES`.
    mode: str = ""
    #: kind "sensor": bias per axis in the sensor's wire frame (gyro rad/s FRD, accel m/s^2 NED,
    #: attitude rad roll/pitch/yaw FRD, position m NED, velocity m/s NED); noise: std per axis;
    #: delay: value[0] seconds; stuck, dropout: unused.
    value: Vec3 = _ZERO3
    #: kind "force": step force, world NED, N.
    force_ned_n: Vec3 = _ZERO3
    #: kind "torque": step torque, body FRD, N m.
    torque_frd_n_m: Vec3 = _ZERO3
    #: kind "gust": horizontal gust force std (each of N, E), N.
    force_std_n: float = 0.0
    #: kind "gust": gust torque std about each body axis, N m.
    torque_std_n_m: float = 0.0
    #: kind "gust": correlation time, s.
    tau_s: float = 1.0

    def __post_init__(self) -> None:
        problem = _problem(self)
        if problem is not None:
            raise FaultError(f"fault{'' if self.kind not in FAULT_KINDS else f' ({self.kind})'}: {problem}")

    # -- derived ----------------------------------------------------------------------------------
    @property
    def delay_s(self) -> float:
        """Kind "sensor", mode "delay": the delay, s."""
        return self.value[0]

    def active(self, t_s: float) -> bool:
        """Whether the fault acts at simulated time ``t_s`` (start inclusive, stop exclusive)."""
        return self.start_s <= t_s < self.stop_s

    def describe(self) -> str:
        """One line naming the fault as it starts, e.g. ``motor 1 at 70%`` (for STATUSTEXT and logs)."""
        k = self.kind
        if k == "motor":
            if self.efficiency == 0.0:
                return f"motor {self.motor} off"
            return f"motor {self.motor} at {self.efficiency * 100.0:.0f}%"
        if k == "sensor":
            unit = SENSOR_UNITS[self.sensor]
            if self.mode in ("stuck", "dropout"):
                return f"{self.sensor} {self.mode}"
            if self.mode == "delay":
                return f"{self.sensor} delay {_g(self.delay_s)} s"
            v = self.value
            num = _g(v[0]) if v[0] == v[1] == v[2] else ",".join(_g(x) for x in v)
            return f"{self.sensor} {self.mode} {num} {unit}"
        if k == "force":
            return "force " + ",".join(_g(x) for x in self.force_ned_n) + " N NED"
        if k == "torque":
            return "torque " + ",".join(_g(x) for x in self.torque_frd_n_m) + " Nm FRD"
        if k == "gust":
            return f"gust {_g(self.force_std_n)} N {_g(self.torque_std_n_m)} Nm tau {_g(self.tau_s)} s"
        return "paper disturbance"

    def describe_stop(self) -> str:
        """One line for the fault's end, e.g. ``motor 1 ok``."""
        k = self.kind
        if k == "motor":
            return f"motor {self.motor} ok"
        if k == "sensor":
            return f"{self.sensor} ok"
        if k == "paper_disturbance":
            return "paper disturbance off"
        return f"{k} off"

    # -- TOML -------------------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, d: Mapping[str, Any], where: str = "fault") -> FaultSpec:
        """Build from one ``[[fault]]`` table; errors start with ``where`` (e.g. ``fault[2] (motor): ...``).

        ``value`` may be one number (every axis) or a list of three; an omitted ``stop_s`` is inf.
        """
        if not isinstance(d, Mapping):
            raise FaultError(f"{where} must be a table, got {d!r}")
        kind = d.get("kind")
        if kind is None:
            raise FaultError(f"{where}: missing key 'kind' (one of {', '.join(FAULT_KINDS)})")
        if kind not in FAULT_KINDS:
            raise FaultError(f"{where}: unknown kind {kind!r} (known: {', '.join(FAULT_KINDS)})")
        label = f"{where} ({kind})"
        known = ("kind", "start_s", "stop_s") + KIND_FIELDS[kind]
        for key in d:
            if key not in known:
                other = [k for k, used in KIND_FIELDS.items() if key in used]
                hint = f" (it belongs to kind {other[0]!r})" if other else ""
                raise FaultError(f"{label}: unknown key {key!r}{hint}; known: {', '.join(known)}")
        kw: dict[str, Any] = {"kind": kind}
        for key, raw in d.items():
            if key == "kind":
                continue
            if key in ("sensor", "mode"):
                if not isinstance(raw, str):
                    raise FaultError(f"{label}: {key} must be a string, got {raw!r}")
                kw[key] = raw
            elif key == "motor":
                if isinstance(raw, bool) or not isinstance(raw, int):
                    raise FaultError(f"{label}: motor must be a whole number 1..4, got {raw!r}")
                kw[key] = raw
            elif key in ("value", "force_ned_n", "torque_frd_n_m"):
                if key == "value" and _is_number(raw):
                    kw[key] = (float(raw),) * 3
                elif isinstance(raw, (list, tuple)) and len(raw) == 3 and all(_is_number(x) for x in raw):
                    kw[key] = tuple(float(x) for x in raw)
                else:
                    what = "one number or a list of 3 numbers" if key == "value" else "a list of 3 numbers"
                    raise FaultError(f"{label}: {key} must be {what}, got {raw!r}")
            else:
                if not _is_number(raw):
                    raise FaultError(f"{label}: {key} must be a number, got {raw!r}")
                kw[key] = float(raw)
        try:
            return cls(**kw)
        except FaultError as exc:
            msg = str(exc)
            raise FaultError(where + msg[len("fault"):] if msg.startswith("fault") else f"{label}: {msg}") from None

    def to_mapping(self) -> dict[str, Any]:
        """The ``[[fault]]`` table :meth:`from_mapping` reads back to an equal spec (only this kind's keys)."""
        out: dict[str, Any] = {"kind": self.kind, "start_s": self.start_s}
        if not math.isinf(self.stop_s):
            out["stop_s"] = self.stop_s
        for name in KIND_FIELDS[self.kind]:
            v = getattr(self, name)
            out[name] = list(v) if isinstance(v, tuple) else v
        return out


def _is_number(x: Any) -> bool:
    return not isinstance(x, bool) and isinstance(x, (int, float))


def _problem(s: FaultSpec) -> str | None:
    """What is wrong with a spec (None: valid)."""
    if s.kind not in FAULT_KINDS:
        return f"unknown kind {s.kind!r} (known: {', '.join(FAULT_KINDS)})"
    if not (_is_number(s.start_s) and math.isfinite(s.start_s) and s.start_s >= 0.0):
        return f"start_s must be a finite number >= 0 s, got {s.start_s!r}"
    if not (_is_number(s.stop_s) and not math.isnan(s.stop_s)):
        return f"stop_s must be a number of seconds (or omitted: until the end), got {s.stop_s!r}"
    if s.stop_s <= s.start_s:
        return f"stop_s ({s.stop_s!r}) must be after start_s ({s.start_s!r})"
    k = s.kind
    if k == "motor":
        if isinstance(s.motor, bool) or not isinstance(s.motor, int) or not 1 <= s.motor <= 4:
            return f"motor must be 1..4 (1 right, 2 front, 3 left, 4 rear), got {s.motor!r}"
        if not (_is_number(s.efficiency) and 0.0 <= s.efficiency <= 1.0):
            return f"efficiency must lie in [0, 1], got {s.efficiency!r}"
    elif k == "sensor":
        if s.sensor not in SENSORS:
            return f"unknown sensor {s.sensor!r} (known: {', '.join(SENSORS)})"
        if s.mode not in SENSOR_MODES:
            return f"unknown mode {s.mode!r} (known: {', '.join(SENSOR_MODES)})"
        if not _finite3(s.value):
            return f"value must be 3 finite numbers, got {s.value!r}"
        if s.mode == "noise" and min(s.value) < 0.0:
            return f"value (noise std, {SENSOR_UNITS[s.sensor]}) must be >= 0, got {s.value!r}"
        if s.mode == "delay" and not 0.0 <= s.value[0] <= MAX_DELAY_S:
            return f"value (delay) must lie in [0, {MAX_DELAY_S:g}] s, got {s.value[0]!r}"
    elif k == "force":
        if not _finite3(s.force_ned_n):
            return f"force_ned_n must be 3 finite numbers N, E, D (N), got {s.force_ned_n!r}"
    elif k == "torque":
        if not _finite3(s.torque_frd_n_m):
            return f"torque_frd_n_m must be 3 finite numbers (N m, body FRD), got {s.torque_frd_n_m!r}"
    elif k == "gust":
        if not (_is_number(s.force_std_n) and math.isfinite(s.force_std_n) and s.force_std_n >= 0.0):
            return f"force_std_n must be a finite number >= 0 N, got {s.force_std_n!r}"
        if not (_is_number(s.torque_std_n_m) and math.isfinite(s.torque_std_n_m) and s.torque_std_n_m >= 0.0):
            return f"torque_std_n_m must be a finite number >= 0 N m, got {s.torque_std_n_m!r}"
        if not (_is_number(s.tau_s) and math.isfinite(s.tau_s) and s.tau_s > 0.0):
            return f"tau_s must be a finite number > 0 s, got {s.tau_s!r}"
    return None


FAULT_FIELDS = tuple(f.name for f in fields(FaultSpec))


# -- live simulator parameters ---------------------------------------------------------------------
class SimParam(NamedTuple):
    """One live simulator parameter (``PARAM_SET`` to the simulator's component)."""

    name: str
    default: float
    lo: float
    hi: float
    is_int: bool
    unit: str
    doc: str


#: sensor -> its SIM_*_FAULT parameter (the value parameter is that name + ``_V``).
SENSOR_FAULT_PARAM = {
    "gyro": "SIM_GYR_FAULT",
    "accel": "SIM_ACC_FAULT",
    "attitude": "SIM_ATT_FAULT",
    "position": "SIM_POS_FAULT",
    "velocity": "SIM_VEL_FAULT",
}
#: Range of every SIM_*_FAULT_V value parameter (its meaning depends on the mode).
FAULT_VALUE_LIMIT = 1000.0
_MODE_DOC = "0 none, 1 stuck, 2 bias, 3 noise, 4 dropout, 5 delay"


def _sensor_params() -> tuple[SimParam, ...]:
    out: list[SimParam] = []
    for sensor, name in SENSOR_FAULT_PARAM.items():
        unit = SENSOR_UNITS[sensor]
        out.append(SimParam(name, 0.0, 0.0, float(len(SENSOR_MODES)), True, "", f"{sensor} fault: {_MODE_DOC}"))
        out.append(SimParam(name + "_V", 0.0, -FAULT_VALUE_LIMIT, FAULT_VALUE_LIMIT, False, unit,
                            f"{sensor} fault value: bias ({unit}, every axis, wire frame) / noise std ({unit}) / delay (s)"))  # fmt: skip
    return tuple(out)


SIM_PARAMS: tuple[SimParam, ...] = (
    SimParam("SIM_ENGINE_MUL", 1.0, 0.0, 1.0, False, "", "thrust factor of the motors in SIM_ENGINE_FAIL"),
    SimParam("SIM_ENGINE_FAIL", 0.0, 0.0, 15.0, True, "", "bitmask of motors (bit0 = motor 1) SIM_ENGINE_MUL applies to"),
    SimParam("SIM_MOT_OFF", 0.0, 0.0, 15.0, True, "", "bitmask of motors stopped (bit0 = motor 1)"),
    *_sensor_params(),
    SimParam("SIM_DIST_FN", 0.0, -20.0, 20.0, False, "N", "step force north (world NED)"),
    SimParam("SIM_DIST_FE", 0.0, -20.0, 20.0, False, "N", "step force east (world NED)"),
    SimParam("SIM_DIST_FD", 0.0, -20.0, 20.0, False, "N", "step force down (world NED)"),
    SimParam("SIM_DIST_TX", 0.0, -2.0, 2.0, False, "N m", "step torque about body x (FRD)"),
    SimParam("SIM_DIST_TY", 0.0, -2.0, 2.0, False, "N m", "step torque about body y (FRD)"),
    SimParam("SIM_DIST_TZ", 0.0, -2.0, 2.0, False, "N m", "step torque about body z (FRD)"),
    SimParam("SIM_GUST_F", 0.0, 0.0, 10.0, False, "N", "horizontal gust force std (each of N, E)"),
    SimParam("SIM_GUST_T", 0.0, 0.0, 1.0, False, "N m", "gust torque std about each body axis"),
    SimParam("SIM_PAPER_DIST", 0.0, 0.0, 1.0, True, "", "the paper's sensor-failure disturbances on (1) / off (0)"),
)
SIM_PARAM_INDEX: dict[str, int] = {p.name: i for i, p in enumerate(SIM_PARAMS)}
#: Correlation time of the live gusts (SIM_GUST_F, SIM_GUST_T), s.
SIM_GUST_TAU_S = 1.0


def sim_param(name: str) -> SimParam:
    """The ``SIM_*`` parameter called ``name``; :class:`FaultError` for an unknown name."""
    try:
        return SIM_PARAMS[SIM_PARAM_INDEX[name]]
    except KeyError:
        raise FaultError(f"unknown simulator parameter {name!r} (known: {', '.join(SIM_PARAM_INDEX)})") from None


def check_sim_param(name: str, value: float) -> float:
    """``value`` validated for ``name`` (whole-number parameters rounded); :class:`FaultError` with the reason."""
    p = sim_param(name)
    v = float(value)
    if not math.isfinite(v):
        raise FaultError(f"{name} must be a finite number, got {v!r}")
    if p.is_int:
        v = float(round(v))
    if not p.lo <= v <= p.hi:
        raise FaultError(f"{name} out of range [{p.lo:g}, {p.hi:g}]: {value!r}")
    return v


def motor_efficiencies(engine_mul: float, engine_fail: int, mot_off: int) -> tuple[float, float, float, float]:
    """Per-rotor thrust factors (1..4) from SIM_ENGINE_MUL, SIM_ENGINE_FAIL and SIM_MOT_OFF."""
    out = []
    for i in range(4):
        bit = 1 << i
        out.append(0.0 if mot_off & bit else (engine_mul if engine_fail & bit else 1.0))
    return (out[0], out[1], out[2], out[3])


def sensor_fault_from_params(sensor: str, mode_number: int, value: float, start_s: float = 0.0) -> FaultSpec | None:
    """The sensor fault that ``SIM_<X>_FAULT = mode_number`` and ``SIM_<X>_FAULT_V = value`` describe.

    None for mode 0; :class:`FaultError` if the pair is not a valid fault (e.g. a negative noise std).
    Bias and noise apply ``value`` to every axis; delay takes ``value`` seconds.
    """
    if mode_number == 0:
        return None
    if not 1 <= mode_number <= len(SENSOR_MODES):
        raise FaultError(f"{SENSOR_FAULT_PARAM[sensor]} must be 0..{len(SENSOR_MODES)} ({_MODE_DOC}), got {mode_number!r}")
    mode = SENSOR_MODES[mode_number - 1]
    vec: Vec3 = (value, 0.0, 0.0) if mode == "delay" else (value, value, value)
    try:
        return FaultSpec("sensor", start_s=start_s, sensor=sensor, mode=mode, value=vec)
    except FaultError as exc:
        raise FaultError(f"{SENSOR_FAULT_PARAM[sensor]}_V = {value!r} with {mode}: {str(exc).split(': ', 1)[-1]}") from None
