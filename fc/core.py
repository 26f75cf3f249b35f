"""The flight core: one control tick of the flight controller, with no I/O.

Every runner calls :meth:`FlightCore.tick` and nothing else flies the vehicle: the FC process
(:mod:`fc.app`, in lockstep and in real time), the in-process scenario runner (:mod:`lab.runner`)
and the tests. One tick, in order:

1. the timed plan's due steps (simulated time since the first tick), carried out as a ground
   station would command them;
2. **the estimate** (:func:`fc.estimate.estimate_step`): fields the simulator did not measure
   (NaN: a sensor dropout) are dead-reckoned (position, velocity: for at most ``FS_POS_TMO``
   seconds, with a ``STATUSTEXT`` when that starts and ends) or make the state unusable
   (attitude, rates, or a position missing longer); the hold point (a filtered position and
   yaw) for the set-points "here" goes to the commander;
   **state-loss failsafe**: no state, a stale one (real time) or an unusable one, while armed ->
   open loop, level, a fraction of hover thrust, ``STATUSTEXT``; when the state comes back: land
   where we are;
3. otherwise the mode logic (:class:`fc.commander.Commander`: the disarm delay, then the current
   mode object of :mod:`fc.modes`, e.g. AUTO's items or RTL's phases) and the flight pipeline
   (:class:`fc.flight.FlightControl`: prefilters, position loop, law, mixer, anti-windup);
   **touchdown** while landing disarms (the pipeline decides that, and nothing else does), and
   the commander hears of it (:meth:`fc.commander.Commander.on_touchdown`);
4. **GCS-loss failsafe** on the wall clock the caller passes (a ground station lives in real time).

Inputs are arguments (time in microseconds, the state in the paper frame or None, whether it is
fresh, the wall clock for the GCS link); the output is a :class:`TickOutput`. Events (arming,
failsafes, landings) go to the ``event`` sink the runner gives, as ``(severity, text)``; the FC
process turns them into ``STATUSTEXT``, the in-process runner records them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.commander import Commander, CommanderInput
from fc.config import FcConfig
from fc.estimate import (
    EST_ATTITUDE_LOST,
    EST_DEAD_RECKONING,
    EST_OK,
    ESTIMATOR_START,
    MISSING_ATTITUDE,
    MISSING_POSITION,
    MISSING_RATES,
    EstimatorConfig,
    EstimatorState,
    estimate_step,
    estimator_params,
)
from fc.flight import FlightControl, LawFault, PipelineOutput, VehicleState
from fc.modes.base import WATCH_ALWAYS
from smcpilot.geo import Home
from smcpilot.plan import PlanRunner, PlanStep
from smcpilot.protocol import FLAG_ARMED, FLAG_FAILSAFE, FLAG_LANDING, FLAG_POSITION_HOLD
from smcpilot.vehicle import VehicleParams

EventSink = Callable[[int, str], None]
_NO_EVENTS: tuple[tuple[int, str], ...] = ()


class TickOutput(NamedTuple):
    """What one tick of the flight core produced."""

    #: motor commands c1..c4 in [0, 1] (rotors 1 right, 2 front, 3 left, 4 rear).
    motors: tuple[float, float, float, float]
    #: the motors spin (SAFETY_ARMED in HIL_ACTUATOR_CONTROLS.mode).
    armed: bool
    #: ``FLAG_*`` bits of :mod:`smcpilot.protocol` (armed, landing, failsafe, position hold).
    flags: int
    #: the mode after this tick (ArduCopter custom-mode number).
    mode: int
    #: the pipeline's output: realised inputs, limits, the law's diagnostics, references.
    pipeline: PipelineOutput
    #: events raised during this tick, ``(MAV_SEVERITY, text)``, in order.
    events: tuple[tuple[int, str], ...]


class FlightCore:
    """The flight controller without sockets: plan, modes, failsafes, pipeline, events."""

    def __init__(
        self,
        config: FcConfig,
        vehicle: VehicleParams,
        *,
        home: Home = Home(),
        plan: Sequence[PlanStep] = (),
        event: EventSink | None = None,
        item_reached: Callable[[int], None] | None = None,
        estimator: EstimatorConfig | None = None,
    ) -> None:
        """``event`` receives every event as it happens; ``item_reached`` every mission item
        reached (the FC's ground edge sends ``MISSION_ITEM_REACHED``; the mission protocol itself
        lives there too, over :attr:`Commander.mission`); ``estimator`` sets the dead reckoning and
        the hold filter (None: the defaults; ``FS_POS_TMO`` in the FC)."""
        self.config = config
        self.vehicle = vehicle
        self.home = home
        self._sink: EventSink = event if event is not None else (lambda severity, text: None)
        #: events raised during the tick in progress (one list, reused: no allocation per tick).
        self._events: list[tuple[int, str]] = []
        self._in_tick = False
        self.flight = FlightControl(config, vehicle)
        self.commander = Commander(self.flight, home, self.event, item_reached=item_reached)
        self.plan = PlanRunner(plan)
        #: the latest state (paper frame), None before the first one.
        self.state: VehicleState | None = None
        #: in the state-loss failsafe.
        self.failsafe = False
        self.failsafe_events = 0
        self.ticks = 0
        #: time of the first tick, µs (plan times count from it).
        self.t0_us = 0
        #: simulated time of the latest tick, µs (events raised between ticks carry it too).
        self.t_us = 0
        self._last: TickOutput | None = None
        #: the lockstep kernel's last tick, not yet made a TickOutput (:attr:`last` makes it when read).
        self._plain_last: tuple[list[float], int, int] | None = None
        self.estimator = estimator if estimator is not None else EstimatorConfig()
        self._est_params = estimator_params(self.estimator, config.period_s)
        self.commander.estimate_params = self._est_params
        self._est: EstimatorState = ESTIMATOR_START
        #: the estimate's status after the latest tick (``fc.estimate.EST_*``).
        self.estimate_status = EST_OK
        self._est_missing = 0
        #: states with fields not measured (non-finite), and ticks flown on a dead-reckoned state.
        self.states_missing = 0
        self.dead_reckoning_ticks = 0
        #: the control law failed (raised, NaN, a malformed command): the state-loss failsafe flies
        #: until the vehicle is down and disarmed; the first failure's message.
        self.law_failed = False
        self.law_fault: str | None = None

    # -- events and configuration ---------------------------------------------------------------
    def event(self, severity: int, text: str) -> None:
        """Raise an event: to the sink now, and into the current tick's output."""
        if self._in_tick:
            self._events.append((severity, text))
        self._sink(severity, text)

    def reconfigure(self, config: FcConfig) -> None:
        """Live parameter change: takes effect from the next tick. The FC process reaches this
        through its one listener for changes (:meth:`fc.app.FlightControllerApp.apply_config`,
        which also retimes the telemetry streams)."""
        self.flight.reconfigure(config)  # first: a law that refuses the settings (LawError) changes nothing
        self.config = config
        self._est_params = self.commander.estimate_params = estimator_params(self.estimator, config.period_s)

    def reconfigure_estimator(self, estimator: EstimatorConfig) -> None:
        """New estimator settings (``FS_POS_TMO``), from the next tick; its state is kept."""
        self.estimator = estimator
        self._est_params = self.commander.estimate_params = estimator_params(estimator, self.config.period_s)

    @property
    def estimate_missing(self) -> int:
        """Which groups of the latest state were not measured (``fc.estimate.MISSING_*`` bits)."""
        return self._est_missing

    @property
    def mode(self) -> int:
        return int(self.commander.mode)

    def flags(self) -> int:
        """The ``FLAG_*`` bits of the current condition."""
        f = self.flight
        return (
            (FLAG_ARMED if f.armed else 0)
            | (FLAG_LANDING if f.landing else 0)
            | (FLAG_FAILSAFE if self.failsafe else 0)
            | (FLAG_POSITION_HOLD if f.position_hold else 0)
        )

    # -- inputs between ticks -------------------------------------------------------------------
    def set_state(self, state: VehicleState | None, fresh: bool = True) -> None:
        """Tell the commander the latest state (before a command is judged, e.g. arming).

        ``state`` must be finite (what :meth:`tick` gives after the estimate); called from
        outside a tick, the hold point is the state's own position and yaw."""
        if state is not None:
            self.state = state
        c = self.commander
        c.observe(CommanderInput(self.state, fresh and self.state is not None, self.failsafe, None, c.estimate_ok))

    def on_gcs_heartbeat(self, wall_s: float) -> None:
        """A ground station's heartbeat at wall time ``wall_s``: keeps the GCS-loss failsafe away."""
        self.commander.on_gcs_heartbeat(wall_s)

    # -- the tick -------------------------------------------------------------------------------
    def tick(
        self, t_us: int, state: VehicleState | None, *, fresh: bool = True, wall_s: float | None = None,
        accel_frd: tuple[float, float, float] | None = None,
    ) -> TickOutput:  # fmt: skip
        """One control tick at simulated time ``t_us``.

        ``state`` is the latest state (None: none yet); ``fresh`` False marks it stale (real time:
        older than ``failsafe_state_timeout_s``). ``wall_s`` is the wall clock for the GCS-loss
        failsafe (None: not checked this tick). ``accel_frd`` is the IMU's specific force with the
        state (body FRD, m/s^2; None: none), for a law that measures acceleration
        (:meth:`fc.flight.FlightControl.step`).
        """
        if self.ticks == 0:
            self.t0_us = t_us
        self.ticks += 1
        self.t_us = t_us
        self._in_tick = True
        try:
            out = self._step(t_us, state, fresh, accel_frd)
            if wall_s is not None:
                self.commander.check_gcs(wall_s)
        finally:
            self._in_tick = False
        events = self._events
        tick_events = _NO_EVENTS
        if events:  # rare: most ticks raise none, and then nothing is allocated
            tick_events = tuple(events)
            events.clear()
        f = self.flight
        mode = int(self.commander.current.number)
        result = TickOutput(out.motors, f.armed, self.flags(), mode, out, tick_events)
        self.last = result
        return result

    @property
    def last(self) -> TickOutput | None:
        """What the latest tick produced (None before the first)."""
        plain = self._plain_last
        if plain is not None:  # (made when read: telemetry reads it a few times a second, not every tick)
            self._plain_last = None
            outputs, flags, mode = plain
            out = self.flight._held_output(outputs)
            self._last = TickOutput(out.motors, True, flags, mode, out, _NO_EVENTS)
        return self._last

    @last.setter
    def last(self, value: TickOutput | None) -> None:
        self._plain_last = None
        self._last = value

    # -- ticks flown by a compiled kernel (fc.lockstep_kernel) ---------------------------------------
    def plain_watch(self) -> tuple[float, float, float, float, float] | None:
        """The mode's watch (:class:`fc.modes.base.Watch`) when the next tick may be flown by the
        lockstep kernel (:mod:`fc.lockstep_kernel`, which checks the rest itself), else None: a
        tick after the first, armed, no failsafe, the law not failed, the estimate "everything
        measured", no event waiting, a compiled pipeline, a mode whose per-tick work is a
        watched condition."""
        f = self.flight
        if self.ticks == 0 or not f.armed or self.failsafe or self.law_failed or self.estimate_status != EST_OK or self._events or f._held is None:
            return None
        watch = self.commander.current.watch()
        return None if watch.kind == WATCH_ALWAYS else watch

    def flown_plain(self, t_us: int, state: VehicleState, est: EstimatorState, ground_armed_s: float, outputs: list[float],
                    flags: int, mode: int, *, again: bool) -> None:  # fmt: skip
        """The lockstep kernel flew the tick at ``t_us`` on ``state`` (everything measured: the
        estimate is the state itself; ``est``: the estimator's new state; ``ground_armed_s``: the
        disarm delay's count; ``outputs``: the compiled pipeline's, :data:`fc.compiled_pipeline.IO_OUT`
        on, its new state held already; ``flags`` and ``mode`` as before the tick, which changed
        neither; ``again``: the tick before was the kernel's too, and nothing ran in between): the
        core as :meth:`tick` would have left it (:attr:`last` made when read)."""
        self.ticks += 1
        self.t_us = t_us
        self._est = est
        self._est_missing = 0
        self.state = state
        c = self.commander
        if again:  # (its fresh, failsafe and estimate-ok are the last plain tick's)
            c.state = state
            c.estimate = est
        else:
            c.observe(CommanderInput(state, True, False, est, True))
        c.resume((t_us - self.t0_us) * 1e-6, ground_armed_s)
        self.flight._held.ticks += 1  # type: ignore[union-attr]
        self._plain_last = (outputs, flags, mode)

    def _estimate(self, state: VehicleState, fresh: bool) -> tuple[VehicleState | None, int]:
        """The estimate of a received state: (the state to fly on, or None if it is unusable;
        the status); the commander gets it and the hold point. Events when it changes."""
        self._est, est, status, missing = estimate_step(self._est, state, self.config.period_s, self._est_params)
        if missing:
            self.states_missing += 1
        if status != self.estimate_status:
            self._estimate_event(status, missing)
        self.estimate_status = status
        self._est_missing = missing
        c = self.commander
        if status > EST_DEAD_RECKONING:
            c.observe(CommanderInput(self.state, False, self.failsafe, None, False))
            return None, status
        if status == EST_DEAD_RECKONING:
            self.dead_reckoning_ticks += 1
        self.state = est
        c.observe(CommanderInput(est, fresh, self.failsafe, self._est, status == EST_OK))
        return est, status

    def _estimate_event(self, status: int, missing: int) -> None:
        """``STATUSTEXT`` for a change of the estimate's status (never on an ordinary tick).
        Losing the state while armed is announced by the failsafe."""
        if status == EST_DEAD_RECKONING:
            self.event(mavlink.MAV_SEVERITY_WARNING, f"{_missing_name(missing)} lost: dead reckoning")
        elif status == EST_OK:
            self.event(mavlink.MAV_SEVERITY_INFO, f"{_missing_name(self._est_missing)} back")

    def _step(self, t_us: int, state: VehicleState | None, fresh: bool, accel_frd: tuple[float, float, float] | None = None) -> PipelineOutput:
        status = EST_OK
        if state is not None:
            status = self._estimate(state, fresh)[1]
        else:
            self.set_state(None, fresh)
        st = self.state
        c = self.commander
        t_s = (t_us - self.t0_us) * 1e-6
        for step in self.plan.due(t_s):
            c.apply_plan_step(step)
        flight = self.flight
        dt = self.config.period_s
        if not fresh or st is None or status > EST_DEAD_RECKONING:
            if not self.failsafe and flight.armed:
                self.failsafe = True
                self.failsafe_events += 1
                if status == EST_ATTITUDE_LOST:
                    text = "FAILSAFE: attitude lost, level and descend"
                elif status > EST_DEAD_RECKONING:
                    text = "FAILSAFE: position lost, level and descend"
                else:
                    text = "FAILSAFE: state lost, level and descend"
                self.event(mavlink.MAV_SEVERITY_CRITICAL, text)
            return flight.failsafe_step()
        if self.failsafe:
            # The state is back: stay in failsafe, now closed loop: land where we are.
            self.event(mavlink.MAV_SEVERITY_WARNING, "State back: failsafe landing")
            self.failsafe = False
            if flight.armed:
                c.land()
        c.on_tick(t_s, dt)
        was_armed = flight.armed
        if self.law_failed:
            return self._law_failsafe(st)
        try:
            out = flight.step(st, dt, accel_frd)
        except LawFault as exc:
            # The law is anyone's code: counted, announced once, and the vehicle flown down open loop.
            self._law_failed(str(exc))
            return self._law_failsafe(st)
        if was_armed and not flight.armed:
            c.on_touchdown()
            self.event(mavlink.MAV_SEVERITY_INFO, "Landed: disarmed")
        return out


    def law_failure(self, why: str) -> None:
        """The law failed in a way the runner saw (in real time: it overran its tick again and again):
        from the next tick on the failsafe flies, as for a law that raised."""
        self.flight.law_faults += 1
        self._law_failed(f"law {self.flight.law.name}: {why}")

    def _law_failed(self, text: str) -> None:
        self.law_failed = True
        if self.law_fault is None:
            self.law_fault = text
        self.event(mavlink.MAV_SEVERITY_CRITICAL, f"FAILSAFE: {text}"[:_LAW_TEXT_MAX])

    def _law_failsafe(self, st: VehicleState) -> PipelineOutput:
        """After a law failure: level, a fraction of hover thrust (the state-loss failsafe), and
        disarm once down (low and slow), with an event."""
        flight = self.flight
        cfg = self.config
        if flight.armed and st.z_m < cfg.land_detect_height_m and abs(st.vz_mps) < 0.2:
            flight.disarm()
            self.commander.on_touchdown()
            self.event(mavlink.MAV_SEVERITY_INFO, "Landed: disarmed (control law failed)")
        if not flight.armed:
            self.law_failed = False  # a new arming tries the law again
        return flight.failsafe_step()


#: longest law-failure STATUSTEXT (a few chunks of 50 characters at most).
_LAW_TEXT_MAX = 150


def _missing_name(missing: int) -> str:
    """The sensor a ``MISSING_*`` mask names in a message: attitude, position or velocity."""
    if missing & (MISSING_ATTITUDE | MISSING_RATES):
        return "attitude"
    return "position" if missing & MISSING_POSITION else "velocity"
