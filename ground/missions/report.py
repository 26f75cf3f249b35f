"""The mission report: :class:`MissionReport` (the verdicts and what was flown, also as JSON) and
:func:`print_report`. Times are seconds (mission time, simulated; ``wall_time_s`` wall clock)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from ground.logs.summary import format_metrics
from ground.missions.expectations import ExpectationResult, _json_num

if TYPE_CHECKING:
    from ground.missions.schema import Mission

__all__ = ["MissionReport", "print_report"]


@dataclass
class MissionReport:
    """The outcome of :func:`run_mission`: the verdicts and what was flown."""

    mission: Mission
    results: list[ExpectationResult]
    #: "log" or "telemetry".
    source: str
    source_description: str
    #: True when the vehicle disarmed before ``max_duration_s``.
    finished: bool
    #: mission time at which the runner stopped waiting, s.
    flight_time_s: float
    #: "lockstep SITL (...)" or "connected to URL".
    flown_with: str
    tlog: Path | None = None
    plots: list[Path] = field(default_factory=list)
    json_path: Path | None = None
    wall_time_s: float = 0.0
    events: list[tuple[float, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: the flight's :func:`ground.logs.metrics.flight_metrics` from the FC's log (IAE/ISE/ITAE,
    #: effort, max tilt, recovery, crash; its times are seconds since the log's first record),
    #: None when flown without that log (``--connect``: telemetry has no per-tick set-point).
    metrics: dict[str, Any] | None = None

    @property
    def passed(self) -> bool:
        """True when every expectation held."""
        return all(r.passed for r in self.results)

    @property
    def failed(self) -> list[ExpectationResult]:
        return [r for r in self.results if not r.passed]

    def as_dict(self) -> dict[str, Any]:
        m = self.mission
        return {
            "mission": m.name,
            "file": str(m.path) if m.path is not None else None,
            "description": m.description,
            "passed": self.passed,
            "expectations_passed": sum(r.passed for r in self.results),
            "expectations_total": len(self.results),
            "flown_with": self.flown_with,
            "source": self.source,
            "source_description": self.source_description,
            "finished": self.finished,
            "flight_time_s": _json_num(self.flight_time_s),
            "wall_time_s": _json_num(self.wall_time_s),
            "tlog": str(self.tlog) if self.tlog is not None else None,
            "plots": [str(p) for p in self.plots],
            "items": [it.to_toml_entry() for it in m.items],
            "expectations": [r.as_dict() for r in self.results],
            "events": [{"t_s": round(t, 3), "text": text} for t, text in self.events],
            "notes": list(self.notes),
            "metrics": self.metrics,
        }


def print_report(report: MissionReport, file: TextIO | None = None) -> None:
    """The readable report: each expectation PASS/FAIL with the measured value and the limit."""
    f = file if file is not None else sys.stdout
    m = report.mission
    print(file=f)
    print(f"Mission {m.name!r}" + (f" ({m.path})" if m.path else "") + f": {len(m.items)} items, flown with {report.flown_with}", file=f)
    state = "landed and disarmed" if report.finished else "did NOT land and disarm"
    print(f"  {state}; {report.flight_time_s:.1f} s of mission time in {report.wall_time_s:.1f} s wall", file=f)
    print(f"  evaluated from {report.source_description}", file=f)
    for note in report.notes:
        print(f"  note: {note}", file=f)
    if not report.results:
        print("  no expectations in the file", file=f)
    for r in report.results:
        verdict = "PASS" if r.passed else "FAIL"
        subject = f" {r.subject}" if r.subject else ""
        print(f"  {verdict}  expect {r.number} {r.kind}{subject}: {r.measured_text} vs limit {r.limit_text}", file=f)
        print(f"        {r.detail}" + ("  [from telemetry]" if r.source == "telemetry" else ""), file=f)
    n_ok = sum(r.passed for r in report.results)
    print(f"Result: {n_ok}/{len(report.results)} expectations held -> {'PASS' if report.passed else 'FAIL'}", file=f)
    if report.failed:
        print("  failed: " + "; ".join(f"expect {r.number} {r.kind} ({r.description})" for r in report.failed), file=f)
    if report.metrics is not None:
        for label, text in format_metrics(report.metrics, "; times in s of the FC log"):
            print(f"  {label:<20}{text}", file=f)
    else:
        print("  Metrics: n/a (they need the FC's log with its per-tick SMC records)", file=f)
    if report.tlog is not None:
        print(f"log: {report.tlog}", file=f)
    if report.plots:
        print(f"plots: {len(report.plots)} PNG files in {report.plots[0].parent}/", file=f)
    if report.json_path is not None:
        print(f"json: {report.json_path}", file=f)
    f.flush()
