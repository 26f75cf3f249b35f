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
from dataclasses import dataclass
from typing import Sequence

from fc.control.base import Diagnostics, IntegratingBaseline, Vec4
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel



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


class SignSmc(IntegratingBaseline):
    """State: ``(int e_phi, int e_theta, int e_psi, int e_z)``."""

    name = "sign_smc"
    state_names = ("int_e_phi", "int_e_theta", "int_e_psi", "int_e_z")

    def __init__(self, model: PaperModel, params: SignSmcParams = SignSmcParams()) -> None:
        self.model = model
        self.params = params
        p = params
        self._k = tuple((p.kp[i], p.ki[i], p.kd[i], p.eta[i], p.lam[i]) for i in range(4))

    def _output(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> tuple[Vec4, Vec4, Diagnostics]:
        """(u, d(int e)/dt = e, diagnostics with sigma = s) for every channel."""
        m = self.model
        f = m.drift(meas[1], meas[3], meas[5], meas[7], 0.0)
        g = (m.b1, m.b2, m.b3, m.tilt_cos(meas[0], meas[2], self.params.tilt_cos_min) / m.mass_kg)
        u = [0.0] * 4
        s = [0.0] * 4
        e = [0.0] * 4
        for i in range(4):
            kp, ki, kd, eta, lam = self._k[i]
            ei = meas[2 * i] - ref[4 * i]
            edi = meas[2 * i + 1] - ref[4 * i + 1]
            si = kp * ei + ki * state[i] + kd * edi
            sgn = 1.0 if si > 0.0 else -1.0 if si < 0.0 else 0.0
            u[i] = (-kp * edi - ki * ei - kd * (f[i] - ref[4 * i + 2]) - eta * sgn - lam * si) / (kd * g[i])
            s[i] = si
            e[i] = ei
        uu = (u[0], u[1], u[2], u[3])
        return uu, (e[0], e[1], e[2], e[3]), Diagnostics(None, (s[0], s[1], s[2], s[3]), None, uu, None)
