"""In-process closed-loop simulation of a controller on a plant, without MAVLink.

Two forms, matching the controller's two forms (:mod:`fc.control.base`):

- **continuous time** (default): plant and controller states are integrated together by one
  classical RK4 step of ``dt_s`` (1 ms by default), so the controller's integrated u, int S and
  chi_hat are part of the ODE;
- **sampled data** (``rate_hz``): the controller steps at ``rate_hz`` with a zero-order hold and
  the plant alone is integrated by RK4 at ``dt_s`` in between.

Samples are recorded every ``dt_s`` (1 kHz by default), at the start of each step. A run that
produces non-finite or absurd values stops and is reported as diverged, with the time.

By default the loop flies compiled (:mod:`lab.fast.paper`: the same pure functions the classes
call, the whole loop in one numba call, the same trajectory bit for bit) when it can: the paper's
plant, a built-in controller, a constant reference, the compiled paths on; otherwise (said once
why) and with ``compiled=False`` it flies the CPython loop below.
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


#: why a sample means divergence, by the code :func:`divergence_code` gives (0: it does not).
DIVERGED_REASONS: tuple[str, ...] = (
    "",
    "non-finite state or input",
    f"angular rate above {DIVERGED_RATE:g} rad/s",
    "altitude or climb rate out of range",
    f"input above {DIVERGED_INPUT:g}",
)


def divergence_code(y: Sequence[float], u: Sequence[float]) -> int:
    """Does this sample (the state ``y``, its 8 leading values the paper's channels, and the input
    ``u``) mean divergence: 0 no, else the index of the reason in :data:`DIVERGED_REASONS` (pure;
    the first reason that holds, in that order; a cheap fast path first)."""
    total = 0.0
    for v in y:
        total += v
    total = total + u[0] + u[1] + u[2] + u[3]
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
        return 0
    if not _isfinite(total):
        return 1
    if abs(y[1]) >= DIVERGED_RATE or abs(y[3]) >= DIVERGED_RATE or abs(y[5]) >= DIVERGED_RATE:
        return 2
    if abs(y[6]) >= DIVERGED_POSITION or abs(y[7]) >= DIVERGED_POSITION:
        return 3
    return 4


def _bad(y: Sequence[float], u: Sequence[float]) -> str | None:
    """Why this sample means divergence, or None (checked every step: :func:`divergence_code`)."""
    code = divergence_code(y, u)
    return DIVERGED_REASONS[code] if code else None


def simulate(
    controller: Controller,
    plant: OdePlant,
    reference: Sequence[float] | RefFn,
    x0: Sequence[float],
    duration_s: float,
    dt_s: float = 1.0e-3,
    rate_hz: float | None = None,
    *,
    compiled: bool = True,
) -> Trajectory:
    """Fly ``controller`` on ``plant`` from ``x0`` for ``duration_s`` and record every ``dt_s``.

    ``reference`` is the 16-float reference (constant) or a function of time returning one.
    ``x0`` is the 12-float plant state. With ``rate_hz`` the controller runs sampled (its period
    must be a whole number of ``dt_s`` steps).

    With ``compiled`` (the default) the loop runs compiled when it can (:mod:`lab.fast.paper`: the
    paper's plant, a built-in controller, a constant reference, numba on; else said once why) and
    gives the same trajectory; ``compiled=False`` always flies the CPython loop.
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
    rec = _Rows()
    part = None
    if compiled and ref_fn is None:
        from lab.fast.paper import fly_compiled

        part = fly_compiled(controller, plant, ref_const, y, list(c), n_steps, dt_s, None if rate_hz is None else substeps)
    elif compiled:
        from lab.fast.paper import unsupported
        from smcpilot.jit import jit_enabled, say_once

        if jit_enabled():
            say_once(f"the paper's ODE runner flies in CPython ({unsupported(controller, plant, reference)})")
    diverged_at: float | None = None
    reason = ""
    i0 = 0
    u: Sequence[float] | None = None
    diag: Any = None
    if part is not None:
        i0 = part.n
        if part.done:
            return _trajectory(controller, rec, part, None, "", dt_s, rate_hz)
        if rate_hz is None:
            y = part.y
        else:
            y, c, u, diag = part.y, part.c or c, part.u, part.diag
    if rate_hz is None:
        yy = y if part is not None else y + list(c)
        diverged_at, reason = _fly_continuous(controller, plant, ref_fn, ref_const, nx, yy, i0, n_steps, dt_s, rec)
    else:
        diverged_at, reason = _fly_sampled(controller, plant, ref_fn, ref_const, y, c, u, diag, i0, n_steps, dt_s, substeps, rec)
    return _trajectory(controller, rec, part, diverged_at, reason, dt_s, rate_hz)


class _Rows:
    """The rows the CPython loop records."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.x: list[Sequence[float]] = []
        self.ref: list[tuple[float, float, float, float]] = []
        self.u: list[Sequence[float]] = []
        self.w: list[Sequence[float]] = []
        self.s: list = []
        self.sig: list = []
        self.chi: list = []

    def record(self, t: float, y: Sequence[float], ref: Sequence[float], u: Any, w: Any, diag: Any) -> None:
        self.t.append(t)
        self.x.append(tuple(y))
        self.ref.append((ref[0], ref[4], ref[8], ref[12]))
        self.u.append(u)
        self.w.append(w)
        self.s.append(diag.s)
        self.sig.append(diag.sigma)
        self.chi.append(diag.chi_hat)


def _fly_continuous(
    controller: Controller, plant: OdePlant, ref_fn: RefFn | None, ref_const: tuple[float, ...], nx: int,
    yy: list[float], i0: int, n_steps: int, h: float, rec: _Rows,
) -> tuple[float | None, str]:  # fmt: skip
    """The continuous-time loop from step ``i0`` (plant and controller states ``yy`` at its start):
    one ODE of plant + controller states. Returns (divergence time or None, reason)."""

    def closed(t: float, yy: Sequence[float]):
        ref = ref_fn(t) if ref_fn is not None else ref_const
        meas = yy[:8]
        cs = yy[nx:]
        u = controller.command(meas, ref, cs)
        dp, acc, w = plant.derivatives(t, yy[:nx], u)
        dc, diag = controller.derivatives(meas, ref, cs, acc)
        return dp + dc, u, w, diag, ref

    t = i0 * h if i0 else 0.0
    h2 = 0.5 * h
    h6 = h / 6.0
    try:
        for i in range(i0, n_steps + 1):
            k1, u, w, diag, ref = closed(t, yy)
            why = _bad(yy, u)
            if why:
                if i == 0:  # keep one sample, so a run diverged at the start still has metrics
                    rec.record(t, yy[:nx], ref, u, w, diag)
                return t, why
            rec.record(t, yy[:nx], ref, u, w, diag)
            if i == n_steps:
                break
            k2 = closed(t + h2, [a + h2 * b for a, b in zip(yy, k1)])[0]
            k3 = closed(t + h2, [a + h2 * b for a, b in zip(yy, k2)])[0]
            k4 = closed(t + h, [a + h * b for a, b in zip(yy, k3)])[0]
            yy = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(yy, k1, k2, k3, k4)]
            t = (i + 1) * h
    except (OverflowError, ValueError, ZeroDivisionError) as exc:
        return t, f"arithmetic failure ({exc})"
    return None, ""


def _fly_sampled(
    controller: Controller, plant: OdePlant, ref_fn: RefFn | None, ref_const: tuple[float, ...], y: list[float],
    c: Sequence[float], u: Any, diag: Any, i0: int, n_steps: int, h: float, substeps: int, rec: _Rows,
) -> tuple[float | None, str]:  # fmt: skip
    """The sampled-data loop from step ``i0``: controller at every ``substeps`` steps (ZOH; its
    state ``c``, the held ``u`` and ``diag``), plant RK4 at ``h``. Returns (divergence time or None, reason)."""
    dt_ctrl = substeps * h
    t = i0 * h if i0 else 0.0
    h2 = 0.5 * h
    h6 = h / 6.0
    try:
        for i in range(i0, n_steps + 1):
            ref = ref_fn(t) if ref_fn is not None else ref_const
            if i % substeps == 0:
                acc: Sequence[float] | None = plant.derivatives(t, y, u)[1] if u is not None else None
                u, c, diag = controller.step(y[:8], ref, c, dt_ctrl, acc)
            k1, _acc, w = plant.derivatives(t, y, u)
            why = _bad(y, u)
            if why:
                if i == 0:  # keep one sample, so a run diverged at the start still has metrics
                    rec.record(t, y, ref, u, w, diag)
                return t, why
            rec.record(t, y, ref, u, w, diag)
            if i == n_steps:
                break
            k2 = plant.derivatives(t + h2, [a + h2 * b for a, b in zip(y, k1)], u)[0]
            k3 = plant.derivatives(t + h2, [a + h2 * b for a, b in zip(y, k2)], u)[0]
            k4 = plant.derivatives(t + h, [a + h * b for a, b in zip(y, k3)], u)[0]
            y = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]
            t = (i + 1) * h
    except (OverflowError, ValueError, ZeroDivisionError) as exc:
        return t, f"arithmetic failure ({exc})"
    return None, ""


def _trajectory(controller: Controller, rec: _Rows, part: Any, diverged_at: float | None, reason: str, dt_s: float,
                rate_hz: float | None) -> Trajectory:  # fmt: skip
    """The Trajectory of the rows the compiled loop flew (``part``, or None) followed by the CPython loop's."""

    def arr(rows: list) -> np.ndarray | None:
        if not rows or rows[0] is None:
            return None
        return np.array(rows, dtype=float)

    cols: dict[str, np.ndarray | None] = {
        "t": np.array(rec.t), "x": np.array(rec.x, dtype=float), "x_ref": np.array(rec.ref, dtype=float),
        "u": np.array(rec.u, dtype=float), "w_sq": np.array(rec.w, dtype=float),
        "s": arr(rec.s), "sigma": arr(rec.sig), "chi_hat": arr(rec.chi),
    }  # fmt: skip
    if part is not None and part.n > 0:  # else every row is CPython's (none at all, if it failed at once)
        for k, head in part.rows.items():
            tail = cols[k]
            if head is None or not rec.t:
                cols[k] = head
            elif tail is not None:
                cols[k] = np.concatenate((head, tail))
    return Trajectory(
        controller=controller.name,
        t_s=cols["t"],  # type: ignore[arg-type]
        x=cols["x"],  # type: ignore[arg-type]
        x_ref=cols["x_ref"],  # type: ignore[arg-type]
        u=cols["u"],  # type: ignore[arg-type]
        w_sq=cols["w_sq"],  # type: ignore[arg-type]
        s=cols["s"],
        sigma=cols["sigma"],
        chi_hat=cols["chi_hat"],
        diverged=diverged_at is not None,
        diverged_at_s=diverged_at,
        reason=reason,
        dt_s=dt_s,
        rate_hz=rate_hz,
    )
