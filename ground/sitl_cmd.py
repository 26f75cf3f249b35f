"""``smcpilot sitl`` and ``smcpilot demo``: launch the two SITL processes from the command line."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

from ground.logs.housekeeping import KEEP_PLAIN, compress_old_flights, format_bytes
from ground.logs.progress import ProgressLine
from ground.sitl import Sitl, SitlError, SitlOptions, print_connect_help
from smcpilot.errors import ConfigError, EndpointError
from smcpilot.lawref import law_argument
from smcpilot.link import parse_endpoint
from smcpilot.protocol import FC_CONTROLLERS
from smcpilot.scenario import Scenario
from smcpilot.signing import load_key
from smcpilot.swarm import MAX_VEHICLES, SwarmSpec, check_count


def _ned_triple(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N,E,D numbers, got {text!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"expected three finite numbers N,E,D, got {text!r}")
    return vals  # type: ignore[return-value]


def add_common(p: argparse.ArgumentParser, *, lockstep_flag: bool) -> None:
    if lockstep_flag:
        p.add_argument("--lockstep", action="store_true",
                       help="deterministic lockstep (as fast as possible unless --speed caps it); default: real time")  # fmt: skip
    p.add_argument("--speed", type=float, metavar="FACTOR",
                   help="lockstep: at most FACTOR x real time (a ground station needs 1); real time: clock speed")  # fmt: skip
    p.add_argument("--vehicle", type=Path, metavar="FILE", help="vehicle TOML (default: the spec's parameters)")
    p.add_argument("--controller", "--law", dest="controller", type=law_argument, default=None, metavar="LAW",
                   help=f"control law: a built-in ({', '.join(FC_CONTROLLERS)}), an installed plug-in, path/to/file.py:NAME or"
                   " package.module:NAME (default adaptive_pid_smc; `smcpilot laws` lists them)")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="seed of sensor noise and gusts (default 0)")
    p.add_argument("--log-dir", type=Path, default=Path("logs"), metavar="DIR", help="where the .tlog goes (default logs/)")
    p.add_argument("--plant", choices=("rigid-body", "paper"), default=None, help="simulated vehicle model (default rigid-body)")
    p.add_argument("--noise", action="store_true", default=None, help="sensor noise on the simulated state")
    p.add_argument("--wind-force", type=_ned_triple, metavar="N,E,D", help="constant wind force, newtons, NED")
    p.add_argument("--gust-std", type=float, default=None, metavar="N", help="horizontal gust force std, newtons (default 0)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="lockstep: a progress line on stderr (simulated time, speed, ETA); default: only on a terminal")  # fmt: skip


def add_sitl_arguments(p: argparse.ArgumentParser) -> None:
    add_common(p, lockstep_flag=True)
    p.add_argument("--sim", metavar="URL",
                   help="fly on another simulator instead of ours: px4[:tcp:HOST[:PORT]] (PX4's simulator API: Gazebo,"
                   " jMAVSim, AirSim, rotorpy; the FC connects as PX4 does, default 127.0.0.1:4560); lockstep on its clock;"
                   " docs/external-simulators.md")  # fmt: skip
    p.add_argument("--px4-frame", choices=("quad-x", "plus"), default=None,
                   help="with --sim px4: the motor order, quad-x (PX4's, default) or plus (ours)")
    p.add_argument("--px4-motor", choices=("speed", "thrust"), default=None,
                   help="with --sim px4: a control in [0, 1] sets the rotor speed (default) or the thrust above idle")
    p.add_argument("--duration", type=float, metavar="SIM_S", help="stop after this many simulated seconds (default: until Ctrl-C)")
    p.add_argument("--gcs", default="udp:127.0.0.1:14550", metavar="URL",
                   help="ground link of the FC: udp:HOST:PORT sends telemetry there (default udp:127.0.0.1:14550,"
                   " where QGroundControl and MAVProxy listen), udpin:HOST:PORT listens, none: no ground link")  # fmt: skip
    p.add_argument("--plan", type=Path, metavar="FILE", help="timed set-point plan (TOML) the FC flies in simulated time")
    p.add_argument("--param-file", type=Path, metavar="FILE",
                   help="a parameter file to keep across runs: loaded at start if it exists, saved to after every"
                   " PARAM_SET (default: none loaded; the run starts from the defaults and writes its own NAME.parm"
                   " beside its tlog)")  # fmt: skip
    p.add_argument("--signing-key", type=Path, metavar="FILE",
                   help="MAVLink 2 signing on the ground link: FILE holds 64 hex digits (the key) or a passphrase"
                   " (key = its SHA-256, as MAVProxy's 'signing setup'); see docs/security.md")  # fmt: skip
    p.add_argument("--paper-disturbance", action="store_true", default=None, help="add the paper's disturbances fs1..fs4")
    p.add_argument("--sim-link", metavar="SPEC",
                   help="impair the simulator <-> FC link, both directions, seeded: loss, delay_ms, jitter_ms, duplicate,"
                   " reorder, reorder_ms, dup_gap_ms, outage_at_s, outage_s, seed, e.g. loss=0.2,delay_ms=4 (docs/links.md)")
    p.add_argument("--gcs-link", metavar="SPEC", help="impair the FC's ground link the same way, e.g. loss=0.3")
    p.add_argument("--scenario", type=Path, metavar="FILE",
                   help="fly this scenario (TOML, see `smcpilot run`): its vehicle, environment, seed, controller,"
                   " parameters and plan (the flags above change it); runs until Ctrl-C unless --duration is given")  # fmt: skip
    p.add_argument("--count", type=int, metavar="K",
                   help=f"fly K vehicles (1..{MAX_VEHICLES}) in one simulator on one clock: one FC each, system ids"
                   " from --sysid, spawned on a grid, all on the one ground URL (a router sends each station's"
                   " packets to the vehicle they name); default: the scenario's [swarm] count, else 1")  # fmt: skip
    p.add_argument("--sysid", type=int, metavar="N",
                   help="system id of the (first) vehicle; the others count up from it (default 1)")
    p.add_argument("--fc-processes", type=int, metavar="N",
                   help="swarm: fly the K flight controllers in N processes, several in each (the same FCs; in lockstep"
                   " one loop and the same logs byte for byte; far fewer wake-ups on a machine of few cores: N = its cores"
                   " less one, or its cores, is fastest); default: one process per vehicle")  # fmt: skip


def layout_hint(count: int, fc_processes: int | None, cores: int, lockstep: bool) -> str | None:
    """One line for a swarm of ``count`` vehicles whose flight controllers would each take a process
    (``fc_processes`` None) on a machine of ``cores`` that cannot run them all at once: what
    ``--fc-processes`` would do instead. None when there is nothing to say."""
    if count <= 1 or fc_processes is not None or count + 1 <= cores:
        return None
    n = max(1, cores - 1)
    gain = ("16 vehicles on 2 cores flew 1.7-2.2x faster in lockstep that way" if lockstep
            else "16 vehicles on 2 cores missed 0.1-0.6 % of their deadlines in real time that way, against 14-16 %")  # fmt: skip
    return (f"sitl: {count} flight controllers, a process each, on {cores} cores; --fc-processes {n} flies them in"
            f" {'one loop' if n == 1 else f'{n} loops'} (measured: {gain}; docs/swarms.md)")  # fmt: skip


def _options(args: argparse.Namespace, **extra: Any) -> SitlOptions:
    if args.speed is not None and not (math.isfinite(args.speed) and args.speed > 0):
        raise ConfigError(f"--speed must be a finite number > 0, got {args.speed:g}")
    duration = getattr(args, "duration", None)
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be a finite number > 0 of simulated seconds, got {duration:g}"
                          " (leave it out to run until Ctrl-C)")  # fmt: skip
    if args.gust_std is not None and not (math.isfinite(args.gust_std) and args.gust_std >= 0):
        raise ConfigError(f"--gust-std must be a finite number >= 0, got {args.gust_std:g}")
    if args.vehicle is not None and not args.vehicle.is_file():
        raise ConfigError(f"vehicle file not found: {args.vehicle}")
    kw: dict[str, Any] = dict(speed=args.speed, log_dir=args.log_dir)
    scenario_file = getattr(args, "scenario", None)
    if scenario_file is not None:
        kw["scenario"] = Scenario.from_toml(scenario_file)
    # Only what the command line says changes the scenario (the defaults are the scenario's).
    for key, value in (("vehicle", args.vehicle), ("controller", args.controller), ("seed", args.seed), ("plant", args.plant),
                       ("noise", args.noise), ("wind_force_ned_n", args.wind_force), ("gust_std_n", args.gust_std)):  # fmt: skip
        if value is not None:
            kw[key] = value
    kw.update({k: v for k, v in extra.items() if v is not None or k in ("gcs",)})
    return SitlOptions.of(**kw)


class _Terminated(Exception):
    """SIGTERM arrived (exit 143, as the shell reports a process ended by it)."""


def _raise_terminated(*_: object) -> None:
    raise _Terminated()


#: exit code of the FC and the simulator for a configuration error (a bad URL, file or value).
_CHILD_EXIT_CONFIG = 2


def _startup_config_error(sitl: Sitl) -> str | None:
    """The one-line reason if a child ended during start-up with a configuration error, else None."""
    for child in (*sitl.fcs, sitl.sim, sitl.router):
        if child is not None and child.proc.poll() == _CHILD_EXIT_CONFIG:
            errors = [ln.split("error:", 1)[1].strip() for ln in child.tail if "error:" in ln]
            return errors[-1] if errors else f"{child.name} rejected its configuration"
    return None


def _launch_and_wait(
    opts: SitlOptions,
    command: str,
    started: Callable[[Sitl], None] | None = None,
    progress_total_s: float | None | bool = False,
) -> tuple[int | None, Sitl, float]:
    """Run SITL to its end; (exit code if it did not end normally, the launcher, wall seconds).

    Ctrl-C gives 130, SIGTERM 143 (both processes are stopped either way), a failed child 1, a
    child that rejected its configuration during start-up 2 (one line: its reason). Output of
    the children during start-up is held back until they are ready, so that a rejected
    configuration is reported once. ``progress_total_s`` other than False shows a progress line on
    stderr (simulated seconds of the whole run, or None if open-ended) while SITL runs.
    """
    old = signal.signal(signal.SIGTERM, _raise_terminated)
    t0 = time.monotonic()
    held: list[str] | None = []

    line: ProgressLine | None = None

    def echo(text: str) -> None:
        if held is not None:
            held.append(text)
        else:
            if line is not None:
                line.clear()
            print(text, flush=True)

    def release() -> None:
        nonlocal held
        lines, held = held or [], None
        for text in lines:
            print(text, flush=True)

    sitl = Sitl(opts, echo=echo)
    rc: int | None = None
    try:
        with sitl:
            release()
            if started is not None:
                started(sitl)
            if progress_total_s is not False and sitl.tlog is not None:
                line = ProgressLine(sitl.tlog, progress_total_s or None, sys.stderr).start()
            try:
                sitl.wait()
            finally:
                if line is not None:
                    line.stop()
    except KeyboardInterrupt:
        print(f"smcpilot {command}: stopped", file=sys.stderr)
        rc = 130
    except _Terminated:
        print(f"smcpilot {command}: terminated", file=sys.stderr)
        rc = 143
    except SitlError as exc:
        reason = _startup_config_error(sitl) if held is not None else None
        if reason is not None:
            print(f"smcpilot {command}: error: {reason}", file=sys.stderr)
            held = None  # the children's own report of it is that line
            rc = 2
        else:
            release()
            print(f"smcpilot {command}: error: {exc}", file=sys.stderr)
            rc = 1
    finally:
        signal.signal(signal.SIGTERM, old)
        if held is not None:
            release()
    return rc, sitl, time.monotonic() - t0


def _progress(args: argparse.Namespace, total_s: float | None) -> float | None | bool:
    """The ``progress_total_s`` of :func:`_launch_and_wait`: False unless asked or on a terminal."""
    wanted = args.progress if args.progress is not None else sys.stderr.isatty()
    return total_s if wanted else False


def _tidy_log_dir(log_dir: Path) -> None:
    """Compress the logs of older flights (all but the newest few stay readable by pymavlink)."""
    done = compress_old_flights(log_dir)
    if done:
        before, after = sum(r.bytes_before for r in done), sum(r.bytes_after for r in done)
        print(f"logs: compressed {len(done)} older flight log(s) in {log_dir}/ ({format_bytes(before)} -> {format_bytes(after)};"
              f" the newest {KEEP_PLAIN} stay plain; `smcpilot log clean` deletes old flights)")  # fmt: skip


def _with_count(opts: SitlOptions, count: int | None, sysid: int | None) -> SitlOptions:
    """``--count`` and ``--sysid`` over the scenario's [swarm] table (checked: one line, exit 2)."""
    if count is None and sysid is None:
        return opts
    sc = opts.scenario
    swarm = sc.swarm if sc.swarm is not None else SwarmSpec()
    changes: dict[str, Any] = {}
    if count is not None:
        check_count(count)
        changes["count"] = count
    if sysid is not None:
        if not 1 <= sysid <= 255:
            raise ConfigError(f"--sysid must be a system id in 1..255, got {sysid}")
        changes["sysid_base"] = sysid
    swarm = replace(swarm, **changes)
    if swarm.count == 1 and sc.swarm is None and sysid is None:
        return opts
    scenario = sc.with_changes(swarm=swarm)
    scenario.fleet()  # every vehicle's flight checked now, before anything starts
    return replace(opts, scenario=scenario)


def sitl_main(args: argparse.Namespace) -> int:
    if args.plan is not None and not args.plan.is_file():
        raise ConfigError(f"plan file not found: {args.plan}")
    if args.gcs != "none":
        try:
            parse_endpoint(args.gcs)
        except EndpointError as exc:
            raise ConfigError(f"--gcs: {exc}, or none") from None
    if args.signing_key is not None:
        load_key(args.signing_key)  # a bad key file: one line, exit 2, before anything starts
    opts = _options(
        args,
        lockstep=args.lockstep,
        duration_s=args.duration,
        gcs=None if args.gcs == "none" else args.gcs,
        plan=args.plan,
        paper_disturbance=args.paper_disturbance,
        param_file=args.param_file,
        signing_key=args.signing_key,
        sim_link=args.sim_link,
        gcs_link=args.gcs_link,
    )
    opts = _with_count(opts, args.count, args.sysid)
    if args.fc_processes is not None:
        if not 1 <= args.fc_processes <= MAX_VEHICLES:
            raise ConfigError(f"--fc-processes must be a whole number in 1..{MAX_VEHICLES}, got {args.fc_processes}")
        if opts.scenario.count == 1:
            raise ConfigError("--fc-processes groups the flight controllers of a swarm: give --count K > 1 (or a scenario's [swarm])")
        opts = replace(opts, fc_processes=args.fc_processes)
    if args.sim is not None:
        if not (args.sim == "px4" or args.sim.startswith("px4:")):
            raise ConfigError(f"--sim must be px4[:tcp:HOST[:PORT]] (PX4's simulator API), got {args.sim!r}")
        if opts.scenario.count > 1:
            raise ConfigError(f"--sim px4 flies one vehicle on the other simulator; a swarm ({opts.scenario.count} vehicles)"
                              " flies on ours: leave out --sim or --count")  # fmt: skip
        px4 = [*(("--px4-frame", args.px4_frame) if args.px4_frame else ()), *(("--px4-motor", args.px4_motor) if args.px4_motor else ())]
        opts = replace(opts, sim_url=args.sim, lockstep=True, fc_args=(*opts.fc_args, *px4))
    elif args.px4_frame or args.px4_motor:
        raise ConfigError("--px4-frame and --px4-motor go with --sim px4:...")

    hint = layout_hint(opts.scenario.count, opts.fc_processes, os.cpu_count() or 1, opts.lockstep)
    if hint is not None:
        print(hint, flush=True)

    def started(sitl: Sitl) -> None:
        print_connect_help(sitl)
        print("  stop with Ctrl-C" + (f"; runs {args.duration:g} simulated seconds" if args.duration else ""), flush=True)

    rc, sitl, wall = _launch_and_wait(opts, "sitl", started, _progress(args, args.duration) if args.lockstep else False)
    if rc is not None:
        return rc
    fcs = sitl.fc_summary or {}
    # The simulator's clock is the simulated time (the FC's runs from its own start in real time).
    sim_s = (sitl.sim_summary or {}).get("sim_time_s", fcs.get("sim_time_s"))
    if len(sitl.fcs) > 1:
        print(f"SITL ended: {'—' if sim_s is None else f'{sim_s:.2f}'} simulated s in {wall:.2f} wall s, {len(sitl.fcs)} vehicles")
        for sysid, summary, tlog in zip(sitl.sysids, sitl.fc_summaries, sitl.tlogs):
            s = summary or {}
            print(f"  vehicle {sysid}: {s.get('ticks', 0)} control ticks, {s.get('overruns', 0)} overruns; log {tlog};"
                  f" {rejected_line(s.get('rx_rejected') or {}).strip()}")  # fmt: skip
        print(proximity_line((sitl.sim_summary or {}).get("proximity")))
        _tidy_log_dir(args.log_dir)
        return 0
    print(
        f"SITL ended: {'—' if sim_s is None else f'{sim_s:.2f}'} simulated s in {wall:.2f} wall s,"
        f" {fcs.get('ticks', 0)} control ticks, {fcs.get('overruns', 0)} overruns; log {sitl.tlog}"
    )
    _tidy_log_dir(args.log_dir)
    print(rejected_line(fcs.get("rx_rejected") or {}))
    return 0


def proximity_line(prox: dict | None) -> str:
    """A swarm's closest approach, separation events and contacts (the simulator's summary), one line."""
    if not prox or prox.get("min_separation_m") is None:
        return "  separation: not measured"
    a, b = prox["min_pair"]
    line = (f"  separation: min {prox['min_separation_m']:.2f} m (vehicles {a} and {b} at t = {prox['min_at_s']:.2f} s);"
            f" {len(prox['events'])} closer than {prox['separation_m']:g} m")  # fmt: skip
    contacts = prox.get("contacts") or []
    if contacts:
        line += "; CONTACT: " + ", ".join(f"{c['vehicles'][0]}-{c['vehicles'][1]} at {c['t_s']:.2f} s" for c in contacts)
    return line


def rejected_line(rejected: dict[str, int]) -> str:
    """The FC's rejected packets by reason (its exit summary), one line."""
    total = rejected.get("total", 0)
    if not total:
        return "  rejected packets: none"
    parts = ", ".join(f"{k} {v}" for k, v in sorted(rejected.items(), key=lambda kv: -kv[1]) if k != "total")
    return f"  rejected packets: {total} ({parts})"


# -- demo ---------------------------------------------------------------------------------------
DEMO_DURATION_S = 55.0


def demo_plan_path() -> Path:
    return Path(str(resources.files("ground") / "data" / "demo-plan.toml"))


def add_demo_arguments(p: argparse.ArgumentParser) -> None:
    add_common(p, lockstep_flag=False)
    p.add_argument("--json", type=Path, metavar="PATH", help="write the demo's results as JSON")
    p.add_argument("--out", type=Path, default=Path("out/demo"), metavar="DIR", help="plot directory (default out/demo)")
    p.add_argument("--no-plots", action="store_true", help="skip the plots")


def demo_main(args: argparse.Namespace) -> int:
    from ground.logs import load_log, plot_log, print_summary, summarize

    plan = demo_plan_path()
    opts = _options(args, lockstep=True, duration_s=DEMO_DURATION_S, gcs=None, plan=plan)
    print(f"demo: lockstep SITL, {DEMO_DURATION_S:g} s of flight ({plan.name}): take-off to 3 m, set-points,"
          " a heading change across ±180°, landing", flush=True)  # fmt: skip
    rc, sitl, wall = _launch_and_wait(opts, "demo", progress_total_s=_progress(args, DEMO_DURATION_S))
    if rc is not None:
        return rc
    fcs = sitl.fc_summary or {}
    assert sitl.tlog is not None
    log = load_log(sitl.tlog)
    summary = summarize(log)
    result = demo_result(summary, fcs, wall, sitl.tlog)
    print()
    print_summary(summary, sys.stdout)
    print(
        f"\ndemo: {result['sim_seconds']:.1f} simulated s in {wall:.2f} wall s ({result['speed']:.1f}× real time),"
        f" final position error {_fmt(result['position_error_final_m'])} m, max tilt {_fmt(result['max_tilt_deg'])}°,"
        f" χ̂ = [{', '.join(_fmt(c) for c in result['chi_hat_final'] or [])}], {result['overruns']} overruns"
    )
    if not args.no_plots:
        paths = plot_log(log, args.out)
        print(f"plots: {len(paths)} PNG files in {args.out}/")
        result["plots"] = [str(p) for p in paths]
    print(f"log: {sitl.tlog}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n", encoding="utf-8")
        print(f"results: {args.json}")
    _tidy_log_dir(args.log_dir)
    return 0


def _fmt(v: Any) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def demo_result(summary: dict[str, Any], fc_summary: dict[str, Any], wall_s: float, tlog: Path) -> dict[str, Any]:
    sim_s = float(fc_summary.get("sim_time_s") or summary.get("duration_s") or 0.0)
    chi = summary.get("chi_hat_final")
    return {
        "sim_seconds": sim_s,
        "wall_seconds": wall_s,
        "speed": sim_s / wall_s if wall_s > 0 else None,
        "position_error_final_m": summary.get("position_error_final_m"),
        "max_tilt_deg": summary.get("max_tilt_deg"),
        "chi_hat_final": list(chi) if chi is not None else None,
        "overruns": int(fc_summary.get("overruns", 0)),
        "tlog": str(tlog),
        "events": summary.get("events"),
    }
