"""Our simulator as the physics back-end of another autopilot: what the two servers share.

``smcpilot sim --serve ardupilot-json[:PORT]`` (:mod:`sim_bridge.serve_ardupilot`, ArduPilot's JSON
interface, ``--model JSON``) and ``smcpilot sim --serve px4[:PORT]`` (:mod:`sim_bridge.serve_px4`,
PX4's simulator MAVLink API) fly the plant a scenario describes, built by :mod:`sim_bridge.build`
exactly as for our own flight controller: the same vehicle, environment, noise, gusts and faults.
Both are lockstep: the autopilot's motor message steps the physics, the answer carries the state.

What they share (here): the plant factory, the IMU an autopilot expects (gyro and specific force in
body FRD), bad input counted with rate-limited messages (:class:`Complaints`), the watchdog, the
clean stop on SIGINT/SIGTERM with a one-line summary (``SIM_SUMMARY {json}``), the announcements of
fault starts and stops (printed: neither protocol has a channel for them), the physics step with
its log (:meth:`ServerBase.step_plant`: the served flight's ``.tlog``, :mod:`sim_bridge.serve_log`,
which ``smcpilot log summary`` scores), and the command line.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from sim_bridge.build import plant_for
from sim_bridge.plants.paper_vehicle import PaperVehiclePlant
from sim_bridge.plants.rigid_body import RigidBodyPlant
from sim_bridge.serve_log import ServedLog
from smcpilot.complaints import Complaints
from smcpilot.errors import ConfigError, DivergenceError, WatchdogError
from smcpilot.scenario import Scenario

#: the protocols served and their conventional ports.
DEFAULT_PORTS = {"ardupilot-json": 9002, "px4": 4560}
EXIT_OK = 0
EXIT_CONFIG = 2
EXIT_WATCHDOG = 3
EXIT_DIVERGED = 4
WARNING = 4  # MAV_SEVERITY_WARNING

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class ServeOptions:
    """Where to listen and when to give up (wall seconds; None or 0: never)."""

    kind: str
    host: str = "127.0.0.1"
    port: int = 9002
    duration_s: float | None = None
    watchdog_s: float = 10.0
    startup_timeout_s: float | None = None
    #: ArduPilot: the motor PWM range (ArduCopter's MOT_PWM_MIN / MOT_PWM_MAX).
    pwm_min: int = 1000
    pwm_max: int = 2000
    #: PX4: sensor (and step) rate, Hz.
    rate_hz: float = 250.0
    #: the served flight's log (:mod:`sim_bridge.serve_log`); None: none.
    tlog: Path | None = None


def parse_serve(text: str) -> tuple[str, int]:
    """``ardupilot-json[:PORT]`` or ``px4[:PORT]`` -> (kind, port); port 0 takes a free one."""
    kind, _, port_text = text.partition(":")
    if kind not in DEFAULT_PORTS:
        raise ConfigError(f"--serve must be ardupilot-json[:PORT] or px4[:PORT], got {text!r}")
    if not port_text:
        return kind, DEFAULT_PORTS[kind]
    if not port_text.isdigit() or int(port_text) > 65535:
        raise ConfigError(f"--serve {kind}: the port must be a number in [0, 65535], got {port_text!r}")
    return kind, int(port_text)


class ServerBase:
    """The plant, the clean stop, the summary; a server implements :meth:`_serve` and :meth:`counters`."""

    name = "sim"

    def __init__(self, scenario: Scenario, options: ServeOptions, *, out: TextIO = sys.stdout,
                 monotonic: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.scenario = scenario
        self.options = options
        self.out = out
        self._mono = monotonic
        self.plant: RigidBodyPlant | PaperVehiclePlant = plant_for(scenario)
        self.gravity = scenario.vehicle.gravity_mps2
        self.complaints = Complaints(self.say, self.name, monotonic)
        self._stop = False
        self._wall_start = monotonic()
        self.restarts = 0
        #: sensor values that were NaN (a dropout) where the protocol cannot say "not measured".
        self.held_values = 0
        #: the served flight's log, if one is written (opened when serving starts).
        self.log: ServedLog | None = None

    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def restart_plant(self, why: str, step_s: float) -> None:
        """A fresh vehicle at rest, as the scenario describes it (the autopilot restarted: ``why``);
        in the log, its time goes on ``step_s`` after the last state."""
        self.plant = plant_for(self.scenario)
        self.restarts += 1
        if self.log is not None:
            self.log.restarted(int(round(step_s * 1e6)))
            self.log.event(self.log.stamp_us(0.0), WARNING, why)

    def announce_faults(self) -> None:
        faults = self.plant.faults
        if faults is not None and faults.events:
            log = self.log
            for ev in faults.take_events():
                self.say(f"{self.name}: t = {ev.t_s:.3f} s: {ev.text}")
                if log is not None:
                    log.event(log.stamp_us(ev.t_s), ev.severity, ev.text)

    def step_plant(self, t_s: float, dt_s: float, commands: tuple[float, float, float, float], armed: bool, lockstep: bool) -> None:
        """One physics step from ``t_s`` (the plant's time now) of ``dt_s`` with these motor
        commands, logged: the commands, the fault events, the state after the step."""
        plant = self.plant
        log = self.log
        if log is not None:
            log.commands_flown(log.stamp_us(t_s), commands, armed, lockstep)
        plant.step(t_s, dt_s, commands, armed)
        self.announce_faults()
        self.log_state()

    def log_state(self) -> None:
        """Log the state now (if a log is written and it is not logged yet). Observing the state
        draws the sensors' noise once a step: the protocol observes it too, the same draw."""
        if self.log is not None:
            self.log.state(self.plant, self.gravity)
            self.announce_faults()  # (those of observing it)

    def duration_reached(self) -> bool:
        d = self.options.duration_s
        return d is not None and self.plant.t_s >= d - 1e-9

    def check_silence(self, last_heard: float | None, what: str) -> None:
        """Raise :class:`WatchdogError` if the peer has been silent too long (None: never heard)."""
        now = self._mono()
        if last_heard is None:
            limit = self.options.startup_timeout_s
            if limit and now - self._wall_start > limit:
                raise WatchdogError(f"no {what} within {limit:g} s of starting (startup timeout); stopping")
            return
        limit = self.options.watchdog_s
        if limit and now - last_heard > limit:
            raise WatchdogError(f"no {what} for {now - last_heard:.1f} s (watchdog {limit:g} s): the autopilot has stopped; stopping")

    def counters(self) -> dict[str, Any]:  # pragma: no cover - each server's own
        raise NotImplementedError

    def _serve(self) -> None:  # pragma: no cover - each server's own
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - each server's own
        raise NotImplementedError

    def run(self) -> int:
        """Serve until stopped (signal, duration, watchdog); print the summary; the exit code.
        Raises :class:`smcpilot.errors.TlogError` before serving if the log cannot be written."""
        if self.options.tlog is not None:
            self.log = ServedLog(self.options.tlog, self.options.kind)
        code = EXIT_OK
        try:
            self._serve()
        except WatchdogError as exc:
            self.say(f"{self.name}: error: {exc}")
            code = EXIT_WATCHDOG
        except (ArithmeticError, DivergenceError) as exc:
            self.say(f"{self.name}: error: the simulation diverged at t = {self.plant.t_s:.3f} s: {exc}")
            code = EXIT_DIVERGED
        finally:
            self.close()
            if self.log is not None:
                self.log.close()
                self.say(f"{self.name}: log {self.log.path} ({self.log.states} states); its score: smcpilot log summary {self.log.path}"
                         " [--setpoints AUTOPILOT.tlog]")  # fmt: skip
            wall = self._mono() - self._wall_start
            faults = self.plant.faults
            summary = {
                "serve": self.options.kind,
                "sim_time_s": round(self.plant.t_s, 6),
                "wall_s": round(wall, 3),
                "restarts": self.restarts,
                "bad_input": dict(self.complaints.counts),
                "held_values": self.held_values,
                "faults_started": faults.started if faults is not None else 0,
                "faults_stopped": faults.stopped if faults is not None else 0,
                "tlog": str(self.log.path) if self.log is not None else None,
                **self.counters(),
            }
            self.say("SIM_SUMMARY " + json.dumps(summary, sort_keys=True))
        return code


def install_signal_handlers(server: ServerBase) -> None:
    signal.signal(signal.SIGTERM, server.request_stop)
    signal.signal(signal.SIGINT, server.request_stop)


# -- command line (``smcpilot sim``) ---------------------------------------------------------------
def _seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a number of seconds >= 0, got {text!r}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--serve", required=True, metavar="PROTOCOL[:PORT]",
                   help="ardupilot-json (ArduPilot SITL --model JSON; UDP, default port 9002) or px4 (PX4's simulator"
                   " MAVLink API; TCP, default port 4560); port 0 takes a free one (printed)")  # fmt: skip
    p.add_argument("--scenario", type=Path, metavar="FILE", help="scenario TOML: vehicle, plant, environment, seed and faults (default: the default vehicle, clean)")
    p.add_argument("--listen", default="127.0.0.1", metavar="HOST", help="address to listen on (default 127.0.0.1; 0.0.0.0 for an autopilot on another machine)")
    p.add_argument("--duration", type=_seconds, metavar="SIM_S", help="stop after this many simulated seconds")
    p.add_argument("--watchdog-s", type=_seconds, default=10.0, metavar="S", help="stop with an error when the autopilot has been silent this long once it has started (default 10; 0: never)")
    p.add_argument("--startup-timeout-s", type=_seconds, metavar="S", help="stop with an error when no autopilot has come within this long (default: wait until stopped)")
    p.add_argument("--pwm-min", type=int, default=1000, metavar="US", help="ardupilot-json: PWM of a stopped motor, MOT_PWM_MIN (default 1000)")
    p.add_argument("--pwm-max", type=int, default=2000, metavar="US", help="ardupilot-json: PWM of a motor at full thrust, MOT_PWM_MAX (default 2000)")
    p.add_argument("--rate-hz", type=float, default=250.0, metavar="HZ", help="px4: the sensor rate, one physics step of 1/HZ per HIL_ACTUATOR_CONTROLS (default 250)")
    log = p.add_mutually_exclusive_group()
    log.add_argument("--tlog", type=Path, metavar="FILE",
                     help="the served flight's log: every state (sensed and true), every motor command, the faults;"
                     " `smcpilot log summary FILE` scores it (default logs/serve-PROTOCOL-DATE-TIME-PID.tlog, the scenario beside it)")  # fmt: skip
    log.add_argument("--no-tlog", action="store_true", help="write no log")


def options_from_args(args: argparse.Namespace) -> ServeOptions:
    kind, port = parse_serve(args.serve)
    if not 0 < args.pwm_min < args.pwm_max <= 3000:
        raise ConfigError(f"--pwm-min and --pwm-max must satisfy 0 < min < max <= 3000, got {args.pwm_min} and {args.pwm_max}")
    if not (math.isfinite(args.rate_hz) and 1.0 <= args.rate_hz <= 2000.0):
        raise ConfigError(f"--rate-hz must lie in [1, 2000], got {args.rate_hz:g}")
    if args.no_tlog:
        tlog = None
    elif args.tlog is not None:
        tlog = args.tlog
        if tlog.is_dir():
            raise ConfigError(f"--tlog {tlog}: a directory, not a file")
    else:
        tlog = Path("logs") / time.strftime(f"serve-{kind}-%Y%m%d-%H%M%S-{os.getpid()}.tlog")
    return ServeOptions(
        kind=kind, host=args.listen, port=port, duration_s=args.duration or None, watchdog_s=args.watchdog_s,
        startup_timeout_s=args.startup_timeout_s or None, pwm_min=args.pwm_min, pwm_max=args.pwm_max, rate_hz=args.rate_hz,
        tlog=tlog,
    )  # fmt: skip


def make_server(scenario: Scenario, options: ServeOptions, *, out: TextIO = sys.stdout) -> ServerBase:
    """The server of ``options.kind``, bound to its port (raises OSError if the port is taken)."""
    if options.kind == "px4":
        from sim_bridge.serve_px4 import Px4Server

        return Px4Server(scenario, options, out=out)
    from sim_bridge.serve_ardupilot import ArduPilotJsonServer

    return ArduPilotJsonServer(scenario, options, out=out)


def main(args: argparse.Namespace) -> int:
    """``smcpilot sim``: serve until Ctrl-C / SIGTERM (exit 0), the duration, or the watchdog (exit 3)."""
    options = options_from_args(args)
    scenario = Scenario.from_toml(args.scenario) if args.scenario is not None else Scenario()
    try:
        server = make_server(scenario, options)
    except OSError as exc:
        raise ConfigError(f"cannot listen on {options.host}:{options.port}: {exc.strerror or exc}") from None
    if options.tlog is not None:  # the flight can be served again: the scenario beside its log
        try:
            scenario.save(options.tlog.with_name(options.tlog.stem + ".scenario.toml"))
        except OSError as exc:
            server.close()
            raise ConfigError(f"--tlog {options.tlog}: cannot write beside it: {exc.strerror or exc}") from None
    install_signal_handlers(server)
    return server.run()
