"""``smcpilot mission``: the command line of scripted missions (:func:`add_arguments`,
:func:`main`). Exit codes: 0 every expectation held, 1 one failed or the mission could not be
flown, 2 a broken file or bad usage."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path

from ground.missions.errors import MissionRunError
from ground.missions.runner import run_mission
from ground.missions.schema import load_mission
from ground.sitl import SitlError
from ground.vehicle import VehicleError
from smcpilot.errors import ConfigError, LinkError, TlogError

__all__ = ["EXIT_FAILED", "EXIT_PASSED", "EXIT_USAGE", "add_arguments", "main"]

EXIT_PASSED = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Subcommands of ``smcpilot mission``: ``run FILE [--connect URL] [--json PATH] [--out DIR]``."""
    sub = p.add_subparsers(dest="mission_command", metavar="SUBCOMMAND")
    sub.required = True
    r = sub.add_parser(
        "run",
        help="fly a scripted mission (TOML) and check its expectations",
        description="Fly FILE's [[item]] list as a real mission (upload, arm, MISSION_START) in lockstep SITL"
        " launched with its [sitl] settings, or on a running vehicle (--connect), then check its [[expect]]"
        " entries on the FC's log. Exit 0 when every expectation held, 1 when one failed or the flight"
        " could not be flown, 2 for a broken file or bad usage. The file format is in ground/missions/__init__.py.",
    )
    r.add_argument("file", type=Path, metavar="FILE", help="mission TOML file")
    r.add_argument("--connect", metavar="URL", default=None,
                   help="fly the already-running vehicle at URL (udpin:HOST:PORT or udpout:HOST:PORT) instead of launching"
                   " SITL; expectations then use the telemetry received")  # fmt: skip
    r.add_argument("--json", type=Path, metavar="PATH", default=None, help="also write the report as JSON")
    r.add_argument("--out", type=Path, metavar="DIR", default=None,
                   help="directory for the log and plots (default out/missions/<file stem>)")  # fmt: skip
    r.add_argument("--no-plots", action="store_true", help="skip the plots")
    r.set_defaults(mission_handler=_run_main)


def main(args: argparse.Namespace) -> int:
    """``smcpilot mission SUBCOMMAND``."""
    handler: Callable[[argparse.Namespace], int] = args.mission_handler
    return handler(args)


class _Terminated(Exception):
    pass


def _raise_terminated(*_: object) -> None:
    raise _Terminated()


def _run_main(args: argparse.Namespace) -> int:
    mission = load_mission(args.file)  # MissionFileError -> exit 2 (lab.cli)
    out = args.out if args.out is not None else Path("out") / "missions" / args.file.stem
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        report = run_mission(mission, args.connect, out_dir=out, json_path=args.json, plots=not args.no_plots)
    except (_Terminated, KeyboardInterrupt):
        print("smcpilot mission run: stopped", file=sys.stderr)
        return 130
    except ConfigError:
        raise  # usage/configuration: exit 2
    except (VehicleError, SitlError, MissionRunError, LinkError, TlogError) as exc:
        print(f"smcpilot mission run: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return EXIT_PASSED if report.passed else EXIT_FAILED
