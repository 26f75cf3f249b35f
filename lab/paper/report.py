"""The ``smcpilot paper`` command: run, print a table, write figures and metrics JSON."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from fc.control import CONTROLLER_NAMES
from fc.control.gains import PAPER_GAINS, gains_with_overrides
from lab.paper.run import PaperRunOptions, run_paper
from smcpilot.errors import ConfigError
from smcpilot.model import CHANNELS
from smcpilot.typos import TYPOS
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--controller",
        action="append",
        choices=CONTROLLER_NAMES,
        metavar="NAME",
        help=f"run only this controller (repeatable; default: all of {', '.join(CONTROLLER_NAMES)})",
    )
    p.add_argument(
        "--rate-hz",
        type=float,
        default=None,
        metavar="N",
        help="sampled-data control at N Hz with zero-order hold (must divide the 1 kHz physics rate);"
        " default: continuous-time RK4 at 1 kHz",
    )
    p.add_argument(
        "--sigma",
        choices=("model", "oracle"),
        default="model",
        help="PID-SMC sigma from the nominal model (implementable, default) or from the true"
        " acceleration (the paper's 'oracle')",
    )
    p.add_argument(
        "--chi-hat0",
        type=float,
        default=0.5,
        metavar="X",
        help="initial adaptive gain chi_hat(0) on every channel (paper simulation 0.5; Assumption 1: 0)",
    )
    p.add_argument(
        "--literal",
        default="",
        metavar="NAMES",
        help="reproduce the paper's printed typos literally: comma-separated names or 'all' ("
        + ", ".join(sorted(TYPOS))
        + "); see docs/paper-reproduction.md",
    )
    p.add_argument(
        "--gain",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="change a PID-SMC gain (both flavours), e.g. kd=2 (every channel) or psi.nu=0.2; names: c1, c2,"
        " kp, ki, kd, kappa, delta, nu, chi, adapt_rate (repeatable)",
    )
    p.add_argument("--no-disturbance", action="store_true", help="fly without the paper's disturbances fs1..fs4")
    p.add_argument("--duration", type=float, default=15.0, metavar="S", help="simulated seconds (default 15)")
    p.add_argument("--vehicle", type=Path, default=None, metavar="FILE", help="vehicle TOML (default: the spec's)")
    p.add_argument("--out", type=Path, default=Path("out/paper"), metavar="DIR", help="figure directory (default out/paper)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="write the metrics JSON here")


def _fmt(v: Any, unit: str = "", prec: int = 3) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        if v != 0.0 and (abs(v) < 1e-2 or abs(v) >= 1e4):
            return f"{v:.2e}{unit}"
        return f"{v:.{prec}f}{unit}"
    return str(v)


#: per channel: the units of its error e (and overshoot), its input u (max|u|, Σ|Δu|) and χ̂ (σ̇'s).
CHANNEL_UNITS = {
    "phi": ("rad", "N", "rad/s²"),
    "theta": ("rad", "N", "rad/s²"),
    "psi": ("rad", "N·m", "rad/s²"),
    "z": ("m", "N", "m/s²"),
}


def print_table(metrics: dict[str, Any], walls: dict[str, float], duration_s: float, out=sys.stdout) -> None:
    """The table of ``metrics``: every number with its unit (a channel's error is in rad or m, its
    input in N or N·m: the unit is in the cell where the rows differ, in the header where they do not)."""
    head = (f"{'controller':<18}{'ch':<7}{'t|σ|<.01 s':>12}{'t|e|<.01 s':>12}{'e(end)':>14}{'overshoot':>14}{'max|u|':>13}"
            f"{'Σ|Δu|':>13}{'χ̂(end)':>15}")  # fmt: skip
    print(head, file=out)
    print("-" * len(head), file=out)
    for name, entry in metrics["controllers"].items():
        for c in CHANNELS:
            m = entry["channels"][c]
            e_unit, u_unit, chi_unit = CHANNEL_UNITS[c]
            print(
                f"{name if c == 'phi' else '':<18}{c:<7}"
                f"{_fmt(m['t_sigma_below_0p01_s'], '', 2):>12}{_fmt(m['t_err_below_0p01_s'], '', 2):>12}"
                f"{_fmt(m['err_final'], ' ' + e_unit):>14}{_fmt(m['overshoot'], ' ' + e_unit):>14}{_fmt(m['max_abs_u'], ' ' + u_unit, 2):>13}"
                f"{_fmt(m['total_variation_u'], ' ' + u_unit, 2):>13}{_fmt(m['chi_hat_final'], ' ' + chi_unit):>15}",
                file=out,
            )
        wall = walls.get(name, float("nan"))
        status = (
            f"DIVERGED at t = {entry['diverged_at_s']:.3f} s ({entry['reason']})" if entry["diverged"] else "converged run"
        )
        speed = duration_s / wall if wall > 0 and not entry["diverged"] else float("nan")
        print(
            f"{'':<18}{status}; min ω²/ω²_hover = {_fmt(entry['min_omega_sq_over_hover'])};"
            f" {wall:.2f} s wall" + (f" ({speed:.0f}× real time)" if math.isfinite(speed) else ""),
            file=out,
        )
    print(file=out)


def main(args: argparse.Namespace) -> int:
    vehicle = VehicleParams.from_toml(args.vehicle) if args.vehicle else DEFAULT_VEHICLE
    from lab.paper.scenario import PaperScenario

    if not (args.duration > 0 and math.isfinite(args.duration)):
        raise ConfigError(f"--duration must be a positive number of seconds, got {args.duration}")
    overrides: dict[str, float] = {}
    for item in args.gain:
        key, sep, value = item.partition("=")
        try:
            overrides[key.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--gain expects NAME=VALUE with a number, got {item!r}") from None
        if not sep:
            raise ConfigError(f"--gain expects NAME=VALUE, got {item!r}")
    options = PaperRunOptions(
        gains=gains_with_overrides(PAPER_GAINS, overrides),
        controllers=tuple(args.controller) if args.controller else CONTROLLER_NAMES,
        rate_hz=args.rate_hz,
        sigma_source=args.sigma,
        chi_hat0=args.chi_hat0,
        typos=args.literal,
        disturbance=not args.no_disturbance,
        vehicle=vehicle,
        scenario=PaperScenario(duration_s=args.duration),
    )
    if args.json is not None and args.json.is_dir():
        raise ConfigError(f"--json {args.json} is a directory; give a file path")
    if not args.no_figures and args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out {args.out} exists and is not a directory")
    if options.rate_hz is not None and not (options.rate_hz > 0 and math.isfinite(options.rate_hz)):
        raise ConfigError(f"--rate-hz must be a positive number of Hz, got {options.rate_hz:g}")
    mode = "continuous-time RK4 at 1 kHz" if options.rate_hz is None else f"sampled-data control at {options.rate_hz:g} Hz"
    print(f"paper scenario: {options.scenario.duration_s:g} s, {mode}, sigma from {options.sigma_source},"
          f" ideal (unlimited) actuators" + (f", literal typos: {', '.join(sorted(options.typos))}" if options.typos else ""))

    def progress(name: str, tr, wall: float) -> None:
        state = f"diverged at {tr.diverged_at_s:.3f} s" if tr.diverged else "done"
        print(f"  {name:<18} {state} ({wall:.2f} s)", file=sys.stderr, flush=True)

    run = run_paper(options, progress)
    metrics = run.metrics()
    print()
    print_table(metrics, run.wall_seconds, options.scenario.duration_s)
    try:
        if args.json:  # before the figures: a plotting problem must not lose the numbers
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(metrics, indent=2, allow_nan=False) + "\n", encoding="utf-8")
            print(f"metrics: {args.json}")
        if not args.no_figures:
            from lab.paper.figures import write_figures

            paths = write_figures(run, args.out)
    except OSError as exc:
        raise ConfigError(f"cannot write results: {exc}") from None
    if not args.no_figures:
        print(f"figures: {len(paths)} PNG files in {args.out}/ ({', '.join(p.name for p in paths)})")
    return 0
