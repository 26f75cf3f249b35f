"""AUTO: fly the stored mission from the current item (item 0 is home and is not flown).

Per item: start it (:meth:`AutoMode._start_item` sets the target), then follow
:class:`AutoPhase`: FLY until the target is reached (within the item's acceptance radius, or
``WP_RADIUS_M``), HOLD for the item's param1 seconds, DONE: ``MISSION_ITEM_REACHED`` and the next
item. A ``NAV_LAND`` item descends (LANDING) and a ``NAV_RETURN_TO_LAUNCH`` item is flown by the
RTL mode object (phase RTL); both are reached on touchdown. ``MISSION_CURRENT`` stays on the last
item when the mission completes.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import TYPE_CHECKING

from fc import inbound
from fc.mission import (
    CMD_CHANGE_SPEED,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_RTL,
    CMD_TAKEOFF,
    CMD_WAYPOINT,
    MissionItem,
)
from fc.modes.base import (
    TAKEOFF_DONE_M,
    WATCH_DIST3,
    WATCH_EVERY_TICK,
    WATCH_NOTHING,
    WATCH_TIME,
    WATCH_Z_NEAR,
    FlightMode,
    ModeHost,
    Refusal,
    Watch,
)
from fc.modes.rtl import RtlMode
from smcpilot.protocol import Mode

if TYPE_CHECKING:  # pragma: no cover
    from fc.flight import VehicleState

_POSITION_ITEMS = (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LAND)
_LANDING_ITEMS = (CMD_LAND, CMD_RTL)


class AutoPhase(Enum):
    #: flying to the item's target.
    FLY = "fly"
    #: at the target, waiting the item's hold time.
    HOLD = "hold"
    #: the item is complete: report it, go on with the next.
    DONE = "done"
    #: a NAV_LAND item descends; reached on touchdown.
    LANDING = "landing"
    #: a NAV_RETURN_TO_LAUNCH item, flown by the RTL mode object; reached on touchdown.
    RTL = "rtl"


class AutoMode(FlightMode):
    number = Mode.AUTO
    allows_arming = True

    def __init__(self, host: ModeHost, rtl: RtlMode) -> None:
        super().__init__(host)
        self._rtl = rtl
        self.mission = host.mission
        #: the mission was flown to its end (until restarted).
        self.complete = False
        self.phase = AutoPhase.FLY
        #: the item being flown; -1: (re)start the current item at the next tick.
        self._seq = -1
        self._t0_s = 0.0

    @property
    def is_landing(self) -> bool:
        return self.phase is AutoPhase.LANDING or (self.phase is AutoPhase.RTL and self._rtl.is_landing)

    # -- the commander's hooks --------------------------------------------------------------------
    def refuse_entry(self) -> Refusal | None:
        if len(self.mission.items) < 2:
            return Refusal("AUTO: no mission loaded")
        return None

    def prearm_failure(self) -> str | None:
        why = super().prearm_failure()
        if why is None and len(self.mission.items) < 2:
            why = "PreArm: AUTO without a mission"
        return why

    def restart_item(self) -> None:
        """Start the current item afresh at the next tick (the mission or the current item changed)."""
        self._seq = -1

    def restart(self) -> None:
        """Fly on from the current item, even after the mission completed."""
        self.complete = False
        self._seq = -1

    def _end_rtl_item(self) -> None:
        if self.phase is AutoPhase.RTL:
            self.phase = AutoPhase.FLY
        self._rtl.reset()

    def enter(self, prev: Mode, st: VehicleState | None) -> None:
        self._end_rtl_item()
        if st is not None:
            self.restart()

    def exit(self, to: Mode) -> None:
        if self.phase is AutoPhase.RTL:
            self.phase = AutoPhase.FLY
        if to is not Mode.RTL:
            # Leaving for RTL mode, a return in progress stays where it is: RTL restarts it on
            # entry when armed (a disarmed vehicle switched to RTL keeps it for a forced re-arm).
            self._rtl.reset()
        self._seq = -1
        self.flight.speed_xy_mps = None  # DO_CHANGE_SPEED holds in AUTO only

    def on_armed(self) -> None:
        self.restart()

    def on_touchdown(self) -> Mode | None:
        if not self.complete:
            items = self.mission.items
            cur = self.mission.current
            if 0 < cur < len(items) and items[cur].command in _LANDING_ITEMS:
                self.host.item_reached(cur)  # a landing item is reached on touchdown
            self._finish()
        self._end_rtl_item()
        return None

    def _finish(self) -> None:
        if not self.complete:
            self.complete = True
            self.host.say("Mission complete")

    # -- per tick ---------------------------------------------------------------------------------
    def _start_item(self, it: MissionItem, st: VehicleState, t_s: float) -> None:
        f = self.flight
        home = self.host.home
        self.phase = AutoPhase.FLY
        self._t0_s = t_s
        cmd = it.command
        yaw = inbound.mission_item_yaw(it)
        here = self.host.here(st)
        if cmd == CMD_TAKEOFF:
            f.set_target(here.x_m, here.y_m, inbound.mission_item_altitude(home, it), yaw)
        elif cmd in _POSITION_ITEMS:
            if cmd != CMD_WAYPOINT and it.x == 0 and it.y == 0:  # 0, 0: here
                x, y = here.x_m, here.y_m
                z = inbound.mission_item_altitude(home, it) if it.z > 0 else here.z_m
            else:
                x, y, z = inbound.mission_item_position(home, it)
            if cmd == CMD_LAND:
                z = max(here.z_m, 0.0)
            f.set_target(x, y, z, yaw)
        elif cmd == CMD_RTL:
            self.phase = AutoPhase.RTL
            self._rtl.start()
        elif cmd == CMD_CHANGE_SPEED:
            if it.param2 > 0.0:
                f.speed_xy_mps = it.param2
            self.phase = AutoPhase.DONE

    def watch(self) -> Watch:
        phase = self.phase
        if phase is AutoPhase.RTL:
            return self._rtl.watch()
        mission = self.mission
        items = mission.items
        if self.complete or len(items) < 2:
            return WATCH_NOTHING
        cur = mission.current
        if cur < 1 or cur >= len(items) or self._seq != cur:
            return WATCH_EVERY_TICK
        it = items[cur]
        if phase is AutoPhase.FLY:
            tx, ty, tz = self.flight.target
            cmd = it.command
            if cmd == CMD_TAKEOFF:
                return Watch(WATCH_Z_NEAR, tz, r=TAKEOFF_DONE_M)
            if cmd in _POSITION_ITEMS:
                radius = it.param2 if (cmd == CMD_WAYPOINT and it.param2 > 0.0) else self.host.config.wp_radius_m
                return Watch(WATCH_DIST3, tx, ty, tz, radius)
            return WATCH_NOTHING
        if phase is AutoPhase.HOLD:
            return Watch(WATCH_TIME, self._t0_s, it.param1)
        return WATCH_NOTHING if phase is AutoPhase.LANDING else WATCH_EVERY_TICK

    def run(self, st: VehicleState, t_s: float, dt_s: float) -> None:
        if self.phase is AutoPhase.RTL:
            self._rtl.run(st, t_s, dt_s)
            return
        mission = self.mission
        items = mission.items
        if self.complete or len(items) < 2:
            return
        if mission.current < 1:
            mission.current = 1
        if mission.current >= len(items):
            self._finish()
            return
        it = items[mission.current]
        if self._seq != mission.current:
            self._seq = mission.current
            self._start_item(it, st, t_s)
        phase = self.phase
        if phase is AutoPhase.FLY:
            f = self.flight
            tx, ty, tz = f.target
            cmd = it.command
            if cmd == CMD_TAKEOFF:
                if abs(st.z_m - tz) < TAKEOFF_DONE_M:
                    phase = AutoPhase.DONE
            elif cmd in _POSITION_ITEMS:
                radius = it.param2 if (cmd == CMD_WAYPOINT and it.param2 > 0.0) else self.host.config.wp_radius_m
                if math.dist((st.x_m, st.y_m, st.z_m), (tx, ty, tz)) < radius:
                    if cmd == CMD_LAND:
                        f.land()
                        phase = AutoPhase.LANDING
                    else:
                        phase = AutoPhase.HOLD
                        self._t0_s = t_s
            self.phase = phase
        if phase is AutoPhase.HOLD and t_s - self._t0_s >= it.param1:
            phase = self.phase = AutoPhase.DONE
        if phase is AutoPhase.DONE:
            self.host.item_reached(mission.current)
            if mission.current + 1 >= len(items):
                self._finish()  # MISSION_CURRENT stays on the last item
            else:
                mission.current += 1
                self._seq = -1
