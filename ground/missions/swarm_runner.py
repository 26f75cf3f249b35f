"""A swarm mission (``[sitl] count = K``): K vehicles, each flying its own mission, one report.

The runner launches the swarm in lockstep (:class:`ground.sitl.Sitl`: K flight controllers, one
simulator, the ground router), connects a :class:`ground.vehicle.Swarm` to the router, and flies
every vehicle's mission at once, on one thread each, exactly as the one-vehicle runner flies one:
upload (home as item 0), GUIDED, arm, ``MISSION_START``, wait in simulated time until it disarms
or ``max_duration_s``. Then each vehicle's expectations are evaluated on its own FC log, and the
swarm's ``separation`` expectations on the simulator's closest approach (no contact either).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from ground.logs.load import LogError, load_log
from ground.logs.plots import plot_log
from ground.logs.summary import log_metrics
from ground.missions.errors import MissionRunError
from ground.missions.expectations import evaluate
from ground.missions.record import record_from_log
from ground.missions.report import MissionReport, print_report
from ground.missions.schema import Mission
from ground.sitl import Sitl
from ground.vehicle import Swarm, Vehicle

__all__ = ["SeparationResult", "SwarmMissionReport", "run_swarm_mission"]


@dataclass
class SeparationResult:
    """The verdict on one ``separation`` expectation."""

    min_m: float
    measured_m: float | None
    pair: list[int] | None
    at_s: float | None
    contacts: list[dict[str, Any]]

    @property
    def passed(self) -> bool:
        return self.measured_m is not None and self.measured_m >= self.min_m and not self.contacts

    def as_dict(self) -> dict[str, Any]:
        return {"kind": "separation", "passed": self.passed, "min_m": self.min_m, "measured_m": self.measured_m, "pair": self.pair,
                "at_s": self.at_s, "contacts": self.contacts}  # fmt: skip


@dataclass
class SwarmMissionReport:
    """Every vehicle's :class:`MissionReport` (by system id) and the swarm's separation verdicts."""

    mission: Mission
    reports: dict[int, MissionReport]
    separation: list[SeparationResult] = field(default_factory=list)
    proximity: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = 0.0
    json_path: Path | None = None

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.reports.values()) and all(s.passed for s in self.separation)

    def as_dict(self) -> dict[str, Any]:
        return {
            "mission": self.mission.name,
            "file": str(self.mission.path) if self.mission.path is not None else None,
            "count": self.mission.count,
            "passed": self.passed,
            #: every vehicle disarmed before max_duration_s.
            "finished": all(r.finished for r in self.reports.values()),
            "wall_time_s": self.wall_time_s,
            "separation": [s.as_dict() for s in self.separation],
            "proximity": self.proximity,
            "vehicles": {str(sid): r.as_dict() for sid, r in self.reports.items()},
        }


def _print(report: SwarmMissionReport, out: TextIO | None) -> None:
    import sys

    f = out if out is not None else sys.stdout
    for sid, r in report.reports.items():
        print(f"\n=== vehicle {sid} ===", file=f)
        print_report(r, f)
    if report.separation:
        print("\n=== the swarm ===", file=f)
    for s in report.separation:
        where = f" (vehicles {s.pair[0]} and {s.pair[1]} at t = {s.at_s:.2f} s)" if s.pair and s.at_s is not None else ""
        measured = "n/a" if s.measured_m is None else f"{s.measured_m:.2f} m"
        contact = f"; CONTACT {', '.join(str(c['vehicles']) for c in s.contacts)}" if s.contacts else ""
        print(f"  {'PASS' if s.passed else 'FAIL'}  separation >= {s.min_m:g} m: closest {measured}{where}{contact}", file=f)
    verdict = "PASSED" if report.passed else "FAILED"
    print(f"\nswarm mission {report.mission.name}: {verdict} ({len(report.reports)} vehicles, {report.wall_time_s:.1f} s wall)", file=f)


def run_swarm_mission(
    mission: Mission,
    *,
    out_dir: Path,
    json_path: Path | None = None,
    progress: Callable[[str], None] | None = None,
    plots: bool = True,
    report_file: TextIO | None = None,
) -> SwarmMissionReport:
    """Fly a swarm mission in lockstep SITL and evaluate it (see the module docstring)."""
    from ground.missions.runner import _fly, write_report_json

    say = progress if progress is not None else (lambda line: print(line, flush=True))
    lock = threading.Lock()

    def said(line: str) -> None:
        with lock:
            say(line)

    stem = mission.path.stem if mission.path is not None else mission.name
    tlog = out_dir / f"{stem}.tlog"
    wall0 = time.monotonic()
    opts = mission.sitl.options(gcs="udpin:127.0.0.1:0", log_dir=out_dir, tlog=tlog, param_file=out_dir / f"{stem}-fc.parm", name=stem)
    for i in range(mission.count):
        out_dir.joinpath(f"{stem}-fc-v{i + 1}.parm").unlink(missing_ok=True)  # our own files from an earlier run
    said(f"swarm mission {mission.name}: {mission.count} vehicles; lockstep SITL ({mission.sitl.describe()})")
    sitl = Sitl(opts, echo=lambda line: said(f"  {line}"))
    flights: dict[int, Any] = {}
    with sitl:
        assert sitl.gcs_address is not None

        def alive() -> str | None:
            fc_rc, sim_rc = sitl.poll()
            if fc_rc is not None or sim_rc is not None:
                who = "a flight controller" if fc_rc is not None else "the simulator"
                return f"{who} exited during the flight (code {fc_rc if fc_rc is not None else sim_rc})"
            return None

        with Swarm(f"udpout:{sitl.gcs_address}", sitl.sysids, connect_timeout_s=30.0) as swarm:
            index = {sid: i for i, sid in enumerate(sitl.sysids)}

            def fly(v: Vehicle) -> object:
                sid = v.target_system
                flights[sid] = _fly(v, mission.for_vehicle(index[sid]), lambda line: said(f"[v{sid}] {line}"), alive)
                return flights[sid]

            swarm.wait_all(fly)
        sitl.terminate()
    prox = (sitl.sim_summary or {}).get("proximity") or {}
    reports: dict[int, MissionReport] = {}
    for i, (sid, vlog) in enumerate(zip(sitl.sysids, sitl.tlogs)):
        flight = flights[sid]
        vmission = mission.for_vehicle(i)
        try:
            log = load_log(vlog)
        except LogError as exc:
            raise MissionRunError(f"cannot read vehicle {sid}'s FC log: {exc}") from None
        rec = record_from_log(log)
        report = MissionReport(
            mission=vmission, results=evaluate(vmission, rec, flight.home), source=rec.source, source_description=rec.description,
            finished=flight.finished, flight_time_s=flight.end_sim_s - flight.start_sim_s,
            flown_with=f"lockstep SITL swarm, vehicle {sid} of {mission.count}", tlog=vlog, wall_time_s=time.monotonic() - wall0,
            events=[(t, text) for t, text in rec.events if t >= -5.0], notes=[*flight.notes, *rec.notes], metrics=log_metrics(log),
        )  # fmt: skip
        if plots:
            try:
                report.plots = plot_log(log, out_dir / "plots" / f"v{sid}")
            except (LogError, OSError) as exc:
                report.notes.append(f"plots not written: {exc}")
        reports[sid] = report
    separation = [
        SeparationResult(m, prox.get("min_separation_m"), prox.get("min_pair"), prox.get("min_at_s"), list(prox.get("contacts") or []))
        for m in mission.separation_min_m
    ]
    result = SwarmMissionReport(mission, reports, separation, prox, time.monotonic() - wall0)
    if json_path is not None:
        result.json_path = write_report_json(json_path, result.as_dict())
    _print(result, report_file)
    return result
