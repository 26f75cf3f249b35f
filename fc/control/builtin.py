"""The built-in laws, registered through the same :class:`fc.control.law.Law` interface a plug-in uses.

Each is the law module's pure functions behind the interface's signatures (:mod:`fc.control.law`):

- ``adaptive_pid_smc`` and ``pid_smc``: the paper's PID sliding-mode controller, adaptive
  (Theorem 2) or with the known bound chi (Theorem 1) -- :mod:`fc.control.pid_smc`;
- ``cascade_pid``: the cascaded PID most flight stacks fly -- :mod:`fc.control.cascade_pid`;
- ``sign_smc``: the paper's comparison, a conventional SMC whose sign(s) reaches the actuators --
  :mod:`fc.control.sign_smc`;
- ``se3_geometric``: geometric tracking control on SE(3) (Lee, Leok and McClamroch 2010), a
  whole-stack law -- :mod:`fc.control.geometric`, ``docs/geometric-control.md``;
- ``indi``: incremental nonlinear dynamic inversion (Smeur, Chu and de Croon 2016) --
  :mod:`fc.control.indi`, ``docs/indi.md``.

The PID-SMC and the cascade read their parameters from :class:`fc.config.FcConfig` (their MAVLink
names, ``SMC_*``, ``ATC_*``, ``PSC_*Z*``, are in :mod:`fc.params`); the sign-SMC's are declared on its
parameter class, as a plug-in's are (``SSMC_*``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fc.control.base import integrators_anti_windup
from fc.control.cascade_pid import (
    CascadePid,
    CascadePidConsts,
    CascadePidParams,
    cascade_pid_anti_windup,
    cascade_pid_consts,
    cascade_pid_step,
)
from fc.control.geometric import GEOMETRIC_FUNCTIONS, SE3_GEOMETRIC
from fc.control.indi import INDI, INDI_FUNCTIONS
from fc.control.law import STAGE_ATTITUDE, Law, LawContext, LawParam
from fc.control.pid_smc import (
    PidSmc,
    PidSmcConsts,
    PidSmcParams,
    pid_smc_anti_windup,
    pid_smc_consts,
    pid_smc_initial_state,
    pid_smc_integrate,
    pid_smc_law,
)
from fc.control.sign_smc import SignSmc, SignSmcConsts, SignSmcParams, sign_smc_consts, sign_smc_output
from smcpilot.protocol import FC_CONTROLLERS

_ZERO4 = (0.0, 0.0, 0.0, 0.0)
Vec4 = tuple[float, float, float, float]


# -- the PID-SMC ------------------------------------------------------------------------------------
def pid_smc_params_of(config: Any, adaptive: bool = True) -> PidSmcParams:
    """The PID-SMC's parameters as an :class:`fc.config.FcConfig` holds them."""
    c = config
    dob = "input" if c.disturbance_estimate == "auto" else c.disturbance_estimate
    return PidSmcParams(gains=c.gains, adaptive=adaptive, adaptation=c.adaptation, chi_hat0=(c.chi_hat0,) * 4,
                        disturbance_estimate=dob)  # type: ignore[arg-type]  # FcConfig validated it  # fmt: skip


def _known_bound_params_of(config: Any) -> PidSmcParams:
    return pid_smc_params_of(config, adaptive=False)


def _pid_smc_consts(ctx: LawContext, params: PidSmcParams) -> PidSmcConsts:
    return pid_smc_consts(ctx.model, params)


def pid_smc_flight_init(meas: Sequence[float], k: PidSmcConsts) -> tuple[float, ...]:
    """Initial state (12 floats): hover trim, chi_hat(0)."""
    return pid_smc_initial_state(meas, k)


def pid_smc_flight_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, k: PidSmcConsts, d_hat: Sequence[float], u_prev: Sequence[float]
) -> tuple[Vec4, tuple[float, ...], tuple[Vec4, Vec4, Vec4, Vec4]]:
    """One tick of the PID-SMC (u integrated by forward Euler, held); d_hat as ``SMC``'s DOB mode says."""
    s, sg, chi, ud, rate = pid_smc_law(meas, ref, state, k, _ZERO4, False, d_hat)
    new = pid_smc_integrate(state, s, ud, rate, dt_s, k)
    return (new[4], new[5], new[6], new[7]), new, (s, sg, chi, ud)


def pid_smc_flight_anti_windup(
    prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool], k: PidSmcConsts
) -> tuple[float, ...]:
    """Limited channels: u follows what was realised, int S and chi_hat hold."""
    return pid_smc_anti_windup(prev, new, u_realised, limited)


ADAPTIVE_PID_SMC = Law(
    name="adaptive_pid_smc", stage=STAGE_ATTITUDE, prefix="SMC",
    description="the paper's adaptive PID sliding-mode controller (Theorem 2), corrected; chi_hat adapts",
    params_class=PidSmcParams, consts=_pid_smc_consts,
    initial_state=pid_smc_flight_init, step=pid_smc_flight_step, anti_windup=pid_smc_flight_anti_windup,
    state_names=PidSmc.state_names, diagnostics=("s", "sigma", "chi_hat", "u_dot"), params=(),
    params_of=pid_smc_params_of, observer_default="input", reference="docs/pid-smc.md",
)  # fmt: skip

KNOWN_BOUND_PID_SMC = Law(
    name="pid_smc", stage=STAGE_ATTITUDE, prefix="SMC",
    description="the paper's PID sliding-mode controller with the known disturbance bound chi (Theorem 1)",
    params_class=PidSmcParams, consts=_pid_smc_consts,
    initial_state=pid_smc_flight_init, step=pid_smc_flight_step, anti_windup=pid_smc_flight_anti_windup,
    state_names=PidSmc.state_names, diagnostics=("s", "sigma", "chi_hat", "u_dot"), params=(),
    params_of=_known_bound_params_of, observer_default="input", reference="docs/pid-smc.md",
)  # fmt: skip


# -- the cascaded PID -------------------------------------------------------------------------------
def _cascade_params_of(config: Any) -> CascadePidParams:
    return config.cascade


def _cascade_consts(ctx: LawContext, params: CascadePidParams) -> CascadePidConsts:
    return cascade_pid_consts(ctx.model, params)


def cascade_flight_init(meas: Sequence[float], k: CascadePidConsts) -> tuple[float, ...]:
    """Integrators and D terms zero, the gyro low-passes at the measured rates."""
    return (0.0, 0.0, 0.0, 0.0, meas[1], meas[3], meas[5], 0.0, 0.0, 0.0)


def cascade_flight_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, k: CascadePidConsts, d_hat: Sequence[float], u_prev: Sequence[float]
) -> tuple[Vec4, tuple[float, ...], tuple[Vec4, Vec4, Vec4, Vec4]]:
    u, new = cascade_pid_step(meas, ref, state, dt_s, k)
    return u, new, (_ZERO4, _ZERO4, _ZERO4, _ZERO4)


def cascade_flight_anti_windup(
    prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool], k: CascadePidConsts
) -> tuple[float, ...]:
    return cascade_pid_anti_windup(prev, new, limited)


CASCADE_PID = Law(
    name="cascade_pid", stage=STAGE_ATTITUDE, prefix="ATC",
    description="cascaded PID as ArduCopter flies it: angle P -> rate PID with filters; altitude P -> climb PI",
    params_class=CascadePidParams, consts=_cascade_consts,
    initial_state=cascade_flight_init, step=cascade_flight_step, anti_windup=cascade_flight_anti_windup,
    state_names=CascadePid.state_names, diagnostics=(), params=(), params_of=_cascade_params_of,
    reference="docs/baselines.md",
)  # fmt: skip


# -- the sign-SMC of the paper's comparison ----------------------------------------------------------
def _sign_consts(ctx: LawContext, params: SignSmcParams) -> SignSmcConsts:
    return sign_smc_consts(ctx.model, params)


def sign_flight_init(meas: Sequence[float], k: SignSmcConsts) -> tuple[float, float, float, float]:
    return (0.0, 0.0, 0.0, 0.0)


def sign_flight_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, k: SignSmcConsts, d_hat: Sequence[float], u_prev: Sequence[float]
) -> tuple[Vec4, Vec4, tuple[Vec4, Vec4, Vec4, Vec4]]:
    u, e, sg = sign_smc_output(meas, ref, state, k)
    new = (state[0] + dt_s * e[0], state[1] + dt_s * e[1], state[2] + dt_s * e[2], state[3] + dt_s * e[3])
    return u, new, (_ZERO4, sg, _ZERO4, _ZERO4)


def sign_flight_anti_windup(
    prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool], k: SignSmcConsts
) -> Vec4:
    return integrators_anti_windup(prev, new, limited)


_TAGS = ("R", "P", "Y", "Z")
_CH = ("roll", "pitch", "yaw", "altitude")
_SIGN_PARAMS = tuple(
    LawParam(f"{tag}_{suffix}", field, lo, hi, unit, f"sign_smc {ch}: {doc}", i)
    for i, (tag, ch) in enumerate(zip(_TAGS, _CH))
    for suffix, field, lo, hi, unit, doc in (
        ("KP", "kp", 0.0, 100.0, "", "s = kp e + ki int e + kd e': proportional weight"),
        ("KI", "ki", 0.0, 100.0, "1/s", "s: integral weight"),
        ("KD", "kd", 0.01, 100.0, "s", "s: derivative weight"),
        ("ETA", "eta", 0.0, 100.0, "", "switching gain eta sign(s), in units of s'"),
        ("LAM", "lam", 0.0, 100.0, "1/s", "linear reaching gain lam s"),
    )
)

SIGN_SMC = Law(
    name="sign_smc", stage=STAGE_ATTITUDE, prefix="SSMC",
    description="the paper's comparison: conventional SMC on a PID surface, sign(s) acting directly on u (chatters)",
    params_class=SignSmcParams, consts=_sign_consts,
    initial_state=sign_flight_init, step=sign_flight_step, anti_windup=sign_flight_anti_windup,
    state_names=SignSmc.state_names, diagnostics=("sigma",), params=_SIGN_PARAMS, reference="docs/paper-reproduction.md",
)  # fmt: skip

#: the built-in laws in FC_CONTROLLER order (the parameter's values 0..5; smcpilot.protocol.FC_CONTROLLERS).
BUILTIN_LAWS: tuple[Law, ...] = (ADAPTIVE_PID_SMC, KNOWN_BOUND_PID_SMC, CASCADE_PID, SIGN_SMC, SE3_GEOMETRIC, INDI)

# smcpilot.protocol names them for the ground side, which imports no law: one order, checked here.
assert tuple(law.name for law in BUILTIN_LAWS) == FC_CONTROLLERS, "smcpilot.protocol.FC_CONTROLLERS and BUILTIN_LAWS differ"

#: the pure functions of the built-in laws' flight interface (checked and compiled by the tests).
BUILTIN_FLIGHT_FUNCTIONS = (
    pid_smc_flight_init, pid_smc_flight_step, pid_smc_flight_anti_windup,
    cascade_flight_init, cascade_flight_step, cascade_flight_anti_windup,
    sign_flight_init, sign_flight_step, sign_flight_anti_windup,
    *GEOMETRIC_FUNCTIONS, *INDI_FUNCTIONS,
)  # fmt: skip
