"""The paper's plant: the corrected eq. (10) model with ideal actuators and eq. (11)'s mixer.

State (12 floats), paper frame (z up)::

    (phi, phi', theta, theta', psi, psi', z, z', x, x', y, y')   rad, rad/s, m, m/s

The input is u in channel order (u_phi [N], u_theta [N], u_psi [N m], u_z [N]). The plant turns
it into rotor speeds with the inverse mixer (ideal, unlimited actuators: negative w^2 is allowed
and reported, not clipped) and applies what those rotor speeds produce, plus the paper's
disturbances when enabled.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from sim_bridge.disturbances import paper_disturbance
from smcpilot.model import PaperModel, accelerations, actuation, horizontal_accelerations, omega_bar, unmix

STATE_NAMES = ("phi", "phi_dot", "theta", "theta_dot", "psi", "psi_dot", "z", "z_dot", "x", "x_dot", "y", "y_dot")


class PaperPlantConsts(NamedTuple):
    """What :func:`paper_plant_derivatives` reads, flattened from the model (floats and bools)."""

    #: the model's constants, in :class:`~smcpilot.model.ModelConsts` order.
    model: tuple[float | bool, ...]
    mass_kg: float
    lin_drag_x: float
    lin_drag_y: float
    #: the "pitch-moment" typo: eq. (7)'s printed pitch moment.
    pitch_moment_typo: bool
    #: the paper's disturbances are added.
    disturbance: bool


def paper_plant_consts(model: PaperModel, disturbance: bool) -> PaperPlantConsts:
    return PaperPlantConsts(
        tuple(model.consts()), float(model.mass_kg), float(model.lin_drag_x_n_s_m), float(model.lin_drag_y_n_s_m),
        "pitch-moment" in model.typos, bool(disturbance),
    )  # fmt: skip


def paper_plant_derivatives(
    t_s: float, y: Sequence[float], u: Sequence[float], p: PaperPlantConsts
) -> tuple[
    tuple[float, float, float, float, float, float, float, float, float, float, float, float],
    tuple[float, float, float, float],
    tuple[float, float, float, float],
]:
    """(dy/dt, true accelerations (phi'', theta'', psi'', z''), rotor speeds squared w1..w4^2) of the
    12-float state ``y`` under the input ``u`` (pure: the one copy of the paper plant's equations)."""
    phi, phi_d, th, th_d, psi, psi_d, z, z_d, _x, x_d, _y, y_d = y
    m = p.model
    w_sq = unmix(m, u[0], u[1], u[2], u[3])
    u_phi, u_th, u_psi, u_z = actuation(m, p.pitch_moment_typo, w_sq[0], w_sq[1], w_sq[2], w_sq[3])
    wbar = omega_bar(w_sq[0], w_sq[1], w_sq[2], w_sq[3])
    a0, a1, a2, a3 = accelerations(m, phi, phi_d, th, th_d, psi_d, z_d, u_phi, u_th, u_psi, u_z, wbar)
    if p.disturbance:
        d0, d1, d2, d3 = paper_disturbance(t_s, phi, th, psi, z)
        a0 += d0
        a1 += d1
        a2 += d2
        a3 += d3
    ax, ay = horizontal_accelerations(p.mass_kg, p.lin_drag_x, p.lin_drag_y, phi, th, psi, x_d, y_d, u_z)
    return (phi_d, a0, th_d, a1, psi_d, a2, z_d, a3, x_d, ax, y_d, ay), (a0, a1, a2, a3), w_sq


#: the plant's pure functions (what a compiled runner compiles with it).
PURE_FUNCTIONS = (paper_plant_derivatives, paper_disturbance, unmix, actuation, omega_bar, accelerations, horizontal_accelerations)


class PaperPlant:
    """Truth model of the paper's scenario: f + g u + d on the attitude/altitude channels.

    The public face of the pure :func:`paper_plant_derivatives`; ``consts`` holds its constants
    (rebuilt when ``model`` or ``disturbance`` is set).
    """

    state_names = STATE_NAMES

    def __init__(self, model: PaperModel, disturbance: bool = True) -> None:
        self._model = model
        self._disturbance = disturbance
        #: the flattened constants the pure function takes.
        self.consts = paper_plant_consts(model, disturbance)

    @property
    def model(self) -> PaperModel:
        return self._model

    @model.setter
    def model(self, model: PaperModel) -> None:
        self._model = model
        self.consts = paper_plant_consts(model, self._disturbance)

    @property
    def disturbance(self) -> bool:
        return self._disturbance

    @disturbance.setter
    def disturbance(self, on: bool) -> None:
        if on != self._disturbance or bool(on) != self.consts.disturbance:
            self.consts = paper_plant_consts(self._model, on)
        self._disturbance = on

    def derivatives(
        self, t_s: float, y: Sequence[float], u: Sequence[float]
    ) -> tuple[tuple[float, ...], tuple[float, float, float, float], tuple[float, float, float, float]]:
        """(dy/dt, true accelerations (phi'', theta'', psi'', z''), rotor speeds squared w1..w4^2)."""
        return paper_plant_derivatives(t_s, y, u, self.consts)
