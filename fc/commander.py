"""The vehicle's state machine: modes, arming, commands, missions in AUTO, RTL, failsafes.

The commander decides *what* to fly; :class:`fc.flight.FlightControl` flies it. Every request
returns ``(MAV_RESULT, reason)`` so the ground protocol can answer with ``COMMAND_ACK`` and a
``STATUSTEXT`` saying why. Positions handed to the flight pipeline are in the paper frame
(x north, y west, z up); conversions go through :mod:`smcpilot.frames` and :mod:`smcpilot.geo`.
Flight logic runs on simulated time; the GCS-loss failsafe on the wall clock (a ground station
lives in real time).
"""

from __future__ import annotations

import math
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.flight import FlightControl, VehicleState
from fc.mission import (
    CMD_CHANGE_SPEED,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_RTL,
    CMD_TAKEOFF,
    CMD_WAYPOINT,
    RELATIVE_FRAMES,
    MissionItem,
    MissionProtocol,
)
from smcpilot.plan import PlanStep
from smcpilot.frames import euler_frd_to_flu, ned_to_nwu
from smcpilot.geo import Home, global_to_ned
from smcpilot.protocol import ARMABLE_MODES, Mode, mode_name

Result = tuple[int, str | None]
ACCEPTED: Result = (mavlink.MAV_RESULT_ACCEPTED, None)

#: a take-off counts as done within this height of its target, m.
TAKEOFF_DONE_M = 0.3
#: RTL: horizontal distance from home at which the descent starts, m.
RTL_HOME_RADIUS_M = 0.5


def _denied(reason: str) -> Result:
    return (mavlink.MAV_RESULT_DENIED, reason)


class Commander:
    """Owns the mode and the mission execution for one vehicle."""

    def __init__(
        self,
        flight: FlightControl,
        home: Home,
        event: Callable[[int, str], None],
        *,
        mav: mavlink.MAVLink | None = None,
        send_to: Callable[[mavlink.MAVLink_message, tuple[str, int]], None] | None = None,
        broadcast: Callable[[mavlink.MAVLink_message], None] | None = None,
    ) -> None:
        """``mav`` encodes ground messages; ``send_to``/``broadcast`` reach ground stations
        (None: no ground link, e.g. the in-process runner)."""
        self.flight = flight
        self.home = home
        self._event = event
        self._mav = mav if mav is not None else mavlink.MAVLink(None)
        self._broadcast = broadcast
        self.mission = MissionProtocol(
            self._mav, send_to if send_to is not None else (lambda m, a: None), self.on_mission_changed, self.on_set_current
        )
        self.mode = Mode.GUIDED
        self.state: VehicleState | None = None
        self.state_fresh = False
        self.failsafe_active = False
        self.t_s = 0.0
        self._ground_armed_s = 0.0
        # AUTO
        self._auto_seq = -1
        self._auto_phase = ""
        self._auto_t0 = 0.0
        self.mission_complete = False
        # RTL (also inside AUTO): "", "start", "climb", "home", "land"
        self._rtl_phase = ""
        self._rtl_z = 0.0
        # GCS-loss failsafe
        self._gcs_last_hb_s: float | None = None
        self._gcs_failsafe = False

    # -- helpers --------------------------------------------------------------------------------
    @property
    def config(self):
        return self.flight.config

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self._event(severity, text)

    def local_of_global(self, lat_deg: float, lon_deg: float, alt_m: float, relative: bool) -> tuple[float, float, float]:
        """Paper-frame (x north, y west, z up above home) position of a global point."""
        alt_amsl = alt_m + self.home.alt_m if relative else alt_m
        n, e, d = global_to_ned(self.home, lat_deg, lon_deg, alt_amsl)
        return ned_to_nwu((n, e, d))

    @staticmethod
    def yaw_from_compass_deg(yaw_deg: float) -> float:
        return euler_frd_to_flu(0.0, 0.0, math.radians(yaw_deg))[2]

    def on_ground(self) -> bool:
        st = self.state
        return st is not None and st.z_m < 0.2 and abs(st.vz_mps) < 0.5

    def landed_state(self) -> int:
        f = self.flight
        st = self.state
        if not f.armed or st is None:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if f.landing:
            return mavlink.MAV_LANDED_STATE_LANDING
        tz = f.target[2]
        if st.z_m < 0.15 and tz < 0.3:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if st.z_m < 0.5 and tz > st.z_m + 0.3:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def flying(self) -> bool:
        return self.flight.armed and self.landed_state() != mavlink.MAV_LANDED_STATE_ON_GROUND

    # -- modes ----------------------------------------------------------------------------------
    def set_mode(self, number: int) -> Result:
        try:
            mode = Mode(int(number))
        except ValueError:
            return _denied(f"Mode {mode_name(int(number))} not supported")
        if mode == Mode.AUTO and len(self.mission.items) < 2:
            return _denied("AUTO: no mission loaded")
        self._enter(mode)
        return ACCEPTED

    def _enter(self, mode: Mode) -> None:
        f = self.flight
        prev = self.mode
        self.mode = mode
        f.position_hold = mode != Mode.ALT_HOLD
        st = self.state
        if mode != Mode.AUTO:
            self._auto_seq = -1
            f.speed_xy_mps = None
        if mode != Mode.RTL:
            self._rtl_phase = ""
        if st is None:
            return
        if mode in (Mode.GUIDED, Mode.LOITER, Mode.ALT_HOLD) and f.armed and prev != mode:
            f.set_target(st.x_m, st.y_m, st.z_m if self.flying() else f.target[2])
        elif mode == Mode.LAND and f.armed:
            f.set_target(st.x_m, st.y_m, st.z_m)
            f.land()
        elif mode == Mode.RTL and f.armed:
            self._rtl_phase = "start"
        elif mode == Mode.AUTO:
            self.mission_complete = False
            self._auto_seq = -1  # (re)start the current item
        if prev != mode:
            self.say(f"Mode {mode.name}")

    # -- arming ---------------------------------------------------------------------------------
    def prearm_failure(self) -> str | None:
        """Why arming (without force) would be refused now, or None: the PREARM_CHECK health bit."""
        if self.state is None:
            return "PreArm: no vehicle state yet"
        if not self.state_fresh:
            return "PreArm: vehicle state is stale"
        if self.config.arming_check:
            if self.failsafe_active:
                return "PreArm: in failsafe"
            if not self.on_ground():
                return "PreArm: vehicle is not on the ground"
            if self.mode not in ARMABLE_MODES:
                return f"PreArm: cannot arm in {self.mode.name}"
            if self.mode == Mode.AUTO and len(self.mission.items) < 2:
                return "PreArm: AUTO without a mission"
        return None

    def arm(self, force: bool = False) -> Result:
        f = self.flight
        if f.armed:
            return ACCEPTED
        st = self.state
        if st is None:
            return _denied("PreArm: no vehicle state yet")
        if not force:
            why = self.prearm_failure()
            if why is not None:
                return _denied(why)
        f.arm(st)
        self._ground_armed_s = 0.0
        if self.mode == Mode.AUTO:
            self.mission_complete = False
            self._auto_seq = -1
        self.say("Armed")
        return ACCEPTED

    def disarm(self, force: bool = False, reason: str = "Disarmed") -> Result:
        f = self.flight
        if not f.armed:
            return ACCEPTED
        if not force and self.flying():
            return _denied("Disarm refused: flying (use force)")
        f.disarm()
        self.say(reason)
        return ACCEPTED

    # -- commands -------------------------------------------------------------------------------
    def takeoff(self, alt_m: float) -> Result:
        if not math.isfinite(alt_m) or not 0.5 <= alt_m <= 100.0:
            return _denied(f"Takeoff: altitude must lie in [0.5, 100] m, got {alt_m:g}")
        if self.mode != Mode.GUIDED:
            return _denied(f"Takeoff: needs GUIDED, in {self.mode.name}")
        f = self.flight
        if not f.armed:
            return _denied("Takeoff: arm first")
        st = self.state
        assert st is not None
        x, y = (st.x_m, st.y_m) if not self.flying() else (f.target[0], f.target[1])
        f.set_target(x, y, alt_m)
        self.say(f"Takeoff to {alt_m:.1f} m")
        return ACCEPTED

    def goto_local(self, x: float, y: float, z: float, yaw_rad: float | None) -> Result:
        """GUIDED set-point in the paper frame (z up above home)."""
        if not all(math.isfinite(v) for v in (x, y, z)) or (yaw_rad is not None and not math.isfinite(yaw_rad)):
            return _denied("Set-point: non-finite value")
        if self.mode != Mode.GUIDED:
            return _denied(f"Set-point: needs GUIDED, in {self.mode.name}")
        if not self.flight.armed:
            return _denied("Set-point: not armed")
        if z < 0.0 or z > 500.0:
            return _denied(f"Set-point: altitude {z:.1f} m out of [0, 500]")
        self.flight.set_target(x, y, z, yaw_rad)
        return ACCEPTED

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, relative: bool, yaw_deg: float) -> Result:
        if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
            return _denied("Reposition: non-finite position")
        if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
            return _denied("Reposition: latitude/longitude out of range")
        if not self.flight.armed:
            return _denied("Reposition: not armed")
        if self.mode != Mode.GUIDED:
            self._enter(Mode.GUIDED)
        x, y, z = self.local_of_global(lat_deg, lon_deg, alt_m, relative)
        yaw = self.yaw_from_compass_deg(yaw_deg) if math.isfinite(yaw_deg) else None
        return self.goto_local(x, y, z, yaw)

    def land(self) -> Result:
        self._enter(Mode.LAND)
        return ACCEPTED

    def rtl(self) -> Result:
        if not self.flight.armed:
            return _denied("RTL: not armed")
        self._enter(Mode.RTL)
        return ACCEPTED

    def mission_start(self, first: int) -> Result:
        items = self.mission.items
        if len(items) < 2:
            return _denied("Mission start: no mission loaded")
        if first > 0:
            if first >= len(items):
                return _denied(f"Mission start: item {first} does not exist")
            self.mission.current = first
        elif self.mission.current < 1 or self.mission_complete:
            self.mission.current = 1
        if not self.flight.armed:
            return _denied("Mission start: arm first")
        self._enter(Mode.AUTO)
        self.mission_complete = False
        self._auto_seq = -1
        return ACCEPTED

    def on_mission_changed(self) -> None:
        if self.mode == Mode.AUTO and len(self.mission.items) < 2:
            self.say("Mission cleared: LOITER", mavlink.MAV_SEVERITY_WARNING)
            self._enter(Mode.LOITER)
        self._auto_seq = -1

    def on_set_current(self, seq: int) -> None:
        self._auto_seq = -1
        self.mission_complete = False

    # -- GCS-loss failsafe ----------------------------------------------------------------------
    def on_gcs_heartbeat(self, now_s: float) -> None:
        self._gcs_last_hb_s = now_s
        if self._gcs_failsafe:
            self._gcs_failsafe = False
            self.say("GCS link back")

    def check_gcs(self, now_s: float) -> None:
        cfg = self.config
        last = self._gcs_last_hb_s
        if cfg.fs_gcs_enable == 0 or last is None or self._gcs_failsafe:
            return
        if now_s - last > cfg.fs_gcs_timeout_s and self.flying():
            self._gcs_failsafe = True
            if cfg.fs_gcs_enable == 1:
                self.say("Failsafe: GCS lost, RTL", mavlink.MAV_SEVERITY_CRITICAL)
                self._enter(Mode.RTL)
            else:
                self.say("Failsafe: GCS lost, LAND", mavlink.MAV_SEVERITY_CRITICAL)
                self._enter(Mode.LAND)

    # -- per tick -------------------------------------------------------------------------------
    def on_tick(self, t_s: float, dt_s: float) -> None:
        """Mode logic before the flight pipeline's step (simulated time)."""
        self.t_s = t_s
        f = self.flight
        st = self.state
        if not f.armed or st is None:
            return
        # Armed on the ground with nothing to do: disarm after DISARM_DELAY (ArduCopter behaviour).
        delay = self.config.disarm_delay_s
        if delay > 0.0 and self.landed_state() == mavlink.MAV_LANDED_STATE_ON_GROUND and not f.landing:
            self._ground_armed_s += dt_s
            if self._ground_armed_s >= delay:
                self.disarm(reason="Disarming: no take-off")
                return
        else:
            self._ground_armed_s = 0.0
        if self.mode == Mode.RTL or (self.mode == Mode.AUTO and self._rtl_phase):
            self._run_rtl(st)
        elif self.mode == Mode.AUTO:
            self._run_auto(st, t_s)

    def on_disarmed(self) -> None:
        """The pipeline disarmed by itself (touchdown)."""
        if self.mode == Mode.AUTO and not self.mission_complete:
            items = self.mission.items
            cur = self.mission.current
            if 0 < cur < len(items) and items[cur].command in (CMD_LAND, CMD_RTL):
                self._send_reached(cur)  # a landing item is reached on touchdown
            self._complete()
        self._rtl_phase = ""
        if self.mode in (Mode.LAND, Mode.RTL):
            self.mode = Mode.GUIDED if self.mode == Mode.RTL else self.mode

    def _run_rtl(self, st: VehicleState) -> None:
        """RTL: climb to max(altitude, RTL_ALT_M) where we are, fly home at that height, land."""
        f = self.flight
        phase = self._rtl_phase
        if phase in ("", "start"):
            self._rtl_z = max(st.z_m, self.config.rtl_alt_m)
            f.set_target(st.x_m, st.y_m, self._rtl_z)
            self._rtl_phase = "climb"
        elif phase == "climb":
            if abs(st.z_m - self._rtl_z) < TAKEOFF_DONE_M:
                f.set_target(0.0, 0.0, self._rtl_z)
                self._rtl_phase = "home"
        elif phase == "home":
            if math.hypot(st.x_m, st.y_m) < RTL_HOME_RADIUS_M:
                f.land()
                self._rtl_phase = "land"
        # "land": the pipeline descends and disarms on touchdown

    def _start_item(self, it: MissionItem, st: VehicleState, t_s: float) -> None:
        f = self.flight
        self._auto_phase = "fly"
        self._auto_t0 = t_s
        rel = it.frame in RELATIVE_FRAMES
        yaw = self.yaw_from_compass_deg(it.param4) if math.isfinite(it.param4) and it.command == CMD_WAYPOINT else None
        if it.command == CMD_TAKEOFF:
            z = it.z if rel else it.z - self.home.alt_m
            f.set_target(st.x_m, st.y_m, z, yaw)
        elif it.command in (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LAND):
            if it.command != CMD_WAYPOINT and it.x == 0 and it.y == 0:
                x, y = st.x_m, st.y_m
                z = (it.z if rel else it.z - self.home.alt_m) if it.z > 0 else st.z_m
            else:
                x, y, z = self.local_of_global(it.lat_deg, it.lon_deg, it.z, rel)
            if it.command == CMD_LAND:
                z = max(st.z_m, 0.0)
            f.set_target(x, y, z, yaw)
        elif it.command == CMD_RTL:
            self._rtl_phase = "start"
        elif it.command == CMD_CHANGE_SPEED:
            if it.param2 > 0.0:
                f.speed_xy_mps = it.param2
            self._auto_phase = "done"

    def _run_auto(self, st: VehicleState, t_s: float) -> None:
        mission = self.mission
        items = mission.items
        if self.mission_complete or len(items) < 2:
            return
        if mission.current < 1:
            mission.current = 1
        if mission.current >= len(items):
            self._complete()
            return
        it = items[mission.current]
        if self._auto_seq != mission.current:
            self._auto_seq = mission.current
            self._start_item(it, st, t_s)
        f = self.flight
        if self._auto_phase == "fly":
            tx, ty, tz = f.target
            if it.command == CMD_TAKEOFF:
                if abs(st.z_m - tz) < TAKEOFF_DONE_M:
                    self._auto_phase = "done"
            elif it.command in (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LAND):
                radius = it.param2 if (it.command == CMD_WAYPOINT and it.param2 > 0.0) else self.config.wp_radius_m
                if math.dist((st.x_m, st.y_m, st.z_m), (tx, ty, tz)) < radius:
                    if it.command == CMD_LAND:
                        f.land()
                        self._auto_phase = "landing"
                    else:
                        self._auto_phase = "hold"
                        self._auto_t0 = t_s
        if self._auto_phase == "hold" and t_s - self._auto_t0 >= it.param1:
            self._auto_phase = "done"
        if self._auto_phase == "done":
            self._send_reached(mission.current)
            if mission.current + 1 >= len(items):
                self._complete()  # MISSION_CURRENT stays on the last item
            else:
                mission.current += 1
                self._auto_seq = -1

    def _send_reached(self, seq: int) -> None:
        if self._broadcast is not None:
            self._broadcast(self._mav.mission_item_reached_encode(seq))

    # -- timed plans ----------------------------------------------------------------------------
    def apply_plan_step(self, step: PlanStep) -> None:
        """Carry out a plan step as a ground station would command it (same checks, same modes)."""
        yaw = self.yaw_from_compass_deg(step.yaw_deg) if step.yaw_deg is not None else None
        result: Result = ACCEPTED
        if step.action == "takeoff":
            if self.mode != Mode.GUIDED:
                result = self.set_mode(Mode.GUIDED)
            if result == ACCEPTED and not self.flight.armed:
                result = self.arm()
            if result == ACCEPTED:
                result = self.takeoff(float(step.alt_m or 0.0))
                if result == ACCEPTED and yaw is not None:
                    f = self.flight
                    f.set_target(*f.target, yaw)
        elif step.action == "goto":
            if self.mode != Mode.GUIDED:
                result = self.set_mode(Mode.GUIDED)
            if result == ACCEPTED:
                x, y, z = ned_to_nwu((float(step.north_m or 0.0), float(step.east_m or 0.0), -float(step.alt_m or 0.0)))
                result = self.goto_local(x, y, z, yaw)
        elif step.action == "land":
            result = self.land()
        else:
            result = self.disarm(force=True)
        if result[0] != mavlink.MAV_RESULT_ACCEPTED:
            self.say(f"Plan step at {step.t_s:g} s ({step.action}) refused: {result[1]}", mavlink.MAV_SEVERITY_WARNING)

    def _complete(self) -> None:
        if not self.mission_complete:
            self.mission_complete = True
            self.say("Mission complete")
