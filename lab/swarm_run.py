"""``smcpilot run`` of a swarm scenario (a ``[swarm]`` table): K vehicles in-process, or as SITL.

In-process, K flight cores (:class:`fc.core.FlightCore`) fly K plants in one loop, in the order
the simulator process steps them: every vehicle's state at t and tick, then every plant's physics
for one control period, then the separation check on the true positions at t + period (a contact
crashes both vehicles before their next tick; separation events and contacts are logged as the
simulator's ``STATUSTEXT``). So the K vehicles give the same motor commands, tick for tick, as
``smcpilot sitl --count K`` in lockstep (a test checks it, contact included). Each vehicle writes
its own ``.tlog`` (``NAME-vN.tlog``, as the launcher names them) and gets its own summary; the run
has the swarm's separation summary. ``--sitl`` flies the real processes (:class:`ground.sitl.Sitl`).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc.core import FlightCore
from fc.params import config_for, options_for
from lab.run import FlightResult, _diverged_text, _TlogRecorder
from lab.runner import imu_accel, state_of_wire, wire_values
from sim_bridge.build import plant_for
from sim_bridge.faults import FaultEvent
from sim_bridge.proximity import Proximity
from smcpilot.errors import DivergenceError
from smcpilot.geo import Home
from smcpilot.scenario import FleetVehicle, Scenario

_f32x4 = struct.Struct("<4f")
#: ``stop()`` of :func:`fly_swarm_in_process` is asked this often (control ticks).
STOP_EVERY_TICKS = 500


@dataclass
class SwarmResult:
    """A flown swarm: each vehicle's :class:`~lab.run.FlightResult` (in fleet order) and the separation."""

    scenario: Scenario
    mode: str
    vehicles: list[FlightResult]
    sysids: list[int]
    proximity: dict[str, Any] = field(default_factory=dict)
    wall_s: float = 0.0

    @property
    def status(self) -> str:
        bad = [r.status for r in self.vehicles if r.status != "ok"]
        return bad[0] if bad else "ok"

    def as_json(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario.name,
            "mode": self.mode,
            "status": self.status,
            "count": len(self.vehicles),
            "wall_seconds": self.wall_s,
            "proximity": self.proximity,
            "vehicles": [{"sysid": sid, **r.as_json()} for sid, r in zip(self.sysids, self.vehicles)],
        }


def vehicle_tlog(tlog: Path, sysid: int) -> Path:
    """The log of vehicle ``sysid`` of a swarm whose run is named by ``tlog`` (as the launcher names it)."""
    return tlog.with_name(f"{tlog.stem}-v{sysid}.tlog")


def _flight(v: FleetVehicle) -> Scenario:
    """A vehicle's one-vehicle scenario with its system id as a parameter (the FC process gets --sysid)."""
    return v.scenario.with_changes(params=tuple(dict(v.scenario.params, SYSID_THISMAV=float(v.sysid)).items()))


def fly_swarm_in_process(scenario: Scenario, tlog: Path, *, echo: Callable[[str], None] | None = None,
                         stop: Callable[[], bool] | None = None) -> SwarmResult:  # fmt: skip
    """Fly every vehicle of ``scenario`` on its own flight core in this process (see the module
    docstring). ``stop()``, asked every :data:`STOP_EVERY_TICKS` ticks, ends the flight early
    (status "timed out")."""
    fleet = scenario.fleet()
    swarm = scenario.swarm
    assert swarm is not None
    contact = swarm.contact_m if swarm.contact_m is not None else 2.0 * scenario.vehicle.arm_length_m
    prox = Proximity(len(fleet), swarm.separation_m, contact)
    tlog.parent.mkdir(parents=True, exist_ok=True)
    cores: list[FlightCore] = []
    plants = []
    recorders: list[_TlogRecorder] = []
    events: list[list[tuple[float, str]]] = [[] for _ in fleet]
    for i, v in enumerate(fleet):
        sc = _flight(v)
        options = options_for(sc)
        home = Home(*sc.home) if sc.home is not None else Home()

        def event(severity: int, text: str, i: int = i) -> None:
            t_s = cores[i].t_us * 1e-6
            events[i].append((t_s, text))
            recorders[i].event(severity, text)
            if echo is not None:
                echo(f"[v{fleet[i].sysid} {t_s:7.2f} s] {text}")

        cores.append(FlightCore(config_for(sc), sc.vehicle, home=home, plan=sc.plan, event=event, estimator=options.estimator))
        plants.append(plant_for(sc))
        recorders.append(_TlogRecorder(vehicle_tlog(tlog, v.sysid), cores[i], sysid=v.sysid, options=options, plant=plants[i]))

    def sim_event(i: int, ev: FaultEvent) -> None:
        events[i].append((ev.t_s, ev.text))
        recorders[i].sim_event(ev)
        if echo is not None:
            echo(f"[v{fleet[i].sysid} {ev.t_s:7.2f} s] {ev.text}")

    def take_fault_events(i: int) -> None:
        faults = plants[i].faults
        if faults is not None and faults.events:
            for ev in faults.take_events():
                sim_event(i, ev)

    rate_hz, physics_hz = scenario.rate_hz, scenario.physics_hz
    substeps = int(round(physics_hz / rate_hz))
    dt = 1.0 / physics_hz
    step_us = int(round(dt * 1e6))
    pack, unpack = _f32x4.pack, _f32x4.unpack
    k_vehicles = range(len(fleet))
    crashed = [False] * len(fleet)
    status, message = "ok", ""
    t_us = 0
    ticks = 0
    t0 = time.perf_counter()
    try:
        for k in range(scenario.n_ticks):
            if stop is not None and k % STOP_EVERY_TICKS == 0 and k and stop():
                status, message = "timed out", f"stopped at t = {t_us * 1e-6:.2f} of {scenario.duration_s:g} simulated s"
                break
            motors: list[tuple[float, ...]] = []
            armed: list[bool] = []
            for i in k_vehicles:
                obs = plants[i].observe()
                wire = wire_values(obs)
                take_fault_events(i)
                st = state_of_wire(wire)
                out = cores[i].tick(t_us, st, accel_frd=imu_accel(obs, plants[i]) if cores[i].flight.measures_accel else None)
                m = unpack(pack(*out.motors))  # float32, as HIL_ACTUATOR_CONTROLS carries them
                recorders[i].on_tick(ticks, t_us, wire, st, out, m)
                motors.append(m)
                armed.append(out.armed)
            for _ in range(substeps):
                t_s = t_us * 1e-6
                for i in k_vehicles:
                    plants[i].step(t_s, dt, motors[i], armed[i])
                t_us += step_us
            for i in k_vehicles:
                take_fault_events(i)
            ticks += 1
            positions = []
            for i in k_vehicles:
                x, y, z = plants[i].truth().position_m  # type: ignore[attr-defined]
                n_off, e_off = fleet[i].offset_ne_m
                positions.append((x + n_off, -y + e_off, -z))
            t_s = t_us * 1e-6
            for kind, i, j, dist in prox.check(t_s, positions):
                a, b = fleet[i].sysid, fleet[j].sysid
                if kind == "contact":
                    for me, other in ((i, b), (j, a)):
                        sim_event(me, FaultEvent(t_s, mavlink.MAV_SEVERITY_CRITICAL, f"SIM: contact with vehicle {other} ({dist:.2f} m)"))
                        if not crashed[me]:
                            crashed[me] = True
                            faults = plants[me].faults
                            if faults is not None:
                                faults.set_param("SIM_MOT_OFF", 15.0, t_s)
                                take_fault_events(me)
                else:
                    text = f"SIM: vehicles {a} and {b} within {dist:.1f} m"
                    for me in (i, j):
                        sim_event(me, FaultEvent(t_s, mavlink.MAV_SEVERITY_WARNING, text))
    except DivergenceError as exc:
        status, message = "diverged", f"the simulation diverged at t = {exc.time_s:.3f} s: {exc}"
        for rec in recorders:
            rec.event(mavlink.MAV_SEVERITY_CRITICAL, _diverged_text(exc.time_s))
    finally:
        wall = time.perf_counter() - t0
        for rec in recorders:
            rec.close()
    sim_s = (ticks - 1) / rate_hz if ticks else 0.0
    results = []
    for i, v in enumerate(fleet):
        vstatus, vmessage = status, message
        if vstatus == "ok" and cores[i].law_fault is not None:
            vstatus, vmessage = "error", f"the control law failed in flight (the failsafe flew on): {cores[i].law_fault}"
        results.append(FlightResult(v.scenario, "in-process", vehicle_tlog(tlog, v.sysid), ticks, sim_s, wall, vstatus, vmessage, events[i]))
    return SwarmResult(scenario, "in-process", results, [v.sysid for v in fleet], prox.summary([v.sysid for v in fleet]), wall)


def fly_swarm_sitl(scenario: Scenario, tlog: Path, *, echo: Callable[[str], None] | None = None,
                   fc_processes: int | None = None) -> SwarmResult:  # fmt: skip
    """Fly the swarm as its SITL processes in lockstep on free ports (no ground link);
    ``fc_processes``: the flight controllers in that many processes (``smcpilot sitl --fc-processes``)."""
    from ground.sitl import Sitl, SitlError, SitlOptions
    from sim_bridge.app import EXIT_DIVERGED

    fleet = scenario.fleet()
    for v in fleet:
        vehicle_tlog(tlog, v.sysid).with_suffix(".parm").unlink(missing_ok=True)
    opts = SitlOptions(scenario=scenario, timed=True, lockstep=True, gcs=None, log_dir=tlog.parent, tlog=tlog,
                       fc_processes=fc_processes)  # fmt: skip
    t0 = time.perf_counter()
    status, message = "ok", ""
    sitl = Sitl(opts, echo=echo)
    try:
        with sitl:
            sitl.wait()
    except SitlError as exc:
        diverged = sitl.sim is not None and sitl.sim.proc.returncode == EXIT_DIVERGED
        status, message = ("diverged" if diverged else "error"), str(exc)
    wall = time.perf_counter() - t0
    results = []
    for v, fcs in zip(fleet, sitl.fc_summaries or [None] * len(fleet)):
        s = fcs or {}
        results.append(FlightResult(v.scenario, "sitl", vehicle_tlog(tlog, v.sysid), int(s.get("ticks", 0)), float(s.get("sim_time_s") or 0.0),
                                    wall, status, message))  # fmt: skip
    prox = (sitl.sim_summary or {}).get("proximity") or {}
    return SwarmResult(scenario, "sitl", results, [v.sysid for v in fleet], prox, wall)


def fly_swarm(scenario: Scenario, out_dir: Path, *, sitl: bool = False, echo: Callable[[str], None] | None = None,
              fc_processes: int | None = None) -> SwarmResult:  # fmt: skip
    """Fly a swarm scenario one way or the other into ``out_dir``; summarise each vehicle's log
    (``fc_processes``: SITL's flight controllers in that many processes)."""
    from ground.logs import load_log, summarize

    for v in scenario.fleet():
        config_for(_flight(v))  # unknown or out-of-range FC parameters: a clear error before anything flies
    out_dir.mkdir(parents=True, exist_ok=True)
    tlog = out_dir / f"{scenario.name}.tlog"
    scenario.save(out_dir / f"{scenario.name}.scenario.toml")
    result = fly_swarm_sitl(scenario, tlog, echo=echo, fc_processes=fc_processes) if sitl else fly_swarm_in_process(scenario, tlog, echo=echo)
    for r in result.vehicles:
        if r.tlog.exists() and r.tlog.stat().st_size > 0:
            log = load_log(r.tlog)
            r.summary = summarize(log)
            if not r.events:
                r.events = [(e.t_s, e.text) for e in log.events]
    return result


def print_swarm(result: SwarmResult, out: Any) -> None:
    """One line per vehicle and the separation line."""
    from ground.sitl_cmd import proximity_line

    for sid, r in zip(result.sysids, result.vehicles):
        s = r.summary
        err = s.get("position_error_final_m")
        tilt = s.get("max_tilt_deg")
        crash = (s.get("metrics") or {}).get("crashed")
        print(f"  vehicle {sid}: {r.status}, {r.ticks} ticks, final position error {'—' if err is None else f'{err:.3f}'} m,"
              f" max tilt {'—' if tilt is None else f'{tilt:.1f}'}°{', CRASHED' if crash else ''}; log {r.tlog}", file=out)  # fmt: skip
    print(proximity_line(result.proximity), file=out)
