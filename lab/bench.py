"""``smcpilot bench``: speed figures, printed as numbers and ratios, never asserted.

``bench control``: microseconds per 4-channel controller step and per plant RK4 step, and the
paper scenario's simulated seconds per wall second for each controller, with a baseline measured
in the same run (the cost of the RK4 arithmetic alone on the same number of states) so figures
from different machines can be compared as ratios.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import math
import os
import platform
import subprocess
import sys
import time
import timeit
from collections.abc import Callable
from pathlib import Path
from typing import Any

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
    from lab.closed_loop import simulate
    from lab.paper.run import PaperRunOptions, build_controller
    from lab.paper.scenario import PAPER_TARGETS, PAPER_X0, PaperScenario
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
        us = _best_us(functools.partial(ctrl.step, meas, ref, st, 0.002), n, args.repeat)
        print(f"  {name:<18} {us:7.2f} µs/step   ({us / floor:.2f}× baseline; goal ≤ 10 µs)")

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
            tr = simulate(ctrl, plant, sc.reference, sc.plant_x0, sc.duration_s, compiled=False)
            best = min(best, time.perf_counter() - t0)
        steps = len(tr.t_s)
        print(
            f"  {name:<18} {sc.duration_s / best:6.1f}× real time  ({best * 1e6 / steps:6.1f} µs per 1 ms step,"
            f" {best * 1e6 / steps / floor:.1f}× baseline){'  DIVERGED' if tr.diverged else ''}"
        )
    print("\ngoals: controller step ≤ 10 µs; the paper scenario above is the CPython loop (compiled: smcpilot bench paper,"
          " goal ≥ 30× the CPython loop per controller)")  # fmt: skip
    return 0


def _add_paper(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("paper", help="the paper scenario per controller: CPython against the compiled ODE runner, in the same run")
    c.add_argument("--repeat", type=int, default=3, metavar="N", help="rounds of one CPython run and five compiled runs, alternating; the best of each is reported (default 3)")
    c.add_argument("--duration", type=float, default=15.0, metavar="S", help="paper scenario length (default 15)")
    c.add_argument("--rate", type=float, default=None, metavar="HZ", help="sampled-data control at this rate (default: continuous time)")
    c.set_defaults(bench=bench_paper)


def bench_paper(args: argparse.Namespace) -> int:
    """``smcpilot paper``'s runs per controller: the CPython loop and the compiled runner
    (:mod:`lab.fast.paper`) alternating in this process, their real-time factors and ratio, the
    compiled runner's first call (compiling it, or loading it from numba's disk cache), and whether
    the two trajectories are the same bits."""
    import numpy as np

    from lab.closed_loop import simulate
    from lab.fast import paper as fast_paper
    from lab.paper.run import PaperRunOptions, build_controller
    from lab.paper.scenario import PaperScenario
    from sim_bridge.plants.paper import PaperPlant
    from smcpilot.jit import jit_enabled
    from smcpilot.model import PaperModel

    if args.repeat < 1 or not args.duration > 0:
        raise ConfigError("--repeat must be >= 1 and --duration > 0")
    sc = PaperScenario(duration_s=args.duration)
    mode = "continuous-time RK4 at 1 kHz" if args.rate is None else f"sampled-data control at {args.rate:g} Hz, plant RK4 at 1 kHz"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"smcpilot bench paper — Python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} cores (load {load:.2f}),"
          f" the paper scenario, {sc.duration_s:g} s, {mode}; best of {args.repeat} CPython and {5 * args.repeat} compiled runs, alternating")  # fmt: skip
    on = jit_enabled()
    model = PaperModel.from_vehicle()
    opts = PaperRunOptions()
    print(f"\n  {'controller':<18} {'CPython':>10} {'compiled':>11} {'ratio':>8}   first compiled call")
    for name in CONTROLLER_NAMES:
        t0 = time.perf_counter()
        simulate(build_controller(name, model, opts), PaperPlant(model), sc.reference, sc.plant_x0, 1e-3, rate_hz=args.rate)
        first = time.perf_counter() - t0
        best_py = best_co = math.inf
        same = True
        for _ in range(args.repeat):
            runs = {}
            for compiled in (False, True):
                for _k in range(5 if compiled else 1):  # a compiled run is short: several, so one a busy machine slows does not count
                    ctrl = build_controller(name, model, opts)
                    t0 = time.perf_counter()
                    runs[compiled] = simulate(ctrl, PaperPlant(model), sc.reference, sc.plant_x0, sc.duration_s, rate_hz=args.rate, compiled=compiled)
                    wall = time.perf_counter() - t0
                    if compiled:
                        best_co = min(best_co, wall)
                    else:
                        best_py = min(best_py, wall)
            a, b = runs[False], runs[True]
            same = same and all(
                (x is None and y is None) or (x is not None and y is not None and x.shape == y.shape and x.tobytes() == y.tobytes())
                for x, y in ((np.asarray(a.x), np.asarray(b.x)), (a.u, b.u), (a.sigma, b.sigma), (a.chi_hat, b.chi_hat))
            ) and (a.reason, a.diverged_at_s) == (b.reason, b.diverged_at_s)
        rtf_py = sc.duration_s / best_py
        rtf_co = sc.duration_s / best_co
        note = "" if on else "  (compiled path off: both are CPython)"
        print(f"  {name:<18} {rtf_py:8.1f}× {rtf_co:9.0f}× {best_py / best_co:7.0f}×   {first:6.2f} s"
              f"{'' if same else '  TRAJECTORIES DIFFER'}{note}")  # fmt: skip
    if on:
        print("\n  real-time factors (simulated s per wall s); ratio = compiled/CPython speed; the first compiled call compiles the"
              " runner for a law family (PID-SMC flavours share one) or loads it from the disk cache, then flies 1 ms")
        print(f"  first calls this process (s): {', '.join(f'{f} {m} {s:.2f}' for (f, m), s in fast_paper.FIRST_CALL_S.items())}")
    print("  goal: compiled ≥ 30× the CPython path per controller")
    return 0


def _add_sitl(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("sitl", help="SITL speed: two processes over UDP vs the in-process ceiling; real-time lateness")
    c.add_argument("--duration", type=float, default=60.0, metavar="SIM_S", help="lockstep flight length (default 60)")
    c.add_argument("--realtime-s", type=float, default=60.0, metavar="S", help="real-time run length, wall seconds (default 60; 0 skips it)")
    c.add_argument("--controller", default="adaptive_pid_smc", choices=("adaptive_pid_smc", "pid_smc", "cascade_pid"))
    c.add_argument("--repeat", type=int, default=2, metavar="N",
                   help="lockstep runs per variant (raw UDP; all CPython; the FC's pipeline compiled; and the simulator's physics too),"
                        " alternating; the best is printed (default 2)")
    c.set_defaults(bench=bench_sitl)


#: the echo process of :func:`raw_udp_round_trip_us`: answers every datagram to its sender.
_ECHO = """
import socket, sys
spin = sys.argv[1] == "spin"
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
s.setblocking(not spin)
print(s.getsockname()[1], flush=True)
while True:
    try:
        data, addr = s.recvfrom(2048)
    except BlockingIOError:
        continue
    if data == b"stop":
        break
    s.sendto(data, addr)
"""


def _recv_blocking(s: Any) -> None:
    s.recvfrom(2048)


def _recv_spinning(s: Any) -> None:
    while True:
        try:
            s.recvfrom(2048)
            return
        except BlockingIOError:
            continue


def raw_udp_round_trip_us(n: int = 20000, size: int = 80, *, spin: bool = False) -> float:
    """Mean wall time of a round trip of a ``size``-byte datagram between this process and an echo
    process on 127.0.0.1 (plain sockets, no codec; ``spin``: both sides poll without blocking, as
    the lockstep FC and simulator do, else blocking reads): the limit of any two-process lockstep
    in Python on this machine now. µs."""
    import socket
    import subprocess

    echo = subprocess.Popen([sys.executable, "-c", _ECHO, "spin" if spin else "block"], stdout=subprocess.PIPE, text=True)
    try:
        assert echo.stdout is not None
        port = int(echo.stdout.readline())
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            peer = ("127.0.0.1", port)
            payload = bytes(size)
            if spin:
                s.setblocking(False)
                recv: Callable[[Any], object] = _recv_spinning
            else:
                s.settimeout(5.0)
                recv = _recv_blocking
            for _ in range(200):  # warm up
                s.sendto(payload, peer)
                recv(s)
            t0 = time.perf_counter()
            for _ in range(n):
                s.sendto(payload, peer)
                recv(s)
            dt = time.perf_counter() - t0
            s.sendto(b"stop", peer)
    finally:
        try:
            echo.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            echo.kill()
    return dt / n * 1e6


def bench_sitl(args: argparse.Namespace) -> int:
    import tempfile
    from pathlib import Path

    from fc.config import FcConfig
    from ground.sitl import Sitl, SitlOptions
    from ground.sitl_cmd import demo_plan_path
    from lab.runner import fly
    from sim_bridge.plants.rigid_body import RigidBodyPlant
    from smcpilot.plan import load_plan
    from smcpilot.vehicle import DEFAULT_VEHICLE

    if not args.duration > 0 or args.realtime_s < 0:
        raise ConfigError("--duration must be > 0 and --realtime-s >= 0")
    plan_path = demo_plan_path()
    plan = load_plan(plan_path)
    print(f"smcpilot bench sitl — Python {platform.python_version()}, {args.controller}, 1 kHz physics, 500 Hz control,"
          f" rigid-body plant, demo plan ({args.duration:g} s)")  # fmt: skip
    _bench_codec()
    _bench_physics()

    cfg = FcConfig(controller=args.controller)
    plant = RigidBodyPlant(DEFAULT_VEHICLE)
    t0 = time.perf_counter()
    fly(cfg, DEFAULT_VEHICLE, plant, plan, args.duration, fast=False)  # CPython, as the two processes tick
    inproc = time.perf_counter() - t0
    ceiling = args.duration / inproc
    print(f"\nin-process loop in CPython (FC pipeline + plant, no MAVLink): {ceiling:6.1f}× real time ({inproc * 1e6 / (args.duration * 500):.1f} µs per control tick;"
          " compiled: smcpilot bench fast)")  # fmt: skip

    # the FC's compiled pipeline, compiled (or loaded) here first so the FC processes find it cached
    from fc.compiled_pipeline import attach_compiled
    from fc.flight import FlightControl
    from sim_bridge.plants import compiled_physics

    why = attach_compiled(FlightControl(cfg, DEFAULT_VEHICLE), compile_new=True)
    _phys, why_phys = compiled_physics.load([plant], compile_new=True)
    # (name, the FC's --jit, the simulator's --jit)
    variants = [("all CPython (--jit off)", "off", "off")]
    if why is None:
        variants.append(("FC pipeline compiled", "wait", "off"))
    else:
        print(f"  (the FC's compiled pipeline is not available: {why})")
    if why_phys is None:
        variants.append(("FC pipeline + sim physics compiled" if why is None else "sim physics compiled", "wait" if why is None else "off", "wait"))
    else:
        print(f"  (the simulator's compiled physics is not available: {why_phys})")
    best: dict[str, float] = {}
    raw_us = raw_spin_us = math.inf
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(max(1, args.repeat)):  # alternating, so a machine that speeds up or slows down favours no one
            raw_us = min(raw_us, raw_udp_round_trip_us(spin=False))
            raw_spin_us = min(raw_spin_us, raw_udp_round_trip_us(spin=True))
            for name, jit, sim_jit in variants:
                opts = SitlOptions.of(lockstep=True, duration_s=args.duration, controller=args.controller, gcs=None,
                                   plan=plan_path, tlog=Path(tmp) / f"bench-{jit}-{sim_jit}-{rep}.tlog", fc_args=("--jit", jit),
                                   sim_args=("--jit", sim_jit))  # fmt: skip
                sitl = Sitl(opts)
                with sitl:
                    sitl.wait()
                speed = (sitl.sim_summary or {}).get("speed") or float("nan")
                if jit == "wait" and not (sitl.fc_summary or {}).get("pipeline", {}).get("compiled"):
                    print(f"  (run {rep + 1}: the FC flew its pipeline in CPython: {(sitl.fc_summary or {}).get('pipeline')})")
                if sim_jit == "wait" and not (sitl.sim_summary or {}).get("physics", {}).get("compiled"):
                    print(f"  (run {rep + 1}: the simulator stepped its physics in Python: {(sitl.sim_summary or {}).get('physics')})")
                best[name] = max(best.get(name, 0.0), speed)
        raw_speed = 2000.0 / raw_us
        print(f"raw Python UDP round trip, two processes, 80 bytes, no codec, blocking reads: {raw_us:6.1f} µs = {raw_speed:6.1f}× real time"
              " at 500 Hz (the baseline of the ratios below)\n"
              f"  the same, both sides polling without blocking (each takes a core):   {raw_spin_us:6.1f} µs = {2000.0 / raw_spin_us:6.1f}×")  # fmt: skip
        base = best.get(variants[0][0])
        for name, _jit, _sim_jit in variants:
            loop_speed = best[name]
            extra = f"; {loop_speed / base:.2f}× all CPython" if base and name != variants[0][0] else ""
            print(
                f"lockstep over UDP, two processes, {name + ':':<36} {loop_speed:6.1f}× real time"
                f" ({1e6 / (loop_speed * 500):.1f} µs per control tick; {loop_speed / raw_speed:.2f} of the raw UDP round trip,"
                f" {loop_speed / ceiling:.2f} of the in-process ceiling{extra})"
            )
        print(f"  best of {max(1, args.repeat)} alternating runs each; goal: ≥ 0.6 of the raw UDP round trip")
        if args.realtime_s > 0:
            opts = SitlOptions.of(lockstep=False, duration_s=args.realtime_s, controller=args.controller, gcs=None,
                               plan=plan_path, tlog=Path(tmp) / "bench-rt.tlog")  # fmt: skip
            print(f"\nreal time, {args.realtime_s:g} s at 500 Hz (takes {args.realtime_s:g} s) ...", flush=True)
            sitl = Sitl(opts)
            with sitl:
                # beside the flight, a loop that only waits for the same deadlines: its stalls are the machine's
                floor_proc = subprocess.Popen([sys.executable, "-m", "lab.timer_floor", f"{max(1.0, args.realtime_s - 1.0):g}"],
                                              stdout=subprocess.PIPE, text=True)  # fmt: skip
                sitl.wait(timeout_s=args.realtime_s + 60)
                floor_out, _ = floor_proc.communicate(timeout=120)
            fcs = sitl.fc_summary or {}
            ticks = fcs.get("ticks", 0)
            p50 = fcs.get("lateness_p50_s")
            p99 = fcs.get("lateness_p99_s")
            mx = fcs.get("lateness_max_s")
            print(
                f"  {ticks} ticks, {fcs.get('overruns', 0)} missed deadlines"
                f" ({100.0 * fcs.get('overruns', 0) / max(ticks, 1):.2f} %), loop lateness p50 {_us(p50)},"
                f" p99 {_us(p99)}, max {_us(mx)} (period 2000 µs)"
            )
            _print_stalls(fcs, floor_out)
            pipe = fcs.get("pipeline") or {}
            print(f"  the FC's pipeline: {'compiled' if pipe.get('compiled') else 'CPython (' + str(pipe.get('why_not')) + ')'}")
            phys = (sitl.sim_summary or {}).get("physics") or {}
            print(f"  the simulator's physics: {'compiled' if phys.get('compiled') else 'Python (' + str(phys.get('why_not')) + ')'}")
    return 0


def _print_stalls(fcs: dict, floor_out: str) -> None:
    """Where the FC's late ticks came from: the garbage collector's passes, and the stalls of a
    bare loop in its own process at the same moments (the machine's)."""
    from lab.timer_floor import coincident

    st = fcs.get("stalls") or {}
    gcs = fcs.get("gc") or {}
    at, late = st.get("at_s") or [], st.get("late_s") or []
    try:
        floor = json.loads(floor_out.strip().splitlines()[-1])
    except (ValueError, IndexError):
        floor = None
    thr = 1e3 * float(st.get("threshold_s") or 0.001)
    by_gc = coincident(at, late, gcs.get("long_at_s") or [], gcs.get("long_s") or [])
    cols = gcs.get("collections") or [0, 0, 0]
    print(f"  stalls (ticks ≥ {thr:g} ms late): the FC {st.get('count', 0)}; during a garbage collection {by_gc}"
          f" (collections {'/'.join(str(c) for c in cols)} by generation, longest {1e3 * float(gcs.get('max_s') or 0.0):.2f} ms)")  # fmt: skip
    if floor is None:
        print("  the bare loop beside it gave no figures")
        return
    fst = floor["stalls"]
    same = coincident(at, late, fst["at_s"], fst["late_s"])
    steal = floor.get("steal_share")
    print(f"  a bare {1.0 / floor['period_s']:g} Hz loop beside it, computing nothing: {fst['count']} stalls, {floor['missed']} missed"
          f" of {floor['ticks']} ({100.0 * floor['missed'] / max(1, floor['ticks']):.2f} %), p99 {_us(floor['lateness_p99_s'])};"
          f" of the FC's {len(at)} stalls with times, {same} at the same moments as the bare loop's (the machine's)"
          + (f"; CPU steal {100.0 * steal:.1f} % of the machine's time" if steal is not None else ""))  # fmt: skip


def _us(v: float | None) -> str:
    return "n/a" if v is None else f"{v * 1e6:.0f} µs"


def _bench_physics(repeat: int = 5) -> None:
    """The simulator's physics for one control period (two 1 ms steps) of 1 and 16 vehicles: the
    plants' Python steps against the compiled span (:mod:`sim_bridge.plants.compiled_physics`),
    alternating in this process."""
    from sim_bridge.plants import compiled_physics
    from sim_bridge.plants.rigid_body import RigidBodyPlant
    from smcpilot.vehicle import DEFAULT_VEHICLE

    print("\nthe simulator's physics per control period (2 × 1 ms steps, hovering rotors), µs:")
    cmd = (0.6, 0.6, 0.6, 0.6)
    for k in (1, 16):
        py = [RigidBodyPlant(DEFAULT_VEHICLE) for _ in range(k)]
        co = [RigidBodyPlant(DEFAULT_VEHICLE) for _ in range(k)]
        phys, why = compiled_physics.load(co, compile_new=True)
        if phys is None:
            print(f"  (compiled physics not available: {why})")
            return
        cmds, armed = [cmd] * k, [True] * k

        def python_period(py: list = py) -> None:
            for step in range(2):
                for p in py:
                    p.step(step * 1e-3, 1e-3, cmd, True)

        def compiled_period(co: list = co, cmds: list = cmds, armed: list = armed, fly: Any = phys.fly) -> None:
            fly(co, cmds, armed, 0, 1000, 1e-3, 2)

        n = 2000 if k == 1 else 200
        t_py = t_co = math.inf
        for _ in range(repeat):
            t_py = min(t_py, _best_us(python_period, n, 1))
            t_co = min(t_co, _best_us(compiled_period, n, 1))
        print(f"  {k:>2} vehicle{'s' if k > 1 else ' '}  Python {t_py:7.1f}   compiled {t_co:6.1f}   ({t_py / t_co:.1f}×)")


def _bench_codec() -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from smcpilot import fastcodec

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    dec = mavlink.MAVLink(None)
    msgs = {
        "ATTITUDE": mav.attitude_encode(1000, 0.1, -0.2, 1.3, 0.01, 0.02, -0.03),
        "LOCAL_POSITION_NED": mav.local_position_ned_encode(1000, 1.0, -2.0, -3.0, 0.1, 0.2, 0.3),
        "HIL_ACTUATOR_CONTROLS": mav.hil_actuator_controls_encode(10**6, [0.5, 0.51, 0.49, 0.5] + [0.0] * 12, 128, 1),
    }
    print("\nMAVLink codec per message (pymavlink → fast path, µs):")
    for name, m in msgs.items():
        pkt = m.pack(mav)
        enc_slow = _best_us(functools.partial(m.pack, mav), 20000, 5)
        enc_fast = _best_us(functools.partial(fastcodec.pack_message, m, 0, 1, 1), 20000, 5)
        dec_slow = _best_us(lambda pkt=pkt: dec.decode(bytearray(pkt)), 20000, 5)  # type: ignore[misc]
        dec_fast = _best_us(functools.partial(fastcodec.decode_packet, pkt), 20000, 5)
        print(f"  {name:<22} encode {enc_slow:5.2f} → {enc_fast:4.2f} ({enc_slow / enc_fast:.1f}×)"
              f"   decode {dec_slow:5.2f} → {dec_fast:4.2f} ({dec_slow / dec_fast:.1f}×)")  # fmt: skip


def _add_campaign(sub: argparse._SubParsersAction) -> None:
    from lab.campaign import bench as campaign_bench

    campaign_bench.add_arguments(sub)


def _add_soak(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("soak", help="random missions, faults and lossy links in lockstep SITL for hours: crashes, logs, memory trend")
    c.add_argument("--sim-hours", type=float, default=1.0, metavar="H", help="simulated hours to fly (default 1)")
    c.add_argument("--segment-s", type=float, default=600.0, metavar="SIM_S",
                   help="simulated seconds per SITL run (a fresh pair of processes; default 600)")
    c.add_argument("--seed", type=int, default=0, help="seed of the random missions, faults and impairments (default 0)")
    c.add_argument("--sample-s", type=float, default=1.0, metavar="S", help="wall seconds between memory samples (default 1)")
    c.add_argument("--speed", type=float, default=None, metavar="FACTOR", help="pace the simulation at most FACTOR x real time")
    c.add_argument("--keep-logs", type=Path, default=None, metavar="DIR", help="keep the logs here (default: deleted once checked)")
    c.set_defaults(bench=bench_soak)


def bench_soak(args: argparse.Namespace) -> int:
    from lab.soak import SoakConfig, report, run_soak

    cfg = SoakConfig(sim_hours=args.sim_hours, segment_s=args.segment_s, seed=args.seed, sample_s=args.sample_s,
                     keep_logs=args.keep_logs, speed=args.speed)  # fmt: skip
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    print(f"smcpilot bench soak — {cfg.sim_hours:g} simulated h in {len(cfg.segments)} lockstep SITL runs, seed {cfg.seed};"
          f" Python {platform.python_version()}, machine load {load[0]:.2f} on {os.cpu_count()} cores")  # fmt: skip
    return report(cfg, run_soak(cfg))


def _add_flood(sub: argparse._SubParsersAction) -> None:
    from lab import flood

    flood.add_arguments(sub)


_EXTRA_TARGETS: list[Callable[[argparse._SubParsersAction], None]] = [_add_paper, _add_sitl, _add_campaign, _add_soak, _add_flood]


def main(args: argparse.Namespace) -> int:
    sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    return int(args.bench(args))


def _lazy(module: str, add: str = "add_arguments") -> Callable[[argparse._SubParsersAction], None]:
    """A bench target whose module is imported only when the command line is built."""

    def register(sub: argparse._SubParsersAction) -> None:
        getattr(importlib.import_module(module), add)(sub)

    return register


_EXTRA_TARGETS.extend([
    _lazy("lab.fast.bench"),  # bench fast
    _lazy("lab.fast.bench", "add_batch_arguments"),  # bench batch
    _lazy("lab.swarm_bench"),  # bench swarm
    _lazy("lab.realtime_bench"),  # bench realtime
])  # fmt: skip
