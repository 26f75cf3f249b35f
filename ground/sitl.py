"""Launch SITL: the flight-controller and simulator-bridge processes, wired together on loopback.

:class:`Sitl` is a context manager: it starts ``python -m fc`` on a free port, reads the port the
FC bound from its first output line, starts ``python -m sim_bridge`` pointed at it, waits until
the FC has flown its first tick, and on exit (normal, Ctrl-C, SIGTERM or a child's death) stops
both children and waits for them: no orphan is left. Children also die with the launcher
(``PR_SET_PDEATHSIG`` on Linux) and stop on their own if their peer goes silent (watchdogs).

Children's output is read on background threads: lines the user wants (events, errors) are
echoed with a prefix, the machine-readable ``*_SUMMARY`` lines are parsed and kept.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TextIO

from smcpilot.errors import SmcpilotError
from smcpilot.geo import Home
from smcpilot.impair import parse_impairment
from smcpilot.plan import load_plan
from smcpilot.scenario import Scenario
from smcpilot.vehicle import VehicleParams

#: at the end of a run, how long the launcher waits for the other process to exit by itself (s);
#: one it then has to stop makes the run a failure.
END_GRACE_S = 5.0


class SitlError(SmcpilotError):
    """SITL could not start, or a child process failed."""


#: SitlOptions keywords that describe the flight (they build its Scenario).
SCENARIO_KEYWORDS = frozenset(
    {"controller", "seed", "plant", "rate_hz", "physics_hz", "vehicle", "plan", "home", "duration_s", "noise",
     "noise_scale", "wind_force_ned_n", "gust_std_n", "paper_disturbance", "sim_link", "gcs_link"}
)  # fmt: skip


@dataclass(frozen=True)
class SitlOptions:
    """What to launch: the flight (a :class:`~smcpilot.scenario.Scenario`) and how to launch it.

    Build with ``SitlOptions.of(scenario=..., lockstep=...)`` or, for the flat keywords of earlier
    versions and the pytest marker, :meth:`of` (``SitlOptions.of(controller="pid_smc", seed=3)``).
    """

    #: the flight: vehicle, plant, environment, seed, controller, rates, home, parameters, plan.
    scenario: Scenario = field(default_factory=Scenario)
    #: stop after the scenario's ``duration_s`` (False: run until stopped).
    timed: bool = False
    lockstep: bool = True
    speed: float | None = None
    gcs: str | None = "udp:127.0.0.1:14550"
    log_dir: Path = Path("logs")
    tlog: Path | None = None
    #: a parameter file to keep across runs (loaded, and saved to on PARAM_SET); None: the run
    #: starts from defaults and writes a file of its own beside the tlog.
    param_file: Path | None = None
    watchdog_s: float = 5.0
    #: MAVLink 2 signing of the FC's ground link: a key file (64 hex digits or a passphrase);
    #: None: unsigned. The signing timestamp is kept beside the log (``signing-timestamp``).
    signing_key: Path | None = None
    #: extra arguments for the FC / the bridge (advanced use, tests).
    fc_args: tuple[str, ...] = ()
    sim_args: tuple[str, ...] = ()

    @classmethod
    def of(cls, **kw: Any) -> SitlOptions:
        """Options from flat keywords: the flight's (:data:`SCENARIO_KEYWORDS`: ``vehicle`` and
        ``plan`` as file paths, ``home`` as ``"LAT,LON,ALT"``, ``duration_s`` None for "until
        stopped") and the launch's (the other fields). A ``scenario`` keyword is the base."""
        flight = {k: kw.pop(k) for k in list(kw) if k in SCENARIO_KEYWORDS}
        base: Scenario = kw.pop("scenario", None) or Scenario()
        duration = flight.pop("duration_s", None)
        changes: dict[str, Any] = {}
        if duration is not None:
            changes["duration_s"] = float(duration)
            kw.setdefault("timed", True)
        vehicle = flight.pop("vehicle", None)
        if vehicle is not None:
            changes["vehicle"] = VehicleParams.from_toml(vehicle)
            changes["vehicle_file"] = Path(vehicle)
        plan = flight.pop("plan", None)
        if plan is not None:
            changes["plan"] = load_plan(plan)
        home = flight.pop("home", None)
        if home is not None:
            h = Home.parse(home) if isinstance(home, str) else Home(*home)
            changes["home"] = (h.lat_deg, h.lon_deg, h.alt_m)
        env_keys = {"noise", "noise_scale", "wind_force_ned_n", "gust_std_n", "paper_disturbance"}
        env = {k: flight.pop(k) for k in list(flight) if k in env_keys}
        if env.get("wind_force_ned_n", 0) is None:
            env.pop("wind_force_ned_n")
        if env:
            if "wind_force_ned_n" in env:
                env["wind_force_ned_n"] = tuple(float(v) for v in env["wind_force_ned_n"])
            changes["environment"] = replace(base.environment, **env)
        for key in ("sim_link", "gcs_link"):  # "loss=0.2,delay_ms=4" or a LinkImpairment
            if isinstance(flight.get(key), str):
                flight[key] = parse_impairment(flight[key], f"--{key.replace('_', '-')}")
        changes.update(flight)
        return cls(scenario=replace(base, **changes) if changes else base, **kw)

    # The flat names of earlier versions, read-only (tests written against them keep working).
    @property
    def controller(self) -> str:
        return self.scenario.controller

    @property
    def seed(self) -> int:
        return self.scenario.seed

    @property
    def plant(self) -> str:
        return self.scenario.plant

    @property
    def rate_hz(self) -> float:
        return self.scenario.rate_hz

    @property
    def physics_hz(self) -> float:
        return self.scenario.physics_hz

    @property
    def duration_s(self) -> float | None:
        return self.scenario.duration_s if self.timed else None

    @property
    def vehicle(self) -> Path | None:
        return self.scenario.vehicle_file

    @property
    def noise(self) -> bool:
        return self.scenario.environment.noise

    @property
    def wind_force_ned_n(self) -> tuple[float, float, float]:
        return self.scenario.environment.wind_force_ned_n

    @property
    def gust_std_n(self) -> float:
        return self.scenario.environment.gust_std_n


def _pdeathsig() -> None:  # pragma: no cover - runs in the child
    """Ask Linux to SIGTERM this child when the launcher dies (best effort)."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:
        pass


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    lines: queue.Queue[str] = field(default_factory=queue.Queue)
    tail: list[str] = field(default_factory=list)
    summary: dict | None = None
    thread: threading.Thread | None = None


class Sitl:
    """Both SITL processes. Use ``with Sitl(options) as sitl: sitl.wait()``."""

    def __init__(self, options: SitlOptions, *, echo: Callable[[str], None] | None = None, python: str = sys.executable) -> None:
        self.options = options
        self.echo = echo if echo is not None else (lambda line: None)
        self.python = python
        self.fc: Child | None = None
        self.sim: Child | None = None
        self.sim_port: int | None = None
        self.gcs_address: str | None = None
        self.tlog: Path | None = None
        #: the scenario file both processes were started with (beside the tlog).
        self.scenario_file: Path | None = None
        self.started_wall = 0.0

    # -- start -----------------------------------------------------------------------------------
    def _spawn(self, name: str, args: list[str]) -> Child:
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        proc = subprocess.Popen(
            [self.python, "-m", *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            env=env,
            preexec_fn=_pdeathsig if sys.platform.startswith("linux") else None,
        )
        child = Child(name, proc)

        def pump() -> None:
            assert proc.stdout is not None
            for raw in proc.stdout:
                line = raw.rstrip("\n")
                child.tail.append(line)
                del child.tail[:-40]
                if line.startswith(("FC_SUMMARY ", "SIM_SUMMARY ")):
                    try:
                        child.summary = json.loads(line.split(" ", 1)[1])
                    except ValueError:
                        pass
                    continue
                child.lines.put(line)
                if not line.startswith(("FC_LISTENING", "SIM_READY", "FC_READY")):
                    self.echo(f"[{name}] {line}")

        child.thread = threading.Thread(target=pump, name=f"{name}-output", daemon=True)
        child.thread.start()
        return child

    def _await_line(self, child: Child, prefix: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise SitlError(f"{child.name} did not report {prefix!r} within {timeout_s:g} s{self._tail(child)}")
            try:
                line = child.lines.get(timeout=min(remaining, 0.1))
            except queue.Empty:
                if child.proc.poll() is not None:
                    if child.thread is not None:
                        child.thread.join(timeout=1.0)
                    raise SitlError(
                        f"{child.name} exited with code {child.proc.returncode} during start-up{self._tail(child)}"
                    ) from None
                continue
            if line.startswith(prefix):
                return line

    @staticmethod
    def _tail(child: Child) -> str:
        lines = [ln for ln in child.tail if not ln.startswith(("FC_SUMMARY", "SIM_SUMMARY"))][-8:]
        return (":\n  " + "\n  ".join(lines)) if lines else ""

    def start(self, ready_timeout_s: float = 30.0) -> Sitl:
        o = self.options
        if o.tlog is not None:
            tlog = o.tlog
        else:
            o.log_dir.mkdir(parents=True, exist_ok=True)
            tlog = o.log_dir / time.strftime(f"sitl-%Y%m%d-%H%M%S-{os.getpid()}.tlog")
        self.tlog = tlog
        sc = o.scenario
        # The flight goes to both processes as one file, kept beside the log: `smcpilot run FILE`
        # flies it again (in-process, or with --sitl as here).
        self.scenario_file = sc.save(tlog.with_name(tlog.stem + ".scenario.toml"))
        timed = ["--duration", repr(sc.duration_s)] if o.timed else []
        fc_args = ["fc", "--sim", "udpin:127.0.0.1:0", "--gcs", o.gcs or "none", "--scenario", str(self.scenario_file),
                   "--tlog", str(tlog), "--watchdog-s", f"{o.watchdog_s:g}"]  # fmt: skip
        if o.lockstep:
            fc_args.append("--lockstep")
        if o.param_file is not None:  # else the FC starts from defaults with a file of its own (NAME.parm)
            fc_args += ["--param-file", str(o.param_file)]
        fc_args += ["--signing-timestamps", str(tlog.parent / "signing-timestamp")]
        if o.signing_key is not None:
            fc_args += ["--signing-key", str(o.signing_key)]
        if o.lockstep:
            fc_args += timed
        fc_args += list(o.fc_args)
        self.started_wall = time.monotonic()
        self.fc = self._spawn("fc", fc_args)
        listening = self._await_line(self.fc, "FC_LISTENING", 20.0)
        fields = dict(part.split("=", 1) for part in listening.split()[1:] if "=" in part)
        self.sim_port = int(fields["sim"].rsplit(":", 1)[1])
        self.gcs_address = fields.get("gcs")
        sim_args = ["sim_bridge", "--fc", f"udp:127.0.0.1:{self.sim_port}", "--scenario", str(self.scenario_file),
                    "--watchdog-s", f"{o.watchdog_s:g}"]  # fmt: skip
        if o.lockstep:
            sim_args.append("--lockstep")
        if o.speed is not None:
            sim_args += ["--speed", f"{o.speed:g}"]
        sim_args += timed
        sim_args += list(o.sim_args)
        self.sim = self._spawn("sim", sim_args)
        self._await_line(self.fc, "FC_READY", ready_timeout_s)
        return self

    # -- run and stop ----------------------------------------------------------------------------
    def poll(self) -> tuple[int | None, int | None]:
        return (
            self.fc.proc.poll() if self.fc else None,
            self.sim.proc.poll() if self.sim else None,
        )

    def wait(self, timeout_s: float | None = None) -> int:
        """Wait until the run ends (the bridge reaches its duration, or a child exits).

        Returns 0 when both children ended cleanly; raises :class:`SitlError` naming the child and
        showing its last output when one failed.
        """
        assert self.fc is not None and self.sim is not None
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            fc_rc, sim_rc = self.poll()
            if sim_rc is not None or fc_rc is not None:
                break
            if deadline is not None and time.monotonic() > deadline:
                raise SitlError(f"SITL did not finish within {timeout_s:g} s")
            time.sleep(0.05)
        # The child that ended first is the one to name when something went wrong (the other one
        # then only reports that its peer is gone).
        first: Child
        first_rc: int | None
        if sim_rc is not None and fc_rc is not None:  # both seen ended at once: the one killed by a signal
            first, first_rc = (self.fc, fc_rc) if fc_rc < 0 <= sim_rc else (self.sim, sim_rc)
        else:
            first, first_rc = (self.sim, sim_rc) if sim_rc is not None else (self.fc, fc_rc)
        # One side ended; the other ends by itself: in lockstep at the same simulated time, in real
        # time on the simulator's end-of-run heartbeat (the FC) or its watchdog (the simulator).
        # A child still running after END_GRACE_S is stopped, and that is a failure of the run.
        signalled = self.stop(grace_s=END_GRACE_S)
        fc_rc = self.fc.proc.returncode
        sim_rc = self.sim.proc.returncode
        clean = (0, -signal.SIGTERM, -signal.SIGINT)
        if first_rc not in clean:
            raise SitlError(f"{first.name} {_how(first_rc)}{self._tail(first)}")
        for child, rc in ((self.sim, sim_rc), (self.fc, fc_rc)):
            if child.name in signalled:
                raise SitlError(f"{child.name} did not exit by itself within {END_GRACE_S:g} s of the run's end: stopped ({_how(rc)}){self._tail(child)}")
            if rc not in clean:
                raise SitlError(f"{child.name} {_how(rc)}{self._tail(child)}")
        return 0

    def stop(self, grace_s: float = 5.0) -> list[str]:
        """Stop both children: let them finish for ``grace_s``, then SIGTERM, then SIGKILL. Returns
        the names of the children that had to be signalled."""
        children = [c for c in (self.sim, self.fc) if c is not None]
        signalled: list[str] = []
        deadline = time.monotonic() + grace_s
        for c in children:
            try:
                c.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for c in children:
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
                signalled.append(c.name)
        for c in children:
            try:
                c.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait(timeout=5.0)
        for c in children:
            if c.thread is not None:
                c.thread.join(timeout=2.0)
            if c.proc.stdout is not None:
                c.proc.stdout.close()
        return signalled

    def terminate(self) -> None:
        """Stop now (Ctrl-C): SIGTERM both, then wait."""
        for c in (self.sim, self.fc):
            if c is not None and c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
        self.stop(grace_s=0.0)

    def __enter__(self) -> Sitl:
        try:
            return self.start()
        except BaseException:
            self.terminate()
            raise

    def __exit__(self, *exc: object) -> None:
        self.terminate()

    @property
    def fc_summary(self) -> dict | None:
        return self.fc.summary if self.fc else None

    @property
    def sim_summary(self) -> dict | None:
        return self.sim.summary if self.sim else None


def _how(rc: int | None) -> str:
    """How a child ended, for a message: "exited with code 3", "was killed by SIGKILL (exit code -9)"."""
    if rc is not None and rc < 0:
        try:
            name = signal.Signals(-rc).name
        except ValueError:
            name = f"signal {-rc}"
        return f"was killed by {name} (exit code {rc})"
    return f"exited with code {rc}"


#: the UDP port QGroundControl (and MAVProxy's default output) listens on out of the box.
QGC_DEFAULT_PORT = 14550


def print_connect_help(sitl: Sitl, out: TextIO = sys.stdout) -> None:
    o = sitl.options
    print(f"SITL running: {'lockstep' if o.lockstep else 'real time'}, controller {o.scenario.controller}, plant {o.scenario.plant},"
          f" log {sitl.tlog}", file=out)  # fmt: skip
    if o.gcs and o.gcs.startswith(("udp:", "udpout:")):
        target = o.gcs.split(":", 1)[1]
        port = target.rsplit(":", 1)[-1]
        qgc = ("QGroundControl listens there by default" if port == str(QGC_DEFAULT_PORT) else
               f"QGroundControl listens on {QGC_DEFAULT_PORT} by default: add a UDP comm link on port {port}")  # fmt: skip
        print(f"  telemetry goes to {target} ({qgc}; MAVProxy: mavproxy.py --master=udpin:{target})", file=out)
    if sitl.gcs_address and sitl.gcs_address != "-":
        print(f"  the FC answers on {sitl.gcs_address} (any GCS may also connect there: --master=udpout:{sitl.gcs_address})", file=out)
    if o.signing_key is not None:
        print("  the ground link is signed: sign with the same key (MAVProxy: module load signing; signing key"
              " PASSPHRASE; pymavlink: setup_signing; docs/security.md)", file=out)  # fmt: skip
    if o.lockstep and o.speed is None and o.gcs:
        print("  note: lockstep runs as fast as possible; a ground station needs --speed 1", file=out)
    out.flush()
