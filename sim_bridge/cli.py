"""Command line of the simulator-bridge process (``python -m sim_bridge``)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from sim_bridge.app import BridgeTiming, SimBridgeApp, install_signal_handlers
from sim_bridge.build import make_plant, plant_for
from sim_bridge.proximity import Proximity
from smcpilot.errors import ConfigError, SmcpilotError
from smcpilot.jit import AUTO_MIN_LOCKSTEP_S, JIT_POLICIES
from smcpilot.scenario import PLANTS, EnvironmentSpec, Scenario
from smcpilot.vehicle import DEFAULT_VEHICLE, VehicleParams

EXIT_CONFIG = 2

def _triple(text: str) -> tuple[float, float, float]:
    try:
        parts = tuple(float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers N,E,D, got {text!r}") from None
    if len(parts) != 3 or not all(math.isfinite(v) for v in parts):
        raise argparse.ArgumentTypeError(f"expected three finite numbers N,E,D, got {text!r}")
    return parts  # type: ignore[return-value]


def build_parser() -> argparse.ArgumentParser:
    t = BridgeTiming()
    p = argparse.ArgumentParser(
        prog="python -m sim_bridge",
        description="Simulator bridge: integrates the quadrotor and exchanges MAVLink with the flight controller"
        " (state out as ATTITUDE + LOCAL_POSITION_NED, motor commands in as HIL_ACTUATOR_CONTROLS).",
    )
    p.add_argument("--fc", action="append", default=None, metavar="URL",
                   help="flight controller's simulator port (default udp:127.0.0.1:14560); a swarm scenario takes one"
                   " --fc per vehicle, in the order of its vehicles")  # fmt: skip
    p.add_argument("--plant", choices=PLANTS, default="rigid-body",
                   help="rigid-body (default: 6-DOF, motor lag and limits) or paper (the corrected eq. 10 model, ideal actuators)")
    p.add_argument("--vehicle", type=Path, metavar="FILE", help="vehicle TOML (default: the spec's parameters)")
    p.add_argument("--physics-hz", type=float, default=t.physics_hz, metavar="HZ", help=f"physics rate (default {t.physics_hz:g})")
    p.add_argument("--rate-hz", type=float, default=t.rate_hz, metavar="HZ", help=f"state message rate = FC control rate (default {t.rate_hz:g})")
    p.add_argument("--lockstep", action="store_true", help="advance only when the FC answers each state (deterministic)")
    p.add_argument("--speed", type=float, metavar="FACTOR", help="lockstep: at most FACTOR x real time; real time: clock speed (default 1)")
    p.add_argument("--duration", type=float, metavar="SIM_S", help="stop after this many simulated seconds")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise and gust random streams (default 0)")
    p.add_argument("--noise", action="store_true", help="add sensor noise (0.002 rad, 0.01 rad/s, 0.01 m, 0.02 m/s 1-sigma)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="K", help="multiply the --noise levels by K")
    p.add_argument("--wind-force", type=_triple, metavar="N,E,D", help="constant wind force on the vehicle, newtons, NED")
    p.add_argument("--gust-std", type=float, default=0.0, metavar="N", help="horizontal gust force std, newtons (0: none)")
    p.add_argument("--gust-tau", type=float, default=1.0, metavar="S", help="gust correlation time (default 1 s)")
    p.add_argument("--paper-disturbance", action="store_true", help="add the paper's disturbances fs1..fs4")
    p.add_argument("--watchdog-s", type=float, default=t.watchdog_s, metavar="S", help=f"exit if the FC is silent this long (default {t.watchdog_s:g})")
    p.add_argument("--spin-s", type=float, default=t.spin_s, metavar="S",
                   help=f"lockstep: busy-poll this long for the answers before blocking (default {t.spin_s:g}; 0: always block)")
    p.add_argument("--startup-timeout-s", type=float, default=t.startup_timeout_s, metavar="S", help="exit if the FC never answers within this many seconds (default 30)")
    p.add_argument("--scenario", type=Path, metavar="FILE",
                   help="scenario TOML (smcpilot.scenario): plant, vehicle, environment, faults, seed and rates come from it"
                   " (their flags are then ignored)")
    p.add_argument("--jit", choices=JIT_POLICIES, default="auto",
                   help="the physics compiled with numba (the same states bit for bit; spans with gusts or a timed fault due"
                        " are stepped in Python): auto (when cached, in real time and in lockstep flights of"
                        f" {AUTO_MIN_LOCKSTEP_S:g} vehicle-seconds or more or open-ended; not cached: Python, compiling it in the background"
                        " for the next runs), wait (always; compile it first if need be: a few seconds once), off (Python);"
                        " SMCPILOT_JIT=0 also turns it off (default auto)")  # fmt: skip
    p.add_argument("--sysid", type=int, default=1, metavar="N", help="MAVLink system id of the vehicle (default 1)")
    return p


def build_plant(args: argparse.Namespace, vehicle: VehicleParams):
    """The plant the command line describes (built as a scenario's is: :mod:`sim_bridge.build`)."""
    for flag, value, ok in (("--noise-scale", args.noise_scale, args.noise_scale >= 0), ("--gust-std", args.gust_std, args.gust_std >= 0),
                            ("--gust-tau", args.gust_tau, args.gust_tau > 0)):  # fmt: skip
        if not ok:  # (NaN fails every comparison)
            raise ConfigError(f"{flag} must be {'> 0' if flag == '--gust-tau' else '>= 0'}, got {value:g}")
    env = EnvironmentSpec(
        noise=args.noise, noise_scale=args.noise_scale,
        wind_force_ned_n=tuple(args.wind_force) if args.wind_force else (0.0, 0.0, 0.0),
        gust_std_n=args.gust_std, gust_tau_s=args.gust_tau, paper_disturbance=args.paper_disturbance,
    )  # fmt: skip
    return make_plant(args.plant, vehicle, env, args.seed)


def swarm_app(scenario: Scenario, fc_urls: Sequence[str], timing: BridgeTiming, *, jit: str = "off", freeze_gc: bool = False) -> SimBridgeApp:
    """The bridge of a swarm scenario: every vehicle's plant (its own seed, faults, spawn) on one clock."""
    fleet = scenario.fleet()
    if len(fc_urls) != len(fleet):
        raise ConfigError(f"the scenario flies {len(fleet)} vehicles: give one --fc per vehicle, got {len(fc_urls)}")
    swarm = scenario.swarm
    assert swarm is not None
    contact = swarm.contact_m if swarm.contact_m is not None else 2.0 * scenario.vehicle.arm_length_m
    return SimBridgeApp(
        timing=timing,
        vehicles=[(plant_for(v.scenario), url, v.sysid, v.offset_ne_m) for v, url in zip(fleet, fc_urls)],
        proximity=Proximity(len(fleet), swarm.separation_m, contact),
        lost=swarm.lost,
        jit=jit,
        freeze_gc=freeze_gc,
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        vehicle = VehicleParams.from_toml(args.vehicle) if args.vehicle else DEFAULT_VEHICLE
        scenario = Scenario.from_toml(args.scenario) if args.scenario is not None else None
        if scenario is not None:
            args.physics_hz, args.rate_hz, vehicle = scenario.physics_hz, scenario.rate_hz, scenario.vehicle
        if not (math.isfinite(args.spin_s) and 0.0 <= args.spin_s <= 1.0):
            raise ConfigError(f"--spin-s must be a number of seconds in [0, 1], got {args.spin_s}")
        if not (args.physics_hz > 0 and args.rate_hz > 0):
            raise ConfigError("--physics-hz and --rate-hz must be > 0")
        ratio = args.physics_hz / args.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(f"--physics-hz ({args.physics_hz:g}) must be a whole multiple of --rate-hz ({args.rate_hz:g})")
        if args.rate_hz > 1000:
            raise ConfigError("--rate-hz must be at most 1000 (state time stamps are in milliseconds)")
        if args.speed is not None and not args.speed > 0:
            raise ConfigError("--speed must be > 0")
        if args.duration is not None and not args.duration > 0:
            raise ConfigError("--duration must be > 0")
        timing = BridgeTiming(
            physics_hz=args.physics_hz,
            rate_hz=args.rate_hz,
            lockstep=args.lockstep,
            speed=args.speed,
            duration_s=args.duration,
            watchdog_s=args.watchdog_s,
            startup_timeout_s=args.startup_timeout_s,
            spin_s=args.spin_s,
        )
        fc_urls = args.fc or ["udp:127.0.0.1:14560"]
        if scenario is not None and scenario.swarm is not None:
            app = swarm_app(scenario, fc_urls, timing, jit=args.jit, freeze_gc=True)
        else:
            if len(fc_urls) != 1:
                raise ConfigError(f"{len(fc_urls)} --fc links for one vehicle (a swarm scenario takes one per vehicle)")
            plant = plant_for(scenario) if scenario is not None else build_plant(args, vehicle)
            app = SimBridgeApp(plant, fc_url=fc_urls[0], timing=timing, system_id=args.sysid, jit=args.jit, freeze_gc=True)
    except (SmcpilotError, OSError) as exc:
        print(f"sim_bridge: error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    install_signal_handlers(app)
    return app.run()
