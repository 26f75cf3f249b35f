"""In-process closed-loop simulation of a controller on a plant, without MAVLink.

Two forms, matching the controller's two forms (:mod:`fc.control.base`):

- **continuous time** (default): plant and controller states are integrated together by one
  classical RK4 step of ``dt_s`` (1 ms by default), so the controller's integrated u, int S and
  chi_hat are part of the ODE;
- **sampled data** (``rate_hz``): the controller steps at ``rate_hz`` with a zero-order hold and
  the plant alone is integrated by RK4 at ``dt_s`` in between.

Samples are recorded every ``dt_s`` (1 kHz by default), at the start of each step. A run that
produces non-finite or absurd values stops and is reported as diverged, with the time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from fc.control.base import Controller
from smcpilot.errors import ConfigError

RefFn = Callable[[float], Sequence[float]]
_isfinite = math.isfinite

#: Limits past which a run counts as diverged (rad/s, m, N or N m).
DIVERGED_RATE = 1.0e3
DIVERGED_POSITION = 1.0e4
DIVERGED_INPUT = 1.0e6


class OdePlant(Protocol):
    """The continuous-time form of a plant (its derivatives), what :func:`simulate` integrates together
    with the controller's states; the stepping form every SITL runner uses is :class:`sim_bridge.plants.base.Plant`.
    What :func:`simulate` needs from a plant (see :class:`sim_bridge.plants.paper.PaperPlant`)."""

    @property
    def state_names(self) -> tuple[str, ...]: ...

    def derivatives(self, t_s: float, y: Sequence[float], u: Sequence[float]) -> tuple[Any, Any, Any]:
        """(dy/dt, true accelerations (4), rotor speeds squared (4))."""
        ...


@dataclass
class Trajectory:
    """A recorded run. Arrays have one row per sample (``dt_s`` apart)."""

    controller: str
    t_s: np.ndarray
    #: plant state, columns as the plant's ``state_names``.
    x: np.ndarray
    #: references x_d per channel (phi, theta, psi, z).
    x_ref: np.ndarray
    #: inputs (u_phi [N], u_theta [N], u_psi [N m], u_z [N]).
    u: np.ndarray
    #: rotor speeds squared, (rad/s)^2.
    w_sq: np.ndarray
    s: np.ndarray | None
    sigma: np.ndarray | None
    chi_hat: np.ndarray | None
    diverged: bool
    diverged_at_s: float | None
    reason: str
    dt_s: float
    rate_hz: float | None

    @property
    def errors(self) -> np.ndarray:
        """Tracking errors e = x - x_d per channel."""
        return self.x[:, [0, 2, 4, 6]] - self.x_ref


def _bad(y: Sequence[float], u: Sequence[float]) -> str | None:
    """Why this sample means divergence, or None (checked every step: a cheap fast path first)."""
    total = sum(y) + u[0] + u[1] + u[2] + u[3]
    if (
        _isfinite(total)
        and -DIVERGED_RATE < y[1] < DIVERGED_RATE
        and -DIVERGED_RATE < y[3] < DIVERGED_RATE
        and -DIVERGED_RATE < y[5] < DIVERGED_RATE
        and -DIVERGED_POSITION < y[6] < DIVERGED_POSITION
        and -DIVERGED_POSITION < y[7] < DIVERGED_POSITION
        and -DIVERGED_INPUT < u[0] < DIVERGED_INPUT
        and -DIVERGED_INPUT < u[1] < DIVERGED_INPUT
        and -DIVERGED_INPUT < u[2] < DIVERGED_INPUT
        and -DIVERGED_INPUT < u[3] < DIVERGED_INPUT
    ):
        return None
    if not _isfinite(total):
        return "non-finite state or input"
    for i in (1, 3, 5):
        if abs(y[i]) >= DIVERGED_RATE:
            return f"angular rate above {DIVERGED_RATE:g} rad/s"
    if abs(y[6]) >= DIVERGED_POSITION or abs(y[7]) >= DIVERGED_POSITION:
        return "altitude or climb rate out of range"
    return f"input above {DIVERGED_INPUT:g}"


def simulate(
    controller: Controller,
    plant: OdePlant,
    reference: Sequence[float] | RefFn,
    x0: Sequence[float],
    duration_s: float,
    dt_s: float = 1.0e-3,
    rate_hz: float | None = None,
) -> Trajectory:
    """Fly ``controller`` on ``plant`` from ``x0`` for ``duration_s`` and record every ``dt_s``.

    ``reference`` is the 16-float reference (constant) or a function of time returning one.
    ``x0`` is the 12-float plant state. With ``rate_hz`` the controller runs sampled (its period
    must be a whole number of ``dt_s`` steps).
    """
    if not (duration_s > 0.0 and math.isfinite(duration_s)):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration_s!r}")
    if not (0.0 < dt_s <= 0.1):
        raise ConfigError(f"integration step must lie in (0, 0.1] s, got {dt_s!r}")
    substeps = 1
    if rate_hz is not None:
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
            raise ConfigError(f"control rate must be a positive number of Hz, got {rate_hz!r}")
        ratio = 1.0 / (rate_hz * dt_s)
        substeps = round(ratio)
        if substeps < 1 or abs(ratio - substeps) > 1e-9 * max(1.0, ratio):
            raise ConfigError(
                f"control rate {rate_hz:g} Hz must divide the physics rate {1.0 / dt_s:g} Hz"
                " (e.g. 1000, 500, 250, 200, 100)"
            )
    ref_fn: RefFn | None = reference if callable(reference) else None
    ref_const: tuple[float, ...] = () if ref_fn is not None else tuple(float(v) for v in reference)  # type: ignore[union-attr]
    n_steps = int(round(duration_s / dt_s))
    nx = len(x0)
    y: list[float] = [float(v) for v in x0]
    c: Sequence[float] = list(controller.initial_state(y[:8]))
    rec_t: list[float] = []
    rec_x: list[Sequence[float]] = []
    rec_ref: list[tuple[float, float, float, float]] = []
    rec_u: list[Sequence[float]] = []
    rec_w: list[Sequence[float]] = []
    rec_s: list = []
    rec_sig: list = []
    rec_chi: list = []
    diverged_at: float | None = None
    reason = ""
    t = 0.0
    h = dt_s

    def record(t: float, y: Sequence[float], ref: Sequence[float], u, w, diag) -> None:
        rec_t.append(t)
        rec_x.append(tuple(y))
        rec_ref.append((ref[0], ref[4], ref[8], ref[12]))
        rec_u.append(u)
        rec_w.append(w)
        rec_s.append(diag.s)
        rec_sig.append(diag.sigma)
        rec_chi.append(diag.chi_hat)

    try:
        if rate_hz is None:
            # Continuous time: one ODE of plant + controller states.
            def closed(t: float, yy: Sequence[float]):
                ref = ref_fn(t) if ref_fn is not None else ref_const
                meas = yy[:8]
                cs = yy[nx:]
                u = controller.command(meas, ref, cs)
                dp, acc, w = plant.derivatives(t, yy[:nx], u)
                dc, diag = controller.derivatives(meas, ref, cs, acc)
                return dp + dc, u, w, diag, ref

            yy = y + list(c)
            h2 = 0.5 * h
            h6 = h / 6.0
            for i in range(n_steps + 1):
                k1, u, w, diag, ref = closed(t, yy)
                why = _bad(yy, u)
                if why:
                    diverged_at, reason = t, why
                    if i == 0:  # keep one sample, so a run diverged at the start still has metrics
                        record(t, yy[:nx], ref, u, w, diag)
                    break
                record(t, yy[:nx], ref, u, w, diag)
                if i == n_steps:
                    break
                k2 = closed(t + h2, [a + h2 * b for a, b in zip(yy, k1)])[0]
                k3 = closed(t + h2, [a + h2 * b for a, b in zip(yy, k2)])[0]
                k4 = closed(t + h, [a + h * b for a, b in zip(yy, k3)])[0]
                yy = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(yy, k1, k2, k3, k4)]
                t = (i + 1) * h
        else:
            # Sampled data: controller at rate_hz (ZOH), plant RK4 at dt_s.
            dt_ctrl = substeps * h
            u = None
            diag = None
            h2 = 0.5 * h
            h6 = h / 6.0
            for i in range(n_steps + 1):
                ref = ref_fn(t) if ref_fn is not None else ref_const
                if i % substeps == 0:
                    acc: Sequence[float] | None = plant.derivatives(t, y, u)[1] if u is not None else None
                    u, c, diag = controller.step(y[:8], ref, c, dt_ctrl, acc)
                k1, _acc, w = plant.derivatives(t, y, u)
                why = _bad(y, u)
                if why:
                    diverged_at, reason = t, why
                    if i == 0:  # keep one sample, so a run diverged at the start still has metrics
                        record(t, y, ref, u, w, diag)
                    break
                record(t, y, ref, u, w, diag)
                if i == n_steps:
                    break
                k2 = plant.derivatives(t + h2, [a + h2 * b for a, b in zip(y, k1)], u)[0]
                k3 = plant.derivatives(t + h2, [a + h2 * b for a, b in zip(y, k2)], u)[0]
                k4 = plant.derivatives(t + h, [a + h * b for a, b in zip(y, k3)], u)[0]
                y = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]
                t = (i + 1) * h
    except (OverflowError, ValueError, ZeroDivisionError) as exc:
        diverged_at, reason = t, f"arithmetic failure ({exc})"

    def arr(rows: list) -> np.ndarray | None:
        if not rows or rows[0] is None:
            return None
        return np.array(rows, dtype=float)

    return Trajectory(
        controller=controller.name,
        t_s=np.array(rec_t),
        x=np.array(rec_x, dtype=float),
        x_ref=np.array(rec_ref, dtype=float),
        u=np.array(rec_u, dtype=float),
        w_sq=np.array(rec_w, dtype=float),
        s=arr(rec_s),
        sigma=arr(rec_sig),
        chi_hat=arr(rec_chi),
        diverged=diverged_at is not None,
        diverged_at_s=diverged_at,
        reason=reason,
        dt_s=dt_s,
        rate_hz=rate_hz,
    )
