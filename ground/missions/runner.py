"""The runner: fly a :class:`~ground.missions.schema.Mission` in lockstep SITL (or on a running
vehicle) and evaluate its expectations (:func:`run_mission`; see :mod:`ground.missions`). Waits
are in simulated seconds; the report's wall time in wall-clock seconds.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from ground.logs.load import LogError, load_log
from ground.logs.plots import plot_log
from ground.logs.summary import log_metrics
from ground.missions.errors import MissionRunError
from ground.missions.expectations import evaluate
from ground.missions.record import TelemetryRecorder, record_from_log
from ground.missions.report import MissionReport, print_report
from ground.missions.schema import Mission, _geo_home
from ground.sitl import Sitl
from ground.vehicle import HomePosition, Vehicle, VehicleError
from smcpilot.geo import Home

__all__ = ["PROGRESS_EVERY_SIM_S", "MissionRunError", "run_mission"]

#: A progress line every this many simulated seconds while flying.
PROGRESS_EVERY_SIM_S = 5.0


def _stamp(vehicle: Vehicle) -> float:
    return vehicle.sim_time_s if vehicle.sim_time_s is not None else 0.0


@dataclass
class _Flight:
    home: Home | None
    start_sim_s: float
    end_sim_s: float
    finished: bool
    notes: list[str]


def _fly(vehicle: Vehicle, mission: Mission, progress: Callable[[str], None], alive: Callable[[], str | None]) -> _Flight:
    """Upload, arm, MISSION_START, and wait (simulated time) until disarmed or max_duration_s."""
    notes: list[str] = []
    home_pos: HomePosition | None
    try:
        home_pos = vehicle.get_home(timeout_s=10.0)
    except VehicleError:
        home_pos = None
    if home_pos is None and mission.uses_local_positions:
        raise MissionRunError("the vehicle sent no HOME_POSITION: north_m/east_m items cannot be converted")
    home = _geo_home(home_pos) if home_pos is not None else None
    items = mission.to_items(home)
    progress(f"uploading {len(items)} items (+ home as item 0) through the mission protocol")
    vehicle.upload_mission(items)
    if not vehicle.armed:
        if vehicle.mode != "GUIDED":
            # e.g. AUTO or LAND left over from an earlier flight: arm where nothing starts by itself
            progress(f"mode {vehicle.mode} -> GUIDED before arming")
            vehicle.set_mode("GUIDED")
        progress("arming")
        vehicle.arm()
    progress("MISSION_START (AUTO from item 1)")
    vehicle.start_mission(1)
    start = _stamp(vehicle)
    limit = mission.sitl.max_duration_s
    deadline = start + limit
    next_progress = start + PROGRESS_EVERY_SIM_S
    n_items = len(mission.items)
    dead: list[str] = []

    def done(s: Any) -> bool:
        why = alive()
        if why is not None:
            dead.append(why)
            return True
        now = s.sim_time_s if s.sim_time_s is not None else start
        return (not s.armed) or now >= min(next_progress, deadline)

    finished = False
    while True:
        st = vehicle.wait_for(done, PROGRESS_EVERY_SIM_S + 10.0, what="the mission to progress",
                              value=lambda s: f"armed={s.armed}, mode {s.mode_name}")  # fmt: skip
        if dead:
            raise MissionRunError(dead[0])
        now = st.sim_time_s if st.sim_time_s is not None else start
        if not st.armed:
            finished = True
            progress(f"t={now - start:7.1f} s  disarmed ({st.landed_state_name or 'landed'}) — mission over")
            break
        if now >= deadline:
            notes.append(f"the vehicle was still armed after max_duration_s = {limit:g} s of mission time; the runner stopped waiting")
            progress(f"t={now - start:7.1f} s  max_duration_s reached ({limit:g} s): stop waiting")
            break
        cur = st.mission_current
        if cur is not None and 1 <= cur <= n_items:
            item = mission.items[cur - 1].type
        elif cur is not None and cur > n_items:
            item, cur = "(complete)", n_items
        else:
            item = "-"
        pos = st.position_ned_m
        where = f"N {pos[0]:+7.2f} E {pos[1]:+7.2f} alt {-pos[2]:6.2f} m" if pos is not None else "position unknown"
        progress(f"t={now - start:7.1f} s  item {cur if cur is not None else '-'}/{n_items} {item:<11} {where}  {st.mode_name}")
        while next_progress <= now:
            next_progress += PROGRESS_EVERY_SIM_S
    return _Flight(home, start, _stamp(vehicle), finished, notes)


def _mission_start_from_texts(vehicle: Vehicle, fallback: float) -> float:
    for s in vehicle.statustexts:
        if s.text.strip() == "Mode AUTO" and s.sim_time_s is not None and s.sim_time_s >= fallback - 2.0:
            return s.sim_time_s
    return fallback


def run_mission(
    mission: Mission,
    connect_url: str | None = None,
    *,
    out_dir: Path,
    json_path: Path | None = None,
    progress: Callable[[str], None] | None = None,
    plots: bool = True,
    report_file: TextIO | None = None,
) -> MissionReport:
    """Fly ``mission`` and evaluate its expectations.

    Without ``connect_url``: launch lockstep SITL with the ``[sitl]`` settings (log and FC
    parameter file in ``out_dir``; the FC's ground link points at a free port our
    :class:`~ground.vehicle.Vehicle` listens on), upload the mission through the mission protocol,
    arm, MISSION_START, wait in simulated time until the vehicle disarms or ``max_duration_s``
    passes, stop SITL, and evaluate every expectation on the FC's ``.tlog``. With
    ``connect_url`` (a :mod:`smcpilot.link` URL of a running vehicle): the same flight, evaluated
    on the telemetry received (also written to ``out_dir/<name>-telemetry.tlog``).

    The report carries the flight's metrics (:func:`ground.logs.summary.log_metrics`) from the
    FC's log; there are none from telemetry. Then prints the report (:func:`print_report`, to
    ``report_file``, default stdout), writes the
    plots (:func:`ground.logs.plot_log`, into ``out_dir/plots``) and, with ``json_path``,
    the report as JSON. ``progress`` receives the progress lines (default: print them).
    Raises :class:`MissionRunError`, :class:`ground.sitl.SitlError` or
    :class:`ground.vehicle.VehicleError` when the mission cannot be flown.
    """
    say = progress if progress is not None else (lambda line: print(line, flush=True))
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MissionRunError(f"cannot create the output directory {out_dir}: {exc.strerror or exc}") from None
    if mission.count > 1:
        if connect_url is not None:
            raise MissionRunError(f"a swarm mission ([sitl] count = {mission.count}) launches its own SITL: leave out --connect")
        from ground.missions.swarm_runner import run_swarm_mission

        return run_swarm_mission(mission, out_dir=out_dir, json_path=json_path, progress=progress, plots=plots,  # type: ignore[return-value]
                                 report_file=report_file)  # fmt: skip
    stem = mission.path.stem if mission.path is not None else mission.name
    wall0 = time.monotonic()
    notes: list[str] = []
    log = None
    if connect_url is None:
        tlog = out_dir / f"{stem}.tlog"
        param_file = out_dir / f"{stem}-fc.parm"
        if param_file.exists():
            param_file.unlink()  # our own file from an earlier run: start from the FC's defaults
        vehicle = Vehicle("udpin:127.0.0.1:0", connect_timeout_s=30.0)
        vehicle.open()
        flown_with = f"lockstep SITL ({mission.sitl.describe()})"
        say(f"mission {mission.name}: {len(mission.items)} items, {len(mission.expectations)} expectations; {flown_with}")
        try:
            opts = mission.sitl.options(gcs=f"udp:127.0.0.1:{vehicle.local_address[1]}", log_dir=out_dir, tlog=tlog, param_file=param_file)
            sitl = Sitl(opts, echo=lambda line: say(f"  {line}"))

            def alive() -> str | None:
                fc_rc, sim_rc = sitl.poll()
                if fc_rc is not None or sim_rc is not None:
                    who = "the flight controller" if fc_rc is not None else "the simulator"
                    return f"{who} exited during the flight (code {fc_rc if fc_rc is not None else sim_rc}); log {tlog}"
                return None

            with sitl:
                vehicle.wait_heartbeat()
                flight = _fly(vehicle, mission, say, alive)
        finally:
            vehicle.close()
        fcs = sitl.fc_summary or {}
        if fcs.get("overruns"):
            notes.append(f"the FC reported {fcs['overruns']} control overruns")
        try:
            log = load_log(tlog)
        except LogError as exc:
            raise MissionRunError(f"cannot read the FC log: {exc}") from None
        rec = record_from_log(log)
        report_tlog: Path | None = tlog
    else:
        telemetry_tlog = out_dir / f"{stem}-telemetry.tlog"
        flown_with = f"the vehicle at {connect_url}"
        say(f"mission {mission.name}: {len(mission.items)} items, {len(mission.expectations)} expectations; connecting to {connect_url}")
        vehicle = Vehicle(connect_url)
        recorder = TelemetryRecorder(vehicle, telemetry_tlog)
        try:
            vehicle.open()
            recorder.start()
            vehicle.wait_heartbeat()
            flight = _fly(vehicle, mission, say, lambda: None)
            # Let the last telemetry of the landing arrive.
            try:
                vehicle.sleep_sim(1.0)
            except VehicleError:
                pass
        finally:
            recorder.stop()
            vehicle.close()
        t0 = _mission_start_from_texts(vehicle, flight.start_sim_s)
        rec = recorder.record(t0, mission, flight.home)
        notes.append("no FC log over the ground link: expectations use the telemetry received (10 Hz; armed state at 1 Hz)")
        report_tlog = telemetry_tlog
        try:
            log = load_log(telemetry_tlog)
        except LogError:
            log = None
    notes.extend(flight.notes)
    notes.extend(rec.notes)
    results = evaluate(mission, rec, flight.home)
    report = MissionReport(
        mission=mission,
        results=results,
        source=rec.source,
        source_description=rec.description,
        finished=flight.finished,
        flight_time_s=flight.end_sim_s - flight.start_sim_s,
        flown_with=flown_with,
        tlog=report_tlog,
        wall_time_s=time.monotonic() - wall0,
        events=[(t, text) for t, text in rec.events if t >= -5.0],
        notes=notes,
        metrics=log_metrics(log) if log is not None else None,
    )
    if plots and log is not None:
        try:
            report.plots = plot_log(log, out_dir / "plots")
        except (LogError, OSError) as exc:
            report.notes.append(f"plots not written: {exc}")
    if json_path is not None:
        report.json_path = write_report_json(json_path, report.as_dict())
    print_report(report, report_file)
    return report


def write_report_json(path: Path | str, doc: dict[str, Any]) -> Path:
    """Write a report's JSON to ``path`` (its directory made); :class:`MissionRunError` if it cannot."""
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    except OSError as exc:
        raise MissionRunError(f"cannot write {path}: {exc.strerror or exc}") from None
    return p
