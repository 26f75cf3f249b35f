"""One unit's flight, wherever it runs (a Dask worker, this process): the result row, optionally
its time series and its ``.tlog``.

In-process (the default) the unit is the flight core (:class:`fc.core.FlightCore`) on the
simulator's plant (:func:`sim_bridge.build.plant_for`, or the plant's own vehicle for ``plant.*``
variations), through :func:`lab.runner.simulate`, scored with
:func:`ground.logs.metrics.flight_metrics` on the plant's **true** state from the unit's
``score_from_s`` on (a sensor fault is scored by what the vehicle did). A wall-clock watchdog
checked every tick stops a flight that overruns its ``timeout_s`` ("timed out").

With ``sitl`` the unit is the real two processes in lockstep on free ports
(:class:`ground.sitl.Sitl`), stopped (process group, SIGTERM then SIGKILL) when it overruns, and
scored from its log with :func:`ground.logs.summary.log_metrics` (the FC's view, whole flight,
as ``smcpilot log summary`` does).

Statuses: ``ok``; ``crashed`` (the metrics' crash detection: tilt, ground impact, ...); ``diverged``
(the plant left its valid region); ``timed out``; ``error`` with the exception's message.
"""

from __future__ import annotations

import math
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lab.campaign.units import Unit

STATUSES = ("ok", "crashed", "diverged", "timed out", "error")


@dataclass
class Trace:
    """Sampled time series of one flight (true state): time s, 3-D position error m, tilt deg."""

    t_s: list[float] = field(default_factory=list)
    pos_err_m: list[float] = field(default_factory=list)
    tilt_deg: list[float] = field(default_factory=list)


def _base_row(unit: Unit) -> dict[str, Any]:
    return {"unit": unit.index, "group": unit.group, "controller": unit.controller, "seed_index": unit.seed_index, "seed": unit.seed,
            "status": "error", "message": "", "wall_s": 0.0, "sim_s": 0.0, **dict(unit.values)}  # fmt: skip


def fly_unit(unit: Unit, *, trace: bool = False, tlog: Path | None = None) -> tuple[dict[str, Any], Trace | None]:
    """Fly ``unit``: (its result row, its trace if asked). Never raises for a failed flight: the
    row's status and message say what happened."""
    row = _base_row(unit)
    t0 = time.perf_counter()
    try:
        if unit.scenario.swarm is not None:  # K vehicles, one row (lab.campaign.swarm_unit)
            from lab.campaign.swarm_unit import fly_swarm_unit

            _status(row, fly_swarm_unit(unit, row, tlog))
            tr = None
        elif unit.sitl:
            tr = _fly_sitl(unit, row, tlog)
        else:
            tr = _fly_in_process(unit, row, tlog, trace)
    except Exception as exc:  # a worker never loses a unit to an exception: the row says what it was
        row["status"] = "error"
        row["message"] = f"{type(exc).__name__}: {exc}".strip() or traceback.format_exc(limit=1)
        tr = None
    row["wall_s"] = round(time.perf_counter() - t0, 4)
    return row, (tr if trace else None)


def fly_row(unit: Unit) -> dict[str, Any]:
    """The result row of ``unit`` (what a campaign's workers run)."""
    return fly_unit(unit)[0]


def _status(row: dict[str, Any], status: str) -> None:
    if status == "ok" and row.get("crashed"):
        reason = row.get("crash_reason")
        row["status"], row["message"] = "crashed", f"crashed at t = {row.get('crash_t_s') or 0.0:.2f} s" + (f": {reason}" if reason else "")
    else:
        row["status"] = status


def _fly_in_process(unit: Unit, row: dict[str, Any], tlog: Path | None, trace: bool = True) -> Trace | None:
    from fc.core import FlightCore
    from fc.params import settings_for
    from ground.logs.metrics import flight_metrics
    from lab.fast.flight import FastRecord
    from lab.metrics import MetricsRecorder
    from lab.runner import simulate
    from sim_bridge.build import plant_for
    from smcpilot.errors import DivergenceError
    from smcpilot.geo import Home

    sc = unit.scenario
    config, options = settings_for(sc)
    recorder = None
    home = Home(*sc.home) if sc.home is not None else Home()

    def event(severity: int, text: str) -> None:
        if recorder is not None:
            recorder.event(severity, text)

    core = FlightCore(config, sc.vehicle, home=home, plan=sc.plan, event=event, estimator=options.estimator)
    plant = plant_for(sc if unit.plant_vehicle is None else sc.with_changes(vehicle=unit.plant_vehicle))
    if tlog is not None:
        from lab.run import _TlogRecorder

        tlog.parent.mkdir(parents=True, exist_ok=True)
        recorder = _TlogRecorder(tlog, core, options=options, plant=plant)
    every = unit.record_every
    rec = MetricsRecorder(core, every=every)

    # scored on the true state (what the vehicle did), not on what the sensors said; the compiled
    # flight (lab.fast) records the rows and the log itself
    record = FastRecord(rec, every, truth=True)

    deadline = time.perf_counter() + unit.timeout_s
    perf = time.perf_counter
    status, message = "ok", ""
    diverged_t_s: float | None = None
    try:
        ticks = simulate(core, plant, sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, fast=True, record=record, log=recorder,
                         stop=lambda: perf() > deadline, on_fault_event=None if recorder is None else recorder.sim_event)  # fmt: skip
        if ticks < sc.n_ticks:
            status, message = "timed out", f"over the {unit.timeout_s:g} s limit at t = {core.t_us * 1e-6:.2f} of {sc.duration_s:g} simulated s"
    except DivergenceError as exc:
        status, message = "diverged", f"the simulation diverged at t = {exc.time_s:.3f} s: {exc}"
        diverged_t_s = core.t_us * 1e-6
        if recorder is not None:
            from pymavlink.dialects.v20 import ardupilotmega as mavlink

            from lab.run import _diverged_text

            recorder.event(mavlink.MAV_SEVERITY_CRITICAL, _diverged_text(exc.time_s))
    finally:
        if recorder is not None:
            recorder.close()
    if status == "ok" and core.law_fault is not None:
        status, message = "error", f"the control law failed in flight: {core.law_fault}"
    row["sim_s"] = round(core.t_us * 1e-6, 6)
    a = rec.arrays()
    # the rows from score_from_s on: a slice (the rows are in time order), no copies
    keep = slice(int(np.searchsorted(a["t_s"], unit.score_from_s, side="left")), None)
    if a["t_s"][keep].size >= 2:
        metrics = flight_metrics(
            a["t_s"][keep], a["position_m"][keep], a["target_m"][keep], a["euler_rad"][keep], a["euler_ref_rad"][keep],
            a["motors"][keep], a["armed"][keep], a["landing"][keep], fault_starts_s=unit.fault_starts_s,
            velocity_m_s=a["velocity_m_s"][keep], target_yaw_rad=a["target_yaw_rad"][keep], sigma=a["sigma"][keep],
            land_speed_mps=float(config.land_speed_mps), diverged_t_s=diverged_t_s,
        )  # fmt: skip
        row.update(metrics)
    row["message"] = message
    _status(row, status)
    if not trace:
        return None
    err = np.linalg.norm(a["position_m"] - a["target_m"], axis=1)
    eul = a["euler_rad"]
    tilt = np.degrees(np.arccos(np.clip(np.cos(eul[:, 0]) * np.cos(eul[:, 1]), -1.0, 1.0)))
    return Trace(a["t_s"].tolist(), err.tolist(), tilt.tolist())


def _fly_sitl(unit: Unit, row: dict[str, Any], tlog: Path | None) -> Trace | None:
    from ground.logs import load_log
    from ground.logs.summary import log_metrics
    from ground.sitl import Sitl, SitlError, SitlOptions
    from sim_bridge.app import EXIT_DIVERGED

    with tempfile.TemporaryDirectory(prefix="smcpilot-unit-") as tmp:
        path = tlog if tlog is not None else Path(tmp) / "unit.tlog"
        path.parent.mkdir(parents=True, exist_ok=True)
        opts = SitlOptions(scenario=unit.scenario, timed=True, lockstep=True, gcs=None, log_dir=path.parent, tlog=path,
                           param_file=Path(tmp) / "unit.parm")  # fmt: skip
        status, message = "ok", ""
        sitl = Sitl(opts)
        t0 = time.monotonic()
        try:
            with sitl:  # leaving it stops both children (SIGTERM, then SIGKILL): no orphans
                sitl.wait(timeout_s=max(0.1, unit.timeout_s - (time.monotonic() - t0)))
        except SitlError as exc:
            if time.monotonic() - t0 >= unit.timeout_s:
                status, message = "timed out", f"over the {unit.timeout_s:g} s limit: {exc}"
            elif sitl.sim is not None and sitl.sim.proc.returncode == EXIT_DIVERGED:
                status, message = "diverged", str(exc)
            else:
                status, message = "error", str(exc)
        fcs = sitl.fc_summary or {}
        row["sim_s"] = float(fcs.get("sim_time_s") or 0.0)
        if path.exists() and path.stat().st_size > 0:
            log = load_log(path)
            metrics = log_metrics(log)
            if metrics is not None:
                if status == "diverged":
                    metrics["crashed"] = True
                row.update(metrics)
    row["message"] = message
    _status(row, status)
    return None


#: statuses of a flight the vehicle did not survive: the metrics' crash detection, or the plant
#: left its valid region (also a crash in the metrics). Words for the vehicle.
CRASH_STATUSES = ("crashed", "diverged")
#: statuses of a flight the software did not fly to its end: an exception (the law's, the
#: simulator's, ours) or the wall-clock limit. Words for the software.
ERROR_STATUSES = ("error", "timed out")


def is_failure(row: dict[str, Any]) -> bool:
    """A flight that did not end well: any status but ok (a crash or an error)."""
    return row.get("status") != "ok"


def is_crash(row: dict[str, Any]) -> bool:
    """The vehicle crashed (status crashed or diverged, or the metrics say so)."""
    return row.get("status") in CRASH_STATUSES or row.get("crashed") is True or row.get("crashed") == "True"


def is_error(row: dict[str, Any]) -> bool:
    """The software did not fly the unit to its end (status error or timed out)."""
    return row.get("status") in ERROR_STATUSES


def badness(row: dict[str, Any]) -> tuple[int, float]:
    """Sort key of the worst runs: crashes and errors first, then the largest max position error."""
    v = row.get("max_pos_err_m")
    return (1 if is_failure(row) else 0, float(v) if isinstance(v, (int, float)) and math.isfinite(v) else math.inf)
