"""The control-law interface: what a law is, what it replaces, what it takes and returns.

A law is a :class:`Law`: a name, the stage of the flight pipeline it replaces, a frozen validated
parameter class (every field a MAVLink parameter under the law's prefix), a function flattening
those parameters once into constants, and three **pure** functions of tuples and floats -- the
style of :func:`fc.control.pid_smc.pid_smc_step`, which the flight pipeline calls every tick and
a compiler such as numba's ``njit`` takes unchanged::

    initial_state(meas, k)                                  -> state
    step(meas, ref, state, dt_s, k, d_hat, u_prev)          -> (u, new_state, diag)            attitude stage
    step(meas, ref, state, dt_s, k, d_hat, u_prev)          -> (u, new_state, diag, att_ref)   full stage
    anti_windup(prev, new, u_law_realised, limited, k)      -> state

**Stages.** ``STAGE_ATTITUDE`` ("attitude"): the law replaces the paper's attitude/altitude stage,
below the shared position loop and reference prefilters. It sees

- ``meas`` (8 floats, paper frame, z up): ``(phi, phi', theta, theta', psi, psi', z, z')`` in
  rad, rad/s, m, m/s (Euler angles ZYX and their rates; psi unwrapped next to its reference);
- ``ref`` (16 floats): per channel (phi, theta, psi, z) the reference and its first three
  derivatives, channel-major.

``STAGE_FULL`` ("full"): the law replaces the position loop and the attitude stage (thrust and
torques from the position set-point, as geometric control does). It sees

- ``meas`` (12 floats, paper frame): ``(x, y, z, x', y', z', phi, theta, psi, phi', theta', psi')``;
- ``ref`` (16 floats): x, y, z and psi, each with its first three derivatives (the prefiltered
  position set-point: smooth, rate- and acceleration-limited), channel-major;

and also returns ``att_ref``, the (phi, theta) it commands, rad (telemetry and tracking metrics).

Both return ``u`` = (u_phi N, u_theta N, u_psi N m, u_z N), the paper's inputs (the torques are
l u_phi, l u_theta about x and y; u_z the total thrust), which the pipeline's priority mixer turns
into motor commands. ``d_hat`` is the disturbance observer's estimate (Euler-angle accelerations
phi'', theta'', psi'' in rad/s^2, not body axes; z'' in m/s^2) when it is
configured to hand it to the law (``DOB_MODE`` 1 or 2), zeros otherwise; ``u_prev`` the input the
motors realised over the previous tick, the law's own share (after the mixer's limits, without the
observer's compensation; zeros after arming) -- what an incremental law (INDI) increments.
``initial_state`` gets the measurement when the vehicle arms (or when the law takes over in flight).
A law with :attr:`Law.measures_accel` gets, after the 8 (12) floats of ``meas``, the measured
acceleration x'', y'', z'' (m/s^2, paper frame, gravity removed; NaN where the IMU gave none).
A whole-stack law's integrators are held (``anti_windup`` with every channel limited) in ALT_HOLD
and on the ground, where the pipeline gives it no horizontal correction to make. ``diag`` is four 4-tuples, ``(S, sigma,
chi_hat, u')`` in channel order, zeros where the law has no such quantity (:attr:`Law.diagnostics`
names those it has: they reach telemetry as ``SIG_*``, ``CHI_*``).

**Anti-windup** is offered to every law: when the mixer limits a channel, the pipeline calls
``anti_windup(prev, new, u_law_realised, limited, k)`` with the law's state before and after the
step, the share of the realised input that was the law's, and which channels were limited
(:func:`keep_new_state` is the law that wants none; :func:`hold_integrators` helps write one).

The constants ``k`` are whatever tuple ``consts(ctx, params)`` returns: floats, ints, bools and
tuples of them (no objects, no lists), flattened once at start-up and on a live parameter change.

A law that breaks these rules still flies, in CPython (:func:`fc.control.purity.law_problems` says
what breaks them; ``smcpilot laws`` shows it); one that raises or returns NaN in flight is caught by
the FC, which counts it and keeps the vehicle safe (:mod:`fc.flight`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from smcpilot.errors import ConfigError
from smcpilot.model import PaperModel
from smcpilot.vehicle import VehicleParams

STAGE_ATTITUDE = "attitude"
STAGE_FULL = "full"
STAGES = (STAGE_ATTITUDE, STAGE_FULL)
#: the diagnostics a law may report, in the order of its ``diag`` tuple.
DIAGNOSTICS = ("s", "sigma", "chi_hat", "u_dot")
#: longest MAVLink parameter name (PARAM_VALUE's param_id is 16 characters).
PARAM_NAME_MAX = 16
_PREFIX_RE = re.compile(r"^[A-Z][A-Z0-9]{0,7}$")
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
_ZERO4 = (0.0, 0.0, 0.0, 0.0)
#: ``diag`` of a law that reports none of :data:`DIAGNOSTICS`.
NO_DIAGNOSTICS = (_ZERO4, _ZERO4, _ZERO4, _ZERO4)


class LawError(ConfigError):
    """A control law cannot be loaded or registered (bad prefix, duplicate name, a parameter
    without a range, an import that failed); the message names the law."""


class LawFunctions(NamedTuple):
    """The three pure functions of a law, as the flight pipeline receives them (a NamedTuple of
    functions: numba specialises a compiled caller on it, as on any argument)."""

    initial_state: Callable[..., tuple]
    step: Callable[..., tuple]
    anti_windup: Callable[..., tuple]


@dataclass(frozen=True)
class LawContext:
    """What a law's constants may depend on besides its parameters."""

    #: the vehicle the FC was configured for (its nominal model: mass, inertia, arm, rotor limits).
    vehicle: VehicleParams
    #: the paper's nominal model of that vehicle (:mod:`smcpilot.model`).
    model: PaperModel
    #: the control rate, Hz.
    rate_hz: float
    #: the whole FC configuration (:class:`fc.config.FcConfig`): what the built-in laws read their
    #: parameters from; a plug-in law reads its own parameter class instead.
    config: Any = None


@dataclass(frozen=True)
class LawParam:
    """One parameter of a law: the MAVLink name is ``PREFIX_`` + :attr:`suffix`.

    ``field`` names the parameter-class field it reads and writes (``index`` the element of a
    tuple field; -1 for a plain number)."""

    suffix: str
    field: str
    lo: float
    hi: float
    unit: str
    doc: str
    index: int = -1
    is_int: bool = False


def param(default: float, *, lo: float, hi: float, unit: str = "", doc: str, name: str | None = None, is_int: bool = False) -> Any:
    """A plug-in law's parameter, as a dataclass field::

        @dataclass(frozen=True)
        class MyParams:
            kp: float = param(4.0, lo=0.0, hi=50.0, unit="1/s", doc="angle error -> rate")

    The MAVLink name is the law's prefix, ``_`` and ``name`` (default: the field name in upper case);
    the whole name has at most 16 characters, checked when the law is registered.
    """
    meta = {"smcpilot": {"lo": float(lo), "hi": float(hi), "unit": unit, "doc": doc, "name": name, "is_int": is_int}}
    return dataclasses.field(default=default, metadata=meta)


def params_from_fields(params_class: type) -> tuple[LawParam, ...]:
    """The :class:`LawParam` of every field of a parameter class declared with :func:`param`."""
    if not (isinstance(params_class, type) and dataclasses.is_dataclass(params_class)):
        raise LawError(f"parameter class {params_class!r} is not a dataclass")
    if not params_class.__dataclass_params__.frozen:  # type: ignore[attr-defined]
        raise LawError(f"parameter class {params_class.__name__} must be frozen (@dataclass(frozen=True))")
    out = []
    for f in dataclasses.fields(params_class):
        meta = f.metadata.get("smcpilot")
        if meta is None:
            raise LawError(f"parameter {params_class.__name__}.{f.name} has no range: declare it with fc.control.law.param(default, lo=, hi=, doc=)")
        out.append(LawParam(meta["name"] or f.name.upper(), f.name, meta["lo"], meta["hi"], meta["unit"], meta["doc"], -1, meta["is_int"]))
    return tuple(out)


def keep_new_state(prev: Sequence[float], new: tuple, u_realised: Sequence[float], limited: Sequence[bool], k: tuple) -> tuple:
    """The anti-windup of a law that wants none: the state the step computed."""
    return new


def hold_integrators(prev: Sequence[float], new: Sequence[float], limited: Sequence[bool]) -> tuple[float, float, float, float]:
    """The first four states as integrators of the four channels: those of ``limited`` channels
    keep their previous value (helper for a law's ``anti_windup``)."""
    return (
        prev[0] if limited[0] else new[0],
        prev[1] if limited[1] else new[1],
        prev[2] if limited[2] else new[2],
        prev[3] if limited[3] else new[3],
    )


@dataclass(frozen=True)
class Law:
    """A control law as the flight controller flies it. Build one, then register it: a package's
    entry point in the group ``smcpilot.laws``, or ``--controller path/to/file.py:NAME``.

    ``consts(ctx, params)`` flattens a :class:`LawContext` and an instance of ``params_class`` into
    the constants ``k`` the pure functions take. ``params_of(config)`` (built-in laws only) reads
    the law's parameter instance out of the FC configuration; a plug-in law's parameters live as
    MAVLink values and are built from ``params_class`` by the FC.
    """

    name: str
    stage: str
    #: MAVLink parameter prefix (upper case, at most 8 characters; names are PREFIX_SUFFIX).
    prefix: str
    description: str
    params_class: type
    consts: Callable[[LawContext, Any], tuple]
    initial_state: Callable[..., tuple]
    step: Callable[..., tuple]
    anti_windup: Callable[..., tuple] = keep_new_state
    #: names of the state tuple's entries (its length is the law's state length).
    state_names: tuple[str, ...] = ()
    #: which of :data:`DIAGNOSTICS` the law reports (the others are zeros in its diag).
    diagnostics: tuple[str, ...] = ()
    #: the MAVLink parameters (default: from ``params_class``'s :func:`param` fields).
    params: tuple[LawParam, ...] | None = None
    #: built-in laws: the parameter instance in an :class:`fc.config.FcConfig`.
    params_of: Callable[[Any], Any] | None = None
    #: the disturbance observer's mode when ``DOB_MODE`` is -1 ("auto"): "none", "sigma", "lumped" or
    #: "input" (:mod:`fc.control.observer`; the PID-SMC flies with "input", the baselines without).
    observer_default: str = "none"
    #: where it came from: "built-in", "entry point PKG", a file or a module (set on registration).
    origin: str = "built-in"
    #: documentation page or reference.
    reference: str = ""
    #: the law measures acceleration: its ``step`` gets ``meas`` with three more floats, the
    #: measured acceleration (x'', y'', z'': m/s^2, paper frame NWU, gravity removed) from the
    #: IMU's accelerometer and the attitude flown on, NaN when the IMU gave none this tick (a
    #: dropout, or a simulator that sends none). ``initial_state`` gets the state alone.
    measures_accel: bool = False

    @property
    def functions(self) -> LawFunctions:
        return LawFunctions(self.initial_state, self.step, self.anti_windup)

    @property
    def full_stack(self) -> bool:
        return self.stage == STAGE_FULL

    def param_list(self) -> tuple[LawParam, ...]:
        return self.params if self.params is not None else params_from_fields(self.params_class)

    def param_names(self) -> tuple[str, ...]:
        return tuple(f"{self.prefix}_{p.suffix}" for p in self.param_list())

    def default_params(self) -> Any:
        try:
            return self.params_class()
        except TypeError as exc:
            raise LawError(f"law {self.name!r}: its parameter class {self.params_class.__name__} needs a default for every field ({exc})") from None

    def params_from_values(self, values: Mapping[str, float]) -> Any:
        """The parameter instance with the MAVLink ``values`` given (full names) over the defaults."""
        base = self.default_params()
        changes: dict[str, Any] = {}
        for p, name in zip(self.param_list(), self.param_names()):
            if name in values:
                v = values[name]
                if p.index >= 0:
                    cur = list(changes.get(p.field, getattr(base, p.field)))
                    cur[p.index] = v
                    changes[p.field] = tuple(cur)
                else:
                    changes[p.field] = int(v) if p.is_int else float(v)
        try:
            return dataclasses.replace(base, **changes) if changes else base
        except Exception as exc:  # the parameter class's own validation: anyone's code
            raise LawError(f"law {self.name!r}: {exc}") from None

    def param_value(self, params: Any, p: LawParam) -> float:
        v = getattr(params, p.field)
        return float(v[p.index] if p.index >= 0 else v)


def validate_law(law: object, where: str = "") -> Law:
    """Check a law before registering it; LawError naming it (and ``where``) otherwise."""
    at = f" ({where})" if where else ""
    if not isinstance(law, Law):
        raise LawError(f"{where or repr(law)}: not a fc.control.law.Law but {type(law).__name__}")
    name = law.name
    if not (isinstance(name, str) and _NAME_RE.match(name)):
        raise LawError(f"law name {name!r}{at}: lower-case letters, digits and _ (at most 40), starting with a letter")
    if law.stage not in STAGES:
        raise LawError(f"law {name!r}{at}: stage must be {' or '.join(repr(s) for s in STAGES)}, got {law.stage!r}")
    if not (isinstance(law.prefix, str) and _PREFIX_RE.match(law.prefix)):
        raise LawError(f"law {name!r}{at}: parameter prefix {law.prefix!r} must be 1-8 upper-case letters or digits, starting with a letter")
    for fn_name in ("consts", "initial_state", "step", "anti_windup"):
        if not callable(getattr(law, fn_name)):
            raise LawError(f"law {name!r}{at}: {fn_name} is not a function")
    if law.observer_default not in ("none", "sigma", "lumped", "input"):
        raise LawError(f"law {name!r}{at}: observer_default must be none, sigma, lumped or input, got {law.observer_default!r}")
    bad = [d for d in law.diagnostics if d not in DIAGNOSTICS]
    if bad:
        raise LawError(f"law {name!r}{at}: unknown diagnostics {bad}; choose from {', '.join(DIAGNOSTICS)}")
    params = law.param_list()
    defaults = law.default_params()
    seen: set[str] = set()
    for p, full in zip(params, law.param_names()):
        if len(full) > PARAM_NAME_MAX:
            raise LawError(f"law {name!r}{at}: parameter name {full} is longer than {PARAM_NAME_MAX} characters (MAVLink's limit)")
        if not re.match(r"^[A-Z0-9_]+$", full):
            raise LawError(f"law {name!r}{at}: parameter name {full!r} must be upper-case letters, digits and _")
        if full in seen:
            raise LawError(f"law {name!r}{at}: parameter {full} declared twice")
        seen.add(full)
        if not (math.isfinite(p.lo) and math.isfinite(p.hi) and p.lo < p.hi):
            raise LawError(f"law {name!r}{at}: parameter {full} needs a finite range lo < hi, got [{p.lo}, {p.hi}]")
        try:
            v = law.param_value(defaults, p)
        except (AttributeError, IndexError, TypeError, ValueError):
            raise LawError(f"law {name!r}{at}: parameter {full} reads field {p.field!r}, which its parameter class does not have") from None
        if not (p.lo <= v <= p.hi):
            raise LawError(f"law {name!r}{at}: parameter {full} default {v:g} outside its range [{p.lo:g}, {p.hi:g}]")
    return law
