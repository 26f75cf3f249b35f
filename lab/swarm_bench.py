"""``smcpilot bench swarm``: how many vehicles one machine flies, in lockstep and in real time.

For each K of ``--counts`` a lockstep SITL swarm of K vehicles (one simulator, no ground link) flies
``--duration`` simulated seconds of the take-off-and-hover plan, in each layout of
``--fc-processes``: the K flight controllers in K processes, or in N processes of several FCs each
(:mod:`fc.group`; real time flies the same layouts); printed per K and layout:
start-up wall time (launch to every FC's first tick), aggregate vehicle-seconds per wall second,
that as a ratio of K = 1's (measured in the same run), vehicle-ticks per wall second, CPU seconds
per vehicle per simulated second (the FCs' own, from their first tick on, and the operating
system's share of it), the simulator's CPU, and the skew between the vehicles' clocks at the
end (their FCs' last simulated times: zero when the lockstep holds). With ``--realtime-s S`` each K
also flies S seconds in real time: missed control deadlines (overruns / ticks, all FCs), the
99th-percentile lateness of the worst FC, and the clock skew between vehicles (the 99th percentile
of the wall time between the first and the last vehicle's copy of the same state; the plants share
one physics clock). Figures, never pass/fail.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import tempfile
import time
from pathlib import Path

from smcpilot.errors import ConfigError
from smcpilot.swarm import MAX_VEHICLES

PLAN = ({"t_s": 0.0, "action": "takeoff", "alt_m": 2.0},)


def add_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("swarm", help="many vehicles: lockstep vehicle-seconds per wall second for K = 1, 4, 16 ...; real time")
    c.add_argument("--counts", default="1,4,16", metavar="K,K,...", help=f"swarm sizes (default 1,4,16; at most {MAX_VEHICLES})")
    c.add_argument("--duration", type=float, default=10.0, metavar="S", help="simulated seconds per lockstep run (default 10)")
    c.add_argument("--realtime-s", type=float, default=0.0, metavar="S",
                   help="also fly S wall seconds in real time per K, counting missed deadlines (default 0: skip)")
    c.add_argument("--fc-processes", default=default_layouts(), metavar="N,N,...",
                   help="lockstep layouts to fly each K in: the FCs in N processes (fc.group), 0 for one process per vehicle"
                   f" (default {default_layouts()}: a process per vehicle; one less than this machine's cores, where the groups"
                   " and the simulator busy-poll; the cores)")  # fmt: skip
    c.set_defaults(bench=bench_swarm)


def default_layouts(cores: int | None = None) -> str:
    """``--fc-processes``' default: 0 (a process per vehicle), one less than the cores (the groups
    and the simulator fit the cores, so they busy-poll: the fastest on 2 cores, docs/swarms.md),
    and the cores; each once ("0,1,2" on 2 cores, "0,1" on one)."""
    n = cores if cores is not None else os.cpu_count() or 2
    return ",".join(str(v) for v in dict.fromkeys((0, max(1, n - 1), n)))


def _whole_numbers(text: str, flag: str, what: str, lowest: int) -> list[int]:
    """``--flag N,N,...``: whole numbers in ``lowest..MAX_VEHICLES``, each once (else one line, exit 2)."""
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(f"{flag} must be whole numbers {what}, got {text!r}") from None
    if not values or not all(lowest <= v <= MAX_VEHICLES for v in values):
        raise ConfigError(f"{flag} must lie in {lowest}..{MAX_VEHICLES}, got {text!r}")
    return list(dict.fromkeys(values))


def _fly(k: int, duration_s: float, lockstep: bool, log_dir: Path, fc_processes: int = 0) -> dict:
    from ground.sitl import Sitl, SitlOptions
    from smcpilot.plan import PlanStep
    from smcpilot.scenario import Scenario
    from smcpilot.swarm import SwarmSpec

    scenario = Scenario(name=f"bench-{k}", duration_s=duration_s, plan=tuple(PlanStep(**s) for s in PLAN),  # type: ignore[arg-type]
                        swarm=SwarmSpec(count=k) if k > 1 else None)  # fmt: skip
    opts = SitlOptions(scenario=scenario, timed=True, lockstep=lockstep, gcs=None, log_dir=log_dir,
                       tlog=log_dir / f"swarm-{k}-{'ls' if lockstep else 'rt'}-{fc_processes}.tlog", watchdog_s=30.0,
                       fc_processes=fc_processes if 0 < fc_processes < k else None)  # fmt: skip
    t0 = time.perf_counter()
    sitl = Sitl(opts)
    try:
        sitl.start(ready_timeout_s=60.0 + 2.0 * k)
        started = time.perf_counter() - t0
        t1 = time.perf_counter()
        sitl.wait(timeout_s=600.0 + 10.0 * k * duration_s)
        wall = time.perf_counter() - t1
    finally:
        sitl.terminate()
    fcs = [s or {} for s in sitl.fc_summaries]
    ticks = sum(int(s.get("ticks", 0)) for s in fcs)
    # CPU is the process's: one summary per FC process (a group's FCs each report the group's)
    per_process = [s for c, s in zip(sitl.fcs, fcs) if c is next(x for x in sitl.fcs if x.proc is c.proc)]
    overruns = sum(int(s.get("overruns", 0)) for s in fcs)
    sim_times = [float(s.get("sim_time_s") or 0.0) for s in fcs]
    p99 = [float(s["lateness_p99_s"]) for s in fcs if s.get("lateness_p99_s") is not None]
    return {
        "k": k,
        "start_s": started,
        "wall_s": wall,
        "vehicle_s_per_s": k * duration_s / wall if wall > 0 else float("nan"),
        "ticks_per_s": ticks / wall if wall > 0 else float("nan"),
        "cpu_per_vehicle": sum(float(s.get("cpu_s", 0.0)) - float(s.get("cpu_start_s", 0.0)) for s in per_process) / k / duration_s,
        "sys_share": sum(float(s.get("cpu_sys_s", 0.0)) for s in per_process) / max(1e-9, sum(float(s.get("cpu_s", 0.0)) for s in per_process)),
        "processes": len(per_process),
        "compiled": sum(1 for s in fcs if (s.get("pipeline") or {}).get("compiled")),
        "skew_s": max(sim_times) - min(sim_times) if sim_times else float("nan"),
        "sim_cpu": (float((sitl.sim_summary or {}).get("cpu_s", float("nan"))) - float((sitl.sim_summary or {}).get("cpu_start_s", 0.0))) / duration_s,
        "sim_physics": "compiled" if ((sitl.sim_summary or {}).get("physics") or {}).get("compiled") else "Python",
        "missed": overruns / ticks if ticks else float("nan"),
        "p99_ms": 1e3 * max(p99) if p99 else float("nan"),
        "fanout_p99_ms": 1e3 * float(((sitl.sim_summary or {}).get("fanout_skew_s") or {}).get("p99", float("nan"))),
    }


def bench_swarm(args: argparse.Namespace) -> int:
    counts = _whole_numbers(args.counts, "--counts", "K,K,...", 1)
    if not args.duration > 0:
        raise ConfigError(f"--duration must be > 0 simulated seconds, got {args.duration:g}")
    print(f"bench swarm: {platform.python_implementation()} {platform.python_version()}, {os.cpu_count()} CPUs; lockstep,"
          f" {args.duration:g} simulated s of take-off and hover per run, no ground link")  # fmt: skip
    layouts = _whole_numbers(args.fc_processes, "--fc-processes", "N,N,... (0: one process per vehicle)", 0)
    print(f"{'K':>4} {'FC procs':>8} {'start s':>8} {'wall s':>8} {'veh-s/s':>9} {'vs K=1':>7} {'x real':>7} {'ticks/s':>9} {'CPU/veh':>8}"
          f" {'kernel':>7} {'compiled':>8} {'sim CPU':>8} {'physics':>9} {'skew s':>7}")  # fmt: skip
    base: float | None = None
    with tempfile.TemporaryDirectory(prefix="smcpilot-bench-swarm-") as tmp:
        for k in counts:
            for n in [n for n in layouts if n < k] or [0]:  # (n >= K: one process per vehicle anyway)
                r = _fly(k, args.duration, True, Path(tmp), n)
                if k == 1 and base is None:
                    base = r["vehicle_s_per_s"]
                ratio = f"{r['vehicle_s_per_s'] / base:.2f}x" if base else "-"
                print(f"{k:>4} {r['processes']:>8} {r['start_s']:>8.2f} {r['wall_s']:>8.2f} {r['vehicle_s_per_s']:>9.2f} {ratio:>7}"
                      f" {r['vehicle_s_per_s'] / k:>6.2f}x {r['ticks_per_s']:>9.0f} {r['cpu_per_vehicle']:>8.3f} {100 * r['sys_share']:>6.0f}%"
                      f" {r['compiled']:>4}/{k:<3} {r['sim_cpu']:>8.3f} {r['sim_physics']:>9} {r['skew_s']:>7.3f}", flush=True)  # fmt: skip
        if args.realtime_s > 0:
            print(f"real time, {args.realtime_s:g} s per K at the scenario's 500 Hz:")
            print(f"{'K':>4} {'FC procs':>8} {'missed':>8} {'p99 ms':>7} {'skew p99 ms':>12} {'CPU/veh':>8} {'compiled':>8} {'sim CPU':>8}")
            for k in counts:
                for n in [n for n in layouts if n < k] or [0]:
                    r = _fly(k, args.realtime_s, False, Path(tmp), n)
                    skew = "-" if math.isnan(r["fanout_p99_ms"]) else f"{r['fanout_p99_ms']:.3f}"
                    print(f"{k:>4} {r['processes']:>8} {100 * r['missed']:>7.3f}% {r['p99_ms']:>7.2f} {skew:>12} {r['cpu_per_vehicle']:>8.3f}"
                          f" {r['compiled']:>4}/{k:<3} {r['sim_cpu']:>8.3f}", flush=True)  # fmt: skip
    print("FC procs: the flight controllers' processes (K: one each; fewer: several FCs in one loop, python -m fc.group);"
          " veh-s/s: simulated vehicle-seconds per wall second (K x simulated s / wall s); vs K=1: the same, over this run's K = 1;"
          " x real: simulated seconds per wall second; compiled: FCs flying the compiled pipeline (--jit auto: a group loads it"
          " once for all its FCs when they fly 60 s or more together);"
          " CPU/veh: FC CPU seconds per vehicle per simulated second of flight, start-up left out (kernel: the operating system's share of it: system calls,"
          " wake-ups); skew p99 (real time): wall time from the first to the last"
          " vehicle's copy of a state; sim CPU: the simulator's CPU seconds per simulated second, start-up left out; physics: the"
          " simulator's physics compiled or stepped in Python (sim --jit auto: compiled when cached and the run has"
          " 60 vehicle-seconds or more)"
          "; skew: spread of the FCs' final simulated times")  # fmt: skip
    return 0
