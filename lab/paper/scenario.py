"""The paper's scenario (eq. 45 and §VI; ``docs/pid-smc.md`` §5)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fc.control.base import constant_reference

#: X(0) = (phi, phi', theta, theta', psi, psi', z, z'): rad, rad/s, m, m/s.
PAPER_X0: tuple[float, ...] = (0.9, -0.9, 0.75, -1.0, 0.75, -0.1, 0.25, -0.1)
#: Constant targets (phi_d, theta_d, psi_d, z_d) = (pi/3, pi/6, pi/2, 3 m).
PAPER_TARGETS: tuple[float, float, float, float] = (math.pi / 3.0, math.pi / 6.0, math.pi / 2.0, 3.0)
PAPER_DURATION_S = 15.0


@dataclass(frozen=True)
class PaperScenario:
    """Initial state, constant targets and duration. x, y start at rest at the origin."""

    x0: tuple[float, ...] = PAPER_X0
    targets: tuple[float, float, float, float] = PAPER_TARGETS
    duration_s: float = PAPER_DURATION_S
    horizontal0: tuple[float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0))

    @property
    def plant_x0(self) -> tuple[float, ...]:
        """The 12-float initial plant state."""
        return tuple(self.x0) + tuple(self.horizontal0)

    @property
    def reference(self) -> tuple[float, ...]:
        return constant_reference(self.targets)
