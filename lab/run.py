"""``smcpilot run SCENARIO.toml``: fly one scenario in-process (default) or as the two SITL processes.

Both ways fly the same flight core (:class:`fc.core.FlightCore`) on the same plant
(:func:`sim_bridge.build.plant_for`) and write the same ``.tlog`` (state, motor commands, the
per-tick ``SMC`` record, events), from which the same summary is computed
(:func:`ground.logs.summarize`): in-process has no UDP and no second process, so it runs as
fast as the machine allows; ``--sitl`` runs the real processes in lockstep on free ports. A
lockstep flight is deterministic: the two ways give the same motor commands tick for tick.

Faults (the scenario's ``[[fault]]`` tables, :mod:`smcpilot.faults`) are acted out by the
simulator side either way; their starts and stops are in the ``.tlog`` as the simulator's
``STATUSTEXT`` (component :data:`smcpilot.protocol.SIM_COMPONENT_ID`), as the FC process logs them
when they arrive on its sim link, and in the results' events.

Output (``--out DIR``, default ``out/run/<scenario name>``): ``<name>.tlog``, the effective
scenario ``<name>.scenario.toml`` (re-runnable), the figures of ``smcpilot plot``, and with
``--json PATH`` the results. A run owns what it writes there: it lists its files in
``DIR/.smcpilot-run`` (:data:`RUN_FILES`), and the next run into the same directory first deletes
the files that list names (only those: anything else in DIR is left alone), so a directory never
mixes two runs' artefacts (a cascade run does not keep the adaptive run's ``controller.png``).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fc import telemetry
from fc.core import FlightCore, TickOutput
from fc.flight import VehicleState
from fc.params import FcOptions, config_for, param_messages, settings_for
from lab.fast.kernel import LOG_IMU, LOG_TRUTH
from lab.runner import simulate
from sim_bridge.app import EXIT_DIVERGED
from sim_bridge.build import plant_for
from sim_bridge.faults import FaultEvent
from sim_bridge.sensors import specific_force_frd
from smcpilot.errors import DivergenceError, SmcpilotError
from smcpilot.fastcodec import SMC_NAME, TickRecords, framed
from smcpilot.geo import Home
from smcpilot.lawref import law_argument
from smcpilot.protocol import (
    ACTUATOR_FLAG_LOCKSTEP,
    FC_COMPONENT_ID,
    IMU_FIELDS_UPDATED,
    SIM_COMPONENT_ID,
    SMC_ARRAY_ID,
)
from smcpilot.scenario import Scenario, ScenarioError
from smcpilot.tlog import TlogWriter

MODES = ("in-process", "sitl")
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_ZEROS12 = [0.0] * 12
_ZEROS27 = [0.0] * 27


@dataclass
class FlightResult:
    """One flown scenario: where its log is, how it went, its summary."""

    scenario: Scenario
    mode: str
    tlog: Path
    ticks: int
    sim_s: float
    wall_s: float
    #: "ok", or "diverged" / "error" with ``message``.
    status: str = "ok"
    message: str = ""
    events: list[tuple[float, str]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        s = self.summary
        chi = s.get("chi_hat_final")
        return {
            "scenario": self.scenario.name,
            "mode": self.mode,
            "status": self.status,
            "message": self.message,
            "controller": self.scenario.controller,
            "seed": self.scenario.seed,
            "ticks": self.ticks,
            "sim_seconds": self.sim_s,
            "wall_seconds": self.wall_s,
            "speed": self.sim_s / self.wall_s if self.wall_s > 0 else None,
            "chi_hat_final": dict(zip(("phi", "theta", "psi", "z"), chi)) if chi is not None else None,
            "position_error_final_m": s.get("position_error_final_m"),
            "position_error_rms_m": s.get("position_error_rms_m"),
            "position_error_max_m": s.get("position_error_max_m"),
            "yaw_error_final_deg": s.get("yaw_error_final_deg"),
            "max_tilt_deg": s.get("max_tilt_deg"),
            # IAE/ISE/ITAE, effort, crash, recovery, sigma: ground.logs.metrics (None without a log)
            "metrics": s.get("metrics"),
            "events": [{"t_s": t, "text": text} for t, text in self.events],
            "tlog": str(self.tlog),
            "summary": s,
        }


# -- in-process ---------------------------------------------------------------------------------
_NAN = math.nan


class _TlogRecorder:
    """Writes an in-process flight's ``.tlog`` as the FC process writes its own: the simulator's
    state messages (``ATTITUDE``, ``LOCAL_POSITION_NED`` and, given the ``plant``, the sensed IMU as
    ``HIGHRES_IMU`` and the plant's true state as ``ODOMETRY``, what the simulator process sends
    with each state), the actuator message and the ``SMC`` record of every tick, and the events.

    The simulator's messages carry the sequence numbers the simulator process gives them (it sends
    ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED; the FC logs the state pair first), so a
    tick's records are those of a SITL log of the same flight but for their record stamps (SITL:
    when the datagram arrived, one tick earlier). A NaN is written as the canonical NaN."""

    def __init__(self, path: Path, core: FlightCore, sysid: int = 1, options: FcOptions | None = None, plant: Any = None) -> None:
        self.tlog = TlogWriter(path)
        self.core = core
        self.sysid = sysid
        #: the plant whose IMU and truth are logged (None: the state pair only).
        self.plant = plant
        self._gravity = float(plant.vehicle.gravity_mps2) if plant is not None else 0.0
        self._packets = TickRecords(sysid)
        self._sim_seq = 0
        self._fc_seq = 0
        self._log_seq = 0
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=FC_COMPONENT_ID)
        self._sim_mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=SIM_COMPONENT_ID)
        mav = self._mav
        self.tlog.write_many(0, [m.pack(mav) for m in param_messages(mav, core.config, options)])

    def event(self, severity: int, text: str) -> None:
        """An FC event as the FC process sends it: STATUSTEXT, in chunks when over 50 characters."""
        mav = self._mav
        self.tlog.write_many(self.core.t_us, [m.pack(mav) for m in telemetry.statustexts(mav, severity, text)])

    def sim_event(self, ev: FaultEvent) -> None:
        """A fault start/stop as the simulator sends it (its component's STATUSTEXT), at its time."""
        mav = self._sim_mav
        mav.seq = self._sim_seq  # one sequence for everything the simulator sends
        self.tlog.write(int(round(ev.t_s * 1e6)), telemetry.statustext(mav, ev.severity, ev.text).pack(mav))
        self._sim_seq = mav.seq

    def on_tick(self, k: int, t_us: int, w: tuple[float, ...], st: VehicleState, out: TickOutput, motors: tuple[float, ...]) -> None:
        plant = self.plant
        if plant is None:
            self._write_tick(t_us, w, out.motors, out.armed, telemetry.smc_record(self.core, out))
            return
        tru = plant.truth()
        f = specific_force_frd(plant.observe().accel_mps2, tru.quaternion, self._gravity)
        self._write_tick(t_us, w, out.motors, out.armed, telemetry.smc_record(self.core, out),
                         f, (*tru.position_m, *tru.velocity_mps, *tru.quaternion, *tru.body_rates_radps))  # fmt: skip

    def on_rows(self, rows: np.ndarray) -> None:
        """The ticks a compiled flight logged (:data:`lab.fast.kernel.LOG_COLUMNS`): the records
        :meth:`_write_tick` writes, byte for byte (a test compares the files), in one loop: a
        logged compiled flight spends most of its time here."""
        if self.plant is None:
            for r in rows.tolist():
                self._write_tick(int(r[0]), r[1:13], r[13:17], r[17] != 0.0, r[18:49] + _ZEROS27)
            return
        enc = self._packets
        sysid, sim, fcc = self.sysid, SIM_COMPONENT_ID, FC_COMPONENT_ID
        att_p, att_lo, att_hi, att_x = enc.att
        lpn_p, lpn_lo, lpn_hi, lpn_x = enc.lpn
        imu_p, imu_lo, imu_hi, imu_x = enc.imu
        odo_p, odo_lo, odo_hi, odo_x = enc.odo
        act_p, act_lo, act_hi, act_x = enc.act
        smc_p, smc_lo, smc_hi, smc_x = enc.smc31
        odo_tail = enc.odo_tail
        nan, fields = _NAN, IMU_FIELDS_UPDATED
        write_many = self.tlog.write_many
        s, fs, ls = self._sim_seq, self._fc_seq, self._log_seq
        i0, t0 = LOG_IMU, LOG_TRUTH
        for r in rows.tolist():
            t_us = int(r[0])
            t_ms = (t_us // 1000) & 0xFFFFFFFF
            p, q, rr = r[4], r[5], r[6]
            packets = [
                framed(att_p(0xFD, 0, 0, 0, s, sysid, sim, att_lo, att_hi, t_ms, r[1], r[2], r[3], p, q, rr), att_x),
                framed(lpn_p(0xFD, 0, 0, 0, (s + 3) & 0xFF, sysid, sim, lpn_lo, lpn_hi, t_ms, r[7], r[8], r[9], r[10], r[11], r[12]), lpn_x),
            ]
            fx, fy, fz = r[i0], r[i0 + 1], r[i0 + 2]
            try:
                packets.append(framed(imu_p(0xFD, 0, 0, 0, (s + 1) & 0xFF, sysid, sim, imu_lo, imu_hi, t_us, fx if fx == fx else nan,
                                            fy if fy == fy else nan, fz if fz == fz else nan, p, q, rr, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                            fields, 0), imu_x))  # fmt: skip
                packets.append(framed(odo_p(0xFD, 0, 0, 0, (s + 2) & 0xFF, sysid, sim, odo_lo, odo_hi, t_us, r[t0], -r[t0 + 1], -r[t0 + 2],
                                            r[t0 + 6], r[t0 + 7], -r[t0 + 8], -r[t0 + 9], r[t0 + 3], -r[t0 + 4], -r[t0 + 5],
                                            r[t0 + 10], -r[t0 + 11], -r[t0 + 12]) + odo_tail, odo_x))  # fmt: skip
            except (OverflowError, struct.error):  # beyond float32 (as _write_tick)
                del packets[2:]
            s = (s + 4) & 0xFF
            packets.append(framed(act_p(0xFD, 0, 0, 0, fs, sysid, fcc, act_lo, act_hi, t_us, ACTUATOR_FLAG_LOCKSTEP, r[13], r[14], r[15], r[16],
                                        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, _ARMED if r[17] != 0.0 else 0), act_x))  # fmt: skip
            packets.append(framed(smc_p(0xFD, 0, 0, 0, ls, sysid, fcc, smc_lo, smc_hi, t_us, SMC_ARRAY_ID, SMC_NAME, *r[18:49]), smc_x))
            fs = (fs + 1) & 0xFF
            ls = (ls + 1) & 0xFF
            write_many(t_us, packets)
        self._sim_seq, self._fc_seq, self._log_seq = s, fs, ls

    def _write_tick(self, t_us: int, w: Sequence[float], m: Sequence[float], armed: bool, data: list[float],
                    imu: Sequence[float] | None = None, truth: Sequence[float] | None = None) -> None:  # fmt: skip
        enc = self._packets
        t_ms = (t_us // 1000) & 0xFFFFFFFF
        s = self._sim_seq
        att = enc.attitude(s, t_ms, w[0], w[1], w[2], w[3], w[4], w[5])
        act = enc.actuators(self._fc_seq, t_us, m, _ARMED if armed else 0)
        smc = enc.smc(self._log_seq, t_us, data)
        self._fc_seq = (self._fc_seq + 1) & 0xFF
        self._log_seq = (self._log_seq + 1) & 0xFF
        if truth is None or imu is None:
            self.tlog.write_many(t_us, (att, enc.local_position_ned((s + 1) & 0xFF, t_ms, w[6], w[7], w[8], w[9], w[10], w[11]), act, smc))
            self._sim_seq = (s + 2) & 0xFF
            return
        # the simulator sends ATTITUDE, HIGHRES_IMU, ODOMETRY, LOCAL_POSITION_NED; the FC logs the state pair first
        self._sim_seq = (s + 4) & 0xFF
        lpn = enc.local_position_ned((s + 3) & 0xFF, t_ms, w[6], w[7], w[8], w[9], w[10], w[11])
        # the truth NED/FRD as smcpilot.frames' nwu_to_ned, rates_flu_to_frd and quat_nwu_flu_to_ned_frd give it
        x, y, z, vx, vy, vz, qw, qx, qy, qz, p, q, r = truth
        fx, fy, fz = imu
        try:
            sensed = enc.highres_imu((s + 1) & 0xFF, t_us, fx if fx == fx else _NAN, fy if fy == fy else _NAN, fz if fz == fz else _NAN,
                                     w[3], w[4], w[5])  # fmt: skip
            odo = enc.odometry((s + 2) & 0xFF, t_us, x, -y, -z, qw, qx, -qy, -qz, vx, -vy, -vz, p, -q, -r)
        except (OverflowError, struct.error):  # beyond float32 (a vehicle about to diverge): not logged
            self.tlog.write_many(t_us, (att, lpn, act, smc))
            return
        self.tlog.write_many(t_us, (att, lpn, sensed, odo, act, smc))

    def close(self) -> None:
        self.tlog.close()


def fly_in_process(scenario: Scenario, tlog_path: Path, *, echo=None) -> FlightResult:
    """Fly ``scenario`` on the flight core in this process, logging to ``tlog_path``."""
    config, options = settings_for(scenario)
    home = Home(*scenario.home) if scenario.home is not None else Home()
    events: list[tuple[float, str]] = []

    def event(severity: int, text: str) -> None:  # stamped with the tick that raised it
        t_s = core.t_us * 1e-6
        events.append((t_s, text))
        recorder.event(severity, text)
        if echo is not None:
            echo(f"[{t_s:7.2f} s] {text}")

    def fault_event(ev: FaultEvent) -> None:  # the simulator's announcement
        events.append((ev.t_s, ev.text))
        recorder.sim_event(ev)
        if echo is not None:
            echo(f"[{ev.t_s:7.2f} s] {ev.text}")

    core = FlightCore(config, scenario.vehicle, home=home, plan=scenario.plan, event=event, estimator=options.estimator)
    plant = plant_for(scenario)
    tlog_path.parent.mkdir(parents=True, exist_ok=True)
    recorder = _TlogRecorder(tlog_path, core, options=options, plant=plant)
    status, message = "ok", ""
    t0 = time.perf_counter()
    ticks = 0
    try:
        ticks = simulate(core, plant, scenario.n_ticks, rate_hz=scenario.rate_hz, physics_hz=scenario.physics_hz,
                         log=recorder, on_fault_event=fault_event)  # fmt: skip
    except DivergenceError as exc:
        status, message = "diverged", f"the simulation diverged at t = {exc.time_s:.3f} s: {exc}"
        ticks = core.ticks
        # The log says so, for its summary and metrics (a crash) as for this result.
        recorder.event(mavlink.MAV_SEVERITY_CRITICAL, _diverged_text(exc.time_s))
    finally:
        wall = time.perf_counter() - t0
        recorder.close()
    if status == "ok" and core.law_fault is not None:
        status, message = "error", f"the control law failed in flight (the failsafe flew on): {core.law_fault}"
    sim_s = (ticks - 1) / scenario.rate_hz if ticks else 0.0
    return FlightResult(scenario, "in-process", tlog_path, ticks, sim_s, wall, status, message, events)


def _diverged_text(t_s: float) -> str:
    """The STATUSTEXT that marks a divergence in a log (<= 50 characters; see
    :func:`ground.logs.metrics.divergence_from_events`)."""
    return f"Simulation diverged at t = {t_s:.3f} s"


def _note_divergence_in_tlog(path: Path, sysid: int = 1) -> None:
    """Append the divergence STATUSTEXT to a SITL flight's ``.tlog``, stamped with its last record:
    the simulator process stops without a word on the sim link, so the FC's log cannot say so."""
    from ground.logs import load_log

    log = load_log(path)
    if log.t0_us is None:
        return
    t_us = log.t0_us + round(log.log_span_s * 1e6)
    t_s = float(log.att_t_s[-1]) if log.att_t_s.size else log.log_span_s
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=SIM_COMPONENT_ID)
    packet = telemetry.statustext(mav, mavlink.MAV_SEVERITY_CRITICAL, _diverged_text(t_s)).pack(mav)
    with path.open("ab") as f:
        f.write(struct.pack(">Q", t_us) + packet)


# -- SITL ----------------------------------------------------------------------------------------
def fly_sitl(scenario: Scenario, tlog_path: Path, *, echo=None) -> FlightResult:
    """Fly ``scenario`` as the two SITL processes in lockstep on free ports (no ground link)."""
    from ground.sitl import Sitl, SitlError, SitlOptions

    param_file = tlog_path.with_name(tlog_path.stem + ".parm")
    param_file.unlink(missing_ok=True)  # a fresh parameter file: nothing carried over from an earlier run
    opts = SitlOptions(scenario=scenario, timed=True, lockstep=True, gcs=None, log_dir=tlog_path.parent,
                       tlog=tlog_path, param_file=param_file)  # fmt: skip
    t0 = time.perf_counter()
    status, message = "ok", ""
    sitl = Sitl(opts, echo=echo)
    try:
        with sitl:
            rc = sitl.wait()
        if rc != 0:
            status, message = "error", f"SITL ended with exit code {rc}"
    except SitlError as exc:
        diverged = sitl.sim is not None and sitl.sim.proc.returncode == EXIT_DIVERGED
        status, message = ("diverged" if diverged else "error"), str(exc)
    wall = time.perf_counter() - t0
    param_file.unlink(missing_ok=True)
    fcs = sitl.fc_summary or {}
    return FlightResult(scenario, "sitl", tlog_path, int(fcs.get("ticks", 0)), float(fcs.get("sim_time_s") or 0.0), wall, status, message)


def fly(scenario: Scenario, out_dir: Path, *, sitl: bool = False, echo=None) -> FlightResult:
    """Fly ``scenario`` one way or the other; write its log and scenario file into ``out_dir``,
    and summarise the log."""
    from ground.logs import load_log, summarize

    config_for(scenario)  # unknown or out-of-range FC parameters: a clear error before anything flies
    out_dir.mkdir(parents=True, exist_ok=True)
    tlog = out_dir / f"{scenario.name}.tlog"
    scenario.save(out_dir / f"{scenario.name}.scenario.toml")
    result = (fly_sitl if sitl else fly_in_process)(scenario, tlog, echo=echo)
    if tlog.exists() and tlog.stat().st_size > 0:
        if sitl and result.status == "diverged":
            _note_divergence_in_tlog(tlog)
        log = load_log(tlog)
        result.summary = summarize(log)
        if not result.events:
            result.events = [(e.t_s, e.text) for e in log.events]
    return result


# -- the output directory: one run's files at a time ------------------------------------------------
#: the list of the files the last run wrote into its output directory (relative paths, one a line).
RUN_FILES = ".smcpilot-run"


def clear_previous_run(out_dir: Path) -> list[Path]:
    """Delete the files the previous run listed in ``out_dir`` (never anything it did not write,
    never outside ``out_dir``) and the list itself; return what was deleted."""
    listing = out_dir / RUN_FILES
    try:
        names = listing.read_text(encoding="utf-8").splitlines()
    except (FileNotFoundError, NotADirectoryError):
        return []
    except OSError as exc:
        raise SmcpilotError(f"cannot read {listing}: {exc.strerror}") from None
    root = out_dir.resolve()
    removed = []
    for name in filter(None, (n.strip() for n in names)):
        path = (out_dir / name).resolve()
        if path.parent != root and root not in path.parents:
            continue  # the list was edited by hand: never outside the directory
        if path.is_file():
            path.unlink()
            removed.append(out_dir / name)
    listing.unlink(missing_ok=True)
    return removed


def record_run(out_dir: Path, paths: list[Path]) -> Path:
    """Write ``out_dir``'s :data:`RUN_FILES`: those of ``paths`` that lie inside it."""
    root = out_dir.resolve()
    names = []
    for p in paths:
        rp = p.resolve()
        if root in rp.parents:
            names.append(rp.relative_to(root).as_posix())
    listing = out_dir / RUN_FILES
    listing.write_text("".join(f"{n}\n" for n in dict.fromkeys(names)), encoding="utf-8")
    return listing


# -- command line --------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, metavar="SCENARIO.toml", help="the scenario file (see examples/scenarios/)")
    p.add_argument("--sitl", action="store_true",
                   help="fly the real two processes over MAVLink/UDP in lockstep (default: in-process, the same core, no UDP)")
    p.add_argument("--out", type=Path, metavar="DIR", help="where the .tlog, the effective scenario and the plots go"
                   " (default out/run/<scenario name>)")  # fmt: skip
    p.add_argument("--json", type=Path, metavar="PATH", help="write the results as JSON")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--controller", "--law", dest="controller", type=law_argument, metavar="LAW",
                   help="fly this control law instead of the scenario's: a built-in, an installed plug-in, path/to/file.py:NAME"
                   " or package.module:NAME (`smcpilot laws` lists them)")
    p.add_argument("--seed", type=int, metavar="N", help="use this seed instead of the scenario's")
    p.add_argument("--duration", type=float, metavar="SIM_S", help="fly this many simulated seconds instead")
    p.add_argument("--quiet", action="store_true", help="print only the summary")


def main(args: argparse.Namespace) -> int:
    from ground.logs import load_log, plot_log, print_summary

    scenario = Scenario.from_toml(args.scenario)
    changes: dict[str, Any] = {}
    if args.controller is not None:
        changes["controller"] = args.controller
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.duration is not None:
        changes["duration_s"] = args.duration
    if changes:
        scenario = scenario.with_changes(**changes)
    try:
        config_for(scenario)
    except ScenarioError as exc:
        raise ScenarioError(f"{args.scenario}: {exc}") from None
    out_dir = args.out if args.out is not None else Path("out") / "run" / scenario.name
    mode = "sitl" if args.sitl else "in-process"
    echo = None if args.quiet else (lambda line: print(line, flush=True))
    if not args.quiet:
        print(f"run: {scenario.name} ({mode}): {scenario.duration_s:g} s, {scenario.controller}, plant {scenario.plant},"
              f" seed {scenario.seed}" + (f" — {scenario.description}" if scenario.description else ""), flush=True)  # fmt: skip
    if out_dir.exists() and not out_dir.is_dir():
        raise SmcpilotError(f"--out {out_dir}: not a directory")
    cleared = clear_previous_run(out_dir)
    if cleared and not args.quiet:
        print(f"out: {out_dir}/: deleted the previous run's {len(cleared)} files (a run owns its output directory)", flush=True)
    if scenario.swarm is not None:
        return _main_swarm(args, scenario, out_dir, echo)
    written = [out_dir / f"{scenario.name}.tlog", out_dir / f"{scenario.name}.scenario.toml"]
    out_dir.mkdir(parents=True, exist_ok=True)
    record_run(out_dir, written)  # claimed before the flight: a run stopped half-way is cleared by the next too
    result = fly(scenario, out_dir, sitl=args.sitl, echo=echo)
    if result.summary:
        print()
        print_summary(result.summary, sys.stdout)
    speed = f"{result.sim_s / result.wall_s:.1f}× real time" if result.wall_s > 0 and result.ticks else "—× real time"
    print(f"\nrun: {result.status}{': ' + result.message if result.message else ''};"
          f" {result.ticks} ticks, {result.sim_s:.2f} simulated s in {result.wall_s:.2f} wall s ({speed})")  # fmt: skip
    doc = result.as_json()
    if not args.no_plots and result.summary:
        paths = plot_log(load_log(result.tlog), out_dir)
        written += paths
        doc["plots"] = [str(p) for p in paths]
        print(f"plots: {len(paths)} PNG files in {out_dir}/")
    print(f"log: {result.tlog}")
    _write_results(args.json, doc, out_dir, written)
    return 0 if result.status == "ok" else 1


def _main_swarm(args: argparse.Namespace, scenario: Scenario, out_dir: Path, echo: Any) -> int:
    """``smcpilot run`` of a swarm scenario: every vehicle's log, summary line and figures (in
    ``DIR/vN/``), the separation, and the results JSON (:mod:`lab.swarm_run`)."""
    from ground.logs import load_log, plot_log
    from lab.swarm_run import fly_swarm, print_swarm, vehicle_tlog

    fleet = scenario.fleet()
    tlog = out_dir / f"{scenario.name}.tlog"
    written = [out_dir / f"{scenario.name}.scenario.toml", *(vehicle_tlog(tlog, v.sysid) for v in fleet)]
    written += [vehicle_tlog(tlog, v.sysid).with_name(vehicle_tlog(tlog, v.sysid).stem + ".scenario.toml") for v in fleet]
    written += [vehicle_tlog(tlog, v.sysid).with_suffix(".parm") for v in fleet]
    out_dir.mkdir(parents=True, exist_ok=True)
    record_run(out_dir, written)
    result = fly_swarm(scenario, out_dir, sitl=args.sitl, echo=echo)
    ticks = result.vehicles[0].ticks if result.vehicles else 0
    sim_s = result.vehicles[0].sim_s if result.vehicles else 0.0
    print(f"\nrun: {result.status}; {len(fleet)} vehicles, {ticks} ticks each, {sim_s:.2f} simulated s in {result.wall_s:.2f} wall s"
          f" ({len(fleet) * sim_s / result.wall_s if result.wall_s > 0 else 0.0:.1f} vehicle-s per wall s)")  # fmt: skip
    print_swarm(result, sys.stdout)
    doc = result.as_json()
    if not args.no_plots:
        n = 0
        for sid, r in zip(result.sysids, result.vehicles):
            if r.summary:
                paths = plot_log(load_log(r.tlog), out_dir / f"v{sid}")
                written += paths
                doc["vehicles"][result.sysids.index(sid)]["plots"] = [str(p) for p in paths]
                n += len(paths)
        print(f"plots: {n} PNG files in {out_dir}/vN/")
    _write_results(args.json, doc, out_dir, written)
    return 0 if result.status == "ok" else 1


def _write_results(json_path: Path | None, doc: dict[str, Any], out_dir: Path, written: list[Path]) -> None:
    """The results JSON (if asked), then the run's list of the files it wrote."""
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(_finite(doc), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        written.append(json_path)
        print(f"results: {json_path}")
    record_run(out_dir, written)


def _finite(v: Any) -> Any:
    """JSON has no NaN: non-finite floats become null."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


__all__ = ["FlightResult", "MODES", "RUN_FILES", "SmcpilotError", "clear_previous_run", "fly", "fly_in_process", "fly_sitl", "record_run"]
