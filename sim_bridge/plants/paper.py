"""The paper's plant: the corrected eq. (10) model with ideal actuators and eq. (11)'s mixer.

State (12 floats), paper frame (z up)::

    (phi, phi', theta, theta', psi, psi', z, z', x, x', y, y')   rad, rad/s, m, m/s

The input is u in channel order (u_phi [N], u_theta [N], u_psi [N m], u_z [N]). The plant turns
it into rotor speeds with the inverse mixer (ideal, unlimited actuators: negative w^2 is allowed
and reported, not clipped) and applies what those rotor speeds produce, plus the paper's
disturbances when enabled.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from sim_bridge.disturbances import paper_disturbance
from smcpilot.model import PaperModel

STATE_NAMES = ("phi", "phi_dot", "theta", "theta_dot", "psi", "psi_dot", "z", "z_dot", "x", "x_dot", "y", "y_dot")

_cos = math.cos


class PaperPlant:
    """Truth model of the paper's scenario: f + g u + d on the attitude/altitude channels."""

    state_names = STATE_NAMES

    def __init__(self, model: PaperModel, disturbance: bool = True) -> None:
        self.model = model
        self.disturbance = disturbance

    def derivatives(
        self, t_s: float, y: Sequence[float], u: Sequence[float]
    ) -> tuple[tuple[float, ...], tuple[float, float, float, float], tuple[float, float, float, float]]:
        """(dy/dt, true accelerations (phi'', theta'', psi'', z''), rotor speeds squared w1..w4^2)."""
        phi, phi_d, th, th_d, psi, psi_d, z, z_d, _x, x_d, _y, y_d = y
        m = self.model
        w_sq = m.unmix(u[0], u[1], u[2], u[3])
        u_phi, u_th, u_psi, u_z = m.actuation(w_sq[0], w_sq[1], w_sq[2], w_sq[3])
        wbar = m.omega_bar(w_sq[0], w_sq[1], w_sq[2], w_sq[3])
        a0, a1, a2, a3 = m.accelerations(phi, phi_d, th, th_d, psi_d, z_d, u_phi, u_th, u_psi, u_z, wbar)
        if self.disturbance:
            d0, d1, d2, d3 = paper_disturbance(t_s, phi, th, psi, z)
            a0 += d0
            a1 += d1
            a2 += d2
            a3 += d3
        ax, ay = m.horizontal_accelerations(phi, th, psi, x_d, y_d, u_z)
        accel = (a0, a1, a2, a3)
        return (phi_d, a0, th_d, a1, psi_d, a2, z_d, a3, x_d, ax, y_d, ay), accel, w_sq
