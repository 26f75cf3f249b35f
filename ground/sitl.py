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
from smcpilot.protocol import DEFAULT_GCS_URL, FC_GROUND_PORT
from smcpilot.scenario import Scenario
from smcpilot.swarm import fc_ground_port, fc_groups
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
    #: another simulator the FC connects to (``px4[:tcp:HOST[:PORT]]``, PX4's simulator API; the
    #: FC's ``--sim``): no simulator of ours is started, and the run is lockstep on its clock.
    sim_url: str | None = None
    #: a swarm's flight controllers in this many processes (``python -m fc.group``: several FCs in
    #: one process, each the same FC; in lockstep the same log); None: one process per vehicle.
    fc_processes: int | None = None

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
    #: a group of flight controllers in one process (:mod:`fc.group`): one child each, sharing ``proc``.
    members: list[Child] = field(default_factory=list)


class Sitl:
    """Both SITL processes. Use ``with Sitl(options) as sitl: sitl.wait()``."""

    def __init__(self, options: SitlOptions, *, echo: Callable[[str], None] | None = None, python: str = sys.executable) -> None:
        self.options = options
        self.echo = echo if echo is not None else (lambda line: None)
        self.python = python
        self.fc: Child | None = None
        self.sim: Child | None = None
        #: every vehicle's FC (one for a single vehicle: ``fc``), in the order of the swarm's vehicles.
        self.fcs: list[Child] = []
        #: a swarm's ground router (None for one vehicle, or without a ground link).
        self.router: Child | None = None
        self.sim_port: int | None = None
        self.gcs_address: str | None = None
        #: a swarm: every vehicle's system id, FC ground address and tlog, in order.
        self.sysids: list[int] = []
        self.gcs_addresses: list[str] = []
        self.tlogs: list[Path] = []
        self.tlog: Path | None = None
        #: the scenario file both processes were started with (beside the tlog).
        self.scenario_file: Path | None = None
        self.started_wall = 0.0

    # -- start -----------------------------------------------------------------------------------
    def _spawn(self, name: str, args: list[str], *, members: tuple[str, ...] = ()) -> Child:
        """``python -m ARGS`` with its output read by a thread. ``members``: the process is a group
        of flight controllers (:mod:`fc.group`), each with a child of its own (``Child.members``)."""
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
        group = Child(name, proc)
        group.members = [Child(member, proc) for member in members]
        route = bool(members)

        def pump() -> None:
            assert proc.stdout is not None
            for raw in proc.stdout:
                line = raw.rstrip("\n")
                child, name = group, group.name
                if route:  # a group of FCs: "@I LINE" is member I's
                    head, _, rest = line.partition(" ")
                    if head[:1] == "@" and head[1:].isdigit() and int(head[1:]) < len(group.members):
                        child = group.members[int(head[1:])]
                        line, name = rest, child.name
                    elif group.members:
                        child = group.members[0]
                child.tail.append(line)
                del child.tail[:-40]
                if line.startswith(("FC_SUMMARY ", "SIM_SUMMARY ", "ROUTER_SUMMARY ")):
                    try:
                        child.summary = json.loads(line.split(" ", 1)[1])
                    except ValueError:
                        pass
                    continue
                child.lines.put(line)
                if not line.startswith(("FC_LISTENING", "SIM_READY", "FC_READY", "ROUTER_READY")):
                    self.echo(f"[{name}] {line}")

        group.thread = threading.Thread(target=pump, name=f"{name}-output", daemon=True)
        for member in group.members:
            member.thread = group.thread
        group.thread.start()
        return group

    def _grouped(self) -> bool:
        """The swarm's flight controllers fly in groups (:mod:`fc.group`): fewer processes than vehicles."""
        o = self.options
        return o.scenario.swarm is not None and o.fc_processes is not None and o.fc_processes < o.scenario.count

    def _spinning(self) -> bool:
        """The swarm's processes busy-poll for their next message in lockstep (their ``--spin-s``
        default) only when the FC groups and the simulator fit the machine's cores (on two cores:
        one group). Otherwise (a process per vehicle, or more groups) every process blocks: a
        spinning process would take the core another needs to answer it. On a 2-core machine,
        K = 16 in lockstep, one spinning group flew 19.6 vehicle-seconds per wall second against
        13.4 for two blocking groups and 11.1 for a process per vehicle, in one run on 4 December
        (docs/swarms.md)."""
        o = self.options
        if not self._grouped():
            return False
        assert o.fc_processes is not None
        return o.fc_processes + 1 <= (os.cpu_count() or 1)

    def _spawn_group(self, name: str, group_file: Path, members: list[str]) -> list[Child]:
        """``python -m fc.group FILE``: one process, a :class:`Child` per flight controller in it
        (its lines are the ones the group prints as ``@I LINE``; the group's own lines go to the first)."""
        return self._spawn(name, ["fc.group", str(group_file)], members=tuple(members)).members

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
        lines = [ln for ln in child.tail if not ln.startswith(("FC_SUMMARY", "SIM_SUMMARY", "ROUTER_SUMMARY"))][-8:]
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
        if sc.swarm is not None:
            return self._start_swarm(tlog, ready_timeout_s)
        self.sysids = [1]
        self.tlogs = [tlog]
        fc_args = self._fc_args(self.scenario_file, tlog, o.gcs or "none", None, o.param_file, tlog.parent / "signing-timestamp")
        self.started_wall = time.monotonic()
        self.fc = self._spawn("fc", fc_args)
        self.fcs = [self.fc]
        listening = self._await_line(self.fc, "FC_LISTENING", 20.0)
        fields = dict(part.split("=", 1) for part in listening.split()[1:] if "=" in part)
        self.sim_port = int(fields["sim"].rsplit(":", 1)[1])
        self.gcs_address = fields.get("gcs")
        self.gcs_addresses = [self.gcs_address or "-"]
        if o.sim_url is not None:  # another simulator: the FC waits for it (its --startup-timeout-s)
            self._await_line(self.fc, "FC_READY", ready_timeout_s + 60.0)
            return self
        self.sim = self._spawn("sim", self._sim_args([self.sim_port]))
        self._await_line(self.fc, "FC_READY", ready_timeout_s)
        return self

    def _fc_args(self, scenario_file: Path, tlog: Path, gcs: str, gcs_port: int | None, param_file: Path | None,
                 signing_timestamps: Path, sysid: int | None = None, tick_phase: float | None = None) -> list[str]:  # fmt: skip
        o = self.options
        timed = ["--duration", repr(o.scenario.duration_s)] if o.timed else []
        fc_args = ["fc", "--sim", o.sim_url or "udpin:127.0.0.1:0", "--gcs", gcs, "--scenario", str(scenario_file),
                   "--tlog", str(tlog), "--watchdog-s", f"{o.watchdog_s:g}"]  # fmt: skip
        if gcs_port is not None:
            fc_args += ["--gcs-port", str(gcs_port)]
        if sysid is not None:
            fc_args += ["--sysid", str(sysid)]
        if o.scenario.swarm is not None:
            if not self._spinning():
                fc_args += ["--spin-s", "0"]
            if not self._grouped():  # and the pipelines fly in CPython: loading the compiled one costs each FC about a
                # second of CPU at start-up, more than it saves a swarm in flights of a few minutes (fc_args may say
                # --jit auto); a group loads it once for all its FCs, and --jit auto counts their flights together
                fc_args += ["--jit", "off"]
        if o.lockstep:
            fc_args.append("--lockstep")
        elif tick_phase is not None:  # real time, a swarm: its FCs' ticks spread over the period (docs/swarms.md)
            fc_args += ["--tick-phase", repr(tick_phase)]
        if param_file is not None:  # else the FC starts from defaults with a file of its own (NAME.parm)
            fc_args += ["--param-file", str(param_file)]
        fc_args += ["--signing-timestamps", str(signing_timestamps)]
        if o.signing_key is not None:
            fc_args += ["--signing-key", str(o.signing_key)]
        if o.lockstep:
            fc_args += timed
        return fc_args + list(o.fc_args)

    def _sim_args(self, ports: list[int]) -> list[str]:
        o = self.options
        assert self.scenario_file is not None
        sim_args = ["sim_bridge"]
        for port in ports:
            sim_args += ["--fc", f"udp:127.0.0.1:{port}"]
        sim_args += ["--scenario", str(self.scenario_file), "--watchdog-s", f"{o.watchdog_s:g}"]
        if o.scenario.swarm is not None and not self._spinning():
            sim_args += ["--spin-s", "0"]
        if o.lockstep:
            sim_args.append("--lockstep")
        if o.speed is not None:
            sim_args += ["--speed", f"{o.speed:g}"]
        if o.timed:
            sim_args += ["--duration", repr(o.scenario.duration_s)]
        return sim_args + list(o.sim_args)

    def _start_swarm(self, tlog: Path, ready_timeout_s: float) -> Sitl:
        """K flight controllers (system ids from the scenario's [swarm]), one ground router, one
        simulator stepping every plant (see :mod:`smcpilot.swarm`)."""
        o = self.options
        fleet = o.scenario.fleet()
        default_ground = o.gcs == DEFAULT_GCS_URL
        self.started_wall = time.monotonic()
        fc_gcs = "none"
        if o.gcs:
            router_args = ["ground.router", "--ground", o.gcs, "--sysids", ",".join(str(v.sysid) for v in fleet)]
            if default_ground:
                router_args += ["--ground-port", str(FC_GROUND_PORT)]
            self.router = self._spawn("router", router_args)
            ready = self._await_line(self.router, "ROUTER_READY", 20.0)
            fields = dict(part.split("=", 1) for part in ready.split()[1:] if "=" in part)
            fc_gcs = f"udp:{fields['vehicles']}"
            self.gcs_address = fields["ground"]
        every_args = []
        for v in fleet:
            vlog = tlog.with_name(f"{tlog.stem}-v{v.sysid}.tlog")
            vfile = v.scenario.save(vlog.with_name(vlog.stem + ".scenario.toml"))
            param_file = None if o.param_file is None else o.param_file.with_name(f"{o.param_file.stem}-v{v.sysid}{o.param_file.suffix}")
            gcs_port = (fc_ground_port(v.index) if default_ground else 0) if o.gcs else None
            every_args.append(self._fc_args(vfile, vlog, fc_gcs, gcs_port, param_file, tlog.parent / f"signing-timestamp-v{v.sysid}", v.sysid,
                                            v.index / len(fleet) if len(fleet) > 1 else None))  # fmt: skip
            self.sysids.append(v.sysid)
            self.tlogs.append(vlog)
        if self._grouped():
            assert o.fc_processes is not None
            by_vehicle: dict[int, Child] = {}
            for g, members in enumerate(fc_groups(len(fleet), o.fc_processes)):
                group_file = tlog.with_name(f"{tlog.stem}-fc-group{g + 1}.json")
                group_file.write_text(json.dumps([every_args[i][1:] for i in members], indent=1))  # (without "fc": the module)
                children = self._spawn_group(f"fc-group{g + 1}", group_file, [f"fc{self.sysids[i]}" for i in members])
                by_vehicle.update(zip(members, children))
            self.fcs = [by_vehicle[i] for i in range(len(fleet))]  # (in the swarm's order, whatever the groups)
        else:
            for sysid, args in zip(self.sysids, every_args):
                self.fcs.append(self._spawn(f"fc{sysid}", args))
        self.fc = self.fcs[0]
        ports = []
        for child in self.fcs:
            listening = self._await_line(child, "FC_LISTENING", 20.0 + 2.0 * len(fleet))
            fields = dict(part.split("=", 1) for part in listening.split()[1:] if "=" in part)
            ports.append(int(fields["sim"].rsplit(":", 1)[1]))
            self.gcs_addresses.append(fields.get("gcs", "-"))
        self.sim_port = ports[0]
        if self.router is None:
            self.gcs_address = self.gcs_addresses[0]
        self.sim = self._spawn("sim", self._sim_args(ports))
        for child in self.fcs:
            self._await_line(child, "FC_READY", ready_timeout_s + 0.5 * len(fleet))
        return self

    # -- run and stop ----------------------------------------------------------------------------
    def poll(self) -> tuple[int | None, int | None]:
        """(the FC's exit code or None while it runs, the simulator's); in a swarm, the first FC that ended."""
        fc_rc = next((c.proc.poll() for c in self.fcs if c.proc.poll() is not None), None)
        return (fc_rc, self.sim.proc.poll() if self.sim else None)

    def _vehicle_children(self) -> list[Child]:
        return [c for c in (self.sim, *self.fcs) if c is not None]

    def wait(self, timeout_s: float | None = None) -> int:
        """Wait until the run ends (the bridge reaches its duration, or a child exits).

        Returns 0 when every child ended cleanly; raises :class:`SitlError` naming the child and
        showing its last output when one failed.
        """
        assert self.fc is not None and (self.sim is not None or self.options.sim_url is not None)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        children = self._vehicle_children()
        while True:
            ended = [(c, c.proc.poll()) for c in children if c.proc.poll() is not None]
            if ended:
                break
            if deadline is not None and time.monotonic() > deadline:
                raise SitlError(f"SITL did not finish within {timeout_s:g} s")
            time.sleep(0.05)
        # The child that ended first is the one to name when something went wrong (the others
        # then only report that their peer is gone); seen ended at once: the one killed by a signal.
        first, first_rc = next(((c, rc) for c, rc in ended if rc is not None and rc < 0), ended[0])
        if len(ended) > 1 and first is not self.sim and all(rc is not None and rc >= 0 for _, rc in ended):
            first, first_rc = next(((c, rc) for c, rc in ended if c is self.sim), ended[0])
        # One side ended; the others end by themselves: in lockstep at the same simulated time, in
        # real time on the simulator's end-of-run heartbeat (the FCs) or its watchdog (the simulator).
        # A child still running after END_GRACE_S is stopped, and that is a failure of the run.
        signalled = self.stop(grace_s=END_GRACE_S)
        clean = (0, -signal.SIGTERM, -signal.SIGINT)
        if first_rc not in clean:
            raise SitlError(f"{first.name} {_how(first_rc)}{self._tail(first)}")
        for child in children:
            rc = child.proc.returncode
            if child.name in signalled:
                raise SitlError(f"{child.name} did not exit by itself within {END_GRACE_S:g} s of the run's end: stopped ({_how(rc)}){self._tail(child)}")
            if rc not in clean:
                raise SitlError(f"{child.name} {_how(rc)}{self._tail(child)}")
        if self.router is not None and self.router.proc.returncode not in clean:
            raise SitlError(f"router {_how(self.router.proc.returncode)}{self._tail(self.router)}")
        return 0

    def stop(self, grace_s: float = 5.0) -> list[str]:
        """Stop every child: let them finish for ``grace_s``, then SIGTERM, then SIGKILL. Returns
        the names of the children that had to be signalled (the router, which only ever ends on
        a signal, is stopped last and not counted)."""
        children = self._vehicle_children()
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
        if self.router is not None:
            if self.router.proc.poll() is None:
                self.router.proc.send_signal(signal.SIGTERM)
            children.append(self.router)
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
        for c in (self.sim, *self.fcs, self.router):
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

    @property
    def fc_summaries(self) -> list[dict | None]:
        """Every vehicle's FC summary, in the order of :attr:`sysids`."""
        return [c.summary for c in self.fcs]

    @property
    def router_summary(self) -> dict | None:
        return self.router.summary if self.router else None


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
    where = f"logs {sitl.tlogs[0].parent}/{sitl.tlog.stem if sitl.tlog else ''}-v*.tlog" if len(sitl.fcs) > 1 else f"log {sitl.tlog}"
    print(f"SITL running: {'lockstep' if o.lockstep else 'real time'}, controller {o.scenario.controller}, plant {o.scenario.plant},"
          f" {where}", file=out)  # fmt: skip
    if o.gcs and o.gcs.startswith(("udp:", "udpout:")):
        target = o.gcs.split(":", 1)[1]
        port = target.rsplit(":", 1)[-1]
        qgc = ("QGroundControl listens there by default" if port == str(QGC_DEFAULT_PORT) else
               f"QGroundControl listens on {QGC_DEFAULT_PORT} by default: add a UDP comm link on port {port}")  # fmt: skip
        print(f"  telemetry goes to {target} ({qgc}; MAVProxy: mavproxy.py --master=udpin:{target})", file=out)
    if len(sitl.fcs) > 1:
        print(f"  {len(sitl.fcs)} vehicles, system ids {', '.join(map(str, sitl.sysids))}: every vehicle's telemetry goes there"
              " through one router, which sends each station's packets to the vehicle their target system names"
              " (MAVProxy: vehicle N; QGroundControl: the vehicle selector)", file=out)  # fmt: skip
        if sitl.router is not None and sitl.gcs_address:
            print(f"  the router answers on {sitl.gcs_address} (a GCS may also connect there: --master=udpout:{sitl.gcs_address})", file=out)
        for sysid, addr, tlog in zip(sitl.sysids, sitl.gcs_addresses, sitl.tlogs):
            print(f"    vehicle {sysid}: its own FC port {addr}, log {tlog}", file=out)
    elif sitl.gcs_address and sitl.gcs_address != "-":
        print(f"  the FC answers on {sitl.gcs_address} (any GCS may also connect there: --master=udpout:{sitl.gcs_address})", file=out)
    if o.signing_key is not None:
        print("  the ground link is signed: sign with the same key (MAVProxy: module load signing; signing key"
              " PASSPHRASE; pymavlink: setup_signing; docs/security.md)", file=out)  # fmt: skip
    if o.lockstep and o.speed is None and o.gcs:
        print("  note: lockstep runs as fast as possible; a ground station needs --speed 1", file=out)
    out.flush()
