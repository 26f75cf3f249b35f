"""The ``smcpilot`` command line: one subcommand per job, each with a true ``--help``.

Errors the user can fix (a bad option, gain or file) print one line and exit 2; no traceback.
"""

from __future__ import annotations

import argparse
import sys
from typing import Callable, Sequence

from smcpilot import __version__
from smcpilot.errors import SmcpilotError

Handler = Callable[[argparse.Namespace], int]


def _paper(sub: argparse._SubParsersAction) -> None:
    from ground.paper import report

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
    from ground import bench

    p = sub.add_parser("bench", help="measure speed (prints figures; never pass/fail)")
    bench.add_arguments(p)
    p.set_defaults(handler=bench.main)


SUBCOMMANDS = (_paper, _bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="smcpilot",
        description="MAVLink SITL flight controller flying the adaptive PID sliding-mode controller.",
    )
    parser.add_argument("--version", action="version", version=f"smcpilot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
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
