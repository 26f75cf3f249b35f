"""Command line of the flight-controller process (``python -m fc``)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

from fc.app import EXIT_CONFIG, FlightControllerApp, install_signal_handlers
from fc.config import FcConfig
from fc.control import registry
from fc.control.purity import law_problems
from fc.params import ParamStore, apply_scenario
from fc.sim_px4 import PX4_FRAMES, PX4_MOTOR_MODELS, Px4FlightControllerApp, Px4Output, is_px4_url, parse_px4_url
from smcpilot.errors import SmcpilotError
from smcpilot.geo import Home
from smcpilot.impair import parse_impairment
from smcpilot.lawref import law_argument
from smcpilot.plan import load_plan
from smcpilot.protocol import DEFAULT_GCS_URL, FC_CONTROLLERS, FC_GROUND_PORT
from smcpilot.scenario import Scenario
from smcpilot.signing import Signing, TimestampStore, load_key
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams


def build_parser() -> argparse.ArgumentParser:
    d = FcConfig()
    p = argparse.ArgumentParser(
        prog="python -m fc",
        description="Flight-controller process: runs the adaptive PID-SMC at a fixed rate on MAVLink state from"
        " the simulator bridge, sends HIL_ACTUATOR_CONTROLS back, and serves ground stations.",
    )
    p.add_argument("--sim", default="udpin:127.0.0.1:14560", metavar="URL",
                   help="simulator link: our simulator over UDP (default udpin:127.0.0.1:14560; udpin:HOST:0 picks a free"
                   " port), or px4[:tcp:HOST[:PORT]]: PX4's simulator API (Gazebo, jMAVSim, AirSim, rotorpy, smcpilot sim"
                   " --serve px4), connecting to HOST:PORT (default 127.0.0.1:4560) as PX4 does; always lockstep")
    p.add_argument("--px4-frame", choices=PX4_FRAMES, default="quad-x",
                   help="with --sim px4: the motor order of HIL_ACTUATOR_CONTROLS: quad-x (PX4's quadrotor X, default) or"
                   " plus (our rotors 1..4, as smcpilot sim --serve px4 reads them)")
    p.add_argument("--px4-motor", choices=PX4_MOTOR_MODELS, default="speed",
                   help="with --sim px4: what a control in [0, 1] sets: the rotor speed, omega = c * rotor_speed_max (speed,"
                   " default: Gazebo, rotorpy) or the thrust above idle (thrust: our plant)")
    p.add_argument("--gcs", default=DEFAULT_GCS_URL, metavar="URL",
                   help="ground link: udp:HOST:PORT sends telemetry there and answers whoever writes to our"
                   " port; udpin:HOST:PORT listens there (default udp:127.0.0.1:14550; 'none' for no ground link)")
    p.add_argument("--gcs-port", type=int, default=None, metavar="PORT",
                   help=f"with a udp:HOST:PORT ground link, send from this port of ours, so that other ground stations"
                   f" can write to it (default {FC_GROUND_PORT} with the default --gcs, else any free port; 0: any free port)")
    p.add_argument("--controller", "--law", dest="controller", type=law_argument, default=None, metavar="LAW",
                   help=f"control law: a built-in ({', '.join(FC_CONTROLLERS)}), an installed plug-in, path/to/file.py:NAME"
                   f" or package.module:NAME (default {d.controller}, or FC_CONTROLLER from the parameter file)")
    p.add_argument("--rate-hz", type=float, default=None, metavar="HZ",
                   help=f"control rate (default {d.rate_hz:g}, or FC_RATE_HZ from the parameter file)")
    p.add_argument("--lockstep", action="store_true", help="one tick per simulator state message (simulated time)")
    p.add_argument("--vehicle", type=Path, metavar="FILE", help="vehicle TOML (default: the spec's parameters)")
    p.add_argument("--plan", type=Path, metavar="FILE", help="timed set-point plan (TOML) executed in simulated time")
    p.add_argument("--duration", type=float, metavar="SIM_S", help="stop after this many simulated seconds")
    p.add_argument("--log-dir", type=Path, default=Path("logs"), metavar="DIR", help="where the .tlog goes (default logs/)")
    p.add_argument("--tlog", type=Path, metavar="PATH", help="exact .tlog path (overrides --log-dir)")
    p.add_argument("--telemetry-rate-hz", type=float, default=None, metavar="HZ",
                   help=f"ground telemetry rate incl. CHI_*/SIG_* (default {d.telemetry_rate_hz:g}, or TELEM_RATE_HZ)")
    p.add_argument("--watchdog-s", type=float, default=None, metavar="S",
                   help=f"exit if the simulator is silent this long, wall seconds (default {d.watchdog_s:g}, or FS_WATCHDOG)")
    p.add_argument("--jit", choices=("auto", "wait", "off"), default="auto",
                   help="the pipeline compiled with numba (the same commands bit for bit): auto (when cached, in real time and"
                        " in lockstep flights of 60 s or more or open-ended; not cached: CPython, compiling it in the background"
                        " for the next runs), wait (always; compile it first if need be: 10-30 s once), off (CPython);"
                        " SMCPILOT_JIT=0 also turns it off (default auto). In lockstep, each plain tick then flies in one"
                        " compiled call (SMCPILOT_LOCKSTEP_KERNEL=0 turns that alone off)")  # fmt: skip
    p.add_argument("--spin-s", type=float, default=0.002, metavar="S",
                   help="lockstep: busy-poll this long for the next state before blocking (default 0.002; 0: always"
                   " block, best when more processes than cores share the machine, as in a swarm)")  # fmt: skip
    p.add_argument("--tick-phase", type=float, default=None, metavar="F",
                   help="real time: tick F of a period later (0 <= F < 1) than the beat of one period from the first"
                   " state: a swarm's launcher spreads its FCs' ticks over the period (the i-th of K: i/K) so that they"
                   " do not all wake at once (default 0; in a group of FCs, each one's place among them)")  # fmt: skip
    p.add_argument("--startup-timeout-s", type=float, default=30.0, metavar="S",
                   help="exit if no simulator state arrives within this many wall seconds (default 30)")
    p.add_argument("--param-file", type=Path, metavar="PATH",
                   help="a parameter file to keep across runs (NAME VALUE lines): loaded at start if it exists,"
                   " rewritten atomically after every PARAM_SET. Default: none is loaded; the run starts from the"
                   " defaults and writes its parameters to a file of its own beside the tlog (NAME.parm)")
    p.add_argument("--home", default=None, metavar="LAT,LON,ALT",
                   help="home position for global coordinates (default -35.363261,149.165230,584: ArduPilot's SITL field)")
    p.add_argument("--scenario", type=Path, metavar="FILE",
                   help="scenario TOML (smcpilot.scenario): vehicle, controller, rate, home, parameters, plan and"
                   " duration come from it; the explicit flags above still win")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="set a parameter for this run, over the parameter file and the scenario (repeatable)")
    p.add_argument("--sim-link", metavar="SPEC",
                   help="impair the simulator link, both directions (smcpilot.impair), e.g. loss=0.2,delay_ms=4 (default: the scenario's)")
    p.add_argument("--gcs-link", metavar="SPEC", help="impair the ground link, both directions, e.g. loss=0.3 (default: the scenario's)")
    p.add_argument("--sysid", type=int, default=None, metavar="N",
                   help=f"MAVLink system id (default {d.system_id}, or SYSID_THISMAV from the parameter file)")
    p.add_argument("--signing-key", type=Path, metavar="FILE",
                   help="sign the ground link (MAVLink 2 signing): FILE holds 64 hex digits (the key) or a passphrase"
                   " (key = its SHA-256, as MAVProxy's 'signing setup'); unsigned packets other than HEARTBEAT and"
                   " RADIO_STATUS are then dropped and counted (docs/security.md)")
    p.add_argument("--signing-timestamps", type=Path, metavar="PATH",
                   help="where the signing timestamp is kept across restarts (default: signing-timestamp in --log-dir)")
    p.add_argument("--gcs-trusted", action="store_true",
                   help="declare the ground link trusted: it accepts SETUP_SIGNING unsigned even while a key is set")
    return p


def param_file_line(path: Path, *, kept: bool, loaded: bool, from_file: int, differences: list[tuple[str, float, float]]) -> str:
    """The line every run prints about its parameters: which file it loaded (or none), where it
    writes them, and how many values differ from the defaults (the first few named)."""
    if loaded:
        head = f"fc: parameters: loaded {path} ({from_file} differ from defaults); changes are saved to it"
    elif kept:
        head = f"fc: parameters: {path} does not exist yet: defaults, changes are saved to it"
    else:
        head = f"fc: parameters: defaults, no file loaded (--param-file FILE keeps one across runs); this run's file: {path}"
    n = len(differences)
    shown = ", ".join(f"{name}={value:g}" for name, value, _ in differences[:6]) + (", ..." if n > 6 else "")
    return head + f"; {n} value{'s' if n != 1 else ''} differ{'s' if n == 1 else ''} from defaults" + (f": {shown}" if n else "")


def main(argv: Sequence[str] | None = None) -> int:
    app = build_app(argv)
    if isinstance(app, int):
        return app
    install_signal_handlers(app)
    return app.run()


def build_app(argv: Sequence[str] | None = None, *, out: TextIO | None = None) -> FlightControllerApp | int:
    """The flight controller ``python -m fc ARGV`` flies, built and ready to :meth:`~FlightControllerApp.run`
    (its parameter writer started), or the exit code when it cannot be built (the error said in one
    line). ``out``: where the app's own lines go (default stdout)."""
    args = build_parser().parse_args(argv)
    try:
        tlog = args.tlog
        if tlog is None:
            tlog = args.log_dir / time.strftime("fc-%Y%m%d-%H%M%S.tlog")
        # The parameter-file rule: no hidden state between runs. A file is loaded only when
        # --param-file names it; otherwise the run has a file of its own beside its tlog.
        kept = args.param_file is not None
        param_file = args.param_file if kept else tlog.with_name(tlog.stem + ".parm")
        scenario = Scenario.from_toml(args.scenario) if args.scenario is not None else None
        for ref in (args.controller, scenario.controller if scenario is not None else None):
            if ref is not None:
                registry.resolve(ref)  # a plug-in's parameters join the table before any is read or set
        params = ParamStore(FcConfig(), param_file)
        for leftover in params.clean_leftovers():
            print(f"fc: removed {leftover.name} (an interrupted write of {param_file.name})", file=sys.stderr)
        loaded = kept and param_file.exists()
        if loaded:
            for warning in params.load():
                print(f"fc: warning: {warning}", file=sys.stderr)
        from_file = len(params.differences())
        if scenario is not None:
            apply_scenario(params, scenario)
        # What the command line says explicitly wins over the parameter file, for this run.
        explicit = {
            name: value
            for name, value in (
                ("rate_hz", args.rate_hz),
                ("controller", args.controller),
                ("telemetry_rate_hz", args.telemetry_rate_hz),
                ("watchdog_s", args.watchdog_s),
                ("system_id", args.sysid),
            )
            if value is not None
        }
        if explicit:
            params.config = replace(params.config, **explicit)
            params.pending = replace(params.pending, **explicit)
        for item in args.param:
            name, sep, text = item.partition("=")
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not sep or not name.strip() or not math.isfinite(value):
                raise SmcpilotError(f"--param expects NAME=VALUE with a finite number, got {item!r}")
            params.set(name.strip(), value, persist=False)
        params.config = params.pending  # start-up: restart parameters apply now
        if args.home:
            home = Home.parse(args.home)
        elif scenario is not None and scenario.home is not None:
            home = Home(*scenario.home)
        else:
            home = Home()
        if args.vehicle:
            vehicle = VehicleParams.from_toml(args.vehicle)
        else:
            vehicle = scenario.vehicle if scenario is not None else DEFAULT_VEHICLE
        if args.plan:
            plan = load_plan(args.plan)
        else:
            plan = scenario.plan if scenario is not None else ()
        if args.tick_phase is not None and not (math.isfinite(args.tick_phase) and 0.0 <= args.tick_phase < 1.0):
            raise SmcpilotError(f"--tick-phase must be a fraction of the period in [0, 1), got {args.tick_phase}")
        if not (math.isfinite(args.spin_s) and 0.0 <= args.spin_s <= 1.0):
            raise SmcpilotError(f"--spin-s must be a number of seconds in [0, 1], got {args.spin_s}")
        if args.duration is not None and not args.duration > 0:
            raise SmcpilotError(f"--duration must be > 0 simulated seconds, got {args.duration}")
        gcs_port = args.gcs_port if args.gcs_port is not None else (FC_GROUND_PORT if args.gcs == DEFAULT_GCS_URL else 0)
        if not 0 <= gcs_port <= 65535:
            raise SmcpilotError(f"--gcs-port must be a UDP port 0..65535, got {gcs_port}")
        tlog.parent.mkdir(parents=True, exist_ok=True)
        signing_store = TimestampStore(
            args.signing_timestamps if args.signing_timestamps is not None else tlog.parent / "signing-timestamp"
        )
        signing = Signing(load_key(args.signing_key) if args.signing_key is not None else None, store=signing_store)
        px4 = is_px4_url(args.sim)
        app_class: type[FlightControllerApp] = FlightControllerApp
        extra: dict[str, Any] = {}
        if px4:
            parse_px4_url(args.sim)  # a bad URL: one line, exit 2
            app_class = Px4FlightControllerApp
            extra["px4_output"] = Px4Output(args.px4_frame, args.px4_motor)
        app = app_class(
            params.config,
            vehicle,
            sim_url=args.sim,
            gcs_url=None if args.gcs == "none" else args.gcs,
            lockstep=args.lockstep,
            tlog_path=tlog,
            plan=plan,
            params=params,
            home=home,
            duration_s=args.duration,
            startup_timeout_s=args.startup_timeout_s,
            spin_s=args.spin_s,
            tick_phase=args.tick_phase,
            jit=args.jit,
            sim_system_id=args.sysid if args.sysid is not None else 1,
            gcs_port=gcs_port,
            signing=signing,
            gcs_trusted=args.gcs_trusted,
            sim_impairment=parse_impairment(args.sim_link, "--sim-link") if args.sim_link is not None
            else (scenario.sim_link if scenario is not None else None),
            gcs_impairment=parse_impairment(args.gcs_link, "--gcs-link") if args.gcs_link is not None
            else (scenario.gcs_link if scenario is not None else None),
            impair_seed=scenario.seed if scenario is not None else 0,
            out=out if out is not None else sys.stdout,
            **extra,
        )
        if not kept:
            params.save()  # the run's own file says from the start what flew
    except (SmcpilotError, OSError) as exc:
        print(f"fc: error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    print(param_file_line(param_file, kept=kept, loaded=loaded, from_file=from_file, differences=params.differences()),
          flush=True)  # fmt: skip
    style = law_problems(registry.resolve(params.config.controller))
    if style:  # said once: it flies, but no compiler will take it (docs/your-own-law.md §1)
        print(f"fc: law {params.config.controller} is not in the pure style ({style[0]}): it flies in CPython only", flush=True)
    params.start_writer()
    return app
