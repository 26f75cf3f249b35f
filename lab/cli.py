"""The ``smcpilot`` command line: one subcommand per job, each with a true ``--help``.

Errors the user can fix (a bad option, gain or file) print one line and exit 2; no traceback.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any, NoReturn, TextIO

from smcpilot import __version__
from smcpilot.errors import SmcpilotError

Handler = Callable[[argparse.Namespace], int]

#: the namespace attribute naming the (deepest) parser that found arguments it does not know.
_EXTRAS_OWNER = "_smcpilot_extras_owner"


class CliParser(argparse.ArgumentParser):
    """The parser of ``smcpilot`` and, through ``add_subparsers`` (which makes its subparsers of
    the parser's own class), of every subcommand at every depth.

    A usage error (a missing argument, a bad value or choice, an unknown option) is one line on
    stderr, ``smcpilot SUBCOMMAND: error: ...`` naming the subcommand whose parser found it and
    pointing at its ``--help``, and exit 2: argparse's default prints the usage block first, and
    reports an unknown option of a subcommand as the top level's.
    """

    def error(self, message: str) -> NoReturn:
        text = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {text} (see `{self.prog} --help`)\n")

    def parse_known_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:  # type: ignore[override]
        ns, extras = super().parse_known_args(args, namespace)
        if extras and not hasattr(ns, _EXTRAS_OWNER):
            setattr(ns, _EXTRAS_OWNER, self)  # the innermost parser returns first: the subcommand that was given them
        return ns, extras

    def parse_args(self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None) -> argparse.Namespace:  # type: ignore[override]
        ns, extras = self.parse_known_args(args, namespace)
        owner: Any = getattr(ns, _EXTRAS_OWNER, self)
        if hasattr(ns, _EXTRAS_OWNER):
            delattr(ns, _EXTRAS_OWNER)
        if extras:
            owner.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns


def _paper(sub: argparse._SubParsersAction) -> None:
    from lab.paper import report

    p = sub.add_parser(
        "paper",
        help="reproduce the paper's simulation for all four controllers (table, figures, metrics JSON)",
        description="Run the paper's scenario (spec §5: X(0) of eq. 45, targets π/3, π/6, π/2, 3 m, 15 s) for"
        " the known-bound PID-SMC, the adaptive PID-SMC, a sign-SMC and a cascaded PID, on the corrected"
        " eq. (10) plant with the paper's disturbances and ideal actuators.",
    )
    report.add_arguments(p)
    p.set_defaults(handler=report.main)


def _bench(sub: argparse._SubParsersAction) -> None:
    from lab import bench

    p = sub.add_parser("bench", help="measure speed (prints figures; never pass/fail)")
    bench.add_arguments(p)
    p.set_defaults(handler=bench.main)


def _sitl(sub: argparse._SubParsersAction) -> None:
    from ground import sitl_cmd

    p = sub.add_parser(
        "sitl",
        help="launch SITL: the flight controller and the simulator bridge, talking MAVLink over UDP",
        description="Start both processes on loopback (the FC on a free port), wait until the vehicle is ready,"
        " print where to connect, and stop both on Ctrl-C/SIGTERM (or when a child dies, with its last output).",
    )
    sitl_cmd.add_sitl_arguments(p)
    p.set_defaults(handler=sitl_cmd.sitl_main)


def _sim(sub: argparse._SubParsersAction) -> None:
    from sim_bridge import serve

    p = sub.add_parser(
        "sim",
        help="our simulator as the physics back-end of another autopilot: ArduPilot SITL (--model JSON) or PX4 SITL",
        description="Serve a scenario's plant, environment and faults to ArduPilot SITL over its JSON interface"
        " (--serve ardupilot-json, UDP 9002) or to PX4 SITL over its simulator MAVLink API (--serve px4, TCP 4560),"
        " in lockstep with the autopilot. Stops on Ctrl-C/SIGTERM with a summary (exit 0), at --duration, or when the"
        " autopilot stops answering (exit 3). Command lines, motor order and frame parameters: docs/external-simulators.md.",
    )
    serve.add_arguments(p)
    p.set_defaults(handler=serve.main)


def _demo(sub: argparse._SubParsersAction) -> None:
    from ground import sitl_cmd

    p = sub.add_parser(
        "demo",
        help="fly the demo mission in lockstep SITL: take-off to 3 m, set-points, a yaw change across ±180°, landing",
        description="Launch lockstep SITL with the built-in demo plan, then print a summary, write plots and"
        " (with --json) the results.",
    )
    sitl_cmd.add_demo_arguments(p)
    p.set_defaults(handler=sitl_cmd.demo_main)


def _run(sub: argparse._SubParsersAction) -> None:
    from lab import run

    p = sub.add_parser(
        "run",
        help="fly one scenario (TOML): in-process on the flight core, or --sitl as the two processes over UDP",
        description="Fly a scenario file (vehicle, plant, environment, seed, controller, parameters, plan, duration;"
        " examples in examples/scenarios/). In-process by default (the FC's own control tick and the simulator's"
        " plant in one loop, no UDP, as fast as the machine allows); --sitl runs the real FC and simulator processes"
        " in lockstep on free ports. Both write the same .tlog and print the same summary. Exit codes: 0 flown,"
        " 1 the flight diverged or SITL failed, 2 broken file or usage.",
    )
    run.add_arguments(p)
    p.set_defaults(handler=run.main)


def _compare(sub: argparse._SubParsersAction) -> None:
    from lab import compare

    p = sub.add_parser(
        "compare",
        help="robustness study: fault and disturbance cases x controllers x seeds, in-process; table and figures",
        description="Fly each case (motor loss at hover and mid-step, wind, gusts, mass and inertia errors the FC is"
        " not told of, gyro bias, a position dropout, the paper's disturbances) with each controller and several"
        " noise seeds on the flight core in this process; write results.csv, summary.json, table.md (mean and 95 %"
        " interval per metric) and figures. docs/robustness.md holds a run of it and its reading.",
    )
    compare.add_arguments(p)
    p.set_defaults(handler=compare.main)


def _campaign(sub: argparse._SubParsersAction) -> None:
    from lab.campaign import cli as campaign_cli

    p = sub.add_parser(
        "campaign",
        help="Monte Carlo and grid campaigns over thousands of flights on a Dask cluster; replay of any one",
        description="Campaign files (docs/campaigns.md): a base scenario, controllers, seeds and variations of any"
        " scenario field, flown on a local Dask cluster or an existing scheduler.",
    )
    campaign_cli.add_arguments(p)
    p.set_defaults(handler=campaign_cli.main)


def _tune(sub: argparse._SubParsersAction) -> None:
    from lab.tuning import study

    p = sub.add_parser(
        "tune",
        help="gain tuning with Optuna: trials flown as campaign units; best gains as a .parm file and a TOML fragment",
        description="Optuna ask-and-tell over named FC gains with ranges, each trial's flights (scenario groups x seeds)"
        " flown on the campaign engine, the objective built from their metrics (docs/campaigns.md). The study lives"
        " in DIR/study.journal: --resume continues it.",
    )
    study.add_arguments(p)
    p.set_defaults(handler=study.main)


def _plot(sub: argparse._SubParsersAction) -> None:
    from ground.logs import cli as logs_cli

    p = sub.add_parser(
        "plot",
        help="PNG figures of a flight log (position, attitude, motors, sigma/chi_hat, track)",
        description="Read a flight-controller .tlog and write PNG figures into DIR"
        " (default: <log stem>-plots/ next to the log).",
    )
    logs_cli.add_plot_arguments(p)
    p.set_defaults(handler=logs_cli.plot_main)


def _log(sub: argparse._SubParsersAction) -> None:
    from ground.logs import cli as logs_cli

    p = sub.add_parser("log", help="flight logs (.tlog): summary, compress, clean (keep the newest N flights)",
                       description="Inspect and tidy flight-controller .tlog files: summary, compress, clean.")
    logs_cli.add_log_arguments(p)
    p.set_defaults(handler=logs_cli.log_main)


def _gcs(sub: argparse._SubParsersAction) -> None:
    from ground import gcs_cmd

    p = sub.add_parser(
        "gcs",
        help="ground station: status, arm, take-off, go-to, land, modes, parameters, missions, live view",
        description="Talk to a running flight controller over MAVLink (docs/gcs-protocol.md). Exit codes: 0 done,"
        " 1 the vehicle refused or did not answer in time, 2 usage or configuration error.",
        epilog="Mission files (`mission upload`, `mission download`) use the format of `smcpilot mission`: [[item]]"
        " tables with type = takeoff (alt_m) | waypoint (north_m/east_m or lat_deg/lon_deg, alt_m, hold_s, yaw_deg,"
        " radius_m) | loiter_time (hold_s, position, alt_m) | land (position) | rtl | speed (speed_mps);"
        " north/east are metres from the vehicle's home.",
    )
    gcs_cmd.add_arguments(p)
    p.set_defaults(handler=gcs_cmd.main)


def _mission(sub: argparse._SubParsersAction) -> None:
    from ground.missions import cli as missions_cli

    p = sub.add_parser(
        "mission",
        help="scripted missions: fly a mission TOML in SITL (or on a running vehicle) and check its expectations",
        description="Scripted missions ([[item]], [sitl], [[expect]] in a TOML file; format in ground/missions/__init__.py)."
        " Exit codes: 0 every expectation held, 1 one failed or the flight could not be flown, 2 broken file or usage.",
    )
    missions_cli.add_arguments(p)
    p.set_defaults(handler=missions_cli.main)


def _laws(sub: argparse._SubParsersAction) -> None:
    from lab import laws_cmd

    p = sub.add_parser(
        "laws",
        help="list the control laws: built-ins, installed plug-ins, laws from files; their parameters",
        description="Every control law the flight controller can fly (built-ins, installed plug-ins of the entry-point"
        " group smcpilot.laws, and --law files or modules), with its stage, origin and MAVLink parameters."
        " A law that fails to load is named in one line (exit 2). docs/your-own-law.md shows how to write one.",
    )
    laws_cmd.add_arguments(p)
    p.set_defaults(handler=laws_cmd.main)


SUBCOMMANDS = (_run, _laws, _compare, _campaign, _tune, _paper, _sitl, _sim, _demo, _bench, _plot, _log, _gcs, _mission)


def build_parser() -> argparse.ArgumentParser:
    parser = CliParser(
        prog="smcpilot",
        description="MAVLink SITL flight controller flying the adaptive PID sliding-mode controller.",
    )
    parser.add_argument("--version", action="version", version=f"smcpilot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in SUBCOMMANDS:
        add(sub)
    return parser


class PipeSafeStdout(io.TextIOBase):
    """``sys.stdout`` that survives its reader going away (``smcpilot log summary LOG | head``).

    The first write or flush that meets a closed pipe points file descriptor 1 at the null device,
    and every later write succeeds and goes nowhere: the command (a mission in flight, a SITL run)
    carries on to its end and its exit code, without a ``BrokenPipeError`` traceback.
    """

    def __init__(self, stream: TextIO) -> None:
        super().__init__()
        self._stream = stream
        #: True once the reader of stdout has gone.
        self.broken = False

    def _detach_fd(self) -> None:
        self.broken = True
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)

    def write(self, text: str) -> int:  # type: ignore[override]
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._detach_fd()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._detach_fd()

    def isatty(self) -> bool:
        return self._stream.isatty()

    def fileno(self) -> int:
        return self._stream.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return self._stream.encoding

    def writable(self) -> bool:
        return True

    def __getattr__(self, name: str) -> object:
        """Everything else (``reconfigure``, ``buffer``, ``line_buffering``) is the stream's own."""
        return getattr(self._stream, name)


def main(argv: Sequence[str] | None = None) -> int:
    original = sys.stdout
    if not isinstance(original, PipeSafeStdout):
        try:
            original.fileno()
        except (AttributeError, OSError, ValueError):
            pass  # captured (pytest, StringIO): no file descriptor to protect
        else:
            sys.stdout = PipeSafeStdout(original)  # type: ignore[assignment]
    try:
        return _main(argv)
    finally:
        sys.stdout.flush()
        sys.stdout = original


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        return int(handler(args) or 0)
    except SmcpilotError as exc:
        print(f"smcpilot {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"smcpilot {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
