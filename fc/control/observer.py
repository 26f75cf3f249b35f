"""A disturbance observer for the PID-SMC: what the nominal model does not explain, estimated on board.

The law's sliding manifold needs the channel accelerations e'' (paper eq. 19-20). With the nominal
model alone (``a = f + g u``) an unmodelled torque or force -- a weak motor, a gust, a wrong mass --
is invisible to sigma and reaches the law only through the slow surface dynamics. This module
estimates, per channel k in (phi, theta, psi, z), the lumped disturbance

    d_k = x_k'' - (f_k(x) + g_k u_k)          (rad/s^2 for the angles, m/s^2 for z)

from the quantities the FC receives (Euler-angle rates and the vertical velocity) and the input it
applied, with a first-order low-pass observer of bandwidth L_k (rad/s)::

    d_hat = xi + L x'                        (x' the measured rate)
    xi'   = -L (f(x) + g u_eff + d_hat)      (no differentiation of the measurement)

so that d_hat' = L (x'' - f - g u_eff - d_hat) = L (d - d_hat): d_hat follows d through a
first-order lag 1/L. ``u_eff`` is the input as the rotors realise it: the commanded (mixer-realised)
input through the motors' first-order lag (time constant tau_m of the vehicle; 0: no lag). Without
that the lag itself would read as a disturbance during every manoeuvre.

Discretisation (control period dt, input held): the rotor lag is solved exactly,
``u_eff(k+1) = u_r + (u_eff(k) - u_r) a`` with ``a = exp(-dt / tau_m)``, and the observer uses the
input averaged over the period, ``u_r + (u_eff(k) - u_r) b`` with ``b = tau_m (1 - a) / dt``, so
``d_hat(k+1) = d_hat(k) + L dt ((x'(k+1) - x'(k)) / dt - a_nom(k) - d_hat(k))``: a discrete
low-pass of the acceleration residual. |d_hat| is clamped to ``d_max`` per channel (the vehicle's
authority), and the estimate is held at 0 while the vehicle is on the ground (the ground's reaction
is not a disturbance to cancel).

How the law uses d_hat is the law's choice (:class:`fc.control.pid_smc.PidSmcParams`,
``disturbance_estimate``): in sigma only (the paper's measured-acceleration sigma made real), or
lumped into f (sigma and the equivalent control). Derivation, filter design and the stability
argument: ``docs/disturbance-observer.md``.

Pure functions of tuples and floats (numba-compilable, see ``tests/test_compilable.py``). The
observer state is 8 floats: ``(xi_phi, xi_theta, xi_psi, xi_z, u_eff_phi, u_eff_theta, u_eff_psi,
u_eff_z)``.
"""

from __future__ import annotations

from collections.abc import Sequence

from smcpilot.model import drift, omega_bar_of_inputs, tilt_cos

_ZERO8 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def observer_reset(meas: Sequence[float], u: Sequence[float], w: Sequence[float]) -> tuple[float, ...]:
    """Observer state giving d_hat = 0 at the measured rates ``meas`` (8-tuple, law order), with the
    realised input ``u`` as the rotors' current state."""
    return (
        -w[0] * meas[1], -w[1] * meas[3], -w[2] * meas[5], -w[3] * meas[7],
        u[0], u[1], u[2], u[3],
    )  # fmt: skip


def observer_estimate(obs: Sequence[float], meas: Sequence[float], w: Sequence[float], d_max: Sequence[float]) -> tuple[float, float, float, float]:
    """d_hat per channel (rad/s^2, rad/s^2, rad/s^2, m/s^2), clamped to +-``d_max``."""
    d0 = obs[0] + w[0] * meas[1]
    d1 = obs[1] + w[1] * meas[3]
    d2 = obs[2] + w[2] * meas[5]
    d3 = obs[3] + w[3] * meas[7]
    m0, m1, m2, m3 = d_max[0], d_max[1], d_max[2], d_max[3]
    d0 = m0 if d0 > m0 else (-m0 if d0 < -m0 else d0)
    d1 = m1 if d1 > m1 else (-m1 if d1 < -m1 else d1)
    d2 = m2 if d2 > m2 else (-m2 if d2 < -m2 else d2)
    d3 = m3 if d3 > m3 else (-m3 if d3 < -m3 else d3)
    return (d0, d1, d2, d3)


def observer_update(
    obs: Sequence[float],
    meas: Sequence[float],
    d_hat: Sequence[float],
    u_applied: Sequence[float],
    model: tuple[float | bool, ...],
    w: Sequence[float],
    tilt_min: float,
    inv_mass: float,
    lag_a: float,
    lag_b: float,
    dt_s: float,
) -> tuple[float, ...]:
    """The observer state after one control period with ``u_applied`` held (what the mixer realised).

    ``meas``: the law's 8-tuple at the start of the period; ``model``: the law's model constants
    (:class:`smcpilot.model.ModelConsts` order); ``lag_a`` = exp(-dt/tau_m), ``lag_b`` =
    tau_m (1 - lag_a)/dt (both 0 without a lag model: the input acts at once).
    """
    gz = tilt_cos(meas[0], meas[2], tilt_min) * inv_mass
    return observer_update_gz(obs, meas, d_hat, u_applied, model, w, gz, lag_a, lag_b, dt_s)


def observer_update_gz(
    obs: Sequence[float],
    meas: Sequence[float],
    d_hat: Sequence[float],
    u_applied: Sequence[float],
    model: tuple[float | bool, ...],
    w: Sequence[float],
    gz: float,
    lag_a: float,
    lag_b: float,
    dt_s: float,
) -> tuple[float, ...]:
    """:func:`observer_update` with the input gain of the z channel, ``gz`` = tilt_cos(phi, theta,
    tilt_min) * inv_mass, given (a caller that has it already)."""
    e0, e1, e2, e3 = obs[4], obs[5], obs[6], obs[7]
    r0, r1, r2, r3 = u_applied[0], u_applied[1], u_applied[2], u_applied[3]
    # the input the rotors deliver, averaged over the period, and at its end
    v0 = r0 + (e0 - r0) * lag_b
    v1 = r1 + (e1 - r1) * lag_b
    v2 = r2 + (e2 - r2) * lag_b
    v3 = r3 + (e3 - r3) * lag_b
    phi_d, th_d, psi_d, z_d = meas[1], meas[3], meas[5], meas[7]
    wbar = omega_bar_of_inputs(model, v0, v1, v2, v3)
    f0, f1, f2, f3 = drift(model, phi_d, th_d, psi_d, z_d, wbar)
    a0 = f0 + model[13] * v0
    a1 = f1 + model[14] * v1
    a2 = f2 + model[15] * v2
    a3 = f3 + gz * v3
    # xi restarts from the (clamped) estimate in use, so a clamp cannot wind the observer up
    d0, d1, d2, d3 = d_hat[0], d_hat[1], d_hat[2], d_hat[3]
    return (
        d0 - w[0] * (phi_d + dt_s * (a0 + d0)),
        d1 - w[1] * (th_d + dt_s * (a1 + d1)),
        d2 - w[2] * (psi_d + dt_s * (a2 + d2)),
        d3 - w[3] * (z_d + dt_s * (a3 + d3)),
        r0 + (e0 - r0) * lag_a,
        r1 + (e1 - r1) * lag_a,
        r2 + (e2 - r2) * lag_a,
        r3 + (e3 - r3) * lag_a,
    )


#: the observer's pure functions (checked and compiled by ``tests/test_compilable.py``).
OBSERVER_FUNCTIONS = (observer_reset, observer_estimate, observer_update, observer_update_gz)
