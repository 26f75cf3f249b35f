"""External disturbances added to the plant's accelerations (the controller never sees them).

The paper's "sensor failure" disturbances (§VI, spec §1), as accelerations in the channel order
(phi, theta, psi, z): rad/s^2, rad/s^2, rad/s^2, m/s^2.
"""

from __future__ import annotations

import math

_sin = math.sin
_cos = math.cos


def paper_disturbance(t_s: float, phi: float, theta: float, psi: float, z: float) -> tuple[float, float, float, float]:
    """fs2 = 0.1 phi cos t, fs3 = 0.1 theta sin 2t, fs4 = 0.1 psi cos 2t, fs1 = 0.1 z sin t."""
    return (
        0.1 * phi * _cos(t_s),
        0.1 * theta * _sin(2.0 * t_s),
        0.1 * psi * _cos(2.0 * t_s),
        0.1 * z * _sin(t_s),
    )


def paper_disturbance_rate(
    t_s: float,
    phi: float,
    theta: float,
    psi: float,
    z: float,
    phi_dot: float,
    theta_dot: float,
    psi_dot: float,
    z_dot: float,
) -> tuple[float, float, float, float]:
    """Time derivatives of :func:`paper_disturbance` along a trajectory."""
    return (
        0.1 * (phi_dot * _cos(t_s) - phi * _sin(t_s)),
        0.1 * (theta_dot * _sin(2.0 * t_s) + 2.0 * theta * _cos(2.0 * t_s)),
        0.1 * (psi_dot * _cos(2.0 * t_s) - 2.0 * psi * _sin(2.0 * t_s)),
        0.1 * (z_dot * _sin(t_s) + z * _cos(t_s)),
    )
