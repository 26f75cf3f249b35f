"""Baseline: the cascaded PID most flight stacks fly, with the filtering a real one has.

Attitude (phi, theta, psi): angle P -> rate PID, the reference's rate and acceleration fed
forward, as ArduCopter's attitude and rate controllers (``ATC_ANG_*_P``, ``ATC_RAT_*_P/I/D/IMAX``,
``ATC_RAT_*_FLTD``, ``INS_GYRO_FILTER``)::

    w_f      = LPF_gyro(x')                                  (gyro low-pass, first order)
    rate_cmd = k_angle (x_d - x) + x_d'
    D        = LPF_d(d w_f / dt)                             (D on the measured rate, own low-pass)
    alpha    = k_rate (rate_cmd - w_f) + ki_rate I - kd_rate D + x_d''
    I'       = rate_cmd - w_f,   |ki_rate I| <= i_max        (clamp; frozen while the mixer limits)
    u        = alpha / g            (g = b1, b2, b3: the inertia scaling, no model inversion)

The D term acts on the measurement, not on the error: a step of the rate command gives no
derivative kick (the reference's acceleration is fed forward instead).

Altitude: P -> climb-rate PI with gravity and tilt feed-forward (no filtering, no D)::

    climb_cmd = k_alt (z_d - z) + z_d'
    a_z       = k_climb (climb_cmd - z') + ki_climb int (climb_cmd - z') dt + z_d''
    u_z       = m (g + a_z) / (cos phi cos theta)

The low-passes are first order, ``y' = w_c (x - y)`` with ``w_c = 2 pi f_c``; the sampled form
holds the input over the step (``y += (1 - exp(-w_c dt)) (x - y)``, exact for a held input), and
the sampled D is ``LPF_d((w_f[k] - w_f[k-1]) / dt)``. A cut-off of 0 Hz switches a filter off
(the raw rate; the raw difference quotient). The defaults of :class:`CascadePidParams` are the
plain P -> PI cascade (no D, no filter, no clamp), the form ``smcpilot paper`` compares;
the flight controller flies :data:`fc.config.FC_CASCADE` (docs/baselines.md).

State (10 floats, :attr:`CascadePid.state_names`): the four integrators, the three low-passed
rates w_f (rad/s) and the three low-passed rate derivatives D (rad/s^2).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from fc.control.base import Diagnostics, IntegratingBaseline, Vec4
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel, tilt_cos

_INF = math.inf
_exp = math.exp
_TWO_PI = 2.0 * math.pi
Vec3 = tuple[float, float, float]
#: length of the cascade's state.
CASCADE_STATE_N = 10


@dataclass(frozen=True)
class CascadePidParams:
    """Gains in channel order (phi, theta, psi, z); for z the "angle" gain is the altitude gain.

    The defaults are the plain P -> PI cascade (no D term, no filters, no integrator clamp).
    """

    #: outer P gain, 1/s (angle error -> rate command; altitude error -> climb-rate command).
    k_outer: Vec4 = (6.0, 6.0, 4.0, 2.0)
    #: inner P gain, 1/s (rate error -> angular or vertical acceleration).
    k_inner: Vec4 = (20.0, 20.0, 12.0, 5.0)
    #: inner I gain, 1/s^2.
    ki_inner: Vec4 = (20.0, 20.0, 8.0, 2.0)
    #: rate D gain on the measured rate, (rad/s^2)/(rad/s^2) = 1, for (phi, theta, psi).
    kd_rate: Vec3 = (0.0, 0.0, 0.0)
    #: largest |ki_inner x integral| per channel, rad/s^2 (phi, theta, psi) and m/s^2 (z); inf: no clamp.
    i_max: Vec4 = (_INF, _INF, _INF, _INF)
    #: gyro (Euler-rate) low-pass cut-off, Hz; 0: off.
    gyro_filter_hz: float = 0.0
    #: low-pass cut-off of the D term, Hz; 0: off (only without a D gain).
    d_filter_hz: float = 0.0
    tilt_cos_min: float = 0.05

    def __post_init__(self) -> None:
        for name, n in (("k_outer", 4), ("k_inner", 4), ("ki_inner", 4), ("kd_rate", 3)):
            v = getattr(self, name)
            if len(v) != n or not all(isinstance(x, (int, float)) and math.isfinite(x) and x >= 0.0 for x in v):
                raise InvalidGainError(f"cascade_pid gain {name} needs {n} finite values >= 0, got {v!r}")
        if len(self.i_max) != 4 or not all(isinstance(x, (int, float)) and not math.isnan(x) and x >= 0.0 for x in self.i_max):
            raise InvalidGainError(f"cascade_pid i_max needs 4 values >= 0 (inf: no clamp), got {self.i_max!r}")
        for name in ("gyro_filter_hz", "d_filter_hz"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.0 <= v <= 1000.0:
                raise InvalidGainError(f"cascade_pid {name} must lie in [0, 1000] Hz (0: off), got {v!r}")
        if any(k > 0.0 for k in self.kd_rate) and self.d_filter_hz == 0.0:
            raise InvalidGainError("cascade_pid kd_rate > 0 needs the D-term low-pass: set d_filter_hz > 0")


class CascadePidConsts(NamedTuple):
    """:class:`CascadePidParams` and the model's constants, flattened (floats) for the pure step."""

    k_outer: Vec4
    k_inner: Vec4
    ki_inner: Vec4
    tilt_cos_min: float
    b1: float
    b2: float
    b3: float
    mass_kg: float
    gravity_mps2: float
    kd_rate: Vec3
    #: the integrators' own limits, i_max / ki_inner (inf where there is no clamp or no I gain).
    int_lim: Vec4
    #: gyro low-pass cut-off, rad/s (0: off).
    gyro_w_radps: float
    #: D-term low-pass cut-off, rad/s (0: off).
    d_w_radps: float


def cascade_pid_consts(model: PaperModel, params: CascadePidParams) -> CascadePidConsts:
    def f4(v: Sequence[float]) -> Vec4:
        return (float(v[0]), float(v[1]), float(v[2]), float(v[3]))

    def lim(i: int) -> float:
        ki, imax = float(params.ki_inner[i]), float(params.i_max[i])
        return imax / ki if ki > 0.0 and math.isfinite(imax) else _INF

    kd = params.kd_rate
    return CascadePidConsts(
        f4(params.k_outer), f4(params.k_inner), f4(params.ki_inner), float(params.tilt_cos_min),
        float(model.b1), float(model.b2), float(model.b3), float(model.mass_kg), float(model.gravity_mps2),
        (float(kd[0]), float(kd[1]), float(kd[2])), (lim(0), lim(1), lim(2), lim(3)),
        _TWO_PI * float(params.gyro_filter_hz), _TWO_PI * float(params.d_filter_hz),
    )  # fmt: skip


class CascadePid(IntegratingBaseline):
    """State: the inner loops' integrators ``(I_phi, I_theta, I_psi, I_z)``, the low-passed rates
    and the low-passed rate derivatives (see the module doc).

    The public face of the pure :func:`cascade_pid_output` / :func:`cascade_pid_step`.
    """

    name = "cascade_pid"
    state_names: tuple[str, ...] = (
        "int_rate_err_phi", "int_rate_err_theta", "int_rate_err_psi", "int_climb_err_z",
        "gyro_lpf_phi_dot", "gyro_lpf_theta_dot", "gyro_lpf_psi_dot",
        "d_lpf_phi_ddot", "d_lpf_theta_ddot", "d_lpf_psi_ddot",
    )  # fmt: skip

    def __init__(self, model: PaperModel, params: CascadePidParams = CascadePidParams()) -> None:
        self.model = model
        self.params = params
        #: the flattened constants the pure functions take.
        self.consts = cascade_pid_consts(model, params)

    def initial_state(self, meas: Sequence[float]) -> tuple[float, ...]:
        """Integrators and D terms zero, the gyro low-passes at the measured rates (:func:`cascade_pid_initial_state`)."""
        return cascade_pid_initial_state((float(meas[0]), float(meas[1]), float(meas[2]), float(meas[3]), float(meas[4]), float(meas[5])))

    def _output(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        """Continuous form: (u, the state's time derivative, diagnostics).

        The D term's input is the filtered rate's derivative, which the gyro low-pass gives; without
        a gyro filter the continuous form has no angular acceleration here and holds D (the sampled
        form, what the flight controller flies, differences the rate instead).
        """
        u, e = cascade_pid_output(meas, ref, state, self.consts)
        return u, cascade_pid_derivatives(meas, state, e, self.consts), Diagnostics(None, None, None, u, None)

    def step(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, accel: Sequence[float] | None = None
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        u, new = cascade_pid_step(meas, ref, state, dt_s, self.consts)
        return u, new, Diagnostics(None, None, None, u, None)

    def anti_windup(
        self, prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool]
    ) -> tuple[float, ...]:
        """Integrators of limited channels keep their previous values; the filters run on."""
        return cascade_pid_anti_windup(prev, new, limited)


def cascade_pid_initial_state(meas: Sequence[float]) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """The state at t = 0 (pure): integrators and D terms zero, the gyro low-passes at the measured rates."""
    return (0.0, 0.0, 0.0, 0.0, meas[1], meas[3], meas[5], 0.0, 0.0, 0.0)


def _cascade_channel(
    k_outer: float, k_inner: float, ki_inner: float, x: float, x_dot: float, r: float, r_d: float, r_dd: float, integ: float
) -> tuple[float, float]:
    """(commanded acceleration, inner-loop rate error) of one channel, without D."""
    rate_cmd = k_outer * (r - x) + r_d
    er = rate_cmd - x_dot
    return k_inner * er + ki_inner * integ + r_dd, er


def _rate_channel(
    k_outer: float, k_inner: float, ki_inner: float, kd: float, x: float, w_f: float, d_f: float,
    r: float, r_d: float, r_dd: float, integ: float,
) -> tuple[float, float]:
    """(commanded angular acceleration, rate error) of one attitude channel: P on the filtered
    rate's error, I, D on the filtered measured rate (-kd D), the reference's acceleration."""
    rate_cmd = k_outer * (r - x) + r_d
    er = rate_cmd - w_f
    return k_inner * er + ki_inner * integ - kd * d_f + r_dd, er


def cascade_pid_output(meas: Sequence[float], ref: Sequence[float], state: Sequence[float], p: CascadePidConsts) -> tuple[Vec4, Vec4]:
    """(u, inner-loop rate errors = the integrators' derivatives) for every channel (pure).

    Uses the state's low-passed rates (the measured ones with the gyro filter off) and D terms.
    """
    ko, kin, kii, tilt_min, b1, b2, b3, mass, g, kd, _lim, gw, _dw = p
    if gw > 0.0:
        w0, w1, w2 = state[4], state[5], state[6]
    else:
        w0, w1, w2 = meas[1], meas[3], meas[5]
    acc0, e0 = _rate_channel(ko[0], kin[0], kii[0], kd[0], meas[0], w0, state[7], ref[0], ref[1], ref[2], state[0])
    acc1, e1 = _rate_channel(ko[1], kin[1], kii[1], kd[1], meas[2], w1, state[8], ref[4], ref[5], ref[6], state[1])
    acc2, e2 = _rate_channel(ko[2], kin[2], kii[2], kd[2], meas[4], w2, state[9], ref[8], ref[9], ref[10], state[2])
    acc3, e3 = _cascade_channel(ko[3], kin[3], kii[3], meas[6], meas[7], ref[12], ref[13], ref[14], state[3])
    ctc = tilt_cos(meas[0], meas[2], tilt_min)
    return (acc0 / b1, acc1 / b2, acc2 / b3, mass * (g + acc3) / ctc), (e0, e1, e2, e3)


def lowpass_step(y: float, x: float, w_radps: float, dt_s: float) -> float:
    """One step of the first-order low-pass ``y' = w (x - y)`` with ``x`` held for ``dt_s`` (exact);
    ``w_radps`` 0: off, returns ``x``."""
    if w_radps > 0.0:
        return y + (1.0 - _exp(-w_radps * dt_s)) * (x - y)
    return x


def _clamp(v: float, lim: float) -> float:
    if v > lim:
        return lim
    if v < -lim:
        return -lim
    return v


def cascade_pid_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, p: CascadePidConsts
) -> tuple[Vec4, tuple[float, float, float, float, float, float, float, float, float, float]]:
    """Sampled form: (u to hold for ``dt_s``, the new 10-float state). ``state`` may be longer (padding).

    The filters advance first on this sample, then the law runs on their outputs; the integrators
    take a forward-Euler step of the rate errors and are clamped to ``int_lim``.
    """
    gw = p.gyro_w_radps
    dw = p.d_w_radps
    w0 = lowpass_step(state[4], meas[1], gw, dt_s)
    w1 = lowpass_step(state[5], meas[3], gw, dt_s)
    w2 = lowpass_step(state[6], meas[5], gw, dt_s)
    d0 = lowpass_step(state[7], (w0 - state[4]) / dt_s, dw, dt_s)
    d1 = lowpass_step(state[8], (w1 - state[5]) / dt_s, dw, dt_s)
    d2 = lowpass_step(state[9], (w2 - state[6]) / dt_s, dw, dt_s)
    filt = (state[0], state[1], state[2], state[3], w0, w1, w2, d0, d1, d2)
    u, e = cascade_pid_output(meas, ref, filt, p)
    lim = p.int_lim
    return u, (
        _clamp(state[0] + dt_s * e[0], lim[0]), _clamp(state[1] + dt_s * e[1], lim[1]),
        _clamp(state[2] + dt_s * e[2], lim[2]), _clamp(state[3] + dt_s * e[3], lim[3]),
        w0, w1, w2, d0, d1, d2,
    )  # fmt: skip


def _clamped_rate(integ: float, e: float, lim: float) -> float:
    """An integrator's derivative: the error, or 0 at its clamp while the error pushes outward."""
    if (integ >= lim and e > 0.0) or (integ <= -lim and e < 0.0):
        return 0.0
    return e


def cascade_pid_derivatives(meas: Sequence[float], state: Sequence[float], e: Vec4, p: CascadePidConsts) -> tuple[float, ...]:
    """The continuous form's state derivative (pure): clamped integrators, gyro low-passes
    ``w_f' = w_g (x' - w_f)``, D low-passes ``D' = w_d (w_f' - D)`` (held without a gyro filter)."""
    gw = p.gyro_w_radps
    dw = p.d_w_radps
    lim = p.int_lim
    g0 = g1 = g2 = 0.0
    if gw > 0.0:
        g0 = gw * (meas[1] - state[4])
        g1 = gw * (meas[3] - state[5])
        g2 = gw * (meas[5] - state[6])
    h0 = h1 = h2 = 0.0
    if dw > 0.0 and gw > 0.0:
        h0 = dw * (g0 - state[7])
        h1 = dw * (g1 - state[8])
        h2 = dw * (g2 - state[9])
    return (
        _clamped_rate(state[0], e[0], lim[0]), _clamped_rate(state[1], e[1], lim[1]),
        _clamped_rate(state[2], e[2], lim[2]), _clamped_rate(state[3], e[3], lim[3]),
        g0, g1, g2, h0, h1, h2,
    )  # fmt: skip


def cascade_pid_anti_windup(
    prev: Sequence[float], new: Sequence[float], limited: Sequence[bool]
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """The mixer limited a channel: its integrator keeps its previous value; the filters run on (pure)."""
    return (
        prev[0] if limited[0] else new[0],
        prev[1] if limited[1] else new[1],
        prev[2] if limited[2] else new[2],
        prev[3] if limited[3] else new[3],
        new[4], new[5], new[6], new[7], new[8], new[9],
    )  # fmt: skip
