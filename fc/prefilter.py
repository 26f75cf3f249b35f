"""Third-order reference prefilter: turns set-point steps into smooth references with the three
derivatives the PID-SMC needs (x_d', x_d'', x_d''').

Critically damped, triple pole at -omega::

    x_d''' = omega^3 (r - x_d) - 3 omega^2 x_d' - 3 omega x_d''

integrated by semi-implicit Euler (jerk -> acceleration -> velocity -> position), with optional
limits on |x_d'| and |x_d''| (a large step then moves at a bounded speed). Pure function of plain
floats; the caller keeps the state (x, v, a).
"""

from __future__ import annotations

_INF = float("inf")


def prefilter_step(
    x: float,
    v: float,
    a: float,
    target: float,
    omega_radps: float,
    dt_s: float,
    v_max: float = _INF,
    a_max: float = _INF,
) -> tuple[float, float, float, float]:
    """Advance the filter by ``dt_s``; return the new (x_d, x_d', x_d'', x_d''').

    Units follow the input (m or rad); ``omega_radps`` is the filter bandwidth in rad/s.
    """
    w = omega_radps
    j = w * w * w * (target - x) - 3.0 * w * w * v - 3.0 * w * a
    a1 = a + dt_s * j
    if a1 > a_max:
        a1 = a_max
    elif a1 < -a_max:
        a1 = -a_max
    v1 = v + dt_s * a1
    if v1 > v_max:
        v1 = v_max
        if a1 > 0.0:
            a1 = 0.0
    elif v1 < -v_max:
        v1 = -v_max
        if a1 < 0.0:
            a1 = 0.0
    x1 = x + dt_s * v1
    j1 = (a1 - a) / dt_s
    return x1, v1, a1, j1
