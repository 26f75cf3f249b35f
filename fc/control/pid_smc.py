"""The PID sliding-mode controller of the paper, corrected (``pid-smc-spec.md`` §§2-4).

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Sequence

from fc.control.base import Diagnostics, Vec4
from fc.control.gains import PAPER_GAINS, ChannelGains, Gains4
from smcpilot.errors import InvalidGainError
from smcpilot.model import CHANNELS, PaperModel
from smcpilot.typos import CONTROLLER_TYPOS, parse_typos

_INF = math.inf
_copysign = math.copysign


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
        object.__setattr__(self, "typos", parse_typos(self.typos) & CONTROLLER_TYPOS)


class PidSmc:
    """Adaptive (default) or known-bound PID-SMC on the four channels.

    State tuple (12 floats): ``(I_phi, I_theta, I_psi, I_z, u_phi, u_theta, u_psi, u_z,
    chi_phi, chi_theta, chi_psi, chi_z)`` with I = int S dt.
    """

    state_names = tuple(f"int_s_{c}" for c in CHANNELS) + tuple(f"u_{c}" for c in CHANNELS) + tuple(
        f"chi_hat_{c}" for c in CHANNELS
    )

    def __init__(self, model: PaperModel, params: PidSmcParams = PidSmcParams()) -> None:
        self.model = model
        self.params = params
        self.name = "adaptive_pid_smc" if params.adaptive else "pid_smc"
        ty = params.typos
        # Per-channel constants, flattened once: the hot path reads them from tuples.
        self._k = tuple(
            (
                g.c1,
                g.c2,
                g.kp,
                g.ki,
                g.kd,
                g.kappa,
                g.delta,
                g.nu,
                g.adapt_rate,
                # 1/(kd c2) (the paper's literal prefactor drops kd)
                1.0 / (g.c2 if "prefactor" in ty else g.kd * g.c2),
            )
            for g in params.gains
        )
        self._adaptive = params.adaptive
        self._algebraic_chi = "adaptive-law" in ty
        self._theta_uses_phi_chi = "theta-chi" in ty
        self._oracle = params.sigma_source == "oracle"
        a = params.adaptation
        self._dead_zone = a.dead_zone
        self._leak = a.leakage_per_s
        self._chi_lo = a.chi_hat_min
        self._chi_hi = a.chi_hat_max
        self._chi0 = params.chi_hat0 if params.adaptive else tuple(g.chi for g in params.gains)
        self._u_lo = params.u_min
        self._u_hi = params.u_max
        self._has_limits = any(math.isfinite(v) for v in params.u_min + params.u_max)
        self._tilt_min = params.tilt_cos_min
        self._inv_mass = 1.0 / model.mass_kg

    # -- state ------------------------------------------------------------------------------------
    def initial_state(self, meas: Sequence[float]) -> tuple[float, ...]:
        if self.params.u0 is not None:
            u = self.params.u0
        else:
            cphi_ctheta = self.model.tilt_cos(meas[0], meas[2], self._tilt_min)
            u = (0.0, 0.0, 0.0, self.model.mass_kg * self.model.gravity_mps2 / cphi_ctheta)
        return (0.0, 0.0, 0.0, 0.0) + tuple(float(x) for x in u) + tuple(float(c) for c in self._chi0)

    def command(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> Vec4:
        """u is a controller state: the command is simply its current value."""
        return (state[4], state[5], state[6], state[7])

    # -- the law ----------------------------------------------------------------------------------
    def _law(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], accel: Sequence[float] | None
    ) -> tuple[Vec4, Vec4, Vec4, Vec4, Vec4]:
        """(S, sigma, chi_hat in use, u_dot, chi_hat_dot) for every channel; the one copy of the law."""
        phi, phi_d, th, th_d, psi, psi_d, z, z_d = meas
        u0, u1, u2, u3 = state[4], state[5], state[6], state[7]
        model = self.model
        wbar = model.omega_bar_of_inputs(u0, u1, u2, u3)
        gz = model.tilt_cos(phi, th, self._tilt_min) * self._inv_mass
        f0, f1, f2, f3 = model.drift(phi_d, th_d, psi_d, z_d, wbar)
        g0, g1, g2 = model.b1, model.b2, model.b3
        a0 = f0 + g0 * u0
        a1 = f1 + g1 * u1
        a2 = f2 + g2 * u2
        a3 = f3 + gz * u3
        fd0, fd1, fd2, fd3, gzd = model.drift_rates(phi, phi_d, th, th_d, psi_d, z_d, a0, a1, a2, a3, wbar)
        if accel is not None and self._oracle:
            m0, m1, m2, m3 = accel
        else:
            m0, m1, m2, m3 = a0, a1, a2, a3
        k = self._k
        s0, sg0, ud0 = _channel(phi, phi_d, ref[0], ref[1], ref[2], ref[3], a0, m0, fd0, 0.0, g0, u0, state[0], k[0])
        s1, sg1, ud1 = _channel(th, th_d, ref[4], ref[5], ref[6], ref[7], a1, m1, fd1, 0.0, g1, u1, state[1], k[1])
        s2, sg2, ud2 = _channel(psi, psi_d, ref[8], ref[9], ref[10], ref[11], a2, m2, fd2, 0.0, g2, u2, state[2], k[2])
        s3, sg3, ud3 = _channel(z, z_d, ref[12], ref[13], ref[14], ref[15], a3, m3, fd3, gzd, gz, u3, state[3], k[3])
        # Switching gains chi in use and their rates.
        c0, c1, c2, c3 = state[8], state[9], state[10], state[11]
        if self._adaptive:
            if self._algebraic_chi:
                c0, c1, c2, c3 = k[0][8] * abs(sg0), k[1][8] * abs(sg1), k[2][8] * abs(sg2), k[3][8] * abs(sg3)
                r0 = r1 = r2 = r3 = 0.0
            else:
                r0 = self._chi_rate(sg0, c0, 0)
                r1 = self._chi_rate(sg1, c1, 1)
                r2 = self._chi_rate(sg2, c2, 2)
                r3 = self._chi_rate(sg3, c3, 3)
            if self._theta_uses_phi_chi:
                c1 = c0
        else:
            r0 = r1 = r2 = r3 = 0.0
        # u' = -(kd c2 g)^-1 [N + reaching terms] -- the switching part chi sign(sigma) here.
        ud0 -= (c0 if sg0 > 0.0 else -c0 if sg0 < 0.0 else 0.0) * k[0][9] / g0
        ud1 -= (c1 if sg1 > 0.0 else -c1 if sg1 < 0.0 else 0.0) * k[1][9] / g1
        ud2 -= (c2 if sg2 > 0.0 else -c2 if sg2 < 0.0 else 0.0) * k[2][9] / g2
        ud3 -= (c3 if sg3 > 0.0 else -c3 if sg3 < 0.0 else 0.0) * k[3][9] / gz
        return (s0, s1, s2, s3), (sg0, sg1, sg2, sg3), (c0, c1, c2, c3), (ud0, ud1, ud2, ud3), (r0, r1, r2, r3)

    def _chi_rate(self, sigma: float, chi: float, i: int) -> float:
        mag = abs(sigma) - self._dead_zone
        rate = self._k[i][8] * mag if mag > 0.0 else 0.0
        if self._leak:
            rate -= self._leak * (chi - self._chi0[i])
        if (chi >= self._chi_hi and rate > 0.0) or (chi <= self._chi_lo and rate < 0.0):
            return 0.0
        return rate

    # -- continuous-time form ---------------------------------------------------------------------
    def derivatives(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], accel: Sequence[float] | None = None
    ) -> tuple[tuple[float, ...], Diagnostics]:
        s, sg, chi, ud, rate = self._law(meas, ref, state, accel)
        if self._has_limits:
            # Anti-windup in continuous time: no motion further into an input limit, and int S and
            # chi_hat freeze on that channel (as in the sampled form).
            lo, hi = self._u_lo, self._u_hi
            at = [(state[4 + i] >= hi[i] and ud[i] > 0.0) or (state[4 + i] <= lo[i] and ud[i] < 0.0) for i in range(4)]
            if any(at):
                ud = tuple(0.0 if at[i] else ud[i] for i in range(4))
                ds = tuple(0.0 if at[i] else s[i] for i in range(4))
                rate = tuple(0.0 if at[i] else rate[i] for i in range(4))
                u = (state[4], state[5], state[6], state[7])
                return ds + ud + rate, Diagnostics(s, sg, chi, u, ud)
        u = (state[4], state[5], state[6], state[7])
        return s + ud + rate, Diagnostics(s, sg, chi, u, ud)

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
        channel's int S and chi_hat are not integrated this step.
        """
        s, sg, chi, ud, rate = self._law(meas, ref, state, accel)
        lo, hi = self._u_lo, self._u_hi
        new = list(state)
        for i in range(4):
            u = state[4 + i] + dt_s * ud[i]
            if u > hi[i]:
                new[4 + i] = hi[i]
            elif u < lo[i]:
                new[4 + i] = lo[i]
            else:
                new[4 + i] = u
                new[i] = state[i] + dt_s * s[i]
                c = state[8 + i] + dt_s * rate[i]
                new[8 + i] = self._chi_lo if c < self._chi_lo else self._chi_hi if c > self._chi_hi else c
        u_out = (new[4], new[5], new[6], new[7])
        return u_out, tuple(new), Diagnostics(s, sg, chi, u_out, ud)


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
        """
        out = list(new)
        for i in range(4):
            if limited[i]:
                out[i] = prev[i]
                out[4 + i] = u_realised[i]
                out[8 + i] = prev[8 + i]
        return tuple(out)


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
