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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

from smcpilot.errors import SmcpilotError


class SitlError(SmcpilotError):
    """SITL could not start, or a child process failed."""


@dataclass(frozen=True)
class SitlOptions:
    """What to launch. Paths may be None (defaults of the child processes)."""

    lockstep: bool = True
    speed: float | None = None
    duration_s: float | None = None
    vehicle: Path | None = None
    controller: str = "adaptive_pid_smc"
    seed: int = 0
    gcs: str | None = "udp:127.0.0.1:14550"
    log_dir: Path = Path("logs")
    tlog: Path | None = None
    #: FC parameter file (default: fc-params.parm in log_dir).
    param_file: Path | None = None
    #: home for global coordinates "LAT,LON,ALT" (default: the FC's).
    home: str | None = None
    plan: Path | None = None
    plant: str = "rigid-body"
    rate_hz: float = 500.0
    physics_hz: float = 1000.0
    noise: bool = False
    noise_scale: float = 1.0
    wind_force_ned_n: tuple[float, float, float] | None = None
    gust_std_n: float = 0.0
    paper_disturbance: bool = False
    watchdog_s: float = 5.0
    #: extra arguments for the FC / the bridge (advanced use, tests).
    fc_args: tuple[str, ...] = ()
    sim_args: tuple[str, ...] = ()


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
    lines: "queue.Queue[str]" = field(default_factory=queue.Queue)
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

    def start(self, ready_timeout_s: float = 30.0) -> "Sitl":
        o = self.options
        if o.tlog is not None:
            tlog = o.tlog
        else:
            o.log_dir.mkdir(parents=True, exist_ok=True)
            tlog = o.log_dir / time.strftime(f"sitl-%Y%m%d-%H%M%S-{os.getpid()}.tlog")
        self.tlog = tlog
        fc_args = ["fc", "--sim", "udpin:127.0.0.1:0", "--gcs", o.gcs or "none", "--controller", o.controller,
                   "--rate-hz", f"{o.rate_hz:g}", "--tlog", str(tlog), "--watchdog-s", f"{o.watchdog_s:g}"]  # fmt: skip
        if o.lockstep:
            fc_args.append("--lockstep")
        if o.vehicle is not None:
            fc_args += ["--vehicle", str(o.vehicle)]
        if o.plan is not None:
            fc_args += ["--plan", str(o.plan)]
        param_file = o.param_file if o.param_file is not None else tlog.parent / "fc-params.parm"
        fc_args += ["--param-file", str(param_file)]
        if o.home is not None:
            fc_args += ["--home", o.home]
        if o.duration_s is not None and o.lockstep:
            fc_args += ["--duration", f"{o.duration_s!r}"]
        fc_args += list(o.fc_args)
        self.started_wall = time.monotonic()
        self.fc = self._spawn("fc", fc_args)
        listening = self._await_line(self.fc, "FC_LISTENING", 20.0)
        fields = dict(part.split("=", 1) for part in listening.split()[1:] if "=" in part)
        self.sim_port = int(fields["sim"].rsplit(":", 1)[1])
        self.gcs_address = fields.get("gcs")
        sim_args = ["sim_bridge", "--fc", f"udp:127.0.0.1:{self.sim_port}", "--plant", o.plant, "--seed", str(o.seed),
                    "--rate-hz", f"{o.rate_hz:g}", "--physics-hz", f"{o.physics_hz:g}", "--watchdog-s", f"{o.watchdog_s:g}"]  # fmt: skip
        if o.lockstep:
            sim_args.append("--lockstep")
        if o.speed is not None:
            sim_args += ["--speed", f"{o.speed:g}"]
        if o.duration_s is not None:
            sim_args += ["--duration", f"{o.duration_s!r}"]
        if o.vehicle is not None:
            sim_args += ["--vehicle", str(o.vehicle)]
        if o.noise:
            sim_args += ["--noise", "--noise-scale", f"{o.noise_scale:g}"]
        if o.wind_force_ned_n is not None:
            sim_args += ["--wind-force", ",".join(f"{v:g}" for v in o.wind_force_ned_n)]
        if o.gust_std_n > 0:
            sim_args += ["--gust-std", f"{o.gust_std_n:g}"]
        if o.paper_disturbance:
            sim_args.append("--paper-disturbance")
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
        # One side ended. In lockstep the other ends by itself at the same simulated time: give it a
        # moment. In real time the FC would only fly on into its state-loss failsafe: stop it now.
        self.stop(grace_s=3.0 if self.options.lockstep else 0.0)
        fc_rc = self.fc.proc.returncode
        sim_rc = self.sim.proc.returncode
        for child, rc in ((self.sim, sim_rc), (self.fc, fc_rc)):
            if rc not in (0, -signal.SIGTERM, -signal.SIGINT):
                raise SitlError(f"{child.name} exited with code {rc}{self._tail(child)}")
        return 0

    def stop(self, grace_s: float = 5.0) -> None:
        """Stop both children: let them finish for ``grace_s``, then SIGTERM, then SIGKILL."""
        children = [c for c in (self.sim, self.fc) if c is not None]
        deadline = time.monotonic() + grace_s
        for c in children:
            try:
                c.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for c in children:
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
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

    def terminate(self) -> None:
        """Stop now (Ctrl-C): SIGTERM both, then wait."""
        for c in (self.sim, self.fc):
            if c is not None and c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
        self.stop(grace_s=0.0)

    def __enter__(self) -> "Sitl":
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


def print_connect_help(sitl: Sitl, out: TextIO = sys.stdout) -> None:
    o = sitl.options
    print(f"SITL running: {'lockstep' if o.lockstep else 'real time'}, controller {o.controller}, plant {o.plant},"
          f" log {sitl.tlog}", file=out)  # fmt: skip
    if o.gcs and o.gcs.startswith(("udp:", "udpout:")):
        target = o.gcs.split(":", 1)[1]
        print(f"  telemetry goes to {target} (QGroundControl listens there by default;"
              f" MAVProxy: mavproxy.py --master=udpin:{target})", file=out)  # fmt: skip
    if sitl.gcs_address and sitl.gcs_address != "-":
        print(f"  the FC answers on {sitl.gcs_address} (any GCS may also connect there: --master=udpout:{sitl.gcs_address})", file=out)
    if o.lockstep and o.speed is None and o.gcs:
        print("  note: lockstep runs as fast as possible; a ground station needs --speed 1", file=out)
    out.flush()
