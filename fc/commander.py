"""The vehicle's state machine: arming, the mode switch, the command entry points, failsafes.

The commander decides *what* to fly; :class:`fc.flight.FlightControl` flies it. Each flight mode
is one object (:mod:`fc.modes`, after ArduCopter's mode.h); the commander keeps arming and
disarming, the switch between modes, the command entry points (``takeoff``, ``goto_local``,
``reposition``, ``land``, ``rtl``, ``mission_start``, ``set_mode``, ``apply_plan_step``), the
disarm delay and the GCS-loss failsafe, and hands every control tick to the current mode
(:meth:`Commander.on_tick`).

Every request returns None (carried out) or a :class:`fc.modes.Refusal` saying why not; the
ground protocol (:mod:`fc.gcs`) turns that into ``COMMAND_ACK`` and a ``STATUSTEXT``. Positions
handed to the flight pipeline are in the paper frame (x north, y west, z up); conversions from
wire frames happen in :mod:`fc.inbound`. Flight logic runs on simulated time; the GCS-loss
failsafe on the wall clock (a ground station lives in real time).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import inbound
from fc.estimate import EstimatorParams, EstimatorState, HoldPoint, hold_point
from fc.flight import FlightControl, VehicleState
from fc.mission import MissionStore
from fc.modes import AutoMode, FlightMode, Refusal, build_modes
from smcpilot.geo import Home
from smcpilot.limits import takeoff_refusal, target_refusal
from smcpilot.plan import PlanStep
from smcpilot.protocol import Mode, mode_name

__all__ = ["Commander", "CommanderInput", "Refusal"]


#: armed "on the ground": the estimate below this height (m, up) with the set-point's below
#: :data:`ON_GROUND_TARGET_M` (MAV_LANDED_STATE_ON_GROUND; the disarm delay counts then).
ON_GROUND_Z_M = 0.15
ON_GROUND_TARGET_M = 0.3


def ground_armed_count(ground_s: float, delay_s: float, z_m: float, target_z_m: float, landing: bool, dt_s: float) -> float:
    """The disarm delay's count after an armed tick of ``dt_s`` s (s): grown while the vehicle sits on
    the ground with nothing to do (height ``z_m`` and set-point ``target_z_m``, m up; not while
    landing) and a delay ``delay_s`` > 0 is set (ArduCopter's DISARM_DELAY), else 0. The vehicle
    disarms once it reaches ``delay_s``. Pure: the compiled flights (:mod:`lab.fast`,
    :mod:`fc.lockstep_kernel`) count it as :meth:`Commander.on_tick` does."""
    if delay_s > 0.0 and not landing and z_m < ON_GROUND_Z_M and target_z_m < ON_GROUND_TARGET_M:
        return ground_s + dt_s
    return 0.0


class CommanderInput(NamedTuple):
    """What the flight core tells the commander about the vehicle (paper frame), in one value:
    every tick, and between ticks before a command is judged (:meth:`Commander.observe`)."""

    #: the state flown on (the estimate); None: none usable yet.
    state: VehicleState | None
    #: the state is recent (real time: younger than the state timeout) and usable.
    fresh: bool
    #: the state-loss failsafe is flying.
    failsafe: bool
    #: the estimator's state, the hold point's source (:mod:`fc.estimate`); None: the hold point
    #: is the state's own position and yaw.
    estimate: EstimatorState | None
    #: every field of the latest state was measured (False: dead reckoning, or unusable).
    estimate_ok: bool


class Commander:
    """Owns the modes and the mission execution for one vehicle."""

    def __init__(
        self,
        flight: FlightControl,
        home: Home,
        event: Callable[[int, str], None],
        *,
        item_reached: Callable[[int], None] | None = None,
    ) -> None:
        """``event`` hears every event; ``item_reached`` every mission item reached (the FC's
        ground edge sends ``MISSION_ITEM_REACHED``; None: nobody hears it)."""
        self.flight = flight
        self.home = home
        self._event = event
        self._item_reached = item_reached
        #: the stored mission (the ground protocol at the FC's edge fills it; AUTO flies it).
        self.mission = MissionStore(self.on_mission_changed, self.on_set_current)
        self.state: VehicleState | None = None
        self.state_fresh = False
        #: the flight core's estimate after the latest tick and its settings (:mod:`fc.estimate`),
        #: the source of the hold point; None: the hold point is the state's own.
        self.estimate: EstimatorState | None = None
        self.estimate_params: EstimatorParams | None = None
        #: every field of the latest state was measured (False: dead reckoning, or unusable).
        self.estimate_ok = True
        self.failsafe_active = False
        self.t_s = 0.0
        self._ground_armed_s = 0.0
        #: one object per mode, by number; the current one flies each tick.
        self.modes: dict[Mode, FlightMode] = build_modes(self)
        self._auto: AutoMode = self.modes[Mode.AUTO]  # type: ignore[assignment]
        self.current: FlightMode = self.modes[Mode.GUIDED]
        # GCS-loss failsafe
        self._gcs_last_hb_s: float | None = None
        self._gcs_failsafe = False

    # -- what the flight core tells it -----------------------------------------------------------
    def observe(self, inp: CommanderInput) -> None:
        """The vehicle as the flight core sees it now (the one way in: no attribute writes)."""
        self.state = inp.state
        self.state_fresh = inp.fresh
        self.failsafe_active = inp.failsafe
        self.estimate = inp.estimate
        self.estimate_ok = inp.estimate_ok

    @property
    def ground_armed_s(self) -> float:
        """How long the vehicle has sat armed on the ground with nothing to do (the disarm delay), s."""
        return self._ground_armed_s

    def resume(self, t_s: float, ground_armed_s: float) -> None:
        """After ticks flown elsewhere (the compiled flight, :mod:`lab.fast`, which checks the
        disarm delay and the mode's watch itself): the last tick's time and the disarm delay's count."""
        self.t_s = t_s
        self._ground_armed_s = ground_armed_s

    # -- helpers --------------------------------------------------------------------------------
    @property
    def config(self):
        return self.flight.config

    @property
    def mode(self) -> Mode:
        return self.current.number

    @property
    def mission_complete(self) -> bool:
        """AUTO flew the mission to its end (until it is restarted)."""
        return self._auto.complete

    def say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self._event(severity, text)

    def here(self, st: VehicleState) -> HoldPoint:
        """Where the vehicle is, for a set-point "here" (arming, take-off, holding or landing
        where it is): the estimate's filtered hold point when the flight core gave one, else the
        position and yaw of ``st`` (paper frame)."""
        est, p = self.estimate, self.estimate_params
        if est is not None and p is not None:
            return hold_point(est, p)
        return HoldPoint(st.x_m, st.y_m, st.z_m, st.psi_rad)

    def _at_hold_point(self, st: VehicleState) -> VehicleState:
        """``st`` with the hold point's position and yaw (``st`` itself when they agree)."""
        h = self.here(st)
        if (h.x_m, h.y_m, h.z_m, h.psi_rad) == (st.x_m, st.y_m, st.z_m, st.psi_rad):
            return st
        return st._replace(x_m=h.x_m, y_m=h.y_m, z_m=h.z_m, psi_rad=h.psi_rad)

    def item_reached(self, seq: int) -> None:
        """Mission item ``seq`` reached (the ground edge tells every station)."""
        if self._item_reached is not None:
            self._item_reached(seq)

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
        if st.z_m < ON_GROUND_Z_M and tz < ON_GROUND_TARGET_M:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if st.z_m < 0.5 and tz > st.z_m + 0.3:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def flying(self) -> bool:
        return self.flight.armed and self.landed_state() != mavlink.MAV_LANDED_STATE_ON_GROUND

    # -- modes ----------------------------------------------------------------------------------
    def set_mode(self, number: int) -> Refusal | None:
        try:
            mode = Mode(int(number))
        except ValueError:
            return Refusal(f"Mode {mode_name(int(number))} not supported")
        refusal = self.modes[mode].refuse_entry()
        if refusal is not None:
            return refusal
        self._enter(mode)
        return None

    def _enter(self, mode: Mode) -> None:
        """Switch to ``mode`` (no checks): the old mode exits if it changes, the new one enters
        (also when it is the current one: that restarts LAND, RTL and AUTO)."""
        prev = self.current
        new = self.modes[mode]
        if new is not prev:
            prev.exit(mode)
            self.current = new
        self.flight.position_hold = new.position_hold
        st = self.state
        new.enter(prev.number, st)
        if st is not None and new is not prev:
            self.say(f"Mode {new.name}")

    # -- arming ---------------------------------------------------------------------------------
    def prearm_failure(self) -> str | None:
        """Why arming (without force) would be refused now, or None: the PREARM_CHECK health bit."""
        if self.state is None:
            return "PreArm: no vehicle state yet"
        if not self.state_fresh:
            return "PreArm: vehicle state is stale"
        if not self.estimate_ok:
            return "PreArm: position or velocity not measured"
        if self.config.arming_check:
            if self.failsafe_active:
                return "PreArm: in failsafe"
            if not self.on_ground():
                return "PreArm: vehicle is not on the ground"
            return self.current.prearm_failure()
        return None

    def arm(self, force: bool = False) -> Refusal | None:
        f = self.flight
        if f.armed:
            return None
        st = self.state
        if st is None:
            return Refusal("PreArm: no vehicle state yet")
        if not force:
            why = self.prearm_failure()
            if why is not None:
                return Refusal(why)
        f.arm(self._at_hold_point(st))
        self._ground_armed_s = 0.0
        self.current.on_armed()
        self.say("Armed")
        return None

    def disarm(self, force: bool = False, reason: str = "Disarmed") -> Refusal | None:
        f = self.flight
        if not f.armed:
            return None
        if not force and self.flying():
            return Refusal("Disarm refused: flying (use force)")
        f.disarm()
        self.say(reason)
        return None

    # -- commands -------------------------------------------------------------------------------
    def takeoff(self, alt_m: float) -> Refusal | None:
        why = takeoff_refusal(alt_m, self.config.fence)
        if why is not None:
            return Refusal(f"Takeoff refused: {why}")
        if self.mode != Mode.GUIDED:
            return Refusal(f"Takeoff: needs GUIDED, in {self.mode.name}")
        f = self.flight
        if not f.armed:
            return Refusal("Takeoff: arm first")
        st = self.state
        assert st is not None
        if self.flying():
            x, y = f.target[0], f.target[1]
        else:
            here = self.here(st)
            x, y = here.x_m, here.y_m
        f.set_target(x, y, alt_m)
        self.say(f"Takeoff to {alt_m:.1f} m")
        return None

    def goto_local(self, x: float, y: float, z: float, yaw_rad: float | None) -> Refusal | None:
        """GUIDED set-point in the paper frame (z up above home; FLU yaw, None: keep)."""
        why = self.target_refusal(x, y, z, yaw_rad)
        if why is not None:
            return Refusal(f"Set-point refused: {why}")
        if self.mode != Mode.GUIDED:
            return Refusal(f"Set-point: needs GUIDED, in {self.mode.name}")
        if not self.flight.armed:
            return Refusal("Set-point refused: not armed (arm and take off first)")
        self.flight.set_target(x, y, z, yaw_rad)
        return None

    def target_refusal(self, x: float, y: float, z: float, yaw_rad: float | None = None) -> str | None:
        """Why a paper-frame target (x north, y west, z up above home; FLU yaw) may not be flown,
        or None: the one validation of every target source (:func:`smcpilot.limits.target_refusal`
        with this vehicle's fence)."""
        if yaw_rad is not None and not math.isfinite(yaw_rad):
            return "yaw is not a finite number"
        return target_refusal(x, -y, z, self.config.fence)

    def goto(self, target: inbound.Target) -> Refusal | None:
        """:meth:`goto_local` of a target from :mod:`fc.inbound`."""
        return self.goto_local(target.x_m, target.y_m, target.z_m, target.yaw_rad)

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, relative: bool, yaw_deg: float) -> Refusal | None:
        """DO_REPOSITION: fly to a global point (altitude above home if ``relative``, else AMSL),
        compass heading ``yaw_deg`` (NaN: keep); switches to GUIDED."""
        if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
            return Refusal("Reposition: non-finite position")
        if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
            return Refusal("Reposition: latitude/longitude out of range")
        if not self.flight.armed:
            return Refusal("Reposition: not armed")
        target = inbound.reposition_target(self.home, lat_deg, lon_deg, alt_m, relative, yaw_deg)
        why = self.target_refusal(target.x_m, target.y_m, target.z_m, target.yaw_rad)
        if why is not None:
            return Refusal(f"Reposition refused: {why}")
        if self.mode != Mode.GUIDED:
            self._enter(Mode.GUIDED)
        return self.goto(target)

    def land(self) -> Refusal | None:
        self._enter(Mode.LAND)
        return None

    def rtl(self) -> Refusal | None:
        if not self.flight.armed:
            return Refusal("RTL: not armed")
        self._enter(Mode.RTL)
        return None

    def mission_start(self, first: int) -> Refusal | None:
        items = self.mission.items
        if len(items) < 2:
            return Refusal("Mission start: no mission loaded")
        if first > 0:
            if first >= len(items):
                return Refusal(f"Mission start: item {first} does not exist")
            self.mission.current = first
        elif self.mission.current < 1 or self.mission_complete:
            self.mission.current = 1
        if not self.flight.armed:
            return Refusal("Mission start: arm first")
        self._enter(Mode.AUTO)
        self._auto.restart()
        return None

    def on_mission_changed(self) -> None:
        if self.mode == Mode.AUTO and len(self.mission.items) < 2:
            self.say("Mission cleared: LOITER", mavlink.MAV_SEVERITY_WARNING)
            self._enter(Mode.LOITER)
        self._auto.restart_item()

    def on_set_current(self, seq: int) -> None:
        self._auto.restart()

    # -- GCS-loss failsafe ----------------------------------------------------------------------
    def on_gcs_heartbeat(self, now_s: float) -> None:
        self._gcs_last_hb_s = now_s
        if self._gcs_failsafe:
            self._gcs_failsafe = False
            self.say("GCS link back")

    def gcs_loss_may_act(self, now_s: float) -> bool:
        """:meth:`check_gcs` at wall time ``now_s`` might act (False: it would certainly do nothing)."""
        cfg = self.config
        last = self._gcs_last_hb_s
        return cfg.fs_gcs_enable != 0 and last is not None and not self._gcs_failsafe and now_s - last > cfg.fs_gcs_timeout_s

    def check_gcs(self, now_s: float) -> None:
        """The GCS-loss failsafe (``FS_GCS_ENABLE``): no ground-station heartbeat for ``FS_GCS_TIMEOUT``
        while flying: RTL or LAND."""
        if self.gcs_loss_may_act(now_s) and self.flying():
            cfg = self.config
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
        self._ground_armed_s = ground_armed_count(self._ground_armed_s, delay, st.z_m, f.target[2], f.landing, dt_s)
        if self._ground_armed_s >= delay > 0.0:
            self.disarm(reason="Disarming: no take-off")
            return
        self.current.run(st, t_s, dt_s)

    def on_touchdown(self) -> None:
        """The pipeline disarmed by itself on touchdown (it owns that decision): the mode hears
        of it (AUTO reports a landing item reached; RTL hands over to GUIDED, silently)."""
        nxt = self.current.on_touchdown()
        if nxt is not None:
            self.current.exit(nxt)
            self.current = self.modes[nxt]

    # -- timed plans ----------------------------------------------------------------------------
    def apply_plan_step(self, step: PlanStep) -> None:
        """Carry out a plan step as a ground station would command it (same checks, same modes)."""
        yaw = inbound.plan_step_yaw(step)
        result: Refusal | None = None
        if step.action == "takeoff":
            if self.mode != Mode.GUIDED:
                result = self.set_mode(Mode.GUIDED)
            if result is None and not self.flight.armed:
                result = self.arm()
            if result is None:
                result = self.takeoff(float(step.alt_m or 0.0))
                if result is None and yaw is not None:
                    f = self.flight
                    f.set_target(*f.target, yaw)
        elif step.action == "goto":
            if self.mode != Mode.GUIDED:
                result = self.set_mode(Mode.GUIDED)
            if result is None:
                result = self.goto(inbound.plan_step_target(step))
        elif step.action == "land":
            result = self.land()
        else:
            result = self.disarm(force=True)
        if result is not None:
            self.say(f"Plan step at {step.t_s:g} s ({step.action}) refused: {result.reason}", mavlink.MAV_SEVERITY_WARNING)
