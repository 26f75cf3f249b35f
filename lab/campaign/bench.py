"""``smcpilot bench campaign``: the engine's speed, printed, never asserted.

- the baseline: the same units flown one after another in this process, no engine;
- flights per second on a local cluster of 1 and of 2 workers (processes), and the ratio
  (goal ≥ 1.7× on 2 cores);
- the engine's per-unit overhead: the 1-worker campaign's wall time less the flights' own wall
  time (measured inside the workers), per unit, as a share of the flight time (goal < 2 %);
- in-process against ``--sitl`` units (the real two processes over UDP in lockstep).

Clusters are started and their workers warmed up (modules imported, one short flight) before the
clock starts: startup is printed on its own line, not counted in the rates.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import replace

from lab.campaign.spec import CampaignError, parse_campaign
from lab.campaign.units import Unit, expand

_BENCH_DOC = {
    "name": "bench",
    "seed": 7,
    "controllers": ["adaptive_pid_smc"],
    "scenario": {"environment": {"noise": True}, "step": [{"t_s": 0.0, "action": "takeoff", "alt_m": 2.0}]},
    "vary": [{"field": "environment.wind_force_ned_n[0]", "dist": "normal", "mean": 0.0, "std": 0.3}],
}


def add_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("campaign", help="campaign engine: flights/s with 1 and 2 workers, per-unit overhead, in-process vs --sitl")
    c.add_argument("--units", type=int, default=16, help="units per measurement (default 16)")
    c.add_argument("--duration", type=float, default=10.0, metavar="S", help="simulated seconds per flight (default 10, a short campaign flight)")
    c.add_argument("--sitl-units", type=int, default=2, metavar="N", help="SITL units for the in-process vs --sitl line (default 2; 0 skips)")
    c.set_defaults(bench=bench_campaign)


def _units(n: int, duration_s: float, *, sitl: bool = False) -> list[Unit]:
    spec = parse_campaign({**_BENCH_DOC, "seeds": n, "duration_s": duration_s}, source="bench")
    return expand(spec, sitl=sitl)


def _warm(dask_worker: object = None) -> bool:
    """(Runs on every worker.) Import the flight modules and fly 0.2 s, so the clock does not time imports."""
    from lab.campaign.flight import fly_row

    fly_row(_units(1, 0.2)[0])
    return True


def _campaign_rate(workers: int, units: list[Unit]) -> tuple[float, float, float]:
    """(startup s, wall s of the units, Σ of the flights' own wall s) on a local cluster of ``workers``."""
    from lab.campaign.engine import ClusterOptions, Engine

    t0 = time.perf_counter()
    with Engine(ClusterOptions(workers=workers), tag=f"bench{workers}") as engine:
        engine.client.run(_warm)
        startup = time.perf_counter() - t0
        flight_s = 0.0
        t1 = time.perf_counter()

        def take(unit: Unit, row: dict) -> None:
            nonlocal flight_s
            if row.get("status") != "ok":
                raise CampaignError(f"bench unit {unit.index}: {row.get('status')}: {row.get('message')}")
            flight_s += float(row["wall_s"])

        engine.run(units, take)
        wall = time.perf_counter() - t1
    return startup, wall, flight_s


def bench_campaign(args: argparse.Namespace) -> int:
    from lab.campaign.flight import fly_row

    if args.units < 2 or not args.duration > 0 or args.sitl_units < 0:
        raise CampaignError("--units must be >= 2, --duration > 0 and --sitl-units >= 0")
    n, d = args.units, args.duration
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"smcpilot bench campaign — Python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} cores,"
          f" load average {load:.2f} at the start; {n} units of {d:g} simulated s (take-off and hover, noise, random wind)")  # fmt: skip
    units = _units(n, d)
    _warm()
    t0 = time.perf_counter()
    for u in units:
        fly_row(u)
    serial = time.perf_counter() - t0
    per_flight = serial / n
    print(f"\nbaseline, one after another in this process (no engine): {per_flight:.3f} s per flight, {n / serial:.2f} flights/s")
    s1, w1, f1 = _campaign_rate(1, [replace(u) for u in units])
    print(f"engine, local cluster of 1 worker:  {n / w1:.2f} flights/s ({w1 / serial:.2f}× the baseline's time; cluster up and warm in {s1:.1f} s)")
    overhead = (w1 - f1) / n
    print(f"  per-unit engine overhead: {overhead * 1e3:.1f} ms = {overhead / (f1 / n) * 100:.2f} % of the flight time"
          f" ({f1 / n:.3f} s per flight inside the worker; goal < 2 %)")  # fmt: skip
    s2, w2, _ = _campaign_rate(2, units)
    print(f"engine, local cluster of 2 workers: {n / w2:.2f} flights/s (cluster up and warm in {s2:.1f} s)")
    print(f"  scaling 1 -> 2 workers: {w1 / w2:.2f}× (goal ≥ 1.7× on 2 cores; the other work on the machine takes its share)")
    if args.sitl_units:
        from lab.campaign.flight import fly_unit

        su = _units(args.sitl_units, d, sitl=True)
        t0 = time.perf_counter()
        for u in su:
            row, _ = fly_unit(u)
            if row["status"] != "ok":
                raise CampaignError(f"bench SITL unit {u.index}: {row['status']}: {row['message']}")
        sitl_s = (time.perf_counter() - t0) / len(su)
        print(f"\nunit as SITL (two processes over UDP, lockstep): {sitl_s:.2f} s per flight against {per_flight:.3f} s in-process"
              f" ({sitl_s / per_flight:.1f}× slower; process start included)")  # fmt: skip
    return 0
