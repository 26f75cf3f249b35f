"""Helpers shared by the SITL end-to-end tests and the FC bad-input tests.

- :func:`write_plan` writes a plan TOML; :func:`fly_sitl` runs both SITL processes in lockstep and
  returns the parsed FC log (:class:`Flight`).
- :class:`Flight` holds the FC's ``.tlog`` as numpy arrays: the simulator's state (source
  component 200, NED, simulated time from ``time_boot_ms``), the actuator commands, the per-tick
  ``DEBUG_FLOAT_ARRAY`` "SMC" columns (:data:`smcpilot.protocol.SMC_FIELDS`) and the STATUSTEXT events.
- :class:`FcProcess` runs ``python -m fc`` with its output read on a thread; :class:`FakeSim` is a
  UDP socket that plays the simulator (sysid 1, component 200) for the bad-input tests.

Everything binds 127.0.0.1 on ephemeral ports, so tests can run in parallel.
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.sitl import Sitl, SitlOptions
from smcpilot.protocol import SIM_COMPONENT_ID, SMC_ARRAY_ID, SMC_FIELDS
from smcpilot.tlog import read_tlog

PYTHON = sys.executable
LOOPBACK = "127.0.0.1"
SIM_COMPONENT = SIM_COMPONENT_ID
#: Generous wall-clock limits: only to turn a hang into a failure, never to measure speed.
HANG_TIMEOUT_S = 120.0


# -- plans ---------------------------------------------------------------------------------------
def write_plan(path: Path, steps: Iterable[dict]) -> Path:
    """Write ``[[step]]`` tables (dicts of key -> number/str) as a plan TOML file."""
    lines: list[str] = []
    for st in steps:
        lines.append("[[step]]")
        for k, v in st.items():
            lines.append(f"{k} = {json.dumps(v) if isinstance(v, str) else repr(float(v))}")
        lines.append("")
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


TAKEOFF_3M = ({"t_s": 0.0, "action": "takeoff", "alt_m": 3.0},)


# -- the log ---------------------------------------------------------------------------------------
@dataclass
class Flight:
    """A FC ``.tlog`` as arrays. Angles in radians (NED/FRD), times in simulated seconds."""

    path: Path
    t: np.ndarray  # state time (time_boot_ms of the simulator's LOCAL_POSITION_NED)
    north: np.ndarray
    east: np.ndarray
    alt: np.ndarray
    att_t: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    act_t: np.ndarray  # HIL_ACTUATOR_CONTROLS time_usec in s
    motors: np.ndarray  # (n, 4)
    armed: np.ndarray  # bool
    smc_t: np.ndarray
    smc: dict[str, np.ndarray]
    events: list[tuple[float, str]] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)

    def window(self, t0: float, t1: float = math.inf) -> np.ndarray:
        """Mask of state samples with t0 <= t <= t1."""
        return (self.t >= t0 - 1e-9) & (self.t <= t1 + 1e-9)

    def att_window(self, t0: float, t1: float = math.inf) -> np.ndarray:
        return (self.att_t >= t0 - 1e-9) & (self.att_t <= t1 + 1e-9)

    def smc_window(self, t0: float, t1: float = math.inf) -> np.ndarray:
        return (self.smc_t >= t0 - 1e-9) & (self.smc_t <= t1 + 1e-9)

    def position_error(self, mask: np.ndarray, north: float, east: float, alt: float) -> np.ndarray:
        """3-D distance from (north, east, alt) of the masked samples, m."""
        return np.sqrt((self.north[mask] - north) ** 2 + (self.east[mask] - east) ** 2 + (self.alt[mask] - alt) ** 2)

    @property
    def chi_hat(self) -> np.ndarray:
        return np.column_stack([self.smc[f"chi_{c}"] for c in ("phi", "theta", "psi", "z")])

    @property
    def sigma(self) -> np.ndarray:
        return np.column_stack([self.smc[f"sigma_{c}"] for c in ("phi", "theta", "psi", "z")])


def load_flight(path: Path) -> Flight:
    """Parse the FC's tlog. State rows come from the simulator (source component 200) only."""
    pos: list[tuple] = []
    att: list[tuple] = []
    act: list[tuple] = []
    smc_t: list[int] = []
    smc_rows: list[Sequence[float]] = []
    events: list[tuple[float, str]] = []
    counts: dict[str, int] = {}
    nsmc = len(SMC_FIELDS)
    for t_us, m in read_tlog(path):
        ty = m.get_type()
        counts[ty] = counts.get(ty, 0) + 1
        if ty == "LOCAL_POSITION_NED":
            if m.get_srcComponent() == SIM_COMPONENT:
                pos.append((m.time_boot_ms * 1e-3, m.x, m.y, -m.z))
        elif ty == "ATTITUDE":
            if m.get_srcComponent() == SIM_COMPONENT:
                att.append((m.time_boot_ms * 1e-3, m.roll, m.pitch, m.yaw))
        elif ty == "HIL_ACTUATOR_CONTROLS":
            c = m.controls
            act.append((m.time_usec * 1e-6, c[0], c[1], c[2], c[3], bool(m.mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)))
        elif ty == "DEBUG_FLOAT_ARRAY":
            if m.name == "SMC" and m.array_id == SMC_ARRAY_ID:
                smc_t.append(t_us)
                smc_rows.append(m.data[:nsmc])
        elif ty == "STATUSTEXT":
            events.append((t_us * 1e-6, m.text))
    p = np.asarray(pos, dtype=float).reshape(-1, 4)
    a = np.asarray(att, dtype=float).reshape(-1, 4)
    ac = np.asarray(act, dtype=float).reshape(-1, 6)
    s = np.asarray(smc_rows, dtype=float).reshape(-1, nsmc)
    return Flight(
        path=path,
        t=p[:, 0], north=p[:, 1], east=p[:, 2], alt=p[:, 3],
        att_t=a[:, 0], roll=a[:, 1], pitch=a[:, 2], yaw=a[:, 3],
        act_t=ac[:, 0], motors=ac[:, 1:5], armed=ac[:, 5] > 0.5,
        smc_t=np.asarray(smc_t, dtype=float) * 1e-6,
        smc={name: s[:, i] for i, name in enumerate(SMC_FIELDS)},
        events=events, counts=counts,
    )  # fmt: skip


def wrap_deg(a: np.ndarray | float) -> np.ndarray:
    """Wrap degrees to [-180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


# -- SITL runs ----------------------------------------------------------------------------------
def sitl_options(tmp_path: Path, name: str, *, plan: Sequence[dict] | None = TAKEOFF_3M, **kw) -> SitlOptions:
    """Lockstep options with the log at ``tmp_path/name/name.tlog`` and no ground link by default.

    Each run has its own directory: the FC keeps its parameter file next to the log."""
    run_dir = tmp_path / name
    run_dir.mkdir(parents=True, exist_ok=True)
    plan_path = write_plan(run_dir / f"{name}-plan.toml", plan) if plan else None
    kw.setdefault("gcs", None)
    kw.setdefault("lockstep", True)
    return SitlOptions.of(tlog=run_dir / f"{name}.tlog", log_dir=run_dir, plan=plan_path, **kw)


def fly_sitl(tmp_path: Path, name: str, duration_s: float, **kw) -> tuple[Sitl, Flight]:
    """Run lockstep SITL for ``duration_s`` simulated seconds and parse the FC's log."""
    opts = sitl_options(tmp_path, name, duration_s=duration_s, **kw)
    with Sitl(opts) as sitl:
        assert sitl.wait(timeout_s=HANG_TIMEOUT_S) == 0
    assert sitl.fc_summary is not None, "the FC printed no FC_SUMMARY"
    assert sitl.fc_summary["sim_time_s"] >= duration_s - 1e-6, sitl.fc_summary
    assert opts.tlog is not None
    return sitl, load_flight(opts.tlog)


# -- the FC process on its own -----------------------------------------------------------------
class FcProcess:
    """``python -m fc ARGS`` with stdout/stderr read line by line on a thread.

    Runs in ``cwd`` (the test's tmp dir), so files the FC keeps by default under ``logs/`` (its
    parameter file, logs) are private to the test."""

    def __init__(self, args: Sequence[str], cwd: Path) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            [PYTHON, "-m", "fc", *args],
            cwd=cwd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            env=env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.all_lines: list[str] = []
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = raw.rstrip("\n")
            self.all_lines.append(line)
            self.lines.put(line)

    def await_line(self, prefix: str, timeout_s: float = 30.0) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"fc did not print {prefix!r} within {timeout_s} s; output: {self.all_lines}")
            try:
                line = self.lines.get(timeout=min(remaining, 0.1))
            except queue.Empty:
                if self.proc.poll() is not None:
                    self._thread.join(timeout=2.0)
                    hits = [ln for ln in self.all_lines if ln.startswith(prefix)]
                    if hits:
                        return hits[0]
                    raise AssertionError(f"fc exited ({self.proc.returncode}) before {prefix!r}: {self.all_lines}") from None
                continue
            if line.startswith(prefix):
                return line

    def listening(self) -> dict[str, str]:
        line = self.await_line("FC_LISTENING")
        return dict(part.split("=", 1) for part in line.split()[1:] if "=" in part)

    def wait(self, timeout_s: float = 30.0) -> int:
        rc = self.proc.wait(timeout=timeout_s)
        self._thread.join(timeout=5.0)
        return rc

    def summary(self) -> dict:
        for line in self.all_lines:
            if line.startswith("FC_SUMMARY "):
                return json.loads(line.split(" ", 1)[1])
        raise AssertionError(f"no FC_SUMMARY in {self.all_lines}")

    def stop(self) -> int:
        """SIGTERM (clean stop: tlog closed, summary printed) and wait."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.wait()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        try:
            self.wait(timeout_s=10.0)
        except subprocess.TimeoutExpired:  # pragma: no cover
            pass
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def udp_socket(timeout_s: float = 5.0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
    sock.bind((LOOPBACK, 0))
    sock.settimeout(timeout_s)
    return sock


def parse_datagram(data: bytes) -> list[mavlink.MAVLink_message]:
    """Every MAVLink message in one datagram (a fresh parser each time)."""
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    return mav.parse_buffer(data) or []


class FakeSim:
    """Plays the simulator: sends ATTITUDE + LOCAL_POSITION_NED in one datagram (sysid 1,
    component 200 unless told otherwise) to the FC's sim port; reads HIL_ACTUATOR_CONTROLS back."""

    def __init__(self, fc_sim_address: tuple[str, int], *, timeout_s: float = 10.0) -> None:
        self.addr = fc_sim_address
        self.sock = udp_socket(timeout_s)
        self._mavs: dict[tuple[int, int], mavlink.MAVLink] = {}

    def mav(self, sysid: int = 1, compid: int = SIM_COMPONENT) -> mavlink.MAVLink:
        key = (sysid, compid)
        if key not in self._mavs:
            self._mavs[key] = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        return self._mavs[key]

    def state_packets(
        self,
        t_ms: int,
        *,
        ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rpy: tuple[float, float, float] = (0.0, 0.0, 0.0),
        vel: tuple[float, float, float] = (0.0, 0.0, 0.0),
        sysid: int = 1,
        compid: int = SIM_COMPONENT,
    ) -> tuple[bytes, bytes]:
        mav = self.mav(sysid, compid)
        att = mav.attitude_encode(t_ms, rpy[0], rpy[1], rpy[2], 0.0, 0.0, 0.0).pack(mav)
        pos = mav.local_position_ned_encode(t_ms, ned[0], ned[1], ned[2], vel[0], vel[1], vel[2]).pack(mav)
        return bytes(att), bytes(pos)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.addr)

    def send_state(self, t_ms: int, **kw) -> None:
        att, pos = self.state_packets(t_ms, **kw)
        self.send_raw(att + pos)

    def recv_actuators(self, timeout_s: float | None = None) -> list[mavlink.MAVLink_message]:
        """The HIL_ACTUATOR_CONTROLS of the next datagram (waits up to the socket timeout)."""
        if timeout_s is not None:
            self.sock.settimeout(timeout_s)
        data, _ = self.sock.recvfrom(65535)
        return [m for m in parse_datagram(data) if m.get_type() == "HIL_ACTUATOR_CONTROLS"]

    def exchange(self, t_ms: int, **kw) -> mavlink.MAVLink_message:
        """Send a good state and return the FC's answer (the first actuator message that arrives)."""
        self.send_state(t_ms, **kw)
        msgs = self.recv_actuators()
        assert len(msgs) == 1, msgs
        return msgs[0]

    def close(self) -> None:
        self.sock.close()


# -- processes ----------------------------------------------------------------------------------
def children_of(pid: int) -> list[int]:
    """Pids whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                stat = f.read().decode("ascii", "replace")
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces, so split after the last ')'.
        rest = stat.rsplit(")", 1)[1].split()
        if int(rest[1]) == pid:
            out.append(int(entry))
    return out


def process_alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read().decode("ascii", "replace")
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return ""
