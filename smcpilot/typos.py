"""The paper's printed typos, each switchable so a reader can see why its correction matters.

Every name below reverts one correction of ``docs/pid-smc.md`` to the paper's literal text.
Model typos change :class:`smcpilot.model.PaperModel` (and therefore both the simulated plant and
the controller's nominal model, since the paper writes one set of equations for both); controller
typos change only the control law in :mod:`fc.control.pid_smc`.
"""

from __future__ import annotations

from collections.abc import Iterable

from smcpilot.errors import ConfigError

#: name -> (where it is printed, what the paper prints, what is right)
TYPOS: dict[str, tuple[str, str, str]] = {
    "b3": (
        "eqs. (10), (14)",
        "b3 = Cd/Iz: the yaw input gain counts the drag coefficient a second time",
        "b3 = 1/Iz, because u4 of eq. (11) is already a torque Cd(w1^2 - w2^2 + w3^2 - w4^2)",
    ),
    "z-drift": (
        "eqs. (13), (15)",
        "f_z = a9 z_dot psi_dot - g",
        "f_z = a9 z_dot - g (eq. 10's drag term has no psi_dot)",
    ),
    "pitch-moment": (
        "eq. (7)",
        "pitch moment d(F4 - F1)",
        "d(F4 - F2), consistent with the mixer of eq. (11)",
    ),
    "fdot": (
        "eqs. (20), (27), (34)",
        "time derivatives of f write the a1, a4, a7 cross terms as a product of derivatives (a1 theta_dd psi_dd, ...)",
        "full product rule: a1 (theta_dd psi_dot + theta_dot psi_dd), ...",
    ),
    "prefactor": (
        "eq. (20)",
        "u_dot prefactor -(c2 b)^-1",
        "-(kd c2 g)^-1 (equal only when kd = 1)",
    ),
    "adaptive-law": (
        "eq. (33)",
        "chi_hat = Theta |sigma| (algebraic)",
        "d chi_hat/dt = Theta |sigma|",
    ),
    "theta-chi": (
        "eq. (34)",
        "the theta channel uses chi_hat_1 (the phi channel's estimate)",
        "each channel uses its own chi_hat",
    ),
}

MODEL_TYPOS = frozenset({"b3", "z-drift", "pitch-moment", "fdot"})
CONTROLLER_TYPOS = frozenset({"prefactor", "adaptive-law", "theta-chi"})


def parse_typos(spec: str | Iterable[str] | None) -> frozenset[str]:
    """Parse ``"b3,fdot"``, ``"all"``, ``"none"`` or an iterable of names; unknown names raise."""
    if spec is None:
        return frozenset()
    if isinstance(spec, str):
        items = [s.strip() for s in spec.split(",") if s.strip()]
    else:
        items = [str(s).strip() for s in spec]
    if items == ["all"]:
        return frozenset(TYPOS)
    if items in ([], ["none"]):
        return frozenset()
    unknown = [s for s in items if s not in TYPOS]
    if unknown:
        raise ConfigError(
            f"unknown literal-equation name {unknown[0]!r}; choose from: all, none, "
            + ", ".join(sorted(TYPOS))
        )
    return frozenset(items)
