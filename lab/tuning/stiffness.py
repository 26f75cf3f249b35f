"""Stiffness of the outer position loop: RMS position error in gusts, steady offset in constant wind.

In-process flights (:func:`lab.runner.fly`: the flight core, the rigid-body plant, the wire round
trip) of a take-off to 3 m and a hold over the take-off point, with the scenario's environment
(``[environment] wind_force_ned_n`` / ``gust_std_n``; see ``examples/scenarios/gusty-hold.toml``).
Simulated time only.

- **gusts**: horizontal gusts of ``gust_std_n`` (1 s correlation), no constant wind; the RMS of
  the horizontal distance to the set-point over the window after ``settle_s``, for each seed;
- **wind**: a constant force from the north (``wind_force_ned_n = (F, 0, 0)``); the steady offset
  is the mean horizontal distance to the set-point over the last ``window_s`` of the flight.

``python -m lab.tuning.stiffness`` prints both for the FC's default law and position loop.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace

from fc.params import config_for
from lab.runner import fly
from sim_bridge.build import plant_for
from smcpilot.plan import PlanStep
from smcpilot.scenario import EnvironmentSpec, Scenario

HOLD_ALT_M = 3.0


@dataclass(frozen=True)
class HoldFlight:
    """A take-off and hold; what is measured, when."""

    duration_s: float = 60.0
    #: measuring starts this long after take-off, s.
    settle_s: float = 20.0
    #: the steady offset is averaged over the last ``window_s``, s.
    window_s: float = 10.0
    controller: str = "adaptive_pid_smc"
    #: FC parameters over the defaults.
    params: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        if not 0.0 < self.settle_s < self.duration_s or not 0.0 < self.window_s <= self.duration_s - self.settle_s:
            raise ValueError("HoldFlight needs 0 < settle_s < duration_s and 0 < window_s <= duration_s - settle_s")


def hold_errors(flight: HoldFlight, environment: EnvironmentSpec, seed: int = 1) -> tuple[list[float], list[float]]:
    """(times s, horizontal distances to the set-point m) after ``settle_s``, every 10th tick."""
    sc = Scenario(
        name="stiffness", duration_s=flight.duration_s, seed=seed, environment=environment, controller=flight.controller,
        params=flight.params, plan=(PlanStep(0.0, "takeoff", alt_m=HOLD_ALT_M),),
    )  # fmt: skip
    run = fly(config_for(sc), sc.vehicle, plant_for(sc), sc.plan, sc.duration_s, physics_hz=sc.physics_hz, record_every=10)
    ts: list[float] = []
    errs: list[float] = []
    for t, st, target in zip(run.t_s, run.states, run.targets):
        if t >= flight.settle_s:
            ts.append(t)
            errs.append(math.hypot(st.x_m - target[0], st.y_m - target[1]))
    return ts, errs


def gust_rms_m(flight: HoldFlight, gust_std_n: float = 0.5, seeds: Sequence[int] = (1, 2, 3), noise: bool = False) -> list[float]:
    """RMS horizontal position error (m) in gusts of ``gust_std_n`` (1 s correlation), per seed."""
    out = []
    for seed in seeds:
        _, e = hold_errors(flight, EnvironmentSpec(noise=noise, gust_std_n=gust_std_n, gust_tau_s=1.0), seed)
        out.append(math.sqrt(sum(v * v for v in e) / len(e)))
    return out


def wind_offset_m(flight: HoldFlight, wind_n: float) -> float:
    """Steady horizontal offset (m) in a constant wind force of ``wind_n`` from the north."""
    ts, e = hold_errors(flight, EnvironmentSpec(wind_force_ned_n=(-wind_n, 0.0, 0.0)))
    t_end = flight.duration_s - flight.window_s
    tail = [v for t, v in zip(ts, e) if t >= t_end]
    return sum(tail) / len(tail)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m lab.tuning.stiffness",
        description="Outer position loop at hover: RMS error in 0.5 N gusts and steady offset in 1 N and 2 N wind, "
        "in-process (docs/baselines.md).",
    )
    ap.add_argument("--controller", default="adaptive_pid_smc", choices=("adaptive_pid_smc", "pid_smc", "cascade_pid"))
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="an FC parameter over the defaults (repeatable)")
    ap.add_argument("--gust-n", type=float, default=0.5, help="gust force std, N (default %(default)g)")
    ap.add_argument("--wind-n", type=float, action="append", help="constant wind force, N (repeatable; default 1 and 2)")
    ap.add_argument("--seeds", type=int, default=3, help="gust flights, seeds 1..N (default %(default)d)")
    ap.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    args = ap.parse_args(argv)
    params = []
    for item in args.param:
        name, sep, value = item.partition("=")
        try:
            params.append((name.strip(), float(value)))
        except ValueError:
            print(f"error: --param {item!r}: expected NAME=VALUE with a number", file=sys.stderr)
            return 2
    flight = replace(HoldFlight(), controller=args.controller, params=tuple(params))
    try:
        config_for(Scenario(controller=flight.controller, params=flight.params))
    except Exception as exc:  # a bad parameter: say which
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rms = gust_rms_m(flight, args.gust_n, tuple(range(1, args.seeds + 1)))
    winds = args.wind_n or [1.0, 2.0]
    offsets = {w: wind_offset_m(flight, w) for w in winds}
    print(f"{args.controller}, params {dict(params) or 'defaults'}")
    print(f"gusts {args.gust_n:g} N: RMS horizontal error {sum(rms) / len(rms):.3f} m (seeds: " + ", ".join(f"{v:.3f}" for v in rms) + ")")
    for w, off in offsets.items():
        print(f"constant wind {w:g} N: steady offset {off * 1000:.3f} mm")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"controller": args.controller, "params": dict(params), "gust_rms_m": rms,
                       "wind_offset_m": {str(w): v for w, v in offsets.items()}}, f, indent=1)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
