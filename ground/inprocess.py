"""The SITL flight without processes or MAVLink: the FC pipeline and a plant in one loop.

Same pieces as the two processes — :class:`fc.flight.FlightControl`, the plan runner, the
simulator's plants and environment, the frame conversions — called directly, so it measures the
ceiling that MAVLink and UDP take a share of (``smcpilot bench sitl``) and lets tests fly many
scenarios quickly. The state goes through the same NED/FRD round trip the wire applies, rounded to
float32 as MAVLink carries it, so the in-process and process runs see the same numbers.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Sequence

from fc.config import FcConfig
from fc.flight import FlightControl, TickOutput, VehicleState
from fc.commander import Commander
from fc.plan import PlanRunner, PlanStep
from sim_bridge.sensors import VehicleObservation
from smcpilot.frames import (
    body_rates_to_euler_rates,
    euler_frd_to_flu,
    euler_flu_to_frd,
    ned_to_nwu,
    nwu_to_ned,
    rates_flu_to_frd,
    rates_frd_to_flu,
)
from smcpilot.geo import Home
from smcpilot.vehicle import VehicleParams

_f32 = struct.Struct("<12f")


def wire_state(obs: VehicleObservation) -> VehicleState:
    """The FC's view of an observation after the NED/FRD float32 wire round trip."""
    roll, pitch, yaw = euler_flu_to_frd(*obs.euler_rad)
    p, q, r = rates_flu_to_frd(*obs.body_rates_radps)
    xn, yn, zn = nwu_to_ned(obs.position_m)
    vxn, vyn, vzn = nwu_to_ned(obs.velocity_mps)
    v = _f32.unpack(_f32.pack(roll, pitch, yaw, p, q, r, xn, yn, zn, vxn, vyn, vzn))
    phi, theta, psi = euler_frd_to_flu(v[0], v[1], v[2])
    pf, qf, rf = rates_frd_to_flu(v[3], v[4], v[5])
    phi_d, theta_d, psi_d = body_rates_to_euler_rates(phi, theta, pf, qf, rf)
    x, y, z = ned_to_nwu((v[6], v[7], v[8]))
    vx, vy, vz = ned_to_nwu((v[9], v[10], v[11]))
    return VehicleState(x, y, z, vx, vy, vz, phi, theta, psi, phi_d, theta_d, psi_d)


@dataclass
class InProcessRun:
    """Samples of an in-process flight (every ``record_every`` ticks)."""

    t_s: list[float] = field(default_factory=list)
    states: list[VehicleState] = field(default_factory=list)
    outputs: list[TickOutput] = field(default_factory=list)
    targets: list[tuple[float, float, float]] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)
    ticks: int = 0


def fly(
    config: FcConfig,
    vehicle: VehicleParams,
    plant,
    plan: Sequence[PlanStep],
    duration_s: float,
    *,
    physics_hz: float = 1000.0,
    record_every: int = 0,
) -> InProcessRun:
    """Fly ``plan`` for ``duration_s`` simulated seconds; lockstep semantics of the processes.

    ``plant`` has the simulator's ``step(t_s, dt_s, motor_commands, armed)``/``observe()``.
    ``record_every`` = 0 records nothing (benchmarks).
    """
    flight = FlightControl(config, vehicle)
    run = InProcessRun()
    t_now = [0.0]
    commander = Commander(flight, Home(), lambda severity, text: run.events.append((t_now[0], text)))
    runner = PlanRunner(plan)
    period = config.period_s
    substeps = int(round(physics_hz / config.rate_hz))
    dt_phys = 1.0 / physics_hz
    n_ticks = int(round(duration_s * config.rate_hz))
    motors: Sequence[float] = (0.0, 0.0, 0.0, 0.0)
    t_us = 0
    step_us = int(round(dt_phys * 1e6))
    for k in range(n_ticks):
        t_s = t_us * 1e-6
        t_now[0] = t_s
        st = wire_state(plant.observe())
        commander.state = st
        commander.state_fresh = True
        for step in runner.due(t_s):
            commander.apply_plan_step(step)
        commander.on_tick(t_s, period)
        armed_before = flight.armed
        out = flight.step(st, period)
        if armed_before and not flight.armed:
            commander.on_disarmed()
            run.events.append((t_s, "Landed: disarmed"))
        motors = out.motors
        armed = flight.armed
        for _ in range(substeps):
            plant.step(t_us * 1e-6, dt_phys, motors, armed)
            t_us += step_us
        if record_every and k % record_every == 0:
            run.t_s.append(t_s)
            run.states.append(st)
            run.outputs.append(out)
            run.targets.append(flight.target)
    run.ticks = n_ticks
    return run
