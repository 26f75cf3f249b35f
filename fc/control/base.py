"""The interface every attitude/altitude controller implements, and the tuples it exchanges.

All quantities are in the paper's frame (z up) and channel order (phi, theta, psi, z); see
:mod:`smcpilot.model`. The tuples are plain so the hot path allocates as little as possible:

``meas`` (8 floats)
    ``(phi, phi_dot, theta, theta_dot, psi, psi_dot, z, z_dot)``: rad, rad/s, m, m/s.
``ref`` (16 floats)
    per channel ``(x_d, x_d', x_d'', x_d''')``, channel-major.
``accel`` (4 floats or None)
    measured ``(phi'', theta'', psi'', z'')``, used only by controllers configured for the
    paper's "oracle" sigma.
``u`` (4 floats)
    inputs ``(u_phi [N], u_theta [N], u_psi [N m], u_z [N])`` = the paper's (u2, u3, u4, u1).
``state``
    the controller's own states, a flat tuple whose meaning is given by ``state_names``.

A controller offers the same law in two forms:

- continuous time: :meth:`Controller.command` gives u for the current state and
  :meth:`Controller.derivatives` the time derivative of the state, for integrating the
  controller inside the plant's ODE;
- sampled data: :meth:`Controller.step` advances the state by ``dt_s`` (forward Euler of the
  same derivatives, zero-order hold) and returns the u to hold until the next step.

Each law's sampled form is also a module-level pure function of tuples and a NamedTuple of
constants (``pid_smc_step``, ``cascade_pid_step``, ``sign_smc_step``; anti-windup
:func:`integrators_anti_windup` here for the baselines): what the flight pipeline calls. The
classes validate their parameters once, flatten them (``consts``) and wrap those functions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol

Meas = Sequence[float]
Ref = Sequence[float]
Vec4 = tuple[float, float, float, float]


class Diagnostics(NamedTuple):
    """Per-channel internals (each a 4-tuple in channel order, or None where it has no meaning).

    ``s``: sliding variable S = c1 e + c2 e'; ``sigma``: PID sliding manifold (or the baseline's
    switching function); ``chi_hat``: switching gain in use; ``u``: input; ``u_dot``: its rate.
    """

    s: Vec4 | None
    sigma: Vec4 | None
    chi_hat: Vec4 | None
    u: Vec4
    u_dot: Vec4 | None


class Controller(Protocol):
    """What the runners, the flight controller and the benchmarks need from a control law."""

    #: short identifier (``pid_smc``, ``adaptive_pid_smc``, ``sign_smc``, ``cascade_pid``).
    name: str
    #: names of the entries of the state tuple.
    state_names: tuple[str, ...]

    def initial_state(self, meas: Meas) -> tuple[float, ...]:
        """Controller state at t = 0 for the vehicle state ``meas``."""
        ...

    def command(self, meas: Meas, ref: Ref, state: Sequence[float]) -> Vec4:
        """Input u in effect for this state (continuous-time form)."""
        ...

    def derivatives(
        self, meas: Meas, ref: Ref, state: Sequence[float], accel: Sequence[float] | None = None
    ) -> tuple[tuple[float, ...], Diagnostics]:
        """Time derivative of the state and the diagnostics (continuous-time form)."""
        ...

    def step(
        self,
        meas: Meas,
        ref: Ref,
        state: Sequence[float],
        dt_s: float,
        accel: Sequence[float] | None = None,
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        """Advance by ``dt_s`` seconds; return (u to hold, new state, diagnostics)."""
        ...


class IntegratingBaseline:
    """Shared machinery of the baselines whose u is algebraic and whose states are integrators.

    Subclasses implement :meth:`_output` returning (u, state derivative, diagnostics); the
    continuous form integrates the derivative in the ODE, the sampled form by forward Euler.
    """

    state_names: tuple[str, ...]
    #: the last (meas, ref, state) objects and their output: command() then derivatives() on the
    #: same objects (what an ODE right-hand side does) computes the law once. Keyed on identity,
    #: so callers must pass new sequences rather than mutate one in place (tuples, or fresh slices).
    _memo: tuple = (None, None, None, None)

    def initial_state(self, meas: Meas) -> tuple[float, ...]:
        return (0.0,) * len(self.state_names)

    def _output(self, meas: Meas, ref: Ref, state: Sequence[float]) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        raise NotImplementedError

    def _cached(self, meas: Meas, ref: Ref, state: Sequence[float]) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        m = self._memo
        if m[0] is meas and m[1] is ref and m[2] is state:
            return m[3]
        out = self._output(meas, ref, state)
        self._memo = (meas, ref, state, out)
        return out

    def command(self, meas: Meas, ref: Ref, state: Sequence[float]) -> Vec4:
        return self._cached(meas, ref, state)[0]

    def derivatives(
        self, meas: Meas, ref: Ref, state: Sequence[float], accel: Sequence[float] | None = None
    ) -> tuple[tuple[float, ...], Diagnostics]:
        _u, d, diag = self._cached(meas, ref, state)
        return d, diag

    def step(
        self, meas: Meas, ref: Ref, state: Sequence[float], dt_s: float, accel: Sequence[float] | None = None
    ) -> tuple[Vec4, tuple[float, ...], Diagnostics]:
        u, d, diag = self._output(meas, ref, state)
        return u, tuple(x + dt_s * dx for x, dx in zip(state, d)), diag

    def anti_windup(
        self, prev: Sequence[float], new: Sequence[float], u_realised: Sequence[float], limited: Sequence[bool]
    ) -> tuple[float, ...]:
        """Integrators of limited channels keep their previous values (:func:`integrators_anti_windup`)."""
        return integrators_anti_windup(prev, new, limited)


def integrators_anti_windup(prev: Sequence[float], new: Sequence[float], limited: Sequence[bool]) -> Vec4:
    """Four integrators: those of ``limited`` channels keep their previous values (pure)."""
    return (
        prev[0] if limited[0] else new[0],
        prev[1] if limited[1] else new[1],
        prev[2] if limited[2] else new[2],
        prev[3] if limited[3] else new[3],
    )


def constant_reference(targets: Sequence[float]) -> tuple[float, ...]:
    """The 16-float reference of constant set-points (derivatives zero), channel order."""
    if len(targets) != 4:
        raise ValueError("need 4 targets (phi, theta, psi, z)")
    out: list[float] = []
    for x in targets:
        out.extend((float(x), 0.0, 0.0, 0.0))
    return tuple(out)
