"""The command-line pieces of the log tools, wired into :mod:`lab.cli`:
:func:`add_plot_arguments` / :func:`plot_main` for ``smcpilot plot LOG`` and
:func:`add_log_arguments` / :func:`log_main` for ``smcpilot log summary LOG``,
``smcpilot log compress LOG...`` and ``smcpilot log clean [DIR]``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ground.logs.housekeeping import DEFAULT_KEEP, clean_logs, compress_logs, flight_stem, format_bytes
from ground.logs.load import LogError, load_log
from ground.logs.plots import plot_log
from ground.logs.setpoints import SETPOINT_MAX_AGE_S, load_setpoints
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
    out_dir: Path = args.out if args.out is not None else log_path.with_name(f"{flight_stem(log_path)}-plots")
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
        "--setpoints",
        type=Path,
        default=None,
        metavar="AUTOPILOT.tlog",
        help="for a served flight's log (smcpilot sim --serve): the autopilot's own log, whose POSITION_TARGET_LOCAL_NED and"
        " ATTITUDE_TARGET (or our FC's SMC records) the position and attitude errors are scored against"
        " (without it only the set-point-free metrics are)",
    )
    s.add_argument(
        "--settle-s",
        type=float,
        default=DEFAULT_SETTLE_S,
        metavar="S",
        help=f"seconds a set-point change is given before tracking error counts (default {DEFAULT_SETTLE_S:g})",
    )
    s.set_defaults(log_handler=_summary_main)

    m = sub.add_parser(
        "compare",
        help="the same metrics for several flights side by side (e.g. ArduCopter or PX4 on smcpilot sim --serve against our FC)",
        description="Score each log as `smcpilot log summary` does and print the metrics side by side: the true state's"
        " (ODOMETRY) where the log has it, else the sensed state's. Our FC's logs are scored against their own set-points; a"
        " served flight's log (smcpilot sim --serve) against its autopilot's set-points given with --setpoints, or with the"
        " set-point-free metrics only. Flights under the same scenario (vehicle, environment, faults) compare like for like.",
    )
    m.add_argument("logs", type=Path, nargs="+", metavar="LOG", help=".tlog files (ours, or served)")
    m.add_argument("--setpoints", action="append", default=[], metavar="LOG=AUTOPILOT.tlog",
                   help="the autopilot's own log for the served flight LOG (repeat for each served log)")  # fmt: skip
    m.add_argument("--settle-s", type=float, default=DEFAULT_SETTLE_S, metavar="S",
                   help=f"seconds a set-point change is given before tracking error counts (default {DEFAULT_SETTLE_S:g})")  # fmt: skip
    m.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the summaries as JSON to PATH ('-': stdout, instead of text)")
    m.set_defaults(log_handler=_compare_main)

    c = sub.add_parser(
        "compress",
        help="gzip flight logs (about 2.5x smaller); smcpilot log/plot still read them, `gunzip -k` for pymavlink",
        description="Compress each .tlog to .tlog.gz (gzip) and delete the original once the copy is complete."
        " smcpilot log summary and smcpilot plot read .tlog.gz directly; pymavlink (mavlogdump.py, MAVProxy)"
        " needs the plain file back: gunzip -k LOG.tlog.gz. A directory compresses every .tlog in it.",
    )
    c.add_argument("paths", type=Path, nargs="+", metavar="LOG|DIR", help=".tlog files or directories of them")
    c.set_defaults(log_handler=_compress_main)

    k = sub.add_parser(
        "clean",
        help=f"delete all but the newest flights in a log directory (default: keep {DEFAULT_KEEP})",
        description="Delete the oldest flights in DIR: each flight's .tlog (or .tlog.gz), its .scenario.toml, its own .parm"
        " and its -plots/ directory go together; other files (a parameter file kept with --param-file) are never touched. --compress gzips"
        " the older flights instead of deleting them.",
    )
    k.add_argument("dir", type=Path, nargs="?", default=Path("logs"), metavar="DIR", help="log directory (default logs/)")
    k.add_argument("--keep", type=int, default=DEFAULT_KEEP, metavar="N", help=f"newest flights to keep (default {DEFAULT_KEEP})")
    k.add_argument("--compress", action="store_true", help="compress the older flights' logs instead of deleting them")
    k.add_argument("--dry-run", action="store_true", help="only print what would be done")
    k.set_defaults(log_handler=_clean_main)


def log_main(args: argparse.Namespace) -> int:
    """``smcpilot log SUBCOMMAND``: dispatch to the chosen subcommand."""
    handler: Callable[[argparse.Namespace], int] = args.log_handler
    return handler(args)


def _check_settle(settle_s: float) -> None:
    if not (math.isfinite(settle_s) and settle_s >= 0.0):
        raise LogError(f"--settle-s must be a finite number >= 0, got {settle_s}")


def _summarize_path(path: Path, setpoints_path: Path | None, settle_s: float) -> dict[str, Any]:
    """``path`` read and summarized (a served flight's against ``setpoints_path``'s set-points)."""
    log = load_log(path)
    if log.records == 0:
        raise LogError(f"{path} is empty: no records (a flight that never started, or a log cut at its start)")
    setpoints = None
    if log.served_to is not None:
        if not log.has_truth:
            raise LogError(f"{path}: a served flight's log without a served state: the autopilot never stepped the physics")
        if setpoints_path is not None:
            setpoints = load_setpoints(setpoints_path)
            first, last = setpoints.span_s()
            t0 = (log.t0_us or 0) * 1e-6
            start, end = t0 + float(log.truth_t_s[0]), t0 + float(log.truth_t_s[-1])
            if first > end or last + SETPOINT_MAX_AGE_S < start:
                raise LogError(f"--setpoints {setpoints_path}: its set-points ({first:.3f} to {last:.3f} s of the autopilot's time) are"
                               f" outside the served flight ({start:.3f} to {end:.3f} s): not this flight's autopilot log?")  # fmt: skip
    elif setpoints_path is not None:
        raise LogError(f"--setpoints is for a served flight's log (smcpilot sim --serve); {path} is our flight controller's,"
                       " scored against its own set-points")  # fmt: skip
    return summarize(log, settle_s=settle_s, setpoints=setpoints)


#: the rows of ``smcpilot log compare``: (metric key, label, format).
_COMPARE_ROWS = (
    ("flight_time_s", "flight time, s", "{:.2f}"),
    ("iae_pos_m_s", "IAE position, m s", "{:.3f}"),
    ("ise_pos_m2_s", "ISE position, m^2 s", "{:.3f}"),
    ("itae_pos_m_s2", "ITAE position, m s^2", "{:.3f}"),
    ("max_pos_err_m", "max position error, m", "{:.3f}"),
    ("iae_att_rad_s", "IAE attitude, rad s", "{:.4f}"),
    ("effort_u2_s", "effort, u^2 s", "{:.2f}"),
    ("motor_tv_per_s", "motor TV per s", "{:.3f}"),
    ("max_tilt_deg", "max tilt, deg", "{:.1f}"),
    ("recover_s", "recovery, s", "{:.2f}"),
    ("crashed", "crashed", "{}"),
)


def _compare_main(args: argparse.Namespace) -> int:
    _check_settle(args.settle_s)
    given: dict[Path, Path] = {}
    for item in args.setpoints:
        name, sep, ap = item.partition("=")
        if not sep or not name or not ap:
            raise LogError(f"--setpoints wants LOG=AUTOPILOT.tlog, got {item!r}")
        if Path(name) not in args.logs:
            raise LogError(f"--setpoints {item}: {name} is not one of the logs compared")
        given[Path(name)] = Path(ap)
    summaries = [_summarize_path(p, given.get(p), args.settle_s) for p in args.logs]
    rows: list[dict[str, Any]] = []
    for p, sm in zip(args.logs, summaries):
        truth = sm.get("truth_metrics")
        metrics = truth if truth else sm.get("metrics")
        rows.append({"log": str(p), "scored": "true state" if truth else "sensed state", "scored_against": (sm.get("metrics_sources") or {}).get("setpoints"),
                     "controller": sm.get("controller_data"), "metrics": metrics})  # fmt: skip
    if args.json is not None:
        text = json.dumps(rows, indent=2, allow_nan=False)
        if str(args.json) == "-":
            print(text)
            return 0
        try:
            args.json.write_text(text + "\n")
        except OSError as exc:
            raise LogError(f"cannot write {args.json}: {exc.strerror}") from exc
    width = max(12, *(len(p.name) for p in args.logs))
    print(f"{'':<24}" + "".join(f"  {p.name:>{width}}" for p in args.logs))
    for key, label, fmt in _COMPARE_ROWS:
        cells = []
        for r in rows:
            v = (r["metrics"] or {}).get(key)
            cells.append("-" if v is None else fmt.format(v))
        print(f"{label:<24}" + "".join(f"  {c:>{width}}" for c in cells))
    for p, r in zip(args.logs, rows):
        against = r["scored_against"] or "its own set-points"
        print(f"{p.name}: {r['scored']}, against {against}")
    return 0


def _summary_main(args: argparse.Namespace) -> int:
    _check_settle(args.settle_s)
    summary = _summarize_path(args.log, args.setpoints, args.settle_s)
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


def _compress_main(args: argparse.Namespace) -> int:
    results = compress_logs(args.paths)
    before = sum(r.bytes_before for r in results)
    after = sum(r.bytes_after for r in results)
    for r in results:
        print(f"{r.path}: {format_bytes(r.bytes_before)} -> {format_bytes(r.bytes_after)}")
    if not results:
        print("no .tlog to compress", file=sys.stderr)
        return 1
    print(f"{len(results)} log(s): {format_bytes(before)} -> {format_bytes(after)}")
    return 0


def _clean_main(args: argparse.Namespace) -> int:
    if args.keep < 0:
        raise LogError(f"--keep must be >= 0, got {args.keep}")
    report = clean_logs(args.dir, keep=args.keep, compress=args.compress, dry_run=args.dry_run)
    verb = ("would compress" if args.compress else "would delete") if args.dry_run else ("compressed" if args.compress else "deleted")
    for path in report.touched:
        print(f"{verb} {path}")
    print(f"{args.dir}: {report.flights} flight(s), kept the newest {min(args.keep, report.flights)};"
          f" {verb} {len(report.touched)} file(s), {format_bytes(report.bytes_freed)} freed")  # fmt: skip
    return 0
