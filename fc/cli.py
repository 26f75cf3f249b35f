"""Command line of the flight-controller process (``python -m fc``)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from fc.app import EXIT_CONFIG, FlightControllerApp, install_signal_handlers
from fc.config import FcConfig
from fc.params import ParamStore, apply_scenario
from smcpilot.errors import SmcpilotError
from smcpilot.geo import Home
from smcpilot.impair import parse_impairment
from smcpilot.plan import load_plan
from smcpilot.protocol import FC_CONTROLLERS
from smcpilot.scenario import Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams


def build_parser() -> argparse.ArgumentParser:
    d = FcConfig()
    p = argparse.ArgumentParser(
        prog="python -m fc",
        description="Flight-controller process: runs the adaptive PID-SMC at a fixed rate on MAVLink state from"
        " the simulator bridge, sends HIL_ACTUATOR_CONTROLS back, and serves ground stations.",
    )
    p.add_argument("--sim", default="udpin:127.0.0.1:14560", metavar="URL",
                   help="simulator link (default udpin:127.0.0.1:14560; udpin:HOST:0 picks a free port)")
    p.add_argument("--gcs", default="udp:127.0.0.1:14550", metavar="URL",
                   help="ground link: udp:HOST:PORT sends telemetry there and answers whoever writes to our"
                   " port; udpin:HOST:PORT listens there (default udp:127.0.0.1:14550; 'none' for no ground link)")
    p.add_argument("--controller", choices=FC_CONTROLLERS, default=None,
                   help=f"control law (default {d.controller}, or FC_CONTROLLER from the parameter file)")
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
    p.add_argument("--startup-timeout-s", type=float, default=30.0, metavar="S",
                   help="exit if no simulator state arrives within this many wall seconds (default 30)")
    p.add_argument("--param-file", type=Path, metavar="PATH",
                   help="parameter file (NAME VALUE lines), loaded at start and rewritten atomically on every"
                   " PARAM_SET (default: fc-params.parm in --log-dir)")
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
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        param_file = args.param_file if args.param_file is not None else args.log_dir / "fc-params.parm"
        params = ParamStore(FcConfig(), param_file)
        for warning in params.load():
            print(f"fc: warning: {warning}", file=sys.stderr)
        scenario = Scenario.from_toml(args.scenario) if args.scenario is not None else None
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
        if args.duration is not None and not args.duration > 0:
            raise SmcpilotError(f"--duration must be > 0 simulated seconds, got {args.duration}")
        tlog = args.tlog
        if tlog is None:
            args.log_dir.mkdir(parents=True, exist_ok=True)
            tlog = args.log_dir / time.strftime("fc-%Y%m%d-%H%M%S.tlog")
        else:
            tlog.parent.mkdir(parents=True, exist_ok=True)
        app = FlightControllerApp(
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
            sim_system_id=args.sysid if args.sysid is not None else 1,
            sim_impairment=parse_impairment(args.sim_link, "--sim-link") if args.sim_link is not None
            else (scenario.sim_link if scenario is not None else None),
            gcs_impairment=parse_impairment(args.gcs_link, "--gcs-link") if args.gcs_link is not None
            else (scenario.gcs_link if scenario is not None else None),
            impair_seed=scenario.seed if scenario is not None else 0,
        )
    except (SmcpilotError, OSError) as exc:
        print(f"fc: error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    install_signal_handlers(app)
    return app.run()
