"""``smcpilot bench``: speed figures, printed as numbers and ratios, never asserted.

``bench control``: microseconds per 4-channel controller step and per plant RK4 step, and the
paper scenario's simulated seconds per wall second for each controller, with a baseline measured
in the same run (the cost of the RK4 arithmetic alone on the same number of states) so figures
from different machines can be compared as ratios.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
import timeit
from typing import Callable

from fc.control import CONTROLLER_NAMES
from smcpilot.errors import ConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="target", metavar="TARGET")
    sub.required = True
    c = sub.add_parser("control", help="control-law and plant step costs, paper scenario speed")
    c.add_argument("--repeat", type=int, default=5, help="timing repeats; the best is reported (default 5)")
    c.add_argument("--duration", type=float, default=15.0, metavar="S", help="paper scenario length (default 15)")
    c.set_defaults(bench=bench_control)
    for extra in _EXTRA_TARGETS:
        extra(sub)


def _best_us(fn: Callable[[], object], number: int, repeat: int) -> float:
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def bench_control(args: argparse.Namespace) -> int:
    from fc.control.base import constant_reference
    from ground.paper.run import PaperRunOptions, build_controller
    from ground.paper.scenario import PAPER_TARGETS, PAPER_X0, PaperScenario
    from ground.closed_loop import simulate
    from sim_bridge.plants.paper import PaperPlant
    from smcpilot.integrate import rk4_step
    from smcpilot.model import PaperModel

    if args.repeat < 1:
        raise ConfigError("--repeat must be >= 1")
    print(f"smcpilot bench control — Python {platform.python_version()} on {platform.machine()}, best of {args.repeat}")
    model = PaperModel.from_vehicle()
    plant = PaperPlant(model)
    opts = PaperRunOptions()
    ref = constant_reference(PAPER_TARGETS)
    meas = PAPER_X0
    y12 = list(PAPER_X0) + [0.0] * 4
    n = 20000

    floor = _best_us(lambda: rk4_step(lambda t, y: y, 0.0, y12 * 2, 1e-3), n // 4, args.repeat)
    print(f"\nbaseline: RK4 arithmetic alone on 24 states (identity derivative): {floor:.2f} µs/step")

    print("\ncontroller step (sampled form, 4 channels):")
    for name in CONTROLLER_NAMES:
        ctrl = build_controller(name, model, opts)
        st = ctrl.initial_state(meas)
        us = _best_us(lambda: ctrl.step(meas, ref, st, 0.002), n, args.repeat)
        print(f"  {name:<18} {us:7.2f} µs/step   ({us / floor:.2f}× baseline; target ≤ 10 µs)")

    u = model.hover_inputs()
    f = lambda t, y: plant.derivatives(t, y, u)[0]  # noqa: E731
    us_plant = _best_us(lambda: rk4_step(f, 0.1, y12, 1e-3), n // 4, args.repeat)
    print(f"\npaper plant RK4 step (12 states, 4 derivative calls): {us_plant:.2f} µs/step ({us_plant / floor:.2f}× baseline)")

    sc = PaperScenario(duration_s=args.duration)
    print(f"\npaper scenario, {sc.duration_s:g} s continuous-time RK4 at 1 kHz (controller states in the ODE):")
    for name in CONTROLLER_NAMES:
        ctrl = build_controller(name, model, opts)
        best = math.inf
        for _ in range(max(1, min(args.repeat, 3))):
            t0 = time.perf_counter()
            tr = simulate(ctrl, plant, sc.reference, sc.plant_x0, sc.duration_s)
            best = min(best, time.perf_counter() - t0)
        steps = len(tr.t_s)
        print(
            f"  {name:<18} {sc.duration_s / best:6.1f}× real time  ({best * 1e6 / steps:6.1f} µs per 1 ms step,"
            f" {best * 1e6 / steps / floor:.1f}× baseline){'  DIVERGED' if tr.diverged else ''}"
        )
    print("\ntargets (issue 3): controller step ≤ 10 µs; paper scenario ≥ 50× real time per controller")
    return 0


_EXTRA_TARGETS: list[Callable[[argparse._SubParsersAction], None]] = []


def main(args: argparse.Namespace) -> int:
    sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    return int(args.bench(args))
