"""INDI: incremental nonlinear dynamic inversion of the attitude and altitude channels.

The law of Smeur, Chu & de Croon, "Adaptive Incremental Nonlinear Dynamic Inversion for Attitude
Control of Micro Air Vehicles" (J. Guidance, Control, and Dynamics 39(3), 2016), in this project's
frame and channel order (paper frame z up; channels phi, theta, psi, z; inputs
u = (u_phi N, u_theta N, u_psi N m, u_z N); docs/indi.md has the derivation and the tuning).

Per channel the model is ``x'' = f(X) + G u`` (:mod:`smcpilot.model`; G = b1, b2, b3 and
cos(phi) cos(theta) / m). Instead of inverting f, INDI measures the acceleration and increments
the input the actuators realise::

    a_k     = (x'_k - x'_{k-1}) / dt                    mean acceleration over the last tick
    m_k     = mean over the last tick of the modelled actuator (the realised u_prev through the
              motors' first-order lag, time constant tau)
    a_f     = H(a_k),   u_f = H(m_k)                    the SAME second-order low-pass H (sync)
    nu      = x_d'' + kd (x_d' - x') + kp (x_d - x)      virtual control (reference tracking)
    u       = u_f + G^-1 (nu - a_f)                      the increment

``H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)`` is discretised exactly for an input held over the
tick (zero-order hold, its 2x2 transition matrix computed once in :func:`indi_consts`). Because
the acceleration and the actuator pass through the same filter, their delays cancel in the
increment: with a perfect model ``u = G^-1 (nu - H f)``, and the realised acceleration is
``A nu + (1 - A H) f`` (A the actuator's dynamics) -- the filter delays only the disturbance
rejection, not the response to nu (the point of Smeur's section III).

Measured acceleration: the law asks for the IMU (``measures_accel``), and the altitude channel's
a_k is then the accelerometer's z'' (``meas[10]``: specific force rotated into the world with
the attitude, gravity removed) when it is finite; where the IMU gives none (a dropout, a
simulator without it) z' is differenced as above. The attitude channels always difference the
rates: an accelerometer does not measure angular acceleration.

Altitude: the same on z'' (from the vertical velocity z'), incrementing the vertical thrust
``w = cos(phi) cos(theta) u_z`` and dividing by the current cos(phi) cos(theta):
``u_z = (w_f + m (nu_z - a_zf)) / (cos phi cos theta)``, w_f = H(cos phi cos theta m_z).

Adaptive G (the paper's title; off by default, ``INDI_ADAPT`` 0): per channel the ratio
r = G / G_nominal follows a normalised least-mean-squares fit of the filtered signals' rates of
change, ``r += mu dt (a_f' - r x) x / (x^2 + eps^2)`` with ``x = G_nominal u_f'``, kept in
[0.25, 4]. (The paper fits G on the one-tick increments of the same filtered signals.)

No integrator: the increment integrates by itself (u_k builds on what was realised), so a steady
state has nu = a_f = 0, i.e. no tracking error, whatever the constant disturbance; and because it
builds on the *realised* input, a limited channel winds nothing up (:func:`indi_anti_windup`
keeps the state). ``d_hat`` is ignored: the measured acceleration already holds the disturbance
(fly INDI without the observer, ``DOB_MODE`` 0 or -1; see docs/indi.md).

State (29 floats, :data:`INDI_STATE_NAMES`): the previous rates (4), the modelled actuator (4),
the acceleration filters' (y, y') (8), the actuator filters' (y, y') (8), the G ratios (4), and
whether a previous rate exists (0 right after :func:`indi_initial_state`: the first tick takes no
finite difference, since the pipeline initialises a law with the rates zeroed).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import NamedTuple

from fc.control.law import STAGE_ATTITUDE, Law, LawContext, param
from smcpilot.errors import InvalidGainError
from smcpilot.model import tilt_cos

Vec4 = tuple[float, float, float, float]
_ZERO4 = (0.0, 0.0, 0.0, 0.0)
_NAN = math.nan
#: smallest |cos(phi) cos(theta)| the altitude channel divides by (as the pipeline's hover trim).
TILT_COS_MIN = 0.05
#: bounds of the adaptive G ratio G / G_nominal.
G_RATIO_MIN = 0.25
G_RATIO_MAX = 4.0
#: regularisation of the normalised LMS (rad/s^3, m/s^3): below it the fit hardly moves.
ADAPT_EPS = 1.0
#: length of the law's state.
INDI_STATE_N = 29
_CH = ("phi", "theta", "psi", "z")
INDI_STATE_NAMES: tuple[str, ...] = (
    tuple(f"{c}_dot_prev" for c in _CH)
    + tuple(f"act_{c}" for c in _CH)
    + tuple(f"acc_f{d}_{c}" for c in _CH for d in ("", "d"))
    + tuple(f"act_f{d}_{c}" for c in _CH for d in ("", "d"))
    + tuple(f"g_ratio_{c}" for c in _CH)
    + ("primed",)
)


@dataclass(frozen=True)
class IndiParams:
    """INDI's parameters (MAVLink ``INDI_*``). Defaults: docs/indi.md §4 (the PID-SMC's roll
    bandwidth; Smeur's filter)."""

    kp_rp: float = param(12.5, lo=0.0, hi=400.0, unit="1/s^2", doc="roll/pitch: angle error -> angular acceleration", name="KP_RP")
    kd_rp: float = param(4.6, lo=0.0, hi=60.0, unit="1/s", doc="roll/pitch: rate error -> angular acceleration", name="KD_RP")
    kp_yaw: float = param(12.5, lo=0.0, hi=400.0, unit="1/s^2", doc="yaw: angle error -> angular acceleration", name="KP_Y")
    kd_yaw: float = param(4.6, lo=0.0, hi=60.0, unit="1/s", doc="yaw: rate error -> angular acceleration", name="KD_Y")
    kp_z: float = param(12.5, lo=0.0, hi=400.0, unit="1/s^2", doc="altitude: height error -> vertical acceleration", name="KP_Z")
    kd_z: float = param(4.6, lo=0.0, hi=60.0, unit="1/s", doc="altitude: climb-rate error -> vertical acceleration", name="KD_Z")
    wn_rp: float = param(100.0, lo=1.0, hi=1000.0, unit="rad/s", doc="natural frequency of the roll/pitch filter H (rates and actuators)", name="WN_RP")
    wn_yaw: float = param(20.0, lo=1.0, hi=1000.0, unit="rad/s", doc="natural frequency of the yaw filter H (yaw rate and yaw actuator)", name="WN_Y")
    wn_z: float = param(10.0, lo=1.0, hi=1000.0, unit="rad/s", doc="natural frequency of the altitude filter H (climb rate and thrust)", name="WN_Z")
    zeta: float = param(0.55, lo=0.1, hi=2.0, doc="damping ratio of every filter H", name="ZETA")
    lag_scale: float = param(1.0, lo=0.0, hi=5.0, doc="motor time constant modelled, x the vehicle's (0: actuators taken as instantaneous)", name="LAG_SCL")
    adapt_rate: float = param(0.0, lo=0.0, hi=100.0, unit="1/s", doc="adaptive G: normalised LMS rate (0: off, G nominal)", name="ADAPT")

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            meta = f.metadata["smcpilot"]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not meta["lo"] <= v <= meta["hi"]:
                raise InvalidGainError(f"indi {f.name} must be a number in [{meta['lo']:g}, {meta['hi']:g}], got {v!r}")


class Filter2(NamedTuple):
    """A second-order low-pass discretised with a zero-order hold: state (y, y'), input x held
    over the tick: ``y+ = a11 y + a12 y' + b1 x``, ``y'+ = a21 y + a22 y' + b2 x``."""

    a11: float
    a12: float
    a21: float
    a22: float
    b1: float
    b2: float


class IndiConsts(NamedTuple):
    """:class:`IndiParams` and the vehicle's constants, flattened for the pure step."""

    #: angle (height) gains and rate (climb-rate) gains, channel order.
    kp: Vec4
    kd: Vec4
    #: nominal control effectiveness: b1, b2, b3 (1/(kg m), 1/(kg m), 1/(kg m^2)) and 1/m (1/kg).
    g_nom: Vec4
    #: hover thrust m g, N.
    hover_n: float
    tilt_min: float
    #: motor lag over one tick: state factor exp(-dt/tau), and the mean's factor tau (1 - a) / dt.
    lag_a: float
    lag_b: float
    #: the filters H of roll/pitch, yaw and altitude.
    f_rp: Filter2
    f_yaw: Filter2
    f_z: Filter2
    #: adaptive G: mu (1/s; 0 off) and the LMS regularisation.
    adapt_rate: float
    adapt_eps: float


def _expm(m: list[list[float]]) -> list[list[float]]:
    """exp(m) of a small square matrix: scaling and squaring around a 24-term Taylor series."""
    n = len(m)
    norm = max(sum(abs(x) for x in row) for row in m)
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    a = [[x / 2.0**s for x in row] for row in m]

    def mul(p: list[list[float]], q: list[list[float]]) -> list[list[float]]:
        return [[sum(p[i][k] * q[k][j] for k in range(n)) for j in range(n)] for i in range(n)]

    out = [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]
    term = [row[:] for row in out]
    for k in range(1, 25):
        term = [[x / k for x in row] for row in mul(term, a)]
        out = [[out[i][j] + term[i][j] for j in range(n)] for i in range(n)]
    for _ in range(s):
        out = mul(out, out)
    return out


@functools.lru_cache(maxsize=256)  # a campaign builds the same filters flight after flight
def filter2_zoh(wn_radps: float, zeta: float, dt_s: float) -> Filter2:
    """H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2) in state form (y, y'), discretised exactly for an
    input held over ``dt_s`` (the exponential of the augmented matrix [[A, B], [0, 0]] dt)."""
    w = float(wn_radps)
    e = _expm([[0.0, dt_s, 0.0], [-w * w * dt_s, -2.0 * zeta * w * dt_s, w * w * dt_s], [0.0, 0.0, 0.0]])
    return Filter2(e[0][0], e[0][1], e[1][0], e[1][1], e[0][2], e[1][2])


def indi_consts(ctx: LawContext, params: IndiParams) -> IndiConsts:
    """Flatten the parameters with the nominal model (b1, b2, b3, m), the motor time constant and
    the control period 1 / ``ctx.rate_hz`` (the filters and the lag are discretised at it)."""
    p = params
    model = ctx.model
    dt = 1.0 / float(ctx.rate_hz)
    tau = float(ctx.vehicle.motor_time_constant_s) * float(p.lag_scale)
    lag_a = math.exp(-dt / tau) if tau > 0.0 else 0.0
    lag_b = tau * (1.0 - lag_a) / dt if tau > 0.0 else 0.0
    z = float(p.zeta)
    return IndiConsts(
        kp=(float(p.kp_rp), float(p.kp_rp), float(p.kp_yaw), float(p.kp_z)),
        kd=(float(p.kd_rp), float(p.kd_rp), float(p.kd_yaw), float(p.kd_z)),
        g_nom=(float(model.b1), float(model.b2), float(model.b3), 1.0 / float(model.mass_kg)),
        hover_n=float(model.mass_kg) * float(model.gravity_mps2),
        tilt_min=TILT_COS_MIN,
        lag_a=lag_a,
        lag_b=lag_b,
        f_rp=filter2_zoh(p.wn_rp, z, dt),
        f_yaw=filter2_zoh(p.wn_yaw, z, dt),
        f_z=filter2_zoh(p.wn_z, z, dt),
        adapt_rate=float(p.adapt_rate),
        adapt_eps=ADAPT_EPS,
    )


# -- the pure functions ---------------------------------------------------------------------------
def indi_filter(y: float, yd: float, x: float, c: Filter2) -> tuple[float, float]:
    """One tick of the filter H: (y, y') after the input ``x`` held over the tick."""
    return (c.a11 * y + c.a12 * yd + c.b1 * x, c.a21 * y + c.a22 * yd + c.b2 * x)


def indi_channel(
    x: float, xd: float, xd_prev: float, act: float, u_prev: float, scale: float,
    fa: float, fad: float, fu: float, fud: float, ratio: float,
    x_ref: float, v_ref: float, a_ref: float, kp: float, kd: float, g_nom: float,
    c: Filter2, lag_a: float, lag_b: float, mu_dt: float, eps: float, dt_s: float, acc_meas: float,
) -> tuple[float, float, float, float, float, float, float]:  # fmt: skip
    """One channel: (u, actuator state, a_f, a_f', u_f, u_f', G ratio) after the tick.

    ``scale`` multiplies the actuator before it is filtered and divides the result (1 for the
    attitude channels; cos(phi) cos(theta) for the thrust, whose vertical part acts on z'').
    ``acc_meas`` is the channel's measured acceleration (the accelerometer's, for z''); NaN: the
    mean acceleration over the last tick from the rates, (x'_k - x'_{k-1}) / dt."""
    acc = acc_meas
    if acc != acc:
        acc = (xd - xd_prev) / dt_s
    mean = u_prev + (act - u_prev) * lag_b
    act_new = u_prev + (act - u_prev) * lag_a
    fa1, fad1 = indi_filter(fa, fad, acc, c)
    fu1, fud1 = indi_filter(fu, fud, scale * mean, c)
    r = ratio
    if mu_dt > 0.0:
        w = g_nom * fud1
        r = r + mu_dt * (fad1 - r * w) * w / (w * w + eps * eps)
        r = min(max(r, G_RATIO_MIN), G_RATIO_MAX)
    nu = a_ref + kd * (v_ref - xd) + kp * (x_ref - x)
    u = (fu1 + (nu - fa1) / (g_nom * r)) / scale
    return u, act_new, fa1, fad1, fu1, fud1, r


def indi_initial_state(meas: Sequence[float], k: IndiConsts) -> tuple[float, ...]:
    """The actuators and their filters at hover trim for the measured tilt (no torques,
    u_z = m g / (cos phi cos theta)), no acceleration, G nominal, not primed (the first step
    differences nothing: the rates it is given here may be placeholders)."""
    ctc = tilt_cos(meas[0], meas[2], k.tilt_min)
    uz = k.hover_n / ctc
    return (
        meas[1], meas[3], meas[5], meas[7],
        0.0, 0.0, 0.0, uz,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ctc * uz, 0.0,
        1.0, 1.0, 1.0, 1.0, 0.0,
    )  # fmt: skip


def indi_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, k: IndiConsts, d_hat: Sequence[float], u_prev: Sequence[float]
) -> tuple[Vec4, tuple[float, ...], tuple[Vec4, Vec4, Vec4, Vec4]]:
    """One tick: (u, new state, diag). ``u_prev`` is what the mixer realised over the last tick;
    diag's u' is the command's rate of change (u - u_prev) / dt, the rest zeros. ``meas`` may end
    with the measured acceleration (x'', y'', z'', :attr:`fc.control.law.Law.measures_accel`):
    a finite z'' is the altitude channel's acceleration; NaN, or 8 floats, differences z'."""
    acc_z = _NAN
    if len(meas) > 10:
        acc_z = meas[10]
    s = state
    p0, p1, p2, p3 = s[0], s[1], s[2], s[3]
    if s[28] == 0.0:  # the first tick: no previous rate to difference
        p0, p1, p2, p3 = meas[1], meas[3], meas[5], meas[7]
    mu_dt = k.adapt_rate * dt_s
    eps = k.adapt_eps
    la = k.lag_a
    lb = k.lag_b
    kp = k.kp
    kd = k.kd
    g = k.g_nom
    u0, c0, fa0, fad0, fu0, fud0, r0 = indi_channel(
        meas[0], meas[1], p0, s[4], u_prev[0], 1.0, s[8], s[9], s[16], s[17], s[24],
        ref[0], ref[1], ref[2], kp[0], kd[0], g[0], k.f_rp, la, lb, mu_dt, eps, dt_s, _NAN,
    )  # fmt: skip
    u1, c1, fa1, fad1, fu1, fud1, r1 = indi_channel(
        meas[2], meas[3], p1, s[5], u_prev[1], 1.0, s[10], s[11], s[18], s[19], s[25],
        ref[4], ref[5], ref[6], kp[1], kd[1], g[1], k.f_rp, la, lb, mu_dt, eps, dt_s, _NAN,
    )  # fmt: skip
    u2, c2, fa2, fad2, fu2, fud2, r2 = indi_channel(
        meas[4], meas[5], p2, s[6], u_prev[2], 1.0, s[12], s[13], s[20], s[21], s[26],
        ref[8], ref[9], ref[10], kp[2], kd[2], g[2], k.f_yaw, la, lb, mu_dt, eps, dt_s, _NAN,
    )  # fmt: skip
    ctc = tilt_cos(meas[0], meas[2], k.tilt_min)
    u3, c3, fa3, fad3, fu3, fud3, r3 = indi_channel(
        meas[6], meas[7], p3, s[7], u_prev[3], ctc, s[14], s[15], s[22], s[23], s[27],
        ref[12], ref[13], ref[14], kp[3], kd[3], g[3], k.f_z, la, lb, mu_dt, eps, dt_s, acc_z,
    )  # fmt: skip
    new = (
        meas[1], meas[3], meas[5], meas[7],
        c0, c1, c2, c3,
        fa0, fad0, fa1, fad1, fa2, fad2, fa3, fad3,
        fu0, fud0, fu1, fud1, fu2, fud2, fu3, fud3,
        r0, r1, r2, r3, 1.0,
    )  # fmt: skip
    u = (u0, u1, u2, u3)
    ud = ((u0 - u_prev[0]) / dt_s, (u1 - u_prev[1]) / dt_s, (u2 - u_prev[2]) / dt_s, (u3 - u_prev[3]) / dt_s)
    return u, new, (_ZERO4, _ZERO4, _ZERO4, ud)


def indi_anti_windup(prev: Sequence[float], new: tuple, u_realised: Sequence[float], limited: Sequence[bool], k: IndiConsts) -> tuple:
    """Nothing to hold: the increment builds on the realised input (``u_prev`` of the next tick),
    so a limited channel winds nothing up; the filters and the actuator model run on."""
    return new


#: every pure function this module defines (what a compiler such as numba's ``njit`` takes).
INDI_FUNCTIONS = (indi_filter, indi_channel, indi_initial_state, indi_step, indi_anti_windup)

INDI = Law(
    name="indi", stage=STAGE_ATTITUDE, prefix="INDI",
    description="incremental nonlinear dynamic inversion (Smeur, Chu & de Croon 2016): measured "
                "angular/vertical acceleration, synchronised filters, increments on the realised input",
    params_class=IndiParams, consts=indi_consts,
    initial_state=indi_initial_state, step=indi_step, anti_windup=indi_anti_windup,
    state_names=INDI_STATE_NAMES, diagnostics=("u_dot",), observer_default="none", reference="docs/indi.md",
    measures_accel=True,
)  # fmt: skip
