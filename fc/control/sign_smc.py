"""Baseline: conventional SMC on a PID surface, sign(s) acting directly on u.

This is the kind of controller the paper compares against (its ref. [1]): the switching function
is ``s = kp e + ki int e dt + kd e'`` and the reaching law ``s' = -eta sign(s) - lam s`` is solved
for u algebraically::

    u = (kd g)^-1 [-kp e' - ki e - kd (f - x_d'') - eta sign(s) - lam s]

so the discontinuous sign(s) reaches the actuators and u chatters at the sampling rate, which is
the paper's point. The nominal model is the same :class:`~smcpilot.model.PaperModel`; since u is
algebraic, the gyroscopic term uses Omega-bar = 0 (its hover value).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from fc.control.base import Diagnostics, IntegratingBaseline, Vec4
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel, drift, tilt_cos


@dataclass(frozen=True)
class SignSmcParams:
    """Gains per channel (phi, theta, psi, z)."""

    kp: Vec4 = (4.0, 4.0, 4.0, 4.0)
    ki: Vec4 = (2.0, 2.0, 2.0, 2.0)
    kd: Vec4 = (1.0, 1.0, 1.0, 1.0)
    #: switching gain, in units of s' (covers the same disturbance bound as the PID-SMC's chi).
    eta: Vec4 = (1.0, 1.0, 1.5, 3.0)
    #: linear reaching gain, 1/s.
    lam: Vec4 = (0.3, 0.3, 0.15, 0.15)
    tilt_cos_min: float = 0.05

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "eta", "lam"):
            v = getattr(self, name)
            if len(v) != 4 or not all(math.isfinite(x) and x >= 0.0 for x in v):
                raise InvalidGainError(f"sign_smc gain {name} needs 4 finite values >= 0, got {v!r}")
        if any(x <= 0.0 for x in self.kd):
            raise InvalidGainError(f"sign_smc gain kd must be > 0 (u divides by kd g), got {self.kd!r}")


class SignSmcChannel(NamedTuple):
    kp: float
    ki: float
    kd: float
    eta: float
    lam: float


class SignSmcConsts(NamedTuple):
    """:class:`SignSmcParams` and the model's constants, flattened for the pure step (``model``
    and the ``k`` as plain tuples in ModelConsts and SignSmcChannel order, for CPython's fast unpacking)."""

    model: tuple[float | bool, ...]
    k: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    tilt_cos_min: float


def sign_smc_consts(model: PaperModel, params: SignSmcParams) -> SignSmcConsts:
    p = params
    k = tuple(tuple(SignSmcChannel(float(p.kp[i]), float(p.ki[i]), float(p.kd[i]), float(p.eta[i]), float(p.lam[i]))) for i in range(4))
    return SignSmcConsts(tuple(model.consts()), (k[0], k[1], k[2], k[3]), float(p.tilt_cos_min))


class SignSmc(IntegratingBaseline):
    """State: ``(int e_phi, int e_theta, int e_psi, int e_z)``.

    The public face of the pure :func:`sign_smc_output` / :func:`sign_smc_step`.
    """

    name = "sign_smc"
    state_names: tuple[str, ...] = ("int_e_phi", "int_e_theta", "int_e_psi", "int_e_z")

    def __init__(self, model: PaperModel, params: SignSmcParams = SignSmcParams()) -> None:
        self.model = model
        self.params = params
        #: the flattened constants the pure functions take.
        self.consts = sign_smc_consts(model, params)

    def _output(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> tuple[Vec4, Vec4, Diagnostics]:
        """(u, d(int e)/dt = e, diagnostics with sigma = s) for every channel."""
        u, e, s = sign_smc_output(meas, ref, state, self.consts)
        return u, e, Diagnostics(None, s, None, u, None)

    def step(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, accel: Sequence[float] | None = None
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        u, new, s = sign_smc_step(meas, ref, state, dt_s, self.consts)
        return u, new, Diagnostics(None, s, None, u, None)


def _sign_channel(k: tuple[float, ...], x: float, x_dot: float, r: float, r_d: float, r_dd: float, f: float, g: float, integ: float) -> tuple[float, float, float]:
    """(u, e, s) of one channel."""
    kp, ki, kd, eta, lam = k
    ei = x - r
    edi = x_dot - r_d
    si = kp * ei + ki * integ + kd * edi
    sgn = 1.0 if si > 0.0 else -1.0 if si < 0.0 else 0.0
    return (-kp * edi - ki * ei - kd * (f - r_dd) - eta * sgn - lam * si) / (kd * g), ei, si


def sign_smc_output(meas: Sequence[float], ref: Sequence[float], state: Sequence[float], p: SignSmcConsts) -> tuple[Vec4, Vec4, Vec4]:
    """(u, d(int e)/dt = e, s) for every channel (pure)."""
    m, k, tilt_min = p
    f0, f1, f2, f3 = drift(m, meas[1], meas[3], meas[5], meas[7], 0.0)
    gz = tilt_cos(meas[0], meas[2], tilt_min) / m[0]  # mass_kg
    u0, e0, s0 = _sign_channel(k[0], meas[0], meas[1], ref[0], ref[1], ref[2], f0, m[13], state[0])  # b1
    u1, e1, s1 = _sign_channel(k[1], meas[2], meas[3], ref[4], ref[5], ref[6], f1, m[14], state[1])  # b2
    u2, e2, s2 = _sign_channel(k[2], meas[4], meas[5], ref[8], ref[9], ref[10], f2, m[15], state[2])  # b3
    u3, e3, s3 = _sign_channel(k[3], meas[6], meas[7], ref[12], ref[13], ref[14], f3, gz, state[3])
    return (u0, u1, u2, u3), (e0, e1, e2, e3), (s0, s1, s2, s3)


def sign_smc_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, p: SignSmcConsts
) -> tuple[Vec4, Vec4, Vec4]:
    """Sampled form: (u to hold for ``dt_s``, integrators after a forward-Euler step, s)."""
    u, e, s = sign_smc_output(meas, ref, state, p)
    return u, (state[0] + dt_s * e[0], state[1] + dt_s * e[1], state[2] + dt_s * e[2], state[3] + dt_s * e[3]), s
