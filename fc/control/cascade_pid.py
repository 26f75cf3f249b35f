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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from fc.control.base import Diagnostics, IntegratingBaseline, Vec4
from smcpilot.errors import InvalidGainError
from smcpilot.model import PaperModel, tilt_cos


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


def cascade_pid_consts(model: PaperModel, params: CascadePidParams) -> CascadePidConsts:
    def f4(v: Sequence[float]) -> Vec4:
        return (float(v[0]), float(v[1]), float(v[2]), float(v[3]))

    return CascadePidConsts(
        f4(params.k_outer), f4(params.k_inner), f4(params.ki_inner), float(params.tilt_cos_min),
        float(model.b1), float(model.b2), float(model.b3), float(model.mass_kg), float(model.gravity_mps2),
    )  # fmt: skip


class CascadePid(IntegratingBaseline):
    """State: integrals of the inner-loop rate errors ``(I_phi, I_theta, I_psi, I_z)``.

    The public face of the pure :func:`cascade_pid_output` / :func:`cascade_pid_step`.
    """

    name = "cascade_pid"
    state_names: tuple[str, ...] = ("int_rate_err_phi", "int_rate_err_theta", "int_rate_err_psi", "int_climb_err_z")

    def __init__(self, model: PaperModel, params: CascadePidParams = CascadePidParams()) -> None:
        self.model = model
        self.params = params
        #: the flattened constants the pure functions take.
        self.consts = cascade_pid_consts(model, params)

    def _output(self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float]) -> tuple[Vec4, Vec4, Diagnostics]:
        """(u, inner-loop rate errors = the integrators' derivatives, diagnostics)."""
        u, err = cascade_pid_output(meas, ref, state, self.consts)
        return u, err, Diagnostics(None, None, None, u, None)

    def step(
        self, meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, accel: Sequence[float] | None = None
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        u, new = cascade_pid_step(meas, ref, state, dt_s, self.consts)
        return u, new, Diagnostics(None, None, None, u, None)


def _cascade_channel(
    k_outer: float, k_inner: float, ki_inner: float, x: float, x_dot: float, r: float, r_d: float, r_dd: float, integ: float
) -> tuple[float, float]:
    """(commanded acceleration, inner-loop rate error) of one channel."""
    rate_cmd = k_outer * (r - x) + r_d
    er = rate_cmd - x_dot
    return k_inner * er + ki_inner * integ + r_dd, er


def cascade_pid_output(meas: Sequence[float], ref: Sequence[float], state: Sequence[float], p: CascadePidConsts) -> tuple[Vec4, Vec4]:
    """(u, inner-loop rate errors = the integrators' derivatives) for every channel (pure)."""
    ko, kin, kii, tilt_min, b1, b2, b3, mass, g = p
    acc0, e0 = _cascade_channel(ko[0], kin[0], kii[0], meas[0], meas[1], ref[0], ref[1], ref[2], state[0])
    acc1, e1 = _cascade_channel(ko[1], kin[1], kii[1], meas[2], meas[3], ref[4], ref[5], ref[6], state[1])
    acc2, e2 = _cascade_channel(ko[2], kin[2], kii[2], meas[4], meas[5], ref[8], ref[9], ref[10], state[2])
    acc3, e3 = _cascade_channel(ko[3], kin[3], kii[3], meas[6], meas[7], ref[12], ref[13], ref[14], state[3])
    ctc = tilt_cos(meas[0], meas[2], tilt_min)
    return (acc0 / b1, acc1 / b2, acc2 / b3, mass * (g + acc3) / ctc), (e0, e1, e2, e3)


def cascade_pid_step(
    meas: Sequence[float], ref: Sequence[float], state: Sequence[float], dt_s: float, p: CascadePidConsts
) -> tuple[Vec4, Vec4]:
    """Sampled form: (u to hold for ``dt_s``, integrators after a forward-Euler step)."""
    u, e = cascade_pid_output(meas, ref, state, p)
    return u, (state[0] + dt_s * e[0], state[1] + dt_s * e[1], state[2] + dt_s * e[2], state[3] + dt_s * e[3])
