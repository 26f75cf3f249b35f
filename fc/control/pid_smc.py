"""The PID sliding-mode controller of the paper, corrected (``docs/pid-smc.md`` §§2-4).

Per channel k (phi, theta, psi, z), with e = x - x_d:

    S      = c1 e + c2 e'                                                  (18)
    sigma  = kp S + ki int S dt + kd S'                                    (19)
    S'     = c1 e' + c2 e'',   e'' = a - x_d''   (a = f + g u "model", or measured "oracle")
    N      = kp [c1 e' + c2 (f + g u - x_d'')] + ki S
             + kd [c1 (f + g u - x_d'') + c2 (f' + g' u - x_d''')]
    u'     = -(kd c2 g)^-1 [N + kappa sign(sigma)|sigma|^delta + nu sigma + chi sign(sigma)]  (20)
    chi_hat' = Theta |sigma|                                    (33, adaptive flavour)

The controller state per channel is (int S dt, u, chi_hat); u is integrated, which is what removes
the chattering. The known-bound flavour (Theorem 1) is the same law with chi_hat held at chi.

One law, two forms: :meth:`PidSmc.derivatives` (continuous time) and :meth:`PidSmc.step`
(forward Euler of the same derivatives with a zero-order hold). Everything is plain floats.

The hot path is pure: :class:`PidSmc` validates its :class:`PidSmcParams` once and flattens them
into a :class:`PidSmcConsts` (NamedTuple of floats, bools and tuples of them, in ``PidSmc.consts``);
the law is the module-level :func:`pid_smc_law`, its sampled form :func:`pid_smc_step` and the
saturation feedback :func:`pid_smc_anti_windup`, functions of tuples only (no objects, no
allocation of lists, nothing a compiler such as numba's ``njit`` would refuse). The methods of
:class:`PidSmc` are the public, validated wrappers around them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

from fc.control.base import Diagnostics, Vec4
from fc.control.gains import PAPER_GAINS, ChannelGains, Gains4
from smcpilot.errors import InvalidGainError
from smcpilot.model import CHANNELS, PaperModel, drift, drift_rates, omega_bar_of_inputs, tilt_cos
from smcpilot.typos import CONTROLLER_TYPOS, parse_typos

_INF = math.inf
#: :attr:`PidSmcParams.disturbance_estimate` values, in the order of :attr:`PidSmcConsts.dob_mode`.
DISTURBANCE_ESTIMATES = ("none", "sigma", "lumped", "input")
DOB_NONE = 0
DOB_SIGMA = 1
DOB_LUMPED = 2
DOB_INPUT = 3
_copysign = math.copysign
_ZERO4 = (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class AdaptationBounds:
    """How the adaptive gain chi_hat is kept bounded (spec §4). The defaults are the paper's law.

    d chi_hat/dt = Theta max(|sigma| - dead_zone, 0) - leakage_per_s (chi_hat - chi_hat0),
    then projected onto [chi_hat_min, chi_hat_max].
    """

    #: |sigma| below which chi_hat does not grow (noise floor).
    dead_zone: float = 0.0
    #: sigma-modification rate pulling chi_hat back to its initial value, 1/s.
    leakage_per_s: float = 0.0
    #: lower projection bound.
    chi_hat_min: float = 0.0
    #: upper projection bound.
    chi_hat_max: float = _INF

    def __post_init__(self) -> None:
        for name in ("dead_zone", "leakage_per_s", "chi_hat_min"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0.0):
                raise InvalidGainError(f"adaptation bound {name} must be a finite number >= 0, got {v!r}")
        if not (isinstance(self.chi_hat_max, (int, float)) and self.chi_hat_max >= self.chi_hat_min):
            raise InvalidGainError(
                f"adaptation bound chi_hat_max must be >= chi_hat_min, got {self.chi_hat_max!r}"
            )


@dataclass(frozen=True)
class PidSmcParams:
    """Everything that configures :class:`PidSmc` besides the vehicle model."""

    gains: Gains4 = PAPER_GAINS
    #: True: adaptive chi_hat (Theorem 2); False: known bound chi (Theorem 1).
    adaptive: bool = True
    #: "model": e'' from the nominal model (implementable); "oracle": from measured acceleration.
    sigma_source: Literal["model", "oracle"] = "model"
    #: chi_hat(0) per channel (the paper's simulation uses 0.5; Assumption 1 says 0).
    chi_hat0: Vec4 = (0.5, 0.5, 0.5, 0.5)
    #: u(0) per channel; None means hover trim (0, 0, 0, m g / (cos phi0 cos theta0)).
    u0: Vec4 | None = None
    adaptation: AdaptationBounds = field(default_factory=AdaptationBounds)
    #: input limits per channel for anti-windup (u is clamped; int S and chi_hat freeze there).
    u_min: Vec4 = (-_INF, -_INF, -_INF, -_INF)
    u_max: Vec4 = (_INF, _INF, _INF, _INF)
    #: smallest |cos phi cos theta| used in g_z (guards 1/g_z near 90 deg of tilt).
    tilt_cos_min: float = 0.05
    #: controller typos to reproduce literally (see smcpilot.typos); model typos go to PaperModel.
    typos: frozenset[str] = frozenset()
    #: the on-board disturbance estimate d_hat (:mod:`fc.control.observer`) and how the law uses it:
    #: "none" (the paper's nominal-model sigma), "sigma" (a = f + g u + d_hat in S' only: the
    #: measured-acceleration sigma made real), "lumped" (d_hat added to f: sigma and the equivalent
    #: control), "input" (the law stays nominal and the flight pipeline cancels d_hat at its input,
    #: u_cmd = u - d_hat/g: the classical disturbance-observer compensation). The observer runs in
    #: the flight pipeline; the law takes d_hat as an input.
    disturbance_estimate: Literal["none", "sigma", "lumped", "input"] = "none"
    #: observer bandwidth L per channel, rad/s.
    observer_bandwidth_radps: Vec4 = (25.0, 25.0, 25.0, 10.0)
    #: the rotors' time constant the observer models, s (0: the input acts at once).
    observer_motor_tau_s: float = 0.0
    #: largest |d_hat| per channel (rad/s^2, rad/s^2, rad/s^2, m/s^2).
    observer_d_max: Vec4 = (_INF, _INF, _INF, _INF)

    def __post_init__(self) -> None:
        if len(self.gains) != 4 or not all(isinstance(g, ChannelGains) for g in self.gains):
            raise InvalidGainError("gains must be four ChannelGains (phi, theta, psi, z)")
        if self.sigma_source not in ("model", "oracle"):
            raise InvalidGainError(f"sigma_source must be 'model' or 'oracle', got {self.sigma_source!r}")
        for name in ("chi_hat0", "u_min", "u_max") + (("u0",) if self.u0 is not None else ()):
            v = getattr(self, name)
            if len(v) != 4:
                raise InvalidGainError(f"{name} needs 4 values (phi, theta, psi, z), got {len(v)}")
            if name != "u_min" and name != "u_max" and not all(math.isfinite(x) for x in v):
                raise InvalidGainError(f"{name} must be finite, got {v!r}")
            if any(math.isnan(x) for x in v):
                raise InvalidGainError(f"{name} must not contain NaN, got {v!r}")
        if any(c < 0.0 for c in self.chi_hat0):
            raise InvalidGainError(f"chi_hat0 must be >= 0, got {self.chi_hat0!r}")
        if any(lo >= hi for lo, hi in zip(self.u_min, self.u_max)):
            raise InvalidGainError("u_min must be below u_max in every channel")
        if not 0.0 < self.tilt_cos_min < 1.0:
            raise InvalidGainError(f"tilt_cos_min must lie in (0, 1), got {self.tilt_cos_min}")
        if self.disturbance_estimate not in DISTURBANCE_ESTIMATES:
            raise InvalidGainError(
                f"disturbance_estimate must be one of {', '.join(DISTURBANCE_ESTIMATES)}, got {self.disturbance_estimate!r}"
            )
        bw = self.observer_bandwidth_radps
        if len(bw) != 4 or not all(math.isfinite(x) and x > 0.0 for x in bw):
            raise InvalidGainError(f"observer_bandwidth_radps needs 4 finite values > 0 rad/s, got {bw!r}")
        if not (math.isfinite(self.observer_motor_tau_s) and self.observer_motor_tau_s >= 0.0):
            raise InvalidGainError(f"observer_motor_tau_s must be a finite number >= 0 s, got {self.observer_motor_tau_s!r}")
        dm = self.observer_d_max
        if len(dm) != 4 or not all(x > 0.0 for x in dm):
            raise InvalidGainError(f"observer_d_max needs 4 values > 0, got {dm!r}")
        object.__setattr__(self, "typos", parse_typos(self.typos) & CONTROLLER_TYPOS)


class ChannelConsts(NamedTuple):
    """One channel's gains as the law uses them (floats)."""

    c1: float
    c2: float
    kp: float
    ki: float
    kd: float
    kappa: float
    delta: float
    nu: float
    #: adaptation rate Theta.
    theta: float
    #: 1/(kd c2) (the paper's literal prefactor drops kd: 1/c2).
    inv_kd_c2: float


class PidSmcConsts(NamedTuple):
    """Everything :func:`pid_smc_law` reads, flattened once from the model and the parameters.

    ``model`` and the four ``k`` are plain tuples in :class:`~smcpilot.model.ModelConsts` and
    :class:`ChannelConsts` order: the law unpacks them on every step, and CPython unpacks an exact
    tuple on its fast path (a NamedTuple goes through the iterator protocol).
    """

    #: the model's constants, in ModelConsts order.
    model: tuple[float | bool, ...]
    #: per channel (phi, theta, psi, z), each in ChannelConsts order.
    k: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    adaptive: bool
    #: "adaptive-law" typo: chi_hat = Theta |sigma| algebraically.
    algebraic_chi: bool
    #: "theta-chi" typo: the theta channel uses phi's chi_hat.
    theta_uses_phi_chi: bool
    #: sigma from measured accelerations when they are given.
    oracle: bool
    dead_zone: float
    leak: float
    chi_lo: float
    chi_hi: float
    #: chi_hat(0) (adaptive) or the known bounds chi (known-bound flavour).
    chi0: Vec4
    u_lo: Vec4
    u_hi: Vec4
    #: some u limit is finite.
    has_limits: bool
    #: u(0) given (else hover trim).
    has_u0: bool
    u0: Vec4
    tilt_min: float
    inv_mass: float
    #: how the disturbance estimate is used: :data:`DOB_NONE`, :data:`DOB_SIGMA`, :data:`DOB_LUMPED`,
    #: :data:`DOB_INPUT` (the last by the pipeline, not the law).
    dob_mode: int
    #: observer bandwidth per channel, rad/s.
    dob_w: Vec4
    #: the rotors' time constant modelled by the observer, s.
    dob_tau: float
    #: largest |d_hat| per channel.
    dob_max: Vec4


def _f4(v: Sequence[float]) -> Vec4:
    return (float(v[0]), float(v[1]), float(v[2]), float(v[3]))


def pid_smc_consts(model: PaperModel, params: PidSmcParams) -> PidSmcConsts:
    """Flatten a model and validated parameters into the law's constants."""
    ty = params.typos
    k = tuple(
        tuple(ChannelConsts(
            float(g.c1),
            float(g.c2),
            float(g.kp),
            float(g.ki),
            float(g.kd),
            float(g.kappa),
            float(g.delta),
            float(g.nu),
            float(g.adapt_rate),
            1.0 / (g.c2 if "prefactor" in ty else g.kd * g.c2),
        ))
        for g in params.gains
    )
    a = params.adaptation
    chi0 = params.chi_hat0 if params.adaptive else tuple(g.chi for g in params.gains)
    return PidSmcConsts(
        model=tuple(model.consts()),
        k=(k[0], k[1], k[2], k[3]),
        adaptive=bool(params.adaptive),
        algebraic_chi="adaptive-law" in ty,
        theta_uses_phi_chi="theta-chi" in ty,
        oracle=params.sigma_source == "oracle",
        dead_zone=float(a.dead_zone),
        leak=float(a.leakage_per_s),
        chi_lo=float(a.chi_hat_min),
        chi_hi=float(a.chi_hat_max),
        chi0=_f4(chi0),
        u_lo=_f4(params.u_min),
        u_hi=_f4(params.u_max),
        has_limits=any(math.isfinite(v) for v in params.u_min + params.u_max),
        has_u0=params.u0 is not None,
        u0=_f4(params.u0) if params.u0 is not None else _ZERO4,
        tilt_min=float(params.tilt_cos_min),
        inv_mass=1.0 / model.mass_kg,
        dob_mode=DISTURBANCE_ESTIMATES.index(params.disturbance_estimate),
        dob_w=_f4(params.observer_bandwidth_radps),
        dob_tau=float(params.observer_motor_tau_s),
        dob_max=_f4(params.observer_d_max),
    )


class PidSmc:
    """Adaptive (default) or known-bound PID-SMC on the four channels.

    State tuple (12 floats): ``(I_phi, I_theta, I_psi, I_z, u_phi, u_theta, u_psi, u_z,
    chi_phi, chi_theta, chi_psi, chi_z)`` with I = int S dt.

    The public, validated face of the pure functions :func:`pid_smc_law`, :func:`pid_smc_step`
    and :func:`pid_smc_anti_windup`; ``consts`` holds their flattened constants.
    """

    state_names = tuple(f"int_s_{c}" for c in CHANNELS) + tuple(f"u_{c}" for c in CHANNELS) + tuple(
        f"chi_hat_{c}" for c in CHANNELS
    )

    def __init__(self, model: PaperModel, params: PidSmcParams = PidSmcParams()) -> None:
        self.model = model
        self.params = params
        self.name = "adaptive_pid_smc" if params.adaptive else "pid_smc"
        #: the flattened constants the pure functions take.
        self.consts = pid_smc_consts(model, params)
        self._oracle = self.consts.oracle
        self._has_limits = self.consts.has_limits

    # -- state ------------------------------------------------------------------------------------
    def initial_state(self, meas: Sequence[float]) -> tuple[float, ...]:
        return pid_smc_initial_state(meas, self.consts)

    def command(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> Vec4:
        """u is a controller state: the command is simply its current value (:func:`pid_smc_command`)."""
        return pid_smc_command(state)

    # -- continuous-time form ---------------------------------------------------------------------
    def derivatives(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], accel: Sequence[float] | None = None
    ) -> tuple[tuple[float, ...], Diagnostics]:
        """The state's time derivative and the diagnostics (:func:`pid_smc_derivatives`)."""
        if accel is not None and self._oracle:
            d, s, sg, chi, ud = pid_smc_derivatives(meas, ref, state, self.consts, accel, True)
        else:
            d, s, sg, chi, ud = pid_smc_derivatives(meas, ref, state, self.consts, _ZERO4, False)
        return d, Diagnostics(s, sg, chi, (state[4], state[5], state[6], state[7]), ud)

    # -- sampled-data form ------------------------------------------------------------------------
    def step(
        self,
        meas: Sequence[float],
        ref: Sequence[float],
        state: Sequence[float],
        dt_s: float,
        accel: Sequence[float] | None = None,
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        """Forward-Euler step of :meth:`derivatives`' law; returns the u to hold for ``dt_s``.

        Anti-windup: where the new u would pass ``u_min``/``u_max`` it is clamped and that
        channel's int S and chi_hat are not integrated this step. (:func:`pid_smc_step`.)
        """
        if accel is not None and self._oracle:
            return pid_smc_step_measured(meas, ref, state, dt_s, self.consts, accel)
        return pid_smc_step(meas, ref, state, dt_s, self.consts)

    # -- saturation feedback ----------------------------------------------------------------------
    def anti_windup(
        self,
        prev: Sequence[float],
        new: Sequence[float],
        u_realised: Sequence[float],
        limited: Sequence[bool],
    ) -> tuple[float, ...]:
        """State after the actuators could only realise ``u_realised`` on the ``limited`` channels.

        On a limited channel u tracks what the motors really produce and int S and chi_hat keep
        their previous values (they must not wind up against a limit the law cannot see).
        (:func:`pid_smc_anti_windup`.)
        """
        return pid_smc_anti_windup(prev, new, u_realised, limited)


# -- the pure law -------------------------------------------------------------------------------------
def pid_smc_initial_state(meas: Sequence[float], p: PidSmcConsts) -> tuple[float, ...]:
    """Controller state (12 floats) at t = 0 for the vehicle state ``meas``: u(0) or hover trim."""
    if p.has_u0:
        u0, u1, u2, u3 = p.u0
    else:
        m = p.model
        u0, u1, u2 = 0.0, 0.0, 0.0
        u3 = m[0] * m[1] / tilt_cos(meas[0], meas[2], p.tilt_min)  # mass_kg * gravity_mps2
    c0, c1, c2, c3 = p.chi0
    return (0.0, 0.0, 0.0, 0.0, u0, u1, u2, u3, c0, c1, c2, c3)


def pid_smc_command(state: Sequence[float]) -> Vec4:
    """Continuous form: the input in effect, u (a controller state)."""
    return (state[4], state[5], state[6], state[7])


def _held(at_limit: bool, v: float) -> float:
    return 0.0 if at_limit else v


def pid_smc_derivatives(
    meas: Sequence[float],
    ref: Sequence[float],
    state: Sequence[float],
    p: PidSmcConsts,
    accel: Sequence[float],
    use_accel: bool,
) -> tuple[tuple[float, float, float, float, float, float, float, float, float, float, float, float], Vec4, Vec4, Vec4, Vec4]:
    """Continuous form: (the state's time derivative (d int S, u', chi_hat'), S, sigma, chi_hat in
    use, u' as it acts) for every channel; ``accel`` as :func:`pid_smc_law` takes it.

    Anti-windup in continuous time: no motion further into an input limit, and int S and chi_hat
    freeze on that channel (as in the sampled form).
    """
    s, sg, chi, ud, rate = pid_smc_law(meas, ref, state, p, accel, use_accel, _ZERO4)
    if p.has_limits:
        lo = p.u_lo
        hi = p.u_hi
        at0 = (state[4] >= hi[0] and ud[0] > 0.0) or (state[4] <= lo[0] and ud[0] < 0.0)
        at1 = (state[5] >= hi[1] and ud[1] > 0.0) or (state[5] <= lo[1] and ud[1] < 0.0)
        at2 = (state[6] >= hi[2] and ud[2] > 0.0) or (state[6] <= lo[2] and ud[2] < 0.0)
        at3 = (state[7] >= hi[3] and ud[3] > 0.0) or (state[7] <= lo[3] and ud[3] < 0.0)
        if at0 or at1 or at2 or at3:
            ud = (_held(at0, ud[0]), _held(at1, ud[1]), _held(at2, ud[2]), _held(at3, ud[3]))
            return (
                _held(at0, s[0]), _held(at1, s[1]), _held(at2, s[2]), _held(at3, s[3]),
                ud[0], ud[1], ud[2], ud[3],
                _held(at0, rate[0]), _held(at1, rate[1]), _held(at2, rate[2]), _held(at3, rate[3]),
            ), s, sg, chi, ud  # fmt: skip
    return (s[0], s[1], s[2], s[3], ud[0], ud[1], ud[2], ud[3], rate[0], rate[1], rate[2], rate[3]), s, sg, chi, ud


def pid_smc_law(
    meas: Sequence[float],
    ref: Sequence[float],
    state: Sequence[float],
    p: PidSmcConsts,
    accel: Sequence[float],
    use_accel: bool,
    dist: Sequence[float] = _ZERO4,
) -> tuple[Vec4, Vec4, Vec4, Vec4, Vec4]:
    """(S, sigma, chi_hat in use, u_dot, chi_hat_dot) for every channel; the one copy of the law.

    ``accel`` (measured accelerations) is used for S' only if ``use_accel`` and the constants say
    "oracle"; otherwise pass any 4-tuple. ``dist`` is the disturbance estimate d_hat
    (:mod:`fc.control.observer`), used as the constants' ``dob_mode`` says (ignored for "none").
    """
    (m, k, adaptive, algebraic_chi, theta_uses_phi_chi, oracle, dead_zone, leak, chi_lo, chi_hi, chi0,
     _u_lo, _u_hi, _has_limits, _has_u0, _u0, tilt_min, inv_mass, dob_mode, _dob_w, _dob_tau, _dob_max) = p  # fmt: skip
    phi, phi_d, th, th_d, psi, psi_d, z, z_d = meas
    u0, u1, u2, u3 = state[4], state[5], state[6], state[7]
    wbar = omega_bar_of_inputs(m, u0, u1, u2, u3)
    gz = tilt_cos(phi, th, tilt_min) * inv_mass
    f0, f1, f2, f3 = drift(m, phi_d, th_d, psi_d, z_d, wbar)
    g0, g1, g2 = m[13], m[14], m[15]  # b1, b2, b3
    if dob_mode == 2:  # DOB_LUMPED: the estimate is part of the drift
        f0 += dist[0]
        f1 += dist[1]
        f2 += dist[2]
        f3 += dist[3]
    a0 = f0 + g0 * u0
    a1 = f1 + g1 * u1
    a2 = f2 + g2 * u2
    a3 = f3 + gz * u3
    fd0, fd1, fd2, fd3, gzd = drift_rates(m, phi, phi_d, th, th_d, psi_d, z_d, a0, a1, a2, a3, wbar)
    if use_accel and oracle:
        m0, m1, m2, m3 = accel[0], accel[1], accel[2], accel[3]
    elif dob_mode == 1:  # DOB_SIGMA: estimated acceleration in S' only
        m0, m1, m2, m3 = a0 + dist[0], a1 + dist[1], a2 + dist[2], a3 + dist[3]
    else:
        m0, m1, m2, m3 = a0, a1, a2, a3
    k0, k1, k2, k3 = k
    s0, sg0, ud0 = _channel(phi, phi_d, ref[0], ref[1], ref[2], ref[3], a0, m0, fd0, 0.0, g0, u0, state[0], k0)
    s1, sg1, ud1 = _channel(th, th_d, ref[4], ref[5], ref[6], ref[7], a1, m1, fd1, 0.0, g1, u1, state[1], k1)
    s2, sg2, ud2 = _channel(psi, psi_d, ref[8], ref[9], ref[10], ref[11], a2, m2, fd2, 0.0, g2, u2, state[2], k2)
    s3, sg3, ud3 = _channel(z, z_d, ref[12], ref[13], ref[14], ref[15], a3, m3, fd3, gzd, gz, u3, state[3], k3)
    # Switching gains chi in use and their rates.
    c0, c1, c2, c3 = state[8], state[9], state[10], state[11]
    if adaptive:
        if algebraic_chi:
            c0, c1, c2, c3 = k0[8] * abs(sg0), k1[8] * abs(sg1), k2[8] * abs(sg2), k3[8] * abs(sg3)
            r0 = r1 = r2 = r3 = 0.0
        else:
            r0 = _chi_rate(sg0, c0, k0[8], dead_zone, leak, chi0[0], chi_lo, chi_hi)
            r1 = _chi_rate(sg1, c1, k1[8], dead_zone, leak, chi0[1], chi_lo, chi_hi)
            r2 = _chi_rate(sg2, c2, k2[8], dead_zone, leak, chi0[2], chi_lo, chi_hi)
            r3 = _chi_rate(sg3, c3, k3[8], dead_zone, leak, chi0[3], chi_lo, chi_hi)
        if theta_uses_phi_chi:
            c1 = c0
    else:
        r0 = r1 = r2 = r3 = 0.0
    # u' = -(kd c2 g)^-1 [N + reaching terms] -- the switching part chi sign(sigma) here.
    ud0 -= (c0 if sg0 > 0.0 else -c0 if sg0 < 0.0 else 0.0) * k0[9] / g0
    ud1 -= (c1 if sg1 > 0.0 else -c1 if sg1 < 0.0 else 0.0) * k1[9] / g1
    ud2 -= (c2 if sg2 > 0.0 else -c2 if sg2 < 0.0 else 0.0) * k2[9] / g2
    ud3 -= (c3 if sg3 > 0.0 else -c3 if sg3 < 0.0 else 0.0) * k3[9] / gz
    return (s0, s1, s2, s3), (sg0, sg1, sg2, sg3), (c0, c1, c2, c3), (ud0, ud1, ud2, ud3), (r0, r1, r2, r3)


def _chi_rate(
    sigma: float, chi: float, theta: float, dead_zone: float, leak: float, chi0: float, chi_lo: float, chi_hi: float
) -> float:
    """d chi_hat/dt: Theta max(|sigma| - dead zone, 0) - leak (chi_hat - chi_hat0), projected."""
    mag = abs(sigma) - dead_zone
    rate = theta * mag if mag > 0.0 else 0.0
    if leak != 0.0:
        rate -= leak * (chi - chi0)
    if (chi >= chi_hi and rate > 0.0) or (chi <= chi_lo and rate < 0.0):
        return 0.0
    return rate


def pid_smc_integrate(
    state: Sequence[float], s: Vec4, ud: Vec4, rate: Vec4, dt_s: float, p: PidSmcConsts
) -> tuple[float, ...]:
    """The state after a forward-Euler step of ``dt_s`` (u clamped to its limits; where it is,
    that channel's int S and chi_hat are not integrated; chi_hat projected)."""
    # Unrolled per channel (this is the hot path): u clamped; int S and chi_hat only where it is not.
    lo0, lo1, lo2, lo3 = p.u_lo
    hi0, hi1, hi2, hi3 = p.u_hi
    chi_lo = p.chi_lo
    chi_hi = p.chi_hi
    i0, i1, i2, i3, v0, v1, v2, v3, c0, c1, c2, c3 = state
    u = v0 + dt_s * ud[0]
    if u > hi0:
        v0 = hi0
    elif u < lo0:
        v0 = lo0
    else:
        v0 = u
        i0 = i0 + dt_s * s[0]
        c = c0 + dt_s * rate[0]
        c0 = chi_lo if c < chi_lo else chi_hi if c > chi_hi else c
    u = v1 + dt_s * ud[1]
    if u > hi1:
        v1 = hi1
    elif u < lo1:
        v1 = lo1
    else:
        v1 = u
        i1 = i1 + dt_s * s[1]
        c = c1 + dt_s * rate[1]
        c1 = chi_lo if c < chi_lo else chi_hi if c > chi_hi else c
    u = v2 + dt_s * ud[2]
    if u > hi2:
        v2 = hi2
    elif u < lo2:
        v2 = lo2
    else:
        v2 = u
        i2 = i2 + dt_s * s[2]
        c = c2 + dt_s * rate[2]
        c2 = chi_lo if c < chi_lo else chi_hi if c > chi_hi else c
    u = v3 + dt_s * ud[3]
    if u > hi3:
        v3 = hi3
    elif u < lo3:
        v3 = lo3
    else:
        v3 = u
        i3 = i3 + dt_s * s[3]
        c = c3 + dt_s * rate[3]
        c3 = chi_lo if c < chi_lo else chi_hi if c > chi_hi else c
    return (i0, i1, i2, i3, v0, v1, v2, v3, c0, c1, c2, c3)


def pid_smc_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, p: PidSmcConsts
) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
    """Sampled form (nominal-model sigma): (u to hold for ``dt_s``, new state, diagnostics)."""
    s, sg, chi, ud, rate = pid_smc_law(meas, ref, state, p, _ZERO4, False)
    new = pid_smc_integrate(state, s, ud, rate, dt_s, p)
    u_out = (new[4], new[5], new[6], new[7])
    return u_out, new, Diagnostics(s, sg, chi, u_out, ud)


def pid_smc_step_measured(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, p: PidSmcConsts, accel: Sequence[float]
) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
    """:func:`pid_smc_step` with measured accelerations (used for sigma by "oracle" constants)."""
    s, sg, chi, ud, rate = pid_smc_law(meas, ref, state, p, accel, True)
    new = pid_smc_integrate(state, s, ud, rate, dt_s, p)
    u_out = (new[4], new[5], new[6], new[7])
    return u_out, new, Diagnostics(s, sg, chi, u_out, ud)


def pid_smc_anti_windup(
    prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool]
) -> tuple[float, ...]:
    """On a ``limited`` channel u becomes what the motors realise and int S and chi_hat keep their
    previous values; other channels keep ``new``."""
    l0, l1, l2, l3 = limited[0], limited[1], limited[2], limited[3]
    return (
        prev[0] if l0 else new[0],
        prev[1] if l1 else new[1],
        prev[2] if l2 else new[2],
        prev[3] if l3 else new[3],
        u_realised[0] if l0 else new[4],
        u_realised[1] if l1 else new[5],
        u_realised[2] if l2 else new[6],
        u_realised[3] if l3 else new[7],
        prev[8] if l0 else new[8],
        prev[9] if l1 else new[9],
        prev[10] if l2 else new[10],
        prev[11] if l3 else new[11],
    )


def _channel(
    x: float,
    x_dot: float,
    r: float,
    r_d: float,
    r_dd: float,
    r_ddd: float,
    a_nom: float,
    a_meas: float,
    f_dot: float,
    g_dot: float,
    g: float,
    u: float,
    int_s: float,
    k: tuple[float, ...],
) -> tuple[float, float, float]:
    """One channel of eq. (20) without the chi term: returns (S, sigma, u' so far)."""
    c1, c2, kp, ki, kd, kappa, delta, nu, _theta, inv_kd_c2 = k
    e = x - r
    e_d = x_dot - r_d
    s = c1 * e + c2 * e_d
    e_dd_nom = a_nom - r_dd
    s_dot = c1 * e_d + c2 * (a_meas - r_dd)
    sigma = kp * s + ki * int_s + kd * s_dot
    n = kp * (c1 * e_d + c2 * e_dd_nom) + ki * s + kd * (c1 * e_dd_nom + c2 * (f_dot + g_dot * u - r_ddd))
    reach = kappa * _copysign(abs(sigma) ** delta, sigma) + nu * sigma if sigma != 0.0 else 0.0
    return s, sigma, -(n + reach) * inv_kd_c2 / g
