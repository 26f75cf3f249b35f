"""The command-line pieces of the log tools, wired into :mod:`lab.cli`:
:func:`add_plot_arguments` / :func:`plot_main` for ``smcpilot plot LOG`` and
:func:`add_log_arguments` / :func:`log_main` for ``smcpilot log summary LOG``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Callable

from ground.logs.load import LogError, load_log
from ground.logs.plots import plot_log
from ground.logs.summary import DEFAULT_SETTLE_S, print_summary, summarize

__all__ = ["add_log_arguments", "add_plot_arguments", "log_main", "plot_main"]


def add_plot_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``smcpilot plot LOG [--out DIR]``."""
    p.add_argument("log", type=Path, metavar="LOG", help="a .tlog written by the flight controller")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory for the PNGs (created if needed; default: <log stem>-plots/ next to the log)",
    )


def plot_main(args: argparse.Namespace) -> int:
    """``smcpilot plot``: write the figures, print their paths. Exit 1 if the log has nothing to plot."""
    log_path: Path = args.log
    out_dir: Path = args.out if args.out is not None else log_path.with_name(f"{log_path.stem}-plots")
    log = load_log(log_path)
    for note in log.warnings:
        print(f"note: {note}", file=sys.stderr)
    paths = plot_log(log, out_dir)
    if not paths:
        print(f"nothing to plot: {log_path} has no state, actuator or controller messages", file=sys.stderr)
        return 1
    for path in paths:
        print(path)
    return 0


def add_log_arguments(p: argparse.ArgumentParser) -> None:
    """Subcommands of ``smcpilot log``: ``summary LOG [--json PATH]`` (room for more)."""
    sub = p.add_subparsers(dest="log_command", metavar="SUBCOMMAND")
    sub.required = True
    s = sub.add_parser(
        "summary",
        help="headline numbers of a flight: duration, overruns, tracking error, chi_hat, events",
        description="Read a flight-controller .tlog and print its summary (see ground.logtools.summarize"
        " for the definitions).",
    )
    s.add_argument("log", type=Path, metavar="LOG", help="a .tlog written by the flight controller")
    s.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the summary as JSON to PATH ('-': stdout, instead of text)"
    )
    s.add_argument(
        "--settle-s",
        type=float,
        default=DEFAULT_SETTLE_S,
        metavar="S",
        help=f"seconds a set-point change is given before tracking error counts (default {DEFAULT_SETTLE_S:g})",
    )
    s.set_defaults(log_handler=_summary_main)


def log_main(args: argparse.Namespace) -> int:
    """``smcpilot log SUBCOMMAND``: dispatch to the chosen subcommand."""
    handler: Callable[[argparse.Namespace], int] = args.log_handler
    return handler(args)


def _summary_main(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.settle_s) and args.settle_s >= 0.0):
        raise LogError(f"--settle-s must be a finite number >= 0, got {args.settle_s}")
    summary = summarize(load_log(args.log), settle_s=args.settle_s)
    text = json.dumps(summary, indent=2, allow_nan=False)
    if args.json is not None and str(args.json) == "-":
        print(text)
        return 0
    print_summary(summary)
    if args.json is not None:
        try:
            args.json.write_text(text + "\n")
        except OSError as exc:
            raise LogError(f"cannot write {args.json}: {exc.strerror}") from exc
    return 0
