"""``smcpilot bench fast``: the compiled in-process flight against the CPython one, in the same run.

For each scenario (by default the example hover, step-yaw, gusty-hold with noise and gusts, and
motor-loss), the same flight is flown in CPython (``SMCPILOT_JIT=0``'s path) and compiled
(:mod:`lab.fast`), with no log, keeping a metrics row every tick (what a campaign unit keeps);
the wall times are the best of ``--repeat`` flights. Printed: simulated seconds per wall second
(× real time), µs per tick, and the ratio compiled / CPython. The first compiled flight also
shows what loading (or compiling) the kernel cost, separately. Then the same flights as
``smcpilot run`` flies them, writing the full-rate ``.tlog``. With ``--compare N``, also
``smcpilot compare --seeds N`` end to end, once each way (subprocesses, 2 workers).
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smcpilot.errors import ConfigError

_EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "scenarios"
DEFAULT_SCENARIOS = ("hover", "step-yaw", "gusty-hold", "motor-loss")


def add_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("fast", help="the compiled in-process flight against CPython (same run; ratios)")
    c.add_argument("scenarios", nargs="*", metavar="SCENARIO", help="scenario files (default: the example scenarios)")
    c.add_argument("--repeat", type=int, default=3, help="flights each way; the best is reported (default 3)")
    c.add_argument("--compare", type=int, default=0, metavar="SEEDS",
                   help="also time 'smcpilot compare --seeds SEEDS' end to end each way (default 0: not)")  # fmt: skip
    c.set_defaults(bench=bench_fast)


def _flight_s(sc, fast: bool) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    from fc.core import FlightCore
    from fc.params import settings_for
    from lab.fast.flight import FastRecord
    from lab.metrics import MetricsRecorder
    from lab.runner import simulate
    from sim_bridge.build import plant_for
    from smcpilot.geo import Home

    config, options = settings_for(sc)
    core = FlightCore(config, sc.vehicle, home=Home(*sc.home) if sc.home is not None else Home(), plan=sc.plan, estimator=options.estimator)
    plant = plant_for(sc)
    rec = MetricsRecorder(core)
    t0 = time.perf_counter()
    n = simulate(core, plant, sc.n_ticks, rate_hz=sc.rate_hz, physics_hz=sc.physics_hz, fast=fast, record=FastRecord(rec))
    return time.perf_counter() - t0, n


def _logged_flight_s(sc, fast: bool) -> float:  # type: ignore[no-untyped-def]
    from lab.run import fly_in_process

    old = os.environ.get("SMCPILOT_JIT")
    os.environ["SMCPILOT_JIT"] = "1" if fast else "0"
    try:
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            fly_in_process(sc, Path(d) / "flight.tlog")
            return time.perf_counter() - t0
    finally:
        if old is None:
            del os.environ["SMCPILOT_JIT"]
        else:
            os.environ["SMCPILOT_JIT"] = old


def bench_fast(args: argparse.Namespace) -> int:
    from smcpilot.jit import jit_unavailable_reason
    from smcpilot.scenario import Scenario

    if args.repeat < 1:
        raise ConfigError("--repeat must be at least 1")
    why = jit_unavailable_reason()
    if why is not None:
        print(f"the compiled path is off ({why}): nothing to compare")
        return 1
    paths = [Path(p) for p in args.scenarios] or [_EXAMPLES / f"{n}.toml" for n in DEFAULT_SCENARIOS]
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; best of {args.repeat}")
    print(f"{'scenario':<14} {'ticks':>7} {'CPython':>10} {'compiled':>10} {'CPython':>9} {'compiled':>9} {'ratio':>7} {'first call':>11}")
    print(f"{'':<14} {'':>7} {'x real':>10} {'x real':>10} {'us/tick':>9} {'us/tick':>9} {'':>7} {'(load, s)':>11}")
    ratios = []
    for path in paths:
        sc = Scenario.from_toml(path)
        first, _ = _flight_s(sc, True)  # loads (or compiles) the kernel for this law
        py = min(_flight_s(sc, False)[0] for _ in range(args.repeat))
        fast, n = min(_flight_s(sc, True) for _ in range(args.repeat))
        sim_s = n / sc.rate_hz
        ratios.append(py / fast)
        print(f"{path.stem:<14} {n:>7} {sim_s / py:>10.0f} {sim_s / fast:>10.0f} {py / n * 1e6:>9.1f} {fast / n * 1e6:>9.2f} "
              f"{py / fast:>6.1f}x {first - fast:>11.2f}")  # fmt: skip
    if len(ratios) > 1:
        print(f"compiled / CPython: {min(ratios):.1f}x to {max(ratios):.1f}x")
    print("\nthe same flights as `smcpilot run` flies them, writing the full-rate .tlog (byte for byte the same either way):")
    print(f"{'scenario':<14} {'CPython':>10} {'compiled':>10} {'ratio':>7}")
    print(f"{'':<14} {'x real':>10} {'x real':>10} {'':>7}")
    tl_ratios = []
    for path in paths:
        sc = Scenario.from_toml(path)
        py = min(_logged_flight_s(sc, False) for _ in range(args.repeat))
        fast = min(_logged_flight_s(sc, True) for _ in range(args.repeat))
        sim_s = sc.n_ticks / sc.rate_hz
        tl_ratios.append(py / fast)
        print(f"{path.stem:<14} {sim_s / py:>10.0f} {sim_s / fast:>10.0f} {py / fast:>6.1f}x")
    if len(tl_ratios) > 1:
        print(f"compiled / CPython, with the log: {min(tl_ratios):.1f}x to {max(tl_ratios):.1f}x")
    if args.compare:
        _bench_compare(args.compare)
    return 0


def _bench_compare(seeds: int) -> None:
    print(f"\nsmcpilot compare --seeds {seeds} (2 workers), end to end:")
    walls = {}
    for label, env in (("CPython", {"SMCPILOT_JIT": "0"}), ("compiled", {})):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "lab.cli", "compare", "--seeds", str(seeds), "--out", out, "--jobs", "2", "--quiet", "--no-plots"],
                               capture_output=True, text=True, env={**os.environ, **env})  # fmt: skip
            walls[label] = time.perf_counter() - t0
            ok = "ok" if p.returncode == 0 else f"exit {p.returncode}: {p.stderr.strip().splitlines()[-1:]}"
        print(f"  {label:<9} {walls[label]:7.1f} s  ({ok})")
    print(f"  ratio     {walls['CPython'] / walls['compiled']:7.1f}x")


# -- smcpilot bench batch -------------------------------------------------------------------------------
def add_batch_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("batch", help="campaign flights in batches, per core: vehicle-ticks/s against CPython (same run; ratio)")
    c.add_argument("--seeds", type=int, default=1, help="seeds of the robustness study's cases x controllers flown compiled (default 1: 70 flights)")
    c.add_argument("--duration", type=float, default=20.0, metavar="S", help="simulated seconds a flight (default 20, the study's)")
    c.add_argument("--cpython", type=int, default=14, metavar="N",
                   help="flights of them flown in CPython for the baseline, spread over the controllers and cases (default 14: two of each controller)")  # fmt: skip
    c.add_argument("--repeat", type=int, default=2, help="rounds of CPython and compiled, alternately; the best of each is reported (default 2)")
    c.add_argument("--engine", action="store_true",
                   help="also the same flights on a local cluster of 2 workers, in batches and one flight per task")  # fmt: skip
    c.set_defaults(bench=bench_batch)


def _study_units(seeds: int, duration_s: float, variants: list) -> list:  # type: ignore[type-arg]
    from lab.compare import study_cases, study_unit

    cases = study_cases(duration_s=duration_s, t_event_s=duration_s / 2.0)
    combos = [(c, v, s) for c in cases for v in variants for s in range(seeds)]
    return [study_unit(c, v, s, i) for i, (c, v, s) in enumerate(combos)]


def _fly_batch_s(units: list, jit: bool) -> tuple[float, list[dict]]:  # type: ignore[type-arg]
    from lab.campaign.engine import fly_batch
    from lab.campaign.flight import fly_row

    old = os.environ.get("SMCPILOT_JIT")
    os.environ["SMCPILOT_JIT"] = "1" if jit else "0"
    try:
        t0 = time.perf_counter()
        rows = fly_batch(fly_row, units)
        return time.perf_counter() - t0, rows
    finally:
        if old is None:
            del os.environ["SMCPILOT_JIT"]
        else:
            os.environ["SMCPILOT_JIT"] = old


def bench_batch(args: argparse.Namespace) -> int:
    from lab.fast.flight import KERNEL_TIME
    from smcpilot.jit import jit_unavailable_reason

    if args.seeds < 1 or args.cpython < 1 or args.repeat < 1 or not args.duration > 0:
        raise ConfigError("--seeds, --cpython and --repeat must be at least 1, --duration > 0")
    why = jit_unavailable_reason()
    if why is not None:
        print(f"the compiled path is off ({why}): nothing to compare")
        return 1
    from lab.compare import VARIANTS

    variants = list(VARIANTS)
    units = _study_units(args.seeds, args.duration, variants)
    ticks = sum(u.scenario.n_ticks for u in units)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load average {load:.2f} at the start")
    print(f"{len(units)} flights of the robustness study ({args.duration:g} s each: sensor noise, faults, gusts, model errors;"
          f" {len(variants)} controllers), flown one after another in this process as a worker flies a batch: building, flying, scoring\n")  # fmt: skip
    # units in the order case x controller x seed: the first case's flight of each controller loads the kernels
    n_var = len(variants)
    n_cases = len(units) // (n_var * args.seeds)
    first, _ = _fly_batch_s([units[v * args.seeds] for v in range(n_var)], True)
    # CPython: a subset spread over the controllers and the cases (flight i: case i, controller i)
    picks = sorted({((i % n_cases) * n_var + i % n_var) * args.seeds for i in range(args.cpython)})
    sub = [units[i] for i in picks]
    # alternately, the best of each: a machine shared with other work disturbs both alike
    py_s = math.inf
    best = None
    for _ in range(args.repeat):
        py_s = min(py_s, _fly_batch_s(sub, False)[0])
        KERNEL_TIME[:] = [0, 0, 0.0]
        wall, rows = _fly_batch_s(units, True)
        if best is None or wall < best[0]:
            best = (wall, list(KERNEL_TIME), rows)
    assert best is not None
    py_rate = sum(u.scenario.n_ticks for u in sub) / py_s
    wall, (calls, flown, kernel_s), rows = best
    rate = ticks / wall
    bad = sum(r["status"] not in ("ok", "crashed") for r in rows)
    print(f"{'':<34} {'vehicle-ticks/s':>16} {'us/tick':>8} {'ratio':>7}")
    print(f"{'CPython (' + str(len(sub)) + ' of the flights)':<34} {py_rate:>16,.0f} {1e6 / py_rate:>8.1f} {'1.0x':>7}")
    print(f"{'compiled, batch of ' + str(len(units)):<34} {rate:>16,.0f} {1e6 / rate:>8.2f} {rate / py_rate:>6.1f}x")
    kr = flown / kernel_s if kernel_s > 0 else float("nan")
    print(f"{'  of which the kernel alone':<34} {kr:>16,.0f} {1e6 / kr:>8.2f} {kr / py_rate:>6.1f}x")
    print(f"\nwhere a compiled flight's time goes: the kernel {kernel_s / wall:.0%} ({calls / len(units):.1f} calls a flight,"
          f" {flown / ticks:.1%} of the ticks), the rest {1 - kernel_s / wall:.0%}: building the flight core and plant, the eventful"
          f" ticks in Python ({ticks - flown:,} of {ticks:,}) and the hand-overs, scoring ({wall / len(units) * 1e3:.1f} ms a flight in all;"
          f" loading the kernels first took {first:.1f} s)" + (f"; {bad} flights not ok" if bad else ""))  # fmt: skip
    if args.engine:
        _bench_engine(units)
    return 0


def _bench_engine(units: list) -> None:  # type: ignore[type-arg]
    from lab.campaign.engine import ClusterOptions, Engine

    print(f"\nthe same {len(units)} flights on a local cluster of 2 workers (started and warm before the clock):")
    walls = {}
    for batch in (False, True):
        with Engine(ClusterOptions(workers=2), tag="bench-batch", batch=batch) as engine:
            engine.client.run(_warm_worker)
            t0 = time.perf_counter()
            engine.run(units, lambda u, r: None)
            walls[batch] = time.perf_counter() - t0
        label = f"in batches ({len(engine.batches(units))} tasks)" if batch else f"one flight per task ({len(units)} tasks)"
        print(f"  {label:<32} {walls[batch]:6.2f} s  {len(units) / walls[batch]:6.1f} flights/s")
    print(f"  batches / one per task: {walls[False] / walls[True]:.2f}x")


def _warm_worker(dask_worker: object = None) -> bool:
    """(Runs on every worker.) Load every controller's kernel: one short flight each."""
    from lab.campaign.flight import fly_row
    from lab.compare import VARIANTS

    for u in _study_units(1, 0.5, list(VARIANTS))[: len(VARIANTS)]:
        fly_row(u)
    return True
