"""The SITL flight without processes or MAVLink: the flight core and a plant in one loop.

The same pieces as the two processes — :class:`fc.core.FlightCore` (the one control tick), the
simulator's plants and environment, the frame conversions — called directly, so it measures the
ceiling that MAVLink and UDP take a share of (``smcpilot bench sitl``), lets tests fly many
scenarios quickly, and is what ``smcpilot run`` uses by default. The state goes through the same
NED/FRD float32 round trip the wire applies, and so do the motor commands (``HIL_ACTUATOR_CONTROLS``
carries float32), so an in-process flight and a lockstep SITL flight of the same scenario give the
same per-tick motor commands, bit for bit.

:func:`simulate` is the loop (parts passed in, as rotorpy's ``simulate()``); :func:`fly` builds
the core for a configuration and a plan.

The IMU: a law that measures acceleration (:attr:`fc.control.law.Law.measures_accel`) gets the
accelerometer's specific force the simulator sends it in ``HIGHRES_IMU`` (:func:`imu_accel`: the
same conversion, the same float32 rounding; the compiled kernel gives the same). Other laws never
see it, and their flights are unchanged.

Faults: the plant's (:mod:`sim_bridge.faults`) act as in the simulator process — the observation
is the faulty sensors' (a dropped-out sensor's wire values are NaN and pass through
:func:`state_of_wire` unconverted: NaN in, NaN out), and every fault start/stop is handed to
``on_fault_event`` (``simulate``) or recorded in :attr:`InProcessRun.events` (``fly``) as the
simulator process would send it as STATUSTEXT.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from fc.config import FcConfig
from fc.core import FlightCore, TickOutput
from fc.flight import VehicleState
from lab.fast.flight import FastRecord, fast_note, fast_simulate, fast_unsupported
from sim_bridge.faults import FaultEvent
from sim_bridge.plants.base import Plant
from sim_bridge.sensors import VehicleObservation, specific_force_frd
from smcpilot.geo import Home
from smcpilot.plan import PlanStep
from smcpilot.vehicle import VehicleParams
from smcpilot.wire import paper_of_wire, wire_of_paper

_f32 = struct.Struct("<12f")
_tuple_new = tuple.__new__
_f32x4 = struct.Struct("<4f")
_f32x3 = struct.Struct("<3f")
_isfinite = math.isfinite


def wire_values(obs: VehicleObservation) -> tuple[float, ...]:
    """The 12 wire values of an observation, NED/FRD, rounded to float32 as MAVLink carries them:
    roll, pitch, yaw, p, q, r (rad, rad/s), x, y, z (m), vx, vy, vz (m/s) (:mod:`smcpilot.wire`)."""
    (phi, theta, psi), (p, q, r), (x, y, z), (vx, vy, vz) = obs.euler_rad, obs.body_rates_radps, obs.position_m, obs.velocity_mps
    return _f32.unpack(_f32.pack(*wire_of_paper(phi, theta, psi, p, q, r, x, y, z, vx, vy, vz)))


def state_of_wire(v: Sequence[float]) -> VehicleState:
    """The FC's state (paper frame) of the 12 wire values of :func:`wire_values`."""
    return _tuple_new(VehicleState, paper_of_wire(*v)[:12])


def wire_state(obs: VehicleObservation) -> VehicleState:
    """The FC's view of an observation after the NED/FRD float32 wire round trip."""
    return state_of_wire(wire_values(obs))


def imu_accel(obs: VehicleObservation, plant: Plant) -> tuple[float, float, float] | None:
    """The accelerometer's specific force as the FC receives it in ``HIGHRES_IMU`` (body FRD, m/s^2,
    float32; :func:`sim_bridge.sensors.specific_force_frd` of the observation with the true
    attitude), or None when it is not measured (a dropout: NaN fields), as the FC takes it."""
    f = _f32x3.unpack(_f32x3.pack(*specific_force_frd(obs.accel_mps2, plant.truth().quaternion, plant.vehicle.gravity_mps2)))  # type: ignore[attr-defined]
    return f if _isfinite(f[0]) and _isfinite(f[1]) and _isfinite(f[2]) else None


#: called after each tick with (tick index, t_us, wire values, state, tick output, motors as sent).
TickHook = Callable[[int, int, tuple[float, ...], VehicleState, TickOutput, tuple[float, ...]], None]
#: called with each fault start/stop of the plant (:class:`sim_bridge.faults.FaultEvent`).
FaultHook = Callable[[FaultEvent], None]


class TickLog(Protocol):
    """What logs every tick of a flight, compiled or not (:class:`lab.run._TlogRecorder`)."""

    def on_tick(self, k: int, t_us: int, wire: tuple[float, ...], st: VehicleState, out: TickOutput, motors: tuple[float, ...]) -> None: ...

    def on_rows(self, rows: np.ndarray) -> None: ...


def simulate(
    core: FlightCore,
    plant: Plant,
    n_ticks: int,
    *,
    rate_hz: float,
    physics_hz: float = 1000.0,
    on_tick: TickHook | None = None,
    stop: Callable[[], bool] | None = None,
    on_fault_event: FaultHook | None = None,
    fast: bool | None = None,
    record: FastRecord | None = None,
    log: TickLog | None = None,
) -> int:
    """Fly ``core`` on ``plant`` for ``n_ticks`` control ticks (lockstep semantics of the processes:
    state at t, one tick, the motor commands held for one control period of physics); returns the
    number of ticks flown (fewer if ``stop()`` said so). The plant's fault starts and stops go to
    ``on_fault_event`` as they happen: those of the state at t before the tick at t, those of the
    physics after the period's steps.

    ``fast`` (None: whenever it can, True: also when a plug-in law's kernel must be compiled
    first) flies the plain ticks in the compiled kernel (:mod:`lab.fast`): the same flight, bit for
    bit, many times faster. It cannot call ``on_tick``
    every tick, so a flight with a tick hook flies in CPython; ``record`` instead keeps a
    :class:`lab.metrics.MetricsRecorder`'s rows (every n-th tick, of the received or the true
    state), compiled or not, and ``log`` gets every tick (its ``on_tick`` in CPython, its
    ``on_rows`` with the compiled flight's log rows: :class:`lab.run._TlogRecorder` writes the same
    ``.tlog`` either way). ``stop()`` is asked at least every
    :data:`lab.fast.flight.CHUNK_TICKS` ticks.
    """
    substeps = int(round(physics_hz / rate_hz))
    dt_phys = 1.0 / physics_hz
    step_us = int(round(dt_phys * 1e6))
    tick = core.tick
    pack, unpack = _f32x4.pack, _f32x4.unpack
    observe = plant.observe
    pstep = plant.step
    faults = getattr(plant, "faults", None)
    rec_every = record.every if record is not None else 0
    rec_on_tick = record.recorder.on_tick if record is not None else None
    truth = getattr(plant, "truth", None) if record is not None and record.truth else None

    flight = core.flight

    def one_tick(k: int, t_us: int) -> int:
        obs = observe()
        wire = wire_values(obs)
        if faults is not None and faults.events:
            for ev in faults.take_events():
                if on_fault_event is not None:
                    on_fault_event(ev)
        st = state_of_wire(wire)
        out = tick(t_us, st, accel_frd=imu_accel(obs, plant) if flight.measures_accel else None)
        motors = unpack(pack(*out.motors))  # float32, as HIL_ACTUATOR_CONTROLS carries them
        armed = out.armed
        if on_tick is not None:
            on_tick(k, t_us, wire, st, out, motors)
        if log is not None:
            log.on_tick(k, t_us, wire, st, out, motors)
        if rec_on_tick is not None and k % rec_every == 0:
            rec_on_tick(k, t_us, wire, wire_state(truth()) if truth is not None else st, out, motors)
        for _ in range(substeps):
            pstep(t_us * 1e-6, dt_phys, motors, armed)
            t_us += step_us
        if faults is not None and faults.events:
            for ev in faults.take_events():
                if on_fault_event is not None:
                    on_fault_event(ev)
        return t_us

    if fast is not False and on_tick is None:
        why = fast_unsupported(core, plant, physics_hz, rate_hz, compile_new=bool(fast))
        if why is None:
            return fast_simulate(core, plant, n_ticks, rate_hz=rate_hz, physics_hz=physics_hz, py_tick=one_tick,  # type: ignore[arg-type]
                                 stop=stop, record=record, log=log)  # fmt: skip
        if fast:
            fast_note(why)
    t_us = 0
    for k in range(n_ticks):
        t_us = one_tick(k, t_us)
        if stop is not None and stop():
            return k + 1
    return n_ticks


@dataclass
class InProcessRun:
    """Samples of an in-process flight (every ``record_every`` ticks); ``events`` holds the FC's
    events and the simulator's fault starts/stops, (t_s, text), in the order they happened."""

    t_s: list[float] = field(default_factory=list)
    states: list[VehicleState] = field(default_factory=list)
    outputs: list[TickOutput] = field(default_factory=list)
    targets: list[tuple[float, float, float]] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)
    ticks: int = 0


def fly(
    config: FcConfig,
    vehicle: VehicleParams,
    plant: Plant,
    plan: Sequence[PlanStep],
    duration_s: float,
    *,
    physics_hz: float = 1000.0,
    record_every: int = 0,
    home: Home = Home(),
    fast: bool | None = None,
) -> InProcessRun:
    """Fly ``plan`` for ``duration_s`` simulated seconds (``duration_s`` × rate ticks).

    ``record_every`` = 0 records nothing but the events (benchmarks); then the flight flies
    compiled where it can (``fast``, as :func:`simulate`).
    """
    run = InProcessRun()
    core = FlightCore(config, vehicle, home=home, plan=plan, event=lambda severity, text: run.events.append((core.t_us * 1e-6, text)))
    flight = core.flight

    def record(k: int, t_us: int, wire: tuple[float, ...], st: VehicleState, out: TickOutput, motors: tuple[float, ...]) -> None:
        if record_every and k % record_every == 0:
            run.t_s.append(t_us * 1e-6)
            run.states.append(st)
            run.outputs.append(out)
            run.targets.append(flight.target)

    n_ticks = int(round(duration_s * config.rate_hz))
    run.ticks = simulate(core, plant, n_ticks, rate_hz=config.rate_hz, physics_hz=physics_hz, on_tick=record if record_every else None, fast=fast,
                         on_fault_event=lambda ev: run.events.append((ev.t_s, ev.text)))  # fmt: skip
    return run
