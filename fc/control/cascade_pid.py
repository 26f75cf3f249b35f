"""Baseline: the cascaded PID most flight stacks fly.

Attitude (phi, theta, psi): angle P -> rate PI, with the reference's rate and acceleration fed
forward::

    rate_cmd = k_angle (x_d - x) + x_d'
    alpha    = k_rate (rate_cmd - x') + ki_rate int (rate_cmd - x') dt + x_d''
    u        = alpha / g            (g = b1, b2, b3: the inertia scaling, no model inversion)

Altitude: P -> climb-rate PI with gravity and tilt feed-forward::

    climb_cmd = k_alt (z_d - z) + z_d'
    a_z       = k_climb (climb_cmd - z') + ki_climb int (climb_cmd - z') dt + z_d''
    u_z       = m (g + a_z) / (cos phi cos theta)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from fc.control.base import Diagnostics, IntegratingBaseline, Vec4
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel



@dataclass(frozen=True)
class CascadePidParams:
    """Gains in channel order (phi, theta, psi, z); for z the "angle" gain is the altitude gain."""

    #: outer P gain, 1/s (angle error -> rate command; altitude error -> climb-rate command).
    k_outer: Vec4 = (6.0, 6.0, 4.0, 2.0)
    #: inner P gain, 1/s (rate error -> angular or vertical acceleration).
    k_inner: Vec4 = (20.0, 20.0, 12.0, 5.0)
    #: inner I gain, 1/s^2.
    ki_inner: Vec4 = (20.0, 20.0, 8.0, 2.0)
    tilt_cos_min: float = 0.05

    def __post_init__(self) -> None:
        for name in ("k_outer", "k_inner", "ki_inner"):
            v = getattr(self, name)
            if len(v) != 4 or not all(math.isfinite(x) and x >= 0.0 for x in v):
                raise InvalidGainError(f"cascade_pid gain {name} needs 4 finite values >= 0, got {v!r}")


class CascadePid(IntegratingBaseline):
    """State: integrals of the inner-loop rate errors ``(I_phi, I_theta, I_psi, I_z)``."""

    name = "cascade_pid"
    state_names = ("int_rate_err_phi", "int_rate_err_theta", "int_rate_err_psi", "int_climb_err_z")

    def __init__(self, model: PaperModel, params: CascadePidParams = CascadePidParams()) -> None:
        self.model = model
        self.params = params

    def _output(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> tuple[Vec4, Vec4, Diagnostics]:
        """(u, inner-loop rate errors = the integrators' derivatives, diagnostics)."""
        p = self.params
        m = self.model
        acc = [0.0] * 4
        err = [0.0] * 4
        for i in range(4):
            rate_cmd = p.k_outer[i] * (ref[4 * i] - meas[2 * i]) + ref[4 * i + 1]
            er = rate_cmd - meas[2 * i + 1]
            acc[i] = p.k_inner[i] * er + p.ki_inner[i] * state[i] + ref[4 * i + 2]
            err[i] = er
        ctc = m.tilt_cos(meas[0], meas[2], p.tilt_cos_min)
        u = (
            acc[0] / m.b1,
            acc[1] / m.b2,
            acc[2] / m.b3,
            m.mass_kg * (m.gravity_mps2 + acc[3]) / ctc,
        )
        return u, (err[0], err[1], err[2], err[3]), Diagnostics(None, None, None, u, None)
