"""Fixed-step integration on plain float sequences (no numpy in the hot path)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

Deriv = Callable[[float, Sequence[float]], Sequence[float]]


def rk4_step(f: Deriv, t: float, y: Sequence[float], h: float) -> list[float]:
    """One classical Runge-Kutta step of size ``h`` for dy/dt = f(t, y)."""
    h2 = 0.5 * h
    k1 = f(t, y)
    k2 = f(t + h2, [a + h2 * b for a, b in zip(y, k1)])
    k3 = f(t + h2, [a + h2 * b for a, b in zip(y, k2)])
    k4 = f(t + h, [a + h * b for a, b in zip(y, k3)])
    h6 = h / 6.0
    return [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]
