"""RTL: climb to max(altitude, ``RTL_ALT_M``) where the vehicle is, fly home at that height, land.

The progress is :class:`RtlPhase`; AUTO flies a ``NAV_RETURN_TO_LAUNCH`` item with this same
object (:meth:`RtlMode.start` then :meth:`RtlMode.run`).
"""

from __future__ import annotations

import math
from enum import Enum
from typing import TYPE_CHECKING

from fc.modes.base import TAKEOFF_DONE_M, WATCH_DIST2, WATCH_EVERY_TICK, WATCH_NOTHING, WATCH_Z_NEAR, FlightMode, Watch
from smcpilot.protocol import Mode

if TYPE_CHECKING:  # pragma: no cover
    from fc.flight import VehicleState

#: horizontal distance from home at which the descent starts, m.
RTL_HOME_RADIUS_M = 0.5


class RtlPhase(Enum):
    #: not under way yet: the next tick fixes the return altitude and starts the climb.
    START = "start"
    #: climbing (or staying) at the return altitude over where RTL began.
    CLIMB = "climb"
    #: flying home at the return altitude.
    HOME = "home"
    #: descending over home; the pipeline disarms on touchdown.
    LAND = "land"


class RtlMode(FlightMode):
    number = Mode.RTL

    def __init__(self, host) -> None:
        super().__init__(host)
        self.phase = RtlPhase.START
        #: the return altitude, m above home.
        self.return_z_m = 0.0

    @property
    def is_landing(self) -> bool:
        return self.phase is RtlPhase.LAND

    def start(self) -> None:
        """Begin a return (from the beginning) at the next tick."""
        self.phase = RtlPhase.START

    def reset(self) -> None:
        """Drop a return in progress."""
        self.phase = RtlPhase.START

    def enter(self, prev: Mode, st: VehicleState | None) -> None:
        if st is not None and self.flight.armed:
            self.start()

    def exit(self, to: Mode) -> None:
        self.reset()

    def on_touchdown(self) -> Mode | None:
        self.reset()
        return Mode.GUIDED  # home and landed: back to GUIDED, as ArduCopter's RTL ends

    def watch(self) -> Watch:
        phase = self.phase
        if phase is RtlPhase.CLIMB:
            return Watch(WATCH_Z_NEAR, self.return_z_m, r=TAKEOFF_DONE_M)
        if phase is RtlPhase.HOME:
            return Watch(WATCH_DIST2, 0.0, 0.0, r=RTL_HOME_RADIUS_M)
        return WATCH_NOTHING if phase is RtlPhase.LAND else WATCH_EVERY_TICK

    def run(self, st: VehicleState, t_s: float, dt_s: float) -> None:
        phase = self.phase
        f = self.flight
        if phase is RtlPhase.START:
            h = self.host.here(st)
            self.return_z_m = max(h.z_m, self.host.config.rtl_alt_m)
            f.set_target(h.x_m, h.y_m, self.return_z_m)
            self.phase = RtlPhase.CLIMB
        elif phase is RtlPhase.CLIMB:
            if abs(st.z_m - self.return_z_m) < TAKEOFF_DONE_M:
                f.set_target(0.0, 0.0, self.return_z_m)
                self.phase = RtlPhase.HOME
        elif phase is RtlPhase.HOME:
            if math.hypot(st.x_m, st.y_m) < RTL_HOME_RADIUS_M:
                f.land()
                self.phase = RtlPhase.LAND
        # LAND: the pipeline descends and disarms on touchdown
