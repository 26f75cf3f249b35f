"""LAND: descend at ``LAND_SPD`` where the vehicle is; the pipeline disarms on touchdown."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fc.modes.base import FlightMode
from smcpilot.protocol import Mode

if TYPE_CHECKING:  # pragma: no cover
    from fc.flight import VehicleState


class LandMode(FlightMode):
    number = Mode.LAND

    @property
    def is_landing(self) -> bool:
        return True

    def enter(self, prev: Mode, st: VehicleState | None) -> None:
        f = self.flight
        if st is not None and f.armed:
            h = self.host.here(st)
            f.set_target(h.x_m, h.y_m, h.z_m)
            f.land()
